"""Fixes from a user-journey hunt on real data: messages a CLI user with a file can act on."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

import stepterrain as st
from stepterrain.export import read_mesh

from .conftest import needs_render
from .conftest import run_cli as run
from .test_cli_fixes import _UNTYPED_NUMBERS

#: (subcommand, option): every option of one number, whole or not
_NUMBER_OPTIONS = sorted({(command, option) for command, option, value in _UNTYPED_NUMBERS
                          if value == "1_0" and option not in ("--spacing", "--tile", "--scale")})


@pytest.mark.parametrize(("command", "option"), _NUMBER_OPTIONS)
@pytest.mark.parametrize("value", ["abc", "200,0"])
def test_a_bad_number_is_refused_in_the_house_style(command, option, value, tmp_path, capsys):
    """--interval abc, --face-size abc and closeup's --stepped 200,0 got argparse's stock "invalid float value:
    'abc'", which said neither what was expected nor why 200,0 is no number; they say "expected a number" (or a
    whole number) and the text typed, one line, exit 2, as the options of several numbers do."""
    out = tmp_path / "out"
    code, stdout, err = run(capsys, command, f"{option}={value}", "-o", out / "x.glb" if command != "batch" else out)
    assert code == 2, err
    line = err.strip()
    assert len(line.splitlines()) == 1 and stdout == "" and "Traceback" not in err, err
    assert f"argument {option}: expected a " in line and "number" in line and f"got {value!r}" in line, line
    assert "invalid" not in line, line
    if "," in value and ("a number;" in line or "a whole number;" in line):  # not --spin's own message
        assert "decimal point" in line, line
    assert not out.exists()


@pytest.mark.parametrize(("lat", "lon", "covers"), [
    (np.linspace(40.5, 39.5, 5), np.linspace(-106.0, -105.0, 6), "covers 1.2 degrees of longitude (-106 to -105)"),
    (np.linspace(40.0, -40.0, 5), np.arange(0.0, 360.0, 60.0), "covers 360 degrees of longitude (0 to 300)"),
])
def test_globe_of_a_regional_grid_names_the_file_and_what_it_covers(lat, lon, covers, tmp_path, capsys):
    """`stepterrain globe front_range.tif` said "lon must cover 360 degrees (W · step = 360)": lon is a Python
    argument a CLI user never gave. The refusal names INPUT, what globe needs and what the file covers."""
    src = tmp_path / "region.npz"
    np.savez(src, elevation=np.ones((len(lat), len(lon)), np.float32), lat=lat, lon=lon)
    code, stdout, err = run(capsys, "-q", "globe", src, "--face-size", "5", "-o", tmp_path / "g.ply")
    assert code == 2, err
    line = err.strip()
    assert len(line.splitlines()) == 1 and "Traceback" not in err, err
    assert f"INPUT {str(src)!r} is no global grid" in line and "360 degrees of longitude" in line, line
    assert covers in line and f"latitudes {lat.min():.6g} to {lat.max():.6g}" in line, line
    assert "lon must" not in line and "lat must" not in line, line
    assert not (tmp_path / "g.ply").exists()


def _npz_with_units(path, units):
    arrays = {"elevation": np.arange(12, dtype=np.float32).reshape(3, 4) + 100.0}
    if units is not None:
        arrays["units"] = np.array(units)
    np.savez(path, **arrays)
    return path


def _geotiff_with_unit(path, unit):
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", height=3, width=4, count=1, dtype="float32", crs="EPSG:32611",
                       transform=from_origin(500000.0, 4000000.0, 30.0, 30.0)) as dst:
        dst.write(np.arange(12, dtype=np.float32).reshape(1, 3, 4) + 100.0)
        if unit is not None:
            dst.units = (unit,)
    return path


@pytest.mark.parametrize("make", [_npz_with_units, _geotiff_with_unit])
def test_height_unit_overriding_a_declared_unit_is_warned(make, tmp_path):
    """--height-unit's help said it was "for a file that names none or one not known", yet it silently overrode a
    unit the file declares (`stepterrain info front_range.npz --height-unit ft` read metres as feet). The override
    stays (load_dem's documented height_unit) and is warned of, naming the file's unit; the heights are those the
    given unit makes, as before."""
    src = make(tmp_path / ("dem.npz" if make is _npz_with_units else "dem.tif"), "m")
    stored = st.load_dem(src).heights
    with pytest.warns(UserWarning, match=r"height_unit='ft' overrides the unit the file declares \(.*'m'\): its "
                                         r"heights are read in ft \(0\.3048 m each\), not in m \(1 m each\)"):
        terrain = st.load_dem(src, height_unit="ft")
    np.testing.assert_allclose(terrain.heights, stored * np.float32(0.3048), rtol=1e-6)


@pytest.mark.parametrize("make", [_npz_with_units, _geotiff_with_unit])
@pytest.mark.parametrize(("declared", "given"), [(None, "ft"), ("ft", "ft"), ("metre", "m"), ("m", "m")])
def test_height_unit_is_silent_where_it_overrides_nothing(make, declared, given, tmp_path):
    """No warning where the file names no unit, or one of the same length as --height-unit's."""
    src = make(tmp_path / ("dem.npz" if make is _npz_with_units else "dem.tif"), declared)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        st.load_dem(src, height_unit=given)


def test_info_height_unit_over_a_declared_unit_warns_naming_the_option(tmp_path, capsys):
    """The CLI's line names --height-unit, the file and both units; the help says it overrides a declared unit."""
    src = _npz_with_units(tmp_path / "dem.npz", "m")
    code, stdout, err = run(capsys, "info", src, "--height-unit", "ft")
    assert code == 0, err
    assert ("stepterrain info: warning: dem.npz: --height-unit 'ft' overrides the unit the file declares (its "
            "'units': 'm')") in err, err
    code, stdout, err = run(capsys, "info", "--help")
    assert "overrides a unit the file names" in " ".join(stdout.split())


def _wavy_dem(path):
    y, x = np.mgrid[0:60, 0:80]
    np.savez(path, elevation=(200 * np.sin(x / 7.0) * np.cos(y / 9.0) + 300).astype(np.float32))
    return path


_ADVICE = re.compile(r"raise the budget \(--memory-budget SIZE\) to at least (\d+[KMG]iB)")


def test_mesh_over_the_budget_with_png_advises_a_budget_the_render_fits(tmp_path, capsys):
    """`--memory-budget 20MB steps dem --png p.png` advised "at least 30MiB" for the mesh, and at 30MiB the render of
    that mesh was refused ("at least 50MiB"). With --png the mesh's refusal names a budget the render of it fits
    too (and both figures); without --png it names the mesh's alone, as before."""
    src = _wavy_dem(tmp_path / "dem.npz")
    argv = ["steps", src, "--interval", "5", "-o", tmp_path / "m.glb"]
    code, _, err = run(capsys, "-q", "--memory-budget", "1100KiB", *argv)
    assert code == 2 and "the stepped mesh (73,858 vertices, 146,018 faces) would need 7.7 MiB" in err, err
    assert _ADVICE.search(err).group(1) == "8MiB", err
    code, _, err = run(capsys, "-q", "--memory-budget", "1100KiB", *argv, "--png", tmp_path / "p.png",
                       "--size", "64x48")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "the stepped mesh (73,858 vertices, 146,018 faces) would need 7.7 MiB" in err, err
    assert "(its --png render, 64x48, needs 13.6 MiB for a mesh of at least 146,018 faces)" in err, err
    # the render's own check, at the budget advised, passes (8MiB did not: "would need 13.6 MiB")
    advised = st.cli._byte_size(_ADVICE.search(err).group(1))
    mesh = st.stepped(st.load_dem(src), interval=5.0)
    st.set_memory_budget(advised)
    try:
        st.render._check_render_budget(64, 48, mesh=(len(mesh.vertices), len(mesh.faces)))
    finally:
        st.set_memory_budget(16 * 1024**3)
    assert not (tmp_path / "m.glb").exists() and not (tmp_path / "p.png").exists()


@needs_render
def test_the_budget_advised_for_a_mesh_with_png_runs_to_the_end(tmp_path, capsys):
    """The budget the refusal advises is one the whole run (mesh, write and render) fits: rerun with it, it writes
    both files."""
    src = _wavy_dem(tmp_path / "dem.npz")
    argv = ["steps", src, "--interval", "5", "-o", tmp_path / "m.glb", "--png", tmp_path / "p.png", "--size", "64x48"]
    code, _, err = run(capsys, "-q", "--memory-budget", "1100KiB", *argv)
    assert code == 2, err
    code, _, err = run(capsys, "-q", "--memory-budget", _ADVICE.search(err).group(1), *argv)
    assert code == 0, err
    assert (tmp_path / "m.glb").stat().st_size > 0 and (tmp_path / "p.png").stat().st_size > 0


def _stepterrain_obj(path):
    from stepterrain.export import save_mesh

    y, x = np.mgrid[0:20, 0:24]
    save_mesh(st.stepped((40 * np.sin(x / 4.0) * np.cos(y / 5.0)).astype(np.float32), interval=10.0), path)
    return path


@pytest.mark.parametrize("fraction", [0.2, 0.5, 0.9, 0.999])
def test_a_stepterrain_obj_cut_short_is_refused_not_read_as_its_first_vertices(fraction, tmp_path, capsys):
    """A stepterrain OBJ cut to 50 kB read (read_mesh, `stepterrain info`) as its first 627 vertices and no face,
    without a word. stepterrain's writer ends every line with a newline: one that ends mid-line is refused."""
    whole = _stepterrain_obj(tmp_path / "whole.obj").read_bytes()
    assert whole.endswith(b"\n") and len(read_mesh(tmp_path / "whole.obj").faces) > 0
    end = int(len(whole) * fraction)
    while whole[end - 1:end] == b"\n":  # mid-line
        end += 1
    cut = tmp_path / "cut.obj"
    cut.write_bytes(whole[:end])
    cut_short = (r"cut\.obj.*the file is cut short: it ends mid-line .*no newline at its end\) and stepterrain's "
                 r"OBJ writer ends every line with a newline")
    with pytest.raises(st.DataFileError, match=cut_short):
        read_mesh(cut)
    code, stdout, err = run(capsys, "info", cut)
    assert code == 2 and "cut short" in err and len(err.strip().splitlines()) == 1, err


def test_obj_files_without_a_final_newline_or_faces_still_read(tmp_path):
    """Legitimate files are read as before: points written by save_mesh (v lines, no f line), a hand-written OBJ
    whose last line has no newline; a foreign OBJ ending in a face of fewer than 3 corners, mid-line, is cut short."""
    import trimesh

    from stepterrain.export import save_mesh

    points = tmp_path / "points.obj"
    save_mesh(trimesh.Trimesh(vertices=np.arange(12.0).reshape(4, 3), faces=np.empty((0, 3), int), process=False),
              points)
    mesh = read_mesh(points)
    assert len(mesh.vertices) == 4 and len(mesh.faces) == 0
    hand = tmp_path / "hand.obj"
    hand.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3")
    mesh = read_mesh(hand)
    assert len(mesh.vertices) == 3 and mesh.faces.tolist() == [[0, 1, 2]]
    hand.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0")
    assert len(read_mesh(hand).vertices) == 3
    hand.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3")
    with pytest.raises(st.DataFileError, match=r"cut short: it ends mid-line \('f 1 3'.*a face of 2 corners"):
        read_mesh(hand)
