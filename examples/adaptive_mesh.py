"""Adaptive RTIN meshes of a local DEM with a true vertical error bound (paper 003's hierarchy in the plane).

The embedded Big Tujunga DEM (30 m SRTM), cropped and subsampled to about SIZE x SIZE nodes, meshed by
``stepterrain.globe.adaptive_mesh`` at three error bounds and rendered side by side with the triangle edges;
each panel names its triangle count and the measured largest vertical error over every grid node, which never
exceeds the bound. The edges are drawn thin and translucent (:func:`render_panel`), so the colours stay readable
and the mesh's density shows as shade: darker where the terrain is rough and the triangles small. An inset in each
panel's lower right corner zooms on the same small square (outlined in red, across a valley floor and its slopes),
where the single triangles show. The PNG is written with a palette of COLORS colours (default 256; ``--colors 0``:
full colour), a third of the full-colour file's size.

    python examples/adaptive_mesh.py --size 512 --output out/adaptive_mesh.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import trimesh

import stepterrain as st
from stepterrain.cli import (
    add_colors_option,
    add_dem_option,
    check_colors_option,
    check_example_outputs,
    example_dem,
    save_example_picture,
    usage_errors,
)
from stepterrain.globe import adaptive_mesh
from stepterrain.render import render_mesh


def crop(size: int, dem: st.Terrain | None = None) -> st.Terrain:
    """``dem`` (default: the embedded DEM), centre-cropped and subsampled to about ``size`` x ``size`` nodes (as
    stored: :func:`adaptive_mesh` takes a north-up DEM's negative dy and north-west origin as they are)."""
    dem = st.sample_dem() if dem is None else dem
    rows, cols = dem.shape
    stride = max(1, min(rows, cols) // size)
    n = min(size, rows // stride, cols // stride)
    i0, j0 = (rows - n * stride) // 2, (cols - n * stride) // 2
    heights = dem.heights[i0 : i0 + n * stride : stride, j0 : j0 + n * stride : stride]
    (dx, dy), (x0, y0) = dem.spacing, dem.origin
    return st.Terrain.from_heights(heights, spacing=(dx * stride, dy * stride), origin=(x0 + j0 * dx, y0 + i0 * dy),
                                   crs=dem.crs, source=dem.source)


def true_error(mesh, terrain: st.Terrain) -> float:
    """The largest |z - mesh(x, y)| over every grid node (linear interpolation on the mesh's triangles).

    Measured in node indices (column, row), where the mesh's vertices, all at grid nodes, are whole numbers: an
    affine map keeps linear interpolation as it is. In metres, a last row or column a rounding beyond the mesh's
    outer vertices (j * dx against x0 + j * dx - x0: 64 nodes of a 3" DEM's local metres) was outside every
    triangle, masked, and the panel read "max nan m"."""
    import matplotlib.tri as mtri

    (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
    v = np.asarray(mesh.vertices, dtype=np.float64)
    col, row = np.round((v[:, 0] - x0) / dx), np.round((v[:, 1] - y0) / dy)
    interp = mtri.LinearTriInterpolator(mtri.Triangulation(col, row, np.asarray(mesh.faces)), v[:, 2])
    i, j = np.mgrid[0 : terrain.shape[0], 0 : terrain.shape[1]]
    z = interp(j.astype(np.float64), i.astype(np.float64))
    if np.ma.is_masked(z):  # a node outside every triangle: no error to measure there, not a NaN to print
        raise AssertionError(f"{np.ma.count_masked(z)} grid nodes lie outside the mesh")
    return float(np.abs(np.ma.getdata(z) - terrain.heights).max())


def label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` in its top left corner, black on a white box, in type scaled to the panel: 16 px at
    400 px high, 11 px at least. Pillow's fixed 11 px bitmap font, in a box sized at 6 px a character, read small
    beside a 480 x 400 panel in docs/adaptive_mesh.png."""
    from PIL import Image, ImageDraw, ImageFont

    size = max(11, image.shape[0] // 25)
    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=size)
    origin = (4, 1)
    right, bottom = draw.textbbox(origin, text, font=font)[2:]
    draw.rectangle([0, 0, right + 4, bottom + 2], fill=(255, 255, 255))
    draw.text(origin, text, fill=(0, 0, 0), font=font)
    return np.asarray(picture)


def render_panel(mesh, size: tuple[int, int], *, bounds: np.ndarray | None = None, supersample: int = 2,
                 edge_opacity: float = 0.6) -> np.ndarray:
    """``mesh`` coloured by height with its triangle edges thin and translucent, as a ``size`` (width, height) image.

    Black one-pixel edges at the panel's size buried the 10 m panel and blacked out the 2.5 m one (more triangles than
    pixels). Rendered ``supersample`` times larger with and without edges, blended at ``edge_opacity`` and averaged
    back down, each edge is a fraction of a pixel, half-tone: where the triangles are smaller than a pixel the surface
    only darkens with their density, and the height colours show through everywhere. ``bounds``: the box to frame
    (render_mesh's), default the mesh's own."""
    factor = max(1, min(supersample, 16384 // max(size)))  # render_mesh's largest window
    window = (size[0] * factor, size[1] * factor)
    plain, edged = (render_mesh(mesh, window_size=window, z_scale=1.5, scalars="height", show_edges=edges,
                                bounds=bounds) for edges in (False, True))
    blend = (1.0 - edge_opacity) * plain.astype(np.float32) + edge_opacity * edged.astype(np.float32)
    blend = blend.reshape(size[1], factor, size[0], factor, 3).mean(axis=(1, 3))
    return np.round(blend).astype(np.uint8)


#: the zoomed square: centre and side as fractions of the crop's extent (x east, y north from its south-west corner)
ZOOM_CENTRE, ZOOM_SIDE = (0.3, 0.3), 0.06


def zoom_box(terrain: st.Terrain) -> tuple[np.ndarray, trimesh.Trimesh | None]:
    """The zoomed square's (2, 2) [min, max] box in x, y and a mesh of the crop's grid inside it (for its outline),
    None where the square holds under two nodes a side."""
    rows, cols = terrain.shape
    (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
    x, y = x0 + dx * np.arange(cols), y0 + dy * np.arange(rows)
    lo, hi = np.array([min(x[0], x[-1]), min(y[0], y[-1])]), np.array([max(x[0], x[-1]), max(y[0], y[-1])])
    centre, half = lo + (hi - lo) * ZOOM_CENTRE, (hi - lo) * ZOOM_SIDE / 2
    box = np.array([centre - half, centre + half])
    j = np.flatnonzero((x >= box[0, 0]) & (x <= box[1, 0]))
    i = np.flatnonzero((y >= box[0, 1]) & (y <= box[1, 1]))
    if len(i) < 2 or len(j) < 2:  # a crop too small for a zoom
        return box, None
    gx, gy = np.meshgrid(x[j], y[i])
    vertices = np.column_stack([gx.ravel(), gy.ravel(), terrain.heights[np.ix_(i, j)].ravel()])
    k = np.arange(len(vertices)).reshape(len(i), len(j))[:-1, :-1].ravel()
    n = len(j)
    faces = np.concatenate([np.column_stack([k, k + 1, k + n + 1]), np.column_stack([k, k + n + 1, k + n])])
    return box, trimesh.Trimesh(vertices, faces, process=False)


def add_zoom(image: np.ndarray, mesh, box: np.ndarray, grid: trimesh.Trimesh | None) -> np.ndarray:
    """``image`` (``mesh``'s panel) with ``box`` outlined in red and zoomed in an inset in its lower right corner (not
    in a panel under 43 pixels a side)."""
    if grid is None:
        return image
    height, width = image.shape[:2]
    whole = np.array([mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)])
    inside = render_mesh(grid, window_size=(width, height), z_scale=1.5, bounds=whole).min(axis=2) < 250
    ring = inside & ~(np.roll(inside, 1, 0) & np.roll(inside, -1, 0) & np.roll(inside, 1, 1) & np.roll(inside, -1, 1))
    ring |= np.roll(ring, 1, 0) | np.roll(ring, 1, 1)  # two pixels wide
    out = image.copy()
    out[ring] = (220, 0, 0)
    w, h = (width * 3) // 8, (height * 3) // 8
    if min(w, h) < 16:  # a tiny panel: no room for an inset
        return out
    z = grid.vertices[:, 2]
    inset = render_panel(mesh, (w - 2, h - 2), bounds=np.column_stack([box, [z.min(), z.max()]]))
    out[height - h :, width - w :] = (220, 0, 0)
    out[height - h + 1 : height - 1, width - w + 1 : width - 1] = inset
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda, cuda:0 (default: Warp's)")
    parser.add_argument("--size", type=int, default=512, help="nodes per side of the DEM crop (default 512)")
    add_dem_option(parser)
    parser.add_argument("--errors", type=float, nargs="+", default=(40.0, 10.0, 2.5), help="bounds in metres")
    parser.add_argument("--output", type=Path, default=Path("out/adaptive_mesh.png"), help="PNG to write")
    parser.add_argument("--panel", type=int, nargs=2, default=(480, 400), metavar=("W", "H"),
                        help="size of one panel in pixels (default 480 400)")
    add_colors_option(parser)
    args = parser.parse_args(argv)
    check_colors_option(parser, args.colors, args.output)
    if args.size < 2:  # 0 raised a ZeroDivisionError in the crop; below 2 is no grid
        parser.error(f"--size must be at least 2 nodes; got {args.size}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    terrain = crop(args.size, example_dem(args.dem, args.nodata))
    panels = []
    box, grid = zoom_box(terrain)
    for error in args.errors:
        mesh = adaptive_mesh(terrain, error=error, device=args.device)
        worst = true_error(mesh, terrain)
        image = add_zoom(render_panel(mesh, tuple(args.panel)), mesh, box, grid)
        panels.append(label(image, f"error <= {error:g} m: {len(mesh.faces):,} triangles, max {worst:.2f} m"))
    save_example_picture(np.concatenate(panels, axis=1), args.output, args.colors)
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
