"""Regression tests of the texture module's bug hunt (fixes-texture): each fails before its fix."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain.texture import (
    TextureLayer,
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
