"""MapLibre GL's hillshade methods (``hillshade(method="maplibre-...")``): the Warp kernel against a plain NumPy
transcription of MapLibre's fragment shader, tilted planes against the analytic value, and the methods' relation
to GDAL's (issue 5 §3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

from stepterrain.errors import InvalidInputError
from stepterrain.texture import MAPLIBRE_METHODS, hillshade

from .reference_texture import hillshade_reference, lambert, maplibre_reference
from .reference_texture import real_dem_crop as real_dem

RAD = math.radians
SHADOW = (0.2, 0.1, 0.4, 0.8)  # straight alpha, as given to hillshade()
HIGHLIGHT = (1.0, 0.9, 0.6, 0.7)
ACCENT = (0.3, 0.5, 0.2, 0.9)


def premultiplied(colour) -> np.ndarray:
    c = np.asarray(colour, dtype=np.float64)
    return np.append(c[:3] * c[3], c[3])


def tilted(a, b, spacing, rows=7, cols=8):
    dx, dy = spacing
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return (a * j * dx + b * i * dy).astype(np.float32)


def analytic(method, a, b, azimuths, altitudes, exaggeration, shadows, highlights, accent):
    """A plane of gradient (a, b) (east, north) in geometric terms: the angle between its normal and the light,
    the angle between the light's azimuth and the plane's downhill azimuth, and its slope."""
    sh, hi, ac = (premultiplied(c) for c in (shadows[0], highlights[0], accent))
    downhill = math.atan2(-a, -b)  # compass bearing of steepest descent

    def turn(azimuth):  # |angle between the light's azimuth and the downhill azimuth| in [0, pi]
        return abs((azimuth - downhill + math.pi) % (2 * math.pi) - math.pi)

    def cos_incidence(s, azimuth, altitude):
        normal = np.array([-s * a, -s * b, 1.0]) / math.sqrt(1 + s * s * (a * a + b * b))
        light = np.array([math.sin(azimuth) * math.cos(altitude), math.cos(azimuth) * math.cos(altitude),
                          math.sin(altitude)])
        return float(normal @ light)

    def two_tone(cos_i, shadow, highlight):
        shade = min(max(cos_i, 0.0), 1.0)
        return highlight * (2 * shade - 1) if shade > 0.5 else shadow * (1 - 2 * shade)

    s = 2 * exaggeration
    slope = math.atan(s * math.hypot(a, b))
    if method == "maplibre-standard":  # exaggeration 0.5: the slope is not eased
        assert exaggeration == 0.5
        slope = math.atan(0.625 * math.hypot(a, b))
        facing = 1 - turn(azimuths[0]) / math.pi  # 1 facing the light, 0 facing away
        shade = (sh * (1 - facing) + hi * facing) * math.sin(slope)
        return (1 - math.cos(slope)) * ac * (1 - shade[3]) + shade
    if method == "maplibre-basic":
        return two_tone(cos_incidence(s, azimuths[0], altitudes[0]), sh, hi)
    if method == "maplibre-multidirectional":
        colours = [(premultiplied(x), premultiplied(y)) for x, y in zip(shadows, highlights, strict=True)]
        lights = zip(azimuths, altitudes, colours, strict=True)
        return np.mean([two_tone(cos_incidence(s, az, alt), *c) for az, alt, c in lights], axis=0)
    if method == "maplibre-combined":
        angle = min(math.acos(cos_incidence(s, azimuths[0], altitudes[0])), math.pi / 2)
        return (sh * angle + hi * (math.pi / 2 - angle)) * slope / (math.pi / 2) ** 2
    away = turn(azimuths[0]) / math.pi  # igor: 0 facing the light, 1 facing away
    return slope / (math.pi / 2) * (sh * away + hi * (1 - away))


PLANES = [(0.3, -0.2), (0.0, 0.5), (-0.7, 0.0), (1.2, 0.9)]


@pytest.mark.parametrize("method", MAPLIBRE_METHODS)
@pytest.mark.parametrize("spacing", [(2.0, 3.0), (2.0, -3.0)])
def test_tilted_plane_equals_analytic(device, method, spacing):
    multi = method == "maplibre-multidirectional"
    exaggeration = 0.5 if method == "maplibre-standard" else 0.35
    for (a, b), (az, alt) in zip(PLANES, [(315, 45), (90, 30), (200, 70), (0, 20)], strict=True):
        azimuths = [RAD(az), RAD(az + 100), RAD(az + 215)] if multi else [RAD(az)]
        altitudes = [RAD(alt), RAD(60), RAD(15)] if multi else [RAD(alt)]
        shadows = [SHADOW, (0.0, 0.0, 0.3, 1.0), (0.5, 0.5, 0.5, 0.4)] if multi else [SHADOW]
        highlights = [HIGHLIGHT, (1.0, 1.0, 1.0, 1.0), (0.9, 0.2, 0.1, 0.6)] if multi else [HIGHLIGHT]
        got = hillshade(tilted(a, b, spacing), spacing=spacing, method=method,
                        azimuth=azimuths if multi else azimuths[0], altitude=altitudes if multi else altitudes[0],
                        exaggeration=exaggeration, shadow_color=shadows if multi else SHADOW,
                        highlight_color=highlights if multi else HIGHLIGHT, accent_color=ACCENT, device=device)
        expected = analytic(method, a, b, azimuths, altitudes, exaggeration, shadows, highlights, ACCENT)
        np.testing.assert_allclose(got[1:-1, 1:-1], np.broadcast_to(expected, got[1:-1, 1:-1].shape), atol=2e-5,
                                   err_msg=f"{method} plane {(a, b)} light {(az, alt)}")


@pytest.mark.parametrize("method", MAPLIBRE_METHODS)
@pytest.mark.parametrize("exaggeration", [0.2, 0.5, 1.0])
def test_matches_shader_reference_on_real_dem(device, method, exaggeration):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=3)
    heights[5, 7] = np.nan
    multi = method == "maplibre-multidirectional"
    azimuths, altitudes = ([RAD(335), RAD(45), RAD(150)], [RAD(45), RAD(30)]) if multi else ([RAD(335)], [RAD(40)])
    shadows = [SHADOW, (0.1, 0.2, 0.6)] if multi else [SHADOW]
    ours = hillshade(heights, spacing=(90.0, -90.0), z_factor=2.0, method=method,
                     azimuth=azimuths if multi else azimuths[0], altitude=altitudes if multi else altitudes[0],
                     exaggeration=exaggeration, shadow_color=shadows if multi else SHADOW, highlight_color=HIGHLIGHT,
                     accent_color=ACCENT, device=device)
    ref = maplibre_reference(heights, (90.0, -90.0), method.removeprefix("maplibre-"), azimuths, altitudes,
                             exaggeration, [premultiplied(c if len(c) == 4 else (*c, 1.0)) for c in shadows],
                             [premultiplied(HIGHLIGHT)], premultiplied(ACCENT), z_factor=2.0)
    assert ours.shape == (*heights.shape, 4) and ours.dtype == np.float32
    assert np.isnan(ours[5, 7]).all() and not np.isnan(np.delete(ours.reshape(-1, 4), 5 * 40 + 7, 0)).any()
    np.testing.assert_allclose(ours, ref, atol=2e-5)


def test_defaults_are_the_style_spec_colours(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=4)
    for method in MAPLIBRE_METHODS:
        ours = hillshade(heights, spacing=(120.0, -120.0), method=method, device=device)
        ref = maplibre_reference(heights, (120.0, -120.0), method.removeprefix("maplibre-"))
        np.testing.assert_allclose(ours, ref, atol=2e-5, err_msg=method)


# ------------------------------------------------------------------------- relation to GDAL's methods
def test_basic_over_grey_is_gdal_standard(device):
    """MapLibre's note: basic with a white highlight and a black shadow over grey is GDAL's standard shade,
    here with the z factor 2 * exaggeration."""
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=3)
    rgba = hillshade(heights, spacing=(90.0, -90.0), method="maplibre-basic", exaggeration=0.3, device=device)
    over_grey = rgba[..., :3] + 0.5 * (1 - rgba[..., 3:])
    gdal = hillshade(heights, spacing=(90.0, -90.0), method="standard", z_factor=0.6, device=device)
    # the interior: beyond the border MapLibre repeats the edge, gdaldem -compute_edges extrapolates
    np.testing.assert_allclose(over_grey[1:-1, 1:-1], np.repeat(gdal[1:-1, 1:-1, None], 3, axis=-1), atol=3e-6)


def test_igor_and_combined_shadows_are_gdal_with_a_highlight(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=3)
    low = RAD(10)  # a low sun: some slopes face away from it
    kw = dict(spacing=(90.0, -90.0), exaggeration=1.0, altitude=low, highlight_color=(0, 0, 0, 0), device=device)
    gdal_kw = dict(spacing=(90.0, -90.0), z_factor=2.0, altitude=low, device=device)
    inner = (slice(1, -1), slice(1, -1))  # MapLibre repeats the edge beyond the border, gdaldem extrapolates
    igor = hillshade(heights, method="maplibre-igor", **kw)[inner]
    igor_kw = {k: v for k, v in gdal_kw.items() if k != "altitude"}  # gdaldem -igor takes no altitude (refused)
    np.testing.assert_allclose(igor[..., 3], 1 - hillshade(heights, method="igor", **igor_kw)[inner], atol=3e-6)
    combined = hillshade(heights, method="maplibre-combined", **kw)[inner]
    gdal = hillshade(heights, method="combined", **gdal_kw)[inner]
    # MapLibre clamps the angle between normal and light at 90 degrees, GDAL does not
    facing = hillshade_reference(heights, (90.0, -90.0), altitude=low, z_factor=2.0)[inner] > 0
    assert 0 < facing.sum() < facing.size
    np.testing.assert_allclose(combined[..., 3][facing], 1 - gdal[facing], atol=3e-6)
    assert (combined[..., 3][~facing] < 1 - gdal[~facing] + 1e-6).all()


def test_multidirectional_with_one_light_is_basic(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=4)
    kw = dict(spacing=(120.0, -120.0), shadow_color=SHADOW, highlight_color=HIGHLIGHT, device=device)
    np.testing.assert_allclose(hillshade(heights, method="maplibre-multidirectional", azimuth=[RAD(100)], **kw),
                               hillshade(heights, method="maplibre-basic", azimuth=RAD(100), **kw), atol=1e-7)


def test_flat_terrain(device):
    flat = np.zeros((5, 6), np.float32)
    assert np.all(hillshade(flat, method="maplibre-standard", device=device) == 0)  # no slope, no colour
    # basic: a flat shade sin(30 deg) = 0.5 is the transparent middle
    np.testing.assert_allclose(hillshade(flat, method="maplibre-basic", altitude=RAD(30), device=device), 0,
                               atol=1e-7)
    assert np.all(hillshade(flat, method="maplibre-igor", device=device) == 0)


@given(arrays(np.float32, (6, 7), elements=hst.floats(-50, 50, width=32)),
       hst.sampled_from(MAPLIBRE_METHODS), hst.floats(0, 1), hst.floats(0, 2 * math.pi), hst.floats(0, math.pi / 2))
@settings(max_examples=25)
def test_premultiplied_rgba_in_range(heights, method, exaggeration, azimuth, altitude):
    rgba = hillshade(heights, method=method, exaggeration=exaggeration, azimuth=azimuth, altitude=altitude,
                     shadow_color=SHADOW, highlight_color=HIGHLIGHT, accent_color=ACCENT, device="cpu")
    assert np.all(np.isfinite(rgba))
    assert rgba.min() >= -1e-6 and rgba[..., 3].max() <= 1 + 1e-6
    assert np.all(rgba[..., :3] <= rgba[..., 3:] + 1e-6)  # a premultiplied colour never exceeds its alpha


# ------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("kwargs,match", [
    (dict(method="maplibre-basic", shadows=True), "shadows=True applies to the grey methods"),
    (dict(method="maplibre-basic", exaggeration=1.5), r"exaggeration must lie in \[0, 1\]"),
    (dict(method="maplibre-basic", shadow_color=(1.2, 0, 0)), r"shadow_color components must lie in \[0, 1\]"),
    (dict(method="maplibre-basic", accent_color="black"), "accent_color must be an RGB or RGBA colour"),
    (dict(method="maplibre-igor", highlight_color=[(1, 1, 1), (0, 0, 0)]), "highlight_color must be .* got 2"),
    (dict(method="maplibre-basic", azimuth=[1.0, 2.0]), "a sequence only with method='maplibre-multidirectional'"),
    (dict(method="maplibre-multidirectional", altitude=[0.5, 2.0]), "altitude must lie in"),
    (dict(method="maplibre-multidirectional", azimuth=[]), "at least one angle"),
    (dict(method="standard", exaggeration=0.5), "exaggeration applies to the MapLibre methods"),
    (dict(method="maplibre-hypsometric"), "method must be one of .*maplibre-standard"),
])
def test_bad_input(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        hillshade(np.zeros((4, 4), np.float32), device="cpu", **kwargs)


def test_lambert_helper_is_the_gdal_incidence():
    """The analytic planes and the GDAL reference agree on the incidence they share (a guard on the helper)."""
    p, q = np.array([0.3]), np.array([-0.2])
    normal = np.array([-0.3, 0.2, 1.0]) / math.sqrt(1.13)
    light = np.array([math.sin(RAD(315)) * math.cos(RAD(45)), math.cos(RAD(315)) * math.cos(RAD(45)),
                      math.sin(RAD(45))])
    assert lambert(p, q, RAD(315), RAD(45))[0] == pytest.approx(normal @ light)


def test_topographic_layer_refuses_an_rgba_method():
    from stepterrain.texture import topographic_layer

    with pytest.raises(InvalidInputError, match="topographic layer takes a grey method"):
        topographic_layer(np.zeros((4, 4), np.float32), method="maplibre-basic", shadows=False, device="cpu")
