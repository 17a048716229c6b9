"""The pyvista accessor grid.stepterrain and the interactive example, driven offscreen through its widgets."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import pyvista as pv
from hypothesis import given
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

import stepterrain as st
import stepterrain.pyvista_accessor  # noqa: F401 - registers the accessor
from stepterrain import render
from stepterrain.errors import InvalidInputError

from .conftest import real_dem

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
OFFSCREEN, REASON = render.offscreen_available()
needs_offscreen = pytest.mark.skipif(not OFFSCREEN, reason=f"no off-screen OpenGL context: {REASON}")


def image_grid(heights: np.ndarray, spacing=(30.0, 30.0), origin=(500.0, 900.0)) -> pv.ImageData:
    grid = pv.ImageData(dimensions=(heights.shape[1], heights.shape[0], 1), spacing=(*spacing, 1.0),
                        origin=(*origin, 0.0))  # fmt: skip
    grid["elevation"] = heights.reshape(-1)
    return grid


def test_entry_point_registers_the_accessor_lazily():
    """``import stepterrain`` leaves pyvista (VTK) alone; a pyvista user gets ``grid.stepterrain`` without
    importing stepterrain, through the ``pyvista.accessors`` entry point (fresh interpreters: no module cached)."""
    quiet = "import sys; import stepterrain; print('pyvista' in sys.modules, 'vtkmodules' in sys.modules)"
    use = (
        "import sys, numpy as np, pyvista as pv\n"
        "assert 'stepterrain' not in sys.modules\n"
        "g = pv.ImageData(dimensions=(5, 4, 1)); g['elevation'] = np.arange(20.0)\n"
        "print(g.stepterrain.stepped(interval=4.0, device='cpu').n_cells > 0)"
    )
    started = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for code in (quiet, use)]  # both at once: each imports the project
    try:
        outputs = [p.communicate(timeout=300) for p in started]
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
                p.communicate()
    for p, (_, err) in zip(started, outputs, strict=True):
        assert p.returncode == 0, err
    assert outputs[0][0].split() == ["False", "False"]
    assert outputs[1][0].split()[-1:] == ["True"]


def test_image_data_steps_like_the_api(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=5)
    steps = image_grid(heights).stepterrain.stepped(interval=100.0, device=device)
    expected = st.stepped(heights, interval=100.0, spacing=(30.0, 30.0), origin=(500.0, 900.0), device=device)
    assert isinstance(steps, pv.PolyData) and steps.is_all_triangles
    np.testing.assert_allclose(steps.points, expected.vertices, atol=1e-6)
    np.testing.assert_array_equal(steps.regular_faces, expected.faces)
    np.testing.assert_array_equal(steps.cell_data["level"], expected.face_attributes["level"])
    np.testing.assert_array_equal(steps.cell_data["wall"], expected.face_attributes["wall"].astype(np.uint8))
    np.testing.assert_allclose(steps.field_data["isovalues"], expected.metadata["isovalues"])


def test_image_data_whose_extent_starts_past_zero_steps_where_its_points_are():
    """A grid cut out of a larger one (a VOI, a .vti piece) or given an offset has node (i, j) at origin + (extent
    start + (i, j)) x spacing: its terraces lay at the origin, (10, 21) off the grid's own points."""
    heights = np.add.outer(np.arange(3.0), np.arange(4.0)) * 3.0
    grid = image_grid(heights, spacing=(2.0, 3.0), origin=(100.0, 200.0))
    grid.extent = (5, 8, 7, 9, 2, 2)  # the same 4 x 3 nodes, starting at index (5, 7, 2)
    grid.spacing = (2.0, 3.0, 0.5)
    steps = grid.stepterrain.stepped(interval=2.0, device="cpu")
    expected = st.stepped(heights + 1.0, interval=2.0, spacing=(2.0, 3.0), origin=(110.0, 221.0), device="cpu")
    np.testing.assert_allclose(steps.bounds[:4], grid.bounds[:4])
    np.testing.assert_allclose(steps.points, expected.vertices, atol=1e-6)


def test_structured_grid_uses_point_z_and_colors():
    x, y = np.meshgrid(np.linspace(0, 100, 9), np.linspace(0, 60, 7))
    z = 10 * np.sin(x / 30) + y / 3
    grid = pv.StructuredGrid(x, y, z)
    steps = grid.stepterrain.stepped(interval=5.0, colors="terrain")
    z = steps.points[:, 2] / 5.0  # γ = 1: every vertex lies on an isovalue k * 5
    assert np.allclose(z, np.round(z), atol=1e-5) and np.ptp(z) >= 4
    assert steps.point_data["RGBA"].shape == (steps.n_points, 4)
    x0, x1, y0, y1, _, _ = steps.bounds
    assert (x0, x1, y0, y1) == pytest.approx((0, 100, 0, 60))


def test_named_elevation_and_active_scalars():
    heights = np.add.outer(np.arange(4.0), np.arange(5.0)).astype(np.float32)
    grid = image_grid(heights)
    grid["other"] = np.zeros(grid.n_points)
    grid.set_active_scalars("other")
    # an array named as elevation wins over active scalars of another name; elevation= steps any array
    np.testing.assert_array_equal(grid.stepterrain.elevation(), heights)
    assert np.ptp(grid.stepterrain.elevation("other")) == 0
    np.testing.assert_array_equal(grid.stepterrain.elevation("elevation"), heights)
    steps = grid.stepterrain.stepped(levels=[0.0, 3.0, 6.0], elevation="elevation")
    assert set(np.round(steps.points[:, 2], 4)) == {0.0, 3.0, 6.0}


@pytest.mark.parametrize(
    ("make", "kwargs", "match"),
    [
        (lambda: pv.ImageData(dimensions=(3, 3, 2)), {"interval": 1.0}, r"\(W, H, 1\) surface"),
        (lambda: pv.ImageData(dimensions=(3, 3, 1)), {"interval": 1.0}, "has no elevation"),
        (lambda: image_grid(np.zeros((3, 3))), {"interval": 1.0, "elevation": "nope"}, "must name a point-data"),
        (lambda: image_grid(np.zeros((3, 3))), {}, "give interval"),
    ],
)
def test_bad_grids(make, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        make().stepterrain.stepped(**kwargs)


def _structured(z: np.ndarray, x: np.ndarray | None = None) -> pv.StructuredGrid:
    y, xx = np.meshgrid(np.arange(z.shape[0], dtype=float), np.arange(z.shape[1], dtype=float), indexing="ij")
    return pv.StructuredGrid(xx if x is None else x, y, z)


_BIG = np.where(np.add.outer(np.arange(3.0), np.arange(4.0)) == 5.0, 1e39, 1.0)  # 1e39 at (2, 3)


@pytest.mark.parametrize(
    ("make", "kwargs", "match"),
    [
        # VTK's TypeError
        (lambda: image_grid(np.zeros((3, 3))), {"elevation": 5}, r"^elevation must name a point-data array \(a str\); "
         "got 5$"),
        # stepped as 0/1 heights; stepped() refuses bool heights
        (lambda: image_grid(np.zeros((3, 3), bool)), {}, r"must hold one real number per point; got shape \(9,\), "
         "dtype bool$"),
        # float64 beyond float32: "an infinite value at index (1, 3)" after numpy's overflow warning
        (lambda: image_grid(_BIG), {}, r"^elevation must fit in float32 .*got 1e\+39 at index \(2, 3\), finite"),
        # ... and on a StructuredGrid the cast made it inf, silently nodata (holes)
        (lambda: _structured(_BIG), {}, r"^elevation must fit in float32 .*got 1e\+39 at index \(\d, \d\), finite"),
        (lambda: image_grid(np.full((3, 3), 3e38), origin=(0.0, 0.0)), {"origin_z": 3e38},
         r"^elevation \+ the grid's origin z must fit in float32 .*got 6.0+\d*e\+38 at index \(0, 0\)"),
        # an infinite elevation: an error on an ImageData, silently nodata (a hole) on a StructuredGrid; NaN is nodata
        (lambda: image_grid(np.where(_BIG > 1, np.inf, 1.0)), {},
         r"^elevation must be finite or NaN \(nodata\); got an infinite value at index \(2, 3\)$"),
        (lambda: _structured(np.where(_BIG > 1, -np.inf, 1.0)), {},
         r"^elevation must be finite or NaN \(nodata\); got an infinite value at index \(\d, \d\)$"),
        # a StructuredGrid whose x equals its y: every vertex of the steps lay on one line
        (lambda: _structured(np.add.outer(np.arange(3.0), np.arange(3.0)), x=np.add.outer(np.arange(3.0), np.zeros(3))),
         {}, "none of its 8 faces with finite heights has an area in xy"),
    ],
)
def test_bad_elevation_is_named(make, kwargs, match):
    grid = make()
    if "origin_z" in kwargs:
        grid.origin = (0.0, 0.0, kwargs.pop("origin_z"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no overflow in a cast on the way
        with pytest.raises(InvalidInputError, match=match):
            grid.stepterrain.stepped(interval=1.0, **kwargs)


@given(arrays(np.float32, hst.tuples(hst.integers(2, 9), hst.integers(2, 9)),
              elements=hst.floats(-50, 50, width=32)), hst.sampled_from([1.0, 2.5, 7.0]))  # fmt: skip
def test_terrace_tops_lie_on_isovalues(heights, interval):
    steps = image_grid(heights, origin=(0.0, 0.0)).stepterrain.stepped(interval=interval)
    values = np.asarray(steps.field_data["isovalues"])
    z = steps.points[:, 2]
    assert np.min(np.abs(z[:, None] - values[None, :]), axis=1).max() < 1e-4
    assert steps.n_cells == int(np.sum(steps.cell_data["wall"] == 0) + np.sum(steps.cell_data["wall"] == 1))


# ---------------------------------------------------------------------------------------------- example
def load_example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@needs_offscreen
def test_interactive_example_through_its_widgets():
    example = load_example("interactive")
    plotter = pv.Plotter(off_screen=True, window_size=(200, 150))
    try:
        scene = example.build(plotter, example.dem_grid(40), device="cpu")
        interval_slider, gamma_slider = plotter.widgets.slider_widgets
        (sphere,) = plotter.widgets.sphere_widgets
        before = scene.mesh.n_cells

        interval_slider.GetRepresentation().SetValue(4 * scene.interval)
        interval_slider.InvokeEvent("EndInteractionEvent")
        assert scene.mesh.n_cells < before  # fewer steps, fewer walls

        gamma_slider.GetRepresentation().SetValue(0.0)
        gamma_slider.InvokeEvent("EndInteractionEvent")
        assert scene.gamma == 0.0
        walls = scene.mesh.cell_data["wall"] == 1
        wall_z = scene.mesh.points[scene.mesh.regular_faces[walls]][:, :, 2]
        assert walls.any() and np.ptp(wall_z, axis=1).max() < 1e-3  # γ = 0: walls collapse onto the surface

        updates = scene.updates
        sphere.SetCenter(1000.0, 2000.0, 0.0)
        sphere.InvokeEvent("EndInteractionEvent")
        assert scene.lens_center == (1000.0, 2000.0) and scene.updates == updates + 1
    finally:
        plotter.close()


@needs_offscreen
def test_interactive_example_writes_a_png(tmp_path):
    example = load_example("interactive")
    assert example.__doc__ and "sphere widget" in example.__doc__
    out = tmp_path / "interactive.png"
    assert example.main(["--size", "40", "--window", "160", "120", "--output", str(out), "--device", "cpu"]) == 0
    from PIL import Image

    with Image.open(out) as image:
        array = np.asarray(image)
    assert array.shape[:2] == (120, 160) and array.std() > 5


@pytest.mark.parametrize("origin", [(0.0, 0.0, np.nan), (0.0, 0.0, np.inf), (np.nan, 0.0, 0.0), (0.0, -np.inf, 0.0)])
def test_a_non_finite_origin_is_named_as_the_grid_origin(origin):
    """A NaN origin z was reported as "terrain has no finite height (all nodata)", an infinite one as an infinite
    elevation at index (0, 0), and a NaN x as Terrain's "origin must be a pair": none named the grid's origin."""
    grid = image_grid(np.add.outer(np.arange(3.0), np.arange(4.0)))
    grid.origin = origin
    with pytest.raises(InvalidInputError, match=r"^the grid's origin .* must be finite; got origin \("):
        grid.stepterrain.stepped(interval=1.0, device="cpu")


@pytest.mark.parametrize(("args", "match"), [(["--size", "0"], "--size must be at least 2"),      # ZeroDivisionError
                                             (["--size", "-3"], "--size must be at least 2"),     # the full DEM
                                             (["--window", "0", "0"], "--window must be W H of 8"),  # a 300 x 300 PNG
                                             (["--window", "160", "99999"], "--window must be W H of 8")])
def test_interactive_example_names_a_bad_size_or_window(tmp_path, capsys, args, match):
    example = load_example("interactive")
    out = tmp_path / "interactive.png"
    with pytest.raises(SystemExit) as exit_info:
        example.main([*args, "--output", str(out), "--device", "cpu"])
    assert exit_info.value.code == 2 and match in capsys.readouterr().err
    assert not out.exists()


@needs_offscreen
@pytest.mark.parametrize("window", [(120, 160), (160, 120), (240, 80)])
def test_interactive_examples_initial_view_shows_the_whole_terrain_in_any_window(tmp_path, window):
    """The initial view was VTK's bounding-sphere fit zoomed by a fixed 1.35, which suits a landscape window: in a
    portrait one (--window 240 320) the terrain's west and east ends were cut off at the picture's sides. Found by
    writing the PNG in windows of several shapes. The view is now fitted to the terrain's projected box, below the
    sliders, in any window."""
    example = load_example("interactive")
    out = tmp_path / "interactive.png"
    assert example.main(["--size", "40", "--window", *map(str, window), "--output", str(out), "--device", "cpu"]) == 0
    from PIL import Image

    with Image.open(out) as image:
        drawn = (np.asarray(image) < 245).any(axis=2)
    width, height = window
    below = drawn[int(0.3 * height):]  # the sliders and their labels lie above
    assert not below[:, 0].any() and not below[:, -1].any() and not below[-1].any()  # nothing cut at the sides
    columns = np.flatnonzero(below.any(axis=0))
    rows = np.flatnonzero(below.any(axis=1))
    # and it fills the window across or down (a fit that shrank it to a dot would pass the test above)
    assert (columns[-1] - columns[0]) > 0.8 * width or (rows[-1] - rows[0]) > 0.55 * height
