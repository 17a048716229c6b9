"""Export and render hunt (h363): each test failed before its fix."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stepterrain.errors import DataFileError, InvalidInputError
from stepterrain.export import read_mesh, save_mesh


def _box_with_levels() -> trimesh.Trimesh:
    mesh = trimesh.creation.box()
    mesh.face_attributes["level"] = np.arange(12, dtype=np.int32)
    mesh.face_attributes["wall"] = np.arange(12) % 2 == 0
    return mesh


def test_a_ply_face_attribute_of_the_wrong_length_is_refused_not_dropped(tmp_path):
    # setting mesh.faces keeps trimesh's face_attributes as they were: the .ply was written without 'level', and
    # read back without it, without a word (save_mesh kept only attributes of one value per face)
    mesh = _box_with_levels()
    mesh.faces = mesh.faces[:5]
    out = tmp_path / "cut.ply"
    with pytest.raises(InvalidInputError) as info:
        save_mesh(mesh, out)
    message = str(info.value)
    assert "face_attributes['level']" in message and "(5)" in message and "got 12" in message, message
    assert not out.exists() and list(tmp_path.iterdir()) == []
    # cut down with update_faces (which cuts the attributes too), it is written and read back whole
    mesh = _box_with_levels()
    mesh.update_faces(np.arange(5))
    back = read_mesh(save_mesh(mesh, out))
    np.testing.assert_array_equal(back.face_attributes["level"], np.arange(5))
    np.testing.assert_array_equal(back.face_attributes["wall"], np.arange(5) % 2 == 0)


def test_a_ply_vertex_attribute_of_a_single_value_is_refused(tmp_path):
    mesh = trimesh.creation.box()
    mesh.vertex_attributes["height"] = np.float64(3.0)
    with pytest.raises(InvalidInputError, match=r"vertex_attributes\['height'\].*one value per vertex \(8\).*single"):
        save_mesh(mesh, tmp_path / "box.ply")


def test_a_ply_attribute_the_format_cannot_hold_is_left_out_with_a_warning(tmp_path):
    # text (or objects, complex numbers) was dropped without a word
    mesh = _box_with_levels()
    mesh.face_attributes["name"] = np.array(["terrace"] * 12)
    with pytest.warns(UserWarning, match=r"left out face_attributes\['name'\]"):
        back = read_mesh(save_mesh(mesh, tmp_path / "box.ply"))
    assert set(back.face_attributes) == {"level", "wall"}
    np.testing.assert_array_equal(back.face_attributes["level"], np.arange(12))


def test_a_ragged_attribute_is_left_out_not_a_numpy_error(tmp_path):
    # a ragged list (no array NumPy makes) was warned of as left out of a .ply, then NumPy's ValueError "setting an
    # array element with a sequence" went out of save_mesh (of every format) from the copy it writes
    for ext in (".ply", ".glb", ".obj"):
        mesh = _box_with_levels()
        mesh.face_attributes["ragged"] = [[1, 2], [3]]
        out = tmp_path / f"box{ext}"
        if ext == ".ply":
            with pytest.warns(UserWarning, match=r"left out face_attributes\['ragged'\] \(a list of no array shape"):
                back = read_mesh(save_mesh(mesh, out))
            assert set(back.face_attributes) == {"level", "wall"}
            np.testing.assert_array_equal(back.face_attributes["level"], np.arange(12))
        else:
            assert len(read_mesh(save_mesh(mesh, out)).faces) == 12


def test_other_formats_do_not_check_the_attributes_they_drop(tmp_path):
    mesh = _box_with_levels()
    mesh.faces = mesh.faces[:5]
    for ext in (".glb", ".obj", ".stl", ".3mf"):
        assert len(read_mesh(save_mesh(mesh, tmp_path / f"cut{ext}")).faces) == 5


def test_a_3mf_of_vertex_colours_with_an_unused_vertex_reads_back_its_vertex_colours(tmp_path):
    # a vertex no triangle names has no colour in the file; read_mesh then gave every face its first corner's colour
    # (face colours), the vertex colours of all the others lost, though each vertex's corners had one colour
    rng = np.random.default_rng(3)
    box = trimesh.creation.box()
    vertices = np.vstack([box.vertices, [[5.0, 5.0, 5.0]]])  # vertex 8: in no face
    mesh = trimesh.Trimesh(vertices, box.faces, process=False)
    colours = rng.integers(0, 256, (9, 4), dtype=np.uint8)
    colours[:, 3] = 255
    mesh.visual.vertex_colors = colours
    back = read_mesh(save_mesh(mesh, tmp_path / "print.3mf"))
    assert back.visual.kind == "vertex"
    np.testing.assert_array_equal(back.vertices, vertices)
    np.testing.assert_array_equal(back.visual.vertex_colors[:8], colours[:8])
    assert back.visual.vertex_colors[8, 3] == 255  # opaque: written again, no glTF of it turns BLEND
    # a vertex whose corners have several colours still makes face colours (written as face colours)
    mesh = trimesh.Trimesh(box.vertices, box.faces, process=False)
    face_colours = rng.integers(0, 256, (12, 4), dtype=np.uint8)
    mesh.visual.face_colors = face_colours
    back = read_mesh(save_mesh(mesh, tmp_path / "faces.3mf"))
    assert back.visual.kind == "face"
    np.testing.assert_array_equal(back.visual.face_colors, face_colours)


def test_bounds_that_miss_the_mesh_are_refused_not_rendered_blank():
    # a fitted camera frames the bounds; one given in other coordinates than the mesh's (local ones for a mesh in UTM
    # metres) saw none of it, and the render came back blank without a word
    from stepterrain.render import render_mesh

    box = trimesh.creation.box()
    box.vertices += [500_000.0, 5_000_000.0, 1_000.0]
    with pytest.raises(InvalidInputError, match=r"bounds \[0, 0, 0\] - \[10, 10, 10\] frame none of the mesh, whose "
                                                r"faces span \[500000, 5e\+06, 999.5\].*sees none of it"):
        render_mesh(box, window_size=(64, 48), bounds=[[0, 0, 0], [10, 10, 10]])


def test_a_mesh_under_a_pixel_within_its_bounds_is_refused():
    from stepterrain.render import render_mesh

    with pytest.raises(InvalidInputError, match=r"would render at most 0.000\d+ x 0.000\d+ pixels within bounds"):
        render_mesh(trimesh.creation.box(), window_size=(64, 48), bounds=[[-1e5] * 3, [1e5] * 3])


def test_an_explicit_camera_too_far_to_show_the_mesh_is_refused():
    from stepterrain.render import render_mesh

    with pytest.raises(InvalidInputError, match=r"shows the mesh at most .* pixels, too small to see .* 1 x 1 x 1"):
        render_mesh(trimesh.creation.box(), window_size=(64, 48), camera=[(1e7, 1e7, 1e7), (0, 0, 0), (0, 0, 1)])


def test_bounds_around_the_mesh_and_a_camera_inside_it_still_render():
    from stepterrain.render import offscreen_available, render_mesh

    if not offscreen_available()[0]:
        pytest.skip(offscreen_available()[1])
    box = trimesh.creation.box()
    seen = (render_mesh(box, window_size=(64, 48), bounds=[[-2] * 3, [2] * 3]) != 255).any(axis=2).mean()
    assert 0.01 < seen < 0.9
    inside = render_mesh(box, window_size=(64, 48), camera=[(0, 0, 0), (1, 0, 0), (0, 0, 1)])
    assert (inside != 255).any(axis=2).all()


def test_shared_bounds_with_the_corners_swapped_are_refused(tmp_path):
    # (highest, lowest), or a transposed (3, 2) box read as (2, 3), was taken as given
    mesh = trimesh.creation.box()
    with pytest.raises(InvalidInputError, match=r"shared_bounds .*lowest no higher than the highest; got x from 1 to "
                                                r"-1 in \[\[1, 1, 1\], \[-1, -1, -1\]\]"):
        save_mesh(mesh, tmp_path / "tile.glb", shared_bounds=[[1, 1, 1], [-1, -1, -1]])
    assert list(tmp_path.iterdir()) == []
    back = read_mesh(save_mesh(mesh, tmp_path / "tile.glb", shared_bounds=[[-1, -1, -1], [1, 1, 1]]))
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-6)


def test_a_temporary_file_whose_close_fails_is_not_left_behind(tmp_path, monkeypatch):
    # os.close's error (EIO, a network file system's deferred one) went out of _new_temporary with the empty
    # temporary file it had just made left in the output folder
    import errno
    import os

    real_close, failed = os.close, []

    def close(fd):
        real_close(fd)
        if not failed:
            failed.append(fd)
            raise OSError(errno.EIO, "Input/output error")

    out = tmp_path / "terrain.ply"
    out.write_bytes(b"an earlier mesh")
    monkeypatch.setattr(os, "close", close)
    with pytest.raises(DataFileError, match="Input/output error"):
        save_mesh(trimesh.creation.box(), out)
    monkeypatch.undo()
    assert failed and sorted(p.name for p in tmp_path.iterdir()) == ["terrain.ply"]
    assert out.read_bytes() == b"an earlier mesh"


def test_a_mesh_of_slivers_a_fitted_camera_shows_thinner_than_a_pixel_is_refused():
    # a triangle 1e6 long and 1 wide, seen oblique: its box is 60 x 4 pixels (passing the too-thin check), its area
    # in space 5e5 (passing the no-area check), and it covers 0.0014 of a pixel: rendered blank, without a word
    from stepterrain.render import offscreen_available, render_mesh

    sliver = trimesh.Trimesh([[0, 0, 0], [1e6, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(InvalidInputError, match=r"faces would cover 0.0014 pixels in all .* 64x48 window: they are "
                                                r"slivers, too thin to see"):
        render_mesh(sliver, window_size=(64, 48))
    # a strip of a DEM (2 x 3000 nodes) a few pixels tall covers pixels: still rendered
    import stepterrain as st

    strip = st.stepped(np.zeros((2, 3000), np.float32), interval=10.0)
    if not offscreen_available()[0]:
        pytest.skip(offscreen_available()[1])
    assert (render_mesh(strip, window_size=(320, 200)) != 255).any(axis=2).sum() > 5
