"""``export.scale_for_print``: a stepped solid of a UTM DEM scaled for a 3D print (issue #2). In UTM metres a slicer
read the embedded DEM's ``.stl`` as millimetres, a print 36 m wide placed 3.8 km from its bed, and STL's
float32 moved its northings by up to 0.125 m; scaled, its longer side is the print size, its lowest corner at the
origin."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st_

import stepterrain as st
from stepterrain.errors import InvalidInputError
from stepterrain.export import read_mesh, save_mesh, scale_for_print

from .test_export import needs_3mf


@pytest.fixture(scope="module")
def crop():
    """A 60 x 90 crop of the embedded DEM at its UTM place (northings near 3.8e6 m)."""
    dem = st.sample_dem()
    return st.Terrain.from_heights(dem.heights[100:160, 200:290], spacing=dem.spacing, origin=(
        dem.origin[0] + 200 * dem.spacing[0], dem.origin[1] + 100 * dem.spacing[1]), crs=dem.crs)


@pytest.fixture(scope="module")
def solid(crop):
    return st.stepped(crop, interval=50.0, solid=True, colors="terrain")


def _check_print(model: trimesh.Trimesh, mesh: trimesh.Trimesh, size: float, z_scale: float) -> None:
    """The invariants of a print model of ``mesh``: extent, corner, volume, faces and watertightness."""
    lo, hi = np.asarray(mesh.vertices).min(axis=0), np.asarray(mesh.vertices).max(axis=0)
    s = size / max(hi[0] - lo[0], hi[1] - lo[1])
    m_lo, m_hi = np.asarray(model.vertices).min(axis=0), np.asarray(model.vertices).max(axis=0)
    assert np.array_equal(m_lo, [0.0, 0.0, 0.0])
    assert max(m_hi[0], m_hi[1]) == pytest.approx(size, rel=1e-12)
    assert m_hi[2] == pytest.approx((hi[2] - lo[2]) * s * z_scale, rel=1e-12)
    np.testing.assert_array_equal(model.faces, mesh.faces)
    # an independent reference: each vertex's offset from the corner, times the scale
    np.testing.assert_allclose(model.vertices, (np.asarray(mesh.vertices) - lo) * [s, s, s * z_scale],
                               rtol=1e-12, atol=1e-12 * size)
    if mesh.is_watertight:
        assert model.is_watertight and model.is_winding_consistent
        assert model.volume > 0
        assert model.volume == pytest.approx(mesh.volume * s**3 * z_scale, rel=1e-9)


@pytest.mark.parametrize(("size", "z_scale"), [(150.0, 1.0), (80.0, 2.5), (1e-3, 0.1)])
def test_print_model_of_a_utm_solid_has_the_size_its_corner_at_zero_and_scaled_volume(solid, size, z_scale):
    before = np.array(solid.vertices)
    model = scale_for_print(solid, size, z_scale=z_scale)
    _check_print(model, solid, size, z_scale)
    np.testing.assert_array_equal(solid.vertices, before)  # the input is not modified
    assert model is not solid


def test_print_model_keeps_colours_face_attributes_and_maps_back_to_world(solid):
    model = scale_for_print(solid, 150.0, z_scale=3.0)
    np.testing.assert_array_equal(model.visual.vertex_colors, solid.visual.vertex_colors)
    for key in ("level", "wall"):
        np.testing.assert_array_equal(model.face_attributes[key], solid.face_attributes[key])
    record = model.metadata["print"]
    assert record["size"] == 150.0 and record["z_scale"] == 3.0
    # world = model / (scale, scale, scale * z_scale) + origin, as the docstring says
    back = np.asarray(model.vertices) / [record["scale"], record["scale"], record["scale"] * 3.0] + record["origin"]
    np.testing.assert_allclose(back, solid.vertices, rtol=0, atol=1e-6)
    # world coordinates are gone: no CRS, no floor height of the world
    assert "crs" in solid.metadata and "crs" not in model.metadata
    assert "floor" not in model.metadata and model.metadata["isovalues"] == solid.metadata["isovalues"]


def test_stl_of_the_print_model_reads_back_watertight_at_its_size_without_a_warning(solid, tmp_path):
    with pytest.warns(UserWarning, match="stores float32"):  # the world solid: northings rounded by centimetres
        save_mesh(solid, tmp_path / "world.stl")
    model = scale_for_print(solid, 150.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # float32 holds 150 mm to 1e-5 mm: nothing to warn about
        save_mesh(model, tmp_path / "print.stl")
    back = trimesh.load(tmp_path / "print.stl")  # corners merged by position, as slicers do
    assert back.is_watertight and back.is_winding_consistent
    assert len(back.vertices) == len(model.vertices)
    np.testing.assert_allclose(back.bounds, model.bounds, atol=1e-4)
    assert back.volume == pytest.approx(model.volume, rel=1e-5)


@pytest.mark.parametrize("ext", [".3mf", ".ply", ".glb", ".obj"])
def test_print_model_round_trips_with_its_record(solid, ext, tmp_path):
    if ext == ".3mf":
        needs_3mf()
    model = scale_for_print(solid, 120.0, z_scale=2.0)
    back = read_mesh(save_mesh(model, tmp_path / f"print{ext}"))
    np.testing.assert_allclose(back.vertices, model.vertices, atol=1e-5)
    assert back.metadata["print"]["size"] == 120.0
    assert back.metadata["print"]["origin"] == model.metadata["print"]["origin"]


def test_print_model_of_a_tall_narrow_mesh_takes_its_longer_side_in_y():
    # y longer than x: y's extent becomes the size
    mesh = trimesh.creation.box(extents=(2.0, 10.0, 4.0))
    mesh.apply_translation((500000.0, 4000000.0, 1000.0))
    model = scale_for_print(mesh, 100.0)
    _check_print(model, mesh, 100.0, 1.0)
    np.testing.assert_allclose(model.extents, [20.0, 100.0, 40.0])


@settings(max_examples=12, deadline=None)
@given(rows=st_.integers(3, 9), cols=st_.integers(3, 9), seed=st_.integers(0, 2**16),
       size=st_.floats(1.0, 500.0), z_scale=st_.floats(0.25, 8.0))
def test_print_models_of_random_utm_solids_keep_their_invariants(rows, cols, seed, size, z_scale):
    rng = np.random.default_rng(seed)
    heights = rng.uniform(0.0, 300.0, (rows, cols)).astype(np.float32)
    terrain = st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(376328.6554542635, 3807902.8276283755))
    solid = st.stepped(terrain, interval=50.0, solid=True)
    _check_print(scale_for_print(solid, size, z_scale=z_scale), solid, size, z_scale)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"size": 0.0}, "size must be positive; got 0"),
    ({"size": -150.0}, "size must be positive; got -150"),
    ({"size": float("nan")}, "size must be finite; got nan"),
    ({"size": float("inf")}, "size must be finite; got inf"),
    ({"size": "150mm"}, "size must be a number; got '150mm'"),
    ({"size": 150.0, "z_scale": 0.0}, "z_scale must be positive; got 0"),
    ({"size": 150.0, "z_scale": float("nan")}, "z_scale must be finite; got nan"),
    ({"size": 1e30, "z_scale": 1e30}, "beyond float32"),
    ({"size": 1e-300}, "below float32.s least normal number"),
    ({"size": 150.0, "z_scale": 1e-300}, "below float32.s least normal number"),
])
def test_bad_print_size_or_z_scale_is_refused_naming_it(solid, kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        scale_for_print(solid, **kwargs)


def test_print_model_of_a_mesh_without_faces_or_horizontal_extent_is_refused():
    with pytest.raises(InvalidInputError, match="mesh must have faces"):
        scale_for_print(trimesh.Trimesh(np.zeros((3, 3)), np.zeros((0, 3), int)), 150.0)
    vertical = trimesh.Trimesh([[5.0, 7.0, 0.0], [5.0, 7.0, 1.0], [5.0, 7.0, 2.0]], [[0, 1, 2]], process=False)
    with pytest.raises(InvalidInputError, match="horizontal extent"):
        scale_for_print(vertical, 150.0)
    bad = trimesh.Trimesh([[0.0, 0.0, 0.0], [1.0, np.nan, 0.0], [0.0, 1.0, 0.0]], [[0, 1, 2]], process=False)
    with pytest.raises(InvalidInputError, match="finite"):
        scale_for_print(bad, 150.0)
    with pytest.raises(InvalidInputError, match="mesh"):
        scale_for_print(np.zeros((3, 3)), 150.0)


def test_print_model_of_a_pyvista_solid_is_that_of_its_trimesh(crop):
    pv = pytest.importorskip("pyvista")
    from stepterrain.pyvista_accessor import from_polydata

    grid = pv.ImageData(dimensions=(90, 60, 1), spacing=(30.0, 30.0, 1.0), origin=(376328.0, 3790000.0, 0.0))
    grid.point_data["elevation"] = np.asarray(np.flipud(crop.heights), np.float32).ravel()
    poly = grid.stepterrain.stepped(interval=50.0, solid=True)
    mesh = from_polydata(poly)
    model = scale_for_print(poly, 100.0, z_scale=1.5)
    _check_print(model, mesh, 100.0, 1.5)


def test_print_model_metadata_is_its_own(solid):
    """The copy's metadata shares no list with the input's: editing the model's isovalues left the solid's as they were
    (a shallow copy of the input's metadata shared them)."""
    before = list(solid.metadata["isovalues"])
    model = scale_for_print(solid, 150.0)
    model.metadata["isovalues"].append(1e9)
    model.metadata["print"]["origin"][0] = 0.0
    assert solid.metadata["isovalues"] == before
    assert "print" not in solid.metadata


def test_print_model_bounds_are_those_of_the_faces_not_of_a_stray_vertex():
    """A watertight box with one vertex of no face far from it (a file's unused point): the model's bounds, as trimesh
    and a slicer see them, are size long from the origin (the stray vertex set the scale and the corner: 9.9 mm)."""
    box = trimesh.creation.box(extents=(2.0, 10.0, 4.0))
    box.apply_translation((500000.0, 4000000.0, 1000.0))
    mesh = trimesh.Trimesh(np.vstack([box.vertices, [[500100.0, 3999950.0, 970.0]]]), box.faces, process=False)
    model = scale_for_print(mesh, 100.0)
    np.testing.assert_allclose(model.bounds, [[0.0, 0.0, 0.0], [20.0, 100.0, 40.0]], atol=1e-9)
    # the box's own print, the stray vertex moved alike
    np.testing.assert_allclose(model.vertices, (mesh.vertices - box.bounds[0]) * 10.0, rtol=0, atol=1e-9)
    assert model.is_watertight and model.volume == pytest.approx(20.0 * 100.0 * 40.0, rel=1e-12)
    assert model.metadata["print"]["origin"] == pytest.approx([499999.0, 3999995.0, 998.0])
    bad = trimesh.Trimesh(box.vertices, np.vstack([box.faces, [[0, 1, 99]]]), process=False, validate=False)
    with pytest.raises(InvalidInputError, match="mesh faces must index its 8 vertices"):
        scale_for_print(bad, 100.0)


def test_print_model_of_a_vertical_mesh_is_refused_naming_its_xy_as_numbers():
    """The refusal named the line the faces stand on as ``x = np.float64(5.0)`` (a NumPy scalar's repr), and as where
    "all its vertices" lie while a vertex of no face lay elsewhere: the faces' vertices, as plain numbers."""
    vertical = trimesh.Trimesh([[5.0, 7.0, 0.0], [5.0, 7.0, 1.0], [5.0, 7.0, 2.0], [9.0, 9.0, 9.0]], [[0, 1, 2]],
                               process=False)
    with pytest.raises(InvalidInputError) as caught:
        scale_for_print(vertical, 150.0)
    assert str(caught.value).endswith("got the vertices of its faces all at x = 5.0, y = 7.0")


def test_print_model_says_its_unit_is_the_millimetre():
    """trimesh's ``units`` of a print model is millimetres, whatever the input said: a mesh read back from a glTF
    (metres by the format) kept "meters" on the model its size made millimetres."""
    box = trimesh.creation.box(extents=(300.0, 200.0, 50.0))
    box.units = "meters"
    model = scale_for_print(box, 150.0)
    assert model.units == "millimeters"
    assert box.units == "meters"
    assert np.allclose(model.extents, (150.0, 100.0, 25.0))
