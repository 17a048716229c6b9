"""The same pipelines on Warp's CPU backend and on CUDA, side by side in one process, on real data.

Each pipeline runs on every device named (default: ``cpu`` and every CUDA device Warp finds), warmed up
first (kernels compiled or loaded from Warp's cache), then timed ``--repeat`` times with the device
synchronized before the clock stops; the table gives medians and the ratio to the CPU backend. Where a
NumPy reference exists it runs in the same process. The outputs of the devices are
compared as well (topology exactly, positions to 1e-5 relative), so a fast wrong kernel cannot pass. The NumPy
reference runs once, cold (a row of its own, its face and vertex counts checked against the first device's).

- ``stepped 2048²/20``: ``stepterrain.stepped`` end to end (kernels, device-to-host copies, the Trimesh)
  and the kernels alone (``step_arrays`` + ``blend``) on the 2048² grid of ``baselines.grid_heights``
  (tiled real SRTM), 20 equal steps; the NumPy reference of the tests on the same input.
- ``re-step 512²``: the interactive loop of issue 2 (a new interval; a new γ into the kept arrays).
- ``globe``: ``Globe.from_latlon`` on the ETOPO 10' grid (6 x 1025² nodes) and a far-view adaptive mesh
  of about 200k triangles (the error found once on the CPU, reused on every device).
- ``hillshade``: ``stepterrain.hillshade`` with cast shadows on the 2048² grid.
- ``closeup``: ``closeup_layers`` for 4 close-ups whose ROIs cover 5 % of a 1025² terrain each: per frame
  (the ROIs' cull kept, M applied again) and with new ROIs (amplify and cull as well). Rendering is not
  included (pyvista/VTK draw on the CPU's OpenGL here).

Run: ``python benchmarks/run_cuda.py [--devices cpu cuda:0] [--repeat 5] [--output FILE]``. Needs no
pyvista/VTK (the VTK contenders of run_stepped.py are CPU programs; see RESULTS.md for them).
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

_HERE = Path(__file__).resolve().parent
if str(_HERE.parent) not in sys.path:
    sys.path.insert(0, str(_HERE.parent))

from benchmarks import baselines  # noqa: E402
from benchmarks.machine import cpu_model, repeat_count  # noqa: E402


def timed(fn: Callable[[], Any], device: str, repeat: int) -> tuple[float, Any]:
    """Median wall seconds of ``fn`` (device synchronized inside the clock) and its last result."""
    import warp as wp

    out = fn()  # warm: compile or load, first-touch allocations
    wp.synchronize_device(device)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def same_mesh(a: Any, b: Any) -> str:
    """'identical', 'equal to 1e-5' or what differs, for two Trimesh results."""
    if a.faces.shape != b.faces.shape or a.vertices.shape != b.vertices.shape:
        return f"DIFFERENT sizes {a.faces.shape}/{a.vertices.shape} vs {b.faces.shape}/{b.vertices.shape}"
    if not np.array_equal(a.faces, b.faces):
        return "DIFFERENT faces"
    if np.array_equal(a.vertices, b.vertices):
        return "identical"
    scale = max(float(np.abs(a.vertices).max()), 1.0)
    err = float(np.abs(a.vertices - b.vertices).max()) / scale
    return f"equal to {err:.1e}" if err <= 1e-5 else f"DIFFERENT positions ({err:.1e})"


def bench_stepped(devices: list[str], repeat: int, rows: list[list[str]]) -> None:
    import warp as wp

    import stepterrain
    from stepterrain import Terrain
    from stepterrain.stepped import blend, step_arrays

    heights, spacing = baselines.grid_heights(2049)
    values = baselines.steps_isovalues(heights, 20)
    results: dict[str, Any] = {}
    for dev in devices:
        t_mesh, mesh = timed(lambda d=dev: stepterrain.stepped(heights, levels=values, spacing=spacing, device=d),
                             dev, repeat)
        terrain = Terrain.from_heights(heights, spacing=spacing)

        wdev = wp.get_device(dev)  # the internal API takes a wp.Device

        def kernels(d: Any = wdev, t: Terrain = terrain) -> Any:
            return blend(t, step_arrays(t, values, device=d), 1.0, device=d)

        t_kern, _ = timed(kernels, dev, repeat)
        results[dev] = mesh
        rows.append([f"stepped 2048²/20 ({len(mesh.faces):,} faces)", dev, f"{t_mesh * 1e3:,.1f}",
                     f"{t_kern * 1e3:,.1f} (step_arrays + blend)", ""])
        print(rows[-1], flush=True)
    # one run, not warmed up (tens of seconds on a CPU): unlike the devices' medians, it may pay the first touch of
    # its memory; checked to give the first device's mesh size (the same topology as the kernels, tests/reference.py)
    t0 = time.perf_counter()
    ref = baselines.numpy_reference(heights, spacing, values)
    ms = (time.perf_counter() - t0) * 1e3
    first = results[devices[0]]
    same = (len(ref.faces), len(ref.points)) == (len(first.faces), len(first.vertices))
    rows.append(["stepped 2048²/20", "NumPy reference (one cold run)", f"{ms:,.0f}", "",
                 f"same faces and vertices as `{devices[0]}`" if same else
                 f"DIFFERENT: {len(ref.faces):,} faces, {len(ref.points):,} vertices"])
    print(rows[-1], flush=True)
    for dev in devices[1:]:
        check = same_mesh(results[devices[0]], results[dev])
        rows.append(["stepped 2048²/20", f"{dev} vs {devices[0]}", "", "", check])


def bench_restep(devices: list[str], repeat: int, rows: list[list[str]]) -> None:
    import warp as wp

    from benchmarks.run_stepped import restep

    for dev in devices:
        out = restep(wp.get_device(dev), 512, repeat=max(repeat, 10))
        rows.append([f"re-step 512² ({out['faces']:,} faces)", dev, f"{out['interval_mesh_ms']:.2f}",
                     f"{out['interval_arrays_ms']:.2f} (arrays); new γ {out['gamma_ms']:.2f} ms", ""])
        print(rows[-1], flush=True)


def bench_globe(devices: list[str], repeat: int, rows: list[list[str]]) -> None:
    from benchmarks.run_globe import data_file, views
    from stepterrain.globe import Globe

    with np.load(data_file("global_relief.npz")) as d:
        lat, lon, z = d["lat"], d["lon"], d["elevation"]
    globes, meshes, error = {}, {}, None
    for dev in devices:
        t_pre, globe = timed(lambda d=dev: Globe.from_latlon(z, lat, lon, face_size=1025, device=d), dev, repeat)
        cam = views(globe)["far"]
        if error is None:  # the error that gives about 200k triangles, found once
            lo, hi = 0.1, 1e6
            for _ in range(40):
                error = math.sqrt(lo * hi)
                count = len(globe.mesh(error=error, camera=cam).faces)
                if abs(count - 200_000) < 10_000:
                    break
                lo, hi = (error, hi) if count > 200_000 else (lo, error)
        t_view, mesh = timed(lambda g=globe, c=cam, e=error: g.mesh(error=e, camera=c), dev, repeat)
        globes[dev], meshes[dev] = globe, mesh
        rows.append(["globe 6 x 1025²: from_latlon", dev, f"{t_pre * 1e3:,.1f}", "", ""])
        rows.append([f"globe far view ({len(mesh.faces):,} faces)", dev, f"{t_view * 1e3:,.1f}", "", ""])
        print(rows[-2:], flush=True)
    for dev in devices[1:]:
        h0, h1 = globes[devices[0]].heights, globes[dev].heights
        rows.append(["globe heights", f"{dev} vs {devices[0]}", "", "",
                     f"max |Δ| {float(np.abs(h0 - h1).max()):.3g} m"])
        rows.append(["globe far view", f"{dev} vs {devices[0]}", "", "", same_mesh(meshes[devices[0]], meshes[dev])])


def bench_hillshade(devices: list[str], repeat: int, rows: list[list[str]]) -> None:
    import stepterrain

    heights, spacing = baselines.grid_heights(2049)
    images = {}
    for dev in devices:
        t, img = timed(lambda d=dev: stepterrain.hillshade(heights, spacing=spacing, shadows=True, device=d), dev,
                       repeat)
        images[dev] = np.asarray(img)
        rows.append(["hillshade + shadows 2049²", dev, f"{t * 1e3:,.1f}", "", ""])
        print(rows[-1], flush=True)
    for dev in devices[1:]:
        diff = np.abs(images[devices[0]].astype(np.int32) - images[dev].astype(np.int32))
        rows.append(["hillshade", f"{dev} vs {devices[0]}", "", "",
                     f"max |Δ| {int(diff.max())} grey level(s), {float((diff > 0).mean()) * 100:.3f} % of pixels"])


def bench_closeup(devices: list[str], repeat: int, rows: list[list[str]]) -> None:
    from stepterrain import Terrain
    from stepterrain.closeup import ROI, CloseUp, closeup_layers

    heights, spacing = baselines.grid_heights(1025)
    terrain = Terrain.from_heights(heights, spacing=spacing)
    xmin, xmax, ymin, ymax = terrain.extent
    w, h = xmax - xmin, ymax - ymin
    radius = math.sqrt(0.05 * w * h / math.pi)  # each ROI covers 5 % of the terrain, as in issue 4
    def make_items() -> list[Any]:  # fresh ROI objects: their cull is not cached yet
        return [CloseUp(ROI.circle((xmin + fx * w, ymin + fy * h), radius), scale=1.5, offset=(0.0, 0.0, 0.2 * w))
                for fx, fy in [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]]

    layers = {}
    for dev in devices:
        t_cold, _ = timed(lambda d=dev: closeup_layers(terrain, make_items(), device=d), dev, repeat)
        items = make_items()
        t, out = timed(lambda it=items, d=dev: closeup_layers(terrain, it, device=d), dev, repeat)
        layers[dev] = out
        n = sum(len(layer.vertices) for layer in out)
        rows.append([f"close-up layers per frame, 4 ROIs on 1025² ({n:,} vertices)", dev, f"{t * 1e3:,.2f}",
                     f"{t_cold * 1e3:,.1f} (new ROIs: cull)", ""])
        print(rows[-1], flush=True)
    for dev in devices[1:]:
        same = all(np.array_equal(a.faces, b.faces) and np.array_equal(a.vertices, b.vertices)
                   for a, b in zip(layers[devices[0]], layers[dev], strict=True))
        rows.append(["close-up layers", f"{dev} vs {devices[0]}", "", "", "identical" if same else "DIFFERENT"])


BENCHES = {"stepped": bench_stepped, "restep": bench_restep, "globe": bench_globe, "hillshade": bench_hillshade,
           "closeup": bench_closeup}


def markdown(rows: list[list[str]], devices: list[str], args: argparse.Namespace, started: str,
             argv: list[str] | None = None) -> str:
    import warp as wp

    names = {d: wp.get_device(d).name for d in devices}
    lines = [
        f"Measured {started} with `python benchmarks/run_cuda.py {' '.join(sys.argv[1:] if argv is None else argv)}`",
        "",
        f"CPU {cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, NumPy {np.__version__}, "
        f"Warp {wp.__version__}; devices: " + ", ".join(f"`{d}` ({names[d]})" for d in devices)
        + f"; medians of {args.repeat} after a warm-up.",
        "",
        "| pipeline | device | ms | also | check |",
        "|---|---|---:|---:|---|",
    ]
    first: dict[str, float] = {}  # pipeline -> ms on the first device: the other devices' rows get the ratio
    for row in rows:
        if row[1] in devices and row[2]:
            ms = float(row[2].replace(",", ""))
            base = first.setdefault(row[0].split(" (")[0], ms)  # the name without its face count
            if row[1] != devices[0] and not row[4]:
                row[4] = f"{base / ms:,.1f}x faster than `{devices[0]}`"
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", nargs="+", help="Warp devices (default: cpu and every CUDA device)")
    parser.add_argument("--benches", nargs="+", default=list(BENCHES), choices=list(BENCHES))
    parser.add_argument("--repeat", type=repeat_count, default=5)
    parser.add_argument("--output", type=Path, help="also write the markdown table here")
    args = parser.parse_args(argv)

    import warp as wp

    from stepterrain._device import init_warp

    init_warp()  # quietly, as the package does (wp.config.quiet, set here before, is gone from Warp >= 1.12)
    devices = args.devices or ["cpu"] + [str(d) for d in wp.get_cuda_devices()]
    started = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    rows: list[list[str]] = []
    for name in args.benches:
        BENCHES[name](devices, args.repeat, rows)
    text = markdown(rows, devices, args, started, argv)
    print(text)
    if args.output:
        args.output.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
