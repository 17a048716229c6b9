"""Bugs found by an adversarial hunt over the stepped-terrain path (issue 2), one test each."""

from __future__ import annotations

import importlib

import numpy as np

import stepterrain as st
from stepterrain._device import resolve_device
from stepterrain.stepped import step_arrays
from stepterrain.terrain import as_terrain

from .test_stepped import compare_with_reference

stepped_module = importlib.import_module("stepterrain.stepped")  # the package's `stepped` is the function


def test_isovalue_memo_is_built_from_the_float32_values_it_is_keyed_by():
    """The isovalue memo was keyed by the float32 bytes of the values but built from the values as given: float64
    levels (step_arrays given them, as the benchmarks and tests call it) put thresholds rounded from their float64
    midpoints into the memo, and every later call with the same float32 values (stepped(levels=...)) got them.
    (64.7 + 67.1) / 2 rounds to 65.9 in float32 from float64, to 65.899994 from the float32 levels: a height of
    65.899994 sits on the threshold (upper level) in the reference and fell below it. Found by stepping levels given
    once as float64 and once as float32, as the brief's "levels equal as values but different dtype" asked."""
    levels64 = np.array([64.7, 67.1])
    on = np.float32(65.899994)
    assert np.float32((levels64[0] + levels64[1]) / 2) != on  # the two roundings differ
    heights = np.array([[64.0, on, 68.0], [on, 68.0, on], [64.0, on, 64.0]], np.float32)
    stepped_module._ISOVALUES.clear()
    step_arrays(as_terrain(heights), levels64, device=resolve_device("cpu"))  # float64 values first
    compare_with_reference(heights, levels64.astype(np.float32), "cpu")
    fresh = stepped_module._build_isovalue_struct(levels64.astype(np.float32), resolve_device("cpu"))
    stepped_module._ISOVALUES.clear()
    mesh = st.stepped(heights, levels=levels64)
    assert fresh.thresholds.numpy()[0] == on
    stepped_module._ISOVALUES.clear()
    step_arrays(as_terrain(heights), levels64, device=resolve_device("cpu"))
    again = st.stepped(heights, levels=levels64)
    np.testing.assert_array_equal(again.vertices, mesh.vertices)
    np.testing.assert_array_equal(again.faces, mesh.faces)
