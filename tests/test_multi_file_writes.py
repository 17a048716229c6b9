"""Outputs of several files (a textured OBJ's .obj, .mtl and texture images; an image and GDAL's side files): all
new or all old after a failure part-way, never a mix."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest
import trimesh
from PIL import Image

from stepterrain.errors import DataFileError
from stepterrain.export import save_mesh


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
    save_mesh(_textured((10, 200, 10), alpha=True), tmp_path / "ok.obj")  # the same bytes as without a failure
    assert _files(folder) == old


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
