"""Regression tests of the texture module's bug hunt (fixes-texture): each fails before its fix."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain.errors import InvalidInputError, StepTerrainError
from stepterrain.texture import (
    TextureLayer,
    adjust,
    combine,
    highlight_lens,
    hillshade,
    terrain_layer,
    topographic_layer,
)


# ------------------------------------------------------------------------------------------ cached RGBA
def test_a_layers_cached_rgba_cannot_be_changed_through_the_returned_array():
    """The RGBA of a layer over a read-only image is cached and handed out again (and wrapped for the kernels):
    it came back writeable, so a caller's in-place edit of one result changed every later rgba() and blend."""
    image = np.full((2, 3), 0.5, np.float32)
    image.setflags(write=False)
    layer = TextureLayer("luminance", image, (0, 3, 0, 2))
    first = layer.rgba()
    with pytest.raises(ValueError):
        first[...] = 0.0
    np.testing.assert_array_equal(layer.rgba()[..., 0], 0.5)


# ------------------------------------------------------------------------------------------ choices
@pytest.mark.parametrize("call", [
    lambda bad: hillshade(np.zeros((3, 3)), method=bad, device="cpu"),
    lambda bad: topographic_layer(np.zeros((3, 3)), method=bad, device="cpu"),
    lambda bad: adjust(TextureLayer("luminance", np.ones((2, 2)), (0, 1, 0, 1)), split=bad, device="cpu"),
    lambda bad: combine(TextureLayer("luminance", np.ones((2, 2)), (0, 1, 0, 1)), np.ones((2, 2)), bad,
                        device="cpu"),
    lambda bad: TextureLayer("luminance", np.ones((2, 2)), (0, 1, 0, 1), border=bad),
    lambda bad: TextureLayer(bad, np.ones((2, 2)), (0, 1, 0, 1)),
    lambda bad: terrain_layer(np.zeros((2, 2)), np.ones((2, 2)), bad),
], ids=["hillshade method", "topographic method", "adjust split", "combine mode", "layer border", "layer kind",
        "terrain_layer kind"])
def test_a_named_choice_given_as_an_array_is_an_input_error(call):
    """A choice by name (method, split, mode, border, kind) given as a numpy array was compared with the names
    and failed with numpy's "truth value of an array is ambiguous" ValueError."""
    with pytest.raises(InvalidInputError):
        call(np.array(["standard", "left"]))


# ------------------------------------------------------------------------------------------ overflow
def test_a_colour_beyond_float64_is_an_input_error():
    """An integer colour component beyond float64 (10**400) escaped as OverflowError."""
    with pytest.raises(InvalidInputError, match="shadow_color"):
        hillshade(np.zeros((3, 3)), method="maplibre-multidirectional", shadow_color=[10**400, 0, 0], device="cpu")


def test_a_lens_resolution_beyond_float64_is_refused():
    """A lens resolution whose image size is beyond float64 escaped as OverflowError from the budget message."""
    with pytest.raises(StepTerrainError, match="resolution"):
        highlight_lens((0.0, 0.0), 1.0, resolution=10**400)
