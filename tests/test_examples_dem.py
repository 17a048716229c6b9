"""The examples' ``--dem PATH`` (stepterrain.cli.add_dem_option / example_dem): run on a user's DEM file instead of
the embedded one, cropped by ``--size`` as the embedded DEM is, writing their picture; a file that cannot be read is a
usage error (exit 2) that writes nothing."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import stepterrain as st
from stepterrain import render

from .test_examples import load_example

AVAILABLE, REASON = render.offscreen_available()
pytestmark = [pytest.mark.render,
              pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")]

#: example -> (its arguments at a tiny size, the picture's (height, width)); ``{out}`` is the PNG written
RUNS = {
    "stepped_terrain": (["--size", "24", "--panel", "96", "72", "--device", "cpu"], (72, 3 * 96)),
    "textures": (["--size", "24", "--panel", "96", "72", "--device", "cpu"], (72, 2 * 96)),
    "adaptive_mesh": (["--size", "24", "--errors", "20", "--panel", "96", "72", "--device", "cpu"], None),
    "flood": (["--size", "24", "--frames", "2", "--keyframes", "2", "--device", "cpu"], None),
    "batch_tiles": (["--size", "40", "--tile", "16", "--scheduler", "serial", "--interval", "2",
                     "--window", "96", "72", "--device", "cpu"], (72, 96)),
    "closeup_anchors": (["--window", "256", "144", "--device", "cpu"], (144, 256)),
    "closeup_mappings": (["--window", "192", "108", "--device", "cpu"], (108, 192)),
    "interactive": (["--size", "24", "--window", "96", "72", "--device", "cpu"], (72, 96)),
}


def read_png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


@pytest.fixture
def user_dem(tmp_path):
    """A 30 x 40 crop of the embedded DEM as a .npy (1 m cells: heights divided by its 30 m spacing, so the relief
    keeps its proportions), in a folder of its own."""
    dem = st.sample_dem()
    folder = tmp_path / "data"
    folder.mkdir()
    path = folder / "mine.npy"
    np.save(path, (dem.heights[500:530, 600:640] / 30.0).astype(np.float32))
    return path


@pytest.fixture
def only_the_user_dem(monkeypatch):
    """The embedded DEM cannot be read; the files load_dem reads are listed."""
    read = []
    load = st.load_dem

    def embedded(*args, **kwargs):
        raise AssertionError("the embedded DEM was read, not --dem's file")

    def loading(path, *args, **kwargs):
        read.append(Path(path))
        return load(path, *args, **kwargs)

    monkeypatch.setattr(st, "sample_dem", embedded)
    monkeypatch.setattr(st, "load_dem", loading)
    return read


@pytest.mark.parametrize("name", sorted(RUNS))
def test_an_example_runs_on_a_dem_file(name, user_dem, only_the_user_dem, tmp_path, capsys):
    argv, shape = RUNS[name]
    out = tmp_path / "out" / f"{name}.png"
    out.parent.mkdir()
    example = load_example(name)
    assert example.main([*argv, "--dem", str(user_dem), "--output", str(out)]) == 0
    assert only_the_user_dem == [user_dem]
    image = read_png(out)
    if shape is not None:
        assert image.shape[:2] == shape
    assert image.std() > 5  # a picture, not a blank one


def test_the_crop_is_of_the_dem_file(user_dem, only_the_user_dem, tmp_path, capsys):
    """stepped_terrain's --size crops the file as it crops the embedded DEM: of a 30 x 40 file, --size 30 keeps the
    centre 30 x 30 nodes, --size 15 every second node of them."""
    example = load_example("stepped_terrain")
    out = tmp_path / "s.png"
    assert example.main(["--size", "30", "--panel", "64", "48", "--device", "cpu", "--dem", str(user_dem),
                         "--output", str(out)]) == 0
    assert "(30 x 30 nodes" in capsys.readouterr().err
    assert example.main(["--size", "15", "--panel", "64", "48", "--device", "cpu", "--dem", str(user_dem),
                         "--output", str(out)]) == 0
    assert "(15 x 15 nodes" in capsys.readouterr().err


def test_an_example_reads_a_geotiff_dem(tmp_path, capsys):
    """A GeoTIFF crop (30 m cells, its CRS) runs as the embedded DEM does."""
    rasterio = pytest.importorskip("rasterio")
    dem = st.sample_dem()
    heights = dem.heights[400:440, 500:548].astype(np.float32)
    dx, dy = dem.spacing
    x0, y0 = dem.origin[0] + 500 * dx, dem.origin[1] + 400 * dy
    path = tmp_path / "crop.tif"
    transform = rasterio.transform.Affine(dx, 0.0, x0 - dx / 2, 0.0, dy, y0 - dy / 2)  # node-centred pixels
    with rasterio.open(path, "w", driver="GTiff", width=48, height=40, count=1, dtype="float32", crs=dem.crs,
                       transform=transform) as dst:
        dst.write(heights, 1)
    terrain = st.load_dem(path)
    assert terrain.shape == (40, 48) and terrain.spacing == pytest.approx((dx, dy))
    out = tmp_path / "t.png"
    example = load_example("stepped_terrain")
    assert example.main(["--size", "48", "--panel", "64", "48", "--device", "cpu", "--dem", str(path),
                         "--output", str(out)]) == 0
    assert "(40 x 48 nodes" in capsys.readouterr().err and read_png(out).shape[:2] == (48, 3 * 64)


def test_interactive_shows_a_dem_file_with_nodata(user_dem, only_the_user_dem, tmp_path, capsys):
    """interactive.py's slider range and first interval come from the grid's lowest and highest heights: a DEM file
    with nodata holes (NaN) gave a NaN interval, refused as a usage error. They are the heights it has; the picture
    is the one of the same DEM without the holes but for the holes."""
    heights = np.load(user_dem)
    holes = heights.copy()
    holes[5:10, 5:12] = np.nan
    holed = user_dem.with_name("holes.npy")
    np.save(holed, holes)
    example = load_example("interactive")
    argv, shape = RUNS["interactive"]
    pictures = []
    for dem in (user_dem, holed):
        out = tmp_path / f"{dem.stem}.png"
        assert example.main([*argv, "--dem", str(dem), "--output", str(out)]) == 0
        pictures.append(read_png(out))
    assert only_the_user_dem == [user_dem, holed]
    assert pictures[1].shape[:2] == shape and pictures[1].std() > 5
    # the same heights around the holes: the same interval and view, so most pixels agree
    assert np.mean(np.all(pictures[0] == pictures[1], axis=2)) > 0.5


@pytest.mark.parametrize("name", ["stepped_terrain", "closeup_mappings", "batch_tiles", "interactive"])
def test_an_unreadable_dem_is_a_usage_error_writing_nothing(name, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "bad.npy").write_bytes(b"not a numpy file")
    for dem in (tmp_path / "missing.tif", tmp_path / "bad.npy"):
        example = load_example(name)
        argv, _ = RUNS[name]
        with pytest.raises(SystemExit) as exit_info:
            example.main([*argv, "--dem", str(dem), "--output", str(out / "x.png")])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert "error: " in err and dem.name in err and "Traceback" not in err
        assert list(out.iterdir()) == []


@pytest.fixture
def holed_dems(user_dem):
    """``user_dem`` with a hole of 5 x 7 cells: (its NaN version, its -9999 version: a .npy has no nodata value of its
    own, so --nodata -9999 is how a user says what its -9999 cells are)."""
    heights = np.load(user_dem)
    heights[5:10, 5:12] = np.nan
    nan_file = user_dem.with_name("holes_nan.npy")
    np.save(nan_file, heights)
    sentinel = user_dem.with_name("holes_9999.npy")
    np.save(sentinel, np.where(np.isnan(heights), np.float32(-9999.0), heights))
    return nan_file, sentinel


@pytest.mark.parametrize("name", sorted(RUNS))
def test_an_example_reads_a_dem_file_with_nodata(name, holed_dems, monkeypatch, tmp_path, capsys):
    """--dem had no --nodata (the CLI's --nodata V[,V...], load_dem's nodata): a file whose voids are -9999 without a
    nodata value of its own was read as heights of -9999 m (a cliff 9 km deep; the interval picked for it), and
    `--nodata -9999` was an unrecognised argument. Now every example with --dem takes it, parsed as the CLI parses it
    (repeatable, comma-separated), and passes it to load_dem: the picture is the one of the file with NaN holes."""
    nan_file, sentinel = holed_dems
    calls = []
    load = st.load_dem
    monkeypatch.setattr(st, "load_dem", lambda path, **kw: calls.append((Path(path), kw)) or load(path, **kw))
    argv, _ = RUNS[name]
    outcomes = []
    for dem, extra in ((nan_file, []), (sentinel, ["--nodata", "-32768,-9999"]), (sentinel, ["--nodata=-9999"])):
        out = tmp_path / f"{dem.stem}{len(outcomes)}.png"
        try:
            code = load_example(name).main([*argv, "--dem", str(dem), *extra, "--output", str(out)])
        except SystemExit as exc:  # adaptive_mesh's RTIN refuses holes: the same usage error for both files
            code = exc.code
        err = capsys.readouterr().err
        outcomes.append((code, read_png(out) if code == 0 else err.splitlines()[-1]))
    assert [c[1].get("nodata") for c in calls] == [None, [-32768.0, -9999.0], [-9999.0]]
    assert outcomes[0][0] in (0, 2)
    for code, result in outcomes[1:]:
        assert code == outcomes[0][0]
        if code == 0:
            np.testing.assert_array_equal(result, outcomes[0][1])
        else:
            assert result == outcomes[0][1] and "NaN" in result


def test_nodata_applies_to_the_embedded_dem():
    """Without --dem, --nodata applies to the embedded DEM as the CLI's --nodata applies to it without an INPUT."""
    from stepterrain.cli import example_dem

    plain = example_dem(None)
    low = example_dem(None, [315.0])
    assert not plain.has_nodata and low.has_nodata
    np.testing.assert_array_equal(low.nodata_mask, plain.heights == 315.0)


@pytest.mark.parametrize("value", ["abc", "1,,2", ""])
def test_a_bad_nodata_is_a_usage_error_naming_it(value, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    example = load_example("stepped_terrain")
    with pytest.raises(SystemExit) as exit_info:
        example.main(["--size", "8", "--nodata", value, "--output", str(out / "x.png")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "--nodata" in err and "expected a number" in err and "Traceback" not in err
    assert list(out.iterdir()) == []


@pytest.fixture
def centre_hole(tmp_path):
    """A 30 x 30 crop of the embedded DEM (1 m cells) with NaN in its centre 10 x 10 cells, and that hole's mask."""
    heights = (st.sample_dem().heights[500:530, 600:630] / 30.0).astype(np.float32)
    heights[10:20, 10:20] = np.nan
    path = tmp_path / "hole.npy"
    np.save(path, heights)
    return path, np.isnan(heights)


def test_flood_draws_nodata_as_background_not_black_ground(centre_hole, tmp_path, capsys):
    """flood's hypsometric layer kept the colormap's RGB only: its colour for NaN, (0, 0, 0, 0), became opaque black,
    so a --dem file's voids were drawn as black ground in every frame. Now they are transparent: white, as the
    background around the terrain is, and the ground around them is not."""
    path, hole = centre_hole
    out = tmp_path / "flood.png"
    assert load_example("flood").main(["--size", "30", "--frames", "2", "--keyframes", "2", "--device", "cpu",
                                       "--dem", str(path), "--output", str(out)]) == 0
    image = read_png(out)
    assert image.shape[:2] == hole.shape  # one pixel a node, north up as the .npy's rows
    assert (image[hole] == 255).all()
    assert (image[~hole] < 250).any(axis=1).all()
    import imageio.v3 as iio

    for frame in iio.imread(out.with_suffix(".gif"), index=None):
        assert (frame[..., :3][hole] == 255).all()


def test_textures_draws_nodata_as_background_in_the_texture_panel(centre_hole, tmp_path, capsys):
    """textures' hypsometric and slope layers kept the colormaps' RGB only: a --dem file's voids were opaque black in
    the texture panel (the 3-D view has a hole there). Now transparent: the panel is white there, as around it."""
    path, hole = centre_hole
    example = load_example("textures")
    hyps, slopes = example.colour_layers(example.crop_sample(30, st.load_dem(path)))
    np.testing.assert_array_equal(hyps[..., 3] == 0, hole)  # opaque elsewhere
    assert (slopes[..., 3][hole] == 0).all()
    out = tmp_path / "textures.png"
    assert example.main(["--size", "30", "--panel", "96", "72", "--device", "cpu", "--dem", str(path),
                         "--output", str(out)]) == 0
    panel = read_png(out)[:, :96]
    # the 30 x 30 texture is scaled 2.4 times into the 96 x 72 panel, 12 pixels from its left: the hole's cells
    # 10:20 are pixels 24:48 down and 36:60 across; their inner part is background white (but for the resampling's
    # ringing, a few levels; it was 0)
    assert (panel[26:46, 38:58] >= 240).all()
    assert (panel[4:20, 16:32] < 250).any(axis=2).all()


def test_interactive_shows_a_flat_dem(tmp_path, capsys):
    """interactive.py's first interval and slider range come from the heights' span: a flat --dem file (a lake, a
    level pad; or one whose every kept node is the same) gave interval 0, and the example ended with "interval must
    be a positive finite number; got 0.0", an option it has not. It shows the flat terrain now, as the other
    examples do."""
    path = tmp_path / "flat.npy"
    np.save(path, np.full((30, 40), 7.0, np.float32))
    out = tmp_path / "flat.png"
    argv, shape = RUNS["interactive"]
    assert load_example("interactive").main([*argv, "--dem", str(path), "--output", str(out)]) == 0
    image = read_png(out)
    assert image.shape[:2] == shape
    assert (image[shape[0] // 3:] != 255).any(axis=2).mean() > 0.2  # below the sliders: the terrain, not white


@pytest.mark.parametrize("name", ["stepped_terrain", "batch_tiles"])
def test_an_undeclared_nodata_warning_names_the_examples_nodata_option(name, tmp_path, capsys):
    """load_dem's warning of an undeclared common nodata value (-32768 voids in an int32 GeoTIFF) told an example's
    user to "pass nodata=-32768", with Python's ``UserWarning`` and the example's source line: a Python caller's
    advice. It names the example's --nodata now and prints as the stepterrain command's warnings do, one
    ``PROG: warning:`` line; the library's own warning, and Python's warning machinery after the run, are as before."""
    rasterio = pytest.importorskip("rasterio")
    dem = st.sample_dem()
    z = np.round(dem.heights[500:530, 600:640]).astype(np.int32)
    z[5:9, 10:16] = -32768  # 24 voids
    path = tmp_path / "dem.tif"
    with rasterio.open(path, "w", driver="GTiff", width=40, height=30, count=1, dtype="int32", crs=dem.crs,
                       transform=rasterio.transform.Affine(30.0, 0.0, 380000.0, 0.0, -30.0, 3800000.0)) as dst:
        dst.write(z, 1)
    advice = "declare it (`gdal_edit.py -a_nodata -32768 dem.tif`, or pass "
    with pytest.warns(UserWarning, match=r"dem.tif: 24 cells of band 1 hold -32768, .*, or pass nodata=-32768\)$"):
        st.load_dem(path)  # the library's words, for a Python caller
    argv, _ = RUNS[name]
    shown = warnings.showwarning
    example = load_example(name)
    assert example.main([*argv, "--dem", str(path), "--output", str(tmp_path / "a.png")]) == 0
    assert warnings.showwarning is shown
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "-32768" in line]
    assert len(lines) == 1, err
    # as its parser's errors begin: its prog (argparse's, from sys.argv[0]), then the library's words
    prog = Path(sys.argv[0]).name
    assert lines[0].startswith(f"{prog}: warning: dem.tif: 24 cells of band 1 hold -32768, a common nodata value")
    assert lines[0].endswith(advice + "--nodata -32768)"), lines[0]
    assert "UserWarning" not in err and "nodata=" not in err and "example_dem(" not in err, err  # no source line
    # the advice followed: the voids are voids, and nothing is said of them
    assert example.main([*argv, "--dem", str(path), "--nodata", "-32768", "--output", str(tmp_path / "b.png")]) == 0
    assert "-32768" not in capsys.readouterr().err


@pytest.mark.parametrize("name", ["stepped_terrain", "batch_tiles"])
def test_an_examples_error_names_its_nodata_option(name, tmp_path, capsys):
    """An example's usage error (usage_errors) kept the library's spelling of the advice, "or pass
    nodata=-1.7976931348623157e+308" of a float64 .npy whose voids are float64's lowest value, where its warnings say
    "--nodata" already (and the stepterrain command's errors do): now its errors name the example's --nodata too, and
    the advice followed reads the file."""
    dem = st.sample_dem()
    z = dem.heights[500:530, 600:640].astype(np.float64)
    z[5:9, 10:16] = np.finfo(np.float64).min  # 24 voids, beyond float32
    path = tmp_path / "dem.npy"
    np.save(path, z)
    argv, _ = RUNS[name]
    example = load_example(name)
    with pytest.raises(SystemExit) as exit_info:
        example.main([*argv, "--dem", str(path), "--output", str(tmp_path / "a.png")])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "or pass --nodata -1.7976931348623157e+308)" in err and "nodata=" not in err, err
    assert example.main([*argv, "--dem", str(path), "--nodata", "-1.7976931348623157e+308",
                         "--output", str(tmp_path / "b.png")]) == 0
