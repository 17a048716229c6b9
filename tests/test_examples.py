"""Each script in examples/ runs headless at a tiny size and writes what it promises."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from stepterrain import render

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
AVAILABLE, REASON = render.offscreen_available()
pytestmark = [pytest.mark.render,
              pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")]


def load_example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def assert_usage_error_writing_nothing(name: str, argv: list[str], message: str, folder: Path, capsys) -> None:
    """Example ``name`` run with ``argv`` ends as an argparse error (exit 2, ``message`` on stderr, no traceback)
    and ``folder`` stays empty."""
    example = load_example(name)
    with pytest.raises(SystemExit) as exit_info:
        example.main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "error: " in err and message in err and "Traceback" not in err
    assert list(folder.iterdir()) == []


def read_png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image)


def test_stepped_terrain(tmp_path):
    example = load_example("stepped_terrain")
    assert example.__doc__ and "side by side" in example.__doc__
    out = tmp_path / "stepped.png"
    argv = ["--size", "32", "--panel", "160", "120", "--output", str(out), "--device", "cpu"]
    assert example.main(argv) == 0
    image = read_png(out)
    assert image.shape[:2] == (120, 3 * 160)
    panels = np.split(image[..., :3].astype(int), 3, axis=1)
    assert all(p.std() > 5 for p in panels)
    assert np.abs(panels[0] - panels[1]).mean() > 1, "continuous and stepped panels look the same"


def test_dynamic_peaks(tmp_path):
    import imageio.v3 as iio

    example = load_example("dynamic_peaks")
    assert example.__doc__ and "emerge" in example.__doc__
    out = tmp_path / "peaks.png"
    argv = ["--size", "32", "--frames", "3", "--window", "120", "96", "--output", str(out), "--device", "cpu"]
    assert example.main(argv) == 0
    frames = iio.imread(out.with_suffix(".gif"), index=None)
    assert frames.shape[0] == 3 and frames.shape[1:3] == (96, 120)
    assert read_png(out).shape[:2] == (96, 120)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["peaks.gif", "peaks.png"]


def test_moving_peaks_emerge_and_collapse():
    example = load_example("dynamic_peaks")
    frames = example.moving_peaks(24, 8)
    assert frames.shape == (8, 24, 24) and frames.dtype == np.float32
    assert frames.min() == 0.0 and frames.max() == pytest.approx(1.0)
    peak_heights = frames.reshape(8, -1).max(axis=1)
    assert np.ptp(peak_heights) > 0.2  # peaks rise and fall over the series
