"""Topographic and thematic texture layers draped on the stepped terrain (paper 004, Fig. 3 and Fig. 5).

The embedded Big Tujunga DEM (30 m SRTM), cropped and subsampled to about SIZE x SIZE nodes:

1. a topographic layer: Horn hillshade (light from the north-west at 30 degrees) with self-shadowing by the
   full-resolution terrain and a touch of horizon-based ambient occlusion (§7);
2. a hypsometric thematic layer (colours by height), modulated by the topographic layer (Fig. 5);
3. a thematic lens: a circular visibility layer blends in a second thematic layer (slope classes) around a
   hot spot (§5, Fig. 3 right), and a highlight lens brightens it (Fig. 3 centre);
4. contour lines laid over it all, unshaded as a map prints them: every other isovalue of the steps (the
   middle of every other terrace: every 200 m on the default crop, stepped every 100 m), an index line every fifth;
5. the composite draped on the stepped terrain (paper 000) and rendered off-screen.

Left panel: the composite texture seen from above; right panel: the draped stepped terrain; each names itself in its
top left corner (a panel 240 px high or more). The PNG is written with
a palette of COLORS colours (default 256, octree quantisation): a third of the full-colour file's size,
and the hillshade and the lens's slope colours read the same; ``--colors 0`` writes it in full colour.

    python examples/textures.py --size 256 --output out/textures.png
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import matplotlib
import numpy as np

import stepterrain as st
from stepterrain.cli import (
    add_colors_option,
    add_dem_option,
    check_colors_option,
    check_example_outputs,
    example_dem,
    nice_interval,
    save_example_picture,
    usage_errors,
)
from stepterrain.render import render_textured_mesh
from stepterrain.texture import (
    Pipeline,
    contour_layer,
    drape,
    highlight_lens,
    terrain_layer,
    thematic_lens,
    topographic_layer,
)


def crop_sample(size: int, dem: st.Terrain | None = None) -> st.Terrain:
    """``dem`` (default: the embedded DEM), subsampled and centre-cropped to about ``size`` x ``size`` nodes."""
    dem = st.sample_dem() if dem is None else dem
    rows, cols = dem.shape
    stride = max(1, min(rows, cols) // size)
    n_rows, n_cols = min(size, rows // stride), min(size, cols // stride)
    i0, j0 = (rows - n_rows * stride) // 2, (cols - n_cols * stride) // 2
    heights = dem.heights[i0: i0 + n_rows * stride: stride, j0: j0 + n_cols * stride: stride]
    dx, dy = dem.spacing
    return st.Terrain.from_heights(heights, spacing=(dx * stride, dy * stride),
                                   origin=(dem.origin[0] + j0 * dx, dem.origin[1] + i0 * dy), crs=dem.crs,
                                   source=dem.source)


def colour_layers(terrain: st.Terrain) -> tuple[np.ndarray, np.ndarray]:
    """(hypsometric RGBA by height, slope classes RGBA) per node, float32 in [0, 1]: opaque, but transparent at nodata
    (the colormaps' colour for NaN; its RGB alone, black, drew a --dem file's voids as black ground in the texture
    panel) and, for the slopes, beside it (no gradient there; the hypsometric colour shows through)."""
    h = terrain.heights
    lo, hi = terrain.height_range
    hyps = matplotlib.colormaps["terrain"](0.25 + 0.75 * (h - lo) / max(hi - lo, 1e-9))
    gy, gx = np.gradient(h, abs(terrain.spacing[1]), abs(terrain.spacing[0]))
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    classes = matplotlib.colormaps["magma_r"](np.clip(slope / 45.0, 0, 1))
    return hyps.astype(np.float32), classes.astype(np.float32)


def label_band(height: int) -> int:
    """Rows along the top of a panel ``height`` px high that :func:`label`'s box takes (0: no label)."""
    return 0 if height < 240 else 2 * (height // 30)


def label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` in its top left corner, black on a white box, in type scaled to the panel (20 px at
    600 px high); none on a panel under 240 px high, where the type would be too small to read. Unlabelled, the two
    panels of docs/texture.png did not say that the left one is the texture itself, seen from above."""
    if not label_band(image.shape[0]):
        return image
    from PIL import Image, ImageDraw, ImageFont

    size = image.shape[0] // 30
    picture = Image.fromarray(np.ascontiguousarray(image[..., :3]))
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=size)
    origin = (size // 2, size // 3)
    right, bottom = draw.textbbox(origin, text, font=font)[2:]
    draw.rectangle([0, 0, right + size // 2, bottom + size // 3], fill=(255, 255, 255))
    draw.text(origin, text, fill=(0, 0, 0), font=font)
    return np.asarray(picture)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda, cuda:0 (default: Warp's)")
    parser.add_argument("--size", type=int, default=256, help="nodes per side of the DEM crop (default 256)")
    add_dem_option(parser)
    parser.add_argument("--output", type=Path, default=Path("out/textures.png"), help="PNG to write")
    parser.add_argument("--panel", type=int, nargs=2, default=(800, 600), metavar=("W", "H"),
                        help="size of one panel in pixels (default 800 600)")
    add_colors_option(parser)
    args = parser.parse_args(argv)
    check_colors_option(parser, args.colors, args.output)
    if args.size < 2:  # 0 raised a ZeroDivisionError in the crop; below 2 is no grid
        parser.error(f"--size must be at least 2 nodes; got {args.size}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    terrain = crop_sample(args.size, example_dem(args.dem, args.nodata))
    topo = topographic_layer(terrain, azimuth=math.radians(315), altitude=math.radians(30), shadows=True,
                             shadow_strength=0.5, occlusion=0.25, device=args.device)
    hyps, slopes = colour_layers(terrain)
    xmin, xmax, ymin, ymax = terrain.extent
    centre = (xmin + 0.62 * (xmax - xmin), ymin + 0.45 * (ymax - ymin))
    radius = 0.22 * min(xmax - xmin, ymax - ymin)
    interval = nice_interval(terrain.height_range, target=12)
    composite = (
        Pipeline()
        .blend(terrain_layer(terrain, slopes), thematic_lens(centre, radius))   # §5 thematic lens
        .modulate(topo)                                                          # §7 topographic layer
        .modulate(highlight_lens(centre, radius * 1.15, strength=0.2))         # §5 highlight lens
        .blend(contour_layer(terrain, interval=2 * interval, device=args.device))  # contour lines
        .apply(terrain_layer(terrain, hyps), device=args.device)
    )
    print(f"layers: {time.perf_counter() - start:.2f} s", file=sys.stderr)

    mesh = drape(st.stepped(terrain, interval=interval, device=args.device), composite)
    width, height = args.panel
    top = np.asarray(composite.to_uint8(background=(1, 1, 1)))
    # the texture panel: the composite letterboxed into the panel, north up, in the terrain's proportions (its
    # texels drawn as squares squashed a DEM of cells taller than wide, a 3" one's, north-south)
    from PIL import Image

    picture = Image.fromarray(top)
    band = label_band(height)  # the label's strip along the top: the texture below it, none of it covered
    room = max(1, height - band)
    extent_x, extent_y = xmax - xmin, ymax - ymin
    if extent_x > 0 and extent_y > 0:
        scale = min(width / extent_x, room / extent_y)
        size = (round(extent_x * scale), round(extent_y * scale))
    else:  # a DEM of one row or column of nodes: no proportions to keep
        scale = min(width / picture.width, room / picture.height)
        size = (int(picture.width * scale), int(picture.height * scale))
    picture = picture.resize((min(width, max(1, size[0])), min(room, max(1, size[1]))), Image.Resampling.LANCZOS)
    panel = np.full((height, width, 3), 255, np.uint8)
    y0, x0 = band + (room - picture.height) // 2, (width - picture.width) // 2
    panel[y0: y0 + picture.height, x0: x0 + picture.width] = np.asarray(picture)
    # relief: the terraces and walls lit, a level face in the texture's own colour (lit fully, its hillshade was shaded
    # twice: the draped view darker than the texture beside it)
    view = render_textured_mesh(mesh, window_size=(width, height), z_scale=1.5, lighting="relief")
    panel = label(panel, "the texture from above, north up")
    view = label(view, f"draped on the terrain stepped every {interval:g} m")
    save_example_picture(np.concatenate([panel, view], axis=1), args.output, args.colors)
    print(f"wrote {args.output} ({terrain.shape[0]} x {terrain.shape[1]} nodes, {len(mesh.faces):,} faces, "
          f"{time.perf_counter() - start:.2f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
