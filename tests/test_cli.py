"""The ``stepterrain`` command, run in-process on small DEMs: outputs, progress, exit codes, atomicity."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from stepterrain import cli, render
from stepterrain.errors import MissingDependencyError

from .conftest import run_cli as run

AVAILABLE, REASON = render.offscreen_available()


def files_in(folder):
    return sorted(p.name for p in folder.iterdir())


def test_steps_writes_a_loadable_glb_and_reports_progress(dem, tmp_path, capsys):
    out = tmp_path / "out" / "hill.glb"
    code, _, err = run(capsys, "steps", dem, "--interval", "2", "-o", out)
    assert code == 0, err
    mesh = trimesh.load(out, force="mesh")
    assert len(mesh.faces) > 0
    z = np.unique(np.round(mesh.vertices[:, 1], 4))  # the file as viewers see it: glTF's y is up
    assert set(z.tolist()) <= {0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0}
    for stage in ("loading", "kernels ready", "stepping", "faces", "writing"):
        assert stage in err
    assert "Traceback" not in err


def test_default_interval_is_round_and_announced(dem, tmp_path, capsys):
    code, _, err = run(capsys, "steps", dem, "-o", tmp_path / "auto.ply")
    assert code == 0, err
    assert "using --interval 1," in err  # heights 0-11.4: 1 gives 11 steps, 0.5 would give 23
    assert trimesh.load(tmp_path / "auto.ply").faces.shape[0] > 0


@pytest.mark.parametrize("value", [(0.0, 10.0), (315.0, 2295.0), (0.0, 1e-3), (-5.0, 5.0)])
def test_nice_interval_is_round_and_near_fifteen_steps(value):
    interval = cli.nice_interval(value)
    mantissa = interval / 10.0 ** np.floor(np.log10(interval))
    assert any(np.isclose(mantissa, m) for m in (1.0, 2.0, 2.5, 5.0))
    steps = (value[1] - value[0]) / interval
    assert 7 <= steps <= 30


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".gltf"])
def test_formats_by_extension(dem, tmp_path, capsys, suffix):
    out = tmp_path / f"hill{suffix}"
    colours = [] if suffix == ".stl" else ["--colormap", "viridis"]  # an STL holds none: refused there
    code, _, err = run(capsys, "steps", dem, "--levels", "1,3,5,7,9", *colours, "-o", out)
    assert code == 0, err
    assert len(trimesh.load(out, force="mesh").faces) > 0


def test_solid_stl_is_watertight(dem, tmp_path, capsys):
    out = tmp_path / "print.stl"
    code, _, err = run(capsys, "steps", dem, "--interval", "2", "--solid", "--floor", "-2", "-o", out)
    assert code == 0, err
    mesh = trimesh.load(out)
    assert mesh.is_watertight
    assert mesh.bounds[0][2] == pytest.approx(-2.0)


@pytest.mark.parametrize(
    ("argv", "floor"),
    [
        (["--interval", "2", "--base", "-5"], None),
        (["--interval", "2", "--base", "-1E+0"], None),
        (["--levels", "-5,0,5"], None),
        (["--levels", "-1e1,-.5,5"], None),
        (["--interval", "2", "--solid", "--floor", "-1e1"], -10.0),
        (["--interval", "2", "--solid", "--floor", "-2.5"], -2.5),
    ],
)
def test_negative_numbers_after_an_option_are_its_value(dem, tmp_path, capsys, argv, floor):
    """'--base -1e20' is the value -1e20, not an unknown option '-1e20' (argparse's own pattern knows neither
    exponents nor lists)."""
    out = tmp_path / "neg.stl"
    code, _, err = run(capsys, "steps", dem, *argv, "-o", out)
    assert code == 0, err
    if floor is not None:
        assert trimesh.load(out).bounds[0][2] == pytest.approx(floor)


def test_closeup_help_shows_negative_lists_as_plain_values(dem, tmp_path, capsys):
    """closeup --help said values starting with a minus need '=' (--offset=-500,0,3000), which the parser stopped
    needing when it learnt negative numbers and lists; the help showed a workaround as a rule. Found reading --help."""
    code, out, _ = run(capsys, "closeup", "--help")
    assert code == 0 and "need '='" not in out and "--offset -500,0,3000" in out
    code, _, err = run(capsys, "-q", "closeup", dem, "--offset", "-5,0,30", "--rotation", "-10,-5", "-o",
                       tmp_path / "c.ply")
    assert code == 0, err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["steps", "{dem}", "--interval", "2", "--base", "-1e20", "-o", "{out}.glb"],
         "with --base -1e+20, more than 2**53 intervals"),
        (["steps", "{dem}", "--interval", "2", "--base", "-inf", "-o", "{out}.glb"], "base must be finite; got -inf"),
        (["batch", "{dem}", "--tile", "8", "--interval", "2", "--base", "-1e20", "--scheduler", "serial",
          "-o", "{out}"], "with --base -1e+20, more than 2**53 intervals"),
        (["texture", "{dem}", "--azimuth", "-1e400", "-o", "{out}.png"], "--azimuth must be a finite number"),
        (["batch", "{dem}", "--tile", "8", "--levels", "1,2", "--base", "-0.5", "--scheduler", "serial",
          "-o", "{out}"], "--base applies only to uniform isovalues"),
    ],
)
def test_a_negative_number_reaches_the_value_checks(dem, tmp_path, capsys, argv, message):
    code, _, err = run(capsys, *[a.format(dem=dem, out=tmp_path / "neg") for a in argv])
    assert code == 2
    assert message in err and "expected one argument" not in err


def test_library_warnings_print_as_one_line(tmp_path, capsys):
    """A library warning prints as one 'stepterrain steps: warning:' line, no source line or warning class: here a
    height on a threshold that lies one float32 step below the next (levels a few float32 steps apart), which cannot
    be moved up within its level for a solid. Integer heights on the thresholds of --interval 2 give a watertight
    solid without a warning (they warned that it may leak, and to shift --base)."""
    heights = np.add.outer(np.arange(12), np.arange(12)).astype(np.float32)  # odd heights sit on thresholds
    path = tmp_path / "ints.npy"
    np.save(path, heights)
    code, _, err = run(capsys, "steps", path, "--interval", "2", "--solid", "-o", tmp_path / "p.stl")
    assert code == 0 and "warning:" not in err, err
    assert trimesh.load(tmp_path / "p.stl").is_watertight
    np.save(path, heights % 3)  # 1.0 sits on t_0 = 1, one float32 step below t_1
    code, _, err = run(capsys, "steps", path, "--levels", "0.99999994,1,1.0000002", "--solid", "-o",
                       tmp_path / "q.stl")
    assert code == 0, err
    lines = [line for line in err.splitlines() if "threshold" in line]
    assert len(lines) == 1 and lines[0].startswith("stepterrain steps: warning: some heights sit exactly"), err
    assert "UserWarning" not in err and "warnings.warn" not in err


@pytest.mark.parametrize("lens", [["--lens", "15,-11,6"],  # .npy rows run north to south: y = -row
                                  ["--lens-relative", "0.5,0.5,0.3", "--lens-edge", "2"]])
def test_lens_keeps_original_heights_inside(dem, tmp_path, capsys, lens):
    out = tmp_path / "lens.glb"
    code, _, err = run(capsys, "steps", dem, "--interval", "2", *lens, "-o", out)
    assert code == 0, err
    assert "lens at" in err
    z = trimesh.load(out, force="mesh").vertices[:, 2]
    assert not np.all(np.isclose(z % 2.0, 0.0, atol=1e-4) | np.isclose(z % 2.0, 2.0, atol=1e-4))


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_png_render(dem, tmp_path, capsys):
    from PIL import Image

    out, png = tmp_path / "hill.glb", tmp_path / "img" / "hill.png"
    code, _, err = run(capsys, "steps", dem, "--interval", "1", "-o", out, "--png", png, "--size", "160x120")
    assert code == 0, err
    assert "rendering 160x120" in err
    with Image.open(png) as image:
        assert image.size == (160, 120)
        assert np.asarray(image).std() > 5


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--interval", "1", "--levels", "1,2"], "not allowed with argument"),
        (["--interval", "-1"], "error: --interval must be a positive"),
        (["--interval", "nan"], "error: --interval must be a positive"),
        (["--levels", "3,2,1"], "error: --levels must be strictly increasing"),
        (["--levels", "1,2", "--base", "0.5"], "error: --base applies only to uniform isovalues"),
        (["--lens", "1,2,3", "--lens-edge", "-1"], "error: --lens-edge must be >= 0"),
        (["--levels", "a,b"], "comma-separated"),
        (["--levels", "1,,2"], "expected comma-separated heights a,b,c; got '1,,2' (an empty value)"),
        (["--levels", "1,2,"], "expected comma-separated heights a,b,c; got '1,2,' (an empty value)"),
        (["--lens", "15,,-11,6"], "expected x,y,r; got '15,,-11,6' (an empty value)"),
        (["--gamma", "2"], "--gamma must lie in [0, 1]"),
        (["--lens", "1,2"], "x,y,r"),
        (["--lens", "1,2,-3"], "error: --lens radius must be a positive"),
        (["--floor", "0"], "--floor applies only with --solid"),
        (["--interval", "1", "--solid", "--floor", "1e9"], "--floor must lie below the lowest surface height"),
        (["--interval", "1", "--solid", "--floor=-1e300"], "--floor must fit in float32 (|x| < 3.4e+38); got -1e+300"),
        (["--colormap", "no-such-map"], "colormap"),
        (["--device", "tpu"], "error: --device"),
        (["--size", "huge"], "WIDTHxHEIGHT"),
    ],
)
def test_bad_input_exits_2_with_a_message_and_no_output(dem, tmp_path, capsys, argv, message):
    out = tmp_path / "bad.glb"
    code, _, err = run(capsys, "steps", dem, *argv, "-o", out)
    assert code == 2
    assert message in err
    assert "Traceback" not in err
    assert files_in(tmp_path) == ["hill.npy"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["globe", "--face-size", "100"], "stepterrain globe: error: --face-size must be 2^k + 1"),
        (["globe", "--exaggeration", "-1"], "stepterrain globe: error: --exaggeration must be a positive"),
        (["globe", "--error", "-1"], "stepterrain globe: error: --error must be a finite number >= 0"),
        (["globe", "--metrics", "foo"], "stepterrain globe: error: --metrics must be names among"),
    ],
)
def test_library_errors_name_the_option_not_the_argument(tmp_path, capsys, argv, message):
    code, _, err = run(capsys, "-q", *argv, "-o", tmp_path / "bad.glb")
    assert code == 2
    assert message in err, err
    assert files_in(tmp_path) == []


def test_as_option_rewrites_only_a_leading_name_the_subcommand_has():
    sub = cli._subcommand(cli.build_parser(), "steps")
    assert cli._as_option("interval must be positive", sub) == "--interval must be positive"
    assert cli._as_option("device='tpu' is unknown", sub) == "--device 'tpu' is unknown"
    assert cli._as_option("face_size must be 2^k + 1", sub) == "face_size must be 2^k + 1"  # not a steps option
    assert cli._as_option("cannot read 'x.npy': no such file", sub) == "cannot read 'x.npy': no such file"
    assert cli._as_option("--gamma must lie in [0, 1]", sub) == "--gamma must lie in [0, 1]"
    assert cli._as_option("output folder '/x' is not writable", sub) == "output folder '/x' is not writable"
    texture = cli._subcommand(cli.build_parser(), "texture")
    assert cli._as_option("mesh has no faces; nothing to render", texture) == "mesh has no faces; nothing to render"
    assert cli._as_option("z_factor x height range must stay below 1e+18", texture).startswith("--z-factor x")


@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_works_before_and_after_the_subcommand(dem, tmp_path, capsys, where):
    argv = ["steps", dem, "--interval", "2", "-o", tmp_path / "q.ply"]
    argv = ["-q", *argv] if where == "before" else [*argv[:1], "-q", *argv[1:]]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    assert err == ""
    code, _, err = run(capsys, "steps", dem, "--interval", "2", "-o", tmp_path / "loud.ply")
    assert code == 0 and "stepping" in err  # without -q the progress lines are there


def test_missing_file_and_unknown_extensions(dem, tmp_path, capsys):
    code, _, err = run(capsys, "steps", tmp_path / "nope.npy", "-o", tmp_path / "x.glb")
    assert code == 2 and "nope.npy" in err and "Traceback" not in err
    code, _, err = run(capsys, "steps", dem, "-o", tmp_path / "x.xyz")
    assert code == 2 and "unknown extension '.xyz'" in err
    code, _, err = run(capsys, "steps", dem, "-o", tmp_path / "x.glb", "--png", tmp_path / "x.jpg")
    assert code == 2 and "--png" in err
    text = tmp_path / "notes.txt"
    text.write_text("not elevation data")
    code, _, err = run(capsys, "steps", text, "-o", tmp_path / "x.glb")
    assert code == 2 and "Traceback" not in err
    assert files_in(tmp_path) == ["hill.npy", "notes.txt"]


def test_a_failing_render_leaves_no_partial_output(dem, tmp_path, capsys, monkeypatch):
    def broken(*args, **kwargs):
        raise MissingDependencyError("no OpenGL here (simulated)")

    monkeypatch.setattr(render, "render_mesh", broken)
    monkeypatch.setattr(render, "require_offscreen", lambda: "simulated")
    code, _, err = run(capsys, "steps", dem, "--interval", "1", "-o", tmp_path / "a.glb",
                       "--png", tmp_path / "a.png")
    assert code == 2 and "simulated" in err
    assert files_in(tmp_path) == ["hill.npy"]  # neither the mesh nor the image, and no temporary files


def test_a_failing_write_leaves_no_partial_output(dem, tmp_path, capsys, monkeypatch):
    def disk_full(self, data):
        with open(self, "wb") as handle:
            handle.write(bytes(data)[: len(data) // 2])
        raise OSError(28, "No space left on device (simulated)")

    class DiskFullHandle:  # a file opened for writing that fills the disk halfway through its first write
        def __init__(self, handle):
            self.handle = handle

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.handle.close()

        def write(self, data):
            self.handle.write(bytes(data)[: len(data) // 2])
            raise OSError(28, "No space left on device (simulated)")

    real_open = Path.open

    def open_disk_full(self, mode="r", *args, **kwargs):
        handle = real_open(self, mode, *args, **kwargs)
        return DiskFullHandle(handle) if "w" in mode else handle

    monkeypatch.setattr(Path, "write_bytes", disk_full)
    monkeypatch.setattr(Path, "open", open_disk_full)
    for name in ("w.stl", "w.glb"):
        code, _, err = run(capsys, "steps", dem, "--interval", "1", "-o", tmp_path / name)
        assert code == 2 and "No space left" in err and "Traceback" not in err
        assert files_in(tmp_path) == ["hill.npy"]  # no truncated mesh, no temporary file


def test_an_unwritable_png_folder_fails_before_the_mesh_is_written(dem, tmp_path, capsys, monkeypatch):
    # the mesh used to be written first, then the PNG failed: exit 2 with half of the outputs on disk
    monkeypatch.setattr(render, "require_offscreen", lambda: "simulated")
    monkeypatch.setattr(render, "render_mesh", lambda *a, **k: np.zeros((8, 8, 3), np.uint8))
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for png in (blocker / "a.png", tmp_path / "dir.png"):
        (tmp_path / "dir.png").mkdir(exist_ok=True)
        code, _, err = run(capsys, "-q", "steps", dem, "--interval", "1", "-o", tmp_path / "out" / "a.glb",
                           "--png", png)
        assert code == 2 and "--png" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert not (tmp_path / "out").exists()



def test_an_output_folder_that_is_a_dangling_link_is_written_through_or_refused_before_any_work(dem, tmp_path, capsys,
                                                                                                  monkeypatch):
    """-o through a symbolic link to a folder that does not exist yet (out -> /data/new) failed after all the work,
    "cannot create the output folder 'out': File exists" (the check walked past the link to its own folder); the
    folder is now made where the link leads, as a dangling link to the file itself is, and one that cannot be made
    there (under a file) is refused before any work."""
    import stepterrain as st

    (tmp_path / "out").symlink_to(tmp_path / "new" / "meshes")
    code, _, err = run(capsys, "-q", "steps", dem, "--interval", "1", "-o", tmp_path / "out" / "a.glb")
    assert code == 0, err
    assert (tmp_path / "out").is_symlink() and (tmp_path / "new" / "meshes" / "a.glb").is_file()
    (tmp_path / "file").write_text("x")
    (tmp_path / "bad").symlink_to(tmp_path / "file" / "meshes")
    monkeypatch.setattr(st, "stepped", lambda *a, **k: pytest.fail("stepped before the output was checked"))
    code, _, err = run(capsys, "-q", "steps", dem, "--interval", "1", "-o", tmp_path / "bad" / "a.glb")
    assert code == 2 and "--output" in err and "is not a folder" in err and len(err.strip().splitlines()) == 1

def test_help_version_and_usage(capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0 and "steps" in out and "info" in out
    code, out, _ = run(capsys, "steps", "--help")
    assert code == 0 and "examples:" in out and "--lens-relative" in out
    code, out, _ = run(capsys, "--version")
    assert code == 0 and out.startswith("stepterrain ")
    code, _, err = run(capsys)
    assert code == 2
    code, _, err = run(capsys, "frobnicate")
    assert code == 2 and "invalid choice" in err
    code, _, err = run(capsys, "steps")
    assert code == 2 and "-o/--output" in err


def test_python_dash_m_runs_the_command(tmp_path):
    """``python -m stepterrain`` is the same command, its exit status passed on (2 for a usage error)."""
    import subprocess

    started = [subprocess.Popen([sys.executable, "-m", "stepterrain", arg], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=tmp_path)
               for arg in ("--version", "frobnicate")]  # both at once: each imports stepterrain (2.5 s)
    try:
        outputs = [p.communicate(timeout=120) for p in started]  # then their exit statuses are set
        ok, bad = (subprocess.CompletedProcess(p.args, p.returncode, *out) for p, out in zip(started, outputs,
                                                                                               strict=True))
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
                p.communicate()
    assert ok.returncode == 0 and ok.stdout.startswith("stepterrain "), ok.stderr
    assert bad.returncode == 2 and "invalid choice" in bad.stderr and bad.stderr.startswith("stepterrain: error:")


def test_info_on_a_dem_and_on_a_mesh(dem, tmp_path, capsys):
    code, out, err = run(capsys, "info", dem, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["shape"] == [24, 32] and summary["kind"] == "grid"
    mesh_path = tmp_path / "hill.glb"
    assert run(capsys, "steps", dem, "--interval", "2", "-o", mesh_path)[0] == 0
    code, out, err = run(capsys, "info", mesh_path)
    assert code == 0, err
    assert "faces" in out and "vertices" in out
    code, _, err = run(capsys, "info", tmp_path / "missing.glb")
    assert code == 2 and "missing.glb" in err


@pytest.mark.parametrize("kind", ["mesh", "dem"])
def test_info_on_a_large_file_says_it_is_reading_on_a_terminal_only(dem, tmp_path, capsys, monkeypatch, kind):
    """``info big.obj`` (a 190 MB OBJ: a minute in trimesh's reader, one call with no progress to report) printed
    nothing until the summary. A file of at least _INFO_LOUD_BYTES now says "reading PATH (N MB)..." and its time on
    stderr when that is a terminal; piped or captured (scripts, these tests) info's stderr stays empty, and -q
    silences it as every progress line."""
    import io

    path = dem
    if kind == "mesh":
        path = tmp_path / "hill.obj"
        assert run(capsys, "-q", "steps", dem, "--interval", "2", "-o", path)[0] == 0
    size = path.stat().st_size

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    def info(*options, limit=size, stream_cls=Terminal):
        monkeypatch.setattr(cli, "_INFO_LOUD_BYTES", limit)
        stream = stream_cls()
        monkeypatch.setattr("sys.stderr", stream)
        code = cli.main(["info", str(path), *options])
        return code, capsys.readouterr().out, stream.getvalue()

    code, out, err = info()
    lines = err.splitlines()
    assert code == 0 and len(lines) == 2, err
    assert lines[0] == f"stepterrain: reading {path} ({cli._size(path)})..." and lines[1].startswith(
        "stepterrain:   in "), err
    assert out == info(stream_cls=io.StringIO)[1]  # the summary itself is the same
    assert info(stream_cls=io.StringIO)[2] == ""  # not a terminal
    assert info(limit=size + 1)[2] == ""  # smaller than the limit
    assert info("-q")[2] == ""
    assert info("--json")[2].startswith("stepterrain: reading")  # the JSON is on stdout, untouched
    json.loads(info("--json")[1])


def test_info_with_stderr_closed_still_prints_its_summary(dem, capsys, monkeypatch):
    """With stderr closed (``stepterrain info dem.npy 2>&-``, a service without one: Python's sys.stderr is None),
    the large-file check asked None whether it was a terminal: info died with an AttributeError, exit 1, and printed
    no summary. No stream is no terminal: the summary is printed, exit 0."""
    expected = run(capsys, "info", dem)
    monkeypatch.setattr(cli, "_INFO_LOUD_BYTES", 0)  # every file a large one
    monkeypatch.setattr("sys.stderr", None)
    code = cli.main(["info", str(dem)])
    assert (code, capsys.readouterr().out) == (0, expected[1])


def test_info_counts_nonfinite_vertices_and_bounds_the_finite_ones(tmp_path, capsys):
    mesh = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, np.nan], [1, 1, 2]], [[0, 1, 2], [1, 3, 2]], process=False)
    path = tmp_path / "nan.ply"
    mesh.export(path)
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert summary["nonfinite_vertices"] == 1
    assert summary["bounds_min"] == [0, 0, 0] and summary["bounds_max"] == [1, 1, 2]


def test_info_json_stays_json_without_a_finite_vertex_and_names_a_folder(tmp_path, capsys):
    """A mesh file whose vertices are all NaN printed "bounds_min": [NaN, NaN, NaN] under --json, which is no JSON
    (strict parsers and jq refuse it): the bounds are null now. A folder named like a mesh 'does not exist'
    said the message; it exists and is no file."""
    path = tmp_path / "nan.ply"
    path.write_bytes(trimesh.exchange.ply.export_ply(
        trimesh.Trimesh(np.full((3, 3), np.nan), [[0, 1, 2]], process=False), encoding="ascii"))
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0, err

    def refuse(constant):
        raise ValueError(f"not JSON: {constant}")

    summary = json.loads(out, parse_constant=refuse)
    assert summary["bounds_min"] is None and summary["bounds_max"] is None and summary["nonfinite_vertices"] == 3
    code, out, err = run(capsys, "info", path)
    assert code == 0 and "bounds_min          None" in out, (out, err)
    (tmp_path / "folder.glb").mkdir()
    code, _, err = run(capsys, "info", tmp_path / "folder.glb")
    assert code == 2 and err.strip().endswith("folder.glb' is not a regular file"), err


def test_default_input_is_the_embedded_dem(tmp_path, capsys):
    code, out, err = run(capsys, "info")
    assert code == 0, err
    assert "643" in out and "1197" in out


def test_an_empty_mesh_is_written_with_a_warning(tmp_path, capsys):
    path = tmp_path / "holes.npy"
    np.save(path, np.array([[1.0, np.nan, 2.0], [np.nan, np.nan, np.nan]], np.float32))
    code, _, err = run(capsys, "steps", path, "--interval", "1", "-o", tmp_path / "e.ply")
    assert code == 0, err
    assert "stepterrain steps: warning: the mesh is empty" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["steps", "{png}", "--interval", "1000", "-o", "{tmp}/a.glb", "--png", "{png}"],
        ["texture", "{png}", "-o", "{png}"],
        ["texture", "{png}", "-o", "{tmp}/t.png", "--normals", "{tmp}/./dem.png"],
        ["closeup", "{png}", "--size", "160x120", "-o", "{png}"],
        ["globe", "--face-size", "9", "--texture", "{png}", "-o", "{tmp}/g.glb", "--png", "{png}"],
        ["batch", "{png}", "--tile", "8", "--interval", "1000", "--scheduler", "serial", "-o", "{tmp}/b",
         "--png", "{png}"],
    ],
)
def test_an_output_naming_an_input_file_is_refused(tmp_path, capsys, argv):
    """An output path that is the INPUT DEM (or globe's --texture image) replaced the input with the output."""
    from PIL import Image

    png = tmp_path / "dem.png"
    Image.fromarray((np.arange(24 * 32).reshape(24, 32) * 50).astype(np.uint16)).save(png)
    before = png.read_bytes()
    code, _, err = run(capsys, "-q", *[a.format(png=png, tmp=tmp_path) for a in argv])
    assert code == 2, err
    assert "give the output its own name" in err and len(err.strip().splitlines()) == 1, err
    assert png.read_bytes() == before
    assert files_in(tmp_path) == ["dem.png"]


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["steps", "", "--interval", "100", "-o", "{tmp}/a.glb"], "INPUT"),
        (["steps", "{dem}", "--interval", "2", "-o", "{tmp}/a.glb", "--png", ""], "--png"),
        (["texture", "", "-o", "{tmp}/t.png"], "INPUT"),
        (["texture", "{dem}", "-o", "{tmp}/t.png", "--mesh", ""], "--mesh"),
        (["texture", "{dem}", "-o", "{tmp}/t.png", "--png", ""], "--png"),
        (["texture", "{dem}", "-o", "{tmp}/t.png", "--normals", ""], "--normals"),
        (["closeup", "", "-o", "{tmp}/c.ply"], "INPUT"),
        (["closeup", "{dem}", "-o", "{tmp}/c.ply", "--png", ""], "--png"),
        (["closeup", "{dem}", "-o", "{tmp}/c.ply", "--gif", ""], "--gif"),
        (["globe", "", "--face-size", "9", "-o", "{tmp}/g.ply"], "INPUT"),
        (["globe", "--face-size", "9", "-o", "{tmp}/g.ply", "--texture", ""], "--texture"),
        (["globe", "--face-size", "9", "-o", "{tmp}/g.ply", "--png", ""], "--png"),
        (["batch", "", "--interval", "100", "--scheduler", "serial", "-o", "{tmp}/b"], "INPUT"),
        (["batch", "{dem}", "--tile", "8", "--interval", "2", "--scheduler", "serial", "-o", ""], "-o/--output"),
        (["batch", "{dem}", "--tile", "8", "--interval", "2", "--scheduler", "serial", "-o", "{tmp}/b",
          "--png", ""], "--png"),
        (["info", ""], "FILE"),
    ],
)
def test_an_empty_path_is_refused_not_ignored(dem, tmp_path, capsys, argv, option):
    """An empty INPUT (an unset shell variable) silently meant the embedded DEM (a 0.8 GB mesh at --interval 2),
    and an empty --png/--gif/--mesh/--normals/--texture was silently skipped."""
    code, out, err = run(capsys, "-q", *[a.format(dem=dem, tmp=tmp_path) for a in argv])
    assert code == 2, err
    assert err == f"stepterrain {argv[0]}: error: argument {option}: expected a file name; got ''\n"
    assert out == "" and files_in(tmp_path) == ["hill.npy"]


def test_batch_png_naming_the_output_folder_is_refused_before_any_work(dem, tmp_path, capsys):
    """`batch -o out.png --png out.png` stepped and wrote every tile into the folder out.png, then failed writing the
    overview over that folder ("Is a directory"). Found by giving one path to both outputs of each subcommand."""
    out = tmp_path / "b.png"
    code, _, err = run(capsys, "-q", "batch", dem, "--tile", "8", "--interval", "2", "--scheduler", "serial",
                       "-o", out, "--png", tmp_path / "." / "b.png")
    assert code == 2, err
    assert err.startswith("stepterrain batch: error: --output and --png name the same path") and len(
        err.strip().splitlines()) == 1, err
    assert files_in(tmp_path) == ["hill.npy"]


@pytest.mark.parametrize("suffix", [".glb", ".gltf", ".obj", ".ply", ".stl", ".3mf"])
def test_info_describes_the_empty_mesh_steps_writes(tmp_path, capsys, suffix):
    """steps writes an all-nodata DEM as a valid empty mesh (with a warning), but `info` on that file exited 2 with
    "holds no triangle mesh". Found by running info on the output of each subcommand in each format."""
    path = tmp_path / "holes.npy"
    np.save(path, np.array([[1.0, np.nan, 2.0], [np.nan, np.nan, np.nan]], np.float32))
    out = tmp_path / f"e{suffix}"
    code, _, err = run(capsys, "-q", "steps", path, "--interval", "1", "-o", out)
    assert code == 0, err
    code, text, err = run(capsys, "info", out, "--json")
    assert code == 0, err
    summary = json.loads(text)
    assert (summary["vertices"], summary["faces"], summary["bounds_min"], summary["bounds_max"]) == (0, 0, None, None)


def test_every_subcommand_names_itself_and_its_input_in_the_mesh_metadata(dem, tmp_path, capsys):
    """steps, globe, texture and batch store generator and input in the glTF extras (`info` shows them); closeup's
    scene mesh stored only its close-up count. Found running info on each subcommand's mesh."""
    out = tmp_path / "scene.glb"
    code, _, err = run(capsys, "-q", "closeup", dem, "-o", out)
    assert code == 0, err
    code, text, err = run(capsys, "info", out, "--json")
    assert code == 0, err
    summary = json.loads(text)
    assert summary["meta.generator"] == "stepterrain closeup" and summary["meta.input"] == str(dem)
    assert summary["meta.closeups"] == 1


def test_info_welds_an_stl_so_a_watertight_solid_reads_as_one(dem, tmp_path, capsys):
    """STL keeps no shared vertices: `info print.stl` read it unwelded (process=False) and said a watertight solid
    from `steps --solid` was not watertight, with three vertices per face. Found by running info on every format."""
    for suffix in (".stl", ".ply"):
        out = tmp_path / f"print{suffix}"
        code, _, err = run(capsys, "steps", dem, "--interval", "2", "--base", "0.5", "--solid", "-o", out)
        assert code == 0, err
        code, text, err = run(capsys, "info", out, "--json")
        assert code == 0, err
        summary = json.loads(text)
        assert summary["watertight"] is True and summary["winding_consistent"] is True, (suffix, summary)
        if suffix == ".ply":
            ply = summary
    assert summary["vertices"] == ply["vertices"] and summary["faces"] == ply["faces"]


def test_info_leaves_out_an_stl_headers_nul_padding(dem, tmp_path, capsys):
    """An STL's 80-byte header is padded with NUL bytes; `info` printed them as meta.header (80 NULs: grep called
    the output binary). Found by running info on every mesh format."""
    out = tmp_path / "hill.stl"
    assert run(capsys, "steps", dem, "--interval", "2", "-o", out)[0] == 0
    header = b"solid hill".ljust(80, b"\x00")
    data = out.read_bytes()
    out.write_bytes(header + data[80:])
    code, text, err = run(capsys, "info", out)
    assert code == 0, err
    assert "\x00" not in text and "solid hill" in text
    out.write_bytes(b"\x00" * 80 + data[80:])
    code, text, err = run(capsys, "info", out, "--json")
    assert code == 0 and "meta.header" not in json.loads(text) and "\\u0000" not in text, text


def test_steps_with_stderr_closed_prints_nothing_on_stdout(dem, tmp_path, capsys, monkeypatch):
    """With stderr closed (``stepterrain steps ... 2>&-``: Python's sys.stderr is None) the progress lines went
    to stdout (``print(file=None)`` writes there), mixed into what a script reads from the command, and the run died
    after loading the DEM (exit 1, no mesh). Now what would go to stderr is dropped: stdout stays empty, the mesh is
    written, an error still exits 2, and stderr is None again after."""
    monkeypatch.setattr("sys.stderr", None)
    assert cli.main(["steps", str(dem), "--interval", "50", "-o", str(tmp_path / "out.ply")]) == 0
    assert capsys.readouterr().out == ""
    assert (tmp_path / "out.ply").stat().st_size > 0
    assert cli.main(["steps", str(dem), "--interval", "-1", "-o", str(tmp_path / "bad.ply")]) == 2
    assert capsys.readouterr().out == ""
    assert sys.stderr is None


@pytest.mark.parametrize(("option", "name"), [("-o", "a.glb"), ("--png", "a.png")])
def test_an_output_ending_in_a_folder_separator_is_refused_before_any_work(dem, tmp_path, capsys, monkeypatch,
                                                                              option, name):
    """'steps -o x.glb/' (a folder meant) wrote a file named x.glb: Path drops the trailing '/'. It is refused
    naming the option, before any work, and nothing is written."""
    import stepterrain as st

    monkeypatch.setattr(st, "stepped", lambda *a, **k: pytest.fail("stepped before the output was checked"))
    monkeypatch.setattr(render, "require_offscreen", lambda: "simulated")
    given = str(tmp_path / name) + "/"
    code, _, err = run(capsys, "-q", "steps", dem, "--interval", "1", option, given)
    assert code == 2, err
    assert f"{'--output' if option == '-o' else '--png'} {given!r} ends in '/', so it names a folder" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / name).exists()
