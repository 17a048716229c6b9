"""Terrain.crop and Terrain.coarsen (and --crop / --coarsen): smaller grids of a DEM too big to step whole; and
--spacing, the cell size of a DEM file with no georeferencing.

Checked against brute force over the nodes' world positions (heightfield_mesh's vertices) and NumPy block means,
on hand-made grids, hypothesis grids with either spacing sign, and the real DEMs in shared/data.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st_
from PIL import Image

import stepterrain as st
from stepterrain import cli
from stepterrain.errors import InvalidInputError

from .conftest import SHARED_DATA


def _nodes(terrain):
    """(H*W, 3) node positions and heights, row-major: x0 + j·dx, y0 + i·dy (heightfield_mesh's placement)."""
    rows, cols = terrain.shape
    i, j = np.mgrid[0:rows, 0:cols]
    (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
    return np.column_stack([(x0 + j * dx).ravel(), (y0 + i * dy).ravel(), terrain.heights.ravel()])


def _grid(rows, cols, spacing=(10.0, -10.0), origin=(500.0, 900.0), seed=0, nodata=0.0):
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(rows, cols)).cumsum(axis=0).cumsum(axis=1).astype(np.float32)
    if nodata:
        z[rng.random(z.shape) < nodata] = np.nan
    return st.Terrain.from_heights(z, spacing=spacing, origin=origin, crs="EPSG:32611", source="t.tif",
                                   height_unit="ft")


# ------------------------------------------------------------------------------------------ crop
def test_crop_keeps_the_nodes_inside_bounds_included_at_their_positions():
    t = _grid(6, 8)  # x 500..570, y 900..850 (north-up: dy < 0)
    c = t.crop((510.0, 540.0, 860.0, 880.0))
    assert c.shape == (3, 4)
    assert c.extent == (510.0, 540.0, 860.0, 880.0)
    assert c.origin == (510.0, 880.0) and c.spacing == t.spacing
    np.testing.assert_array_equal(c.heights, t.heights[2:5, 1:5])
    assert (c.crs, c.source, c.height_unit) == (t.crs, t.source, t.height_unit)
    # a bound a centimetre inside a node drops it; within half a centimetre (the rounding of a coordinate typed back
    # from `stepterrain info`) keeps it
    assert t.crop((510.0 + 0.01, 540.0, 860.0, 880.0)).shape == (3, 3)
    assert t.crop((510.0 + 0.004, 540.0 - 0.004, 860.0, 880.0)).shape == (3, 4)
    assert t.crop((510.0 - 1e-6, 540.0 + 1e-12, 860.0, 880.0)).shape == (3, 4)
    assert t.crop((-1e300, 1e300, -1e300, 1e300)).shape == t.shape  # beyond the grid: clamped


@settings(max_examples=60, deadline=None)
@given(rows=st_.integers(2, 9), cols=st_.integers(2, 9), dx=st_.sampled_from([1.0, -1.0, 2.5, -30.0]),
       dy=st_.sampled_from([1.0, -1.0, 0.5, -30.0]), seed=st_.integers(0, 10**6))
def test_crop_keeps_exactly_the_nodes_brute_force_finds_inside(rows, cols, dx, dy, seed):
    t = _grid(rows, cols, spacing=(dx, dy), origin=(100.0, -40.0), seed=seed)
    rng = np.random.default_rng(seed)
    xmin, xmax, ymin, ymax = t.extent
    x0, x1 = np.sort(rng.uniform(xmin - 2 * abs(dx), xmax + 2 * abs(dx), 2))
    y0, y1 = np.sort(rng.uniform(ymin - 2 * abs(dy), ymax + 2 * abs(dy), 2))
    nodes = _nodes(t)
    # a node within half a centimetre (at most a hundredth of a step) outside is kept: typed-back rounding
    sx, sy = (max(1e-9 * abs(d), min(0.005, 0.01 * abs(d))) for d in (dx, dy))
    inside = (nodes[:, 0] >= x0 - sx) & (nodes[:, 0] <= x1 + sx) & (nodes[:, 1] >= y0 - sy) & (nodes[:, 1] <= y1 + sy)
    mask = inside.reshape(rows, cols)
    kept_rows, kept_cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(kept_rows) < 2 or len(kept_cols) < 2:
        with pytest.raises(InvalidInputError, match=r"^extent \(.*\) \(xmin, xmax, ymin, ymax\) holds \d+ x \d+ "
                                                    r"nodes of the grid, fewer than the 2 x 2 a mesh needs"):
            t.crop((x0, x1, y0, y1))
        return
    c = t.crop((x0, x1, y0, y1))
    # the kept nodes form the rectangle brute force finds, at the same positions with the same heights
    np.testing.assert_array_equal(_nodes(c), nodes[inside])
    assert mask.sum() == len(kept_rows) * len(kept_cols)


def test_a_cropped_stepped_mesh_lies_on_the_whole_one():
    t = st.sample_dem()
    xmin, xmax, ymin, ymax = t.extent
    c = t.crop((xmin + 3000.0, xmin + 9000.0, ymin + 4000.0, ymin + 8000.0))
    whole = st.stepped(t, interval=50.0, base=0.0, device="cpu")
    part = st.stepped(c, interval=50.0, base=0.0, device="cpu")
    # every terrace vertex (a node) of the part is a vertex of the whole at the same position: one frame
    whole_set = {tuple(v) for v in np.round(np.asarray(whole.vertices), 6)}
    nodes = {tuple(n) for n in np.round(_nodes(c)[:, :2], 6)}
    at_nodes = {tuple(v) for v in np.round(np.asarray(part.vertices), 6) if tuple(v[:2]) in nodes}
    assert len(at_nodes) > 1000 and at_nodes <= whole_set
    assert part.bounds[0][0] >= c.extent[0] and part.bounds[1][0] <= c.extent[1]
    assert part.bounds[0][1] >= c.extent[2] and part.bounds[1][1] <= c.extent[3]


@pytest.mark.parametrize(
    ("extent", "message"),
    [
        ((0.0, 1.0, 2.0), r"^extent must be 4 finite numbers \(xmin, xmax, ymin, ymax\), xmin <= xmax and ymin <= "
                          r"ymax, in the terrain's coordinates \(its extent is \(500, 570, 850, 900\)\); got "
                          r"\(0\.0, 1\.0, 2\.0\)$"),
        ((560.0, 510.0, 860.0, 880.0), r"xmin <= xmax .* got \(560\.0, 510\.0, 860\.0, 880\.0\)$"),
        ((510.0, 560.0, math.nan, 880.0), r"^extent must be 4 finite numbers"),
        ("510,560,860,880", r"^extent must be 4 finite numbers"),
        ((510.0, 515.0, 860.0, 880.0), r"holds 3 x 1 nodes of the grid, fewer than the 2 x 2 a mesh needs; the "
                                       r"terrain's extent is \(500, 570, 850, 900\), spacing \(10\.0, -10\.0\)$"),
        ((0.0, 1.0, 0.0, 1.0), r"holds 0 x 0 nodes"),
    ],
)
def test_crop_refuses_bad_extents(extent, message):
    with pytest.raises(InvalidInputError, match=message):
        _grid(6, 8).crop(extent)


def test_crop_refuses_only_nodata_and_tins():
    z = np.ones((5, 5), dtype=np.float32)
    z[:, :3] = np.nan
    with pytest.raises(InvalidInputError, match=r"^extent \(0\.0, 2\.0, 0\.0, 4\.0\) holds only nodata \(5 x 3 "
                                                r"nodes\)$"):
        st.Terrain.from_heights(z).crop((0.0, 2.0, 0.0, 4.0))
    tin = st.Terrain.from_mesh(trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 1]], [[0, 1, 2]], process=False))
    for call in (lambda: tin.crop((0, 1, 0, 1)), lambda: tin.coarsen(2)):
        with pytest.raises(InvalidInputError, match=r"applies to a grid Terrain; got a TIN"):
            call()


# ------------------------------------------------------------------------------------------ coarsen
def _block_means(z, f):
    h, w = z.shape[0] // f, z.shape[1] // f
    out = np.full((h, w), np.nan)
    for i in range(h):
        for j in range(w):
            block = z[i * f:(i + 1) * f, j * f:(j + 1) * f].astype(np.float64)
            if np.isfinite(block).any():
                out[i, j] = np.nanmean(block)
    return out


@settings(max_examples=40, deadline=None)
@given(rows=st_.integers(2, 17), cols=st_.integers(2, 17), f=st_.integers(1, 5),
       dx=st_.sampled_from([1.0, -2.0, 30.0]), dy=st_.sampled_from([-1.0, 3.0, -30.0]),
       nodata=st_.sampled_from([0.0, 0.3, 0.9]), seed=st_.integers(0, 10**6))
def test_coarsen_mean_is_the_block_mean_at_the_block_centre(rows, cols, f, dx, dy, nodata, seed):
    t = _grid(rows, cols, spacing=(dx, dy), origin=(7.0, 11.0), seed=seed, nodata=nodata)
    if f == 1:
        assert t.coarsen(1) is t
        return
    if rows // f < 2 or cols // f < 2:
        with pytest.raises(InvalidInputError, match=rf"^factor {f} leaves {rows // f} x {cols // f} nodes of the "
                                                    rf"{rows} x {cols} grid \(mean\), fewer than the 2 x 2"):
            t.coarsen(f)
        return
    c = t.coarsen(f)
    expected = _block_means(t.heights, f)
    np.testing.assert_allclose(c.heights, expected, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(np.isnan(c.heights), np.isnan(expected))
    assert c.spacing == (f * dx, f * dy)
    # each new node sits at the mean position of its block's nodes
    nodes = _nodes(t)[:, :2].reshape(rows, cols, 2)[: rows // f * f, : cols // f * f]
    centres = nodes.reshape(rows // f, f, cols // f, f, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(_nodes(c)[:, :2].reshape(centres.shape), centres, rtol=0, atol=1e-9)
    assert (c.crs, c.source, c.height_unit) == (t.crs, t.source, t.height_unit)


def test_coarsen_nearest_keeps_every_nth_node():
    t = _grid(7, 10)
    c = t.coarsen(3, method="nearest")
    np.testing.assert_array_equal(c.heights, t.heights[::3, ::3])
    assert c.origin == t.origin and c.spacing == (30.0, -30.0)
    np.testing.assert_array_equal(_nodes(c), _nodes(t).reshape(7, 10, 3)[::3, ::3].reshape(-1, 3))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(factor=0), r"^factor must be a positive integer \(nodes per new node along each axis\); got 0$"),
        (dict(factor=2.0), r"^factor must be a positive integer .* got 2\.0$"),
        (dict(factor=True), r"^factor must be a positive integer .* got True$"),
        (dict(factor=2, method="cubic"), r"^method must be 'mean' or 'nearest'; got 'cubic'$"),
        (dict(factor=4), r"^factor 4 leaves 1 x 2 nodes of the 6 x 8 grid \(mean\), fewer than the 2 x 2"),
        (dict(factor=6, method="nearest"), r"^factor 6 leaves 1 x 2 nodes of the 6 x 8 grid \(nearest\)"),
    ],
)
def test_coarsen_refuses_bad_factors(kwargs, message):
    with pytest.raises(InvalidInputError, match=message):
        _grid(6, 8).coarsen(**kwargs)


def test_coarsen_keeps_a_real_dems_heights_and_volume():
    """Big Tujunga (UTM, with its nodata) and the Front Range (degrees as local metres): block means keep the
    height range within the original and the mean height (the volume over the area) to a small fraction."""
    for name in ("big_tujunga_srtm_30m_utm11n.tif", "front_range_srtmgl3_3arcsec.tif"):
        t = st.load_dem(SHARED_DATA / name)
        c = t.coarsen(4)
        lo, hi = t.height_range
        clo, chi = c.height_range
        assert lo <= clo and chi <= hi
        whole = t.heights[: c.shape[0] * 4, : c.shape[1] * 4]
        assert abs(np.nanmean(c.heights, dtype=np.float64) - np.nanmean(whole, dtype=np.float64)) < 1.0
        assert c.crs == t.crs and c.source == t.source


# ------------------------------------------------------------------------------------------ CLI
def test_steps_crop_and_coarsen_mesh_the_smaller_grid(tmp_path, capsys):
    t = st.sample_dem()
    xmin, _, ymin, _ = t.extent
    crop = (xmin + 3000.0, xmin + 15000.0, ymin + 2000.0, ymin + 14000.0)
    out = tmp_path / "part.ply"
    code = cli.main(["steps", "--crop", ",".join(f"{v:.3f}" for v in crop), "--coarsen", "2", "--interval", "100",
                     "-o", str(out)])
    _, err = capsys.readouterr()
    assert code == 0, err
    expected = t.crop(crop).coarsen(2)
    assert f"{expected.shape[0]} x {expected.shape[1]} nodes" in err
    mesh = st.export.read_mesh(out)
    reference = st.stepped(expected, interval=100.0, device="cpu")
    assert len(mesh.faces) == len(reference.faces)
    np.testing.assert_allclose(mesh.bounds[:, :2], reference.bounds[:, :2], atol=1e-3)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--coarsen", "0"], "argument --coarsen: expected a positive whole number; got '0'"),
        (["--coarsen", "2.5"], "argument --coarsen: expected a positive whole number; got '2.5'"),
        (["--crop", "1,2,3"], "argument --crop: expected xmin,xmax,ymin,ymax; got '1,2,3'"),
        (["--crop", "0,1,0,1"], "error: --crop: extent (0.0, 1.0, 0.0, 1.0) (xmin, xmax, ymin, ymax) holds 0 x 0 "
                                "nodes of the grid"),
        (["--coarsen", "700"], "error: --coarsen: factor 700 leaves 0 x 1 nodes of the 643 x 1197 grid (mean)"),
    ],
)
@pytest.mark.parametrize("command", ["steps", "closeup", "texture"])
def test_bad_crop_and_coarsen_exit_2_writing_nothing(tmp_path, capsys, command, argv, message):
    code = cli.main([command, *argv, "-o", str(tmp_path / "x.png" if command != "steps" else tmp_path / "x.glb")])
    _, err = capsys.readouterr()
    assert code == 2
    assert message in err, err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------ --spacing
def test_spacing_places_a_plain_array_dem_as_the_api_would(tmp_path, capsys):
    """A .npy (or PNG) DEM has no georeferencing: read as 1 m cells, a 30 m DEM rendered as a spike forest, and
    the CLI had no way to say otherwise. --spacing D (or dx,dy) gives its cells, rows north to south."""
    z = np.load(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.npz")["elevation"][:60, :80].astype(np.float32)
    source = tmp_path / "dem.npy"
    np.save(source, z)
    for typed, spacing in (("30", (30.0, -30.0)), ("30,20", (30.0, -20.0))):
        out = tmp_path / "dem.ply"
        assert cli.main(["-q", "steps", str(source), "--spacing", typed, "--interval", "50", "-o", str(out)]) == 0
        mesh = st.export.read_mesh(out)
        reference = st.stepped(st.Terrain.from_heights(z, spacing=spacing), interval=50.0, device="cpu")
        assert len(mesh.faces) == len(reference.faces)
        np.testing.assert_allclose(mesh.bounds, reference.bounds, atol=1e-3)
        assert mesh.bounds[1][0] - mesh.bounds[0][0] == pytest.approx(79 * spacing[0])
        assert mesh.bounds[1][1] - mesh.bounds[0][1] == pytest.approx(59 * -spacing[1])
    capsys.readouterr()


@pytest.mark.parametrize(
    ("source", "value", "message"),
    [
        (None, "0", "argument --spacing: expected one cell size D or dx,dy in positive metres; got '0'"),
        (None, "1,2,3", "argument --spacing: expected one cell size D or dx,dy in positive metres; got '1,2,3'"),
        (None, "30", "error: --spacing applies to a DEM file with no georeferencing (.npy, a PNG heightmap, a GeoTIFF "
                     "without a geotransform); the embedded DEM places its nodes itself: spacing (30.0, -30.0)"),
        ("front_range_srtmgl3_3arcsec.tif", "30", "front_range_srtmgl3_3arcsec.tif places its nodes itself"),
    ],
)
def test_spacing_is_refused_where_the_file_places_its_nodes(tmp_path, capsys, source, value, message):
    argv = ["steps"] + ([str(SHARED_DATA / source)] if source else []) + ["--spacing", value]
    code = cli.main([*argv, "-o", str(tmp_path / "x.glb")])
    _, err = capsys.readouterr()
    assert code == 2 and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_crop_to_the_extent_stepterrain_info_prints_keeps_every_node(capsys):
    """--crop takes the coordinates `stepterrain info` prints, which are rounded (2 decimals from 1e4 up; the crop's
    own messages 10 significant digits): the Big Tujunga DEM's whole extent typed back from them lost its west column
    and south row (642 x 1196 of 643 x 1197 nodes), the UTM origin's rounding being 1e-4 of a step, not 1e-9. A bound
    too far out to step to (1e300 with spacing 1e-10) is clamped, not an OverflowError."""
    path = SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif"
    t = st.load_dem(path)
    assert cli.main(["info", str(path)]) == 0
    line = next(row for row in capsys.readouterr().out.splitlines() if row.startswith("extent "))
    printed = tuple(float(v) for v in line.split(None, 1)[1].strip("()").split(","))
    assert printed != t.extent  # rounded
    assert t.crop(printed).shape == t.shape
    own = tuple(float(v) for v in t._extent_text().strip("()").split(","))
    assert t.crop(own).shape == t.shape
    # a bound a hundredth of a step inside a node still drops it (30 m spacing: 0.3 m)
    xmin, xmax, ymin, ymax = t.extent
    assert t.crop((xmin + 0.3, xmax, ymin, ymax - 0.3)).shape == (t.shape[0] - 1, t.shape[1] - 1)
    tiny = st.Terrain.from_heights(np.zeros((3, 4), np.float32), spacing=(1e-10, -1e-10))
    assert tiny.crop((-1e300, 1e300, -1e300, 1e300)).shape == (3, 4)


def test_a_cropped_or_coarsened_mesh_records_the_input_options_in_its_metadata(tmp_path, capsys):
    """A mesh of `steps`, `closeup` or `texture --mesh` with --crop/--coarsen (or --spacing) recorded only its input
    file as its source, as if it covered the whole file at the file's spacing: `stepterrain info` of the output said
    nothing of the crop. The input options given are recorded beside the input now (none when not given)."""
    rng = np.random.default_rng(3)
    dem = tmp_path / "dem.npy"
    np.save(dem, (rng.random((40, 60)) * 100).astype(np.float32))
    options = ["--spacing", "10,20", "--crop", "50,500,-600,-100", "--coarsen", "2"]
    # spacing as the DEM it placed has it, (dx, -dy): rows run north to south (test_cli_fixes'
    # test_a_meshs_spacing_metadata_is_the_dems_signed_spacing)
    expected = {"input": str(dem), "spacing": [10.0, -20.0], "crop": [50.0, 500.0, -600.0, -100.0], "coarsen": 2}
    runs = {"steps": ["steps", str(dem), *options, "--interval", "10", "-o", str(tmp_path / "s.glb")],
            "closeup": ["closeup", str(dem), *options, "-o", str(tmp_path / "c.glb")],
            "texture": ["texture", str(dem), *options, "-o", str(tmp_path / "t.png"),
                        "--mesh", str(tmp_path / "t.glb")]}
    for name, argv in runs.items():
        assert cli.main(argv) == 0, capsys.readouterr().err
        mesh = st.export.read_mesh(argv[-1])
        assert {k: mesh.metadata.get(k) for k in expected} == expected, name
        part = st.Terrain.from_heights(np.load(dem), spacing=(10.0, -20.0)).crop((50, 500, -600, -100)).coarsen(2)
        xmin, xmax, ymin, ymax = part.extent
        assert mesh.bounds[0, 0] >= xmin - 1e-6 and mesh.bounds[1, 1] <= ymax + 1e-6, name
    capsys.readouterr()
    assert cli.main(["info", str(tmp_path / "s.glb")]) == 0
    info = capsys.readouterr().out
    assert "meta.crop" in info and "(50, 500, -600, -100)" in info and "meta.coarsen" in info
    assert cli.main(["steps", str(dem), "--interval", "10", "-o", str(tmp_path / "whole.glb")]) == 0
    meta = st.export.read_mesh(tmp_path / "whole.glb").metadata
    assert meta["input"] == str(dem) and not {"spacing", "crop", "coarsen", "height_unit"} & set(meta)


def test_coarsen_refuses_a_result_of_nodata_only():
    """coarsen gave a grid of nodata only where the finite nodes all lay in the rows and columns it drops (crop
    refuses an extent of nodata only): every later step failed on it ("no finite height") far from the cause."""
    z = np.full((5, 7), np.nan, np.float32)
    z[4, :] = 1.0  # the last row only: block means over rows 0-3 (factor 2) and rows 0, 2, 4 (nearest 2) differ
    with pytest.raises(InvalidInputError, match=r"^factor 2 \(mean\) leaves only nodata of the 5 x 7 grid"):
        st.Terrain.from_heights(z).coarsen(2)
    assert np.isfinite(st.Terrain.from_heights(z).coarsen(2, method="nearest").heights).sum() == 4
    z[4, :] = np.nan
    z[1, 1] = z[1, 3] = 2.0  # odd rows and columns: nearest keeps rows/columns 0, 2, 4
    with pytest.raises(InvalidInputError, match=r"^factor 2 \(nearest\) leaves only nodata of the 5 x 7 grid"):
        st.Terrain.from_heights(z).coarsen(2, method="nearest")
    assert np.isfinite(st.Terrain.from_heights(z).coarsen(2).heights).sum() == 2


def test_a_crop_in_degrees_of_a_dem_in_degrees_is_named_with_its_metres(tmp_path, capsys):
    """A DEM in degrees is read as local metres; a crop in degrees held 0 x 0 nodes, the message naming the metres
    extent only. Terrain.crop (and so batch's crop=/--crop) now says the extent looks like degrees and gives it in
    the DEM's metres, which crop the nodes inside those degrees: 200 x 200 of the Front Range tile here."""
    from stepterrain.io import describe_dem

    from .conftest import shared_file

    dem = st.load_dem(shared_file("front_range_srtmgl3_3arcsec.npz"))
    (lon0, _, _, lat1), (dlon, dlat) = describe_dem(dem)["lonlat_extent"], describe_dem(dem)["lonlat_step"]
    # nodes 100..299 west to east, 50..249 north to south: the box's edges lie halfway between nodes
    box = (lon0 + 99.5 * dlon, lon0 + 299.5 * dlon, lat1 + 249.5 * dlat, lat1 + 49.5 * dlat)
    with pytest.raises(InvalidInputError, match="it looks like degrees") as caught:
        dem.crop(box)
    metres = [float(v) for v in str(caught.value).rsplit("those degrees are (", 1)[1].rstrip(")").split(",")]
    assert dem.crop(metres).shape == (200, 200)
    np.testing.assert_array_equal(dem.crop(metres).heights, dem.heights[50:250, 100:300])
    with pytest.raises(InvalidInputError, match="0 x 0 nodes") as caught:  # metres off the DEM: no degrees named
        dem.crop((-500.0, -100.0, 100.0, 500.0))
    assert "degrees" not in str(caught.value)
    out = tmp_path / "out"
    assert cli.main(["batch", str(shared_file("front_range_srtmgl3_3arcsec.npz")), "--tile", "128",
                     "--crop=" + ",".join(repr(v) for v in box), "--scheduler", "serial", "-o", str(out)]) == 2
    assert "it looks like degrees" in capsys.readouterr().err


def test_a_crop_in_gdals_order_is_refused_with_the_numbers_in_ours(tmp_path, capsys):
    """--crop takes xmin,xmax,ymin,ymax; GDAL's -te and rasterio's bounds give xmin,ymin,xmax,ymax. Big Tujunga's
    bounds in that order (easting to northing, each way) cropped one corner of a 3400 km box without a word: the
    nodes north-east of (xmin, xmax), not the box meant. Refused now, naming our order and the same box in it, which
    crops what Terrain.crop does for it; a crop that runs past the DEM's edges in the right order is kept."""
    import re

    from .conftest import shared_file

    source = str(shared_file("big_tujunga_srtm_30m_utm11n.npz"))
    out = tmp_path / "t.png"
    assert cli.main(["texture", source, "--crop", "380000,3790000,390000,3800000", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "not GDAL's -te xmin,ymin,xmax,ymax" in err and not out.exists(), err
    ours = re.search(r"that box is --crop=(\S+)", err).group(1)
    assert ours == "380000,390000,3790000,3800000"
    assert cli.main(["-q", "texture", source, "--crop", ours, "-o", str(out)]) == 0
    with Image.open(out) as image:
        assert image.size[::-1] == st.load_dem(source).crop((380000, 390000, 3790000, 3800000)).shape
    assert cli.main(["-q", "texture", source, "--crop", "380000,500000,3700000,3800000", "-o", str(out)]) == 0


def test_steps_crop_of_a_geotiff_over_the_memory_budget_reads_only_its_window(tmp_path, capsys):
    """steps/closeup/texture --crop read the whole GeoTIFF, then cropped it: a DEM over the memory budget was refused
    (naming gdal_translate) even for a crop far inside it. A GeoTIFF's --crop is load_dem's crop= now: only its
    window is read and checked against the budget, the same nodes and mesh as the whole read's crop (then
    --coarsen, as before); the refusals of a crop in degrees or in GDAL's order still name the whole DEM's extent,
    before anything is read."""
    from .conftest import shared_file

    source = shared_file("big_tujunga_srtm_30m_utm11n.tif")  # 643 x 1197: 3.1 MB as float32 heights
    whole = st.load_dem(source)
    x0, _, _, y1 = whole.extent
    crop = (x0 + 3000.0, x0 + 6000.0, y1 - 5000.0, y1 - 2000.0)  # 101 x 101 nodes
    budget = ["--memory-budget", "2000000"]  # the mesh fits; the whole file does not
    out = tmp_path / "part.glb"  # a .ply's write (~4 MB for this mesh: its copies, counted now) would not fit
    code = cli.main(["steps", str(source), "--crop", ",".join(map(repr, crop)), "--interval", "100", "-o", str(out),
                     *budget])
    assert code == 0, capsys.readouterr().err
    mesh = st.export.read_mesh(out)
    reference = st.stepped(whole.crop(crop), interval=100.0, device="cpu")
    assert mesh.faces.shape == reference.faces.shape
    np.testing.assert_allclose(mesh.bounds, reference.bounds, atol=1e-3)
    assert cli.main(["-q", "steps", str(source), "--interval", "100", "-o", str(out), *budget]) == 2
    assert "the raster: 643 x 1197 cells" in capsys.readouterr().err  # the whole file is over that budget
    code = cli.main(["steps", str(source), "--crop", ",".join(map(repr, crop)), "--coarsen", "2", "--interval", "100",
                     "-o", str(out), *budget])
    assert code == 0 and f"{whole.crop(crop).coarsen(2).shape[0]} x" in capsys.readouterr().err
    gdal = f"{crop[0]!r},{crop[2]!r},{crop[1]!r},{crop[3]!r}"
    assert cli.main(["-q", "steps", str(source), "--crop", gdal, "-o", str(out), "--memory-budget", "1000"]) == 2
    assert "not GDAL's -te xmin,ymin,xmax,ymax" in capsys.readouterr().err
    assert cli.main(["-q", "steps", str(source), "--crop", "0,1,0,1", "-o", str(out), *budget]) == 2
    assert "error: --crop: extent (0.0, 1.0, 0.0, 1.0) (xmin, xmax, ymin, ymax) holds 0 x 0 nodes of the grid" in \
        capsys.readouterr().err
    degrees = shared_file("front_range_srtmgl3_3arcsec.tif")
    assert cli.main(["-q", "steps", str(degrees), "--crop", "-105.5,-105.4,39.9,40.0", "-o", str(out),
                     "--memory-budget", "1000"]) == 2
    assert "--crop=-105.5,-105.4,39.9,40 looks like degrees" in capsys.readouterr().err


@pytest.mark.parametrize(("name", "exact"), [("big_tujunga_srtm_30m_utm11n.tif", True),
                                             ("front_range_srtmgl3_3arcsec.tif", False)])
def test_a_cropped_stepped_mesh_lies_on_the_whole_one_as_crop_says(name, exact):
    """Terrain.crop's docstring: a cropped mesh's nodes lie exactly on the whole one's where the spacing adds up
    exactly (a UTM DEM's 30 m), else (a geographic DEM's metres, 70.8 x 92.7 m here), as its wall crossings, within
    float32 rounding of coordinates about another local origin; it said "its nodes exactly" of every DEM."""
    from scipy.spatial import cKDTree

    dem = st.load_dem(SHARED_DATA / name)
    xmin, _, ymin, _ = dem.extent
    dx, dy = (abs(s) for s in dem.spacing)
    whole = dem.crop((xmin, xmin + 60 * dx, ymin, ymin + 60 * dy))
    part = whole.crop((xmin + 20 * dx, xmin + 60 * dx, ymin + 25 * dy, ymin + 60 * dy))
    a, b = (np.asarray(st.stepped(t, interval=20.0, device="cpu").vertices) for t in (whole, part))
    distance = cKDTree(a).query(b)[0]
    (ox, oy), (sx, sy) = whole.origin, whole.spacing
    near = [np.abs((b[:, k] - o) / s % 1 - 0.5) > 0.5 - 1e-5 for k, o, s in ((0, ox, sx), (1, oy, sy))]
    at_node = near[0] & near[1]
    assert at_node.sum() > 500
    rounding = 2.0**-23 * 60 * max(dx, dy)  # float32 about each grid's local origin, both
    assert distance.max() <= rounding
    assert (distance[at_node] == 0).all() == exact


# ------------------------------------------------------------------------------------------ batch's coarsen
def _coast_tiles(folder):
    """Three 9 x 9 tiles: ``land`` of heights, ``sea`` of nodata only, and ``coast`` of nodata but its last row and
    column, which coarsen=2's blocks (rows and columns 0-7) leave out."""
    folder.mkdir()
    land = (np.random.default_rng(4).random((9, 9)) * 100).astype(np.float32)
    coast = np.full((9, 9), np.nan, np.float32)
    coast[8, :], coast[:, 8] = 50.0, 60.0
    for name, z in (("land", land), ("sea", np.full((9, 9), np.nan, np.float32)), ("coast", coast)):
        np.save(folder / f"{name}.npy", z)
    return folder, land, coast


def test_batch_coarsen_of_a_tile_whose_land_it_drops_is_an_empty_item_as_the_sea_is(tmp_path):
    """batch(coarsen=2) of a folder of tiles (a coast cut from one raster): a tile of nodata only is an empty item,
    done, but one whose finite nodes all lay in the last row and column, which the 2 x 2 blocks leave out, failed
    (Terrain.coarsen's refusal of a result of nodata only); in a series such a frame failed the whole batch before
    any item ran. Both are empty items now, coarsened to nodata as the sea tile is; a raster of one grid so coarsened
    is still refused, as Terrain.coarsen refuses it."""
    from stepterrain.batch import _reshaped_source, _Source

    folder, land, coast = _coast_tiles(tmp_path / "tiles")
    report = st.batch(folder, tmp_path / "out", interval=10.0, coarsen=2, scheduler="serial", format=".ply")
    assert report.ok, report.summary()
    faces = {r.key: r.faces for r in report.done}
    assert faces["coast"] == faces["sea"] == 0 and faces["land"] > 0, faces
    assert faces["land"] == len(st.stepped(st.Terrain.from_heights(land).coarsen(2), interval=10.0).faces)

    stack = np.stack([land, coast, np.full_like(land, np.nan)])
    series = _reshaped_source(_Source(stack, (1.0, 1.0), (0.0, 0.0), None, "series"), None, 2)
    np.testing.assert_array_equal(series.heights[0], st.Terrain.from_heights(land).coarsen(2).heights)
    assert series.heights.shape == (3, 4, 4) and np.isnan(series.heights[1:]).all()
    with pytest.raises(InvalidInputError, match=r"^coarsen=2: factor 2 \(mean\) leaves only nodata of the 9 x 9 "):
        _reshaped_source(_Source(coast, (1.0, 1.0), (0.0, 0.0), None, "raster"), None, 2)


# ------------------------------------------------------------------------------------------ crop then coarsen
def _crop_then_coarsen_reference(z, spacing, origin, nodes, f, method):
    """NumPy reference of ``crop`` to the node ranges ``nodes`` = ((i0, i1), (j0, j1)), bounds included, then
    ``coarsen(f, method)``: heights (block means of the finite nodes in float64, NaN for a block of nodata only; or
    every f-th node) and the origin (the first block's mean node position; the first kept node)."""
    (i0, i1), (j0, j1) = nodes
    (dx, dy), (ox, oy) = spacing, origin
    part = z[i0:i1 + 1, j0:j1 + 1].astype(np.float64)
    x0, y0 = ox + j0 * dx, oy + i0 * dy
    if f == 1:
        return part, (x0, y0)
    if method == "nearest":
        return part[::f, ::f], (x0, y0)
    h, w = part.shape[0] // f, part.shape[1] // f
    blocks = part[:h * f, :w * f].reshape(h, f, w, f).transpose(0, 2, 1, 3).reshape(h, w, f * f)
    finite = np.isfinite(blocks)
    sums = np.where(finite, blocks, 0.0).sum(axis=2)
    counts = finite.sum(axis=2)
    means = np.full((h, w), np.nan)
    np.divide(sums, counts, out=means, where=counts > 0)
    return means, (x0 + (f - 1) / 2 * dx, y0 + (f - 1) / 2 * dy)


@settings(max_examples=40, deadline=None)
@given(rows=st_.integers(2, 16), cols=st_.integers(2, 16), dx=st_.sampled_from([0.3, -0.3, 30.0, 1e-3, -7.123456789]),
       dy=st_.sampled_from([-0.3, 0.7, -30.0, 7.123456789]), far=st_.booleans(), f=st_.integers(1, 4),
       method=st_.sampled_from(["mean", "nearest"]), nodata=st_.sampled_from([0.0, 0.4]), data=st_.data())
def test_crop_to_node_positions_then_coarsen_matches_a_numpy_reference(rows, cols, dx, dy, far, f, method, nodata,
                                                                         data):
    """An extent typed from node positions (origin + k·step in float64, as `stepterrain info` or a GIS reports a
    node) keeps exactly those nodes, for spacings that do not add up exactly and origins of UTM size; coarsening the
    crop gives the NumPy reference's heights and origin, the crop's spacing times f, and every node of its
    heightfield mesh where the reference puts it; crs, source and height_unit carried through both."""
    origin = (376328.6554542635, 3807902.8276283755) if far else (-12.5, 3.25)
    t = _grid(rows, cols, spacing=(dx, dy), origin=origin, seed=data.draw(st_.integers(0, 10**6)), nodata=nodata)
    i0 = data.draw(st_.integers(0, rows // 3))
    i1 = data.draw(st_.integers(i0 + 1, rows - 1))
    j0 = data.draw(st_.integers(0, cols // 3))
    j1 = data.draw(st_.integers(j0 + 1, cols - 1))
    xs = (origin[0] + j0 * dx, origin[0] + j1 * dx)
    ys = (origin[1] + i0 * dy, origin[1] + i1 * dy)
    extent = (min(xs), max(xs), min(ys), max(ys))
    expected, expected_origin = _crop_then_coarsen_reference(t.heights, (dx, dy), origin, ((i0, i1), (j0, j1)),
                                                              f, method)
    if not np.isfinite(t.heights[i0:i1 + 1, j0:j1 + 1]).any():
        with pytest.raises(InvalidInputError, match=r"^extent \(.*\) holds only nodata"):
            t.crop(extent)
        return
    c = t.crop(extent)
    assert c.shape == (i1 - i0 + 1, j1 - j0 + 1) and c.spacing == (dx, dy)
    if min(expected.shape) < 2 or not np.isfinite(expected).any():
        with pytest.raises(InvalidInputError, match=rf"^factor {f} leaves "):
            c.coarsen(f, method=method)
        return
    k = c.coarsen(f, method=method)
    np.testing.assert_allclose(k.heights, expected, rtol=1e-6, atol=1e-4)
    np.testing.assert_array_equal(np.isnan(k.heights), np.isnan(expected))
    assert k.spacing == ((f * dx, f * dy) if f > 1 else (dx, dy))
    np.testing.assert_allclose(k.origin, expected_origin, rtol=0, atol=1e-9 * max(1.0, abs(origin[0]), abs(origin[1])))
    assert (k.crs, k.source, k.height_unit) == (t.crs, t.source, t.height_unit)
    mesh = st.heightfield_mesh(k)
    index = mesh.metadata.get("node_index", np.arange(k.heights.size))
    i, j = np.divmod(index, k.shape[1])
    np.testing.assert_allclose(mesh.vertices[:, 0], expected_origin[0] + j * f * dx, rtol=0, atol=1e-6)
    np.testing.assert_allclose(mesh.vertices[:, 1], expected_origin[1] + i * f * dy, rtol=0, atol=1e-6)
    assert (mesh.metadata["crs"], mesh.metadata["source"]) == (t.crs, t.source)


def test_cli_crop_and_coarsen_of_a_y_up_geotiff_with_nodata_is_the_librarys(tmp_path, capsys):
    """`steps --crop --coarsen` of a GeoTIFF stored south-up (positive pixel height: load_dem's dy > 0) with nodata
    reads only the crop's window, and its mesh is, vertex for vertex, stepped(load_dem(path).crop(c).coarsen(n))."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    z = np.random.default_rng(11).normal(size=(40, 50)).cumsum(axis=0).cumsum(axis=1).astype(np.float32) * 5
    z[:6, :9] = -9999.0
    path = tmp_path / "south_up.tif"
    with rasterio.open(path, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32", crs="EPSG:32611",
                       transform=Affine(30.0, 0.0, 380000.0, 0.0, 30.0, 3790000.0), nodata=-9999.0) as ds:
        ds.write(z, 1)
    whole = st.load_dem(path)
    assert whole.spacing == (30.0, 30.0) and whole.origin == (380015.0, 3790015.0)  # node (0, 0): first row's centre
    crop = (380100.0, 381000.25, 3790000.0, 3790900.5)
    expected = whole.crop(crop).coarsen(3)
    assert st.load_dem(path, crop=crop).origin == whole.crop(crop).origin
    out = tmp_path / "part.ply"
    assert cli.main(["-q", "steps", str(path), "--crop", ",".join(map(repr, crop)), "--coarsen", "3",
                     "--interval", "20", "-o", str(out)]) == 0, capsys.readouterr().err
    reference = tmp_path / "reference.ply"
    st.export.save_mesh(st.stepped(expected, interval=20.0, device="cpu"), reference)
    got, want = st.export.read_mesh(out), st.export.read_mesh(reference)
    assert len(got.faces) > 0
    np.testing.assert_array_equal(got.vertices, want.vertices)
    np.testing.assert_array_equal(got.faces, want.faces)
