"""close_solid of a surface wound clockwise seen from +z, and of a floor on the lowest point in float32.

* A TIN whose faces are wound clockwise (normals down: a user's flipped TIN, a stepped surface through trimesh's
  ``invert``) closed into a solid turned inside out: its skirts and base follow the surface's winding, so the
  mesh was watertight and consistently wound but its volume negative, its normals inward (a slicer reads it as a
  hole). close_solid now reverses every face of such a surface's solid (``faces[:, ::-1]``, with a warning): its
  vertices are the counter-clockwise surface's bit for bit, its surface faces the user's reversed, outward.
* A floor below the lowest surface point in float64 but on it in float32 was accepted: the base lay on the lowest
  point in an .stl or a .glb (a solid of no thickness there, the .stl writer's warning later). close_solid refuses
  it, naming the highest float32 floor it takes (stepped()'s default floor is a float32 step below at least).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as hs
from scipy.spatial import Delaunay

import stepterrain as st
from stepterrain.mesh import close_solid


def _tin(seed: int, n: int, offset=(0.0, 0.0), z_offset: float = 0.0):
    """n random points with distinct xy, Delaunay-triangulated, faces counter-clockwise seen from +z; ``offset``
    moves them in xy, ``z_offset`` in z."""
    rng = np.random.default_rng(seed)
    xy = np.unique(np.round(rng.uniform(0.0, 100.0, (n, 2)), 3), axis=0)
    vertices = np.column_stack([xy + np.asarray(offset), rng.uniform(5.0, 40.0, len(xy)) + z_offset])
    faces = Delaunay(xy).simplices.astype(np.int64)
    a, b, c = (vertices[faces[:, k], :2] for k in range(3))
    cw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    faces[cw] = faces[cw][:, ::-1]
    return vertices, faces


def _prism_volume(vertices, faces, floor):
    """The solid's volume as the NumPy sum of the prisms under the surface's faces: |projected area| times the mean
    height of the corners above the floor."""
    a, b, c = (np.asarray(vertices, np.float64)[faces[:, k]] for k in range(3))
    area = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    return float(np.sum(area * ((a[:, 2] + b[:, 2] + c[:, 2]) / 3.0 - floor)))


def _close(vertices, faces, floor):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = close_solid(vertices, faces, np.ones(len(faces), bool), floor)
    return result, [str(w.message) for w in caught]


@settings(max_examples=15, deadline=None)
@given(seed=hs.integers(0, 2**31 - 1), n=hs.integers(3, 60), floor=hs.sampled_from([0.0, -7.5, 4.0]))
def test_random_tins_close_outward_both_ways(seed, n, floor):
    """Either winding: positive volume equal to the prism sum, watertight, consistently wound; the clockwise TIN's
    solid has the counter-clockwise one's vertices bit for bit and its surface faces reversed back, with a warning;
    the counter-clockwise one's without."""
    vertices, faces = _tin(seed, n)
    (ccw_v, ccw_f, ccw_kept, ccw_added, ccw_source), said = _close(vertices, faces, floor)
    assert not said
    (cw_v, cw_f, cw_kept, cw_added, cw_source), said = _close(vertices, np.ascontiguousarray(faces[:, ::-1]), floor)
    assert len(said) == 1 and "faces: the surface is wound clockwise seen from +z" in said[0]
    want = _prism_volume(vertices, faces, floor)
    for v, f in ((ccw_v, ccw_f), (cw_v, cw_f)):
        mesh = trimesh.Trimesh(v, f, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0.0
        assert mesh.volume == pytest.approx(want, rel=1e-9)
    np.testing.assert_array_equal(cw_v.view(np.uint64), ccw_v.view(np.uint64))
    np.testing.assert_array_equal(cw_f, ccw_f)  # closed with its faces reversed: the counter-clockwise one's solid
    np.testing.assert_array_equal(cw_kept, ccw_kept)
    np.testing.assert_array_equal(cw_source, ccw_source)
    assert cw_added == ccw_added


@pytest.mark.parametrize("interval", [20.0, 7.0])
def test_a_stepped_surface_through_invert_closes_watertight(interval):
    """A stepped surface with its faces reversed (trimesh's ``invert``), its terrace mask as it was: its solid was
    reversed after closing, but the fins and the walls' pairs are read from the step kernels' layout (u_top, v_top,
    v_bottom), (u_top, v_bottom, u_bottom), which the reversal scrambles: the solid leaked (not watertight), with a
    warning that said it faced outward. Closed with its faces reversed back, it is the stepped surface's solid."""
    from stepterrain import stepped as stepped_module
    from stepterrain.terrain import as_terrain

    t = as_terrain(st.sample_dem().heights[:30, :30])
    arrays, vertices = stepped_module._stepped_arrays(t, st.isovalues(t.height_range, interval=interval), 0.0, None,
                                                      wp.get_device("cpu"))
    faces, terrace = arrays.faces.astype(np.int64), ~arrays.face_walls
    assert (~terrace).sum() > 0  # walls
    floor = float(vertices[:, 2].min()) - 10.0
    want = close_solid(vertices, faces, terrace, floor)
    with pytest.warns(UserWarning, match="faces: the surface is wound clockwise seen from"):
        got = close_solid(vertices, np.ascontiguousarray(faces[:, ::-1]), terrace, floor)
    mesh = trimesh.Trimesh(got[0], got[1], process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0.0
    np.testing.assert_array_equal(got[0].view(np.uint64), want[0].view(np.uint64))
    for g, w in zip(got[1:], want[1:], strict=True):
        np.testing.assert_array_equal(g, w)


def test_counter_clockwise_surfaces_are_left_alone():
    """stepped(..., solid=True) on the sample DEM: no warning, outward (the step kernels wind counter-clockwise)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = st.stepped(st.sample_dem().heights[:40, :40], interval=20.0, solid=True)
    assert mesh.is_watertight and mesh.volume > 0.0


@pytest.mark.parametrize("lowest", [1.1815060912382438, 1234.5678, 5_000_000.25, -0.001])
def test_floor_on_the_lowest_point_in_float32_is_refused(lowest):
    """A floor one float64 step below the lowest point lies on it in float32: refused, naming the highest float32
    floor taken, which is accepted (a solid with a base below the surface in float32 too)."""
    vertices, faces = _tin(3, 20)
    vertices[:, 2] += lowest - vertices[:, 2].min()
    zmin = float(vertices[:, 2].min())
    floor = float(np.nextafter(zmin, -np.inf))
    assert floor < zmin and np.float32(floor) == np.float32(zmin)
    highest = float(np.nextafter(np.float32(zmin), np.float32(-np.inf)))
    with pytest.raises(st.InvalidInputError, match=rf"floor must lie below the lowest surface height {zmin!r} in "
                       rf"float32 too .* at most {highest:.9g}\); got {floor!r}"):
        close_solid(vertices, faces, np.ones(len(faces), bool), floor)
    solid_vertices, _, *_ = close_solid(vertices, faces, np.ones(len(faces), bool), highest)
    base = solid_vertices[:, 2] == highest
    assert base.any() and (solid_vertices[~base, 2].astype(np.float32) > np.float32(highest)).all()


@settings(max_examples=15, deadline=None)
@given(seed=hs.integers(0, 2**31 - 1), n=hs.integers(3, 60), offset=hs.sampled_from([0.0, 3.7e5, 5.2e6]),
       clockwise=hs.booleans(), holes=hs.integers(0, 5))
def test_the_boundary_area_is_the_faces_area(seed, n, offset, clockwise, holes):
    """close_solid reads the surface's winding from its boundary (the shoelace sum, O(boundary)): equal to the
    faces' signed projected area summed in NumPy, with holes (faces left out) and at UTM-sized coordinates."""
    from stepterrain.mesh import _projected_area, boundary_edges

    vertices, faces = _tin(seed, n)
    vertices[:, :2] += offset
    faces = np.delete(faces, np.random.default_rng(seed).integers(0, len(faces), holes), axis=0) if len(faces) > holes \
        else faces
    if clockwise:
        faces = faces[:, ::-1]
    a, b, c = (vertices[faces[:, k], :2] for k in range(3))
    want = float(np.sum((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])))
    got = _projected_area(vertices, boundary_edges(faces))
    assert got == pytest.approx(want, rel=1e-9, abs=1e-6 * (1.0 + offset))
    assert (got < 0) == clockwise
