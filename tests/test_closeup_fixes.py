"""Close-up bugs found by an adversarial pass (each test failed before its fix)."""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs
from hypothesis.extra import numpy as hnp

from stepterrain import render
from stepterrain.closeup import (
    ROI,
    AnchorStyle,
    CloseUp,
    anchor_strips,
    animate_closeups,
    closeup_layers,
    closeup_scene,
    render_closeups,
)
from stepterrain.errors import InvalidInputError, OutputTooLargeError

from .reference_closeup import nodata_gradient, surface_heights
from .test_closeup import hills
from .test_closeup_render import AVAILABLE, REASON, SIZE, one, red_pixels, terrain


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_reused_renderer_redraws_an_overview_texture_changed_in_place():
    # the overview was keyed by id(texture): a texture edited in place kept the old colours on a reused renderer
    t = terrain()
    texture = np.zeros((16, 16, 3), np.uint8)
    texture[..., 0] = 255
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")
        texture[..., 0], texture[..., 2] = 0, 255
        again = render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")
    finally:
        renderer.close()
    fresh = render_closeups(t, [one()], window_size=SIZE, texture=texture.copy(), device="cpu")
    assert np.array_equal(again, fresh)



@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_reused_renderer_knows_a_read_only_texture_by_identity(monkeypatch):
    """A read-only texture is a promise not to change it: its overview is found again without hashing its pixels
    every frame (a 3840 x 1920 image is 22 MB); the frames equal a fresh render."""
    import stepterrain.closeup as closeup_module

    t = terrain()
    texture = np.zeros((16, 16, 3), np.uint8)
    texture[..., 1] = 200
    texture.setflags(write=False)
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")

        def refuse(*args, **kwargs):
            raise AssertionError("a read-only texture was hashed")

        monkeypatch.setattr(closeup_module.hashlib, "blake2b", refuse)
        again = render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")
    finally:
        renderer.close()
    monkeypatch.undo()
    fresh = render_closeups(t, [one()], window_size=SIZE, texture=texture.copy(), device="cpu")
    assert np.array_equal(again, fresh)

@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("option", [{"window_size": (320, 240)}, {"window_size": (320, 240), "cus": "billboard"},
                                    {"z_scale": 3.0}, {"z_scale": -1.0}, {"background": "black"}])
def test_render_closeups_refuses_options_its_renderer_does_not_have(option):
    # a renderer of 160x120 gave a 160x120 image for window_size=(320, 240) (a billboard: an error about a "box");
    # its z_scale silently replaced the one asked for (even a negative one)
    option = dict(option)
    cus = [one(view="billboard")] if option.pop("cus", None) else [one()]
    name = next(iter(option))
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        with pytest.raises(InvalidInputError, match=name):
            render_closeups(terrain(), cus, renderer=renderer, device="cpu",
                            **{"window_size": SIZE, **option})  # fmt: skip
    finally:
        renderer.close()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_animate_closeups_keeps_its_z_scale():
    # animate_closeups builds its renderer with z_scale: the frames must still render (and with that scale)
    t = terrain()
    flat, tall = (animate_closeups(t, [one(spin=(1.0, 1))], frames=1, window_size=SIZE, z_scale=z, device="cpu")[0]
                  for z in (1.0, 3.0))
    assert flat.shape == tall.shape == (SIZE[1], SIZE[0], 3)
    dark = animate_closeups(t, [one(spin=(1.0, 1))], frames=1, window_size=SIZE, background="black", device="cpu")[0]
    assert dark.shape == flat.shape and (dark[0, 0] == 0).all() and (flat[0, 0] == 255).all()
    assert not np.array_equal(flat, tall)


@pytest.mark.parametrize("make", [
    lambda: ROI.circle((0.0, 0.0), 5.0, edge_width=100.0),
    lambda: ROI.ellipse((0.0, 0.0), (10.0, 4.0), edge_width=4.5),
    lambda: ROI.rectangle((0.0, 0.0), (20.0, 8.0), edge_width=4.5),
    lambda: ROI.rounded_rectangle((0.0, 0.0), (20.0, 8.0), corner_radius=2.0, edge_width=5.0),
])
def test_soft_edge_wider_than_the_shape_is_refused(make):
    # m stayed below 1 everywhere (a circle of radius 5 with a 100-wide edge peaked at 0.007): a close-up with no
    # content, silently
    with pytest.raises(InvalidInputError, match="edge_width"):
        make()


def test_soft_edge_as_deep_as_the_shape_still_reaches_one():
    assert ROI.circle((0.0, 0.0), 5.0, edge_width=5.0).mask.max() == 1.0
    assert ROI.rectangle((0.0, 0.0), (20.0, 8.0), edge_width=4.0).mask.max() == 1.0


def test_cli_refuses_an_edge_wider_than_the_roi(tmp_path, capsys):
    import stepterrain.cli as cli

    dem = tmp_path / "dem.npy"
    np.save(dem, hills())
    assert cli.main(["-q", "closeup", str(dem), "--roi-relative", "0.5,0.5,0.1", "--edge", "1000",
                     "-o", str(tmp_path / "o.glb")]) == 2  # fmt: skip
    assert "--edge must be at most the ROI radius" in capsys.readouterr().err
    assert not (tmp_path / "o.glb").exists()


# ------------------------------------------------------------------------------------------ fuzzing (h9)
ARRAY_CHOICE = np.array(["overview", "billboard"], dtype=object)


@pytest.mark.parametrize("call, name", [
    (lambda: AnchorStyle(inactive=ARRAY_CHOICE), "anchor inactive"),
    (lambda: CloseUp(ROI.circle((0.0, 0.0), 5.0), view=ARRAY_CHOICE), "close-up view"),
    (lambda: CloseUp(ROI.circle((0.0, 0.0), 5.0), scalars=ARRAY_CHOICE), "close-up scalars"),
    (lambda: closeup_scene(hills(), [CloseUp(ROI.circle((20.0, 16.0), 5.0))], scalars=np.zeros((2, 2)),
                           device="cpu"), "scalars"),
], ids=["AnchorStyle inactive", "CloseUp view", "CloseUp scalars", "closeup_scene scalars"])
def test_a_choice_given_as_an_array_is_named(call, name):
    """``value not in ("a", "b")`` compared an array with each name: numpy's "truth value is ambiguous" ValueError."""
    with pytest.raises(InvalidInputError, match=rf"^{name} must be"):
        call()


@pytest.mark.parametrize("cmap", [["terrain"], {"terrain": 1}, np.array(["terrain"])])
def test_an_unhashable_colormap_is_named(cmap):
    """matplotlib.colormaps[...] of a list, dict or array raised Python's "unhashable type" TypeError."""
    with pytest.raises(InvalidInputError, match=r"cmap must name a matplotlib colormap"):
        CloseUp(ROI.circle((0.0, 0.0), 5.0), cmap=cmap)
    with pytest.raises(InvalidInputError, match=r"cmap must name a matplotlib colormap"):
        closeup_scene(hills(), [CloseUp(ROI.circle((20.0, 16.0), 5.0))], cmap=cmap, device="cpu")


@pytest.mark.parametrize("edge", [3.5e38, 1e300])
def test_a_height_band_edge_beyond_float32_ramps_as_a_wide_edge(edge):
    """The float32 ramp's bounds overflowed to inf and inf / inf made the mask NaN -> 0 everywhere (an empty ROI)
    with RuntimeWarnings; an edge that wide ramps to ~1 everywhere, as an edge of 1e37 already did."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mask = ROI.height_band(hills(), 40.0, 60.0, edge=edge).mask
    np.testing.assert_allclose(mask, ROI.height_band(hills(), 40.0, 60.0, edge=1e37).mask, atol=1e-6)
    assert mask.min() > 0.99


@pytest.mark.parametrize("call", [
    lambda: ROI.height_band(hills(), -1e308, 60.0),
    lambda: ROI.height_band(hills(), 40.0, 1e308),
    lambda: ROI.height_band(hills(), 40.0, 60.0, edge=1e-320),
    lambda: ROI.slope_above(hills(), 20.0, edge=1e-320),
], ids=["low -1e308", "high 1e308", "band edge 1e-320", "slope edge 1e-320"])
def test_generated_masks_with_extreme_bounds_leak_no_runtime_warning(call):
    """The float32 casts and divisions overflowed with RuntimeWarnings (the masks came out as meant)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        call()


@pytest.mark.parametrize("call", [lambda: ROI.circle((0.0, 0.0), 1e308), lambda: ROI.ellipse((0.0, 0.0), (1.0, 1e308))])
def test_a_shape_too_large_is_refused_before_any_runtime_warning(call):
    """The mask's texel grid over an inf box warned ("invalid value encountered") before the size was refused."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InvalidInputError, match=r"^ROI size must be positive \(width, height\) up to 1e\+12"):
            call()


def test_animating_more_frames_than_a_float_can_count_is_over_budget():
    """The budget message divided 10**400 bytes by 1024**2 in float: Python's OverflowError."""
    with pytest.raises(OutputTooLargeError, match=r"over 10\^\d+ MiB"):
        animate_closeups(terrain(), [one()], frames=10**400, window_size=(64, 48), device="cpu")


def test_an_fps_too_small_for_finite_frame_times_is_named():
    """Frame times i / fps overflowed (RuntimeWarnings) and the NaN time was refused as "time", not fps."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InvalidInputError, match=r"^fps must be large enough"):
            animate_closeups(terrain(), [one()], frames=3, fps=1e-320, window_size=(64, 48), device="cpu")


@pytest.mark.parametrize(
    "options, message",
    [
        ({"rotation": (0.0, 1e308)}, r"close-up rotation must be \(α, β\) in radians, each within ±6433.98 \(1024"),
        ({"rotation": (-1e5, 0.0)}, r"close-up rotation must be \(α, β\) in radians, each within ±6433.98"),
        ({"billboard_view": (0.0, 2.0)}, r"billboard_view must be \(azimuth, elevation\) in radians.*elevation in"),
        ({"billboard_view": (1e300, 1.0)}, r"billboard_view must be \(azimuth, elevation\) in radians, the azimuth"),
    ],
)
def test_a_closeup_angle_beyond_its_range_is_refused(options, message):
    """CloseUp took rotation (0, 1e308) radians: the close-up turned by whatever cos(1e308) gave, and a spin added to
    so large an angle was lost to rounding (the animation stood still); an elevation of 2 radians (past the zenith)
    turned the billboard's camera over. Angles beyond 1024 turns (degrees, most likely) and an elevation outside
    [-π/2, π/2] are refused by name."""
    roi = ROI.circle((0.0, 0.0), 1.0)
    with pytest.raises(InvalidInputError, match=message):
        CloseUp(roi, **options)
    assert CloseUp(roi, rotation=(-6433.0, 6433.0), billboard_view=(6433.0, -1.5)).rotation == (-6433.0, 6433.0)


def test_a_float32_quarter_turn_billboard_view_is_taken_not_refused():
    """π/2 in float32 (np.float32(np.pi / 2), 4e-8 above float64's π/2) was refused as an elevation outside
    [-π/2, π/2], where float64's π/2 is taken; render's camera takes it alike. The next float32 beyond is refused."""
    roi = ROI.circle((0.0, 0.0), 1.0)
    for sign in (1.0, -1.0):
        quarter = np.float32(sign * np.pi / 2)
        assert CloseUp(roi, billboard_view=(np.pi, quarter)).billboard_view == (np.pi, float(quarter))
        render._camera_position(CloseUp(roi, billboard_view=(np.pi, quarter)).billboard_view,
                                np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), 1.0)
        with pytest.raises(InvalidInputError, match=r"billboard_view must be .*elevation in \[-π/2, π/2\]"):
            CloseUp(roi, billboard_view=(np.pi, np.nextafter(quarter, np.float32(sign * np.inf))))


@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("z_scale", [1e30, 1e6])
def test_a_z_scale_that_renders_a_sliver_is_refused(z_scale):
    """render_closeups (the CLI's closeup --z-scale 1e30) passed _check_reach (below ±1e150) and wrote a blank white
    image: the fitted camera showed the terrain less than a pixel wide. The layered renderer now refuses it as
    render_mesh does, naming z_scale and the value that would make the terrain as tall as it is wide; within reach,
    the image is not blank."""
    scale = re.escape(f"z_scale={z_scale:g}")
    message = rf"^the mesh would render .*\(with {scale}\), too thin to see .*; a z_scale near"
    with pytest.raises(InvalidInputError, match=message):
        render_closeups(terrain(), [one()], window_size=SIZE, z_scale=z_scale)
    image = render_closeups(terrain(), [one()], window_size=SIZE, z_scale=2.0)
    assert (image != 255).any(axis=2).sum() > 100


def test_closeup_gif_frames_over_the_budget_are_refused_before_the_dem_is_read(tmp_path, capsys):
    """closeup --gif --frames 100000 loaded the DEM and rendered the still image before animate_closeups refused
    the frames (all kept until written) against the memory budget; the CLI now checks them up front, counting the
    copy save_animation's writer makes of them (np.stack) too."""
    from stepterrain import cli

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((12, 14)) * 100)
    code = cli.main(["closeup", str(dem), "--gif", str(tmp_path / "a.gif"), "--frames", "100000", "--size", "320x200",
                     "-o", str(tmp_path / "still.png")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert "--frames 100000 of 320 x 200 pixels (kept, then copied once by the writer) would need 36,621.1 MiB" in err
    assert "loading" not in err
    assert not (tmp_path / "still.png").exists()


@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_animate_closeups_shows_progress_when_asked(capfd):
    """animate_closeups rendered thousands of frames (the CLI's --frames) for minutes without a word; with
    progress=True (the CLI passes it unless -q) a tqdm bar counts the frames on stderr."""
    frames = animate_closeups(terrain(), [one(spin=(1.0, 1))], frames=3, fps=3.0, window_size=SIZE, progress=True)
    assert len(frames) == 3
    assert "close-up frames" in capfd.readouterr().err
    with pytest.raises(InvalidInputError, match="progress"):
        animate_closeups(terrain(), [one()], frames=1, window_size=SIZE, progress="yes")


@pytest.mark.parametrize("spacing", [(2.0, 3.0), (30.0, -20.0), (-7.0, 11.0)])
def test_slope_above_a_region_takes_the_terrains_slope_at_the_regions_edge(spacing):
    # the slope was taken of the region's heights alone: one-sided differences along its edge marked a node of 13°
    # as steeper than 30° and missed one of 36°; it is the terrain's slope (central differences) there too
    from stepterrain.terrain import Terrain

    heights = hills(37, 45, seed=1) * np.float32(max(abs(spacing[0]), abs(spacing[1])) / 2)  # slopes alike
    t = Terrain.from_heights(heights, spacing=spacing, origin=(500.0, -300.0))
    xmin, xmax, ymin, ymax = t.extent
    region = (xmin + 0.2 * (xmax - xmin), xmin + 0.7 * (xmax - xmin), ymin + 0.1 * (ymax - ymin),
              ymin + 0.5 * (ymax - ymin))
    roi = ROI.slope_above(t, 20.0, region=region)
    rows, cols = np.mgrid[0:37, 0:45]
    x, y = 500.0 + cols * spacing[0], -300.0 + rows * spacing[1]
    gy, gx = np.gradient(heights.astype(np.float64), spacing[1], spacing[0])  # the whole terrain's slope
    steep = np.degrees(np.arctan(np.hypot(gx, gy))) > 20.0
    inside = (x >= region[0]) & (x <= region[1]) & (y >= region[2]) & (y <= region[3])
    m = roi.factor(np.column_stack([x[inside], y[inside]]))
    assert 0 < steep[inside].sum() < inside.sum()
    np.testing.assert_array_equal(m, steep[inside].astype(np.float64))


@pytest.mark.parametrize("speed", [0.5, -0.5])
def test_spin_stands_still_before_time_zero(speed):
    # copysign took the sign of the speed only: at a negative time the close-up had turned as far as at the positive
    # one, in the spin's direction (β(−t) = β(t)); before the animation starts it stands at its rotation
    cu = CloseUp(ROI.circle((0.0, 0.0), 1.0), rotation=(0.0, 0.25), spin=(speed, 2))
    times = np.linspace(-3.0, 6.0, 37)
    turns = np.array([cu.turn(float(t)) for t in times])
    assert np.all(np.diff(turns) * np.sign(speed) >= 0)  # never back against the spin
    assert np.all(turns[times <= 0] == cu.rotation[1])
    assert cu.turn(-np.inf) == cu.rotation[1]


def test_animation_frames_every_turn_of_a_spinning_closeup(monkeypatch):
    # the frame box was the union of 9 evenly spaced times: at 4 fps over 8 s with one turn per second all 9 fell on
    # whole turns, and a long close-up turned across them left the box (and the camera's view) at the quarter turns
    import stepterrain.closeup as closeup_module
    from stepterrain.closeup import closeup_layers

    class NoRenderer:
        def __init__(self, **kwargs):
            pass

        def close(self):
            pass

    boxes = []
    monkeypatch.setattr(render, "LayeredRenderer", NoRenderer)
    monkeypatch.setattr(closeup_module, "render_closeups", lambda *args, bounds, **kwargs: boxes.append(bounds))
    t = terrain()
    cu = CloseUp(ROI.rectangle((1040.0, 2030.0), (40.0, 6.0)), scale=2.0, offset=(0.0, 0.0, 60.0), spin=(1.0, 8))
    frames, fps = 33, 4.0
    animate_closeups(t, [cu], frames=frames, fps=fps, window_size=SIZE, device="cpu")
    assert len(boxes) == frames
    box = np.asarray(boxes[0])
    for i in range(frames):  # frame i at time i / fps: its close-up lies in the box
        (layer,) = closeup_layers(t, [cu], time=i / fps, device="cpu")
        assert np.all(layer.vertices >= box[0]) and np.all(layer.vertices <= box[1]), f"frame {i}"


@pytest.mark.parametrize("spacing", [(2.0, 3.0), (3.0, -2.0)])
def test_anchor_feet_lie_on_the_overview_surface(spacing):
    # the foot of each rung took the bilinear height of its cell, not the height of the overview's triangle there:
    # the fence stood above or sank below the drawn terrain (up to 1.6 m on the 30 m Big Tujunga DEM)
    from stepterrain.closeup import anchor_strips
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(hills(), spacing=spacing, origin=(1000.0, 2000.0))
    xmin, xmax, ymin, ymax = t.extent
    cu = CloseUp(ROI.circle(((xmin + xmax) / 2, (ymin + ymax) / 2), 20.0), scale=2.0, offset=(0.0, 0.0, 60.0))
    (strip,) = anchor_strips(t, [cu], device="cpu")
    feet = strip.vertices[:: strip.rungs + 1]
    mesh = t.mesh()  # every triangle of the overview, brute force
    surface = surface_heights(np.asarray(mesh.vertices), np.asarray(mesh.faces), feet[:, :2])
    assert len(feet) > 20
    np.testing.assert_allclose(feet[:, 2], surface, atol=1e-3)


def holed(seed: int = 2) -> np.ndarray:
    """Hills with nodata: a 3 x 3 hole, node (20, 11) between two missing nodes along x, a lone missing node, and
    node (0, 5) at the grid's edge whose only neighbour along y is missing."""
    heights = hills(33, 41, seed=seed)
    heights[10:13, 15:18] = np.nan
    heights[20, 10] = heights[20, 12] = np.nan
    heights[5, 30] = np.nan
    heights[1, 5] = np.nan
    return heights


@pytest.mark.parametrize("spacing", [(2.0, 3.0), (3.0, -2.0), (-2.5, 1.5)])
@pytest.mark.parametrize("kind", ["slope", "aspect"])
def test_slope_and_aspect_next_to_nodata_take_the_one_sided_difference(spacing, kind):
    # np.gradient gave NaN at every node next to a hole, then nan_to_num made it slope 0 / aspect north (0)
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    heights = holed()
    (ox, oy), (dx, dy) = (1000.0, 2000.0), spacing
    t = Terrain.from_heights(heights, spacing=spacing, origin=(ox, oy))
    xmin, xmax, ymin, ymax = t.extent
    roi = ROI.rectangle(((xmin + xmax) / 2, (ymin + ymax) / 2), (xmax - xmin, ymax - ymin), edge_width=0.5)
    (layer,) = closeup_layers(t, [CloseUp(roi, scalars=kind)], device="cpu")
    fj, fi = (layer.original[:, 0] - ox) / dx, (layer.original[:, 1] - oy) / dy
    j, i = np.rint(fj).astype(int), np.rint(fi).astype(int)
    np.testing.assert_allclose(np.column_stack([fj, fi]), np.column_stack([j, i]), atol=1e-6)  # at the nodes
    gy, gx = nodata_gradient(heights, dy, dx)  # world +y and +x
    expected = np.arctan(np.hypot(gx, gy)) if kind == "slope" else np.mod(np.arctan2(-gx, -gy), 2 * np.pi)
    expected = expected[i, j]
    plain_gy, plain_gx = np.gradient(heights.astype(np.float64), dy, dx)
    one_sided = ~np.isfinite(plain_gx[i, j] + plain_gy[i, j]) & np.isfinite(expected)
    assert one_sided.sum() > 20 and np.isnan(expected).sum() >= 2  # (20, 11) and (0, 5) are drawn, without gradient
    np.testing.assert_allclose(layer.scalars, expected, rtol=1e-6, atol=1e-6, equal_nan=True)


@pytest.mark.parametrize("spacing", [(2.0, 3.0), (3.0, -2.0), (-2.5, 1.5)])
@pytest.mark.parametrize("region", [False, True])
def test_slope_above_next_to_nodata_takes_the_one_sided_difference(spacing, region):
    # next to a hole the slope was NaN, so m = 0 there however steep the terrain: a steep rim left out of the ROI
    from stepterrain.terrain import Terrain

    heights = holed(seed=3)
    dx, dy = spacing
    t = Terrain.from_heights(heights, spacing=spacing, origin=(500.0, -300.0))
    xmin, xmax, ymin, ymax = t.extent
    window = (slice(None), slice(None))
    box = None
    if region:  # nodes 4..24 along y and 8..35 along x of the grid as the ROI sees it (rows at increasing y)
        box = (xmin + 8 * abs(dx), xmin + 35 * abs(dx), ymin + 4 * abs(dy), ymin + 24 * abs(dy))
        window = (slice(4, 25), slice(8, 36))
    roi = ROI.slope_above(t, 25.0, edge=10.0, region=box)
    gy, gx = nodata_gradient(heights, dy, dx)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    expected = np.nan_to_num(np.clip((slope - 25.0) / 10.0, 0, 1), nan=0.0)
    plain_gy, plain_gx = np.gradient(heights.astype(np.float64), dy, dx)  # the slope before the fix
    plain = np.clip((np.degrees(np.arctan(np.hypot(plain_gx, plain_gy))) - 25.0) / 10.0, 0, 1)
    flip = (slice(None, None, -1 if dy < 0 else 1), slice(None, None, -1 if dx < 0 else 1))  # rows at increasing y
    expected, plain = expected[flip][window], plain[flip][window]
    assert roi.mask.shape == expected.shape
    one_sided = np.isnan(plain) & (expected > 0)
    assert one_sided.sum() >= 3
    np.testing.assert_allclose(roi.mask, expected, atol=1e-6)
    away = np.isfinite(plain) & np.isfinite(heights[flip][window])  # away from holes: the bits np.gradient gave
    np.testing.assert_array_equal(roi.mask[away], plain[away].astype(roi.mask.dtype))


def test_a_node_without_a_gradient_shows_the_colormaps_bad_color():
    # a drawn node with no neighbour with a height along x (both missing) was colored as slope 0; it has no slope
    import matplotlib

    from stepterrain.terrain import Terrain

    heights = holed()
    t = Terrain.from_heights(heights, spacing=(2.0, -3.0), origin=(0.0, 0.0))
    cu = CloseUp(ROI.circle((22.0, -60.0), 8.0), offset=(0.0, 0.0, 30.0))
    scene = closeup_scene(t, [cu], scalars="slope", cmap="magma", device="cpu")
    overview = np.unique(scene.faces[scene.face_attributes["layer"] == 0])
    rgb = np.asarray(scene.visual.vertex_colors)[overview, :3]
    xy = np.asarray(scene.vertices)[overview, :2]
    table = matplotlib.colormaps["magma"]
    bad = (np.asarray(table.get_bad())[:3] * 255 + 0.5).astype(np.uint8)
    flat = (np.asarray(table(0.0))[:3] * 255 + 0.5).astype(np.uint8)
    assert not np.array_equal(bad, flat)
    gy, gx = nodata_gradient(heights, -3.0, 2.0)
    j, i = np.rint(xy[:, 0] / 2.0).astype(int), np.rint(xy[:, 1] / -3.0).astype(int)
    none = np.isnan(gx[i, j] + gy[i, j])
    assert none.sum() >= 2  # nodes (20, 11) and (0, 5)
    assert (rgb[none] == bad).all()
    assert not (rgb[~none] == bad).all(axis=1).any()


def test_closeup_docstring_states_the_billboard_azimuth_convention_the_render_uses():
    # CloseUp gave billboard_view as (azimuth, elevation) without saying where the azimuth counts from or which way
    import inspect
    import math

    from stepterrain.render import _camera_position  # render_billboard's camera for billboard_view

    doc = " ".join(inspect.getdoc(CloseUp).split())
    part = doc[doc.index("billboard_view"):doc.index("stepped :")]
    assert "clockwise from north" in part and "0 looks from the north, π/2 from the east" in part
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-2.0, 2.0) for z in (0.0, 0.5)])
    for azimuth, from_xy in ((0.0, (0.0, 1.0)), (math.pi / 2, (1.0, 0.0)), (math.pi, (0.0, -1.0))):
        eye, focal, _ = _camera_position((azimuth, 0.4), corners, 1.0)
        seen_from = np.subtract(eye, focal)[:2]
        np.testing.assert_allclose(seen_from / np.linalg.norm(seen_from), from_xy, atol=1e-9)


def test_anchor_feet_lie_on_a_coarse_tins_triangles():
    # on a TIN each foot took the height of the nearest vertex: on a coarse TIN the fence floated above or sank
    # below the drawn faces; the feet now lie on the triangle holding them, outside every triangle on the nearest
    # vertex's height
    import trimesh

    from stepterrain.closeup import anchor_strips
    from stepterrain.terrain import Terrain, heightfield_mesh

    rng = np.random.default_rng(5)
    heights = (rng.normal(0.0, 25.0, (7, 8)) + 100.0).astype(np.float32)
    grid = heightfield_mesh(heights, spacing=(40.0, 40.0))
    vertices = np.asarray(grid.vertices, dtype=np.float64).copy()
    interior = (vertices[:, 0] > 0) & (vertices[:, 0] < 280) & (vertices[:, 1] > 0) & (vertices[:, 1] < 240)
    vertices[interior, :2] += rng.uniform(-12.0, 12.0, (int(interior.sum()), 2))  # irregular, still one-to-one
    vertices[:, :2] += (388000.0, 3798000.0)  # UTM-sized coordinates
    faces = np.asarray(grid.faces)
    corner = vertices[faces, :2].mean(axis=1) - (388000.0, 3798000.0)
    faces = faces[~((corner[:, 0] > 200) & (corner[:, 1] > 160))]  # a notch: part of the fence stands outside
    t = Terrain.from_mesh(trimesh.Trimesh(vertices, faces, process=False))
    cus = [CloseUp(ROI.circle((388000.0 + cx, 3798000.0 + cy), 55.0), offset=(0.0, 0.0, 200.0))
           for cx, cy in ((120.0, 110.0), (235.0, 190.0))]
    strips = anchor_strips(t, cus, device="cpu")
    feet = np.concatenate([s.vertices[:: s.rungs + 1] for s in strips])
    surface = surface_heights(vertices, faces, feet[:, :2])  # brute force over every triangle
    used = vertices[np.unique(faces)]
    nearest = used[np.argmin(((feet[:, None, :2] - used[None, :, :2]) ** 2).sum(-1), axis=1), 2]
    inside = np.isfinite(surface)
    assert inside.sum() > 40 and (~inside).sum() > 5
    assert np.abs(nearest[inside] - surface[inside]).max() > 5.0  # the nearest vertex is far off the faces here
    np.testing.assert_allclose(feet[inside, 2], surface[inside], atol=1e-3)
    np.testing.assert_allclose(feet[~inside, 2], nearest[~inside], atol=1e-3)


def test_flat_ground_has_no_aspect():
    """arctan2(-0, -0) mod 2π is π: a flat node (a lake, a plateau) was coloured as facing south. It has no downhill
    direction: NaN, the colormap's "bad" colour, as gdaldem's aspect marks flat ground. Sloping nodes keep their
    aspect, clockwise from north (a plane falling to the east: π/2)."""
    from stepterrain.closeup import _vertex_scalars
    from stepterrain.terrain import Terrain

    heights = np.zeros((6, 7))
    heights[:, 4:] = -np.arange(3.0) - 1.0  # flat to column 3, then falling to the east (x grows with the column)
    t = Terrain.from_heights(heights, spacing=(1.0, 1.0))
    jj, ii = np.meshgrid(np.arange(7), np.arange(6))
    points = np.column_stack([jj.ravel(), ii.ravel(), heights.ravel()]).astype(np.float32)
    aspect = _vertex_scalars(t, points, "aspect").reshape(6, 7)
    assert np.isnan(aspect[:, :3]).all()  # flat: no aspect (was π, south)
    np.testing.assert_allclose(aspect[:, 4:], np.pi / 2, atol=1e-6)  # falling to the east


@pytest.mark.parametrize("spacing", [(10.0, 10.0), (10.0, -10.0), (-10.0, 10.0)])
def test_source_faces_index_the_overview_mesh_of_a_dem_with_nodata(spacing):
    """``CloseUpLayer.source_faces`` index ``Terrain.mesh()``'s faces; that mesh leaves out the faces at nodata, so
    the grid numbering 2·cell + t named other faces of the overview (or past its end) after the first hole."""
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    heights = hills()
    heights[4:7, 10:13] = np.nan  # a hole before the ROI's rows
    heights[16, 18] = np.nan  # one inside it
    t = Terrain.from_heights(heights, spacing=spacing, origin=(0.0, 0.0))
    x0, x1, y0, y1 = t.extent
    cu = CloseUp(ROI.circle(((x0 + x1) / 2, (y0 + y1) / 2), 100.0), offset=(0.0, 0.0, 50.0))
    layer = closeup_layers(t, [cu], device="cpu")[0]
    mesh = t.mesh()
    assert len(layer.faces) > 100 and layer.source_faces.max() < len(mesh.faces)
    # each culled face is the overview face it names, corner for corner
    named = np.asarray(mesh.vertices)[mesh.faces[layer.source_faces]]
    np.testing.assert_array_equal(layer.original[layer.faces], named)


def _fence_feet(t, cu):
    """The fence's feet (P, 3) and the length of the outline they follow (the panels' bottom edges)."""
    from stepterrain.closeup import anchor_strips

    (strip,) = anchor_strips(t, [cu], device="cpu")
    feet = strip.vertices[:: strip.rungs + 1]
    panels = strip.faces[:: 2 * strip.rungs]  # each panel's first face (a + 0, b + 0, b + 1)
    a, b = feet[panels[:, 0] // (strip.rungs + 1)], feet[panels[:, 1] // (strip.rungs + 1)]
    return feet, float(np.linalg.norm(a - b, axis=1).sum())


@pytest.mark.parametrize(("center", "length"), [((0.0, 100.0), np.pi * 90 + 180), ((0.0, 0.0), np.pi * 45 + 180),
                                                ((400.0, 200.0), np.pi * 45 + 180), ((200.0, 100.0), np.pi * 180)])
def test_a_fence_stops_at_the_terrains_edge_and_closes_along_it(center, length):
    """A ROI reaching past the terrain's edge: the fence followed the whole outline through empty space (a full
    disc's fence about a half or quarter disc of close-up); it now follows the outline inside the extent and the
    extent's edge where the ROI holds it (m = 0.5 at radius 90 for a radius 100 with the default soft edge)."""
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((101, 201), np.float32), spacing=(2.0, 2.0), origin=(0.0, 0.0))
    cu = CloseUp(ROI.circle(center, 100.0), offset=(0.0, 0.0, 50.0), anchor=AnchorStyle(simplify=0))
    feet, followed = _fence_feet(t, cu)
    assert (feet[:, :2] >= 0).all() and (feet[:, 0] <= 400).all() and (feet[:, 1] <= 200).all()
    assert followed == pytest.approx(length, rel=1e-3)


def test_a_fence_cut_by_the_terrains_edge_closes_only_where_the_roi_holds_the_edge():
    """Two arms of a U-shaped painted ROI reach into the terrain across its left edge: two fences, each closed along
    the edge by its arm's width, none along the edge between the arms (m = 0 there)."""
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((101, 201), np.float32), spacing=(2.0, 2.0), origin=(0.0, 0.0))
    mask = np.zeros((50, 50))
    mask[5:45, 5:15] = mask[5:15, 5:45] = mask[35:45, 5:45] = 1  # the U's base lies left of x = 0
    roi = ROI.painted(mask, (10.0, 100.0), (200.0, 200.0), top_row_north=False)
    cu = CloseUp(roi, offset=(0.0, 0.0, 50.0), anchor=AnchorStyle(simplify=0))
    feet, _ = _fence_feet(t, cu)
    assert (feet[:, 0] >= 0).all()
    on_edge = feet[feet[:, 0] == 0, 1]
    between = (on_edge > 70) & (on_edge < 130)  # the edge between the arms (y ≈ 59..141 lies outside the ROI)
    assert len(on_edge) >= 4 and not between.any()
    assert ((on_edge < 65) | (on_edge > 135)).all()


@pytest.mark.parametrize("mapping", [{}, {"stepped": 20.0}, {"scalars": "slope"}])
def test_a_roi_that_holds_no_terrain_is_refused_by_name(mapping):
    """A ROI between grid nodes (smaller than a cell) or over a nodata hole has no geometry: the close-up was drawn as
    an anchor fence about nothing, without a word, and a stepped one raised "terrain has no finite height (all
    nodata)" of a terrain that has heights. Both are now refused, naming the close-up and the cause."""
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    heights = hills()
    heights[5:25, 5:25] = np.nan
    t = Terrain.from_heights(heights, spacing=(10.0, 10.0), origin=(0.0, 0.0))
    for roi, why in ((ROI.circle((305.0, 255.0), 4.0), "between the nodes, at the grid spacing 10 x 10"),  # in a cell
                     (ROI.circle((150.0, 150.0), 40.0), "the 81 grid nodes in its box are nodata")):  # in the hole
        cu = CloseUp(roi, offset=(0.0, 0.0, 50.0), **mapping)
        expected = rf"^closeups\[1\]: ROI box .* holds no terrain: .*{why}"
        with pytest.raises(InvalidInputError, match=expected):
            closeup_layers(t, [CloseUp(ROI.circle((305.0, 255.0), 30.0)), cu], device="cpu")
        with pytest.raises(InvalidInputError, match=r"closeups\[0\]: ROI box .* holds no terrain"):
            closeup_scene(t, [cu], device="cpu")


def test_a_fence_over_nodata_keeps_the_height_of_the_nearest_node_with_one():
    """An outline crossing a nodata hole: its feet there dropped to the terrain's lowest height (a fence reaching
    hundreds of metres below the hole's rim); they now take the height of the nearest node with a height."""
    from stepterrain.terrain import Terrain

    y, x = np.mgrid[0:60, 0:80]
    heights = (1000 + 5 * x + 3 * y).astype(np.float32)
    heights[10:40, 10:40] = np.nan
    t = Terrain.from_heights(heights, spacing=(10.0, 10.0), origin=(0.0, 0.0))
    cu = CloseUp(ROI.circle((400.0, 250.0), 100.0), offset=(0.0, 0.0, 500.0), anchor=AnchorStyle(simplify=0))
    feet, _ = _fence_feet(t, cu)
    nodes = np.column_stack([x.reshape(-1) * 10.0, y.reshape(-1) * 10.0, heights.reshape(-1)])
    nodes = nodes[np.isfinite(nodes[:, 2])]
    over = feet[feet[:, 0] < 390]  # no drawn triangle (every cell left of x = 390 there has a nodata corner)
    checked = 0
    for foot in over:
        distance = np.hypot(nodes[:, 0] - foot[0], nodes[:, 1] - foot[1])
        first, second = np.argsort(distance)[:2]
        if distance[second] - distance[first] > 1e-6:  # one nearest node
            assert foot[2] == nodes[first, 2]
            checked += 1
    assert checked > 5 and feet[:, 2].min() > 1200  # the terrain's lowest height is 1000


@pytest.mark.parametrize("radii", [(10.0, 2.0), (2.0, 10.0), (10.0, 6.0)])
def test_an_ellipses_soft_edge_is_edge_width_wide_all_round(radii):
    """``edge_width`` is the width of the soft edge inside the rim (ROI.circle's docstring, which ROI.ellipse follows):
    m = smoothstep(distance to the rim / edge_width) inside. An ellipse's came from its scaled radius, a/b times wider
    at the ends of the major axis (a 5:1 ellipse's edge of 1 spanned 5 there)."""
    a, b = radii
    roi = ROI.ellipse((0.0, 0.0), radii, edge_width=1.0, resolution=1025)
    angle = np.linspace(0.0, 2 * np.pi, 20_001)
    rim = np.column_stack([a * np.cos(angle), b * np.sin(angle)])
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (800, 2)) * radii
    points = points[(points[:, 0] / a) ** 2 + (points[:, 1] / b) ** 2 < 1]
    depth = np.array([np.hypot(*(rim - p).T).min() for p in points])  # distance to the rim, by brute force
    x = np.clip(depth, 0.0, 1.0)
    np.testing.assert_allclose(roi.factor(points), x * x * (3 - 2 * x), atol=0.02)


def test_the_scene_mesh_depicts_inactive_anchors_as_the_render_does():
    """closeup_scene exported every anchor as an active close-up's (full color and opacity), whatever ``active`` and
    ``anchor.inactive`` said; the render hides, grays or fades it (Fig. 5)."""
    from stepterrain.closeup import _gray
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(hills(), spacing=(2.0, 2.0))

    def anchor_colors(**kwargs):
        cu = CloseUp(ROI.circle((40.0, 32.0), 8.0), offset=(0, 0, 50.0), color="red", **kwargs)
        scene = closeup_scene(t, [cu], device="cpu")
        return scene.visual.vertex_colors[np.unique(scene.faces[scene.face_attributes["layer"] == 2])]

    active = anchor_colors()
    assert len(active) and np.all(active[:, :3] == [255, 0, 0])
    assert len(anchor_colors(active=False, anchor=AnchorStyle(inactive="hidden"))) == 0
    gray = anchor_colors(active=False, anchor=AnchorStyle(inactive="gray"))
    assert np.all(gray[:, :3] == np.rint(np.asarray(_gray((1.0, 0.0, 0.0))) * 255))
    faint = anchor_colors(active=False, anchor=AnchorStyle(inactive="faint"))
    assert np.all(faint[:, :3] == [255, 0, 0]) and faint[:, 3].max() == np.rint(0.85 * 0.25 * 255)
    assert active[:, 3].max() == np.rint(0.85 * 255)


def test_a_stepped_closeup_without_its_own_cmap_follows_the_scenes_colormap():
    """A stepped close-up (MPFR) that names no cmap was coloured with 'terrain' whatever colormap the scene (or the
    CLI's --colormap) was given; its levels now follow that colormap, and a cmap of its own still wins."""
    t = terrain()

    def closeup_colors(scene_cmap, **kwargs):
        scene = closeup_scene(t, [one(stepped=5.0, **kwargs)], cmap=scene_cmap, device="cpu")
        rgb = scene.visual.vertex_colors[:, :3]
        return rgb[scene.faces[scene.face_attributes["layer"] == 1].reshape(-1)]

    followed = closeup_colors("viridis")
    assert np.array_equal(followed, closeup_colors("terrain", cmap="viridis"))
    assert not np.array_equal(followed, closeup_colors("terrain"))
    assert np.array_equal(closeup_colors("viridis", cmap="magma"), closeup_colors("terrain", cmap="magma"))


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_a_stepped_closeup_without_its_own_cmap_is_rendered_in_the_renders_colormap():
    t = terrain()
    followed = render_closeups(t, [one(stepped=5.0)], window_size=SIZE, cmap="viridis", device="cpu")
    named = render_closeups(t, [one(stepped=5.0, cmap="viridis")], window_size=SIZE, cmap="viridis", device="cpu")
    default = render_closeups(t, [one(stepped=5.0, cmap="terrain")], window_size=SIZE, cmap="viridis", device="cpu")
    assert np.array_equal(followed, named) and not np.array_equal(followed, default)


def test_a_16_bit_painted_mask_is_scaled_and_a_mask_out_of_range_gets_its_dtypes_hint():
    """A 16-bit grayscale mask (uint16, as a 16-bit PNG reads) given to ROI.painted, "any grayscale image", was refused
    with "divide an 8-bit mask by 255"; it is now divided by 65535 as an 8-bit one is by 255. A mask out of [0, 1]
    given to ROI itself is told the scale of its own dtype or range."""
    eight = np.zeros((9, 9), np.uint8)
    eight[2:7, 3:8] = 255
    eight[4, 4] = 51
    sixteen = eight.astype(np.uint16) * 257  # the same image at 16 bits
    as_8, as_16 = (ROI.painted(m, (0.0, 0.0), (8.0, 8.0)) for m in (eight, sixteen))
    np.testing.assert_array_equal(as_16.mask, as_8.mask)
    assert as_16.mask.max() == 1.0 and as_16.mask[4, 4] == np.float32(0.2)
    for mask, hint in [(sixteen, "a 16-bit uint16 mask: divide it by 65535"), (eight, "an 8-bit uint8 mask: "),
                       (sixteen.astype(np.float64), "a 16-bit image's values: divide them by 65535"),
                       (eight.astype(np.int32), "an 8-bit image's values: divide them by 255"),
                       (eight.astype(np.float32) - 100, r"scale it to \[0, 1\]\)")]:
        with pytest.raises(InvalidInputError, match=r"^ROI mask values must lie in \[0, 1\]; got range .*\(" + hint):
            ROI((0.0, 0.0), (8.0, 8.0), mask)
    binary = ROI.painted((eight > 0).astype(np.int64), (0.0, 0.0), (8.0, 8.0))  # other integers as they are: 0/1
    assert set(np.unique(binary.mask).tolist()) == {0.0, 1.0}


@pytest.mark.parametrize(("center", "size", "length"), [((50.0, 100.0), (100.0, 300.0), 600.0),
                                                        ((350.0, 100.0), (100.0, 260.0), 600.0),
                                                        ((200.0, 20.0), (500.0, 40.0), 880.0)])
def test_a_fence_along_the_terrains_edge_is_drawn_once(center, size, length):
    """A painted ROI whose box edge is the terrain's edge (its outline runs along it) and which reaches past the
    terrain elsewhere: the stretch along the edge was fenced twice, with the outline and again with the terrain's
    boundary (coincident panels). Each stretch is now fenced once: the feet follow the ROI's part over the terrain."""
    from collections import Counter

    from stepterrain.closeup import anchor_strips
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((101, 201), np.float32), spacing=(2.0, 2.0), origin=(0.0, 0.0))
    roi = ROI.painted(np.ones((20, 20)), center, size)
    _, followed = _fence_feet(t, CloseUp(roi, offset=(0.0, 0.0, 50.0), anchor=AnchorStyle(simplify=0)))
    assert followed == pytest.approx(length, rel=1e-9)
    (strip,) = anchor_strips(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0))], device="cpu")
    faces = Counter(frozenset(map(tuple, np.round(strip.vertices[f], 6))) for f in strip.faces)
    assert len(strip.faces) and max(faces.values()) == 1


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_the_camera_frames_the_closeup_where_it_is_drawn(monkeypatch):
    """The content is drawn fully transformed (M·V_O) up to its outline, but the camera was fitted to the blended
    vertices V_C: a close-up moved off the terrain and scaled reached up to a cell times the scale past the fitted
    box. The box now holds the drawn content, in a render and in an animation."""
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    y, x = np.mgrid[0:21, 0:21]
    t = Terrain.from_heights((10 * np.sin(x / 3.0) + 5 * np.cos(y / 4.0)).astype(np.float32), spacing=(10.0, 10.0))
    cu = CloseUp(ROI.circle((100.0, 100.0), 50.0), scale=3.0, offset=(400.0, 0.0, 0.0))
    (layer,) = closeup_layers(t, [cu], device="cpu")
    seen = layer.mask_factor >= cu.anchor.outline_level
    used = np.unique(layer.faces[seen[layer.faces].any(axis=1)])
    drawn = layer.original[used] @ layer.matrix[:3, :3].T + layer.matrix[:3, 3]
    boxes = []
    fit = render.LayeredRenderer.set_view

    def spy(self, camera, box, **kwargs):
        boxes.append(np.asarray(box, np.float64))
        return fit(self, camera, box, **kwargs)

    monkeypatch.setattr(render.LayeredRenderer, "set_view", spy)
    render_closeups(t, [cu], window_size=SIZE, camera="top", device="cpu")
    animate_closeups(t, [cu], frames=2, window_size=SIZE, camera="top", device="cpu")
    assert len(boxes) == 3
    for box in boxes:
        assert (box[0] <= drawn.min(axis=0)).all() and (box[1] >= drawn.max(axis=0)).all()
    assert drawn[:, 0].max() - layer.vertices[:, 0].max() > 10  # the blended vertices fall short by over a cell


def test_an_unknown_colormap_of_the_stepped_closeups_is_named_by_its_argument():
    """closeup_layers(colors='nope') was refused as "cmap must name a matplotlib colormap", an argument it has not."""
    from stepterrain.closeup import closeup_layers

    stepped = CloseUp(ROI.circle((20.0, 16.0), 5.0), stepped=5.0)
    with pytest.raises(InvalidInputError, match=r"^colors must name a matplotlib colormap .*; got 'nope'"):
        closeup_layers(hills(), [stepped], colors="nope", device="cpu")
    with pytest.raises(InvalidInputError, match=r"^cmap must name a matplotlib colormap .*; got 'nope'"):
        closeup_scene(hills(), [stepped], scalars=None, cmap="nope", device="cpu")


def _stepped_closeup_tins():
    """Two real TINs: a crop of the sample DEM meshed as a heightfield (integer heights: many on thresholds, so
    twins), with nodata holes and a stray point, and a Delaunay TIN of jittered points of the same DEM."""
    import trimesh
    from scipy.spatial import Delaunay

    from stepterrain import heightfield_mesh, sample_dem

    dem = sample_dem()
    h = np.array(dem.heights[:90, :110], dtype=np.float32)
    h[40:43, 60:62] = np.nan
    grid = heightfield_mesh(h, spacing=(30.0, -30.0), origin=(390000.0, 3800000.0))
    grid = trimesh.Trimesh(np.vstack([grid.vertices, [[1e6, 1e7, 5.0]]]), grid.faces, process=False)
    rng = np.random.default_rng(7)
    ij = rng.integers(0, 90, (3000, 2))
    xy = ij[:, ::-1] * 30.0 + rng.uniform(-9.0, 9.0, (3000, 2)) + (400000.0, 3700000.0)
    xy, first = np.unique(xy, axis=0, return_index=True)
    z = np.asarray(dem.heights, dtype=np.float64)[ij[first, 0], ij[first, 1]]
    delaunay = trimesh.Trimesh(np.c_[xy, z], Delaunay(xy).simplices, process=False)
    return [(grid, [ROI.circle((391500.0, 3798500.0), 400.0), ROI.rectangle((390100.0, 3797400.0), (500.0, 700.0))]),
            (delaunay, [ROI.ellipse((401200.0, 3701300.0), (500.0, 250.0)), ROI.circle((400050.0, 3700060.0), 300.0)])]


@pytest.mark.parametrize("case", [0, 1])
def test_a_stepped_closeup_on_a_tin_steps_only_the_faces_near_its_roi(monkeypatch, case):
    """A stepped close-up (MPFR) of a TIN stepped the whole TIN for every close-up and then culled it to the ROI: its
    cost followed the terrain's size, not the ROI's (0.5 s for a small ROI on a 1M-face TIN). It steps the faces that
    can touch the ROI now, to exactly the geometry (vertices, faces, order, colours, mask) of the whole TIN culled,
    with the whole terrain's isovalues."""
    import stepterrain.stepped as stepped_module
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    mesh, rois = _stepped_closeup_tins()[case]
    step = stepped_module.stepped
    closeups = [CloseUp(rois[0], stepped=20.0, scale=2.0), CloseUp(rois[1], stepped=35.0, gamma=0.4, cmap="viridis")]
    whole = Terrain.from_mesh(mesh.copy())  # own caches: the close-ups' sources are built again
    monkeypatch.setattr(stepped_module, "stepped", lambda window, **kw: step(whole, **kw))  # the whole TIN stepped
    expected = closeup_layers(whole, closeups, device="cpu")
    stepped_faces = []

    def spy(window, **kw):
        stepped_faces.append(len(window.faces))
        return step(window, **kw)

    monkeypatch.setattr(stepped_module, "stepped", spy)
    t = Terrain.from_mesh(mesh)
    got = closeup_layers(t, closeups, device="cpu")
    assert len(stepped_faces) == 2 and max(stepped_faces) < len(t.faces) / 4
    for a, b in zip(expected, got, strict=True):
        assert len(a.faces) > 50
        for name in ("vertices", "faces", "colors", "mask_factor", "original", "source_faces"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("scalars", ["height", None])
def test_an_overview_texture_with_transparent_texels_shows_the_overview_mapping_under_them(scalars):
    """render_closeups took an (h, w, 4) texture and dropped its alpha: texels with alpha 0 (nodata, outside an aerial
    image's footprint) rendered opaque in whatever RGB they held (here red). The texture is now laid over the
    overview's own mapping by its alpha: the transparent half shows the render without a texture, the opaque half
    the image, and an opaque RGBA texture renders as its RGB."""
    t = terrain()
    red = np.zeros((16, 16, 4), np.uint8)
    red[..., 0] = 255
    red[:, :8, 3] = 255  # the west half opaque, the east half transparent
    plain = render_closeups(t, [], window_size=SIZE, scalars=scalars, camera="top", device="cpu")
    draped = render_closeups(t, [], window_size=SIZE, scalars=scalars, camera="top", texture=red, device="cpu")
    east = slice(SIZE[0] // 2 + 8, None)
    west = slice(8, SIZE[0] // 2 - 8)

    def reddish(image):
        rgb = image.astype(int)
        return (rgb[..., 0] > 150) & (rgb[..., 1] < 90) & (rgb[..., 2] < 90)

    assert np.abs(draped[:, east].astype(int) - plain[:, east].astype(int)).max() <= 1
    assert not reddish(draped[:, east]).any()
    assert reddish(draped[:, west]).mean() > 0.3  # the terrain fills ~40 % of the window
    opaque = red.copy()
    opaque[..., 3] = 255
    as_rgba = render_closeups(t, [], window_size=SIZE, scalars=scalars, camera="top", texture=opaque, device="cpu")
    as_rgb = render_closeups(t, [], window_size=SIZE, scalars=scalars, camera="top", texture=opaque[..., :3].copy(),
                             device="cpu")
    assert np.array_equal(as_rgba, as_rgb)


@pytest.mark.parametrize("mapping", [{}, {"stepped": 20.0}, {"scalars": "slope"}])
def test_a_roi_over_lone_heights_names_them_instead_of_a_mask_of_zero(mapping):
    """A ROI over nodes with a height that join no triangle (a grid with nodata on every other node, a TIN point on
    no face) was refused with "its mask is 0 at every grid node with a height", of nodes inside the ROI whose mask is
    1: the refusal now names those nodes and why they give no surface. A ROI whose mask is 0 at every node keeps the
    old message."""
    import trimesh

    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    heights = hills(9, 11)
    sparse = heights.copy()
    sparse[::2, ::2] = np.nan  # a checkerboard of nodata: every cell has a nodata corner, no triangle is drawn
    sparse[1::2, 1::2] = np.nan
    t = Terrain.from_heights(sparse, spacing=(10.0, 10.0), origin=(500000.0, 4500000.0))
    roi = ROI.circle((500050.0, 4500040.0), 20.0)
    inside = (roi.factor(np.column_stack([500000.0 + np.tile(np.arange(11), 9) * 10.0,
                                          4500000.0 + np.repeat(np.arange(9), 11) * 10.0])) > 0)
    expected_nodes = int((inside & np.isfinite(sparse).reshape(-1)).sum())
    assert expected_nodes >= 4
    with pytest.raises(InvalidInputError, match=rf"^closeups\[0\]: ROI box .* holds no terrain: its mask is above 0 "
                                                rf"only at {expected_nodes} grid nodes with a height that join no "
                                                r"triangle with three heights \(.*nodata around them\)") as info:
        closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0), **mapping)], device="cpu")
    assert "mask is 0 at every" not in str(info.value)
    # a TIN point on no face (inside the TIN's extent), under the ROI: named as such
    points = np.array([[0.0, 0.0, 1.0], [100.0, 0.0, 2.0], [0.0, 100.0, 3.0], [80.0, 80.0, 4.0]])
    tin = trimesh.Trimesh(points, [[0, 1, 2]], process=False)
    with pytest.raises(InvalidInputError, match=r"mask is above 0 only at 1 TIN point with a height that joins no "
                                                r"triangle with three heights \(the overview has no surface there\)"):
        closeup_scene(tin, [CloseUp(ROI.circle((80.0, 80.0), 3.0), offset=(0.0, 0.0, 5.0))], device="cpu")
    # the mask 0 at every node with a height (a ROI inside one cell of the full grid): the message as it was
    full = Terrain.from_heights(heights, spacing=(10.0, 10.0))
    with pytest.raises(InvalidInputError, match=r"its mask is 0 at every grid node with a height"):
        closeup_layers(full, [CloseUp(ROI.circle((55.0, 45.0), 3.0), offset=(0.0, 0.0, 50.0), **mapping)],
                       device="cpu")


def test_cli_closeup_png_beside_a_png_output_is_refused(tmp_path, capsys):
    """``closeup -o a.png --png b.png`` rendered once and wrote the same picture to both files: --png is the render
    beside a mesh --output (its help), and a .png --output is the render already. Refused by name now, before any
    work and with no file written; beside a mesh --output it is taken as before (checked up to the renderer)."""
    from stepterrain import cli

    argv = ["-q", "closeup", "--device", "cpu", "-o", str(tmp_path / "a.png"), "--png", str(tmp_path / "b.png")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err == (f"stepterrain closeup: error: --png writes the render beside a mesh --output, or alone (a .png "
                   f"--output is the render already); got --output {str(tmp_path / 'a.png')!r} with --png "
                   f"{str(tmp_path / 'b.png')!r}\n"), err
    assert list(tmp_path.iterdir()) == []
    # beside a mesh: past the check (a --size too small for the close-up stops it before any work)
    assert cli.main(["-q", "closeup", "-o", str(tmp_path / "s.ply"), "--png", str(tmp_path / "b.png"),
                     "--size", "8x8"]) == 2
    assert "--size 8x8 holds at most 0 close-ups" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_closeup_animation_options_without_gif_are_refused(tmp_path, capsys):
    """``closeup --spin 1 --frames 48 --fps 24 -o still.png`` (or -o scene.ply) was accepted and made the same still
    render or scene mesh as without them: both show the close-ups at time 0, before any spin. Without --gif they are
    refused by name now, after their values are checked, and with no file written."""
    from stepterrain import cli

    for output in ("still.png", "scene.ply"):
        for extra, names, verb in ((["--spin", "1"], "--spin", "applies"),
                                   (["--frames", "48", "--fps", "24"], "--frames and --fps", "apply"),
                                   (["--spin", "-2", "--frames", "3", "--fps", "6"], "--spin, --frames and --fps",
                                    "apply")):
            assert cli.main(["-q", "closeup", "-o", str(tmp_path / output), *extra]) == 2
            pronoun = "it" if verb == "applies" else "them"
            assert capsys.readouterr().err == (
                f"stepterrain closeup: error: {names} {verb} only with --gif (the still render and the scene mesh "
                f"show the close-ups before any spin); got {pronoun} without --gif\n")
    assert cli.main(["-q", "closeup", "-o", str(tmp_path / "scene.ply"), "--fps", "0"]) == 2  # the value first
    assert "--fps must be a positive number; got 0" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_closeup_an_unknown_anchor_names_the_presets_alone(tmp_path, capsys):
    """``closeup --anchor bogus`` said "--anchor transparency must be one of [...] or an opacity table" (the library's
    words: no option takes a table), and only after the DEM was loaded. It names the presets in the option's terms
    now, before any work; every preset passes."""
    from stepterrain import cli
    from stepterrain.closeup import TRANSFER_PRESETS

    out = tmp_path / "s.ply"
    assert cli.main(["-q", "closeup", "--anchor", "bogus", "-o", str(out)]) == 2
    assert capsys.readouterr().err == ("stepterrain closeup: error: --anchor must be one of opaque, linear, inverse, "
                                       "ends, hidden; got 'bogus'\n")
    assert not out.exists()
    for preset in TRANSFER_PRESETS:
        assert cli.main(["-q", "closeup", "--anchor", preset, "-o", str(out), "--device", "cpu"]) == 0, preset


def test_cli_closeup_a_colormap_that_colours_nothing_is_refused(tmp_path, capsys):
    """``closeup --scalars none --colormap viridis`` without a --stepped close-up made the same image and scene mesh
    as without --colormap: it colours the overview's scalars and the stepped close-ups' levels only. Refused by name
    now, before any work; with a --stepped close-up (its levels take the colormap) it passes."""
    from stepterrain import cli

    out = tmp_path / "s.ply"
    for stepped in ([], ["--stepped", "0"]):
        assert cli.main(["-q", "closeup", "--scalars", "none", "--colormap", "viridis", *stepped, "-o", str(out)]) == 2
        assert capsys.readouterr().err == (
            "stepterrain closeup: error: --colormap colours the overview's --scalars and the --stepped close-ups; "
            "with --scalars none and no --stepped close-up it colours nothing; got --colormap viridis\n")
        assert not out.exists()
    assert cli.main(["-q", "closeup", "--scalars", "none", "--colormap", "viridis", "--stepped", "100", "-o", str(out),
                     "--device", "cpu"]) == 0 and out.exists()


def _odd_feet(strip) -> list[tuple[float, float]]:
    """The fence's feet (x, y) at an odd number of panel ends: where the fence is left open (none for closed fences)."""
    from collections import Counter

    r1 = strip.rungs + 1
    panels = strip.faces[:: 2 * strip.rungs]  # each panel's first face (a + 0, b + 0, b + 1)
    feet = np.round(strip.vertices[:: r1, :2], 9)
    ends = Counter(map(tuple, np.concatenate([feet[panels[:, 0] // r1], feet[panels[:, 1] // r1]])))
    return [foot for foot, count in ends.items() if count % 2]


def test_a_painted_fence_cut_by_the_terrains_edge_closes_where_its_outline_encloses_the_edge():
    """A painted ROI cut by the terrain's bottom edge: its outline (contourpy's piecewise linear contour of the mask)
    crosses the edge at x = 0.5 and x = 12.95 and encloses the edge between them, but m at that stretch's midpoint
    (bilinear, 0.46) fell below the outline level 0.5, so the stretch was not fenced: the fence stood open, a 12 m
    gap between its two ends on the edge. The stretch is now judged by the outline itself (even-odd rule)."""
    from stepterrain.closeup import anchor_strips
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((21, 21), np.float32), spacing=(1.0, 1.0))
    roi = ROI((10.0, 6.0), (19.0, 29.0), [[0.6, 0.0], [0.4, 1.0]])  # row 0 at the lower y
    (strip,) = anchor_strips(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0), anchor=AnchorStyle(simplify=0))], device="cpu")
    assert _odd_feet(strip) == []
    on_edge = strip.vertices[:: strip.rungs + 1][strip.vertices[:: strip.rungs + 1, 1] == 0.0, 0]
    assert on_edge.min() == pytest.approx(0.5) and on_edge.max() == pytest.approx(12.948, abs=1e-3)


@settings(max_examples=40, deadline=None)
@given(mask=hnp.arrays(np.float64, hs.tuples(hs.integers(2, 3), hs.integers(2, 3)), elements=hs.floats(0.0, 1.0)),
       fx=hs.floats(-0.45, 0.45), fy=hs.floats(-0.45, 0.45), w=hs.floats(3.0, 30.0), h=hs.floats(3.0, 30.0),
       level=hs.floats(0.05, 0.95))
def test_property_a_fence_cut_by_the_terrains_edge_is_closed(mask, fx, fy, w, h, level):
    """Any painted ROI over a terrain's corner (its box across both edges): the fence (the outline inside the extent,
    closed along the edges where the ROI holds them) has no open end: every foot is the end of an even number of
    panels."""
    from stepterrain.closeup import anchor_strips
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((21, 21), np.float32), spacing=(1.0, 1.0))
    cu = CloseUp(ROI((fx * w, fy * h), (w, h), mask), offset=(0.0, 0.0, 50.0),
                 anchor=AnchorStyle(simplify=0, outline_level=level))
    (strip,) = anchor_strips(t, [cu], device="cpu")
    assert _odd_feet(strip) == []


def _whole_image_texture_rgb(image, xy, extent, below):
    """_texture_rgb's colours as they were computed before session 30, from the whole ``image`` in float32 (RGBA
    premultiplied, laid over ``below``, (n, 3)): the reference of the two tests below. ``extent``: the image's outer
    pixel edges (session 49: terrain_extent, as terrain_layer places an image)."""
    xmin, xmax, ymin, ymax = extent
    h, w = image.shape[:2]
    fx = np.clip((xy[:, 0] - xmin) / (xmax - xmin) * w - 0.5, 0, w - 1)
    fy = np.clip((ymax - xy[:, 1]) / (ymax - ymin) * h - 0.5, 0, h - 1)
    j0 = np.minimum(np.floor(fx).astype(np.int64), w - 2)
    i0 = np.minimum(np.floor(fy).astype(np.int64), h - 2)
    tx, ty = (fx - j0)[:, None], (fy - i0)[:, None]
    img = np.asarray(image).astype(np.float32)
    if img.shape[2] == 4:
        img[..., :3] *= img[..., 3:] / 255.0
    top = img[i0, j0] + tx * (img[i0, j0 + 1] - img[i0, j0])
    bottom = img[i0 + 1, j0] + tx * (img[i0 + 1, j0 + 1] - img[i0 + 1, j0])
    sampled = top + ty * (bottom - top)
    if img.shape[2] == 4:
        sampled = sampled[:, :3] + (1.0 - sampled[:, 3:] / 255.0) * np.asarray(below, np.float32)
    return np.clip(np.rint(sampled), 0, 255).astype(np.uint8)


def test_texture_colours_convert_only_the_texels_they_sample():
    """_texture_rgb (a close-up's or overview's aerial image, every frame) converted the whole image to float32 and,
    for RGBA, premultiplied all of it on every call: 66 ms a frame for a 2048 x 2048 RGBA texture under 20 000
    vertices (3.6 ms now). Only the four texels each vertex samples are converted and premultiplied; the colours are
    the whole-image formula's, byte for byte (RGBA over the tan and over given colours, RGB, outside the extent)."""
    from stepterrain import Terrain
    from stepterrain.closeup import _texture_rgb
    from stepterrain.render import _DEFAULT_COLOR
    from stepterrain.texture import terrain_extent

    calls = []

    class Counted(np.ndarray):
        def astype(self, *args, **kwargs):
            calls.append(self.shape)
            return np.asarray(self).astype(*args, **kwargs)

    rng = np.random.default_rng(11)
    t = Terrain.from_heights(np.zeros((40, 50), np.float32), spacing=(30.0, -30.0), origin=(1000.0, 5000.0))
    xmin, xmax, ymin, ymax = t.extent
    n = 5000
    xy = np.column_stack([rng.uniform(xmin - 60, xmax + 60, n), rng.uniform(ymin - 60, ymax + 60, n)])
    under = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    rgba = rng.integers(0, 256, (64, 96, 4), dtype=np.uint8)
    rgba[..., 3] = np.where(rng.random((64, 96)) < 0.3, 0, rgba[..., 3])

    def whole_image(image, below=None):  # the formula as it was, over the whole image
        below = (below if below is not None else np.float32(255.0) * np.asarray(_DEFAULT_COLOR, np.float32))
        return _whole_image_texture_rgb(image, xy, terrain_extent(t), below)

    for image, below in ((rgba, None), (rgba, under), (np.ascontiguousarray(rgba[..., :3]), None)):
        calls.clear()
        got = _texture_rgb(t, image.view(Counted), xy, below)
        np.testing.assert_array_equal(got, whole_image(image, below))
        assert image.shape not in calls and calls, calls  # the sampled texels only, never the whole image


def test_an_overview_texture_is_sampled_at_its_vertices_without_a_float_copy_of_the_image():
    """The colours of a textured overview or close-up (render_closeups' texture=, per layer and per frame) converted
    the whole texture to float32 on every call to sample four texels a vertex: an 8000 x 8000 RGBA orthophoto took
    1 GB of floats (16 bytes a texel, past any memory budget) and 5 s a call. Only the vertices' texels are taken
    in floats now; the colours are bit for bit those of the whole image's floats (premultiplied where alpha, laid
    over what lies under them)."""
    import tracemalloc

    from stepterrain.closeup import _texture_rgb
    from stepterrain.terrain import Terrain
    from stepterrain.texture import terrain_extent

    t = Terrain.from_heights(np.zeros((20, 30), np.float32), spacing=(10.0, -10.0))
    xmin, xmax, ymin, ymax = t.extent
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(xmin - 5, xmax + 5, 500), rng.uniform(ymin - 5, ymax + 5, 500)])
    xy[:4] = [[xmin, ymin], [xmax, ymax], [xmin, ymax], [xmax, ymin]]  # the image's corners and edges
    under = rng.integers(0, 256, (500, 3), dtype=np.uint8)

    def whole_image_floats(image, under):  # the former sampling, from the whole image in float32
        return _whole_image_texture_rgb(image, xy, terrain_extent(t), under)

    for shape in ((7, 9, 3), (7, 9, 4), (2, 2, 4), (1000, 1000, 4)):
        image = rng.integers(0, 256, shape, dtype=np.uint8)
        if shape[2] == 4:
            image[..., 3][rng.random(shape[:2]) < 0.3] = 0  # transparent texels
        np.testing.assert_array_equal(_texture_rgb(t, image, xy, under if shape[2] == 4 else None),
                                      whole_image_floats(image, under))
    tracemalloc.start()
    try:
        _texture_rgb(t, image, xy, under)  # the 1000 x 1000 RGBA image: 16 MB of floats whole
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000, f"{peak} bytes at the peak for 500 vertices of a {image.shape} texture"


def test_save_animation_on_a_full_disk_raises_data_file_error_and_keeps_the_old_gif(tmp_path, monkeypatch):
    """A GIF that met a full disk raised the bare OSError "[Errno 28] No space left on device" (the CLI's closeup
    --gif said that much, no file named), and imageio's plugin wrote its queued frames once more in __del__, printing
    a second traceback. Now a DataFileError naming the file; the old GIF stays, no temporary file is left."""
    import errno

    from PIL import ImageFile

    from stepterrain.closeup import save_animation
    from stepterrain.errors import DataFileError

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    old = tmp_path / "spin.gif"
    old.write_bytes(b"the old animation")
    monkeypatch.setattr(ImageFile, "_save", full)
    frames = [np.full((16, 24, 3), k * 40, np.uint8) for k in range(4)]
    with pytest.raises(DataFileError, match=rf"^cannot write {re.escape(repr(str(old)))}: No space left on device"):
        save_animation(frames, old, fps=4.0)
    assert [p.name for p in tmp_path.iterdir()] == ["spin.gif"]
    assert old.read_bytes() == b"the old animation"


@pytest.mark.parametrize("keep", [0, 0.5])
def test_save_animation_refuses_an_mp4_ffmpeg_did_not_finish(tmp_path, monkeypatch, keep):
    """ffmpeg that failed while writing an MP4 (a full disk: "Error writing trailer: No space left on device")
    exits with an error imageio-ffmpeg does not check: save_animation returned the path, and the truncated file (empty,
    or with its 'moov' index missing or cut: unplayable) replaced the old output. Simulated here by cutting the file
    ffmpeg wrote as it would have stopped; now a DataFileError naming the file, the old MP4 kept, no temporary file
    left."""
    import importlib.util

    if importlib.util.find_spec("imageio_ffmpeg") is None:
        pytest.skip("MP4 output needs imageio-ffmpeg")
    import imageio.v3 as iio

    from stepterrain.closeup import save_animation
    from stepterrain.errors import DataFileError

    real = iio.imwrite

    def dying(uri, image, **kwargs):
        real(uri, image, **kwargs)
        with open(uri, "r+b") as fh:  # what a full disk left: nothing, or the media without the index written last
            fh.truncate(int(os.path.getsize(uri) * keep))

    old = tmp_path / "spin.mp4"
    old.write_bytes(b"the old animation")
    frames = [np.full((16, 24, 3), k * 40, np.uint8) for k in range(4)]
    monkeypatch.setattr(iio, "imwrite", dying)
    with pytest.raises(DataFileError, match=rf"^cannot write {re.escape(repr(str(old)))}: ffmpeg did not finish the "
                                            r"MP4 \([0-9,]+ bytes, (its|without its) .*box"):
        save_animation(frames, old, fps=4.0)
    assert [p.name for p in tmp_path.iterdir()] == ["spin.mp4"]
    assert old.read_bytes() == b"the old animation"
    monkeypatch.setattr(iio, "imwrite", real)
    video = iio.imread(save_animation(frames, old, fps=4.0), index=None, plugin="FFMPEG")
    assert video.shape[:3] == (4, 16, 24)


def test_closeup_layers_budget_counts_what_the_cull_holds_not_only_its_joined_inputs():
    """closeup_layers checked its geometry as the joined inputs alone (32 bytes a source point, 28 a face), while the
    cull holds its own pass (transformed points, factors, counts, kept faces) and its results (float64 vertices and
    originals, int64 faces twice, sources, uploads) beside them: a stepped close-up of 2.2 M points and 4.4 M faces
    was checked as 183 MiB and took 736 MiB, so a memory_budget the check allowed was overrun four times. Now 163
    bytes a point and 96 a face are counted (737.8 MiB there)."""
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(hills(65, 65, seed=2), spacing=(1.0, 1.0))
    cu = CloseUp(ROI.rectangle((32.0, 32.0), (80.0, 80.0)), offset=(0.0, 0.0, 30.0))  # every node and cell
    n_points, n_faces = 65 * 65, 2 * 64 * 64
    joined_only = 32 * n_points + 28 * n_faces  # what was checked: 364,576 bytes
    with pytest.raises(OutputTooLargeError, match=r"^close-up geometry would need 1\.4 MiB, over the memory budget "
                                                  r"of 0\.7 MiB"):
        closeup_layers(t, [cu], memory_budget=2 * joined_only, device="cpu")
    (layer,) = closeup_layers(t, [cu], memory_budget=163 * n_points + 96 * n_faces, device="cpu")
    assert len(layer.faces) == n_faces and len(layer.vertices) == n_points


def test_closeup_reaching_the_terrain_with_its_soft_edge_only_is_refused_not_drawn_as_nothing():
    from stepterrain.terrain import Terrain

    # a ROI whose centre lies just off the extent's edge (or whose core lies over nodata) reached the terrain with its
    # soft edge only: m < outline_level at every node under it, so no face was content and no fence stood on the
    # terrain; `stepterrain closeup --roi` wrote the overview alone (exit 0), the scene a barely lifted sliver
    t = terrain()  # extent x [1000, 1080], y [2000, 2064], spacing 2
    off_edge = ROI.circle((1000.0 - 0.95 * 12.0, 2030.0), 12.0)  # 0.6 inside: m <= 0.16 at the nodes of x = 1000
    heights = hills()
    y, x = np.mgrid[0:33, 0:41]
    heights[np.hypot(x * 2.0 - 40.0, y * 2.0 - 30.0) < 11.0] = np.nan  # the core (m >= 0.5 within 10.8) is nodata
    holed = Terrain.from_heights(heights, spacing=(2.0, 2.0), origin=(1000.0, 2000.0))
    in_hole = ROI.circle((1040.0, 2030.0), 12.0)
    for terrain_, roi in ((t, off_edge), (holed, in_hole)):
        (layer,) = closeup_layers(terrain_, [CloseUp(roi)], device="cpu")  # the kernels' layer is still returned
        assert 0 < layer.mask_factor.max() < 0.5
        for cu in (CloseUp(roi, offset=(0.0, 0.0, 60.0)), CloseUp(roi, anchor=AnchorStyle(outline_level=0.4))):
            with pytest.raises(InvalidInputError, match=r"^closeups\[0\]: ROI box .* reaches the terrain with its soft "
                                                        r"edge only: its mask is at most 0\.\d+ at every grid node"):
                closeup_scene(terrain_, [cu], device="cpu")
        if AVAILABLE:
            with pytest.raises(InvalidInputError, match="soft edge only"):
                render_closeups(terrain_, [CloseUp(roi)], window_size=SIZE, device="cpu")
        # with band the soft edge is drawn (stretched, with the anchor): not refused
        scene = closeup_scene(terrain_, [CloseUp(roi, anchor=AnchorStyle(band=True))], device="cpu")
        assert (scene.face_attributes["layer"] == 1).any()
    # a low outline level that the nodes reach draws the close-up
    scene = closeup_scene(t, [CloseUp(off_edge, anchor=AnchorStyle(outline_level=0.1))], device="cpu")
    assert (scene.face_attributes["layer"] == 2).any()


def test_mp4_of_odd_sized_frames_is_refused_not_stretched(tmp_path, capsys):
    # H.264 (4:2:0) codes 2 x 2 colour blocks: imageio resized 33 x 21 frames to 34 x 22 (each frame stretched, the
    # video not the size asked for, save_animation's "keep the frame size" broken) with only a printed warning; the
    # CLI rendered every frame of --size 321x241 first
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg (pip install 'stepterrain[video]')")
    import imageio.v3 as iio

    from stepterrain import cli
    from stepterrain.closeup import save_animation

    frames = [np.full((21, 33, 3), 40 * k, np.uint8) for k in range(3)]
    with pytest.raises(InvalidInputError, match=r"^frames of an MP4 must have an even width and height .*got 33x21$"):
        save_animation(frames, tmp_path / "odd.mp4", fps=5.0)
    assert not list(tmp_path.iterdir())
    gif = save_animation(frames, tmp_path / "odd.gif", fps=5.0)  # a GIF takes any size
    assert iio.imread(gif, index=None).shape[1:3] == (21, 33)
    even = save_animation([f[:20, :32] for f in frames], tmp_path / "even.mp4", fps=5.0)
    assert iio.imread(even, index=None, plugin="FFMPEG").shape[1:3] == (20, 32)
    dem = tmp_path / "dem.npy"
    np.save(dem, hills())
    argv = ["-q", "closeup", str(dem), "--size", "321x241", "-o", str(tmp_path / "p.png"), "--gif",
            str(tmp_path / "spin.mp4"), "--frames", "2"]
    assert cli.main(argv) == 2
    assert "--size of an MP4 must have an even width and height" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy", "even.mp4", "odd.gif"]


@pytest.mark.parametrize("make", [lambda: ROI.rectangle((0.0, 0.0), (10000.0, 100.0), edge_width=10.0),
                                  lambda: ROI.rectangle((0.0, 0.0), (100.0, 10000.0), edge_width=10.0),
                                  lambda: ROI.ellipse((0.0, 0.0), (5000.0, 50.0), edge_width=10.0),
                                  lambda: ROI.rounded_rectangle((0.0, 0.0), (1000.0, 100.0), edge_width=10.0)])
def test_an_elongated_shapes_mask_resolves_its_shorter_side(make):
    # the mask had square texels, `resolution` along the longer side: a 10000 x 100 m strip (a road, a river) got 3
    # texel rows (its rim and centre), so m was a tent across it, 0.2 at 10 m inside its long edge instead of 1, and
    # its outline (the fence) ran at half its width; 10:1 was off by 0.06 at that depth
    roi = make()
    w, h = roi.size
    across = np.linspace(-0.5, 0.5, 401) * min(w, h)  # across the shorter side, through the centre
    points = np.column_stack([across, np.zeros_like(across)]) if w < h else np.column_stack([np.zeros_like(across),
                                                                                              across])
    depth = min(w, h) / 2 - np.abs(across)  # distance to the long edge (the ends lie far away)
    x = np.clip(depth / 10.0, 0.0, 1.0)
    np.testing.assert_allclose(roi.factor(points), x * x * (3 - 2 * x), atol=0.02)
    (line,) = roi.outline(0.5)  # at m = 0.5: 5 m inside the long edges
    half = np.abs(line[:, 0] if w < h else line[:, 1]).max()
    assert half == pytest.approx(min(w, h) / 2 - 5.0, abs=0.5)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_spinning_billboard_keeps_its_size_and_place_over_the_spin(monkeypatch):
    """A spinning billboard's camera was fitted to the box of its turned content, pasted into the screen box of its
    turned fence top: both grow and shrink as the content turns, and the picture pulsed over a spin (its area fell
    by a quarter at 45°, to a fifth at 135°). It is now fitted from the content's cylinder about the spin axis,
    which turning keeps: one size, one centre."""
    coverages = []
    real = render.LayeredRenderer.render_billboard

    def spy(self, *args, **kwargs):
        out = real(self, *args, **kwargs)
        coverages.append(out[1].copy())
        return out

    monkeypatch.setattr(render.LayeredRenderer, "render_billboard", spy)
    cu = CloseUp(ROI.rectangle((1040.0, 2030.0), (32.0, 16.0)), scale=1.5, offset=(0.0, 0.0, 60.0), color="red",
                 view="billboard", scalars="slope", spin=(0.125, 1))
    animate_closeups(terrain(), [cu], frames=5, fps=1.0, window_size=(320, 240), device="cpu")  # 0°, 45°, ..., 180°
    assert len(coverages) == 5
    areas = np.array([c.sum() for c in coverages])
    centres = np.array([np.argwhere(c).mean(axis=0) for c in coverages])
    assert areas.min() > 200
    assert areas.max() <= 1.03 * areas.min(), areas
    assert np.abs(centres - centres[0]).max() <= 1.5, centres


def test_roi_box_collapsed_in_float32_is_refused_not_read_out_of_bounds():
    """A ROI narrower than float32 resolves at its local coordinates (1e-4 wide at x = 5000) has x0 == x1 on the
    device: a node on that x gave u = 0 / 0 = NaN, which passed the kernel's box test (NaN compares false), and
    int32(floor(NaN)) indexed the mask some 2^31 texels before it (a segfault on the CPU, an assertion in Warp's
    debug mode). Such a point now lies outside the box, as ROI.factor takes it, and the close-up that holds no
    terrain is refused by name. In a fresh interpreter, Warp in debug mode: the out-of-bounds read is caught."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import warp as wp
        wp.config.quiet = True
        wp.config.mode = "debug"
        import numpy as np
        import stepterrain as st
        from stepterrain.closeup import ROI, CloseUp, closeup_layers
        from stepterrain.errors import InvalidInputError

        t = st.terrain.as_terrain(np.zeros((101, 101), np.float32), spacing=(100.0, 100.0), origin=(0.0, 0.0))
        roi = ROI((5000.0, 5000.0), (1e-4, 2000.0), np.ones((3, 3), np.float32))
        assert np.float32(roi.box[0]) == np.float32(roi.box[1])  # the box collapses on the device
        assert roi.factor([[5000.0, 5000.0]])[0] == 1.0  # in float64 the node lies inside
        try:
            closeup_layers(t, [CloseUp(roi, scale=2.0, offset=(0.0, 0.0, 10.0))], device="cpu")
        except InvalidInputError as exc:
            assert "holds no terrain" in str(exc), exc
            print("refused")
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0 and result.stdout.strip() == "refused", (result.returncode, result.stderr[-2000:])


def test_closeup_sources_beyond_int32_are_refused(monkeypatch):
    """The cull indexes the joined source points and faces with int32 (faces cast by astype(np.int32), counts and
    offsets of n + 1 slots, launch dims): past 2^31 - 1 they wrapped into a wrong mesh or an out-of-range read,
    whatever memory_budget= allowed. The guard is checked at its boundary with the limit lowered (no 2^31 arrays)."""
    import stepterrain.closeup as closeup_module
    from stepterrain.terrain import as_terrain

    t = as_terrain(np.zeros((41, 41), np.float32))
    cu = CloseUp(ROI.circle((20.0, 20.0), 6.0, resolution=5), scale=2.0, offset=(0.0, 0.0, 10.0))
    source = closeup_module._grid_source(t, cu.roi.box)
    most = max(len(source.points), len(source.faces)) + 1  # the count slots: n + 1 of them
    assert cu.roi.mask.size < most - 1  # the geometry, not the mask, reaches it
    monkeypatch.setattr(closeup_module, "_MAX_INT32", most - 1, raising=False)
    with pytest.raises(OutputTooLargeError, match=r"int32.*whatever the memory budget"):
        closeup_layers(t, [cu], device="cpu")
    monkeypatch.setattr(closeup_module, "_MAX_INT32", most, raising=False)
    (layer,) = closeup_layers(t, [cu], device="cpu")
    assert len(layer.faces) > 0


def test_closeup_masks_beyond_int32_texels_are_refused(monkeypatch):
    """Every close-up's mask is packed into one array that the kernels index with int32 (each mask's offset, cast by
    astype(np.int32), plus row · cols + column): masks of 2^31 texels or more together (eight shape masks at their
    largest resolution, or one large painted mask) wrapped into reads outside the packed masks. Checked at the guard's
    boundary with the limit lowered (no 2^31-texel masks)."""
    import stepterrain.closeup as closeup_module
    from stepterrain.terrain import as_terrain

    t = as_terrain(np.zeros((21, 21), np.float32))
    items = [CloseUp(ROI.circle((x, 10.0), 2.0, resolution=150), scale=2.0, offset=(0.0, 0.0, 10.0))
             for x in (6.0, 14.0)]
    texels = sum(cu.roi.mask.size for cu in items)
    sources = [closeup_module._grid_source(t, cu.roi.box) for cu in items]
    assert sum(len(s.points) + len(s.faces) for s in sources) < texels  # the masks, not the geometry, reach it
    monkeypatch.setattr(closeup_module, "_MAX_INT32", texels - 1, raising=False)
    with pytest.raises(OutputTooLargeError, match=rf"{texels:,} texels.*int32"):
        closeup_layers(t, items, device="cpu")
    monkeypatch.setattr(closeup_module, "_MAX_INT32", texels, raising=False)
    assert all(len(layer.faces) for layer in closeup_layers(t, items, device="cpu"))


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_a_billboard_at_the_windows_edge_is_cut_by_it_not_squeezed_into_what_shows():
    """A billboard whose screen box reached past the window's edge was fitted whole into the part inside the window:
    squeezed (a quarter of its height lost) and shifted as it neared the edge, and gone once less than 8 pixels of it
    showed. It now keeps the size and place of its whole screen box, and the window's edge cuts it."""
    from stepterrain.terrain import grid_faces

    renderer = render.LayeredRenderer(window_size=(200, 160))
    try:
        ground = np.array([[0, 0, 0], [1000, 0, 0], [1000, 1000, 0], [0, 1000, 0]], float)
        renderer.set_mesh("overview", ground, np.array([[0, 1, 2], [0, 2, 3]]))
        renderer.set_view("top", np.array([[0, 0, 0], [1000, 1000, 10]]))
        xs, ys = np.meshgrid(np.linspace(0, 100, 11), np.linspace(0, 100, 11))
        content = np.column_stack([xs.ravel(), ys.ravel(), 50 + 10 * np.sin(xs.ravel() / 20)])
        top = np.array([[0, 0, 60], [100, 0, 60], [100, 100, 60], [0, 100, 60]], float)

        def covered(shift: float) -> tuple[np.ndarray, np.ndarray]:
            at = np.array([shift, 450.0, 0.0])
            _color, coverage, _depth = renderer.render_billboard(content + at, grid_faces(11, 11), None,
                                                                 (np.pi, np.radians(89.0)), top + at)
            return coverage, renderer.project(top + at)

        inside, _ = covered(450.0)
        rows = np.flatnonzero(inside.any(axis=1))
        for shift in (1080.0, 1100.0, 1110.0):  # its screen box about 190-206, 193-208, 194-210: the window ends at 200
            coverage, pixels = covered(shift)
            assert pixels[:, 0].max() > 200 > pixels[:, 0].min() + 4
            seen_rows = np.flatnonzero(coverage.any(axis=1))
            seen_cols = np.flatnonzero(coverage.any(axis=0))
            assert len(seen_rows) and abs(seen_rows[0] - rows[0]) <= 1 and abs(seen_rows[-1] - rows[-1]) <= 1, \
                (shift, seen_rows, rows)
            assert seen_cols[-1] == 199 and abs(seen_cols[0] - pixels[:, 0].min()) <= 1.5, (shift, seen_cols, pixels)
        at = np.array([1130.0, 450.0, 0.0])  # spinning: 2 of its picture's columns in the window, no longer left out
        _color, coverage, _depth = renderer.render_billboard(content + at, grid_faces(11, 11), None,
                                                             (np.pi, np.radians(89.0)), top + at, axis=(1180.0, 500.0))
        seen_rows = np.flatnonzero(coverage.any(axis=1))
        assert len(seen_rows) and abs(seen_rows[0] - rows[0]) <= 1 and abs(seen_rows[-1] - rows[-1]) <= 1, seen_rows
        assert np.flatnonzero(coverage.any(axis=0))[-1] == 199
    finally:
        renderer.close()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("camera", ["top", "oblique", (0.5, 0.6)])
def test_a_camera_framing_away_from_the_closeups_renders_the_overview_alone(camera):
    """A close-up whose screen box lay wholly right of or below the window (the camera's ``bounds`` framing another
    part of the terrain) got a read-back rect (col0 > col1 = width) that the renderer refused: "rect must lie in the
    window" instead of a frame. Outside the screen boxes of its content and fence every pixel is the bare overview's
    (none, where the close-up lies beyond the frame)."""
    t = terrain()
    box = [[1000.0, 2000.0, 0.0], [1016.0, 2012.0, 60.0]]
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        bare = render_closeups(t, [], window_size=SIZE, bounds=box, camera=camera, renderer=renderer, device="cpu")
        for centre in ((1068.0, 2052.0), (1068.0, 2010.0), (1010.0, 2052.0)):  # north and east of the frame
            cu = CloseUp(ROI.circle(centre, 8.0), scale=1.5, offset=(0.0, 0.0, 30.0), color="red")
            image = render_closeups(t, [cu], window_size=SIZE, bounds=box, camera=camera, renderer=renderer,
                                    device="cpu")
            layer = closeup_layers(t, [cu], device="cpu")[0]
            fence = anchor_strips(t, [cu], device="cpu")[0]
            footprint = np.zeros(bare.shape[:2], bool)
            for points in (layer.original @ layer.matrix[:3, :3].T + layer.matrix[:3, 3], fence.vertices):
                rect = renderer.screen_rect(points) or (0, 0, *SIZE)  # None: partly behind the eye
                footprint[rect[1]: rect[3], rect[0]: rect[2]] = True
            np.testing.assert_array_equal(image[~footprint], bare[~footprint])
    finally:
        renderer.close()


@pytest.mark.parametrize("n", [2, 3, 7])
def test_a_hard_rectangle_over_the_whole_extent_holds_all_of_the_terrain(n):
    """A hard-edged rectangle (edge_width=0) whose box is the terrain's extent: its mask was 0 on the box's rim where
    the boundary nodes sit, so a 2 x 2 grid (four corner nodes) was refused as holding no terrain and larger grids
    lost their rim. The hard rectangle is closed: every node is inside (m = 1) and the close-up is the whole terrain
    moved by M."""
    from stepterrain.terrain import Terrain

    rng = np.random.default_rng(n)
    t = Terrain.from_heights(rng.uniform(0, 50, (n, n)).astype(np.float32), spacing=(10.0, 10.0), origin=(5.0, 7.0))
    x0, x1, y0, y1 = t.extent
    roi = ROI.rectangle(((x0 + x1) / 2, (y0 + y1) / 2), (x1 - x0, y1 - y0), edge_width=0)
    layer = closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 100.0))], device="cpu")[0]
    mesh = t.mesh()
    assert len(layer.faces) == len(mesh.faces)
    assert np.all(layer.mask_factor == 1.0)
    np.testing.assert_allclose(layer.vertices, layer.original + [0.0, 0.0, 100.0], atol=1e-3)
    jj, ii = np.meshgrid(np.arange(n), np.arange(n))
    nodes = np.column_stack([x0 + 10.0 * jj.ravel(), y0 + 10.0 * ii.ravel()])
    assert np.all(roi.factor(nodes) == 1.0)


def test_a_soft_or_curved_hard_edge_keeps_its_mask():
    """The closed hard edge is the rectangle's: soft edges and a hard circle keep m = 0 on the box rim."""
    assert ROI.rectangle((0.0, 0.0), (10.0, 4.0)).mask[0].max() == 0.0
    circle = ROI.circle((0.0, 0.0), 5.0, edge_width=0).mask
    assert circle[0].max() == circle[-1].max() == circle[:, 0].max() == circle[:, -1].max() == 0.0
    hard = ROI.rectangle((0.0, 0.0), (10.0, 4.0), edge_width=0).mask
    assert hard.min() == 1.0


def test_a_roi_without_terrain_is_told_what_its_box_holds_not_a_guessed_cause():
    """"holds no terrain" blamed "a ROI smaller than the grid spacing, between the nodes, or over nodata" whatever
    the ROI: a box over many nodes with a height whose mask is 0 at all of them was told it was too small. The
    message now says what the box holds."""
    from stepterrain.closeup import closeup_layers
    from stepterrain.terrain import Terrain

    heights = hills()
    heights[5:25, 5:25] = np.nan
    t = Terrain.from_heights(heights, spacing=(10.0, 10.0), origin=(0.0, 0.0))
    ring = np.zeros((141, 141), np.float32)
    ring[1::20, 1::20] = 1.0  # m > 0 only off the nodes: the 140 x 140 box has 15 x 15 nodes with a height, m = 0
    painted = ROI.painted(ring, (330.0, 200.0), (140.0, 140.0))
    cases = [
        (painted, r"its mask is 0 at every grid node with a height \(the ROI's mask factor m is 0 at all 225 grid "
                  r"nodes with a height in its box\)"),
        (ROI.circle((150.0, 150.0), 40.0), r"\(the 81 grid nodes in its box are nodata\)"),
        (ROI.circle((305.0, 255.0), 4.0), r"\(its box holds no grid node \(it lies between the nodes, at the grid "
                                          r"spacing 10 x 10\)\)"),
    ]
    for roi, expected in cases:
        with pytest.raises(InvalidInputError, match=r"holds no terrain: .*" + expected) as info:
            closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0))], device="cpu")
        assert "smaller than" not in str(info.value)


def test_an_empty_stepped_level_is_refused_when_the_roi_is_built():
    """ROI.stepped_level took a level with no terrain (the sample DEM's level 0 at 200 m: isovalue 200 holds heights
    below 300 m, the DEM starts at 315 m) and made an all-zero ROI, refused only later as "holds no terrain". It is
    now refused at once, naming the level and the levels that hold terrain (checked against the stepped levels of
    the heights by NumPy)."""
    import stepterrain as st
    from stepterrain.stepped import isovalues, thresholds_of

    t = st.sample_dem()
    values = np.asarray(isovalues(t.height_range, interval=200.0), np.float32)
    finite = t.heights[np.isfinite(t.heights)]
    held = sorted(set(np.digitize(finite, thresholds_of(values)).tolist()))
    assert held == list(range(held[0], held[-1] + 1)) and held[0] > 0 and held[-1] < len(values) - 1
    for level in (0, len(values) - 1):
        with pytest.raises(InvalidInputError, match=rf"^level {level} \(isovalue {values[level]:g}\) holds no height "
                                                    rf"of the terrain, so the ROI would be empty; the levels that "
                                                    rf"hold terrain there are {held[0]}\.\.{held[-1]}$"):
            ROI.stepped_level(t, level, interval=200.0)
    for level in held:
        assert ROI.stepped_level(t, level, interval=200.0).mask.max() == 1.0
    x0, x1, y0, y1 = t.extent
    region = (x0, x0 + 2000.0, y0, y0 + 2000.0)  # a corner: some of the levels only
    in_region = []
    for level in held:
        try:
            assert ROI.stepped_level(t, level, interval=200.0, region=region).mask.max() == 1.0
            in_region.append(level)
        except InvalidInputError as exc:
            assert re.match(rf"level {level} .* holds no height of the terrain in region x \[{x0:g}, .*\], so the ROI "
                            rf"would be empty; the levels that hold terrain there are ", str(exc)), exc
    assert in_region and in_region != held


def test_each_anchor_strip_has_the_rungs_its_closeup_asked_for():
    """anchor_strips gave every close-up of a call the largest anchor.rungs among them (one launch), so a close-up
    asking for 2 rungs drawn beside one asking for 16 got 16 (AnchorStrip.rungs said 16). Each strip now has its own,
    still in one launch, and equals the strip of its close-up alone bit for bit: P·(rungs + 1) vertices on the
    segments from V_O to M·V_O, 2·rungs faces per outline segment."""
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(hills(), spacing=(2.0, 2.0), origin=(1000.0, 2000.0))
    cus = [CloseUp(ROI.circle((1020.0, 2020.0), 8.0), offset=(0.0, 0.0, 40.0), anchor=AnchorStyle(rungs=2)),
           CloseUp(ROI.circle((1060.0, 2040.0), 10.0), offset=(5.0, 0.0, 60.0), anchor=AnchorStyle(rungs=16)),
           CloseUp(ROI.rectangle((1040.0, 2015.0), (12.0, 8.0)), offset=(0.0, 5.0, 30.0), anchor=AnchorStyle(rungs=5))]
    together = anchor_strips(t, cus, device="cpu")
    for cu, strip in zip(cus, together, strict=True):
        rungs = cu.anchor.rungs
        assert strip.rungs == rungs
        (alone,) = anchor_strips(t, [cu], device="cpu")
        for name in ("vertices", "faces", "distance", "opacity"):
            np.testing.assert_array_equal(getattr(strip, name), getattr(alone, name), err_msg=name)
        points = len(strip.vertices) // (rungs + 1)
        assert points * (rungs + 1) == len(strip.vertices) and points >= 3
        rung = strip.vertices.reshape(points, rungs + 1, 3)
        steps = np.diff(rung, axis=1)  # evenly spaced along each rung
        np.testing.assert_allclose(steps, np.repeat(steps[:, :1], rungs, axis=1), atol=1e-3)
        assert len(strip.faces) % (2 * rungs) == 0 and strip.faces.max() < len(strip.vertices)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_a_closeup_moved_absurdly_far_is_refused_not_rendered_blank():
    """A close-up 1e7 m off an 80 m terrain: the camera fitted to the overview and close-ups together framed a box
    1e7 m wide (wide enough for the fitted camera's check), where the overview and the close-up both came out under
    a pixel, and the image was blank (every pixel the background) without a word. It is refused as the fitted
    camera's too-thin box is; a near close-up and the same far one in a caller's own frame still render."""
    t = terrain()
    far = one(offset=(1e7, 0.0, 60.0))
    with pytest.raises(InvalidInputError, match=r"^the camera fitted to the overview and its close-ups would show the "
                                                r"overview \(.* px\) and closeups\[0\]'s content \(.* px\) under a "
                                                r"pixel: .*closeups\[0\] \(offset \(10000000.0, 0.0, 60.0\)\)"):
        render_closeups(t, [far], window_size=SIZE, device="cpu")
    with pytest.raises(InvalidInputError, match=r"closeups\[1\] \(offset \(10000000.0, 0.0, 60.0\)\) is drawn"):
        render_closeups(t, [one(), far], window_size=SIZE, device="cpu")
    with pytest.raises(InvalidInputError, match=r"would show the overview .* under a pixel"):  # its own fitted box
        animate_closeups(t, [far], frames=2, window_size=SIZE, device="cpu")
    assert len(animate_closeups(t, [one()], frames=2, window_size=SIZE, device="cpu")) == 2
    near = render_closeups(t, [one()], window_size=SIZE, device="cpu")
    assert red_pixels(near).sum() > 100
    framed = render_closeups(t, [far], window_size=SIZE, device="cpu", bounds=[(1000, 2000, 0), (1080, 2064, 160)])
    assert (framed != 255).any(axis=2).sum() > 1000  # the overview, drawn in the caller's frame


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("dz", [1e7, -1e7])
def test_a_closeup_lifted_absurdly_high_is_named_as_the_closeup_not_as_the_z_scale(dz):
    """A close-up lifted 1e7 m over an 80 m terrain: render_closeups refused it as the renderer's too-thin box ("the
    mesh would render 0.0019 x 1.1e+02 pixels ... a z_scale near 8e-06 makes it as tall as it is wide"), naming
    neither the close-up nor its offset and offering a z_scale that flattens the terrain, while animate_closeups of
    the same close-up named it (its framing check came before the renderer's; in render_closeups it came after)."""
    t = terrain()
    high = one(offset=(0.0, 0.0, dz))
    named = (r"^the camera fitted to the overview and its close-ups would show the overview \(.* px\) .*under a "
             rf"pixel: .*closeups\[0\] \(offset \(0.0, 0.0, {dz}\)\)")
    with pytest.raises(InvalidInputError, match=named):
        render_closeups(t, [high], window_size=SIZE, device="cpu")
    with pytest.raises(InvalidInputError, match=named):
        animate_closeups(t, [high], frames=1, window_size=SIZE, device="cpu")
    with pytest.raises(InvalidInputError, match=rf"closeups\[1\] \(offset \(0.0, 0.0, {dz}\)\) is drawn"):
        render_closeups(t, [one(), high], window_size=SIZE, device="cpu")


@pytest.mark.parametrize("renderer", ["yes", 5, object()])
def test_render_closeups_names_a_renderer_that_is_not_a_layered_renderer(renderer):
    """A renderer that is not a LayeredRenderer (a pyvista Plotter, a flag) raised AttributeError "'Plotter' object has
    no attribute 'size'" after the close-ups were transformed and culled."""
    t = terrain()
    cu = CloseUp(ROI.circle((1040.0, 2030.0), 10.0), offset=(0.0, 0.0, 30.0))
    with pytest.raises(InvalidInputError, match=r"renderer must be a stepterrain\.render\.LayeredRenderer \(or None\); "
                                                r"got "):
        render_closeups(t, [cu], window_size=SIZE, renderer=renderer, device="cpu")


def test_the_closeup_memos_let_go_of_rois_no_longer_used():
    """The identity memos of the close-ups (the ROI uploads, a process-wide memo; per terrain the culls and the anchor
    outlines) held their ROIs strongly, up to 64 entries: a loop over new ROIs on one DEM (a height band swept over the
    heights) kept every ROI's mask, its upload, its cull and its outline alive, ~12 MB an iteration on the embedded
    DEM (800 MB after 64). An entry now goes once one of its ROIs is gone."""
    import gc
    import weakref

    from stepterrain import closeup

    t = terrain()
    xmin, xmax, ymin, ymax = t.extent
    uploads = len(closeup._ROI_UPLOADS)
    dead = []
    for i in range(5):
        roi = ROI.circle((xmin + 20.0 + 5 * i, (ymin + ymax) / 2), 12.0)
        dead.append(weakref.ref(roi))
        cu = CloseUp(roi, offset=(0.0, 0.0, 30.0))
        closeup_layers(t, [cu], device="cpu")
        anchor_strips(t, [cu], device="cpu")
        del roi, cu
        gc.collect()
    assert all(ref() is None for ref in dead), "a ROI no longer used is kept alive by a close-up memo"
    # the last ROI's entries go at the next entry made; none of the four before it stays
    assert len(t.cached(("closeup", "cull"), dict)) <= 1
    assert len(t.cached(("closeup", "anchor-static"), dict)) <= 1
    assert len(closeup._ROI_UPLOADS) <= uploads + 1


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_render_closeups_lets_go_of_closeups_no_longer_used(monkeypatch):
    """render_closeups kept the geometry of the last frames per terrain (up to 8 sets of close-ups) with the close-ups
    themselves, held strongly: rendering new close-ups in a loop (a ROI dragged over the DEM) kept 8 frames' close-ups,
    ROI masks, uploads and culls alive (a 2049-texel mask on the embedded DEM: 0.7 to 1.2 GB after 24 frames)."""
    import gc
    import weakref

    layers_of = closeup_layers
    t = terrain()
    xmin, xmax, ymin, ymax = t.extent
    dead = []
    for i in range(3):
        cu = CloseUp(ROI.circle((xmin + 25.0 + 5 * i, (ymin + ymax) / 2), 12.0), offset=(0.0, 0.0, 30.0))
        dead += [weakref.ref(cu), weakref.ref(cu.roi)]
        render_closeups(t, [cu], window_size=SIZE, device="cpu")
        del cu
        gc.collect()
    assert all(ref() is None for ref in dead), "a close-up no longer used is kept alive by render_closeups' memo"
    # the same close-up again still finds its geometry: not transformed and culled anew
    from stepterrain import closeup

    cu = CloseUp(ROI.circle((xmin + 25.0, (ymin + ymax) / 2), 12.0), offset=(0.0, 0.0, 30.0))
    first = render_closeups(t, [cu], window_size=SIZE, device="cpu")
    calls = []
    monkeypatch.setattr(closeup, "closeup_layers", lambda *a, **k: calls.append(1) or layers_of(*a, **k))
    again = render_closeups(t, [cu], window_size=SIZE, device="cpu")
    assert calls == []
    np.testing.assert_array_equal(first, again)


@pytest.mark.parametrize("name", ["terrain", "viridis"])
def test_a_reversed_colormap_is_its_maps_land_part_reversed(name):
    """LAND_START knew only 'terrain': 'terrain_r' was sampled whole, its sea-blue last quarter on the highest
    ground. A reversed map is now the land part of its map, reversed, in stepped's level colours and in the
    close-ups' per-vertex colours."""
    import matplotlib

    from stepterrain.closeup import _colors_for
    from stepterrain.stepped import colormap_samples

    # matplotlib looks a map up in its 256-entry table: the reversed map's samples fall at most one entry apart
    table_step = np.abs(np.diff(matplotlib.colormaps[name](np.linspace(0, 1, 257))[:, :3], axis=0)).max()
    levels = colormap_samples(name, 7)
    assert np.abs(colormap_samples(f"{name}_r", 7) - levels[::-1]).max() <= table_step + 1e-9
    x = np.linspace(0.0, 1.0, 101, dtype=np.float32)
    reversed_rgb = _colors_for(x, f"{name}_r", 0.0, 1.0).astype(int)
    # an independent reference: the forward map's land part at 1 - x
    lo = 0.25 if name == "terrain" else 0.0
    reference = np.round(matplotlib.colormaps[name](lo + (1 - lo) * (1.0 - x.astype(np.float64)))[:, :3] * 255)
    assert np.abs(reversed_rgb - reference).max() <= table_step * 255 + 1
    top = reversed_rgb[-1]
    assert not (top[2] > top[0] + 40 and top[2] > top[1]), f"the highest ground is sea blue: {top}"


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_render_closeups_memo_lets_go_of_frames_whose_texture_is_gone():
    """render_closeups' frame memo held the texture weakly but apart from the close-ups, where the sweep of gone
    entries did not look: a new texture image each frame (a video draped) over the same close-up kept an entry per
    frame, its layers, strips and boards, up to 8. An entry now goes once its texture is gone, as once a close-up is."""
    import gc

    t = terrain()
    xmin, xmax, ymin, ymax = t.extent
    cu = CloseUp(ROI.circle((xmin + 25.0, (ymin + ymax) / 2), 12.0), offset=(0.0, 0.0, 30.0))
    memo = t.cached(("closeup", "frame"), dict)
    for i in range(4):
        image = np.full((4, 4, 3), 40 * i, np.uint8)  # a new frame of a video, the previous one dropped
        render_closeups(t, [cu], window_size=SIZE, texture=image, device="cpu")
        del image
        gc.collect()
    assert len(memo) <= 1, f"{len(memo)} frames kept for textures no longer used"


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize(("option", "value", "message"), [
    ("merge_passes", "no", r"merge_passes must be True or False; got 'no'"),
    ("reuse_overview", "yes", r"reuse_overview must be True or False; got 'yes'"),
    ("reuse_closeups", 2, r"reuse_closeups must be True or False; got 2"),
    ("timings", [], r"timings must be a dict .*; got list"),
])
def test_render_closeups_names_a_bad_flag_or_timings(option, value, message, monkeypatch):
    """merge_passes="no" (true to Python) merged the passes, reuse_closeups=2 reused: options read as their opposite
    without a word; timings=[] raised list's TypeError after every pass was rendered. Refused before any work."""
    import stepterrain.closeup as closeup_module

    def no_work(*args, **kwargs):
        raise AssertionError("the close-ups were transformed before the options were checked")

    monkeypatch.setattr(closeup_module, "closeup_layers", no_work)
    with pytest.raises(InvalidInputError, match=message):
        render_closeups(terrain(), [one()], window_size=SIZE, device="cpu", **{option: value})


def test_animate_closeups_names_an_unknown_option_before_any_work(monkeypatch):
    """An option render_closeups does not take (a typo: ``zscale``) raised its TypeError at the first frame, after
    the swept box was fitted (every distinct turn's close-ups transformed and culled) and the renderer made."""
    import stepterrain.closeup as closeup_module

    def no_work(*args, **kwargs):
        raise AssertionError("the close-ups were transformed before the options were checked")

    monkeypatch.setattr(closeup_module, "closeup_layers", no_work)
    with pytest.raises(InvalidInputError, match=r"animate_closeups passes options to render_closeups, which takes no "
                                                r"'zscale'; got zscale=2"):
        animate_closeups(terrain(), [one()], frames=2, window_size=SIZE, device="cpu", zscale=2)


def _small_closeup_dem(folder) -> str:
    """A 30 x 40 hill as .npy (10 m nodes): a close-up's render at 96x64 in a fraction of a second."""
    i, j = np.mgrid[0:30, 0:40].astype(np.float32)
    path = folder / "hill.npy"
    np.save(path, (300.0 * np.exp(-((i - 15.0) ** 2 + (j - 20.0) ** 2) / 120.0) + 2.0 * j).astype(np.float32))
    return str(path)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_closeup_png_without_output_writes_the_render_alone(tmp_path, capsys):
    """A user who wants only the picture: ``closeup --roi ... --png view.png`` without ``-o`` was refused (-o was
    required), as ``steps`` and ``globe`` take --png alone. It renders and writes the PNG alone, the same picture
    as ``-o view.png`` makes."""
    from PIL import Image

    from stepterrain import cli

    dem = _small_closeup_dem(tmp_path)
    args = ["closeup", dem, "--spacing", "10", "--roi-relative", "0.5,0.5,0.2", "--size", "96x64", "--device", "cpu"]
    alone = tmp_path / "alone"
    alone.mkdir()
    assert cli.main([*args, "--png", str(alone / "view.png")]) == 0, capsys.readouterr().err
    assert f"writing {alone / 'view.png'}" in capsys.readouterr().err
    assert [p.name for p in alone.iterdir()] == ["view.png"]
    with Image.open(alone / "view.png") as image:
        assert image.format == "PNG" and image.size == (96, 64)
        pixels = np.asarray(image.convert("RGB"))
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 10  # the terrain and its close-up, not one flat colour
    assert cli.main(["-q", *args, "-o", str(tmp_path / "o.png")]) == 0, capsys.readouterr().err
    with Image.open(tmp_path / "o.png") as image:
        np.testing.assert_array_equal(np.asarray(image.convert("RGB")), pixels)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_closeup_gif_without_output_writes_the_animation_alone(tmp_path, capsys):
    """``closeup --gif spin.gif`` without ``-o`` was refused (-o was required, so an animation came with a still or a
    scene mesh nobody asked for). It writes the animation alone: its frames spin (they differ), no other file."""
    from PIL import Image, ImageSequence

    from stepterrain import cli

    dem = _small_closeup_dem(tmp_path)
    gif = tmp_path / "spin.gif"
    code = cli.main(["-q", "closeup", dem, "--spacing", "10", "--roi-relative", "0.5,0.5,0.2", "--size", "64x64",
                     "--gif", str(gif), "--frames", "3", "--fps", "4", "--spin", "1", "--device", "cpu"])
    assert code == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hill.npy", "spin.gif"]
    with Image.open(gif) as image:
        frames = [np.asarray(frame.convert("RGB")) for frame in ImageSequence.Iterator(image)]
    assert len(frames) == 3 and frames[0].shape == (64, 64, 3)
    assert len(np.unique(frames[0].reshape(-1, 3), axis=0)) > 10
    assert not np.array_equal(frames[0], frames[1])  # a quarter turn a frame: the close-up has turned


def test_cli_closeup_without_any_output_is_a_usage_error(tmp_path, capsys):
    """-o/--output is optional with --png or --gif; with none of them the run has nothing to write: exit 2 with
    one line naming the three, before any work (a DEM that does not exist is not looked at), nothing written."""
    from stepterrain import cli

    code = cli.main(["closeup", str(tmp_path / "missing.npy"), "--roi-relative", "0.5,0.5,0.2"])
    assert code == 2
    assert capsys.readouterr().err == (
        "stepterrain closeup: error: give -o/--output OUT (the render .png, or the scene as a mesh), --png OUT.png "
        "(a render) or --gif OUT.gif|OUT.mp4 (a spinning animation), or several of them; got none\n")
    assert list(tmp_path.iterdir()) == []


def test_layers_and_anchor_strips_compare_and_hash_by_identity_as_rois_do():
    """``CloseUpLayer`` and ``AnchorStrip`` were frozen dataclasses with the generated ``__eq__`` and ``__hash__`` over
    their fields: ``layer == other`` and ``layer in [a, b]`` raised numpy's "truth value ... is ambiguous" from
    comparing their arrays, and ``hash(layer)`` "unhashable type: 'numpy.ndarray'". They compare by identity now, as
    :class:`ROI` and :class:`CloseUp` do (and the private ``texture_lod._InView`` and ``batch._Source``)."""
    from stepterrain.batch import _Source
    from stepterrain.texture_lod import _InView

    t = terrain()
    cus = [CloseUp(ROI.circle((1030.0, 2030.0), 12.0), scale=2.0, offset=(0.0, 0.0, 60.0)),
           CloseUp(ROI.circle((1050.0, 2040.0), 8.0), scale=1.5, offset=(0.0, 0.0, 40.0))]
    for a, b in (closeup_layers(t, cus, device="cpu"), anchor_strips(t, cus, device="cpu")):
        again = type(a)(**{name: getattr(a, name) for name in a.__dataclass_fields__})  # same field values
        assert a == a and a != b and not (a == b) and a != again
        assert b in [a, b] and again not in [a, b]
        assert len({a, b, a}) == 2 and {a: 1, b: 2}[b] == 2
    source = _Source(np.zeros((2, 2), np.float32), (1.0, 1.0), (0.0, 0.0), None, "x")
    view = _InView(1.0, np.zeros(2), np.zeros(2), np.eye(3), np.zeros(3))
    for item in (source, view):
        copy = type(item)(**{name: getattr(item, name) for name in item.__dataclass_fields__})
        assert item == item and item != copy and item in [copy, item] and len({item, copy}) == 2


@pytest.mark.parametrize("point", [(0.0, 0.0, 0.0), "centre"])
def test_bounds_of_a_single_point_are_refused_by_name_without_a_numpy_warning(point):
    """render_closeups(bounds=<a box of no size>) fitted its camera to the point: far from the overview's origin (the
    point (0, 0, 0) under a UTM DEM) the eye fell on the point itself, numpy warned "invalid value encountered in
    divide", and the error then said "the mesh would render 0 x 0 pixels", naming no ``bounds``. It is refused up
    front by name, with the point got; render_mesh's ``bounds`` and LayeredRenderer.set_view's ``box`` alike, and
    render_mesh names ``bounds`` too thin to see. An explicit camera position (it takes only the box's centre) still
    accepts a point."""
    import stepterrain as st

    t = st.sample_dem()
    xmin, xmax, ymin, ymax = t.extent
    centre = ((xmin + xmax) / 2, (ymin + ymax) / 2, 500.0)
    box = [centre, centre] if point == "centre" else [point, point]
    cu = CloseUp(ROI.circle(centre[:2], (xmax - xmin) / 10), scale=2.0, offset=(0.0, 0.0, 60.0))
    named = r"^bounds must be a box of some size for a fitted camera: .*; got the single point \("
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for camera in ("oblique", "top", (0.5, 0.6)):
            with pytest.raises(InvalidInputError, match=named):
                render_closeups(t, [cu], bounds=box, camera=camera, window_size=SIZE, device="cpu")
            with pytest.raises(InvalidInputError, match=named):
                render.render_mesh(t.mesh(), bounds=box, camera=camera, window_size=SIZE)


@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_thin_bounds_are_named_and_a_point_still_centres_an_explicit_camera():
    t = terrain()
    column = [(1030.0, 2030.0, 0.0), (1030.0, 2030.0, 100.0)]  # no extent across: under a pixel wide
    with pytest.raises(InvalidInputError, match=r"^bounds would render .* pixels: it spans 0 x 0 across and 100 tall"):
        render.render_mesh(t.mesh(), bounds=column, window_size=SIZE)
    point = [(1040.0, 2032.0, 50.0)] * 2
    position = [(0.0, -150.0, 120.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]  # relative to the point
    image = render_closeups(t, [one()], bounds=point, camera=position, window_size=SIZE, device="cpu")
    assert (image != 255).any(axis=2).sum() > 100
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        mesh = t.mesh()
        renderer.set_mesh("overview", mesh.vertices, mesh.faces)
        far = [(-5e6, -5e6, 0.0)] * 2  # far from the overview: the eye fell on it (numpy's divide warning)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(InvalidInputError, match=r"^box must be a box of some size .* single point \(-5000000"):
                renderer.set_view("oblique", far)
        renderer.set_view(position, point)  # an explicit camera: the point is its centre
    finally:
        renderer.close()


def test_a_stepped_closeup_over_the_budget_names_what_a_closeup_can_change():
    """A stepped close-up (MPFR) whose window's stepped mesh went over the memory budget was refused with stepped()'s
    advice, "or coarsen the isovalues", which no close-up option does (its isovalues are the whole terrain's at its
    ``stepped`` interval); it names the close-up's interval, its ROI and the terrain now. closeup_layers'
    ``memory_budget`` now reaches that stepped mesh too: it was checked against the global budget alone (a larger
    memory_budget= was refused by the smaller global one, and a smaller one let it through)."""
    from stepterrain import set_memory_budget
    from stepterrain.terrain import Terrain

    cu = CloseUp(ROI.circle((1040.0, 2032.0), 20.0), stepped=0.05)
    with pytest.raises(OutputTooLargeError, match=r"^the stepped mesh .* over the memory budget of 100,000 bytes; "
                       r"step the close-up at a larger interval \(CloseUp.stepped\) or give it a smaller ROI, or crop "
                       r"or coarsen the terrain \(Terrain.crop, Terrain.coarsen\), or raise the budget") as caught:
        closeup_layers(terrain(), [cu], memory_budget=100_000, device="cpu")
    assert "isovalues" not in str(caught.value)
    previous = set_memory_budget(100_000)
    try:  # the call's own budget, larger than the global one, is the one that counts
        (layer,) = closeup_layers(Terrain.from_heights(hills(), spacing=(2.0, 2.0), origin=(1000.0, 2000.0)), [cu],
                                  memory_budget=1 << 30, device="cpu")
    finally:
        set_memory_budget(previous)
    assert len(layer.faces) > 10_000 and (layer.source_faces == -1).all()


def test_a_stepped_closeup_past_int32_names_what_a_closeup_can_change(monkeypatch):
    """The stepped close-up's own advice reaches every refusal of its window's stepped mesh, not only the budget's:
    a grid past the int32 vertex slots one call indexes was advised "coarsen the isovalues, or step it in tiles
    (stepterrain.batch)", neither a close-up option (the advice is now given to stepped(), not patched into its
    message text)."""
    import stepterrain.stepped as stepped_module

    monkeypatch.setattr(stepped_module, "_MAX_INT32", 100)  # any window's 4 slots a node are past it
    cu = CloseUp(ROI.circle((1040.0, 2032.0), 20.0), stepped=1.0)
    with pytest.raises(OutputTooLargeError, match=r"int32 vertex slots .* one call can index; step the close-up at a "
                       r"larger interval \(CloseUp.stepped\) or give it a smaller ROI, or crop or coarsen the terrain "
                       r"\(Terrain.crop, Terrain.coarsen\)$") as caught:
        closeup_layers(terrain(), [cu], device="cpu")
    assert "isovalues" not in str(caught.value) and "tiles" not in str(caught.value)


@pytest.mark.parametrize("camera", [[(0.0, 0.0, 5.0), (0.0, 0.0)], [(0.0, -150.0, 120.0), (0.0, 0.0, 0.0), (0.0, 1.0)]])
def test_a_ragged_camera_beside_bounds_is_refused_by_name_not_by_numpy(camera):
    """The check that ``bounds`` is no single point under a fitted camera asked ``np.shape(camera)`` before the camera
    was checked: a ragged camera (an eye, focal point or view up of the wrong length) raised numpy's ValueError
    ("inhomogeneous shape") from render_mesh and render_closeups instead of the InvalidInputError naming ``camera``
    they raise without ``bounds``."""
    t = terrain()
    box = [(1020.0, 2020.0, 0.0), (1060.0, 2040.0, 100.0)]
    with pytest.raises(InvalidInputError, match=r"^camera must be "):
        render.render_mesh(t.mesh(), bounds=box, camera=camera, window_size=SIZE)
    with pytest.raises(InvalidInputError, match=r"^camera must be "):
        render_closeups(t, [one()], bounds=box, camera=camera, window_size=SIZE, device="cpu")


@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_a_ragged_camera_is_refused_by_name_by_set_view():
    """LayeredRenderer.set_view asked ``np.shape(camera)`` (is it fitted?) before checking the camera: numpy's
    ValueError for a ragged one, not the InvalidInputError naming ``camera``."""
    t = terrain()
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        mesh = t.mesh()
        renderer.set_mesh("overview", mesh.vertices, mesh.faces)
        with pytest.raises(InvalidInputError, match=r"^camera must be "):
            renderer.set_view([(0.0, 0.0, 5.0), (0.0, 0.0)], [(1020.0, 2020.0, 0.0), (1060.0, 2040.0, 100.0)])
    finally:
        renderer.close()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("kwargs", [{"anchor": AnchorStyle(band=True)}, {"view": "billboard"}])
def test_an_animation_frames_the_anchors_as_render_closeups_does(kwargs):
    """render_closeups fits its camera to the overview, the close-ups and their anchors; animate_closeups fitted its
    box to the overview and the close-ups alone. A band's or a billboard's close-up is bounded by its blended
    vertices, below its anchor's top (M·V_O of the outline): the fence stood past the animation's box, and the
    animation of a close-up that does not spin was framed otherwise than its render_closeups picture."""
    t = terrain()
    cu = one(scale=3.0, **kwargs)
    layer, strip = closeup_layers(t, [cu], device="cpu")[0], anchor_strips(t, [cu], device="cpu")[0]
    assert strip.vertices[:, 0].max() > layer.vertices[:, 0].max()  # the fence reaches past the blended close-up
    frame = animate_closeups(t, [cu], frames=1, window_size=SIZE, device="cpu")[0]
    np.testing.assert_array_equal(frame, render_closeups(t, [cu], window_size=SIZE, device="cpu"))


def test_a_box_built_from_the_extent_holds_its_rim_rows_to_rounding():
    """A ROI's box is ``center ± size / 2``, rounded: a hard rectangle built from a terrain's extent (its centre and
    size), or a height band over a whole terrain (built the same way), could lie one ulp inside the extent. The nodes
    of the rim row at the local origin then had m = 0 (float32 keeps the 1e-10 m there): left on the terrain under the
    lifted close-up, its faces stretched up to it; a 2 x 2 grid lost half its nodes. Here the box lies 1.2e-10 m
    inside the extent's west side (a lidar-like 0.1 m spacing at UTM coordinates)."""
    from stepterrain.terrain import Terrain

    h = np.add.outer(np.arange(45.0), np.arange(30.0)).astype(np.float32)
    t = Terrain.from_heights(h, spacing=(0.1, -0.1), origin=(678916.7866872508, 8847681.58466728))
    x0, x1, y0, y1 = t.extent
    hard = ROI.rectangle(((x0 + x1) / 2, (y0 + y1) / 2), (x1 - x0, y1 - y0), edge_width=0)
    band = ROI.height_band(t, -1.0, 1000.0)
    for roi in (hard, band):
        assert roi.box[0] > x0  # one ulp inside the extent, as rounded
        (layer,) = closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0))], device="cpu")
        assert len(layer.faces) == 2 * 44 * 29 and (layer.mask_factor == 1).all()
        np.testing.assert_array_equal(layer.vertices[:, 2], layer.original[:, 2] + 50.0)
        west = np.column_stack([np.full(45, x0), y1 - 0.1 * np.arange(45)])
        assert (roi.factor(west) == 1).all()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_an_animation_frames_the_overview_as_render_closeups_does():
    """render_closeups frames the overview by its mesh; animate_closeups by the terrain's extent and height range,
    which hold a DEM's nodata rim (a collar of NaN, common in clipped DEMs): the animation of a close-up that does
    not spin was framed wider than its render_closeups picture."""
    from stepterrain.terrain import Terrain

    heights = hills().astype(np.float32)
    heights[:, :8] = np.nan
    heights[:5] = np.nan
    t = Terrain.from_heights(heights, spacing=(2.0, 2.0), origin=(1000.0, 2000.0))
    assert t.mesh().bounds[0, 0] > t.extent[0]  # the mesh starts past the nodata columns
    frame = animate_closeups(t, [one()], frames=1, window_size=SIZE, device="cpu")[0]
    np.testing.assert_array_equal(frame, render_closeups(t, [one()], window_size=SIZE, device="cpu"))


def test_an_anchor_table_of_t_and_opacity_pairs_is_refused_not_flattened():
    """An anchor's opacity table is K opacities at evenly spaced t; a table of (t, opacity) control points, (3, 2),
    was flattened into six opacities (0, 0.85, 0.5, 0, 1, 0.85): an anchor that flickers along its rungs, drawn
    without a word. A single row or column is still a table."""
    pairs = [[0.0, 0.85], [0.5, 0.0], [1.0, 0.85]]
    with pytest.raises(InvalidInputError, match=r"^anchor transparency table must be \(K,\) .* shape \(3, 2\)"):
        AnchorStyle(pairs)
    assert AnchorStyle([[0.85, 0.0]]).table.tolist() == AnchorStyle([0.85, 0.0]).table.tolist()


def test_roi_factor_refuses_rows_of_x_and_of_y():
    """ROI.factor takes (N, 2) points; np.array([xs, ys]), (2, N), was read as N pairs (x0, x1), (x2, x3), ...: the mask
    at points nobody asked for, without a word."""
    roi = ROI.circle((0.0, 0.0), 10.0)
    xs, ys = np.array([0.0, 9.0, 20.0]), np.array([0.0, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match=r"^ROI factor points must be \(N, 2\) .* shape \(2, 3\)"):
        roi.factor(np.array([xs, ys]))
    assert roi.factor(np.column_stack([xs, ys]))[[0, 2]].tolist() == [1.0, 0.0]


@pytest.mark.parametrize(("shape", "spacing", "origin"),
                         [((28, 15), 0.10066220055414109, (470094.29585065856, 5911159.964824296)),
                          ((7, 25), 0.06243220249655396, (366654.8085450701, 8721352.384978961))])
def test_the_kernel_holds_the_far_rim_rows_to_float32_rounding(shape, spacing, origin):
    """The kernel's margin was the world box's float64 rounding (1e-9 m), but it compares float32 local coordinates:
    the far rim's node (j·dx) and box side (x1 − ox) round to float32 apart, one float32 ulp (2e-7 m here), and the
    whole south rim row of a box built from the extent had m = 0 (left on the terrain under the lifted close-up),
    though ROI.factor gives it 1."""
    from stepterrain.terrain import Terrain

    h = (np.add.outer(np.arange(float(shape[0])), np.arange(float(shape[1]))) * 0.37).astype(np.float32)
    t = Terrain.from_heights(h, spacing=(spacing, -spacing), origin=origin)
    x0, x1, y0, y1 = t.extent
    hard = ROI.rectangle(((x0 + x1) / 2, (y0 + y1) / 2), (x1 - x0, y1 - y0), edge_width=0)
    for roi in (hard, ROI.height_band(t, -1.0, 1000.0)):
        assert (roi.factor(t.mesh().vertices[:, :2]) == 1).all()  # NumPy's float64 factor: every node on the box
        (layer,) = closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0))], device="cpu")
        assert len(layer.mask_factor) == h.size and (layer.mask_factor == 1).all()
        np.testing.assert_allclose(layer.vertices[:, 2], layer.original[:, 2] + 50.0, atol=1e-4)  # float32
        # a stepped close-up's rim vertices too (their float32 positions lay as far outside: 1.6 % of them lost)
        (layer,) = closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0), stepped=1.0)], device="cpu")
        assert len(layer.faces) > 0 and (layer.mask_factor == 1).all()


@pytest.mark.parametrize("east", [True, False])
def test_the_kernels_rim_margin_is_each_sides_own_not_the_farthest_sides(east):
    """The kernel's rounding margin about a ROI box was two float32 ulps of its farthest side, on every side: a hard
    rectangle reaching 2e7 m west of a 0.5 m grid (its far side's ulp 2 m, a margin of 4 m) lifted the node column
    0.5 m east of its near edge (m = 1 there, clamped onto the rim), where ROI.factor, and the float32 rounding of that
    side and of the nodes (a few 1e-6 m), give 0: the close-up took a strip of terrain past its edge."""
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((21, 81), np.float32), spacing=(0.5, 0.5), origin=(0.0, 0.0))
    far = 2e7
    center = (20.0 - far / 2, 5.0) if east else (20.0 + far / 2, 5.0)  # its near side at x = 20 m either way
    roi = ROI.rectangle(center, (far, 20.0), edge_width=0)
    nodes = np.asarray(t.mesh().vertices)[:, :2]
    expected = roi.factor(nodes)
    held = (nodes[:, 0] <= 20.0) if east else (nodes[:, 0] >= 20.0)
    assert ((expected == 1) == (held & (nodes[:, 1] >= -5.0) & (nodes[:, 1] <= 15.0))).all()
    (layer,) = closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 10.0))], device="cpu")
    at = np.rint(layer.original[:, :2] / 0.5).astype(np.int64)  # each kept vertex's node
    np.testing.assert_array_equal(layer.mask_factor, expected[at[:, 1] * 81 + at[:, 0]])
    lifted = layer.original[layer.mask_factor > 0, 0]
    assert (lifted <= 20.0).all() if east else (lifted >= 20.0).all()


def test_a_box_collapsed_in_float32_lifts_no_node_beside_it():
    """A ROI narrower than a float32 ulp of its local coordinates collapses to one value in the kernel: a node one ulp
    beside it, within the kernel's rounding margin, gave u = ±inf, which was clamped onto the mask's edge (m = 1 under a
    hard rectangle) where ROI.factor, which leaves non-finite u out, gives 0."""
    from stepterrain.terrain import Terrain

    t = Terrain.from_heights(np.zeros((5, 3001), np.float32), spacing=(1.0, 1.0), origin=(0.0, 0.0))
    roi = ROI.rectangle((3000.0 - 1.5e-4, 2.0), (1e-5, 1e-5), edge_width=0)
    assert np.float32(roi.box[0] - 0.0) == np.float32(roi.box[1] - 0.0) != 3000.0  # collapsed, one ulp from the node
    assert (roi.factor(t.mesh().vertices[:, :2]) == 0).all()  # no node lies on the box
    with pytest.raises(InvalidInputError, match=r"^closeups\[0\]: ROI box .* holds no terrain"):
        closeup_layers(t, [CloseUp(roi, offset=(0.0, 0.0, 50.0))], device="cpu")  # the node beside it was lifted


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_an_explicit_camera_that_sees_nothing_warns_and_one_that_sees_a_closeup_does_not():
    """An explicit camera position looking away from the overview, its close-ups and anchors rendered the background
    alone without a word (render_mesh refuses such a camera). A camera path may look away for a frame, so it is a
    warning, not an error; a camera that sees only a close-up and its anchor (not the overview) is not warned of."""
    t = terrain()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the fitted camera: no warning
        assert (render_closeups(t, [one()], window_size=SIZE, device="cpu") < 250).any()
    away = [(0.0, -300.0, 200.0), (0.0, -600.0, 300.0), (0.0, 0.0, 1.0)]  # behind the eye, looking further off
    with pytest.warns(UserWarning, match=r"^camera .* sees none of the overview, its close-ups and anchors: the image "
                                         r"is the background alone .*; got \[\(0\.0, -300\.0, 200\.0\)"):
        image = render_closeups(t, [one()], window_size=SIZE, camera=away, device="cpu")
    assert (image == 255).all()  # white: nothing drawn, as warned
    # from above the overview (z 90 > its top 71.5), looking up at the lifted close-up: the overview is behind the eye
    box = np.array([[1039.0, 2029.0, 89.0], [1041.0, 2031.0, 91.0]])  # the position is relative to its centre
    up = [(0.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image = render_closeups(t, [one()], window_size=SIZE, camera=up, bounds=box, device="cpu")
    assert (image < 250).any(axis=2).mean() > 0.1  # the close-up's underside and its anchor, seen from below


@pytest.mark.parametrize("animate", [False, True])
@pytest.mark.parametrize(("option", "value", "message"), [
    ("background", "notacolor", r"^background must be a colour"),
    ("z_scale", -1.0, r"^z_scale must be a positive finite number; got -1"),
    ("camera", "sideways", r"^camera must be 'oblique', 'top', .*; got 'sideways'"),
    ("camera", (0.0, 100.0), r"^camera's elevation must lie in \[-π/2, π/2\]"),
    ("camera", [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)], r"needs an eye apart from its focal point"),
    ("view_angle", 0.0, r"^view_angle must be a vertical field of view"),
    ("scalars", "foo", r"^scalars must be None, 'height'"),
    ("cmap", "nosuchcmap", r"^cmap must name a matplotlib colormap"),
    ("texture", np.zeros((1, 4, 3), np.uint8), r"^texture must be an \(h, w, 3\|4\) image"),
])
def test_bad_view_options_are_refused_before_the_closeups_are_transformed(monkeypatch, animate, option, value,
                                                                          message):
    """The background, z_scale and camera were checked by the renderer, after the close-ups and anchors were
    transformed and culled; animate_closeups checked those and its scalars, cmap and view_angle at its first frame,
    after fitting the box over every turn of the spin (the close-ups transformed for each)."""
    pytest.importorskip("pyvista")
    import stepterrain.closeup as closeup_module

    def work(*args, **kwargs):
        raise AssertionError("the close-ups were transformed before the options were checked")

    monkeypatch.setattr(closeup_module, "closeup_layers", work)
    monkeypatch.setattr(closeup_module, "anchor_strips", work)
    cu = one(spin=(0.5, 1)) if animate else one()
    with pytest.raises(InvalidInputError, match=message):
        if animate:
            animate_closeups(terrain(), [cu], frames=3, window_size=SIZE, device="cpu", **{option: value})
        else:
            render_closeups(terrain(), [cu], window_size=SIZE, device="cpu", **{option: value})


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_the_unseen_camera_warning_points_at_the_callers_line_through_animate_closeups():
    """The warning of an explicit camera that sees nothing took a fixed stacklevel=3: right for render_closeups
    called directly, but through animate_closeups (which calls render_closeups per frame) it pointed at that call
    inside stepterrain/closeup.py, not at the user's line, as the package's other warnings do
    (errors.caller_stacklevel)."""
    away = [(0.0, -300.0, 200.0), (0.0, -600.0, 300.0), (0.0, 0.0, 1.0)]  # as the test above: sees nothing
    with pytest.warns(UserWarning, match=r"^camera .* sees none of the overview") as caught:
        animate_closeups(terrain(), [one(spin=(0.5, 1))], frames=2, window_size=SIZE, camera=away, device="cpu")
    assert {w.filename for w in caught if "sees none" in str(w.message)} == {__file__}
