"""Bugs found by a hunt over the less-tested stepped combinations (lenses, TINs, series, γ, nodata, solids, extreme
intervals and coordinates), one test each."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st_

import stepterrain as st


def _minimal_cover(lo: float, hi: float, interval: float, base: float) -> np.ndarray:
    """The run of ``float32(base + k * interval)`` over consecutive k that covers [float32(lo), float32(hi)] with the
    fewest values: the last at or below lo to the first at or above hi, found by walking k over a wide window (no
    floor or ceil of a quotient)."""
    k_lo, k_hi = int(np.floor((lo - base) / interval)) - 3, int(np.ceil((hi - base) / interval)) + 3
    run = (base + np.arange(k_lo, k_hi + 1, dtype=np.float64) * interval).astype(np.float32)
    lo32, hi32 = np.float32(lo), np.float32(hi)
    below = np.flatnonzero(run <= lo32)
    above = np.flatnonzero(run >= hi32)
    return run[below[-1] : above[0] + 1]


def test_isovalues_add_no_empty_level_where_the_quotient_rounds_off_an_integer():
    """(lo - base) / interval rounds in float64: float32 heights 0.7 to 1.0 at interval 0.1 give 6.99999988 and the
    floor took 6, an isovalue 0.6 no height reaches (0.7 is an isovalue itself); heights 0 to float32(0.3) gave
    3.0000001 and the ceil took 4, an empty 0.4 on top. Heights 7 to 10 at interval 1 got no such level: level indices
    then started at 1, colormaps were spread over a level too many, and a solid's default floor lay two intervals
    below the lowest terrace rather than one."""
    lo = float(np.float32(0.7))
    np.testing.assert_array_equal(st.isovalues((lo, 1.0), interval=0.1),
                                  np.float32([0.7, 0.8, 0.9, 1.0]))
    np.testing.assert_array_equal(st.isovalues((0.0, float(np.float32(0.3))), interval=0.1),
                                  np.float32([0.0, 0.1, 0.2, 0.3]))
    heights = np.array([[0.7, 0.8], [0.9, 1.0]], np.float32)
    mesh = st.stepped(heights, interval=0.1)
    assert mesh.metadata["isovalues"] == np.float32([0.7, 0.8, 0.9, 1.0]).tolist()
    assert mesh.face_attributes["level"].min() == 0  # the lowest terrace is level 0, as heights 7 to 10 at 1 give
    solid = st.stepped(heights, interval=0.1, solid=True)
    assert solid.metadata["floor"] == float(np.float32(0.7)) - 0.1  # one interval below the lowest isovalue
    integers = st.stepped(heights * 10, interval=1.0, solid=True)
    assert integers.metadata["floor"] == 6.0 and integers.metadata["isovalues"] == [7.0, 8.0, 9.0, 10.0]


@settings(max_examples=300, deadline=None)
@given(lo=st_.integers(-3000, 3000), span=st_.integers(0, 400),
       interval=st_.sampled_from([0.1, 0.2, 0.3, 0.7, 1.0, 2.5, 0.05, 0.01]),
       base=st_.sampled_from([0.0, 0.1, -0.3, 0.05, 1.7]), scale=st_.sampled_from([0.1, 0.01, 0.5, 1.0]))
def test_isovalues_are_the_fewest_that_cover_the_float32_heights(lo, span, interval, base, scale):
    """Against an independent walk over k: decimal heights (float32, as stepped() takes them) and decimal intervals,
    whose quotients land a hair off integers; the isovalues are the shortest run of float32(base + k * interval)
    whose first lies at or below the lowest height and whose last at or above the highest."""
    h_lo = float(np.float32(lo * scale))
    h_hi = float(np.float32((lo + span) * scale))
    got = st.isovalues((h_lo, h_hi), interval=interval, base=base)
    np.testing.assert_array_equal(got, _minimal_cover(h_lo, h_hi, interval, base))


def test_a_lens_of_two_by_two_samples_is_refused_rather_than_changing_nothing():
    """A circular lens's mask covers the square around its centre whose border samples lie beyond its reach, so a
    2 x 2 mask (resolution=2, accepted as ">= 2") held only those four corners, all ``outside``: a lens in the middle
    of the terrain left every vertex stepped, without the warning a lens beside the terrain gets."""
    heights = np.zeros((50, 50))
    with pytest.raises(st.InvalidInputError, match=r"lens resolution must be an int >= 3; got 2"):
        st.circular_lens(heights, (25.0, 25.0), 10.0, resolution=2)


@pytest.mark.parametrize("resolution", [3, 4, 5, 8, 512])
def test_every_accepted_lens_resolution_shows_the_inside_at_the_centre(resolution):
    """The smallest masks still reach ``inside`` at the lens's centre (γ sampled there as stepped() samples it): the
    original terrain, not the steps, at the centre vertex."""
    rng = np.random.default_rng(0)
    heights = rng.uniform(0.0, 10.0, (51, 51)).astype(np.float32)
    lens = st.circular_lens(heights, (25.0, 25.0), 10.0, resolution=resolution)
    mesh = st.stepped(heights, interval=1.0, gamma=lens)
    at_zero = st.stepped(heights, interval=1.0, gamma=0.0)
    at_one = st.stepped(heights, interval=1.0, gamma=1.0)
    centre = np.flatnonzero((at_one.vertices[:, 0] == 25.0) & (at_one.vertices[:, 1] == 25.0))
    z0, z1, z = at_zero.vertices[centre, 2], at_one.vertices[centre, 2], mesh.vertices[centre, 2]
    moved = z1 != z0
    assert moved.any()
    gamma = (z[moved] - z0[moved]) / (z1[moved] - z0[moved])
    assert np.all(gamma < 0.01)


def _lens_gamma(lens: st.Lens, xy: np.ndarray) -> np.ndarray:
    """γ of ``lens`` at world ``xy``, bilinear over its mask (row 0 at the lower y), clamped to its edges: Lens's
    documented sampling, in float64."""
    xmin, xmax, ymin, ymax = lens.extent
    rows, cols = lens.mask.shape
    u = np.clip((xy[:, 0] - xmin) / (xmax - xmin), 0.0, 1.0) * (cols - 1)
    w = np.clip((xy[:, 1] - ymin) / (ymax - ymin), 0.0, 1.0) * (rows - 1)
    j0, i0 = np.minimum(u.astype(int), cols - 1), np.minimum(w.astype(int), rows - 1)
    j1, i1 = np.minimum(j0 + 1, cols - 1), np.minimum(i0 + 1, rows - 1)
    fu, fw = u - j0, w - i0
    m = lens.mask.astype(np.float64)
    return (1 - fw) * ((1 - fu) * m[i0, j0] + fu * m[i0, j1]) + fw * ((1 - fu) * m[i1, j0] + fu * m[i1, j1])


@settings(max_examples=15, deadline=None)
@given(seed=st_.integers(0, 2**31 - 1), n=st_.integers(6, 30), holes=st_.floats(0.0, 0.3),
       where=st_.sampled_from(["centre", "corner", "beyond an edge"]), on_thresholds=st_.booleans(),
       clockwise=st_.booleans())
def test_a_lens_on_a_tin_with_nodata_at_utm_blends_every_vertex_and_closes(seed, n, holes, where, on_thresholds,
                                                                           clockwise):
    """A circular lens over a TIN (Delaunay of random points at UTM coordinates, NaN heights dropping faces, either
    winding, heights on thresholds or not), the lens at the centre, a corner or reaching in from beyond an edge: every
    vertex of the surface is (1 - γ) z(γ=0) + γ z(γ=1) for γ sampled at its xy, faces and xy those of γ = 1; the
    solid is watertight and consistently wound with a positive volume."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 100.0, (n, 2))
    faces = Delaunay(xy).simplices
    z = rng.integers(-2, 5, n).astype(np.float64) + (0.0 if on_thresholds else rng.uniform(0.1, 0.4, n))
    z[rng.random(n) < holes] = np.nan
    a, b, c = (xy[faces[:, k]] for k in range(3))
    area = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    keep = np.isfinite(z)[faces].all(axis=1)
    if not keep.any() or area.min() < 1e-2:  # no surface, or a sliver: not what this tests
        return
    origin = np.array([612_000.0, 4_210_000.0])
    tin = trimesh.Trimesh(np.column_stack([xy + origin, z]), faces[:, ::-1] if clockwise else faces, process=False)
    centre = {"centre": origin + 50.0, "corner": origin + xy.min(axis=0),
              "beyond an edge": origin + [xy[:, 0].max() + 30.0, 50.0]}  # its soft edge reaches 15 in
    lens = st.circular_lens(tin, tuple(centre[where]), 40.0)
    mesh = st.stepped(tin, interval=1.0, gamma=lens)
    at_zero = st.stepped(tin, interval=1.0, gamma=0.0)
    at_one = st.stepped(tin, interval=1.0, gamma=1.0)
    np.testing.assert_array_equal(mesh.faces, at_one.faces)
    np.testing.assert_array_equal(mesh.vertices[:, :2], at_one.vertices[:, :2])
    gamma = _lens_gamma(lens, mesh.vertices[:, :2])
    want = (1.0 - gamma) * at_zero.vertices[:, 2] + gamma * at_one.vertices[:, 2]
    np.testing.assert_allclose(mesh.vertices[:, 2], want, rtol=0, atol=1e-4)
    solid = st.stepped(tin, interval=1.0, gamma=lens, solid=True)
    assert solid.is_watertight and solid.is_winding_consistent and solid.volume > 0
