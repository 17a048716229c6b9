"""``--camera`` of the renders of ``steps``, ``texture``, ``closeup`` and ``batch``: parsed in one place, the same
view as the library's ``camera=``, refused with exit 2 before any work when malformed or given without a render."""

from __future__ import annotations

import math

import numpy as np
import pytest

import stepterrain as st
from stepterrain import cli, render

from .conftest import needs_render
from .test_cli import run
from .test_examples_dem import read_png


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("oblique", "oblique"),
        ("top", "top"),
        (" TOP ", "top"),
        ("225,30", (math.radians(225.0), math.radians(30.0))),
        ("-90, -45", (math.radians(270.0), math.radians(-45.0))),  # azimuths from 0 to a turn
        ("720,90", (0.0, math.radians(90.0))),  # whole turns taken off
    ],
)
def test_camera_values_parse_to_render_mesh_cameras(text, expected):
    got = cli._camera(text)
    assert got == pytest.approx(expected) if isinstance(expected, tuple) else got == expected


@pytest.mark.parametrize("text", ["190,45", "-170,45", "550,45", "-530,45"])
def test_the_default_views_angles_name_it_exactly(text):
    """The oblique view is the fixed (190, 45) degrees for any mesh: its azimuth written another way round names the
    same camera bit for bit (radians(-170) differed from radians(190) - 2 pi in the last bit, so '--camera=-170,45'
    gave the default's pixels only where that rounding moved no pixel edge)."""
    assert cli._camera(text) == render._OBLIQUE


def test_top_is_straight_down_from_the_south_as_the_help_says():
    """--help: top is 180,90 (the far side up: north); 0,90 looks down with south up."""
    corners = np.array([[0.0, 0.0, 0.0], [300.0, 200.0, 40.0]])
    top = render._camera_position("top", corners, 1.5)
    assert render._camera_position(cli._camera("180,90"), corners, 1.5) == top
    assert render._camera_position(cli._camera("-180,89.95"), corners, 1.5) == top
    assert render._camera_position(cli._camera("0,90"), corners, 1.5)[2] == pytest.approx((0.0, -1.0, 0.0), abs=1e-12)


@pytest.mark.parametrize("text", ["side", "", "10", "1,2,3", "a,b", "1,,2", "10,90.5", "10,-91", "nan,10", "10,inf"])
@pytest.mark.parametrize(
    "argv",
    [
        ["steps", "{dem}", "--interval", "2", "--png", "{tmp}/a.png"],
        ["texture", "{dem}", "--png", "{tmp}/a.png"],
        ["closeup", "{dem}", "--png", "{tmp}/a.png"],
        ["batch", "{dem}", "--tile", "8", "--interval", "2", "--scheduler", "serial", "-o", "{tmp}/b",
         "--png", "{tmp}/a.png"],
    ],
)
def test_a_malformed_camera_is_a_usage_error_writing_nothing(dem, tmp_path, capsys, monkeypatch, argv, text):
    loaded = []
    monkeypatch.setattr(st, "load_dem", lambda *a, **k: loaded.append(a))  # never reached
    code, _, err = run(capsys, *[a.format(dem=dem, tmp=tmp_path) for a in argv], f"--camera={text}")
    assert code == 2, err
    assert "error: argument --camera: expected" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hill.npy"] and not loaded


@pytest.mark.parametrize(
    ("argv", "needs"),
    [
        (["steps", "{dem}", "--interval", "2", "-o", "{tmp}/a.glb"], "--png"),
        (["texture", "{dem}", "-o", "{tmp}/t.png"], "--png"),
        (["closeup", "{dem}", "-o", "{tmp}/c.glb"], "a render"),
        (["batch", "{dem}", "--tile", "8", "--interval", "2", "--scheduler", "serial", "-o", "{tmp}/b"], "--png"),
    ],
)
def test_camera_without_a_render_is_refused(dem, tmp_path, capsys, argv, needs):
    code, _, err = run(capsys, *[a.format(dem=dem, tmp=tmp_path) for a in argv], "--camera", "top")
    assert code == 2, err
    assert f"--camera applies only with {needs}" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hill.npy"]


@pytest.mark.parametrize("command", ["steps", "texture", "closeup", "batch"])
def test_help_names_the_camera(capsys, command):
    assert cli.main([command, "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "--camera oblique|top|AZ,EL" in out and "azimuth clockwise from north" in out


@needs_render
def test_steps_camera_is_render_mesh_camera(dem, tmp_path, capsys):
    size = (160, 120)
    mesh = st.stepped(st.load_dem(dem), interval=2.0, colors="terrain")
    images = {}
    for camera, value in (("top", "top"), ("30,60", (math.radians(30.0), math.radians(60.0))), (None, "oblique")):
        png = tmp_path / f"{camera}.png"
        extra = [] if camera is None else ["--camera", camera]
        code, _, err = run(capsys, "-q", "steps", dem, "--interval", "2", "--colormap", "terrain", "--png", png,
                           "--size", "160x120", *extra)
        assert code == 0, err
        images[camera] = read_png(png)
        expected = render.render_mesh(mesh, window_size=size, z_scale=2.0, camera=value)
        assert np.array_equal(images[camera], expected), camera
    # the views differ: top is not the default oblique view, nor the 30,60 one
    assert not np.array_equal(images["top"], images[None])
    assert not np.array_equal(images["30,60"], images[None])
    assert not np.array_equal(images["top"], images["30,60"])
    # the default oblique view is the one "oblique" names, and the pair of its angles (190, 45)
    code, _, err = run(capsys, "-q", "steps", dem, "--interval", "2", "--colormap", "terrain", "--png",
                       tmp_path / "named.png", "--size", "160x120", "--camera=-170,45")
    assert code == 0, err
    assert np.array_equal(read_png(tmp_path / "named.png"), images[None])


@needs_render
def test_texture_and_closeup_and_batch_take_the_camera(dem, tmp_path, capsys):
    for command, extra in (("texture", []), ("closeup", []),
                           ("batch", ["--tile", "16", "--interval", "2", "--scheduler", "serial", "-o"])):
        images = {}
        for camera in ("top", None):
            png = tmp_path / f"{command}_{camera}.png"
            argv = [*extra, tmp_path / f"{command}_{camera}"] if extra else []
            code, _, err = run(capsys, "-q", command, dem, *argv, "--png", png, "--size", "96x64",
                               *([] if camera is None else ["--camera", camera]))
            assert code == 0, err
            images[camera] = read_png(png)
        assert not np.array_equal(images["top"], images[None]), command


@needs_render
def test_batch_views_every_cell_of_a_contact_sheet_from_the_camera(tmp_path, capsys):
    """A series' contact sheet (2 x 2 cells of 48 x 32): every cell is seen from --camera (another picture than the
    default view's), as the mosaic's one render is."""
    frames = np.cumsum(np.random.default_rng(0).random((4, 10, 12)), axis=0).astype(np.float32)
    np.save(tmp_path / "s.npy", frames)
    sheets = {}
    for camera in ("top", None):
        png = tmp_path / f"{camera}.png"
        code, _, err = run(capsys, "-q", "batch", tmp_path / "s.npy", "-o", tmp_path / f"o_{camera}", "--scheduler",
                           "serial", "--png", png, "--size", "96x64", *([] if camera is None else ["--camera", camera]))
        assert code == 0, err
        sheets[camera] = read_png(png)
    for r in range(2):
        for c in range(2):
            cell = np.s_[r * 32:(r + 1) * 32, c * 48:(c + 1) * 48]
            assert not np.array_equal(sheets["top"][cell], sheets[None][cell]), (r, c)


@pytest.mark.parametrize(
    "argv",
    [
        ["steps", "{dem}", "--interval", "0.1", "--png", "{tmp}/a.png"],
        ["texture", "{dem}", "--shadows", "--png", "{tmp}/a.png"],
        ["closeup", "{dem}", "--roi", "300,-2.5,2", "--offset", "0,0,1", "--png", "{tmp}/a.png"],
        ["batch", "{dem}", "--interval", "0.1", "--scheduler", "serial", "-o", "{tmp}/b", "--png", "{tmp}/a.png"],
    ],
)
@needs_render
def test_a_view_too_thin_to_see_points_to_the_camera_option(tmp_path, capsys, argv):
    """A strip of ground 600 x 6 nodes seen from the top, under a pixel tall in 64 x 64 whatever its z-scale: the
    advice to look from another direction named render_mesh's ``camera``, which the command line spells --camera."""
    path = tmp_path / "strip.npy"
    np.save(path, np.random.default_rng(0).random((6, 600)).astype(np.float32))
    code, _, err = run(capsys, "-q", *[a.format(dem=path, tmp=tmp_path) for a in argv], "--size", "64x64",
                       "--camera", "top")
    assert code == 2, err
    assert "too thin to see" in err and "look from another direction (--camera)" in err, err
    assert "(camera)" not in err and "Traceback" not in err
