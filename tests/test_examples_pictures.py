"""The pictures in docs/ as a reader sees them: found by looking at each one beside the text that shows it."""

from __future__ import annotations

import numpy as np
import pytest

from .conftest import needs_render
from .test_examples import assert_usage_error_writing_nothing, load_example

#: small runs of the examples that write their PNG with a palette
PALETTE_RUNS = {
    "textures": ["--size", "24", "--panel", "96", "72", "--device", "cpu"],
    "adaptive_mesh": ["--size", "24", "--errors", "20", "--panel", "96", "72", "--device", "cpu"],
}


def read(path):
    from PIL import Image

    with Image.open(path) as image:
        return image.mode, np.asarray(image.convert("RGB")).astype(np.int16)


@needs_render
@pytest.mark.parametrize("name", sorted(PALETTE_RUNS))
def test_examples_write_their_pictures_with_a_palette(name, tmp_path):
    """docs/texture.png (1.02 MB) and docs/adaptive_mesh.png (0.86 MB) were full-colour PNGs of hillshaded or
    half-toned pixels, every one a little different: heavy pages for a README. Written with a 256-colour palette they
    take 0.32 and 0.26 MB; the picture is the full-colour one but for a few levels, and --colors 0 still writes it
    in full colour, --colors N with at most N colours."""
    example = load_example(name)
    paths = {colors: tmp_path / f"{colors}.png" for colors in ("256", "0", "8")}
    for colors, path in paths.items():
        assert example.main([*PALETTE_RUNS[name], "--colors", colors, "--output", str(path)]) == 0
    (mode, palette), (full_mode, full), (few_mode, few) = (read(paths[c]) for c in ("256", "0", "8"))
    assert (mode, full_mode, few_mode) == ("P", "RGB", "P")
    assert palette.shape == full.shape
    assert len(np.unique(palette.reshape(-1, 3), axis=0)) <= 256
    assert len(np.unique(few.reshape(-1, 3), axis=0)) <= 8
    difference = np.abs(palette - full)
    assert difference.mean() < 3 and np.percentile(difference, 99) < 24
    assert len(np.unique(full.reshape(-1, 3), axis=0)) > 256  # a picture a palette cannot hold exactly


@pytest.mark.parametrize("name", sorted(PALETTE_RUNS))
@pytest.mark.parametrize("colors", ["1", "257", "-3"])
def test_examples_refuse_a_palette_they_cannot_write(name, colors, tmp_path, capsys):
    argv = [*PALETTE_RUNS[name], "--colors", colors, "--output", str(tmp_path / "x.png")]
    assert_usage_error_writing_nothing(name, argv, f"--colors must be 0 (full colour) or 2 to 256; got {colors}",
                                      tmp_path, capsys)


def test_adaptive_mesh_labels_are_legible():
    """adaptive_mesh's captions were Pillow's default 10 px type on a 400 px panel: small beside the picture. The type
    scales with the panel now, 16 px at 400 px high, and its box holds the whole caption."""
    example = load_example("adaptive_mesh")
    text = "error <= 2.5 m: 311,324 triangles, max 2.25 m"
    image = example.label(np.full((400, 480, 3), 128, np.uint8), text)
    rows, cols = np.nonzero(image.max(axis=2) < 60)
    assert rows.max() - rows.min() >= 12  # the glyphs from ascender to descender
    box = (image == 255).all(axis=2)
    across = slice(cols.min(), cols.max() + 1)
    assert box[rows.min() - 1, across].all() and box[rows.max() + 1, across].all()
    small = example.label(np.full((80, 96, 3), 128, np.uint8), "error <= 0 m")
    assert not (small[17:] != 128).any()  # the caption's box stays in the 17 rows kept for it on a small panel
