"""The README's "Python and command-line defaults" table checked against the code: each row's Python default
against the function's signature, and its CLI default against the value the command really passes to that
function (a spy in its place, run through ``cli.main``), so the table cannot go stale."""

from __future__ import annotations

import ast
import inspect
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

import stepterrain
from stepterrain import render
from stepterrain.errors import MissingDependencyError

from .conftest import run_cli as run

README = Path(__file__).resolve().parent.parent / "README.md"
HEADING = "### Python and command-line defaults"


class Seen(MissingDependencyError):
    """Raised by a spy once it has recorded its call: the command stops there with exit status 2."""


def table_rows() -> dict[tuple[str, str], list[str]]:
    """(command, Python column) -> the row's six cells, from the README's table under HEADING."""
    text = README.read_text(encoding="utf-8")
    assert text.count(HEADING) == 1, f"README has no single {HEADING!r} section"
    section = text.split(HEADING, 1)[1].split("\n#", 1)[0]
    rows = {}
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        assert len(cells) == 6, line
        key = (cells[0].strip("`"), cells[1].strip("`"))
        assert key not in rows, f"row {key} twice"
        rows[key] = cells
    return rows


def first_code(cell: str) -> str:
    """The first `...` span of a cell."""
    match = re.search(r"`([^`]*)`", cell)
    assert match, cell
    return match.group(1)


def python_callable(name: str):
    from stepterrain import batch as batch_module
    from stepterrain import closeup, globe, texture

    return {
        "stepped": stepterrain.stepped,
        "render_mesh": render.render_mesh,
        "render_textured_mesh": render.render_textured_mesh,
        "CloseUp": closeup.CloseUp,
        "render_closeups": closeup.render_closeups,
        "animate_closeups": closeup.animate_closeups,
        "topographic_layer": texture.topographic_layer,
        "Globe.mesh": globe.Globe.mesh,
        "look_from": globe.look_from,
        "batch": sys.modules[batch_module.__name__].batch,
    }[name]


def spy(record: dict, name: str, real=None):
    """A stand-in recording its arguments under ``name``; it calls ``real`` when given, else stops the command."""

    def stand_in(*args, **kwargs):
        record[name] = (args, kwargs)
        if real is not None:
            return real(*args, **kwargs)
        raise Seen(f"{name} called (test spy)")

    return stand_in


@pytest.fixture
def offscreen(monkeypatch):
    monkeypatch.setattr(render, "require_offscreen", lambda: "simulated")


def cli_steps(dem, tmp_path, capsys, monkeypatch) -> dict:
    record: dict = {}
    monkeypatch.setattr(stepterrain, "stepped", spy(record, "stepped", stepterrain.stepped))
    monkeypatch.setattr(render, "render_mesh", spy(record, "render_mesh"))
    code, _, err = run(capsys, "steps", dem, "--png", tmp_path / "a.png")
    assert code == 2 and "test spy" in err, err
    return record


def cli_closeup(dem, tmp_path, capsys, monkeypatch, *outputs) -> dict:
    from stepterrain import closeup

    record: dict = {}
    monkeypatch.setattr(closeup, "render_closeups", spy(record, "render_closeups"))
    monkeypatch.setattr(closeup, "animate_closeups", spy(record, "animate_closeups"))
    code, _, err = run(capsys, "closeup", dem, *outputs)
    assert code == 2 and "test spy" in err, err
    return record


def cli_texture(dem, tmp_path, capsys, monkeypatch, *outputs) -> dict:
    from stepterrain import texture

    record: dict = {}
    monkeypatch.setattr(texture, "topographic_layer", spy(record, "topographic_layer", texture.topographic_layer))
    monkeypatch.setattr(render, "render_textured_mesh", spy(record, "render_textured_mesh"))
    code, _, err = run(capsys, "texture", dem, *outputs)
    # stopped at the render's spy with --png; without it the texture is written
    assert (code, "test spy" in err) == ((2, True) if "render_textured_mesh" in record else (0, False)), err
    return record


class FakeGlobe:
    """Globe.from_latlon's stand-in: the command's eye checks pass, and its mesh call is recorded."""

    def __init__(self, record, radius):
        self.record, self.radius, self.heights, self.device = record, radius, np.zeros(1), "cpu"

    def _check_eye(self, eye):
        pass

    def mesh(self, **kwargs):
        self.record["Globe.mesh"] = ((), kwargs)
        raise Seen("Globe.mesh called (test spy)")


def cli_globe(tmp_path, capsys, monkeypatch) -> dict:
    from stepterrain import globe

    record: dict = {}
    monkeypatch.setattr(globe.Globe, "from_latlon",
                        classmethod(lambda cls, *a, radius, **k: FakeGlobe(record, radius)))
    monkeypatch.setattr(globe, "look_from", spy(record, "look_from", globe.look_from))
    code, _, err = run(capsys, "globe", "-o", tmp_path / "g.glb")
    assert code == 2 and "test spy" in err, err
    return record


def cli_batch(tmp_path, capsys, monkeypatch, *options) -> dict:
    from stepterrain import batch as batch_module

    record: dict = {}
    monkeypatch.setattr(sys.modules[batch_module.__name__], "batch", spy(record, "batch"))
    code, _, err = run(capsys, "batch", "-o", tmp_path / "out", *options)
    assert code == 2 and "test spy" in err, err
    return record


#: (command, Python column) -> (the CLI's effective default as the command passes it, given the recorded calls),
#: for the rows whose CLI default cell is a literal; the descriptive rows are checked in their own tests below.
def literal_cli_defaults(dem, tmp_path, capsys, monkeypatch) -> dict[tuple[str, str], object]:
    steps = cli_steps(dem, tmp_path, capsys, monkeypatch)
    still = cli_closeup(dem, tmp_path, capsys, monkeypatch, "-o", tmp_path / "c.png")
    anim = cli_closeup(dem, tmp_path, capsys, monkeypatch, "--gif", tmp_path / "c.gif")
    texture = cli_texture(dem, tmp_path, capsys, monkeypatch, "-o", tmp_path / "t.png")
    shot = cli_texture(dem, tmp_path, capsys, monkeypatch, "--png", tmp_path / "t.png")
    globe = cli_globe(tmp_path, capsys, monkeypatch)
    batch = cli_batch(tmp_path, capsys, monkeypatch)
    (closeup,) = still["render_closeups"][0][1]
    scale = closeup.scale
    assert np.ndim(scale) == 0 or len(set(np.ravel(scale))) == 1, scale
    return {
        ("steps", "render_mesh(z_scale=)"): steps["render_mesh"][1]["z_scale"],
        ("closeup", "CloseUp(scale=)"): float(np.ravel(scale)[0]),
        ("closeup", "CloseUp(spin=)"): still["render_closeups"][0][1][0].spin[0],
        ("closeup", "render_closeups(z_scale=)"): still["render_closeups"][1]["z_scale"],
        ("closeup", "animate_closeups(window_size=)"): tuple(anim["animate_closeups"][1]["window_size"]),
        ("texture", "topographic_layer(shadows=)"): texture["topographic_layer"][1]["shadows"],
        ("texture", "render_textured_mesh(z_scale=)"): shot["render_textured_mesh"][1]["z_scale"],
        ("globe", "Globe.mesh(error=)"): globe["Globe.mesh"][1]["error"],
        ("batch", "batch(colors=)"): batch["batch"][1]["colors"],
        ("batch", "batch(tile_size=)"): batch["batch"][1]["tile_size"],
    }


def test_every_python_default_in_the_table_is_the_signatures():
    rows = table_rows()
    assert rows, "the defaults table has no rows"
    for (command, column), cells in rows.items():
        name, param = re.fullmatch(r"([\w.]+)\((\w+)=\)", column).groups()
        default = inspect.signature(python_callable(name)).parameters[param].default
        if cells[2] == "required":
            assert default is inspect.Parameter.empty, (command, column, default)
        else:
            assert ast.literal_eval(first_code(cells[2])) == default, (command, column, cells[2], default)


def test_every_literal_cli_default_in_the_table_is_what_the_command_passes(dem, tmp_path, capsys, monkeypatch,
                                                                            offscreen):
    rows = table_rows()
    effective = literal_cli_defaults(dem, tmp_path, capsys, monkeypatch)
    descriptive = {("steps", "stepped(interval=)"), ("steps", "stepped(colors=)"), ("closeup", "CloseUp(roi=)"),
                   ("closeup", "CloseUp(offset=)"), ("texture", "render_textured_mesh(lighting=)"),
                   ("globe", "look_from(altitude=)"), ("batch", "batch(progress=)")}
    assert set(rows) == set(effective) | descriptive  # no row unchecked, no checked difference left out
    for key, value in effective.items():
        assert ast.literal_eval(first_code(rows[key][4])) == value, (key, rows[key][4], value)
        # and the difference is real: the Python default is another value
        assert ast.literal_eval(first_code(rows[key][2])) != value, key
    # --colormap's default as steps passes it: the colours of stepped(colors="terrain")
    assert ast.literal_eval(first_code(rows["batch", "batch(colors=)"][4])) == "terrain"


def test_the_descriptive_cli_defaults_in_the_table(dem, tmp_path, capsys, monkeypatch, offscreen):
    from stepterrain.stepped import colormap_samples

    rows = table_rows()
    # steps: an interval chosen (~15 steps) and the 'terrain' colours, as stepped(colors="terrain") samples them
    steps = cli_steps(dem, tmp_path, capsys, monkeypatch)["stepped"][1]
    assert steps["interval"] is not None and steps["levels"] is None
    assert "about 15 steps" in rows["steps", "stepped(interval=)"][4]
    levels = stepterrain.isovalues(stepterrain.load_dem(dem).height_range, interval=steps["interval"])
    assert 8 <= len(levels) <= 25
    assert ast.literal_eval(first_code(rows["steps", "stepped(colors=)"][4])) == "terrain"
    np.testing.assert_array_equal(steps["colors"], colormap_samples("terrain", len(levels)))

    # closeup: the default ROI and lift
    terrain = stepterrain.load_dem(dem)
    xmin, xmax, ymin, ymax = terrain.extent
    (closeup,) = cli_closeup(dem, tmp_path, capsys, monkeypatch, "-o", tmp_path / "c.png")["render_closeups"][0][1]
    np.testing.assert_allclose(closeup.roi.center, ((xmin + xmax) / 2, (ymin + ymax) / 2))
    np.testing.assert_allclose(np.ravel(closeup.roi.size), 2 * 0.12 * min(xmax - xmin, ymax - ymin))
    assert "radius 0.12 of its shorter side" in rows["closeup", "CloseUp(roi=)"][4]
    lift = max(0.2 * max(xmax - xmin, ymax - ymin), 0.3 * (ymax - ymin))
    np.testing.assert_allclose(closeup.offset, (0.0, 0.0, lift))
    assert "max(0.2 × the extent's longer side, 0.3 × its north-south depth)" in rows["closeup", "CloseUp(offset=)"][4]

    # texture --lighting auto: unlit on the hillshaded heightfield (True in Python), relief on the stepped terrain
    # under the hillshade (lit fully, shaded twice), lit on it without one
    shot = cli_texture(dem, tmp_path, capsys, monkeypatch, "--png", tmp_path / "t.png")
    assert shot["render_textured_mesh"][1]["lighting"] is False
    stepped_shot = cli_texture(dem, tmp_path, capsys, monkeypatch, "--png", tmp_path / "t.png", "--interval", "2")
    assert stepped_shot["render_textured_mesh"][1]["lighting"] == "relief"
    assert '`"relief"` on the stepped terrain' in rows["texture", "render_textured_mesh(lighting=)"][4]
    plain_shot = cli_texture(dem, tmp_path, capsys, monkeypatch, "--png", tmp_path / "t.png", "--interval", "2",
                             "--hillshade", "none")
    assert plain_shot["render_textured_mesh"][1]["lighting"] is True
    assert first_code(rows["texture", "render_textured_mesh(lighting=)"][4]) == '"auto"'

    # globe --eye: 30N 10E, three radii up
    args, kwargs = cli_globe(tmp_path, capsys, monkeypatch)["look_from"]
    assert args[:3] == (30.0, 10.0, 3 * kwargs["radius"]) and math.isclose(kwargs["radius"], 6_371_000.0)
    assert "latitude 30, longitude 10, altitude 3 × the radius" in rows["globe", "look_from(altitude=)"][4]

    # batch: a progress bar unless -q (Python: none), and no colours for .stl
    assert callable(cli_batch(tmp_path, capsys, monkeypatch)["batch"][1]["progress"])
    assert cli_batch(tmp_path, capsys, monkeypatch, "-q")["batch"][1]["progress"] is False
    assert cli_batch(tmp_path, capsys, monkeypatch, "--format", ".stl")["batch"][1]["colors"] is None
    assert "unless `-q`" in rows["batch", "batch(progress=)"][4]


def test_every_cli_option_in_the_table_states_its_default_in_its_help():
    import argparse

    from stepterrain import cli

    commands = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    for (command, _column), cells in table_rows().items():
        option = first_code(cells[3])
        if option == "-q":  # the progress lines: on unless -q, as its help says
            continue
        (action,) = [a for a in commands[command]._actions if option in a.option_strings]
        assert "default" in action.help, (command, option, action.help)
