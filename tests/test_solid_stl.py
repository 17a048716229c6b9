"""A solid written as ``.stl`` reads back watertight: STL has no indices, so readers and slicers (``trimesh.load``)
merge its corners by position, in float32 world coordinates. A solid used to be stepped from heights on a threshold
moved up by one float32 step only: a wall's top vertex then lay within float32 rounding of the node (the same height
at γ = 1), and the merged STL had degenerate faces and open edges although the indexed mesh was watertight (a 167²
crop of the embedded DEM at interval 100: 2128 coincident pairs; 0 once 0.5 m is added to every height). Found by a
bug hunt over ``stepterrain steps --solid -o x.stl``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import example, given, settings
from hypothesis import strategies as st_

import stepterrain as st
from stepterrain.export import save_mesh
from stepterrain.stepped import isovalues, thresholds_of

from .conftest import shared_file

stepped_module = st.stepped  # the module, callable as its function stepped


def _stl_round_trip(mesh: trimesh.Trimesh, path) -> trimesh.Trimesh:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # UTM coordinates: .stl's float32 moves them by centimetres (it says so)
        save_mesh(mesh, path)
    return trimesh.load(path)  # merges the corners by position, as STL readers do


def _coincident(mesh: trimesh.Trimesh) -> int:
    """Distinct vertices that float32 (STL) puts on one position."""
    _, counts = np.unique(mesh.vertices.astype(np.float32), axis=0, return_counts=True)
    return int((counts - 1).sum())


def _assert_stl_is_the_solid(mesh: trimesh.Trimesh, path) -> None:
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert _coincident(mesh) == 0
    back = _stl_round_trip(mesh, path)
    assert back.is_watertight and back.is_winding_consistent
    assert len(back.vertices) == len(mesh.vertices)
    # float32 world coordinates (3.8e6 m northings: steps of 0.25 m) move the volume by that rounding only: each
    # vertex by at most half a float32 step u, the volume by at most u times the area
    u = float(np.spacing(np.float32(np.abs(mesh.vertices).max())))
    assert back.volume == pytest.approx(mesh.volume, abs=u * mesh.area)


@pytest.fixture(scope="module")
def crop():
    dem = st.sample_dem()
    return st.Terrain.from_heights(dem.heights[:167, :167], spacing=dem.spacing, origin=dem.origin, crs=dem.crs)


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_solid_of_the_sample_dem_reads_back_watertight_from_stl(crop, gamma, tmp_path):
    assert np.isin(crop.heights, thresholds_of(isovalues(crop.height_range, interval=100.0))).any()
    mesh = st.stepped(crop, interval=100.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path / "solid.stl")


def test_solid_with_a_nodata_hole_reads_back_watertight_from_stl(crop, tmp_path):
    heights = crop.heights.copy()
    heights[60:70, 60:75] = np.nan
    holed = st.Terrain.from_heights(heights, spacing=crop.spacing, origin=crop.origin)
    mesh = st.stepped(holed, interval=100.0, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path / "holed.stl")


def test_nodes_keep_their_isovalue_and_move_at_most_a_quarter_gap(crop):
    """At γ = 1 the nodes on a threshold keep their isovalue bit for bit; the move τ stays within a quarter of the gap
    to the next threshold (the level is kept) and is what the docs say: metres at most in UTM coordinates."""
    values = isovalues(crop.height_range, interval=100.0)
    nudged = stepped_module._off_thresholds(crop, values)
    moved = nudged.heights.astype(np.float64) - crop.heights
    on = np.isin(crop.heights, thresholds_of(values))
    assert (moved[on] > 0).all() and (moved[~on] == 0).all()
    assert moved.max() <= 25.0 and moved.max() < 3.0
    snap = stepped_module.snapped_isovalue
    assert all(snap(a, values) == snap(b, values) for a, b in zip(crop.heights[on], nudged.heights[on], strict=True))


@settings(max_examples=15, deadline=None)
@given(
    rows=st_.integers(3, 9),
    cols=st_.integers(3, 9),
    seed=st_.integers(0, 2**32 - 1),
    gamma=st_.sampled_from([1.0, 0.5]),
    far=st_.sampled_from([(0.0, 0.0), (12345.0, 23456.0)]),
)
def test_integer_grids_read_back_watertight_from_stl(rows, cols, seed, gamma, far, tmp_path_factory):
    """Small integer grids with interval 2 (thresholds on odd integers: many heights on them), near the origin and
    away from it (float32 steps of 2^-9 m)."""
    rng = np.random.default_rng(seed)
    heights = rng.integers(0, 9, size=(rows, cols)).astype(np.float32)
    t = st.Terrain.from_heights(heights, spacing=(1.0, 1.0), origin=far)
    mesh = st.stepped(t, interval=2.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path_factory.mktemp("stl") / "grid.stl")


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_solid_tiles_of_one_raster_share_their_edges_walls(crop, gamma, tmp_path):
    """τ depends on a node's 8 neighbours and on the coordinates' float32 step: ``batch`` stepped each solid tile alone,
    so a node on the edge two tiles share got another τ in each (its walls along that edge crossed it elsewhere in the
    two tiles: 4 to 8 of ~75 top vertices on each shared edge of a 129² crop cut into 64² tiles; at γ < 1 the node's
    height too). A tile now moves its heights with the ring of raster nodes around it and the raster's coordinates."""
    from stepterrain.batch import batch

    heights = crop.heights[:129, :129]
    values = isovalues(crop.height_range, interval=100.0)
    assert np.isin(heights[:, 64], thresholds_of(values)).any() and np.isin(heights[64], thresholds_of(values)).any()
    raster = st.Terrain.from_heights(heights, spacing=crop.spacing, origin=crop.origin)
    batch(raster, tmp_path, tile_size=64, levels=values, gamma=gamma, solid=True, format=".ply", scheduler="serial")
    tiles = {(r, c): trimesh.load(tmp_path / f"tile_r{r}_c{c}.ply", process=False) for r in (0, 1) for c in (0, 1)}
    floor = min(float(m.vertices[:, 2].min()) for m in tiles.values())

    def on_edge(mesh: trimesh.Trimesh, axis: int, value: float) -> set[tuple[float, ...]]:
        v = np.asarray(mesh.vertices)
        return {tuple(p) for p in v[(v[:, axis] == value) & (v[:, 2] > floor)]}

    x_edge = float(tiles[0, 1].vertices[:, 0].min())
    y_edge = float(tiles[0, 0].vertices[:, 1].min())
    for a, b, axis, value in [((0, 0), (0, 1), 0, x_edge), ((1, 0), (1, 1), 0, x_edge),
                              ((0, 0), (1, 0), 1, y_edge), ((0, 1), (1, 1), 1, y_edge)]:  # fmt: skip
        shared_a, shared_b = on_edge(tiles[a], axis, value), on_edge(tiles[b], axis, value)
        assert len(shared_a) > 60 and shared_a == shared_b
    # and the whole raster's solid has those vertices too
    whole = st.stepped(raster, levels=values, gamma=gamma, solid=True)
    assert on_edge(tiles[0, 0], 0, x_edge) <= {tuple(p) for p in np.asarray(whole.vertices)}


def test_solid_tile_block_shipped_to_a_worker_carries_the_ring(crop):
    """A dask task gets only its tile's block (``_item_source``): with the ring of nodes around it, so that its τ is
    the one the whole source gives (the serial run above reads the whole source)."""
    from types import SimpleNamespace

    from stepterrain import batch as batch_module

    values = isovalues(crop.height_range, interval=100.0)
    items, src = batch_module.plan_items(crop, tile_size=64)
    src = batch_module.dataclasses.replace(src, bounds=batch_module._raster_bounds(src, crop.height_range))
    options = SimpleNamespace(interval=None, levels=values, base=0.0)
    moved = 0
    for item in items:
        block = batch_module._item_source(src, item)
        whole = batch_module._tile_off_thresholds(item, src, batch_module._item_terrain(item, src), options)
        alone = batch_module._tile_off_thresholds(item, block, batch_module._item_terrain(item, block), options)
        assert np.array_equal(whole.heights, alone.heights, equal_nan=True)
        moved += int((whole.heights != batch_module._item_terrain(item, src).heights).sum())
    assert moved > 0


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_height_on_the_last_threshold_moves_at_most_half_way_to_the_top_isovalue(gamma):
    """The last threshold has no next one: its quarter gap was unbounded, so τ grew with the drop to the lowest
    neighbour (coordinates of 4.5e6, float32 steps of 0.5 m, 6 m cells: τ = drop / 2), 525 m over a cliff 1050 m
    deep at levels 0 and 100, and the solid's top at γ = 0.5 stood at 337.5 m, its surface at 75 m."""
    heights = np.full((3, 3), -1000.0, np.float32)
    heights[1, 1] = 50.0  # the threshold between 0 and 100
    t = st.Terrain.from_heights(heights, spacing=(6.0, -6.0), origin=(500000.0, 4500000.0))
    values = np.array([0.0, 100.0], np.float32)
    moved = float(stepped_module._off_thresholds(t, values).heights[1, 1]) - 50.0
    assert 0.0 < moved <= (100.0 - 50.0) / 2
    mesh = st.stepped(t, levels=values, gamma=gamma, solid=True)
    assert mesh.is_watertight
    node = (1 - gamma) * 50.0 + gamma * 100.0  # the node's height on the surface without solid
    assert node <= mesh.vertices[:, 2].max() <= node + (1 - gamma) * moved


def _lens(terrain: st.Terrain) -> st.Lens:
    """γ 1 outside a circle over a quarter of the terrain's width, 0 inside (circular_lens's default: the original
    terrain under the lens)."""
    x0, x1, y0, y1 = terrain.extent
    return st.circular_lens(terrain, center=((x0 + x1) / 2, (y0 + y1) / 2), radius=(x1 - x0) / 4)


def _assert_stl_folds_the_flat_walls(mesh: trimesh.Trimesh, path) -> trimesh.Trimesh:
    """A solid with walls of zero height: watertight as indexed, and its .stl, which leaves those walls' triangles out
    (no area), watertight with its corners merged by position, of the same volume, holding every position the solid
    has; the solid itself is not modified by the writing."""
    assert mesh.is_watertight and mesh.is_winding_consistent
    before = mesh.faces.copy()
    back = _stl_round_trip(mesh, path)
    np.testing.assert_array_equal(mesh.faces, before)
    assert back.is_watertight and back.is_winding_consistent
    positions = np.unique(mesh.vertices.astype(np.float32), axis=0)
    assert len(back.vertices) == len(positions)
    u = float(np.spacing(np.float32(np.abs(mesh.vertices).max())))
    assert back.volume == pytest.approx(mesh.volume, abs=u * mesh.area)
    return back


@pytest.mark.parametrize("gamma", [0.0, "lens", 1e-9])
def test_solid_with_walls_of_zero_height_reads_back_watertight_from_stl(crop, gamma, tmp_path):
    """Where γ = 0 (the whole terrain, or inside a lens) a wall's bottom and top lie on one position: the indexed solid
    is watertight, but its .stl merged them (a 167² crop at interval 100 and γ = 0: 11 k pairs; edges used by four
    faces, and faces of no area; at a lens's edge, where one end of a wall has zero height, single faces of no area).
    save_mesh leaves the triangles with two corners on one float32 position out of an .stl. A γ of 1e-9 blends a
    wall's ends onto one float32 height too (γ times the gap is under a float32 step of the heights)."""
    gamma = _lens(crop) if gamma == "lens" else gamma
    mesh = st.stepped(crop, interval=100.0, gamma=gamma, solid=True)
    assert _coincident(mesh) > 1000  # the walls of zero height, kept in the indexed solid (its colours stay sharp)
    back = _assert_stl_folds_the_flat_walls(mesh, tmp_path / "flat.stl")
    corners = mesh.vertices.astype(np.float32)[mesh.faces]
    point = ((corners[:, 0] == corners[:, 1]).all(1) | (corners[:, 1] == corners[:, 2]).all(1)
             | (corners[:, 2] == corners[:, 0]).all(1))
    assert len(back.faces) == len(mesh.faces) - point.sum()


@settings(max_examples=25, deadline=None)
@given(
    rows=st_.integers(3, 9),
    cols=st_.integers(3, 9),
    seed=st_.integers(0, 2**32 - 1),
    gamma=st_.sampled_from(["zero", "lens", "nodes"]),
    hole=st_.booleans(),
    tin=st_.booleans(),
)
def test_walls_of_zero_height_on_small_grids_read_back_watertight(rows, cols, seed, gamma, hole, tin,
                                                                   tmp_path_factory):
    """Small integer grids (heights on the thresholds, nudged) at γ = 0, under a lens (γ 0 inside, 1 outside: walls
    with one end of zero height at its edge) and with γ per node, some 0 (a wall has zero height only where both its
    edge's ends have γ = 0), with a nodata node and as a TIN, far from the origin: watertight from .stl."""
    rng = np.random.default_rng(seed)
    heights = rng.integers(0, 9, size=(rows, cols)).astype(np.float32)
    if hole:
        heights[rng.integers(rows), rng.integers(cols)] = np.nan
    t = st.Terrain.from_heights(heights, spacing=(1.0, 1.0), origin=(12345.0, 23456.0))
    terrain = st.Terrain.from_mesh(t.mesh()) if tin else t
    if gamma == "lens":
        gamma = _lens(t)
    elif gamma == "nodes":
        gamma = np.where(rng.random(terrain.shape) < 0.6, 0.0, rng.random(terrain.shape))
    else:
        gamma = 0.0
    values = isovalues(t.height_range, interval=2.0)
    if not np.isfinite(heights).sum() or len(st.stepped(terrain, levels=values, gamma=gamma).faces) == 0:
        return
    mesh = st.stepped(terrain, levels=values, gamma=gamma, solid=True)
    _assert_stl_folds_the_flat_walls(mesh, tmp_path_factory.mktemp("stl") / "grid.stl")


def test_stl_leaves_out_triangles_with_two_corners_on_one_float32_position(tmp_path):
    """Two distinct vertices on one position (and one index twice) make triangles of no area: left out of the .stl,
    the others written as they are; the mesh is not modified."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [1 + 1e-9, 0, 0]], float)  # 4 rounds onto 1
    faces = np.array([[0, 1, 2], [1, 3, 2], [0, 4, 1], [2, 2, 0], [0, 1, 4]])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    save_mesh(mesh, tmp_path / "m.stl")
    back = trimesh.load(tmp_path / "m.stl", process=False)
    assert len(back.faces) == 1
    np.testing.assert_array_equal(back.vertices[back.faces[0]], vertices[[0, 1, 2]])
    assert len(mesh.faces) == 5


def _pinched(heights: np.ndarray, at: tuple[int, int], size: int = 6) -> np.ndarray:
    """``heights`` with two nodata blocks whose cells touch at node ``at`` only (diagonally): a pinch there."""
    r, c = at
    out = heights.copy()
    out[r - size:r, c - size:c] = np.nan  # nodes: the cells with a NaN corner are left out, up to node r - 1 + 1
    out[r + 1:r + 1 + size, c + 1:c + 1 + size] = np.nan
    return out


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_solid_with_nodata_holes_touching_at_a_node_reads_back_watertight_from_stl(crop, gamma, tmp_path):
    """Two nodata holes whose cells meet at one node (SRTM voids touch diagonally): the indexed solid has a copy of the
    node per side, but the copies and their skirt columns lay on one position, and the .stl (corners merged by
    position) had a vertical skirt edge of 4 faces. Each copy now moves a few float32 steps into its own cell."""
    heights = _pinched(crop.heights, (80, 80))
    heights[np.random.default_rng(3).random(heights.shape) < 0.03] = np.nan  # random void nodes: more pinches
    holed = st.Terrain.from_heights(heights, spacing=crop.spacing, origin=crop.origin)
    values = isovalues(holed.height_range, interval=100.0)
    mesh = st.stepped(holed, levels=values, gamma=gamma, solid=True)
    floor = float(mesh.vertices[:, 2].min())
    surface = st.stepped(stepped_module._off_thresholds(holed, values), levels=values, gamma=gamma)
    copies = len(mesh.vertices) - len(surface.vertices) - int((mesh.vertices[:, 2] == floor).sum())
    assert copies > 10
    _assert_stl_is_the_solid(mesh, tmp_path / "pinched.stl")
    # the volume is the surface's integral over the domain (signed xy area times mean height above the floor) but
    # for the copies' moves: each moves its cell's corner by d = 2 u in x and y, which changes the integral by at
    # most |d| times its fan's outline (under 4 cell sides) times the height above the floor
    v = np.asarray(surface.vertices)[np.asarray(surface.faces)]
    area = 0.5 * ((v[:, 1, 0] - v[:, 0, 0]) * (v[:, 2, 1] - v[:, 0, 1])
                  - (v[:, 2, 0] - v[:, 0, 0]) * (v[:, 1, 1] - v[:, 0, 1]))
    integral = float((area * (v[:, :, 2].mean(axis=1) - floor)).sum())
    u = float(np.spacing(np.float32(np.abs(mesh.vertices[:, :2]).max())))
    bound = copies * 2 * np.sqrt(2) * u * 4 * max(crop.spacing) * (float(mesh.vertices[:, 2].max()) - floor)
    assert abs(mesh.volume - integral) <= bound
    assert bound < 1e-3 * mesh.volume  # UTM coordinates: u = 0.5 m, the moves ~1 m; near the origin far less


@settings(max_examples=25, deadline=None)
@given(
    rows=st_.integers(4, 10),
    cols=st_.integers(4, 10),
    seed=st_.integers(0, 2**32 - 1),
    gamma=st_.sampled_from([1.0, 0.5]),
    far=st_.sampled_from([(0.0, 0.0), (12345.0, 23456.0)]),
)
def test_small_grids_with_random_nodata_read_back_watertight_from_stl(rows, cols, seed, gamma, far,
                                                                      tmp_path_factory):
    """Small integer grids with random nodata nodes (pinches wherever two void regions touch at a node), near the
    origin and away from it: the indexed solid and its .stl are watertight and consistently wound."""
    rng = np.random.default_rng(seed)
    heights = rng.integers(0, 9, size=(rows, cols)).astype(np.float32)
    heights[rng.random((rows, cols)) < 0.2] = np.nan
    t = st.Terrain.from_heights(heights, spacing=(1.0, 1.0), origin=far)
    if not len(st.stepped(t, interval=2.0).faces):
        return
    mesh = st.stepped(t, interval=2.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path_factory.mktemp("stl") / "holed.stl")


def test_solid_tiles_share_their_edge_walls_where_holes_touch_on_the_edge(crop, tmp_path):
    """Nodata holes touching at a node on the edge two tiles share (a pinch of the raster, none of either tile: each
    has one or two cells there) and inside a tile: the tiles' edge vertices are the same, each tile's .stl is
    watertight and the whole raster's solid has the edge's vertices too."""
    from stepterrain.batch import batch

    heights = _pinched(_pinched(crop.heights[:129, :129], (40, 64)), (100, 30))
    values = isovalues(crop.height_range, interval=100.0)
    raster = st.Terrain.from_heights(heights, spacing=crop.spacing, origin=crop.origin)
    batch(raster, tmp_path, tile_size=64, levels=values, solid=True, format=".ply", scheduler="serial")
    tiles = {(r, c): trimesh.load(tmp_path / f"tile_r{r}_c{c}.ply", process=False) for r in (0, 1) for c in (0, 1)}
    floor = min(float(m.vertices[:, 2].min()) for m in tiles.values())
    x_edge = float(tiles[0, 1].vertices[:, 0].min())

    y_pinch = crop.origin[1] + 40 * crop.spacing[1]

    def on_edge(mesh: trimesh.Trimesh, away: bool = False) -> set[tuple[float, ...]]:
        v = np.asarray(mesh.vertices)  # away: from the holes' rows (a hole beside the edge in one tile only)
        near = np.abs(v[:, 1] - y_pinch) <= 8 * abs(crop.spacing[1])
        return {tuple(p) for p in v[(v[:, 0] == x_edge) & (v[:, 2] > floor) & ~(away & near)]}

    for (r, c), tile in tiles.items():
        _assert_stl_is_the_solid(tile, tmp_path / f"tile_{r}_{c}.stl")
    assert len(on_edge(tiles[0, 0], True)) > 40 and on_edge(tiles[0, 0], True) == on_edge(tiles[0, 1], True)
    assert on_edge(tiles[1, 0]) == on_edge(tiles[1, 1])
    whole = st.stepped(raster, levels=values, solid=True)
    _assert_stl_is_the_solid(whole, tmp_path / "whole.stl")
    assert on_edge(tiles[0, 0]) <= {tuple(p) for p in np.asarray(whole.vertices)}


def _xy_areas(mesh: trimesh.Trimesh) -> np.ndarray:
    v = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    return ((v[:, 1, 0] - v[:, 0, 0]) * (v[:, 2, 1] - v[:, 0, 1])
            - (v[:, 2, 0] - v[:, 0, 0]) * (v[:, 1, 1] - v[:, 0, 1]))


@pytest.mark.parametrize("spacing", [1.0, 0.5])
def test_pinch_copy_does_not_leave_its_cell_on_a_fine_grid_at_utm_coordinates(spacing):
    """A 1 m (LiDAR) grid at UTM northings: 2 float32 steps are 1 m there, and the copy moved onto the far corner of
    its cell (a triangle of no area, half the volume) or past it (0.5 m: the triangle turned over, no volume). A move
    that would turn or flatten a face of its fan is not made: the copy stays on the node, as before."""
    nan = np.nan
    bowtie = np.array([[0.25, 0.25, nan], [nan, 0.25, nan], [nan, 0.25, 0.25]])
    t = st.Terrain.from_heights(bowtie, spacing=(spacing, spacing), origin=(500000.0, 5000000.0))
    surface = st.stepped(t, interval=1.0)
    mesh = st.stepped(t, interval=1.0, solid=True, floor=-1.0)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(spacing**2, rel=1e-9)  # two right triangles of side s, terraces 1 high
    top = np.asarray(mesh.vertices)[:, 2] > -1.0
    up = top[np.asarray(mesh.faces)].all(axis=1)
    assert (np.sign(_xy_areas(mesh)[up]) == np.sign(_xy_areas(surface)[0])).all()


def test_pinch_copy_of_a_tin_fan_stays_out_of_the_other_fan():
    """A TIN whose thin fan lies between 0° and -5.7° of the pinch vertex: its faces' mean direction has signs (+, -),
    the -45° diagonal, which runs into the other fan (between -38.7° and -50.2°): the copy landed inside the other
    fan's triangle (the solid intersected itself). Such a diagonal move is refused; the copy moves along its fan's
    mean direction (-2.9°, the larger component 2 u) instead, strictly inside its own fan's triangle, out of the
    other's. It used to stay on the vertex (the mean direction was tried only within 1e-3 rad of the angle), the
    volume then exactly 25; the move, 2 u along x, takes u off the thin triangle's area: the volume is 25 within
    the documented bound, 2√2 u times the fan's outline times its height (1), as for every moved copy."""
    from stepterrain.mesh import close_solid

    vertices = np.array([[0, 0, 1], [10, -12, 1], [10, -8, 1], [10, -1, 1], [10, 0, 1]], np.float64)
    faces = np.array([[0, 1, 2], [0, 3, 4]])  # both counter-clockwise; the first fan keeps vertex 0
    out_vertices, out_faces, _, _, _ = close_solid(vertices, faces, np.ones(2, bool), floor=0.0)
    mesh = trimesh.Trimesh(out_vertices, out_faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    a, b, c = vertices[faces[0], :2]

    def cross(q: np.ndarray, r: np.ndarray) -> float:
        return float(q[0] * r[1] - q[1] * r[0])

    for p in out_vertices[:, :2]:  # none strictly inside the first fan's triangle
        assert not (cross(b - a, p - a) > 0 and cross(c - b, p - b) > 0 and cross(a - c, p - c) > 0)
    copy = out_faces[1, 0]  # the second fan's copy of vertex 0: strictly inside its own fan's triangle
    assert copy == len(vertices)
    p, (a, b, c) = out_vertices[copy, :2], vertices[faces[1], :2]
    assert cross(b - a, p - a) > 0 and cross(c - b, p - b) > 0 and cross(a - c, p - c) > 0
    assert len(np.unique(out_vertices[out_vertices[:, 2] > 0].astype(np.float32), axis=0)) == 6  # apart in float32
    u = float(np.spacing(np.float32(12.0)))
    outline = np.hypot(10, 1) + 10 + 1
    assert mesh.volume == pytest.approx(20 + 5, abs=2 * np.sqrt(2) * u * outline * 1.0)  # the triangles' areas, 1 high


def _xy2(v: np.ndarray) -> np.ndarray:
    """Twice the signed xy areas of triangles ``v`` (n, 3, >= 2)."""
    return ((v[:, 1, 0] - v[:, 0, 0]) * (v[:, 2, 1] - v[:, 0, 1])
            - (v[:, 2, 0] - v[:, 0, 0]) * (v[:, 1, 1] - v[:, 0, 1]))


@settings(max_examples=30, deadline=None)
@example(rows=8, cols=8, seed=8, spacing=0.5, origin=(5e5, 5e6), gamma=1.0, tin=True)  # into another face: see below
@example(rows=7, cols=4, seed=4, spacing=0.5, origin=(0.0, 0.0), gamma=1.0, tin=True)
@given(
    rows=st_.integers(4, 9),
    cols=st_.integers(4, 9),
    seed=st_.integers(0, 2**32 - 1),
    spacing=st_.one_of(st_.sampled_from([0.5, 1.0]), st_.floats(0.5, 30.0)),  # 2 u is 1 m at UTM northings
    origin=st_.sampled_from([(0.0, 0.0), (5e5, 5e6)]),
    gamma=st_.sampled_from([1.0, 0.5, 0.0]),
    tin=st_.booleans(),
)
def test_moved_pinch_copies_keep_their_faces_and_stay_out_of_others(rows, cols, seed, spacing, origin, gamma, tin,
                                                                     tmp_path_factory):
    """Random small grids and TINs (jittered nodes, Delaunay) with random nodata, spacings 0.5 to 30 m, near the origin
    and at UTM coordinates: every face of a moved copy's fan faces as it did with the copy on its node, in float64
    and float32, and is not flat (a moved copy turned none over or flat), no moved copy lies inside another terrace
    face's xy triangle, the solid is watertight and consistently wound, and where every copy moved its .stl reads
    back watertight. The examples: a thin TIN fan whose faces' mean direction has signs pointing out of it, past the
    other fans, into a face not at the node (UTM: 2 u is 1 m); the copy moved there (the solid intersected itself).
    A copy now moves only into its own fan's angle. And a TIN fan holding a sliver that stepping left facing down by
    a hair (xy area -6e-8) with its copy on the node: the copy moves along its fan's mean direction, the sliver
    still faces down (the guard keeps each face's sign; it does not make it face up)."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(seed)
    heights = rng.integers(0, 9, size=(rows, cols)).astype(np.float64)
    heights[rng.random((rows, cols)) < 0.25] = np.nan
    if tin:
        yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64)
        xy = np.column_stack([xx.ravel(), yy.ravel()]) + rng.uniform(-0.3, 0.3, (rows * cols, 2))
        points = np.column_stack([origin[0] + spacing * xy[:, 0], origin[1] + spacing * xy[:, 1], heights.ravel()])
        faces = Delaunay(xy).simplices
        faces = faces[np.isfinite(heights.ravel()[faces]).all(axis=1)]
        if not len(faces):
            return
        try:
            terrain = st.Terrain.from_mesh(trimesh.Trimesh(points, faces, process=False))
        except st.errors.StepTerrainError:
            return
    else:
        terrain = st.Terrain.from_heights(heights.astype(np.float32), spacing=(spacing, spacing), origin=origin)
    from unittest import mock

    import stepterrain.mesh as mesh_module

    split = mesh_module._split_pinches
    seen = []

    def recording(*args):  # the copies _split_pinches appends, and the nodes they copy
        out = split(*args)
        seen.append((out[0][len(args[0]):], out[0][out[3]]))
        return out

    with warnings.catch_warnings(), mock.patch.object(mesh_module, "_split_pinches", recording):
        warnings.simplefilter("ignore")
        if not len(st.stepped(terrain, interval=2.0, gamma=gamma).faces):
            return
        mesh = st.stepped(terrain, interval=2.0, gamma=gamma, solid=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    floor = float(vertices[:, 2].min())
    top = (vertices[faces, 2] > floor).all(axis=1)
    terraces = faces[top][_xy2(vertices[faces[top]]) > 0]
    added, nodes = seen[-1]
    shifted = (added[:, :2] != nodes[:, :2]).any(axis=1)
    up = np.flatnonzero(vertices[:, 2] > floor)
    moved = up[(vertices[up, None, :] == added[None, shifted]).all(axis=2).any(axis=1)]
    assert len(moved) >= shifted.sum()
    fan = faces[top][np.isin(faces[top], moved).any(axis=1)]  # the moved copies' faces, but walls (vertical edges)
    xy = vertices[fan, :2]
    fan = fan[~((xy[:, 0] == xy[:, 1]).all(axis=1) | (xy[:, 1] == xy[:, 2]).all(axis=1)
                | (xy[:, 2] == xy[:, 0]).all(axis=1))]
    # each face of a moved copy's fan faces the way it faced with the copy on its node (up, but for a TIN's sliver
    # that stepping left a hair under zero area, which stays as it was), in float64 and float32, and is not flat
    before = vertices.copy()
    for m in moved:
        before[m, :2] = nodes[shifted][(added[shifted] == vertices[m]).all(axis=1)][0, :2]
    side = np.sign(_xy2(before[fan]))
    assert (side != 0).all() and (np.sign(_xy2(vertices[fan])) == side).all()
    assert (np.sign(_xy2(vertices.astype(np.float32).astype(np.float64)[fan])) == side).all()
    for m in moved:
        p = vertices[m, :2]
        others = terraces[~(terraces == m).any(axis=1)]
        t = vertices[others, :2]
        inside = ((_xy2(np.stack([t[:, 0], t[:, 1], np.broadcast_to(p, t[:, 0].shape)], axis=1)) > 0)
                  & (_xy2(np.stack([t[:, 1], t[:, 2], np.broadcast_to(p, t[:, 0].shape)], axis=1)) > 0)
                  & (_xy2(np.stack([t[:, 2], t[:, 0], np.broadcast_to(p, t[:, 0].shape)], axis=1)) > 0))
        assert not inside.any(), (m, p)
    if shifted.all() and _coincident(mesh) == 0:  # (UTM: wall vertices 0.5 m apart may share a float32 position)
        back = _stl_round_trip(mesh, tmp_path_factory.mktemp("stl") / "solid.stl")
        assert back.is_watertight and back.is_winding_consistent


def _stl_warnings(mesh: trimesh.Trimesh, path) -> tuple[list[str], trimesh.Trimesh]:
    """The warnings ``save_mesh`` gives writing ``mesh`` as ``path`` (an .stl), and the file read back merged."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_mesh(mesh, path)
    return [str(w.message) for w in caught], trimesh.load(path)


_OPEN_STL = "not shared by exactly two triangles"


@pytest.mark.parametrize("origin", [(500000.0, 5000000.0), (0.0, 0.0)])
def test_stl_of_a_solid_whose_pinch_copies_stay_on_the_node_warns(origin, tmp_path):
    """Two nodata holes touching at a node of a 1 m grid (LiDAR) of the embedded DEM's heights, at UTM northings:
    the pinch copies stay on the node (their 2 float32 steps, 1 m, would leave their cells), and the .stl, corners
    merged by position, is not watertight there. It was written without a word; it now warns, naming the open edges
    and what keeps them apart. In local coordinates the copies move: no warning, and the .stl is watertight."""
    heights = _pinched(st.sample_dem().heights[:40, :40], (20, 20))
    terrain = st.Terrain.from_heights(heights, spacing=(1.0, -1.0), origin=origin)
    mesh = st.stepped(terrain, interval=20.0, solid=True)
    assert mesh.is_watertight
    messages, back = _stl_warnings(mesh, tmp_path / "pinched.stl")
    opened = [m for m in messages if _OPEN_STL in m]
    if origin == (0.0, 0.0):
        assert not opened and back.is_watertight
        assert back.volume == pytest.approx(mesh.volume, rel=1e-6)
    else:
        assert not back.is_watertight
        assert len(opened) == 1 and "pinched.stl" in opened[0] and "origin=(0, 0)" in opened[0]
        assert ".ply, .obj or .3mf" in opened[0]


def test_stl_of_a_pinch_at_whole_utm_metres_warns_alone(tmp_path):
    """The bowtie at whole metres of UTM: float32 holds every coordinate exactly (no rounding warning), but the pinch
    copy stays on its node (a 1 m cell is 2 float32 steps there): the only word the user gets is this warning."""
    nan = np.nan
    bowtie = np.array([[0.25, 0.25, nan], [nan, 0.25, nan], [nan, 0.25, 0.25]])
    t = st.Terrain.from_heights(bowtie, spacing=(1.0, 1.0), origin=(500000.0, 5000000.0))
    mesh = st.stepped(t, interval=1.0, solid=True, floor=-1.0)
    messages, back = _stl_warnings(mesh, tmp_path / "bowtie.stl")
    assert mesh.is_watertight and not back.is_watertight
    _, counts = np.unique(back.edges_sorted, axis=0, return_counts=True)  # the reader's: merged by position
    assert (counts != 2).sum() == 1  # the copy's vertical skirt edge, of four triangles
    assert len(messages) == 1 and f"1 edge {_OPEN_STL}" in messages[0]


def test_cli_stl_warnings_give_only_advice_the_command_line_can_follow(tmp_path, capsys):
    """``stepterrain steps --solid -o x.stl`` of a steep 1 m grid at UTM northings (a GeoTIFF-like .npz, EPSG:32611):
    its .stl reads back open, and the warnings said to "step the terrain in local coordinates (e.g. origin=(0, 0))"
    and to "move the mesh to a local origin first", which no option of the command line does. They now give the
    formats' advice alone, and following it works: the .3mf is watertight, its coordinates the DEM's own (UTM)."""
    from stepterrain import cli
    from stepterrain.export import _STL_OPEN_LOCAL, _STL_ROUNDING_LOCAL, read_mesh

    heights = (np.random.default_rng(0).random((8, 9)) * 30.0).astype(np.float32)
    dem = tmp_path / "steep.npz"
    np.savez(dem, elevation=heights, transform=np.array([500000.0, 1.0, 0.0, 4000008.0, 0.0, -1.0]),
             crs="EPSG:32611")
    assert cli.main(["steps", str(dem), "--interval", "2", "--solid", "-q", "-o", str(tmp_path / "x.stl")]) == 0
    err = capsys.readouterr().err
    assert not trimesh.load(tmp_path / "x.stl").is_watertight
    opened = [line for line in err.splitlines() if _OPEN_STL in line]
    rounded = [line for line in err.splitlines() if "which move this mesh's vertices" in line]
    assert len(opened) == 1 and len(rounded) == 1, err
    assert opened[0].endswith("write .ply, .obj or .3mf, which keep the indices and the float64 world coordinates")
    assert rounded[0].endswith("write .ply, .obj or .3mf to keep float64")
    assert "origin" not in err and "local coordinates" not in err
    assert cli.main(["steps", str(dem), "--interval", "2", "--solid", "-q", "-o", str(tmp_path / "x.3mf")]) == 0
    assert "warning" not in capsys.readouterr().err
    mesh = read_mesh(tmp_path / "x.3mf")
    assert mesh.is_watertight
    assert np.asarray(mesh.vertices)[:, :2].min(axis=0).tolist() == [500000.5, 4000000.5]  # the nodes: cell centres
    # a Python caller, who can step the terrain at a local origin, is still told so
    solid = st.stepped(heights, interval=2.0, solid=True, spacing=(1.0, 1.0), origin=(500000.0, 4000000.0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_mesh(solid, tmp_path / "py.stl")
    said = [str(w.message) for w in caught]
    assert len(said) == 2, said
    assert [m for m in said if _OPEN_STL in m][0].endswith(_STL_OPEN_LOCAL)
    assert [m for m in said if "which move this mesh's vertices" in m][0].endswith(_STL_ROUNDING_LOCAL)


def test_stl_of_unmerged_or_flat_walled_solids_does_not_warn(crop, tmp_path):
    """No false alarm: an unmerged mesh's corners lie on one position by design (not watertight by its indices), and
    a solid's walls of zero height (γ = 0) have top and bottom on one position, which the .stl merges watertight."""
    mesh = st.stepped(crop, interval=100.0, gamma=0.0, solid=True)
    messages, back = _stl_warnings(mesh, tmp_path / "flat.stl")
    assert back.is_watertight and not [m for m in messages if _OPEN_STL in m]
    unmerged = mesh.copy()
    unmerged.unmerge_vertices()
    messages, _ = _stl_warnings(unmerged, tmp_path / "unmerged.stl")
    assert not [m for m in messages if _OPEN_STL in m]


@settings(max_examples=20, deadline=None)
@given(
    rows=st_.integers(4, 9),
    cols=st_.integers(4, 9),
    seed=st_.integers(0, 2**32 - 1),
    spacing=st_.sampled_from([0.5, 1.0, 7.3]),
    origin=st_.sampled_from([(0.0, 0.0), (5e5, 5e6), (376328.6554542635, 3807902.8276283755)]),
    gamma=st_.sampled_from([1.0, 0.5, 0.0]),
)
def test_stl_warns_exactly_when_a_watertight_solid_reads_back_open(rows, cols, seed, spacing, origin, gamma,
                                                                   tmp_path_factory):
    """Random small grids with nodata (pinches), spacings 0.5 to 7.3 m, near the origin and at UTM coordinates, at
    γ = 1, 0.5, 0 (walls of zero height): save_mesh warns that the .stl reads back open exactly when trimesh.load,
    merging corners by position, finds it not watertight."""
    rng = np.random.default_rng(seed)
    heights = rng.integers(0, 9, size=(rows, cols)).astype(np.float32)
    heights[rng.random((rows, cols)) < 0.25] = np.nan
    t = st.Terrain.from_heights(heights, spacing=(spacing, spacing), origin=origin)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if not len(st.stepped(t, interval=2.0, gamma=gamma).faces):
            return
        mesh = st.stepped(t, interval=2.0, gamma=gamma, solid=True)
    assert mesh.is_watertight
    messages, back = _stl_warnings(mesh, tmp_path_factory.mktemp("stl") / "solid.stl")
    assert any(_OPEN_STL in m for m in messages) == (not back.is_watertight)


def test_batch_of_solid_tiles_says_once_that_their_stl_reads_back_open(tmp_path):
    """A batch of UTM solid tiles (a 1 m grid of the embedded DEM's heights, pinches in every tile) as .stl: each
    tile's file reads back open, and the batch says so once (as it does float32's rounding), not once per tile."""
    from stepterrain.batch import batch

    heights = st.sample_dem().heights[:80, :80]
    for r in (20, 60):
        for c in (20, 60):
            heights = _pinched(heights, (r, c))
    raster = st.Terrain.from_heights(heights, spacing=(1.0, -1.0), origin=(500000.0, 5000000.0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        report = batch(raster, tmp_path, tile_size=40, interval=20.0, solid=True, format=".stl", scheduler="serial")
    opened = [str(w.message) for w in caught if _OPEN_STL in str(w.message)]
    assert len(opened) == 1 and opened[0].startswith("4 of the 4 .stl outputs written read back open")
    assert all(any(_OPEN_STL in m for m in item.warnings) for item in report.results)
    assert not any(trimesh.load(tmp_path / f"tile_r{r}_c{c}.stl").is_watertight for r in (0, 1) for c in (0, 1))


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_pinch_copy_of_a_one_triangle_fan_moves_into_it_at_utm_coordinates(gamma, tmp_path):
    """Big Tujunga's SRTM (30 m, UTM) with 5 % void nodes: where voids lie north and south of a node, each side's fan
    is one grid triangle, and the copy's diagonal move runs along its diagonal edge: float64 rounding put it a hair
    outside its angle, the copy stayed on the node (13 of 477 on 300², 2 on this 150²) and the .stl read back open. It
    now moves along its fan's mean direction, strictly inside: the .stl is watertight, every face of the fan still
    faces up."""
    dem = st.load_dem(shared_file("big_tujunga_srtm_30m_utm11n.tif"))
    heights = dem.heights[:150, :150].copy()  # 4 copies of a one-triangle fan (26 at 300 x 300, 18 s a case)
    heights[np.random.default_rng(0).random(heights.shape) < 0.05] = np.nan
    holed = st.Terrain.from_heights(heights, spacing=dem.spacing, origin=dem.origin)
    mesh = st.stepped(holed, interval=50.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path / "voids.stl")
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    top = (vertices[faces, 2] > float(vertices[:, 2].min())).all(axis=1)
    xy = _xy2(vertices[faces[top]])
    assert (xy >= 0).all()  # terraces face up (walls: 0); none turned over


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_pinch_copies_on_non_square_cells_move_into_their_fans(gamma, tmp_path):
    """The Front Range's SRTM 3" (equirectangular local metres, cells about 71 x 93 m) with 5 % void nodes: on
    non-square cells a copy's diagonal move misses a one-triangle fan's angle by degrees, not by a hair; the mean
    direction was tried only under 1e-3 rad, so copies stayed on their nodes (218 distinct vertices on
    one float32 position) and the .stl read back open. Any copy whose diagonal move is refused now tries its fan's
    mean direction, under the same guards: none stays, the .stl is the solid, the terraces still face up and the
    volume is the surface's integral within 2√2 u times each copy's fan outline times its height."""
    dem = st.load_dem(shared_file("front_range_srtmgl3_3arcsec.tif"))
    assert abs(dem.spacing[0]) != abs(dem.spacing[1])
    heights = dem.heights[:120, :120].copy()
    heights[np.random.default_rng(0).random(heights.shape) < 0.05] = np.nan
    holed = st.Terrain.from_heights(heights, spacing=dem.spacing, origin=dem.origin)
    surface = st.stepped(holed, interval=50.0, gamma=gamma)
    mesh = st.stepped(holed, interval=50.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path / "voids.stl")
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    floor = float(vertices[:, 2].min())
    top = (vertices[faces, 2] > floor).all(axis=1)
    assert (_xy2(vertices[faces[top]]) >= 0).all()  # terraces face up (walls: 0); none turned over
    copies = len(vertices) - len(surface.vertices) - int((vertices[:, 2] == floor).sum())
    assert copies > 20
    v = np.asarray(surface.vertices)[np.asarray(surface.faces)]
    integral = float((0.5 * _xy2(v) * (v[:, :, 2].mean(axis=1) - floor)).sum())
    u = float(np.spacing(np.float32(np.abs(vertices[:, :2]).max())))
    bound = copies * 2 * np.sqrt(2) * u * 4 * max(np.abs(dem.spacing)) * (float(vertices[:, 2].max()) - floor)
    assert abs(mesh.volume - integral) <= bound
