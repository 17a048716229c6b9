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


def caption(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the dark text pixels in ``image``'s top left corner, the label's place."""
    corner = image[: image.shape[0] // 10, : image.shape[1] // 2]
    return np.nonzero(corner.max(axis=2) < 90)


@needs_render
def test_stepped_terrain_names_its_panels(tmp_path):
    """docs/stepped_panels.png showed three panels with no names: the continuous and stepped ones could be told
    apart, but nothing said which was the lens view, nor that its lens was the smooth circle in the middle. Each
    panel names itself now, in type scaled to the panel (16 px at 480 px high); a tiny panel has no label to hide
    it."""
    example = load_example("stepped_terrain")
    out = tmp_path / "s.png"
    assert example.main(["--size", "32", "--panel", "320", "240", "--output", str(out), "--device", "cpu"]) == 0
    _, image = read(out)
    panels = np.split(image, 3, axis=1)
    spans = []
    for panel in panels:
        rows, cols = caption(panel)
        assert len(rows) > 30, "no label in the panel's corner"
        spans.append(cols.max() - cols.min())
    assert spans[2] > 1.5 * spans[0]  # the lens panel's label says what the lens is, at more length
    tiny = tmp_path / "t.png"
    assert example.main(["--size", "16", "--panel", "64", "48", "--output", str(tiny), "--device", "cpu"]) == 0
    plain = example.label(np.full((48, 64, 3), 200, np.uint8), "stepped (gamma 1)")
    assert (plain == 200).all()


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


def swatches(image: np.ndarray) -> list[tuple[int, int, int]]:
    """The PALETTE colours found in ``image``'s top band, in the order their leftmost pixels come, left to right."""
    from PIL import ImageColor

    from stepterrain.closeup import PALETTE

    band = image[: image.shape[0] // 12]
    found = []
    for name in PALETTE:
        colour = ImageColor.getrgb(name)
        cols = np.nonzero((band == colour).all(axis=2).any(axis=0))[0]
        if len(cols) >= band.shape[0] // 4:  # a square swatch, not a stray pixel of a fence
            found.append((cols.min(), colour))
    return [colour for _, colour in sorted(found)]


def test_closeup_anchors_legend_names_each_anchor_style():
    """docs/closeup_anchors.png drew four close-ups with fences in four colours and four transfer functions, and
    nothing in the picture said which was which. A legend along the top names them by colour, left to right as the
    close-ups stand; with --inactive it names the depictions (their fences are hidden, gray or faint: no colour
    swatches to match); an image under 240 px high gets none."""
    from PIL import ImageColor

    from stepterrain.closeup import PALETTE

    example = load_example("closeup_anchors")
    blank = np.full((360, 640, 3), 255, np.uint8)
    image = example.legend(blank)
    assert swatches(image) == [ImageColor.getrgb(name) for name in PALETTE[:4]]
    text = (image[:40].max(axis=2) < 60).sum(axis=0) > 0
    assert text.sum() > 150  # the title and the four names
    inactive = example.legend(blank, inactive=True)
    assert swatches(inactive) == [] and (inactive[:40].max(axis=2) < 60).any(axis=0).sum() > 150
    assert not (inactive[40:] != 255).any() and not (image[40:] != 255).any()  # the terrain's place untouched
    assert (example.legend(blank[:239]) == 255).all()


@needs_render
def test_closeup_anchors_picture_has_its_legend(tmp_path):
    from PIL import ImageColor

    from stepterrain.closeup import PALETTE

    example = load_example("closeup_anchors")
    out = tmp_path / "a.png"
    assert example.main(["--window", "384", "240", "--device", "cpu", "--output", str(out)]) == 0
    _, image = read(out)
    assert swatches(image.astype(np.uint8)) == [ImageColor.getrgb(name) for name in PALETTE[:4]]


def test_flood_gif_frames_share_one_palette(tmp_path):
    """flood.py handed its full-colour frames to the GIF writer, which gave each its own palette: docs/flood.gif took
    1.09 MB for 24 frames of 256 x 256 (nothing carried from frame to frame) and the dry summits of the early frames
    showed flat blotches where a frame's palette ran short. The frames now share one palette of 256 colours (0.21
    MB); the GIF's last frame is the PNG's (full colour, as before) within a few levels."""
    import imageio.v3 as iio

    example = load_example("flood")
    out = tmp_path / "flood.png"
    assert example.main(["--size", "64", "--frames", "6", "--keyframes", "3", "--device", "cpu",
                         "--output", str(out)]) == 0
    frames = iio.imread(out.with_suffix(".gif"), index=None)[..., :3].astype(np.int16)
    assert len(np.unique(frames.reshape(-1, 3), axis=0)) <= 256
    _, last = read(out)
    assert frames.shape[1:] == last.shape
    difference = np.abs(frames[-1] - last)
    assert difference.mean() < 3 and np.percentile(difference, 99) < 24


def test_closeup_mappings_legend_names_both_close_ups():
    """docs/closeup.png (the README's top row) showed a red and a blue fence and a purple patch, and did not say that
    one close-up was the terrain stepped and the other its slope seen as a billboard. A legend along the top names
    both by their anchors' colours, the steps' interval with them."""
    from PIL import ImageColor

    import stepterrain as st

    example = load_example("closeup_mappings")
    closeups = example.closeups(st.sample_dem())
    assert [cu.stepped is not None for cu in closeups] == [True, False] and closeups[1].scalars == "slope"
    image = example.legend(np.full((360, 640, 3), 255, np.uint8), closeups)
    found = swatches(image)
    assert found == [ImageColor.getrgb(example.STEPPED_COLOR), ImageColor.getrgb(example.SLOPE_COLOR)]
    assert np.allclose(closeups[0].color, np.divide(found[0], 255), atol=0.01)
    assert np.allclose(closeups[1].color, np.divide(found[1], 255), atol=0.01)
    assert (image[:40].max(axis=2) < 60).any(axis=0).sum() > 200 and not (image[40:] != 255).any()


def test_textures_panels_are_labelled_above_the_texture(monkeypatch, tmp_path):
    """docs/texture.png's two panels did not say that the left one is the texture itself, seen from above, and the
    right one the terrain it is draped on. Each panel names itself now; the texture is letterboxed below the label's
    strip, so the label covers none of it, and keeps its proportions."""
    example = load_example("textures")
    monkeypatch.setattr(example, "render_textured_mesh", lambda mesh, window_size, **kw: np.full(
        (window_size[1], window_size[0], 3), 255, np.uint8))  # the draped view is not this test's: no render
    out = tmp_path / "t.png"
    width, height = 320, 240
    assert example.main(["--size", "32", "--panel", str(width), str(height), "--device", "cpu", "--colors", "0",
                         "--output", str(out)]) == 0
    _, image = read(out)
    band = example.label_band(height)
    assert band == 16
    texture, view = image[:, :width], image[:, width:]
    for panel in (texture, view):
        assert (panel[:band].max(axis=2) < 60).sum() > 30  # the label's text
    drawn = (texture[band:] < 250).any(axis=2)  # the texture, below the strip
    rows, cols = np.nonzero(drawn)
    assert rows.min() == 0 and rows.max() == height - band - 1  # it fills the room left, no more
    xmin, xmax, ymin, ymax = example.crop_sample(32).extent
    assert (cols.max() - cols.min() + 1) / (height - band) == pytest.approx((xmax - xmin) / (ymax - ymin), abs=0.03)
    left, right = cols.min(), cols.max()
    assert (texture[:band, left:right + 1] >= 250).all(axis=2).mean() > 0.5  # the strip above it mostly blank
    assert (example.label(np.zeros((239, 300, 3), np.uint8), "x") == 0).all()  # a small panel: no label


def test_globe_labels_are_legible():
    """globe.py's captions were Pillow's default 10 px type on 640 x 400 panels (docs/globe.png, the README's top
    row): small beside the picture. The type scales with the panel now, 16 px at 400 px high, white on a black box
    that holds the whole caption; 11 px at least."""
    example = load_example("globe")
    text = "close view (clipped), spheres: 2,202 triangles"
    image = example.label(np.full((400, 640, 3), 128, np.uint8), text)
    rows, cols = np.nonzero(image.min(axis=2) > 200)
    assert rows.max() - rows.min() >= 12  # the glyphs from ascender to descender
    box = (image == 0).all(axis=2)
    across = slice(cols.min(), cols.max() + 1)
    assert box[rows.min() - 1, across].all() and box[rows.max() + 1, across].all()
    small = example.label(np.full((48, 64, 3), 128, np.uint8), "far view")
    rows = np.nonzero((small != 128).any(axis=(1, 2)))[0]
    assert 0 < rows.max() < 20


@pytest.mark.parametrize("width, height", [(640, 720), (800, 720), (1024, 720), (1280, 720), (1600, 900), (400, 300)])
def test_closeup_mappings_legend_fits_the_window(width, height):
    """The legend ran in one row in type a thirtieth of the height: 1155 px at 720 px high, cut off mid-name in a
    window under that wide (``--window 800 720``). Its type shrinks to fit the widest entry and entries wrap onto
    more rows: at any width every swatch is whole and every word inside the image, a margin clear on the right, and
    the legend stays in the top band (the terrain's place below it untouched)."""
    from PIL import ImageColor

    import stepterrain as st

    example = load_example("closeup_mappings")
    closeups = example.closeups(st.sample_dem())
    image = example.legend(np.full((height, width, 3), 255, np.uint8), closeups)
    ink = (image != 255).any(axis=2)
    rows, cols = np.nonzero(ink)
    margin = min(height // 30, 12)
    assert cols.min() >= margin and cols.max() < width - margin, (cols.min(), cols.max())
    assert rows.max() < height // 6 and not ink[height // 6:].any()
    def text_per_type(picture):  # the black text's pixels over the type's size squared (a swatch is one type high)
        r, c = np.nonzero((picture == ImageColor.getrgb(example.STEPPED_COLOR)).all(axis=2))
        return (picture.max(axis=2) < 100).sum() / (r.max() - r.min() + 1) ** 2

    for colour in (example.STEPPED_COLOR, example.SLOPE_COLOR):  # each swatch a whole square, not cut at the edge
        r, c = np.nonzero((image == ImageColor.getrgb(colour)).all(axis=2))
        assert len(r) > 0 and len(r) == (r.max() - r.min() + 1) * (c.max() - c.min() + 1)
        assert r.max() - r.min() == c.max() - c.min() >= min(height // 30, 12) - 1  # legible, 10 px and up
    # every word drawn: as much text for its type as in one row of a window wide enough for it
    wide = example.legend(np.full((height, 4000, 3), 255, np.uint8), closeups)
    assert text_per_type(image) == pytest.approx(text_per_type(wide), rel=0.15)
