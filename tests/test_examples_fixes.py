"""Bugs found by running the examples/ scripts with the arguments a user would try, one test each."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stepterrain.errors import InvalidInputError

from .conftest import needs_render
from .test_examples import EXAMPLES, assert_usage_error_writing_nothing, load_example


def test_batch_tiles_refuses_an_image_name_it_cannot_write_before_writing_tiles(tmp_path, capsys):
    """--output out.jpg stepped and wrote every tile into out_tiles/, rendered the overview, and only then failed
    (save_image takes PNG or TIFF): a failed command left a folder of tiles behind. Now a usage error, before any
    work."""
    example = load_example("batch_tiles")
    out = tmp_path / "overview.jpg"
    argv = ["--size", "12", "--tile", "4", "--scheduler", "serial", "--output", str(out), "--device", "cpu"]
    with pytest.raises(SystemExit) as exit_info:
        example.main(argv)
    assert exit_info.value.code == 2
    assert "--output must end in .png, .tif, .tiff" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_interactive_refuses_an_image_name_it_cannot_write_before_rendering(tmp_path, monkeypatch, capsys):
    """--output view.jpg built the scene (stepping the DEM and rendering) before save_image refused the
    name. Now a usage error before any work; --interactive writes no file, so any name goes there."""
    example = load_example("interactive")
    ran = []
    monkeypatch.setattr(example, "run", lambda args: ran.append(args) or 0)
    with pytest.raises(SystemExit) as exit_info:
        example.main(["--output", str(tmp_path / "view.jpg")])
    assert exit_info.value.code == 2 and ran == []
    assert "--output must end in .png" in capsys.readouterr().err
    assert example.main(["--output", str(tmp_path / "view.jpg"), "--interactive"]) == 0 and len(ran) == 1
    assert example.main(["--output", str(tmp_path / "view.PNG")]) == 0 and len(ran) == 2


@needs_render
def test_interactive_steps_the_dem_once_at_startup(monkeypatch):
    """Both sliders and the sphere widget run their callback when created (pyvista does, to apply the initial value),
    and each re-stepped the grid: the scene was stepped four times at startup, the same mesh every time. A setter
    given the value the scene holds now keeps the mesh; a new value still re-steps once."""
    import pyvista as pv

    from stepterrain.pyvista_accessor import StepTerrainAccessor

    example = load_example("interactive")
    calls = []
    real = StepTerrainAccessor.stepped
    monkeypatch.setattr(StepTerrainAccessor, "stepped", lambda self, *a, **k: calls.append(a) or real(self, *a, **k))
    plotter = pv.Plotter(off_screen=True, window_size=(160, 120))
    try:
        scene = example.build(plotter, example.dem_grid(24), device="cpu")
        assert len(calls) == 1 and scene.mesh.n_cells > 0
        (sphere,) = plotter.widgets.sphere_widgets
        sphere.SetCenter(1000.0, 2000.0, 0.0)
        sphere.InvokeEvent("EndInteractionEvent")
        assert len(calls) == 2 and scene.lens_center == (1000.0, 2000.0)
        interval_slider, _gamma_slider = plotter.widgets.slider_widgets
        interval_slider.InvokeEvent("EndInteractionEvent")  # released where it was: nothing changes
        assert len(calls) == 2
        interval_slider.GetRepresentation().SetValue(2 * scene.interval)
        interval_slider.InvokeEvent("EndInteractionEvent")
        assert len(calls) == 3
    finally:
        plotter.close()


EXAMPLE_ARGUMENTS_FOUND_LATE = [
    # --panel 0 0 raised a ZeroDivisionError (the cameras' aspect w / h), with a traceback
    ("globe", ["--size", "3", "--panel", "0", "0"], "--panel must be W H of 8 to 16384 pixels"),
    # the overview's window was refused by the render after every tile had been stepped and written
    ("batch_tiles", ["--size", "12", "--tile", "4", "--scheduler", "serial", "--window", "0", "0"],
     "--window must be W H of 8 to 16384 pixels"),
    # an animation name save_animation refuses: the PNG was rendered and written, the frames rendered, then exit 2
    ("closeup_mappings", ["--size", "48", "--window", "200", "150", "--frames", "2", "--gif", "{tmp}/spin.avi"],
     "--gif must end in .gif or .mp4"),
    # frames over the memory budget: animate_closeups refused them after the PNG had been written
    ("closeup_mappings", ["--size", "48", "--window", "200", "150", "--frames", "10000000", "--gif", "{tmp}/spin.gif"],
     "would need"),
]


@pytest.mark.parametrize("name, argv, message", EXAMPLE_ARGUMENTS_FOUND_LATE,
                         ids=[f"{c[0]}-{k}" for k, c in enumerate(EXAMPLE_ARGUMENTS_FOUND_LATE)])
def test_examples_refuse_bad_arguments_before_any_work(name, argv, message, tmp_path, capsys):
    """Arguments the library refuses only at the end were found after the work and, for batch_tiles and
    closeup_mappings, after outputs were written: a failed command left them behind. Now usage errors (exit 2, one
    line) before any work, and nothing is written."""
    argv = [a.format(tmp=tmp_path) for a in argv] + ["--output", str(tmp_path / "out.png"), "--device", "cpu"]
    assert_usage_error_writing_nothing(name, argv, message, tmp_path, capsys)


def test_closeup_mappings_refuses_an_mp4_without_imageio_ffmpeg_before_any_work(tmp_path, monkeypatch, capsys):
    """--gif spin.mp4 without the video extra rendered and wrote the PNG and rendered every frame before
    save_animation raised; now a usage error naming the extra, and nothing is written."""
    import sys

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import imageio_ffmpeg raises ImportError
    argv = ["--size", "48", "--window", "200", "150", "--frames", "2", "--gif", str(tmp_path / "spin.mp4"),
            "--output", str(tmp_path / "out.png"), "--device", "cpu"]
    assert_usage_error_writing_nothing("closeup_mappings", argv, "pip install 'stepterrain[video]'", tmp_path, capsys)


def test_flood_mp4_keeps_the_frame_size(tmp_path):
    """--mp4 wrote the frames through imageio's default macro_block_size of 16, which stretched every frame whose
    sides are not multiples of 16 (a 20 x 20 crop became a 32 x 32 video, with a warning); the GIF and PNG kept
    20 x 20. Now the MP4 keeps the frame size, as closeup.save_animation does."""
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg (pip install 'stepterrain[video]')")
    import imageio.v3 as iio
    import numpy as np

    example = load_example("flood")
    out = tmp_path / "flood.png"
    argv = ["--size", "20", "--frames", "3", "--keyframes", "2", "--mp4", "--output", str(out), "--device", "cpu"]
    assert example.main(argv) == 0
    gif = iio.imread(out.with_suffix(".gif"), index=None)
    video = iio.imread(out.with_suffix(".mp4"), index=None, extension=".mp4")
    assert gif.shape[:3] == (3, 20, 20)
    assert video.shape[:3] == (3, 20, 20)
    # the same picture, not a rescaled one: H.264 is lossy, so compare the last frame's mean colour and pattern
    last = gif[-1][..., :3].astype(float)
    np.testing.assert_allclose(video[-1].reshape(-1, 3).mean(0), last.reshape(-1, 3).mean(0), atol=8)
    assert np.corrcoef(video[-1].astype(float).mean(-1).ravel(), last.mean(-1).ravel())[0, 1] > 0.8


def test_flood_mp4_refuses_an_odd_frame_size_before_writing_anything(tmp_path, capsys):
    """--size 21 --mp4 wrote the GIF and the PNG at 21 x 21 and an MP4 that imageio stretched to 22 x 22 (a printed
    warning only): the example wrote MP4 through imageio itself, past the even-size check of the library's
    save_animation. Now it writes through save_animation, and an odd crop is a usage error before any work."""
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg (pip install 'stepterrain[video]')")
    example = load_example("flood")
    out = tmp_path / "flood.png"
    argv = ["--size", "21", "--frames", "2", "--keyframes", "2", "--mp4", "--output", str(out), "--device", "cpu"]
    with pytest.raises(SystemExit) as exit_info:
        example.main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--mp4 needs frames of an even width and height" in err and "crops 21 x 21 nodes" in err
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InvalidInputError, match=r"^frames of an MP4 must have an even width and height"):
        example.write_mp4([np.zeros((21, 20, 3), np.uint8)] * 2, tmp_path / "odd.mp4")  # its own writer checks too
    assert list(tmp_path.iterdir()) == []


def test_closeup_mappings_refuses_an_odd_mp4_window_before_rendering(tmp_path, capsys):
    """--window 201 150 --gif spin.mp4 rendered the overview and the spin, wrote the PNG and only then had
    save_animation refuse the odd width: a failed command left the PNG behind. Now a usage error before any work."""
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg (pip install 'stepterrain[video]')")
    argv = ["--size", "48", "--window", "201", "150", "--frames", "2", "--gif", str(tmp_path / "spin.mp4"),
            "--output", str(tmp_path / "out.png"), "--device", "cpu"]
    assert_usage_error_writing_nothing("closeup_mappings", argv, "--window of an MP4 must have an even width and "
                                       "height", tmp_path, capsys)


def test_batch_tiles_exits_1_when_every_tile_failed(tmp_path, monkeypatch, capsys):
    """When every tile failed (--device cuda on workers without a GPU), the summary listed the failures and then
    the overview was refused as a usage error, exit 2 with the usage line: 'error: the batch wrote no output to
    show', as if the arguments were wrong. Now exit 1 after the summary, as for a partial failure, and no picture."""
    from stepterrain.batch import BatchReport, ItemResult

    example = load_example("batch_tiles")

    def failing_batch(terrain, output_dir, **options):
        results = [ItemResult(key=f"tile_r0_c{k}", status="failed", error="DeviceError: no GPU") for k in range(3)]
        return BatchReport(output_dir=Path(output_dir), results=results)

    monkeypatch.setattr(example, "batch", failing_batch)
    out = tmp_path / "overview.png"
    assert example.main(["--size", "12", "--tile", "4", "--scheduler", "serial", "--output", str(out)]) == 1
    err = capsys.readouterr().err
    assert "failed tile_r0_c0" in err and "usage:" not in err
    assert not out.exists()


def test_adaptive_mesh_example_meshes_the_dem_the_right_way_up():
    """examples/adaptive_mesh.py gave adaptive_mesh the DEM's rows as stored, north to south, but adaptive_mesh put
    row i at y = i * spacing (south to north): every panel showed the terrain mirrored north to south (beside
    stepped_terrain.py's panels of the same crop). The crop is now a north-up Terrain, which adaptive_mesh takes as
    it is: every vertex lies at the DEM node of its height, and the example's true error is measured there."""
    import numpy as np

    import stepterrain as st

    example = load_example("adaptive_mesh")
    terrain = example.crop(64)
    mesh = st.adaptive_mesh(terrain, error=10.0)  # as run() calls it
    dem = st.sample_dem()
    stride = 643 // 64  # the crop's own arithmetic for 643 x 1197 nodes
    assert terrain.shape == (64, 64) and terrain.spacing == (30.0 * stride, -30.0 * stride)
    (x0, y0), (dx, dy) = dem.origin, dem.spacing
    i, j = (mesh.vertices[:, 1] - y0) / dy, (mesh.vertices[:, 0] - x0) / dx
    assert np.allclose(i, np.round(i), atol=1e-6) and np.allclose(j, np.round(j), atol=1e-6)
    np.testing.assert_array_equal(mesh.vertices[:, 2], dem.heights[np.round(i).astype(int), np.round(j).astype(int)])
    assert (mesh.face_normals[:, 2] > 0).all()
    assert 0.0 < example.true_error(mesh, terrain) <= 10.0 + 1e-3


@needs_render
def test_interactive_headless_run_picks_an_offscreen_context_without_vtk_warnings(tmp_path):
    """Headless (no DISPLAY), interactive.py let VTK try an X window first: every run printed VTK's
    'bad X server connection' warning before falling back. It now picks EGL or OSMesa as the library's renders do
    (render.require_offscreen), and writes the same picture."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "VTK_DEFAULT_OPENGL_WINDOW")}
    out = tmp_path / "view.png"
    argv = [sys.executable, str(EXAMPLES / "interactive.py"), "--size", "12", "--window", "64", "48",
            "--output", str(out), "--device", "cpu"]
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "X server" not in done.stderr and "WARN" not in done.stderr, done.stderr
    from PIL import Image

    with Image.open(out) as image:
        assert image.size == (64, 48)


@pytest.mark.parametrize("name, argv", [
    ("dynamic_peaks", ["--size", "16", "--window", "128", "96", "--frames", "60"]),
    ("flood", ["--size", "64", "--frames", "200", "--keyframes", "2"]),
])
def test_animations_refuse_frames_over_the_memory_budget_before_any_work(name, argv, tmp_path, capsys):
    """dynamic_peaks.py and flood.py keep every frame for the GIF (and stack them once more to write it), with no
    check: a large --frames ran the machine out of memory after minutes of work. The frames they would hold are now
    checked against the memory budget (st.set_memory_budget) before any work: a usage error, nothing written."""
    import stepterrain as st

    example = load_example(name)
    previous = st.set_memory_budget(4 << 20)  # room for the embedded DEM's read (2.9 MiB), not for the frames
    try:
        with pytest.raises(SystemExit) as exit_info:
            example.main([*argv, "--output", str(tmp_path / "out.png"), "--device", "cpu"])
    finally:
        st.set_memory_budget(previous)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--frames" in err and "over the memory budget" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@needs_render
def test_interactive_initial_view_shows_the_whole_terrain(tmp_path):
    """The initial view's eye was placed by hand: it cut off the terrain's west and east ends (docs/interactive.png
    showed the mesh running off both sides). The camera now keeps that direction at the distance that frames it
    all: the image's left and right columns, and its bottom row, are background."""
    import numpy as np
    from PIL import Image

    example = load_example("interactive")
    out = tmp_path / "view.png"
    assert example.main(["--size", "40", "--window", "160", "120", "--output", str(out), "--device", "cpu"]) == 0
    image = np.asarray(Image.open(out))[..., :3]
    terrain = (image < 250).any(axis=2)
    terrain[:30] = False  # the sliders
    assert terrain.sum() > 0.25 * terrain.size, "the terrain fills much of the view"
    assert not terrain[:, 0].any() and not terrain[:, -1].any() and not terrain[-1].any()


@pytest.mark.parametrize("name", ["closeup_anchors", "closeup_mappings"])
@pytest.mark.parametrize("size", ["-5", "1"])
def test_closeup_examples_refuse_a_size_below_two_nodes_by_name(name, size, tmp_path, capsys):
    """--size -5 cropped the DEM to nothing and --size 1 to one node: the library refused 'heights needs at least
    2 x 2 nodes; got shape (0, 0)', naming no option (the other examples refuse --size by name). 0 stays the whole
    DEM."""
    argv = ["--size", size, "--window", "200", "150", "--output", str(tmp_path / "out.png"), "--device", "cpu"]
    assert_usage_error_writing_nothing(name, argv, f"--size must be 0 (the whole DEM) or at least 2 nodes; got {size}",
                                       tmp_path, capsys)


def test_interactive_grid_of_a_dem_with_columns_east_to_west_is_not_mirrored():
    """interactive.py's grid puts x growing with the column index: the rows of a north-up DEM (negative y spacing)
    were turned south to north, but the columns of one running east to west (negative x spacing, as load_dem keeps a
    GeoTIFF's negative pixel width) were not, and the terrain showed mirrored east-west. Each of the four sign
    combinations gives the grid of the same terrain."""
    from stepterrain import Terrain

    example = load_example("interactive")
    heights = np.random.default_rng(0).random((7, 9)).astype(np.float32)  # rows south to north, columns west to east
    reference = np.asarray(example.dem_grid(9, Terrain.from_heights(heights, spacing=(30.0, 30.0)))["elevation"])
    for flip_x in (False, True):
        for flip_y in (False, True):
            stored = heights[::-1] if flip_y else heights
            stored = stored[:, ::-1] if flip_x else stored
            spacing = (-30.0 if flip_x else 30.0, -30.0 if flip_y else 30.0)
            grid = example.dem_grid(9, Terrain.from_heights(stored, spacing=spacing))
            assert np.array_equal(np.asarray(grid["elevation"]), reference), spacing
            assert grid.spacing[:2] == (30.0, 30.0)


@pytest.mark.parametrize("size", [64, 100])
def test_adaptive_mesh_example_measures_its_error_on_a_dem_in_local_metres(size):
    """true_error interpolated the mesh at j * dx, i * dy, the mesh's vertices at x0 + j * dx - x0: for a 3" DEM read
    into local metres (spacing 779.097..., -1019.288...), its last row of nodes lay a rounding outside the mesh, was
    masked, and the panel printed "max nan m". Measured in node indices now: finite, within the bound, and equal to
    the largest |z - mesh| found by an independent barycentric interpolation on every triangle."""
    import stepterrain as st

    from .conftest import shared_file

    example = load_example("adaptive_mesh")
    terrain = example.crop(size, st.load_dem(shared_file("front_range_srtmgl3_3arcsec.tif")))
    mesh = st.adaptive_mesh(terrain, error=10.0, device="cpu")
    worst = example.true_error(mesh, terrain)
    assert 0.0 < worst <= 10.0 + 1e-3
    # the reference: each triangle's nodes by barycentric coordinates in node indices
    (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
    v = np.asarray(mesh.vertices, dtype=np.float64)
    ij = np.column_stack([np.round((v[:, 1] - y0) / dy), np.round((v[:, 0] - x0) / dx)])
    reference = np.full(terrain.shape, np.nan)
    for face in np.asarray(mesh.faces):
        (a, b, c), z = ij[face], v[face, 2]
        lo, hi = ij[face].min(axis=0).astype(int), ij[face].max(axis=0).astype(int)
        i, j = np.mgrid[lo[0]: hi[0] + 1, lo[1]: hi[1] + 1]
        p = np.stack([i.ravel(), j.ravel()], axis=1).astype(float)
        m = np.array([b - a, c - a]).T
        uv = np.linalg.solve(m, (p - a).T).T
        w = np.column_stack([1 - uv.sum(axis=1), uv])
        inside = (w >= -1e-9).all(axis=1)
        reference[p[inside, 0].astype(int), p[inside, 1].astype(int)] = w[inside] @ z
    assert not np.isnan(reference).any()
    assert worst == pytest.approx(np.abs(reference - terrain.heights).max(), abs=1e-6)


@pytest.mark.parametrize("relief", [0.8, 12.0, 100.0])
def test_closeup_mappings_steps_a_dem_of_little_relief(relief):
    """The stepped close-up's interval was max(1, range / 20 rounded to tens): a --dem file of under 20 m relief (a
    floodplain, or heights in km) got 1 m, one flat terrace or two; 100 m of relief got 1 m too (5 rounds to 0): 100
    steps. Now a round interval giving about 20 steps, as stepped_terrain's and textures' are picked; the embedded
    DEM's 100 m is kept."""
    import stepterrain as st

    example = load_example("closeup_mappings")
    dem = st.sample_dem()
    assert example.closeups(dem)[0].stepped == 100.0
    heights = dem.heights[200:330, 300:460]
    heights = (heights - heights.min()) / np.ptp(heights) * relief
    terrain = st.Terrain.from_heights(heights, spacing=(30.0, -30.0))
    stepped = example.closeups(terrain)[0]
    assert 10 <= relief / stepped.stepped <= 40


@pytest.mark.parametrize(("argv", "message"), [
    (["--size", "10"], "--size must be 2^k + 1 nodes"),
    (["--size", "1"], "--size must be 2^k + 1 nodes"),
    (["--size", "32769"], "--size must be 2^k + 1 nodes"),  # 2^15 + 1: the library's "face_size must be at most"
    (["--far-error", "-1"], "--far-error must be a finite number >= 0"),
    (["--close-error", "nan"], "--close-error must be a finite number >= 0"),
])
def test_globe_example_names_its_own_option_in_a_refusal(argv, message, tmp_path, capsys):
    """globe.py passed --size, --far-error and --close-error to the library unchecked, whose refusals named its own
    arguments: "face_size must be 2^k + 1", and "error must be a finite number" for either error option."""
    assert_usage_error_writing_nothing("globe", [*argv, "--panel", "64", "48", "--device", "cpu", "--output",
                                                 str(tmp_path / "g.png")], message, tmp_path, capsys)


#: each example at a tiny size, but for --output
TINY = {
    "stepped_terrain": ["--size", "8", "--panel", "64", "48"],
    "textures": ["--size", "8", "--panel", "64", "48"],
    "adaptive_mesh": ["--size", "8", "--panel", "64", "48"],
    "flood": ["--size", "8", "--frames", "2", "--keyframes", "2"],
    "batch_tiles": ["--size", "12", "--tile", "4", "--scheduler", "serial", "--window", "64", "48"],
    "closeup_anchors": ["--size", "20", "--window", "256", "144"],
    "closeup_mappings": ["--size", "20", "--window", "192", "108"],
    "interactive": ["--size", "8", "--window", "64", "48"],
    "globe": ["--size", "3", "--panel", "64", "48"],
    "dynamic_peaks": ["--size", "8", "--frames", "2", "--window", "64", "48"],
}


@needs_render
@pytest.mark.parametrize("target", ["folder", "under_a_file"])
@pytest.mark.parametrize("name", sorted(TINY))
def test_examples_refuse_an_output_they_cannot_write_before_any_work(name, target, tmp_path, capsys):
    """--output naming a folder (out.png/) or a file in a "folder" that is a file: dynamic_peaks stepped every frame
    and then ended in a FileExistsError traceback (its GIF's mkdir); flood wrote its GIF and then failed on the PNG,
    batch_tiles wrote every tile and then failed on the overview: a failed command left files behind. The others
    refused it only after all the work. Now every example checks its outputs first, as the CLI does: a usage error
    (exit 2) naming --output, no traceback, nothing written."""
    (tmp_path / "out.png").mkdir()
    (tmp_path / "file").write_text("a file")
    output = tmp_path / "out.png" if target == "folder" else tmp_path / "file" / "x.png"
    before = sorted(tmp_path.rglob("*"))
    example = load_example(name)
    with pytest.raises(SystemExit) as exit_info:
        example.main([*TINY[name], "--device", "cpu", "--output", str(output)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "error: --output" in err and "Traceback" not in err
    assert sorted(tmp_path.rglob("*")) == before


@needs_render
def test_an_example_refuses_to_write_over_its_dem_file(tmp_path, capsys):
    """--dem heights.png --output heights.png (a 16-bit heightmap as the DEM) replaced the user's DEM with the
    picture, exit 0. Now refused before any work, the DEM kept."""
    from PIL import Image

    import stepterrain as st

    heights = (st.sample_dem().heights[500:530, 600:640]).astype(np.uint16)
    dem = tmp_path / "heights.png"
    Image.fromarray(heights).save(dem)
    data = dem.read_bytes()
    example = load_example("stepped_terrain")
    with pytest.raises(SystemExit) as exit_info:
        example.main([*TINY["stepped_terrain"], "--device", "cpu", "--dem", str(dem), "--output", str(dem)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--output" in err and "is the --dem file" in err
    assert dem.read_bytes() == data


@needs_render
def test_closeup_mappings_refuses_a_gif_named_as_its_output(tmp_path, capsys):
    """--gif x.gif --output x.gif wrote the PNG as x.gif and then replaced it by the animation: one file of two."""
    out = tmp_path / "x.gif"
    assert_usage_error_writing_nothing("closeup_mappings", [*TINY["closeup_mappings"], "--device", "cpu", "--frames",
                                                            "2", "--gif", str(out), "--output", str(out)],
                                       "name the same file", tmp_path, capsys)


def test_batch_tiles_names_its_tiles_folder_when_a_file_is_in_its_way(tmp_path, capsys):
    """A file named as the tiles folder beside --output (x_tiles for x.png) was refused by batch as "output_dir
    '.../x_tiles' exists and is not a folder": an argument the example has not. Now the refusal says what that folder
    is and which option placed it; the file is kept."""
    (tmp_path / "x_tiles").write_text("not tiles")
    example = load_example("batch_tiles")
    with pytest.raises(SystemExit) as exit_info:
        example.main([*TINY["batch_tiles"], "--device", "cpu", "--output", str(tmp_path / "x.png")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "the tiles folder beside --output" in err and "output_dir" not in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x_tiles"]
    assert (tmp_path / "x_tiles").read_text() == "not tiles"


def test_batch_tiles_refuses_a_tiles_folder_name_too_long_by_name(tmp_path, capsys):
    """--output of a 250-byte name (a name the system takes) puts the tiles folder at 256 bytes (x_tiles), over the
    255 a folder's name may have: looking for a file in its way ended in an OSError traceback (File name too long),
    where batch had refused it as a usage error. Now a usage error naming the tiles folder and --output, nothing
    written."""
    output = tmp_path / ("a" * 250 + ".png")
    assert_usage_error_writing_nothing("batch_tiles", [*TINY["batch_tiles"], "--device", "cpu", "--output",
                                                       str(output)], "the tiles folder beside --output", tmp_path,
                                       capsys)


def test_batch_tiles_steps_a_dem_of_little_relief_by_default(tmp_path, monkeypatch, capsys):
    """batch_tiles.py stepped every DEM at a fixed 100 m by default: a --dem of 4 m relief (a patch of the embedded
    DEM's heights / 100) came out as one flat terrace in every tile, with a warning. By default it now leaves the
    interval to the library (nice_interval of the DEM's range, 100 m for the embedded DEM, as before)."""
    import trimesh

    import stepterrain as st

    example = load_example("batch_tiles")
    monkeypatch.setattr(example, "overview_image", lambda report, **kw: np.zeros((8, 8, 3), np.uint8))  # no render
    dem = tmp_path / "flat.npy"
    np.save(dem, (st.sample_dem().heights[300:341, 600:641] / 100.0).astype(np.float32))  # 9.15 to 13.08 m
    out = tmp_path / "batch.png"
    assert example.main(["--dem", str(dem), "--size", "41", "--tile", "20", "--scheduler", "serial",
                         "--device", "cpu", "--output", str(out)]) == 0
    tiles = sorted(example.tiles_folder(out).glob("*.glb"))
    assert len(tiles) == 4
    # glTF is y-up: a height is a vertex's y
    z = np.concatenate([trimesh.load(path, force="mesh").vertices[:, 1] for path in tiles])
    terraces = np.unique(np.round(z, 3))
    assert len(terraces) >= 3, f"terraces at {terraces}"
    assert "has no step" not in capsys.readouterr().err


def test_textures_texture_panel_keeps_the_dems_proportions(monkeypatch, tmp_path, capsys):
    """textures.py's texture panel letterboxed the composite's texels as squares: a DEM of cells taller than wide
    (the Front Range's 3", 70.8 x 92.7 m) was drawn square, squashed north-south by a quarter, its circular lens an
    ellipse. The panel now keeps the terrain's extent in metres."""
    import stepterrain as st

    from .conftest import shared_file

    dem = shared_file("front_range_srtmgl3_3arcsec.tif")
    example = load_example("textures")
    monkeypatch.setattr(example, "render_textured_mesh", lambda mesh, window_size, **kw: np.full(
        (window_size[1], window_size[0], 3), 255, np.uint8))  # the draped view is not this test's: no render
    out = tmp_path / "t.png"
    assert example.main(["--dem", str(dem), "--size", "24", "--panel", "96", "72", "--device", "cpu",
                         "--output", str(out)]) == 0
    from PIL import Image

    with Image.open(out) as image:
        panel = np.asarray(image.convert("RGB"))[:, :96].astype(int)
    drawn = np.nonzero((panel < 250).any(axis=-1))
    rows, cols = np.ptp(drawn[0]) + 1, np.ptp(drawn[1]) + 1
    xmin, xmax, ymin, ymax = example.crop_sample(24, st.load_dem(dem)).extent
    assert cols / rows == pytest.approx((xmax - xmin) / (ymax - ymin), abs=0.03)


@pytest.mark.parametrize("name", ["closeup_anchors", "closeup_mappings"])
def test_closeup_examples_crop_keeps_the_dems_crs_and_source(name, monkeypatch, tmp_path):
    """closeup_anchors.py's and closeup_mappings.py's --size crop made a Terrain of the heights, spacing and origin
    only: the DEM's CRS and source were lost (the other examples' crops keep them)."""
    import stepterrain as st

    example = load_example(name)
    seen = []

    def render(terrain, closeups, **kw):
        seen.append(terrain)
        return np.zeros((8, 8, 3), np.uint8)

    monkeypatch.setattr(example, "render_closeups", render)
    assert example.main(["--size", "40", "--device", "cpu", "--output", str(tmp_path / "c.png")]) == 0
    dem = st.sample_dem()
    assert seen[0].shape == (40, 40)
    assert (seen[0].crs, seen[0].source) == (dem.crs, dem.source)


def test_textures_crop_keeps_the_dems_source():
    """textures.py's (and flood.py's) crop_sample kept the DEM's CRS but not its source, as stepped_terrain's does."""
    import stepterrain as st

    dem = st.sample_dem()
    terrain = load_example("textures").crop_sample(32, dem)
    assert (terrain.crs, terrain.source) == (dem.crs, dem.source)


@pytest.mark.parametrize("rows, cols", [(60, 112), (60, 60), (100, 60), (40, 200)])
def test_closeup_anchors_closeups_stay_apart_on_any_dem(rows, cols):
    """closeup_anchors.py's four close-ups (ROI radius a tenth of the shorter side, 1.3 x enlarged, centres 0.225 of
    the width apart) overlapped one another on a DEM not much wider than tall (a square one, the Front Range's,
    taller than wide): four discs merged into one band, the anchor styles could not be told apart. They now stay
    apart, and inside the DEM, whatever its proportions (unchanged on the embedded DEM, 1.86 times wider than tall)."""
    import stepterrain as st

    terrain = st.Terrain.from_heights(np.zeros((rows, cols), np.float32), spacing=(30.0, -30.0))
    xmin, xmax, ymin, ymax = terrain.extent
    cus = load_example("closeup_anchors").closeups(terrain)
    for cu in cus:  # each ROI on the DEM
        (x, y), (w, h) = cu.roi.center, cu.roi.size
        assert xmin <= x - w / 2 and x + w / 2 <= xmax and ymin <= y - h / 2 and y + h / 2 <= ymax
    for a, b in zip(cus, cus[1:], strict=False):  # neighbours apart, overview ROIs and enlarged close-ups alike
        gap = (b.roi.center[0] + b.offset[0]) - (a.roi.center[0] + a.offset[0])
        assert gap >= a.roi.size[0] * a.scale[0] / 2 + b.roi.size[0] * b.scale[0] / 2
        assert b.roi.center[0] - a.roi.center[0] >= a.roi.size[0] / 2 + b.roi.size[0] / 2


def test_flood_frames_keep_the_dems_proportions(tmp_path, capsys):
    """flood.py drew one pixel per node: a DEM of cells taller than wide (the Front Range's 3", 70.8 x 92.7 m) came
    out square, squashed north-south by a quarter. The frames now have square pixels on the ground: as many
    columns as nodes across, the rows stretched (the embedded DEM's 30 m cells keep one pixel per node)."""
    import imageio.v3 as iio

    import stepterrain as st

    from .conftest import shared_file

    dem = shared_file("front_range_srtmgl3_3arcsec.tif")
    example = load_example("flood")
    out = tmp_path / "flood.png"
    assert example.main(["--dem", str(dem), "--size", "24", "--frames", "2", "--keyframes", "2", "--device", "cpu",
                         "--output", str(out)]) == 0
    terrain = example.crop_sample(24, st.load_dem(dem))
    (dx, dy), (rows, cols) = terrain.spacing, terrain.shape
    frames = iio.imread(out.with_suffix(".gif"), index=None)
    assert frames.shape[1:3] == (round(rows * abs(dy) / abs(dx)), cols) == (31, 24)
    water = frames[-1][..., 2].astype(int) > frames[-1][..., 0].astype(int) + 40  # east (the plains) flooded
    assert water[:, -4:].mean() > 0.9 and water[:, :4].mean() < 0.5


def test_flood_mp4_of_stretched_frames_is_even(tmp_path):
    """An MP4 of the Front Range's frames, stretched north-south to square pixels (24 nodes x 31 rows), is written
    at an even 24 x 32, as the GIF beside it, not refused for an odd size its --size 24 did not ask for."""
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg (pip install 'stepterrain[video]')")
    import imageio.v3 as iio

    from .conftest import shared_file

    dem = shared_file("front_range_srtmgl3_3arcsec.tif")
    out = tmp_path / "flood.png"
    assert load_example("flood").main(["--dem", str(dem), "--size", "24", "--frames", "2", "--keyframes", "2",
                                       "--mp4", "--device", "cpu", "--output", str(out)]) == 0
    assert iio.imread(out.with_suffix(".mp4"), index=None, extension=".mp4").shape[:3] == (2, 32, 24)
    assert iio.imread(out.with_suffix(".gif"), index=None).shape[:3] == (2, 32, 24)


@needs_render
def test_adaptive_mesh_example_keeps_a_dense_mesh_readable(tmp_path):
    """The panels drew every triangle edge black and one pixel wide: a mesh with more triangles than pixels (the 2.5 m
    panel of docs/adaptive_mesh.png, 311k triangles in 480 x 400) rendered almost black, its height colours and the
    mesh's adaptivity lost. The edges are now a blended fraction of a pixel: the dense panel keeps most of the plain
    surface's brightness, and an inset (framed in red, its square outlined in red) zooms in on single triangles."""
    import stepterrain as st
    from stepterrain.render import render_mesh

    example = load_example("adaptive_mesh")
    out = tmp_path / "a.png"
    width, height = 96, 80
    assert example.main(["--size", "64", "--errors", "0", "--panel", str(width), str(height), "--device", "cpu",
                         "--output", str(out)]) == 0
    from PIL import Image

    image = np.asarray(Image.open(out).convert("RGB")).astype(np.float64)
    mesh = st.adaptive_mesh(example.crop(64), error=0.0, device="cpu")  # every node: 7,938 triangles
    assert len(mesh.faces) > width * height
    plain = render_mesh(mesh, window_size=(width, height), z_scale=1.5, scalars="height").astype(np.float64)
    surface = plain.min(axis=2) < 250  # the mesh's pixels, less the caption and the inset
    surface[:17] = False
    surface[height - (height * 3) // 8 :, width - (width * 3) // 8 :] = False
    assert surface.sum() > 1000
    ratio = image[surface].mean() / plain[surface].mean()
    assert ratio > 0.45, ratio  # 0.51 (0.065 with the black edges)
    red = (image[..., 0] > 200) & (image[..., 1] < 30) & (image[..., 2] < 30)
    assert red.sum() > 2 * (width + height) * 3 // 8  # at least the inset's frame
