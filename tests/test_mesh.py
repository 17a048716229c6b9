"""stepterrain.mesh: the sort-based helpers against np.unique references, on random inputs."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from hypothesis import example, given, settings
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

import stepterrain as st
import stepterrain.mesh as mesh_module
from stepterrain import _device
from stepterrain.errors import InvalidInputError, OutputTooLargeError
from stepterrain.mesh import boundary_edges, exact_keys
from tests.reference_solid import _repeated_rows  # close_solid finds fins with kernels now (test_solid_kernels)


def boundary_reference(faces):
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    key = np.minimum(directed[:, 0], directed[:, 1]) * 10**6 + np.maximum(directed[:, 0], directed[:, 1])
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return directed[counts[inverse.reshape(-1)] == 1]


@settings(max_examples=60, deadline=None)
@given(arrays(np.int64, hst.tuples(hst.integers(0, 60), hst.just(3)), elements=hst.integers(0, 30)))
def test_boundary_edges_equal_the_unique_reference(faces):
    np.testing.assert_array_equal(boundary_edges(faces), boundary_reference(faces))


def test_boundary_edges_of_a_grid_and_of_nothing():
    rows, cols = 40, 57  # (rows - 1) * (cols - 1) cells, two triangles each: the boundary is the rim
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    edges = boundary_edges(faces)
    assert len(edges) == 2 * (rows - 1) + 2 * (cols - 1)
    np.testing.assert_array_equal(edges, boundary_reference(faces))
    assert boundary_edges(np.zeros((0, 3), np.int64)).shape == (0, 2)
    assert boundary_edges(np.concatenate([faces, faces[:, ::-1]])).shape == (0, 2)  # every edge twice


def _corners_reference(faces, n):
    """Per vertex the sorted (next, previous) pairs of its corners: what its bucket of the corner table holds."""
    pairs = np.stack([faces[:, [1, 2, 0]], faces[:, [2, 0, 1]]], -1).reshape(-1, 2)
    at = faces.reshape(-1)
    return [sorted(map(tuple, pairs[at == v].tolist())) for v in range(n)]


@settings(max_examples=40, deadline=None)
@given(faces=arrays(np.int64, hst.tuples(hst.integers(1, 40), hst.just(3)), elements=hst.integers(0, 12)),
       unused=hst.integers(0, 3), seed=hst.integers(0, 2**32 - 1))
def test_the_boundary_pass_reads_its_corner_buckets_in_any_order(faces, unused, seed):
    """The corner table that fill_corners leaves (vertex v's bucket: corners[ends[v + 1]:ends[v + 2]]) holds each
    vertex's corners, also for the vertices no face uses (``unused`` more after the last one); and count_boundary
    reads only counts from a bucket, so the boundary is the reference's, in its order, with every bucket shuffled
    (as CUDA's atomics may leave it; on the CPU one range fills it in reverse face order) and count_boundary and
    emit_boundary split into ranges of one face over several threads."""
    n = int(faces.max()) + 1 + unused
    rng = np.random.default_rng(seed)
    launch_chunked = mesh_module.launch_chunked
    filled = []

    def shuffled(kernel, count, inputs, outputs, device, **options):
        if not options.get("atomics"):
            options["min_elements"] = 1
        launch_chunked(kernel, count, inputs, outputs, device, **options)
        if kernel is mesh_module.kernels.fill_corners:
            ends, corners = outputs[0].numpy(), outputs[1].numpy()  # the CPU arrays' own buffers
            assert ends.shape == (n + 2,) and ends[1] == 0 and ends[n + 1] == len(corners)
            got = [sorted(map(tuple, corners[ends[v + 1]:ends[v + 2]].tolist())) for v in range(n)]
            assert got == _corners_reference(faces, n)
            bucket = np.repeat(np.arange(n), np.diff(ends[1:]))
            corners[:] = corners[np.lexsort((rng.random(len(corners)), bucket))]
            filled.append(True)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(mesh_module, "launch_chunked", shuffled)
        patch.setattr(_device, "CPU_CHUNK", 1)
        old = _device.set_cpu_threads(3)
        try:
            cpu = wp.get_device("cpu")
            got = mesh_module._boundary(mesh_module._flat_faces(faces, cpu), n, cpu)
        finally:
            _device.set_cpu_threads(old)
    assert filled
    np.testing.assert_array_equal(got, boundary_reference(faces))


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, hst.tuples(hst.integers(0, 80), hst.integers(1, 3)),
              elements=hst.sampled_from([0.0, -0.0, 1.0, 2.5, -3.0, np.nan, np.inf, 1e300])))
def test_exact_keys_group_bit_identical_rows(xy):
    ids = exact_keys(xy)
    assert ids.shape == (len(xy),)
    rows = np.ascontiguousarray(xy)
    void = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).reshape(-1)
    _, ref = np.unique(void, return_inverse=True)
    # the same partition: one id per distinct byte pattern, ids 0..k-1
    pairs = {(int(i), int(r)) for i, r in zip(ids, ref.reshape(-1), strict=True)}
    assert len(pairs) == len(set(ref.reshape(-1).tolist())) == (int(ids.max()) + 1 if len(ids) else 0)


@settings(max_examples=60, deadline=None)
@given(arrays(np.int64, hst.tuples(hst.integers(1, 50), hst.just(4)), elements=hst.integers(0, 4)))
def test_repeated_rows_equal_the_unique_reference(rows):
    _, inverse, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    np.testing.assert_array_equal(_repeated_rows(rows), counts[inverse.reshape(-1)] > 1)


@pytest.mark.parametrize("faces", [np.array([[2**63 + 5, 0, 1]], np.uint64), np.array([[1e20, 0, 1]]),
                                   np.array([[0, 1, 2.0**63]])])
def test_boundary_edges_name_an_index_beyond_int64_as_given(faces):
    # cast to int64 they wrapped round to -2^63 (numpy's RuntimeWarning): "faces must hold vertex indices >= 0; got
    # -9223372036854775808", an index the caller never gave
    with pytest.raises(OutputTooLargeError, match="faces") as caught:
        boundary_edges(faces)
    assert "-9223372036854775" not in str(caught.value)
    assert str(faces.max())[:6] in str(caught.value)


@settings(max_examples=30, deadline=None)
@given(hst.lists(hst.integers(0, mesh_module.MAX_INT32 - 3), min_size=3, max_size=12, unique=True),
       hst.lists(hst.tuples(*[hst.integers(0, 11)] * 3), min_size=1, max_size=20))
@example(pool=[0, 1, 2**30], picks=[(0, 1, 2)])
def test_boundary_edges_of_sparse_indices_size_their_work_by_the_faces(pool, picks):
    # the corner table was sized by the largest index: one face [0, 1, 2**30] allocated 4 GiB (n + 2 int32, twice)
    faces = np.array(pool, np.int64)[np.array(picks) % len(pool)]
    largest = []
    real_empty = mesh_module._empty

    def empty(n, *args, **kwargs):
        largest.append(n)
        assert n <= 6 * len(faces) + 8, f"a work array of {n} elements for {len(faces)} faces"
        return real_empty(n, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(mesh_module, "_empty", empty)
        edges = boundary_edges(faces)
    np.testing.assert_array_equal(edges, boundary_reference(faces))
    assert edges.dtype == np.int64 and largest


def test_boundary_edges_of_an_empty_list_is_no_edge():
    # _face_indices' docstring: an empty list (numpy's float64, shape (0,)) is no faces; it raised "got shape (0,)"
    assert boundary_edges([]).shape == (0, 2)
    np.testing.assert_array_equal(boundary_edges([]), boundary_edges(np.zeros((0, 3), np.int64)))


def test_boundary_edges_name_a_negative_float_index_beyond_int64_as_given():
    # -1e20 cast to int64 is -2^63: "got -9223372036854775808", an index the caller never gave
    with pytest.raises(InvalidInputError, match=">= 0") as caught:
        boundary_edges(np.array([[0.0, 1.0, -1e20]]))
    assert "-1e+20" in str(caught.value) and "-9223372036854775" not in str(caught.value)
    with pytest.raises(InvalidInputError, match="got -1$"):  # an int's message as before
        boundary_edges(np.array([[0, 1, -1]]))


def test_close_solid_names_a_face_index_beyond_int64_as_given():
    # the uint64 index wrapped to a negative int64: "got indices -9223372036854775803 .. 2", never given
    vertices = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    faces = np.array([[0, 1, 2**63 + 5]], np.uint64)
    with pytest.raises(InvalidInputError, match=r"faces must index the 3 vertices \(0 \.\. 2\); got "
                                                r"9223372036854775813 at \(0, 2\)"):
        mesh_module.close_solid(vertices, faces, np.ones(1, bool), 0.0)


def _heightfield_reference(heights, dx, dy, x0, y0):
    """heightfield_mesh's contract in plain NumPy: node k = (x0 + j dx, y0 + i dy, float32 height), two triangles a
    cell, each turned counter-clockwise seen from +z, none on a NaN node; the faces as sorted node triples."""
    rows, cols = heights.shape
    i, j = np.divmod(np.arange(rows * cols), cols)
    nodes = np.column_stack([x0 + j * dx, y0 + i * dy, heights.astype(np.float32).astype(np.float64).reshape(-1)])
    triangles = []
    for r in range(rows - 1):
        for c in range(cols - 1):
            a, b, d, e = r * cols + c, r * cols + c + 1, (r + 1) * cols + c, (r + 1) * cols + c + 1
            triangles += [(a, b, e), (a, e, d)]
    triangles = np.array(triangles).reshape(-1, 3)
    triangles = triangles[np.isfinite(nodes[triangles, 2]).all(axis=1)]
    return nodes, {tuple(sorted(t)) for t in triangles.tolist()}


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, hst.tuples(hst.integers(2, 6), hst.integers(2, 6)),
              elements=hst.one_of(hst.floats(-50, 50), hst.just(np.nan))),
       hst.sampled_from([1.0, -1.0]), hst.sampled_from([1.0, -1.0]), hst.booleans())
def test_heightfield_mesh_equals_the_numpy_reference(heights, sx, sy, utm):
    """Vertex k is node k (its node_index with nodata), the faces are the reference's, every one counter-clockwise
    seen from +z (negative spacings swap the winding), and no face touches a NaN node."""
    dx, dy, origin = 30.0 * sx, 20.0 * sy, (500000.0, 4100000.0) if utm else (0.0, 0.0)
    mesh = st.heightfield_mesh(heights[:, ::-1] if utm else heights, spacing=(dx, dy), origin=origin)
    nodes, faces = _heightfield_reference(heights[:, ::-1] if utm else heights, dx, dy, *origin)
    node = mesh.metadata.get("node_index", np.arange(len(nodes)))
    np.testing.assert_array_equal(mesh.vertices, nodes[node])
    assert {tuple(sorted(t)) for t in node[mesh.faces].tolist()} == faces
    corners = mesh.vertices[mesh.faces]
    u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    assert (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0] > 0).all()
    assert np.isfinite(mesh.vertices).all()
