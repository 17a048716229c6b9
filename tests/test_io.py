"""load_dem / sample_dem / describe_dem: real DEMs in shared/data, round-trips and every refused input."""

from __future__ import annotations

import builtins
import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import stepterrain as st
from stepterrain.errors import DataFileError, InvalidInputError, MissingDependencyError
from stepterrain.io import EARTH_RADIUS_M, describe_dem, load_dem, sample_dem

from .conftest import SHARED_DATA

DATA = SHARED_DATA  # beside the project, or further up from a git worktree
TUJUNGA = "big_tujunga_srtm_30m_utm11n"
FRONT_RANGE = "front_range_srtmgl3_3arcsec"


def data_file(name: str) -> Path:
    path = DATA / name
    if not path.exists():
        pytest.skip(f"shared data file {name} not found in {DATA}")
    return path


def needs_rasterio():
    return pytest.importorskip(
        "rasterio", reason="GeoTIFF tests need rasterio (pip install 'stepterrain[geo]')"
    )


# ---------------------------------------------------------------------------------------------- real data
@pytest.mark.parametrize("ext", ["npz", "tif"])
def test_big_tujunga(ext):
    if ext == "tif":
        needs_rasterio()
    t = load_dem(data_file(f"{TUJUNGA}.{ext}"))
    assert t.kind == "grid" and t.shape == (643, 1197)
    assert t.heights.dtype == np.float32 and not np.isnan(t.heights).any()
    assert t.spacing == (30.0, -30.0)
    assert t.crs == "EPSG:32611"
    assert t.source == f"{TUJUNGA}.{ext}"
    # node (0, 0) is the centre of the top-left cell: half a cell inside the corner bounds
    x0, x1, y0, y1 = t.extent
    assert x0 == pytest.approx(376313.66 + 15.0, abs=0.01)
    assert x1 == pytest.approx(412223.66 - 15.0, abs=0.01)
    assert y0 == pytest.approx(3788627.83 + 15.0, abs=0.01)
    assert y1 == pytest.approx(3807917.83 - 15.0, abs=0.01)
    assert t.origin == (x0, y1)
    assert t.height_range == (315.0, 2295.0)


@pytest.mark.parametrize("ext", ["npz", "tif"])
def test_front_range_geographic_to_local_metres(ext):
    if ext == "tif":
        needs_rasterio()
    t = load_dem(data_file(f"{FRONT_RANGE}.{ext}"))
    assert t.shape == (758, 758)
    assert not np.isnan(t.heights).any()
    dx, dy = t.spacing
    assert dx == pytest.approx(70.8, abs=0.05) and dy == pytest.approx(-92.66, abs=0.01)
    # dy is the arc of 3 arc-seconds on the sphere; dx shrinks with the cosine of the centre latitude
    assert -dy == pytest.approx(EARTH_RADIUS_M * math.radians(3 / 3600), rel=1e-6)
    assert dx / -dy == pytest.approx(math.cos(math.radians(40.1504)), rel=1e-5)
    assert t.origin == (0.0, 0.0)
    assert t.extent == pytest.approx((0.0, 757 * dx, 757 * dy, 0.0))
    assert "+proj=eqc" in t.crs and "+units=m" in t.crs
    assert "lon -105.81583" in t.source and "lat 40.46583" in t.source
    assert t.height_range == (1547.0, 4320.0)


@pytest.mark.parametrize("name", [TUJUNGA, FRONT_RANGE])
def test_tif_and_npz_agree(name):
    needs_rasterio()
    a = load_dem(data_file(f"{name}.npz"))
    b = load_dem(data_file(f"{name}.tif"))
    np.testing.assert_array_equal(a.heights, b.heights)
    np.testing.assert_allclose(a.spacing, b.spacing, rtol=1e-9)
    np.testing.assert_allclose(a.origin, b.origin, rtol=1e-9, atol=1e-6)
    assert a.crs == b.crs


def test_sample_dem():
    t = sample_dem()
    assert t.shape == (643, 1197)
    assert t.spacing == (30.0, -30.0)
    assert t.crs == "EPSG:32611"
    assert t.height_range == (315.0, 2295.0)
    assert t.source == "big_tujunga_srtm_30m_utm11n.npz"
    assert sample_dem() is not t  # a fresh object each call
    assert st.sample_dem().shape == t.shape


def test_describe_dem_is_json_ready():
    info = describe_dem(sample_dem())
    assert info["shape"] == (643, 1197)
    assert info["spacing"] == (30.0, -30.0)
    assert info["height_range"] == (315.0, 2295.0)
    assert info["nodata_count"] == 0
    assert info["crs"] == "EPSG:32611"
    assert info["extent"][1] - info["extent"][0] == pytest.approx(1196 * 30.0)
    json.dumps(info)


def test_describe_dem_all_nodata_and_tin():
    grid = st.Terrain.from_heights(np.full((2, 3), np.nan), spacing=(2.0, 2.0))
    info = describe_dem(grid)
    assert info["height_range"] is None and info["nodata_count"] == 6
    tin = describe_dem(st.heightfield_mesh(np.zeros((3, 3))))
    assert tin["kind"] == "tin" and tin["spacing"] is None and tin["shape"] == (9,)


def test_global_relief_npz_is_described_in_degrees(capsys):
    """The global relief grids hold 1-D lat/lon axes beside 'elevation' and no transform: they were read as an
    unreferenced (1, -1) grid and `stepterrain info` said so. Now they are geographic: local metres as a
    geographic 'transform' makes them, and the description gives the nodes' lon/lat extent and step in degrees."""
    from importlib.resources import as_file, files

    from stepterrain import cli

    with as_file(files("stepterrain") / "data" / "global_relief_20min.npz") as embedded:
        with pytest.warns(UserWarning, match=r"global_relief_20min\.npz: .* local metres .* up to [0-9.e+]+ % over its "
                                             r"node latitudes -89\.8333 to 89\.8333 \(179\.667 degrees\)"):
            t = load_dem(embedded)
        assert cli.main(["info", str(embedded), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    step_m = EARTH_RADIUS_M * math.radians(1 / 3)
    assert t.spacing == pytest.approx((step_m, -step_m), rel=1e-12) and t.origin == (0.0, 0.0)
    assert t.crs.startswith("+proj=eqc") and "lon -179.833333333, lat 89.833333333" in t.source
    info = describe_dem(t)
    assert info["lonlat_extent"] == pytest.approx((-179.5 - 1 / 3, 179.5 + 1 / 3, -89.5 - 1 / 3, 89.5 + 1 / 3),
                                                  abs=1e-8)  # fmt: skip
    assert info["lonlat_step"] == pytest.approx((1 / 3, -1 / 3), rel=1e-9)
    assert printed["lonlat_extent"] == pytest.approx(list(info["lonlat_extent"]))
    assert printed["lonlat_step"] == pytest.approx(list(info["lonlat_step"])) and printed["spacing"][0] > 1e4
    json.dumps(info)

    shared = DATA / "global_relief.npz"  # 10': the shared copy, where present
    if shared.exists():
        with pytest.warns(UserWarning, match="local metres"):
            info = describe_dem(load_dem(shared))
        assert info["lonlat_extent"] == pytest.approx((-179 - 11 / 12, 179 + 11 / 12, -89 - 11 / 12, 89 + 11 / 12),
                                                      abs=1e-8)  # fmt: skip
        assert info["lonlat_step"] == pytest.approx((1 / 6, -1 / 6), rel=1e-9)
    # a projected or unreferenced grid has no degrees to report
    assert describe_dem(sample_dem())["lonlat_extent"] is None and describe_dem(sample_dem())["lonlat_step"] is None
    assert describe_dem(np.zeros((2, 2)))["lonlat_step"] is None


def test_latlon_npz_axes_are_checked(tmp_path):
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    lat, lon = np.array([10.0, 11.0, 12.0]), np.array([5.0, 5.5, 6.0, 6.5])  # south-first rows: dy > 0
    np.savez(tmp_path / "up.npz", elevation=z, lat=lat, lon=lon)
    info = describe_dem(load_dem(tmp_path / "up.npz"))
    assert info["spacing"][1] > 0 and info["lonlat_step"] == pytest.approx((0.5, 1.0), rel=1e-9)
    assert info["lonlat_extent"] == pytest.approx((5.0, 6.5, 10.0, 12.0), abs=1e-8)
    for name, arrays, match in (
        ("short.npz", dict(lat=lat[:2], lon=lon), r"'lat' must hold 3 finite degrees, one per row"),
        ("nan.npz", dict(lat=lat, lon=np.array([5.0, np.nan, 6.0, 6.5])), r"'lon' must hold 4 finite degrees"),
        ("uneven.npz", dict(lat=np.array([10.0, 11.0, 13.0]), lon=lon), r"'lat' must be evenly spaced degrees"),
        ("text.npz", dict(lat=np.array(["a", "b", "c"]), lon=lon), r"'lat' must hold 3 finite degrees"),
        # a constant axis said "steps that differ from their mean 0 by up to 0"
        ("flat.npz", dict(lat=np.full(3, 10.0), lon=lon), r"'lat' must be .*3 values from 10 to 10, no span"),
    ):
        np.savez(tmp_path / name, elevation=z, **arrays)
        with pytest.raises(DataFileError, match=match):
            load_dem(tmp_path / name)


# ---------------------------------------------------------------------------------------------- round-trips
def test_npy_round_trip(tmp_path):
    z = np.arange(20, dtype=np.int16).reshape(4, 5)
    np.save(tmp_path / "z.npy", z)
    t = load_dem(tmp_path / "z.npy")
    np.testing.assert_array_equal(t.heights, z.astype(np.float32))
    assert t.heights.dtype == np.float32
    assert t.spacing == (1.0, -1.0) and t.origin == (0.0, 0.0) and t.source == "z.npy" and t.crs is None


def test_npy_inf_becomes_nodata(tmp_path):
    z = np.zeros((3, 3))
    z[1, 2] = np.inf
    np.save(tmp_path / "z.npy", z)
    t = load_dem(tmp_path / "z.npy")
    assert np.isnan(t.heights[1, 2]) and np.isfinite(t.heights).sum() == 8


@pytest.mark.parametrize("key", ["heights", "elevation", "z", "anything"])
def test_generic_npz(tmp_path, key):
    z = np.random.default_rng(0).random((5, 4)).astype(np.float64)
    np.savez(tmp_path / "g.npz", **{key: z, "meta": np.arange(3)})
    t = load_dem(tmp_path / "g.npz")
    np.testing.assert_array_equal(t.heights, z.astype(np.float32))
    assert t.spacing == (1.0, -1.0)


def test_georeferenced_npz_projected(tmp_path):
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.savez(
        tmp_path / "p.npz",
        elevation=z,
        transform=np.array([1000.0, 10.0, 0, 5000.0, 0, -20.0]),
        crs="EPSG:32633",
    )
    t = load_dem(tmp_path / "p.npz")
    assert t.origin == (1005.0, 4990.0) and t.spacing == (10.0, -20.0) and t.crs == "EPSG:32633"


@pytest.mark.parametrize("key", ["heights", "z", "dem"])
def test_npz_transform_is_honoured_whatever_the_heights_key(tmp_path, key):
    # 'transform' beside 'heights', 'z' or a lone 2-D array georeferences it as it does 'elevation'
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.savez(tmp_path / "p.npz", **{key: z}, transform=np.array([1000.0, 10.0, 0, 5000.0, 0, -20.0]),
             crs="EPSG:32633")  # fmt: skip
    t = load_dem(tmp_path / "p.npz")
    np.testing.assert_array_equal(t.heights, z)
    assert t.origin == (1005.0, 4990.0) and t.spacing == (10.0, -20.0) and t.crs == "EPSG:32633"
    np.savez(tmp_path / "bad.npz", **{key: z}, transform=np.array([0.0, 1.0, 0.0]))
    with pytest.raises(DataFileError, match="GDAL geotransform of 6 finite numbers"):
        load_dem(tmp_path / "bad.npz")


@pytest.mark.parametrize("transform", [False, True], ids=["plain", "georeferenced"])
def test_npz_reads_the_first_2d_heights_key(tmp_path, transform):
    """A 1-D 'heights' (a profile) beside a 2-D 'elevation' was read first and refused without a transform; the
    first 2-D key of heights/elevation/z is read, and the same one with a transform as without (with one,
    'elevation' came first, without one 'heights'). A 1-D 'heights' alone is still refused by its shape."""
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    extra = {"transform": np.array([1000.0, 10.0, 0, 5000.0, 0, -20.0])} if transform else {}
    np.savez(tmp_path / "a.npz", heights=np.arange(5.0), elevation=z, **extra)
    np.testing.assert_array_equal(load_dem(tmp_path / "a.npz").heights, z)
    np.savez(tmp_path / "b.npz", heights=z, elevation=z + 1, **extra)
    np.testing.assert_array_equal(load_dem(tmp_path / "b.npz").heights, z)
    np.savez(tmp_path / "c.npz", heights=np.arange(5.0), other=z, **extra)
    with pytest.raises(DataFileError, match=r"expected a 2-D \(H, W\) elevation grid; got 'heights' of shape \(5,\)"):
        load_dem(tmp_path / "c.npz")


@pytest.mark.parametrize("dtype", [np.int16, np.float32])
def test_npz_nodata_value_becomes_nan(tmp_path, dtype):
    # the shared/data layout stores its nodata value beside the heights; a finite one marks missing cells
    z = np.array([[100, -32768, 102], [103, 104, 105]], dtype)
    transform = np.array([0.0, 30.0, 0, 0.0, 0, -30.0])
    np.savez(tmp_path / "g.npz", elevation=z, transform=transform, crs="EPSG:32611", nodata=dtype(-32768))
    np.savez(tmp_path / "h.npz", heights=z, nodata=np.float64(-32768))
    for name in ("g.npz", "h.npz"):
        h = load_dem(tmp_path / name).heights
        assert np.isnan(h[0, 1]) and np.isfinite(h).sum() == 5 and h[1, 2] == 105.0
    np.savez(tmp_path / "nan.npz", elevation=z, transform=transform, crs="EPSG:32611", nodata=np.float32(np.nan))
    with warnings.catch_warnings(record=True) as told:  # the -32768 is read, but named as a likely void
        warnings.simplefilter("always")
        assert np.isfinite(load_dem(tmp_path / "nan.npz").heights).all()  # NaN nodata: NaN cells only
    assert [str(w.message)[:61] for w in told] == (  # in float32, as a common nodata value far below the others
        ["nan.npz: 1 cell of 'elevation' holds -32768, the lowest int16"] if dtype == np.int16 else
        ["nan.npz: 1 cell of 'elevation' holds -32768, a common nodata "])
    np.savez(tmp_path / "all.npz", heights=np.full((2, 2), -1, dtype), nodata=-1)
    with pytest.raises(DataFileError, match="all nodata"):
        load_dem(tmp_path / "all.npz")


def test_npz_float64_nodata_beyond_float32_is_nodata_without_a_warning(tmp_path):
    # a float64 DEM with nodata -1e300: those cells overflowed in the cast to float32 (numpy's "overflow
    # encountered in cast" warning) before they became NaN
    np.savez(tmp_path / "far.npz", heights=np.array([[1.0, -1e300], [2.0, 3.0]]), nodata=-1e300)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        h = load_dem(tmp_path / "far.npz").heights
    assert np.isnan(h[0, 1]) and np.isfinite(h).sum() == 3


@pytest.mark.parametrize("dtype", [np.uint16, np.uint8])
def test_png_round_trip(tmp_path, dtype):
    top = np.iinfo(dtype).max
    z = np.linspace(0, top, 6 * 7).astype(dtype).reshape(6, 7)
    Image.fromarray(z).save(tmp_path / "h.png")
    t = load_dem(tmp_path / "h.png")
    np.testing.assert_array_equal(t.heights, z.astype(np.float32))
    assert t.heights.max() == top
    assert t.spacing == (1.0, -1.0) and t.shape == (6, 7) and t.source == "h.png"


def test_nan_nodata_geotiff_round_trip(tmp_path):
    rasterio = needs_rasterio()
    z = np.arange(30, dtype=np.int16).reshape(5, 6) + 100
    z[2, 3] = -9999
    path = tmp_path / "nodata.tif"
    profile = dict(
        driver="GTiff",
        width=6,
        height=5,
        count=1,
        dtype="int16",
        crs="EPSG:32611",
        nodata=-9999,
        transform=rasterio.Affine(10.0, 0.0, 500000.0, 0.0, -10.0, 4000000.0),
    )
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z, 1)
    t = load_dem(path)
    assert np.isnan(t.heights[2, 3]) and np.isfinite(t.heights).sum() == 29
    assert t.heights[0, 0] == 100.0 and t.heights.dtype == np.float32
    assert t.origin == (500005.0, 3999995.0) and t.spacing == (10.0, -10.0) and t.crs == "EPSG:32611"
    assert describe_dem(t)["nodata_count"] == 1

    f = tmp_path / "float_nan.tif"
    zf = z.astype(np.float32)
    zf[2, 3] = np.nan
    with rasterio.open(f, "w", **{**profile, "dtype": "float32", "nodata": np.nan}) as ds:
        ds.write(zf, 1)
    np.testing.assert_array_equal(load_dem(f).heights, zf)


def test_geotiff_scale_and_offset_are_applied(tmp_path):
    # heights stored as int16 decimetres above 1000 m: height = value * scale + offset (GDAL's convention)
    rasterio = needs_rasterio()
    z = np.array([[100, 200, 300], [400, -9999, 600]], np.int16)
    path = tmp_path / "scaled.tif"
    with rasterio.open(path, "w", driver="GTiff", width=3, height=2, count=1, dtype="int16", crs="EPSG:32611",
                       nodata=-9999, transform=rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0)) as ds:  # fmt: skip
        ds.write(z, 1)
        ds.scales, ds.offsets = (0.1,), (1000.0,)
    h = load_dem(path).heights
    np.testing.assert_allclose(h[0], [1010.0, 1020.0, 1030.0])
    assert h[1, 0] == 1040.0 and np.isnan(h[1, 1])


def test_geotiff_band_choice(tmp_path):
    rasterio = needs_rasterio()
    path = tmp_path / "two.tif"
    z = np.stack([np.zeros((4, 4)), np.full((4, 4), 7.0)]).astype(np.float32)
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=4,
        height=4,
        count=2,
        dtype="float32",
        crs="EPSG:32611",
        transform=rasterio.Affine(10.0, 0.0, 0.0, 0.0, -10.0, 40.0),
    ) as ds:
        ds.write(z)
    assert load_dem(path, band=2).heights.max() == 7.0
    with pytest.raises(InvalidInputError, match="band must be between 1 and 2"):
        load_dem(path, band=3)


def test_geotiff_with_crs_but_no_geotransform_is_north_up(tmp_path):
    # rasterio reports the identity transform for a TIFF without a geotransform: with a CRS it was read south-up
    # (dy = +1, origin (0.5, 0.5)); now it is an unreferenced grid as without a CRS, and the CRS is named as ignored
    rasterio = needs_rasterio()
    from rasterio.errors import NotGeoreferencedWarning

    z = np.arange(6, dtype=np.float32).reshape(2, 3)
    for name, crs in (("crs_only.tif", "EPSG:32611"), ("plain.tif", None)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(tmp_path / name, "w", driver="GTiff", width=3, height=2, count=1, dtype="float32",
                               crs=crs) as ds:  # fmt: skip
                ds.write(z, 1)
    with pytest.warns(UserWarning, match=r"crs_only.tif: its CRS EPSG:32611 is ignored because the file has no "
                                         r"geotransform"):  # fmt: skip
        t = load_dem(tmp_path / "crs_only.tif")
    assert t.spacing == (1.0, -1.0) and t.origin == (0.0, 0.0) and t.crs is None
    np.testing.assert_array_equal(t.heights, z)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no CRS: nothing to warn about
        plain = load_dem(tmp_path / "plain.tif")
    assert (plain.spacing, plain.origin, plain.crs) == (t.spacing, t.origin, t.crs)


US_FOOT = 1200 / 3937  # metres per US survey foot
SMALL_Z = np.array([[100.0, 110.0, 120.0], [130.0, 140.0, 150.0]], np.float32)


def write_small_tif(path: Path, crs: str, transform: tuple[float, ...], units: str | None = None) -> Path:
    """:data:`SMALL_Z` as a float32 GeoTIFF in ``crs`` with ``transform`` = (dx, x0, dy, y0), the band's height
    unit ``units`` if given."""
    rasterio = needs_rasterio()
    dx, x0, dy, y0 = transform
    with rasterio.open(path, "w", driver="GTiff", width=3, height=2, count=1, dtype="float32", crs=crs,
                       transform=rasterio.Affine(dx, 0.0, x0, 0.0, dy, y0)) as ds:  # fmt: skip
        ds.write(SMALL_Z, 1)
        if units is not None:
            ds.units = (units,)
    return path


def test_geotiff_in_us_survey_feet_becomes_metres(tmp_path):
    # EPSG:2229 (NAD83 / California zone 5) counts US survey feet: spacing and origin become metres, the CRS its
    # metre twin EPSG:26945; heights stay as stored unless the band names their unit
    z, transform = SMALL_Z, (10.0, 6500000.0, -10.0, 1900000.0)
    write_small_tif(tmp_path / "ft.tif", "EPSG:2229", transform)
    with pytest.warns(UserWarning, match="heights are kept as stored"):
        t = load_dem(tmp_path / "ft.tif")
    assert t.spacing == pytest.approx((10.0 * US_FOOT, -10.0 * US_FOOT), rel=1e-12)
    assert t.origin == pytest.approx((6500005.0 * US_FOOT, 1899995.0 * US_FOOT), rel=1e-12)
    assert t.crs == "EPSG:26945" and "US survey foot" in t.source
    np.testing.assert_array_equal(t.heights, z)

    # the band says its heights are feet too
    t = load_dem(write_small_tif(tmp_path / "ft_z.tif", "EPSG:2229", transform, units="US survey foot"))
    np.testing.assert_allclose(t.heights, z * US_FOOT, rtol=1e-6)
    assert t.spacing == pytest.approx((10.0 * US_FOOT, -10.0 * US_FOOT), rel=1e-12)


def test_georeferenced_npz_in_feet_becomes_metres(tmp_path):
    needs_rasterio()  # an EPSG code's unit is looked up through rasterio
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    transform = np.array([6500000.0, 10.0, 0, 1900000.0, 0, -20.0])
    np.savez(tmp_path / "ft.npz", elevation=z, transform=transform, crs="EPSG:2229", units="ft")
    t = load_dem(tmp_path / "ft.npz")
    assert t.spacing == pytest.approx((10.0 * US_FOOT, -20.0 * US_FOOT), rel=1e-12)
    assert t.origin == pytest.approx((6500005.0 * US_FOOT, 1899990.0 * US_FOOT), rel=1e-12)
    assert t.crs == "EPSG:26945"
    np.testing.assert_allclose(t.heights, z * 0.3048, rtol=1e-6)  # units names the heights' unit
    np.savez(tmp_path / "m.npz", elevation=z, transform=transform, crs="EPSG:2229", units="m")
    np.testing.assert_array_equal(load_dem(tmp_path / "m.npz").heights, z)


# ---------------------------------------------------------------------------------------------- refusals
def test_missing_file(tmp_path):
    with pytest.raises(DataFileError, match=r"nope\.npz' does not exist"):
        load_dem(tmp_path / "nope.npz")


def test_unknown_extension(tmp_path):
    (tmp_path / "dem.txt").write_text("ncols 2\n")  # an .asc is read now, as GDAL reads it
    with pytest.raises(
        InvalidInputError, match=r"unknown DEM extension '\.txt'; supported: \.npy, \.npz, \.png"
    ):
        load_dem(tmp_path / "dem.txt")


def test_directory_is_refused(tmp_path):
    (tmp_path / "d.npy").mkdir()
    with pytest.raises(DataFileError, match="not a regular file"):
        load_dem(tmp_path / "d.npy")


@pytest.mark.parametrize("band", [0, -1, 1.5, True])
def test_bad_band(tmp_path, band):
    with pytest.raises(InvalidInputError, match="band must be a positive"):
        load_dem(tmp_path / "x.npy", band=band)


def test_band_on_single_band_format(tmp_path):
    np.save(tmp_path / "z.npy", np.zeros((2, 2)))
    with pytest.raises(InvalidInputError, match="band applies to GDAL rasters only"):
        load_dem(tmp_path / "z.npy", band=2)


def test_1d_array(tmp_path):
    np.save(tmp_path / "line.npy", np.arange(5.0))
    with pytest.raises(
        DataFileError, match=r"line\.npy.*expected a 2-D \(H, W\) elevation grid; got array of shape \(5,\)"
    ):
        load_dem(tmp_path / "line.npy")


def test_too_small_and_non_numeric(tmp_path):
    np.save(tmp_path / "one.npy", np.zeros((1, 5)))
    with pytest.raises(DataFileError, match="at least 2 x 2 nodes"):
        load_dem(tmp_path / "one.npy")
    np.save(tmp_path / "s.npy", np.array([["a", "b"], ["c", "d"]]))
    with pytest.raises(DataFileError, match="expected real-valued elevation data; got array of dtype <U1"):
        load_dem(tmp_path / "s.npy")
    np.save(tmp_path / "b.npy", np.zeros((2, 2), bool))
    with pytest.raises(DataFileError, match="dtype bool"):
        load_dem(tmp_path / "b.npy")


def test_all_nodata(tmp_path):
    np.save(tmp_path / "nan.npy", np.full((3, 3), np.nan))
    with pytest.raises(DataFileError, match="all nodata"):
        load_dem(tmp_path / "nan.npy")


@pytest.mark.parametrize("name", ["text.npy", "text.npz", "text.png", "text.tif"])
def test_text_file(tmp_path, name):
    if name.endswith(".tif"):
        needs_rasterio()
    (tmp_path / name).write_text("this is not elevation data\n")
    with pytest.raises(DataFileError, match=rf"cannot read '.*{name}': expected a"):
        load_dem(tmp_path / name)


def test_pickled_npy(tmp_path):
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(DataFileError, match=r"obj\.npy.*expected a NumPy \.npy array file"):
        load_dem(tmp_path / "obj.npy")


def _npy_declaring(shape: tuple[int, ...]) -> bytes:
    """A 100-byte .npy file whose header declares ``shape`` float64 (far more data than it holds)."""
    header = f"{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}".encode()
    header += b" " * (-(10 + len(header) + 1) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + bytes(8)


def test_huge_declared_shape_is_a_data_file_error_not_an_allocation(tmp_path):
    # the header declared 10^8 x 10^8 floats: np.load allocated them first (MemoryError for 71 PiB)
    (tmp_path / "huge.npy").write_bytes(_npy_declaring((10**8, 10**8)))
    with pytest.raises(DataFileError, match=r"huge\.npy.*declares shape \(100000000, 100000000\).*holds 8 bytes"):
        load_dem(tmp_path / "huge.npy")
    import zipfile

    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as archive:
        archive.writestr("elevation.npy", _npy_declaring((10**8, 10**8)))
    with pytest.raises(DataFileError, match=r"huge\.npz.*member 'elevation' declares shape"):
        load_dem(tmp_path / "huge.npz")
    (tmp_path / "short.npy").write_bytes(_npy_declaring((3, 4)))  # truncated: 8 of 96 bytes
    with pytest.raises(DataFileError, match=r"short\.npy.*declares shape \(3, 4\) of float64 \(96 bytes\)"):
        load_dem(tmp_path / "short.npy")
    (tmp_path / "plain.npz").write_bytes(_npy_declaring((10**5, 10**5)))  # an .npy under an .npz name: no check
    with pytest.raises(DataFileError, match=r"plain\.npz.*declares shape \(100000, 100000\)"):  # MemoryError
        load_dem(tmp_path / "plain.npz")


def test_npz_without_elevation(tmp_path):
    np.savez(tmp_path / "many.npz", a=np.zeros((2, 2)), b=np.ones((3, 3)), c=np.arange(3))
    with pytest.raises(DataFileError, match=r"exactly one 2-D array; got a \(2, 2\), b \(3, 3\), c \(3,\)"):
        load_dem(tmp_path / "many.npz")


def test_an_empty_npz_says_it_holds_no_arrays(tmp_path):
    """np.savez() with no arrays starts with the zip end-of-directory record: it was called 'not a NumPy .npz'."""
    np.savez(tmp_path / "empty.npz")
    with pytest.raises(DataFileError, match="got no arrays"):
        load_dem(tmp_path / "empty.npz")


def test_npz_with_text_where_numbers_belong_is_a_data_file_error(tmp_path):
    z = np.zeros((2, 2))
    np.savez(tmp_path / "t.npz", elevation=z, transform=np.array("a"))
    with pytest.raises(DataFileError, match="GDAL geotransform of 6 finite numbers"):
        load_dem(tmp_path / "t.npz")
    np.savez(tmp_path / "m.npz", elevation=z, transform=np.array([0.0, 1.0, 0, 0.0, 0, -1.0]), crs="EPSG:4326",
             dx_m=np.array("thirty"), dy_m=np.array(30.0))  # fmt: skip
    with pytest.raises(DataFileError, match="dx_m"):
        load_dem(tmp_path / "m.npz")


@pytest.mark.parametrize("ext", ["npz", "tif"])
def test_a_projected_grid_labelled_geographic_is_refused(tmp_path, ext):
    """A UTM transform (394000, 30, 0, 3798000, 0, -30) under crs EPSG:4326 loaded silently as degrees: spacing
    (1.67e6, -3.3e6) m and lat_0 = 3797985 in the local CRS. Latitudes beyond ±90 cannot be degrees; now a
    DataFileError names them. A grid reaching the poles exactly (nodes at ±90) still loads."""
    z = np.arange(16.0).reshape(4, 4)
    transforms = {"utm": (394000.0, 30.0, 0.0, 3798000.0, 0.0, -30.0), "poles": (0.0, 1.0, 0.0, 120.0, 0.0, -60.0)}
    for name, transform in transforms.items():
        path = tmp_path / f"{name}.{ext}"
        if ext == "npz":
            np.savez(path, elevation=z, transform=np.array(transform), crs=np.array("EPSG:4326"))
        else:
            rasterio = needs_rasterio()
            with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float64",
                               crs="EPSG:4326", transform=rasterio.Affine.from_gdal(*transform)) as ds:
                ds.write(z, 1)
        if name == "utm":
            with pytest.raises(DataFileError, match=r"EPSG:4326 is geographic \(degrees\), but the grid's node "
                               r"latitudes run from 3797895 to 3797985; expected them within \[-90, 90\]"):
                load_dem(path)
        else:
            with pytest.warns(UserWarning, match=r"err .* by an unbounded amount \(a row of nodes at a pole"):
                t = load_dem(path)  # nodes at 90, 30, -30, -90
            assert t.extent[2:] == pytest.approx((-3 * EARTH_RADIUS_M * math.radians(60.0), 0.0))


def test_npz_bad_transform(tmp_path):
    np.savez(tmp_path / "t.npz", elevation=np.zeros((2, 2)), transform=np.array([0.0, 1.0, 0.0]))
    with pytest.raises(DataFileError, match="GDAL geotransform of 6 finite numbers"):
        load_dem(tmp_path / "t.npz")
    np.savez(
        tmp_path / "r.npz", elevation=np.zeros((2, 2)), transform=np.array([0.0, 1.0, 0.5, 0.0, 0.0, -1.0])
    )
    with pytest.raises(DataFileError, match="rotated geotransform"):
        load_dem(tmp_path / "r.npz")


def test_rgb_png(tmp_path):
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(
        DataFileError, match=r"rgb\.png.*expected a single-channel 8- or 16-bit greyscale.*got a RGB"
    ):
        load_dem(tmp_path / "rgb.png")


def test_palette_geotiff(tmp_path):
    rasterio = needs_rasterio()
    from rasterio.enums import ColorInterp

    path = tmp_path / "palette.tif"
    with rasterio.open(
        path,
        "w",
        driver="GTiff",
        width=4,
        height=4,
        count=1,
        dtype="uint8",
        crs="EPSG:4326",
        transform=rasterio.Affine(1.0, 0.0, 0.0, 0.0, -1.0, 4.0),
    ) as ds:
        ds.write(np.zeros((4, 4), np.uint8), 1)
        ds.write_colormap(1, {0: (255, 0, 0, 255), 1: (0, 255, 0, 255)})
        ds.colorinterp = [ColorInterp.palette]
    with pytest.raises(
        DataFileError, match=r"palette\.tif.*colour image band \(palette\), not elevation data"
    ):
        load_dem(path)


def test_geotiff_without_rasterio(tmp_path, monkeypatch):
    real_import = builtins.__import__

    def no_rasterio(name, *args, **kwargs):
        if name == "rasterio" or name.startswith("rasterio."):
            raise ImportError("No module named 'rasterio'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rasterio)
    (tmp_path / "dem.tif").write_bytes(b"II*\x00")
    with pytest.raises(
        MissingDependencyError, match=r"reading GeoTIFF needs rasterio: pip install 'stepterrain\[geo\]'"
    ):
        load_dem(tmp_path / "dem.tif")


def test_heights_beyond_float32_are_refused_not_read_as_nodata(tmp_path):
    z = np.full((3, 4), 100.0)
    z[1, 2] = 1e39  # finite in float64, inf in float32
    path = tmp_path / "big.npy"
    np.save(path, z)
    with pytest.raises(DataFileError, match=r"beyond float32 .* got 1e\+39 at index \(1, 2\)"):
        load_dem(path)
    z[1, 2] = np.nan  # real nodata still reads as a hole
    np.save(path, z)
    assert np.isnan(load_dem(path).heights[1, 2])


@pytest.mark.parametrize("case", ["complex", "beyond-float32", "scaled-beyond-float32"])
def test_geotiff_complex_or_beyond_float32_is_refused_as_npy_is(tmp_path, case):
    """A complex band kept its real part silently, and a float64 value beyond float32 (or an int16 one scaled
    beyond it) was cast to inf, then read as nodata (a hole); both are DataFileErrors now, in .npy's words."""
    rasterio = needs_rasterio()
    z = np.full((3, 4), 100.0)
    dtype, scale = {"complex": ("complex64", 1.0), "beyond-float32": ("float64", 1.0),
                    "scaled-beyond-float32": ("int16", 1e35)}[case]  # fmt: skip
    if case == "complex":
        z = z + 1j
    else:
        z[1, 2] = 1e39 if case == "beyond-float32" else 10000.0  # scaled: about 1e39, beside 1e37
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=1, dtype=dtype, crs="EPSG:32611",
                       transform=rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0)) as ds:  # fmt: skip
        ds.write(z.astype(dtype), 1)
        ds.scales = (scale,)
    match = (r"dem\.tif.*expected real-valued elevation data; got band 1 of dtype complex64$" if case == "complex"
             else r"dem\.tif.*band 1 holds heights beyond float32 .*; got [\d.]+e\+39 at index \(1, 2\)$")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning or overflow on the way
        with pytest.raises(DataFileError, match=match):
            load_dem(path)


def test_compound_crs_vertical_feet_become_metres(tmp_path):
    """A compound CRS names the heights' unit (NAD83 / UTM 11N + NAVD88 height (ftUS)): with no band unit the
    heights become metres and ``crs`` keeps the horizontal part, which still applies; a band unit wins."""
    z, transform = SMALL_Z, (30.0, 380000.0, -30.0, 3800000.0)
    write_small_tif(tmp_path / "navd88_ft.tif", "EPSG:26911+6360", transform)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t = load_dem(tmp_path / "navd88_ft.tif")
    np.testing.assert_allclose(t.heights, z * US_FOOT, rtol=1e-6)
    assert t.crs == "EPSG:26911" and t.spacing == (30.0, -30.0)
    t = load_dem(write_small_tif(tmp_path / "band_m.tif", "EPSG:26911+6360", transform, units="metre"))
    np.testing.assert_array_equal(t.heights, z)
    transform = np.array([380000.0, 30.0, 0, 3800000.0, 0, -30.0])
    np.savez(tmp_path / "navd88_ft.npz", elevation=z, transform=transform, crs="EPSG:26911+6360")
    t = load_dem(tmp_path / "navd88_ft.npz")
    np.testing.assert_allclose(t.heights, z * US_FOOT, rtol=1e-6)
    assert t.crs == "EPSG:26911"
    np.savez(tmp_path / "plain.npz", elevation=z, transform=transform, crs="EPSG:26911")
    np.testing.assert_array_equal(load_dem(tmp_path / "plain.npz").heights, z)
