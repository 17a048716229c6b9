"""Batch runs and reruns of DEM files: the default interval said, one read of a single file, one read of the
manifest, a versioned range cache, and a .vrt's source tiles in its fingerprint."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

import stepterrain as st
from stepterrain.batch import MANIFEST_NAME, batch
from stepterrain.io import load_dem
from stepterrain.stepped import isovalues, nice_interval

from .conftest import run_cli as run
from .test_batch_files_shared import _count_reads, _write_tif, strips
from .test_export import glb_json

pytest.importorskip("rasterio", reason="GeoTIFF tiles are written with rasterio")

INTERVAL_LINE = re.compile(r"^stepterrain: no --interval or --levels given: using --interval (\S+), a round interval "
                           r"giving (\d+) levels over heights (\S+) to (\S+) \(aim ~\d+ steps\)$", re.M)


@pytest.mark.parametrize("given", [[], ["--tile", "256"]], ids=["folder", "tiles"])
def test_batch_says_the_default_interval_it_chose_once(given, tmp_path, capsys):
    # steps says "no --interval or --levels given: using --interval 100, ..."; batch chose one for the whole folder
    # (or raster) and said nothing of it: the interval was found only in the outputs' metadata
    if given:  # the embedded DEM cut into tiles
        terrain, argv = st.sample_dem(), ["batch", *given]
    else:
        terrain, _ = strips(tmp_path / "tiles", 3, step=3)
        argv = ["batch", tmp_path / "tiles"]
    code, out, err = run(capsys, *argv, "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 0, err
    said = INTERVAL_LINE.findall(err)
    assert len(said) == 1, err
    interval, n, lo, hi = said[0]
    expected = nice_interval(terrain.height_range)  # the files share their border columns: the whole DEM's range
    assert float(interval) == pytest.approx(expected)
    assert (float(lo), float(hi)) == pytest.approx(terrain.height_range)
    assert int(n) == len(isovalues(terrain.height_range, interval=expected))
    written = sorted((tmp_path / "out").glob("*.glb"))
    assert written and all(glb_json(p)["meshes"][0]["extras"]["interval"] == expected for p in written)
    # given, or explicit levels: nothing to say; --quiet: nothing at all
    code, _, err = run(capsys, *argv, "--interval", "50", "--scheduler", "serial", "--format", ".ply",
                       "-o", tmp_path / "out50")  # fmt: skip
    assert code == 0 and "no --interval" not in err
    code, _, err = run(capsys, "--quiet", *argv, "--scheduler", "serial", "--format", ".ply", "-o", tmp_path / "q")
    assert code == 0 and "no --interval" not in err


def test_a_single_file_is_read_once_on_a_first_coloured_serial_run(tmp_path, monkeypatch):
    # one DEM file, coloured: the range pass read it, then its item read it again
    _, (dem,) = strips(tmp_path / "one", 1, step=2)
    kwargs = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    calls = _count_reads(monkeypatch)
    first = batch([dem], tmp_path / "out", **kwargs)
    assert first.ok and len(first.done) == 1
    assert calls == [dem.name]
    written = Path(first.done[0].path).read_bytes()
    # redone: its range recorded, so only the item reads it; the output is the same bytes
    calls.clear()
    again = batch([dem], tmp_path / "out", resume=False, **kwargs)
    assert again.ok and calls == [dem.name]
    assert Path(again.done[0].path).read_bytes() == written
    # several files are each read twice still (none held in memory until its item runs)
    _, files = strips(tmp_path / "tiles", 2, step=4)
    calls.clear()
    assert batch(files, tmp_path / "out2", **kwargs).ok
    assert sorted(calls) == sorted(2 * [f.name for f in files])


def test_a_rerun_reads_the_manifest_and_stats_each_file_once(tmp_path, monkeypatch):
    # the manifest was parsed twice per run (its ranges, then its items) and each file's identity (a stat of it and
    # of its sidecars) found twice (the range's key, then the fingerprint)
    import stepterrain.batch as batch_module

    _, files = strips(tmp_path / "tiles", 3, step=4)
    kwargs = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    out = tmp_path / "out"
    assert batch(tmp_path / "tiles", out, **kwargs).ok
    real_read, real_identity = Path.read_text, batch_module._file_identity
    manifest_reads: list[str] = []
    identities: list[str] = []

    def read_text(self, *args, **kw):
        if self.name == MANIFEST_NAME:
            manifest_reads.append(str(self))
        return real_read(self, *args, **kw)

    def file_identity(path, *args, **kw):
        identities.append(Path(path).name)
        return real_identity(path, *args, **kw)

    monkeypatch.setattr(Path, "read_text", read_text)
    monkeypatch.setattr(batch_module, "_file_identity", file_identity)
    again = batch(tmp_path / "tiles", out, **kwargs)
    assert len(again.skipped) == 3
    assert len(manifest_reads) == 1
    assert sorted(identities) == sorted(f.name for f in files)


@pytest.mark.parametrize("version", ["dropped", "other"])
def test_ranges_recorded_by_another_version_are_read_again_not_trusted(version, tmp_path, monkeypatch):
    # the manifest's ranges carried no version: a stepterrain that finds a file's range otherwise reused an earlier
    # one's values; here a recorded range edited to [0, 5000] stands for such a stale value
    _, files = strips(tmp_path / "tiles", 2, step=4)
    kwargs = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    out = tmp_path / "out"
    fresh = batch(tmp_path / "tiles", tmp_path / "fresh", **kwargs)
    assert batch(tmp_path / "tiles", out, **kwargs).ok
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert len(manifest["ranges"]) == 2
    manifest["ranges"] = {key: [0.0, 5000.0] for key in manifest["ranges"]}
    if version == "dropped":  # a manifest written before the ranges had a version
        manifest.pop("ranges_version", None)
    else:
        manifest["ranges_version"] = "another"
    (out / MANIFEST_NAME).write_text(json.dumps(manifest))
    calls = _count_reads(monkeypatch)
    again = batch(tmp_path / "tiles", out, **kwargs)
    assert again.ok and len(again.skipped) == 2  # the real ranges again: the levels and outputs as before
    assert sorted(calls) == sorted(f.name for f in files)  # read for their ranges, not stepped again
    assert [Path(r.path).read_bytes() for r in again.results] == [Path(r.path).read_bytes() for r in fresh.done]
    rewritten = json.loads((out / MANIFEST_NAME).read_text())
    assert sorted(rewritten["ranges"].values()) != [[0.0, 5000.0]] * 2  # recorded afresh, with this version
    calls.clear()
    assert len(batch(tmp_path / "tiles", out, **kwargs).skipped) == 2 and calls == []


@pytest.mark.skipif(shutil.which("gdalbuildvrt") is None, reason="needs gdalbuildvrt (gdal-bin)")
@pytest.mark.parametrize("colors", [None, "terrain"])
def test_a_vrt_whose_source_tile_changed_is_redone(colors, tmp_path):
    # a .vrt's fingerprint was the .vrt file's identity alone: a source tile rewritten under it left the item
    # "complete", the rerun skipping it with the old heights (and its recorded range reused for the levels)
    terrain, files = strips(tmp_path / "tiles", 2, step=4)
    vrt = tmp_path / "mosaic.vrt"
    subprocess.run(["gdalbuildvrt", "-q", str(vrt), *map(str, files)], check=True, cwd=tmp_path)
    kwargs = {"interval": 100.0, "colors": colors, "format": ".ply", "scheduler": "serial"}
    out = tmp_path / "out"
    first = batch([vrt], out, **kwargs)
    assert first.ok and len(first.done) == 1
    before = Path(first.done[0].path).read_bytes()
    assert len(batch([vrt], out, **kwargs).skipped) == 1  # unchanged: complete
    east = load_dem(files[1])
    higher = east.heights.copy()
    higher[3, 3] = terrain.height_range[1] + 250.0
    _write_tif(files[1], higher, *east.origin, *east.spacing, terrain.crs)
    again = batch([vrt], out, **kwargs)
    assert again.ok and len(again.done) == 1
    fresh = batch([vrt], tmp_path / "fresh", **kwargs)
    assert Path(again.done[0].path).read_bytes() == Path(fresh.done[0].path).read_bytes()
    assert Path(again.done[0].path).read_bytes() != before  # the new heights stepped
    assert len(batch([vrt], out, **kwargs).skipped) == 1


def test_a_single_file_read_once_keeps_its_read_s_warnings_in_its_result(tmp_path):
    # a GeoTIFF in US survey feet warns, as it is read, that its heights are kept as stored: an item reading its file
    # records that in its result's warnings, but the one file of a serial run, stepped from the range pass's read,
    # had none (a 2-file run's items, or the same item rerun from its recorded range, had it)
    z = st.sample_dem().heights[::4, ::4]
    dem = tmp_path / "feet.tif"
    _write_tif(dem, z, 6_450_000.0, 1_950_000.0, 100.0, -100.0, "EPSG:2229")
    kwargs = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        first = batch([dem], tmp_path / "out", **kwargs)
    with pytest.warns(UserWarning, match="EPSG:2229 is in US survey foot units"):
        again = batch([dem], tmp_path / "out", resume=False, **kwargs)  # its range recorded: the item reads it
    assert first.ok and again.ok and len(first.done) == len(again.done) == 1
    said = [w for w in again.done[0].warnings if "US survey foot units" in w]
    assert said and first.done[0].warnings == again.done[0].warnings
