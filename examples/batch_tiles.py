"""Batch meshing: the embedded DEM cut into tiles, stepped on a dask LocalCluster, welded back without cracks.

Each tile shares its border nodes and the isovalues with its neighbours, so the tiles' stepped meshes (one
GLB each, written atomically into the output folder, resumable) join seamlessly; the picture renders every
tile's file together, alternate tiles shaded slightly differently so the seams can be found.

    python examples/batch_tiles.py --output out/batch.png              # tiles in out/batch_tiles/
    python examples/batch_tiles.py --size 200 --tile 64 --scheduler serial --output small.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from stepterrain.batch import batch, overview_image
from stepterrain.cli import add_dem_option, check_example_outputs, example_dem, usage_errors
from stepterrain.export import IMAGE_EXTENSIONS, save_image
from stepterrain.terrain import Terrain


def tiles_folder(output: str | Path) -> Path:
    """The folder the tiles go into, beside the picture ``output``: ``out/batch.png`` -> ``out/batch_tiles``."""
    output = Path(output)
    return output.with_name(f"{output.stem}_tiles")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1197,
                        help="keep every (COLS // SIZE)-th DEM node, COLS the DEM's columns (1197 in the embedded "
                             "one): SIZE to 2 x SIZE - 1 nodes across, all COLS from SIZE (COLS + 1) // 2 on "
                             "(default: all 1197 of the embedded DEM)")
    add_dem_option(parser)
    parser.add_argument("--tile", type=int, default=256, help="cells per tile (default 256)")
    parser.add_argument("--interval", type=float, default=None,
                        help="step interval in metres (default: a round one giving about 15 steps over the DEM's "
                             "heights, 100 m for the embedded DEM; a fixed 100 m left a DEM of little relief one "
                             "flat terrace)")
    parser.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    parser.add_argument("--scheduler", default=None, help="'serial', or tcp://host:port (default: a LocalCluster)")
    parser.add_argument("--window", type=int, nargs=2, default=(1600, 900), metavar=("W", "H"))
    parser.add_argument("--output", default="batch.png", help="PNG to write; the tiles go beside it")
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda:0 (default: Warp's)")
    args = parser.parse_args(argv)
    if args.size < 2:  # 0 raised a ZeroDivisionError in the crop; below 2 is no grid
        parser.error(f"--size must be at least 2 nodes; got {args.size}")
    if not all(8 <= side <= 16384 for side in args.window):  # refused by the render, after the tiles were written
        parser.error(f"--window must be W H of 8 to 16384 pixels each; got {' '.join(map(str, args.window))}")
    if Path(args.output).suffix.lower() not in IMAGE_EXTENSIONS:  # found after the tiles were written, beside it
        parser.error(f"--output must end in {', '.join(IMAGE_EXTENSIONS)}, the tiles go beside it; got {args.output!r}")
    tiles = tiles_folder(args.output)
    try:  # a name the system refuses to look up (x_tiles over 255 bytes, x.png not) raised a bare OSError traceback
        in_the_way = tiles.exists() and not tiles.is_dir()
    except OSError as exc:
        parser.error(f"the tiles folder beside --output, {str(tiles)!r}, cannot be made: {exc.strerror or exc}; give "
                     "--output a shorter name")
    if in_the_way:  # batch's refusal named its own argument: "output_dir '...' exists"
        parser.error(f"the tiles folder beside --output, {str(tiles)!r}, exists and is not a folder; move that file "
                     "or give --output another name")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    dem = example_dem(args.dem, args.nodata)
    step = max(1, dem.shape[1] // args.size)
    terrain = Terrain.from_heights(dem.heights[::step, ::step], spacing=(dem.spacing[0] * step, dem.spacing[1] * step),
                                   origin=dem.origin, crs=dem.crs, source=dem.source)  # fmt: skip
    output = Path(args.output)
    tiles = tiles_folder(output)
    # base 0.5: no integer SRTM height sits on a threshold, so no node gets a twin vertex (solids need no such shift)
    report = batch(terrain, tiles, tile_size=args.tile, interval=args.interval, base=0.5, colors="terrain",
                   scheduler=args.scheduler, workers=args.workers, device=args.device,
                   overview_size=tuple(args.window))  # its render checked against the memory budget first
    # fmt: skip
    print(report.summary(), file=sys.stderr)
    if not (report.done or report.skipped):  # every tile failed (listed above): no picture to render, exit 1
        return 1
    save_image(overview_image(report, window_size=tuple(args.window), z_scale=2.0), output)
    return 0 if report.ok else 1


if __name__ == "__main__":
    sys.exit(main())
