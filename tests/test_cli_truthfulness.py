"""The CLI says what its options need and names them in its own terms: each option's help states when it applies
(as the refusals check it), an option that changes nothing is refused by name (globe --eye with the geometric metric
alone, closeup --anchor with an .obj --output alone), and no Python argument (``closeups[0]``) leaks into a message."""

from __future__ import annotations

import numpy as np
import pytest

import stepterrain as st
from stepterrain import cli

from .conftest import needs_render
from .conftest import run_cli as run


def option_help(command: str, option: str) -> str:
    """The help of ``option`` of ``stepterrain command``, on one line (as argparse holds it, before wrapping)."""
    sub = cli._subcommand(cli.build_parser(), command)
    for action in sub._actions:
        if option in action.option_strings:
            return " ".join(action.help.split())
    raise AssertionError(f"{command} has no {option}")


@pytest.mark.parametrize("command, option, phrases", [
    # globe refuses the view's options without the metric that reads them and no --png (_run_globe)
    ("globe", "--eye", ["distance and clip metrics and the --png render", "--metrics geometric alone", "refused"]),
    ("globe", "--tilt", ["clip metric and the --png render: refused without either"]),
    ("globe", "--heading", ["clip metric and the --png render: refused without either"]),
    ("globe", "--view-angle", ["clip metric refines and culls", "--png render's: refused without either"]),
    ("globe", "--size", ["with --png", "clip metric's view", "refused without either"]),
    ("globe", "--error", ["with the distance metric", "else everywhere"]),  # it said "at the eye's altitude" always
    ("globe", "--bounds", ["with the camera and the distance or clip metric only"]),
    ("globe", "--texture", ["refused with an .stl -o and no --png"]),
    # closeup refuses them with a mesh --output that cannot hold what they change and no render
    ("closeup", "--anchor", ["vertex alpha of a .glb, .gltf, .ply or .3mf", "refused with an .obj or .stl --output "
                                                                            "alone"]),
    ("closeup", "--scalars", ["refused with an .stl --output alone"]),
    ("closeup", "--colormap", ["refused with --scalars none and no --stepped close-up"]),
    ("closeup", "--output", ["--anchor is refused with it unless --png or --gif",
                             "--colormap, --color, --scalars and --anchor are refused with it"]),
    ("closeup", "--edge", ["at most the ROI radius"]),
    ("closeup", "--spin", ["with --gif only, of 2 --frames or more"]),
    ("closeup", "--frames", ["with --gif only"]),
    ("closeup", "--fps", ["with --gif only"]),
    ("steps", "--colormap", ["an .stl -o holds no colours: a colormap is refused there without --png"]),
    ("steps", "--lens", ["with --gamma 0", "refused"]),
    ("steps", "--lens-relative", ["refused with --gamma 0"]),
    ("steps", "--print-size", ["(-o, required)"]),
    ("texture", "--azimuth", ["--hillshade none", "refused without them"]),
    ("texture", "--altitude", ["--hillshade none", "refused without them"]),
    ("texture", "--z-factor", ["with --hillshade none only with --shadows, --occlusion or --normals"]),
    ("batch", "--colormap", ["a colormap is refused there"]),
])
def test_each_option_help_states_what_it_needs(command, option, phrases):
    """Each of these options is refused where it does nothing (the runs below and the earlier sessions' tests), but
    its help did not say so: globe --tilt read "tilt of the view from straight down" and was refused with --metrics
    geometric,distance; closeup --anchor read "anchor transparency" and was refused with an .stl --output."""
    text = option_help(command, option)
    for phrase in phrases:
        assert phrase in text, (command, option, text)


def test_the_geometric_metric_alone_refuses_the_eye(tmp_path, capsys):
    """``globe --metrics geometric --eye 46,9,400000 -o g.ply`` was accepted and wrote the mesh of ``--metrics
    geometric`` (the geometric metric measures each node's own error: kernels/bounds.py's refine_node reads the eye
    only for the distance and clip metrics), and recorded that eye as the one the mesh was refined for; the refusal of
    --tilt there said "the geometric and distance metrics read only the --eye position". --eye is refused by name
    now, the message says what the geometric metric reads, and the metadata records no eye it was not refined for."""
    globe = st.Globe.sample(face_size=17, device="cpu")
    top = globe.radius + float(globe.heights.max())
    meshes = [globe.mesh(error=300.0, metrics=("geometric",),
                         camera=st.globe.look_from(*eye, radius=globe.radius, max_radius=top))
              for eye in ((46.0, 9.0, 4e5), (-20.0, 100.0, 3 * globe.radius))]
    assert np.array_equal(meshes[0].faces, meshes[1].faces)  # the eye changes nothing there
    assert np.array_equal(meshes[0].vertices, meshes[1].vertices)

    out = tmp_path / "g.ply"
    base = ["-q", "globe", "--face-size", "9", "--device", "cpu", "-o", out, "--metrics", "geometric"]
    code, _, err = run(capsys, *base, "--eye", "46,9,400000")
    assert code == 2
    assert err == ("stepterrain globe: error: --eye applies only with the distance or clip metric or a --png render "
                   "(the geometric metric measures each node's own error, nothing of the view); got it with "
                   "--metrics geometric and no --png\n")
    code, _, err = run(capsys, *base, "--eye", "46,9,400000", "--tilt", "20")
    assert code == 2
    assert err == ("stepterrain globe: error: --eye applies only with the distance or clip metric or a --png render; "
                   "--tilt applies only with the clip metric or a --png render (the geometric metric measures each "
                   "node's own error, nothing of the view); got them with --metrics geometric and no --png\n")
    assert "geometric and distance metrics read" not in err
    assert not out.exists()

    code, _, err = run(capsys, *base)
    assert code == 0, err
    meta = st.export.read_mesh(out).metadata
    assert meta["metrics"] == "geometric" and "eye_lat_lon_alt" not in meta  # it recorded the default eye
    code, _, err = run(capsys, *base[:-1], "geometric,distance", "--eye", "46,9,400000")
    assert code == 0, err  # the distance metric reads the eye: it passes and is recorded
    assert st.export.read_mesh(out).metadata["eye_lat_lon_alt"] == [46.0, 9.0, 400000.0]


def test_closeup_library_index_is_named_in_the_clis_terms():
    """closeup._check_framed's refusal named ``closeups[0]`` mid-message ("... is that large because closeups[0]
    (offset (0.0, 0.0, 1000000000.0)) is drawn ..."), a Python argument no option gives; only a leading
    ``closeups[k]: ROI box`` was spelled as the CLI's. Now every one reads as the close-up's number and its --offset."""
    message = ("the camera fitted to the overview and its close-ups would show the overview (0.0015 px) and "
               "closeups[1]'s content (0.0004 px) under a pixel: the framed box x [0, 1], y [0, 1], z [0, 1e+09] is "
               "that large because closeups[1] (offset (0.0, -5.5, 1000000000.0)) is drawn 1e+09 from the terrain's "
               "centre; move it nearer, or frame what to see with bounds")
    text = cli._as_option(message, cli._subcommand(cli.build_parser(), "closeup"))
    assert "closeups[" not in text
    assert ("close-up 2's content (0.0004 px)" in text and "because close-up 2 (--offset 0,-5.5,1e+09) is drawn"
            in text and text.endswith("move it nearer: give it a smaller --offset")), text


@needs_render
def test_closeup_framing_refusal_names_no_python_argument(tmp_path, capsys):
    """The run that meets that refusal: a close-up lifted 1e9 m."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32))
    code, _, err = run(capsys, "-q", "closeup", dem, "--offset", "0,0,1e9", "--size", "96x72", "-o",
                       tmp_path / "c.png")
    assert code == 2
    assert "closeups[" not in err and "because close-up 1 (--offset 0,0,1e+09) is drawn" in err, err
    assert list(tmp_path.iterdir()) == [dem]


@pytest.mark.parametrize("preset", ["opaque", "linear", "hidden"])
def test_closeup_anchor_with_an_obj_output_alone_is_refused(tmp_path, capsys, preset):
    """``closeup --anchor X -o scene.obj`` wrote the same file for every preset (an OBJ's ``v x y z r g b`` lines
    hold no alpha, the anchors' opacity: five presets, one md5) and said nothing, as --anchor with an .stl did before
    it was refused. Refused by name now, before the DEM is read; a .ply keeps what it changes, and an OBJ of those
    .ply scenes is the same file whatever the preset."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32))
    out = tmp_path / "scene.obj"
    code, _, err = run(capsys, "-q", "closeup", dem, "--anchor", preset, "-o", out)
    assert code == 2
    assert err == (f"stepterrain closeup: error: an .obj --output holds RGB only, the anchors opaque: got --anchor "
                   f"{preset} (the anchors' opacity, in the vertex alpha of the other formats and in the renders) "
                   f"with --output {str(out)!r} and no --png or --gif; write .glb, .ply or .3mf for the anchors' "
                   "opacity, or leave --anchor out\n")
    assert list(tmp_path.iterdir()) == [dem]
    code, _, err = run(capsys, "-q", "closeup", dem, "-o", out)  # the default: as before
    assert code == 0, err
    objs = {}
    for other in ("opaque", preset):
        (tmp_path / other).mkdir(exist_ok=True)
        ply = tmp_path / other / "scene.ply"  # one name: the OBJ names the file it came from
        code, _, err = run(capsys, "-q", "closeup", dem, "--roi-relative", "0.5,0.5,0.25", "--anchor", other,
                           "-o", ply)
        assert code == 0, err
        scene = st.export.read_mesh(ply)
        st.export.save_mesh(scene, tmp_path / other / "scene.obj")
        objs[other] = ((tmp_path / other / "scene.obj").read_bytes(), scene.visual.vertex_colors[:, 3])
    assert objs["opaque"][0] == objs[preset][0]  # what --anchor changes, an OBJ drops
    if preset == "hidden":
        assert (objs["hidden"][1] < objs["opaque"][1]).any()


def test_closeup_spin_with_one_frame_is_refused(tmp_path, capsys):
    """``closeup --gif a.gif --frames 1 --spin 0.5`` wrote the animation of ``--frames 1``: its one frame is at time 0,
    before any turn (animate_closeups: frame i at time i / fps). Refused by name now, before the DEM is read; and with
    one frame the default spin is no longer refused as turning too fast for a slow --fps (``--frames 1 --fps 0.1``
    was told "the default --spin 0.25 turns more than half a turn a frame", of a spin that never turns)."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32))
    gif = tmp_path / "a.gif"
    code, _, err = run(capsys, "-q", "closeup", dem, "--gif", gif, "--frames", "1", "--spin", "0.5")
    assert code == 2
    assert err == ("stepterrain closeup: error: --spin turns the close-ups from frame to frame; --frames 1 renders "
                   "one, at time 0 (before any turn): give --frames 2 or more, or leave --spin out; got --spin 0.5\n")
    assert list(tmp_path.iterdir()) == [dem]


@needs_render
def test_closeup_one_frame_at_a_slow_fps_is_no_aliased_spin(tmp_path, capsys):
    """The run ``--frames 1 --fps 0.1`` now makes: one still frame."""
    dem = tmp_path / "dem.npy"
    np.save(dem, np.add.outer(np.linspace(0.0, 40.0, 24), np.linspace(0.0, 30.0, 28)).astype(np.float32))
    gif = tmp_path / "a.gif"
    code, _, err = run(capsys, "-q", "closeup", dem, "--gif", gif, "--frames", "1", "--fps", "0.1", "--size", "96x72")
    assert code == 0, err
    assert gif.exists()


def test_the_geometric_metric_alone_places_no_camera(tmp_path, capsys):
    """With the geometric metric alone nothing looks from the eye without --png, yet the run placed the default one:
    ``--metrics geometric --radius 1e30`` was refused as putting that eye (3 radii up) past the camera's bound, which
    ``--no-camera --radius 1e30`` takes; and the mesh recorded the eye (metadata "eye"), a glTF stored relative to it
    rather than to the mesh's centre (vertices 1 m apart from --no-camera's same mesh). Now the mesh is that of
    --no-camera, metadata and glTF alike."""
    grid = tmp_path / "g.npz"
    np.savez(grid, elevation=np.add.outer(np.linspace(0.0, 900.0, 18), np.linspace(0.0, 500.0, 36)),
             lat=np.linspace(85.0, -85.0, 18), lon=np.linspace(-175.0, 175.0, 36))
    base = ["-q", "globe", grid, "--face-size", "9", "--device", "cpu"]
    code, _, err = run(capsys, *base, "--metrics", "geometric", "--radius", "1e30", "-o", tmp_path / "far.ply")
    assert code == 0, err
    meshes = {}
    for name, options in (("geometric", ["--metrics", "geometric"]), ("no-camera", ["--no-camera"])):
        out = tmp_path / name / "g.glb"
        out.parent.mkdir()
        code, _, err = run(capsys, *base, *options, "-o", out)
        assert code == 0, err
        meshes[name] = st.export.read_mesh(out)
    assert "eye" not in meshes["geometric"].metadata
    assert np.array_equal(meshes["geometric"].faces, meshes["no-camera"].faces)
    assert np.array_equal(meshes["geometric"].vertices, meshes["no-camera"].vertices)
    assert meshes["geometric"].metadata == meshes["no-camera"].metadata
