"""Fixes from a user-journey hunt on real data: messages a CLI user with a file can act on."""

from __future__ import annotations

import numpy as np
import pytest

from .conftest import run_cli as run
from .test_cli_fixes import _UNTYPED_NUMBERS

#: (subcommand, option): every option of one number, whole or not
_NUMBER_OPTIONS = sorted({(command, option) for command, option, value in _UNTYPED_NUMBERS
                          if value == "1_0" and option not in ("--spacing", "--tile", "--scale")})


@pytest.mark.parametrize(("command", "option"), _NUMBER_OPTIONS)
@pytest.mark.parametrize("value", ["abc", "200,0"])
def test_a_bad_number_is_refused_in_the_house_style(command, option, value, tmp_path, capsys):
    """--interval abc, --face-size abc and closeup's --stepped 200,0 got argparse's stock "invalid float value:
    'abc'", which said neither what was expected nor why 200,0 is no number; they say "expected a number" (or a
    whole number) and the text typed, one line, exit 2, as the options of several numbers do."""
    out = tmp_path / "out"
    code, stdout, err = run(capsys, command, f"{option}={value}", "-o", out / "x.glb" if command != "batch" else out)
    assert code == 2, err
    line = err.strip()
    assert len(line.splitlines()) == 1 and stdout == "" and "Traceback" not in err, err
    assert f"argument {option}: expected a " in line and "number" in line and f"got {value!r}" in line, line
    assert "invalid" not in line, line
    if "," in value and ("a number;" in line or "a whole number;" in line):  # not --spin's own message
        assert "decimal point" in line, line
    assert not out.exists()


@pytest.mark.parametrize(("lat", "lon", "covers"), [
    (np.linspace(40.5, 39.5, 5), np.linspace(-106.0, -105.0, 6), "covers 1.2 degrees of longitude (-106 to -105)"),
    (np.linspace(40.0, -40.0, 5), np.arange(0.0, 360.0, 60.0), "covers 360 degrees of longitude (0 to 300)"),
])
def test_globe_of_a_regional_grid_names_the_file_and_what_it_covers(lat, lon, covers, tmp_path, capsys):
    """`stepterrain globe front_range.tif` said "lon must cover 360 degrees (W · step = 360)": lon is a Python
    argument a CLI user never gave. The refusal names INPUT, what globe needs and what the file covers."""
    src = tmp_path / "region.npz"
    np.savez(src, elevation=np.ones((len(lat), len(lon)), np.float32), lat=lat, lon=lon)
    code, stdout, err = run(capsys, "-q", "globe", src, "--face-size", "5", "-o", tmp_path / "g.ply")
    assert code == 2, err
    line = err.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in err, err
    assert f"INPUT {str(src)!r} is no global grid" in line and "360 degrees of longitude" in line, line
    assert covers in line and f"latitudes {lat.min():.6g} to {lat.max():.6g}" in line, line
    assert "lon must" not in line and "lat must" not in line, line
    assert not (tmp_path / "g.ply").exists()
