"""save_mesh / atomic_path / `stepterrain info` bugs found by a pass over the mesh formats (each test failed before
its fix)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

from stepterrain.errors import DataFileError
from stepterrain.export import save_image, save_mesh


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
@pytest.mark.parametrize("ext", [".glb", ".obj", ".ply", ".png"])
def test_a_symbolic_link_is_written_through_and_kept(tmp_path, ext):
    # os.replace put the new file in place of the link: the link was gone and the file it named kept the old content
    (tmp_path / "store").mkdir()
    real = tmp_path / "store" / f"latest{ext}"
    link = tmp_path / f"link{ext}"
    os.symlink(os.path.join("store", real.name), link)  # relative, as `ln -s` makes them

    def write(path, size):
        if ext == ".png":
            return save_image(np.zeros((size, 3, 3), np.uint8), path)
        return save_mesh(trimesh.creation.box(extents=(size, 1, 1)), path)

    write(real, 1)
    before = real.read_bytes()
    assert write(link, 2) == link
    assert link.is_symlink() and os.readlink(link) == os.path.join("store", real.name)
    assert real.read_bytes() != before and link.read_bytes() == real.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["store", link.name])
    assert [p.name for p in (tmp_path / "store").iterdir()] == [real.name]  # the temporary file went beside it


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_a_dangling_symbolic_link_gets_its_target_and_a_loop_is_refused(tmp_path):
    link = tmp_path / "out.ply"
    os.symlink(os.path.join("new", "mesh.ply"), link)  # the target and its folder do not exist yet
    save_mesh(trimesh.creation.box(), link)
    assert link.is_symlink() and (tmp_path / "new" / "mesh.ply").is_file()
    assert len(trimesh.load(link).faces) == 12
    os.symlink("b.ply", tmp_path / "a.ply")
    os.symlink("a.ply", tmp_path / "b.ply")
    with pytest.raises(DataFileError, match=r"a\.ply.*symbolic link in a loop"):
        save_mesh(trimesh.creation.box(), tmp_path / "a.ply")
    assert (tmp_path / "a.ply").is_symlink() and (tmp_path / "b.ply").is_symlink()
