"""read_mesh on foreign files (not written by stepterrain): glTF primitives and accessors trimesh's reader misreads,
OBJ vertices and faces it reads wrong, each refused by name where it was a silently wrong mesh."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh

from .conftest import python_calls, traced_peak

#: a y-up ramp (heights along +y), two triangles
_RAMP = np.array([[0, 0, 0], [1, 0, 0], [1, 0.5, -1], [0, 0.5, -1]], np.float32)
_TRIANGLES = np.array([0, 1, 2, 0, 2, 3], np.uint16)


def _write_glb(path, tree: dict, binary: bytes) -> None:
    binary += b"\0" * (-len(binary) % 4)
    tree["buffers"] = [{"byteLength": len(binary)}]
    text = json.dumps(tree).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(text), b"JSON") + text
                     + struct.pack("<I4s", len(binary), b"BIN\0") + binary)


def _tree(primitives: list[dict], accessors: list[dict], views: list[dict]) -> dict:
    return {"asset": {"version": "2.0", "generator": "another tool"}, "scene": 0, "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}], "meshes": [{"primitives": primitives}], "accessors": accessors,
            "bufferViews": views}


def _ramp_glb(path, *, indices: np.ndarray, mode: int | None = None, triangles_too: bool = False) -> None:
    """The ramp's positions with ``indices`` in primitive ``mode`` and, ``triangles_too``, a second primitive of
    plain triangles beside it."""
    binary = _RAMP.tobytes() + indices.tobytes()
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": _RAMP.nbytes},
             {"buffer": 0, "byteOffset": _RAMP.nbytes, "byteLength": indices.nbytes}]
    accessors = [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                  "min": _RAMP.min(axis=0).tolist(), "max": _RAMP.max(axis=0).tolist()},
                 {"bufferView": 1, "componentType": 5123, "count": len(indices), "type": "SCALAR"}]
    primitive = {"attributes": {"POSITION": 0}, "indices": 1} | ({} if mode is None else {"mode": mode})
    primitives = [primitive]
    if triangles_too:
        binary += b"\0" * (-len(binary) % 4)
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": _TRIANGLES.nbytes})
        accessors.append({"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"})
        binary += _TRIANGLES.tobytes()
        primitives.append({"attributes": {"POSITION": 0}, "indices": 2})
    _write_glb(path, _tree(primitives, accessors, views), binary)


def test_triangles_read_y_up_turned_z_up(tmp_path):
    """The reference the refusals below stand against: a foreign y-up glTF of triangles comes back z-up."""
    _ramp_glb(tmp_path / "ramp.glb", indices=_TRIANGLES)
    mesh = read_mesh(tmp_path / "ramp.glb")
    np.testing.assert_allclose(mesh.vertices, _RAMP[:, [0, 2, 1]] * [1, -1, 1])
    assert len(mesh.faces) == 2


@pytest.mark.parametrize("triangles_too", [False, True])
def test_triangle_fan_refused(tmp_path, triangles_too):
    """A TRIANGLE_FAN primitive (mode 6) was skipped by trimesh's reader: alone, the file was refused as "KeyError:
    'world'"; beside a primitive of triangles, its surface was silently left out of the mesh."""
    path = tmp_path / "fan.glb"
    _ramp_glb(path, indices=np.array([0, 1, 2, 3], np.uint16), mode=6, triangles_too=triangles_too)
    with pytest.raises(DataFileError, match=r"fan\.glb.*TRIANGLE_FAN"):
        read_mesh(path)


def test_normalized_positions_refused(tmp_path):
    """Positions stored as normalized integers (KHR_mesh_quantization, ``"normalized": true``: 65535 is 1.0) were
    read as the integers, a mesh 65535 times too large, without a word."""
    quantized = (np.array([[0, 0, 0], [1, 0, 0], [1, 0.5, 1], [0, 0.5, 1]]) * 65535).astype(np.uint16)
    binary = b"".join(row.tobytes() + b"\0\0" for row in quantized)  # VEC3 of uint16, padded to a 4-byte stride
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(binary), "byteStride": 8},
             {"buffer": 0, "byteOffset": len(binary), "byteLength": _TRIANGLES.nbytes}]
    accessors = [{"bufferView": 0, "componentType": 5123, "normalized": True, "count": 4, "type": "VEC3",
                  "min": [0, 0, 0], "max": [65535, 32767, 65535]},
                 {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}]
    tree = _tree([{"attributes": {"POSITION": 0}, "indices": 1}], accessors, views)
    tree["extensionsUsed"] = tree["extensionsRequired"] = ["KHR_mesh_quantization"]
    _write_glb(tmp_path / "quantized.glb", tree, binary + _TRIANGLES.tobytes())
    with pytest.raises(DataFileError, match=r"quantized\.glb.*accessor 0.*normalized"):
        read_mesh(tmp_path / "quantized.glb")


def test_obj_vertex_of_two_coordinates_refused(tmp_path):
    """An OBJ ``v`` line of two numbers made trimesh's reader clip every vertex to two coordinates: a mesh of (N, 2)
    vertices, which info described with 2-D bounds and every later step crashed on."""
    path = tmp_path / "short.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n")
    with pytest.raises(DataFileError, match=r"short\.obj.*fewer than 3 coordinates.*'v 0 1'"):
        read_mesh(path)


@pytest.mark.parametrize("face", ["f 0 1 2", "f 1 2 0", "f 1/0 2/1 3/1", "f 3 2 1 0"])
def test_obj_face_index_zero_refused(tmp_path, face):
    """OBJ indices start at 1 (0 names no vertex): trimesh's reader took a 0 as the first vertex and shifted the
    others, so ``f 0 1 2`` became the degenerate face (0, 0, 1) without a word."""
    path = tmp_path / "zero.obj"
    path.write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n{face}\n")
    with pytest.raises(DataFileError, match=r"zero\.obj.*index 0"):
        read_mesh(path)


@pytest.mark.parametrize("face", ["f 1 2 3", "f -3 -2 -1", "f 1/1 2/1 3/1", "f 1//1 2//1 3//1"])
def test_obj_faces_without_zero_read(tmp_path, face):
    """The refusal above leaves good faces alone (negative indices count back from the last vertex)."""
    path = tmp_path / "good.obj"
    path.write_text(f"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n{face}\n")
    mesh = read_mesh(path)
    assert len(mesh.faces) == 1
    np.testing.assert_allclose(np.sort(mesh.vertices[mesh.faces[0]], axis=0),
                               np.sort(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float), axis=0))


def test_obj_objects_after_faces_read(tmp_path):
    """Vertices with zero coordinates after the first face (a second object) are no face naming index 0."""
    path = tmp_path / "two.obj"
    path.write_text("o a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\n"
                    "f -3 -2 -1\n")
    mesh = read_mesh(path)
    assert len(mesh.faces) == 3  # the quad as two triangles
    assert np.isclose(mesh.area, 1.5)


_PLY_HEAD = ("ply\nformat {form} 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
             "element face {faces}\nproperty list uchar int vertex_indices\nproperty int label\nend_header\n")
_PLY_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 2, 0], [2, 0.5, 0]], np.float32)


@pytest.mark.parametrize(("polygons", "form"), [
    ([[0, 1, 2, 3], [3, 2, 4], [1, 5, 2]], "ascii"),  # a quad among triangles
    ([[0, 1, 2, 3], [3, 2, 4, 3]], "ascii"),  # quads only
    ([[0, 1, 2, 3], [3, 2, 4, 3]], "binary_big_endian"),
    ([[3, 2, 4], [0, 1, 5, 2, 3], [0, 1, 2, 3]], "ascii"),  # a pentagon, a quad
    ([[0, 1, 2], [3, 2, 4]], "ascii"),  # triangles: trimesh read the label as (N, 1), which was dropped too
])
def test_ply_polygon_face_attributes_follow_triangles(tmp_path, polygons, form):
    """A PLY of quads or polygons with a face property (a classification, a label): trimesh's reader cuts the
    polygons into triangles (triangles first, then the quads' first halves, their second halves, the polygons'
    fans), and the property, one per polygon, was dropped without a word. Each triangle now carries its polygon's
    value: checked against which polygon's corners the triangle's are."""
    labels = [10 * (i + 1) for i in range(len(polygons))]
    rows = list(zip(polygons, labels, strict=True))
    path = tmp_path / "polygons.ply"
    head = _PLY_HEAD.format(form=form, faces=len(polygons)).encode()
    if form == "ascii":
        body = "".join(" ".join(map(str, v)) + "\n" for v in _PLY_VERTICES.tolist())
        body += "".join(f"{len(p)} {' '.join(map(str, p))} {label}\n" for p, label in rows)
        path.write_bytes(head + body.encode())
    else:
        body = _PLY_VERTICES.astype(">f4").tobytes()
        body += b"".join(struct.pack(f">B{len(p)}ii", len(p), *p, label) for p, label in rows)
        path.write_bytes(head + body)
    mesh = read_mesh(path)
    label = mesh.face_attributes["label"]
    assert len(label) == len(mesh.faces) == sum(len(p) - 2 for p in polygons)
    for face, value in zip(mesh.faces.tolist(), label.tolist(), strict=True):
        owner = polygons[labels.index(value)]
        assert set(face) <= set(owner)


@pytest.mark.parametrize("order", ["<", ">"])
def test_binary_ply_of_mixed_polygons_refused_by_name(tmp_path, order):
    """A binary PLY of triangles and quads is valid, but trimesh's binary reader takes every list as long as the
    first and refused it as "PLY is unexpected length!", which reads as a file cut short: it is said what it is."""
    form = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    head = (f"ply\nformat {form} 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 2\nproperty list uchar int vertex_indices\nend_header\n").encode()
    body = _PLY_VERTICES[:5].astype(order + "f4").tobytes()
    body += struct.pack(f"{order}B4i", 4, 0, 1, 2, 3) + struct.pack(f"{order}B3i", 3, 3, 2, 4)
    (tmp_path / "mixed.ply").write_bytes(head + body)
    with pytest.raises(DataFileError, match=r"mixed\.ply.*face 0's vertex_indices has 4, face 1's 3"):
        read_mesh(tmp_path / "mixed.ply")
    quads = body[:-13] + struct.pack(f"{order}B4i", 4, 3, 2, 4, 3)
    (tmp_path / "short.ply").write_bytes(head + quads[:-4])  # quads cut short: not said to be mixed
    with pytest.raises(DataFileError, match=r"short\.ply") as caught:
        read_mesh(tmp_path / "short.ply")
    assert "differ in length" not in str(caught.value)


@pytest.mark.parametrize("kind, code", [("int64", "q"), ("uint64", "Q"), ("float16", "e")])
@pytest.mark.parametrize("element", ["vertex", "face"])
def test_binary_ply_of_mixed_polygons_with_a_64_bit_or_half_property_refused_by_name(tmp_path, kind, code, element):
    """trimesh reads PLY properties of int64, uint64 and float16, which the walk over a binary PLY's lists did not know:
    a file of triangles and quads with such a property got trimesh's bare "PLY is unexpected length!" again."""
    vertex_extra = f"property {kind} id\n" if element == "vertex" else ""
    face_extra = f"property {kind} id\n" if element == "face" else ""
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
            f"property float z\n{vertex_extra}element face 2\nproperty list uchar int vertex_indices\n{face_extra}"
            "end_header\n").encode()
    body = b"".join(_PLY_VERTICES[k].astype("<f4").tobytes() + (struct.pack(f"<{code}", k) if vertex_extra else b"")
                    for k in range(5))
    tail = struct.pack(f"<{code}", 7) if face_extra else b""
    body += struct.pack("<B4i", 4, 0, 1, 2, 3) + tail + struct.pack("<B3i", 3, 3, 2, 4) + tail
    (tmp_path / "mixed.ply").write_bytes(head + body)
    with pytest.raises(DataFileError, match=r"mixed\.ply.*face 0's vertex_indices has 4, face 1's 3"):
        read_mesh(tmp_path / "mixed.ply")


@pytest.mark.parametrize("mode", [1, 3])
def test_gltf_of_lines_only_refused(tmp_path, mode):
    """A glTF of lines only (LINES, LINE_STRIP) read as an empty mesh, 0 vertices, 0 faces in ``stepterrain info``
    without a word, where the file holds positions: refused as no mesh. Lines beside triangles are left out of the
    mesh, as before."""
    _ramp_glb(tmp_path / "lines.glb", indices=np.array([0, 1, 1, 2], np.uint16), mode=mode)
    with pytest.raises(DataFileError, match=r"lines\.glb.*lines only"):
        read_mesh(tmp_path / "lines.glb")
    _ramp_glb(tmp_path / "both.glb", indices=np.array([0, 1, 1, 2], np.uint16), mode=mode, triangles_too=True)
    assert len(read_mesh(tmp_path / "both.glb").faces) == 2


def test_gltf_buffer_view_past_its_buffer_refused_by_name(tmp_path):
    """A bufferView reaching past its buffer's bytes was refused as "AssertionError: " (trimesh's bare assert)."""
    path = tmp_path / "over.glb"
    _ramp_glb(path, indices=_TRIANGLES)
    data = bytearray(path.read_bytes())
    length = struct.unpack_from("<I", data, 12)[0]
    tree = json.loads(bytes(data[20:20 + length]))
    tree["bufferViews"][1]["byteLength"] = 400
    tree["accessors"][1]["count"] = 200
    binary = bytes(data[20 + length + 8:])
    tree.pop("buffers")
    _write_glb(path, tree, binary)
    with pytest.raises(DataFileError, match=r"over\.glb.*bufferView 1 ends at byte 448 of buffer 0, which holds 60"):
        read_mesh(path)


def _strip_ply(path, strip: list[int], *, binary: bool) -> None:
    """A PLY of a 3 x 2 grid of vertices (z = x + 10 y) whose triangles are one ``tristrips`` row, as the Stanford
    scanning repository's tools and VCG write them, and no face element."""
    vertices = np.array([[x, y, x + 10 * y] for y in range(2) for x in range(3)], np.float32)
    head = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0", "element vertex 6",
            "property float x", "property float y", "property float z", "element tristrips 1",
            "property list int int vertex_indices", "end_header"]
    if binary:
        body = vertices.tobytes() + np.array([len(strip), *strip], "<i4").tobytes()
        path.write_bytes(("\n".join(head) + "\n").encode() + body)
    else:
        rows = [" ".join(map(str, v)) for v in vertices.tolist()] + [" ".join(map(str, [len(strip), *strip]))]
        path.write_text("\n".join(head + rows) + "\n")


@pytest.mark.parametrize("binary", [False, True])
def test_ply_triangle_strips_read_as_triangles(tmp_path, binary):
    """trimesh's reader skips a ``tristrips`` element: the mesh came back as its 6 vertices without a face. Its
    strips (-1 between them) are triangles, every other one turned so all face up as the strip winds, and a
    stitching triangle naming a vertex twice dropped; each triangle's corners are those of the grid's cells."""
    # the 3 x 2 grid: 0 1 2 along y = 0, 3 4 5 along y = 1; strip 3 0 4 1 5 2 winds its two cells' four triangles
    _strip_ply(tmp_path / "strips.ply", [3, 0, 4, 1, -1, 4, 1, 5, 2, 2], binary=binary)
    mesh = read_mesh(tmp_path / "strips.ply")
    assert mesh.faces.tolist() == [[3, 0, 4], [4, 0, 1], [4, 1, 5], [5, 1, 2]]
    normals = np.cross(*(mesh.vertices[mesh.faces[:, 1:]] - mesh.vertices[mesh.faces[:, :1]]).transpose(1, 0, 2))
    assert (normals[:, 2] > 0).all()  # one winding: all face up, as the strip starts (3 0 4 is anticlockwise from +z)
    np.testing.assert_allclose(mesh.area, 2 * np.sqrt(1 + 1 + 100))  # two 1 x 1 cells on the plane z = x + 10 y


_OBJ_SQUARE = "v 0 0 0\nv 1 0 0\nv 1 1 0.5\nv 0 1 0\nvn 0 0 1\nf 1 2 3\nf 1//1 3//1 4//1\n"


@pytest.mark.parametrize("layout", ["tabs", "tab after keyword", "indented", "indented with tabs, CRLF"])
def test_obj_written_with_tabs_or_indented_reads_as_with_spaces(tmp_path, layout):
    """OBJ words are separated by white space: trimesh's reader finds a statement by a newline, its keyword and one
    space, and skipped every other line without a word: a file written with tabs came back empty (0 vertices, 0
    faces), an indented one as its first vertex alone. Each reads as the same file with single spaces does."""
    text = {"tabs": _OBJ_SQUARE.replace(" ", "\t"),
            "tab after keyword": _OBJ_SQUARE.replace("v ", "v\t").replace("f ", "f\t"),
            "indented": "".join(f"  {line}\n" for line in _OBJ_SQUARE.splitlines()),
            "indented with tabs, CRLF": "".join(f"\t{line}\r\n" for line in _OBJ_SQUARE.splitlines())}[layout]
    (tmp_path / "plain.obj").write_text(_OBJ_SQUARE)
    (tmp_path / "loose.obj").write_bytes(text.encode())
    plain, loose = read_mesh(tmp_path / "plain.obj"), read_mesh(tmp_path / "loose.obj")
    assert len(plain.vertices) == 4 and len(plain.faces) == 2  # the reference itself
    np.testing.assert_array_equal(loose.vertices, plain.vertices)
    np.testing.assert_array_equal(loose.faces, plain.faces)
    assert loose.metadata["name"] == "loose.obj"


def test_obj_of_several_materials_keeps_its_vertices_once(tmp_path):
    """An OBJ of vertex indices only with several ``usemtl`` came back split at the materials (trimesh's one mesh per
    material, joined): its seam vertices repeated, its unused vertex dropped, the closed surface open. It keeps the
    file's vertices, one per ``v`` line in order, its faces in the file's order, and each face's material colour."""
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    tetra = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    materials = ["red", "blue", "red", "blue"]  # alternating: each usemtl a chunk of its own
    lines = ["mtllib m.mtl", *(f"v {x:g} {y:g} {z:g}" for x, y, z in corners), "v 9 9 9"]
    for face, material in zip(tetra, materials, strict=True):
        lines += [f"usemtl {material}", "f " + " ".join(str(i + 1) for i in face)]
    (tmp_path / "t.obj").write_text("\n".join(lines) + "\n")
    mesh = read_mesh(tmp_path / "t.obj")
    assert np.array_equal(mesh.vertices, [*corners, [9, 9, 9]])
    assert np.array_equal(mesh.faces, tetra)
    assert mesh.is_watertight
    kd = {"red": [255, 0, 0, 255], "blue": [0, 0, 255, 255]}
    assert np.array_equal(mesh.visual.face_colors, [kd[m] for m in materials])
    # without its .mtl: the same geometry, no colours made up
    (tmp_path / "m.mtl").unlink()
    bare = read_mesh(tmp_path / "t.obj")
    assert np.array_equal(bare.vertices, mesh.vertices) and np.array_equal(bare.faces, tetra)
    assert bare.visual.kind is None


def test_obj_trailing_comments_read(tmp_path):
    """A comment after an OBJ statement of numbers (``v 0 0 0 # a``, ``f 1 2 3 # x``) was refused with NumPy's
    "could not be read to its end due to unmatched data"; it is dropped (a zero or slash in it not taken for an
    index), while a ``#`` in a name (``usemtl Material#1``) stays part of the name."""
    (tmp_path / "m.mtl").write_text("newmtl Material#1\nKd 1 0 0\nnewmtl b\nKd 0 0 1\n")
    (tmp_path / "c.obj").write_text("mtllib m.mtl\nv 0 0 0 # a\nv 1 0 0\t# b\nv 0 1 0#c\nv 1 1 0\nv 7 7 7 # unused\n"
                                    "usemtl Material#1\nf 1 2 3 # x 0 a/b\nusemtl b\nf 2 4 3#y\n")
    mesh = read_mesh(tmp_path / "c.obj")
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [7, 7, 7]])
    assert np.array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])
    assert np.array_equal(mesh.visual.face_colors, [[255, 0, 0, 255], [0, 0, 255, 255]])
    (tmp_path / "short.obj").write_text("v 0 0 0\nv 1 0 # two\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(DataFileError, match="line 2, 'v 1 0 # two'"):
        read_mesh(tmp_path / "short.obj")


@pytest.mark.parametrize("form", ["bytes", "floats", "normals"])
def test_off_vertex_colours_read(tmp_path, form):
    """A COFF's vertex colours (RGB or RGBA after the coordinates, and after the normals of a CNOFF) were dropped by
    trimesh's reader; they come back as RGBA bytes, written as integers bytes, with a decimal point floats 0..1."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    colours = np.array([[255, 0, 0, 255], [0, 255, 0, 128], [0, 0, 255, 255], [10, 20, 30, 255]], np.uint8)
    keyword, rows = ("CNOFF" if form == "normals" else "COFF"), []
    for vertex, colour in zip(vertices, colours, strict=True):
        numbers = [f"{x:g}" for x in vertex] + (["0", "0", "1"] if form == "normals" else [])
        numbers += [repr(int(c) / 255) for c in colour] if form == "floats" else [str(c) for c in colour]
        rows.append(" ".join(numbers))
    (tmp_path / "c.off").write_text(f"{keyword}\n# a comment\n4 2 0\n" + "\n".join(rows) + "\n3 0 1 2\n3 1 3 2\n")
    mesh = read_mesh(tmp_path / "c.off")
    assert np.array_equal(mesh.vertices, vertices) and np.array_equal(mesh.faces, [[0, 1, 2], [1, 3, 2]])
    assert np.array_equal(mesh.visual.vertex_colors, colours)


def test_off_vertex_colours_of_zeros_and_ones_dropped(tmp_path):
    """Integer colours of 0 and 1 only are floats (green) or bytes (nearly black): the mesh is read (as before its
    colours were read), the colours dropped with a warning saying why, never guessed; RGB gets alpha 255, and a plain
    OFF has no colours."""
    (tmp_path / "rgb.off").write_text("COFF\n3 1 0\n0 0 0 0 255 0\n1 0 0 9 9 9\n0 1 0 0 0 0\n3 0 1 2\n")
    assert np.array_equal(read_mesh(tmp_path / "rgb.off").visual.vertex_colors[:, 3], [255] * 3)
    (tmp_path / "ones.off").write_text("COFF\n3 1 0\n0 0 0 0 1 0\n1 0 0 1 1 1\n0 1 0 0 0 0\n3 0 1 2\n")
    with pytest.warns(UserWarning, match="integers of 0 and 1 only.*dropped"):
        mesh = read_mesh(tmp_path / "ones.off")
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]]) and np.array_equal(mesh.faces, [[0, 1, 2]])
    assert mesh.visual.kind is None


@pytest.mark.parametrize("rows", ["0 0 0 1\n1 0 0 2\n0 1 0 3", "0 0 0 9 9 9\n1 0 0 9 9\n0 1 0 9 9 9",
                                  "0 0 0\n1 0 0\n0 1 0"])
def test_off_vertex_colours_uneven_dropped(tmp_path, rows):
    """A COFF whose vertex lines hold no RGB(A) colour each (Geomview's colour map index, one number; colours of
    different lengths; none) was read by trimesh's reader, coordinates alone: it still is, with a warning that its
    colours are dropped."""
    (tmp_path / "u.off").write_text(f"COFF\n3 1 0\n{rows}\n3 0 1 2\n")
    with pytest.warns(UserWarning, match="vertex colours are dropped"):
        mesh = read_mesh(tmp_path / "u.off")
    assert np.array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]]) and np.array_equal(mesh.faces, [[0, 1, 2]])
    assert mesh.visual.kind is None
    (tmp_path / "plain.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert read_mesh(tmp_path / "plain.off").visual.kind is None


def _foreign_3mf(path, unit, objects=1):
    """A 3MF as another tool writes it: ``objects`` tetrahedra in a model of ``unit`` (None: no attribute)."""
    import zipfile

    shapes = "".join(
        f'<object id="{k + 1}" type="model"><mesh><vertices><vertex x="{k}" y="0" z="0"/><vertex x="{k + 1}" y="0" '
        f'z="0"/><vertex x="{k}" y="1" z="0"/><vertex x="{k}" y="0" z="1"/></vertices><triangles>'
        '<triangle v1="0" v2="2" v3="1"/><triangle v1="0" v2="1" v3="3"/><triangle v1="1" v2="2" v3="3"/>'
        '<triangle v1="0" v2="3" v3="2"/></triangles></mesh></object>' for k in range(objects))
    items = "".join(f'<item objectid="{k + 1}"/>' for k in range(objects))
    declared = f' unit="{unit}"' if unit else ""
    model = (f'<?xml version="1.0" encoding="UTF-8"?><model{declared} xml:lang="en-US" '
             f'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"><resources>{shapes}</resources>'
             f'<build>{items}</build></model>')
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("[Content_Types].xml", '<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.'
                         'openxmlformats.org/package/2006/content-types"><Default Extension="model" ContentType="'
                         'application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
        archive.writestr("_rels/.rels", '<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
                         'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel.model" '
                         'Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>'
                         '</Relationships>')
        archive.writestr("3D/3dmodel.model", model)
    return path


@pytest.mark.parametrize(("unit", "units"), [("meter", "meters"), ("inch", "inches"), ("millimeter", None),
                                             (None, None)])
def test_3mf_unit_read_and_kept_on_a_round_trip(tmp_path, unit, units):
    """A foreign 3MF's ``unit`` was not read: one in metres, saved again, declared millimetres (1000 times too small
    in a slicer). It comes back as ``metadata["units"]`` (none for millimetres, 3MF's default, as a mesh without
    units writes), and save_mesh declares it again."""
    import zipfile

    from stepterrain.export import save_mesh

    mesh = read_mesh(_foreign_3mf(tmp_path / "f.3mf", unit))
    assert len(mesh.vertices) == 4 and len(mesh.faces) == 4
    assert mesh.metadata.get("units") == units
    save_mesh(mesh, tmp_path / "again.3mf")
    model = zipfile.ZipFile(tmp_path / "again.3mf").read("3D/3dmodel.model").decode()
    assert f'unit="{unit or "millimeter"}"' in model
    assert read_mesh(tmp_path / "again.3mf").metadata.get("units") == units


def test_obj_of_several_materials_polygons_and_negative_indices(tmp_path):
    """The faces of an OBJ of several ``usemtl`` are read from its ``f`` lines (trimesh's reader gives the vertices and
    materials, one mesh per material): quads, larger polygons and negative indices as trimesh's reader reads them, in
    the file's order, each with its chunk's colour (a material the ``.mtl`` lacks, and faces before any ``usemtl``,
    trimesh's default)."""
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    vertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 2, 0], [5, 5, 5]]
    text = ("mtllib m.mtl\n" + "".join(f"v {x:g} {y:g} {z:g}\n" for x, y, z in vertices) + "f 1 2 3\nusemtl red\n"
            "f 1 2 3 4\nusemtl blue\nf -6 -5 -4 -2 -3\nusemtl nowhere\nf 2 3 4\nusemtl red\n\tf 1  3\t4 # x\n")
    (tmp_path / "p.obj").write_text(text)
    mesh = read_mesh(tmp_path / "p.obj")
    # by hand: a quad (a, b, c), (c, d, a); a pentagon a fan from its first corner; -k counts back from 6 v lines
    expected = [[0, 1, 2], [0, 1, 2], [2, 3, 0], [0, 1, 2], [0, 2, 4], [0, 4, 3], [1, 2, 3], [0, 2, 3]]
    assert np.array_equal(mesh.vertices, vertices) and np.array_equal(mesh.faces, expected)
    grey, red, blue = [102, 102, 102, 255], [255, 0, 0, 255], [0, 0, 255, 255]
    assert np.array_equal(mesh.visual.face_colors, [grey, red, red, blue, blue, blue, grey, red])


def test_obj_chunk_faces_vectorised_and_as_a_reference_reads():
    """The faces of an OBJ of several ``usemtl`` were read by a Python loop over its lines (90,000 vertices in two
    materials: 0.39 -> 0.90 s a read): they are read by NumPy over the text's bytes, as many calls for 5,000 faces as
    for 50 in as many chunks (the loop made 2 a face), and as a line-by-line reference reads them: CRLF,
    several blanks, quads, polygons, negative indices, faces of fewer than 3 corners skipped."""
    from stepterrain.export import _obj_chunk_faces

    rng = np.random.default_rng(7)

    def text(faces: int) -> bytes:
        lines = []
        for k in range(faces):
            lines += ["v 1 2 3"] * int(rng.integers(0, 3))
            if k % 7 == 0 and k < 50:  # as many chunks in each
                lines.append(f"usemtl m{k % 3}")
            corners = [str(int(rng.integers(1, 50))) if rng.random() < 0.8 else str(-int(rng.integers(1, 3)))
                       for _ in range(int(rng.integers(2, 7)))]
            lines.append("f" + rng.choice([" ", "  "]) + rng.choice([" ", "  ", " \t"]).join(corners))
        return (rng.choice(["\n", "\r\n"])).join(lines).encode()

    def reference(data: bytes):
        names, chunks, seen = [None], [[]], 0
        for line in data.splitlines():
            if line.startswith(b"v "):
                seen += 1
            elif line.startswith(b"usemtl "):
                names.append(line[7:].strip())
                chunks.append([])
            elif line.startswith(b"f "):
                c = [int(w) - 1 if int(w) > 0 else seen + int(w) for w in line.split()[1:]]
                if len(c) == 4:
                    chunks[-1] += [c[:3], [c[2], c[3], c[0]]]
                elif len(c) >= 3:
                    chunks[-1] += [[c[0], c[i], c[i + 1]] for i in range(1, len(c) - 1)]
        return names, [np.asarray(chunk, np.int64).reshape(-1, 3) for chunk in chunks]

    for faces in (0, 1, 50, 300):
        data = text(faces)
        names, chunks = _obj_chunk_faces(data)
        expected_names, expected = reference(data)
        assert names == expected_names
        assert len(chunks) == len(expected) and all(np.array_equal(a, b) for a, b in zip(chunks, expected, strict=True))
    assert _obj_chunk_faces(b"v 0 0 0\nf 1 2.5 3\n") is None  # not integers: trimesh's reader decides
    small, large = python_calls(_obj_chunk_faces, text(50)), python_calls(_obj_chunk_faces, text(5000))
    assert large < small + 50, (small, large)


@pytest.mark.parametrize("form", ["vertices", "materials", "texture"])
def test_obj_relative_indices_count_back_from_the_lines_before_the_face(tmp_path, form):
    """An OBJ's negative index counts back from the ``v`` (``vt``, ``vn``) lines before its face (-1: the last one
    defined so far, by the OBJ specification); trimesh's reader counted back from the file's end, so two objects each
    of ``v v v f -3 -2 -1`` read as the second triangle twice ([[3, 4, 5], [3, 4, 5]]). One of faces of vertex
    indices, one of several ``usemtl`` and one of UVs each read as the same file of positive indices does; an index
    counting back past the file's start is refused by line."""
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    blocks = []
    for k, material in enumerate(["red", "blue"]):
        lines = [f"v {5 * k + x} {y} 0" for x, y in [(0, 0), (1, 0), (0, 1)]]
        if form == "texture":
            lines += [f"vt {u} {k}" for u in (0, 0.5, 1)]
        if form == "materials":
            lines.append(f"usemtl {material}")
        corners = [str(-i) if form != "texture" else f"{-i}/{-i}" for i in (3, 2, 1)]
        absolute = [str(3 * k + i) if form != "texture" else f"{3 * k + i}/{3 * k + i}" for i in (1, 2, 3)]
        blocks.append((lines, corners, absolute))
    head = "mtllib m.mtl\n" if form == "materials" else ""
    relative = head + "".join("\n".join([*lines, "f " + " ".join(c)]) + "\n" for lines, c, _ in blocks)
    plain = head + "".join("\n".join([*lines, "f " + " ".join(a)]) + "\n" for lines, _, a in blocks)
    (tmp_path / "relative.obj").write_text(relative)
    (tmp_path / "plain.obj").write_text(plain)
    mesh, reference = read_mesh(tmp_path / "relative.obj"), read_mesh(tmp_path / "plain.obj")
    assert np.array_equal(reference.faces, [[0, 1, 2], [3, 4, 5]])  # the reference itself
    assert np.array_equal(mesh.vertices, reference.vertices) and np.array_equal(mesh.faces, reference.faces)
    if form == "materials":
        assert np.array_equal(mesh.visual.face_colors, [[255, 0, 0, 255], [0, 0, 255, 255]])
    if form == "texture":
        assert np.array_equal(mesh.visual.uv, reference.visual.uv)
        assert np.array_equal(mesh.visual.uv[:, 1], [0, 0, 0, 1, 1, 1])
    (tmp_path / "past.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 2\nv 0 1 0\nf -4 -2 -1\n")
    with pytest.raises(DataFileError, match=r"line 5, 'f -4 -2 -1', names v -4, and 3 v lines come before it"):
        read_mesh(tmp_path / "past.obj")


def test_obj_of_carriage_return_line_ends_reads_as_with_newlines(tmp_path):
    """An OBJ whose lines end in a carriage return alone (classic Mac OS) was one line to trimesh's reader: one of
    several materials read as an empty mesh, one of a single mesh was refused with NumPy's "could not be read to its
    end". Each reads as the same file with newlines does (vertices, faces, material colours, metadata), and its
    index 0 is refused by line as there."""
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    texts = {"materials": "# stepterrain-metadata {\"a\":1}\nmtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
                          "usemtl red\nf 1 2 3\nusemtl blue\nf 2 4 3\n",
             "single": "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 7 7 7\nf 1 2 3\n",
             "texture": "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"}
    for name, text in texts.items():
        (tmp_path / f"{name}.obj").write_text(text)
        (tmp_path / f"{name}-cr.obj").write_bytes(text.replace("\n", "\r").encode())
        mesh, reference = read_mesh(tmp_path / f"{name}-cr.obj"), read_mesh(tmp_path / f"{name}.obj")
        assert len(reference.faces) > 0  # the reference itself
        assert np.array_equal(mesh.vertices, reference.vertices) and np.array_equal(mesh.faces, reference.faces)
        assert mesh.visual.kind == reference.visual.kind
    assert np.array_equal(mesh.visual.uv, reference.visual.uv)
    materials = read_mesh(tmp_path / "materials-cr.obj")
    assert np.array_equal(materials.visual.face_colors, [[255, 0, 0, 255], [0, 0, 255, 255]])
    assert materials.metadata["a"] == 1
    (tmp_path / "zero.obj").write_bytes(b"v 0 0 0\rv 1 0 0\rv 0 1 0\rf 0 1 2\r")
    with pytest.raises(DataFileError, match="line 4, 'f 0 1 2', names index 0"):
        read_mesh(tmp_path / "zero.obj")


def test_off_byte_order_mark_keeps_colours_and_a_word_colour_is_named(tmp_path):
    """A COFF written with a UTF-8 byte-order mark lost its colours (its keyword read as '\\ufeffCOFF', no OFF keyword;
    trimesh's reader read the mesh): they come back as without it. A colour that is no number was refused with NumPy's
    bare "could not convert string to float: 'red'": the error names the file, the line and what a vertex line holds."""
    body = "COFF\n# c\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 128\n0 1 0 0 0 255 255\n3 0 1 2\n"
    (tmp_path / "plain.off").write_text(body)
    (tmp_path / "bom.off").write_bytes(b"\xef\xbb\xbf" + body.encode())
    mesh, reference = read_mesh(tmp_path / "bom.off"), read_mesh(tmp_path / "plain.off")
    assert np.array_equal(reference.visual.vertex_colors, [[255, 0, 0, 255], [0, 255, 0, 128], [0, 0, 255, 255]])
    assert np.array_equal(mesh.vertices, reference.vertices) and np.array_equal(mesh.faces, reference.faces)
    assert np.array_equal(mesh.visual.vertex_colors, reference.visual.vertex_colors)
    (tmp_path / "word.off").write_text(body.replace("0 255 0 128", "0 red 0 128"))
    expected = (r"word\.off.*line 5, '1 0 0 0 red 0 128': its colour 'red' is not a number; a COFF vertex line "
                r"holds 3 numbers \(x y z\), then an RGB or RGBA")
    with pytest.raises(DataFileError, match=expected):
        read_mesh(tmp_path / "word.off")


def test_obj_byte_order_mark_reads_as_without(tmp_path):
    """An OBJ written with a UTF-8 byte-order mark before its first ``v`` line lost that vertex (trimesh's reader took
    the line for no statement): its faces named the vertices one further on without a word (here (1, 0, 0), (0, 1,
    0), (5, 5, 5)), or one past the end (an IndexError). It reads as without the mark."""
    text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\n"
    (tmp_path / "plain.obj").write_bytes(text)
    (tmp_path / "mark.obj").write_bytes(b"\xef\xbb\xbf" + text)
    mesh, reference = read_mesh(tmp_path / "mark.obj"), read_mesh(tmp_path / "plain.obj")
    assert np.array_equal(reference.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]])  # the reference itself
    assert np.array_equal(mesh.vertices, reference.vertices) and np.array_equal(mesh.faces, [[0, 1, 2]])


def test_obj_absolute_indices_vectorised_and_as_a_reference_counts():
    """The relative indices of an OBJ whose ``v`` lines follow faces are made absolute by NumPy over its bytes (a
    Python loop over its lines took 3 s for 168,200 faces): as many calls for 5,000 faces as for 50 (the loop made
    several a line), and each index as a line-by-line count of the ``v``, ``vt`` and ``vn`` lines before it reads it
    (1-2 and -3x left as they are)."""
    from stepterrain.export import _obj_absolute_indices

    rng = np.random.default_rng(11)

    def text(faces: int) -> tuple[bytes, list[list[bytes]]]:
        lines, expected, seen = [], [], [0, 0, 0]
        for _ in range(faces):
            for k, keyword in enumerate(["v 1 -2 3", "vt 0 -1", "vn 0 0 -1"]):
                for _ in range(int(rng.integers(0, 3))):
                    lines.append(keyword)
                    expected.append(keyword.encode().split())
                    seen[k] += 1
            words, absolute = [], []
            for _ in range(int(rng.integers(3, 6))):
                parts = [(-int(rng.integers(1, count + 1)) if rng.random() < 0.7 else int(rng.integers(1, 99)))
                         if count else None for count in seen]
                words.append("/".join("" if p is None else str(p) for p in parts).rstrip("/"))
                absolute.append("/".join("" if p is None else str(p if p > 0 else seen[k] + 1 + p)
                                         for k, p in enumerate(parts)).rstrip("/"))
            lines.append("f " + " ".join(w or "1" for w in words))
            expected.append([b"f", *(a.encode() or b"1" for a in absolute)])
        lines.append("f 1-2 -3x 4")
        expected.append([b"f", b"1-2", b"-3x", b"4"])
        return ("\n".join(lines) + "\n").encode(), expected

    for faces in (1, 40, 300):
        data, expected = text(faces)
        assert [line.split() for line in _obj_absolute_indices(data).splitlines()] == expected
    small = python_calls(_obj_absolute_indices, text(50)[0])
    large = python_calls(_obj_absolute_indices, text(5000)[0])
    assert large < small + 50, (small, large)


def _index_zero_line(data: bytes) -> int | None:
    """The line number of the first face line of the OBJ text ``data`` naming an index 0 (``0``, ``00``: not ``10``,
    ``0.5``, ``0e1``; signed, ``-0``, or not; after a blank or a slash, before any ``#`` of its line), by a Python
    loop over its lines: a reference for :func:`_check_obj_indices`."""
    for k, line in enumerate(data.split(b"\n")):
        if line.lstrip()[:2] not in (b"f ", b"f\t"):
            continue
        for at in range(1, len(line)):
            if line[at - 1 : at] in (b" ", b"\t", b"/"):
                rest = line[at + (line[at : at + 1] in (b"-", b"+")) :]
                if (rest[:1] == b"0" and b"#" not in line[: at - 1]
                        and rest.lstrip(b"0")[:1] not in [bytes([c]) for c in b"0123456789.eE"]):
                    return k + 1
    return None


@pytest.mark.parametrize("block", [1 << 24, 1, 7])
def test_obj_index_zero_check_vectorised_and_as_a_reference_refuses(tmp_path, monkeypatch, block):
    """The index-0 check of an OBJ's faces is NumPy over blocks of its lines (a regular expression's search, then a
    Python loop over every zero coordinate of the ``v`` lines after a face: 0.63 s for 168,000 faces before their
    vertices): as many calls for 4,000 such vertices as for 40, and the same refusals, by line, as a line-by-line
    reference on texts of zeros, comments, blanks, slashes, CRLF and long runs, in blocks of any size."""
    import stepterrain.export as export

    monkeypatch.setattr(export, "_OBJ_ZERO_BLOCK", block)
    rng = np.random.default_rng(5)
    words = [b"f", b"f ", b"f\t", b" f ", b"\t" * 10 + b"f ", b"v ", b"vt ", b"#", b"0", b"00", b"0" * 20, b"0.5",
             b"0e1", b"10", b"1", b"/", b" ", b"\t", b"\r\n", b"\n", b"\n", b"-1", b"x", b"0x", b"\r", b"g a-0 ",
             b"usemtl m#0 ", b"-0", b"+0", b"-", b"+"]
    path = tmp_path / "a.obj"
    refused = 0
    for _ in range(1500):
        data = b"".join(words[k] for k in rng.integers(0, len(words), int(rng.integers(0, 50))))
        path.write_bytes(data)
        line = _index_zero_line(data)
        refused += line is not None
        if line is None:
            export._check_obj_indices(path)
            export._check_obj_indices(path, data)
        else:
            for source in (None, data):
                with pytest.raises(ValueError, match=rf"^line {line}, .*names index 0"):
                    export._check_obj_indices(path, source)
    assert refused > 100

    def after(count: int) -> bytes:
        return b"f 1 2 3\n" + b"v 0 0 0\n" * count + b"f -3 10 -1\n"

    monkeypatch.undo()  # blocks of the size the reader looks at
    path.write_bytes(after(40))
    small = python_calls(export._check_obj_indices, path)
    path.write_bytes(after(4000))
    assert python_calls(export._check_obj_indices, path) < small + 50


@pytest.mark.parametrize(("text", "line"), [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n f 0 1 2\n", "line 4, 'f 0 1 2'"),  # indented, and no face at a line's start
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n  f 0 1 2\nf 1 2 3\n", "line 4, 'f 0 1 2'"),  # indented, before such a face
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -0 2 3\n", "line 4, 'f -0 2 3'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/+0 2/1 3/1\n", "line 5, 'f 1/\\+0 2/1 3/1'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 5 5 5\nv 6 5 5\nv 5 6 5\nf -0 -2 -3\nv 9 9 9\n", "line 8, 'f -0 -2 -3'"),
])
def test_obj_index_zero_signed_or_indented_refused(tmp_path, text, line):
    """An indented face before the first line starting with ``f`` was not looked at (`` f 0 1 2`` read as the
    degenerate (0, 0, 1)), and ``-0`` or ``+0`` was no index 0: read as the first vertex, or where ``v`` lines follow
    faces as the one after its face (``f -0 -2 -3`` above as (9 9 9), (6 5 5), (5 5 5))."""
    path = tmp_path / "zero.obj"
    path.write_text(text)
    with pytest.raises(DataFileError, match=rf"zero\.obj.*{line}, names index 0"):
        read_mesh(path)


def test_obj_newlines_replaced_as_lines_joined_without_a_list_of_lines(tmp_path):
    """An OBJ of carriage-return line ends (or a byte-order mark) is read with newlines for them, as its lines split
    and joined by newlines (CR, LF and CRLF each a line's end; a newline after the last line), without a list of
    its lines: that took 9 times the file's size."""
    from stepterrain.export import _obj_newlines

    rng = np.random.default_rng(3)
    pieces = [b"v 0 0 0", b"f 1 2 3", b"\r", b"\n", b"\r\n", b"\r\r", b"\n\r", b" ", b"#"]
    path = tmp_path / "a.obj"
    for _ in range(400):
        text = b"".join(pieces[k] for k in rng.integers(0, len(pieces), int(rng.integers(0, 12))))
        for data in (text, b"\xef\xbb\xbf" + text):
            path.write_bytes(data)
            lone = data.replace(b"\r\n", b"").find(b"\r") >= 0
            expected = b"\n".join(data.removeprefix(b"\xef\xbb\xbf").splitlines()) + b"\n"
            assert _obj_newlines(path) == (expected if lone or data[:1] == b"\xef" else None), data
    data = b"v 0 0 0\r" * 250_000
    path.write_bytes(data)
    peak = traced_peak(_obj_newlines, path)
    assert peak < 4 * len(data), (peak, len(data))


def _absolute_reference(data: bytes) -> bytes:
    """The OBJ text ``data`` (single blanks, no comments) with each face's negative indices counted back from the
    ``v``, ``vt``, ``vn`` lines before it, by a Python loop over its lines."""
    seen, out = [0, 0, 0], []
    for line in data.split(b"\n"):
        words = line.split(b" ")
        if words[0] in (b"v", b"vt", b"vn"):
            seen[[b"v", b"vt", b"vn"].index(words[0])] += 1
        elif words[0] == b"f":
            words = [words[0], *(b"/".join(str(seen[k] + 1 + int(p)).encode() if p[:1] == b"-" else p
                                           for k, p in enumerate(word.split(b"/"))) for word in words[1:])]
        out.append(b" ".join(words))
    return b"\n".join(out)


@pytest.mark.parametrize("block", [1, 7, 100, 1 << 20])
def test_obj_absolute_indices_in_blocks_of_lines(monkeypatch, block):
    """Relative indices are made absolute in blocks of whole lines (the arrays of the whole text took 56 times its
    size: 292 MB for 5 MB of one-face objects), each block counting on from the ``v``, ``vt``, ``vn`` lines and the
    lines before it: as a line-by-line reference reads them, a face counting back past the start refused by its line
    in the file, and 5 MB rewritten within 20 times its size."""
    import stepterrain.export as export

    monkeypatch.setattr(export, "_OBJ_INDEX_BLOCK", block, raising=False)
    rng = np.random.default_rng(7)
    lines = ["v 1 2 3", "vt 0 1", "vn 0 0 1", "f -1 -1 -1", "f -1/-1 1/-1 -1/1", "f 1//-1 -1//1 -1//-1", "g a-1"]
    for _ in range(60):
        words = ["v 1 2 3", "vt 0 1", "vn 0 0 1"] + [lines[k] for k in rng.integers(0, len(lines), 40)]
        data = ("\n".join(words) + "\n" * int(rng.integers(0, 2))).encode()
        assert export._obj_absolute_indices(data) == _absolute_reference(data), data
    data = b"v 1 2 3\nf 1 1 1\n" * 50 + b"f -1 -60 -1\n"
    with pytest.raises(ValueError, match=r"^line 101, .f -1 -60 -1., names v -60, and 50 v lines come before it"):
        export._obj_absolute_indices(data)
    if block == 1 << 20:
        data = b"v 1 2 3\nv 4 5 6\nv 7 8 9\nf -3 -2 -1\n" * 150_000
        peak = traced_peak(export._obj_absolute_indices, data)
        assert peak < 20 * len(data), (peak, len(data))


def _chunk_reference(data: bytes) -> tuple[list[bytes | None], list[list[list[int]]]]:
    """The faces of the OBJ text ``data`` per ``usemtl`` chunk, by a Python loop over its lines (as
    :func:`_obj_chunk_faces` read them before it was vectorised)."""
    names: list[bytes | None] = [None]
    chunks: list[list[list[int]]] = [[]]
    seen = 0
    for line in data.splitlines():
        if line.startswith(b"v "):
            seen += 1
        elif line.startswith(b"f "):
            corners = [int(word) - 1 if int(word) > 0 else seen + int(word) for word in line.split()[1:]]
            if len(corners) == 4:
                chunks[-1] += [corners[:3], [corners[2], corners[3], corners[0]]]
            elif len(corners) >= 3:
                chunks[-1] += [[corners[0], corners[i], corners[i + 1]] for i in range(1, len(corners) - 1)]
        elif line.startswith(b"usemtl "):
            names.append(line[7:].strip())
            chunks.append([])
    return names, chunks


@pytest.mark.parametrize("block", [1, 7, 100, 1 << 20])
def test_obj_chunk_faces_in_blocks_of_lines(monkeypatch, block):
    """The faces of an OBJ of several ``usemtl`` are read in blocks of whole lines (the arrays of the whole text took
    28 times its size: 285 MB for 10 MB), each counting on from the ``v`` lines and chunks before it: as a
    line-by-line reference reads them, and 10 MB read within 10 times its size."""
    import stepterrain.export as export

    monkeypatch.setattr(export, "_OBJ_INDEX_BLOCK", block, raising=False)
    rng = np.random.default_rng(9)
    lines = ["v 1 2 3", "f 1 2 3", "f -1 -2 -3 -1", "f 2 -1 1 -2 3", "f 1 2", "usemtl a", "usemtl b c", "g x", ""]
    for _ in range(60):
        data = ("v 0 0 0\nv 1 0 0\nv 0 1 0\n" + "\n".join(lines[k] for k in rng.integers(0, len(lines), 40))).encode()
        names, chunks = export._obj_chunk_faces(data)
        expected = _chunk_reference(data)
        assert names == expected[0]
        assert [chunk.tolist() for chunk in chunks] == expected[1], data
    assert export._obj_chunk_faces(b"v 0 0 0\nf 1 2 3\nusemtl a\nf 1 2.5 3\n") is None
    if block == 1 << 20:
        data = (b"".join(b"v %d 0 0\n" % i for i in range(300_000)) + b"usemtl a\n"
                + b"".join(b"f %d %d %d\n" % (i, i + 1, i + 2) for i in range(1, 300_000)) + b"usemtl b\nf 1 2 3\n")
        peak = traced_peak(export._obj_chunk_faces, data)
        assert peak < 10 * len(data), (peak, len(data))


def test_obj_of_carriage_returns_or_a_byte_order_mark_not_tidied_line_by_line(tmp_path):
    """An OBJ of carriage-return line ends, or with a byte-order mark, that needs no tidying (no tabs, indents or
    comments after numbers) is read as its text with newlines, not tidied by a Python loop over its lines (0.4-0.7 s
    more than the same file with newlines, of 2.6 s, for 39 MB): as many calls for 5,000 lines as for 50, and the
    same mesh as with newlines, for relative indices after vertices too."""
    from stepterrain.export import _obj_newlines, _obj_tidied

    def text(count: int, end: bytes) -> bytes:
        return (b"v 0 0 0" + end + b"v 1 0 0" + end + b"v 0 1 0" + end + b"f -3 -2 -1" + end) * count

    calls = []
    for count in (50, 5000):
        path = tmp_path / f"cr{count}.obj"
        path.write_bytes(text(count, b"\r"))
        calls.append(python_calls(_obj_tidied, path, _obj_newlines(path)))
    assert calls[1] < calls[0] + 50, calls
    for data in (text(3, b"\r"), b"\xef\xbb\xbf" + text(3, b"\n"), b"\xef\xbb\xbf" + text(3, b"\r\n")):
        path, plain = tmp_path / "odd.obj", tmp_path / "plain.obj"
        path.write_bytes(data)
        plain.write_bytes(text(3, b"\n"))
        mesh, expected = read_mesh(path), read_mesh(plain)
        np.testing.assert_array_equal(mesh.vertices[mesh.faces], expected.vertices[expected.faces])
        assert len(mesh.faces) == 3


@pytest.mark.parametrize("form", ["bytes", "floats", "quad"])
def test_off_face_colours_read(tmp_path, form):
    """An OFF's face colours (RGB or RGBA after a face line's indices: bytes as integers, floats 0..1 with a decimal
    point, as a COFF's vertex colours) were dropped by trimesh's reader without a word; a quad's colour is both its
    triangles' (in trimesh's order: triangles first, then the quads' first halves, then their second ones)."""
    head = "OFF\n# c\n5 3 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 2 0\n"
    if form == "floats":  # RGBA
        written = np.array([[255, 0, 0, 255], [0, 128, 0, 51], [0, 0, 255, 255]])
        rows = ["3 0 1 2 1.0 0.0 0.0 1", "3 1 4 2 0.0 0.5 0.0 0.2", "3 2 3 0 0 0 1.0 1.0"]
    else:  # RGB
        written = np.array([[255, 0, 0, 255], [0, 128, 0, 255], [0, 0, 255, 255]])
        rows = ["3 0 1 2 255 0 0", "3 1 4 2 0 128 0", f"{'4 2 3 0 4' if form == 'quad' else '3 2 3 0'} 0 0 255"]
    (tmp_path / "f.off").write_text(head + "\n".join(rows) + "\n")
    mesh = read_mesh(tmp_path / "f.off")
    assert mesh.visual.kind == "face"
    triangles = {(0, 1, 2): 0, (1, 4, 2): 1, (2, 3, 0): 2, (0, 4, 2): 2} if form == "quad" else None
    expected = written[[triangles[tuple(face)] for face in mesh.faces.tolist()]] if triangles else written
    assert len(mesh.faces) == (4 if form == "quad" else 3)
    np.testing.assert_array_equal(mesh.visual.face_colors, expected)


@pytest.mark.parametrize("rows", ["3 0 1 2 255 0 0\n3 1 3 2", "3 0 1 2 255 0 0\n3 1 3 2 0 255 0 9 9",
                                  "3 0 1 2 7\n3 1 3 2 8"])
def test_off_face_colours_uneven_dropped(tmp_path, rows):
    """Face lines some with a colour and some without, of colours of different lengths or of a colour map index
    (one number) are read without face colours, with a warning naming the words found (as a COFF's vertex colours)."""
    (tmp_path / "u.off").write_text(f"OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n{rows}\n")
    with pytest.warns(UserWarning, match=r"face lines hold \[.*\] numbers after their indices.*face colours are "
                                         "dropped"):
        mesh = read_mesh(tmp_path / "u.off")
    assert mesh.visual.kind is None and len(mesh.faces) == 2


def test_off_vertex_and_face_colours_keep_vertex_ones(tmp_path):
    """A COFF of vertex colours and face colours reads with its vertex colours, warning that the face ones are
    dropped (a mesh holds one kind)."""
    (tmp_path / "b.off").write_text("COFF\n3 1 0\n0 0 0 255 0 0\n1 0 0 0 255 0\n0 1 0 0 0 255\n3 0 1 2 9 9 9\n")
    with pytest.warns(UserWarning, match="vertex and face colours: its face colours are dropped"):
        mesh = read_mesh(tmp_path / "b.off")
    np.testing.assert_array_equal(mesh.visual.vertex_colors[:, :3], [[255, 0, 0], [0, 255, 0], [0, 0, 255]])
