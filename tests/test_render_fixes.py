"""Regression tests for render.py bugs found by an adversarial hunt (bad cameras, read-back rects)."""

from __future__ import annotations

import copy
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import stepterrain as st
from stepterrain import render
from stepterrain.errors import DataFileError, InvalidInputError, OutputTooLargeError

from .conftest import needs_render

VERTICES = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 5]], float)
FACES = np.array([[0, 1, 2], [1, 3, 2]])
#: An elevation of 89.9 degrees, where an elevation beyond a quarter turn (35, meant as any view) was clipped to.
TOP = float(np.radians(89.9))


@pytest.mark.parametrize("camera", [
    [(0, 0, 0), (0, 0, 0), (0, 0, 1)],          # eye on the focal point: rendered blank
    [(0, 0, 30), (0, 0, 0), (0, 0, 1)],         # view up along the view direction: rendered blank
    [(0, 0, 30), (0, 0, 0), (0, 0, -2)],        # ... or against it
    [(0, -20, 20), (0, 0, 0), (0, 0, 0)],       # zero view up: VTK's own ValueError
    [(1e300, 0, 0), (0, 0, 0), (0, 0, 1)],      # a view direction whose length overflows: rendered blank
])
def test_a_degenerate_explicit_camera_position_is_named(camera):
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"camera \[\(eye\), \(focal point\), \(view up\)\] needs .*; got "):
        render.render_mesh(mesh, window_size=(32, 32), camera=camera)


@needs_render
def test_a_usable_explicit_camera_position_still_renders():
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    image = render.render_mesh(mesh, window_size=(32, 32), camera=[(0, -20, 20), (0, 0, 0), (0, 0, 1)])
    assert (image < 250).any(axis=2).sum() > 50


@needs_render
def test_layered_renderer_refuses_a_degenerate_view_camera():
    with render.LayeredRenderer(window_size=(32, 32)) as renderer:
        renderer.set_mesh("a", VERTICES, FACES)
        with pytest.raises(InvalidInputError, match=r"camera \[\(eye\), \(focal point\), \(view up\)\] needs"):
            renderer.set_view([(5, 5, 40), (5, 5, 0), (0, 0, 1)], [[0, 0, 0], [10, 10, 5]])


@needs_render
@pytest.mark.parametrize("rect", ["abcd", 5, (0, 0, 10), (np.nan, 0, 10, 10), (1.7, 0, 10.2, 10), (0.5, 0, 10, 10),
                                  (True, 0, 10, 10)])
def test_render_names_a_bad_rect(rect):
    """int() read 'abcd' (ValueError), 5 (TypeError), a 3-tuple failed to unpack, NaN raised its own ValueError:
    raw tracebacks; 1.7 and 10.2 were truncated and True read as 1: a silently shifted crop."""
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("a", VERTICES, FACES)
        renderer.set_view("oblique", [[0, 0, 0], [10, 10, 5]])
        for reuse in (False, True):
            with pytest.raises(InvalidInputError, match=r"rect must be four whole pixel numbers .* 64x48 .*; got "):
                renderer.render(["a"], rect=rect, reuse=reuse)
        color, depth = renderer.render(["a"], rect=(0, 0, 10.0, np.int64(8)))  # whole numbers of any type
        full, _ = renderer.render(["a"])
        assert color.shape == (8, 10, 3) and depth.shape == (8, 10)
        np.testing.assert_array_equal(color, full[:8, :10])


def textured(image) -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    uv = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    return mesh


@pytest.mark.parametrize("image", [np.full((4, 4, 3), 60000, np.uint16),     # wrapped modulo 256: 60000 drew 96
                                   np.full((4, 4, 3), 0.5, np.float32),       # truncated to 0: drew black
                                   np.full((4, 4, 2), 9, np.uint8)])
def test_a_texture_image_that_is_not_uint8_is_named(image):
    with pytest.raises(InvalidInputError, match=r"texture image must be .* uint8 array .*; got dtype"):
        render.render_textured_mesh(textured(image), window_size=(32, 32), lighting=False)



@needs_render
@pytest.mark.parametrize("draw", ["render_textured_mesh", "render_mesh"])
def test_a_pbr_material_with_an_array_texture_renders_it(draw):
    """A PBRMaterial's baseColorTexture given as an array (glTF's material, as trimesh takes it) raised numpy's
    "truth value of an array ... is ambiguous" ValueError from reading the texture, naming nothing; a bad one (uint16)
    is named as a SimpleMaterial's is."""
    def pbr(image):
        mesh = textured(image)
        mesh.visual = trimesh.visual.TextureVisuals(
            uv=mesh.visual.uv, material=trimesh.visual.material.PBRMaterial(baseColorTexture=image))
        return mesh

    kwargs = {"lighting": False} if draw == "render_textured_mesh" else {}
    image = getattr(render, draw)(pbr(np.full((4, 4, 3), (30, 140, 220), np.uint8)), window_size=(32, 32),
                                  camera="top", **kwargs)
    plain = getattr(render, draw)(textured(np.full((4, 4, 3), (30, 140, 220), np.uint8)), window_size=(32, 32),
                                  camera="top", **kwargs)
    np.testing.assert_array_equal(image, plain)  # drawn as the same texture on a SimpleMaterial
    assert image[16, 16, 2] > image[16, 16, 1] > image[16, 16, 0]  # the texture's blue, not the plain tan
    with pytest.raises(InvalidInputError, match=r"texture image must be .* uint8 array .*; got dtype uint16"):
        getattr(render, draw)(pbr(np.full((4, 4, 3), 60000, np.uint16)), window_size=(32, 32), **kwargs)

def test_a_float_pillow_texture_is_named():
    from PIL import Image

    with pytest.raises(InvalidInputError, match=r"texture image must be an 8-bit or 16-bit image; got Pillow mode F"):
        render.render_textured_mesh(textured(Image.new("F", (4, 4), 0.5)), window_size=(32, 32), lighting=False)


@needs_render
def test_a_16_bit_pillow_texture_is_scaled_not_saturated():
    """Pillow's convert('RGB') saturated every 16-bit value above 255: a 16-bit texture drew white."""
    from PIL import Image

    image = render.render_textured_mesh(textured(Image.new("I;16", (4, 4), 100 * 257)), window_size=(32, 32),
                                        lighting=False)
    assert abs(int(image[16, 16, 0]) - 100) <= 2
    gray = render.render_textured_mesh(textured(Image.new("L", (4, 4), 100)), window_size=(32, 32), lighting=False)
    np.testing.assert_array_equal(image, gray)


@pytest.mark.parametrize("size", [{32, 40}, frozenset({64, 48}), {32: 1, 40: 2}])
def test_an_unordered_size_is_refused(size):
    """A set has no order: window_size={32, 40} or Camera(viewport={640, 480}) could come out as height x width."""
    from stepterrain.camera import Camera

    with pytest.raises(InvalidInputError, match="window_size must be two positive whole numbers"):
        render._check_window(size, 1.0)
    with pytest.raises(InvalidInputError, match="Camera viewport must be"):
        Camera((0.0, -10.0, 5.0), (0.0, 0.0, 0.0), viewport=size)


# ------------------------------------------------------------------------------------------ fuzzing (h9)
def test_render_scalars_given_as_an_array_is_named():
    """``scalars not in (None, "level", "height")`` compared an array with each name: numpy's ambiguous-truth error."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"^scalars must be None, 'level' or 'height'"):
        render.render_mesh(mesh, window_size=(64, 48), scalars=np.array(["level", "height"], dtype=object))


@pytest.mark.parametrize("z_scale", [1e155, 1e305, 1e308])
def test_a_z_scale_overflowing_the_height_range_is_refused_without_runtime_warnings(z_scale):
    """z times z_scale overflowed float64 with RuntimeWarnings before the fitted camera refused the mesh (an
    explicit camera went on with inf vertices)."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for camera in ("oblique", [(5, -40, 40), (5, 5, 0), (0, 0, 1)]):
            with pytest.raises(InvalidInputError, match=r"^z_scale=.* tall: beyond .* overflow float64"):
                render.render_mesh(mesh, window_size=(64, 48), z_scale=z_scale, camera=camera)


def test_a_ragged_image_is_named_by_save_png(tmp_path):
    """np.asarray of ragged rows raised numpy's "inhomogeneous shape" ValueError, naming no argument."""
    with pytest.raises(InvalidInputError, match=r"^image must be .*got rows of different lengths"):
        render.save_png([[1, 2], [3]], tmp_path / "a.png")
    assert not list(tmp_path.iterdir())


def test_a_path_with_a_nul_character_is_named(tmp_path):
    """The NUL reached tempfile/os calls: a bare ValueError ("embedded null byte")."""
    with pytest.raises(InvalidInputError, match=r"^path must be a file name without NUL characters"):
        render.save_png(np.zeros((8, 8, 3), np.uint8), str(tmp_path / "a\x00b.png"))
    assert not list(tmp_path.iterdir())


def test_a_file_name_too_long_is_a_data_file_error(tmp_path):
    """Path.is_symlink raised the bare OSError ENAMETOOLONG, outside the library's hierarchy."""
    with pytest.raises(DataFileError, match=r"^cannot write .*: File name too long"):
        render.save_png(np.zeros((8, 8, 3), np.uint8), tmp_path / ("x" * 300 + ".png"))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("cmap", [5, None, ["terrain"], b"terrain"])
def test_render_refuses_a_cmap_that_is_no_name_without_scalars(cmap):
    """With scalars=None the cmap was never looked at: cmap=5 (or a list) rendered without a word, though the same
    call with scalars='height' refused it."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"^cmap must name a matplotlib colormap .*; got "):
        render.render_mesh(mesh, window_size=(64, 48), cmap=cmap)
    with pytest.raises(InvalidInputError, match=r"^cmap must name a matplotlib colormap .*; got "):
        render.render_mesh(mesh, window_size=(64, 48), scalars="height", cmap=cmap)


@pytest.fixture
def tiny_budget():
    """A 1 MiB memory budget for one test, restored afterwards."""
    previous = st.set_memory_budget(1 << 20)
    yield
    st.set_memory_budget(previous)


def _no_render(*args, **kwargs):
    raise AssertionError("the render started: its memory was not checked against the budget first")


def _textured_quad() -> trimesh.Trimesh:
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    image = Image.fromarray(np.full((4, 4, 3), 128, np.uint8))
    mesh.visual = trimesh.visual.TextureVisuals(uv=VERTICES[:, :2] / 10.0, image=image)
    return mesh


def _render_calls():
    from stepterrain import globe
    from stepterrain.batch import BatchReport, overview_image
    from stepterrain.closeup import ROI, CloseUp, animate_closeups, render_closeups

    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    hills = np.random.default_rng(0).random((20, 20)).astype(np.float32) * 10
    closeup = CloseUp(ROI.circle((10.0, 10.0), 3.0), scale=1.5, offset=(0.0, 0.0, 20.0))
    camera = globe.look_from(0.0, 0.0, 1000.0, radius=100.0)
    return {
        "render_mesh": lambda size, aa: render.render_mesh(mesh, window_size=size, anti_aliasing=aa),
        "render_textured_mesh": lambda size, aa: render.render_textured_mesh(_textured_quad(), window_size=size,
                                                                             anti_aliasing=aa),
        "LayeredRenderer": lambda size, aa: render.LayeredRenderer(window_size=size),
        "render_closeups": lambda size, aa: render_closeups(hills, [closeup], window_size=size, device="cpu"),
        "animate_closeups": lambda size, aa: animate_closeups(hills, [closeup], frames=1, window_size=size,
                                                              device="cpu"),
        "globe.render_view": lambda size, aa: globe.render_view(mesh, camera, window_size=size),
        "batch.overview_image": lambda size, aa: overview_image(BatchReport(Path(".")), window_size=size),
    }


@pytest.mark.parametrize("name", list(_render_calls()))
def test_a_render_over_the_memory_budget_is_refused_before_it_starts(name, tiny_budget, monkeypatch):
    """Windows up to 16384 x 16384 were taken whatever st.set_memory_budget said: an off-screen render holds ~43
    bytes per pixel (colour and depth buffers, the screenshot and its copy; measured peak RSS on llvmpipe), ~70 with
    MSAA, so a 16384² render took ~11 GiB (or died of it) unchecked. The budget is now checked before the render
    (before pyvista is even imported, and before the close-ups are transformed or the globe mesh moved into the
    view's frame), naming the size and the argument."""
    from stepterrain import closeup, globe

    monkeypatch.setattr(render, "_import_pyvista", _no_render)
    monkeypatch.setattr(closeup, "closeup_layers", _no_render)
    monkeypatch.setattr(globe, "_view_frame", _no_render)
    call = _render_calls()[name]
    with pytest.raises(OutputTooLargeError, match=r"^an off-screen render of 512 x 384 pixels \(window_size 512x384"
                                                   r"\) would need .* MiB, over the memory budget of 1\.0 MiB; give a "
                                                   r"smaller window_size"):
        call((512, 384), False)


def test_anti_aliasing_counts_its_multi_samples_against_the_budget(tiny_budget, monkeypatch):
    """MSAA's multi-sampled colour and depth buffers (~28 bytes per pixel more, measured) were not counted: a window
    that fits without anti-aliasing can be over the budget with it, and the message says how to shrink it."""
    monkeypatch.setattr(render, "_import_pyvista", _no_render)
    size = (128, 128)
    assert render._render_bytes(*size) <= st.get_memory_budget() < render._render_bytes(*size, anti_aliasing=True)
    for name in ("render_mesh", "render_textured_mesh"):
        with pytest.raises(OutputTooLargeError, match=r"\(window_size 128x128, anti-aliased\) would need .*; give "
                                                       r"a smaller window_size or turn anti_aliasing off"):
            _render_calls()[name](size, True)
        with pytest.raises(AssertionError, match="the render started"):  # without MSAA it fits: the render begins
            _render_calls()[name](size, False)


@needs_render
def test_a_render_within_the_budget_still_renders(tiny_budget):
    """The check refuses only what exceeds the budget: a window whose estimate fits renders as before."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    assert render._render_bytes(64, 48) <= st.get_memory_budget()
    image = render.render_mesh(mesh, window_size=(64, 48))
    assert image.shape == (48, 64, 3) and (image < 250).any()


@needs_render
def test_layered_renderer_tells_numpy_cameras_apart_beyond_eight_digits():
    """set_view kept its view when the camera's repr was the same: numpy prints 8 digits, so an eye moved from
    1234567.810 to 1234567.814 (4 mm at UTM scale) kept the first eye. A camera refused once was also taken silently
    when asked again (its token was stored before the checks). Found by reading the view cache (helper 30)."""
    with render.LayeredRenderer(window_size=(32, 32)) as renderer:
        renderer.set_mesh("a", VERTICES, FACES)
        box = [[0, 0, 0], [10, 10, 5]]
        first = np.array([(1234567.81, -20.0, 20.0), (5.0, 5.0, 0.0), (0.0, 0.0, 1.0)])
        second = first.copy()
        second[0, 0] = 1234567.814
        assert repr(first) == repr(second)  # the old token could not tell them apart
        renderer.set_view(first, box)
        eye = np.array(renderer._plotter.camera_position[0])
        renderer.set_view(second, box)
        assert np.array(renderer._plotter.camera_position[0])[0] - eye[0] == pytest.approx(0.004, abs=1e-6)
        degenerate = [(5, 5, 40), (5, 5, 0), (0, 0, 1)]
        for _ in range(2):
            with pytest.raises(InvalidInputError, match=r"camera \[\(eye\), \(focal point\), \(view up\)\] needs"):
                renderer.set_view(degenerate, box)


def _bump_pixel(image: np.ndarray) -> tuple[float, float]:
    """Mean (row, column) of the yellow pixels (viridis' top level) of ``image``."""
    pixels = image.astype(int)
    yellow = (pixels[:, :, 0] > 150) & (pixels[:, :, 1] > 150) & (pixels[:, :, 2] < 100)
    rows, cols = np.nonzero(yellow)
    assert yellow.sum() > 20
    return rows.mean(), cols.mean()


@needs_render
@pytest.mark.parametrize("azimuth", [0.0, 90.0, 270.0])
def test_a_near_vertical_camera_keeps_the_far_side_up(azimuth):
    """At 89° elevation and above the view up switched from +z to +y: the image turned by 180° (from the north) or
    90° (from the east or west) between 88.9° and 89°, so a bump in the north-east corner jumped across it."""
    heights = np.zeros((30, 40))
    heights[2:8, 30:37] = 4.0  # rows first = north (dy < 0), columns to the east
    mesh = st.stepped(heights, spacing=(1.0, -1.0), origin=(0.0, 0.0), interval=2.0)
    spots = [_bump_pixel(render.render_mesh(mesh, window_size=(96, 64), camera=(np.radians(azimuth), np.radians(el)),
                                            scalars="level", cmap="viridis")) for el in (88.9, 89.0, 89.9)]
    for row, col in spots[1:]:
        assert abs(row - spots[0][0]) < 4 and abs(col - spots[0][1]) < 4, spots
    expected = {0.0: (True, False), 90.0: (True, True), 270.0: (False, False)}[azimuth]  # (bottom?, right?)
    assert (spots[0][0] > 32, spots[0][1] > 48) == expected, spots


@needs_render
@pytest.mark.parametrize("dy", [-1.0, 1.0])
def test_the_top_camera_is_north_up_and_east_right(dy):
    heights = np.zeros((30, 40))
    heights[2:8, 30:37] = 4.0  # first rows: north with dy < 0, south with dy > 0; east columns
    mesh = st.stepped(heights, spacing=(1.0, dy), origin=(0.0, 0.0), interval=2.0)
    row, col = _bump_pixel(render.render_mesh(mesh, window_size=(96, 64), camera="top", scalars="level",
                                              cmap="viridis"))
    assert col > 60 and (row < 24 if dy < 0 else row > 40)


@pytest.mark.parametrize("background", [(1, 0, 0), (1, 1, 1), np.array([0, 1, 0])])
def test_a_background_of_whole_zeros_and_ones_is_refused_as_ambiguous(background):
    """pyvista reads whole numbers as 0-255: (1, 0, 0) meant for red rendered a black (1, 0, 0) / 255 background."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"background .* is ambiguous"):
        render.render_mesh(mesh, window_size=(32, 32), background=background)



@pytest.mark.parametrize(("background", "read"), [((1, 0.5, 0), (1, 128, 0)), ([1, 1, 1.0], (1, 1, 255)),
                                                  ((np.int64(255), 0.5, 0), (255, 128, 0))])
def test_a_background_mixing_whole_numbers_and_floats_is_refused_as_ambiguous(background, read):
    """pyvista reads each channel by its type, an int as 0-255 and a float as 0-1: (1, 0.5, 0) meant for orange rendered
    a green (1, 128, 0) background, (1, 1, 1.0) meant for white a dark blue (numpy made floats of them all, which
    passed the check of whole numbers)."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=rf"background .* is ambiguous: it mixes whole numbers.* would be "
                                                rf"\({read[0]}, {read[1]}, {read[2]}\)"):
        render.render_mesh(mesh, window_size=(32, 32), background=background)
    with pytest.raises(InvalidInputError, match=r"background .* is ambiguous"):
        render.LayeredRenderer(window_size=(32, 32), background=background)

@needs_render
@pytest.mark.parametrize(("background", "expected"), [((1.0, 0.0, 0.0), (255, 0, 0)), ((255, 0, 0), (255, 0, 0)),
                                                      ((0, 0, 0), (0, 0, 0)), ("#00ff00", (0, 255, 0)),
                                                      ((1.0, 0, 0), (255, 0, 0))])  # a whole 0 is 0 either way
def test_the_background_colour_is_the_one_given(background, expected):
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    image = render.render_mesh(mesh, window_size=(32, 32), background=background)
    assert tuple(image[0, 0]) == expected


@needs_render
def test_face_colours_are_rendered():
    """A mesh with one colour per face (a PLY or 3MF read back) rendered in the default tan: its colours were dropped
    without a word."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    mesh.visual.face_colors = [[255, 0, 0, 255], [0, 0, 255, 255]]
    assert mesh.visual.kind == "face"
    image = render.render_mesh(mesh, window_size=(64, 48), camera="top").astype(int)
    red = (image[:, :, 0] > 100) & (image[:, :, 1] < 40) & (image[:, :, 2] < 40)
    blue = (image[:, :, 2] > 100) & (image[:, :, 0] < 40) & (image[:, :, 1] < 40)
    assert red.sum() > 100 and blue.sum() > 100
    rows, cols = np.nonzero(red)
    assert rows.mean() > 24 and cols.mean() < 32  # face 0 holds the south-west corner: bottom left


def _two_squares(front: tuple[int, ...], back: tuple[int, ...], *, front_first: bool, per: str) -> trimesh.Trimesh:
    """A unit square at z = 1 coloured ``front`` over one at z = 0 coloured ``back``, as one mesh (vertex or face
    colours per ``per``), the front square's faces first or last."""
    squares = [(np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], float), color)
               for z, color in ((1.0, front), (0.0, back))]
    if not front_first:
        squares.reverse()
    mesh = trimesh.Trimesh(np.vstack([v for v, _ in squares]), [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]],
                           process=False)
    colors = np.array([c for _, c in squares], np.uint8)
    if per == "vertex":
        mesh.visual.vertex_colors = np.repeat(colors, 4, axis=0)
    else:
        mesh.visual.face_colors = np.repeat(colors, 2, axis=0)
    return mesh


@needs_render
@pytest.mark.parametrize("per", ["vertex", "face"])
@pytest.mark.parametrize("front_first", [True, False])
def test_colour_alpha_blends_the_front_surface_over_the_one_behind(per, front_first):
    """render_mesh dropped the alpha of vertex and face colours: a mesh coloured semi-transparent (its GLB written
    alphaMode BLEND, so viewers show it so) rendered opaque. Now a red square of alpha 192 over an opaque blue one
    shows 192/255 of the red and 63/255 of the blue, in either face order (depth peeling: without it VTK blended the
    blue square over the red one)."""
    def centre(front, back):
        image = render.render_mesh(_two_squares(front, back, front_first=front_first, per=per), window_size=(64, 64),
                                   camera="top")
        return image[28:36, 28:36].reshape(-1, 3).astype(float).mean(axis=0)

    red = centre((255, 0, 0, 255), (0, 0, 255, 255))[0]  # the lit red and blue, opaque
    blue = centre((0, 0, 255, 255), (255, 0, 0, 255))[2]
    assert red > 150 and blue > 150
    blended = centre((255, 0, 0, 192), (0, 0, 255, 255))
    a = 192 / 255
    assert blended == pytest.approx([a * red, 0.0, (1 - a) * blue], abs=6)
    opaque = render.render_mesh(_two_squares((255, 0, 0, 255), (0, 0, 255, 255), front_first=front_first, per=per),
                                window_size=(64, 64), camera="top")
    square = (opaque[..., 0] > 100) & (opaque[..., 1] < 40)
    assert square.sum() > 500 and (opaque[..., 2][square] == 0).all()  # opaque colours still hide what lies behind


@needs_render
def test_anti_aliased_translucent_colours_are_blended_not_blank():
    """Depth peeling under MSAA rendered a blank image (Mesa), and MSAA without it blended out of depth order:
    translucent colours anti-alias by SSAA, which blends as the render without anti-aliasing does."""
    mesh = _two_squares((255, 0, 0, 192), (0, 0, 255, 255), front_first=False, per="vertex")
    plain, smooth = (render.render_mesh(mesh, window_size=(64, 64), camera="top", anti_aliasing=aa)[28:36, 28:36]
                     for aa in (False, True))
    assert np.abs(smooth.astype(int) - plain.astype(int)).max() <= 3 and plain[..., 0].min() > 100
    bytes_ssaa = render._render_bytes(1000, 1000, anti_aliasing=True, ssaa=True)
    assert bytes_ssaa > render._render_bytes(1000, 1000, anti_aliasing=True)
    previous = st.set_memory_budget(bytes_ssaa - 1)  # enough for MSAA, not for SSAA: refused before rendering
    try:
        with pytest.raises(OutputTooLargeError, match="anti-aliased"):
            render.render_mesh(mesh, window_size=(1000, 1000), camera="top", anti_aliasing=True)
        opaque = _two_squares((255, 0, 0, 255), (0, 0, 255, 255), front_first=False, per="vertex")
        assert render.render_mesh(opaque, window_size=(1000, 1000), camera="top", anti_aliasing=True).shape[0] == 1000
    finally:
        st.set_memory_budget(previous)


@needs_render
def test_view_angle_sets_the_renders_field_of_view():
    """render_mesh rendered at a fixed 30° vertical field of view, so an explicit camera could not show a narrower
    or wider view (globe.render_view's camera fov was ignored). view_angle sets it: from an eye 10 m over a 2 m square
    looking straight down, the square fills a tenth of a 90° picture's side, and a fitted camera still frames the
    whole mesh at any view angle."""
    vertices = np.array([[-1, -1, 0], [1, -1, 0], [-1, 1, 0], [1, 1, 0]], float)
    small = trimesh.Trimesh(vertices, [[0, 1, 2], [1, 3, 2]], process=False)
    covered = {angle: (render.render_mesh(small, window_size=(64, 64), camera=[(0, 0, 10), (0, 0, 0), (0, 1, 0)],
                                          background="black", view_angle=angle).max(axis=2) > 0).mean()
               for angle in (90.0, 30.0, 10.0)}
    for angle, share in covered.items():  # the square spans 2 / (2 · 10 · tan(angle / 2)) of the picture's side
        expected = min(1.0, 0.1 / np.tan(np.radians(angle) / 2)) ** 2
        assert abs(share - expected) < 0.06, covered
    for angle in (10.0, 90.0):  # fitted cameras frame the mesh alike at any view angle
        image = render.render_mesh(small, window_size=(64, 64), camera="top", background="black", view_angle=angle)
        assert 0.7 < (image.max(axis=2) > 0).mean() < 1.0


@pytest.mark.parametrize("angle", [0.0, 180.0, 1e-9, float("nan"), "30", True])
def test_a_view_angle_vtk_cannot_render_is_named(angle):
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"^view_angle must be a vertical field of view in \[1e-08, 179\] "
                                                r"degrees; got "):
        render.render_mesh(mesh, window_size=(64, 64), view_angle=angle)


@needs_render
@pytest.mark.parametrize("front_first", [True, False])
def test_anti_aliased_translucent_colours_blend_in_depth_order(front_first):
    """pyvista's SSAA pass replaced the renderer's own drawing, so depth peeling never ran under anti-aliasing: the
    faces blended in the order they were drawn, and an opaque square drawn after the translucent one in front of it
    hid it (pure blue where 3/4 red showed without anti-aliasing)."""
    mesh = _two_squares((255, 0, 0, 192), (0, 0, 255, 255), front_first=front_first, per="vertex")
    plain, smooth = (render.render_mesh(mesh, window_size=(64, 64), camera="top", anti_aliasing=aa)[28:36, 28:36]
                     for aa in (False, True))
    assert np.abs(smooth.astype(int) - plain.astype(int)).max() <= 3 and smooth[..., 0].min() > 100


def _two_textured_squares(texture: object, *, front_first: bool, material: str = "simple", **material_kw
                          ) -> trimesh.Trimesh:
    """``_two_squares`` textured: the front square (z = 1) takes texel (0, 0) of a 2 x 1 ``texture`` (an array or a
    Pillow image), the back one (z = 0) texel (0, 1)."""
    mesh = _two_squares((0, 0, 0, 255), (0, 0, 0, 255), front_first=front_first, per="vertex")
    front_uv, back_uv = [0.25, 0.5], [0.75, 0.5]
    uv = np.array([front_uv] * 4 + [back_uv] * 4 if front_first else [back_uv] * 4 + [front_uv] * 4)
    if material == "pbr":
        mat = trimesh.visual.material.PBRMaterial(baseColorTexture=texture, **material_kw)
    else:
        mat = trimesh.visual.material.SimpleMaterial(image=texture)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
    return mesh


@needs_render
@pytest.mark.parametrize("anti_aliasing", [False, True])
@pytest.mark.parametrize("front_first", [True, False])
@pytest.mark.parametrize("as_image", [True, False])
def test_texture_alpha_blends_the_front_surface_over_the_one_behind(as_image, front_first, anti_aliasing):
    """render_textured_mesh dropped the texture's alpha (a Pillow image was converted to RGB, an RGBA array drawn
    without depth peeling): a texel of alpha 192 rendered opaque. Now, unlit, a red texel of alpha 192 over an
    opaque blue one shows 192/255 of the red and 63/255 of the blue in either face order, anti-aliased or not."""
    def centre(front, back):
        texture = np.array([[front, back]], np.uint8)
        mesh = _two_textured_squares(Image.fromarray(texture, "RGBA") if as_image else texture,
                                     front_first=front_first)
        image = render.render_textured_mesh(mesh, window_size=(64, 64), camera="top", lighting=False,
                                            anti_aliasing=anti_aliasing)
        return image[28:36, 28:36].reshape(-1, 3).astype(float)

    opaque = centre((255, 0, 0, 255), (0, 0, 255, 255))
    assert (opaque == [255, 0, 0]).all()  # an opaque texture hides what lies behind, as before
    blended = centre((255, 0, 0, 192), (0, 0, 255, 255))
    assert blended.mean(axis=0) == pytest.approx([192, 0, 63], abs=3)
    assert np.ptp(blended, axis=0).max() <= 3


@needs_render
@pytest.mark.parametrize("mode", ["RGBa", "La"])
def test_a_premultiplied_alpha_texture_blends_as_its_straight_alpha_twin(mode):
    """Pillow's premultiplied-alpha modes rendered without their alpha: an RGBa texture was converted to RGB (its
    translucent texel drawn opaque), an La one raised Pillow's "conversion from La to L not supported". They are
    un-premultiplied to RGBA and LA now: a texel of alpha 192 over an opaque one blends as the RGBA image does."""
    straight = Image.fromarray(np.array([[[255, 0, 0, 192], [0, 0, 255, 255]]], np.uint8), "RGBA")
    if mode == "La":
        straight = straight.convert("LA")
    texture = straight.convert(mode)
    assert texture.mode == mode

    def centre(image):
        mesh = _two_textured_squares(image, front_first=True)
        shot = render.render_textured_mesh(mesh, window_size=(64, 64), camera="top", lighting=False)
        return shot[28:36, 28:36].reshape(-1, 3).mean(axis=0)

    expected = [192, 0, 63] if mode == "RGBa" else [192 * 76 / 255 + 63 * 29 / 255] * 3  # grey: 0.299 R, 0.114 B
    assert centre(straight) == pytest.approx(expected, abs=3)
    assert centre(texture) == pytest.approx(centre(straight), abs=2)


@needs_render
def test_texture_transparency_follows_png_transparency_and_gltf_alpha_mode():
    """A palette PNG's transparent colour (tRNS) hides its texels; a glTF material's alphaMode is followed when set:
    OPAQUE ignores the alpha, MASK shows or hides each texel at alphaCutoff."""
    def centre(mesh):
        image = render.render_textured_mesh(mesh, window_size=(64, 64), camera="top", lighting=False)
        return image[28:36, 28:36].reshape(-1, 3).mean(axis=0)

    palette = Image.fromarray(np.array([[[255, 0, 0], [0, 0, 255]]], np.uint8)).convert("P")
    palette.info["transparency"] = palette.getpixel((0, 0))  # the red entry
    assert centre(_two_textured_squares(palette, front_first=True)) == pytest.approx([0, 0, 255], abs=1)
    texture = Image.fromarray(np.array([[[255, 0, 0, 100], [0, 0, 255, 255]]], np.uint8), "RGBA")
    for kw, expected in (({"alphaMode": "OPAQUE"}, [255, 0, 0]), ({"alphaMode": "MASK"}, [0, 0, 255]),
                         ({"alphaMode": "MASK", "alphaCutoff": 0.3}, [255, 0, 0]),
                         ({"alphaMode": "BLEND"}, [100, 0, 155]), ({}, [100, 0, 155])):
        mesh = _two_textured_squares(texture, front_first=True, material="pbr", **kw)
        assert centre(mesh) == pytest.approx(expected, abs=2), kw


@needs_render
def test_anti_aliased_translucent_texture_is_checked_against_the_budget_for_ssaa():
    """An anti-aliased render of a translucent texture takes SSAA with depth peeling: its memory is refused before
    rendering, as for translucent colours; an opaque texture is checked for MSAA only."""
    texture = np.array([[[255, 0, 0, 192], [0, 0, 255, 255]]], np.uint8)
    bytes_ssaa = render._render_bytes(1000, 1000, anti_aliasing=True, ssaa=True)
    previous = st.set_memory_budget(bytes_ssaa - 1)
    try:
        with pytest.raises(OutputTooLargeError, match="anti-aliased"):
            render.render_textured_mesh(_two_textured_squares(texture, front_first=True), window_size=(1000, 1000),
                                        camera="top", anti_aliasing=True)
        opaque = texture.copy()
        opaque[..., 3] = 255
        shot = render.render_textured_mesh(_two_textured_squares(opaque, front_first=True), window_size=(1000, 1000),
                                           camera="top", anti_aliasing=True, lighting=False)
        assert (shot[500, 500] == [255, 0, 0]).all()
    finally:
        st.set_memory_budget(previous)


@needs_render
def test_the_drape_of_a_translucent_layer_renders_as_before():
    """drape composites its layer over a background, so its texture is opaque: it renders as the composited image,
    the layer's alpha already spent."""
    from stepterrain.texture import TextureLayer, drape

    mesh = st.heightfield_mesh(np.zeros((3, 3)))
    rgba = np.zeros((2, 2, 4), np.float32)
    rgba[...] = (1.0, 0.0, 0.0, 0.5)
    draped = drape(mesh, TextureLayer("thematic", rgba, (-0.5, 2.5, -0.5, 2.5)), background=(0.0, 0.0, 1.0))
    assert draped.visual.material.baseColorTexture.mode == "RGB"
    image = render.render_textured_mesh(draped, window_size=(64, 64), camera="top", lighting=False)
    assert image[32, 32] == pytest.approx([128, 0, 128], abs=1)


@needs_render
def test_an_explicit_camera_is_relative_to_the_centre_of_the_box_in_every_entry_point():
    """LayeredRenderer.set_view (and so render_closeups) took an explicit [(eye), (focal point), (view up)] relative
    to the centre of the first mesh uploaded, while render_mesh, which both name as their model, takes it relative to
    the centre of ``bounds``: with a box not centred on the terrain (room above it for lifted close-ups, or the default
    box of overview and close-ups together) the same camera showed the terrain 27 rows higher in a 100-row picture."""
    from stepterrain.closeup import render_closeups
    from stepterrain.terrain import as_terrain

    heights = (np.random.default_rng(0).random((30, 40)) * 5).astype(np.float32)
    terrain = as_terrain(heights)
    mesh = terrain.mesh()
    rgb = np.tile(np.array([[200, 120, 60]], np.uint8), (len(mesh.vertices), 1))
    mesh.visual.vertex_colors = rgb
    box = np.array([mesh.vertices.min(axis=0), mesh.vertices.max(axis=0) + [5.0, 0.0, 30.0]])  # off the mesh's centre
    camera = [(0.0, -60.0, 40.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    alone = render.render_mesh(mesh, window_size=(160, 100), camera=camera, bounds=box)
    with render.LayeredRenderer(window_size=(160, 100)) as renderer:
        renderer.set_mesh("terrain", mesh.vertices, mesh.faces, rgb=rgb)
        renderer.set_view(camera, box)
        layered, _ = renderer.render(["terrain"])
    np.testing.assert_array_equal(layered, alone)
    overview = render_closeups(terrain, [], window_size=(160, 100), camera=camera, bounds=box, device="cpu")
    np.testing.assert_array_equal((overview < 250).any(axis=2), (alone < 250).any(axis=2))  # the same pixels drawn


@needs_render
def test_the_z_scale_a_too_thin_error_suggests_renders_or_is_not_suggested():
    """A fitted camera refusing a mesh too thin to see named the z_scale that makes it as tall as it is wide, even
    where height was not what was thin: a 2-row strip seen from the top (199 x 1 across) was told 'a z_scale near
    39.9', which failed with the same message. The z_scale is now offered as the fix only where that camera then
    sees the mesh; elsewhere the message says it does not help."""
    import re

    strip = st.heightfield_mesh((np.random.default_rng(0).random((2, 200)) * 5).astype(np.float32))
    tower = st.heightfield_mesh(np.array([[0, 0], [0, 1e6]], np.float32))
    for mesh, camera, helps in ((strip, "top", False), (tower, "oblique", True)):
        with pytest.raises(InvalidInputError, match="too thin to see") as caught:
            render.render_mesh(mesh, window_size=(160, 90), camera=camera)
        scale = float(re.search(r"a z_scale near ([0-9.e+-]+)", str(caught.value))[1])
        assert ("does not show it from this camera" not in str(caught.value)) == helps
        if helps:
            assert render.render_mesh(mesh, window_size=(160, 90), camera=camera, z_scale=scale).shape == (90, 160, 3)
        else:
            with pytest.raises(InvalidInputError, match="too thin to see"):
                render.render_mesh(mesh, window_size=(160, 90), camera=camera, z_scale=scale)


@needs_render
def test_a_render_leaves_pyvistas_global_off_screen_setting_alone(monkeypatch):
    """Loading pyvista for a render set pyvista.OFF_SCREEN = True for the whole process: after one st.render_mesh (or
    offscreen_available) every later pv.Plotter() and mesh.plot() of the caller's rendered off-screen, with no window
    and no word. The library's own plotters are made off-screen explicitly; the global stays the caller's."""
    import pyvista as pv

    from stepterrain.closeup import render_closeups

    monkeypatch.setattr(pv, "OFF_SCREEN", False)
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    assert render.render_mesh(mesh, window_size=(32, 32)).shape == (32, 32, 3)
    assert render.offscreen_available()[0]
    render_closeups(np.zeros((8, 8), np.float32), [], window_size=(32, 32), device="cpu")
    assert pv.OFF_SCREEN is False


@needs_render
def test_a_fitted_camera_frames_every_vertex_of_a_large_mesh():
    """render_mesh fitted its camera to at most ~100k vertices of a mesh, every k-th: a tower or a mast made of
    vertices between those (a building in a DSM of a million nodes) was cut off at the top of the picture. The fit
    now takes in the vertices the strided one leaves outside the view, until none is."""
    ground = np.array([[0, 0, 0], [800, 0, 0], [800, 800, 0], [0, 800, 0]], float)
    tower = trimesh.creation.box(extents=(60, 60, 2000))
    tower.vertices += (400, 700, 1000)
    # vertices on the ground (framed too: each used by a degenerate face, which draws nothing) set the stride to 2
    filler = np.full((250_000, 3), 400.0)
    filler[:, 2] = 0.0
    pairs = np.repeat(np.asarray(tower.vertices), 2, axis=0)
    pairs[::2] = (400.0, 400.0, 0.0)  # each tower vertex after a ground one: the tower's at odd indices, none strided
    vertices = np.concatenate([ground, filler, pairs])
    tower_index = len(ground) + len(filler) + 1 + 2 * np.arange(len(tower.vertices))
    points = np.repeat(np.r_[len(ground) + np.arange(len(filler)), tower_index - 1], 3).reshape(-1, 3)
    faces = np.concatenate([[[0, 1, 2], [0, 2, 3]], points, tower_index[np.asarray(tower.faces)]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert len(vertices) // 100_000 == 2 and (tower_index % 2 == 1).all()
    image = render.render_mesh(mesh, window_size=(200, 150))
    drawn = (image < 250).any(axis=2)
    assert drawn[:20].any() and not drawn[0].any()  # the tower's top shows, below the picture's edge


@needs_render
def test_an_eye_close_over_a_large_mesh_sees_the_ground_in_front_of_it():
    """With the eye inside the box of the mesh the near plane lay at a ten-thousandth of the far one: 2.2 m over a
    30 km square, so an eye 1 m over the ground looking 45° down saw the ground clipped away (the background). The
    near plane now stays within half the eye's distance to the mesh: the ground fills the picture."""
    ground = trimesh.Trimesh([[-15e3, -15e3, 0], [15e3, -15e3, 0], [15e3, 15e3, 0], [-15e3, 15e3, 0]],
                             [[0, 1, 2], [0, 2, 3]], process=False)
    image = render.render_mesh(ground, window_size=(64, 48), camera=[(0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (0, 0, 1)])
    assert (image < 250).any(axis=2).all()


@needs_render
@pytest.mark.parametrize("background", [(1.0, 1.0, 1.0, 0.0), (0, 0, 0, 0), "#ff000080"])
def test_a_translucent_background_is_refused_not_rendered_opaque(background):
    """A background with alpha (a transparent white asked for a PNG with no background) was taken and its alpha
    dropped: the render came back opaque white (or black, or red), an (H, W, 3) image, without a word."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"^background must be opaque: renders are \(H, W, 3\) RGB"):
        render.render_mesh(mesh, window_size=(32, 32), background=background)
    with pytest.raises(InvalidInputError, match=r"^background must be opaque"):
        render.LayeredRenderer(window_size=(32, 32), background=background)



@needs_render
@pytest.mark.parametrize("background", [(255, 128, 0, 1), (1.0, 0.5, 0.0, 1), (255, 128, 0, 1.0), (255, 128, 0, 255)])
def test_a_background_with_an_alpha_of_one_is_opaque_not_refused(background):
    """The translucent-background refusal read an alpha written 1 as pyvista reads a whole number, 1/255: CSS's
    rgba(255, 128, 0, 1), opaque orange, which rendered orange before, was refused as 'alpha 0.00392'. An alpha of
    1 is opaque whichever way it is read; the render's background is the colour asked for."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    image = render.render_mesh(mesh, window_size=(32, 32), background=background)
    assert image[0, 0].tolist() == [255, 128, 0]

@needs_render
def test_render_closeups_with_an_eye_close_over_a_large_terrain_sees_the_ground():
    """LayeredRenderer.set_view (render_closeups' camera) had render_mesh's near plane at a ten-thousandth of the far
    one with the eye inside the box: an eye 1 m over a 30 km terrain, looking 45° down, rendered only background. The
    near plane keeps off the meshes uploaded when the view is set, as render_mesh's keeps off its mesh."""
    from stepterrain.closeup import render_closeups
    from stepterrain.terrain import Terrain

    terrain = Terrain.from_heights(np.zeros((301, 301), np.float32), spacing=(100.0, 100.0))
    image = render_closeups(terrain, [], window_size=(64, 48), camera=[(0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (0, 0, 1)],
                            device="cpu")
    assert (image < 250).any(axis=2).all()


@needs_render
def test_keeping_the_near_plane_off_a_large_mesh_costs_no_more_memory_than_a_fitted_render():
    """The near plane's distance to the mesh (an eye inside the box of the mesh) took ~230 bytes a triangle at once,
    every triangle's nine coordinates gathered: 4.6 GB over a 20-million-triangle DSM, more than its render needed,
    and longer. Only triangles near the eye are measured now, a million at a time: a close eye's render costs about
    what a fitted camera's does (measured with tracemalloc, numpy's allocations)."""
    import tracemalloc

    n = 400  # 318,402 triangles, a wall at one edge so the eye lies inside the box of the mesh
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    heights = np.sin(x / 50.0) * 3.0 + 100.0 * (x > n - 3)
    corner = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.column_stack([corner, corner + 1, corner + n]),
                            np.column_stack([corner + 1, corner + n + 1, corner + n])])
    mesh = trimesh.Trimesh(np.column_stack([x.ravel(), y.ravel(), heights.ravel()]), faces, process=False)
    centre = mesh.bounds.mean(axis=0)
    eye, target = np.array([200.0, 200.0, 5.0]) - centre, np.array([250.0, 250.0, 0.0]) - centre
    close = [tuple(eye), tuple(target), (0, 0, 1)]  # 5 m over the ground in the middle, 45 degrees down: in the box
    peaks = {}
    for name, camera in (("fitted", "oblique"), ("close", close)):
        tracemalloc.start()
        try:
            image = render.render_mesh(mesh, window_size=(64, 48), camera=camera)
            peaks[name] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert (image < 250).any(axis=2).mean() > 0.5, name
    assert peaks["close"] < 1.5 * peaks["fitted"], peaks


@needs_render
@pytest.mark.parametrize("shown, verbosity", [(1, "VERBOSITY_WARNING"), (1, "VERBOSITY_INFO"), (0, "VERBOSITY_OFF")])
def test_a_render_leaves_the_users_vtk_warning_settings_as_they_were(shown, verbosity):
    """The first render turned VTK's warnings off (vtkObject.GlobalWarningDisplayOff) and its stderr log down to
    errors for the whole process: a user's own pyvista and VTK code in it lost its warnings from then on. stepterrain
    quiets VTK only while it renders now, and restores the caller's settings after every entry point."""
    from vtkmodules.vtkCommonCore import vtkLogger, vtkObject

    from stepterrain.closeup import render_closeups
    from stepterrain.terrain import Terrain

    old = (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff())
    try:
        vtkObject.SetGlobalWarningDisplay(shown)
        vtkLogger.SetStderrVerbosity(getattr(vtkLogger, verbosity))
        before = (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff())
        mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
        render.render_mesh(mesh, window_size=(32, 32))
        assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
        assert render.offscreen_available()[0]
        assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
        terrain = Terrain.from_heights(np.arange(100, dtype=np.float32).reshape(10, 10), spacing=(1.0, 1.0))
        render_closeups(terrain, [], window_size=(32, 32), device="cpu")
        assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
        with render.LayeredRenderer(window_size=(32, 32)) as renderer:
            renderer.set_mesh("m", VERTICES, FACES)
            assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
            renderer.set_view("oblique", [(0, 0, 0), (10, 10, 5)])
            renderer.render(["m"])
            assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
        assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
    finally:
        vtkObject.SetGlobalWarningDisplay(old[0])
        vtkLogger.SetStderrVerbosity(old[1])


def _textured_square(rgba: np.ndarray) -> trimesh.Trimesh:
    """A 10 x 10 square, a hill at one corner, with ``rgba`` as its texture (row 0 at the north)."""
    uv = VERTICES[:, :2] / 10.0
    visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(rgba))
    return trimesh.Trimesh(VERTICES, FACES, visual=visual, process=False)


def _covered(image: np.ndarray) -> np.ndarray:
    return (image < 250).any(axis=2)


@needs_render
@pytest.mark.parametrize("camera", ["oblique", "top", (0.5, 0.6)])
def test_render_textured_mesh_takes_view_angle_and_frames_as_render_mesh(camera):
    """render_mesh took a view_angle (the globe's camera field of view goes through it), render_textured_mesh had
    none: a textured mesh could only be shown at 30 degrees, and a textured and a coloured render of one mesh could not
    be matched at another field of view. It takes one now, fitted and framed as render_mesh's: the same pixels are
    covered, and a narrower angle from the same explicit eye shows the mesh larger."""
    gray = np.full((4, 4, 3), 120, np.uint8)
    textured = _textured_square(gray)
    plain = trimesh.Trimesh(VERTICES, FACES, process=False)
    for view_angle in (10.0, 30.0, 90.0):
        a = render.render_textured_mesh(textured, window_size=(64, 48), camera=camera, view_angle=view_angle)
        b = render.render_mesh(plain, window_size=(64, 48), camera=camera, view_angle=view_angle)
        assert np.array_equal(_covered(a), _covered(b)), view_angle
    eye = [(0.0, -40.0, 30.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    wide = render.render_textured_mesh(textured, window_size=(64, 48), camera=eye, view_angle=40.0)
    narrow = render.render_textured_mesh(textured, window_size=(64, 48), camera=eye, view_angle=20.0)
    assert _covered(narrow).sum() > 3 * _covered(wide).sum()
    with pytest.raises(InvalidInputError, match=r"^view_angle must be a vertical field of view in \[1e-08, 179\]"):
        render.render_textured_mesh(textured, window_size=(64, 48), view_angle=180.0)


@needs_render
def test_render_closeups_takes_view_angle():
    """render_closeups had no view_angle, unlike render_mesh: its LayeredRenderer always set VTK's 30 degrees. The
    angle now reaches the renderer's camera and its fit: with no close-ups the composite is the overview's render
    as render_mesh draws it at that angle (the same pixels covered), and a narrower angle from the same explicit eye
    shows the terrain larger."""
    from stepterrain.closeup import render_closeups
    from stepterrain.terrain import Terrain

    terrain = Terrain.from_heights(np.add.outer(np.arange(20.0), np.arange(30.0)).astype(np.float32),
                                   spacing=(1.0, 1.0))
    mesh = terrain.mesh()
    for view_angle in (10.0, 60.0):
        layered = render_closeups(terrain, [], window_size=(64, 48), scalars=None, view_angle=view_angle, device="cpu")
        plain = render.render_mesh(mesh, window_size=(64, 48), bounds=mesh.bounds, view_angle=view_angle)
        assert np.abs(layered.astype(int) - plain.astype(int)).max() <= 1, view_angle
    eye = [(0.0, -60.0, 40.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
    wide, narrow = (render_closeups(terrain, [], window_size=(64, 48), camera=eye, view_angle=angle, device="cpu")
                    for angle in (40.0, 20.0))
    assert _covered(narrow).sum() > 2 * _covered(wide).sum()
    with pytest.raises(InvalidInputError, match=r"^view_angle must be a vertical field of view"):
        render_closeups(terrain, [], window_size=(64, 48), view_angle=0.0, device="cpu")


@needs_render
def test_a_magnified_texture_is_filtered_linearly_not_drawn_as_blocks():
    """render_textured_mesh gave VTK its texture without interpolation: magnified (a DEM's topographic texture, one
    texel per node, on a 1280-pixel window), each texel was drawn as a flat block with hard steps between, where a
    glTF viewer shows the mesh's GLB (no sampler: linear filtering) smooth. A ramp of 9 texels, one per node, now
    renders as a ramp: many grey levels, rising steadily along the row, the texel value at each node."""
    from stepterrain.texture import TextureLayer, drape

    mesh = st.heightfield_mesh(np.zeros((9, 9)))
    ramp = np.tile(np.arange(9) / 8.0, (9, 1))
    draped = drape(mesh, TextureLayer("luminance", ramp, (-0.5, 8.5, -0.5, 8.5)))
    image = render.render_textured_mesh(draped, window_size=(160, 120), camera="top", lighting=False)
    row = image[60, :, 0].astype(int)
    on_mesh = row[np.argmax(row < 255):]  # from the west edge (black) to the east edge (white, as the background)
    on_mesh = on_mesh[: np.argmax(on_mesh == 255) + 1]
    assert len(np.unique(on_mesh)) > 40
    assert (np.diff(on_mesh) >= 0).all() and np.diff(on_mesh).max() <= 8


@needs_render
def test_a_texture_shrunk_on_screen_is_mipmapped_not_aliased():
    """render_textured_mesh's texture had no mipmaps: shrunk on screen (a texture of more texels than the pixels it
    covers), each pixel took one texel of many, and a fine pattern shimmered as noise. A 1024² one-texel checker on
    a quad ~100 pixels wide now renders as its mean grey, evenly; without mipmaps pixels were near black or white."""
    checker = (np.add.outer(np.arange(1024), np.arange(1024)) % 2 * 255).astype(np.uint8)
    mesh = trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float), [[0, 1, 2], [0, 2, 3]],
                           process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.vertices[:, :2], image=Image.fromarray(checker))
    image = render.render_textured_mesh(mesh, window_size=(128, 128), camera="top", lighting=False)
    centre = image[40:88, 40:88].astype(float)
    assert np.abs(centre - 127.5).max() <= 8  # every pixel the checker's mean, not one of its texels


@needs_render
def test_render_mesh_draws_a_textured_mesh_with_its_texture():
    """render_mesh drew a textured mesh (drape's, a GLB read back: TextureVisuals) in the plain tan, its texture
    dropped. It now draws the texture, lit, as render_textured_mesh(lighting=True) does, pixel for pixel; a
    coloured mesh still renders with its colours, and scalars= still colours by the colormap."""
    from stepterrain.texture import TextureLayer, drape

    mesh = st.heightfield_mesh(np.zeros((11, 11)))
    picture = np.zeros((20, 20, 3), np.uint8)
    picture[:10, :, 0] = 255  # north half red
    picture[10:, :, 2] = 255  # south half blue
    textured = drape(mesh, TextureLayer("thematic", picture, (-0.5, 10.5, -0.5, 10.5)))
    shot = render.render_mesh(textured, window_size=(120, 120), camera="top")
    north, south = shot[30, 60].astype(int), shot[90, 60].astype(int)
    assert north[0] > 150 and north[1:].max() < 20 and south[2] > 150 and south[:2].max() < 20
    np.testing.assert_array_equal(
        shot, render.render_textured_mesh(textured, window_size=(120, 120), camera="top", lighting=True))
    by_height = render.render_mesh(textured, window_size=(120, 120), camera="top", scalars="height")
    assert not (by_height[30, 60].astype(int)[1:] < 20).all()  # the colormap, not the texture


@needs_render
def test_a_pbr_texture_is_multiplied_by_its_base_color_factor():
    """render_textured_mesh (and render_mesh) ignored a PBR material's baseColorFactor, which glTF multiplies with
    the texture and save_mesh writes to the GLB: a tinted or dimmed texture rendered at full brightness, a factor's
    alpha (alphaMode BLEND) opaque. The colour is multiplied in linear light, as a viewer shows the GLB: a texel of
    200 times 0.5 is 147; with BLEND an alpha factor 0.5 lays the texel half over the background; unset alphaMode
    over an opaque texture is glTF's OPAQUE, the factor's alpha ignored."""
    quad = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)

    def centre(factor, alpha_mode=None):
        mesh = trimesh.Trimesh(quad, [[0, 1, 2], [0, 2, 3]], process=False)
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (4, 4), (200, 200, 200)),
                                                       baseColorFactor=factor, alphaMode=alpha_mode)
        mesh.visual = trimesh.visual.TextureVisuals(uv=quad[:, :2], material=material)
        shot = render.render_textured_mesh(mesh, window_size=(64, 64), camera="top", lighting=False,
                                           background="black")
        return shot[32, 32].astype(int).tolist()

    linear = ((200 / 255 + 0.055) / 1.055) ** 2.4 * (128 / 255)  # trimesh holds the factor as bytes: 0.5 is 128
    half = round((1.055 * linear ** (1 / 2.4) - 0.055) * 255)
    assert centre([1.0, 0.5, 0.0, 1.0]) == [200, half, 0]
    assert centre([1.0, 1.0, 1.0, 0.5], "BLEND") == pytest.approx([100, 100, 100], abs=1)
    assert centre([1.0, 1.0, 1.0, 0.5]) == [200, 200, 200]
    assert centre([1.0, 1.0, 1.0, 1.0]) == [200, 200, 200]


@needs_render
def test_renders_in_two_threads_at_once_leave_the_users_vtk_warning_settings_as_they_were():
    """Each render saved VTK's process-wide warning settings, quieted them and put back what it had saved: two
    renders overlapping in two threads (a web service) left the warnings off for good, as the second saved the
    first's quiet settings and restored them after the first had restored the user's. The overlap is forced here:
    the first render ends while the second is still in its quiet section."""
    import threading

    from vtkmodules.vtkCommonCore import vtkLogger, vtkObject

    old = (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff())
    try:
        vtkObject.SetGlobalWarningDisplay(1)
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_WARNING)
        before = (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff())
        first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
        seen = {}

        def first():
            with render._quiet_vtk():
                first_in.set()
                second_in.wait(10)
            first_out.set()

        def second():
            first_in.wait(10)
            with render._quiet_vtk():
                second_in.set()
                first_out.wait(10)
                seen["quiet while the second renders"] = vtkObject.GetGlobalWarningDisplay()

        threads = [threading.Thread(target=first), threading.Thread(target=second)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(20)
        assert seen == {"quiet while the second renders": 0}
        assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
        # and through the entry points, four threads rendering at once: the same images as one at a time
        mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
        alone = render.render_mesh(mesh, window_size=(32, 24))
        images = []
        barrier = threading.Barrier(4)

        def draw():
            barrier.wait(10)
            images.extend(render.render_mesh(mesh, window_size=(32, 24)) for _ in range(3))

        threads = [threading.Thread(target=draw) for _ in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(60)
        assert len(images) == 12 and all(np.array_equal(image, alone) for image in images)
        assert (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff()) == before
    finally:
        vtkObject.SetGlobalWarningDisplay(old[0])
        vtkLogger.SetStderrVerbosity(old[1])


def test_a_pyvista_users_global_theme_leaves_the_renders_alone():
    """render_mesh, render_textured_mesh and the LayeredRenderer took show_edges, opacity, silhouette,
    show_vertices and the camera orientation widget from pv.global_theme: a pyvista user's theme drew edges over a
    textured mesh and the close-ups, a half-transparent terrain, dots at every vertex, a widget in the corner, and a
    values pass read edge colours as values. Found by rendering with a pyvista user's theme set. Now stepterrain's
    plotters get pyvista's default theme, and add_mesh those settings, as smooth shading and lights were."""
    import pyvista as pv

    heights = np.add.outer(np.arange(12.0), np.arange(16.0)) ** 1.5
    steps = st.stepped(heights.astype(np.float32), interval=8.0, colors="terrain", device="cpu")
    picture = np.random.default_rng(0).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    textured = steps.copy()
    uv = steps.vertices[:, :2] / [15.0, 11.0]
    textured.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(picture))
    values = np.linspace(0.0, 1.0, len(steps.vertices))

    def shots():
        with render.LayeredRenderer(window_size=(64, 48)) as renderer:
            renderer.set_mesh("values", steps.vertices, steps.faces, values=values)
            renderer.set_view("oblique", renderer.bounds_of("values"))
            layered = renderer.render(["values"])[0]
        return [render.render_mesh(steps, window_size=(64, 48)),
                render.render_textured_mesh(textured, window_size=(64, 48)), layered]

    plain = shots()
    theme = copy.deepcopy(pv.global_theme)
    try:
        pv.global_theme.show_edges = True
        pv.global_theme.opacity = 0.5
        pv.global_theme.silhouette.enabled = True
        pv.global_theme.show_vertices = True
        pv.global_theme.enable_camera_orientation_widget = True
        themed = shots()
    finally:
        pv.global_theme.load_theme(theme)
    for name, a, b in zip(("render_mesh", "render_textured_mesh", "LayeredRenderer"), plain, themed, strict=True):
        assert np.array_equal(a, b), f"{name}: {np.mean(np.any(a != b, axis=2)):.0%} of the pixels changed by the theme"


@pytest.mark.parametrize("name", ["render_mesh", "render_textured_mesh"])
@pytest.mark.parametrize("channels", [3, 4])
def test_a_textured_meshs_texture_counts_against_the_render_budget(tiny_budget, monkeypatch, name, channels):
    """Only the window was counted: a mesh draped with a big texture (an orthophoto at its own resolution) rendered in
    a small window took ~12 bytes per texel more (VTK's copy, the texture and mipmaps llvmpipe holds; 4.6 GB for a
    17000 x 17000 texture, measured) past any budget. The texture's texels now count, 16 bytes each: a window that
    fits with a small texture is refused with a 1024 x 512 texel one, before the render starts, naming the texture."""
    monkeypatch.setattr(render, "_import_pyvista", _no_render)
    size = (64, 48)
    assert render._render_bytes(*size) + render._TEXTURE_BYTES_PER_TEXEL * 4 * 4 <= st.get_memory_budget()
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    image = np.full((512, 1024, channels), 128, np.uint8)
    if channels == 4:
        image[:, :, 3] = 200  # translucent: SSAA is not asked for (no anti-aliasing), the texels count alike
    mesh.visual = trimesh.visual.TextureVisuals(uv=VERTICES[:, :2] / 10.0, image=image)
    call = getattr(render, name)
    with pytest.raises(OutputTooLargeError, match=r"^an off-screen render of 64 x 48 pixels \(window_size 64x48\) "
                                                   r"of a mesh with a 1024 x 512 texel texture would need 8\.1 MiB, "
                                                   r"over the memory budget of 1\.0 MiB; give a smaller window_size "
                                                   r"or a smaller texture"):
        call(mesh, window_size=size)
    with pytest.raises(AssertionError, match="the render started"):  # a small texture fits: the render begins
        call(_textured_quad(), window_size=size)


@pytest.mark.parametrize("name", ["render_mesh", "render_textured_mesh"])
def test_a_texture_over_the_render_budget_is_refused_before_it_is_decoded(tiny_budget, monkeypatch, tmp_path, name):
    """The texture was decoded (a PIL image opened from a file, 4 bytes a texel as RGBA, more with a baseColorFactor)
    before its texels were counted against the budget: the refusal came after the largest allocation of all. Its
    size is known from the file's header: the render is refused with the image still undecoded."""
    monkeypatch.setattr(render, "_import_pyvista", _no_render)

    def decoded(*args, **kwargs):
        raise AssertionError("the texture was decoded before the budget was checked")

    Image.fromarray(np.full((512, 1024, 3), 90, np.uint8)).save(tmp_path / "big.png")
    picture = Image.open(tmp_path / "big.png")  # lazily: the header read, the pixels not
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=VERTICES[:, :2] / 10.0, image=picture)
    monkeypatch.setattr(render, "_texture_picture", decoded)
    with pytest.raises(OutputTooLargeError, match=r"of a mesh with a 1024 x 512 texel texture would need 8\.1 MiB"):
        getattr(render, name)(mesh, window_size=(64, 48))
    assert picture._im is None  # never loaded
    picture.close()


def _grid_mesh(n: int) -> trimesh.Trimesh:
    """A heightfield of n x n nodes: 2 (n - 1)² faces, n² vertices."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    z = np.random.default_rng(0).random((n, n))
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return trimesh.Trimesh(np.stack([x.ravel(), y.ravel(), z.ravel()], 1), faces, process=False)


@pytest.mark.parametrize("name", ["render_mesh", "render_textured_mesh", "globe.render_view"])
def test_a_mesh_whose_render_copies_are_over_the_budget_is_refused_whatever_the_window(name, tiny_budget,
                                                                                          monkeypatch):
    """Only the window (and a texture's texels) was counted, while the copies made for rendering (the recentred
    vertices, the PolyData's cells, VTK's and llvmpipe's buffers) grow with the mesh: ~26 bytes a face and ~94 a
    vertex measured, so the stepped embedded DEM at interval 5 (18 M faces) took 1.2-1.5 GiB in a 400 x 300 render
    checked as 5.5 MiB. The mesh is now counted before any copy of it is made, and the message says that a smaller
    window does not help."""
    from stepterrain import globe

    monkeypatch.setattr(render, "_import_pyvista", _no_render)
    monkeypatch.setattr(globe, "_view_frame", _no_render)
    mesh = _grid_mesh(80)  # 12,482 faces, 6,400 vertices
    if name == "render_textured_mesh":
        mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.vertices[:, :2] / 80.0,
                                                    image=Image.fromarray(np.zeros((4, 4, 3), np.uint8)))
    assert render._render_bytes(64, 48, texels=16) <= st.get_memory_budget() // 4  # the window alone fits
    assert render._render_bytes(64, 48, vertices=6400, faces=12482) > st.get_memory_budget()
    call = {
        "render_mesh": lambda: render.render_mesh(mesh, window_size=(64, 48)),
        "render_textured_mesh": lambda: render.render_textured_mesh(mesh, window_size=(64, 48)),
        "globe.render_view": lambda: globe.render_view(mesh, globe.look_from(0.0, 0.0, 1000.0, radius=100.0),
                                                       window_size=(64, 48)),
    }[name]
    with pytest.raises(OutputTooLargeError, match=r"^an off-screen render of 64 x 48 pixels \(window_size 64x48\) of "
                                                   r"a mesh .*12,482 faces and 6,400 vertices would need .* MiB, over "
                                                   r"the memory budget of 1\.0 MiB; render a mesh of fewer faces .*"
                                                   r"not with the window_size\)"):
        call()
    with pytest.raises(AssertionError, match="the render started"):  # a mesh of a quarter the nodes fits
        render.render_mesh(_grid_mesh(40), window_size=(64, 48))


def test_face_colours_count_against_the_render_budget(tiny_budget, monkeypatch):
    """A colour per face (a PLY or 3MF read back) costs more to render than none (VTK's cell colours): a mesh that
    fits plain is refused with face colours once they push it over the budget."""
    monkeypatch.setattr(render, "_import_pyvista", _no_render)
    mesh = _grid_mesh(64)  # 7,938 faces, 4,096 vertices
    size = dict(vertices=4096, faces=7938)
    assert render._render_bytes(64, 48, **size) <= st.get_memory_budget() < render._render_bytes(
        64, 48, face_colors=True, **size)
    with pytest.raises(AssertionError, match="the render started"):
        render.render_mesh(mesh, window_size=(64, 48))
    mesh.visual.face_colors = np.full((len(mesh.faces), 4), 200, np.uint8)
    with pytest.raises(OutputTooLargeError, match=r"of a mesh of 7,938 faces and 4,096 vertices would need"):
        render.render_mesh(mesh, window_size=(64, 48))


@needs_render
def test_layered_renderer_counts_every_mesh_it_holds_against_the_budget():
    """A LayeredRenderer (render_closeups') checked its window alone, while it holds a render copy of every mesh set
    on it at once: the meshes are counted now, each set_mesh adding its mesh to those held (a mesh replaced by name
    counted once), before it is uploaded."""
    mesh = _grid_mesh(40)  # 3,042 faces, 1,600 vertices
    one = render._render_bytes(64, 48, layered=True, vertices=1600, faces=3042)
    two = render._render_bytes(64, 48, layered=True, vertices=3200, faces=6084)
    previous = st.set_memory_budget(two)
    try:
        assert one < two < render._render_bytes(64, 48, layered=True, vertices=4800, faces=9126)
        with render.LayeredRenderer(window_size=(64, 48)) as renderer:
            renderer.set_mesh("a", mesh.vertices, mesh.faces)
            renderer.set_mesh("b", mesh.vertices + 50.0, mesh.faces)
            renderer.set_mesh("a", mesh.vertices + 1.0, mesh.faces)  # replaced: still two meshes held
            with pytest.raises(OutputTooLargeError, match=r"of a mesh of 9,126 faces and 4,800 vertices would need"):
                renderer.set_mesh("c", mesh.vertices + 100.0, mesh.faces)
            assert sorted(renderer._meshes) == ["a", "b"]  # refused before it was uploaded
    finally:
        st.set_memory_budget(previous)


@pytest.mark.parametrize("name", ["render_mesh", "render_textured_mesh"])
def test_a_periodic_texture_spanning_many_periods_is_refused_before_it_is_widened(name):
    """A texture that repeats in u and is clamped in v (a globe's drape) is drawn from its columns repeated over the
    UVs' u range, and that widened picture was made before the render budget was checked: UVs spanning 2000 periods
    of a 256² image allocated ~400 MB first (a MemoryError for a larger one) where the budget refused it. The
    widened shape is checked before it is made."""
    import tracemalloc

    mesh = trimesh.creation.box()
    uv = np.zeros((len(mesh.vertices), 2))
    uv[:, 0], uv[:, 1] = np.linspace(0.0, 2000.0, len(mesh.vertices)), 0.5
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(np.zeros((256, 256, 3), np.uint8)))
    material.wrap = ("REPEAT", "CLAMP_TO_EDGE")
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    previous = st.set_memory_budget(200 << 20)
    tracemalloc.start()
    try:
        with pytest.raises(OutputTooLargeError, match="512768 x 256 texel texture"):
            getattr(render, name)(mesh, window_size=(64, 48))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
        st.set_memory_budget(previous)
    assert peak < 20 << 20  # the widened picture is 256 x 512768 x 3 bytes = 394 MB


@needs_render
@pytest.mark.parametrize("name", ["render_mesh", "render_textured_mesh"])
def test_vertices_no_face_uses_do_not_move_the_fitted_camera(name):
    """The camera was fitted to every finite vertex, those no face uses included: a stepped DEM cut down to its
    eastern part with trimesh's ``update_faces`` (which keeps every vertex) rendered as a small patch in the corner
    of a picture framed for the whole DEM (10 % of the pixels drawn, 50 % once the unused vertices were removed).
    VTK draws faces only: a render is the same with or without the vertices no face uses."""
    from stepterrain.texture import drape, topographic_layer

    dem = st.sample_dem()
    terrain = st.Terrain.from_heights(dem.heights[::16, ::16], spacing=(480.0, -480.0), origin=dem.origin)
    mesh = st.stepped(terrain, interval=200.0, colors="terrain", device="cpu")
    if name == "render_textured_mesh":
        mesh = drape(mesh, topographic_layer(terrain, device="cpu"))
    east = mesh.triangles_center[:, 0] > np.quantile(mesh.vertices[:, 0], 0.7)
    cut = mesh.copy()
    cut.update_faces(east)
    assert len(np.unique(cut.faces)) < 0.5 * len(cut.vertices)  # most vertices are used by no face
    clean = cut.copy()
    clean.remove_unreferenced_vertices()
    for camera in ("oblique", "top", (1.0, 0.4)):
        with_unused = getattr(render, name)(cut, window_size=(96, 64), camera=camera)
        without = getattr(render, name)(clean, window_size=(96, 64), camera=camera)
        # framed: 0.21 to 0.42 of the picture (the oblique view drew 0.11 of it before)
        assert (without < 250).any(axis=2).mean() > 0.15
        # the same picture, to the float rounding of the recentred vertices (a gray level at a few edge pixels)
        assert (np.abs(with_unused.astype(int) - without).max(axis=2) > 8).mean() < 0.01, camera


def _plain_box(material):
    box = trimesh.creation.box(extents=(4.0, 4.0, 1.0))
    box.visual = trimesh.visual.TextureVisuals(material=material)
    return box


@needs_render
def test_a_plain_coloured_material_renders_in_its_colour_not_tan(tmp_path):
    """A GLB of one plain-coloured mesh (a PBR baseColorFactor, no texture: trimesh reads it back as TextureVisuals
    without UVs) and an OBJ with a .mtl Kd rendered in the uniform tan. Now in the material's colour: glTF's linear
    factor shown sRGB-encoded, as a viewer shows it (red 0.5 linear: 188 before lighting), the OBJ's Kd as it is."""
    pbr = trimesh.visual.material.PBRMaterial(baseColorFactor=[128, 0, 0, 255])
    glb = tmp_path / "red.glb"
    st.export.save_mesh(_plain_box(pbr), glb)
    simple = trimesh.visual.material.SimpleMaterial(diffuse=[20, 40, 230, 255])
    obj = tmp_path / "blue.obj"
    _plain_box(simple).export(obj)

    def centre(mesh):
        image = render.render_mesh(mesh, window_size=(64, 64), camera="top")
        return image[28:36, 28:36].reshape(-1, 3).astype(float).mean(axis=0)

    plain = centre(trimesh.creation.box(extents=(4.0, 4.0, 1.0)))  # the tan, lit: all channels similar
    red = centre(st.export.read_mesh(glb))
    blue = centre(trimesh.load(obj, force="mesh"))
    assert plain.min() > 120 and red[1] < 5 and red[2] < 5 and blue[0] < blue[2] / 4
    shade = plain[0] / (render._DEFAULT_COLOR[0] * 255)  # the lighting on a face seen from the top
    assert red[0] == pytest.approx(188 * shade, abs=4)
    assert blue == pytest.approx(np.array([20, 40, 230]) * shade, abs=4)


@needs_render
def test_a_blended_plain_material_shows_what_lies_behind():
    """A plain material's alpha blends where its alphaMode is BLEND (and only there), as a glTF viewer shows it."""
    def square(color, mode, z):
        box = trimesh.creation.box(extents=(4.0, 4.0, 0.1))
        box.apply_translation([0, 0, z])
        box.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(baseColorFactor=color, alphaMode=mode))
        return box

    def centre(front_mode):
        front = square([255, 0, 0, 128], front_mode, 1.0)
        image = render.render_mesh(front, window_size=(64, 64), camera="top")
        return image[28:36, 28:36].reshape(-1, 3).astype(float).mean(axis=0)

    assert centre("OPAQUE")[1] < 5 and centre("OPAQUE")[0] > 150  # opaque red
    blended = centre("BLEND")  # the box's top and bottom, each half red, over the white background
    assert blended[1] == pytest.approx(255 * (1 - 128 / 255) ** 2, abs=6) and blended[0] > 200


@needs_render
def test_a_white_material_renders_in_the_tan_as_read_mesh_reads_it(tmp_path):
    """save_mesh gives a mesh without colours a white material (baseColorFactor 1: COLOR_0, or white, is the colour),
    which read_mesh reads back as the plain mesh it is; trimesh.load reads it as TextureVisuals of that material, which
    rendered white (on the white background) once a plain material's colour was drawn, where the same file read by
    read_mesh, and the mesh before it was saved, render in the tan."""
    box = trimesh.creation.box(extents=(4.0, 4.0, 1.0))
    glb = tmp_path / "plain.glb"
    st.export.save_mesh(box, glb)
    loaded = trimesh.load(glb, force="mesh", process=False)
    assert isinstance(loaded.visual, trimesh.visual.TextureVisuals)  # the white PBR material, no UVs
    loaded.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # glTF's y-up to z-up
    np.testing.assert_allclose(loaded.vertices, st.export.read_mesh(glb).vertices, atol=1e-6)
    white = _plain_box(trimesh.visual.material.PBRMaterial(baseColorFactor=[255, 255, 255, 255]))
    tan = render.render_mesh(box, window_size=(64, 64), camera="top")
    for mesh in (loaded, white):
        np.testing.assert_array_equal(render.render_mesh(mesh, window_size=(64, 64), camera="top"), tan)


@needs_render
def test_an_obj_material_without_kd_renders_in_the_tan_and_kd_grey_in_its_grey(tmp_path):
    """trimesh fills an .mtl material that names no Kd with its grey (0.4), which rendered as if the file asked for it;
    a material without a diffuse colour is no colour, as a mesh without a material: the tan. Kd 0.4 stays grey."""
    def obj(name, mtl_lines):
        (tmp_path / f"{name}.mtl").write_text("newmtl a\n" + mtl_lines)
        box = trimesh.creation.box(extents=(4.0, 4.0, 1.0))
        lines = [f"mtllib {name}.mtl"] + [f"v {x} {y} {z}" for x, y, z in box.vertices] + ["usemtl a"]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in box.faces]
        (tmp_path / f"{name}.obj").write_text("\n".join(lines) + "\n")
        return trimesh.load(tmp_path / f"{name}.obj", force="mesh")

    no_kd, kd = obj("nokd", "Ka 1 1 1\nKs 0.5 0.5 0.5\n"), obj("kd", "Kd 0.4 0.4 0.4\n")
    assert isinstance(no_kd.visual, trimesh.visual.TextureVisuals)
    np.testing.assert_array_equal(no_kd.visual.material.diffuse, kd.visual.material.diffuse)  # the same grey
    tan = render.render_mesh(trimesh.creation.box(extents=(4.0, 4.0, 1.0)), window_size=(64, 64), camera="top")
    np.testing.assert_array_equal(render.render_mesh(no_kd, window_size=(64, 64), camera="top"), tan)
    grey = render.render_mesh(kd, window_size=(64, 64), camera="top")[28:36, 28:36].reshape(-1, 3).astype(float)
    lit_tan = tan[28:36, 28:36].reshape(-1, 3).mean(axis=0)
    assert np.ptp(grey.mean(axis=0)) < 3 and np.abs(grey.mean(axis=0) - lit_tan).max() > 20


@needs_render
@pytest.mark.parametrize("camera", ["oblique", (0.7, 0.4)])
@pytest.mark.parametrize("view_angle", [120.0, 150.0])
def test_a_wide_view_angle_frames_the_mesh_in_the_middle(camera, view_angle):
    """A fitted camera recentres the projected box on screen in a few steps of the focal point. Whole steps
    overshot in a wide view: the near corners swung from one side of the picture to the other at each step, and
    the last left the mesh against one edge (a cube at 120 degrees in the right half of the picture only, at 170
    degrees not drawn at all). The drawn pixels' box is now centred, as the fit's symmetric projection puts it,
    and each axis of it reaches both halves of the picture."""
    mesh = trimesh.creation.box()
    width, height = 96, 64
    image = render.render_mesh(mesh, window_size=(width, height), camera=camera, view_angle=view_angle,
                               background="black")
    rows, cols = np.nonzero(image.max(axis=2) > 0)
    assert len(rows) > 0
    assert cols.min() < width / 2 < cols.max() and rows.min() < height / 2 < rows.max()
    assert abs((cols.min() + cols.max() + 1) / 2 - width / 2) <= 0.1 * width
    assert abs((rows.min() + rows.max() + 1) / 2 - height / 2) <= 0.1 * height


def test_the_fitted_camera_centres_the_box_it_frames_at_every_view_angle():
    """The projection behind the test above, without a render: the fitted camera leaves the middle of the framed
    corners' extreme directions within 5 % of the view's half-width of its axis on both screen axes (they
    alternated between one side and the other at wide angles: a cube at 120 degrees between 0.05 and 1 of it), and
    every corner inside the view."""
    for box in ([[-5.0, -3.0, 0.0], [5.0, 3.0, 1.5]], [[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]]):
        corners = render._box_corners(np.array(box))
        for camera in ("oblique", "top", (0.7, 0.4), (2.0, -0.3)):
            for view_angle in (10.0, 30.0, 60.0, 90.0, 120.0, 150.0, 170.0, 179.0):
                position = render._camera_position(camera, corners, 1.5, view_angle)
                rel, depth, right, up = render._eye_frame(corners, position)
                assert (depth > 0).all()
                tan_v = np.tan(np.radians(view_angle) / 2)
                for tangents, half in ((rel @ right / depth, tan_v * 1.5), (rel @ up / depth, tan_v)):
                    assert abs(tangents.max() + tangents.min()) / 2 <= 0.05 * half, (box, camera, view_angle)
                    assert np.abs(tangents).max() <= half * (1 + 1e-9), (box, camera, view_angle)


@needs_render
def test_a_tiny_mesh_renders_as_its_scaled_up_copy():
    """The fitted camera's distance had a floor of 1e-9 in the mesh's units: a mesh smaller than about 1e-10 was
    framed from that far, and refused as "too thin to see from a camera fitted to it" (a cube of side 1e-12
    measured 0.1 x 0.13 pixels), with a z_scale hint that could not help. The floor is now relative to the
    framed box, and a perspective view does not depend on the scale."""
    cube = trimesh.creation.box()
    reference = render.render_mesh(cube, window_size=(64, 48), background="black").max(axis=2) > 0
    for scale in (1e-12, 1e-20):
        tiny = trimesh.Trimesh(cube.vertices * scale, cube.faces, process=False)
        covered = render.render_mesh(tiny, window_size=(64, 48), background="black").max(axis=2) > 0
        assert (covered != reference).mean() < 0.01, scale


@needs_render
@pytest.mark.parametrize("scale", [1e-40, 1e-100, 1e-200])
def test_a_mesh_too_small_for_the_renderer_is_refused_not_drawn_blank(scale):
    """The fitted camera frames a mesh at any scale (its least distance is relative to the box), but VTK draws in
    single precision: a mesh smaller than about 1e-37 came back as a blank picture (1e-200: numpy's divide-by-zero
    warnings first). It is refused, naming its size."""
    cube = trimesh.creation.box()
    tiny = trimesh.Trimesh(cube.vertices * scale, cube.faces, process=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InvalidInputError, match="too small"):
            render.render_mesh(tiny, window_size=(64, 48), background="black")


@needs_render
@pytest.mark.parametrize("camera", ["oblique", (0.7, 0.4)])
def test_a_single_point_mesh_is_refused_without_nan_or_warnings(camera):
    """A mesh of one point (no extent at all): the relative least distance of the fitted camera was 1e-309, its eye
    on its focal point (numpy warnings, "nan x nan pixels" in the message). It is refused as 0 x 0 pixels."""
    point = trimesh.Trimesh([[1.0, 2.0, 3.0]] * 3, [[0, 1, 2]], process=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InvalidInputError, match="0 x 0 pixels") as caught:
            render.render_mesh(point, window_size=(64, 48), camera=camera)
    assert "nan" not in str(caught.value)


@needs_render
@pytest.mark.parametrize("step", ["set_mesh", "set_view", "render", "render_layers", "render_billboard", "project"])
def test_a_closed_layered_renderer_is_named_closed(step):
    """A LayeredRenderer used after close() (or its with-block) went on against the closed plotter: set_mesh and
    set_view passed without a word, render raised AttributeError ("'NoneType' object has no attribute 'Render'")
    from deep in VTK's window, and render_closeups(renderer=...) of the same terrain said "no layer named
    ['overview']; have []"."""
    with render.LayeredRenderer(window_size=(32, 32)) as renderer:
        renderer.set_mesh("a", VERTICES, FACES)
        renderer.set_view("oblique", [[0, 0, 0], [10, 10, 5]])
    calls = {
        "set_mesh": lambda: renderer.set_mesh("b", VERTICES, FACES),
        "set_view": lambda: renderer.set_view("top", [[0, 0, 0], [10, 10, 5]]),
        "render": lambda: renderer.render(["a"]),
        "render_layers": lambda: renderer.render_layers("x", {0: (VERTICES, FACES, {})}),
        "render_billboard": lambda: renderer.render_billboard(VERTICES, FACES, None, (0.0, 1.0), VERTICES),
        "project": lambda: renderer.project(VERTICES),
    }
    with pytest.raises(InvalidInputError, match=r"LayeredRenderer is closed .*make a new one"):
        calls[step]()
    renderer.close()  # closing twice stays harmless


@needs_render
def test_render_closeups_names_a_closed_renderer():
    """render_closeups with a renderer closed after an earlier frame: "no layer named ['overview']; have []" (the
    overview's mesh record outlived close(), so it was 'updated' in place and never shown)."""
    from stepterrain.closeup import ROI, CloseUp, render_closeups

    heights = np.add.outer(np.linspace(0, 50, 20), np.linspace(0, 30, 24)).astype(np.float32)
    terrain = st.Terrain.from_heights(heights, spacing=(10.0, 10.0))
    cu = CloseUp(ROI.circle((120.0, 100.0), 40.0), scale=1.5, offset=(0.0, 0.0, 60.0))
    renderer = render.LayeredRenderer(window_size=(96, 64))
    render_closeups(terrain, [cu], window_size=(96, 64), renderer=renderer)
    renderer.close()
    with pytest.raises(InvalidInputError, match=r"LayeredRenderer is closed"):
        render_closeups(terrain, [cu], window_size=(96, 64), renderer=renderer)


@needs_render
@pytest.mark.parametrize("then", ["plain", "values"])
def test_joined_layers_of_colours_now_gone_are_not_found_for_the_same_faces_without_them(then):
    """The renderer's memo of joined layers (keyed by prefix and group only) holds its parts weakly: once the colours
    of a first call were gone, their dead references read as None, matched a second call's absent colours for the same
    faces, and the gone colours came back: plain layers were drawn red, value layers raised "rgb and values"."""
    import gc

    def frozen(array):
        array = np.array(array)
        array.setflags(write=False)
        return array

    v0 = frozen([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]]).astype(float)
    v1 = v0 + [40.0, 0.0, 0.0]
    f0, f1 = frozen(FACES), frozen(FACES)
    kw = {"plain": lambda: {}, "values": lambda: {"values": np.full(4, 0.5)}}[then]

    def second(renderer):
        renderer.set_mesh("all", np.concatenate([v0, v1]), np.concatenate([f0, f1 + 4]))
        renderer.set_view("top", [[0, 0, 0], [50, 10, 0]])
        return renderer.render_layers("x", {0: (v0, f0, kw()), 1: (v1, f1, kw())})

    with render.LayeredRenderer(window_size=(96, 64)) as fresh:
        expected = second(fresh)
    with render.LayeredRenderer(window_size=(96, 64)) as renderer:
        renderer.set_mesh("all", np.concatenate([v0, v1]), np.concatenate([f0, f1 + 4]))
        renderer.set_view("top", [[0, 0, 0], [50, 10, 0]])
        red = {k: frozen(np.tile(np.array([255, 0, 0], np.uint8), (4, 1))) for k in (0, 1)}
        renderer.render_layers("x", {0: (v0, f0, {"rgb": red[0]}), 1: (v1, f1, {"rgb": red[1]})})
        assert len(renderer._joined) == 1  # the two layers did share a pass
        del red
        gc.collect()
        got = second(renderer)
    for k in (0, 1):
        assert ((expected[k][0][..., 0] > 200) & (expected[k][0][..., 1] < 50)).sum() == 0
        np.testing.assert_array_equal(got[k][0], expected[k][0])


@needs_render
def test_a_reused_pass_cannot_be_edited_through_the_returned_images():
    """render(reuse=True) returned its cached arrays themselves: a caller who drew into the returned image changed the
    cache, and the next reuse returned the edited image instead of the pass."""
    with render.LayeredRenderer(window_size=(48, 32)) as renderer:
        renderer.set_mesh("a", VERTICES, FACES)
        renderer.set_view("oblique", [[0, 0, 0], [10, 10, 5]])
        fresh, fresh_depth = renderer.render(["a"])
        for _ in range(2):  # the pass that fills the cache, then the one that reuses it
            color, depth = renderer.render(["a"], reuse=True)
            for image, value in ((color, 7), (depth, 0.5)):
                try:
                    image[...] = value
                except ValueError:
                    pass
                try:  # nor made writeable again
                    image.flags.writeable = True
                    image[...] = value
                except ValueError:
                    pass
        again, again_depth = renderer.render(["a"], reuse=True)
        np.testing.assert_array_equal(again, fresh)
        np.testing.assert_array_equal(again_depth, fresh_depth)


def _grid(nx: int, x0: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    """A flat nx x nx grid of 1 m cells at x0, height z: (vertices, faces)."""
    xs, ys = np.meshgrid(np.arange(nx, dtype=float) + x0, np.arange(nx, dtype=float))
    vertices = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)])
    i = (np.arange(nx - 1)[:, None] * nx + np.arange(nx - 1)[None, :]).ravel()
    faces = np.concatenate([np.column_stack([i, i + 1, i + nx]), np.column_stack([i + 1, i + nx + 1, i + nx])])
    return vertices, faces


@needs_render
def test_render_layers_drops_the_layers_of_an_earlier_call_it_no_longer_draws():
    """Layers of an earlier frame (a close-up gone) stayed as hidden actors: they kept the next view's clipping range
    out to where they were (near plane 300 times nearer, far 50 times farther: depth precision lost) and their
    meshes counted against the budget of the next frame's uploads, which refused a frame a fresh renderer drew."""
    ground = _grid(20, 0.0, 0.0)
    near_layer, far_layer = _grid(6, 5.0, 4.0), _grid(6, 5.0 + 20000.0, 3000.0)
    box = [[0, 0, 0], [20, 20, 5]]

    def frames(renderer, layers_of_frames):
        renderer.set_mesh("overview", *ground)
        for n, layers in enumerate(layers_of_frames):
            renderer.set_view((30.0 + n, TOP), box)
            renderer.render_layers("closeup", {k: (v, f, {}) for k, (v, f) in layers.items()}, merge=False)
        renderer.set_view((40.0, TOP), box)
        return renderer._plotter.camera.clipping_range

    with render.LayeredRenderer(window_size=(64, 48)) as fresh:
        expected = frames(fresh, [{0: near_layer}])
    with render.LayeredRenderer(window_size=(64, 48)) as reused:
        got = frames(reused, [{0: near_layer, 1: far_layer}, {0: near_layer}])
        assert "closeup:1" not in reused._actors
    np.testing.assert_allclose(got, expected, rtol=1e-12)

    # the budget: the first frame's layers fit, and so does the second's layer 0 (grown) beside the overview, but not
    # beside the gone layer 1 too
    big = _grid(60, 5.0, 4.0)
    need = render._render_bytes(64, 48, layered=True, vertices=sum(len(m[0]) for m in (ground, near_layer, big)),
                                faces=sum(len(m[1]) for m in (ground, near_layer, big)))
    previous = st.set_memory_budget(need)
    try:
        with render.LayeredRenderer(window_size=(64, 48)) as renderer:
            renderer.set_mesh("overview", *ground)
            renderer.set_view((30.0, TOP), box)
            renderer.render_layers("closeup", {0: (*near_layer, {}), 1: (*big, {})}, merge=False)
            renderer.render_layers("closeup", {0: (*big, {})}, merge=False)  # refused while layer 1 stayed
            assert sorted(renderer._actors) == ["closeup:0", "overview"]
    finally:
        st.set_memory_budget(previous)


@needs_render
def test_render_layers_drops_only_its_own_prefixs_earlier_layers():
    """Dropping the layers an earlier call drew and this one does not stays within the prefix: another prefix's
    layers (render_closeups' anchors beside its close-ups) and meshes set with set_mesh (a name that starts like the
    prefix too) stay, and are drawn as before."""
    ground, layer = _grid(20, 0.0, 0.0), _grid(6, 5.0, 4.0)
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *ground)
        renderer.set_mesh("closeup_user", *_grid(4, 12.0, 2.0))
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        user = renderer.render(["closeup_user"])
        both = {0: (*layer, {}), 1: (*_grid(4, 1.0, 3.0), {})}
        anchors = renderer.render_layers("anchor", both, merge=False)
        renderer.render_layers("closeup", both, merge=False)
        renderer.render_layers("closeup", {0: (*layer, {})}, merge=False)
        assert sorted(renderer._actors) == ["anchor:0", "anchor:1", "closeup:0", "closeup_user", "overview"]
        for k in (0, 1):
            np.testing.assert_array_equal(renderer.render([f"anchor:{k}"])[0], anchors[k][0])
        renderer.render_layers("anchor", {}, merge=False)
        assert sorted(renderer._actors) == ["closeup:0", "closeup_user", "overview"]
        np.testing.assert_array_equal(renderer.render(["closeup_user"])[0], user[0])


@needs_render
def test_render_layers_names_cannot_collide_across_prefixes():
    """Layer names were ``prefix + str(k)``: prefix "cu" layer 10 and prefix "cu1" layer 0 were both "cu10", one actor.
    The second call overwrote the first's mesh, and a later call of "cu" that no longer drew layer 10 removed "cu1"'s
    layer 0 (its later render: "no layer named")."""
    ground = _grid(20, 0.0, 0.0)
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *ground)
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        many = {k: (*_grid(3, 1.0 + k, 2.0), {}) for k in range(11)}
        renderer.render_layers("cu", many, merge=False)
        other = renderer.render_layers("cu1", {0: (*_grid(5, 8.0, 3.0), {})}, merge=False)
        assert len(renderer._actors) == 1 + 11 + 1
        renderer.render_layers("cu", {k: many[k] for k in range(10)}, merge=False)  # drops "cu"'s layer 10 only
        assert len(renderer._actors) == 1 + 10 + 1
        again = renderer.render_layers("cu1", {0: (*_grid(5, 8.0, 3.0), {})}, merge=False)
        np.testing.assert_array_equal(again[0][0], other[0][0])
        (name,) = set(renderer._actors) - set(renderer._layer_names["cu"]) - {"overview"}
        np.testing.assert_array_equal(renderer.render([name])[0], other[0][0])


@needs_render
@pytest.mark.parametrize("prefix", [5, None, b"cu", "cu:1"])
def test_render_layers_names_a_bad_prefix(prefix):
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *_grid(20, 0.0, 0.0))
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        with pytest.raises(InvalidInputError, match=r"render_layers prefix must be a str without ':' .*; got "):
            renderer.render_layers(prefix, {0: (*_grid(3, 1.0, 2.0), {})}, merge=False)


@needs_render
@pytest.mark.parametrize(("layers", "message"), [
    ([(VERTICES, FACES, {})], r"layers must be a dict \{k: \(vertices, faces, options\)\} .*; got list"),
    ({0: (VERTICES,)}, r"layers\[0\] must be \(vertices, faces, options\).*; got tuple of 1"),
    ({0: (VERTICES, FACES, None)}, r"layers\[0\] must be \(vertices, faces, options\).*; got options NoneType"),
    ({0: (VERTICES, FACES, {"color": 1})}, r"layers\[0\] options may hold 'rgb' and 'values' only; got \['color'\]"),
    ({"merged0": (VERTICES, FACES, {})}, r"layers keys must be ints .*; got 'merged0'"),
    ({True: (VERTICES, FACES, {})}, r"layers keys must be ints .*; got True"),
    ({0: ("x", FACES, {})}, r"layers\[0\] vertices must be \(V, 3\) coordinates"),
    ({0: ([[1.0, 2.0]], FACES, {})}, r"layers\[0\] vertices must be \(V, 3\) coordinates; got shape \(1, 2\)"),
])
def test_render_layers_names_a_bad_layer(layers, message):
    """A list raised AttributeError ('items'), a short entry ValueError (unpack), options None AttributeError ('get'),
    an unknown option set_mesh's TypeError; a str key "merged0" was named as a merged pass of the same prefix (one
    actor for two layers)."""
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *_grid(20, 0.0, 0.0))
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        with pytest.raises(InvalidInputError, match=message):
            renderer.render_layers("cu", layers)


@needs_render
@pytest.mark.parametrize("call", ["render", "render_layers merge", "render_layers crop"])
def test_layered_renderer_names_a_bad_flag(call):
    """reuse="no", merge="no", crop="no" are true to Python: the option was switched on without a word."""
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *_grid(20, 0.0, 0.0))
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        name = call.split()[-1] if " " in call else "reuse"
        with pytest.raises(InvalidInputError, match=rf"{name} must be True or False; got 'no'"):
            if call == "render":
                renderer.render(["overview"], reuse="no")
            else:
                renderer.render_layers("cu", {0: (*_grid(3, 1.0, 2.0), {})}, **{name: "no"})


@needs_render
def test_layered_renderer_screen_rect_and_bounds_of_name_bad_input():
    """screen_rect("x") raised numpy's ValueError, bounds_of an unknown name a bare KeyError."""
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *_grid(20, 0.0, 0.0))
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        with pytest.raises(InvalidInputError, match=r"vertices must be \(N, 3\) world points"):
            renderer.screen_rect("x")
        with pytest.raises(InvalidInputError, match=r"no layer named 'zz'; have \['overview'\]"):
            renderer.bounds_of("zz")
        with pytest.raises(InvalidInputError, match=r"no layer named \['overview'\]; have \['overview'\]"):
            renderer.bounds_of(["overview"])
        assert renderer.screen_rect(_grid(3, 1.0, 2.0)[0]) is not None
        np.testing.assert_array_equal(renderer.bounds_of("overview"), [[0, 0, 0], [19, 19, 0]])


@needs_render
def test_reused_passes_of_earlier_views_and_many_rects_are_not_kept():
    """render(reuse=True) kept every pass it read under its layers and rect, whatever the view: a loop moving the
    camera with a crop following a mesh kept each frame's images (50 frames of a 320 x 240 window: 50 passes, 4.9 MB),
    though a pass of an earlier view can never be reused (the view's version only grows). Now the passes of other
    views go, and at most a few of the current view's are kept; a still view's pass is reused as before."""
    vertices, faces = _grid(20, 0.0, 1.0)
    with render.LayeredRenderer(window_size=(320, 240)) as renderer:
        renderer.set_mesh("a", vertices, faces)
        for n in range(50):
            renderer.set_view((30.0 + n, TOP), [[0, 0, 0], [20, 20, 1]])
            rect = renderer.screen_rect(vertices[:60] + [n * 0.1, 0, 0])
            renderer.render(["a"], reuse=True, rect=rect)
        assert len(renderer._passes) == 1
        for c0 in range(40):  # a still view, crops of many places
            renderer.render(["a"], reuse=True, rect=(c0, 0, c0 + 100, 100))
        assert len(renderer._passes) <= render._REUSED_PASSES
        color, depth = renderer.render(["a"], reuse=True)
        again, again_depth = renderer.render(["a"], reuse=True)
        assert np.shares_memory(again, color)  # the kept images, not a new pass
        fresh, fresh_depth = renderer.render(["a"])
        np.testing.assert_array_equal(again, fresh)
        np.testing.assert_array_equal(again_depth, fresh_depth)


@needs_render
def test_render_layers_merges_layers_given_as_flat_vertex_arrays():
    """Vertices as a flat (3V,) array (taken by set_mesh) counted 3V vertices in a merged pass: the second layer's
    faces were shifted past the joined vertices (or numpy's ValueError joining a flat array to (V, 3) rows)."""
    near, far = _grid(3, 1.0, 2.0), _grid(3, 12.0, 2.0)
    with render.LayeredRenderer(window_size=(64, 48)) as renderer:
        renderer.set_mesh("overview", *_grid(20, 0.0, 0.0))
        renderer.set_view((30.0, TOP), [[0, 0, 0], [20, 20, 5]])
        rows = renderer.render_layers("cu", {0: (*near, {}), 1: (*far, {})})
        assert any(name.startswith("cu:merged") for name in renderer._actors)  # one pass for both
        flat = renderer.render_layers("cu", {0: (near[0].ravel(), near[1], {}), 1: (far[0].ravel(), far[1], {})})
    for k in (0, 1):
        np.testing.assert_array_equal(flat[k][0], rows[k][0])
        np.testing.assert_array_equal(flat[k][1], rows[k][1])


@needs_render
def test_height_colours_span_the_drawn_part_not_vertices_no_face_uses():
    """scalars='height' took its colormap's range from every vertex: a mesh cut down to a part with update_faces (which
    keeps every vertex) drew the part in a sliver of the colours, as the whole terrain's range stretched them (the
    framing already left such vertices out)."""
    mesh = st.stepped(st.sample_dem().coarsen(8), interval=100.0)
    centre = mesh.triangles_center
    low = centre[:, 2] < np.percentile(centre[:, 2], 30)  # the lowest 30 % of the faces: part of the height range
    part = mesh.copy()
    part.update_faces(low)
    assert len(part.vertices) == len(mesh.vertices)  # the unused vertices are kept
    alone = part.copy()
    alone.remove_unreferenced_vertices()
    kwargs = {"window_size": (96, 64), "scalars": "height", "camera": "top"}
    image, reference = (render.render_mesh(m, **kwargs).astype(int) for m in (part, alone))
    # renumbered vertices move a few edge pixels' rasterisation by a level or so; the stretched range moved a fifth of
    # the picture by up to 220 levels
    assert np.abs(image - reference).max() <= 8


@needs_render
def test_a_fitted_camera_that_shows_the_surface_under_a_pixel_is_refused_not_blank():
    """The visibility check measured the framed box's corners, not the surface drawn within it: the embedded DEM seen
    11 degrees up in an 8 x 500 window spans 0.94 pixels (its box 1.5) and rendered blank, without a word."""
    mesh = st.stepped(st.sample_dem().coarsen(8), interval=100.0)
    with pytest.raises(InvalidInputError, match=r"the mesh would render 7.5 x 0.9\d? pixels: .* too thin to see"):
        render.render_mesh(mesh, window_size=(8, 500), camera=(0.3, 0.2))
    # twice as wide, it spans 1.9 pixels and is drawn
    image = render.render_mesh(mesh, window_size=(16, 500), camera=(0.3, 0.2))
    assert (image != 255).any(axis=-1).sum() > 0


@pytest.mark.parametrize("camera", [(190.0, 45.0), (0.0, 3.0), (0.0, -1.6), [0.5, 1e9]])
def test_a_camera_elevation_beyond_a_quarter_turn_is_named_not_clipped_to_the_top_view(camera):
    """An (azimuth, elevation) pair's elevation beyond ±π/2 radians was clipped to ±89.9 degrees: camera=(190, 45),
    degrees given for radians, rendered the view straight down without a word (the CLI's --camera refuses an EL beyond
    ±90 degrees). It is named, before anything renders."""
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    with pytest.raises(InvalidInputError, match=r"camera's elevation must lie in \[-π/2, π/2\] radians.*; got "):
        render.render_mesh(mesh, window_size=(32, 32), camera=camera)


@needs_render
def test_a_camera_elevation_of_exactly_a_quarter_turn_still_looks_straight_down():
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)
    for elevation in (np.pi / 2, -np.pi / 2):
        image = render.render_mesh(mesh, window_size=(32, 32), camera=(np.pi, elevation))
        assert (image != 255).any()


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_float32_quarter_turn_elevation_is_the_view_straight_down_not_refused(sign):
    """π/2 in float32 (np.float32(np.pi / 2), np.radians(np.float32(90)), a float32 camera array) is 4e-8 above
    float64's π/2: the check for degrees given for radians refused it ("elevation 1.5708", which reads as π/2) where
    float64's π/2 looks straight down (up, for -π/2). It frames the mesh as float64's quarter turn does."""
    corners = np.array([[-1.0, -2.0, -0.5], [1.0, 2.0, 0.5]])
    expected = render._camera_position((np.pi, sign * np.pi / 2), corners, 1.5)
    for elevation in (np.float32(sign * np.pi / 2), np.radians(np.float32(sign * 90.0))):
        assert render._camera_position((np.pi, elevation), corners, 1.5) == expected
    assert render._camera_position(np.array([np.pi, sign * np.pi / 2], np.float32), corners, 1.5) == \
        render._camera_position((float(np.float32(np.pi)), sign * np.pi / 2), corners, 1.5)
    # the next float32 beyond is a camera past the vertical: refused
    beyond = np.nextafter(np.float32(sign * np.pi / 2), np.float32(sign * np.inf))
    with pytest.raises(InvalidInputError, match=r"camera's elevation must lie in \[-π/2, π/2\] radians"):
        render._camera_position((np.pi, beyond), corners, 1.5)


def test_an_explicit_camera_that_sees_none_of_the_mesh_is_named_not_rendered_blank():
    """An explicit camera position is taken in the mesh's coordinates less the centre of the framed box: one given in
    the mesh's own (UTM) coordinates, or looking away from it, rendered a blank image without a word. It is named,
    with the centre to take off where that makes it see the mesh; one that sees the mesh still renders."""
    mesh = st.stepped(st.sample_dem(), interval=200.0)
    centre = mesh.bounds.mean(axis=0)
    world = [tuple((centre + [0.0, -30000.0, 20000.0]).tolist()), tuple(centre.tolist()), (0.0, 0.0, 1.0)]
    with pytest.raises(InvalidInputError, match=r"camera \[\(eye\), \(focal point\), \(view up\)\] sees none of the "
                                                r"mesh .*it looks given in the mesh's own coordinates: less \(394268"):
        render.render_mesh(mesh, window_size=(32, 24), camera=world)
    away = [(0.0, -30000.0, 20000.0), (0.0, -60000.0, 30000.0), (0.0, 0.0, 1.0)]
    with pytest.raises(InvalidInputError, match=r"sees none of the mesh .*; got \[\(0\.0, -30000\.0"):
        render.render_mesh(mesh, window_size=(32, 24), camera=away)
    # with bounds, the vertices drawn decide: a box east of the mesh, looked at from its own east side, away from it
    lo, hi = mesh.bounds
    east = [lo + [1e5, 0.0, 0.0], hi + [1e5, 0.0, 0.0]]
    with pytest.raises(InvalidInputError, match=r"sees none of the mesh"):
        render.render_mesh(mesh, window_size=(32, 24), bounds=east, camera=[(1e4, 0, 0), (2e4, 0, 0), (0, 0, 1)])
    textured = trimesh.Trimesh(VERTICES, FACES, process=False, visual=trimesh.visual.TextureVisuals(
        uv=VERTICES[:, :2] / 10.0, image=Image.fromarray(np.full((4, 4, 3), 200, np.uint8))))
    with pytest.raises(InvalidInputError, match=r"sees none of the mesh"):
        render.render_textured_mesh(textured, window_size=(32, 24), camera=[(0, -20, 20), (0, -40, 30), (0, 0, 1)])


@needs_render
def test_an_explicit_camera_that_sees_part_of_the_mesh_still_renders():
    mesh = trimesh.Trimesh(VERTICES, FACES, process=False)  # local box x, y in [-5, 5], z in [-2.5, 2.5]
    inside = [(0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)]  # the eye within the box, looking along it
    edge = [(0.0, -20.0, 0.0), (30.0, 0.0, 0.0), (0.0, 0.0, 1.0)]  # the mesh at the left edge of a wide view
    for camera in (inside, edge):
        assert (render.render_mesh(mesh, window_size=(32, 32), camera=camera, view_angle=90.0) != 255).any()


@pytest.mark.parametrize(("levels", "got"), [([1.0, np.nan], "got nan at face 1"), ([np.inf, 2.0], "got inf at face 0"),
                                             ([2.0, 1e39], r"got 1e\+39 at face 1"), (["a", "b"], "got <U1 values"),
                                             ([1.0], r"got shape \(1,\)"),
                                             ([1, 10**400], "got object values")])  # OverflowError came out
def test_level_scalars_that_are_not_finite_are_named_not_reported_as_their_shape(levels, got):
    """render_mesh(scalars='level') refused a NaN level (or an infinite one, or one beyond float32) by the levels'
    shape alone, "got (2,)" for a mesh of two faces: the right shape, so nothing said what was wrong. Strings the
    same. The message names the value and its face, or the dtype, or the wrong shape."""
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False)
    mesh.face_attributes["level"] = np.asarray(levels)
    with pytest.raises(InvalidInputError, match=r"face_attributes\['level'\] must hold one finite number per face "
                                                rf"\(2\); {got}$"):
        render.render_mesh(mesh, scalars="level", window_size=(16, 16))


@needs_render
def test_a_mesh_of_degenerate_faces_is_refused_not_rendered_blank():
    """A mesh whose faces all have no area (corners on one line, or repeated: a profile line saved as triangles)
    has a box of some size, so it passed every check and rendered a blank picture without a word: VTK rasterises
    none of its faces. It is refused by name now; one face of some area among them renders, and shows."""
    line = np.array([[0.0, 0.0, 0.0], [50.0, 20.0, 3.0], [100.0, 40.0, 6.0], [30.0, 80.0, 1.0]])
    degenerate = trimesh.Trimesh(line, [[0, 1, 2], [0, 0, 3], [3, 3, 3]], process=False)
    for camera in ("oblique", "top", (0.3, 0.2)):
        with pytest.raises(InvalidInputError, match=r"mesh has no face of some area: every one of its 3 faces is "
                                                    r"degenerate .* renders blank"):
            render.render_mesh(degenerate, window_size=(32, 24), camera=camera)
    shown = trimesh.Trimesh(line, [[0, 1, 2], [0, 0, 3], [0, 1, 3]], process=False)
    image = render.render_mesh(shown, window_size=(32, 24))
    assert (image != 255).any(axis=2).sum() > 20


def test_the_degenerate_faces_check_takes_the_framed_box_span_not_a_pass_over_the_vertices(monkeypatch):
    """The check that some face has an area took the extent of the vertices drawn by a masked min/max over all of
    them, 50 ms a million vertices (0.17 s for a 3.4M-vertex stepped mesh) on every render, where it stops at the
    first chunk of faces. Without bounds the framed box is that extent (z scaled, loose and NaN vertices left out):
    it is passed in, equal to the extent a pass would find; with bounds, the one pass _frame_mesh makes over them."""
    seen = []
    check = render._check_some_area
    monkeypatch.setattr(render, "_check_some_area", lambda *a: seen.append(a) or check(*a))
    vertices = np.array([[5.0, 1.0, 2.0], [9.0, 4.0, 3.0], [6.0, 7.0, 10.0], [1e6, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    mesh = trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 4]], process=False)
    render._frame_mesh(mesh, (32, 24), 2.5, None, "oblique")
    local, _, finite, _, span = seen[-1]
    assert span is not None
    expected = np.array([9.0 - 5.0, 7.0 - 1.0, 2.5 * (10.0 - 2.0)])
    np.testing.assert_allclose(span, expected, rtol=1e-12)
    np.testing.assert_allclose(np.nanmax(local[finite], axis=0) - np.nanmin(local[finite], axis=0), expected)
    render._frame_mesh(mesh, (32, 24), 2.5, [[0.0, 0.0, 0.0], [20.0, 20.0, 20.0]], "oblique")
    np.testing.assert_array_equal(seen[-1][4], expected)


def test_ragged_level_scalars_are_refused_by_name_not_numpys_valueerror():
    """face_attributes is a dict: a ragged list of levels stays a list. render_mesh(scalars='level') refused it with
    numpy's ValueError ("inhomogeneous shape"), raised again while naming what was wrong (the levels' dtype)."""
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False)
    mesh.face_attributes["level"] = [[1.0], [2.0, 3.0]]
    with pytest.raises(InvalidInputError, match=r"face_attributes\['level'\] must hold one finite number per face "
                                                r"\(2\); got a ragged list$"):
        render.render_mesh(mesh, scalars="level", window_size=(16, 16))


@pytest.mark.parametrize("camera", ["oblique", [(30.0, -40.0, 50.0), (5.0, 4.0, 6.0), (0.0, 0.0, 1.0)]],
                         ids=["fitted", "position"])
def test_frame_mesh_with_bounds_finds_the_drawn_box_once(monkeypatch, camera):
    """With explicit bounds and a camera position, _frame_mesh took the box of the vertices drawn twice, two masked
    min/max passes over every vertex: once for the in-view check, again inside _check_some_area. One pass now, its
    extent handed to the area check; what it returns is the same, bit for bit."""
    vertices = np.array([[5.0, 1.0, 2.0], [9.0, 4.0, 3.0], [6.0, 7.0, 10.0], [1e6, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    mesh = trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 4]], process=False)
    bounds = [[0.0, 0.0, 0.0], [20.0, 20.0, 20.0]]
    before = render._frame_mesh(mesh, (32, 24), 2.5, bounds, camera)
    passes = []
    np_min = np.min

    def counting_min(a, *args, **kwargs):
        if "where" in kwargs and np.shape(a) == vertices.shape:
            passes.append(kwargs["where"].shape)
        return np_min(a, *args, **kwargs)

    monkeypatch.setattr(np, "min", counting_min)
    after = render._frame_mesh(mesh, (32, 24), 2.5, bounds, camera)
    assert len(passes) == 1
    for a, b in zip(before, after, strict=True):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    span = np.nanmax(after[3][after[4]], axis=0) - np.nanmin(after[3][after[4]], axis=0)
    np.testing.assert_array_equal(span, [9.0 - 5.0, 7.0 - 1.0, 2.5 * (10.0 - 2.0)])


def _grey_drape(mesh: trimesh.Trimesh, grey: int) -> trimesh.Trimesh:
    """``mesh`` with a texture of one grey, its UVs spread over the mesh's xy extent."""
    xy = mesh.vertices[:, :2]
    uv = (xy - xy.min(axis=0)) / np.ptp(xy, axis=0)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.new("RGB", (8, 8), (grey, grey, grey)))
    return mesh


@needs_render
def test_relief_lighting_keeps_a_level_face_in_its_texture_colour():
    """docs/texture.png's draped view was darker than the texture beside it (0.76 of its mean brightness): the
    texture carries a hillshade, and lighting=True shaded it again, a level terrace at 0.87 of its colour (ambient
    0.2 + diffuse 0.9 x the key and fill lights' 0.74 on a level face) and walls facing the camera at 0.55.
    ``lighting="relief"`` takes the same lights with the ambient raised so that a level face is its texture's
    colour: the steps still read (walls apart from terraces), no darker overall."""
    grey = 180
    level = _grey_drape(trimesh.Trimesh([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], [[0, 1, 2], [0, 2, 3]],
                                        process=False), grey)
    shots = {lighting: render.render_textured_mesh(level, window_size=(64, 48), lighting=lighting)
             for lighting in (True, "relief", False)}
    seen = (shots[False] != 255).any(axis=2)
    assert seen.mean() > 0.3
    assert np.abs(shots["relief"][seen].astype(int) - grey).max() <= 1  # the texture's colour, as unlit
    assert np.abs(shots[True][seen].astype(int) - round(0.866 * grey)).max() <= 2  # lit: darker

    x, y = np.meshgrid(np.arange(12.0), np.arange(12.0))
    steps = _grey_drape(st.stepped(st.heightfield_mesh(np.floor(x / 3) + np.floor(y / 4)), interval=1.0), grey)
    view = (math.radians(200), math.radians(35))
    relief = render.render_textured_mesh(steps, window_size=(96, 72), lighting="relief", camera=view)
    lit = render.render_textured_mesh(steps, window_size=(96, 72), lighting=True, camera=view)
    mesh = (relief != 255).any(axis=2)
    levels = np.unique(relief[mesh].mean(axis=1).round())
    assert grey in levels and len(levels) >= 3  # terraces in the texture's grey, walls in other greys
    assert relief[mesh].mean() > lit[mesh].mean() + 0.1 * grey
    assert (relief[mesh].astype(int) >= lit[mesh].astype(int)).all()  # every face lighter than lit fully


@pytest.mark.parametrize("lighting", ["on", "flat", 1, None])
def test_render_textured_mesh_refuses_a_lighting_it_does_not_know(lighting):
    level = _grey_drape(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 2]], process=False), 100)
    with pytest.raises(InvalidInputError, match=r"lighting must be True, False or 'relief'; got "):
        render.render_textured_mesh(level, window_size=(16, 16), lighting=lighting)
