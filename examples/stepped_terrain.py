"""Continuous terrain, stepped terrain and a lens, side by side (paper 000, Fig. 1 and Fig. 4).

Three panels of the embedded Big Tujunga DEM (30 m SRTM), cropped and subsampled to about SIZE x SIZE
nodes, each rendered off-screen with the same camera and lighting:

1. γ = 0: the original, continuous surface, colored by level;
2. γ = 1: the fully stepped terrain, terraces at the isovalues joined by vertical walls;
3. a soft circular lens: original terrain inside, steps outside (the focus + context view of §4).

Each panel names itself in its top left corner.

    python examples/stepped_terrain.py --size 256 --output out/stepped_terrain.png
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import stepterrain as st
from stepterrain.cli import add_dem_option, check_example_outputs, example_dem, nice_interval, usage_errors
from stepterrain.render import render_mesh, save_png


def crop_sample(size: int, dem: st.Terrain | None = None) -> st.Terrain:
    """``dem`` (default: the embedded DEM), subsampled and centre-cropped to about ``size`` x ``size`` nodes."""
    dem = st.sample_dem() if dem is None else dem
    rows, cols = dem.shape
    stride = max(1, min(rows, cols) // size)
    n_rows, n_cols = min(size, rows // stride), min(size, cols // stride)
    i0 = (rows - n_rows * stride) // 2
    j0 = (cols - n_cols * stride) // 2
    heights = dem.heights[i0 : i0 + n_rows * stride : stride, j0 : j0 + n_cols * stride : stride]
    dx, dy = dem.spacing
    origin = (dem.origin[0] + j0 * dx, dem.origin[1] + i0 * dy)
    return st.Terrain.from_heights(heights, spacing=(dx * stride, dy * stride), origin=origin, crs=dem.crs,
                                   source=dem.source)


def label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` in its top left corner, black on a white box, in type scaled to the panel (16 px at
    480 px high; none on a panel under 60 px high, where it would hide the terrain). Unlabelled, the three panels
    of docs/stepped_panels.png left the reader to guess which was the lens view and where its lens was."""
    from PIL import Image, ImageDraw, ImageFont

    size = image.shape[0] // 30
    if size < 2:
        return image
    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=size)
    left, top, right, bottom = draw.textbbox((size // 2, size // 3), text, font=font)
    draw.rectangle([0, 0, right + size // 2, bottom + size // 3], fill=(255, 255, 255))
    draw.text((size // 2, size // 3), text, fill=(0, 0, 0), font=font)
    return np.asarray(picture)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda, cuda:0 (default: Warp's)")
    parser.add_argument("--size", type=int, default=256, help="nodes per side of the DEM crop (default 256)")
    add_dem_option(parser)
    parser.add_argument("--output", type=Path, default=Path("out/stepped_terrain.png"), help="PNG to write")
    parser.add_argument("--panel", type=int, nargs=2, default=(640, 480), metavar=("W", "H"),
                        help="size of one panel in pixels (default 640 480)")
    args = parser.parse_args(argv)
    if args.size < 2:  # 0 raised a ZeroDivisionError in the crop; below 2 is no grid
        parser.error(f"--size must be at least 2 nodes; got {args.size}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    terrain = crop_sample(args.size, example_dem(args.dem, args.nodata))
    lo, hi = terrain.height_range
    interval = nice_interval((lo, hi), target=12)
    levels = st.isovalues((lo, hi), interval=interval)
    xmin, xmax, ymin, ymax = terrain.extent
    centre = ((xmin + xmax) / 2, (ymin + ymax) / 2)
    lens = st.circular_lens(terrain, centre, 0.3 * min(xmax - xmin, ymax - ymin))
    # one frame for all panels, so the camera does not move between them
    bounds = [(xmin, ymin, float(levels[0])), (xmax, ymax, float(levels[-1]))]

    panels = []
    lens_name = "lens: continuous within a central circle, stepped outside"
    for name, gamma in (("continuous (gamma 0)", 0.0), ("stepped (gamma 1)", 1.0), (lens_name, lens)):
        start = time.perf_counter()
        mesh = st.stepped(terrain, interval=interval, gamma=gamma, colors="terrain", device=args.device)
        image = render_mesh(mesh, window_size=tuple(args.panel), z_scale=2.0, bounds=bounds)
        panels.append(label(image, name))
        print(f"{name}: {len(mesh.faces):,} faces, {time.perf_counter() - start:.2f} s", file=sys.stderr)
    save_png(np.concatenate(panels, axis=1), args.output)
    print(f"wrote {args.output} ({terrain.shape[0]} x {terrain.shape[1]} nodes, interval {interval:g} m)",
          file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
