"""Exports of real stepped terrain by extension: colours, textures (OBJ + MTL + images), flat shading, extras."""

from __future__ import annotations

import contextlib
import json

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st_h
from PIL import Image

import stepterrain as st
from stepterrain.errors import DataFileError, InvalidInputError
from stepterrain.export import MESH_EXTENSIONS, read_mesh, save_image, save_mesh

from .conftest import assert_valid_mesh, real_dem, shared_file
from .test_export import glb_json, needs_3mf


@pytest.fixture(scope="module")
def real_stepped() -> trimesh.Trimesh:
    terrain = st.load_dem(shared_file("big_tujunga_srtm_30m_utm11n.npz"))
    crop = st.Terrain.from_heights(terrain.heights[:80:2, :80:2], spacing=(60.0, -60.0), origin=terrain.origin,
                                   crs=terrain.crs, source=terrain.source)  # fmt: skip
    return st.stepped(crop, interval=50.0, base=0.5, colors="terrain")


def textured(n: int = 6, seed: int = 0) -> trimesh.Trimesh:
    rng = np.random.default_rng(seed)
    mesh = st.heightfield_mesh(rng.random((n, n)).astype(np.float32))
    uv = np.c_[mesh.vertices[:, 0] / (n - 1), mesh.vertices[:, 1] / (n - 1)]
    image = Image.fromarray((rng.random((8, 8, 3)) * 255).astype(np.uint8))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    return mesh


@pytest.mark.parametrize("ext", MESH_EXTENSIONS)
def test_real_stepped_terrain_round_trips_with_colors(tmp_path, real_stepped, ext):
    if ext == ".3mf":
        needs_3mf()
    # UTM metres: STL's float32 rounds them by up to 0.125 m here, and says so
    with pytest.warns(UserWarning, match="stores float32") if ext == ".stl" else contextlib.nullcontext():
        out = save_mesh(real_stepped, tmp_path / f"steps{ext}")
    # read_mesh: a glTF's world is y-up, read back z-up
    back = read_mesh(out) if ext in (".glb", ".gltf") else trimesh.load(out, force="mesh", process=False)
    assert_valid_mesh(back)
    if ext in (".stl", ".3mf", ".obj"):  # these formats weld or split vertices their own way
        assert len(back.faces) == len(real_stepped.faces)
    else:
        assert back.vertices.shape == real_stepped.vertices.shape and len(back.faces) == len(real_stepped.faces)
    np.testing.assert_allclose(back.bounds, real_stepped.bounds, atol=0.05)
    if ext in (".glb", ".gltf", ".ply", ".obj"):
        # glTF: trimesh's reader turns the primitive's material into a TextureVisuals without UVs, and a
        # force="mesh" load drops COLOR_0; read_mesh gives the vertex colours back
        assert (read_mesh(out) if ext in (".glb", ".gltf") else back).visual.kind == "vertex"
        original = {tuple(c) for c in np.asarray(real_stepped.visual.vertex_colors)[:, :3]}
        # read_mesh: glTF's COLOR_0 is linear, which trimesh's reader gives as it is stored
        colors = read_mesh(out).visual.vertex_colors
        assert {tuple(c) for c in np.asarray(colors)[:, :3]} == original


def test_glb_extras_carry_source_isovalues_gamma_crs(tmp_path, real_stepped):
    extras = glb_json(save_mesh(real_stepped, tmp_path / "s.glb", metadata={"batch": "x"}))["meshes"][0]["extras"]
    assert extras["crs"] == "EPSG:32611" and "big_tujunga" in extras["source"]
    assert extras["gamma"] == 1.0 and extras["batch"] == "x"
    assert np.allclose(np.diff(extras["isovalues"]), 50.0)


def test_flat_shading_no_normals(tmp_path, real_stepped):
    real_stepped.vertex_normals  # noqa: B018 - normals in the cache must not leak into the files
    gltf = glb_json(save_mesh(real_stepped, tmp_path / "s.glb"))
    assert "NORMAL" not in gltf["meshes"][0]["primitives"][0]["attributes"]
    text = save_mesh(real_stepped, tmp_path / "s.obj").read_text()
    assert "\nvn " not in text


def test_obj_with_texture_writes_mtl_and_its_own_image(tmp_path):
    a, b = textured(seed=1), textured(seed=2)
    save_mesh(a, tmp_path / "a.obj")
    save_mesh(b, tmp_path / "b.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "a.mtl", "a.obj", "a_material_0.png", "b.mtl", "b.obj", "b_material_0.png"]  # fmt: skip
    assert "map_Kd a_material_0.png" in (tmp_path / "a.mtl").read_text()
    for name, mesh in (("a", a), ("b", b)):
        back = trimesh.load(tmp_path / f"{name}.obj", process=False)
        image = np.asarray(back.visual.material.image.convert("RGB"))
        assert np.array_equal(image, np.asarray(mesh.visual.material.image))
        assert back.visual.uv.shape[1] == 2


def test_obj_with_a_material_name_with_spaces_finds_its_image(tmp_path):
    terrain = st.Terrain.from_heights(np.random.default_rng(0).random((6, 7)) * 10.0)
    mesh = st.drape(st.stepped(terrain, interval=2.0), st.topographic_layer(terrain))  # material "terrain texture"
    save_mesh(mesh, tmp_path / "d.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.mtl", "d.obj", "d_terrain_texture.png"]
    assert "map_Kd d_terrain_texture.png" in (tmp_path / "d.mtl").read_text()
    back = trimesh.load(tmp_path / "d.obj", process=False)
    assert back.visual.material.image is not None
    original = mesh.visual.material.baseColorTexture  # drape gives a PBR material
    assert np.array_equal(np.asarray(back.visual.material.image.convert("RGB")), np.asarray(original.convert("RGB")))


def test_obj_side_files_never_replace_another_output_of_the_run(tmp_path):
    """A textured OBJ's image <stem>_<material>.png replaced, without a word, an image of the same name written
    earlier in the run (stepterrain texture -o t_terrain_texture.png --mesh t.obj lost its -o image, --normals
    likewise), and a later image replaced the OBJ's texture. Both are refused now, before anything is written;
    saving the same OBJ or image again, or after the other file is gone, still works."""
    picture = np.full((4, 4, 3), 7, np.uint8)
    image = save_image(picture, tmp_path / "a_material_0.png")
    before = image.read_bytes()
    with pytest.raises(DataFileError, match=r"a_material_0.png' as a side file of .*a.obj'.*wrote it earlier as an "
                                            r"image"):  # fmt: skip
        save_mesh(textured(), tmp_path / "a.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_material_0.png"] and image.read_bytes() == before
    save_image(picture, image)  # the image again: its own file
    image.unlink()
    save_mesh(textured(), tmp_path / "a.obj")  # gone: the OBJ may take the name
    texture = (tmp_path / "a_material_0.png").read_bytes()
    with pytest.raises(DataFileError, match=r"wrote it earlier as a side file \(material or texture image\) of "
                                            r".*a.obj'"):  # fmt: skip
        save_image(picture, tmp_path / "a_material_0.png")
    assert (tmp_path / "a_material_0.png").read_bytes() == texture
    save_mesh(textured(seed=3), tmp_path / "a.obj")  # the same OBJ again replaces its own side files
    assert (tmp_path / "a_material_0.png").read_bytes() != texture
    with pytest.raises(DataFileError, match=r"as a side file of .*a.OBJ'.* of .*a.obj'"):  # same stem, other OBJ
        save_mesh(textured(), tmp_path / "a.OBJ")
    assert not (tmp_path / "a.OBJ").exists()


def test_textured_glb_keeps_uv_and_image(tmp_path):
    mesh = textured()
    back = trimesh.load(save_mesh(mesh, tmp_path / "t.glb"), force="mesh", process=False)
    assert back.visual.kind == "texture"
    np.testing.assert_allclose(np.sort(back.visual.uv, axis=0), np.sort(mesh.visual.uv, axis=0), atol=1e-6)


def test_solid_3mf_and_stl_are_watertight(tmp_path):
    needs_3mf()
    mesh = st.stepped(real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=6), interval=100.0, base=0.5,
                      solid=True)  # fmt: skip
    for ext in (".3mf", ".stl"):
        back = trimesh.load(save_mesh(mesh, tmp_path / f"solid{ext}"), force="mesh")
        assert back.is_watertight and back.volume > 0



def strict_3mf_model(lib3mf, path):
    """The 3MF Consortium's lib3mf model of ``path``, read in strict mode with no warning."""
    model = lib3mf.get_wrapper().CreateModel()
    reader = model.QueryReader("3mf")
    reader.SetStrictModeActive(True)
    reader.ReadFromFile(str(path))
    assert reader.GetWarningCount() == 0
    return model


def test_3mf_keeps_positions_faces_and_vertex_colours(tmp_path):
    """The 3MF writer: positions exact (repr), the faces as they are, and the vertex colours as a colorgroup with
    each triangle's corner colours (trimesh's writer dropped them; a colour 3D print lost its hypsometric tints).
    The 3MF Consortium's lib3mf reads it in strict mode without a warning and finds it manifold and oriented."""
    lib3mf = pytest.importorskip("lib3mf")
    import xml.etree.ElementTree as ET
    import zipfile

    mesh = st.stepped(real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=6), interval=100.0, base=0.5,
                      solid=True, colors="terrain")  # fmt: skip
    out = save_mesh(mesh, tmp_path / "solid.3mf")
    root = ET.fromstring(zipfile.ZipFile(out).read("3D/3dmodel.model"))
    core = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"
    material = "{http://schemas.microsoft.com/3dmanufacturing/material/2015/02}"
    points = np.array([[float(v.get(k)) for k in "xyz"] for v in root.iter(core + "vertex")])
    triangles = [t.attrib for t in root.iter(core + "triangle")]
    faces = np.array([[int(t[k]) for k in ("v1", "v2", "v3")] for t in triangles])
    corners = np.array([[int(t[k]) for k in ("p1", "p2", "p3")] for t in triangles])
    palette = [c.get("color") for c in root.iter(material + "color")]
    np.testing.assert_array_equal(points, mesh.vertices)  # exact: repr round-trips float64
    np.testing.assert_array_equal(faces, mesh.faces)
    rgba = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
    expected = ["#" + "".join(f"{c:02X}" for c in rgba[v]) for v in mesh.faces.reshape(-1)]
    assert [palette[i] for i in corners.reshape(-1)] == expected
    model = strict_3mf_model(lib3mf, out)
    objects = model.GetMeshObjects()
    assert objects.MoveNext()
    lib_mesh = objects.GetCurrentMeshObject()
    assert (lib_mesh.GetVertexCount(), lib_mesh.GetTriangleCount()) == (len(mesh.vertices), len(mesh.faces))
    assert lib_mesh.IsManifoldAndOriented()

@pytest.mark.parametrize("bad", [(2, 0, np.nan), (1, 2, np.inf), (0, 1, -np.inf)])
def test_non_finite_vertices_are_refused(tmp_path, bad):
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float64)
    points[bad[0], bad[1]] = bad[2]
    mesh = trimesh.Trimesh(points, [[0, 1, 2]], process=False)
    with pytest.raises(InvalidInputError, match="vertices must be finite.*1 of 3"):
        save_mesh(mesh, tmp_path / "bad.glb")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------- metadata in OBJ and 3MF (they dropped it)
def _own_metadata(mesh: trimesh.Trimesh) -> dict:
    """A mesh's metadata less what trimesh's readers add (``name``/``node`` from the file name, ``_ply_raw``)."""
    return {k: v for k, v in mesh.metadata.items() if not k.startswith("_") and k not in ("name", "node")}


@pytest.mark.parametrize("ext", [".obj", ".3mf"])
def test_obj_and_3mf_keep_the_metadata_and_the_ply_positions(tmp_path, ext):
    """A stepped UTM DEM written as OBJ or 3MF reads back with its metadata (crs, source, isovalues, gamma: a GIS
    user's georeference; both dropped it, so ``stepterrain info`` showed no CRS) equal to the PLY round trip's and
    to the JSON of the mesh's, and with the same vertices as the PLY and GLB round trips (world coordinates, no
    offset left in the metadata)."""
    dem = st.sample_dem().coarsen(8)
    mesh = st.stepped(dem, interval=100.0, device="cpu")
    assert mesh.metadata["crs"] == "EPSG:32611"
    ply = read_mesh(save_mesh(mesh, tmp_path / "m.ply"))
    glb = read_mesh(save_mesh(mesh, tmp_path / "m.glb"))
    back = read_mesh(save_mesh(mesh, tmp_path / f"m{ext}"))
    assert _own_metadata(back) == _own_metadata(ply) == json.loads(json.dumps(mesh.metadata))
    np.testing.assert_array_equal(back.vertices, ply.vertices)
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    gap = np.abs(back.vertices - glb.vertices).max()  # glTF: float32 about its node translation
    assert gap <= np.spacing(np.float32(np.ptp(mesh.vertices, axis=0).max())), gap
    np.testing.assert_array_equal(back.faces, mesh.faces)


@pytest.mark.parametrize("ext", [".obj", ".3mf"])
def test_awkward_metadata_survives_obj_and_3mf_and_trimesh_still_reads_them(tmp_path, ext):
    """Metadata longer than one comment line (a fine interval's isovalues), with spaces, line breaks, a trailing
    backslash at a piece's end, XML's special characters, non-ASCII text and the words readers look for anywhere
    (``mtllib``: trimesh's OBJ reader takes the rest of the first line holding it for a material file) comes back
    equal; trimesh reads both files as the same mesh, an OBJ's metadata lines are comments of at most 430 characters,
    and lib3mf reads the 3MF in strict mode without a warning and finds the metadata."""
    mesh = st.stepped(np.array([[0.0, 1, 2], [1, 2, 3], [2, 3, 4]]), interval=1.0, base=0.5, device="cpu")
    awkward = {
        "crs": 'PROJCS["WGS 84 / UTM zone 11N",GEOGCS["WGS 84"]]',
        "note": "a <b> & 'c' \"d\"\nline two\\",
        "place": "Zürich – Ōsaka",
        "source": "mtllib usemtl end_header TextureFile.png",
        "isovalues": [0.125 * k for k in range(400)],
        "path": "\\" * 399 + "x",
        "nested": {"origin": [376328.6554542635, 3807902.8276283755], "flag": True, "none": None},
    }
    out = save_mesh(mesh, tmp_path / f"m{ext}", metadata=awkward)
    back = read_mesh(out)
    assert _own_metadata(back) == {**json.loads(json.dumps(mesh.metadata)), **awkward}
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    loaded = trimesh.load(out, force="mesh", process=False)
    assert len(loaded.faces) == len(mesh.faces)
    np.testing.assert_allclose(np.sort(loaded.vertices, axis=0), np.sort(mesh.vertices, axis=0))
    if ext == ".obj":
        lines = out.read_text(encoding="utf-8").splitlines()
        meta = [line for line in lines if "stepterrain-metadata" in line]
        assert len(meta) > 1 and all(line.startswith("# stepterrain-metadata ") and len(line) <= 430 for line in meta)
        assert all(line.isascii() and not line.endswith("\\") for line in meta)
        assert not (tmp_path / "m.mtl").exists() and loaded.visual.kind is None
        return
    lib3mf = pytest.importorskip("lib3mf")
    model = strict_3mf_model(lib3mf, out)
    group = model.GetMetaDataGroup()
    found = {}
    for k in range(group.GetMetaDataCount()):
        item = group.GetMetaData(k)
        found[(item.GetNameSpace(), item.GetName())] = item.GetValue()
    assert len(found) == 1
    (value,) = found.values()
    assert json.loads(value)["place"] == awkward["place"]


def test_info_shows_the_crs_of_an_obj_and_a_3mf(tmp_path):
    """``stepterrain info`` (its summary) names the CRS and source of a stepped DEM written as OBJ or 3MF, as it did
    for PLY and glTF only."""
    from stepterrain.cli import _mesh_summary

    mesh = st.stepped(st.sample_dem().coarsen(16), interval=200.0, device="cpu")
    for ext in (".ply", ".obj", ".3mf"):
        summary = _mesh_summary(save_mesh(mesh, tmp_path / f"m{ext}"))
        assert summary["meta.crs"] == "EPSG:32611", ext
        assert summary["meta.source"] == mesh.metadata["source"], ext


_json_leaf = st_h.none() | st_h.booleans() | st_h.integers(-10**12, 10**12) | st_h.floats(allow_nan=False,
                                                                                          allow_infinity=False)
_json_text = st_h.text(st_h.sampled_from(list("\\\\ \"ab<&>\nü€mtllibend_header")), max_size=60)
_json_values = st_h.recursive(_json_leaf | _json_text, lambda inner: st_h.lists(inner, max_size=30)
                              | st_h.dictionaries(_json_text, inner, max_size=5), max_leaves=60)


@settings(max_examples=40, deadline=None)
@given(st_h.dictionaries(_json_text, _json_values, min_size=1, max_size=8))
def test_metadata_pieces_join_back_and_never_end_in_a_backslash(metadata):
    """The pieces of the PLY and OBJ comment lines (and the 3MF's text, joined): ASCII without whitespace, at most
    400 characters, none ending in a backslash (an OBJ line's continuation), and joined back the metadata."""
    from stepterrain.export import _metadata_from_pieces, _metadata_pieces

    pieces = _metadata_pieces(metadata)
    assert pieces and all(0 < len(p) <= 400 and p.isascii() and not p.endswith("\\") for p in pieces)
    assert not any(c.isspace() for p in pieces for c in p)
    assert "mtllib" not in "".join(pieces).lower() and "end_header" not in "".join(pieces).lower()
    assert _metadata_from_pieces(p.encode("ascii") for p in pieces) == json.loads(json.dumps(metadata))
