"""Close-ups (paper 001): ROI masks, the transform kernel against a NumPy reference, culling, anchors,
transfer functions, compositing and bad input. Renders live in test_closeup_render.py."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import trimesh
from hypothesis import given
from hypothesis import strategies as hs

from stepterrain.closeup import (
    ROI,
    TRANSFER_PRESETS,
    AnchorStyle,
    CloseUp,
    anchor_strips,
    closeup_layers,
    closeup_matrix,
    composite,
    max_closeups,
    transfer_function,
)
from stepterrain.errors import InvalidInputError, OutputTooLargeError
from stepterrain.terrain import Terrain, heightfield_mesh

from .conftest import assert_valid_mesh, real_dem
from .reference_closeup import (
    bilinear_mask,
    close_up_matrix,
    culled_faces,
    drawn_min_height,
    surface_heights,
    transform,
)


def hills(rows: int = 33, cols: int = 41, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols]
    z = 20 * np.sin(x / 5.0) * np.cos(y / 7.0) + 50 + rng.normal(0, 1, (rows, cols))
    return z.astype(np.float32)


def reference_layer(terrain: Terrain, cu: CloseUp):
    """Whole-mesh NumPy reference: m, V_C, the culled face indices and the mesh. The transform pivots at the lowest
    height of a node on a drawn triangle (:func:`drawn_min_height`), not of every finite node: a grid's."""
    assert terrain.kind == "grid"
    mesh = terrain.mesh()
    v = np.asarray(mesh.vertices, dtype=np.float64)
    m = bilinear_mask(cu.roi.mask.astype(np.float64), cu.roi.box, v[:, 0], v[:, 1])
    zmin = drawn_min_height(terrain.heights)
    matrix = close_up_matrix(*cu.roi.center, zmin, cu.rotation[0], cu.rotation[1], cu.scale, cu.offset)
    return m, transform(v, m, matrix), culled_faces(np.asarray(mesh.faces), m), mesh, matrix


def assert_matches_reference(terrain: Terrain, cu: CloseUp, layer, atol: float = 1e-3) -> None:
    m, vc, faces, mesh, matrix = reference_layer(terrain, cu)
    # exactly the faces with m > 0; a face whose largest m is within float32 rounding of 0 may go either way
    ambiguous = np.flatnonzero(m[np.asarray(mesh.faces)].max(axis=1) <= 1e-5)
    differ = np.setxor1d(layer.source_faces, faces)
    assert np.isin(differ, ambiguous).all(), f"faces {differ[~np.isin(differ, ambiguous)]} culled wrongly"
    both, ours, theirs = np.intersect1d(layer.source_faces, faces, return_indices=True)
    assert len(both) >= len(faces) - len(ambiguous)
    corners_ref = vc[np.asarray(mesh.faces)[faces[theirs]]]
    corners = layer.vertices[layer.faces[ours]]
    scale = max(1.0, float(np.abs(corners_ref).max())) if len(corners_ref) else 1.0
    v = np.column_stack([np.asarray(mesh.vertices), np.ones(len(mesh.vertices))])
    reach = float(np.linalg.norm((v @ (matrix - np.eye(4)).T)[:, :3], axis=1).max())  # ‖M·v − v‖ at most
    # float32 m (relative error ~1e-6 of the ROI box) moves a soft-edge vertex by Δm·‖M·v − v‖
    np.testing.assert_allclose(corners, corners_ref, atol=atol * scale / 1000 + 1e-4 + 3e-5 * reach, rtol=1e-6)
    m_corners = m[np.asarray(mesh.faces)[faces[theirs]]]
    np.testing.assert_allclose(layer.mask_factor[layer.faces[ours]], m_corners, atol=2e-5)
    np.testing.assert_allclose(layer.matrix, matrix, atol=1e-9)


# ------------------------------------------------------------------------------------------------ ROI masks
SHAPES = {
    "circle": lambda: ROI.circle((0.0, 0.0), 10.0, edge_width=3.0),
    "ellipse": lambda: ROI.ellipse((0.0, 0.0), (10.0, 6.0), edge_width=2.0),
    "rectangle": lambda: ROI.rectangle((0.0, 0.0), (20.0, 12.0), edge_width=2.0),
    "rounded_rectangle": lambda: ROI.rounded_rectangle((0.0, 0.0), (20.0, 12.0), corner_radius=3.0, edge_width=2.0),
}


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_shape_mask_is_one_inside_zero_outside_monotone_across_edge(name):
    roi = SHAPES[name]()
    assert roi.shape == name
    assert roi.mask.min() >= 0 and roi.mask.max() <= 1
    w, h = roi.size
    # along both axes through the centre (texel rows/columns), outwards: 1 at the centre, non-increasing, 0 at the rim
    for direction in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        extent = (w if direction[0] else h) / 2
        s = np.linspace(0, extent * 1.2, 400)
        m = roi.factor(np.column_stack([s * direction[0], s * direction[1]]))
        assert m[0] == 1.0
        assert np.all(np.diff(m) <= 1e-7), f"{name}: m rises outwards along {direction}"
        assert np.all(m[s >= extent] == 0.0)
        assert np.any((m > 0) & (m < 1)), "no soft edge"
    # far outside the box and well inside
    assert roi.factor([[3 * w, 0], [0, 3 * h]]).tolist() == [0.0, 0.0]
    assert roi.factor([[0.1, 0.1]])[0] == pytest.approx(1.0)
    assert roi.factor([[np.inf, 0.0]]).tolist() == [0.0]  # far outside


@pytest.mark.parametrize("xy", [[np.nan, 0.0], [1.0, 2.0, 3.0], "ab", [["a", "b"]]])
def test_roi_factor_refuses_points_that_are_not_xy_numbers(xy):
    # a NaN point indexed the mask at -2^63 (IndexError); three numbers or text raised numpy's ValueError
    with pytest.raises(InvalidInputError, match=r"ROI factor points must be \(N, 2\) numbers"):
        ROI.circle((0.0, 0.0), 10.0).factor(xy)


@pytest.mark.parametrize("flag", ["no", 1, None])
def test_closeup_flags_must_be_bools(flag):
    # active="no" stayed "no" and drew an active close-up, band="no" became True, top_row_north="no" flipped
    roi = ROI.circle((0.0, 0.0), 10.0)
    with pytest.raises(InvalidInputError, match=rf"close-up active must be True or False; got {flag!r}"):
        CloseUp(roi, active=flag)
    with pytest.raises(InvalidInputError, match=rf"anchor band must be True or False; got {flag!r}"):
        AnchorStyle(band=flag)
    with pytest.raises(InvalidInputError, match=rf"top_row_north must be True or False; got {flag!r}"):
        ROI.painted(np.ones((3, 3)), (0.0, 0.0), (1.0, 1.0), top_row_north=flag)
    assert CloseUp(roi, active=np.bool_(False)).active is False


@pytest.mark.parametrize("level", ["a", "0.5", True, [0.5], [0.5, 0.6], np.nan, 0.0, 1.0, 2.0])
def test_roi_outline_level_must_lie_in_0_1(level):
    # text reached contourpy (TypeError), a list the cache (unhashable), NaN or 2 gave no outline silently;
    # "0.5" and [0.5] were taken as 0.5 by the outline, and kept as they were by AnchorStyle (a text level then
    # failed in numpy's >= at the first render). Both take the same values, refused in the same words.
    with pytest.raises(InvalidInputError,
                       match=rf"ROI outline level must be a number in \(0, 1\); got {re.escape(repr(level))}"):
        ROI.circle((0.0, 0.0), 10.0).outline(level)
    with pytest.raises(InvalidInputError,
                       match=rf"anchor outline_level must be a number in \(0, 1\); got {re.escape(repr(level))}"):
        AnchorStyle(outline_level=level)


def test_outline_levels_take_numpy_numbers_as_floats():
    assert AnchorStyle(outline_level=np.float32(0.25)).outline_level == 0.25
    assert type(AnchorStyle(outline_level=np.float32(0.25)).outline_level) is float
    assert len(ROI.circle((0.0, 0.0), 10.0).outline(np.float64(0.5))) == 1


def test_hard_edge_and_painted_mask_orientation():
    hard = ROI.circle((0, 0), 5.0, edge_width=0.0, resolution=65)
    assert set(np.unique(hard.mask)) == {0.0, 1.0}
    painted = np.zeros((4, 6), np.uint8)
    painted[0, :] = 255  # top row (north) painted
    roi = ROI.painted(painted, (0.0, 0.0), (6.0, 4.0))
    assert roi.mask.max() == 1.0 and roi.mask[-1].min() == 1.0  # row 0 of ROI.mask is the south edge
    assert roi.factor([[0.0, 2.0]])[0] == 1.0 and roi.factor([[0.0, -2.0]])[0] == 0.0
    assert roi.outline(), "a painted band has an outline"


def test_generated_masks_follow_terrain_features():
    heights = hills()
    t = Terrain.from_heights(heights, spacing=(10.0, -10.0), origin=(1000.0, 5000.0))
    band = ROI.height_band(t, 40.0, 60.0)
    assert band.mask.shape == heights.shape
    # the mask is the grid flipped to rows at increasing y: the north-up grid's last row is mask row 0
    np.testing.assert_array_equal(band.mask[::-1] == 1.0, (heights >= 40) & (heights <= 60))
    assert band.box == pytest.approx(t.extent)
    soft = ROI.height_band(t, 40.0, 60.0, edge=5.0)
    assert np.all(soft.mask >= band.mask) and np.any((soft.mask > 0) & (soft.mask < 1))
    steep = ROI.slope_above(t, 30.0)
    gy, gx = np.gradient(heights.astype(np.float64), 10.0, 10.0)
    expected = np.degrees(np.arctan(np.hypot(gx, gy))) > 30.0
    np.testing.assert_array_equal(steep.mask[::-1] == 1.0, expected)
    level = ROI.stepped_level(t, 3, interval=10.0)
    import stepterrain as st

    values = st.isovalues(t.height_range, interval=10.0)
    th = (values[:-1] + values[1:]) / 2
    expected = (heights >= th[2]) & (heights < th[3])
    np.testing.assert_array_equal(level.mask[::-1] == 1.0, expected)
    region = ROI.height_band(t, 0, 100, region=(1050.0, 1200.0, 4800.0, 4900.0))
    assert region.box == pytest.approx((1050.0, 1200.0, 4800.0, 4900.0))



def test_stepped_level_mask_agrees_with_the_stepped_mesh_on_a_threshold():
    """Isovalues 64.7 and 67.1 (float32) meet at the kernels' float32 threshold 65.899994; the float64 midpoint
    of the two is 65.8999977. A node at 65.899994 is on the kernels' threshold, so it belongs to the upper level
    (heights on a threshold go up), and so to the upper level's mask: the float64 midpoint put it in the lower
    level's."""
    from stepterrain.stepped import thresholds_of

    heights = np.array([[60.0, 65.899994, 70.0], [61.0, 66.0, 64.0], [62.0, 65.0, 69.0]], np.float32)
    levels = [64.7, 67.1]
    assert thresholds_of(np.float32(levels))[0] == heights[0, 1]
    upper = ROI.stepped_level(heights, 1, levels=levels)
    lower = ROI.stepped_level(heights, 0, levels=levels)
    assert upper.mask[0, 1] == 1.0 and lower.mask[0, 1] == 0.0
    np.testing.assert_array_equal(upper.mask + lower.mask, 1.0)

def test_outline_follows_the_shape():
    roi = ROI.circle((100.0, 50.0), 10.0, edge_width=2.0)
    (line,) = roi.outline(0.5)
    r = np.hypot(line[:, 0] - 100.0, line[:, 1] - 50.0)
    assert np.allclose(line[0], line[-1])  # closed
    assert np.all(np.abs(r - 9.0) < 0.2)  # the 0.5 contour lies half an edge inside the rim


# ------------------------------------------------------------------------------------------------ transform
def test_matrix_is_rotation_scale_translation_about_the_roi():
    m = closeup_matrix((10.0, 20.0), 5.0, 0.0, 0.0, (2.0, 3.0, 0.5), (1.0, 2.0, 3.0))
    # the pivot O maps to O + p; a point one unit east maps sx units east of that
    assert (m @ [10, 20, 5, 1]).tolist() == pytest.approx([11, 22, 8, 1])
    assert (m @ [11, 20, 5, 1]).tolist() == pytest.approx([13, 22, 8, 1])
    r = closeup_matrix((0.0, 0.0), 0.0, 0.0, math.pi / 2, 1.0, (0, 0, 0))
    assert (r @ [1, 0, 0, 1]).tolist() == pytest.approx([0, 1, 0, 1])  # β turns about the vertical axis
    a = closeup_matrix((0.0, 0.0), 0.0, math.pi / 2, 0.0, 1.0, (0, 0, 0))
    assert (a @ [0, 1, 0, 1]).tolist() == pytest.approx([0, 0, 1, 1])  # α tilts about x
    np.testing.assert_allclose(m, close_up_matrix(10, 20, 5, 0, 0, (2, 3, 0.5), (1, 2, 3)))


def test_m_one_gives_M_v_and_m_zero_leaves_vertices_unchanged(device):
    t = Terrain.from_heights(hills(), spacing=(2.0, 2.0))
    cu = CloseUp(ROI.circle((40.0, 32.0), 20.0, edge_width=6.0), rotation=(0.3, 0.7), scale=(1.5, 2.0, 3.0),
                 offset=(5.0, -3.0, 80.0))
    (layer,) = closeup_layers(t, [cu], device=device)
    assert_valid_mesh(layer.mesh())
    ones = layer.mask_factor == 1.0
    zeros = layer.mask_factor == 0.0
    assert ones.sum() > 50 and zeros.sum() > 10
    mv = (layer.matrix @ np.column_stack([layer.original, np.ones(len(layer.original))]).T).T[:, :3]
    np.testing.assert_allclose(layer.vertices[ones], mv[ones], rtol=1e-6, atol=1e-4)
    np.testing.assert_array_equal(layer.vertices[zeros], layer.original[zeros])  # bit for bit
    inside = (layer.mask_factor > 0) & ~ones  # the soft edge lies on the segment V_O -> M·V_O
    lam = layer.mask_factor[inside][:, None]
    v_o = layer.original[inside]
    np.testing.assert_allclose(layer.vertices[inside], v_o + lam * (mv[inside] - v_o),
                               atol=1e-3)


def float32_closeup_replica(points_local: np.ndarray, matrix: np.ndarray, local_origin) -> np.ndarray:
    """V_C = M·V_O for m = 1, by the library's own sequence of roundings, in NumPy:

    1. the world matrix M (float64) moved to the terrain's local origin o: inv(T(o)) @ M @ T(o) in float64,
       rounded once to float32 (``closeup._layers_struct``);
    2. C = m·M + (1 − m)·I with m = 1 is 1·M + 0·I = M exactly (``blend_transform``);
    3. C·(x, y, z, 1) in float32 as Warp's mat-vec product runs it, column by column with no fused
       multiply-add (``fuse_fp`` is off): ((C₀x + C₁y) + C₂z) + C₃·1 (``apply``);
    4. back to world: float32 → float64, then x + oₓ and y + o_y in float64 (``closeup._world``).

    Every step is a correctly rounded IEEE operation on the same operands, so the result is bit-identical;
    only against M·v evaluated in float64 does float32 rounding show (the assert_allclose test above)."""
    ox, oy = local_origin
    shift = np.eye(4)
    shift[:2, 3] = (ox, oy)
    c = (np.linalg.inv(shift) @ matrix @ shift).astype(np.float32)
    x, y, z = (points_local[:, k].astype(np.float32)[:, None] for k in range(3))
    r = c[:3, 0] * x
    r = r + c[:3, 1] * y
    r = r + c[:3, 2] * z
    r = r + c[:3, 3] * np.float32(1.0)
    world = r.astype(np.float64)
    world[:, 0] += ox
    world[:, 1] += oy
    return world


def test_m_one_vertices_equal_a_float32_replica_of_M_v_exactly(device, monkeypatch):
    """Issue 4 §4: with m = 1 the close-up vertices equal M·v exactly: bit for bit against the float32
    replica (see :func:`float32_closeup_replica`), far from the world origin (where float32 local coordinates
    and the float64 shift both round), for the first frame (the cull's transform kernel) and for a frame that
    only moves the close-up (the kept vertices' kernel)."""
    import stepterrain.closeup as closeup_module

    kernels_run: list[str] = []
    real_launch = closeup_module.launch

    def recording_launch(kernel, *args, **kwargs):
        kernels_run.append(kernel.key)
        return real_launch(kernel, *args, **kwargs)

    monkeypatch.setattr(closeup_module, "launch", recording_launch)
    spacing, origin = (30.0, -30.0), (376313.66, 3807917.83)
    t = Terrain.from_heights(hills(), spacing=spacing, origin=origin)
    roi = ROI.circle((origin[0] + 600.0, origin[1] - 480.0), 300.0, edge_width=90.0)
    first = CloseUp(roi, rotation=(0.3, 0.7), scale=(1.5, 2.0, 3.0), offset=(5.0, -3.0, 80.0))
    moved = CloseUp(roi, rotation=(-0.2, 2.1), scale=(0.7, 1.3, 2.5), offset=(-41.0, 17.5, 120.25))
    for cu, kernel in ((first, "transform_closeup_vertices"), (moved, "transform_kept_vertices")):
        kernels_run.clear()
        (layer,) = closeup_layers(t, [cu], device=device)
        # the second call reuses the cull (same terrain and ROI) and transforms only the kept vertices
        assert [k for k in kernels_run if k.startswith("transform_")] == [kernel]
        ones = layer.mask_factor == 1.0
        assert ones.sum() > 50 and (layer.mask_factor < 1.0).any()
        # the kernel's float32 local input: node (i, j) at (float32(j dx), float32(i dy), height)
        j = np.rint((layer.original[:, 0] - origin[0]) / spacing[0]).astype(np.int64)
        i = np.rint((layer.original[:, 1] - origin[1]) / spacing[1]).astype(np.int64)
        local = np.column_stack([(j * spacing[0]).astype(np.float32), (i * spacing[1]).astype(np.float32),
                                 t.heights[i, j]])
        back = local.astype(np.float64)
        back[:, :2] += origin
        np.testing.assert_array_equal(layer.original, back)  # the replica starts from the kernel's input
        expected = float32_closeup_replica(local[ones], layer.matrix, t.local_origin)
        np.testing.assert_array_equal(layer.vertices[ones], expected)


def test_culling_matches_the_whole_mesh_reference(device):
    t = Terrain.from_heights(hills(), spacing=(2.0, -2.0), origin=(500.0, 800.0))
    cus = [
        CloseUp(ROI.circle((540.0, 770.0), 15.0), scale=2.0, offset=(0.0, 0.0, 60.0)),
        CloseUp(ROI.rounded_rectangle((520.0, 750.0), (20.0, 14.0)), rotation=(0.2, -0.4), scale=(1.0, 1.5, 0.0),
                offset=(-10.0, 5.0, 40.0)),
        CloseUp(ROI.ellipse((575.0, 745.0), (12.0, 30.0)), scale=1.2, offset=(3.0, 3.0, 30.0)),  # clipped by the edge
    ]
    layers = closeup_layers(t, cus, device=device)
    for cu, layer in zip(cus, layers, strict=True):
        assert_valid_mesh(layer.mesh())
        assert_matches_reference(t, cu, layer)
    # one launch for all equals one call per close-up
    for k, cu in enumerate(cus):
        (alone,) = closeup_layers(t, [cu], device=device)
        np.testing.assert_array_equal(alone.faces, layers[k].faces)
        np.testing.assert_array_equal(alone.vertices, layers[k].vertices)


def test_real_dem_against_reference(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=8)
    t = Terrain.from_heights(heights, spacing=(240.0, -240.0), origin=(376313.0, 3807917.0))
    xmin, xmax, ymin, ymax = t.extent
    cus = [CloseUp(ROI.circle(((xmin + xmax) / 2, (ymin + ymax) / 2), 2000.0), rotation=(0.1, 0.5), scale=2.0,
                   offset=(0.0, 0.0, 3000.0)),
           CloseUp(ROI.slope_above(t, 25.0, region=(xmin + 2000, xmin + 5000, ymin + 2000, ymin + 5000)),
                   scale=1.5, offset=(0.0, 0.0, 2500.0))]
    for cu, layer in zip(cus, closeup_layers(t, cus, device=device), strict=True):
        assert len(layer.faces) > 0
        assert_matches_reference(t, cu, layer, atol=5.0)  # UTM metres: float32 relative to the local origin


def test_tin_terrain_is_culled_like_the_grid(device):
    heights = hills(17, 19)
    mesh = heightfield_mesh(heights, spacing=(3.0, 3.0))
    cu = CloseUp(ROI.circle((27.0, 24.0), 10.0), scale=2.0, offset=(0.0, 0.0, 40.0))
    (grid_layer,) = closeup_layers(Terrain.from_heights(heights, spacing=(3.0, 3.0)), [cu], device=device)
    (tin_layer,) = closeup_layers(mesh, [cu], device=device)
    np.testing.assert_array_equal(tin_layer.source_faces, grid_layer.source_faces)
    np.testing.assert_allclose(tin_layer.vertices[tin_layer.faces], grid_layer.vertices[grid_layer.faces], atol=1e-4)
    (strip,) = anchor_strips(mesh, [cu], device=device)  # a TIN's outline heights: its nearest vertex
    bottom = strip.vertices[:: strip.rungs + 1]
    assert len(bottom) > 10 and np.isfinite(strip.vertices).all()
    assert heights.min() <= bottom[:, 2].min() and bottom[:, 2].max() <= heights.max()


@pytest.mark.parametrize("kind", ["slope", "aspect"])
def test_slope_and_aspect_on_a_tin_are_refused(kind):
    """Slope and aspect come from a grid's gradient: on a TIN they were its heights in metres, read as radians
    (one color everywhere), silently. Refused by name; height still maps a TIN."""
    from stepterrain.closeup import closeup_scene, render_closeups

    mesh = heightfield_mesh(hills(17, 19), spacing=(3.0, 3.0))
    cu = CloseUp(ROI.circle((27.0, 24.0), 10.0), offset=(0.0, 0.0, 40.0))
    with pytest.raises(InvalidInputError, match=rf"closeups\[0\]\.scalars='{kind}' needs a grid terrain"):
        closeup_layers(mesh, [CloseUp(cu.roi, offset=cu.offset, scalars=kind)], device="cpu")
    with pytest.raises(InvalidInputError, match=rf"^scalars='{kind}' needs a grid terrain .* got a TIN"):
        closeup_scene(mesh, [cu], scalars=kind, device="cpu")
    with pytest.raises(InvalidInputError, match=rf"^scalars='{kind}' needs a grid terrain"):
        render_closeups(mesh, [cu], scalars=kind, device="cpu")
    assert len(closeup_scene(mesh, [cu], scalars="height", device="cpu").faces) > 0


@pytest.mark.parametrize("name", ["time", "renderer", "reuse_overview"])
def test_animate_refuses_the_options_it_sets_per_frame(name):
    """animate_closeups passes its options to render_closeups but sets these per frame: they raised render_closeups'
    TypeError "got multiple values for keyword argument"; now an InvalidInputError naming the option."""
    from stepterrain.closeup import animate_closeups

    cu = CloseUp(ROI.circle((27.0, 24.0), 10.0), offset=(0.0, 0.0, 40.0))
    with pytest.raises(InvalidInputError, match=rf"animate_closeups sets {name} for each frame itself .*; got {name}="):
        animate_closeups(Terrain.from_heights(hills(17, 19), spacing=(3.0, 3.0)), [cu], frames=1, **{name: 1.0})


@pytest.mark.parametrize("lone", [(10, 10), (0, 0), (20, 20)])
def test_with_nodata_the_closeup_pivots_at_the_lowest_drawn_node_as_the_reference(device, lone):
    # a finite node on no triangle with three finite heights (in a hole, or a corner whose neighbours are nodata) is
    # in no mesh: the close-up pivots at the lowest drawn node, not at that node's extreme height (the reference
    # pivoted at nanmin of all heights, right only without nodata)
    heights = hills(21, 21)
    heights[8:13, 8:13] = np.nan
    heights[0, 1] = heights[1, 0] = heights[20, 19] = heights[19, 20] = np.nan
    heights[lone] = -500.0
    t = Terrain.from_heights(heights, spacing=(1.5, -1.5), origin=(100.0, 200.0))
    pivot = drawn_min_height(heights)
    assert pivot == t.height_range[0]
    assert pivot > float(np.nanmin(heights)) + 400
    cus = [CloseUp(ROI.circle((115.0, 185.0), 9.0), rotation=(0.3, -0.5), scale=(1.5, 0.8, 2.0),
                   offset=(2.0, -3.0, 40.0)),
           CloseUp(ROI.rectangle((110.0, 190.0), (14.0, 10.0)), scale=2.0, offset=(0.0, 0.0, 25.0))]
    for cu, layer in zip(cus, closeup_layers(t, cus, device=device), strict=True):
        assert len(layer.faces) > 0
        assert_matches_reference(t, cu, layer)


def test_nodata_faces_are_never_emitted(device):
    heights = hills(21, 21)
    heights[8:12, 8:12] = np.nan
    t = Terrain.from_heights(heights)
    (layer,) = closeup_layers(t, [CloseUp(ROI.circle((10.0, 10.0), 8.0), offset=(0, 0, 30.0))], device=device)
    assert_valid_mesh(layer.mesh())
    assert len(layer.faces) > 0


def test_stepped_closeup_is_mpfr(device):
    t = Terrain.from_heights(hills(), spacing=(2.0, 2.0))
    cu = CloseUp(ROI.circle((40.0, 32.0), 20.0), scale=1.0, offset=(0.0, 0.0, 100.0), stepped=10.0)
    (layer,) = closeup_layers(t, [cu], device=device)
    assert_valid_mesh(layer.mesh())
    assert layer.colors is not None and layer.colors.shape == (len(layer.vertices), 3)
    assert np.all(layer.source_faces == -1)
    # terrace heights of the close-up part (m = 1) are isovalues, lifted by the offset
    import stepterrain as st

    values = st.isovalues(t.height_range, interval=10.0)
    full = layer.mask_factor == 1.0
    z = layer.original[full, 2]
    assert np.isin(np.round(z, 3), np.round(values, 3)).mean() > 0.5


def test_spin_turns_the_closeup():
    cu = CloseUp(ROI.circle((0, 0), 1.0), rotation=(0.0, 0.25), spin=(0.5, 2))
    assert cu.turn(0.0) == 0.25
    assert cu.turn(1.0) == pytest.approx(0.25 + math.pi)
    assert cu.turn(100.0) == pytest.approx(0.25 + 4 * math.pi)  # stops after the repetitions


@given(
    cx=hs.floats(5.0, 75.0), cy=hs.floats(5.0, 60.0), radius=hs.floats(3.0, 30.0), edge=hs.floats(0.0, 1.0),
    scale=hs.floats(0.2, 4.0), sz=hs.floats(0.0, 3.0), alpha=hs.floats(-3.2, 3.2), beta=hs.floats(-3.2, 3.2),
    dz=hs.floats(-50.0, 200.0), seed=hs.integers(0, 3),
)
def test_property_kernel_equals_reference(cx, cy, radius, edge, scale, sz, alpha, beta, dz, seed):
    t = Terrain.from_heights(hills(17, 21, seed), spacing=(4.0, 4.0))
    cu = CloseUp(ROI.circle((cx, cy), radius, edge_width=edge * radius, resolution=33), rotation=(alpha, beta),
                 scale=(scale, scale, sz), offset=(1.0, -2.0, dz))
    (layer,) = closeup_layers(t, [cu], device="cpu")
    assert_matches_reference(t, cu, layer)
    if len(layer.faces):
        assert_valid_mesh(layer.mesh())
        assert np.all(layer.mask_factor[layer.faces].max(axis=1) > 0)


# ------------------------------------------------------------------------------------------------ anchors
def test_anchor_strips_join_outline_points_carry_color_and_follow_the_transfer_function(device):
    heights = hills()
    t = Terrain.from_heights(heights, spacing=(2.0, 2.0))
    styles = ["linear", "ends", (0.1, 0.9, 0.3, 0.7)]
    cus = [CloseUp(ROI.circle((30.0 + 12 * k, 32.0), 8.0), rotation=(0.2, 0.3 * k), scale=1.5,
                   offset=(0.0, 0.0, 50.0 + 10 * k), color=c, anchor=AnchorStyle(s, rungs=4, simplify=0.0))
           for k, (s, c) in enumerate(zip(styles, ["red", "#00ff00", (0.0, 0.0, 1.0)], strict=True))]
    strips = anchor_strips(t, cus, device=device)
    for cu, strip in zip(cus, strips, strict=True):
        assert strip.color == cu.color
        r1 = strip.rungs + 1
        rings = strip.vertices.reshape(-1, r1, 3)
        bottom, top = rings[:, 0], rings[:, -1]
        # bottoms lie on the outline, on the terrain; tops are M applied to the bottoms
        (line,) = cu.roi.outline(cu.anchor.outline_level)
        np.testing.assert_allclose(bottom[:, :2], line, atol=1e-4)
        tm = heightfield_mesh(heights, spacing=(2.0, 2.0))  # on the drawn triangles, not a bilinear surface
        np.testing.assert_allclose(bottom[:, 2], surface_heights(tm.vertices, tm.faces, bottom[:, :2]), atol=1e-3)
        mv = (strip.max_length and (np.column_stack([bottom, np.ones(len(bottom))]) @ cu.matrix(t.height_range[0]).T))
        np.testing.assert_allclose(top, mv[:, :3], atol=1e-3)
        # rungs are straight, evenly spaced; t = s·|M·V_O − V_O| / D
        s = np.linspace(0, 1, r1)
        np.testing.assert_allclose(rings, bottom[:, None] + s[None, :, None] * (top - bottom)[:, None], atol=1e-3)
        lengths = np.linalg.norm(top - bottom, axis=1)
        assert strip.max_length == pytest.approx(lengths.max(), rel=1e-5)
        expected_t = (s[None, :] * lengths[:, None] / lengths.max()).reshape(-1)
        np.testing.assert_allclose(strip.distance, expected_t, atol=1e-5)
        table = cu.anchor.table
        np.testing.assert_allclose(strip.opacity, np.interp(expected_t, np.linspace(0, 1, len(table)), table),
                                   atol=1e-5)
        # every face joins rung vertices of two consecutive outline points
        point = strip.faces // r1
        spans = point.max(axis=1) - point.min(axis=1)
        assert np.all(spans == 1)
        assert_valid_mesh(trimesh.Trimesh(strip.vertices, strip.faces, process=False))


@pytest.mark.parametrize("scale", [1.0, (2.5, 1.0, 4.0)])
@pytest.mark.parametrize("simplify", [0.25, 1.0])
def test_thinned_anchor_fence_stays_within_its_tolerance_of_the_full_one(scale, simplify):
    """AnchorStyle.simplify thins the outline points: the kept ones are outline points in order, and every rung
    of the full-resolution fence (every outline point) lies within simplify · texel of the thinned rung."""
    from stepterrain.closeup import simplify_polyline

    heights = hills()
    t = Terrain.from_heights(heights, spacing=(2.0, 2.0))
    roi = ROI.circle((40.0, 32.0), 12.0)
    full_cu, thin_cu = (CloseUp(roi, rotation=(0.3, 0.7), scale=scale, offset=(0.0, 0.0, 60.0),
                                anchor=AnchorStyle(rungs=3, simplify=f)) for f in (0.0, simplify))
    (full,) = anchor_strips(t, [full_cu], device="cpu")
    (thin,) = anchor_strips(t, [thin_cu], device="cpu")
    r1 = full.rungs + 1
    full_rings, thin_rings = full.vertices.reshape(-1, r1, 3), thin.vertices.reshape(-1, r1, 3)
    assert 3 <= len(thin_rings) < len(full_rings) // 2
    # the kept bottoms are outline points, in order
    match: list[int] = []
    for p in thin_rings[:, 0]:  # a closed outline repeats its first point last: search after the previous match
        start = match[-1] + 1 if match else 0
        match.append(start + int(np.flatnonzero(np.all(np.abs(full_rings[start:, 0] - p) < 1e-9, axis=1))[0]))
    assert match[0] == 0 and match[-1] == len(full_rings) - 1
    texel = min(np.ptp(roi.box[:2]) / (roi.mask.shape[1] - 1), np.ptp(roi.box[2:]) / (roi.mask.shape[0] - 1))
    tolerance = simplify * texel
    worst = 0.0
    for r in range(r1):
        for a, b in zip(match[:-1], match[1:], strict=True):
            p0, p1 = full_rings[a, r], full_rings[b, r]
            seg = p1 - p0
            mid = full_rings[a + 1: b, r] - p0
            along = np.clip(mid @ seg / (seg @ seg), 0, 1)
            worst = max(worst, float(np.linalg.norm(mid - along[:, None] * seg, axis=1).max(initial=0.0)))
    assert worst <= tolerance * (1 + 1e-4) + 1e-4
    # the same distances and transfer values at the kept points
    np.testing.assert_allclose(thin.distance.reshape(-1, r1), full.distance.reshape(-1, r1)[match] *
                               full.max_length / thin.max_length, atol=1e-5)
    # Douglas-Peucker itself: a straight run collapses to its ends, a corner stays
    line = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [2.0, 2.0]])
    assert simplify_polyline(line, 0.1).tolist() == [True, False, True, False, True]
    assert simplify_polyline(line[:1], 0.1).tolist() == [True]


def test_anchor_style_refuses_a_bad_simplify():
    for bad in (-0.1, 5.0, float("nan"), "1", True):
        with pytest.raises(InvalidInputError, match="simplify"):
            AnchorStyle(simplify=bad)
    # float(10**400) raised a bare OverflowError past the isinstance check
    with pytest.raises(InvalidInputError, match=r"^anchor simplify \(mask texels\) must be finite; got an integer too "
                                                r"large for a float"):
        AnchorStyle(simplify=10**400)
    with pytest.raises(InvalidInputError, match=r"^anchor simplify \(mask texels\) must lie in \[0, 4\]; got 5$"):
        AnchorStyle(simplify=5)
    for good in (np.float32(0.5), np.array(0.5), 0.5, 1, 4):  # a 0-d array as outline_level takes it
        assert type(AnchorStyle(simplify=good).simplify) is float


def test_scene_mesh_holds_overview_closeups_and_anchors():
    from stepterrain.closeup import closeup_scene

    t = Terrain.from_heights(hills(), spacing=(2.0, 2.0))
    cus = [CloseUp(ROI.circle((30.0, 32.0), 8.0), offset=(0, 0, 50.0), color="red"),
           CloseUp(ROI.circle((50.0, 32.0), 8.0), offset=(0, 0, 50.0), color="blue")]
    scene = closeup_scene(t, cus, device="cpu")
    assert_valid_mesh(scene)
    layer = scene.face_attributes["layer"]
    assert (layer == 0).sum() == 2 * 32 * 40
    assert sorted(set(layer.tolist())) == [0, 1, 2, 3, 4]
    anchor_vertices = np.unique(scene.faces[layer == 2])
    colors = scene.visual.vertex_colors[anchor_vertices]
    assert np.all(colors[:, :3] == [255, 0, 0])


def test_transfer_function_presets_and_tables():
    assert set(TRANSFER_PRESETS) >= {"opaque", "linear", "inverse", "ends", "hidden"}
    assert transfer_function("hidden").max() == 0.0
    np.testing.assert_allclose(transfer_function([0.0, 0.5, 1.0]), [0.0, 0.5, 1.0])
    with pytest.raises(InvalidInputError, match="one of"):
        transfer_function("rainbow")
    with pytest.raises(InvalidInputError, match=r"\[0, 1\]"):
        AnchorStyle((0.0, 1.5))
    with pytest.raises(InvalidInputError, match="rungs"):
        AnchorStyle(rungs=0)


# ------------------------------------------------------------------------------------------------ compositing
def test_composite_without_layers_is_the_base_and_follows_its_formula():
    rng = np.random.default_rng(7)
    h, w = 12, 16
    base = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    base_depth = rng.uniform(0.2, 1.0, (h, w)).astype(np.float32)
    np.testing.assert_array_equal(composite(base, base_depth, []), base)
    layers = []
    for k in range(4):
        color = rng.uniform(0, 255, (h, w, 3))
        alpha = rng.uniform(0, 1, (h, w)).astype(np.float32) * (rng.uniform(size=(h, w)) > 0.3)
        depth = rng.uniform(0.0, 1.0, (h, w)).astype(np.float32)
        layers.append((color, alpha, depth, k % 2 == 0, k % 3 != 1))
    got = composite(base, base_depth, layers)
    # the formula, pixel by pixel
    expected = np.empty_like(base)
    for i in range(h):
        for j in range(w):
            c = base[i, j].astype(np.float64)
            z = float(base_depth[i, j])
            for color, alpha, depth, test, writes in layers:
                a = float(alpha[i, j])
                if test and not depth[i, j] < z:
                    a = 0.0
                c = a * color[i, j] + (1 - a) * c
                if writes and a > 0:
                    z = float(depth[i, j])
            expected[i, j] = np.clip(np.rint(c), 0, 255)
    assert np.abs(got.astype(int) - expected.astype(int)).max() <= 1


@given(seed=hs.integers(0, 2**31 - 1), count=hs.integers(1, 6))
def test_boxed_composite_equals_the_full_window_composite(seed, count):
    """Layers cut to their pixel boxes (as render_closeups reads them back) composite bit for bit like the same
    layers padded to the window (empty outside their boxes): overlapping boxes, one-color layers, empty boxes."""
    from stepterrain.closeup import _composite_boxed

    rng = np.random.default_rng(seed)
    h, w = 24, 32
    base = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    base_depth = np.where(rng.uniform(size=(h, w)) < 0.2, np.inf, rng.uniform(0.2, 1.0, (h, w))).astype(np.float32)
    boxed, padded = [], []
    for k in range(count):
        c0, c1 = np.sort(rng.integers(0, w + 1, 2))
        r0, r1 = np.sort(rng.integers(0, h + 1, 2))
        bh, bw = r1 - r0, c1 - c0
        one_color = k % 3 == 2
        color = rng.uniform(0, 255, 3).astype(np.float32) if one_color else rng.integers(0, 256, (bh, bw, 3), np.uint8)
        alpha = (rng.uniform(0, 1, (bh, bw)) * (rng.uniform(size=(bh, bw)) > 0.3)).astype(np.float32)
        depth = np.where(alpha > 0, rng.uniform(0.0, 1.0, (bh, bw)), np.inf).astype(np.float32)
        test, writes = bool(rng.integers(2)), bool(rng.integers(2))
        boxed.append((color, alpha, depth, test, writes, (int(c0), int(r0), int(c1), int(r1))))
        full_color = np.zeros((h, w, 3), np.float32)
        full_color[r0:r1, c0:c1] = color
        full_alpha = np.zeros((h, w), np.float32)
        full_alpha[r0:r1, c0:c1] = alpha
        full_depth = np.full((h, w), np.inf, np.float32)
        full_depth[r0:r1, c0:c1] = depth
        padded.append((full_color, full_alpha, full_depth, test, writes))
    np.testing.assert_array_equal(_composite_boxed(base, base_depth, boxed), composite(base, base_depth, padded))


@pytest.mark.parametrize("cmap", ["terrain", "magma", "twilight"])
def test_vertex_colors_equal_matplotlib(cmap):
    """_colors_for looks up a uint8 table: the same colors as matplotlib's colormap per vertex, NaN included."""
    import matplotlib

    from stepterrain.closeup import _colors_for

    rng = np.random.default_rng(3)
    for dtype in (np.float32, np.float64):
        values = np.concatenate([rng.uniform(-50, 1050, 20000), np.linspace(0, 1000, 4001), [np.nan]]).astype(dtype)
        for vmin, vmax in [(0.0, 1000.0), (np.float32(12.5), np.float32(999.0))]:
            x = np.clip((values - vmin) / (vmax - vmin), 0, 1)
            x = 0.25 + 0.75 * x if cmap == "terrain" else x
            expected = (np.asarray(matplotlib.colormaps[cmap](x))[:, :3] * 255 + 0.5).astype(np.uint8)
            np.testing.assert_array_equal(_colors_for(values, cmap, vmin, vmax), expected)


def test_boxed_composite_rejects_a_box_outside_the_image():
    from stepterrain.closeup import _composite_boxed

    base = np.zeros((4, 4, 3), np.uint8)
    layer = (np.zeros(3), np.ones((2, 2), np.float32), np.zeros((2, 2), np.float32), False, True, (3, 0, 5, 2))
    with pytest.raises(InvalidInputError, match="box"):
        _composite_boxed(base, np.ones((4, 4), np.float32), [layer])


# ------------------------------------------------------------------------------------------------ bad input
def test_closeup_spin_pivot_and_roi_mask_are_checked():
    """spin=(1, 2.7) was cut to 2 repetitions and (1, 2, 3) accepted; matrix(nan) gave a NaN matrix and
    matrix('a') a bare ValueError; a complex ROI mask lost its imaginary part, a ragged one raised numpy's."""
    roi = ROI.circle((40.0, 30.0), 10.0)
    for spin in ((1.0, 2.7), (1.0, 2.0, 3.0), (1.0,), "ab", (1.0, float("nan"))):
        with pytest.raises(InvalidInputError, match=r"close-up spin must be \(turns per second, whole repetitions\)"):
            CloseUp(roi, spin=spin)
    assert CloseUp(roi, spin=(0.5, 2.0)).spin == (0.5, 2)
    for pivot in (float("nan"), "a", float("inf")):
        with pytest.raises(InvalidInputError, match="pivot_z must be"):
            CloseUp(roi).matrix(pivot)
    for mask in (np.ones((4, 4), complex), [[1.0, 1.0], [1.0]]):
        with pytest.raises(InvalidInputError, match=r"ROI mask must be a real \(rows, cols\) array"):
            ROI((0.0, 0.0), (1.0, 1.0), mask, "painted")


def test_bad_input_raises_clear_errors():
    t = Terrain.from_heights(hills(), spacing=(2.0, 2.0))
    roi = ROI.circle((40.0, 30.0), 10.0)
    with pytest.raises(InvalidInputError, match="outside the terrain"):
        closeup_layers(t, [CloseUp(ROI.circle((1000.0, 30.0), 10.0))], device="cpu")
    for scale in (0.0, -1.0, (1.0, 0.0, 1.0), (1.0, 1.0, -2.0)):
        with pytest.raises(InvalidInputError, match="scale must be positive"):
            CloseUp(roi, scale=scale)
    for rotation in ((math.nan, 0.0), (0.0, math.inf), (1.0,)):
        with pytest.raises(InvalidInputError, match="rotation must be finite"):
            CloseUp(roi, rotation=rotation)
    with pytest.raises(InvalidInputError, match="2-D"):
        ROI((0, 0), (1, 1), np.ones(5))
    with pytest.raises(InvalidInputError, match="at least 2 x 2"):
        ROI((0, 0), (1, 1), np.ones((1, 5)))
    with pytest.raises(InvalidInputError, match=r"\[0, 1\]"):
        ROI((0, 0), (1, 1), np.full((3, 3), 2.0))
    with pytest.raises(InvalidInputError, match="finite"):
        ROI((0, 0), (1, 1), np.full((3, 3), np.nan))
    with pytest.raises(InvalidInputError, match="grayscale"):
        ROI.painted(np.zeros((4, 4, 3), np.uint8), (0, 0), (1, 1))
    with pytest.raises(InvalidInputError, match="size must be positive"):
        ROI((0, 0), (0, 1), np.ones((3, 3)))
    with pytest.raises(InvalidInputError, match="offset"):
        CloseUp(roi, offset=(0.0, math.nan, 0.0))
    with pytest.raises(InvalidInputError, match="color"):
        CloseUp(roi, color="not-a-color")
    with pytest.raises(InvalidInputError, match="CloseUp"):
        closeup_layers(t, [roi], device="cpu")
    assert max_closeups((1280, 720)) == 16 and max_closeups((128, 64)) == 2 and max_closeups((40, 40)) == 0


@pytest.mark.parametrize("window_size", [("1280", "720"), "ab", (1280.5, 720), (True, 720), (-64, -64), (1280,)])
def test_max_closeups_checks_its_window_size(window_size):
    # text and a fraction were cut to whole pixels (16), True read as 1 pixel, (-64, -64) held one close-up,
    # "ab" and (1280,) raised a bare ValueError: the window is checked as render_closeups checks it
    with pytest.raises(InvalidInputError, match=r"window_size must be two positive whole numbers \(width, height\); "
                                                rf"got {re.escape(repr(window_size))}"):
        max_closeups(window_size)
    assert max_closeups((np.int64(1280), 720.0)) == 16


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda roi: CloseUp(roi, scale="2"), r"close-up scale must be a finite number or \(sx, sy, sz\); got '2'"),
        (lambda roi: CloseUp(roi, scale=["2", "2", "2"]), r"close-up scale must be .*; got \['2', '2', '2'\]"),
        (lambda roi: CloseUp(roi, scale=True), r"close-up scale must be .*; got True"),
        (lambda roi: CloseUp(roi, scale=[True, True, True]), r"close-up scale must be .*; got \[True, True, True\]"),
        (lambda roi: CloseUp(roi, rotation=("0", "1")), r"close-up rotation must be finite \(α, β\) in radians"),
        (lambda roi: CloseUp(roi, offset=("0", "0", "1")), r"close-up offset must be finite \(dx, dy, dz\)"),
        (lambda roi: CloseUp(roi, offset=np.array([True, False, True])), r"close-up offset must be finite"),
        (lambda roi: CloseUp(roi, billboard_view=("1", "1")), r"billboard_view must be finite \(azimuth, elevation\)"),
        (lambda roi: CloseUp(roi, spin=("1", "2")), r"close-up spin must be \(turns per second, whole repetitions\)"),
        (lambda roi: CloseUp(roi, gamma="0.5"), r"close-up gamma must lie in \[0, 1\]; got '0.5'"),
        (lambda roi: CloseUp(roi, gamma=True), r"close-up gamma must lie in \[0, 1\]; got True"),
        (lambda roi: CloseUp(roi, gamma=[0.5]), r"close-up gamma must lie in \[0, 1\]; got \[0.5\]"),
        (lambda roi: roi.factor([["1", "2"]]), r"ROI factor points must be \(N, 2\) numbers"),
        (lambda roi: transfer_function(["0", "1"]), r"anchor transparency table must hold opacities in \[0, 1\]"),
        (lambda roi: transfer_function([True, False]), r"anchor transparency table must hold opacities in \[0, 1\]"),
        (lambda roi: ROI.height_band(hills(), 0.0, 50.0, region=("0", "20", "0", "20")),
         r"region must be \(xmin, xmax, ymin, ymax\); got \('0', '20', '0', '20'\)"),
        (lambda roi: ROI.height_band(hills(), 0.0, 50.0, region=(False, True, False, True)),
         r"region must be \(xmin, xmax, ymin, ymax\); got \(False, True, False, True\)"),
    ],
)
def test_numbers_given_as_text_or_bools_are_refused_in_closeups(build, match):
    # np.asarray(..., dtype=float) read "2" as 2.0 and True as 1.0: CloseUp(scale="2") drew a close-up at scale 2,
    # gamma="0.5" was kept as text (float() took it later), a region (False, True, ...) was x in [0, 1]; the rest
    # of the library refuses numbers given as text (as_number, real_numbers)
    with pytest.raises(InvalidInputError, match=match):
        build(ROI.circle((20.0, 16.0), 6.0))


def test_numpy_numbers_stay_numbers_in_closeups():
    roi = ROI.circle((20.0, 16.0), 6.0)
    cu = CloseUp(roi, scale=np.float32(2.0), offset=np.array([0, 0, 3], np.int16), gamma=np.float64(0.5),
                 spin=(np.float32(0.5), np.int64(2)))
    assert cu.scale == (2.0, 2.0, 2.0) and cu.offset == (0.0, 0.0, 3.0) and cu.spin == (0.5, 2)
    assert cu.gamma == 0.5 and type(cu.gamma) is float
    np.testing.assert_allclose(transfer_function(np.array([0, 1], np.uint8)), [0.0, 1.0])
    assert ROI.height_band(hills(), 0.0, 100.0, region=np.array([0.0, 20.0, 0.0, 20.0])).size == (20.0, 20.0)


def test_closeup_lengths_are_checked_as_finite_numbers():
    """The private _positive check duplicated terrain.finite_number; its one-sided form (>= 0) raised a bare
    TypeError formatting the missing upper bound, and an int beyond float64 a bare OverflowError."""
    with pytest.raises(InvalidInputError, match="ROI radius must be finite; got an integer too large for a float"):
        ROI.circle((0.0, 0.0), 10**400)
    with pytest.raises(InvalidInputError, match="ROI radius must be positive; got 0"):
        ROI.circle((0.0, 0.0), 0)
    with pytest.raises(InvalidInputError, match="edge_width must be >= 0; got -1"):
        ROI.circle((0.0, 0.0), 1.0, edge_width=-1)
    with pytest.raises(InvalidInputError, match="corner_radius must be a number; got '1'"):
        ROI.rounded_rectangle((0.0, 0.0), (4.0, 4.0), corner_radius="1")
    with pytest.raises(InvalidInputError, match="edge must be finite; got nan"):
        ROI.height_band(hills(), 0.0, 1.0, edge=math.nan)
    with pytest.raises(InvalidInputError, match="close-up stepped interval must be positive; got -2"):
        CloseUp(ROI.circle((0.0, 0.0), 1.0), stepped=-2)
    with pytest.raises(InvalidInputError, match="height band low must be a finite number; got 10000"):
        ROI.height_band(hills(), 10**400, 1.0)  # the messages pinned above stay as they were
    assert ROI.circle((0.0, 0.0), 1.0, edge_width=0).mask.max() == 1.0



@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((("1", "2"), 0.0, 0.0, 0.0, 1.0, (0, 0, 0)), r"center must be a pair of numbers \(x, y\); got \('1', '2'\)"),
        (((math.nan, 2.0), 0.0, 0.0, 0.0, 1.0, (0, 0, 0)), r"center must be a pair of finite numbers \(x, y\)"),
        (((1.0, 2.0, 3.0), 0.0, 0.0, 0.0, 1.0, (0, 0, 0)), r"center must be a pair of finite numbers \(x, y\); got "
                                                         r"\(1.0, 2.0, 3.0\)"),
        (((1.0, 2.0), "3", 0.0, 0.0, 1.0, (0, 0, 0)), r"pivot_z must be a number; got '3'"),
        (((1.0, 2.0), math.nan, 0.0, 0.0, 1.0, (0, 0, 0)), r"pivot_z must be finite; got nan"),
        (((1.0, 2.0), 0.0, "0", 0.0, 1.0, (0, 0, 0)), r"alpha must be a number; got '0'"),
        (((1.0, 2.0), 0.0, math.inf, 0.0, 1.0, (0, 0, 0)), r"alpha must be finite; got inf"),
        (((1.0, 2.0), 0.0, 0.0, True, 1.0, (0, 0, 0)), r"beta must be a number; got True"),
        (((1.0, 2.0), 0.0, 0.0, 0.0, "2", (0, 0, 0)), r"scale must be a finite number or \(sx, sy, sz\); got '2'"),
        (((1.0, 2.0), 0.0, 0.0, 0.0, (1.0, 2.0), (0, 0, 0)), r"scale must be .*; got \(1.0, 2.0\)"),
        (((1.0, 2.0), 0.0, 0.0, 0.0, (1.0, math.nan, 1.0), (0, 0, 0)), r"scale must be .*; got \(1.0, nan, 1.0\)"),
        (((1.0, 2.0), 0.0, 0.0, 0.0, 1.0, ("0", 0, 0)), r"offset must be finite \(dx, dy, dz\); got \('0', 0, 0\)"),
        (((1.0, 2.0), 0.0, 0.0, 0.0, 1.0, (0, 0)), r"offset must be finite \(dx, dy, dz\); got \(0, 0\)"),
        (((1.0, 2.0), 0.0, 0.0, 0.0, 1.0, (math.nan, 0, 0)), r"offset must be finite .*; got \(nan, 0, 0\)"),
    ],
)
def test_closeup_matrix_names_its_bad_arguments(args, match):
    # closeup_matrix checked nothing: text ("1", "2") became numbers, NaN gave a NaN matrix, True a turn of one
    # radian, and a wrong length raised Python's unpacking or numpy's broadcasting ValueError
    with pytest.raises(InvalidInputError, match=match):
        closeup_matrix(*args)
    m = closeup_matrix(np.array([10, 20], np.int32), np.float32(5.0), np.float64(0.0), 0, np.float32(2.0), [1, 2, 3])
    np.testing.assert_allclose(m, closeup_matrix((10.0, 20.0), 5.0, 0.0, 0.0, (2.0, 2.0, 2.0), (1.0, 2.0, 3.0)))

def test_a_kept_cull_gives_the_layers_and_anchors_of_a_fresh_one(device):
    """The cull by ROI, the outline on the terrain and the fence faces do not depend on M: calls with the same
    ROIs keep them and only apply M; the layers and strips equal those of new ROI objects, bit for bit."""
    from dataclasses import replace

    t = Terrain.from_heights(hills(), spacing=(2.0, -2.0), origin=(500.0, 800.0))
    cus = [CloseUp(ROI.circle((540.0, 770.0), 15.0), scale=2.0, offset=(0.0, 0.0, 60.0), spin=(0.2, 5)),
           CloseUp(ROI.rounded_rectangle((520.0, 750.0), (20.0, 14.0)), rotation=(0.2, -0.4), scale=(1.0, 1.5, 0.0),
                   offset=(-10.0, 5.0, 40.0), anchor=AnchorStyle("ends", band=True))]
    closeup_layers(t, cus, device=device)
    anchor_strips(t, cus, device=device)
    for time in (0.0, 0.7, 2.3):
        kept = closeup_layers(t, cus, time=time, device=device)
        kept_strips = anchor_strips(t, cus, time=time, device=device)
        fresh_cus = [replace(cu, roi=replace(cu.roi)) for cu in cus]
        fresh = closeup_layers(t, fresh_cus, time=time, device=device)
        fresh_strips = anchor_strips(t, fresh_cus, time=time, device=device)
        for a, b in zip(kept, fresh, strict=True):
            for name in ("vertices", "faces", "mask_factor", "original", "source_faces", "matrix"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
            assert not a.faces.flags.writeable and not a.mask_factor.flags.writeable  # shared between frames
        for a, b in zip(kept_strips, fresh_strips, strict=True):
            for name in ("vertices", "faces", "distance", "opacity"):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
            assert a.max_length == b.max_length
    assert np.abs(kept[0].vertices - closeup_layers(t, cus, time=0.0, device=device)[0].vertices).max() > 1.0


def test_roi_keeps_its_own_mask(device):
    """A float32 mask array is copied: writing into the caller's buffer later (a painting canvas) changes
    neither the ROI nor the cull kept for it, and the caller's array stays writable."""
    t = Terrain.from_heights(hills(21, 21))
    canvas = np.zeros((2, 9, 9), np.float32)
    canvas[0, 2:7, 2:7] = 1.0
    roi = ROI((10.0, 10.0), (8.0, 8.0), canvas[0])
    cu = CloseUp(roi, offset=(0.0, 0.0, 5.0))
    (before,) = closeup_layers(t, [cu], device=device)
    canvas[0] = 0.0
    assert roi.mask.max() == 1.0
    (after,) = closeup_layers(t, [cu], device=device)
    (fresh,) = closeup_layers(t, [CloseUp(ROI((10.0, 10.0), (8.0, 8.0), np.pad(np.ones((5, 5)), 2)),
                                          offset=(0.0, 0.0, 5.0))], device=device)
    assert len(before.faces) > 0
    np.testing.assert_array_equal(after.faces, fresh.faces)
    np.testing.assert_array_equal(after.vertices, fresh.vertices)
    mine = np.ones((5, 5), np.float32)
    ROI((0.0, 0.0), (1.0, 1.0), mine)
    mine[0, 0] = 0.5  # still the caller's, writable


def test_memory_budget_is_checked_and_named():
    t = Terrain.from_heights(hills(), spacing=(1.0, 1.0))
    cu = CloseUp(ROI.circle((10.0, 10.0), 8.0), offset=(0, 0, 30.0))
    with pytest.raises(InvalidInputError, match="memory_budget must be a positive int of bytes; got -5"):
        closeup_layers(t, [cu], memory_budget=-5, device="cpu")
    with pytest.raises(OutputTooLargeError, match="close-up geometry would need .* smaller ROIs or fewer close-ups"):
        closeup_layers(t, [cu], memory_budget=100, device="cpu")



def test_closeup_options_are_keyword_only():
    roi = ROI.circle((10.0, 10.0), 8.0)
    with pytest.raises(TypeError):
        CloseUp(roi, (0.1, 0.2))  # rotation by position
    assert CloseUp(roi, rotation=(0.1, 0.2)).rotation == (0.1, 0.2)


@pytest.mark.parametrize("time", [float("nan"), "soon", None])
def test_a_time_that_is_not_a_number_is_refused(time):
    # time=nan gave spinning close-ups (layers and anchors) NaN vertices; a string raised a bare ValueError
    cu = CloseUp(ROI.circle((20.0, 16.0), 6.0), offset=(0.0, 0.0, 30.0), spin=(0.5, 1))
    for build in (closeup_layers, anchor_strips):
        with pytest.raises(InvalidInputError, match=rf"time must be a number of seconds \(not NaN\); got {time!r}"):
            build(hills(), [cu], time=time, device="cpu")
    assert np.isfinite(closeup_layers(hills(), [cu], time=math.inf, device="cpu")[0].vertices).all()


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda roi: CloseUp(roi, rotation="ab"), r"close-up rotation must be finite \(α, β\) in radians; got 'ab'"),
        (lambda roi: CloseUp(roi, offset="abc"), r"close-up offset must be finite \(dx, dy, dz\) metres.*; got 'abc'"),
        (lambda roi: CloseUp(roi, billboard_view="ab"),
         r"billboard_view must be finite \(azimuth, elevation\); got 'ab'"),
        (lambda roi: CloseUp(roi, gamma="a"), r"close-up gamma must lie in \[0, 1\]; got 'a'"),
        (lambda roi: CloseUp(roi, spin=(1.0, math.inf)),
         r"close-up spin must be \(turns per second, whole repetitions\)"),
        (lambda roi: AnchorStyle(outline_level="a"), r"anchor outline_level must be a number in \(0, 1\); got 'a'"),
    ],
)
def test_closeup_options_that_are_not_numbers_are_refused_by_name(build, match):
    # each raised a bare ValueError / OverflowError from float() or int()
    with pytest.raises(InvalidInputError, match=match):
        build(ROI.circle((20.0, 16.0), 6.0))


def test_more_bad_roi_and_closeup_options_are_refused_by_name():
    """Non-numbers, NaN and absurd sizes reach a named InvalidInputError, not numpy's ValueError, a MemoryError,
    a silent truncation or non-finite vertices."""
    from stepterrain.closeup import closeup_scene

    heights = hills()
    cases = [
        (lambda: ROI.circle((0, 0), 1.0, resolution="x"), "mask resolution must be a whole number"),
        (lambda: ROI.circle((0, 0), 1.0, resolution=float("nan")), "mask resolution must be a whole number"),
        (lambda: ROI.circle((0, 0), 1.0, resolution=10**6), r"mask resolution must lie in \[3, 16385\]"),
        (lambda: ROI.height_band(heights, "a", 5.0), "height band low must be a finite number"),
        (lambda: ROI.height_band(heights, 0.0, float("inf")), "height band high must be a finite number"),
        (lambda: ROI.slope_above(heights, "a"), "slope threshold must be a finite number"),
        (lambda: ROI.stepped_level(heights, 1.5, interval=1.0), "level must be a whole isovalue index"),
        (lambda: ROI.stepped_level(heights, "a", interval=1.0), "level must be a whole isovalue index"),
        (lambda: ROI.painted([[0.0, 1.0], [0.5]], (0, 0), (1, 1)), "rows of different lengths"),
        (lambda: CloseUp(ROI.circle((0, 0), 1.0), scale=1e300), "scale must be at most 1e"),
        (lambda: CloseUp(ROI.circle((0, 0), 1.0), offset=(1e300, 0, 0)), "offset must be finite"),
        (lambda: CloseUp(ROI.circle((0, 0), 1.0), cmap="nope"), "close-up cmap must name a matplotlib colormap"),
        (lambda: closeup_scene(heights, [], scalars="x"), "scalars must be None"),
    ]
    for make, message in cases:
        with pytest.raises(InvalidInputError, match=message):
            make()
    assert ROI.stepped_level(heights, np.int64(1), interval=1.0).shape == "stepped_level"  # numpy ints are fine
    assert CloseUp(ROI.circle((0, 0), 1.0), cmap="viridis", scale=1e6).cmap == "viridis"


def test_closeup_texture_is_a_private_copy():
    """CloseUp.texture was a view of the caller's RGB image: changing that array after constructing changed the
    close-up (and what it draped). It is a read-only copy now, of the RGB channels of an RGBA image too."""
    for channels in (3, 4):
        image = np.zeros((4, 5, channels), np.uint8)
        image[..., 0] = 255
        cu = CloseUp(ROI.circle((0.0, 0.0), 1.0), texture=image)
        image[..., 0], image[..., 1] = 0, 255  # the caller reuses their buffer
        assert cu.texture.shape == (4, 5, 3) and not np.shares_memory(cu.texture, image)
        assert np.all(cu.texture[..., 0] == 255) and np.all(cu.texture[..., 1] == 0)
        with pytest.raises(ValueError, match="read-only"):
            cu.texture[0, 0, 0] = 1


@pytest.mark.parametrize("base, layer, message", [
    (np.full((2, 2, 3), 300.0), None, r"base must be an \(H, W, 3\) uint8 image; got dtype float64"),
    (np.full((2, 2, 3), 100, np.int64), None, r"base must be an \(H, W, 3\) uint8 image; got dtype int64"),
    (None, (np.full((2, 2, 3), 200.0), np.full((2, 2), 2.0), 0.5), r"layer 0 alpha must lie in \[0, 1\]; got values "
                                                                     "from 2 to 2"),
    (None, (np.full((2, 2, 3), 200.0), np.full((2, 2), np.nan), 0.5), r"layer 0 alpha must lie in \[0, 1\]; got NaN"),
    (None, (np.full((2, 2, 3), 300.0), np.ones((2, 2)), 0.5), r"layer 0 color must lie in \[0, 255\]; got values "
                                                               "from 300 to 300"),
    (None, (np.full((2, 2, 3), 100.0), np.ones((2, 2)), np.nan), r"layer 0 depth must be real depths .*not NaN"),
    (None, (np.full((2, 2, 3), 100.0), np.ones((2, 2))), r"layer 0 must be \(color, alpha, depth, depth_test, "
                                                         r"writes_depth\); got 2 items"),
])
def test_composite_refuses_values_outside_their_ranges(base, layer, message):
    """composite() took any base and layer values: a float base of 300 came out 44 (cast to uint8), an alpha of 2
    doubled the colour and NaN made it black (clipped, cast), a colour of 300 was clipped, a NaN depth hid the layer,
    and a layer tuple of the wrong length raised Python's ValueError from its unpacking."""
    depth = np.ones((2, 2), np.float32)
    if base is None:
        base = np.zeros((2, 2, 3), np.uint8)
    layers = [(np.zeros((2, 2, 3)), np.zeros((2, 2)), depth, True, False)]
    if layer is not None:
        layers = [(*layer[:2], np.full((2, 2), layer[2], np.float32), True, False)] if len(layer) == 3 else [layer]
    with pytest.raises(InvalidInputError, match=message):
        composite(base, depth, layers)


def test_composite_takes_a_bool_coverage_mask_as_alpha():
    """A bool alpha (a coverage mask such as np.isfinite(depth)) composited as 0 and 1; the range check of alpha
    refused it as not real numbers. It composites as the same mask in float32 does."""
    rng = np.random.default_rng(3)
    base = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    base_depth = np.full((6, 8), np.inf, np.float32)
    depth = np.where(rng.uniform(size=(6, 8)) > 0.4, rng.uniform(0, 1, (6, 8)), np.inf).astype(np.float32)
    color = rng.uniform(0, 255, (6, 8, 3))
    mask = np.isfinite(depth)
    got = composite(base, base_depth, [(color, mask, depth, True, True)])
    np.testing.assert_array_equal(got, composite(base, base_depth, [(color, mask.astype(np.float32), depth, True,
                                                                     True)]))
    assert (got[~mask] == base[~mask]).all() and (got[mask] == np.rint(color[mask])).all()


@pytest.mark.parametrize("layer, got", [("abcde", "str"), (b"abcde", "bytes"), (5, "int"), ((1, 2), "2 items")])
def test_composite_names_what_a_malformed_layer_is(layer, got):
    """A layer of text was refused as "must be (color, alpha, depth, depth_test, writes_depth); got 5 items" for
    "abcde": five items, as asked. It names the type it got; a tuple or list its length."""
    depth = np.ones((2, 2), np.float32)
    with pytest.raises(InvalidInputError, match=rf"^layer 0 must be \(color, alpha, depth, depth_test, "
                                                rf"writes_depth\); got {got}$"):
        composite(np.zeros((2, 2, 3), np.uint8), depth, [layer])


@pytest.mark.parametrize("which, message", [
    ("base", r"^base must be an \(H, W, 3\) uint8 image; got rows of different lengths$"),
    ("base_depth", r"^base_depth must be .*; got rows of different lengths$"),
    ("color", r"^layer 0 color must be .*; got rows of different lengths$"),
    ("alpha", r"^layer 0 alpha must be .*; got rows of different lengths$"),
    ("depth", r"^layer 0 depth must be .*; got rows of different lengths$"),
])
def test_composite_names_a_ragged_image(which, message):
    """A ragged nested list as the base, its depth or a layer's colour, alpha or depth raised numpy's own ValueError
    ("setting an array element with a sequence ... inhomogeneous shape"), naming no argument. It is refused naming
    the argument; the same values as arrays still composite."""
    rng = np.random.default_rng(4)
    args = {"base": rng.integers(0, 256, (2, 2, 3), dtype=np.uint8), "base_depth": np.ones((2, 2), np.float32),
            "color": rng.uniform(0, 255, (2, 2, 3)), "alpha": rng.uniform(0, 1, (2, 2)),
            "depth": np.full((2, 2), 0.5, np.float32)}
    ragged = dict(args)
    ragged[which] = [args[which][0].tolist(), args[which][1][:1].tolist()]

    def run(a):
        return composite(a["base"], a["base_depth"], [(a["color"], a["alpha"], a["depth"], True, False)])

    with pytest.raises(InvalidInputError, match=message):
        run(ragged)
    expected = np.rint(args["alpha"][..., None] * args["color"] + (1 - args["alpha"][..., None]) * args["base"])
    np.testing.assert_allclose(run(args), expected, atol=1)
