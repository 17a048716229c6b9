"""read_mesh's left-alone items: an OFF read from one read of its bytes; an OBJ whose ``.mtl`` or texture image is
missing warned of by name; a CRLF (or CR) copy of a stepterrain OBJ cut short refused as an LF one is; a multi-material
textured OBJ's faces in the file's order."""

from __future__ import annotations

import builtins
import io
import warnings

import numpy as np
import pytest
import trimesh
from PIL import Image

from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh, save_mesh


def _plain_obj(path):
    mesh = trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]], float),
                           [[0, 1, 2], [1, 3, 2]], process=False)
    save_mesh(mesh, path)
    return path.read_bytes()


def _textured_obj(path):
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [0, 1], [1, 1]],
                                                image=Image.new("RGB", (4, 4), (9, 99, 9)))
    save_mesh(mesh, path)
    return path.read_bytes()


@pytest.mark.parametrize("end", [b"\r\n", b"\r"])
def test_crlf_or_cr_copy_of_a_stepterrain_obj_cut_mid_line_refused(tmp_path, end):
    """A stepterrain OBJ whose line ends were turned into CRLF (a Windows copy, git's autocrlf) or CR, then cut
    mid-line, is refused as cut short, as the LF file is (its first line read as '# written by stepterrain\\r', not
    stepterrain's, so the copy read as the vertices before the cut without a word)."""
    whole = _plain_obj(tmp_path / "whole.obj")
    copy = whole.replace(b"\n", end)
    (tmp_path / "copy.obj").write_bytes(copy)
    assert len(read_mesh(tmp_path / "copy.obj").faces) == 2
    cut = copy[: copy.index(b"f ") - len(end) - 3]  # mid-line, within the last v line
    assert not cut.endswith((b"\n", b"\r"))
    (tmp_path / "cut.obj").write_bytes(cut)
    with pytest.raises(DataFileError, match=r"the file is cut short: it ends mid-line .*stepterrain's OBJ writer"):
        read_mesh(tmp_path / "cut.obj")


def test_crlf_copy_of_a_textured_stepterrain_obj_cut_at_a_line_end_refused(tmp_path):
    """A CRLF copy of a textured stepterrain OBJ cut at the end of a v or vt line is refused as cut short, as the LF
    file is (it read as points without a word)."""
    lines = _textured_obj(tmp_path / "whole.obj").replace(b"\n", b"\r\n").splitlines(keepends=True)
    first_v = next(k for k, line in enumerate(lines) if line.startswith(b"v "))
    first_f = next(k for k, line in enumerate(lines) if line.startswith(b"f "))
    for cut in range(first_v + 1, first_f):
        (tmp_path / "whole.obj").write_bytes(b"".join(lines[:cut]))  # beside its .mtl and image
        with pytest.raises(DataFileError, match=r"cut short: stepterrain's OBJ writer gives each v line of a textured"):
            read_mesh(tmp_path / "whole.obj")
    (tmp_path / "whole.obj").write_bytes(b"".join(lines))
    assert len(read_mesh(tmp_path / "whole.obj").faces) == 2


_COFF = "COFF\n4 2 0\n0 0 0 255 0 0\n1 0 0 0 255 0\n0 1 0 0 0 255\n1 1 1 9 9 9\n3 0 1 2\n3 1 3 2\n"
_OFF_FACE_COLOURS = "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 1\n3 0 1 2 255 0 0\n3 1 3 2 0 0 255\n"
_OFF_BOM = "\ufeffOFF # a\n\n4 2\n0 0 0\n1 0 0\n0 1 0\n1 1 1\n3 0 1 2\n3 1 3 2\n"


@pytest.mark.parametrize("text", [_COFF, _OFF_FACE_COLOURS, _OFF_BOM])
def test_off_file_opened_once(tmp_path, monkeypatch, text):
    """An OFF is opened and read once, its bytes kept: trimesh's reader, the header's keyword and counts, the vertex
    and face colour scans read them (the file was opened 5 times, and read whole 2 to 3 times), and the mesh comes
    back as before: named after its file, with its colours."""
    path = tmp_path / "mesh.off"
    path.write_text(text, encoding="utf-8", newline="")
    opened = []
    real = io.open

    def counting(file, *args, **kwargs):
        if str(file) == str(path) or (hasattr(file, "__fspath__") and str(file.__fspath__()) == str(path)):
            opened.append(args[:1] or kwargs.get("mode"))
        return real(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", counting)
    monkeypatch.setattr(io, "open", counting)
    mesh = read_mesh(path)
    monkeypatch.undo()
    assert len(opened) == 1, opened
    assert mesh.faces.tolist() == [[0, 1, 2], [1, 3, 2]] and len(mesh.vertices) == 4
    assert mesh.metadata.get("name") == "mesh.off"
    if text is _COFF:
        assert mesh.visual.kind == "vertex"
        assert mesh.visual.vertex_colors[:, :3].tolist() == [[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]]
    elif text is _OFF_FACE_COLOURS:
        assert mesh.visual.kind == "face"
        assert mesh.visual.face_colors[:, :3].tolist() == [[255, 0, 0], [0, 0, 255]]


def test_off_problems_still_said_by_line(tmp_path):
    """An OFF's bad face line and a cut-short OFF, read from its bytes kept, are still said by line and count."""
    path = tmp_path / "bad.off"
    path.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(DataFileError, match=r"line 6, '3 0 1 7', names vertex 7, and the file has 3 vertices"):
        read_mesh(path)
    path.write_text("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    with pytest.raises(DataFileError, match=r"its counts declare 3 vertices and 2 faces, a line each, and the file "
                                            r"has 4 lines after them: is it cut short\?"):
        read_mesh(path)


def _not_there_warnings(record):
    return [str(w.message) for w in record if "is not there" in str(w.message)]


def test_obj_whose_mtl_or_texture_image_is_missing_warns_naming_it(tmp_path):
    """A textured OBJ whose ``.mtl`` (its ``mtllib``) or whose material's texture image (``map_Kd``) is not beside it
    was read untextured without a word (trimesh's reader logs it at debug level): each is warned of by name and the
    path looked for, the mesh read without it, as a .gltf's missing image is; a whole OBJ reads without a warning."""
    _textured_obj(tmp_path / "t.obj")
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        whole = read_mesh(tmp_path / "t.obj")
    assert whole.visual.kind == "texture" and not _not_there_warnings(record)
    (tmp_path / "t_material_0.png").unlink()
    with pytest.warns(UserWarning, match=r"'.*t\.obj': the OBJ's texture image 't_material_0\.png' \(map_Kd, "
                                         r"'.*t_material_0\.png'\) is not there: the mesh is read without that "
                                         r"texture") as record:
        mesh = read_mesh(tmp_path / "t.obj")
    assert len(_not_there_warnings(record)) == 1
    assert len(mesh.faces) == 2 and mesh.visual.material.image is None  # its UVs kept, the image not
    (tmp_path / "t.mtl").unlink()
    with pytest.warns(UserWarning, match=r"'.*t\.obj': the OBJ's material library 't\.mtl' \(mtllib, '.*t\.mtl'\) "
                                         r"is not there: the mesh is read without its materials") as record:
        mesh = read_mesh(tmp_path / "t.obj")
    assert len(_not_there_warnings(record)) == 1
    np.testing.assert_array_equal(mesh.faces, whole.faces)


def test_obj_of_several_materials_whose_mtl_is_missing_warns(tmp_path):
    """An OBJ of several materials (read as one mesh, a colour per face) whose ``.mtl`` is missing is warned of once,
    its faces read with trimesh's default colour."""
    text = ("mtllib colours.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl red\nf 1 2 3\nusemtl blue\nf 2 4 3\n")
    (tmp_path / "two.obj").write_text(text)
    (tmp_path / "colours.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        assert read_mesh(tmp_path / "two.obj").visual.face_colors[:, :3].tolist() == [[255, 0, 0], [0, 0, 255]]
    assert not _not_there_warnings(record)
    (tmp_path / "colours.mtl").unlink()
    with pytest.warns(UserWarning, match=r"material library 'colours\.mtl' \(mtllib, '.*colours\.mtl'\) is not "
                                         r"there") as record:
        mesh = read_mesh(tmp_path / "two.obj")
    assert len(_not_there_warnings(record)) == 1
    assert mesh.faces.tolist() == [[0, 1, 2], [1, 3, 2]]


def _two_textures(folder, faces):
    Image.new("RGB", (4, 4), (255, 0, 0)).save(folder / "red.png")
    Image.new("RGB", (4, 4), (0, 0, 255)).save(folder / "blue.png")
    (folder / "m.mtl").write_text("newmtl A\nKd 1 1 1\nmap_Kd red.png\nnewmtl B\nKd 1 1 1\nmap_Kd blue.png\n")
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    uvs = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float)
    text = "mtllib m.mtl\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
    text += "".join(f"vt {u} {v}\n" for u, v in uvs) + faces
    (folder / "m.obj").write_text(text)
    return vertices


def test_textured_obj_of_several_materials_reads_its_faces_in_the_file_order(tmp_path):
    """A textured OBJ of two materials, their usemtl chunks interleaved, came back with its faces material by
    material (trimesh's reader: A's, then B's), so face k of the mesh was not the file's face k. Its triangles now come
    back in the file's order, each with its corners' positions, and the same vertices, UVs and packed texture."""
    faces = ("usemtl B\nf 1/1 2/2 3/3\nusemtl A\nf 2/2 4/4 3/3\nusemtl B\nf 2/1 5/2 4/3\nusemtl A\nf 5/2 6/4 4/3\n"
             "f 1/1 5/2 6/3\n")
    vertices = _two_textures(tmp_path, faces)
    mesh = read_mesh(tmp_path / "m.obj")
    written = np.array([[int(word.split("/")[0]) - 1 for word in line.split()[1:]]
                        for line in faces.splitlines() if line.startswith("f ")])
    assert mesh.visual.kind == "texture" and len(mesh.faces) == len(written)
    np.testing.assert_array_equal(mesh.vertices[mesh.faces], vertices[written])
    loaded = trimesh.load(tmp_path / "m.obj", force="mesh", process=False)  # trimesh's reader, material by material
    np.testing.assert_array_equal(mesh.vertices, loaded.vertices)
    np.testing.assert_array_equal(mesh.visual.uv, loaded.visual.uv)
    assert sorted(map(tuple, mesh.faces.tolist())) == sorted(map(tuple, loaded.faces.tolist()))
    assert not np.array_equal(mesh.faces, loaded.faces)


def test_textured_obj_of_several_materials_with_a_quad_reads_as_trimesh_orders_it(tmp_path):
    """Where a face is a polygon, trimesh's reader orders a material's triangles by the mix of its faces (of quads
    only: every first half, then every second half): the faces come back as trimesh's reader gives them, material
    by material (the read_mesh docstring says so)."""
    faces = "usemtl B\nf 1/1 2/2 3/3\nusemtl A\nf 1/1 2/2 4/4 3/3\nf 2/2 5/2 6/4 4/3\nusemtl B\nf 2/1 5/2 4/3\n"
    _two_textures(tmp_path, faces)
    mesh = read_mesh(tmp_path / "m.obj")
    loaded = trimesh.load(tmp_path / "m.obj", force="mesh", process=False)
    np.testing.assert_array_equal(mesh.faces, loaded.faces)
    assert len(mesh.faces) == 6
