"""Common nodata values a DEM file holds without declaring them are named as likely voids.

A GeoTIFF or .npy whose voids hold -9999 (ESRI's and many GeoTIFFs' NoData), -32768 or -32767 in a dtype wider than
int16 (a float32 copy of an SRTM tile), -99999 or 1e+20 (netCDF models' _FillValue) with no nodata value declared
was read as heights without a word: the stepped terrain got a pit or spike kilometres deep and the mesh was silently
wrong. Only the lowest value of an integer dtype and the extremes of a float one were named. Now load_dem warns once,
at its caller, when such a value lies far outside the other cells' values, counting its cells and giving the nodata to
declare; legitimate heights (the Dead Sea, ocean depths to -11000 m, a trench cell of exactly -9999 m among other
depths) and every real DEM of shared/data do not warn. Every test here but the real-data ones failed before."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st_h

import stepterrain as st
from stepterrain.io import load_dem

from .conftest import SHARED_DATA
from .conftest import run_cli as run

rasterio = pytest.importorskip("rasterio", reason="GeoTIFFs are written with rasterio")

TUJUNGA = SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz"


def _real(rows: int = 40, cols: int = 50) -> np.ndarray:
    """A corner of the Big Tujunga SRTM DEM (float64, metres)."""
    return np.load(TUJUNGA)["elevation"][:rows, :cols].astype(np.float64)


def _geotiff(path: Path, z: np.ndarray, nodata: float | None = None) -> Path:
    from rasterio.transform import Affine

    with rasterio.open(path, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1, dtype=z.dtype,
                       crs="EPSG:32611", transform=Affine(30.0, 0.0, 380000.0, 0.0, -30.0, 3800000.0),
                       nodata=nodata) as dataset:  # fmt: skip
        dataset.write(z, 1)
    return path


def _told(path: Path) -> tuple[st.Terrain, list[warnings.WarningMessage]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        terrain = load_dem(path)
    return terrain, [w for w in caught if "common nodata value" in str(w.message)]


@pytest.mark.parametrize(("dtype", "sentinel", "text"), [
    ("int16", -9999, "-9999"),
    ("int32", -32768, "-32768"),
    ("float32", -32767, "-32767"),
    ("float32", -99999, "-99999"),
    ("float32", -9999, "-9999"),
    ("float32", 1e20, "1e+20"),
    ("float64", float(np.float32(1e20)), "1.0000000200408773e+20"),  # a float32 fill kept through a widening copy
])  # fmt: skip
def test_an_undeclared_common_nodata_value_far_from_the_heights_is_named_with_the_fix(tmp_path, dtype, sentinel, text):
    real = _real()
    z = np.round(real).astype(dtype)
    voids = np.zeros(z.shape, bool)
    voids[5:9, 10:16] = voids[30, 40] = True  # a void patch and a lone void, as an SRTM tile has them
    z[voids] = sentinel
    n = int(voids.sum())
    others = z[~voids]
    where = (f"far {'below' if sentinel < 0 else 'above'} the other cells' values "
             f"({float(others.min()):.6g} to {float(others.max()):.6g})")
    _geotiff(tmp_path / "dem.tif", z)
    np.save(tmp_path / "dem.npy", z)
    for name, what, fix in (("dem.tif", "band 1", f"`gdal_edit.py -a_nodata {text} dem.tif`"),
                            ("dem.npy", "array", f"save it as an .npz with a 'nodata' of {text}")):
        terrain, told = _told(tmp_path / name)
        assert [str(w.message) for w in told] == [
            f"{name}: {n} cells of {what} hold {text}, a common nodata value, {where}, which marks voids, but no "
            f"nodata value or mask of the file marks them: read as heights; if they are voids, declare it ({fix}, or "
            f"pass nodata={text})"]
        assert told[0].filename == __file__  # said at load_dem's caller
        np.testing.assert_array_equal(terrain.heights, z.astype(np.float32))  # still read as stored, as GDAL does
    # the value named, declared as the hint says, marks exactly those cells, and nothing warns
    for name, path in (("tif", _geotiff(tmp_path / "declared.tif", z, nodata=float(text))),
                       ("npz", tmp_path / "declared.npz")):
        if name == "npz":
            np.savez(path, elevation=z, nodata=float(text))
        terrain, told = _told(path)
        assert told == []
        np.testing.assert_array_equal(np.isnan(terrain.heights), voids)


def test_several_common_nodata_values_are_each_named_and_measured_from_the_heights(tmp_path):
    # -32768 and -9999 voids in one int32 grid: each named once, both far below the heights (not -32768 only below
    # -9999); a declared -9999 leaves -32768 named alone
    z = np.round(_real()).astype(np.int32)
    z[:3, :4] = -9999
    z[-2:, -5:] = -32768
    low, high = float(z[z > 0].min()), float(z.max())
    messages = [str(w.message) for w in _told(_geotiff(tmp_path / "two.tif", z))[1]]
    assert [m.split(", a common")[0] for m in messages] == ["two.tif: 12 cells of band 1 hold -9999",
                                                           "two.tif: 10 cells of band 1 hold -32768"]
    assert all(f"far below the other cells' values ({low:.6g} to {high:.6g})" in m for m in messages)
    messages = [str(w.message) for w in _told(_geotiff(tmp_path / "one.tif", z, nodata=-9999))[1]]
    assert [m.split(", a common")[0] for m in messages] == ["one.tif: 10 cells of band 1 hold -32768"]


def test_a_grid_of_nothing_but_a_common_nodata_value_is_named(tmp_path):
    # a tile of sea whose -9999 was not declared: a flat plain 10 km down, no terrain
    np.save(tmp_path / "sea.npy", np.full((4, 5), -9999.0, np.float32))
    assert [str(w.message).split(", which")[0] for w in _told(tmp_path / "sea.npy")[1]] == [
        "sea.npy: 20 cells of array hold -9999, a common nodata value, and no other cell holds a value"]


def test_legitimate_heights_at_or_near_common_nodata_values_do_not_warn(tmp_path):
    """Real terrain below sea level and ocean depths are heights: the Dead Sea's shore (-430 m), a bathymetry grid
    reaching -11000 m whose trench holds cells of exactly -9999 m among other depths (inside the others' range, or
    at its end with depths all along to it), an int32 grid down to -32768 m of a continuous slope."""
    real = _real()
    dead_sea = np.round(real - real.min() - 430.0).astype(np.int16)
    # bathymetry: the real relief stretched over -11000..+500 m, in int16; a trench row at exactly -9999
    stretch = (real - real.min()) / np.ptp(real) * 11500.0 - 11000.0
    bathymetry = np.round(stretch).astype(np.int16)
    bathymetry[10, 5:12] = -9999
    assert bathymetry.min() < -9999 < bathymetry.max()
    # a trench whose deepest cells are -9999: the depths run on to them, no gap
    trench = np.round(np.linspace(-9999.0, -2000.0, 40 * 50)).reshape(40, 50).astype(np.int16)
    assert trench.min() == -9999 and (trench == -9999).sum() == 1
    slope = np.linspace(-32768, -20000, 40 * 50).round().astype(np.int32).reshape(40, 50)
    for name, z in (("dead_sea", dead_sea), ("bathymetry", bathymetry), ("trench", trench), ("slope", slope)):
        for path in (_geotiff(tmp_path / f"{name}.tif", z), tmp_path / f"{name}.npy"):
            np.save(tmp_path / f"{name}.npy", z)
            terrain, told = _told(path)
            assert told == [], (path.name, [str(w.message) for w in told])
            np.testing.assert_array_equal(terrain.heights, z.astype(np.float32))


def test_no_real_dem_warns_of_a_common_nodata_value(tmp_path):
    # every DEM of shared/data (the global relief reaches -10082 m) and the embedded sample: no false alarm
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        st.sample_dem()
        for path in sorted(SHARED_DATA.iterdir()):
            if path.suffix in (".npz", ".npy") or (path.suffix == ".tif" and "bluemarble" not in path.name):
                load_dem(path)
    assert [str(w.message) for w in caught if "common nodata value" in str(w.message)] == []
    # the global relief's trench cells set to exactly -9999 m (its others reach -10082 m): heights, not voids
    relief = dict(np.load(SHARED_DATA / "global_relief.npz"))
    z = relief["elevation"].copy()
    trench = (z < -9000) & (z > -9990)
    assert trench.any() and z.min() < -9999
    z[trench] = -9999
    np.savez(tmp_path / "relief.npz", **{**relief, "elevation": z})
    assert _told(tmp_path / "relief.npz")[1] == []


def test_cli_says_the_common_nodata_warning_once(tmp_path, capsys):
    z = np.round(_real()).astype(np.int16)
    z[:4, :5] = -9999
    _geotiff(tmp_path / "dem.tif", z)
    code, out, err = run(capsys, "info", tmp_path / "dem.tif")
    assert code == 0, err
    assert err.count("dem.tif: 20 cells of band 1 hold -9999, a common nodata value") == 1, err
    assert "gdal_edit.py -a_nodata -9999 dem.tif" in err


@settings(max_examples=30, deadline=None)
@given(seed=st_h.integers(0, 2**31 - 1), dtype=st_h.sampled_from(["int16", "int32", "float32", "float64"]))
def test_cells_a_mask_marks_are_as_if_they_held_no_value(seed, dtype):
    # the check first looks only for candidate cells no mask marks, and skips the range pass where there are none:
    # a mask over cells (a declared nodata, an .npz mask) names the same values as those cells holding no value
    # (NaN in a float copy of the grid), or the cells' removal (the marked rows of an integer grid cut off)
    from stepterrain.io import _warn_void_values

    rng = np.random.default_rng(seed)
    z = np.round(_real(24, 30) - 1000.0 * rng.integers(0, 12)).astype(dtype)
    values = [-9999, -32767, -99999 if dtype != "int16" else -32767]
    for value in values:  # voids in whole rows, some marked, some not
        rows = rng.choice(24, size=int(rng.integers(0, 4)), replace=False)
        z[rows] = value
    marked = np.zeros(z.shape, bool)
    marked[rng.choice(24, size=int(rng.integers(0, 12)), replace=False)] = True

    def said(data, missing):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            _warn_void_values(Path("x.npy"), data, missing, "array")
        return [str(w.message) for w in caught if "common nodata value" in str(w.message)]

    masked = said(z, marked)
    assert masked == said(z[~marked.all(axis=1)], None)
    if dtype.startswith("float"):
        assert masked == said(np.where(marked, np.nan, z).astype(dtype), None)
