"""A file's load_dem warning is said once by batch, not twice.

The files of a folder are read once for their shared height range (a solid's floor, a colormap, the default
interval) and again as their items: each read warned. A float32 GeoTIFF whose voids hold the lowest float32 value
without a declared nodata printed load_dem's "undeclared void" warning before the progress bar (the range pass) and
again after it (the item's read, warned again in the caller's process), and the Python API recorded it twice. Every
test here but the last failed before the range pass's warnings were kept from being said again; the last, before
the solid floor's check stopped taking np.spacing of the float32 maximum (numpy's overflow warning, said next)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import stepterrain as st
from stepterrain.batch import batch

from .conftest import run_cli as run

rasterio = pytest.importorskip("rasterio", reason="GeoTIFF tiles are written with rasterio")

LOWEST = float(np.finfo(np.float32).min)
LEVELS = [500.0, 1000.0, 1500.0, 2000.0]


def _voided_tif(path: Path, degrees: bool = False) -> Path:
    """The embedded DEM (every 4th node) as a float32 GeoTIFF whose corner block holds the lowest float32 value, no
    nodata declared (load_dem warns of undeclared voids); ``degrees``: no CRS, its transform in degree-sized cells
    (load_dem warns that degrees are read as metres) and no voids."""
    from rasterio.transform import Affine

    dem = st.sample_dem()
    z = dem.heights[::4, ::4].astype(np.float32)
    if degrees:
        crs, transform = None, Affine(0.001, 0.0, -118.2, 0.0, -0.001, 34.4)
    else:
        z[:5, :7] = LOWEST
        (dx, dy), (x0, y0) = dem.spacing, dem.origin
        crs, transform = dem.crs, Affine(4 * dx, 0.0, x0 - 2 * dx, 0.0, 4 * dy, y0 - 2 * dy)
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs=crs, transform=transform) as f:  # fmt: skip
        f.write(z, 1)
    return path


def _recorded(source: Path, out: Path, **kwargs) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch(str(source), str(out), levels=LEVELS, solid=True, **kwargs)
    assert [r.status for r in report.results] == ["done"] * len(report.results)
    return [str(w.message) for w in caught]


@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("degrees", [False, True], ids=["voids", "degrees"])
def test_each_files_read_warning_once_serial(tmp_path, n, degrees):
    # one file: the range pass's read is its item's (kept); two: each file read twice
    for k in range(n):
        _voided_tif(tmp_path / "tiles" / f"t{k}.tif", degrees)
    said = _recorded(tmp_path / "tiles", tmp_path / "out", scheduler="serial")
    marker = "look like degrees" if degrees else "the lowest float32 value"
    for k in range(n):  # each file's own, once (not one for all files: they name their file)
        assert sum(m.startswith(f"t{k}.tif: ") and marker in m for m in said) == 1, said
    assert sum(marker in m for m in said) == n


def test_each_files_void_warning_once_local_cluster(tmp_path):
    # the items' reads in worker processes, their recorded warnings said again in this process
    for k in range(2):
        _voided_tif(tmp_path / "tiles" / f"t{k}.tif")
    said = _recorded(tmp_path / "tiles", tmp_path / "out", workers=2)
    assert sorted(m.split(":")[0] for m in said if "the lowest float32 value" in m) == ["t0.tif", "t1.tif"], said


def test_cli_says_the_void_warning_once(tmp_path, capsys):
    _voided_tif(tmp_path / "tiles" / "t0.tif")
    code, _, err = run(capsys, "batch", tmp_path / "tiles", "--levels", "500,1000,1500,2000", "--solid",
                       "--scheduler", "serial", "-o", tmp_path / "out")  # fmt: skip
    assert code == 0, err
    assert err.count("t0.tif: 35 cells of band 1 hold -3.4028235e+38, the lowest float32 value") == 1, err


def test_solid_floor_over_lowest_float32_heights_warns_no_overflow(tmp_path):
    # the floor's check took np.spacing of the float32 maximum: numpy's "overflow encountered in spacing" warning,
    # said by batch after the file's void warning (its solid's floor is given to every item)
    terrain = st.Terrain.from_heights(np.where(np.arange(36).reshape(6, 6) < 3, LOWEST, 700.0).astype(np.float32))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        mesh = st.stepped(terrain, levels=LEVELS, gamma=0.5, solid=True, floor=-3e38)
    assert mesh.is_watertight


def _minus_9999_tif(path: Path) -> Path:
    """The embedded DEM (every 4th node) as an int16 GeoTIFF whose corner block holds -9999, no nodata declared
    (load_dem names it as a common nodata value far below the heights)."""
    from rasterio.transform import Affine

    dem = st.sample_dem()
    z = np.round(dem.heights[::4, ::4]).astype(np.int16)
    z[:5, :7] = -9999
    (dx, dy), (x0, y0) = dem.spacing, dem.origin
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="int16",
                       crs=dem.crs, transform=Affine(4 * dx, 0.0, x0 - 2 * dx, 0.0, 4 * dy, y0 - 2 * dy)) as f:
        f.write(z, 1)
    return path


def test_each_files_common_nodata_warning_once(tmp_path, capsys):
    # the range pass and the item's read both named the -9999 voids; once per file, naming its file
    for k in range(2):
        _minus_9999_tif(tmp_path / "tiles" / f"t{k}.tif")
    said = _recorded(tmp_path / "tiles", tmp_path / "out", scheduler="serial")
    marker = "35 cells of band 1 hold -9999, a common nodata value"
    assert sorted(m.split(":")[0] for m in said if marker in m) == ["t0.tif", "t1.tif"], said
    code, _, err = run(capsys, "batch", tmp_path / "tiles", "--levels", "500,1000,1500,2000", "--solid",
                       "--scheduler", "serial", "-o", tmp_path / "out2")  # fmt: skip
    assert code == 0, err
    assert err.count(f"t0.tif: {marker}") == 1 and err.count(f"t1.tif: {marker}") == 1, err
    assert "gdal_edit.py -a_nodata -9999 t0.tif" in err
