"""read_mesh of OBJ faces naming a texture (``vt``) or normal (``vn``) index the file has no line for (trimesh's reader
dropped the UVs or normals without a word), of a textured stepterrain OBJ cut short at a line's end among its ``v`` or
``vt`` lines (read as points without a word), and of a .gltf whose buffer file is missing (trimesh's bare
"FileNotFoundError: name.bin"): each refused naming the line, index or file; valid files read as before."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from stepterrain import export
from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh, save_mesh

_TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (_TRIANGLE + "f 1/1 2/2 3/9\n", r"line 7, 'f 1/1 2/2 3/9', names vt 9, and the file has 3 vt lines"),
        (_TRIANGLE + "f 1/1 2/2 3/-5\n", r"line 7, 'f 1/1 2/2 3/-5', names vt -5, and 3 vt lines come before it"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1 2/2 3/3\n", r"line 4, 'f 1/1 2/2 3/3', names vt 1, and the file has 0 vt"),
        (_TRIANGLE + "vn 0 0 1\nf 1/1/1 2/2/1 3/3/5\n", r"line 8, 'f 1/1/1 2/2/1 3/3/5', names vn 5, and the file has "
                                                     r"1 vn line:"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//4\n", r"line 5, 'f 1//1 2//1 3//4', names vn 4"),
        (_TRIANGLE + "v 1 1 0\nusemtl a\nf 1/1 2/2 3/3\nusemtl b\nf 2/2 4/7 3/3\n", r"line 11, .*names vt 7, and the"),
        (_TRIANGLE + "f 1/1 2/2 3/3\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf 4/1 5/2 6/9\n", r"line 12, .*names vt 9,"),
        (_TRIANGLE + " f\t1/1 2/2 3/4 # a\n", r"line 7, 'f\\t1/1 2/2 3/4 # a', names vt 4"),
        (_TRIANGLE.replace("\n", "\r") + "f 1/1 2/2 3/4\r", r"line 7, 'f 1/1 2/2 3/4', names vt 4"),
        (_TRIANGLE + "f 1/1 2/2 3/99999999999999999999\n", r"line 7, .*names vt 9{20}, and the file has 3 vt"),
    ],
)
def test_obj_texture_or_normal_index_outside_refused(tmp_path, text, expected):
    """A face's texture or normal index past the file's ``vt`` (``vn``) lines, counting back past the first, or naming
    one where there is none, in one material or the second, one object or the second, indented, of tabs and a
    comment, of CR line ends, or of more digits than an int64's: refused naming the line and index (trimesh's reader
    dropped every UV, or the normals, or gave a second material's corners the first's UVs, without a word)."""
    (tmp_path / "bad.obj").write_text(text, newline="")
    with pytest.raises(DataFileError, match=rf"'.*bad\.obj' as a mesh: ValueError: {expected}"):
        read_mesh(tmp_path / "bad.obj")


@pytest.mark.parametrize(
    "text",
    [
        _TRIANGLE + "f 1/1 2/2 3/3\n",
        _TRIANGLE + "f -3/-3 -2/-2 -1/-1\n",
        _TRIANGLE + "vn 0 0 1\nf 1/1/1 2/2/1 3/3/-1\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//+1\n",
        "f 1/1 2/2 3/3\n" + _TRIANGLE,  # faces before their lines: an index counts into the whole file's
        _TRIANGLE + "f 1/1 2/2 3/3\n" + _TRIANGLE + "f -3/-3 -2/-2 -1/-1\nf 4/4 5/5 6/000006\n",
        "mtllib dir/a.mtl\nusemtl x/99\n" + _TRIANGLE + "f 1/1 2/2 3/3\n",  # slashes in names: no index
    ],
)
def test_obj_texture_and_normal_indices_inside_read(tmp_path, text):
    """Faces whose texture and normal indices name lines the file has (positive, relative, signed, faces before the
    lines they name, relative ones after more lines, leading zeros, slashes in names) read as before, with their UVs
    where they name ``vt`` lines."""
    (tmp_path / "ok.obj").write_text(text)
    mesh = read_mesh(tmp_path / "ok.obj")
    assert len(mesh.faces) >= 1
    if "vt" in text and "f 1//1" not in text:
        assert np.asarray(mesh.visual.uv).shape == (len(mesh.vertices), 2)


@st.composite
def _texture_objs(draw: st.DrawFn) -> tuple[str, bool]:
    """A random OBJ text of faces naming v/vt, v//vn or v/vt/vn indices (the vertex ones all valid), some texture or
    normal ones maybe past the lines of their kind or counting back past the first, lines of every kind maybe after
    faces; and whether a line-by-line reference finds such an index (positive past the file's lines of its kind,
    negative past the lines before its face)."""
    form = draw(st.sampled_from(["v/vt", "v//vn", "v/vt/vn"]))
    seen = {"v": 0, "vt": 0, "vn": 0}
    lines: list[str] = []
    faces: list[tuple[dict[str, int], list[dict[str, int]]]] = []  # the lines before it, its corners' indices
    for _ in range(draw(st.integers(1, 4))):
        for _ in range(draw(st.integers(1, 3))):
            for kind in ("v", "vt", "vn"):
                if kind == "v" or kind in form:
                    seen[kind] += 1
                    lines.append({"v": "v 1 2 3", "vt": "vt 0.5 0.5", "vn": "vn 0 0 1"}[kind])
        for _ in range(draw(st.integers(0, 3))):
            corners = []
            for _ in range(3):
                corner = {"v": draw(st.integers(1, seen["v"]))}
                for kind in ("vt", "vn"):
                    if kind in form:
                        corner[kind] = draw(st.integers(-seen[kind] - 2, seen[kind] + 3).filter(lambda k: k != 0))
                corners.append(corner)
            faces.append((dict(seen), corners))
            words = ["/".join([str(c["v"]), str(c.get("vt", "")), str(c["vn"])] if "vn" in form
                              else [str(c["v"]), str(c["vt"])]) for c in corners]
            lines.append("f " + " ".join(words))
    if not faces:
        word = {"v/vt": "1/1", "v//vn": "1//1", "v/vt/vn": "1/1/1"}[form]
        lines.append(f"f {word} {word} {word}")
        faces.append((dict(seen), [{kind: 1 for kind in ("v", "vt", "vn") if kind in form}] * 3))
    outside = any((index > seen[kind]) if index > 0 else (-index > before[kind])
                  for before, corners in faces for corner in corners for kind, index in corner.items() if kind != "v")
    return "".join(line + "\n" for line in lines), outside


@given(_texture_objs())
def test_random_obj_texture_indices_as_the_reference(tmp_path_factory, drawn):
    """Random OBJ files of texture and normal indices, some outside: refused naming a vt or vn index exactly where a
    line-by-line reference finds one outside, read otherwise."""
    text, outside = drawn
    path = tmp_path_factory.mktemp("obj") / "random.obj"
    path.write_text(text)
    if outside:
        with pytest.raises(DataFileError, match=r"names v[tn] -?\d+, and "):
            read_mesh(path)
    else:
        assert len(read_mesh(path).faces) >= 1


def test_texture_index_scan_over_blocks_and_long_fields(monkeypatch):
    """The scan gives the same answer in blocks of a few lines as in one, and reads a field wider than its window
    (leading zeros) by its value."""
    text = (_TRIANGLE + "f 1/1 2/2 3/3\n") * 5 + "f 1/1 2/2 3/" + "0" * 30 + "15\n"
    assert export._obj_texture_index_outside(text.encode()) is False
    assert export._obj_texture_index_outside(text.replace("15\n", "16\n").encode()) is True
    monkeypatch.setattr(export, "_OBJ_INDEX_BLOCK", 7)
    assert export._obj_texture_index_outside(text.encode()) is False
    assert export._obj_texture_index_outside(text.replace("15\n", "16\n").encode()) is True


def _textured(tmp_path):
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [0, 1], [1, 1]],
                                                image=Image.new("RGB", (4, 4), (9, 99, 9)))
    save_mesh(mesh, tmp_path / "whole.obj")
    return (tmp_path / "whole.obj").read_bytes()


def test_textured_stepterrain_obj_cut_at_a_line_end_refused(tmp_path):
    """A textured OBJ save_mesh wrote, cut short at the end of any of its v or vt lines (a copy interrupted between
    lines), is refused as cut short, saying its v and vt lines (it read as points without a word); cut among its
    faces it reads as the faces before the cut (no different from a whole file of fewer faces), and whole as all."""
    data = _textured(tmp_path)
    lines = data.splitlines(keepends=True)
    first_v = next(k for k, line in enumerate(lines) if line.startswith(b"v "))
    first_f = next(k for k, line in enumerate(lines) if line.startswith(b"f "))
    for cut in range(first_v + 1, first_f):
        (tmp_path / "cut.obj").write_bytes(b"".join(lines[:cut]))
        vs = sum(line.startswith(b"v ") for line in lines[:cut])
        vts = sum(line.startswith(b"vt ") for line in lines[:cut])
        with pytest.raises(DataFileError, match=rf"cut short: stepterrain's OBJ writer gives each v line of a "
                                                rf"textured mesh a vt line, .* holds {vs} v lines?, {vts} vt lines? "
                                                r"and no face"):
            read_mesh(tmp_path / "cut.obj")
    (tmp_path / "cut.obj").write_bytes(b"".join(lines[: first_f + 1]))
    assert len(read_mesh(tmp_path / "cut.obj").faces) == 1
    assert len(read_mesh(tmp_path / "whole.obj").faces) == 2


def test_untextured_or_foreign_obj_of_points_reads(tmp_path):
    """A file of points is no cut: untextured (save_mesh's points), textured with a vt per v (save_mesh's textured
    points), or not stepterrain's (a usemtl and no vt lines): each read as its vertices."""
    points = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), process=False)
    save_mesh(points, tmp_path / "points.obj")
    assert len(read_mesh(tmp_path / "points.obj").vertices) == 3
    points.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [0, 1]], image=Image.new("RGB", (2, 2)))
    save_mesh(points, tmp_path / "textured.obj")
    assert len(read_mesh(tmp_path / "textured.obj").vertices) == 3
    (tmp_path / "foreign.obj").write_text("mtllib a.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\n")
    assert len(read_mesh(tmp_path / "foreign.obj").vertices) == 2


def test_gltf_buffer_file_missing_names_it(tmp_path):
    """A .gltf whose buffer file is not beside it is refused naming the buffer, its uri and the path looked for (was
    trimesh's "FileNotFoundError: gltf_buffer_0.bin", the folder and that it is a buffer unsaid); with it, read."""
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(mesh))
    (tmp_path / "model.gltf").write_bytes(files["model.gltf"])
    tree = json.loads(files["model.gltf"])
    names = [buffer["uri"] for buffer in tree["buffers"]]
    for name in names[1:]:
        (tmp_path / name).write_bytes(files[name])
    expected = (rf"'.*model\.gltf' as a mesh: ValueError: glTF buffer 0 \(of {len(names)}\) is the file "
                rf"'{re.escape(names[0])}', and '.*{re.escape(str(tmp_path / names[0]))}' does not exist")
    with pytest.raises(DataFileError, match=expected):
        read_mesh(tmp_path / "model.gltf")
    (tmp_path / names[0]).write_bytes(files[names[0]])
    assert len(read_mesh(tmp_path / "model.gltf").faces) == 1


def test_gltf_image_file_missing_warned(tmp_path):
    """A .gltf whose texture image file is not beside it reads untextured there with a warning naming the image, its
    uri and the path looked for (trimesh's reader read it without the texture, without a word); with it, textured
    and no warning."""
    import warnings

    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [0, 1]], image=Image.new("RGB", (4, 4), "red"))
    tree = json.loads(trimesh.exchange.gltf.export_gltf(trimesh.Scene(mesh), embed_buffers=True)["model.gltf"])
    tree["images"] = [{"uri": "tex.png"}]
    (tmp_path / "model.gltf").write_text(json.dumps(tree))
    with pytest.warns(UserWarning, match=r"model\.gltf': the glTF's image 0, 'tex\.png' \('.*tex\.png'\) is not "
                                         r"there: the mesh is read without that texture"):
        read = read_mesh(tmp_path / "model.gltf")
    assert len(read.faces) == 1 and getattr(read.visual.material, "baseColorTexture", None) is None
    Image.new("RGB", (4, 4), "red").save(tmp_path / "tex.png")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read = read_mesh(tmp_path / "model.gltf")
    assert read.visual.material.baseColorTexture is not None


def test_gltf_percent_escaped_uris_found(tmp_path):
    """A .gltf's buffer and image uris are percent-encoded (glTF 2.0 §3.3): ``a%20b0.bin`` and ``a%20b.png`` name the
    files ``a b0.bin`` and ``a b.png`` beside it, read as such (trimesh's reader looked for the uri as written: the
    buffer refused with "FileNotFoundError: a%20b0.bin", the texture dropped without a word); the same file named
    as written (``a%20b.png``) is still found."""
    import base64
    import warnings

    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [0, 1]], image=Image.new("RGB", (4, 4), "red"))
    tree = json.loads(trimesh.exchange.gltf.export_gltf(trimesh.Scene(mesh), embed_buffers=True)["model.gltf"])
    for number, buffer in enumerate(tree["buffers"]):
        (tmp_path / f"a b{number}.bin").write_bytes(base64.b64decode(buffer["uri"].split(",", 1)[1]))
        buffer["uri"] = f"a%20b{number}.bin"
    tree["images"] = [{"uri": "a%20b.png"}]
    (tmp_path / "model.gltf").write_text(json.dumps(tree))
    Image.new("RGB", (4, 4), (0, 255, 0)).save(tmp_path / "a b.png")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read = read_mesh(tmp_path / "model.gltf")
    np.testing.assert_array_equal(read.faces, [[0, 1, 2]])
    assert np.asarray(read.visual.material.baseColorTexture.convert("RGB"))[0, 0].tolist() == [0, 255, 0]
    (tmp_path / "a b.png").rename(tmp_path / "a%20b.png")  # named as written
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read = read_mesh(tmp_path / "model.gltf")
    assert read.visual.material.baseColorTexture is not None
    (tmp_path / "a%20b.png").unlink()
    with pytest.warns(UserWarning, match=r"image 0, 'a%20b\.png' \('.*a b\.png'\) is not there"):
        assert len(read_mesh(tmp_path / "model.gltf").faces) == 1
