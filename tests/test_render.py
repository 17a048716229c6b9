"""Off-screen renders: image shape and dtype, walls and terraces lit differently, reproducibility, errors."""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh

import stepterrain as st
from stepterrain import render
from stepterrain.errors import InvalidInputError, MissingDependencyError

from .conftest import needs_render, trimeshes_left_by

SIZE = (200, 200)


def ramp(rows: int = 12, cols: int = 12) -> np.ndarray:
    """Heights rising to the north (+y), so every wall faces south, towards the oblique camera."""
    return np.repeat(np.linspace(0.0, 4.0, rows, dtype=np.float32)[:, None], cols, axis=1)


def foreground(image: np.ndarray) -> np.ndarray:
    """Gray levels of the pixels that are not the white background."""
    gray = image.astype(np.float64).mean(axis=2)
    return gray[(image < 250).any(axis=2)]


def square(normal: str) -> trimesh.Trimesh:
    """A unit square facing +z (a terrace) or -y (a wall turned to the camera)."""
    if normal == "+z":
        vertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    else:
        vertices = [[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]]
    return trimesh.Trimesh(np.array(vertices, float), [[0, 1, 2], [0, 2, 3]], process=False)


@needs_render
def test_stepped_render_shape_dtype_and_content():
    mesh = st.stepped(ramp(), interval=1.0, spacing=(0.5, 0.5), device="cpu")
    image = render.render_mesh(mesh, window_size=SIZE)
    assert image.shape == (SIZE[1], SIZE[0], 3)
    assert image.dtype == np.uint8
    assert image.std() > 5, "the image is uniform"
    fg = foreground(image)
    assert fg.size > 0.05 * SIZE[0] * SIZE[1], "the mesh covers almost nothing: camera not fitted"


@needs_render
def test_render_leaves_no_mesh_behind():
    """The PolyData is built from the arrays directly: a temporary Trimesh refers to itself and would hold its
    arrays until Python's cyclic collector ran (frame after frame in an animation)."""
    mesh = st.stepped(ramp(), interval=1.0, spacing=(0.5, 0.5), device="cpu")
    assert trimeshes_left_by(lambda: render.render_mesh(mesh, window_size=SIZE, scalars="level")) == 0


@needs_render
def test_walls_and_terraces_differ_in_brightness():
    terrace = foreground(render.render_mesh(square("+z"), window_size=SIZE, camera="oblique"))
    wall = foreground(render.render_mesh(square("-y"), window_size=SIZE, camera="oblique"))
    assert terrace.size and wall.size
    assert abs(np.median(terrace) - np.median(wall)) > 40, (np.median(terrace), np.median(wall))
    # a stepped ramp shows exactly these two shades (flat shading: no smoothing across a step edge)
    mesh = st.stepped(ramp(), interval=1.0, spacing=(0.5, 0.5), device="cpu")
    image = render.render_mesh(mesh, window_size=SIZE)
    shades = foreground(image)
    near_terrace = np.abs(shades - np.median(terrace)) < 12
    near_wall = np.abs(shades - np.median(wall)) < 12
    assert near_terrace.mean() > 0.2 and near_wall.mean() > 0.1
    assert (near_terrace | near_wall).mean() > 0.9


@needs_render
def test_vertex_colors_and_scalars():
    mesh = st.stepped(ramp(), interval=1.0, colors="viridis", device="cpu")
    image = render.render_mesh(mesh, window_size=SIZE)
    chroma = image.max(axis=2).astype(int) - image.min(axis=2).astype(int)
    assert chroma.max() > 60, "vertex colors were not used"
    for scalars in ("level", "height"):
        colored = render.render_mesh(mesh, window_size=SIZE, scalars=scalars, cmap="viridis")
        assert colored.shape == (SIZE[1], SIZE[0], 3) and colored.std() > 5


@needs_render
def test_render_is_reproducible_and_handles_utm_coordinates():
    heights = ramp() + 1500.0
    mesh = st.stepped(heights, interval=1.0, spacing=(30.0, -30.0), origin=(376313.0, 3807917.0),
                      device="cpu")
    first = render.render_mesh(mesh, window_size=SIZE, z_scale=20.0)
    second = render.render_mesh(mesh, window_size=SIZE, z_scale=20.0)
    np.testing.assert_array_equal(first, second)
    assert foreground(first).size > 0.05 * SIZE[0] * SIZE[1]
    top = render.render_mesh(mesh, window_size=SIZE, camera="top")
    assert top.std() > 5
    fixed = render.render_mesh(mesh, window_size=SIZE, camera=(np.pi, 0.6),
                               bounds=[(376313.0, 3807587.0, 1490.0), (376643.0, 3807917.0, 1510.0)])
    assert fixed.std() > 5


@needs_render
def test_save_png_roundtrip(tmp_path):
    from PIL import Image

    image = render.render_mesh(square("+z"), window_size=(64, 48))
    path = render.save_png(image, tmp_path / "square.png")
    with Image.open(path) as loaded:
        assert loaded.size == (64, 48)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"z_scale": 0.0}, "z_scale"),
        ({"window_size": (4, 4)}, "window_size"),
        ({"scalars": "slope"}, "scalars"),
        ({"camera": "sideways"}, "camera"),
        ({"bounds": [(1, 1, 1), (0, 0, 0)]}, "bounds"),
        ({"bounds": [("0", "0", "0"), ("1", "1", "1")]}, r"bounds must be .* \(real numbers\); got dtype <U1"),  # taken
        ({"z_scale": "abc"}, "z_scale"),  # float()'s ValueError before
        ({"z_scale": None}, "z_scale"),  # float()'s TypeError before
        ({"show_edges": "no"}, "show_edges must be True or False"),  # VTK's TypeError from SetEdgeVisibility
        ({"anti_aliasing": "no"}, "anti_aliasing must be True or False"),  # 'no' switched MSAA on
        ({"scalars": "height", "cmap": "bogus"}, "cmap must name a matplotlib colormap"),  # matplotlib's ValueError
        ({"scalars": "height", "cmap": 5}, "cmap must name a matplotlib colormap"),  # a TypeError before
    ],
)
def test_bad_arguments_raise_before_rendering(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        render.render_mesh(square("+z"), **kwargs)


WHOLE = r"window_size must be two positive whole numbers \(width, height\)"


@pytest.mark.parametrize(
    ("window_size", "match"),
    [
        ((64.7, 48.2), WHOLE),  # truncated to 64 x 48 before
        ((64, 48.5), WHOLE),
        ((True, 48), WHOLE),  # read as 1 pixel before
        ((np.nan, 48), WHOLE),
        ((np.inf, 48), WHOLE),  # int()'s OverflowError before
        (("640", "480"), WHOLE),  # int() read the text before
        ((None, 48), WHOLE),
        ((0, 48), WHOLE),
        ((-64, 48), WHOLE),
        ((64,), WHOLE),
        ((64, 48, 3), WHOLE),
        (64, WHOLE),
        ((10**6, 48), r"window_size must lie in \[8, 16384\] pixels"),
        ((10**400, 48), r"window_size must lie in \[8, 16384\] pixels"),
        ((4, 4), r"window_size must lie in \[8, 16384\] pixels"),
    ],
)
def test_window_size_must_be_whole_pixels(window_size, match):
    """Every public function taking window_size refuses it by name (before pyvista loads)."""
    from PIL import Image

    from stepterrain.batch import BatchReport, overview_image

    with pytest.raises(InvalidInputError, match=match):
        render.render_mesh(square("+z"), window_size=window_size)
    textured = square("+z")
    textured.visual = trimesh.visual.TextureVisuals(uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float),
                                                    image=Image.new("RGB", (4, 4)))
    with pytest.raises(InvalidInputError, match=match):
        render.render_textured_mesh(textured, window_size=window_size)
    with pytest.raises(InvalidInputError, match=match):
        render.LayeredRenderer(window_size=window_size)
    with pytest.raises(InvalidInputError, match=match):  # "the batch wrote no output to show" before, or
        overview_image(BatchReport(output_dir="."), window_size=window_size)  # a contact sheet of w // cols


@needs_render
def test_whole_number_floats_are_a_window_size():
    image = render.render_mesh(square("+z"), window_size=(64.0, np.float32(48.0)))
    assert image.shape == (48, 64, 3)
    with render.LayeredRenderer(window_size=(np.int64(64), 48.0)) as renderer:
        assert renderer.size == (64, 48) and all(type(v) is int for v in renderer.size)


def test_level_scalars_need_one_number_per_face():
    """Strings or the wrong length in face_attributes['level'] raised numpy's or pyvista's ValueError."""
    for levels in (["a", "b"], [1.0], [1.0, np.nan]):
        mesh = square("+z")
        mesh.face_attributes["level"] = np.asarray(levels)
        with pytest.raises(InvalidInputError, match=r"face_attributes\['level'\] must hold one finite number per face"):
            render.render_mesh(mesh, scalars="level")


@needs_render
@pytest.mark.parametrize("background", ["bogus", (1, 2), (np.nan, 0, 0)])
def test_a_bad_background_is_named(background):
    """pyvista's ValueError came from set_background after the scene was built."""
    with pytest.raises(InvalidInputError, match=r"background must be a colour"):
        render.render_mesh(square("+z"), window_size=(16, 16), background=background)
    with pytest.raises(InvalidInputError, match=r"background must be a colour"):
        render.LayeredRenderer(window_size=(16, 16), background=background)


def test_empty_mesh_and_wrong_type():
    with pytest.raises(InvalidInputError, match="no faces"):
        render.render_mesh(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int), process=False))
    with pytest.raises(InvalidInputError, match="trimesh.Trimesh"):
        render.render_mesh(np.zeros((3, 3)))


def test_missing_opengl_raises_missing_dependency(monkeypatch):
    monkeypatch.setattr(render, "_backend_checked", None)
    monkeypatch.setattr(render.sys, "platform", "linux")
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(render.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(MissingDependencyError, match="OpenGL"):
        render.require_offscreen()
    with pytest.raises(ImportError):  # MissingDependencyError is also an ImportError
        render.require_offscreen()


# ------------------------------------------------------------------------------------------------ regression
IMAGES = __import__("pathlib").Path(__file__).resolve().parent / "image_cache"


def _regression_terrain(name: str) -> trimesh.Trimesh:
    if name == "stepped_ramp":
        return st.stepped(ramp(16, 16), interval=0.5, colors="terrain", device="cpu")
    if name == "stepped_real_dem":  # the embedded DEM, cropped and thinned: real walls, lens-free
        dem = st.sample_dem()
        heights = dem.heights[100:260:2, 300:460:2]
        return st.stepped(heights, interval=100.0, spacing=(60.0, 60.0), colors="terrain", device="cpu")
    return st.stepped(ramp(16, 16), interval=0.5, gamma=0.5, colors="viridis", solid=True, device="cpu")


@needs_render
@pytest.mark.parametrize("name", ["stepped_ramp", "stepped_real_dem", "stepped_solid_half_gamma"])
def test_image_regression(name):
    """Renders compare with committed reference images (STEPTERRAIN_UPDATE_IMAGES=1 rewrites them)."""
    import os

    from PIL import Image

    image = render.render_mesh(_regression_terrain(name), window_size=SIZE)
    path = IMAGES / f"{name}.png"
    if os.environ.get("STEPTERRAIN_UPDATE_IMAGES") or not path.exists():
        render.save_png(image, path)
        pytest.skip(f"reference image {path.name} written; re-run to compare")
    with Image.open(path) as ref:
        expected = np.asarray(ref.convert("RGB")).astype(int)
    assert expected.shape == image.shape[:2] + (3,)
    diff = np.abs(image[..., :3].astype(int) - expected)
    assert diff.mean() < 2.0, f"mean difference {diff.mean():.2f} against {path.name}"
    assert (diff.max(axis=2) > 60).mean() < 0.01, "more than 1% of the pixels changed a lot"


@pytest.mark.parametrize("bad", [[[0, 1, 5]], [[0, 1, -1]]])
def test_face_indices_outside_the_vertices_are_refused(bad):
    # VTK read the missing vertex from outside its point buffer and drew a garbage triangle, without an error
    mesh = trimesh.Trimesh(process=False)
    mesh.vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 1]])
    mesh.faces = np.array(bad)
    with pytest.raises(InvalidInputError, match=r"mesh\.faces must index its 3 vertices \(0 \.\. 2\); face 0 is "):
        render.render_mesh(mesh, window_size=(64, 48))


@needs_render
def test_layered_renderer_refuses_face_indices_outside_the_vertices():
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        with pytest.raises(InvalidInputError,
                           match=r"faces of layer 'a' must index its 3 vertices .*face 0 is \[0, 1, 7\]$"):
            renderer.set_mesh("a", [[0.0, 0, 0], [1, 0, 0], [0, 1, 1]], [[0, 1, 7]])


LAYER = ([[0.0, 0, 0], [1, 0, 0], [0, 1, 1]], [[0, 1, 2]])


@needs_render
@pytest.mark.parametrize(
    ("name", "vertices", "faces", "kwargs", "match"),
    [
        (5, *LAYER, {}, r"name must be a string; got 5"),  # rendered, then render(['a', 5]) failed in sorted()
        (None, *LAYER, {}, r"name must be a string; got None"),
        ("a", [0.0, 1, 2, 3], LAYER[1], {}, r"vertices of layer 'a' must be \(V, 3\) coordinates; got shape \(4,\)"),
        ("a", [["x", "y", "z"]] * 3, LAYER[1], {},
         r"vertices of layer 'a' must be \(V, 3\) coordinates \(real numbers\); got dtype <U1"),
        ("a", LAYER[0], [0, 1], {}, r"faces of layer 'a' must be \(F, 3\) vertex indices; got shape \(2,\)"),
        ("a", LAYER[0], [["x", "y", "z"]], {},
         r"faces of layer 'a' must be \(F, 3\) vertex indices \(real numbers\); got dtype <U1"),
        ("a", LAYER[0], [[0, 1.5, 2]], {},  # truncated to vertex 1 before
         r"faces of layer 'a' must be \(F, 3\) vertex indices; got 1.5 \(not a whole number\)"),
        ("a", *LAYER, {"rgb": np.zeros((2, 3), np.uint8)},  # pyvista's "Invalid array shape" before
         r"rgb of layer 'a' must be \(V, 3\) or \(V, 4\) colours in 0-255, one per vertex \(3\); got shape \(2, 3\)"),
        ("a", *LAYER, {"rgb": np.zeros(3, np.uint8)}, r"rgb of layer 'a' must be .*; got shape \(3,\)"),  # IndexError
        ("a", *LAYER, {"rgb": np.full((3, 3), 300)}, r"rgb of layer 'a' must be .*; got values from 300 to 300"),
        ("a", *LAYER, {"rgb": np.full((3, 3), np.nan)}, r"rgb of layer 'a' must be .*; got values from nan to nan"),
        ("a", *LAYER, {"rgb": [["r", "g", "b"]] * 3}, r"rgb of layer 'a' must be .*; got dtype <U1"),
        ("a", *LAYER, {"values": [0.5, 0.5]},  # pyvista's "Invalid array shape" before
         r"values of layer 'a' must be one finite number in \[0, 1\] per vertex \(3\); got shape \(2,\)"),
        ("a", *LAYER, {"values": [0.5, np.nan, 0.5]}, r"values of layer 'a' must be .*; got NaN or inf at vertex 1"),
        ("a", *LAYER, {"values": ["x", "y", "z"]}, r"values of layer 'a' must be .*; got dtype <U1"),
        ("a", *LAYER, {"values": [0.5, 1.5, 0.5]},  # clipped to white before
         r"values of layer 'a' must be one finite number in \[0, 1\] per vertex \(3\); got 1.5 at vertex 1"),
        ("a", *LAYER, {"values": [-0.25, 0.5, 0.5]}, r"values of layer 'a' must be .*; got -0.25 at vertex 0"),
        ("a", *LAYER, {"values": [0.5] * 3, "rgb": np.zeros((3, 3), np.uint8)},  # values won silently
         r"layer 'a' takes rgb or values, not both"),
        ("a", *LAYER, {"bounds": [1.0, 2.0, 3.0]},  # "too many values to unpack" before
         r"bounds of layer 'a' must be \[\(xmin, ymin, zmin\), \(xmax, ymax, zmax\)\] with max >= min"),
        ("a", *LAYER, {"bounds": [[np.nan] * 3, [1.0] * 3]}, r"bounds of layer 'a' must be"),  # a NaN origin
    ],
)
def test_layered_renderer_names_bad_set_mesh_arguments(name, vertices, faces, kwargs, match):
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        with pytest.raises(InvalidInputError, match=match):
            renderer.set_mesh(name, vertices, faces, **kwargs)


@needs_render
def test_layered_renderer_names_bad_colours_of_a_mesh_it_updates():
    """Same topology: the colours were assigned in place, and pyvista's ValueError named nothing."""
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("a", *LAYER, rgb=np.zeros((3, 3), np.uint8))
        renderer.set_mesh("b", *LAYER, values=[0.0, 0.5, 1.0])
        with pytest.raises(InvalidInputError, match=r"rgb of layer 'a' must be .*; got shape \(2, 3\)"):
            renderer.set_mesh("a", *LAYER, rgb=np.zeros((2, 3), np.uint8))
        with pytest.raises(InvalidInputError, match=r"values of layer 'b' must be .*; got shape \(4,\)"):
            renderer.set_mesh("b", *LAYER, values=[0.0, 0.5, 1.0, 1.0])
        renderer.set_view("oblique", renderer.bounds_of("a"))
        renderer.set_mesh("a", *LAYER, rgb=np.full((3, 3), 200, np.uint8))
        expected, _depth = renderer.render(["a"])
        assert (expected < 250).any()
        renderer.set_mesh("a", *LAYER, rgb=np.zeros((3, 3), np.uint8))
        renderer.set_mesh("a", *LAYER, rgb=np.full((3, 4), 200.0))  # floats in 0-255 and RGBA still work
        np.testing.assert_array_equal(renderer.render(["a"])[0], expected)


@needs_render
@pytest.mark.parametrize("names", ["ab", "a", b"a", 5, None, [["a"]]])
def test_layered_renderer_render_wants_a_sequence_of_names(names):
    """render("ab") showed the layers 'a' and 'b' (the string's characters) instead of a layer 'ab', and render(5)
    raised the int's 'not iterable' TypeError: the names are a sequence, as the docstring says."""
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        for name in ("a", "b", "ab"):
            renderer.set_mesh(name, *LAYER)
        renderer.set_view("oblique", renderer.bounds_of("a"))
        with pytest.raises(InvalidInputError, match=r"names must be a sequence of layer names, e.g. \['overview'\]; "
                                                    rf"got {re.escape(repr(names))}"):
            renderer.render(names)
        assert renderer.render(["ab"])[0].shape == renderer.render(("a", "b"))[0].shape == (48, 64, 3)


@needs_render
@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda r: r.set_view("oblique", "abc"),  # numpy's "could not convert string to float" before
         r"box must be \[\(xmin, ymin, zmin\), \(xmax, ymax, zmax\)\] with max >= min \(real numbers\); got dtype <U3"),
        (lambda r: r.set_view("oblique", [["0", "0", "0"], ["1", "1", "1"]]),  # taken as numbers before
         r"box must be .*; got dtype <U1"),
        (lambda r: r.set_view("oblique", [[False] * 3, [True] * 3]), r"box must be .*; got dtype bool"),  # 0 and 1
        (lambda r: r.set_view("oblique", [[0, 0, 0], [1, 1]]), r"box must be .*; got rows of different lengths"),
        (lambda r: r.set_view("oblique", [[0, 0, 0], [1, 1, np.nan]]),
         r"box must be .* with max >= min; got \[\[0, 0, 0\], \[1, 1, nan\]\]"),
        (lambda r: r.set_view(("1", "2"), r.bounds_of("a")),  # taken as (1.0, 2.0) before
         r"camera must be 'oblique', 'top', \(azimuth, elevation\) in radians .*; got \('1', '2'\)"),
        (lambda r: r.project("abc"), r"points must be \(N, 3\) world points \(real numbers\); got dtype <U3"),
        (lambda r: r.project([["1", "2", "3"]]), r"points must be \(N, 3\) world points .*; got dtype <U1"),  # taken
        (lambda r: r.project([[True, False, True]]), r"points must be .*; got dtype bool"),  # taken as 1 and 0
        (lambda r: r.project([[1.0, 2.0]]), r"points must be \(N, 3\) world points; got shape \(1, 2\)"),  # reshape
        (lambda r: r.project([[1.0, 2.0, 3.0], [1.0]]), r"points must be .*; got rows of different lengths"),
    ],
)
def test_layered_renderer_view_and_projection_name_bad_arguments(call, match):
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("a", *LAYER)
        with pytest.raises(InvalidInputError, match=match):
            call(renderer)
        renderer.set_view((np.float32(0.5), 1), np.array(renderer.bounds_of("a"), np.float32))  # numpy numbers
        np.testing.assert_allclose(renderer.project(np.array([0, 0, 0], np.int32)), renderer.project([[0.0, 0, 0]]))


BOARD = (np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 1]]), np.array([[0, 1, 2]]), None, (np.pi, 1.2),
         np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 1]]))


def billboard(**changes):
    names = ("vertices", "faces", "rgb", "view", "anchor_points")
    return tuple(changes.get(name, value) for name, value in zip(names, BOARD, strict=True))


@needs_render
@pytest.mark.parametrize(
    ("args", "match"),
    [
        (billboard(rgb=np.zeros((2, 3), np.uint8)),  # pyvista's "Invalid array shape" before
         r"rgb must be \(V, 3\) or \(V, 4\) colours in 0-255, one per vertex \(3\); got shape \(2, 3\)"),
        (billboard(rgb=np.zeros((3, 1))), r"rgb must be .*; got shape \(3, 1\)"),  # pyvista's "RGB array must be"
        (billboard(rgb=np.full((3, 3), 300)), r"rgb must be .*; got values from 300 to 300"),  # wrapped to 44
        (billboard(rgb=np.full((3, 3), -5.0)), r"rgb must be .*; got values from -5 to -5"),  # wrapped to 251
        (billboard(rgb=np.full((3, 3), np.nan)), r"rgb must be .*; got values from nan to nan"),  # drawn black
        (billboard(rgb=[["r", "g", "b"]] * 3), r"rgb must be .* \(real numbers\); got dtype <U1"),  # int("r")
        (billboard(faces=np.array([[0, 1, 7]])),  # VTK read a vertex past the end
         r"faces must index its 3 vertices \(0 \.\. 2\); face 0 is \[0, 1, 7\]"),
        (billboard(faces=[[0, 1, 1.5]]), r"faces must be \(F, 3\) vertex indices; got 1.5 \(not a whole number\)"),
        (billboard(vertices="abc"), r"vertices must be \(V, 3\) coordinates \(real numbers\); got dtype <U3"),
        (billboard(anchor_points=np.zeros((3, 2))),  # reshaped to (2, 3) before
         r"anchor_points must be \(N, 3\) world points; got shape \(3, 2\)"),
        (billboard(view=(np.nan, 1.0)), r"view must be \(azimuth, elevation\) in radians, finite; got \(nan, 1.0\)"),
        (billboard(view="top"), r"view must be \(azimuth, elevation\) in radians, finite; got 'top'"),
        (billboard(view=(0.0, 2.0)),  # named 'camera' (render_mesh's) by the pair's check, not the argument given
         r"view's elevation must lie in \[-π/2, π/2\] radians .*; got \(0.0, 2.0\)"),
    ],
)
def test_layered_renderer_billboard_names_bad_arguments(args, match):
    with render.LayeredRenderer(window_size=(64, 64)) as renderer:
        renderer.set_mesh("a", *BOARD[:2])
        renderer.set_view("top", renderer.bounds_of("a"))
        with pytest.raises(InvalidInputError, match=match):
            renderer.render_billboard(*args)
        color, coverage, _depth = renderer.render_billboard(*billboard(rgb=np.full((3, 3), 200, np.uint8)))
        assert coverage.any()
        again = renderer.render_billboard(*billboard(rgb=np.full((3, 4), 200.0)))  # floats in 0-255, RGBA
        np.testing.assert_array_equal(again[0], color)


@needs_render
def test_layered_renderer_billboard_takes_nan_vertices_as_set_mesh_does_and_refuses_infinite_ones():
    """One NaN vertex made the billboard's centre, and so every coordinate, NaN; an infinite one blanked VTK's render:
    nothing was drawn, without a word. As in set_mesh, a NaN vertex is left out of the framing (its faces are not
    drawn); an infinite one, and vertices with none finite, are refused by name."""
    quad = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 1], [0, 10, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    with render.LayeredRenderer(window_size=(64, 64)) as renderer:
        renderer.set_mesh("a", quad, faces)
        renderer.set_view("top", renderer.bounds_of("a"))
        expected = renderer.render_billboard(quad, faces, None, (np.pi, 1.2), quad)
        assert expected[1].any()
        with_nan = np.vstack([quad, [[5.0, np.nan, 0.5]]])  # a fifth vertex, on a third face
        got = renderer.render_billboard(with_nan, np.vstack([faces, [[0, 1, 4]]]), None, (np.pi, 1.2), quad)
        for a, b in zip(got, expected, strict=True):
            np.testing.assert_array_equal(a, b)
        with pytest.raises(InvalidInputError, match=r"vertices must be finite or NaN \(nodata\); got an infinite "
                                                    r"value at index \(4, 1\)"):
            renderer.render_billboard(np.vstack([quad, [[5.0, -np.inf, 0.5]]]), faces, None, (np.pi, 1.2), quad)
        with pytest.raises(InvalidInputError, match=r"vertices must include a finite vertex; got 4 vertices, none "
                                                    r"finite \(nothing to render\)"):
            renderer.render_billboard(np.full((4, 3), np.nan), faces, None, (np.pi, 1.2), quad)


@needs_render
def test_render_mesh_and_set_mesh_take_nan_vertices_and_refuse_infinite_ones_as_the_billboard_does():
    """One infinite vertex, even one no face uses, blanked the whole render without a word (render_mesh,
    render_textured_mesh and set_mesh, with or without given bounds). As in render_billboard, it is refused by
    name, and a NaN vertex is still left out of the framing."""
    quad = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 1], [0, 10, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    with_nan, with_inf = (np.vstack([quad, [[5.0, bad, 0.5]]]) for bad in (np.nan, -np.inf))  # a fifth, unused vertex
    infinite = r"must be finite or NaN \(nodata\); got an infinite value at index \(4, 1\)"
    expected = render.render_mesh(trimesh.Trimesh(quad, faces, process=False), window_size=(64, 64))
    assert (expected < 250).any()
    got = render.render_mesh(trimesh.Trimesh(with_nan, faces, process=False), window_size=(64, 64))
    np.testing.assert_array_equal(got, expected)
    with pytest.raises(InvalidInputError, match=r"mesh.vertices " + infinite):
        render.render_mesh(trimesh.Trimesh(with_inf, faces, process=False), window_size=(64, 64))
    textured = trimesh.Trimesh(with_inf, faces, process=False)
    from PIL import Image

    textured.visual = trimesh.visual.TextureVisuals(uv=np.zeros((5, 2)), image=Image.new("RGB", (4, 4)))
    with pytest.raises(InvalidInputError, match=r"mesh.vertices " + infinite):
        render.render_textured_mesh(textured, window_size=(64, 64))
    with render.LayeredRenderer(window_size=(64, 64)) as renderer:
        renderer.set_mesh("a", quad, faces)
        renderer.set_view("top", renderer.bounds_of("a"))
        expected, _depth = renderer.render(["a"])
        assert (expected < 250).any()
        renderer.set_mesh("a", with_nan, faces)
        np.testing.assert_array_equal(renderer.render(["a"])[0], expected)
        with pytest.raises(InvalidInputError, match=r"vertices of layer 'a' " + infinite):
            renderer.set_mesh("a", with_inf, faces)
        with pytest.raises(InvalidInputError, match=r"vertices of layer 'b' " + infinite):  # the per-frame path
            renderer.set_mesh("b", with_inf, faces, bounds=renderer.bounds_of("a"))
        assert not renderer.has("b", None)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e300])
def test_textured_render_refuses_non_finite_uvs(bad):
    # NaN or inf UVs (or beyond float32) rendered silently, with garbage texels on the faces they touch
    from PIL import Image

    mesh = square("+z")
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array([[0, 0], [1, 0], [1, bad], [0, 1]], float),
                                                image=Image.new("RGB", (4, 4)))
    with pytest.raises(InvalidInputError, match=r"mesh.visual.uv must hold finite texture coordinates \(u, v\); got "
                                                r"1 of 4 vertices not finite in float32 \(first: vertex 2 at \[1.0, "):
        render.render_textured_mesh(mesh, window_size=(64, 48))


def test_textured_render_refuses_uvs_of_the_wrong_shape():
    from PIL import Image

    mesh = square("+z")
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.zeros((4, 3)), image=Image.new("RGB", (4, 4)))
    with pytest.raises(InvalidInputError, match=r"mesh.visual.uv must be \(V, 2\) texture coordinates \(u, v\); "
                                                r"got shape \(4, 3\)"):
        render.render_textured_mesh(mesh, window_size=(64, 48))


@pytest.mark.parametrize(("kwargs", "match"), [({"lighting": "no"}, "lighting must be True, False or .relief."),
                                               ({"anti_aliasing": "no"}, "anti_aliasing must be True or False")])
def test_textured_render_flags_must_be_bools(kwargs, match):
    # lighting='no' is true to Python: the texture was lit by the key and fill lights
    from PIL import Image

    mesh = square("+z")
    mesh.visual = trimesh.visual.TextureVisuals(uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float),
                                                image=Image.new("RGB", (4, 4)))
    with pytest.raises(InvalidInputError, match=match):
        render.render_textured_mesh(mesh, window_size=(64, 48), **kwargs)


def _hill() -> trimesh.Trimesh:
    y, x = np.mgrid[0:20, 0:20].astype(np.float32)
    return st.heightfield_mesh(10.0 * np.exp(-((x - 9.5) ** 2 + (y - 9.5) ** 2) / 30.0))  # 19 across, 10 tall


@pytest.mark.parametrize(
    ("mesh", "kwargs"),
    [
        (_hill, {"z_scale": 1e4}),  # 19 across, 1e5 tall: a sub-pixel sliver, a blank image before
        (lambda: _hill().apply_scale([1e-6, 1e-6, 1.0]), {}),  # a tiny footprint under ordinary heights
        (lambda: _hill().apply_scale([1e-6, 1e-6, 1.0]), {"camera": (0.5, 0.2)}),  # a fitted pair of angles too
    ],
)
def test_a_mesh_too_thin_to_see_is_refused_before_rendering(mesh, kwargs):
    with pytest.raises(InvalidInputError, match=r"the mesh would render 0\.\d+ x \d.* pixels.*z_scale near"):
        render.render_mesh(mesh(), window_size=(160, 120), **kwargs)


def test_pixel_extent_of_a_fitted_box_fills_the_frame_and_a_thin_one_does_not():
    box = np.array([[-9.5, -9.5, -5.0], [9.5, 9.5, 5.0]])
    corners = render._box_corners(box)
    position = render._camera_position("oblique", corners, 160 / 120)
    px, py = render._pixel_extent(corners, position, (160, 120))
    assert max(px / 160, py / 120) > 0.85 and min(px, py) > 50  # fitted: the box fills the frame
    thin = render._box_corners(box * [1.0, 1.0, 1e5])
    px, py = render._pixel_extent(thin, render._camera_position("oblique", thin, 160 / 120), (160, 120))
    assert px < 1.0 < py


@needs_render
def test_an_exaggerated_but_visible_mesh_still_renders():
    image = render.render_mesh(_hill(), window_size=(160, 120), z_scale=20.0)  # 200 tall, 19 across: fine
    assert (image != 255).any(axis=-1).mean() > 0.02
