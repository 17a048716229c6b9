"""A solid's skirt and base counted against the memory budget (stepped.py: solid_boundary_edges, solid_bytes).

``stepped(..., solid=True)`` checked only the surface against the budget: close_solid's closed mesh (a copy of the
surface, a base vertex per vertex, a base face per terrace, skirt faces per boundary edge) and its work arrays came
after it, uncounted, at 4-5 times the surface's bytes (a 5 x 6 ramp over 1e6 levels peaked at 24 GB under a 17 GB
budget). They are now predicted, as an upper bound, and checked with the surface before anything is allocated.
"""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as hs

import stepterrain as st
from stepterrain import stepped as stepped_module
from stepterrain.mesh import boundary_edges
from stepterrain.terrain import as_terrain


def _need(heights, interval, colors=None):
    """The bytes the budget check asks of a solid: the surface's (stepped.py's per-vertex and per-face bytes) and the
    predicted skirt and base, from the surface's counts (the terrain nudged off the thresholds, as stepped() steps a
    solid), and those counts and the boundary bound."""
    t = as_terrain(heights)
    values = st.isovalues(t.height_range, interval=interval)
    t = stepped_module._off_thresholds(t, values)
    arrays, _ = stepped_module._stepped_arrays(t, values, 1.0, colors, wp.get_device("cpu"))
    v, f = arrays.vertex_count, arrays.face_count
    b = stepped_module.solid_boundary_edges(t, values)
    extra = 0 if colors is None else stepped_module._COLOR_BYTES
    surface = v * (stepped_module._VERTEX_BYTES + extra) + f * stepped_module._FACE_BYTES
    return surface + stepped_module.solid_bytes(v, f, b), (v, f, b, arrays.faces)


def _ramp(top):
    """A 5 x 6 grid rising from 0 to ``top``: every edge crosses many levels, the skirt's share is large."""
    return np.linspace(0.0, top, 30, dtype=np.float32).reshape(5, 6)


def test_a_solid_over_the_budget_is_refused_and_one_at_its_need_is_built():
    """The surface alone (~3 MB here) passed a budget its solid needed ~5 times over: close_solid allocated the rest
    unchecked. A budget one byte under the need is refused, naming the solid and the budget with the usual hint; the
    need itself is accepted, and the solid is the one the default budget gives."""
    heights = _ramp(2000.0)
    need, (v, f, _, _) = _need(heights, 1.0)
    surface = v * stepped_module._VERTEX_BYTES + f * stepped_module._FACE_BYTES
    assert need > 3 * surface  # the skirt and base are most of it: a budget between was the bug's room
    with pytest.raises(st.OutputTooLargeError, match=r"the stepped solid \(a surface of [\d,]+ vertices and [\d,]+ "
                       r"faces, up to [\d,]+ boundary edges for its skirt, and its base\) would need [\d.,]+ MiB, over "
                       r"the memory budget of [\d.,]+ MiB; crop or coarsen the input .*raise the budget"):
        st.stepped(heights, interval=1.0, solid=True, memory_budget=need - 1)
    with pytest.raises(st.OutputTooLargeError, match="stepped solid"):
        st.stepped(heights, interval=1.0, solid=True, memory_budget=2 * surface)  # the surface fits, the solid not
    solid = st.stepped(heights, interval=1.0, solid=True, memory_budget=need)
    assert solid.is_watertight
    reference = st.stepped(heights, interval=1.0, solid=True)
    assert np.array_equal(solid.vertices, reference.vertices) and np.array_equal(solid.faces, reference.faces)
    # the surface alone is held to its own bytes as before
    assert len(st.stepped(heights, interval=1.0, memory_budget=surface).faces) == f


def test_the_set_budget_holds_for_a_solid_too():
    heights = _ramp(500.0)
    need, _ = _need(heights, 1.0)
    previous = st.set_memory_budget(need - 1)
    try:
        with pytest.raises(st.OutputTooLargeError, match="stepped solid"):
            st.stepped(heights, interval=1.0, solid=True)
        st.set_memory_budget(need)
        assert st.stepped(heights, interval=1.0, solid=True).is_watertight
    finally:
        st.set_memory_budget(previous)


def _actual_bytes(mesh):
    arrays = [mesh.vertices, mesh.faces, mesh.face_attributes["level"], mesh.face_attributes["wall"]]
    if mesh.visual.kind == "vertex":
        arrays.append(mesh.visual.vertex_colors)
    return sum(a.nbytes for a in arrays)


@settings(max_examples=25, deadline=None)
@given(
    rows=hs.integers(2, 7),
    cols=hs.integers(2, 7),
    seed=hs.integers(0, 2**31 - 1),
    interval=hs.sampled_from([0.5, 1.0, 2.0, 3.0, 7.0]),
    holes=hs.integers(0, 4),
    below=hs.sampled_from([None, 1.0, 50.0]),
    integers=hs.booleans(),
)
def test_the_prediction_bounds_the_solid_for_random_grids(rows, cols, seed, interval, holes, below, integers):
    """The predicted boundary is at least the surface's boundary edges, and the predicted skirt and base at least the
    closed mesh's arrays (vertices, faces, levels, walls, colours); heights on thresholds (integers), nodata holes
    (pinches between them) and floors far below included. The need is accepted as the budget, one byte less not."""
    rng = np.random.default_rng(seed)
    heights = rng.normal(0.0, 6.0, size=(rows, cols)).cumsum(0).cumsum(1).astype(np.float32)
    if integers:
        heights = np.round(heights)
    heights.reshape(-1)[rng.integers(0, rows * cols, size=holes)] = np.nan
    need, (v, f, b, faces) = _need(heights, interval, colors="terrain")
    if f == 0:
        return  # no triangle with three finite heights: nothing to close (refused by stepped)
    assert b >= len(boundary_edges(faces))
    floor = None if below is None else float(np.nanmin(heights)) - interval - below
    options = {"interval": interval, "solid": True, "floor": floor, "colors": "terrain"}
    mesh = st.stepped(heights, memory_budget=need, **options)
    assert stepped_module.solid_bytes(v, f, b) >= _actual_bytes(mesh)
    with pytest.raises(st.OutputTooLargeError, match="stepped solid"):
        st.stepped(heights, memory_budget=need - 1, **options)


def test_the_prediction_bounds_a_tin_solid():
    """A TIN's boundary edges are its edges of one face: their crossings bound the skirt's."""
    rng = np.random.default_rng(5)
    heights = rng.normal(0.0, 3.0, size=(9, 11)).cumsum(0).cumsum(1)
    tin = st.heightfield_mesh(heights)
    t = as_terrain(tin)
    values = st.isovalues(t.height_range, interval=1.0)
    t = stepped_module._off_thresholds(t, values)
    arrays, _ = stepped_module._stepped_arrays(t, values, 1.0, None, wp.get_device("cpu"))
    b = stepped_module.solid_boundary_edges(t, values)
    assert b >= len(boundary_edges(arrays.faces)) > 0
    mesh = st.stepped(tin, interval=1.0, solid=True)
    assert stepped_module.solid_bytes(arrays.vertex_count, arrays.face_count, b) >= _actual_bytes(mesh)


@pytest.mark.parametrize("case", ["ramp", "walk", "small"])
def test_a_solids_peak_stays_within_its_predicted_bytes(case):
    """What a solid allocates at its peak (tracemalloc: the surface's numpy arrays, close_solid's closed mesh and its
    work arrays) stays under the bytes the budget check counts, and not far under it (the prediction is not a
    blanket factor)."""
    if case == "ramp":
        heights, interval = _ramp(4000.0), 1.0
    else:
        rng = np.random.default_rng(11)
        n = 120 if case == "walk" else 12  # small: the fixed part (small arrays) counts most
        heights, interval = rng.normal(size=(n, n)).cumsum(0).cumsum(1).astype(np.float32), 2.0
    need, _ = _need(heights, interval)
    st.stepped(heights, interval=interval, solid=True)  # kernels loaded, caches warm
    # every array fresh (and so traced): outputs lent from the pool on memory an earlier mesh freed were not, and
    # whether the warm-up's mesh had been collected by then decided the peak (walk: 0.35 of the need, or 0.68)
    gc.collect()
    previous = st.set_output_pool_limit(0)
    tracemalloc.start()
    try:
        st.stepped(heights, interval=interval, solid=True)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
        st.set_output_pool_limit(previous)
    assert 0.4 * need <= peak <= need, (peak, need)


def _boundary_edges_reference(h, thresholds):
    """solid_boundary_edges of a grid, as first written: every candidate edge of the outer ring and of each cell
    touching nodata, with 2 k + 3 per edge of two finite ends crossing k thresholds."""
    level = np.searchsorted(thresholds, np.where(np.isfinite(h), h, 0), side="right").reshape(-1)
    ok = np.isfinite(h).reshape(-1)
    total = 0

    def add(a, b):
        both = ok[a] & ok[b]
        return int((2 * np.abs(level[a] - level[b]) + 3)[both].sum())

    rows, cols = h.shape
    index = np.arange(h.size).reshape(h.shape)
    for a, b in ((index[0, :-1], index[0, 1:]), (index[-1, :-1], index[-1, 1:]), (index[:-1, 0], index[1:, 0]),
                 (index[:-1, -1], index[1:, -1])):
        total += add(a, b)
    bad = ~np.isfinite(h)
    r, c = np.nonzero(bad[:-1, :-1] | bad[1:, :-1] | bad[:-1, 1:] | bad[1:, 1:])
    i00, i01, i10, i11 = index[r, c], index[r, c + 1], index[r + 1, c], index[r + 1, c + 1]
    for a, b in ((i00, i01), (i10, i11), (i00, i10), (i01, i11), (i00, i11), (i01, i10)):
        total += add(a, b)
    return total


@settings(max_examples=25, deadline=None)
@given(rows=hs.integers(2, 40), cols=hs.integers(2, 40), seed=hs.integers(0, 2**16), holes=hs.floats(0.0, 1.0),
       block=hs.integers(1, 200))
def test_the_boundary_bound_of_a_grid_matches_its_reference(rows, cols, seed, holes, block):
    """solid_boundary_edges counts each candidate edge as the reference does, whatever the holes (none, some, all
    but a few) and the nodes read at a time (``block``: one row to all of them), so the rows taken a block at a time
    and the cells wholly nodata left out change no count."""
    rng = np.random.default_rng(seed)
    h = rng.uniform(0.0, 50.0, (rows, cols)).astype(np.float32)
    h[rng.random((rows, cols)) < holes] = np.nan
    t = as_terrain(h)
    values = st.isovalues((0.0, 50.0), interval=3.0)
    expected = _boundary_edges_reference(h, stepped_module.thresholds_of(values))
    default = stepped_module._SOLID_BOUNDARY_BLOCK
    stepped_module._SOLID_BOUNDARY_BLOCK = block  # not monkeypatch: hypothesis runs the examples in one test call
    try:
        assert stepped_module.solid_boundary_edges(t, values) == expected
    finally:
        stepped_module._SOLID_BOUNDARY_BLOCK = default


def test_the_boundary_bound_of_a_grid_half_nodata_takes_little_memory():
    """The bound is computed before the budget check, so it must not itself take memory in proportion to the grid:
    a grid half nodata (a coast: the sea is nodata) made index and height arrays for every cell touching nodata, the
    sea's cells wholly nodata included (~30 bytes a node here, 180 MB for a 6000² DEM before any check). Now only
    the cells where nodata meets heights are candidates, and the grid's rows are taken a block at a time."""
    h = np.linspace(0.0, 100.0, 1500 * 1500, dtype=np.float32).reshape(1500, 1500)
    h[:, 700:] = np.nan
    t = as_terrain(h)
    values = st.isovalues(t.height_range, interval=1.0)
    assert t.has_nodata  # cached before the peak is measured
    tracemalloc.start()
    try:
        stepped_module.solid_boundary_edges(t, values)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < h.size  # under a byte a node
