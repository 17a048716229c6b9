"""load_dem's ``height_encoding``: RGB(A) PNG web-map terrain tiles, Mapbox Terrain-RGB and Mapzen/AWS Terrarium,
checked against an independent NumPy encoder on real DEMs, a hypothesis round trip over the codes' ranges, their
nodata (alpha 0), a world file's placement, the refusals and the CLI's --height-encoding."""

from __future__ import annotations

import json
import struct
import warnings
import zlib
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st_
from hypothesis.extra import numpy as hnp
from PIL import Image

import stepterrain as st
from stepterrain.errors import DataFileError, InvalidInputError
from stepterrain.export import read_mesh
from stepterrain.io import HEIGHT_ENCODINGS, load_dem

from .conftest import needs_render, shared_file
from .conftest import run_cli as run
from .test_export import glb_json


# ---------------------------------------------------------------- an encoder of its own (the formulas inverted)
def encode_terrain_rgb(heights: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 of Terrain-RGB: code = round((h + 10000) / 0.1), R = code / 65536, G, B its lower bytes."""
    code = np.rint((heights.astype(np.float64) + 10000.0) * 10.0).astype(np.int64)
    assert code.min() >= 0 and code.max() < 2**24
    return np.stack([code // 65536, (code // 256) % 256, code % 256], axis=-1).astype(np.uint8)


def encode_terrarium(heights: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 of Terrarium: v = h + 32768 in 1/256 m, R = v // 256, G = v % 256, B = the fraction x 256."""
    v = np.rint((heights.astype(np.float64) + 32768.0) * 256.0).astype(np.int64)
    assert v.min() >= 0 and v.max() < 2**24
    return np.stack([v // 65536, (v // 256) % 256, v % 256], axis=-1).astype(np.uint8)


ENCODERS = {"terrain-rgb": (encode_terrain_rgb, 0.05), "terrarium": (encode_terrarium, 0.5 / 256)}


def exact(rgb: np.ndarray, encoding: str) -> np.ndarray:
    """The float64 decimal heights of the codes, computed apart from the loader (Python ints and fractions)."""
    r, g, b = (rgb[..., i].astype(np.int64) for i in range(3))
    if encoding == "terrain-rgb":
        return np.vectorize(lambda c: float(Fraction(c - 100000, 10)), otypes=[np.float64])(r * 65536 + g * 256 + b)
    return (r * 256 + g).astype(np.float64) - 32768.0 + b.astype(np.float64) / 256.0


def real_heights() -> list[np.ndarray]:
    """The embedded DEM and a crop of a shared GeoTIFF (the Front Range: 1500-4300 m), NaN nodata added to each."""
    sample = st.sample_dem().heights[::3, ::3].copy()
    tif = load_dem(shared_file("front_range_srtmgl3_3arcsec.tif"), crop=None).heights[200:330, 400:560].copy()
    for z in (sample, tif):
        z[5:9, 7:12] = np.nan
    return [sample, tif]


@pytest.mark.parametrize("encoding", list(HEIGHT_ENCODINGS))
def test_real_dems_encoded_by_an_independent_encoder_load_back(tmp_path, encoding):
    """Each real DEM, encoded by this test's own encoder and saved by Pillow (RGBA, alpha 0 at its nodata; and RGB
    without nodata), loads back to within half a code step, NaN exactly where alpha is 0, and each height is the
    float32 of the code's exact decimal height."""
    encode, half_step = ENCODERS[encoding]
    for k, heights in enumerate(real_heights()):
        missing = np.isnan(heights)
        rgb = encode(np.where(missing, 0.0, heights))
        alpha = np.where(missing, 0, 255).astype(np.uint8)[..., None]
        Image.fromarray(np.concatenate([rgb, alpha], axis=-1), "RGBA").save(tmp_path / f"dem{k}.png")
        Image.fromarray(rgb, "RGB").save(tmp_path / f"opaque{k}.png")
        terrain = load_dem(tmp_path / f"dem{k}.png", height_encoding=encoding)
        assert terrain.heights.dtype == np.float32 and terrain.shape == heights.shape
        assert np.array_equal(np.isnan(terrain.heights), missing)
        assert np.nanmax(np.abs(terrain.heights.astype(np.float64) - heights)) <= half_step + 1e-3 * half_step
        np.testing.assert_array_equal(terrain.heights[~missing], exact(rgb, encoding).astype(np.float32)[~missing])
        assert terrain.spacing == (1.0, -1.0) and terrain.origin == (0.0, 0.0) and terrain.crs is None
        opaque = load_dem(tmp_path / f"opaque{k}.png", height_encoding=encoding.upper())  # any case
        assert not np.isnan(opaque.heights).any()
        np.testing.assert_array_equal(opaque.heights, exact(rgb, encoding).astype(np.float32))


@settings(max_examples=25, deadline=None)
@given(codes=hnp.arrays(np.int64, st_.tuples(st_.integers(2, 4), st_.integers(2, 5)),
                        elements=st_.integers(0, 2**24 - 1)),
       encoding=st_.sampled_from(list(HEIGHT_ENCODINGS)))
def test_round_trip_over_the_codes_ranges(tmp_path_factory, codes, encoding):
    """Any 24-bit codes, saved as RGB and loaded, are the float32 of their exact decimal heights; re-encoded they
    are the codes again: every Terrarium code (1/256 m over ±32 km fits float32's 24 bits), and every Terrain-RGB
    code of a height within ±10 km (float32 keeps 0.1 m steps there; above, to 1.67e6 m, its own rounding)."""
    rgb = np.stack([codes // 65536, (codes // 256) % 256, codes % 256], axis=-1).astype(np.uint8)
    path = tmp_path_factory.mktemp("rt") / "tile.png"
    Image.fromarray(rgb, "RGB").save(path)
    heights = load_dem(path, height_encoding=encoding).heights
    np.testing.assert_array_equal(heights, exact(rgb, encoding).astype(np.float32))
    again = ENCODERS[encoding][0]
    if encoding == "terrain-rgb":
        within = np.abs(heights) <= 10000.0
        np.testing.assert_array_equal(again(np.where(within, heights, 0.0)), np.where(within[..., None], rgb,
                                                                                        encode_terrain_rgb(np.zeros(1))))
    else:
        np.testing.assert_array_equal(again(heights), rgb)


def test_terrain_rgb_heights_within_10_km_decode_as_their_decimals():
    """The 0.1 m steps over ±10 km: (code - 100000) / 10 is the nearest float64 (and float32) of the decimal; -10000
    + code * 0.1, the formula as written, is not for half of them (code 20482: -7951.799999999999)."""
    from stepterrain.io import decode_terrain_rgb

    codes = np.arange(0, 200001, dtype=np.int64)
    rgb = np.stack([codes // 65536, (codes // 256) % 256, codes % 256], axis=-1)
    decoded = decode_terrain_rgb(rgb, "terrain-rgb")
    assert decoded.dtype == np.float64
    np.testing.assert_array_equal(decoded, [float(f"{c / 10 - 10000:.1f}") for c in codes.tolist()])
    assert decoded[20482] == -7951.8 and -10000 + 20482 * 0.1 != -7951.8


def test_transparent_colour_and_palette_tiles(tmp_path):
    """A tRNS transparent colour is nodata as alpha 0 is; a palette PNG reads through its palette (lossless)."""
    heights = np.array([[100.0, 200.5], [300.25, -50.0], [0.0, 8848.0]])
    rgb = encode_terrarium(heights)
    Image.fromarray(rgb, "RGB").save(tmp_path / "trns.png", transparency=tuple(int(v) for v in rgb[1, 0]))
    terrain = load_dem(tmp_path / "trns.png", height_encoding="terrarium")
    assert np.isnan(terrain.heights[1, 0]) and np.isnan(terrain.heights).sum() == 1
    palette = Image.fromarray(rgb, "RGB").quantize(colors=6, method=Image.Quantize.MAXCOVERAGE)
    palette.save(tmp_path / "palette.png")
    with Image.open(tmp_path / "palette.png") as image:
        assert image.mode == "P"
        colours = np.asarray(image.convert("RGB"))
    np.testing.assert_array_equal(load_dem(tmp_path / "palette.png", height_encoding="terrarium").heights,
                                  exact(colours, "terrarium").astype(np.float32))


def test_a_world_file_places_the_tile(tmp_path):
    """A tile with a world file (.pgw: A, D, B, E, C, F at the upper-left pixel's centre) and a .prj gets its spacing,
    origin and CRS, as GDAL reads them; a grey PNG's world file is still only warned of."""
    heights = load_dem(shared_file("big_tujunga_srtm_30m_utm11n.tif")).heights[:40, :50]
    Image.fromarray(encode_terrain_rgb(heights), "RGB").save(tmp_path / "tile.png")
    (tmp_path / "tile.pgw").write_text("30.0\n0.0\n0.0\n-30.0\n380015.0\n3800985.0\n")
    (tmp_path / "tile.prj").write_text("EPSG:32611")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        terrain = load_dem(tmp_path / "tile.png", height_encoding="terrain-rgb")
    assert terrain.spacing == (30.0, -30.0) and terrain.origin == (380015.0, 3800985.0)
    assert terrain.crs == "EPSG:32611"
    assert np.nanmax(np.abs(terrain.heights - heights)) <= 0.05 + 1e-3
    (tmp_path / "tile.prj").unlink()
    (tmp_path / "tile.pgw").rename(tmp_path / "tile.WLD")  # GDAL's other name, UPPER case too
    assert load_dem(tmp_path / "tile.png", height_encoding="terrain-rgb").origin == (380015.0, 3800985.0)
    (tmp_path / "tile.WLD").write_text("30 0 0 -30 nan 5\n")
    with pytest.raises(DataFileError, match=r"world file 'tile\.WLD' to hold six finite numbers"):
        load_dem(tmp_path / "tile.png", height_encoding="terrain-rgb")


def test_a_web_mercator_tile_warns_of_its_scale(tmp_path):
    """A zoom-12 Terrarium tile of the Alps in EPSG:3857 (as the tiles are served) is placed in its Mercator metres,
    with load_dem's warning that they are ground metres times about 1/cos φ."""
    heights = st.sample_dem().heights[:64, :64] + 1000.0
    Image.fromarray(encode_terrarium(heights), "RGB").save(tmp_path / "12_2138_1447.png")
    (tmp_path / "12_2138_1447.pgw").write_text("152.874\n0\n0\n-152.874\n1001875.4\n5831724.8\n")
    (tmp_path / "12_2138_1447.prj").write_text("EPSG:3857")
    with pytest.warns(UserWarning, match="Mercator"):
        terrain = load_dem(tmp_path / "12_2138_1447.png", height_encoding="terrarium")
    assert terrain.crs == "EPSG:3857" and terrain.spacing == (152.874, -152.874)


def _png16_rgb(path, rgb16: np.ndarray) -> None:
    """A 16-bit-per-channel RGB PNG (Pillow writes none), by hand."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    h, w, _ = rgb16.shape
    raw = b"".join(b"\0" + rgb16[i].astype(">u2").tobytes() for i in range(h))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def test_refusals(tmp_path):
    """An RGB PNG without an encoding is refused naming the encodings; an unknown encoding lists them; a grey (8- or
    16-bit) PNG, a 16-bit RGB PNG, another format under .png, and a file that is no PNG, with an encoding, are
    refused."""
    rgb = encode_terrarium(np.full((3, 3), 500.0))
    Image.fromarray(rgb, "RGB").save(tmp_path / "tile.png")
    with pytest.raises(DataFileError, match=r"an RGB terrain tile reads with its encoding named, "
                                            r"height_encoding='terrain-rgb' or 'terrarium'\)$"):
        load_dem(tmp_path / "tile.png")
    with pytest.raises(InvalidInputError, match=r"height_encoding must be one of 'terrain-rgb', 'terrarium' or None; "
                                                r"got 'mapbox'"):
        load_dem(tmp_path / "tile.png", height_encoding="mapbox")
    Image.fromarray(np.full((3, 3), 7, np.uint8)).save(tmp_path / "grey.png")
    Image.fromarray(np.full((3, 3), 700, np.uint16)).save(tmp_path / "grey16.png")
    for name in ("grey.png", "grey16.png"):
        with pytest.raises(DataFileError, match=r"expected an 8-bit RGB or RGBA PNG terrain tile "
                                                r"\(height_encoding='terrarium'\); got a greyscale \(.*without "
                                                r"height_encoding"):
            load_dem(tmp_path / name, height_encoding="terrarium")
    _png16_rgb(tmp_path / "deep.png", np.full((3, 3, 3), 40000, np.uint16))
    with pytest.raises(DataFileError, match=r"16 bits per channel"):
        load_dem(tmp_path / "deep.png", height_encoding="terrarium")
    Image.fromarray(rgb, "RGB").save(tmp_path / "lossy.png", format="JPEG")
    with pytest.raises(DataFileError, match=r"got a JPEG image under a \.png name"):
        load_dem(tmp_path / "lossy.png", height_encoding="terrarium")
    np.save(tmp_path / "z.npy", np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match=r"height_encoding applies to a local RGB PNG tile .*z\.npy' is no "
                                                r"PNG"):
        load_dem(tmp_path / "z.npy", height_encoding="terrarium")


def _tile(tmp_path) -> np.ndarray:
    heights = st.sample_dem().heights[::8, ::8][:40, :60]
    Image.fromarray(encode_terrarium(heights), "RGB").save(tmp_path / "tile.png")
    return heights


@needs_render
def test_cli_steps_renders_a_terrarium_tile(tmp_path, capsys):
    """`stepterrain steps tile.png --height-encoding terrarium --png out.png` renders the decoded tile."""
    _tile(tmp_path)
    code, _, err = run(capsys, "steps", tmp_path / "tile.png", "--height-encoding", "terrarium", "--png",
                       tmp_path / "out.png", "--size", "320x200", "-q")
    assert code == 0, err
    with Image.open(tmp_path / "out.png") as image:
        assert image.size == (320, 200)


def test_cli_steps_and_info_read_a_terrarium_tile(tmp_path, capsys):
    """`stepterrain steps tile.png --height-encoding terrarium -o out.glb` meshes the decoded tile, its terraces
    within its heights; `info` reads it as load_dem does; without the option the tile is refused naming it, an
    unknown name by argparse, and the option with the embedded DEM."""
    heights = _tile(tmp_path)
    code, _, err = run(capsys, "steps", tmp_path / "tile.png", "--height-encoding", "terrarium",
                       "-o", tmp_path / "out.glb", "-q")
    assert code == 0, err
    z = np.asarray(read_mesh(tmp_path / "out.glb").vertices)[:, 2]
    assert heights.min() - 1 <= z.min() and z.max() <= heights.max() + 1 and z.max() - z.min() > 100
    code, out, err = run(capsys, "info", tmp_path / "tile.png", "--height-encoding", "Terrarium", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["shape"] == [40, 60]
    code, _, err = run(capsys, "steps", tmp_path / "tile.png", "-o", tmp_path / "no.glb", "-q")
    assert code != 0 and "with its encoding named, --height-encoding 'terrain-rgb' or 'terrarium')" in err
    assert not (tmp_path / "no.glb").exists()
    code, _, err = run(capsys, "steps", tmp_path / "tile.png", "--height-encoding", "mapbox", "-o", tmp_path / "m.glb")
    assert code == 2 and "argument --height-encoding: expected one of terrain-rgb, terrarium; got 'mapbox'" in err
    code, _, err = run(capsys, "steps", "--height-encoding", "terrarium", "-o", tmp_path / "e.glb", "-q")
    assert code != 0 and "--height-encoding applies to an RGB PNG INPUT" in err


def test_batch_reads_a_folder_of_tiles_with_its_encoding(tmp_path, capsys):
    """batch's ``height_encoding`` (the CLI's --height-encoding) reaches every file: a folder of two Terrarium tiles
    gives meshes within their heights, recorded in the metadata; the same run resumed skips them, another encoding
    redoes them (the fingerprint holds it); an array source refuses it."""
    import trimesh

    from stepterrain.batch import batch

    folder = tmp_path / "tiles"
    folder.mkdir()
    heights = st.sample_dem().heights[::6, ::6][:30, :40]
    for k, z in enumerate((heights, heights + 250.0)):
        Image.fromarray(encode_terrarium(z), "RGB").save(folder / f"t{k}.png")
    out = tmp_path / "out"
    report = batch(folder, out, interval=50.0, scheduler="serial", format=".ply", height_encoding="terrarium")
    assert report.ok and len(report.done) == 2
    for r in report.done:
        zs = trimesh.load(r.path, process=False).vertices[:, 2]
        assert heights.min() - 1 <= zs.min() and zs.max() <= heights.max() + 251 and zs.max() - zs.min() > 100
    assert len(batch(folder, out, interval=50.0, scheduler="serial", format=".ply",
                     height_encoding="terrarium").skipped) == 2
    assert len(batch(folder, out, interval=50.0, scheduler="serial", format=".ply",
                     height_encoding="terrain-rgb").done) == 2  # other heights: redone
    with pytest.raises(InvalidInputError, match=r"height_encoding applies to RGB PNG tile files"):
        batch(heights, tmp_path / "a", tile_size=16, scheduler="serial", height_encoding="terrarium")
    code, _, err = run(capsys, "batch", folder, "-o", tmp_path / "cli", "--height-encoding", "terrarium",
                       "--scheduler", "serial", "-q")
    assert code == 0, err
    glb = sorted((tmp_path / "cli").glob("*.glb"))
    assert len(glb) == 2
    assert glb_json(glb[0])["meshes"][0]["extras"]["height_encoding"] == "terrarium"


def test_an_encoding_gives_metres_so_a_height_unit_is_refused_and_none_is_asked_for(tmp_path):
    """The encodings define metres: ``height_unit='ft'`` scaled the decoded metres by 0.3048 without a word (a tile
    of 500 m read as 152.4 m), and a tile placed in a CRS in feet was told to pass ``height_unit='US survey foot'``,
    which did so. A unit other than the metre is refused naming both arguments; the metre is taken; the Terrain's
    ``height_unit`` is "m", so no placement asks for a unit."""
    pytest.importorskip("rasterio")
    rgb = encode_terrarium(np.full((3, 4), 500.0))
    Image.fromarray(rgb, "RGB").save(tmp_path / "tile.png")
    with pytest.raises(InvalidInputError, match=r"height_unit applies to heights of no stated unit; "
                                                r"height_encoding='terrarium' gives metres; got height_unit='ft'"):
        load_dem(tmp_path / "tile.png", height_encoding="terrarium", height_unit="ft")
    metres = load_dem(tmp_path / "tile.png", height_encoding="terrarium", height_unit="metre")
    assert metres.height_unit == "m" and np.all(metres.heights == 500.0)
    assert load_dem(tmp_path / "tile.png", height_encoding="terrarium").height_unit == "m"
    (tmp_path / "tile.pgw").write_text("100\n0\n0\n-100\n6400000\n1900000\n")
    (tmp_path / "tile.prj").write_text("EPSG:2229")  # NAD83 / California zone 5 (US survey feet)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        terrain = load_dem(tmp_path / "tile.png", height_encoding="terrarium")
    assert not [w for w in caught if "height_unit" in str(w.message)], [str(w.message) for w in caught]
    assert terrain.crs == "EPSG:26945" and np.all(terrain.heights == 500.0)


def test_batch_refuses_a_height_unit_with_an_encoding_before_any_item(tmp_path):
    """batch(height_encoding=..., height_unit='ft') is refused up front, as load_dem refuses it, not item by item."""
    from stepterrain.batch import batch

    folder = tmp_path / "tiles"
    folder.mkdir()
    Image.fromarray(encode_terrarium(np.full((8, 8), 500.0) + np.arange(8)), "RGB").save(folder / "t.png")
    with pytest.raises(InvalidInputError, match=r"height_unit applies to heights of no stated unit; "
                                                r"height_encoding='terrarium' gives metres; got height_unit='ft'"):
        batch(folder, tmp_path / "out", interval=1.0, scheduler="serial", height_encoding="terrarium",
              height_unit="ft")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("sidecar", ["tile.pgw", "tile.PGW", "tile.prj"])
def test_a_changed_world_file_or_prj_beside_a_tile_redoes_its_batch_item(tmp_path, sidecar):
    """A terrain tile's world file and .prj place it (its origin, CRS): a batch resumed after either changed skipped
    the tile as complete, its mesh at the old place, as a GeoTIFF's changed sidecars redo its item."""
    from stepterrain.batch import batch

    folder = tmp_path / "tiles"
    folder.mkdir()
    heights = st.sample_dem().heights[:24, :32]
    Image.fromarray(encode_terrarium(heights), "RGB").save(folder / "tile.png")
    world = folder / (sidecar if sidecar != "tile.prj" else "tile.pgw")
    world.write_text("30\n0\n0\n-30\n380015\n3800985\n")
    (folder / "tile.prj").write_text("EPSG:32611")
    kwargs = dict(interval=50.0, scheduler="serial", format=".ply", height_encoding="terrarium")
    assert len(batch(folder, tmp_path / "out", **kwargs).done) == 1
    assert len(batch(folder, tmp_path / "out", **kwargs).skipped) == 1
    if sidecar == "tile.prj":
        (folder / "tile.prj").write_text("EPSG:32610")
    else:
        world.write_text("30\n0\n0\n-30\n390015\n3800985\n")
    assert len(batch(folder, tmp_path / "out", **kwargs).done) == 1


def test_cli_batch_height_encoding_every_file_refuses_is_one_usage_error(tmp_path, capsys):
    """`batch FOLDER --height-encoding terrarium` over a folder with no PNG failed every item alike (exit 1, the same
    refusal once per file); as --band every file refuses, it is one usage error (exit 2) naming the option."""
    folder = tmp_path / "dems"
    folder.mkdir()
    for k in range(3):
        np.save(folder / f"d{k}.npy", st.sample_dem().heights[:20, :20] + k)
    code, _, err = run(capsys, "batch", folder, "-o", tmp_path / "out", "--height-encoding", "terrarium",
                       "--scheduler", "serial", "-q")
    assert code == 2, err
    assert err.count("applies to") == 1
    assert ("--height-encoding terrarium applies to RGB PNG terrain tiles; all 3 inputs are no PNG (e.g. d0: "
            in err and ": leave --height-encoding out" in err), err


@pytest.mark.parametrize("encoding", list(HEIGHT_ENCODINGS))
@pytest.mark.parametrize("mode", ["RGB", "RGBA"])
def test_the_documented_peak_of_a_tile_read_holds(tmp_path, encoding, mode):
    """load_dem's budget check counts the float32 heights a tile keeps (4 bytes a cell); its docstring states what the
    read allocates at its peak beyond that: about 17 bytes a cell for a terrain tile (45 when three int64 channels and
    their float64 sums were decoded). Measured with tracemalloc (numpy's allocations), as a GeoTIFF's read is."""
    import tracemalloc

    rows, cols = 300, 200
    rng = np.random.default_rng(3)
    pixels = rng.integers(0, 256, (rows, cols, 4), dtype=np.uint8)
    pixels[..., 0] = rng.integers(0, 2, (rows, cols))  # heights within float32's reach either way
    pixels[..., 3] = 255
    pixels[0, 0, 3] = 0
    Image.fromarray(pixels if mode == "RGBA" else pixels[..., :3].copy(), mode).save(tmp_path / "tile.png")
    expected = load_dem(tmp_path / "tile.png", height_encoding=encoding).heights  # imports and caches outside it
    tracemalloc.start()
    try:
        terrain = load_dem(tmp_path / "tile.png", height_encoding=encoding)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(terrain.heights, expected)
    assert peak <= 17.5 * rows * cols, peak / (rows * cols)


def test_a_tiles_aux_xml_georeferencing_warning_gives_advice_that_reads(tmp_path):
    """A terrain tile placed by a tile.png.aux.xml alone (no world file) is read unreferenced, warned; the warning told
    a greyscale heightmap's way out, `gdal_translate tile.png tile.tif`, whose RGB GeoTIFF load_dem refuses (colour
    bands, and height_encoding is for PNGs): it names a world file, which places the tile."""
    Image.fromarray(encode_terrarium(np.full((4, 5), 800.0)), "RGB").save(tmp_path / "tile.png")
    (tmp_path / "tile.png.aux.xml").write_text(
        "<PAMDataset><GeoTransform>380000, 30, 0, 3800000, 0, -30</GeoTransform></PAMDataset>")
    with pytest.warns(UserWarning, match=r"tile\.png\.aux\.xml is not read") as caught:
        terrain = load_dem(tmp_path / "tile.png", height_encoding="terrarium")
    assert terrain.origin == (0.0, 0.0)
    message = " ".join(str(w.message) for w in caught)
    assert "GeoTIFF" not in message and "-co WORLDFILE=YES" in message, message
    (tmp_path / "placed.wld").write_text("30\n0\n0\n-30\n380015\n3799985\n")  # what that command writes
    (tmp_path / "tile.png").rename(tmp_path / "placed.png")
    assert load_dem(tmp_path / "placed.png", height_encoding="terrarium").origin == (380015.0, 3799985.0)


def test_a_grey_and_alpha_png_is_refused_as_what_it_is(tmp_path):
    """With an encoding, an 8-bit grey + alpha PNG is refused as greyscale (LA), a 16-bit one (read by Pillow as RGBA
    from its rawmode LA;16B) as 16-bit grey + alpha: the 8-bit one was called 16-bit too."""
    grey = np.stack([np.full((3, 4), 90, np.uint8), np.full((3, 4), 255, np.uint8)], axis=-1)
    Image.fromarray(grey, "LA").save(tmp_path / "la8.png")
    with pytest.raises(DataFileError, match=r"terrain tile \(height_encoding='terrarium'\); got a greyscale \(LA\) "
                                            r"image"):
        load_dem(tmp_path / "la8.png", height_encoding="terrarium")
    h, w = 3, 4
    raw = b"".join(b"\0" + np.full((w, 2), 40000, ">u2").tobytes() for _ in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    (tmp_path / "la16.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 4, 0,
                                                                                       0, 0))
                                       + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))
    with pytest.raises(DataFileError, match=r"got a 16-bit greyscale \+ alpha image"):
        load_dem(tmp_path / "la16.png", height_encoding="terrarium")
