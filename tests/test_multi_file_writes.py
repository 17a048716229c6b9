"""Outputs of several files (a textured OBJ's .obj, .mtl and texture images; an image and GDAL's side files): all
new or all old after a failure part-way, never a mix."""

from __future__ import annotations

import errno
import os
import signal
import threading
import warnings

import numpy as np
import pytest
import trimesh
from PIL import Image

from stepterrain.errors import DataFileError
from stepterrain.export import save_image, save_mesh


def _textured(color: tuple[int, int, int], alpha: bool = False) -> trimesh.Trimesh:
    mesh = trimesh.creation.box()
    image = Image.new("RGBA", (2, 2), (*color, 100)) if alpha else Image.new("RGB", (2, 2), color)
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)), image=image)
    return mesh


def _files(folder) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir()) if not path.is_symlink()}


def _failing_replace(monkeypatch, n: int) -> list[tuple[str, str]]:
    """os.replace failing (EIO) on its ``n``-th call (1-based), the calls before and after going through."""
    real = os.replace
    calls: list[tuple[str, str]] = []

    def replace(src, dst, *args, **kwargs):
        calls.append((os.fspath(src), os.fspath(dst)))
        if len(calls) == n:
            raise OSError(errno.EIO, "Input/output error")
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    return calls


def _renames_of_a_textured_obj(tmp_path, monkeypatch) -> int:
    """How many files a textured OBJ (with an alpha map: .obj, .mtl, texture) renames into place."""
    probe = tmp_path / "probe"
    probe.mkdir()
    calls = _failing_replace(monkeypatch, 0)
    save_mesh(_textured((1, 2, 3), alpha=True), probe / "t.obj")
    monkeypatch.undo()
    count = sum(1 for _, dst in calls if not os.path.basename(dst).startswith("."))
    for path in probe.iterdir():
        path.unlink()
    probe.rmdir()
    return count


@pytest.mark.parametrize("existing", [True, False], ids=["replacing", "new"])
def test_a_textured_obj_whose_nth_rename_fails_leaves_all_old_files(tmp_path, monkeypatch, existing):
    # the .obj, .mtl and texture were renamed into place one at a time: a failure of the second or third rename left
    # the new texture (and .mtl) beside the old .obj, or new side files beside no .obj at all
    count = _renames_of_a_textured_obj(tmp_path, monkeypatch)
    assert count == 3
    for n in range(1, count + 1):
        folder = tmp_path / f"n{n}"
        folder.mkdir()
        if existing:
            save_mesh(_textured((200, 10, 10), alpha=True), folder / "t.obj")
        old = _files(folder)
        calls = _failing_replace(monkeypatch, n)
        with pytest.raises(DataFileError, match="Input/output error"):
            save_mesh(_textured((10, 200, 10), alpha=True), folder / "t.obj")
        monkeypatch.undo()
        assert len(calls) >= n
        assert _files(folder) == old, f"rename {n} of {count} failed"  # no temporary left either
    clean = tmp_path / "clean"  # written without a failure: the same bytes as the last folder's would have been
    save_mesh(_textured((10, 200, 10), alpha=True), clean / "t.obj")
    save_mesh(_textured((10, 200, 10), alpha=True), folder / "t.obj")
    assert _files(folder) == _files(clean)


def test_a_textured_obj_rolled_back_keeps_the_old_files_own_inodes_and_modes(tmp_path, monkeypatch):
    folder = tmp_path
    save_mesh(_textured((200, 10, 10)), folder / "t.obj")
    for path in folder.iterdir():
        path.chmod(0o640)
    before = {path.name: (os.stat(path).st_ino, os.stat(path).st_mode) for path in folder.iterdir()}
    _failing_replace(monkeypatch, 3)  # the .obj's own rename, after its side files'
    with pytest.raises(DataFileError):
        save_mesh(_textured((10, 200, 10)), folder / "t.obj")
    monkeypatch.undo()
    assert {path.name: (os.stat(path).st_ino, os.stat(path).st_mode) for path in folder.iterdir()} == before


def test_a_textured_obj_written_whole_is_as_without_the_rollback(tmp_path):
    # the success path: each file once, no backup left behind, the bytes a second write repeats
    first = save_mesh(_textured((10, 200, 10), alpha=True), tmp_path / "a" / "t.obj")
    save_mesh(_textured((200, 10, 10), alpha=True), tmp_path / "b" / "t.obj")
    save_mesh(_textured((10, 200, 10), alpha=True), tmp_path / "b" / "t.obj")
    assert _files(first.parent) == _files(tmp_path / "b")
    assert sorted(_files(first.parent)) == ["t.mtl", "t.obj", "t_material_0.png"]


def test_a_textured_obj_interrupted_part_way_is_rolled_back_too(tmp_path, monkeypatch):
    save_mesh(_textured((200, 10, 10)), tmp_path / "t.obj")
    old = _files(tmp_path)
    real = os.replace
    calls = []

    def interrupted(src, dst):
        calls.append(dst)
        if len(calls) == 2:
            raise KeyboardInterrupt
        real(src, dst)

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        save_mesh(_textured((10, 200, 10)), tmp_path / "t.obj")
    monkeypatch.undo()
    assert _files(tmp_path) == old


def test_without_hard_links_the_old_files_are_kept_as_copies(tmp_path, monkeypatch):
    # a file system without hard links (FAT, some network shares): the old files are copied to be put back
    save_mesh(_textured((200, 10, 10)), tmp_path / "t.obj")
    old = _files(tmp_path)

    def no_links(src, dst, **kwargs):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    _failing_replace(monkeypatch, 3)
    with pytest.raises(DataFileError, match="Input/output error"):
        save_mesh(_textured((10, 200, 10)), tmp_path / "t.obj")
    monkeypatch.undo()
    assert _files(tmp_path) == old
    monkeypatch.setattr(os, "link", no_links)
    save_mesh(_textured((10, 200, 10)), tmp_path / "t.obj")  # and without a failure: no copy left
    assert sorted(_files(tmp_path)) == ["t.mtl", "t.obj", "t_material_0.png"] and _files(tmp_path) != old


def test_a_file_that_cannot_be_put_back_is_named_with_where_its_old_content_is(tmp_path, monkeypatch):
    save_mesh(_textured((200, 10, 10)), tmp_path / "t.obj")
    old_texture = (tmp_path / "t_material_0.png").read_bytes()
    real = os.replace
    calls = []

    def failing(src, dst):
        calls.append(dst)
        if len(calls) >= 2:  # the .mtl's rename, and then putting back the texture
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(DataFileError, match=r"t\.mtl': Input/output error; and then '.*t_material_0\.png' could not "
                                            r"be put back \(Input/output error; its old content is in '.*\.tmp'\)"):
        save_mesh(_textured((10, 200, 10)), tmp_path / "t.obj")
    monkeypatch.undo()
    kept = [path for path in tmp_path.iterdir() if path.name.startswith(".t_material_0.png.")]
    assert len(kept) == 1 and kept[0].read_bytes() == old_texture  # never lost


_OB_TRAN = "+proj=ob_tran +o_proj=longlat +o_lon_p=0 +o_lat_p=30 +lon_0=10 +datum=WGS84 +no_defs"
_STALE_AUX = "<PAMDataset><SRS>EPSG:4326</SRS><GeoTransform>100, 1, 0, 50, 0, -1</GeoTransform></PAMDataset>"


def _placement(path) -> tuple[object, tuple[float, ...]]:
    rasterio = pytest.importorskip("rasterio")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NotGeoreferencedWarning
        with rasterio.open(path) as dataset:
            return dataset.crs, tuple(dataset.transform)[:6]


@pytest.mark.parametrize("name", ["l.png", "l.tif"])
def test_an_image_written_through_a_link_drops_the_stale_side_file_beside_the_link(tmp_path, name):
    # GDAL reads <name>.aux.xml beside the name it opens, the link's: save_image removed only the one beside the
    # link's target, and the new image read through the link had the old one's CRS and placement
    pytest.importorskip("rasterio")
    target = tmp_path / f"target{name[1:]}"
    save_image(np.zeros((4, 6, 3), np.uint8), target)
    (tmp_path / name).symlink_to(target.name)
    (tmp_path / f"{name}.aux.xml").write_text(_STALE_AUX)
    assert _placement(tmp_path / name)[0] is not None  # (GDAL reads it)
    save_image(np.ones((4, 6, 3), np.uint8), tmp_path / name)
    assert _placement(tmp_path / name) == _placement(target) == (None, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, target.name])


def test_a_geotiff_written_through_a_link_drops_the_stale_side_file_beside_the_link(tmp_path):
    # with a CRS GeoTIFF's keys cannot hold, the new side file goes beside the file the link points to, and the stale
    # one beside the link (which GDAL reads through the link) is removed, not left to give the image its CRS
    rasterio = pytest.importorskip("rasterio")
    crs = rasterio.crs.CRS.from_user_input(_OB_TRAN)
    target = tmp_path / "data" / "target.tif"
    target.parent.mkdir()
    save_image(np.zeros((4, 6, 3), np.uint8), target)
    (tmp_path / "l.tif").symlink_to(target)
    (tmp_path / "l.tif.aux.xml").write_text(_STALE_AUX)
    save_image(np.ones((4, 6, 3), np.uint8), tmp_path / "l.tif", extent=(0, 6, 0, 4), crs=_OB_TRAN)
    assert _placement(target) == (crs, (1.0, 0.0, 0.0, 0.0, -1.0, 4.0))
    assert not (tmp_path / "l.tif.aux.xml").exists()
    assert _placement(tmp_path / "l.tif") == (None, (1.0, 0.0, 0.0, 0.0, -1.0, 4.0))  # (see save_image's crs)


def test_a_geotiffs_side_file_that_is_a_link_gets_the_new_crs_at_its_target_and_the_link_stays(tmp_path):
    # the old side file (a link) was set aside and removed with the write, the new side file written through it to
    # the link's target: no <image>.aux.xml was left beside the image, and GDAL read the image without its CRS
    rasterio = pytest.importorskip("rasterio")
    store = tmp_path / "store"
    store.mkdir()
    image, link = tmp_path / "t.tif", tmp_path / "t.tif.aux.xml"
    save_image(np.zeros((4, 6, 3), np.uint8), image, extent=(0, 6, 0, 4), crs=_OB_TRAN)
    link.rename(store / "kept.aux.xml")
    link.symlink_to(store / "kept.aux.xml")
    crs = _OB_TRAN.replace("o_lat_p=30", "o_lat_p=40")
    save_image(np.ones((4, 6, 3), np.uint8), image, extent=(10, 16, 0, 4), crs=crs)
    assert link.is_symlink() and os.readlink(link) == str(store / "kept.aux.xml")
    assert _placement(image) == (rasterio.crs.CRS.from_user_input(crs), (1.0, 0.0, 10.0, 0.0, -1.0, 4.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store", "t.tif", "t.tif.aux.xml"]
    assert sorted(p.name for p in store.iterdir()) == ["kept.aux.xml"]  # (no temporary left)
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    save_image(np.ones((4, 6, 3), np.uint8), fresh / "t.tif", extent=(10, 16, 0, 4), crs=crs)
    assert (store / "kept.aux.xml").read_bytes() == (fresh / "t.tif.aux.xml").read_bytes()


def test_a_linked_geotiff_whose_side_file_beside_the_link_links_to_its_own_keeps_that_link(tmp_path):
    # l.tif -> data/t.tif and l.tif.aux.xml -> data/t.tif.aux.xml: the side file beside the link was removed as a
    # stale one, and the image read through the link lost its CRS; it names the new side file, so it stays
    rasterio = pytest.importorskip("rasterio")
    data = tmp_path / "data"
    data.mkdir()
    save_image(np.zeros((4, 6, 3), np.uint8), data / "t.tif", extent=(0, 6, 0, 4), crs=_OB_TRAN)
    (tmp_path / "l.tif").symlink_to(data / "t.tif")
    (tmp_path / "l.tif.aux.xml").symlink_to(data / "t.tif.aux.xml")
    crs = _OB_TRAN.replace("o_lat_p=30", "o_lat_p=40")
    save_image(np.ones((4, 6, 3), np.uint8), tmp_path / "l.tif", extent=(10, 16, 0, 4), crs=crs)
    placed = (rasterio.crs.CRS.from_user_input(crs), (1.0, 0.0, 10.0, 0.0, -1.0, 4.0))
    assert _placement(tmp_path / "l.tif") == _placement(data / "t.tif") == placed
    assert (tmp_path / "l.tif.aux.xml").is_symlink()
    assert sorted(p.name for p in data.iterdir()) == ["t.tif", "t.tif.aux.xml"]


@pytest.mark.parametrize("failing", ["image", "side file"])
def test_a_geotiff_whose_linked_side_file_cannot_be_replaced_keeps_the_old_pair_and_the_link(tmp_path, monkeypatch,
                                                                                            failing):
    pytest.importorskip("rasterio")
    store, folder = tmp_path / "store", tmp_path / "f"
    store.mkdir(), folder.mkdir()
    image, link = folder / "t.tif", folder / "t.tif.aux.xml"
    save_image(np.zeros((4, 6, 3), np.uint8), image, extent=(0, 6, 0, 4), crs=_OB_TRAN)
    link.rename(store / "kept.aux.xml")
    link.symlink_to(store / "kept.aux.xml")
    old, old_aux = _files(folder), (store / "kept.aux.xml").read_bytes()
    real = os.replace
    failed = []

    def replace(src, dst):  # the first rename onto the file, not the one putting the old file back
        if not failed and os.path.basename(dst) == {"image": "t.tif", "side file": "kept.aux.xml"}[failing]:
            failed.append(dst)
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(DataFileError, match="Input/output error"):
        save_image(np.ones((4, 6, 3), np.uint8), image, extent=(10, 16, 0, 4),
                   crs=_OB_TRAN.replace("o_lat_p=30", "o_lat_p=40"))
    monkeypatch.undo()
    assert failed
    assert _files(folder) == old and link.is_symlink()
    assert sorted(p.name for p in store.iterdir()) == ["kept.aux.xml"]
    assert (store / "kept.aux.xml").read_bytes() == old_aux
    assert _placement(image)[1] == (1.0, 0.0, 0.0, 0.0, -1.0, 4.0)


@pytest.mark.parametrize("name, crs", [("i.png", None), ("i.tif", None), ("i.tif", "EPSG:32611")])
def test_a_stale_side_file_that_is_a_link_is_unlinked_and_the_file_it_names_kept(tmp_path, name, crs):
    # nothing is written to replace it: the link (which GDAL reads with the image) goes, and the file elsewhere it
    # names, perhaps another image's, stays as it was
    rasterio = pytest.importorskip("rasterio")
    elsewhere = tmp_path / "other" / "shared.aux.xml"
    elsewhere.parent.mkdir()
    elsewhere.write_text(_STALE_AUX)
    save_image(np.zeros((4, 6, 3), np.uint8), tmp_path / name)
    (tmp_path / f"{name}.aux.xml").symlink_to(elsewhere)
    assert _placement(tmp_path / name)[0] is not None  # (GDAL reads it)
    extent = None if crs is None else (0, 6, 0, 4)
    save_image(np.ones((4, 6, 3), np.uint8), tmp_path / name, extent=extent, crs=crs)
    placed = (None, (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)) if crs is None else (rasterio.crs.CRS.from_user_input(crs),
                                                                         (1.0, 0.0, 0.0, 0.0, -1.0, 4.0))
    assert _placement(tmp_path / name) == placed
    assert not os.path.lexists(tmp_path / f"{name}.aux.xml")
    assert elsewhere.read_text() == _STALE_AUX


@pytest.mark.parametrize("failing", ["image", "side file"])
def test_a_geotiff_whose_side_file_cannot_be_put_in_place_keeps_the_old_image_and_side_file(tmp_path, monkeypatch,
                                                                                              failing):
    # the image was renamed into place first and its side file (the CRS) after: a failure of that second rename left
    # the new image without its CRS, the old side file removed
    pytest.importorskip("rasterio")
    target = tmp_path / "t.tif"
    save_image(np.zeros((4, 6, 3), np.uint8), target, extent=(0, 6, 0, 4), crs=_OB_TRAN)
    old = _files(tmp_path)
    assert sorted(old) == ["t.tif", "t.tif.aux.xml"]
    real = os.replace
    failed = []

    def replace(src, dst):  # the first rename onto the file, not the one putting the old file back
        if not failed and os.path.basename(dst) == {"image": "t.tif", "side file": "t.tif.aux.xml"}[failing]:
            failed.append(dst)
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(DataFileError, match="Input/output error"):
        save_image(np.ones((4, 6, 3), np.uint8), target, extent=(10, 16, 0, 4), crs=_OB_TRAN)
    monkeypatch.undo()
    assert _files(tmp_path) == old
    assert _placement(target)[1] == (1.0, 0.0, 0.0, 0.0, -1.0, 4.0)


@pytest.mark.parametrize("suffix, world", [(".png", ".pgw"), (".tif", ".tfw")])
def test_a_world_file_beside_a_plain_image_is_the_users_and_kept(tmp_path, suffix, world):
    # stepterrain writes no world file: one beside the image is the user's (the extent of an orthophoto re-rendered
    # under its name), kept as save_image documents, and GDAL places the new image by it
    target = tmp_path / f"i{suffix}"
    save_image(np.zeros((4, 6, 3), np.uint8), target)
    (tmp_path / f"i{world}").write_text("1\n0\n0\n-1\n100.5\n49.5\n")
    save_image(np.ones((4, 6, 3), np.uint8), target)
    assert (tmp_path / f"i{world}").exists()
    assert _placement(target)[1] == (1.0, 0.0, 100.0, 0.0, -1.0, 50.0)


def test_a_pyramid_whose_nth_level_rename_fails_leaves_the_storage_as_it_was(tmp_path, monkeypatch):
    # the level files were renamed into place one at a time: a failure part-way left the storage with the new image's
    # first levels beside the old one's last (a pyramid reopened from it mixed the two images)
    from stepterrain.texture_lod import ImagePyramid

    rng = np.random.default_rng(1)
    storage = tmp_path / "levels"
    first = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    ImagePyramid.build(first, storage=storage).close()
    old = _files(storage)
    assert len(old) == 4  # levels 1-4 (level 0 is the array itself)
    for n in (2, 4):
        calls = _failing_replace(monkeypatch, n)
        with pytest.raises(DataFileError, match=r"cannot write the pyramid level .*Input/output error"):
            ImagePyramid.build(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8), storage=storage)
        monkeypatch.undo()
        assert len(calls) >= n and _files(storage) == old, f"rename {n} failed"


def test_a_textured_obj_whose_rename_meets_a_ctrl_c_is_never_a_mix(tmp_path, monkeypatch):
    # SIGINT arriving while a rename runs: the rename completes and Python raises KeyboardInterrupt as os.replace
    # returns, inside its try: that file's backup was removed as if it had not been replaced, and the rollback put back
    # the files before it only, leaving the new texture beside the old .obj with the texture's old content lost
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread() or not callable(signal.getsignal(signal.SIGINT)):
        pytest.skip("needs Python's SIGINT handler in the main thread")
    new = tmp_path / "new"
    save_mesh(_textured((10, 200, 10)), new / "t.obj")
    for n in (1, 2):
        folder = tmp_path / f"n{n}"
        save_mesh(_textured((200, 10, 10)).apply_scale(2.0), folder / "t.obj")  # another .obj too
        old = _files(folder)
        calls: list[str] = []

        def replace(src, dst, *args, real=os.replace, calls=calls, n=n, **kwargs):
            real(src, dst, *args, **kwargs)
            calls.append(dst)
            if len(calls) == n:
                os.kill(os.getpid(), signal.SIGINT)

        monkeypatch.setattr(os, "replace", replace)
        with pytest.raises(KeyboardInterrupt):
            save_mesh(_textured((10, 200, 10)), folder / "t.obj")
        monkeypatch.undo()
        assert _files(folder) in (old, _files(new)), f"Ctrl-C in rename {n}"  # no backup left either


def test_a_thread_writing_does_not_join_another_threads_block(tmp_path):
    # the block is the thread's own (a context variable): a file another thread writes meanwhile is renamed into place
    # as its atomic_path ends, not staged in (and rolled back or renamed with) this thread's files
    import threading

    from stepterrain.export import _replaced_together, atomic_path

    seen = {}

    def other() -> None:
        with atomic_path(tmp_path / "other.txt") as tmp:
            tmp.write_text("other")
        seen["other"] = (tmp_path / "other.txt").exists()

    with _replaced_together():
        with atomic_path(tmp_path / "mine.txt") as tmp:
            tmp.write_text("mine")
        thread = threading.Thread(target=other)
        thread.start()
        thread.join()
        seen["mine"] = (tmp_path / "mine.txt").exists()
    assert seen == {"other": True, "mine": False}
    assert sorted(_files(tmp_path)) == ["mine.txt", "other.txt"]


def _interrupting_replace(monkeypatch, n: int, *, kill: bool) -> None:
    """os.replace renaming, then on its ``n``-th call a Ctrl-C as it returns: a real SIGINT (``kill``; held back by
    signals_held during a set's renames) or a KeyboardInterrupt raised there (a second Ctrl-C, let through at once)."""
    calls: list[object] = []

    def replace(src, dst, *args, real=os.replace, **kwargs):
        real(src, dst, *args, **kwargs)
        calls.append(dst)
        if len(calls) == n:
            if kill:
                os.kill(os.getpid(), signal.SIGINT)
            else:
                raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", replace)


@pytest.fixture
def _sigint_restored():
    previous = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_a_geotiff_whose_renames_meet_a_ctrl_c_is_never_a_mix(tmp_path, monkeypatch, n, _sigint_restored):
    # the image and its .aux.xml (an ob_tran CRS) are one set: the old side file was put back beside the new image
    # (the Ctrl-C held back until the renames were done), or left under a temporary name when it came as the old
    # side file was set aside
    pytest.importorskip("rasterio")
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("a SIGINT goes to the main thread")
    # Python's own handler, as in a terminal: a shell starts background jobs with SIGINT ignored (CI's nohup run)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    crs = _OB_TRAN.replace("o_lat_p=30", "o_lat_p=40")
    new, folder = tmp_path / "new", tmp_path / "f"
    new.mkdir(), folder.mkdir()
    save_image(np.ones((4, 6, 3), np.uint8), new / "t.tif", extent=(0, 6, 0, 4), crs=crs)
    save_image(np.zeros((4, 6, 3), np.uint8), folder / "t.tif", extent=(0, 6, 0, 4), crs=_OB_TRAN)
    old = _files(folder)
    assert "t.tif.aux.xml" in old
    _interrupting_replace(monkeypatch, n, kill=True)
    with pytest.raises(KeyboardInterrupt):
        save_image(np.ones((4, 6, 3), np.uint8), folder / "t.tif", extent=(0, 6, 0, 4), crs=crs)
    monkeypatch.undo()
    assert _files(folder) in (old, _files(new))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_an_interrupt_raised_as_a_rename_of_a_textured_obj_returns_never_loses_a_file(tmp_path, monkeypatch, n):
    # raised after the file was renamed: its backup was deleted as if it had not been, and it was not put back (the
    # old texture lost, the new one beside the old .obj)
    save_mesh(_textured((200, 10, 10)), tmp_path / "old" / "t.obj")
    save_mesh(_textured((10, 200, 10)), tmp_path / "new" / "t.obj")
    save_mesh(_textured((200, 10, 10)), tmp_path / "f" / "t.obj")
    _interrupting_replace(monkeypatch, n, kill=False)
    with pytest.raises(KeyboardInterrupt):
        save_mesh(_textured((10, 200, 10)), tmp_path / "f" / "t.obj")
    monkeypatch.undo()
    expected = _files(tmp_path / "new") if n == 3 else _files(tmp_path / "old")  # the last: every file in place
    assert _files(tmp_path / "f") == expected


def test_an_interrupt_raised_as_a_plain_geotiffs_rename_returns_leaves_the_new_file_alone(tmp_path, monkeypatch):
    pytest.importorskip("rasterio")
    save_image(np.zeros((4, 6, 3), np.uint8), tmp_path / "t.tif", extent=(0, 6, 0, 4), crs="EPSG:32611")
    _interrupting_replace(monkeypatch, 1, kill=False)
    with pytest.raises(KeyboardInterrupt):
        save_image(np.ones((4, 6, 3), np.uint8), tmp_path / "t.tif", extent=(0, 6, 0, 4), crs="EPSG:32611")
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.tif"]


@pytest.mark.parametrize("suffix", [".png", ".tif"])
@pytest.mark.parametrize("n", [1, 2])
@pytest.mark.parametrize("kill", [True, False])
def test_a_plain_image_whose_rename_meets_a_ctrl_c_never_keeps_the_old_side_file_beside_the_new_image(
        tmp_path, monkeypatch, suffix, n, kill, _sigint_restored):
    # a PNG or TIFF is one rename, its old .aux.xml set aside before it: a Ctrl-C as that rename returned put the old
    # side file back beside the new image, which GDAL then read with the old CRS and placement
    if kill and threading.current_thread() is not threading.main_thread():
        pytest.skip("a SIGINT goes to the main thread")
    signal.signal(signal.SIGINT, signal.default_int_handler)  # (CI's background run starts with SIGINT ignored)
    new, folder = tmp_path / "new", tmp_path / "f"
    save_image(np.ones((4, 6, 3), np.uint8), new / f"i{suffix}")
    save_image(np.zeros((4, 6, 3), np.uint8), folder / f"i{suffix}")
    (folder / f"i{suffix}.aux.xml").write_text(_STALE_AUX)
    old = _files(folder)
    _interrupting_replace(monkeypatch, n, kill=kill)
    with pytest.raises(KeyboardInterrupt):
        save_image(np.ones((4, 6, 3), np.uint8), folder / f"i{suffix}")
    monkeypatch.undo()
    assert _files(folder) in (old, _files(new)), f"Ctrl-C in rename {n}"


def test_a_nested_block_that_fails_inside_the_outer_one_puts_none_of_its_files_in_place(tmp_path):
    # an inner _replaced_together whose error the outer block caught left its files staged in the outer block, whose
    # end renamed them into place: a file of the failed write replaced the old one
    from stepterrain.export import _replaced_together, atomic_path

    (tmp_path / "inner.txt").write_text("old")
    with _replaced_together():
        with pytest.raises(ValueError):
            with _replaced_together():
                with atomic_path(tmp_path / "inner.txt") as tmp:
                    tmp.write_text("new, of a failed write")
                raise ValueError("the inner write failed")
        with atomic_path(tmp_path / "outer.txt") as tmp:
            tmp.write_text("outer")
    assert _files(tmp_path) == {"inner.txt": b"old", "outer.txt": b"outer"}  # no temporary file left either


def test_a_geotiff_within_another_block_is_put_back_whole_when_a_later_file_of_that_block_fails(tmp_path,
                                                                                                 monkeypatch):
    # the GeoTIFF's old side file was set aside and removed as its own (inner) block ended, before the outer block
    # renamed anything: a failed rename of a later file of the outer set put the old image back without its CRS
    rasterio = pytest.importorskip("rasterio")
    from stepterrain.export import _replaced_together, atomic_path

    target = tmp_path / "t.tif"
    save_image(np.zeros((4, 6, 3), np.uint8), target, extent=(0, 6, 0, 4), crs=_OB_TRAN)
    (tmp_path / "other.txt").write_text("old")
    old = _files(tmp_path)
    assert "t.tif.aux.xml" in old
    real, failed = os.replace, []

    def replace(src, dst, *args, **kwargs):
        if not failed and os.path.basename(dst) == "other.txt":
            failed.append(dst)
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    crs = _OB_TRAN.replace("o_lat_p=30", "o_lat_p=40")
    with pytest.raises(DataFileError, match="Input/output error"):
        with _replaced_together():
            save_image(np.ones((4, 6, 3), np.uint8), target, extent=(10, 16, 0, 4), crs=crs)
            with atomic_path(tmp_path / "other.txt") as tmp:
                tmp.write_text("new")
    monkeypatch.undo()
    assert failed and _files(tmp_path) == old
    with _replaced_together():  # and without a failure, the new image with its own side file
        save_image(np.ones((4, 6, 3), np.uint8), target, extent=(10, 16, 0, 4), crs=crs)
        with atomic_path(tmp_path / "other.txt") as tmp:
            tmp.write_text("new")
    assert _placement(target) == (rasterio.crs.CRS.from_user_input(crs), (1.0, 0.0, 10.0, 0.0, -1.0, 4.0))
    assert sorted(_files(tmp_path)) == ["other.txt", "t.tif", "t.tif.aux.xml"]


@pytest.mark.parametrize("after", ["last_rename", "set_aside"])
def test_a_second_ctrl_c_in_the_renames_bookkeeping_loses_no_file(tmp_path, after):
    # signals_held lets a second Ctrl-C through: one raised after the last rename of a set had returned (the loop's
    # next line) rolled the set back, and the last file has no backup, so the user's old image was removed outright;
    # one raised after the old side file was set aside but before the set recorded it left that file under its
    # temporary name, never put back
    import sys

    save_image(np.zeros((4, 6, 3), np.uint8), tmp_path / "new" / "i.png")
    save_image(np.ones((4, 6, 3), np.uint8), tmp_path / "f" / "i.png")
    (tmp_path / "f" / "i.png.aux.xml").write_text(_STALE_AUX)
    old, new = _files(tmp_path / "f"), _files(tmp_path / "new")
    fired = []

    def tracer(frame, event, arg):
        if frame.f_code.co_name != "_rename_all":
            return None

        def local(frame, event, arg):
            state = frame.f_locals
            if event != "line" or fired or "pending" not in state:
                return local
            pending, done = state["pending"], state.get("done", [])
            at = ((not pending and done) if after == "last_rename"
                  else (done or pending and pending[0][0] is None and not os.path.lexists(pending[0][1])))
            if at:
                fired.append(frame.f_lineno)
                raise KeyboardInterrupt
            return local
        return local

    sys.settrace(tracer)
    try:
        with pytest.raises(KeyboardInterrupt):
            save_image(np.zeros((4, 6, 3), np.uint8), tmp_path / "f" / "i.png")
    finally:
        sys.settrace(None)
    assert fired
    assert _files(tmp_path / "f") in (old, new), f"interrupt at line {fired}"
