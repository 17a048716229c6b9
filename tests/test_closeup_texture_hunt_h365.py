"""Bug hunt h365 on close-ups and texture layers: each test failed before its fix."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain import cli
from stepterrain.closeup import ROI, CloseUp, render_closeups
from stepterrain.errors import InvalidInputError
from stepterrain.texture import Pipeline, TextureLayer, adjust
from stepterrain.texture_lod import pyramid_shapes

from .conftest import needs_render

rng = np.random.default_rng(365)


@pytest.mark.parametrize("split, position", [("left", 0.5), ("right", 0.5), ("left", 0.3), ("right", 0.8)])
def test_adjust_split_on_a_mirrored_texture_is_by_world_x(device, split, position):
    """adjust's split counted "left" in image columns: on a texture whose matrix mirrors x (column 0 in the east)
    split="left" kept the east side. The same picture given mirrored (image flipped, matrix flipped) must split
    alike, and "left" keeps the pixels whose centres lie west of xmin + position * width."""
    image = rng.random((3, 5, 3)).astype(np.float32)
    extent = (10.0, 15.0, 0.0, 3.0)
    plain = TextureLayer("thematic", image, extent)
    # world -> texel: column = 14.5 - x (texel centres at integers), row = 2.5 - y as plain's
    mirror = np.array([[-1.0, 0.0, 14.5], [0.0, -1.0, 2.5], [0.0, 0.0, 1.0]])
    mirrored = TextureLayer("thematic", image[:, ::-1].copy(), extent, matrix=mirror)
    a = adjust(plain, split=split, split_position=position, device=device).rgba()
    b = adjust(mirrored, split=split, split_position=position, device=device).rgba()
    np.testing.assert_array_equal(b[:, ::-1], a)  # b's columns run east to west
    centres = 10.0 + np.arange(5) + 0.5  # world x of plain's columns
    west = centres < 10.0 + position * 5.0
    kept = west if split == "left" else ~west
    np.testing.assert_array_equal(a[..., 3], np.broadcast_to(kept, (3, 5)).astype(np.float32))


@pytest.mark.parametrize("height, width, name, got", [(0, 5, "height", "0"), (4, -1, "width", "-1"),
                                                       (2.5, 3, "height", "2.5"), (3, True, "width", "True")])
def test_pyramid_shapes_refuses_sizes_that_never_reach_one(height, width, name, got):
    """pyramid_shapes(0, 5) halved 0 to 0 for ever, its list growing until memory ran out; 2.5 was cut to 2."""
    with pytest.raises(InvalidInputError, match=rf"^{name} must be a whole number of pixels >= 1; got {got}$"):
        pyramid_shapes(height, width)


def test_pyramid_shapes_of_whole_sizes():
    assert pyramid_shapes(np.int64(5), 8) == [(5, 8), (3, 4), (2, 2), (1, 1)]
    assert pyramid_shapes(1, 1) == [(1, 1)]


@needs_render
def test_a_closeup_framed_too_large_by_its_scale_is_told_to_scale_down():
    """_check_framed blamed the offset of whatever close-up reached farthest: a close-up scaled 1e6 times with an
    offset of 0 was told to "move it nearer" (the CLI: "give it a smaller --offset"), which changes nothing. It now
    names the scale when the close-up's own size, not its offset, takes it that far; an absurd offset still names
    the offset."""
    heights = np.add.outer(np.linspace(0.0, 4.0, 24), np.linspace(0.0, 3.0, 28)).astype(np.float32)
    roi = ROI.circle((14.0, 12.0), 4.0)
    with pytest.raises(InvalidInputError, match=r"because closeups\[0\] \(scale \(1000000\.0, 1000000\.0, "
                                                r"1000000\.0\)\) is drawn .* across, reaching .*; scale it down, or "
                                                r"frame what to see with bounds$"):
        render_closeups(heights, [CloseUp(roi, scale=1e6)], window_size=(96, 72), device="cpu")
    with pytest.raises(InvalidInputError, match=r"because closeups\[0\] \(offset \(0\.0, 0\.0, 1000000000\.0\)\) "
                                                r"is drawn .*; move it nearer, or frame what to see with bounds$"):
        render_closeups(heights, [CloseUp(roi, offset=(0, 0, 1e9))], window_size=(96, 72), device="cpu")


def test_closeup_scale_named_in_the_clis_terms():
    """The scale's refusal read as the CLI's: the close-up's number, its --scale and the advice to give a smaller one
    (the library's "(scale (1000000.0, ...))" and "frame what to see with bounds" name no option)."""
    message = ("the camera fitted to the overview and its close-ups would show the overview (0.0011 px) under a pixel: "
               "the framed box x [0, 1], y [0, 1], z [0, 1e+07] is that large because closeups[0] (scale (1000000.0, "
               "1000000.0, 1000000.0)) is drawn 6.7e+06 across, reaching 1e+07 from the terrain's centre; scale it "
               "down, or frame what to see with bounds")
    text = cli._as_option(message, cli._subcommand(cli.build_parser(), "closeup"))
    assert "closeups[" not in text and "bounds" not in text, text
    assert "because close-up 1 (--scale 1e+06,1e+06,1e+06) is drawn" in text, text
    assert text.endswith("scale it down: give it a smaller --scale"), text


def test_pipeline_modulate_without_a_layer_is_refused_when_built():
    """Pipeline().modulate() was taken, and apply() then failed with modulate's "needs at least two layers", of a
    pipeline that supplies the current layer itself."""
    with pytest.raises(InvalidInputError, match=r"^Pipeline.modulate needs at least one layer to modulate the "
                                                r"current one by; got none$"):
        Pipeline().modulate()
    base = TextureLayer("thematic", np.full((1, 1, 3), 0.5), (0, 1, 0, 1))
    out = Pipeline().modulate(np.full((1, 1), 0.5)).apply(base, device="cpu").rgba()
    assert out[0, 0].tolist() == [0.25, 0.25, 0.25, 1.0]
