"""The earth on the cube sphere: a far view and a clipped close view, cone frustums against spheres (paper 003,
Abb. 11 and 12).

The embedded ETOPO 2022 relief (20 arc-minutes) is resampled onto 6 x SIZE² nodes and meshed four times, each
view with its own error bound (--far-error, --close-error), cones and spheres with the same one:

1. far view, cone frustums (rendered from the eye);  2. far view, bounding spheres;
3. close view from 400 km above the Ligurian coast (44° N, 9° E), tilted 65° to look north over the Alps, cone
   frustums, clipped to the view (from 48° N to the horizon beyond the pole) and rendered with the triangle edges
   from an overview camera that frames it whole (the part under the eye at the bottom), so the saving outside the
   view shows;  4. the same, spheres.

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
from stepterrain.globe import EARTH_RADIUS, Camera, Globe, elevation_colors, look_from, render_view


def coloured_mesh(globe: Globe, camera, bounds: str, error: float):
    mesh = globe.mesh(error=error, camera=camera, bounds=bounds)
    heights = globe.heights.reshape(-1)[mesh.metadata["node_entry"]] / globe.exaggeration
    mesh.visual.vertex_colors = elevation_colors(heights)
    return mesh


def overview_of(meshes, up, aspect: float, fov: float = math.radians(30.0), fill: float = 0.9) -> Camera:
    """A camera looking straight down at ``meshes``' vertices (towards the centre), ``up`` its image's up (minus the
    close camera's eye: the part of the view under the eye at the bottom, the horizon at the top), high enough that all
    of them lie within ``fill`` of its field of view, aimed at the middle of their image: the clipped close views were
    framed by a fixed camera (51° N, 2600 km up), and the part of them towards the horizon (to the north pole, 3.7 times
    the panel's half height above its centre) was cut off at the top of the panels."""
    points = np.concatenate([np.asarray(mesh.vertices, dtype=np.float64) for mesh in meshes])
    unit = points / np.linalg.norm(points, axis=1, keepdims=True)

    def fitted(direction):  # the lowest altitude (to 5 %) whose narrower frustum holds every vertex
        altitude = 100_000.0
        while True:
            eye, clip = tuple(direction * (EARTH_RADIUS + altitude)), (altitude / 1000, 4 * EARTH_RADIUS + altitude)
            planes = Camera(eye, (0.0, 0.0, 0.0), up, fov * fill, aspect, *clip).planes()
            if ((points @ planes[:, :3].T + planes[:, 3]) <= 0).all():
                return Camera(eye, (0.0, 0.0, 0.0), up, fov, aspect, *clip)
            altitude *= 1.05

    middle = (unit.min(axis=0) + unit.max(axis=0)) / 2  # their directions' box (a view over a pole has no lon range)
    middle /= np.linalg.norm(middle)
    for _ in range(3):  # aimed again at the vertex nearest the middle of their image
        pixels, _ = fitted(middle).project(points)
        middle = unit[np.argmin(np.linalg.norm(pixels - (pixels.min(axis=0) + pixels.max(axis=0)) / 2, axis=1))]
    return fitted(middle)


def label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` with ``text`` in its top left corner, white on a black box, in type scaled to the panel: 16 px at
    400 px high, 11 px at least. Pillow's default 10 px type, in a box sized at 7 px a character, read small beside a
    640 x 400 panel in docs/globe.png (the README's top row)."""
    from PIL import Image, ImageDraw, ImageFont

    size = max(11, image.shape[0] // 25)
    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=size)
    origin = (4, 2)
    right, bottom = draw.textbbox(origin, text, font=font)[2:]
    draw.rectangle([0, 0, right + 4, bottom + 3], fill=(0, 0, 0))
    draw.text(origin, text, fill=(255, 255, 255), font=font)
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
    rows = []
    for camera, edges, error in ((far, False, args.far_error), (close, True, args.close_error)):
        meshes = {bounds: coloured_mesh(globe, camera, bounds, error) for bounds in ("cone", "sphere")}
        # the far view from its eye; the clipped close views from above, one camera framing both whole
        view_camera = far if camera is far else overview_of(meshes.values(), -np.asarray(camera.eye), w / h)
        row = []
        for bounds, mesh in meshes.items():
            image = render_view(mesh, view_camera, window_size=(w, h), show_edges=edges)
            name = "far view" if camera is far else "close view (clipped)"
            row.append(label(image, f"{name}, {bounds}s: {len(mesh.faces):,} triangles"))
        rows.append(np.concatenate(row, axis=1))
    save_image(np.concatenate(rows, axis=0), args.output)
    print(f"wrote {args.output} in {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
