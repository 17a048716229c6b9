"""Side-by-side benchmark of closing a stepped surface into a solid: ``stepterrain.mesh.close_solid`` (the Warp
kernels of ``kernels/solid.py``) against the NumPy implementation it replaced (``tests/reference_solid.py``, what a
user would otherwise have), on the same surface.

Cases: the embedded sample DEM at a 50 m interval, and a 2049² grid tiled from it with a 300 x 600 nodata hole at a
20 m interval. Per case: the surface (``stepped`` without ``solid``: the kernels' own share), both ``close_solid``
implementations on that surface (median and best of ``--repeat`` runs, warmed up; the outputs checked equal once, bit
for bit up to the order of the base vertices), and ``stepped(..., solid=True)`` end to end.

    python benchmarks/run_solid.py --repeat 5
    python benchmarks/run_solid.py --cases sample --repeat 3 --device cpu
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

_HERE = Path(__file__).resolve().parent
if str(_HERE.parent) not in sys.path:
    sys.path.insert(0, str(_HERE.parent))

import warp as wp  # noqa: E402

import stepterrain as st  # noqa: E402
from benchmarks.machine import cpu_model, repeat_count  # noqa: E402
from stepterrain import stepped as stepped_module  # noqa: E402
from stepterrain.mesh import _close_solid  # noqa: E402
from stepterrain.terrain import as_terrain  # noqa: E402
from tests.reference_solid import close_solid as close_solid_numpy  # noqa: E402

# close_solid as stepped() calls it on its own surfaces: without the public close_solid's check of a foreign surface
# (an oriented manifold with a boundary: a sort of the directed edges, about 0.45 s a million faces), which the NumPy
# reference does not make either
close_solid = partial(_close_solid, turn=True)

CASES = ("sample", "holes2048")


def _case(name: str) -> tuple[Any, float]:
    dem = st.sample_dem()
    if name == "sample":
        return dem, 50.0
    big = np.tile(np.asarray(dem.heights), (3, 2))[:2049, :2049].copy()
    big[100:400, 300:900] = np.nan
    return big, 20.0


def _surface(heights: Any, interval: float, device: wp.Device) -> tuple[Any, ...]:
    """The surface stepped() closes for a solid (heights moved off the thresholds) and its default floor."""
    t = as_terrain(heights)
    values = st.isovalues(t.height_range, interval=interval)
    t = stepped_module._off_thresholds(t, values)
    arrays, vertices = stepped_module._stepped_arrays(t, values, 1.0, None, device)
    floor = stepped_module.default_floor(values, float(vertices[:, 2].min()), interval)
    return vertices, arrays.faces, ~arrays.face_walls, floor


def _same_solid(got: tuple[Any, ...], want: tuple[Any, ...]) -> bool:
    """Whether two close_solid results are the same solid up to the order of the base vertices (the kernels number the
    columns in the order of their smallest surface vertex, the reference in their key's lexical order): the same
    dtypes and shapes, the surface vertices, kept mask, faces added and sources equal bit for bit, and one bijection
    of the base vertices (read off the faces, which use every base vertex here) taking the reference's faces and base
    rows to the kernels'."""
    (gv, gf, gk, ga, gs), (wv, wf, wk, wa, ws) = got, want
    if ga != wa or any(g.dtype != w.dtype or g.shape != w.shape for g, w in ((gv, wv), (gf, wf), (gk, wk), (gs, ws))):
        return False
    n = len(ws)
    if not (np.array_equal(gk, wk) and np.array_equal(gs, ws) and np.array_equal(gv[:n].view(np.uint64),
                                                                                     wv[:n].view(np.uint64))):
        return False
    base = wf >= n
    if not np.array_equal(base, gf >= n) or not np.array_equal(gf[~base], wf[~base]):
        return False
    perm = np.full(len(wv) - n, -1, np.int64)
    perm[wf[base] - n] = gf[base] - n
    return bool((perm >= 0).all() and np.array_equal(perm[wf[base] - n], gf[base] - n)
                and len(np.unique(perm)) == len(perm)
                and np.array_equal(gv[n + perm].view(np.uint64), wv[n:].view(np.uint64)))


def _times(fn: Callable[[], Any], repeat: int) -> list[float]:
    fn()  # warm: kernels loaded, caches
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return times


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    parser.add_argument("--repeat", type=repeat_count, default=5, help="timed runs per contender (default 5)")
    parser.add_argument("--device", default="cpu", help="Warp device of the kernels (default cpu)")
    args = parser.parse_args(argv)
    device = wp.get_device(args.device)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=_HERE, capture_output=True, text=True,
                            check=False).stdout.strip() or "unknown"
    print(f"command: `python benchmarks/run_solid.py {' '.join(sys.argv[1:] if argv is None else argv)}`; "
          f"commit {commit}; {cpu_model()}")
    print(f"device {device}, repeat {args.repeat}, {st.get_cpu_threads()} CPU threads")
    print("| case | faces | contender | median s | best s | NumPy / Warp (median) |")
    print("|---|---:|---|---:|---:|---:|")
    for name in args.cases:
        heights, interval = _case(name)
        vertices, faces, terrace, floor = _surface(heights, interval, device)
        got = close_solid(vertices, faces, terrace, floor, device)
        want = close_solid_numpy(vertices, faces, terrace, floor)
        if not _same_solid(got, want):
            raise SystemExit(f"{name}: close_solid differs from the NumPy reference")
        del got, want
        surface = (vertices, faces, terrace, floor)
        rows = {
            "surface (stepped)": _times(partial(st.stepped, heights, interval=interval, device=device), args.repeat),
            "close_solid, Warp": _times(partial(close_solid, *surface, device), args.repeat),
            "close_solid, NumPy": _times(partial(close_solid_numpy, *surface), args.repeat),
            "solid (stepped)": _times(partial(st.stepped, heights, interval=interval, solid=True, device=device),
                                      args.repeat),
        }
        warp_median = statistics.median(rows["close_solid, Warp"])
        for contender, times in rows.items():
            median = statistics.median(times)
            ratio = f"{median / warp_median:.1f}x" if contender == "close_solid, NumPy" else ""
            print(f"| {name} | {len(faces):,} | {contender} | {median:.3f} | {min(times):.3f} | {ratio} |")


if __name__ == "__main__":
    main()
