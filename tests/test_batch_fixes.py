"""Batch bugs found by an adversarial pass (each test failed before its fix)."""

from __future__ import annotations

import re
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from stepterrain.batch import MANIFEST_NAME, batch
from stepterrain.export import read_mesh
from stepterrain.mesh import boundary_edges

from .conftest import needs_render, shared_file


def test_a_rerun_removes_the_partial_temporary_files_a_killed_run_left(tmp_path):
    # a run killed while writing left its hidden temporary file (16 MB of a 174 MB tile, say) beside the outputs,
    # and every rerun kept it, done or not: the truncated bytes stayed in the output folder for good
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    out = tmp_path / "out"
    out.mkdir()
    stale = [out / ".tile_r0_c0.glb.k2x9abcd.tmp", out / ".tile_r1_c1.glb.zz_1e0_q.tmp",
             out / f".{MANIFEST_NAME}.q1w2e3r4.tmp"]
    for path in stale:
        path.write_bytes(b"glTF partial")
    kept = [out / ".tile_r0_c0.ply.k2x9abcd.tmp", out / ".notes.k2x9abcd.tmp", out / "tile_r0_c0.glb.tmp",
            out / ".tile_r0_c0.glb.k2x9abcdef.tmp"]  # not this run's temporary files
    for path in kept:
        path.write_bytes(b"other")
    report = batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
    assert report.ok and len(report.done) == 4
    assert not any(p.exists() for p in stale)
    assert all(p.read_bytes() == b"other" for p in kept)
    # a skipped (complete) item's leftover goes too
    (out / ".tile_r0_c1.glb.abc_1234.tmp").write_bytes(b"glTF partial")
    report = batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
    assert len(report.skipped) == 4 and not (out / ".tile_r0_c1.glb.abc_1234.tmp").exists()


@pytest.mark.parametrize("fmt", [".glb", ".gltf", ".ply"])
@pytest.mark.parametrize("spacing, origin", [
    ((30.0, -30.0), (376328.6554542635, 3807902.8276283755)),  # the embedded DEM's UTM origin
    ((3000.0, 3000.0), (1000.3, 2000.7)),  # local metres whose extent crosses 65536: some tiles small, some large
], ids=["utm", "straddle"])
def test_tiles_written_as_float32_weld_exactly(tmp_path, fmt, spacing, origin):
    # Found by welding the GLB tiles of `stepterrain batch --tile 128` (the embedded DEM) with exact vertex
    # equality (trimesh's merge_vertices): 31377 boundary edges against the whole raster's 4227. glTF stores
    # float32 positions relative to a node translation, the floor of each *tile's* lowest corner, so a vertex
    # two tiles share was rounded differently in each; PLY chose float32 or float64 per tile (by its own
    # coordinates' size), so beside 65536 one tile rounded the seam and its neighbour did not
    rng = np.random.default_rng(5)
    z = (rng.random((33, 41)) * 40 + 100).astype(np.float32)
    z[16, 3] = z[10, 20] = np.nan  # nodata on the shared borders too
    report = batch(z, tmp_path, tile_size=(16, 20), interval=3.0, spacing=spacing, origin=origin, format=fmt,
                   scheduler="serial")  # fmt: skip
    assert report.ok and len(report.done) == 2 * 2
    meshes = [read_mesh(r.path) for r in report.done]  # node translations applied
    vertices = np.concatenate([np.asarray(m.vertices, np.float64) for m in meshes])
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])[:-1]
    faces = np.concatenate([np.asarray(m.faces) + o for m, o in zip(meshes, offsets, strict=True)])
    unique, inverse = np.unique(vertices, axis=0, return_inverse=True)  # exact equality: no rounding
    faces = inverse.reshape(-1)[faces]
    xy = unique[boundary_edges(faces)][:, :, :2]
    (x_lo, x_hi), (y_lo, y_hi) = ((origin[k] + min(0.0, n * spacing[k]), origin[k] + max(0.0, n * spacing[k]))
                                  for k, n in ((0, z.shape[1] - 1), (1, z.shape[0] - 1)))
    near = 1e-3 * abs(spacing[0])
    on_border = (
        (np.abs(xy[:, :, 0] - x_lo) < near).all(1) | (np.abs(xy[:, :, 0] - x_hi) < near).all(1)
        | (np.abs(xy[:, :, 1] - y_lo) < near).all(1) | (np.abs(xy[:, :, 1] - y_hi) < near).all(1)
    )  # fmt: skip
    seams = np.abs(xy - np.array([origin[0] + 20 * spacing[0], origin[1] + 16 * spacing[1]])) < near
    # the holes' rims are boundaries of the whole raster's mesh too: only edges *along* a seam count
    along_seam = (seams[:, :, 0].all(1) | seams[:, :, 1].all(1)) & ~on_border
    assert not along_seam.any(), f"{int(along_seam.sum())} open edges along the seams (cracks)"


def test_save_mesh_shared_bounds_are_checked(tmp_path):
    from stepterrain.errors import InvalidInputError
    from stepterrain.export import save_mesh

    with pytest.raises(InvalidInputError, match=r"shared_bounds must be finite \(2, 3\) corners"):
        save_mesh(trimesh.creation.box(), tmp_path / "box.glb", shared_bounds=[[0, 0, np.nan], [1, 1, 1]])
    # a box far from the origin, stored relative to the floor of the shared bounds' centre: world positions come back
    box = trimesh.creation.box()
    box.apply_translation([400000.5, 3800000.25, 10.0])
    out = save_mesh(box, tmp_path / "box.glb", shared_bounds=[[399000.7, 3799000.2, -3.5], [401000.0, 3801000.0, 50]])
    from .test_export import glb_json

    # the local origin (400000, 3800000, 23) in glTF's y-up world: (ox, oz, -oy)
    assert glb_json(out)["nodes"][0]["translation"] == [400000.0, 23.0, -3800000.0]
    np.testing.assert_allclose(read_mesh(out).vertices, box.vertices, atol=1e-6)


# a batch run in another process that holds its first item until the file `go` appears (`started` says it began)
_HELD_RUN = """
import sys, time
from pathlib import Path
import re
from pathlib import Path

import numpy as np
import stepterrain.batch

b = sys.modules["stepterrain.batch"]

out, signals = Path(sys.argv[1]), Path(sys.argv[2])
real = b.run_item

def held(*args, **kwargs):
    (signals / "started").touch()
    while not (signals / "go").exists():
        time.sleep(0.02)
    return real(*args, **kwargs)

b.run_item = held
z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
report = b.batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
print(len(report.done), report.ok)
"""


def test_a_second_run_into_a_folder_in_use_is_refused_naming_the_folder_and_the_other_run(tmp_path):
    # two runs into one folder at once both rewrote the manifest (each from what it had read at its start, so
    # one run's records were lost), wrote the same outputs, and the second removed the first one's temporary
    # files as "left by a killed run", failing its items
    import os
    import subprocess
    import sys
    import time

    from stepterrain.batch import LOCK_NAME
    from stepterrain.errors import DataFileError

    out, signals = tmp_path / "out dir é", tmp_path / "signals"
    signals.mkdir()
    script = tmp_path / "held_run.py"
    script.write_text(_HELD_RUN)
    other = subprocess.Popen([sys.executable, str(script), str(out), str(signals)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not (signals / "started").exists():
            assert other.poll() is None, other.communicate()
            assert time.monotonic() < deadline, "the other run did not start"
            time.sleep(0.05)
        z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
        refused = rf"output folder .*out dir é.* is in use by another stepterrain batch run \(pid {other.pid} on .*\)"
        with pytest.raises(DataFileError, match=refused):
            batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
        assert not (out / MANIFEST_NAME).exists()  # the refused run wrote nothing
    finally:
        (signals / "go").touch()
        stdout, stderr = other.communicate(timeout=120)
    assert other.returncode == 0, stderr
    assert stdout.split() == ["4", "True"]
    assert not (out / LOCK_NAME).exists()  # the finished run took its lock file away
    # the folder is free again: a rerun resumes what the other run recorded
    assert len(batch(z, out, tile_size=4, interval=2.0, scheduler="serial").skipped) == 4
    # a lock file a killed run left (its process gone, so its lock too) does not block the folder
    (out / LOCK_NAME).write_text(f"pid {os.getpid() + 10**6} on nowhere, started long ago")
    assert len(batch(z, out, tile_size=4, interval=2.0, scheduler="serial").skipped) == 4
    assert not (out / LOCK_NAME).exists()


def test_a_rerun_in_another_format_keeps_both_formats_recorded_and_says_so(tmp_path):
    # the manifest held one entry per item: a .ply rerun replaced the .glb entries, so the .glb files stayed in the
    # folder unrecorded (the report said nothing of them), and a .glb run after it redid every complete .glb
    import json

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    first = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    assert len(first.done) == 4 and first.notes == []
    glb = {r.key: (tmp_path / f"{r.key}.glb").read_bytes() for r in first.done}
    ply = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial", format=".ply")
    assert len(ply.done) == 4 and not ply.skipped  # the .glb outputs do not count as complete .ply ones
    assert ply.notes == ["the manifest also records 4 outputs of these items in another format (.glb), kept "
                         "beside this run's .ply files"]  # fmt: skip
    assert "note: the manifest also records 4 outputs" in ply.summary()
    recorded = json.loads((tmp_path / MANIFEST_NAME).read_text())["items"]
    assert sorted(recorded) == sorted(f"{k}{e}" for k in glb for e in (".glb", ".ply"))
    # both formats are complete: reruns in either skip everything, and the .glb files are the first run's
    assert len(batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial").skipped) == 4
    assert len(batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial", format=".ply").skipped) == 4
    assert all((tmp_path / f"{k}.glb").read_bytes() == data for k, data in glb.items())
    # other heights: the .glb outputs are redone, and the .ply ones (now stale) are no longer complete either
    assert len(batch(z + 1, tmp_path, tile_size=4, interval=2.0, scheduler="serial").done) == 4
    assert len(batch(z + 1, tmp_path, tile_size=4, interval=2.0, scheduler="serial", format=".ply").done) == 4
    # resume=False redoes this format but keeps the other's records
    assert len(batch(z + 1, tmp_path, tile_size=4, interval=2.0, scheduler="serial", resume=False).done) == 4
    assert len(batch(z + 1, tmp_path, tile_size=4, interval=2.0, scheduler="serial", format=".ply").skipped) == 4


def test_a_manifest_of_an_earlier_version_is_read_by_file(tmp_path):
    # manifests written before the per-file layout (version 1, keyed by item) keep their complete outputs
    import json

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    old = {entry["file"].rsplit(".", 1)[0]: entry for entry in data["items"].values()}
    (tmp_path / MANIFEST_NAME).write_text(json.dumps({"version": 1, "items": old}))
    report = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    assert len(report.skipped) == 4 and report.notes == []


@pytest.mark.parametrize("text, why", [
    ('{"version": 2, "items": {"tile_r0_c0.glb": {"fingerp', r"is not valid JSON \(cut short or edited"),
    ("[1, 2]", r"expected an object with version 1 or 2 and its items; got a JSON list"),
    ('{"version": 7, "items": {}}', r"got version 7"),
    ('{"version": 2, "items": []}', r"got version 2"),
    ("\xff\xfe", r"is not valid JSON"),
])  # fmt: skip
def test_a_manifest_cut_short_or_edited_is_reported_and_replaced(tmp_path, text, why):
    # an unreadable manifest was taken as empty without a word: every complete output was redone silently
    import json

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    (tmp_path / MANIFEST_NAME).write_bytes(text.encode("latin-1"))
    report = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    assert len(report.done) == 4 and report.ok
    assert len(report.notes) == 1
    assert re.search(rf"^the manifest {MANIFEST_NAME} .*{why}.*; it is written afresh", report.notes[0])
    assert f"note: the manifest {MANIFEST_NAME}" in report.summary()
    assert len(json.loads((tmp_path / MANIFEST_NAME).read_text())["items"]) == 4
    assert batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial").notes == []


def test_a_manifest_entry_edited_by_hand_is_not_complete(tmp_path):
    # an entry naming another file (or a size that is no int) made its item "skipped" with that file as its output
    import json

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    data = json.loads((tmp_path / MANIFEST_NAME).read_text())
    entry = data["items"]["tile_r0_c0.glb"]
    (tmp_path / "elsewhere.glb").write_bytes((tmp_path / "tile_r0_c0.glb").read_bytes())
    entry["file"] = "elsewhere.glb"
    data["items"]["tile_r0_c1.glb"]["bytes"] = float(data["items"]["tile_r0_c1.glb"]["bytes"]) + 0.5
    (tmp_path / MANIFEST_NAME).write_text(json.dumps(data))
    report = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    assert sorted(r.key for r in report.done) == ["tile_r0_c0", "tile_r0_c1"]
    assert all(r.path == str(tmp_path / f"{r.key}.glb") for r in report.results)


def test_a_folder_on_a_file_system_without_locks_is_written_and_the_report_says_so(tmp_path, monkeypatch):
    # some network and FUSE mounts answer flock with ENOLCK or EOPNOTSUPP: the lock must not make batch refuse
    # every such folder; the run goes on and the report says a second run would not be refused there
    import errno
    import fcntl

    from stepterrain.batch import LOCK_NAME

    def no_locks(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    report = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    assert report.ok and len(report.done) == 4
    assert report.notes == [f"the file system of the output folder {str(tmp_path)!r} does not support file locks: "
                            "another batch run into it at the same time would not be refused"]  # fmt: skip
    assert not (tmp_path / LOCK_NAME).exists()


@pytest.mark.render
def test_the_overview_of_3mf_tiles_shows_their_colours(tmp_path):
    """overview_image read the outputs with trimesh, whose 3MF reader ignores the colour group: coloured 3MF tiles
    were drawn in the plain tan. It reads them as ``stepterrain info`` does (export.read_mesh): the same picture as
    of the same tiles written as PLY, whose colours trimesh reads."""
    from stepterrain import render
    from stepterrain.batch import overview_image

    from .conftest import real_dem

    ok, reason = render.offscreen_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL context: {reason}")
    z = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=33, step=4)
    pictures = {}
    for ext in (".3mf", ".ply"):
        report = batch(z, tmp_path / ext[1:], tile_size=16, interval=100.0, colors="terrain", format=ext,
                       scheduler="serial")  # fmt: skip
        assert report.ok
        pictures[ext] = overview_image(report, window_size=(320, 200))
    terrain = (pictures[".ply"][..., :3] != pictures[".ply"][0, 0, :3]).any(axis=-1)
    assert terrain.mean() > 0.005
    np.testing.assert_array_equal(pictures[".3mf"], pictures[".ply"])


def test_a_manifest_that_is_a_folder_is_refused_before_any_item_runs(tmp_path):
    # it was read as "could not be read", every item ran, and only the manifest's final write failed
    from stepterrain.errors import DataFileError

    out = tmp_path / "out"
    (out / MANIFEST_NAME).mkdir(parents=True)
    with pytest.raises(DataFileError, match="is a folder"):
        batch(np.zeros((3, 5, 6), np.float32), out, interval=1.0, scheduler="serial")
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST_NAME]


_Z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)


@pytest.mark.parametrize("shape", [(0, 0), (0, 5)])
def test_an_empty_raster_to_tile_is_refused_by_its_size(tmp_path, shape):
    # the height range was taken before the size was checked: min() of no heights, numpy's bare ValueError
    from stepterrain.batch import plan_items
    from stepterrain.errors import InvalidInputError

    message = rf"^a raster to tile needs at least 2 x 2 nodes; got {shape[0]} x {shape[1]}$"
    with pytest.raises(InvalidInputError, match=message):
        plan_items(np.zeros(shape, np.float32), tile_size=3)
    with pytest.raises(InvalidInputError, match=message):
        batch(np.zeros(shape, np.float32), tmp_path / "out", tile_size=3, interval=1.0, scheduler="serial")
    assert not (tmp_path / "out").exists()


def test_retries_as_a_numpy_uint64_runs_each_item(tmp_path):
    # range(1, retries + 2) in uint64 wrapped to range(1, 1) (with numpy's overflow warning): no attempt ran and every
    # item was reported failed with an empty error
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report = batch(_Z, tmp_path, tile_size=4, interval=2.0, scheduler="serial", retries=np.uint64(2**64 - 1))
    assert report.ok and len(report.done) == 4 and all(r.attempts == 1 for r in report.done)


@pytest.mark.parametrize(
    "device, error, message",
    [
        (
            5,
            "InvalidInputError",
            r"^device must be a Warp device name \('cpu', 'cuda:0'\), a warp.Device or None; got 5$",
        ),
        ("abc", "DeviceError", r"^device must be one of \[.*\] \(or None\); got 'abc'$"),
    ],
)
def test_a_bad_device_of_a_serial_batch_is_refused_before_any_work(tmp_path, device, error, message):
    # str(device) went to every item, each failing (with its retries) the same way, in a report that was not ok
    import stepterrain.errors as errors

    with pytest.raises(getattr(errors, error), match=message):
        batch(_Z, tmp_path / "out", tile_size=4, interval=2.0, scheduler="serial", device=device)
    assert not (tmp_path / "out").exists()


def test_the_package_attribute_batch_is_the_module_and_its_entry_point(tmp_path):
    """``stepterrain/__init__`` bound ``st.batch`` to the function, so ``st.batch.LOCAL_CLUSTER_MALLOC`` (and every
    name of the module) raised AttributeError. It is now the module, callable as :func:`batch` with batch's
    signature, and it pickles by name (dask's workers import the module's task functions by qualified name)."""
    import inspect
    import pickle

    import cloudpickle

    import stepterrain as st
    import stepterrain.batch as batch_module

    assert st.batch is batch_module
    assert st.batch.LOCAL_CLUSTER_MALLOC is batch_module.LOCAL_CLUSTER_MALLOC
    assert st.batch.batch is batch
    assert inspect.signature(st.batch) == inspect.signature(batch)
    for dumps, loads in ((pickle.dumps, pickle.loads), (cloudpickle.dumps, cloudpickle.loads)):
        assert loads(dumps(st.batch)) is st.batch
        assert loads(dumps(batch_module.run_item)) is batch_module.run_item
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    report = st.batch(z, tmp_path / "out", tile_size=4, interval=2.0, scheduler="serial")
    assert isinstance(report, st.BatchReport) and report.ok and len(report.done) == 4
    with pytest.raises(TypeError, match="tile_sizes"):  # the call is batch's: its keywords are checked
        st.batch(z, tmp_path / "out2", tile_sizes=4)


@pytest.mark.parametrize(
    "keys",
    [{"transform": np.array([5e5, 30.0, 0.0, 4e6, 0.0, -30.0]), "crs": "EPSG:32611"},
     {"dx": 30.0, "dy": 30.0, "crs": "EPSG:32611"}, {"spacing": (30.0, -30.0), "origin": (5e5, 4e6)},
     {"lat": np.linspace(45.0, 44.0, 3), "lon": np.linspace(5.0, 6.0, 4)}],
)  # fmt: skip
def test_a_series_npz_with_georeferencing_keys_is_refused_not_meshed_as_metre_cells(tmp_path, keys):
    # load_series read only the stack and 'nodata': np.savez(heights=(T, H, W), transform=..., crs=...) (or dx/dy,
    # spacing/origin, lat/lon) was meshed frame by frame as 1 m cells at (0, 0), the keys ignored without a word,
    # where load_dem refuses such keys it cannot read ("refuse an .npz whose georeferencing keys have no transform")
    from stepterrain.batch import load_series
    from stepterrain.errors import DataFileError

    stack = np.random.default_rng(3).random((2, 3, 4)).astype(np.float32) * 100.0
    np.savez(tmp_path / "series.npz", heights=stack, nodata=-9999.0, **keys)
    named = ", ".join(repr(k) for k in keys)
    message = rf"series\.npz.*series is meshed unreferenced, as 1 m cells.*got {named} beside 'heights'"
    with pytest.raises(DataFileError, match=message):
        load_series(tmp_path / "series.npz")
    with pytest.raises(DataFileError, match=message):
        batch(tmp_path / "series.npz", tmp_path / "out", interval=10.0, scheduler="serial")
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").glob("frame_*"))
    np.savez(tmp_path / "plain.npz", heights=stack, nodata=-9999.0)  # no such key: a series, unreferenced
    np.testing.assert_array_equal(load_series(tmp_path / "plain.npz"), stack)
    np.savez(tmp_path / "raster.npz", heights=stack[0], **keys)  # 2-D: not a series, load_dem's to read or refuse
    assert load_series(tmp_path / "raster.npz") is None


def test_a_series_npz_in_feet_is_meshed_in_metres_as_load_dem_reads_it(tmp_path):
    """load_series ignored an .npz's 'units': a (T, H, W) series in feet was meshed as metres, 3.28 times too high,
    where load_dem converts a 2-D file's heights (found by helper 36). An unknown unit is refused as load_dem
    refuses it."""
    from stepterrain.batch import load_series
    from stepterrain.errors import DataFileError
    from stepterrain.io import load_dem

    stack = np.random.default_rng(4).random((2, 3, 4)).astype(np.float32) * 1000.0
    np.savez(tmp_path / "feet.npz", heights=stack, units="ft")
    expected = (stack.astype(np.float64) * 0.3048).astype(np.float32)
    np.testing.assert_array_equal(load_series(tmp_path / "feet.npz"), expected)
    np.savez(tmp_path / "frame.npz", heights=stack[1], units="ft")
    np.testing.assert_array_equal(load_dem(tmp_path / "frame.npz").heights, expected[1])  # as load_dem reads it
    np.savez(tmp_path / "odd.npz", heights=stack, units="furlong")
    with pytest.raises(DataFileError, match=r"expected heights in a known length unit .*got 'furlong' \(its 'units'\)"):
        load_series(tmp_path / "odd.npz")


def _dem_crop() -> tuple[np.ndarray, tuple[float, float], tuple[float, float]]:
    """A 64 x 80 crop of the embedded DEM, its spacing and its own UTM origin."""
    import stepterrain as st

    dem = st.sample_dem()
    (dx, dy), (x0, y0) = dem.spacing, dem.origin
    return dem.heights[100:164, 200:280].copy(), dem.spacing, (x0 + 200 * dx, y0 + 100 * dy)


@pytest.mark.parametrize("kwargs", [
    dict(interval=20.0, base=0.5), dict(interval=20.0, base=0.5, gamma=0.4),
    dict(levels=[1200.3, 1300.3], gamma=0.5),  # heights under the lowest level pull the surface below it
    dict(),  # the default interval: the floor lay a tenth of the levels' span down, not one interval
], ids=["interval", "interval-gamma", "levels-gamma", "default"])  # fmt: skip
def test_solid_tiles_are_closed_at_the_floor_of_the_whole_rasters_solid(tmp_path, kwargs):
    """Each tile was stepped alone with the shared levels but without the interval, so its solid's default floor was
    a tenth of the levels' span under the *tile's* lowest vertex: 954 m under interval=20 where the whole raster's
    solid stands on 980 m, and with levels and γ < 1 nine different floors in nine tiles. Every tile now stands on
    the floor ``stepped`` gives the whole raster."""
    import stepterrain as st

    from .test_export import glb_json

    z, spacing, origin = _dem_crop()
    z[3:7, 30:40] = np.nan  # nodata on a tile border
    chosen = kwargs or {"interval": st.stepped.nice_interval((np.nanmin(z), np.nanmax(z)))}  # batch's default
    whole = st.stepped(z, spacing=spacing, origin=origin, solid=True, **chosen)
    report = batch(z, tmp_path, tile_size=(20, 27), spacing=spacing, origin=origin, solid=True, format=".glb",
                   scheduler="serial", **kwargs)  # fmt: skip
    assert report.ok and len(report.done) == 4 * 3
    floors = {glb_json(tmp_path / f"{r.key}.glb")["meshes"][0]["extras"]["floor"] for r in report.done}
    assert floors == {whole.metadata["floor"]}
    lowest = [read_mesh(r.path).vertices[:, 2].min() for r in report.done]
    np.testing.assert_allclose(lowest, whole.vertices[:, 2].min(), atol=1e-3)  # the base itself lies there


def test_solid_frames_of_a_series_stand_on_one_floor(tmp_path):
    """Every frame of a series was closed under its own lowest vertex: the base jumped from frame to frame. The
    frames share the floor of the series as one raster (its frames side by side: the same heights and levels)."""
    import stepterrain as st

    z, _, _ = _dem_crop()
    frames = np.stack([z[:20, :30], z[20:40, :30] + 40.0, z[40:60, :30] - 30.0])
    side_by_side = np.concatenate(list(frames), axis=1)
    for kwargs in (dict(interval=20.0, base=0.5, gamma=0.7), dict(levels=[1150.3, 1250.3, 1400.3], gamma=0.3)):
        whole = st.stepped(side_by_side, solid=True, **kwargs)
        report = batch(frames, tmp_path / str(len(kwargs["levels"]) if "levels" in kwargs else "interval"),
                       solid=True, format=".ply", scheduler="serial", **kwargs)  # fmt: skip
        assert report.ok and len(report.done) == 3
        lowest = [read_mesh(r.path).vertices[:, 2].min() for r in report.done]
        np.testing.assert_allclose(lowest, whole.metadata["floor"], atol=1e-4)


def test_a_terrain_with_vertex_colours_is_refused_not_tiled_grey(tmp_path):
    """stepped() carries a grid Terrain's vertex colours onto its steps; batch cut its tiles from the heights alone
    and wrote them without colours (trimesh's grey), silently. Such a source is refused, naming its visual, unless
    colors= (which replaces the carried colours in stepped() as well) or solid (which carries none) is given."""
    import stepterrain as st
    from stepterrain.errors import InvalidInputError

    z, spacing, origin = _dem_crop()
    z = z[:20, :24]
    red = np.tile(np.array([[200, 10, 10, 255]], np.uint8), (z.size, 1))
    terrain = st.Terrain(kind="grid", heights=z, spacing=spacing, origin=origin,
                         visual=trimesh.visual.ColorVisuals(vertex_colors=red))  # fmt: skip
    assert (st.stepped(terrain, interval=50.0).visual.vertex_colors == red[0]).all()  # the whole raster is red
    with pytest.raises(InvalidInputError, match=r"^source is a Terrain with a visual \(ColorVisuals\).*give colors="):
        batch(terrain, tmp_path / "out", tile_size=10, interval=50.0, format=".ply", scheduler="serial")
    assert not (tmp_path / "out").exists()
    report = batch(terrain, tmp_path / "out", tile_size=10, interval=50.0, colors="terrain", format=".ply",
                   scheduler="serial")  # fmt: skip
    whole = st.stepped(terrain, interval=50.0, colors="terrain")
    assert report.ok and {tuple(c) for r in report.done
                          for c in trimesh.load(r.path, process=False).visual.vertex_colors} == {
        tuple(c) for c in whole.visual.vertex_colors}  # fmt: skip


def test_a_skipped_item_reports_the_faces_and_vertices_of_its_output(tmp_path):
    """A rerun reported every complete (skipped) item with 0 faces and 0 vertices, though its output holds the mesh
    the first run wrote (and the manifest records its counts)."""
    z, spacing, origin = _dem_crop()
    first = batch(z[:30, :40], tmp_path, tile_size=16, interval=50.0, base=0.5, format=".ply", scheduler="serial")
    again = batch(z[:30, :40], tmp_path, tile_size=16, interval=50.0, base=0.5, format=".ply", scheduler="serial")
    assert len(again.skipped) == len(first.done) == 2 * 3
    for result in again.skipped:
        mesh = trimesh.load(result.path, process=False)
        assert (result.faces, result.vertices) == (len(mesh.faces), len(mesh.vertices)) != (0, 0)


def test_outputs_of_an_earlier_runs_other_tiles_are_noted(tmp_path):
    """A rerun with another tile size left the earlier run's extra tiles (tile_r3_c3.glb ...) in the folder and the
    manifest and said nothing: out/*.glb then loaded overlapping stale tiles with the new ones (found by helper 39).
    The report notes them (they are left as they were: they may be wanted)."""
    from pathlib import Path

    heights = np.add.outer(np.arange(12.0), np.arange(14.0))
    first = batch(heights, tmp_path / "out", tile_size=4, interval=2.0, scheduler="serial")
    assert first.ok and not first.notes
    second = batch(heights, tmp_path / "out", tile_size=8, interval=2.0, scheduler="serial")
    stale = {Path(r.path).name for r in first.done} - {Path(r.path).name for r in second.done}
    assert second.ok and stale
    note = next(n for n in second.notes if "items this run does not have" in n)
    assert len(stale) > 1 and note.startswith(f"the folder holds {len(stale)} recorded outputs of items")
    assert all((tmp_path / "out" / name).exists() for name in stale)


# the top-left cell's centre y is 2000.5, then 3000.5: a world file names the centre, a GeoTransform the corner
@pytest.mark.parametrize("sidecar, text", [
    ("dem.tfw", "10\n0\n0\n-10\n1000.5\n{y}\n"),  # a world file: the georeferencing of a TIFF without its own
    ("DEM.TFW", "10\n0\n0\n-10\n1000.5\n{y}\n"),  # GDAL finds it in upper case too
    ("dem.tif.aux.xml", "<PAMDataset><GeoTransform>995.5, 10, 0, {y}5.5, 0, -10</GeoTransform></PAMDataset>\n"),
], ids=["tfw", "TFW", "aux.xml"])
def test_a_changed_georeferencing_sidecar_redoes_the_geotiff_item(tmp_path, sidecar, text):
    # the fingerprint of a file item was its path, size and mtime alone: GDAL reads a GeoTIFF's origin from a world
    # file or a PAM .aux.xml beside it, so a rerun after the sidecar was added or corrected skipped the tile as
    # complete and kept the mesh at the old origin
    rasterio = pytest.importorskip("rasterio")
    import warnings

    folder = tmp_path / "dems"
    folder.mkdir()
    z = np.add.outer(np.arange(5.0), np.arange(6.0)).astype(np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning: a plain TIFF
        with rasterio.open(folder / "dem.tif", "w", driver="GTiff", width=6, height=5, count=1,
                           dtype="float32") as dataset:  # fmt: skip
            dataset.write(z, 1)
    out = tmp_path / "out"

    def lowest_y():
        report = batch(folder, out, interval=1.0, format=".ply", scheduler="serial")
        assert report.ok
        mesh = trimesh.load(out / "dem.ply", process=False)
        return len(report.done), float(np.asarray(mesh.vertices)[:, 1].min())

    assert lowest_y() == (1, -4.0)  # no georeferencing: rows run south from y = 0
    corner = sidecar.endswith(".xml")
    (folder / sidecar).write_text(text.format(y="200" if corner else "2000.5"))
    assert lowest_y() == (1, 2000.5 - 40)  # 4 rows of 10 m south
    (folder / sidecar).write_text(text.format(y="300" if corner else "3000.5"))  # corrected in place: same size
    assert lowest_y() == (1, 3000.5 - 40)
    assert lowest_y() == (0, 3000.5 - 40)  # unchanged: skipped


def test_a_changed_prj_beside_a_world_file_tiff_redoes_its_item(tmp_path):
    # load_dem reads the CRS of a TIFF georeferenced by a world file from the .prj beside it (GDAL does not): a rerun
    # after the .prj was added or corrected skipped the item as complete, its mesh in the old CRS's units
    rasterio = pytest.importorskip("rasterio")
    import warnings

    from rasterio.crs import CRS

    folder = tmp_path / "dems"
    folder.mkdir()
    z = np.add.outer(np.arange(5.0), np.arange(6.0)).astype(np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rasterio's NotGeoreferencedWarning: a plain TIFF
        with rasterio.open(folder / "dem.tif", "w", driver="GTiff", width=6, height=5, count=1,
                           dtype="float32") as dataset:  # fmt: skip
            dataset.write(z, 1)
    (folder / "dem.tfw").write_text("10\n0\n0\n-10\n6400005\n1900005\n")
    out = tmp_path / "out"

    def lowest_y():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # feet as metres, heights kept as stored
            report = batch(folder, out, interval=1.0, format=".ply", scheduler="serial")
        assert report.ok
        mesh = trimesh.load(out / "dem.ply", process=False)
        return len(report.done), round(float(np.asarray(mesh.vertices)[:, 1].min()), 3)

    assert lowest_y() == (1, 1900005.0 - 40)  # no CRS: the world file's numbers as they are
    (folder / "dem.prj").write_text(CRS.from_epsg(2229).to_wkt())  # US survey feet
    assert lowest_y() == (1, round((1900005.0 - 40) * 1200 / 3937, 3))
    assert lowest_y()[0] == 0  # unchanged: skipped


def test_a_file_rewritten_with_its_size_and_mtime_kept_is_redone(tmp_path):
    # a DEM file replaced by another of the same size with its mtime kept (`cp -p`, `rsync -t`, os.utime) kept
    # the fingerprint (path, size, mtime), so the rerun skipped it as complete and its mesh stayed the old one
    import os
    import time

    folder = tmp_path / "dems"
    folder.mkdir()
    dem = folder / "dem.npy"
    np.save(dem, np.add.outer(np.arange(5.0), np.arange(6.0)).astype(np.float32))
    out = tmp_path / "out"
    report = batch(folder, out, interval=1.0, format=".ply", scheduler="serial")
    assert report.ok and len(report.done) == 1
    before = os.stat(dem)
    time.sleep(0.05)  # past the file system's clock tick, so the rewrite's ctime differs
    np.save(dem, np.full((5, 6), 7.0, np.float32))  # the same size
    os.utime(dem, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert os.stat(dem).st_size == before.st_size and os.stat(dem).st_mtime_ns == before.st_mtime_ns
    report = batch(folder, out, interval=1.0, format=".ply", scheduler="serial")
    assert report.ok and len(report.done) == 1
    np.testing.assert_allclose(trimesh.load(out / "dem.ply", process=False).vertices[:, 2], 7.0)


def _raster_or_folder(tmp_path, *, tiled):
    """A 9 x 9 ramp as the batch source: the array itself (cut into tiles), or a folder holding it as a.npy."""
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    if tiled:
        return z
    folder = tmp_path / "dems"
    folder.mkdir()
    np.save(folder / "a.npy", z)
    return folder


@pytest.mark.parametrize("kwargs, interval, base", [
    (dict(tile_size=4, interval=2.0, base=0.5), 2.0, 0.5),  # tiles of one raster: shared levels
    (dict(tile_size=4), 1.0, 0.0),  # the shared levels' default interval
    (dict(interval=1.5, base=-0.25), 1.5, -0.25),  # a folder: each file's own isovalues
], ids=["tiles", "default", "folder"])
def test_outputs_record_the_interval_and_base_of_their_isovalues(tmp_path, kwargs, interval, base):
    # shared levels recorded `interval` but not `base`, though the isovalues are base + k * interval (a list of more
    # than 4096 keeps only its ends); a folder's files and the default interval recorded neither
    from .test_export import glb_json

    source = _raster_or_folder(tmp_path, tiled="tile_size" in kwargs)
    report = batch(source, tmp_path / "out", scheduler="serial", **kwargs)
    assert report.ok and report.done
    for result in report.done:
        extras = glb_json(Path(result.path))["meshes"][0]["extras"]
        assert (extras["interval"], extras["base"]) == (interval, base)
        steps = (np.asarray(extras["isovalues"]) - base) / interval
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)


@pytest.mark.parametrize("metadata, kwargs, taken", [
    ({"interval": 5.0}, dict(tile_size=4, interval=2.0), "'interval'"),  # batch's value replaced it silently
    ({"isovalues": [1, 2], "gamma": 0.5}, dict(tile_size=4, interval=2.0), "'gamma', 'isovalues'"),  # the mesh's
    ({"tile_row": 9}, dict(tile_size=4, interval=2.0), "'tile_row'"),
    ({"input": "survey 2020"}, dict(interval=2.0), "'input'"),  # a folder's items record their files there
], ids=["interval", "isovalues", "tile_row", "input"])
def test_metadata_keys_the_library_writes_are_refused(tmp_path, metadata, kwargs, taken):
    # a user's metadata={"interval": ...} was overwritten by batch's own keys without a word, and a user's
    # "isovalues" or "gamma" replaced the values the mesh was made with
    from stepterrain.errors import InvalidInputError

    source = _raster_or_folder(tmp_path, tiled="tile_size" in kwargs)
    with pytest.raises(InvalidInputError, match=rf"^metadata keys {taken} are written by stepterrain itself"):
        batch(source, tmp_path / "out", scheduler="serial", metadata=metadata, **kwargs)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_metadata_keys_the_library_does_not_write_here_are_kept(tmp_path):
    from .test_export import glb_json

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    report = batch(z, tmp_path / "out", tile_size=4, interval=2.0, scheduler="serial",
                   metadata={"generator": "my tool", "input": "survey 2020", "frame": 3})  # fmt: skip
    extras = glb_json(Path(report.done[0].path))["meshes"][0]["extras"]
    assert (extras["generator"], extras["input"], extras["frame"]) == ("my tool", "survey 2020", 3)


def test_run_item_restores_the_workers_memory_budget(tmp_path):
    """run_item set the caller's memory budget in the worker process and left it there: a remote worker stepped
    other clients' tasks under it afterwards (found by helper 28). It holds for the item only, also when the item
    fails on it."""
    from stepterrain import get_memory_budget, set_memory_budget
    from stepterrain.batch import BatchItem, _Options, run_item

    rows, cols = np.mgrid[0:33, 0:33]
    np.save(tmp_path / "tile.npy", (rows * 3.0 + cols * 2.0).astype(np.float32))
    options = _Options(5.0, None, 0.5, 1.0, None, False, None, ".ply", "cpu", ())
    item = BatchItem("tile", "file", path=str(tmp_path / "tile.npy"))
    before = get_memory_budget()
    previous = set_memory_budget(before + 4096)  # the worker's own
    try:
        refused = run_item(item, None, options, str(tmp_path), memory_budget=1024)
        assert refused.status == "failed" and "OutputTooLargeError" in refused.error  # the caller's budget held
        assert get_memory_budget() == before + 4096
        done = run_item(item, None, options, str(tmp_path), memory_budget=1 << 30)
        assert done.status == "done" and get_memory_budget() == before + 4096
    finally:
        set_memory_budget(previous)


def test_stls_float32_rounding_is_warned_once_per_batch_with_its_count(tmp_path):
    """A batch of .stl tiles cut from a UTM raster warned STL's float32 rounding once per tile (each message names
    its own file, so none was folded): thousands of identical lines for a large raster. It is one warning now,
    with how many outputs it moved and the worst of them; each item's own message stays in its result."""
    import warnings

    z = (np.add.outer(np.arange(13.0), np.arange(9.0)) * 10.3).astype(np.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch(z, tmp_path / "out", tile_size=4, interval=20.0, format=".stl", scheduler="serial",
                       origin=(500000.123, 4100000.456), spacing=(30.0, -30.0))  # fmt: skip
    assert report.ok and len(report.done) == 6
    said = [w for w in caught if "float32" in str(w.message)]
    assert len(said) == 1, [str(w.message) for w in caught]
    text = str(said[0].message)
    assert "6 of the 6 .stl outputs" in text and "write .ply, .obj or .3mf" in text
    assert said[0].filename == __file__  # at the caller's line
    moves = [float(re.search(r"by up to (\S+) ", m)[1]) for r in report.done for m in r.warnings]
    assert len(moves) == 6 and f"by up to {max(moves):.3g} " in text  # the worst tile's message
    # a batch of one such tile says its own message, as save_mesh does
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        one = batch(z[:5, :5], tmp_path / "one", tile_size=4, interval=20.0, format=".stl", scheduler="serial",
                    origin=(500000.123, 4100000.456), spacing=(30.0, -30.0))  # fmt: skip
    assert [str(w.message) for w in caught] == list(one.done[0].warnings)
    assert "tile_r0_c0.stl" in str(caught[0].message)


def test_items_whose_worker_died_are_submitted_again(tmp_path):
    """A worker process that died (killed for memory, a crash) took the tiles' heights scattered to it along: the
    scheduler cancelled their tasks and batch reported them "failed: cancelled (after 0 attempt(s))", about half
    the tiles of a two-worker cluster, retries or not. They are scattered and submitted again now, and the
    temporary file the dead worker was writing is gone at the end."""
    distributed = pytest.importorskip("distributed", reason="needs dask.distributed")
    import logging

    z = (np.add.outer(np.arange(33.0), np.arange(33.0)) % 7).astype(np.float32)
    serial = batch(z, tmp_path / "serial", tile_size=8, interval=1.0, scheduler="serial")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=logging.CRITICAL) as cluster, distributed.Client(cluster) as client:

        def die_on_first_item() -> None:  # in one worker process: its first item dies while writing
            import os

            import stepterrain.batch as module

            def dying(item, source, options, output_dir, *rest):
                (Path(output_dir) / f".{item.key}{options.ext}.dying012.tmp").write_bytes(b"glTF partial")
                os._exit(1)

            module._run_item = dying

        client.run(die_on_first_item, workers=[sorted(client.scheduler_info()["workers"])[0]])
        report = batch(z, tmp_path / "out", tile_size=8, interval=1.0, scheduler=client)
    assert report.ok, report.summary()
    assert len(report.done) == 16 and any(r.attempts > 1 for r in report.done)
    assert sorted(p.name for p in (tmp_path / "out").iterdir() if p.name.startswith(".")) == []
    for r in serial.done:
        assert Path(r.path).read_bytes() == (tmp_path / "out" / Path(r.path).name).read_bytes()


def test_a_warning_every_item_gives_alike_is_said_once(tmp_path):
    """Each item's warnings are recorded and said again by the caller (serial runs too, since STL's rounding is
    said once per batch); a message every tile gives alike (a solid's heights on a threshold that lies one float32 step
    below the next) is said once, as Python's "default" filter said it when the serial run warned directly."""
    import warnings

    z = (np.add.outer(np.arange(9.0), np.arange(9.0)) % 3).astype(np.float32)  # 1.0 in every tile, on t_0
    levels = [float(np.nextafter(np.float32(1), np.float32(0))), 1.0, 1.0 + 2.0**-22]  # t_1 = 1 + 2^-23
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        report = batch(z, tmp_path / "out", tile_size=4, levels=levels, solid=True, scheduler="serial")
    assert report.ok and sum("watertight" in m for r in report.done for m in r.warnings) >= 2
    said = [str(w.message) for w in caught if "watertight" in str(w.message)]
    assert len(said) == 1 and caught[0].filename == __file__


def test_a_rerun_removes_the_partial_file_of_an_output_with_a_long_name(tmp_path):
    """atomic_path cuts a long name for its temporary file (.<name cut>.XXXXXXXX.tmp fits 255 bytes); the rerun looked
    for the whole name, so a killed run's partial file of a tile file named with 246 characters stayed for good."""
    from stepterrain.export import _temporary_stem

    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    name = "t" * 246
    np.save(src / f"{name}.npy", np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    out.mkdir()
    partial = out / f".{_temporary_stem(name + '.ply')}.abcdefgh.tmp"
    assert len(partial.name) <= 255 and _temporary_stem(name + ".ply") != name + ".ply"
    partial.write_bytes(b"glTF partial")
    report = batch(src, out, interval=2.0, format=".ply", scheduler="serial")
    assert report.ok and (out / f"{name}.ply").exists(), report.summary()
    assert not partial.exists()


def test_cli_batch_on_a_cluster_leaves_the_device_to_its_workers(tmp_path, capsys):
    """`stepterrain batch --scheduler tcp://gpu-cluster:8786 --device cuda` from a machine without a GPU (a login
    node) was refused before connecting: "--device 'cuda' needs a CUDA GPU, and Warp finds none on this machine",
    though the help says "Warp device on the workers". The workers' devices decide now; here only the name's form
    is checked (a typo is still exit 2 before any work)."""
    pytest.importorskip("distributed", reason="needs dask.distributed")
    import warp as wp

    from stepterrain import cli

    from .test_batch import free_port

    if wp.is_cuda_available():
        pytest.skip("this machine has a CUDA GPU: the local check passes anyway")
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens: the run gets as far as connecting
    argv = ["batch", "--tile", "64", "-o", str(tmp_path / "o"), "--scheduler", address, "--connect-timeout", "1"]
    assert cli.main([*argv, "--device", "cuda:0"]) == 2
    err = capsys.readouterr().err
    assert "cannot reach the dask scheduler" in err and "CUDA" not in err
    assert cli.main([*argv, "--device", "tpu:7"]) == 2
    assert "--device must be cpu, cuda or cuda:N" in capsys.readouterr().err
    assert cli.main(["batch", "--tile", "64", "-o", str(tmp_path / "o"), "--device", "cuda"]) == 2  # here: refused
    assert "needs a CUDA GPU" in capsys.readouterr().err


def test_a_folder_named_another_way_keeps_its_complete_outputs(tmp_path, monkeypatch):
    """A file item's fingerprint held its path as given: the same folder given as "src" and then as its absolute
    path (a cron job, another working folder) redid every item, though the files were unchanged."""
    src = tmp_path / "src"
    src.mkdir()
    for k in range(3):
        np.save(src / f"t{k}.npy", (np.add.outer(np.arange(9.0), np.arange(9.0)) + k).astype(np.float32))
    monkeypatch.chdir(tmp_path)
    first = batch("src", tmp_path / "out", interval=2.0, scheduler="serial")
    assert len(first.done) == 3
    again = batch(str(src), tmp_path / "out", interval=2.0, scheduler="serial")
    assert len(again.skipped) == 3, again.summary()
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    listed = batch([Path("..") / "src" / "t0.npy", src / "t1.npy"], tmp_path / "out", interval=2.0, scheduler="serial")
    assert len(listed.skipped) == 2, listed.summary()
    np.save(src / "t2.npy", np.zeros((9, 9), np.float32) + np.arange(9.0))  # a changed file is still redone
    assert [r.key for r in batch(str(src), tmp_path / "out", interval=2.0, scheduler="serial").done] == ["t2"]


def test_3mf_outputs_are_the_same_bytes_on_every_run(tmp_path, monkeypatch):
    """A 3MF's zip members were dated with the clock's time, so the same tiles written twice (workers=1 and 2, a
    rerun with resume=False, a day later) never compared equal, whereas every other format did."""
    import time
    import zipfile

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    first = batch(z, tmp_path / "a", tile_size=4, interval=2.0, format=".3mf", colors="viridis", scheduler="serial")
    real_localtime = time.localtime
    monkeypatch.setattr(time, "localtime", lambda secs=None: real_localtime((secs or time.time()) + 86400 + 3))
    second = batch(z, tmp_path / "b", tile_size=4, interval=2.0, format=".3mf", colors="viridis", scheduler="serial")
    for a, b in zip(first.done, second.done, strict=True):
        assert Path(a.path).read_bytes() == Path(b.path).read_bytes()
        with zipfile.ZipFile(a.path) as archive:
            assert {info.date_time for info in archive.infolist()} == {(1980, 1, 1, 0, 0, 0)}


def test_a_failed_items_earlier_output_is_noted(tmp_path):
    """A rerun with other options (or input) whose item failed left that item's output of the earlier run in the
    folder, unrecorded and unsaid: out/*.glb loaded it beside this run's outputs, its terraces another interval's."""
    src = tmp_path / "src"
    src.mkdir()
    for k in range(3):
        np.save(src / f"t{k}.npy", (np.add.outer(np.arange(9.0), np.arange(9.0)) + k).astype(np.float32))
    out = tmp_path / "out"
    assert batch(src, out, interval=2.0, scheduler="serial").ok
    (src / "t1.npy").write_bytes(b"not a numpy file")  # t1 fails on the rerun
    report = batch(src, out, interval=3.0, scheduler="serial")
    assert [r.key for r in report.failed] == ["t1"] and (out / "t1.glb").exists()
    said = [note for note in report.notes if "failed item" in note]
    assert len(said) == 1 and "t1.glb" in said[0] and "1 failed item (" in said[0], report.notes
    assert "t1.glb" in report.summary()
    (src / "t1.npy").unlink()
    (src / "t2.npy").write_bytes(b"not a numpy file")
    fresh = batch(src, tmp_path / "fresh", interval=3.0, scheduler="serial")  # a failure with no earlier output
    assert len(fresh.failed) == 1 and not any("failed item" in note for note in fresh.notes)


def test_a_folder_named_like_an_output_is_not_noted_as_an_earlier_runs_output(tmp_path):
    """A folder in the way of an item's output (out/tile_r0_c0.glb/) fails that item, naming it; the report also
    said the output folder "still holds an earlier run's output" of it, "made with that run's input and options":
    no run made it, and there is no output of it to redo or remove."""
    from .conftest import SHARED_DATA

    z = np.load(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz")["elevation"][:61, :61].astype(np.float32)
    out = tmp_path / "out"
    (out / "tile_r0_c0.glb").mkdir(parents=True)
    report = batch(z, out, tile_size=30, interval=50.0, scheduler="serial")
    assert [r.key for r in report.failed] == ["tile_r0_c0"] and len(report.done) == 3
    assert "it is a folder" in report.failed[0].error
    assert not any("earlier run" in note for note in report.notes), report.notes


@pytest.mark.parametrize("source", ["folder", "tiles"])
@pytest.mark.parametrize("how", ["address", "client"])
def test_a_scheduler_without_workers_is_a_clear_error_not_a_hang(tmp_path, source, how):
    """A reachable scheduler with no worker left a folder's items waiting for ever, and tiles failed after
    connect_timeout with dask's bare "TimeoutError: No valid workers found". Now a SchedulerError within
    connect_timeout, and no output folder is left behind."""
    distributed = pytest.importorskip("distributed", reason="needs dask.distributed")
    import logging
    import threading

    from stepterrain.errors import SchedulerError

    src = tmp_path / "src"
    src.mkdir()
    np.save(src / "t0.npy", np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    kwargs = dict(tile_size=4) if source == "tiles" else {}
    data = np.add.outer(np.arange(9.0), np.arange(9.0)) if source == "tiles" else src
    with distributed.LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=":0",
                                  silence_logs=logging.CRITICAL) as cluster, distributed.Client(cluster) as client:
        raised: list[BaseException] = []

        def run() -> None:
            try:
                batch(data, tmp_path / "out", interval=2.0, connect_timeout=1, **kwargs,
                      scheduler=cluster.scheduler_address if how == "address" else client)  # fmt: skip
            except BaseException as exc:  # noqa: BLE001 - checked below
                raised.append(exc)

        thread = threading.Thread(target=run, daemon=True)  # a hang fails the test instead of stopping the suite
        thread.start()
        thread.join(30)
        assert not thread.is_alive(), "batch still waits for a worker after 30 s"
    assert len(raised) == 1 and isinstance(raised[0], SchedulerError), raised
    assert "has no worker: none joined within connect_timeout=1 s; start workers" in str(raised[0])
    assert not (tmp_path / "out").exists()


def test_cli_batch_of_a_raster_named_another_way_keeps_its_complete_tiles(tmp_path, monkeypatch, capsys):
    """`stepterrain batch dem.npy --tile N` recorded its INPUT as given in every tile's metadata, which is part of
    the tiles' fingerprint: the same raster named from another folder (or by its absolute path) redid every tile."""
    from stepterrain import cli

    (tmp_path / "data").mkdir()
    np.save(tmp_path / "data" / "dem.npy", np.add.outer(np.arange(17.0), np.arange(17.0)).astype(np.float32))
    out = tmp_path / "out"
    monkeypatch.chdir(tmp_path / "data")
    assert cli.main(["-q", "batch", "dem.npy", "--tile", "8", "--interval", "2", "--scheduler", "serial",
                     "-o", str(out)]) == 0  # fmt: skip
    manifest = (out / MANIFEST_NAME).read_text()
    monkeypatch.chdir(tmp_path)
    assert cli.main(["batch", str(tmp_path / "data" / "dem.npy"), "--tile", "8", "--interval", "2", "--scheduler",
                     "serial", "-o", str(out)]) == 0  # fmt: skip
    assert "0 written, 4 complete already" in capsys.readouterr().err
    assert (out / MANIFEST_NAME).read_text() == manifest


def test_a_series_npz_honours_its_mask_and_valid_as_load_dem_does(tmp_path):
    """load_dem reads an .npz's boolean ``mask`` (True = missing) and ``valid`` (True = present) as nodata, but
    load_series ignored them: a (T, H, W) series saved from a masked array was meshed with its masked cells as
    heights (0 or -32768 pits in every frame). A (H, W) mask marks the same cells of every frame, a (T, H, W) one
    each frame's own; any other shape or dtype is refused, as load_dem refuses it."""
    from stepterrain.batch import load_series
    from stepterrain.errors import DataFileError

    z = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32)
    stack = np.stack([z, z + 1.0, z + 2.0])
    stack[:, 2, 3] = -32768.0  # the masked cell's stored value
    every = np.zeros(z.shape, bool)
    every[2, 3] = True
    np.savez(tmp_path / "every.npz", heights=stack, mask=every)
    got = load_series(tmp_path / "every.npz")
    assert np.isnan(got).sum() == 3 and np.isnan(got[:, 2, 3]).all()
    assert np.array_equal(got[1][~every], stack[1][~every])
    per_frame = np.zeros(stack.shape, bool)
    per_frame[1, 0, 0] = True
    valid = ~per_frame
    valid[:, 2, 3] = False
    np.savez(tmp_path / "frames.npz", elevation=stack, valid=valid)
    got = load_series(tmp_path / "frames.npz")
    assert np.array_equal(np.isnan(got), ~valid)
    np.savez(tmp_path / "both.npz", z=stack, mask=per_frame, valid=~every)  # missing where either says so
    assert np.array_equal(np.isnan(load_series(tmp_path / "both.npz")), per_frame | every)
    # a batch of it steps the frames without the pit: no vertex near -32768
    report = batch(tmp_path / "every.npz", tmp_path / "out", interval=1.0, format=".ply", scheduler="serial")
    assert report.ok and len(report.done) == 3
    assert min(trimesh.load(r.path).vertices[:, 2].min() for r in report.done) >= 0.0
    np.savez(tmp_path / "bad.npz", heights=stack, mask=every[:, :4])
    with pytest.raises(DataFileError, match=r"'mask' must be a boolean array of the series' shape \(3, 6, 7\)"):
        load_series(tmp_path / "bad.npz")
    np.savez(tmp_path / "ints.npz", heights=stack, valid=valid.astype(np.uint8) * 255)
    with pytest.raises(DataFileError, match="GDAL's mask band"):
        load_series(tmp_path / "ints.npz")
    np.savez(tmp_path / "unnamed.npz", mask=per_frame, stack=stack)  # the mask is not the series
    with pytest.warns(UserWarning, match=r"3 cells .*hold -32768, a common nodata value"):  # [:, 2, 3] unmasked now
        assert np.array_equal(np.isnan(load_series(tmp_path / "unnamed.npz")), per_frame)


def test_file_names_differing_only_in_case_do_not_share_an_output(tmp_path):
    """A.npy and a.npy wrote A.glb and a.glb: one file on a case-insensitive file system (macOS, Windows), the second
    item overwriting the first's output, which a rerun then skipped as complete. Names are compared in lower case:
    A.npy beside a.npz are renamed as a.npy beside a.npz are (A_npy, a_npz), and A.npy beside a.npy is refused."""
    from stepterrain.batch import plan_items
    from stepterrain.errors import InvalidInputError

    z = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32)
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    np.save(mixed / "A.npy", z)
    np.savez(mixed / "a.npz", heights=z + 5.0)
    np.save(mixed / "b.npy", z)
    items, _ = plan_items(mixed)
    assert [i.key for i in items] == ["A_npy", "a_npz", "b"]
    report = batch(mixed, tmp_path / "out", interval=1.0, format=".ply", scheduler="serial")
    assert report.ok and sorted(Path(r.path).name.lower() for r in report.done) == ["a_npy.ply", "a_npz.ply", "b.ply"]
    same = tmp_path / "same"
    same.mkdir()
    np.save(same / "A.npy", z)
    np.save(same / "a.npy", z + 5.0)
    with pytest.raises(InvalidInputError, match=r"source files '.*A.npy' and '.*a.npy' would write the outputs 'A_npy' "
                                                r"and 'a_npy', one file on a case-insensitive file system"):
        batch(same, tmp_path / "out2", interval=1.0, scheduler="serial")
    assert not (tmp_path / "out2").exists()


def test_items_run_at_once_by_a_threaded_worker_each_step_under_their_own_budget(tmp_path, monkeypatch):
    """A dask worker of several threads (``dask worker --nthreads 4``) runs items at once; each set the process-wide
    memory budget and put back the one it had found. The second item found the first's and put that back (the worker
    kept a client's budget for good), and an item stepped under the budget another item had just restored, or under
    another client's. Items of one budget now share it, an item with another waits for them, and the worker's own is
    restored after the last."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    import stepterrain.batch as batch_module
    from stepterrain import get_memory_budget, set_memory_budget
    from stepterrain.batch import BatchItem, ItemResult, _Options, run_item

    seen: dict[str, list[int]] = {}
    running = {"now": 0, "most": 0}
    lock = threading.Lock()

    def recording(item, source, options, output_dir, start, cpu_start):
        with lock:
            running["now"] += 1
            running["most"] = max(running["most"], running["now"])
        seen[item.key] = [get_memory_budget()]
        time.sleep(0.02 + 0.01 * (int(item.key[4:]) % 3))  # others start and finish meanwhile
        seen[item.key].append(get_memory_budget())
        with lock:
            running["now"] -= 1
        return ItemResult(item.key, "done", attempts=1)

    def run_all(budgets):
        with ThreadPoolExecutor(4) as pool:
            return list(pool.map(lambda key: run_item(BatchItem(key, "file", path="x.npy"), None, options,
                                                      str(tmp_path), memory_budget=budgets[key]), budgets))  # fmt: skip

    monkeypatch.setattr(batch_module, "_run_item", recording)
    options = _Options(5.0, None, 0.0, 1.0, None, False, None, ".ply", "cpu", ())
    own = get_memory_budget() + 4096
    previous = set_memory_budget(own)  # the worker's own
    try:
        one = {f"item{k}": 1 << 20 for k in range(8)}  # one client's items
        assert [r.status for r in run_all(one)] == ["done"] * 8
        assert {key: values for key, values in seen.items() if values != [one[key]] * 2} == {}
        assert running["most"] > 1 and get_memory_budget() == own  # they did run at once
        seen.clear()
        two = {f"item{k}": (1 << 20) if k % 3 else (1 << 21) for k in range(16)}  # two clients' items
        assert [r.status for r in run_all(two)] == ["done"] * 16
        assert {key: values for key, values in seen.items() if values != [two[key]] * 2} == {}
        assert get_memory_budget() == own
    finally:
        set_memory_budget(previous)

    # the real thing: a budget too small for the tile refuses it, a large one writes it, whichever runs beside it
    monkeypatch.undo()
    rows, cols = np.mgrid[0:33, 0:33]
    np.save(tmp_path / "tile.npy", (rows * 3.0 + cols * 2.0).astype(np.float32))
    real = _Options(5.0, None, 0.5, 1.0, None, False, None, ".ply", "cpu", ())
    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(lambda k: run_item(BatchItem(f"tile{k}", "file", path=str(tmp_path / "tile.npy")),
                                                   None, real, str(tmp_path), memory_budget=1024 if k % 2 else 1 << 30),
                                range(12)))  # fmt: skip
    assert [r.status for r in results] == ["done", "failed"] * 6
    assert all("OutputTooLargeError" in r.error for r in results if r.status == "failed")


def test_a_report_of_one_item_and_one_attempt_says_so_in_the_singular(tmp_path):
    """BatchReport.summary() said "failed of 1 items" and "(after 1 attempt(s))"; the notes "1 failed item(s)" and
    "4 output(s)". Counts and nouns now agree (stepterrain.errors.counted, the library's messages alike)."""
    from stepterrain.batch import BatchReport, ItemResult

    one = BatchReport(tmp_path, [ItemResult("t0", "failed", error="InvalidInputError: no", attempts=1)], 0.1)
    assert one.summary().splitlines() == [
        f"0 written, 0 complete already (skipped), 1 failed of 1 item in 0.1 s on serial; output {tmp_path}",
        "  failed t0: InvalidInputError: no (after 1 attempt)",
    ]
    two = BatchReport(tmp_path, [ItemResult(f"t{k}", "failed", error="x", attempts=2) for k in range(2)], 0.1)
    assert "1 failed of 2 items" not in two.summary() and "2 failed of 2 items" in two.summary()
    assert "(after 2 attempts)" in two.summary()


def test_the_progress_bar_writes_each_failure_as_the_summary_lists_it_reworded_by_a_callable(tmp_path, capsys):
    """The progress bar wrote a failed item's line its own way ("failed t0: ..." without its attempts) and the CLI
    could not reword it (its library argument names), so the command line printed each failure twice. The bar's
    line is the summary's now, and progress= takes a callable that rewords it."""
    folder = tmp_path / "dems"  # a folder: each file's heights are known only to its item, which fails
    folder.mkdir()
    for k in range(2):
        np.save(folder / f"t{k}.npy", np.add.outer(np.arange(6.0), np.arange(7.0)) * 10.0)
    report = batch(folder, tmp_path / "a", interval=1e-9, scheduler="serial", progress=True)
    err = capsys.readouterr().err
    expected = [line.strip() for line in report.summary().splitlines()[1:]]
    assert len(expected) == len(report.results) == 2 and all("(after 1 attempt)" in line for line in expected)
    assert [line for line in expected if line in err] == expected
    report = batch(folder, tmp_path / "b", interval=1e-9, scheduler="serial",
                   progress=lambda line: "<< " + line.upper())
    err = capsys.readouterr().err
    assert err.count("<< FAILED T") == 2 and "interval=1e-09" not in err


def test_the_default_clusters_malloc_settings_hold_after_another_cluster_and_stay_out_of_os_environ():
    """distributed's nanny takes a pre-spawn variable from os.environ before the configuration, and writes its own
    into os.environ when it spawns a worker. After any LocalCluster of the session (dask's defaults), batch's default
    cluster started its workers with MALLOC_TRIM_THRESHOLD_=65536, not LOCAL_CLUSTER_MALLOC (test_batch.py's check
    failed when this file's cluster tests ran first), and its own values stayed in the caller's os.environ."""
    import logging
    import os

    distributed = pytest.importorskip("distributed", reason="needs dask.distributed")
    from stepterrain.batch import LOCAL_CLUSTER_MALLOC, start_local_cluster

    keys = sorted(LOCAL_CLUSTER_MALLOC)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=logging.CRITICAL):
        pass  # dask's own values, now in os.environ
    before = {key: os.environ.get(key) for key in keys}
    cluster = start_local_cluster(1)
    try:
        after = {key: os.environ.get(key) for key in keys}
        with distributed.Client(cluster) as client:
            (environ,) = client.run(lambda: {key: os.environ.get(key) for key in keys}).values()
    finally:
        cluster.close()
    assert environ == {key: str(value) for key, value in LOCAL_CLUSTER_MALLOC.items()}
    assert after == before


def test_an_item_of_another_budget_is_not_starved_by_items_that_keep_arriving(tmp_path, monkeypatch):
    """An item of budget A waited, behind an item of budget B, for the A items running; when the B item took the
    worker first, the A item waited uncounted, so B items that kept arriving (another client's thousands of tiles on
    a worker of several threads) joined the B one ahead of it, each in turn: it waited until the last B item was done.
    It now counts as waiting for another budget whenever it waits for one, so that B items queue behind it."""
    import threading
    import time

    import stepterrain.batch as batch_module
    from stepterrain.batch import BatchItem, ItemResult, _BudgetLease, _Options, run_item

    releases: dict[str, threading.Event] = {}
    inside: list[str] = []

    def blocking(item, source, options, output_dir, start, cpu_start):
        inside.append(item.key)
        releases[item.key].wait(10)
        return ItemResult(item.key, "done", attempts=1)

    def start(key, budget):
        releases[key] = threading.Event()
        thread = threading.Thread(target=run_item, args=(BatchItem(key, "file", path="x.npy"), None, options,
                                                         str(tmp_path)), kwargs={"memory_budget": budget}, daemon=True)
        thread.start()
        return thread

    def until(condition):
        end = time.monotonic() + 5
        while not condition() and time.monotonic() < end:
            time.sleep(0.002)
        return condition()

    monkeypatch.setattr(batch_module, "_run_item", blocking)
    options = _Options(5.0, None, 0.0, 1.0, None, False, None, ".ply", "cpu", ())
    a, b = 1 << 30, 1 << 31
    checked = 0
    for trial in range(40):  # which waiter takes the worker when the A item is done is the threads' race
        lease = _BudgetLease()
        monkeypatch.setattr(batch_module, "_BUDGET_LEASE", lease)
        inside.clear()
        threads = [start(f"a0-{trial}", a)]
        assert until(lambda trial=trial: inside == [f"a0-{trial}"])
        threads.append(start(f"b0-{trial}", b))  # waits for the A item: another budget
        assert until(lambda lease=lease: lease._others == 1)
        threads.append(start(f"a1-{trial}", a))  # waits behind the B one
        time.sleep(0.02)
        assert inside == [f"a0-{trial}"]
        releases[f"a0-{trial}"].set()
        assert until(lambda: len(inside) == 2)
        if inside[1] == f"b0-{trial}":  # the B item took the worker, the A one waits for it
            checked += 1
            threads.append(start(f"b1-{trial}", b))  # a B item arriving now queues behind the waiting A one
            time.sleep(0.05)
            assert inside == [f"a0-{trial}", f"b0-{trial}"], "a later B item went ahead of the waiting A item"
        for event in releases.values():
            event.set()
        for thread in threads:
            thread.join(10)
        assert len(inside) == len(threads) and lease._holders == 0 and lease._others == 0
        if checked >= 3:
            break
    if not checked:
        pytest.skip("the A item took the worker first in every trial")


def test_the_default_clusters_malloc_settings_stay_out_of_os_environ_when_a_worker_is_restarted(tmp_path, monkeypatch):
    """start_local_cluster puts os.environ back after the workers start, but a nanny writes its pre-spawn variables
    into os.environ again whenever it restarts a worker that died (killed for memory, a crash: the items batch then
    submits again), so LOCAL_CLUSTER_MALLOC stayed in the caller's environment after such a run, for its later
    subprocesses and the next LocalCluster of the session (whose nannies prefer os.environ to their configuration)."""
    import os

    distributed = pytest.importorskip("distributed", reason="needs dask.distributed")
    import stepterrain.batch as batch_module
    from stepterrain.batch import LOCAL_CLUSTER_MALLOC

    keys = sorted(LOCAL_CLUSTER_MALLOC)
    for key in keys:
        monkeypatch.delenv(key, raising=False)
    start = batch_module.start_local_cluster

    def start_with_a_dying_worker(workers):  # the worker process dies on its first item; its nanny restarts it
        cluster = start(workers)

        def die_on_first_item() -> None:
            import os

            import stepterrain.batch as module

            def dying(*args):
                os._exit(1)

            module._run_item = dying

        with distributed.Client(cluster) as client:
            client.run(die_on_first_item)
        return cluster

    monkeypatch.setattr(batch_module, "start_local_cluster", start_with_a_dying_worker)
    z = (np.add.outer(np.arange(17.0), np.arange(17.0)) % 7).astype(np.float32)
    report = batch(z, tmp_path / "out", tile_size=8, interval=1.0, workers=1, retries=2)
    assert report.ok and len(report.done) == 4 and any(r.attempts > 1 for r in report.done), report.summary()
    assert {key: os.environ.get(key) for key in keys} == dict.fromkeys(keys)


def test_a_one_worker_cluster_is_described_in_the_singular(tmp_path):
    # the run's description said "LocalCluster (1 worker processes)"
    pytest.importorskip("distributed")
    heights = np.add.outer(np.arange(9.0), np.arange(9.0)) * 10.0
    report = batch(heights, tmp_path / "out", tile_size=4, interval=25.0, base=0.5, workers=1)
    assert report.scheduler == "LocalCluster (1 worker process)", report.scheduler
    assert not report.failed


@pytest.mark.render
def test_the_contact_sheet_is_the_window_size_asked_for(tmp_path):
    """overview_image's contact sheet gave each item width // cols x height // rows pixels, at least 16: 10 items in
    1280 x 800 came back 1280 x 798 (the CLI's 'rendering an overview 1280x800' wrote that), in 100 x 100 as 100 x 99,
    in 40 x 40 as 64 x 48. The cells now share the window's pixels exactly, each item still rendered in its cell."""
    from stepterrain import render
    from stepterrain.batch import overview_image

    ok, reason = render.offscreen_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL context: {reason}")
    z = (np.random.default_rng(0).random((10, 9, 9)) * 5).astype(np.float32)
    report = batch(z, tmp_path, interval=1.0, scheduler="serial", format=".ply")
    assert report.ok
    for size in [(100, 100), (40, 40), (33, 17)]:
        sheet = overview_image(report, window_size=size)
        assert sheet.shape == (size[1], size[0], 3), size
    sheet = overview_image(report, window_size=(100, 100))  # 4 x 3 cells: 25 wide, 33 / 33 / 34 tall
    drawn = (sheet < 250).any(axis=2)
    for k in range(10):
        r, c = divmod(k, 4)
        assert drawn[r * 100 // 3 : (r + 1) * 100 // 3, c * 25 : (c + 1) * 25].mean() > 0.05, k  # each item shows
    assert not drawn[2 * 100 // 3 :, 50:].any()  # cells 10 and 11 hold no item


@pytest.mark.parametrize("ext", [".npy", ".npz"])
def test_a_series_file_with_a_tile_size_is_told_what_the_option_is_for(tmp_path, capsys, ext):
    """``stepterrain batch series.npy --tile 32`` said "cannot read 'series.npy': expected a 2-D (H, W) elevation
    grid; got array of shape (6, 64, 80)", as if the file were broken (the same series in memory said that tile_size
    applies to one raster). A series file with a tile size says so now, naming --tile on the command line; without
    it the file meshes one item per frame, and a 2-D file still tiles."""
    from stepterrain.cli import main
    from stepterrain.errors import InvalidInputError

    stack = np.add.outer(np.arange(3.0), np.add.outer(np.arange(9.0), np.arange(11.0))).astype(np.float32)
    path = tmp_path / f"series{ext}"
    np.save(path, stack) if ext == ".npy" else np.savez(path, heights=stack)
    with pytest.raises(InvalidInputError, match=r"^tile_size applies to one \(H, W\) raster; got a \(T, H, W\) "
                                                r"series \(3, 9, 11\) in '.*series\.np[yz]': leave tile_size "
                                                r"\(the CLI's --tile\) out to mesh one item per frame$"):
        batch(path, tmp_path / "out", tile_size=4, interval=1.0, scheduler="serial")
    assert main(["-q", "batch", str(path), "--tile", "4", "-o", str(tmp_path / "cli"), "--scheduler", "serial"]) == 2
    err = capsys.readouterr().err
    assert "error: --tile applies to one (H, W) raster; got a (T, H, W) series (3, 9, 11) in " in err, err
    assert "leave --tile out to mesh one item per frame" in err and not (tmp_path / "cli").exists()

    report = batch(path, tmp_path / "frames", interval=1.0, scheduler="serial")
    assert report.ok and len(report.done) == 3
    flat = tmp_path / f"one{ext}"
    np.save(flat, stack[0]) if ext == ".npy" else np.savez(flat, heights=stack[0])
    report = batch(flat, tmp_path / "tiles", tile_size=4, interval=1.0, scheduler="serial")
    assert report.ok and sorted(r.key for r in report.done)[:2] == ["tile_r0_c0", "tile_r0_c1"]


def test_a_manifest_that_cannot_be_written_does_not_abort_the_run(tmp_path, monkeypatch):
    # A disk that filled up just as the manifest was rewritten (a tile fitted, the manifest's page did not) ended the
    # whole run with "stepterrain batch: error: [Errno 28] No space left on device", exit 2: no file named, the items
    # after it never run, the tiles already written neither recorded nor reported
    import errno

    import stepterrain.batch as batch_module

    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    out = tmp_path / "out"
    real = batch_module._write_manifest

    def full_disk(output_dir, entries):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(batch_module, "_write_manifest", full_disk)
    report = batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
    assert report.ok and len(report.done) == 4  # every item ran, and its output is there, complete
    assert all(Path(r.path).stat().st_size == r.bytes for r in report.done)
    assert not (out / MANIFEST_NAME).exists()
    note = [n for n in report.notes if MANIFEST_NAME in n]
    assert len(note) == 1 and "No space left on device" in note[0] and "4 outputs" in note[0], report.notes
    assert note[0] in report.summary()
    monkeypatch.setattr(batch_module, "_write_manifest", real)  # space again: the rerun redoes what went unrecorded
    again = batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
    assert len(again.done) == 4 and not again.notes
    assert len(batch(z, out, tile_size=4, interval=2.0, scheduler="serial").skipped) == 4


def interrupted_run_leaves(out, capfd, unraisable):
    """What an interrupted run on the default LocalCluster left: asserts that no worker process, lock file,
    temporary file, traceback or log line of dask's scheduler remains, and returns the folder's file names."""
    import gc
    import multiprocessing

    from stepterrain.batch import LOCK_NAME

    gc.collect()  # a generator of the run left for the garbage collector fails here (sys.unraisablehook)
    err = capfd.readouterr().err
    assert unraisable == [], unraisable
    assert "Traceback" not in err and "distributed.scheduler" not in err and "Exception ignored" not in err, err[-3000:]
    assert multiprocessing.active_children() == []  # the cluster's worker processes are gone
    names = sorted(p.name for p in out.iterdir()) if out.exists() else []
    assert LOCK_NAME not in names and not [n for n in names if n.endswith(".tmp")]
    return names


@pytest.fixture
def unraisable(monkeypatch):
    import sys

    caught: list[str] = []
    monkeypatch.setattr(sys, "unraisablehook", lambda info: caught.append(f"{info.exc_type.__name__}: "
                                                                           f"{info.exc_value} in {info.object!r}"))
    return caught


def test_ctrl_c_while_a_result_is_drawn_cancels_the_clusters_tasks_quietly(tmp_path, capfd, unraisable):
    # Ctrl-C while the progress bar drew a result (in batch's loop, not inside dask's wait) left the tasks to the
    # garbage collector, which ran the generator's cancel after the client had closed: "Exception ignored in:
    # <generator object _run_dask>" ... "RuntimeError: IOLoop is closed" on stderr, and as the LocalCluster went
    # down its scheduler logged a CRITICAL traceback per task still reported to the closed client
    src = tmp_path / "dems"
    src.mkdir()
    (src / "a_broken.npy").write_bytes(b"not a DEM")  # the first item: fails at once, and its line is drawn
    rng = np.random.default_rng(0)
    for k in range(12):
        np.save(src / f"t{k:02d}.npy", (rng.random((30, 30)) * 100).astype(np.float32))

    def ctrl_c(line):
        raise KeyboardInterrupt

    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        batch(src, out, interval=10.0, workers=2, progress=ctrl_c)
    interrupted_run_leaves(out, capfd, unraisable)
    report = batch(src, out, interval=10.0, scheduler="serial")  # the rerun completes the rest
    assert [r.key for r in report.failed] == ["a_broken"] and len(report.done) + len(report.skipped) == 12


def test_ctrl_c_while_the_local_cluster_starts_closes_it(tmp_path, capfd, unraisable, monkeypatch):
    # Ctrl-C while the LocalCluster's workers started left the cluster unclosed: its worker processes lived on
    # until the interpreter's exit, where dask's exit hook failed on it ("Exception ignored in atexit callback
    # <function close_clusters> ... AssertionError: Status.init")
    import signal

    import distributed

    class InterruptedAsItStarts(distributed.LocalCluster):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            # the user's Ctrl-C as the workers come up: Python's handler of SIGINT, run here as the signal would run
            # it (os.kill ran it wherever the main thread next ran Python code: in a gc callback of dask's, whose
            # exceptions are ignored, at times)
            signal.getsignal(signal.SIGINT)(signal.SIGINT, None)

    monkeypatch.setattr(distributed, "LocalCluster", InterruptedAsItStarts)
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    out = tmp_path / "out"
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # also where the tests run with it ignored
    try:
        with pytest.raises(KeyboardInterrupt):
            batch(z, out, tile_size=4, interval=2.0, workers=1)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Python's handler is back
    finally:
        signal.signal(signal.SIGINT, before)
    assert interrupted_run_leaves(out, capfd, unraisable) == []  # nothing written: the folder made is removed


def test_ctrl_c_that_fails_the_local_cluster_start_ends_as_interrupted(tmp_path, capsys, monkeypatch):
    """The terminal's Ctrl-C reaches the LocalCluster's worker processes too: as they started, they died of it, and
    the start failed. The Ctrl-C held back meanwhile was then lost: `stepterrain batch` ended "error: cannot start a
    LocalCluster of 2 worker processes: Nanny failed to start. (from a script, call batch() under `if __name__ ==
    '__main__':` ...)", exit status 2. It ends as interrupted now: exit status 130, nothing written."""
    import os
    import signal

    import distributed

    from stepterrain import cli

    class DiesOfTheCtrlC:
        def __init__(self, *args, **kwargs):
            os.kill(os.getpid(), signal.SIGINT)  # the user's Ctrl-C, to the whole process group
            raise RuntimeError("Nanny failed to start.")  # as the workers' own share of it ends their start

    monkeypatch.setattr(distributed, "LocalCluster", DiesOfTheCtrlC)
    src = tmp_path / "dem.npy"
    np.save(src, np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    out = tmp_path / "out"
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # also where the tests run with it ignored
    try:
        code = cli.main(["batch", str(src), "--tile", "4", "--interval", "2", "--workers", "1", "-o", str(out)])
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Python's handler is back
    finally:
        signal.signal(signal.SIGINT, before)
    err = capsys.readouterr().err
    assert code == 130, err
    assert err.rstrip().splitlines()[-1] == "stepterrain: interrupted" and "Nanny" not in err, err
    assert not out.exists() or list(out.iterdir()) == []


def test_a_run_of_many_items_on_the_local_cluster_ends_without_dask_errors(tmp_path, capfd):
    # every `stepterrain batch` of some hundreds of small tiles on the default LocalCluster, written in full, ended
    # with a worker's "distributed.worker - ERROR - Failed to communicate with scheduler during heartbeat" and a
    # 30-line traceback on stderr as the cluster closed: an error after a run that succeeded
    z = np.add.outer(np.arange(24 * 8 + 1.0), np.arange(24 * 8 + 1.0)).astype(np.float32)
    report = batch(z, tmp_path, tile_size=8, interval=2.0, workers=2)
    assert report.ok and len(report.done) == 24 * 24
    err = capfd.readouterr().err
    assert "ERROR" not in err and "Traceback" not in err, err[-3000:]


def test_the_cli_takes_several_dem_files_as_a_shell_glob_gives_them(tmp_path, capsys):
    """`stepterrain batch tiles/*.tif -o out` failed with argparse's "unrecognized arguments" though the library
    takes a list of files: each file is one item now, meshed as stepped(load_dem(file)) is, and a rerun skips them;
    --tile (which cuts one raster) is refused with several, and an output naming one of them too."""
    import stepterrain as st
    from stepterrain import cli
    from stepterrain.export import read_mesh

    from .conftest import SHARED_DATA

    z = np.load(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz")["elevation"].astype(np.float32)
    from PIL import Image

    files = []
    for k in range(3):  # the middle one a 16-bit PNG heightmap
        part = z[:60, k * 60: (k + 1) * 60 + 1]
        files.append(tmp_path / f"t{k}.{'png' if k == 1 else 'npy'}")
        if k == 1:
            Image.fromarray(np.round(part).astype(np.uint16)).save(files[-1])
        else:
            np.save(files[-1], part)
    out = tmp_path / "out"
    argv = ["batch", *map(str, files), "--interval", "100", "--scheduler", "serial", "-o", str(out)]
    assert cli.main(argv) == 0
    assert "stepping 3 DEM files" in capsys.readouterr().err
    for f in files:
        mesh, expected = read_mesh(out / f"{f.stem}.glb"), st.stepped(st.load_dem(f), interval=100.0, device="cpu")
        assert len(mesh.faces) == len(expected.faces)
        np.testing.assert_allclose(mesh.bounds, expected.bounds, atol=1e-3)
    assert cli.main(argv) == 0
    assert "0 written, 3 complete already, 0 failed" in capsys.readouterr().err
    for extra, message in ((["--tile", "20"], "--tile cuts one DEM into tiles; got 3 INPUT files"),
                           (["--png", str(files[1])], f"--png {str(files[1])!r} is the INPUT 2 file")):
        assert cli.main([*argv[:-2], "-o", str(tmp_path / "other"), *extra]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "other").exists()


def test_a_rerun_over_complete_tiles_replaces_them_without_flushing_each(tmp_path, monkeypatch):
    """atomic_path flushes a file it replaces (fsync, 5-10 ms here): a --no-resume rerun of many small tiles took
    twice as long. Batch's tiles are replaced without it (the manifest records each tile's size: one a crash empties
    is redone by the next run); the manifest itself, the record of what is complete, is still flushed."""
    import os

    z = np.add.outer(np.arange(17.0), np.arange(17.0)).astype(np.float32)
    batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial")
    flushed: list[str] = []
    real_fsync = os.fsync

    def spy(fd: int) -> None:
        flushed.append(os.path.basename(os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    (tmp_path / "tile_r0_c0.glb").chmod(0o600)
    report = batch(z, tmp_path, tile_size=4, interval=2.0, scheduler="serial", resume=False)
    assert len(report.done) == 16
    assert flushed and all(name.startswith(f".{MANIFEST_NAME}.") for name in flushed), flushed
    assert (tmp_path / "tile_r0_c0.glb").stat().st_mode & 0o777 == 0o600  # a replaced file keeps its mode still
    from stepterrain.export import save_mesh

    flushed.clear()
    save_mesh(trimesh.creation.box(), tmp_path / "tile_r0_c0.glb")  # outside batch: flushed as before
    assert len(flushed) == 1


def test_several_input_files_are_checked_before_the_run_a_folder_a_missing_file_and_one_file_twice(tmp_path, capsys):
    """Several INPUT files (a shell glob): a folder among them was refused as 'source files must end in .npy ...';
    a missing file (a typo) failed as an item after the cluster had started and the others were written (exit 1);
    one file given twice (tiles/*.tif tiles/a.tif) was refused as two files writing one output, 'rename one'. Each is
    refused up front now (exit 2, nothing written), by what it is."""
    from stepterrain import cli

    (tmp_path / "tiles").mkdir()
    a, b = tmp_path / "tiles" / "a.npy", tmp_path / "tiles" / "b.npy"
    for f in (a, b):
        np.save(f, np.arange(12, dtype=np.float32).reshape(3, 4))
    out = tmp_path / "out"
    cases = (([a, tmp_path / "tiles"], f"source lists the folder {str(tmp_path / 'tiles')!r} among DEM files"),
             ([a, tmp_path / "nope.npy"], f"source file {str(tmp_path / 'nope.npy')!r} does not exist"),
             ([a, b, a], f"source names one file twice, {str(a)!r}; give each file once"),
             ([a, tmp_path / "tiles" / ".." / "tiles" / "a.npy"], "source names one file twice, as "))
    for files, message in cases:
        argv = ["batch", *map(str, files), "--interval", "1", "--scheduler", "serial", "-q", "-o", str(out)]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and "rename one" not in err, err
        assert not out.exists()


@pytest.fixture
def threaded_cluster_client():
    distributed = pytest.importorskip("distributed", reason="needs dask.distributed")
    import logging

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=":0",
                                  silence_logs=logging.CRITICAL) as cluster, distributed.Client(cluster) as client:
        yield client


def counting_submits(client, monkeypatch) -> list[str]:
    """The functions of the tasks batch submits to ``client``, by name, as it submits them."""
    submitted: list[str] = []
    real = client.submit

    def submit(function, *args, **kwargs):
        submitted.append(function.__name__)
        return real(function, *args, **kwargs)

    monkeypatch.setattr(client, "submit", submit)
    return submitted


def test_small_tiles_run_several_to_a_dask_task_with_the_serial_run_s_outputs_and_manifest(
        tmp_path, threaded_cluster_client, monkeypatch):
    """Each item was one dask task: hundreds of small tiles ran several times slower on a LocalCluster than serially
    (the scheduler's and worker's cost per task above a 64² tile's ~2 ms). Small items now run several to a task,
    with the results, files and manifest entries of one item per task, and a rerun skips them all."""
    import json

    z = (np.add.outer(np.arange(33.0), np.arange(33.0)) % 7).astype(np.float32)
    serial = batch(z, tmp_path / "serial", tile_size=4, interval=1.0, scheduler="serial")
    submitted = counting_submits(threaded_cluster_client, monkeypatch)
    grouped = batch(z, tmp_path / "dask", tile_size=4, interval=1.0, scheduler=threaded_cluster_client)
    assert grouped.ok and len(grouped.done) == 64
    assert set(submitted) == {"run_items"} and len(submitted) == 8  # 64 items, 4 tasks per worker thread
    assert [(r.key, r.status, r.attempts, r.faces, r.vertices, r.bytes) for r in grouped.results] == [
        (r.key, r.status, r.attempts, r.faces, r.vertices, r.bytes) for r in serial.results]
    for a, b in zip(serial.done, grouped.done, strict=True):
        assert Path(a.path).read_bytes() == Path(b.path).read_bytes()
    assert json.loads((tmp_path / "dask" / MANIFEST_NAME).read_text()) == json.loads(
        (tmp_path / "serial" / MANIFEST_NAME).read_text())
    again = batch(z, tmp_path / "dask", tile_size=4, interval=1.0, scheduler=threaded_cluster_client)
    assert len(again.skipped) == 64 and len(submitted) == 8  # nothing to submit


def test_an_item_failing_in_a_task_of_several_fails_alone(tmp_path, threaded_cluster_client, monkeypatch):
    """A task of several small items: one that raises is retried and reported on its own (its attempts and reason),
    an unreadable file fails at once, and the other items of their tasks are written once."""
    import stepterrain as st

    real = st.stepped.stepped
    calls: dict[str, int] = {}

    def broken_on_one_tile(terrain, **kwargs):
        calls[terrain.source] = calls.get(terrain.source, 0) + 1
        if terrain.source.endswith("[4:9, 8:13]"):
            raise RuntimeError("always broken")
        return real(terrain, **kwargs)

    monkeypatch.setattr(st.stepped, "stepped", broken_on_one_tile)  # the threaded workers share this module
    z = (np.add.outer(np.arange(33.0), np.arange(33.0)) % 7).astype(np.float32)
    submitted = counting_submits(threaded_cluster_client, monkeypatch)
    report = batch(z, tmp_path / "tiles", tile_size=4, interval=1.0, scheduler=threaded_cluster_client, retries=2)
    assert set(submitted) == {"run_items"} and len(submitted) < 64
    assert [(r.key, r.error, r.attempts) for r in report.failed] == [("tile_r1_c2", "RuntimeError: always broken", 3)]
    assert len(report.done) == 63 and all(r.attempts == 1 for r in report.done)
    assert sorted(calls.values()) == [1] * 63 + [3]  # the others of its task were not redone

    folder = tmp_path / "dems"
    folder.mkdir()
    for k in range(16):
        np.save(folder / f"dem_{k:02d}.npy", (np.arange(30.0)[:, None] * np.arange(1, 31)[None] % 11).astype("f4"))
    (folder / "dem_05.npy").write_bytes(b"\x93NUMPY garbage")
    submitted.clear()
    files = batch(folder, tmp_path / "files", interval=1.0, scheduler=threaded_cluster_client)
    assert set(submitted) == {"run_items"} and len(submitted) == 8
    assert [(r.key, r.attempts) for r in files.failed] == [("dem_05", 1)] and "DataFileError" in files.failed[0].error
    assert len(files.done) == 15


def test_task_groups_keep_large_items_alone_and_every_thread_busy():
    from stepterrain.batch import _TASK_NODES, _TASKS_PER_THREAD, _task_groups, plan_items

    items, src = plan_items(np.zeros((1025, 1025), np.float32), tile_size=64)  # 256 tiles of 65² nodes
    groups = _task_groups(items, src, threads=2)
    assert [i for g in groups for i in g] == items  # every item once, in order
    assert len(groups) == 2 * _TASKS_PER_THREAD and {len(g) for g in groups} == {32}
    many = _task_groups(items, src, threads=1) if len(items) * 65 * 65 > 2 * _TASK_NODES else None
    assert many is not None and all(len(g) * 65 * 65 <= _TASK_NODES for g in many)  # capped by nodes, not threads
    large, src = plan_items(np.zeros((2049, 1025), np.float32), tile_size=1024)
    assert _task_groups(large, src, threads=1) == [[item] for item in large]


def test_results_that_reached_the_caller_before_ctrl_c_are_recorded(tmp_path, threaded_cluster_client):
    """Ctrl-C as the progress bar drew an item: the items whose results had already come back from the cluster
    (written complete) were not recorded in the manifest, so a rerun redid them."""
    import json
    import time

    src = tmp_path / "dems"
    src.mkdir()
    (src / "a_broken.npy").write_bytes(b"not a DEM")  # among the first items: its failure line is drawn
    rng = np.random.default_rng(0)
    for k in range(12):
        np.save(src / f"t{k:02d}.npy", (rng.random((30, 30)) * 100).astype(np.float32))
    out = tmp_path / "out"
    client = threaded_cluster_client

    def ctrl_c_once_all_are_back(line):
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (len(list(out.glob("t*.glb"))) == 12 and all(
                state.status == "finished" for state in client.futures.values())):
            time.sleep(0.05)
        time.sleep(0.5)  # their results reach this process
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        batch(src, out, interval=10.0, scheduler=client, progress=ctrl_c_once_all_are_back)
    recorded = json.loads((out / MANIFEST_NAME).read_text())["items"]
    assert sorted(recorded) == [f"t{k:02d}.glb" for k in range(12)]
    report = batch(src, out, interval=10.0, scheduler="serial")
    assert [r.key for r in report.failed] == ["a_broken"] and len(report.skipped) == 12 and not report.done


def test_the_cli_takes_one_dem_file_without_tile_as_one_item(tmp_path, capsys):
    """`stepterrain batch tiles/*.tif -o out` where the glob matched one file failed with "give --tile to cut it
    into tiles": one INPUT was always the raster to cut. One DEM file without --tile is one item now, written and
    recorded as among several (the glob matching two files later skips it); with --tile it is still cut, and a
    (T, H, W) series file is still one item per frame."""
    from stepterrain import cli

    tiles = tmp_path / "tiles"
    tiles.mkdir()
    z = np.add.outer(np.arange(20.0), np.arange(20.0)).astype(np.float32)
    np.save(tiles / "a.npy", z)
    out = tmp_path / "out"
    # --colormap none: coloured (the default now, as steps) the files share their levels, and b's heights, twice
    # a's, move them: a is redone then (tests/test_batch_files_shared.py)
    argv = ["batch", "--interval", "5", "--colormap", "none", "--scheduler", "serial", "-o", str(out)]
    assert cli.main([*argv, str(tiles / "a.npy")]) == 0
    assert "stepping 1 DEM file (" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["a.glb", MANIFEST_NAME]
    first = (out / "a.glb").read_bytes()
    np.save(tiles / "b.npy", z * 2)
    assert cli.main([*argv, str(tiles / "a.npy"), str(tiles / "b.npy")]) == 0
    assert "1 written, 1 complete already, 0 failed" in capsys.readouterr().err
    assert (out / "a.glb").read_bytes() == first
    assert cli.main([*argv[:-1], str(tmp_path / "cut"), str(tiles / "a.npy"), "--tile", "10"]) == 0
    assert len(list((tmp_path / "cut").glob("tile_*.glb"))) == 4
    np.save(tmp_path / "series.npy", np.stack([z, z + 1]))
    assert cli.main([*argv[:-1], str(tmp_path / "frames"), str(tmp_path / "series.npy")]) == 0
    assert sorted(p.name for p in (tmp_path / "frames").glob("*.glb")) == ["frame_0000.glb", "frame_0001.glb"]


def test_serial_batches_in_two_threads_leave_the_warning_machinery_to_the_process(tmp_path, monkeypatch, recwarn):
    """A serial run records each item's warnings with warnings.catch_warnings(record=True), which sets the process's
    filters and display and puts back what it found. Two serial runs in two threads (a web service) recorded at once:
    the second put back the first's recorder, so every later warning of the process went into a list nobody read,
    and its "default" filter stayed before the user's. The overlap is forced: the first item ends its recording while
    the second records."""
    import threading
    import time
    import warnings

    from stepterrain import batch as batch_module

    real = batch_module._run_item
    guard, arrived = threading.Lock(), []
    both_in, first_out = threading.Event(), threading.Event()

    def overlapping(*args, **kwargs):
        with guard:
            arrived.append(None)
            first = len(arrived) == 1
        if first:
            both_in.wait(1.0)  # the second thread's item starts while this one records (unless it must wait)
            result = real(*args, **kwargs)
            first_out.set()
            return result
        both_in.set()
        result = real(*args, **kwargs)
        first_out.wait(5.0)
        time.sleep(0.05)  # the first has put back what its recording found
        return result

    monkeypatch.setattr(batch_module, "_run_item", overlapping)
    heights = (np.add.outer(np.arange(12), np.arange(12)) % 3).astype(np.float32)  # 1.0 on t_0, one step below t_1
    levels = [float(np.nextafter(np.float32(1), np.float32(0))), 1.0, 1.0 + 2.0**-22]
    before = list(warnings.filters)
    reports, errors = {}, []

    def run(k):
        try:
            reports[k] = batch(heights, output_dir=tmp_path / f"out{k}", tile_size=12, levels=levels,
                               solid=True, scheduler="serial", progress=False)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(60)
    assert not errors and sorted(reports) == [0, 1]
    for report in reports.values():  # each item's own warning, in its own result
        assert report.ok and len(report.results) == 1
        assert any("on a threshold" in message for message in report.results[0].warnings)
    assert warnings.filters == before
    recwarn.clear()
    warnings.warn("a warning of the process after the runs", UserWarning, stacklevel=1)
    assert [str(w.message) for w in recwarn] == ["a warning of the process after the runs"]


def test_dask_logs_silenced_in_two_threads_at_once_get_their_levels_back():
    """A dask run silences dask.distributed's loggers while its cluster closes and put back the levels it found: two
    runs closing their clusters in two threads at once left the loggers off for good (the second found the first's
    silence and put it back after the first had restored the user's levels). The overlap is forced: the first block
    ends while the second runs."""
    import logging
    import threading

    from stepterrain.batch import _dask_logs_silenced

    logger = logging.getLogger("distributed")
    old = logger.level
    try:
        logger.setLevel(logging.WARNING)
        first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
        seen = {}

        def first():
            with _dask_logs_silenced():
                first_in.set()
                second_in.wait(10)
            first_out.set()

        def second():
            first_in.wait(10)
            with _dask_logs_silenced():
                second_in.set()
                first_out.wait(10)
                seen["while the second runs"] = logger.level

        threads = [threading.Thread(target=first), threading.Thread(target=second)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(20)
        assert seen == {"while the second runs": logging.CRITICAL + 1}
        assert logger.level == logging.WARNING
    finally:
        logger.setLevel(old)


# ---------------------------------------------------------------------------------------------- input options
def _unreferenced_tiles(folder: Path) -> list[Path]:
    """Two .npy tiles (no georeferencing: load_dem reads 1 m cells) cut from the real Big Tujunga DEM."""
    from .conftest import real_dem

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=41, step=1)
    folder.mkdir()
    files = [folder / "west.npy", folder / "east.npy"]
    np.save(files[0], heights[:, :21])
    np.save(files[1], heights[:, 20:])
    return files


def test_cli_batch_spacing_and_coarsen_apply_to_each_file_and_are_recorded(tmp_path, capsys):
    """``stepterrain batch tiles/ --spacing 30 --coarsen 2`` was refused by argparse (batch had neither option, which
    steps, closeup and texture share), and the library's spacing= refused a folder: a folder of .npy tiles at 30 m
    was meshed as 1 m cells. Each file is now read, placed at 30 m and coarsened as ``steps`` does it, the options
    are recorded in every mesh's metadata, and a rerun with another --coarsen or --spacing redoes the items."""
    from stepterrain import cli
    from stepterrain.io import load_dem
    from stepterrain.stepped import stepped

    from .test_export import glb_json

    files = _unreferenced_tiles(tmp_path / "tiles")
    out = tmp_path / "out"
    argv = ["-q", "batch", str(tmp_path / "tiles"), "--interval", "50", "--scheduler", "serial", "-o", str(out)]
    assert cli.main(argv + ["--spacing", "30", "--coarsen", "2"]) == 0
    for f in files:
        mesh = read_mesh(out / f"{f.stem}.glb")
        expected = stepped(_placed(load_dem(f), 30.0).coarsen(2), interval=50.0)
        assert len(mesh.faces) == len(expected.faces)
        np.testing.assert_allclose(mesh.bounds, expected.bounds, atol=1e-2)
        extras = glb_json(out / f"{f.stem}.glb")["meshes"][0]["extras"]
        assert extras["spacing"] == [30.0, -30.0] and extras["coarsen"] == 2 and "crop" not in extras
    # a node every 60 m: 21 columns -> 10 coarse nodes
    east = read_mesh(out / "east.glb")
    assert east.bounds[1, 0] - east.bounds[0, 0] == pytest.approx(9 * 60.0, abs=1e-2)
    capsys.readouterr()
    assert cli.main(["batch", *argv[2:], "--spacing", "30", "--coarsen", "2"]) == 0
    assert "0 written, 2 complete already" in capsys.readouterr().err
    for options in (["--spacing", "30", "--coarsen", "3"], ["--spacing", "30,20", "--coarsen", "3"],
                    ["--coarsen", "3"]):
        assert cli.main(["batch", *argv[2:], *options]) == 0
        assert "2 written, 0 complete already" in capsys.readouterr().err, options


def test_cli_batch_spacing_or_coarsen_refused_by_every_file_exits_2_once(tmp_path, capsys):
    """``batch FOLDER --spacing 30`` over a folder whose files all place their nodes themselves (GeoTIFFs), or a
    --coarsen that leaves every file fewer than 2 x 2 nodes, failed item by item, a wall of identical failures and
    exit status 1, while a --floor above every surface is one usage error: these are said once too now, naming the
    option, exit 2. A folder where some files pass still lists the others' failures, exit 1."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFFs are written with rasterio")
    from rasterio.transform import Affine

    from stepterrain import cli

    from .conftest import real_dem

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=41, step=1)
    geo = tmp_path / "geo"
    geo.mkdir()
    for k in range(2):
        with rasterio.open(geo / f"g{k}.tif", "w", driver="GTiff", height=41, width=20, count=1, dtype="float32",
                           crs="EPSG:32611", transform=Affine(30, 0, 380000 + 600 * k, 0, -30, 3800000)) as dst:
            dst.write(heights[:, 20 * k:20 * k + 20], 1)
    out = tmp_path / "out"
    argv = ["-q", "batch", "--interval", "50", "--scheduler", "serial", "-o", str(out)]
    assert cli.main([*argv, str(geo), "--spacing", "30"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepterrain batch: error: --spacing applies to DEM files with no georeferencing (.npy, a "
                          "PNG heightmap, a GeoTIFF without a geotransform); all 2 inputs place their nodes "
                          "themselves (e.g. g0: spacing (30.0, -30.0), origin (380015.0, 3799985.0), CRS EPSG:32611)"
                          ": leave --spacing out") and err.count("\n") == 1, err
    assert cli.main([*argv, str(geo / "g1.tif"), "--spacing", "30"]) == 2  # one file, one item
    assert "; the only input places its nodes itself (e.g. g1: " in capsys.readouterr().err
    assert not list(out.glob("*.glb"))
    assert cli.main([*argv, str(geo), "--coarsen", "25"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepterrain batch: error: --coarsen 25 leaves no mesh of any of the 2 inputs (e.g. g0: "
                          "factor 25 leaves 1 x 0 nodes of the 41 x 20 grid (mean)") and err.count("\n") == 1, err
    # a file that passes: the others' failures are their own, listed, exit 1 as before
    np.save(geo / "plain.npy", heights)  # 41 x 41 nodes
    assert cli.main([*argv, str(geo), "--spacing", "30"]) == 1
    err = capsys.readouterr().err
    assert "failed g0: InvalidInputError: --spacing applies" in err and "failed g1:" in err and "error:" not in err
    assert cli.main([*argv, str(geo), "--coarsen", "15"]) == 1  # plain.npy's 2 x 2 coarse nodes pass
    err = capsys.readouterr().err
    assert "failed g0: InvalidInputError: --coarsen 15: factor 15 leaves 2 x 1 nodes" in err and "error:" not in err


def _placed(terrain, d):
    from stepterrain import Terrain

    return Terrain.from_heights(terrain.heights, spacing=(d, -d))


def test_coarsened_tiles_of_one_raster_weld_as_the_coarsened_raster(tmp_path):
    """Coarsening is applied to the raster before it is cut (crop first), so the tiles still share their border
    nodes: their welded mosaic is the cropped, coarsened raster stepped whole, with no crack at a seam (tiles
    coarsened one by one would put their blocks apart). batch had no crop= nor coarsen=."""
    from stepterrain.io import load_dem
    from stepterrain.stepped import isovalues, stepped

    from .conftest import shared_file
    from .test_batch import weld

    dem = shared_file("big_tujunga_srtm_30m_utm11n.npz")
    whole = load_dem(dem)
    (x0, x1, y0, y1) = whole.extent
    crop = (x0 + 3000.0, x0 + 9000.0, y0 + 4000.0, y0 + 9000.0)
    report = batch(str(dem), tmp_path / "out", tile_size=(16, 24), crop=crop, coarsen=3, interval=100.0,
                   format=".ply", scheduler="serial")
    reference = whole.crop(crop).coarsen(3)
    rows, cols = reference.heights.shape
    assert report.ok and len(report.done) == -(-(rows - 1) // 16) * -(-(cols - 1) // 24) > 4
    meshes = [read_mesh(r.path) for r in report.done]
    vertices, faces = weld(meshes, decimals=2)
    values = isovalues(reference.height_range, interval=100.0)
    expected = stepped(reference, levels=values)
    assert len(faces) == len(expected.faces)
    np.testing.assert_allclose([vertices.min(0), vertices.max(0)], expected.bounds, atol=1e-2)
    edges = boundary_edges(faces)
    xy = vertices[edges][:, :, :2]
    (ex0, ex1, ey0, ey1) = reference.extent
    on_border = (np.isclose(xy[:, :, 0], ex0, atol=1e-2).all(1) | np.isclose(xy[:, :, 0], ex1, atol=1e-2).all(1)
                 | np.isclose(xy[:, :, 1], ey0, atol=1e-2).all(1) | np.isclose(xy[:, :, 1], ey1, atol=1e-2).all(1))
    assert on_border.all(), f"{(~on_border).sum()} boundary edges inside the mosaic (cracks at seams)"


def test_batch_input_options_are_refused_where_they_do_not_apply(tmp_path, capsys):
    """--crop of several files, --spacing of a georeferenced raster or of the embedded DEM: refused by name (exit 2)
    before any work, as steps refuses a --spacing of a georeferenced file."""
    from stepterrain import cli
    from stepterrain.errors import InvalidInputError

    from .conftest import shared_file

    _unreferenced_tiles(tmp_path / "tiles")
    out = tmp_path / "out"
    for argv, said in (
        ([str(tmp_path / "tiles"), "--interval", "50", "--crop", "0,10,-10,0"], "--crop applies to one raster"),
        ([str(shared_file("big_tujunga_srtm_30m_utm11n.npz")), "--tile", "64", "--spacing", "30"],
         "--spacing applies to DEM files with no georeferencing"),
        (["--spacing", "30"], "--spacing applies to a DEM file with no georeferencing"),
        (["--coarsen", "0"], "argument --coarsen: expected a positive whole number"),
    ):
        assert cli.main(["batch", *argv, "--scheduler", "serial", "-o", str(out)]) == 2
        assert said in capsys.readouterr().err, argv
    assert not out.exists()
    with pytest.raises(InvalidInputError, match="coarsen must be a positive integer"):
        batch(str(tmp_path / "tiles"), out, interval=50.0, coarsen=True, scheduler="serial")
    with pytest.raises(InvalidInputError, match=r"spacing must be one cell size D or \(dx, dy\) in positive"):
        batch(str(tmp_path / "tiles"), out, interval=50.0, spacing=(30.0, -30.0), scheduler="serial")
    with pytest.raises(InvalidInputError, match="metadata keys 'coarsen' are written by stepterrain"):
        batch(str(tmp_path / "tiles"), out, interval=50.0, coarsen=2, metadata={"coarsen": 1}, scheduler="serial")


def test_cli_batch_spacing_failure_line_of_a_georeferenced_file_names_the_option(tmp_path, capsys):
    """``batch FOLDER --spacing 30`` over a folder of a .npy and the real Big Tujunga GeoTIFF: the GeoTIFF's failure
    line said "spacing applies to DEM files with no georeferencing", the library's argument, mid-line after the
    item's key and error type where the leading-argument rule does not look. It names --spacing now; the file's own
    "spacing (30.0, -30.0)" after it is a value, left as it is, and the .npy is written."""
    import shutil

    from stepterrain import cli

    from .conftest import real_dem, shared_file

    folder = tmp_path / "dems"
    folder.mkdir()
    shutil.copy(shared_file("big_tujunga_srtm_30m_utm11n.tif"), folder / "tujunga.tif")
    np.save(folder / "plain.npy", real_dem("big_tujunga_srtm_30m_utm11n.npz", size=41, step=1))
    out = tmp_path / "out"
    assert cli.main(["-q", "batch", str(folder), "--spacing", "30", "--interval", "50", "--scheduler", "serial",
                     "-o", str(out)]) == 1
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "failed tujunga" in x)
    assert "InvalidInputError: --spacing applies to DEM files with no georeferencing" in line, err
    assert " spacing applies" not in line and "places its nodes itself: spacing (30.0, -30.0)" in line, line
    assert [p.name for p in out.glob("*.glb")] == ["plain.glb"]


def test_crop_and_coarsen_of_a_source_take_its_geometry_without_a_grid_of_its_size(monkeypatch):
    """batch's crop= and coarsen= learned the cropped and coarsened geometry from a probe Terrain of zeros the size
    of the whole source: 64 MB allocated, checked, cropped and coarsened for a few numbers (old 21 ms for a crop of a
    4000 x 4000 raster, 365 ms with coarsen=4 of which half was the probe's). The geometry now comes from the grid's
    shape, spacing and origin alone; the heights, spacing and origin are Terrain.crop's and .coarsen's, a frame of
    nodata only stays an empty item, and the refusals are said as before."""
    from stepterrain import Terrain
    from stepterrain.batch import _reshaped_source, _Source
    from stepterrain.errors import InvalidInputError

    heights = np.random.default_rng(8).normal(500.0, 50.0, (40, 52)).astype(np.float32)
    heights[:3, :5] = np.nan
    whole = Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(1000.0, 5000.0))
    crop = (1100.0, 2200.0, 4200.0, 4900.0)
    cases = [(crop, None, whole.crop(crop)), (crop, 3, whole.crop(crop).coarsen(3)), (None, 4, whole.coarsen(4)),
             (crop, 1, whole.crop(crop))]
    src = _Source(heights, whole.spacing, whole.origin, None, "raster")
    nodata = np.full_like(heights, np.nan)
    series = _Source(np.stack([heights, nodata]), whole.spacing, whole.origin, None, "series")
    built = []
    real = Terrain.from_heights.__func__
    monkeypatch.setattr(Terrain, "from_heights",
                        classmethod(lambda cls, h, **kw: built.append(np.shape(h)) or real(cls, h, **kw)))
    for extent, factor, expected in cases:
        for source in (src, series):
            built.clear()
            got = _reshaped_source(source, extent, factor)
            # no Terrain of the whole source's size but the frame's own when it is coarsened whole
            assert built.count(heights.shape) == (extent is None), built
            assert (got.spacing, got.origin) == (expected.spacing, expected.origin)
            frames = got.heights if source is series else got.heights[None]
            np.testing.assert_array_equal(frames[0], expected.heights)
            if source is series:
                assert frames.shape == (2, *expected.shape) and np.isnan(frames[1]).all()
    with pytest.raises(InvalidInputError, match=r"^crop extent \(0\.0, 10\.0, 0\.0, 10\.0\) .* holds 0 x 0 nodes"):
        _reshaped_source(src, (0.0, 10.0, 0.0, 10.0), None)
    with pytest.raises(InvalidInputError, match=r"^coarsen=30: factor 30 leaves 1 x 1 nodes of the 40 x 52 grid"):
        _reshaped_source(src, None, 30)
    with pytest.raises(InvalidInputError, match=r"^crop extent \(1000\.0, 1090\.0, 4940\.0, 5000\.0\) holds only "
                                                 r"nodata of the source \(3 x 4 nodes\)"):
        _reshaped_source(src, (1000.0, 1090.0, 4940.0, 5000.0), None)


def test_cli_batch_reads_one_npz_input_once(tmp_path, monkeypatch, capsys):
    """``stepterrain batch dem.npz`` (no --tile) read the whole archive to learn whether it holds one raster (one
    item) or a (T, H, W) series (one item per frame), then read it again: the series for plan_items, the raster for
    its item (85 ms for an 8 x 2000 x 2000 compressed series, 34 ms for a 4000 x 4000 raster, before any work). The
    members' .npy headers answer it now: each file is read once, the outputs are as before, and the decision is
    load_series's for every kind of archive (a 2-D elevation beside a 3-D texture is one raster, a 3-D mask no
    series, an .npy under an .npz name by its dimensions, an unreadable header or a truncated member no raster)."""
    import io as bytes_io
    import zipfile

    import stepterrain.io as io_module
    from stepterrain import cli
    from stepterrain.batch import _one_raster_file, load_series
    from stepterrain.errors import DataFileError, InvalidInputError

    from .test_io import _npy_declaring

    rng = np.random.default_rng(4)
    frames = rng.normal(100.0, 10.0, (3, 12, 14)).astype(np.float32)
    np.savez_compressed(tmp_path / "series.npz", heights=frames)
    np.savez_compressed(tmp_path / "one.npz", heights=frames[0])
    reads = []
    real = io_module.read_npz
    monkeypatch.setattr(io_module, "read_npz", lambda file: reads.append(Path(file).name) or real(file))
    for name, outputs in (("series.npz", ["frame_0000.ply", "frame_0001.ply", "frame_0002.ply"]),
                          ("one.npz", ["one.ply"])):
        reads.clear()
        out = tmp_path / f"out_{name}"
        # --colormap none: coloured (the default now), a file item is read once more first for the shared levels
        assert cli.main(["-q", "batch", str(tmp_path / name), "--interval", "5", "--format", ".ply", "--colormap",
                         "none", "--scheduler", "serial", "-o", str(out)]) == 0, capsys.readouterr().err
        assert reads == [name]
        assert sorted(p.name for p in out.glob("*.ply")) == outputs
    monkeypatch.setattr(io_module, "read_npz", real)

    def one_raster(path):
        try:
            return load_series(path) is None
        except (DataFileError, InvalidInputError):
            return False

    cases = {
        "texture.npz": {"elevation": frames[0], "texture": frames},
        "mask3d.npz": {"heights": frames[0], "mask": np.zeros(frames.shape, bool)},
        "other3d.npz": {"stack": frames},
        "flat.npz": {"heights": frames[0, 0]},
        "text.npz": {"heights": frames, "units": np.array("ft")},
    }
    for name, members in cases.items():
        np.savez(tmp_path / name, **members)
    np.save(tmp_path / "plain.npy", frames)
    (tmp_path / "plain.npy").rename(tmp_path / "npy3d.npz")
    np.save(tmp_path / "plain.npy", frames[0])
    (tmp_path / "plain.npy").rename(tmp_path / "npy2d.npz")
    with zipfile.ZipFile(tmp_path / "truncated.npz", "w") as archive:
        archive.writestr("heights.npy", _npy_declaring((30, 40)))
    with zipfile.ZipFile(tmp_path / "bytes.npz", "w") as archive:  # a member that is no .npy: NumPy reads its bytes
        archive.writestr("heights", b"not an array")
        buffer = bytes_io.BytesIO()
        np.save(buffer, frames)
        archive.writestr("stack.npy", buffer.getvalue())
    (tmp_path / "garbage.npz").write_bytes(b"PK\x03\x04 garbage")
    names = [*cases, "npy3d.npz", "npy2d.npz", "truncated.npz", "bytes.npz", "garbage.npz", "series.npz", "one.npz"]
    got = {name: _one_raster_file(tmp_path / name) for name in names}
    assert got == {name: one_raster(tmp_path / name) for name in names}
    assert [name for name in names if got[name]] == ["texture.npz", "mask3d.npz", "flat.npz", "npy2d.npz", "bytes.npz",
                                                      "one.npz"]


def test_batch_crop_of_a_geotiff_to_tile_reads_only_the_crops_window(tmp_path, capsys):
    """batch (and batch --crop --tile) read the whole GeoTIFF to tile before cropping it, so a raster over the memory
    budget was refused even for a small crop of it. Its crop's window is all that is read now (load_dem's crop=):
    the same tiles, fingerprints aside, as the whole raster cropped (here the Terrain read whole, tiled with the same
    crop), and the same refusals of a crop that holds too few nodes; --coarsen still applies after."""
    import stepterrain as st
    from stepterrain import cli
    from stepterrain.errors import InvalidInputError, OutputTooLargeError
    from stepterrain.io import load_dem

    from .conftest import shared_file

    tif = shared_file("big_tujunga_srtm_30m_utm11n.tif")  # 643 x 1197: 3.1 MB as float32 heights
    whole = load_dem(tif)
    x0, _, _, y1 = whole.extent
    crop = (x0 + 3000.0, x0 + 6000.0, y1 - 5000.0, y1 - 2000.0)  # 101 x 101 nodes
    reference = batch(whole, tmp_path / "ref", tile_size=40, crop=crop, coarsen=2, interval=100.0, format=".ply",
                      scheduler="serial")
    previous = st.set_memory_budget(2_000_000)  # a tile's .ply write needs ~1.1 MB, the raster 3.1 MB
    try:
        with pytest.raises(OutputTooLargeError, match=r"the raster: 643 x 1197 cells"):
            batch(str(tif), tmp_path / "whole", tile_size=40, interval=100.0, scheduler="serial")
        report = batch(str(tif), tmp_path / "out", tile_size=40, crop=crop, coarsen=2, interval=100.0, format=".ply",
                       scheduler="serial")
        with pytest.raises(InvalidInputError, match=r"^crop extent \(0\.0, 1\.0, 0\.0, 1\.0\) \(xmin, xmax, ymin, "
                                                    r"ymax\) holds 0 x 0 nodes of the grid"):
            batch(str(tif), tmp_path / "x", tile_size=40, crop=(0.0, 1.0, 0.0, 1.0), scheduler="serial")
        assert cli.main(["-q", "batch", str(tif), "--tile", "40", "--crop", ",".join(map(repr, crop)), "--interval",
                         "100", "--scheduler", "serial", "--format", ".ply", "-o", str(tmp_path / "cli")]) == 0
    finally:
        st.set_memory_budget(previous)
    assert report.ok and [r.key for r in report.done] == [r.key for r in reference.done] and len(report.done) == 4
    for got, expected in zip(report.done, reference.done, strict=True):
        a, b = (trimesh.load(r.path, process=False) for r in (got, expected))
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.faces, b.faces)
    assert len(list((tmp_path / "cli").glob("*.ply"))) == 9 and not (tmp_path / "x").exists()
    capsys.readouterr()


@pytest.mark.parametrize("series", [False, True], ids=["mosaic", "contact_sheet"])
def test_an_overview_over_the_memory_budget_is_refused_before_any_item_is_written(tmp_path, capsys, series):
    """``stepterrain batch --png`` checked the overview's render against the memory budget only once every tile had
    been stepped and written (minutes of work), then refused it: the mosaic of the tiles weighs what their meshes do,
    however small the --size. batch's ``overview_size`` (the CLI's --png --size) checks it from the plan, counting at
    least the tiles' surfaces (each frame's in its cell of a contact sheet), before any item runs; a budget the check
    refuses refuses the render after the run too, and one it passes renders."""
    from stepterrain import render, set_memory_budget
    from stepterrain.batch import overview_image
    from stepterrain.cli import main
    from stepterrain.errors import OutputTooLargeError

    n = 65 if series else 129
    z = np.add.outer(np.arange(n), np.arange(n)).astype(np.float32)  # a few steps: each item fits the budget
    z = np.stack([z + k for k in range(4)]) if series else z
    z[..., 40, 7] = np.nan  # nodata: fewer triangles counted
    if series:  # one render per frame, in a 40 x 30 cell of the 80 x 60 window: the largest frame counts
        size, surface = (80, 60), (65 * 65 - 1, 2 * 64 * 64 - 6)
        window = render._render_bytes(40, 30, vertices=surface[0], faces=surface[1])
    else:  # sixteen tiles of 33 x 33 nodes, their shared borders counted in each
        size, surface = (200, 150), (16 * 33 * 33 - 1, 16 * 2 * 32 * 32 - 6)
        window = render._render_bytes(200, 150, vertices=surface[0], faces=surface[1])
    options = dict(tile_size=None if series else 32, interval=40.0, scheduler="serial", format=".glb")
    previous = set_memory_budget(window - 1)
    try:
        out = tmp_path / "refused"
        with pytest.raises(OutputTooLargeError, match=r"of a mesh of at least "
                           + f"{surface[1]:,} faces and {surface[0]:,} vertices" + r" would need .*; give coarsen= "
                           r"or a crop= \(fewer nodes per item\), or render no overview"):
            batch(z, out, overview_size=size, **options)
        assert not out.exists()  # nothing stepped, nothing written
        report = batch(z, out, **options)  # without the check: the render itself is refused after the run
        assert report.ok
        with pytest.raises(OutputTooLargeError):
            overview_image(report, window_size=size)
        set_memory_budget(window)
        assert batch(z, tmp_path / "passed", overview_size=size, **options).ok
    finally:
        set_memory_budget(previous)

    # the command line: refused before the folder is made, naming its options
    source = tmp_path / "z.npy"
    np.save(source, z)
    tile = [] if series else ["--tile", "32"]
    if not render.offscreen_available()[0]:
        return
    out = tmp_path / "cli"
    assert main(["-q", "batch", str(source), *tile, "--interval", "40", "-o", str(out), "--scheduler", "serial",
                 "--png", str(tmp_path / "o.png"), "--size", f"{size[0]}x{size[1]}",
                 "--memory-budget", str(window - 1)]) == 2
    err = capsys.readouterr().err
    assert "give --coarsen or a --crop (fewer nodes per item), or leave --png out" in err, err
    assert not out.exists() and not (tmp_path / "o.png").exists()


def test_an_overview_mosaic_of_part_of_the_tiles_says_so(tmp_path):
    """overview_image reads the first max_items (64) outputs: ``stepterrain batch --tile 64 --png`` of the embedded DEM
    (209 tiles) drew a jagged strip of its first tile rows as "the welded tiles", without a word. A mosaic that leaves
    tiles out now warns, naming how many it shows; one of every tile, and a contact sheet (up to 16 items, as
    documented), do not."""
    import warnings

    from stepterrain import render
    from stepterrain.batch import overview_image

    ok, reason = render.offscreen_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL context: {reason}")
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    report = batch(z, tmp_path / "tiles", tile_size=2, interval=2.0, scheduler="serial", format=".ply")
    assert report.ok and len(report.done) == 16
    with pytest.warns(UserWarning, match=r"^the overview's mosaic shows the first 5 of the 16 outputs: the rest of "
                                         r"the raster is left out of the picture; give a larger max_items= or "
                                         r"tile_size \(fewer tiles\)$"):
        overview_image(report, window_size=(64, 48), max_items=5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        overview_image(report, window_size=(64, 48), max_items=16)
        frames = batch(np.stack([z] * 3), tmp_path / "frames", interval=2.0, scheduler="serial", format=".ply")
        overview_image(frames, window_size=(64, 48), max_items=2)  # a contact sheet: up to max_items items


def test_the_cli_says_when_no_overview_is_written(tmp_path, capsys):
    """``stepterrain batch ... --png out.png`` whose every item failed wrote no overview, without a word: the failures
    and exit status 1 said nothing of the PNG asked for. It says so now; a run with outputs writes it."""
    from stepterrain import render
    from stepterrain.cli import main

    if not render.offscreen_available()[0]:
        pytest.skip("no off-screen OpenGL context")
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    (tiles / "a.npy").write_bytes(b"garbage")
    png = tmp_path / "overview.png"
    argv = ["-q", "batch", str(tiles), "--interval", "5", "--scheduler", "serial", "--png", str(png), "--size", "64x48"]
    assert main([*argv, "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert f"stepterrain: no overview written to {png}: every item failed, none has an output to show" in err, err
    assert not png.exists()
    np.save(tiles / "a.npy", np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    assert main([*argv, "-o", str(tmp_path / "out")]) == 0
    assert "no overview" not in capsys.readouterr().err and png.stat().st_size > 0


def test_the_contact_sheet_leaves_an_empty_frame_blank(tmp_path):
    """A frame of nodata only is written as an empty mesh and counts as done (batch's Notes), but the contact sheet
    rendered it as any other: ``stepterrain batch series.npy --png`` wrote every frame, then failed with exit status 2,
    "mesh has no faces; nothing to render". Its cell stays blank now, the other frames drawn; outputs that are all
    empty are refused as such."""
    import dataclasses

    from stepterrain import render
    from stepterrain.batch import overview_image
    from stepterrain.errors import InvalidInputError

    ok, reason = render.offscreen_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL context: {reason}")
    z = np.stack([np.add.outer(np.arange(9.0), np.arange(9.0) ** 1.5)] * 4).astype(np.float32)
    z[1] = np.nan
    report = batch(z, tmp_path / "frames", interval=2.0, scheduler="serial", format=".ply")
    assert report.ok and len(report.done) == 4
    sheet = overview_image(report, window_size=(100, 80))  # 2 x 2 cells of 50 x 40
    drawn = (sheet < 250).any(axis=2)
    assert not drawn[:40, 50:].any()  # frame 1's cell
    for r, c in [(0, 0), (1, 0), (1, 1)]:
        assert drawn[r * 40 : (r + 1) * 40, c * 50 : (c + 1) * 50].mean() > 0.05, (r, c)
    with pytest.raises(InvalidInputError, match=r"^every output the overview shows \(1 of 4\) is an empty mesh "
                                                r"\(no triangle with three finite heights: nodata only\); nothing to "
                                                r"render$"):
        overview_image(dataclasses.replace(report, results=report.results[1:] + report.results[:1]),
                       window_size=(100, 80), max_items=1)  # the empty frame first


def test_the_contact_sheet_leaves_a_cell_too_thin_to_see_blank_not_the_whole_sheet(tmp_path):
    """One item of a contact sheet too thin to see in its cell (a two-row strip of a file, seen from the top in a
    50-pixel cell: 0.024 pixels tall) raised render_mesh's refusal after the whole run, and no sheet was written for
    the other items. Its cell is left blank with a warning naming it; the others are drawn."""
    from stepterrain import render
    from stepterrain.batch import overview_image
    from stepterrain.errors import InvalidInputError

    ok, reason = render.offscreen_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL context: {reason}")
    folder = tmp_path / "in"
    folder.mkdir()
    np.save(folder / "a.npy", np.add.outer(np.arange(20.0), np.arange(20.0) ** 1.5).astype(np.float32))
    np.save(folder / "b.npy", np.stack([np.linspace(0.0, 0.01, 2000)] * 2).astype(np.float32))
    report = batch(folder, tmp_path / "out", interval=2.0, scheduler="serial", format=".ply")
    assert report.ok and len(report.done) == 2
    with pytest.warns(UserWarning, match=r"^the overview's cell of b\.ply \(50 x 80 pixels\) is left blank: the mesh "
                      r"would render 47 x 0\.024 pixels") as said:
        sheet = overview_image(report, window_size=(100, 80), camera="top")
    assert said[0].filename == __file__
    drawn = (sheet < 250).any(axis=2)
    assert drawn[:, :50].mean() > 0.05 and not drawn[:, 50:].any()
    with pytest.raises(InvalidInputError, match="too thin to see"):  # the same item alone: refused as before
        render.render_mesh(read_mesh(tmp_path / "out" / "b.ply"), window_size=(50, 80), camera="top")


def test_a_folders_hidden_files_are_left_out_as_a_shell_glob_leaves_them(tmp_path):
    # a folder of tiles copied from macOS onto a FAT/exFAT drive holds an AppleDouble companion "._t.tif" beside every
    # "t.tif": each was an item that failed ("not recognized as being in a supported file format"), so a folder
    # whose tiles were all good ended with exit status 1 and half its items failed; `stepterrain batch tiles/*.tif`,
    # which the docs give as the same thing, never saw them (the shell's * skips names starting with a dot)
    folder = tmp_path / "tiles"
    folder.mkdir()
    z = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32) * 3
    for name in ("a", "b"):
        np.save(folder / f"{name}.npy", z)
        (folder / f"._{name}.npy").write_bytes(b"Mac OS X        \x00\x05\x16\x07")  # AppleDouble header
    np.save(folder / ".hidden.npy", z)
    report = batch(folder, tmp_path / "out", interval=2.0, scheduler="serial")
    assert report.ok, report.summary()
    assert sorted(r.key for r in report.done) == ["a", "b"]
    for name in ("._a", "._b", ".hidden"):
        assert not any(p.name.startswith(name) for p in (tmp_path / "out").iterdir())
    # a folder holding only hidden DEM files says so
    for path in folder.glob("[ab].npy"):
        path.unlink()
    from stepterrain.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match=r"holds no DEM file.*3 hidden"):
        batch(folder, tmp_path / "out2", interval=2.0, scheduler="serial")


@pytest.mark.render
def test_the_overview_of_a_folder_whose_files_are_named_tile_is_a_contact_sheet(tmp_path):
    # overview_image chose the mosaic by the outputs' names (all starting with "tile_"), so a folder of a user's
    # tile_*.tif files (a common naming) was rendered as one mesh in world coordinates, not the contact sheet the
    # docs give a folder: unreferenced .npy tiles (each at (0, 0)) drawn on top of each other, tiles of several UTM
    # zones hundreds of km apart as specks. The batch's items decide: tiles of one raster, or not
    from stepterrain import render
    from stepterrain.batch import overview_image

    ok, reason = render.offscreen_available()
    if not ok:
        pytest.skip(f"no off-screen OpenGL context: {reason}")
    folder = tmp_path / "tiles"
    folder.mkdir()
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    np.save(folder / "tile_001.npy", z)
    np.save(folder / "tile_002.npy", z[::-1] * 2)
    report = batch(folder, tmp_path / "out", interval=2.0, scheduler="serial", format=".ply")
    assert report.ok and len(report.done) == 2
    size = (96, 48)
    sheet = overview_image(report, window_size=size)
    np.testing.assert_array_equal(sheet, overview_image(report, window_size=size, mosaic=False))
    drawn = (sheet < 250).any(axis=2)
    assert drawn[:, :48].mean() > 0.05 and drawn[:, 48:].mean() > 0.05  # one file in each cell
    # the tiles of one raster are still a mosaic, whatever the folder
    tiles = batch(z, tmp_path / "raster", tile_size=4, interval=2.0, scheduler="serial", format=".ply")
    np.testing.assert_array_equal(overview_image(tiles, window_size=size),
                                  overview_image(tiles, window_size=size, mosaic=True))


def test_relative_paths_reach_workers_started_in_another_folder(tmp_path, monkeypatch):
    # `stepterrain batch tiles -o out --scheduler tcp://...` from /data/project, its dask workers started elsewhere
    # (by ssh or systemd, in $HOME): the workers were handed the relative paths as given, so every file item failed
    # "DEM file 'tiles/a.npy' does not exist", and the tiles of one raster were written into out/ under the workers'
    # folder, the report saying "written" and the manifest recording files that were not in the caller's out/
    distributed = pytest.importorskip("distributed")
    elsewhere = tmp_path / "workers_home"
    elsewhere.mkdir()
    here = tmp_path / "project"
    (here / "tiles").mkdir(parents=True)
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    for name in ("a", "b"):
        np.save(here / "tiles" / f"{name}.npy", z)
    monkeypatch.chdir(elsewhere)  # the worker processes start in this folder
    cluster_options = dict(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None)
    with distributed.LocalCluster(**cluster_options) as cluster, distributed.Client(cluster) as client:
        monkeypatch.chdir(here)
        files = batch("tiles", "out_files", interval=2.0, scheduler=client, format=".ply")
        tiles = batch(z, "out_tiles", tile_size=4, interval=2.0, scheduler=client, format=".ply")
    for report, folder, n in [(files, "out_files", 2), (tiles, "out_tiles", 4)]:
        assert report.ok and len(report.done) == n, report.summary()
        for result in report.done:
            assert Path(result.path).parent == Path(folder)  # as a serial run reports it: relative
            assert (here / result.path).stat().st_size == result.bytes
    assert list(elsewhere.iterdir()) == []  # nothing written where the workers run
    # the same bytes as a serial run (the metadata's input as given)
    serial = batch("tiles", "serial", interval=2.0, scheduler="serial", format=".ply")
    for a, b in zip(serial.done, files.done, strict=True):
        assert Path(a.path).read_bytes() == Path(b.path).read_bytes()


def test_a_shell_glob_that_matched_no_file_is_said_to_be_one(tmp_path, capsys):
    # `stepterrain batch tiles/n3*.tif` with no such file: the shell passes the pattern on as written, and the error
    # said "source 'tiles/n3*.tif' does not exist (expected a DEM file or a folder of tiles)", as if a file of that
    # name were meant
    from stepterrain import cli

    (tmp_path / "tiles").mkdir()
    a = tmp_path / "tiles" / "a.npy"
    np.save(a, np.zeros((3, 3), np.float32))
    out = tmp_path / "out"
    pattern = str(tmp_path / "tiles" / "n3*.tif")
    for inputs in ([pattern], [str(a), pattern]):
        argv = ["batch", *inputs, "--interval", "1", "--scheduler", "serial", "-q", "-o", str(out)]
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert f"{pattern!r} does not exist" in err and "a shell glob that matched no file" in err, err
        assert not out.exists()
    # a missing file of no pattern keeps its message
    assert cli.main(["batch", str(tmp_path / "nope.tif"), "--interval", "1", "--scheduler", "serial", "-q", "-o",
                     str(out)]) == 2
    assert "matched no file" not in capsys.readouterr().err


def test_a_folders_broken_link_is_an_item_that_fails_not_a_tile_left_out_unsaid(tmp_path):
    # a folder of links to tiles on another disk (or a share not mounted): a link whose tile had gone was left out of
    # the items without a word (Path.is_file() is False for it), the run "ok" with that tile's mesh missing
    folder = tmp_path / "tiles"
    folder.mkdir()
    z = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32) * 3
    np.save(folder / "a.npy", z)
    (folder / "b.npy").symlink_to(tmp_path / "elsewhere" / "b.npy")
    report = batch(folder, tmp_path / "out", interval=2.0, scheduler="serial")
    assert [r.key for r in report.done] == ["a"]
    assert [r.key for r in report.failed] == ["b"] and "does not exist" in report.failed[0].error
    assert not report.ok


def _cut_tiles(tmp_path, src, folder, size=(31, 41)):
    """Four tiles of ``src`` (rows, cols of nodes each), cut as gdal_translate -srcwin cuts them, neighbours sharing
    their border row or column of nodes; their paths by name (nw, ne, sw, se)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine
    from rasterio.windows import Window

    (tmp_path / folder).mkdir()
    h, w = size
    paths = {}
    with rasterio.open(src) as dataset:
        t = dataset.transform  # (window_transform: a PendingDeprecationWarning of rasterio's own)
        for name, (r, c) in {"nw": (0, 0), "ne": (0, 1), "sw": (1, 0), "se": (1, 1)}.items():
            window = Window(c * (w - 1), r * (h - 1), w, h)
            corner = Affine(t.a, t.b, t.c + window.col_off * t.a, t.d, t.e, t.f + window.row_off * t.e)
            profile = dict(dataset.profile, width=w, height=h, transform=corner)
            paths[name] = tmp_path / folder / f"{name}.tif"
            with rasterio.open(paths[name], "w", **profile) as out:
                out.write(dataset.read(1, window=window), 1)
    return paths


def _border_vertices(mesh, axis, value, tolerance=1e-3):
    """The vertices of ``mesh`` within ``tolerance`` of the plane ``axis`` = ``value`` (float32's rounding of the
    coordinates: stepped meshes place a tile's nodes in float32, so a node two tiles share lies in both within it)."""
    v = np.asarray(mesh.vertices)
    return v[np.abs(v[:, axis] - value) <= tolerance]


def _coincide(a, b, tolerance=1e-3):
    """Whether every point of ``a`` has one of ``b`` within ``tolerance`` and the other way round."""
    gap = np.abs(a[:, None, :] - b[None, :, :]).max(axis=2)
    return bool(len(a) and len(b) and (gap.min(axis=1) <= tolerance).all() and (gap.min(axis=0) <= tolerance).all())


@pytest.mark.skipif(shutil.which("gdalbuildvrt") is None, reason="needs gdalbuildvrt (gdal-bin)")
def test_several_dem_files_in_degrees_lie_in_one_frame_and_weld_as_their_mosaics_tiles(tmp_path):
    """A folder of DEM files in degrees (SRTM .hgt tiles, any EPSG:4326 GeoTIFFs) was stepped each file in local
    metres of its own (node (0, 0) at its first node): the meshes all lay at (0, 0), on top of one another, and
    neighbours sharing their border nodes did not weld as a projected folder's do. They lie now in the local metres
    of their mosaic: every mesh is the one cutting the files' .vrt into tiles gives, the vertices neighbours share
    coincide, and no warning is given; a projected folder's outputs are as they were."""
    from .conftest import SHARED_DATA

    geo = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
    if not geo.exists():
        pytest.skip(f"shared data {geo.name} not found")
    tiles = _cut_tiles(tmp_path, geo, "geo")
    subprocess.run(["gdalbuildvrt", "-q", str(tmp_path / "mosaic.vrt"), *map(str, tiles.values())], check=True)

    def run(source, out, **kwargs):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch(source, tmp_path / out, interval=100.0, scheduler="serial", **kwargs)
        assert report.ok, report.summary()
        return [str(w.message) for w in caught if "in degrees" in str(w.message)]

    said = run(tmp_path / "geo", "geo_out")
    run(tmp_path / "mosaic.vrt", "vrt_out", tile_size=(30, 40))
    mesh = {name: read_mesh(tmp_path / "geo_out" / f"{name}.glb") for name in tiles}
    cut = {"nw": "tile_r0_c0", "ne": "tile_r0_c1", "sw": "tile_r1_c0", "se": "tile_r1_c1"}
    for name, key in cut.items():  # the .vrt's tiles: same vertices, to float32 rounding
        of_vrt = read_mesh(tmp_path / "vrt_out" / f"{key}.glb")
        assert len(mesh[name].vertices) == len(of_vrt.vertices) and len(mesh[name].faces) == len(of_vrt.faces)
        np.testing.assert_allclose(mesh[name].vertices, of_vrt.vertices, rtol=0, atol=1e-3)
    x_border = mesh["nw"].bounds[1, 0]  # the west tiles' east edge, the east tiles' west edge
    assert x_border > 2000.0 and abs(mesh["ne"].bounds[0, 0] - x_border) < 1e-3
    for west, east in (("nw", "ne"), ("sw", "se")):
        shared = _border_vertices(mesh[west], 0, x_border)
        assert len(shared) > 30 and _coincide(shared, _border_vertices(mesh[east], 0, x_border))
    y_border = mesh["nw"].bounds[0, 1]  # the north tiles' south edge, the south tiles' north edge
    assert y_border < -2000.0 and abs(mesh["sw"].bounds[1, 1] - y_border) < 1e-3
    for north, south in (("nw", "sw"), ("ne", "se")):
        shared = _border_vertices(mesh[north], 1, y_border)
        assert len(shared) > 30 and _coincide(shared, _border_vertices(mesh[south], 1, y_border))
    assert "placed in the mosaic of the DEM files" in str(mesh["se"].metadata)
    assert said == []  # nothing left to warn of

    _cut_tiles(tmp_path, SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif", "utm")
    run(tmp_path / "utm", "utm_out")
    west, east = read_mesh(tmp_path / "utm_out" / "nw.glb"), read_mesh(tmp_path / "utm_out" / "ne.glb")
    assert west.bounds[1, 0] == east.bounds[0, 0]  # a projected folder's neighbours meet on their shared column


def test_dem_files_in_degrees_left_each_in_its_own_frame_are_warned_of_once(tmp_path):
    """Files in degrees that are not placed in a shared frame (an .npz, which is not read through GDAL) still lie
    each at (0, 0) in local metres of its own: the run says so once; one such file says nothing."""
    heights = np.arange(12.0, dtype=np.float32).reshape(3, 4) * 50.0
    for i in range(2):
        transform = np.array([-105.0 + i * 0.003, 0.001, 0.0, 40.0, 0.0, -0.001])
        np.savez(tmp_path / f"t{i}.npz", elevation=heights, transform=transform, crs="EPSG:4326")

    def run(source, out):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch(source, tmp_path / out, interval=100.0, scheduler="serial")
        assert report.ok, report.summary()
        return [str(w.message) for w in caught if "in degrees" in str(w.message)]

    said = run([tmp_path / "t0.npz", tmp_path / "t1.npz"], "out")
    assert len(said) == 1 and "neither line up nor weld" in said[0] and "gdalbuildvrt" in said[0]
    # its other remedy warps the files into one raster: each reprojected alone (gdalwarp -t_srs of one file) lies in
    # place, but on a grid of its own, sharing no nodes with its neighbours, so their meshes would not weld either
    assert "gdalwarp -dstalpha -t_srs EPSG:... FILES dem.tif" in said[0] and "one by one" in said[0]
    assert run([tmp_path / "t1.npz"], "one_out") == []


def test_dem_files_in_degrees_left_each_in_its_own_frame_are_warned_of_also_when_coarsened(tmp_path):
    """With ``coarsen``, a file's first node is a block's mean, half a block from load_dem's node (0, 0): files in
    degrees left each in local metres of its own (here .npz files) lay on top of one another as before, but the run
    said nothing, the warning looking for a grid whose origin is (0, 0)."""
    heights = np.arange(42.0, dtype=np.float32).reshape(6, 7) * 50.0
    for i in range(2):
        transform = np.array([-105.0 + i * 0.006, 0.001, 0.0, 40.0, 0.0, -0.001])
        np.savez(tmp_path / f"t{i}.npz", elevation=heights, transform=transform, crs="EPSG:4326")
    for factor in (2, 3):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch([tmp_path / "t0.npz", tmp_path / "t1.npz"], tmp_path / f"out{factor}", interval=100.0,
                           scheduler="serial", coarsen=factor)
        assert report.ok, report.summary()
        said = [str(w.message) for w in caught if "in degrees" in str(w.message)]
        assert len(said) == 1 and "neither line up nor weld" in said[0], (factor, said)


def test_dem_files_in_two_geographic_crss_are_warned_to_lie_in_two_frames(tmp_path):
    """The files in degrees of each geographic CRS are placed in the local metres of their own mosaic, node (0, 0) at
    its top-left node: two files in EPSG:4326 and two in EPSG:4269 (NAD83) made two frames, whose meshes overlapped
    at (0, 0) without a word (a folder of files in degrees said it once before they were placed in a shared frame).
    The run now says so once, naming the CRSs; files in one CRS say nothing (above)."""
    rasterio = pytest.importorskip("rasterio")
    from .conftest import SHARED_DATA

    geo = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
    if not geo.exists():
        pytest.skip(f"shared data {geo.name} not found")
    tiles = _cut_tiles(tmp_path, geo, "geo")
    for name in ("sw", "se"):
        with rasterio.open(tiles[name], "r+") as dataset:
            dataset.crs = rasterio.crs.CRS.from_epsg(4269)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch(tmp_path / "geo", tmp_path / "out", interval=100.0, scheduler="serial")
    assert report.ok, report.summary()
    said = [str(w.message) for w in caught if "geographic CRSs" in str(w.message)]
    assert len(said) == 1 and "EPSG:4269" in said[0] and "EPSG:4326" in said[0] and "gdalwarp" in said[0], said
    nw, sw = read_mesh(tmp_path / "out" / "nw.glb"), read_mesh(tmp_path / "out" / "sw.glb")
    # as warned: the north edges of the NAD83 frame's files and of the WGS 84 frame's both at y = 0, overlapping
    assert nw.bounds[1, 1] == pytest.approx(0.0, abs=1e-3) and sw.bounds[1, 1] == pytest.approx(0.0, abs=1e-3)


def test_dem_files_in_two_projected_crss_are_warned_not_to_line_up(tmp_path):
    """A folder's files in two projected CRSs (tiles of Big Tujunga in UTM zone 11, one warped to zone 10, as a
    download across a zone boundary comes) lie each in its own CRS's metres: their meshes lay hundreds of kilometres
    apart without a word, where files in two geographic CRSs were warned of (above). The run now says so once,
    naming the CRSs and the gdalwarp that joins them, and so for files in a projected CRS beside files in degrees;
    files in one projected CRS, named once by its EPSG code and once by its ESRI WKT, say nothing."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    from .conftest import SHARED_DATA

    utm = SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif"
    if not utm.exists():
        pytest.skip(f"shared data {utm.name} not found")
    tiles = _cut_tiles(tmp_path, utm, "utm")

    def warp(name, crs):
        with rasterio.open(tiles[name]) as src, warnings.catch_warnings():
            warnings.simplefilter("ignore", PendingDeprecationWarning)  # rasterio's own Affine * in it
            transform, width, height = calculate_default_transform(src.crs, crs, src.width, src.height, *src.bounds)
            profile = dict(src.profile, crs=crs, transform=transform, width=width, height=height)
            heights = src.read(1)
        tiles[name].unlink()
        with rasterio.open(tiles[name], "w", **profile) as out:
            reproject(heights, rasterio.band(out, 1), src_transform=src.transform, src_crs=src.crs,
                      dst_transform=transform, dst_crs=crs, resampling=Resampling.nearest)

    def said(folder):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch(folder, tmp_path / f"out_{folder.name}", interval=100.0, scheduler="serial")
        assert report.ok, report.summary()
        return [str(w.message) for w in caught if "CRSs" in str(w.message)]

    # one CRS, named two ways: silent
    with rasterio.open(tiles["se"], "r+") as dataset:
        dataset.crs = rasterio.crs.CRS.from_wkt(dataset.crs.to_wkt(version="WKT1_ESRI"))
    assert said(tmp_path / "utm") == []

    warp("se", "EPSG:32610")
    found = said(tmp_path / "utm")
    assert len(found) == 1 and "EPSG:32611 (3 files)" in found[0] and "EPSG:32610 (1 file)" in found[0], found
    assert "gdalwarp -dstalpha -t_srs EPSG:32611" in found[0], found
    # as warned: the zone 10 tile's mesh lies hundreds of kilometres east of its zone 11 neighbours'
    sw, se = read_mesh(tmp_path / "out_utm" / "sw.glb"), read_mesh(tmp_path / "out_utm" / "se.glb")
    assert se.bounds[0, 0] - sw.bounds[1, 0] > 100e3

    warp("se", "EPSG:4326")
    found = said(tmp_path / "utm")
    assert len(found) == 1 and "EPSG:32611 (3 files)" in found[0] and "EPSG:4326 (1 file in degrees)" in found[0]


def test_a_dem_file_in_degrees_load_dem_refuses_fails_alone_not_the_run_nor_the_others_frame(tmp_path):
    """A file in degrees whose geotransform load_dem refuses, among files it places in their mosaic's frame: one of
    zero pixel height ended the whole run with a ZeroDivisionError (the mosaic's rows counted in its steps), where
    its item had failed alone; one whose latitudes pass 90 (a projected grid labelled EPSG:4326) left every file of
    its CRS out of the shared frame, back at (0, 0). Each now fails alone, as its read says why, and the others are
    placed side by side."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from .conftest import SHARED_DATA

    geo = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
    if not geo.exists():
        pytest.skip(f"shared data {geo.name} not found")
    tiles = _cut_tiles(tmp_path, geo, "geo")
    heights = np.arange(20, dtype=np.float32).reshape(4, 5) * 100.0
    for name, transform in (("a_flat.tif", Affine(0.001, 0.0, -105.0, 0.0, 0.0, 40.0)),  # first: the frame's steps
                            ("z_north.tif", Affine(0.001, 0.0, -105.0, 0.0, -0.001, 95.0))):
        with rasterio.open(tmp_path / "geo" / name, "w", driver="GTiff", width=5, height=4, count=1, dtype="float32",
                           crs="EPSG:4326", transform=transform) as out:
            out.write(heights, 1)
    report = batch(tmp_path / "geo", tmp_path / "out", interval=100.0, scheduler="serial")
    assert sorted(r.key for r in report.done) == sorted(tiles), report.summary()
    failed = {r.key: r.error for r in report.failed}
    assert set(failed) == {"a_flat", "z_north"}, report.summary()
    assert "zero pixel size" in failed["a_flat"] and "latitudes" in failed["z_north"], failed
    nw, ne = read_mesh(tmp_path / "out" / "nw.glb"), read_mesh(tmp_path / "out" / "ne.glb")
    assert nw.bounds[1, 0] > 2000.0 and abs(ne.bounds[0, 0] - nw.bounds[1, 0]) < 1e-3  # side by side


def test_a_file_in_degrees_added_to_a_folder_redoes_the_files_whose_frame_it_moves(tmp_path):
    """The shared frame of a folder's files in degrees depends on all of them: a file that widens their mosaic moves
    the others (node (0, 0) and the latitude of their one spacing), so a rerun redoes them, as a fresh run writes them;
    a file within the mosaic moves none, and the rerun keeps them."""
    from .conftest import SHARED_DATA

    geo = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
    if not geo.exists():
        pytest.skip(f"shared data {geo.name} not found")
    tiles = _cut_tiles(tmp_path, geo, "all")
    (tmp_path / "geo").mkdir()
    for name in ("nw", "ne"):
        shutil.copy(tiles[name], tmp_path / "geo")
    kwargs = {"levels": [2000.0, 2500.0, 3000.0, 3500.0], "scheduler": "serial"}  # the levels no file moves
    assert len(batch(tmp_path / "geo", tmp_path / "out", **kwargs).done) == 2
    assert len(batch(tmp_path / "geo", tmp_path / "out", **kwargs).skipped) == 2
    shutil.copy(tiles["sw"], tmp_path / "geo")  # south of them: the mosaic's middle latitude moves
    report = batch(tmp_path / "geo", tmp_path / "out", **kwargs)
    assert sorted(r.key for r in report.done) == ["ne", "nw", "sw"], report.summary()
    fresh = batch(tmp_path / "geo", tmp_path / "fresh", **kwargs)
    for name in ("nw", "ne", "sw"):
        np.testing.assert_array_equal(read_mesh(tmp_path / "out" / f"{name}.glb").vertices,
                                      read_mesh(tmp_path / "fresh" / f"{name}.glb").vertices)
    assert fresh.ok
    shutil.copy(tiles["nw"], tmp_path / "geo" / "nw_again.tif")  # within the mosaic: no frame moves
    report = batch(tmp_path / "geo", tmp_path / "out", **kwargs)
    assert [r.key for r in report.done] == ["nw_again"] and len(report.skipped) == 3, report.summary()


def test_the_local_cluster_starts_no_more_workers_than_items_to_run(tmp_path, monkeypatch):
    # workers=8 for two files started eight worker processes (seconds each to import stepterrain on a small box), and
    # a LocalCluster gives each worker 1/n_workers of the machine's memory as its limit: the two that had work got an
    # eighth each, killed by their nannies at 95 % of it where two workers had half the memory each
    import stepterrain.batch as batch_module

    pytest.importorskip("distributed")
    started: list[int] = []

    class Started(Exception):
        pass

    def record(workers):
        started.append(workers)
        raise Started  # the count is what matters here: no cluster started

    monkeypatch.setattr(batch_module, "start_local_cluster", record)
    src = tmp_path / "dems"
    src.mkdir()
    for k in range(3):
        np.save(src / f"t{k}.npy", np.add.outer(np.arange(6.0), np.arange(6.0)).astype(np.float32) + k)
    out = tmp_path / "out"
    with pytest.raises(Started):
        batch(src, out, interval=1.0, workers=8)
    batch(src, out, interval=1.0, scheduler="serial")
    (out / "t1.glb").unlink()  # one item left to redo
    with pytest.raises(Started):
        batch(src, out, interval=1.0, workers=8)
    with pytest.raises(Started):
        batch(src, out, interval=1.0, workers=2)
    assert started == [3, 1, 1]


@pytest.mark.parametrize("bad", ["nan_x0", "nan_dx", "inf_x0", "huge_x0"])
def test_a_dem_file_in_degrees_with_a_non_finite_or_absurd_geotransform_fails_alone(tmp_path, bad):
    """A file in degrees whose geotransform holds NaN or inf (x0 or dx), among files placed in their mosaic's frame,
    ended the whole run with a ValueError/OverflowError in shared_degree_frame (its nodes counted in the mosaic's
    steps); load_dem read it alone, its local CRS '+lon_0=nan'. One at lon 1e300 made the union no degrees, so
    every file of its CRS fell back to its own frame at (0, 0). Each now fails alone with a DataFileError naming
    the file, and the others are placed side by side."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from .conftest import SHARED_DATA

    geo = SHARED_DATA / "front_range_srtmgl3_3arcsec.tif"
    if not geo.exists():
        pytest.skip(f"shared data {geo.name} not found")
    tiles = _cut_tiles(tmp_path, geo, "geo")
    nan, inf = float("nan"), float("inf")
    transform = {"nan_x0": Affine(0.001, 0.0, nan, 0.0, -0.001, 40.0),
                 "nan_dx": Affine(nan, 0.0, -105.0, 0.0, -0.001, 40.0),
                 "inf_x0": Affine(0.001, 0.0, inf, 0.0, -0.001, 40.0),
                 "huge_x0": Affine(0.001, 0.0, 1e300, 0.0, -0.001, 40.0)}[bad]
    with rasterio.open(tmp_path / "geo" / "bad.tif", "w", driver="GTiff", width=5, height=4, count=1,
                       dtype="float32", crs="EPSG:4326", transform=transform) as out:
        out.write(np.arange(20, dtype=np.float32).reshape(4, 5) * 100.0, 1)
    report = batch(tmp_path / "geo", tmp_path / "out", interval=100.0, scheduler="serial")
    assert sorted(r.key for r in report.done) == sorted(tiles), report.summary()
    assert [r.key for r in report.failed] == ["bad"], report.summary()
    error = report.failed[0].error
    assert error.startswith("DataFileError: ") and "bad.tif" in error, error
    assert ("finite" in error) if bad != "huge_x0" else ("longitudes" in error), error
    nw, ne = read_mesh(tmp_path / "out" / "nw.glb"), read_mesh(tmp_path / "out" / "ne.glb")
    assert nw.bounds[1, 0] > 2000.0 and abs(ne.bounds[0, 0] - nw.bounds[1, 0]) < 1e-3  # side by side


def test_dem_files_in_degrees_of_several_cell_sizes_are_placed_alike_in_any_order(tmp_path):
    """The shared frame of files in degrees took its steps from the first file: a list of files of several cell sizes
    placed each file elsewhere in another order (node (0, 0) half of another step from the union's corner), and a
    rerun in that order redid them all. The frame now takes the mean of their steps, as ``gdalbuildvrt`` mosaics
    them (``-resolution average``): every order writes the same meshes, and the frame is the one load_dem reads the
    files' .vrt in (its spacing and +proj=eqc CRS)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.io import degree_header, load_dem, shared_degree_frame

    steps = {"a": 0.001, "b": 0.0005, "c": 0.00025}
    for i, (name, step) in enumerate(steps.items()):
        n = round(0.01 / step)
        heights = (np.add.outer(np.arange(n), np.arange(n)) * 50.0 * step / 0.001 + 1000.0).astype(np.float32)
        with rasterio.open(tmp_path / f"{name}.tif", "w", driver="GTiff", width=n, height=n, count=1,
                           dtype="float32", crs="EPSG:4326",
                           transform=Affine(step, 0.0, -105.0 + 0.01 * i, 0.0, -step, 40.0 - 0.003 * i)) as out:
            out.write(heights, 1)
    orders = (["a", "b", "c"], ["c", "b", "a"], ["b", "c", "a"])
    vertices = []
    for k, order in enumerate(orders):
        report = batch([tmp_path / f"{name}.tif" for name in order], tmp_path / f"out{k}", interval=100.0,
                       scheduler="serial")
        assert report.ok and len(report.done) == 3, report.summary()
        vertices.append({name: read_mesh(tmp_path / f"out{k}" / f"{name}.glb").vertices for name in steps})
    for other in vertices[1:]:
        for name in steps:
            np.testing.assert_array_equal(other[name], vertices[0][name])
    if shutil.which("gdalbuildvrt") is None:
        return
    subprocess.run(["gdalbuildvrt", "-q", str(tmp_path / "m.vrt"), *(str(tmp_path / f"{n}.tif") for n in steps)],
                   check=True)
    headers = [degree_header(tmp_path / f"{name}.tif") for name in steps]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spacing, crs, _, _ = shared_degree_frame("EPSG:4326", [h[1] for h in headers], [h[2] for h in headers])
        mosaic = load_dem(tmp_path / "m.vrt")
    np.testing.assert_allclose(spacing, mosaic.spacing, rtol=1e-9)
    assert crs == mosaic.crs


@pytest.mark.parametrize("east_lon", [179.99, 359.99])
def test_dem_files_in_degrees_either_side_of_the_antimeridian_are_warned_of(tmp_path, east_lon):
    """Files in degrees that meet at the antimeridian (a tile at lon 179.99 to 180 and one at -180 to -179.99) were
    placed in their mosaic's frame, as the .vrt gdalbuildvrt makes of them has them: a whole parallel apart
    (some 8500 km at 40° N), without a word. Written with the other file in 0 to 360 (lon 359.99 to 360 and
    -0.01 to 0: one place), the union spanned over 360 degrees, so each file fell back to a frame of its own,
    and the run said only that an .npz, or a file alone in its CRS, was left so. The run now says once which
    files lie either side of the antimeridian (or in two longitude conventions), naming them, and how to join them."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    heights = (np.arange(100, dtype=np.float32).reshape(10, 10) * 5.0 + 100.0)
    west_lon = -180.0 if east_lon < 180.0 else -0.01
    for name, lon in (("east.tif", east_lon), ("west.tif", west_lon)):
        with rasterio.open(tmp_path / name, "w", driver="GTiff", width=10, height=10, count=1, dtype="float32",
                           crs="EPSG:4326", transform=Affine(0.001, 0.0, lon, 0.0, -0.001, 40.0)) as out:
            out.write(heights, 1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch(tmp_path, tmp_path / "out", interval=100.0, scheduler="serial")
    assert report.ok, report.summary()
    said = [str(w.message) for w in caught if "antimeridian" in str(w.message)]
    assert len(said) == 1 and "east.tif" in said[0] and "west.tif" in said[0], [str(w.message) for w in caught]
    assert "+lon_wrap=180" in said[0], said[0]
    # one place, two conventions, each file in a frame of its own: said as such, not as "an .npz, or one alone in
    # its geographic CRS" alone, which neither file is
    own = [str(w.message) for w in caught if "neither line up nor weld" in str(w.message)]
    assert len(own) == (east_lon > 180.0) and all("more than 360 degrees" in m for m in own), own


def test_dem_files_in_degrees_side_by_side_or_round_the_globe_say_nothing_of_the_antimeridian(tmp_path):
    """Neighbours away from it, and files that go round the globe (no gap to close across it), are not warned of."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    heights = (np.arange(100, dtype=np.float32).reshape(10, 10) * 5.0 + 100.0)
    for folder, lons, step in (("near", (-105.0, -104.99), 0.001), ("round", (-180.0, -60.0, 60.0), 12.0)):
        (tmp_path / folder).mkdir()
        for i, lon in enumerate(lons):
            with rasterio.open(tmp_path / folder / f"t{i}.tif", "w", driver="GTiff", width=10, height=10, count=1,
                               dtype="float32", crs="EPSG:4326",
                               transform=Affine(step, 0.0, lon, 0.0, -step, 40.0)) as out:
                out.write(heights, 1)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch(tmp_path / folder, tmp_path / f"{folder}_out", interval=100.0, scheduler="serial")
        assert report.ok, report.summary()
        assert not any("antimeridian" in str(w.message) for w in caught), folder


def test_dem_files_in_degrees_with_float_noise_rotation_terms_are_placed_in_their_mosaics_frame(tmp_path):
    """load_dem takes a geotransform's rotation terms of float noise (1e-16 of a degree, as some tools write) as 0,
    but the folder's frame took any non-zero one for a rotated grid: such files were each left in local metres of
    their own, their meshes on top of one another at (0, 0), and the run said it was for an .npz or a file alone in
    its CRS. They are placed side by side now, as the same files with exact zeros are."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    heights = (np.arange(100, dtype=np.float32).reshape(10, 10) * 5.0 + 100.0)
    meshes = {}
    for folder, noise in (("exact", 0.0), ("noise", 1e-16)):
        (tmp_path / folder).mkdir()
        for name, lon in (("w", -105.0), ("e", -104.991)):  # neighbours sharing a column of nodes
            with rasterio.open(tmp_path / folder / f"{name}.tif", "w", driver="GTiff", width=10, height=10, count=1,
                               dtype="float32", crs="EPSG:4326",
                               transform=Affine(0.001, noise, lon, noise, -0.001, 40.0)) as out:
                out.write(heights, 1)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch(tmp_path / folder, tmp_path / f"{folder}_out", interval=100.0, scheduler="serial")
        assert report.ok, report.summary()
        assert not any("in degrees" in str(w.message) for w in caught), [str(w.message) for w in caught]
        meshes[folder] = {n: read_mesh(tmp_path / f"{folder}_out" / f"{n}.glb").vertices for n in ("w", "e")}
    assert meshes["exact"]["e"][:, 0].min() > 700.0  # east of the west file, not on it at (0, 0)
    for name in ("w", "e"):
        np.testing.assert_allclose(meshes["noise"][name], meshes["exact"][name], rtol=0, atol=1e-3)


def test_dem_files_in_degrees_north_up_and_south_up_are_placed_alike_in_either_order(tmp_path):
    """A list of a north-up file in degrees and a south-up one (rows south to north) south of it took its frame's
    direction from the first: listed the other way round, each file lay elsewhere (node (0, 0) at the union's
    south-west node, not its north-west one). Now the frame is north-up when they disagree, as gdalbuildvrt's
    mosaic is, in either order: the same meshes, the north file's top edge at y = 0 and the south file below it."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    heights = (np.arange(100, dtype=np.float32).reshape(10, 10) * 5.0 + 100.0)
    for name, transform in (("north", Affine(0.001, 0.0, -105.0, 0.0, -0.001, 40.0)),
                            ("south", Affine(0.001, 0.0, -105.0, 0.0, 0.001, 39.98))):
        with rasterio.open(tmp_path / f"{name}.tif", "w", driver="GTiff", width=10, height=10, count=1,
                           dtype="float32", crs="EPSG:4326", transform=transform) as out:
            out.write(heights, 1)
    vertices = []
    for k, order in enumerate((["north", "south"], ["south", "north"])):
        report = batch([tmp_path / f"{name}.tif" for name in order], tmp_path / f"out{k}", interval=10.0,
                       scheduler="serial")
        assert report.ok, report.summary()
        vertices.append({n: read_mesh(tmp_path / f"out{k}" / f"{n}.glb").vertices for n in ("north", "south")})
    for name in ("north", "south"):
        np.testing.assert_array_equal(vertices[1][name], vertices[0][name])
    north, south = vertices[0]["north"], vertices[0]["south"]
    assert north[:, 1].max() == pytest.approx(0.0, abs=1e-3)  # node (0, 0): the union's north-west node
    assert south[:, 1].max() < north[:, 1].min()  # the south file below the north one


@pytest.mark.parametrize(("west_lon", "east_lon"), [(359.9, 0.0), (179.9, -180.0)])
def test_the_antimeridian_warnings_advice_joins_the_files(tmp_path, west_lon, east_lon):
    """Files in degrees in 0 to 360 either side of the prime meridian (lon 359.9 to 360 and 0 to 0.1: western Europe
    as a 0-to-360 product tiles it) were warned of as either side of the antimeridian and told to take longitudes 0
    to 360 (+lon_wrap=180), which they have: the advice left them a whole parallel apart. The warning now names the
    wrap that joins them (+lon_wrap=0 here, 180 across the antimeridian); with each file's longitudes wrapped as it
    says, the run warns no more and their meshes lie side by side."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    heights = np.arange(100, dtype=np.float32).reshape(10, 10) * 5.0 + 100.0

    def write(folder, wrap=None):
        (tmp_path / folder).mkdir()
        for name, lon in (("w", west_lon), ("e", east_lon)):
            if wrap is not None:  # each file's longitudes within [wrap - 180, wrap + 180), as gdalwarp's +lon_wrap
                lon = (lon - (wrap - 180.0)) % 360.0 + (wrap - 180.0)
            with rasterio.open(tmp_path / folder / f"{name}.tif", "w", driver="GTiff", width=10, height=10, count=1,
                               dtype="float32", crs="EPSG:4326",
                               transform=Affine(0.01, 0.0, lon, 0.0, -0.01, 51.5)) as out:
                out.write(heights, 1)

    def run(folder):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            report = batch(tmp_path / folder, tmp_path / f"{folder}_out", interval=50.0, scheduler="serial")
        assert report.ok, report.summary()
        meshes = [read_mesh(tmp_path / f"{folder}_out" / f"{n}.glb") for n in ("w", "e")]
        width = max(m.bounds[1, 0] for m in meshes) - min(m.bounds[0, 0] for m in meshes)
        return [str(w.message) for w in caught if "antimeridian" in str(w.message)], width

    write("given")
    said, width = run("given")
    assert len(said) == 1 and width > 1e6, (said, width)  # a whole parallel apart
    wraps = re.findall(r"\+lon_wrap=(-?[0-9.]+)", said[0])
    assert len(wraps) == 1, said[0]
    assert float(wraps[0]) == (0.0 if west_lon > 180.0 else 180.0), said[0]
    write("wrapped", float(wraps[0]))
    said, width = run("wrapped")
    assert not said and width < 20_000.0, (said, width)  # two tiles of 0.1 degree side by side: some 14 km


def test_the_shared_frame_of_files_in_degrees_rounds_its_size_as_gdalbuildvrt_does(tmp_path):
    """gdalbuildvrt sizes its mosaic as int(0.5 + extent / step), a half cell up; the shared frame rounded it half to
    even, so files whose union is 2.5 mean steps tall (cells of 0.5 and 0.25 degrees) made a mosaic of 2 rows, its
    middle latitude, x spacing and +proj=eqc CRS those of another grid than the .vrt that load_dem reads: the frame
    now has the .vrt's 3 rows, its spacing and CRS."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.io import degree_header, load_dem, shared_degree_frame

    if shutil.which("gdalbuildvrt") is None:
        pytest.skip("gdalbuildvrt not found")
    paths = []
    for name, (x0, y0, step) in {"a": (0.0, 40.0, 0.5), "b": (0.5, 39.3125, 0.25)}.items():  # 0.9375 of latitude
        paths.append(tmp_path / f"{name}.tif")
        with rasterio.open(paths[-1], "w", driver="GTiff", width=1, height=1, count=1, dtype="float32",
                           crs="EPSG:4326", transform=Affine(step, 0.0, x0, 0.0, -step, y0)) as out:
            out.write(np.full((1, 1), 100.0, np.float32), 1)
    subprocess.run(["gdalbuildvrt", "-q", str(tmp_path / "m.vrt"), *map(str, paths)], check=True)
    headers = [degree_header(p) for p in paths]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spacing, crs, _, _ = shared_degree_frame("EPSG:4326", [h[1] for h in headers], [h[2] for h in headers])
        mosaic = load_dem(tmp_path / "m.vrt")
    assert mosaic.heights.shape == (3, 2)
    assert (spacing, crs) == (mosaic.spacing, mosaic.crs)


def test_cli_batch_band_beyond_every_geotiffs_bands_exits_2_once(tmp_path, capsys):
    """``batch FOLDER --band 2`` over one-band GeoTIFFs failed item by item ("band must be between 1 and 1"), a wall
    of identical failures and exit status 1, while --band over .npy files (one band too) and --spacing, --coarsen
    refused by every file are one usage error: said once now, naming the option, exit 2. A folder where some file
    holds the band still lists the others' failures, exit 1."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFFs are written with rasterio")
    from rasterio.transform import Affine

    from stepterrain import cli

    from .conftest import real_dem

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=21, step=1)
    geo = tmp_path / "geo"
    geo.mkdir()
    for k, bands in enumerate((1, 1, 2)):
        with rasterio.open(geo / f"g{k}.tif", "w", driver="GTiff", height=21, width=10, count=bands, dtype="float32",
                           crs="EPSG:32611", transform=Affine(30, 0, 380000 + 300 * k, 0, -30, 3800000)) as dst:
            for b in range(bands):
                dst.write(heights[:, 10 * k:10 * k + 10], b + 1)
    out = tmp_path / "out"
    argv = ["-q", "batch", "--interval", "50", "--scheduler", "serial", "--band", "2", "-o", str(out)]
    assert cli.main([*argv, str(geo / "g0.tif"), str(geo / "g1.tif")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepterrain batch: error: --band 2 is beyond the bands of all 2 inputs (e.g. g0: between "
                          "1 and 1 for ") and err.rstrip().endswith(
        "got --band 2): give a --band every input holds, or leave --band out") and err.count("\n") == 1, err
    assert not list(out.glob("*.glb"))
    assert cli.main([*argv, str(geo)]) == 1  # g2 holds a second band: written, the others' failures listed
    err = capsys.readouterr().err
    assert [p.name for p in out.glob("*.glb")] == ["g2.glb"]
    assert err.count("failed g") == 2 and "band must be between 1 and 1" in err, err


def test_projected_crss_warning_gives_a_gdalwarp_that_a_shell_runs_for_a_crs_without_an_epsg_code():
    """The warning of files in several CRSs ends with the gdalwarp to join them, to the CRS most files are in. One
    without an EPSG code is named by its WKT (quotes, spaces, brackets), which was pasted into the command as it is:
    the shell split it into words and gdalwarp read no CRS. It is quoted now, so the command parses back to it."""
    import shlex

    pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    from stepterrain.batch import _warn_projected_crss

    custom = CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=-117.7 +k=0.9996 +x_0=500000 +y_0=0 +datum=WGS84 +units=m")
    assert custom.to_epsg() is None
    wkt = custom.to_string()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _warn_projected_crss([wkt, wkt, "EPSG:32611"], {})
    (message,) = [str(w.message) for w in caught]
    command = message[message.index("(gdalwarp ") + 1:-1]
    assert shlex.split(command) == ["gdalwarp", "-dstalpha", "-t_srs", wkt, "FILE", "OUT.tif"], command


def _utm_tile(path, heights, crs, west, north):
    """A float32 GeoTIFF of ``heights`` on 30 m cells in ``crs``, its top-left corner at (west, north), no nodata."""
    import rasterio

    rows, cols = heights.shape
    with rasterio.open(path, "w", driver="GTiff", width=cols, height=rows, count=1, dtype="float32", crs=crs,
                       transform=rasterio.Affine(30.0, 0.0, west, 0.0, -30.0, north)) as out:
        out.write(heights.astype(np.float32), 1)
    return path


def _run_gdalwarp(words, folder):
    """Run the gdalwarp command ``words`` (a list) in ``folder`` (skipped without gdal-bin)."""
    if shutil.which("gdalwarp") is None:
        pytest.skip("gdalwarp (gdal-bin) is not installed")
    subprocess.run([*words, "-q"], cwd=folder, check=True, capture_output=True)


def test_the_gdalwarp_the_projected_crss_warning_gives_leaves_no_0_m_corners(tmp_path):
    """The warning of files in several projected CRSs gives the gdalwarp that puts a file in the CRS most are in. Run
    as said, `gdalwarp -t_srs EPSG:32611 FILE OUT.tif`, the corners of the grid in EPSG:32611 outside the file's
    (rotated some 5 degrees, from the next UTM zone) were filled with 0 (the file has no nodata value) and read back
    as heights of 0 m, cliffs to sea level round a mountain tile, without a word. It says -dstalpha now (as
    load_dem's own gdalwarp hints do): those corners are missing, and every height read is one of the file's."""
    import shlex

    pytest.importorskip("rasterio")
    from stepterrain.batch import _warn_projected_crss
    from stepterrain.io import load_dem

    heights = load_dem(shared_file("big_tujunga_srtm_30m_utm11n.npz")).heights[:60, :80]
    _utm_tile(tmp_path / "east.tif", heights, "EPSG:32612", 200000.0, 3800000.0)  # the west of zone 12
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _warn_projected_crss(["EPSG:32611", "EPSG:32611", "EPSG:32612"], {})
    (message,) = [str(w.message) for w in caught]
    words = shlex.split(message[message.index("(gdalwarp ") + 1:-1])
    _run_gdalwarp([{"FILE": "east.tif"}.get(w, w) for w in words], tmp_path)
    warped = load_dem(tmp_path / "OUT.tif")
    assert "32611" in warped.crs or "zone 11N" in warped.crs, warped.crs
    assert warped.has_nodata and np.nanmin(warped.heights) >= np.nanmin(heights) - 1.0  # no 0 m corner


def test_the_gdalwarp_of_files_in_degrees_into_one_raster_leaves_no_0_m_cells_between_them(tmp_path):
    """The warning of files in degrees each in a frame of its own gives the gdalwarp that warps them into one
    projected raster. Run as said, the cells of that raster that no file covers (round the files, rotated by the
    projection, and in a gap between two) were filled with 0 and read back as heights of 0 m. It says -dstalpha
    now: they are missing."""
    import shlex

    rasterio = pytest.importorskip("rasterio")
    from stepterrain.io import load_dem

    heights = load_dem(shared_file("big_tujunga_srtm_30m_utm11n.npz")).heights[:40, :40]
    for i, west in enumerate((-117.9, -117.85)):  # 0.01 degrees apart: a gap between them
        with rasterio.open(tmp_path / f"t{i}.tif", "w", driver="GTiff", width=40, height=40, count=1,
                           dtype="float32", crs="EPSG:4326",
                           transform=rasterio.Affine(0.001, 0.0, west, 0.0, -0.001, 34.3)) as out:
            out.write(heights.astype(np.float32), 1)
        np.savez(tmp_path / f"t{i}.npz", elevation=heights, transform=np.array([west, 0.001, 0.0, 34.3, 0.0, -0.001]),
                 crs="EPSG:4326")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch([tmp_path / "t0.npz", tmp_path / "t1.npz"], tmp_path / "out", interval=100.0,
                       scheduler="serial")
    assert report.ok, report.summary()
    (message,) = [str(w.message) for w in caught if "FILES dem.tif" in str(w.message)]
    command = re.search(r"\((gdalwarp [^;)]*)", message).group(1)
    named = {"EPSG:...": "EPSG:32611", "FILES": ["t0.tif", "t1.tif"]}
    words = [v for w in shlex.split(command) for v in np.atleast_1d(named.get(w, w)).tolist()]
    _run_gdalwarp(words, tmp_path)
    warped = load_dem(tmp_path / "dem.tif")
    assert warped.has_nodata and np.nanmin(warped.heights) >= np.nanmin(heights) - 1.0  # no 0 m cell


@pytest.mark.parametrize("on_the_way", [False, True])
def test_an_output_dir_that_is_a_dangling_symbolic_link_is_made_where_the_link_leads(tmp_path, on_the_way):
    """An output_dir that is a dangling symbolic link to a folder (out -> new/tiles), or lies below one
    (out/tiles, out -> new), was refused "cannot create the output folder 'out': File exists" (mkdir of the link's
    own name); export.atomic_path writes a file through such a link. The folder is made where the link leads."""
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    link = tmp_path / "out"
    link.symlink_to(tmp_path / "new" / ("" if on_the_way else "tiles"))
    output_dir = link / "tiles" if on_the_way else link
    report = batch(z, output_dir, tile_size=4, interval=2.0, scheduler="serial")
    assert report.ok and len(report.done) == 4
    assert link.is_symlink() and (tmp_path / "new" / "tiles").is_dir()
    assert sorted(p.name for p in (tmp_path / "new" / "tiles").glob("*.glb")) == sorted(
        p.name for p in output_dir.glob("*.glb")) and len(list(output_dir.glob("*.glb"))) == 4
    assert len(read_mesh(output_dir / "tile_r0_c0.glb").faces) > 0


def test_a_failed_run_into_a_dangling_link_takes_away_the_folders_it_made_there(tmp_path):
    """The folders made where a dangling link leads are this run's: a run that fails before writing anything (an
    unreachable scheduler) takes them away again, leaving the link dangling as it was."""
    import socket

    pytest.importorskip("distributed", reason="needs dask.distributed")
    from stepterrain.errors import SchedulerError

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    link = tmp_path / "out"
    link.symlink_to(tmp_path / "new" / "tiles")
    with pytest.raises(SchedulerError, match="cannot reach the dask scheduler"):
        batch(np.zeros((5, 5)), link, tile_size=2, interval=1.0, scheduler=f"tcp://127.0.0.1:{port}",
              connect_timeout=1.0)
    assert link.is_symlink() and not (tmp_path / "new").exists()


@pytest.mark.parametrize("fmt", [".ply", ".glb"])
@pytest.mark.parametrize("solid", [False, True])
def test_tiles_of_a_raster_with_an_inexact_spacing_share_their_border_vertices_bit_for_bit(tmp_path, fmt, solid):
    # Found by reading back the tiles of the Front Range DEM (3 arc-seconds as local metres: dx = 70.827 m): a node
    # sat at its tile's origin plus float32(j) * float32(dx), so a tile's last column lay up to half a float32 step
    # of the tile's extent off its right neighbour's first column (its origin, x0 + c dx): 0.27 mm in .ply, a float32
    # step in .glb, on every seam; a spacing of 30 m (the embedded DEM) is exact in float32 and hid it
    from stepterrain.io import load_dem

    terrain = load_dem(shared_file("front_range_srtmgl3_3arcsec.npz"))
    (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
    assert dy < 0 < dx
    assert float(np.float32(dx)) != dx  # the point: a spacing float32 does not hold
    rows, cols = 200, 200  # 16 tiles, their seams up to 13 km out
    crop = (x0, x0 + (cols - 1) * dx, y0 + (rows - 1) * dy, y0)
    # heights are whole metres: thresholds at x.8 hold none (a height on one makes a zero-width terrace, which a
    # tile stepped alone draws only on its own side)
    report = batch(terrain, tmp_path, tile_size=(60, 70), crop=crop, interval=25.0, base=0.3, solid=solid,
                   format=fmt, scheduler="serial")  # fmt: skip
    assert report.ok and len(report.done) == 4 * 3
    meshes = {r.key: np.asarray(read_mesh(r.path).vertices, np.float64) for r in report.done}  # world coordinates
    for key, vertices in meshes.items():
        r, c = (int(n) for n in re.fullmatch(r"tile_r(\d)_c(\d)", key).groups())
        # a tile's last column (x grows with it) and last row (dy < 0: y falls) against its neighbour's first
        for axis, neighbour, side in ((0, f"tile_r{r}_c{c + 1}", 1), (1, f"tile_r{r + 1}_c{c}", -1)):
            if neighbour not in meshes:
                continue
            other = meshes[neighbour]
            line, theirs_line = side * (side * vertices[:, axis]).max(), side * (side * other[:, axis]).min()
            assert line == theirs_line, f"{key} / {neighbour}: seam at {line!r} and {theirs_line!r}"
            mine, theirs = vertices[vertices[:, axis] == line], other[other[:, axis] == line]
            assert set(map(tuple, mine)) == set(map(tuple, theirs)), (key, neighbour)


def test_geotiff_tiles_in_degrees_share_their_border_vertices_bit_for_bit(tmp_path):
    fmt = ".ply"  # float64 as written (a .glb's float32 happened to round both seams alike here)
    # Found by cutting the Front Range GeoTIFF (3 arc-seconds, EPSG:4326) into three tiles sharing their border
    # nodes, as SRTM tiles do, and reading back a folder run's meshes: the files are placed in the local metres of
    # their mosaic (dx = 70.63 m, a file's node (0, 0) at dx * k), but a file's last column lay at its origin plus
    # float32(j) * float32(dx), 0.5 mm off its east neighbour's first column (and its last row off its south
    # neighbour's first row): no seam shared a vertex
    folder = tmp_path / "tiles"
    _write_degree_tiles(folder)
    # heights are whole metres: thresholds at x.8 hold none (a height on one draws a zero-width terrace on one side)
    report = batch(folder, tmp_path / "out", interval=20.0, base=0.3, format=fmt, scheduler="serial")
    assert report.ok and len(report.done) == 3
    a, b, c = (np.asarray(read_mesh(tmp_path / "out" / f"{k}{fmt}").vertices, np.float64) for k in "abc")
    for (first, second), axis, side in (((a, b), 0, 1), ((a, c), 1, -1)):  # east: x grows; south: y falls
        line, other_line = side * (side * first[:, axis]).max(), side * (side * second[:, axis]).min()
        assert line == other_line, f"seam at {line!r} and {other_line!r}"
        mine, theirs = first[first[:, axis] == line], second[second[:, axis] == line]
        assert len(mine) >= min(first.shape[0], 151 if axis == 0 else 181)  # every border node, and wall crossings
        assert set(map(tuple, mine)) == set(map(tuple, theirs))


def _write_degree_tiles(folder: Path) -> None:
    """Three GeoTIFFs cut from the Front Range one (3 arc-seconds, EPSG:4326), sharing their border nodes as SRTM
    tiles do: b east of a, c south of it."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF tiles are written with rasterio")
    from rasterio.transform import Affine
    from rasterio.windows import Window

    folder.mkdir()
    with rasterio.open(shared_file("front_range_srtmgl3_3arcsec.tif")) as ds:
        assert ds.crs.is_geographic
        profile = {k: v for k, v in ds.profile.items() if k not in ("blockxsize", "blockysize", "tiled")}
        for name, (c0, r0) in {"a": (100, 100), "b": (280, 100), "c": (100, 250)}.items():
            g = ds.transform  # the window's own (rasterio's window_transform warns of its Affine `*`)
            moved = Affine(g.a, g.b, g.c + c0 * g.a, g.d, g.e, g.f + r0 * g.e)
            with rasterio.open(folder / f"{name}.tif", "w", **{**profile, "width": 181, "height": 151,
                                                                  "transform": moved}) as f:
                f.write(ds.read(1, window=Window(c0, r0, 181, 151)), 1)


@pytest.mark.parametrize("case", ["inexact tiles", "exact tiles", "files in degrees"])
def test_a_run_resumed_from_before_the_seam_fix_redoes_exactly_the_items_whose_seams_moved(tmp_path, monkeypatch,
                                                                                           case):
    # Tiles (and files in degrees) now put their last node column and row on their neighbour's first; their
    # fingerprints did not change with that, so resuming a run made before it at an inexact spacing (70.827 m) skipped
    # its old tiles, unwelded, beside newly written neighbours: a mix that did not weld. Those items' fingerprints now
    # differ, the others' (an exact spacing: 30 m) do not, so a big finished run is not redone.
    import stepterrain as st
    import stepterrain.batch as batch_mod
    from stepterrain.io import load_dem

    fmt = ".ply"  # float64 as written: a moved seam changes the file
    if case == "files in degrees":
        _write_degree_tiles(tmp_path / "tiles")
        source, kwargs = tmp_path / "tiles", {"interval": 20.0, "base": 0.3}
    elif case == "inexact tiles":
        terrain = load_dem(shared_file("front_range_srtmgl3_3arcsec.npz"))
        (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
        assert float(np.float32(dx)) != dx
        crop = (x0, x0 + 199 * dx, y0 + 199 * dy, y0)
        source, kwargs = terrain, {"tile_size": (60, 70), "crop": crop, "interval": 25.0, "base": 0.3}
    else:
        source = st.sample_dem()
        assert all(float(np.float32(d)) == d for d in source.spacing)  # 30 m: float32 holds it
        kwargs = {"tile_size": 64, "interval": 50.0}
    kwargs.update(format=fmt, scheduler="serial")

    def vertices(folder: Path) -> dict[str, np.ndarray]:
        return {p.stem: np.asarray(read_mesh(p).vertices, np.float64) for p in sorted(folder.glob(f"*{fmt}"))}

    # the previous version's run: no seam moved, and the fingerprint as it defined it (no mark for moved seams)
    with monkeypatch.context() as m:
        m.setattr(batch_mod, "_last_nodes_at", lambda mesh, terrain, exact: mesh)
        m.setattr(batch_mod, "_seams_moved", lambda item, source, options: False)
        old = batch(source, tmp_path / "out", **kwargs)
    assert old.ok and old.done and not old.skipped
    before = vertices(tmp_path / "out")
    fresh = batch(source, tmp_path / "fresh", **kwargs)  # this version's outputs, written afresh
    after = vertices(tmp_path / "fresh")
    changed = {key for key in after if not np.array_equal(after[key], before[key])}
    if case == "exact tiles":
        assert not changed
    else:
        assert changed  # the fix moves something here

    resumed = batch(source, tmp_path / "out", **kwargs)
    assert resumed.ok
    assert {r.key for r in resumed.done} == changed  # exactly the items whose output the fix changes are redone
    assert {r.key for r in resumed.skipped} == {r.key for r in fresh.done} - changed
    now = vertices(tmp_path / "out")
    assert now.keys() == after.keys() and all(np.array_equal(now[k], after[k]) for k in now)  # as a fresh run's


def test_a_series_shared_levels_and_floor_are_read_frame_by_frame_not_over_the_whole_series(tmp_path):
    """batch's shared levels of a (T, H, W) series file (no known range: a series file's source has none) took
    used_height_range of the whole series, and a solid's shared floor lowest_used_height of it: the series' finite
    mask and its triangles' masks, 1.25 times a float32 series' memory again (40 MiB for a 32 x 512 x 512 one),
    before the first frame, as stepped_series did for a stack. Both go frame by frame now (used_height_range and
    lowest_used_height read a stack so), with the levels and floor of the whole series at once in plain NumPy
    (tests/reference.py)."""
    import tracemalloc

    from stepterrain.batch import _floor_under, _levels_and_range, _shared_levels, _Source, plan_items
    from stepterrain.stepped import isovalues

    from .reference import lowest_used_height_reference, used_height_range_reference

    rng = np.random.default_rng(11)
    series = rng.normal(100.0, 20.0, (16, 128, 128)).astype(np.float32)  # 1 MiB
    series[2, 30:60, 40:90] = np.nan
    series[5][np.add.outer(np.arange(128), np.arange(128)) % 3 != 0] = np.nan  # no triangle in that frame: its
    series[5, 0, 0] = -500.0  # finite nodes are on none; one far below the rest moves neither levels nor floor
    np.save(tmp_path / "series.npy", series)
    _, src = plan_items(tmp_path / "series.npy")
    assert src.height_range is None

    def peak_of(call):
        tracemalloc.start()
        try:
            return call(), tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    levels, peak = peak_of(lambda: _shared_levels(src, 10.0, None, 0.0))
    assert peak < series.nbytes / 4, f"{peak:,} bytes for the levels of a series of {series.nbytes:,}"
    assert levels == tuple(isovalues(used_height_range_reference(series), interval=10.0).tolist())
    assert -500.0 < levels[0]
    floor, peak = peak_of(lambda: _floor_under(_levels_and_range(src, 10.0, None, 0.0)[3], levels, 0.5, 10.0))
    assert peak < series.nbytes / 4, f"{peak:,} bytes for the floor of a series of {series.nbytes:,}"
    assert floor == _floor_under(lowest_used_height_reference(series), levels, 0.5, 10.0)
    # small series of every kind of frame against the whole-series computation: no nodata, nodata, no triangle,
    # nodata only, rows of one node
    for seed in range(40):
        rng = np.random.default_rng(seed)
        shape = (int(rng.integers(1, 4)), int(rng.integers(1, 5)), int(rng.integers(1, 5)))
        heights = rng.normal(0.0, 10.0, shape).astype(np.float32)
        heights[rng.random(shape) < rng.choice([0.0, 0.3, 0.7, 1.0])] = np.nan
        if not np.isfinite(heights).any():
            continue
        src = _Source(heights, (1.0, 1.0), (0.0, 0.0), None, "series")
        assert _shared_levels(src, 1.0, None, 0.0) == tuple(isovalues(used_height_range_reference(heights),
                                                                      interval=1.0).tolist()), seed
        lowest = _levels_and_range(src, 1.0, None, 0.0)[3]
        assert _floor_under(lowest, (-50.0, 50.0), 1.0, 1.0) == _floor_under(lowest_used_height_reference(heights),
                                                                            (-50.0, 50.0), 1.0, 1.0), seed


@pytest.mark.parametrize(("given", "recorded"), [("nan,315", [315.0]), ("nan", None), (None, None)])
def test_cli_batch_of_the_embedded_dem_records_its_finite_nodata(tmp_path, capsys, given, recorded):
    """``stepterrain batch`` of the embedded DEM records the --nodata it was read with in every tile's metadata, the
    finite values only (JSON has no NaN: ``--nodata nan`` recorded ``[null]``, which reads as "no nodata value"), and
    no ``nodata`` key without a finite one (a file source's batch records itself)."""
    from .conftest import run_cli

    argv = ["batch", "--coarsen", "16", "--tile", "64", "--interval", "200", "--scheduler", "serial", "--format",
            ".ply", "-o", tmp_path / "out"]
    code, _, err = run_cli(capsys, *argv, *(["--nodata", given] if given else []))
    assert code == 0, err
    paths = sorted((tmp_path / "out").glob("*.ply"))
    assert paths and [read_mesh(p).metadata.get("nodata") for p in paths] == [recorded] * len(paths)


def _blend_below_its_float64_value() -> tuple[float, float]:
    """A lowest height h (isovalue 0 of the levels 0, 10, 20, 30) whose float32 blend at γ = 0.3, as the kernel
    computes it, lies below the blend's float64 value by more than that value's own float32 rounding: (h, vertex)."""
    g = np.float32(0.3)
    for h in np.linspace(0.1, 4.9, 20001, dtype=np.float32):
        vertex = (np.float32(1.0) - g) * h  # + g * 0.0 (its isovalue)
        exact = 0.7 * float(h)
        if float(vertex) < exact and np.float32(exact) > vertex:
            return float(h), float(vertex)
    raise AssertionError("no such height")


def test_a_floor_on_the_float32_blend_of_the_lowest_point_is_refused_before_any_work(tmp_path):
    # The check up front compared the floor with (1 - γ) h + γ α in float64, but the kernel blends in float32 and
    # the lowest vertex came out one float32 step below that: a floor on that vertex passed the check, then
    # close_solid refused it in the one tile (frame, file) holding the lowest point, the others written with it
    # (3 written, 1 failed), where a floor every item cannot take is refused once, before any work
    import stepterrain as st
    from stepterrain.errors import InvalidInputError

    h, vertex = _blend_below_its_float64_value()
    levels = [0.0, 10.0, 20.0, 30.0]
    z = np.linspace(5.0, 30.0, 81, dtype=np.float32).reshape(9, 9)
    z[1, 1] = h
    surface = st.stepped(st.Terrain.from_heights(z), levels=levels, gamma=0.3)
    assert float(surface.vertices[:, 2].min()) == vertex  # the kernel's float32 blend
    with pytest.raises(InvalidInputError, match="floor"):  # the library itself refuses that floor
        st.stepped(st.Terrain.from_heights(z), levels=levels, gamma=0.3, solid=True, floor=vertex)
    folder = tmp_path / "files"
    folder.mkdir()
    np.save(folder / "a.npy", z + 1.0)
    np.save(folder / "b.npy", z)
    for source, tiles, n in ((z, 4, 4), (np.stack([z + 1.0, z]), None, 2), (folder, None, 2)):
        with pytest.raises(InvalidInputError, match=re.escape("floor (the CLI's --floor) must lie below the lowest "
                                                              f"point {vertex:.9g}")):
            batch(source, tmp_path / "out", tile_size=tiles, levels=levels, gamma=0.3, solid=True, floor=vertex,
                  scheduler="serial")
        assert not (tmp_path / "out").exists()
        below = float(np.nextafter(np.float32(vertex), np.float32(-np.inf)))
        report = batch(source, tmp_path / f"ok{n}{tiles}", tile_size=tiles, levels=levels, gamma=0.3, solid=True,
                       floor=below, format=".ply", scheduler="serial")
        assert report.ok and len(report.done) == n, report.summary()
        assert min(float(read_mesh(r.path).vertices[:, 2].min()) for r in report.done) == below


def test_coarsened_empty_item_is_found_by_the_coarsening_without_a_pass_before_it(monkeypatch):
    """batch._coarsened(empty=True) (a file item read with --coarsen, a frame of a series) scanned a grid with nodata
    for a finite node in its whole blocks (np.isfinite of the grid) before coarsening it, which finds the same in its
    blocks' means: that pass is gone (Terrain._coarsen(empty_ok=True) returns the grid of NaN means). The results
    are those of before: a grid of nodata for blocks of nodata only (land beyond the last whole block), the block
    means otherwise, and without ``empty`` the refusal of a result of nodata only, named ``coarsen=``."""
    from stepterrain import batch as batch_module
    from stepterrain.errors import InvalidInputError
    from stepterrain.terrain import Terrain

    heights = np.full((7, 9), np.nan, np.float32)
    heights[6, :], heights[:, 8] = 5.0, 3.0  # only beyond the 3 x 4 whole blocks of 2 x 2 nodes
    coast = Terrain.from_heights(heights, spacing=(10.0, 10.0), origin=(100.0, 200.0))
    land = heights.copy()
    land[1:4, 2:5] = np.arange(9, dtype=np.float32).reshape(3, 3)
    partial = Terrain.from_heights(land, spacing=(10.0, 10.0), origin=(100.0, 200.0))
    passes: list[tuple[int, ...]] = []

    class Counted:  # batch's numpy, its np.isfinite counted
        def __getattr__(self, name):
            return getattr(np, name)

        @staticmethod
        def isfinite(a, *args, **kwargs):
            passes.append(np.shape(a))
            return np.isfinite(a, *args, **kwargs)

    monkeypatch.setattr(batch_module, "np", Counted())
    empty = batch_module._coarsened(coast, 2, empty=True)
    means = batch_module._coarsened(partial, 2, empty=True)
    with pytest.raises(InvalidInputError, match=r"^coarsen=2: factor 2 \(mean\) leaves only nodata"):
        batch_module._coarsened(coast, 2)
    with pytest.raises(InvalidInputError, match=r"^coarsen=5: factor 5 leaves 1 x 1 nodes"):
        batch_module._coarsened(coast, 5, empty=True)
    assert passes == []
    assert empty.heights.shape == (3, 4) and np.isnan(empty.heights).all()
    assert (empty.spacing, empty.origin) == ((20.0, 20.0), (105.0, 205.0))
    block = land[:6, :8].reshape(3, 2, 4, 2).astype(np.float64)
    with np.errstate(invalid="ignore"):
        reference = (np.nansum(block, axis=(1, 3)) / np.isfinite(block).sum(axis=(1, 3))).astype(np.float32)
    assert np.array_equal(means.heights, reference, equal_nan=True) and np.isfinite(means.heights).any()
    assert np.array_equal(means.heights, partial.coarsen(2).heights, equal_nan=True)


@pytest.mark.parametrize("floor", [None, -1000.0, 1e9])
def test_a_solid_batch_reads_its_sources_heights_once_for_levels_and_floor(tmp_path, monkeypatch, floor):
    """A solid batch of a raster (or series) with nodata found its levels' height range (used_height_range: a mask of
    the nodes the triangles use) and then the floor's lowest used height (lowest_used_height: the same masks again)
    in two passes over the whole source: one pass gives both now. Floors and refusals as before: the default floor
    one interval under the lowest vertex (NumPy reference), a given one below it taken, one above it refused before
    any item runs."""
    from stepterrain import terrain as terrain_module
    from stepterrain.errors import InvalidInputError
    from stepterrain.stepped import isovalues

    from .reference import lowest_used_height_reference, used_height_range_reference

    rng = np.random.default_rng(5)
    heights = (rng.random((40, 50)) * 300.0 + 100.0).astype(np.float32)
    heights[:7, :9] = np.nan
    heights[20, 30] = np.nan
    heights[39, 0] = -400.0  # beside nodata on every side a triangle could take: on no triangle
    heights[38, 0] = heights[38, 1] = heights[39, 1] = np.nan
    masks: list[tuple[int, ...]] = []
    real = terrain_module.used_nodes

    def spy(finite, *args, **kwargs):
        masks.append(np.shape(finite))
        return real(finite, *args, **kwargs)

    monkeypatch.setattr(terrain_module, "used_nodes", spy)
    out = tmp_path / "out"
    if floor == 1e9:
        with pytest.raises(InvalidInputError, match=r"^floor \(the CLI's --floor\) must lie below the lowest point "):
            batch(heights, out, tile_size=16, interval=50.0, solid=True, floor=floor, format=".ply",
                  scheduler="serial")
        assert masks.count(heights.shape) == 1 and not list(out.glob("*.ply"))
        return
    report = batch(heights, out, tile_size=16, interval=50.0, solid=True, floor=floor, format=".ply",
                   scheduler="serial")
    assert report.ok, report.summary()
    assert masks.count(heights.shape) == 1, masks
    lo = lowest_used_height_reference(heights)
    values = isovalues(used_height_range_reference(heights), interval=50.0)
    assert lo > -400.0
    expected = floor if floor is not None else min(float(values[0]), float(values[np.searchsorted(
        (values[:-1].astype(np.float64) + values[1:]) / 2, np.float32(lo), side="right")])) - 50.0
    for path in sorted(out.glob("*.ply")):
        mesh = read_mesh(path)
        assert float(np.asarray(mesh.vertices)[:, 2].min()) == pytest.approx(expected, abs=1e-3), path.name


def test_overview_z_scale_beyond_what_the_render_frames_is_refused_before_any_item(tmp_path):
    """``batch --png --z-scale 1e308`` stepped and wrote every mesh, then the overview's render refused the z-scale
    (its z-scaled box beyond ±1e150, where the camera's squared distances overflow float64). batch() takes the
    overview's ``overview_z_scale`` and refuses it with the plan's heights, before anything is written: the meshes a
    render shows span at least their nodes' stepped heights (a solid's floor under them; a contact sheet's cells
    each alone), so what is refused the render would refuse; the largest z-scale taken keeps the written meshes'
    z-scaled half-height within the render's bound (NumPy on the meshes read back)."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.render import _MAX_REACH

    heights = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)  # 0 to 16, levels 0, 2, ..., 16
    kw = dict(tile_size=4, interval=2.0, scheduler="serial", format=".ply", overview_size=(64, 64))
    out = tmp_path / "out"
    for z, solid, tall in ((1e308, False, 16.0), (2e150 / 17, True, 18.0)):  # a solid: its floor 2 under level 0
        with pytest.raises(InvalidInputError, match=rf"^overview_z_scale must keep the overview's meshes \(at least "
                                                    rf"{tall:g} tall\) within ±1e\+150 of their centre .*; got "):
            batch(heights, out, solid=solid, overview_z_scale=z, **kw)
        assert not out.exists()
    with pytest.raises(InvalidInputError, match=r"^overview_z_scale must be a positive finite number; got inf"):
        batch(heights, out, overview_z_scale=float("inf"), **kw)
    with pytest.raises(InvalidInputError, match=r"^overview_z_scale applies only with overview_size .*; got "
                                                r"overview_z_scale=3.0 without it"):
        batch(heights, out, overview_z_scale=3.0, **{**kw, "overview_size": None})
    assert not out.exists()
    # taken below the bound: the written meshes' z-scaled half-height is within the render's
    report = batch(heights, out, overview_z_scale=2e150 / 17, **kw)
    assert report.ok and len(report.done) == 4
    z = np.concatenate([np.asarray(read_mesh(p).vertices)[:, 2] for p in sorted(out.glob("*.ply"))])
    assert (z.max() - z.min()) == 16.0 and (z.max() - z.min()) / 2 * (2e150 / 17) <= _MAX_REACH
    # a series: each frame in its own cell, the tallest frame's height counts (not the stack's range)
    series = np.stack([heights, heights + 100.0, heights * 10.0])
    with pytest.raises(InvalidInputError, match=r"\(at least 160 tall\)"):
        batch(series, tmp_path / "series", interval=2.0, scheduler="serial", overview_size=(64, 64),
              overview_z_scale=2e150 / 150)
    assert not (tmp_path / "series").exists()


@needs_render
def test_cli_batch_png_z_scale_beyond_the_render_is_refused_writing_nothing(tmp_path, capsys):
    """``stepterrain batch --png OUT.png --z-scale 1e308`` wrote every mesh, then refused the overview's render; the
    z-scale is now checked with the plan, before any item: exit 2 naming --z-scale, no output folder, no picture."""
    from stepterrain import cli

    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    out, png = tmp_path / "out", tmp_path / "overview.png"
    assert cli.main(["-q", "batch", str(dem), "--tile", "4", "--interval", "2", "--scheduler", "serial", "-o",
                     str(out), "--png", str(png), "--z-scale", "1e308"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepterrain batch: error: --z-scale must keep the overview's meshes (at least 16 tall) "
                          "within ±1e+150 of their centre"), err
    assert err.rstrip().endswith("; got 1e+308"), err
    assert not out.exists() and not png.exists()
