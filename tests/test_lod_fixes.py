"""Regression tests for texture level-of-detail and camera bugs found by an adversarial hunt."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain.camera import Camera
from stepterrain.errors import InvalidInputError
from stepterrain.texture_lod import ImagePyramid, PatchQuadtree, TextureTree, render_with_textures


@pytest.mark.parametrize("fov", [1e-310, 1e-320, 5e-324])
def test_a_field_of_view_too_narrow_for_a_finite_focal_length_is_named(fov):
    """tan(fov / 2) of a subnormal fov made the focal length in pixels inf: the screen-space errors γ and τ came out
    NaN, compared false with the thresholds, and the traversal drew the root at the coarsest texture level."""
    with pytest.raises(InvalidInputError, match=r"Camera fov must be wide enough for a finite focal length .*; got "
                                                 r"fov="):
        Camera((32.0, -60.0, 40.0), (32.0, 32.0, 0.0), fov=fov)


def test_a_narrow_but_finite_field_of_view_refines_to_full_resolution():
    heights = np.random.default_rng(0).normal(0.0, 5.0, (65, 65)).astype(np.float32)
    quadtree = PatchQuadtree(heights, leaf_size=8)
    image = np.random.default_rng(1).integers(0, 256, (256, 256, 3), dtype=np.uint8)
    with ImagePyramid.build(image, extent=quadtree.root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=32)
        camera = Camera((32.0, -60.0, 40.0), (32.0, 32.0, 0.0), fov=1e-300)  # a huge magnification
        items = render_with_textures(quadtree.root, [tree.root], camera)
        assert items and all(item.geometry.is_leaf and item.textures[0].level == 0 for item in items)
