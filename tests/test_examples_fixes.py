"""Bugs found by running the examples/ scripts with the arguments a user would try, one test each."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load_example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}_fixes", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_batch_tiles_refuses_an_image_name_it_cannot_write_before_writing_tiles(tmp_path, capsys):
    """--output out.jpg stepped and wrote every tile into out_tiles/, rendered the overview, and only then failed
    (save_image takes PNG or TIFF): a failed command left a folder of tiles behind. Now a usage error, before any
    work."""
    example = load_example("batch_tiles")
    out = tmp_path / "overview.jpg"
    argv = ["--size", "12", "--tile", "4", "--scheduler", "serial", "--output", str(out), "--device", "cpu"]
    with pytest.raises(SystemExit) as exit_info:
        example.main(argv)
    assert exit_info.value.code == 2
    assert "--output must end in .png, .tif, .tiff" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_interactive_refuses_an_image_name_it_cannot_write_before_rendering(tmp_path, monkeypatch, capsys):
    """--output view.jpg built the scene (stepping the DEM four times and rendering) before save_image refused the
    name. Now a usage error before any work; --interactive writes no file, so any name goes there."""
    example = load_example("interactive")
    ran = []
    monkeypatch.setattr(example, "run", lambda args: ran.append(args) or 0)
    with pytest.raises(SystemExit) as exit_info:
        example.main(["--output", str(tmp_path / "view.jpg")])
    assert exit_info.value.code == 2 and ran == []
    assert "--output must end in .png" in capsys.readouterr().err
    assert example.main(["--output", str(tmp_path / "view.jpg"), "--interactive"]) == 0 and len(ran) == 1
    assert example.main(["--output", str(tmp_path / "view.PNG")]) == 0 and len(ran) == 2
