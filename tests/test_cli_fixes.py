"""Command-line and example fixes found by a bug hunt of the CLI as a batch-scripting GIS user runs it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stepterrain import cli


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def tile_folder(folder: Path, broken: bool = False) -> Path:
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):
        np.save(folder / f"t{k}.npy", (rng.random((12, 14)) * 100).astype(np.float32))
    if broken:
        (folder / "broken.npy").write_bytes(b"junk")
    return folder


def test_batch_failures_go_to_stderr_not_stdout(tmp_path, capsys):
    """tqdm's ``write`` defaults to stdout: a failed item's line landed in the user's piped stdout."""
    src = tile_folder(tmp_path / "tiles", broken=True)
    code, out, err = run(capsys, "batch", src, "--interval", "10", "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 1
    assert out == ""
    assert "broken" in err


def test_batch_png_in_the_input_folder_is_refused_before_any_work(tmp_path, capsys):
    """The overview written into a folder of tiles was read as a tile by the next (resuming) run, which then
    failed on it (exit 1) every time."""
    src = tile_folder(tmp_path / "tiles")
    argv = ["batch", src, "--interval", "10", "--scheduler", "serial", "-o", tmp_path / "out",
            "--png", src / "overview.png", "--size", "64x48"]
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert "--png" in err and "INPUT folder" in err and "Traceback" not in err
    assert sorted(p.name for p in src.iterdir()) == ["t0.npy", "t1.npy"]
    assert not (tmp_path / "out").exists()
