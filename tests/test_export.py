"""save_mesh / save_image: every format round-trips, glTF extras, flat shading, atomic failures."""

from __future__ import annotations

import base64
import importlib.util
import json
import os
import re
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from stepterrain import export
from stepterrain.errors import DataFileError, InvalidInputError, MissingDependencyError
from stepterrain.export import MESH_EXTENSIONS, atomic_path, save_image, save_mesh
from stepterrain.terrain import as_terrain, heightfield_mesh


def stepped_like_mesh(offset: tuple[float, float] = (0.0, 0.0)) -> trimesh.Trimesh:
    """A small grid mesh with what stepped() attaches: face attributes (int32, bool), colours, metadata."""
    z = np.add.outer(np.arange(5.0), np.arange(6.0)) * 10.0
    mesh = heightfield_mesh(z, spacing=(30.0, -30.0), origin=offset)
    n = len(mesh.faces)
    mesh.face_attributes = {"level": np.arange(n, dtype=np.int32) % 3, "wall": np.arange(n) % 2 == 0}
    mesh.visual = trimesh.visual.ColorVisuals(
        mesh, vertex_colors=np.tile([10, 200, 30, 255], (len(mesh.vertices), 1))
    )
    mesh.metadata.update(
        {"generator": "test", "isovalues": np.array([0.0, 10.0, 20.0], np.float32), "gamma": np.float64(1)}
    )
    return mesh


def glb_json(path: Path) -> dict:
    data = path.read_bytes()
    magic, _version, _length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF"
    chunk_length, chunk_type = struct.unpack_from("<I4s", data, 12)
    assert chunk_type == b"JSON"
    return json.loads(data[20 : 20 + chunk_length])


def no_leftovers(folder: Path, expected: set[str]) -> None:
    assert {p.name for p in folder.iterdir()} == expected


def needs_3mf() -> None:
    for name in ("lxml", "networkx"):
        pytest.importorskip(
            name, reason="trimesh's 3MF writer needs lxml and networkx (pip install lxml networkx)"
        )


# ---------------------------------------------------------------------------------------------- formats
@pytest.mark.parametrize("ext", MESH_EXTENSIONS)
def test_round_trip(tmp_path, ext):
    if ext == ".3mf":
        needs_3mf()
    mesh = stepped_like_mesh()
    out = save_mesh(mesh, tmp_path / f"steps{ext}")
    assert out == tmp_path / f"steps{ext}" and out.stat().st_size > 0
    # read_mesh: a glTF's world is y-up (its node turns the z-up positions), read back z-up
    loaded = export.read_mesh(out) if ext in (".glb", ".gltf") else trimesh.load(out, force="mesh", process=False)
    assert len(loaded.faces) == len(mesh.faces)
    if ext == ".stl":  # STL stores three corners per face
        assert len(loaded.vertices) == 3 * len(mesh.faces)
    else:
        assert len(loaded.vertices) == len(mesh.vertices)
        np.testing.assert_allclose(loaded.vertices, mesh.vertices, atol=1e-4)
    no_leftovers(tmp_path, {f"steps{ext}"})
    # the caller's mesh is untouched
    assert mesh.face_attributes["wall"].dtype == bool and isinstance(mesh.metadata["isovalues"], np.ndarray)


def test_extension_is_case_insensitive(tmp_path):
    out = save_mesh(stepped_like_mesh(), tmp_path / "UPPER.GLB")
    assert glb_json(out)["asset"]["version"] == "2.0"


def test_glb_extras_and_no_normals(tmp_path):
    out = save_mesh(
        stepped_like_mesh(), tmp_path / "m.glb", metadata={"interval": np.float32(10), "note": "hi"}
    )
    tree = glb_json(out)
    (gltf_mesh,) = tree["meshes"]
    extras = gltf_mesh["extras"]
    assert extras["interval"] == 10.0 and extras["note"] == "hi"
    assert (
        extras["generator"] == "test" and extras["isovalues"] == [0.0, 10.0, 20.0] and extras["gamma"] == 1.0
    )
    for primitive in gltf_mesh["primitives"]:
        assert "NORMAL" not in primitive["attributes"]
        assert "COLOR_0" in primitive["attributes"]
    loaded = trimesh.load(out)
    (geometry,) = loaded.geometry.values()
    assert geometry.metadata["interval"] == 10.0


def test_gltf_is_self_contained(tmp_path):
    out = save_mesh(stepped_like_mesh(), tmp_path / "m.gltf", metadata={"k": 1})
    tree = json.loads(out.read_text())
    for buffer in tree["buffers"]:
        assert buffer["uri"].startswith("data:application/octet-stream;base64,")
        assert len(base64.b64decode(buffer["uri"].split(",", 1)[1])) == buffer["byteLength"]
    assert tree["meshes"][0]["extras"]["k"] == 1
    assert all("NORMAL" not in p["attributes"] for p in tree["meshes"][0]["primitives"])
    no_leftovers(tmp_path, {"m.gltf"})


def test_extras_are_json_safe(tmp_path):
    metadata = {
        "nan": float("nan"),
        "path": tmp_path,
        "tuple": (np.int64(1), np.float32(2.5), np.bool_(True)),
        "nested": {"a": np.arange(3)},
        "huge": np.zeros(100_000),
        "_private": 1,
    }
    mesh = stepped_like_mesh()
    mesh.metadata["thing"] = object  # the mesh's own metadata (a loader's, a caller's) is written as before
    tree = glb_json(save_mesh(mesh, tmp_path / "m.glb", metadata=metadata))
    extras = tree["meshes"][0]["extras"]
    assert extras["nan"] is None
    assert extras["path"] == str(tmp_path)
    assert extras["tuple"] == [1, 2.5, True]
    assert extras["nested"] == {"a": [0, 1, 2]}
    assert "huge" not in extras and "_private" not in extras
    assert extras["thing"] == str(object)


def test_numpy_metadata_round_trips_as_json_numbers_and_lists(tmp_path):
    """np.float64 heights, isovalue arrays (float32 or float64), numpy ints and bools, 0-d and 2-D arrays, and
    nested dicts and lists of them reach glTF extras as plain JSON numbers and lists, bit for bit."""
    metadata = {
        "height": np.float64(1234.5678901234567),
        "isovalues": np.array([0.1, 0.2, 1e-7, -3.5e12]),
        "levels32": np.array([0.1, 2.5], np.float32),
        "f32": np.float32(0.1),
        "count": np.int64(2**40),
        "u8": np.uint8(200),
        "flag": np.bool_(False),
        "grid": np.arange(6).reshape(2, 3),
        "zero_d": np.array(3.5),
        "names": np.array(["a", "b"]),
        "inf": np.float64(np.inf),
        "nested": {"a": [np.float64(1.5), {"b": np.int32(-3)}], "t": (1, "x", None)},
    }
    expected = {
        "height": 1234.5678901234567,
        "isovalues": [0.1, 0.2, 1e-7, -3.5e12],
        "levels32": [float(np.float32(0.1)), 2.5],
        "f32": float(np.float32(0.1)),
        "count": 2**40,
        "u8": 200,
        "flag": False,
        "grid": [[0, 1, 2], [3, 4, 5]],
        "zero_d": 3.5,
        "names": ["a", "b"],
        "inf": None,  # non-finite floats are null (JSON has no NaN or Infinity), as before
        "nested": {"a": [1.5, {"b": -3}], "t": [1, "x", None]},
    }
    for ext in (".glb", ".gltf"):
        out = save_mesh(stepped_like_mesh(), tmp_path / f"m{ext}", metadata=metadata)
        tree = glb_json(out) if ext == ".glb" else json.loads(out.read_text())
        extras = tree["meshes"][0]["extras"]
        assert {k: extras[k] for k in expected} == expected
        assert type(extras["height"]) is float and type(extras["count"]) is int and extras["flag"] is False
    (geometry,) = trimesh.load(tmp_path / "m.glb").geometry.values()
    assert geometry.metadata["height"] == 1234.5678901234567 and geometry.metadata["isovalues"][3] == -3.5e12


_NOT_JSON = r"must be JSON \(str, number, bool, None, list or dict of those\); got"


@pytest.mark.parametrize(
    ("metadata", "match"),
    [
        ({"owner": {"ann", "bob"}}, rf"^metadata\['owner'\] {_NOT_JSON} set$"),
        ({"owner": object()}, rf"^metadata\['owner'\] {_NOT_JSON} object$"),
        ({"blob": b"\x00\x01"}, rf"^metadata\['blob'\] {_NOT_JSON} bytes$"),
        ({"z": 1 + 2j}, rf"^metadata\['z'\] {_NOT_JSON} complex$"),
        ({"when": np.datetime64("2024-05-01")}, rf"^metadata\['when'\] {_NOT_JSON} datetime64$"),
        ({"run": {"a": [1, frozenset()]}}, rf"^metadata\['run'\]\['a'\]\[1\] {_NOT_JSON} frozenset$"),
        ({"phases": np.array([1j, 2j])}, rf"^metadata\['phases'\] {_NOT_JSON} an array of dtype complex128$"),
        ({"tags": np.array([b"a", b"b"])}, rf"^metadata\['tags'\] {_NOT_JSON} an array of dtype \|S1$"),
        ({"items": np.array([{}, None], dtype=object)}, rf"{_NOT_JSON} an array of dtype object$"),
        ({"run": {1: "a", "1": "b"}}, r"^metadata\['run'\] keys must be strings \(glTF extras are a JSON object\); "
                                      r"got 1$"),
        ({2: "x"}, r"^metadata keys must be strings \(glTF extras are a JSON object\); got 2$"),
    ],
)
def test_metadata_that_is_not_json_is_refused_before_writing(tmp_path, metadata, match):
    """Such values were written into glTF extras as their str (a set as "{'ann', 'bob'}", bytes as "b'...'", a
    complex array left out), silently; now refused, naming the key, before any file is written."""
    for ext in (".glb", ".ply"):
        with pytest.raises(InvalidInputError, match=match):
            save_mesh(stepped_like_mesh(), tmp_path / f"new{ext}", metadata=metadata)
    (tmp_path / "kept.glb").write_bytes(b"old")
    with pytest.raises(InvalidInputError, match=match):
        save_mesh(stepped_like_mesh(), tmp_path / "kept.glb", metadata=metadata)
    assert (tmp_path / "kept.glb").read_bytes() == b"old"
    no_leftovers(tmp_path, {"kept.glb"})


def test_large_coordinates_keep_precision_in_gltf(tmp_path):
    mesh = stepped_like_mesh(offset=(376328.655, 3807902.827))
    for ext in (".glb", ".gltf", ".ply"):
        loaded = export.read_mesh(save_mesh(mesh, tmp_path / f"utm{ext}"))
        np.testing.assert_allclose(loaded.vertices, mesh.vertices, rtol=0, atol=1e-3)


def test_ply_keeps_face_attributes(tmp_path):
    mesh = stepped_like_mesh()
    mesh.face_attributes["big"] = np.arange(len(mesh.faces), dtype=np.int64)
    mesh.face_attributes["pair"] = np.ones((len(mesh.faces), 2), np.float16)
    out = save_mesh(mesh, tmp_path / "m.ply")
    header = out.read_bytes().split(b"end_header")[0].decode()
    for line in ("property int level", "property uchar wall", "property int big", "property float pair_1"):
        assert line in header
    raw = trimesh.load(out, process=False).metadata["_ply_raw"]["face"]["data"]
    np.testing.assert_array_equal(raw["wall"], mesh.face_attributes["wall"].astype(np.uint8))
    np.testing.assert_array_equal(raw["level"], mesh.face_attributes["level"])


def test_empty_mesh(tmp_path):
    """A mesh with no faces (a view that sees nothing, an empty close-up) writes valid empty files: glTF
    forbids empty arrays and 0-byte buffers (the validator fixture checks them too), OBJ has no bare v/f lines."""
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
    points = trimesh.Trimesh(np.ones((4, 3)), np.zeros((0, 3), np.int64), process=False)  # vertices, no faces
    for mesh in (empty, points):
        for ext in MESH_EXTENSIONS:
            if mesh is points and ext in (".stl", ".3mf"):  # triangles only: refused (test_export_fixes.py)
                continue
            path = save_mesh(mesh, tmp_path / f"e{ext}")
            back = trimesh.load(path, force="mesh", process=False)
            assert len(back.faces) == 0
        tree = json.loads((tmp_path / "e.gltf").read_text())
        assert all(value != [] for value in tree.values())
        assert all(buffer["byteLength"] >= 1 for buffer in tree.get("buffers", []))
        lines = (tmp_path / "e.obj").read_text().splitlines()
        assert not [line for line in lines if line.strip() in ("v", "f")]
    # the metadata of an empty mesh (a tile of sea, a view of nothing) is kept, as the node's extras: trimesh's
    # writer dropped it with the mesh
    for ext in (".glb", ".gltf"):
        path = save_mesh(empty, tmp_path / f"m{ext}", metadata={"source": "sea", "isovalues": [0.0, 50.0]})
        data = path.read_bytes()
        tree = json.loads(data[20 : 20 + struct.unpack("<I", data[12:16])[0]] if ext == ".glb" else data)
        assert tree["nodes"] == [{"name": "m", "extras": {"source": "sea", "isovalues": [0.0, 50.0]}}]
        assert "buffers" not in tree and "meshes" not in tree
        if ext == ".glb":
            assert struct.unpack("<I", data[8:12])[0] == len(data)  # the header's length: no binary chunk
        assert len(trimesh.load(path, force="mesh", process=False).faces) == 0


def test_unknown_extension(tmp_path):
    with pytest.raises(
        InvalidInputError, match=r"unknown mesh extension '\.fbx'; supported: \.glb, \.gltf, \.obj"
    ):
        save_mesh(stepped_like_mesh(), tmp_path / "m.fbx")
    with pytest.raises(InvalidInputError, match=r"unknown mesh extension '\(none\)'"):
        save_mesh(stepped_like_mesh(), tmp_path / "m")
    no_leftovers(tmp_path, set())


@pytest.mark.parametrize("ext", MESH_EXTENSIONS)
@pytest.mark.parametrize(("faces", "shown"), [([[0, 1, 3]], r"\[0, 1, 3\]"), ([[0, 1, -1]], r"\[0, 1, -1\]")])
def test_faces_outside_the_vertices_are_refused(tmp_path, ext, faces, shown):
    """A process=False mesh whose faces index past its vertices (or -1) was written as it was: invalid GLB, glTF,
    OBJ, PLY and 3MF files (-1 became 4294967295 in glTF), and STL raised trimesh's IndexError. Now an
    InvalidInputError names the face; nothing is written."""
    mesh = trimesh.Trimesh([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], faces, process=False)
    with pytest.raises(InvalidInputError,
                       match=rf"^mesh faces must index its 3 vertices \(0 \.\. 2\); face 0 is {shown}$"):
        save_mesh(mesh, tmp_path / f"m{ext}")
    no_leftovers(tmp_path, set())


@pytest.mark.parametrize(("ext", "offset", "refused"), [
    (".stl", 1e300, True), (".glb", 1e300, False), (".gltf", 1e300, False), (".ply", 1e300, False),
    (".glb", 0.0, True), (".gltf", 0.0, True), (".stl", 0.0, True), (".ply", 0.0, False), (".obj", 0.0, False),
])  # fmt: skip
def test_coordinates_beyond_float32_are_refused_where_the_format_stores_float32(tmp_path, ext, offset, refused):
    """STL stores float32 coordinates and glTF float32 ones relative to the node translation: a mesh at x = 1e300
    (st.stepped(..., origin=(1e300, 0))) was written to STL as inf, and a glTF spanning 1e300 got inf positions
    (invalid files, a RuntimeWarning only). PLY (float64) and OBJ (text) hold them."""
    import warnings

    if offset:  # a small mesh far away: glTF keeps it (node translation), STL cannot
        mesh = trimesh.Trimesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]) + [offset, 0, 0], [[0, 1, 2]],
                               process=False)
    else:  # a mesh spanning 1e300
        mesh = trimesh.Trimesh(np.array([[0.0, 0, 0], [1e300, 0, 0], [0, 1, 0]]), [[0, 1, 2]], process=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no overflow on the way
        if refused:
            with pytest.raises(InvalidInputError, match=rf"{re.escape(ext)} stores float32 .*the mesh's x reaches "
                               r"(1e\+300|5e\+299 from it): write \.ply or \.obj"):
                save_mesh(mesh, tmp_path / f"m{ext}")
            no_leftovers(tmp_path, set())
        else:
            save_mesh(mesh, tmp_path / f"m{ext}")


@pytest.mark.parametrize("count", [3, 63, 64, 65, 640, 1000])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_vertex_anywhere_is_refused_and_bounds_are_exact(tmp_path, count, bad):
    """save_mesh's bounds reduce 64 rows side by side, then the rows left over: a NaN or inf in either part (first,
    last, just before and after the 64-row block) is refused by name with the count of such vertices, and finite
    bounds equal numpy's per-column min and max exactly (C order, Fortran order, float32)."""
    rng = np.random.default_rng(count)
    vertices = rng.normal(size=(count, 3)) * 1e5
    faces = np.arange(count - count % 3).reshape(-1, 3)
    for layout in (vertices, np.asfortranarray(vertices), vertices.astype(np.float32)):
        lo, hi = export._vertex_bounds(layout)
        assert np.array_equal(lo, layout.min(axis=0)) and np.array_equal(hi, layout.max(axis=0))
    for row in sorted({0, count - 1, min(count - 1, 63), min(count - 1, 64), count // 2}):
        spoiled = vertices.copy()
        spoiled[row, row % 3] = bad
        mesh = trimesh.Trimesh(spoiled, faces, process=False)
        with pytest.raises(InvalidInputError, match=rf"^mesh vertices must be finite to be written; got 1 of {count} "
                           rf"vertices with NaN or inf \(vertex {row} at \[.*\]\)$"):
            save_mesh(mesh, tmp_path / "m.glb")
    no_leftovers(tmp_path, set())


@pytest.mark.parametrize("index", [-1, -(2**62), 2**40, 3])
def test_one_reduction_finds_any_face_index_outside(tmp_path, index):
    """The face check reads int64 faces once as uint64 (a negative index is >= 2**63 there): any index below 0 or
    past the last vertex, in any face, is refused by name."""
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    faces = np.zeros((100, 3), np.int64)
    faces[57, 2] = index
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    with pytest.raises(InvalidInputError, match=rf"face 57 is \[0, 0, {index}\]$"):
        save_mesh(mesh, tmp_path / "m.ply")
    no_leftovers(tmp_path, set())


def test_not_a_mesh(tmp_path):
    with pytest.raises(InvalidInputError,
                       match="mesh must be a trimesh.Trimesh or a pyvista.PolyData of triangles; got ndarray"):
        save_mesh(np.zeros((3, 3)), tmp_path / "m.glb")


def test_3mf_is_written_without_lxml_or_networkx(tmp_path, monkeypatch):
    """The 3MF writer is ours: trimesh's needed lxml and networkx (and dropped vertex colours)."""
    import builtins

    real_import = builtins.__import__

    def no_xml_libraries(name, *args, **kwargs):
        if name.split(".")[0] in ("lxml", "networkx"):
            raise ImportError(f"no module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_xml_libraries)
    out = save_mesh(stepped_like_mesh(), tmp_path / "m.3mf")
    monkeypatch.undo()
    assert out.stat().st_size > 0


# ---------------------------------------------------------------------------------------------- atomicity
def failing_writer(mesh, tmp, *_):  # a .glb writer also takes the anchor
    tmp.write_bytes(b"partial glb bytes")
    raise RuntimeError("exporter died midway")


def test_failed_export_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setitem(export._WRITERS, ".glb", failing_writer)
    with pytest.raises(RuntimeError, match="midway"):
        save_mesh(stepped_like_mesh(), tmp_path / "m.glb")
    no_leftovers(tmp_path, set())


def test_failed_export_keeps_existing_target(tmp_path, monkeypatch):
    target = tmp_path / "m.glb"
    target.write_bytes(b"previous good file")
    monkeypatch.setitem(export._WRITERS, ".glb", failing_writer)
    with pytest.raises(RuntimeError, match="midway"):
        save_mesh(stepped_like_mesh(), target)
    assert target.read_bytes() == b"previous good file"
    no_leftovers(tmp_path, {"m.glb"})


def test_os_error_in_writer_becomes_data_file_error(tmp_path, monkeypatch):
    def disk_full(mesh, tmp, *_):
        raise OSError(28, "No space left on device")

    monkeypatch.setitem(export._WRITERS, ".stl", disk_full)
    with pytest.raises(DataFileError, match=r"cannot write '.*m\.stl': .*No space left"):
        save_mesh(stepped_like_mesh(), tmp_path / "m.stl")
    no_leftovers(tmp_path, set())


def test_overwrite_and_new_folders(tmp_path):
    target = tmp_path / "a" / "b" / "m.obj"
    save_mesh(stepped_like_mesh(), target)
    first = target.read_bytes()
    save_mesh(trimesh.creation.box(), target)
    assert target.read_bytes() != first and len(trimesh.load(target).faces) == 12
    assert target.stat().st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def test_folder_is_a_file(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    with pytest.raises(DataFileError, match=r"output folder '.*file\.txt' is not a folder"):
        save_mesh(stepped_like_mesh(), blocker / "m.glb")
    with pytest.raises(DataFileError, match="cannot create the output folder"):
        save_image(np.zeros((2, 2, 3), np.uint8), blocker / "sub" / "i.png")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root can write into read-only folders")
def test_read_only_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(DataFileError, match="is not writable"):
            save_mesh(stepped_like_mesh(), folder / "m.glb")
    finally:
        folder.chmod(0o755)


def test_unwritable_folder_reported(tmp_path, monkeypatch):
    # root ignores permission bits, so stand in for a read-only folder by what os.access reports
    monkeypatch.setattr(export.os, "access", lambda path, mode: False)
    with pytest.raises(DataFileError, match=r"output folder '.*' is not writable"):
        save_mesh(stepped_like_mesh(), tmp_path / "m.glb")
    no_leftovers(tmp_path, set())


def test_target_is_a_directory(tmp_path):
    (tmp_path / "m.glb").mkdir()
    with pytest.raises(DataFileError, match=r"cannot write '.*m\.glb'"):
        save_mesh(stepped_like_mesh(), tmp_path / "m.glb")
    no_leftovers(tmp_path, {"m.glb"})


def test_atomic_path_removes_temp_on_error(tmp_path):
    with pytest.raises(KeyError):
        with atomic_path(tmp_path / "x.bin") as tmp:
            tmp.write_bytes(b"half")
            raise KeyError("boom")
    no_leftovers(tmp_path, set())


# ---------------------------------------------------------------------------------------------- images
@pytest.mark.parametrize("channels", [3, 4])
@pytest.mark.parametrize("name", ["img.png", "img.tif"])
def test_save_image_round_trip(tmp_path, channels, name):
    image = np.random.default_rng(1).integers(0, 256, (5, 7, channels), dtype=np.uint8)
    out = save_image(image, tmp_path / name)
    with Image.open(out) as picture:
        assert picture.mode == ("RGB" if channels == 3 else "RGBA")
        back = np.asarray(picture)
    np.testing.assert_array_equal(back, image)
    no_leftovers(tmp_path, {name})


def needs_rasterio():
    return pytest.importorskip("rasterio", reason="GeoTIFF tests need rasterio (pip install 'stepterrain[geo]')")


@pytest.mark.parametrize("background", [(1.0, 1.0, 1.0), None])  # RGB, and RGBA (alpha band)
def test_a_texture_geotiff_lies_exactly_over_its_dem(tmp_path, background):
    """A texture of a GeoTIFF DEM, written as GeoTIFF with the layer's extent and the terrain's CRS: the same
    pixel grid as the DEM (its geotransform, its CRS) and the same pixels as the image."""
    rasterio = needs_rasterio()
    import stepterrain as st
    from stepterrain import texture as tx

    z = np.add.outer(np.arange(12.0) * 3.0, np.sin(np.arange(17.0))).astype(np.float32)
    z[0, 0] = np.nan  # nodata: transparent in the RGBA layer
    geotransform = rasterio.Affine(30.0, 0.0, 390000.0, 0.0, -30.0, 3800000.0)
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", width=17, height=12, count=1, dtype="float32",
                       crs="EPSG:32611", transform=geotransform, nodata=np.nan) as ds:  # fmt: skip
        ds.write(z, 1)
    dem = st.load_dem(tmp_path / "dem.tif")
    layer = tx.modulate(tx.terrain_layer(dem, np.dstack([np.full(z.shape + (3,), 0.5), np.isfinite(z)]),
                                         "thematic"), tx.topographic_layer(dem))  # fmt: skip
    image = layer.to_uint8(background=background)
    out = save_image(image, tmp_path / "shade.tif", extent=layer.extent, crs=dem.crs)
    with rasterio.open(out) as ds:
        assert ds.crs == rasterio.crs.CRS.from_epsg(32611)
        assert ds.transform.almost_equals(geotransform, precision=1e-9)
        assert (ds.width, ds.height, ds.count) == (17, 12, image.shape[2])
        np.testing.assert_array_equal(np.moveaxis(ds.read(), 0, 2), image)
        if image.shape[2] == 4:
            assert ds.colorinterp[3] == rasterio.enums.ColorInterp.alpha
    no_leftovers(tmp_path, {"dem.tif", "shade.tif"})


def test_a_south_up_grid_texture_is_georeferenced_north_up(tmp_path):
    """A grid whose rows run north (dy > 0): the layer's image is turned north-up, so the GeoTIFF is too, with
    the node extent plus half a cell, and the layer's north row is the file's first."""
    rasterio = needs_rasterio()
    from stepterrain import texture as tx

    z = np.add.outer(np.arange(6.0) * 10.0, np.zeros(4)).astype(np.float32)  # higher to the north (row 5)
    terrain = as_terrain(z, spacing=(2.0, 3.0), origin=(100.0, 200.0))
    layer = tx.terrain_layer(terrain, np.dstack([z / 50.0] * 3), "thematic")
    out = save_image(layer.to_uint8(), tmp_path / "t.tiff", extent=layer.extent)
    with rasterio.open(out) as ds:
        assert tuple(ds.bounds) == pytest.approx((99.0, 198.5, 107.0, 216.5))
        assert ds.crs is None
        band = ds.read(1)
    assert band[0, 0] == 255 and band[-1, 0] == 0  # row 0: the north edge, the highest heights


def test_geotiff_refusals(tmp_path, monkeypatch):
    image = np.zeros((2, 3, 3), np.uint8)
    with pytest.raises(InvalidInputError, match="a PNG has no place for an extent"):
        save_image(image, tmp_path / "i.png", extent=(0, 3, 0, 2))
    with pytest.raises(InvalidInputError, match="crs without extent"):
        save_image(image, tmp_path / "i.tif", crs="EPSG:4326")
    with pytest.raises(InvalidInputError, match=r"extent must be finite \(xmin, xmax, ymin, ymax\)"):
        save_image(image, tmp_path / "i.tif", extent=(3, 0, 0, 2))
    if importlib.util.find_spec("rasterio") is not None:
        with pytest.raises(InvalidInputError, match="crs must be a coordinate reference system"):
            save_image(image, tmp_path / "i.tif", extent=(0, 3, 0, 2), crs="not a crs")
        # finite edges whose width overflows: the geotransform held an infinite pixel size and a NaN origin
        with pytest.raises(InvalidInputError, match=r"pixel size of inf x 1 over 3 x 2 pixels"):
            save_image(image, tmp_path / "i.tif", extent=(-1e308, 1e308, 0, 2))
    monkeypatch.setitem(sys.modules, "rasterio", None)  # as if not installed
    with pytest.raises(MissingDependencyError, match=r"pip install 'stepterrain\[geo\]'"):
        save_image(image, tmp_path / "i.tif", extent=(0, 3, 0, 2))
    no_leftovers(tmp_path, set())


def test_save_image_refusals(tmp_path):
    with pytest.raises(InvalidInputError, match="must be uint8"):
        save_image(np.zeros((2, 2, 3), np.float32), tmp_path / "i.png")
    with pytest.raises(InvalidInputError, match=r"got shape \(2, 2\)"):
        save_image(np.zeros((2, 2), np.uint8), tmp_path / "i.png")
    with pytest.raises(InvalidInputError, match="must end in .png, .tif, .tiff"):
        save_image(np.zeros((2, 2, 3), np.uint8), tmp_path / "i.jpg")
    no_leftovers(tmp_path, set())
