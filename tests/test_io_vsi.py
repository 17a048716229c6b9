"""DEMs read through GDAL's virtual file systems, as a GIS user names them to every GDAL tool: a zip of SRTM tiles
(``/vsizip/srtm.zip/N39W106.hgt``, or the ``.zip`` itself when it holds one raster), a gzip (``/vsigzip/``) and a
URL (``https://``, mapped to ``/vsicurl/``). They were refused as "does not exist" before rasterio saw the path."""

from __future__ import annotations

import gzip
import json
import os
import re
import time
import warnings
import zipfile

import numpy as np
import pytest

import stepterrain as st
from stepterrain._files import gdal_path
from stepterrain.errors import DataFileError, InvalidInputError

from .conftest import SHARED_DATA
from .conftest import run_cli as run

rasterio = pytest.importorskip("rasterio")
from affine import Affine  # noqa: E402

_FRONT_RANGE = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"


def _geotiff(path, terrain):
    """``terrain`` (a grid) written as the GeoTIFF load_dem reads back as it: node (0, 0) at the top-left cell's
    centre."""
    (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
    h = terrain.heights
    with rasterio.open(path, "w", driver="GTiff", height=h.shape[0], width=h.shape[1], count=1, dtype="float32",
                       crs=terrain.crs, transform=Affine(dx, 0.0, x0 - dx / 2, 0.0, dy, y0 - dy / 2),
                       nodata=np.nan) as out:
        out.write(h, 1)
    return path


@pytest.fixture(scope="module")
def tiles(tmp_path_factory):
    """The sample DEM (coarsened 4 x 4, for speed) as dem.tif, zipped alone (one.zip), beside a second raster
    (two.zip) and gzipped (dem.tif.gz)."""
    folder = tmp_path_factory.mktemp("vsi")
    tif = _geotiff(folder / "dem.tif", st.sample_dem().coarsen(4))
    with zipfile.ZipFile(folder / "one.zip", "w", zipfile.ZIP_DEFLATED) as archive:
        archive.write(tif, "dem.tif")
    with zipfile.ZipFile(folder / "two.zip", "w") as archive:
        archive.write(tif, "dem.tif")
        archive.write(tif, "west/b.tif")
    with zipfile.ZipFile(folder / "readme.zip", "w") as archive:
        archive.writestr("README.txt", "no raster here")
    (folder / "dem.tif.gz").write_bytes(gzip.compress(tif.read_bytes()))
    return folder


def _same(a, b):
    assert a.shape == b.shape and a.spacing == b.spacing and a.origin == b.origin and a.crs == b.crs
    np.testing.assert_array_equal(a.heights, b.heights)


def test_vsizip_vsigzip_and_a_zip_of_one_raster_read_as_the_geotiff(tiles, monkeypatch):
    reference = st.load_dem(tiles / "dem.tif")
    absolute = f"/vsizip/{tiles / 'one.zip'}/dem.tif"
    assert absolute.startswith("/vsizip//")  # GDAL's absolute form, which a Path would turn into a relative one
    for given in (absolute, tiles / "one.zip", str(tiles / "one.zip"), f"/vsigzip/{tiles / 'dem.tif.gz'}"):
        terrain = st.load_dem(given)
        _same(terrain, reference)
        assert terrain.source == "dem.tif"  # the file inside, as the plain file's
    monkeypatch.chdir(tiles)  # a relative path inside /vsizip/, as GDAL reads it
    _same(st.load_dem("/vsizip/one.zip/dem.tif"), reference)
    _same(st.load_dem("one.zip", crop=(reference.origin[0], reference.origin[0] + 600, reference.origin[1] - 600,
                                       reference.origin[1])),
          reference.crop((reference.origin[0], reference.origin[0] + 600, reference.origin[1] - 600,
                          reference.origin[1])))


def _srtm_tile(folder):
    """A real SRTM GL3 tile, N39W106.hgt (1201 x 1201 big-endian int16, -32768 voids): the Front Range DEM of
    shared/data placed at its cells (its nodes lie on the tile's 3 arc-second nodes), voids elsewhere, and the tile
    as a download zips it (N39W106.SRTMGL3.hgt.zip)."""
    with rasterio.open(_FRONT_RANGE) as source:
        data = source.read(1)
        lon, lat = source.xy(559, 0)  # the first row at or below 40 N
    row, col = round((40 - lat) * 1200), round((lon + 106) * 1200)
    assert (row, col) == (0, 221)
    tile = np.full((1201, 1201), -32768, ">i2")
    tile[0:199, 221:979] = data[559:758, :]
    hgt = folder / "N39W106.hgt"
    tile.tofile(hgt)
    archive = folder / "N39W106.SRTMGL3.hgt.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as out:
        out.write(hgt, "N39W106.hgt")
    return hgt, archive, data[559:758, :]


def test_srtm_hgt_in_a_zip_is_placed_by_its_name_with_voids(tmp_path):
    hgt, archive, covered = _srtm_tile(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a 1-degree tile's local-metres warning, the plain file's too
        reference = st.load_dem(hgt)
        for given in (archive, f"/vsizip/{archive}/N39W106.hgt"):
            terrain = st.load_dem(given)
            _same(terrain, reference)
            assert terrain.source.startswith("N39W106.hgt")  # placed by its name: node (0, 0) at 106 W, 40 N
            assert "lon -106.000000000, lat 40.000000000" in terrain.source
            assert np.isnan(terrain.heights).sum() == 1201 * 1201 - covered.size  # -32768 voids are nodata
            np.testing.assert_array_equal(terrain.heights[0:199, 221:979], covered.astype(np.float32))


def test_zip_of_several_rasters_or_none_and_a_missing_inner_file_are_refused(tiles):
    with pytest.raises(DataFileError, match=r"two\.zip.*2 rasters: 'dem\.tif', 'west/b\.tif'.*/vsizip/"):
        st.load_dem(tiles / "two.zip")
    with pytest.raises(DataFileError, match=r"readme\.zip.*no raster.*'README\.txt'"):
        st.load_dem(tiles / "readme.zip")
    missing = f"/vsizip/{tiles / 'one.zip'}/N46E007.hgt"
    with pytest.raises(DataFileError, match=rf"cannot read '{missing}': GDAL cannot open it .*does not exist"):
        st.load_dem(missing)
    with pytest.raises(InvalidInputError, match=r"name the file inside the zip"):
        st.load_dem(f"/vsizip/{tiles / 'one.zip'}")
    with pytest.raises(InvalidInputError, match=r"/vsizip/.*\.npy files are read from a local file only"):
        st.load_dem(f"/vsizip/{tiles / 'one.zip'}/dem.npy")


def test_a_zip_or_gzip_behind_another_file_system_is_refused_naming_a_path_that_reads_it(tiles, tmp_path):
    """A zip named by a URL or through another file system (/vsis3/, /vsitar/) was refused with the advice to name
    the file inside it as '<that path>/dem.tif': https://host/srtm.zip/dem.tif, which asks the server for a file of
    that name (GDAL opens a zip's member only through /vsizip/ chained to the zip's path), and a .tif.gz URL was "an
    unknown extension '.gz'". The advice is the chained path now, /vsizip//vsicurl/https://... (a zip in a zip in
    GDAL's braces) and /vsigzip//vsicurl/...: here, through a local tar, the paths it names read the DEM."""
    import tarfile

    reference = st.load_dem(tiles / "dem.tif")
    pack = tmp_path / "pack.tar"
    with tarfile.open(pack, "w") as archive:
        archive.add(tiles / "one.zip", "one.zip")
        archive.add(tiles / "dem.tif.gz", "dem.tif.gz")
    with zipfile.ZipFile(tmp_path / "outer.zip", "w") as archive:
        archive.write(tiles / "one.zip", "one.zip")

    def advice(path):
        with pytest.raises(InvalidInputError) as caught:
            st.load_dem(path)
        return re.search(r"name the file inside the zip: '([^']*)'|through /vsigzip/: '([^']*)'$", str(caught.value))

    outer = tmp_path / "outer.zip"
    for given, hinted in [
        (f"/vsitar/{pack}/one.zip", f"/vsizip//vsitar/{pack}/one.zip/<name>.tif"),
        (f"/vsizip/{outer}/one.zip", f"/vsizip/{{/vsizip/{outer}/one.zip}}/<name>.tif"),
        (f"/vsitar/{pack}/dem.tif.gz", f"/vsigzip//vsitar/{pack}/dem.tif.gz"),
    ]:
        found = advice(given)
        assert found and (found.group(1) or found.group(2)) == hinted, (given, found)
        _same(st.load_dem(hinted.replace("<name>", "dem")), reference)
    assert advice("https://example.org/srtm.zip").group(1) == "/vsizip//vsicurl/https://example.org/srtm.zip/<name>.tif"
    assert advice("s3://bucket/dem.tif.gz").group(2) == "/vsigzip//vsis3/bucket/dem.tif.gz"
    signed = advice("https://example.org/srtm.zip?sig=1").group(1)  # no '.zip/' for GDAL to split at: in braces
    assert signed == "/vsizip/{/vsicurl/https://example.org/srtm.zip?sig=1}/<name>.tif"
    assert gdal_path(signed.replace("<name>", "dem")).name == "dem.tif"  # read as the member, not refused as a zip
    assert advice(f"/vsizip/{tiles / 'one.zip'}").group(1) == f"/vsizip/{tiles / 'one.zip'}/<name>.tif"  # as before


def test_a_zip_opened_by_vsizip_without_its_member_is_refused_naming_a_path_that_reads_it(tiles):
    """A zip given to /vsizip/ without the member to read was refused with a path that reads nothing when the zip
    was a signed URL's (/vsizip//vsicurl/https://host/a.zip?sig=1, or in GDAL's braces, as the refusal of the URL
    itself advises): the advice wrapped it in a further /vsizip/{...}, a zip inside the zip; and a local zip in braces
    (/vsizip/{/data/one.zip}) was named 'one.zip}', refused as "unknown DEM extension '.zip}'". Each is advised the
    zip's own path with the member after it now, which reads the DEM for the local one."""
    one = tiles / "one.zip"

    def advice(path):
        with pytest.raises(InvalidInputError) as caught:
            st.load_dem(path)
        return re.search(r"name the file inside the zip: '([^']*)'", str(caught.value)).group(1)

    signed = "/vsizip/{/vsicurl/https://example.org/a.zip?sig=1}/<name>.tif"
    assert advice("/vsizip//vsicurl/https://example.org/a.zip?sig=1") == signed
    assert advice("/vsizip/{/vsicurl/https://example.org/a.zip?sig=1}") == signed
    assert advice(f"/vsizip/{{{one}}}") == f"/vsizip/{one}/<name>.tif"
    _same(st.load_dem(advice(f"/vsizip/{{{one}}}").replace("<name>", "dem")), st.load_dem(tiles / "dem.tif"))


def test_a_zip_opened_by_vsizip_with_a_trailing_slash_is_advised_as_without_it(tiles):
    """A zip given to /vsizip/ with a trailing slash and no member was refused as "unknown DEM extension '(none)' of
    ''" in GDAL's braces (/vsizip/{/data/one.zip}/: named by the empty member after them), and advised a zip inside
    the zip without them (/vsizip/{/vsizip//data/one.zip/}/<name>.tif: its '.zip/' taken for a member's path). Both
    are advised the path /vsizip//data/one.zip is, which reads the DEM."""
    one = tiles / "one.zip"
    reference = st.load_dem(tiles / "dem.tif")

    def advice(path):
        with pytest.raises(InvalidInputError) as caught:
            st.load_dem(path)
        found = re.search(r"name the file inside the zip: '([^']*)'", str(caught.value))
        assert found, str(caught.value)
        return found.group(1)

    expected = advice(f"/vsizip/{one}")
    assert expected == f"/vsizip/{one}/<name>.tif"
    for given in (f"/vsizip/{{{one}}}/", f"/vsizip/{one}/", f"/vsizip/{{{one}}}//"):
        assert advice(given) == expected, given
    _same(st.load_dem(expected.replace("<name>", "dem")), reference)


def test_a_brace_in_a_vsicurl_urls_query_is_no_archives():
    """A /vsicurl/ URL whose query holds a brace (a token, ?t={abc}&x=1) was named by what followed the last brace,
    '&x=1', as if the brace closed GDAL's braces round an archive (/vsizip/{...}/dem.tif), and refused as an unknown
    extension, while the same URL given as https://... read as cog.tif. Only braces right after an archive's file
    system round an archive's path."""
    for given in ("/vsicurl/https://example.org/dem/cog.tif?t={abc}&x=1", "https://example.org/dem/cog.tif?t={abc}&x=1"):
        assert gdal_path(given).name == "cog.tif", given
    assert gdal_path("/vsizip/{/vsicurl/https://example.org/a.zip?t={abc}&x=1}/dem.tif").name == "dem.tif"


def test_a_braced_archive_path_is_resolved_for_a_worker_and_its_fingerprint(tiles, tmp_path, monkeypatch):
    """GDAL's braces round an archive's path (/vsizip/{one.zip}/dem.tif; a zip in a zip,
    /vsizip/{/vsizip//data/outer.zip/one.zip}/dem.tif) were read as part of a local archive's name: a worker in
    another folder was given /vsizip//caller/{/vsizip/.../dem.tif, which names nothing, and the fingerprint stat'ed a
    file '{/vsizip/...' that is not there. A braced local archive is resolved as an unbraced one is; one reached
    through another file system is left as given."""
    from stepterrain._files import local_archive
    from stepterrain.batch import _on_worker

    reference = st.load_dem(tiles / "dem.tif")
    with zipfile.ZipFile(tmp_path / "outer.zip", "w") as archive:
        archive.write(tiles / "one.zip", "one.zip")
    nested = f"/vsizip/{{/vsizip/{tmp_path / 'outer.zip'}/one.zip}}/dem.tif"
    assert local_archive(gdal_path(nested)) is None
    assert local_archive(gdal_path(f"/vsizip/{{{tiles / 'one.zip'}}}/dem.tif")) == str(tiles / "one.zip")
    elsewhere = tmp_path / "worker"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert _on_worker(nested, str(tiles)) == nested
    _same(st.load_dem(_on_worker(nested, str(tiles))), reference)
    _same(st.load_dem(_on_worker("/vsizip/{one.zip}/dem.tif", str(tiles))), reference)
    # a signed URL's zip, as the refusal names it: read as its member (its name was the URL's, 'a.zip', refused)
    signed = gdal_path("/vsizip/{/vsicurl/https://example.org/a.zip?sig=1}/N46E007.hgt")
    assert (signed.name, os.fspath(signed)) == ("N46E007.hgt", "/vsizip/{/vsicurl/https://example.org/a.zip?sig=1}"
                                                               "/N46E007.hgt")


def test_a_braced_zip_path_reads_the_prj_beside_its_tiff_in_the_zip(tmp_path):
    """A world-file TIFF's .prj inside a zip gives its CRS (GDAL reads none for a TIFF): named with GDAL's braces,
    /vsizip/{site.zip}/dem.tif, the member was looked up as '}/dem.tif' and the CRS was lost (feet read as metres)."""
    from rasterio.crs import CRS

    z = (np.arange(12.0).reshape(3, 4) * 10 + 3000).astype(np.int16)
    tif = tmp_path / "dem.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning for the bare TIFF
        with rasterio.open(tif, "w", driver="GTiff", width=4, height=3, count=1, dtype="int16") as ds:
            ds.write(z, 1)
    tif.with_suffix(".tfw").write_text("100.0\n0.0\n0.0\n-100.0\n6400050.0\n1899950.0\n")
    tif.with_suffix(".prj").write_text(CRS.from_epsg(2229).to_wkt())
    with zipfile.ZipFile(tmp_path / "site.zip", "w") as archive:
        for name in ("dem.tif", "dem.tfw", "dem.prj"):
            archive.write(tmp_path / name, name)
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        local = st.load_dem(tif)
    for given in (f"/vsizip/{tmp_path / 'site.zip'}/dem.tif", f"/vsizip/{{{tmp_path / 'site.zip'}}}/dem.tif"):
        with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
            _same(st.load_dem(given), local)


def test_url_is_read_by_gdal_and_an_unreachable_one_is_a_data_file_error(monkeypatch):
    assert os.fspath(gdal_path("https://example.org/dem/cog.tif?sig=1")) == "/vsicurl/https://example.org/dem/cog.tif?sig=1"
    assert gdal_path("https://example.org/dem/cog.tif?sig=1").name == "cog.tif"
    assert os.fspath(gdal_path("s3://bucket/srtm/N46E007.hgt")) == "/vsis3/bucket/srtm/N46E007.hgt"
    assert os.fspath(gdal_path("gs://bucket/dem.tif")) == "/vsigs/bucket/dem.tif"
    assert gdal_path("dem.tif") is None and gdal_path("/data/dem.tif") is None
    with pytest.raises(DataFileError, match=r"unknown URL scheme 'gopher://'"):
        gdal_path("gopher://host/dem.tif")
    monkeypatch.setenv("GDAL_HTTP_TIMEOUT", "5")  # nothing listens on port 9: refused at once, never a hang
    monkeypatch.setenv("GDAL_HTTP_CONNECTTIMEOUT", "5")
    start = time.monotonic()
    with pytest.raises(DataFileError, match=r"cannot read 'http://127\.0\.0\.1:9/x\.tif' \(GDAL path "
                                            r"'/vsicurl/http://127\.0\.0\.1:9/x\.tif'\): GDAL cannot open it"):
        st.load_dem("http://127.0.0.1:9/x.tif")
    assert time.monotonic() - start < 30


def test_a_file_url_is_refused_naming_the_path_to_give(tiles, capsys):
    """A file:// URL was let through as a local path, which a Path made 'file:/...': "DEM file 'file:/tmp/.../dem.tif'
    does not exist" of a file that exists. It is refused naming the path to give, by load_dem, batch and the CLI."""
    url = (tiles / "dem.tif").as_uri()
    said = re.escape(f"cannot read '{url}': a file:// URL names a local file; give its path, '{tiles / 'dem.tif'}'")
    with pytest.raises(DataFileError, match=said):
        st.load_dem(url)
    with pytest.raises(DataFileError, match=said):
        st.batch.plan_items([url])
    code, _, err = run(capsys, "info", url)
    assert code == 2 and f"cannot read '{url}': a file:// URL names a local file" in err


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_a_gdal_path_pickled_or_copied_reads_the_same_file(tiles, how):
    """A GdalPath pickles (a dask worker's argument) and copies as a Path does, by its parts: its GDAL path and the
    text as given were lost, ``/vsizip//abs/one.zip/dem.tif`` coming back as the relative
    ``/vsizip/abs/one.zip/dem.tif`` (GDAL: no such file) and a URL as its host and path, no longer a URL."""
    import copy
    import pickle

    from stepterrain.io import dem_path

    again = (lambda p: pickle.loads(pickle.dumps(p))) if how == "pickle" else copy.deepcopy
    paths = [gdal_path(f"/vsizip/{tiles / 'one.zip'}/dem.tif"), dem_path(tiles / "one.zip"),
             gdal_path("https://example.org/dem/cog.tif?sig=1")]
    for path in paths:
        back = again(path)
        assert (os.fspath(back), str(back), back.name) == (os.fspath(path), str(path), path.name)
    reference = st.load_dem(tiles / "dem.tif")
    _same(st.load_dem(again(paths[0])), reference)
    _same(st.load_dem(again(paths[1])), reference)



def test_a_missing_zip_among_source_files_is_named_missing(tiles):
    """Among several source files, a .zip that does not exist was refused as "source files must end in .npy, ...",
    where the same zip, there, is read as its raster: it is named as missing, as a missing .tif is."""
    from stepterrain.batch import plan_items

    with pytest.raises(DataFileError, match=r"source file '.*missing\.zip' does not exist"):
        plan_items([tiles / "dem.tif", tiles / "missing.zip"])
    with pytest.raises(InvalidInputError, match=r"must end in .*\.zip holding one raster\); got '.*notes\.txt'"):
        plan_items([tiles / "dem.tif", tiles / "notes.txt"])



def test_a_zipped_grid_in_degrees_without_a_crs_is_told_a_hint_that_works(tmp_path):
    """A GeoTIFF without a CRS whose nodes look like degrees is read as metres with a warning; read from a zip its
    hint said to put a .prj beside the file, or gdal_edit it, neither of which reaches a file in a zip (no .prj is
    looked for there): it gives the gdal_translate that writes a local copy naming the CRS."""
    heights = st.sample_dem().coarsen(8).heights[:50, :50]
    terrain = st.Terrain.from_heights(heights, spacing=(0.001, -0.001), origin=(7.0, 46.0))
    tif = _geotiff(tmp_path / "alps.tif", terrain)
    with zipfile.ZipFile(tmp_path / "alps.zip", "w") as archive:
        archive.write(tif, "alps.tif")
    with pytest.warns(UserWarning, match=r"look like degrees.*put a \.prj with it beside the file"):
        st.load_dem(tif)
    with pytest.warns(UserWarning, match=r"look like degrees") as told:
        st.load_dem(tmp_path / "alps.zip")
    said = " ".join(str(w.message) for w in told)
    assert f"gdal_translate -a_srs EPSG:4326 /vsizip/{tmp_path / 'alps.zip'}/alps.tif alps.tif" in said, said
    assert ".prj" not in said and "gdal_edit" not in said



def test_a_virtual_file_item_is_read_by_a_worker_in_another_folder(tiles, tmp_path, monkeypatch):
    """A dask worker started in another folder resolves a file item's relative path against the caller's (batch's
    _on_worker): a URL was joined to that folder ('/caller/https://h/x.tif', a local file that does not exist), and
    a relative /vsizip/ or /vsigzip/ path, starting with '/', was kept as given: GDAL looked for its archive in the
    worker's folder. Its archive is resolved instead, as the fingerprint names it: the same zip from another folder
    keeps its items complete."""
    from stepterrain.batch import _absolute, _on_worker

    reference = st.load_dem(tiles / "dem.tif")
    elsewhere = tmp_path / "worker"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    url = "https://example.org/dem/cog.tif?sig=1"
    assert _on_worker(url, str(tiles)) == url
    assert _on_worker(f"/vsizip/{tiles / 'one.zip'}/dem.tif", str(tiles)) == f"/vsizip/{tiles / 'one.zip'}/dem.tif"
    for relative in ("/vsizip/one.zip/dem.tif", "/vsigzip/dem.tif.gz"):
        _same(st.load_dem(_on_worker(relative, str(tiles))), reference)
    assert _on_worker("dem.tif", str(tiles)) == str(tiles / "dem.tif")  # a plain file, as before
    named = _absolute(f"/vsizip/{tiles / 'one.zip'}/dem.tif")
    monkeypatch.chdir(tiles)
    assert _absolute("/vsizip/one.zip/dem.tif") == named and _absolute(url) == url


# ------------------------------------------------------------------------------------------ CLI
def test_cli_info_reads_a_vsizip_path_and_a_zip(tiles, capsys):
    reference = st.load_dem(tiles / "dem.tif")
    for given in (f"/vsizip/{tiles / 'one.zip'}/dem.tif", tiles / "one.zip"):
        code, out, err = run(capsys, "info", given, "--json")
        assert code == 0, err
        summary = json.loads(out)
        assert summary["source"] == "dem.tif" and summary["crs"] == reference.crs
        assert tuple(summary["shape"]) == reference.shape


def test_cli_steps_writes_the_mesh_of_a_vsizip_dem(tiles, tmp_path, capsys):
    out = tmp_path / "zipped.ply"
    code, _, err = run(capsys, "steps", f"/vsizip/{tiles / 'one.zip'}/dem.tif", "--interval", "200", "-o", out)
    assert code == 0, err
    plain = tmp_path / "plain.ply"
    code, _, err = run(capsys, "steps", tiles / "dem.tif", "--interval", "200", "-o", plain)
    assert code == 0, err
    import trimesh

    a, b = trimesh.load(out, process=False), trimesh.load(plain, process=False)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


@pytest.mark.parametrize("command", ["info", "steps"])
def test_cli_missing_inner_file_and_unreachable_url_are_clear_errors(tiles, tmp_path, capsys, monkeypatch, command):
    monkeypatch.setenv("GDAL_HTTP_TIMEOUT", "5")
    monkeypatch.setenv("GDAL_HTTP_CONNECTTIMEOUT", "5")
    extra = ("-o", tmp_path / "out.ply") if command == "steps" else ()
    missing = f"/vsizip/{tiles / 'one.zip'}/N46E007.hgt"
    for given, reason in ((missing, "does not exist in the file system"),
                          ("http://127.0.0.1:9/x.tif", "GDAL cannot open it"),
                          (tiles / "two.zip", "holds 2 rasters")):
        code, _, err = run(capsys, command, given, *extra)
        assert code != 0
        assert f"cannot read '{given}'" in err and reason in err, err
        assert "Traceback" not in err
    assert not (tmp_path / "out.ply").exists()


def test_cli_batch_names_a_vsizip_file_item_after_the_inner_file(tiles, tmp_path, capsys):
    out = tmp_path / "meshes"
    code, _, err = run(capsys, "batch", f"/vsizip/{tiles / 'one.zip'}/dem.tif", "--interval", "200",
                       "--scheduler", "serial", "-o", out)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["dem.glb", "stepterrain-batch.json"]
    code, _, err = run(capsys, "batch", f"/vsizip/{tiles / 'one.zip'}/dem.tif", "--interval", "200",
                       "--scheduler", "serial", "-o", out)  # resumed: the zip is unchanged
    assert code == 0, err
    assert "1 complete already" in err
    zipped = tiles / "one.zip"  # the archive rewritten: its item is redone (the fingerprint stats the local zip)
    stat = zipped.stat()
    os.utime(zipped, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))
    code, _, err = run(capsys, "batch", f"/vsizip/{zipped}/dem.tif", "--interval", "200", "--scheduler", "serial",
                       "-o", out)
    assert code == 0, err
    assert "1 written, 0 complete already" in err


def test_a_zipped_world_file_tiff_takes_its_crs_from_the_prj_in_the_zip(tmp_path):
    """A zip of a TIFF with its world file (.tfw) and .prj, as GIS software exports a DEM: GDAL reads the world file
    inside the zip but not the .prj (it never does for a TIFF), and load_dem looked for a .prj beside local files
    only. The same three files read in local metres from a folder lost their CRS from the zip: one in degrees was
    read as degrees (with a warning) and one in US survey feet kept its feet as metres, 3.28 times too wide, without
    a word. The .prj inside the zip is read as the one beside a local file (the zip's own raster, a /vsizip/ path
    relative or absolute, in a folder of the zip); one that is no CRS is refused by name."""
    from rasterio.crs import CRS

    z = (np.arange(12.0).reshape(3, 4) * 10 + 3000).astype(np.int16)

    def world_zip(name, a, c, e, f, prj, folder=""):
        local = tmp_path / name
        local.mkdir()
        tif = local / "dem.tif"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning for the bare TIFF
            with rasterio.open(tif, "w", driver="GTiff", width=4, height=3, count=1, dtype="int16") as ds:
                ds.write(z, 1)
        tif.with_suffix(".tfw").write_text(f"{a!r}\n0.0\n0.0\n{e!r}\n{c + a / 2!r}\n{f + e / 2!r}\n")
        local.joinpath(prj[0]).write_text(prj[1])
        with zipfile.ZipFile(tmp_path / f"{name}.zip", "w") as archive:
            for file in local.iterdir():
                archive.write(file, folder + file.name)
        return local / "dem.tif", tmp_path / f"{name}.zip"

    feet_tif, feet_zip = world_zip("site", 100.0, 6.4e6, -100.0, 1.9e6, ("dem.prj", CRS.from_epsg(2229).to_wkt()))
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        local = st.load_dem(feet_tif)
    assert local.crs == "EPSG:26945"
    for given in (feet_zip, f"/vsizip/{feet_zip}/dem.tif"):
        with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
            t = st.load_dem(given)
        assert (t.crs, t.spacing, t.origin) == (local.crs, local.spacing, local.origin), given

    degrees_tif, degrees_zip = world_zip("front", 1 / 1200, -105.8, -1 / 1200, 40.4,
                                         ("dem.tif.prj", CRS.from_epsg(4326).to_wkt()), folder="dem/")
    local = st.load_dem(degrees_tif)
    assert local.crs.startswith("+proj=eqc")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "look like degrees" warning: its CRS is read
        t = st.load_dem(degrees_zip)
    assert (t.crs, t.spacing, t.origin, t.source) == (local.crs, local.spacing, local.origin, local.source)
    # batch places such tiles in the degrees they share by their header: its CRS is the zipped .prj's too
    from stepterrain.io import degree_header

    assert degree_header(degrees_zip) == degree_header(degrees_tif)
    assert degree_header(degrees_zip)[0] == "EPSG:4326"
    old = os.getcwd()
    os.chdir(tmp_path)
    try:
        t = st.load_dem("/vsizip/front.zip/dem/dem.tif")  # relative to the working folder, as GDAL reads it
    finally:
        os.chdir(old)
    assert (t.crs, t.spacing) == (local.crs, local.spacing)

    _, broken_zip = world_zip("broken", 30.0, 5e5, -30.0, 4e6, ("dem.prj", "not a CRS"))
    with pytest.raises(DataFileError, match=r"dem\.prj' beside DEM '.*dem\.tif' is not a CRS"):
        st.load_dem(broken_zip)


def test_a_braced_zip_in_a_zip_without_its_member_is_advised_a_path_that_reads_it(tiles, tmp_path):
    """A zip in a zip already opened in GDAL's braces without the member to read (/vsizip/{/vsizip//d/outer.zip/
    one.zip}) was advised /vsizip/{/vsizip/{...}}/<name>.tif, a zip inside that zip, which reads nothing: its '.zip/'
    was taken for a member's path before the braces were seen. It is advised the braced zip with the member after
    it, which reads the DEM; an unbraced zip-in-zip path is still wrapped in braces (GDAL splits at the first
    '.zip/')."""
    with zipfile.ZipFile(tmp_path / "outer.zip", "w") as archive:
        archive.write(tiles / "one.zip", "one.zip")
    inner = f"/vsizip/{tmp_path / 'outer.zip'}/one.zip"

    def advice(path):
        with pytest.raises(InvalidInputError) as caught:
            st.load_dem(path)
        return re.search(r"name the file inside the zip: '([^']*)'", str(caught.value)).group(1)

    assert advice(f"/vsizip/{{{inner}}}") == f"/vsizip/{{{inner}}}/<name>.tif"
    assert advice(inner) == f"/vsizip/{{{inner}}}/<name>.tif"
    _same(st.load_dem(advice(f"/vsizip/{{{inner}}}").replace("<name>", "dem")), st.load_dem(tiles / "dem.tif"))
    remote = "/vsicurl/https://example.org/x.zip/y.zip"
    assert advice(f"/vsizip/{{{remote}}}") == f"/vsizip/{{{remote}}}/<name>.tif"
