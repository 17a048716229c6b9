"""Review of close_solid on the Warp kernels (kernels/solid.py, stepterrain/mesh.py): the bugs found, one failing test
each (fixed: the kernels with atomics run as one range on the CPU, launch_chunked(atomics=True); the shapes
and the empty mesh refused).

* Warp's CPU atomics are plain read-modify-writes (warp/native/builtin.h: ``atomic_add`` and ``atomic_max`` without
  ``__CUDA_ARCH__``), and ``launch_chunked`` runs one CPU pass as several launches at once: count_keys, fill_buckets,
  fill_corners and last_wall_writes lose updates where two ranges meet on one vertex (a fan's hub).
* close_solid reads ``vertices`` as flat rows of three without checking their shape, and boundary_edges ``faces`` as
  flat rows of three: an (N, 4) array gives a wrong mesh without an error.
* An empty mesh (no vertex) fails in numpy's ``max`` instead of a stepterrain error or an empty solid.
"""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from stepterrain import _device
from stepterrain._compaction import MAX_INT32
from stepterrain.errors import InvalidInputError, OutputTooLargeError
from stepterrain.mesh import boundary_edges, close_solid
from tests import reference_solid


def _fan(n: int) -> np.ndarray:
    """``n`` triangles (0, i, i + 1) around the hub vertex 0: every face's first corner is the hub."""
    rim = np.arange(1, n + 1, dtype=np.int64)
    return np.column_stack([np.zeros(n, np.int64), rim, rim + 1])


def test_a_fans_boundary_over_several_cpu_threads_equals_the_reference():
    # every face adds a corner to the hub's count and takes a slot of its cursor: 32 ranges at once lose some (about
    # one run in three on 2 cores); the boundary is the rim plus the two spokes at its ends in every run
    faces = _fan(2_000_000)
    want = reference_solid.boundary_edges(faces)
    old = _device.set_cpu_threads(32)
    try:
        for _ in range(5):
            got = boundary_edges(faces)
            assert got.shape == want.shape and np.array_equal(got, want)
    finally:
        _device.set_cpu_threads(old)


def _square(extra_columns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two terraces on a unit square, the vertices with ``extra_columns`` more columns than x, y, z (or fewer)."""
    xyz = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 1.0, 2.0]])
    if extra_columns >= 0:
        vertices = np.hstack([xyz, np.full((4, extra_columns), 9.0)])
    else:
        vertices = xyz[:, :3 + extra_columns]
    return vertices, np.array([[0, 1, 2], [1, 3, 2]]), np.ones(2, bool)


@pytest.mark.parametrize("extra", [1, -1])
def test_vertices_that_are_not_rows_of_three_are_refused(extra):
    # (N, 4): emit_vertices and column_starts read the flat array as rows of three, so the solid's vertices were
    # the input's numbers shifted (x = 9.0 for vertex 1) with no error; (N, 2): an IndexError from numpy
    vertices, faces, terrace = _square(extra)
    with pytest.raises(InvalidInputError, match="vertices"):
        close_solid(vertices, faces, terrace, 0.0)


@pytest.mark.parametrize("faces", [np.array([[0, 1, 2, 3], [1, 3, 2, 0]]), np.array([0, 1, 2])])
def test_boundary_edges_refuses_faces_that_are_not_rows_of_three(faces):
    # (F, 4) gave the edges of the flat indices taken three at a time, among them (3, 3)
    with pytest.raises(InvalidInputError, match="faces"):
        boundary_edges(faces)


@pytest.mark.parametrize("index", [MAX_INT32 - 2, MAX_INT32, 1 << 40])
def test_boundary_edges_refuses_an_index_its_int32_corner_table_cannot_hold(index):
    # the corner table has n + 2 entries (n: the largest index + 1), a Warp shape of int32: past it Warp's ValueError
    # or numpy's MemoryError for an 8 GiB - 4 TiB table (the index wrapped in int32 beyond), not a stepterrain error
    with pytest.raises(OutputTooLargeError, match="faces"):
        boundary_edges(np.array([[0, 1, index]]))


def test_an_empty_mesh_gives_an_empty_solid_or_a_stepterrain_error():
    # tests/test_solid_kernels.py::test_empty_inputs_behave_as_the_reference keeps the reference's ValueError
    try:
        vertices, faces, kept, added, source = close_solid(np.zeros((0, 3)), np.zeros((0, 3), np.int64),
                                                           np.zeros(0, bool), -1.0)
    except InvalidInputError as exc:
        assert "vertices" in str(exc) or "faces" in str(exc)
    else:
        assert vertices.shape == (0, 3) and faces.shape == (0, 3) and len(kept) == 0 and added == 0
        assert len(source) == 0


def test_counts_of_one_key_over_several_cpu_threads_are_exact():
    """The race itself, deterministically: 4 M items of one key counted by count_keys as close_solid launches it
    (``atomics=True``: one range on the CPU). Split over ranges run at once, the count came out 2.2-3.5 M."""
    from stepterrain.kernels import solid as kernels

    _device.init_warp()
    device = _device.resolve_device("cpu")
    keys = wp.zeros(4_000_000, dtype=wp.int32, device=device)
    old = _device.set_cpu_threads(8)
    try:
        for _ in range(3):
            counts = wp.zeros(2, dtype=wp.int32, device=device)
            _device.launch_chunked(kernels.count_keys, keys.shape[0], [keys], [counts], device, atomics=True)
            assert counts.numpy()[0] == 4_000_000
    finally:
        _device.set_cpu_threads(old)


def test_a_mesh_of_fins_only_is_refused_not_a_numpy_error():
    """Two walls back to back on the same four vertices and nothing else: both go as a fin, and close_solid failed
    on numpy's max of an empty array (found in the final read; the NumPy reference fails the same way)."""
    vertices = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [1, 0, 3], [1, 3, 2]])
    with pytest.raises(InvalidInputError, match="every face was a zero-volume fin"):
        close_solid(vertices, faces, np.zeros(4, bool), -1.0)
