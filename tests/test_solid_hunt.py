"""Bug hunt in the solids path (stepped(..., solid=True), mesh.close_solid, kernels/solid.py): one failing test per
bug found.

* ``stepped(..., floor=...)`` without ``solid=True`` was refused only after the whole terrain was stepped, so a
  refusal from the stepping (the memory budget's) named something else and the misplaced ``floor`` went unsaid.
* A solid's default floor (no ``floor`` given) one interval (or a tenth of the levels' span, at least 0.1) below the
  lowest point was below float32's resolution of large heights (an interval of 2 at 1e8, a single level at 1e6 and
  more): the base lay on the lowest terrace in float32 (.glb, .stl: no thickness there), or, below float64's (1e16,
  1e20), on it in float64 too, and close_solid refused "floor must lie below ..." for a floor the caller never gave.
"""

from __future__ import annotations

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import InvalidInputError
from stepterrain.stepped import default_floor


def test_a_floor_without_solid_is_refused_before_any_stepping():
    heights = st.sample_dem().heights[:40, :40]
    # a budget the stepped mesh cannot fit: the floor's refusal must come first, before the count pass
    with pytest.raises(InvalidInputError, match="floor applies only with solid=True"):
        st.stepped(heights, interval=50.0, floor=-5.0, memory_budget=1000)
    with pytest.raises(InvalidInputError, match="floor applies only with solid=True"):
        st.stepped(heights, interval=50.0, floor=-5.0, gamma=np.full((3, 3), 0.5))  # γ of the wrong shape


@pytest.mark.parametrize(("offset", "options"), [
    (1e8, {"interval": 2.0}), (4e6, {"levels": [4e6]}), (1e16, {"levels": [1e16]}), (1e20, {"interval": 2.0}),
])
def test_the_default_floor_lies_below_the_lowest_point_in_float32(offset, options):
    heights = np.array([[0.0, 1.0, 2.0], [1.0, 2.0, 3.0], [2.0, 3.0, 4.0]], np.float32) + np.float32(offset)
    mesh = st.stepped(heights, solid=True, **options)  # no floor given: none may be refused
    assert mesh.is_watertight and mesh.is_winding_consistent
    floor = mesh.metadata["floor"]
    top = mesh.vertices[mesh.vertices[:, 2] > floor, 2]
    # a .glb's or .stl's float32 base lies below every surface vertex, not on the lowest terrace
    assert np.float32(floor) < np.float32(top.min())
    f32 = mesh.vertices.astype(np.float32)
    assert len(np.unique(f32, axis=0)) == len(f32)  # every vertex on its own float32 position


def test_the_default_floor_is_unchanged_where_float32_resolves_it():
    values = np.array([0.0, 2.0, 4.0], np.float32)
    assert default_floor(values, 0.0, 2.0) == -2.0
    assert default_floor(values, -0.5, None) == pytest.approx(-0.9)
    assert default_floor(np.array([1000.0], np.float32), 1000.0, None) == pytest.approx(999.9)
    # and float32's lowest value keeps its clamp (nothing lies below it)
    lowest = -float(np.finfo(np.float32).max)
    assert default_floor(np.array([lowest], np.float32), lowest, 1.0) == lowest
