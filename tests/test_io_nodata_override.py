"""load_dem's ``nodata`` and the CLI's ``--nodata``: values the caller marks missing besides a file's own nodata.

A DEM whose nodata value was lost (-9999 voids in a GeoTIFF, an .npy, a PNG) could only be fixed by editing the file
(``gdal_edit.py -a_nodata``) or re-saving it as an .npz with a ``nodata``; the warning named those fixes alone. Now
``load_dem(path, nodata=-9999)`` and ``--nodata -9999`` (steps, closeup, texture, info, batch, globe) declare it
for the read: compared with the values as stored (a band's before its scale and offset), in the band's dtype,
adding to the file's own nodata and mask; the warnings of that value are not said, and the hints offer it. Every
test here failed before (load_dem took no ``nodata``; the CLI had no ``--nodata``)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import stepterrain as st
from stepterrain import load_dem
from stepterrain.errors import DataFileError, InvalidInputError

from .conftest import run_cli as run

VOID = -9999


def _real(step: int = 8) -> np.ndarray:
    """Real heights (the embedded DEM, every ``step``-th node), rounded to whole metres."""
    return np.round(st.sample_dem().heights[::step, ::step]).astype(np.float64)


def _voids(shape: tuple[int, int]) -> np.ndarray:
    voids = np.zeros(shape, bool)
    voids[3:6, 4:9] = voids[20, 30] = True
    return voids


def _read(path: Path, **kwargs) -> tuple[st.Terrain, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        terrain = load_dem(path, **kwargs)
    return terrain, [str(w.message) for w in caught if "marks voids" in str(w.message)]


def _geotiff(path: Path, z: np.ndarray, nodata: float | None = None, scale: float | None = None) -> Path:
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    with rasterio.open(path, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1, dtype=z.dtype.name,
                       crs="EPSG:32611", transform=Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0),
                       nodata=nodata) as dataset:  # fmt: skip
        dataset.write(z, 1)
        if scale is not None:
            dataset.scales = (scale,)
    return path


@pytest.mark.parametrize("dtype", ["int16", "int32", "float32", "float64"])
def test_geotiff_nodata_marks_the_stored_value_and_silences_its_warning(tmp_path, dtype):
    real = _real()
    voids = _voids(real.shape)
    z = np.where(voids, VOID, real).astype(dtype)
    path = _geotiff(tmp_path / "dem.tif", z)
    as_stored, told = _read(path)
    text = "-9999.0" if dtype == "float64" else "-9999"  # a float64 value written in full
    assert len(told) == 1 and f"or pass nodata={text})" in told[0], told  # the hint offers it
    np.testing.assert_array_equal(as_stored.heights, z.astype(np.float32))
    declared, told = _read(path, nodata=VOID)
    assert told == []
    np.testing.assert_array_equal(np.isnan(declared.heights), voids)
    np.testing.assert_array_equal(declared.heights[~voids], real[~voids].astype(np.float32))
    # as gdal_edit.py -a_nodata would declare it: the same heights
    rasterio = pytest.importorskip("rasterio")
    with rasterio.open(path, "r+") as dataset:
        dataset.nodata = VOID
    np.testing.assert_array_equal(load_dem(path).heights, declared.heights)


def test_geotiff_nodata_adds_to_the_files_own_and_to_a_crop_window(tmp_path):
    real = _real()
    voids = _voids(real.shape)
    srtm = np.zeros(real.shape, bool)
    srtm[10:12, 10:12] = True
    z = np.where(voids, VOID, np.where(srtm, -32768, real)).astype(np.int16)
    path = _geotiff(tmp_path / "dem.tif", z, nodata=-32768)
    terrain, told = _read(path, nodata=[VOID])
    assert told == []
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids | srtm)  # both: it adds, does not replace
    # a crop's window read alone (rows 2-5, columns 3-8 of the nodes at the cells' centres): its cells marked too
    crop = (500000.0 + 30 * 3, 500000.0 + 30 * 9, 4000000.0 - 30 * 6, 4000000.0 - 30 * 2)
    window = load_dem(path, crop=crop, nodata=VOID)
    assert window.shape == (4, 6)
    np.testing.assert_array_equal(np.isnan(window.heights), voids[2:6, 3:9])


def test_geotiff_nodata_is_compared_before_the_band_scale_in_the_bands_dtype(tmp_path):
    real = _real()
    voids = _voids(real.shape)
    z = np.where(voids, VOID, real * 10).astype(np.int16)  # decimetres, scale 0.1: heights in metres
    path = _geotiff(tmp_path / "scaled.tif", z, scale=0.1)
    stored = load_dem(path, nodata=VOID)
    np.testing.assert_array_equal(np.isnan(stored.heights), voids)
    np.testing.assert_allclose(stored.heights[~voids], real[~voids], rtol=1e-6)
    with pytest.warns(UserWarning, match="marks voids"):  # the scaled value marks nothing, and says so
        with pytest.warns(UserWarning, match=r"nodata=-999.9000000000001 is no value of the file's int16 cells"):
            assert not np.isnan(load_dem(path, nodata=VOID * 0.1).heights).any()
    # a float32 band: the float32 rounding of the value (1e20 is 1.00000002e+20 there), as GDAL compares it
    f = np.where(voids, np.float32(1e20), real).astype(np.float32)
    path = _geotiff(tmp_path / "fill.tif", f)
    terrain, told = _read(path, nodata=1e20)
    assert told == []
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids)
    # an integer band: a value it cannot hold marks no cell
    with pytest.warns(UserWarning, match="marks voids"):
        with pytest.warns(UserWarning, match="nodata=-9998.5 is no value of the file's int16 cells"):
            assert not np.isnan(load_dem(tmp_path / "scaled.tif", nodata=VOID + 0.5).heights).any()


def test_float64_lowest_value_refusal_is_lifted_by_nodata(tmp_path):
    real = _real()
    voids = _voids(real.shape)
    lowest = -np.finfo(np.float64).max
    z = np.where(voids, lowest, real)
    path = _geotiff(tmp_path / "f64.tif", z)
    with pytest.raises(DataFileError, match=r"or pass nodata=-1\.7976931348623157e\+308\)$"):
        load_dem(path)
    terrain = load_dem(path, nodata=lowest)
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids)
    np.save(tmp_path / "f64.npy", z)
    np.testing.assert_array_equal(np.isnan(load_dem(tmp_path / "f64.npy", nodata=float(lowest)).heights), voids)


@pytest.mark.parametrize("dtype", ["int16", "float32", "float64"])
def test_npy_and_npz_nodata(tmp_path, dtype):
    real = _real()
    voids = _voids(real.shape)
    other = np.zeros(real.shape, bool)
    other[30, 5] = True
    z = np.where(voids, VOID, np.where(other, -32767, real)).astype(dtype)
    np.save(tmp_path / "dem.npy", z)
    terrain, told = _read(tmp_path / "dem.npy", nodata=VOID)
    # the other value, not declared, is still named
    assert len(told) == 1 and " hold -9999" not in told[0] and "-32767" in told[0], told
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids)
    # several values at once, a NumPy scalar among them
    terrain = load_dem(tmp_path / "dem.npy", nodata=(np.int16(VOID), -32767.0))
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids | other)
    # an .npz's own nodata and mask still apply: the value adds to them
    mask = np.zeros(real.shape, bool)
    mask[0, 0] = True
    np.savez(tmp_path / "dem.npz", elevation=z, nodata=-32767, mask=mask)
    terrain, told = _read(tmp_path / "dem.npz", nodata=VOID)
    assert told == []
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids | other | mask)
    before, told = _read(tmp_path / "dem.npz")
    text = "-9999.0" if dtype == "float64" else "-9999"
    assert len(told) == 1 and told[0].endswith(f"(save a 'nodata' of {text} beside the heights, or pass nodata={text})")
    np.testing.assert_array_equal(np.isnan(before.heights), other | mask)


def test_png_heightmap_nodata_is_its_grey_value(tmp_path):
    from PIL import Image

    real = _real()
    voids = _voids(real.shape)
    z = np.where(voids, 0, real).astype(np.uint16)  # a 16-bit heightmap whose voids are black
    Image.fromarray(z).save(tmp_path / "dem.png")
    assert not np.isnan(load_dem(tmp_path / "dem.png").heights).any()
    terrain = load_dem(tmp_path / "dem.png", nodata=0)
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids)
    np.testing.assert_array_equal(terrain.heights[~voids], real[~voids].astype(np.float32))


def test_terrarium_tile_nodata_is_a_decoded_height(tmp_path):
    from PIL import Image

    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 0], rgb[..., 1] = 128, 100  # 100 m
    rgb[1, 2] = 0  # black: -32768, Terrarium's void
    Image.fromarray(rgb).save(tmp_path / "tile.png")
    assert load_dem(tmp_path / "tile.png", height_encoding="terrarium").heights[1, 2] == -32768
    terrain = load_dem(tmp_path / "tile.png", height_encoding="terrarium", nodata=-32768)
    assert np.isnan(terrain.heights).sum() == 1 and np.isnan(terrain.heights[1, 2])


@pytest.mark.parametrize("bad", ["-9999", True, np.bool_(False), 1 + 2j, [], [VOID, "x"], None.__class__, 10**400])
def test_a_nodata_that_is_not_a_real_number_is_refused_naming_it(tmp_path, bad):
    np.save(tmp_path / "dem.npy", _real())
    with pytest.raises(InvalidInputError, match=r"^nodata must be a real number"):
        load_dem(tmp_path / "dem.npy", nodata=bad)


@pytest.mark.skipif(np.finfo(np.longdouble).max <= np.finfo(np.float64).max, reason="long double is float64 here")
@pytest.mark.parametrize("exponent", [400, -400])
def test_a_long_double_nodata_beyond_float64_is_refused_naming_it(tmp_path, exponent):
    """nodata=np.longdouble(10)**400 became inf (marking no cell: the value given was dropped, silently) and
    np.longdouble(10)**-400 became 0.0 (marking every cell at 0 m missing), while nodata=10**400 is refused as
    beyond float64: both are refused so now, naming nodata."""
    z = _real()
    z[:3] = 0.0
    np.save(tmp_path / "dem.npy", z)
    with pytest.raises(InvalidInputError, match=r"^nodata must be a real number.* within float64; got "):
        load_dem(tmp_path / "dem.npy", nodata=np.longdouble(10) ** exponent)
    np.testing.assert_array_equal(np.isnan(load_dem(tmp_path / "dem.npy", nodata=np.longdouble(-0.0)).heights),
                                  z == 0)  # a long double zero is 0


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_non_finite_nodata_changes_nothing(tmp_path, value):
    z = _real().astype(np.float32)
    z[0, 0], z[1, 1] = np.inf, np.nan
    np.save(tmp_path / "dem.npy", z)
    np.testing.assert_array_equal(load_dem(tmp_path / "dem.npy", nodata=value).heights,
                                  load_dem(tmp_path / "dem.npy").heights)


# ---------------------------------------------------------------------------------------------- command line
def _voided_npy(path: Path) -> tuple[Path, int]:
    real = _real()
    voids = _voids(real.shape)
    np.save(path, np.where(voids, VOID, real).astype(np.float32))
    return path, int(voids.sum())


def test_cli_info_nodata_forms(tmp_path, capsys):
    path, n = _voided_npy(tmp_path / "dem.npy")
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0 and json.loads(out)["nodata_count"] == 0
    assert "or pass --nodata -9999)" in err  # the hint as the option
    for given in (["--nodata", "-9999"], ["--nodata=-9999"], ["--nodata", "-9999,-1e+20"],
                  ["--nodata", "5", "--nodata", "-9999"]):
        code, out, err = run(capsys, "info", path, "--json", *given)
        assert code == 0, err
        assert json.loads(out)["nodata_count"] == n and "marks voids" not in err, given
    code, out, err = run(capsys, "info", path, "--nodata", "void")
    assert code == 2 and "--nodata" in err and "'void'" in err


@pytest.mark.parametrize("given", ["1e400", "-1e400", "-9999,1e999", "1e-400"])
def test_cli_nodata_beyond_float64_is_refused_naming_it(tmp_path, capsys, given):
    """--nodata 1e400 parsed to inf (which marks no cell: the value given was dropped, silently) and 1e-400 to 0.0
    (which marks every cell at height 0), while load_dem refuses nodata=10**400; now --nodata refuses both, as
    load_dem does, naming the option and the value. inf and nan as written stay accepted."""
    path, _ = _voided_npy(tmp_path / "dem.npy")
    code, out, err = run(capsys, "info", path, "--json", "--nodata", given)
    assert code == 2 and out == "" and "argument --nodata: expected numbers within float64" in err, err
    assert repr(given.split(",")[-1]) in err and "Traceback" not in err
    for fine in ("inf", "-inf", "nan", "5e-324", "-9999,inf"):
        code, out, err = run(capsys, "info", path, "--json", "--nodata", fine)
        assert code == 0, (fine, err)


def test_cli_steps_and_the_embedded_dem_take_nodata(tmp_path, capsys):
    path, n = _voided_npy(tmp_path / "dem.npy")
    out = tmp_path / "out.ply"
    code, _, err = run(capsys, "steps", path, "--nodata", "-9999", "--interval", "200", "-o", out)
    assert code == 0 and "marks voids" not in err, err
    import trimesh

    assert trimesh.load(out).vertices[:, 2].min() >= 0  # no -9999 m pit
    # the embedded DEM, its lowest height (315 m) as the value: those nodes are nodata
    low = int(np.count_nonzero(st.sample_dem().heights == 315.0))
    code, out_text, err = run(capsys, "info", "--json", "--nodata", "315")
    assert code == 0, err
    assert json.loads(out_text)["nodata_count"] == low > 0


def test_cli_globe_refuses_the_cells_nodata_marks(tmp_path, capsys):
    lat = np.linspace(89.0, -89.0, 10)
    lon = np.linspace(-179.0, 179.0, 20)
    z = np.full((10, 20), 100.0)
    z[4, 5] = VOID
    np.savez(tmp_path / "world.npz", elevation=z, lat=lat, lon=lon)
    code, _, err = run(capsys, "globe", tmp_path / "world.npz", "--nodata", "-9999", "-o", tmp_path / "g.ply")
    assert code == 2 and "1 nodata cell (--nodata -9999" in err, err
    code, _, err = run(capsys, "globe", "--nodata", "-9999", "-o", tmp_path / "g.ply")
    assert code == 2 and "--nodata applies to an INPUT file" in err, err
    assert not (tmp_path / "g.ply").exists()


# ---------------------------------------------------------------------------------------------- batch
def _tiles(folder: Path) -> list[Path]:
    folder.mkdir()
    real = _real(4)
    paths = []
    for k, half in enumerate((real[:, : real.shape[1] // 2], real[:, real.shape[1] // 2:])):
        z = half.astype(np.float32).copy()
        z[:4, :4] = VOID
        np.save(folder / f"t{k}.npy", z)
        paths.append(folder / f"t{k}.npy")
    return paths


def test_batch_nodata_applies_to_every_file_and_the_shared_range(tmp_path):
    from stepterrain.batch import batch

    from .test_export import glb_json

    _tiles(tmp_path / "tiles")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch(str(tmp_path / "tiles"), str(tmp_path / "out"), format=".glb", scheduler="serial",
                       nodata=VOID)
    assert report.ok and not [w for w in caught if "marks voids" in str(w.message)]
    extras = [glb_json(Path(r.path))["meshes"][0]["extras"] for r in report.done]
    assert len(extras) == 2 and all(e["nodata"] == [float(VOID)] for e in extras)
    # the shared levels from the files' heights without the voids: the default interval's isovalues start near
    # the lowest real height (315 m), not at -9999
    isovalues = extras[0]["isovalues"]
    assert min(isovalues) > 0, isovalues
    # without it, the voids are heights: the levels reach down to them
    with pytest.warns(UserWarning, match="marks voids"):
        report = batch(str(tmp_path / "tiles"), str(tmp_path / "out2"), format=".glb", scheduler="serial")
    assert len(report.done) == 2, report.results
    assert min(glb_json(Path(report.done[0].path))["meshes"][0]["extras"]["isovalues"]) < 0


def test_batch_nodata_refused_for_an_array_and_applied_to_a_series(tmp_path):
    from stepterrain.batch import batch, load_series

    with pytest.raises(InvalidInputError, match=r"^nodata applies to DEM files"):
        batch(_real(), str(tmp_path / "out"), tile_size=16, scheduler="serial", nodata=VOID)
    stack = np.stack([_real(16)] * 2).astype(np.float32)
    stack[1, 0, 0] = VOID
    np.save(tmp_path / "series.npy", stack)
    series = load_series(tmp_path / "series.npy", nodata=VOID)
    assert np.isnan(series).sum() == 1 and np.isnan(series[1, 0, 0])
    report = batch(str(tmp_path / "series.npy"), str(tmp_path / "frames"), format=".glb", scheduler="serial",
                   nodata=VOID)
    from .test_export import glb_json

    assert report.ok and all(min(glb_json(Path(r.path))["meshes"][0]["extras"]["isovalues"]) > 0 for r in report.done)
    # one raster cut into tiles: read with it once, before the tiles are cut
    z = _real(4).astype(np.float32)
    z[:4, :4] = VOID
    np.save(tmp_path / "one.npy", z)
    report = batch(str(tmp_path / "one.npy"), str(tmp_path / "tiles"), format=".glb", tile_size=64,
                   scheduler="serial", nodata=VOID)
    extras = [glb_json(Path(r.path))["meshes"][0]["extras"] for r in report.done]
    assert report.ok and len(extras) > 1 and all(min(e["isovalues"]) > 0 and e["nodata"] == [VOID] for e in extras)


def test_cli_batch_nodata(tmp_path, capsys):
    _tiles(tmp_path / "tiles")
    code, _, err = run(capsys, "batch", tmp_path / "tiles", "--nodata", "-9999", "--scheduler", "serial",
                       "--format", ".ply", "-o", tmp_path / "out")  # fmt: skip
    assert code == 0 and "marks voids" not in err, err
    import trimesh

    assert min(trimesh.load(p).vertices[:, 2].min() for p in (tmp_path / "out").glob("*.ply")) >= 0
    code, _, err = run(capsys, "batch", "--nodata", "315", "--scheduler", "serial", "--tile", "512",
                       "--format", ".ply", "-o", tmp_path / "embedded")  # fmt: skip
    assert code == 0, err


@pytest.mark.parametrize("command", ["steps", "closeup", "texture", "info", "batch", "globe"])
def test_every_dem_reading_subcommand_has_nodata_with_its_default(capsys, command):
    code, out, _ = run(capsys, command, "--help")
    assert code == 0
    text = " ".join(out.split())
    assert "--nodata V[,V...]" in text and "(default: none, the file's own nodata only)" in text


def test_cli_texture_takes_nodata(tmp_path, capsys):
    path, _ = _voided_npy(tmp_path / "dem.npy")
    code, _, err = run(capsys, "texture", path, "-o", tmp_path / "t.png")
    assert code == 0 and "or pass --nodata -9999)" in err, err  # the hint as texture's option
    code, _, err = run(capsys, "texture", path, "--nodata", "-9999", "-o", tmp_path / "t.png")
    assert code == 0 and "marks voids" not in err, err


@pytest.mark.parametrize("dtype", ["uint8", "int16", "uint16", "int32", "int64"])
def test_an_integer_band_matches_a_whole_nodata_within_its_dtype_only(dtype):
    """equals_nodata on an integer band: a fraction (100.01) or a value beyond the dtype marks no cell, a whole number
    marks exactly its cells (numpy 1.x compared ``uint8 == 100.01`` in float16, where 100.01 is 100)."""
    from stepterrain.io import equals_nodata

    a = np.array([[0, 100, 101], [100, 7, 127]], dtype=dtype)
    np.testing.assert_array_equal(equals_nodata(a, 100.0), a == 100)
    np.testing.assert_array_equal(equals_nodata(a, 100), a == 100)
    assert not equals_nodata(a, 100.01).any() and not equals_nodata(a, 99.99).any()
    assert not equals_nodata(a, float(np.iinfo(a.dtype).max) + 1.0).any()
    assert not equals_nodata(a, float(np.iinfo(a.dtype).min) - 1.0).any()
    assert equals_nodata(a, 100.0).dtype == bool and equals_nodata(a, 0.5).shape == a.shape


@pytest.mark.parametrize("command, subject, note", [
    ("steps", "the INPUT (or the embedded DEM)", ""), ("closeup", "the INPUT (or the embedded DEM)", ""),
    ("texture", "the INPUT (or the embedded DEM)", ""), ("info", "a DEM (or the embedded one)", "not for a mesh"),
    ("batch", "every DEM file (or the embedded DEM)", "the shared levels' height range is read with it too"),
    ("globe", "the INPUT", "fill them first"),
])
def test_nodata_help_says_whose_cells_it_marks_besides_their_own_nodata(capsys, command, subject, note):
    # the subcommand's own note was put between the subject and "besides its own nodata": info's read "not for a
    # mesh besides its own nodata value and mask", globe's "refused as its own nodata is (fill them first) besides
    # its own nodata value and mask"
    code, out, _ = run(capsys, command, "--help")
    assert code == 0
    text = " ".join(out.split())
    assert f"value(s) marking missing cells of {subject} besides its own nodata value and mask," in text
    assert note in text.split("--nodata V[,V...]")[-1]  # the subcommand's own word on them kept


@pytest.mark.parametrize("dtype, value, held", [
    ("uint16", 3.5, "whole numbers 0 to 65535"), ("int16", -99999.0, "whole numbers -32768 to 32767"),
    ("uint16", -1.0, "whole numbers 0 to 65535"), ("float32", 1e40, "magnitudes up to 3.4028235e+38"),
])
def test_a_nodata_no_cell_of_the_dtype_can_hold_is_warned_of(tmp_path, dtype, value, held):
    """nodata=3.5 or -99999 on an integer GeoTIFF (1e40 on a float32 one) marks no cell, as GDAL compares it (in the
    band's dtype), and said nothing: the voids the user meant stayed heights. Now a warning names the value, the dtype
    and what it holds; a value the dtype holds (and NaN/inf, which mark nothing by design) warns of nothing."""
    z = np.where(_voids((32, 40)), 3, 100 + np.arange(32 * 40).reshape(32, 40) % 50).astype(dtype)
    path = _geotiff(tmp_path / "dem.tif", z)
    with pytest.warns(UserWarning, match="is no value of") as caught:
        terrain = load_dem(path, nodata=value)
    told = [str(w.message) for w in caught if "is no value of" in str(w.message)]
    text = repr(value)[:-2] if repr(value).endswith(".0") else repr(value)
    assert told == [f"nodata={text} is no value of the file's {dtype} cells as stored ({held}): it marks no cell; "
                    "give the value its missing cells hold (`stepterrain info` shows the height range, "
                    "`gdalinfo -stats` the stored values)"]
    assert not np.isnan(terrain.heights).any()
    for fine, marked in ((3, z == 3), (float("nan"), False), (float("inf"), False), ((3, 100), (z == 3) | (z == 100))):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            heights = load_dem(path, nodata=fine).heights
        np.testing.assert_array_equal(np.isnan(heights), np.broadcast_to(marked, z.shape))


def test_cli_nodata_no_cell_can_hold_is_warned_of_as_the_option(tmp_path, capsys):
    """--nodata 3.5 (-99999) on a uint16 GeoTIFF or PNG: the warning names --nodata, the value and the dtype; of a list,
    the value no cell can hold alone, the other applied."""
    from PIL import Image

    z = np.where(_voids((32, 40)), 3, 100 + np.arange(32 * 40).reshape(32, 40) % 50).astype(np.uint16)
    Image.fromarray(z).save(tmp_path / "dem.png")
    for path in (_geotiff(tmp_path / "dem.tif", z), tmp_path / "dem.png"):
        code, out, err = run(capsys, "info", path, "--json", "--nodata", "3.5")
        assert code == 0 and json.loads(out)["nodata_count"] == 0, err
        assert "stepterrain info: warning: --nodata 3.5 is no value of the file's uint16 cells" in err, err
        code, out, err = run(capsys, "info", path, "--json", "--nodata", "-99999,3")
        assert code == 0 and json.loads(out)["nodata_count"] == int((z == 3).sum()), err
        assert "warning: --nodata -99999 is no value of the file's uint16 cells" in err and "--nodata 3 " not in err
        code, out, err = run(capsys, "info", path, "--json", "--nodata", "3")
        assert code == 0 and "warning" not in err, err
