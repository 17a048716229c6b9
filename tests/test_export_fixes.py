"""save_mesh / atomic_path / `stepterrain info` bugs found by a pass over the mesh formats (each test failed before
its fix)."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import stat

import numpy as np
import pytest
import trimesh
from PIL import Image

import stepterrain as st
from stepterrain import cli
from stepterrain.errors import DataFileError, InvalidInputError
from stepterrain.export import atomic_path, read_mesh, save_image, save_mesh


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


def test_obj_coordinates_and_uvs_read_back_as_the_same_float64(tmp_path):
    # the OBJ was written with 8 decimals (trimesh's default): 1e-9 became 0, a micrometre mesh collapsed, and UTM
    # northings lost everything below 1e-8 m; UVs likewise
    rng = np.random.default_rng(7)
    vertices = np.array([[1e-9, -2.5e-12, 3.0e-300], [3807902.8276283755, 376328.6554542635, -0.1],
                         [1.0 / 3.0, 2.0 / 3.0, 1e17], [0.0, 1.0, 0.0]])  # fmt: skip
    vertices = np.concatenate([vertices, rng.normal(scale=1e-4, size=(20, 3))])
    faces = np.array([[0, 1, 2], [1, 3, 2]] + [[k, k + 1, k + 2] for k in range(4, 22)])
    plain = trimesh.Trimesh(vertices, faces, process=False)
    colored = plain.copy()
    colored.visual = trimesh.visual.ColorVisuals(colored, vertex_colors=rng.integers(0, 256, (len(vertices), 4)))
    for name, mesh in (("plain", plain), ("colored", colored)):
        back = trimesh.load(save_mesh(mesh, tmp_path / f"{name}.obj"), process=False)
        np.testing.assert_array_equal(back.vertices, vertices)
        np.testing.assert_array_equal(back.faces, faces)
    np.testing.assert_array_equal(back.visual.vertex_colors[:, :3], colored.visual.vertex_colors[:, :3])
    textured = plain.copy()
    uv = rng.random((len(vertices), 2)) / 7.0
    image = Image.fromarray(rng.integers(0, 256, (4, 4, 3), dtype=np.uint8))
    textured.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    back = trimesh.load(save_mesh(textured, tmp_path / "textured.obj"), process=False)
    np.testing.assert_array_equal(back.vertices, vertices)
    np.testing.assert_array_equal(back.visual.uv, uv)
    np.testing.assert_array_equal(np.asarray(back.visual.material.image), np.asarray(image))


def test_an_obj_with_fewer_uvs_than_vertices_is_refused(tmp_path):
    # each face corner's vt index is its vertex's: trimesh wrote 5 vt lines and faces naming vt 6 to 8 (an invalid
    # OBJ that readers refuse or texture wrongly)
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((5, 2)), image=Image.new("RGB", (2, 2)))
    with pytest.raises(InvalidInputError, match="mesh has 5 texture coordinates .UVs. for 8 vertices"):
        save_mesh(mesh, tmp_path / "box.obj")
    assert list(tmp_path.iterdir()) == []


def points(count: int = 5) -> trimesh.Trimesh:
    rng = np.random.default_rng(3)
    mesh = trimesh.Trimesh(rng.random((count, 3)) * 100.0, np.zeros((0, 3), np.int64), process=False)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rng.integers(0, 256, (count, 4), dtype=np.uint8))
    return mesh


@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj", ".ply"])
def test_vertices_without_faces_are_kept_as_points(tmp_path, ext, capsys):
    # glTF/GLB: trimesh's writer wrote an empty file (no buffer, no mesh), the points silently lost; `info` read
    # every points file as 0 vertices (trimesh's force="mesh" drops a point cloud)
    mesh = points()
    path = save_mesh(mesh, tmp_path / f"points{ext}")
    back = trimesh.load(path, process=False)
    cloud = next(iter(back.geometry.values())) if isinstance(back, trimesh.Scene) else back
    assert isinstance(cloud, trimesh.PointCloud)
    np.testing.assert_allclose(cloud.vertices, mesh.vertices, rtol=1e-7)  # glTF stores float32
    if ext == ".ply":
        np.testing.assert_array_equal(cloud.colors, mesh.visual.vertex_colors)
    if ext in (".glb", ".gltf", ".ply"):  # glTF's COLOR_0 is linear: read_mesh gives the sRGB bytes back
        np.testing.assert_array_equal(read_mesh(path).visual.vertex_colors, mesh.visual.vertex_colors)
    assert cli.main(["info", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["vertices"], summary["faces"]) == (5, 0)
    np.testing.assert_allclose(summary["bounds_min"], mesh.vertices.min(axis=0), rtol=1e-7)


@pytest.mark.parametrize("ext", [".stl", ".3mf"])
def test_vertices_without_faces_are_refused_where_only_triangles_fit(tmp_path, ext):
    # STL wrote an 84-byte file of 0 triangles and 3MF an object without triangles: the points silently lost
    with pytest.raises(InvalidInputError, match=rf"mesh has 5 vertices but no faces, and \{ext} stores triangles only"):
        save_mesh(points(), tmp_path / f"points{ext}")
    assert list(tmp_path.iterdir()) == []
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
    assert len(trimesh.load(save_mesh(empty, tmp_path / f"empty{ext}"), force="mesh").vertices) == 0  # still written


def test_info_and_read_mesh_report_the_colour_group_of_a_3mf(tmp_path, capsys):
    # save_mesh writes vertex colours as an m:colorgroup (per triangle corner), which trimesh's 3MF reader ignores:
    # `info print.3mf` said vertex_colors false for a colour print
    import stepterrain as st
    from stepterrain.export import read_mesh

    from .conftest import real_dem

    mesh = st.stepped(real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=6), interval=100.0, base=0.5,
                      solid=True, colors="terrain")  # fmt: skip
    assert len(np.unique(mesh.visual.vertex_colors, axis=0)) > 2
    path = save_mesh(mesh, tmp_path / "print.3mf")
    back = read_mesh(path)
    assert back.visual.kind == "vertex"
    np.testing.assert_array_equal(back.visual.vertex_colors, mesh.visual.vertex_colors)
    assert cli.main(["info", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["vertex_colors"] is True and summary["faces"] == len(mesh.faces)
    plain = save_mesh(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False), tmp_path / "plain.3mf")
    assert read_mesh(plain).visual.kind is None  # no colour group: none invented


def test_read_mesh_streams_a_one_object_3mf_itself_and_leaves_the_rest_to_trimesh(tmp_path, monkeypatch):
    # trimesh's 3MF reader holds the whole XML tree: `info` on the embedded DEM's coloured solid (4.3 M faces)
    # peaked at 9.8 GB in 38 s (trimesh alone); read_mesh streams a file of one mesh object itself (1.3 GB, 23 s)
    from stepterrain.export import read_mesh

    sphere = trimesh.creation.icosphere(subdivisions=2)
    sphere.vertices += (1e5 + 1e-9, -3.25, 0.1)
    ours = save_mesh(sphere, tmp_path / "ours.3mf")
    theirs = tmp_path / "theirs.3mf"
    theirs.write_bytes(trimesh.exchange.threemf.export_3MF(sphere))  # identity transform written as "1.0 0.0 ..."
    expected = {p: trimesh.load(p, force="mesh", process=False) for p in (ours, theirs)}
    moved = sphere.copy()
    scene = trimesh.Scene()
    scene.add_geometry(moved, transform=trimesh.transformations.translation_matrix((5.0, 0.0, 0.0)))
    shifted = tmp_path / "shifted.3mf"
    shifted.write_bytes(trimesh.exchange.threemf.export_3MF(scene))
    real_load = trimesh.load

    def refuse(path, *args, **kwargs):
        raise AssertionError(f"trimesh.load({path}) for a one-object 3MF")

    monkeypatch.setattr(trimesh, "load", refuse)
    for path, want in expected.items():
        back = read_mesh(path)
        np.testing.assert_array_equal(back.vertices, want.vertices)
        np.testing.assert_array_equal(back.faces, want.faces)
        np.testing.assert_array_equal(back.vertices, sphere.vertices)
    monkeypatch.setattr(trimesh, "load", real_load)
    back = read_mesh(shifted)  # a build transform: trimesh applies it
    np.testing.assert_allclose(back.vertices, sphere.vertices + (5.0, 0.0, 0.0))


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
@pytest.mark.parametrize("mode", [0o600, 0o640, 0o664])
def test_a_replaced_file_keeps_its_permissions(tmp_path, mode):
    # the replacement got 0o666 less the umask: a private 0o600 mesh or image became world-readable (0o644)
    for path, write in ((tmp_path / "m.ply", lambda p: save_mesh(trimesh.creation.box(), p)),
                        (tmp_path / "i.png", lambda p: save_image(np.zeros((2, 2, 3), np.uint8), p))):  # fmt: skip
        write(path)
        path.chmod(mode)
        write(path)
        assert path.stat().st_mode & 0o777 == mode


@pytest.mark.skipif(os.name != "posix" or os.geteuid() != 0, reason="giving a file to another user needs root")
def test_a_replaced_file_keeps_its_owner_and_group(tmp_path, monkeypatch):
    """Root (a container writing into a user's folder) replaced the user's mesh, image or OBJ side file with one
    owned by root:root, which the user could no longer write; ``open(path, "w")`` keeps the owner. A writer that may
    not give the owner (not root) still gives the group, where it belongs to it."""
    obj = _textured_box((200, 10, 10))
    outputs = ((tmp_path / "m.glb", lambda p: save_mesh(trimesh.creation.box(), p)),
               (tmp_path / "i.png", lambda p: save_image(np.zeros((2, 2, 3), np.uint8), p)),
               (tmp_path / "t.obj", lambda p: save_mesh(obj, p)))  # fmt: skip
    for path, write in outputs:
        write(path)
    files = sorted(tmp_path.iterdir())
    assert {f.name for f in files} >= {"m.glb", "i.png", "t.obj", "t.mtl"} and len(files) == 5  # + the texture
    for f in files:
        os.chown(f, 4321, 8765)
        f.chmod(0o2664)  # set-gid: a change of owner clears it, so the mode is given after
    for path, write in outputs:
        write(path)
    for f in tmp_path.iterdir():
        assert (f.stat().st_uid, f.stat().st_gid, f.stat().st_mode & 0o7777) == (4321, 8765, 0o2664), f.name

    chown = os.chown

    def not_root(path, uid, gid):  # as another user: only the group, one of theirs
        if uid != -1:
            raise PermissionError(1, "Operation not permitted")
        chown(path, uid, gid)

    os.chown(tmp_path / "m.glb", 0, 0)
    os.chown(tmp_path / "i.png", 0, 8765)
    monkeypatch.setattr(os, "chown", not_root)
    for path, write in outputs[:2]:
        write(path)
        assert (path.stat().st_uid, path.stat().st_gid) == (0, 0 if path.name == "m.glb" else 8765)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
@pytest.mark.parametrize("umask", [0o077, 0o002], ids=["0o077", "0o002"])
def test_a_new_file_gets_the_mode_of_the_umask_in_force_when_it_is_written(tmp_path, umask):
    # the umask was read once per process (the first write's) and mkstemp's 0o600 widened to that mode: after
    # os.umask(0o077), meant to keep outputs private, every new file still came out 0o644 (world-readable)
    try:  # a default ACL that tmp_path inherits (from /tmp's, on some machines) takes the umask's place: none here
        os.removexattr(tmp_path, "system.posix_acl_default")
    except (AttributeError, OSError):  # none there (ENODATA), no ACLs on this file system, or no xattrs at all
        pass
    save_image(np.zeros((2, 2, 3), np.uint8), tmp_path / "first.png")  # under the test run's own umask
    old = os.umask(umask)
    try:
        written = [save_mesh(trimesh.creation.box(), tmp_path / "m.ply"),
                   save_image(np.zeros((2, 2, 3), np.uint8), tmp_path / "i.png")]
    finally:
        os.umask(old)
    assert {path.name: path.stat().st_mode & 0o777 for path in written} == {"m.ply": 0o666 & ~umask,
                                                                            "i.png": 0o666 & ~umask}


@pytest.mark.skipif(not hasattr(os, "setxattr"), reason="POSIX ACLs through Linux extended attributes")
def test_a_new_file_in_a_folder_with_a_default_acl_gets_the_mode_open_gives(tmp_path):
    # mkstemp's 0o600 then a chmod to 0o666 less the umask: a folder's default ACL granting a group rw- gave the
    # new file an ACL mask of r--, so the group could not write it (open() gives rw-, as the ACL says)
    import struct

    def entry(tag: int, perm: int, ident: int = 0xFFFFFFFF) -> bytes:
        return struct.pack("<HHI", tag, perm, ident)

    folder = tmp_path / "shared"
    folder.mkdir()
    acl = struct.pack("<I", 2) + entry(1, 7) + entry(4, 7) + entry(8, 7, 1234) + entry(0x10, 7) + entry(0x20, 5)
    try:
        os.setxattr(folder, "system.posix_acl_default", acl)
    except OSError as exc:
        pytest.skip(f"no POSIX ACLs here: {exc}")
    with open(folder / "plain", "w", encoding="utf-8"):
        pass
    written = save_image(np.zeros((2, 2, 3), np.uint8), folder / "i.png")
    assert written.stat().st_mode & 0o777 == (folder / "plain").stat().st_mode & 0o777
    assert os.getxattr(written, "system.posix_acl_access") == os.getxattr(folder / "plain", "system.posix_acl_access")


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="names an open file through /proc (Linux)")
def test_a_replaced_file_is_flushed_to_disk_before_the_rename_and_a_new_one_is_not(tmp_path, monkeypatch):
    # the new content was renamed over the old file straight from the page cache: a crash (power loss) right after
    # could leave the name with an empty file on XFS (ext4 flushes a rename over a file itself), the old content gone
    # and the new one never written; a new file, which has no old content to lose, is not flushed (a batch of small
    # tiles took twice as long with an fsync each)
    target, image = tmp_path / "m.ply", tmp_path / "i.png"
    save_mesh(trimesh.creation.box(), target)
    save_image(np.zeros((2, 2, 3), np.uint8), image)
    old = {target: target.read_bytes(), image: image.read_bytes()}
    synced: list[tuple[str, bool]] = []
    real_fsync = os.fsync

    def spy(fd: int) -> None:
        name = os.path.basename(os.readlink(f"/proc/self/fd/{fd}"))  # ".m.ply.XXXXXXXX.tmp"
        replaced = tmp_path / ".".join(name.split(".")[1:3])
        synced.append((name, replaced.read_bytes() == old[replaced]))  # flushed while the old file is in place
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", spy)
    save_mesh(trimesh.creation.icosphere(), target)
    save_image(np.full((2, 2, 3), 9, np.uint8), image)
    assert [(name.split(".")[1:3], kept) for name, kept in synced] == [(["m", "ply"], True), (["i", "png"], True)]
    assert all(name.startswith(".") and name.endswith(".tmp") for name, _ in synced)  # the temporary files
    assert target.read_bytes() != old[target] and sorted(p.name for p in tmp_path.iterdir()) == ["i.png", "m.ply"]
    synced.clear()
    save_mesh(trimesh.creation.box(), tmp_path / "new.glb")
    assert synced == []


def test_a_replacement_that_cannot_be_flushed_keeps_the_old_file(tmp_path, monkeypatch):
    # an fsync error (EIO, a full quota on NFS) is the last word on whether the content reached the disk
    target = save_mesh(trimesh.creation.box(), tmp_path / "m.glb")
    old = target.read_bytes()

    def failing(fd: int) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fsync", failing)
    with pytest.raises(DataFileError, match=r"^cannot write '.*m\.glb': Input/output error$"):
        save_mesh(trimesh.creation.icosphere(), target)
    assert target.read_bytes() == old and [p.name for p in tmp_path.iterdir()] == ["m.glb"]


@pytest.mark.parametrize("code", ["EINVAL", "ENOTSUP", "ENOSYS"])
def test_a_file_system_that_cannot_flush_still_gets_its_file_replaced(tmp_path, monkeypatch, code):
    # fsync's "not supported here" is no write error: the replacement went through on such a file system before
    # the flush was added, and must still
    import errno

    target = save_mesh(trimesh.creation.box(), tmp_path / "m.ply")

    def unsupported(fd: int) -> None:
        raise OSError(getattr(errno, code), os.strerror(getattr(errno, code)))

    monkeypatch.setattr(os, "fsync", unsupported)
    save_mesh(trimesh.creation.icosphere(), target)
    assert len(trimesh.load(target).faces) == len(trimesh.creation.icosphere().faces)
    assert [p.name for p in tmp_path.iterdir()] == ["m.ply"]


@pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="names an open file through /proc (Linux)")
def test_a_textured_obj_that_cannot_be_flushed_keeps_its_old_side_files(tmp_path, monkeypatch):
    # the side files replaced theirs before the OBJ's own fsync: when that failed (or the run was interrupted during
    # it), the old OBJ was left with the new material and texture
    def textured(color: tuple[int, int, int]) -> trimesh.Trimesh:
        mesh = trimesh.creation.box()
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)),
                                                    image=Image.new("RGB", (2, 2), color))  # fmt: skip
        return mesh

    save_mesh(textured((200, 10, 10)), tmp_path / "t.obj")
    old = {path.name: path.read_bytes() for path in tmp_path.iterdir()}
    real_fsync = os.fsync

    def failing_for_the_obj(fd: int) -> None:
        if ".t.obj." in os.path.basename(os.readlink(f"/proc/self/fd/{fd}")):
            raise OSError(5, "Input/output error")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", failing_for_the_obj)
    with pytest.raises(DataFileError, match=r"Input/output error"):
        save_mesh(textured((10, 200, 10)), tmp_path / "t.obj")
    assert {path.name: path.read_bytes() for path in tmp_path.iterdir()} == old


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes (POSIX)")
@pytest.mark.parametrize("through_a_link", [False, True], ids=["named", "linked"])
def test_a_target_that_is_a_named_pipe_or_a_device_is_refused_not_replaced(tmp_path, through_a_link):
    # os.replace put a regular file in place of a named pipe (its reader waited for ever) or of a device: as root, a
    # link out.glb -> /dev/null (to discard the mesh) replaced /dev/null itself with the GLB
    special = tmp_path / "pipe.glb"
    os.mkfifo(special)
    target = special
    if through_a_link:
        target = tmp_path / "out.png"
        target.symlink_to(special)
    with pytest.raises(DataFileError, match=r"^cannot write '.*pipe\.glb': it is a named pipe, not a regular file"):
        _image_or_mesh(target)
    assert stat.S_ISFIFO(os.stat(special).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"pipe.glb", target.name})


def test_a_textured_obj_named_with_spaces_names_its_side_files_in_one_word(tmp_path):
    # "mtllib my terrain.mtl" and "map_Kd my terrain_material_0.png": OBJ/MTL readers that split lines on whitespace,
    # as the formats say, looked for "my" and "terrain.mtl" and lost the texture
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)),
                                                image=Image.new("RGB", (2, 2), (200, 10, 10)))  # fmt: skip
    path = save_mesh(mesh, tmp_path / "my terrain\tü.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([path.name, "my_terrain_ü.mtl",
                                                                 "my_terrain_ü_material_0.png"])  # fmt: skip
    mtllib = [line.split() for line in path.read_text(encoding="utf-8").splitlines() if line.startswith("mtllib")]
    assert mtllib == [["mtllib", "my_terrain_ü.mtl"]]
    maps = [line.split() for line in (tmp_path / "my_terrain_ü.mtl").read_text(encoding="utf-8").splitlines()
            if line.startswith("map_Kd")]  # fmt: skip
    assert maps == [["map_Kd", "my_terrain_ü_material_0.png"]]
    back = trimesh.load(path, process=False)
    assert np.asarray(back.visual.material.image.convert("RGB"))[0, 0].tolist() == [200, 10, 10]


def test_ply_attributes_with_names_that_are_no_ascii_word_are_written_renamed_with_a_warning(tmp_path):
    # `level-2`, `héight` and the element's own `x` or `count` were silently left out of the PLY (a face attribute
    # named `count` would even clash with the face list's count field)
    mesh = trimesh.creation.box()
    mesh.face_attributes["level-2"] = np.arange(12, dtype=np.int32)
    mesh.face_attributes["count"] = np.arange(12, dtype=np.int32) * 2
    mesh.face_attributes["level"] = np.arange(12, dtype=np.int16)
    mesh.vertex_attributes["x"] = np.arange(8, dtype=np.float32)
    mesh.vertex_attributes["héight"] = np.arange(8, dtype=np.float32) + 0.5
    with pytest.warns(UserWarning, match="PLY property names") as record:
        path = save_mesh(mesh, tmp_path / "m.ply")
    assert all(w.filename == __file__ for w in record)  # points at the caller's line, not at the writer
    messages = " ".join(str(w.message) for w in record)
    for renamed in ("'level-2' as 'level_2'", "'count' as 'count_attr'", "'x' as 'x_attr'", "'héight' as 'h_ight'"):
        assert renamed in messages
    data = trimesh.exchange.ply.load_ply(open(path, "rb"), prefer_color="vertex")
    raw_face = data["metadata"]["_ply_raw"]["face"]["data"]
    raw_vertex = data["metadata"]["_ply_raw"]["vertex"]["data"]
    np.testing.assert_array_equal(raw_face["level_2"], mesh.face_attributes["level-2"])
    np.testing.assert_array_equal(raw_face["count_attr"], mesh.face_attributes["count"])
    np.testing.assert_array_equal(raw_face["level"], mesh.face_attributes["level"])
    np.testing.assert_array_equal(raw_vertex["x_attr"], mesh.vertex_attributes["x"])
    np.testing.assert_array_equal(raw_vertex["h_ight"], mesh.vertex_attributes["héight"])
    np.testing.assert_array_equal(raw_vertex["x"].astype(np.float64), mesh.vertices[:, 0])




@pytest.mark.parametrize("ext", [".glb", ".obj"])
def test_a_folder_on_the_way_that_is_a_dangling_link_gets_its_target_made(tmp_path, ext):
    """save_mesh(mesh, "out/a.glb") with ``out`` a symbolic link to a folder not made yet failed: "cannot create the
    output folder 'out': File exists" (mkdir of the link's own name); a dangling link to the file itself already had
    its target made. The folder is made where the link leads, the link kept, and a textured OBJ's side files go there
    too."""
    from .test_export_formats import textured

    (tmp_path / "out").symlink_to(tmp_path / "new" / "meshes")
    path = save_mesh(textured(), tmp_path / "out" / f"a{ext}")
    assert (tmp_path / "out").is_symlink()
    written = tmp_path / "new" / "meshes" / f"a{ext}"
    assert written.is_file() and os.path.samefile(path, written)
    back = read_mesh(written)
    assert len(back.faces) == 50 and back.visual.kind == "texture"
    assert not [p for p in (tmp_path / "new" / "meshes").iterdir() if p.name.endswith(".tmp")]

@pytest.mark.parametrize("dtype", [np.int32, np.bool_])
def test_a_ply_attribute_named_end_header_is_renamed_and_the_file_reads_back(tmp_path, dtype):
    """A vertex or face attribute named ``end_header`` was written as ``property int end_header`` (a bool one also
    named on the ``comment stepterrain-bool`` line): PLY readers that end the header at that word (trimesh's, so
    read_mesh and ``stepterrain info``) took the header as ended there and refused the file ("PLY is unexpected
    length"). It is written renamed, as the element's own names are, with the warning."""
    mesh = trimesh.creation.box()
    mesh.face_attributes["end_header"] = (np.arange(12) % 2).astype(dtype)
    mesh.vertex_attributes["end_header"] = (np.arange(8) % 2).astype(dtype)
    with pytest.warns(UserWarning, match="'end_header' as 'end_header_attr'"):
        path = save_mesh(mesh, tmp_path / "m.ply")
    back = read_mesh(path)
    assert len(back.vertices) == 8 and len(back.faces) == 12
    np.testing.assert_array_equal(back.face_attributes["end_header_attr"], mesh.face_attributes["end_header"])
    np.testing.assert_array_equal(back.vertex_attributes["end_header_attr"], mesh.vertex_attributes["end_header"])
    assert back.face_attributes["end_header_attr"].dtype == dtype
    assert len(trimesh.load(path, process=False).faces) == 12

def _image_or_mesh(path):
    if str(path).endswith(".png"):
        return save_image(np.zeros((4, 4, 3), np.uint8), path)
    return save_mesh(trimesh.creation.box(), path)


@pytest.mark.parametrize("ext", [".glb", ".png"])
def test_a_nul_character_or_an_over_long_name_is_a_stepterrain_error(tmp_path, ext):
    # a NUL went through to tempfile.mkstemp (ValueError "embedded null byte"); a name longer than the file system's
    # 255 bytes raised os.lstat's OSError (ENAMETOOLONG) from the symbolic-link check, before any stepterrain message
    with pytest.raises(InvalidInputError, match=r"^path must be a file name without NUL characters; got '.*a\\x00"):
        _image_or_mesh(tmp_path / f"a\x00{ext}")
    with pytest.raises(DataFileError, match=r"^cannot write '.*xxxx.*': File name too long$"):
        _image_or_mesh(tmp_path / ("x" * 300 + ext))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("corner", [10**400, True], ids=["int_beyond_float64", "bool"])
def test_shared_bounds_must_be_real_numbers(tmp_path, corner):
    # np.asarray(..., float64) raised a bare OverflowError for 10**400 and took True as 1.0
    with pytest.raises(InvalidInputError, match=r"^shared_bounds must be finite \(2, 3\) corners"):
        save_mesh(trimesh.creation.box(), tmp_path / "box.ply", shared_bounds=[[0, 0, 0], [1, 1, corner]])
    assert list(tmp_path.iterdir()) == []


def test_metadata_that_holds_itself_is_refused_or_written_as_text(tmp_path):
    # _json_value recursed into a dict that holds itself until Python's RecursionError: as metadata= and as the
    # mesh's own metadata (which is written as its str when it is not JSON)
    loop: dict = {"name": "tile"}
    loop["self"] = loop
    with pytest.raises(InvalidInputError, match=r"^metadata\['run'\]\['self'\].* must be JSON .* nested at most 64"):
        save_mesh(trimesh.creation.box(), tmp_path / "a.glb", metadata={"run": loop})
    mesh = trimesh.creation.box()
    mesh.metadata["run"] = loop
    out = save_mesh(mesh, tmp_path / "b.gltf")
    extras = json.loads(out.read_text())["meshes"][0]["extras"]
    assert extras["run"]["name"] == "tile" and "nested too deep" in json.dumps(extras)


@pytest.mark.parametrize(
    "name, content, kind",
    [
        ("face.obj", b"v 1 2\nf 1 2 3\n", "ValueError: line 2, 'f 1 2 3', names v 2, and the file has 1 v line:"),
        ("columns.ply", b"ply\nformat ascii 1.0\nelement vertex 99999999999\nend_header\n", "KeyError"),
        ("empty.glb", b"", "ValueError: not a GLB: an empty file$"),
        ("notes.txt", b"hello", "NotImplementedError"),
        ("broken.3mf", b"PK\x03\x04garbage", "BadZipFile"),
    ],
)
def test_read_mesh_words_a_file_it_cannot_read_as_a_data_file_error(tmp_path, name, content, kind):
    # read_mesh let trimesh's IndexError, KeyError, ... out as they were (only `stepterrain info` worded them)
    from stepterrain.export import read_mesh

    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(DataFileError, match=rf"^cannot read '.*{name}' as a mesh: {kind}"):
        read_mesh(path)


def test_read_mesh_says_a_glb_is_cut_short_or_not_one_and_a_gltf_holds_no_scene(tmp_path):
    """A GLB cut short said json's "Unterminated string" (or "Expecting value"), an empty one trimesh's IndexError, a
    glTF of meshes without a scene trimesh's KeyError 'world': now what is wrong with the file."""
    from stepterrain.export import read_mesh

    whole = save_mesh(trimesh.creation.box(), tmp_path / "box.glb").read_bytes()
    for keep in (len(whole) // 2, 40, 16):
        cut = tmp_path / f"cut{keep}.glb"
        cut.write_bytes(whole[:keep])
        counts = "" if keep < 12 else f"its header counts {len(whole):,} bytes, "
        said = rf"as a mesh: ValueError: a GLB cut short: {counts}the file has {keep}$"
        with pytest.raises(DataFileError, match=said):
            read_mesh(cut)
    assert len(read_mesh(tmp_path / "box.glb").faces) == 12
    tree = json.loads(save_mesh(trimesh.creation.box(), tmp_path / "box.gltf").read_text())
    for drop in (("scene", "scenes"), ("scene", "scenes", "nodes")):
        (tmp_path / "bare.gltf").write_text(json.dumps({k: v for k, v in tree.items() if k not in drop}))
        with pytest.raises(DataFileError, match=r"as a mesh: ValueError: the glTF holds no scene \('scenes' missing"):
            read_mesh(tmp_path / "bare.gltf")
    (tmp_path / "json.glb").write_text(json.dumps(tree))
    with pytest.raises(DataFileError, match=r"not a GLB: a binary glTF starts with b'glTF'; this file with b'\{"):
        read_mesh(tmp_path / "json.glb")


def test_read_mesh_says_a_gltf_scene_holds_no_node_or_is_not_there(tmp_path):
    """A scene without nodes (an empty scene as Blender writes it, or meshes no node places) still said trimesh's
    KeyError 'world', and a 'scene' index past the scenes its IndexError: what is wrong with the file now. The files
    trimesh's and save_mesh's writers give (an empty mesh's scene holds a node) and a GLB with bytes after the length
    its header counts still read."""
    from stepterrain.export import read_mesh

    box = trimesh.creation.box()
    tree = json.loads(save_mesh(box, tmp_path / "box.gltf").read_text())
    cases = {"empty.gltf": {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"name": "Scene"}]},
             "unplaced.gltf": {**tree, "scenes": [{"nodes": []}]},
             "past.gltf": {**tree, "scene": 1}}
    said = {"empty.gltf": r"scene 0 holds no node", "unplaced.gltf": r"scene 0 holds no node",
            "past.gltf": r"'scene' is 1, but it holds 1 scene\(s\)"}
    for name, bad in cases.items():
        (tmp_path / name).write_text(json.dumps(bad))
        with pytest.raises(DataFileError, match=rf"as a mesh: ValueError: the glTF's {said[name]}"):
            read_mesh(tmp_path / name)
    (tmp_path / "trimesh.glb").write_bytes(box.export(file_type="glb") + bytes(16))  # trailing bytes: still a GLB
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    for path in (tmp_path / "box.gltf", tmp_path / "trimesh.glb", save_mesh(empty, tmp_path / "e.glb"),
                 save_mesh(empty, tmp_path / "e.gltf")):
        assert len(read_mesh(path).faces) == (0 if path.stem == "e" else 12), path.name


def test_read_mesh_says_a_glb_whose_header_counts_too_few_bytes_is_not_valid(tmp_path):
    """A GLB whose header's total length is 0 (or fewer bytes than its headers and JSON chunk take) said trimesh's
    "IndexError: list index out of range" (its reader read no buffer): now what is wrong with the file."""
    import struct

    whole = bytearray(save_mesh(trimesh.creation.box(), tmp_path / "box.glb").read_bytes())
    least = 20 + struct.unpack_from("<I", whole, 12)[0]
    for declared in (0, least - 1):
        struct.pack_into("<I", whole, 8, declared)
        (tmp_path / "bad.glb").write_bytes(bytes(whole))
        with pytest.raises(DataFileError, match=rf"as a mesh: ValueError: not a valid GLB: its header counts "
                                                rf"{declared:,} bytes for the whole file, fewer than its headers and "
                                                rf"JSON chunk take \({least:,}; glTF 2.0"):
            read_mesh(tmp_path / "bad.glb")
    struct.pack_into("<I", whole, 8, len(whole))
    (tmp_path / "good.glb").write_bytes(bytes(whole))
    assert len(read_mesh(tmp_path / "good.glb").faces) == 12


def test_read_mesh_checks_its_path(tmp_path):
    # None raised pathlib's TypeError, a missing file trimesh's ValueError "string is not a file"
    from stepterrain.export import read_mesh

    with pytest.raises(InvalidInputError, match=r"^path must be a str or os.PathLike; got NoneType$"):
        read_mesh(None)
    with pytest.raises(DataFileError, match=r"^mesh file '.*missing\.glb' does not exist$"):
        read_mesh(tmp_path / "missing.glb")
    (tmp_path / "folder.glb").mkdir()
    with pytest.raises(DataFileError, match=r"^mesh file '.*folder\.glb' is not a regular file$"):
        read_mesh(tmp_path / "folder.glb")


def test_info_on_an_unreadable_mesh_prints_one_line(tmp_path, capsys):
    path = tmp_path / "face.obj"
    path.write_bytes(b"v 1 2\nf 1 2 3\n")
    assert cli.main(["info", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        len(err) == 1
        and err[0].startswith("stepterrain info: error: cannot read")
        and "as a mesh: ValueError: line 2, 'f 1 2 3', names v 2, and the file has 1 v line" in err[0]
    )


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_a_textured_obj_written_through_a_symbolic_link_has_its_side_files_beside_the_real_file(tmp_path):
    # the .obj bytes replaced the file the link points to, but its .mtl and texture went beside the link (named
    # after it): a reader opening the real file found neither, and the mesh came back untextured
    (tmp_path / "store").mkdir()
    real = tmp_path / "store" / "latest.obj"
    link = tmp_path / "view.obj"
    os.symlink(os.path.join("store", real.name), link)
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)),
                                                image=Image.new("RGB", (2, 2), (200, 10, 10)))  # fmt: skip
    assert save_mesh(mesh, link) == link
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store", "view.obj"]
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["latest.mtl", "latest.obj",
                                                                     "latest_material_0.png"]  # fmt: skip
    back = trimesh.load(real, process=False)
    assert np.asarray(back.visual.material.image.convert("RGB"))[0, 0].tolist() == [200, 10, 10]
    save_mesh(mesh, real)  # the same file written by its own name: the same side files, no clash of owners
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["latest.mtl", "latest.obj",
                                                                     "latest_material_0.png"]  # fmt: skip


def gltf_tree_and_buffer(path):
    """A .glb's or self-contained .gltf's JSON and its one binary buffer, read with the standard library."""
    import base64
    import struct

    data = path.read_bytes()
    if path.suffix == ".glb":
        (length,) = struct.unpack_from("<I", data, 12)
        tree = json.loads(data[20 : 20 + length])
        return tree, data[20 + length + 8 :]
    tree = json.loads(data)
    return tree, base64.b64decode(tree["buffers"][0]["uri"].split(",", 1)[1])


def gltf_attribute(path, name):
    """The values of the first primitive's attribute ``name`` in [0, 1] or as stored (floats), via its accessor."""
    tree, binary = gltf_tree_and_buffer(path)
    accessor = tree["accessors"][tree["meshes"][0]["primitives"][0]["attributes"][name]]
    view = tree["bufferViews"][accessor["bufferView"]]
    dtype = {5126: "<f4", 5121: "u1", 5123: "<u2"}[accessor["componentType"]]
    width = {"VEC2": 2, "VEC3": 3, "VEC4": 4}[accessor["type"]]
    start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    values = np.frombuffer(binary, dtype, accessor["count"] * width, start).reshape(-1, width).astype(np.float64)
    return values / np.iinfo(dtype).max if accessor.get("normalized") else values


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("faces", [True, False], ids=["triangles", "points"])
def test_gltf_vertex_colours_are_linear_and_read_back_as_the_same_srgb_bytes(tmp_path, ext, faces):
    # COLOR_0 is linear (glTF 2.0 §3.7.2.1, §3.9.2) but the sRGB bytes of hypsometric colours went in as they were:
    # three.js, Blender and every other spec-following viewer showed the terrain washed out (mid-grey 128 as 188)
    import stepterrain as st

    if faces:
        mesh = st.stepped(np.random.default_rng(5).random((6, 7)) * 30.0, interval=5.0, colors="terrain",
                          device="cpu")  # fmt: skip
        mesh.visual.vertex_colors[:3] = [[0, 0, 0, 255], [1, 10, 128, 200], [255, 254, 12, 0]]  # both curve ends
    else:
        mesh = points(8)
    srgb = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
    path = save_mesh(mesh, tmp_path / f"colours{ext}")
    color_0 = gltf_attribute(path, "COLOR_0")
    c = srgb[:, :3] / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)  # IEC 61966-2-1
    np.testing.assert_allclose(color_0[:, :3], linear, atol=1e-6)
    np.testing.assert_allclose(color_0[:, 3], srgb[:, 3] / 255.0, atol=1e-6)  # alpha is linear already
    back = read_mesh(path)  # `info` and batch's previews read with it: the bytes the mesh had
    np.testing.assert_array_equal(back.visual.vertex_colors, srgb)


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("centre", [(0.0, 0.0, 0.0), (376328.7, 3807902.8, 1200.0)], ids=["globe", "utm"])
def test_gltf_positions_of_a_globe_round_within_float32_of_its_radius(tmp_path, ext, centre):
    # float32 positions were stored relative to the floor of the lowest corner: a globe's far side sat 2R from it,
    # so a vertex at the earth's radius came back up to 0.5 m off (float32's rounding at 2R), twice what float32
    # holds for a distance R from the centre
    radius = 6_371_000.0
    sphere = trimesh.creation.icosphere(subdivisions=3)
    mesh = trimesh.Trimesh(sphere.vertices * radius * 1.0001 + centre, sphere.faces, process=False)
    half = np.abs(mesh.vertices - mesh.bounds.mean(axis=0)).max()  # half the extent, about the radius
    back = read_mesh(save_mesh(mesh, tmp_path / f"globe{ext}"))  # node applied, its y-up world turned back z-up
    error = np.abs(back.vertices - mesh.vertices).max()
    assert error <= np.spacing(np.float32(half)) / 2 * (1 + 1e-9), error  # half a float32 step at the radius


@pytest.mark.parametrize("ext", [".ply", ".glb", ".obj"])
def test_info_does_not_call_points_or_an_empty_mesh_watertight(tmp_path, ext, capsys):
    # trimesh says a mesh without faces is watertight (no open edge): `info` printed "watertight True" for a file of
    # points and for an empty mesh, which enclose no volume
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
    for name, mesh in (("points", points()), ("empty", empty)):
        assert cli.main(["info", str(save_mesh(mesh, tmp_path / f"{name}{ext}")), "--json"]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert (summary["faces"], summary["watertight"]) == (0, False), (name, summary)
    assert cli.main(["info", str(save_mesh(trimesh.creation.box(), tmp_path / f"box{ext}")), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["watertight"] is True


def gltf_materials(path):
    """(each primitive's material, or None without one) of a .glb/.gltf."""
    tree, _ = gltf_tree_and_buffer(path)
    materials = tree.get("materials", [])
    return [materials[p["material"]] if "material" in p else None
            for mesh in tree.get("meshes", []) for p in mesh["primitives"]]  # fmt: skip


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("kind", ["coloured", "plain", "points", "closeup"])
def test_every_gltf_primitive_has_a_matte_material_that_blends_only_translucent_colours(tmp_path, ext, kind):
    # no primitive had a material: glTF's default (glTF 2.0 §3.9.6) is metallicFactor 1, so three.js, Babylon.js,
    # Blender and model-viewer showed the terrain as dark metal, and OPAQUE ignored a close-up anchor's vertex alpha
    import stepterrain as st
    from stepterrain.closeup import ROI, CloseUp, closeup_scene

    if kind == "closeup":
        cu = CloseUp(ROI.circle((5.0, 5.0), 3.0), offset=(0.0, 0.0, 10.0))
        mesh = closeup_scene(np.random.default_rng(2).random((11, 11)).astype(np.float32), [cu], device="cpu")
    elif kind == "points":
        mesh = points(8)
    else:
        mesh = st.stepped(np.random.default_rng(5).random((6, 7)) * 30.0, interval=5.0,
                          colors="terrain" if kind == "coloured" else None, device="cpu")  # fmt: skip
    colored = mesh.visual.kind == "vertex"
    translucent = colored and int(np.asarray(mesh.visual.vertex_colors)[:, 3].min()) < 255
    assert translucent == (kind in ("closeup", "points")), "the case does not test what it says"
    path = save_mesh(mesh, tmp_path / f"{kind}{ext}")
    (material,) = gltf_materials(path)
    assert material is not None
    pbr = material["pbrMetallicRoughness"]
    assert pbr["metallicFactor"] == 0.0 and pbr["roughnessFactor"] == 1.0
    assert pbr.get("baseColorFactor", [1.0] * 4) == [1.0] * 4  # the vertex colours are the colour
    assert material.get("alphaMode", "OPAQUE") == ("BLEND" if translucent else "OPAQUE")
    assert material["doubleSided"] is True
    back = read_mesh(path)  # `info` and batch's previews: the colours as they were, none invented for a plain mesh
    if colored:
        np.testing.assert_array_equal(back.visual.vertex_colors, mesh.visual.vertex_colors)
    else:
        assert back.visual.kind is None
    assert cli.main(["info", str(path), "--json"]) == 0


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_a_draped_image_is_written_to_gltf_at_full_brightness_and_not_metallic(tmp_path, ext):
    # TextureVisuals(uv, image) (drape_texture's) went through trimesh's SimpleMaterial -> PBR conversion:
    # baseColorFactor 0.4 (its default diffuse grey multiplied the image) and no metallicFactor (glTF's default 1)
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)),
                                                image=Image.new("RGB", (2, 2), (200, 10, 10)))  # fmt: skip
    path = save_mesh(mesh, tmp_path / f"draped{ext}")
    (material,) = gltf_materials(path)
    pbr = material["pbrMetallicRoughness"]
    assert "baseColorTexture" in pbr
    assert pbr.get("baseColorFactor", [1.0] * 4) == [1.0] * 4
    assert pbr["metallicFactor"] == 0.0
    back = trimesh.load(path, force="mesh", process=False)
    assert np.asarray(back.visual.material.baseColorTexture.convert("RGB"))[0, 0].tolist() == [200, 10, 10]


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_gltf_face_colours_are_linear_vertex_colours_with_the_matte_material(tmp_path, ext):
    # face-coloured meshes went to trimesh's writer: their vertex means stored as bytes taken for linear values
    # (read back and shown brighter: 200 as 229) and no material (glTF's default: metal)
    mesh = trimesh.creation.box()
    mesh.visual.face_colors = np.random.default_rng(4).integers(0, 256, (12, 4), dtype=np.uint8)
    blended = np.asarray(mesh.visual.vertex_colors).copy()  # trimesh's vertex colours of a face-coloured mesh
    assert mesh.visual.kind == "face"
    path = save_mesh(mesh, tmp_path / f"faces{ext}")
    np.testing.assert_array_equal(read_mesh(path).visual.vertex_colors, blended)
    (material,) = gltf_materials(path)
    assert material is not None and material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert material["alphaMode"] == ("BLEND" if blended[:, 3].min() < 255 else "OPAQUE")


def test_stl_warns_when_float32_moves_a_vertex_more_than_a_millimetre(tmp_path):
    # STL's float32 rounded UTM northings by up to 0.5 m (a globe's surface by 0.25 m) without a word; only values
    # beyond float32's reach were refused
    import warnings

    utm = trimesh.creation.box(extents=(900.0, 900.0, 300.0))
    utm.vertices += (376328.71, 3807902.83, 1200.0)
    with pytest.warns(UserWarning, match=r"float32 .*more than 0\.001.*\.ply, \.obj or \.3mf") as caught:
        path = save_mesh(utm, tmp_path / "utm.stl")
    assert caught[0].filename == __file__  # at the caller's line, not inside the writer
    back = trimesh.load(path, process=False)
    assert np.abs(back.triangles - utm.triangles).max() > 1e-3  # what the warning says: it did round that far
    whole = trimesh.creation.box(extents=(900.0, 900.0, 300.0))
    whole.vertices += (376000.0, 3807900.0, 1200.0)  # whole metres: exact in float32
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_mesh(whole, tmp_path / "whole.stl")
        save_mesh(trimesh.creation.box(extents=(9e3, 9e3, 3e3)), tmp_path / "local.stl")  # a local origin
        save_mesh(utm, tmp_path / "utm.ply")  # float64: nothing to warn about
    back = trimesh.load(tmp_path / "whole.stl", process=False)
    np.testing.assert_array_equal(back.triangles, whole.triangles)


@pytest.mark.parametrize("ext", [".ply", ".3mf"])
def test_face_colours_are_kept_by_ply_and_3mf(tmp_path, ext):
    # PLY (face red/green/blue/alpha) and 3MF (a triangle's p1) hold a colour per face, but both writers kept vertex
    # colours only: a face-coloured mesh came back without colours
    mesh = trimesh.creation.box()
    rng = np.random.default_rng(6)
    mesh.visual.face_colors = rng.integers(0, 256, (12, 4), dtype=np.uint8)
    mesh.face_attributes["level"] = rng.integers(0, 5, 12)
    path = save_mesh(mesh, tmp_path / f"faces{ext}")
    back = read_mesh(path)
    assert back.visual.kind == "face"
    np.testing.assert_array_equal(back.visual.face_colors, mesh.visual.face_colors)
    if ext == ".ply":  # the attributes still follow the colours
        np.testing.assert_array_equal(back.metadata["_ply_raw"]["face"]["data"]["level"], mesh.face_attributes["level"])


def _topographic_texture(alpha: str, simple: bool) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A stepped DEM with a nodata hole, textured with its topographic layer's RGBA (the hole transparent), as an
    image (trimesh's SimpleMaterial, drape_texture's) or a PBRMaterial; ``alpha`` "opaque" fills the hole,
    "half" makes some texels half transparent; and the texture's alpha."""
    import stepterrain as st
    from stepterrain.texture import texture_uv, topographic_layer

    z = np.add.outer(np.arange(8.0), np.arange(9.0)) * 40.0
    z[2:4, 3:5] = np.nan
    dem = st.Terrain.from_heights(z, spacing=(30.0, -30.0))
    layer = topographic_layer(dem)
    rgba = layer.to_uint8()
    if alpha == "opaque":
        rgba[..., 3] = 255
    elif alpha == "half":
        rgba[5:, :, 3] = 128
    mesh = st.stepped(dem, interval=100.0, device="cpu")
    uv = texture_uv(mesh.vertices, layer)
    image = Image.fromarray(rgba)
    if simple:
        mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    else:
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=image, metallicFactor=0.0, roughnessFactor=1.0)
        mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return mesh, rgba[..., 3]


@pytest.mark.parametrize("simple", [True, False])
@pytest.mark.parametrize(("alpha", "mode"), [("opaque", "OPAQUE"), ("hole", "MASK"), ("half", "BLEND")])
def test_a_texture_with_transparent_texels_gets_an_alpha_mode_in_gltf_and_an_alpha_map_in_obj(tmp_path, alpha, mode,
                                                                                                 simple):
    # a texture whose nodata texels are transparent (a topographic layer's RGBA) was written with glTF's default
    # alphaMode, OPAQUE, and an MTL naming the image only as map_Kd: viewers showed the hole in whatever colour its
    # texels hold. Alpha of only 0 and 255 is MASK (cutoff 0.5: the mesh still writes depth), partial alpha BLEND
    from . import gltf_validator

    mesh, texels = _topographic_texture(alpha, simple)
    assert (texels.min() < 255) == (mode != "OPAQUE") and (np.isin(texels, (0, 255)).all()) == (mode != "BLEND")
    paths = [save_mesh(mesh, tmp_path / f"{alpha}{ext}") for ext in (".glb", ".gltf")]
    for path in paths:
        (material,) = gltf_materials(path)
        assert material.get("alphaMode", "OPAQUE") == mode
        assert material.get("alphaCutoff") == (0.5 if mode == "MASK" else None)
        assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    if gltf_validator.available()[0]:
        assert gltf_validator.problems(gltf_validator.validate(paths)) == []
    obj = save_mesh(mesh, tmp_path / f"{alpha}.obj")
    mtl = (tmp_path / f"{alpha}.mtl").read_text().splitlines()
    (diffuse,) = [line.split()[1] for line in mtl if line.startswith("map_Kd ")]
    dissolve = [line for line in mtl if line.startswith("map_d ")]
    assert dissolve == ([] if mode == "OPAQUE" else [f"map_d -imfchan m {diffuse}"])
    with Image.open(tmp_path / diffuse) as written:  # the image keeps its alpha for map_d to read
        np.testing.assert_array_equal(np.asarray(written.convert("RGBA"))[..., 3], texels)
    assert len(read_mesh(obj).faces) == len(mesh.faces)



@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize(("texture", "expected"), [("opaque", "BLEND"), ("hole", "BLEND"), ("none", "BLEND"),
                                                  ("simple", "BLEND"), ("set", "MASK"), ("factor opaque", "OPAQUE")])
def test_a_material_colour_with_alpha_below_one_is_written_blended_to_gltf(tmp_path, ext, texture, expected):
    """A material whose base colour is translucent (a PBRMaterial's baseColorFactor alpha 0.5 over an opaque texture, a
    texture with a nodata hole or none; a SimpleMaterial's diffuse without an image) was written without an alphaMode
    (glTF's default, OPAQUE) or with its texture's (MASK): viewers ignore the alpha under OPAQUE and show the texel of
    alpha 0.5 (texel x factor) under MASK at cutoff 0.5 as opaque, where render_mesh blends it. It is BLEND, unless the
    material sets an alphaMode itself; an opaque factor leaves the texture's mode."""
    from trimesh.visual.material import PBRMaterial, SimpleMaterial

    from . import gltf_validator

    mesh, _ = _topographic_texture("hole" if texture == "hole" else "opaque", simple=False)
    factor = [255, 255, 255, 255 if texture == "factor opaque" else 128]
    image = mesh.visual.material.baseColorTexture
    if texture == "simple":
        material = SimpleMaterial(diffuse=[200, 120, 40, 128])
    else:
        material = PBRMaterial(baseColorTexture=None if texture == "none" else image, baseColorFactor=factor,
                               alphaMode="MASK" if texture == "set" else None)
    mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=material)
    path = save_mesh(mesh, tmp_path / f"m{ext}")
    (written,) = gltf_materials(path)
    assert written.get("alphaMode", "OPAQUE") == expected
    assert expected == "MASK" or written.get("alphaCutoff") is None  # no MASK cutoff left beside BLEND
    if gltf_validator.available()[0]:
        assert gltf_validator.problems(gltf_validator.validate([path])) == []
    # the caller's material is left as it was
    assert getattr(mesh.visual.material, "alphaMode", None) == ("MASK" if texture == "set" else None)


@pytest.mark.parametrize("texture", ["opaque", "hole", "none", "simple", "factor opaque"])
def test_a_material_colour_with_alpha_below_one_is_the_mtl_dissolve(tmp_path, texture):
    """The same translucent material in an OBJ: trimesh's MTL wrote its Kd (RGB) alone, so OBJ readers showed it
    opaque. Its alpha is the MTL's dissolve ``d`` (which multiplies a ``map_d``, as glTF's factor the texels')."""
    from trimesh.visual.material import PBRMaterial, SimpleMaterial

    mesh, _ = _topographic_texture("hole" if texture == "hole" else "opaque", simple=False)
    alpha = 255 if texture == "factor opaque" else 128
    if texture == "simple":
        material = SimpleMaterial(diffuse=[200, 120, 40, alpha])
    else:
        material = PBRMaterial(baseColorTexture=None if texture == "none" else mesh.visual.material.baseColorTexture,
                               baseColorFactor=[255, 255, 255, alpha])
    mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=material)
    obj = save_mesh(mesh, tmp_path / "m.obj")
    mtl = (tmp_path / "m.mtl").read_text().splitlines()
    dissolve = [line for line in mtl if line.split()[:1] == ["d"]]
    assert dissolve == ([] if alpha == 255 else ["d 0.50196078"])
    assert len([line for line in mtl if line.startswith("map_d ")]) == (texture == "hole")
    back = read_mesh(obj)
    assert len(back.faces) == len(mesh.faces) and back.visual.kind == "texture"

def test_a_textured_obj_shows_its_texture_at_full_brightness_and_matte(tmp_path):
    """The .mtl of a draped mesh carried trimesh's default Kd 0.4 and Ks 0.4: the MTL model multiplies map_Kd by Kd
    (three.js's MTLLoader does), so the texture showed at 40 % brightness, and shiny. The glTF path was fixed for the
    same default; the OBJ now says Kd 1, Ks 0 (matte, as the glTF material). A base colour the caller set is kept."""
    from trimesh.visual.material import PBRMaterial

    import stepterrain as st

    dem = st.sample_dem()
    small = st.Terrain.from_heights(dem.heights[:20, :30], spacing=dem.spacing, origin=dem.origin)
    mesh = st.drape(st.stepped(small, interval=50.0, device="cpu"), st.topographic_layer(small, device="cpu"))

    def mtl_lines(mesh, name):
        save_mesh(mesh, tmp_path / f"{name}.obj")
        text = (tmp_path / f"{name}.mtl").read_text()
        return {line.split()[0]: [float(v) for v in line.split()[1:]] for line in text.splitlines()
                if line[:3] in ("Kd ", "Ks ")}  # fmt: skip

    assert mtl_lines(mesh, "plain") == {"Kd": [1.0, 1.0, 1.0], "Ks": [0.0, 0.0, 0.0]}
    tinted = mesh.copy()
    tinted.visual.material = PBRMaterial(baseColorTexture=mesh.visual.material.baseColorTexture,
                                         baseColorFactor=[128, 64, 32, 255])  # fmt: skip
    assert mtl_lines(tinted, "tinted")["Kd"] == pytest.approx([128 / 255, 64 / 255, 32 / 255])


def _textured_box(colour):
    mesh = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (4, 4), colour))
    return mesh


def test_a_textured_obj_that_fails_leaves_the_old_obj_its_own_side_files(tmp_path, monkeypatch):
    """The .mtl and texture image were written (renamed into place) before the .obj text: when the .obj then failed
    (disk full, Ctrl-C), the old .obj was kept, as promised, but read the new texture, and a failed write left side
    files of no OBJ. They now replace the old ones only once the .obj is complete."""
    import errno

    from stepterrain import export

    save_mesh(_textured_box((255, 0, 0)), tmp_path / "t.obj")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["t.mtl", "t.obj", "t_material_0.png"]
    write_rows = export._write_rows

    def disk_full(write, row, blocks):
        if row.startswith("f "):
            raise OSError(errno.ENOSPC, "No space left on device")
        write_rows(write, row, blocks)

    monkeypatch.setattr(export, "_write_rows", disk_full)
    with pytest.raises(DataFileError, match="No space left on device"):
        save_mesh(_textured_box((0, 0, 255)), tmp_path / "t.obj")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # no temporary file either
    monkeypatch.setattr(export, "_write_rows", write_rows)
    with Image.open(tmp_path / "t_material_0.png") as image:
        assert image.getpixel((0, 0)) == (255, 0, 0)


@pytest.mark.parametrize("ext", [".obj", ".glb", ".ply"])
def test_a_folder_in_place_of_the_output_is_refused_before_anything_is_written(tmp_path, ext):
    """A folder at the output path was found only when the finished file was renamed onto it (EISDIR): the whole mesh
    was made first, and a textured OBJ left its .mtl and texture image behind for an OBJ that was never written."""
    (tmp_path / f"out{ext}").mkdir()
    with pytest.raises(DataFileError, match=r"out\.\w+': it is a folder; expected a file name"):
        save_mesh(_textured_box((0, 0, 255)), tmp_path / f"out{ext}")
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"out{ext}"]


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_a_textured_mesh_with_integer_or_bool_vertex_attributes_writes_gltf_without_them(tmp_path, ext):
    """glTF drops vertex attributes (save_mesh's docstring), and the untextured writer did; a textured mesh went to
    trimesh's writer with them, which raised a bare KeyError ('i8') for an integer or bool attribute (a PLY's
    ``level`` read back, then draped) and wrote float ones as custom attributes."""
    mesh = _textured_box((0, 0, 255))
    mesh.vertex_attributes.update(level=np.arange(8), seen=np.arange(8) % 2 == 0, height=np.arange(8.0))
    mesh.face_attributes["wall"] = np.arange(12) % 2 == 0
    path = save_mesh(mesh, tmp_path / f"t{ext}")
    (primitive,) = gltf_tree_and_buffer(path)[0]["meshes"][0]["primitives"]
    assert sorted(primitive["attributes"]) == ["POSITION", "TEXCOORD_0"]
    back = read_mesh(path)
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-7)
    np.testing.assert_allclose(back.visual.uv, mesh.visual.uv, atol=1e-7)
    assert set(mesh.vertex_attributes) == {"level", "seen", "height"}  # the caller's mesh is not modified


@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj"])
@pytest.mark.parametrize(("uv", "message"), [
    (np.full((8, 2), np.nan), r"texture coordinates \(UVs\) must be finite; got 8 of 8 with NaN or inf"),
    (np.zeros((5, 2)), r"mesh has 5 texture coordinates \(UVs\) for 8 vertices; \.\w+ needs one \(u, v\) per vertex"),
    (None, r"mesh has a texture image but no texture coordinates \(UVs\); \.\w+ needs one \(u, v\) per vertex"),
], ids=["nan", "too-few", "none"])  # fmt: skip
def test_a_texture_whose_uvs_cannot_be_written_is_refused(tmp_path, ext, uv, message):
    """glTF wrote NaN UVs' accessor bounds as NaN (invalid JSON) and a texture without TEXCOORD_0 for too few or no
    UVs (MESH_PRIMITIVE_TOO_FEW_TEXCOORDS), files the Khronos validator refuses; the OBJ wrote ``vt nan nan``. They
    are refused as the OBJ's too few UVs were, before anything is written."""
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (2, 2)))
    with pytest.raises(InvalidInputError, match=message):
        save_mesh(mesh, tmp_path / f"box{ext}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["../../../escaped", "terrain/v1", "t_a b/c"])
def test_a_textured_obj_writes_its_image_in_its_own_folder_whatever_the_material_is_called(tmp_path, name):
    """The texture image is named after its material, and the name went into the path as it was: a material called
    ``../../../escaped`` (which survives a glTF round trip, so any downloaded file can carry it) wrote
    ``escaped.png`` outside the output folder, and ``terrain/v1`` made a folder ``t_terrain`` beside the OBJ. Path
    separators become ``_`` like whitespace (which a name starting with the stem kept)."""
    out = tmp_path / "a" / "b" / "out"
    mesh = trimesh.creation.box()
    material = trimesh.visual.material.PBRMaterial(name=name, baseColorTexture=Image.new("RGB", (4, 4), (9, 9, 9)))
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)), material=material)
    save_mesh(mesh, out / "t.obj")
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    (image,) = [p for p in written if p.endswith(".png")]
    assert written == sorted(["a/b/out/t.obj", "a/b/out/t.mtl", image]) and image.startswith("a/b/out/t_")
    assert [p for p in out.iterdir() if p.is_dir()] == []
    (map_kd,) = [line for line in (out / "t.mtl").read_text().splitlines() if line.startswith("map_Kd")]
    assert map_kd == f"map_Kd {image.rsplit('/', 1)[1]}"
    back = read_mesh(out / "t.obj")
    assert np.asarray(back.visual.material.image.convert("RGB"))[0, 0].tolist() == [9, 9, 9]


def test_a_material_name_with_a_line_break_stays_one_statement_of_the_obj_and_mtl(tmp_path):
    """``usemtl`` and ``newmtl`` carried the material's name as it was: a line break in it (any glTF material name
    can hold one) started a statement of its own, here a vertex that shifted every face of the OBJ, and the
    ``map_Kd`` line lost the image. The name is now one word, as the image's file name is."""
    mesh = trimesh.creation.box()
    material = trimesh.visual.material.PBRMaterial(name="rock\nv 9 9 9", baseColorTexture=Image.new("RGB", (4, 4)))
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)), material=material)
    obj = save_mesh(mesh, tmp_path / "t.obj")
    lines = obj.read_text().splitlines()
    assert sum(line.startswith("v ") for line in lines) == len(mesh.vertices)
    assert "usemtl rock_v_9_9_9" in lines
    assert "newmtl rock_v_9_9_9" in (tmp_path / "t.mtl").read_text().splitlines()
    back = read_mesh(obj)
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    assert back.visual.material.image is not None


@pytest.mark.parametrize("faces", [True, False], ids=["triangles", "points"])
def test_read_mesh_gives_a_plys_attributes_back_and_a_second_write_keeps_them(tmp_path, faces):
    """save_mesh keeps face and vertex attributes (stepped's ``level`` and ``wall``) in a PLY only, but read_mesh left
    them in ``metadata["_ply_raw"]``: ``face_attributes`` came back empty, and a mesh read and written again lost
    them."""
    mesh = trimesh.creation.box()
    if not faces:
        mesh = trimesh.Trimesh(mesh.vertices, np.zeros((0, 3), np.int64), process=False)
    else:
        mesh.face_attributes.update(level=np.arange(12) - 3, wall=np.arange(12) % 3 == 0)
        mesh.visual.face_colors = np.random.default_rng(0).integers(0, 256, (12, 4), dtype=np.uint8)
    mesh.vertex_attributes.update(height=np.arange(8.0) * 1e10, pair=np.arange(16, dtype=np.float32).reshape(8, 2))
    back = read_mesh(save_mesh(mesh, tmp_path / "a.ply"))
    again = read_mesh(save_mesh(back, tmp_path / "b.ply"))
    for read in (back, again):
        assert sorted(read.vertex_attributes) == ["height", "pair_0", "pair_1"]
        np.testing.assert_array_equal(read.vertex_attributes["height"], mesh.vertex_attributes["height"])
        np.testing.assert_array_equal(read.vertex_attributes["pair_1"], mesh.vertex_attributes["pair"][:, 1])
        assert sorted(read.face_attributes) == (["level", "wall"] if faces else [])
        if faces:
            np.testing.assert_array_equal(read.face_attributes["level"], mesh.face_attributes["level"])
            np.testing.assert_array_equal(read.face_attributes["wall"], mesh.face_attributes["wall"])
            np.testing.assert_array_equal(read.visual.face_colors, mesh.visual.face_colors)


@pytest.mark.parametrize("colours", ["none", "face", "vertex"])
def test_a_3mf_leaves_out_triangles_that_name_one_vertex_twice(tmp_path, colours):
    """3MF's v1, v2 and v3 MUST be distinct (core spec 4.1.4.1), but a triangle naming one vertex twice was written
    as it was: trimesh.load of an STL with a sliver (its default merge of vertices) makes one, and the 3MF was
    invalid. It has no area and is left out; the others keep their colours."""
    import re
    import zipfile

    sliver = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1e-12, 0], [1, 1, 0]],
                             [[0, 1, 2], [1, 3, 2], [1, 4, 2]], process=False)  # fmt: skip
    (tmp_path / "in.stl").write_bytes(trimesh.exchange.stl.export_stl(sliver))
    mesh = trimesh.load(tmp_path / "in.stl")
    assert mesh.faces.tolist() == [[0, 1, 2], [1, 1, 2], [1, 3, 2]]
    if colours == "face":
        mesh.visual.face_colors = [[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]]
    elif colours == "vertex":
        mesh.visual.vertex_colors = [[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [9, 9, 9, 255]]
    path = save_mesh(mesh, tmp_path / "out.3mf")
    model = zipfile.ZipFile(path).read("3D/3dmodel.model").decode()
    corners = [[int(v) for v in t] for t in re.findall(r'<triangle v1="(\d+)" v2="(\d+)" v3="(\d+)"', model)]
    assert corners == [[0, 1, 2], [1, 3, 2]]
    back = read_mesh(path)
    assert back.faces.tolist() == corners
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    if colours == "face":
        np.testing.assert_array_equal(back.visual.face_colors, mesh.visual.face_colors[[0, 2]])
    elif colours == "vertex":
        np.testing.assert_array_equal(back.visual.vertex_colors, mesh.visual.vertex_colors)


@pytest.mark.parametrize("source", ["array", "webp", "tiff", "cmyk"])
def test_a_texture_image_of_any_kind_is_written_as_a_png_texture(tmp_path, source):
    """``TextureVisuals(uv=..., image=array)`` (trimesh takes a numpy array) wrote a glTF with no texture at all
    (trimesh's writer skips what is not a PIL image) and raised a bare AttributeError for an OBJ; an image opened
    from a WebP or TIFF file went beside the OBJ in that format, which most MTL readers cannot read; a CMYK image
    was a DataFileError ("cannot write mode CMYK as PNG"). Each is now written as a PNG texture."""
    from . import gltf_validator

    texels = np.zeros((4, 6, 3), np.uint8)
    texels[..., 0], texels[..., 1] = 200, np.arange(6) * 40
    image = texels
    if source in ("webp", "tiff"):
        Image.fromarray(texels).save(tmp_path / f"in.{source}", lossless=True)
        image = Image.open(tmp_path / f"in.{source}")
    elif source == "cmyk":
        image = Image.fromarray(texels).convert("CMYK")
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)), image=image)
    paths = [save_mesh(mesh, tmp_path / f"out{ext}") for ext in (".glb", ".gltf", ".obj")]
    for path in paths[:2]:
        tree, _ = gltf_tree_and_buffer(path)
        assert [i["mimeType"] for i in tree["images"]] == ["image/png"]
        back = read_mesh(path).visual.material.baseColorTexture
        np.testing.assert_array_equal(np.asarray(back.convert("RGB")), texels)
    if gltf_validator.available()[0]:
        assert gltf_validator.problems(gltf_validator.validate(paths[:2])) == []
    assert sorted(p.name for p in tmp_path.glob("out*")) == ["out.glb", "out.gltf", "out.mtl", "out.obj",
                                                            "out_material_0.png"]  # fmt: skip
    with Image.open(tmp_path / "out_material_0.png") as written:
        np.testing.assert_array_equal(np.asarray(written.convert("RGB")), texels)
    np.testing.assert_array_equal(np.asarray(read_mesh(paths[2]).visual.material.image.convert("RGB")), texels)


def test_a_texture_array_that_is_no_image_is_refused(tmp_path):
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((8, 2)), image=np.zeros((4, 4, 3), np.float32))
    for ext in (".glb", ".obj"):
        with pytest.raises(InvalidInputError, match=r"texture image \(image\) must be a PIL image or an \(H, W\), "
                                                    r"\(H, W, 3\) or \(H, W, 4\) uint8 array; got ndarray of dtype "
                                                    r"float32 and shape \(4, 4, 3\)"):  # fmt: skip
            save_mesh(mesh, tmp_path / "new" / f"out{ext}")
    assert list(tmp_path.iterdir()) == []  # refused before the folder is made


@pytest.mark.parametrize("mode", ["F", "I"])
def test_a_texture_image_of_32_bit_values_is_refused_before_anything_is_written(tmp_path, mode):
    """A PIL image of floats or 32-bit integers (a GeoTIFF of heights or a float hillshade opened as the texture)
    was a DataFileError ("cannot write mode F as PNG"), as if the file were at fault, raised once the folder was
    made. It is refused as the input it is, naming the mode, before anything is written."""
    Image.fromarray(np.linspace(0, 900, 24, dtype=np.float32).reshape(4, 6)).convert(mode).save(tmp_path / "h.tif")
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((8, 2)), image=Image.open(tmp_path / "h.tif"))
    assert mesh.visual.material.image.mode == mode
    for ext in (".glb", ".gltf", ".obj"):
        with pytest.raises(InvalidInputError, match=rf"texture image \(image\) must be a PIL image of 8-bit colours "
                                                    rf".* got a PIL image of mode '{mode}'"):  # fmt: skip
            save_mesh(mesh, tmp_path / "new" / f"out{ext}")
    assert [p.name for p in tmp_path.iterdir()] == ["h.tif"]  # refused before the folder is made


def test_a_palette_texture_with_alpha_is_written_as_rgba(tmp_path):
    """A palette image with alpha (mode PA) was a DataFileError ("cannot write mode PA as PNG"); it is RGBA now."""
    rgba = np.zeros((4, 6, 4), np.uint8)
    rgba[..., 0], rgba[..., 3] = 200, np.where(np.arange(6) < 3, 255, 0)
    image = Image.fromarray(rgba).convert("PA")
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)), image=image)
    expected = np.asarray(image.convert("RGBA"))
    for ext in (".glb", ".obj"):
        back = read_mesh(save_mesh(mesh, tmp_path / f"out{ext}")).visual.material
        texture = back.baseColorTexture if ext == ".glb" else back.image
        np.testing.assert_array_equal(np.asarray(texture.convert("RGBA")), expected)


def _old_write_rows(write, row, blocks):
    """The reference: the text writers' rows as they were formatted before the joined fast path (one str.format)."""
    for block in blocks:
        write((row * len(block)).format(*block.reshape(-1).tolist()))


@pytest.mark.parametrize("rows_per_write", [2, 1 << 16])
@pytest.mark.parametrize("kind", ["vertex", "face"])
def test_3mf_and_obj_text_is_the_same_as_str_format_gave_and_reads_back_exactly(tmp_path, monkeypatch, kind,
                                                                                 rows_per_write):
    """``_write_rows`` joins each block from the texts of its distinct values (and the 3MF's deflate runs in a thread
    of its own): ``repr`` and zlib, one after the other, took all the time of the embedded DEM's 4.3 M-face solid. The
    text must stay what ``str.format`` wrote, byte for byte: -0.0 apart from 0.0, subnormals, 1e-300, 0.1 + 0.2 and
    1e16 + 2 as their shortest exact repr, and every coordinate reading back bit for bit."""
    import zipfile

    from stepterrain import export

    awkward = [1e-300, -0.0, 0.1 + 0.2, 1e16 + 2, 5e-324, 2.2250738585072014e-308, -1e-310, 0.0, 1.5, -2.5e17, 1e-5]
    rng = np.random.default_rng(7)
    vertices = np.array([[awkward[(i + j) % len(awkward)] for j in range(3)] for i in range(22)])
    vertices[11:] += rng.normal(size=(11, 3))  # mostly distinct values too: blocks of 2 switch to repr each
    faces = np.array([[i, (i + 1) % 22, (i + 5) % 22] for i in range(22)] + [[3, 3, 4]])  # + a degenerate one
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    colours = rng.integers(0, 3, (22 if kind == "vertex" else 23, 4)).astype(np.uint8) * 100
    if kind == "vertex":
        mesh.visual.vertex_colors = colours
    else:
        mesh.visual.face_colors = colours
    monkeypatch.setattr(export, "_ROWS_PER_WRITE", rows_per_write)
    new_3mf, new_obj = save_mesh(mesh, tmp_path / "new.3mf"), save_mesh(mesh, tmp_path / "new.obj")
    with monkeypatch.context() as old:
        old.setattr(export, "_write_rows", _old_write_rows)
        old_3mf, old_obj = save_mesh(mesh, tmp_path / "old.3mf"), save_mesh(mesh, tmp_path / "old.obj")
    model = zipfile.ZipFile(new_3mf).read("3D/3dmodel.model")
    assert model == zipfile.ZipFile(old_3mf).read("3D/3dmodel.model")
    assert b'x="-0.0" y="0.30000000000000004" z="1.0000000000000002e+16"' in model
    assert b'x="5e-324" y="2.2250738585072014e-308" z="-1e-310"' in model
    assert new_3mf.read_bytes() == old_3mf.read_bytes()  # the same deterministic zip
    assert new_obj.read_bytes() == old_obj.read_bytes()
    back = read_mesh(new_3mf)
    assert np.asarray(back.vertices).view(np.uint64).tolist() == vertices.view(np.uint64).tolist()
    assert np.array_equal(back.faces, faces[:-1])


def test_a_3mf_whose_model_stream_fails_raises_at_once_and_keeps_the_old_file(tmp_path, monkeypatch):
    """The 3MF's model text is deflated and written by a thread of its own (``_behind``): a disk full there must still
    reach the caller as the DataFileError naming the file, stop the formatting (no more blocks written after it), end
    the thread, and leave the old file and no temporary file."""
    import errno
    import threading
    import zipfile

    from stepterrain import export

    monkeypatch.setattr(export, "_ROWS_PER_WRITE", 4)
    mesh = trimesh.creation.icosphere(3)
    path = save_mesh(mesh, tmp_path / "m.3mf")
    before = path.read_bytes()
    write, calls = zipfile._ZipWriteFile.write, []

    def disk_full(self, data):
        calls.append(len(data))
        if len(calls) > 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return write(self, data)

    monkeypatch.setattr(zipfile._ZipWriteFile, "write", disk_full)
    with pytest.raises(DataFileError, match=r"m\.3mf': \[Errno 28\] No space left on device"):
        save_mesh(mesh, tmp_path / "m.3mf")
    assert len(calls) < 10  # of the ~340 blocks: the failure stopped the writer
    assert not any(t.name == "stepterrain-3mf-writer" for t in threading.enumerate())
    assert [p.name for p in tmp_path.iterdir()] == ["m.3mf"] and path.read_bytes() == before


@pytest.mark.parametrize("element, names", [("vertex", ("nx", "ny", "nz")), ("vertex", ("u", "v")),
                                            ("vertex", ("s",)), ("vertex", ("texture_u",)), ("face", ("texcoord",)),
                                            ("face", ("vertex_index",))])
def test_ply_attributes_named_as_normals_or_uvs_are_renamed_and_read_back(tmp_path, element, names):
    """A vertex attribute named ``nx``/``ny``/``nz``, ``u``/``v``, ``s``/``t`` or ``texture_u`` was written under that
    name: trimesh's reader (and VTK's) took the columns for normals or texture coordinates, read_mesh left them out,
    and a face attribute named ``texcoord`` made the PLY unreadable (an IndexError in trimesh's reader)."""
    mesh = trimesh.creation.icosphere(subdivisions=1)
    attributes = mesh.vertex_attributes if element == "vertex" else mesh.face_attributes
    count = len(mesh.vertices) if element == "vertex" else len(mesh.faces)
    for k, name in enumerate(names):
        attributes[name] = np.arange(count, dtype=np.float32) * (k + 2) + 0.5
    with pytest.warns(UserWarning, match="PLY property names") as record:
        path = save_mesh(mesh, tmp_path / "a.ply")
    assert all(f"{name!r} as '{name}_attr'" in str(record[0].message) for name in names)
    back = read_mesh(path)
    assert len(back.faces) == len(mesh.faces) and back.visual.kind is None  # no texture made of the attribute
    got = back.vertex_attributes if element == "vertex" else back.face_attributes
    assert sorted(got) == sorted(f"{name}_attr" for name in names)
    for name in names:
        np.testing.assert_array_equal(got[f"{name}_attr"], attributes[name])


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_an_empty_gltf_reads_back_with_its_metadata(tmp_path, ext, capsys):
    """An empty mesh (a batch's tile of sea) is written as a node without a mesh, its metadata in the node's extras,
    but trimesh's reader drops node extras: read_mesh and ``stepterrain info`` gave it none, while the same tile
    with triangles had its crs, spacing and origin."""
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
    metadata = {"crs": "EPSG:32611", "spacing": [30.0, 30.0], "origin": [376328.66, 3807902.83]}
    path = save_mesh(empty, tmp_path / f"sea{ext}", metadata=metadata)
    back = read_mesh(path)
    assert len(back.vertices) == len(back.faces) == 0
    assert {key: back.metadata.get(key) for key in metadata} == metadata
    assert cli.main(["info", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["faces"] == 0 and summary["meta.crs"] == "EPSG:32611", summary


@pytest.mark.parametrize("limit, where", [(200, "before any work"), (900, "once the file is laid out")])
@pytest.mark.parametrize("kind", ["plain", "vertex", "texture"])
def test_a_glb_over_4_gib_is_refused_by_name(tmp_path, monkeypatch, kind, limit, where):
    """A GLB's lengths are uint32 (glTF 2.0 4.4.3): a mesh whose buffer passed 4 GiB (a 10k x 10k DEM with
    colours) raised a bare struct.error (numpy's OverflowError for a texture) once the buffer was built. Refused now
    by name, before the work where the counts tell (the limit is lowered here to keep the meshes small), and
    nothing is left behind."""
    from stepterrain import export

    mesh = trimesh.creation.box() if kind != "texture" else _textured_box((200, 10, 10))
    if kind == "vertex":
        mesh.visual.vertex_colors = np.arange(32, dtype=np.uint8).reshape(8, 4)
    monkeypatch.setattr(export, "_GLB_MAX_BYTES", limit, raising=False)
    with pytest.raises(InvalidInputError, match=r"a \.glb holds at most 4 GiB .* this mesh of 8 vertices and 12 faces "
                                                r"needs [0-9,]+ bytes: write \.ply, \.obj or \.3mf"):  # fmt: skip
        save_mesh(mesh, tmp_path / "big.glb")
    assert list(tmp_path.iterdir()) == []
    assert len(read_mesh(save_mesh(mesh, tmp_path / "big.ply")).faces) == 12  # the others hold it


def _photo(path, size=(96, 64), quality=90):
    """A JPEG file of a noisy colour picture (sharp edges: a second lossy pass shows) and its bytes."""
    rng = np.random.default_rng(3)
    pixels = rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    pixels[:, : size[0] // 2] = (200, 30, 40)
    Image.fromarray(pixels).save(path, format="JPEG", quality=quality)
    return path.read_bytes()


def _glb_image(path):
    tree, binary = gltf_tree_and_buffer(path)
    (image,) = tree["images"]
    view = tree["bufferViews"][image["bufferView"]]
    start = view.get("byteOffset", 0)
    return image["mimeType"], binary[start : start + view["byteLength"]]


@pytest.mark.parametrize("offset", [0.0, 6.4e6], ids=["local", "large"])
@pytest.mark.parametrize("material", ["simple", "pbr"])
def test_a_texture_opened_from_a_jpeg_is_embedded_as_the_file_s_bytes(tmp_path, material, offset):
    """An image opened from a JPEG went through trimesh's ``save(format="JPEG")``: Pillow's default quality 75 and
    4:2:0 chroma, a second lossy generation (the Blue Marble's colours off by up to 119 levels). The GLB now embeds,
    and the OBJ's side image is, the file's bytes unchanged. So too for a mesh in large coordinates (UTM, a globe's
    6.4e6 m), whose GLB moves them into the node's translation on a copy of the mesh: that copy's Image.copy()
    dropped the JPEG's format, and the Blue Marble draped on a globe was a 14.7 MB PNG (a 4.7 MB JPEG)."""
    source = _photo(tmp_path / "photo.jpg")
    mesh = trimesh.creation.box()
    mesh.apply_translation([offset, 0.0, 0.0])
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    with Image.open(tmp_path / "photo.jpg") as image:
        if material == "simple":
            mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
        else:
            pbr = trimesh.visual.material.PBRMaterial(baseColorTexture=image)
            mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=pbr)
        mime, data = _glb_image(save_mesh(mesh, tmp_path / "t.glb"))
        save_mesh(mesh, tmp_path / "t.obj")
    assert mime == "image/jpeg"
    assert data[: len(source)] == source and data[len(source) :].strip(b"\0 ") == b""  # padded to 4 bytes at most
    (side,) = tmp_path.glob("t_*.jpeg")
    assert side.read_bytes() == source
    assert len(read_mesh(tmp_path / "t.glb").faces) == 12


def test_a_jpeg_texture_changed_since_it_was_opened_is_encoded_at_high_quality(tmp_path):
    """A JPEG image painted on after opening is not the file any more: it is encoded again, at quality 95 without
    chroma subsampling (a few levels off), not at Pillow's default (tens of levels off at sharp colour edges)."""
    source = _photo(tmp_path / "photo.jpg")
    mesh = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    with Image.open(tmp_path / "photo.jpg") as image:
        image.paste((0, 0, 255), (10, 10, 40, 30))  # in place: still a JPEG image
        expected = np.asarray(image).astype(int)
        mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
        mime, data = _glb_image(save_mesh(mesh, tmp_path / "t.glb"))
        save_mesh(mesh, tmp_path / "t.obj")
    assert mime == "image/jpeg" and not data.startswith(source)
    for encoded in (data, next(tmp_path.glob("t_*.jpeg")).read_bytes()):
        with Image.open(__import__("io").BytesIO(encoded)) as back:
            error = np.abs(np.asarray(back.convert("RGB")).astype(int) - expected)
        assert error.mean() < 2.0 and np.percentile(error, 99) < 16, (error.mean(), np.percentile(error, 99))


def test_an_obj_keeps_the_vertices_no_face_names_and_a_textured_one_its_uv_seams(tmp_path, capsys):
    """trimesh's OBJ reader dropped the vertices no face names (read_mesh passed process=False, which does not
    keep them): ``stepterrain info`` counted 4 of the 6 vertices written, and the mesh came back renumbered (PLY,
    glTF and 3MF keep all 6). An OBJ of vertex indices only now keeps them, in order, with their colours; one with
    UV indices still splits a vertex per UV (maintain_order would give a seam vertex the median of its UVs), and
    one of several materials does not repeat every vertex in each material's mesh."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [5, 5, 5], [0, 1, 0], [1, 1, 0], [9, 9, 9]], float)
    faces = np.array([[0, 1, 3], [1, 4, 3]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    colours = np.arange(24, dtype=np.uint8).reshape(6, 4) * 10
    colours[:, 3] = 255
    mesh.visual.vertex_colors = colours
    back = read_mesh(save_mesh(mesh, tmp_path / "m.obj"))
    assert np.array_equal(back.vertices, vertices) and np.array_equal(back.faces, faces)
    assert np.array_equal(back.visual.vertex_colors, colours)
    assert cli.main(["info", str(tmp_path / "m.obj"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["vertices"], summary["faces"]) == (6, 2), summary
    # a UV seam: vertex 2 has UV (0, 0) in one face and (1, 0) in the other
    (tmp_path / "seam.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n"
                                       "f 1/1 2/2 3/3\nf 2/1 4/4 3/3\n")
    seam = read_mesh(tmp_path / "seam.obj")
    corners = np.asarray(seam.visual.uv)[seam.faces]
    assert np.array_equal(corners, [[[0, 0], [1, 0], [0, 1]], [[0, 0], [1, 1], [0, 1]]])
    assert np.array_equal(np.asarray(seam.vertices)[seam.faces][:, :, :2], [[[0, 0], [1, 0], [0, 1]],
                                                                            [[1, 0], [1, 1], [0, 1]]])
    (tmp_path / "two.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 2 4 3\n")
    two = read_mesh(tmp_path / "two.obj")  # the file's 4 vertices once (not all 4 twice, nor 3 corners each)
    assert np.array_equal(two.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    assert np.array_equal(two.faces, [[0, 1, 2], [1, 3, 2]])


def test_an_obj_with_faces_before_its_one_material_is_not_read_with_every_vertex_twice(tmp_path, capsys):
    """An OBJ (another tool's) whose first faces come before its one ``usemtl`` was read with maintain_order, as
    one of a single material: trimesh makes the faces before it a mesh of their own, and maintain_order repeated
    every vertex in each (10 vertices for the 5 of the file, ``stepterrain info`` counting them; trimesh's default
    read 6, the corners of each group). Such a file is read as one of several materials is: the file's 5 vertices
    once, in order, and each face's material as its face colour."""
    (tmp_path / "x.mtl").write_text("newmtl red\nKd 1 0 0\n")
    (tmp_path / "late.obj").write_text("mtllib x.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 5 5 5\n"
                                       "f 1 2 3\nusemtl red\nf 1 3 4\n")
    late = read_mesh(tmp_path / "late.obj")
    assert len(late.vertices) == 5 and np.array_equal(late.faces, [[0, 1, 2], [0, 2, 3]])  # not all 5 twice
    assert np.array_equal(late.visual.face_colors[1], [255, 0, 0, 255])  # red's Kd; the first face has none
    assert cli.main(["info", str(tmp_path / "late.obj"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["vertices"] == 5
    # its one usemtl before every face: one material, every vertex kept in order
    (tmp_path / "early.obj").write_text("mtllib x.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 5 5 5\n"
                                        "usemtl red\nf 1 2 3\nf 1 3 4\n")
    early = read_mesh(tmp_path / "early.obj")
    assert len(early.vertices) == 5 and np.array_equal(early.faces, [[0, 1, 2], [0, 2, 3]])


def _short_palette():
    image = Image.new("P", (4, 4), 5)
    image.putpalette([255, 0, 0, 0, 255, 0])  # 2 colours; the pixels use index 5
    return image


@pytest.mark.parametrize("ext", [".glb", ".obj"])
@pytest.mark.parametrize("make, top, colours", [(lambda: Image.new("P", (4, 4)), 0, "0 colours"),
                                                (lambda: Image.new("P", (4, 4), 3), 3, "0 colours"),
                                                (_short_palette, 5, "2 colours")], ids=["new", "new-3", "short"])
def test_a_palette_texture_whose_palette_lacks_its_colours_is_refused_by_name(tmp_path, ext, make, top, colours):
    """``Image.new("P", ...)`` as a texture raised a bare UnboundLocalError from inside Pillow's PNG writer (its
    empty palette is none at all once trimesh copied the material), after the folder was made; a palette shorter
    than the indices used wrote a PNG whose texels name no colour. Refused now, before any file is made; a palette
    image whose palette covers its pixels is written with its colours."""
    mesh = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=make())
    with pytest.raises(InvalidInputError, match=rf"mesh texture image \(image\) is a palette image \(mode 'P'\) whose "
                                                rf"pixels use palette index {top} but whose palette holds {colours}"):
        save_mesh(mesh, tmp_path / "out" / f"t{ext}")
    assert list(tmp_path.iterdir()) == []
    good = Image.new("P", (4, 4), 1)
    good.putpalette([255, 0, 0, 0, 255, 0])
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=good)
    back = read_mesh(save_mesh(mesh, tmp_path / f"t{ext}"))
    material = back.visual.material
    texture = getattr(material, "baseColorTexture", None) or material.image
    assert np.array_equal(np.unique(np.asarray(texture.convert("RGB")).reshape(-1, 3), axis=0), [[0, 255, 0]])


@pytest.mark.parametrize("kind", ["triangles", "points", "empty"])
def test_ply_keeps_the_metadata_in_its_header_comments(tmp_path, capsys, kind):
    """A PLY dropped the metadata a glTF keeps in its extras (crs, spacing, origin, generator): ``stepterrain info``
    of a .ply showed none. It is now compact JSON on ``comment stepterrain-metadata`` header lines (no whitespace,
    lines of at most 430 characters: MeshLab reads header lines into 512 bytes, VTK into 4096), read back by
    read_mesh; trimesh's and pyvista's readers still read the mesh, and the words readers look for in a header
    (end_header, TextureFile) cannot appear in it."""
    import pyvista

    meshes = {"triangles": trimesh.creation.box(), "points": points(),
              "empty": trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)}
    mesh = meshes[kind]
    metadata = {"crs": "EPSG:32611", "spacing": [30.0, -30.0], "origin": [376328.655, 3807902.827],
                "generator": "stepterrain steps", "note": "a b\tc end_header TextureFile x.png \u00fc",
                "wkt": 'PROJCS["WGS 84 / UTM zone 11N",GEOGCS["WGS 84",DATUM["WGS_1984"]]]' * 12,
                "levels": list(range(400)), "nothing": None, "solid": False}
    path = save_mesh(mesh, tmp_path / "m.ply", metadata=metadata)
    header, _ = path.read_bytes().split(b"\nend_header\n", 1)
    lines = header.split(b"\n")
    assert max(map(len, lines)) <= 430 and sum(line.startswith(b"comment stepterrain-metadata ") for line in lines) > 5
    assert not any(b"texturefile" in line.lower() or b"end_header" in line for line in lines)
    assert all(len(line.split()) <= 5 for line in lines)
    back = read_mesh(path)
    assert {key: back.metadata.get(key) for key in metadata} == metadata
    assert len(back.vertices) == len(mesh.vertices) and len(back.faces) == len(mesh.faces)
    if kind != "empty":  # trimesh reads an empty PLY as an empty Scene, and VTK as nothing, as before
        assert len(trimesh.load(path, process=False).vertices) == len(mesh.vertices)
        assert pyvista.read(path).n_points == len(mesh.vertices)
    assert cli.main(["info", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["meta.crs"] == "EPSG:32611" and summary["meta.origin"] == [376328.655, 3807902.827], summary
    assert "crs" not in read_mesh(save_mesh(mesh, tmp_path / "plain.ply")).metadata


def test_a_large_png_replaced_by_another_writer_after_the_rename_is_not_taken_for_this_one(tmp_path, monkeypatch):
    """save_image records a large PNG's pixels digest and file stamp, so a glTF of the same texture embeds the file's
    bytes. The stamp was taken at the path after the rename: another writer's file, renamed over it in between, was
    stamped and paired with this image's digest, and the GLB embedded the other writer's picture. The stamp is now
    the temporary file's, before the rename (the inode survives it): the other file does not match it, and the
    texture is encoded from its own pixels."""
    import io

    from stepterrain import export

    monkeypatch.setattr(export, "_FAST_PNG_PIXELS", 100)
    rng = np.random.default_rng(8)
    mine = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    theirs = 255 - mine
    other = tmp_path / "theirs.png"
    Image.fromarray(theirs).save(other, **export._png_options(Image.fromarray(theirs)))
    target = tmp_path / "tex.png"
    original = os.replace

    def swapped(src, dst, *args, **kwargs):
        original(src, dst, *args, **kwargs)
        if os.fspath(dst) == str(target) and os.fspath(src) != str(other):
            original(other, target)  # the other writer's rename lands right after this one's

    monkeypatch.setattr(os, "replace", swapped)
    export.save_image(mine, target)
    monkeypatch.setattr(os, "replace", original)
    with Image.open(target) as back:
        assert np.array_equal(np.asarray(back), theirs)  # the path holds the other writer's picture now
    mesh = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(mine))
    mime, data = _glb_image(save_mesh(mesh, tmp_path / "t.glb"))
    with Image.open(io.BytesIO(data)) as embedded:
        assert mime == "image/png" and np.array_equal(np.asarray(embedded), mine)
    # the file written and not replaced: its bytes are taken, as before
    export.save_image(mine, target)
    mime, data = _glb_image(save_mesh(mesh, tmp_path / "u.glb"))
    assert data[: target.stat().st_size] == target.read_bytes()
    # replaced by a file of the same size between the reader's stamp check and its read: the bytes read are those
    # of the file stamped, or none (the path was read again after the check, and its length alone compared)
    written = bytearray(target.read_bytes())
    written[len(written) // 2 : len(written) // 2 + 8] = bytes(8)
    other.write_bytes(bytes(written))
    digest = export._pixels_digest

    def digest_then_swap(*args, **kwargs):
        if other.exists():
            os.replace(other, target)
        return digest(*args, **kwargs)

    monkeypatch.setattr(export, "_pixels_digest", digest_then_swap)
    mime, data = _glb_image(save_mesh(mesh, tmp_path / "v.glb"))
    monkeypatch.setattr(export, "_pixels_digest", digest)
    assert target.read_bytes() == bytes(written) and not data.startswith(bytes(written))
    with Image.open(io.BytesIO(data)) as embedded:
        assert np.array_equal(np.asarray(embedded), mine)


def test_an_stl_or_obj_that_is_not_one_is_refused_not_read_as_an_empty_mesh(tmp_path, capsys):
    """trimesh's STL reader took a file whose length does not match a binary STL's header as ASCII and found no
    facets; its OBJ reader skipped every line it did not know. So an STL cut short (a binary one, or an ASCII one
    without its endsolid), random bytes, or a PLY or GLB under the wrong extension read as an empty mesh, and
    `stepterrain info` printed "vertices 0" with exit status 0; st.stepped then said "terrain mesh has no faces".
    They are refused now, naming the format; empty meshes of the formats (as save_mesh writes them) still read."""
    tin = trimesh.Trimesh([[0, 0, 0], [1, 0, 0.5], [1, 1, 1.5], [0, 1, 1]], [[0, 1, 2], [0, 2, 3]], process=False)
    good = {"binary.stl": trimesh.exchange.stl.export_stl(tin),
            "ascii.stl": trimesh.exchange.stl.export_stl_ascii(tin).encode(),
            "tin.ply": trimesh.exchange.ply.export_ply(tin), "tin.glb": trimesh.exchange.gltf.export_glb(tin.scene())}
    bad = {"cut.stl": (good["binary.stl"][:-7], r"not an STL file: its 177 bytes .* header's count of 2 triangles "
                                                r"makes 184 bytes"),
           "cut_ascii.stl": (good["ascii.stl"][:-30], r"not a whole STL file: an ASCII STL .* without its closing "
                                                      r"'endsolid'; is it cut short\?"),
           "noise.stl": (bytes(range(256)) * 3, "not an STL file"), "zero.stl": (b"", "not an STL file: its 0 bytes"),
           "ply.obj": (good["tin.ply"], r"not an OBJ file: line 1 starts with b'ply'"),
           "glb.obj": (good["tin.glb"], r"not an OBJ file: line 1 starts with b'glTF"),
           "ply.stl": (good["tin.ply"], "not an STL file"),
           "text.obj": (b"hello\nworld\n", "not an OBJ file: line 1 starts with b'hello'")}
    for name, data in good.items():
        (tmp_path / name).write_bytes(data)
    for name in ("binary.stl", "ascii.stl"):
        assert len(read_mesh(tmp_path / name).faces) == 2
    for name, (data, message) in bad.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(DataFileError, match=rf"cannot read '.*{name}' as a mesh: ValueError: {message}"):
            read_mesh(tmp_path / name)
    assert cli.main(["info", str(tmp_path / "ply.obj")]) == 2
    assert "not an OBJ file" in capsys.readouterr().err
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int))
    for ext in (".stl", ".obj"):  # stepterrain's own empty meshes, an empty OBJ, an ASCII STL of no facets
        assert len(read_mesh(save_mesh(empty, tmp_path / f"empty{ext}")).vertices) == 0
    for name, data in (("blank.obj", b""), ("comments.obj", b"# nothing\n\ng empty\n"),
                       ("solid.stl", b"solid empty\nendsolid empty\n")):
        (tmp_path / name).write_bytes(data)
        assert len(read_mesh(tmp_path / name).vertices) == 0


def test_an_ascii_stl_of_several_solids_cut_short_is_refused_not_read_as_its_first_solids(tmp_path):
    """trimesh's ASCII STL reader reads solid by solid and stops where no 'endsolid' follows: an STL of two solids (as
    CAD programs write a part of several bodies) cut short in the second read as the first alone, without a word.
    read_mesh checks every STL now, and the whole file still reads."""
    box, ball = trimesh.creation.box(), trimesh.creation.icosphere(subdivisions=1)
    text = (trimesh.exchange.stl.export_stl_ascii(box) + "\n" + trimesh.exchange.stl.export_stl_ascii(ball)).encode()
    (tmp_path / "whole.stl").write_bytes(text)
    assert len(read_mesh(tmp_path / "whole.stl").faces) == len(box.faces) + len(ball.faces)
    (tmp_path / "cut.stl").write_bytes(text[: len(text) * 3 // 4])
    with pytest.raises(DataFileError, match=r"cannot read '.*cut\.stl' as a mesh: ValueError: not a whole STL file: "
                                            r"an ASCII STL .* without its closing 'endsolid'; is it cut short\?$"):
        read_mesh(tmp_path / "cut.stl")


@pytest.mark.parametrize("points", [False, True])
def test_an_ascii_ply_cut_short_is_refused_not_read_as_the_rows_before_the_cut(tmp_path, points):
    """trimesh's ASCII PLY reader slices the rows there are: a file cut short (an interrupted download or copy)
    whose header declares 242 faces read as the 220 before the cut, and a point cloud as its first points, without
    a word (a binary PLY cut short is refused by trimesh for its length). read_mesh compares each element's rows
    with its header's count; the whole files still read."""
    heights = np.random.default_rng(4).random((12, 12))
    mesh = st.heightfield_mesh(heights)
    if points:
        mesh = trimesh.PointCloud(mesh.vertices)
    text = trimesh.exchange.ply.export_ply(mesh, encoding="ascii")
    (tmp_path / "whole.ply").write_bytes(text)
    whole = read_mesh(tmp_path / "whole.ply")
    assert (len(whole.vertices), len(whole.faces)) == (144, 0 if points else 242)
    (tmp_path / "cut.ply").write_bytes(text[: text.rindex(b"\n", 0, len(text) - 300) + 1])  # whole rows
    element, count = ("vertex", 144) if points else ("face", 242)
    with pytest.raises(DataFileError, match=rf"cannot read '.*cut\.ply' as a mesh: ValueError: not a whole PLY file: "
                                            rf"its header declares {count} {element} rows, the file holds \d+; is it "
                                            r"cut short\?$"):
        read_mesh(tmp_path / "cut.ply")


def test_a_gltf_with_sparse_positions_is_refused_not_read_as_its_base_values(tmp_path):
    """glTF's sparse accessors (base values, or zeros, with some elements replaced) are ignored by trimesh's reader:
    a terrain whose heights were stored as a sparse POSITION over a flat base came back flat at z = 0 without a
    word, and stepped as such. read_mesh refuses it, naming the accessor; the same file dense still reads."""
    import struct

    points = np.array([[0, 0, 0], [1, 0, 0.5], [1, 1, 1.5], [0, 1, 1]], np.float32)
    flat = points.copy()
    flat[:, 2] = 0.0

    def glb(sparse):
        parts = [flat.tobytes() if sparse else points.tobytes(), np.array([0, 1, 2, 0, 2, 3], np.uint16).tobytes(),
                 np.array([1, 2, 3], np.uint16).tobytes(), points[1:].tobytes()]
        offsets, blob = [], b""
        for part in parts:
            blob += b"\0" * (-len(blob) % 4)
            offsets.append(len(blob))
            blob += part
        blob += b"\0" * (-len(blob) % 4)
        position = {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0],
                    "max": [1, 1, 1.5]}
        if sparse:
            position["sparse"] = {"count": 3, "indices": {"bufferView": 2, "componentType": 5123},
                                  "values": {"bufferView": 3}}
        tree = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
                "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
                "accessors": [position, {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}],
                "bufferViews": [{"buffer": 0, "byteOffset": o, "byteLength": len(p)} for o, p in zip(offsets, parts,
                                                                                                     strict=True)],
                "buffers": [{"byteLength": len(blob)}]}
        text = json.dumps(tree).encode()
        text += b" " * (-len(text) % 4)
        return (struct.pack("<III", 0x46546C67, 2, 28 + len(text) + len(blob))
                + struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob)

    (tmp_path / "dense.glb").write_bytes(glb(False))
    # read as glTF's y-up world turned z-up: (x, y, z) -> (x, -z, y)
    np.testing.assert_array_equal(read_mesh(tmp_path / "dense.glb").vertices, points[:, [0, 2, 1]] * [1, -1, 1])
    (tmp_path / "sparse.glb").write_bytes(glb(True))
    with pytest.raises(DataFileError, match=r"cannot read '.*sparse\.glb' as a mesh: ValueError: glTF accessor 0 \(a "
                                            r"primitive's POSITION\) is sparse, which trimesh's reader reads as its "
                                            r"base values alone"):
        read_mesh(tmp_path / "sparse.glb")


@pytest.mark.parametrize("extension, message", [
    ("KHR_draco_mesh_compression", r"the glTF's meshes are Draco-compressed \(KHR_draco_mesh_compression\), which "
                                   r"trimesh's reader decodes only with DracoPy installed \(pip install DracoPy\)"),
    ("EXT_meshopt_compression", r"the glTF's buffers are meshopt-compressed \(EXT_meshopt_compression, required\), "
                                r"which trimesh's reader cannot decode"),
])
def test_a_gltf_compressed_beyond_the_reader_is_refused_not_read_as_zeros(tmp_path, monkeypatch, extension, message):
    """A Draco-compressed GLB (gltf-transform's, Blender's option, Cesium's) read, without DracoPy, as a mesh whose
    every position is 0 and every face (0, 0, 0), with only a log line: `stepterrain info` printed its bounds as
    (0, 0, 0) and st.stepped refused faces "with three distinct vertices". A required meshopt compression read the
    compressed bytes. read_mesh refuses both, naming the extension (and DracoPy for Draco)."""
    import importlib.util
    import struct

    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "DracoPy" else real_find_spec(name, *a))
    primitive = {"attributes": {"POSITION": 0}, "indices": 1}
    if extension.startswith("KHR_draco"):
        primitive["extensions"] = {extension: {"bufferView": 0, "attributes": {"POSITION": 0}}}
    tree = {"asset": {"version": "2.0"}, "extensionsUsed": [extension], "extensionsRequired": [extension],
            "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [primitive]}],
            "accessors": [{"componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1.5]},
                          {"componentType": 5123, "count": 6, "type": "SCALAR"}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 16}], "buffers": [{"byteLength": 16}]}
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    (tmp_path / "packed.glb").write_bytes(struct.pack("<III", 0x46546C67, 2, 28 + len(text) + 16)
                                          + struct.pack("<II", len(text), 0x4E4F534A) + text
                                          + struct.pack("<II", 16, 0x004E4942) + bytes(16))
    with pytest.raises(DataFileError, match=rf"cannot read '.*packed\.glb' as a mesh: ValueError: {message}"):
        read_mesh(tmp_path / "packed.glb")


@pytest.mark.parametrize("index", [9, -1])
def test_a_ply_face_naming_a_vertex_the_file_lacks_is_refused(tmp_path, capsys, index):
    """A PLY face naming vertex 9 of 3 (or -1: a corrupt or hand-edited file) read as it was: `stepterrain info`
    described it as a mesh of 2 faces with exit status 0, and only stepping or saving it refused it. (trimesh's OBJ
    reader already raised an IndexError.) read_mesh refuses it, naming the face, the vertex and the count."""
    header = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 2\nproperty list uchar int vertex_indices\nend_header\n")
    (tmp_path / "bad.ply").write_text(header + f"0 0 0\n1 0 0\n1 1 1\n3 0 1 2\n3 0 2 {index}\n")
    (tmp_path / "good.ply").write_text(header + "0 0 0\n1 0 0\n1 1 1\n3 0 1 2\n3 0 2 1\n")
    assert read_mesh(tmp_path / "good.ply").faces.tolist() == [[0, 1, 2], [0, 2, 1]]
    with pytest.raises(DataFileError, match=rf"cannot read '.*bad\.ply' as a mesh: ValueError: face 1 names vertex "
                                            rf"{index}, and the file has 3 vertices$"):
        read_mesh(tmp_path / "bad.ply")
    assert cli.main(["info", str(tmp_path / "bad.ply")]) == 2
    assert f"face 1 names vertex {index}" in capsys.readouterr().err


def test_a_gltf_that_is_not_json_is_refused_saying_what_it_is(tmp_path):
    """trimesh's reader answered a .gltf that is not JSON (random bytes, text) and a GLB named .gltf with
    "FileNotFoundError: model.gltf", naming a file nobody had. read_mesh now says the file is not a glTF (the JSON
    error) or is a GLB under .gltf (rename it .glb); a real .gltf still reads."""
    box = trimesh.creation.box()
    (tmp_path / "real.gltf").write_bytes(trimesh.exchange.gltf.export_gltf(box.scene(), embed_buffers=True)
                                         ["model.gltf"])
    assert len(read_mesh(tmp_path / "real.gltf").faces) == 12
    not_json = r"not a glTF file: its JSON does not parse"
    cases = {"noise.gltf": (bytes(range(200, 256)) * 4, not_json + r" \(UnicodeDecodeError"),
             "text.gltf": (b"hello world\n", not_json + r" \(JSONDecodeError"),
             "binary.gltf": (trimesh.exchange.gltf.export_glb(box.scene()),
                             r"a GLB \(binary glTF: it starts with b'glTF'\) under the extension \.gltf, which names "
                             r"the JSON form: rename it \.glb$")}
    for name, (data, message) in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(DataFileError, match=rf"cannot read '.*{name}' as a mesh: ValueError: {message}"):
            read_mesh(tmp_path / name)


@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj", ".ply", ".stl", ".3mf"])
def test_a_mesh_whose_write_is_over_the_memory_budget_is_refused_before_any_work(ext, tmp_path, monkeypatch):
    """save_mesh had no memory-budget check, while its writers' copies grow with the mesh (measured peak RSS beyond
    the mesh: a 956 MiB stepped mesh took 560 MiB more as .glb, 690 as .obj; a 9 M-face one 2.4 GiB as .stl): a
    write could take gigabytes past st.set_memory_budget. It is now refused before any work, naming the file, the
    mesh's size and formats that need less, and writes nothing; a mesh within the budget is written as before."""
    import stepterrain as st
    from stepterrain import export
    from stepterrain.errors import OutputTooLargeError

    def no_work(*args, **kwargs):
        raise AssertionError("the write started: its memory was not checked against the budget first")

    mesh = trimesh.creation.icosphere(subdivisions=5)  # 20,480 faces, 10,242 vertices
    per_vertex, per_face = export._WRITE_BYTES[ext]
    need = per_vertex * len(mesh.vertices) + per_face * len(mesh.faces)
    previous = st.set_memory_budget(need - 1)
    try:
        monkeypatch.setattr(export, "_prepared_mesh", no_work)
        with pytest.raises(OutputTooLargeError, match=rf"^writing '.*m\{ext}' \({ext}, a mesh of 20,480 faces and "
                                                      r"10,242 vertices\) would need .* over the memory budget of .*; "
                                                      r"write a mesh of fewer faces"):
            export.save_mesh(mesh, tmp_path / f"m{ext}")
        assert list(tmp_path.iterdir()) == []
        monkeypatch.undo()
        st.set_memory_budget(need)
        out = export.save_mesh(mesh, tmp_path / f"m{ext}")
        assert len(trimesh.load(out, force="mesh").faces) == len(mesh.faces)
    finally:
        st.set_memory_budget(previous)


def test_a_ply_write_in_float64_takes_no_more_than_its_budget_check_counts(tmp_path):
    """PLY's write bytes were measured when it wrote float32 coordinates; it writes float64 wherever float32 would
    round them, holding the float64 vertices, the float32 try and the float64 columns at once: an unmerged mesh
    (3 vertices a face) with vertex colours took ~50 % more than the budget check counted. Its peak (tracemalloc)
    is now within the count."""
    import tracemalloc

    from stepterrain import export

    mesh = trimesh.creation.icosphere(subdivisions=5)
    mesh.unmerge_vertices()
    mesh.vertices = mesh.vertices * 1000.0 + 0.123  # float32 rounds them: written as float64
    mesh.visual.vertex_colors = np.full((len(mesh.vertices), 4), 200, np.uint8)
    per_vertex, per_face = export._WRITE_BYTES[".ply"]
    tracemalloc.start()
    try:
        out = export.save_mesh(mesh, tmp_path / "m.ply")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert b"property double x" in out.read_bytes()[:1000]
    assert peak <= per_vertex * len(mesh.vertices) + per_face * len(mesh.faces)


def test_face_colours_count_against_the_write_budget(tmp_path):
    """glTF and OBJ have no per-face colour and write each vertex as the mean of its faces' colours: ~340 bytes a
    face more measured (1.3 GiB on a 3.9 M-face mesh), checked too."""
    import stepterrain as st
    from stepterrain import export
    from stepterrain.errors import OutputTooLargeError

    mesh = trimesh.creation.icosphere(subdivisions=4)
    per_vertex, per_face = export._WRITE_BYTES[".glb"]
    previous = st.set_memory_budget(2 * (per_vertex * len(mesh.vertices) + per_face * len(mesh.faces)))
    try:
        export.save_mesh(mesh, tmp_path / "plain.glb")
        mesh.visual.face_colors = np.full((len(mesh.faces), 4), 200, np.uint8)
        with pytest.raises(OutputTooLargeError, match=r"vertices with face colours\) would need"):
            export.save_mesh(mesh, tmp_path / "coloured.glb")
    finally:
        st.set_memory_budget(previous)


def _gltf_tree(path) -> dict:
    data = path.read_bytes()
    if data[:4] == b"glTF":
        data = data[20 : 20 + int.from_bytes(data[12:16], "little")]
    return json.loads(data)


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("kind", ["plain", "large", "textured", "large textured", "points"])
def test_a_gltf_world_is_y_up_and_reads_back_z_up_exactly(tmp_path, ext, kind):
    # glTF 2.0 §3.4: +Y up. The node held the z-up positions unturned: Blender (y-up to its z-up) showed the terrain
    # standing on its edge, three.js and model-viewer orbited it about the wrong axis
    z = np.add.outer(np.arange(5.0), np.arange(6.0) ** 1.5) * 10.0 + 0.123
    origin = (376328.655, 3807902.827) if "large" in kind else (0.0, 0.0)
    mesh = st.heightfield_mesh(z, spacing=(30.0, -30.0), origin=origin)  # row 0 to the north
    if "textured" in kind:
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((len(mesh.vertices), 2)),
                                                    image=Image.new("RGB", (4, 4), "red"))  # fmt: skip
    if kind == "points":
        mesh = trimesh.Trimesh(mesh.vertices, np.zeros((0, 3), np.int64), process=False)
    out = save_mesh(mesh, tmp_path / f"t{ext}")
    (node,) = _gltf_tree(out)["nodes"]
    s = float(np.sqrt(0.5))
    if "textured" in kind:  # trimesh's writer: the same turn and translation as a matrix (column-major)
        matrix = np.array(node["matrix"]).reshape(4, 4).T
        rotation, translation = matrix[:3, :3], matrix[:3, 3]
        assert np.array_equal(rotation, [[1, 0, 0], [0, 0, 1], [0, -1, 0]])
    else:
        assert node["rotation"] == [-s, 0.0, 0.0, s]
        translation = np.array(node.get("translation", [0.0, 0.0, 0.0]))
    lo = mesh.vertices.min(axis=0)
    hi = mesh.vertices.max(axis=0)
    if "large" in kind:  # the local origin (floor of the centre) in the world frame: (ox, oz, -oy)
        offset = np.floor(lo / 2 + hi / 2)
        assert translation.tolist() == [offset[0], offset[2], -offset[1]]
    else:
        offset = np.zeros(3)
        assert translation.tolist() == [0.0, 0.0, 0.0]
    # the file as a viewer sees it: heights along +Y, north (+y) along -Z
    world = np.asarray(trimesh.load(out, process=False).to_geometry().vertices)
    expected = (np.asarray(mesh.vertices) - offset).astype(np.float32).astype(np.float64) + offset
    np.testing.assert_allclose(world, expected[:, [0, 2, 1]] * [1, 1, -1], rtol=0, atol=1e-6)
    assert world[:, 1].max() == pytest.approx(z.max(), abs=1e-3)
    assert world[:, 1].min() == pytest.approx(z.min(), abs=1e-3)
    north = np.argmax(mesh.vertices[:, 1])
    assert world[north, 2] == world[:, 2].min()
    # read_mesh undoes the turn: the vertices as written, bit for bit (float32 relative to the local origin)
    back = read_mesh(out)
    assert np.array_equal(np.asarray(back.vertices), expected)
    if "textured" not in kind and kind != "points":
        assert len(back.faces) == len(mesh.faces) and st.Terrain.from_mesh(back).kind == "tin"


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_a_y_up_gltf_from_another_tool_reads_z_up_and_steps(tmp_path, ext):
    # Blender's and three.js' glTF exports hold y up (glTF 2.0 §3.4); read_mesh gave them as stored, and a terrain from
    # one was refused as folding over in xy
    z = np.add.outer(np.arange(8.0), np.arange(9.0)) * 5.0 + np.random.default_rng(1).random((8, 9))
    terrain = st.heightfield_mesh(z, spacing=(10.0, -10.0), origin=(100.0, 200.0))
    y_up = terrain.copy()
    y_up.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))  # (x, y, z) -> (x, z, -y)
    assert np.allclose(y_up.vertices[:, 1], terrain.vertices[:, 2])
    out = tmp_path / f"blender{ext}"
    trimesh.Scene(y_up).export(out)  # a y-up scene, no node rotation
    back = read_mesh(out)
    np.testing.assert_allclose(back.vertices, terrain.vertices, rtol=0, atol=1e-4)
    steps = st.stepped(st.Terrain.from_mesh(back), interval=10.0)
    assert len(steps.faces) and np.ptp(steps.vertices[:, 2]) > 20.0


def test_a_stepterrain_gltf_written_before_the_turn_still_reads_z_up(tmp_path):
    # stepterrain's glTF files held z up before they were turned y-up: generator "stepterrain" and no node rotation;
    # read_mesh reads them as they were written, not turned
    z = np.add.outer(np.arange(4.0), np.arange(5.0)) * 3.0
    mesh = st.heightfield_mesh(z, spacing=(2.0, -2.0))
    out = save_mesh(mesh, tmp_path / "old.gltf")
    tree = json.loads(out.read_text())
    del tree["nodes"][0]["rotation"]  # as the old writer wrote it
    out.write_text(json.dumps(tree))
    assert np.array_equal(read_mesh(out).vertices, mesh.vertices)


@pytest.mark.parametrize("large", [False, True])
def test_a_textured_stepterrain_gltf_written_before_the_turn_still_reads_z_up(tmp_path, large):
    # a textured mesh (stepterrain texture --mesh, globe --texture) was written by trimesh's writer, generator trimesh,
    # its node's matrix a translation at most, and the CLI's metadata (generator "stepterrain ...") in the mesh's
    # extras: read_mesh turned such a file as a y-up one, the terrain on its edge (heights along -y)
    z = 10.0 + np.add.outer(np.arange(4.0), np.sin(np.arange(5.0))) * 0.5
    mesh = st.heightfield_mesh(z, spacing=(2.0, -2.0), origin=(500000.0, 4000000.0) if large else (0.0, 0.0))
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((len(mesh.vertices), 2)),
                                                image=Image.new("RGB", (4, 4), (200, 100, 50)))
    mesh.metadata["generator"] = "stepterrain texture"
    out = save_mesh(mesh, tmp_path / "old.gltf")
    tree = json.loads(out.read_text())
    node = tree["nodes"][0]
    assert tree["asset"]["generator"] != "stepterrain"
    assert tree["meshes"][0]["extras"]["generator"] == "stepterrain texture"
    turn = np.asarray(node.pop("matrix")).reshape(4, 4).T
    if large:  # as the old writer wrote it: the same positions, the offset untouched by any turn
        old = np.eye(4)
        old[:3, 3] = turn[:3, :3].T @ turn[:3, 3]
        node["matrix"] = old.T.reshape(-1).tolist()
    out.write_text(json.dumps(tree))
    back = read_mesh(out)
    assert np.ptp(back.vertices[:, 2]) == pytest.approx(np.ptp(mesh.vertices[:, 2]))  # heights along z
    np.testing.assert_allclose(back.vertices, mesh.vertices, rtol=0, atol=1e-6)
    # the same file without stepterrain's metadata (trimesh's own export of a z-up mesh) is y-up by glTF's spec
    del tree["meshes"][0]["extras"]["generator"]
    out.write_text(json.dumps(tree))
    assert np.ptp(read_mesh(out).vertices[:, 1]) == pytest.approx(np.ptp(mesh.vertices[:, 2]))
    # a stepterrain glTF that trimesh loaded as one mesh (its y-up world) and wrote again keeps the metadata, but
    # no node matrix: y-up, read turned
    again = trimesh.load(save_mesh(mesh, tmp_path / "new.glb"), force="mesh", process=False)
    assert again.metadata["generator"] == "stepterrain texture"
    again.export(tmp_path / "again.glb")
    np.testing.assert_allclose(read_mesh(tmp_path / "again.glb").vertices, mesh.vertices, rtol=0, atol=1e-3)


def test_read_mesh_gives_a_plys_boolean_attributes_back_as_bool(tmp_path):
    """PLY has no boolean type, so save_mesh writes stepped's ``wall`` (and any bool attribute) as uchar, and
    read_mesh gave it back as uint8: ``mesh.faces[back.face_attributes["wall"]]`` took rows 0 and 1 over and over
    instead of the walls. The header now names the columns written from bools (a comment readers skip), and read_mesh
    turns them back; a file written before that, by stepterrain, gets its 0/1 ``wall`` back as bool."""
    mesh = st.stepped(np.add.outer(np.arange(12.0), np.arange(10.0)) * 3.0, interval=7.0, spacing=(10.0, -10.0))
    wall = mesh.face_attributes["wall"]
    assert wall.dtype == bool and 0 < wall.sum() < len(wall)
    mesh.vertex_attributes["odd"] = np.arange(len(mesh.vertices)) % 2 == 1
    mesh.face_attributes["flags"] = np.stack([wall, ~wall], axis=1)
    out = save_mesh(mesh, tmp_path / "steps.ply")
    assert b"property uchar wall" in out.read_bytes()[:2000]  # readers that do not know the comment see 0/1
    for back in (read_mesh(out), read_mesh(save_mesh(read_mesh(out), tmp_path / "again.ply"))):
        assert back.face_attributes["wall"].dtype == bool
        np.testing.assert_array_equal(back.face_attributes["wall"], wall)
        np.testing.assert_array_equal(back.faces[back.face_attributes["wall"]], mesh.faces[wall])
        assert back.vertex_attributes["odd"].dtype == bool
        np.testing.assert_array_equal(back.vertex_attributes["odd"], mesh.vertex_attributes["odd"])
        assert back.face_attributes["flags_1"].dtype == bool
        np.testing.assert_array_equal(back.face_attributes["flags_1"], ~wall)
        assert back.face_attributes["level"].dtype == np.int32
    # a PLY stepterrain wrote before: no such comment, its 0/1 wall is stepped's flag; other uchar columns stay
    data = out.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    old = b"\n".join(line for line in head.split(b"\n") if b"stepterrain-bool" not in line) + b"end_header\n" + body
    (tmp_path / "old.ply").write_bytes(old)
    back = read_mesh(tmp_path / "old.ply")
    assert back.face_attributes["wall"].dtype == bool
    np.testing.assert_array_equal(back.face_attributes["wall"], wall)
    assert back.vertex_attributes["odd"].dtype == np.uint8
    # a bool named like trimesh's texture comment is not named in one (trimesh looked for an image): it stays uchar
    mesh.face_attributes["TextureFile"] = wall
    named = save_mesh(mesh, tmp_path / "named.ply")
    assert b"TextureFile" not in b"".join(line for line in named.read_bytes()[:4000].split(b"\n")
                                          if line.startswith(b"comment"))
    back = read_mesh(named)
    assert back.face_attributes["TextureFile"].dtype == np.uint8 and back.face_attributes["wall"].dtype == bool
    # a uint8 attribute of 0/1 written as such stays uint8, wall or not
    box = trimesh.creation.box()
    box.face_attributes.update(wall=(np.arange(12) % 2).astype(np.uint8), mark=(np.arange(12) % 2).astype(np.uint8))
    back = read_mesh(save_mesh(box, tmp_path / "box.ply"))
    assert back.face_attributes["wall"].dtype == back.face_attributes["mark"].dtype == np.uint8


def test_a_ply_written_today_without_bools_keeps_a_uint8_wall_beside_a_level(tmp_path):
    """A PLY save_mesh writes with no bool attribute had no ``comment stepterrain-bool`` line, so read_mesh took it
    for one written before those lines and gave a uint8 0/1 ``wall`` beside a ``level`` back as bool. The header
    now always carries the marker (bare without bools); only a file of ours without it is legacy."""
    box = trimesh.creation.box()
    wall = (np.arange(12) % 2).astype(np.uint8)
    box.face_attributes.update(wall=wall, level=np.arange(12, dtype=np.int32))
    out = save_mesh(box, tmp_path / "box.ply")
    assert b"comment stepterrain-bool\n" in out.read_bytes()[:2000]
    back = read_mesh(out)
    assert back.face_attributes["wall"].dtype == np.uint8
    np.testing.assert_array_equal(back.face_attributes["wall"], wall)
    # the same file without the marker is one stepterrain wrote before: its 0/1 wall beside a level is stepped's
    head, body = out.read_bytes().split(b"end_header\n", 1)
    old = b"\n".join(line for line in head.split(b"\n") if b"stepterrain-bool" not in line) + b"end_header\n" + body
    (tmp_path / "old.ply").write_bytes(old)
    assert read_mesh(tmp_path / "old.ply").face_attributes["wall"].dtype == bool


def test_a_tin_closeup_or_adaptive_mesh_of_a_dem_names_its_crs_in_the_file_and_steps_with_it(tmp_path, capsys):
    """stepped's mesh records the DEM's CRS and source, so the files it is written to name them, but the other meshes
    of a DEM in UTM did not: dem.mesh() (``stepterrain texture --mesh`` drapes it), adaptive_mesh(dem) and
    closeup_scene(dem, ...) were written without a CRS (``stepterrain info`` showed UTM bounds in no CRS), and the
    stepped mesh of a TIN read back from a file that names its CRS named none."""
    dem = st.Terrain.from_heights(np.add.outer(np.arange(17.0), np.sin(np.arange(17.0))) * 10.0, spacing=(30.0, -30.0),
                                  origin=(390000.0, 3800000.0), crs="EPSG:32611", source="dem.tif")
    placed = {"crs": "EPSG:32611", "source": "dem.tif"}
    cu = st.CloseUp(st.ROI.circle((390240.0, 3799760.0), 100.0), scale=1.5, offset=(0, 0, 300))
    tin = dataclasses.replace(st.Terrain.from_mesh(dem.mesh()), crs="EPSG:32611", source="t.ply")
    assert {k: tin.mesh().metadata[k] for k in placed} == {"crs": "EPSG:32611", "source": "t.ply"}
    for mesh in (dem.mesh(), st.adaptive_mesh(dem, error=1.0), st.closeup_scene(dem, [cu])):
        assert {k: mesh.metadata.get(k) for k in placed} == placed
        for ext in (".glb", ".ply"):
            out = save_mesh(mesh, tmp_path / f"m{ext}")
            assert cli.main(["info", str(out), "--json"]) == 0
            assert json.loads(capsys.readouterr().out)["meta.crs"] == "EPSG:32611"
            if "closeups" not in mesh.metadata:  # a TIN: its steps name the CRS and source the file names
                steps = st.stepped(read_mesh(out), interval=20.0)
                assert {k: steps.metadata.get(k) for k in placed} == placed
    assert "crs" not in st.stepped(st.heightfield_mesh(np.eye(3)), interval=0.5).metadata  # none where none is known


def test_a_ply_keeps_coordinates_below_65536_that_float32_rounds(tmp_path):
    """A PLY stored coordinates up to 65536 as float32, so local metres such as 60000.123 came back up to 1/256 off
    (1.9 mm here), though save_mesh's Notes say .ply keeps float64 and the STL warning, for this very rounding,
    said to write .ply to keep it. Such a mesh is now written as float64; one float32 holds exactly (a grid of
    integer spacing and float32 heights) stays float32, half the size: tiles of a set still weld, a float32 tile
    holding its shared vertices exactly, as the float64 tile beside it does."""
    mesh = st.heightfield_mesh(np.random.default_rng(0).random((6, 7)) * 10, spacing=(30.3, -30.7),
                               origin=(60000.123, 50000.456))
    with pytest.warns(UserWarning, match=r"write \.ply, \.obj or \.3mf to keep float64"):
        save_mesh(mesh, tmp_path / "m.stl")
    out = save_mesh(mesh, tmp_path / "m.ply")
    assert b"property double x" in out.read_bytes()[:1000]
    np.testing.assert_array_equal(read_mesh(out).vertices, mesh.vertices)
    exact = st.heightfield_mesh(np.add.outer(np.arange(8.0), np.arange(9.0)).astype(np.float32) * np.float32(1.7),
                                spacing=(30.0, -30.0), origin=(1000.0, 2000.0))
    out = save_mesh(exact, tmp_path / "exact.ply")
    assert b"property float x" in out.read_bytes()[:1000]
    np.testing.assert_array_equal(read_mesh(out).vertices, exact.vertices)


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_a_bad_texture_wrap_is_refused_before_any_folder_is_made(ext, tmp_path):
    """A textured mesh's material.wrap (its glTF sampler) was checked inside the glTF writer, after atomic_path had
    made the target's missing folders: save_mesh refused ('REPEAT', 'MIRROR') but left an empty folder behind. It is
    checked with the texture's image, before anything is made."""
    mesh = trimesh.creation.box()
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(np.zeros((4, 4, 3), np.uint8)))
    material.wrap = ("REPEAT", "MIRROR")
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.full((len(mesh.vertices), 2), 0.5), material=material)
    with pytest.raises(InvalidInputError, match=r"material.wrap must be two of .*got \('REPEAT', 'MIRROR'\)"):
        save_mesh(mesh, tmp_path / "new" / "deeper" / f"m{ext}")
    assert list(tmp_path.iterdir()) == []
    material.wrap = ("REPEAT", "CLAMP_TO_EDGE")  # a good one is written as before
    assert save_mesh(mesh, tmp_path / "new" / f"m{ext}").is_file()


@pytest.mark.parametrize("ext,textured", [(".glb", False), (".gltf", False), (".glb", True)],
                         ids=["glb", "gltf", "textured_glb"])
def test_save_mesh_origin_is_the_gltf_node_translation(tmp_path, ext, textured):
    """glTF positions were stored relative to the floor of the centre of the bounds only: a view of a globe spans
    thousands of km, so the vertices near its eye were rounded to float32 steps of that reach (0.25 m on the earth).
    ``origin`` is the node translation (floored): each vertex read back within float32's rounding of its own distance
    from it, by the direct writer and by trimesh's (a textured mesh) alike."""
    earth = trimesh.creation.icosphere(subdivisions=4, radius=6_371_000.0)
    eye = earth.vertices[0] * (1.0 + 1e-5) + [0.3, -0.7, 0.45]  # 64 m above a vertex, not on whole metres
    if textured:
        uv = np.random.default_rng(0).random((len(earth.vertices), 2))
        earth.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (4, 4), (200, 120, 40)))
    out = save_mesh(earth, tmp_path / f"earth{ext}", origin=eye)
    back = np.asarray(read_mesh(out).vertices, dtype=np.float64)
    exact = np.asarray(earth.vertices, dtype=np.float64)
    distance = np.linalg.norm(exact - eye, axis=1)
    error = np.linalg.norm(back - exact, axis=1)
    assert error[0] <= 1e-5  # 64 m from the eye (float32 steps of 4 µm there): 0.2 m off relative to the centre
    assert (error <= 2.0**-23 * (distance + 2.0)).all(), float((error / distance).max())
    tree = json.loads(out.read_text()) if ext == ".gltf" else None
    if tree is not None:  # the eye's floor in glTF's y-up world: (ox, oz, -oy)
        o = np.floor(eye)
        assert tree["nodes"][0]["translation"] == [o[0], o[2], -o[1]]


@pytest.mark.parametrize("origin", [[0, 0, np.nan], [1, 2], "abc", [True, 0, 0], [10**400, 0, 0]])
def test_save_mesh_origin_is_checked(tmp_path, origin):
    with pytest.raises(InvalidInputError, match=r"^origin must be 3 finite numbers \(x, y, z\); got"):
        save_mesh(trimesh.creation.box(), tmp_path / "box.glb", origin=origin)
    assert list(tmp_path.iterdir()) == []


def test_save_mesh_origin_beyond_float32_is_refused(tmp_path):
    with pytest.raises(InvalidInputError, match=r"float32 coordinates relative to the origin.*reaches 1e\+39 from it"):
        save_mesh(trimesh.creation.box(), tmp_path / "box.glb", origin=[1e39, 0, 0])
    assert list(tmp_path.iterdir()) == []
    save_mesh(trimesh.creation.box(), tmp_path / "box.ply", origin=[1e39, 0, 0])  # PLY stores them as they are


@pytest.mark.skipif(os.name != "posix", reason="a file size limit (RLIMIT_FSIZE) makes the write fail for real")
def test_a_geotiff_write_that_fails_names_gdals_reason_not_a_previous_exception(tmp_path):
    """A GeoTIFF texture whose write failed (a full disk; here a file size limit, for real) was refused as
    "cannot write ...: Write failed. See previous exception for details.": rasterio's words, pointing at an exception
    no message showed. GDAL's own error, the cause of rasterio's, is named now, and no file is left."""
    import subprocess
    import sys

    pytest.importorskip("rasterio")
    script = f"""
import resource, signal
import numpy as np
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails with EFBIG instead of killing the process
from stepterrain.export import save_image
from stepterrain.errors import DataFileError
image = (np.random.default_rng(0).random((300, 300, 3)) * 255).astype(np.uint8)
soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)  # a runner's finite hard limit cannot be raised to infinity
resource.setrlimit(resource.RLIMIT_FSIZE, (20000, hard))
try:
    save_image(image, {str(tmp_path / "shade.tif")!r}, extent=(0, 300, 0, 300), crs="EPSG:32611")
except DataFileError as exc:
    print("REFUSED", exc)
finally:  # what the process writes at its exit (a coverage data file) is not cut short
    resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    said = [line for line in done.stdout.splitlines() if line.startswith("REFUSED")]
    assert len(said) == 1, (done.stdout, done.stderr)
    assert "cannot write" in said[0] and "shade.tif" in said[0] and "Write error" in said[0]
    assert "previous exception" not in said[0]
    assert list(tmp_path.iterdir()) == []  # atomic: neither the target nor its temporary file


@pytest.mark.parametrize("where", ["name", "material"])
def test_a_name_ending_in_a_backslash_does_not_continue_the_obj_line(tmp_path, where):
    """The OBJ's ``o`` line carried the metadata's name, ``usemtl`` (and the MTL's ``newmtl``) the material's, as
    they were: a trailing backslash (a Windows folder, ``C:\\dem\\``) continues the line in OBJ readers, so the
    first ``v`` line became part of the name and every face named the vertex after its own; read_mesh and
    trimesh.load raised an IndexError for the last. Trailing backslashes are now ``_``, and the name read back from
    the metadata comment is still the one written."""
    mesh = trimesh.creation.box()
    name = "C:\\dem\\"
    if where == "material":
        material = trimesh.visual.material.PBRMaterial(name=name, baseColorTexture=Image.new("RGB", (4, 4)))
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)), material=material)
        obj = save_mesh(mesh, tmp_path / "t.obj")
        assert "newmtl C:\\dem_" in (tmp_path / "t.mtl").read_text().splitlines()
    else:
        obj = save_mesh(mesh, tmp_path / "t.obj", metadata={"name": name})
    assert not any(line.endswith("\\") for line in obj.read_text().splitlines())
    for back in (read_mesh(obj), trimesh.load(obj, force="mesh", process=False, maintain_order=True)):
        np.testing.assert_array_equal(back.vertices, mesh.vertices)
        np.testing.assert_array_equal(back.faces, mesh.faces)
    if where == "name":
        assert read_mesh(obj).metadata["name"] == name


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_read_mesh_gives_a_gltfs_metadata_name_back(tmp_path, ext):
    """save_mesh stores the metadata in the glTF mesh's extras, and read_mesh gives it back (as PLY, OBJ and 3MF
    do), but trimesh's reader puts the mesh's own name (the file's stem) over the extras' ``name``: a name given as
    metadata came back as "stem", and a mesh read and written again kept that."""
    mesh = trimesh.creation.box()
    out = save_mesh(mesh, tmp_path / f"stem{ext}", metadata={"name": "Big Tujunga", "crs": "EPSG:32611"})
    back = read_mesh(out)
    assert back.metadata["name"] == "Big Tujunga" and back.metadata["crs"] == "EPSG:32611"
    again = read_mesh(save_mesh(back, tmp_path / f"again{ext}"))
    assert again.metadata["name"] == "Big Tujunga"
    np.testing.assert_allclose(again.vertices, mesh.vertices, atol=1e-6)


def test_obj_vertex_colours_read_back_as_the_same_bytes_by_vtk_and_trimesh(tmp_path):
    """An OBJ's ``v x y z r g b`` colours were c / 255 to 8 decimals, which lie below c / 255 for about half of the
    bytes (217 / 255 = 0.850980392... written as 0.85098039): VTK's reader (pyvista.read) truncates their value times
    255, so those came back one less. Rounded up, every byte reads back as written by truncating and rounding
    readers alike."""
    pv = pytest.importorskip("pyvista")
    levels = np.arange(256, dtype=np.uint8)
    vertices = np.column_stack([np.arange(256.0), np.zeros(256), np.zeros(256)])
    faces = np.array([[0, 1, 2]])
    colors = np.column_stack([levels, levels[::-1], np.roll(levels, 85), np.full(256, 255, np.uint8)])
    mesh = trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)
    obj = save_mesh(mesh, tmp_path / "c.obj")
    np.testing.assert_array_equal(np.asarray(pv.read(obj).point_data["RGB"]), colors[:, :3])
    np.testing.assert_array_equal(read_mesh(obj).visual.vertex_colors, colors)


def _read_only_for_this_user(monkeypatch, *protected: os.PathLike[str]) -> None:
    """What os.access answers a user other than root for files whose write bits are off (root may write any file)."""
    real_access = os.access
    names = {os.path.abspath(p) for p in protected}

    def access(path, mode, *args, **kwargs):
        if mode & os.W_OK and os.path.abspath(path) in names:
            return False
        return real_access(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)


@pytest.mark.parametrize("ext", [".ply", ".glb", ".png", ".obj-side"])
def test_a_read_only_file_is_refused_not_replaced(tmp_path, monkeypatch, ext):
    """A user who write-protected a delivered mesh (chmod a-w) had it replaced without a word: the rename into place
    needs only the folder's permission, where ``open(path, "w")``, a GIS tool or ``cp`` refuse the file. Refused now,
    and the file, its mode and (for a textured OBJ's read-only .mtl) the OBJ itself are kept."""
    textured = trimesh.creation.box()
    textured.visual = trimesh.visual.TextureVisuals(uv=np.random.default_rng(0).random((8, 2)),
                                                    image=Image.new("RGB", (2, 2), (200, 10, 10)))  # fmt: skip
    if ext == ".png":
        path, protected = tmp_path / "i.png", tmp_path / "i.png"
        write = lambda: save_image(np.zeros((2, 2, 3), np.uint8), path)  # noqa: E731
    elif ext == ".obj-side":
        path, protected = tmp_path / "m.obj", tmp_path / "m.mtl"
        write = lambda: save_mesh(textured, path)  # noqa: E731
    else:
        path, protected = tmp_path / f"m{ext}", tmp_path / f"m{ext}"
        write = lambda: save_mesh(trimesh.creation.box(), path)  # noqa: E731
    write()
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    protected.chmod(0o444)
    _read_only_for_this_user(monkeypatch, protected)
    textured.vertices = textured.vertices * 2.0
    with pytest.raises(DataFileError, match=rf"cannot write '.*{protected.name}': the file exists and is read-only"):
        if ext == ".png":
            save_image(np.full((2, 2, 3), 9, np.uint8), path)
        else:
            save_mesh(textured if ext == ".obj-side" else trimesh.creation.icosphere(), path)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # no temporary file left either
    assert protected.stat().st_mode & 0o777 == 0o444


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root may write a read-only file")
def test_a_read_only_file_is_refused_by_its_permission_bits(tmp_path):
    path = save_mesh(trimesh.creation.box(), tmp_path / "m.ply")
    before = path.read_bytes()
    path.chmod(0o444)
    with pytest.raises(DataFileError, match="the file exists and is read-only"):
        save_mesh(trimesh.creation.icosphere(), path)
    assert path.read_bytes() == before


def test_a_command_refuses_a_read_only_output_before_any_work(tmp_path, monkeypatch, capsys):
    out = save_mesh(trimesh.creation.box(), tmp_path / "globe.ply")
    before = out.read_bytes()
    _read_only_for_this_user(monkeypatch, out)
    monkeypatch.setattr("stepterrain.globe.Globe.from_latlon",
                        lambda *a, **k: pytest.fail("the globe was built for an output it cannot write"))
    assert cli.main(["globe", "--face-size", "9", "--no-camera", "-o", str(out)]) == 2
    assert "--output" in (err := capsys.readouterr().err) and "read-only" in err
    assert out.read_bytes() == before


def test_recorded_shared_bounds_decide_the_storage_only_while_they_hold_the_mesh(tmp_path):
    """save_mesh stores a mesh by the shared bounds it records (Globe.mesh's per-face meshes) like given ones; a mesh
    moved since, out of them, is stored by its own bounds: its float32 positions about its own centre, not rounded at
    the distance of the stale ones. So is a small piece within them (a mesh cut from a member of the set), which
    about their centre would round far worse than about its own."""
    box = trimesh.creation.box()
    box.vertices = box.vertices * 0.125 + (1.0e6 + 1 / 3, 2.0e6, 0.0)
    exact = read_mesh(save_mesh(box, tmp_path / "plain.glb")).vertices
    np.testing.assert_allclose(exact, box.vertices, rtol=0, atol=1e-6)
    box.metadata["shared_bounds"] = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]  # stale: the box lies far outside
    np.testing.assert_array_equal(read_mesh(save_mesh(box, tmp_path / "stale.glb")).vertices, exact)
    box.metadata["shared_bounds"] = [[-3.0e6, -3.0e6, -3.0e6], [3.0e6, 3.0e6, 3.0e6]]  # holding a small piece
    np.testing.assert_array_equal(read_mesh(save_mesh(box, tmp_path / "piece.glb")).vertices, exact)
    box.vertices = (box.vertices - box.vertices.mean(axis=0)) * 2.4e7 + (1.0e6 + 1 / 3, 0.5e6, 0.0)  # 3000 km
    own = read_mesh(save_mesh(trimesh.Trimesh(box.vertices, box.faces), tmp_path / "own.glb")).vertices
    about_zero = read_mesh(save_mesh(box, tmp_path / "shared.glb")).vertices  # a member of the set: stored about 0
    as_given = read_mesh(save_mesh(box, tmp_path / "given.glb", shared_bounds=box.metadata["shared_bounds"])).vertices
    np.testing.assert_array_equal(about_zero, as_given)
    assert (about_zero != own).any()


def test_a_piece_cut_from_a_per_face_mesh_is_not_stored_about_the_eye_of_the_whole_face(tmp_path):
    """A piece of a per-face globe mesh with a camera (``submesh``: trimesh copies the metadata, its ``eye`` and
    ``shared_bounds``) is stored by its own bounds, as the shared bounds would round it far worse; but the eye was
    still taken as its glTF origin while within one diagonal of those shared bounds (the whole globe's): a 1 km piece
    400 km from the eye was stored relative to the eye, its vertices rounded by 1 cm instead of 10 µm about its own
    centre. The eye is checked against the bounds the mesh is stored by, as for a mesh recording none."""
    box = trimesh.creation.box()
    box.vertices = box.vertices * 1000.0 + (6.4e6 + 1 / 3, 1 / 7, 0.0)
    own = read_mesh(save_mesh(trimesh.Trimesh(box.vertices, box.faces), tmp_path / "own.glb")).vertices
    box.metadata["eye"] = [6.4e6 + 4.0e5, 0.0, 0.0]
    np.testing.assert_array_equal(read_mesh(save_mesh(box, tmp_path / "eye.glb")).vertices, own)  # eye too far
    box.metadata["shared_bounds"] = [[-6.5e6] * 3, [6.5e6] * 3]  # a piece of a face of the globe's set
    piece = read_mesh(save_mesh(box, tmp_path / "piece.glb")).vertices
    np.testing.assert_array_equal(piece, own)
    np.testing.assert_allclose(piece, box.vertices, rtol=0, atol=1e-4)


@pytest.mark.skipif(os.name == "nt" or os.fsencode("\udcf6") != b"\xf6", reason="needs byte file names (POSIX)")
@pytest.mark.parametrize("ext", [".ply", ".obj", ".stl", ".glb", ".gltf", ".3mf"])
def test_a_file_whose_name_is_not_utf8_is_read(tmp_path, ext):
    """A file named in Latin-1 on a UTF-8 system (``h\\xf6he.ply``, as ``os.listdir`` and a shell glob give it:
    Python's ``'h\\udcf6he.ply'``) was written by save_mesh but not read back: trimesh named the mesh's scene node after
    the file and encoded that name as UTF-8, so read_mesh (and ``stepterrain info``, the batch's skip check) raised
    "cannot read ... UnicodeEncodeError: 'utf-8' codec can't encode character '\\udcf6' ... surrogates not allowed".
    The file is read as the same file under a plain name is; its name in the metadata is the file's with the
    undecodable byte as U+FFFD."""
    heights = np.arange(20.0).reshape(4, 5) % 7
    mesh = st.stepped(heights, interval=2.0, colors="terrain")
    plain, odd = tmp_path / f"plain{ext}", tmp_path / os.fsdecode(b"h\xf6he" + ext.encode())
    save_mesh(mesh, plain)
    save_mesh(mesh, odd)
    assert os.fsencode(odd.name) == b"h\xf6he" + ext.encode()
    expected, got = read_mesh(plain), read_mesh(odd)
    np.testing.assert_array_equal(got.vertices, expected.vertices)
    np.testing.assert_array_equal(got.faces, expected.faces)
    np.testing.assert_array_equal(got.visual.vertex_colors, expected.visual.vertex_colors)
    assert got.metadata.get("isovalues") == expected.metadata.get("isovalues")
    if "name" in expected.metadata and expected.metadata["name"].startswith("plain"):
        assert got.metadata["name"] == expected.metadata["name"].replace("plain", "h\ufffdhe")
    (got.metadata.get("name") or "").encode("utf-8")  # a name every writer can store


@pytest.mark.skipif(os.name == "nt" or os.fsencode("\udcf6") != b"\xf6", reason="needs byte file names (POSIX)")
def test_an_obj_named_with_no_utf8_is_written_with_its_texture(tmp_path):
    """The OBJ's text is UTF-8: a textured OBJ saved as ``t\\xf6x.obj`` (``'t\\udcf6x.obj'``) named its ``.mtl`` in the
    ``mtllib`` line, and a mesh whose ``metadata["name"]`` held a lone surrogate (a file's name as read) its ``o`` line,
    and save_mesh raised a UnicodeEncodeError. Such names are written with U+FFFD in place of the undecodable byte,
    and the side files beside the OBJ are named as its ``mtllib`` line names them, so the texture is found."""
    from PIL import Image

    mesh = st.heightfield_mesh(np.arange(20.0).reshape(4, 5) % 7)
    uv = mesh.vertices[:, :2] / mesh.vertices[:, :2].max(axis=0)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (4, 4), (200, 30, 40)))
    target = tmp_path / os.fsdecode(b"t\xf6x.obj")
    save_mesh(mesh, target)
    back = read_mesh(target)
    assert back.visual.kind == "texture" and back.visual.material.image.size == (4, 4)
    assert (tmp_path / "t\ufffdx.mtl").is_file()
    named = st.stepped(np.arange(20.0).reshape(4, 5) % 7, interval=2.0)
    named.metadata["name"] = "h\udcf6he.ply"
    save_mesh(named, tmp_path / "named.obj")
    assert "o h\ufffdhe.ply\n" in (tmp_path / "named.obj").read_text(encoding="utf-8")


@pytest.mark.skipif(os.name == "nt" or os.fsencode("\udcf6") != b"\xf6", reason="needs byte file names (POSIX)")
@pytest.mark.parametrize("name", [b"h\xf6he.tif", ("\u00fc" * 121 + ".tif").encode()])
@pytest.mark.parametrize("georeferenced", [False, True])
def test_a_tiff_is_written_under_a_name_that_its_temporary_file_could_not_hold(tmp_path, name, georeferenced):
    """atomic_path's temporary ``.<name>.XXXXXXXX.tmp`` took the target's name as it was, and PIL's TIFF writer
    (libtiff) and rasterio (GDAL) pass the file name on as UTF-8: save_image of a TIFF named in Latin-1
    (``h\\xf6he.tif``), or of a name of 246 bytes whose temporary's cut to 255 bytes ended inside a character, raised
    UnicodeEncodeError "surrogates not allowed". The temporary's name is UTF-8 now; the file keeps its own name."""
    target = tmp_path / os.fsdecode(name)
    image = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    if georeferenced:
        pytest.importorskip("rasterio")
        save_image(image, target, extent=(0.0, 6.0, 0.0, 4.0), crs="EPSG:32611")
    else:
        save_image(image, target)
    assert [os.fsencode(p.name) for p in tmp_path.iterdir()] == [name]
    with Image.open(target) as back:
        np.testing.assert_array_equal(np.asarray(back.convert("RGB")), image)


@pytest.mark.skipif(os.name == "nt" or os.fsencode("\udcf6") != b"\xf6", reason="needs byte file names (POSIX)")
@pytest.mark.parametrize("ext", [".zip", ".tar.gz"])
def test_an_archive_whose_name_is_not_utf8_is_read_as_under_a_plain_name(tmp_path, ext):
    """An archive holding a mesh (a ``.zip``, ``.tar.gz``) is read by trimesh, the mesh's name that of the file in it.
    One named in Latin-1 (``h\\xf6he.tar.gz``) was read so too before non-UTF-8 names were read from the open file;
    then its type was taken from the last suffix only (``gz``, which trimesh does not read: NotImplementedError),
    where trimesh takes ``tar.gz``, and a ``.zip``'s mesh was named after the archive, not after the file in it."""
    import io
    import tarfile
    import zipfile

    ply = trimesh.exchange.ply.export_ply(st.stepped(np.arange(20.0).reshape(4, 5) % 7, interval=2.0))
    plain, odd = tmp_path / f"plain{ext}", tmp_path / os.fsdecode(b"h\xf6he" + ext.encode())
    for target in (plain, odd):
        if ext == ".zip":
            with zipfile.ZipFile(target, "w") as archive:
                archive.writestr("m.ply", ply)
        else:
            with tarfile.open(target, "w:" + ext.rsplit(".", 1)[1]) as archive:
                info = tarfile.TarInfo("m.ply")
                info.size = len(ply)
                archive.addfile(info, io.BytesIO(ply))
    expected, got = read_mesh(plain), read_mesh(odd)
    assert len(expected.faces) == 142
    np.testing.assert_array_equal(got.vertices, expected.vertices)
    np.testing.assert_array_equal(got.faces, expected.faces)
    assert got.metadata.get("name") == expected.metadata.get("name")


@pytest.mark.parametrize("ending", ["/", "/.", "//"])
def test_an_output_path_ending_in_a_folder_separator_is_refused_not_written_as_a_file(tmp_path, ending):
    """save_mesh(m, "x.glb/") (a folder meant) wrote a file named x.glb: pathlib drops a trailing separator (and a
    trailing "."). Such a path is refused naming it, and nothing is written; the writers sharing the path check
    (save_image, save_animation) refuse it too."""
    from stepterrain.closeup import save_animation

    mesh = trimesh.creation.box()
    for write, name, data in ((save_mesh, "x.glb", mesh), (save_image, "x.png", np.zeros((4, 4, 3), np.uint8)),
                              (save_animation, "x.gif", np.zeros((2, 4, 4, 3), np.uint8))):
        path = str(tmp_path / name) + ending
        with pytest.raises(InvalidInputError, match=r"^path '.*x\.(glb|png|gif)/\.?/?' ends in '[/.]', so it names "
                                                    r"a folder; expected a file name \('.*x\.(glb|png|gif)' to write"):
            write(data, path)
        assert not (tmp_path / name).exists()
    save_mesh(mesh, tmp_path / "x.glb")  # a file name still writes (a Path cannot end in a separator)
    assert len(read_mesh(str(tmp_path / "x.glb")).faces) == 12


@pytest.mark.parametrize("ending", ["/", "/.", "//"])
def test_atomic_path_refuses_a_name_that_ends_as_a_folders_does(tmp_path, ending):
    """``atomic_path("out.glb/")`` (a folder meant) wrote a file ``out.glb``: Path drops the trailing separator. It is
    refused as save_mesh refuses it, before anything is made."""
    target = f"{tmp_path / 'out.glb'}{ending}"
    with pytest.raises(InvalidInputError, match=r"path .* names a folder"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"content")
    assert os.listdir(tmp_path) == []
    with atomic_path(tmp_path / "out.glb") as tmp:  # the same name as a Path, without the ending, is a file
        tmp.write_bytes(b"content")
    assert (tmp_path / "out.glb").read_bytes() == b"content"


def test_a_geotiff_crs_that_geotiff_keys_cannot_hold_is_kept_beside_it_and_no_temporary_file_stays(tmp_path):
    """An ob_tran CRS does not fit GeoTIFF's keys: GDAL wrote it to ``<temporary>.aux.xml``, which stayed in the folder
    under the temporary's name while the image came out without a CRS. It is now ``<image>.aux.xml``, which GDAL reads
    with the image; and a later image of a CRS the keys hold removes it (it gave the new image the old CRS)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    rotated = "+proj=ob_tran +o_proj=longlat +o_lon_p=0 +o_lat_p=30 +lon_0=0"
    image = np.random.default_rng(3).integers(0, 256, (6, 9, 3), dtype=np.uint8)
    path = tmp_path / "rotated.tif"
    save_image(image, path, extent=(0.0, 9.0, 0.0, 6.0), crs=rotated)
    assert sorted(os.listdir(tmp_path)) == ["rotated.tif", "rotated.tif.aux.xml"]
    with rasterio.open(path) as dataset:
        assert dataset.crs is not None and dataset.crs == CRS.from_user_input(rotated)
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), image)
    save_image(image, path, extent=(0.0, 9.0, 0.0, 6.0), crs="EPSG:4326")
    assert sorted(os.listdir(tmp_path)) == ["rotated.tif"]
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_epsg(4326)


_ROTATED = "+proj=ob_tran +o_proj=longlat +o_lon_p=0 +o_lat_p=30 +lon_0=0"
_ROTATED_45 = "+proj=ob_tran +o_proj=longlat +o_lon_p=0 +o_lat_p=45 +lon_0=0"


@pytest.mark.parametrize(("old_crs", "new_crs"), [("EPSG:4326", _ROTATED), (_ROTATED, "EPSG:4326"),
                                                  (_ROTATED, _ROTATED_45)])
def test_a_geotiffs_aux_xml_never_pairs_with_the_other_image_and_a_failed_write_leaves_the_old_pair(
        tmp_path, monkeypatch, old_crs, new_crs):
    """The new ``.aux.xml`` was put in place before the image, and an old one removed only after: at the image's
    rename the old image stood with the new CRS file (or the new image with the old one), and an image whose rename
    then failed stayed for good with the CRS of the write that failed. The old side file now goes aside before the
    image's rename (back in place if it fails) and the new one follows the image."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    old = np.full((6, 9, 3), 40, np.uint8)
    new = np.full((6, 9, 3), 200, np.uint8)
    path = tmp_path / "layer.tif"
    aux = tmp_path / "layer.tif.aux.xml"
    save_image(old, path, extent=(0.0, 9.0, 0.0, 6.0), crs=old_crs)
    old_aux = aux.read_bytes() if aux.exists() else None
    real_replace = os.replace
    seen: list[bool] = []

    def replace(src, dst, **kwargs):
        if os.fspath(dst) == str(path):
            seen.append(aux.exists())  # the side file beside the image at the moment the image changes
            if fail:
                raise OSError(errno.EIO, "Input/output error")
        return real_replace(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    fail = True
    with pytest.raises(DataFileError, match="Input/output error"):
        save_image(new, path, extent=(0.0, 9.0, 0.0, 6.0), crs=new_crs)
    assert seen == [False]  # neither the old image's side file nor the new one's beside it
    assert (aux.read_bytes() if aux.exists() else None) == old_aux
    assert sorted(os.listdir(tmp_path)) == sorted(["layer.tif"] + (["layer.tif.aux.xml"] if old_aux else []))
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_user_input(old_crs)
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), old)
    fail = False
    save_image(new, path, extent=(0.0, 9.0, 0.0, 6.0), crs=new_crs)
    assert seen == [False, False]
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_user_input(new_crs)
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), new)
    assert sorted(os.listdir(tmp_path)) == sorted(["layer.tif"] + (["layer.tif.aux.xml"] if aux.exists() else []))


@pytest.mark.parametrize("where", ["lstat", "temporary", "rename"])
def test_a_geotiffs_old_aux_xml_that_cannot_be_set_aside_is_a_data_file_error_and_the_old_pair_stays(
        tmp_path, monkeypatch, where):
    """Setting the old ``.aux.xml`` aside before the image's rename may fail (its folder's entry unreadable, no room
    for a temporary name, the rename refused): a DataFileError naming the side file and the image, as atomic_path
    words its write failures, with the old image and its side file as they were and no temporary file left."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    import stepterrain.export as export

    old = np.full((6, 9, 3), 40, np.uint8)
    path = tmp_path / "layer.tif"
    aux = tmp_path / "layer.tif.aux.xml"
    save_image(old, path, extent=(0.0, 9.0, 0.0, 6.0), crs=_ROTATED)
    before = {name: (tmp_path / name).read_bytes() for name in os.listdir(tmp_path)}
    assert sorted(before) == ["layer.tif", "layer.tif.aux.xml"]
    owner, name, hit = {"lstat": (os, "lstat", lambda p, *a: os.fspath(p) == str(aux)),
                        "temporary": (export, "_new_temporary", lambda folder, n, *a: n == aux.name),
                        "rename": (os, "replace", lambda src, dst: os.fspath(src) == str(aux))}[where]
    real = getattr(owner, name)

    def failing(*args, **kwargs):
        if hit(*args):
            raise OSError(errno.EIO, "Input/output error")
        return real(*args, **kwargs)

    monkeypatch.setattr(owner, name, failing)
    with pytest.raises(DataFileError, match=r"cannot remove '.*layer\.tif\.aux\.xml'.*'.*layer\.tif': Input/output"):
        save_image(np.full((6, 9, 3), 200, np.uint8), path, extent=(0.0, 9.0, 0.0, 6.0), crs="EPSG:4326")
    monkeypatch.undo()
    assert {name: (tmp_path / name).read_bytes() for name in os.listdir(tmp_path)} == before
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_user_input(_ROTATED)
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), old)


def test_a_geotiffs_new_aux_xml_keeps_the_old_ones_mode(tmp_path):
    """A GeoTIFF's ``.aux.xml`` written over one keeps its mode (a private 0o600 one stays private), as atomic_path
    keeps a replaced file's: the old one is set aside before the rename, which then found no file to take it from."""
    pytest.importorskip("rasterio")
    image = np.zeros((4, 5, 3), np.uint8)
    path = tmp_path / "private.tif"
    save_image(image, path, extent=(0.0, 5.0, 0.0, 4.0), crs=_ROTATED)
    os.chmod(path, 0o600)
    os.chmod(tmp_path / "private.tif.aux.xml", 0o600)
    save_image(image, path, extent=(0.0, 5.0, 0.0, 4.0), crs=_ROTATED_45)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    assert stat.S_IMODE(os.stat(tmp_path / "private.tif.aux.xml").st_mode) == 0o600
    assert "\"o_lat_p\",45" in (tmp_path / "private.tif.aux.xml").read_text()


@pytest.mark.parametrize("stem", ["a" * 230, "a" * 237, "a" * 243, "\u00f6" * 118])
def test_a_geotiffs_aux_xml_is_written_for_a_long_name_whose_temporary_name_leaves_no_room_for_it(tmp_path, stem):
    """GDAL names the side file holding a CRS GeoTIFF's keys cannot hold after the file it writes: for a target name of
    234 to 247 bytes ``.<name>.XXXXXXXX.tmp.aux.xml`` was over 255 bytes, GDAL wrote no side file, and the image came
    out without its CRS, without a word, although ``<name>.aux.xml`` fits. GDAL now writes to a shorter temporary."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    image = np.random.default_rng(5).integers(0, 256, (4, 6, 3), dtype=np.uint8)
    path = tmp_path / f"{stem}.tif"
    assert 234 <= len(os.fsencode(path.name)) <= 247
    save_image(image, path, extent=(0.0, 6.0, 0.0, 4.0), crs=_ROTATED)
    assert sorted(os.listdir(tmp_path)) == sorted([path.name, path.name + ".aux.xml"])  # no temporary stays
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_user_input(_ROTATED)
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), image)
    save_image(image, path, extent=(0.0, 6.0, 0.0, 4.0), crs="EPSG:4326")  # one the keys hold: the side file goes
    assert os.listdir(tmp_path) == [path.name]
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_epsg(4326)


@pytest.mark.parametrize("length", [248, 255])
def test_a_geotiff_whose_crs_needs_a_side_file_its_name_leaves_no_room_for_is_refused_and_the_old_one_kept(
        tmp_path, length):
    """A CRS GeoTIFF's keys cannot hold goes into ``<name>.aux.xml``, over 255 bytes for a name of 248 bytes or more:
    the image was written without it (its CRS lost, without a word). It is refused, naming the side file and the
    longest name that takes one, and the image there before stays as it was; a CRS the keys hold is still written."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    path = tmp_path / ("a" * (length - 4) + ".tif")
    old = np.full((4, 6, 3), 40, np.uint8)
    save_image(old, path, extent=(0.0, 6.0, 0.0, 4.0), crs="EPSG:4326")
    with pytest.raises(DataFileError, match=rf"cannot write '.*\.tif' with its crs: GeoTIFF's keys cannot hold that "
                                            rf"CRS, and GDAL keeps it in the side file 'a+\.tif\.aux\.xml', whose name "
                                            rf"of {length + 8} bytes is over the 255 .* at most 247 bytes"):
        save_image(np.full((4, 6, 3), 200, np.uint8), path, extent=(0.0, 6.0, 0.0, 4.0), crs=_ROTATED)
    assert os.listdir(tmp_path) == [path.name]
    with rasterio.open(path) as dataset:
        assert dataset.crs == CRS.from_epsg(4326)
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), old)


def _gdal_pair(path, old: np.ndarray) -> bytes:
    """``old`` written at ``path`` (PNG or TIFF) by GDAL with a CRS, a geotransform and a nodata value, which GDAL
    keeps for a PNG (and for a TIFF's ob_tran CRS) in ``<path>.aux.xml``; that side file's bytes."""
    rasterio = pytest.importorskip("rasterio")

    driver = "PNG" if path.suffix == ".png" else "GTiff"
    crs = "EPSG:4326" if driver == "PNG" else _ROTATED
    with rasterio.open(path, "w", driver=driver, width=old.shape[1], height=old.shape[0], count=3, dtype="uint8",
                       crs=crs, transform=rasterio.Affine(0.5, 0, 5, 0, -0.5, 50), nodata=40) as dataset:
        dataset.write(np.moveaxis(old, 2, 0))
    aux = path.with_name(path.name + ".aux.xml")
    assert aux.exists()
    return aux.read_bytes()


@pytest.mark.parametrize("name", ["layer.png", "layer.tif"])
def test_an_image_written_without_extent_removes_the_old_aux_xml_gdal_would_pair_with_it(tmp_path, monkeypatch,
                                                                                          name):
    """A PNG or plain TIFF written over a GDAL-written image (a GeoTIFF whose CRS went into ``.aux.xml``, a PNG whose
    CRS, geotransform and nodata did) left that side file in place, and GDAL read the new image with the old one's
    CRS, placement and nodata. It goes, as a GeoTIFF's old side file goes (and as GDAL removes it when it makes a
    file): set aside just before the image's rename, and back beside the old image when the rename fails."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.errors import NotGeoreferencedWarning

    path = tmp_path / name
    aux = tmp_path / (name + ".aux.xml")
    old = np.full((6, 9, 3), 40, np.uint8)
    old_aux = _gdal_pair(path, old)
    old_image = path.read_bytes()
    new = np.full((6, 9, 3), 200, np.uint8)
    real_replace = os.replace
    seen: list[bool] = []

    def replace(src, dst, **kwargs):
        if os.fspath(dst) == str(path):
            seen.append(aux.exists())
            raise OSError(errno.EIO, "Input/output error")
        return real_replace(src, dst, **kwargs)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(DataFileError, match="Input/output error"):
        save_image(new, path)
    monkeypatch.undo()
    assert seen == [False]  # the old side file was not beside either image when the image changed
    assert sorted(os.listdir(tmp_path)) == sorted([name, aux.name])
    assert path.read_bytes() == old_image and aux.read_bytes() == old_aux
    save_image(new, path)
    assert os.listdir(tmp_path) == [name]
    with pytest.warns(NotGeoreferencedWarning), rasterio.open(path) as dataset:
        assert dataset.crs is None and dataset.transform.is_identity and dataset.nodata is None
        assert np.array_equal(np.moveaxis(dataset.read(), 0, 2), new)


@pytest.mark.parametrize("dtype", [np.int64, np.uint64])
@pytest.mark.parametrize("element", ["vertex", "face"])
def test_a_ply_64_bit_integer_attribute_that_double_rounds_is_warned_of(tmp_path, dtype, element):
    """PLY has no 64-bit integer type: a 64-bit attribute beyond 32 bits is written as double, which holds integers
    exactly only up to 2**53. Beyond that its values came back changed without a word (an ID of 2**53 + 1 read as
    2**53); the write now warns, naming the attribute and how many values it rounds. One within 2**53 is exact and
    written without a warning."""
    import warnings

    mesh = trimesh.creation.icosphere(subdivisions=1)
    count = len(mesh.vertices) if element == "vertex" else len(mesh.faces)
    attributes = mesh.vertex_attributes if element == "vertex" else mesh.face_attributes
    exact = np.arange(count, dtype=dtype) + dtype(2**52)
    attributes["ids"] = exact
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = read_mesh(save_mesh(mesh, tmp_path / "exact.ply"))
    got = (back.vertex_attributes if element == "vertex" else back.face_attributes)["ids"]
    assert np.array_equal(got.astype(dtype), exact)
    rounded = exact + dtype(2**53)  # odd values round to even doubles
    attributes["ids"] = rounded
    with pytest.warns(UserWarning, match=rf"'ids' .*2\*\*53.* {count // 2} of its {count} values"):
        back = read_mesh(save_mesh(mesh, tmp_path / "rounded.ply"))
    got = (back.vertex_attributes if element == "vertex" else back.face_attributes)["ids"]
    assert (got.astype(dtype) != rounded).sum() == count // 2


@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj"])
@pytest.mark.parametrize("make", [lambda: Image.new("RGB", (0, 5)), lambda: np.zeros((4, 0, 3), np.uint8)],
                         ids=["pil", "array"])
def test_a_texture_image_of_no_pixels_is_refused_by_name_before_any_file_is_made(tmp_path, ext, make):
    """A texture image with a side of 0 pixels (a PIL image, or a (0, W, 3) uint8 array, which the array check took)
    raised Pillow's bare ValueError ("cannot write empty image") from inside the writer, after the folder was made.
    It is an InvalidInputError naming the image and its size, before anything is written."""
    mesh = trimesh.creation.box()
    uv = np.random.default_rng(0).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=make())
    with pytest.raises(InvalidInputError, match=r"mesh texture image \(image\) must have at least 1 x 1 pixels; got "
                                                r"(0 x 5|0 x 4)"):
        save_mesh(mesh, tmp_path / "out" / f"t{ext}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("bad", [7, -1])
def test_the_face_index_checks_share_one_message_naming_their_argument(tmp_path, bad):
    """save_mesh, to_polydata/from_polydata and render each refused faces indexing outside the vertices with a
    check of their own and a message of their own ("must index its vertices (0 to 2)", "must index its 3 vertices
    (0 .. 2)", "must hold integer vertex indices in [0, 2]; got indices from 0 to 7"), only two of them naming the
    face. One helper makes them now: each names its argument, the vertex count and range, and the first bad face."""
    from stepterrain import render
    from stepterrain.pyvista_accessor import to_polydata

    points = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 1]])
    mesh = trimesh.Trimesh(points, [[0, 1, 2], [0, 1, bad]], process=False)
    face = rf"face 1 is \[0, 1, {bad}\]$"
    with pytest.raises(InvalidInputError, match=rf"^mesh faces must index its 3 vertices \(0 \.\. 2\); {face}"):
        save_mesh(mesh, tmp_path / "m.ply")
    with pytest.raises(InvalidInputError, match=rf"^mesh faces must index its 3 vertices \(0 \.\. 2\); {face}"):
        to_polydata(mesh)
    with pytest.raises(InvalidInputError, match=rf"^mesh\.faces must index its 3 vertices \(0 \.\. 2\); {face}"):
        render.render_mesh(mesh, window_size=(32, 32))


@pytest.mark.parametrize("bad", [7, -1])
def test_scale_for_print_refuses_a_face_index_with_the_shared_message(bad):
    """scale_for_print kept a face-index check of its own after the others shared one ("mesh faces must index its 3
    vertices (0 .. 2); got indices 0 .. 7", naming no face): it names the first bad face as save_mesh does."""
    points = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 1]])
    mesh = trimesh.Trimesh(points, [[0, 1, 2], [0, 1, bad]], process=False)
    with pytest.raises(InvalidInputError, match=rf"^mesh faces must index its 3 vertices \(0 \.\. 2\); "
                                                rf"face 1 is \[0, 1, {bad}\]$"):
        st.export.scale_for_print(mesh, 100.0)
