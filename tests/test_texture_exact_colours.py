"""A layer operation that leaves a texel's colour alone returns it bit for bit (straight alpha, paper 004 §3.2.3, §6).

The kernels divided a premultiplied sum by its alpha: ``rgb * a / a`` is ``rgb`` give or take one float32 ulp, so
``blend`` with a transparent (nodata) or zero-weight ``b``, an animation frame at a key's time and a layer sampled
at its own texel centres changed colours by an ulp, and ``to_uint8`` rounded a colour near a half step the other
way (957 of 20 000 such texels): a texture with an empty overlay differed from the texture alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst

import stepterrain.texture as texture_ops
from stepterrain.errors import InvalidInputError
from stepterrain.texture import (
    TextureAnimation,
    TextureLayer,
    adjust,
    blend,
    highlight_lens,
    modulate,
    weighted_add,
)

EXTENT = (0.0, 8.0, 0.0, 5.0)


def _near_half_steps(seed: int, shape: tuple[int, int] = (5, 8)) -> TextureLayer:
    """An RGBA float layer whose colours lie within a few ulps of (k + 0.5) / 255 (uint8's rounding edges), its
    alphas anywhere in (0, 1]."""
    rng = np.random.default_rng(seed)
    k = rng.integers(0, 255, (*shape, 3))
    rgb = ((k + 0.5) / 255).astype(np.float32)
    rgb += rng.integers(-3, 4, rgb.shape).astype(np.float32) * np.spacing(rgb)
    alpha = rng.uniform(0.01, 1.0, (*shape, 1)).astype(np.float32)
    return TextureLayer("thematic", np.concatenate([rgb, alpha], axis=2), EXTENT)


def _assert_same(got: TextureLayer, want: TextureLayer) -> None:
    g, w = got.rgba(), want.rgba()
    np.testing.assert_array_equal(g[..., 3], w[..., 3])
    np.testing.assert_array_equal(g[w[..., 3] > 0], w[w[..., 3] > 0])
    np.testing.assert_array_equal(got.to_uint8(), want.to_uint8())


@settings(max_examples=25, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1))
def test_blend_with_nothing_to_lay_over_leaves_a_bit_for_bit(seed):
    a = _near_half_steps(seed)
    nodata = TextureLayer("thematic", np.full((5, 8, 4), np.nan), EXTENT)
    _assert_same(blend(a, nodata, device="cpu"), a)
    other = _near_half_steps(seed + 1)
    _assert_same(blend(a, other, np.zeros((5, 8)), device="cpu"), a)


@settings(max_examples=25, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1))
def test_blend_over_a_transparent_layer_gives_b_bit_for_bit(seed):
    b = _near_half_steps(seed)
    nodata = TextureLayer("thematic", np.full((5, 8, 4), np.nan), EXTENT)
    _assert_same(blend(nodata, b, device="cpu"), b)


@settings(max_examples=20, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), keys=hst.integers(1, 4), data=hst.data())
def test_animation_frame_at_a_key_time_is_that_key(seed, keys, data):
    layers = [_near_half_steps(seed + k) for k in range(keys)]
    times = np.cumsum(data.draw(hst.lists(hst.floats(0.25, 4.0), min_size=keys, max_size=keys)))
    animation = TextureAnimation(layers, times)
    for k in range(keys):
        _assert_same(animation.frame(float(times[k]), device="cpu"), layers[k])


@settings(max_examples=25, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), shift=hst.tuples(hst.integers(-3, 3), hst.integers(-3, 3)))
def test_sampling_a_layer_at_its_own_texel_centres_keeps_its_colours(seed, shift):
    """A layer over the same texel grid shifted by whole texels (not the grid itself: it is resampled)."""
    picture = _near_half_steps(seed)
    dx, dy = shift
    moved = TextureLayer("thematic", picture.image, (EXTENT[0] + dx, EXTENT[1] + dx, EXTENT[2] + dy, EXTENT[3] + dy))
    base = TextureLayer("thematic", np.full((5, 8, 4), np.nan), EXTENT)
    got = blend(base, moved, device="cpu").rgba()
    rows, cols = np.mgrid[0:5, 0:8]
    r, c = rows + dy, cols - dx  # the moved layer's texel at each pixel (row 0 north)
    inside = (r >= 0) & (r < 5) & (c >= 0) & (c < 8)
    np.testing.assert_array_equal(got[inside], picture.rgba()[r[inside], c[inside]])
    assert (got[~inside][:, 3] == 0).all()


@settings(max_examples=25, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), fu=hst.floats(0.0, 0.99), fv=hst.floats(0.0, 0.99))
def test_a_texel_among_transparent_ones_keeps_its_colour_where_sampled_between_them(seed, fu, fv):
    """Bilinear sampling mixes colours premultiplied: beside transparent texels only the opaque one's colour counts,
    as it is, whatever its weight."""
    picture = _near_half_steps(seed, (3, 3))
    image = np.array(picture.image)
    image[[0, 0, 0, 1, 1, 2, 2, 2], [0, 1, 2, 0, 2, 0, 1, 2]] = np.nan  # the centre texel alone has data
    layer = TextureLayer("thematic", image, (0.0, 3.0, 0.0, 3.0))
    # a one-pixel grid whose centre lies (fu, fv) texels east and south of the centre texel's centre
    x, y = 1.5 + fu, 1.5 - fv
    base = TextureLayer("thematic", np.full((1, 1, 4), np.nan), (x - 0.5, x + 0.5, y - 0.5, y + 0.5))
    got = blend(base, layer, device="cpu").rgba()[0, 0]
    want = layer.rgba()[1, 1]
    np.testing.assert_array_equal(got[:3], want[:3])
    np.testing.assert_allclose(got[3], want[3] * (1 - fu) * (1 - fv), rtol=1e-5, atol=1e-7)


def test_animation_names_the_key_it_refuses_when_a_key_is_shown_twice():
    """Keys A, B, A, C (a cycle back to A, then on): between A's second time and C's the frame blends A and C; a C
    off A's extent is refused as ``layers[3]``. The keys were found by identity, A at its first showing, and the
    refusal named ``layers[1]`` (B, which takes no part)."""
    a = _near_half_steps(1)
    b = _near_half_steps(2)
    far = TextureLayer("thematic", np.array(a.image), (100.0, 108.0, 0.0, 5.0))
    animation = TextureAnimation([a, b, a, far], (0.0, 1.0, 2.0, 3.0))
    _assert_same(animation.frame(1.0, device="cpu"), b)
    with pytest.raises(InvalidInputError, match=r"layers\[3\] covers none"):
        animation.frame(2.5, device="cpu")


@settings(max_examples=30, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), channels=hst.sampled_from([3, 4]))
def test_laying_lines_over_a_uint8_texture_is_blend_then_to_uint8(seed, channels):
    """``stepterrain texture --contours`` lays the lines over the uint8 texture in place (``_lay_over_uint8``), as
    ``blend`` lays them and ``to_uint8`` rounds: byte for byte, colours near uint8's half steps too."""
    rng = np.random.default_rng(seed)
    under = rng.integers(0, 256, (5, 8, channels), dtype=np.uint8)
    lines = _near_half_steps(seed)
    image = np.array(lines.image)
    image[rng.random((5, 8)) < 0.3, 3] = 0.0  # no line there
    lines = TextureLayer("thematic", image, EXTENT)
    want = blend(TextureLayer("thematic", under, EXTENT), lines, device="cpu").to_uint8(
        None if channels == 4 else (0.0, 0.0, 0.0))
    got = under.copy()
    texture_ops._lay_over_uint8(got, lines)
    np.testing.assert_array_equal(got, want)


TERRAIN = TextureLayer("thematic", np.full((40, 40, 3), 0.8, dtype=np.float32), (0.0, 40.0, 0.0, 40.0))


@pytest.mark.parametrize("t", [0.0, 0.25, 0.5, 1.0])
def test_an_animated_highlight_lens_darkens_the_terrain_beyond_its_square(t):
    """Keys of an 'edge' border (lenses, §5: 1 - strength outside) animated (§6): the frame kept a transparent
    border, so a terrain modulated by it was darkened only within the lens image's square (the rest left at full
    brightness, a square edge of light), and a frame at a key's time was not that key."""
    keys = [highlight_lens((10.0, 10.0), 4.0, strength=0.5, resolution=16),
            highlight_lens((30.0, 30.0), 4.0, strength=0.5, resolution=16)]
    frame = TextureAnimation(keys, (0.0, 1.0)).frame(t, device="cpu")
    assert frame.border == "edge"
    shaded = modulate(TERRAIN, frame, device="cpu").rgba()
    np.testing.assert_allclose(shaded[0, 39, :3], 0.4, rtol=1e-6)  # the north-east corner: far from both lenses
    np.testing.assert_allclose(shaded[39, 0, :3], 0.4, rtol=1e-6)  # the south-west corner
    if t in (0.0, 1.0):
        np.testing.assert_allclose(shaded, modulate(TERRAIN, keys[int(t)], device="cpu").rgba(), atol=1e-6)


@pytest.mark.parametrize("operation", ["blend", "add", "modulate", "adjust rotated"])
def test_an_operation_on_a_lens_keeps_its_edge_border(operation):
    """A lens dimmed or combined (its first layer 'edge') repeats its edge as the lens does: the result's border was
    transparent, so the terrain beyond the lens image's square was left undarkened."""
    lens = highlight_lens((20.0, 20.0), 4.0, strength=0.5, resolution=16)
    if operation == "blend":
        result = blend(lens, np.full((16, 16), 0.5), np.zeros((16, 16)), device="cpu")
    elif operation == "add":
        result = weighted_add([lens, lens], [0.5, 0.5], device="cpu")
    elif operation == "modulate":
        result = modulate(lens, np.ones((16, 16)), device="cpu")
    else:  # a texture matrix turned a quarter turn about the lens' centre: resampled onto its extent
        c, s = 0.0, 1.0
        turn = np.array([[c, -s, 20.0 - c * 20.0 + s * 20.0], [s, c, 20.0 - s * 20.0 - c * 20.0], [0.0, 0.0, 1.0]])
        result = adjust(TextureLayer("luminance", lens.image, lens.extent, matrix=lens.matrix @ turn,
                                     border="edge"), brightness=1.0, device="cpu")
    assert result.border == "edge"
    np.testing.assert_allclose(modulate(TERRAIN, result, device="cpu").rgba(),
                               modulate(TERRAIN, lens, device="cpu").rgba(), atol=1e-6)
