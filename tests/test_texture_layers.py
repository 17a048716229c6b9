"""Texture layers and their operations (paper 004 §3.2.3), lenses (§5), animation (§6) and draping."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

import stepterrain as st
from stepterrain import render
from stepterrain.errors import InvalidInputError
from stepterrain.export import save_mesh
from stepterrain.texture import (
    Pipeline,
    TextureAnimation,
    TextureLayer,
    adjust,
    blend,
    combine,
    drape,
    highlight_lens,
    modulate,
    terrain_layer,
    thematic_lens,
    topographic_layer,
    weighted_add,
)

EXTENT = (0.0, 4.0, 0.0, 3.0)
rng = np.random.default_rng(5)
RGB_A = rng.random((3, 4, 3)).astype(np.float32)
RGB_B = rng.random((3, 4, 3)).astype(np.float32)
ALPHA = rng.random((3, 4)).astype(np.float32)


def rgba(rgb, alpha=None):
    out = np.ones((*rgb.shape[:2], 4), np.float32)
    out[..., :3] = rgb
    if alpha is not None:
        out[..., 3] = alpha
    return out


def layer(image, kind="thematic", **kw):
    return TextureLayer(kind, image, EXTENT, **kw)


# ------------------------------------------------------------------------------------------ formulas
def test_layer_kinds_to_rgba():
    lum = layer(ALPHA, "luminance").rgba()
    np.testing.assert_allclose(lum[..., 0], ALPHA)
    np.testing.assert_allclose(lum[..., 3], 1.0)
    vis = layer(ALPHA, "visibility").rgba()
    np.testing.assert_allclose(vis[..., :3], 1.0)
    np.testing.assert_allclose(vis[..., 3], ALPHA)
    u8 = layer((RGB_A * 255).round().astype(np.uint8)).rgba()
    np.testing.assert_allclose(u8[..., :3], RGB_A, atol=0.5 / 255 + 1e-6)


def test_blend_formula(device):
    out = blend(layer(RGB_A), layer(RGB_B), layer(ALPHA, "visibility"), device=device).rgba()
    w = ALPHA[..., None]
    np.testing.assert_allclose(out, rgba(RGB_A) * (1 - w) + rgba(RGB_B) * w, atol=1e-6)


def test_weighted_add_formula(device):
    out = weighted_add([layer(RGB_A), layer(RGB_B), layer(ALPHA, "luminance")], [0.3, 0.5, 0.2],
                       device=device).rgba()
    expected = np.clip(0.3 * rgba(RGB_A) + 0.5 * rgba(RGB_B) + 0.2 * rgba(np.repeat(ALPHA[..., None], 3, 2)), 0, 1)
    np.testing.assert_allclose(out, expected, atol=1e-6)


def test_weighted_add_clamps_only_the_sum(device):
    ones = layer(np.ones((3, 4, 3), np.float32))
    out = weighted_add([ones, ones, ones], [1.0, 1.0, -1.5], device=device).rgba()
    np.testing.assert_allclose(out, 0.5, atol=1e-6)  # 1 + 1 - 1.5, not min(1 + 1, 1) - 1.5


def test_modulate_formula(device):
    out = modulate(layer(RGB_A), layer(ALPHA, "topographic"), layer(RGB_B), device=device).rgba()
    np.testing.assert_allclose(out[..., :3], RGB_A * ALPHA[..., None] * RGB_B, atol=1e-6)
    np.testing.assert_allclose(out[..., 3], 1.0)


def cesium_reference(rgb, alpha, brightness, contrast, hue, saturation, gamma, layer_alpha):
    """CesiumJS GlobeFS order (gamma first, since 1.53), in float64."""
    c = rgb.astype(np.float64) ** (1 / gamma) * brightness
    c = 0.5 + (c - 0.5) * contrast
    if hue:
        yiq = c @ np.array([[0.299, 0.587, 0.114], [0.595716, -0.274453, -0.321263],
                            [0.211456, -0.522591, 0.311135]]).T
        angle = np.arctan2(yiq[..., 2], yiq[..., 1]) + hue
        chroma = np.hypot(yiq[..., 1], yiq[..., 2])
        yiq = np.stack([yiq[..., 0], chroma * np.cos(angle), chroma * np.sin(angle)], -1)
        c = yiq @ np.array([[1.0, 0.9563, 0.6210], [1.0, -0.2721, -0.6474], [1.0, -1.1070, 1.7046]]).T
    luma = c @ np.array([0.2125, 0.7154, 0.0721])
    c = luma[..., None] + (c - luma[..., None]) * saturation
    return np.clip(c, 0, 1), alpha * layer_alpha


@pytest.mark.parametrize("params", [
    dict(brightness=1.3, contrast=0.7, hue=0.0, saturation=1.0, gamma=1.0, alpha=1.0),
    dict(brightness=0.8, contrast=1.5, hue=0.6, saturation=0.4, gamma=2.2, alpha=0.5),
    dict(brightness=1.0, contrast=1.0, hue=-1.2, saturation=1.8, gamma=0.5, alpha=0.9),
])
def test_adjust_formula(device, params):
    out = adjust(layer(np.concatenate([RGB_A, ALPHA[..., None]], 2)), device=device, **params).rgba()
    rgb, alpha = cesium_reference(RGB_A, ALPHA, params["brightness"], params["contrast"], params["hue"],
                                  params["saturation"], params["gamma"], params["alpha"])
    np.testing.assert_allclose(out[..., :3], rgb, atol=2e-5)
    np.testing.assert_allclose(out[..., 3], alpha, atol=1e-6)


def test_hue_rotation_keeps_luma_and_full_turn_is_identity(device):
    out = adjust(layer(RGB_A), hue=2 * math.pi, device=device).rgba()
    np.testing.assert_allclose(out[..., :3], np.clip(RGB_A, 0, 1), atol=2e-3)


def test_hue_beyond_float32_keeps_a_white_layer_white(device):
    """hue=1e300 reached the kernel as float32 inf: cos and sin NaN, every pixel black; whole turns are dropped now."""
    from stepterrain.texture import TextureLayer

    white = TextureLayer("thematic", np.ones((2, 3, 3), np.float32), (0.0, 3.0, 0.0, 2.0))
    for hue in (1e300, -1e300, 1e30):
        np.testing.assert_allclose(adjust(white, hue=hue, device=device).rgba(), 1.0, atol=1e-5)
    np.testing.assert_array_equal(adjust(layer(RGB_A), hue=4.0 + 2 * math.pi, device=device).rgba(),
                                  adjust(layer(RGB_A), hue=4.0, device=device).rgba())


def test_split_and_cutout(device):
    base = layer(RGB_A)
    left = adjust(base, split="left", split_position=0.5, device=device).rgba()[..., 3]
    np.testing.assert_array_equal(left, np.repeat([[1, 1, 0, 0]], 3, 0))
    right = adjust(base, split="right", split_position=0.25, device=device).rgba()[..., 3]
    np.testing.assert_array_equal(right, np.repeat([[0, 1, 1, 1]], 3, 0))
    # pixel centres: x = 0.5 .. 3.5, y = 2.5 (row 0) .. 0.5 (row 2)
    cut = adjust(base, cutout=(1.0, 3.0, 0.0, 1.0), device=device).rgba()[..., 3]
    np.testing.assert_array_equal(cut, [[1, 1, 1, 1], [1, 1, 1, 1], [1, 0, 0, 1]])


@given(a=arrays(np.float32, (2, 3, 3), elements=hst.floats(0, 1, width=32)),
       b=arrays(np.float32, (2, 3, 3), elements=hst.floats(0, 1, width=32)),
       w=hst.floats(0, 1))
def test_blend_is_add_with_complementary_weights(a, b, w):
    la, lb = TextureLayer("thematic", a, EXTENT), TextureLayer("thematic", b, EXTENT)
    blended = blend(la, lb, np.full((2, 3), w, np.float32), device="cpu").rgba()
    added = weighted_add([la, lb], [1 - w, w], device="cpu").rgba()
    np.testing.assert_allclose(blended, added, atol=2e-6)


def test_pipeline_composes(device):
    base = layer(RGB_A)
    first = Pipeline().modulate(layer(ALPHA, "luminance")).blend(layer(RGB_B), layer(ALPHA, "visibility"))
    second = Pipeline().add(layer(RGB_B), (0.5, 0.25)).adjust(gamma=1.5, saturation=0.5)
    whole = first.then(second).apply(base, device=device).rgba()
    by_hand = adjust(weighted_add([blend(modulate(base, layer(ALPHA, "luminance"), device=device), layer(RGB_B),
                                         layer(ALPHA, "visibility"), device=device), layer(RGB_B)], [0.5, 0.25],
                                  device=device), gamma=1.5, saturation=0.5, device=device).rgba()
    np.testing.assert_array_equal(whole, by_hand)
    np.testing.assert_array_equal(second.apply(first.apply(base, device=device), device=device).rgba(), whole)


def test_combine_by_mode_name(device):
    a, b = layer(RGB_A), layer(RGB_B)
    np.testing.assert_array_equal(combine(a, b, "modulate", device=device).rgba(), modulate(a, b, device=device).rgba())
    with pytest.raises(InvalidInputError, match="unknown blend mode 'screen'"):
        combine(a, b, "screen")


# ------------------------------------------------------------------------------------------ sampling, lenses
def test_resampling_through_texture_matrix(device):
    # a 2x2 layer over the same extent sampled onto 3x4 pixels: bilinear between texel centres
    coarse = TextureLayer("luminance", np.array([[0.0, 1.0], [0.0, 1.0]], np.float32), EXTENT)
    out = modulate(layer(np.ones((3, 4, 3), np.float32)), coarse, device=device).rgba()[0, :, 0]
    # pixel centres x = 0.5, 1.5, 2.5, 3.5 -> texel u = x / 2 - 0.5 = -0.25 (clamped), 0.25, 0.75, 1.25 (clamped)
    np.testing.assert_allclose(out, [0.0, 0.25, 0.75, 1.0], atol=1e-6)


def test_partial_coverage_is_transparent_outside(device):
    patch = TextureLayer("thematic", np.ones((2, 2, 3), np.float32), (0.0, 2.0, 0.0, 3.0))  # west half only
    out = blend(layer(np.zeros((3, 4, 3), np.float32)), patch, device=device).rgba()
    np.testing.assert_allclose(out[:, :2, 0], 1.0)
    np.testing.assert_allclose(out[:, 2:, 0], 0.0)


def test_moving_a_lens_changes_only_the_matrix(device):
    terrain_rgb = layer(np.full((3, 4, 3), 0.8, np.float32))
    lens = highlight_lens((1.0, 1.5), 0.8, strength=0.5, resolution=32)
    moved = lens.moved(2.0, 0.0)
    assert moved.image is lens.image
    assert not np.allclose(moved.matrix, lens.matrix)
    before = modulate(terrain_rgb, lens, device=device).rgba()[..., 0]
    after = modulate(terrain_rgb, moved, device=device).rgba()[..., 0]
    assert before[1, 1] == pytest.approx(0.8) and before[1, 3] == pytest.approx(0.4)  # hot spot / outside
    assert after[1, 3] == pytest.approx(0.8) and after[1, 1] == pytest.approx(0.4)


def test_adjust_keeps_a_lens_where_it_was_moved_and_its_edge_border(device):
    """adjust() with its defaults leaves a layer unchanged: it resampled a moved lens onto its unmoved extent (the
    hot spot, moved away, was lost) and returned a transparent border, so outside a highlight lens modulation gave
    black instead of 1 - strength. The cutout is in world units, where the moved lens lies."""
    terrain_rgb = TextureLayer("thematic", np.full((40, 40, 3), 0.8, np.float32), (-2.0, 18.0, -10.0, 10.0))
    white = TextureLayer("thematic", np.ones((40, 40, 3), np.float32), terrain_rgb.extent)
    black = TextureLayer("thematic", np.zeros((40, 40, 3), np.float32), terrain_rgb.extent)
    hot, outside = (20, 24), (20, 30)  # pixels at (10, 0), the moved lens' centre, and (13, 0)
    for lens in (thematic_lens((0.0, 0.0), 1.0, resolution=16).moved(10.0, 0.0),
                 highlight_lens((0.0, 0.0), 1.0, strength=0.5, resolution=16).moved(10.0, 0.0)):
        op = blend if lens.kind == "visibility" else modulate
        args = (black, white) if lens.kind == "visibility" else (terrain_rgb,)
        expected = op(*args, lens, device=device).rgba()
        adjusted = adjust(lens, device=device)
        assert adjusted.border == "edge"
        np.testing.assert_allclose(op(*args, adjusted, device=device).rgba(), expected, atol=1e-6)
    assert expected[hot][0] == pytest.approx(0.8) and expected[outside][0] == pytest.approx(0.4)
    visibility = thematic_lens((0.0, 0.0), 1.0, resolution=16).moved(10.0, 0.0)
    cut = adjust(visibility, cutout=(9.0, 11.0, -1.0, 1.0), device=device)
    assert blend(black, white, cut, device=device).rgba()[hot][0] == 0.0
    kept = adjust(visibility, cutout=(-1.0, 1.0, -1.0, 1.0), device=device)  # where the lens was: nothing there
    assert blend(black, white, kept, device=device).rgba()[hot][0] == 1.0


@pytest.mark.parametrize("make", [highlight_lens, thematic_lens])
def test_a_lens_resolution_beyond_the_memory_budget_is_refused_up_front(make):
    """resolution=1_000_000 asked numpy for terabytes of float64 texels and died in a bare MemoryError; the lens
    image is checked against the memory budget before any texel is allocated."""
    with pytest.raises(st.OutputTooLargeError, match=r"a lens image of resolution 1000000 would need .*lower the lens"):
        make((0.0, 0.0), 1.0, resolution=1_000_000)
    previous = st.set_memory_budget(1 << 20)
    try:
        with pytest.raises(st.OutputTooLargeError, match="resolution 256"):
            make((0.0, 0.0), 1.0, resolution=256)
        assert make((0.0, 0.0), 1.0, resolution=64).shape == (64, 64)
    finally:
        st.set_memory_budget(previous)

def test_a_texture_matrix_without_a_finite_inverse_is_refused_when_the_layer_is_made():
    """matrix=zeros made a layer that blend() met with numpy's LinAlgError (it inverts the matrix to find the
    layer's coverage); an extent of 1e-320 over 4 pixels gave an infinite matrix, and (-1e308, 1e308) one whose
    scale rounds to 0."""
    rgb = np.zeros((3, 4, 3), np.float32)
    for matrix in (np.zeros((3, 3)), [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]):
        with pytest.raises(InvalidInputError, match=r"matrix must be an invertible 3 x 3 texture matrix"):
            TextureLayer("thematic", rgb, EXTENT, matrix=matrix)
    for extent in ((0.0, 1e-320, 0.0, 3.0), (-1e308, 1e308, 0.0, 3.0)):
        with pytest.raises(InvalidInputError, match=r"over 4 x 3 pixels gives no finite, invertible texture matrix"):
            TextureLayer("thematic", rgb, extent)
    far = TextureLayer("thematic", rgb, EXTENT, matrix=np.diag([1e-300, 1e-300, 1.0]))  # tiny, but invertible
    assert far.matrix[0, 0] == 1e-300


def test_thematic_lens_blends_two_layers(device):
    a, b = layer(np.zeros((3, 4, 3), np.float32)), layer(np.ones((3, 4, 3), np.float32))
    lens = thematic_lens((0.5, 2.5), 0.6, edge=0.0, resolution=64)
    out = blend(a, b, lens, device=device).rgba()[..., 0]
    assert out[0, 0] == pytest.approx(1.0) and out[2, 3] == pytest.approx(0.0)
    assert lens.shape == (64, 64)


# ------------------------------------------------------------------------------------------ animation
def test_animation_selects_two_keyframes():
    keys = [layer(np.full((3, 4), v, np.float32), "luminance") for v in (0.0, 0.5, 1.0)]
    anim = TextureAnimation(keys, [0.0, 1.0, 3.0])
    a, b, alpha = anim.at(2.0)
    assert a is keys[1] and b is keys[2] and alpha == pytest.approx(0.5)
    assert anim.at(-5.0)[2] == 0.0 and anim.at(99.0)[2] == 1.0
    np.testing.assert_allclose(anim.frame(2.0, device="cpu").rgba()[..., 0], 0.75, atol=1e-6)
    with pytest.raises(InvalidInputError, match="strictly increasing"):
        TextureAnimation(keys, [0.0, 2.0, 1.0])


KEY = layer(np.full((3, 4), 0.5, np.float32), "luminance")


@pytest.mark.parametrize("layers, times, match", [
    (None, [0.0], r"layers must be a sequence of TextureLayer keyframes; got NoneType"),
    (5, [0.0], r"layers must be a sequence of TextureLayer keyframes; got int"),
    ("ab", [0.0, 1.0], r"layers must be a sequence of TextureLayer keyframes; got str"),
    (KEY, [0.0], r"layers must be a sequence of TextureLayer keyframes; got TextureLayer"),
    ([], [], r"an animation needs at least one TextureLayer keyframe; got an empty sequence"),
    ([KEY, "x"], [0.0, 1.0], r"layers\[1\] must be a TextureLayer; got str"),
    ([KEY, None], [0.0, 1.0], r"layers\[1\] must be a TextureLayer; got NoneType"),
    ([KEY, KEY], "ab", r"times must be 2 finite, strictly increasing numbers \(one per layer\); got 'ab'"),
    ([KEY, KEY], None, r"times must be 2 finite, strictly increasing numbers \(one per layer\); got None"),
    ([KEY, KEY], ["a", "b"], r"times must be 2 finite, strictly increasing numbers \(one per layer\) \(real "),
    ([KEY, KEY], [0.0, 1j], r"times must be 2 finite, strictly increasing numbers \(one per layer\) \(real "),
    ([KEY, KEY], [[0.0], [1.0, 2.0]], r"times must be 2 finite, .*; got rows of different lengths"),
    ([KEY, KEY], [0.0], r"times must give one time stamp per layer \(2\); got 1"),
    ([KEY, KEY], [0.0, np.nan], r"times must be finite and strictly increasing; got \[0.0, nan\]"),
    ([KEY, KEY], [1.0, 1.0], r"times must be finite and strictly increasing; got \[1.0, 1.0\]"),
    # accepted before: frame() resamples onto the earlier keyframe of its pair, so the frames changed size
    ([KEY, layer(np.zeros((2, 4), np.float32), "luminance")], [0.0, 1.0],
     r"layers\[1\] has shape \(2, 4\) but layers\[0\] has \(3, 4\) \(mismatched size\); keyframes must all be "
     r"images of one size"),
    ([KEY, KEY, layer(np.zeros((4, 3, 3), np.float32))], [0.0, 1.0, 2.0],
     r"layers\[2\] has shape \(4, 3\) but layers\[0\] has \(3, 4\) \(mismatched size\)"),
])
def test_animation_arguments_are_checked(layers, times, match):
    """times 'ab' raised numpy's 'could not convert string to float' ValueError, layers None or 5 Python's
    'not iterable' TypeError, and a string of layers or a single layer were not named."""
    with pytest.raises(InvalidInputError, match=match):
        TextureAnimation(layers, times)


@pytest.mark.parametrize("t, match", [("x", r"t must be a number; got 'x'"), (None, r"t must be a number; got None"),
                                      (np.nan, r"t must be finite; got nan"), (np.inf, r"t must be finite; got inf")])
def test_animation_frame_time_is_checked(t, match):
    anim = TextureAnimation([KEY, KEY], [0.0, 1.0])
    with pytest.raises(InvalidInputError, match=match):
        anim.frame(t, device="cpu")
    with pytest.raises(InvalidInputError, match=match):
        anim.at(t)


def test_animation_good_arguments_keep_working():
    keys = (layer(np.full((3, 4), v, np.float32), "luminance") for v in (0.0, 1.0))  # any iterable of layers
    anim = TextureAnimation(keys, np.array([0, 4]))  # integer times
    assert anim.times == (0.0, 4.0) and len(anim.layers) == 2
    assert anim.at(1)[2] == pytest.approx(0.25)
    assert TextureAnimation([KEY], 2.5).times == (2.5,)  # one keyframe, one scalar time


# ------------------------------------------------------------------------------------------ bad input
def test_bad_layers_and_operations():
    with pytest.raises(InvalidInputError, match="layer kind must be one of"):
        TextureLayer("normal", ALPHA, EXTENT)
    with pytest.raises(InvalidInputError, match="thematic layer needs"):
        TextureLayer("thematic", ALPHA, EXTENT)
    with pytest.raises(InvalidInputError, match="xmin < xmax"):
        TextureLayer("luminance", ALPHA, (1.0, 0.0, 0.0, 1.0))
    with pytest.raises(InvalidInputError, match="mismatched size"):
        blend(layer(RGB_A), np.zeros((2, 2, 3)))
    far = TextureLayer("thematic", RGB_B, (100.0, 104.0, 0.0, 3.0))
    with pytest.raises(InvalidInputError, match="mismatched extent"):
        blend(layer(RGB_A), far)
    with pytest.raises(InvalidInputError, match=r"weights\[1\] must be finite"):
        weighted_add([layer(RGB_A), layer(RGB_B)], [0.5, float("nan")])
    with pytest.raises(InvalidInputError, match="one weight per layer"):
        weighted_add([layer(RGB_A), layer(RGB_B)], [0.5])
    with pytest.raises(InvalidInputError, match=r"values must lie in \[0, 1\]"):
        blend(layer(RGB_A), layer(RGB_B), layer(ALPHA * 3, "visibility"))
    with pytest.raises(InvalidInputError, match=r"alpha must lie in \[0, 1\]"):
        adjust(layer(RGB_A), alpha=1.5)
    with pytest.raises(InvalidInputError, match="split must be"):
        adjust(layer(RGB_A), split="up")


@pytest.mark.parametrize("extent", [("0", "4", "0", "3"), (False, True, False, True), (0, 4, 0, "3")])
def test_an_extent_of_text_or_bools_is_refused(extent):
    """float() read "4" as 4.0 and True as 1.0: a slip (a value from a file, a flag in the wrong place) was taken."""
    with pytest.raises(InvalidInputError, match=r"extent must be \(xmin, xmax, ymin, ymax\); got "):
        TextureLayer("luminance", ALPHA, extent)
    with pytest.raises(InvalidInputError, match=r"cutout must be \(xmin, xmax, ymin, ymax\); got "):
        adjust(layer(RGB_A), cutout=extent, device="cpu")


@pytest.mark.parametrize(("matrix", "got"), [
    ([["1", "0", "0"], ["0", "1", "0"], ["0", "0", "1"]], r"dtype <U1"),
    (np.eye(3).astype(str), r"dtype <U32"),
    ([[True, 0, 0], [0, 1, 0], [0, 0, 1]], r"a bool \(True\) at index \(0, 0\)"),
    (np.eye(3, dtype=bool), r"dtype bool"),
    (np.eye(3) + 1j, r"dtype complex128"),  # the imaginary part was dropped, with numpy's ComplexWarning
])
def test_a_texture_matrix_of_text_bools_or_complex_numbers_is_refused(matrix, got):
    """np.asarray(matrix, dtype=float) read "1" as 1.0, True as 1.0 and 1+1j as 1.0: each made the identity."""
    with pytest.raises(InvalidInputError, match=rf"matrix must be a finite 3 x 3 texture matrix \(real numbers\); "
                                                rf"got {got}"):
        TextureLayer("luminance", ALPHA, EXTENT, matrix=matrix)
    masked = np.ma.masked_array(np.eye(3), mask=np.eye(3) == 0)  # the masked zeros were read as zeros
    with pytest.raises(InvalidInputError, match=r"matrix must be a finite 3 x 3 texture matrix; got "):
        TextureLayer("luminance", ALPHA, EXTENT, matrix=masked)
    assert TextureLayer("luminance", ALPHA, EXTENT, matrix=np.eye(3, dtype=np.int32)).matrix.dtype == np.float64


@pytest.mark.parametrize("lens", [highlight_lens, thematic_lens])
@pytest.mark.parametrize("center", ["ab", ("1", "2"), (True, False), (1.0, 2j), None, (1.0, np.nan), (1.0, 2.0, 3.0)])
def test_a_lens_center_must_be_a_finite_point(lens, center):
    """'ab' and ('1', '2') raised numpy's 'could not convert string to float' ValueError, True was taken as 1."""
    with pytest.raises(InvalidInputError, match=r"center must be a finite \(x, y\); got "):
        lens(center, 1.0)
    assert lens(np.array([1, 2]), 1.0).shape == (128, 128)


# ------------------------------------------------------------------------------------------ draping
def sample_terrain(size=48):
    dem = st.sample_dem()
    stride = 6
    heights = dem.heights[: size * stride: stride, : size * stride: stride]
    return st.Terrain.from_heights(heights, spacing=(dem.spacing[0] * stride, dem.spacing[1] * stride),
                                   origin=dem.origin)


def test_terrain_layer_is_north_up():
    t = st.Terrain.from_heights(np.zeros((2, 3)), spacing=(1.0, 1.0))  # dy > 0: row 0 is south
    image = np.array([[0.0, 0.1, 0.2], [0.5, 0.6, 0.7]], np.float32)
    lay = terrain_layer(t, image, "luminance")
    np.testing.assert_array_equal(lay.image, image[::-1])


def test_drape_stepped_terrain_to_glb(tmp_path, device):
    terrain = sample_terrain()
    topo = topographic_layer(terrain, device=device)
    mesh = st.stepped(terrain, interval=200.0, device=device)
    textured = drape(mesh, topo)
    uv = textured.visual.uv
    assert uv.shape == (len(mesh.vertices), 2)
    assert uv.min() > 0 and uv.max() < 1
    np.testing.assert_array_equal(textured.faces, mesh.faces)
    out = save_mesh(textured, tmp_path / "draped.glb")
    back = trimesh.load(out, force="mesh", process=False)
    assert isinstance(back.visual, trimesh.visual.TextureVisuals)
    image = back.visual.material.baseColorTexture
    assert image.size == (topo.shape[1], topo.shape[0])
    # the embedded image is the layer itself (lossless PNG inside the GLB)
    np.testing.assert_array_equal(np.asarray(image.convert("RGB")), topo.to_uint8(background=(1, 1, 1)))
    check_with_khronos_validator(out)


def check_with_khronos_validator(path: Path) -> None:
    """Zero errors and zero warnings from the Khronos glTF validator (npm gltf-validator) when it is installed:
    in the repository's .ci/node_modules (bash .ci/run) or under $GLTF_VALIDATOR_PATH."""
    import os

    bases = [Path(__file__).resolve().parents[1] / ".ci" / "node_modules"]
    if os.environ.get("GLTF_VALIDATOR_PATH"):
        bases.insert(0, Path(os.environ["GLTF_VALIDATOR_PATH"]))
    package = next((b / "gltf-validator" for b in bases if (b / "gltf-validator").exists()), None)
    if shutil.which("node") is None or package is None:
        return  # the session-wide check of the batch/export issue covers it where the validator is installed
    script = ("const v=require(process.argv[1]);const fs=require('fs');"
              "v.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2]))).then(r=>"
              "{console.log(r.issues.numErrors+' '+r.issues.numWarnings);"
              "process.exit(r.issues.numErrors+r.issues.numWarnings?1:0)})")
    result = subprocess.run(["node", "-e", script, str(package), str(path)], capture_output=True, text=True)
    assert result.returncode == 0, f"glTF validator: errors, warnings = {result.stdout} {result.stderr}"


def test_drape_maps_world_xy_to_texels():
    mesh = st.heightfield_mesh(np.zeros((3, 5)), spacing=(1.0, 1.0))
    textured = drape(mesh, TextureLayer("luminance", np.ones((3, 5)), (-0.5, 4.5, -0.5, 2.5)))
    uv = textured.visual.uv
    # vertex k = node (i, j) at (j, i): u = (j + 0.5) / 5, v = (i + 0.5) / 3 (v up, row 0 of the image north)
    i, j = np.divmod(np.arange(15), 5)
    np.testing.assert_allclose(uv[:, 0], (j + 0.5) / 5)
    np.testing.assert_allclose(uv[:, 1], (i + 0.5) / 3)


@pytest.mark.parametrize("border", ["transparent", "edge"])
def test_drape_a_layer_covering_part_of_the_mesh_keeps_its_border_beyond_it(border):
    """UVs past 0 and 1 made the texture repeat (glTF's default sampler, VTK's too): a red layer over the west half
    of a mesh showed red on the east half as well. The image now grows to cover the mesh, as its border says."""
    mesh = st.heightfield_mesh(np.zeros((11, 11)))  # x, y in [0, 10]
    image = np.zeros((4, 4, 3), np.float32)
    image[..., 0] = 1.0  # red
    image[:, -1, 2] = 1.0  # the east column magenta
    textured = drape(mesh, TextureLayer("thematic", image, (0.0, 5.0, 0.0, 10.0), border=border),
                     background=(0.0, 1.0, 0.0))
    uv = textured.visual.uv
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    picture = np.asarray(textured.visual.material.baseColorTexture.convert("RGB"))
    rows, cols = picture.shape[:2]
    texels = picture[np.floor((1.0 - uv[:, 1]) * rows).astype(int), np.floor(uv[:, 0] * cols).astype(int)]
    x, y = textured.vertices[:, 0], textured.vertices[:, 1]
    inner = (y > 0.0) & (y < 10.0)  # off the image's north and south edges, which lie between two texels
    assert (texels[inner & (x > 0.0) & (x <= 3.0)] == (255, 0, 0)).all()  # inside, off the east column
    beyond = (0, 255, 0) if border == "transparent" else (255, 0, 255)  # the background, or the edge repeated
    assert (texels[inner & (x >= 6.0)] == beyond).all()


def test_drape_refuses_a_mesh_wholly_outside_the_layer():
    """A mesh in other coordinates than the layer's (a pyvista ImageData at (0, 0) under the layer of a DEM in UTM)
    was draped with the layer's edge texels stretched over it (or the background), silently: the image grew to cover
    both. Now it is refused, naming both extents; a mesh under part of the layer is draped as before."""
    dem = st.sample_dem().coarsen(8)
    layer = st.topographic_layer(dem, device="cpu")
    local = st.heightfield_mesh(np.asarray(dem.heights), spacing=(240.0, 240.0))  # the same heights at (0, 0)
    with pytest.raises(InvalidInputError, match=r"mesh must lie under the layer.*x 0 to .*376\d{3}"):
        drape(local, layer)
    edge = TextureLayer(layer.kind, layer.image, layer.extent, border="edge")
    with pytest.raises(InvalidInputError, match="wholly outside"):
        drape(local, edge)
    part = st.heightfield_mesh(np.asarray(dem.heights), spacing=dem.spacing,
                               origin=(dem.origin[0] + 20_000.0, dem.origin[1]))  # its west half under the layer
    assert len(drape(part, layer).visual.uv) == len(part.vertices)


AVAILABLE, REASON = render.offscreen_available()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_render_draped_texture_orientation():
    mesh = st.heightfield_mesh(np.zeros((11, 11)))
    image = np.zeros((20, 20, 3), np.uint8)
    image[:10, :, 0] = 255  # north half red
    image[10:, :, 2] = 255  # south half blue
    textured = drape(mesh, TextureLayer("thematic", image, (-0.5, 10.5, -0.5, 10.5)))
    shot = render.render_textured_mesh(textured, window_size=(120, 120), camera="top", lighting=False)
    assert tuple(shot[30, 60]) == (255, 0, 0) and tuple(shot[90, 60]) == (0, 0, 255)


@given(image=arrays(np.float32, (2, 3, 4), elements=hst.floats(0, 1, width=32)))
def test_adjust_defaults_leave_the_layer_unchanged(image):
    out = adjust(TextureLayer("thematic", image, EXTENT), device="cpu").rgba()
    np.testing.assert_allclose(out, image, atol=2e-6)


def test_drape_and_render_bad_input():
    mesh = st.heightfield_mesh(np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="layer must be a TextureLayer"):
        drape(mesh, np.ones((3, 3)))
    with pytest.raises(InvalidInputError, match="mesh must be a trimesh.Trimesh"):
        drape("mesh.glb", layer(RGB_A))
    with pytest.raises(InvalidInputError, match="background must be"):
        drape(mesh, layer(RGB_A), background=(2, 0, 0))
    for background in ("white", ("1", "1", "1"), (True, True, True)):  # numpy's ValueError; True taken as 1
        with pytest.raises(InvalidInputError, match=r"background must be \(r, g, b\) in \[0, 1\]; got "):
            drape(mesh, layer(RGB_A), background=background)
    with pytest.raises(InvalidInputError, match="mesh has no texture"):
        render.render_textured_mesh(mesh)


@pytest.mark.parametrize("name", [5, None, b"roads", ["roads"]])
def test_layer_and_drape_names_must_be_strings(name):
    """TextureLayer(name=5) and drape(name=None) were taken: the layer carried a number as its name, and the
    draped mesh's material a number or None as its name (written into a GLB as given)."""
    with pytest.raises(InvalidInputError, match=rf"name must be a string; got {re.escape(repr(name))}"):
        TextureLayer("luminance", ALPHA, EXTENT, name=name)
    with pytest.raises(InvalidInputError, match=rf"name must be a string; got {re.escape(repr(name))}"):
        drape(st.heightfield_mesh(np.zeros((3, 3))), layer(RGB_A), name=name)
    assert TextureLayer("luminance", ALPHA, EXTENT, name=np.str_("roads")).name == "roads"


def test_sampling_is_precise_at_utm_coordinates(device):
    # 0.1 m pixels 400 km from the origin: float32 world coordinates would be off by ~0.3 texel
    x0, y0 = 400_000.0, 3_800_000.0
    extent = (x0, x0 + 0.4, y0, y0 + 0.3)
    ramp = np.tile(np.arange(4, dtype=np.float32) / 3, (3, 1))
    base = TextureLayer("luminance", np.ones((3, 4), np.float32), extent)
    shifted = TextureLayer("luminance", ramp, extent).moved(0.05, 0.0)  # half a texel east
    out = modulate(base, shifted, device=device).rgba()[0, :, 0]
    np.testing.assert_allclose(out, [0.0, 1 / 6, 0.5, 5 / 6], atol=1e-3)
    cut = adjust(base, cutout=(x0 + 0.2, x0 + 0.4, y0, y0 + 0.3), device=device).rgba()[0, :, 3]
    np.testing.assert_array_equal(cut, [1, 1, 0, 0])


def test_layer_sees_later_changes_to_its_image_array():
    """The image is kept as given (no copy): editing it in place must not leave a stale RGBA behind."""
    image = np.zeros((2, 3, 3), np.float32)
    a = TextureLayer("thematic", image, (0, 3, 0, 2))
    zero = np.zeros((2, 3))
    assert float(blend(a, np.ones((2, 3, 3)), zero, device="cpu").rgba()[0, 0, 0]) == 0.0
    image[:] = 0.5
    assert float(a.rgba()[0, 0, 0]) == 0.5
    np.testing.assert_array_equal(blend(a, np.ones((2, 3, 3)), zero, device="cpu").rgba()[..., :3], 0.5)
    frozen = np.full((2, 3), 0.25, np.float32)
    frozen.flags.writeable = False  # a read-only image (a memmap in mode "r") keeps its cached RGBA
    lum = TextureLayer("luminance", frozen, (0, 3, 0, 2))
    assert lum.rgba() is lum.rgba()


@pytest.mark.parametrize("background", [(1, 2), "white", (np.nan, 0, 0), (0, 0, 2), [[0, 0], [0]], ("1", "0", "0"),
                                        (True, 0, 0)])
def test_to_uint8_background_is_checked(background):
    """(1, 2) and 'white' raised numpy's reshape/convert ValueError, (nan, 0, 0) gave a black image silently, text and
    bools were taken as numbers (drape refused the same background)."""
    from stepterrain.texture import TextureLayer

    layer = TextureLayer("luminance", np.full((2, 3), 0.5), (0.0, 3.0, 0.0, 2.0))
    with pytest.raises(st.InvalidInputError, match=r"background must be \(r, g, b\) in \[0, 1\]"):
        layer.to_uint8(background=background)
    assert layer.to_uint8(background=(1.0, 1.0, 1.0)).shape == (2, 3, 3)


def test_a_ragged_layer_image_is_named():
    from stepterrain.texture import TextureLayer

    with pytest.raises(st.InvalidInputError, match="thematic layer image must be an array; got rows of different"):
        TextureLayer("thematic", [[1], [1, 2]], (0.0, 1.0, 0.0, 1.0))


def test_pipeline_and_weighted_add_arguments_are_named_when_given():
    """Pipeline().adjust(foo=1) failed only at apply() with Python's TypeError; weighted_add(None, [1]) and
    Pipeline().add(L, 1.0) raised 'not iterable' TypeErrors."""
    from stepterrain.texture import Pipeline, TextureLayer, weighted_add

    layer = TextureLayer("luminance", np.full((2, 2), 0.5), (0.0, 1.0, 0.0, 1.0))
    with pytest.raises(st.InvalidInputError, match="adjust has no parameter 'foo'; expected some of alpha, "):
        Pipeline().adjust(foo=1.0)
    assert Pipeline().adjust(brightness=2.0).apply(layer, device="cpu").rgba()[0, 0, 0] == pytest.approx(1.0)
    for layers, weights in ((None, [1.0]), ([layer], None), ([layer], 1.0), ("ab", [1.0, 1.0])):
        with pytest.raises(st.InvalidInputError, match="weighted_add needs (layers|weights) as a sequence"):
            weighted_add(layers, weights)
    for weights in (1.0, None, (1.0, 2.0, 3.0), "ab"):
        with pytest.raises(st.InvalidInputError, match=r"Pipeline.add needs weights \(current, other\)"):
            Pipeline().add(layer, weights)


def test_texture_uv_checks_points_and_layer():
    """NaN points gave NaN texture coordinates silently, complex ones lost their imaginary part, text raised
    numpy's ValueError and a layer that is not one an AttributeError."""
    from stepterrain.texture import TextureLayer, texture_uv

    layer = TextureLayer("luminance", np.full((2, 2), 0.5), (0.0, 1.0, 0.0, 1.0))
    with pytest.raises(st.InvalidInputError, match=r"points must have finite x and y; got point 1"):
        texture_uv([[0.5, 0.5], [np.nan, 0.0]], layer)
    for points in ([["a", "b"]], np.ones((2, 2), complex)):
        with pytest.raises(st.InvalidInputError, match=r"points must be real \(N, 2\) or \(N, 3\) world coordinates"):
            texture_uv(points, layer)
    with pytest.raises(st.InvalidInputError, match="layer must be a TextureLayer; got str"):
        texture_uv([[0.0, 0.0]], "x")
    assert texture_uv([[0.5, 0.5, np.nan]], layer).tolist() == [[0.5, 0.5]]  # z is not used: NaN heights are fine


def test_topographic_layer_without_a_hillshade_is_darkened_by_its_shadows_alone():
    """method="none" (the CLI's --hillshade none): 1 where nothing darkens a node, ambient + (1 − ambient) ·
    (1 − shadow_strength) in the shadow, NaN at nodata; the light without shadows is refused."""
    wall = np.zeros((3, 8), np.float32)
    wall[:, 2] = 10.0  # a wall west of the middle
    wall[0, 7] = np.nan
    light = {"azimuth": math.radians(270), "altitude": math.radians(45)}
    shadow = st.texture.cast_shadows(wall, **light, device="cpu")[::-1]  # the layer is north-up (rows reversed)
    layer_ = topographic_layer(wall, method="none", shadow_strength=0.4, **light, device="cpu")
    image = layer_.image
    assert np.isnan(image[2, 7]) and np.isfinite(np.delete(image.ravel(), 2 * 8 + 7)).all()
    finite = np.isfinite(image)
    expected = np.where(shadow == 1, 0.25 + 0.75 * 0.6, 1.0)
    np.testing.assert_allclose(image[finite], expected[finite], rtol=1e-6)
    assert (shadow[finite] == 1).any() and (shadow[finite] == 0).any()
    unlit = topographic_layer(wall, method="none", shadows=False, device="cpu").image
    assert np.all(unlit[np.isfinite(unlit)] == 1.0)
    with pytest.raises(InvalidInputError, match=r"azimuth has no effect on method='none'"):
        topographic_layer(wall, method="none", shadows=False, azimuth=1.0, device="cpu")


@pytest.mark.parametrize("method", ["None", "none ", "basic"])
def test_topographic_layer_refuses_an_unknown_method_naming_the_ones_it_takes(method):
    """An unknown method was refused by hillshade's message, "method must be one of standard, ..., igor,
    maplibre-standard, ...": it listed the MapLibre methods topographic_layer refuses and not "none", which it
    takes. The refusal now lists its own: the grey methods and none."""
    with pytest.raises(InvalidInputError) as caught:
        topographic_layer(np.zeros((3, 3), np.float32), method=method, device="cpu")
    message = str(caught.value)
    assert message == (f"method must be one of standard, multidirectional, combined, igor or none (no hillshade: the "
                       f"shadows and occlusion alone); got {method!r}")
