"""Command-line and example fixes found by a bug hunt of the CLI as a batch-scripting GIS user runs it."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp

import stepterrain as st
from stepterrain import cli

from .conftest import needs_render, real_dem
from .conftest import run_cli as run
from .test_examples import assert_usage_error_writing_nothing


def tile_folder(folder: Path, broken: bool = False) -> Path:
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):
        np.save(folder / f"t{k}.npy", (rng.random((12, 14)) * 100).astype(np.float32))
    if broken:
        (folder / "broken.npy").write_bytes(b"junk")
    return folder


def test_batch_failures_go_to_stderr_not_stdout(tmp_path, capsys):
    """tqdm's ``write`` defaults to stdout: a failed item's line landed in the user's piped stdout."""
    src = tile_folder(tmp_path / "tiles", broken=True)
    code, out, err = run(capsys, "batch", src, "--interval", "10", "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 1
    assert out == ""
    assert "broken" in err


def test_batch_png_in_the_input_folder_is_refused_before_any_work(tmp_path, capsys):
    """The overview written into a folder of tiles was read as a tile by the next (resuming) run, which then
    failed on it (exit 1) every time."""
    src = tile_folder(tmp_path / "tiles")
    argv = ["batch", src, "--interval", "10", "--scheduler", "serial", "-o", tmp_path / "out",
            "--png", src / "overview.png", "--size", "64x48"]
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert "--png" in err and "INPUT folder" in err and "Traceback" not in err
    assert sorted(p.name for p in src.iterdir()) == ["t0.npy", "t1.npy"]
    assert not (tmp_path / "out").exists()


EXAMPLE_BAD_ARGUMENTS = [
    ("adaptive_mesh", ["--size", "0"], "--size must be at least 2"),  # ZeroDivisionError
    ("batch_tiles", ["--size", "0", "--scheduler", "serial"], "--size must be at least 2"),  # ZeroDivisionError
    ("closeup_anchors", ["--size", "48", "--window", "160", "120"], "too many close-ups"),
    ("closeup_mappings", ["--size", "48", "--window", "160", "120", "--frames", "0", "--gif", "{tmp}/a.gif"],
     "--frames must be at least 1"),  # wrote the PNG, then failed
    ("dynamic_peaks", ["--size", "16", "--frames", "2", "--output", "{tmp}/a.gif"], "--output must end in .png"),
    ("flood", ["--size", "0", "--frames", "2", "--keyframes", "2"], "--size must be at least 2"),
    ("globe", ["--size", "16"], "--size must be 2^k + 1"),  # named the library's face_size
    # the library's device='cuda:7' as the example's option, as the stepterrain command's errors spell it
    ("interactive", ["--size", "16", "--device", "cuda:7"], "--device 'cuda:7' needs a CUDA GPU"),
    ("stepped_terrain", ["--size", "16", "--device", "cuda:7"], "--device 'cuda:7' needs a CUDA GPU"),
    ("textures", ["--size", "0"], "--size must be at least 2"),
]


@pytest.mark.parametrize("name, argv, message", EXAMPLE_BAD_ARGUMENTS, ids=[c[0] for c in EXAMPLE_BAD_ARGUMENTS])
def test_examples_report_bad_arguments_as_usage_errors(name, argv, message, tmp_path, capsys):
    """Each example's bad arguments end as an argparse error (exit 2, one line on stderr) and write nothing: they
    raised a ZeroDivisionError or the library's exception with a traceback, or wrote one output then failed."""
    argv = [a.format(tmp=tmp_path) for a in argv]
    if "needs a CUDA GPU" in message and wp.is_cuda_available():  # a GPU here: cuda:7 is one it lacks (_device)
        message = "--device must be one of"
    if "--output" not in argv:
        argv += ["--output", str(tmp_path / "out.png")]
    assert_usage_error_writing_nothing(name, argv, message, tmp_path, capsys)


@pytest.mark.parametrize("argv, option", [
    (["steps", "--lens-relative", "0.5,0.5,-0.1"], "--lens-relative"),
    (["closeup", "--roi-relative", "0.5,0.5,0"], "--roi-relative"),
])
def test_a_relative_radius_is_refused_by_its_own_option(argv, option, tmp_path, capsys):
    """A fraction <= 0 was reported as '--lens radius ... got -39.0' (or '--roi radius'): an option not given and a
    world length never typed."""
    code, out, err = run(capsys, *argv, "-o", tmp_path / ("x.glb" if argv[0] == "steps" else "x.png"))
    assert code == 2
    assert f"{option} radius fraction must be positive" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["steps", "texture", "globe", "closeup", "batch"])
def test_an_unusable_device_is_named_before_any_input_is_read(capsys, tmp_path, command):
    """--device was checked after the DEM was loaded (steps, texture, globe, closeup): a large DEM loaded first, and
    a missing input file was reported instead of the device."""
    import warp as wp

    if any(d.is_cuda for d in wp.get_devices()):
        pytest.skip("a CUDA device is present: cuda is usable here")
    missing = tmp_path / "missing.npy"
    args = [command, str(missing), "--device", "cuda"]
    if command == "batch":
        args = [command, str(tmp_path / "missing"), "--device", "cuda", "-o", str(tmp_path / "out")]
    elif command in ("steps", "globe"):
        args += ["-o", str(tmp_path / "o.glb")]
    else:
        args += ["-o", str(tmp_path / "o.png")]
    code, _, err = run(capsys, *args)
    assert code == 2 and "device" in err and "missing" not in err, err


def furlong_dem(path: Path, unit: str = "furlong") -> Path:
    """A small DEM whose .npz names a unit load_dem does not know (heights stored in centimetres)."""
    rng = np.random.default_rng(1)
    np.savez(path, elevation=(rng.random((12, 14)) * 1e4).astype(np.float32), units=np.array(unit))
    return path


@pytest.mark.parametrize("command", ["steps", "texture", "info"])
def test_height_unit_option_reads_a_dem_whose_unit_is_not_known(tmp_path, capsys, command):
    """load_dem refuses a unit it does not know and points at ``height_unit``; a command-line user had no way to
    pass it (the option did not exist, and every such file was refused)."""
    dem = furlong_dem(tmp_path / "dem.npz")
    out = {"steps": ["-o", tmp_path / "o.glb"], "texture": ["-o", tmp_path / "t.png"], "info": ["--json"]}[command]
    code, _, err = run(capsys, command, dem, *out)
    assert code == 2 and "'furlong'" in err and "--height-unit" in err
    code, stdout, err = run(capsys, command, dem, "--height-unit", "cm", *out)
    assert code == 0, err
    if command == "info":
        import json

        heights = np.load(dem)["elevation"]
        summary = json.loads(stdout)
        assert max(summary["height_range"]) == pytest.approx(float(heights.max()) / 100, rel=1e-6)


def test_height_unit_option_is_checked_and_refused_for_the_embedded_dem(tmp_path, capsys):
    dem = furlong_dem(tmp_path / "dem.npz")
    code, _, err = run(capsys, "steps", dem, "--height-unit", "parsec", "-o", tmp_path / "o.glb")
    assert code == 2 and "--height-unit" in err and "expected a length unit" in err and "'parsec'" in err
    assert "loading" not in err  # refused before the file is read
    for argv in (["steps", "-o", tmp_path / "o.glb"], ["batch", "-o", tmp_path / "b", "--scheduler", "serial"]):
        code, _, err = run(capsys, *argv, "--height-unit", "cm")
        assert code == 2 and "--height-unit applies to an INPUT file" in err
    assert not (tmp_path / "o.glb").exists() and not (tmp_path / "b").exists()


def test_batch_height_unit_reaches_every_file_and_enters_the_fingerprint(tmp_path):
    """batch's folder items are read by the workers: the unit must travel with the options, and a rerun with
    another unit must redo the items instead of skipping them as complete."""
    from stepterrain import batch
    from stepterrain.errors import DataFileError, InvalidInputError

    folder = tmp_path / "tiles"
    folder.mkdir()
    furlong_dem(folder / "a.npz")
    report = batch(folder, tmp_path / "out", interval=10.0, scheduler="serial", format=".ply")
    assert not report.ok and "furlong" in report.failed[0].error
    report = batch(folder, tmp_path / "out", interval=10.0, scheduler="serial", format=".ply", height_unit="cm")
    assert report.ok and len(report.done) == 1
    import trimesh

    z = trimesh.load(tmp_path / "out" / "a.ply").vertices[:, 2]
    assert z.max() <= np.load(folder / "a.npz")["elevation"].max() / 100 + 10.0
    again = batch(folder, tmp_path / "out", interval=10.0, scheduler="serial", format=".ply", height_unit="cm")
    assert len(again.skipped) == 1
    other = batch(folder, tmp_path / "out", interval=10.0, scheduler="serial", format=".ply", height_unit="mm")
    assert len(other.done) == 1  # a new unit: redone, not skipped
    with pytest.raises(InvalidInputError, match="height_unit applies to DEM files"):
        batch(np.zeros((3, 4, 5), np.float32), tmp_path / "o2", interval=1.0, scheduler="serial", height_unit="cm")
    with pytest.raises(InvalidInputError, match="height_unit must be a length unit"):
        batch(folder, tmp_path / "o3", interval=1.0, scheduler="serial", height_unit="parsec")
    np.save(tmp_path / "series.npy", np.zeros((2, 4, 5), np.float32))
    with pytest.raises(InvalidInputError, match="series"):
        batch(tmp_path / "series.npy", tmp_path / "o4", interval=1.0, scheduler="serial", height_unit="cm")
    assert DataFileError  # the refusal of an unknown unit in a file is a DataFileError (report.failed above)


# ------------------------------------------------------------------ adversarial fuzzing of globe, closeup, texture
def one_error_line(err: str, command: str) -> str:
    """The one ``stepterrain COMMAND: error:`` line of a refused run (no traceback, no other line)."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"stepterrain {command}: error: "), err
    return lines[0]


@pytest.mark.parametrize("axis", ["lat", "lon"])
def test_globe_input_with_a_repeated_coordinate_is_a_usage_error(tmp_path, capsys, axis):
    """An axis of equal values (all zeros, or one value twice at the start) has a zero first step: finding where the
    axis stops being monotone indexed an empty array, an IndexError traceback instead of exit 2."""
    lat, lon = np.linspace(-85, 85, 18), np.linspace(-175, 175, 36)
    for values in (np.zeros, lambda n: np.r_[0.0, 0.0, np.arange(1.0, n - 1)]):
        grids = {"lat": lat, "lon": lon}
        grids[axis] = values(len(grids[axis]))
        np.savez(tmp_path / "g.npz", elevation=np.zeros((18, 36)), **grids)
        code, _, err = run(capsys, "-q", "globe", tmp_path / "g.npz", "--face-size", "3", "-o", tmp_path / "g.glb")
        assert code == 2, err
        line = one_error_line(err, "globe")
        assert f"{axis} must be strictly monotone" in line and "index 1" in line
    assert not (tmp_path / "g.glb").exists()


LONG_NAMES = [  # (command, option, extension): a name over 255 bytes is looked up before any work
    ("globe", "-o", ".glb"), ("globe", "--png", ".png"), ("closeup", "-o", ".png"), ("closeup", "--gif", ".gif"),
    ("texture", "-o", ".png"), ("texture", "--mesh", ".glb"), ("texture", "--normals", ".png"),
]


@pytest.mark.parametrize("command, option, ext", LONG_NAMES, ids=[f"{c}{o}" for c, o, _ in LONG_NAMES])
def test_an_output_name_too_long_names_its_option(tmp_path, capsys, command, option, ext):
    """os.stat of a name over 255 bytes raises ENAMETOOLONG: it reached main's OSError handler as a bare
    '[Errno 36] File name too long', naming no option."""
    required = [] if option == "-o" else ["-o", tmp_path / f"ok{'.glb' if command == 'globe' else '.png'}"]
    name = tmp_path / ("a" * 300 + ext)
    code, _, err = run(capsys, command, "-q", *required, option, name, "--size", "64x64")
    assert code == 2
    line = one_error_line(err, command)
    expected = {"-o": "--output"}.get(option, option)
    assert f"{expected} '" in line and "cannot be written: File name too long" in line and "Errno" not in line
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, option", [
    (["closeup", "--scale", "1 2 3"], "--scale"),  # was read as --scale 123
    (["closeup", "--offset", "0, 0, 10 00"], "--offset"),  # was read as 0,0,1000
    (["globe", "--eye", "30,1 0,2e7"], "--eye"),
    (["steps", "--levels", "100 200"], "--levels"),  # was one level, 100200
])
def test_blanks_inside_a_number_are_refused_not_removed(tmp_path, capsys, argv, option):
    """_floats removed every blank before splitting at commas, so digits on either side of a blank were joined
    into another number and the run went on with it."""
    code, _, err = run(capsys, *argv, "-o", tmp_path / "x.png" if argv[0] == "closeup" else tmp_path / "x.glb")
    assert code == 2
    line = one_error_line(err, argv[0])
    assert f"argument {option}: expected" in line
    assert list(tmp_path.iterdir()) == []


def test_blanks_around_comma_separated_values_are_still_taken():
    from stepterrain.cli import _floats

    assert _floats(3, "x,y,r")(" 1, 2 ,3 ") == (1.0, 2.0, 3.0)


@pytest.mark.parametrize("argv, expected", [
    (["--eye", "0,1e308,1e6"], "--eye longitude must lie in [-360, 360] degrees; got 1e+308"),  # named 'longitude'
    (["--eye", "0,-361,1e6"], "--eye longitude must lie in [-360, 360] degrees; got -361"),
    (["--exaggeration", "1e-320"], "--exaggeration must be at least 1.18e-38"),  # a flat globe, NaN colours, rc 0
    (["--exaggeration", "1e-40"], "--exaggeration must be at least 1.18e-38"),
])
def test_globe_eye_longitude_and_a_vanishing_exaggeration_are_refused_by_their_option(tmp_path, capsys, argv, expected):
    """--eye's longitude was refused by look_from as the library's 'longitude' (no such option); an exaggeration
    that is 0 as the kernels' float32 was taken, with a 'invalid value encountered in divide' warning and a flat,
    NaN-coloured globe written with exit 0."""
    code, _, err = run(capsys, "-q", "globe", "--face-size", "3", *argv, "-o", tmp_path / "g.glb")
    assert code == 2
    assert expected in one_error_line(err, "globe")
    assert list(tmp_path.iterdir()) == []


@needs_render
@pytest.mark.parametrize("extra", [[], ["--gif", "a.gif", "--frames", "2"]])
def test_closeup_z_scale_overflowing_float64_is_refused_by_its_option(tmp_path, capsys, monkeypatch, extra):
    """The layered renderer scaled heights by --z-scale without the bound render_mesh has (texture and steps
    refused 1e308): closeup rendered an image of nothing with an 'overflow encountered in multiply' warning, exit 0."""
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "-q", "closeup", "--z-scale", "1e308", "--size", "96x72", "-o", "c.png", *extra)
    assert code == 2
    assert "--z-scale 1e+308 makes layer 'overview'" in one_error_line(err, "closeup")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, expected", [
    (["--scale", "1e30"], "--scale must be at most"),  # each was 'close-up scale ...', naming no option
    (["--scale", "-1"], "--scale must be positive"),
    (["--offset", "1e30,0,0"], "--offset must be finite"),
    (["--roi", "0,0,1"], "--roi/--roi-relative (close-up 1): ROI box x [-1, 1]"),  # was 'closeups[0]: ROI box'
    (["--roi-relative", "0.5,0.5,0.1", "--roi-relative", "5,5,0.1"], "--roi/--roi-relative (close-up 2): ROI box"),
])
def test_closeup_refusals_from_the_library_name_the_option(tmp_path, capsys, argv, expected):
    """CloseUp's and the ROI checks' messages name 'close-up scale', 'closeups[0]', ...: _as_option passed them
    through, so the one-line error named no option of the command."""
    code, _, err = run(capsys, "-q", "closeup", *argv, "-o", tmp_path / "c.glb")
    assert code == 2
    assert one_error_line(err, "closeup").startswith(f"stepterrain closeup: error: {expected}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("typed", ["1,2,0", "1,0,nan", "-1,0,0", "0.5,0.5", "notacolor"])
def test_closeup_color_refusal_names_what_was_typed_before_the_dem_is_read(tmp_path, capsys, typed):
    """--color 1,2,0 was refused by CloseUp after the DEM was read, naming the parsed tuple, "got (1.0, 2.0, 0.0)":
    now as a usage error naming the text typed and what is expected, before any work."""
    code, _, err = run(capsys, "closeup", "--color", typed, "-o", tmp_path / "c.glb")
    assert code == 2
    assert one_error_line(err, "closeup") == (
        "stepterrain closeup: error: argument --color: expected a matplotlib color name, '#rrggbb' or r,g,b with "
        f"each number in [0, 1]; got {typed!r}")
    assert "nodes" not in err  # the DEM was not read
    assert list(tmp_path.iterdir()) == []


def test_closeup_subnormal_fps_for_a_gif_is_a_usage_error(tmp_path, capsys):
    """100 / 1e-320 is inf: _check_fps's int() raised OverflowError, a traceback instead of exit 2."""
    code, _, err = run(capsys, "-q", "closeup", "--gif", tmp_path / "a.gif", "--fps", "1e-320", "--frames", "2",
                       "-o", tmp_path / "c.glb")
    assert code == 2
    assert "--fps must lie in [0.001526, 100] frames per second for a GIF" in one_error_line(err, "closeup")
    assert list(tmp_path.iterdir()) == []


def test_a_non_finite_texture_azimuth_is_refused_before_the_dem_is_read(tmp_path, capsys):
    """--azimuth inf was refused only by the library, after the DEM was read (minutes for a large one); the
    other options' bounds (--altitude in [0, 90]) are checked up front, and so is this one now."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    code, _, err = run(capsys, "texture", dem, "--azimuth", "inf", "-o", tmp_path / "t.png")
    assert code == 2
    assert "--azimuth must be a finite number of degrees; got inf" in err
    assert "loading" not in err


@pytest.mark.parametrize("method, option, value", [("multidirectional", "--azimuth", "100"),
                                                   ("igor", "--altitude", "10")])
def test_a_light_option_the_texture_hillshade_ignores_is_refused_unless_it_aims_shadows(tmp_path, capsys, method,
                                                                                        option, value):
    """--hillshade multidirectional shades by four fixed lights and igor ignores the altitude: --azimuth 100 (or
    --altitude 10) wrote the very texture the default light gave, without a word (gdaldem refuses -multidirectional
    with -az, -igor with -alt). Refused now; with --shadows the light aims the shadows, so it is taken there."""
    dem = tmp_path / "dem.npy"
    y, x = np.mgrid[0:24, 0:30]
    np.save(dem, (40.0 * np.sin(x / 4.0) * np.cos(y / 5.0) + 3.0 * x).astype(np.float32))
    base = ["texture", dem, "--hillshade", method, "--colormap", "none", "--device", "cpu"]
    code, _, err = run(capsys, *base, option, value, "-o", tmp_path / "ignored.png")
    assert code == 2
    assert f"{option} has no effect on --hillshade {method}" in err and f"got {option} {value} without --shadows" in err
    assert "loading" not in err and not (tmp_path / "ignored.png").exists()
    # with --shadows it aims them: a low light from the other side casts other shadows than the default one
    for name, light in (("default", []), ("given", [option, value] if method == "igor" else [option, "135"])):
        assert run(capsys, *base, "--shadows", "--shadow-strength", "1", *light, "-o", tmp_path / f"{name}.png")[0] == 0
    from PIL import Image

    default, given = (np.asarray(Image.open(tmp_path / f"{name}.png")) for name in ("default", "given"))
    assert not np.array_equal(default, given)


def test_a_shadow_strength_without_shadows_is_refused(tmp_path, capsys):
    """--shadow-strength 1 without --shadows (taken for the switch that turns shadows on) wrote the texture without
    shadows, the very one the default gave, without a word; refused now, as --interval without --mesh or --png."""
    dem = tmp_path / "dem.npy"
    np.save(dem, (np.random.default_rng(2).random((12, 14)) * 100).astype(np.float32))
    code, _, err = run(capsys, "texture", dem, "--shadow-strength", "1", "-o", tmp_path / "t.png")
    assert code == 2
    assert "--shadow-strength applies only with --shadows" in err
    assert "loading" not in err and not (tmp_path / "t.png").exists()
    assert run(capsys, "texture", dem, "--shadows", "--shadow-strength", "1", "-o", tmp_path / "t.png")[0] == 0


def test_a_texture_draped_on_a_ply_mesh_becomes_its_vertex_colours(tmp_path, capsys):
    """`texture --mesh out.ply` (or .3mf) wrote the mesh without any colour: those formats keep no texture, and the
    draped image was dropped without a word. Each vertex now gets the texture's colour there (the texel it lies
    in), as `globe --texture` does for them: on the heightfield, exactly the texture PNG's pixel of its node."""
    import trimesh
    from PIL import Image

    dem = tmp_path / "dem.npy"
    y, x = np.mgrid[0:18, 0:23]
    np.save(dem, (30.0 * np.sin(x / 3.0) + 2.0 * y * y).astype(np.float32))
    code, _, _ = run(capsys, "texture", dem, "--shadows", "-o", tmp_path / "t.png", "--mesh", tmp_path / "m.ply",
                     "--device", "cpu")
    assert code == 0
    png = np.asarray(Image.open(tmp_path / "t.png"))
    mesh = trimesh.load(tmp_path / "m.ply", process=False)
    assert mesh.visual.kind == "vertex"
    # a file's rows run north to south: node (i, j) at (j, -i), the PNG's pixel (i, j)
    j, i = np.rint(mesh.vertices[:, 0]).astype(int), np.rint(-mesh.vertices[:, 1]).astype(int)
    assert len(mesh.vertices) == 18 * 23
    np.testing.assert_array_equal(mesh.visual.vertex_colors[:, :3], png[i, j])
    assert len(np.unique(png.reshape(-1, 3), axis=0)) > 50  # a real texture, not one colour


def test_a_texture_draped_on_an_stl_mesh_is_refused_before_the_dem_is_read(tmp_path, capsys, monkeypatch):
    """`texture --mesh out.stl` composed the texture, draped it and wrote an STL without it (an STL holds no texture
    nor colour), saying nothing, where `steps --colormap` and `globe --texture` refuse an .stl. Refused by name now,
    before the DEM is read; a .ply (the texture's colours at the vertices) still passes."""
    from stepterrain import _cli_texture

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)).astype(np.float32) * 100)
    loads = []
    real = _cli_texture._input_terrain
    monkeypatch.setattr(_cli_texture, "_input_terrain", lambda args: loads.append(args) or real(args))
    mesh = tmp_path / "m.STL"
    code, _, err = run(capsys, "-q", "texture", dem, "-o", tmp_path / "t.png", "--mesh", mesh, "--device", "cpu")
    assert code == 2
    assert one_error_line(err, "texture") == (
        f"stepterrain texture: error: --mesh drapes the texture on a mesh; an .stl --mesh holds no texture or "
        f"colours: got --mesh {str(mesh)!r}; write .glb, .gltf or .obj (the texture) or .ply or .3mf (its colour at "
        f"each vertex)")
    assert loads == [] and list(tmp_path.iterdir()) == [dem]
    code, _, err = run(capsys, "-q", "texture", dem, "-o", tmp_path / "t.png", "--mesh", tmp_path / "m.ply",
                       "--device", "cpu")
    assert code == 0 and len(loads) == 1 and (tmp_path / "m.ply").exists(), err


@pytest.mark.parametrize("argv, message", [
    (["steps", "--interval", "-1"], "--interval must be a positive finite number; got -1.0"),
    (["steps", "--base", "nan"], "--base must be finite; got nan"),
    (["steps", "--lens", "1,2,0"], "--lens radius must be a positive finite number; got 0.0"),
    (["steps", "--lens", "1,2,5", "--lens-edge", "-1"], "--lens-edge must be >= 0; got -1.0"),
    (["steps", "--lens", "1,2,5", "--lens-edge", "nan"], "--lens-edge must be finite; got nan"),
    (["texture", "--z-factor", "0"], "--z-factor must be positive; got 0.0"),
    (["texture", "--shadows", "--shadow-strength", "2"], "--shadow-strength must lie in [0, 1]; got 2"),
    (["texture", "--occlusion", "nan"], "--occlusion must be finite; got nan"),
    (["closeup", "--scale", "0"], "--scale must be positive (sx, sy > 0; sz >= 0, 0 flattens); got (0.0, 0.0, 0.0)"),
    (["closeup", "--scale", "1e30"], "--scale must be at most 1e+06; got (1e+30, 1e+30, 1e+30)"),
    (["closeup", "--scale", "1,2"], "--scale must be s or sx,sy,sz; got 1,2"),
    (["closeup", "--offset", "1,1,1", "--offset", "2,2,2"], "--offset must be given once or once per ROI (1); got 2"),
    (["closeup", "--offset", "0,0,1e13"], "--offset must be finite (dx, dy, dz) metres, each within ±1e+12; got "
                                          "(0.0, 0.0, 10000000000000.0)"),
    (["closeup", "--stepped", "-1"], "--stepped must be a finite number >= 0 (0: a continuous close-up); got -1"),
    (["closeup", "--roi", "1,2,-1"], "--roi radius must lie in (0, 1e+12]; got -1"),
    (["closeup", "--roi", "1,2,5", "--edge", "6"], "--edge must be at most the ROI radius 5; got 6"),
])
def test_option_values_refused_whatever_the_dem_are_refused_before_it_is_read(tmp_path, capsys, monkeypatch, argv,
                                                                              message):
    """steps --interval -1 / --base nan / a --lens radius or --lens-edge, texture --z-factor 0 / --shadow-strength /
    --occlusion, closeup --scale / --offset counts and bound / --stepped / a --roi radius and its --edge: values
    refused whatever the DEM were refused only once it had been read (a large GeoTIFF: minutes), by the library or a
    check after the load. Refused before now, with the same messages; the DEM is read once the value is fine."""
    from stepterrain import _cli_texture
    from stepterrain import cli as cli_module

    loads = []

    def load(args, *rest, **options):
        loads.append(1)
        raise st.errors.InvalidInputError("the DEM was read")

    for module in (cli_module, _cli_texture):
        monkeypatch.setattr(module, "_input_terrain", load)
    out = tmp_path / ("t.png" if argv[0] == "texture" else "m.glb")
    code, _, err = run(capsys, "-q", *argv, "-o", out, "--device", "cpu")
    assert code == 2
    assert one_error_line(err, argv[0]) == f"stepterrain {argv[0]}: error: {message}"
    assert loads == [] and list(tmp_path.iterdir()) == []
    code, _, err = run(capsys, "-q", argv[0], "-o", out, "--device", "cpu")
    assert code == 2 and "the DEM was read" in err and loads == [1]


def test_a_closeup_rotation_of_many_turns_is_its_angle_modulo_360(tmp_path, capsys):
    """--rotation 0,1e308 was converted to radians first: math.radians(1e308) kept none of the angle, so the close-up
    turned by whatever cos(1.7e306) gave. Whole turns come off first (exactly), so it is 1e308 mod 360 degrees."""
    import trimesh

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    reduced = math.fmod(1e308, 360.0)
    meshes = []
    for beta in (1e308, reduced):
        out = tmp_path / f"scene_{len(meshes)}.ply"
        code, _, err = run(capsys, "closeup", dem, "--rotation", f"0,{beta!r}", "-o", out)
        assert code == 0, err
        meshes.append(trimesh.load(out, process=False))
    np.testing.assert_array_equal(meshes[0].vertices, meshes[1].vertices)


@pytest.fixture
def tiny_budget():
    """A 1 MiB memory budget for one test, restored afterwards."""
    import stepterrain as st

    previous = st.set_memory_budget(1 << 20)
    yield
    st.set_memory_budget(previous)


@pytest.mark.parametrize("command", ["steps", "closeup", "globe", "texture", "batch"])
def test_a_render_size_over_the_memory_budget_is_refused_before_the_dem_is_read(command, tmp_path, capsys,
                                                                                 tiny_budget):
    """--size took up to 16384x16384 whatever the memory budget said: the DEM was read and the mesh built (or a
    whole batch run) before the render allocated its framebuffers (~43 bytes per pixel measured: 11 GiB at 16384²).
    The render's memory is now checked with the other arguments, naming --size."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    png = tmp_path / "r.png"
    argv = {
        "steps": ["steps", dem, "-o", tmp_path / "m.glb", "--png", png],
        "closeup": ["closeup", dem, "-o", png],
        "globe": ["globe", "-o", tmp_path / "g.glb", "--png", png],
        "texture": ["texture", dem, "-o", tmp_path / "t.png", "--png", png],
        "batch": ["batch", tmp_path / "tiles", "--interval", "10", "--scheduler", "serial", "-o", tmp_path / "out",
                  "--png", png],
    }[command]
    if command == "batch":
        tile_folder(tmp_path / "tiles")
    code, out, err = run(capsys, *argv, "--size", "640x400")
    assert code == 2
    assert "an off-screen render of 640 x 400 pixels (--size 640x400) would need" in err
    assert "over the memory budget of 1.0 MiB; give a smaller --size" in err
    assert len(err.strip().splitlines()) == 1  # the error alone: no progress line, nothing loaded or built
    assert sorted(p.name for p in tmp_path.iterdir()) == (["dem.npy", "tiles"] if command == "batch" else ["dem.npy"])


def test_a_size_that_renders_nothing_is_not_held_to_the_render_budget(tmp_path, capsys, tiny_budget):
    """Only a run that renders allocates the window: steps without --png still meshes under a small budget (its
    default --size unchecked; a --size given without --png is refused as doing nothing, by name, not by the budget)."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    code, out, err = run(capsys, "steps", dem, "-o", tmp_path / "m.glb", "--size", "640x400")
    assert code == 2 and "error: --size applies only with --png (the render); got it without --png" in err, err
    code, out, err = run(capsys, "steps", dem, "-o", tmp_path / "m.glb")
    assert code == 0, err
    assert (tmp_path / "m.glb").exists()


def test_memory_budget_option_refuses_a_run_then_lets_it_pass(tmp_path, capsys):
    """A run over the memory budget said "raise the budget (stepterrain.set_memory_budget or memory_budget=)", which
    a command-line user cannot follow. Every subcommand (and the command before it) takes --memory-budget SIZE now,
    for that run only, and the refusal names it."""
    import stepterrain as st

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    before = st.get_memory_budget()
    for argv in (["steps", dem, "-o", tmp_path / "m.glb", "--memory-budget", "1KiB"],
                 ["--memory-budget", "1024", "steps", dem, "-o", tmp_path / "m.glb"]):
        code, out, err = run(capsys, *argv)
        assert code == 2
        assert "over the memory budget of 1,024 bytes" in err and "--memory-budget SIZE" in err, err
        assert "set_memory_budget" not in err
        assert st.get_memory_budget() == before  # the option holds for its run only
        assert not (tmp_path / "m.glb").exists()
    code, out, err = run(capsys, "steps", dem, "-o", tmp_path / "m.glb", "--memory-budget", "1MiB")
    assert code == 0, err
    assert (tmp_path / "m.glb").exists()
    assert st.get_memory_budget() == before


@pytest.mark.parametrize("command", ["steps", "globe", "closeup", "texture", "batch", "info"])
@pytest.mark.parametrize("value", ["0", "-1GiB", "8XB", "1e9", "", "0.1"])
def test_a_bad_memory_budget_is_a_usage_error_naming_the_option(command, value, tmp_path, capsys):
    code, out, err = run(capsys, command, "--memory-budget", value, "-o", tmp_path / "x.glb")
    assert code == 2
    assert "argument --memory-budget: expected a positive size in bytes" in err and repr(value) in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["steps", "globe", "closeup", "texture", "batch", "info"])
def test_every_subcommand_help_shows_the_memory_budget_option(command, capsys):
    code, out, err = run(capsys, command, "--help")
    assert code == 0 and "--memory-budget SIZE" in out


def test_memory_budget_reaches_the_batch_worker_processes(tmp_path, capsys):
    """batch's default LocalCluster steps in worker processes, which kept their own (default, 16 GiB) budget:
    st.set_memory_budget, and so --memory-budget, did not hold for the items. run_item now sets the caller's budget
    in the worker first."""
    pytest.importorskip("distributed", reason="needs dask.distributed")
    src = tile_folder(tmp_path / "tiles")
    code, out, err = run(capsys, "batch", src, "--interval", "10", "--workers", "1", "--retries", "0",
                         "--memory-budget", "1KiB", "-o", tmp_path / "out")
    assert code == 1, err  # every item failed, each refused by the budget
    assert err.count("OutputTooLargeError") >= 2 and "over the memory budget of 1,024 bytes" in err
    failures = [line for line in err.splitlines() if line.startswith("stepterrain: failed")]  # the summary's lines
    assert len(failures) == 2 and all("--memory-budget SIZE" in line for line in failures), err


def test_steps_refuses_a_floor_above_the_surface_before_stepping(tmp_path, capsys):
    """``steps --solid --floor <too high>`` stepped the DEM first: the "heights on a threshold" warning printed before
    the --floor error. The floor is refused before stepping now: the error alone."""
    dem = tmp_path / "dem.npy"
    heights = np.round(np.random.default_rng(0).random((12, 14)) * 100).astype(np.float32)
    heights[0, 0] = 15.0  # on the threshold between 10 and 20
    np.save(dem, heights)
    code, out, err = run(capsys, "-q", "steps", dem, "--interval", "10", "--solid", "--floor", "50",
                         "-o", tmp_path / "m.stl")
    assert code == 2
    assert err.startswith("stepterrain steps: error: --floor must lie below the lowest surface height 0 ")
    assert "warning" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.stl").exists()


@pytest.mark.parametrize("scheduler", ["serial", "local"])
def test_batch_progress_lines_of_a_budget_refusal_name_the_option(scheduler, tmp_path, capsys):
    """batch's progress bar wrote each failed item as the library worded it, "raise the budget
    (stepterrain.set_memory_budget or memory_budget=)", under which the summary named --memory-budget: two hints
    for one refusal, the first one a command-line user cannot follow. Every line names the option now."""
    import stepterrain as st

    if scheduler == "local":
        pytest.importorskip("distributed", reason="needs dask.distributed")
    src = tile_folder(tmp_path / "tiles")
    argv = ["batch", src, "--interval", "10", "--retries", "0", "--memory-budget", "1KiB", "-o", tmp_path / "out"]
    argv += ["--scheduler", "serial"] if scheduler == "serial" else ["--workers", "1"]
    code, out, err = run(capsys, *argv)
    assert code == 1, err
    failed = [line for line in err.splitlines() if "OutputTooLargeError" in line]
    assert len(failed) == 2, err  # the bar's line for each of the two items (the summary's no more: said once)
    assert all("--memory-budget SIZE" in line for line in failed), err
    assert "set_memory_budget" not in err
    from stepterrain._compaction import BUDGET_HINT, budget_hint

    assert budget_hint() == BUDGET_HINT  # for the run only: the library's own refusals keep the library's hint
    with pytest.raises(st.errors.OutputTooLargeError, match="stepterrain.set_memory_budget"):
        st.stepped(np.zeros((40, 40)) + np.arange(40), interval=1, memory_budget=1024)


def test_batch_warnings_of_worker_processes_are_one_line_each(tmp_path, capsys):
    """batch's default LocalCluster steps in worker processes, whose warnings (here STL's float32 rounding of UTM
    coordinates) printed in Python's format: ".../dask/_task_spec.py:768: UserWarning: ..." and a source line
    "return self.func(*new_argspec)". Workers record them now and the command says each as one warning line (STL's
    rounding once for all tiles)."""
    pytest.importorskip("distributed", reason="needs dask.distributed")
    src = tmp_path / "tiles"
    src.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):  # UTM-sized coordinates: float32 keeps them to 0.25 m
        np.savez(src / f"t{k}.npz", elevation=(rng.random((12, 14)) * 100).astype(np.float32), dx=30.0, dy=30.0,
                 crs="EPSG:32611", transform=[376313.6554 + 10.1 * k, 30.0, 0.0, 3807917.8276, 0.0, -30.0])
    code, out, err = run(capsys, "-q", "batch", src, "--interval", "10", "--workers", "1", "--format", ".stl",
                         "-o", tmp_path / "out")
    assert code == 0, err
    said = [line for line in err.splitlines() if "float32" in line]  # the two tiles' rounding, said once for both
    assert len(said) == 1 and said[0].startswith("stepterrain batch: warning: "), err
    assert "2 of the 2 .stl outputs" in said[0] and any(f"t{k}.stl'" in said[0] for k in range(2))  # the worst
    assert "UserWarning" not in err and "_task_spec" not in err and "return self.func" not in err


def test_a_warning_during_batchs_progress_bar_is_a_line_of_its_own(tmp_path, capsys):
    """A warning raised while batch's progress bar was drawn went after the bar on its line:
    "stepterrain batch:  50%|#####     | 1/2 [...]stepterrain batch: warning: ...". The bar is cleared first now."""
    src = tmp_path / "tiles"
    src.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):  # UTM-sized coordinates: .stl's float32 moves them by up to 0.25 m, which warns
        np.savez(src / f"t{k}.npz", elevation=(rng.random((12, 14)) * 100).astype(np.float32), dx=30.0, dy=30.0,
                 crs="EPSG:32611", transform=[376313.6554 + 10.1 * k, 30.0, 0.0, 3807917.8276, 0.0, -30.0])
    code, out, err = run(capsys, "batch", src, "--interval", "10", "--scheduler", "serial", "--format", ".stl",
                         "-o", tmp_path / "out")
    assert code == 0, err
    said = [line.strip() for line in err.replace("\r", "\n").splitlines() if "warning:" in line]
    assert len(said) == 1 and said[0].startswith("stepterrain batch: warning: "), err  # both tiles' rounding


@pytest.mark.parametrize("ext", [".ply", ".3mf"])
def test_info_reports_the_face_colours_ply_and_3mf_keep(ext, tmp_path, capsys):
    """PLY and 3MF keep face colours (66d79db), but info reported only vertex_colors: a face-coloured file read as
    "vertex_colors False" and nothing more, as if it had no colours."""
    import json

    import trimesh

    from stepterrain.export import save_mesh

    mesh = trimesh.creation.box()
    mesh.visual.face_colors = np.random.default_rng(2).integers(0, 256, (len(mesh.faces), 4), dtype=np.uint8)
    plain = trimesh.creation.box()
    for name, m in (("colored", mesh), ("plain", plain)):
        save_mesh(m, tmp_path / f"{name}{ext}")
    code, out, err = run(capsys, "info", tmp_path / f"colored{ext}", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["face_colors"] is True and summary["vertex_colors"] is False
    code, out, err = run(capsys, "info", tmp_path / f"plain{ext}", "--json")
    assert code == 0, err
    assert json.loads(out)["face_colors"] is False


@pytest.mark.parametrize("ext", [".glb", ".gltf", ".obj"])
def test_info_reports_the_texture_a_mesh_carries(ext, tmp_path, capsys):
    """A textured mesh (texture --mesh, globe --texture: GLB, glTF and OBJ embed or write the image) was described as
    "vertex_colors False, face_colors False" and nothing more, as if it had no colour at all; info gives the texture
    image's (width, height) now, None for a mesh without one."""
    import json

    import trimesh
    from PIL import Image

    from stepterrain.export import save_mesh

    mesh = trimesh.creation.box()
    image = Image.fromarray(np.random.default_rng(3).integers(0, 256, (6, 10, 3), dtype=np.uint8))
    uv = np.random.default_rng(4).random((len(mesh.vertices), 2))
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    save_mesh(mesh, tmp_path / f"textured{ext}")
    save_mesh(trimesh.creation.box(), tmp_path / f"plain{ext}")
    code, out, err = run(capsys, "info", tmp_path / f"textured{ext}", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["texture"] == [10, 6] and summary["vertex_colors"] is False, summary
    code, out, err = run(capsys, "info", tmp_path / f"textured{ext}")
    assert code == 0 and re.search(r"^texture +\(10, 6\)$", out, re.M), out
    code, out, err = run(capsys, "info", tmp_path / f"plain{ext}", "--json")
    assert code == 0, err
    assert json.loads(out)["texture"] is None


def test_globe_help_states_the_tilt_range_it_checks(capsys):
    """globe --tilt refuses values outside [0, 90) ("--tilt must lie in [0, 90) degrees"), but its help said only
    "tilt of the view from straight down, degrees": the limit was found by trial."""
    code, out, err = run(capsys, "globe", "--help")
    assert code == 0
    assert "[0, 90) degrees" in " ".join(out.split())
    code, out, err = run(capsys, "globe", "--tilt", "90", "-o", "x.glb")
    assert code == 2 and "--tilt must lie in [0, 90) degrees" in err


def test_a_reader_that_closes_the_pipe_ends_the_run_quietly(capsys, monkeypatch):
    """`stepterrain info FILE | head` printed "error: [Errno 32] Broken pipe" and exited 2 (bad input) when head
    closed the pipe (found by helper 37). The run now ends quietly with 141, the status a shell gives a command
    that SIGPIPE ended."""
    import io

    from stepterrain import cli

    class ClosedPipe(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr("sys.stdout", ClosedPipe())
    sample = Path(cli.__file__).parent / "data" / "big_tujunga_srtm_30m_utm11n.npz"
    assert cli.main(["info", str(sample)]) == 141
    assert capsys.readouterr().err == ""


def test_a_batch_floor_refusal_names_the_option_once(tmp_path, capsys):
    """The library's message says ``floor (the CLI's --floor) must ...``; the CLI spelled its argument as the option,
    which printed "--floor (the CLI's --floor) must lie below" on the command line."""
    np.save(tmp_path / "series.npy", np.linspace(100.0, 200.0, 2 * 12 * 14, dtype=np.float32).reshape(2, 12, 14))
    code, _, err = run(capsys, "batch", tmp_path / "series.npy", "--interval", "10", "--solid", "--floor", "150",
                       "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 2
    assert "--floor must lie below the lowest point" in err
    assert "the CLI's" not in err


# ------------------------------------------------------------------------------- library names as options (h20)
def test_a_folder_without_isovalues_is_stepped_at_the_default_interval(tmp_path, capsys):
    """batch on a folder without --interval or --levels said "needs interval or levels" (library arguments, not
    the options the user types: h20); its files share one height range now, which gives the default interval, as
    steps picks it for one DEM (the rewriting of names mid-message is checked on other messages below)."""
    code, out, err = run(capsys, "-q", "batch", tile_folder(tmp_path / "tiles"), "--scheduler", "serial",
                         "-o", tmp_path / "out")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "out").glob("*.glb")) == ["t0.glb", "t1.glb"]


def test_a_globe_over_the_budget_names_the_face_size_option(tmp_path, capsys):
    """globe refused a face size over the memory budget with "use a smaller face_size" (the library argument)
    in the middle of the message, where the leading-name rewrite did not reach."""
    code, out, err = run(capsys, "-q", "--memory-budget", "1MiB", "globe", "--face-size", "257",
                         "-o", tmp_path / "g.glb")
    assert code == 2
    assert "error: a globe of --face-size 257 from a 540x1080 grid would need" in err
    assert "use a smaller --face-size or a coarser grid, or raise" in err
    assert "face_size" not in err and not (tmp_path / "g.glb").exists()


def test_library_arguments_named_mid_message_are_spelled_as_options():
    """Arguments written name= or in snake_case anywhere in a message become the subcommand's options; plain words
    in a sentence ("gives 5e+09 levels"), name[k], quoted text and names the subcommand has no option for stay."""
    batch, globe = (cli._subcommand(cli.build_parser(), name) for name in ("batch", "globe"))
    assert cli._as_option("base applies only to interval= (uniform isovalues), not to levels=; got base=3.0 "
                          "with levels", batch) == ("--base applies only to --interval (uniform isovalues), not to "
                                                    "--levels; got --base 3.0 with levels")
    count = "over heights [0, 5] gives 5e+09 levels; at most 1,000 are supported"
    assert cli._as_option(f"interval=1e-09 {count}", batch) == f"--interval 1e-09 {count}"
    assert cli._as_option("levels must increase; levels[0]=1.0 and levels[1]=1.0", batch) == (
        "--levels must increase; levels[0]=1.0 and levels[1]=1.0")
    assert cli._as_option("a series of face_size 9", batch) == "a series of face_size 9"  # not a batch option
    assert cli._as_option("got 'face_size' for a globe of face_size=9", globe) == (
        "got 'face_size' for a globe of --face-size 9")


@pytest.mark.parametrize("name", ["t.tif", "t.png"])
def test_texture_of_a_dem_with_nodata_marks_the_holes_transparent(tmp_path, capsys, name):
    """texture -o flattened the texture over white: a nodata node came out opaque white (255, 255, 255), as bright
    as lit ground or the top of the terrain colormap, and --normals wrote (0, 0, 1), flat ground; nothing in the
    GeoTIFF (no alpha band, no nodata value) or PNG told the holes from data. Now both are RGBA, alpha 0 there."""
    heights = np.arange(30, dtype=np.float32).reshape(5, 6) * 10.0
    heights[1, 2] = heights[4, 5] = np.nan
    np.save(dem := tmp_path / "holes.npy", heights)
    out, normals = tmp_path / name, tmp_path / f"n_{name}"
    code, _, err = run(capsys, "-q", "texture", dem, "-o", out, "--normals", normals)
    assert code == 0, err
    for path in (out, normals):
        if name.endswith(".tif"):
            rasterio = pytest.importorskip("rasterio", reason="GeoTIFF output needs rasterio")
            with rasterio.open(path) as tif:
                assert tif.count == 4
                mask = tif.dataset_mask()  # GDAL's reading of the alpha band: 0 = no data
        else:
            from PIL import Image

            with Image.open(path) as picture:
                assert picture.mode == "RGBA"
                mask = np.asarray(picture)[..., 3]
        # spacing (1, -1): row 0 is north, so pixel (i, j) is node (i, j)
        np.testing.assert_array_equal(mask == 0, np.isnan(heights))


def test_info_reports_a_dems_nodata_fraction_and_height_unit(tmp_path, capsys):
    """info gave a DEM's nodata count but not its share of the grid, and not the unit of its heights: a file in feet
    (converted to metres by load_dem) and a plain array (heights as stored, unit unknown) read the same."""
    import json

    heights = np.arange(20.0).reshape(4, 5)
    heights[0, :3] = np.nan
    np.savez(tmp_path / "feet.npz", elevation=heights, units="ft")
    np.save(tmp_path / "plain.npy", heights)
    code, out, err = run(capsys, "info", tmp_path / "feet.npz", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["nodata_count"] == 3 and summary["nodata_fraction"] == pytest.approx(3 / 20)
    assert summary["height_unit"] == "m" and summary["height_unit_read"] == "ft"
    assert summary["height_range"] == pytest.approx([3 * 0.3048, 19 * 0.3048], rel=1e-6)
    code, out, err = run(capsys, "info", tmp_path / "plain.npy", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["height_unit"] is None and summary["height_unit_read"] is None
    code, out, err = run(capsys, "info", tmp_path / "plain.npy", "--height-unit", "cm", "--json")
    summary = json.loads(out)
    assert summary["height_unit_read"] == "cm" and summary["height_range"] == pytest.approx([0.03, 0.19])
    code, out, err = run(capsys, "info", tmp_path / "plain.npy")  # text: the same keys, a None unit said in words
    assert code == 0, err
    lines = dict(line.split(None, 1) for line in out.splitlines())
    assert lines["nodata_fraction"] == "0.15" and lines["height_unit"].startswith("as stored")
    code, out, err = run(capsys, "info")  # the embedded DEM names metres
    lines = dict(line.split(None, 1) for line in out.splitlines())
    assert lines["height_unit"] == "m" and lines["nodata_fraction"] == "0"


def test_info_refuses_a_height_unit_for_a_mesh(tmp_path, capsys):
    """info's --height-unit is "not for a mesh" (its help), but given with a mesh file it was ignored without a word:
    the bounds came out as stored while the user asked for feet to be read as such."""
    import trimesh

    from stepterrain.export import save_mesh

    save_mesh(trimesh.creation.box(), tmp_path / "box.glb")
    code, out, err = run(capsys, "info", tmp_path / "box.glb", "--height-unit", "ft")
    assert code == 2 and out == ""
    assert "--height-unit applies to a DEM" in err and "box.glb" in err
    assert run(capsys, "info", tmp_path / "box.glb")[0] == 0


@pytest.mark.parametrize("lens, why", [
    (("--lens", "-118.2,34.3,5"), "lies outside the terrain's extent"),  # degrees given for a grid in metres
    (("--lens-relative", "2,2,0.1"), "lies outside the terrain's extent"),
    (("--lens", "30.5,-20.5,0.3"), "holds none of them (node spacing 1 x 1)"),  # between four nodes
])
def test_steps_warns_when_the_lens_changes_nothing(lens, why, tmp_path, capsys):
    """A lens given where the terrain is not (longitude and latitude for a UTM grid, a fraction past 1), or between
    nodes, left every node's γ at --gamma: the mesh came out fully stepped (but for walls between nodes), exit 0,
    while the progress line said "original terrain inside"."""
    import trimesh

    np.save(tmp_path / "ramp.npy", np.add.outer(np.arange(40.0), np.arange(60.0)) * 10.0)
    code, out, err = run(capsys, "steps", tmp_path / "ramp.npy", *lens, "--interval", "50", "-o", tmp_path / "a.ply")
    assert code == 0, err
    said = [line for line in err.splitlines() if "warning:" in line]
    assert len(said) == 1 and "changes nothing" in said[0] and why in said[0], err
    plain = tmp_path / "plain.ply"
    assert run(capsys, "steps", tmp_path / "ramp.npy", "--interval", "50", "-o", plain)[0] == 0
    assert np.array_equal(trimesh.load(tmp_path / "a.ply").vertices, trimesh.load(plain).vertices)
    code, out, err = run(capsys, "steps", tmp_path / "ramp.npy", "--lens-relative", "0.5,0.5,0.2", "--interval", "50",
                         "-o", tmp_path / "b.ply")
    assert code == 0 and "warning" not in err  # a lens on the terrain is not warned about


@pytest.mark.parametrize("options, why", [
    # the lens reaches 2e-7 m into the extent, between the mask's samples: every sample is --gamma
    (("--lens", "61.9999998,-20,3", "--lens-edge", "0"), "reaches only 2e-07 into the terrain's extent"),
    (("--lens", "30,-20,5", "--gamma", "1e-50"), None),  # γ 1e-50 is float32 0: the original surface, lens or not
    # a lens inside the extent, smaller than the mask's samples: it was told to "move it inside"
    (("--lens", "30.5,-20.5,1e-300", "--lens-edge", "0"), "lies inside the terrain's extent x 0 to 59, y -39 to 0, but "
                                                        "is smaller than its mask resolves; give a larger radius"),
])
def test_steps_lens_over_the_terrain_that_changes_nothing_is_no_unbound_local(options, why, tmp_path, capsys):
    """A lens overlapping the terrain's extent whose mask still held --gamma everywhere (a sliver of it between the
    mask's samples, or a --gamma that float32 rounds to 0) ended the run in "UnboundLocalError: cannot access local
    variable 'why'" (a traceback, exit 1): the warning's reason was set only for a lens outside the extent."""
    import trimesh

    np.save(tmp_path / "ramp.npy", np.add.outer(np.arange(40.0), np.arange(60.0)) * 10.0)
    code, out, err = run(capsys, "steps", tmp_path / "ramp.npy", *options, "--interval", "50", "-o", tmp_path / "a.ply")
    assert code == 0, err
    said = [line for line in err.splitlines() if "warning:" in line]
    if why is None:
        assert said == [], err
    else:
        assert len(said) == 1 and "changes nothing" in said[0] and why in said[0], err
    gamma = [v for k, v in zip(options, options[1:], strict=False) if k == "--gamma"] or ["1"]
    plain = tmp_path / "plain.ply"
    assert run(capsys, "steps", tmp_path / "ramp.npy", "--gamma", gamma[0], "--interval", "50", "-o", plain)[0] == 0
    assert np.array_equal(trimesh.load(tmp_path / "a.ply").vertices, trimesh.load(plain).vertices)


def test_closeup_rois_mixed_from_both_options_keep_their_command_line_order(tmp_path, capsys):
    """--roi-relative, then --roi, with --color once per ROI: every --roi was taken first, so the colors (and any
    per-close-up option) went to the other close-up than the one given in that place."""
    import trimesh

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((40, 60)) * 10)  # extent x [0, 59], y [-39, 0] (north-up)
    out = tmp_path / "scene.ply"
    code, _, err = run(capsys, "closeup", dem, "--roi-relative", "0.25,0.5,0.15", "--roi", "45,-20,6",
                       "--color", "#ff0000", "--color", "#0000ff", "--offset", "0,0,100", "-o", out)
    assert code == 0, err
    scene = trimesh.load(out, process=False)
    v, rgb = np.asarray(scene.vertices), np.asarray(scene.visual.vertex_colors)[:, :3]
    high = v[:, 2] > 50  # the lifted close-ups' outlines (the anchors' tops): red on the left, blue on the right
    red = high & np.all(rgb == [255, 0, 0], axis=1)
    blue = high & np.all(rgb == [0, 0, 255], axis=1)
    assert red.any() and blue.any()
    assert v[red, 0].max() < 30 < v[blue, 0].min()


def test_counts_in_progress_lines_agree_with_their_nouns(tmp_path, capsys, monkeypatch):
    """Progress and summary lines said "1 levels", "a LocalCluster of 1 workers", "holds at most 1 close-ups",
    "tiles of (4, 6) cells": a count of one takes the singular (cli._counted), a tile R x C."""
    assert [cli._counted(n, "vertex", "vertices") for n in (0, 1, 2, 1024)] == [
        "0 vertices", "1 vertex", "2 vertices", "1,024 vertices"]
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32))
    code, _, err = run(capsys, "steps", dem, "--levels", "5", "-o", tmp_path / "one.glb")
    assert code == 0 and "stepping on cpu: 1 level (5 to 5)" in err.replace("cuda", "cpu") and "1 levels" not in err
    code, _, err = run(capsys, "steps", dem, "--levels", "3,5", "-o", tmp_path / "two.glb")
    assert code == 0 and ": 2 levels (3 to 5)" in err

    import stepterrain.batch

    def stop(*args, **kwargs):
        raise KeyboardInterrupt  # the stage line is out; no cluster is started

    monkeypatch.setattr(stepterrain.batch, "batch", stop)
    _, _, err = run(capsys, "batch", dem, "--tile", "4x6", "--interval", "1", "--workers", "1", "-o", tmp_path / "o")
    assert "in tiles of 4 x 6 cells" in err and "on a LocalCluster of 1 worker\n" in err and "1 workers" not in err
    _, _, err = run(capsys, "batch", dem, "--tile", "4", "--interval", "1", "--workers", "3", "-o", tmp_path / "o")
    assert "in tiles of 4 x 4 cells" in err and "on a LocalCluster of up to 3 workers" in err


def test_batch_stage_line_does_not_promise_more_workers_than_it_may_start(tmp_path, capsys, monkeypatch):
    """The LocalCluster starts at most one worker per item to run (f9f8cc7): two files with --workers 8 start two,
    but the stage line said "on a LocalCluster of 8 workers". It says "up to 8" now, as the cluster's size depends on
    the items left to run (a rerun's complete ones start none)."""
    import stepterrain.batch

    started: list[int] = []

    def record(workers):
        started.append(workers)
        raise KeyboardInterrupt  # the stage line is out and the count known: no cluster started

    monkeypatch.setattr(stepterrain.batch, "start_local_cluster", record)
    for k in range(2):
        np.save(tmp_path / f"t{k}.npy", np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32) + k)
    _, _, err = run(capsys, "batch", tmp_path / "t0.npy", tmp_path / "t1.npy", "--interval", "1", "--workers", "8",
                    "-o", tmp_path / "o")
    assert started == [2]
    assert "LocalCluster of 8 workers" not in err and "on a LocalCluster of up to 8 workers" in err, err


@needs_render
def test_a_window_for_one_close_up_says_so_in_the_singular(tmp_path, capsys):
    code, _, err = run(capsys, "closeup", "--roi-relative", "0.3,0.3,0.1", "--roi-relative", "0.6,0.6,0.1",
                       "--size", "64x64", "--png", tmp_path / "c.png", "-o", tmp_path / "c.glb")
    assert code == 2 and "holds at most 1 close-up (one per 64x64 pixels" in err


def test_library_names_that_leaked_to_the_command_line_are_spelled_as_options(tmp_path, capsys):
    """Found by provoking each subcommand's errors: library argument names the option rewrite missed reached the
    user as they were: steps' and batch's "bring base closer" (a plain word mid-sentence), batch's "tile_size
    applies to one raster" (--tile) and its failure lines (printed raw: "interval=1.0 with base=1e+39"), closeup's
    "--stepped 1e-09: interval=1e-09 over heights", globe's budget hint "raise the error" (--error)."""
    dem = tmp_path / "dem.npy"
    np.save(dem, (np.add.outer(np.arange(6.0), np.arange(7.0)) + 1000).astype(np.float32))
    folder = tile_folder(tmp_path / "tiles")
    leaks = ("bring base", "interval=", "base=", "tile_size", "raise the error")
    cases = [
        (["steps", dem, "--interval", "1", "--base", "1e20", "-o", tmp_path / "s.glb"],
         "error: --interval 1 with --base 1e+20, more than 2**53", "bring --base closer to the heights"),
        (["steps", dem, "--interval", "1", "--base", "1e39", "-o", tmp_path / "s.glb"],
         "error: --base must fit in float32 (|x| < 3.4e+38)", ""),
        (["batch", folder, "--tile", "4", "--interval", "1", "--scheduler", "serial", "-o", tmp_path / "b"],
         "error: --tile applies to one raster, not to a folder of tiles", ""),
        (["batch", folder, "--interval", "1", "--base", "1e20", "--scheduler", "serial", "-o", tmp_path / "b"],
         "error: --interval 1 with --base 1e+20, more than 2**53", "bring --base closer"),  # up front: any heights
        (["batch", folder, "--interval", "1e-5", "--colormap", "none", "--scheduler", "serial", "-o",
          tmp_path / "b"], "failed t0: InvalidInputError: --interval 1e-05 over heights", ""),  # per item
        (["batch", folder, "--interval", "1e-5", "--scheduler", "serial", "-o", tmp_path / "b"],
         "error: --interval 1e-05 over heights", ""),  # coloured (the default): up front, the files' range
        (["closeup", dem, "--roi", "3,-3,2", "--stepped", "1e-9", "-o", tmp_path / "c.glb"],
         "error: --stepped 1e-09 over heights [1000, 1011] gives", ""),
    ]
    for argv, expected, also in cases:
        code, _, err = run(capsys, "-q", *argv)
        assert code != 0 and expected in err and also in err, (argv, err)
        assert not any(leak in err for leak in leaks), err
    globe = cli._subcommand(cli.build_parser(), "globe")
    assert cli._as_option("the mesh would need 5 GiB; raise the error or narrow the view", globe) == (
        "the mesh would need 5 GiB; raise --error or narrow the view")


def test_library_names_in_warnings_are_spelled_as_options(tmp_path, capsys):
    """Warnings reached the command line as the library words them: a GeoTIFF in feet's "pass height_unit='US survey
    foot'" (and "Shift base by ... (e.g. base=0.5, on the command line --base 0.5, ...)" of heights on a threshold,
    which a solid no longer warns of: it is watertight)."""
    dem = tmp_path / "int.npy"
    np.save(dem, np.add.outer(np.arange(10.0), np.arange(10.0)).astype(np.float32))
    code, _, err = run(capsys, "-q", "steps", dem, "--interval", "2", "--solid", "-o", tmp_path / "s.glb")
    assert code == 0 and "warning" not in err, err
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF needs rasterio")
    from affine import Affine

    tif = tmp_path / "ft.tif"
    with rasterio.open(tif, "w", driver="GTiff", height=10, width=10, count=1, dtype="float32", crs="EPSG:2229",
                       transform=Affine(30.0, 0.0, 6400000.0, 0.0, -30.0, 1900000.0)) as out:
        out.write(np.add.outer(np.arange(10.0), np.arange(10.0)).astype(np.float32) * 10 + 1000, 1)
    for argv in (["steps", tif, "--interval", "20", "-o", tmp_path / "f.glb"], ["info", tif]):
        code, _, err = run(capsys, "-q", *argv)
        assert code == 0 and "pass --height-unit 'US survey foot'" in err and "height_unit" not in err, err


@pytest.mark.skipif(not Path("/proc/self/mounts").is_file(), reason="needs Linux's /proc")
def test_an_output_on_a_virtual_file_system_is_refused_with_the_true_reason(tmp_path, capsys):
    """--output /proc/x.glb was refused as "folder '/proc' is not writable (No such file or directory)": the kernel's
    answer for a file /proc will not hold, of a folder that exists. The reason now says what the folder is (a proc or
    sysfs file system), for the CLI's check, batch's output folder and save_mesh alike; a file taken for a folder is
    named as a file."""
    import errno

    from stepterrain import export

    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32))
    cases = [
        (["steps", dem, "--interval", "1", "-o", "/proc/x.glb"],
         "folder '/proc' is not writable (it lies on a proc file system"),
        (["steps", dem, "--interval", "1", "-o", "/proc/a/b/x.glb"],
         "folder '/proc' is not writable (it lies on a proc file system"),
        (["texture", dem, "-o", "/sys/x.png"], "folder '/sys' is not writable (it lies on a sysfs file system"),
        (["batch", dem, "--tile", "4", "--interval", "1", "--scheduler", "serial", "-o", "/proc/out"],
         "cannot create the output folder '/proc/out': '/proc' lies on a proc file system"),
        (["batch", dem, "--tile", "4", "--interval", "1", "--scheduler", "serial", "-o", dem / "out" / "deeper"],
         f"cannot create the output folder '{dem / 'out' / 'deeper'}': '{dem}' is a file, not a folder"),
    ]
    for argv, expected in cases:
        code, _, err = run(capsys, "-q", *argv)
        assert code == 2 and expected in err and "No such file or directory" not in err, err
    mesh = st.stepped(np.load(dem), interval=1.0)
    with pytest.raises(st.DataFileError, match="'/proc': it lies on a proc file system") as refused:
        export.save_mesh(mesh, "/proc/x.glb")
    assert "No such file" not in str(refused.value)
    # an ENOENT of an ordinary folder that exists: not "No such file or directory" as the whole reason
    reason = export.unwritable_reason(OSError(errno.ENOENT, "No such file or directory"), tmp_path)
    assert reason.startswith("it exists but refuses new entries")
    assert export.unwritable_reason(OSError(errno.EACCES, "Permission denied"), tmp_path) == "Permission denied"


@pytest.mark.parametrize("scheduler", ["serial", "tcp://127.0.0.1:1"])
def test_batch_refuses_workers_with_a_scheduler_that_ignores_them(scheduler, tmp_path, capsys):
    """--workers sizes the default LocalCluster only: with --scheduler serial (or a cluster's address) it was
    ignored without a word, as if the run used 4 workers; refused before any work, naming both options."""
    src = tile_folder(tmp_path / "tiles")
    code, out, err = run(capsys, "batch", src, "--interval", "10", "--scheduler", scheduler, "--workers", "4",
                         "-o", tmp_path / "out")
    assert code == 2
    said = err.splitlines()[-1]
    assert "--workers" in said and "--scheduler" in said and scheduler in said, err
    assert not (tmp_path / "out").exists()
    code, out, err = run(capsys, "batch", src, "--interval", "10", "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 0, err  # without --workers, a scheduler runs as it did


def test_batch_names_its_tile_option_not_the_librarys_tile_size(tmp_path, capsys):
    """The library's tile_size (the command line's --tile) is spelled otherwise than the option, so the mapping of
    library names to options missed it: "error: tile_size applies to one raster", an argument the user never typed;
    and a raster without --tile said "give tile_size (the CLI's --tile)" (it is one item now, as a shell glob that
    matched one file gives it: test_the_cli_takes_one_dem_file_without_tile_as_one_item)."""
    src = tile_folder(tmp_path / "tiles")
    code, out, err = run(capsys, "-q", "batch", src, "--tile", "4", "--interval", "10", "--scheduler", "serial",
                         "-o", tmp_path / "out")
    assert code == 2
    assert "error: --tile applies to one raster, not to a folder of tiles" in err and "tile_size" not in err, err
    code, out, err = run(capsys, "-q", "batch", src / "t0.npy", "--interval", "10", "--scheduler", "serial",
                         "-o", tmp_path / "out")
    assert code == 0 and "tile_size" not in err, err
    assert [p.name for p in (tmp_path / "out").glob("*.glb")] == ["t0.glb"]


def test_batch_with_its_progress_bar_says_each_failure_once_as_options(tmp_path, capsys):
    """Without -q, batch printed each failed item twice: the progress bar's line as the library worded it
    ("failed t0: InvalidInputError: interval=1e-05 over heights ...") and the summary's line spelled as options. The
    bar's line is now the summary's, spelled as options, and the summary leaves it out; under -q the summary says it."""
    src = tile_folder(tmp_path / "tiles")
    # --colormap none: with colours (the default now, as steps) the files' shared levels are found up front, and so
    # many are refused once there (exit 2), before any item runs to fail on its own
    argv = ["batch", src, "--interval", "1e-5", "--colormap", "none", "--scheduler", "serial", "-o", tmp_path / "out"]
    for quiet in ((), ("-q",)):
        code, _, err = run(capsys, *quiet, *argv)
        assert code == 1, err
        lines = [line.strip() for line in err.replace("\r", "\n").splitlines()]
        failed = [line for line in lines if "InvalidInputError" in line]
        for key in ("t0", "t1"):
            (line,) = [line for line in failed if f"failed {key}:" in line]
            assert line.startswith(f"stepterrain: failed {key}: InvalidInputError: --interval 1e-05 over heights ")
            assert line.endswith("(after 1 attempt)"), line
        assert len(failed) == 2 and "interval=" not in err, err


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="named pipes (POSIX)")
def test_an_output_that_is_a_named_pipe_is_refused_before_any_work(tmp_path, capsys):
    """save_mesh now refuses a named pipe or a device at the output (os.replace put a regular file in its place), but
    only once the mesh was stepped and the mesh before it written: --png pipe.png left x.glb written and exit 1."""
    import os

    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32))
    os.mkfifo(tmp_path / "pipe.png")
    (tmp_path / "link.png").symlink_to(tmp_path / "pipe.png")
    for png in ("pipe.png", "link.png"):
        code, _, err = run(capsys, "-q", "steps", dem, "--interval", "1", "-o", tmp_path / "x.glb",
                           "--png", tmp_path / png)
        assert code == 2, err
        line = one_error_line(err, "steps")
        assert f"--png '{tmp_path / png}' is a named pipe, not a regular file" in line
        assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy", "link.png", "pipe.png"]


def test_info_shows_the_list_metadata_stepterrain_writes(tmp_path, capsys):
    """info showed only a mesh's scalar metadata: the eye a view-dependent globe mesh was refined for
    (eye_lat_lon_alt), a batch tile's node_rows/node_cols and a stepped mesh's isovalues were left out, though its
    help promises 'the metadata stepterrain wrote'. Lists of plain values are shown now: in full in JSON, in the text
    output in full up to 8 values, a longer one by its first values, its last and its length."""
    import json

    globe = tmp_path / "globe.glb"
    code, out, err = run(capsys, "-q", "globe", "--face-size", "9", "--eye", "46,9,400000", "-o", globe,
                         "--device", "cpu")
    assert code == 0, err
    code, out, err = run(capsys, "info", globe, "--json")
    assert code == 0, err
    assert json.loads(out)["meta.eye_lat_lon_alt"] == [46.0, 9.0, 400000.0]
    code, out, err = run(capsys, "info", globe)
    lines = dict(line.split(None, 1) for line in out.splitlines())
    assert lines["meta.eye_lat_lon_alt"] == "(46, 9, 400000)"

    np.save(tmp_path / "ramp.npy", np.add.outer(np.arange(6.0), np.arange(7.0)) * 10.0)
    steps = tmp_path / "steps.glb"
    levels = ",".join(str(v) for v in range(0, 130, 10))  # 13 isovalues
    code, out, err = run(capsys, "-q", "steps", tmp_path / "ramp.npy", "--levels", levels, "-o", steps,
                         "--device", "cpu")
    assert code == 0, err
    code, out, err = run(capsys, "info", steps, "--json")
    assert json.loads(out)["meta.isovalues"] == [float(v) for v in range(0, 130, 10)]
    code, out, err = run(capsys, "info", steps)
    lines = dict(line.split(None, 1) for line in out.splitlines())
    assert lines["meta.isovalues"] == "(0, 10, 20, 30, 40, 50, ..., 120; 13 values)"
    assert lines["meta.isovalues_count"] == "13"


def test_every_device_option_says_its_default(capsys):
    """``stepterrain steps --help`` and ``batch --help`` said '--device ... (default: Warp's)', while globe, closeup and
    texture said only 'Warp device: cpu, cuda, cuda:0', as if they had another default (they have the same: Warp's,
    the first GPU where there is one)."""
    parser = cli.build_parser()
    subcommands = next(a for a in parser._actions if a.dest == "command").choices
    seen = []
    for name, sub in subcommands.items():
        for action in sub._actions:
            if "--device" in action.option_strings:
                assert action.default is None and action.help.endswith("(default: Warp's)"), (name, action.help)
                seen.append(name)
    assert sorted(seen) == ["batch", "closeup", "globe", "steps", "texture"]


@pytest.mark.parametrize("value", ["-1", "nan", "inf"])
def test_closeup_stepped_refusal_says_zero_is_allowed(value, tmp_path, capsys):
    """``closeup --stepped -1`` said '--stepped must be a positive finite number', though its help says '0:
    continuous' and --stepped 0 is accepted; the refusal now names the range the option takes, and 0 still renders a
    continuous close-up."""
    out = tmp_path / "c.png"
    code, _, err = run(capsys, "-q", "closeup", "--stepped", value, "-o", out, "--size", "128x96")
    assert code == 2 and not out.exists()
    assert f"error: --stepped must be a finite number >= 0 (0: a continuous close-up); got {float(value):g}" in err, err
    if value == "-1" and cli_renders():  # 0: the continuous close-up, accepted as before
        code, _, err = run(capsys, "-q", "closeup", "--stepped", "0", "-o", out, "--size", "128x96")
        assert code == 0 and out.exists(), err


def cli_renders() -> bool:
    from stepterrain import render

    return bool(render.offscreen_available()[0])


@pytest.mark.parametrize("command", ["steps", "globe"])
def test_a_mesh_output_named_png_points_to_the_png_option(command, tmp_path, capsys):
    """closeup's and texture's --output take a .png, so ``stepterrain steps -o terrain.png`` was a natural try; it
    said only that '.png' is an unknown extension. The refusal now says that --png writes a render, beside the mesh;
    other extensions are refused as before."""
    code, _, err = run(capsys, "-q", command, "-o", tmp_path / "terrain.png")
    assert code == 2 and not (tmp_path / "terrain.png").exists()
    assert err.rstrip().endswith("has an unknown extension '.png'; expected one of .glb, .gltf, .obj, .ply, .stl, "
                                 ".3mf; --png writes a render, beside the mesh"), err
    code, _, err = run(capsys, "-q", command, "-o", tmp_path / "terrain.dae")
    assert code == 2 and err.rstrip().endswith("expected one of .glb, .gltf, .obj, .ply, .stl, .3mf"), err


@pytest.mark.parametrize("scheduler", ["serial", "local"])
def test_sigterm_ends_a_batch_as_ctrl_c_does(tmp_path, scheduler):
    """`kill`, `timeout` or a job scheduler's SIGTERM killed `stepterrain batch` outright: the tile being written
    stayed as a hidden partial file (38 MB of a 400-cell solid), the lock file stayed, the manifest lost the items
    finished in its last second, and the LocalCluster's "leaked semaphore objects" were reported. It now ends the run
    as Ctrl-C does: exit status 143, "stepterrain: terminated", the partial file removed, every finished item
    recorded, no worker process left."""
    import json
    import os
    import subprocess
    import sys

    from stepterrain.batch import LOCK_NAME, MANIFEST_NAME

    out = tmp_path / "out"
    # the SIGTERM comes as the third tile is written (in the worker's process on the LocalCluster: to its parent)
    script = f"""
import os, signal, sys
import stepterrain.export as export
from stepterrain.cli import main
real, calls = export._WRITERS[".glb"], []
def writer(mesh, tmp, target, bounds, *shared):
    calls.append(target)
    if len(calls) == 3:
        tmp.write_bytes(b"glTF half a file")
        os.kill(os.getppid() if {scheduler == "local"} else os.getpid(), signal.SIGTERM)
        if {scheduler == "local"}:
            import time; time.sleep(120)  # the worker is closed with its cluster (in seconds, even on a busy machine)
    real(mesh, tmp, target, bounds, *shared)
export._WRITERS[".glb"] = writer
if __name__ == "__main__":
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # as a shell's command has it, also under a runner ignoring it
    sys.exit(main(["-q", "batch", "--tile", "128", "-o", {str(out)!r}]
                  + ({{"serial": ["--scheduler", "serial"], "local": ["--workers", "1"]}}[{scheduler!r}])))
"""
    (tmp_path / "run.py").write_text(script)
    done = subprocess.run([sys.executable, str(tmp_path / "run.py")], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(Path(st.__file__).parents[1])})
    assert done.returncode == 143, (done.returncode, done.stderr[-2000:])
    assert done.stderr.strip().splitlines()[-1] == "stepterrain: terminated", done.stderr[-2000:]
    assert "leaked" not in done.stderr and "Traceback" not in done.stderr, done.stderr[-2000:]
    names = sorted(p.name for p in out.iterdir())
    assert LOCK_NAME not in names and not [n for n in names if n.endswith(".tmp")], names
    written = [n for n in names if n.endswith(".glb")]
    assert len(written) == 2  # complete, as atomic writes leave them
    if scheduler == "serial":  # a worker's finished items may not have reached the client yet: redone by a rerun
        assert sorted(json.loads((out / MANIFEST_NAME).read_text())["items"]) == written


@pytest.mark.parametrize("command", ["steps", "globe", "closeup", "texture", "batch"])
def test_an_unknown_device_names_leaving_the_option_out_not_none(tmp_path, capsys, command):
    """'--device gpu' said "--device must be one of ['cpu'] (or None)": None is the library's default, which the
    command line spells by leaving --device out."""
    out = tmp_path / ("out" if command == "batch" else "x.png")
    extra = ["--scheduler", "serial"] if command == "batch" else []
    assert cli.main([command, "--device", "gpu", *extra, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--device must be one of ['cpu'" in err and ", or left out for Warp's default; got 'gpu'" in err, err
    assert "None" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command, argv, given, needs, got", [
    ("steps", ["-o", "{tmp}/m.glb", "--size", "64x48"], "--size applies", "--png (the render)", "it without --png"),
    ("steps", ["-o", "{tmp}/m.glb", "--z-scale", "5", "--size", "64x48"], "--size and --z-scale apply",
     "--png (the render)", "them without --png"),
    ("texture", ["-o", "{tmp}/t.png", "--mesh", "{tmp}/t.glb", "--z-scale", "5"], "--z-scale applies",
     "--png (the render of the draped mesh)", "it without --png"),
    ("batch", ["--scheduler", "serial", "-o", "{tmp}/out", "--size", "64x48"], "--size applies",
     "--png (the overview render)", "it without --png"),
    ("batch", ["--scheduler", "serial", "-o", "{tmp}/out", "--z-scale", "5"], "--z-scale applies",
     "--png (the overview render)", "it without --png"),
    ("closeup", ["-o", "{tmp}/s.ply", "--z-scale", "5"], "--z-scale applies",
     "a render (a .png --output, --png or --gif)", "it with the mesh --output '{tmp}/s.ply' alone"),
])
def test_render_options_without_a_render_are_refused_by_name(tmp_path, capsys, command, argv, given, needs, got):
    """``steps -o m.glb --size 64x48 --z-scale 5`` (and texture's, batch's, a close-up scene mesh's --size and
    --z-scale without a render) were accepted and made the same files as without them: they shape the render alone.
    Refused by name now, before any work; their values are still checked first."""
    argv = [str(a).replace("{tmp}", str(tmp_path)) for a in argv]
    code, _, err = run(capsys, "-q", command, *argv)
    assert code == 2
    assert one_error_line(err, command) == (f"stepterrain {command}: error: {given} only with {needs}; got "
                                            f"{got.replace('{tmp}', str(tmp_path))}")
    assert list(tmp_path.iterdir()) == []
    if "--z-scale" in argv:  # a bad value is named as such first
        argv[argv.index("--z-scale") + 1] = "-1"
        code, _, err = run(capsys, "-q", command, *argv)
        assert code == 2 and "--z-scale must be a positive number; got -1.0" in err, err


def test_a_meshs_spacing_metadata_is_the_dems_signed_spacing(tmp_path, capsys):
    """``--spacing 30,20`` was recorded in a mesh's metadata as given, (30, 20), while the DEM it placed has spacing
    (30, -20) (rows run north to south) as `info` prints it and as the library records it in a heightfield mesh:
    texture's draped mesh said (1, -1) without --spacing and (30, 20) with it. Every subcommand records the DEM's
    signed spacing now, the form `info` prints for the DEM."""
    from stepterrain.export import read_mesh

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)).astype(np.float32) * 100)
    for command, argv in (("steps", ["-o", tmp_path / "s.glb"]),
                          ("texture", ["-o", tmp_path / "t.png", "--mesh", tmp_path / "t.glb"]),
                          ("closeup", ["-o", tmp_path / "c.glb"])):
        for spacing, expected in (("30", [30.0, -30.0]), ("30,20", [30.0, -20.0])):
            code, _, err = run(capsys, "-q", command, dem, "--spacing", spacing, *argv)
            assert code == 0, err
            mesh = read_mesh(next(p for p in argv if str(p).endswith(".glb")))
            assert list(mesh.metadata["spacing"]) == expected, (command, spacing, mesh.metadata["spacing"])


def test_options_that_change_nothing_are_refused_lens_at_gamma_0_and_texture_on_stl(tmp_path, capsys):
    """``steps --lens-relative 0.5,0.5,0.2 --gamma 0`` (original terrain inside the lens, --gamma 0 outside: the
    original everywhere) and ``globe --texture IMAGE -o g.stl`` without --png (an STL holds no colours) were accepted
    and wrote the files they write without the option. Refused by name now; with --gamma > 0, a .ply or a --png they
    pass."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)).astype(np.float32) * 100)
    for lens in (["--lens-relative", "0.5,0.5,0.2"], ["--lens", "6,-5,3"]):
        code, _, err = run(capsys, "-q", "steps", dem, *lens, "--gamma", "0", "-o", tmp_path / "m.glb")
        assert code == 2
        assert one_error_line(err, "steps").endswith(
            f"error: {lens[0]} shows the original terrain inside it and --gamma outside: with --gamma 0 the terrain "
            f"is original everywhere and the lens changes nothing; give --gamma > 0 or leave {lens[0]} out")
        assert not (tmp_path / "m.glb").exists()
        code, _, err = run(capsys, "-q", "steps", dem, *lens, "--gamma", "0.5", "-o", tmp_path / "m.glb")
        assert code == 0, err
        (tmp_path / "m.glb").unlink()
    picture = tmp_path / "tex.png"
    from PIL import Image

    Image.fromarray(np.zeros((18, 36, 3), np.uint8)).save(picture)
    base = ["-q", "globe", "--face-size", "9", "--no-camera", "--texture", picture, "--device", "cpu"]
    code, _, err = run(capsys, *base, "-o", tmp_path / "g.stl")
    assert code == 2
    assert one_error_line(err, "globe") == (
        f"stepterrain globe: error: --texture colours the mesh and the --png render; an .stl --output holds no "
        f"colours: got --texture {str(picture)!r} with --output {str(tmp_path / 'g.stl')!r} and no --png")
    assert not (tmp_path / "g.stl").exists()
    code, _, err = run(capsys, *base, "-o", tmp_path / "g.ply")
    assert code == 0, err


def test_a_colormap_an_stl_cannot_hold_is_refused(tmp_path, capsys):
    """``steps --colormap viridis -o m.stl`` (no --png) and ``batch --colormap viridis --format .stl`` wrote meshes
    without any colour and said nothing: an STL holds none (batch's --png overview reads the files, so it shows none
    either). Refused by name now; without --colormap, with 'none', with --png (steps renders its mesh in memory) or
    another format they pass."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)).astype(np.float32) * 100)
    out = tmp_path / "m.stl"
    code, _, err = run(capsys, "-q", "steps", dem, "--colormap", "viridis", "-o", out)
    assert code == 2
    assert one_error_line(err, "steps") == (
        f"stepterrain steps: error: --colormap colours the mesh and the --png render; an .stl --output holds no "
        f"colours: got --colormap viridis with --output {str(out)!r} and no --png")
    assert list(tmp_path.iterdir()) == [dem]
    for extra in ([], ["--colormap", "none"]):
        code, _, err = run(capsys, "-q", "steps", dem, *extra, "-o", out)
        assert code == 0 and out.exists(), err
        out.unlink()
    code, _, err = run(capsys, "-q", "batch", dem, "--colormap", "viridis", "--format", ".stl", "--scheduler",
                       "serial", "-o", tmp_path / "out")
    assert code == 2
    assert "error: --colormap colours the meshes by level; --format .stl holds no colours" in one_error_line(err,
                                                                                                           "batch")
    assert list(tmp_path.iterdir()) == [dem]
    code, _, err = run(capsys, "-q", "batch", dem, "--tile", "8", "--colormap", "viridis", "--format", ".ply",
                       "--scheduler", "serial", "-o", tmp_path / "out")
    assert code == 0 and any((tmp_path / "out").glob("*.ply")), err


def test_closeup_colours_an_stl_cannot_hold_are_refused(tmp_path, capsys):
    """``closeup --colormap viridis -o scene.stl`` (or --color), with no --png or --gif, wrote the scene without any
    colour and said nothing, where steps and batch refuse their --colormap with an .stl. Refused by name now, before
    the DEM is read; without them, or with a .ply, it passes."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)).astype(np.float32) * 100)
    out = tmp_path / "scene.stl"
    for colours, named in ((["--colormap", "viridis"], "--colormap viridis"), (["--color", "red"], "--color")):
        code, _, err = run(capsys, "-q", "closeup", dem, *colours, "-o", out)
        assert code == 2
        assert one_error_line(err, "closeup") == (
            f"stepterrain closeup: error: an .stl --output holds no colours: got {named} (colouring the scene and its "
            f"renders) with --output {str(out)!r} and no --png or --gif; write .glb, .ply or .3mf for colours, or "
            "leave them out")
        assert list(tmp_path.iterdir()) == [dem]
    code, _, err = run(capsys, "-q", "closeup", dem, "-o", out)
    assert code == 0 and out.exists(), err
    code, _, err = run(capsys, "-q", "closeup", dem, "--color", "red", "-o", tmp_path / "scene.ply")
    assert code == 0, err


def test_closeup_anchor_opacity_an_stl_cannot_hold_is_refused(tmp_path, capsys):
    """``closeup --anchor hidden -o scene.stl`` with no --png or --gif wrote the file ``--anchor opaque`` writes (an
    .stl holds no colours, so no opacity either) and said nothing, where its --colormap and --color are refused; so did
    ``--scalars slope`` (the overview's colours). Refused by name now, before the DEM is read; a .ply keeps the
    anchors' opacity in its vertex alpha, so it passes there."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32))
    out = tmp_path / "scene.stl"
    code, _, err = run(capsys, "-q", "closeup", dem, "--anchor", "hidden", "-o", out)
    assert code == 2
    assert one_error_line(err, "closeup") == (
        f"stepterrain closeup: error: an .stl --output holds no colours: got --anchor hidden (colouring the scene and "
        f"its renders) with --output {str(out)!r} and no --png or --gif; write .glb, .ply or .3mf for colours, or "
        "leave them out")
    code, _, err = run(capsys, "-q", "closeup", dem, "--scalars", "slope", "-o", out)
    assert code == 2 and "an .stl --output holds no colours: got --scalars slope (colouring" in err, err
    assert list(tmp_path.iterdir()) == [dem]
    alphas = {}
    for preset in ("opaque", "hidden"):
        path = tmp_path / f"{preset}.ply"
        code, _, err = run(capsys, "-q", "closeup", dem, "--roi-relative", "0.5,0.5,0.25", "--anchor", preset,
                           "-o", path)
        assert code == 0, err
        alphas[preset] = st.export.read_mesh(path).visual.vertex_colors[:, 3]
    assert (alphas["hidden"] < alphas["opaque"]).any()  # what --anchor changes, which an .stl cannot hold


def test_closeup_billboard_without_a_render_is_refused(tmp_path, capsys):
    """``closeup --billboard -o scene.glb`` (a scene mesh alone) was accepted and wrote the mesh ``closeup -o
    scene.glb`` writes: a billboard is an orthographic render pasted over the close-up's place, so it shapes the renders
    alone, like --size and --z-scale, which are refused without a render. Refused by name now, before the DEM is read;
    with a render it passes."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32))
    out = tmp_path / "scene.glb"
    code, _, err = run(capsys, "-q", "closeup", dem, "--billboard", "-o", out)
    assert code == 2
    assert one_error_line(err, "closeup") == (
        "stepterrain closeup: error: --billboard applies only with a render (a .png --output, --png or --gif); got "
        f"it with the mesh --output {str(out)!r} alone")
    code, _, err = run(capsys, "-q", "closeup", dem, "--billboard", "--z-scale", "3", "-o", out)
    assert code == 2 and "--z-scale and --billboard apply only with a render" in err, err
    assert list(tmp_path.iterdir()) == [dem]
    # the scene mesh is the same with and without it (what made it a no-op)
    from stepterrain.closeup import ROI, CloseUp, closeup_scene

    heights = np.load(dem)
    roi = ROI.circle((14.0, 12.0), 5.0)
    scenes = [closeup_scene(heights, [CloseUp(roi, offset=(0.0, 0.0, 20.0), view=view)], device="cpu")
              for view in ("overview", "billboard")]
    assert np.array_equal(scenes[0].vertices, scenes[1].vertices) and np.array_equal(scenes[0].faces,
                                                                                      scenes[1].faces)


def test_a_roi_or_lens_in_degrees_of_a_dem_in_degrees_names_its_centre_in_metres(tmp_path, capsys):
    """closeup --roi=-105.5,40.1,0.05 on the Front Range tile (in degrees, read as local metres) was refused as
    outside the extent, steps --lens warned it changed nothing, naming the metres extent only. Both now say it looks
    like degrees and give the centre in the DEM's metres, where a close-up then lies."""
    import re

    from stepterrain.io import lonlat_as_local_metres

    from .conftest import shared_file

    source = str(shared_file("front_range_srtmgl3_3arcsec.npz"))
    xs, ys = lonlat_as_local_metres(st.load_dem(source).crs, [-105.5], [40.1])
    out = tmp_path / "c.png"
    assert cli.main(["closeup", source, "--roi=-105.5,40.1,0.05", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    found = re.search(r"it looks like degrees.*the centre \(-105\.5, 40\.1\) is there \((\S+), (\S+)\)", err)
    assert found and not out.exists(), err
    assert (float(found[1]), float(found[2])) == pytest.approx((xs[0], ys[0]), abs=0.01)
    assert cli.main(["-q", "closeup", source, f"--roi={found[1]},{found[2]},4000", "-o", str(out)]) == 0
    capsys.readouterr()
    assert cli.main(["-q", "steps", source, "--lens=-105.5,40.1,0.05", "-o", str(tmp_path / "s.glb")]) == 0
    err = capsys.readouterr().err
    assert re.search(r"changes nothing.*it looks like degrees.*\(-105\.5, 40\.1\) is there", err), err


def test_band_picks_the_band_of_a_multiband_geotiff_input(tmp_path, capsys):
    """A multi-band GeoTIFF (a DSM and a DTM, or years of a survey) was read as its first band by every command, and
    no option reached the others: load_dem's band= had none on the command line. --band N reads band N (steps,
    closeup, texture through the INPUT options, and info); a band the file lacks, a single-band format, the embedded
    DEM and a mesh file are refused naming --band."""
    rasterio = pytest.importorskip("rasterio")
    import json

    import trimesh

    z = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32)
    path = tmp_path / "stack.tif"
    with rasterio.open(path, "w", driver="GTiff", width=7, height=6, count=3, dtype="float32", crs="EPSG:32611",
                       transform=rasterio.Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)) as ds:  # fmt: skip
        for band in (1, 2, 3):
            ds.write(z + 1000.0 * band, band)
    code, out, _ = run(capsys, "info", path, "--band", "2", "--json")
    assert code == 0 and json.loads(out)["height_range"] == [2000.0, 2011.0]
    code, _, err = run(capsys, "-q", "steps", path, "--band", "3", "--interval", "2", "-o", tmp_path / "b3.ply")
    assert code == 0, err
    mesh = trimesh.load(tmp_path / "b3.ply", process=False)
    assert 3000.0 <= mesh.bounds[0][2] and mesh.bounds[1][2] <= 3012.0
    assert cli._load_input(str(path), None).height_range == (1000.0, 1011.0)  # the first band without --band

    np.save(tmp_path / "one.npy", z)
    for argv, message in [
        (("info", path, "--band", "4"), "--band must be between 1 and 3 for"),
        (("-q", "steps", tmp_path / "one.npy", "--band", "2", "-o", tmp_path / "x.ply"),
         "--band applies to GDAL rasters only"),
        (("info", "--band", "2"), "--band applies to a GeoTIFF INPUT; the embedded DEM holds one band"),
        (("info", tmp_path / "b3.ply", "--band", "2"), "--band applies to a GeoTIFF DEM;"),
    ]:
        code, _, err = run(capsys, *argv)
        assert code == 2 and message in err, err
    assert not (tmp_path / "x.ply").exists()


def test_batch_band_reaches_every_file_its_fingerprint_and_metadata(tmp_path, capsys):
    """steps, closeup, texture and info got --band N; batch had none (nor batch(band=)), so a folder of multi-band
    GeoTIFFs (a DSM and a DTM each) or one to tile was stepped from its first band only. band= now reaches load_dem
    for every file (read by the workers: it travels with the options) and for the raster cut into tiles, is
    recorded as 'band' in every output's metadata and enters the fingerprint (a rerun with another band redoes the
    items); an array, a Terrain or a series is refused, a file of one band fails as load_dem refuses it, and the
    command line's --band does the same (the embedded DEM and a folder of single-band files refused naming it)."""
    rasterio = pytest.importorskip("rasterio")
    import trimesh

    from stepterrain import batch
    from stepterrain.errors import InvalidInputError

    from .test_export import glb_json

    z = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32)
    folder = tmp_path / "tiles"
    folder.mkdir()
    for k, name in enumerate(("a.tif", "b.tif")):
        with rasterio.open(folder / name, "w", driver="GTiff", width=7, height=6, count=2, dtype="float32",
                           crs="EPSG:32611", transform=rasterio.Affine(30.0, 0.0, 500000.0 + 180 * k, 0.0, -30.0,
                                                                       4000000.0)) as ds:  # fmt: skip
            ds.write(z, 1)
            ds.write(z + 1000.0, 2)

    def z_range(path):
        bounds = trimesh.load(path, process=False).bounds
        return bounds[0][2], bounds[1][2]

    out = tmp_path / "out"
    report = batch(folder, out, interval=2.0, scheduler="serial", format=".ply", band=2)
    assert report.ok and len(report.done) == 2
    assert all(1000.0 <= lo and hi <= 1012.0 for lo, hi in (z_range(r.path) for r in report.done))
    assert len(batch(folder, out, interval=2.0, scheduler="serial", format=".ply", band=2).skipped) == 2
    first = batch(folder, out, interval=2.0, scheduler="serial", format=".ply", band=1)
    assert len(first.done) == 2 and all(z_range(r.path)[1] <= 12.0 for r in first.done)  # redone, not skipped

    glb = batch(folder / "a.tif", tmp_path / "tiled", tile_size=3, interval=2.0, scheduler="serial", band=2)
    assert glb.ok and len(glb.done) == 4
    extras = glb_json(Path(glb.done[0].path))["meshes"][0]["extras"]
    assert extras["band"] == 2 and extras["isovalues"][0] >= 1000.0
    assert glb_json(Path(batch(folder, tmp_path / "g", interval=2.0, scheduler="serial",
                               band=2).done[0].path))["meshes"][0]["extras"]["band"] == 2

    np.save(tmp_path / "one.npy", z)
    np.save(tmp_path / "series.npy", np.stack([z, z]))
    for source, tile, band, message in [
        (z, 3, 2, "band applies to DEM files (a GeoTIFF's bands), read by load_dem; got a ndarray source"),
        (tmp_path / "series.npy", None, 2, "band applies to GDAL rasters only; the (T, H, W) series"),
        (folder / "a.tif", 3, 3, "band must be between 1 and 2 for"),  # one raster to tile: read before any work
    ]:
        with pytest.raises(InvalidInputError, match=re.escape(message)):
            batch(source, tmp_path / "x", tile_size=tile, interval=2.0, scheduler="serial", band=band)
    with pytest.raises(InvalidInputError, match="band must be a positive 1-based band number; got 0"):
        batch(folder, tmp_path / "x", interval=2.0, scheduler="serial", band=0)
    failed = batch([tmp_path / "one.npy", folder / "a.tif"], tmp_path / "y", interval=2.0, scheduler="serial",
                   band=2)
    assert len(failed.done) == 1 and "band applies to GDAL rasters only" in failed.failed[0].error

    code, _, err = run(capsys, "-q", "batch", folder, "--band", "2", "--interval", "2", "--scheduler", "serial",
                       "--format", ".ply", "-o", tmp_path / "cli")
    assert code == 0, err
    assert all(z_range(p)[0] >= 1000.0 for p in (tmp_path / "cli").glob("*.ply"))
    code, _, err = run(capsys, "-q", "batch", "--band", "2", "--scheduler", "serial", "-o", tmp_path / "emb")
    assert code == 2 and "--band applies to a GeoTIFF INPUT; the embedded DEM holds one band" in err
    npys = tmp_path / "npys"
    npys.mkdir()
    np.save(npys / "one.npy", z)
    code, _, err = run(capsys, "-q", "batch", npys, "--band", "2", "--interval", "2", "--scheduler", "serial",
                       "-o", tmp_path / "n")
    assert code == 2 and "--band 2 applies to GDAL rasters only; the only input holds one band" in err, err
    assert not (tmp_path / "x").exists() and not (tmp_path / "emb").exists()


def test_steps_png_counts_the_mesh_against_the_render_budget(tmp_path, capsys):
    """steps --png checked the render's window alone (5.5 MiB at --size 400x300) while the render's copies of the mesh
    grow with it: the embedded DEM at --interval 5 (18 M faces) took 1.2-1.5 GiB in the render step. Now the DEM's
    surface (the fewest faces the mesh can have) is checked before stepping, and the stepped mesh before the render,
    each naming the mesh's size and options that make it smaller (a smaller --size does not); nothing is written."""
    rng = np.random.default_rng(0)
    big, small = tmp_path / "big.npy", tmp_path / "small.npy"
    np.save(big, rng.random((80, 80)) * 100)
    np.save(small, rng.random((30, 30)) * 100)
    args = ["--interval", "2", "--png", tmp_path / "r.png", "--size", "64x48", "-o", tmp_path / "m.glb"]
    code, _, err = run(capsys, "--memory-budget", "1MiB", "steps", big, *args)
    assert code == 2
    assert "stepping" not in err  # refused from the DEM's surface, before the step
    assert ("error: an off-screen render of 64 x 48 pixels (--size 64x48) of a mesh of at least 12,482 faces and "
            "6,400 vertices would need") in err
    assert "give a larger --interval, --coarsen N or a --crop, or leave --png out" in err
    code, _, err = run(capsys, "--memory-budget", "12MiB", "steps", small, *args)  # the mesh fits, its render not
    assert code == 2
    assert re.search(r"\n[^\n]*error: an off-screen render of 64 x 48 pixels \(--size 64x48\) of a mesh of "
                     r"[0-9,]+ faces and [0-9,]+ vertices would need [0-9.]+ MiB, over the memory budget of 12\.0 MiB",
                     err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.npy", "small.npy"]


def test_steps_checks_the_mesh_file_against_the_budget_before_the_render(tmp_path, capsys, monkeypatch):
    """The mesh file's write (its writers' copies: ~24 bytes a vertex and 40 a face for .glb, 352 a face for .stl) is
    checked as soon as the mesh is known: a write refused after the render wasted the render."""
    from stepterrain import render

    def no_render(*args, **kwargs):
        raise AssertionError("the render started before the write was checked")

    monkeypatch.setattr(render, "render_mesh", no_render)
    dem = tmp_path / "small.npy"
    np.save(dem, np.random.default_rng(0).random((30, 30)) * 100)
    code, _, err = run(capsys, "--memory-budget", "40MiB", "steps", dem, "--interval", "2", "--png", tmp_path / "r.png",
                       "--size", "64x48", "-o", tmp_path / "m.stl")
    assert code == 2
    assert re.search(r"error: writing '.*m\.stl' \(\.stl, a mesh of [0-9,]+ faces and [0-9,]+ vertices\) would "
                     r"need", err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.npy"]


_UNITS = {"KiB": 1024, "MiB": 1024**2, "GiB": 1024**3, "TiB": 1024**4}


def _suggested_budget(message: str) -> int:
    """The bytes of a budget refusal's "to at least 20GiB", checked to cover the need it states (and not by 10x)."""
    need = re.search(r"would need ([\d,.]+) (MiB|bytes)", message)
    figure = re.search(r"to at least (\d+)(KiB|MiB|GiB|TiB)\b", message)
    assert need and figure, message
    need_bytes = float(need.group(1).replace(",", "")) * (1024**2 if need.group(2) == "MiB" else 1)
    suggested = int(figure.group(1)) * _UNITS[figure.group(2)]
    assert need_bytes <= suggested < 10 * max(need_bytes, 1024), message
    return suggested


def test_a_refusal_over_the_memory_budget_suggests_a_budget_that_covers_the_need(tmp_path, capsys):
    """A run over the memory budget said "e.g. --memory-budget 32GiB" whatever it needed: 32 GiB for a run that
    needed a megabyte, and 32 GiB again for one that needed 100 GiB (which refused again). The refusal suggests the
    need rounded up to one significant digit of its unit now, on the command line and in the library alike, and
    following it the run goes through."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    budget = "1KiB"
    for _ in range(4):  # each refusal (the mesh, then its writing) suggests enough for itself
        code, out, err = run(capsys, "steps", dem, "-o", tmp_path / "m.glb", "--memory-budget", budget)
        if code == 0:
            break
        assert code == 2 and "--memory-budget SIZE" in err and "32GiB" not in err, err
        budget = str(_suggested_budget(err))
    assert code == 0 and (tmp_path / "m.glb").exists(), err
    surface = np.zeros((40, 40)) + np.arange(40)
    with pytest.raises(st.errors.OutputTooLargeError, match="stepterrain.set_memory_budget") as refused:
        st.stepped(surface, interval=1, memory_budget=1024)
    mesh = st.stepped(surface, interval=1, memory_budget=_suggested_budget(str(refused.value)))
    assert len(mesh.faces) > 0
    with pytest.raises(st.errors.OutputTooLargeError) as refused:  # a need over 32 GiB: not 32 GiB again
        st._compaction.check_budget(100 * 1024**3, "the stepped mesh", 1024**3)
    assert "to at least 100GiB" in str(refused.value)


@pytest.mark.parametrize("command", ["steps", "closeup", "texture", "batch"])
def test_coarsen_1_is_refused_as_keeping_every_node(capsys, tmp_path, command):
    """--coarsen 1 was accepted and did nothing (Terrain.coarsen(1) is the terrain itself, as documented), while the
    other options that do nothing are refused by name: it is refused now, before the DEM is read, saying it keeps
    every node; --coarsen 2 still runs."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    out = tmp_path / ("out" if command == "batch" else "o.glb" if command == "steps" else "o.png")
    args = [command, dem, "--coarsen", "1", "-o", out]
    if command == "closeup":
        args += ["--center", "5,-5", "--radius", "3"]
    code, _, err = run(capsys, *args)
    assert code == 2, err
    assert "--coarsen" in err and "1 keeps every node" in err and "Traceback" not in err, err
    assert not out.exists()
    if command == "steps":
        code, _, err = run(capsys, command, dem, "--coarsen", "2", "-o", out)
        assert code == 0 and out.stat().st_size > 0, err


@pytest.mark.parametrize("command", ["texture", "globe"])
def test_a_textured_obj_whose_side_file_name_is_too_long_is_refused_before_any_work(capsys, tmp_path, command):
    """An OBJ name that fits (245 + 4 bytes) whose texture image beside it does not (``<stem>_terrain_texture.png``,
    the globe's ``<stem>_material_0.png``: over 255 bytes) failed "File name too long" only after all the work, -o
    (texture's image) already written. Refused before any work now, naming the option and the side file."""
    import os

    from PIL import Image

    limit = os.pathconf(tmp_path, "PC_NAME_MAX") if hasattr(os, "pathconf") else 255
    obj = tmp_path / ("a" * (limit - 10) + ".obj")
    if command == "texture":
        dem = tmp_path / "dem.npy"
        np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
        args, option, side = ["texture", dem, "-o", tmp_path / "t.png", "--mesh", obj], "--mesh", "_terrain_texture"
    else:
        picture = tmp_path / "earth.png"
        Image.fromarray(np.full((32, 64, 3), (200, 30, 30), np.uint8)).save(picture)
        args = ["globe", "--face-size", "9", "--error", "0", "--no-camera", "--texture", picture, "-o", obj]
        option, side = "--output", "_material_0"
    before = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = run(capsys, *args)
    assert code == 2, err
    assert f"{option} {str(obj)!r} writes 'a" in err and f"{side}.png' beside it" in err, err
    assert f"over the {limit} its folder allows" in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_info_counts_the_levels_and_walls_a_ply_keeps(tmp_path, capsys):
    """`stepterrain info` of a stepped .ply said nothing of the levels and walls it keeps (its face attributes
    ``level`` and ``wall``, which the other formats drop): now how many levels its faces lie on (a solid's skirts
    and base, level -1, on none) and how many faces are walls, as the mesh itself counts them."""
    import json

    from stepterrain.export import save_mesh

    solid = st.stepped(np.add.outer(np.arange(12.0), np.sin(np.arange(10.0))) * 4.0 + 0.3, interval=5.0,
                       spacing=(10.0, -10.0), solid=True)
    level, wall = solid.face_attributes["level"], solid.face_attributes["wall"]
    assert (level == -1).any() and wall.any()
    for ext in (".ply", ".glb"):
        code, out, err = run(capsys, "info", save_mesh(solid, tmp_path / f"solid{ext}"), "--json")
        assert code == 0, err
        summary = json.loads(out)
        if ext == ".ply":
            assert summary["levels"] == len(set(level.tolist()) - {-1}) == len(solid.metadata["isovalues"])
            assert summary["wall_faces"] == int(wall.sum())
            assert summary["watertight"] is True and summary["faces"] == len(solid.faces)
        else:  # a glTF holds no face attributes: nothing is said, rather than 0
            assert "levels" not in summary and "wall_faces" not in summary


def as_a_terminal_job() -> None:
    """``preexec_fn`` of a child that a test interrupts: SIGINT and SIGHUP at their defaults, as a terminal's job has
    them. A test run under nohup, or put in the background by a non-interactive shell (`.ci/run &`), ignores both, a
    child inherits that, and Python then installs no KeyboardInterrupt handler: the signals did nothing (exit 0)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def run_as_a_terminal_job(script: str, folder: Path) -> subprocess.CompletedProcess:
    """``script`` written to ``folder``/run.py and run there in a child (:func:`as_a_terminal_job`) that imports this
    checkout's stepterrain, its output captured."""
    (folder / "run.py").write_text(script)
    return subprocess.run([sys.executable, str(folder / "run.py")], capture_output=True, text=True, timeout=120,
                          cwd=folder, env={**os.environ, "PYTHONPATH": str(Path(st.__file__).parents[1])},
                          preexec_fn=as_a_terminal_job)


@needs_render
def test_ctrl_c_as_vtk_loads_ends_the_run_as_interrupted(tmp_path):
    """Ctrl-C while VTK's rendering modules loaded (the first render of `steps --png`, about a second on a busy
    machine) crashed the process (SIGSEGV, a core dump) or ended it with a 30-line traceback of "ImportError: Failed to
    load vtkRenderingContextOpenGL2" and exit status 1. The modules now load whole, then the run ends as after any
    Ctrl-C: exit status 130, "stepterrain: interrupted", no file written."""

    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(24.0), np.arange(24.0)).astype(np.float32))
    # the SIGINT comes as VTK's 2D rendering module loads (pyvista.plotting's), as a user's Ctrl-C may
    script = f"""
import os, signal, sys
import vtkmodules
from stepterrain.cli import main
load = vtkmodules.VTKLoader.exec_module
def exec_module(self, module):
    if module.__name__ == "vtkmodules.vtkRenderingContext2D":
        os.kill(os.getpid(), signal.SIGINT)
    load(self, module)
vtkmodules.VTKLoader.exec_module = exec_module
sys.exit(main(["-q", "steps", {str(dem)!r}, "--interval", "10", "--device", "cpu", "-o", {str(tmp_path / "t.glb")!r},
               "--png", {str(tmp_path / "t.png")!r}, "--size", "64x48"]))
"""
    done = run_as_a_terminal_job(script, tmp_path)
    assert done.returncode == 130, (done.returncode, done.stderr[-2000:])
    assert done.stderr.strip().splitlines() == ["stepterrain: interrupted"], done.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy", "run.py"]


def test_ctrl_c_as_the_package_loads_is_not_ignored(tmp_path):
    """trimesh catches every exception of its optional imports, KeyboardInterrupt too: Ctrl-C in the first second of
    a command (trimesh importing scipy, as `import stepterrain` loads it) was swallowed and the command ran on to its
    end and wrote its output (or failed later with "TypeError: unsupported operand type(s) for |: 'ExceptionWrapper'
    and 'NoneType'"). The package's imports now hold the signal back and it ends the start-up once they are done."""
    import signal

    out = tmp_path / "t.glb"
    script = f"""
import os, signal, sys
class Interrupt:
    def find_spec(self, name, path=None, target=None):
        if name == "scipy.spatial":  # trimesh's import, in its try block
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None
sys.meta_path.insert(0, Interrupt())
from stepterrain.cli import main
sys.exit(main(["-q", "steps", "--interval", "10", "--device", "cpu", "-o", {str(out)!r}]))
"""
    done = run_as_a_terminal_job(script, tmp_path)
    assert done.returncode == -signal.SIGINT, (done.returncode, done.stderr[-2000:])  # as after any Ctrl-C at start
    assert done.stderr.rstrip().endswith("KeyboardInterrupt"), done.stderr[-2000:]
    assert not out.exists()


def test_batch_output_that_is_a_file_is_refused_naming_the_option(tmp_path, capsys):
    """`stepterrain batch -o /dev/stdout` (or -o an existing file) said "error: output_dir '/dev/stdout' exists and is
    not a folder": the library's argument, which the command line never named; it names --output now."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    taken = tmp_path / "taken.glb"
    taken.write_bytes(b"mine")
    for out in (taken, "/dev/stdout"):
        code, _, err = run(capsys, "-q", "batch", dem, "--interval", "2", "--scheduler", "serial", "-o", out)
        assert code == 2 and err.strip() == f"stepterrain batch: error: --output {str(out)!r} exists and is not a " \
                                            "folder", err
    assert taken.read_bytes() == b"mine" and sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy", "taken.glb"]


def test_batch_output_dash_is_refused_as_standard_output_writing_nothing(tmp_path, capsys, monkeypatch):
    """`stepterrain batch -o -` made a folder named '-' in the working directory and wrote every mesh there, where a
    dash reads as standard output: it is refused now, naming --output, before anything is read or written (a folder
    named '-' is still ./-)."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32))
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "-q", "batch", dem, "--interval", "2", "--scheduler", "serial", "-o", "-")
    assert code == 2 and out == ""
    assert err.strip() == ("stepterrain batch: error: --output '-' would be standard output, which is no folder: batch "
                           "writes a mesh file per item into the folder --output names; give a folder (./- for one "
                           "named '-')"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy"]
    code, _, err = run(capsys, "-q", "batch", dem, "--interval", "2", "--scheduler", "serial", "-o", "./-")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "-").glob("*.glb")) == ["dem.glb"]


@pytest.mark.skipif(not hasattr(__import__("signal"), "SIGHUP"), reason="POSIX's SIGHUP")
def test_sighup_ends_a_run_as_sigterm_does(tmp_path):
    """SIGHUP (the terminal closed, the ssh connection dropped) killed a command outright: the file being written
    stayed as a hidden partial file ('.terrain.glb.1a2b3c4d.tmp', tens of MB for a large mesh). It now ends the run
    as SIGTERM does: exit status 129, "stepterrain: hung up", the partial file removed, the old output kept."""

    dem, out = tmp_path / "dem.npy", tmp_path / "terrain.glb"
    np.save(dem, np.add.outer(np.arange(12.0), np.arange(12.0)).astype(np.float32))
    out.write_bytes(b"the old terrain")
    script = f"""
import os, signal, sys
import stepterrain.export as export
from stepterrain.cli import main
def writer(mesh, tmp, target, bounds, *shared):
    tmp.write_bytes(b"glTF half a file")
    os.kill(os.getpid(), signal.SIGHUP)
export._WRITERS[".glb"] = writer
if __name__ == "__main__":
    signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as a shell's command has it, also under a runner ignoring it
    sys.exit(main(["-q", "steps", {str(dem)!r}, "--interval", "2", "--device", "cpu", "-o", {str(out)!r}]))
"""
    done = run_as_a_terminal_job(script, tmp_path)
    assert done.returncode == 129, (done.returncode, done.stderr[-2000:])
    assert done.stderr.strip().splitlines() == ["stepterrain: hung up"], done.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy", "run.py", "terrain.glb"]
    assert out.read_bytes() == b"the old terrain"


@pytest.mark.parametrize("signame, code, line", [("SIGINT", 130, "stepterrain: interrupted"),
                                                 ("SIGHUP", 129, "stepterrain: hung up")])
def test_batch_ctrl_c_as_the_workers_start_prints_no_worker_tracebacks(tmp_path, signame, code, line):
    """The terminal's Ctrl-C reaches the whole foreground process group: the LocalCluster's worker processes too,
    which were importing the package as they started (multiprocessing's spawn runs the main script) and each printed a
    KeyboardInterrupt traceback of some thirty lines above the command's own "stepterrain: interrupted". The
    workers now start with SIGINT blocked: the command's process closes them after a Ctrl-C, and ends as documented
    (exit status 130, one line). A closed terminal's SIGHUP (the shell sends it to the job's process group) killed
    multiprocessing's resource tracker, whose relaunched successor printed a KeyError traceback for each of the
    workers' semaphores, and the workers, whose lost connections printed a CommClosedError traceback: both now start
    with SIGHUP blocked too, and the run ends with exit status 129 and one line."""
    import os
    import signal
    import subprocess
    import sys
    import time

    psutil = pytest.importorskip("psutil")
    pytest.importorskip("distributed")
    out = tmp_path / "tiles"
    proc = subprocess.Popen([sys.executable, "-m", "stepterrain", "-q", "batch", "--tile", "32", "--device", "cpu",
                             "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path, start_new_session=True,  # its own process group, as a terminal's job
                            env={**os.environ, "PYTHONPATH": str(Path(st.__file__).parents[1])},
                            preexec_fn=as_a_terminal_job)
    try:
        workers: list = []
        deadline = time.monotonic() + 90
        while len(workers) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
            try:
                workers = [child for child in psutil.Process(proc.pid).children(recursive=True)
                           if "spawn_main" in " ".join(child.cmdline())]
            except psutil.Error:
                workers = []
        assert len(workers) == 2, "the LocalCluster's two worker processes did not start"
        time.sleep(0.3)  # they import stepterrain (seconds)
        os.killpg(proc.pid, getattr(signal, signame))  # the user's Ctrl-C (or closed terminal), to the whole group
        _, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == code, (proc.returncode, err[-3000:])
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    assert err.strip().splitlines() == [line], err[-3000:]
    assert not out.exists() or not [p for p in out.iterdir() if p.suffix in (".glb", ".tmp") and
                                    p.name.startswith(".")]  # no partial file left


def test_interrupt_of_a_dask_call_not_yet_started_logs_no_name_error(caplog):
    """A SIGTERM (or Ctrl-C) as `stepterrain batch` waited on a dask call that the client's busy event loop had not
    started yet ended, after "stepterrain: terminated", with a traceback from the loop thread: distributed.utils.sync's
    `cancel` reads its `future` before it is set ("NameError: cannot access free variable 'future'"), which tornado
    logs. batch's connections drop that record (and only it) from tornado's log."""
    import logging
    import os
    import signal
    import threading
    import time

    pytest.importorskip("distributed")
    from distributed.utils import LoopRunner, sync

    from stepterrain import batch as batch_module

    runner = LoopRunner(asynchronous=False)
    runner.start()
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        batch_module._quiet_dask_sync_cancel()  # as _connect does, once a process
        batch_module._quiet_dask_sync_cancel()
        loop = runner.loop
        loop.add_callback(time.sleep, 1.0)  # the loop is busy: the call below does not start before the interrupt
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
        caplog.set_level(logging.ERROR, logger="tornado.application")
        with pytest.raises(KeyboardInterrupt):
            sync(loop, _sleep_briefly)
        time.sleep(1.5)  # the loop runs sync's `cancel`, then the call
        errors = [record for record in caplog.records if record.exc_info and isinstance(record.exc_info[1], NameError)]
        loop.add_callback(_raise_name_error)  # any other NameError in a callback is still logged
        time.sleep(0.3)
        others = [record for record in caplog.records if record.exc_info and isinstance(record.exc_info[1], NameError)]
    finally:
        signal.signal(signal.SIGINT, before)
        runner.stop()
    assert errors == []
    assert len(others) == 1
    assert len(logging.getLogger("tornado.application").filters) == 1  # installed once


def _raise_name_error() -> None:
    raise NameError("name 'future' is not defined", name="future")


async def _sleep_briefly() -> None:
    import asyncio

    await asyncio.sleep(0.01)


@pytest.mark.parametrize("height_range", [(1e7, 1e7 + 3.0), (-2e7 - 3.0, -2e7), (3e6, 3e6 + 0.25), (0.0, 11.4),
                                          (315.0, 2295.0)])
def test_default_interval_is_one_float32_holds(height_range):
    """The default interval (``nice_interval``, steps' and batch's when neither --interval nor --levels is given)
    aimed at ~15 steps whatever float32 holds: heights 1e7 to 1e7 + 3 (float32 steps of 1 there) got 0.2, which
    ``isovalues`` refused as too small, so ``stepterrain steps dem.npy`` failed naming an --interval nobody gave."""
    interval = st.stepped.nice_interval(height_range)
    values = st.isovalues(height_range, interval=interval)  # raised InvalidInputError
    assert values[0] <= np.float32(height_range[0]) and values[-1] >= np.float32(height_range[1])
    mantissa = interval / 10.0 ** math.floor(math.log10(interval))
    assert any(math.isclose(mantissa, m) for m in (1.0, 2.0, 2.5, 5.0))
    if height_range == (315.0, 2295.0):
        assert interval == 100.0  # ranges float32 resolves as they are keep their interval


def test_steps_default_interval_on_heights_far_from_zero(tmp_path, capsys):
    """``stepterrain steps`` without --interval on a DEM of heights 1e7 to 1e7 + 3 (a survey's offset heights in mm,
    say) stepped instead of refusing the interval it picked itself; every vertex on an isovalue (γ = 1)."""
    heights = (1e7 + np.random.default_rng(0).random((12, 14)) * 3.0).astype(np.float32)
    np.save(tmp_path / "offset.npy", heights)
    code, _, err = run(capsys, "steps", tmp_path / "offset.npy", "-o", tmp_path / "offset.ply")
    assert code == 0, err
    assert "using --interval" in err
    mesh = st.export.read_mesh(tmp_path / "offset.ply")
    levels = np.asarray(mesh.metadata["isovalues"], dtype=np.float32)
    assert len(mesh.faces) > 0 and np.isin(mesh.vertices[:, 2].astype(np.float32), levels).all()


def test_floor_help_tells_the_default_with_levels(tmp_path, capsys):
    """``steps --help`` said --floor defaults to "one step below"; with --levels 1000,1200 (a step of 200) the solid
    was closed 20 below (a tenth of the levels' span), and with one level 0.1 below: a slab, not a step. The help
    now says so, and the floors are what it says."""
    code, out, _ = run(capsys, "steps", "--help")
    assert code == 0
    text = " ".join(out.split())
    assert "--levels a tenth of their span, at least 0.1" in text
    heights = np.array([[1050.0, 1100.0, 1150.0], [1120.0, 1190.0, 1210.0]], dtype=np.float32)
    np.save(tmp_path / "hill.npy", heights)
    for levels, floor in (("1000,1200", 980.0), ("1100", 1099.9)):
        out = tmp_path / f"solid{len(levels)}.ply"
        code, _, err = run(capsys, "steps", tmp_path / "hill.npy", "--levels", levels, "--solid", "-o", out)
        assert code == 0, err
        assert st.export.read_mesh(out).vertices[:, 2].min() == pytest.approx(floor)
    code, _, err = run(capsys, "steps", tmp_path / "hill.npy", "--interval", "200", "--solid", "-o", tmp_path / "i.ply")
    assert code == 0, err
    assert st.export.read_mesh(tmp_path / "i.ply").vertices[:, 2].min() == 800.0  # the lowest isovalue 1000, less 200


def test_closeup_help_names_what_obj_keeps_of_the_anchors(tmp_path, capsys):
    """``closeup -o`` said every mesh format but .stl holds the scene's vertex colours; an .obj's ``v x y z r g b``
    lines drop the alpha, so its anchors (transparent by their transfer function in .glb, .ply, .3mf) come out
    opaque. The help now says so, and the file is as it says. (The .obj run gave ``--anchor linear``; since an
    .obj --output alone refuses --anchor, whose every preset wrote the same file, it takes the default, linear.)"""
    code, out, _ = run(capsys, "closeup", "--help")
    assert code == 0
    assert ".obj holds RGB only, the anchors opaque" in " ".join(out.split())
    heights = np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32)
    np.save(tmp_path / "hill.npy", heights)
    alphas = {}
    for ext in (".ply", ".obj"):
        out_path = tmp_path / f"scene{ext}"
        anchor = ["--anchor", "linear"] if ext == ".ply" else []
        code, _, err = run(capsys, "closeup", tmp_path / "hill.npy", "--roi-relative", "0.5,0.5,0.25", *anchor,
                           "-o", out_path)
        assert code == 0, err
        alphas[ext] = st.export.read_mesh(out_path).visual.vertex_colors[:, 3]
    assert (alphas[".ply"] < 255).any() and (alphas[".obj"] == 255).all()


def test_closeup_color_takes_r_g_b_as_its_message_says(tmp_path, capsys):
    """``closeup --color`` refused ``1,0,0`` with "--color must be a matplotlib color (name, '#rrggbb' or RGB in
    [0, 1])": the message offered RGB, which no command line could give (matplotlib reads the string "1,0,0" as no
    color). ``r,g,b`` in [0, 1] is now that color: the scene is the one ``--color red`` gives, and one out of [0, 1]
    is refused naming the option."""
    base = ["-q", "closeup", "--coarsen", "8", "--roi-relative", "0.5,0.5,0.15", "--device", "cpu"]
    code, _, err = run(capsys, *base, "--color", "1,0,0", "-o", tmp_path / "rgb.ply")
    assert code == 0, err
    assert run(capsys, *base, "--color", "red", "-o", tmp_path / "named.ply")[0] == 0
    rgb, named = (st.export.read_mesh(tmp_path / f"{name}.ply") for name in ("rgb", "named"))
    assert np.array_equal(rgb.visual.vertex_colors, named.visual.vertex_colors)
    anchor = (rgb.visual.vertex_colors[:, :3] == (255, 0, 0)).all(axis=1)
    assert anchor.any()
    for bad in ("1,2,0", "nan,0,0"):  # NaN: matplotlib took it, a colour cast from NaN with a warning, exit 0
        code, _, err = run(capsys, *base, "--color", bad, "-o", tmp_path / "bad.ply")
        assert code == 2
        assert one_error_line(err, "closeup").startswith("stepterrain closeup: error: argument --color: expected a "
                                                         "matplotlib color")
        assert not (tmp_path / "bad.ply").exists()


def test_a_closeup_color_of_nan_is_refused():
    """matplotlib's to_rgb passes NaN in a tuple through: CloseUp(color=(nan, 0, 0)) was accepted, and its anchor's
    colour cast from NaN ('invalid value encountered in cast') at the render or the scene."""
    from stepterrain.closeup import ROI, CloseUp

    with pytest.raises(st.errors.InvalidInputError, match=r"close-up color must be a matplotlib color .*nan"):
        CloseUp(ROI.circle((0.0, 0.0), 1.0), color=(math.nan, 0.0, 0.0))


@pytest.mark.parametrize("command", ["texture", "globe"])
@pytest.mark.parametrize("side", ["image", "mtl"])
def test_a_textured_obj_whose_side_file_is_a_folder_is_refused_before_any_work(capsys, tmp_path, command, side):
    """A folder where a textured OBJ writes its .mtl or texture image (``t_terrain_texture.png``, the globe's
    ``t_material_0.png``) failed "cannot write ...: it is a folder" only after all the work: ``texture -o t.png
    --mesh t.obj`` had written t.png already, and the globe's --png render. Refused before any work now, as a folder
    at an output's own name is, naming the option and the side file."""
    from PIL import Image

    obj = tmp_path / "t.obj"
    if command == "texture":
        dem = tmp_path / "dem.npy"
        np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
        args = ["texture", dem, "-o", tmp_path / "t.png", "--mesh", obj]
        option, image = "--mesh", "t_terrain_texture.png"
    else:
        picture = tmp_path / "earth.png"
        Image.fromarray(np.full((32, 64, 3), (200, 30, 30), np.uint8)).save(picture)
        args = ["globe", "--face-size", "9", "--texture", picture, "-o", obj, "--png", tmp_path / "r.png",
                "--size", "64x48"]
        option, image = "--output", "t_material_0.png"
    name = image if side == "image" else "t.mtl"
    (tmp_path / name).mkdir()
    before = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = run(capsys, "-q", *args, "--device", "cpu")
    assert code == 2, err
    line = one_error_line(err, command)
    assert f"{option} {str(obj)!r} writes {name!r} beside it" in line and "a folder" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


@pytest.mark.parametrize("heights", [(-3.4028235e38, 3.4028235e38), (3.3e38, 3.4028235e38)])
def test_steps_default_interval_near_the_float32_maximum_is_refused_naming_the_pick(tmp_path, capsys, heights):
    """Without --interval, steps picked nice_interval of the height range: np.spacing of the float32 maximum is inf,
    an OverflowError traceback (exit 1); past it, the refusal named an --interval the user never gave."""
    assert cli.nice_interval(heights) > 0  # the library's pick, finite (it raised)
    grid = np.full((6, 7), heights[0], np.float32)
    grid[3:, 4:] = heights[1]
    np.save(tmp_path / "dem.npy", grid)
    code, _, err = run(capsys, "-q", "steps", tmp_path / "dem.npy", "-o", tmp_path / "x.ply")
    assert code == 2 and "Traceback" not in err, err
    assert "no --interval or --levels given, and the round interval" in err and "give --levels" in err, err
    assert not (tmp_path / "x.ply").exists()
    for base, message in (("nan", "--base must be finite; got nan"), ("1e39", "--base must fit in float32")):
        code, _, err = run(capsys, "-q", "steps", "--base", base, "-o", tmp_path / "x.ply")  # the base's own refusal
        assert code == 2 and err.startswith(f"stepterrain steps: error: {message}"), err


def test_steps_floor_beyond_float32_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    """``steps --solid --floor 1e39`` read the DEM and stepped the whole terrain before close_solid refused the
    floor; refused now before the DEM is read, and the library refuses it before stepping."""
    for floor, message in (("1e39", "--floor must fit in float32 (|x| < 3.4e+38); got 1e+39"),
                           ("-inf", "--floor must be finite; got -inf"), ("nan", "--floor must be finite; got nan")):
        code, _, err = run(capsys, "steps", "--solid", "--floor", floor, "-o", tmp_path / "x.ply")
        assert code == 2 and message in err, err
        assert "loading" not in err and "stepping" not in err, err
    from stepterrain import stepped as stepped_module

    def no_stepping(*args, **kwargs):
        raise AssertionError("stepped before the floor was checked")

    monkeypatch.setattr(stepped_module, "_stepped_arrays", no_stepping)
    terrain = st.Terrain.from_heights(np.arange(20, dtype=np.float32).reshape(4, 5), spacing=1.0)
    for floor, message in ((1e39, "floor must fit in float32"), (-math.inf, "floor must be finite")):
        with pytest.raises(st.InvalidInputError, match=message):
            st.stepped(terrain, interval=2.0, solid=True, floor=floor, device="cpu")


def test_closeup_spin_is_checked_at_parse_time_and_within_half_a_turn_a_frame(tmp_path, capsys):
    """``closeup --spin 1e308 --gif`` was accepted: every frame after the first showed the same capped turn (a spin
    of --fps turns per second stands still, faster ones alias). inf, NaN and 0 were refused only after the output
    paths and the other options were checked; now by argparse, naming --spin."""
    for spin in ("inf", "nan", "0", "-0", "1e400", "fast"):
        code, _, err = run(capsys, "closeup", "--spin", spin, "--gif", tmp_path / "a.gif", "-o", tmp_path / "x.png")
        assert code == 2, err
        assert f"argument --spin: expected a finite non-zero number of turns per second (negative: the other way); " \
               f"got '{spin}'" in err, err
    for spin, fps in (("1e308", "12"), ("12", "12"), ("-6.5", "12"), ("3", "5")):
        code, _, err = run(capsys, "closeup", "--spin", spin, "--fps", fps, "--gif", tmp_path / "a.gif", "-o",
                           tmp_path / "x.png")
        assert code == 2, err
        assert f"--spin must be at most half a turn a frame, |--spin| <= --fps / 2 = {float(fps) / 2:g} turns per " \
               f"second" in err and "loading" not in err, err
    assert sorted(tmp_path.iterdir()) == []


def test_texture_contours_with_no_line_drawn_warns_and_one_beyond_the_heights_is_drawn(tmp_path, capsys):
    """``texture --contours M`` with no contour line drawn (1e308, or 200 over heights 100 to 180) came out as without
    --contours, and nothing said so: a warning says it now, the texture still written (a tile no level crosses, in a
    set textured at one interval, is no mistake). A level just beyond the heights draws a line within half its width
    (the 100 m line along the upper edge of a hillside tile reaching 99.8 m, 181 at the corner of heights 100 to
    180): it is not refused."""
    from PIL import Image

    def texture(dem, *extra):
        out = tmp_path / f"t{len(list(tmp_path.iterdir()))}.png"
        code, _, err = run(capsys, "-q", "texture", dem, *extra, "-o", out)
        assert code == 0, err
        return np.asarray(Image.open(out)), err

    heights = np.add.outer(np.linspace(100.0, 140.0, 24), np.linspace(0.0, 40.0, 32)).astype(np.float32)
    np.save(tmp_path / "dem.npy", heights)
    plain, err = texture(tmp_path / "dem.npy")
    assert err == ""
    for interval in ("200", "1e308", "183"):
        image, err = texture(tmp_path / "dem.npy", "--contours", interval)
        assert err == f"stepterrain texture: warning: --contours {float(interval):g} drew no line: no contour level " \
                      f"(a multiple of it) passes within the heights 100 to 180; the texture is as without " \
                      f"--contours (a smaller interval draws lines)\n", err
        assert np.array_equal(image, plain)
    image, err = texture(tmp_path / "dem.npy", "--contours", "150")  # one level, 150, within them: drawn
    assert err == "" and not np.array_equal(image, plain), err
    image, err = texture(tmp_path / "dem.npy", "--contours", "181")  # 1 above the top corner, ~2.2 a texel: drawn
    assert err == "" and not np.array_equal(image, plain), err
    hillside = np.tile(np.linspace(60.0, 99.8, 32, dtype=np.float32), (24, 1))  # 60 to 99.8 m, no multiple of 100
    np.save(tmp_path / "hill.npy", hillside)
    plain, _ = texture(tmp_path / "hill.npy")
    image, err = texture(tmp_path / "hill.npy", "--contours", "100")
    assert err == "", err
    changed = np.nonzero((image != plain).any(axis=2))[1]
    assert changed.size and set(changed.tolist()) <= {30, 31}, changed  # the 100 m line along the east edge
    np.save(tmp_path / "flat.npy", np.full((6, 7), 100.0, np.float32))
    assert texture(tmp_path / "flat.npy", "--contours", "50")[1] == ""  # flat on a level: all line
    assert texture(tmp_path / "flat.npy", "--contours", "30")[1] == "stepterrain texture: warning: --contours 30 " \
        "drew no line: no contour level (a multiple of it) passes within the heights 100 to 100; the texture is as " \
        "without --contours (flat ground draws a line only exactly on a level)\n"


@pytest.mark.parametrize("fractions", ["0.5,0.5,1e308", "1e308,0.5,0.1", "0.5,-1e308,0.1", "0.5,0.5,1e12"])
def test_closeup_roi_relative_beyond_the_extent_is_refused_naming_it(tmp_path, capsys, fractions):
    """A --roi-relative whose fractions overflow the centre or the radius was refused as the library's "ROI center
    must be a pair of finite numbers; got (inf, ...)" or as "--roi radius ...; got inf": neither the option typed
    nor its numbers."""
    code, _, err = run(capsys, "-q", "closeup", "--roi-relative", fractions, "-o", tmp_path / "c.ply")
    assert code == 2, err
    shown = ",".join(f"{float(v):g}" for v in fractions.split(","))
    assert err.startswith(f"stepterrain closeup: error: --roi-relative {shown} places a close-up at ("), err
    assert "expected fractions of the extent (0 to 1 across it)" in err and "ROI center" not in err, err
    assert not (tmp_path / "c.ply").exists()


def test_batch_default_interval_near_the_float32_maximum_is_refused_naming_the_pick(tmp_path, capsys):
    """batch's default interval (nice_interval over a file's or all files' heights) near the float32 maximum was an
    OverflowError; past it, the refusal named an --interval the user never gave."""
    grid = np.full((6, 7), 3.3e38, np.float32)
    grid[3:, 4:] = np.finfo(np.float32).max
    folder = tmp_path / "tiles"
    folder.mkdir()
    np.save(folder / "a.npy", grid)
    np.save(folder / "b.npy", grid[::-1])
    for source in (folder, folder / "a.npy"):
        code, _, err = run(capsys, "-q", "batch", source, "--scheduler", "serial", "-o", tmp_path / "out")
        assert code == 2 and "Traceback" not in err, err
        assert "no --interval or --levels given, and the round interval" in err and "give --levels" in err, err


@pytest.mark.parametrize("fractions", ["0.5,0.5,1e308", "1e308,0.5,0.2", "0.5,-1e308,0.2"])
def test_steps_lens_relative_beyond_the_extent_is_refused_naming_it(tmp_path, capsys, fractions):
    """A --lens-relative whose fractions overflow the lens' centre or radius was refused as "--lens radius must be
    finite; got inf" (an option not given, a number not typed) or by the library's lens centre."""
    code, _, err = run(capsys, "-q", "steps", "--lens-relative", fractions, "-o", tmp_path / "s.ply")
    assert code == 2, err
    shown = ",".join(f"{float(v):g}" for v in fractions.split(","))
    assert err.startswith(f"stepterrain steps: error: --lens-relative {shown} places the lens at ("), err
    assert "expected fractions of the extent (0 to 1 across it)" in err, err
    assert not (tmp_path / "s.ply").exists()


def test_closeup_edge_refusal_says_finite(tmp_path, capsys):
    """``closeup --edge inf`` was refused as "--edge must be >= 0; got inf": inf is >= 0."""
    for edge in ("inf", "nan", "-1"):
        code, _, err = run(capsys, "-q", "closeup", "--edge", edge, "-o", tmp_path / "c.ply")
        assert code == 2 and f"--edge must be a finite number >= 0; got {float(edge):g}" in err, err


def test_closeup_slow_fps_without_spin_names_the_default_spin(tmp_path, capsys):
    """``closeup --gif a.gif --fps 0.4`` (a slow slideshow GIF, a rate a GIF stores) with no --spin was refused as
    "--spin must be at most half a turn a frame ...; got 0.25": an option and a number the user never typed. The
    refusal names the default spin and the --spin that fits; a --spin within half a turn a frame is not refused."""
    code, _, err = run(capsys, "closeup", "--gif", tmp_path / "a.gif", "--fps", "0.4", "-o", tmp_path / "x.png")
    assert code == 2, err
    assert "the default --spin 0.25 turns more than half a turn a frame at --fps 0.4" in err, err
    assert "give a --spin with |TURNS/S| <= --fps / 2 = 0.2" in err and "loading" not in err, err
    assert sorted(tmp_path.iterdir()) == []


def test_texture_contour_color_of_alpha_zero_is_refused_not_warned_of_as_no_level(tmp_path, capsys):
    """``texture --contours 10 --contour-color 0.2,0.2,0.2,0`` over heights 100 to 180 (nine levels within them)
    drew every line transparent, and the no-line warning said "no contour level (a multiple of it) passes within the
    heights 100 to 180 ... a smaller interval draws lines": untrue, and no smaller interval would. A colour with alpha
    0 makes --contours draw nothing (index lines take its alpha): refused before any work, naming the option."""
    heights = np.add.outer(np.linspace(100.0, 140.0, 24), np.linspace(0.0, 40.0, 32)).astype(np.float32)
    np.save(tmp_path / "dem.npy", heights)
    out = tmp_path / "t.png"
    code, _, err = run(capsys, "-q", "texture", tmp_path / "dem.npy", "--contours", "10", "--contour-color",
                       "0.2,0.2,0.2,0", "-o", out)
    assert code == 2, err
    assert err.startswith("stepterrain texture: error: --contour-color must have an alpha above 0 (0 draws every "
                          "contour line transparent: the texture as without --contours); got 0.2,0.2,0.2,0"), err
    assert "passes within the heights" not in err and not out.exists()
    code, _, err = run(capsys, "-q", "texture", tmp_path / "dem.npy", "--contours", "10", "--contour-color",
                       "0.2,0.2,0.2,0.01", "-o", out)  # faint, not invisible
    assert code == 0 and err == "" and out.exists(), err


def test_texture_contours_no_line_warning_names_a_level_within_the_heights_it_did_not_draw(tmp_path, capsys):
    """A DEM at 60 m with one node at 100.5 (a DSM's mast, a lone summit node): the 100 m level lies within the
    heights, but its loop around the node is narrower than a texel and no texel is within half a line's width of it.
    The no-line warning said "no contour level (a multiple of it) passes within the heights 60 to 100.5 ... a smaller
    interval draws lines": 100 does. It names that level now; a wider --contour-width draws it."""
    heights = np.full((32, 32), 60.0, np.float32)
    heights[15, 15] = 100.5
    np.save(tmp_path / "spike.npy", heights)
    code, _, err = run(capsys, "-q", "texture", tmp_path / "spike.npy", "--contours", "100", "-o", tmp_path / "a.png")
    assert code == 0, err
    assert err == "stepterrain texture: warning: --contours 100 drew no line: its level 100, within the heights 60 " \
                  "to 100.5, passes within half a line's width of no texel (a loop narrower than a texel, around a " \
                  "lone peak or pit node); the texture is as without --contours (a wider --contour-width may draw " \
                  "it)\n", err
    code, _, err = run(capsys, "-q", "texture", tmp_path / "spike.npy", "--contours", "100", "--contour-width", "2.5",
                       "-o", tmp_path / "b.png")
    assert code == 0 and err == "", err


@pytest.mark.parametrize("argv, level, flat", [
    (("--levels", "5000,6000"), "5000", True),  # levels typed in feet for a DEM in metres, or a wrong number
    (("--levels", "-20,-10"), "-10", True),
    (("--interval", "1e6"), "0", True),  # an interval over the whole relief
    (("--levels", "-980,980"), "980", True),  # the lowest height on the threshold 0: it steps up, as all do
    (("--levels", "100,200"), None, False),  # a threshold (150) within the heights 0 to 980: two terraces
    (("--interval", "50"), None, False),
])
def test_steps_and_batch_warn_when_the_isovalues_give_one_flat_terrace(argv, level, flat, tmp_path, capsys):
    """Isovalues outside the heights (0 to 980 here) clamp every node to the end one: the mesh came out a flat plate
    at a height the terrain never reaches, exit 0 and not a word said (the lens that changes nothing is warned of)."""
    import trimesh

    np.save(tmp_path / "ramp.npy", np.add.outer(np.arange(40.0), np.arange(60.0)) * 10.0)
    code, out, err = run(capsys, "steps", tmp_path / "ramp.npy", *argv, "-o", tmp_path / "a.ply")
    assert code == 0, err
    z = np.unique(trimesh.load(tmp_path / "a.ply").vertices[:, 2])
    assert (z.size == 1) == flat  # the warning tells the truth about the mesh
    said = [line for line in err.splitlines() if "warning:" in line]
    if flat:
        assert len(said) == 1 and f"one flat terrace at {level}" in said[0] and "height (0 to 980)" in said[0], err
        assert argv[0] in said[0] and float(z[0]) == float(level)
    else:
        assert not said, err
    code, out, err = run(capsys, "batch", tmp_path / "ramp.npy", "--tile", "20", *argv, "--scheduler", "serial",
                         "-q", "-o", tmp_path / "out")
    assert code == 0, err
    said = [line for line in err.splitlines() if "warning:" in line]
    if flat:  # once for the whole raster, not per tile, naming the option
        assert len(said) == 1 and f"one flat terrace at {level}" in said[0] and argv[0] in said[0], err
    else:
        assert not said, err


def test_the_one_flat_terrace_warning_is_not_given_for_an_empty_mesh(tmp_path, capsys):
    """Nodes on no triangle (nodata between them) give an empty mesh, warned of as such: not also "one flat terrace"
    at a height no vertex has."""
    heights = np.full((10, 10), np.nan, np.float32)
    heights[::3, ::3] = 100.0
    heights[1, 1] = 5.0
    np.save(tmp_path / "isolated.npy", heights)
    code, out, err = run(capsys, "steps", tmp_path / "isolated.npy", "--levels", "1,2", "-o", tmp_path / "a.ply")
    said = [line for line in err.splitlines() if "warning:" in line]
    assert code == 0 and len(said) == 1 and "the mesh is empty" in said[0], err


@pytest.mark.parametrize("heights, argv, said", [
    ("flat", ("--interval", "10"), None),  # a flat DEM is one terrace whatever the isovalues: nothing lost
    ("ramp", ("--levels", "5000,6000", "--gamma", "1e-60"), None),  # γ 0 in float32: the original terrain
    ("ramp", ("--levels", "5000,6000", "--gamma", "0.5"), "no step, its heights pulled toward 5000 (γ = 0.5)"),
    ("ramp", ("--levels", "5000,6000", "--lens-relative", "0.5,0.5,0.3"), "one flat terrace at 5000 outside the lens"),
])
def test_the_one_level_warning_says_what_the_mesh_is(heights, argv, said, tmp_path, capsys):
    """The one-isovalue warning said "one flat terrace" of a mesh that is none: a γ < 1 blend (the relief pulled
    toward the level), γ 0 in float32 (the original terrain, isovalues unused) and a lens (the original terrain
    inside it); and warned a flat DEM, one terrace whatever its isovalues, with isovalues on its height."""
    import trimesh

    dem = np.full((20, 30), 100.0) if heights == "flat" else np.add.outer(np.arange(40.0), np.arange(60.0)) * 10.0
    np.save(tmp_path / "dem.npy", dem)
    code, _, err = run(capsys, "steps", tmp_path / "dem.npy", *argv, "-o", tmp_path / "a.ply")
    assert code == 0, err
    z = trimesh.load(tmp_path / "a.ply").vertices[:, 2]
    warned = [line for line in err.splitlines() if "warning:" in line]
    if said is None:
        assert not warned and np.isin(z, dem).all(), err  # the DEM's own heights: nothing lost to the isovalues
    else:
        assert len(warned) == 1 and said in warned[0] and np.unique(z).size > 1, err  # no plate
    if argv[-2] == "--gamma":  # batch takes a scalar γ alike
        code, _, err = run(capsys, "batch", tmp_path / "dem.npy", "--tile", "20", *argv, "--scheduler", "serial",
                           "-q", "-o", tmp_path / "out")
        warned = [line for line in err.splitlines() if "warning:" in line]
        assert code == 0 and len(warned) == (said is not None) and (said is None or said in warned[0]), err


def test_the_one_level_warning_of_a_single_level_within_the_heights_asks_for_a_threshold(tmp_path, capsys):
    """``--levels 500`` over heights 0 to 980 is one plate however it lies: the warning said "give isovalues within
    the heights" of a level within them. A plate needs two isovalues whose midpoint (the threshold) lies within."""
    import trimesh

    np.save(tmp_path / "ramp.npy", np.add.outer(np.arange(40.0), np.arange(60.0)) * 10.0)
    code, _, err = run(capsys, "steps", tmp_path / "ramp.npy", "--levels", "500", "-o", tmp_path / "a.ply")
    warned = [line for line in err.splitlines() if "warning:" in line]
    assert code == 0 and len(warned) == 1 and "one flat terrace at 500" in warned[0], err
    assert "two of which have their midpoint within the heights" in warned[0], err
    assert np.unique(trimesh.load(tmp_path / "a.ply").vertices[:, 2]).tolist() == [500.0]
    code, _, err = run(capsys, "steps", tmp_path / "ramp.npy", "--levels", "0,500", "-o", tmp_path / "b.ply")
    assert code == 0 and "warning:" not in err, err  # their midpoint, 250, within: two terraces
    assert np.unique(trimesh.load(tmp_path / "b.ply").vertices[:, 2]).tolist() == [0.0, 500.0]


@needs_render
def test_steps_png_without_output_writes_the_render_alone(tmp_path, capsys):
    """A user who wants only the picture: ``steps --png out.png`` without ``-o`` was refused (-o was required). It
    steps, renders and writes the PNG, and no mesh file."""
    from PIL import Image

    dem = tmp_path / "dem.npy"
    np.save(dem, (np.add.outer(np.arange(12.0), np.arange(14.0)) * 10 + 1000).astype(np.float32))
    png = tmp_path / "out.png"
    code, _, err = run(capsys, "steps", dem, "--interval", "20", "--png", png, "--size", "64x48")
    assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy", "out.png"]
    with Image.open(png) as image:
        assert image.format == "PNG" and image.size == (64, 48)
        pixels = np.asarray(image.convert("RGB")).reshape(-1, 3)
    assert len(np.unique(pixels, axis=0)) > 1  # a picture of the terrain, not one flat colour
    assert "writing out.png" in err or f"writing {png}" in err, err


def test_steps_without_output_or_png_is_a_usage_error(tmp_path, capsys):
    """-o/--output is optional with --png; with neither, the run has nothing to write: exit 2 naming both options,
    before any work, nothing written."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32))
    code, _, err = run(capsys, "steps", dem, "--interval", "1")
    assert code == 2
    line = one_error_line(err, "steps")
    assert "-o/--output" in line and "--png" in line and "got neither" in line
    assert [p.name for p in tmp_path.iterdir()] == ["dem.npy"]


def test_closeup_default_roi_over_nodata_names_the_default_not_a_roi_option(tmp_path, capsys):
    """Without --roi or --roi-relative the one close-up sits at the DEM's centre; over nodata there (a lake, the sea
    of a coastal DEM) the refusal read '--roi/--roi-relative (close-up 1): ... make it larger or move it', naming
    options the user never gave. It now says the default close-up was placed there, and how to place one."""
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=64, step=4)
    heights[16:48, 16:48] = np.nan  # nodata all round the centre, wider than the default ROI (0.12 of 63 nodes)
    path = tmp_path / "lake.npy"
    np.save(path, heights)
    code, _, err = run(capsys, "-q", "closeup", path, "-o", tmp_path / "c.glb")
    assert code == 2
    line = one_error_line(err, "closeup")
    assert line.startswith("stepterrain closeup: error: no --roi or --roi-relative given: the default close-up at the "
                           "DEM's centre"), line
    assert "holds no terrain" in line and "are nodata" in line  # the library's reason is kept
    assert line.endswith("give --roi x,y,r or --roi-relative fx,fy,fr over the terrain"), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lake.npy"]


@pytest.mark.parametrize("strip", [True, False], ids=["north-south strip", "whole DEM"])
def test_closeup_default_lift_clears_the_overview_seen_from_the_default_camera(tmp_path, strip):
    """The default close-up is lifted so that, seen from the default (oblique, from the south) camera at the render's
    z scale of 2, its lowest point lies above the overview's highest on screen. The lift was a fifth of the longer
    side: on a north-south strip (6 x 19 km of the embedded DEM) the close-up sat on the far half of the overview,
    drawn over the terrain; the whole DEM (wider than tall) is lifted as before."""
    from stepterrain import render
    from stepterrain.export import read_mesh

    xmin, _, ymin, ymax = st.sample_dem().extent
    crop = ["--crop", f"{xmin + 15000},{xmin + 21000},{ymin},{ymax}"] if strip else []
    assert cli.main(["closeup", *crop, "-o", str(tmp_path / "scene.ply"), "-q"]) == 0
    scene = read_mesh(tmp_path / "scene.ply")
    points = np.asarray(scene.vertices) * [1.0, 1.0, 2.0]  # the render's default --z-scale
    layer = scene.face_attributes["layer"]
    overview, closeup = (points[np.unique(scene.faces[layer == k])] for k in (0, 1))
    (x0, y0, _), (x1, y1, _) = overview.min(axis=0), overview.max(axis=0)
    assert (y1 - y0 > 3 * (x1 - x0)) == strip
    # the close-up proper: the default ROI at the centre, radius r = 0.12 of the shorter side, scaled by 1.5 about its
    # centre; layer 1's soft edge blends down to the terrain between r and 1.2 r from it, so those within r are lifted
    radius = 0.12 * min(x1 - x0, y1 - y0)
    closeup = closeup[np.hypot(closeup[:, 0] - (x0 + x1) / 2, closeup[:, 1] - (y0 + y1) / 2) < 0.95 * radius]
    eye, focal, up = (np.asarray(v) for v in render._camera_position("oblique", points, 1280 / 800))
    view = (focal - eye) / np.linalg.norm(focal - eye)
    screen_up = up - (up @ view) * view
    screen_up /= np.linalg.norm(screen_up)

    def screen_y(p):  # the perspective render's height on screen
        return ((p - eye) @ screen_up) / ((p - eye) @ view)

    closeup_height = np.ptp(screen_y(closeup))
    gap = screen_y(closeup).min() - screen_y(overview).max()
    assert gap > 0.3 * closeup_height, f"the close-up clears the overview by {gap / closeup_height:.2f} of its height"


def test_closeup_stepped_over_the_budget_names_the_closeup_options(tmp_path, capsys):
    """closeup --stepped INTERVAL over --memory-budget was told to "coarsen the isovalues" (stepped()'s advice, no
    closeup option) and to use Terrain.crop; it names --stepped, the ROI's radius, --crop/--coarsen and --memory-budget
    now."""
    from .test_closeup import hills

    dem = tmp_path / "hills.npy"
    np.save(dem, hills())
    code, _, err = run(capsys, "closeup", dem, "--stepped", "0.05", "--roi-relative", "0.5,0.5,0.5",
                       "--memory-budget", "1MiB", "-o", tmp_path / "out.ply")
    assert code == 2, err
    assert ("the stepped mesh" in err and "step the close-up at a larger interval (--stepped) or give it a smaller ROI "
            "(the r of --roi x,y,r or --roi-relative fx,fy,fr), or crop or coarsen the DEM (--crop, --coarsen), or "
            "raise the budget (--memory-budget SIZE)" in err), err
    assert "isovalues" not in err and "Terrain." not in err and "CloseUp" not in err
    assert not (tmp_path / "out.ply").exists()


@pytest.mark.parametrize("command", ["steps", "info"])
def test_unknown_height_unit_refusal_names_the_option_cleanly(tmp_path, capsys, command):
    """A GeoTIFF whose band names a unit off the list (here 'meters above sea level') was refused on the command
    line with the library's advice half-spelled as an option: "name their unit: load_dem(..., --height-unit 'm')
    (or 'ft', ...; the CLI's --height-unit m)", a Python call with an option inside it, the option said twice. The
    refusal names --height-unit once, as an option the user can type, and the file's unit; with it the run works."""
    from .test_io_fixes import write_unit_tif

    tif = write_unit_tif(tmp_path / "msl.tif", "meters above sea level")
    out = [] if command == "info" else ["--interval", "1", "-o", tmp_path / "x.ply"]
    code, _, err = run(capsys, command, tif, *out)
    assert code == 2, err
    assert "got 'meters above sea level' (band 1's unit)" in err, err
    assert "name their unit: --height-unit 'm' (or 'ft', ...)" in err, err
    assert "load_dem(" not in err and "the CLI's" not in err and err.count("--height-unit") == 1, err
    code, _, err = run(capsys, command, tif, "--height-unit", "m", *out)
    assert code == 0, err


def test_info_spacing_prints_the_coordinates_steps_crop_takes(tmp_path, capsys):
    """steps' --crop takes "the coordinates `stepterrain info` prints", but a .npy placed by --spacing 30 could not be
    described so: info had no --spacing (exit 2, "unrecognized arguments") and printed the 1 m grid's extent, 30
    times too small for the crop. info --spacing places it as steps does: a crop of the middle of the extent info
    prints keeps the nodes steps meshes there; a mesh file or a georeferenced DEM is refused --spacing."""
    heights = st.sample_dem().heights[:40, :60].astype(np.float32)
    npy = tmp_path / "dem.npy"
    np.save(npy, heights)
    code, out, err = run(capsys, "info", npy, "--spacing", "30,20", "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["spacing"] == [30.0, -20.0] and summary["shape"] == [40, 60]
    xmin, xmax, ymin, ymax = summary["extent"]
    assert (xmax - xmin, ymax - ymin) == (59 * 30.0, 39 * 20.0)
    crop = (xmin + 0.25 * (xmax - xmin), xmin + 0.75 * (xmax - xmin), ymin + 0.25 * (ymax - ymin),
            ymin + 0.75 * (ymax - ymin))
    mesh_file = tmp_path / "crop.ply"
    code, _, err = run(capsys, "steps", npy, "--spacing", "30,20", "--crop", ",".join(f"{v:.17g}" for v in crop),
                       "--interval", "50", "-o", mesh_file, "-q")
    assert code == 0, err
    lo, hi = trimesh.load(mesh_file, process=False).bounds
    nodes_x = xmin + 30.0 * np.arange(60)
    nodes_y = ymin + 20.0 * np.arange(40)
    kept_x = nodes_x[(nodes_x >= crop[0]) & (nodes_x <= crop[1])]
    kept_y = nodes_y[(nodes_y >= crop[2]) & (nodes_y <= crop[3])]
    np.testing.assert_allclose([lo[0], hi[0], lo[1], hi[1]], [kept_x[0], kept_x[-1], kept_y[0], kept_y[-1]])
    code, _, err = run(capsys, "info", mesh_file, "--spacing", "30")
    assert code == 2 and "--spacing applies to a DEM with no georeferencing" in err and "got --spacing 30" in err
    from .test_io_fixes import write_unit_tif

    code, _, err = run(capsys, "info", write_unit_tif(tmp_path / "utm.tif", "m"), "--spacing", "30")
    assert code == 2 and "--spacing applies to a DEM file with no georeferencing" in err, err


def test_info_and_globe_over_the_memory_budget_point_at_no_crop_they_lack(tmp_path, capsys):
    """A raster over the memory budget told info and globe, which have no --crop, to "crop or coarsen it first
    (crop= (the CLI's --crop) reads only the crop's window; ...)": a Python argument and an option neither command
    takes (and a globe needs the whole grid). They advise coarsening alone now; steps keeps its --crop advice."""
    rasterio = pytest.importorskip("rasterio")
    from .conftest import shared_file

    tif = shared_file("big_tujunga_srtm_30m_utm11n.tif")  # 643 x 1197 int16: 1.5 MB
    code, _, err = run(capsys, "-q", "--memory-budget", "1MB", "info", tif)
    assert code == 2, err
    assert "over the memory budget" in err and "coarsen it first (gdal_translate -outsize), or raise the budget" in err
    assert "crop" not in err.split("over the memory budget")[1], err
    world = np.add.outer(np.arange(180), np.arange(360)).astype(np.int16)
    with rasterio.open(tmp_path / "world.tif", "w", driver="GTiff", width=360, height=180, count=1, dtype="int16",
                       crs="EPSG:4326", transform=rasterio.transform.from_origin(-180, 90, 1, 1)) as dst:
        dst.write(world, 1)
    code, _, err = run(capsys, "-q", "--memory-budget", "100kB", "globe", tmp_path / "world.tif", "--face-size", "9",
                       "-o", tmp_path / "g.glb")
    assert code == 2, err
    assert "coarsen it first (gdal_translate -outsize; the globe needs the whole grid)" in err, err
    assert "crop" not in err.split("over the memory budget")[1] and not (tmp_path / "g.glb").exists(), err


def test_steps_over_the_memory_budget_names_options_not_python(tmp_path, capsys):
    """Two budget refusals of steps spoke Python to a command-line user: a GeoTIFF over the budget said "crop or
    coarsen it first (load_dem's --crop, --crop on the command line, reads only the crop's window", the library's
    crop= rewritten into an option inside a Python name; a stepped solid over it said "crop or coarsen the input
    (Terrain.crop, Terrain.coarsen; --crop, --coarsen) or coarsen the isovalues" (no option coarsens isovalues: a
    larger --interval does). Both name the options alone now, and following the advice works."""
    from .conftest import shared_file

    tif = shared_file("big_tujunga_srtm_30m_utm11n.tif")  # 643 x 1197 int16: 1.5 MB
    out = tmp_path / "x.ply"
    code, _, err = run(capsys, "-q", "steps", tif, "--interval", "100", "-o", out, "--memory-budget", "1MB")
    assert code == 2, err
    assert "crop or coarsen it first (--crop reads only the crop's window; gdal_translate -outsize coarsens)" in err
    assert "load_dem" not in err and "the CLI's" not in err, err
    solid = ["--coarsen", "3", "--solid", "-o", tmp_path / "x.3mf", "--memory-budget", "60MB"]
    code, _, err = run(capsys, "-q", "steps", tif, "--interval", "20", *solid)
    assert code == 2, err
    assert "crop or coarsen the DEM (--crop, --coarsen) or give a larger --interval (fewer --levels)" in err, err
    assert "Terrain." not in err and "coarsen the isovalues" not in err, err
    code, _, err = run(capsys, "-q", "steps", tif, "--interval", "500", *solid)  # a larger --interval: it fits
    assert code == 0, err


@needs_render
def test_batch_overview_warning_of_a_cell_too_tall_to_see_names_an_option_batch_has(tmp_path, capsys):
    """``batch --png`` leaves a contact-sheet cell too thin to see blank with a warning quoting render_mesh's
    refusal, "(with z_scale=2) ... a z_scale near 0.0004 makes it as tall as it is wide": advice no batch user could
    follow, as ``stepterrain batch`` had no --z-scale (the overview always rendered at 2). It has one now, for the
    overview alone: the warning names it, and the value it suggests draws the cell."""
    folder = tmp_path / "in"
    folder.mkdir()
    np.save(folder / "a.npy", np.add.outer(np.arange(20.0), np.arange(20.0) ** 1.5).astype(np.float32))
    np.save(folder / "b.npy", np.stack([np.linspace(0.0, 5000.0, 3)] * 3).astype(np.float32))  # a spike: a top
    # view of it at z_scale 2, fitted to its height, sees 2 x 2 across as a fraction of a pixel
    png = tmp_path / "sheet.png"
    argv = ["batch", folder, "-o", tmp_path / "out", "--interval", "2", "--scheduler", "serial", "--format", ".ply",
            "--png", png, "--size", "100x80", "--camera", "top"]
    code, _, err = run(capsys, "-q", *argv)
    assert code == 0, err
    said = re.search(r"the overview's cell of b\.ply \(50 x 80 pixels\) is left blank: .*\(with --z-scale 2\), too "
                     r"thin to see .*; a --z-scale near (\S+) makes it as tall as it is wide", err)
    assert said is not None, err
    assert "z_scale" not in err, err
    from PIL import Image

    drawn = (np.asarray(Image.open(png))[..., :3] < 250).any(axis=2)
    assert drawn[:, :50].mean() > 0.05 and not drawn[:, 50:].any()
    code, _, err = run(capsys, "-q", *argv, "--z-scale", said.group(1))  # the advice, followed
    assert code == 0 and "b.ply" not in err, err
    drawn = (np.asarray(Image.open(png))[..., :3] < 250).any(axis=2)
    assert drawn[:, 50:].mean() > 0.02, drawn[:, 50:].mean()


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_steps_output_that_is_a_folder_or_a_pipe_is_refused_in_one_plain_sentence(tmp_path, capsys, kind):
    """``_check_outputs``' own refusals (DataFileError, an OSError) were caught by its ``except OSError`` and wrapped:
    "--output 'x.glb' cannot be written: --output 'x.glb' is a folder; expected a file name"."""
    target = tmp_path / "x.glb"
    if kind == "folder":
        target.mkdir()
    else:
        if not hasattr(os, "mkfifo"):
            pytest.skip("no named pipes here")
        os.mkfifo(target)
    np.save(tmp_path / "d.npy", np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32))
    code, _, err = run(capsys, "-q", "steps", tmp_path / "d.npy", "--interval", "2", "-o", target)
    assert code == 2, err
    line = err.strip()
    expected = "is a folder; expected a file name" if kind == "folder" else "is a named pipe, not a regular file"
    assert line.startswith(f"stepterrain steps: error: --output {str(target)!r} {expected}"), line
    assert line.count("--output") == 1 and "cannot be written" not in line, line


def test_memory_budget_of_one_byte_is_said_in_the_singular(tmp_path, capsys):
    """``--memory-budget 1`` (the least it takes) was refused "over the memory budget of 1 bytes"."""
    np.save(tmp_path / "d.npy", np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32))
    code, out, err = run(capsys, "info", tmp_path / "d.npy", "--memory-budget", "1")
    assert code == 2 and out == "", err
    assert "over the memory budget of 1 byte;" in err and "1 bytes" not in err, err
    assert "would need 168 bytes" in err, err  # 6 x 7 float32 cells: more than one, plural


@pytest.mark.parametrize("lens", [["--lens-relative", "0.45,0.55,0.3"], ["--lens-relative", "0.5,0.5,0.25",
                                                                          "--lens-edge", "0"]])
def test_steps_lens_metadata_records_the_lens_and_gamma_outside_it(tmp_path, capsys, lens):
    """``steps --lens ... --gamma G`` recorded ``gamma: "lens"`` alone: the lens' centre, radius, edge and the γ outside
    it were lost, so two files of different meshes (--gamma 0.3 and 0.7) carried the same metadata. The metadata now
    rebuilds the library's mesh: circular_lens from it, stepped on the cropped DEM, gives the file's vertices."""
    x0, x1, y0, y1 = st.sample_dem().extent
    crop = (x0 + 0.4 * (x1 - x0), x0 + 0.46 * (x1 - x0), y0 + 0.4 * (y1 - y0), y0 + 0.48 * (y1 - y0))
    terrain = st.sample_dem().crop(crop)
    metas, meshes = [], []
    for gamma in (0.3, 0.7):
        out = tmp_path / f"lens{gamma}.ply"
        code, _, err = run(capsys, "steps", "--crop", ",".join(repr(v) for v in crop), "--interval", "50", *lens,
                           "--gamma", gamma, "-q", "-o", out)
        assert code == 0, err
        mesh = st.export.read_mesh(out)
        meta = mesh.metadata
        assert meta["gamma"] == "lens"
        rec = meta["lens"]
        assert rec["outside"] == gamma
        rebuilt = st.circular_lens(terrain, tuple(rec["center"]), rec["radius"], edge_width=rec["edge_width"],
                                   outside=rec["outside"])
        ref = st.stepped(terrain, interval=50.0, gamma=rebuilt)
        np.testing.assert_allclose(mesh.vertices, ref.vertices, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(mesh.faces, ref.faces)
        metas.append(meta)
        meshes.append(mesh)
    assert not np.array_equal(meshes[0].vertices, meshes[1].vertices)
    assert metas[0]["lens"] != metas[1]["lens"]


def test_info_shows_metadata_named_like_a_summary_field(tmp_path, capsys):
    """info left out a mesh's metadata item named like one of its own summary fields (``faces``, ``kind``,
    ``vertex_colors``) without a word, though it prints each as ``meta.NAME``, which clashes with none of them: it
    checked the plain name against the summary. Now every such item is shown, the summary's own fields as they were."""
    from stepterrain.export import save_mesh

    mesh = trimesh.creation.box()
    mesh.metadata.update({"faces": "from the DEM's cells", "kind": "terrain", "vertex_colors": True, "other": 3})
    path = tmp_path / "box.glb"
    save_mesh(mesh, path)
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["kind"] == "mesh" and summary["faces"] == 12 and summary["vertex_colors"] is False
    assert {key: summary.get(f"meta.{key}") for key in ("faces", "kind", "vertex_colors", "other")} == {
        "faces": "from the DEM's cells", "kind": "terrain", "vertex_colors": True, "other": 3}


def test_info_with_stdout_closed_is_an_error_not_a_silent_success(dem, capsys, monkeypatch):
    """With stdout closed (``stepterrain info dem.npy >&-``: Python's sys.stdout is None) info printed its summary
    to nowhere (``print`` to None writes nothing) and exited 0, as if a script reading it had got it. Its summary is
    its whole output: it fails now, saying why on stderr, exit 2, before reading the file."""
    monkeypatch.setattr("sys.stdout", None)
    monkeypatch.setattr(cli, "_mesh_summary", lambda path: pytest.fail("read the file with nowhere to print"))
    code = cli.main(["info", str(dem)])
    err = capsys.readouterr().err
    assert code == 2 and "stepterrain info: error: standard output is closed" in err, err
    code = cli.main(["info", str(tmp := dem.with_suffix(".ply"))])
    assert code == 2 and "standard output is closed" in capsys.readouterr().err and not tmp.exists()


@needs_render
def test_closeup_gif_refused_for_identical_frames_writes_no_mesh_or_png(tmp_path, capsys):
    """``closeup --gif --spin 1e-12 --fps 0.002`` shows identical frames of 500 s each: two of them are one GIF frame of
    1000 s, past a GIF delay's 655.35 s. save_animation refused it, but only after the scene mesh and the PNG were
    written (the old ones replaced, though the run failed). Now refused before any file is written."""
    mesh, png, gif = tmp_path / "c.glb", tmp_path / "c.png", tmp_path / "spin.gif"
    for path in (mesh, png):
        path.write_bytes(b"an earlier output")
    code, _, err = run(capsys, "-q", "closeup", "--size", "96x72", "--gif", gif, "--spin", "1e-12", "--fps", "0.002",
                       "--frames", "2", "-o", mesh, "--png", png)
    assert code == 2
    assert ("--fps 0.002 shows frames[0] to frames[1] (identical: one GIF frame) for 1000 s, longer than a GIF "
            "frame's longest delay (655.35 s)") in one_error_line(err, "closeup")
    assert mesh.read_bytes() == png.read_bytes() == b"an earlier output"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.glb", "c.png"]


#: (subcommand, option, value): every numeric option, in a value float()/int() reads though a user did not type that
#: number: digit grouping (1_0 is 10 to Python, 1 or an error to strtod and to other tools) and non-ASCII digits (an
#: Arabic-Indic 3 is 3 to Python). --band, --coarsen and --nodata refused them already; these read them silently.
_UNTYPED_NUMBERS = [
    *[("steps", opt, v) for opt in ("--interval", "--base", "--gamma", "--lens-edge", "--floor", "--print-size",
                                    "--print-z-scale", "--z-scale") for v in ("1_0", "\u0663")],
    ("steps", "--levels", "1_0,20"), ("steps", "--crop", "0,1_0,0,10"), ("steps", "--lens", "1,2,\u0663"),
    ("steps", "--lens-relative", "0.5,0.5,0_2"), ("steps", "--spacing", "1_0"), ("steps", "--camera", "1_0,30"),
    ("steps", "--size", "1_28x96"), ("steps", "--size", "\u0661\u0662\u0668x96"),
    ("steps", "--memory-budget", "\u0663GiB"),
    *[("globe", opt, "1_0") for opt in ("--face-size", "--exaggeration", "--radius", "--error", "--tilt", "--heading",
                                        "--view-angle")],
    ("globe", "--eye", "3_0,10,1e7"),
    *[("closeup", opt, "1_0") for opt in ("--edge", "--stepped", "--z-scale", "--frames", "--fps", "--spin",
                                          "--scale")],
    ("closeup", "--offset", "0,0,1_0"), ("closeup", "--rotation", "1_0,0"), ("closeup", "--roi", "1,2,\u0663"),
    ("closeup", "--color", "0_0,0,0"),
    *[("texture", opt, "1_0") for opt in ("--azimuth", "--altitude", "--z-factor", "--shadow-strength", "--occlusion",
                                          "--texel-size", "--contours", "--contour-width", "--contour-index",
                                          "--interval", "--z-scale")],
    ("texture", "--image-extent", "0,1_0,0,10"), ("texture", "--contour-color", "0_0,0,0"),
    *[("batch", opt, "1_0") for opt in ("--interval", "--base", "--gamma", "--floor", "--workers", "--connect-timeout",
                                        "--retries", "--z-scale", "--tile")],
]


@pytest.mark.parametrize(("command", "option", "value"), _UNTYPED_NUMBERS)
def test_numbers_with_underscores_or_non_ascii_digits_are_refused_naming_the_option(command, option, value, tmp_path,
                                                                                    capsys):
    """Every numeric option read '1_0' as 10 and an Arabic-Indic 3 as 3 (float()'s and int()'s reading): --interval
    1_0 stepped at 10 m without a word, and a refusal named a value not typed (--gamma 1_0: 'got 10.0'). They are
    argparse errors now, naming the option and the text typed, as --band's, --coarsen's and --nodata's were."""
    out = tmp_path / "out"
    code, stdout, err = run(capsys, command, f"{option}={value}", "-o", out / "x.glb" if command != "batch" else out)
    assert code == 2, err
    assert f"argument {option}" in err and repr(value) in err and "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and stdout == ""
    assert not out.exists()


def test_batch_spacing_beyond_float32_is_a_usage_error_before_any_item_runs(tmp_path, capsys):
    """batch --spacing 1e308 ran every item, each failing alike ('spacing must lie between 1e-30 and 1e+30'), exit 1
    after the work, where steps refused it (exit 2); and steps' refusal named (1e+308, -1e+308), not the 1e308 typed.
    --spacing's range is argparse's now, for every subcommand, naming the text typed."""
    src = tile_folder(tmp_path / "tiles")
    for spacing in ("1e308", "1e-31", "30,1e31"):
        code, out, err = run(capsys, "batch", src, "--spacing", spacing, "--scheduler", "serial",
                             "-o", tmp_path / "out")
        assert code == 2, err
        assert "argument --spacing" in err and repr(spacing) in err and "1e-30" in err, err
        assert not (tmp_path / "out").exists()
        code, out, err = run(capsys, "steps", src / "t0.npy", "--spacing", spacing, "-o", tmp_path / "s.glb")
        assert code == 2 and "argument --spacing" in err and repr(spacing) in err, err
        assert not (tmp_path / "s.glb").exists()
    code, out, err = run(capsys, "steps", src / "t0.npy", "--spacing", "1e-30,1e30", "-o", tmp_path / "s.glb")
    assert code == 0, err  # the range's ends are accepted


#: Text no numeric option reads as a number: empty, blank, non-finite, hex, another separator, digit grouping,
#: non-ASCII digits (each option's own range is its own test's).
_NOT_NUMBERS = ("", " ", "nan", "inf", "-inf", "0x10", "1;2", "1_0", "\u0663")

#: subcommand -> (argv before the option, {option: (context options it needs, values refused besides _NOT_NUMBERS)}).
_FUZZ = {
    "steps": (["--spacing", "30", "-o", "{out}/a.glb"], {
        "--band": ((), ("0", "-1", "1e308", "1,2")), "--spacing": ((), ("0", "-1", "1e308", "1e-400", "1,2,3")),
        "--crop": ((), ("1,2", "1,2,3,4,5")), "--coarsen": ((), ("0", "1", "-1", "1.5")),
        "--interval": ((), ("0", "-1", "-0", "1e308")), "--levels": ((), ("1e308", "2,1")),
        "--base": (("--interval=2",), ("1e308",)), "--gamma": ((), ("-1", "1.5", "1e308")),
        "--lens": ((), ("1,2",)), "--lens-relative": ((), ("0.5,0.5,0", "1,2,3,4")),
        "--lens-edge": (("--lens-relative=0.5,0.5,0.2",), ("-1",)), "--floor": (("--solid",), ("1e308",)),
        "--print-size": (("--solid",), ("0", "-1")), "--print-z-scale": (("--solid", "--print-size=100"), ("0",)),
        "--size": (("--png", "{out}/a.png"), ("7x8", "8x16385", "0x0", "8x8x8")),
        "--z-scale": (("--png", "{out}/a.png"), ("0", "-1")), "--camera": (("--png", "{out}/a.png"), ("0,91", "1")),
        "--memory-budget": ((), ("0", "0.5", "-1", "1 XB")),
    }),
    "globe": (["--face-size=9", "-o", "{out}/a.glb"], {
        "--face-size": ((), ("0", "4", "1.5")), "--exaggeration": ((), ("0", "-1")), "--radius": ((), ("0", "1e308")),
        "--error": ((), ("-1",)), "--eye": ((), ("91,0,1e7", "0,0")), "--tilt": ((), ("90", "-1")),
        "--heading": ((), ()), "--view-angle": ((), ("0", "180")), "--size": (("--png", "{out}/a.png"), ("7x8",)),
    }),
    "closeup": (["--spacing", "30", "-o", "{out}/a.glb"], {
        "--roi": ((), ("1,2", "0,0,0")), "--roi-relative": ((), ("0.5,0.5,0",)), "--edge": ((), ("-1",)),
        "--scale": ((), ("0", "1,2")), "--offset": ((), ("1,2",)), "--rotation": ((), ("1,2,3",)),
        "--color": ((), ("2,0,0", "nope")), "--stepped": ((), ("-1",)),
        "--frames": (("--gif", "{out}/a.gif", "--size=128x96"), ("0", "-1")),
        "--fps": (("--gif", "{out}/a.gif", "--size=128x96"), ("0", "1000")),
        "--spin": (("--gif", "{out}/a.gif", "--size=128x96"), ("0",)),
        "--z-scale": (("--png", "{out}/a.png", "--size=128x96"), ("0",)),
    }),
    "texture": (["--spacing", "30", "-o", "{out}/a.png"], {
        "--azimuth": ((), ()), "--altitude": ((), ("91", "-1")), "--z-factor": ((), ("0", "1e308")),
        "--shadow-strength": (("--shadows",), ("1.5", "-1")), "--occlusion": ((), ("1.5", "-1")),
        "--texel-size": ((), ("0", "-1", "31")), "--contours": ((), ("0", "-1")),
        "--contour-width": (("--contours=2",), ("0",)), "--contour-color": (("--contours=2",), ("1,0", "2,0,0")),
        "--contour-index": (("--contours=2",), ("-1", str(2**31))), "--interval": (("--mesh", "{out}/a.glb"), ("0",)),
        "--image-extent": (("--image", "{dem}"), ("1,2", "1,0,0,1")),
    }),
    "batch": (["--scheduler=serial", "-o", "{out}/d"], {
        "--tile": ((), ("0", "1x", "1x2x3")), "--interval": ((), ("0", "-1")), "--gamma": ((), ("-1", "2")),
        "--retries": ((), ("-1",)), "--floor": (("--solid",), ("1e308",)), "--spacing": ((), ("1e308",)),
    }),
}


@pytest.mark.parametrize("command", sorted(_FUZZ))
def test_fuzzed_option_values_are_refused_in_one_line_naming_the_option(command, dem, tmp_path, capsys):
    """A fuzz of every numeric option of every subcommand (not a number, not finite, out of range, a list of the
    wrong length): each ends with exit status 2 and one line naming the option and the text typed, no traceback,
    nothing written, before any work."""
    before, options = _FUZZ[command]
    out = tmp_path / "out"
    bad = []
    for option, (context, values) in options.items():
        for value in (*_NOT_NUMBERS, *values):  # (--nodata's own: nan and inf are nodata values)
            argv = [command, str(dem), "-q", *(a.format(out=out, dem=dem) for a in (*before, *context)),
                    f"{option}={value}"]
            code, stdout, err = run(capsys, *argv)
            lines = err.strip().splitlines()
            ok = (code == 2 and stdout == "" and len(lines) == 1 and "Traceback" not in err
                  and lines[0].startswith(f"stepterrain {command}: error: ") and option in lines[0]
                  and not out.exists())
            if not ok:
                bad.append(f"{option}={value!r}: exit {code}, {err.strip()!r}")
                shutil.rmtree(out, ignore_errors=True)
    assert not bad, "\n".join(bad)
