"""circular_lens over a raw array takes the spacing and origin that stepped() is given, and a lens wholly beside
the terrain is warned of (paper 000 §4, Fig. 4: the lens shows the original terrain where the user points it)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import stepterrain as st
from stepterrain.terrain import Terrain


def _dem() -> np.ndarray:
    y, x = np.mgrid[0:64, 0:80]
    return (100.0 + 40.0 * np.sin(x / 9.0) + 30.0 * np.cos(y / 7.0)).astype(np.float32)


def test_a_raw_arrays_lens_takes_the_spacing_and_origin_stepped_is_given():
    h = _dem()
    spacing, origin = (30.0, -30.0), (500000.0, 4200000.0)
    center = (origin[0] + 40 * 30.0, origin[1] - 30 * 30.0)  # column 40, row 30: in the terrain, in metres
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lens = st.circular_lens(h, center, 300.0, spacing=spacing, origin=origin)
    same = st.circular_lens(Terrain.from_heights(h, spacing=spacing, origin=origin), center, 300.0)
    np.testing.assert_array_equal(lens.mask, same.mask)
    assert lens.extent == same.extent
    mesh = st.stepped(h, interval=10.0, spacing=spacing, origin=origin, gamma=lens)
    flat = st.stepped(h, interval=10.0, spacing=spacing, origin=origin, gamma=1.0)
    # the original terrain shows inside the lens: vertices near its centre are off the isovalues there
    near = np.hypot(mesh.vertices[:, 0] - center[0], mesh.vertices[:, 1] - center[1]) < 150.0
    assert near.any() and not np.allclose(mesh.vertices[near, 2] % 10.0, 0.0, atol=1e-3)
    assert len(mesh.faces) != len(flat.faces) or not np.array_equal(mesh.vertices, flat.vertices)


def test_a_lens_beside_the_terrain_warns_and_names_the_raw_arrays_coordinates():
    h = _dem()
    with pytest.warns(UserWarning, match=r"circular_lens: the lens at \(1500, 900\), radius 300, lies outside the "
                      r"terrain's extent x 0 to 79, y 0 to 63: gamma is `outside` \(1\) everywhere \(a raw array's "
                      r"coordinates are its column and row unless spacing=/origin= are given") as said:
        lens = st.circular_lens(h, (1500.0, 900.0), 300.0)
    assert said[0].filename == __file__  # pointed at the user's call
    assert (lens.mask == 1.0).all()
    t = Terrain.from_heights(h, spacing=(30.0, 30.0))
    with pytest.warns(UserWarning, match=r"lies outside the terrain's extent x 0 to 2370.*everywhere$"):
        st.circular_lens(t, (-2000.0, 900.0), 300.0)  # a Terrain has its coordinates: no hint about them


@pytest.mark.parametrize("center", [(40.0, 30.0), (-2.0, 30.0), (79.0 + 2.0, 63.0 + 2.0)])
def test_a_lens_on_or_reaching_into_the_terrain_says_nothing(center):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        st.circular_lens(_dem(), center, 4.0)


def test_spacing_for_a_terrain_that_has_its_own_is_refused_by_name():
    t = Terrain.from_heights(_dem(), spacing=(30.0, 30.0))
    with pytest.raises(st.errors.InvalidInputError, match="spacing/origin apply to raw"):
        st.circular_lens(t, (0.0, 0.0), 10.0, spacing=(30.0, 30.0))
