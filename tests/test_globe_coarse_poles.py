"""The globe at its extremes: the coarsest mesh's poles under a drape, an eye altitude below float64's resolution
at a huge radius, and per-face parts saved again after reading them back."""

from __future__ import annotations

import re

import numpy as np
import pytest

from stepterrain.cli import main
from stepterrain.errors import InvalidInputError
from stepterrain.globe import Globe, look_from


@pytest.mark.parametrize("radius, altitude, spacing", [(1e20, 1000.0, "16384"), (1e20, -1000.0, "16384"),
                                                       (1e29, 1e12, "1.75922e+13")])
def test_an_eye_rounded_onto_a_huge_sphere_is_refused_saying_by_how_much_to_raise_it(radius, altitude, spacing):
    """look_from(0, 0, 1000, radius=1e20): float64's numbers lie 16384 m apart at 1e20, so radius + altitude rounded
    to the radius, the eye onto the sphere, and the globe refused it as "inside the planet ... |eye| =
    100000000000000000000.0 m, the surface there 100000000000000000000.0 m ... terrain +0.0 m; raise the eye",
    saying neither why nor by how much. The refusal names float64's spacing there (the least altitude that keeps the
    eye off the sphere); an eye that high is taken. (look_from itself keeps such an eye's view direction:
    test_look_from_keeps_its_view_direction_over_a_large_sphere.)"""
    lat = np.linspace(89.5, -89.5, 18)
    lon = np.linspace(-175.0, 175.0, 36)
    globe = Globe.from_latlon(np.zeros((18, 36)), lat, lon, face_size=3, radius=radius, device="cpu")
    with pytest.raises(InvalidInputError, match=re.escape(
            f"raise the eye by at least float64's spacing of numbers at this distance, {spacing} m (an eye closer "
            "above the surface rounds onto it)") + "$"):
        globe.mesh(camera=look_from(10.0, 20.0, altitude, radius=radius))
    assert float(spacing) * (1 - 1e-5) < np.spacing(radius) <= float(spacing)  # as printed, not below it
    assert len(globe.mesh(camera=look_from(10.0, 20.0, float(spacing), radius=radius), cull=False).faces) > 0
    earth = Globe.from_latlon(np.zeros((18, 36)), lat, lon, face_size=3, device="cpu")
    with pytest.raises(InvalidInputError, match=r"terrain \+0.0 m\); raise the eye$"):  # no word of float64 there
        earth.mesh(camera=look_from(10.0, 20.0, -1000.0))


def test_the_cli_refuses_an_eye_altitude_below_float64_s_resolution_naming_radius(tmp_path, capsys):
    out = tmp_path / "g.glb"
    assert main(["-q", "globe", "--face-size", "9", "--radius", "1e20", "--eye", "0,0,1000", "-o", str(out)]) == 2
    assert capsys.readouterr().err == (
        "stepterrain globe: error: --eye altitude must be resolved against --radius in float64 (|altitude| at least "
        "16384 m at this radius, or a radius below 4.61168e+18 m for this altitude); got altitude 1000 m, --radius "
        "1e+20 m\n")
    assert not out.exists()
    assert main(["-q", "globe", "--face-size", "9", "--radius", "1e20", "--eye", "0,0,1e6", "-o", str(out),
                 "--device", "cpu"]) == 0
    assert out.exists()
