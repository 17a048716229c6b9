"""load_dem / save_mesh / save_image bugs found by an adversarial pass over the shared input and output rooms (each
test failed before its fix)."""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest
import trimesh
from PIL import Image

from stepterrain.batch import batch
from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh, save_image, save_mesh
from stepterrain.io import load_dem

from .conftest import SHARED_DATA


def test_a_png_beyond_pillows_pixel_limit_is_a_data_file_error(tmp_path, monkeypatch):
    # a 20000 x 10000 heightmap (200 M pixels, over Pillow's 179 M) raised PIL.Image.DecompressionBombError, which
    # is no OSError and went past load_dem as a raw Pillow exception; the limit is lowered here to keep the file small
    path = tmp_path / "large.png"
    Image.fromarray(np.zeros((40, 30), np.uint16)).save(path)
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)
    with pytest.raises(DataFileError, match=r"large\.png.*decompression-bomb limit.*1200 pixels"):
        load_dem(path)


def test_a_geotiff_too_large_for_memory_is_a_data_file_error(tmp_path):
    # a sparse GeoTIFF of a few kB whose header declares 1,000,000 x 1,000,000 cells raised numpy's raw MemoryError
    # ("Unable to allocate 3.64 TiB") from rasterio's read; the memory budget refuses it before reading now (see
    # test_a_raster_over_the_memory_budget_is_refused_before_it_is_read), and with the budget raised the failed
    # allocation is still a DataFileError
    import stepterrain as st
    from stepterrain.errors import OutputTooLargeError

    rasterio = pytest.importorskip("rasterio")
    path = tmp_path / "huge.tif"
    profile = {"driver": "GTiff", "width": 1_000_000, "height": 1_000_000, "count": 1, "dtype": "float32",
               "tiled": True, "blockxsize": 4096, "blockysize": 4096, "sparse_ok": True, "BIGTIFF": "YES",
               "transform": rasterio.Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0), "crs": "EPSG:32611"}
    with rasterio.open(path, "w", **profile):
        pass
    assert path.stat().st_size < 10_000_000
    with pytest.raises(OutputTooLargeError, match=r"^reading '.*huge\.tif' \(the raster: 1000000 x 1000000 cells of "
                                                  r"float32\) would need 3,814,697\.3 MiB, over the memory budget"):
        load_dem(path)
    previous = st.set_memory_budget(1 << 50)
    try:
        with pytest.raises(DataFileError, match=r"huge\.tif.*fits in memory.*allocate"):
            load_dem(path)
    finally:
        st.set_memory_budget(previous)


@pytest.mark.parametrize("length", [241, 242, 250, 255])
def test_a_file_name_near_the_file_system_limit_is_written(tmp_path, length):
    # atomic_path's temporary file is named ".<name>.XXXXXXXX.tmp", 14 bytes longer than its target: a valid name of
    # 242-255 bytes made it too long (ENAMETOOLONG), refused as "cannot write in the output folder"
    mesh = trimesh.creation.box()
    for ext, write in ((".ply", lambda p: save_mesh(mesh, p)),
                       (".png", lambda p: save_image(np.zeros((2, 3, 3), np.uint8), p))):
        path = tmp_path / ("é" * ((length - len(ext)) // 2) + "a" * ((length - len(ext)) % 2) + ext)
        assert len(os.fsencode(path.name)) == length
        assert write(path) == path
        assert os.listdir(tmp_path).count(path.name) == 1
    assert len(trimesh.load(tmp_path / path.name.replace(".png", ".ply")).faces) == 12
    assert not [name for name in os.listdir(tmp_path) if name.endswith(".tmp")]


def test_an_npz_nodata_in_a_one_element_array_marks_missing_cells_and_an_unusable_one_is_refused(tmp_path):
    # np.savez(..., nodata=dataset.nodatavals) stores rasterio's per-band tuple, shape (1,): npz_nodata took only a
    # 0-d value and ignored it silently, so the -32768 cells became heights (pits in the mesh); text or a mask under
    # 'nodata' was ignored the same way. load_series (batch) reads 'nodata' through the same function.
    from stepterrain.batch import load_series

    z = np.array([[100, -32768, 102], [103, 104, 105]], np.int16)
    transform = np.array([500000.0, 30.0, 0.0, 4000000.0, 0.0, -30.0])
    np.savez(tmp_path / "tuple.npz", elevation=z, transform=transform, crs="EPSG:32611", nodata=(-32768.0,))
    h = load_dem(tmp_path / "tuple.npz").heights
    assert np.isnan(h[0, 1]) and np.isfinite(h).sum() == 5
    np.savez(tmp_path / "series.npz", heights=np.stack([z, z]), nodata=np.array([-32768]))
    assert np.isnan(load_series(tmp_path / "series.npz")[:, 0, 1]).all()
    for name, nodata, got in (("text.npz", "-32768", "'-32768'"), ("mask.npz", z == -32768, "bool"),
                              ("two.npz", (-32768.0, -9999.0), r"\[-32768.0, -9999.0\]")):
        np.savez(tmp_path / name, heights=z, nodata=nodata)
        with pytest.raises(DataFileError, match=rf"{name}.*'nodata' must be one real number.*got .*{got}"):
            load_dem(tmp_path / name)
    np.savez(tmp_path / "series_text.npz", heights=np.stack([z, z]), nodata="-32768")
    with pytest.raises(DataFileError, match="'nodata' must be one real number"):
        load_series(tmp_path / "series_text.npz")


@pytest.mark.parametrize("fmt", ["JPEG", "TIFF", "BMP"])
def test_an_image_that_is_not_a_png_under_a_png_name_is_refused(tmp_path, fmt):
    # Pillow opens any format it knows whatever the name, so a lossy JPEG (its block artefacts as heights) or a TIFF
    # (a GeoTIFF's pixels without its georeferencing: spacing 1 instead of 30 m) named .png was read silently, where
    # load_dem checks an .npy's or .npz's content against its extension
    path = tmp_path / "dem.png"
    Image.fromarray(np.arange(64, dtype=np.uint8).reshape(8, 8)).save(path, format=fmt)
    with pytest.raises(DataFileError, match=rf"dem\.png.*expected a PNG heightmap; got a {fmt} image"):
        load_dem(path)
    Image.fromarray(np.arange(64, dtype=np.uint8).reshape(8, 8)).save(path, format="PNG")
    assert load_dem(path).heights[7, 7] == 63.0


def test_an_npz_crs_in_a_one_element_array_is_read_and_an_unusable_one_is_refused(tmp_path):
    """np.savez(crs=[...]) stores the CRS in a one-element array, which load_dem ignored: with a geographic CRS the
    degree spacing was then taken as metres (a 0.01° grid 0.01 m apart). Text in a one-element array is read; a
    number or several values under 'crs' or 'units' are refused by name."""
    heights = np.arange(20.0, dtype=np.float32).reshape(4, 5)
    transform = np.array([10.0, 0.01, 0.0, 45.0, 0.0, -0.01])
    plain, listed = tmp_path / "plain.npz", tmp_path / "listed.npz"
    np.savez(plain, elevation=heights, transform=transform, crs="EPSG:4326")
    np.savez(listed, elevation=heights, transform=transform, crs=np.array(["EPSG:4326"]))
    a, b = load_dem(plain), load_dem(listed)
    assert abs(a.spacing[0]) > 500.0  # 0.01° of longitude at 45° N: about 790 m
    assert a.spacing == b.spacing and a.origin == b.origin and a.crs == b.crs
    for key, value in (("crs", np.array([4326])), ("crs", np.array(["EPSG:4326", "EPSG:32611"])),
                       ("units", np.array([1.0]))):
        bad = tmp_path / f"bad_{key}.npz"
        np.savez(bad, elevation=heights, transform=transform, **{key: value})
        with pytest.raises(DataFileError, match=rf"bad_{key}\.npz.*'{key}' must be one text value"):
            load_dem(bad)


@pytest.mark.parametrize("reference", ["gcps", "rpcs"])
def test_a_geotiff_referenced_only_by_gcps_or_rpcs_is_refused_not_read_as_1_m_cells(tmp_path, reference):
    # without a geotransform rasterio reports the identity: a scanned map or satellite scene georeferenced by
    # ground control points (or RPCs) was read as an unreferenced grid of 1 m cells at (0, 0), without a word
    rasterio = pytest.importorskip("rasterio")
    from rasterio.control import GroundControlPoint
    from rasterio.crs import CRS
    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.rpc import RPC

    path = tmp_path / f"{reference}.tif"
    with pytest.warns(NotGeoreferencedWarning):
        with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=1, dtype="float32") as ds:
            ds.write(np.arange(12, dtype=np.float32).reshape(1, 3, 4) + 100.0)
            if reference == "gcps":
                points = [GroundControlPoint(0, 0, -118.0, 34.0), GroundControlPoint(0, 4, -117.9, 34.0),
                          GroundControlPoint(3, 0, -118.0, 33.9)]  # fmt: skip
                ds.gcps = (points, CRS.from_epsg(4326))
            else:
                unit, zero = [1.0] + [0.0] * 19, [0.0] * 20  # line = -latitude, sample = longitude (normalised)
                ds.rpcs = RPC(height_off=100.0, height_scale=500.0, lat_off=34.0, lat_scale=0.1, long_off=-118.0,
                              long_scale=0.1, line_off=1.5, line_scale=1.5, samp_off=2.0, samp_scale=2.0,
                              line_num_coeff=zero[:2] + [-1.0] + zero[3:], line_den_coeff=unit,
                              samp_num_coeff=zero[:1] + [1.0] + zero[2:], samp_den_coeff=unit)  # fmt: skip
    what = r"3 ground control points \(GCPs\) in EPSG:4326" if reference == "gcps" else r"rational polynomial"
    with pytest.raises(DataFileError, match=rf"{reference}\.tif.*regular grid.*referenced only by {what}.*gdalwarp"):
        load_dem(path)


Z_UNITS = np.array([[100.0, 110.0, 120.0], [130.0, 140.0, 150.0]], np.float32)


def write_unit_tif(path, unit):
    rasterio = pytest.importorskip("rasterio")
    with rasterio.open(path, "w", driver="GTiff", width=3, height=2, count=1, dtype="float32", crs="EPSG:32611",
                       transform=rasterio.Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)) as ds:  # fmt: skip
        ds.write(Z_UNITS, 1)
        ds.units = (unit,)
    return path


@pytest.mark.parametrize(
    ("unit", "metres"),
    [("km", 1000.0), ("kilometres", 1000.0), ("dm", 0.1), ("cm", 0.01), ("Centimeters", 0.01), ("mm", 0.001),
     ("feet", 0.3048), ("ft.", 0.3048), ("ftUS", 1200 / 3937), ("foot (US survey)", 1200 / 3937)],
)  # fmt: skip
def test_heights_in_other_length_units_become_metres(tmp_path, unit, metres):
    # a band or an .npz naming its heights in km, dm, cm or mm (or spelling feet another way) was used as metres:
    # a DEM in centimetres came out 100 times too high, one in kilometres 1000 times too flat
    t = load_dem(write_unit_tif(tmp_path / "u.tif", unit))
    np.testing.assert_allclose(t.heights, Z_UNITS.astype(np.float64) * metres, rtol=1e-6)
    np.savez(tmp_path / "u.npz", elevation=Z_UNITS, transform=np.array([0.0, 30.0, 0, 60.0, 0, -30.0]),
             crs="EPSG:32611", units=unit)  # fmt: skip
    np.testing.assert_allclose(load_dem(tmp_path / "u.npz").heights, Z_UNITS.astype(np.float64) * metres, rtol=1e-6)
    np.savez(tmp_path / "plain.npz", heights=Z_UNITS, units=unit)  # no transform: the unit was ignored here
    np.testing.assert_allclose(load_dem(tmp_path / "plain.npz").heights, Z_UNITS * metres, rtol=1e-6)


@pytest.mark.parametrize("unit", ["degC", "furlong", "meters above sea level"])
def test_heights_in_an_unknown_unit_are_refused_unless_height_unit_names_it(tmp_path, unit):
    # any unit off the list was used as stored without a word (a temperature grid meshed as terrain)
    from stepterrain.errors import InvalidInputError

    path = write_unit_tif(tmp_path / "odd.tif", unit)
    refused = rf"odd\.tif.*known length unit.*got '{unit}' \(band 1's unit\).*height_unit='m'"
    with pytest.raises(DataFileError, match=refused):
        load_dem(path)
    np.savez(tmp_path / "odd.npz", heights=Z_UNITS, units=unit)
    with pytest.raises(DataFileError, match=rf"odd\.npz.*got '{unit}' \(its 'units'\)"):
        load_dem(tmp_path / "odd.npz")
    np.testing.assert_array_equal(load_dem(path, height_unit="m").heights, Z_UNITS)  # the caller names the unit
    np.testing.assert_allclose(load_dem(path, height_unit="US survey foot").heights, Z_UNITS * (1200 / 3937), rtol=1e-6)
    np.save(tmp_path / "plain.npy", Z_UNITS)  # a file that names no unit: height_unit converts it
    np.testing.assert_allclose(load_dem(tmp_path / "plain.npy", height_unit="ft").heights, Z_UNITS * 0.3048, rtol=1e-6)
    for bad in ("furlong", 0.3048):
        with pytest.raises(InvalidInputError, match=rf"height_unit must be a length unit \(m, km.*got {bad!r}"):
            load_dem(path, height_unit=bad)


def test_an_alpha_or_imagery_band_is_refused_as_elevation_while_alpha_masks_the_grey_band(tmp_path):
    # load_dem(band=2) on a grey + alpha GeoTIFF read the alpha band's 0/255 as heights (only palette and RGB bands
    # were refused); the grey band itself reads with the alpha band as its mask
    rasterio = pytest.importorskip("rasterio")
    from rasterio.enums import ColorInterp

    z = np.arange(12, dtype=np.uint8).reshape(3, 4) + 100
    alpha = np.full((3, 4), 255, np.uint8)
    alpha[0, 0] = 0
    path = tmp_path / "grey_alpha.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=2, dtype="uint8", crs="EPSG:32611",
                       transform=rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 90.0), photometric="MINISBLACK",
                       alpha="YES") as ds:  # fmt: skip
        ds.write(np.stack([z, alpha]))
        ds.colorinterp = [ColorInterp.gray, ColorInterp.alpha]
    h = load_dem(path).heights
    assert np.isnan(h[0, 0]) and np.array_equal(h.ravel()[1:], z.ravel()[1:])
    with pytest.raises(DataFileError, match=r"grey_alpha\.tif.*band 2 is an alpha \(transparency\) band.*not elevat"):
        load_dem(path, band=2)
    with rasterio.open(path, "r+") as ds:
        ds.colorinterp = [ColorInterp.gray, ColorInterp.nir]
    with pytest.raises(DataFileError, match=r"band 2 is an image band \(nir\), not elevation data"):
        load_dem(path, band=2)


def write_raw_png(path, pixels, color_type):
    """(H, W, C) uint16 ``pixels`` as a 16-bit PNG of ``color_type`` (4: grey + alpha), which Pillow cannot write."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\x00" + row.astype(">u2").tobytes() for row in pixels)
    header = struct.pack(">IIBBBBB", pixels.shape[1], pixels.shape[0], 16, color_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows))
                     + chunk(b"IEND", b""))  # fmt: skip
    return path


def test_png_transparency_marks_missing_cells_and_16_bit_grey_alpha_is_refused(tmp_path):
    # a grey PNG's transparent value (tRNS, GDAL's nodata for PNG) and an 8-bit grey + alpha PNG's alpha were
    # ignored or refused as "colour": the transparent cells became heights; a 16-bit grey + alpha PNG, which
    # Pillow opens as 8-bit RGBA, was refused as a colour image
    z = np.arange(12).reshape(3, 4)
    Image.fromarray(z.astype(np.uint8)).save(tmp_path / "trns8.png", transparency=5)
    Image.fromarray(z.astype(np.uint16) * 1000).save(tmp_path / "trns16.png", transparency=5000)
    for name, scale in (("trns8.png", 1), ("trns16.png", 1000)):
        h = load_dem(tmp_path / name).heights
        assert np.isnan(h[1, 1]) and np.isfinite(h).sum() == 11
        np.testing.assert_array_equal(h[np.isfinite(h)], (z * scale)[z != 5])
    grey_alpha = np.stack([z.astype(np.uint8) + 50, np.full((3, 4), 255, np.uint8)], axis=-1)
    grey_alpha[2, 3, 1] = 0
    Image.fromarray(grey_alpha, "LA").save(tmp_path / "la8.png")
    h = load_dem(tmp_path / "la8.png").heights
    assert np.isnan(h[2, 3]) and np.array_equal(h.ravel()[:-1], z.ravel()[:-1] + 50)
    write_raw_png(tmp_path / "la16.png", np.stack([z * 1000 + 7, np.full((3, 4), 65535)], axis=-1), 4)
    with pytest.raises(DataFileError, match=r"la16\.png.*16-bit greyscale PNG with an alpha channel.*8-bit"):
        load_dem(tmp_path / "la16.png")


def test_a_geographic_grid_whose_longitudes_go_round_the_globe_more_than_once_is_refused(tmp_path):
    # latitudes beyond ±90 were refused, but 4 columns 150 degrees apart (450 degrees of longitude, a wrong step or
    # a projected grid labelled EPSG:4326) read as a strip 50,000 km wide; a whole globe (361 nodes) still reads
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.savez(tmp_path / "wide.npz", elevation=z, lat=np.array([10.0, 0.0, -10.0]), lon=np.arange(4) * 150.0)
    with pytest.raises(DataFileError, match=r"wide\.npz.*longitudes span 450 degrees \(4 columns of 150\).*most 360"):
        load_dem(tmp_path / "wide.npz")
    globe = np.zeros((3, 361), np.float32)
    np.savez(tmp_path / "globe.npz", elevation=globe, lat=np.array([1.0, 0.0, -1.0]), lon=np.arange(361) - 180.0)
    assert load_dem(tmp_path / "globe.npz").extent[1] == pytest.approx(2 * np.pi * 6371008.8)  # dx at the equator


#: NAD83 / UTM 11N + a height in a foot _HEIGHT_UNITS does not list: its metres per unit stated in the WKT.
_COMPOUND_WKT = (
    'COMPD_CS["NAD83 / UTM zone 11N + height ({name})",PROJCS["NAD83 / UTM zone 11N",GEOGCS["NAD83",DATUM['
    '"North_American_Datum_1983",SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",'
    '0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER['
    '"central_meridian",-117],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER['
    '"false_northing",0],UNIT["metre",1],AUTHORITY["EPSG","26911"]],VERT_CS["height ({name})",VERT_DATUM['
    '"local",2005],UNIT["{name}",{factor}{authority}],AXIS["Up",UP]]]'
)


@pytest.mark.parametrize(
    "name, factor, authority",
    [  # a GeoTIFF keeps a vertical unit by its EPSG code only
        ("British foot (Sears 1922)", 0.3047994715386762, ',AUTHORITY["EPSG","9051"]'),
        ("Clarke's foot", 0.3047972654, ',AUTHORITY["EPSG","9005"]'),
    ],
)
def test_a_compound_crs_vertical_unit_outside_the_known_list_converts_by_its_stated_factor(
    tmp_path, name, factor, authority
):
    """A compound CRS whose vertical unit is not in the known list (British foot, Clarke's foot) kept the heights
    as stored, in feet, without a word (an .npz), or was refused as an unknown band unit (a GeoTIFF: GDAL names the
    band's unit after the vertical CRS). The WKT states the metres per unit: the heights become metres by it, and
    ``crs`` keeps the horizontal part, as for a vertical unit in the list."""
    rasterio = pytest.importorskip("rasterio")
    wkt = _COMPOUND_WKT.format(name=name, factor=factor, authority=authority)
    z = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 1000.0]], np.float32)
    np.savez(tmp_path / "feet.npz", elevation=z, transform=np.array([380000.0, 30.0, 0, 3800000.0, 0, -30.0]), crs=wkt)
    t = load_dem(tmp_path / "feet.npz")
    np.testing.assert_allclose(t.heights, z * factor, rtol=1e-6)
    assert t.crs == "EPSG:26911"
    path = tmp_path / "feet.tif"
    with rasterio.open(path, "w", driver="GTiff", width=3, height=2, count=1, dtype="float32",
                       crs=rasterio.crs.CRS.from_wkt(wkt), transform=rasterio.Affine(30, 0, 380000, 0, -30, 3800000)
                       ) as ds:  # fmt: skip
        ds.write(z, 1)
    with rasterio.open(path) as ds:  # GDAL's own reading of the vertical unit (it may rename an EPSG unit)
        stated = float(ds.crs.to_wkt().rsplit("UNIT[", 1)[1].split(",")[1].rstrip("]"))
    t = load_dem(path)
    np.testing.assert_allclose(t.heights, z * stated, rtol=1e-6)
    assert abs(stated - 0.3048) < 1e-5 and t.crs == "EPSG:26911"


def test_a_1_bit_png_is_refused_as_1_bit_not_as_colour(tmp_path):
    """A 1-bit black-and-white PNG (Pillow's mode '1') was refused as 'a 1 image (colour or palette images are
    not elevation data)': it is neither. The message now says what it is; an RGB PNG keeps the colour wording."""
    path = tmp_path / "mask.png"
    Image.fromarray(np.eye(4, dtype=bool)).save(path)
    with Image.open(path) as image:
        assert image.mode == "1"
    with pytest.raises(DataFileError, match=r"mask\.png'?: expected a single-channel 8- or 16-bit greyscale "
                                            r"heightmap; got a 1-bit black-and-white image \(mode '1': two levels "
                                            r"are no elevation data; save the heights as 8- or 16-bit greyscale\)$"):
        load_dem(path)
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(DataFileError, match=r"got a RGB image \(colour or palette images are not elevation data; "
                                            r"an RGB terrain tile reads with its encoding named, "
                                            r"height_encoding='terrain-rgb' or 'terrarium'\)$"):
        load_dem(tmp_path / "rgb.png")


@pytest.mark.parametrize("ext", [".tif", ".npy", ".npz", ".png"])
def test_a_raster_over_the_memory_budget_is_refused_before_it_is_read(tmp_path, ext):
    """load_dem read a raster whatever st.set_memory_budget said: only a raw MemoryError from the allocation was
    caught, so a file whose header declared more cells than the budget (and than the machine) allocated until the
    machine swapped. Its declared size is now checked before reading: an OutputTooLargeError names the file, its
    shape and the bytes; within the budget the same file reads."""
    import stepterrain as st
    from stepterrain.errors import OutputTooLargeError

    z = np.arange(40 * 30, dtype=np.uint16).reshape(40, 30)  # 1,200 cells: 4,800 bytes as float32 heights
    path = tmp_path / f"dem{ext}"
    if ext == ".tif":
        rasterio = pytest.importorskip("rasterio")
        with rasterio.open(path, "w", driver="GTiff", width=30, height=40, count=1, dtype="uint16",
                           transform=rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0)) as ds:  # fmt: skip
            ds.write(z, 1)
    elif ext == ".npy":
        np.save(path, z)
    elif ext == ".npz":
        np.savez(path, elevation=z)
    else:
        Image.fromarray(z).save(path)
    previous = st.set_memory_budget(4_000)
    try:
        with pytest.raises(OutputTooLargeError, match=rf"^reading '.*dem\{ext}' \(.*: 40 x 30 cells of uint16\) would "
                                                      r"need 4,800 bytes, over the memory budget of 4,000 bytes; crop "
                                                      r"or coarsen it first"):
            load_dem(path)
        st.set_memory_budget(4_800)
        np.testing.assert_array_equal(load_dem(path).heights, z)
    finally:
        st.set_memory_budget(previous)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda p: load_dem(p / ("x" * 300 + ".npy")), r"^cannot read '.*xxxx\.npy': File name too long$"),
        (lambda p: read_mesh(p / ("x" * 300 + ".glb")), r"^cannot read '.*xxxx\.glb': File name too long$"),
        (
            lambda p: batch(np.zeros((5, 5)), p / ("x" * 300), tile_size=2, interval=1.0, scheduler="serial"),
            r"^cannot create the output folder '.*xxxx': File name too long$",
        ),
    ],
    ids=["load_dem", "read_mesh", "batch_output_dir"],
)
def test_a_name_too_long_for_the_file_system_is_a_data_file_error(tmp_path, call, message):
    # Path.exists() / is_file() raise os.stat's OSError for ENAMETOOLONG (they hide only "no such file"): a bare
    # OSError came out of load_dem, read_mesh and batch before any check of theirs
    with pytest.raises(DataFileError, match=message):
        call(tmp_path)


@pytest.mark.parametrize(
    "call, missing, irregular",
    [
        (load_dem, r"^DEM file '.*nope\.npy' does not exist$", r"^DEM path '.*folder\.npy' is not a regular file$"),
        (read_mesh, r"^mesh file '.*nope\.npy' does not exist$", r"^mesh file '.*folder\.npy' is not a regular file$"),
    ],
    ids=["load_dem", "read_mesh"],
)
def test_load_dem_and_read_mesh_check_their_path_through_one_helper(tmp_path, call, missing, irregular):
    # load_dem and read_mesh each carried the same six lines (exists / is_file in a try turning ENAMETOOLONG's
    # OSError into a DataFileError, then "does not exist" / "not a regular file"); both go through one helper now,
    # with the messages they had
    from stepterrain import _files

    (tmp_path / "folder.npy").mkdir()
    with pytest.raises(DataFileError, match=missing):
        call(tmp_path / "nope.npy")
    with pytest.raises(DataFileError, match=irregular):
        call(tmp_path / "folder.npy")
    with pytest.raises(DataFileError, match=r"^cannot read '.*xxxx': File name too long$"):
        _files.require_regular_file(tmp_path / ("x" * 300), "file", "path")


def test_an_unknown_epsg_code_loads_without_gdal_printing_to_stderr(tmp_path, capfd):
    # the CRS lookup ran outside a rasterio Env, so GDAL's own error handler printed "ERROR 1: PROJ:
    # internal_proj_create_from_database: crs not found: EPSG:999999" to stderr (three times) while load_dem went
    # on and succeeded, the grid keeping its own units as documented
    pytest.importorskip("rasterio")
    path = tmp_path / "unknown.npz"
    np.savez(path, elevation=np.arange(12, dtype=np.float32).reshape(3, 4), crs="EPSG:999999",
             transform=np.array([500.0, 2.0, 0.0, 100.0, 0.0, -2.0]))  # fmt: skip
    capfd.readouterr()
    terrain = load_dem(path)
    out, err = capfd.readouterr()
    assert (out, err) == ("", "")
    assert terrain.crs == "EPSG:999999" and terrain.spacing == (2.0, -2.0) and terrain.heights.shape == (3, 4)


@pytest.mark.parametrize("reader", ["load_series", "from_heights", "stepped", "batch"])
def test_a_memory_map_over_the_memory_budget_is_refused_before_it_is_copied(tmp_path, reader):
    """A memory-mapped .npy (load_series maps its file; np.load(mmap_mode="r") given to Terrain.from_heights,
    stepped or batch) was read into memory as float32 whatever st.set_memory_budget said: the map's data is on disk
    and only its copy needs memory. Its size is now checked before the copy; a slice of the map within the budget
    reads."""
    import stepterrain as st
    from stepterrain.batch import load_series
    from stepterrain.errors import OutputTooLargeError

    path = tmp_path / "series.npy"
    np.save(path, np.arange(3 * 40 * 30, dtype=np.float64).reshape(3, 40, 30))  # 3,600 cells: 14,400 bytes float32
    mapped = np.load(path, mmap_mode="r")
    call = {
        "load_series": lambda: load_series(path),
        "from_heights": lambda: st.Terrain.from_heights(mapped[0]),
        "stepped": lambda: st.stepped(mapped[0], interval=100.0),
        "batch": lambda: batch(mapped, tmp_path / "out", interval=100.0, scheduler="serial"),
    }[reader]
    previous = st.set_memory_budget(4_000)  # under one frame's 4,800 bytes
    try:
        message = r"(40 x 30|40, 30\)).*float64.* would need [\d,]+ bytes, over the memory budget of 4,000 bytes"
        with pytest.raises(OutputTooLargeError, match=message):
            call()
        assert st.Terrain.from_heights(mapped[0, :20, :20]).shape == (20, 20)  # 1,600 bytes: within the budget
    finally:
        st.set_memory_budget(previous)


@pytest.mark.parametrize(
    "dtype, options, most",
    [
        ("uint8", {}, 9.5),
        ("uint16", {"nodata": 0}, 9.5),
        ("float32", {}, 9.5),
        ("float32", {"nodata": -9999.0}, 9.5),
        ("float64", {"nodata": -9999.0}, 16.5),
        ("int16", {"scale": 0.1, "offset": 5.0, "nodata": -1}, 16.5),
        ("float64", {"scale": 2.0, "unit": "ft"}, 16.5),
    ],
)
def test_the_documented_peak_of_a_geotiff_read_holds(tmp_path, dtype, options, most):
    """load_dem's budget check counts the heights it keeps (cells x max(stored bytes, 4)); its docstring and the
    README state what the read allocates at its peak beyond that (8-9 bytes a cell for 8- to 32-bit rasters, up
    to 16 for float64 or scaled bands; 12-14 and 27-32 before the masked array's copies were replaced by one working
    copy filled in place). Measured here with tracemalloc (numpy's allocations), so the numbers stay true: the check
    is a lower bound of the peak and the peak within the stated bytes per cell."""
    import tracemalloc

    rasterio = pytest.importorskip("rasterio")
    from stepterrain.io import _check_read_budget

    rows, cols = 300, 200
    path = tmp_path / "dem.tif"
    transform = rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0)
    profile = {"driver": "GTiff", "width": cols, "height": rows, "count": 1, "dtype": dtype}
    profile.update(crs="EPSG:32611", nodata=options.get("nodata"), transform=transform)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write((np.arange(rows * cols) % 1000 + 1).reshape(rows, cols).astype(dtype), 1)
        if "scale" in options:
            ds.scales, ds.offsets = (options["scale"],), (options.get("offset", 0.0),)
        if "unit" in options:
            ds.units = (options["unit"],)
    load_dem(path)  # imports and caches outside the measurement
    tracemalloc.start()
    try:
        load_dem(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    checked = rows * cols * max(np.dtype(dtype).itemsize, 4)
    import stepterrain as st

    previous = st.set_memory_budget(checked)
    try:
        _check_read_budget(path, (rows, cols), np.dtype(dtype))  # exactly what is checked: passes at the budget
        st.set_memory_budget(checked - 1)
        with pytest.raises(st.errors.OutputTooLargeError):
            _check_read_budget(path, (rows, cols), np.dtype(dtype))
    finally:
        st.set_memory_budget(previous)
    assert checked <= peak <= most * rows * cols


# WGS 84, for the independent geodesy below (not stepterrain's own)
_A, _F = 6378137.0, 1 / 298.257223563
_B, _E2 = _A * (1 - _F), _F * (2 - _F)


def _vincenty(lat1, lon1, lat2, lon2):
    """Geodesic distance (m) on WGS 84 between points in radians: Vincenty's inverse formula, vectorised."""
    u1, u2 = np.arctan((1 - _F) * np.tan(lat1)), np.arctan((1 - _F) * np.tan(lat2))
    lam = big_l = lon2 - lon1
    for _ in range(60):
        sin_sigma = np.hypot(np.cos(u2) * np.sin(lam), np.cos(u1) * np.sin(u2) - np.sin(u1) * np.cos(u2) * np.cos(lam))
        cos_sigma = np.sin(u1) * np.sin(u2) + np.cos(u1) * np.cos(u2) * np.cos(lam)
        sigma = np.arctan2(sin_sigma, cos_sigma)
        sin_alpha = np.cos(u1) * np.cos(u2) * np.sin(lam) / np.where(sin_sigma > 0, sin_sigma, 1.0)
        cos2_alpha = 1 - sin_alpha**2
        cos_2sm = np.where(cos2_alpha > 0, cos_sigma - 2 * np.sin(u1) * np.sin(u2) / np.where(cos2_alpha > 0,
                                                                                                cos2_alpha, 1.0), 0.0)
        c = _F / 16 * cos2_alpha * (4 + _F * (4 - 3 * cos2_alpha))
        lam = big_l + (1 - c) * _F * sin_alpha * (sigma + c * sin_sigma * (cos_2sm + c * cos_sigma * (2 * cos_2sm**2
                                                                                                     - 1)))
    u_sq = cos2_alpha * (_A**2 - _B**2) / _B**2
    big_a = 1 + u_sq / 16384 * (4096 + u_sq * (-768 + u_sq * (320 - 175 * u_sq)))
    big_b = u_sq / 1024 * (256 + u_sq * (-128 + u_sq * (74 - 47 * u_sq)))
    delta = big_b * sin_sigma * (cos_2sm + big_b / 4 * (cos_sigma * (2 * cos_2sm**2 - 1) - big_b / 6 * cos_2sm
                                                        * (4 * sin_sigma**2 - 3) * (4 * cos_2sm**2 - 3)))
    return _B * big_a * (sigma - delta)


def _band_area(lat1, lat2, dlon):
    """Exact area (m²) of the WGS 84 quadrangle between latitudes lat1, lat2 and dlon of longitude (radians), from
    the authalic function q(φ)."""
    e = np.sqrt(_E2)

    def q(phi):
        s = np.sin(phi)
        return s / (1 - _E2 * s * s) + np.log((1 + e * s) / (1 - e * s)) / (2 * e)

    return _B**2 * dlon / 2 * np.abs(q(lat2) - q(lat1))


def _local_metres_truth(lat, lon, spacing):
    """Worst relative errors, against WGS 84, of the grid of ``spacing`` (dx, dy) metres load_dem made of the nodes at
    degrees lat (rows) and lon (columns): of the local scale at the rows (east-west, north-south and their product,
    the area scale), of the cells' areas (from the band areas) and of the nodes' map distances from the centre node
    (from Vincenty's geodesics)."""
    phi, lam = np.radians(lat), np.radians(lon)
    (dx, dy), dlam, dphi = spacing, abs(lam[1] - lam[0]), abs(phi[1] - phi[0])
    w = np.sqrt(1 - _E2 * np.sin(phi) ** 2)
    east, north = abs(dx) / (_A / w * np.cos(phi) * dlam), abs(dy) / (_A * (1 - _E2) / w**3 * dphi)
    scale = max(np.abs(east - 1).max(), np.abs(north - 1).max(), np.abs(east * north - 1).max())
    area = np.abs(abs(dx * dy) / _band_area(phi[:-1], phi[1:], dlam) - 1).max()
    i, j = np.meshgrid(np.arange(len(lat)), np.arange(len(lon)), indexing="ij")
    ci, cj = len(lat) // 2, len(lon) // 2
    geodesic = _vincenty(np.full(i.shape, phi[ci]), np.full(i.shape, lam[cj]), phi[i], lam[j])
    mapped = np.hypot((j - cj) * dx, (i - ci) * dy)
    away = geodesic > 0
    return scale, area, np.abs(mapped[away] / geodesic[away] - 1).max()


@pytest.mark.parametrize(
    "lat_c, span, warns",
    [(0.0, 0.5, False), (0.0, 5.0, False), (0.0, 10.0, False), (45.0, 0.5, False), (-45.0, 0.5, False),
     (45.0, 1.0, True), (60.0, 0.5, True), (60.0, 5.0, True), (-75.0, 0.5, True), (0.0, 30.0, True)],
)  # fmt: skip
def test_a_geographic_grid_whose_one_local_spacing_errs_over_1_percent_warns(tmp_path, lat_c, span, warns):
    """A geographic grid became local metres with one spacing (a sphere of R = 6371008.8 m, dx at the centre
    latitude) without a word however tall it was: a 1-degree grid at 45N errs by 1.1 % against WGS 84 east-west, one
    of 5 degrees at 60N by 8 %. load_dem warns (at the caller's line) when the worst scale or cell-area error over its
    rows passes 1 %, naming it; grids it keeps quiet about are within 1 % in scale, cell area and node distances."""
    lat = np.linspace(lat_c + span / 2, lat_c - span / 2, 21)  # north first
    lon = np.linspace(100.0 - span / 2, 100.0 + span / 2, 21)
    np.savez(tmp_path / "geo.npz", elevation=np.zeros((21, 21), np.float32), lat=lat, lon=lon)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t = load_dem(tmp_path / "geo.npz")
    scale, area, distance = _local_metres_truth(lat, lon, t.spacing)
    said = [w for w in caught if "read as local metres" in str(w.message)]
    assert len(said) == int(warns), [str(w.message) for w in caught]
    if warns:
        assert said[0].filename == __file__  # at the caller's line
        message = str(said[0].message)
        assert f"node latitudes {lat_c - span / 2:.6g} to {lat_c + span / 2:.6g} ({span:.6g} degrees)" in message
        stated = float(re.search(r"by up to ([0-9.e+]+) %", message).group(1)) / 100
        assert stated == pytest.approx(scale, rel=6e-3) and stated > 0.01 and area <= stated  # 3 digits stated
        assert ("EPSG:32747 (WGS 84 / UTM zone 47S)" if lat_c < 0 else "EPSG:32647") in message or span > 20
    else:
        assert scale <= 0.01 and area <= 0.01 and distance <= 0.01


def test_a_geographic_geotiff_warns_at_the_callers_line_and_front_range_is_within_1_percent(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    path = tmp_path / "tall.tif"
    profile = {"driver": "GTiff", "width": 4, "height": 40, "count": 1, "dtype": "float32", "crs": "EPSG:4326",
               "transform": rasterio.Affine(0.25, 0.0, 10.0, 0.0, -0.25, 70.0)}
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(np.zeros((40, 4), np.float32), 1)
    with pytest.warns(UserWarning, match=r"tall\.tif: EPSG:4326 degrees read as local metres.*node latitudes 60\.125 "
                                         r"to 69\.875 \(9\.75 degrees\).*gdalwarp -r bilinear -dstalpha -t_srs "
                                         r"EPSG:32632 tall\.tif tall_m\.tif") as caught:
        load_dem(path)
    assert caught[0].filename == __file__
    front_range = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
    if front_range.exists():  # 0.63 degrees at 40N: 0.7 % at worst, quiet
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            t = load_dem(front_range)
        lat = 40.4658333333 - np.arange(0, 758, 21) / 1200  # every 21st node: 21 times the spacing
        lon = -105.8158333333 + np.arange(0, 758, 21) / 1200
        scale, area, distance = _local_metres_truth(lat, lon, (21 * t.spacing[0], 21 * t.spacing[1]))
        assert max(scale, area, distance) <= 0.01


def test_npz_dx_m_dy_m_are_described_by_the_crs_they_are_exact_in(tmp_path):
    """An .npz's dx_m/dy_m became the spacing, but the crs still said +R=6371008.8 with the standard parallel at the
    centre latitude: describe_dem's lon/lat extent and an exported GeoTIFF's georeference were off by the ratio (the
    far corner of a 0.1-degree grid by 0.0003 degrees here, any amount for other metres). The crs now is the sphere
    and parallel that make those metres exact, checked here by PROJ (rasterio) against the file's own degrees."""
    from stepterrain.io import describe_dem

    z = np.zeros((11, 21), np.float32)
    transform = np.array([10.0, 0.01, 0.0, 45.0, 0.0, -0.01])  # node (0, 0) at 10.005E 44.995N
    np.savez(tmp_path / "m.npz", elevation=z, transform=transform, crs="EPSG:4326", dx_m=785.0, dy_m=1111.0)
    t = load_dem(tmp_path / "m.npz")
    assert t.spacing == (785.0, -1111.0)
    truth = (10.005, 10.005 + 20 * 0.01, 44.995 - 10 * 0.01, 44.995)
    assert describe_dem(t)["lonlat_extent"] == pytest.approx(truth, abs=1e-9)
    assert describe_dem(t)["lonlat_step"] == pytest.approx((0.01, -0.01), rel=1e-9)
    rasterio = pytest.importorskip("rasterio")
    from rasterio.warp import transform as reproject

    lon, lat = reproject(rasterio.crs.CRS.from_string(t.crs), "EPSG:4326", [20 * 785.0], [-10 * 1111.0])
    assert (lon[0], lat[0]) == pytest.approx((truth[1], truth[2]), abs=1e-9)
    # more metres per degree of longitude than of latitude (WGS 84 at the equator: N > M): no sphere's equidistant
    # cylindrical projection has them; the metres are kept, without a crs
    equator = np.array([10.0, 0.01, 0.0, 0.05, 0.0, -0.01])
    np.savez(tmp_path / "wide.npz", elevation=z, transform=equator, crs="EPSG:4326", dx_m=1113.195, dy_m=1105.74)
    message = r"wide\.npz: its dx_m, dy_m \(1113\.195, 1105\.74 m\).*without a CRS"
    with pytest.warns(UserWarning, match=message) as w:
        t = load_dem(tmp_path / "wide.npz")
    assert t.crs is None and t.spacing == (1113.195, -1105.74) and w[0].filename == __file__


@pytest.mark.parametrize(
    "keys",
    [{"dx": 30.0, "dy": 30.0, "crs": "EPSG:32611"}, {"spacing": (30.0, -30.0), "origin": (5e5, 4e6)},
     {"lat": np.linspace(45.0, 44.0, 3)}, {"lon": np.linspace(5.0, 6.0, 4)}, {"crs": "EPSG:4326"}],
)  # fmt: skip
def test_npz_georeferencing_keys_without_a_transform_are_refused_not_ignored(tmp_path, keys):
    # np.savez(elevation=z, dx=30, dy=30, crs="EPSG:32611") (or spacing/origin, or 'lat' without 'lon') read as an
    # unreferenced grid of 1 m cells at (0, 0), the keys ignored without a word: a mesh 30 times too small
    np.savez(tmp_path / "keys.npz", elevation=np.zeros((3, 4), np.float32), **keys)
    named = ", ".join(repr(k) for k in keys)
    with pytest.raises(DataFileError, match=rf"keys\.npz.*expected a 'transform'.*'lat' and 'lon'.*got {named} but "
                                            r"neither.*1 m cells"):
        load_dem(tmp_path / "keys.npz")
    np.savez(tmp_path / "plain.npz", elevation=np.zeros((3, 4), np.float32), units="m")  # no such key: unreferenced
    assert load_dem(tmp_path / "plain.npz").spacing == (1.0, -1.0)


@pytest.mark.parametrize(
    ("lon", "x0", "dx"),
    [([178.0, 179.0, 180.0, -179.0], 177.5, 1.0), ([179.5, -179.5, -178.5, -177.5], 179.0, 1.0),
     ([358.0, 359.0, 0.0, 1.0], 357.5, 1.0), ([-179.0, 180.0, 179.0, 178.0], -178.5, -1.0)],
)  # fmt: skip
def test_npz_lat_lon_axes_across_the_antimeridian_read_as_the_same_grid_with_a_transform(tmp_path, lon, x0, dx):
    # a 'lon' axis of evenly spaced nodes that crosses the antimeridian ([178, 179, 180, -179]) was refused as
    # "'lon' must be evenly spaced degrees; got steps that differ from their mean -119 by up to 240"; it reads as the
    # grid whose geotransform runs on past 180 (as a GeoTIFF's does), and an axis uneven across it is still refused
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    lat = np.array([10.0, 9.0, 8.0])
    np.savez(tmp_path / "axes.npz", elevation=z, lat=lat, lon=np.array(lon))
    np.savez(tmp_path / "transform.npz", elevation=z, transform=np.array([x0, dx, 0.0, 10.5, 0.0, -1.0]),
             crs="EPSG:4326")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # degrees read as local metres: the same warning, or none, for both
        axes, transform = load_dem(tmp_path / "axes.npz"), load_dem(tmp_path / "transform.npz")
    assert (axes.spacing, axes.origin, axes.crs) == (transform.spacing, transform.origin, transform.crs)
    assert np.array_equal(axes.heights, transform.heights)
    uneven = np.array(lon) + np.array([0.0, 0.0, 0.0, 1.0])
    np.savez(tmp_path / "uneven.npz", elevation=z, lat=lat, lon=uneven)
    with pytest.raises(DataFileError, match=r"uneven\.npz.*'lon' must be evenly spaced degrees"):
        load_dem(tmp_path / "uneven.npz")


@pytest.mark.parametrize("lat, warns", [(0.0, False), (46.5, True), (-60.0, True)])
def test_a_web_mercator_grid_warns_that_its_metres_are_not_ground_metres(tmp_path, lat, warns):
    """A DEM in Web Mercator (EPSG:3857, the CRS of web terrain tiles) was read with its Mercator metres as ground
    metres without a word: 1/cos φ too wide and long, 1.45 times at 46.5N (the Alps), so every slope was 1.45 times
    too flat. load_dem warns at the caller's line, naming the scale; checked against the closed-form inverse of the
    spherical Mercator on WGS 84 (kx = a / (N cos φ)), independent of PROJ. A UTM grid there and a Web Mercator one
    at the equator (within 1 %) stay quiet."""
    rasterio = pytest.importorskip("rasterio")
    a, e2 = 6378137.0, 0.0066943799901413165  # WGS 84
    y0 = a * np.log(np.tan(np.pi / 4 + np.radians(lat) / 2))
    profile = {"driver": "GTiff", "width": 4, "height": 3, "count": 1, "dtype": "float32", "crs": "EPSG:3857",
               "transform": rasterio.Affine(30.0, 0.0, a * np.radians(9.5), 0.0, -30.0, y0 + 45.0)}
    with rasterio.open(tmp_path / "tiles.tif", "w", **profile) as ds:
        ds.write(np.full((3, 4), 1000.0, np.float32), 1)
    np.savez(tmp_path / "tiles.npz", elevation=np.full((3, 4), 1000.0, np.float32), crs="EPSG:3857",
             transform=np.array(profile["transform"].to_gdal()))  # fmt: skip
    for name in ("tiles.tif", "tiles.npz"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t = load_dem(tmp_path / name)
        assert t.spacing == (30.0, -30.0) and t.crs == "EPSG:3857"  # read as stored
        said = [w for w in caught if "Mercator" in str(w.message)]
        assert len(said) == int(warns), [str(w.message) for w in caught]
        if warns:
            assert said[0].filename == __file__
            message = str(said[0].message)
            phi = np.radians(lat)
            kx = a / (a / np.sqrt(1 - e2 * np.sin(phi) ** 2) * np.cos(phi))
            stated = float(re.search(r"x ([0-9.]+) east-west", message).group(1))
            assert stated == pytest.approx(kx, rel=1e-3), message
            zone = "EPSG:32632" if lat > 0 else "EPSG:32732"
            assert zone in message and f"{name}: EPSG:3857 is a Mercator projection" in message
    with rasterio.open(tmp_path / "utm.tif", "w", **{**profile, "crs": "EPSG:32632",
                       "transform": rasterio.Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 5150000.0)}) as ds:
        ds.write(np.full((3, 4), 1000.0, np.float32), 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_dem(tmp_path / "utm.tif")


@pytest.mark.parametrize("saved", ["first_six", "matrix", "flat_nine"])
def test_an_npz_transform_in_rasterios_affine_order_is_refused_naming_to_gdal(tmp_path, saved):
    """np.savez(..., transform=dataset.transform[:6]) (or np.array(dataset.transform)) saves rasterio's Affine order
    (dx, 0, x0, 0, -dy, y0), not GDAL's: the north-up grid was refused as "a rotated geotransform" (or a list of 9
    numbers as not 6), sending the user after a rotation that is not there. The error now names the Affine order and
    gives the GDAL geotransform to save; that geotransform reads as the grid rasterio places."""
    rasterio = pytest.importorskip("rasterio")
    affine = rasterio.Affine(30.0, 0.0, 376313.5, 0.0, -30.0, 3807917.5)
    transform = {"first_six": np.array(affine)[:6], "matrix": np.array(affine).reshape(3, 3),
                 "flat_nine": np.array(affine)}[saved]  # fmt: skip
    heights = np.arange(12.0, dtype=np.float32).reshape(3, 4)
    np.savez(tmp_path / "dem.npz", elevation=heights, transform=transform, crs="EPSG:32611")
    with pytest.raises(DataFileError, match=r"'transform' must be a GDAL geotransform") as info:
        load_dem(tmp_path / "dem.npz")
    message = str(info.value)
    assert "Affine" in message and "to_gdal()" in message and "rotated" not in message
    stated = eval(re.search(r"here (\([^)]*\))", message).group(1))  # the geotransform the message gives
    assert stated == affine.to_gdal()
    np.savez(tmp_path / "fixed.npz", elevation=heights, transform=np.array(stated), crs="EPSG:32611")
    t = load_dem(tmp_path / "fixed.npz")
    assert t.origin == affine @ (0.5, 0.5) and t.spacing == (30.0, -30.0)  # node (0, 0): the top-left cell's centre


def _grey_png(path, bits, rows, transparent):
    """A greyscale PNG of ``bits`` per sample (1, 2 or 4: Pillow writes none), rows of raw samples, a tRNS value."""
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    per_byte = 8 // bits
    packed = b""
    for row in rows:
        row = list(row) + [0] * (-len(row) % per_byte)
        packed += b"\0" + bytes(sum(v << (8 - bits * (k + 1)) for k, v in enumerate(row[i:i + per_byte]))
                                for i in range(0, len(row), per_byte))
    header = struct.pack(">IIBBBBB", len(rows[0]), len(rows), bits, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"tRNS", struct.pack(">H", transparent))
                     + chunk(b"IDAT", zlib.compress(packed)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("bits", [2, 4])
def test_the_transparent_value_of_a_2_or_4_bit_png_marks_its_missing_cells(tmp_path, bits):
    """Pillow reads a 2- or 4-bit grey PNG's samples scaled to 0-255 (x 85, x 17) but reports its tRNS value raw,
    so the transparent cells (GDAL's nodata for a PNG) were read as heights: a 4-bit map's hole at tRNS 15 became a
    255 m peak. The tRNS value is now compared in the samples' scale."""
    top = 2**bits - 1
    rows = [[0, 1, top], [top, 2, 1], [1, 0, top]]
    _grey_png(tmp_path / "map.png", bits, rows, transparent=top)
    t = load_dem(tmp_path / "map.png")
    raw = np.array(rows)
    np.testing.assert_array_equal(np.isnan(t.heights), raw == top)
    np.testing.assert_array_equal(t.heights[raw != top], raw[raw != top] * (255 // top))  # heights as before


@pytest.mark.parametrize("dtype, nodata", [(np.float32, 1e40), (np.float16, -99999.0)])
def test_an_npz_nodata_beyond_the_heights_dtype_reads_without_a_numpy_warning(tmp_path, dtype, nodata):
    """A nodata the heights' float dtype cannot hold (-99999 beside float16 heights) leaked NumPy's "overflow
    encountered in cast" RuntimeWarning from inside load_dem; it matches no finite height, and none is marked."""
    heights = np.array([[1.0, 2.0], [np.inf, 4.0]], dtype)
    np.savez(tmp_path / "dem.npz", elevation=heights, nodata=nodata)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t = load_dem(tmp_path / "dem.npz")
    np.testing.assert_array_equal(t.heights, np.array([[1.0, 2.0], [np.nan, 4.0]], np.float32))


@pytest.mark.parametrize("arcsec", [1, 3])
def test_npz_lat_lon_axes_in_float32_read_as_evenly_spaced(tmp_path, arcsec):
    """1-D lat/lon axes stored as float32 (an xarray DEM's coordinates, np.savez(elevation=..., lat=ds.lat.values,
    lon=ds.lon.values)) at 1 or 3 arc-seconds were refused as "unevenly spaced": float32 rounds degrees near 100-180 to
    1.5e-5, 1-5 % of such a step, beyond the 0.1 % allowed. Within the axis's own rounding they now read, as the
    float64 axes they round read; an axis off by more than that is still refused."""
    step, n = arcsec / 3600.0, 400
    lat64, lon64 = 40.0 - np.arange(n) * step, 179.8 + np.arange(n) * step  # across the antimeridian in the end
    lon64 = (lon64 + 180.0) % 360.0 - 180.0
    heights = np.random.default_rng(0).random((n, n)).astype(np.float32)
    np.savez(tmp_path / "f64.npz", elevation=heights, lat=lat64, lon=lon64)
    np.savez(tmp_path / "f32.npz", elevation=heights, lat=lat64.astype(np.float32), lon=lon64.astype(np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # not the point here
        exact, rounded = load_dem(tmp_path / "f64.npz"), load_dem(tmp_path / "f32.npz")
    np.testing.assert_array_equal(rounded.heights, heights)
    span_error = 2 * float(np.spacing(np.float32(180.0))) / ((n - 1) * step)  # the ends' float32 rounding
    np.testing.assert_allclose(rounded.spacing, exact.spacing, rtol=span_error)
    node = re.search(r"lon (\S+), lat (\S+);", rounded.source).groups()
    assert abs(float(node[0]) - lon64[0]) < 1e-5 and abs(float(node[1]) - lat64[0]) < 1e-5
    bent = lon64.astype(np.float32)
    bent[n // 2 :] += np.float32(5e-5)  # one step 5e-5 degrees (3 float32 spacings) longer
    np.savez(tmp_path / "bent.npz", elevation=heights, lat=lat64.astype(np.float32), lon=bent)
    with pytest.raises(DataFileError, match=r"'lon' must be evenly spaced degrees.*float32 rounding"):
        load_dem(tmp_path / "bent.npz")


def test_a_site_grid_in_feet_has_its_spacing_and_origin_converted_to_metres_with_its_heights(tmp_path):
    """A GeoTIFF on a local engineering CRS (a site grid, LOCAL_CS: drone and survey DEMs) in US survey feet kept
    its spacing and origin in feet as metres while the band's unit "US survey foot" made its heights metres: the mesh
    was 3.28 times too wide for its heights. Spacing and origin now become metres as a projected CRS's do, checked
    against rasterio's own transform, and the crs is the site grid in metres."""
    rasterio = pytest.importorskip("rasterio")
    site = ('LOCAL_CS["site grid",UNIT["US survey foot",0.304800609601219,AUTHORITY["EPSG","9003"]],'
            'AXIS["Easting",EAST],AXIS["Northing",NORTH]]')
    heights = np.arange(12.0, dtype=np.float32).reshape(3, 4) + 100.0
    profile = {"driver": "GTiff", "width": 4, "height": 3, "count": 1, "dtype": "float32", "crs": site,
               "transform": rasterio.Affine(3.0, 0.0, 1000.0, 0.0, -3.0, 5000.0)}
    with rasterio.open(tmp_path / "site.tif", "w", **profile) as ds:
        ds.write(heights, 1)
        ds.units = ("US survey foot",)
    foot = 1200 / 3937
    with rasterio.open(tmp_path / "site.tif") as ds:
        centre = ds.transform @ (0.5, 0.5)  # node (0, 0) in the file's feet
        stored = ds.read(1)
    np.savez(tmp_path / "site.npz", elevation=heights, transform=np.array(profile["transform"].to_gdal()), crs=site,
             units="US survey foot")  # fmt: skip
    for name in ("site.tif", "site.npz"):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # heights' unit named: nothing to warn about
            t = load_dem(tmp_path / name)
        np.testing.assert_allclose(t.spacing, (3.0 * foot, -3.0 * foot), rtol=1e-12)
        np.testing.assert_allclose(t.origin, (centre[0] * foot, centre[1] * foot), rtol=1e-12)
        np.testing.assert_allclose(t.heights, stored * foot, rtol=1e-6)
        assert t.crs is not None and 'UNIT["metre",1' in t.crs and "site grid" in t.crs and "foot" not in t.crs


@pytest.mark.parametrize("noise", [(1e-16, -1e-16), (30e-12, 0.0), (0.0, -3e-11)])
def test_a_geotransform_whose_rotation_terms_are_float_noise_reads_as_north_up(tmp_path, noise):
    """A geotransform whose rotation terms are float noise (1e-16, or 1e-12 of the pixel size, as some tools write
    after a round trip through an Affine or a projection) was refused as "a rotated geotransform", GeoTIFF and .npz
    alike. Terms that move no node by more than 1e-6 of a cell over the grid are taken as 0 now: the grid reads as
    the north-up one without them. A real rotation (shifting the last of 300 rows by 3e-6 of a cell, or more) is
    still refused, and rasterio's Affine order saved with such noise is still told apart (the to_gdal() hint)."""
    rasterio = pytest.importorskip("rasterio")
    heights = np.arange(12.0, dtype=np.float32).reshape(3, 4)
    row_x, col_y = noise
    gdal = (376298.5, 30.0, row_x, 3807932.5, col_y, -30.0)
    clean = (376298.5, 30.0, 0.0, 3807932.5, 0.0, -30.0)
    profile = {"driver": "GTiff", "width": 4, "height": 3, "count": 1, "dtype": "float32", "crs": "EPSG:32611"}
    for name, transform in (("noisy", gdal), ("clean", clean)):
        with rasterio.open(tmp_path / f"{name}.tif", "w", **profile,
                           transform=rasterio.Affine.from_gdal(*transform)) as ds:
            ds.write(heights, 1)
        np.savez(tmp_path / f"{name}.npz", elevation=heights, transform=np.array(transform), crs="EPSG:32611")
    with rasterio.open(tmp_path / "noisy.tif") as ds:
        assert ds.transform.to_gdal() != clean  # the noise survives the GeoTIFF
    for ext in ("tif", "npz"):
        noisy, expected = load_dem(tmp_path / f"noisy.{ext}"), load_dem(tmp_path / f"clean.{ext}")
        assert (noisy.spacing, noisy.origin, noisy.crs) == (expected.spacing, expected.origin, expected.crs)
        assert noisy.origin == (376313.5, 3807917.5)
        np.testing.assert_array_equal(noisy.heights, heights)
    tall = np.zeros((300, 4), np.float32)  # 300 rows: 1e-8 of a 30 m cell per row shifts the last by 3e-6 of a cell
    for rotation in (30.0 * 1e-8, 0.5):
        np.savez(tmp_path / "rotated.npz", elevation=tall, transform=np.array([0.0, 30.0, rotation, 0.0, 0.0, -30.0]),
                 crs="EPSG:32611")  # fmt: skip
        with pytest.raises(DataFileError, match=r"rotated\.npz.*expected a north-up grid; got a rotated geotransform"):
            load_dem(tmp_path / "rotated.npz")
    affine = np.array([30.0, row_x, 376298.5, col_y, -30.0, 3807932.5])  # rasterio's order, with the noise
    np.savez(tmp_path / "affine.npz", elevation=heights, transform=affine, crs="EPSG:32611")
    with pytest.raises(DataFileError, match=r"Affine .*to_gdal\(\)"):
        load_dem(tmp_path / "affine.npz")


def test_an_npz_mask_or_valid_key_marks_missing_cells(tmp_path):
    """np.savez(..., elevation=m.data, mask=m.mask) (a NumPy masked array's parts) or a 'valid' array beside the
    heights was ignored silently: the masked cells (0, -32768 fill) read as heights, pits in the mesh. A boolean
    'mask' (True = missing) and 'valid' (True = present) of the heights' shape now make those cells NaN, with a
    transform or without, alone or together; an archive of one unnamed array and a mask reads the array. A mask of
    another dtype or shape is refused, naming what it must be (a 0/255 GDAL mask band means the opposite of 0/1)."""
    z = np.array([[100, -32768, 102, 103], [104, 105, 0, 107], [108, 109, 110, 111]], np.int16)
    masked = np.ma.masked_equal(np.where(z == 0, -32768, z), -32768)
    missing = np.ma.getmaskarray(masked)
    transform = np.array([500000.0, 30.0, 0.0, 4000000.0, 0.0, -30.0])
    np.savez(tmp_path / "mask.npz", elevation=z, mask=missing, transform=transform, crs="EPSG:32611")
    np.savez(tmp_path / "valid.npz", elevation=z, valid=~missing)
    np.savez(tmp_path / "plain.npz", z, mask=missing)  # arr_0 and a mask
    half = missing.copy()
    half[0, 1] = False
    np.savez(tmp_path / "both.npz", heights=z, mask=half, valid=~(missing & ~half))  # each marks one cell
    for name in ("mask.npz", "valid.npz", "plain.npz", "both.npz"):
        h = load_dem(tmp_path / name).heights
        np.testing.assert_array_equal(np.isnan(h), missing, err_msg=name)
        np.testing.assert_array_equal(h[~missing], z[~missing].astype(np.float32), err_msg=name)
    np.savez(tmp_path / "all.npz", elevation=z, mask=np.ones(z.shape, bool))
    with pytest.raises(DataFileError, match=r"all\.npz.*all nodata"):
        load_dem(tmp_path / "all.npz")
    for name, key, value, got in (
        ("gdal.npz", "mask", np.where(missing, 0, 255).astype(np.uint8), r"uint8 of shape \(3, 4\); save .*valid="),
        ("shape.npz", "mask", missing[:, :3], r"bool of shape \(3, 3\)"),
        ("float.npz", "valid", (~missing).astype(float), r"float64 of shape \(3, 4\)"),
    ):
        np.savez(tmp_path / name, elevation=z, transform=transform, **{key: value})
        with pytest.raises(DataFileError, match=rf"{name}.*'{key}' must be a boolean array of the heights' shape "
                                                rf"\(3, 4\), True where a cell is .*; got {got}"):
            load_dem(tmp_path / name)


_E2 = 0.0066943799901413165  # WGS 84
_E = np.sqrt(_E2)


def _m(phi):
    return np.cos(phi) / np.sqrt(1 - _E2 * np.sin(phi) ** 2)


def _lcc_scale(lat, lat_1=33.0, lat_2=45.0):
    """Map scale of the two-parallel Lambert conformal conic on WGS 84 at ``lat`` (Snyder 15-9 to 15-11, 14-15)."""
    def t(phi):
        return np.tan(np.pi / 4 - phi / 2) / ((1 - _E * np.sin(phi)) / (1 + _E * np.sin(phi))) ** (_E / 2)
    p1, p2, phi = np.radians([lat_1, lat_2, lat])
    n = (np.log(_m(p1)) - np.log(_m(p2))) / (np.log(t(p1)) - np.log(t(p2)))
    return _m(p1) * t(phi) ** n / (_m(phi) * t(p1) ** n)


def _albers_parallel_scale(lat, lat_1=29.5, lat_2=45.5):
    """Scale along the parallel of the Albers equal-area conic on WGS 84 at ``lat`` (Snyder 14-12, 14-13, 3-12);
    along the meridian it is the inverse."""
    def q(phi):
        s = np.sin(phi)
        return (1 - _E2) * (s / (1 - _E2 * s * s) - np.log((1 - _E * s) / (1 + _E * s)) / (2 * _E))
    p1, p2, phi = np.radians([lat_1, lat_2, lat])
    n = (_m(p1) ** 2 - _m(p2) ** 2) / (q(p2) - q(p1))
    return np.sqrt(_m(p1) ** 2 + n * q(p1) - n * q(phi)) / _m(phi)


_LCC = "+proj=lcc +lat_1=33 +lat_2=45 +lat_0=39 +lon_0=-96 +datum=WGS84 +units=m +no_defs"
_AEA = "+proj=aea +lat_1=29.5 +lat_2=45.5 +lat_0=23 +lon_0=-96 +datum=WGS84 +units=m +no_defs"
_SINU = "+proj=sinu +lon_0=0 +datum=WGS84 +units=m +no_defs"


def _sinusoidal(lon, lat):
    return 1.0, 1 / np.hypot(1.0, np.radians(lon) * np.sin(np.radians(lat))), 1.0


def _web_mercator(lon, lat):
    phi = np.radians(lat)
    meridian = (1 - _E2) / (1 - _E2 * np.sin(phi) ** 2) ** 1.5  # M / a
    return 1 / _m(phi), 1 / (meridian * np.cos(phi)), 1 / (_m(phi) * meridian * np.cos(phi))


def _polar_stereographic_at_pole(lon, lat, lat_ts=-71.0):
    """Scale at the pole of the polar stereographic true at ``lat_ts`` on WGS 84 (Snyder 21-35; EPSG:3031)."""
    phi = np.radians(abs(lat_ts))
    t = np.tan(np.pi / 4 - phi / 2) / ((1 - _E * np.sin(phi)) / (1 + _E * np.sin(phi))) ** (_E / 2)
    k = _m(phi) * np.sqrt((1 + _E) ** (1 + _E) * (1 - _E) ** (1 - _E)) / (2 * t)
    return k, k, k * k


@pytest.mark.parametrize("crs, lon, lat, expected", [
    (_LCC, -96.0, 25.0, lambda lon, lat: (_lcc_scale(lat), _lcc_scale(lat), _lcc_scale(lat) ** 2)),  # south edge
    (_LCC, -96.0, 53.0, lambda lon, lat: (_lcc_scale(lat), _lcc_scale(lat), _lcc_scale(lat) ** 2)),  # north edge
    (_LCC.replace("+units=m", "+units=us-ft"), -96.0, 25.0,
     lambda lon, lat: (_lcc_scale(lat), _lcc_scale(lat), _lcc_scale(lat) ** 2)),  # in feet
    (_AEA, -96.0, 50.0, lambda lon, lat: (_albers_parallel_scale(lat), 1 / _albers_parallel_scale(lat), 1.0)),
    (_SINU, 40.0, 40.0, _sinusoidal),
    (_SINU, 60.0, 20.0, _sinusoidal),
    ("EPSG:3857", 9.5, 46.5, _web_mercator),  # spherical Mercator on WGS 84 degrees: not conformal on the ellipsoid
    ("EPSG:3031", 0.0, -90.0, _polar_stereographic_at_pole),  # Antarctic polar stereographic, true at 71 S
])  # fmt: skip
def test_a_projected_grid_whose_map_scale_errs_by_over_1_percent_warns_naming_it(tmp_path, crs, lon, lat, expected):
    """Only a Mercator grid's map scale was checked: a continent-wide Lambert conformal conic or Albers grid (1-2 %
    off at its edges) or a sinusoidal one (MODIS) far from its central meridian (stretched north-south by its shear)
    was read as ground metres without a word. Every projected CRS is measured now (through PROJ at sampled nodes),
    and the warning's x and y scales and cell-area factor match the closed-form map scales of each projection on
    WGS 84: conformal conic k along both axes and k² in area; Albers k along the parallel, 1/k along the meridian,
    area 1; sinusoidal 1 along the parallel, 1/sqrt(1 + (λ sin φ)²) along its grid y (sheared), area 1 (equal-area);
    Web Mercator a/(N cos φ) east-west and a/(M cos φ) north-south. GeoTIFF and .npz alike; the stated error is the
    worst of them."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.warp import transform

    (x,), (y,) = transform("EPSG:4326", crs, [lon], [lat])
    unit = 1200 / 3937 if "us-ft" in crs else 1.0
    cell = 100.0 / unit  # 100 m
    gdal = (x - cell / 2, cell, 0.0, y + cell / 2, 0.0, -cell)  # node (0, 0) at (lon, lat)
    heights = np.full((3, 4), 1000.0, np.float32)
    with rasterio.open(tmp_path / "grid.tif", "w", driver="GTiff", width=4, height=3, count=1, dtype="float32",
                       crs=crs, transform=rasterio.Affine.from_gdal(*gdal)) as ds:
        ds.write(heights, 1)
    np.savez(tmp_path / "grid.npz", elevation=heights, transform=np.array(gdal), crs=crs, units="m")
    kx, ky, area = expected(lon, lat)
    for name in ("grid.tif", "grid.npz"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t = load_dem(tmp_path / name)
        assert t.spacing == pytest.approx((100.0, -100.0), rel=1e-9)
        said = [str(w.message) for w in caught if "ground distances and cell areas" in str(w.message)]
        assert len(said) == 1 and caught[-1].filename == __file__, [str(w.message) for w in caught]
        stated = re.search(r"by up to ([0-9.]+) % .*\(x ([0-9.]+) east-west and x ([0-9.]+) north-south along the "
                           r"grid's x and y, x ([0-9.]+) in cell area, at latitude ([-0-9.]+)", said[0])
        assert stated, said[0]
        error, sx, sy, sa, at = (float(v) for v in stated.groups())
        assert (sx, sy, sa) == pytest.approx((kx, ky, area), rel=1e-3), said[0]
        assert error / 100 == pytest.approx(max(abs(kx - 1), abs(ky - 1), abs(area - 1)), rel=1e-2), said[0]
        assert at == pytest.approx(lat, abs=0.01)
        assert ("is a Mercator projection" in said[0]) == (crs == "EPSG:3857")
        if crs == "EPSG:3031":  # the hint is not the CRS the grid is in already
            assert "+proj=stere +lat_0=-90 +lat_ts=-90.0" in said[0] and "-t_srs EPSG:3031" not in said[0]


@pytest.mark.parametrize("crs, lon, lat, cell, shape", [
    ("EPSG:32633", 12.0, 0.5, 10000.0, (70, 67)),  # a whole UTM zone at the equator, 3 degrees either side
    ("EPSG:32633", 15.0, 60.0, 30.0, (50, 40)),  # a small UTM grid
    ("EPSG:2229", -118.3, 34.1, 10.0, (20, 30)),  # state plane, US survey feet
    (_LCC, -96.0, 36.0, 1000.0, (40, 40)),  # between the conic's standard parallels
    (_SINU, 0.5, 40.0, 1000.0, (40, 40)),  # sinusoidal near its central meridian
    ("EPSG:3857", 9.5, 0.5, 30.0, (30, 30)),  # Web Mercator at the equator
])  # fmt: skip
def test_a_projected_grid_within_1_percent_of_ground_metres_stays_quiet(tmp_path, crs, lon, lat, cell, shape):
    """The generalised map-scale check stays quiet where a projection's metres are ground metres to 1 %: UTM over
    its zone (0.9996-1.001), a small local grid in state-plane feet, a conic between its standard parallels."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.warp import transform

    (x,), (y,) = transform("EPSG:4326", crs, [lon], [lat])
    with rasterio.open(tmp_path / "grid.tif", "w", driver="GTiff", width=shape[1], height=shape[0], count=1,
                       dtype="float32", crs=crs, transform=rasterio.Affine(cell, 0.0, x, 0.0, -cell, y)) as ds:
        ds.units = ("metre",)
        ds.write(np.full(shape, 10.0, np.float32), 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_dem(tmp_path / "grid.tif")


def _geographic_tif(path, crs, x0, y0, step, shape=(11, 21)):
    rasterio = pytest.importorskip("rasterio")
    profile = {"driver": "GTiff", "width": shape[1], "height": shape[0], "count": 1, "dtype": "float32", "crs": crs,
               "transform": rasterio.Affine(step, 0.0, x0, 0.0, -step, y0)}
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(np.zeros(shape, np.float32), 1)
    return path


@pytest.mark.parametrize("crs, radius", [
    ("IAU_2015:49900", 3396190.0),  # Mars (2015) sphere, ocentric
    ("+proj=longlat +R=3396190 +no_defs", 3396190.0),
    ("IAU_2015:30100", 1737400.0),  # Moon (2015) sphere
    ("+proj=longlat +a=3396190 +rf=169.894447223612 +no_defs", 3396190.0 * (1 - 1 / (3 * 169.894447223612))),
])
def test_a_geographic_grid_on_another_body_becomes_metres_of_that_body(tmp_path, crs, radius):
    """Degrees of a Mars or Moon DEM became metres of the earth's sphere (R = 6371008.8 m): a Mars grid 1.88 times too
    wide and long for its heights, its crs an earth projection that put an exported texture on the earth. They are
    now metres of the CRS's own body (a sphere of its ellipsoid's mean radius), checked against the file's degrees
    through PROJ, and the 1 % check compares them with that body, not with WGS 84 (which warned of a 47 % error)."""
    from stepterrain.io import describe_dem

    path = _geographic_tif(tmp_path / "body.tif", crs, 10.0, 5.0, 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t = load_dem(path)
    centre = np.radians(5.0 - 0.055)
    assert t.spacing == pytest.approx((radius * np.cos(centre) * np.radians(0.01), -radius * np.radians(0.01)),
                                      rel=1e-9)
    truth = (10.005, 10.205, 4.895, 4.995)
    assert describe_dem(t)["lonlat_extent"] == pytest.approx(truth, abs=1e-9)
    rasterio = pytest.importorskip("rasterio")
    from rasterio.warp import transform as reproject

    sphere = f"+proj=longlat +R={radius!r} +no_defs"  # the far corner node back to degrees on that body's sphere
    x, y = 20 * t.spacing[0], 10 * t.spacing[1]
    lon, lat = reproject(rasterio.crs.CRS.from_string(t.crs), rasterio.crs.CRS.from_string(sphere), [x], [y])
    assert (lon[0], lat[0]) == pytest.approx((truth[1], truth[2]), abs=1e-9)
    # a grid 10 degrees tall at 60-70 N errs by cos φ against the body's own ellipsoid, named as such (no earth UTM)
    tall = _geographic_tif(tmp_path / "tall.tif", crs, 10.0, 70.0, 0.25, shape=(40, 4))
    with pytest.warns(UserWarning, match=r"tall\.tif: .*degrees read as local metres.*node latitudes 60\.125 to "
                                         r"69\.875") as caught:
        load_dem(tall)
    assert "WGS 84" not in str(caught[0].message) and "UTM" not in str(caught[0].message)


@pytest.mark.parametrize("crs, x0, y0, step", [
    ("EPSG:4807", 0.0, 50.0, 0.01),  # NTF (Paris): grads east of Paris
    ('GEOGCS["NTF (Paris) in degrees",DATUM["NTF",SPHEROID["Clarke 1880 (IGN)",6378249.2,293.466021293627]],'
     'PRIMEM["Paris",2.33722917],UNIT["degree",0.0174532925199433],AXIS["Latitude",NORTH],AXIS["Longitude",EAST]]',
     0.0, 45.0, 0.01),
])
def test_a_geographic_grid_in_grads_or_east_of_another_prime_meridian_is_placed_by_greenwich_degrees(
        tmp_path, crs, x0, y0, step):
    """A geographic CRS whose angles are grads (EPSG:4807, NTF (Paris)) had its grads read as degrees (the grid 10 %
    too large, its latitudes 10 % off), and one whose longitudes count from the Paris meridian had them read as
    Greenwich longitudes: describe_dem's extent and the crs (so an exported GeoTIFF texture) lay 2.34 degrees west.
    Checked against PROJ (rasterio) taking the file's own node coordinates to NTF degrees from Greenwich
    (EPSG:4275)."""
    from stepterrain.io import EARTH_RADIUS_M, describe_dem

    rasterio = pytest.importorskip("rasterio")
    from rasterio.warp import transform as reproject

    path = _geographic_tif(tmp_path / "ntf.tif", crs, x0, y0, step)
    t = load_dem(path)
    with rasterio.open(path) as ds:
        (ax, ay), (bx, by) = ds.xy(0, 0), ds.xy(10, 20)
    (lon0, lon1), (lat0, lat1) = reproject(ds.crs, "EPSG:4275", [ax, bx], [ay, by])
    info = describe_dem(t)
    assert info["lonlat_extent"] == pytest.approx((lon0, lon1, lat1, lat0), abs=1e-8)  # PROJ: Paris 2°20'14.025"
    assert -t.spacing[1] == pytest.approx(EARTH_RADIUS_M * np.radians(lat0 - lat1) / 10, rel=1e-3)
    lon, lat = reproject(rasterio.crs.CRS.from_string(t.crs), "+proj=longlat +R=6371008.8 +no_defs",
                         [20 * t.spacing[0]], [10 * t.spacing[1]])
    assert (lon[0], lat[0]) == pytest.approx((lon1, lat1), abs=1e-8)


@pytest.mark.parametrize("dtype", [np.float32, np.int16, np.uint8])
def test_a_geotiffs_nodata_internal_mask_and_alpha_band_all_mark_missing_cells(tmp_path, dtype):
    """GDAL's mask of a band is one of its internal mask, its nodata value and an alpha band, in that order: the
    others a file also has went unread. A cell at the nodata value (-9999, 255) beside an internal mask was read as a
    height (a -9999 m pit), and a transparent cell of a grey + alpha file that also names a nodata value as one.
    Each now marks its missing cells, as load_dem says (the file's nodata value, an internal mask or an alpha
    band)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.enums import ColorInterp

    nodata = 255 if dtype == np.uint8 else -9999
    z = (np.arange(20).reshape(4, 5) + 1).astype(dtype)
    z[0, 0] = nodata
    base = {"driver": "GTiff", "width": 5, "height": 4, "dtype": z.dtype.name, "crs": "EPSG:32611", "nodata": nodata,
            "transform": rasterio.Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)}
    with rasterio.open(tmp_path / "masked.tif", "w", count=1, **base) as ds:
        ds.write(z, 1)
        mask = np.full((4, 5), 255, np.uint8)
        mask[3, 3] = 0
        ds.write_mask(mask)  # an internal mask (.msk inside the file)
    with rasterio.open(tmp_path / "alpha.tif", "w", count=2, photometric="MINISBLACK", alpha="YES", **base) as ds:
        alpha = np.full((4, 5), 255, dtype)
        alpha[2, 1] = 0
        ds.write(np.stack([z, alpha]))
        ds.colorinterp = [ColorInterp.gray, ColorInterp.alpha]
    with rasterio.open(tmp_path / "alpha.tif") as ds:  # an alpha band GDAL's mask leaves out for the nodata value
        assert ds.colorinterp[1] == ColorInterp.alpha and ds.mask_flag_enums[0] == [rasterio.enums.MaskFlags.nodata]
    for name, hole in (("masked.tif", (3, 3)), ("alpha.tif", (2, 1))):
        t = load_dem(tmp_path / name)
        expected = z.astype(np.float32)
        expected[0, 0] = expected[hole] = np.nan
        np.testing.assert_array_equal(t.heights, expected)
        assert t.height_range == (2.0, 20.0)


def test_the_crs_of_a_grid_on_another_body_states_the_radius_its_metres_are_of(tmp_path):
    """49e81b3 made another body's degrees metres of its mean radius a·(1 - f/3), for Mars 3389526.666...; the crs
    wrote R to 10 digits (3389526.667) while the spacing used the unrounded radius, so the grid read back through its
    own crs (describe_dem, a texture's extent, PROJ) was off by 1e-10 of itself: lonlat_step 0.009999999999016579
    for 0.01, `stepterrain info --json` printing that. The metres are now of the radius the crs states."""
    from stepterrain.io import describe_dem

    crs = "+proj=longlat +a=3396190 +rf=169.894447223612 +no_defs"  # Mars 2000's ellipsoid
    t = load_dem(_geographic_tif(tmp_path / "mars.tif", crs, 10.0, 5.0, 0.01))
    stated = float(re.search(r"\+R=(\S+)", t.crs).group(1))
    assert stated != 3396190.0 * (1 - 1 / (3 * 169.894447223612))  # a radius with more digits than the crs holds
    assert abs(t.spacing[1]) == pytest.approx(stated * np.radians(0.01), rel=1e-15)
    info = describe_dem(t)
    assert info["lonlat_step"] == pytest.approx((0.01, -0.01), rel=1e-14)
    assert info["lonlat_extent"] == pytest.approx((10.005, 10.205, 4.895, 4.995), rel=1e-14)


def test_a_geographic_grid_on_a_west_positive_longitude_axis_is_placed_by_greenwich_east_degrees(tmp_path):
    """A geographic CRS whose longitude axis increases westwards (AXIS["Longitude",WEST], as planetographic CRSs
    such as IAU_2015:49901 have it) had its west longitudes read as east ones: the Front Range (105.8 W) stored
    east-right in such a CRS (x0 = 105.816 W, dx = -0.000833) was read at 105.8 E, mirrored (x spacing negative for
    columns that run east). It now reads as the same grid as the EPSG:4326 GeoTIFF: crs, spacing, lon/lat extent."""
    from stepterrain.io import describe_dem

    from .reference_texture import find_shared

    west = ('GEOGCS["WGS 84 west-positive",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
            'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AXIS["Latitude",NORTH],AXIS["Longitude",WEST]]')
    pytest.importorskip("rasterio")
    source = np.load(find_shared("front_range_srtmgl3_3arcsec.npz"))
    x0, dx, _, y0, _, dy = (float(v) for v in source["transform"])
    path = tmp_path / "front_range_west.npz"
    np.savez(path, elevation=source["elevation"], crs=west, transform=np.array([-x0, -dx, 0.0, y0, 0.0, dy]))
    t, reference = load_dem(path), load_dem(find_shared("front_range_srtmgl3_3arcsec.tif"))
    assert t.crs == reference.crs and t.spacing == pytest.approx(reference.spacing, rel=1e-12)
    assert describe_dem(t)["lonlat_extent"] == pytest.approx(describe_dem(reference)["lonlat_extent"], abs=1e-9)
    np.testing.assert_array_equal(t.heights, reference.heights)


def test_a_folder_given_as_a_dem_is_named_as_a_folder(tmp_path, capsys):
    """``load_dem('tiles')`` (and ``stepterrain steps tiles/``, ``info tiles``) said "unknown DEM extension '(none)'"
    of a folder: the extension was not the matter. It says the path is a folder now (exit 2 on the command line); a
    file without a known extension is refused as before."""
    from stepterrain import cli
    from stepterrain.errors import InvalidInputError

    folder = tmp_path / "tiles"
    folder.mkdir()
    with pytest.raises(DataFileError, match=r"^DEM path '.*tiles' is a folder; expected a DEM file \(\.npy, \.npz, "):
        load_dem(folder)
    assert cli.main(["info", str(folder)]) == 2
    assert f"stepterrain info: error: DEM path {str(folder)!r} is a folder; expected a DEM file" in \
        capsys.readouterr().err
    (tmp_path / "dem").write_bytes(b"")
    with pytest.raises(InvalidInputError, match=r"unknown DEM extension '\(none\)'"):
        load_dem(tmp_path / "dem")


def test_plain_tiffs_read_in_threads_at_once_leave_the_warning_filters_as_they_were(tmp_path, monkeypatch):
    """load_dem and ImagePyramid.build hid rasterio's NotGeoreferencedWarning of a plain TIFF with
    warnings.catch_warnings, which swaps the filters of the whole process and puts back the list it found: two
    threads reading at once (a service loading DEMs) left the "ignore" filter in the process for good, as the second
    put back the list holding the first's. Each open here takes 10 ms, so that the threads' opens overlap."""
    import threading
    import time

    rasterio = pytest.importorskip("rasterio")
    from stepterrain.texture_lod import ImagePyramid

    heights = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    dem, picture = tmp_path / "plain_dem.tif", tmp_path / "plain_picture.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # plain TIFFs, on purpose
        with rasterio.open(dem, "w", driver="GTiff", height=20, width=30, count=1, dtype="float32") as out:
            out.write(heights[None])
    pixels = (np.arange(16 * 24 * 3) % 251).astype(np.uint8).reshape(16, 24, 3)
    Image.fromarray(pixels).save(picture)
    real_open = rasterio.open

    def slow_open(*args, **kwargs):
        time.sleep(0.01)
        return real_open(*args, **kwargs)

    monkeypatch.setattr(rasterio, "open", slow_open)
    before = list(warnings.filters)
    read, errors = [], []
    start = threading.Barrier(4)

    def work(k):
        try:
            start.wait(10)
            for _ in range(6):
                if k % 2:
                    read.append(np.array_equal(load_dem(dem).heights, heights))
                else:
                    with ImagePyramid.build(picture, device="cpu") as pyramid:
                        read.append(np.array_equal(pyramid.levels[0], pixels))
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert not errors and read == [True] * 24
    assert warnings.filters == before


def test_a_tiff_georeferenced_by_a_world_file_takes_its_crs_from_the_prj_beside_it(tmp_path):
    """A TIFF with a world file (.tfw) and a .prj beside it, as ESRI software delivers a DEM: GDAL reads the world
    file's geotransform but not the .prj for a TIFF, so the grid had no CRS; one in degrees was read as metres (cells
    of 0.000833 m under 3000 m of relief: a needle mesh) and one in US survey feet kept feet as metres. The .prj is
    read as the texture's --image reads it beside an image; one that is no CRS is refused by name."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    z = (np.arange(12.0).reshape(3, 4) * 10 + 3000).astype(np.int16)

    def world_tiff(name, a, c, e, f, prj):
        path = tmp_path / name
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning for the bare TIFF
            with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=1, dtype="int16") as ds:
                ds.write(z, 1)
        # the world file's six lines: pixel size x, two rotation terms, pixel size y, centre of the top-left pixel
        path.with_suffix(".tfw").write_text(f"{a!r}\n0.0\n0.0\n{e!r}\n{c + a / 2!r}\n{f + e / 2!r}\n")
        if prj is not None:
            path.with_name(prj[0]).write_text(prj[1])
        return path

    degrees = world_tiff("front.tif", 1 / 1200, -105.8, -1 / 1200, 40.4, ("front.prj", CRS.from_epsg(4326).to_wkt()))
    t = load_dem(degrees)
    assert t.crs is not None and t.crs.startswith("+proj=eqc")
    assert t.spacing[0] == pytest.approx(70.6, abs=0.1) and t.spacing[1] == pytest.approx(-92.66, abs=0.01)
    assert "lon -105.799583333, lat 40.399583333" in t.source

    feet = world_tiff("site.tif", 100.0, 6.4e6, -100.0, 1.9e6, ("site.tif.prj", CRS.from_epsg(2229).to_wkt()))
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        t = load_dem(feet)
    assert t.crs == "EPSG:26945" and t.spacing == pytest.approx((30.480060960121925, -30.480060960121925))
    assert t.origin == pytest.approx((6400050.0 * 1200 / 3937, 1899950.0 * 1200 / 3937))

    bare = world_tiff("bare.tif", 30.0, 500000.0, -30.0, 4000000.0, None)  # no .prj: no CRS, as before
    t = load_dem(bare)
    assert t.crs is None and t.spacing == (30.0, -30.0) and t.origin == (500015.0, 3999985.0)

    broken = world_tiff("broken.tif", 30.0, 500000.0, -30.0, 4000000.0, ("broken.prj", "not a CRS"))
    with pytest.raises(DataFileError, match=r"broken\.prj' beside DEM '.*broken\.tif' is not a CRS"):
        load_dem(broken)


def test_an_upper_case_prj_beside_a_world_file_tiff_gives_its_crs(tmp_path):
    """DEM.TIF with DEM.TFW and DEM.PRJ (as DOS-era ESRI data ships, all upper case): GDAL reads the world file in
    either case, but load_dem looked for dem.prj / DEM.TIF.prj in lower case only, so the grid in degrees was read as
    metres (a needle of cells 0.000833 m wide), as was an image's (texture --image ORTHO.TIF). The .prj is now found
    in either case, as the world file is."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    from stepterrain.texture_lod import ImagePyramid

    z = (np.arange(12.0).reshape(3, 4) * 10 + 3000).astype(np.int16)
    path = tmp_path / "DEM.TIF"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning for the bare TIFF
        with rasterio.open(path, "w", driver="GTiff", width=4, height=3, count=1, dtype="int16") as ds:
            ds.write(z, 1)
    a, c, e, f = 1 / 1200, -105.8, -1 / 1200, 40.4
    (tmp_path / "DEM.TFW").write_text(f"{a!r}\n0.0\n0.0\n{e!r}\n{c + a / 2!r}\n{f + e / 2!r}\n")
    (tmp_path / "DEM.PRJ").write_text(CRS.from_epsg(4326).to_wkt())
    t = load_dem(path)
    assert t.crs is not None and t.crs.startswith("+proj=eqc")
    assert t.spacing[0] == pytest.approx(70.6, abs=0.1) and t.spacing[1] == pytest.approx(-92.66, abs=0.01)
    image = tmp_path / "ORTHO.TIF"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(image, "w", driver="GTiff", width=4, height=3, count=3, dtype="uint8") as ds:
            ds.write(np.zeros((3, 3, 4), np.uint8))
    (tmp_path / "ORTHO.TFW").write_text((tmp_path / "DEM.TFW").read_text())
    (tmp_path / "ORTHO.TIF.PRJ").write_text(CRS.from_epsg(4326).to_wkt())
    with ImagePyramid.build(image, device="cpu") as pyramid:
        assert pyramid.crs == "EPSG:4326"


def test_a_grid_in_degrees_without_a_crs_warns_that_it_was_read_as_metres(tmp_path):
    """A GeoTIFF whose CRS was lost (or a world file without its .prj) in degrees was read as metres without a word:
    the Front Range tile became a needle 0.06 m wide under 644 m of relief (the render then refused it as too thin).
    load_dem warns, naming the CRS to give it; a grid in metres without a CRS and a small one in one unit do not."""
    rasterio = pytest.importorskip("rasterio")

    def no_crs_tiff(name, z, a, c, e, f):
        path = tmp_path / name
        with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                           transform=rasterio.Affine(a, 0.0, c, 0.0, e, f)) as ds:  # fmt: skip
            ds.write(z.astype(np.float32), 1)
        return path

    with rasterio.open(SHARED_DATA / "front_range_srtmgl3_3arcsec.tif") as ds:
        z, t = ds.read(1, window=((0, 40), (0, 50))), ds.transform
    degrees = no_crs_tiff("front.tif", z, t.a, t.c, t.e, t.f)
    with pytest.warns(UserWarning, match=r"front\.tif: it names no CRS, so its coordinates were read as metres, but "
                                         r"they look like degrees: nodes at x -105\.81.*assign it: `gdal_edit\.py "
                                         r"-a_srs EPSG:4326 front\.tif`"):
        terrain = load_dem(degrees)
    assert terrain.crs is None and terrain.spacing == (t.a, t.e)  # read as before: the warning says what to do

    metres = no_crs_tiff("site.tif", z, 30.0, 1000.0, -30.0, 2000.0)  # a local grid in metres: 1470 m wide
    bench = no_crs_tiff("bench.tif", np.add.outer(np.arange(20.0), np.arange(30.0)) * 0.01, 0.01, 0.0, -0.01, 0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_dem(metres)
        load_dem(bench)  # a 0.3 m model with 0.48 m of relief, in metres near (0, 0)


def _window_flavours(tmp_path):
    """GeoTIFFs of every placement load_dem reads (the shared DEMs, north-up and south-up metres, degrees north-up
    and south-up far north, a CRS in feet with a scaled band, nodata by value and by alpha band, no geotransform),
    each with extents to crop (random boxes, boxes past the edges, on nodes, too small, nodata only, in degrees)."""
    rasterio = pytest.importorskip("rasterio")
    rng = np.random.default_rng(7)
    z = (rng.random((37, 53)) * 900.0 + 100.0).astype(np.float32)
    z[:9, :11] = -9999.0  # a corner of nodata: a crop there holds only nodata
    z[20, 30] = -9999.0

    def tiff(name, data, transform, crs, nodata=None, **extra):
        path = tmp_path / name
        count = 1 + ("alpha" in extra)
        with warnings.catch_warnings():  # plain.tif: "GDAL may ignore this matrix", as wanted (no geotransform)
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            dataset = rasterio.open(path, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=count,
                                    dtype=data.dtype, crs=crs, transform=transform, nodata=nodata)
        with dataset as ds:
            ds.write(data, 1)
            if "scales" in extra:
                ds.scales, ds.offsets, ds.units = extra["scales"], extra["offsets"], extra["units"]
            if "alpha" in extra:
                ds.write(extra["alpha"], 2)
                ds.colorinterp = [rasterio.enums.ColorInterp.gray, rasterio.enums.ColorInterp.alpha]
        return path

    affine = rasterio.Affine
    alpha = np.full(z.shape, 255, np.uint8)
    alpha[30:, 40:] = 0
    alpha[z == -9999.0] = 0  # its voids too: undeclared, they warn as a common nodata value (of the window read)
    files = [
        SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif",
        SHARED_DATA / "front_range_srtmgl3_3arcsec.tif",
        tiff("north.tif", z, affine(30.0, 0.0, 376000.0, 0.0, -30.0, 3808000.0), "EPSG:32611", -9999.0),
        tiff("south.tif", z, affine(30.0, 0.0, 376000.0, 0.0, 30.0, 3790000.0), "EPSG:32611", -9999.0),
        tiff("deg_north.tif", z, affine(0.01, 0.0, -105.5, 0.0, -0.01, 64.3), "EPSG:4326", -9999.0),
        tiff("deg_south.tif", z, affine(0.01, 0.0, 170.2, 0.0, 0.01, -70.4), "EPSG:4326", -9999.0),
        tiff("feet.tif", np.where(z < 0, 0, z * 10).astype(np.uint16), affine(100.0, 0.0, 6400000.0, 0.0, -100.0,
             1900000.0), "EPSG:2229", 0, scales=[0.1], offsets=[-5.0], units=["ft"]),
        tiff("alpha.tif", z, affine(30.0, 0.0, 376000.0, 0.0, -30.0, 3808000.0), "EPSG:32611", None, alpha=alpha),
        tiff("plain.tif", z, affine(1.0, 0.0, 0.0, 0.0, 1.0, 0.0), None, -9999.0),
    ]
    for path in files:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            whole = load_dem(path)
        x0, x1, y0, y1 = whole.extent
        (dx, dy), (ox, oy) = whole.spacing, whole.origin
        extents = [tuple(sorted(rng.uniform(x0, x1, 2))) + tuple(sorted(rng.uniform(y0, y1, 2))) for _ in range(6)]
        extents += [
            (x0 - 1e6, x1 + 1e6, y0 - 1e6, y1 + 1e6),  # the whole grid
            (ox + 3 * dx, ox + 7 * dx, oy + 2 * dy, oy + 5 * dy)[:2] + tuple(sorted((oy + 2 * dy, oy + 5 * dy))),
            (x0, x0 + 0.5 * abs(dx), y0, y1),  # one column: refused
            (x1 + 10 * abs(dx), x1 + 20 * abs(dx), y0, y1),  # off the grid: refused
        ]
        if path.name in ("north.tif", "deg_north.tif"):  # the nodata corner: refused
            extents.append((ox, ox + 8 * dx, oy + 6 * dy, oy))
        if path.name == "deg_north.tif":  # in degrees: refused naming its metres
            extents.append((-105.4, -105.2, 64.0, 64.2))
        yield path, whole, extents


def test_load_dem_crop_reads_the_window_that_terrain_crop_keeps(tmp_path):
    """--crop (and Terrain.crop after load_dem) read the whole GeoTIFF first, so a file over the memory budget was
    refused even for a small crop of it. load_dem(path, crop=extent) places the whole grid from the header and reads
    only the window: the same Terrain as load_dem(path).crop(extent) (heights, nodata, spacing, origin, crs, source,
    height unit; a degrees DEM's local metres of its whole grid), the same warnings, and the same refusals after
    'crop: ', for GeoTIFFs of every placement; other formats are read whole and cropped."""
    from stepterrain.errors import InvalidInputError

    def outcome(call):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                result = call()
            except InvalidInputError as exc:
                result = exc
        return result, [str(w.message) for w in caught]

    checked = refused = 0
    for path, whole, extents in _window_flavours(tmp_path):
        for extent in extents:
            expected, said = outcome(lambda: load_dem(path).crop(extent))  # noqa: B023
            got, told = outcome(lambda: load_dem(path, crop=extent))  # noqa: B023
            assert told == said, (path.name, extent)
            if isinstance(expected, Exception):
                assert isinstance(got, InvalidInputError) and str(got) == f"crop: {expected}", (path.name, extent)
                refused += 1
                continue
            assert not isinstance(got, Exception), (path.name, extent, got)
            assert got.shape == expected.shape and (got.shape != whole.shape or extent[1] - extent[0] > 1e6)
            np.testing.assert_array_equal(got.heights, expected.heights)
            assert (got.spacing, got.origin, got.crs, got.source, got.height_unit) == \
                (expected.spacing, expected.origin, expected.crs, expected.source, expected.height_unit)
            assert got.has_nodata == expected.has_nodata and got.height_range == expected.height_range
            checked += 1
    assert checked >= 50 and refused >= 15
    np.save(tmp_path / "plain.npy", whole.heights)
    t = load_dem(tmp_path / "plain.npy", crop=(3.0, 9.0, -12.0, -4.0))  # other formats: read whole, cropped
    assert t.shape == (9, 7) and t.origin == (3.0, -4.0)
    with pytest.raises(InvalidInputError, match=r"^crop: extent \(3\.0, 3\.5, -12\.0, -4\.0\) .* holds 9 x 1 nodes"):
        load_dem(tmp_path / "plain.npy", crop=(3.0, 3.5, -12.0, -4.0))


def test_load_dem_crop_checks_only_the_window_against_the_memory_budget(tmp_path):
    """A GeoTIFF over the memory budget was refused (pointing at gdal_translate) even when only a small crop of it
    was wanted: load_dem read it whole, then cropped. Its crop's window is now what is checked and read: a budget
    under the whole file's bytes and over the window's reads the crop, the same nodes as the whole read's crop; a
    window over the budget is refused naming its rows and columns."""
    import stepterrain as st
    from stepterrain.errors import OutputTooLargeError

    path = SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif"  # 643 x 1197 float32 or int16: over 1.5 MB as float32
    whole = load_dem(path)
    (x0, _, _, y1), (dx, dy) = whole.extent, whole.spacing
    extent = (x0 + 100 * dx, x0 + 199 * dx, y1 + 299 * dy, y1 + 200 * dy)  # 100 x 100 nodes: 40,000 bytes
    expected = whole.crop(extent)
    assert expected.shape == (100, 100)
    previous = st.set_memory_budget(100_000)
    try:
        with pytest.raises(OutputTooLargeError, match=r"the raster: 643 x 1197 cells .* crop or coarsen it first "
                                                      r"\(crop= \(the CLI's --crop\) reads only the crop's "
                                                      r"window"):
            load_dem(path)
        got = load_dem(path, crop=extent)
        np.testing.assert_array_equal(got.heights, expected.heights)
        assert (got.spacing, got.origin, got.crs, got.source) == (expected.spacing, expected.origin, expected.crs,
                                                                  expected.source)
        st.set_memory_budget(39_999)
        with pytest.raises(OutputTooLargeError, match=r"\(rows 200-299, columns 100-199 of its 643 x 1197, the crop's: "
                                                      r"100 x 100 cells of .*\) would need 40,000 bytes.*make the crop "
                                                      r"smaller"):
            load_dem(path, crop=extent)
    finally:
        st.set_memory_budget(previous)


def test_an_npz_mask_of_a_masked_array_with_no_cell_masked_reads_every_cell(tmp_path):
    """np.savez(..., elevation=m.data, mask=m.mask), the recipe load_dem's docstring gives, was refused for a masked
    array with no cell masked ("'mask' must be a boolean array of the heights' shape (3, 4) ...; got bool of shape
    ()"): NumPy then keeps m.mask as nomask, np.False_, saved as a 0-d False (np.ma.masked_equal(z, -9999) of a tile
    without voids). A 0-d mask or valid applies to every cell, of a grid and of a series, beside a full one too."""
    from stepterrain.batch import load_series

    z = np.arange(12.0, dtype=np.float32).reshape(3, 4)
    clean = np.ma.masked_equal(z, -9999.0)
    assert clean.mask.shape == ()  # NumPy's nomask: the case at hand
    transform = np.array([500000.0, 30.0, 0.0, 4000000.0, 0.0, -30.0])
    np.savez(tmp_path / "clean.npz", elevation=clean.data, mask=clean.mask, transform=transform, crs="EPSG:32611")
    np.savez(tmp_path / "plain.npz", elevation=clean.data, mask=clean.mask)
    np.savez(tmp_path / "valid.npz", elevation=clean.data, valid=np.True_)
    for name in ("clean.npz", "plain.npz", "valid.npz"):
        np.testing.assert_array_equal(load_dem(tmp_path / name).heights, z, err_msg=name)
    holes = np.eye(3, 4, dtype=bool)
    np.savez(tmp_path / "both.npz", elevation=z, mask=holes, valid=np.True_)  # the full mask still marks its cells
    np.testing.assert_array_equal(np.isnan(load_dem(tmp_path / "both.npz").heights), holes)
    np.savez(tmp_path / "none.npz", elevation=z, valid=np.False_)  # a 0-d "no cell valid": all nodata, refused
    with pytest.raises(DataFileError, match=r"none\.npz.*all nodata"):
        load_dem(tmp_path / "none.npz")
    series = np.ma.masked_equal(np.stack([z, z + 1.0]), -9999.0)
    np.savez(tmp_path / "series.npz", heights=series.data, mask=series.mask)
    np.testing.assert_array_equal(load_series(tmp_path / "series.npz"), series.data)


def test_a_png_heightmaps_world_file_or_aux_xml_georeferencing_is_named_not_dropped_silently(tmp_path):
    """A 16-bit PNG heightmap exported by a GIS with its world file (dem.pgw, as GDAL and QGIS write it) or a
    geotransform in dem.png.aux.xml was read as 1 m cells at (0, 0) without a word: a 30 m DEM meshed 30 times too
    steep, far from its place (the texture readers place such a PNG by its world file). load_dem still reads it
    unreferenced, as documented, but warns at the caller, naming the file not read and the gdal_translate (with
    the .prj's CRS) that makes it a GeoTIFF placed by it; a PNG without one does not warn."""
    z = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 100)
    Image.fromarray(z).save(tmp_path / "dem.png")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plain = load_dem(tmp_path / "dem.png")
    (tmp_path / "dem.pgw").write_text("30\n0\n0\n-30\n500015\n3999985\n")
    (tmp_path / "dem.prj").write_text('PROJCS["WGS 84 / UTM zone 11N"]')
    told = (r"dem\.png: its georeferencing in dem\.pgw is not read: .*spacing \(1, -1\) and origin \(0, 0\).*"
            r"`gdal_translate -a_srs dem\.prj dem\.png dem\.tif`")
    with pytest.warns(UserWarning, match=told) as got:
        t = load_dem(tmp_path / "dem.png")
    assert got[0].filename == __file__  # at the caller's line
    assert t.spacing == plain.spacing == (1.0, -1.0) and t.origin == (0.0, 0.0)
    np.testing.assert_array_equal(t.heights, z.astype(np.float32))
    (tmp_path / "dem.prj").rename(tmp_path / "dem.png.prj")  # as prj_crs reads it too: named in the command
    with pytest.warns(UserWarning, match=r"`gdal_translate -a_srs dem\.png\.prj dem\.png dem\.tif`"):
        load_dem(tmp_path / "dem.png")
    (tmp_path / "dem.pgw").unlink()
    (tmp_path / "dem.png.prj").unlink()
    (tmp_path / "dem.png.aux.xml").write_text("<PAMDataset>\n  <GeoTransform> 5.0e+05, 3.0e+01, 0.0, 4.0e+06, 0.0, "
                                              "-3.0e+01</GeoTransform>\n</PAMDataset>\n")
    with pytest.warns(UserWarning, match=r"its georeferencing in dem\.png\.aux\.xml is not read.*"
                                         r"`gdal_translate dem\.png dem\.tif`"):
        load_dem(tmp_path / "dem.png")
    (tmp_path / "dem.png.aux.xml").write_text("<PAMDataset>\n  <Metadata/>\n</PAMDataset>\n")  # no geotransform
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_dem(tmp_path / "dem.png")


def test_an_npz_scale_or_offset_of_the_heights_is_refused_not_ignored(tmp_path):
    """np.savez(..., elevation=src.read(1), scale=src.scales[0], offset=src.offsets[0]) of an int16 GeoTIFF of
    decimetres (or CF's scale_factor/add_offset, as xarray encodes them) was read as stored: heights 10 times too
    high, the offset lost, without a word. A scale other than 1 or an offset other than 0 is refused now, by load_dem
    and load_series, naming them and how to save the heights scaled; 1 and 0 (no scaling) and text read as before."""
    from stepterrain.batch import load_series

    z = np.array([[10234, 10250, 10300], [10111, 10090, 10020], [9990, 9900, 9850]], np.int16)  # decimetres
    transform = np.array([500000.0, 30.0, 0.0, 4000000.0, 0.0, -30.0])
    for name, extra, got in (
        ("scale.npz", {"scale": 0.1, "transform": transform, "crs": "EPSG:32611"}, "scale=0.1"),
        ("cf.npz", {"scale_factor": np.float32(0.5), "add_offset": [100.0]}, "scale_factor=0.5, add_offset=100"),
        ("offset.npz", {"offsets": np.array([-500.0]), "scales": np.array([1.0])}, "offsets=-500"),
    ):
        np.savez(tmp_path / name, elevation=z, **extra)
        with pytest.raises(DataFileError, match=rf"{name}.*beside 'elevation'; got {got}, a scale of the stored "
                                                r"values \(height = value \* scale \+ offset\) that load_dem does not "
                                                r"read.*z \* scale \+ offset"):
            load_dem(tmp_path / name)
    np.savez(tmp_path / "series.npz", heights=np.stack([z, z]), scale_factor=0.1)
    with pytest.raises(DataFileError, match=r"series\.npz.*got scale_factor=0\.1"):
        load_series(tmp_path / "series.npz")
    np.savez(tmp_path / "identity.npz", elevation=z, scale=1.0, offset=0, scale_factor="1:24000")
    np.testing.assert_array_equal(load_dem(tmp_path / "identity.npz").heights, z.astype(np.float32))


def test_the_lowest_value_of_a_signed_or_float_dtype_unmarked_by_nodata_is_named_as_a_likely_void(tmp_path):
    """An int16 DEM whose nodata tag was lost (SRTM voids are -32768) or a float32 one holding ArcGIS's NoData
    -3.4028235e+38 without declaring it was read as heights without a word: a pit 33 km deep in the mesh, or
    stepped's "3.4e+37 levels" refusal naming no void. They are still read as stored (as GDAL reads them), but
    load_dem warns at the caller, counting the cells and naming the nodata value to declare; cells a nodata value or
    mask marks, other dtypes' extremes (a 16-bit PNG's 65535 peak) and a crop's window without them do not warn."""
    import rasterio
    from rasterio.transform import Affine

    def geotiff(name, z, **profile):
        with rasterio.open(tmp_path / name, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1,
                           dtype=z.dtype, crs="EPSG:32611", transform=Affine(30.0, 0.0, 500000.0, 0.0, -30.0,
                                                                             4000000.0), **profile) as dataset:
            dataset.write(z, 1)
        return tmp_path / name

    def told(path, **kwargs):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            terrain = load_dem(path, **kwargs)
        return terrain, [str(w.message) for w in caught if "marks voids" in str(w.message)], caught

    z = np.add.outer(np.arange(5), np.arange(6)).astype(np.int16) * 10 + 1000
    z[1, 2] = z[3, 4] = -32768
    terrain, messages, caught = told(geotiff("voids.tif", z))
    assert messages == ["voids.tif: 2 cells of band 1 hold -32768, the lowest int16 value, which marks voids, but no "
                        "nodata value or mask of the file marks them: read as heights; if they are voids, declare it "
                        "(`gdal_edit.py -a_nodata -32768 voids.tif`, or pass nodata=-32768)"]
    assert caught[0].filename == __file__
    np.testing.assert_array_equal(terrain.heights, z.astype(np.float32))  # read as stored, as documented
    assert told(geotiff("window.tif", z), crop=(500000, 500050, 3999900, 4000000))[1] == []  # a window without them
    assert len(told(tmp_path / "window.tif", crop=(500000, 500100, 3999900, 4000000))[1]) == 1  # with one
    terrain, messages, _ = told(geotiff("declared.tif", z, nodata=-32768))
    assert messages == [] and np.isnan(terrain.heights).sum() == 2
    f = z.astype(np.float32)
    f[1, 2] = f[3, 4] = np.finfo(np.float32).min
    assert told(geotiff("arcgis.tif", f, nodata=float(np.finfo(np.float32).min)))[1] == []
    # a float band warned twice: on the values as stored, and again when its heights passed through nodata_as_nan
    terrain, messages, _ = told(geotiff("undeclared.tif", f))
    assert messages == ["undeclared.tif: 2 cells of band 1 hold -3.4028235e+38, the lowest float32 value, which marks "
                        "voids, but no nodata value or mask of the file marks them: read as heights; if they are "
                        "voids, declare it (`gdal_edit.py -a_nodata -3.4028235e+38 undeclared.tif`, or pass "
                        "nodata=-3.4028235e+38)"]
    np.testing.assert_array_equal(terrain.heights, f)
    np.save(tmp_path / "lowest.npy", f)
    assert told(tmp_path / "lowest.npy")[1] == [
        "lowest.npy: 2 cells of array hold -3.4028235e+38, the lowest float32 value, which marks voids, but no nodata "
        "value or mask of the file marks them: read as heights; if they are voids, declare it (save it as an .npz with "
        "a 'nodata' of -3.4028235e+38, or pass nodata=-3.4028235e+38)"]
    np.savez(tmp_path / "other.npz", elevation=z, nodata=-9999)  # another nodata value: the -32768 cells unmarked
    assert told(tmp_path / "other.npz")[1][0].endswith(
        "(save a 'nodata' of -32768 beside the heights, or pass nodata=-32768)")
    np.savez(tmp_path / "masked.npz", elevation=z, mask=z == -32768)
    assert told(tmp_path / "masked.npz")[1] == []
    Image.fromarray(np.where(z < 0, 65535, z).astype(np.uint16)).save(tmp_path / "peak.png")
    assert told(tmp_path / "peak.png")[1] == []


def test_float32_nodata_kept_in_a_float64_grid_is_named_as_a_likely_void(tmp_path):
    """A float32 DEM's NoData (-3.4028235e+38, ArcGIS's) kept through a widening copy (``src.read(1).astype(float)``
    saved as .npy, ``gdal_translate -ot Float64``) was read as heights without a word: float64's own lowest value,
    the only one checked, lies beyond float32 and is refused anyway. Its cells were a pit of 3.4e38 m (with explicit
    levels, a terrace silently flattened onto the lowest one). Now they warn as in a float32 grid, naming the value
    in full: a float64 cell equals only that, so the nodata the hint gives marks them when declared."""
    import rasterio
    from rasterio.transform import Affine

    real = np.load(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz")["elevation"][:40, :50].astype(np.float64)
    z = np.where(real > np.percentile(real, 95), float(np.finfo(np.float32).min), real)
    n_voids = int((z < -1e38).sum())
    assert n_voids > 0
    np.save(tmp_path / "wide.npy", z)
    with rasterio.open(tmp_path / "wide.tif", "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1,
                       dtype="float64", crs="EPSG:32611",
                       transform=Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)) as dataset:
        dataset.write(z, 1)
    value = "-3.4028234663852886e+38"
    for name, what, hint in (
        ("wide.npy", "array", f"save it as an .npz with a 'nodata' of {value}"),
        ("wide.tif", "band 1", f"`gdal_edit.py -a_nodata {value} wide.tif`"),
    ):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            terrain = load_dem(tmp_path / name)
        assert [str(w.message) for w in caught if "marks voids" in str(w.message)] == [
            f"{name}: {n_voids} cells of {what} hold {value}, the lowest float32 value (stored as float64), which "
            f"marks voids, but no nodata value or mask of the file marks them: read as heights; if they are voids, "
            f"declare it ({hint}, or pass nodata={value})"]
        np.testing.assert_array_equal(terrain.heights, z.astype(np.float32))  # still read as stored
    # the value named marks exactly those cells once declared, as the hint says
    np.savez(tmp_path / "declared.npz", elevation=z, nodata=float(value))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        declared = load_dem(tmp_path / "declared.npz")
    assert [w for w in caught if "marks voids" in str(w.message)] == []
    np.testing.assert_array_equal(np.isnan(declared.heights), z < -1e38)


@pytest.mark.parametrize("sentinel", [-np.finfo(np.float64).max, np.finfo(np.float64).max])
def test_float64_nodata_beyond_float32_undeclared_is_refused_naming_the_void_and_the_fix(tmp_path, capsys, sentinel):
    """A Float64 GeoTIFF whose voids hold float64's lowest value (-1.7976931348623157e+308, the nodata GDAL and
    ArcGIS give a Float64 raster by default) without declaring it was refused as "band 1 holds heights beyond
    float32 ...; got -1.7976931348623157e+308 at index (i, j)": no word of a void, how many cells, nor how to mark
    them. The refusal (load_dem, and `stepterrain info` and `steps`, which read through it) now counts the cells
    and gives the nodata to declare, in full; declared as it says, the file reads with those cells as nodata and
    every other height as stored."""
    import rasterio

    from stepterrain import cli

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as source:
        real = source.read(1)[:60, :80].astype(np.float64)
        profile = {**source.profile, "width": 80, "height": 60, "dtype": "float64", "nodata": None}
    voids = real > np.percentile(real, 97)
    z = np.where(voids, sentinel, real)
    path = tmp_path / "voids.tif"
    with rasterio.open(path, "w", **profile) as dataset:
        dataset.write(z, 1)
    value = repr(float(sentinel))
    extreme = "lowest" if sentinel < 0 else "highest"
    told = (f"in {int(voids.sum())} cells: the {extreme} float64 value, which marks voids, but no nodata value or "
            f"mask of the file marks them; if they are voids, declare it (`gdal_edit.py -a_nodata {value} voids.tif`, "
            f"or pass ")
    with pytest.raises(DataFileError, match=r"band 1 holds heights beyond float32") as caught:
        load_dem(path)
    i, j = np.argwhere(voids)[0]
    assert str(caught.value).endswith(f"; got {value} at index ({i}, {j}), {told}nodata={value})")
    for command in ("info", "steps"):
        code = cli.main([command, str(path), "-o", str(tmp_path / "out.ply")][: 2 if command == "info" else 4])
        err = capsys.readouterr().err
        assert code == 2 and err.rstrip().endswith(f"{told}--nodata {value})") and "Traceback" not in err
    assert not (tmp_path / "out.ply").exists()
    np.save(tmp_path / "voids.npy", z)
    with pytest.raises(DataFileError,
                       match=re.escape(f"(save it as an .npz with a 'nodata' of {value}, or pass nodata={value})")):
        load_dem(tmp_path / "voids.npy")
    with rasterio.open(path, "r+") as dataset:  # as the hint's gdal_edit.py does
        dataset.nodata = float(value)
    declared = load_dem(path)
    np.testing.assert_array_equal(np.isnan(declared.heights), voids)
    np.testing.assert_array_equal(declared.heights[~voids], real[~voids].astype(np.float32))


def test_the_highest_float32_value_undeclared_warns_as_the_lowest_does(tmp_path, capsys):
    """A float32 DEM whose voids hold +3.4028235e+38 (FLT_MAX, no height in any unit) without declaring it was read
    as heights without a word (the lowest value warned): `stepterrain steps` then refused "the round interval
    2.5e+37 picked for heights 315 to 3.40282e+38" naming no void, and explicit levels stepped a tower 3.4e38 m
    tall. It warns now as the lowest value does, in a float64 copy too (the value in full), and `stepterrain info`
    still describes the file after the warning; declared as the hint says, the cells are nodata."""
    import rasterio

    from stepterrain import cli

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as source:
        real = source.read(1)[:60, :80].astype(np.float32)
        profile = {**source.profile, "width": 80, "height": 60, "dtype": "float32", "nodata": None}
    voids = real > np.percentile(real, 97)
    top = np.finfo(np.float32).max
    z = np.where(voids, top, real)
    path = tmp_path / "top.tif"
    with rasterio.open(path, "w", **profile) as dataset:
        dataset.write(z, 1)
    n = int(voids.sum())

    def told(file):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            terrain = load_dem(file)
        return terrain, [str(w.message) for w in caught if "marks voids" in str(w.message)]

    terrain, messages = told(path)
    assert messages == [f"top.tif: {n} cells of band 1 hold 3.4028235e+38, the highest float32 value, which marks "
                        "voids, but no nodata value or mask of the file marks them: read as heights; if they are "
                        "voids, declare it (`gdal_edit.py -a_nodata 3.4028235e+38 top.tif`, or pass "
                        "nodata=3.4028235e+38)"]
    np.testing.assert_array_equal(terrain.heights, z)  # still read as stored
    np.save(tmp_path / "wide.npy", z.astype(np.float64))
    assert told(tmp_path / "wide.npy")[1] == [
        f"wide.npy: {n} cells of array hold 3.4028234663852886e+38, the highest float32 value (stored as float64), "
        "which marks voids, but no nodata value or mask of the file marks them: read as heights; if they are voids, "
        "declare it (save it as an .npz with a 'nodata' of 3.4028234663852886e+38, or pass "
        "nodata=3.4028234663852886e+38)"]
    assert cli.main(["info", str(path)]) == 0
    out, err = capsys.readouterr()
    assert "the highest float32 value" in err and "height_range" in out and "nodata_count      0" in out
    with rasterio.open(path, "r+") as dataset:  # as the hint's gdal_edit.py does
        dataset.nodata = float("3.4028235e+38")
    declared, messages = told(path)
    assert messages == []
    np.testing.assert_array_equal(np.isnan(declared.heights), voids)
    np.testing.assert_array_equal(declared.heights[~voids], real[~voids])
    assert told(tmp_path / "wide.npy")[0].heights.max() == np.float32(top)  # unchanged: only warned


def test_a_lone_value_beyond_float32_is_refused_without_a_void_hint(tmp_path):
    """A single odd value beyond float32 (not float64's extreme) is no void marker: refused as before, no hint;
    repeated, it is named as one."""
    z = np.full((3, 4), 100.0)
    z[1, 2] = 1e39
    np.save(tmp_path / "big.npy", z)
    with pytest.raises(DataFileError, match=r"got 1e\+39 at index \(1, 2\)$"):
        load_dem(tmp_path / "big.npy")
    z[2, 3] = 1e39
    z[2, 0] = -5e39
    np.savez(tmp_path / "big.npz", elevation=z)
    with pytest.raises(DataFileError, match=re.escape(
            "got 1e+39 at index (1, 2), in 2 cells (and 1 other cell beyond float32): one value repeated beyond "
            "float32, no height: a mark of voids, but no nodata value or mask of the file marks them; if they "
            "are voids, declare it (save a 'nodata' of 1e+39 beside the heights, or pass nodata=1e+39)")):
        load_dem(tmp_path / "big.npz")


@pytest.mark.skipif(np.finfo(np.longdouble).max <= np.finfo(np.float64).max, reason="no extended long double")
def test_a_long_double_value_beyond_float64_gets_no_nodata_hint_of_inf(tmp_path):
    """A repeated float128 value beyond float64 is no nodata a GeoTIFF or an .npz of float64 can hold: written as a
    float it is inf, and the hint said to declare a 'nodata' of inf, which matches no cell. Refused without one."""
    z = np.full((3, 4), 100, dtype=np.longdouble)
    z[0, :2] = np.longdouble("1e400")
    np.save(tmp_path / "wide.npy", z)
    with pytest.raises(DataFileError, match=r"beyond float32 .*at index \(0, 0\)$"):
        load_dem(tmp_path / "wide.npy")


def test_undeclared_void_hint_through_a_gdal_virtual_path_translates_rather_than_edits_in_place(tmp_path):
    """A DEM read through /vsigzip/ (a local dem.tif.gz), /vsizip/ (a local zip or its /vsizip/ path) holding
    undeclared voids was told `gdal_edit.py -a_nodata ... dem.tif`: there is no dem.tif to edit, and gdal_edit.py
    cannot write inside a .gz or a zip. The hint now gives the gdal_translate that writes a GeoTIFF declaring it,
    from the path GDAL reads; run as told, the new file reads with the voids as nodata."""
    import gzip
    import shlex
    import shutil
    import zipfile

    import rasterio

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as source:
        real = source.read(1)[:30, :40].astype(np.float64)
        profile = {**source.profile, "width": 40, "height": 30, "nodata": None}
    voids = real > np.percentile(real, 95)
    for dtype, sentinel in (("float64", -np.finfo(np.float64).max), ("float32", np.finfo(np.float32).max)):
        folder = tmp_path / dtype
        folder.mkdir()
        tif = folder / "dem.tif"
        with rasterio.open(tif, "w", **{**profile, "dtype": dtype}) as dataset:
            dataset.write(np.where(voids, sentinel, real).astype(dtype), 1)
        with open(tif, "rb") as raw, gzip.open(folder / "dem.tif.gz", "wb") as packed:
            shutil.copyfileobj(raw, packed)
        with zipfile.ZipFile(folder / "dem.zip", "w") as archive:
            archive.write(tif, "dem.tif")
        tif.unlink()
        for given in (folder / "dem.tif.gz", folder / "dem.zip", f"/vsizip/{folder}/dem.zip/dem.tif"):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    load_dem(given)
                    message = next(str(w.message) for w in caught if "marks voids" in str(w.message))
                except DataFileError as exc:
                    message = str(exc)
            hint = re.search(r"declare it \(`([^`]*)`", message)
            assert hint and hint.group(1).startswith("gdal_translate -a_nodata "), message
            words = shlex.split(hint.group(1))
            assert words[-1] == "dem.tif" and words[-2].startswith(("/vsigzip/", "/vsizip/")), message
            with rasterio.open(words[-2]) as src:  # as gdal_translate -a_nodata does
                out = folder / words[-1]
                with rasterio.open(out, "w", **{**src.profile, "nodata": float(words[2])}) as dst:
                    dst.write(src.read(1), 1)
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                declared = load_dem(out)
            np.testing.assert_array_equal(np.isnan(declared.heights), voids)
            out.unlink()


def test_undeclared_float64_void_under_a_band_scale_is_named_by_its_stored_value(tmp_path):
    """A scaled Float64 GeoTIFF (scale 0.1) holding float64's lowest value undeclared was refused naming the scaled
    value, -1.7976931348623158e+307, as "one value repeated" and the nodata to declare: GDAL compares nodata with the
    stored values, so declaring it matched no cell. The stored value is named (float64's lowest) and declaring it
    as told reads the voids as nodata."""
    import rasterio

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as source:
        real = source.read(1)[:30, :40].astype(np.float64)
        profile = {**source.profile, "width": 40, "height": 30, "dtype": "float64", "nodata": None}
    voids = real > np.percentile(real, 95)
    path = tmp_path / "scaled.tif"
    with rasterio.open(path, "w", **profile) as dataset:
        dataset.write(np.where(voids, -np.finfo(np.float64).max, real * 10), 1)
        dataset.scales = (0.1,)
    value = repr(float(-np.finfo(np.float64).max))
    with pytest.raises(DataFileError, match=re.escape(
            f"in {int(voids.sum())} cells: the lowest float64 value as stored, which marks voids, but no nodata value "
            f"or mask of the file marks them; if they are voids, declare it (`gdal_edit.py -a_nodata {value} "
            f"scaled.tif`, or pass nodata={value})")):
        load_dem(path)
    with rasterio.open(path, "r+") as dataset:
        dataset.nodata = float(value)
    declared = load_dem(path)
    np.testing.assert_array_equal(np.isnan(declared.heights), voids)
    np.testing.assert_allclose(declared.heights[~voids], real[~voids], rtol=1e-6)


@pytest.mark.parametrize(
    ("dx_m", "dy_m", "message"),
    [(0.0, 1111.0, r"'dx_m' and 'dy_m' must be finite, non-zero metres per cell; got 0\.0 and 1111\.0"),
     (float("nan"), 1111.0, r"'dx_m' and 'dy_m' must be finite, non-zero metres per cell; got nan and 1111\.0"),
     (785.0, float("inf"), r"'dx_m' and 'dy_m' must be finite, non-zero metres per cell; got 785\.0 and inf"),
     (785.0, None, r"both 'dx_m' and 'dy_m'.*got 'dx_m' without 'dy_m'"),
     (None, 1111.0, r"both 'dx_m' and 'dy_m'.*got 'dy_m' without 'dx_m'")],
)  # fmt: skip
def test_npz_dx_m_dy_m_that_are_no_metres_are_refused_by_name(tmp_path, dx_m, dy_m, message):
    """An .npz in degrees with dx_m = 0, NaN or inf warned that its metres erred "by up to 100 %" ("nan %", or that
    NaN gave "more metres per degree of longitude than of latitude") and then failed on "spacing must be non-zero"
    or "a pair of finite numbers", naming a spacing the file does not hold; one of dx_m, dy_m without the other was
    ignored without a word (the grid's metres then came from R and the degrees). Now a DataFileError names the keys,
    before any warning."""
    z = np.arange(231.0, dtype=np.float32).reshape(11, 21)
    transform = np.array([10.0, 0.01, 0.0, 45.0, 0.0, -0.01])
    keys = {name: value for name, value in (("dx_m", dx_m), ("dy_m", dy_m)) if value is not None}
    np.savez(tmp_path / "m.npz", elevation=z, transform=transform, crs="EPSG:4326", **keys)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(DataFileError, match=r"m\.npz.*" + message):
            load_dem(tmp_path / "m.npz")
    assert [str(w.message) for w in caught] == []


def test_a_truncated_npz_leaves_no_file_open(tmp_path):
    """A truncated .npz (a copy cut short: the zip's central directory lost) was refused, but np.load, which opens
    the file itself, left it open when zipfile failed on it: a ResourceWarning per file, and a handle held until the
    garbage collector found it (a batch over a folder of damaged downloads). The file is opened and closed here."""
    import gc

    np.savez(tmp_path / "whole.npz", elevation=np.arange(2000.0).reshape(40, 50))
    data = (tmp_path / "whole.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(DataFileError, match=r"cut\.npz.*expected a NumPy \.npz archive; got unreadable content"):
            load_dem(tmp_path / "cut.npz")
        gc.collect()
    assert [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)] == []


@pytest.mark.parametrize(("scale", "offset"), [(0.0, 0.0), (0.0, 250.0), (float("nan"), 0.0), (0.1, float("nan")),
                                               (float("inf"), 0.0), (1.0, float("-inf"))])  # fmt: skip
def test_a_geotiff_scale_of_zero_or_not_finite_is_refused_naming_it(tmp_path, scale, offset):
    """A band whose scale is 0 (a producer's placeholder) read every cell as the offset: a flat terrain at 0 m (or
    250 m), silently, its relief lost; a NaN or infinite scale or offset made every height NaN and was refused as
    "all nodata", which the file is not. Now a DataFileError names the band's scale and offset."""
    rasterio = pytest.importorskip("rasterio")

    z = (np.arange(20, dtype=np.int16) * 7).reshape(4, 5)
    path = tmp_path / "scaled.tif"
    with rasterio.open(path, "w", driver="GTiff", height=4, width=5, count=1, dtype="int16", crs="EPSG:32611",
                       transform=rasterio.Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)) as ds:  # fmt: skip
        ds.write(z, 1)
        ds.scales, ds.offsets = (scale,), (offset,)
    message = (r"scaled\.tif.*expected band 1's scale and offset \(height = value \* scale \+ offset\) to be a finite, "
               rf"non-zero scale and a finite offset; got scale {scale!r}, offset {offset!r}")
    with pytest.raises(DataFileError, match=message):
        load_dem(path)
    with pytest.raises(DataFileError, match=message):  # the window of a crop too
        load_dem(path, crop=(500015.0, 500075.0, 3999900.0, 3999985.0))


@pytest.mark.parametrize("crs", ["4326", "EPSG:99999", "WGS 84 lon/lat"])
def test_a_grid_in_degrees_under_a_crs_proj_cannot_read_warns_as_one_without_a_crs(tmp_path, crs):
    """An .npz in degrees saved with a CRS that PROJ cannot read (crs="4326", an EPSG code that does not exist, a
    free-text name) was read as metres with its CRS kept, without a word: a needle a few centimetres wide under
    hundreds of metres of relief, as a grid with no CRS at all was before it warned. An unreadable CRS says no more
    than none, so it warns the same, naming the CRS; a readable projected one does not."""
    pytest.importorskip("rasterio")
    with np.load(SHARED_DATA / "front_range_srtmgl3_3arcsec.npz") as data:
        z, transform = data["elevation"][:40, :50], data["transform"]
    np.savez(tmp_path / "front.npz", elevation=z, transform=transform, crs=crs)
    message = (rf"front\.npz: its CRS {re.escape(repr(crs))} is not one PROJ can read, so its coordinates were read as "
               r"metres, but they look like degrees: nodes at x -105\.81.*give the file its CRS: save it beside the "
               r"'transform' \(crs='EPSG:4326'\)")
    with pytest.warns(UserWarning, match=message):
        terrain = load_dem(tmp_path / "front.npz")
    assert terrain.crs == crs and terrain.spacing == (transform[1], transform[5])  # read as before
    np.savez(tmp_path / "utm.npz", elevation=z, transform=np.array([450000.0, 90.0, 0.0, 4480000.0, 0.0, -90.0]),
             crs="EPSG:99999")  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_dem(tmp_path / "utm.npz")  # metres by the look of them: nothing to say


def test_an_npz_member_cut_short_is_called_unreadable_not_python_objects(tmp_path):
    """A member of an .npz whose .npy header was cut short (a damaged archive) was refused as "member 'elevation'
    holds Python objects (EOF: reading array header ...)": every ValueError of NumPy's read was taken for the
    allow_pickle refusal. Now it is called unreadable; a member of Python objects is still named as such."""
    import io
    import zipfile

    buffer = io.BytesIO()
    np.save(buffer, np.arange(12.0).reshape(3, 4))
    with zipfile.ZipFile(tmp_path / "cut.npz", "w") as archive:
        archive.writestr("elevation.npy", buffer.getvalue()[:100])
    with pytest.raises(DataFileError, match=r"cut\.npz': member 'elevation' is unreadable \(EOF: reading array header"):
        load_dem(tmp_path / "cut.npz")
    np.savez(tmp_path / "objects.npz", elevation=np.array([[1, "a"], [2, None]], dtype=object))
    with pytest.raises(DataFileError, match=r"objects\.npz': member 'elevation' holds Python objects"):
        load_dem(tmp_path / "objects.npz")


@pytest.mark.parametrize("unit, factor", [("ft", 0.3048), ("US survey foot", 1200 / 3937), ("km", 1000.0),
                                          ("Feet", 0.3048)])
def test_an_npz_s_units_xy_in_another_length_unit_is_converted_to_metres(tmp_path, unit, factor):
    """An .npz whose 'units_xy' named the transform's unit (np.savez(..., transform=t_ft, units_xy="ft")) was read
    as metres whatever it said: a grid in feet 3.28 times too wide under its heights in metres. Its coordinates are
    converted to metres now (the mesh of the same grid saved in metres, to float tolerance), the unit named in the
    source; units_xy is read only without a CRS that states its own unit."""
    import stepterrain as st

    sample = np.load(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz")
    heights, transform = sample["elevation"][:120, :180], sample["transform"]
    np.savez(tmp_path / "m.npz", elevation=heights, transform=transform, units="m", units_xy="m")
    np.savez(tmp_path / "u.npz", elevation=heights, transform=transform / factor, units="m", units_xy=unit)
    metres, other = load_dem(tmp_path / "m.npz"), load_dem(tmp_path / "u.npz")
    assert other.spacing == pytest.approx(metres.spacing, rel=1e-12) == (30.0, -30.0)
    assert other.origin == pytest.approx(metres.origin, rel=1e-12)
    np.testing.assert_allclose(other.mesh().vertices, metres.mesh().vertices, rtol=1e-12, atol=1e-6)
    steps = [st.stepped(t, interval=100.0) for t in (metres, other)]
    np.testing.assert_allclose(steps[1].vertices, steps[0].vertices, rtol=1e-9, atol=1e-5)
    assert other.crs is None and other.source == f"u.npz (units_xy {unit!r} as metres: x {factor:.10g})"


def test_an_npz_s_units_xy_unknown_or_against_its_crs_is_refused(tmp_path):
    """'units_xy' that names no length unit (nor degrees), or one its CRS contradicts (metres of EPSG:32611 named
    feet), is refused naming the key and the value; one that names the CRS's own unit (feet of EPSG:2229, in any
    foot) converts once, by the CRS; degrees spelled "deg" read the grid as geographic."""
    pytest.importorskip("rasterio")
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    feet = np.array([6500000.0, 10.0, 0.0, 1900000.0, 0.0, -20.0])
    np.savez(tmp_path / "f.npz", elevation=z, transform=feet, units="m", units_xy="furlong")
    with pytest.raises(DataFileError, match=r"f\.npz': 'units_xy' must name the unit of the 'transform' \(a length "
                                            r"unit: m, km, .*US survey foot; or degrees\); got 'furlong'$"):
        load_dem(tmp_path / "f.npz")
    np.savez(tmp_path / "utm.npz", elevation=z, transform=feet, crs="EPSG:32611", units="m", units_xy="ft")
    with pytest.raises(DataFileError, match=r"utm\.npz': 'units_xy' is 'ft' \(0\.3048 m\), but its CRS EPSG:32611 "
                                            r"counts metre \(1 m\)"):
        load_dem(tmp_path / "utm.npz")
    np.savez(tmp_path / "m.npz", elevation=z, transform=feet, crs="EPSG:2229", units="m", units_xy="m")
    with pytest.raises(DataFileError, match=r"'units_xy' is 'm' \(1 m\), but its CRS EPSG:2229 counts US survey foot"):
        load_dem(tmp_path / "m.npz")
    np.savez(tmp_path / "ft.npz", elevation=z, transform=feet, crs="EPSG:2229", units="m", units_xy="ft")
    t = load_dem(tmp_path / "ft.npz")
    assert t.spacing == pytest.approx((10.0 * 1200 / 3937, -20.0 * 1200 / 3937), rel=1e-12) and t.crs == "EPSG:26945"
    degrees = np.array([-105.8, 0.001, 0.0, 40.4, 0.0, -0.001])
    np.savez(tmp_path / "deg.npz", elevation=z, transform=degrees, units="m", units_xy="deg")
    t = load_dem(tmp_path / "deg.npz")
    assert t.crs.startswith("+proj=eqc") and 80.0 < t.spacing[0] < 90.0


@pytest.mark.parametrize("units_xy, crs, factor", [("metres (EPSG:32611)", "EPSG:32611", 1.0),
                                                    ("m (UTM zone 11N)", None, 1.0), ("ft; State Plane", None, 0.3048),
                                                    ("US survey feet (CA zone 5)", None, 1200 / 3937)])
def test_an_npz_s_units_xy_naming_its_unit_then_a_note_is_read_by_that_unit(tmp_path, units_xy, crs, factor):
    """'units_xy' in the descriptive layout of shared/data ("degrees (EPSG:4326); see dx_m/dy_m for metres"), spelled
    for metres ("metres (EPSG:32611)"), was read as metres until units_xy was parsed, then refused as no unit:
    the unit it names first is read, the note after it ignored, as degrees are read in "decimal degrees (...)"."""
    z = np.arange(12, dtype=np.float32).reshape(3, 4)
    transform = np.array([400000.0, 30.0, 0.0, 3800000.0, 0.0, -30.0])
    extra = {} if crs is None else {"crs": crs}
    np.savez(tmp_path / "d.npz", elevation=z, transform=transform, units="m", units_xy=units_xy, **extra)
    t = load_dem(tmp_path / "d.npz")
    assert t.spacing == pytest.approx((30.0 * factor, -30.0 * factor), rel=1e-12)
    assert t.origin == pytest.approx((400015.0 * factor, 3799985.0 * factor), rel=1e-12)
    assert t.crs == crs

    # "ft" with a note naming the survey foot is not read as the international foot (2 ppm off): refused
    np.savez(tmp_path / "s.npz", elevation=z, transform=transform, units="m", units_xy="ft (US survey)")
    with pytest.raises(DataFileError, match=r"'units_xy' must name the unit .*; got 'ft \(US survey\)'$"):
        load_dem(tmp_path / "s.npz")


@pytest.mark.parametrize("lon", [[-180.0, 180.0], [180.0, -180.0], [0.0, 360.0, 1.0]])
def test_an_npz_lon_axis_with_neighbours_360_degrees_apart_is_refused_for_what_it_is(tmp_path, lon):
    """An .npz whose 'lon' is [-180, 180] was refused as "2 values from -180 to -180, no span" (the axis unwrapped
    across the antimeridian: values the file does not hold); the message names the two columns as stored and says
    they are the same meridian. An axis crossing the antimeridian still reads."""
    np.savez(tmp_path / "same.npz", elevation=np.zeros((3, len(lon))), lat=[-10.0, 0.0, 10.0], lon=lon)
    said = (rf"^cannot read '.*same\.npz': 'lon' must be a different meridian in each neighbouring column; got "
            rf"lon\[0\] = {lon[0]:g} and lon\[1\] = {lon[1]:g}, 360° apart: the same meridian twice$")
    with pytest.raises(DataFileError, match=said):
        load_dem(tmp_path / "same.npz")
    np.savez(tmp_path / "across.npz", elevation=np.zeros((3, 3)), lat=[-10.0, 0.0, 10.0], lon=[179.0, 180.0, -179.0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert load_dem(tmp_path / "across.npz").shape == (3, 3)


def test_a_geotiff_whose_name_is_not_utf8_is_refused_by_name(tmp_path, capsys):
    """A GeoTIFF named in Latin-1 ('H\\xf6he.tif', from an old zip or a network share, on a UTF-8 system) reaches
    Python as a name with surrogate escapes, which rasterio cannot hand to GDAL: load_dem raised UnicodeEncodeError
    from deep in rasterio, and `stepterrain info` printed a traceback. It is refused as a DataFileError naming the file
    and the rename that reads it; an .npy of such a name is read as before (NumPy opens any name)."""
    pytest.importorskip("rasterio")
    from stepterrain import cli

    name = os.fsdecode(b"H\xf6he")
    try:
        tif = tmp_path / f"{name}.tif"
        tif.write_bytes((SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif").read_bytes())
    except (OSError, UnicodeError):
        pytest.skip("the file system takes UTF-8 names only")
    refused = r"cannot read '.*H\\udcf6he\.tif': its path is not UTF-8 \(its bytes: b'.*H\\xf6he\.tif'\).*rename"
    with pytest.raises(DataFileError, match=refused):
        load_dem(tif)
    assert cli.main(["info", str(tif)]) == 2
    assert "its path is not UTF-8" in capsys.readouterr().err
    npy = tmp_path / f"{name}.npy"
    np.save(npy, np.arange(12.0).reshape(3, 4))
    assert load_dem(npy).shape == (3, 4)


def test_a_png_heightmaps_scale_and_offset_in_its_aux_xml_are_refused_not_dropped(tmp_path):
    """A DEM of scaled integers (height = value * scale + offset, GDAL's band scale and offset) exported to a 16-bit
    PNG by `gdal_translate -of PNG` keeps its values and writes the scale and offset to dem.png.aux.xml, which load_dem
    does not read for a PNG (Pillow reads the pixels): the stored values were read as heights, 10 times too high and
    100 m off, without a word (a GeoTIFF of the same values is read scaled). Refused naming the scale and offset and
    the gdal_translate to a GeoTIFF that keeps them; a scale of 1 and offset of 0, or no band entry, read as before."""
    heights = load_dem(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz").heights[:40, :50]
    stored = np.round((heights - 100.0) / 0.1).astype(np.uint16)  # decimetres above 100 m
    png = tmp_path / "dem.png"
    Image.fromarray(stored).save(png)

    def aux(scale, offset):
        (tmp_path / "dem.png.aux.xml").write_text(
            "<PAMDataset>\n  <Metadata>\n    <MDI key=\"AREA_OR_POINT\">Area</MDI>\n  </Metadata>\n"
            f"  <PAMRasterBand band=\"1\">\n    <Offset>{offset}</Offset>\n    <Scale>{scale}</Scale>\n"
            "  </PAMRasterBand>\n</PAMDataset>\n")

    aux(0.1, 100)
    with pytest.raises(DataFileError, match=r"scale 0\.1, offset 100 of its values in dem\.png\.aux\.xml.*"
                                            r"gdal_translate dem\.png dem\.tif"):
        load_dem(png)
    if _has_rasterio():  # the GeoTIFF the hint names reads the heights (GDAL reads the PNG's aux.xml)
        import rasterio

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning for the plain PNG and TIFF
            with rasterio.open(png) as src, \
                    rasterio.open(tmp_path / "dem.tif", "w", **{**src.profile, "driver": "GTiff"}) as out:
                out.write(src.read())
                out.scales, out.offsets = src.scales, src.offsets
        np.testing.assert_allclose(load_dem(tmp_path / "dem.tif").heights, heights, atol=0.05)
    aux(1, 0)
    np.testing.assert_array_equal(load_dem(png).heights, stored.astype(np.float32))
    (tmp_path / "dem.png.aux.xml").write_text("<PAMDataset>\n  <Metadata/>\n</PAMDataset>\n")
    np.testing.assert_array_equal(load_dem(png).heights, stored.astype(np.float32))


def _has_rasterio():
    try:
        import rasterio  # noqa: F401
    except ImportError:
        return False
    return True


def test_an_arcinfo_style_prj_beside_a_world_file_tiff_gives_its_crs(tmp_path):
    """An ESRI .prj in the ArcInfo keyword form ("Projection UTM / Zone 11 / Units METERS ...", as ArcInfo and
    ArcView 3 wrote it beside grids and their TIFF exports) is the CRS GDAL reads beside an ASCII grid, but no WKT
    parser takes it: beside a TIFF with a world file it was refused as "not a CRS". It gives the same CRS as beside
    the ASCII grid (one in US survey feet converted as any such CRS); a .prj in neither form is still refused."""
    rasterio = pytest.importorskip("rasterio")

    arcinfo = ("Projection    UTM\nZone          11\nDatum         WGS84\nZunits        NO\nUnits         METERS\n"
               "Spheroid      WGS84\nXshift        0.0000000000\nYshift        0.0000000000\nParameters\n")
    z = load_dem(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz").heights[:30, :40]
    tif = tmp_path / "dem.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning for the bare TIFF
        with rasterio.open(tif, "w", driver="GTiff", width=40, height=30, count=1, dtype="float32") as ds:
            ds.write(z, 1)
    tif.with_suffix(".tfw").write_text("30.0\n0.0\n0.0\n-30.0\n376328.655\n3807902.828\n")
    tif.with_suffix(".prj").write_text(arcinfo)
    asc = tmp_path / "grid.asc"
    asc.write_text("ncols 40\nnrows 30\nxllcorner 376313.655\nyllcorner 3807017.828\ncellsize 30\n"
                   + "\n".join(" ".join(f"{v:g}" for v in row) for row in z) + "\n")
    asc.with_suffix(".prj").write_text(arcinfo)
    beside_grid = load_dem(asc)
    assert beside_grid.crs == "EPSG:32611"  # as GDAL reads it beside the grid
    t = load_dem(tif)
    assert (t.crs, t.spacing) == (beside_grid.crs, (30.0, -30.0))
    assert t.origin == pytest.approx(beside_grid.origin)
    np.testing.assert_array_equal(t.heights, beside_grid.heights)
    tif.with_suffix(".prj").write_text("Projection    STATEPLANE\nFipszone      0405\nDatum         NAD83\n"
                                       "Units         FEET\nSpheroid      GRS1980\nParameters\n")
    with pytest.warns(UserWarning, match=r"Foot_US units, so spacing and origin were converted to metres"):
        feet = load_dem(tif)
    assert feet.spacing == pytest.approx((30.0 * 1200 / 3937, -30.0 * 1200 / 3937))
    for text in ("WGS 84 / UTM zone 11N, metres\n",  # a note, in neither form
                 arcinfo.replace("UTM", "UTMX", 1)):  # a projection GDAL does not know: a local CRS "UTMX" to it
        tif.with_suffix(".prj").write_text(text)
        with pytest.raises(DataFileError, match=r"dem\.prj' beside DEM '.*dem\.tif' is not a CRS"):
            load_dem(tif)


@pytest.mark.parametrize("crop", [None, (0.0, 50.0, -50.0, 0.0)])
def test_a_complex_int16_band_is_refused_as_a_complex64_one_is(tmp_path, crop):
    # a CInt16 band (SAR, interferograms: `gdal_translate -ot CInt16`) has no NumPy dtype: rasterio names it
    # 'complex_int16', and np.dtype() of it in the memory-budget check raised a raw TypeError ("data type
    # 'complex_int16' not understood") out of load_dem and `stepterrain info`; it is refused as a complex64 band is,
    # from the header, before the band is read
    rasterio = pytest.importorskip("rasterio")
    source = tmp_path / "heights.tif"
    with rasterio.open(source, "w", driver="GTiff", width=4, height=3, count=1, dtype="int16", crs="EPSG:32611",
                       transform=rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0)) as ds:  # fmt: skip
        ds.write(np.arange(12, dtype=np.int16).reshape(3, 4), 1)
    vrt = tmp_path / "sar.vrt"  # GDAL's own CInt16 band over it, as `gdal_translate -ot CInt16 -of VRT` writes
    vrt.write_text(
        '<VRTDataset rasterXSize="4" rasterYSize="3"><SRS>EPSG:32611</SRS>'
        "<GeoTransform>0, 30, 0, 0, 0, -30</GeoTransform>"
        '<VRTRasterBand dataType="CInt16" band="1"><SimpleSource>'
        f'<SourceFilename relativeToVRT="0">{source}</SourceFilename><SourceBand>1</SourceBand>'
        "</SimpleSource></VRTRasterBand></VRTDataset>"
    )
    with rasterio.open(vrt) as ds:
        assert ds.dtypes == ("complex_int16",)  # what the header declares, which no np.dtype() reads
    with pytest.raises(DataFileError, match=r"sar\.vrt.*expected real-valued elevation data; got band 1 of dtype "
                                            r"complex_int16$"):
        load_dem(vrt, crop=crop)


def test_an_srtm_tile_renamed_or_cut_short_says_what_gdal_needs_of_a_hgt(tmp_path):
    # GDAL knows a .hgt only by its name (N40W106.hgt: its south-west corner, which places it) and its size (1201 or
    # 3601 samples square); a tile renamed by a user (everest.hgt) or cut short was refused as "unreadable content
    # ('everest.hgt' not recognized as being in a supported file format.)", though its content was fine
    pytest.importorskip("rasterio")
    tile = tmp_path / "N40W106.hgt"
    (np.arange(1201 * 1201) % 3000).astype(">i2").tofile(tile)
    z = load_dem(tile).heights
    assert z.shape == (1201, 1201) and z[0, 1] == 1.0  # the tile itself reads
    renamed = tmp_path / "everest.hgt"
    renamed.write_bytes(tile.read_bytes())
    with pytest.raises(DataFileError, match=r"everest\.hgt.*expected an SRTM tile named by its south-west corner "
                                            r"\(N34W119\.hgt.*\); got the name 'everest\.hgt'"):
        load_dem(renamed)
    cut = tmp_path / "N41W106.hgt"
    cut.write_bytes(tile.read_bytes()[:1000])
    with pytest.raises(DataFileError, match=r"N41W106\.hgt.*expected an SRTM tile of 1201 x 1201 or 3601 x 3601 "
                                            r"16-bit samples \(2,884,802 or 25,934,402 bytes.*\); got 1,000 bytes"):
        load_dem(cut)


def test_a_hgt_missing_from_a_zip_is_named_missing_not_to_be_renamed(tmp_path):
    # the name refusal of a .hgt (GDAL places a tile by its name) applies to a file GDAL found and did not know: a
    # /vsizip/ path to a renamed tile the zip does not hold was told to "rename it so", not that it is not there
    pytest.importorskip("rasterio")
    import zipfile

    archive = tmp_path / "srtm.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("everest.hgt", (np.arange(1201 * 1201) % 3000).astype(">i2").tobytes())
    there = f"/vsizip/{archive}/everest.hgt"
    with pytest.raises(DataFileError, match=r"everest\.hgt.*expected an SRTM tile named by its south-west corner"):
        load_dem(there)  # in the zip, under a name GDAL does not place
    missing = f"/vsizip/{archive}/lhotse.hgt"
    with pytest.raises(DataFileError) as caught:
        load_dem(missing)
    assert "does not exist" in str(caught.value) and "rename" not in str(caught.value), caught.value


def test_a_raster_gdal_opened_under_a_hgt_name_keeps_gdal_s_read_failure(tmp_path):
    # a .hgt GDAL opened by its content (a GeoTIFF under that name) and failed to read (cut short) was told to be
    # renamed as an SRTM tile, which would not read it either: GDAL's reason, as for a .tif cut short
    rasterio = pytest.importorskip("rasterio")
    source = tmp_path / "whole.tif"
    with rasterio.open(source, "w", driver="GTiff", width=256, height=256, count=1, dtype="float32",
                       transform=rasterio.Affine(30.0, 0.0, 0.0, 0.0, -30.0, 0.0)) as ds:  # fmt: skip
        ds.write(np.random.default_rng(0).random((256, 256), np.float32), 1)
    cut = tmp_path / "dem.hgt"
    cut.write_bytes(source.read_bytes()[: source.stat().st_size // 2])
    with pytest.raises(DataFileError, match=r"dem\.hgt.*IReadBlock failed") as caught:
        load_dem(cut)
    assert "rename" not in str(caught.value)


def test_undeclared_void_hint_quotes_a_file_name_with_a_space(tmp_path):
    """The hint of undeclared voids gives a command to run (`gdal_edit.py -a_nodata ... dem.tif`, or the
    `gdal_translate` to a GeoTIFF for another GDAL format) with the file's name as it is: a name with a space, as
    downloads are often named ("my dem.tif"), split into two words in the shell, and gdal_edit.py edited no file.
    The names are quoted now, so the command parses back to the file and the GeoTIFF it writes."""
    import shlex

    pytest.importorskip("rasterio")
    z = np.full((4, 5), 120.0, np.float32)
    z[0, :2] = np.finfo(np.float32).min
    asc = tmp_path / "my dem.asc"
    asc.write_text("ncols 5\nnrows 4\nxllcorner 0\nyllcorner 0\ncellsize 30\n"
                   + "".join(" ".join(f"{v:.9g}" for v in row) + "\n" for row in z))
    import rasterio

    with rasterio.open(tmp_path / "my dem.tif", "w", driver="GTiff", width=5, height=4, count=1, dtype="float32",
                       crs="EPSG:32611", transform=rasterio.transform.Affine(30.0, 0, 0, 0, -30.0, 120.0)) as f:
        f.write(z, 1)
    expected = {"my dem.tif": ["gdal_edit.py", "-a_nodata", "-3.4028235e+38", "my dem.tif"],
                "my dem.asc": ["gdal_translate", "-a_nodata", "-3.4028235e+38", "my dem.asc", "my dem.tif"]}
    for name, words in expected.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            load_dem(tmp_path / name)
        message = next(str(w.message) for w in caught if "marks voids" in str(w.message))
        hint = re.search(r"declare it \(`([^`]*)`, or pass nodata=-3.4028235e\+38\)", message)
        assert hint and shlex.split(hint.group(1)) == words, message


def _pam_nodata(png, value):
    png.with_name(png.name + ".aux.xml").write_text(
        f"<PAMDataset>\n  <PAMRasterBand band=\"1\">\n    <NoDataValue>{value}</NoDataValue>\n  </PAMRasterBand>\n"
        "</PAMDataset>\n")


def test_a_png_heightmaps_nodata_in_its_aux_xml_marks_its_voids(tmp_path):
    """A PNG heightmap's nodata value in GDAL's PAM file beside it (dem.png.aux.xml, <NoDataValue>: `gdal_translate
    -of PNG` writes it there for a grey + alpha PNG, which holds no tRNS, and a nodata set by hand or by another tool
    lies there) is read by GDAL and every GIS, but Pillow reads no such file: the voids were heights (9999 m spikes)
    without a word. Now they are nodata, as GDAL masks them; a tRNS value, which GDAL takes first, still wins."""
    heights = np.round(load_dem(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz").heights[:40, :50]).astype(np.uint16)
    voids = np.zeros(heights.shape, bool)
    voids[3:6, 7:12] = voids[30, 40] = True
    png = tmp_path / "dem.png"
    Image.fromarray(np.where(voids, 9999, heights).astype(np.uint16)).save(png)
    _pam_nodata(png, "9999")
    terrain = load_dem(png)
    np.testing.assert_array_equal(np.isnan(terrain.heights), voids)
    np.testing.assert_array_equal(terrain.heights[~voids], heights[~voids].astype(np.float32))
    if _has_rasterio():  # as GDAL masks them
        import rasterio

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning
            with rasterio.open(png) as src:
                np.testing.assert_array_equal(np.ma.getmaskarray(src.read(1, masked=True)), voids)
    _pam_nodata(png, "not a number")  # read as 0, as GDAL reads it (strtod), with a warning: no cell here is 0
    with pytest.warns(UserWarning, match="'not a number' in dem.png.aux.xml is not a number; read as 0"):
        assert not np.isnan(load_dem(png).heights).any()
    # a tRNS value is the PNG's own nodata, which GDAL takes before the aux.xml's
    Image.fromarray(np.where(voids, 9999, heights).astype(np.uint16)).save(png, transparency=int(heights[0, 0]))
    _pam_nodata(png, "9999")
    np.testing.assert_array_equal(np.isnan(load_dem(png).heights), heights == heights[0, 0])


def test_a_grey_and_alpha_png_from_gdal_translate_keeps_its_nodata(tmp_path):
    """`gdal_translate -of PNG` of a grey + alpha raster with a nodata value writes an 8-bit LA PNG and the nodata
    to its aux.xml (a PNG with alpha holds no tRNS): the alpha was read, the nodata cells (opaque) came out as
    heights of 0 m. Both mark missing cells now, as a GeoTIFF's nodata and alpha band do."""
    pytest.importorskip("rasterio")
    import rasterio
    import rasterio.shutil
    from rasterio.enums import ColorInterp

    heights = np.clip(load_dem(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz").heights[:30, :40] / 8, 1, 255)
    grey = np.round(heights).astype(np.uint8)
    grey[2:4, 5:9] = 0  # nodata
    alpha = np.full(grey.shape, 255, np.uint8)
    alpha[20:25, 30:33] = 0  # transparent
    tif, png = tmp_path / "src.tif", tmp_path / "dem.png"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning
        with rasterio.open(tif, "w", driver="GTiff", width=40, height=30, count=2, dtype="uint8", nodata=0,
                           alpha="YES") as out:
            out.write(np.stack([grey, alpha]))
            out.colorinterp = [ColorInterp.gray, ColorInterp.alpha]
        rasterio.shutil.copy(tif, png, driver="PNG")  # GDAL's CreateCopy, as gdal_translate -of PNG
    assert "<NoDataValue>" in png.with_name("dem.png.aux.xml").read_text()
    terrain = load_dem(png)
    np.testing.assert_array_equal(np.isnan(terrain.heights), (grey == 0) | (alpha == 0))
    np.testing.assert_array_equal(np.isnan(terrain.heights), np.isnan(load_dem(tif).heights))  # as the GeoTIFF


def _run_the_hinted_gdalwarp(message, folder):
    """The `gdalwarp ...` command ``message`` gives, run in ``folder`` (skipped without gdal-bin)."""
    import shlex
    import shutil
    import subprocess

    if shutil.which("gdalwarp") is None:
        pytest.skip("gdalwarp (gdal-bin) is not installed")
    command = re.search(r"`(gdalwarp [^`]*)`", message).group(1)
    subprocess.run([*shlex.split(command), "-q"], cwd=folder, check=True, capture_output=True)
    return shlex.split(command)[-1]


def test_the_gdalwarp_a_rotated_grid_is_refused_with_leaves_no_0_m_corners(tmp_path):
    """A rotated GeoTIFF is refused with the gdalwarp that makes it north-up: run as said, `gdalwarp dem.tif`,
    the corners of the north-up grid outside the rotated one were filled with 0 (the file has no nodata value) and
    read back as heights of 0 m, cliffs to sea level round a mountain DEM, without a word. The command now adds
    -dstalpha: those corners are missing, and every height read is one of the file's."""
    rasterio = pytest.importorskip("rasterio")
    heights = load_dem(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz").heights[:40, :50].astype(np.float32)
    transform = rasterio.Affine.translation(385000.0, 3800000.0) @ rasterio.Affine.rotation(10.0) \
        @ rasterio.Affine.scale(30.0, -30.0)
    with rasterio.open(tmp_path / "rotated.tif", "w", driver="GTiff", width=50, height=40, count=1, dtype="float32",
                       crs="EPSG:32611", transform=transform) as out:
        out.write(heights, 1)
    with pytest.raises(DataFileError, match=r"rotated geotransform") as caught:
        load_dem(tmp_path / "rotated.tif")
    north_up = load_dem(tmp_path / _run_the_hinted_gdalwarp(str(caught.value), tmp_path))
    assert north_up.has_nodata and north_up.spacing == pytest.approx((30.0, -30.0))
    assert np.nanmin(north_up.heights) >= heights.min()  # no 0 m corner


def test_the_gdalwarp_of_a_polar_grid_in_degrees_leaves_no_0_m_corners(tmp_path):
    """A grid in degrees near a pole is warned of with the gdalwarp to a polar stereographic projection: run as
    said, the corners round the projected wedge were 0 (the file has no nodata value): a quarter of the grid at 0 m,
    read back without a word. The command now adds -dstalpha: they are missing."""
    rasterio = pytest.importorskip("rasterio")
    heights = np.round(load_dem(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz").heights[::8, ::8]).astype(np.float32)
    rows, cols = heights.shape
    with rasterio.open(tmp_path / "arctic.tif", "w", driver="GTiff", width=cols, height=rows, count=1,
                       dtype="float32", crs="EPSG:4326",
                       transform=rasterio.Affine(20.0 / cols, 0.0, 0.0, 0.0, -10.0 / rows, 80.0)) as out:
        out.write(heights, 1)
    with pytest.warns(UserWarning, match=r"polar stereographic") as caught:
        load_dem(tmp_path / "arctic.tif")
    message = next(str(w.message) for w in caught if "polar stereographic" in str(w.message))
    with pytest.warns(UserWarning, match=r"errs against WGS 84") as caught:
        projected = load_dem(tmp_path / _run_the_hinted_gdalwarp(message, tmp_path))
    assert projected.has_nodata and "Polar_Stereographic" in projected.crs
    assert np.nanmin(projected.heights) >= np.nanmin(heights)  # no 0 m corner
    # its metres err by 2.9 % over 10 degrees of latitude, in the projection it was advised: that same gdalwarp was
    # advised again (warped again, it warned again), which no projection helps
    again = next(str(w.message) for w in caught if "errs against WGS 84" in str(w.message))
    assert "gdalwarp" not in again and "no one projection keeps a grid over 10.4 degrees of latitude" in again, again


def test_a_one_bit_pngs_transparent_colour_is_read_as_alpha(tmp_path):
    """A 1-bit PNG whose transparent colour is a tRNS chunk (Pillow mode "1", info["transparency"]) was read as RGB by
    picture_uint8(alpha=True) (a palette, L or RGB one became RGBA): a texture draped from it showed its transparent
    pixels opaque black, where the GLB (alphaMode MASK) hid them. Its alpha is Pillow's RGBA conversion's now."""
    from stepterrain import globe
    from stepterrain.io import picture_uint8

    bits = np.zeros((4, 6), bool)
    bits[1:3, 2:5] = True
    Image.fromarray(bits).save(tmp_path / "mask.png", transparency=0)
    with Image.open(tmp_path / "mask.png") as picture:
        assert picture.mode == "1" and picture.info["transparency"] == 0
        expected = np.asarray(picture.convert("RGBA"))
        got = picture_uint8(picture, "mask", alpha=True)
    assert got.shape == (4, 6, 4)
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(got[..., 3], np.where(bits, 255, 0))
    np.testing.assert_array_equal(globe._texture_pixels(tmp_path / "mask.png"), expected)


def test_a_signed_16_bit_tiff_is_refused_as_an_image_not_scaled_to_black(tmp_path):
    """A DEM GeoTIFF (int16, SampleFormat 2) given as a picture, `stepterrain texture dem.tif --image dem.tif` or
    `globe --texture relief.tif`, was read by Pillow as mode I and scaled by 1/257 as a 16-bit image: Big Tujunga's
    315-2295 m became grey levels 1-9, a silently black drape; a DEM with one negative height was refused instead.
    Signed samples are refused whatever their values now, as rasterio's read of such a TIFF refuses int16; unsigned
    16-bit TIFFs are still read by their full range."""
    rasterio = pytest.importorskip("rasterio")
    from stepterrain import globe
    from stepterrain.errors import InvalidInputError
    from stepterrain.io import picture_uint8

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as src:
        heights = src.read(1, window=rasterio.windows.Window(0, 0, 40, 30))
    assert heights.dtype == np.int16 and heights.min() > 0  # every value non-negative: was accepted
    profile = dict(driver="GTiff", width=40, height=30, count=1, crs="EPSG:4326",
                   transform=rasterio.transform.from_origin(-180, 90, 9, 6))
    with rasterio.open(tmp_path / "dem.tif", "w", dtype="int16", **profile) as dst:
        dst.write(heights, 1)
    ramp = np.round(np.linspace(0, 65535, 1200)).astype(np.uint16).reshape(30, 40)
    with rasterio.open(tmp_path / "u16.tif", "w", dtype="uint16", **profile) as dst:
        dst.write(ramp, 1)
    with Image.open(tmp_path / "dem.tif") as picture, pytest.raises(
            InvalidInputError, match=r"dem must be an 8-bit or 16-bit image of unsigned samples; got a TIFF of signed "
                                     r"16-bit integers \(SampleFormat 2\)"):
        picture_uint8(picture, "dem")
    with pytest.raises(InvalidInputError, match=r"texture .*dem\.tif' must be an 8-bit or 16-bit image of unsigned"):
        globe._texture_pixels(tmp_path / "dem.tif")
    with Image.open(tmp_path / "u16.tif") as picture:
        got = picture_uint8(picture, "u16")
    np.testing.assert_array_equal(got, np.repeat(np.round(ramp / 257.0).astype(np.uint8)[..., None], 3, axis=2))


@pytest.mark.parametrize("ext", [".npy", ".npz"])
def test_an_array_over_the_memory_budget_is_not_told_to_use_gdal(tmp_path, capsys, ext):
    """An .npy or .npz over the memory budget was told to "crop or coarsen it first (gdal_translate -srcwin or
    -outsize)", advice for a GDAL raster: GDAL reads neither, and `stepterrain info global_relief.npz --memory-budget
    1MB` said so too. The advice is NumPy's now (a slice, saved again); a GeoTIFF keeps gdal_translate's."""
    import stepterrain as st
    from stepterrain.errors import OutputTooLargeError

    from .conftest import run_cli

    relief = np.load(SHARED_DATA / "global_relief_1deg.npz")["elevation"]  # (180, 360) int16: 259,200 bytes kept
    path = tmp_path / f"relief{ext}"
    np.save(path, relief) if ext == ".npy" else np.savez(path, elevation=relief)
    previous = st.set_memory_budget(100_000)
    try:
        with pytest.raises(OutputTooLargeError, match=r"180 x 360 cells of int16\) would need 0.2 MiB, .*; crop "
                                                      r"or coarsen it first in NumPy \(heights\[r0:r1, c0:c1\]"):
            load_dem(path)
    finally:
        st.set_memory_budget(previous)
    code, _, err = run_cli(capsys, "-q", "--memory-budget", "100kB", "info", path)
    assert code == 2 and "first in NumPy" in err and "gdal_translate" not in err, err
