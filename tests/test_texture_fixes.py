"""Regression tests of the texture module's bug hunt (fixes-texture): each fails before its fix."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import given
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

import stepterrain.texture as texture_ops
from stepterrain.errors import InvalidInputError, StepTerrainError
from stepterrain.texture import (
    Pipeline,
    TextureAnimation,
    TextureLayer,
    adjust,
    ambient_occlusion,
    blend,
    cast_shadows,
    combine,
    drape,
    highlight_lens,
    hillshade,
    modulate,
    normal_map,
    relight,
    terrain_layer,
    topographic_layer,
    weighted_add,
)

from .conftest import budget_counts, needs_render
from .reference_texture import hillshade_reference, occlusion_reference, real_dem_crop, shadows_reference

RAD = math.radians


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


@pytest.mark.parametrize("z_factor", [1e39, 1e300])
def test_a_z_factor_beyond_float32_is_refused_not_shaded_wrong(z_factor):
    """The kernels take z_factor / (8 dx) and z_factor · h in float32: beyond float32 they were infinite, and a
    flat grid (which passed the slope check) came out black or NaN instead of sin(altitude)."""
    for flat in (np.full((6, 6), 100.0, np.float32), np.zeros((6, 6), np.float32)):
        for call in (hillshade, cast_shadows, ambient_occlusion, normal_map):
            with pytest.raises(InvalidInputError, match="z_factor"):
                call(flat, z_factor=z_factor, device="cpu")
        with pytest.raises(InvalidInputError, match="z_factor"):
            relight(normal_map(flat, device="cpu"), point=(1.0, 1.0, 10.0), terrain=flat, z_factor=z_factor,
                    device="cpu")
    ok = hillshade(np.full((6, 6), 100.0, np.float32), z_factor=1e30, device="cpu")  # large, but within float32
    np.testing.assert_allclose(ok, math.sin(math.radians(45)), rtol=1e-6)


@pytest.mark.parametrize("height", [1e38, 3e38])
def test_heights_beyond_the_kernels_float32_sums_are_refused(height):
    """Horn's sums (c + 2f + k) and the border's 2 · edge − next overflow float32 for |h| near its maximum: a flat
    grid at 1e38 came out black, or NaN for the multidirectional, igor and MapLibre methods."""
    flat = np.full((5, 5), height, np.float32)
    for method in ("standard", "multidirectional", "igor", "maplibre-standard"):
        with pytest.raises(InvalidInputError, match="heights"):
            hillshade(flat, method=method, device="cpu")
    with pytest.raises(InvalidInputError, match="heights"):
        normal_map(flat, device="cpu")
    ok = np.full((5, 5), 1e37, np.float32)  # well inside: shaded as the flat grid it is
    np.testing.assert_allclose(hillshade(ok, device="cpu"), math.sin(math.radians(45)), rtol=1e-6)


# ------------------------------------------------------------------------------------------ azimuth
@pytest.mark.parametrize("turns", [1000, 1e9, 1e299])
def test_igor_and_maplibre_take_a_large_azimuth_as_radians(turns):
    """An azimuth past two turns is warned about and used as radians. The light vector is made in float64, but
    igor and the MapLibre methods got the azimuth itself in float32: 1e10 rad shaded as some other angle, 1e300
    as infinity (NaN everywhere)."""
    rng = np.random.default_rng(3)
    heights = (rng.normal(size=(8, 9)) * 3).astype(np.float32)
    azimuth = 1.0 + 2 * math.pi * turns
    wrapped = math.fmod(azimuth, 2 * math.pi)
    with pytest.warns(UserWarning, match="radians"):
        igor = hillshade(heights, azimuth=azimuth, method="igor", device="cpu")
    np.testing.assert_allclose(igor, hillshade_reference(heights, azimuth=wrapped, method="igor"), atol=2e-5)
    for method in ("maplibre-standard", "maplibre-basic", "maplibre-igor", "maplibre-multidirectional"):
        with pytest.warns(UserWarning, match="radians"):
            ours = hillshade(heights, azimuth=azimuth, method=method, device="cpu")
        np.testing.assert_allclose(ours, hillshade(heights, azimuth=wrapped, method=method, device="cpu"),
                                   atol=2e-5)


# ------------------------------------------------------------------------------------------ point light
@pytest.mark.parametrize("point", [(1.0, 1.0, 1e30), (1.0, 1.0, 1e300), (1e39, 1.0, 1.0)])
def test_a_point_light_beyond_float32_distances_is_refused(point):
    """relight's point light: the kernel squares the distance to the light in float32, which overflowed from
    about 1e19 on, and every texel came out 0 (a light straight above a flat grid, which shades it 1)."""
    flat = np.zeros((4, 4), np.float32)
    normals = normal_map(flat, device="cpu")
    with pytest.raises(InvalidInputError, match="point"):
        relight(normals, point=point, terrain=flat, device="cpu")
    near = relight(normals, point=(1.5, 1.5, 1e17), terrain=flat, device="cpu")  # far, but within float32
    overhead = relight(normals, azimuth=0.0, altitude=math.pi / 2, device="cpu")  # the light straight above
    np.testing.assert_allclose(near, overhead, atol=1e-6)


# ------------------------------------------------------------------------------------------ fuzzing (h9)
RAGGED = [[1.0, 2.0], [3.0]]


def _layer(values=None):
    return TextureLayer("luminance", np.full((2, 2), 0.5) if values is None else values, (0, 2, 0, 2))


@pytest.mark.parametrize("call, name", [
    (lambda: relight(RAGGED, azimuth=1.0, altitude=0.5, device="cpu"), "normals"),
    (lambda: terrain_layer(np.zeros((2, 2)), RAGGED), "image"),
    (lambda: Pipeline().blend(RAGGED).apply(_layer(), device="cpu"), "b"),
    (lambda: Pipeline().blend(_layer(), RAGGED).apply(_layer(), device="cpu"), "weights"),
    (lambda: Pipeline().add(RAGGED).apply(_layer(), device="cpu"), "layers"),
    (lambda: Pipeline().modulate(RAGGED).apply(_layer(), device="cpu"), "layer"),
], ids=["relight normals", "terrain_layer image", "blend other", "blend weights", "add other", "modulate other"])
def test_ragged_rows_are_an_input_error_naming_the_argument(call, name):
    """A ragged nested list reached np.asarray, whose "inhomogeneous shape" ValueError named no argument."""
    with pytest.raises(InvalidInputError, match=rf"^{name}[^ ]*( [0-9]+)? must be .*; got rows of different lengths"):
        call()


@pytest.mark.parametrize("weights", [np.array(2.0), np.array(1.0, dtype=object)])
def test_pipeline_add_weights_without_a_length_are_refused(weights):
    """A 0-d array passed the Sequence | ndarray check and len() raised Python's TypeError."""
    with pytest.raises(InvalidInputError, match="Pipeline.add needs weights"):
        Pipeline().add(_layer(), weights)


def test_pipeline_add_ragged_weights_name_the_weight():
    """A ragged weights list reached weighted_add, which names the weight that is not a number."""
    with pytest.raises(InvalidInputError, match=r"^weights\[0\] must be a number"):
        Pipeline().add(_layer(), [[1.0, 2.0], [3.0]]).apply(_layer(), device="cpu")


@pytest.mark.parametrize("z_factor", ["abc", None, math.nan, -1.0, [1.0, 2.0]])
def test_relight_checks_z_factor_with_a_directional_light(z_factor):
    """With azimuth and altitude z_factor was never read, so text, None or a negative value passed silently."""
    rgb = normal_map(np.zeros((3, 3)), device="cpu")
    with pytest.raises(InvalidInputError, match="z_factor"):
        relight(rgb, azimuth=1.0, altitude=0.5, z_factor=z_factor, device="cpu")


@pytest.mark.parametrize(
    "given, message",
    [
        ({"terrain": np.zeros((3, 3))}, r"^terrain applies to a point light only .*; got terrain with azimuth"),
        ({"spacing": (2.0, 2.0)}, r"^spacing applies to a point light only .*; got spacing with azimuth"),
        ({"terrain": np.zeros((3, 3)), "spacing": 2.0}, r"^terrain and spacing apply to a point light only"),
    ],
    ids=["terrain", "spacing", "both"],
)
def test_relight_refuses_terrain_and_spacing_with_a_directional_light(given, message):
    """With azimuth and altitude, terrain and spacing were never read: a caller who meant them (a point light, a
    scaled surface) got the directional shading of the normals alone without a word."""
    rgb = normal_map(np.zeros((3, 3)), device="cpu")
    with pytest.raises(InvalidInputError, match=message):
        relight(rgb, azimuth=1.0, altitude=0.5, device="cpu", **given)
    assert relight(rgb, azimuth=1.0, altitude=0.5, device="cpu").shape == (3, 3)


# ------------------------------------------------------------------------------------------ compositing (h9)
def test_blending_a_translucent_layer_over_an_opaque_one_stays_opaque():
    """blend(a, b) with b's own alpha as the weight took the alpha channel through a (1 - w) + b w too: alpha
    alpha_a (1 - alpha_b) + alpha_b², 0.75 for an opaque a under b at 0.5, so drape() let the background through
    the opaque base."""
    grey = TextureLayer("thematic", np.full((2, 2, 3), 0.2, np.float32), (0, 2, 0, 2))
    red = np.zeros((2, 2, 4), np.float32)
    red[..., 0] = 1.0
    red[..., 3] = 0.5
    out = blend(grey, TextureLayer("thematic", red, (0, 2, 0, 2)), device="cpu").rgba()
    np.testing.assert_allclose(out[..., 3], 1.0, atol=1e-6)
    np.testing.assert_allclose(out[..., :3], np.broadcast_to([0.6, 0.1, 0.1], (2, 2, 3)), atol=1e-6)


def test_a_nodata_pixel_of_the_blended_layer_leaves_the_base_under_a_lens():
    """Under a lens (explicit weights) a nodata pixel of b, RGBA (1, 1, 1, 0), replaced a's colour: a transparent
    white hole in an opaque base where the lens is, grey-white fringes at its soft rim."""
    base = np.zeros((3, 3, 3), np.float32)
    base[..., 2] = 0.8
    values = np.full((3, 3), 0.4, np.float32)
    values[1, 1] = np.nan
    for w in (1.0, 0.5):
        out = blend(TextureLayer("thematic", base, (0, 3, 0, 3)), TextureLayer("luminance", values, (0, 3, 0, 3)),
                    np.full((3, 3), w, np.float32), device="cpu").rgba()
        np.testing.assert_allclose(out[1, 1], [0.0, 0.0, 0.8, 1.0], atol=1e-6)
        np.testing.assert_allclose(out[0, 0], [0.4 * w, 0.4 * w, 0.8 * (1 - w) + 0.4 * w, 1.0], atol=1e-6)


def test_resampling_does_not_bleed_the_colour_of_transparent_texels():
    """Bilinear sampling through a texture matrix interpolated straight (not premultiplied) RGBA: next to a
    transparent texel its colour leaked in, white from nodata (1, 1, 1, 0) and black from a clear RGBA texel, so a
    layer resampled onto another's pixels got light or dark fringes along every hole and edge."""
    extent = (0.0, 4.0, 0.0, 1.0)
    base = TextureLayer("thematic", np.full((1, 4, 3), 0.5, np.float32), extent)
    clear = np.zeros((1, 2, 4), np.float32)
    clear[0, 0] = (1.0, 0.0, 0.0, 1.0)  # red, then a transparent black texel
    grey = np.array([[0.2, np.nan]], np.float32)  # grey, then nodata
    # base pixel centres x = 0.5 ... 3.5 are texels u = -0.25 (clamped), 0.25, 0.75, 1.25 (clamped) of b
    for b, colour in ((TextureLayer("thematic", clear, extent), (1.0, 0.0, 0.0)),
                      (TextureLayer("luminance", grey, extent), (0.2, 0.2, 0.2))):
        out = blend(base, b, device="cpu").rgba()[0]
        for pixel, coverage in ((0, 1.0), (1, 0.75), (2, 0.25), (3, 0.0)):
            expected = coverage * np.array(colour) + (1 - coverage) * 0.5
            np.testing.assert_allclose(out[pixel], [*expected, 1.0], atol=1e-6)


def test_modulating_by_a_layer_that_covers_part_of_the_extent_keeps_the_rest():
    """modulate() multiplied by the RGB of transparent texels too: outside a layer that covers part of the base
    (partial coverage, border 'transparent', sampled as (0, 0, 0, 0)) the base came out black, though a nodata
    texel (1, 1, 1, 0) of the same layer left it unchanged."""
    base = TextureLayer("thematic", np.full((1, 4, 3), 0.8, np.float32), (0.0, 4.0, 0.0, 1.0))
    west = TextureLayer("luminance", np.full((1, 2), 0.5, np.float32), (0.0, 2.0, 0.0, 1.0))
    out = modulate(base, west, device="cpu").rgba()[0]
    np.testing.assert_allclose(out[:2], [[0.4, 0.4, 0.4, 1.0]] * 2, atol=1e-6)
    np.testing.assert_allclose(out[2:], [[0.8, 0.8, 0.8, 1.0]] * 2, atol=1e-6)


# ------------------------------------------------------------------------------------------ animation (h20)
def interpolate_reference(a, b, t):
    """Premultiplied interpolation of two straight RGBA images in float64: alpha (1 - t) alpha_a + t alpha_b,
    colour ((1 - t) alpha_a a + t alpha_b b) / alpha, straight mix where both are transparent."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    wa, wb = (1 - t) * a[..., 3:], t * b[..., 3:]
    alpha = wa + wb
    mixed = (1 - t) * a[..., :3] + t * b[..., :3]
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.where(alpha > 0, (wa * a[..., :3] + wb * b[..., :3]) / alpha, mixed)
    return np.concatenate([rgb, alpha], axis=-1)


def test_an_animation_frame_fades_to_a_transparent_key_without_tinting():
    """TextureAnimation.frame added its two keys per channel, straight RGBA: halfway between an opaque red key and
    a nodata key (RGBA (1, 1, 1, 0)) it drew pink (1, 0.5, 0.5) at alpha 0.5, and the colour of any transparent
    texel (the flood example's water colour above the water line) tinted the frames."""
    extent = (0.0, 3.0, 0.0, 2.0)
    red = np.zeros((2, 3, 4), np.float32)
    red[..., 0] = red[..., 3] = 1.0
    nodata = np.full((2, 3), np.nan, np.float32)
    keys = [TextureLayer("thematic", red, extent), TextureLayer("luminance", nodata, extent)]
    np.testing.assert_allclose(TextureAnimation(keys, (0.0, 2.0)).frame(1.0, device="cpu").rgba(),
                               np.broadcast_to([1.0, 0.0, 0.0, 0.5], (2, 3, 4)), atol=1e-6)
    rng = np.random.default_rng(20)
    a, b = rng.random((2, 5, 7, 4)).astype(np.float32)
    a[0, :, 3] = 0.0  # a transparent row of a, a transparent column of b, one pixel transparent in both
    b[:, 2, 3] = 0.0
    keys = [TextureLayer("thematic", a, (0, 7, 0, 5)), TextureLayer("thematic", b, (0, 7, 0, 5))]
    anim = TextureAnimation(keys, (1.0, 3.0))
    for t in (1.0, 1.5, 2.3, 3.0):
        np.testing.assert_allclose(anim.frame(t, device="cpu").rgba(), interpolate_reference(a, b, (t - 1.0) / 2.0),
                                   atol=2e-6)


# ------------------------------------------------------------------------------------------ layer values (h5)
def test_an_infinite_layer_value_is_refused_and_nan_stays_nodata():
    """A layer pixel holding inf was taken for nodata, as NaN is: blend's weights of inf (a weight far above 1) left
    ``a`` as it was, and an inf colour turned the pixel transparent, without a word. Heights refuse inf and keep
    NaN as nodata; layers now do the same."""
    a = TextureLayer("thematic", np.zeros((2, 2, 3), np.float32), (0, 2, 0, 2))
    weights = np.full((2, 2), 0.5, np.float32)
    weights[0, 1] = np.inf
    with pytest.raises(InvalidInputError, match=r"must be finite or NaN \(nodata\); got an infinite value at pixel "
                                                r"\(0, 1\)"):
        blend(a, np.ones((2, 2, 3)), weights, device="cpu")
    colours = np.full((2, 2, 3), 0.5, np.float32)
    colours[1, 0, 2] = -np.inf
    with pytest.raises(InvalidInputError, match=r"got an infinite value at pixel \(1, 0\)"):
        TextureLayer("thematic", colours, (0, 2, 0, 2)).rgba()
    weights[0, 1] = np.nan  # nodata: a transparent weight keeps a
    out = blend(a, np.ones((2, 2, 3)), weights, device="cpu").rgba()
    np.testing.assert_array_equal(out[..., 0], [[0.5, 0.0], [0.5, 0.5]])
    np.testing.assert_array_equal(out[..., 3], 1.0)


@pytest.mark.parametrize("call, name", [
    (lambda a: blend(a, np.ones((2, 2, 3)), np.full((2, 2), 1.5)), "weights"),
    (lambda a: blend(a, np.ones((2, 2, 3)), np.ones((2, 2), np.int64)), "weights"),
    (lambda a: blend(a, np.full((2, 2, 3), 2.0)), "b"),
    (lambda a: weighted_add([a, np.ones((2, 2, 3)), np.full((2, 2, 3), 3.0)], [1.0, 1.0, 1.0]), r"layers\[2\]"),
    (lambda a: modulate(a, np.ones((2, 2)), np.full((2, 2), 7, np.int16)), "layer 3"),
    (lambda a: adjust(TextureLayer("luminance", np.full((2, 2), 3.0), (0, 2, 0, 2))), "layer"),
    (lambda a: TextureAnimation([a, TextureLayer("luminance", np.full((2, 2), 3.0), (0, 2, 0, 2))],
                                (0.0, 1.0)).frame(0.5), r"layers\[1\]"),
], ids=["blend weights range", "blend weights dtype", "blend b", "weighted_add layer", "modulate layer", "adjust",
        "animation key"])
def test_bad_layer_values_name_the_argument(call, name):
    """An operation given values outside [0, 1] (or an image of int dtype) said "visibility layer values must lie in
    [0, 1]" or "thematic layer image must be uint8 or float": the kind of the layer made from them, not which of
    weighted_add's layers, modulate's others or blend's b and weights it was."""
    a = TextureLayer("thematic", np.zeros((2, 2, 3), np.float32), (0, 2, 0, 2))
    with pytest.raises(InvalidInputError, match=rf"^{name}: (visibility|thematic|luminance) layer "
                                                r"(values must lie in \[0, 1\]|image must be uint8 or float)"):
        call(a)


def test_blend_refuses_weights_without_an_alpha():
    """blend weighs by the alpha of ``weights``: a luminance layer of weights (or the highlight lens, taken for the
    thematic one, or an RGB layer) is opaque wherever it has data, so the result was b there whatever its values,
    without a word. Refused now, naming the fix; visibility and RGBA layers still weigh by their alpha."""
    extent = (0, 3, 0, 2)
    a = TextureLayer("thematic", np.zeros((2, 3, 3), np.float32), extent)
    b = np.ones((2, 3, 3), np.float32)
    values = np.array([[0.0, 0.25, 0.5], [0.75, 1.0, 0.5]], np.float32)
    for weights in (TextureLayer("luminance", values, extent), highlight_lens((1.5, 1.0), 1.0),
                    TextureLayer("thematic", np.repeat(values[..., None], 3, axis=2), extent)):
        with pytest.raises(InvalidInputError, match=r"^weights must be a layer with an alpha .* got a "
                                                    rf"{weights.kind} layer.*TextureLayer\('visibility'"):
            blend(a, b, weights, device="cpu")
    for weights in (TextureLayer("visibility", values, extent), values,
                    TextureLayer("thematic", np.dstack([b, values]), extent)):
        np.testing.assert_allclose(blend(a, b, weights, device="cpu").rgba()[..., 0], values, atol=1e-7)


def test_a_layer_s_rgba_over_the_memory_budget_is_refused_before_it_is_allocated(tmp_path):
    """rgba() expanded an image to 16 bytes a pixel (float32 RGBA) without looking at the memory budget: a
    memory-mapped gigapixel layer ran the machine out of memory instead of an OutputTooLargeError naming the size."""
    import stepterrain as st

    path = tmp_path / "big.npy"
    np.lib.format.open_memmap(path, mode="w+", dtype=np.uint8, shape=(600, 500, 3)).flush()  # 6.3 MiB
    layer = TextureLayer("thematic", np.load(path, mmap_mode="r"), (0, 500, 0, 600))
    previous = st.set_memory_budget(1 << 20)
    try:
        with pytest.raises(st.OutputTooLargeError, match=r"RGBA of a 500 x 600 thematic layer would need 6\.3 MiB, "
                                                         r"over the memory budget of 1\.0 MiB; crop or downsample"):
            layer.rgba()
        with pytest.raises(st.OutputTooLargeError):  # the operations that read a layer's RGBA are refused as well
            adjust(layer, brightness=0.5, device="cpu")
    finally:
        st.set_memory_budget(previous)
    rgba = layer.rgba()  # within the budget: as before
    assert rgba.shape == (600, 500, 4) and rgba.dtype == np.float32 and (rgba[..., 3] == 1.0).all()


@pytest.mark.parametrize("z_factor", [0.5, 3.0])
def test_a_point_light_is_exaggerated_with_the_surface(z_factor):
    """relight compared the point light's z, in world units, with the exaggerated surface (heights × z_factor):
    at z_factor 3 a light 50 m above a plain at 100 m lay below its exaggerated 300 m and lit nothing (black)."""
    flat = np.full((21, 21), 100.0, np.float32)
    shade = relight(normal_map(flat, z_factor=z_factor, device="cpu"), point=(10.0, 10.0, 150.0), terrain=flat,
                    z_factor=z_factor, device="cpu")
    i, j = np.meshgrid(np.arange(21), np.arange(21), indexing="ij")
    above = 50.0 * z_factor  # the light over the exaggerated plain
    np.testing.assert_allclose(shade, above / np.sqrt((i - 10.0) ** 2 + (j - 10.0) ** 2 + above**2), atol=0.01)
    # the same scene exaggerated beforehand, at z_factor 1: the surface and the light scaled alike
    heights = np.random.default_rng(4).normal(100.0, 2.0, (15, 17)).astype(np.float32)
    ours = relight(normal_map(heights, z_factor=z_factor, device="cpu"), point=(6.0, 9.0, 120.0), terrain=heights,
                   z_factor=z_factor, device="cpu")
    scaled = heights * np.float32(z_factor)
    theirs = relight(normal_map(scaled, device="cpu"), point=(6.0, 9.0, 120.0 * z_factor), terrain=scaled,
                     device="cpu")
    np.testing.assert_allclose(ours, theirs, atol=1e-5)


@pytest.mark.parametrize(("call", "match"), [
    (lambda z: hillshade(z, method="multidirectional", azimuth=1.0, device="cpu"),
     r"^azimuth has no effect on method='multidirectional', which shades by its four fixed lights.*got azimuth=1\.0 "
     r"without shadows"),
    (lambda z: hillshade(z, method="igor", altitude=0.3, device="cpu"),
     r"^altitude has no effect on method='igor'.*got altitude=0\.3 without shadows"),
    (lambda z: hillshade(z, shadow_strength=0.3, device="cpu"),
     r"^shadow_strength applies only with shadows=True .*got shadow_strength=0\.3 with shadows=False"),
    (lambda z: topographic_layer(z, shadows=False, shadow_strength=0.3, device="cpu"),
     r"^shadow_strength applies only with shadows=True"),
    (lambda z: topographic_layer(z, method="multidirectional", shadows=False, azimuth=1.0, device="cpu"),
     r"^azimuth has no effect on method='multidirectional'"),
], ids=["multidirectional azimuth", "igor altitude", "hillshade strength", "topographic strength",
        "topographic azimuth"])
def test_an_argument_the_shading_ignores_is_refused(call, match):
    """hillshade(method="multidirectional", azimuth=...) (four fixed lights), method="igor" with an altitude and
    shadow_strength without shadows (in hillshade and topographic_layer) shaded exactly as without them, without a
    word; the CLI and gdaldem refuse the like. Left at their defaults (None) the results are unchanged, and with
    shadows the angles aim the shadows."""
    heights = np.random.default_rng(5).normal(0.0, 20.0, (12, 14)).astype(np.float32)
    with pytest.raises(InvalidInputError, match=match):
        call(heights)
    default = hillshade(heights, azimuth=math.radians(315.0), altitude=math.radians(45.0), device="cpu")
    np.testing.assert_array_equal(hillshade(heights, device="cpu"), default)
    for method in ("multidirectional", "igor"):
        hillshade(heights, method=method, device="cpu")
        aimed = hillshade(heights, method=method, azimuth=1.0, altitude=0.3, shadows=True, device="cpu")
        assert aimed.shape == heights.shape
    layer = topographic_layer(heights, device="cpu").image
    np.testing.assert_array_equal(layer, topographic_layer(heights, shadow_strength=0.6, device="cpu").image)
    topographic_layer(heights, shadows=False, device="cpu")


def test_the_degrees_warning_points_at_the_callers_line():
    # a fixed stacklevel pointed into stepterrain/texture.py when topographic_layer reached the azimuth check
    import stepterrain.texture as tx

    heights = np.add.outer(np.arange(12.0), np.arange(14.0)) * 3.0
    calls = [lambda: tx.topographic_layer(heights, azimuth=315.0),
             lambda: tx.hillshade(heights, azimuth=315.0),
             lambda: tx.hillshade(heights, method="maplibre-multidirectional", azimuth=[1.0, 270.0]),
             lambda: tx.cast_shadows(heights, azimuth=-400.0, altitude=0.7)]
    for call in calls:
        with pytest.warns(UserWarning, match="azimuth is in radians") as record:
            call()
        assert {w.filename for w in record if "radians" in str(w.message)} == {__file__}


# ------------------------------------------------------------------------------------------ layout symmetry
def _layouts(heights, spacing):
    """The same terrain as four arrays (rows and columns as given, or reversed with dy / dx negated), with the
    function that brings a result back to the first layout."""
    dx, dy = spacing
    return [(heights, (dx, dy), lambda r: r),
            (heights[::-1].copy(), (dx, -dy), lambda r: r[::-1]),
            (heights[:, ::-1].copy(), (-dx, dy), lambda r: r[:, ::-1]),
            (heights[::-1, ::-1].copy(), (-dx, -dy), lambda r: r[::-1, ::-1])]


@given(
    heights=arrays(np.float32, hst.tuples(hst.integers(2, 16), hst.integers(2, 16)),
                   elements=hst.one_of(hst.integers(0, 60).map(float), hst.just(np.nan))),
    directions=hst.integers(1, 24),
    spacing=hst.sampled_from([(1.0, 1.0), (30.0, 30.0), (2.0, 0.5), (0.7, 1.3)]),
)
def test_occlusion_does_not_depend_on_which_way_the_rows_and_columns_run_property(heights, directions, spacing):
    """ambient_occlusion of one terrain laid out north-up (dy < 0) and south-up, or with its columns reversed
    (dx < 0), differed by up to 0.05-0.15: the sweep lines were anchored at major index 0 (the other edge of the
    terrain in the flipped layout) and rounded floor(x + 1/2), so the two layouts walked different nodes. The lines
    are now anchored at the middle and rounded symmetrically (and the distances measured from the grid's centre).
    A mirrored terrain gives the mirror image when the directions are symmetric: transposed with non-square
    pixels it did not (sin(π/2 − a) and cos(a) differ in the last bit, and a line rounded at a tie took other
    nodes); the directions' vectors are now mirror-exact (texture.compass)."""
    results = [back(ambient_occlusion(z, directions=directions, spacing=s, device="cpu"))
               for z, s, back in _layouts(heights, spacing)]
    # the terrain mirrored (not the same terrain): the mirror image where the directions map onto themselves
    results.append(ambient_occlusion(heights[:, ::-1].copy(), directions=directions, spacing=spacing,
                                     device="cpu")[:, ::-1])
    if directions % 2 == 0:
        results.append(ambient_occlusion(heights[::-1].copy(), directions=directions, spacing=spacing,
                                         device="cpu")[::-1])
    if directions % 4 == 0:  # transposed, its spacing swapped: mirrored across a diagonal
        results.append(ambient_occlusion(heights.T.copy(), directions=directions, spacing=spacing[::-1],
                                         device="cpu").T)
    for other in results[1:]:
        np.testing.assert_allclose(other, results[0], atol=1e-6)
    np.testing.assert_allclose(results[0], occlusion_reference(heights, spacing, directions), atol=2e-5)


@given(
    heights=arrays(np.float32, hst.tuples(hst.integers(2, 16), hst.integers(2, 16)),
                   elements=hst.integers(0, 50).map(float)),
    azimuth=hst.floats(0, 360),
    altitude=hst.floats(1, 80),
    spacing=hst.sampled_from([(1.0, 1.0), (30.0, 30.0), (2.0, 0.5), (0.7, 1.3)]),
)
def test_shadows_do_not_depend_on_which_way_the_rows_and_columns_run_property(heights, azimuth, altitude,
                                                                               spacing):
    """cast_shadows from a light that is neither axis-aligned nor diagonal (300° on a north-up raster: 2403 of
    52000 nodes of Big Tujunga) differed between the layouts of one terrain, and hillshade(shadows=True) with it."""
    az, alt = RAD(azimuth), RAD(altitude)
    results = [back(cast_shadows(z, azimuth=az, altitude=alt, spacing=s, device="cpu"))
               for z, s, back in _layouts(heights, spacing)]
    for other in results[1:]:
        np.testing.assert_array_equal(other, results[0])
    np.testing.assert_array_equal(results[0], shadows_reference(heights, spacing, az, alt))


def test_real_terrain_shades_alike_north_up_south_up_and_mirrored():
    """Big Tujunga north-up against south-up and with columns reversed: occlusion, shadows (lights off the axes
    and diagonals) and igor / multidirectional hillshades with shadows agree; a mirrored terrain (rows reversed,
    dy kept) is shadowed from the mirrored azimuth (180° - θ; -θ for columns, 90° - θ transposed) as the mirror
    image, and its occlusion is the mirror image when the directions are symmetric (transposed: a multiple of 4)."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=90, step=2)[:, :70]
    spacing = (60.0, -60.0)
    for directions in (16, 7):
        results = [back(ambient_occlusion(z, directions=directions, spacing=s, device="cpu"))
                   for z, s, back in _layouts(heights, spacing)]
        for other in results[1:]:
            np.testing.assert_allclose(other, results[0], atol=1e-6)
    for azimuth in (20.0, 100.3, 300.0, 333.0):
        az = RAD(azimuth)
        results = [back(cast_shadows(z, azimuth=az, altitude=RAD(20), spacing=s, device="cpu"))
                   for z, s, back in _layouts(heights, spacing)]
        assert results[0].sum() > 100
        for other in results[1:]:
            np.testing.assert_array_equal(other, results[0])
        mirrored = [cast_shadows(heights[::-1].copy(), azimuth=math.pi - az, altitude=RAD(20), spacing=spacing,
                                 device="cpu")[::-1],
                    cast_shadows(heights[:, ::-1].copy(), azimuth=-az, altitude=RAD(20), spacing=spacing,
                                 device="cpu")[:, ::-1],
                    cast_shadows(heights.T.copy(), azimuth=math.pi / 2 - az, altitude=RAD(20),
                                 spacing=spacing[::-1], device="cpu").T]
        for other in mirrored:
            np.testing.assert_array_equal(other, results[0])
    for method, light in (("igor", {"azimuth": 2.0}), ("multidirectional", {"altitude": 0.4})):
        results = [back(hillshade(z, method=method, shadows=True, spacing=s, device="cpu", **light))
                   for z, s, back in _layouts(heights, spacing)]
        for other in results[1:]:
            np.testing.assert_array_equal(other, results[0])
    ao = ambient_occlusion(heights, directions=16, spacing=(60.0, 60.0), device="cpu")
    for other in (ambient_occlusion(heights[::-1].copy(), directions=16, spacing=(60.0, 60.0), device="cpu")[::-1],
                  ambient_occlusion(heights.T.copy(), directions=16, spacing=(60.0, 60.0), device="cpu").T):
        np.testing.assert_allclose(other, ao, atol=1e-6)


@pytest.mark.parametrize("directions", [8, 16])
def test_occlusion_of_a_mirrored_terrain_is_its_mirror_image_on_non_square_pixels(directions):
    """Big Tujunga on 60 x 15 m pixels (89 x 69 nodes) mirrored north-south or across a diagonal (transposed, the
    spacing swapped): the occlusion was not the mirror image (up to 0.19): the direction at 2π k/n and its mirror
    image took sin and cos that differ in the last bit (sin(π/2 − a) against cos(a)), and the digital lines of
    slope ¼ · tan 45° rounded their ties apart. The directions' vectors are now exact mirror images (compass)."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=90, step=2)[:89, :69]
    spacing = (60.0, 15.0)
    ao = ambient_occlusion(heights, directions=directions, spacing=spacing, device="cpu")
    mirrored = [ambient_occlusion(heights[::-1].copy(), directions=directions, spacing=spacing, device="cpu")[::-1],
                ambient_occlusion(heights[:, ::-1].copy(), directions=directions, spacing=spacing,
                                  device="cpu")[:, ::-1],
                ambient_occlusion(heights.T.copy(), directions=directions, spacing=spacing[::-1], device="cpu").T]
    for other in mirrored:
        np.testing.assert_allclose(other, ao, atol=1e-6)
    np.testing.assert_allclose(ao, occlusion_reference(heights, spacing, directions), atol=2e-5)


def test_an_image_extent_in_gdals_order_is_refused_with_the_numbers_in_ours(tmp_path, capsys):
    """--image-extent takes xmin,xmax,ymin,ymax; GDAL's -te and rasterio's bounds give xmin,ymin,xmax,ymax. Big
    Tujunga's bounds typed in that order placed a 120 x 64 PNG over a 3400 km box (an easting to a northing, each
    way) and draped the pixel or two over the DEM, a smear, without a word. Refused now, naming our order and the
    same box in it, whose pixels are square; that box drapes the whole image, and an image extent a few times the
    DEM's in the right order is kept."""
    import re

    from PIL import Image

    from stepterrain import cli

    from .conftest import shared_file

    source = str(shared_file("big_tujunga_srtm_30m_utm11n.tif"))
    rng = np.random.default_rng(3)
    image = tmp_path / "map.png"
    Image.fromarray(rng.integers(0, 256, (64, 120, 3), dtype=np.uint8)).save(image)
    out = tmp_path / "t.png"
    gdal = "376328.66,3788642.83,412208.66,3807902.83"  # xmin,ymin,xmax,ymax of the DEM
    argv = ["-q", "texture", source, "--image", str(image), "-o", str(out)]
    assert cli.main([*argv, "--image-extent", gdal]) == 2
    err = capsys.readouterr().err
    assert "not GDAL's -te xmin,ymin,xmax,ymax" in err and not out.exists(), err
    ours = re.search(r"that box is --image-extent=(\S+)", err).group(1)
    assert ours == "376328.66,412208.66,3788642.83,3807902.83"
    assert cli.main([*argv, "--image-extent", ours]) == 0
    with Image.open(out) as texture:  # the image's many colours, not a pixel or two smeared over the DEM
        assert len(np.unique(np.asarray(texture.convert("RGB")).reshape(-1, 3), axis=0)) > 100_000  # the smear: 12661
    out.unlink()
    assert cli.main([*argv, "--image-extent", "340000,450000,3760000,3830000"]) == 0 and out.exists()


# ------------------------------------------------------------------------------------------ writing big textures
def _png_encodes(monkeypatch) -> list[tuple[int, int]]:
    """The (width, height) of every image Pillow deflates as PNG from here on (``Image.SAVE['PNG']`` wrapped)."""
    from PIL import Image

    Image.init()
    original = Image.SAVE["PNG"]
    sizes: list[tuple[int, int]] = []

    def counting(im, fp, filename, *args, **kwargs):
        sizes.append(im.size)
        return original(im, fp, filename, *args, **kwargs)

    monkeypatch.setitem(Image.SAVE, "PNG", counting)
    return sizes


def _hill(tmp_path, name: str = "hill.npy", hole: bool = False) -> str:
    """A 40 x 50 Gaussian hill 100 m high saved as ``tmp_path/name`` (a nodata block at rows 10-14, columns 20-29 with
    ``hole``); its path as a string."""
    i, j = np.meshgrid(np.arange(40), np.arange(50), indexing="ij")
    heights = (100 * np.exp(-((i - 20) ** 2 + (j - 25) ** 2) / 80.0)).astype(np.float32)
    if hole:
        heights[10:15, 20:30] = np.nan
    np.save(tmp_path / name, heights)
    return str(tmp_path / name)


def test_a_large_png_is_deflated_with_z_rle_and_decodes_to_the_same_pixels(tmp_path, monkeypatch):
    """save_image deflates a PNG of more than export._FAST_PNG_PIXELS pixels with zlib's Z_RLE strategy (about 4x
    faster than the default level 6: 29-31 s of a 77 M texel texture's 38 s went to deflating it): the file decodes
    to exactly the image given; a smaller one is written byte for byte as Pillow's default writes it."""
    import io

    from PIL import Image

    from stepterrain import export

    monkeypatch.setattr(export, "_FAST_PNG_PIXELS", 5000, raising=False)
    rng = np.random.default_rng(3)
    big = (np.cumsum(rng.integers(0, 3, (90, 80, 4)), axis=1) % 256).astype(np.uint8)
    small = big[:50, :50, :3]
    for image, fast in ((big, True), (small, False)):
        out = export.save_image(image, tmp_path / f"{image.shape[0]}.png")
        with Image.open(out) as picture:
            assert np.array_equal(np.asarray(picture), image)
        default = io.BytesIO()
        Image.fromarray(image).save(default, format="PNG")
        rle = io.BytesIO()
        Image.fromarray(image).save(rle, format="PNG", compress_type=3)
        assert out.read_bytes() == (rle if fast else default).getvalue()


def test_cli_texture_glb_takes_the_written_pngs_bytes_instead_of_deflating_the_texture_again(tmp_path, monkeypatch):
    """stepterrain texture -o tex.png --mesh out.glb (--texel-size, a large texture): the texture was deflated twice,
    for the PNG and again inside trimesh's glTF writer (at zlib's default). It is deflated once: the GLB embeds the
    PNG file's bytes; its image decodes to the texture, and the GLB validates. A texture no PNG file holds is
    deflated once for a GLB, by save_mesh with the large-PNG settings (Z_RLE), not again by trimesh."""
    from PIL import Image

    from stepterrain import export
    from stepterrain.cli import main

    from . import gltf_validator

    monkeypatch.setattr(export, "_FAST_PNG_PIXELS", 5000, raising=False)
    dem = _hill(tmp_path)
    sizes = _png_encodes(monkeypatch)
    out, glb = tmp_path / "tex.png", tmp_path / "out.glb"
    assert main(["texture", dem, "--spacing", "30", "--texel-size", "10", "-o", str(out),
                 "--mesh", str(glb), "--device", "cpu"]) == 0
    with Image.open(out) as picture:
        texture = np.asarray(picture)
    assert texture.shape == (120, 150, 3)
    assert sizes == [(150, 120)]  # the -o file alone
    embedded = trimesh.load(glb, force="mesh").visual.material.baseColorTexture
    assert np.array_equal(np.asarray(embedded), texture)
    assert out.read_bytes() in glb.read_bytes()
    ok, _ = gltf_validator.available()
    if ok:
        assert gltf_validator.problems(gltf_validator.validate([glb])) == []
    textured = trimesh.load(glb, force="mesh")
    keyed = Image.fromarray(texture)  # the file's pixels, but its PNG carries a transparent colour: not the file's
    keyed.info["transparency"] = tuple(int(v) for v in texture[0, 0])
    textured.visual.material.baseColorTexture = keyed
    sizes.clear()
    export.save_mesh(textured, tmp_path / "keyed.glb")
    assert sizes == [(150, 120)] and out.read_bytes() not in (tmp_path / "keyed.glb").read_bytes()
    # its transparent colour kept as alpha (written as RGBA, the colour under it filled: see
    # test_texture_transparent_fill), the other texels as they are
    keyed_back = trimesh.load(tmp_path / "keyed.glb", force="mesh").visual.material.baseColorTexture
    keyed_back = np.asarray(keyed_back.convert("RGBA"))
    hidden = (texture == texture[0, 0]).all(axis=-1)
    assert hidden.any() and not hidden.all()
    np.testing.assert_array_equal(keyed_back[..., 3], np.where(hidden, 0, 255))
    np.testing.assert_array_equal(keyed_back[~hidden][:, :3], texture[~hidden])
    export._LAST_PNG.clear()  # a texture no PNG holds: deflated once for the GLB, with Z_RLE
    sizes.clear()
    textured = trimesh.load(glb, force="mesh")
    export.save_mesh(textured, tmp_path / "again.glb")
    assert sizes == [(150, 120)]
    again = trimesh.load(tmp_path / "again.glb", force="mesh").visual.material.baseColorTexture
    assert np.array_equal(np.asarray(again), texture)


def test_composed_pair_gives_the_rgba_and_the_rgb_over_a_background_of_two_passes_in_one(monkeypatch):
    """texture._composed_pair (a DEM with nodata, `stepterrain texture --mesh/--png`: the RGBA file and the drape's RGB
    over white, which the command composed in two kernel passes, 8 s each at 77 M texels) gives, from one pass of
    compose_texture, the bytes _composed gives RGBA and over the background: shading with a nodata hole, colours,
    pictures sampled (part transparent, part half) or on the grid, on the node grid and 3 x 3 texels a node."""
    from stepterrain import texture as tx

    rng = np.random.default_rng(11)
    heights = np.cumsum(rng.normal(size=(23, 31)), axis=0) * 5.0 + np.linspace(0, 40, 31)
    heights[8:12, 10:15] = np.nan
    topo = tx.topographic_layer(heights, spacing=(30.0, -30.0), shadows=True, device="cpu")
    colours = tx.terrain_layer(heights, rng.random((23, 31, 4)).astype(np.float32), spacing=(30.0, -30.0))
    extent = topo.extent
    sampled = rng.integers(0, 256, (40, 50, 4), dtype=np.uint8)
    sampled[:10, :, 3] = 0
    sampled[20:25, :, 3] = 128
    inside = (extent[0] + 100, extent[1] - 200, extent[2] + 50, extent[3] - 40)
    launches = []
    original = tx.launch

    def counting(kernel, *args, **kwargs):
        launches.append(kernel.key)
        return original(kernel, *args, **kwargs)

    for fine in (1, 3):
        shape = (23 * fine, 31 * fine)
        own = rng.integers(0, 256, (*shape, 4), dtype=np.uint8)
        own[:5, :, 3] = 0
        for picture in (None, tx.TextureLayer("thematic", sampled, inside), tx.TextureLayer("thematic", own, extent)):
            for hypsometric in (None, colours):
                for over in ((1.0, 1.0, 1.0), (0.2, 0.5, 0.9)):
                    monkeypatch.setattr(tx, "launch", counting)
                    launches.clear()
                    rgba, rgb = tx._composed_pair(topo, hypsometric, picture, extent, shape, None, over, "cpu")
                    assert launches == ["compose_texture"]
                    monkeypatch.setattr(tx, "launch", original)
                    assert np.array_equal(rgba, tx._composed(topo, hypsometric, picture, extent, shape, None, "cpu"))
                    assert np.array_equal(rgb, tx._composed(topo, hypsometric, picture, extent, shape, over, "cpu"))


def test_cli_texture_of_a_dem_with_nodata_composes_once_for_the_file_and_the_drape(tmp_path, monkeypatch):
    """stepterrain texture over a DEM with nodata, -o and --mesh: the RGBA texture and the drape's RGB over white came
    from two passes of compose_texture (8 s each at 77 M texels); one now. The GLB's texture is the file's RGB where
    it is opaque and white over the nodata hole (alpha 0), as before."""
    from PIL import Image

    from stepterrain import texture as tx
    from stepterrain.cli import main

    dem = _hill(tmp_path, "holes.npy", hole=True)
    launches = []
    original = tx.launch

    def counting(kernel, *args, **kwargs):
        launches.append(kernel.key)
        return original(kernel, *args, **kwargs)

    monkeypatch.setattr(tx, "launch", counting)
    out, glb = tmp_path / "tex.png", tmp_path / "out.glb"
    assert main(["texture", dem, "--spacing", "30", "-o", str(out), "--mesh", str(glb),
                 "--device", "cpu"]) == 0
    assert launches.count("compose_texture") == 1
    with Image.open(out) as picture:
        rgba = np.asarray(picture)
    assert rgba.shape == (40, 50, 4) and set(np.unique(rgba[..., 3])) == {0, 255}
    embedded = np.asarray(trimesh.load(glb, force="mesh").visual.material.baseColorTexture)
    assert embedded.shape == (40, 50, 3)
    opaque = rgba[..., 3] == 255
    assert np.array_equal(embedded[opaque], rgba[..., :3][opaque])
    assert (embedded[~opaque] == 255).all()


def test_cli_texture_obj_side_image_is_the_written_pngs_bytes(tmp_path, monkeypatch):
    """stepterrain texture -o tex.png --mesh out.obj (a large texture): trimesh's to_obj deflated the texture again
    for the OBJ's side image, at zlib's default. It is deflated once: the side image is the -o file's bytes, and
    decodes to the texture; a texture no PNG file holds is deflated once, with the large-PNG settings."""
    import io

    from PIL import Image

    from stepterrain import export
    from stepterrain.cli import main

    monkeypatch.setattr(export, "_FAST_PNG_PIXELS", 5000, raising=False)
    dem = _hill(tmp_path)
    sizes = _png_encodes(monkeypatch)
    out, obj = tmp_path / "tex.png", tmp_path / "out.obj"
    assert main(["texture", dem, "--spacing", "30", "--texel-size", "10", "-o", str(out),
                 "--mesh", str(obj), "--device", "cpu"]) == 0
    assert sizes == [(2, 2), (150, 120)]  # the 2 x 2 stand-in whose side files are checked before any work, once
    (side,) = [p for p in tmp_path.glob("out_*.png")]
    assert side.read_bytes() == out.read_bytes()
    with Image.open(out) as picture:
        texture = np.asarray(picture)
    mesh = trimesh.load(tmp_path / "out.obj", force="mesh")
    assert np.array_equal(np.asarray(mesh.visual.material.image.convert("RGB")), texture)
    export._LAST_PNG.clear()
    sizes.clear()
    export.save_mesh(mesh, tmp_path / "again.obj")
    assert sizes == [(150, 120)]
    rle = io.BytesIO()
    Image.fromarray(texture).save(rle, format="PNG", compress_type=3)
    (again,) = [p for p in tmp_path.glob("again_*.png")]
    assert again.read_bytes() == rle.getvalue()


def test_cli_pngs_no_mesh_takes_are_not_hashed_and_keep_the_texture_for_the_mesh(tmp_path, monkeypatch):
    """save_image hashed every large PNG (0.3 s at 77 M texels) so that a later GLB or OBJ could take its bytes, also
    the CLI's PNGs no mesh drapes: `texture -o tex.png` alone, its --normals map (which, written after the texture,
    also displaced it: the GLB deflated the texture again), a --png render. Those are not hashed now; the texture a
    --mesh drapes is, and the GLB takes its bytes (decoding to the texture) with a --normals PNG written between."""
    from PIL import Image

    from stepterrain import export
    from stepterrain.cli import main

    monkeypatch.setattr(export, "_FAST_PNG_PIXELS", 5000, raising=False)
    dem = _hill(tmp_path)
    hashed = []
    digest = export._pixels_digest

    def counting(picture, *args, **kwargs):
        hashed.append(picture.size)
        return digest(picture, *args, **kwargs)

    monkeypatch.setattr(export, "_pixels_digest", counting)
    export._LAST_PNG.clear()
    out, normals = tmp_path / "tex.png", tmp_path / "normals.png"
    assert main(["texture", dem, "--spacing", "30", "--texel-size", "10", "-o", str(out),
                 "--normals", str(normals), "--device", "cpu"]) == 0
    assert hashed == [] and export._LAST_PNG == []
    glb = tmp_path / "out.glb"
    assert main(["texture", dem, "--spacing", "30", "--texel-size", "10", "-o", str(out),
                 "--normals", str(normals), "--mesh", str(glb), "--device", "cpu"]) == 0
    assert hashed == [(150, 120), (150, 120)]  # the texture once written, its drape once asked
    assert export._LAST_PNG[0][1] == out.absolute()
    assert out.read_bytes() in glb.read_bytes()
    with Image.open(out) as picture:
        texture = np.asarray(picture)
    embedded = trimesh.load(glb, force="mesh").visual.material.baseColorTexture
    assert np.array_equal(np.asarray(embedded), texture)


@pytest.mark.parametrize("kind, dtype, shape", [("thematic", np.uint8, (600, 500, 3)),
                                                 ("thematic", np.float32, (600, 500, 4)),
                                                 ("luminance", np.uint8, (600, 500))])
def test_rgba_allocates_no_more_than_its_budget_check_counted(monkeypatch, kind, dtype, shape):
    """TextureLayer.rgba() checked 16 bytes a pixel (the float32 RGBA) against the memory budget, then made a float32
    copy of the image, its scaled copy and a copy of every finite pixel for their range: 62 bytes a pixel at its peak
    (a 3000² layer checked as 137 MiB took 532 MiB). The image now goes straight into the RGBA's channels and the range
    is read in place; its peak (numpy's allocations, traced) stays within what the check counted, and the RGBA is
    the same."""
    import tracemalloc

    import stepterrain.texture as texture

    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, shape).astype(np.uint8) if dtype == np.uint8 else rng.random(shape, np.float32)
    image.setflags(write=False)
    counted = budget_counts(monkeypatch, texture)
    layer = TextureLayer(kind, image, (0, 500, 0, 600))
    tracemalloc.start()
    try:
        out = layer.rgba()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(counted) == 1  # checked once, before anything was allocated
    assert peak <= counted[0], f"rgba() allocated {peak:,} bytes at its peak; its check counted {counted[0]:,}"
    scaled = image.astype(np.float32) / 255.0 if dtype == np.uint8 else image
    expected = np.ones((600, 500, 4), np.float32)
    if kind == "thematic":
        expected[..., : shape[2]] = scaled
    else:
        expected[..., :3] = scaled[..., None]
    np.testing.assert_array_equal(out, expected)


# ------------------------------------------------------------------------------------------ texture wrap
def _two_edge_drape():
    """A flat 512 x 512 terrain draped with a texture whose west 32 columns are red, east 32 blue, green between."""
    from stepterrain import heightfield_mesh
    from stepterrain.texture import drape

    image = np.zeros((512, 512, 3), np.uint8)
    image[:] = (40, 160, 40)
    image[:, :32] = (220, 30, 30)
    image[:, -32:] = (30, 30, 220)
    mesh = heightfield_mesh(np.zeros((33, 33)), spacing=(16.0, 16.0))
    return drape(mesh, TextureLayer("thematic", image, (-8.0, 520.0, -8.0, 520.0)))


def test_a_terrain_drape_s_texture_is_clamped_at_its_edges(tmp_path):
    """A terrain drape's UVs lie inside its image, but trimesh writes no glTF sampler, so viewers repeated the image
    (glTF's default) and, in the coarse mip levels, blended the terrain's border with the opposite border's texels.
    The drape's material now asks for CLAMP_TO_EDGE both ways: the GLB's and glTF's texture get that sampler (valid
    glTF), and read_mesh gives it back (trimesh's reader ignores samplers), so a mesh read back is written again
    with it."""
    import json
    import struct

    from stepterrain.export import read_mesh, save_mesh

    from . import gltf_validator

    textured = _two_edge_drape()
    assert textured.visual.material.wrap == ("CLAMP_TO_EDGE", "CLAMP_TO_EDGE")

    def sampler(path):
        data = path.read_bytes()
        if path.suffix == ".glb":
            data = data[20 : 20 + struct.unpack_from("<I", data, 12)[0]]
        tree = json.loads(data)
        (texture,) = tree["textures"]
        return tree["samplers"][texture["sampler"]]

    paths = []
    for name in ("terrain.glb", "terrain.gltf"):
        path = save_mesh(textured, tmp_path / name)
        assert sampler(path) == {"wrapS": 33071, "wrapT": 33071}
        back = read_mesh(path)
        assert back.visual.material.wrap == ("CLAMP_TO_EDGE", "CLAMP_TO_EDGE")
        again = save_mesh(back, tmp_path / f"again_{name}")
        assert sampler(again) == {"wrapS": 33071, "wrapT": 33071}
        paths += [path, again]
    if gltf_validator.available()[0]:
        assert gltf_validator.problems(gltf_validator.validate(paths)) == []


@needs_render
@pytest.mark.parametrize("renderer", ["render_textured_mesh", "render_mesh"])
def test_a_terrain_drape_renders_its_borders_in_their_own_colours(renderer):
    """Seen from low over its south edge (the far part foreshortened: a coarse mip level), the drape's west border
    (red) showed up to a third blue and its east border (blue) a third red: the render repeated the texture, so the
    coarse mip levels' edge texels blended with the opposite edge's. Clamped, each border keeps its own colour (a
    share of the other of 30 / 250, as the pure colour has, or a little more from the green beside it)."""
    import stepterrain.render as render

    kwargs = {"lighting": False} if renderer == "render_textured_mesh" else {}
    picture = getattr(render, renderer)(_two_edge_drape(), window_size=(200, 200), camera=(math.pi, 0.12),
                                        background="black", **kwargs).astype(int)
    drawn = picture.sum(axis=2) > 30
    west, east = [], []
    for row in np.flatnonzero(drawn.any(axis=1)):
        cols = np.flatnonzero(drawn[row])
        if len(cols) >= 6:
            west.append(picture[row, cols[0]])
            east.append(picture[row, cols[-1]])
    west, east = np.array(west), np.array(east)
    assert len(west) > 10  # the rows the terrain covers, seen from low
    assert (west[:, 2] / (west[:, 0] + west[:, 2])).max() < 0.2  # blue in the red border: 0.33 repeated
    assert (east[:, 0] / (east[:, 0] + east[:, 2])).max() < 0.2


def test_the_texture_command_s_mesh_clamps_its_texture(tmp_path):
    """``stepterrain texture --mesh`` drapes its DEM as drape does: its GLB's texture repeated (no sampler) and
    blended the terrain's borders with the opposite ones in the coarse mip levels; it now has a clamping sampler."""
    import json
    import struct

    from stepterrain.cli import main

    dem = tmp_path / "hill.npy"
    np.save(dem, np.arange(30 * 40, dtype=np.float32).reshape(30, 40) % 17)
    glb = tmp_path / "t.glb"
    assert main(["texture", str(dem), "-o", str(tmp_path / "t.png"), "--mesh", str(glb), "--device", "cpu"]) == 0
    data = glb.read_bytes()
    tree = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    (texture,) = tree["textures"]
    assert tree["samplers"][texture["sampler"]] == {"wrapS": 33071, "wrapT": 33071}
# ------------------------------------------------------------------------------------------ Cesium's adjustment order
@pytest.mark.parametrize("grey, params, expected", [
    # CesiumJS (GlobeFS.glsl sampleAndBlend, since 1.53) raises the sampled colour to 1/gamma first, then brightness:
    # 0.5^(1/2) * 0.5, not (0.5 * 0.5)^(1/2) = 0.5 as with gamma last
    (0.5, dict(brightness=0.5, gamma=2.0), 0.5 ** 0.5 * 0.5),
    # brightness past 1 clamped at the end (the framebuffer's clamp), after gamma: 0.25^(1/2) * 3 = 1.5 -> 1
    (0.25, dict(brightness=3.0, gamma=2.0), 1.0),
    # gamma then contrast: 0.5 + (0.25^(1/2) - 0.5) * 1.5 = 0.5 (gamma last: (0.125)^(1/2) = 0.354)
    (0.25, dict(contrast=1.5, gamma=2.0), 0.5),
])
def test_adjust_applies_gamma_first_as_cesium_does(grey, params, expected):
    """adjust() applied gamma last (after brightness, contrast, hue and saturation, as CesiumJS did before 1.53),
    while its docstring promised Cesium's order: CesiumJS applies ``pow(color, 1/gamma)`` to the sampled colour first,
    so a layer with brightness or contrast and gamma set came out other than in Cesium (grey 0.5 with brightness 0.5,
    gamma 2: 0.354 in Cesium, 0.5 here)."""
    layer = TextureLayer("thematic", np.full((2, 3, 3), grey, np.float32), (0.0, 3.0, 0.0, 2.0))
    out = adjust(layer, device="cpu", **params).rgba()
    np.testing.assert_allclose(out[..., :3], expected, atol=1e-6)
    np.testing.assert_allclose(out[..., 3], 1.0)


# ------------------------------------------------------------------------------------------ contour layer's memory
def test_a_contour_layer_over_the_memory_budget_is_refused_before_it_is_allocated():
    """contour_layer's float32 RGBA is 16 bytes a texel, and texel_size multiplies the texels (a 30 m DEM drawn at
    0.1 m: 90 000 texels a node): the library function, not only ``stepterrain texture --contours``, refuses a layer
    over the memory budget with an OutputTooLargeError naming the size and the way out, before allocating it."""
    import tracemalloc

    import stepterrain as st
    from stepterrain.texture import contour_layer

    ramp = np.add.outer(np.arange(20.0), np.arange(30.0)).astype(np.float32)
    terrain = st.Terrain.from_heights(ramp, spacing=(30.0, -30.0))
    with pytest.raises(st.OutputTooLargeError, match=r"the 9000000 x 6000000 float32 RGBA contour layer would need "
                                                     r".* over the memory budget .*give a larger texel_size"):
        contour_layer(terrain, interval=5.0, texel_size=1e-4, device="cpu")  # 5.4e13 texels: 786 TiB
    previous = st.set_memory_budget(1 << 20)
    try:
        tracemalloc.start()
        with pytest.raises(st.OutputTooLargeError, match=r"the 900 x 600 float32 RGBA contour layer .* 8\.2 MiB"):
            contour_layer(terrain, interval=5.0, texel_size=1.0, device="cpu")  # 900 x 600 texels: 8.2 MiB
        assert tracemalloc.get_traced_memory()[1] < 1 << 20  # refused before the 8.2 MiB were allocated
        tracemalloc.stop()
        layer = contour_layer(terrain, interval=5.0, texel_size=3.0, device="cpu")  # 300 x 200 texels: 938 KiB
    finally:
        tracemalloc.stop()
        st.set_memory_budget(previous)
    assert layer.shape == (200, 300) and layer.image.nbytes == 16 * 200 * 300
    assert (layer.image[..., 3] > 0.5).any()


@pytest.mark.parametrize("width, index_width, base, every", [
    (1.0, 2.0, 0.0, 5),
    (0.4, 3.0, 0.3, 3),
    (3.0, 1.0, -2.0, 1),
    (2e29, 2e29, 0.0, 2),  # wider than the far-line skip handles (level_distance caps at 1e30): never skipped
    (1.0, 2.0, -2.0**54, 4),  # a base 2^52 lines away: the same lines as from the base a whole period from it
    (1.0, 2.0, 0.0, 2**31 - 1),
])
def test_contour_lines_on_a_ramp_follow_the_documented_coverage(width, index_width, base, every):
    """draw_contours skips a line too far to cover a texel before dividing, and tests index lines with a reciprocal:
    on a ramp (0.75 height units a texel) every texel's alpha is still the documented box coverage of the nearer
    levels' lines, ``d = |h - level| / |grad h|`` texels away, the wider and darker index lines where k divides."""
    from stepterrain.texture import contour_layer

    rows, cols = 5, 90
    heights = np.tile((0.75 * np.arange(cols)).astype(np.float32), (rows, 1))
    layer = contour_layer(heights, interval=4.0, base=base, width=width, index_width=index_width,
                          color=(0.2, 0.4, 0.6, 0.9), index_color=(0.1, 0.1, 0.1, 0.7), index_every=every,
                          device="cpu")
    h = heights[2, 1:-1].astype(np.float64)  # interior texels: the central difference is 0.75
    # the levels base + k * 4 and their index lines from the base nearest 0 a whole period (4 * every) away: from
    # -2^54 itself (h - base) / 4 lost the heights' fraction of a level (every height rounded onto one)
    near = math.fmod(base, 4.0 * every) if abs(base) >= 4.0 * every else base
    q = (h - near) / 4.0
    k = np.floor(q)
    alpha = np.zeros_like(h)
    for line, gap in ((k, (q - k) * 4.0), (k + 1.0, (k + 1.0 - q) * 4.0)):
        index = (line - every * np.floor(line / every)) == 0
        half = np.where(index, index_width / 2, width / 2).astype(np.float32)
        d = np.minimum((gap / np.float64(np.float32(0.75))).astype(np.float32), np.float32(1e30))
        cover = np.clip(np.minimum(d + half, np.float32(0.5)) - np.maximum(d - half, np.float32(-0.5)), 0, 1)
        alpha = np.maximum(alpha, cover * np.where(index, np.float32(0.7), np.float32(0.9)))
    np.testing.assert_allclose(layer.image[2, 1:-1, 3], alpha, atol=1e-6)
    assert (layer.image[2, 1:-1, 3] > 0).any()
    if width < 1e28 and abs(base) < 1e9:  # (past 2^52 in float64 every height rounds onto a level)
        assert (layer.image[2, 1:-1, 3] == 0).any()  # texels far from any line: the skip ran


@pytest.mark.parametrize("base, interval, every", [(-1e17, 7.3, 3), (1e16, 3.3, 9), (-1e17, 3.7, 0)])
def test_contour_lines_from_a_far_base_lie_on_its_levels_when_the_period_is_not_a_float(base, interval, every):
    """A base far from the heights is taken a whole number of periods (interval * index_every) nearer: that period
    rounded in float64 (7.3 * 3) and math.fmod reduced by the rounded one, moving every level by up to ulp(base)
    (0.85 of an interval at 1e17: lines off their levels, index lines among the others). The reference is exact:
    each texel's line numbers (h - base) / interval in rational arithmetic."""
    from fractions import Fraction

    from stepterrain.texture import contour_layer

    heights = np.tile((0.75 * np.arange(90)).astype(np.float32), (5, 1))
    layer = contour_layer(heights, interval=interval, base=base, width=1.0, index_width=2.0, index_every=every,
                          color=(0.2, 0.4, 0.6, 0.9), index_color=(0.1, 0.1, 0.1, 0.7), device="cpu")
    alpha = []
    for h in heights[2, 1:-1]:  # interior texels: the central difference is 0.75
        q = (Fraction(float(h)) - Fraction(base)) / Fraction(interval)
        k = math.floor(q)
        best = np.float32(0.0)
        for line, gap in ((k, (q - k) * Fraction(interval)), (k + 1, (k + 1 - q) * Fraction(interval))):
            index = every > 0 and line % every == 0
            half = np.float32(1.0 if index else 0.5)
            d = np.float32(float(gap) / 0.75)
            cover = np.clip(min(d + half, np.float32(0.5)) - max(d - half, np.float32(-0.5)), 0, 1)
            best = max(best, cover * np.float32(0.7 if index else 0.9))
        alpha.append(best)
    np.testing.assert_allclose(layer.image[2, 1:-1, 3], alpha, atol=1e-5)
    assert (layer.image[2, 1:-1, 3] == 0).any() and (layer.image[2, 1:-1, 3] > 0.5).any()


def test_contour_index_lines_past_2_51_lines_from_the_base():
    """Line numbers k past 2^51 take index_lines' division (is_index_line), not its reciprocal: the case of
    test_contour_lines_on_a_ramp_follow_the_documented_coverage that reached it (base -2^54) is now reduced to a base
    near 0, so heights 2^53 and up (k = 2^51 + j * 2^28 at interval 4, float32 and float64 exact) keep it run. Every
    texel lies on its line k (the next, k + 1, as close in texels on this slope): the index colour, more opaque,
    where 3 divides k or k + 1, worked out in Python's integers."""
    from stepterrain.texture import contour_layer

    j = np.arange(40)
    row = (2.0**53 + j * 2.0**30).astype(np.float32)
    assert np.array_equal(row.astype(np.float64), 2.0**53 + j * 2.0**30)
    layer = contour_layer(np.tile(row, (5, 1)), interval=4.0, index_every=3, color=(0.2, 0.4, 0.6, 0.5),
                          index_color=(0.1, 0.1, 0.1, 1.0), device="cpu")
    k = [(2**53 + int(n) * 2**30) // 4 for n in j[1:-1]]
    want = np.array([line % 3 == 0 or (line + 1) % 3 == 0 for line in k])
    assert want.any() and not want.all()
    np.testing.assert_array_equal(layer.image[2, 1:-1, 3] == 1.0, want)
    np.testing.assert_allclose(layer.image[2, 1:-1, 3][~want], 0.5, atol=1e-6)


def test_contour_lines_shift_with_heights_and_base_together():
    """Heights and base moved together by an amount float32 and float64 keep exact draw the same texels: a base
    within reach of the heights is used as given. It was taken a period (7.3 * 3) at a time towards 0 whenever it
    was a period from 0, and the rounding of that reduced base put a height exactly on a level (1198 m, base
    1234.5 m) just below it: the line below was drawn instead of the one above, an index line's colour over 710
    texels of the sample DEM."""
    from stepterrain import sample_dem
    from stepterrain.texture import contour_layer

    heights = np.asarray(sample_dem().heights, dtype=np.float32)
    shifted = heights - np.float32(1234.5)  # whole metres minus 1234.5: exact
    assert np.array_equal(shifted.astype(np.float64), heights.astype(np.float64) - 1234.5)
    given = contour_layer(heights, interval=7.3, base=1234.5, index_every=3, device="cpu").image
    moved = contour_layer(shifted, interval=7.3, base=0.0, index_every=3, device="cpu").image
    assert 0.05 < given[..., 3].mean() < 0.95
    np.testing.assert_array_equal(given, moved)


@pytest.mark.parametrize("combine_with", ["blend", "modulate", "weighted_add"])
def test_a_layer_over_another_extent_is_resampled_at_any_pixel_size(combine_with):
    """Whether a layer is already the pixel grid it combines on was an absolute test of the texture matrices (1e-9),
    whose entries scale as 1 / pixel size: with pixels 10^9 units wide a layer of the same shape over twice the
    extent passed it and was read pixel for pixel, as if over the grid's extent. Scaling the world changes nothing."""
    values = np.tile(np.array([0.0, 0.25, 0.5, 1.0], np.float32), (2, 1))
    outs = []
    for unit in (1.0e3, 1.0e9):  # the pixel size of the grid
        a = TextureLayer("thematic", np.full((2, 4, 3), 0.5, np.float32), (0, 4 * unit, 0, 2 * unit))
        b = TextureLayer("luminance", values, (0, 8 * unit, 0, 4 * unit), border="edge")
        if combine_with == "blend":
            out = blend(a, b, np.ones((2, 4), np.float32), device="cpu")
        elif combine_with == "modulate":
            out = modulate(a, b, device="cpu")
        else:
            out = weighted_add([a, b], [0.0, 1.0], device="cpu")
        outs.append(out.rgba())
    np.testing.assert_allclose(outs[1], outs[0], atol=1e-6)
    assert not np.allclose(outs[0][..., 0], np.broadcast_to(values, (2, 4)) * (0.5 if combine_with == "modulate"
                                                                               else 1.0))


@pytest.mark.parametrize("weights", [(1.0e39, 1.0), (1.0, -1.0e39)])
def test_weights_beyond_float32_are_refused_not_added_as_nan(weights):
    """weighted_add's weights reach the kernel as float32: 1e39 became inf, and inf times a zero channel NaN, clamped
    to 0: 1e39 · 0 + 1 · 0.5 came out 0 instead of 0.5, without a word."""
    black = TextureLayer("thematic", np.zeros((2, 2, 3), np.float32), (0, 2, 0, 2))
    grey = np.full((2, 2, 3), 0.5, np.float32)
    with pytest.raises(InvalidInputError, match=r"weights\[\d\] must lie in \[-3\.40282e\+38, 3\.40282e\+38\]; got"):
        weighted_add([black, grey], weights, device="cpu")
    # the largest float32 weight still adds as float32 does: 3.4e38 · 0 + 1 · 0.5
    out = weighted_add([black, grey], (float(np.finfo(np.float32).max), 1.0), device="cpu").rgba()
    np.testing.assert_allclose(out[..., :3], 0.5)


@pytest.mark.parametrize("pixel, shape, origin, nudged", [
    (1.0e-3, (1, 16384), (5.0e5, 9.9e6), False),  # the grid's own matrix: its corners round by 1e-6 texel
    (1.0e-4, (512, 512), (-2.0e7, 1.0e7), True),  # one ulp off in the scale: 2e-5 texel at the corner, float64's grain
])
def test_a_layer_on_the_grid_is_read_as_it_is_at_fine_pixels_far_from_the_origin(pixel, shape, origin, nudged):
    """The corner test of _is_grid (within 1e-6 texel) took float64's rounding of the corners for a mismatch: at mm
    pixels near a UTM false northing a layer over the grid itself was resampled, its texels off by up to 1e-3."""
    rows, cols = shape
    extent = (origin[0], origin[0] + cols * pixel, origin[1], origin[1] + rows * pixel)
    matrix = TextureLayer("luminance", np.zeros(shape, np.float32), extent).matrix.copy()
    if nudged:
        matrix[0, 0] = np.nextafter(matrix[0, 0], np.inf)
    values = np.random.default_rng(5).uniform(0.0, 1.0, (rows, cols, 3)).astype(np.float32)
    a = TextureLayer("thematic", np.zeros((rows, cols, 3), np.float32), extent)
    b = TextureLayer("thematic", values, extent, matrix=matrix)
    out = weighted_add([a, b], [0.0, 1.0], device="cpu").rgba()
    np.testing.assert_array_equal(out[..., :3], values)


@pytest.mark.parametrize("order", [(0, 1, 2, 3, 4), (4, 0, 2, 1, 3), (0, 2, 1, 3, 4)])
def test_huge_weights_that_cancel_add_the_same_in_any_order(order):
    """weighted_add summed Σ w_k · layer_k pairwise in float32: weights near float32's top that cancel (3e38, 3e38,
    −3e38, −3e38) on one layer overflowed the running sum to inf, and inf − 3e38 stayed inf, clamped to 1: a sum of
    0.5 · 0.8 came out white, and with the 0.5 · grey term first black (3e38 · shade swallowed it), without a word.
    Such sums now run in float64, compensated: no partial sum overflows and exactly cancelling terms leave the rest."""
    shade = hillshade(real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", 48, 4), spacing=(120.0, 120.0), device="cpu")
    grey = np.full(shade.shape + (3,), 0.8, np.float32)
    extent = (0.0, 48.0, 0.0, 48.0)
    a = TextureLayer("thematic", np.repeat(shade[..., None], 3, axis=2), extent)
    b = TextureLayer("thematic", grey, extent)
    pairs = [(a, 3e38), (a, 3e38), (a, -3e38), (a, -3e38), (b, 0.5)]
    out = weighted_add([pairs[k][0] for k in order], [pairs[k][1] for k in order], device="cpu").rgba()
    np.testing.assert_allclose(out[..., :3], 0.4, atol=1e-6)  # 3e38 · s cancels exactly: 0.5 · 0.8 is left
    np.testing.assert_allclose(out[..., 3], 0.5, atol=1e-6)  # alpha: 3e38 · 1 cancels too, 0.5 · 1
    # within float32 the pairwise float32 sum is kept as it was, bit for bit (1 + 1 − 1.5, clamped last)
    assert np.array_equal(weighted_add([a, a, b], [1.0, 1.0, -1.5], device="cpu").rgba(),
                          np.clip(np.float32(2.0) * a.rgba() - np.float32(1.5) * b.rgba(), 0.0, 1.0))


@pytest.mark.parametrize("power", [-80, 60])
def test_occlusion_of_a_terrain_scaled_by_a_power_of_two_is_the_same(power):
    """Ambient occlusion depends only on the terrain's shape: scaled as a whole (heights and spacing) it is the same.
    Its kernel took sin(horizon) = rise / sqrt(rise² + run²) in float32 world units: at 2^-80 (heights 1e-21 m,
    spacing 1e-23 m) rise² + run² underflowed to 0 and the occlusion came out −inf; at 2^60 (heights 1e21 m) it
    overflowed to inf, sin 0, and the valleys came out 1 (open). By a power of two the scaling is exact in float32."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", 40, 3)
    heights[10:14, 20:23] = np.nan  # nodata stays NaN
    spacing = (90.0, -90.0)
    ref = ambient_occlusion(heights, spacing=spacing, directions=8, device="cpu")
    k = 2.0 ** power
    scaled = ambient_occlusion(heights * np.float32(k), spacing=(spacing[0] * k, spacing[1] * k), directions=8,
                               device="cpu")
    assert np.nanmin(ref) < 0.9 and np.isnan(ref[10:14, 20:23]).all()  # valleys are occluded
    np.testing.assert_array_equal(scaled, ref)


@pytest.mark.parametrize("power", [-90, -80])
def test_a_point_light_on_a_tiny_terrain_shades_as_on_the_terrain_scaled_up(power):
    """relight's point light depends on the scene's shape only: the terrain, its spacing and the light scaled
    together by a power of two shade the same. The kernel normalized the texel-to-light vector in float32: at
    2^-90 (spacing 2.4e-26 m) its squared length underflowed, and texels came out lit wrongly, up to 0.5 off."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", 40, 3)
    spacing, light = (90.0, -90.0), (1800.0, -1500.0, float(np.nanmax(heights)) + 400.0)
    normals = normal_map(heights, spacing=spacing, device="cpu")
    ref = relight(normals, point=light, terrain=heights, spacing=spacing, device="cpu")
    k = 2.0 ** power
    scaled = relight(normals, point=tuple(c * k for c in light), terrain=heights * np.float32(k),
                     spacing=(spacing[0] * k, spacing[1] * k), device="cpu")
    assert 0.2 < np.nanmean(ref) < 0.95
    np.testing.assert_allclose(scaled, ref, atol=1e-6)


@pytest.mark.parametrize("order", [(0, 1, 2), (2, 0, 1)])
def test_huge_weights_that_are_one_float32_cancel_as_the_kernel_takes_them(order):
    """The weights are taken as float32 (the kernel's), so 3e38 and float32(3e38) = 3.0000000054977558e38 are one
    weight: w · layer − w · layer cancels. The float64 sum took them as given: their difference, 5.5e30 · shade,
    turned the 0.5 · 0.8 under it white (main, summing in float32, gave 0.4). A float32 weight times a float32
    channel is exact in float64, so the sum does not depend on how a device fuses its products and additions."""
    shade = hillshade(real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", 48, 4), spacing=(120.0, 120.0), device="cpu")
    extent = (0.0, 48.0, 0.0, 48.0)
    a = TextureLayer("thematic", np.repeat(shade[..., None], 3, axis=2), extent)
    b = TextureLayer("thematic", np.full(shade.shape + (3,), 0.8, np.float32), extent)
    assert float(np.float32(3e38)) != 3e38 and (shade > 0.1).mean() > 0.9
    pairs = [(a, float(np.float32(3e38))), (a, -3e38), (b, 0.5)]
    out = weighted_add([pairs[k][0] for k in order], [pairs[k][1] for k in order], device="cpu").rgba()
    np.testing.assert_allclose(out[..., :3], 0.4, atol=1e-6)
    np.testing.assert_allclose(out[..., 3], 0.5, atol=1e-6)


# ------------------------------------------------------------------------------------------ masked arrays
def _masked_ortho():
    """An 'orthophoto' of the Big Tujunga crop (its hillshade as uint8 RGB) as rasterio's ``read(masked=True)`` gives
    one, bands moved last: a nodata collar of zeros masked along the west and north edges."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=40, step=3)
    shade = hillshade(heights, spacing=(90.0, -90.0), device="cpu")
    rgb = np.repeat(np.round(shade * 254 + 1).astype(np.uint8)[..., None], 3, axis=2)
    collar = np.zeros(rgb.shape[:2], dtype=bool)
    collar[:, :6] = True
    collar[:4] = True
    rgb[collar] = 0
    return heights, rgb, collar, np.ma.masked_array(rgb, mask=np.repeat(collar[..., None], 3, axis=2))


def test_masked_array_layers_take_the_mask_as_nodata():
    """A numpy masked array as a layer's image (an orthophoto read with rasterio's masked=True, a hillshade masked
    where it has no data): its masked pixels are nodata (transparent), as a masked array's masked heights are.
    np.asarray dropped the mask: the collar's zeros were drawn opaque black (black over the background in the drape),
    and a float image whose masked entries hold a fill value (1e20) was refused as out of [0, 1]."""
    _, rgb, collar, ortho = _masked_ortho()
    extent = (0.0, 40.0, 0.0, 40.0)
    layer = TextureLayer("thematic", ortho, extent)
    rgba = layer.rgba()
    assert (rgba[collar, 3] == 0).all()
    assert (rgba[~collar, 3] == 1).all()
    assert np.array_equal(rgba[~collar], TextureLayer("thematic", rgb, extent).rgba()[~collar])
    # the drape composites it over the background: white on the collar, not the black under the mask
    mesh = trimesh.Trimesh([[1.0, 1.0, 0.0], [39.0, 1.0, 0.0], [1.0, 39.0, 0.0]], [[0, 1, 2]], process=False)
    picture = np.asarray(drape(mesh, layer).visual.material.baseColorTexture)
    assert (picture[collar] == 255).all() and np.array_equal(picture[~collar], rgb[~collar])
    # stepterrain texture's one-pass composite reads a uint8 picture on its grid as bytes: the mask through rgba()
    from stepterrain import texture as tx

    shading = TextureLayer("luminance", np.ones(rgb.shape[:2], np.float32), extent)
    composed = tx._composed(shading, None, layer, extent, rgb.shape[:2], (1.0, 1.0, 1.0), "cpu")
    assert np.array_equal(composed, picture)
    # a float luminance layer masked where it holds a fill value
    shade = np.ma.masked_array(rgb[..., 0] / 255.0, mask=collar)
    shade.data[collar] = 1e20
    lum = TextureLayer("luminance", shade, extent).rgba()
    assert (lum[collar, 3] == 0).all() and np.allclose(lum[~collar, 0], rgb[~collar, 0] / 255.0)


def test_masked_arrays_as_operation_arguments_and_on_terrain_nodes():
    """A masked array given where an operation takes an array (blend's b and weights, terrain_layer's image on the
    nodes, turned north-up): its mask is the layer's nodata, so a masked weight or colour leaves ``a`` as it is."""
    heights, rgb, collar, ortho = _masked_ortho()
    a = TextureLayer("thematic", np.full((*rgb.shape[:2], 3), 0.25, np.float32), (0.0, 40.0, 0.0, 40.0))
    out = blend(a, ortho, device="cpu").rgba()
    assert np.allclose(out[collar, :3], 0.25) and np.allclose(out[~collar, 0], rgb[~collar, 0] / 255.0)
    weights = np.ma.masked_array(np.ones(rgb.shape[:2]), mask=collar)
    out = blend(a, np.ones((*rgb.shape[:2], 3)), weights, device="cpu").rgba()
    assert np.allclose(out[collar, :3], 0.25) and np.allclose(out[~collar, :3], 1.0)
    # on the nodes of a grid with dy > 0: row 0 is the south edge, the layer's row 0 the north one
    layer = terrain_layer(heights, ortho, spacing=(90.0, 90.0))
    assert np.array_equal(layer.rgba()[..., 3] == 0, collar[::-1])


def test_masked_array_pyramid_and_image_layer_get_alpha():
    """ImagePyramid.build and image_layer of a masked uint8 array: alpha 0 at its masked pixels (an alpha channel
    added to RGB), so the collar is transparent over the terrain and its zeros do not darken the coarser levels; the
    mask was dropped and the collar drawn black."""
    from stepterrain.texture_lod import ImagePyramid, image_layer

    from .reference_texture import reduce_rounded_reference

    heights, rgb, collar, ortho = _masked_ortho()
    with ImagePyramid.build(ortho, device="cpu") as pyramid:
        level0 = np.asarray(pyramid.levels[0])
        assert level0.shape == (*rgb.shape[:2], 4)
        assert np.array_equal(level0[..., 3], np.where(collar, 0, 255)) and np.array_equal(level0[..., :3], rgb)
        assert np.array_equal(pyramid.levels[1], reduce_rounded_reference(level0))
    layer = image_layer(ortho, heights, extent=(-0.5, 39.5, -0.5, 39.5), device="cpu")  # a pixel a node
    assert layer.shape == rgb.shape[:2] and np.array_equal(layer.image[..., 3] == 0, collar)


def test_contour_layer_texel_size_too_small_to_count_is_refused_by_name():
    """contour_layer(texel_size=1e-320): its texels a side overflow float64 (inf), and math.ceil raised an
    OverflowError; now an InvalidInputError naming texel_size (a small finite count is left to the budget check)."""
    from stepterrain.texture import contour_layer

    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=20, step=3)
    with pytest.raises(InvalidInputError, match=r"texel_size must be a positive size that cuts the terrain's "
                                                r"1800 x 1800 texture extent into a finite number of texels; "
                                                r"got 9.99989e-321"):
        contour_layer(heights, interval=50.0, spacing=(90.0, -90.0), texel_size=1e-320, device="cpu")


def test_blend_weights_as_a_mask():
    """blend's weights as a mask over the Big Tujunga hillshade (where the ground lies above its median): a bool mask
    weighs 1 where True; it was refused (a layer takes no bools), and the way out, mask.astype(np.uint8), weighed 1/255
    (uint8 is 0-255): b all but invisible, without a word. A uint8 array of 0 and 1 only is warned about, naming
    weights, and weighed as given: a faint 0-255 weight image (a fade's first frame, 1 everywhere) may be just that,
    and was refused. A masked uint8 array masking every pixel weighs nothing (int() of its maximum, np.ma.masked,
    raised a MaskError)."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=48, step=2)
    shade = hillshade(heights, spacing=(60.0, -60.0), device="cpu")
    mask = heights > np.median(heights)
    a = TextureLayer("luminance", shade, (0.0, 48.0, 0.0, 48.0))
    b = np.zeros((48, 48, 3), np.float32)
    out = blend(a, b, mask, device="cpu").rgba()
    assert np.allclose(out[mask, :3], 0.0) and np.allclose(out[~mask, 0], shade[~mask])
    faint = np.where(mask, np.float32(1 / 255), np.float32(0))
    for ones, weight in ((mask.astype(np.uint8), faint),  # a 0/1 mask
                         (np.ones((48, 48), np.uint8), np.full((48, 48), np.float32(1 / 255)))):  # a fade's 1st frame
        with pytest.warns(UserWarning, match=r"weights is a uint8 array of 0 and 1 only: uint8 weights are 0-255, "
                                             r"so 1 weighs 1/255") as record:
            got = blend(a, b, ones, device="cpu").rgba()
        assert record[0].filename == __file__  # pointed at the caller
        assert np.array_equal(got, blend(a, b, weight, device="cpu").rgba())
    full = blend(a, b, mask.astype(np.uint8) * 255, device="cpu").rgba()  # 0-255 as before
    assert np.array_equal(full, out)
    hidden = np.ma.masked_array(np.ones((48, 48), np.uint8), mask=True)
    assert np.array_equal(blend(a, b, hidden, device="cpu").rgba(), a.rgba())


@pytest.mark.parametrize("cached", [False, True])
@pytest.mark.parametrize("background", [None, (1.0, 0.5, 0.0)])
def test_to_uint8_stays_within_its_budget_check(monkeypatch, cached, background):
    """``to_uint8`` composited the whole layer at once: RGB times alpha, one minus alpha, the background times it, their
    sum, its clip, times 255 and its rounding (12 to 16 bytes a texel each) on top of the RGBA that ``rgba`` checked as
    22 bytes a texel, so a layer that passed the check took 54 (drape's texture, a draped GLB's). It composes by bands
    of rows now and checks what it keeps (the RGBA unless cached, the uint8 image, a band's temporaries); its peak
    (numpy's allocations, traced) stays within what it counted, and the bytes are those of the one-pass formula."""
    import tracemalloc

    import stepterrain.texture as texture

    rng = np.random.default_rng(5)
    image = rng.random((600, 500, 4), np.float32)
    image[..., 3] = np.where(rng.random((600, 500)) < 0.3, 1.0, image[..., 3])
    layer = TextureLayer("thematic", image, (0, 500, 0, 600))
    rgba = layer.rgba() if cached else np.array(layer.rgba())
    if not cached:
        layer = TextureLayer("thematic", image, (0, 500, 0, 600))
    counted = budget_counts(monkeypatch, texture)
    tracemalloc.start()
    try:
        out = layer.to_uint8(background=background)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert counted and peak <= max(counted), f"to_uint8 allocated {peak:,} bytes at its peak; it counted {counted}"
    if background is None:
        expected = np.round(rgba * 255.0).astype(np.uint8)
    else:
        bg = np.asarray(background, np.float32).reshape(1, 1, 3)
        rgb = rgba[..., :3] * rgba[..., 3:] + bg * (1.0 - rgba[..., 3:])
        expected = np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)
    np.testing.assert_array_equal(out, expected)


def _operation_layers(n=300):
    """Three fresh (writeable, so uncached) 300 x 300 layers over one extent: RGB, RGBA and a visibility layer."""
    rng = np.random.default_rng(11)
    extent = (0.0, float(n), 0.0, float(n))
    return (TextureLayer("thematic", rng.random((n, n, 3), np.float32), extent),
            TextureLayer("thematic", rng.random((n, n, 4), np.float32), extent),
            TextureLayer("visibility", rng.random((n, n), np.float32), extent))


_OPERATIONS = {
    "blend": lambda a, b, w: texture_ops.blend(a, b, w, device="cpu"),
    "modulate": lambda a, b, w: texture_ops.modulate(a, b, w, device="cpu"),
    "weighted_add": lambda a, b, w: texture_ops.weighted_add([a, b, w], [0.3, 0.3, 0.4], device="cpu"),
    "weighted_add wide": lambda a, b, w: texture_ops.weighted_add([a, b, w], [3e38, -3e38, 0.4], device="cpu"),
    "adjust": lambda a, b, w: texture_ops.adjust(a, brightness=1.5, device="cpu"),
    "pipeline": lambda a, b, w: texture_ops.Pipeline().blend(b, w).modulate(w).apply(a, device="cpu"),
}


@pytest.mark.parametrize("name", list(_OPERATIONS))
def test_layer_operations_check_what_they_allocate(name):
    """blend, modulate, weighted_add and adjust (and a Pipeline of them) allocate 16 bytes a texel for their output,
    for each layer resampled onto its grid and for a chain's previous result, besides their layers' RGBA, but only
    each layer's RGBA was checked, one at a time (22 bytes a texel): blend of three fresh layers took 64 bytes a texel
    of a budget of 30. Now each operation checks the whole before allocating: over the budget it refuses, naming the
    operation, and at the size it counted it runs."""
    import stepterrain as st

    operation = _OPERATIONS[name]
    texels = 300 * 300
    previous = st.set_memory_budget(30 * texels)  # above every layer's RGBA check, below what the call allocates
    try:
        with pytest.raises(st.OutputTooLargeError, match=r"would need .* over the memory budget of 2\.6 MiB"):
            operation(*_operation_layers())
        with pytest.MonkeyPatch.context() as patch:
            counted = budget_counts(patch, texture_ops)
            st.set_memory_budget(1 << 40)
            reference = operation(*_operation_layers()).rgba()
        st.set_memory_budget(max(counted))  # exactly what it counted: runs
        out = operation(*_operation_layers()).rgba()
    finally:
        st.set_memory_budget(previous)
    np.testing.assert_array_equal(out, reference)


def test_drape_checks_its_texture_coordinates(monkeypatch):
    """drape checked the layer's image (its RGBA, the uint8 texture) but not the texture coordinates, whose making took
    72 bytes a vertex (a float64 copy of the vertices, the texels, their columns and the UVs): a 770 000-vertex stepped
    mesh under a 2.7 MiB texture took 55 MiB. drape now checks them with the texture before making either; its peak
    (numpy's allocations, traced) stays within the largest check, and at a budget below it the drape is refused."""
    import tracemalloc

    import stepterrain as st
    from stepterrain.texture import drape, topographic_layer

    terrain = st.sample_dem().coarsen(2)
    mesh = st.stepped(terrain, levels=12)
    layer = topographic_layer(terrain, device="cpu")
    layer.rgba()  # cached: what is counted below is drape's own
    counted = budget_counts(monkeypatch, texture_ops)
    tracemalloc.start()
    try:
        out = drape(mesh, layer)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert counted and peak <= max(counted), f"drape allocated {peak:,} bytes at its peak; it counted {counted}"
    np.testing.assert_array_equal(out.visual.uv, texture_ops.texture_uv(mesh.vertices, layer))
    previous = st.set_memory_budget(peak // 2)
    try:
        with pytest.raises(st.OutputTooLargeError, match=r"texture coordinates .* would need"):
            drape(mesh, layer)
    finally:
        st.set_memory_budget(previous)


_TOPOGRAPHIC = {
    "hillshade": lambda t: texture_ops.hillshade(t, device="cpu"),
    "hillshade maplibre": lambda t: texture_ops.hillshade(t, method="maplibre-standard", device="cpu"),
    "cast_shadows": lambda t: texture_ops.cast_shadows(t, device="cpu"),
    "ambient_occlusion": lambda t: texture_ops.ambient_occlusion(t, directions=4, device="cpu"),
    "normal_map": lambda t: texture_ops.normal_map(t, device="cpu"),
    "topographic_layer": lambda t: texture_ops.topographic_layer(t, device="cpu"),
    "topographic_layer occlusion": lambda t: texture_ops.topographic_layer(t, occlusion=0.5, device="cpu"),
}


@pytest.mark.parametrize("name", list(_TOPOGRAPHIC))
def test_topographic_functions_check_the_budget(name):
    """hillshade, cast_shadows, ambient_occlusion, normal_map and topographic_layer checked nothing: a DEM loaded
    within the budget (4 bytes a node) made a hillshade of 4.5 bytes a node (16.4 with a MapLibre method's RGBA), an
    occlusion of 11.2 and a topographic layer of 13.7 (28.2 with occlusion), as peak RSS. Each now checks its bytes a
    node before allocating: a budget one byte below them refuses it, naming the DEM's size; at them it runs, with the
    result it gives under the default budget."""
    import stepterrain as st

    terrain = st.sample_dem().coarsen(4)
    rows, cols = terrain.heights.shape
    operation = _TOPOGRAPHIC[name]
    reference = operation(terrain)
    with pytest.MonkeyPatch.context() as patch:
        counted = budget_counts(patch, texture_ops)
        operation(terrain)
    assert counted and max(counted) >= np.asarray(getattr(reference, 'image', reference)).nbytes  # what it keeps
    previous = st.set_memory_budget(max(counted) - 1)
    try:
        with pytest.raises(st.OutputTooLargeError, match=rf"of a {cols} x {rows} DEM would need"):
            operation(terrain)
        st.set_memory_budget(max(counted))
        out = operation(terrain)
    finally:
        st.set_memory_budget(previous)
    np.testing.assert_array_equal(out.image if hasattr(out, "image") else out,
                                  reference.image if hasattr(reference, "image") else reference)
