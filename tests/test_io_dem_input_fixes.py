"""load_dem's DEM input: refusals that give the way on (a netCDF or Surfer grid's gdal_translate, a tar's /vsitar/
path), a PNG's .aux.xml nodata text read as GDAL reads it, and the command line's --nodata values."""

from __future__ import annotations

import json
import shlex
import tarfile
import warnings

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import InvalidInputError

from .reference_texture import find_shared


@pytest.mark.parametrize(("name", "driver"), [("dem.nc", "netCDF"), ("dem.grd", "GSBG"), ("my dem.xyz", "XYZ")])
def test_a_gdal_raster_of_another_format_is_refused_with_the_gdal_translate_that_converts_it(tmp_path, name, driver):
    """A netCDF grid, a Surfer .grd or an XYZ grid (rasters GDAL reads, that load_dem does not) was refused as
    "unknown DEM extension '.nc'; supported: ..." alone, though load_dem's docs say `gdal_translate -of GTiff`
    converts it. The refusal gives that command, the path quoted for a shell; the GeoTIFF it writes reads."""
    pytest.importorskip("rasterio")
    import rasterio.shutil

    source = find_shared("big_tujunga_srtm_30m_utm11n.tif")
    path = tmp_path / name
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rasterio.shutil.copy(source, path, driver=driver)
    with pytest.raises(InvalidInputError, match=r"unknown DEM extension") as caught:
        st.load_dem(path)
    command = str(caught.value).split("`")[1]
    words = shlex.split(command)
    assert words[:3] == ["gdal_translate", "-of", "GTiff"] and words[3] == str(path), command
    assert words[4] == path.stem + ".tif", command
    converted = tmp_path / words[4]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rasterio.shutil.copy(words[3], converted, driver=words[2])  # what the command does
    np.testing.assert_allclose(st.load_dem(converted).heights, st.load_dem(source).heights, rtol=1e-6)


@pytest.mark.parametrize("suffix", [".tar", ".tgz"])
def test_a_local_tar_is_refused_naming_its_vsitar_path(tmp_path, suffix):
    """A local ``tiles.tar`` was refused as an unknown extension without a word of the ``/vsitar/`` path GDAL reads
    its files through (a ``.tar.gz``'s refusal gave it). It names it now, and that path reads."""
    pytest.importorskip("rasterio")
    source = find_shared("big_tujunga_srtm_30m_utm11n.tif")
    archive = tmp_path / f"tiles{suffix}"
    with tarfile.open(archive, "w:gz" if suffix == ".tgz" else "w") as tar:
        tar.add(source, arcname="dem.tif")
    with pytest.raises(InvalidInputError, match=r"unknown DEM extension") as caught:
        st.load_dem(archive)
    message = str(caught.value)
    hint = f"'/vsitar/{archive}/<name>.tif'"
    assert hint in message, message
    read = st.load_dem(hint.strip("'").replace("<name>", "dem"))
    np.testing.assert_array_equal(read.heights, st.load_dem(source).heights)


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize(("text", "malformed"), [
    ("7.5", False), ("7.6", False), ("0x7", True), ("7abc", True), ("1_0", True), ("abc", True), ("  7 ", False),
    ("-0.5", False), ("255.9", False), ("nan", False), ("+.7e1", False), ("7 8", True), ("1e-400", False),
    # GDAL's (CPLStrtod's) own spellings: MSVC's NaN and infinity (which old GDAL wrote), by prefix, NaN, inf and
    # Infinity as the whole text only (NAN, INFINITY, 'inf ' are 0 to it), one '+' skipped before a sign; white space
    # and digits in ASCII only (an Arabic-Indic 3 or a no-break space before 7 is 0 to it)
    ("1.#QNAN", False), ("-1.#IND", False), ("1.#INF", False), ("1.#SNAN junk", False), ("NaN", False),
    ("Infinity", False), ("NAN", True), ("INFINITY", True), ("inf ", True), ("+-7", False), ("\u0663", True),
    ("\u00a07", True),
])
def test_a_png_aux_xml_nodata_text_is_read_as_gdal_reads_it(tmp_path, bits, text, malformed):
    """A PNG heightmap's .aux.xml <NoDataValue> text was read by Python's float(): ``7.5`` masked no cell of the
    integer band (GDAL masks those at 7, casting it to the band's type), ``0x7``/``7abc``/``abc`` were no nodata
    (GDAL reads the number the text starts with, as C's strtod, else 0: cells at 0 / 7 / 0 masked) and ``1_0`` was
    10 (GDAL: 1). Each now masks the cells GDAL masks (checked here against rasterio's mask of the same file), and a
    text that is no number warns, naming what it was read as."""
    rasterio = pytest.importorskip("rasterio")
    from PIL import Image

    dtype = np.uint8 if bits == 8 else np.uint16
    values = np.array([[0, 1, 7, 8], [10, 255, 3, 4], [256, 7, 0, 9]]) % (256 if bits == 8 else 65536)
    png = tmp_path / "dem.png"
    Image.fromarray(values.astype(dtype)).save(png)
    png.with_name("dem.png.aux.xml").write_text(
        f"<PAMDataset>\n  <PAMRasterBand band=\"1\">\n    <NoDataValue>{text}</NoDataValue>\n  </PAMRasterBand>\n"
        "</PAMDataset>\n", encoding="utf-8")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(png) as src:
            gdal_missing = src.read_masks(1) == 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        heights = st.load_dem(png).heights
    np.testing.assert_array_equal(np.isnan(heights), gdal_missing, err_msg=text)
    messages = [str(w.message) for w in caught if "NoDataValue" in str(w.message)]
    assert len(messages) == malformed, messages
    if malformed:  # the text as it is: 'inf ' and a no-break space's '\xa07' are no number to GDAL, 'inf' and '7' are
        assert f"NoDataValue {text!r} in dem.png.aux.xml is not a number; read as " in messages[0], messages


def test_cli_nodata_underscore_is_refused(tmp_path, capsys):
    """``--nodata 1_0`` was read as 10 (Python's float() takes digit-grouping underscores), though GDAL's
    ``-a_nodata 1_0`` declares 1 (strtod stops at the underscore): which cells it marks depended on the tool. Refused
    now, naming the value; ``10`` and ``1.0`` as written read."""
    from .conftest import run_cli as run

    z = np.arange(20, dtype=np.float32).reshape(4, 5)
    np.save(tmp_path / "dem.npy", z)
    for given in ("1_0", "-9999,1_0", "1__0", "\u0663"):  # and an Arabic-Indic 3, float()'s 3.0 (GDAL's 0)
        code, out, err = run(capsys, "info", tmp_path / "dem.npy", "--json", "--nodata", given)
        assert code == 2 and out == "" and "argument --nodata:" in err and repr(given.split(",")[-1]) in err, err
        assert "ASCII digits, without underscores" in err, err
    for given, count in (("10", 1), ("1.0", 1), ("1,10", 2)):
        code, out, err = run(capsys, "info", tmp_path / "dem.npy", "--json", "--nodata", given)
        assert code == 0 and json.loads(out)["nodata_count"] == count, (given, err)


def test_non_finite_nodata_is_left_out_of_the_outputs_metadata(tmp_path, capsys):
    """``--nodata nan,-9999`` (and batch's ``nodata=(nan, -9999)``) recorded ``"nodata": [null, -9999.0]`` in the
    mesh's metadata (JSON has no NaN: written as null), and ``--nodata nan`` ``[null]``, which reads as "no nodata
    value". NaN and inf mark no cell (non-finite cells are nodata anyway), so only the finite values are recorded, and
    no ``nodata`` key when none is."""
    from stepterrain.batch import batch
    from stepterrain.export import read_mesh

    from .conftest import run_cli as run

    z = find_shared("big_tujunga_srtm_30m_utm11n.npz")
    heights = np.load(z)["elevation"][:40, :50].astype(np.float32)
    heights[3, 4] = -9999
    np.save(tmp_path / "dem.npy", heights)
    for given, recorded in (("nan,-9999", [-9999.0]), ("-inf,-9999,inf", [-9999.0]), ("nan", None)):
        out = tmp_path / "out.ply"
        code, _, err = run(capsys, "steps", tmp_path / "dem.npy", f"--nodata={given}", "--interval", "200", "-o", out)
        assert code == 0, err
        assert read_mesh(out).metadata.get("nodata") == recorded, given
    (tmp_path / "tiles").mkdir()
    np.save(tmp_path / "tiles" / "a.npy", heights)
    report = batch(str(tmp_path / "tiles"), str(tmp_path / "meshes"), format=".ply", scheduler="serial",
                   nodata=(np.nan, -9999.0))
    assert report.ok and [read_mesh(r.path).metadata.get("nodata") for r in report.done] == [[-9999.0]]


def test_cli_band_and_coarsen_refuse_underscores(tmp_path, capsys):
    """``--band 1_0`` read band 10 (int() takes digit-grouping underscores), refused for a 3-band file as "got --band
    10", a value not typed; ``--coarsen 1_0`` coarsened by 10. Both are refused by argparse now, quoting the text."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from .conftest import run_cli as run

    z = np.arange(3 * 20 * 30, dtype=np.float32).reshape(3, 20, 30)
    path = tmp_path / "bands.tif"
    with rasterio.open(path, "w", driver="GTiff", width=30, height=20, count=3, dtype="float32", crs="EPSG:32611",
                       transform=Affine(30, 0, 380000, 0, -30, 3800000)) as dataset:
        dataset.write(z)
    for command, option, rest in (("info", "--band", ["--json"]), ("steps", "--coarsen", ["-o", tmp_path / "out.ply"])):
        code, out, err = run(capsys, command, path, f"{option}=1_0", *rest)
        assert code == 2 and f"argument {option}: expected a " in err and "'1_0'" in err, err
    assert not (tmp_path / "out.ply").exists()
    code, out, err = run(capsys, "info", path, "--json", "--band=2")
    assert code == 0 and json.loads(out)["height_range"][0] == 600.0, err
