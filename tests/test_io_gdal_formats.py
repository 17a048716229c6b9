"""DEM formats GDAL reads besides GeoTIFF (ESRI ASCII grid, SRTM .hgt, ERDAS .img, VRT, ESRI .bil/.flt, USGS .dem):
read through the same rasterio path as a GeoTIFF, each checked against the GeoTIFF load of the same data."""

from __future__ import annotations

import builtins
import warnings
from pathlib import Path

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import InvalidInputError, MissingDependencyError

rasterio = pytest.importorskip("rasterio")
import rasterio.shutil  # noqa: E402, F811 - the AAIGrid and USGS DEM copies
from rasterio.io import MemoryFile  # noqa: E402
from rasterio.transform import Affine  # noqa: E402

_UTM = "EPSG:32611"


def _heights(shape=(7, 9), dtype=np.float32):
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    return (300.0 + 7.0 * rows + 3.0 * cols + 0.5 * rows * cols).astype(dtype)


def _write(path, z, driver, transform, crs=_UTM, nodata=None, units=None, **options):
    profile = dict(driver=driver, width=z.shape[1], height=z.shape[0], count=1, dtype=z.dtype.name,
                   transform=transform, **options)
    if crs is not None:
        profile["crs"] = crs
    if nodata is not None:
        profile["nodata"] = nodata
    if driver == "AAIGrid":  # CreateCopy only: written through a GeoTIFF in memory
        with MemoryFile() as memory:
            with memory.open(**{**profile, "driver": "GTiff"}) as dataset:
                dataset.write(z, 1)
            with memory.open() as dataset:
                rasterio.shutil.copy(dataset, str(path), driver="AAIGrid", **options)
        return path
    with rasterio.open(path, "w", **profile) as dataset:
        dataset.write(z, 1)
        if units:
            dataset.units = (units,)
    return path


def _same(terrain, reference):
    np.testing.assert_array_equal(terrain.heights, reference.heights)
    assert terrain.spacing == reference.spacing
    assert terrain.origin == reference.origin
    assert terrain.crs == reference.crs
    assert terrain.height_unit == reference.height_unit


_TRANSFORM = Affine(30.0, 0.0, 380000.0, 0.0, -30.0, 3800000.0)


@pytest.mark.parametrize(("driver", "ext", "dtype"), [
    ("AAIGrid", ".asc", np.float32), ("HFA", ".img", np.float32), ("EHdr", ".bil", np.int16),
    ("EHdr", ".flt", np.float32),
])
def test_gdal_formats_read_as_the_geotiff_of_the_same_data(tmp_path, driver, ext, dtype):
    z = _heights(dtype=dtype)
    nodata = -9999
    z[2, 3] = nodata
    reference = st.load_dem(_write(tmp_path / "ref.tif", z, "GTiff", _TRANSFORM, nodata=nodata))
    terrain = st.load_dem(_write(tmp_path / f"dem{ext}", z, driver, _TRANSFORM, nodata=nodata))
    _same(terrain, reference)
    assert np.isnan(terrain.heights[2, 3]) and np.isfinite(terrain.heights).sum() == z.size - 1
    assert terrain.source == f"dem{ext}"
    # crop= reads the window, as a GeoTIFF's
    box = (380060.0, 380150.0, 3799850.0, 3799930.0)
    _same(st.load_dem(tmp_path / f"dem{ext}", crop=box), st.load_dem(tmp_path / "ref.tif", crop=box))
    # the upper-case extension DOS-era data ships
    for side in tmp_path.glob("dem.*"):
        side.rename(tmp_path / f"DEM{side.suffix.upper()}")
    _same(st.load_dem(tmp_path / f"DEM{ext.upper()}"), reference)


def _write_asc(path, z, header, nodata=None):
    lines = [f"ncols {z.shape[1]}", f"nrows {z.shape[0]}", *header]
    if nodata is not None:
        lines.append(f"NODATA_value {nodata}")
    lines += [" ".join(f"{v:g}" for v in row) for row in z]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("corner", ["xllcorner", "xllcenter"])
def test_ascii_grid_corner_and_center_place_the_nodes(tmp_path, corner):
    """An .asc's xllcorner is the lower-left cell's corner, xllcenter its centre (ESRI): node (0, 0) is the centre of
    the top-left cell either way, as GDAL's pixel-is-area geotransform of a GeoTIFF places it."""
    z = _heights((4, 5))
    x, y = 500000.0, 4000000.0
    header = ([f"xllcorner {x}", f"yllcorner {y}"] if corner == "xllcorner" else
              [f"xllcenter {x + 5.0}", f"yllcenter {y + 5.0}"]) + ["cellsize 10"]
    terrain = st.load_dem(_write_asc(tmp_path / "dem.asc", z, header, nodata=-9999))
    assert terrain.crs is None  # no .prj: no CRS, as a GeoTIFF without one
    assert terrain.spacing == (10.0, -10.0)
    # the top-left cell's centre: half a cell in from the west edge, half a cell down from the north edge
    assert terrain.origin == (x + 5.0, y + 4 * 10.0 - 5.0)
    np.testing.assert_array_equal(terrain.heights, z)
    reference = st.load_dem(_write(tmp_path / "ref.tif", z, "GTiff", Affine(10.0, 0, x, 0, -10.0, y + 40.0),
                                   crs=None))
    _same(terrain, reference)
    # its .prj gives the CRS, as GDAL reads it
    (tmp_path / "dem.prj").write_text(rasterio.crs.CRS.from_string(_UTM).to_wkt())
    assert st.load_dem(tmp_path / "dem.asc").crs == _UTM


def test_ascii_grid_in_degrees_without_prj_warns_like_a_geotiff(tmp_path):
    z = _heights((6, 6)) * 10
    header = ["xllcorner -118.5", "yllcorner 34.0", "cellsize 0.000833333333"]
    _write_asc(tmp_path / "dem.asc", z, header)
    with pytest.warns(UserWarning, match="look like degrees"):
        st.load_dem(tmp_path / "dem.asc")


def _hgt(path, size):
    """An SRTM tile by hand: big-endian int16, its name the latitude and longitude of its lower-left corner."""
    rows, cols = np.mgrid[0:size, 0:size]
    z = (100 + rows + 2 * cols).astype(">i2")
    z[5, 7] = -32768  # a void
    z.tofile(path)
    return z.astype(np.int16)


def test_srtm_hgt_reads_as_the_geographic_geotiff_of_the_same_tile(tmp_path):
    z = _hgt(tmp_path / "N34W119.hgt", 1201)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the local-metres warnings of a 1-degree tile, if any, are the GeoTIFF's too
        terrain = st.load_dem(tmp_path / "N34W119.hgt")
        step = 1 / 1200
        reference = st.load_dem(_write(tmp_path / "ref.tif", z, "GTiff",
                                       Affine(step, 0, -119 - step / 2, 0, -step, 35 + step / 2), crs="EPSG:4326",
                                       nodata=-32768, units="m"))  # GDAL's SRTM driver names metres
    _same(terrain, reference)
    assert np.isnan(terrain.heights[5, 7])  # the void is nodata
    assert np.isfinite(terrain.heights).sum() == z.size - 1
    assert "N34W119.hgt" in terrain.source
    # a crop of the tile's local metres is that of the GeoTIFF
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        box = (1000.0, 3000.0, -5000.0, -2000.0)
        _same(st.load_dem(tmp_path / "N34W119.hgt", crop=box), st.load_dem(tmp_path / "ref.tif", crop=box))


def test_vrt_over_a_geotiff_reads_as_the_geotiff(tmp_path):
    z = _heights()
    z[0, 0] = -9999
    _write(tmp_path / "tile.tif", z, "GTiff", _TRANSFORM, nodata=-9999)
    (tmp_path / "dem.vrt").write_text(f"""<VRTDataset rasterXSize="{z.shape[1]}" rasterYSize="{z.shape[0]}">
  <SRS>{_UTM}</SRS>
  <GeoTransform>{", ".join(map(str, _TRANSFORM.to_gdal()))}</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <NoDataValue>-9999</NoDataValue>
    <SimpleSource>
      <SourceFilename relativeToVRT="1">tile.tif</SourceFilename>
      <SourceBand>1</SourceBand>
    </SimpleSource>
  </VRTRasterBand>
</VRTDataset>
""")
    _same(st.load_dem(tmp_path / "dem.vrt"), st.load_dem(tmp_path / "tile.tif"))
    # band= applies to any raster GDAL reads: a VRT has one band here
    with pytest.raises(InvalidInputError, match="band must be between 1 and 1"):
        st.load_dem(tmp_path / "dem.vrt", band=2)


def test_a_failed_read_names_gdals_reason_not_a_previous_exception(tmp_path):
    """A .vrt mosaic whose source tile is missing, or a GeoTIFF cut short, was refused as "unreadable content
    (Read failed. See previous exception for details.)": rasterio's words, pointing at an exception no message
    showed, so nothing said which tile was missing or that the file was short. GDAL's own error, rasterio's
    exception's cause, is named now."""
    from .conftest import SHARED_DATA

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as dataset:
        z = dataset.read(1)[:40, :60]
    _write(tmp_path / "west.tif", z[:, :30], "GTiff", _TRANSFORM)
    _write(tmp_path / "east.tif", z[:, 30:], "GTiff", Affine(30.0, 0.0, _TRANSFORM.c + 900.0, 0.0, -30.0, _TRANSFORM.f))
    sources = "".join(f"""
    <SimpleSource>
      <SourceFilename relativeToVRT="1">{name}.tif</SourceFilename>
      <SourceBand>1</SourceBand>
      <SrcRect xOff="0" yOff="0" xSize="30" ySize="40" />
      <DstRect xOff="{offset}" yOff="0" xSize="30" ySize="40" />
    </SimpleSource>""" for name, offset in (("west", 0), ("east", 30)))
    (tmp_path / "dem.vrt").write_text(f"""<VRTDataset rasterXSize="60" rasterYSize="40">
  <SRS>{_UTM}</SRS>
  <GeoTransform>{", ".join(map(str, _TRANSFORM.to_gdal()))}</GeoTransform>
  <VRTRasterBand dataType="Int16" band="1">{sources}
  </VRTRasterBand>
</VRTDataset>
""")
    np.testing.assert_array_equal(st.load_dem(tmp_path / "dem.vrt").heights, z.astype(np.float32))
    (tmp_path / "east.tif").unlink()
    with pytest.raises(st.errors.DataFileError) as refused:
        st.load_dem(tmp_path / "dem.vrt")
    assert "east.tif: No such file or directory" in str(refused.value)
    assert "previous exception" not in str(refused.value)
    data = (tmp_path / "west.tif").read_bytes()
    (tmp_path / "short.tif").write_bytes(data[: len(data) // 2])  # its header whole, its strips cut
    with pytest.raises(st.errors.DataFileError, match=r"short\.tif.*unreadable content \(short\.tif, band 1: ") as cut:
        st.load_dem(tmp_path / "short.tif")
    assert "previous exception" not in str(cut.value)


def test_usgs_dem_reads_through_rasterio(tmp_path):
    z = _heights((6, 5), np.int16)
    path = tmp_path / "dem.dem"
    with MemoryFile() as memory:
        with memory.open(driver="GTiff", width=5, height=6, count=1, dtype="int16", transform=_TRANSFORM,
                         crs=_UTM) as dataset:
            dataset.write(z, 1)
        with memory.open() as dataset:
            try:
                rasterio.shutil.copy(dataset, str(path), driver="USGSDEM", PRODUCT="DEFAULT")
            except Exception as exc:  # noqa: BLE001 - GDAL's USGS DEM writer is picky about the grid
                pytest.skip(f"GDAL cannot write this USGS DEM: {exc}")
    with rasterio.open(path) as dataset:
        expected = dataset.read(1, masked=True).astype(np.float32).filled(np.nan)
        transform, crs = dataset.transform, dataset.crs
    terrain = st.load_dem(path)
    np.testing.assert_array_equal(terrain.heights, expected)
    assert np.isfinite(terrain.heights).any()
    assert terrain.spacing == (transform.a, transform.e)
    assert terrain.origin == (transform.c + transform.a / 2, transform.f + transform.e / 2)
    assert terrain.crs == crs.to_string()


def test_unreadable_file_under_a_gdal_extension_names_its_format(tmp_path):
    (tmp_path / "dem.asc").write_text("not a grid\n")
    with pytest.raises(st.errors.DataFileError, match=r"dem\.asc.*ESRI ASCII grid"):
        st.load_dem(tmp_path / "dem.asc")


def test_unknown_extension_lists_the_gdal_formats(tmp_path):
    (tmp_path / "dem.xyz1").write_text("1 2 3\n")
    with pytest.raises(InvalidInputError, match=r"supported: .*\.asc.*\.hgt.*\.img.*\.vrt"):
        st.load_dem(tmp_path / "dem.xyz1")


@pytest.mark.parametrize(("name", "what"), [
    ("N34W119.hgt", r"an SRTM tile \(\.hgt\)"), ("dem.asc", r"an ESRI ASCII grid \(\.asc\)"),
])
def test_gdal_formats_without_rasterio_ask_for_the_geo_extra(tmp_path, monkeypatch, name, what):
    real_import = builtins.__import__

    def no_rasterio(name, *args, **kwargs):
        if name == "rasterio" or name.startswith("rasterio."):
            raise ImportError("No module named 'rasterio'")
        return real_import(name, *args, **kwargs)

    (tmp_path / name).write_bytes(b"\x00\x01" * 8)
    monkeypatch.setattr(builtins, "__import__", no_rasterio)
    with pytest.raises(MissingDependencyError, match=rf"reading {what} needs rasterio: pip install "
                                                     r"'stepterrain\[geo\]'"):
        st.load_dem(tmp_path / name)


def test_batch_picks_up_gdal_formats_from_a_folder_but_not_a_vrt_mosaic(tmp_path):
    from stepterrain.batch import plan_items
    z = _heights()
    _write(tmp_path / "a.tif", z, "GTiff", _TRANSFORM)
    _write(tmp_path / "b.bil", z, "EHdr", _TRANSFORM)
    _write_asc(tmp_path / "c.asc", z, ["xllcorner 0", "yllcorner 0", "cellsize 1"])
    _hgt(tmp_path / "N34W119.hgt", 1201)
    (tmp_path / "mosaic.vrt").write_text("<VRTDataset/>")  # gdalbuildvrt's mosaic of the tiles beside it
    items, _ = plan_items(tmp_path)
    names = sorted(Path(item.path).name for item in items)
    assert names == ["N34W119.hgt", "a.tif", "b.bil", "c.asc"]
    # a .vrt named on its own is read
    items, _ = plan_items([tmp_path / "mosaic.vrt"])
    assert len(items) == 1


def test_ascii_grid_in_degrees_reads_its_prj(tmp_path):
    """An .asc in degrees without a .prj warns, naming the .prj to put beside it; with one it is geographic, placed
    as the GeoTIFF of the same grid in EPSG:4326."""
    z = _heights((6, 6)) * 10
    step = 1 / 1200
    _write_asc(tmp_path / "dem.asc", z, ["xllcorner -118.5", "yllcorner 34.0", f"cellsize {step!r}"])
    with pytest.warns(UserWarning, match=r"put a \.prj with it beside the file \(dem\.prj\)"):
        st.load_dem(tmp_path / "dem.asc")
    (tmp_path / "dem.prj").write_text(rasterio.crs.CRS.from_epsg(4326).to_wkt())
    reference = st.load_dem(_write(tmp_path / "ref.tif", z, "GTiff", Affine(step, 0, -118.5, 0, -step, 34 + 6 * step),
                                   crs="EPSG:4326"))
    _same(st.load_dem(tmp_path / "dem.asc"), reference)
    # node (0, 0) at the top-left cell's centre: half a cell in from xllcorner
    assert "node (0, 0) at lon -118.499583333, lat 34.004583333" in st.load_dem(tmp_path / "dem.asc").source


def test_cli_steps_texture_and_batch_read_gdal_formats(tmp_path, capsys):
    from stepterrain import cli
    z = _heights((12, 14))
    _write_asc(tmp_path / "dem.asc", z, ["xllcorner 500000", "yllcorner 4000000", "cellsize 10"])
    assert cli.main(["-q", "steps", str(tmp_path / "dem.asc"), "--interval", "10", "-o", str(tmp_path / "a.ply"),
                     "--device", "cpu"]) == 0
    assert (tmp_path / "a.ply").stat().st_size > 0
    assert cli.main(["-q", "texture", str(tmp_path / "dem.asc"), "-o", str(tmp_path / "t.png"),
                     "--device", "cpu"]) == 0
    assert (tmp_path / "t.png").stat().st_size > 0
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    _write(tiles / "a.bil", z, "EHdr", _TRANSFORM)
    _write(tiles / "b.img", z, "HFA", _TRANSFORM)
    assert cli.main(["-q", "batch", str(tiles), "--interval", "10", "--format", ".ply", "-o", str(tmp_path / "out"),
                     "--scheduler", "serial", "--device", "cpu"]) == 0
    assert sorted(p.name for p in (tmp_path / "out").glob("*.ply")) == ["a.ply", "b.ply"]


def test_a_bil_header_corrected_in_place_redoes_its_batch_item(tmp_path):
    """A .bil's georeferencing lies in the .hdr beside it: the batch fingerprint holds it, as a GeoTIFF's world file,
    so a rerun after the header was corrected (same size) does not skip the item with its mesh at the old origin."""
    import trimesh

    from stepterrain.batch import batch
    folder = tmp_path / "dems"
    folder.mkdir()
    _write(folder / "dem.bil", _heights((5, 6)), "EHdr", Affine(10.0, 0, 1000.0, 0, -10.0, 2000.0))
    out = tmp_path / "out"

    def lowest_y():
        report = batch(folder, out, interval=5.0, format=".ply", scheduler="serial")
        assert report.ok
        return len(report.done), float(np.asarray(trimesh.load(out / "dem.ply", process=False).vertices)[:, 1].min())

    assert lowest_y() == (1, 2000.0 - 5.0 - 40.0)
    header = (folder / "dem.hdr").read_text()
    assert "ULYMAP" in header and "1995" in header
    (folder / "dem.hdr").write_text(header.replace("1995", "2995"))  # corrected in place: same size
    assert lowest_y() == (1, 2995.0 - 40.0)
    assert lowest_y() == (0, 2995.0 - 40.0)  # unchanged: skipped


@pytest.mark.parametrize("ext, dtype", [(".flt", np.float32), (".bil", np.int16)])
def test_a_truncated_raw_grid_is_refused_not_filled_with_zeros(tmp_path, ext, dtype):
    """An ESRI .flt or .bil cut short (an interrupted download or copy) holds fewer rows than its .hdr declares. GDAL
    reads such a raw raster whole in one read that fills the missing bytes with zeros without an error (only its
    block-by-block read fails), so the rows past the cut were read as heights of 0 m: a cliff down to sea level in
    the mesh, without a word. It is refused as unreadable content, the whole file and a crop reaching past the cut;
    a crop of the rows it holds reads them, as the intact file's."""
    z = st.sample_dem().heights[:30, :40].astype(dtype)  # real heights, 315-2295 m
    path = _write(tmp_path / f"dem{ext}", z, "EHdr", _TRANSFORM)
    whole = st.load_dem(path)
    intact = whole.crop((380000.0, 380500.0, 3799700.0, 3800000.0))  # rows 0-9
    with open(path, "r+b") as raw:
        raw.truncate(path.stat().st_size // 2)  # rows 15 on are gone
    with pytest.raises(st.errors.DataFileError, match=r"got unreadable content"):
        st.load_dem(path)
    with pytest.raises(st.errors.DataFileError, match=r"got unreadable content"):
        st.load_dem(path, crop=whole.extent)
    _same(st.load_dem(path, crop=(380000.0, 380500.0, 3799700.0, 3800000.0)), intact)
