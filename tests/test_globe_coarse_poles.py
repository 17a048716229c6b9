"""The globe at its extremes: the coarsest mesh's poles under a drape, an eye altitude below float64's resolution
at a huge radius, and per-face parts saved again after reading them back."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from stepterrain.cli import main
from stepterrain.errors import InvalidInputError
from stepterrain.globe import Globe, look_from


@pytest.mark.parametrize("radius, altitude, spacing", [(1e20, 1000.0, "16384"), (1e20, -1000.0, "16384"),
                                                       (1e29, 1e12, "1.75922e+13")])
def test_an_eye_rounded_onto_a_huge_sphere_is_refused_saying_by_how_much_to_raise_it(radius, altitude, spacing):
    """look_from(0, 0, 1000, radius=1e20): float64's numbers lie 16384 m apart at 1e20, so radius + altitude rounded
    to the radius, the eye onto the sphere, and the globe refused it as "inside the planet ... |eye| =
    100000000000000000000.0 m, the surface there 100000000000000000000.0 m ... terrain +0.0 m; raise the eye",
    saying neither why nor by how much. The refusal names float64's spacing there (the least altitude that keeps the
    eye off the sphere); an eye that high is taken. (look_from itself keeps such an eye's view direction:
    test_look_from_keeps_its_view_direction_over_a_large_sphere.)"""
    lat = np.linspace(89.5, -89.5, 18)
    lon = np.linspace(-175.0, 175.0, 36)
    globe = Globe.from_latlon(np.zeros((18, 36)), lat, lon, face_size=3, radius=radius, device="cpu")
    with pytest.raises(InvalidInputError, match=re.escape(
            f"raise the eye by at least float64's spacing of numbers at this distance, {spacing} m (an eye closer "
            "above the surface rounds onto it)") + "$"):
        globe.mesh(camera=look_from(10.0, 20.0, altitude, radius=radius))
    assert float(spacing) * (1 - 1e-5) < np.spacing(radius) <= float(spacing)  # as printed, not below it
    assert len(globe.mesh(camera=look_from(10.0, 20.0, float(spacing), radius=radius), cull=False).faces) > 0
    earth = Globe.from_latlon(np.zeros((18, 36)), lat, lon, face_size=3, device="cpu")
    with pytest.raises(InvalidInputError, match=r"terrain \+0.0 m\); raise the eye$"):  # no word of float64 there
        earth.mesh(camera=look_from(10.0, 20.0, -1000.0))


def test_the_cli_refuses_an_eye_altitude_below_float64_s_resolution_naming_radius(tmp_path, capsys):
    """globe --radius 1e20 --eye 0,0,1000: the eye rounded onto the sphere and was refused in the library's words
    (|eye| and the surface both 1e20 m, "terrain +0.0 m"). It names --radius and the usable range now; where such an
    eye still lies above the terrain (over an ocean floor below the sphere) it is taken, as before."""
    out = tmp_path / "g.glb"
    assert main(["-q", "globe", "--face-size", "9", "--radius", "1e20", "--eye", "0,0,1000", "-o", str(out)]) == 2
    assert capsys.readouterr().err == (
        "stepterrain globe: error: --eye altitude must be resolved against --radius in float64 (|altitude| at least "
        "16384 m at this radius, or a radius below 4.61168e+18 m for this altitude); got altitude 1000 m, --radius "
        "1e+20 m: the eye rounded onto the sphere, below the terrain there\n")
    assert not out.exists()
    assert main(["-q", "globe", "--face-size", "9", "--radius", "1e20", "--eye", "0,0,1e6", "-o", str(out),
                 "--device", "cpu"]) == 0
    assert out.exists()
    out.unlink()  # over the ocean, 4 km below the sphere, an eye rounded onto it is above the terrain: taken
    assert main(["-q", "globe", "--face-size", "9", "--radius", "1e16", "--eye", "0,0,1", "-o", str(out),
                 "--device", "cpu"]) == 0
    assert out.exists()


def _longitude_off(textured, fraction=0.2, samples=8):
    """Per face, the u span of its corners, and the largest difference in degrees between the longitude the UVs give
    (u linear over the face) and the true one (atan2 of the point), at points of a barycentric grid lying at least
    ``fraction`` of their distance from the centre off the polar axis (at a pole every longitude is right)."""
    w = np.array([(i, j, samples - i - j) for i in range(samples + 1) for j in range(samples + 1 - i)]) / samples
    corners = textured.vertices[textured.faces]
    u = textured.visual.uv[textured.faces][..., 0]
    points = np.einsum("sk,fkc->fsc", w, corners)
    lon = np.degrees(np.arctan2(points[..., 1], points[..., 0]))
    off = np.abs((lon - (np.einsum("sk,fk->fs", w, u) * 360.0 - 180.0) + 180.0) % 360.0 - 180.0)
    far = np.hypot(points[..., 0], points[..., 1]) >= fraction * np.linalg.norm(points, axis=-1)
    return np.ptp(u, axis=1), np.where(far, off, 0.0).max(axis=1)


def _same_surface(textured, mesh):
    """The textured mesh covers the same surface as ``mesh``: the same area, closed where it is (its copies welded
    by position), and every vertex on one of ``mesh``'s faces (a split face's new corner on it)."""
    import trimesh

    assert textured.area == pytest.approx(mesh.area, rel=1e-12)
    if mesh.is_watertight:
        welded = trimesh.Trimesh(textured.vertices, textured.faces, process=False)
        welded.merge_vertices()
        assert welded.is_watertight
    known = {tuple(v) for v in mesh.vertices}
    corners = mesh.vertices[mesh.faces]
    for point in (v for v in textured.vertices if tuple(v) not in known):  # a split's new corner: on a face
        edge1, edge2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        normal = np.cross(edge1, edge2)
        rel = point - corners[:, 0]
        height = np.abs(np.einsum("fc,fc->f", rel, normal)) / np.linalg.norm(normal, axis=1)
        b1 = np.einsum("fc,fc->f", np.cross(rel, edge2), normal) / np.einsum("fc,fc->f", normal, normal)
        b2 = np.einsum("fc,fc->f", np.cross(edge1, rel), normal) / np.einsum("fc,fc->f", normal, normal)
        within = (b1 >= -1e-9) & (b2 >= -1e-9) & (b1 + b2 <= 1 + 1e-9)
        assert (within & (height <= 1e-9 * np.linalg.norm(point))).any()


def test_the_coarsest_globe_drape_splits_its_pole_diagonals_and_no_face_spans_half_the_map():
    """At error 1e9 a globe mesh is its 12 root triangles, two a cube face; the ±z faces' shared diagonal runs
    through each pole, so four triangles spanned 180 degrees of longitude, and drape_texture's UVs (linear over a
    face) gave each a u span of 0.5: the texture smeared across half the map, 67.5 degrees off the true longitude
    away from the pole. Every finer mesh has the pole as a vertex, whose u each face takes as the mean of its
    other corners' (a span of at most 0.125). The drape now splits a face the polar axis crosses at the point
    where it does (here the diagonal's, both faces beside it), a pole vertex like the finer meshes': at every level
    no face spans over a quarter of the map, and the UVs give each point's longitude within 45 degrees away from the
    poles (an independent atan2 of sampled points), over the same surface."""
    from stepterrain.globe import drape_texture

    globe = Globe.sample(face_size=9, device="cpu")
    camera = look_from(0.0, 0.0, 2.0e7)
    meshes = [globe.mesh(error=e) for e in (1e9, 3e5, 1e5, 0.0)]
    meshes += [globe.mesh(error=1e6, camera=camera, cull=False), *globe.mesh(error=1e9, per_face=True)]
    assert len(meshes[0].faces) == 12
    for mesh in meshes:
        before = mesh.faces.copy()
        textured = drape_texture(mesh, np.zeros((4, 8, 3), np.uint8))
        np.testing.assert_array_equal(mesh.faces, before)  # the mesh draped is left as it was
        span, off = _longitude_off(textured)
        assert span.max() <= 0.25 + 1e-12 and off.max() <= 45.0
        _same_surface(textured, mesh)
        np.testing.assert_array_equal(textured.vertices[textured.faces[: len(mesh.faces)]][:, 0],
                                      mesh.vertices[mesh.faces][:, 0])  # each face's first piece keeps its index
        cube_face = mesh.face_attributes["cube_face"]
        np.testing.assert_array_equal(textured.face_attributes["cube_face"][: len(mesh.faces)], cube_face)
    coarse = drape_texture(meshes[0], np.zeros((4, 8, 3), np.uint8))
    assert len(coarse.faces) == 16  # the two diagonals through the poles split, each face beside them in two
    assert np.bincount(coarse.face_attributes["cube_face"]).tolist() == [4, 2, 2, 2, 2, 4]
    nudged = meshes[0].copy()  # the axis a micrometre off the diagonal: the same split, on the edge
    nudged.vertices[nudged.faces[0, 0]] += [1e-6, 0.0, 0.0]
    textured = drape_texture(nudged, np.zeros((4, 8, 3), np.uint8))
    assert len(textured.faces) == 16 and _longitude_off(textured)[0].max() <= 0.25 + 1e-12


def test_a_face_the_polar_axis_pierces_is_split_in_three_at_the_pole():
    """A mesh of any shape: an icosahedron turned so that no vertex lies on the polar axis, which pierces two faces
    inside. Each spanned 360 degrees of longitude around the pole (a u span of 0.67); each is split in three at the
    point where the axis meets it, a pole vertex (the faces beside it keep theirs)."""
    import trimesh
    from scipy.spatial.transform import Rotation

    from stepterrain.globe import drape_texture

    mesh = trimesh.creation.icosahedron()
    mesh.apply_transform(np.block([[Rotation.from_euler("xyz", [0.3, 0.2, 0.1]).as_matrix(), np.zeros((3, 1))],
                                   [np.zeros((1, 3)), np.ones((1, 1))]]))
    mesh.apply_scale(6.4e6)
    assert np.hypot(*mesh.vertices[:, :2].T).min() > 1e5  # no vertex near the axis
    textured = drape_texture(mesh, np.zeros((4, 8, 3), np.uint8))
    assert len(textured.faces) == len(mesh.faces) + 4
    span, off = _longitude_off(textured, fraction=0.5)
    assert span.max() <= 0.4 and off.max() <= 45.0
    _same_surface(textured, mesh)
    flat = trimesh.Trimesh([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]], [[0, 1, 2]], process=False)
    assert len(drape_texture(flat, np.zeros((4, 8, 3), np.uint8)).faces) == 1  # the axis meets it at the centre


def _per_face_parts(view):
    """The per-face parts of a face-size-33 sample globe at error 300 m, culled to ``view`` (latitude, longitude,
    altitude and field of view in degrees)."""
    globe = Globe.sample(face_size=33, device="cpu")
    latitude, longitude, altitude, fov = view
    return globe.mesh(error=300.0, camera=look_from(latitude, longitude, altitude, fov=math.radians(fov)),
                      per_face=True)


def _assert_seams_welded(parts, back):
    """The copies of every seam vertex of ``parts`` (as :func:`_seam_pairs` of ``parts`` pairs them) are identical in
    ``back`` (the parts saved and read back), and some seam is checked."""
    from .test_globe_fixes import _seam_pairs

    seams = 0
    for a, b, pairs in _seam_pairs(parts):
        seams += len(pairs)
        np.testing.assert_array_equal(back[a].vertices[pairs[:, 0]], back[b].vertices[pairs[:, 1]],
                                      err_msg=f"faces {a} and {b}")
    assert seams > 0


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("view", [(30.0, 120.0, 1.0e7, 30.0), (44.0, 45.0, 3.0e7, 8.0)])
def test_per_face_parts_read_back_and_saved_again_keep_their_seams_welded(tmp_path, ext, view):
    """A per-face part records its counts and bounds as made (metadata["whole_part"]), and save_mesh keeps the set's
    frame for it however culled it is. Read back from its glTF (the record kept in its extras) its bounds are those
    float32 positions give, not the recorded ones: saved again it took the rule of a piece cut from a part, a culled
    part stored about its own centre, the others about the eye or the shared bounds, and the copies of a seam vertex
    came apart by up to 0.25 m on the Earth. A part whose bounds are exactly those its recorded ones read back as is
    a member as made: saved again, every part's positions read back as the first time, and the seams stay welded."""
    from stepterrain.export import read_mesh, save_mesh

    parts = _per_face_parts(view)
    back = [read_mesh(save_mesh(part, tmp_path / f"face{k}{ext}")) for k, part in enumerate(parts)]
    again = [read_mesh(save_mesh(part, tmp_path / f"again{k}{ext}")) for k, part in enumerate(back)]
    for first, second in zip(back, again, strict=True):
        np.testing.assert_array_equal(second.vertices, first.vertices)
    _assert_seams_welded(parts, again)
    moved = back[1].copy()  # moved since: its own frame, as before
    moved.apply_translation([0.5, 0.0, 0.0])
    from stepterrain.export import _as_made

    assert _as_made(moved.metadata, {}, moved, (moved.vertices.min(axis=0), moved.vertices.max(axis=0))) is None
    assert _as_made(back[1].metadata, {}, back[1], (back[1].vertices.min(axis=0), back[1].vertices.max(axis=0)))


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("view", [(30.0, 0.0, 1.0e7, 8.0), (44.0, 45.0, 1.0e7, 8.0)])
def test_per_face_parts_draped_and_saved_one_by_one_keep_their_seams_welded(tmp_path, ext, view):
    """A texture per face (paper 003 §5.3): each per-face part draped, then saved. drape_texture adds vertices (the
    seam's and poles' copies), so a part no longer had the counts it records as made (metadata["whole_part"]) and
    save_mesh took the rule of a piece cut from a part: a culled part stored about its own centre, the others about
    the eye, and the copies of a seam vertex read back up to 0.69 m apart (3 of 72 views at face size 33). The drape
    records a part's new counts (its bounds are the part's: every copy and split point lies within them)."""
    from stepterrain.export import read_mesh, save_mesh
    from stepterrain.globe import drape_texture

    parts = _per_face_parts(view)
    image = np.random.default_rng(0).integers(0, 255, (8, 16, 3)).astype(np.uint8)
    draped = [drape_texture(part, image) if len(part.faces) else part for part in parts]
    for part, textured in zip(parts, draped, strict=True):
        if len(part.faces):
            assert textured.metadata["whole_part"] == {"vertices": len(textured.vertices),
                                                       "faces": len(textured.faces),
                                                       "bounds": part.metadata["whole_part"]["bounds"]}
            assert part.metadata["whole_part"]["vertices"] == len(part.vertices)  # the part's own record kept
    back = [read_mesh(save_mesh(part, tmp_path / f"face{k}{ext}")) for k, part in enumerate(draped)]
    _assert_seams_welded(draped, back)
