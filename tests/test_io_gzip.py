"""Single-file gzip DEMs given as local files: SRTM tiles as AWS Terrain Tiles serve them (``N40W106.hgt.gz``) and
``dem.tif.gz``/``dem.asc.gz`` downloads. They were refused as "unknown DEM extension '.gz'" by load_dem, the CLI and
batch (a folder of .hgt.gz tiles held "no DEM file"); they are read as the file inside, through GDAL's /vsigzip/."""

from __future__ import annotations

import gzip
import os
import warnings

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import DataFileError, InvalidInputError

from .conftest import SHARED_DATA
from .conftest import run_cli as run

rasterio = pytest.importorskip("rasterio")
from affine import Affine  # noqa: E402
from rasterio.io import MemoryFile  # noqa: E402
from rasterio.shutil import copy as gdal_copy  # noqa: E402

_FRONT_RANGE = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
_TUJUNGA = SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif"


def _gz(path, folder=None):
    """A gzip copy of ``path`` (in ``folder``, else beside it): ``path.gz``."""
    out = (folder or path.parent) / (path.name + ".gz")
    out.write_bytes(gzip.compress(path.read_bytes()))
    return out


def _hgt_tiles(folder):
    """The two real SRTM GL3 tiles the Front Range DEM of shared/data covers, N39W106.hgt and N40W106.hgt, written by
    GDAL's SRTMHGT driver (as gdal_translate -of SRTMHGT writes them) from the DEM placed on their 3 arc-second
    nodes, -32768 voids elsewhere; the tiles share the row of 40 N."""
    with rasterio.open(_FRONT_RANGE) as source:
        data = source.read(1)
    tiles = []
    for name, lat0, rows, part in (("N39W106", 39, slice(0, 199), data[559:758]),
                                   ("N40W106", 40, slice(641, 1201), data[0:560])):
        tile = np.full((1201, 1201), -32768, np.int16)
        tile[rows, 221:979] = part
        h = 1 / 1200
        with MemoryFile() as memory:
            with memory.open(driver="GTiff", width=1201, height=1201, count=1, dtype="int16", crs="EPSG:4326",
                             transform=Affine(h, 0.0, -106 - h / 2, 0.0, -h, lat0 + 1 + h / 2), nodata=-32768) as ds:
                ds.write(tile, 1)
            gdal_copy(memory.name, folder / f"{name}.hgt", driver="SRTMHGT")
        tiles.append(folder / f"{name}.hgt")
    return tiles


@pytest.fixture(scope="module")
def hgt(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hgt")
    plain, gz = folder / "plain", folder / "gz"
    plain.mkdir()
    gz.mkdir()
    tiles = _hgt_tiles(plain)
    for tile in tiles:
        _gz(tile, gz)
    return plain, gz


def _same(a, b):
    assert a.shape == b.shape and a.spacing == b.spacing and a.origin == b.origin and a.crs == b.crs
    assert a.source == b.source
    np.testing.assert_array_equal(a.heights, b.heights)


def test_an_hgt_gz_tile_is_read_as_the_tile_placed_by_its_name_and_cropped(hgt):
    plain, gz = hgt
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a 1-degree tile's local-metres warning, the plain file's too
        reference = st.load_dem(plain / "N40W106.hgt")
        terrain = st.load_dem(gz / "N40W106.hgt.gz")
        _same(terrain, reference)
        assert terrain.source.startswith("N40W106.hgt (")  # placed by its name: node (0, 0) at 106 W, 41 N
        assert "lon -106.000000000, lat 41.000000000" in terrain.source
        assert np.isnan(terrain.heights).sum() == 1201 * 1201 - 560 * 758  # -32768 voids are nodata
        x0, _, _, y1 = reference.extent
        box = (x0 + 20000, x0 + 40000, y1 - 70000, y1 - 50000)
        _same(st.load_dem(str(gz / "N40W106.hgt.gz"), crop=box), st.load_dem(plain / "N40W106.hgt", crop=box))
    # GDAL wrote the stream's size to a 'N40W106.hgt.gz.properties' beside the user's file: nothing is written
    assert sorted(p.name for p in gz.iterdir()) == ["N39W106.hgt.gz", "N40W106.hgt.gz"]


def test_a_tif_gz_and_an_asc_gz_with_its_prj_beside_read_as_the_plain_files(tmp_path):
    tif = _gz(_TUJUNGA, tmp_path)
    _same(st.load_dem(tif), st.load_dem(_TUJUNGA))
    # an ESRI ASCII grid takes its CRS from the .prj beside it: dem.prj beside dem.asc.gz, as beside dem.asc
    asc = tmp_path / "front.asc"
    gdal_copy(str(_FRONT_RANGE), str(asc), driver="AAIGrid")
    assert (tmp_path / "front.prj").is_file()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reference = st.load_dem(asc)
        gz = _gz(asc)
        asc.unlink()
        terrain = st.load_dem(gz)
        # the same grid and WGS 84 degrees; GDAL names the plain grid's .prj OGC:CRS84 (its ESRI import), load_dem
        # the gzip's EPSG:4326 (read by prj_crs, as beside a TIFF)
        assert (terrain.shape, terrain.spacing, terrain.origin, terrain.crs) == (
            reference.shape, reference.spacing, reference.origin, reference.crs)
        np.testing.assert_array_equal(terrain.heights, reference.heights)
        assert "(OGC:CRS84 degrees as local metres" in reference.source
        assert "(EPSG:4326 degrees as local metres" in terrain.source
        (tmp_path / "front.prj").unlink()  # without it: no CRS, its degrees read as metres (as the plain .asc's)
        assert st.load_dem(gz).crs is None


def test_a_world_file_beside_a_gzipped_tiff_without_georeferencing_is_refused(tmp_path):
    """GDAL reads no file beside a gzip: dem.tif.gz with dem.tfw beside was read as 1 m cells at (0, 0)."""
    z = (np.arange(12.0).reshape(3, 4) * 10 + 3000).astype(np.int16)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning
        with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=4, height=3, count=1,
                           dtype="int16") as ds:
            ds.write(z, 1)
    gz = _gz(tmp_path / "dem.tif")
    (tmp_path / "dem.tif").unlink()
    assert st.load_dem(gz).origin == (0.0, 0.0)  # no world file: a plain grid, as the plain TIFF
    (tmp_path / "dem.tfw").write_text("100.0\n0.0\n0.0\n-100.0\n500050.0\n4000050.0\n")
    with pytest.raises(DataFileError, match=r"dem\.tif\.gz.*no world file beside a gzip: 'dem\.tfw'.*gunzip -k"):
        st.load_dem(gz)


def test_a_cut_short_or_corrupt_gzip_is_refused_not_read_in_part(hgt, tmp_path):
    data = (hgt[1] / "N39W106.hgt.gz").read_bytes()
    cut = tmp_path / "N39W106.hgt.gz"
    cut.write_bytes(data[: len(data) - 9])  # its last block and trailer lost
    with pytest.raises(DataFileError, match=r"N39W106\.hgt\.gz': expected a whole gzip file of an SRTM tile "
                                            r"\(\.hgt\); it is cut short"):
        st.load_dem(cut)
    # one byte of the stored heights changed (a stored deflate block): the CRC-32 no longer matches
    raw = bytearray(gzip.compress(_TUJUNGA.read_bytes(), compresslevel=0))
    raw[len(raw) // 2] ^= 0xFF
    bad = tmp_path / "dem.tif.gz"
    bad.write_bytes(bytes(raw))
    with pytest.raises(DataFileError, match=r"dem\.tif\.gz': expected a whole gzip file of a GeoTIFF; it is corrupt"):
        st.load_dem(bad)
    with pytest.raises(DataFileError, match=r"dem\.tif\.gz': expected a whole gzip file"):
        st.load_dem(bad, crop=(0, 1, 0, 1))  # a window before the damage was read unchecked
    notgz = tmp_path / "plain.tif.gz"
    notgz.write_bytes(_TUJUNGA.read_bytes())
    with pytest.raises(DataFileError, match=r"plain\.tif\.gz'.*it is corrupt or no gzip"):
        st.load_dem(notgz)
    with pytest.raises(DataFileError, match=r"missing\.hgt\.gz' does not exist"):
        st.load_dem(tmp_path / "missing.hgt.gz")


@pytest.mark.parametrize(("name", "said"), [
    ("dem.npy.gz", r"\.npy files are read uncompressed only: gunzip it first"),
    ("dem.bil.gz", r"\.bil files are read uncompressed only \(GDAL reads no \.hdr beside a gzip\)"),
    ("tiles.tar.gz", r"a tar archive: name the file inside it, '/vsitar/"),
    ("notes.txt.gz", r"unknown DEM extension '\.txt' of the file inside, 'notes\.txt'"),
])
def test_a_gzip_of_another_file_is_refused_naming_what_is_read(tmp_path, name, said):
    path = tmp_path / name
    path.write_bytes(gzip.compress(b"x"))
    with pytest.raises(InvalidInputError, match=r"a \.gz is read as the raster it compresses, one of \.tif\.gz, "
                                                r".*\.hgt\.gz.*; " + said):
        st.load_dem(path)


# ------------------------------------------------------------------------------------------ batch and CLI
def test_batch_of_a_folder_of_hgt_gz_tiles_places_them_as_the_plain_tiles(hgt, tmp_path):
    """A folder of .hgt.gz tiles (as AWS Terrain Tiles serve them) held "no DEM file": its tiles are items named as
    the tiles (N39W106.ply), placed side by side in their mosaic's local metres as the plain tiles are."""
    import trimesh

    from stepterrain.batch import batch

    plain, gz = hgt
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = batch(plain, tmp_path / "plain", interval=500, format=".ply", scheduler="serial")
        got = batch(gz, tmp_path / "gz", interval=500, format=".ply", scheduler="serial")
    assert ref.ok and got.ok, got.summary()
    names = sorted(p.name for p in (tmp_path / "gz").iterdir() if p.suffix == ".ply")
    assert names == ["N39W106.ply", "N40W106.ply"]
    for name in names:
        a = trimesh.load(tmp_path / "plain" / name, process=False)
        b = trimesh.load(tmp_path / "gz" / name, process=False)
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.faces, b.faces)
    # a rerun keeps both; a tile's .gz rewritten (its fingerprint stats the .gz) redoes that one only
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again = batch(gz, tmp_path / "gz", interval=500, format=".ply", scheduler="serial")
        assert len(again.skipped) == 2 and not again.done
        st_ = os.stat(gz / "N40W106.hgt.gz")
        os.utime(gz / "N40W106.hgt.gz", ns=(st_.st_atime_ns, st_.st_mtime_ns + 1_000_000_000))
        redone = batch(gz, tmp_path / "gz", interval=500, format=".ply", scheduler="serial")
    assert [r.key for r in redone.done] == ["N40W106"] and len(redone.skipped) == 1


def test_a_gz_tile_fingerprint_holds_the_prj_beside_it(tmp_path):
    from stepterrain.batch import _file_identity

    gz = _gz(_TUJUNGA, tmp_path)
    before = _file_identity(str(gz), {})
    (tmp_path / "big_tujunga_srtm_30m_utm11n.prj").write_text("x")
    assert _file_identity(str(gz), {}) != before  # the .prj load_dem reads beside it: rewritten, item redone


def test_cli_info_steps_and_batch_read_an_hgt_gz(hgt, tmp_path, capsys):
    plain, gz = hgt
    tile = gz / "N39W106.hgt.gz"
    code, out, err = run(capsys, "info", tile)
    assert code == 0, err
    assert "N39W106.hgt" in out
    code, _, err = run(capsys, "steps", tile, "--interval", "500", "-o", tmp_path / "gz.ply")
    assert code == 0, err
    code, _, err = run(capsys, "steps", plain / "N39W106.hgt", "--interval", "500", "-o", tmp_path / "plain.ply")
    assert code == 0, err
    import trimesh

    a, b = trimesh.load(tmp_path / "gz.ply", process=False), trimesh.load(tmp_path / "plain.ply", process=False)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    code, _, err = run(capsys, "batch", tile, "--interval", "500", "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["N39W106.glb", "stepterrain-batch.json"]
    bad = tmp_path / "dem.npy.gz"
    bad.write_bytes(gzip.compress(b"x"))
    code, _, err = run(capsys, "steps", bad, "-o", tmp_path / "x.ply")
    assert code != 0 and "gunzip it first" in err and "Traceback" not in err


def test_cli_globe_reads_a_gzip_of_a_raster_in_degrees(tmp_path, capsys):
    """load_dem reads a local .tif.gz, and the globe reads a raster as load_dem does: it refused g.tif.gz as "INPUT
    must be a .npz ... or a raster in degrees"; it gives the mesh of g.tif. A gzip of an .npz is refused (gunzip it)."""
    import trimesh

    z = (np.add.outer(np.arange(18), np.arange(36)) % 50 * 100).astype(np.float32)
    tif = tmp_path / "g.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=36, height=18, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(10.0, 0.0, 0.0, 0.0, -10.0, 90.0)) as ds:
        ds.write(z, 1)
    gz = _gz(tif)
    meshes = []
    for source in (tif, gz):
        out = tmp_path / f"{source.name}.ply"
        code, _, err = run(capsys, "-q", "globe", source, "--face-size", "9", "--no-camera", "--error", "0", "-o", out)
        assert code == 0, err
        meshes.append(trimesh.load(out, process=False))
    np.testing.assert_array_equal(meshes[0].vertices, meshes[1].vertices)
    np.testing.assert_array_equal(meshes[0].faces, meshes[1].faces)
    npz = tmp_path / "grid.npz.gz"
    npz.write_bytes(gzip.compress(b"x"))
    code, _, err = run(capsys, "globe", npz, "--face-size", "9", "-o", tmp_path / "x.glb")
    assert code == 2 and ".npz files are read uncompressed only: gunzip it first" in err, err
