"""A folder or list of DEM tiles shares one set of levels and one solid floor, as tiles of one raster do.

Each file of a folder was stepped as ``stepped(load_dem(file), ...)``: its colormap spread over its own levels (one
height, two colours in neighbouring tiles: seams in a tileset) and its solid's default floor under its own lowest
vertex (printed tiles on different bases). Every test here failed before the files shared one height range."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import stepterrain as st
from stepterrain import cli
from stepterrain.batch import MANIFEST_NAME, batch
from stepterrain.errors import InvalidInputError
from stepterrain.export import read_mesh
from stepterrain.io import load_dem
from stepterrain.stepped import isovalues, stepped

rasterio = pytest.importorskip("rasterio", reason="GeoTIFF tiles are written with rasterio")


def _write_tif(path: Path, z: np.ndarray, x0: float, y0: float, dx: float, dy: float, crs: str | None) -> None:
    from rasterio.transform import Affine

    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs=crs, nodata=-9999.0, transform=Affine(dx, 0.0, x0 - dx / 2, 0.0, -abs(dy), y0 + abs(dy) / 2),
                       ) as f:  # fmt: skip
        f.write(np.where(np.isnan(z), -9999.0, z).astype(np.float32), 1)


def strips(folder: Path, n: int, step: int = 1, sea: bool = False) -> tuple[st.Terrain, list[Path]]:
    """The embedded DEM (every ``step``-th node) cut into ``n`` GeoTIFF strips west to east that share their border
    column of nodes, as a GIS user cuts a raster into tiles; ``sea``: and a tile of nodata only south of them."""
    whole = st.sample_dem()
    z = whole.heights[::step, ::step]
    (dx, dy), (x0, y0) = (whole.spacing[0] * step, whole.spacing[1] * step), whole.origin
    terrain = st.Terrain.from_heights(z, spacing=(dx, dy), origin=(x0, y0), crs=whole.crs)
    folder.mkdir(parents=True, exist_ok=True)
    cuts = np.linspace(0, z.shape[1] - 1, n + 1).round().astype(int)
    files = []
    for k in range(n):
        c0, c1 = int(cuts[k]), int(cuts[k + 1])
        files.append(folder / f"tile_{k}.tif")
        _write_tif(files[-1], z[:, c0 : c1 + 1], x0 + c0 * dx, y0, dx, dy, whole.crs)
    if sea:
        files.append(folder / "tile_sea.tif")
        _write_tif(files[-1], np.full((9, 9), np.nan, np.float32), x0, y0 + z.shape[0] * dy, dx, dy, whole.crs)
    return terrain, files


def colours_by_height(path: Path | str) -> dict[float, set[tuple[int, ...]]]:
    mesh = read_mesh(path)
    rgb = np.asarray(mesh.visual.vertex_colors)[:, :3]
    out: dict[float, set[tuple[int, ...]]] = {}
    for z, c in zip(np.asarray(mesh.vertices)[:, 2].tolist(), map(tuple, rgb.tolist()), strict=True):
        out.setdefault(z, set()).add(c)
    return out


def test_a_height_has_one_colour_in_every_file(tmp_path):
    # the lead's check: the embedded DEM's west and east halves (sharing a column), interval 100, 'terrain': at
    # 1300 m the west half's vertices were [158 131 101] and the east half's [224 215 136]
    terrain, files = strips(tmp_path / "tiles", 2)
    report = batch(tmp_path / "tiles", tmp_path / "out", interval=100.0, colors="terrain", format=".ply",
                   scheduler="serial")  # fmt: skip
    assert report.ok and [r.key for r in report.done] == ["tile_0", "tile_1"], report.summary()
    west, east = (colours_by_height(r.path) for r in report.done)
    shared = sorted(set(west) & set(east) & {float(v) for v in isovalues(terrain.height_range, interval=100.0)})
    assert 1300.0 in shared and len(shared) >= 10
    for z in shared:
        assert len(west[z]) == 1 and west[z] == east[z], (z, west[z], east[z])
    # the colours of the whole raster stepped at once: the files' levels are the whole's
    whole = stepped(terrain, interval=100.0, colors="terrain")
    at = np.asarray(whole.vertices)[:, 2] == 1300.0
    assert {tuple(c) for c in np.asarray(whole.visual.vertex_colors)[at, :3].tolist()} == west[1300.0]
    for r, f in zip(report.done, files, strict=True):  # the geometry is each file's own, bit for bit
        alone = stepped(load_dem(f), interval=100.0)
        mesh = read_mesh(r.path)
        assert np.array_equal(np.asarray(mesh.vertices), np.asarray(alone.vertices))
        assert np.array_equal(np.asarray(mesh.faces), np.asarray(alone.faces))


def test_solids_of_a_folder_stand_on_one_floor(tmp_path):
    terrain, files = strips(tmp_path / "tiles", 3, step=4)
    lows = [float(np.nanmin(load_dem(f).heights)) for f in files]
    assert len({float(isovalues((lo, lo), interval=100.0)[0]) for lo in lows}) > 1  # the files' own floors differ
    report = batch(files, tmp_path / "out", interval=100.0, solid=True, format=".ply", scheduler="serial")
    assert report.ok and len(report.done) == 3, report.summary()
    floors = {float(np.asarray(read_mesh(r.path).vertices)[:, 2].min()) for r in report.done}
    # the floor the whole raster's solid has: one interval under its lowest isovalue
    assert floors == {float(np.asarray(stepped(terrain, interval=100.0, solid=True).vertices)[:, 2].min())}
    for r in report.done:
        mesh = read_mesh(r.path)
        assert mesh.is_watertight and mesh.is_volume


def test_a_floor_above_one_files_lowest_point_is_refused_up_front_naming_it(tmp_path):
    _, files = strips(tmp_path / "tiles", 3, step=4)
    lowest = [float(isovalues((h, h), interval=100.0)[0]) for h in
              (float(np.nanmin(load_dem(f).heights)) for f in files)]  # γ = 1: the isovalue the lowest node snaps to
    order = np.argsort(lowest)
    floor = (lowest[order[0]] + lowest[order[1]]) / 2  # under every file's surface but the lowest one's
    assert lowest[order[0]] < floor < lowest[order[1]]
    refused = rf"floor .*must lie below the lowest point .* of the stepped surface of '{files[order[0]]}' \(the lowest"
    with pytest.raises(InvalidInputError, match=refused + " of the 3 files"):
        batch(tmp_path / "tiles", tmp_path / "out", interval=100.0, solid=True, floor=floor, scheduler="serial")
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())  # before any item ran
    report = batch(tmp_path / "tiles", tmp_path / "out", interval=100.0, solid=True, floor=lowest[order[0]] - 1.0,
                   format=".ply", scheduler="serial")  # fmt: skip
    assert report.ok and {float(np.asarray(read_mesh(r.path).vertices)[:, 2].min()) for r in report.done} == {
        lowest[order[0]] - 1.0}


def test_a_tile_of_nodata_moves_no_level_and_a_rerun_skips(tmp_path):
    terrain, files = strips(tmp_path / "tiles", 2, step=2, sea=True)
    kwargs = {"interval": 100.0, "colors": "terrain", "solid": True, "format": ".ply", "scheduler": "serial"}
    report = batch(tmp_path / "tiles", tmp_path / "out", **kwargs)
    assert report.ok and [r.key for r in report.done] == ["tile_0", "tile_1", "tile_sea"], report.summary()
    assert report.done[2].faces == 0
    west, east = (colours_by_height(r.path) for r in report.done[:2])
    shared = set(west) & set(east) & {float(v) for v in isovalues(terrain.height_range, interval=100.0)}
    assert len(shared) >= 5 and all(west[z] == east[z] for z in shared)
    manifest = json.loads((tmp_path / "out" / MANIFEST_NAME).read_text())
    again = batch(tmp_path / "tiles", tmp_path / "out", **kwargs)
    assert again.ok and len(again.skipped) == 3 and not again.done
    assert json.loads((tmp_path / "out" / MANIFEST_NAME).read_text()) == manifest
    # a file rewritten with the same heights: its item alone is redone (the levels stay)
    _write_tif(files[0], load_dem(files[0]).heights, *load_dem(files[0]).origin, *load_dem(files[0]).spacing,
               terrain.crs)  # fmt: skip
    again = batch(tmp_path / "tiles", tmp_path / "out", **kwargs)
    assert [r.key for r in again.done] == ["tile_0"] and len(again.skipped) == 2
    # a file whose heights reach a new level: the levels of every file change, so every item is redone
    east = load_dem(files[1])
    higher = east.heights.copy()
    higher[5, 5] = terrain.height_range[1] + 250.0
    _write_tif(files[1], higher, *east.origin, *east.spacing, terrain.crs)
    again = batch(tmp_path / "tiles", tmp_path / "out", **kwargs)
    assert again.ok and [r.key for r in again.done] == ["tile_0", "tile_1", "tile_sea"], again.summary()
    top = float(isovalues((0.0, terrain.height_range[1] + 250.0), interval=100.0)[-1])
    assert max(colours_by_height(again.done[0].path)) < top  # the west file's colours spread to the new level too
    west, east = (colours_by_height(r.path) for r in again.done[:2])
    assert all(west[z] == east[z] for z in set(west) & set(east) & shared)


def test_the_files_are_read_as_their_items_read_them(tmp_path):
    # the range of the heights each item steps: in feet, converted to metres (height_unit), and coarsened
    terrain, files = strips(tmp_path / "tiles", 2, step=4)
    feet = tmp_path / "feet"
    feet.mkdir()
    for f in files:
        dem = load_dem(f)
        _write_tif(feet / f.name, dem.heights / 0.3048, *dem.origin, *dem.spacing, terrain.crs)
    report = batch(feet, tmp_path / "out", interval=100.0, colors="terrain", height_unit="ft", coarsen=2,
                   scheduler="serial")  # fmt: skip
    assert report.ok
    coarse = [load_dem(f, height_unit="ft").coarsen(2) for f in (feet / f.name for f in files)]
    lo, hi = min(c.height_range[0] for c in coarse), max(c.height_range[1] for c in coarse)
    expected = isovalues((lo, hi), interval=100.0).tolist()
    for r in report.done:
        from .test_export import glb_json

        assert glb_json(Path(r.path))["meshes"][0]["extras"]["isovalues"] == pytest.approx(expected)


def test_cli_batch_of_a_folder_shares_colours_and_floor(tmp_path, capsys):
    _, files = strips(tmp_path / "tiles", 2, step=2)
    out = tmp_path / "out"
    argv = ["-q", "batch", str(tmp_path / "tiles"), "--interval", "100", "--colormap", "terrain", "--solid",
            "--format", ".ply", "-o", str(out), "--scheduler", "serial"]
    assert cli.main(argv) == 0, capsys.readouterr().err
    west, east = (colours_by_height(out / f"{f.stem}.ply") for f in files)
    floors = {min(c) for c in (west, east)}
    assert len(floors) == 1
    shared = set(west) & set(east) - floors
    assert len(shared) >= 5 and all(west[z] == east[z] for z in shared)
    assert cli.main(argv[1:]) == 0
    assert "0 written, 2 complete already, 0 failed" in capsys.readouterr().err
    assert os.path.getsize(out / MANIFEST_NAME) > 0


def test_dask_workers_get_the_shared_levels_and_floor(tmp_path):
    # the levels and floor are found in this process and reach every worker with the options
    distributed = pytest.importorskip("distributed", reason="needs dask.distributed")
    _, files = strips(tmp_path / "tiles", 3, step=4)
    kwargs = {"interval": 100.0, "colors": "terrain", "solid": True, "format": ".ply"}
    serial = batch(files, tmp_path / "serial", scheduler="serial", **kwargs)
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0")
    with cluster, distributed.Client(cluster) as client:
        on_dask = batch(files, tmp_path / "dask", scheduler=client, progress=True, **kwargs)
    assert serial.ok and on_dask.ok and len(on_dask.done) == 3
    for a, b in zip(serial.done, on_dask.done, strict=True):
        assert Path(a.path).read_bytes() == Path(b.path).read_bytes()
    assert len({float(np.asarray(read_mesh(r.path).vertices)[:, 2].min()) for r in on_dask.done}) == 1


def test_an_unreadable_file_fails_its_item_and_a_disk_error_is_retried_or_refuses_the_run(tmp_path, monkeypatch):
    import errno

    import stepterrain.io as io
    from stepterrain.errors import DataFileError

    _, files = strips(tmp_path / "tiles", 2, step=4)
    (tmp_path / "tiles" / "tile_bad.tif").write_bytes(b"II*\x00 not a GeoTIFF")
    kwargs = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    report = batch(tmp_path / "tiles", tmp_path / "out", **kwargs)
    assert [r.key for r in report.done] == ["tile_0", "tile_1"] and [r.key for r in report.failed] == ["tile_bad"]
    west, east = (colours_by_height(r.path) for r in report.done)
    assert all(west[z] == east[z] for z in set(west) & set(east))
    (tmp_path / "tiles" / "tile_bad.tif").unlink()
    real, calls = io.read_dem, []

    def flaky(path, **kwargs):  # the east file's disk fails with EIO `fails` times
        calls.append(str(path))
        if str(path) == str(files[1]) and calls.count(str(path)) <= fails:
            raise DataFileError(f"cannot read {str(path)!r}") from OSError(errno.EIO, "Input/output error")
        return real(path, **kwargs)

    monkeypatch.setattr(io, "read_dem", flaky)
    fails = 1  # retried in the range pass: the levels are those of both files
    report = batch(tmp_path / "tiles", tmp_path / "out2", retries=1, **kwargs)
    assert report.ok and calls.count(str(files[1])) == 3  # twice for the range, once for its item
    assert [r.bytes for r in report.done] == [r.bytes for r in batch(files, tmp_path / "out3", **kwargs).done]
    calls.clear()
    fails = 10  # still failing: the run is refused before any item, naming the file
    with pytest.raises(DataFileError, match=rf"cannot read '{files[1]}' for the height range every file's levels"):
        batch(tmp_path / "tiles", tmp_path / "out4", retries=1, **kwargs)
    assert not (tmp_path / "out4").exists()  # refused before the output folder is made


# ---------------------------------------------------------------------------------- follow-ups (h177)
def test_a_folder_without_interval_or_levels_gets_the_default_interval_of_all_files(tmp_path):
    # refused with "a folder or list of DEM files needs interval= or levels="; steps picks nice_interval over one
    # raster's heights, and a folder's files now share one range: that interval over all of them, recorded
    from stepterrain.stepped import nice_interval

    from .test_export import glb_json

    terrain, files = strips(tmp_path / "tiles", 2, step=4)
    report = batch(tmp_path / "tiles", tmp_path / "out", base=5.0, scheduler="serial")
    assert report.ok and [r.key for r in report.done] == ["tile_0", "tile_1"], report.summary()
    interval = nice_interval(terrain.height_range)
    expected = isovalues(terrain.height_range, interval=interval, base=5.0).tolist()
    for r in report.done:
        extras = glb_json(Path(r.path))["meshes"][0]["extras"]
        assert extras["interval"] == interval and extras["base"] == 5.0
        assert extras["isovalues"] == pytest.approx(expected)
    # the files' steps are the whole raster's steps at that interval
    whole = {float(z) for z in np.asarray(stepped(terrain, interval=interval, base=5.0).vertices)[:, 2]}
    assert set().union(*({float(z) for z in np.asarray(read_mesh(r.path).vertices)[:, 2]}
                         for r in report.done)) == whole  # fmt: skip
    assert len(batch(files, tmp_path / "out", base=5.0, scheduler="serial").skipped) == 2


def _count_reads(monkeypatch) -> list[str]:
    import stepterrain.io as io

    real, calls = io.read_dem, []

    def counted_read(path, **kwargs):
        calls.append(Path(path).name)
        return real(path, **kwargs)

    monkeypatch.setattr(io, "read_dem", counted_read)
    return calls


def test_a_rerun_reads_no_unchanged_file_for_the_range(tmp_path, monkeypatch):
    # every rerun read every file of the folder again for the shared height range, also when every item was then
    # skipped: each file's range is recorded in the manifest by the file's identity and read options
    terrain, files = strips(tmp_path / "tiles", 3, step=4)
    calls = _count_reads(monkeypatch)
    kwargs = {"interval": 100.0, "colors": "terrain", "solid": True, "format": ".ply", "scheduler": "serial"}
    out = tmp_path / "out"
    first = batch(tmp_path / "tiles", out, **kwargs)
    assert first.ok and sorted(calls) == sorted(2 * [f.name for f in files])  # the range pass, then the item
    calls.clear()
    again = batch(tmp_path / "tiles", out, **kwargs)
    assert len(again.skipped) == 3 and calls == []
    # another height unit reads them again (and the items: other heights); the manifest keeps this run's ranges
    calls.clear()
    assert batch(tmp_path / "tiles", out, height_unit="ft", **kwargs).ok and len(calls) == 6
    calls.clear()
    assert len(batch(tmp_path / "tiles", out, height_unit="ft", **kwargs).skipped) == 3 and calls == []
    assert len(batch(tmp_path / "tiles", out, **kwargs).done) == 3 and len(calls) == 6
    # a file touched (mtime changed, heights not): read again for the range, its item alone redone
    stat = files[2].stat()
    os.utime(files[2], ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    calls.clear()
    again = batch(tmp_path / "tiles", out, **kwargs)
    assert [r.key for r in again.done] == ["tile_2"] and calls == ["tile_2.tif", "tile_2.tif"]
    # a file rewritten higher: its new range is used, not the recorded one
    east = load_dem(files[2])
    higher = east.heights.copy()
    higher[3, 3] = terrain.height_range[1] + 250.0
    _write_tif(files[2], higher, *east.origin, *east.spacing, terrain.crs)
    calls.clear()
    again = batch(tmp_path / "tiles", out, **kwargs)
    assert again.ok and len(again.done) == 3 and calls.count("tile_2.tif") == 2 and len(calls) == 4
    # (every item redone: the shared levels moved) and the outputs are those of a run that read every file
    fresh = batch(tmp_path / "tiles", tmp_path / "fresh", **kwargs)
    assert [Path(r.path).read_bytes() for r in again.done] == [Path(r.path).read_bytes() for r in fresh.done]
    calls.clear()
    assert len(batch(tmp_path / "tiles", out, **kwargs).skipped) == 3 and calls == []


def test_ranges_a_manifest_lacks_are_read_once_and_then_recorded(tmp_path, monkeypatch):
    # a manifest of a run before the ranges were recorded (or with an entry edited into another form): its items
    # stay complete, the files are read once more and their ranges recorded although no item is redone
    _, files = strips(tmp_path / "tiles", 2, step=4)
    kwargs = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    out = tmp_path / "out"
    assert batch(tmp_path / "tiles", out, **kwargs).ok
    manifest = json.loads((out / MANIFEST_NAME).read_text())
    assert len(manifest["ranges"]) == 2
    key = sorted(manifest["ranges"])[0]
    manifest["ranges"] = {key: ["low", 3.0]}
    (out / MANIFEST_NAME).write_text(json.dumps(manifest))
    calls = _count_reads(monkeypatch)
    again = batch(tmp_path / "tiles", out, **kwargs)
    assert len(again.skipped) == 2 and len(calls) == 2
    assert len(json.loads((out / MANIFEST_NAME).read_text())["ranges"]) == 2
    calls.clear()
    assert len(batch(tmp_path / "tiles", out, **kwargs).skipped) == 2 and calls == []


def test_cli_batch_of_a_folder_needs_no_interval_and_colours_as_steps(tmp_path, capsys):
    # `stepterrain batch FOLDER -o out` was refused (needs --interval or --levels), and its meshes were grey unless
    # --colormap was given (default none, unlike steps' terrain); now as steps: a default interval, terrain colours
    from stepterrain.stepped import nice_interval

    terrain, files = strips(tmp_path / "tiles", 2, step=4)
    out = tmp_path / "out"
    assert cli.main(["-q", "batch", str(tmp_path / "tiles"), "--format", ".ply", "-o", str(out), "--scheduler",
                     "serial"]) == 0, capsys.readouterr().err  # fmt: skip
    west, east = (colours_by_height(out / f"{f.stem}.ply") for f in files)
    values = {float(v) for v in isovalues(terrain.height_range, interval=nice_interval(terrain.height_range))}
    shared = set(west) & set(east) & values
    assert len(shared) >= 5 and all(west[z] == east[z] and len(west[z]) == 1 for z in shared)
    assert len({c for z in shared for c in west[z]}) == len(shared)  # coloured by level, not one grey
    steps_out = tmp_path / "whole.ply"
    np.save(tmp_path / "whole.npy", terrain.heights)
    assert cli.main(["-q", "steps", str(tmp_path / "whole.npy"), "--interval", str(nice_interval(
        terrain.height_range)), "-o", str(steps_out)]) == 0  # fmt: skip
    whole = colours_by_height(steps_out)
    assert all(whole[z] == west[z] for z in shared)  # steps' default colours
    # .stl holds no colours: no colormap by default, as steps writes an .stl without one; a named one still refused
    assert cli.main(["-q", "batch", str(tmp_path / "tiles"), "--format", ".stl", "-o", str(tmp_path / "stl"),
                     "--scheduler", "serial"]) == 0  # fmt: skip
    assert sorted(p.name for p in (tmp_path / "stl").glob("*.stl")) == ["tile_0.stl", "tile_1.stl"]
    capsys.readouterr()
    assert cli.main(["-q", "batch", str(tmp_path / "tiles"), "--format", ".stl", "--colormap", "terrain", "-o",
                     str(tmp_path / "stl2"), "--scheduler", "serial"]) == 2  # fmt: skip
    assert "--format .stl holds no colours" in capsys.readouterr().err


def test_a_bad_output_dir_is_refused_before_any_file_is_read(tmp_path, monkeypatch):
    # the range pass ran before output_dir was checked: every file was read, then the argument refused
    strips(tmp_path / "tiles", 2, step=4)
    calls = _count_reads(monkeypatch)
    with pytest.raises(InvalidInputError, match="output_dir must be a str or os.PathLike; got int"):
        batch(tmp_path / "tiles", 123, interval=100.0, colors="terrain", scheduler="serial")
    assert calls == []


def test_an_output_dir_in_use_or_not_a_folder_is_refused_before_any_file_is_read(tmp_path, monkeypatch):
    # the range pass ran before the output folder was checked and locked: every file was read (minutes for a large
    # folder), then the run refused as writing into a file, or into a folder another run was writing
    from stepterrain.batch import _FolderLock
    from stepterrain.errors import DataFileError

    strips(tmp_path / "tiles", 2, step=4)
    calls = _count_reads(monkeypatch)
    kwargs = {"interval": 100.0, "colors": "terrain", "scheduler": "serial"}
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(DataFileError, match="exists and is not a folder"):
        batch(tmp_path / "tiles", tmp_path / "file", **kwargs)
    assert calls == []
    (tmp_path / "busy").mkdir()
    other = _FolderLock(tmp_path / "busy")  # another run writing there
    try:
        with pytest.raises(DataFileError, match="in use by another stepterrain batch run"):
            batch(tmp_path / "tiles", tmp_path / "busy", **kwargs)
        assert calls == []
    finally:
        other.release()
    # a floor refused after the range pass leaves no output folder made for it, nor its lock
    with pytest.raises(InvalidInputError, match="floor"):
        batch(tmp_path / "tiles", tmp_path / "new" / "out", solid=True, floor=1e6, **kwargs)
    assert len(calls) == 2 and not (tmp_path / "new").exists()


def test_the_recorded_ranges_outlast_a_run_that_reads_no_file(tmp_path, monkeypatch):
    # a run that needs no range (no colours, no solid, an interval) rewrote the manifest without the recorded ranges:
    # the next coloured run, every item complete, read every file again
    _, files = strips(tmp_path / "tiles", 2, step=4)
    out = tmp_path / "out"
    coloured = {"interval": 100.0, "colors": "terrain", "format": ".ply", "scheduler": "serial"}
    assert batch(tmp_path / "tiles", out, **coloured).ok
    calls = _count_reads(monkeypatch)
    plain = batch(tmp_path / "tiles", out, interval=100.0, format=".glb", scheduler="serial")
    assert len(plain.done) == 2 and sorted(calls) == sorted(f.name for f in files)  # the items alone
    assert len(json.loads((out / MANIFEST_NAME).read_text())["ranges"]) == 2
    calls.clear()
    again = batch(tmp_path / "tiles", out, **coloured)
    assert len(again.skipped) == 2 and calls == []
