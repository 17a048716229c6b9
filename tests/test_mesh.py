"""stepterrain.mesh: the sort-based helpers against np.unique references, on random inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

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
