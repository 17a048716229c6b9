"""close_solid on the Warp kernels of kernels/solid.py against its NumPy reference (tests/reference_solid.py).

close_solid's boundary edges, fins and base moved from NumPy sorts to count -> scan -> emit kernels, and its
columns (the vertices of one (x, y, [fan], wall pair), one base vertex each) to buckets of the wall pairs without a
sort, numbered in the order of their smallest vertex where the reference numbers them in the key's lexical order.
Its result must stay the same up to that order of the base vertices: the surface vertices bit for bit, the kept mask,
number of faces added and source vertices, the faces and base vertices through one permutation of the base, and
the same errors. The surfaces
are the stepper's own (the sample DEM at several intervals, gammas and levels; grids with nodata holes and pinches;
integer heights on thresholds, stepped as is, so fins appear; TINs with cliffs and zero-area faces) and random ones.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as hs

import stepterrain as st
from stepterrain import mesh as mesh_module
from stepterrain import stepped as stepped_module
from stepterrain.terrain import Terrain, as_terrain
from tests import reference_solid
from tests.conftest import shared_file

CPU = wp.get_device("cpu")

# random and hand-made surfaces come wound either way: close_solid's warning on a clockwise one (its solid reversed,
# as the reference reverses it: test_solid_orientation.py checks the warning) is expected here, not news
pytestmark = pytest.mark.filterwarnings("ignore:faces. the surface is wound clockwise seen from [+]z:UserWarning")


def _surface(terrain, interval=None, levels=None, gamma=1.0, nudged=True):
    """The stepped surface close_solid gets: vertices, faces, terrace mask and the default floor (``nudged``: the
    heights moved off the thresholds, as stepped() steps a solid; else as given, so fins can appear)."""
    t = as_terrain(terrain)
    values = (np.asarray(levels, np.float32) if levels is not None
              else st.isovalues(t.height_range, interval=interval))
    if nudged:
        t = stepped_module._off_thresholds(t, values)
    arrays, vertices = stepped_module._stepped_arrays(t, values, gamma, None, CPU)
    floor = stepped_module.default_floor(values, float(vertices[:, 2].min()), interval) if len(vertices) else -1.0
    return vertices, arrays.faces, ~arrays.face_walls, floor


def _bits(a):
    """The float64 array ``a``'s bit patterns (0.0 and -0.0 differ, a NaN equals itself)."""
    return np.ascontiguousarray(a, np.float64).view(np.uint64)


def _unchecked(vertices, faces, terrace, floor):
    """close_solid without its check of a foreign surface (test_solid_foreign.py), as stepped() closes its own: the
    reference closes any faces, repeated and degenerate ones and surfaces stepped on the thresholds included."""
    return mesh_module._close_solid(vertices, faces, terrace, floor, None, turn=True)


def _close_recording_columns(vertices, faces, terrace, floor):
    """close_solid, and what its _columns got and gave: (vertices, fan, pair) and the columns (None if not called)."""
    seen = {}
    columns = mesh_module._columns

    def recording(v, fan, pair, device):
        got = columns(v, fan, pair, device)
        seen["call"] = (np.array(v), None if fan is None else np.array(fan), pair.numpy().copy(), got[0].copy())
        return got

    mesh_module._columns = recording
    try:
        result = _unchecked(vertices, faces, terrace, floor)
    finally:
        mesh_module._columns = columns
    return result, seen.get("call")


def _lexical_rank(key):
    """Each row's rank among the distinct rows of the columns ``key`` (uint64 arrays) in lexical order: what
    ``np.unique(np.column_stack(key), axis=0, return_inverse=True)[1]`` gives, through one lexsort and a scan for the
    rows that differ from the one before (np.unique's row sort of the sample DEM's 2 million columns took 1 s)."""
    order = np.lexsort(key[::-1])  # lexsort's primary key is its last
    ranked = [k[order] for k in key]
    starts = np.zeros(len(order), bool)
    starts[1:] = np.logical_or.reduce([k[1:] != k[:-1] for k in ranked])
    rank = np.empty(len(order), np.int64)
    rank[order] = np.cumsum(starts)
    return rank


def test_lexical_rank_is_np_uniques_inverse():
    rng = np.random.default_rng(5)
    key = [rng.integers(0, 4, 500).astype(np.uint64), rng.integers(0, 3, 500).astype(np.uint64),
           rng.integers(0, 2**64 - 1, 500, dtype=np.uint64, endpoint=True) % np.uint64(5) << np.uint64(61)]
    for columns in (key[:1], key[:2], key):
        want = np.unique(np.column_stack(columns), axis=0, return_inverse=True)[1].reshape(-1)
        np.testing.assert_array_equal(_lexical_rank(columns), want)


def _assert_same(vertices, faces, terrace, floor):
    """close_solid and the reference give the same solid up to the order of the base vertices, or the same error;
    returns the result.

    Same dtypes and shapes; the surface vertices (the first ``len(source)`` rows) bit for bit, ``kept``, ``added`` and
    ``source`` equal. The columns (one base vertex each) are checked against their definition: the vertices with the
    same (x, y, [fan], pair) bit for bit, numbered in the order of their smallest vertex. The reference numbers the same
    columns in the lexicographic order of that key: the permutation between the two must be one bijection, the faces
    the reference's with their base indices sent through it, the base rows the reference's permuted bit for bit."""
    try:
        want = reference_solid.close_solid(vertices, faces, terrace, floor)
    except Exception as exc:  # the same type and message
        with pytest.raises(type(exc)) as got:
            _unchecked(vertices, faces, terrace, floor)
        assert str(got.value) == str(exc)
        return None
    got, call = _close_recording_columns(vertices, faces, terrace, floor)
    gv, gf, gk, ga, gs = got
    wv, wf, wk, wa, ws = want
    assert type(ga) is type(wa) and ga == wa
    for g, w in ((gv, wv), (gf, wf), (gk, wk), (gs, ws)):
        assert g.dtype == w.dtype and g.shape == w.shape
    assert np.array_equal(gk, wk) and np.array_equal(gs, ws)
    n = len(ws)
    assert np.array_equal(_bits(gv[:n]), _bits(wv[:n]))
    if n == 0:
        assert len(gv) == 0 and len(gf) == 0
        return got
    # the columns close_solid used, against their definition
    v, fan, pair, column = call
    assert np.array_equal(_bits(v), _bits(gv[:n]))
    key = [_bits(v[:, 0]), _bits(v[:, 1])] + ([_bits(fan)] if fan is not None else []) + [pair.astype(np.uint64)]
    old = _lexical_rank(key)  # the reference's numbering: the key's lexical rank
    count = int(old.max()) + 1
    assert column.min() == 0 and column.max() == count - 1
    perm = np.full(count, -1, np.int64)
    perm[old] = column
    assert np.array_equal(perm[old], column)  # one column per key (no key split)
    assert len(np.unique(perm)) == count  # one key per column (no two merged)
    smallest = np.full(count, n, np.int64)
    np.minimum.at(smallest, column, np.arange(n))
    assert (np.diff(smallest) > 0).all()  # numbered in the order of their smallest vertex
    # the solid: the reference's with the base vertices permuted
    assert len(gv) == n + count
    assert np.array_equal(_bits(gv[n + perm]), _bits(wv[n:]))
    assert np.array_equal(gf, np.where(wf < n, wf, n + perm[np.maximum(wf - n, 0)]))
    return got


@pytest.mark.parametrize("options", [
    {"interval": 50.0}, {"interval": 100.0}, {"interval": 250.0}, {"interval": 100.0, "gamma": 0.5},
    {"levels": [500, 700, 1000, 1500, 2000]},
])
def test_the_sample_dems_solids_equal_the_reference(options):
    dem = st.sample_dem()
    _assert_same(*_surface(dem, **options))


def test_a_crop_of_the_sample_dem_with_holes_and_pinches_equals_the_reference():
    """Nodata holes, two of them meeting at one node (a pinch the kernels' boundary must find, split by
    _split_pinches, and a second boundary pass after it)."""
    h = np.asarray(st.sample_dem().heights[:60, :70], np.float32).copy()
    h[10:20, 10:25] = np.nan
    h[30, 30] = h[31, 31] = np.nan  # meet at a node diagonally
    h[40, 40] = h[40, 42] = np.nan  # meet at node (40, 41)? no: at the cell corners between them
    vertices, faces, terrace, floor = _surface(h, interval=10.0)
    got = _assert_same(vertices, faces, terrace, floor)
    assert len(got[4]) > len(vertices)  # a pinch was split: its copies follow the surface's vertices


def test_a_pinch_of_two_holes_equals_the_reference():
    heights = np.arange(36.0).reshape(6, 6) * 0.25 + 0.125
    heights[1, 1] = heights[1, 3] = np.nan  # their holes meet at node (1, 2) only
    vertices, faces, terrace, floor = _surface(heights, interval=1.0)
    got = _assert_same(vertices, faces, terrace, -2.0)
    assert len(got[4]) > len(vertices)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_integer_heights_on_thresholds_stepped_as_is_equal_the_reference(seed):
    """Heights on the thresholds, stepped without stepped()'s nudge: fins (walls back to back) are removed, and
    vertices no face uses any more with them."""
    rng = np.random.default_rng(seed)
    h = np.round(rng.normal(0.0, 2.0, size=(30, 40)).cumsum(0).cumsum(1)).astype(np.float32)
    vertices, faces, terrace, floor = _surface(h, interval=2.0, nudged=False)
    got = _assert_same(vertices, faces, terrace, floor)
    assert got is not None
    if seed == 0:
        assert not got[2].all()  # fins were found and removed


def test_fins_are_found():
    """A ridge on a threshold stands two walls back to back: both go (the kept mask), found by the kernels."""
    h = np.zeros((5, 7), np.float32)
    h[:, 3] = 1.0  # a ridge line at height 1.0, on the threshold between 0 and 2 (interval 2: levels 0, 2)
    vertices, faces, terrace, floor = _surface(h, levels=[0.0, 2.0], nudged=False)
    got = _assert_same(vertices, faces, terrace, -1.0)
    assert not got[2].all()


def _tin_with_cliff():
    """A TIN with a cliff (two points on one xy at different heights) and a zero-area face."""
    pts = np.array([[0, 0, 0.3], [4, 0, 1.7], [8, 0, 2.2], [0, 4, 3.1], [4, 4, 0.6], [8, 4, 5.3], [4, 4, 4.4],
                    [0, 8, 1.1], [4, 8, 2.9], [8, 8, 0.2], [2, 0, 1.0]], float)
    faces = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 6], [3, 4, 8], [3, 8, 7], [6, 5, 9], [6, 9, 8],
                      [0, 10, 1]])
    return trimesh.Trimesh(pts, faces, process=False)


@pytest.mark.parametrize("nudged", [True, False])
def test_a_tin_with_a_cliff_and_a_zero_area_face_equals_the_reference(nudged):
    tin = _tin_with_cliff()
    t = Terrain.from_mesh(tin)
    vertices, faces, terrace, floor = _surface(t, interval=1.0, nudged=nudged)
    _assert_same(vertices, faces, terrace, floor)
    # the TIN itself, closed as a surface (every face a terrace)
    _assert_same(np.asarray(tin.vertices), np.asarray(tin.faces), np.ones(len(tin.faces), bool), -1.0)


@pytest.mark.parametrize("floor", [np.nan, np.inf, 1e39, 0.5, 100.0])
def test_the_floor_errors_are_the_references(floor):
    vertices, faces, terrace, _ = _surface(np.arange(12.0).reshape(3, 4), interval=1.0)
    assert _assert_same(vertices, faces, terrace, floor) is None


def test_empty_inputs_behave_as_the_reference():
    none = np.zeros((0, 3), np.int64)
    with pytest.raises(st.InvalidInputError, match="needs a surface to close"):  # the reference: numpy's ValueError
        mesh_module.close_solid(np.zeros((0, 3)), none, np.zeros(0, bool), -1.0)
    _assert_same(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 2.0]]), none, np.zeros(0, bool), -1.0)


def test_the_device_is_checked_and_the_cpu_is_the_default():
    vertices, faces, terrace, floor = _surface(np.arange(20.0).reshape(4, 5), interval=2.0)
    default = mesh_module.close_solid(vertices, faces, terrace, floor)
    named = mesh_module.close_solid(vertices, faces, terrace, floor, "cpu")
    assert all(np.array_equal(a, b) for a, b in zip(default, named, strict=True))
    with pytest.raises(st.DeviceError, match="device must be one of"):
        mesh_module.close_solid(vertices, faces, terrace, floor, "tpu:7")


def test_faces_out_of_range_are_refused():
    message = r"faces must index the 3 vertices \(0 \.\. 2\); got indices 0 \.\. 3"
    with pytest.raises(st.InvalidInputError, match=message):
        mesh_module.close_solid(np.zeros((3, 3)), np.array([[0, 1, 3]]), np.ones(1, bool), -1.0)


def test_a_terrace_mask_of_another_length_or_dtype_is_refused():
    """The kernels read the mask as one byte a face: a mask of ints or of another length read past it or misread."""
    vertices, faces = np.zeros((3, 3)), np.array([[0, 1, 2], [0, 2, 1]])
    for mask in (np.ones(1, bool), np.ones(3, bool), np.ones(2, np.int64)):
        with pytest.raises(st.InvalidInputError, match=r"terrace_mask must be a bool array of one flag per face \(2\)"):
            mesh_module.close_solid(vertices, faces, mask, -1.0)


@settings(max_examples=30, deadline=None)
@given(
    rows=hs.integers(2, 9),
    cols=hs.integers(2, 9),
    seed=hs.integers(0, 2**31 - 1),
    interval=hs.sampled_from([0.5, 1.0, 2.0, 3.0]),
    holes=hs.integers(0, 6),
    integers=hs.booleans(),
    nudged=hs.booleans(),
)
def test_random_grids_equal_the_reference(rows, cols, seed, interval, holes, integers, nudged):
    rng = np.random.default_rng(seed)
    h = rng.normal(0.0, 3.0, size=(rows, cols)).cumsum(0).cumsum(1).astype(np.float32)
    if integers:
        h = np.round(h)
    h.reshape(-1)[rng.integers(0, rows * cols, size=holes)] = np.nan
    if not np.isfinite(h).any():
        return
    vertices, faces, terrace, floor = _surface(h, interval=interval, nudged=nudged)
    _assert_same(vertices, faces, terrace, floor)


@settings(max_examples=40, deadline=None)
@given(faces=hs.lists(hs.tuples(*[hs.integers(0, 12)] * 3), max_size=40))
def test_boundary_edges_equal_the_reference(faces):
    """Any faces, degenerate ones (an edge (a, a)) included."""
    faces = np.array(faces, np.int64).reshape(-1, 3)
    np.testing.assert_array_equal(mesh_module.boundary_edges(faces), reference_solid.boundary_edges(faces))


@settings(max_examples=30, deadline=None)
@given(faces=hs.lists(hs.tuples(*[hs.integers(0, 9)] * 3), min_size=4, max_size=30), seed=hs.integers(0, 2**31 - 1))
def test_random_meshes_close_as_the_reference(faces, seed):
    """Random faces (repeated, degenerate) with random wall pairs and heights: the fins, the columns (pairs within
    one xy) and the skirts as the reference has them."""
    rng = np.random.default_rng(seed)
    faces = np.array(faces, np.int64)
    vertices = np.column_stack([rng.integers(0, 3, size=(10, 2)), rng.integers(0, 3, size=10)]).astype(float)
    terrace = rng.random(len(faces)) < 0.5
    _assert_same(vertices, faces, terrace, -1.0)


def test_a_pinch_copy_on_a_walls_vertical_edge_keeps_its_own_column():
    """A pinch vertex P whose second fan (a wall pair) gets the copy: the copy pairs with the wall's top T on the same
    xy through the wall's vertical edge, and only its fan keeps their columns apart (as the reference's key does)."""
    vertices = np.array([[0, 0, 0], [-1, -1, 0], [-1, 1, 0], [1, 0, 1], [0, 0, 1], [1, 0, 0]], float)
    p, q1, q2, u_top, t, u_bottom = range(6)
    faces = np.array([[p, q1, q2],  # fan A: first, keeps P
                      [u_top, t, p], [u_top, p, u_bottom]])  # fan B: a wall pair (u_top, v_top, v_bottom), ...
    got = _assert_same(vertices, faces, np.array([True, False, False]), -1.0)
    assert len(got[4]) == 7  # P was split


def _wall_fan(m, seed=0, ring=True, pinch=False, fins=0.05):
    """``m`` wall pairs (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom) whose u_bottom is the hub vertex 0: every
    pair's quad holds the hub (one fin bucket of m pairs), and every u_top pairs with it (one pair group of m + 1
    vertices, half of them over the hub: one column, the other half one each). ``ring``: terraces (0, u_top_i,
    v_bottom_i+1) join the walls' faces around the hub into one fan; ``pinch``: that fan left open and one more
    triangle on the hub, so the hub is a pinch whose big fan _split_pinches finds; ``fins``: the share of pairs
    repeated (fins in the big bucket)."""
    rng = np.random.default_rng(seed)
    angle = rng.random(m) * 2 * np.pi
    over = rng.random(m) < 0.5
    tops = np.column_stack([np.where(over, 0.0, np.cos(angle) / 2), np.where(over, 0.0, np.sin(angle) / 2),
                            1.0 + rng.random(m)])
    v_tops = np.column_stack([np.cos(angle), np.sin(angle), 2.0 + rng.random(m)])
    v_bottoms = np.column_stack([np.cos(angle), np.sin(angle), 0.5 + rng.random(m)])
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], tops, v_tops, v_bottoms])
    t, a, b = 1 + np.arange(m), 1 + m + np.arange(m), 1 + 2 * m + np.arange(m)
    first, second = np.column_stack([t, a, b]), np.column_stack([t, b, np.zeros(m, np.int64)])
    faces = [np.stack([first, second], 1).reshape(-1, 3)]
    if ring:
        k = np.arange(m - 1 if pinch else m)
        faces.append(np.column_stack([np.zeros(len(k), np.int64), t[k], b[(k + 1) % m]]))
    if pinch:
        vertices = np.concatenate([vertices, [[-3.0, -3.0, 1.0], [-3.0, -2.0, 1.0]]])
        faces.append(np.array([[0, len(vertices) - 2, len(vertices) - 1]]))
    terrace = np.ones(sum(len(f) for f in faces), bool)
    terrace[:2 * m] = False
    repeated = rng.random(m) < fins
    faces.append(np.stack([first[repeated], second[repeated]], 1).reshape(-1, 3))
    terrace = np.concatenate([terrace, np.zeros(2 * repeated.sum(), bool)])
    return vertices, np.concatenate(faces), terrace


@pytest.mark.parametrize("ring, pinch, fins", [(False, False, 0.05), (True, False, 0.0), (True, True, 0.0),
                                               (True, True, 0.05)])
def test_a_fan_of_walls_on_one_vertex_equals_the_reference(ring, pinch, fins):
    """A fin bucket and a pair group far above LARGE_BUCKET (searched through hashes of the whole key: a scan per item
    took 3-5 s at 60 k walls) and a pinch with a fan of thousands of faces (_split_pinches' label propagation took a
    round per face: a minute at 20 k walls)."""
    vertices, faces, terrace = _wall_fan(3000, ring=ring, pinch=pinch, fins=fins)
    if ring and not fins:  # the hub's pair group stays whole (fins break the ring into fans, each with its copy)
        assert np.bincount(reference_solid._wall_pairs(faces, terrace, len(vertices))).max() > 3000
    got = _assert_same(vertices, faces, terrace, -1.0)
    assert got[2].all() == (fins == 0)
    assert (len(got[4]) > len(vertices)) == (pinch or fins > 0)


@settings(max_examples=30, deadline=None)
@given(faces=hs.lists(hs.tuples(*[hs.integers(0, 9)] * 3), min_size=4, max_size=30), seed=hs.integers(0, 2**31 - 1),
       limit=hs.sampled_from([0, 1, 2]))
def test_random_meshes_close_as_the_reference_through_the_hashed_buckets(faces, seed, limit):
    """As test_random_meshes_close_as_the_reference with LARGE_BUCKET at 0 to 2: the fins and the columns of every
    bucket (or of most) found through the hashes of their whole key."""
    rng = np.random.default_rng(seed)
    faces = np.array(faces, np.int64)
    vertices = np.column_stack([rng.integers(0, 3, size=(10, 2)), rng.integers(0, 3, size=10)]).astype(float)
    terrace = rng.random(len(faces)) < 0.5
    old = mesh_module.LARGE_BUCKET
    mesh_module.LARGE_BUCKET = limit
    try:
        _assert_same(vertices, faces, terrace, -1.0)
    finally:
        mesh_module.LARGE_BUCKET = old


@pytest.mark.parametrize("limit", [0, 1])
def test_the_sample_dem_with_holes_through_the_hashed_buckets_equals_the_reference(limit):
    h = np.asarray(st.sample_dem().heights[:60, :70], np.float32).copy()
    h[10:20, 10:25] = np.nan
    h[30, 30] = h[31, 31] = np.nan
    old = mesh_module.LARGE_BUCKET
    mesh_module.LARGE_BUCKET = limit
    try:
        got = _assert_same(*_surface(h, interval=10.0))
    finally:
        mesh_module.LARGE_BUCKET = old
    assert got is not None


@pytest.mark.parametrize("seed", [0, 1])
def test_fins_through_the_hashed_buckets_equal_the_reference(seed):
    rng = np.random.default_rng(seed)
    h = np.round(rng.normal(0.0, 2.0, size=(30, 40)).cumsum(0).cumsum(1)).astype(np.float32)
    old = mesh_module.LARGE_BUCKET
    mesh_module.LARGE_BUCKET = 0
    try:
        got = _assert_same(*_surface(h, interval=2.0, nudged=False))
    finally:
        mesh_module.LARGE_BUCKET = old
    assert got is not None and not got[2].all()


def _walls_on_three_vertices(m, hub_first):
    """``m`` wall pairs (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom) on one v_top, v_bottom and u_bottom
    (the hub) and their own u_top: sorted quads alike but for one vertex, none repeated (no fin). ``hub_first``: the
    hub is vertex 0 (the quads differ in their second vertex; every u_top's vertical edge ends at the hub, its lower
    end: one pair group of m + 1 vertices, three columns, over the hub and 0.5 off it in x or in y, keys alike but
    for x or for y); else the u_tops are vertices 0 .. m - 1 (the quads differ in their smallest vertex)."""
    i = np.arange(m)
    tops = np.column_stack([np.where(i % 3 == 1, 0.5, 0.0), np.where(i % 3 == 2, 0.5, 0.0), 2.0 + i])
    hub, others = [[0.0, 0.0, 1.0]], [[1.0, 0.0, 3.0], [1.0, 0.0, 1.0]]
    if hub_first:
        vertices, t, a, b, u = np.concatenate([hub, tops, others]), 1 + i, m + 1, m + 2, 0
    else:
        vertices, t, a, b, u = np.concatenate([tops, others, hub]), i, m, m + 1, m + 2
    first = np.column_stack([t, np.full(m, a), np.full(m, b)])
    second = np.column_stack([t, np.full(m, b), np.full(m, u)])
    faces = np.stack([first, second], 1).reshape(-1, 3)
    return vertices, faces, np.zeros(len(faces), bool)


def _bucket_case(case):
    """(vertices, faces, terrace, floor) of the bucket tests' cases: walls on three vertices that differ in their
    smallest vertex or (hub) in their second one, a fan of walls with pinch copies (a column's keys alike but for the
    fan), and a small integer surface with a hole and fins."""
    if case in ("smallest", "hub"):
        return (*_walls_on_three_vertices(40, hub_first=case == "hub"), -1.0)
    if case == "fan":
        return (*_wall_fan(120, ring=True, pinch=True, fins=0.2, seed=3), -1.0)
    h = np.round(np.random.default_rng(0).normal(0.0, 2.0, size=(20, 24)).cumsum(0).cumsum(1))
    h[5:9, 5:11] = np.nan
    return _surface(h.astype(np.float32), interval=2.0, nudged=False)


@pytest.mark.parametrize("case", ["smallest", "hub", "fan", "sample"])
def test_hashed_buckets_that_all_collide_equal_the_reference(case, monkeypatch):
    """The hashes only bucket the keys: every deferred key sent to one bucket (hash_fin_keys' and hash_column_keys'
    keys all made ``count``, as if every hash collided), find_fins_hashed and column_reps still tell the quads and
    the columns apart by the whole key (sorted quad; x, y, fan and pair), and find each column's first member the
    same for the whole column. A compare of part of the key went unnoticed where the real hashes rarely collide."""
    collided = []
    launch = mesh_module.launch_chunked

    def colliding(kernel, n, inputs, outputs, device, **options):
        launch(kernel, n, inputs, outputs, device, **options)
        if kernel in (mesh_module.kernels.hash_fin_keys, mesh_module.kernels.hash_column_keys):
            keys = outputs[0].numpy()  # the CPU array's own buffer: the kernels after read these keys
            keys[keys >= n] = n
            collided.append(kernel.key)

    monkeypatch.setattr(mesh_module, "launch_chunked", colliding)
    monkeypatch.setattr(mesh_module, "LARGE_BUCKET", 0)
    got = _assert_same(*_bucket_case(case))
    # the pass that closed it hashed both (a clockwise surface, as these hand-made ones are, is closed again with its
    # faces reversed: its fins hashed in the first pass too)
    assert got is not None and collided[-2:] == ["hash_fin_keys", "hash_column_keys"]
    assert len(collided) == (3 if case in ("smallest", "hub", "fan") else 2)
    assert got[2].all() == (case in ("smallest", "hub"))  # no fin where the quads differ in one vertex


@pytest.mark.parametrize("limit", [0, mesh_module.LARGE_BUCKET])
@pytest.mark.parametrize("case", ["hub", "fan", "sample"])
def test_buckets_in_reverse_order_equal_the_reference(case, limit, monkeypatch):
    """On the CPU a bucket fills in item order (fill_buckets runs as one range), so a column's first member in its
    hashed bucket (column_reps' representative) was always its smallest vertex, its leader, and the atomic min that
    finds the leader on CUDA (whose atomic cursors fill a bucket in any order) went untested: taking the
    representative as the leader passed every test (as did column_leaders taking the first smaller fellow in its
    bucket for the smallest). Every bucket reversed here, as CUDA may leave it."""
    buckets = mesh_module._buckets

    def reversed_buckets(keys, n, device):
        offsets, items = buckets(keys, n, device)
        starts, flat = offsets.numpy(), items.numpy()  # the CPU arrays' own buffers
        sizes = np.diff(starts)
        bucket = np.repeat(np.arange(len(sizes)), sizes)
        flat[:] = flat[starts[bucket] + starts[bucket + 1] - 1 - np.arange(len(flat))]
        return offsets, items

    monkeypatch.setattr(mesh_module, "_buckets", reversed_buckets)
    monkeypatch.setattr(mesh_module, "LARGE_BUCKET", limit)  # 0: every bucket hashed; else the small ones scanned
    assert _assert_same(*_bucket_case(case)) is not None


def test_non_finite_vertices_float_faces_and_a_floor_not_a_number_are_refused():
    """close_solid (public, in stepterrain.mesh) took NaN or infinite coordinates into the solid without a word (NaN
    in its vertices and base), truncated float face indices (1.5 -> 1: another vertex), and met a floor given as
    None, text or an array with numpy's TypeError deep inside; each is now an InvalidInputError naming it.
    Whole-number float faces are still taken."""
    vertices, faces, terrace, floor = _surface(np.arange(20.0).reshape(4, 5), interval=2.0)
    for bad in (np.nan, np.inf):
        given = vertices.copy()
        given[3, 1] = bad
        with pytest.raises(st.InvalidInputError, match="vertices must be finite; got 1 NaN or infinite coordinate"):
            mesh_module.close_solid(given, faces, terrace, floor)
    with pytest.raises(st.InvalidInputError, match="faces must hold whole vertex indices; got 0.5 at \\(0, 0\\)"):
        mesh_module.close_solid(vertices, faces + 0.5, terrace, floor)
    nan_faces = faces.astype(np.float64)
    nan_faces[2, 1] = np.nan
    with pytest.raises(st.InvalidInputError, match="faces must hold whole vertex indices; got nan at \\(2, 1\\)"):
        mesh_module.boundary_edges(nan_faces)
    with pytest.raises(st.InvalidInputError, match="faces must be an \\(F, 3\\) integer array .* got dtype bool"):
        mesh_module.boundary_edges(faces > 0)
    # whole-number floats (faces read back from a text file) are the same faces
    assert np.array_equal(mesh_module.boundary_edges(faces.astype(np.float64)), mesh_module.boundary_edges(faces))
    for bad in (None, "0", np.array([floor]), 1j):
        with pytest.raises(st.InvalidInputError, match="floor must be a number"):
            mesh_module.close_solid(vertices, faces, terrace, bad)
    # integer faces of any width, and lists, still work
    same = mesh_module.close_solid(vertices, faces.astype(np.int32).tolist(), terrace, floor)
    assert all(np.array_equal(a, b) for a, b in zip(same, mesh_module.close_solid(vertices, faces, terrace, floor),
                                                    strict=True))


def _voided_crop_against_the_reference(name: str) -> tuple[tuple, np.ndarray]:
    """An 80² crop of a shared/data DEM with 5 % void nodes (seed 0), stepped at 50 m and closed by the kernels and
    the reference (equal: :func:`_assert_same`): the kernels' result and each pinch copy's xy move off its node."""
    dem = st.load_dem(shared_file(name))
    heights = dem.heights[:80, :80].copy()
    heights[np.random.default_rng(0).random(heights.shape) < 0.05] = np.nan
    holed = st.Terrain.from_heights(heights, spacing=dem.spacing, origin=dem.origin)
    vertices, faces, terrace, floor = _surface(holed, interval=50.0)
    got = _assert_same(vertices, faces, terrace, floor)
    moved = got[0][: len(got[4]), :2] - vertices[got[4], :2]
    return got, moved


def test_pinch_copies_moved_along_their_fans_mean_equal_the_reference():
    """Big Tujunga's SRTM (30 m, UTM) with 5 % void nodes: copies whose diagonal move misses a one-triangle fan by a
    hair move along their fan's mean direction, as the reference's do (no other test compared that path)."""
    got, moved = _voided_crop_against_the_reference("big_tujunga_srtm_30m_utm11n.tif")
    along = (moved != 0).any(axis=1) & (np.abs(np.abs(moved[:, 0]) - np.abs(moved[:, 1])) > 0)
    assert along.any()  # some copy moved along its mean direction, not the diagonal


def test_pinch_copies_on_non_square_cells_equal_the_reference():
    """The Front Range's SRTM 3" (cells about 71 x 93 m) with 5 % void nodes: diagonal moves that miss a one-triangle
    fan by degrees are retried along the fan's mean direction, as the reference's are (the retry was limited to
    misses under 1e-3 rad before)."""
    got, moved = _voided_crop_against_the_reference("front_range_srtmgl3_3arcsec.tif")
    shared = np.bincount(got[4])[got[4]] > 1  # the pinch vertices and their copies
    assert shared.sum() > 20
    # every copy moved off its node (none here has a wall): one vertex per pinch node stays on it, the original
    assert ((moved[shared] == 0).all(axis=1)).sum() == len(np.unique(got[4][shared]))
    along = (moved != 0).any(axis=1) & (np.abs(np.abs(moved[:, 0]) - np.abs(moved[:, 1])) > 0)
    assert along.any()  # some along its mean direction, not the diagonal
