"""Interactive stepped terrain in pyvista: sliders for the step interval and γ, a sphere widget for the lens.

Shows paper 000 (Glander et al. 2010) §3.3 and §4 live: drag the interval slider to change the isovalues,
the γ slider to blend between the original surface (0) and the steps (1), and move the sphere to place a
lens that shows the original terrain inside it. Every change re-steps the grid through the pyvista accessor
``grid.stepterrain.stepped(...)``. Headless by default: writes one PNG of the initial state;
``--interactive`` opens a window. ``--dem PATH`` shows a DEM file of yours instead of the embedded one.

    python examples/interactive.py --output out/interactive.png
    python examples/interactive.py --interactive
    python examples/interactive.py --interactive --dem my_dem.tif
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

import numpy as np
import pyvista as pv

from stepterrain import Terrain, circular_lens, sample_dem
from stepterrain.cli import add_dem_option, check_example_outputs, example_dem, usage_errors
from stepterrain.export import IMAGE_EXTENSIONS, save_image
from stepterrain.render import require_offscreen


def dem_grid(size: int, terrain: Terrain | None = None) -> pv.ImageData:
    """``terrain`` (default: the embedded Big Tujunga DEM, 1197 columns), every (columns // ``size``)-th node
    (``size`` to 2 ``size`` - 1 nodes across, at most all of them), as a pyvista ImageData of its cell size."""
    terrain = sample_dem() if terrain is None else terrain
    step = max(1, terrain.shape[1] // size)
    heights = terrain.heights[::step, ::step]
    if terrain.spacing[1] < 0:  # a north-up DEM: its rows south to north, as y grows with the grid's row index
        heights = heights[::-1]
    if terrain.spacing[0] < 0:  # columns east to west (a GeoTIFF's negative pixel width): x grows with the column
        heights = heights[:, ::-1]
    dx, dy = abs(terrain.spacing[0]) * step, abs(terrain.spacing[1]) * step
    grid = pv.ImageData(dimensions=(heights.shape[1], heights.shape[0], 1), spacing=(dx, dy, 1))
    grid["elevation"] = heights.reshape(-1)
    return grid


class SteppedScene:
    """The state behind the widgets: each callback updates one value and re-steps the grid in place.

    A callback given the value the scene already holds keeps the mesh: pyvista runs every widget's callback once
    when it is created, which stepped the grid four times at startup, and a slider released where it was
    re-stepped it too.
    """

    def __init__(self, plotter: pv.Plotter, grid: pv.ImageData, *, interval: float, gamma: float,
                 lens_radius: float, z_scale: float = 2.0, device: str | None = None) -> None:  # fmt: skip
        self.plotter, self.grid, self.device = plotter, grid, device
        self.interval, self.gamma = interval, gamma
        xmin, xmax, ymin, ymax, _, _ = grid.bounds
        self.lens_center = ((xmin + xmax) / 2, (ymin + ymax) / 2)
        self.lens_radius = lens_radius
        self.z_scale = z_scale
        self.updates = 0
        self.mesh = pv.PolyData()
        self.update()
        self.actor = plotter.add_mesh(self.mesh, scalars="RGBA", rgb=True, smooth_shading=False)

    def set_interval(self, value: float) -> None:
        if float(value) != self.interval:
            self.interval = float(value)
            self.update()

    def set_gamma(self, value: float) -> None:
        if float(value) != self.gamma:
            self.gamma = float(value)
            self.update()

    def move_lens(self, center: tuple[float, float, float]) -> None:
        if (float(center[0]), float(center[1])) != self.lens_center:
            self.lens_center = (float(center[0]), float(center[1]))
            self.update()

    def update(self) -> None:
        terrain = self.grid.stepterrain.terrain()
        lens = circular_lens(terrain, self.lens_center, self.lens_radius, outside=self.gamma)
        steps = self.grid.stepterrain.stepped(self.interval, gamma=lens, colors="terrain", device=self.device)
        steps.points[:, 2] *= self.z_scale
        self.mesh.copy_from(steps)
        self.updates += 1


def build(plotter: pv.Plotter, grid: pv.ImageData, *, device: str | None = None) -> SteppedScene:
    """Add the stepped terrain, two sliders and the lens sphere to ``plotter``."""
    lo, hi = float(np.nanmin(grid["elevation"])), float(np.nanmax(grid["elevation"]))  # a DEM's nodata is NaN
    span = hi - lo or 1.0  # a flat DEM: 1 m (a span of 0 gave interval 0, refused by the library, and no slider range)
    xmin, xmax, ymin, ymax, _, _ = grid.bounds
    radius = 0.2 * min(xmax - xmin, ymax - ymin)
    scene = SteppedScene(plotter, grid, interval=round(span / 15, -1) or span / 15, gamma=1.0, lens_radius=radius,
                         device=device)  # fmt: skip
    plotter.add_slider_widget(scene.set_interval, (span / 40, span / 4), value=scene.interval, title="interval (m)",
                              pointa=(0.05, 0.92), pointb=(0.45, 0.92), interaction_event="end")  # fmt: skip
    plotter.add_slider_widget(scene.set_gamma, (0.0, 1.0), value=scene.gamma, title="gamma",
                              pointa=(0.55, 0.92), pointb=(0.95, 0.92), interaction_event="end")  # fmt: skip
    z = (hi + span * 0.2) * scene.z_scale
    plotter.add_sphere_widget(scene.move_lens, center=(*scene.lens_center, z), radius=radius * 0.3,
                              color="tomato", interaction_event="end")  # fmt: skip
    plotter.add_light(pv.Light(position=(-1, 1, 1), light_type="scene light", intensity=0.8))
    width = xmax - xmin
    eye = ((xmin + xmax) / 2 - 0.2 * width, ymin - 1.2 * (ymax - ymin), 1.1 * width)
    plotter.camera_position = [eye, ((xmin + xmax) / 2, (ymin + ymax) / 2, lo * scene.z_scale), (0, 0, 1)]
    # that view direction, at the distance that shows the whole terrain: the eye placed by hand cut off its west and
    # east ends (docs/interactive.png); the bounding sphere VTK fits leaves a margin, taken back by fitting the view
    # angle to the terrain's projected box (a fixed zoom suited landscape windows only: a portrait one cut the ends)
    plotter.reset_camera()
    fit_view(plotter, scene.mesh.bounds)
    return scene


def fit_view(plotter: pv.Plotter, bounds: tuple[float, ...], *, side: float = 0.95, top: float = 0.6) -> None:
    """Narrow (or widen) the camera's view angle so that the box ``bounds`` (xmin, xmax, ymin, ymax, zmin, zmax)
    fills the window: its projection within ``side`` of the window's half-width and half-height from the centre,
    and below ``top`` of its half-height above it (the sliders lie above)."""
    corners = np.array(list(itertools.product(bounds[0:2], bounds[2:4], bounds[4:6])))
    width, height = plotter.window_size
    matrix = plotter.camera.GetCompositeProjectionTransformMatrix(width / height, -1, 1)
    project = np.array([[matrix.GetElement(i, j) for j in range(4)] for i in range(4)])
    clip = np.column_stack([corners, np.ones(len(corners))]) @ project.T
    x, y = clip[:, 0] / clip[:, 3], clip[:, 1] / clip[:, 3]  # normalized device coordinates, -1 to 1
    reach = max(np.abs(x).max() / side, y.max() / top, -y.min() / side)
    # screen coordinates scale with tan(view angle / 2): the one angle that brings the box to its reach
    angle = math.radians(plotter.camera.view_angle)
    plotter.camera.view_angle = math.degrees(2.0 * math.atan(math.tan(angle / 2.0) * reach))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=240,
                        help="keep every (columns // SIZE)-th DEM node: SIZE to 2 x SIZE - 1 nodes across, all of the "
                             "embedded DEM's 1197 from SIZE 599 on (default 240: 300 nodes)")
    add_dem_option(parser)
    parser.add_argument("--window", type=int, nargs=2, default=(1024, 768), metavar=("W", "H"))
    parser.add_argument("--output", default="interactive.png", help="PNG of the initial view (headless)")
    parser.add_argument("--interactive", action="store_true", help="open a window instead of writing a PNG")
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda:0 (default: Warp's)")
    args = parser.parse_args(argv)
    if args.size < 2:  # 0 raised a ZeroDivisionError, a negative size stepped the full DEM without a word
        parser.error(f"--size must be at least 2 nodes; got {args.size}")
    if not all(8 <= side <= 16384 for side in args.window):  # 0 0 wrote pyvista's default 300 x 300 image
        parser.error(f"--window must be W H of 8 to 16384 pixels each; got {' '.join(map(str, args.window))}")
    if not args.interactive and Path(args.output).suffix.lower() not in IMAGE_EXTENSIONS:  # refused after the render
        parser.error(f"--output must end in {', '.join(IMAGE_EXTENSIONS)}; got {args.output!r}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": None if args.interactive else args.output}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    if not args.interactive:  # headless: EGL or OSMesa as the library's renders pick it (VTK tried X first)
        require_offscreen()
    # before the window: a file it cannot read opens none
    grid = dem_grid(args.size, example_dem(args.dem, args.nodata))
    plotter = pv.Plotter(off_screen=not args.interactive, window_size=tuple(args.window))
    plotter.set_background("white")
    build(plotter, grid, device=args.device)
    if args.interactive:  # pragma: no cover - needs a display
        plotter.show()
        return 0
    image = plotter.screenshot(return_img=True)
    plotter.close()
    save_image(np.ascontiguousarray(image[..., :3]), Path(args.output))
    return 0


if __name__ == "__main__":
    sys.exit(main())
