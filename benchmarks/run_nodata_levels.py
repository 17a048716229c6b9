"""Nodata against fine levels: quantizing a grid half nodata against the same grid without nodata.

level_of (kernels/stepped.py) walked a NaN height up through every threshold and back down on the estimate-and-correct
path of uniform levels (every ``interval=``; on the CPU above 64 thresholds, on CUDA always), 2 x levels comparisons a
nodata node, before it returned level 0; it now returns 0 at once. Input: a crop of the embedded DEM (Big Tujunga,
30 m; 512² nodes, 347-1986 m), its lower half by height made nodata (a flooded valley floor, NaN) or left as it is,
the same uniform levels for both, ``interval`` apart over the crop's range (50 m: 35 levels, the CPU's vector path,
which level_of does not serve; 1 m: 1,640; 0.2 m: 8,196). Prints, per interval, the best of ``--repeat`` CPU times of
``quantize_levels`` on each grid and their ratio, and ``stepped()`` end to end on a smaller crop (``--stepped-size``,
1 m) for scale: the half-nodata mesh is half the size, and the mesh's cost grows with the levels crossed, so compare
that case between trees, not with the full grid. Pinned to one core.

Run once per tree, alternating, each in its own process (an old tree extracted with ``git archive REV | tar -x -C
/tmp/old && cp -r /tmp/old/kernels /tmp/old/stepterrain/kernels``)::

    for k in 1 2; do for r in /tmp/old .; do python benchmarks/run_nodata_levels.py $r; done; done
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

from machine import pin_to_one_core, repeat_count  # benchmarks/ is the script folder (standard library only)


def best_seconds(run: Callable[[], object], repeat: int) -> float:
    run()  # compile / warm the scratch buffers
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        run()
        times.append(time.process_time() - t0)
    return min(times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("root", nargs="?", default=".", help="the tree to import stepterrain from")
    parser.add_argument("--size", type=int, default=512,
                        help="nodes a side of the quantized crop (default 512; the DEM is 643 x 1197)")
    parser.add_argument("--intervals", type=float, nargs="+", default=[50.0, 1.0, 0.2], help="metres between levels")
    parser.add_argument("--stepped-size", type=int, default=256, help="nodes a side for stepped() (0: skip)")
    parser.add_argument("--stepped-interval", type=float, default=1.0)
    parser.add_argument("--repeat", type=repeat_count, default=3)
    args = parser.parse_args(argv)
    root = Path(args.root).resolve()
    sys.path.insert(0, str(root))
    pin_to_one_core()
    import numpy as np
    import warp as wp
    from stepterrain.kernels import stepped as stepped_kernels

    import stepterrain as st
    from stepterrain import kernels
    from stepterrain._device import launch_chunked, resolve_device

    for module in (st, kernels):  # a tree without stepterrain/kernels gets the running venv's kernels
        if not module.__file__.startswith(str(root)):
            raise SystemExit(f"imported {module.__name__} from {module.__file__}, not from {root} (copy its kernels/ "
                             "to stepterrain/kernels)")
    dem = st.sample_dem()
    device = resolve_device("cpu")

    def half_nodata(size: int) -> tuple[np.ndarray, np.ndarray]:
        full = np.ascontiguousarray(dem.heights[:size, :size], dtype=np.float32)
        return full, np.where(full < np.median(full), np.float32(np.nan), full)

    def uniform_levels(full: np.ndarray, interval: float) -> np.ndarray:
        return np.asarray(st.isovalues((float(full.min()), float(full.max())), interval=interval), np.float32)

    def ratio(name: str, plain: float, nodata: float) -> str:
        return f"{name}: {plain * 1e3:.1f} ms no nodata, {nodata * 1e3:.1f} ms half nodata (x{nodata / plain:.1f})"

    full, holed = half_nodata(args.size)
    out = wp.zeros(full.size, dtype=wp.int32, device=device)
    grids = [wp.array(z.reshape(-1), device=device) for z in (full, holed)]
    parts = []
    for interval in args.intervals:
        levels = uniform_levels(full, interval)
        iso = st.stepped._build_isovalue_struct(levels, device)
        plain, nodata = (best_seconds(lambda h=h, iso=iso: launch_chunked(
            stepped_kernels.quantize_levels, n=full.size, inputs=[h, iso], outputs=[out], device=device), args.repeat)
            for h in grids)
        parts.append(ratio(f"quantize {args.size}² {len(levels)} levels", plain, nodata))
    if args.stepped_size:
        full, holed = half_nodata(args.stepped_size)
        levels = uniform_levels(full, args.stepped_interval)
        plain, nodata = (best_seconds(lambda z=z: st.stepped(z, levels=levels, spacing=dem.spacing, device=device),
                                      args.repeat) for z in (full, holed))
        parts.append(f"stepped {args.stepped_size}² {len(levels)} levels: {plain * 1e3:.1f} ms no nodata, "
                     f"{nodata * 1e3:.1f} ms half nodata (half the mesh)")
    print(root, "; ".join(parts))


if __name__ == "__main__":
    main()
