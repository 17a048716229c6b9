"""Contour lines as a texture layer (:func:`stepterrain.texture.contour_layer`): placement against the formula on
analytic surfaces, line widths, index lines, nodata, bad input, and agreement with matplotlib's contours on a real
DEM."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

import stepterrain as st
from stepterrain.errors import InvalidInputError
from stepterrain.terrain import as_terrain
from stepterrain.texture import CONTOUR_COLOR, blend, contour_layer, drape, topographic_layer


def texel_centres(layer):
    """World (x, y) of every texel centre of a north-up layer, from its extent alone."""
    xmin, xmax, ymin, ymax = layer.extent
    rows, cols = layer.shape
    px, py = (xmax - xmin) / cols, (ymax - ymin) / rows
    x = xmin + (np.arange(cols) + 0.5) * px
    y = ymax - (np.arange(rows) + 0.5) * py
    return np.meshgrid(x, y)


def plane(shape, spacing, a, b):
    """Heights a * x + b * y on the nodes of a grid with origin (0, 0)."""
    rows, cols = shape
    x = np.arange(cols) * spacing[0]
    y = np.arange(rows) * spacing[1]
    return (a * x[None, :] + b * y[:, None]).astype(np.float32)


def distance_to_levels(h, interval, base, slope_per_texel):
    """Texels from heights ``h`` to the nearest level base + k * interval, where heights change by
    ``slope_per_texel``: the independent NumPy answer."""
    q = (h - base) / interval
    return np.abs(q - np.round(q)) * interval / slope_per_texel


@pytest.mark.parametrize("spacing", [(1.0, 1.0), (30.0, -30.0), (-2.0, 2.0)])
@pytest.mark.parametrize("width", [1.0, 2.0, 3.5])
@pytest.mark.parametrize("gradient", [(0.3, 0.1), (-4.0, 7.0)])
def test_plane_lines_lie_where_the_formula_says(device, spacing, width, gradient):
    a, b = gradient  # height per world unit along x and y
    heights = plane((40, 50), spacing, a, b)
    interval, base = 25.0, 3.0
    layer = contour_layer(heights, spacing=spacing, interval=interval, base=base, width=width, index_every=0,
                          device=device)
    assert layer.kind == "thematic" and layer.shape == (40, 50) and layer.image.shape == (40, 50, 4)
    x, y = texel_centres(layer)
    h = a * x + b * y  # the plane at the texel centres: placement from the layer's extent alone
    slope = math.hypot(a * abs(spacing[0]), b * abs(spacing[1]))  # height change per texel
    d = distance_to_levels(h, interval, base, slope)
    alpha = layer.image[..., 3]
    clear = np.abs(d - width / 2) > 1e-3  # float32 rounding decides texels exactly at the edge
    np.testing.assert_array_equal((alpha > 0.5)[clear], (d < width / 2)[clear])
    inside = d <= width / 2 - 0.5 - 1e-3
    assert np.all(alpha[inside] > 0.999)
    expected = np.clip(np.minimum(d + width / 2, 0.5) - np.maximum(d - width / 2, -0.5), 0, 1)
    np.testing.assert_allclose(alpha, expected, atol=2e-3)
    drawn = layer.image[..., :3][alpha > 0]
    np.testing.assert_allclose(drawn, np.broadcast_to(CONTOUR_COLOR, drawn.shape), atol=1e-6)


@pytest.mark.parametrize("width", [1.0, 1.5, 3.0])
@pytest.mark.parametrize("slope, interval", [(0.2, 10.0), (7.0, 100.0)])  # height per texel: gentle and steep
def test_line_width_in_texels_holds_on_gentle_and_steep_slopes(device, width, slope, interval):
    """Across an east-west ramp each line's alpha sums to its width in texels, whatever the slope: the line is
    ``width`` texels wide on the image, not a height band."""
    heights = plane((4, 300), (30.0, -30.0), slope / 30.0, 0.0)
    layer = contour_layer(heights, spacing=(30.0, -30.0), interval=interval, width=width, index_every=0,
                          device=device)
    row = layer.image[2, :, 3]
    lines = np.arange(interval, heights[2, -1] - interval / 2, interval)  # the levels away from the ends
    for level in lines:
        centre = level / slope
        span = slice(int(centre - width - 2), int(centre + width + 3))
        assert row[span].sum() == pytest.approx(width, abs=1e-3)
        assert np.count_nonzero(row[span] > 0.5) in (math.floor(width), math.ceil(width))


def test_cone_lines_lie_where_the_formula_says(device):
    n, width, interval = 121, 2.0, 7.0
    j, i = np.meshgrid(np.arange(n), np.arange(n))
    r = np.hypot(i - 60.0, j - 60.0)
    heights = (100.0 - r).astype(np.float32)  # unit slope per texel everywhere but the apex
    layer = contour_layer(heights, interval=interval, width=width, index_every=0, device=device)
    # spacing (1, 1): north-up flips the rows; the cone is symmetric in rows, so node (i, j) is texel (n-1-i, j)
    alpha = layer.image[::-1, :, 3]
    d = distance_to_levels(100.0 - r, interval, 0.0, 1.0)
    away = (r > 4) & (r < 58) & (np.abs(d - width / 2) > 0.05)  # off the apex and the border; the curvature's error
    np.testing.assert_array_equal((alpha > 0.5)[away], (d < width / 2)[away])


def test_index_lines_every_nth_are_wider_and_darker(device):
    slope, interval = 0.5, 4.0
    heights = plane((3, 200), (1.0, 1.0), slope, 0.0)
    layer = contour_layer(heights, interval=interval, width=1.0, index_every=5, device=device)
    row = layer.image[1]
    for k in range(1, 24):
        centre = int(round(k * interval / slope))
        span = slice(centre - 3, centre + 4)
        index = k % 5 == 0
        assert row[span, 3].sum() == pytest.approx(2.0 if index else 1.0, abs=1e-3), k
        colour = np.array(CONTOUR_COLOR) * (0.7 if index else 1.0)
        np.testing.assert_allclose(row[centre, :3], colour, atol=1e-6)
    custom = contour_layer(heights, interval=interval, base=4.0, index_every=3, index_width=3.0,
                           index_color=(0, 0, 1), device=device)
    row = custom.image[1]
    for k in range(1, 24):
        centre = int(round(k * interval / slope))
        index = (k - 1) % 3 == 0  # base 4: line 0 is at height 4
        assert row[centre - 4 : centre + 5, 3].sum() == pytest.approx(3.0 if index else 1.0, abs=1e-3), k
        assert (row[centre, 2] == 1.0) == index
    none = contour_layer(heights, interval=interval, index_every=0, device=device)
    np.testing.assert_allclose(none.image[1, :, 3].reshape(-1, 8).sum(axis=1)[1:-1], 1.0, atol=1e-3)


def test_explicit_levels_and_their_index_positions(device):
    heights = plane((3, 100), (1.0, 1.0), 1.0, 0.0)
    levels = [10.0, 25.5, 40.0, 77.25]
    layer = contour_layer(heights, levels=levels, width=1.0, index_every=2, device=device)
    alpha = layer.image[1, :, 3]
    d = np.min(np.abs(np.arange(100.0)[:, None] - np.array(levels)[None, :]), axis=1)
    nearest = np.argmin(np.abs(np.arange(100.0)[:, None] - np.array(levels)[None, :]), axis=1)
    half = np.where(nearest % 2 == 0, 1.0, 0.5)  # levels[0] and levels[2] are index lines (twice as wide)
    expected = np.clip(np.minimum(d + half, 0.5) - np.maximum(d - half, -0.5), 0, 1)
    np.testing.assert_allclose(alpha, expected, atol=1e-6)
    below = contour_layer(heights, levels=[500.0], device=device)  # no level crosses the terrain: no line
    assert not below.image[..., 3].any()


def test_flat_ground_draws_no_line_unless_exactly_on_a_level(device):
    flat = np.full((6, 7), 12.0, np.float32)
    assert not contour_layer(flat, interval=5.0, device=device).image[..., 3].any()
    on = contour_layer(flat, interval=4.0, index_every=0, device=device)
    np.testing.assert_array_equal(on.image[..., 3], 1.0)


def test_nodata_no_lines_into_holes_and_no_nan(device):
    slope, interval, width = 0.75, 6.0, 2.0
    heights = plane((30, 60), (1.0, 1.0), slope, 0.25)
    heights[10:18, 20:35] = np.nan
    heights[0, 0] = np.nan
    layer = contour_layer(heights, interval=interval, width=width, index_every=0, device=device)
    image = layer.image[::-1]  # back to node order (spacing (1, 1): north-up flips the rows)
    assert np.isfinite(layer.image).all()
    holes = np.isnan(heights)
    assert not image[..., 3][holes].any()
    # next to the hole the one-sided differences of a plane are exact: the lines still lie where the formula says
    h = np.where(holes, 0.0, heights)
    d = distance_to_levels(h, interval, 0.0, math.hypot(slope, 0.25))
    ok = ~holes & (np.abs(d - width / 2) > 1e-3)
    np.testing.assert_array_equal((image[..., 3] > 0.5)[ok], (d < width / 2)[ok])
    everything = np.full((4, 4), np.nan, np.float32)
    assert not contour_layer(everything, interval=1.0, device=device).image[..., 3].any()


def test_texel_size_samples_the_bilinear_heights_at_finer_texel_centres(device):
    spacing, texel, width = (30.0, -30.0), 10.0, 1.5
    a, b = 0.05, -0.02  # height per metre
    heights = plane((20, 24), spacing, a, b)
    layer = contour_layer(heights, spacing=spacing, interval=5.0, width=width, texel_size=texel, index_every=0,
                          device=device)
    assert layer.shape == (60, 72) and layer.extent == st.texture.terrain_extent(as_terrain(heights, spacing=spacing))
    x, y = texel_centres(layer)
    d = distance_to_levels(a * x + b * y, 5.0, 0.0, math.hypot(a * texel, b * texel))
    core = np.zeros(layer.shape, bool)
    core[2:-2, 2:-2] = True  # the outer texels lie beyond the nodes, where the heights are clamped
    ok = core & (np.abs(d - width / 2) > 1e-3)
    np.testing.assert_array_equal((layer.image[..., 3] > 0.5)[ok], (d < width / 2)[ok])


def test_composes_with_blend_and_drapes(device):
    dem = as_terrain(st.sample_dem().heights[:64, :80], spacing=(30.0, -30.0))
    topo = topographic_layer(dem, shadows=False, device=device)
    lines = contour_layer(dem, interval=50.0, width=1.5, device=device)
    assert lines.frame == topo.frame
    out = blend(topo, lines, device=device).rgba()
    a = lines.image[..., 3:]
    expected = topo.rgba()[..., :3] * (1 - a) + lines.image[..., :3] * a
    np.testing.assert_allclose(out[..., :3], expected, atol=1e-5)
    np.testing.assert_allclose(out[..., 3], 1.0)
    draped = drape(dem.mesh(), blend(topo, lines, device=device))
    assert isinstance(draped, trimesh.Trimesh) and draped.visual.uv.shape == (len(draped.vertices), 2)


def test_on_a_real_dem_matplotlib_contours_fall_on_line_texels():
    plt = pytest.importorskip("matplotlib.pyplot")
    pytest.importorskip("scipy")
    from scipy.spatial import cKDTree

    dem = st.sample_dem()
    heights = dem.heights[:300, :400]  # 30 m Big Tujunga (north-up: dy < 0, dx > 0, so texel (i, j) = node (i, j))
    assert dem.spacing[0] > 0 > dem.spacing[1]
    width = 1.5
    layer = contour_layer(heights, spacing=dem.spacing, interval=100.0, width=width, index_every=0, device="cpu")
    alpha = layer.image[..., 3]
    fig, ax = plt.subplots()
    try:
        found = ax.contour(np.arange(heights.shape[1]), np.arange(heights.shape[0]), heights,
                           levels=np.arange(400.0, 2300.0, 100.0))
        points = np.concatenate([p.vertices for p in found.get_paths() if len(p.vertices)])
    finally:
        plt.close(fig)
    assert len(points) > 1000
    i = np.clip(np.round(points[:, 1]).astype(int), 0, heights.shape[0] - 1)
    j = np.clip(np.round(points[:, 0]).astype(int), 0, heights.shape[1] - 1)
    on_line = alpha[i, j] > 0.5
    assert on_line.mean() > 0.95, on_line.mean()
    # and the line texels are near matplotlib's paths (no lines where there are no contours)
    rows, cols = np.nonzero(alpha > 0.5)
    distance, _ = cKDTree(points[:, ::-1]).query(np.column_stack([rows, cols]).astype(float))
    assert (distance < 1.5).mean() > 0.97, (distance < 1.5).mean()


@pytest.mark.parametrize("kwargs, name", [
    ({"interval": 0.0}, "interval"), ({"interval": -5.0}, "interval"), ({"interval": float("nan")}, "interval"),
    ({"interval": float("inf")}, "interval"), ({"interval": "10"}, "interval"),
    ({}, "interval"), ({"interval": 5.0, "levels": [1.0]}, "interval"),
    ({"levels": [3.0, 2.0]}, "levels"), ({"levels": [1.0, 1.0]}, "levels"), ({"levels": []}, "levels"),
    ({"levels": [1.0, float("nan")]}, "levels"), ({"levels": [[1.0, 2.0]]}, "levels"),
    ({"levels": ["a"]}, "levels"), ({"levels": [1.0], "base": 2.0}, "base"),
    ({"interval": 5.0, "base": float("nan")}, "base"),
    ({"interval": 5.0, "width": 0.0}, "width"), ({"interval": 5.0, "width": -1.0}, "width"),
    ({"interval": 5.0, "width": float("nan")}, "width"), ({"interval": 5.0, "index_width": 0.0}, "index_width"),
    ({"interval": 5.0, "color": (1.0, 0.0)}, "color"), ({"interval": 5.0, "color": (2.0, 0.0, 0.0)}, "color"),
    ({"interval": 5.0, "color": "red"}, "color"), ({"interval": 5.0, "color": (float("nan"), 0, 0)}, "color"),
    ({"interval": 5.0, "index_color": (0, 0, 0, 1.5)}, "index_color"),
    ({"interval": 5.0, "index_every": -1}, "index_every"), ({"interval": 5.0, "index_every": 1.5}, "index_every"),
    ({"interval": 5.0, "index_every": True}, "index_every"),
    ({"interval": 5.0, "texel_size": 0.0}, "texel_size"), ({"interval": 5.0, "texel_size": 2.0}, "texel_size"),
])
def test_bad_input_names_the_argument(kwargs, name):
    with pytest.raises(InvalidInputError, match=name):
        contour_layer(np.arange(12.0, dtype=np.float32).reshape(3, 4), device="cpu", **kwargs)


# ---------------------------------------------------------------------------------------------- CLI --contours
def _read_png(path):
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image)


@pytest.fixture
def ramp_dem(tmp_path):
    """An east-west ramp, 0.8 m per 1-unit node, with a hole: the CLI reads .npy at spacing 1."""
    heights = np.tile((np.arange(60) * 0.8).astype(np.float32), (30, 1))
    heights[5:9, 40:50] = np.nan
    path = tmp_path / "ramp.npy"
    np.save(path, heights)
    return path, heights


def test_cli_contours_are_laid_over_the_texture_as_blend_lays_them(tmp_path, ramp_dem, capsys):
    from stepterrain.cli import main

    path, heights = ramp_dem
    plain, lined = tmp_path / "plain.png", tmp_path / "lined.png"
    assert main(["texture", str(path), "--colormap", "none", "-o", str(plain), "--device", "cpu",
                 "--mesh", str(tmp_path / "p.glb")]) == 0
    assert main(["texture", str(path), "--colormap", "none", "--contours", "8", "--contour-width", "1.5",
                 "--contour-color", "0,0,1", "--contour-index", "0", "-o", str(lined), "--device", "cpu",
                 "--mesh", str(tmp_path / "m.glb")]) == 0, capsys.readouterr().err
    under, over = _read_png(plain), _read_png(lined)
    assert under.shape == over.shape == (30, 60, 4)  # nodata: RGBA
    # a .npy loads north-up, spacing (1, -1): texel (i, j) = node (i, j)
    lines = contour_layer(heights, spacing=(1.0, -1.0), interval=8.0, width=1.5, color=(0, 0, 1), index_every=0,
                          device="cpu")
    c = lines.image[..., 3:]
    a = under[..., 3:] / 255.0
    alpha = c + a * (1 - c)
    expected = np.where(alpha > 0, (lines.image[..., :3] * c + under[..., :3] / 255.0 * a * (1 - c))
                        / np.maximum(alpha, 1e-12), under[..., :3] / 255.0)
    np.testing.assert_array_less(np.abs(over[..., :3] - expected * 255.0), 0.51 + 1e-6)
    # the lines every 10 nodes (8 m at 0.8 m a node) are blue, between them the texture is unchanged
    row = over[20]
    assert row[10, 2] > 200 and row[10, 0] < 60 and row[20, 2] > 200
    np.testing.assert_array_equal(over[20, 13:17], under[20, 13:17])
    np.testing.assert_array_equal(over[..., 3], under[..., 3])  # the holes stay transparent: no lines into them
    assert (over[5:9, 40:50, 3] == 0).all()


def test_cli_contours_on_the_texel_size_grid(tmp_path, ramp_dem, capsys):
    from stepterrain.cli import main

    path, heights = ramp_dem
    out, plain = tmp_path / "fine.png", tmp_path / "plain.png"
    assert main(["texture", str(path), "--colormap", "none", "--texel-size", "0.25", "-o", str(plain),
                 "--device", "cpu"]) == 0
    assert main(["texture", str(path), "--colormap", "none", "--texel-size", "0.25", "--contours", "8",
                 "--contour-index", "0", "--contour-color", "0,0,0", "-o", str(out), "--device", "cpu"]) == 0, \
        capsys.readouterr().err
    image = _read_png(out)
    assert image.shape == (120, 240, 4)
    # one texel wide on the finer grid: at most two dark texels across each line, 40 texels apart (the first
    # texels, in the half cell beyond the outer nodes, take the edge's heights, as the hillshade does: left out)
    dark = image[80, 4:, 0].astype(int) < _read_png(plain)[80, 4:, 0].astype(int) - 20
    starts = np.flatnonzero(dark[1:] & ~dark[:-1]) + 1
    assert len(starts) >= 4 and set(np.diff(starts)) == {40}
    assert dark.sum() <= 2 * (len(starts) + 1)


def test_cli_contours_help_and_refusals(tmp_path, ramp_dem, capsys):
    from stepterrain.cli import main

    assert main(["texture", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--contours" in text and "--contour-width" in text and "--contour-color" in text
    path, _ = ramp_dem
    out = str(tmp_path / "x.png")
    for argv, match in [
        (["--contours", "0"], "--contours must be a positive"),
        (["--contours", "nan"], "--contours must be a positive"),
        (["--contour-width", "2"], "--contour-width applies only with --contours"),
        (["--contour-color", "1,0,0"], "--contour-color applies only with --contours"),
        (["--contour-index", "2"], "--contour-index applies only with --contours"),
        (["--contours", "5", "--contour-width", "-1"], "--contour-width must be a positive"),
        (["--contours", "5", "--contour-color", "2,0,0"], "--contour-color must be an RGB"),
        (["--contours", "5", "--contour-color", "1,0"], "--contour-color must be an RGB"),
        (["--contours", "5", "--contour-index", "-1"], "--contour-index must be 0"),
        (["--contours", "5", "--contour-index", str(2**31)], "--contour-index must be 0 (no index lines) or more, "
                                                              "below 2**31; got 2147483648"),
    ]:
        assert main(["texture", str(path), "-o", out, "--device", "cpu", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert match in err, (argv, err)
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("power", [-95, 70])
def test_contours_of_heights_scaled_by_a_power_of_two_are_the_same(power):
    """Contour lines depend on the terrain's shape only: heights, interval and spacing scaled together by a power of
    two draw the same lines. The kernel took |∇h| = sqrt(gx² + gy²) in float32, the heights' change per texel: below
    ~1e-19 (heights 2.5e-26 m, spacing 7.6e-28 m) it squared to 0, flat ground, and the lines vanished; above
    ~1.8e19 (heights 1e24 m, spacing 3.5e22 m) it squared to inf, every distance 0, and the whole layer came out
    line colour."""
    heights = np.asarray(st.sample_dem().heights, np.float32)[:60, :80]
    ref = contour_layer(heights, interval=50.0, spacing=(30.0, -30.0), device="cpu").rgba()
    k = 2.0 ** power
    scaled = contour_layer(heights * np.float32(k), interval=50.0 * k, spacing=(30.0 * k, -30.0 * k),
                           device="cpu").rgba()
    assert 0.05 < (ref[..., 3] > 0.5).mean() < 0.5  # lines, not the whole layer
    np.testing.assert_allclose(scaled, ref, atol=1e-6)
