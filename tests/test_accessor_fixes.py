"""Bugs found by a hunt for silent wrong results in the pyvista accessor (grid.stepterrain), one test each."""

from __future__ import annotations

import numpy as np
import pytest
import pyvista as pv
import trimesh

import stepterrain.pyvista_accessor  # noqa: F401 - registers the accessor
from stepterrain import render
from stepterrain.errors import InvalidInputError
from stepterrain.pyvista_accessor import RGBA_ALIAS


def test_structured_grid_with_elevation_in_cell_data_is_refused_not_stepped_flat():
    """A flat StructuredGrid (z = 0) whose elevation sits in cell data stepped its points' z without a word: one
    flat terrace at 0 whatever the elevation held. Found by stepping grids with elevation in point data, cell data
    and z. Now the elevation in cell data is named with the conversion to point data; after it, the grid steps."""
    heights = np.random.default_rng(0).random((5, 6)) * 100
    x, y = np.meshgrid(np.arange(6) * 30.0, np.arange(5) * 30.0)
    grid = pv.StructuredGrid(x, y, np.zeros_like(x))
    grid.cell_data["elevation"] = heights[:-1, :-1].ravel(order="F")
    with pytest.raises(InvalidInputError, match=r"cell data 'elevation'.*cell_data_to_point_data"):
        grid.stepterrain.stepped(interval=10.0)
    steps = grid.cell_data_to_point_data().stepterrain.stepped(interval=10.0)
    assert np.ptp(steps.points[:, 2]) > 0


def test_image_data_elevation_in_cell_data_is_named_in_the_error():
    """An ImageData with elevation in cell data only was refused with "point data: []", not saying where its
    elevation was nor how to use it; elevation=NAME of a cell-data array the same."""
    grid = pv.ImageData(dimensions=(4, 3, 1))
    grid.cell_data["height"] = np.arange(6.0)
    with pytest.raises(InvalidInputError, match=r"cell data 'height'.*cell_data_to_point_data"):
        grid.stepterrain.stepped(interval=1.0)
    with pytest.raises(InvalidInputError, match=r"got 'height'.*cell_data_to_point_data"):
        grid.stepterrain.stepped(interval=1.0, elevation="height")


@pytest.mark.skipif(not render.offscreen_available()[0], reason="no off-screen OpenGL context")
def test_default_plot_of_coloured_steps_shows_the_level_colours_not_a_colormap():
    """steps.plot() / add_mesh(steps) of a grid stepped with colors= drew the "RGBA" bytes through viridis with a
    scalar bar of their magnitudes: pyvista plots an array as colours only when its name ends in "_rgb"/"_rgba" (or
    with rgb=True). Found by plotting the accessor's result as a pyvista user would. "RGBA" stays; the same buffer
    is also the active scalars "colors_rgba", so the default plot shows the level colours, no bar."""
    y, x = np.mgrid[0:40, 0:40]
    grid = pv.ImageData(dimensions=(40, 40, 1), spacing=(10.0, 10.0, 1.0))
    grid["elevation"] = (300 * np.exp(-((x - 20.0) ** 2 + (y - 20.0) ** 2) / 150.0)).ravel()
    table = np.array([[255, 0, 0], [0, 160, 0], [0, 0, 255], [255, 255, 0], [255, 0, 255], [0, 255, 255],
                      [128, 64, 0]], np.uint8)  # fmt: skip
    steps = grid.stepterrain.stepped(levels=np.arange(0.0, 301.0, 50.0), colors=table, device="cpu")

    def shot(**kwargs):
        plotter = pv.Plotter(off_screen=True, window_size=(200, 200), lighting=None)
        plotter.add_mesh(steps, **kwargs)
        plotter.view_xy()
        plotter.background_color = "black"
        image = plotter.screenshot(return_img=True)
        plotter.close()
        return image

    image = shot()  # what steps.plot() draws, here unlit and from above
    assert np.array_equal(image, shot(scalars="RGBA", rgb=True))
    levels = np.unique(steps.cell_data["level"])
    centre = image[100, 100, :3].astype(int)  # the summit's terrace, unlit: its colour exactly
    np.testing.assert_array_equal(centre, table[levels.max()], err_msg="the summit is not drawn in its colour")
    pixels = image[..., :3].reshape(-1, 3)
    pixels = pixels[pixels.any(axis=1)]  # the terrain, not the black background
    in_table = (pixels[:, None, :] == table[None]).all(axis=2).any(axis=1)
    assert in_table.mean() > 0.8, f"{in_table.mean():.0%} of the terrain's pixels are level colours"  # edges blend
    assert steps.point_data["RGBA"].shape == (steps.n_points, 4)  # the documented name is kept
    assert np.shares_memory(steps.point_data["RGBA"], steps.point_data[RGBA_ALIAS])
    assert steps.active_scalars_name == RGBA_ALIAS


def test_to_polydata_hands_the_faces_to_vtk_without_a_padded_copy():
    """grid.stepterrain.stepped built VTK's cells as a padded [3, a, b, c] int64 copy of the faces, converted again by
    VTK: 2.5 s and 550 MB more for 13 M faces (a 2600² grid stepped), almost all of its time past the kernels. Found
    by timing the conversion of a 13 M-face mesh (now 0.05 s). VTK's connectivity is now the faces' own buffer."""
    from stepterrain.pyvista_accessor import to_polydata

    grid = pv.ImageData(dimensions=(30, 20, 1), spacing=(10.0, 10.0, 1.0))
    grid["elevation"] = np.random.default_rng(1).random(600) * 100
    mesh = stepterrain.stepped(grid.stepterrain.terrain(), interval=20.0, colors="terrain", device="cpu")
    poly = to_polydata(mesh)
    connectivity = pv.convert_array(poly.GetPolys().GetConnectivityArray())
    assert np.shares_memory(connectivity, mesh.faces), "the faces were copied"
    np.testing.assert_array_equal(poly.regular_faces, mesh.faces)
    np.testing.assert_array_equal(poly.cell_data["level"], mesh.face_attributes["level"])
    np.testing.assert_array_equal(poly.point_data["RGBA"], mesh.visual.vertex_colors)
    empty = to_polydata(trimesh.Trimesh(np.zeros((4, 3)), np.zeros((0, 3), np.int64), process=False))
    assert (empty.n_points, empty.n_cells) == (4, 0)


@pytest.mark.parametrize("flip", [(1, -1), (-1, 1), (-1, -1)])
def test_image_data_with_a_flipped_axis_steps_where_its_points_are(flip):
    """An ImageData whose direction_matrix flips y (diag(1, -1, 1): rows north to south, a north-up raster as it
    is, without heights[::-1]) or x was refused as "a rotated ImageData". Found by stepping grids as a pyvista
    user lays a DEM out. A flip is a negative spacing, as load_dem's dy < 0: the steps now lie on the grid's own
    points, as stepped() steps the heights from node (0, 0) with that spacing; a rotation is still refused."""
    heights = (np.random.default_rng(0).random((5, 6)) * 10).astype(np.float32)
    sx, sy = flip
    grid = pv.ImageData(dimensions=(6, 5, 1), spacing=(30.0, 20.0, 1.0), origin=(1000.0, 5000.0, 0.0),
                        direction_matrix=np.diag([sx, sy, 1]))  # fmt: skip
    grid.extent = (2, 7, 3, 7, 0, 0)
    grid["elevation"] = heights.ravel()
    steps = grid.stepterrain.stepped(interval=2.0, device="cpu")
    # node (0, 0) at the grid's first point, the flipped axes' spacing negative: as load_dem gives a north-up DEM
    expected = stepterrain.stepped(heights, interval=2.0, spacing=(30.0 * sx, 20.0 * sy), origin=grid.points[0, :2],
                                   device="cpu")  # fmt: skip
    np.testing.assert_allclose(steps.bounds[:4], grid.bounds[:4])
    np.testing.assert_allclose(steps.points, expected.vertices, atol=1e-9)
    np.testing.assert_array_equal(steps.regular_faces, expected.faces)
    rotated = pv.ImageData(dimensions=(6, 5, 1), direction_matrix=[[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    rotated["elevation"] = heights.ravel()
    with pytest.raises(InvalidInputError, match=r"rotated ImageData .*direction_matrix .*got \[\[0\.0, -1\.0"):
        rotated.stepterrain.stepped(interval=2.0)


def test_rectilinear_grid_steps_as_a_grid_or_a_tin():
    """A RectilinearGrid (what pyvista-xarray makes of a rioxarray DEM: x and y coordinate arrays, y often north
    to south) had no accessor: grid.stepterrain raised an AttributeError. Found by laying a DEM out as GIS users
    bring one into pyvista. Evenly spaced coordinates now step as the grid Terrain they are (descending y a negative
    spacing, as load_dem's), uneven ones as a TIN on the grid's nodes, the plane's z added as an ImageData's origin."""
    heights = (np.random.default_rng(2).random((5, 7)) * 40).astype(np.float32)  # row 0 north
    xs = 500.0 + 30.0 * np.arange(7)
    ys = 9000.0 - 20.0 * np.arange(5)  # north to south
    grid = pv.RectilinearGrid(xs, ys, [3.0])
    grid["elevation"] = heights.ravel()
    steps = grid.stepterrain.stepped(interval=5.0, colors="terrain", device="cpu")
    expected = stepterrain.stepped(heights + 3.0, interval=5.0, spacing=(30.0, -20.0), origin=(500.0, 9000.0),
                                   colors="terrain", device="cpu")  # fmt: skip
    np.testing.assert_allclose(steps.points, expected.vertices, atol=1e-6)
    np.testing.assert_array_equal(steps.regular_faces, expected.faces)
    np.testing.assert_array_equal(steps.cell_data["level"], expected.face_attributes["level"])
    uneven = pv.RectilinearGrid(np.r_[xs[:3], xs[3:] + 12.0], ys)  # one column 42 m wide
    uneven["elevation"] = heights.ravel()
    tin = uneven.stepterrain.terrain()
    assert isinstance(tin, trimesh.Trimesh)
    np.testing.assert_allclose(tin.vertices[:, :2], uneven.points[:, :2])
    np.testing.assert_allclose(tin.vertices[:, 2], heights.ravel())
    tin_steps = uneven.stepterrain.stepped(interval=5.0, device="cpu")
    np.testing.assert_allclose(tin_steps.bounds[:4], uneven.bounds[:4])
    assert np.allclose(tin_steps.points[:, 2] % 5.0, 0.0)
