"""Fixes from a user-journey hunt on real data: messages a CLI user with a file can act on."""

from __future__ import annotations

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
