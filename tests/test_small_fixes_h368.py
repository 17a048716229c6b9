"""Small fixes (h368): thresholds_of for float64 levels, NumPy scalars in messages, singular counts, an empty path."""

from __future__ import annotations

import numpy as np

import stepterrain as st
from stepterrain.stepped import _isovalue_struct


def test_thresholds_of_float64_levels_are_the_thresholds_stepped_uses():
    """``thresholds_of`` averaged a float64 array in float64 as it was, while ``stepped`` takes levels as float32
    first: for levels 0.1 to 0.9 (np.arange(1, 10) / 10) the midpoint of 0.3 and 0.4 came out one float32 step off
    the threshold the kernels step at. Every input must give the kernels' thresholds bit for bit."""
    levels = np.arange(1, 10) / 10.0
    thresholds_of = st.stepped.thresholds_of
    kernels = _isovalue_struct(levels, "cpu").thresholds.numpy()  # what stepped(levels=levels) uploads
    float64_midpoints = ((levels[:-1] + levels[1:]) * 0.5).astype(np.float32)
    assert not np.array_equal(float64_midpoints, kernels)  # the case does round differently
    for given in (levels, list(levels), tuple(levels), levels.astype(np.float32), levels.astype(np.longdouble)):
        got = thresholds_of(given)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got.view(np.uint32), kernels.view(np.uint32))
