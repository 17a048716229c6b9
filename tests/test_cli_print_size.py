"""``stepterrain steps --print-size MM [--print-z-scale S]``: the mesh file scaled for a 3D print (issue #2), as
:func:`stepterrain.export.scale_for_print` scales it; the run without the options writes what it wrote before."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import stepterrain as st
from stepterrain.export import read_mesh, scale_for_print

from .test_cli import run

CROP = (380000.0, 382000.0, 3790000.0, 3791200.0)  # of the embedded DEM, in UTM metres


def test_steps_print_size_writes_an_stl_of_the_size_at_the_origin_watertight(tmp_path, capsys):
    out = tmp_path / "model.stl"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       "--print-size", "150", "--print-z-scale", "2", "-o", out)
    assert code == 0, err
    assert "scaled for a print: 150 x" in err
    back = trimesh.load(out)  # corners merged by position, as slicers read it
    assert back.is_watertight and back.is_winding_consistent
    lo, hi = back.bounds
    np.testing.assert_allclose(lo, 0.0, atol=1e-9)
    assert max(hi[0], hi[1]) == pytest.approx(150.0, abs=1e-4)
    # the same as the Python function on the same solid (float32 as STL stores it)
    solid = st.stepped(st.sample_dem().crop(CROP), interval=100.0, solid=True)
    model = scale_for_print(solid, 150.0, z_scale=2.0)
    assert len(back.vertices) == len(model.vertices)
    assert back.volume == pytest.approx(model.volume, rel=1e-5)
    assert back.volume == pytest.approx(solid.volume * model.metadata["print"]["scale"] ** 3 * 2.0, rel=1e-5)
    np.testing.assert_allclose(np.unique(back.vertices, axis=0),
                               np.unique(np.asarray(model.vertices).astype(np.float32), axis=0), atol=0)


def test_steps_print_size_records_the_mapping_back_in_a_3mf(tmp_path, capsys):
    from .test_export import needs_3mf

    needs_3mf()
    out = tmp_path / "model.3mf"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       "--print-size", "80", "-o", out)
    assert code == 0, err
    back = read_mesh(out)
    record = back.metadata["print"]
    assert record["size"] == 80.0 and record["z_scale"] == 1.0
    assert record["origin"][0] == pytest.approx(CROP[0], abs=30.0)
    assert record["origin"][1] == pytest.approx(CROP[2], abs=30.0)
    assert back.metadata["generator"] == "stepterrain steps"
    assert max(back.extents[:2]) == pytest.approx(80.0, rel=1e-12)


def test_steps_without_print_size_stays_georeferenced_without_a_print_record(tmp_path, capsys):
    out = tmp_path / "world.ply"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       "-o", out)
    assert code == 0, err
    assert "scaled for a print" not in err
    back = read_mesh(out)
    assert "print" not in back.metadata
    assert back.bounds[0][0] > 3e5 and back.bounds[0][1] > 3e6  # georeferenced, as before


@pytest.mark.parametrize(("extra", "match"), [
    (["--print-size", "0", "-o", "m.stl"], "--print-size must be positive; got 0"),
    (["--print-size", "-5", "-o", "m.stl"], "--print-size must be positive; got -5"),
    (["--print-size", "nan", "-o", "m.stl"], "--print-size must be finite; got nan"),
    (["--print-size", "inf", "-o", "m.stl"], "--print-size must be finite; got inf"),
    (["--print-size", "150", "--print-z-scale", "0", "-o", "m.stl"], "--print-z-scale must be positive; got 0"),
    (["--print-z-scale", "2", "-o", "m.stl"], "--print-z-scale applies only with --print-size"),
    (["--print-size", "150", "--png", "r.png"], "--print-size scales the mesh file"),
])
def test_steps_bad_print_options_are_refused_before_any_file(tmp_path, capsys, monkeypatch, extra, match):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       *extra)
    assert code == 2
    assert match in err
    assert not any(tmp_path.iterdir())


def test_steps_print_size_stl_of_a_steep_1m_grid_at_utm_reads_back_watertight(tmp_path, capsys):
    """A steep 1 m grid at UTM northings (float32 steps of 0.25-0.5 m): its world .stl reads back open (walls' corners
    within float32 rounding of the nodes, a warning says so); scaled for a print its coordinates lie within 150 mm of
    0, where float32 keeps them apart, and the .stl reads back watertight without a warning."""
    heights = (np.random.default_rng(0).random((8, 9)) * 30.0).astype(np.float32)
    dem = tmp_path / "steep.npz"
    np.savez(dem, elevation=heights, transform=np.array([500000.0, 1.0, 0.0, 4000008.0, 0.0, -1.0]),
             crs="EPSG:32611")
    code, _, err = run(capsys, "steps", dem, "--interval", "2", "--solid", "-q", "-o", tmp_path / "world.stl")
    assert code == 0 and "not shared by exactly two triangles" in err
    assert not trimesh.load(tmp_path / "world.stl").is_watertight
    code, _, err = run(capsys, "steps", dem, "--interval", "2", "--solid", "-q", "--print-size", "150",
                       "-o", tmp_path / "print.stl")
    assert code == 0 and "warning" not in err.lower(), err
    back = trimesh.load(tmp_path / "print.stl")
    assert back.is_watertight and back.is_winding_consistent
    assert max(back.extents[:2]) == pytest.approx(150.0, abs=1e-4)
    solid = st.stepped(st.load_dem(dem), interval=2.0, solid=True)  # the indexed solid the run wrote
    model = scale_for_print(solid, 150.0)
    assert len(back.vertices) == len(model.vertices)
    assert back.volume == pytest.approx(model.volume, rel=1e-5)


def test_steps_print_size_of_a_surface_warns_that_it_is_no_solid(tmp_path, capsys):
    """Without --solid the print model is the open surface, no slicer prints it: the run said nothing of it."""
    crop = ",".join(f"{v:g}" for v in CROP)
    code, _, err = run(capsys, "steps", "--crop", crop, "--interval", "100", "--print-size", "150",
                       "-o", tmp_path / "sheet.stl")
    assert code == 0, err
    assert "warning: --print-size without --solid" in err
    assert not trimesh.load(tmp_path / "sheet.stl").is_watertight  # what the warning says
    code, _, err = run(capsys, "steps", "--crop", crop, "--interval", "100", "--solid", "--print-size", "150",
                       "-o", tmp_path / "solid.stl")
    assert code == 0 and "warning" not in err, err


def test_info_shows_the_print_record_of_a_print_model(tmp_path, capsys):
    """`info` of a print model names its mapping back to the world (meta.print.*): a dict, it was left out."""
    import json

    out = tmp_path / "model.ply"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       "--print-size", "150", "--print-z-scale", "2", "-o", out)
    assert code == 0, err
    record = read_mesh(out).metadata["print"]
    code, text, err = run(capsys, "info", out, "--json")
    assert code == 0, err
    summary = json.loads(text)
    assert {key: summary[f"meta.print.{key}"] for key in record} == record
    # the world's x of the model's corner, as the record maps it: the crop's first node
    assert summary["meta.print.origin"][0] == pytest.approx(CROP[0], abs=30.0)
    code, text, err = run(capsys, "info", out)
    assert code == 0 and "meta.print.scale" in text and "meta.print.z_scale" in text, err


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_steps_print_size_to_gltf_warns_that_its_unit_is_the_metre(tmp_path, capsys, ext):
    """glTF's unit is the metre: a 150 mm print model written as .glb opened 150 m wide, without a word."""
    crop = ",".join(f"{v:g}" for v in CROP)
    out = tmp_path / f"model{ext}"
    code, _, err = run(capsys, "steps", "--crop", crop, "--interval", "100", "--solid", "--print-size", "150",
                       "-o", out)
    assert code == 0, err
    assert "warning: --print-size 150 writes millimetres, but glTF's unit is the metre" in err
    assert f"model{ext} opens 150 m wide" in err
    assert max(read_mesh(out).extents[:2]) == pytest.approx(150.0, rel=1e-5)  # written as asked
    code, _, err = run(capsys, "steps", "--crop", crop, "--interval", "100", "--solid", "--print-size", "150",
                       "-o", tmp_path / "model.3mf")
    assert code == 0 and "warning" not in err, err


@pytest.mark.parametrize("ext", [".stl", ".glb"])
@pytest.mark.parametrize("options", [("--print-size", "1e-300"), ("--print-size", "1e-40"),
                                     ("--print-size", "150", "--print-z-scale", "1e-300")])
def test_steps_print_size_that_underflows_float32_is_refused_writing_nothing(tmp_path, capsys, ext, options):
    """A model scaled below float32's least normal number (STL's and glTF's coordinates) lost its faces or its
    vertices: --print-size 1e-300 wrote an .stl of no face and a .glb with every vertex at 0, exit 0."""
    out = tmp_path / f"model{ext}"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       *options, "-o", out)
    assert code == 2, err
    assert "below float32's least normal number" in err and "give a larger --print-size or --print-z-scale" in err
    assert not out.exists()


def test_steps_print_size_that_overflows_float32_says_so_in_one_error_without_numpys_warning(tmp_path, capsys):
    out = tmp_path / "model.stl"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       "--print-size", "1e308", "--print-z-scale", "100", "-o", out)
    assert code == 2, err
    assert "beyond float32" in err and "overflow encountered" not in err
    assert not out.exists()


def test_steps_print_size_tiny_but_within_float32_keeps_every_face(tmp_path, capsys):
    out = tmp_path / "model.stl"
    code, _, err = run(capsys, "steps", "--crop", ",".join(f"{v:g}" for v in CROP), "--interval", "100", "--solid",
                       "--print-size", "1e-20", "-o", out)
    assert code == 0, err
    solid = st.stepped(st.sample_dem().crop(CROP), interval=100.0, solid=True)
    assert len(trimesh.load(out, process=False).faces) == len(solid.faces)
