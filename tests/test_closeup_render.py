"""Close-up renders (paper 001 §IV): layered passes and compositing, image regression, animation, CLI, examples."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import numpy as np
import pytest

import stepterrain.cli as cli
from stepterrain import render
from stepterrain.closeup import (
    ROI,
    AnchorStyle,
    CloseUp,
    animate_closeups,
    render_closeups,
    save_animation,
)
from stepterrain.errors import InvalidInputError, MissingDependencyError, OutputTooLargeError
from stepterrain.terrain import Terrain

from .test_closeup import hills

AVAILABLE, REASON = render.offscreen_available()
IMAGES = Path(__file__).resolve().parent / "image_cache"
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SIZE = (160, 120)


def terrain() -> Terrain:
    return Terrain.from_heights(hills(), spacing=(2.0, 2.0), origin=(1000.0, 2000.0))


def red_pixels(image: np.ndarray) -> np.ndarray:
    rgb = image.astype(int)
    return (rgb[..., 0] > 150) & (rgb[..., 1] < 90) & (rgb[..., 2] < 90)


def one(**kwargs) -> CloseUp:
    base = dict(scale=1.5, offset=(0.0, 0.0, 60.0), color="red")
    base.update(kwargs)
    return CloseUp(ROI.circle((1040.0, 2030.0), 12.0), **base)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_no_closeups_composite_equals_the_overview_render():
    t = terrain()
    mesh = t.mesh()
    composite = render_closeups(t, [], window_size=SIZE, scalars=None, device="cpu")
    plain = render.render_mesh(mesh, window_size=SIZE, bounds=mesh.bounds)
    assert composite.shape == plain.shape == (SIZE[1], SIZE[0], 3)
    assert np.abs(composite.astype(int) - plain.astype(int)).max() <= 1


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_closeup_and_anchor_appear_in_the_closeup_color():
    t = terrain()
    active = render_closeups(t, [one(anchor=AnchorStyle("opaque"))], window_size=SIZE, device="cpu")
    assert red_pixels(active).sum() > 100, "the opaque red anchor is missing"
    hidden = render_closeups(t, [one(anchor=AnchorStyle("opaque", inactive="hidden"), active=False)],
                             window_size=SIZE, device="cpu")
    gray = render_closeups(t, [one(anchor=AnchorStyle("opaque", inactive="gray"), active=False)], window_size=SIZE,
                           device="cpu")
    faint = render_closeups(t, [one(anchor=AnchorStyle("opaque", inactive="faint"), active=False)],
                            window_size=SIZE, device="cpu")
    assert red_pixels(hidden).sum() == 0 and red_pixels(gray).sum() == 0
    assert 0 <= red_pixels(faint).sum() < red_pixels(active).sum()
    assert np.abs(hidden.astype(int) - gray.astype(int)).sum() > 0  # the gray anchor is drawn
    band = render_closeups(t, [one(anchor=AnchorStyle("opaque", band=True))], window_size=SIZE, device="cpu")
    assert red_pixels(band).sum() > 100, "the paper's SPFR anchor (soft-edge faces) is missing"
    none = render_closeups(t, [one(anchor=AnchorStyle("hidden"))], window_size=SIZE, device="cpu")
    assert red_pixels(none).sum() == 0
    # the close-up content itself: more non-background pixels than without it
    plain = render_closeups(t, [], window_size=SIZE, device="cpu", bounds=[(1000, 2000, 0), (1080, 2064, 160)])
    shown = render_closeups(t, [one(anchor=AnchorStyle("hidden"))], window_size=SIZE, device="cpu",
                            bounds=[(1000, 2000, 0), (1080, 2064, 160)])
    assert ((shown < 250).any(axis=2).sum()) > ((plain < 250).any(axis=2).sum()) + 50


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_billboard_and_mpfr_closeups_render():
    t = terrain()
    board = render_closeups(t, [one(view="billboard", scalars="slope", anchor=AnchorStyle("hidden"))],
                            window_size=SIZE, device="cpu")
    plain = render_closeups(t, [one(anchor=AnchorStyle("hidden"), scale=1e-3)], window_size=SIZE, device="cpu")
    assert np.abs(board.astype(int) - plain.astype(int)).sum() > 0
    stepped = render_closeups(t, [one(stepped=5.0)], window_size=SIZE, device="cpu")
    assert stepped.std() > 5
    # an aerial texture on the close-up only (MPFR): a pure green image shows up as green pixels
    green = np.zeros((8, 8, 3), np.uint8)
    green[..., 1] = 255
    textured = render_closeups(t, [one(texture=green, anchor=AnchorStyle("hidden"))], window_size=SIZE,
                               scalars=None, device="cpu")
    rgb = textured.astype(int)
    assert ((rgb[..., 1] > 100) & (rgb[..., 0] < 60) & (rgb[..., 2] < 60)).sum() > 50
    with pytest.raises(InvalidInputError, match="texture"):
        one(texture=np.zeros((4, 4), np.uint8))


# ------------------------------------------------------------------------------------------------ regression
REGRESSION = {
    "closeup_circle": lambda: [one()],
    "closeup_two_mappings": lambda: [
        one(stepped=5.0, color="#1f77b4", anchor=AnchorStyle("ends")),
        CloseUp(ROI.rounded_rectangle((1060.0, 2040.0), (20.0, 14.0)), scale=1.2, offset=(5.0, 0.0, 50.0),
                rotation=(0.3, 0.4), scalars="slope", color="#2ca02c"),
    ],
}


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("name", sorted(REGRESSION))
def test_image_regression(name):
    from PIL import Image

    image = render_closeups(terrain(), REGRESSION[name](), window_size=SIZE, camera="oblique", device="cpu")
    path = IMAGES / f"{name}.png"
    if os.environ.get("STEPTERRAIN_UPDATE_IMAGES") or not path.exists():
        render.save_png(image, path)
        pytest.skip(f"reference image {path.name} written; re-run to compare")
    with Image.open(path) as ref:
        expected = np.asarray(ref.convert("RGB")).astype(int)
    diff = np.abs(image.astype(int) - expected)
    assert diff.mean() < 2.0, f"mean difference {diff.mean():.2f} against {path.name}"
    assert (diff.max(axis=2) > 60).mean() < 0.01, "more than 1% of the pixels changed a lot"


# ------------------------------------------------------------------------------------------------ animation
@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_spinning_closeup_animates_and_saves(tmp_path):
    import imageio.v3 as iio

    frames = animate_closeups(terrain(), [one(spin=(0.5, 1), rotation=(0.4, 0.0))], frames=3, fps=2.0,
                              window_size=SIZE, device="cpu")
    assert len(frames) == 3 and frames[0].shape == (SIZE[1], SIZE[0], 3)
    assert np.abs(frames[0].astype(int) - frames[1].astype(int)).sum() > 0, "the close-up did not turn"
    gif = save_animation(frames, tmp_path / "spin.gif", fps=2.0)
    assert iio.imread(gif, index=None).shape[0] == 3
    with pytest.raises(InvalidInputError, match=".gif or .mp4"):
        save_animation(frames, tmp_path / "spin.avi")
    if importlib.util.find_spec("imageio_ffmpeg") is None:
        with pytest.raises(MissingDependencyError, match="imageio-ffmpeg"):
            save_animation(frames, tmp_path / "spin.mp4")
    else:  # the MP4 must read back (the temporary file's suffix must not decide the container)
        mp4 = save_animation(frames, tmp_path / "spin.mp4", fps=2.0)
        video = iio.imread(mp4, index=None, plugin="FFMPEG")
        assert video.shape[0] == 3 and video.shape[1:3] == (SIZE[1], SIZE[0])
        assert sorted(p.name for p in tmp_path.iterdir()) == ["spin.gif", "spin.mp4"]


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_reused_renderer_and_overview_pass_give_the_same_image():
    t = terrain()
    box = [(1000, 2000, 0), (1080, 2064, 160)]
    fresh = render_closeups(t, [one()], window_size=SIZE, bounds=box, device="cpu")
    with render.LayeredRenderer(window_size=SIZE) as renderer:
        first = render_closeups(t, [one()], window_size=SIZE, bounds=box, renderer=renderer, reuse_overview=True,
                                device="cpu")
        second = render_closeups(t, [one(rotation=(0.0, 0.5))], window_size=SIZE, bounds=box, renderer=renderer,
                                 reuse_overview=True, device="cpu")
        third = render_closeups(t, [one()], window_size=SIZE, bounds=box, renderer=renderer, reuse_overview=True,
                                device="cpu")
    np.testing.assert_array_equal(first, fresh)
    np.testing.assert_array_equal(third, fresh)
    assert np.abs(second.astype(int) - fresh.astype(int)).sum() > 0


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_merged_passes_equal_one_pass_per_layer():
    t = terrain()
    cus = [CloseUp(ROI.circle((1008.0 + 24 * k, 2030.0), 6.0), scale=1.2, offset=(0.0, 0.0, 30.0),
                   anchor=AnchorStyle(style), scalars="slope" if k == 1 else None)
           for k, style in enumerate(["opaque", "ends", "linear"])]
    box = [(1000, 2000, 0), (1080, 2064, 120)]
    separate = render_closeups(t, cus, window_size=(320, 200), bounds=box, merge_passes=False, device="cpu")
    with render.LayeredRenderer(window_size=(320, 200)) as renderer:
        merged = render_closeups(t, cus, window_size=(320, 200), bounds=box, renderer=renderer, device="cpu")
        names = set(renderer._actors)
    assert any("merged" in name for name in names), f"nothing was merged: {sorted(names)}"
    diff = np.abs(merged.astype(int) - separate.astype(int))
    # VTK shifts each vertex buffer by its own bounds before float32: a merged mesh rounds a hair differently
    assert diff.max() <= 3 and (diff.max(axis=2) > 0).mean() < 1e-3


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_reused_closeup_geometry_gives_the_same_frames():
    """Frames that keep the previous frame's close-up geometry (same CloseUp objects, same M) equal frames
    that transform again; a spinning close-up at another time is transformed again."""
    t = terrain()
    box = [(1000, 2000, 0), (1080, 2064, 160)]
    still = one()
    spinning = one(spin=(0.25, 10))
    with render.LayeredRenderer(window_size=SIZE) as renderer:
        frames = {}
        for reuse in (False, True, True):
            for time in (0.0, 1.0):
                timings = {}
                image = render_closeups(t, [still, spinning], window_size=SIZE, bounds=box, renderer=renderer,
                                        time=time, reuse_closeups=reuse, timings=timings, device="cpu")
                frames.setdefault(time, []).append(image)
    for images in frames.values():
        for image in images[1:]:
            np.testing.assert_array_equal(image, images[0])
    assert np.abs(frames[0.0][0].astype(int) - frames[1.0][0].astype(int)).sum() > 0


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("where", ["overview", "closeup"])
def test_reused_closeup_geometry_samples_a_texture_changed_in_place(where):
    """An image changed in place between two frames of the same close-ups (the same array object) shows its new
    colors on the close-up, as a copy of it does: the kept close-up geometry does not keep the old colors."""
    t = terrain()
    image = np.zeros((16, 16, 3), np.uint8)
    image[..., 0] = 255  # red
    cu = one(texture=image) if where == "closeup" else one()
    options = dict(window_size=SIZE, scalars=None, device="cpu")
    if where == "overview":
        options["texture"] = image
    render_closeups(t, [cu], **options)
    image[..., 0], image[..., 2] = 0, 255  # blue, in place (a CloseUp keeps its own copy; the overview's is this)
    again = render_closeups(t, [cu], **options)
    fresh = render_closeups(t, [cu], reuse_closeups=False, **options)
    np.testing.assert_array_equal(again, fresh)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_boxed_read_backs_equal_the_full_window_pass():
    """A pass read back in a pixel box is that box of the full-window pass, bit for bit; layers cut to their
    screen boxes (crop) are the boxes of the full-window layers, which hold nothing outside them."""
    t = terrain()
    cus = [CloseUp(ROI.circle((1008.0 + 24 * k, 2030.0), 6.0), scale=1.2, offset=(0.0, 0.0, 30.0))
           for k in range(3)]
    from stepterrain.closeup import closeup_layers

    layers = closeup_layers(t, cus, device="cpu")
    box = [(1000, 2000, 0), (1080, 2064, 120)]
    with render.LayeredRenderer(window_size=(320, 200)) as renderer:
        mesh = t.mesh()
        renderer.set_mesh("overview", mesh.vertices, mesh.faces)
        renderer.set_view("oblique", box)
        color, depth = renderer.render(["overview"])
        for rect in [(0, 0, 320, 200), (17, 30, 250, 141), (5, 7, 5, 20)]:
            c0, r0, c1, r1 = rect
            part_color, part_depth = renderer.render(["overview"], rect=rect)
            np.testing.assert_array_equal(part_color, color[r0:r1, c0:c1])
            np.testing.assert_array_equal(part_depth, depth[r0:r1, c0:c1])
        with pytest.raises(InvalidInputError, match="rect"):
            renderer.render(["overview"], rect=(0, 0, 321, 10))
        for merge in (False, True):
            spec = {k: (layer.vertices, layer.faces, {"values": layer.mask_factor}) for k, layer in enumerate(layers)}
            full = renderer.render_layers("f", spec, merge=merge)
            cut = renderer.render_layers("c", spec, merge=merge, crop=True)
            assert full.keys() == cut.keys() == {0, 1, 2}
            for k, (cut_color, cut_depth, (c0, r0, c1, r1)) in cut.items():
                full_color, full_depth = full[k]
                np.testing.assert_array_equal(cut_color, full_color[r0:r1, c0:c1])
                np.testing.assert_array_equal(cut_depth, full_depth[r0:r1, c0:c1])
                outside = np.ones(full_depth.shape, bool)
                outside[r0:r1, c0:c1] = False
                assert np.isinf(full_depth[outside]).all() and np.isfinite(cut_depth).any()


def test_too_many_closeups_for_the_window():
    cus = [one()] * 3
    with pytest.raises(InvalidInputError, match="too many close-ups"):
        render_closeups(terrain(), cus, window_size=(128, 64), device="cpu")


@pytest.mark.parametrize(
    ("bounds", "match"),
    [
        ([("1000", "2000", "0"), ("1080", "2064", "160")], r"got dtype <U4"),  # framed as numbers before
        ([[False] * 3, [True] * 3], r"got dtype bool"),  # a box from 0 to 1 before
        ("abc", r"got dtype <U3"),  # numpy's "could not convert string to float" after the close-ups were culled
        ([(1000, 2000, 0), (1080, 2064)], r"got rows of different lengths"),  # numpy's "inhomogeneous shape"
        ([1000, 2000, 0], r"; got \[1000, 2000, 0\]"),  # named only after the transform before
    ],
)
def test_render_closeups_refuses_bounds_that_are_not_a_box_of_numbers(bounds, match):
    with pytest.raises(InvalidInputError, match=r"bounds must be \[\(xmin, ymin, zmin\), \(xmax, ymax, zmax\)\] "
                                                 r"with max >= min.*" + match):
        render_closeups(terrain(), [one()], window_size=SIZE, bounds=bounds, device="cpu")


# ------------------------------------------------------------------------------------------------ CLI
@pytest.fixture
def dem(tmp_path) -> Path:
    path = tmp_path / "dem.npy"
    np.save(path, hills())
    return path


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_closeup_writes_png_and_gif(dem, tmp_path, capsys):
    from PIL import Image

    out = tmp_path / "out" / "closeup.png"
    gif = tmp_path / "out" / "spin.gif"
    argv = ["closeup", str(dem), "--roi-relative", "0.3,0.5,0.2", "--roi", "30,-16,6", "--scale", "1.5",
            "--offset", "0,0,40", "--stepped", "5", "--stepped", "0", "--size", "160x120", "-o", str(out),
            "--gif", str(gif), "--frames", "2", "--device", "cpu"]
    assert cli.main(argv) == 0
    with Image.open(out) as image:
        assert image.size == (160, 120)
    assert gif.exists()
    assert "rendering 2 close-ups" in capsys.readouterr().err


def test_cli_closeup_writes_a_scene_mesh(dem, tmp_path):
    import trimesh

    out = tmp_path / "scene.ply"
    assert cli.main(["closeup", str(dem), "--roi-relative", "0.5,0.5,0.2", "--offset", "0,0,40", "-o", str(out),
                     "--device", "cpu"]) == 0
    scene = trimesh.load(out, process=False)
    assert len(scene.faces) > 2 * 32 * 40  # the overview and more
    assert scene.visual.vertex_colors.shape[0] == len(scene.vertices)


def test_cli_closeup_bad_input_exits_2(dem, tmp_path, capsys):
    out = str(tmp_path / "x.ply")  # a mesh output: the argument errors show where no renderer exists too
    assert cli.main(["closeup", str(dem), "--roi", "9999,9999,5", "-o", out]) == 2
    assert "outside the terrain" in capsys.readouterr().err
    assert cli.main(["closeup", str(dem), "--scale", "0", "-o", out]) == 2
    assert "scale must be positive" in capsys.readouterr().err
    assert cli.main(["closeup", str(dem), "-o", str(tmp_path / "x.jpg")]) == 2
    assert cli.main(["closeup", str(dem), "--roi", "1,2", "-o", out]) == 2
    assert cli.main(["closeup", str(dem), "--roi", "5,5,2", "--roi", "9,9,2", "--offset", "0,0,1",
                     "--offset", "0,0,2", "--offset", "0,0,3", "-o", out]) == 2
    assert "once per ROI" in capsys.readouterr().err
    png = str(tmp_path / "same.png")
    assert cli.main(["closeup", str(dem), "-o", png, "--png", png]) == 2
    assert "--output and --png name the same file" in capsys.readouterr().err
    for fps in ("0", "nan", "-3"):
        assert cli.main(["closeup", str(dem), f"--fps={fps}", "-o", out]) == 2
        assert capsys.readouterr().err == f"stepterrain closeup: error: --fps must be a positive number; got {fps}\n"
    # a rate the GIF cannot store was an OverflowError traceback (exit 1) after every frame was rendered
    assert cli.main(["closeup", str(dem), "--fps=1e-300", "--gif", str(tmp_path / "spin.gif"), "-o", out]) == 2
    assert capsys.readouterr().err.startswith("stepterrain closeup: error: --fps must lie in [0.001526, 100] frames "
                                              "per second for a GIF")
    assert not (tmp_path / "x.ply").exists()


@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_closeup_a_huge_spin_is_no_overflow(dem, tmp_path, capsys):
    """The spin's repetitions ceil(|spin| * frames / fps) overflowed to inf: an OverflowError traceback, exit 1
    (without --gif too, where --spin is refused now: it does nothing there). A spin of more than half a turn a frame
    is refused now, before any work (1e308 made every frame after the first the same); the largest one taken makes
    the animation. (Two frames: --spin with --frames 1, one frame at time 0 before any turn, is refused as doing
    nothing, see test_cli_truthfulness.py.)"""
    out, gif = tmp_path / "scene.ply", tmp_path / "spin.gif"
    argv = ["-q", "closeup", str(dem), "--roi-relative", "0.5,0.5,0.2", "-o", str(out), "--gif", str(gif),
            "--frames", "2", "--size", "160x120", "--device", "cpu"]
    assert cli.main([*argv, "--spin", "1e308"]) == 2
    err = capsys.readouterr().err
    assert "--spin must be at most half a turn a frame" in err and "Traceback" not in err, err
    assert not out.exists() and not gif.exists()
    assert cli.main([*argv, "--spin", "-6", "--fps", "12"]) == 0, capsys.readouterr().err
    assert out.exists() and gif.exists()


def test_cli_closeup_mp4_without_ffmpeg_is_refused_before_any_output(dem, tmp_path, capsys, monkeypatch):
    """The scene mesh and the PNG were written first, then the animation failed on the missing extra."""
    import sys

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if not installed
    argv = ["-q", "closeup", str(dem), "--roi-relative=0.5,0.5,0.2", "--size", "160x120", "-o",
            str(tmp_path / "scene.ply"), "--png", str(tmp_path / "p.png"), "--gif", str(tmp_path / "spin.mp4")]
    assert cli.main(argv) == 2
    assert "MP4 output needs imageio-ffmpeg: pip install 'stepterrain[video]'" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy"]


@pytest.mark.parametrize("size, rois", [("64x48", 1), ("128x64", 3)])
def test_cli_closeup_too_small_a_size_is_refused_before_any_output(dem, tmp_path, capsys, size, rois):
    """The scene mesh was written, then the render found the window too small for the close-ups: exit 2 with
    one of the two outputs on disk and a message that named no option."""
    argv = ["-q", "closeup", str(dem), *["--roi-relative=0.5,0.5,0.1"] * rois, "--size", size,
            "-o", str(tmp_path / "scene.ply"), "--gif", str(tmp_path / "spin.gif"), "--frames", "1"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stepterrain closeup: error: --size {size} holds at most") and f"got {rois}" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy"]


def test_cli_closeup_a_failing_render_leaves_no_scene_mesh(dem, tmp_path, capsys, monkeypatch):
    import stepterrain.closeup as closeup

    def broken(*args, **kwargs):
        raise MissingDependencyError("no OpenGL here (simulated)")

    monkeypatch.setattr(render, "require_offscreen", lambda: "simulated")
    monkeypatch.setattr(closeup, "render_closeups", broken)
    argv = ["-q", "closeup", str(dem), "-o", str(tmp_path / "scene.ply"), "--png", str(tmp_path / "x.png")]
    assert cli.main(argv) == 2
    assert "simulated" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy"]


@pytest.mark.parametrize("roi", ["--roi=30,-16,1e300", "--roi-relative=0.5,0.5,1e300"])
def test_cli_closeup_an_absurd_roi_radius_is_refused_by_name(dem, tmp_path, capsys, roi):
    """A radius of 1e300 overflowed float32: 'overflow encountered in cast' warnings, then an error about
    non-finite vertices at the write; ROI itself took a size of 2e39. A --roi-relative is named as itself, with
    the fractions typed (it was named as --roi, with the radius in metres)."""
    out = tmp_path / "x.ply"
    assert cli.main(["-q", "closeup", str(dem), roi, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    expected = "--roi radius must lie in (0, 1e+12]; got " if roi.startswith("--roi=") else \
        "--roi-relative 0.5,0.5,1e+300 places a close-up at ("
    assert err.startswith(f"stepterrain closeup: error: {expected}") and "\n" == err[-1], err
    assert len(err.splitlines()) == 1 and not out.exists()
    with pytest.raises(InvalidInputError, match=r"ROI size must be positive \(width, height\) up to 1e\+12"):
        ROI.circle((0.0, 0.0), 1e39)


def test_cli_closeup_colormap_and_stepped_interval_errors_name_the_option(dem, tmp_path, capsys):
    # were "cmap must name a matplotlib colormap" (at render time) and "interval=0.001 over heights ..."
    out = tmp_path / "x.ply"
    assert cli.main(["-q", "closeup", str(dem), "--colormap", "nope", "-o", str(out)]) == 2
    assert capsys.readouterr().err.startswith("stepterrain closeup: error: --colormap must name")
    assert cli.main(["-q", "closeup", str(dem), "--stepped", "1e-6", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepterrain closeup: error: --stepped 1e-06 over heights"), err
    assert "levels" in err
    assert not out.exists()


def test_cli_closeup_help_has_examples(capsys):
    assert cli.main(["closeup", "--help"]) == 0
    text = capsys.readouterr().out
    assert "examples:" in text and "--roi" in text and "--stepped" in text


# ------------------------------------------------------------------------------------------------ examples
def load_example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("name", ["closeup_mappings", "closeup_anchors"])
def test_examples_write_their_pictures(name, tmp_path):
    from PIL import Image

    example = load_example(name)
    assert example.__doc__ and "paper 001" in example.__doc__
    out = tmp_path / f"{name}.png"
    argv = ["--size", "48", "--window", "192", "128", "--output", str(out), "--device", "cpu"]
    if name == "closeup_mappings":
        argv += ["--gif", str(tmp_path / "spin.gif"), "--frames", "2"]
    assert example.main(argv) == 0
    with Image.open(out) as image:
        picture = np.asarray(image)
    assert picture.shape[:2] == (128, 192) and picture.std() > 5
    if name == "closeup_mappings":
        assert (tmp_path / "spin.gif").exists()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_turning_closeups_on_a_kept_renderer_equal_fresh_renders():
    """Frames that re-use the kept cull, colors, joined faces and uploads of earlier frames (a new M each frame)
    equal renders from scratch, pixel for pixel."""
    t = terrain()
    cus = [CloseUp(ROI.circle((1008.0 + 24 * k, 2030.0), 6.0), scale=1.2, offset=(0.0, 0.0, 30.0),
                   spin=(0.1, 5), anchor=AnchorStyle(style, band=k == 1))
           for k, style in enumerate(["opaque", "ends", "linear"])]
    box = [(1000, 2000, 0), (1080, 2064, 120)]
    with render.LayeredRenderer(window_size=(320, 200)) as renderer:
        kept = [render_closeups(t, cus, window_size=(320, 200), bounds=box, renderer=renderer, time=time,
                                reuse_closeups=False, device="cpu") for time in (0.0, 1.5, 3.0, 1.5)]
    for time, image in zip((0.0, 1.5, 3.0, 1.5), kept, strict=True):
        fresh_cus = [CloseUp(ROI.circle(cu.roi.center, 6.0), scale=1.2, offset=(0.0, 0.0, 30.0), spin=(0.1, 5),
                             anchor=cu.anchor) for cu in cus]
        fresh = render_closeups(t, fresh_cus, window_size=(320, 200), bounds=box, time=time, device="cpu")
        np.testing.assert_array_equal(image, fresh)
    assert np.abs(kept[0].astype(int) - kept[1].astype(int)).sum() > 0


@pytest.mark.parametrize(
    ("frames", "match"),
    [
        ([np.full((8, 8, 3), 0.9)] * 2, r"frames\[0\] must be an \(H, W, 3\|4\) uint8 image.*float64"),  # black GIF
        ([np.zeros((8, 8), np.uint8)] * 2, r"frames\[0\] .*shape \(8, 8\)"),  # f[..., :3] kept 3 columns
        ([np.full((8, 8, 3), 300, np.int16)] * 2, r"frames\[0\] .*int16"),  # 300 wrapped to 44
        ([np.zeros((8, 8, 3), np.uint8), np.zeros((9, 8, 3), np.uint8)], "share one size"),  # numpy's stack error
        ([np.zeros((8, 8, 1), np.uint8)] * 2, r"frames\[0\] .*shape \(8, 8, 1\)"),  # PIL's TypeError
        ([np.zeros((0, 8, 3), np.uint8)] * 2, r"frames\[0\] .*shape \(0, 8, 3\)"),  # PIL 'cannot write empty image'
        ([[[1, 2, 3]]], r"frames\[0\] .*got list"),  # TypeError: list indices must be integers
        (None, "frames must be a sequence"),  # len()'s TypeError
        ([], "no frames to write"),
    ],
)
def test_save_animation_checks_its_frames(tmp_path, frames, match):
    with pytest.raises(InvalidInputError, match=match):
        save_animation(frames, tmp_path / "bad.gif")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, fps, match", [
    # Pillow raised OverflowError ("int too big to convert") for a delay past 655.35 s
    ("slow.gif", 1e-9, r"fps must lie in \[0.001526, 100\] frames per second for a GIF .*got 1e-09"),
    # a delay of int(100 / 1000) = 0 hundredths was written: players show the GIF at their own default rate
    ("fast.gif", 1000.0, r"fps must lie in \[0.001526, 100\] frames per second for a GIF .*got 1000"),
    # ffmpeg failed on the rate but the broken (empty) file was renamed onto the target, without an error
    ("slow.mp4", 1e-9, r"fps must lie in \[0.001, 1000\] frames per second for an MP4; got 1e-09"),
])
def test_save_animation_refuses_a_frame_rate_the_format_cannot_store(tmp_path, name, fps, match):
    (tmp_path / name).write_bytes(b"an earlier animation")
    with pytest.raises(InvalidInputError, match=match):
        save_animation([np.zeros((8, 8, 3), np.uint8)] * 2, tmp_path / name, fps=fps)
    assert (tmp_path / name).read_bytes() == b"an earlier animation"
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


@pytest.mark.parametrize("path", [5, b"spin.gif", None])
def test_save_animation_refuses_a_path_that_is_no_path(path):
    with pytest.raises(InvalidInputError, match=r"path must be a str or os.PathLike; got "):  # pathlib's TypeError
        save_animation([np.zeros((8, 8, 3), np.uint8)] * 2, path)


def test_save_animation_takes_a_4d_stack(tmp_path):
    import imageio.v3 as iio

    frames = np.zeros((2, 8, 6, 4), np.uint8)
    frames[..., 3] = 255  # opaque (alpha 0 is kept transparent in a GIF: imageio reads such frames as RGB, then RGBA)
    frames[1] = 200
    frames[1, ..., 3] = 255
    gif = save_animation(frames, tmp_path / "stack.gif", fps=2.0)
    assert iio.imread(gif, index=None).shape[:3] == (2, 8, 6)


def test_animate_closeups_refuses_frames_over_the_memory_budget():
    # every frame is kept in a list: frames=10**7 of 640 x 400 (7 TiB) rendered on until memory ran out, and
    # frames=10**12 died in numpy's arange (MemoryError)
    for frames in (10**7, 10**12):
        with pytest.raises(OutputTooLargeError, match=f"{frames} frames of 640 x 400 pixels"):
            animate_closeups(terrain(), [one()], frames=frames, window_size=(640, 400), device="cpu")


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("offset", ["0,0,1e9", "1e9,0,40"])
def test_cli_closeup_an_absurd_offset_is_refused_with_advice_an_option_follows(dem, tmp_path, capsys, offset):
    """A close-up moved absurdly far (--offset 0,0,1e9 over a 40 x 32 m DEM) is refused before any file is written; the
    advice was the library's "frame what to see with bounds", which no option of closeup gives: it names --offset."""
    argv = ["-q", "closeup", str(dem), "--roi-relative", "0.5,0.5,0.2", "--offset", offset, "--size", "160x120",
            "-o", str(tmp_path / "scene.ply"), "--png", str(tmp_path / "x.png"), "--device", "cpu"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("stepterrain closeup: error: the camera fitted to the overview and its close-ups would show "
                          "the overview ("), err
    assert "bounds" not in err and err.endswith("; move it nearer: give it a smaller --offset\n"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy"]
