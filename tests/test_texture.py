"""Topographic textures (paper 004 §7): hillshade, sweep-line shadows, ambient occlusion, encoded normals."""

from __future__ import annotations

import math
import shutil
import subprocess

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays

import stepterrain as st
from stepterrain.errors import InvalidInputError
from stepterrain.texture import ambient_occlusion, cast_shadows, hillshade, normal_map, relight

from .reference_texture import (
    find_shared,
    hillshade_reference,
    occlusion_reference,
    shadows_continuous,
    shadows_reference,
)
from .reference_texture import real_dem_crop as real_dem

RAD = math.radians


def tilted(rows=9, cols=11, a=0.3, b=-0.2, spacing=(2.0, 3.0)):
    dx, dy = spacing
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return (a * j * dx + b * i * dy).astype(np.float32)


# ------------------------------------------------------------------------------------------ hillshade
@pytest.mark.parametrize("spacing", [(2.0, 3.0), (2.0, -3.0), (-1.5, 1.0)])
def test_tilted_plane_equals_analytic(device, spacing):
    a, b = 0.3, -0.2
    heights = tilted(a=a, b=b, spacing=spacing)
    for az, alt in ((315, 45), (90, 30), (200, 70)):
        shade = hillshade(heights, spacing=spacing, azimuth=RAD(az), altitude=RAD(alt), device=device)
        light = np.array([math.sin(RAD(az)) * math.cos(RAD(alt)), math.cos(RAD(az)) * math.cos(RAD(alt)),
                          math.sin(RAD(alt))])
        normal = np.array([-a, -b, 1.0]) / math.sqrt(1 + a * a + b * b)
        expected = max(float(normal @ light), 0.0)
        np.testing.assert_allclose(shade[1:-1, 1:-1], expected, atol=2e-6)


@pytest.mark.parametrize("method", ["standard", "combined", "igor"])
def test_azimuth_315_lights_slopes_facing_north_west(device, method):
    # azimuth is radians clockwise from north: RAD(315) is gdaldem's default -az 315, a light from the north-west.
    # A plane sloping down to the north-west faces it (gdaldem: byte 251), one sloping down to the south-east
    # turns away (byte 1); 315 read as radians (about 48 degrees, north-east) would light both alike
    i, j = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    down_nw = (i + j).astype(np.float32)  # rows north-first, spacing (1, -1): heights grow to the south-east
    shade = {name: hillshade(z, spacing=(1.0, -1.0), azimuth=RAD(az), method=method, device=device)[1:-1, 1:-1]
             for name, z, az in (("nw", down_nw, 315), ("se", -down_nw, 315), ("se_135", -down_nw, 135))}
    assert shade["nw"].min() > shade["se"].max() + 0.5
    np.testing.assert_allclose(shade["se_135"], shade["nw"], atol=1e-6)  # the mirror image of the light
    np.testing.assert_array_equal(hillshade(down_nw, spacing=(1.0, -1.0), method=method, device=device)[1:-1, 1:-1],
                                  shade["nw"])  # the default is 315 degrees
    if method == "standard":
        np.testing.assert_allclose(1 + 254 * shade["nw"], 251.0, atol=0.5)
        np.testing.assert_allclose(1 + 254 * shade["se"], 1.0, atol=0.5)


def test_z_factor_scales_gradient(device):
    heights = tilted()
    np.testing.assert_allclose(hillshade(heights * 3, spacing=(2.0, 3.0), device=device),
                               hillshade(heights, spacing=(2.0, 3.0), z_factor=3.0, device=device), atol=1e-5)


@pytest.mark.parametrize("method", ["standard", "multidirectional", "combined", "igor"])
def test_hillshade_matches_reference(device, method):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=48, step=3)
    heights[5, 7] = np.nan
    ours = hillshade(heights, spacing=(90.0, -90.0), method=method, z_factor=2.0, device=device)
    ref = hillshade_reference(heights, (90.0, -90.0), z_factor=2.0, method=method)
    assert np.isnan(ours[5, 7])
    np.testing.assert_allclose(ours, ref, atol=2e-5)


#: hillshade methods and their gdaldem flags
GDAL_METHODS = [("standard", []), ("multidirectional", ["-multidirectional"]), ("combined", ["-combined"]),
                ("igor", ["-igor"])]


@pytest.fixture
def rasterio():
    """rasterio, for a test that compares with ``gdaldem`` (skipped without either)."""
    if shutil.which("gdaldem") is None:
        pytest.skip("gdaldem not installed (Debian: apt-get install gdal-bin)")
    return pytest.importorskip("rasterio")


def test_multidirectional_flat_is_sin_altitude(device):
    shade = hillshade(np.zeros((4, 4)), method="multidirectional", altitude=RAD(30), device=device)
    np.testing.assert_allclose(shade, 0.5, atol=1e-6)


@pytest.mark.parametrize("method,flag", GDAL_METHODS)
def test_agrees_with_gdaldem(tmp_path, method, flag, rasterio):
    path = find_shared("big_tujunga_srtm_30m_utm11n.tif")
    out = tmp_path / "hs.tif"
    subprocess.run(["gdaldem", "hillshade", "-q", str(path), str(out), "-of", "GTiff", "-z", "1.5", *flag],
                   check=True)
    with rasterio.open(out) as f:
        gdal = f.read(1).astype(np.float64)[1:-1, 1:-1]
    shade = hillshade(st.load_dem(path), method=method, z_factor=1.5, device="cpu")[1:-1, 1:-1]
    ours = 255 * shade if method == "igor" else 1 + 254 * shade  # GDAL's byte scalings
    assert np.corrcoef(gdal.ravel(), ours.ravel())[0, 1] >= 0.99
    assert np.abs(gdal - ours).max() <= 1.0  # GDAL rounds to bytes


@pytest.mark.parametrize("method,flag", GDAL_METHODS)
def test_border_agrees_with_gdaldem_compute_edges(tmp_path, method, flag, rasterio):
    # the border, nodata beside it and the corners included: gdaldem -compute_edges extrapolates beyond an edge
    # (the border was edge-replicated before, up to 35 of 255 grey levels off on this crop)
    from affine import Affine  # rasterio's own dependency (from_origin warns about its * operator)

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=23, step=5)[:, :17].copy()
    for at in ((1, 5), (4, 1), (1, 1), (21, 15), (0, 9), (12, 16), (11, 8)):
        heights[at] = np.nan
    rows, cols = heights.shape
    path, out = tmp_path / "dem.tif", tmp_path / "hs.tif"
    with rasterio.open(path, "w", driver="GTiff", height=rows, width=cols, count=1, dtype="float32",
                       crs="EPSG:32611", transform=Affine(150.0, 0.0, 394000.0, 0.0, -150.0, 3798000.0),
                       nodata=np.nan) as f:
        f.write(heights, 1)
    subprocess.run(["gdaldem", "hillshade", "-q", "-compute_edges", "-z", "1.5", *flag, str(path), str(out)],
                   check=True)
    with rasterio.open(out) as f:
        gdal = f.read(1).astype(np.float64)
    shade = hillshade(st.load_dem(path), method=method, z_factor=1.5, device="cpu").astype(np.float64)
    ours = 255 * shade if method == "igor" else 1 + 254 * shade  # GDAL's byte scalings
    valid = ~np.isnan(heights)
    assert np.abs(gdal - ours)[valid].max() <= 0.51  # GDAL rounds to bytes


@given(
    heights=arrays(np.float32, hst.tuples(hst.integers(2, 7), hst.integers(2, 7)),
                   elements=hst.one_of(hst.integers(0, 60).map(float), hst.just(np.nan))),
    method=hst.sampled_from(["standard", "multidirectional", "combined", "igor"]),
    spacing=hst.sampled_from([(1.0, 1.0), (30.0, -30.0), (2.0, 0.5), (-0.7, 1.3)]),
)
def test_hillshade_border_matches_reference_property(heights, method, spacing):
    # every pixel of small grids, most of them border pixels, with nodata anywhere: gdaldem's -compute_edges rule
    ours = hillshade(heights, spacing=spacing, method=method, device="cpu")
    ref = hillshade_reference(heights, spacing, method=method)
    np.testing.assert_allclose(ours, ref, atol=2e-5)


@pytest.mark.parametrize("spacing", [(2.0, 3.0), (2.0, -3.0), (-1.5, 1.0)])
def test_tilted_plane_border_is_exact_but_corners(device, spacing):
    # linear extrapolation continues a plane beyond every edge; only the corners repeat a column (as gdaldem)
    a, b = 0.3, -0.2
    heights = tilted(a=a, b=b, spacing=spacing)
    shade = hillshade(heights, spacing=spacing, azimuth=RAD(90), altitude=RAD(30), device=device)
    light = np.array([math.cos(RAD(30)), 0.0, math.sin(RAD(30))])
    expected = max(float(np.array([-a, -b, 1.0]) @ light) / math.sqrt(1 + a * a + b * b), 0.0)
    corners = np.zeros(shade.shape, bool)
    corners[[0, 0, -1, -1], [0, -1, 0, -1]] = True
    np.testing.assert_allclose(shade[~corners], expected, atol=2e-6)


# ------------------------------------------------------------------------------------------ shadows
def ridge(cols=40, rows=5, x0=10, height=20.0):
    heights = np.zeros((rows, cols), np.float32)
    heights[:, x0] = height
    return heights


def test_ridge_shadows_behind_not_in_front(device):
    heights = ridge()
    # light from the west at 45 degrees: the ridge at column 10, height 20, spacing 1 shadows 20 columns east
    shadow = cast_shadows(heights, azimuth=RAD(270), altitude=RAD(45), device=device)
    assert (shadow[:, :11] == 0).all(), "in front of the ridge (towards the light) must be lit"
    assert (shadow[:, 11:30] == 1).all(), "behind the ridge within height / tan(altitude) must be shadowed"
    assert (shadow[:, 31:] == 0).all(), "beyond the shadow's reach must be lit"
    # from the east the shadow falls west: 20 / tan(60 degrees) = 11.5 columns
    shadow = cast_shadows(ridge(x0=25), azimuth=RAD(90), altitude=RAD(60), device=device)
    assert (shadow[:, 25:] == 0).all()
    assert (shadow[:, 14:25] == 1).all() and (shadow[:, :13] == 0).all()


def test_hillshade_with_shadows_darkens_only_shadowed(device):
    heights = ridge()
    plain = hillshade(heights, azimuth=RAD(270), altitude=RAD(45), device=device)
    dark = hillshade(heights, azimuth=RAD(270), altitude=RAD(45), shadows=True, shadow_strength=0.5,
                     device=device)
    shadow = cast_shadows(heights, azimuth=RAD(270), altitude=RAD(45), device=device).astype(bool)
    np.testing.assert_allclose(dark[shadow], plain[shadow] * 0.5, rtol=1e-6)
    np.testing.assert_array_equal(dark[~shadow], plain[~shadow])


@pytest.mark.parametrize("azimuth", [0, 30, 45, 90, 135, 200, 270, 315, 333])
def test_sweep_equals_brute_force_ray_march_on_real_dem(device, azimuth):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=5)
    spacing = (150.0, -150.0)
    for altitude in (10.0, 25.0):
        ours = cast_shadows(heights, spacing=spacing, azimuth=RAD(azimuth), altitude=RAD(altitude), device=device)
        ref = shadows_reference(heights, spacing, RAD(azimuth), RAD(altitude))
        assert ref.sum() > 0
        np.testing.assert_array_equal(ours, ref)


@given(
    heights=arrays(np.float32, hst.tuples(hst.integers(2, 14), hst.integers(2, 14)),
                   elements=hst.integers(0, 50).map(float)),
    azimuth=hst.floats(0, 360),
    altitude=hst.floats(1, 80),
    spacing=hst.sampled_from([(1.0, 1.0), (1.0, -1.0), (2.0, 0.5), (-0.7, 1.3)]),
)
def test_sweep_equals_ray_march_property(heights, azimuth, altitude, spacing):
    ours = cast_shadows(heights, spacing=spacing, azimuth=RAD(azimuth), altitude=RAD(altitude), device="cpu")
    ref = shadows_reference(heights, spacing, RAD(azimuth), RAD(altitude))
    np.testing.assert_array_equal(ours, ref)


def test_no_shadow_at_zenith_and_nodata_is_lit(device):
    heights = ridge()
    assert cast_shadows(heights, altitude=RAD(90), device=device).sum() == 0
    heights[2, 15] = np.nan
    shadow = cast_shadows(heights, azimuth=RAD(270), altitude=RAD(45), device=device)
    assert shadow[2, 15] == 0 and shadow[2, 16] == 1



def _standard_shade_float32(heights, spacing, azimuth, altitude, shadow=None, strength=1.0):
    """The interior of the standard hillshade in float32, in shade_heights' order of operations (no fused
    multiply-adds; IEEE division and square root): what the kernel's vector path must give, bit for bit."""
    f32 = np.float32
    z = np.asarray(heights, f32)
    s0, s1 = f32(1.0 / (8.0 * spacing[0])), f32(1.0 / (8.0 * spacing[1]))
    l0, l1, l2 = (f32(v) for v in (math.sin(azimuth) * math.cos(altitude), math.cos(azimuth) * math.cos(altitude),
                                   math.sin(altitude)))
    a, b, c = z[:-2, :-2], z[:-2, 1:-1], z[:-2, 2:]
    d, f = z[1:-1, :-2], z[1:-1, 2:]
    g, h, k = z[2:, :-2], z[2:, 1:-1], z[2:, 2:]
    two = f32(2.0)
    p = ((c + two * f + k) - (a + two * d + g)) * s0
    q = ((g + two * h + k) - (a + two * b + c)) * s1
    v = (l2 - p * l0 - q * l1) / np.sqrt(f32(1.0) + p * p + q * q)
    v = np.where(v >= 0, v, f32(0.0)).astype(f32)
    if shadow is not None:
        v = np.where(shadow[1:-1, 1:-1] != 0, v * (f32(1.0) - f32(strength)), v).astype(f32)
    return v


@pytest.mark.parametrize("shape", [(5, 17), (9, 64 + 33), (4, 130), (70, 3 * 64 + 15)])
def test_hillshade_interior_is_the_scalar_formula_bit_for_bit(shape):
    """On the CPU the interior of a row without nodata is shaded sixteen pixels at a time (native vector code,
    kernels/texture.py shade_interior_run), the rest pixel by pixel: both must give the float32 formula's bits,
    across lane, run (64 pixels) and row ends, with and without shadows."""
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=max(shape), step=2)[: shape[0], : shape[1]]
    spacing = (30.0, -30.0)
    az, alt = RAD(315), RAD(30)
    ours = hillshade(heights, spacing=spacing, azimuth=az, altitude=alt, device="cpu")
    expected = _standard_shade_float32(heights, spacing, az, alt)
    np.testing.assert_array_equal(ours[1:-1, 1:-1].view(np.uint32), expected.view(np.uint32))
    shadow = cast_shadows(heights, spacing=spacing, azimuth=az, altitude=alt, device="cpu")
    dark = hillshade(heights, spacing=spacing, azimuth=az, altitude=alt, shadows=True, shadow_strength=0.3,
                     device="cpu")
    expected = _standard_shade_float32(heights, spacing, az, alt, shadow, 0.3)
    np.testing.assert_array_equal(dark[1:-1, 1:-1].view(np.uint32), expected.view(np.uint32))



@given(
    heights=arrays(np.float32, hst.tuples(hst.integers(3, 9), hst.integers(3, 150)),
                   elements=hst.floats(-500, 3000, width=32)),
    azimuth=hst.floats(0, 360),
    altitude=hst.floats(0, 90),
    spacing=hst.sampled_from([(30.0, -30.0), (1.0, 1.0), (-2.5, 0.7), (90.0, -10.0)]),
    strength=hst.floats(0, 1),
)
def test_hillshade_interior_is_the_scalar_formula_property(heights, azimuth, altitude, spacing, strength):
    """The vector rows give the float32 formula's bits for any heights, light, spacing and shadow strength."""
    az, alt = RAD(azimuth), RAD(altitude)
    ours = hillshade(heights, spacing=spacing, azimuth=az, altitude=alt, device="cpu")
    np.testing.assert_array_equal(ours[1:-1, 1:-1].view(np.uint32),
                                  _standard_shade_float32(heights, spacing, az, alt).view(np.uint32))
    if altitude < 90:
        shadow = cast_shadows(heights, spacing=spacing, azimuth=az, altitude=alt, device="cpu")
        dark = hillshade(heights, spacing=spacing, azimuth=az, altitude=alt, shadows=True,
                         shadow_strength=strength, device="cpu")
        expected = _standard_shade_float32(heights, spacing, az, alt, shadow, strength)
        np.testing.assert_array_equal(dark[1:-1, 1:-1].view(np.uint32), expected.view(np.uint32))

@pytest.mark.parametrize("azimuth", [45, 135, 225, 315])
def test_diagonal_light_sweeps_the_same_lines_along_rows(azimuth):
    """A diagonal light sweeps along rows on the CPU (the faster axis, bundles of 1024 lines); the reference
    walks its diagonals along columns. A tall grid has more than one bundle of lines."""
    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=96, step=1)
    heights = np.tile(dem[:, :40], (14, 1))  # 1344 x 40: 1383 diagonal lines
    spacing = (30.0, 30.0)
    ours = cast_shadows(heights, spacing=spacing, azimuth=RAD(azimuth), altitude=RAD(12), device="cpu")
    ref = shadows_reference(heights, spacing, RAD(azimuth), RAD(12))
    assert ref.sum() > 100
    np.testing.assert_array_equal(ours, ref)


# ------------------------------------------------------------------------------------------ occlusion
def test_occlusion_matches_reference(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=8)
    ours = ambient_occlusion(heights, spacing=(240.0, -240.0), directions=8, device=device)
    ref = occlusion_reference(heights, (240.0, -240.0), directions=8)
    np.testing.assert_allclose(ours, ref, atol=1e-5)



def test_occlusion_bundles_give_the_bits_of_one_line_per_thread(monkeypatch):
    """On the CPU a thread walks a bundle of adjacent lines in lockstep (128 along rows, 16 along columns); each
    line still sees its nodes in its own order, so the image is that of one line per thread, bit for bit, and
    the reference's. A tall grid with nodata has several bundles each way."""
    import stepterrain.texture as texture_module

    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=96, step=1)
    heights = np.tile(dem[:, :37], (3, 1))[:260]  # 260 x 37
    heights[40:44, 10:15] = np.nan
    spacing = (30.0, -25.0)
    bundled = ambient_occlusion(heights, spacing=spacing, directions=8, device="cpu")
    monkeypatch.setattr(texture_module, "_OCCLUSION_LINES_PER_THREAD_CPU", {0: 1, 1: 1})
    single = ambient_occlusion(heights, spacing=spacing, directions=8, device="cpu")
    np.testing.assert_array_equal(bundled.view(np.uint32), single.view(np.uint32))
    finite = np.isfinite(heights)
    np.testing.assert_allclose(bundled[finite], occlusion_reference(heights, spacing, directions=8)[finite],
                               atol=1e-5)
    assert np.isnan(bundled[~finite]).all() and bundled[finite].min() < 0.9

def test_shadow_bundles_of_rows_a_page_apart_give_the_bits_of_one_line_per_thread(monkeypatch):
    """Rows 4 KiB apart (1024 floats wide) sweep east-west in bundles of 8 lines, others of 16: same bits as one
    line per thread, and the ray march's mask, for lights along and across the rows."""
    import stepterrain.texture as texture_module

    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=96, step=1)
    heights = np.ascontiguousarray(np.tile(dem[:40], (1, 11))[:, :1024])  # 40 x 1024: rows 4096 bytes apart
    heights[20:23, 500:505] = np.nan
    spacing = (30.0, -30.0)
    seen = []
    launch = texture_module.launch

    def spy(kernel, dim, inputs, **kwargs):
        if kernel.key.startswith("sweep_shadows"):
            seen.append(inputs[2])
        return launch(kernel, dim=dim, inputs=inputs, **kwargs)

    monkeypatch.setattr(texture_module, "launch", spy)
    for azimuth in (90.0, 260.0, 300.0):
        bundled = cast_shadows(heights, spacing=spacing, azimuth=np.radians(azimuth), device="cpu")
        with monkeypatch.context() as m:
            m.setattr(texture_module, "_LINES_PER_THREAD_CPU", {0: 1, 1: 1})
            m.setattr(texture_module, "_LINES_PER_THREAD_CPU_ALIASED_ROWS", 1)
            single = cast_shadows(heights, spacing=spacing, azimuth=np.radians(azimuth), device="cpu")
        np.testing.assert_array_equal(bundled, single)
        ref = shadows_reference(heights, spacing, azimuth=np.radians(azimuth))
        finite = np.isfinite(heights)
        np.testing.assert_array_equal(bundled[finite], ref[finite])
        assert 0 < bundled.sum() < bundled.size
    assert seen[0] == 8 and seen[2] == 8  # the aliased rows' bundle, along rows 4 KiB apart
    narrow = cast_shadows(heights[:, :1000].copy(), spacing=spacing, azimuth=np.radians(90.0), device="cpu")
    assert seen[-1] == 16 and narrow.shape == (40, 1000)


def _sweeps_launched(monkeypatch, on_nodes):
    """Spy on the sweep launches (kernel names in order); ``on_nodes`` False: every sweep told its nodes are off
    their straight lines, so the general kernels run where the on-node ones would."""
    import stepterrain.texture as texture_module

    names = []
    launch, sweep = texture_module.launch, texture_module._sweep

    def spy(kernel, *args, **kwargs):
        names.append(kernel.key)
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(texture_module, "launch", spy)
    if not on_nodes:
        monkeypatch.setattr(texture_module, "_sweep", lambda *a: (*sweep(*a)[:2], False))
    return names


@pytest.mark.parametrize("spacing", [(30.0, -30.0), (30.0, -25.0)])
def test_sweeps_along_an_axis_or_a_diagonal_skip_the_sideways_steps_bit_for_bit(device, monkeypatch, spacing):
    """Lights along an axis, or along a diagonal of square cells, sweep lines whose nodes lie on their straight
    lines (every sideways step 0): the on-node kernels give the general kernels' bits, on a real DEM with nodata
    and on random heights, down to grazing light; other azimuths keep the general kernel."""
    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=96, step=1)[:70, :83].copy()
    dem[30:33, 40:46] = np.nan
    rng = np.random.default_rng(7)
    grids = [dem, st.sample_dem().heights, rng.normal(0.0, 20.0, (41, 57)).astype(np.float32)]
    square = spacing[0] == -spacing[1]
    for heights in grids:
        for azimuth in (0, 90, 180, 270, 45, 135, 225, 315, 300):
            on_nodes = azimuth % 90 == 0 or square and azimuth != 300
            for altitude in (0.5, 5.0, 45.0):
                light = {"azimuth": RAD(azimuth), "altitude": RAD(altitude), "spacing": spacing, "device": device}
                with monkeypatch.context() as m:
                    names = _sweeps_launched(m, True)
                    fast = cast_shadows(heights, **light)
                assert len(names) == 1 and names[0].startswith("sweep_shadows_")
                assert names[0].endswith("_on_nodes") == on_nodes
                with monkeypatch.context() as m:
                    names = _sweeps_launched(m, False)
                    general = cast_shadows(heights, **light)
                assert len(names) == 1 and not names[0].endswith("_on_nodes")
                np.testing.assert_array_equal(fast, general)
                if altitude == 5.0:
                    assert 0 < fast.sum() < np.isfinite(heights).sum()
        for directions in (4, 8, 16, 6):
            with monkeypatch.context() as m:
                names = _sweeps_launched(m, True)
                fast = ambient_occlusion(heights, directions=directions, spacing=spacing, device=device)
            swept = [name for name in names if name.startswith("sweep_occlusion_")]
            axes = [k for k in range(directions) if 4 * k % directions == 0]
            diagonals = [k for k in range(directions) if 8 * k % directions == 0 and k not in axes]
            expected = len(axes) + (len(diagonals) if square else 0)
            assert len(swept) == directions
            assert sum(name.endswith("_on_nodes") for name in swept) == expected
            with monkeypatch.context() as m:
                names = _sweeps_launched(m, False)
                general = ambient_occlusion(heights, directions=directions, spacing=spacing, device=device)
            assert not any(name.endswith("_on_nodes") for name in names)
            np.testing.assert_array_equal(fast.view(np.uint32), general.view(np.uint32))


def test_occlusion_open_ground_and_pit(device):
    flat = ambient_occlusion(np.zeros((8, 8)), directions=8, device=device)
    np.testing.assert_allclose(flat, 1.0)
    pit = np.full((9, 9), 10.0, np.float32)
    pit[4, 4] = 0.0
    ao = ambient_occlusion(pit, directions=8, device=device)
    # the pit sees a horizon at 45 degrees (10 m rise over one cell... on axes; steeper diagonally not)
    assert ao[4, 4] < 0.4 and ao[0, 0] == pytest.approx(1.0)


@pytest.mark.parametrize("spacing", [(1.0, 1.0), (30.0, -30.0), (2.0, 0.5)])
@pytest.mark.parametrize("directions", [12, 16])
def test_occlusion_of_a_plane_is_its_slopes_horizons(device, spacing, directions):
    """On a plane the horizon towards a direction is the plane's rise that way (none where it falls), the same at
    every node with a node before it on each line: 1 − mean(sin(atan(max(0, ∇z · d)))). The digital lines' own nodes
    zig-zagged a node sideways, and their cross slope raised the horizons: 0.69-0.73 against 0.7425 on a 45° plane
    at 16 directions."""
    a, b = 0.3, 1.0  # dz/dx, dz/dy
    heights = tilted(rows=40, cols=44, a=a, b=b, spacing=spacing)
    ao = ambient_occlusion(heights, directions=directions, spacing=spacing, device=device)
    sines = []
    for k in range(directions):
        s = max(0.0, a * math.sin(2 * math.pi * k / directions) + b * math.cos(2 * math.pi * k / directions))
        sines.append(s / math.sqrt(1 + s * s))
    np.testing.assert_allclose(ao[3:-3, 3:-3], 1.0 - np.mean(sines), atol=1e-5)


@pytest.mark.parametrize("directions", [0, 361, 10**9, 2.0, True])
def test_occlusion_directions_are_bounded(directions):
    """10**9 directions ran one sweep of launches each: effectively a hang; now refused by name."""
    with pytest.raises(InvalidInputError, match=r"directions must be an int in \[1, 360\]"):
        ambient_occlusion(np.zeros((4, 4)), directions=directions, device="cpu")


# ------------------------------------------------------------------------------------------ normals
def test_normal_map_relit_equals_hillshade(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=32, step=4)
    rgb = normal_map(heights, spacing=(120.0, -120.0), device=device)
    assert rgb.dtype == np.uint8 and rgb.shape == (*heights.shape, 3)
    for az, alt in ((315, 45), (45, 20)):
        relit = relight(rgb, azimuth=RAD(az), altitude=RAD(alt), device=device)
        direct = hillshade(heights, spacing=(120.0, -120.0), azimuth=RAD(az), altitude=RAD(alt), device=device)
        np.testing.assert_allclose(relit, direct, atol=0.02)  # 8-bit normals


def test_point_light_relight(device):
    plane = np.zeros((21, 21), np.float32)
    terrain = st.Terrain.from_heights(plane, spacing=(1.0, 1.0), origin=(100.0, 200.0))
    rgb = normal_map(terrain, device=device)
    shade = relight(rgb, point=(110.0, 210.0, 5.0), terrain=terrain, device=device)
    assert shade[10, 10] == pytest.approx(1.0, abs=1e-3)  # directly under the light
    i, j = np.meshgrid(np.arange(21), np.arange(21), indexing="ij")
    d = np.hypot(i - 10.0, j - 10.0)
    np.testing.assert_allclose(shade, 5.0 / np.sqrt(d * d + 25.0), atol=0.01)


# ------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("kwargs,match", [
    ({"altitude": RAD(95)}, "altitude must lie in"),
    ({"altitude": -0.1}, "altitude must lie in"),
    ({"azimuth": float("nan")}, "azimuth must be finite"),
    ({"z_factor": 0.0}, "z_factor must be positive"),
    ({"method": "basic"}, "method must be one of"),
    ({"shadow_strength": 2.0}, "shadow_strength"),
])
def test_bad_light_raises(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        hillshade(np.zeros((3, 3)), device="cpu", **kwargs)


def test_bad_relight_inputs():
    with pytest.raises(InvalidInputError, match="uint8 RGB"):
        relight(np.zeros((3, 3)), azimuth=0.0, altitude=0.5)
    rgb = normal_map(np.zeros((3, 3)), device="cpu")
    with pytest.raises(InvalidInputError, match="point light needs terrain"):
        relight(rgb, point=(0, 0, 1))
    with pytest.raises(InvalidInputError, match="mismatched size"):
        relight(rgb, point=(0, 0, 1), terrain=np.zeros((4, 3)))
    with pytest.raises(InvalidInputError, match="not both"):
        relight(rgb, point=(0, 0, 1), azimuth=0.0, altitude=0.1, terrain=np.zeros((3, 3)))
    for point in ("abc", ("0", "0", "1"), (True, True, True), (0, 0)):  # numpy's ValueError for text; True taken as 1
        with pytest.raises(InvalidInputError, match=r"point must be a finite \(x, y, z\); got "):
            relight(rgb, point=point, terrain=np.zeros((3, 3)), device="cpu")


def test_an_azimuth_beyond_two_turns_warns_of_degrees():
    """The API takes radians (the CLI degrees): 315 passed as radians is most likely degrees; a warning says so
    and names the radian value. Angles within two turns (computed ones past a turn too) stay silent."""
    heights = tilted()
    with pytest.warns(UserWarning, match=r"azimuth is in radians; got 315.*math.radians\(315\) = 5.4978"):
        hillshade(heights, azimuth=315, device="cpu")
    with pytest.warns(UserWarning, match="azimuth is in radians"):
        cast_shadows(heights, azimuth=-400.0, altitude=RAD(45), device="cpu")
    with pytest.warns(UserWarning, match="azimuth is in radians"):
        hillshade(heights, method="maplibre-multidirectional", azimuth=[RAD(100), 270.0], device="cpu")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        hillshade(heights, azimuth=RAD(315), device="cpu")
        hillshade(heights, azimuth=-2 * math.pi, device="cpu")
        hillshade(heights, azimuth=RAD(315 + 360), device="cpu")  # a computed angle past one turn


@pytest.mark.parametrize("flag", ["no", 1, None])
def test_shadows_must_be_a_bool(flag):
    # shadows="no" cast shadows (a non-empty string is true)
    with pytest.raises(InvalidInputError, match=rf"shadows must be True or False; got {flag!r}"):
        hillshade(np.zeros((4, 4)), shadows=flag)
    with pytest.raises(InvalidInputError, match=rf"shadows must be True or False; got {flag!r}"):
        st.texture.topographic_layer(np.zeros((4, 4)), shadows=flag)


@pytest.mark.parametrize("spacing", [(1.0, 1.0), (30.0, -30.0), (2.0, 0.5), (-0.7, 1.3)])
@pytest.mark.parametrize("azimuth", [10, 30, 100, 200, 280, 290, 300, 330])
def test_a_plane_the_sun_rises_above_casts_no_shadow(device, spacing, azimuth):
    """A point is in shadow iff the terrain towards the light rises above the ray from it: on a plane whose rise
    towards the light is below tan(altitude) nowhere does. The digital sweep lines step sideways by a node now and
    then; with the nodes' own heights a plane sloping across the light rose by a whole node's cross slope at each
    step, and bands of a lit plane (hillshade > 0.2) came out shadowed (a quarter of the nodes at 300°)."""
    altitude = RAD(30)
    toward = np.array([math.sin(RAD(azimuth)), math.cos(RAD(azimuth))])
    across = np.array([toward[1], -toward[0]])
    for cross, along in ((1.0, 0.0), (2.0, 0.3), (0.7, -0.5), (3.0, 0.5)):
        a, b = cross * across + along * math.tan(altitude) * toward  # dz/dx, dz/dy: along < 1 keeps it lit
        heights = tilted(rows=23, cols=31, a=a, b=b, spacing=spacing)
        shadow = cast_shadows(heights, spacing=spacing, azimuth=RAD(azimuth), altitude=altitude, device=device)
        assert shadow.sum() == 0, (cross, along, shadow.mean())


@pytest.mark.parametrize("azimuth", [280, 300, 330])
def test_shadows_on_a_real_dem_agree_with_the_bilinear_ray_march(azimuth):
    """Against the definition, marched over the bilinear terrain in quarter cells: few nodes differ (a node's shadow
    is its straight line's point's, at most half a node sideways). With the digital lines' own nodes about 4 % of
    the nodes were shadowed that the march finds lit, at these lights off the axes and diagonals."""
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=80, step=2)
    spacing = (60.0, -60.0)
    ours = cast_shadows(heights, spacing=spacing, azimuth=RAD(azimuth), altitude=RAD(20), device="cpu").astype(bool)
    truth = shadows_continuous(heights, spacing, RAD(azimuth), RAD(20)).astype(bool)
    assert truth.mean() > 0.05
    assert (ours & ~truth).mean() < 0.015 and (~ours & truth).mean() < 0.03
