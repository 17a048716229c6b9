"""The earth on the cube sphere: a far view and a clipped close view, cone frustums against spheres (paper 003,
Abb. 11 and 12).

The embedded ETOPO 2022 relief (20 arc-minutes) is resampled onto 6 x SIZE² nodes and meshed four times, each
view with its own error bound (--far-error, --close-error), cones and spheres with the same one:

1. far view, cone frustums (rendered from the eye);  2. far view, bounding spheres;
3. close view from 400 km above the Ligurian coast (44° N, 9° E), tilted 65° to look north over the Alps, cone
   frustums, clipped to the view and rendered from an overview camera with the triangle edges, so the saving
   outside the view shows;  4. the same, spheres.

Each panel is labelled with its triangle count (the paper reports spheres needing ~1.4x the triangles).

    python examples/globe.py --size 513 --output out/globe.png
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from stepterrain.cli import check_example_outputs, usage_errors
from stepterrain.export import save_image
from stepterrain.globe import EARTH_RADIUS, Globe, elevation_colors, look_from, render_view


def panel(globe: Globe, camera, view_camera, bounds: str, error: float, size: tuple[int, int], edges: bool):
    mesh = globe.mesh(error=error, camera=camera, bounds=bounds)
    heights = globe.heights.reshape(-1)[mesh.metadata["node_entry"]] / globe.exaggeration
    mesh.visual.vertex_colors = elevation_colors(heights)
    image = render_view(mesh, view_camera, window_size=size, show_edges=edges)
    return image, len(mesh.faces)


def label(image: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    draw.rectangle([0, 0, 8 + 7 * len(text), 18], fill=(0, 0, 0))
    draw.text((4, 3), text, fill=(255, 255, 255))
    return np.asarray(picture)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))  # not line 1 only
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda, cuda:0 (default: Warp's)")
    parser.add_argument("--size", type=int, default=513, help="nodes per cube face edge, 2^k+1 (default 513)")
    parser.add_argument("--output", type=Path, default=Path("out/globe.png"), help="PNG to write")
    parser.add_argument("--panel", type=int, nargs=2, default=(640, 400), metavar=("W", "H"),
                        help="size of one panel in pixels (default 640 400)")
    parser.add_argument("--far-error", type=float, default=3000.0,
                        help="far view: error in metres tolerated at the eye's altitude (default 3000)")
    parser.add_argument("--close-error", type=float, default=100.0,
                        help="close view: error in metres tolerated at the eye's altitude (default 100)")
    args = parser.parse_args(argv)
    if not all(8 <= side <= 16384 for side in args.panel):  # 0 0 raised a ZeroDivisionError in the camera's aspect
        parser.error(f"--panel must be W H of 8 to 16384 pixels each; got {' '.join(map(str, args.panel))}")
    # the library's refusals named its own arguments, face_size and error (which of the two errors?)
    # at most 16385: the library's int32 node entries (globe._MAX_CELLS + 1); above it, it named face_size
    if args.size < 3 or (args.size - 1) & (args.size - 2) or args.size > 16385:
        parser.error(f"--size must be 2^k + 1 nodes with k >= 1, at most 16385 (3, 5, 9, ..., 513, 1025); "
                     f"got {args.size}")
    for option, error in (("--far-error", args.far_error), ("--close-error", args.close_error)):
        if not (math.isfinite(error) and error >= 0):
            parser.error(f"{option} must be a finite number >= 0 (metres); got {error}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output})  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    globe = Globe.sample(face_size=args.size, exaggeration=10.0, device=args.device)
    w, h = args.panel
    far = look_from(35.0, 15.0, 3.0 * EARTH_RADIUS, aspect=w / h)
    close = look_from(44.0, 9.0, 400_000.0, tilt=65.0, heading=0.0, aspect=w / h)
    overview = look_from(51.0, 9.0, 2_600_000.0, aspect=w / h)
    rows = []
    for camera, view_camera, edges, error in ((far, far, False, args.far_error),
                                              (close, overview, True, args.close_error)):
        row = []
        for bounds in ("cone", "sphere"):
            image, count = panel(globe, camera, view_camera, bounds, error, (w, h), edges)
            name = "far view" if camera is far else "close view (clipped)"
            row.append(label(image, f"{name}, {bounds}s: {count:,} triangles"))
        rows.append(np.concatenate(row, axis=1))
    save_image(np.concatenate(rows, axis=0), args.output)
    print(f"wrote {args.output} in {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
