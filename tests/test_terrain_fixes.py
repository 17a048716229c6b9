"""Regression tests for bugs found in Terrain (terrain.py): each fails without its fix."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st_

import stepterrain as st
from stepterrain.errors import InvalidInputError

_H = np.add.outer(np.arange(6.0), 2.0 * np.arange(7.0)).astype(np.float32)  # heights 0 to 17


@pytest.mark.parametrize(
    "fields, message",
    [
        (dict(kind="grid", heights=np.arange(5.0)), r"^heights must be a 2-D \(H, W\) array; got shape \(5,\)$"),
        (dict(kind="grid", heights=np.zeros((1, 5))), r"^heights needs at least 2 x 2 nodes; got shape \(1, 5\)$"),
        (
            dict(kind="grid", heights=[["a", "b"], ["c", "d"]]),
            r"^heights must be a real-valued \(H, W\) array; got "
            r"dtype <U1$",
        ),
        (
            dict(kind="grid", heights=np.full((3, 3), np.inf)),
            r"^heights must be finite or NaN \(nodata\); got an "
            r"infinite value at index \(0, 0\)$",
        ),
        (
            dict(kind="grid", heights=_H, spacing=(1.0, 2.0, 3.0)),
            r"^spacing must be a pair of finite numbers \(x, y\) "
            r"\(or one number for both\); got \(1\.0, 2\.0, 3\.0\)$",
        ),
        (
            dict(kind="grid", heights=_H, spacing=(0.0, 1.0)),
            r"^spacing must be non-zero in x and y; got \(0\.0, 1\.0\)$",
        ),
        (dict(kind="grid", heights=_H, origin="ab"), r"^origin must be a pair of numbers \(x, y\); got 'ab'$"),
        (
            dict(kind="grid", heights=_H, origin=(1.0,)),
            r"^origin must be a pair of finite numbers \(x, y\); got "
            r"\(1\.0,\)$",
        ),
        (dict(kind="grd", heights=_H), r"^kind must be 'grid' or 'tin'; got 'grd'$"),
        (dict(kind="grid", heights=_H, crs=32611), r"^crs must be a str \(e\.g\. 'EPSG:32611'\) or None; got 32611$"),
        (
            dict(kind="grid", heights=_H, faces=np.zeros((1, 3), int)),
            r"^a Terrain of kind 'grid' takes heights, "
            r"spacing and origin; got faces too",
        ),
        (
            dict(kind="tin", heights=np.zeros(3, np.float32)),
            r"^a Terrain of kind 'tin' needs points \(N, 3\) and "
            r"faces \(F, 3\); got points None, faces None: build it "
            r"with Terrain\.from_mesh",
        ),
        (
            dict(kind="tin", heights=None, points=np.zeros((4, 2)), faces=[[0, 1, 2]]),
            r"^points must be an \(N, 3\) array of x, y, z; got shape \(4, 2\)$",
        ),
        (
            dict(kind="tin", heights=None, points=np.eye(3), faces=[[0.0, 1.0, 2.0]]),
            r"^faces must be an \(F, 3\) integer array of point indices; got shape \(1, 3\), dtype float64$",
        ),
        (
            dict(kind="tin", heights=None, points=np.eye(3), faces=[[0, 1, 5]]),
            r"^terrain mesh faces must index its vertices \(0 to 2\); face 0 is \[0, 1, 5\]",
        ),
        (
            dict(kind="tin", heights=np.ones(3), points=np.eye(3), faces=[[0, 1, 2]]),
            r"^heights of a Terrain of kind 'tin' are its points' z \(None to take them\); got an array of shape "
            r"\(3,\), dtype float64 that differs from points\[:, 2\]$",
        ),
    ],
)
def test_a_terrain_built_directly_is_checked_by_field(fields, message):
    """``Terrain(kind=..., heights=...)`` checked nothing: a 1-D array failed deep in stepped ('not enough values
    to unpack'), a TIN without faces with a NoneType error, a text origin with 'must be real number'; a 3-number
    or zero spacing was meshed (flat, or with its third number ignored). Each is now an InvalidInputError naming
    the field, what was expected and what was got, at construction."""
    with pytest.raises(InvalidInputError, match=message):
        st.Terrain(**fields)


def test_a_terrain_built_directly_takes_lists_and_other_dtypes_as_float32():
    """A list of rows failed in stepped ('list' object has no attribute 'min'); float64 and int heights and a
    Fortran-ordered array are now the same float32 grid as from_heights makes, and mesh the same."""
    reference = st.stepped(st.Terrain.from_heights(_H, spacing=(2.0, 3.0)), interval=2.0, device="cpu")
    for heights in (_H.tolist(), _H.astype(np.float64), _H.astype(np.int32), np.asfortranarray(_H)):
        terrain = st.Terrain(kind="grid", heights=heights, spacing=(2.0, 3.0))
        assert terrain.heights.dtype == np.float32 and terrain.heights.flags.c_contiguous
        mesh = st.stepped(terrain, interval=2.0, device="cpu")
        np.testing.assert_array_equal(mesh.vertices, reference.vertices)
        np.testing.assert_array_equal(mesh.faces, reference.faces)


def test_dataclasses_replace_does_not_carry_the_old_caches():
    """``dataclasses.replace(terrain, heights=new)`` passed the old terrain's cache dict to the new one: its height
    range (0 to 17 m) stayed, and stepped() clamped the new heights (100 to 117 m) into it. The replaced terrain
    now starts with its own caches; a TIN replaced keeps working (its edge tables rebuilt)."""
    terrain = st.Terrain.from_heights(_H)
    assert terrain.height_range == (0.0, 17.0)
    raised = dataclasses.replace(terrain, heights=_H + 100.0)
    assert raised.height_range == (100.0, 117.0)
    mesh = st.stepped(raised, interval=2.0, device="cpu")
    assert mesh.vertices[:, 2].min() >= 100.0 - 1.0
    assert terrain.height_range == (0.0, 17.0)
    tin = st.Terrain.from_mesh(
        trimesh.Trimesh([[0, 0, 0], [1, 0, 1], [0, 1, 2], [1, 1, 3]], [[0, 1, 2], [1, 3, 2]], process=False)
    )
    renamed = dataclasses.replace(tin, source="survey.ply")
    np.testing.assert_array_equal(renamed.edges, tin.edges)
    np.testing.assert_array_equal(
        st.stepped(renamed, interval=1.0, device="cpu").faces, st.stepped(tin, interval=1.0, device="cpu").faces
    )


_DURATIONS = np.arange(16).reshape(4, 4).astype("timedelta64[s]")


@pytest.mark.parametrize(
    "call, message",
    [
        (
            lambda: st.Terrain.from_heights(_DURATIONS),
            r"^heights must be a real-valued \(H, W\) array; got dtype "
            r"timedelta64\[s\]$",
        ),
        (lambda: st.stepped(_DURATIONS, interval=1.0, device="cpu"), r"^heights must be a real-valued"),
        (
            lambda: st.isovalues((0.0, 3.0), levels=_DURATIONS[0]),
            r"^levels must be a sequence of numbers \(real "
            r"numbers\); got dtype timedelta64\[s\]$",
        ),
        (
            lambda: st.stepped(_H[:4, :4], interval=2.0, gamma=_DURATIONS, device="cpu"),
            r"^gamma must be .*\(real numbers\); got dtype timedelta64\[s\]$",
        ),
        (
            lambda: list(st.stepped_series(_DURATIONS[None], interval=1.0, device="cpu")),
            r"^frames must be a real-valued \(T, H, W\) stack; got dtype timedelta64\[s\]$",
        ),
        (
            lambda: st.stepped(_H, levels=[0.0, 8.0, 16.0], colors=_DURATIONS[:3, :3], device="cpu"),
            r"^colors must be numbers \(0-1 floats or 0-255 integers\); got dtype timedelta64\[s\]$",
        ),
        (
            lambda: st.Terrain(kind="tin", heights=None, points=np.eye(3), faces=_DURATIONS[:1, :3]),
            r"^faces must be an \(F, 3\) integer array of point indices; got shape \(1, 3\), dtype timedelta64\[s\]$",
        ),
    ],
    ids=["from_heights", "stepped", "levels", "gamma", "stepped_series", "colors", "tin_faces"],
)
def test_durations_are_no_real_numbers(call, message):
    """numpy makes timedelta64 a subtype of signedinteger, so the dtype checks (``np.issubdtype(dtype, np.integer)``)
    took durations as heights, levels, γ, colours and point indices (a mesh stepped from seconds, silently), and a
    (T, H, W) stack of them reached ``float(min)``, a bare TypeError. They are refused as datetime64 always was."""
    with pytest.raises(InvalidInputError, match=message):
        call()


@pytest.mark.parametrize("make", ["from_heights", "direct", "stepped", "heightfield_mesh"])
@pytest.mark.parametrize(("origin", "spacing"), [((1e17, 0.0), (1.0, 1.0)), ((0.0, -1e300), (30.0, -30.0))])
def test_an_origin_too_far_for_float64_to_keep_the_nodes_apart_is_refused(make, origin, spacing):
    """An origin of 1e17 with spacing 1 put neighbouring nodes on one float64 value (1e300: every node on one):
    a stepped mesh of zero area, silently. Found by stepping grids at ever farther origins. Refused, naming it;
    UTM-sized origins (millions of metres, centimetre spacing) stay far inside the bound."""
    heights = np.arange(12.0).reshape(3, 4)
    calls = {
        "from_heights": lambda: st.Terrain.from_heights(heights, spacing=spacing, origin=origin),
        "direct": lambda: st.Terrain(kind="grid", heights=heights, spacing=spacing, origin=origin),
        "stepped": lambda: st.stepped(heights, interval=2.0, spacing=spacing, origin=origin),
        "heightfield_mesh": lambda: st.heightfield_mesh(heights, spacing=spacing, origin=origin),
    }
    with pytest.raises(st.InvalidInputError, match=r"^origin .* lies too far from zero for spacing .* float64"):
        calls[make]()
    near = st.stepped(heights, interval=2.0, spacing=(0.01, -0.01), origin=(4.5e6, 5e5))
    assert near.area_faces.min() > 0


def test_a_trimesh_scene_or_point_cloud_as_terrain_is_named_with_a_hint():
    """trimesh.load of a GLB (stepterrain's own output too) gives a trimesh.Scene, not a Trimesh; stepped() and
    circular_lens took it for a raw array and said "heights must be a real-valued (H, W) array; got dtype object",
    naming neither the Scene nor the way out. Such trimesh objects (a Scene, a PointCloud) are now refused by type,
    a Scene with how to get its mesh; the mesh it gives steps as a TIN."""
    tin = st.heightfield_mesh(_H)
    scene = trimesh.load(trimesh.util.wrap_as_stream(tin.export(file_type="glb")), file_type="glb")
    assert isinstance(scene, trimesh.Scene)
    for call in (lambda: st.stepped(scene, interval=2.0), lambda: st.circular_lens(scene, (1.0, 1.0), 1.0)):
        with pytest.raises(InvalidInputError, match=r"^terrain must be .*; got a trimesh\..*Scene .*force='mesh'"):
            call()
    with pytest.raises(InvalidInputError, match=r"^terrain must be .*; got a trimesh\..*PointCloud$"):
        st.stepped(trimesh.PointCloud(tin.vertices), interval=2.0)
    mesh = trimesh.load(trimesh.util.wrap_as_stream(tin.export(file_type="glb")), file_type="glb", force="mesh")
    assert st.stepped(mesh, interval=2.0).area == pytest.approx(st.stepped(_H, interval=2.0).area, rel=1e-6)


# ------------------------------------------------------------------ TIN faces that overlap in xy without folding


def _sheet(rows=5, cols=6, spacing=1.0, origin=(0.0, 0.0), z=0.0, angle=0.0, centre=None):
    """A rough heightfield sheet as a TIN, turned by ``angle`` about its middle and moved so the middle is ``centre``
    (else laid from ``origin``)."""
    heights = z + np.random.default_rng(rows * cols).random((rows, cols)) * 3.0
    mesh = st.heightfield_mesh(heights, spacing=spacing, origin=origin)
    if centre is not None:
        xy = mesh.vertices[:, :2] - mesh.vertices[:, :2].mean(axis=0)
        turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        mesh.vertices[:, :2] = xy @ turn.T + centre
    return mesh


def _joined(*meshes, process=False):
    """The meshes as one TIN, each keeping its own vertices (duplicates where they touch)."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    return trimesh.Trimesh(np.vstack([m.vertices for m in meshes]),
                           np.vstack([m.faces + o for m, o in zip(meshes, offsets, strict=False)]), process=process)


def _ramp(turns, rise=0.0, segments=36):
    """A spiral ramp: an annulus between radii 1 and 2 (both growing by ``rise`` over the turns) climbing 1 per
    segment, ``turns`` times round."""
    t = np.linspace(0.0, 2.0 * np.pi * turns, round(segments * turns) + 1)
    grow = np.linspace(0.0, rise, len(t))
    rims = [np.column_stack([(r + grow) * np.cos(t), (r + grow) * np.sin(t), np.arange(len(t))]) for r in (1.0, 2.0)]
    n = len(t)
    k = np.arange(n - 1)
    faces = np.concatenate([np.column_stack([k, n + k, n + k + 1]), np.column_stack([k, n + k + 1, k + 1])])
    return trimesh.Trimesh(np.vstack(rims), faces, process=False)


def _soup(mesh):
    """The mesh as a triangle soup: three points of its own per face (as an STL file read without merging)."""
    return trimesh.Trimesh(mesh.triangles.reshape(-1, 3), np.arange(3 * len(mesh.faces)).reshape(-1, 3),
                           process=False)


def _doubled_fan():
    """8 faces round a middle point, a quarter turn each, so winding twice round it (radius 1, then 2): all wound
    alike, every inner edge shared by two faces wound oppositely."""
    angle, radius = np.arange(8) * np.pi / 2, np.repeat([1.0, 2.0], 4)
    rim = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.arange(8.0)])
    return trimesh.Trimesh(np.vstack([[0.0, 0.0, 0.0], rim]), [[0, 1 + k, 1 + (k + 1) % 8] for k in range(8)],
                           process=False)


def _cross(u, v):
    """The z of the cross product of xy vectors (..., 2)."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _inside(point, triangle):
    """Whether ``point`` lies strictly inside the xy projection of ``triangle`` (3, 3), either winding."""
    a, b, c = triangle[:, :2]
    sides = [_cross(q - p, point - p) for p, q in ((a, b), (b, c), (c, a))]
    return min(sides) > 0 or max(sides) < 0


_OVERLAP = (r"^terrain mesh faces must project one-to-one onto the xy plane; faces (\d+) and (\d+) overlap in xy "
            r"around \(([-\d.e+]+), ([-\d.e+]+)\) \(at least \d+ of its \d+ faces with finite heights overlap another: "
            r"two sheets one above the other, or a surface that wraps over itself\)$")


def _refused_overlap(mesh):
    """The two faces and the point the overlap error names; asserts the point lies inside both faces in xy."""
    import re

    with pytest.raises(InvalidInputError, match=_OVERLAP) as info:
        st.stepped(mesh, interval=1.0)
    first, second, x, y = re.match(_OVERLAP, str(info.value)).groups()
    first, second, point = int(first), int(second), np.array([float(x), float(y)])
    assert first != second
    assert _inside(point, mesh.triangles[first]) and _inside(point, mesh.triangles[second])
    return first, second, point


@settings(max_examples=40, deadline=None)
@given(
    u=st_.floats(0.02, 0.98), v=st_.floats(0.02, 0.98), angle=st_.floats(0.0, 2.0 * np.pi),
    spacing=st_.floats(0.2, 3.0), lift=st_.floats(-20.0, 20.0), rows=st_.integers(2, 5), cols=st_.integers(2, 5),
)
def test_a_second_sheet_overlapping_the_first_in_xy_is_refused_naming_two_faces_and_a_point(
    u, v, angle, spacing, lift, rows, cols
):
    """Issue 2 accepts a TIN "whose faces project one-to-one onto the xy plane" and refuses "TIN faces that fold
    over in projection"; the check looked only at each face's winding and at edges used twice the same way, so two
    separate sheets one above the other (all faces wound alike, no shared edge) were stepped into overlapping
    terraces and walls. Any second sheet whose middle lies inside the first (so that they overlap) is now refused,
    naming two faces that overlap and a point inside both, wherever it lies, however turned, sized and lifted."""
    first = _sheet()
    second = _sheet(rows, cols, spacing, z=lift, angle=angle, centre=(u * 5.0, v * 4.0))
    _refused_overlap(_joined(first, second))
    _refused_overlap(_joined(second, first))


@pytest.mark.parametrize(
    "mesh",
    [
        _ramp(2.0),  # a parking-garage ramp: the second turn right above the first
        _ramp(1.3, rise=0.5),  # growing, but not enough to clear the first turn
        _joined(_sheet(11, 11), trimesh.Trimesh([[1.2, 1.2, 9.0], [2.5, 1.2, 9.0], [1.2, 2.5, 9.0]], [[0, 1, 2]])),
        _joined(trimesh.Trimesh([[0, 0, 0], [9, 0, 0], [0, 9, 0]], [[0, 1, 2]]),
                trimesh.Trimesh([[1, 1, 5], [2, 1, 5], [1, 2, 5]], [[0, 1, 2]])),  # a face inside another's face
        _doubled_fan(),
        _soup(_joined(_sheet(), _sheet(z=9.0))),  # two sheets on one xy grid, as a triangle soup
    ],
    ids=["spiral ramp", "widening spiral ramp", "triangle over a grid", "triangle in a face", "doubled fan",
         "stacked soups"],
)
def test_a_tin_that_wraps_over_itself_or_holds_a_face_over_another_is_refused(mesh):
    """A sheet that wraps round over itself (a spiral ramp), a fan that winds twice round a point, a lone face above
    another component's face: no face folds and no edge is used twice the same way, so all were stepped into
    overlapping nonsense. Refused, naming two overlapping faces and a point inside both."""
    _refused_overlap(mesh)


def _holed(poke=0.0):
    """A 11 x 11 sheet with nodata in its middle (a hole from x, y = 2 to 8), and a face in the hole reaching
    ``poke`` past its right side."""
    heights = np.random.default_rng(1).random((11, 11))
    heights[3:8, 3:8] = np.nan
    island = trimesh.Trimesh([[4.2, 4.2, 5.0], [8.0 + poke, 4.2, 5.0], [4.2, 5.8, 5.0]], [[0, 1, 2]])
    return _joined(st.heightfield_mesh(heights), island)


_NAN_CORNER = _sheet().vertices.copy()
_NAN_CORNER[0, 2] = np.nan

_TOUCHING = {
    "one sheet": _sheet(),
    "abutting sheets, vertices duplicated": _joined(_sheet(), _sheet(origin=(5.0, 0.0))),
    "sheets meeting at a corner": _joined(_sheet(), _sheet(origin=(5.0, 4.0))),
    "sheets meeting at a corner, diagonally": _joined(_sheet(), _sheet(origin=(5.0, -4.0))),
    "abutting sheets, shifted (T-junctions)": _joined(_sheet(), _sheet(origin=(5.0, 0.5))),
    "abutting sheets, finer (T-junctions)": _joined(_sheet(), _sheet(9, 11, 0.5, origin=(5.0, 0.0))),
    "abutting sheets, welded": _joined(_sheet(), _sheet(origin=(5.0, 0.0)), process=True),
    "sheets apart": _joined(_sheet(), _sheet(origin=(9.0, 9.0))),
    "triangle soup": _soup(_sheet()),
    "triangle soups abutting": _soup(_joined(_sheet(), _sheet(origin=(5.0, 0.5)))),
    "a face in a hole": _holed(),
    "a face touching the side of a hole": _holed(0.0),
    "an L-shaped outline": trimesh.Trimesh(_sheet().vertices, _sheet().faces[
        ~((_sheet().triangles[:, :, 0].mean(axis=1) > 2.0) & (_sheet().triangles[:, :, 1].mean(axis=1) > 2.0))],
        process=False),
    "one turn of a spiral ramp, its ends abutting": _ramp(1.0),
    "a spiral ramp widening clear of itself": _ramp(1.5, rise=3.0),
    "nodata, unused and duplicate points": trimesh.Trimesh(np.vstack([_NAN_CORNER, [[99, 99, 0], [2, 2, 0]]]),
                                                           _sheet().faces, process=False),
}


@pytest.mark.parametrize("name", list(_TOUCHING))
def test_tin_faces_that_only_touch_in_xy_are_stepped(name):
    """What must stay accepted beside the overlap check: sheets that abut along an edge (shared or duplicated
    vertices, or T-junctions), meet at a corner, lie apart, a triangle soup, holes (a face in one, touching its
    side), non-convex outlines, a one-turn ramp whose ends abut, nodata and unused points. Overlap means an
    intersection of positive area: the terraces cover the input's projected area exactly once."""
    mesh = _TOUCHING[name]
    stepped = st.stepped(mesh, interval=0.5)
    kept = np.isfinite(mesh.triangles[:, :, 2]).all(axis=1)
    tri = mesh.triangles[kept][:, :, :2]
    area = 0.5 * np.abs(_cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])).sum()
    terrace = stepped.triangles[~stepped.face_attributes["wall"]][:, :, :2]
    covered = 0.5 * _cross(terrace[:, 1] - terrace[:, 0], terrace[:, 2] - terrace[:, 0])
    assert covered.min() > -1e-9
    assert covered.sum() == pytest.approx(area, rel=1e-6)


def test_a_face_poking_out_of_a_hole_over_the_sheet_is_refused():
    """A face in a nodata hole is a separate patch (accepted above); one reaching past the hole's side over the
    sheet overlaps it there."""
    first, second, point = _refused_overlap(_holed(0.5))
    assert point[0] > 8.0


@pytest.mark.parametrize("kind", ["grid", "rtin"])
def test_a_real_dem_tin_is_stepped_and_a_copy_shifted_over_it_refused(kind):
    """Real TINs of a shared DEM (its grid meshed by heightfield_mesh, and a Martini RTIN of it: faces of many sizes)
    pass the overlap check, their terraces covering them once; a copy moved by a fraction of the extent and lifted
    (as a second survey over the first) overlaps it and is refused."""
    from .conftest import real_dem

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=129, step=2)
    if kind == "grid":
        mesh = st.heightfield_mesh(heights, spacing=(60.0, -60.0), origin=(380000.0, 3800000.0))
    else:
        pymartini = pytest.importorskip("pymartini")
        points, faces = pymartini.Martini(129).create_tile(heights).get_mesh(20.0)
        col, row = points.reshape(-1, 2).T.astype(np.int64)
        mesh = trimesh.Trimesh(np.column_stack([380000.0 + 60.0 * col, 3800000.0 - 60.0 * row, heights[row, col]]),
                               faces.reshape(-1, 3).astype(np.int64), process=False)
        assert mesh.area_faces.max() > 16 * mesh.area_faces.min()  # faces of many sizes
    stepped = st.stepped(mesh, interval=50.0)
    terrace = stepped.triangles[~stepped.face_attributes["wall"]][:, :, :2]
    tri = mesh.triangles[:, :, :2]
    assert np.abs(_cross(terrace[:, 1] - terrace[:, 0], terrace[:, 2] - terrace[:, 0])).sum() == pytest.approx(
        np.abs(_cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])).sum(), rel=1e-6)
    copy = mesh.copy()
    copy.vertices += [0.37 * 128 * 60.0, -0.21 * 128 * 60.0, 500.0]
    _refused_overlap(_joined(mesh, copy))


def _clipped_area(a, b):
    """The area of the intersection of two counter-clockwise triangles' xy (3, 2): a clipped by b's edge lines."""
    polygon = list(a)
    for p, q in zip(b, np.roll(b, -1, axis=0), strict=True):
        side = [_cross(q - p, v - p) for v in polygon]
        clipped = []
        for k, v in enumerate(polygon):
            if (side[k] > 0) != (side[k - 1] > 0):
                clipped.append(polygon[k - 1] + (v - polygon[k - 1]) * (side[k - 1] / (side[k - 1] - side[k])))
            if side[k] > 0:
                clipped.append(v)
        polygon = clipped
        if not polygon:
            return 0.0
    ring = np.array(polygon)
    return 0.5 * abs(_cross(ring, np.roll(ring, -1, axis=0)).sum())


_TRIANGLE = st_.tuples(st_.floats(-3.0, 33.0), st_.floats(-3.0, 33.0), st_.floats(-1.5, 1.3), st_.floats(0.0, 6.3),
                       st_.floats(0.3, 2.8), st_.floats(0.3, 2.8))


@settings(max_examples=40, deadline=None)
@given(triangles=st_.lists(_TRIANGLE, min_size=1, max_size=8), sheet=st_.booleans())
def test_random_faces_over_a_sheet_are_refused_exactly_when_some_overlap(triangles, sheet):
    """Against an independent count (the intersections' areas by clipping, every pair whose boxes meet): faces of
    sizes over three decades, alone (a triangle soup: every face on a boundary) or beside a welded 30 x 30 sheet
    (few boundary faces), are refused exactly when two overlap with positive area."""
    from hypothesis import assume, event

    corners = []
    for x, y, scale, turn, first, second in triangles:
        angles = turn + np.array([0.0, first, first + second])
        corners.append(np.column_stack([x + 10**scale * np.cos(angles), y + 10**scale * np.sin(angles)]))
    parts = [trimesh.Trimesh(np.column_stack([c, np.full(3, 5.0)]), [[0, 1, 2]], process=False) for c in corners]
    if sheet:
        parts.insert(0, st.heightfield_mesh(np.random.default_rng(3).random((31, 31))))
    mesh = _joined(*parts)
    tri = mesh.triangles[:, :, :2]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    size = (hi - lo).max(axis=1)
    first, second = np.triu_indices(len(tri), 1)
    near = (np.maximum(lo[first], lo[second]) < np.minimum(hi[first], hi[second])).all(axis=1)
    near &= second >= len(tri) - len(corners)  # the sheet's own faces do not overlap
    overlap = False
    for i, j in zip(first[near], second[near], strict=True):
        share = _clipped_area(tri[i], tri[j]) / min(size[i], size[j]) ** 2
        assume(not 1e-15 < share < 1e-4)  # a near touch: either answer is right
        overlap |= share > 0
    event(f"{'overlapping' if overlap else 'apart'}, {'beside a sheet' if sheet else 'alone'}")
    if overlap:
        _refused_overlap(mesh)
    else:
        assert st.Terrain.from_mesh(mesh).faces.shape == (len(tri), 3)


# ------------------------------------------------------------------ TIN faces that fold over: a refusal with a way out
_FOLDED = (r"^terrain mesh(?: \(from '([^']*)'\))? faces must project one-to-one onto the xy plane; (\d+) of its (\d+) "
           r"faces with finite heights fold over \(wound against the rest\): faces? ([\d, .]+), the first around "
           r"\(([-\d.e+]+), ([-\d.e+]+)\)\. ")


def _folded_sheet(moved, clockwise):
    """A 9 x 12 sheet whose interior vertices ``moved`` are pushed 1.4 spacings in x, across their neighbours' edges
    (as quadric decimation moves a vertex), wound clockwise seen from +z if ``clockwise``."""
    mesh = _sheet(9, 12, origin=(1000.0, 2000.0))
    vertices = mesh.vertices.copy()
    for row, col in moved:
        vertices[row * 12 + col, :2] += [1.4, 0.3]
    faces = mesh.faces[:, ::-1] if clockwise else mesh.faces
    return trimesh.Trimesh(vertices, faces, process=False)


@pytest.mark.parametrize("clockwise", [False, True], ids=["counter-clockwise", "clockwise"])
@pytest.mark.parametrize("moved", [[(4, 5)], [(2, 2), (2, 8), (6, 2), (6, 8)]], ids=["one vertex", "four vertices"])
def test_folded_faces_are_counted_named_placed_and_the_hints_in_the_refusal_work(moved, clockwise):
    """A DEM's TIN decimated by trimesh's simplify_quadric_decimation folds a few faces (4 of 384k for the shared
    DEM's full grid at a quarter of its faces, 5 of 154k at a tenth): the refusal named one face and a count, with no
    way out, and dropping only the folded faces is refused in turn (their neighbours overlap others). It now says how
    many fold, names the first few (by index in the mesh given) and a point inside the first, and gives code that
    makes the mesh acceptable: dropping every face touching a folded one, or a 2-D Delaunay triangulation; both,
    run as the message prints them, are stepped (whichever way the mesh is wound)."""
    import re

    mesh = _folded_sheet(moved, clockwise)
    tri = mesh.triangles[:, :, :2]
    area2 = _cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    folded = np.flatnonzero(area2 > 0 if clockwise else area2 < 0)
    assert 0 < len(folded) < len(area2) / 2
    with pytest.raises(InvalidInputError, match=_FOLDED) as info:
        st.Terrain.from_mesh(mesh, source="decimated.ply")
    message = str(info.value)
    source, count, total, listed, x, y = re.match(_FOLDED, message).groups()
    assert (source, int(count), int(total)) == ("decimated.ply", len(folded), len(mesh.faces))
    named = [int(k) for k in listed.replace(", ...", "").split(", ")]
    assert named == folded[:5].tolist() and listed.endswith("...") == (len(folded) > 5)
    assert _inside(np.array([float(x), float(y)]), mesh.triangles[named[0]])

    alone = mesh.copy()  # dropping only the folded faces leaves their neighbours overlapping: refused
    alone.update_faces(np.setdiff1d(np.arange(len(mesh.faces)), folded))
    _refused_overlap(alone)

    dropped = mesh.copy()  # the message's update_faces call, as printed
    exec(re.search(r"(mesh\.update_faces\(.*?\));", message).group(1), {"np": np, "mesh": dropped})
    assert 0 < len(mesh.faces) - len(dropped.faces) <= 20 * len(moved)  # small holes round the moved vertices
    assert len(st.stepped(dropped, interval=0.5).faces) > 0

    pytest.importorskip("scipy")
    import scipy.spatial

    names = {"trimesh": trimesh, "scipy": scipy, "mesh": mesh.copy()}  # the message's re-triangulation, as printed
    exec(re.search(r"(mesh = trimesh\.Trimesh\(.*?\.simplices\))", message).group(1), names)
    assert np.array_equal(names["mesh"].vertices, mesh.vertices)
    stepped = st.stepped(names["mesh"], interval=0.5)
    terrace = stepped.triangles[~stepped.face_attributes["wall"]][:, :, :2]
    covered = _cross(terrace[:, 1] - terrace[:, 0], terrace[:, 2] - terrace[:, 0])
    assert covered.min() > -1e-9  # one-to-one: its terraces cover the points' hull once
    assert 0.5 * covered.sum() == pytest.approx(scipy.spatial.ConvexHull(mesh.vertices[:, :2]).volume, rel=1e-9)


# ------------------------------------------------------------------ sorted_unique: np.unique without numpy 2's hash
@settings(max_examples=60, deadline=None)
@given(
    values=st_.lists(st_.integers(-(2**62), 2**62), max_size=200), spread=st_.integers(1, 2**40),
    dtype=st_.sampled_from([np.int64, np.int32, np.uint32, np.int8]), rows=st_.integers(1, 3),
)
def test_sorted_unique_gives_what_np_unique_gives(values, spread, dtype, rows):
    """A value-only np.unique of integers hashes in numpy 2.x (5-7x slower than a sort for a close-up's 0.6-1.4M face
    corners of the shared DEM, which render_closeups and animate_closeups take per close-up and frame): the helper
    that replaces it sorts, and must give exactly np.unique's answer: values, dtype and 1-D shape, for any integer
    dtype and shape, repeats, extremes and the empty array."""
    from stepterrain.terrain import sorted_unique

    info = np.iinfo(dtype)
    array = (np.array(values, dtype=np.int64) % spread) if len(values) else np.zeros(0, np.int64)
    array = np.clip(array + info.min // 2, info.min, info.max).astype(dtype)
    array = np.repeat(array, rows).reshape(-1, rows) if rows > 1 else array  # a 2-D array too: flattened
    got, want = sorted_unique(array), np.unique(array)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert np.array_equal(got, want)


def test_sorted_unique_gives_a_close_up_s_used_vertices_as_np_unique_did():
    """The close-up content faces of the shared DEM (the call render_closeups and animate_closeups make): the same
    vertices as np.unique, so the same drawn bounds."""
    from stepterrain import closeup
    from stepterrain.terrain import sorted_unique

    from .conftest import real_dem

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=200, step=2)
    cu = st.CloseUp(st.ROI.circle((100.0, 100.0), 60.0), offset=(0.0, 0.0, 50.0), scale=2.0)
    layer = closeup.closeup_layers(heights, [cu], device="cpu")[0]
    content = closeup._content_faces(layer, cu)[0]
    assert content.size > 10000
    used = sorted_unique(content)
    assert np.array_equal(used, np.unique(content))
    assert np.array_equal(closeup._drawn_bounds(layer, cu), closeup._drawn_bounds(layer, cu, np.unique(content)))


def test_a_tins_extent_is_computed_once_and_right():
    # every TIN close-up recomputed the extent over all used points (~11 ms at 1 M faces); points are read-only,
    # so it is kept. A stray point on no face stays out of it.
    points = np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 2.0], [0.0, 3.0, 3.0], [4.0, 3.0, 4.0], [1e9, -1e9, 0.0]])
    tin = st.Terrain.from_mesh(trimesh.Trimesh(points, [[0, 1, 3], [0, 3, 2]], process=False))
    first = tin.extent
    assert first == (0.0, 4.0, 0.0, 3.0)
    assert tin.extent is first  # kept, not recomputed


def test_an_rtin_with_large_boundary_faces_beside_small_ones_is_accepted():
    # adaptive_mesh of a DEM flat but for a rough strip along one edge: the flat area's large faces lie on the
    # boundary, the strip's small ones too. The overlap check paired every small boundary face with every small
    # face in each large cell (3.3 s for these 66 k faces, 21 s at 264 k; 0.06 s and 0.23 s since 7f33d34, figures
    # in benchmarks/RESULTS.md "Session 27", not timed here). It must accept the RTIN and step it.
    rng = np.random.default_rng(0)
    heights = np.zeros((513, 513), np.float32)
    heights[:, :64] = rng.normal(0.0, 10.0, (513, 64))
    rtin = st.adaptive_mesh(heights, error=0.01)
    tin = st.Terrain.from_mesh(trimesh.Trimesh(np.array(rtin.vertices), np.array(rtin.faces), process=False))
    assert len(tin.faces) == len(rtin.faces)
    mesh = st.stepped(tin, interval=5.0, base=0.5)
    assert len(mesh.faces) > len(rtin.faces)


def test_the_overlap_check_still_finds_a_small_face_under_a_large_boundary_face():
    # the searches split by level: a small interior face (no boundary edge) under a large boundary face is found
    # from the large face's side, a small boundary face under it from the small face's side
    rng = np.random.default_rng(0)
    heights = np.zeros((65, 65), np.float32)
    heights[:, :8] = rng.normal(0.0, 10.0, (65, 8))
    rtin = st.adaptive_mesh(heights, error=0.01)
    points, faces = np.array(rtin.vertices), np.array(rtin.faces)
    big = [[70.0, 0.0], [130.0, 0.0], [70.0, 60.0]]  # beside the grid (0 to 64), over nothing: accepted
    for xy, refused in ((big, False), ([[3.0, 3.0], [60.0, 3.0], [3.0, 60.0]], True)):
        v = np.r_[points, np.c_[xy, np.zeros(3)]]
        f = np.r_[faces, [[len(points), len(points) + 1, len(points) + 2]]]
        mesh = trimesh.Trimesh(v, f, process=False)
        if refused:
            with pytest.raises(InvalidInputError, match="overlap in xy"):
                st.Terrain.from_mesh(mesh)
        else:
            st.Terrain.from_mesh(mesh)


def test_the_refusals_delaunay_way_out_works_at_utm_coordinates():
    # a TIN of scattered survey points in UTM (x ~ 5e5, y ~ 4e6 m): scipy's Delaunay of them as given folds a few
    # faces (Qhull's precision at that offset), so that mesh is refused as folded, and the message's own way out,
    # Delaunay(mesh.vertices[:, :2]), gave the same folded mesh again. Taken from the points' corner, it is accepted.
    import re

    pytest.importorskip("scipy")
    import scipy.spatial

    rng = np.random.default_rng(0)
    xy = rng.uniform(0.0, 500.0, (50000, 2)) + [500000.0, 4000000.0]
    points = np.c_[xy, rng.normal(100.0, 1.0, len(xy))]
    mesh = trimesh.Trimesh(points, scipy.spatial.Delaunay(xy).simplices, process=False)
    with pytest.raises(InvalidInputError, match=_FOLDED) as info:
        st.Terrain.from_mesh(mesh)
    names = {"trimesh": trimesh, "scipy": scipy, "mesh": mesh.copy()}  # the message's re-triangulation, as printed
    exec(re.search(r"(mesh = trimesh\.Trimesh\(.*?\.simplices\))", str(info.value)).group(1), names)
    again = names["mesh"]
    tin = st.Terrain.from_mesh(again)
    assert np.array_equal(again.vertices, points)  # every point kept (Qhull left out 226 of them as given)
    tri = again.triangles[:, :, :2] - xy.min(axis=0)
    area2 = _cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert area2.min() > 0 and len(tin.faces) == len(again.faces)  # every face kept, none folded
    assert 0.5 * area2.sum() == pytest.approx(scipy.spatial.ConvexHull(xy - xy.min(axis=0)).volume, rel=1e-9)


def test_heightfield_mesh_takes_a_grid_terrain_with_its_own_spacing_and_origin():
    """heightfield_mesh(load_dem(...)) read the Terrain as an array: "dtype object", naming no way out. A grid
    Terrain is meshed with its own spacing and origin, as Terrain.mesh(); spacing/origin beside it, or a TIN, are
    refused by name."""
    terrain = st.Terrain.from_heights(_H, spacing=(30.0, -30.0), origin=(376000.0, 3.8e6))
    mesh, expected = st.heightfield_mesh(terrain), terrain.mesh()
    np.testing.assert_array_equal(mesh.vertices, expected.vertices)
    np.testing.assert_array_equal(mesh.faces, expected.faces)
    assert mesh.bounds[0][0] == 376000.0 and mesh.bounds[1][1] == 3.8e6
    with pytest.raises(InvalidInputError, match=r"^spacing/origin apply to a raw \(H, W\) array; the Terrain has"):
        st.heightfield_mesh(terrain, spacing=(1.0, 1.0))
    tin = st.Terrain.from_mesh(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 1]], [[0, 1, 2]], process=False))
    with pytest.raises(InvalidInputError, match=r"got a TIN Terrain \(its mesh is terrain.mesh\(\)\)$"):
        st.heightfield_mesh(tin)


def test_a_pyvista_dataset_as_terrain_is_named_with_the_way_in():
    """A pyvista user passing a grid or mesh to stepped(), circular_lens or topographic_layer was told "heights must
    be a real-valued (H, W) array; got dtype object" (numpy made a 0-d object array of it), naming neither the
    dataset nor the accessor. Found by walking through the library as a pyvista user. Now the dataset is named, a
    grid with grid.stepterrain.terrain() / .stepped(), a PolyData with pyvista_accessor.from_polydata (keeping its
    colours, where pyvista.to_trimesh drops them); those ways in step."""
    pv = pytest.importorskip("pyvista")
    import stepterrain.pyvista_accessor  # noqa: F401 - registers the accessor

    grid = pv.ImageData(dimensions=(_H.shape[1], _H.shape[0], 1))
    grid["elevation"] = _H.ravel()
    surface = pv.wrap(st.heightfield_mesh(_H))  # a TIN as PolyData
    calls = (lambda t: st.stepped(t, interval=2.0), lambda t: st.circular_lens(t, (1.0, 1.0), 1.0))
    for call in calls:
        for dataset in (grid, grid.cast_to_structured_grid()):
            way_in = rf"^terrain must be .*; got a pyvista\.{type(dataset).__name__} \(pass grid\.stepterrain\.terrain"
            with pytest.raises(InvalidInputError, match=way_in):
                call(dataset)
        with pytest.raises(InvalidInputError, match=r"got a pyvista\.PolyData \(a TIN: pass stepterrain\."
                                                    r"pyvista_accessor\.from_polydata\(mesh\.triangulate\(\)\)"):
            call(surface)
    expected = st.stepped(_H, interval=2.0)
    assert st.stepped(grid.stepterrain.terrain(), interval=2.0).area == pytest.approx(expected.area, rel=1e-6)
    from stepterrain.pyvista_accessor import from_polydata

    assert st.stepped(from_polydata(surface.triangulate()), interval=2.0).area == pytest.approx(expected.area,
                                                                                                rel=1e-6)


def test_heightfield_mesh_is_checked_against_the_memory_budget_before_it_is_built(monkeypatch):
    """heightfield_mesh (Terrain.mesh, the close-up overview, a drape on the DEM's own surface) had no memory check:
    a DEM read under the budget at 4 bytes a node became a mesh of ~144 bytes a node at its peak (int64 faces,
    float64 vertices and the index grids they are built from; more with nodata), so a budget that admitted the DEM
    let its mesh take 36 times as much. Now the mesh is refused before anything is allocated, naming the grid."""
    import stepterrain as st
    import stepterrain.terrain as terrain_module
    from stepterrain.errors import OutputTooLargeError

    heights = np.zeros((300, 400), np.float32)
    previous = st.set_memory_budget(144 * 300 * 400 - 1)
    try:
        monkeypatch.setattr(terrain_module, "grid_faces", lambda *a, **k: pytest.fail("allocated before the check"))
        with pytest.raises(OutputTooLargeError, match=r"^the heightfield mesh of a 300 x 400 grid would need "
                                                      r"16\.5 MiB, over the memory budget of 16\.5 MiB; crop or "
                                                      r"coarsen the terrain"):
            st.heightfield_mesh(heights)
        with_nodata = heights.copy()
        with_nodata[5, 5] = np.nan
        st.set_memory_budget(144 * 300 * 400)  # enough without nodata, not with it
        with pytest.raises(OutputTooLargeError, match=r"^the heightfield mesh of a 300 x 400 grid would need "
                                                      r"22\.4 MiB"):
            st.Terrain.from_heights(with_nodata, spacing=(1.0, 1.0)).mesh()
        monkeypatch.undo()
        mesh = st.heightfield_mesh(heights)
        assert (len(mesh.vertices), len(mesh.faces)) == (300 * 400, 2 * 299 * 399)
    finally:
        st.set_memory_budget(previous)


# ------------------------------------------------------------------ TINs whose points are copied per face or per part
def _boundary_edges(mesh):
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return int((counts == 1).sum())


@pytest.mark.parametrize("ext", [".stl", ".glb"])
def test_a_tin_read_from_stl_or_from_a_gltf_of_two_parts_steps_welded(tmp_path, ext):
    """An STL holds three points per face (read_mesh, as trimesh, gives a triangle soup) and a glTF exported as two
    primitives or nodes holds two copies of the points on their seam. The TIN's edge table paired edges by point
    index only, so these were stepped as separate faces: no vertex shared (1 boundary edge per output edge), and
    solid=True closed every face of the STL (or each part) with its own skirt, walls back to back inside the solid,
    twice as many faces as the same TIN welded. Coincident points (same x, y, z) are welded: the steps of the file
    equal those of the welded TIN."""
    from stepterrain.export import read_mesh

    tin = _sheet(7, 8, spacing=10.0, origin=(394000.0, 3798000.0))
    tin.vertices[:, 2] = np.round(tin.vertices[:, 2] * 8.0, 3)
    path = tmp_path / f"tin{ext}"
    if ext == ".stl":
        tin.export(path)
    else:  # two parts, each with its own copy of the points on the seam; y-up, as glTF holds them (read z-up)
        half = len(tin.faces) // 2
        scene = trimesh.Scene()
        y_up = tin.vertices[:, [0, 2, 1]] * [1, 1, -1]
        for part in (tin.faces[:half], tin.faces[half:]):
            used = np.unique(part)
            scene.add_geometry(trimesh.Trimesh(y_up[used], np.searchsorted(used, part), process=False))
        scene.export(path)
    read = read_mesh(path)
    assert len(read.vertices) > len(tin.vertices)  # copies: read as the file holds them
    for solid in (False, True):
        want = st.stepped(tin, interval=4.0, base=0.25, solid=solid)
        got = st.stepped(read, interval=4.0, base=0.25, solid=solid)
        assert (len(got.vertices), len(got.faces)) == (len(want.vertices), len(want.faces))
        assert _boundary_edges(got) == _boundary_edges(want) == (0 if solid else _boundary_edges(want))
        assert got.is_watertight == solid
        np.testing.assert_allclose(np.sort(got.vertices, axis=0), np.sort(want.vertices, axis=0), atol=2e-3)
        assert got.volume == pytest.approx(want.volume, rel=1e-6) if solid else got.area == pytest.approx(want.area)


def test_welding_keeps_points_apart_where_colours_differ_or_a_face_would_lose_a_corner():
    """Coincident points are welded only where what the steps carry agrees: a colour seam keeps its two colours,
    and a face two of whose corners coincide (zero area) keeps them (welding them would leave it two corners)."""
    tin = _sheet(4, 4)
    soup = _soup(tin)
    colours = np.repeat(np.array([[255, 0, 0, 255], [0, 0, 255, 255]], np.uint8), [9, len(soup.vertices) - 9], axis=0)
    soup.visual = trimesh.visual.ColorVisuals(soup, vertex_colors=colours)
    faces = st.Terrain.from_mesh(soup).faces
    seam = len(np.unique(faces))
    assert len(np.unique(tin.faces)) < seam < len(soup.vertices)  # welded, except across the first 3 faces' colours
    steps = st.stepped(soup, interval=0.5)
    assert {tuple(c) for c in np.asarray(steps.visual.vertex_colors)} == {(255, 0, 0, 255), (0, 0, 255, 255)}
    sliver = trimesh.Trimesh(np.vstack([tin.vertices, tin.vertices[:2]]),
                             np.vstack([tin.faces, [[0, len(tin.vertices), 1]]]), process=False)
    assert st.Terrain.from_mesh(sliver).faces[-1].tolist() == [0, len(tin.vertices), 1]
    assert len(st.stepped(sliver, interval=0.5).faces) >= len(st.stepped(tin, interval=0.5).faces)


def test_a_y_up_terrain_is_refused_with_the_turn_that_makes_it_z_up(tmp_path):
    """Blender and three.js export a terrain to OBJ (and glTF) with its heights along y, and read_mesh gives an OBJ's
    coordinates as stored (the format has no axis convention). Such a TIN folds over or overlaps itself in xy, and the
    refusal spoke only of decimation and Delaunay. It now says the faces face along y and names the turn to z-up
    (what Blender's importer does), after which the TIN steps as the z-up one. A glTF is y-up by its spec: read_mesh
    turns it z-up itself, and it steps as it is."""
    from stepterrain.export import read_mesh

    tin = _sheet(6, 7, spacing=10.0)
    tin.vertices[:, 2] *= 4.0
    y_up = tin.copy()
    y_up.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # as glTF exporters store it
    np.testing.assert_allclose(y_up.vertices[:, 1], tin.vertices[:, 2], atol=1e-9)
    path = tmp_path / "blender.obj"
    y_up.export(path)
    mesh = read_mesh(path)
    hint = r"Its faces face along y more than along z, .* if it is one, turn it z-up, mesh\.apply_transform\("
    with pytest.raises(InvalidInputError, match=r"^terrain mesh faces must project one-to-one onto the xy plane; .*"
                                                + hint):
        st.stepped(mesh, interval=2.0)
    flat = y_up.copy()
    flat.vertices[:, 1] = 5.0  # and a flat one (its heights along y alike): a line in xy
    with pytest.raises(InvalidInputError, match=r"so it is no height field\. " + hint):
        st.stepped(flat, interval=2.0)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # the turn the message names
    want = st.stepped(tin, interval=2.0)
    got = st.stepped(mesh, interval=2.0)
    assert len(got.faces) == len(want.faces) and got.area == pytest.approx(want.area, rel=1e-5)
    y_up.export(tmp_path / "blender.glb")  # glTF: y-up by its spec, read z-up
    got = st.stepped(read_mesh(tmp_path / "blender.glb"), interval=2.0)
    assert len(got.faces) == len(want.faces) and got.area == pytest.approx(want.area, rel=1e-5)
    for other in (trimesh.creation.box(), trimesh.creation.icosphere(), _joined(_sheet(), _sheet(z=9.0))):
        with pytest.raises(InvalidInputError) as info:  # not terrains with y up: no such hint
            st.stepped(other, interval=0.5)
        assert "along y" not in str(info.value)


def test_a_z_up_gltf_read_turned_is_refused_with_the_turn_that_keeps_it_right_side_up(tmp_path):
    """trimesh's own export (mesh.export("x.glb")) writes a z-up terrain's coordinates as stored, against glTF's y-up
    spec; read_mesh turns any glTF z-up, so the terrain's heights run down y, and the refusal named the +90 degree
    turn of a y-up file: followed, the terrain stepped upside down (heights negated, mirrored), without a word. The
    hint now follows the way the faces face and names -90 degrees, after which it steps as the z-up TIN."""
    from stepterrain.export import read_mesh

    tin = _sheet(6, 7, spacing=10.0)
    tin.vertices[:, 2] = 100.0 + 4.0 * tin.vertices[:, 2]
    tin.export(tmp_path / "trimesh.glb")  # z up as stored: glTF readers show it on its edge
    mesh = read_mesh(tmp_path / "trimesh.glb")
    with pytest.raises(InvalidInputError, match=r"faces face along y more than along z, .* turn it z-up, "
                                                r"mesh\.apply_transform\(trimesh\.transformations\.rotation_matrix"
                                                r"\(-np\.pi / 2, \[1, 0, 0\]\)\)") as info:
        st.stepped(mesh, interval=2.0)
    turn = float(str(info.value).split("rotation_matrix(")[1].split(" / 2")[0].replace("np.pi", "1"))
    mesh.apply_transform(trimesh.transformations.rotation_matrix(turn * np.pi / 2, [1, 0, 0]))  # the turn named
    np.testing.assert_allclose(mesh.vertices, tin.vertices, atol=1e-4)  # right side up, not mirrored
    want, got = st.stepped(tin, interval=2.0), st.stepped(mesh, interval=2.0)
    assert len(got.faces) == len(want.faces) and got.area == pytest.approx(want.area, rel=1e-5)
    np.testing.assert_allclose(got.bounds, want.bounds, atol=1e-4)


def test_a_utm_tin_rounded_by_a_float32_file_is_refused_saying_so(tmp_path):
    """A glTF (or STL) written by another program holds float32 positions; at a UTM northing those lie 0.25 m apart,
    so a dense TIN at map coordinates comes back with its points rounded and some faces folded. The refusal spoke of
    decimation; it now says the points are float32 values that far apart (the file rounded them), and the Delaunay
    it names steps them. A TIN at float64 map coordinates, or rounded at local ones, gets no such hint."""
    from scipy.spatial import Delaunay

    from stepterrain.export import read_mesh

    rng = np.random.default_rng(1)
    xy = rng.random((3000, 2)) * 100.0 + (394000.0, 3798000.0)
    tin = trimesh.Trimesh(np.column_stack([xy, 100.0 + 5.0 * np.sin(xy[:, 0] / 7.0)]),
                          Delaunay(xy - xy.min(axis=0)).simplices, process=False)
    assert len(st.stepped(tin, interval=1.0).faces)
    path = tmp_path / "utm.glb"
    y_up = tin.vertices[:, [0, 2, 1]] * [1, 1, -1]  # as glTF holds it (read_mesh turns it z-up)
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Trimesh(y_up.astype(np.float32), tin.faces,
                                                                       process=False).scene()))
    rounded = read_mesh(path)
    assert 0.0 < np.abs(rounded.vertices - tin.vertices).max() <= 0.125
    with pytest.raises(InvalidInputError, match=r"fold over .*\. Its x and y are all float32 values \(as glTF and STL "
                                                r"store them\), which at these coordinates lie 0\.25 apart: the file "
                                                r"rounded the points"):
        st.stepped(rounded, interval=1.0)
    corner = rounded.vertices[:, :2].min(axis=0)
    remeshed = trimesh.Trimesh(rounded.vertices, Delaunay(rounded.vertices[:, :2] - corner).simplices, process=False)
    assert len(st.stepped(remeshed, interval=1.0).faces)
    local = trimesh.Trimesh(rounded.vertices - (*corner, 0.0), rounded.faces, process=False)
    for other in (local, _joined(_sheet(), _sheet(z=9.0))):  # rounded at local coordinates; float64 stacked sheets
        with pytest.raises(InvalidInputError) as info:
            st.stepped(other, interval=1.0)
        assert "float32" not in str(info.value)


def test_a_point_cloud_is_refused_with_the_triangulation_that_steps_it(tmp_path):
    """A TIN's points without faces (a PLY of survey points, read by read_mesh as a mesh without faces) was refused
    as "terrain mesh has no faces; expected a triangulated surface", leaving the user to find out how. It now names
    the point count and the Delaunay triangulation in xy (from the points' corner), which steps."""
    from scipy.spatial import Delaunay

    from stepterrain.export import read_mesh

    rng = np.random.default_rng(2)
    xyz = np.column_stack([rng.random((200, 2)) * 500.0 + (394000.0, 3798000.0), rng.random(200) * 40.0])
    path = tmp_path / "survey.ply"
    path.write_bytes(trimesh.exchange.ply.export_ply(trimesh.PointCloud(xyz)))
    mesh = read_mesh(path)
    with pytest.raises(InvalidInputError, match=r"^terrain mesh has no faces; expected a triangulated surface; got "
                                                r"200 points without faces \(a point cloud.*\): triangulate them in xy "
                                                r"first, e\.g\. mesh = trimesh\.Trimesh\(mesh\.vertices, "
                                                r"scipy\.spatial\.Delaunay\("):
        st.stepped(mesh, interval=5.0)
    mesh = trimesh.Trimesh(mesh.vertices, Delaunay(mesh.vertices[:, :2] - mesh.vertices[:, :2].min(axis=0)).simplices)
    assert len(st.stepped(mesh, interval=5.0).faces) > len(mesh.faces)
    with pytest.raises(InvalidInputError, match=r"^terrain mesh has no faces; expected a triangulated surface$"):
        st.stepped(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), interval=5.0)  # nothing at all


def test_a_zero_area_face_in_a_triangle_soup_keeps_only_its_coincident_corners_apart():
    """An STL's sliver (two corners at one point, as CAD exports leave them) keeps those corners apart when the soup
    is welded (welding them would leave the face two corners); its third corner was kept apart too, with every copy
    of it in the soup, so the faces round it stayed unwelded (walls inside the solid there). Only the coincident
    point stays apart now."""
    tin = _sheet(5, 6)
    a, b = tin.faces[7][:2]
    soup = _soup(trimesh.Trimesh(np.vstack([tin.vertices, tin.vertices[a]]),
                                 np.vstack([tin.faces, [[len(tin.vertices), a, b]]]), process=False))
    faces = st.Terrain.from_mesh(soup).faces
    corners = soup.vertices[soup.faces]
    at_b = (corners == tin.vertices[b]).all(axis=2)
    assert at_b[-1].any() and len(np.unique(faces[at_b])) == 1  # every copy of b welded, the sliver's included
    at_a = (corners == tin.vertices[a]).all(axis=2)
    assert len(np.unique(faces[at_a])) == at_a.sum()  # the coincident point's copies as given
    steps = st.stepped(soup, interval=0.5, base=0.25, solid=True)
    assert steps.is_watertight


def test_an_edge_used_twice_in_one_direction_is_refused_naming_the_faces():
    """A mesh from another program with a face twice (the same three indices, as some exporters and merges leave
    them) was refused as "an edge is used twice in the same direction" without saying where: among 10^5 faces the
    user could not find it. The refusal now names the two faces by their index in the mesh given (past dropped
    nodata faces), the edge's points, and for two copies of one face the way to drop them, after which it steps."""
    mesh = st.heightfield_mesh(np.random.default_rng(0).random((5, 5)))
    mesh.vertices[2, 2] = np.nan  # faces before the copy are dropped: the indices are still the mesh's own
    doubled = trimesh.Trimesh(mesh.vertices, np.vstack([mesh.faces, mesh.faces[30:31]]), process=False)
    with pytest.raises(InvalidInputError, match=r"an edge is used twice in the same direction \(overlapping or "
                                                r"inconsistently wound faces\): faces 30 and 32 both run from point "
                                                r"\d+ to point \d+ \(two copies of one face: drop one, e\.g\. "
                                                r"mesh\.update_faces\(mesh\.unique_faces\(\)\)\)$"):
        st.stepped(doubled, interval=0.2)
    doubled.update_faces(doubled.unique_faces())
    assert len(st.stepped(doubled, interval=0.2).faces) == len(st.stepped(mesh, interval=0.2).faces)


def test_a_grid_built_in_degrees_is_read_into_local_metres_as_load_dem_reads_the_same_geotiff(tmp_path):
    """Terrain.from_heights(h, spacing=(0.000833, -0.000833), origin=(lon, lat), crs="EPSG:4326") kept its degrees as
    metres: cells of a millimetre under heights of hundreds of metres, slopes 10^5 too steep (an ROI's slope_above
    marked 99.5 % of the terrain steep, renders asked for z_scale 8e-5). It now gives the Terrain load_dem gives for
    the same grid written as a GeoTIFF; a projected or no CRS keeps the grid as given; metres labelled geographic are
    refused naming crs, spacing and origin."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    rng = np.random.default_rng(4)
    heights = (1500.0 + 300.0 * rng.random((40, 50))).astype(np.float32)
    step, lon, lat = 0.000833, -105.5, 40.1
    built = st.Terrain.from_heights(heights, spacing=(step, -step), origin=(lon, lat), crs="EPSG:4326")
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", height=40, width=50, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(step, 0.0, lon - 0.5 * step, 0.0, -step, lat + 0.5 * step)) as dst:
        dst.write(heights, 1)
    read = st.load_dem(path)
    assert built.spacing == read.spacing and built.origin == read.origin == (0.0, 0.0)
    assert built.crs == read.crs and built.crs.startswith("+proj=eqc")
    assert 70.0 < built.spacing[0] < 72.0 and -93.0 < built.spacing[1] < -92.0  # metres, dy north-up
    np.testing.assert_array_equal(built.heights, read.heights)
    assert "EPSG:4326 degrees as local metres" in built.source
    direct = st.Terrain(kind="grid", heights=heights, spacing=(step, -step), origin=(lon, lat), crs="EPSG:4326")
    assert (direct.spacing, direct.origin, direct.crs) == (read.spacing, read.origin, read.crs)
    roi = st.ROI.slope_above(built, 45.0)  # a few cells of 300 m relief over 65 m: steep, but not all of them
    assert 0.0 < float(np.mean(np.asarray(roi.mask) > 0.5)) < 0.9

    for crs in ("EPSG:32613", None):  # metres stay metres
        kept = st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(480000.0, 4440000.0), crs=crs)
        assert (kept.spacing, kept.origin, kept.crs) == ((30.0, -30.0), (480000.0, 4440000.0), crs)
    with pytest.raises(InvalidInputError, match=r"^crs 'EPSG:4326' is geographic, so spacing \(30\.0, -30\.0\) and "
                                                r"origin \(480000\.0, 4440000\.0\) are read as degrees .*latitudes run "
                                                r".*pass the projected CRS they are in \(or crs=None\)$"):
        st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(480000.0, 4440000.0), crs="EPSG:4326")


def test_from_mesh_carries_the_mesh_s_crs_and_source_to_the_tin_and_its_steps(tmp_path):
    """Only stepped(mesh) copied a TIN's ``metadata["crs"]`` and ``["source"]`` onto its result: Terrain.from_mesh
    dropped them, so stepped(Terrain.from_mesh(mesh)), describe_dem and every other mesh built from the Terrain (a
    DEM's mesh read back from a file in UTM) named no CRS. from_mesh now reads them (text, not blank; a source given
    wins), and the cache does not hand back a TIN of the mesh's old CRS."""
    from stepterrain.export import read_mesh, save_mesh
    from stepterrain.io import describe_dem

    dem = st.sample_dem().crop((390000.0, 391500.0, 3800000.0, 3801200.0))
    mesh = read_mesh(save_mesh(dem.mesh(), tmp_path / "dem.ply"))
    assert mesh.metadata["crs"] == dem.crs == "EPSG:32611"
    tin = st.Terrain.from_mesh(mesh)
    assert (tin.kind, tin.crs, tin.source) == ("tin", "EPSG:32611", mesh.metadata["source"])
    assert describe_dem(tin)["crs"] == "EPSG:32611"
    direct, via_terrain = st.stepped(mesh, interval=50.0), st.stepped(tin, interval=50.0)
    np.testing.assert_array_equal(direct.vertices, via_terrain.vertices)
    for steps in (direct, via_terrain):
        assert (steps.metadata["crs"], steps.metadata["source"]) == ("EPSG:32611", mesh.metadata["source"])
    assert st.Terrain.from_mesh(mesh, source="given.ply").source == "given.ply"  # the argument wins
    mesh.metadata["crs"] = "EPSG:32612"  # a changed CRS: not the cached TIN of the old one
    assert st.Terrain.from_mesh(mesh).crs == "EPSG:32612"
    for value in ("  ", 32611, None):  # blank or not text: no CRS
        mesh.metadata["crs"] = value
        assert st.Terrain.from_mesh(mesh).crs is None
        assert "crs" not in st.stepped(mesh, interval=50.0).metadata


def test_from_heights_in_degrees_names_the_grid_as_given_in_its_warnings_refusals_and_source():
    """degrees_as_local_metres places the degrees as load_dem places a file's (io._placement): the warnings and the
    source name the grid by the ``source`` given ("the heights" without one), at the caller's line, and a refusal
    names crs, spacing and origin with the nodes' reason (latitudes or longitudes), not a file."""
    import warnings

    heights = np.add.outer(np.arange(51.0), np.arange(4.0)).astype(np.float32)  # 50 degrees of latitude: the one
    for source, name in (("tile.tif", "tile.tif"), (None, "the heights")):  # spacing errs, and is told
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t = st.Terrain.from_heights(heights, spacing=(1.0, -1.0), origin=(10.0, 60.0), crs="EPSG:4326",
                                        source=source)
        told = [w for w in caught if "degrees read as local metres with one spacing" in str(w.message)]
        assert len(told) == 1 and str(told[0].message).startswith(f"{name}: EPSG:4326 degrees read as local metres")
        assert told[0].filename == __file__
        assert t.source.startswith(f"{name} (EPSG:4326 degrees as local metres: node (0, 0) at lon 10.000000000")
    refused = (r"^crs 'EPSG:4326' is geographic, so spacing \(1\.0, -1\.0\) and origin \(-180\.0, 10\.0\) are read "
               r"as degrees \(and made local metres, as load_dem makes a file in degrees\), but the grid's node "
               r"longitudes span 399 degrees \(400 columns of 1\); expected at most 360 \(.*\); if they are metres, "
               r"pass the projected CRS they are in \(or crs=None\)$")
    with pytest.raises(InvalidInputError, match=refused):
        st.Terrain.from_heights(np.zeros((3, 400), np.float32), spacing=(1.0, -1.0), origin=(-180.0, 10.0),
                                crs="EPSG:4326")


def test_a_placed_grid_s_crs_is_not_looked_up_again_by_load_dem_or_its_crops(monkeypatch):
    """load_dem placed a file (io._placement), then Terrain.from_heights looked its CRS up again
    (degrees_as_local_metres: a rasterio CRS parse and is_geographic for EPSG:32611), and so did every crop and
    coarsening of a Terrain, whose CRS is placed already. Only a grid given in a CRS is placed now: once, with the
    same refusal for degrees that are none."""
    import stepterrain.io as stio

    placed = stio.degrees_as_local_metres
    calls: list[str | None] = []

    def counted(shape, spacing, origin, crs, source):
        calls.append(crs)
        return placed(shape, spacing, origin, crs, source)

    monkeypatch.setattr(stio, "degrees_as_local_metres", counted)
    dem = st.sample_dem()
    x0, x1, y0, y1 = dem.extent
    crop = dem.crop((x0, (x0 + x1) / 2, y0, (y0 + y1) / 2))
    coarse = dem.coarsen(4)
    assert calls == [] and dem.crs == crop.crs == coarse.crs == "EPSG:32611"
    heights = np.add.outer(np.arange(40.0), np.arange(50.0)).astype(np.float32)
    geo = st.Terrain.from_heights(heights, spacing=(0.000833, -0.000833), origin=(-105.5, 40.1), crs="EPSG:4326")
    part = geo.crop((0.0, 20 * geo.spacing[0], 20 * geo.spacing[1], 0.0))
    assert calls == ["EPSG:4326"] and geo.crs.startswith("+proj=eqc") and part.crs == geo.crs
    assert part.spacing == geo.spacing and part.heights.shape == (21, 21)
    with pytest.raises(InvalidInputError, match=r"^crs 'EPSG:4326' is geographic, .* latitudes run "):
        st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(480000.0, 4440000.0), crs="EPSG:4326")


def test_a_grid_built_in_a_crs_in_feet_is_read_into_metres_as_load_dem_reads_the_same_geotiff(tmp_path):
    """Terrain.from_heights(h, spacing=(100, -100), origin=(x, y), crs="EPSG:2229") kept its US survey feet as
    metres while load_dem of the same grid written as a GeoTIFF converts them (the CRS its metre twin EPSG:26945):
    the same DEM was 3.28 times wider one way than the other, and its heights in metres stood on feet (slopes 3.28
    times too steep). from_heights now gives load_dem's Terrain, with its warning that the heights are taken as
    given; naming height_unit silences it, and international feet (+units=ft) convert by 0.3048."""
    rasterio = pytest.importorskip("rasterio")
    import warnings

    from rasterio.transform import Affine

    heights = np.ascontiguousarray(st.sample_dem().heights[:160, :240])
    step, x0, y0 = 100.0, 6_450_000.0, 1_950_000.0  # 100 ft cells, node (0, 0) in California zone 5 (ftUS)
    path = tmp_path / "dem_ft.tif"
    with rasterio.open(path, "w", driver="GTiff", height=160, width=240, count=1, dtype="float32", crs="EPSG:2229",
                       transform=Affine(step, 0.0, x0 - 0.5 * step, 0.0, -step, y0 + 0.5 * step)) as dst:
        dst.write(heights, 1)
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        read = st.load_dem(path)
    with pytest.warns(UserWarning, match=r"^dem_ft\.tif: EPSG:2229 is in US survey foot units, so spacing and origin "
                                         r"were converted to metres; the heights are taken as given") as told:
        built = st.Terrain.from_heights(heights, spacing=(step, -step), origin=(x0, y0), crs="EPSG:2229",
                                        source="dem_ft.tif")
    assert told[0].filename == __file__  # at the caller's line
    assert built.crs == read.crs == "EPSG:26945" and built.source == read.source
    assert built.spacing == pytest.approx(read.spacing, rel=1e-12)
    assert built.spacing == pytest.approx((step * 1200 / 3937, -step * 1200 / 3937), rel=1e-12)
    assert built.origin == pytest.approx(read.origin, rel=1e-12)
    np.testing.assert_array_equal(built.heights, read.heights)
    np.testing.assert_allclose(built.mesh().vertices, read.mesh().vertices, rtol=1e-12, atol=1e-6)
    assert built.mesh().area == pytest.approx(read.mesh().area, rel=1e-9)

    with warnings.catch_warnings():  # the heights' unit named: nothing to warn of; built directly: the same
        warnings.simplefilter("error")
        named = st.Terrain.from_heights(heights, spacing=(step, -step), origin=(x0, y0), crs="EPSG:2229",
                                        height_unit="m")
        direct = st.Terrain(kind="grid", heights=heights, spacing=(step, -step), origin=(x0, y0), crs="EPSG:2229",
                            height_unit="m")
    for t in (named, direct):
        assert (t.spacing, t.origin, t.crs) == (built.spacing, built.origin, built.crs)
        assert t.source.startswith("the heights (EPSG:2229 US survey foot as metres")
    # x0 feet taken as international feet lie 1500 km east of that central meridian: its map scale warned of
    with pytest.warns(UserWarning, match="is a projection whose metres are ground metres only near its standard"):
        intl = st.Terrain.from_heights(heights, spacing=(step, -step), origin=(x0, y0), height_unit="m",
                                       crs="+proj=tmerc +lat_0=0 +lon_0=-117 +k=0.9996 +x_0=500000 +y_0=0 "
                                           "+ellps=GRS80 +units=ft +no_defs")
    assert intl.spacing == pytest.approx((step * 0.3048, -step * 0.3048), rel=1e-12)
    assert intl.origin == pytest.approx((x0 * 0.3048, y0 * 0.3048), rel=1e-12)
    again = st.Terrain.from_heights(heights, spacing=built.spacing, origin=built.origin, crs=built.crs)
    assert (again.spacing, again.origin) == (built.spacing, built.origin)  # the metre twin stays as given


@pytest.mark.parametrize("crs, spacing, origin, match", [
    ("EPSG:2229", (100.0, -100.0), (6_450_000.0, 1_950_000.0), "EPSG:2229 is in US survey foot units"),
    ("EPSG:4326", (0.01, -0.01), (-105.0, 61.0), "EPSG:4326 degrees read as local metres"),
])
def test_a_terrain_built_directly_warns_at_the_caller_s_line(crs, spacing, origin, match):
    """Terrain(kind="grid", ..., crs=...) converting feet or degrees warned at '<string>' (the dataclass's generated
    __init__, the first frame outside the package's files), not at the line that built it, as from_heights does."""
    pytest.importorskip("rasterio")
    heights = np.zeros((200, 3), np.float32)
    with pytest.warns(UserWarning, match=match) as told:
        st.Terrain(kind="grid", heights=heights, spacing=spacing, origin=origin, crs=crs)
    assert {w.filename for w in told if re.search(match, str(w.message))} == {__file__}


def _tin_of(heights: np.ndarray, spacing: tuple[float, float], origin: tuple[float, float], crs: str,
            ) -> trimesh.Trimesh:
    """The grid's surface as a TIN in the grid's own units (feet, degrees), its CRS in the metadata as a mesh file
    read back with read_mesh names it."""
    mesh = st.Terrain.from_heights(heights, spacing=spacing, origin=origin).mesh()
    mesh.metadata.clear()
    mesh.metadata["crs"] = crs
    return mesh


def test_a_tin_in_a_crs_in_feet_is_read_into_metres_as_load_dem_reads_the_grid(tmp_path):
    """Terrain.from_mesh of a mesh whose CRS is EPSG:2229 (US survey feet) kept its points' x and y in feet under
    heights taken as metres, while load_dem (and from_heights) of the same surface as a grid makes them metres in
    EPSG:26945: the TIN was 3.28 times wider, its slopes 3.28 times flatter. It now gives the grid's points, with
    the warning that the heights are taken as given (at the caller's line; height_unit silences it); built directly
    the same, and a mesh of the TIN (its metre twin CRS) is not converted again."""
    rasterio = pytest.importorskip("rasterio")
    import warnings

    from rasterio.transform import Affine

    heights = np.ascontiguousarray(st.sample_dem().heights[:120, :160])
    step, x0, y0 = 100.0, 6_450_000.0, 1_950_000.0
    path = tmp_path / "dem_ft.tif"
    with rasterio.open(path, "w", driver="GTiff", height=120, width=160, count=1, dtype="float32", crs="EPSG:2229",
                       transform=Affine(step, 0.0, x0 - 0.5 * step, 0.0, -step, y0 + 0.5 * step)) as dst:
        dst.write(heights, 1)
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        grid = st.load_dem(path)
    mesh = _tin_of(heights, (step, -step), (x0, y0), "EPSG:2229")
    with pytest.warns(UserWarning, match=r"^the mesh: EPSG:2229 is in US survey foot units, so x and y of its points "
                                         r"were converted to metres; the heights are taken as given") as told:
        tin = st.Terrain.from_mesh(mesh)
    assert told[0].filename == __file__
    assert tin.crs == grid.crs == "EPSG:26945" and tin.source.startswith("the mesh (EPSG:2229 US survey foot as metres")
    expected = grid.mesh().vertices
    np.testing.assert_allclose(tin.points, expected, rtol=1e-12, atol=1e-6)
    np.testing.assert_array_equal(tin.heights, mesh.vertices[:, 2].astype(np.float32))  # heights untouched
    assert tin.mesh().area == pytest.approx(grid.mesh().area, rel=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        named = st.Terrain.from_mesh(mesh, height_unit="m")
        direct = st.Terrain(kind="tin", heights=None, points=mesh.vertices, faces=mesh.faces, crs="EPSG:2229",
                             height_unit="m")
        again = st.Terrain.from_mesh(tin.mesh())  # its metadata names EPSG:26945: metres already
    for t in (named, direct, again):
        assert t.crs == "EPSG:26945"
        np.testing.assert_allclose(t.points, expected, rtol=1e-12, atol=1e-6)
    assert named.height_unit == direct.height_unit == "m"
    assert st.Terrain.from_mesh(mesh, height_unit="m") is named  # cached per CRS and height unit as given


def test_a_tin_in_degrees_is_read_into_local_metres_as_a_grid_in_degrees_is():
    """Terrain.from_mesh of a mesh in EPSG:4326 kept its degrees as x and y under heights in metres (slopes 10^5 too
    steep) while from_heights and load_dem make a grid in degrees local metres. It now makes them local metres of a
    spherical +proj=eqc CRS true at the points' middle latitude, as the grid's: the same cell sizes, extent and area;
    x and y that are no degrees are refused as a grid's are, and the TIN's own mesh is not converted again."""
    pytest.importorskip("rasterio")
    heights = np.ascontiguousarray(st.sample_dem().heights[:90, :120])
    spacing, origin = (0.0003, -0.0003), (-117.3, 34.1)
    grid = st.Terrain.from_heights(heights, spacing=spacing, origin=origin, crs="EPSG:4326")
    tin = st.Terrain.from_mesh(_tin_of(heights, spacing, origin, "EPSG:4326"))
    assert tin.crs.startswith("+proj=eqc +lat_ts=34.086650000 +lat_0=34.073300000 +lon_0=-117.300000000 ")
    assert tin.source.startswith("the mesh (EPSG:4326 degrees as local metres")
    vertices = grid.mesh().vertices
    np.testing.assert_allclose(np.ptp(tin.points[:, :2], axis=0), np.ptp(vertices[:, :2], axis=0), rtol=1e-12)
    # the same points, the grid's (0, 0) at node (0, 0) (the top-left), the TIN's at the lowest lon and lat
    np.testing.assert_allclose(tin.points[:, :2] - tin.points[:, :2].min(axis=0),
                               vertices[:, :2] - vertices[:, :2].min(axis=0), rtol=1e-12, atol=1e-6)
    assert tin.mesh().area == pytest.approx(grid.mesh().area, rel=1e-9)
    assert st.Terrain.from_mesh(tin.mesh()).points.tolist() == tin.points.tolist()
    with pytest.raises(InvalidInputError, match=r"^crs 'EPSG:4326' is geographic, so the mesh's x and y are read as "
                                                r"degrees .* latitudes run from 4440000 to 4442670"):
        st.Terrain.from_mesh(_tin_of(heights, (30.0, -30.0), (480000.0, 4442670.0), "EPSG:4326"))
    tall = _tin_of(np.zeros((200, 3), np.float32), (0.01, -0.01), (-105.0, 61.0), "EPSG:4326")  # 2 degrees at 60 N
    with pytest.warns(UserWarning, match=r"^the mesh: EPSG:4326 degrees read as local metres with one spacing") as told:
        st.Terrain.from_mesh(tall)  # the grid's warning of one spacing's drift, at the caller's line
    assert told[0].filename == __file__


def test_a_grid_from_heights_in_web_mercator_far_from_the_equator_warns_as_load_dem_does(tmp_path):
    """load_dem warns when a projected grid's map scale is far from 1 (_check_projected_metres: Web Mercator at 60 N
    meshes the ground twice too large), but from_heights of the same grid, 'the same Terrain as load_dem of the grid
    saved as a GeoTIFF', said nothing. It now warns the same, at the caller's line; so does a TIN in that CRS. A UTM
    grid of its zone (the sample DEM's placement) stays silent."""
    rasterio = pytest.importorskip("rasterio")
    import warnings

    from rasterio.transform import Affine

    heights = np.ascontiguousarray(st.sample_dem().heights[:100, :100])
    step, x0, y0 = 30.0, 1_000_000.0, 8_500_000.0  # about 60.4 N, 9 E
    path = tmp_path / "merc.tif"
    with rasterio.open(path, "w", driver="GTiff", height=100, width=100, count=1, dtype="float32", crs="EPSG:3857",
                       transform=Affine(step, 0.0, x0 - 0.5 * step, 0.0, -step, y0 + 0.5 * step)) as dst:
        dst.write(heights, 1)
    match = r"EPSG:3857 is a Mercator projection, whose metres are not ground metres away from the equator"
    with pytest.warns(UserWarning, match=match) as read:
        st.load_dem(path)
    with pytest.warns(UserWarning, match=match) as told:
        st.Terrain.from_heights(heights, spacing=(step, -step), origin=(x0, y0), crs="EPSG:3857")
    (said,) = [w for w in told if re.search(match, str(w.message))]
    assert said.filename == __file__ and str(said.message).startswith("the heights: EPSG:3857")
    # the same measure as load_dem's (up to ... % over its node latitudes ...)
    assert str(said.message).split(": ", 1)[1].split("; for true")[0] == \
        str(read[-1].message).split(": ", 1)[1].split("; for true")[0]
    with pytest.warns(UserWarning, match=match):
        st.Terrain.from_mesh(_tin_of(heights, (step, -step), (x0, y0), "EPSG:3857"))
    dem = st.sample_dem()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        st.Terrain.from_heights(dem.heights, spacing=dem.spacing, origin=dem.origin, crs=dem.crs)
        st.Terrain.from_mesh(_tin_of(dem.heights[:50, :50], dem.spacing, dem.origin, dem.crs))


def test_a_grid_placed_from_degrees_rebuilt_from_its_fields_or_tiled_warns_no_map_scale(tmp_path):
    """check_projected_scale (from_heights' new map-scale check) read a grid placed from degrees, whose CRS is the
    library's local spherical +proj=eqc, as a projection far from its standard line: from_heights of the placed
    grid's own fields, dataclasses.replace of it and every tile of a batch of it warned "is a projection whose
    metres are ground metres only near its standard point or lines", after the degrees' drift was warned of once
    (at placing). Only the placing warns now."""
    import warnings

    heights = np.ascontiguousarray(st.sample_dem().heights[:200, :40])
    with pytest.warns(UserWarning, match="degrees read as local metres with one spacing"):
        placed = st.Terrain.from_heights(heights, spacing=(0.01, -0.01), origin=(-105.0, 61.0), crs="EPSG:4326")
    assert placed.crs.startswith("+proj=eqc ")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = st.Terrain.from_heights(placed.heights, spacing=placed.spacing, origin=placed.origin, crs=placed.crs)
        dataclasses.replace(placed, heights=placed.heights + np.float32(1.0))
        report = st.batch(placed, tmp_path / "tiles", tile_size=50, interval=100.0, scheduler="serial",
                          format=".ply")
    assert (again.spacing, again.origin, again.crs) == (placed.spacing, placed.origin, placed.crs)
    assert [r.status for r in report.results] == ["done"] * 4
    assert all(r.warnings == () for r in report.results)


def test_a_batch_of_a_placed_web_mercator_grid_warns_its_map_scale_once_not_per_tile(tmp_path):
    """A batch's tiles of a Terrain are its placed grid cut (_item_terrain), but were rebuilt by from_heights with the
    source's CRS looked up again: with the new map-scale check every tile of a Web Mercator grid far north (warned
    of when the grid was built) warned again, one message per tile. The tiles are the source's placement now."""
    import warnings

    heights = np.ascontiguousarray(st.sample_dem().heights[:101, :101])
    with pytest.warns(UserWarning, match="EPSG:3857 is a Mercator projection"):
        merc = st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(1_000_000.0, 8_500_000.0),
                                       crs="EPSG:3857")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report = st.batch(merc, tmp_path / "tiles", tile_size=50, interval=100.0, scheduler="serial", format=".ply")
    assert [r.status for r in report.results] == ["done"] * 4
    assert all(r.warnings == () for r in report.results)


def test_dataclasses_replace_warns_at_the_caller_s_line():
    """dataclasses.replace of a grid Terrain is checked as from_heights (the docstring's "built directly, or by
    dataclasses.replace"), its warnings (a Web Mercator grid's map scale, a CRS in feet) pointed into the standard
    library's dataclasses.py (the frame of replace), not at the caller's line."""
    heights = np.ascontiguousarray(st.sample_dem().heights[:100, :100])
    grid = st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(1_000_000.0, 100_000.0), crs="EPSG:3857")
    with pytest.warns(UserWarning, match="EPSG:3857 is a Mercator projection") as told:
        dataclasses.replace(grid, origin=(1_000_000.0, 8_500_000.0))
    assert {w.filename for w in told} == {__file__}


@pytest.mark.parametrize("wrap", [180.0, 360.0])
def test_a_tin_in_degrees_across_the_antimeridian_is_the_grid_s_surface(wrap):
    """Terrain.from_mesh of a TIN in EPSG:4326 whose points cross the antimeridian (longitudes wrapped to [-180, 180),
    or to [0, 360) at Greenwich) took them as given: the faces across the line each spanned the globe and the TIN
    was about 40,000 km wide (or refused as folded). Its longitudes are unwrapped now: the same points, extent and
    area as the grid of the same heights, whose longitudes run on past the line."""
    pytest.importorskip("rasterio")
    heights = np.ascontiguousarray(st.sample_dem().heights[:60, :80])
    spacing, origin = (0.001, -0.001), (179.96 if wrap == 180.0 else -0.04, -16.8)  # Fiji; Greenwich
    grid = st.Terrain.from_heights(heights, spacing=spacing, origin=origin, crs="EPSG:4326")
    mesh = _tin_of(heights, spacing, origin, "EPSG:4326")
    lon = mesh.vertices[:, 0]
    wrapped = np.where(lon >= 180.0, lon - 360.0, lon) if wrap == 180.0 else np.where(lon < 0.0, lon + 360.0, lon)
    assert (wrapped != lon).any() and (wrapped == lon).any()  # both sides of the line
    mesh.vertices[:, 0] = wrapped
    tin = st.Terrain.from_mesh(mesh)
    vertices = grid.mesh().vertices
    np.testing.assert_allclose(tin.points[:, :2] - tin.points[:, :2].min(axis=0),
                               vertices[:, :2] - vertices[:, :2].min(axis=0), rtol=1e-9, atol=1e-6)
    assert tin.mesh().area == pytest.approx(grid.mesh().area, rel=1e-9)


def test_a_terrains_repr_is_one_short_line_naming_it():
    """repr(Terrain) was the dataclass's, printing every array whole (heights, a TIN's points, faces and edge tables:
    thousands of lines for the sample DEM). One line now: kind, shape (a TIN's points and faces), a grid's spacing and
    origin, its finite heights' range, nodata, and the height unit, CRS and source where known, long ones cut."""
    dem = st.sample_dem()
    h = dem.heights
    assert repr(dem) == (
        f"Terrain(kind='grid', shape={h.shape}, spacing=(30, -30), origin=({dem.origin[0]:.10g}, "
        f"{dem.origin[1]:.10g}), heights=({float(h.min()):.10g}, {float(h.max()):.10g}), nodata=False, "
        f"height_unit='m', crs='EPSG:32611', source='big_tujunga_srtm_30m_utm11n.npz')")
    holes = np.full((4, 5), np.nan, np.float32)
    holes[1, 2], holes[3, 4] = -2.5, 7.0  # on no triangle: finite heights all the same
    wkt = 'PROJCS["a local grid",' + "x" * 500 + "]"
    grid = st.Terrain.from_heights(holes, spacing=(0.5, -0.25), origin=(10, 20), crs=wkt)
    text = repr(grid)
    assert text.startswith("Terrain(kind='grid', shape=(4, 5), spacing=(0.5, -0.25), origin=(10, 20), "
                           "heights=(-2.5, 7), nodata=True, crs='PROJCS[\"a local grid\",xxx")
    assert len(text) < 200 and "..." in text and "\n" not in text
    tin = st.Terrain.from_mesh(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 1], [1, 1, 2]], [[0, 1, 2], [1, 3, 2]],
                                               process=False))
    assert repr(tin) == "Terrain(kind='tin', points=4, faces=2, heights=(0, 2), nodata=False)"
    assert "array" not in repr(dem) + text + repr(tin)


_SPECIAL = st_.sampled_from([np.nan, np.inf, -np.inf, 0.0, -0.0])


@settings(max_examples=80, deadline=None)
@given(data=st_.data(), dtype=st_.sampled_from(["float16", "float32", "float64"]),
       shape=st_.tuples(st_.integers(1, 4), st_.integers(1, 5), st_.integers(1, 5)), mapped=st_.booleans())
def test_a_stacks_used_range_and_lowest_used_height_go_frame_by_frame_with_the_whole_stacks_values(
        data, dtype, shape, mapped, tmp_path_factory):
    """used_height_range and lowest_used_height of a (T, H, W) stack (a memory map too) against the whole stack at
    once in plain NumPy (tests/reference.py), over NaN, infinities, signed zeros, frames all NaN or without a
    triangle (1 x N), float16/32/64: they took the whole stack's finite and triangle masks at once (1.25 times a
    float32 stack's memory again) and go a frame at a time now, with the same values; and with the very floats
    (the sign of a zero too) of stepped_series' own frame-by-frame range (``_stack_ranges``), which batch's series
    levels took before."""
    from hypothesis.extra.numpy import arrays

    from stepterrain.stepped import _stack_ranges
    from stepterrain.terrain import lowest_used_height, used_height_range

    from .reference import lowest_used_height_reference, used_height_range_reference

    values = st_.one_of(_SPECIAL, st_.floats(-1e4, 1e4, width=16 if dtype == "float16" else 32))
    stack = data.draw(arrays(dtype, shape, elements=values))
    for k in data.draw(st_.sets(st_.integers(0, shape[0] - 1), max_size=2)):
        stack[k] = np.nan
    if mapped:
        path = tmp_path_factory.mktemp("stack") / "stack.npy"
        np.save(path, stack)
        stack = np.load(path, mmap_mode="r")
    got, want = used_height_range(stack), used_height_range_reference(stack)
    assert got == want
    assert got is None or all(type(v) is float for v in got)
    low = lowest_used_height(stack)
    assert low == lowest_used_height_reference(stack)
    assert low is None or type(low) is float
    same = _stack_ranges(stack)[2]
    assert (None if got is None else np.array(got).tobytes()) == (None if same is None else np.array(same).tobytes())
    if shape[-2] >= 2 and shape[-1] >= 2 and np.isfinite(stack).all():  # a known range: no pass
        assert lowest_used_height(stack, (-1.0, 1.0)) == -1.0


def test_a_memory_mapped_stacks_used_range_and_lowest_used_height_take_a_frames_memory_not_the_stacks(tmp_path):
    """used_height_range and lowest_used_height of a memory-mapped (T, H, W) stack (np.load(mmap_mode="r"), a
    32 x 512 x 512 float32 series of 32 MiB) took the whole stack's finite mask (8 MiB) and triangle masks at once:
    more than the stack's memory again, read in full before any answer. A frame at a time now: a frame's masks, less
    than twice a frame's memory (1 MiB), with the values of the whole stack at once (tests/reference.py)."""
    import tracemalloc

    from stepterrain.terrain import lowest_used_height, used_height_range

    from .reference import used_height_range_reference

    shape = (32, 512, 512)
    path = tmp_path / "series.npy"
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=shape)
    rng = np.random.default_rng(3)
    for k in range(shape[0]):
        frame = rng.normal(100.0, 20.0, shape[1:]).astype(np.float32)
        frame[rng.integers(0, 400):][:, rng.integers(0, 400):][:100, :100] = np.nan  # a void
        out[k] = frame
    out[7] = np.nan  # nodata only
    out[9, 1::2] = np.nan  # every other row: no triangle; its finite nodes, one far below the rest, are on none
    out[9, 0, 0] = -1e4
    out.flush()
    del out
    mapped = np.load(path, mmap_mode="r")
    frame_bytes = mapped[0].nbytes
    got = []
    for call in (used_height_range, lowest_used_height):
        tracemalloc.start()
        try:
            got.append(call(mapped))
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 2 * frame_bytes, f"{call.__name__}: {peak:,} bytes for a stack of {mapped.nbytes:,}"
    want = used_height_range_reference(mapped)  # some frame has a triangle: its low is the lowest used height
    assert got == [want, want[0]]
    assert want[0] > -1e4


@settings(max_examples=25, deadline=None)
@given(data=st_.data(), dtype=st_.sampled_from(["int8", "int16", "uint16", "int32", "int64", "uint8"]),
       shape=st_.one_of(st_.tuples(st_.integers(1, 4), st_.integers(1, 5)),
                        st_.tuples(st_.integers(1, 3), st_.integers(1, 4), st_.integers(1, 5))))
def test_lowest_used_height_of_integer_heights_is_their_float_low(data, dtype, shape):
    """lowest_used_height of an integer grid or (T, H, W) stack without a known range raised numpy's
    ``OverflowError: cannot convert float infinity to integer`` (``np.min(..., initial=np.inf)`` cast to the integer
    dtype); it is the float lowest height of a node a triangle uses (tests/reference.py on a float64 copy), None
    without a triangle (a 1 x N grid), as used_height_range of the same integers already gave."""
    from hypothesis.extra.numpy import arrays

    from stepterrain.terrain import lowest_used_height, used_height_range

    from .reference import lowest_used_height_reference

    info = np.iinfo(dtype)
    heights = data.draw(arrays(dtype, shape, elements=st_.integers(int(info.min), int(info.max))))
    low = lowest_used_height(heights)
    assert low == lowest_used_height_reference(heights.astype(np.float64))
    assert low is None or type(low) is float
    if low is not None:
        assert low == used_height_range(heights)[0]


def test_lowest_used_height_of_the_sample_dem_in_whole_metres():
    """The sample DEM rounded to int16 metres (as many DEMs are stored), a grid and a two-frame stack: the lowest
    height as a float, where numpy's OverflowError came from ``initial=np.inf``."""
    from stepterrain.terrain import lowest_used_height

    grid = np.round(np.asarray(st.sample_dem().heights, np.float64)).astype(np.int16)
    assert lowest_used_height(grid) == float(grid.min())
    assert lowest_used_height(np.stack([grid + 7, grid])) == float(grid.min())


def test_lowest_used_height_takes_nested_lists_of_floats_and_integers():
    """Nested lists (no ``dtype``) were read as numpy reads them before the integer path was added: the integer
    check reads the list's dtype through numpy, not an attribute a list lacks."""
    from stepterrain.terrain import lowest_used_height

    assert lowest_used_height([[1.0, 2.0], [3.0, 4.0]]) == 1.0
    assert lowest_used_height([[5, 2], [3, 4]]) == 2.0
    rows = [[np.nan, 2.0, 5.0], [3.0, 4.0, 6.0]]
    assert lowest_used_height(rows) == lowest_used_height(np.array(rows))


@pytest.mark.parametrize("method", [np.array(["mean", "nearest"]), np.array(["mean", "mean"]), np.array("mean"),
                                    ["mean"], None, 2])
def test_coarsen_refuses_a_method_that_is_not_text_naming_it(method):
    """``coarsen(method=...)`` compared the argument with ``in``: an array of names raised numpy's "truth value of an
    array ... is ambiguous" ValueError, naming neither the argument nor what it takes (a 0-d array passed as 'mean').
    Every method that is not text is refused as an unknown one is, naming it."""
    t = st.Terrain.from_heights(_H)
    with pytest.raises(InvalidInputError, match=r"^method must be 'mean' or 'nearest'; got "):
        t.coarsen(2, method=method)
    assert t.coarsen(2, method=np.str_("nearest")).shape == (3, 4)  # numpy's text is text
