"""Bugs found by a hunt for silent wrong results in the pyvista accessor (grid.stepterrain), one test each."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import pyvista as pv
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import stepterrain.pyvista_accessor  # noqa: F401 - registers the accessor
from stepterrain import render
from stepterrain.errors import InvalidInputError
from stepterrain.pyvista_accessor import RGBA_ALIAS, from_polydata, to_polydata


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


def _coloured_steps() -> tuple[pv.PolyData, trimesh.Trimesh]:
    """A grid stepped with colours through the accessor, and the same steps as stepterrain's Trimesh."""
    import stepterrain as st

    grid = pv.ImageData(dimensions=(7, 6, 1), spacing=(30, 30, 1), origin=(500.0, 900.0, 0.0))
    grid["elevation"] = np.random.default_rng(3).uniform(0, 300, 42)
    poly = grid.stepterrain.stepped(interval=50, colors="terrain")
    mesh = st.stepped(grid.stepterrain.terrain(), interval=50, colors="terrain")
    return poly, mesh


@pytest.mark.parametrize("suffix", [".glb", ".ply", ".obj"])
def test_save_mesh_takes_the_accessors_polydata_as_its_trimesh(tmp_path, suffix):
    """save_mesh, render_mesh and drape refused grid.stepterrain.stepped's PolyData ("mesh must be a
    trimesh.Trimesh; got PolyData") and pv.to_trimesh leaves its colours a plain vertex attribute (not written).
    Now the PolyData is taken as its Trimesh (from_polydata): the file is the Trimesh's, byte for byte (positions,
    faces, colours, and the GLB's extras: source, isovalues, gamma), and reads back with the same arrays."""
    from stepterrain.export import save_mesh

    poly, mesh = _coloured_steps()
    (tmp_path / "poly").mkdir(), (tmp_path / "mesh").mkdir()
    a = save_mesh(poly, tmp_path / "poly" / f"steps{suffix}")  # one name: the GLB holds it
    b = save_mesh(mesh, tmp_path / "mesh" / f"steps{suffix}")
    assert a.read_bytes() == b.read_bytes()
    back = trimesh.load(a, force="mesh", process=False)
    ref = trimesh.load(b, force="mesh", process=False)
    assert np.array_equal(back.vertices, ref.vertices) and np.array_equal(back.faces, ref.faces)
    if suffix == ".ply":  # unwelded: the points, faces and colours of the PolyData itself
        assert np.allclose(back.vertices, poly.points) and np.array_equal(back.faces, poly.regular_faces)
        assert np.array_equal(back.visual.vertex_colors, poly.point_data[RGBA_ALIAS])


def test_render_and_drape_take_the_accessors_polydata_and_refuse_other_cells_naming_triangulate():
    """render_mesh and drape took only a Trimesh; a PolyData from the accessor is now drawn (level colours) and
    draped as its Trimesh. A PolyData of quads, or a grid, is refused naming the way to triangles."""
    import stepterrain as st
    from stepterrain.pyvista_accessor import from_polydata, to_polydata
    from stepterrain.texture import TextureLayer

    poly, mesh = _coloured_steps()
    back = from_polydata(poly)
    assert np.array_equal(back.faces, mesh.faces) and np.array_equal(back.vertices, mesh.vertices)
    assert np.array_equal(back.visual.vertex_colors, mesh.visual.vertex_colors)
    assert back.face_attributes["wall"].dtype == bool
    assert np.array_equal(back.face_attributes["wall"], mesh.face_attributes["wall"])
    assert np.array_equal(back.face_attributes["level"], mesh.face_attributes["level"])
    assert back.metadata == mesh.metadata
    assert to_polydata(back).user_dict == poly.user_dict
    kwargs = {"window_size": (48, 32)}
    assert np.array_equal(render.render_mesh(poly, **kwargs), render.render_mesh(mesh, **kwargs))
    layer = TextureLayer("luminance", np.linspace(0, 1, 20).reshape(4, 5), (500.0, 680.0, 900.0, 1050.0))
    assert np.array_equal(st.drape(poly, layer).visual.uv, st.drape(mesh, layer).visual.uv)
    with pytest.raises(InvalidInputError, match=r"triangles only; got 1 polygon of 4 or more corners "
                                                r"\(mesh\.triangulate\(\)"):  # (was "1 polygons")
        render.render_mesh(pv.Plane(i_resolution=1, j_resolution=1), **kwargs)
    with pytest.raises(InvalidInputError, match=r"pyvista\.ImageData.*extract_surface\(\)\.triangulate\(\)"):
        render.render_mesh(pv.ImageData(dimensions=(3, 3, 1)), **kwargs)


def test_to_polydata_keeps_the_json_metadata_in_user_dict():
    """to_polydata kept only the isovalues (source, CRS, gamma, floor dropped), where pv.wrap keeps a Trimesh's
    metadata in user_dict. Every JSON item now goes there (numpy values as plain numbers), the isovalues also stay
    a field_data array; an item that is not JSON is left out with a warning naming it."""
    import stepterrain as st
    from stepterrain.pyvista_accessor import to_polydata

    terrain = st.Terrain.from_heights(np.random.default_rng(1).uniform(0, 90, (5, 6)), crs="EPSG:32633",
                                      source="tile.tif")
    mesh = st.stepped(terrain, interval=20, gamma=0.75, solid=True, floor=-10)
    poly = to_polydata(mesh)
    user = dict(poly.user_dict)
    assert user == dict(mesh.metadata)
    assert {"source", "crs", "gamma", "floor", "isovalues"} <= set(user)
    assert user["crs"] == "EPSG:32633" and user["floor"] == -10 and user["gamma"] == 0.75
    assert np.array_equal(poly.field_data["isovalues"], mesh.metadata["isovalues"])
    mesh.metadata["mask"] = np.array([1, 2], np.int64)
    mesh.metadata["owner"] = {"ann"}
    with pytest.warns(UserWarning, match=r"\['owner'\] are not JSON"):
        poly = to_polydata(mesh)
    assert poly.user_dict["mask"] == [1, 2] and "owner" not in poly.user_dict


def test_accessor_takes_memory_budget():
    """grid.stepterrain.stepped had no memory_budget (a TypeError) where stepterrain.stepped takes one: it is passed
    through, a small one refused before the output is made, naming its size."""
    from stepterrain.errors import OutputTooLargeError

    grid = pv.ImageData(dimensions=(6, 5, 1))
    grid["elevation"] = np.arange(30.0) * 10
    with pytest.raises(OutputTooLargeError, match=r"would need [\d,]+ bytes, over the memory budget of 1,000 bytes"):
        grid.stepterrain.stepped(interval=50, memory_budget=1000)
    assert grid.stepterrain.stepped(interval=50, memory_budget=10**8).n_cells > 0


def test_accessor_takes_a_per_point_gamma_whichever_way_the_grid_steps():
    """A per-node γ had to be (H, W) on an ImageData or an evenly spaced RectilinearGrid (a grid Terrain) but (N,) on
    a StructuredGrid or an unevenly spaced RectilinearGrid (a TIN): pyvista's own point data (grid["gamma"], (N,))
    was refused on the first, and whether a RectilinearGrid wanted one or the other hung on its coordinates being even
    to 1e-6. Found by stepping one grid as each kind with one γ array. Both shapes are now taken on every grid, the
    same node for the same point, giving the same steps."""
    rng = np.random.default_rng(4)
    rows, cols = 5, 7
    heights = rng.uniform(0, 40, (rows, cols))
    heights[2, 3] = np.nan
    gamma = rng.random((rows, cols))
    xs, ys = 30.0 * np.arange(cols), 9000.0 - 20.0 * np.arange(rows)
    x, y = np.meshgrid(xs, ys, indexing="ij")  # (W, H): dimensions (W, H, 1), points x fastest
    structured = pv.StructuredGrid(x, y, np.zeros_like(x))
    even = pv.RectilinearGrid(xs, ys, [0.0])
    uneven = pv.RectilinearGrid(np.r_[xs[:3], xs[3:] + 12.0], ys, [0.0])
    image = pv.ImageData(dimensions=(cols, rows, 1), spacing=(30.0, 20.0, 1.0), origin=(0.0, 9000.0, 0.0),
                         direction_matrix=np.diag([1.0, -1.0, 1.0]))
    for grid in (image, even, structured, uneven):
        grid["elevation"] = heights.ravel()
        grid["gamma"] = gamma.ravel()
        a = grid.stepterrain.stepped(interval=5.0, gamma=grid["gamma"], solid=True)
        b = grid.stepterrain.stepped(interval=5.0, gamma=gamma, solid=True)
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.regular_faces, b.regular_faces)
        # γ blended node by node: each finite node's height is (1 - γ) h + γ α at its own point
        expected = (1 - gamma) * heights + gamma * (np.round(heights / 5.0) * 5.0)
        for point, z in zip(grid.points[:, :2], expected.ravel(), strict=True):
            if np.isfinite(z):
                at = np.flatnonzero((a.points[:, :2] == point).all(axis=1) & np.isclose(a.points[:, 2], z, atol=1e-4))
                assert at.size, (type(grid).__name__, point, z)


def test_to_polydata_keeps_face_colours_and_from_polydata_gives_them_back(tmp_path):
    """to_polydata kept vertex colours only: a stepped TIN's face colours (carried onto its steps) were dropped, and
    save_mesh or render_mesh of that PolyData gave a plain mesh. They are now cell data RGBA (also the active scalars
    colors_rgba, plotted as colours), and from_polydata (save_mesh's way in) gives them back as the face colours,
    not as face attributes beside level and wall."""
    import stepterrain as st
    from stepterrain.export import read_mesh, save_mesh
    from stepterrain.pyvista_accessor import from_polydata, to_polydata

    heights = np.random.default_rng(5).uniform(0, 60, (5, 6))
    tin = st.heightfield_mesh(heights, spacing=(30.0, 30.0))
    colours = np.random.default_rng(6).integers(0, 256, (len(tin.faces), 4)).astype(np.uint8)
    tin.visual = trimesh.visual.ColorVisuals(tin, face_colors=colours)
    mesh = st.stepped(tin, interval=10.0, device="cpu")
    assert mesh.visual.kind == "face"
    poly = to_polydata(mesh)
    np.testing.assert_array_equal(poly.cell_data["RGBA"], mesh.visual.face_colors)
    assert poly.cell_data.active_scalars_name == RGBA_ALIAS
    back = from_polydata(poly)
    assert back.visual.kind == "face"
    np.testing.assert_array_equal(back.visual.face_colors, mesh.visual.face_colors)
    assert set(back.face_attributes) == {"level", "wall"}
    written = read_mesh(save_mesh(poly, tmp_path / "steps.ply"))
    np.testing.assert_array_equal(written.visual.face_colors, mesh.visual.face_colors)
def test_to_polydata_keeps_uvs_vertex_attributes_and_long_metadata_arrays_as_pv_wrap_does():
    """to_polydata dropped a draped mesh's UVs (pl.add_mesh(poly, texture=...) found no texture coordinates), the
    vertex attributes (a close-up layer's mask_factor) and, without the warning its docstring promises, metadata
    arrays too long for user_dict (a globe's node_entry), all of which pv.wrap keeps. UVs are now the active texture
    coordinates, vertex attributes point data, such arrays field data; from_polydata brings the last two back."""
    import warnings

    import stepterrain as st
    from stepterrain.pyvista_accessor import from_polydata, to_polydata
    from stepterrain.texture import TextureLayer

    heights = np.random.default_rng(3).uniform(0, 90, (70, 80))
    mesh = st.stepped(st.Terrain.from_heights(heights), interval=20)
    layer = TextureLayer("luminance", np.linspace(0, 1, 20).reshape(4, 5), (-0.5, 79.5, -0.5, 69.5))
    textured = st.drape(mesh, layer)
    poly = to_polydata(textured)
    assert np.array_equal(poly.active_texture_coordinates, textured.visual.uv)
    assert np.array_equal(poly.cell_data["level"], mesh.face_attributes["level"])

    n = len(mesh.vertices)
    mask = np.linspace(0.0, 1.0, n, dtype=np.float32)
    entry = np.arange(n, dtype=np.int32)[::-1].copy()
    plain = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False, vertex_attributes={"mask_factor": mask},
                            metadata={"node_entry": entry, "closeup": 0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing left out, so no warning
        poly = to_polydata(plain)
    assert np.array_equal(poly.point_data["mask_factor"], mask) and poly.point_data["mask_factor"].dtype == np.float32
    assert np.array_equal(poly.field_data["node_entry"], entry) and poly.user_dict["closeup"] == 0
    back = from_polydata(poly)
    assert np.array_equal(back.vertex_attributes["mask_factor"], mask)
    assert np.array_equal(back.metadata["node_entry"], entry) and back.metadata["closeup"] == 0
    plain.metadata["ids"] = list(range(5000))  # a list too long for user_dict, and no array: named
    with pytest.warns(UserWarning, match=r"\['ids'\] are not JSON"):
        to_polydata(plain)


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_from_polydata_takes_the_rgb_colours_vtks_readers_give(tmp_path, suffix):
    """pv.read of a PLY without alpha, or of an OBJ with vertex colours, names them "RGB" (VTK's readers); from_polydata
    took only colors_rgba, RGBA or active *_rgb scalars, so render_mesh(pv.read(path)) drew the mesh in plain tan and
    save_mesh wrote it uncoloured. "RGB" is now taken as the vertex colours."""
    from stepterrain.export import save_mesh
    from stepterrain.pyvista_accessor import from_polydata

    _, mesh = _coloured_steps()
    path = tmp_path / f"steps{suffix}"
    if suffix == ".ply":  # a PLY of RGB only, as pyvista (VTK) writes one
        poly = pv.PolyData.from_regular_faces(mesh.vertices, mesh.faces)
        poly.point_data["RGB"] = mesh.visual.vertex_colors[:, :3]
        poly.save(path, texture="RGB")
    else:
        save_mesh(mesh, path)
    read = pv.read(path)
    assert "RGB" in read.point_data and read.point_data["RGB"].shape[1] == 3
    back = from_polydata(read)
    assert back.visual.kind == "vertex" and "RGB" not in back.vertex_attributes
    rgb = np.asarray(mesh.visual.vertex_colors)[:, :3]
    # a writer may reorder or duplicate vertices (PLY: float32): each read vertex has the colour of the mesh's there
    nearest = np.array([np.argmin(np.abs(mesh.vertices - v).sum(axis=1)) for v in back.vertices])
    got = np.asarray(back.visual.vertex_colors)[:, :3].astype(int)  # OBJ: floats in [0, 1], read back within 1
    assert np.abs(got - rgb[nearest]).max() <= 1 and np.ptp(got, axis=0).min() > 50  # the level colours, not one
    kwargs = {"window_size": (48, 32)}
    assert np.abs(render.render_mesh(read, **kwargs).astype(int) - render.render_mesh(mesh, **kwargs)).mean() < 2.0


def test_face_colours_go_to_pyvista_and_back(tmp_path):
    """A mesh coloured by face (a PLY or 3MF read back) lost its colours both ways: to_polydata kept vertex colours
    only, and from_polydata (render_mesh(pv.read("faces.ply")), save_mesh of it) took the cell data "RGBA" VTK's PLY
    reader gives as a plain face attribute, so the mesh rendered tan. They are now cell data colours, and back."""
    from stepterrain.export import save_mesh
    from stepterrain.pyvista_accessor import from_polydata, to_polydata

    _, steps = _coloured_steps()
    colours = np.random.default_rng(4).integers(0, 256, (len(steps.faces), 4), dtype=np.uint8)
    colours[:, 3] = 255
    mesh = trimesh.Trimesh(steps.vertices, steps.faces, process=False, face_colors=colours,
                           face_attributes={"level": steps.face_attributes["level"]})
    poly = to_polydata(mesh)
    assert np.array_equal(poly.cell_data["RGBA"], colours) and poly.cell_data.active_scalars_name == RGBA_ALIAS
    assert np.array_equal(poly.cell_data["level"], steps.face_attributes["level"])
    back = from_polydata(poly)
    assert back.visual.kind == "face" and np.array_equal(back.visual.face_colors, colours)
    assert set(back.face_attributes) == {"level"}
    path = tmp_path / "faces.ply"
    save_mesh(mesh, path)
    read = pv.read(path)
    assert np.array_equal(from_polydata(read).visual.face_colors, colours)
    kwargs = {"window_size": (48, 32)}
    expected = render.render_mesh(mesh, **kwargs)
    assert np.array_equal(render.render_mesh(poly, **kwargs), expected)
    # the PLY's float32 points move an edge pixel or two; tan (_DEFAULT_COLOR) differed by far more
    assert np.abs(render.render_mesh(read, **kwargs).astype(int) - expected).mean() < 1.0


def test_a_pyvista_dataset_without_the_accessor_is_not_told_to_step_itself(tmp_path):
    """A MultiBlock (pv.read of a GLB) or an UnstructuredGrid given as a mesh was told to pass "its steps,
    mesh.stepterrain.stepped(...)", an accessor only ImageData, RectilinearGrid and StructuredGrid have (an
    AttributeError for whoever followed it). Only those grids are told so; every dataset is told of its surface."""
    from stepterrain.export import save_mesh

    for dataset in (pv.MultiBlock([pv.Sphere()]), pv.UnstructuredGrid(pv.Sphere())):
        assert not hasattr(dataset, "stepterrain")
        with pytest.raises(InvalidInputError, match=r"pass its surface, mesh\.extract_surface\(\)\.triangulate\(\)\)"):
            save_mesh(dataset, tmp_path / "never.glb")
        assert not (tmp_path / "never.glb").exists()
    with pytest.raises(InvalidInputError, match=r"or its steps, mesh\.stepterrain\.stepped\(\.\.\.\)"):
        render.render_mesh(pv.ImageData(dimensions=(3, 3, 1)), window_size=(48, 32))


def test_to_polydata_gives_a_polydata_of_its_own_not_a_view_of_the_meshs_arrays():
    """to_polydata handed the mesh's own buffers to VTK: exaggerating the PolyData's heights in pyvista's way
    (``poly.points[:, 2] *= 3``, as examples/interactive.py does to its steps) multiplied the Trimesh's too, and a
    GLB saved from it afterwards was exaggerated, without a word; setting the PolyData's colours or levels rewrote
    the mesh's vertex colours and face attributes. pv.wrap copies them. Found by editing the PolyData of a stepped
    mesh and comparing the mesh with a copy made before. Only the connectivity is still shared (VTK does not
    change it in place; see test_to_polydata_hands_the_faces_to_vtk_without_a_padded_copy)."""
    import copy

    import stepterrain as st
    from stepterrain.pyvista_accessor import to_polydata
    from stepterrain.texture import TextureLayer

    heights = np.random.default_rng(5).uniform(0, 90, (30, 40))
    coloured = st.stepped(st.Terrain.from_heights(heights), interval=20, colors="terrain", device="cpu")
    coloured.vertex_attributes["mask_factor"] = np.linspace(0.0, 1.0, len(coloured.vertices), dtype=np.float32)
    coloured.metadata["node_entry"] = np.arange(len(coloured.vertices), dtype=np.int32)
    layer = TextureLayer("luminance", np.linspace(0, 1, 20).reshape(4, 5), (-0.5, 39.5, -0.5, 29.5))
    textured = st.drape(st.stepped(st.Terrain.from_heights(heights), interval=20, device="cpu"), layer)
    for mesh in (coloured, textured):
        before = copy.deepcopy(mesh)
        poly = to_polydata(mesh)
        poly.points[:, 2] *= 3.0
        for data in (poly.point_data, poly.cell_data, poly.field_data):
            for name in data.keys():
                if name != "_PYVISTA_USER_DICT":
                    np.asarray(data[name])[...] = 0
        if poly.active_texture_coordinates is not None:
            poly.active_texture_coordinates[...] = 0.5
        np.testing.assert_array_equal(mesh.vertices, before.vertices)
        np.testing.assert_array_equal(mesh.faces, before.faces)
        for name, values in before.face_attributes.items():
            np.testing.assert_array_equal(mesh.face_attributes[name], values, err_msg=name)
        for name, values in before.vertex_attributes.items():
            np.testing.assert_array_equal(mesh.vertex_attributes[name], values, err_msg=name)
        for name in ("node_entry",):
            if name in before.metadata:
                np.testing.assert_array_equal(mesh.metadata[name], before.metadata[name])
        if mesh.visual.kind == "vertex":
            np.testing.assert_array_equal(mesh.visual.vertex_colors, before.visual.vertex_colors)
        else:
            np.testing.assert_array_equal(mesh.visual.uv, before.visual.uv)
        # and the other way round: the mesh edited in place leaves the PolyData as it was made
        poly = to_polydata(mesh)
        mesh.vertices[:, 2] += 1000.0
        assert poly.points[:, 2].max() < 1000.0


def test_an_elevation_named_array_wins_over_active_scalars_of_another_name():
    """pyvista makes the first array added the active scalars, so ``grid["gamma"] = ...; grid["elevation"] = ...``
    stepped gamma, not the elevation, without a word. An array under one of ELEVATION_NAMES now wins over active
    scalars of another name (elevation="gamma" still steps gamma); several such arrays: the first in that order."""
    heights = np.add.outer(np.arange(5.0) * 7.0, np.arange(6.0) * 3.0)
    grid = pv.ImageData(dimensions=(6, 5, 1))
    grid["gamma"] = np.full(grid.n_points, 0.5)
    grid["elevation"] = heights.ravel()
    assert grid.point_data.active_scalars_name == "gamma"  # the trap: pyvista's choice, not the user's
    np.testing.assert_array_equal(grid.stepterrain.elevation(), heights)
    steps = grid.stepterrain.stepped(interval=5.0, gamma=grid["gamma"])
    assert np.ptp(steps.points[:, 2]) >= 40.0
    np.testing.assert_array_equal(grid.stepterrain.elevation("gamma"), np.full((5, 6), 0.5))
    grid["height"] = heights.ravel() * 2.0  # a second elevation-named array: "elevation" comes first in the order
    np.testing.assert_array_equal(grid.stepterrain.elevation(), heights)
    grid.set_active_scalars("height")  # active scalars under an elevation name are the choice among them
    np.testing.assert_array_equal(grid.stepterrain.elevation(), heights * 2.0)


def test_structured_grid_with_only_another_array_steps_its_points_z_with_a_warning():
    """A StructuredGrid whose heights are its points' z, plus any array (``grid["slope"] = ...``, then the active
    scalars), stepped the slope values: nearly flat terraces, without a word. Its points' z are stepped now, with
    a warning naming the array and ``elevation="slope"``, which still steps it; a flat StructuredGrid (all z equal)
    steps the array as an ImageData does, without a warning."""
    x, y = np.meshgrid(np.linspace(0, 100, 9), np.linspace(0, 60, 7))
    z = 10 * np.sin(x / 30) + y / 3
    grid = pv.StructuredGrid(x, y, z)
    slope = np.abs(np.cos(grid.points[:, 0] / 30.0)) / 3.0  # one value per point, in the grid's point order
    grid["slope"] = slope
    assert grid.point_data.active_scalars_name == "slope"
    with pytest.warns(UserWarning, match=r"points' z.*'slope'.*elevation='slope'"):
        steps = grid.stepterrain.stepped(interval=5.0)
    on = steps.points[:, 2] / 5.0  # γ = 1: every vertex on an isovalue k * 5, over the points' z range
    assert np.allclose(on, np.round(on), atol=1e-5) and np.ptp(steps.points[:, 2]) >= 20.0
    with pytest.warns(UserWarning, match="'slope'"):
        np.testing.assert_array_equal(grid.stepterrain.elevation().ravel(), grid.points[:, 2].astype(np.float32))
    np.testing.assert_array_equal(grid.stepterrain.elevation("slope").ravel(), slope.astype(np.float32))
    flat = pv.StructuredGrid(x, y, np.zeros_like(x))
    flat["data"] = grid.points[:, 2]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(flat.stepterrain.elevation().ravel(), grid.points[:, 2].astype(np.float32))


def test_to_polydata_takes_half_float_attributes_as_float32():
    """A float16 face or vertex attribute (half floats: a compact per-face value) raised VTK's TypeError "Could not
    find a suitable VTK type for float16" from to_polydata (and so from every render and save of the mesh as a
    PolyData); VTK has no half floats: they go to VTK as float32, the same values."""
    from stepterrain.pyvista_accessor import from_polydata, to_polydata

    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 1.0]])
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    per_face = np.array([0.5, 1.5], np.float16)
    per_vertex = np.array([0.25, 2.0, -3.5, 65504.0], np.float16)
    mesh = trimesh.Trimesh(vertices, faces, process=False, face_attributes={"h": per_face},
                           vertex_attributes={"w": per_vertex})
    poly = to_polydata(mesh)
    assert poly.cell_data["h"].dtype == np.float32 and poly.point_data["w"].dtype == np.float32
    np.testing.assert_array_equal(poly.cell_data["h"], per_face.astype(np.float32))
    np.testing.assert_array_equal(poly.point_data["w"], per_vertex.astype(np.float32))
    back = from_polydata(poly)
    np.testing.assert_array_equal(back.face_attributes["h"], per_face.astype(np.float32))
    np.testing.assert_array_equal(back.vertex_attributes["w"], per_vertex.astype(np.float32))


@pytest.mark.parametrize("values", [lambda n: np.array(["wall", "flat"] * (n // 2)),  # strings: kept both ways
                                    lambda n: np.zeros(n, "datetime64[s]"),  # VTK has no such array
                                    lambda n: np.array([None, 1] * (n // 2), object)])  # was drawn as 'None' / '1'
@pytest.mark.parametrize("kind", ["face", "vertex"])
def test_to_polydata_treats_vertex_and_face_attributes_alike(kind, values):
    """A string vertex attribute was dropped without a word while a face one was kept; a datetime face attribute
    raised VTK's TypeError and an object one became its str ('None'), where the vertex ones were dropped silently.
    Now both kinds keep numbers and strings and leave anything else out with a warning naming it."""
    mesh = trimesh.creation.box()
    n = len(mesh.faces) if kind == "face" else len(mesh.vertices)
    array = values(n)
    (mesh.face_attributes if kind == "face" else mesh.vertex_attributes)["tag"] = array
    keep = array.dtype.kind == "U"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        poly = to_polydata(mesh)
    data = poly.cell_data if kind == "face" else poly.point_data
    messages = [str(w.message) for w in caught]
    if keep:
        np.testing.assert_array_equal(np.asarray(data["tag"]), array)
        assert not any("tag" in m for m in messages)
        back = from_polydata(poly)
        np.testing.assert_array_equal((back.face_attributes if kind == "face" else back.vertex_attributes)["tag"],
                                      array)
    else:
        assert "tag" not in data
        assert any(f"{kind} attribute 'tag'" in m and str(array.dtype) in m for m in messages), messages


@pytest.mark.parametrize("values", [lambda n: np.array(["wall", "flat"] * (n // 2), object),  # a pandas column's
                                    lambda n: np.array([b"wall", b"flat"] * (n // 2))])  # bytes
@pytest.mark.parametrize("kind", ["face", "vertex"])
def test_to_polydata_keeps_strings_held_as_objects_or_bytes(kind, values):
    """Strings held in an object array (pandas' string columns) or as bytes are strings: the rule 'numbers and
    strings kept' left them out with a warning (and a face attribute of them had been kept before it)."""
    mesh = trimesh.creation.box()
    n = len(mesh.faces) if kind == "face" else len(mesh.vertices)
    array = values(n)
    (mesh.face_attributes if kind == "face" else mesh.vertex_attributes)["tag"] = array
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        poly = to_polydata(mesh)
    assert not any("tag" in str(w.message) for w in caught)
    expected = np.array([v.decode() if isinstance(v, bytes) else v for v in array])
    np.testing.assert_array_equal(np.asarray((poly.cell_data if kind == "face" else poly.point_data)["tag"]),
                                  expected)
    back = from_polydata(poly)
    np.testing.assert_array_equal((back.face_attributes if kind == "face" else back.vertex_attributes)["tag"],
                                  expected)


@pytest.mark.parametrize("kind", ["face", "vertex"])
def test_to_polydata_leaves_out_complex_attributes_of_several_components(kind):
    """A complex attribute of two components a face or vertex raised pyvista's ValueError ("Complex data must be
    single dimensional") out of to_polydata; now it is left out with a warning naming it, and a one-component complex
    attribute beside it is kept as it is."""
    mesh = trimesh.creation.box()
    n = len(mesh.faces) if kind == "face" else len(mesh.vertices)
    attributes = mesh.face_attributes if kind == "face" else mesh.vertex_attributes
    attributes["pair"] = np.arange(2 * n).reshape(n, 2) * (1 + 2j)
    attributes["one"] = np.arange(n) * (1 - 1j)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        poly = to_polydata(mesh)
    data = poly.cell_data if kind == "face" else poly.point_data
    assert "pair" not in data
    np.testing.assert_array_equal(np.asarray(data["one"]), attributes["one"])
    messages = [str(w.message) for w in caught]
    assert any(f"{kind} attribute 'pair'" in m and "complex128" in m for m in messages), messages
    assert not any("'one'" in m for m in messages), messages


def test_a_stepped_polydata_gives_its_buffers_back_when_it_goes_without_a_collection():
    """``grid.stepterrain.stepped`` steps into a Trimesh whose large arrays are lent from the output pool and hands
    shares them with the PolyData (no copy); the Trimesh refers to itself (visuals, ray, permutate, nearest), so left
    to the cyclic collector it kept the loans after the PolyData was gone: a slider re-stepping the sample DEM took
    fresh memory every call (220 MB a call, 0.3-0.7 s against 0.05-0.08 s from the pool). Now the loans return as the
    PolyData goes, with the collector off, and the PolyData is the mesh ``stepped`` makes."""
    import gc

    import stepterrain as st
    from stepterrain import _device

    heights = np.asarray(st.sample_dem().heights)[:600, :600]
    grid = pv.ImageData(dimensions=(600, 600, 1), spacing=(30, 30, 1))
    grid["elevation"] = heights[::-1].ravel()
    expected = st.stepped(heights[::-1], interval=20.0, spacing=(30.0, 30.0))  # an ImageData's rows run south-north
    gc.collect()
    gc.disable()
    try:
        lent = _device.OUTPUTS._lent
        steps = grid.stepterrain.stepped(interval=20.0)
        assert _device.OUTPUTS._lent > lent  # its arrays are on loan (large enough for the pool)
        points = np.array(steps.points, dtype=np.float64)
        del steps
        assert _device.OUTPUTS._lent == lent
    finally:
        gc.enable()
    np.testing.assert_array_equal(points, expected.vertices)


@pytest.mark.parametrize("kind", ["scene", "pointcloud", "polydata", "none"])
def test_to_polydata_refuses_what_is_no_trimesh_by_name(kind):
    """to_polydata of a Scene (trimesh.load's of a GLB), a PointCloud, a PolyData or None raised trimesh's or Python's
    AttributeError ("'Scene' object has no attribute 'faces'"), naming no argument."""
    tri = trimesh.Trimesh([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]], [[0, 1, 2]], process=False)
    given = {"scene": trimesh.Scene(tri), "pointcloud": trimesh.PointCloud(tri.vertices),
             "polydata": to_polydata(tri), "none": None}[kind]
    with pytest.raises(InvalidInputError, match=r"mesh must be a trimesh\.Trimesh; got .*"
                       + {"scene": "Scene.*read_mesh", "pointcloud": "PointCloud", "polydata": "PolyData",
                          "none": "NoneType"}[kind]):
        to_polydata(given)


def test_from_polydata_of_points_or_lines_names_delaunay_2d_and_counts_in_the_singular():
    """A PolyData of points (pv.PolyData(points) makes a vertex cell of each) was refused with "make triangles of
    them with mesh.triangulate()", which drops vertex cells and lines and gives an empty mesh; such a PolyData is
    refused naming delaunay_2d(), whose TIN converts. Counts of one were plural ("got 1 lines")."""
    from stepterrain.pyvista_accessor import from_polydata

    rng = np.random.default_rng(5)
    points = pv.PolyData(np.column_stack([rng.random((30, 2)) * 100.0, rng.random(30) * 10.0]))
    lines = pv.MultipleLines([(0.0, 0.0, 0.0), (10.0, 0.0, 1.0), (10.0, 10.0, 2.0)])  # one polyline (a contour)
    for poly, found in ((points, "30 vertex cells"), (lines, "1 line"),
                        (points.merge(lines), "30 vertex cells, 1 line")):
        with pytest.raises(InvalidInputError) as caught:
            from_polydata(poly)
        assert str(caught.value) == (f"mesh must be a PolyData of triangles only; got {found} and no faces, so "
                                     "mesh.triangulate() makes nothing of it; mesh.delaunay_2d() makes a TIN "
                                     "(triangles) of its points")
        assert poly.triangulate().n_cells == 0  # what the old advice gave
        tin = from_polydata(poly.delaunay_2d())  # what the new one gives: a TIN over the points' convex hull
        assert len(tin.faces) > 0 and tin.area > 0
    # faces besides: triangulate() kept a line beside triangles (VTK's filter), and the vertex cells and lines are
    # numbered first, so the advice removes them, then makes triangles of the rest
    sphere, quad = pv.Sphere(), pv.Plane(i_resolution=1, j_resolution=1)
    for mixed, found in ((sphere.merge(lines), "1 line"), (quad.merge(points), "30 vertex cells, 1 polygon of 4"),
                         (quad.merge(points).merge(lines), "30 vertex cells, 1 line, 1 polygon of 4")):
        with pytest.raises(InvalidInputError, match=rf"got {found}.*\(mesh\.remove_cells\(range\(mesh\.n_verts \+ "
                                                    r"mesh\.n_lines\)\)\.triangulate\(\) keeps its faces alone"):
            from_polydata(mixed)
        fixed = from_polydata(mixed.remove_cells(range(mixed.n_verts + mixed.n_lines)).triangulate())
        assert len(fixed.faces) == (sphere.n_cells if mixed.n_points > 100 else 2)
    assert sphere.merge(lines).triangulate().n_lines == 1  # the old advice left the line
    with pytest.raises(InvalidInputError, match=r"got 2 polygons of 4 or more corners \(mesh\.triangulate\(\) makes "
                                                r"triangles of them\)$"):
        from_polydata(pv.Plane(i_resolution=2, j_resolution=1))


@pytest.mark.parametrize("kind", ["point", "cell"])
@pytest.mark.parametrize("name", [RGBA_ALIAS, "RGBA", "RGB", "height_rgb"])
def test_from_polydata_takes_float_and_wide_integer_colours_as_pyvista_plots_them(kind, name):
    """from_polydata took colours of uint8 only: poly["colors_rgba"] = floats in [0, 1] (which poly.plot() shows as
    colours, VTK's direct colour mode) stayed a plain attribute, so render_mesh(poly) drew the plain tan and save_mesh
    wrote it uncoloured; int64 colours in [0, 255] (np.array of Python ints) alike. Floats in [0, 1] and whole numbers
    in [0, 255] are the colours (uint8, rounded); anything else stays an attribute."""
    from stepterrain.pyvista_accessor import from_polydata

    poly = pv.Sphere(theta_resolution=8, phi_resolution=6)
    count = poly.n_points if kind == "point" else poly.n_cells
    columns = 3 if name.endswith(("RGB", "_rgb")) else 4
    expected = np.random.default_rng(5).integers(0, 256, (count, columns), dtype=np.uint8)
    data = poly.point_data if kind == "point" else poly.cell_data
    for values in (expected / 255.0, expected.astype(np.float32) / 255, expected.astype(np.int64)):
        data[name] = values
        data.active_scalars_name = name
        back = from_polydata(poly)
        assert back.visual.kind == ("vertex" if kind == "point" else "face")
        colours = back.visual.vertex_colors if kind == "point" else back.visual.face_colors
        assert np.array_equal(colours[:, :columns], expected)
        assert name not in back.vertex_attributes and name not in back.face_attributes
    for values in (expected / 255.0 * 2.0, -expected.astype(np.int64) - 1, np.full((count, columns), np.nan)):
        data[name] = values  # not colours: a plain attribute, as before
        back = from_polydata(poly)
        assert back.visual.kind is None
        assert np.array_equal((back.vertex_attributes if kind == "point" else back.face_attributes)[name], values,
                              equal_nan=True)


def test_bool_attributes_and_metadata_arrays_come_back_from_pyvista_as_bools():
    """to_polydata cast bool attributes to uint8 itself, so from_polydata gave every one but ``wall`` back as 0/1
    numbers: a mask face attribute, ``mesh.faces[back.face_attributes["mask"]]``, indexed rows 0 and 1 instead of
    selecting the masked faces. Bools go to pyvista as they are (uint8 in VTK, read back as bool), in both ways."""
    from stepterrain.pyvista_accessor import from_polydata, to_polydata

    _, steps = _coloured_steps()
    mesh = steps.copy()
    rng = np.random.default_rng(6)
    mask = rng.random(len(mesh.faces)) < 0.3
    mesh.face_attributes["mask"] = mask
    mesh.face_attributes["flags"] = rng.random((len(mesh.faces), 2)) < 0.5
    mesh.vertex_attributes["seen"] = rng.random(len(mesh.vertices)) < 0.5
    mesh.metadata["node_mask"] = rng.random(5000) < 0.5  # too long for user_dict: a field_data array
    poly = to_polydata(mesh)
    assert poly.cell_data["mask"].dtype == bool and poly.cell_data["wall"].dtype == bool
    assert poly.cell_data.GetArray("mask").GetDataTypeAsString() == "unsigned char"  # VTK's own type
    back = from_polydata(poly)
    for name in ("mask", "flags", "wall"):
        assert back.face_attributes[name].dtype == bool
        assert np.array_equal(back.face_attributes[name], mesh.face_attributes[name])
    assert back.vertex_attributes["seen"].dtype == bool
    assert np.array_equal(back.vertex_attributes["seen"], mesh.vertex_attributes["seen"])
    assert back.metadata["node_mask"].dtype == bool and np.array_equal(back.metadata["node_mask"],
                                                                        mesh.metadata["node_mask"])
    assert np.array_equal(back.faces[back.face_attributes["mask"]], mesh.faces[mask])
    stepped_poly = pv.ImageData(dimensions=(6, 5, 1))
    stepped_poly["elevation"] = np.arange(30.0)
    assert stepped_poly.stepterrain.stepped(interval=4.0).cell_data["wall"].dtype == bool  # the accessor's, shared


@pytest.mark.parametrize("kind", ["vertex", "face"])
@pytest.mark.parametrize("shape", [(0,), (2, 0)])
def test_to_polydata_leaves_out_attributes_with_no_values_by_name(kind, shape):
    """An attribute of no values per vertex or face, (N, 0), raised pyvista's ValueError ("Empty arrays are not
    allowed") out of to_polydata, naming no argument (and render_mesh and save_mesh of such a mesh with it). VTK holds
    no array of zero components: it is left out with a warning naming it, the other attributes kept."""
    mesh = trimesh.creation.box()
    count = len(mesh.vertices) if kind == "vertex" else len(mesh.faces)
    attributes = mesh.vertex_attributes if kind == "vertex" else mesh.face_attributes
    attributes["empty"] = np.zeros((count, *shape))
    attributes["kept"] = np.arange(count, dtype=np.float64)
    with pytest.warns(UserWarning, match=rf"{kind} attribute 'empty' \(float64 of shape \({count}, {shape[0]}"):
        poly = to_polydata(mesh)
    data = poly.point_data if kind == "vertex" else poly.cell_data
    assert "empty" not in data and np.array_equal(data["kept"], np.arange(count))


def test_float_colours_round_as_vtk_maps_them_halves_up():
    """Float colours were rounded half to even (np.rint): a float64 value on an exact half, c = (2k + 1) / 510 for an
    even k, became k where VTK's direct colour mode (how pyvista plots the same array) gives k + 1, as it computes
    floor(c * 255 + 0.5) in double. Checked against VTK's own mapping, vtkLookupTable.MapScalars in direct mode, on
    every half and on random float64 and float32 colours."""
    import vtk
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy

    from stepterrain.pyvista_accessor import _uint8_colours

    rng = np.random.default_rng(7)
    halves = np.repeat((np.arange(511) / 510.0)[:, None], 3, axis=1)
    for values in (halves, rng.random((2000, 4)), rng.random((2000, 3)).astype(np.float32)):
        source = numpy_to_vtk(np.ascontiguousarray(values), deep=1)
        mapped = vtk.vtkLookupTable().MapScalars(source, vtk.VTK_COLOR_MODE_DIRECT_SCALARS, -1)
        expected = vtk_to_numpy(mapped)[:, : values.shape[1]]
        assert np.array_equal(_uint8_colours(values), expected)
    poly = pv.Sphere(theta_resolution=6, phi_resolution=4)
    poly["colors_rgba"] = np.full((poly.n_points, 4), 5 / 510)  # 2.5: VTK's 3, np.rint's 2
    assert np.array_equal(from_polydata(poly).visual.vertex_colors, np.full((poly.n_points, 4), 3))


def test_from_polydata_refuses_strips_beside_triangles_not_dropping_them():
    """A PolyData of triangles and triangle strips (what VTK's vtkStripper makes of a surface, with the triangles it
    could not strip) passed as all triangles (pyvista's is_all_triangles looks at the polygons alone): from_polydata
    returned the triangles alone, the strips' faces lost without a word, and a cell-data array of one value per cell
    became a face attribute longer than the faces. Strips are refused with the triangulate() advice, as strips
    alone are; triangulated, every face comes back."""
    sphere = pv.Sphere(theta_resolution=8, phi_resolution=6)
    stripped = sphere.strip()
    poly = stripped.merge(pv.PolyData(sphere.points, faces=[3, 0, 1, 2]), merge_points=False)
    assert poly.n_strips and poly.GetNumberOfPolys() == 1
    poly.cell_data["id"] = np.arange(poly.n_cells)
    with pytest.raises(InvalidInputError, match=r"got \d+ strips? \(mesh\.triangulate\(\) makes triangles"):
        from_polydata(poly)
    back = from_polydata(poly.triangulate())
    assert len(back.faces) == sphere.n_cells + 1 and len(back.face_attributes["id"]) == len(back.faces)
    assert back.area == pytest.approx(sphere.area + trimesh.Trimesh(sphere.points[:3], [[0, 1, 2]]).area)


@pytest.mark.parametrize("isovalues", [["low", "high"], [[0.0, 10.0], [20.0]], {"step": 10.0}])
def test_to_polydata_keeps_isovalues_metadata_that_is_not_numbers_as_any_other_item(isovalues):
    """to_polydata put metadata["isovalues"] into field data as float64 whatever it held: strings or a ragged list
    (a GLB's extras written by another tool) raised numpy's ValueError, a dict its TypeError, out of to_polydata
    (and out of render_mesh and save_mesh of the PolyData's way back), naming nothing. Numbers still go to field
    data; anything else is an item as any other, in user_dict and back."""
    mesh = trimesh.creation.box()
    mesh.metadata["isovalues"] = isovalues
    poly = to_polydata(mesh)
    assert "isovalues" not in poly.field_data
    assert from_polydata(poly).metadata["isovalues"] == isovalues


def test_to_polydata_leaves_out_a_metadata_array_with_no_values_per_row_by_name():
    """A metadata array too long for user_dict went to field data as it was: one of shape (N, 0) raised pyvista's
    ValueError ("Empty arrays are not allowed") out of to_polydata. It is left out with the warning other
    metadata VTK cannot hold get; the other items are kept."""
    mesh = trimesh.creation.box()
    mesh.metadata.update(empty=np.zeros((20000, 0)), node_entry=np.arange(20000))
    with pytest.warns(UserWarning, match=r"metadata items \['empty'\]"):
        poly = to_polydata(mesh)
    back = from_polydata(poly)
    assert "empty" not in back.metadata and np.array_equal(back.metadata["node_entry"], np.arange(20000))


def test_to_polydata_keeps_the_empty_attributes_of_a_mesh_with_no_faces_without_a_warning():
    """The (N, 0) check left out every attribute of no values: a mesh with no faces had its face attributes of
    shape (0,) (one value a face, none) left out with a warning, though VTK holds them (an empty array for no cells),
    as it did before. An attribute of no values per element is still left out, by name."""
    mesh = trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
    mesh.face_attributes["level"] = np.zeros(0, dtype=np.int64)
    mesh.face_attributes["rgb"] = np.zeros((0, 3))  # pyvista refuses it: left out
    with pytest.warns(UserWarning, match=r"face attribute 'rgb' \(float64 of shape \(0, 3\)\) left out") as caught:
        poly = to_polydata(mesh)
    assert not any("'level'" in str(w.message) for w in caught)
    assert poly.cell_data["level"].shape == (0,) and "rgb" not in poly.cell_data


@pytest.mark.parametrize("bad", [7, -1])
def test_faces_outside_the_vertices_are_refused_by_name_both_ways(bad):
    """to_polydata of a ``process=False`` Trimesh whose faces index past its vertices (or -1) handed the indices to
    VTK as they were: the PolyData's compute_normals(), clean() and decimate() then crashed Python with a
    segmentation fault. from_polydata of such a PolyData gave a Trimesh whose first use raised numpy's IndexError.
    Found by feeding both hand-made meshes. Now both name the argument and the offending face."""
    points = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]])
    mesh = trimesh.Trimesh(points, [[0, 1, 2], [0, 1, bad]], process=False)
    with pytest.raises(InvalidInputError, match=rf"mesh faces must index its 3 vertices .*face 1 is \[0, 1, {bad}\]"):
        to_polydata(mesh)
    poly = pv.PolyData(points, faces=[3, 0, 1, 2, 3, 0, 1, bad])
    with pytest.raises(InvalidInputError, match=rf"steps faces must index its 3 points .*face 1 is \[0, 1, {bad}\]"):
        from_polydata(poly, name="steps")


@pytest.mark.parametrize("kind", ["vertex", "face"])
@pytest.mark.parametrize("name", ["RGBA", RGBA_ALIAS])
def test_an_attribute_under_a_colour_name_of_a_coloured_mesh_is_left_out_with_a_warning(kind, name):
    """A coloured mesh with an attribute of its own named "RGBA" or "colors_rgba" (a scalar field, other colours)
    lost it without a word: to_polydata wrote the colours over it. The colours win (they are what the PolyData's
    plot and from_polydata read), and the attribute left out is named in a warning; one holding those very colours
    (a mesh from pv.to_trimesh) is no loss and passes without one."""
    box = trimesh.creation.box()
    count = len(box.vertices) if kind == "vertex" else len(box.faces)
    colours = np.random.default_rng(1).integers(0, 256, (count, 4), dtype=np.uint8)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False, **{f"{kind}_colors": colours})
    getattr(mesh, f"{kind}_attributes")[name] = np.arange(count, dtype=np.float64)
    getattr(mesh, f"{kind}_attributes")["kept"] = np.arange(count, dtype=np.int16)
    with pytest.warns(UserWarning, match=rf"{kind} attribute '{name}' .*left out.*the mesh's {kind} colours"):
        back = from_polydata(to_polydata(mesh))
    assert np.array_equal(getattr(back.visual, f"{kind}_colors"), colours)
    assert list(getattr(back, f"{kind}_attributes")) == ["kept"]
    getattr(mesh, f"{kind}_attributes")[name] = colours.copy()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = from_polydata(to_polydata(mesh))
    assert np.array_equal(getattr(back.visual, f"{kind}_colors"), colours)


@pytest.mark.parametrize("name", ["RGB", "RGBA", "height_rgb"])
def test_face_colours_come_back_as_face_colours_beside_a_colour_named_vertex_attribute(name):
    """A mesh coloured by face with a vertex attribute named "RGB" ("RGBA", "*_rgb": colour-like uint8 values) came
    back from from_polydata(to_polydata(mesh)) coloured by vertex with that attribute, its face colours turned into
    face attributes "RGBA" and "colors_rgba": from_polydata looked at point data before cell data whatever the
    names. Now the strongest colour name wins wherever it is (colors_rgba, then RGBA, then RGB, then active
    scalars named *_rgb/*_rgba; point data first at one name), so to_polydata's colours are found; the vertex
    attribute comes back as it was."""
    box = trimesh.creation.box()
    face_colours = np.random.default_rng(2).integers(0, 256, (len(box.faces), 4), dtype=np.uint8)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False, face_colors=face_colours)
    values = np.random.default_rng(3).integers(0, 256, (len(box.vertices), 3), dtype=np.uint8)
    mesh.vertex_attributes[name] = values
    back = from_polydata(to_polydata(mesh))
    assert back.visual.kind == "face"
    assert np.array_equal(back.visual.face_colors, face_colours)
    assert list(back.vertex_attributes) == [name] and np.array_equal(back.vertex_attributes[name], values)
    assert list(back.face_attributes) == []


def test_a_vertex_attribute_under_the_colour_alias_of_a_mesh_coloured_by_face_is_left_out_with_a_warning():
    """Beside colours by face (cell data "colors_rgba"), a vertex attribute "colors_rgba" of colour-like values was
    read back by from_polydata as vertex colours, the face colours turned into face attributes. It is left out with
    a warning, as one of the face colours' names; the face colours come back."""
    box = trimesh.creation.box()
    face_colours = np.random.default_rng(4).integers(0, 256, (len(box.faces), 4), dtype=np.uint8)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False, face_colors=face_colours)
    mesh.vertex_attributes[RGBA_ALIAS] = np.full((len(box.vertices), 4), 9, np.uint8)
    with pytest.warns(UserWarning, match=rf"vertex attribute '{RGBA_ALIAS}' left out: the mesh's face colours"):
        back = from_polydata(to_polydata(mesh))
    assert back.visual.kind == "face" and np.array_equal(back.visual.face_colors, face_colours)
    assert list(back.vertex_attributes) == [] and list(back.face_attributes) == []


_DTYPES = [np.bool_, np.int8, np.int16, np.int32, np.int64, np.uint8, np.uint16, np.uint32, np.uint64, np.float16,
           np.float32, np.float64]
_COLOUR_NAMES = ("RGB", "RGBA", RGBA_ALIAS, "x_rgb")


@st.composite
def _meshes(draw):
    """Trimeshes of 0 to 8 vertices (unreferenced ones too), 0 to 6 faces, colours by vertex (uint8 or float, RGB or
    RGBA) or by face or none, vertex and face attributes of every dtype VTK holds, (N,) and (N, k), some under the
    colours' names, and JSON metadata."""
    count = draw(st.integers(0, 8))
    vertices = draw(hnp.arrays(np.float64, (count, 3), elements=st.floats(-1e3, 1e3)))
    faces = draw(hnp.arrays(np.int64, (draw(st.integers(0, 6)) if count else 0, 3),
                            elements=st.integers(0, max(count - 1, 0))))
    colour = draw(st.sampled_from([None, "vertex", "face"]))
    rows = {"vertex": count, "face": len(faces)}
    kw = {}
    if colour is not None and rows[colour]:
        dtype = draw(st.sampled_from([np.uint8, np.float64])) if colour == "vertex" else np.uint8
        elements = st.floats(0, 1) if dtype == np.float64 else None
        kw[f"{colour}_colors"] = draw(hnp.arrays(dtype, (rows[colour], draw(st.sampled_from([3, 4]))),
                                                 elements=elements))
    mesh = trimesh.Trimesh(vertices, faces, process=False, **kw)
    for kind, n in rows.items():
        for i in range(draw(st.integers(0, 3))):
            dtype = draw(st.sampled_from(_DTYPES))
            name = draw(st.sampled_from([f"{kind}{i}", *_COLOUR_NAMES]))
            shape = draw(st.sampled_from([(n,), (n, 2), (n, 3), (n, 4)] if n else [(0,)]))
            getattr(mesh, f"{kind}_attributes")[name] = draw(hnp.arrays(dtype, shape))
    mesh.metadata.update(draw(st.dictionaries(
        st.text("abxyz", min_size=1, max_size=3), st.one_of(st.integers(-2**60, 2**60), st.floats(allow_nan=False),
                                                           st.text(max_size=4), st.booleans(), st.none(),
                                                           st.lists(st.integers(-5, 5), max_size=3)), max_size=3)))
    return mesh


@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
@given(_meshes())
def test_to_polydata_and_back_gives_the_mesh_back(mesh):
    """from_polydata(to_polydata(mesh)) gives back the vertices, faces, colours, attributes (dtypes kept; half floats
    as float32) and metadata (JSON values, an infinity as None) of the mesh, with the documented exceptions: an
    attribute under the colours' names of a coloured mesh is left out with a warning naming it, and of an uncoloured
    mesh one holding colour values comes back as the colours (pv.to_trimesh's way)."""
    coloured = mesh.visual.kind if mesh.visual.kind in ("vertex", "face") else None
    colours = None if coloured is None else getattr(mesh.visual, f"{coloured}_colors").copy()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        back = from_polydata(to_polydata(mesh))
    said = " ".join(str(w.message) for w in caught if "left out" in str(w.message))
    assert np.array_equal(back.vertices, mesh.vertices) and np.array_equal(back.faces, mesh.faces)
    if coloured is not None:
        assert back.visual.kind == coloured
        assert np.array_equal(getattr(back.visual, f"{coloured}_colors"), colours)
    for kind in ("vertex", "face"):
        before, after = getattr(mesh, f"{kind}_attributes"), getattr(back, f"{kind}_attributes")
        left_out = {n for n in before if f"{kind} attribute {n!r}" in said}
        assert left_out <= set(_COLOUR_NAMES) and (not left_out or coloured is not None)
        read_as_colours = set(before) - set(after) - left_out
        if read_as_colours:  # one array, of the uncoloured mesh, of the kind that came back coloured
            assert coloured is None and back.visual.kind == kind and len(read_as_colours) == 1
            assert read_as_colours <= set(_COLOUR_NAMES)
        assert set(after) == set(before) - left_out - read_as_colours
        for name, values in after.items():
            expected = before[name].astype(np.float32) if before[name].dtype == np.float16 else before[name]
            assert values.dtype == expected.dtype and values.shape == expected.shape, name
            assert np.array_equal(values, expected, equal_nan=expected.dtype.kind == "f"), name
    for key, value in mesh.metadata.items():
        assert back.metadata[key] == (None if isinstance(value, float) and not np.isfinite(value) else value)


@pytest.mark.parametrize("kind", ["vertex", "face"])
def test_to_polydata_leaves_out_an_attribute_not_named_by_a_str_with_a_warning(kind):
    """An attribute named by a number (``mesh.vertex_attributes[5] = ...``, as trimesh allows) raised pyvista's
    TypeError "Only strings are valid keys for DataSetAttributes" out of to_polydata, naming no argument, so the mesh
    could not go to pyvista at all. It is left out with a warning naming it, as metadata keys that are no str are;
    the other attributes go."""
    box = trimesh.creation.box()
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False)
    attributes = getattr(mesh, f"{kind}_attributes")
    count = len(box.vertices) if kind == "vertex" else len(box.faces)
    attributes[5] = np.arange(count)
    attributes["kept"] = np.arange(count) * 2.0
    with pytest.warns(UserWarning, match=rf"{kind} attribute 5 left out: .*named by a str"):
        back = from_polydata(to_polydata(mesh))
    assert list(getattr(back, f"{kind}_attributes")) == ["kept"]


@pytest.mark.parametrize("values", [np.array(["Zürich", "Bern", "Genève"]),
                                    np.array(["Zürich", "Bern", "Genève"], object),
                                    np.array([b"\xff", b"ab", b"c"])], ids=["str", "object", "bytes"])
@pytest.mark.parametrize("kind", ["vertex", "face"])
def test_to_polydata_leaves_out_non_ascii_string_attributes_with_a_warning(kind, values):
    """A string attribute with a character past ASCII (a place name) raised pyvista's ValueError "String array
    contains non-ASCII characters that are not supported by VTK" out of to_polydata, bytes past ASCII a
    UnicodeDecodeError, naming no argument: the mesh could not go to pyvista at all. Such an attribute is left out
    with a warning naming it, as other arrays VTK holds not; ASCII strings still go and come back."""
    points = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]])
    mesh = trimesh.Trimesh(points, [[0, 1, 2], [0, 2, 1], [1, 2, 0]], process=False)
    attributes = getattr(mesh, f"{kind}_attributes")
    attributes["name"] = values
    attributes["code"] = np.array(["ZH", "BE", "GE"])
    with pytest.warns(UserWarning, match=rf"{kind} attribute 'name' \(.*non-ASCII"):
        back = from_polydata(to_polydata(mesh))
    assert list(getattr(back, f"{kind}_attributes")) == ["code"]
    assert getattr(back, f"{kind}_attributes")["code"].tolist() == ["ZH", "BE", "GE"]


def test_to_polydata_takes_big_endian_half_floats_as_float32():
    """Half floats in big-endian order (``>f2``, as a file's bytes read with np.frombuffer give them) raised VTK's
    TypeError "Could not find a suitable VTK type for >f2" out of to_polydata: only the native float16 dtype went to
    float32. Other big-endian arrays went (pyvista swaps them). Found by fuzzing attribute dtypes and byte orders."""
    box = trimesh.creation.box()
    values = np.arange(len(box.vertices)).astype(">f2") / 4
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False, vertex_attributes={"h": values})
    mesh.metadata["long"] = np.linspace(0, 1, 10_000).astype(">f2")  # a field_data array, past glTF extras' length
    back = from_polydata(to_polydata(mesh))
    assert back.vertex_attributes["h"].dtype == np.float32
    np.testing.assert_array_equal(back.vertex_attributes["h"], values.astype(np.float32))
    np.testing.assert_array_equal(back.metadata["long"], mesh.metadata["long"].astype(np.float32))


@pytest.mark.parametrize(("dtype", "expected"), [(np.longdouble, np.float64), (np.clongdouble, np.complex128),
                                                 (">c16", np.complex128), (">c8", np.complex64), (">U2", np.str_)])
def test_to_polydata_takes_long_double_and_big_endian_complex_and_string_attributes(dtype, expected):
    """A long double attribute raised VTK's TypeError "Could not find a suitable VTK type for float128", a long
    double or big-endian complex one pyvista's ValueError "Only numpy.complex64 or numpy.complex128 is supported",
    and big-endian strings (ASCII) its ValueError "String array contains non-ASCII characters", all out of
    to_polydata. Found by fuzzing attribute dtypes and byte orders. Long doubles go as float64 (complex128): VTK
    holds no wider floats; the others in native order, the same values."""
    box = trimesh.creation.box()
    values = (np.arange(len(box.vertices)) * 3 // 2).astype(dtype)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False)
    mesh.vertex_attributes["a"] = values
    mesh.face_attributes["b"] = np.repeat(values[:6], 2)
    back = from_polydata(to_polydata(mesh))
    for got, sent in ((back.vertex_attributes["a"], values), (back.face_attributes["b"], mesh.face_attributes["b"])):
        assert got.dtype.type is np.dtype(expected).type and got.dtype.isnative
        assert got.tolist() == sent.astype(expected).tolist()


@pytest.mark.parametrize("kind", ["vertex", "face"])
def test_a_complex_attribute_of_one_vertex_or_face_comes_back_one_value_long(kind):
    """pyvista reads a complex array of one value back as a 0-d array: from_polydata gave a mesh of one face (or
    vertex) a complex attribute of shape (), no value per face, which indexing by face refused. Found by fuzzing
    attribute dtypes over meshes of one to six vertices. It comes back of shape (1,), as it went."""
    mesh = trimesh.Trimesh([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    values = np.array([2 + 3j] * (1 if kind == "face" else 3), np.complex64)
    if kind == "vertex":
        mesh = trimesh.Trimesh(mesh.vertices[:1], np.zeros((0, 3), int), process=False)
        values = values[:1]
    getattr(mesh, f"{kind}_attributes")["z"] = values
    back = getattr(from_polydata(to_polydata(mesh)), f"{kind}_attributes")["z"]
    assert back.shape == (1,) and back.dtype == np.complex64 and back.tolist() == [2 + 3j]


@pytest.mark.parametrize("kind", ["image", "structured"])
def test_a_gamma_array_of_neither_shape_is_refused_naming_both_the_accessor_takes(kind):
    """The accessor takes a per-node γ as (H, W) or as one value per point (N,), on every grid; an array of another
    shape was refused with stepped()'s message, which names one of the two (the (H, W) of a grid Terrain, the (N,) of
    a TIN) as the only shape, so a pyvista user told "must be shape (4, 5)" of an ImageData did not learn that
    grid["gamma"] (N,) goes too. Both are named now, with the grid's dimensions."""
    x, y = np.meshgrid(np.arange(5) * 10.0, np.arange(4) * 10.0)
    grid = pv.ImageData(dimensions=(5, 4, 1), spacing=(10, 10, 1)) if kind == "image" else pv.StructuredGrid(
        x, y, np.zeros_like(x))
    grid["elevation"] = np.arange(20.0)
    nx, ny, _ = grid.dimensions
    with pytest.raises(InvalidInputError, match=rf"gamma must be one γ per node, shape \({ny}, {nx}\) or \(20,\) "
                                                r".*got shape \(7,\)"):
        grid.stepterrain.stepped(interval=2.0, gamma=np.full(7, 0.5))
    assert grid.stepterrain.stepped(interval=2.0, gamma=np.full(20, 0.5)).n_cells > 0


@pytest.mark.parametrize("kind", ["vertex", "face"])
def test_to_polydata_leaves_out_an_attribute_named_by_the_empty_string_with_a_warning(kind):
    """An attribute named "" (trimesh allows it) went to VTK as an unnamed array, which pyvista names "Unnamed_0": it
    came back from from_polydata under a name it never had, without a word. It is left out with a warning naming
    it, as an attribute not named by a str is; a numeric metadata array under "" (a field_data array) likewise."""
    box = trimesh.creation.box()
    count = len(box.vertices) if kind == "vertex" else len(box.faces)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False, metadata={"": np.arange(5000)})
    getattr(mesh, f"{kind}_attributes")[""] = np.arange(count) * 1.5
    getattr(mesh, f"{kind}_attributes")["kept"] = np.arange(count) * 2.0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        back = from_polydata(to_polydata(mesh))
    said = " ".join(str(w.message) for w in caught)
    assert f"{kind} attribute '' left out" in said and "mesh.metadata items ['']" in said
    assert list(getattr(back, f"{kind}_attributes")) == ["kept"]
    assert not any(str(key).startswith("Unnamed") for key in back.metadata)


def test_to_polydata_keeps_a_vertex_attribute_named_texture_coordinates_beside_the_uvs():
    """pyvista stores the active texture coordinates under "Texture Coordinates": a textured mesh's vertex attribute
    of that name was written over by its UVs, without a word, and from_polydata then passed it over as the texture
    coordinates. The UVs go under another name when that one is taken, so both reach the PolyData and the attribute
    comes back as it was."""
    from PIL import Image

    box = trimesh.creation.box()
    uv = np.random.default_rng(1).random((len(box.vertices), 2))
    own = np.arange(len(box.vertices) * 2, dtype=np.float64).reshape(-1, 2) + 10.0
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (2, 2))),
                           vertex_attributes={"Texture Coordinates": own})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing left out
        poly = to_polydata(mesh)
    assert np.array_equal(poly.active_texture_coordinates, uv)
    assert np.array_equal(poly.point_data["Texture Coordinates"], own)
    back = from_polydata(poly)
    assert list(back.vertex_attributes) == ["Texture Coordinates"]
    assert np.array_equal(back.vertex_attributes["Texture Coordinates"], own)


def test_to_polydata_and_from_polydata_pass_non_finite_points_alike():
    """Both ways treat NaN and infinite points alike (pinned: a brief said to_polydata refused NaN points and
    from_polydata did not; neither does, and refusing in from_polydata would make render_mesh of a PolyData refuse
    what render_mesh of its Trimesh renders, NaN vertices being nodata left out of the picture). Points come back
    bit for bit, and the renderer's framing takes the PolyData's Trimesh as it takes the Trimesh."""
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0], [1, 1, np.inf]])
    faces = np.array([[0, 1, 2], [1, 3, 2], [1, 4, 2]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    poly = to_polydata(mesh)
    assert np.array_equal(np.asarray(poly.points), vertices, equal_nan=True)
    back = from_polydata(pv.PolyData.from_regular_faces(vertices, faces))
    assert np.array_equal(back.vertices, vertices, equal_nan=True)
    finite = trimesh.Trimesh(vertices[:4], faces[:2], process=False)
    for argument in (finite, to_polydata(finite)):
        framed = render._frame_mesh(render.mesh_argument(argument), (64, 64), 1.0, None, "oblique")
        assert framed[4].tolist() == [True, True, True, False]
