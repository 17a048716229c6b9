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
path, limit, geo, rows, cols = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "geo", int(sys.argv[4]), int(sys.argv[5])
crs = sys.argv[6] if len(sys.argv) > 6 else "EPSG:32632"
image = np.random.default_rng(0).integers(0, 255, (rows, cols, 3), dtype=np.uint8)
soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)  # a runner's finite hard limit cannot be raised to infinity
resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
try:
    save_image(image, path, **({"extent": (0.0, 30.0, 0.0, 40.0), "crs": crs} if geo else {}))
    said = ["ok", ""]
except errors.StepTerrainError as exc:
    said = [type(exc).__name__, str(exc)]
except Exception as exc:
    said = ["uncaught " + type(exc).__name__, str(exc)]
finally:  # what the process writes at its exit (a coverage data file) is not cut short
    resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
print(json.dumps(said))
"""


def _write_full(path, limit, geo, rows=40, cols=30, crs="EPSG:32632"):
    done = subprocess.run([sys.executable, "-c", _WRITER, str(path), str(limit), "geo" if geo else "plain", str(rows),
                           str(cols), crs],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("limit", [0, 1000])
def test_a_geotiff_that_does_not_fit_keeps_the_old_file(tmp_path, limit):
    # GDAL writes a small GeoTIFF's pixels and directory when the dataset closes, and a failure there is only printed
    # (rasterio's close raises nothing): save_image returned, and the old GeoTIFF was replaced by an empty or
    # truncated file that no reader opens
    pytest.importorskip("rasterio")
    old = tmp_path / "ortho.tif"
    old.write_bytes(b"an earlier GeoTIFF" * 100)
    kind, message = _write_full(old, limit, geo=True)
    assert kind == "DataFileError" and str(old) in message, (kind, message)
    assert old.read_bytes() == b"an earlier GeoTIFF" * 100
    assert [p.name for p in tmp_path.iterdir()] == ["ortho.tif"]  # no temporary file left


def test_a_tiff_on_a_full_disk_is_a_data_file_error(tmp_path):
    # libtiff could not write the header of the temporary file: Pillow's "RuntimeError: tiff codec initialization
    # failed" went out uncaught, a traceback, where a PNG said "cannot write ...: No space left on device"
    old = tmp_path / "texture.tif"
    old.write_bytes(b"an earlier TIFF" * 100)
    kind, message = _write_full(old, 0, geo=False)
    assert kind == "DataFileError" and str(old) in message, (kind, message)
    assert old.read_bytes() == b"an earlier TIFF" * 100
    assert [p.name for p in tmp_path.iterdir()] == ["texture.tif"]


def test_a_geotiff_cut_off_past_its_first_block_gives_the_system_reason(tmp_path):
    # the reason was found by writing 4096 bytes at the start of the cut-off temporary file: where GDAL had written
    # more than that, the write went over bytes already on the disk and succeeded (on a full disk as under a size
    # limit), and the message said "GDAL could not finish the file" where the system's words were "File too large"
    pytest.importorskip("rasterio")
    old = tmp_path / "ortho.tif"
    old.write_bytes(b"an earlier GeoTIFF" * 100)
    kind, message = _write_full(old, 8192, geo=True, rows=200)
    assert kind == "DataFileError" and str(old) in message, (kind, message)
    assert message.endswith(os.strerror(errno.EFBIG)), message
    assert old.read_bytes() == b"an earlier GeoTIFF" * 100
    assert [p.name for p in tmp_path.iterdir()] == ["ortho.tif"]


@pytest.mark.parametrize("geo", [False, True])
def test_an_image_whose_pixels_do_not_fit_gives_the_system_reason(tmp_path, geo):
    # a write failing while the pixels went out (not at the close): Pillow's libtiff said "encoder error -9 when
    # writing image file" and GDAL "TIFFAppendToStrip:Write error at scanline 104", where the system's words were
    # "File too large" ("No space left on device" on a full disk), as save_image's docstring promises
    if geo:
        pytest.importorskip("rasterio")
    old = tmp_path / "ortho.tif"
    old.write_bytes(b"an earlier TIFF" * 100)
    kind, message = _write_full(old, 100_000, geo=geo, rows=1000, cols=1000)
    assert kind == "DataFileError" and str(old) in message, (kind, message)
    assert f": {os.strerror(errno.EFBIG)} (" in message, message  # the library's words follow, in brackets
    assert old.read_bytes() == b"an earlier TIFF" * 100
    assert [p.name for p in tmp_path.iterdir()] == ["ortho.tif"]


def test_a_geotiff_whose_crs_side_file_does_not_fit_keeps_the_old_file(tmp_path):
    # a CRS GeoTIFF's keys cannot hold (ob_tran) goes into <image>.aux.xml, which GDAL writes as the dataset closes,
    # a failure only printed: the pixels read back as written, and the image was put in place with an empty or cut-off
    # side file, its CRS lost without a word (a 280-byte GeoTIFF fits a limit of 600 bytes, its 807-byte side file not)
    pytest.importorskip("rasterio")
    rotated = "+proj=ob_tran +o_proj=longlat +o_lon_p=-162 +o_lat_p=39.25 +lon_0=180 +datum=WGS84 +no_defs"
    old = tmp_path / "ortho.tif"
    old.write_bytes(b"an earlier GeoTIFF" * 20)
    kind, message = _write_full(old, 600, geo=True, rows=1, cols=1, crs=rotated)
    assert kind == "DataFileError" and str(old) in message, (kind, message)
    assert os.strerror(errno.EFBIG) in message, message
    assert old.read_bytes() == b"an earlier GeoTIFF" * 20
    assert [p.name for p in tmp_path.iterdir()] == ["ortho.tif"]
