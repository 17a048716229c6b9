"""read_mesh of small hand-made bad OFF, GLB and 3MF files: each refused as a DataFileError naming the file,
the line (OFF), the accessor (GLB) or element (3MF) and what is wrong (trimesh's reader refused them without a
line, with NumPy's or Python's words, or read them without a word), and a valid one read as before."""

from __future__ import annotations

import base64
import json
import re
import struct
import zipfile

import numpy as np
import pytest
import trimesh

from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh

_HEAD = "OFF\n3 {faces} 0\n0 0 0\n1 0 0\n0 1 0\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (_HEAD.format(faces=1) + "3 0 1 3\n", r"line 6, '3 0 1 3', names vertex 3, and the file has 3 vertices"),
        (_HEAD.format(faces=1) + "3 0 1 -1\n", r"line 6, '3 0 1 -1', names vertex -1, and the file has 3"),
        (_HEAD.format(faces=1) + "3 0 1 99999999999999999999\n", r"line 6, .*names vertex 9{20}, and"),
        (_HEAD.format(faces=1) + "3 0 1 2.5\n", r"line 6, '3 0 1 2\.5': a face line needs its count n"),
        (_HEAD.format(faces=2) + "3 0 1\n3 0 1 2\n", r"line 6, '3 0 1': a face line needs its count n"),
        (_HEAD.format(faces=1) + "3 0 1\n2\n", r"line 6, '3 0 1': a face line needs its count n"),
        (_HEAD.format(faces=2) + "3 0 1 2\n", r"its counts declare 3 vertices and 2 faces, .*4 lines after them: is"),
        (_HEAD.format(faces=2) + "3 0 1 2\n\n# more\n", r"its counts declare 3 vertices and 2 faces, .*4 lines after"),
        ("OFF\n5 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", r"its counts declare 5 vertices and 1 face, .*4 lines"),
        ("OFF\n3 x 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", r"line 2, '3 x 0': expected the counts of vertices and"),
    ],
)
def test_bad_off_refused_by_line(tmp_path, text, expected):
    """A face index past the vertices, negative, overflowing an int64 or no integer, and a file of fewer lines than
    its counts declare (of faces: read as the faces it had, without a word) are refused naming the file and the
    line, not with trimesh's "OFF file has a face index outside the range of its vertices", "invalid literal for
    int()", "Python int too large to convert to C long" or "cannot reshape array of size 12 into shape (5,3)"."""
    (tmp_path / "bad.off").write_text(text)
    with pytest.raises(DataFileError, match=rf"'{tmp_path / 'bad.off'}' as a mesh: ValueError: {expected}"):
        read_mesh(tmp_path / "bad.off")


@pytest.mark.parametrize("text", ["OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                                  "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 # c\n",
                                  "OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n4 0 1 3 2\n\n"])
def test_valid_off_reads(tmp_path, text):
    """A valid OFF (counts on the keyword's line, a comment after a face, a quad) reads as its faces."""
    (tmp_path / "ok.off").write_text(text)
    mesh = read_mesh(tmp_path / "ok.off")
    assert len(mesh.vertices) == int(text.split()[1 if text.startswith("OFF ") else 1])
    assert np.asarray(mesh.faces).max() < len(mesh.vertices)


@pytest.mark.parametrize("mark", [b"", b"\xef\xbb\xbf"])
@pytest.mark.parametrize("end", [b"\r", b"\r\n"])
def test_off_of_cr_line_ends_reads_as_of_newlines(tmp_path, mark, end):
    """An OFF (and a COFF, its colours) of CR or CRLF line ends, with a byte-order mark or not, reads as the same file
    of newlines: its vertices, faces and vertex colours."""
    for body in (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                 b"COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 128\n0 1 0 0 0 255 255\n3 0 1 2\n"):
        (tmp_path / "lf.off").write_bytes(body)
        (tmp_path / "cr.off").write_bytes(mark + body.replace(b"\n", end))
        mesh, reference = read_mesh(tmp_path / "cr.off"), read_mesh(tmp_path / "lf.off")
        assert np.array_equal(mesh.vertices, reference.vertices) and np.array_equal(mesh.faces, [[0, 1, 2]])
        assert mesh.visual.kind == reference.visual.kind
        if body.startswith(b"COFF"):
            assert np.array_equal(mesh.visual.vertex_colors, [[255, 0, 0, 255], [0, 255, 0, 128], [0, 0, 255, 255]])


def _glb(tree: dict, chunk: bytes) -> bytes:
    """A GLB of the JSON ``tree`` and the binary ``chunk`` (its header included), as glTF 2.0 §4.4 lays it out."""
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + chunk
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def _triangle_glb() -> tuple[dict, bytes]:
    """The JSON and binary chunk of one triangle's GLB, as trimesh writes it (accessor 0 its indices, 1 its
    positions)."""
    data = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False).export(file_type="glb")
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length]), data[20 + length :]


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda t: t["accessors"][1].update(count=1000), r"POSITION names accessor 1 of 1,000 VEC3 elements from "
                                                          r"byte 0 of bufferView 1, whose 36 bytes hold 3 of them"),
        (lambda t: t["accessors"][0].update(byteOffset=10000), r"indices names accessor 0 of 3 SCALAR elements from "
                                                               r"byte 10,000 of bufferView 0, whose 12 bytes hold 0"),
        (lambda t: t["meshes"][0]["primitives"][0]["attributes"].update(POSITION=99),
         r"POSITION names accessor 99, and the file has 2 accessor"),
        (lambda t: t["accessors"][0].update(bufferView=99), r"indices names accessor 0, whose bufferView is 99, and "
                                                            r"the file has 2 bufferView"),
        (lambda t: t["accessors"][1].pop("type"), r"POSITION names accessor 1, whose type None and componentType "
                                                  r"5126 are not glTF 2\.0's"),
        (lambda t: t["accessors"][0].update(componentType=5126), r"indices names accessor 0 of SCALAR 5126: indices "
                                                                 r"are SCALAR unsigned"),
    ],
)
def test_bad_glb_accessor_refused(tmp_path, change, expected):
    """An accessor past the file's, of no glTF type, past its bufferView's bytes or naming a bufferView the file
    lacks, and indices of floats are refused naming the file, the primitive's attribute and the accessor, not with
    trimesh's IndexError "list index out of range", KeyError 'type' or "cannot reshape array of size 9 into shape
    (1000,3)", and float indices not read as their bits' integers without a word."""
    tree, chunk = _triangle_glb()
    change(tree)
    (tmp_path / "bad.glb").write_bytes(_glb(tree, chunk))
    with pytest.raises(DataFileError, match=rf"'{tmp_path / 'bad.glb'}' as a mesh: ValueError: a glTF primitive's "
                                            rf"{expected}"):
        read_mesh(tmp_path / "bad.glb")


def test_glb_index_past_the_vertices_refused(tmp_path):
    """A stored index past the vertices is refused naming the face and the vertex count."""
    tree, chunk = _triangle_glb()
    chunk = bytearray(chunk)
    chunk[8 + 8 : 8 + 12] = struct.pack("<I", 7)  # the third index of the first bufferView
    (tmp_path / "bad.glb").write_bytes(_glb(tree, bytes(chunk)))
    with pytest.raises(DataFileError, match=r"face 0 names vertex 7, and the file has 3 vertices"):
        read_mesh(tmp_path / "bad.glb")


def test_valid_glb_reads(tmp_path):
    """The triangle's GLB as built here reads as its triangle (the accessor checks pass a valid file)."""
    (tmp_path / "ok.glb").write_bytes(_glb(*_triangle_glb()))
    assert read_mesh(tmp_path / "ok.glb").faces.tolist() == [[0, 1, 2]]


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ('v3="2"', 'v3="99999999999999999999"', r'3MF triangle 0 \(<triangle v1="0" v2="1" v3="9{20}"/>\): expected '
                                                r"v1, v2 and v3 integers .*int too big"),
        ('v3="2"', 'v3="x"', r"3MF triangle 0 .*v3=\"x\".*: expected v1, v2 and v3 integers .*invalid literal"),
        (' v3="2"', "", r"3MF triangle 0 \(<triangle v1=\"0\" v2=\"1\"/>\): expected v1, v2 and v3 .*; no 'v3'"),
        ('v3="2"', 'v3="7"', r"face 0 names vertex 7, and the file has 3 vertices"),
    ],
)
def test_bad_3mf_triangle_refused(tmp_path, old, new, expected):
    """A 3MF triangle of an index overflowing an int64, no integer or missing is refused naming the file, the
    triangle as written and what was expected, not with Python's OverflowError, ValueError or KeyError 'v3' alone;
    one past the vertices naming the face and the vertex count."""
    from stepterrain.export import save_mesh

    save_mesh(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False), tmp_path / "ok.3mf")
    with zipfile.ZipFile(tmp_path / "ok.3mf") as source, zipfile.ZipFile(tmp_path / "bad.3mf", "w") as target:
        for name in source.namelist():
            data = source.read(name)
            target.writestr(name, data.replace(old.encode(), new.encode(), 1) if name.endswith(".model") else data)
    with pytest.raises(DataFileError, match=rf"'{tmp_path / 'bad.3mf'}' as a mesh: ValueError: {expected}"):
        read_mesh(tmp_path / "bad.3mf")


@pytest.mark.parametrize(
    ("name", "data", "expected"),
    [
        ("past.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n",
         r"line 4, 'f 1 2 9{20}', names v 9{20}, and the file has 3 v lines"),
        ("past.glb", None, r"a glTF primitive's POSITION names accessor 1 of 1,000 VEC3 elements"),
        ("uv.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/2 3/1\n",
         r"line 5, 'f 1/1 2/2 3/1', names vt 2, and the file has 1 vt line:"),
    ],
)
def test_info_says_a_bad_mesh_file_in_one_line(tmp_path, capsys, name, data, expected):
    """``stepterrain info`` of a bad mesh file exits with status 2 and one line naming the file and what is wrong,
    without a traceback (trimesh's "index 9223372036854775806 is out of bounds" or NumPy's reshape before; of a face's
    texture index past the vt lines, the mesh described without its UVs)."""
    from .conftest import run_cli

    if data is None:
        tree, chunk = _triangle_glb()
        tree["accessors"][1]["count"] = 1000
        data = _glb(tree, chunk)
    (tmp_path / name).write_bytes(data)
    code, out, err = run_cli(capsys, "info", tmp_path / name)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert re.search(rf"stepterrain info: error: cannot read '.*{name}' as a mesh: ValueError: {expected}", err), err


@pytest.mark.parametrize("where", ["chunk", "file", "data"])
def test_gltf_buffer_shorter_than_declared_refused(tmp_path, where):
    """A buffer holding fewer bytes than its ``byteLength`` (a GLB's BIN chunk, a .gltf's side file or data URI cut
    short) is refused naming the buffer and both counts, not with trimesh's bare "AssertionError: "."""
    tree, chunk = _triangle_glb()
    payload = chunk[8 : 8 + struct.unpack_from("<I", chunk)[0]][:20]
    if where == "chunk":
        name, data = "bad.glb", _glb(tree, struct.pack("<II", 20, 0x004E4942) + payload)
        held = "the GLB's BIN chunk holds 20"
    else:
        if where == "file":
            (tmp_path / "bad.bin").write_bytes(payload)
            tree["buffers"][0]["uri"] = "bad.bin"
            held = r"its file '.*bad\.bin' holds 20"
        else:
            tree["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(payload).decode()
            held = "its data URI holds 20"
        name, data = "bad.gltf", json.dumps(tree).encode()
    (tmp_path / name).write_bytes(data)
    with pytest.raises(DataFileError, match=rf"'.*{name}' as a mesh: ValueError: glTF buffer 0 declares 48 bytes "
                                            rf"\(byteLength\), and {held}: the file is cut short"):
        read_mesh(tmp_path / name)
