"""Command-line leftovers of earlier reviews, each as a demanding GIS user meets it: an option given twice, the 3MF
unit of every export path, a compound CRS's vertical unit, the over-budget advice of a solid's render, and the
close-up framing error's wording."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from stepterrain import cli

from .conftest import run_cli as run


# ------------------------------------------------------------------------------------------ an option given twice
@pytest.mark.parametrize("argv, option, typed", [
    (["steps", "--interval", "10", "--interval", "20", "-o", "{tmp}/a.glb"], "--interval", "('10', then '20')"),
    (["steps", "-o", "{tmp}/a.glb", "-o", "{tmp}/b.glb"], "-o/--output", "('{tmp}/a.glb', then '{tmp}/b.glb')"),
    (["steps", "-o", "{tmp}/a.glb", "--output={tmp}/b.glb"], "-o/--output", "('{tmp}/a.glb', then '{tmp}/b.glb')"),
    (["steps", "--inter", "10", "--interval", "20", "-o", "{tmp}/a.glb"], "--interval", "('10', then '20')"),
    (["steps", "--camera", "top", "--camera", "10,20", "--png", "{tmp}/a.png"], "--camera", "('top', then '10,20')"),
    (["info", "--band", "1", "--band", "2"], "--band", "('1', then '2')"),
    (["globe", "x.npz", "--face-size", "8", "--face-size", "16", "-o", "{tmp}/g.glb"], "--face-size",
     "('8', then '16')"),
    (["closeup", "--roi-relative", "0.5,0.5,0.2", "--size", "64x48", "--size", "80x60", "-o", "{tmp}/c.png"],
     "--size", "('64x48', then '80x60')"),
    (["texture", "--texel-size", "30", "--texel-size", "60", "-o", "{tmp}/t.glb"], "--texel-size",
     "('30', then '60')"),
    (["batch", "tiles", "--interval", "5", "--interval", "6", "-o", "{tmp}/out"], "--interval", "('5', then '6')"),
])
def test_an_option_given_twice_with_other_values_is_refused_naming_it(tmp_path, capsys, argv, option, typed):
    """argparse kept the last of ``--interval 10 --interval 20`` and of ``-o a.glb -o b.glb`` silently: the run
    stepped at 20 and wrote b.glb alone, the user's first value (or first output) dropped. Now the option given twice
    with two values is a usage error naming it and both values as typed, before any work; nothing is written."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == "", err
    assert f"error: argument {option}: given twice {typed.replace('{tmp}', str(tmp_path))}; it takes one value: " \
           "give it once" in err, err
    assert list(tmp_path.iterdir()) == []


def test_an_option_given_twice_with_one_value_and_the_repeating_options_still_work(tmp_path, capsys):
    """The same value twice is no conflict (a script's defaults then the user's, alike); the options meant to repeat
    (--nodata: extend; closeup's --roi, --scale, --stepped: append) and flags (-q) take every value given."""
    parser = cli.build_parser()
    args = parser.parse_args(["steps", "--interval", "10", "--interval", "10.0", "-q", "-q",
                              "--nodata", "-9999", "--nodata", "-32768,5"])
    assert args.interval == 10.0 and args.quiet is True and args.nodata == [-9999.0, -32768.0, 5.0]
    args = parser.parse_args(["closeup", "--roi-relative", "0.3,0.3,0.1", "--roi-relative", "0.7,0.7,0.1",
                              "--scale", "2", "--scale", "3", "--stepped", "50", "--stepped", "100"])
    assert len(args.roi_relative) == 2 and args.scale == [(2.0,), (3.0,)] and args.stepped == [50.0, 100.0]
    # each parse starts afresh: a parser used twice does not take the first parse's value for a repeat
    assert parser.parse_args(["steps", "--interval", "20"]).interval == 20.0
    code, out, err = run(capsys, "steps", "--interval", "100", "--interval", "100", "--png", tmp_path / "a.png",
                         "--size", "64x48", "-q")
    assert code == 0 and (tmp_path / "a.png").is_file(), err


def test_nan_given_twice_is_one_value_not_a_repeat(tmp_path, capsys):
    """NaN is not equal to itself: ``--interval nan --interval nan`` was refused as "given twice ('nan', then 'nan')",
    two values said to differ that are one, in place of what the option says of the value itself (given once)."""
    parser = cli.build_parser()
    args = parser.parse_args(["steps", "--interval", "nan", "--interval", "NaN", "--base", "nan", "--base", "nan"])
    assert np.isnan(args.interval) and np.isnan(args.base)
    with pytest.raises(cli._UsageError, match=r"given twice \('nan', then '1'\)"):
        parser.parse_args(["steps", "--interval", "nan", "--interval", "1"])
    once = run(capsys, "steps", "--interval", "nan", "-o", tmp_path / "a.glb")
    twice = run(capsys, "steps", "--interval", "nan", "--interval", "nan", "-o", tmp_path / "a.glb")
    assert twice == once and once[0] == 2 and "given twice" not in once[2], once
    assert list(tmp_path.iterdir()) == []


def test_every_subcommand_parser_refuses_a_repeat():
    """The check lives in the one parser class every subcommand's parser is (a new subcommand has it too)."""
    parser = cli.build_parser()
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for name, sub in action.choices.items():
        assert isinstance(sub, cli._Parser), name
        stores = [a for a in sub._actions if type(a) is argparse._StoreAction and a.option_strings]
        assert stores, name


def test_memory_budget_before_and_after_the_subcommand_must_agree(tmp_path, capsys):
    """--memory-budget is an option of the command and of each subcommand (two parsers): the one after the
    subcommand replaced the one before silently. Two budgets are refused now; one, or the same on both sides, runs."""
    png = tmp_path / "a.png"
    code, out, err = run(capsys, "--memory-budget", "1GB", "steps", "--memory-budget", "2GB", "--png", png)
    assert code == 2 and not png.exists()
    assert ("stepterrain: error: argument --memory-budget: given twice ('1GB' before steps, then '2GB' after it); it "
            "takes one value: give it once") in err, err
    for argv in (["--memory-budget", "1GB", "steps", "--memory-budget", "1000MB"], ["steps", "--memory-budget", "1kB"],
                 ["--memory-budget", "1kB", "steps"]):
        code, out, err = run(capsys, *argv, "--png", png, "--size", "64x48", "-q")
        budget = "1,000,000,000 bytes" if "1GB" in argv else "1,000 bytes"
        assert (code == 0) == (budget != "1,000 bytes"), (argv, err)
        if code:  # the budget given applies, before or after the subcommand
            assert "over the memory budget of 1,000 bytes" in err, err


def test_memory_budget_given_twice_is_named_as_typed(tmp_path, capsys):
    """The refusal of two --memory-budget values showed them as bytes ("8589934592 bytes before steps, then 500000000
    bytes after it"), no figure the user typed; it quotes each as typed now, as an option given twice to one parser
    is named."""
    png = tmp_path / "a.png"
    code, out, err = run(capsys, "--memory-budget=8GiB", "steps", "--memory-budget", "1.5 GiB", "--png", png)
    assert code == 2 and out == "" and not png.exists()
    assert ("stepterrain: error: argument --memory-budget: given twice ('8GiB' before steps, then '1.5 GiB' after "
            "it); it takes one value: give it once") in err, err
    assert "bytes" not in err, err
    code, out, err = run(capsys, "--memory-budget", "500MB", "globe", "--memory-budget", "17179869184", "-o",
                         tmp_path / "g.glb")
    assert code == 2 and "given twice ('500MB' before globe, then '17179869184' after it)" in err, err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------ the 3MF unit of every path
def _model_unit(path) -> str:
    """The ``unit`` a 3MF's model declares (millimetre when absent, as the 3MF core spec says)."""
    import re
    import zipfile

    with zipfile.ZipFile(path) as archive:
        head = archive.read("3D/3dmodel.model")[:400].decode()
    found = re.search(r'<model [^>]*unit="([a-z]+)"', head)
    return found.group(1) if found else "millimeter"


def test_3mf_declares_the_unit_of_the_coordinates_on_every_path(tmp_path, capsys):
    """A stepped terrain is in metres (UTM metres here, 35.9 x 19.3 km). Written straight to .3mf (`steps --solid -o
    x.3mf`, save_mesh of stepped's mesh) it declared millimetres, 35.9 m wide in a slicer or CAD tool, while the same
    mesh saved as .glb (glTF's metres), read back and saved as .3mf declared metres: one mesh, two sizes by path. Now
    every path declares what the coordinates are: stepterrain's own meshes metres, scale_for_print's (--print-size)
    millimetres, a foreign unitless mesh (an STL's) millimetres, 3MF's default; read back and saved again, the same."""
    import trimesh

    import stepterrain as st
    from stepterrain.export import read_mesh, save_mesh

    dem = st.sample_dem().coarsen(16)  # a 40 x 74 grid: the units, not the sizes, differ by path
    code, _, err = run(capsys, "steps", "--interval", "200", "--solid", "--coarsen", "16", "-o", tmp_path / "s.3mf",
                       "-q")
    assert code == 0, err
    assert _model_unit(tmp_path / "s.3mf") == "meter"
    width = np.ptp(read_mesh(tmp_path / "s.3mf").vertices[:, 0])
    assert 35_000 < width < 36_000  # metres: 35.9 km, as the DEM
    code, _, err = run(capsys, "steps", "--interval", "200", "--solid", "--coarsen", "16", "--print-size", "150", "-o",
                       tmp_path / "p.3mf", "-q")
    assert code == 0 and _model_unit(tmp_path / "p.3mf") == "millimeter", err
    assert np.isclose(np.ptp(read_mesh(tmp_path / "p.3mf").vertices[:, 0]), 150.0)
    mesh = st.stepped(dem, interval=200.0, solid=True, device="cpu")
    assert _model_unit(save_mesh(mesh, tmp_path / "lib.3mf")) == "meter"
    for ext in (".glb", ".ply", ".obj", ".3mf"):  # read back from stepterrain's own files, saved as .3mf again
        back = read_mesh(save_mesh(mesh, tmp_path / f"m{ext}"))
        assert _model_unit(save_mesh(back, tmp_path / f"again{ext}.3mf")) == "meter", ext
    printed = st.export.scale_for_print(mesh, 150.0)
    assert _model_unit(save_mesh(read_mesh(save_mesh(printed, tmp_path / "p.ply")), tmp_path / "p2.3mf")) == \
        "millimeter"
    # a foreign mesh with no unit: 3MF's default, millimetres (an STL's unit by convention), also read from an STL
    foreign = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert _model_unit(save_mesh(foreign, tmp_path / "f.3mf")) == "millimeter"
    foreign.export(tmp_path / "f.stl")
    assert _model_unit(save_mesh(read_mesh(tmp_path / "f.stl"), tmp_path / "f2.3mf")) == "millimeter"
    # a stepterrain 3MF read back keeps its unit, whichever it declares
    assert _model_unit(save_mesh(read_mesh(tmp_path / "p.3mf"), tmp_path / "p3.3mf")) == "millimeter"
    assert _model_unit(save_mesh(read_mesh(tmp_path / "s.3mf"), tmp_path / "s3.3mf")) == "meter"


# ------------------------------------------------------------------------------------------ the close-up framing error
@pytest.mark.parametrize("given, cause, advice", [
    (["--offset", "0,0,1e9"], "close-up 1 (--offset 0,0,1e+09) is drawn 1e+09 from the terrain's centre",
     "; move it nearer: give it a smaller --offset\n"),
    (["--scale", "1e6"], "close-up 1 (--scale 1e+06,1e+06,1e+06) is drawn 3.48e+09 across, reaching 1.74e+09 from "
     "the terrain's centre", "; scale it down: give it a smaller --scale\n"),
])
def test_closeup_framing_error_names_the_close_up_and_the_option_to_change(tmp_path, capsys, given, cause, advice):
    """The framing refusal names the close-up as the user counts them and its --offset (never the library's
    ``closeups[0]``); a close-up blown up by --scale 1e6 at the default offset was told "give it a smaller --offset",
    the one option that was not the cause: it names its --scale, its drawn size and "a smaller --scale" now."""
    code, out, err = run(capsys, "closeup", "--roi-relative", "0.5,0.5,0.1", *given, "--size", "128x128", "-o",
                         tmp_path / "x.png", "-q")
    assert code == 2 and "closeups[" not in err and "bounds" not in err, err
    assert err.startswith("stepterrain closeup: error: the camera fitted to the overview and its close-ups would "
                          "show the overview ("), err
    assert cause in err and err.endswith(advice), err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------ a compound CRS's units
def _compound_tif(path, crs: str, transform, band_unit: str | None = None):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.crs import CRS

    z = (np.arange(40 * 50).reshape(40, 50) % 300 + 1000).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32",
                       crs=CRS.from_user_input(crs), transform=transform) as dataset:
        dataset.write(z, 1)
        if band_unit is not None:
            dataset.set_band_unit(1, band_unit)
    return path, z


def test_compound_crs_horizontal_and_vertical_units_are_read(tmp_path, capsys):
    """A GeoTIFF in a compound CRS (horizontal + vertical): its horizontal unit places the grid, its vertical unit
    (GDAL names the band's unit after it) scales the heights to metres. WGS 84 / UTM 33N + EGM96 height (metres) is
    kept whole and named EPSG:32633+5773 (its WKT, a thousand characters, was the CRS `info` printed); + NAVD88
    height (ftUS) gives heights x 0.3048006 and the horizontal CRS alone (the vertical part no longer describes
    metres); NAD83 / California zone 3 (ftUS) + NAVD88 (ftUS) converts both."""
    import json

    from rasterio.transform import Affine

    ftus = 1200 / 3937
    cases = [("EPSG:32633+5773", Affine(30, 0, 500000, 0, -30, 5000000), "EPSG:32633+5773", 30.0, 1.0, "metre"),
             ("EPSG:32633+6360", Affine(30, 0, 500000, 0, -30, 5000000), "EPSG:32633", 30.0, ftus, "US survey foot"),
             ("EPSG:2227+6360", Affine(100, 0, 6000000, 0, -100, 2000000), None, 100 * ftus, ftus, "US survey foot")]
    for k, (crs, transform, kept, spacing, factor, unit) in enumerate(cases):
        path, z = _compound_tif(tmp_path / f"c{k}.tif", crs, transform)
        code, out, err = run(capsys, "info", path, "--json")
        assert code == 0 and "warning" not in err, (crs, err)
        info = json.loads(out)
        if kept is not None:
            assert info["crs"] == kept, (crs, info["crs"])
        assert info["height_unit_read"] == unit and info["height_unit"] == "m", (crs, info)
        assert np.allclose(np.abs(info["spacing"]), spacing, rtol=1e-9), (crs, info["spacing"])
        assert np.allclose(info["height_range"], [z.min() * factor, z.max() * factor], rtol=1e-6), (crs, info)


def test_a_band_unit_that_contradicts_the_compound_crs_vertical_unit_is_warned_of(tmp_path, capsys):
    """A band unit of metres in a GeoTIFF whose CRS's vertical part is NAVD88 height (ftUS): the file contradicts
    itself, and the band's unit was used (as GDAL reads it) without a word, heights 3.28 times what the CRS makes
    them. Now a warning names both units, the CRS and the --height-unit that reads the CRS's; a foot against a US
    survey foot (2 ppm apart) is no contradiction."""
    import json

    from rasterio.transform import Affine

    path, z = _compound_tif(tmp_path / "c.tif", "EPSG:32633+6360", Affine(30, 0, 500000, 0, -30, 5000000), "metre")
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0 and json.loads(out)["height_range"] == [float(z.min()), float(z.max())]
    assert ("stepterrain info: warning: c.tif: band 1's unit 'metre' is not the vertical unit of its CRS, "
            "'US survey foot' (EPSG:32633+6360): heights read in metre, as GDAL reads them (3.28083 times what the "
            "CRS's unit makes them); if they are in US survey foot, pass --height-unit 'US survey foot'") in err, err
    code, out, err = run(capsys, "info", path, "--json", "--height-unit", "US survey foot")
    assert code == 0 and "is not the vertical unit" not in err
    assert np.isclose(json.loads(out)["height_range"][0], z.min() * 1200 / 3937)
    path, z = _compound_tif(tmp_path / "f.tif", "EPSG:32633+6360", Affine(30, 0, 500000, 0, -30, 5000000), "ft")
    code, out, err = run(capsys, "info", path, "--json")
    assert code == 0 and "warning" not in err, err


# ------------------------------------------------------------------------------------------ over-budget advice
def test_solid_png_over_budget_advice_is_a_budget_the_run_passes_at(tmp_path, capsys):
    """`steps --solid --png` over the memory budget was told the budget of the render of the DEM's surface (70MiB
    here), checked before stepping; at that budget the solid itself was refused (300MiB): a budget per try, each too
    small. The advice is now the whole run's, the stepped solid's (its count pass) or its render's with the most faces
    the solid has, whichever is more: followed, the run passes."""
    import re

    argv = ["steps", "--solid", "--interval", "20", "--coarsen", "3", "--png", tmp_path / "s.png", "-q"]
    code, out, err = run(capsys, *argv, "--memory-budget", "60MiB")
    assert code == 2 and not (tmp_path / "s.png").exists(), err
    assert "(the whole run: the stepped solid needs " in err, err
    advice = re.search(r"raise the budget \(--memory-budget SIZE\) to at least (\d+MiB)", err).group(1)
    code, out, err = run(capsys, *argv, "--memory-budget", advice)
    assert code == 0 and (tmp_path / "s.png").is_file(), (advice, err)


# ------------------------------------------------------------------------------------------ a globe's nodata cells
def test_globe_nodata_refusal_names_only_what_marks_a_cell(tmp_path, capsys):
    """The globe's refusal of an .npz's nodata cells names what marks them: of one NaN cell in a file that also
    declares nodata -9999 (no cell holds it) or an all-False mask, it said "(nodata -9999, NaN or infinite; ...)" and
    "('mask', NaN or infinite; ...)", naming a value and a mask that marked nothing. What does mark a cell is named."""
    lat, lon = np.linspace(89.5, -89.5, 180), np.linspace(-179.5, 179.5, 360)
    grid, out = tmp_path / "grid.npz", tmp_path / "g.ply"
    elevation = np.zeros((180, 360), np.float32)
    elevation[3, 7] = np.nan
    mask = np.zeros(elevation.shape, bool)
    cases = (({"nodata": np.float32(-9999)}, "1 nodata cell (NaN or infinite; first at row 3, column 7)"),
             ({"mask": mask}, "1 nodata cell (NaN or infinite; first at row 3, column 7)"),
             ({"nodata": np.float32(0)}, "64,800 nodata cells (nodata 0, NaN or infinite; first at row 0, column 0)"))
    for beside, told in cases:
        np.savez(grid, elevation=elevation, lat=lat, lon=lon, **beside)
        code, _, err = run(capsys, "globe", grid, "--face-size", "9", "--no-camera", "-o", out, "--device", "cpu")
        assert code == 2 and f"'elevation' has {told}; the globe needs a height everywhere" in err, err
    assert not out.exists()
