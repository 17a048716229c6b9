"""Bug hunt in the solids path (stepped(..., solid=True), mesh.close_solid, kernels/solid.py): one failing test per
bug found.

* ``stepped(..., floor=...)`` without ``solid=True`` was refused only after the whole terrain was stepped, so a
  refusal from the stepping (the memory budget's) named something else and the misplaced ``floor`` went unsaid.
* A solid's default floor (no ``floor`` given) one interval (or a tenth of the levels' span, at least 0.1) below the
  lowest point was below float32's resolution of large heights (an interval of 2 at 1e8, a single level at 4e6 and
  more): the base lay on the lowest terrace in float32 (.glb, .stl: no thickness there), or, below float64's (1e16,
  1e20), on it in float64 too, and close_solid refused "floor must lie below ..." for a floor the caller never gave.

And a property test of what held: a solid's volume against a closed-form NumPy integral of the heights.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs

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


def _fraction_at_or_above(corners: np.ndarray, t: float) -> np.ndarray:
    """Per triangle (rows of its three corner heights), the fraction of its area where the linear interpolant of its
    corners is at least ``t`` (closed form: the triangle cut at the level t of its middle corner)."""
    h = np.sort(corners, axis=1)
    h0, h1, h2 = h[:, 0], h[:, 1], h[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        upper = np.nan_to_num((h2 - t) ** 2 / ((h2 - h0) * (h2 - h1)), nan=0.0)  # t in [h1, h2]: a corner above
        lower = np.nan_to_num(1.0 - (t - h0) ** 2 / ((h1 - h0) * (h2 - h0)), nan=1.0)  # t in (h0, h1): one below
    return np.where(t <= h0, 1.0, np.where(t > h2, 0.0, np.where(t >= h1, upper, lower)))


def _numpy_solid_volume(heights: np.ndarray, values: np.ndarray, gamma: float, floor: float) -> float:
    """The integral of (surface - floor) over the footprint, from the heights alone: two triangles a unit cell,
    (n00, n01, n11) and (n00, n11, n10), those with a NaN corner left out; the surface (1 - γ) h + γ α(h), α(h) the
    nearest isovalue, whose integral over a triangle is α_0 plus each step α_i+1 - α_i times the area at or above its
    threshold."""
    n00, n01, n10, n11 = heights[:-1, :-1], heights[:-1, 1:], heights[1:, :-1], heights[1:, 1:]
    corners = np.concatenate([np.stack([n00, n01, n11], -1).reshape(-1, 3),
                              np.stack([n00, n11, n10], -1).reshape(-1, 3)])
    corners = corners[np.isfinite(corners).all(axis=1)].astype(np.float64)
    area = 0.5
    values = values.astype(np.float64)
    stepped = np.full(len(corners), values[0])
    for low, high in zip(values[:-1], values[1:], strict=True):
        stepped += (high - low) * _fraction_at_or_above(corners, (low + high) / 2.0)
    surface = (1.0 - gamma) * corners.mean(axis=1) + gamma * stepped
    return float(area * (surface - floor).sum())


@settings(max_examples=25, deadline=None)
@given(seed=hs.integers(0, 2**31 - 1), rows=hs.integers(2, 7), cols=hs.integers(2, 7),
       gamma=hs.sampled_from([0.0, 0.35, 1.0]), holes=hs.floats(0.0, 0.4),
       levels=hs.sampled_from([None, [-3.0], [20.0, 30.0], [1.0, 2.5, 7.0], [-5.0, 4.0, 12.0]]))
def test_solid_volume_equals_an_independent_numpy_integral(seed, rows, cols, gamma, holes, levels):
    """Watertight, outward (positive volume), and the volume of the heights' stepped surface over the floor, from a
    closed-form integral over the grid's triangles: random float heights (none on a threshold), nodata holes, γ in
    [0, 1] and levels inside, across or outside the heights."""
    rng = np.random.default_rng(seed)
    heights = rng.uniform(0.0, 10.0, (rows, cols)).astype(np.float32)
    heights[rng.random((rows, cols)) < holes] = np.nan
    options = {"interval": 2.0, "base": 0.25} if levels is None else {"levels": levels}
    try:
        mesh = st.stepped(heights, gamma=gamma, solid=True, **options)
    except InvalidInputError as exc:  # every cell touches nodata
        assert "needs a surface to close" in str(exc)
        return
    assert mesh.is_watertight and mesh.is_winding_consistent
    values = np.asarray(mesh.metadata["isovalues"], np.float32)
    want = _numpy_solid_volume(heights, values, gamma, mesh.metadata["floor"])
    assert mesh.volume > 0
    assert mesh.volume == pytest.approx(want, rel=1e-6)
