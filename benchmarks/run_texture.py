"""Side-by-side benchmark of stepterrain's texture kernels against what a user would run instead (issue 5 §7).

1. Topographic texture on an N² DEM (the real Big Tujunga SRTM DEM mirror-tiled to N², 30 m spacing):
   ``stepterrain.texture.hillshade`` (Warp) alone and with sweep-line self-shadowing, against
   ``gdaldem hillshade`` (GDAL, no shadows: it has none) on the same DEM as a GeoTIFF, and a vectorised NumPy
   Horn hillshade. Shadow rays per second = pixels / shadow time (one ray from every pixel to the light).
2. Image pyramid of a W x H RGB image stored as a memory-mapped .npy: ``ImagePyramid.build`` (Warp,
   area-weighted, memory-mapped levels) against Pillow (``Image.reduce(2)`` repeated, the image in RAM).
   Time and peak memory, each in a fresh subprocess (peak = rise of VmHWM over the resident set before).
3. Contour lines on an N² DEM (``--cases contours``, not run by default; ``--contour-size``, ``--contour-interval``):
   ``stepterrain.texture.contour_layer`` (Warp, one texel per node, an index line every 5th) against what a user
   would do instead: matplotlib's ``contour`` on the same grid, drawn with Agg into an image of the same size
   (lines one pixel wide, index lines two), both measured in the same run.

Everything is pinned to one CPU core (``sched_setaffinity``; gdaldem with ``taskset``) unless ``--all-cores``;
times are the best of ``--repeat`` runs.

    python benchmarks/run_texture.py --dem-size 4096 --image 16384 8192 --repeat 3 --output /tmp/texture.md
    python benchmarks/run_texture.py --cases contours --contour-size 2048 --repeat 3
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
from machine import cpu_model, repeat_count  # noqa: E402  (benchmarks/ is the script folder)

_HERE = Path(__file__).resolve().parent
if str(_HERE.parent) not in sys.path:
    sys.path.insert(0, str(_HERE.parent))

HILLSHADE_GOAL = 1.0   # ours with shadows / gdaldem without: goal <= 1 (no slower)
PYRAMID_SECONDS_GOAL = 5.0
PYRAMID_PEAK_GOAL = 1024**3
CONTOUR_INDEX_EVERY = 5  # both contenders draw every 5th line as an index line, twice as wide


def find_dem() -> Path:
    """The real DEM: in ``STEPTERRAIN_SHARED_DATA`` first (as the other run_*.py scripts and the tests look), else in
    a ``shared/data`` above benchmarks/ (a worktree's is further up)."""
    name = "big_tujunga_srtm_30m_utm11n.npz"
    env = os.environ.get("STEPTERRAIN_SHARED_DATA")
    folders = ([Path(env)] if env else []) + [parent / "shared" / "data" for parent in [_HERE, *_HERE.parents]]
    for folder in folders:
        if (folder / name).exists():
            return folder / name
    sys.exit(f"{name} not found in $STEPTERRAIN_SHARED_DATA ({env or 'unset'}) nor in a shared/data above benchmarks/")


def tiled_dem(size: int) -> np.ndarray:
    with np.load(find_dem()) as data:
        z = np.asarray(data["elevation"], dtype=np.float32)
    reps = (-(-size // z.shape[0]) + 1, -(-size // z.shape[1]) + 1)
    mirrored = np.block([[z, z[:, ::-1]], [z[::-1], z[::-1, ::-1]]])
    tiled = np.tile(mirrored, (reps[0] // 2 + 1, reps[1] // 2 + 1))
    return np.ascontiguousarray(tiled[:size, :size])


def best(fn, repeat: int) -> float:
    """Best CPU time (user + system, this process and its finished children) of ``repeat`` runs.

    CPU time rather than wall time: the machine is shared, and a pinned process that waits for its core
    accumulates wall time but not CPU time. The wall times go to ``WALL`` for the report.
    """
    import resource

    times, walls = [], []
    for _ in range(repeat):
        usage = resource.getrusage(resource.RUSAGE_SELF)
        child = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - start)
        usage2 = resource.getrusage(resource.RUSAGE_SELF)
        child2 = resource.getrusage(resource.RUSAGE_CHILDREN)
        times.append((usage2.ru_utime - usage.ru_utime) + (usage2.ru_stime - usage.ru_stime)
                     + (child2.ru_utime - child.ru_utime) + (child2.ru_stime - child.ru_stime))
    WALL.append(min(walls))
    return min(times)


WALL: list[float] = []


def numpy_hillshade(z: np.ndarray, dx: float, dy: float, azimuth: float, altitude: float) -> np.ndarray:
    """What a NumPy user writes: Horn gradients by slicing a padded array, Lambert shading."""
    p = np.pad(z, 1, mode="edge")
    a, b, c = p[:-2, :-2], p[:-2, 1:-1], p[:-2, 2:]
    d, f = p[1:-1, :-2], p[1:-1, 2:]
    g, h, k = p[2:, :-2], p[2:, 1:-1], p[2:, 2:]
    gx = ((c + 2 * f + k) - (a + 2 * d + g)) / (8 * dx)
    gy = ((g + 2 * h + k) - (a + 2 * b + c)) / (8 * dy)
    lx, ly, lz = np.sin(azimuth) * np.cos(altitude), np.cos(azimuth) * np.cos(altitude), np.sin(altitude)
    return np.maximum((-gx * lx - gy * ly + lz) / np.sqrt(1 + gx * gx + gy * gy), 0)


def bench_hillshade(size: int, repeat: int, pin: list[str]) -> dict:
    import stepterrain.texture as tx

    z = tiled_dem(size)
    spacing = (30.0, -30.0)
    az, alt = np.radians(315.0), np.radians(45.0)
    tx.hillshade(z[:64, :64], spacing=spacing, shadows=True, device="cpu")  # compile / load
    out = {"size": size, "pixels": z.size}
    out["warp_hillshade"] = best(lambda: tx.hillshade(z, spacing=spacing, device="cpu"), repeat)
    out["warp_shadows_only"] = best(lambda: tx.cast_shadows(z, spacing=spacing, device="cpu"), repeat)
    out["warp_hillshade_shadows"] = best(lambda: tx.hillshade(z, spacing=spacing, shadows=True, device="cpu"), repeat)
    out["numpy_hillshade"] = best(lambda: numpy_hillshade(z, *spacing, az, alt), repeat)
    out["rays_per_s"] = z.size / out["warp_shadows_only"]
    out["walls"] = dict(zip(["warp_hillshade", "warp_shadows_only", "warp_hillshade_shadows", "numpy_hillshade"],
                            WALL[-4:], strict=True))
    gdaldem = shutil.which("gdaldem")
    if gdaldem:
        import rasterio
        from rasterio.transform import from_origin

        folder = Path(tempfile.mkdtemp(prefix="texture-bench-"))
        tif = folder / "dem.tif"
        with rasterio.open(tif, "w", driver="GTiff", width=size, height=size, count=1, dtype="float32",
                           crs="EPSG:32611", transform=from_origin(376313.66, 3807917.83, 30.0, 30.0)) as f:
            f.write(z, 1)
        command = [*pin, gdaldem, "hillshade", "-q", "-compute_edges", str(tif), str(folder / "hs.tif")]
        out["gdaldem_hillshade"] = best(lambda: subprocess.run(command, check=True), repeat)
        out["walls"]["gdaldem_hillshade"] = WALL[-1]
        shutil.rmtree(folder, ignore_errors=True)
    return out


def matplotlib_contours(z: np.ndarray, levels: np.ndarray, index: np.ndarray) -> np.ndarray:
    """What a matplotlib user does for contour lines over a texture: ``contour`` on the grid (north-up, one pixel a
    node), rasterised by Agg into an RGBA image of the grid's size; lines 1 pixel wide (0.72 pt at 100 dpi), index
    lines 2."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    import stepterrain.texture as tx

    rows, cols = z.shape
    fig = Figure(figsize=(cols / 100, rows / 100), dpi=100, facecolor="none")  # transparent between lines
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    ax.set_axis_off()
    ax.contour(z, levels=levels, colors=[tx.CONTOUR_COLOR], linewidths=np.where(index, 1.44, 0.72))
    ax.set_xlim(-0.5, cols - 0.5)  # node (i, j) at pixel (i, j): row 0 at the top, as the layer's north-up
    ax.set_ylim(rows - 0.5, -0.5)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())


def bench_contours(size: int, interval: float, repeat: int) -> dict:
    """contour_layer against matplotlib's contour + Agg on the same N² grid, one texel (pixel) a node."""
    import stepterrain.texture as tx

    z = tiled_dem(size)
    spacing = (30.0, -30.0)
    lo, hi = float(np.nanmin(z)), float(np.nanmax(z))
    k = np.arange(np.floor(lo / interval), np.ceil(hi / interval) + 1)
    levels, index = k * interval, k % CONTOUR_INDEX_EVERY == 0
    tx.contour_layer(z[:64, :64], interval=interval, spacing=spacing, device="cpu")  # compile / load
    matplotlib_contours(z[:64, :64], levels, index)  # import matplotlib
    out = {"size": size, "pixels": z.size, "interval": interval, "levels": int(levels.size)}
    layer = None

    def warp() -> None:
        nonlocal layer
        layer = tx.contour_layer(z, interval=interval, index_every=CONTOUR_INDEX_EVERY, spacing=spacing, device="cpu")

    image = None

    def mpl() -> None:
        nonlocal image
        image = matplotlib_contours(z, levels, index)

    out["warp_contours"] = best(warp, repeat)
    out["matplotlib_contours"] = best(mpl, repeat)
    out["walls"] = dict(zip(["warp_contours", "matplotlib_contours"], WALL[-2:], strict=True))
    assert layer is not None and image is not None and image.shape[:2] == layer.shape
    lines, drawn = layer.image[..., 3] > 0.5, image[..., 3] > 127  # the two images' line texels, side by side
    out["line_fraction"] = {"warp_contours": float(lines.mean()), "matplotlib_contours": float(drawn.mean())}
    near = np.pad(lines, 1)  # the layer's line texels and their 8 neighbours
    near = np.logical_or.reduce([near[1 + di: near.shape[0] - 1 + di, 1 + dj: near.shape[1] - 1 + dj]
                                 for di in (-1, 0, 1) for dj in (-1, 0, 1)])
    out["matplotlib_near"] = float((drawn & near).sum() / max(int(drawn.sum()), 1))
    return out


_PEAK = textwrap.dedent("""
    import os, sys, time, json
    import numpy as np
    if {pin}:
        os.sched_setaffinity(0, {{0}})
    def status(key):
        for line in open("/proc/self/status"):
            if line.startswith(key):
                return int(line.split()[1]) * 1024
    contender, path = sys.argv[1], sys.argv[2]
    if contender == "warp":
        from stepterrain.texture_lod import ImagePyramid
        ImagePyramid.build(np.zeros((8, 8, 3), np.uint8), device="cpu").close()
    else:
        from PIL import Image
    open("/proc/self/clear_refs", "w").write("5")
    before = status("VmRSS")
    start = time.perf_counter()
    cpu = time.process_time()
    if contender == "warp":
        pyramid = ImagePyramid.build(path, device="cpu")
        levels = len(pyramid.levels)
        pyramid.close()
    else:
        image = Image.fromarray(np.load(path))
        levels = 1
        while image.size != (1, 1):
            image = image.reduce((2 if image.size[0] > 1 else 1, 2 if image.size[1] > 1 else 1))
            levels += 1
    seconds = time.perf_counter() - start
    cpu = time.process_time() - cpu
    print(json.dumps({{"seconds": seconds, "cpu": cpu, "peak": status("VmHWM") - before, "levels": levels}}))
""")


def bench_pyramid(width: int, height: int, repeat: int, pin: bool) -> dict:
    import json

    folder = Path(tempfile.mkdtemp(prefix="texture-pyramid-"))
    path = folder / "image.npy"
    image = np.lib.format.open_memmap(path, mode="w+", dtype=np.uint8, shape=(height, width, 3))
    rng = np.random.default_rng(0)
    block = rng.integers(0, 256, (256, width, 3), dtype=np.uint8)
    for r in range(0, height, 256):  # fill in bands (a few dozen), never per pixel
        image[r: r + 256] = block[: min(256, height - r)]
    image.flush()
    del image
    out = {"width": width, "height": height, "bytes": width * height * 3}
    script = _PEAK.format(pin=pin)
    for contender in ("warp", "pillow"):
        runs = []
        for _ in range(repeat):
            result = subprocess.run([sys.executable, "-c", script, contender, str(path)], capture_output=True,
                                    text=True, check=True)
            runs.append(json.loads(result.stdout.strip().splitlines()[-1]))
        out[contender] = min(runs, key=lambda r: r["cpu"])
        out[contender]["seconds"] = min(r["seconds"] for r in runs)
        out[contender]["peak_max"] = max(r["peak"] for r in runs)
    shutil.rmtree(folder, ignore_errors=True)
    return out


def machine() -> str:
    model = cpu_model()
    load = os.getloadavg()
    import warp

    return (f"{model}, {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at start "
            f"(other engineers share the machine), Python {platform.python_version()}, numpy {np.__version__}, "
            f"warp-lang {warp.__version__}")


def report(hs: dict | None, pyr: dict | None, args: argparse.Namespace, contours: dict | None = None,
           argv: list[str] | None = None) -> str:
    lines = [f"## Textures (issue 5 §7) — {_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M} UTC", "",
             f"Command: `python benchmarks/run_texture.py {' '.join(sys.argv[1:] if argv is None else argv)}`", "",
             f"- **Machine**: {machine()}. "
             + ("Pinned to one core (sched_setaffinity; gdaldem under `taskset -c 0`)." if not args.all_cores
                else "All cores."),
             f"- Best of {args.repeat} runs each. CPU time = user + system (gdaldem's as a child process, start-up "
             "and GeoTIFF writing included); wall time beside it (it includes waiting for the shared core). "
             "Pyramids: a fresh process per run.",
             ""]
    goals: list[str] = []
    if hs is not None:
        lines += _hillshade_report(hs, goals)
    if pyr is not None:
        lines += _pyramid_report(pyr, goals)
    if contours is not None:
        lines += _contour_report(contours)
    if goals:
        lines += ["| goal | measured | met? |", "|---|---|---|", *goals]
    return "\n".join(lines).rstrip("\n") + "\n"


def _hillshade_report(hs: dict, goals: list[str]) -> list[str]:
    n = hs["size"]
    lines = [f"### Hillshade on a {n}² DEM (Big Tujunga SRTM 30 m, mirror-tiled), CPU", "",
             "| contender | CPU time (s) | vs gdaldem | wall time (s) |", "|---|---|---|---|"]
    gd = hs.get("gdaldem_hillshade")
    for key, name in (("warp_hillshade", "Warp hillshade"), ("warp_shadows_only", "Warp shadows only (sweep)"),
                      ("warp_hillshade_shadows", "**Warp hillshade + shadows**"),
                      ("numpy_hillshade", "NumPy Horn hillshade"),
                      ("gdaldem_hillshade", "gdaldem hillshade (no shadows)")):
        if key in hs:
            ratio = f"{hs[key] / gd:.2f}×" if gd else "n/a"
            lines.append(f"| {name} | {hs[key]:.3f} | {ratio} | {hs['walls'][key]:.3f} |")
    lines += ["", f"Shadow rays: {hs['rays_per_s'] / 1e6:.1f} M rays/s (one ray per pixel, O(1) each by the sweep).",
              ""]
    if gd:
        ratio = hs["warp_hillshade_shadows"] / gd
        goals.append(f"| hillshade + shadows no slower than gdaldem hillshade (one core, {n}², CPU time) | "
                     f"{hs['warp_hillshade_shadows']:.3f} s vs {gd:.3f} s = {ratio:.2f}× | "
                     f"{'met' if ratio <= HILLSHADE_GOAL + 0.005 else 'not met'} |")
    return lines


def _pyramid_report(pyr: dict, goals: list[str]) -> list[str]:
    w, h = pyr["width"], pyr["height"]
    lines = [f"### Pyramid of a {w} × {h} RGB image ({pyr['bytes'] / 1e6:.0f} MB, memory-mapped .npy)", "",
             "| contender | CPU time (s) | wall time (s) | peak memory rise (MB) | levels |", "|---|---|---|---|---|"]
    for key, name in (("warp", "Warp ImagePyramid.build"), ("pillow", "Pillow Image.reduce(2) chain (in RAM)")):
        r = pyr[key]
        lines.append(f"| {name} | {r['cpu']:.2f} | {r['seconds']:.2f} | {r['peak'] / 1e6:.0f} | {r['levels']} |")
    lines.append("")
    r = pyr["warp"]
    goals.append(f"| pyramid {w}×{h} RGB under 5 s | CPU {r['cpu']:.2f} s, wall {r['seconds']:.2f} s (best) | "
                 f"{'met' if r['cpu'] < PYRAMID_SECONDS_GOAL else 'not met'} (CPU time); "
                 f"{'met' if r['seconds'] < PYRAMID_SECONDS_GOAL else 'not met'} (wall) |")
    goals.append(f"| pyramid peak memory under 1 GB | {r['peak_max'] / 1e6:.0f} MB (worst run) | "
                 f"{'met' if r['peak_max'] < PYRAMID_PEAK_GOAL else 'not met'} |")
    return lines


def _contour_report(c: dict) -> list[str]:
    n, mpl = c["size"], c["matplotlib_contours"]
    lines = [f"### Contour lines on a {n}² DEM (Big Tujunga SRTM 30 m, mirror-tiled), every {c['interval']:g} m "
             f"({c['levels']} levels, every {CONTOUR_INDEX_EVERY}th an index line), one texel a node, CPU", "",
             "| contender | CPU time (s) | vs matplotlib | wall time (s) | ns a texel (CPU) | line texels |",
             "|---|---|---|---|---|---|"]
    for key, name in (("warp_contours", "**Warp contour_layer** (float32 RGBA)"),
                      ("matplotlib_contours", "matplotlib contour + Agg (RGBA image of the same size)")):
        lines.append(f"| {name} | {c[key]:.3f} | {c[key] / mpl:.2f}× | {c['walls'][key]:.3f} | "
                     f"{c[key] / c['pixels'] * 1e9:.1f} | {c['line_fraction'][key]:.1%} |")
    lines += ["", "Line texels: the share of texels with alpha over one half (the two draw different widths; a "
                  f"sanity check, not a quality measure); {c['matplotlib_near']:.1%} of matplotlib's line pixels lie "
                  "within a texel of the layer's.", ""]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dem-size", type=int, default=4096)
    parser.add_argument("--image", type=int, nargs=2, default=(16384, 8192), metavar=("W", "H"))
    parser.add_argument("--repeat", type=repeat_count, default=3)
    parser.add_argument("--all-cores", action="store_true")
    parser.add_argument("--output", type=Path)
    parser.add_argument("--cases", nargs="+", choices=("hillshade", "pyramid", "contours"),
                        default=["hillshade", "pyramid"],
                        help="which benchmarks to run (default: hillshade pyramid; contours is opt-in)")
    parser.add_argument("--contour-size", type=int, default=2048, metavar="N",
                        help="contours: the DEM's N² (default 2048)")
    parser.add_argument("--contour-interval", type=float, default=50.0, metavar="M",
                        help="contours: the contour interval in metres (default 50)")
    args = parser.parse_args(argv)
    pin_cmd: list[str] = []
    if not args.all_cores:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
        if shutil.which("taskset"):
            pin_cmd = ["taskset", "-c", str(sorted(os.sched_getaffinity(0))[0])]
    hs = bench_hillshade(args.dem_size, args.repeat, pin_cmd) if "hillshade" in args.cases else None
    pyr = bench_pyramid(args.image[0], args.image[1], args.repeat, not args.all_cores) \
        if "pyramid" in args.cases else None
    contours = bench_contours(args.contour_size, args.contour_interval, args.repeat) \
        if "contours" in args.cases else None
    text = report(hs, pyr, args, contours, argv)
    print(text)
    if args.output:
        args.output.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
