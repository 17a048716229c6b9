"""Output files on a disk that fills while they are written (each test failed before its fix): the old file stays
whole and the error is a DataFileError naming the path. The full disk is the file size limit (RLIMIT_FSIZE, whose
writes past it fail as ENOSPC's do, EFBIG) of a child process: GDAL's and libtiff's writes are C code no patch of
os.write reaches."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys

import pytest

resource = pytest.importorskip("resource")  # POSIX only
if not hasattr(resource, "RLIMIT_FSIZE"):
    pytest.skip("needs RLIMIT_FSIZE", allow_module_level=True)

_WRITER = """
import json, os, resource, signal, sys
import numpy as np
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG) instead of killing the process
import stepterrain.errors as errors
from stepterrain.export import save_image
said = []
for path, limit, geo, rows, cols, crs in json.loads(sys.argv[1]):
    image = np.random.default_rng(0).integers(0, 255, (rows, cols, 3), dtype=np.uint8)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)  # a runner's finite hard limit cannot be raised to infinity
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
    try:
        save_image(image, path, **({"extent": (0.0, 30.0, 0.0, 40.0), "crs": crs} if geo else {}))
        said.append(["ok", ""])
    except errors.StepTerrainError as exc:
        said.append([type(exc).__name__, str(exc)])
    except Exception as exc:
        said.append(["uncaught " + type(exc).__name__, str(exc)])
    finally:  # the next write, and what the process writes at its exit (a coverage data file), are not cut short
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
print(json.dumps(said))
"""

_ROTATED = "+proj=ob_tran +o_proj=longlat +o_lon_p=-162 +o_lat_p=39.25 +lon_0=180 +datum=WGS84 +no_defs"

# each test's write: (file name, the old file's bytes, size limit, geo, rows, cols, crs)
_WRITES = {
    "geotiff 0": ("ortho.tif", b"an earlier GeoTIFF" * 100, 0, True, 40, 30, "EPSG:32632"),
    "geotiff 1000": ("ortho.tif", b"an earlier GeoTIFF" * 100, 1000, True, 40, 30, "EPSG:32632"),
    "tiff": ("texture.tif", b"an earlier TIFF" * 100, 0, False, 40, 30, "EPSG:32632"),
    "geotiff past its first block": ("ortho.tif", b"an earlier GeoTIFF" * 100, 8192, True, 200, 30, "EPSG:32632"),
    "pixels": ("ortho.tif", b"an earlier TIFF" * 100, 100_000, False, 1000, 1000, "EPSG:32632"),
    "geo pixels": ("ortho.tif", b"an earlier TIFF" * 100, 100_000, True, 1000, 1000, "EPSG:32632"),
    "crs side file": ("ortho.tif", b"an earlier GeoTIFF" * 20, 600, True, 1, 1, _ROTATED),
}


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Every write of _WRITES over its old file, each in a folder of its own, in one child process (each test's own
    child imported the project again: 13 s for the seven): by name, (the folder, the old file, the exception's class
    name or "ok", its message)."""
    jobs, found = [], {}
    for name, (file, old, limit, geo, rows, cols, crs) in _WRITES.items():
        path = tmp_path_factory.mktemp("full_disk") / file
        path.write_bytes(old)
        jobs.append([str(path), limit, geo, rows, cols, crs])
        found[name] = path
    done = subprocess.run([sys.executable, "-c", _WRITER, json.dumps(jobs)], capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    said = json.loads(done.stdout.strip().splitlines()[-1])
    return {name: (path.parent, path, *said[k]) for k, (name, path) in enumerate(found.items())}


def _kept(written, name) -> tuple[str, str]:
    """The write ``name`` refused with DataFileError naming the path, the old file whole and alone in its folder:
    the exception's class name and message."""
    folder, old, kind, message = written[name]
    assert kind == "DataFileError" and str(old) in message, (kind, message)
    assert old.read_bytes() == _WRITES[name][1]
    assert [p.name for p in folder.iterdir()] == [old.name]  # no temporary file left
    return kind, message


@pytest.mark.parametrize("limit", [0, 1000])
def test_a_geotiff_that_does_not_fit_keeps_the_old_file(written, limit):
    # GDAL writes a small GeoTIFF's pixels and directory when the dataset closes, and a failure there is only printed
    # (rasterio's close raises nothing): save_image returned, and the old GeoTIFF was replaced by an empty or
    # truncated file that no reader opens
    pytest.importorskip("rasterio")
    _kept(written, f"geotiff {limit}")


def test_a_tiff_on_a_full_disk_is_a_data_file_error(written):
    # libtiff could not write the header of the temporary file: Pillow's "RuntimeError: tiff codec initialization
    # failed" went out uncaught, a traceback, where a PNG said "cannot write ...: No space left on device"
    _kept(written, "tiff")


def test_a_geotiff_cut_off_past_its_first_block_gives_the_system_reason(written):
    # the reason was found by writing 4096 bytes at the start of the cut-off temporary file: where GDAL had written
    # more than that, the write went over bytes already on the disk and succeeded (on a full disk as under a size
    # limit), and the message said "GDAL could not finish the file" where the system's words were "File too large"
    pytest.importorskip("rasterio")
    _, message = _kept(written, "geotiff past its first block")
    assert message.endswith(os.strerror(errno.EFBIG)), message


@pytest.mark.parametrize("geo", [False, True])
def test_an_image_whose_pixels_do_not_fit_gives_the_system_reason(written, geo):
    # a write failing while the pixels went out (not at the close): Pillow's libtiff said "encoder error -9 when
    # writing image file" and GDAL "TIFFAppendToStrip:Write error at scanline 104", where the system's words were
    # "File too large" ("No space left on device" on a full disk), as save_image's docstring promises
    if geo:
        pytest.importorskip("rasterio")
    _, message = _kept(written, "geo pixels" if geo else "pixels")
    assert f": {os.strerror(errno.EFBIG)} (" in message, message  # the library's words follow, in brackets


def test_a_geotiff_whose_crs_side_file_does_not_fit_keeps_the_old_file(written):
    # a CRS GeoTIFF's keys cannot hold (ob_tran) goes into <image>.aux.xml, which GDAL writes as the dataset closes,
    # a failure only printed: the pixels read back as written, and the image was put in place with an empty or cut-off
    # side file, its CRS lost without a word (a 280-byte GeoTIFF fits a limit of 600 bytes, its 807-byte side file not)
    pytest.importorskip("rasterio")
    _, message = _kept(written, "crs side file")
    assert os.strerror(errno.EFBIG) in message, message
