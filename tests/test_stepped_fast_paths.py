"""The native CPU fast paths of kernels/stepped.py against the generic Warp path and the NumPy reference.

On the CPU, count_grid counts the nodes whose cell has no corner on a threshold in native code
(``count_plain_nodes``: sixteen nodes at a time by the closed form, flat or not), and emit_grid writes runs of
plain nodes with flat cells in one native loop (``emit_flat_run``, the default output only: blended vertices,
no sources). ``step_arrays(want_sources=True)`` emits through the generic Warp path, and the independent
reference (tests/reference.py) checks what both count. The grids are rows of plateaus wider than the grid
passes' 256-node chunk (``CPU_CHUNK`` · ``GRID_CHUNK_FACTOR``), so runs cross chunk ends and reach row ends, with
heights on the thresholds, a float32 ulp either side of them, on the levels themselves and beyond the end levels;
levels uniform or irregular, up to past the 64 thresholds of the vector quantization.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st_

import stepterrain as st
from stepterrain._device import CPU_CHUNK, GRID_CHUNK_FACTOR, set_cpu_threads

from .reference import grid_tin, step_reference, thresholds_of
from .test_stepped import _compare_terrain_with_reference, assert_stepped_as_the_generic_pass

# widths around one and two chunks of the grid passes (runs end at, cross and stop short of chunk ends) and narrow ones
CHUNK = CPU_CHUNK * GRID_CHUNK_FACTOR
WIDTHS = [2, 3, 17, 33, CHUNK - 1, CHUNK, CHUNK + 1, CHUNK + 2, CHUNK + 3, 2 * CHUNK + 1, 2 * CHUNK + 2, 200]


@st_.composite
def plateau_grids(draw):
    """(heights, values): rows of plateaus of heights from the thresholds and their neighbourhoods."""
    n_values = draw(st_.integers(2, 90))
    if draw(st_.booleans()):
        scale = draw(st_.sampled_from([1.0, 0.1, 1e-3, 3.7, 1e5]))
        values = (np.arange(n_values) - n_values // 2).astype(np.float32) * np.float32(scale)
    else:
        raw = draw(st_.lists(st_.floats(-1e3, 1e3, width=32), min_size=2, max_size=n_values, unique=True))
        values = np.unique(np.asarray(raw, np.float32))
        assume(len(values) >= 2)
    thresholds = thresholds_of(values)
    assume(np.all(thresholds > values[:-1]))  # levels more than one float32 step apart (stepped refuses others)
    rng = np.random.default_rng(draw(st_.integers(0, 2**32 - 1)))
    between = rng.uniform(values[0] - 1.0, values[-1] + 1.0, len(values)).astype(np.float32)
    pool = np.concatenate([thresholds, np.nextafter(thresholds, np.float32(np.inf)),
                           np.nextafter(thresholds, np.float32(-np.inf)), values, between,
                           [values[0] - np.float32(1.0), values[-1] + np.float32(1.0)]]).astype(np.float32)
    rows = draw(st_.integers(2, 6))
    cols = draw(st_.sampled_from(WIDTHS))
    run = draw(st_.integers(1, 3 * CHUNK))  # plateau length along a row
    tall = draw(st_.integers(1, 3))  # and down the grid: cells flat down it too, nodes below a lower plateau
    noise = draw(st_.sampled_from([0.0, 0.01, 0.1]))
    pieces = rng.choice(pool, size=(rows // tall + 1, cols // run + 1))
    heights = np.repeat(np.repeat(pieces, tall, axis=0), run, axis=1)[:rows, :cols]
    if draw(st_.booleans()):  # plateaus of one level but not of one height: the blend rounds many heights
        level = np.searchsorted(thresholds, heights, side="right")
        lo = np.concatenate([[values[0] - 2.0], thresholds])[level]
        hi = np.concatenate([thresholds, [values[-1] + 2.0]])[level]
        rough = (lo + rng.uniform(0.05, 0.95, heights.shape) * (hi - lo)).astype(np.float32)
        keep = (np.searchsorted(thresholds, rough, side="right") == level) & (rng.random(heights.shape) < 0.8)
        heights = np.where(keep, rough, heights)
    bumps = rng.random((rows, cols)) < noise
    heights[bumps] = rng.choice(pool, int(bumps.sum()))
    return heights.astype(np.float32), values


@settings(max_examples=60, deadline=None)
@given(
    grid=plateau_grids(),
    dy=st_.sampled_from([1.0, -1.0, 30.0, -1e-3, 1e5]),
    gamma=st_.sampled_from([0.0, 0.3, 0.5, 0.7, 1.0]),
)
def test_native_runs_write_what_the_generic_path_writes(grid, dy, gamma):
    """emit_flat_run (stepped's default output) against the generic pass (sources requested): the same faces,
    face levels, walls and vertex bits, both windings (dy < 0: hf.flip), γ where (1 - γ) h + γ α rounds."""
    heights, values = grid
    t = st.Terrain.from_heights(heights, spacing=(30.0, dy), origin=(394000.5, 3798000.25))
    assert_stepped_as_the_generic_pass(t, values, gamma, "cpu")


@settings(max_examples=60, deadline=None)
@given(grid=plateau_grids(), dy=st_.sampled_from([1.0, -1.0]))
def test_native_counts_match_the_reference(grid, dy):
    """count_plain_nodes' vertex prefixes and face totals (and so the generic emit's output) against the NumPy
    reference: nodes on a threshold, a ulp off it, at the clamped end levels, edges crossing many levels."""
    heights, values = grid
    t = st.Terrain.from_heights(heights, spacing=(1.0, dy))
    points, faces = grid_tin(t.heights, t.spacing)
    _compare_terrain_with_reference(t, points, faces, values, "cpu")


def test_many_levels_crossed_by_every_edge_match_the_reference():
    """Plateaus between the lowest, the highest and middle ones of 200 levels (199 thresholds, past the vector
    quantization's 64), none on a threshold: no cell is left to the walk, so every face total is count_grid's
    closed form (1 + 4 (highest - lowest level) a triangle), beside long flat runs."""
    values = np.arange(200, dtype=np.float32)
    row = np.repeat(np.array([-5.0, 250.0, 120.3, -5.0, 250.0, 57.7, 250.0], np.float32), 23)
    heights = np.stack([row, np.roll(row, 7), np.roll(row, 40), row, np.roll(row, -3)])
    t = st.Terrain.from_heights(heights)
    arrays = _compare_terrain_with_reference(t, *grid_tin(heights, (1.0, 1.0)), values, "cpu")
    levels = np.searchsorted(thresholds_of(values), heights, side="right")
    assert np.abs(np.diff(levels, axis=1)).max() == 199
    assert arrays.face_count > 4 * 199 * 10


@pytest.mark.parametrize("threads", [1, 2])
def test_threaded_re_steps_write_what_the_generic_path_writes(threads):
    """A grid split over threads (each a range of chunks), stepped twice with other levels and γ (the scratch
    offsets and outputs reused): the fast paths' output equals the generic pass's and does not depend on the
    split."""
    rows, cols = np.mgrid[0:260, 0:300].astype(np.float64)
    smooth = 40.0 * np.sin(rows / 17.0) * np.cos(cols / 23.0) + 0.3 * cols
    heights = (np.floor(smooth / 2.5) * 2.5).astype(np.float32)  # plateaus, every other one on a threshold
    heights[::9, ::13] += np.float32(0.25)
    t = st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(394000.0, 3798000.0))
    previous = set_cpu_threads(threads)
    try:
        for values, gamma in ((np.arange(-60.0, 120.0, 5.0, dtype=np.float32), 0.3),
                              (np.arange(-65.0, 120.0, 10.0, dtype=np.float32), 1.0)):
            mesh = assert_stepped_as_the_generic_pass(t, values, gamma, "cpu")
        ref = step_reference(*grid_tin(heights, t.spacing), values)
        assert (len(mesh.vertices), len(mesh.faces)) == (len(ref.points), len(ref.faces))
    finally:
        set_cpu_threads(previous)


@pytest.mark.parametrize("span", [4, 12])  # within the eight levels of the per-threshold test, and beyond it
@pytest.mark.parametrize("end", ["lowest", "highest"])
def test_a_node_on_the_threshold_at_either_end_of_a_blocks_levels_matches_the_reference(span, end):
    """count_plain_nodes' sixteen-node test compares the two rows' heights with the thresholds from the one below
    their lowest level to the one below their highest (a per-lane lookup beyond eight levels): one node, in either
    row at lane 0, 7 or 15 of a block or just past it (the last lane's right neighbour), on the threshold below the
    block's lowest level (T[0] where that is level 1) or its highest, among nodes off every threshold. Rows a level
    lower above and below: a node on the threshold of the lowest level around it counts as a plain one (no twin),
    so only a lower neighbour outside the block's two rows tells a missed one."""
    values = np.arange(40, dtype=np.float32)  # thresholds k + 0.5: a height k lies on level k, k - 0.5 on its threshold
    lo = 5 if span == 4 else 1
    cols = 34  # a row's nodes 0..32 go sixteen at a time from 0 and 16
    j = np.arange(cols)
    base = np.stack([np.full(cols, lo - 1), lo + (3 * j) % (span + 1), lo + (3 * j + 2) % (span + 1),
                     np.full(cols, lo - 1)]).astype(np.float32)
    level = lo if end == "lowest" else lo + span
    for row in (1, 2):
        for col in (0, 7, 15, 16):
            heights = base.copy()
            heights[row, col] = level - 0.5
            t = st.Terrain.from_heights(heights)
            assert np.searchsorted(thresholds_of(values), heights, side="right")[row, col] == level
            _compare_terrain_with_reference(t, *grid_tin(heights, (1.0, 1.0)), values, "cpu")
