"""Stepped terrain (paper 000): Warp against the NumPy reference, and the geometry's invariants."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import assume, given, settings
from hypothesis import strategies as st_
from hypothesis.extra.numpy import arrays
from stepterrain.kernels import stepped as stepped_kernels

import stepterrain as st
from stepterrain._device import launch_chunked, resolve_device
from stepterrain.stepped import _build_isovalue_struct, blend, isovalues, step_arrays
from stepterrain.terrain import as_terrain

from .conftest import DEVICES, assert_valid_mesh, real_dem, shared_file
from .reference import grid_tin, step_reference, thresholds_of

# --------------------------------------------------------------------------------------------- helpers


def compare_with_reference(heights, values, device, spacing=(1.0, 1.0)):
    """Warp's arrays equal the reference: same vertices (matched by key), same faces in the same order."""
    t = st.Terrain.from_heights(heights, spacing=spacing)
    points, faces = grid_tin(t.heights, t.spacing)
    return _compare_terrain_with_reference(t, points, faces, values, device)


def compare_tin_with_reference(tin, values, device):
    """The same for a trimesh TIN: the reference steps the terrain's own local points and (oriented) faces."""
    t = as_terrain(tin)
    return _compare_terrain_with_reference(t, t.local_points(), t.faces, values, device)


def _compare_terrain_with_reference(t, points, faces, values, device):
    arrays = step_arrays(t, np.asarray(values, np.float32), device=resolve_device(device), want_sources=True)
    ref = step_reference(points, faces, values)
    assert arrays.vertex_count == len(ref.points)
    assert arrays.face_count == len(ref.faces)
    src = arrays.sources.numpy().astype(np.float64)
    pts = arrays.points.numpy().astype(np.float64)
    keys = np.column_stack([src, pts[:, 2], arrays.step_heights.numpy().astype(np.float64)])
    mine = np.lexsort(keys.T[::-1])
    theirs = np.lexsort(ref.keys.T[::-1])
    np.testing.assert_array_equal(keys[mine], ref.keys[theirs])
    to_mine = np.empty(len(mine), np.int64)
    to_mine[theirs] = mine  # reference vertex index -> warp vertex index
    np.testing.assert_array_equal(arrays.faces, to_mine[ref.faces])
    np.testing.assert_array_equal(arrays.face_levels, ref.face_levels)
    np.testing.assert_array_equal(arrays.face_walls, ref.face_walls)
    scale = max(1.0, float(np.abs(ref.points).max(initial=0.0)))
    np.testing.assert_allclose(pts[mine], ref.points[theirs], rtol=0, atol=1e-5 * scale)
    return arrays


def projected_area(mesh, mask=None):
    tri = mesh.triangles if mask is None else mesh.triangles[mask]
    a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def volume_under(mesh):
    return float((projected_area(mesh) * mesh.triangles[:, :, 2].mean(axis=1)).sum())


def area_below(tri_heights, tri_areas, t):
    """Area of each triangle where the linear height is below t (closed form on sorted corner heights)."""
    h = np.sort(tri_heights, axis=1).astype(np.float64)
    h0, h1, h2 = h[:, 0], h[:, 1], h[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        low = np.where(h1 > h0, (t - h0) ** 2 / ((h2 - h0) * (h1 - h0)), 0.0)
        high = np.where(h2 > h1, 1 - (h2 - t) ** 2 / ((h2 - h0) * (h2 - h1)), 1.0)
    frac = np.where(t <= h0, 0.0, np.where(t >= h2, 1.0, np.where(t <= h1, low, high)))
    return tri_areas * np.nan_to_num(frac)


def contour_length(tri_xyz, t):
    """Length of the level-t segment in each triangle (0 where t does not cut it)."""
    total = 0.0
    h = tri_xyz[:, :, 2].astype(np.float64)
    pts = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        ha, hb = h[:, a], h[:, b]
        lo, hi = np.minimum(ha, hb), np.maximum(ha, hb)
        cut = (lo < t) & (t <= hi) & (hi > lo)
        with np.errstate(divide="ignore", invalid="ignore"):
            beta = np.where(cut, (t - ha) / (hb - ha), 0.0)
        p = tri_xyz[:, a, :2] + beta[:, None] * (tri_xyz[:, b, :2] - tri_xyz[:, a, :2])
        pts.append((cut, p))
    # exactly two edges are cut where t lies strictly inside the triangle's height range
    (c0, p0), (c1, p1), (c2, p2) = pts
    seg = np.where((c0 & c1)[:, None], p1 - p0, np.where((c1 & c2)[:, None], p2 - p1, p0 - p2))
    use = (c0.astype(int) + c1 + c2) == 2
    total = float(np.linalg.norm(seg[use], axis=1).sum())
    return total


# ----------------------------------------------------------------------- paper figures (Fig. 2 and 3)

FIGURE_CASES = {
    # one cell = two triangles; values chosen to reproduce the configurations of Fig. 3
    "flat": [[1.0, 1.0], [1.0, 1.0]],
    "one-step": [[0.0, 0.0], [0.0, 1.0]],
    "single-vertex-in-between (Fig. 3c)": [[0.0, 1.0], [2.0, 3.0]],
    "many levels (Fig. 2)": [[0.0, 7.0], [3.0, 12.0]],
    "finishing triangles": [[0.0, 2.0], [2.0, 0.0]],
    "vertex on threshold": [[0.5, 0.0], [1.5, 2.5]],
    "all on thresholds": [[0.5, 0.5], [1.5, 0.5]],
    "descending": [[9.0, 4.0], [2.0, 0.0]],
}


@pytest.mark.parametrize("name", list(FIGURE_CASES))
def test_figure_configurations_match_reference(name, device):
    heights = np.array(FIGURE_CASES[name], np.float32)
    arrays = compare_with_reference(heights, np.arange(-1.0, 14.0, 1.0, dtype=np.float32), device)
    assert arrays.face_count >= 2


def test_single_vertex_in_between_has_terraces_and_walls():
    mesh = st.stepped(np.array([[0.0, 1.0], [2.0, 3.0]]), interval=1.0)
    assert_valid_mesh(mesh)
    walls = mesh.face_attributes["wall"]
    assert walls.any() and (~walls).any()
    assert sorted(set(np.round(mesh.vertices[:, 2], 6))) == [0.0, 1.0, 2.0, 3.0]


# --------------------------------------------------------------------------------- NumPy reference


@pytest.mark.parametrize("interval", [50.0, 100.0, 250.0])
def test_real_dem_matches_reference(interval, device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=64, step=6)
    values = isovalues((float(heights.min()), float(heights.max())), interval=interval)
    compare_with_reference(heights, values, device, spacing=(30.0, -30.0))


def test_front_range_matches_reference(device):
    heights = real_dem("front_range_srtmgl3_3arcsec.npz", size=64, step=8)
    values = isovalues((float(heights.min()), float(heights.max())), interval=100.0, base=50.0)
    compare_with_reference(heights, values, device, spacing=(70.8, -92.7))


@given(
    heights=arrays(np.int16, st_.tuples(st_.integers(2, 9), st_.integers(2, 9)), elements=st_.integers(-6, 6)),
    interval=st_.sampled_from([1.0, 2.0, 3.0]),
)
def test_integer_heights_on_thresholds_match_reference(heights, interval):
    # interval 1 puts thresholds at k + 0.5 (never hit), 2 and 3 make integer heights sit on thresholds
    h = heights.astype(np.float32)
    values = isovalues((float(h.min()), float(h.max())), interval=interval, base=0.0)
    compare_with_reference(h, values, "cpu")



@pytest.mark.parametrize("seed", range(12))
def test_wide_plateaus_with_nodes_on_thresholds_match_reference(seed):
    """Rows long enough for count_grid's native runs of sixteen flat nodes (kernels/stepped.py, count_plain_nodes)
    over plateaus on a threshold (3 at interval 2) or off one, with a few nodes stepping up or down: a flat node
    on its threshold (a twin or a peak) and a cell with a corner on one must leave the run to the Warp loop."""
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(3, 7)), int(rng.integers(20, 71))
    h = np.full((rows, cols), float(rng.choice([2.0, 3.0, 4.0])), np.float32)
    bumps = rng.random((rows, cols)) < 0.05
    h[bumps] = rng.integers(-1, 7, int(bumps.sum())).astype(np.float32)
    values = isovalues((float(h.min()), float(h.max())), interval=2.0, base=0.0)
    compare_with_reference(h, values, "cpu")

@given(
    heights=arrays(
        np.float32,
        st_.tuples(st_.integers(2, 8), st_.integers(2, 8)),
        elements=st_.floats(-100, 100, width=32, allow_nan=False),
    ),
    levels=st_.lists(st_.floats(-120, 120, width=32), min_size=1, max_size=12, unique=True),
)
def test_random_grids_nonuniform_levels_match_reference(heights, levels):
    compare_with_reference(heights, np.sort(np.array(levels, np.float32)), "cpu")


@given(
    heights=arrays(np.float32, st_.tuples(st_.integers(2, 7), st_.integers(2, 7)),
                   elements=st_.sampled_from([-2.0, -0.5, 0.0, 0.5, 1.0, 1.5, 3.0, np.nan])),
    spacing=st_.tuples(st_.sampled_from([1.0, -1.0, 30.0, -30.0]), st_.sampled_from([1.0, -0.5, 2.0, -92.7])),
)
def test_nodata_patterns_and_spacings_match_reference(heights, spacing):
    """NaN holes of any shape (single nodes, bowties, all but a few nodes) with heights on thresholds (k + 0.5
    at interval 1, so twins and peaks) and spacings of either sign."""
    assume(np.isfinite(heights).any())
    values = isovalues((float(np.nanmin(heights)), float(np.nanmax(heights))), interval=1.0)
    compare_with_reference(heights, values, "cpu", spacing=spacing)


@given(
    xy=arrays(np.float64, st_.tuples(st_.integers(4, 14), st_.just(2)), elements=st_.integers(0, 6)),
    z=st_.lists(st_.sampled_from([0.0, 0.5, 1.0, 1.5, 2.5, 4.0, np.nan]), min_size=20, max_size=20),
    rotate=st_.integers(0, 2),
    clockwise=st_.booleans(),
)
def test_random_delaunay_tins_match_reference(xy, z, rotate, clockwise):
    """Delaunay TINs of points on a small integer lattice (duplicates, collinear and cocircular points: points
    left unused, slivers), NaN heights dropping faces, corners rotated, wound either way, at UTM coordinates."""
    from scipy.spatial import Delaunay, QhullError

    try:
        faces = Delaunay(xy).simplices
    except QhullError:
        assume(False)
    a, b, c = (xy[faces[:, k]] for k in range(3))
    ccw = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) > 0
    faces = np.where(ccw[:, None], faces, faces[:, ::-1])
    faces = np.roll(faces[:, ::-1] if clockwise else faces, rotate, axis=1)
    points = np.column_stack([xy + [512000.0, 4012000.0], z[: len(xy)]])
    assume(np.isfinite(points[faces, 2]).all(axis=1).any())
    tin = trimesh.Trimesh(points, faces, process=False)
    t = as_terrain(tin)
    values = isovalues(t.height_range, interval=1.0)
    compare_tin_with_reference(tin, values, "cpu")


def test_repeated_runs_are_identical(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=48, step=5)
    a = st.stepped(heights, interval=75.0, device=device)
    b = st.stepped(heights, interval=75.0, device=device)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)


def test_cpu_and_cuda_give_the_same_bits(device):
    """No FMA contraction on either backend (kernels/__init__): a CUDA device reproduces the CPU's output."""
    if device == "cpu":
        pytest.skip("compares a CUDA device with the CPU")
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=64, step=4)
    tin = st.heightfield_mesh(heights, spacing=(30.0, 30.0))
    for terrain, kwargs in [(heights, {"spacing": (30.0, 30.0), "gamma": 0.6}), (tin, {"gamma": 1.0})]:
        a = st.stepped(terrain, interval=60.0, device="cpu", **kwargs)
        b = st.stepped(terrain, interval=60.0, device=device, **kwargs)
        np.testing.assert_array_equal(a.faces, b.faces)
        np.testing.assert_array_equal(a.vertices, b.vertices)


# ------------------------------------------------------------------ degenerate TIN triangles (§3)

_SQUARE = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 3.0], [4.0, 4.0, 7.0], [0.0, 4.0, 1.0]])
DEGENERATE_TINS = {
    # the last face is the sliver of three collinear points: zero projected area, a vertical triangle.
    # (2, 0) on the bottom edge, the sliver (0, 1, 4) lies along it
    "boundary sliver": (np.vstack([_SQUARE, [[2.0, 0.0, 6.0]]]), [[0, 4, 3], [4, 1, 2], [4, 2, 3], [0, 1, 4]]),
    # (2, 2) on the diagonal 0-2: the sliver (2, 4, 0) closes the T-junction between (0, 1, 2) and the two
    # triangles on the other side
    "interior T-junction sliver": (
        np.vstack([_SQUARE, [[2.0, 2.0, 6.0]]]), [[0, 1, 2], [0, 4, 3], [4, 2, 3], [2, 4, 0]]
    ),
}


@pytest.mark.parametrize("name", list(DEGENERATE_TINS))
def test_zero_area_tin_faces_are_stepped_like_the_reference(name, device):
    """Issue 2 §3: a TIN face of three collinear points (zero projected area) is stepped, not refused: Warp
    equals the NumPy reference, the mesh is valid, its terraces still cover the input exactly once, and the
    sliver's walls close the crack, so the boundary stays on the square's sides."""
    points, faces = DEGENERATE_TINS[name]
    tin = trimesh.Trimesh(points, np.array(faces), process=False)
    values = isovalues((0.0, 7.0), interval=1.0, base=0.25)  # thresholds at k + 0.75: no height on one
    arrays = compare_tin_with_reference(tin, values, device)
    without = trimesh.Trimesh(points, np.array(faces[:-1]), process=False)
    assert arrays.face_count > len(st.stepped(without, levels=values).faces)  # the sliver adds faces
    mesh = st.stepped(tin, levels=values, device=device)
    assert_valid_mesh(mesh)
    assert np.isin(mesh.vertices[:, 2].astype(np.float32), values).all()
    terrace = ~mesh.face_attributes["wall"]
    areas = projected_area(mesh)
    assert areas[terrace].min() > -1e-12
    np.testing.assert_allclose(areas[terrace].sum(), 16.0, rtol=1e-6)
    assert mesh.is_winding_consistent
    from stepterrain.mesh import boundary_edges

    xy = mesh.vertices[boundary_edges(mesh.faces)][:, :, :2]
    assert (np.isclose(xy, 0.0) | np.isclose(xy, 4.0)).all(axis=1).any(axis=1).all()


@pytest.mark.parametrize(
    "points",
    [
        [[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [2.0, 0.0, 2.0]],  # a vertical triangle: its points on a line in xy
        [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 5.0]],  # on the diagonal
        [[5.0, 5.0, 0.0], [5.0, 5.0, 1.0], [5.0, 5.0, 2.0], [5.0, 5.0, 3.0]],  # every point at one xy
    ],
)
def test_a_tin_without_any_face_of_positive_area_is_refused(points):
    """Zero-area slivers beside real faces are stepped (above), but a TIN with no face of positive projected area
    (a vertical surface, e.g. a pyvista StructuredGrid whose x equals its y) was stepped too: a "valid" mesh with
    every vertex on one xy line or point. It is no height field: refused, saying why."""
    faces = [[0, 1, 2]] if len(points) == 3 else [[0, 1, 2], [1, 3, 2]]
    tin = trimesh.Trimesh(np.array(points), np.array(faces), process=False)
    counted = f"{len(faces)} face{'s' if len(faces) > 1 else ''}"
    with pytest.raises(st.InvalidInputError, match=rf"^terrain mesh faces must project one-to-one onto the xy plane; "
                       rf"none of its {counted} with finite heights has an area in xy \(the points lie on a "
                       r"line or at one point: x over .*\), so it is no height field$"):
        st.stepped(tin, interval=1.0)


@pytest.mark.parametrize("bad_face", [[4, 4, 1], [3, 3, 1], [1, 3, 1], [2, 0, 0]])
def test_repeated_vertex_face_is_refused(bad_face):
    """A face with a repeated vertex (a, a, b) has no interior and no third corner: refused up front, whether
    a-b is an edge of another face or not (the latter once gave uninitialised face indices)."""
    points, faces = DEGENERATE_TINS["boundary sliver"]
    tin = trimesh.Trimesh(points, np.array(faces[:-1] + [bad_face]), process=False)
    message = f"faces must have three distinct vertices; face {len(faces) - 1} is {bad_face}".replace("[", r"\[")
    with pytest.raises(st.errors.InvalidInputError, match=message.replace("]", r"\]")):
        st.stepped(tin, interval=1.0)


# ------------------------------------------------------------------------------ heightfield_mesh (§2)


def _canonical_faces(faces):
    """Faces rotated so the smallest index comes first (winding kept), rows sorted: order-free comparison."""
    faces = np.asarray(faces)
    rolled = np.array([np.roll(f, -int(np.argmin(f))) for f in faces]).reshape(-1, 3)
    return rolled[np.lexsort(rolled.T[::-1])]


@pytest.mark.parametrize("spacing", [(2.0, 0.5), (2.0, -0.5), (-2.0, 0.5), (-2.0, -0.5)], ids=str)
def test_heightfield_mesh_layout_cells_and_winding(spacing):
    """Vertex k = row-major node (i, j) at (x0 + j dx, y0 + i dy, z); two triangles per cell covering it;
    counter-clockwise seen from +z for either sign of dx and dy."""
    rows, cols = 4, 6
    heights = np.random.default_rng(7).integers(-20, 20, (rows, cols)).astype(np.float32) * 0.25
    origin = (100.25, -40.5)
    dx, dy = spacing
    m = st.heightfield_mesh(heights, spacing=spacing, origin=origin)
    assert_valid_mesh(m)
    i, j = np.divmod(np.arange(rows * cols), cols)
    expected = np.column_stack([origin[0] + j * dx, origin[1] + i * dy, heights.reshape(-1)])
    np.testing.assert_array_equal(m.vertices, expected)
    faces = np.asarray(m.faces)
    assert len(faces) == 2 * (rows - 1) * (cols - 1)
    # every face lies in one cell: its corners are among the cell's four nodes (n00 = its smallest index)
    n00 = faces.min(axis=1)
    ci, cj = np.divmod(n00, cols)
    assert (ci < rows - 1).all() and (cj < cols - 1).all()
    corners = n00[:, None] + np.array([0, 1, cols, cols + 1])
    assert (faces[:, :, None] == corners[:, None, :]).any(axis=2).all()
    # two faces per cell that split it along a diagonal: they share exactly two opposite corners (n00-n11 or
    # n01-n10) and each has one of the other two, so they cover the cell and do not overlap
    cell = ci * (cols - 1) + cj
    assert (np.bincount(cell, minlength=(rows - 1) * (cols - 1)) == 2).all()
    by_cell = faces[np.argsort(cell, kind="stable")]
    fa, fb = by_cell[0::2], by_cell[1::2]
    shared = (fa[:, :, None] == fb[:, None, :]).any(axis=2)
    assert (shared.sum(axis=1) == 2).all()
    diagonal = np.diff(np.sort(fa[shared].reshape(-1, 2), axis=1), axis=1).reshape(-1)
    assert np.isin(diagonal, [cols - 1, cols + 1]).all()
    # counter-clockwise seen from +z: positive signed projected area (half a cell each) and normals up
    np.testing.assert_allclose(projected_area(m), 0.5 * abs(dx * dy), rtol=1e-12)
    assert (m.face_normals[:, 2] > 0).all()


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_masked_heights_are_nodata_not_the_values_under_the_mask(dtype):
    """A numpy masked array (what rasterio's read(masked=True) and netCDF readers give) went through
    np.asarray, which drops the mask: the values under it (fill values such as -32768) were stepped and
    triangulated as real heights. Masked entries are nodata (NaN) now, as the docstrings say of NaN."""
    heights = np.add.outer(np.arange(5.0), 0.5 * np.arange(7.0)).astype(dtype)
    mask = np.zeros(heights.shape, bool)
    mask[2, 3] = True
    heights[2, 3] = -32768
    nan_heights = heights.astype(np.float64)
    nan_heights[mask] = np.nan
    masked = np.ma.masked_array(heights, mask=mask)
    expected = st.heightfield_mesh(nan_heights)
    np.testing.assert_array_equal(st.heightfield_mesh(masked).vertices, expected.vertices)
    stepped = st.stepped(nan_heights, interval=1.0).vertices
    np.testing.assert_array_equal(st.stepped(masked, interval=1.0).vertices, stepped)
    series = list(st.stepped_series(np.ma.stack([masked, masked]), interval=1.0))
    assert all(np.array_equal(m.vertices, stepped) for m in series)
    assert np.ma.masked_array(heights).mask is np.ma.nomask  # the caller's array is left alone
    assert heights[2, 3] == -32768

def test_heightfield_mesh_nan_nodes_are_holes_and_node_index_maps_back():
    heights = np.add.outer(np.arange(5.0), 0.5 * np.arange(7.0)).astype(np.float32)
    heights[2, 3] = np.nan  # an interior hole: its six faces go
    heights[0, 1] = np.nan  # with [1, 0] below, node (0, 0) is left on no face and is dropped
    heights[1, 0] = np.nan
    heights[4, 6] = np.nan  # a corner
    nan_nodes = np.flatnonzero(np.isnan(heights))
    spacing, origin = (3.0, -2.0), (10.0, 20.0)
    full = st.heightfield_mesh(np.nan_to_num(heights), spacing=spacing, origin=origin)
    m = st.heightfield_mesh(heights, spacing=spacing, origin=origin)
    assert_valid_mesh(m)  # finite, every vertex on a face
    node = np.asarray(m.metadata["node_index"])
    assert node.shape == (len(m.vertices),) and (np.diff(node) > 0).all()
    # metadata["node_index"]: vertex -> its grid node (row-major), with that node's position and height
    np.testing.assert_array_equal(m.vertices, full.vertices[node])
    np.testing.assert_array_equal(m.vertices[:, 2], heights.reshape(-1)[node])
    assert not np.isin(node, nan_nodes).any() and 0 not in node
    # holes, not spikes: no face touches a NaN node, and every full-grid face that touches none is kept
    grid_faces = node[m.faces]
    assert not np.isin(grid_faces, nan_nodes).any()
    kept = full.faces[~np.isin(full.faces, nan_nodes).any(axis=1)]
    np.testing.assert_array_equal(_canonical_faces(grid_faces), _canonical_faces(kept))
    assert len(m.faces) == len(full.faces) - 6 - 6 - 2  # node (2, 3); nodes (0, 1) and (1, 0); corner (4, 6)
    assert (m.face_normals[:, 2] > 0).all()


# ------------------------------------------------------------------------------------ invariants


@pytest.fixture(scope="module")
def dem():
    return real_dem("big_tujunga_srtm_30m_utm11n.npz", size=80, step=5)


TUJUNGA, FRONT_RANGE = "big_tujunga_srtm_30m_utm11n.npz", "front_range_srtmgl3_3arcsec.npz"
FRONT_RANGE_INTERVALS = (50.0, 150.0, 400.0)
_INVARIANT_DEMS: dict[str, tuple[np.ndarray, tuple[float, float]]] = {}


def invariant_dem(name: str) -> tuple[np.ndarray, tuple[float, float]]:
    """(heights, spacing) of a real DEM crop for the area / wall / volume invariants (issue 2 §5). Big Tujunga:
    the ``dem`` fixture's 80² crop at 30 m. Front Range: a 96² crop (every 6th node, 2460 m of relief), in
    metres from the file's dx_m / dy_m, north up (negative dy, rows run north to south)."""
    if name not in _INVARIANT_DEMS:
        if name == TUJUNGA:
            _INVARIANT_DEMS[name] = real_dem(TUJUNGA, size=80, step=5), (30.0, 30.0)
        else:
            step = 6
            with np.load(shared_file(name)) as data:
                spacing = (step * float(data["dx_m"]), -step * float(data["dy_m"]))
            _INVARIANT_DEMS[name] = real_dem(name, size=96, step=step), spacing
    return _INVARIANT_DEMS[name]


def invariant_cases(*tujunga_intervals: float) -> list:
    """Big Tujunga at the given intervals and the Front Range at FRONT_RANGE_INTERVALS."""
    return [pytest.param(TUJUNGA, i, id=f"tujunga-{i:g}") for i in tujunga_intervals] + [
        pytest.param(FRONT_RANGE, i, id=f"front_range-{i:g}") for i in FRONT_RANGE_INTERVALS
    ]


@pytest.mark.parametrize("interval", [40.0, 125.0])
def test_gamma_one_puts_every_vertex_on_an_isovalue(dem, interval):
    mesh = st.stepped(dem, interval=interval, spacing=(30.0, 30.0))
    values = isovalues((float(dem.min()), float(dem.max())), interval=interval)
    assert np.isin(mesh.vertices[:, 2].astype(np.float32), values).all()
    assert_valid_mesh(mesh)


@pytest.mark.parametrize(("name", "interval"), invariant_cases(40.0, 125.0))
def test_terrace_areas_per_level_equal_the_input_bands(name, interval):
    dem, spacing = invariant_dem(name)
    mesh = st.stepped(dem, interval=interval, spacing=spacing)
    source = st.heightfield_mesh(dem, spacing=spacing)
    values = isovalues((float(dem.min()), float(dem.max())), interval=interval)
    thr = thresholds_of(values).astype(np.float64)
    terrace = ~mesh.face_attributes["wall"]
    areas = projected_area(mesh)
    assert np.all(areas[terrace] > -1e-9)
    np.testing.assert_allclose(areas[terrace].sum(), projected_area(source).sum(), rtol=1e-6)
    tri_h = source.triangles[:, :, 2]
    tri_a = projected_area(source)
    bounds = np.concatenate([[-np.inf], thr, [np.inf]])
    for k in range(len(values)):
        expected = area_below(tri_h, tri_a, bounds[k + 1]).sum() - area_below(tri_h, tri_a, bounds[k]).sum()
        got = areas[terrace & (mesh.face_attributes["level"] == k)].sum()
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-3 * abs(spacing[0] * spacing[1]))


@pytest.mark.parametrize(("name", "interval"), invariant_cases(60.0))
def test_wall_area_equals_contour_length_times_step(name, interval):
    dem, spacing = invariant_dem(name)
    mesh = st.stepped(dem, interval=interval, spacing=spacing)
    source = st.heightfield_mesh(dem, spacing=spacing)
    values = isovalues((float(dem.min()), float(dem.max())), interval=interval).astype(np.float64)
    thr = thresholds_of(values.astype(np.float32)).astype(np.float64)
    walls = mesh.face_attributes["wall"]
    wall_area = float(mesh.area_faces[walls].sum())
    expected = sum(contour_length(source.triangles, t) * (values[i + 1] - values[i]) for i, t in enumerate(thr))
    np.testing.assert_allclose(wall_area, expected, rtol=1e-4)


@pytest.mark.parametrize(("name", "interval"), invariant_cases(80.0))
def test_volume_is_linear_in_gamma_and_equals_input_at_zero(name, interval):
    dem, spacing = invariant_dem(name)
    source = st.heightfield_mesh(dem, spacing=spacing)
    volumes = {
        g: volume_under(st.stepped(dem, interval=interval, gamma=g, spacing=spacing)) for g in (0.0, 0.3, 0.7, 1.0)
    }
    np.testing.assert_allclose(volumes[0.0], volume_under(source), rtol=1e-7)
    for g in (0.3, 0.7):
        np.testing.assert_allclose(volumes[g], volumes[0.0] + g * (volumes[1.0] - volumes[0.0]), rtol=1e-7)


def test_welded_mesh_is_manifold_consistent_and_bounded_by_the_input(dem):
    # 0.37 m offset: no DEM height (integers) sits on a threshold
    mesh = st.stepped(dem, interval=70.0, base=0.37, spacing=(30.0, 30.0))
    assert_valid_mesh(mesh)
    assert mesh.is_winding_consistent
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2
    from stepterrain.mesh import boundary_edges

    b = boundary_edges(mesh.faces)
    xy = mesh.vertices[b][:, :, :2]
    xmax, ymax = 30.0 * (dem.shape[1] - 1), 30.0 * (dem.shape[0] - 1)
    on_side = [
        np.isclose(xy[:, :, 0], 0).all(1),
        np.isclose(xy[:, :, 0], xmax).all(1),
        np.isclose(xy[:, :, 1], 0).all(1),
        np.isclose(xy[:, :, 1], ymax).all(1),
    ]
    assert np.logical_or.reduce(on_side).all()
    normals = mesh.face_normals
    terrace = ~mesh.face_attributes["wall"]
    assert (normals[terrace, 2] > 0.999).all()
    assert np.abs(normals[~terrace, 2]).max() < 1e-6


def test_walls_face_the_lower_terrace_on_a_ramp():
    x = np.linspace(0.0, 10.0, 11)
    heights = np.tile(x, (4, 1))  # rises towards +x
    mesh = st.stepped(heights, interval=2.0, base=0.3)
    walls = mesh.face_attributes["wall"]
    assert walls.sum() == 5 * 3 * 2 * 2  # 5 thresholds x 3 cells x 2 triangles cut x 2 faces per wall piece
    assert (mesh.face_normals[walls, 0] < -0.999).all()


def test_nan_heights_are_holes(device):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=6).copy()
    heights[10:20, 12:25] = np.nan
    heights[0, 0] = np.nan
    mesh = st.stepped(heights, interval=90.0, device=device)
    assert_valid_mesh(mesh)
    xy = mesh.vertices[:, :2]
    inside_hole = (xy[:, 0] > 12) & (xy[:, 0] < 24) & (xy[:, 1] > 10) & (xy[:, 1] < 19)
    assert not inside_hole.any()
    compare_with_reference(
        heights, isovalues((float(np.nanmin(heights)), float(np.nanmax(heights))), interval=90.0), device
    )


def test_tin_input_gives_the_grid_geometry(dem):
    small = dem[:30, :30]
    grid = st.stepped(small, interval=70.0, spacing=(30.0, 30.0))
    tin = st.stepped(st.heightfield_mesh(small, spacing=(30.0, 30.0)), interval=70.0)
    assert len(grid.faces) == len(tin.faces) and len(grid.vertices) == len(tin.vertices)

    def canonical(m):
        tri = np.round(m.triangles, 6)
        return np.sort(tri.reshape(len(tri), -1).view([("", tri.dtype)] * 9).reshape(-1))

    assert np.array_equal(canonical(grid), canonical(tin))


def test_tin_isovalues_ignore_heights_on_no_kept_face():
    """A point no kept face uses (here a -9999 nodata sentinel) is not terrain: it set the low end of the
    isovalues, which moved the hypsometric colours of every level (and the solid's default floor)."""
    h = np.add.outer(np.arange(4.0), np.arange(5.0)) * 0.7 + 100.0
    base = st.heightfield_mesh(h)
    expected = st.stepped(base, interval=1.0, colors="terrain")
    tin = trimesh.Trimesh(np.vstack([base.vertices, [1.0, 1.0, -9999.0]]), base.faces, process=False)
    mesh = st.stepped(tin, interval=1.0, colors="terrain")
    assert mesh.metadata["isovalues"] == expected.metadata["isovalues"]
    np.testing.assert_array_equal(mesh.visual.vertex_colors, expected.visual.vertex_colors)


def test_clockwise_tin_is_flipped_despite_a_far_stray_point():
    """The zero-area tolerance of the winding check scaled with the bounding box of every point: one stray
    point at (0, 0) beside a 1 m TIN at UTM coordinates made it ~2 (twice a face's area), so no face counted
    as clockwise, the clockwise TIN was not flipped and came out upside down (terraces facing -z)."""
    h = np.add.outer(np.arange(3.0), np.arange(4.0)) * 0.7
    base = st.heightfield_mesh(h, origin=(512000.0, 4012000.0))
    tin = trimesh.Trimesh(np.vstack([base.vertices, [0.0, 0.0, np.nan]]), base.faces[:, ::-1], process=False)
    mesh = st.stepped(tin, interval=1.0)
    assert (mesh.face_normals[~mesh.face_attributes["wall"], 2] > 0.999).all()
    assert projected_area(mesh)[~mesh.face_attributes["wall"]].sum() == pytest.approx(6.0)


def test_tin_height_beyond_float32_is_refused_not_stepped_to_infinity():
    """A TIN height finite in float64 but beyond float32 (1e39) became inf on the device: the face was kept
    and stepped into NaN and inf vertices. The grid path refuses such heights; so does the TIN path now."""
    base = st.heightfield_mesh(np.add.outer(np.arange(3.0), np.arange(3.0)))
    vertices = base.vertices.copy()
    vertices[4, 2] = 1e39
    tin = trimesh.Trimesh(vertices, base.faces, process=False)
    with pytest.raises(st.InvalidInputError, match=r"heights must fit in float32 .*; vertex 4 has z=1e\+39"):
        st.stepped(tin, interval=1.0)

def test_tin_xy_extent_beyond_float32_is_refused_not_stepped_to_infinity():
    """The kernels get a TIN's xy relative to its lower-left corner in float32: a TIN 4e38 wide (finite in
    float64) was stepped into inf and NaN vertices without a word. Refused now, naming the extent; a TIN as
    wide as float32 allows, or far from the origin, still steps."""
    base = st.heightfield_mesh(np.add.outer(np.arange(3.0), np.arange(3.0)), spacing=(0.5, 0.5))
    wide = trimesh.Trimesh(base.vertices * [4e38, 1.0, 1.0], base.faces, process=False)
    with pytest.raises(st.InvalidInputError, match=r"terrain mesh x and y must span at most 3.4e\+38 .*got x"):
        st.stepped(wide, interval=1.0)
    # (1e30 apart at 1e300 collapsed every point onto x = y = 1e300 in float64: a TIN of no area, refused since)
    for scale, offset in ((3e38, 0.0), (1e30, 1e40)):
        tin = trimesh.Trimesh(base.vertices * [scale, scale, 1.0] + [offset, offset, 0.0], base.faces, process=False)
        assert np.isfinite(st.stepped(tin, interval=1.0).vertices).all()


def test_tin_face_index_beyond_the_vertices_is_refused():
    """A trimesh whose faces name a vertex it does not have (process=False keeps them) raised a bare
    IndexError from numpy fancy indexing; now an InvalidInputError names the face and the vertex count."""
    base = st.heightfield_mesh(np.add.outer(np.arange(3.0), np.arange(3.0)))
    for bad in (len(base.vertices), -1):
        faces = base.faces.copy()
        faces[2, 1] = bad
        tin = trimesh.Trimesh(base.vertices, faces, process=False)
        with pytest.raises(st.InvalidInputError, match=rf"face 2 is \[.*{bad}.*\]; the mesh has 9 vertices"):
            st.stepped(tin, interval=1.0)


@pytest.mark.parametrize("stray", ["unused", "nan-height-face"])
def test_tin_local_origin_ignores_points_on_no_kept_face(stray):
    """A TIN at UTM coordinates with one stray point at (0, 0) that no kept face uses (unreferenced, or its
    face dropped for a NaN height) steps exactly like the TIN without it: the stray point must not set the
    local origin (float32 coordinates ~4e6 from it moved the output by up to 0.125 m)."""
    h = np.add.outer(np.arange(4.0), np.arange(5.0)) * 0.7
    base = st.heightfield_mesh(h, spacing=(0.1, 0.1), origin=(512345.67, 4012345.67))
    expected = st.stepped(base, interval=1.0, gamma=0.0)
    faces = base.faces if stray == "unused" else np.vstack([base.faces, [[0, len(base.vertices), 1]]])
    tin = trimesh.Trimesh(np.vstack([base.vertices, [0.0, 0.0, np.nan]]), faces, process=False)
    mesh = st.stepped(tin, interval=1.0, gamma=0.0)
    np.testing.assert_array_equal(mesh.faces, expected.faces)
    np.testing.assert_array_equal(mesh.vertices, expected.vertices)


def test_clockwise_tin_is_flipped_and_folded_tin_refused():
    base = st.heightfield_mesh(np.array([[0.0, 1.0, 2.0], [1.0, 2.0, 3.0], [2.0, 3.0, 4.0]]))
    clockwise = trimesh.Trimesh(base.vertices, base.faces[:, ::-1], process=False)
    mesh = st.stepped(clockwise, interval=1.0)
    assert (mesh.face_normals[~mesh.face_attributes["wall"], 2] > 0).all()
    # a face wound the other way alone does not fold (test_a_tin_with_faces_wound_either_way_steps_as_the_one_wound_up)
    # the middle node moved across its neighbours' edge does
    folded = base.vertices.copy()
    folded[4, :2] = [0.4, 1.8]
    with pytest.raises(st.InvalidInputError, match="fold"):
        st.stepped(trimesh.Trimesh(folded, base.faces, process=False), interval=1.0)


def test_negative_dy_keeps_counter_clockwise_faces(dem):
    mesh = st.stepped(dem[:20, :20], interval=50.0, spacing=(30.0, -30.0), origin=(376000.0, 3807900.0))
    terrace = ~mesh.face_attributes["wall"]
    assert (mesh.face_normals[terrace, 2] > 0.999).all()
    assert mesh.vertices[:, 0].min() == pytest.approx(376000.0)
    assert mesh.vertices[:, 1].max() == pytest.approx(3807900.0)


def test_solid_is_watertight_with_the_expected_volume(dem):
    small = dem[:40, :40]
    floor = float(small.min()) - 100.0
    mesh = st.stepped(small, interval=60.0, base=0.5, spacing=(30.0, 30.0), solid=True, floor=floor)
    assert mesh.is_watertight and mesh.is_winding_consistent
    surface = st.stepped(small, interval=60.0, base=0.5, spacing=(30.0, 30.0))
    terrace = ~surface.face_attributes["wall"]
    expected = float((projected_area(surface, terrace) * (surface.triangles[terrace, 0, 2] - floor)).sum())
    np.testing.assert_allclose(mesh.volume, expected, rtol=1e-6)


@given(heights=arrays(np.int16, st_.tuples(st_.integers(2, 7), st_.integers(2, 7)), elements=st_.integers(0, 8)))
def test_solid_is_watertight_for_integer_heights(heights):
    # base 0.5 keeps the thresholds (1.5, 3.5, ...) off the integer heights
    mesh = st.stepped(heights.astype(np.float32), interval=2.0, base=0.5, solid=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0


@pytest.mark.parametrize("gamma", [0.0, 0.5])
def test_solid_default_floor_lies_below_a_surface_under_the_lowest_level(gamma):
    """With explicit levels above the lowest heights and γ < 1 the surface dips below the lowest isovalue; the
    default floor (no floor= given) goes under it instead of refusing the call ("floor must lie below")."""
    heights = np.array([[0.25, 1.25], [2.25, 3.25]])  # the threshold 1.5 sits on no height
    mesh = st.stepped(heights, levels=[1.0, 2.0], gamma=gamma, solid=True)
    assert mesh.is_watertight and mesh.is_winding_consistent
    lowest = 0.25 + gamma * (1.0 - 0.25)
    assert mesh.metadata["floor"] == pytest.approx(lowest - 0.1)
    assert mesh.vertices[:, 2].min() == pytest.approx(lowest - 0.1)


def test_solid_is_watertight_where_nodata_holes_meet_at_one_node():
    """Two triangles that share only a node (NaN on both sides of it) make a boundary that touches itself. The
    node is split per fan, so every edge of the solid has two faces, the volume is the sum of the two prisms, and
    no warning is given. The second fan's copy (and its base) moves 2 float32 steps u into its own triangle, so that
    an .stl (corners merged by float32 position) keeps the two prisms apart too."""
    nan = np.nan
    bowtie = np.array([[0.25, 0.25, nan], [nan, 0.25, nan], [nan, 0.25, 0.25]])
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = st.stepped(bowtie, interval=1.0, solid=True, floor=-1.0)
    assert mesh.is_watertight and mesh.is_winding_consistent
    # two unit right triangles (area 0.5 each) at z = 0 over a floor at -1
    assert mesh.volume == pytest.approx(1.0)
    centre = np.flatnonzero((mesh.vertices[:, 0] == 1.0) & (mesh.vertices[:, 1] == 1.0))
    assert len(centre) == 2  # the node and its base; the copy and its base moved by 2 u in x and y into their cell
    u = float(np.spacing(np.float32(2.0)))
    moved = np.abs(np.abs(mesh.vertices[:, :2] - 1.0) - 2 * u).max(axis=1) == 0
    assert moved.sum() == 2 and len({tuple(p) for p in mesh.vertices[moved, :2]}) == 1
    assert len(mesh.split(only_watertight=True)) == 2
    hole = np.full((4, 4), 0.25)
    hole[1:3, 1:3] = nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert st.stepped(hole, interval=1.0, solid=True).is_watertight


@settings(max_examples=40, deadline=None)
@given(
    holes=st_.lists(st_.booleans(), min_size=36, max_size=36),
    seed=st_.integers(0, 2**16),
)
def test_solid_is_watertight_for_any_nodata_pattern(holes, seed):
    """Random nodata patterns (pinches wherever two holes meet diagonally): the solid is watertight with the
    volume of its prisms over the floor, whatever the pattern."""
    rng = np.random.default_rng(seed)
    heights = rng.uniform(0.0, 5.0, (6, 6)) + 0.125
    heights[np.array(holes).reshape(6, 6)] = np.nan
    surface = st.stepped(heights, interval=1.0)
    if len(surface.faces) == 0:
        return
    mesh = st.stepped(heights, interval=1.0, solid=True, floor=-2.0)
    assert mesh.is_watertight and mesh.is_winding_consistent
    terraces = ~surface.face_attributes["wall"].astype(bool)
    tri_xy = surface.vertices[surface.faces[terraces]]
    u, w = tri_xy[:, 1, :2] - tri_xy[:, 0, :2], tri_xy[:, 2, :2] - tri_xy[:, 0, :2]
    area = 0.5 * np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0])
    expected = float((area * (tri_xy[:, :, 2].mean(axis=1) + 2.0)).sum())
    # but for the pinch copies, each moved 2 u in x and y into its cell (u the float32 step at 5): at most 2√2 u
    # times its fan's outline (4 cell sides) times its height above the floor (under 8)
    copies = len(mesh.vertices) - len(surface.vertices) - int((mesh.vertices[:, 2] == -2.0).sum())
    u = float(np.spacing(np.float32(5.0)))
    assert mesh.volume == pytest.approx(expected, rel=1e-9, abs=copies * 2 * np.sqrt(2) * u * 4 * 8)


def test_solid_colours_a_pinch_vertexs_copy_as_its_original():
    """Where two nodata holes meet at a node, close_solid gives each fan its own copy of the node; with colors= the
    copies were painted the skirt's grey (every vertex past the kept surface ones was taken for a skirt or base
    vertex). Found by checking the colours of every surface vertex of solids over random nodata patterns."""
    heights = np.arange(36.0).reshape(6, 6) * 0.25 + 0.125
    heights[1, 1] = heights[1, 3] = np.nan  # their holes meet at node (1, 2) only
    surface = st.stepped(heights, interval=1.0, colors="viridis")
    mesh = st.stepped(heights, interval=1.0, colors="viridis", solid=True, floor=-2.0)
    assert mesh.is_watertight
    top = mesh.vertices[:, 2] > -2.0
    assert top.sum() > len(surface.vertices)  # the pinch was split
    # by position to 1e-4 (the copy moved 2 float32 steps, 1e-6, into its cell)
    pairs = zip(np.round(surface.vertices, 4).tolist(), surface.visual.vertex_colors.tolist(), strict=True)
    colour_at = {tuple(v): tuple(c) for v, c in pairs}
    got = [tuple(c) for c in mesh.visual.vertex_colors[top].tolist()]
    assert got == [colour_at[tuple(v)] for v in np.round(mesh.vertices[top], 4).tolist()]
    assert (mesh.visual.vertex_colors[~top] == [96, 96, 96, 255]).all()


def test_solid_is_watertight_when_heights_sit_on_thresholds():
    """Heights on a threshold step as the heights one float32 step above them (the same level) for a solid: no
    twin vertex, no warning, a watertight solid whose terraces lie on their isovalues."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = st.stepped(np.array([[0.0, 1.0], [1.0, 2.0]]), interval=2.0, solid=True)
    assert mesh.is_watertight and mesh.is_volume
    assert set(mesh.vertices[:, 2].tolist()) == {-2.0, 0.0, 2.0}


def test_solid_of_a_tin_with_points_on_thresholds():
    """A TIN's used point on a threshold is stepped from one float32 step above it, as a grid's node: no warning,
    a watertight solid; a point no face uses is left as it is."""
    import warnings

    vertices = np.array([[0, 0, 0.25], [4, 0, 1.25], [0, 4, 2.25], [4, 4, 3.25], [9, 9, 2.0]], float)
    faces = np.array([[0, 1, 3], [0, 3, 2]])
    for z in (1.25, 2.0):  # 2.0: a used point on the threshold 2.0 between isovalues 1.5 and 2.5
        vertices[1, 2] = z
        tin = trimesh.Trimesh(vertices, faces, process=False)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            mesh = st.stepped(tin, interval=1.0, base=0.5, solid=True)
        assert mesh.is_watertight and mesh.is_volume
        assert tin.vertices[1, 2] == z  # the caller's mesh is not changed
        surface = st.stepped(tin, interval=1.0, base=0.5)
        assert mesh.volume == pytest.approx(volume_under(surface) - mesh.metadata["floor"] * 16.0, rel=1e-6)


def test_lens_shows_the_original_inside_and_steps_outside(dem):
    small = dem[:41, :41]
    t = st.Terrain.from_heights(small, spacing=(30.0, 30.0))
    lens = st.circular_lens(t, (600.0, 600.0), 300.0, edge_width=60.0)
    mesh = st.stepped(t, interval=100.0, gamma=lens)
    values = isovalues(t.height_range, interval=100.0)
    xy = mesh.vertices[:, :2]
    d = np.hypot(xy[:, 0] - 600.0, xy[:, 1] - 600.0)
    outside = d > 340.0
    assert np.isin(mesh.vertices[outside, 2].astype(np.float32), values).all()
    node = (np.abs(xy[:, 0] - 600) < 1e-6) & (np.abs(xy[:, 1] - 600) < 1e-6)
    assert np.isclose(mesh.vertices[node, 2], small[20, 20]).any()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"radius": "big"}, r"lens radius must be a number; got 'big'"),
        ({"radius": None}, r"lens radius must be a number; got None"),
        ({"radius": float("nan")}, r"lens radius must be finite; got nan"),
        ({"edge_width": "x"}, r"lens edge_width must be a number; got 'x'"),
        ({"inside": None}, r"lens inside must be a number; got None"),
        ({"outside": "1"}, r"lens outside must be a number; got '1'"),  # text, even a number's, as resolution
        ({"outside": True}, r"lens outside must be a number; got True"),
        ({"outside": 1}, None),
        ({"outside": [0.5]}, r"lens outside must be a number; got \[0.5\]"),
        ({"resolution": float("nan")}, r"lens resolution must be an int >= 3; got nan"),
        ({"resolution": "64"}, r"lens resolution must be an int >= 3; got '64'"),
        ({"resolution": 2.7}, r"lens resolution must be an int >= 3; got 2.7"),
        ({"resolution": True}, r"lens resolution must be an int >= 3; got True"),
    ],
)
def test_circular_lens_bad_numbers_are_named(kwargs, match):
    """circular_lens called float()/int() bare: radius='big', inside=None or resolution=nan raised numpy's or
    Python's ValueError/TypeError, and resolution=2.7 was truncated silently; now each is an InvalidInputError
    naming the argument."""
    args = {"radius": 1.0, **kwargs}
    radius = args.pop("radius")
    if match is None:
        assert st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), radius, **args).mask.max() == 1.0
        return
    with pytest.raises(st.InvalidInputError, match=match):
        st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), radius, **args)

def test_circular_lens_resolution_beyond_the_memory_budget_is_refused_up_front():
    """resolution=1_000_000 asked numpy for 7 TiB of float64 distances and died in a bare MemoryError; the mask
    is checked against the memory budget before any texel is allocated."""
    with pytest.raises(st.OutputTooLargeError, match=r"a lens mask of resolution 1000000 would need .*lower the lens"):
        st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), 1.0, resolution=1_000_000)
    previous = st.set_memory_budget(1 << 20)
    try:
        with pytest.raises(st.OutputTooLargeError, match="resolution 256"):
            st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), 1.0, resolution=256)
        assert st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), 1.0, resolution=64).mask.shape == (64, 64)
    finally:
        st.set_memory_budget(previous)

def test_gamma_callable_and_array_agree_with_scalar(dem):
    small = dem[:25, :25]
    scalar = st.stepped(small, interval=70.0, gamma=0.4)
    by_array = st.stepped(small, interval=70.0, gamma=np.full(small.shape, 0.4))
    by_callable = st.stepped(small, interval=70.0, gamma=lambda p: np.full(len(p), 0.4))
    np.testing.assert_allclose(by_array.vertices, scalar.vertices, atol=1e-4)
    np.testing.assert_allclose(by_callable.vertices, scalar.vertices, atol=1e-4)


@pytest.mark.parametrize("gamma", [0.0, 0.37, 1.0])
@pytest.mark.parametrize("case", ["dem", "nodata", "tin", "colors"])
def test_the_vertex_pass_blends_a_scalar_gamma_as_blend_does(device, dem, case, gamma):
    """stepped() with a scalar γ blends in the vertex pass (DirectBlend); its vertices are bit for bit those of the
    separate blend pass over step_arrays' points, on a grid, a grid with nodata and a TIN, and with colours (the
    pass then also keeps the step heights the colours are looked up by)."""
    heights = dem[:40, :50].astype(np.float64)
    if case == "nodata":
        heights[5:9, 7:20] = np.nan
    terrain = st.heightfield_mesh(heights, spacing=(30.0, -30.0), origin=(394000.0, 3798000.0)) if case == "tin" else \
        st.Terrain.from_heights(heights, spacing=(30.0, -30.0), origin=(394000.0, 3798000.0))  # fmt: skip
    colors = "terrain" if case == "colors" else None
    mesh = st.stepped(terrain, interval=35.0, gamma=gamma, colors=colors, device=device)
    t = as_terrain(terrain)
    dev = resolve_device(device)
    separate = blend(t, step_arrays(t, isovalues(t.height_range, interval=35.0), device=dev),
                     gamma, device=dev)  # fmt: skip
    np.testing.assert_array_equal(mesh.vertices.view(np.int64), separate.view(np.int64))
    direct = step_arrays(t, isovalues(t.height_range, interval=35.0), device=dev, gamma=gamma, want_steps=True)
    assert direct.points is None and direct.step_heights is not None
    if case == "colors":
        by_level = st.stepped(terrain, interval=35.0, gamma=np.full(t.shape, gamma) if case != "tin" else gamma,
                              colors=colors, device=device)  # fmt: skip
        np.testing.assert_array_equal(mesh.visual.vertex_colors, by_level.visual.vertex_colors)


def test_colors_by_level_and_face_attributes(dem):
    mesh = st.stepped(dem[:20, :20], interval=50.0, colors="terrain")
    assert mesh.visual.kind == "vertex"
    assert mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)
    levels = mesh.face_attributes["level"]
    assert levels.dtype == np.int32 and levels.shape == (len(mesh.faces),)


def test_input_vertex_colors_are_carried():
    base = st.heightfield_mesh(np.array([[0.0, 1.0], [2.0, 3.0]]))
    base.visual = trimesh.visual.ColorVisuals(
        base,
        vertex_colors=np.array([[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [255, 255, 255, 255]], np.uint8),
    )
    mesh = st.stepped(base, interval=1.0)
    assert mesh.visual.kind == "vertex"
    colors = mesh.visual.vertex_colors
    assert colors.shape == (len(mesh.vertices), 4)
    assert (colors[:4] == base.visual.vertex_colors).all()


def test_series_equals_frame_by_frame():
    rng = np.random.default_rng(1)
    frames = rng.random((4, 12, 12)).astype(np.float32) * 10
    series = list(st.stepped_series(frames, interval=2.0))
    for frame, mesh in zip(frames, series, strict=True):
        single = st.stepped(frame, levels=isovalues((float(frames.min()), float(frames.max())), interval=2.0))
        np.testing.assert_array_equal(mesh.faces, single.faces)
        np.testing.assert_array_equal(mesh.vertices, single.vertices)


def test_series_colours_agree_for_a_stack_and_geometry_for_any_iterable():
    """As the docstring says: a (T, H, W) stack shares one list of isovalues, so one height gets one colour in
    every frame; frames from a generator step heights to the same grid base + k * interval (same vertices), but
    count levels, and so colours, per frame."""
    rng = np.random.default_rng(2)
    low = (rng.random((10, 10)) * 6).astype(np.float32)  # heights 0..6
    high = low + 4.0  # the same shape 4 m higher: 4..10
    frames = np.stack([low, high])

    def colour_of_height(mesh, z):
        at = np.flatnonzero(mesh.vertices[:, 2] == z)
        assert at.size
        return {tuple(c) for c in mesh.visual.vertex_colors[at].tolist()}

    stacked = list(st.stepped_series(frames, interval=2.0, colors="viridis"))
    assert colour_of_height(stacked[0], 6.0) == colour_of_height(stacked[1], 6.0)
    iterated = list(st.stepped_series(iter(frames), interval=2.0, colors="viridis"))
    for a, b in zip(stacked, iterated, strict=True):
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.faces, b.faces)
    assert colour_of_height(iterated[0], 6.0) != colour_of_height(iterated[1], 6.0)


@pytest.mark.parametrize("hole", [False, True], ids=["no-nodata", "hole-in-frame-2"])
def test_series_reuses_buffers_and_equals_fresh_calls(hole):
    """Issue 2 §3/§4 dynamic data: a later frame of the same shape runs in the first frame's device buffers
    (the per-thread scratch arrays: levels, counts, offsets, points, step heights: the same objects and
    pointers) and still gives exactly the mesh of a fresh ``stepped`` call, also when only a later frame has
    nodata (per-frame state such as the nodata flag must not be carried over)."""
    from stepterrain import _device

    rng = np.random.default_rng(5)
    first = (rng.random((14, 14)) * 10).astype(np.float32)
    frames = np.stack([first, 0.5 * first + 2.0, 0.25 * first + 3.0])  # later frames cross fewer levels
    if hole:
        frames[1, 4:7, 5:9] = np.nan
    values = isovalues((float(np.nanmin(frames)), float(np.nanmax(frames))), interval=1.0)

    def buffers():
        pool = getattr(_device._pools, "arrays", {})
        return {key: (array, array.ptr) for key, array in pool.items() if key[0].startswith("stepped.")}

    seen = []
    for frame, mesh in zip(frames, st.stepped_series(frames, interval=1.0, device="cpu"), strict=True):
        seen.append(buffers())
        fresh = st.stepped(frame, levels=values, device="cpu")
        assert_valid_mesh(mesh)
        np.testing.assert_array_equal(mesh.faces, fresh.faces)
        np.testing.assert_array_equal(mesh.vertices, fresh.vertices)
        np.testing.assert_array_equal(mesh.face_attributes["level"], fresh.face_attributes["level"])
    assert {"stepped.levels", "stepped.points", "stepped.step_heights"} <= {key[0] for key in seen[0]}
    for later in seen[1:]:
        assert later.keys() == seen[0].keys()
        for key, (array, ptr) in seen[0].items():
            assert later[key][0] is array and later[key][1] == ptr, f"{key[0]} was reallocated"


def test_terrain_heights_cannot_change_under_its_caches():
    """A Terrain caches what it derives from its heights (the nodata flag, device uploads). Masking its heights
    in place after a first call (dem.heights[dem.heights < x] = nan) stepped the new NaNs with the stale flag
    'no nodata': NaN vertices, spikes. Its arrays are read-only now, and from_heights copies a float32 array
    it would otherwise share with the caller, so later changes to that array do not reach the Terrain."""
    heights = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32)
    t = st.Terrain.from_heights(heights)
    before = st.stepped(t, interval=2.0)
    with pytest.raises(ValueError, match="read-only"):
        t.heights[:2] = np.nan
    heights[:2] = np.nan  # the caller's own array
    after = st.stepped(t, interval=2.0)
    assert_valid_mesh(after)
    np.testing.assert_array_equal(after.vertices, before.vertices)
    np.testing.assert_array_equal(after.faces, before.faces)
    tin = as_terrain(st.heightfield_mesh(heights[2:]))
    for name in ("heights", "points", "faces", "edges", "face_edges", "point_used"):
        assert not getattr(tin, name).flags.writeable, name


def test_stepped_borrows_a_float32_array_for_its_call_only(dem):
    """stepped() on a raw float32, C-contiguous array uses it without the copy a kept Terrain needs (as_terrain's
    borrow): the mesh is the one a copied Terrain gives, the caller's array stays writable and unchanged, and
    changing it afterwards changes nothing already stepped; stepped_series borrows each frame the same way."""
    heights = np.ascontiguousarray(dem[:40, :50], dtype=np.float32)
    kept = heights.copy()
    mesh = st.stepped(heights, interval=35.0, spacing=(30.0, -30.0))
    copied = st.stepped(st.Terrain.from_heights(kept, spacing=(30.0, -30.0)), interval=35.0)
    assert heights.flags.writeable and heights.flags.c_contiguous
    np.testing.assert_array_equal(heights, kept)
    np.testing.assert_array_equal(mesh.vertices, copied.vertices)
    np.testing.assert_array_equal(mesh.faces, copied.faces)
    borrowed = as_terrain(heights, borrow=True)
    assert np.shares_memory(borrowed.heights, heights) and not borrowed.heights.flags.writeable
    assert not np.shares_memory(as_terrain(heights).heights, heights)
    before = mesh.vertices.copy()
    heights[:] = 0.0
    np.testing.assert_array_equal(mesh.vertices, before)
    frames = np.stack([kept, kept + 10.0])
    series = st.stepped_series(frames, interval=35.0, spacing=(30.0, -30.0))
    for k, got in enumerate(series):
        one = st.stepped(frames[k].copy(), levels=got.metadata["isovalues"], spacing=(30.0, -30.0))
        np.testing.assert_array_equal(got.vertices, one.vertices)
        np.testing.assert_array_equal(got.faces, one.faces)
    np.testing.assert_array_equal(frames[0], kept)


def test_terrain_copies_the_buffer_an_array_like_shares():
    """from_heights copied a float32 buffer it would share only when given an ndarray: an array-like exposing its
    own buffer (a memoryview, an object with __array__: an xarray DataArray, a DataFrame) was shared, and masking
    it afterwards stepped the new NaNs with the stale 'no nodata' flag: NaN vertices. Found by stepping a terrain
    again after changing the buffer behind an array-like."""

    class Wrapped:  # what xarray and pandas do: __array__ returns the float32 buffer they hold, not a copy
        def __init__(self, values):
            self.values = values

        def __array__(self, dtype=None, copy=None):
            return self.values

    for make in (Wrapped, memoryview):
        heights = np.add.outer(np.arange(6.0), np.arange(7.0)).astype(np.float32)
        t = st.Terrain.from_heights(make(heights))
        before = st.stepped(t, interval=2.0)
        heights[:2] = np.nan
        after = st.stepped(t, interval=2.0)
        assert np.isfinite(after.vertices).all(), make
        np.testing.assert_array_equal(after.vertices, before.vertices)


def test_lens_mask_is_checked_once_and_cannot_change_afterwards():
    """Lens checked its mask lies in [0, 1] but kept the caller's float32 array: filling it with NaN (or 2.0)
    afterwards stepped NaN vertices (or γ beyond 1) without an error. The Lens holds a read-only copy now. Found by
    changing a lens' mask array after building the Lens."""
    heights = np.add.outer(np.arange(6.0), np.arange(7.0))
    mask = np.full((8, 8), 0.5, np.float32)
    lens = st.Lens(mask)
    before = st.stepped(heights, interval=2.0, gamma=lens)
    mask[:] = np.nan
    after = st.stepped(heights, interval=2.0, gamma=lens)
    np.testing.assert_array_equal(after.vertices, before.vertices)
    with pytest.raises(ValueError, match="read-only"):
        lens.mask[0, 0] = 2.0


def test_heights_outside_the_levels_clamp_to_the_end_levels():
    mesh = st.stepped(np.array([[-50.0, 0.0], [10.0, 90.0]]), levels=[0.0, 10.0, 20.0])
    assert set(np.round(mesh.vertices[:, 2], 6)) <= {0.0, 10.0, 20.0}


def test_empty_result_is_valid_not_an_error():
    heights = np.full((3, 3), np.nan)
    heights[0, 0] = 1.0
    mesh = st.stepped(heights, interval=1.0)
    assert len(mesh.faces) == 0 and len(mesh.vertices) == 0


# ------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({}, "exactly one of interval"),
        ({"interval": 1.0, "levels": [0, 1]}, "exactly one of interval"),
        ({"interval": 0.0}, "interval must be a positive"),
        ({"interval": -2.0}, "interval must be a positive"),
        ({"interval": float("nan")}, "interval must be a positive"),
        ({"interval": float("inf")}, "interval must be a positive"),
        ({"levels": [0.0, 2.0, 2.0]}, r"strictly increasing; got \[0.0, 2.0, 2.0\] \(index 2\)"),
        ({"levels": []}, "at least one"),
        ({"interval": 1.0, "gamma": 1.5}, r"gamma must lie in \[0, 1\]"),
        ({"interval": 1.0, "gamma": np.zeros((2, 2))}, "gamma must be shape"),
        ({"interval": 1.0, "gamma": lambda p: np.ones(3)}, r"gamma\(points\) must be shape"),
        ({"interval": 1.0, "gamma": "0.5x"}, r"gamma must be a number in \[0, 1\], .*; got '0.5x'"),
        ({"interval": 1.0, "gamma": [["a"] * 4] * 4}, r"gamma must be a number in \[0, 1\], .*; got \[\['a'"),
        ({"interval": 1.0, "gamma": lambda p: ["x"] * len(p)}, r"gamma\(points\) must be a number in \[0, 1\]"),
        ({"interval": 1.0, "colors": "not-a-colormap"}, "matplotlib colormap"),
        ({"interval": 1.0, "floor": 0.0}, "floor applies only with solid=True"),
        ({"interval": 1.0, "solid": True, "floor": 100.0}, "floor must lie below"),
        ({"interval": 1.0, "solid": True, "floor": "low"}, r"floor must be a number .*; got 'low'"),
        ({"interval": 1.0, "solid": True, "floor": [-1.0, -2.0]}, r"floor must be a number .*; got \[-1.0, -2.0\]"),
        ({"interval": 1e-9}, "levels; at most"),
        ({"levels": [[0.0, 2.0], [4.0, 6.0]]}, r"levels must be a 1-D sequence of isovalues; got shape \(2, 2\)"),
        ({"levels": [0.0, 1e39]}, r"levels must fit in float32 \(\|x\| < 3.4e\+38\); got \[0.0, 1e\+39\]"),
        ({"interval": 1e300}, r"interval=1e\+300 with base=0.0 gives isovalues beyond float32"),
        ({"interval": 10.0, "base": 1e39}, r"^base must fit in float32 \(\|x\| < 3.4e\+38\), .*; got 1e\+39$"),
        ({"interval": 1.0, "base": 1e20}, r"^interval=1 with base=1e\+20, more than 2\*\*53 intervals from zero"),
    ],
)
def test_bad_arguments_raise_clear_errors(kwargs, match):
    with pytest.raises(st.InvalidInputError, match=match):
        st.stepped(np.arange(16, dtype=np.float32).reshape(4, 4), **kwargs)


def test_ragged_sequences_are_named_not_numpy_errors():
    """Nested lists whose rows differ in length raised numpy's 'setting an array element with a sequence ...
    inhomogeneous shape' from np.asarray / np.ndim for heights, gamma, colors and a Lens mask; each is an
    InvalidInputError naming the argument now."""
    ragged = [[0.0, 1.0, 2.0], [1.0, 2.0]]
    heights = np.arange(16, dtype=np.float32).reshape(4, 4)
    with pytest.raises(st.InvalidInputError, match="heights must be a real-valued .*rows of different lengths"):
        st.heightfield_mesh(ragged)
    with pytest.raises(st.InvalidInputError, match="heights must be a real-valued .*rows of different lengths"):
        st.stepped(ragged, interval=1.0)
    with pytest.raises(st.InvalidInputError, match=r"gamma must be a number in \[0, 1\], an array of them"):
        st.stepped(heights, interval=1.0, gamma=[[0.5] * 4, [0.5]])
    with pytest.raises(st.InvalidInputError, match=r"colors must be .*shape \(16, 3\|4\); got rows of different"):
        st.stepped(heights, interval=1.0, colors=[[0, 0, 0]] * 15 + [[0, 0]])
    with pytest.raises(st.InvalidInputError, match="lens mask must be a real .*rows of different lengths"):
        st.Lens([[0.5, 0.5], [1.0]])

@pytest.mark.parametrize("extent", [(0.0, 1.0, None, 2.0), "abcd", (0.0, 1.0, "y", 2.0)])
def test_lens_extent_not_numbers_is_named(extent):
    """Lens(mask, (0, 1, None, 2)) raised float()'s TypeError and Lens(mask, 'abcd') its ValueError; both are the
    InvalidInputError a wrong-length or inverted extent already got."""
    with pytest.raises(st.InvalidInputError, match=r"lens extent must be \(xmin, xmax, ymin, ymax\)"):
        st.Lens(np.ones((2, 2)), extent)

@pytest.mark.parametrize(
    ("frames", "match"),
    [
        (None, "frames must be a .* or an iterable of .*; got NoneType"),
        (5, "frames must be a .* or an iterable of .*; got int"),
        ("frames.npy", "frames must be a .* or an iterable of .*; got str"),
        (np.full((2, 3, 3), "a"), r"frames must be a real-valued \(T, H, W\) stack; got dtype <U1"),
        (np.zeros((2, 3, 3), object), r"frames must be a real-valued \(T, H, W\) stack; got dtype object"),
        (np.zeros((2, 3, 3), bool), r"frames must be a real-valued \(T, H, W\) stack; got dtype bool"),
    ],
)
def test_stepped_series_bad_frames_are_named(frames, match):
    """stepped_series(None) / (5) raised "'NoneType' object is not iterable", a string stack or an object stack
    numpy's "ufunc 'isfinite' not supported"; now an InvalidInputError names frames (on the first frame asked
    for, as the other checks of this generator)."""
    with pytest.raises(st.InvalidInputError, match=match):
        next(st.stepped_series(frames, interval=1.0))


@pytest.mark.parametrize("as_list", [False, True], ids=["stack", "list"])
def test_stepped_series_frame_errors_name_the_frame(as_list):
    """An all-NaN frame raised "terrain has no finite height" partway through a list of frames (not saying which)
    but gave an empty mesh within a (T, H, W) stack; both refuse it now, as stepped() and batch do, naming the
    frame; an infinite height names its frame too. progress="no" switched the progress bar on."""
    frames = np.random.default_rng(3).random((3, 4, 4))
    frames[2] = np.nan
    series = list(frames) if as_list else frames
    with pytest.raises(st.InvalidInputError, match=r"^frames\[2\]: terrain has no finite height \(all nodata\)$"):
        list(st.stepped_series(series, interval=0.25))
    frames[2] = frames[0]
    frames[1, 0, 3] = np.inf
    series = list(frames) if as_list else frames
    with pytest.raises(st.InvalidInputError, match=r"^frames\[1\]: heights must be finite or NaN \(nodata\); "
                                                   r"got an infinite value at index \(0, 3\)$"):
        list(st.stepped_series(series, interval=0.25))
    with pytest.raises(st.InvalidInputError, match=r"^progress must be True or False; got 'no'$"):
        next(st.stepped_series(frames[:1], interval=0.25, progress="no"))
    with pytest.raises(st.InvalidInputError, match=r"^origin must be a pair of finite numbers \(x, y\); got \(5,\)$"):
        next(st.stepped_series(series, interval=0.25, origin=(5,)))

@pytest.mark.parametrize(
    "height_range",
    [(0.0, float("nan")), (0.0, float("inf")), (-float("inf"), 0.0), (10.0, 0.0), "ab", (1.0, 2.0, 3.0), 5.0, None],
)
def test_isovalues_bad_height_range_is_named(height_range):
    """st.isovalues((0, nan), interval=1) raised 'cannot convert float NaN to integer', (0, inf) an OverflowError,
    (10, 0) numpy's 'zero-size array to reduction operation', 'ab' a TypeError on str - float; now each is an
    InvalidInputError naming height_range."""
    with pytest.raises(st.InvalidInputError, match=r"height_range must be .*\(min, max\)"):
        st.isovalues(height_range, interval=1.0)
    assert st.isovalues((3.0, 3.0), interval=1.0).tolist() == [3.0]

@pytest.mark.parametrize(
    ("heights", "match"),
    [
        (np.zeros(5), "2-D"),
        (np.zeros((1, 5)), "at least 2 x 2"),
        (np.array([["a", "b"], ["c", "d"]]), "real-valued"),
        (np.array([[0.0, np.inf], [0.0, 0.0]]), "infinite value at index"),
        (np.full((3, 3), np.nan), "no finite height"),
    ],
)
def test_bad_heights_raise_clear_errors(heights, match):
    with pytest.raises(st.InvalidInputError, match=match):
        st.stepped(heights, interval=1.0)


def test_a_bool_among_list_heights_is_refused():
    """heightfield_mesh([[True, 2.0], [3.0, 4.0]]) stepped True as a height of 1 (numpy turns a bool beside numbers
    into one); a bool array was already refused, as real_numbers refuses a bool in a list elsewhere."""
    for make in (st.heightfield_mesh, lambda h: st.stepped(h, interval=1.0), st.Terrain.from_heights):
        with pytest.raises(st.InvalidInputError, match=r"^heights must be a real-valued \(H, W\) array; got a bool "
                           r"\(True\) at index \(1, 0\)$"):
            make([[0.0, 2.0], [True, 4.0]])
    assert len(st.heightfield_mesh([[0, 2], [1.5, 4]]).faces) == 2  # ints and floats together are numbers


@pytest.mark.parametrize("value", [1e300, -1e39])
def test_heights_beyond_float32_are_named_not_called_infinite(value):
    """A finite float64 height beyond float32's range was 'an infinite value at index (2, 3)' (after numpy's
    'overflow encountered in cast' warning); it is finite: the message says so and shows it."""
    heights = np.add.outer(np.arange(4.0), np.arange(5.0))
    heights[2, 3] = value
    match = (rf"^heights must fit in float32 \(\|h\| < 3.4e\+38\); got {re.escape(repr(value))} at index \(2, 3\), "
             r"finite but beyond float32's range$")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for make in (lambda: st.stepped(heights, interval=1.0), lambda: st.Terrain.from_heights(heights)):
            with pytest.raises(st.InvalidInputError, match=match):
                make()
    heights[2, 3] = np.finfo(np.float32).max  # the largest float32 is fine
    assert st.Terrain.from_heights(heights).heights[2, 3] == np.finfo(np.float32).max


def test_heights_spanning_beyond_float32_are_refused():
    """Heights from -2e38 to 2e38 fit float32, their differences do not: the step kernels took β = 2e38 / inf = 0 and
    put the wall of threshold 0 on the edge's lower end instead of its middle (from -3e38 to 3e38: inf / inf, NaN
    vertices), in a mesh returned without an error."""
    for top, levels in ((2e38, [-1e38, 1e38]), (3e38, [-3e38, 0.0, 3e38])):
        heights = np.array([[-top, top], [-top, top]], dtype=np.float32)
        message = (f"heights [-{top:g}, {top:g}] span {2 * top:.3g}, beyond float32 (3.4e+38): the step kernels take "
                   "height differences in float32")
        with pytest.raises(st.InvalidInputError, match=f"^{re.escape(message)}$"):
            st.stepped(heights, levels=levels)
    with pytest.raises(st.InvalidInputError, match=r"span 4e\+38, beyond float32"):  # uniform isovalues likewise
        st.stepped(np.array([[-2e38, 0.0], [1.0, 2e38]], dtype=np.float32), interval=1e38)
    half = np.array([[-1e38, 1e38], [-1e38, 1e38]], dtype=np.float32)  # a span of 2e38: the wall in the middle
    mesh = st.stepped(half, levels=[-1e38, 1e38])
    assert np.unique(np.round(mesh.vertices[:, 0], 6)).tolist() == [0.0, 0.5, 1.0]


@pytest.mark.parametrize("n_vertices", [0, 3])
@pytest.mark.parametrize("process", [False, True])
def test_empty_terrain_mesh_is_refused(n_vertices, process):
    """Issue 2 §7: a TIN with no faces (with or without vertices) is a clear InvalidInputError, not an empty
    result or a crash in the edge table."""
    empty = trimesh.Trimesh(vertices=np.arange(3.0 * n_vertices).reshape(-1, 3), faces=np.zeros((0, 3), int),
                            process=process)
    with pytest.raises(st.errors.InvalidInputError, match="no faces"):
        st.stepped(empty, interval=1)


@pytest.mark.parametrize("shape", [(0, 0), (0, 4), (4, 0)])
def test_empty_heights_are_refused(shape):
    expected = rf"at least 2 x 2 nodes; got shape \({shape[0]}, {shape[1]}\)"
    with pytest.raises(st.errors.InvalidInputError, match=expected):
        st.stepped(np.zeros(shape, np.float32), interval=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"origin": (5,)}, r"^origin must be a pair of finite numbers \(x, y\); got \(5,\)$"),
        ({"origin": [5.0]}, r"^origin must be a pair of finite numbers \(x, y\); got \[5.0\]$"),
        ({"origin": 5.0}, r"^origin must be a pair of finite numbers \(x, y\); got 5.0$"),
        ({"spacing": (5,)}, r"^spacing must be a pair of finite numbers .* \(or one number for both\); got \(5,\)$"),
        ({"spacing": np.array([2.0])}, r"^spacing must be a pair .* \(or one number for both\); got array\(\[2.\]\)$"),
    ],
)
def test_one_element_origin_or_spacing_is_refused(kwargs, match):
    """origin=(5,) was taken as (5, 5) silently, and so was a scalar origin or spacing=(5,): a pair that lost its
    y. A point needs both coordinates (adaptive_mesh already refused a scalar origin); a spacing may still be one
    number for square cells."""
    with pytest.raises(st.InvalidInputError, match=match):
        st.stepped(np.eye(3), interval=0.5, **kwargs)
    with pytest.raises(st.InvalidInputError, match=match):
        st.Terrain.from_heights(np.eye(3), **kwargs)
    square = st.stepped(np.eye(3), interval=0.5, spacing=5.0)
    np.testing.assert_array_equal(square.vertices, st.stepped(np.eye(3), interval=0.5, spacing=(5.0, 5.0)).vertices)


def test_bad_spacing_and_paths():
    with pytest.raises(st.InvalidInputError, match="spacing must be non-zero"):
        st.stepped(np.zeros((3, 3)), interval=1.0, spacing=(0.0, 1.0))
    # nodes are placed in float32: a spacing of 1e-300 gave a flat, zero-area mesh silently
    for spacing in (1e-300, (1.0, -1e-40), (1e31, 1.0)):
        with pytest.raises(st.InvalidInputError, match=r"spacing must lie between 1e-30 and 1e\+30 in magnitude"):
            st.stepped(np.zeros((3, 3)), interval=1.0, spacing=spacing)
    assert len(st.stepped(np.eye(3), interval=0.5, spacing=(1e-30, -1e30)).faces) > 0
    with pytest.raises(st.InvalidInputError, match="load it first"):
        st.stepped("terrain.tif", interval=1.0)
    with pytest.raises(st.InvalidInputError, match="spacing/origin apply to raw"):
        st.stepped(st.Terrain.from_heights(np.zeros((3, 3))), interval=1.0, spacing=(2.0, 2.0))


def test_small_memory_budgets_and_outputs_are_named_in_bytes():
    """memory_budget=1000 read "would need 0.0 MiB, over the memory budget of 0.0 MiB": sizes below a tenth of a
    MiB are given in bytes now."""
    with pytest.raises(st.OutputTooLargeError, match=r"^the stepped mesh \(\d+ vertices, \d+ faces\) would need "
                       r"[\d,]+ bytes, over the memory budget of 1,000 bytes; "):
        st.stepped(np.add.outer(np.arange(4.0), np.arange(4.0)), interval=1.0, memory_budget=1000)
    with pytest.raises(st.OutputTooLargeError, match=r"would need [\d,.]+ MiB, over the memory budget of 1,000 bytes"):
        st.stepped(np.add.outer(np.arange(64.0), np.arange(64.0)), interval=1.0, memory_budget=1000)


def test_memory_budget_raises_before_allocating_and_names_the_size():
    heights = np.add.outer(np.arange(64.0), np.arange(64.0))
    with pytest.raises(st.OutputTooLargeError, match=r"MiB, over the memory budget"):
        st.stepped(heights, interval=1.0, memory_budget=10_000)
    previous = st.set_memory_budget(10_000)
    try:
        with pytest.raises(MemoryError, match="crop or coarsen the input .* or coarsen the isovalues"):
            st.stepped(heights, interval=1.0)
    finally:
        st.set_memory_budget(previous)


@pytest.mark.parametrize("memory_budget", [None, 2**62])
def test_more_vertices_than_int32_indexes_are_refused_not_wrapped(memory_budget):
    """2 x 400 nodes alternating 0 and 999,000 at interval 1: ~1200 edges cross ~1e6 thresholds each, 2.4e9
    wall vertices. The int32 scan of the counts wrapped (a negative total gave 'Invalid indexing in slice';
    a total past 2^32 wraps to a small positive one, and the emit pass would write beyond its arrays), and
    the budget check saw the wrapped size: refused with the true size, whatever the budget."""
    heights = np.zeros((2, 400))
    heights[:, 1::2] = 999_000.0
    with pytest.raises(st.OutputTooLargeError, match=r"2,\d{3},\d{3},\d{3} vertices, more than"):
        st.stepped(heights, interval=1.0, memory_budget=memory_budget)


@pytest.mark.parametrize("budget", [-1, 0, 2.5e9, "1GB", True])
def test_bad_memory_budget_is_named(budget):
    heights = np.add.outer(np.arange(8.0), np.arange(8.0))
    with pytest.raises(st.InvalidInputError, match=r"memory_budget must be a positive int of bytes; got"):
        st.stepped(heights, interval=1.0, memory_budget=budget)
    with pytest.raises(st.InvalidInputError, match=r"memory budget must be a positive int of bytes; got"):
        st.set_memory_budget(budget)


def test_device_errors():
    with pytest.raises(st.DeviceError, match="device must be one of"):
        st.stepped(np.zeros((3, 3)), interval=1.0, device="tpu:7")
    missing = f"cuda:{len(wp.get_cuda_devices())}"  # one past the last GPU: none at all on a CPU machine
    expected = "needs a CUDA GPU" if not wp.is_cuda_available() else "device must be one of"
    with pytest.raises(st.DeviceError, match=expected):
        st.stepped(np.zeros((3, 3)), interval=1.0, device=missing)


@pytest.mark.skipif(wp.is_cuda_available(), reason="needs a machine without CUDA")
def test_cuda_without_a_gpu_is_refused_without_native_noise(capfd):
    """The one-line DeviceError only: Warp's native 'CUDA error ... cuCtxGetCurrent' lines, printed when a
    CUDA device is looked up without a driver, must not reach the user's terminal."""
    with pytest.raises(st.DeviceError, match="needs a CUDA GPU"):
        st.stepped(np.zeros((3, 3)), interval=1.0, device="cuda")
    out, err = capfd.readouterr()
    assert "CUDA error" not in out + err, out + err


@pytest.mark.parametrize("solid", ["no", "False", 1, None, [True]])
def test_solid_must_be_a_bool(solid, tmp_path):
    """solid="no" built a solid (a non-empty string is true); batch likewise."""
    with pytest.raises(st.InvalidInputError, match=r"solid must be True or False; got"):
        st.stepped(np.zeros((3, 3)), interval=1.0, solid=solid)
    with pytest.raises(st.InvalidInputError, match=r"solid must be True or False; got"):
        st.batch(np.zeros((3, 3)), tmp_path / "out", tile_size=2, interval=1.0, solid=solid, scheduler="serial")
    assert not (tmp_path / "out").exists()
    assert st.stepped(np.zeros((3, 3)), interval=1.0, solid=np.bool_(True)).is_watertight


def test_as_terrain_accepts_every_input_kind(dem):
    assert as_terrain(dem).kind == "grid"
    assert as_terrain(st.heightfield_mesh(dem[:5, :5])).kind == "tin"


@settings(max_examples=60)
@given(arrays(np.float32, st_.tuples(st_.integers(2, 7), st_.integers(2, 7)),
              elements=st_.one_of(st_.floats(-1e4, 1e4, width=32), st_.just(np.nan))))
def test_height_range_is_the_finite_min_and_max(heights):
    """The grid's cheap path (no nodata: min and max, no copy) and the masked path agree with nanmin/nanmax where
    every finite node is on a triangle; a grid and its TIN count only the nodes (points) on a triangle with three
    finite heights (kept faces), the grid its finite heights where there is none; all nodata is refused by name."""
    t = as_terrain(heights)
    if np.isnan(heights).all():
        with pytest.raises(st.InvalidInputError, match="no finite height"):
            _ = t.height_range
        return
    mesh = st.heightfield_mesh(heights)
    if len(mesh.faces):  # a TIN: the heights of the points on its faces (NaN nodes are on none)
        z = np.asarray(mesh.vertices)[np.unique(mesh.faces), 2]
        expected = (float(z.min()), float(z.max()))
        assert as_terrain(mesh).height_range == expected
    else:
        expected = (float(np.nanmin(heights)), float(np.nanmax(heights)))
    if not np.isnan(heights).any():
        assert expected == (float(heights.min()), float(heights.max()))
    assert t.height_range == expected and t.height_range == expected  # computed once, then cached


def test_tin_edge_table_is_built_once_and_rebuilt_after_a_change():
    tin = st.heightfield_mesh(np.add.outer(np.arange(6.0), np.arange(7.0)))
    first = as_terrain(tin)
    assert as_terrain(tin) is first
    a = st.stepped(tin, interval=2.0)
    assert as_terrain(tin) is first
    tin.vertices[:, 2] += 0.5
    assert as_terrain(tin) is not first
    b = st.stepped(tin, interval=2.0)
    assert not np.array_equal(a.vertices, b.vertices)


def test_input_uvs_are_carried():
    base = st.heightfield_mesh(np.array([[0.0, 1.0], [2.0, 3.0]]))
    uv = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    base.visual = trimesh.visual.TextureVisuals(uv=uv)
    mesh = st.stepped(base, interval=1.0)
    assert mesh.visual.kind == "texture"
    carried = np.asarray(mesh.visual.uv)
    assert carried.shape == (len(mesh.vertices), 2)
    # every output vertex's uv is the uv of its xy position (uv = x, y here)
    np.testing.assert_allclose(carried, mesh.vertices[:, :2], atol=1e-6)


def test_input_uvs_not_one_per_vertex_are_refused_before_stepping():
    """A TIN whose visual.uv has fewer rows than vertices (trimesh keeps it) raised an IndexError from
    _carry_visual after the kernels ran; now an InvalidInputError names visual.uv, for a solid too (it carries the
    visual as well). With colors= the input's visual is not carried, so the mesh steps."""
    base = st.heightfield_mesh(np.array([[0.0, 1.0], [2.0, 3.0]]))
    base.visual = trimesh.visual.TextureVisuals(uv=np.zeros((2, 2)))
    with pytest.raises(st.InvalidInputError, match=r"^terrain mesh visual.uv must hold one \(u, v\) row per vertex, "
                       r"shape \(4, 2\), to be carried onto the steps; got shape \(2, 2\)"):
        st.stepped(base, interval=1.0)
    with pytest.raises(st.InvalidInputError, match=r"^terrain mesh visual.uv must hold one \(u, v\) row per vertex"):
        st.stepped(base, interval=1.0, solid=True)
    assert len(st.stepped(base, interval=1.0, colors="terrain").faces)
    assert len(st.stepped(base, interval=1.0, colors="terrain", solid=True).faces)


@pytest.mark.parametrize(("threads", "chunk"), [(2, 64), (3, 64), (3, 1), (2, 8)])
def test_cpu_passes_split_over_threads_give_identical_meshes(monkeypatch, threads, chunk):
    """Neither the CPU thread count nor the elements per thread (launch_chunked) change the mesh."""
    import stepterrain._device as device_module

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=60, step=5).copy()
    heights[5:9, 30:40] = np.nan
    tin = st.heightfield_mesh(heights[:30, :30])
    single = [st.stepped(heights, interval=40.0, gamma=0.8, device="cpu"), st.stepped(tin, interval=40.0)]
    monkeypatch.setattr(device_module, "MIN_THREAD_ELEMENTS", 16)
    monkeypatch.setattr(device_module, "CPU_CHUNK", chunk)
    previous = st.set_cpu_threads(threads)
    try:
        split = [st.stepped(heights, interval=40.0, gamma=0.8, device="cpu"), st.stepped(tin, interval=40.0)]
    finally:
        st.set_cpu_threads(previous)
    for a, b in zip(single, split, strict=True):
        np.testing.assert_array_equal(a.faces, b.faces)
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.face_attributes["level"], b.face_attributes["level"])


def test_cpu_threads_must_be_positive():
    with pytest.raises(st.InvalidInputError, match="threads must be a positive int"):
        st.set_cpu_threads(0)
    for bad in (np.int64(0), np.bool_(True), 2.0, "2"):
        with pytest.raises(st.InvalidInputError, match="threads must be a positive int or None; got"):
            st.set_cpu_threads(bad)


def test_cpu_threads_take_numpy_integers():
    """set_cpu_threads(np.int64(2)) was refused as 'not a positive int' while set_memory_budget, load_dem(band=) and
    circular_lens(resolution=) take numpy integers (a count read from an array or a config parsed by numpy)."""
    previous = st.set_cpu_threads(np.int64(2))
    try:
        assert st.get_cpu_threads() == 2 and type(st.get_cpu_threads()) is int
    finally:
        st.set_cpu_threads(previous)


def test_embedded_dem_steps_into_a_valid_welded_mesh():
    dem = st.sample_dem()
    mesh = st.stepped(dem, interval=250.0, base=0.5)
    assert_valid_mesh(mesh)
    values = isovalues(dem.height_range, interval=250.0, base=0.5)
    assert np.isin(mesh.vertices[:, 2].astype(np.float32), values).all()
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges[:, 0] * len(mesh.vertices) + edges[:, 1], return_counts=True)
    assert counts.max() == 2  # no height sits on a threshold at base 0.5: edge-manifold
    terrace = ~mesh.face_attributes["wall"]
    source_area = (dem.extent[1] - dem.extent[0]) * (dem.extent[3] - dem.extent[2])
    np.testing.assert_allclose(projected_area(mesh, terrace).sum(), source_area, rtol=1e-6)


@pytest.mark.parametrize("colors, message", [
    (np.full((3, 3), 999), r"integer colors must lie in \[0, 255\]; got values from 999 to 999"),
    (np.full((3, 3), -1), r"integer colors must lie in \[0, 255\]; got values from -1"),
    (np.full((3, 3), 1.5), r"float colors must lie in \[0, 1\]; got values from 1.5 to 1.5"),
    (np.full((3, 3), np.nan), r"float colors must lie in \[0, 1\]"),
    (np.array([["red"] * 3] * 3), r"colors must be numbers"),
])
def test_level_colors_out_of_range_are_refused(colors, message):
    heights = np.add.outer(np.arange(5.0), np.arange(5.0))  # 0..8: levels 0, 4, 8 at interval 4
    with pytest.raises(st.InvalidInputError, match=message):
        st.stepped(heights, interval=4.0, colors=colors)
    ok = st.stepped(heights, interval=4.0, colors=np.full((3, 3), 255, np.int64))  # the full range is fine
    assert len(ok.faces)


def test_huge_level_counts_are_reported_readably():
    with pytest.raises(st.InvalidInputError, match=r"gives 1e\+300 levels; at most 1,000,000 are supported"):
        st.stepped(np.array([[0.0, 1.0], [0.0, 1.0]]), interval=1e-300)


@pytest.mark.parametrize(("interval", "base"), [(1e-320, 0.0), (5e-324, 0.0), (0.5, -1.7e308)])
def test_level_counts_beyond_float64_are_refused_not_an_overflow(interval, base):
    """A subnormal interval (1e-320) divided the height range to infinity and isovalues raised Python's
    'OverflowError: cannot convert float infinity to integer' (stepped, stepped_series and 'stepterrain steps
    --interval 1e-320', a traceback there); now it is the level cap's InvalidInputError."""
    heights = np.array([[0.0, 1.0], [0.0, 1.7e38]])
    with pytest.raises(st.InvalidInputError, match=r"gives more levels than float64 can count; at most 1,000,000"):
        st.isovalues((0.0, 1.7e38), interval=interval, base=base)
    named = "^" + re.escape(f"interval={interval:g} with base={base:g} over heights")
    with pytest.raises(st.InvalidInputError, match=named):
        st.stepped(heights, interval=interval, base=base)
    with pytest.raises(st.InvalidInputError, match="more levels than float64 can count"):
        next(st.stepped_series(heights[None], interval=interval, base=base))


def test_a_terrain_without_a_complete_triangle_gives_an_empty_mesh_and_no_solid():
    heights = np.array([[1.0, np.nan], [np.nan, np.nan]])
    assert len(st.stepped(heights, interval=1.0).faces) == 0
    with pytest.raises(st.InvalidInputError, match="solid=True needs a surface to close"):
        st.stepped(heights, interval=1.0, solid=True)


_HEIGHTS = np.add.outer(np.arange(4.0), np.arange(5.0))  # 0..7
_NODES = np.full(_HEIGHTS.shape, 0.5)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        # numpy read text, bools and complex values as numbers (dropping an imaginary part with a warning only), and
        # np.asarray dropped a mask: each was stepped silently
        (lambda: st.stepped(_HEIGHTS, levels=["1", "5"]), r"^levels must be .*\(real numbers\); got dtype <U1$"),
        (lambda: st.stepped(_HEIGHTS, levels="5"), r"^levels must be a sequence of numbers .*; got dtype <U1$"),
        (lambda: st.stepped(_HEIGHTS, levels=[True, 5]), r"^levels must .*; got a bool \(True\) at index \(0,\)$"),
        (lambda: st.stepped(_HEIGHTS, levels=np.array([1 + 0j, 5 + 1j])), r"^levels must .*; got dtype complex128$"),
        (lambda: st.stepped(_HEIGHTS, levels=np.ma.masked_array([1.0, 3.0, 5.0], mask=[0, 1, 0])),
         r"^levels must be finite; got \[1.0, nan, 5.0\]$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma="0.5"), r"^gamma must be a number in .*; got '0.5'$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=True), r"^gamma must be a number in \[0, 1\], .*; got True$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=None), r"^gamma must be a number in \[0, 1\], .*; got None$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=_NODES > 0), r"^gamma must .*; got dtype bool$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=_NODES + 1j), r"^gamma must .*; got dtype complex128$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=np.ma.masked_greater(_NODES, 0.4)),
         r"^gamma must lie in \[0, 1\] \(0 = original, 1 = stepped\); got nan at index \(0, 0\)$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=np.where(_HEIGHTS > 5, np.nan, _NODES)),
         r"^gamma must lie in \[0, 1\] .*; got nan at index \(2, 4\)$"),  # was "got values in [0.5, 0.5]"
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=lambda p: np.full(len(p), 0.5 + 1j)),
         r"^gamma\(points\) must be a number in \[0, 1\] per output vertex \(real numbers\); got dtype complex128$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=lambda p: np.ma.masked_all(len(p))),
         r"^gamma\(points\) must lie in \[0, 1\] .*; got nan at index \(0,\)$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, gamma=lambda p: 0.5),  # one γ per output vertex, not per node
         r"^gamma\(points\) must be shape \(\d+,\) \(one γ per output vertex\); got shape \(\)$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, solid=True, floor="-5"), r"^floor must be a number .*; got '-5'$"),
        (lambda: st.stepped(_HEIGHTS, interval=1.0, solid=True, floor=True), r"^floor must be a number .*; got True$"),
        (lambda: st.isovalues(("1", "5"), interval=1.0), r"^height_range must be \(min, max\) heights"),
        (lambda: st.circular_lens(_HEIGHTS, "12", 1.0), r"^lens center must be \(x, y\); got '12'$"),
        (lambda: st.circular_lens(_HEIGHTS, (True, 1.0), 1.0), r"^lens center must be \(x, y\); got \(True, 1.0\)$"),
        (lambda: st.Lens(np.ones((2, 2)), "0101"), r"^lens extent must be \(xmin, xmax, ymin, ymax\)"),
        (lambda: st.Lens(np.ones((2, 2)), ("0", "1", "0", "1")), r"^lens extent must be \(xmin, xmax, ymin, ymax\)"),
        (lambda: st.Lens(np.full((2, 2), 0.5 + 1j)), r"^lens mask must be a real \(h, w\) array; .*dtype complex128$"),
        (lambda: st.Lens(np.ma.masked_greater(np.full((2, 2), 0.5), 0.4)), r"^lens mask values must lie in \[0, 1\]"),
    ],
)
def test_text_bools_complex_and_masked_values_are_not_numbers(call, match):
    """levels, γ (scalar, per node, a callable's result), floor, height_range and a lens' center, extent and mask
    took "5", True, complex values (imaginary part dropped) and masked arrays (mask dropped) as numbers; the other
    arguments refuse them (as_number, real_numbers). Decimals and numpy numbers stay numbers."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way
        with pytest.raises(st.InvalidInputError, match=match):
            call()
    from decimal import Decimal

    mesh = st.stepped(_HEIGHTS, levels=[Decimal(1), np.float32(5)], gamma=Decimal("0.5"))
    assert len(mesh.faces)


@pytest.mark.parametrize("tin", [False, True], ids=["grid", "tin"])
def test_per_node_gamma_may_be_nan_where_heights_are_nodata(tin):
    """γ computed from h (np.clip(h / 10, 0, 1)) is NaN where h is nodata, and was refused ("got nan at index");
    those nodes give no vertex, so NaN there is taken (the mesh is the one any γ value there gives). NaN at a
    node with a height is still refused, with its index."""
    heights = _HEIGHTS.copy()
    heights[1:3, 1:3] = np.nan
    terrain = heights
    if tin:  # a TIN whose nodata vertices keep NaN z
        terrain = st.heightfield_mesh(np.nan_to_num(heights))
        terrain.vertices[:, 2] = heights.reshape(-1)
    nodata = np.isnan(heights).reshape(-1) if tin else np.isnan(heights)
    gamma = np.clip(heights / 10.0, 0.0, 1.0).reshape(nodata.shape)
    mesh = st.stepped(terrain, interval=1.0, gamma=gamma)
    filled = st.stepped(terrain, interval=1.0, gamma=np.where(nodata, 0.25, gamma))
    assert len(mesh.faces) > 0
    np.testing.assert_array_equal(mesh.vertices, filled.vertices)
    np.testing.assert_array_equal(mesh.faces, filled.faces)
    # a node with a height that the surface uses (node (0, 0), which this test took, has a height but is on no
    # triangle with three finite heights: its one cell touches the void, so no vertex reads its γ)
    gamma[(4,) if tin else (0, 4)] = np.nan
    at = "4," if tin else "0, 4"
    with pytest.raises(st.InvalidInputError, match=rf"^gamma must lie in \[0, 1\] .*; got nan at index \({at}\)$"):
        st.stepped(terrain, interval=1.0, gamma=gamma)


def test_extreme_but_handled_inputs_leak_no_overflow_warning():
    """A solid on levels spanning more than float32 holds (-3e38 to 3e38) took np.ptp of the float32 levels: inf
    with numpy's "overflow encountered" warning, a default floor of -inf and "floor must be finite; got -inf" for a
    floor nobody gave; it is taken in float64 now and the default floor, a tenth of the span below, stops at
    float32's lowest value. A TIN whose x spans -1e308 to 1e308 warned twice before it was refused."""
    heights = np.array([[-1e38, 0.0, 1.0], [2.0, 1e38, 5.0], [1.0, 2.0, 1e38]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        solid = st.stepped(heights, levels=[-3e38, 0.0, 3e38], solid=True)
        assert np.isfinite(solid.vertices).all() and solid.is_watertight
        assert solid.metadata["floor"] == -float(np.finfo(np.float32).max)
        tin = trimesh.Trimesh([[-1e308, 0.0, 0.0], [1e308, 0.0, 1.0], [0.0, 1e308, 2.0]], [[0, 1, 2]], process=False)
        with pytest.raises(st.InvalidInputError, match=r"^terrain mesh x and y must span at most 3.4e\+38 .*got x over "
                                                       r"inf, y over 1e\+308$"):
            st.stepped(tin, interval=1.0)
    # the default floor of ordinary levels is unchanged: a tenth of their span below the lowest
    levels = st.stepped(np.eye(3) * 7.3, levels=[0.0, 2.5, 7.25], solid=True)
    assert levels.metadata["floor"] == 0.0 - max(float(np.ptp(np.array([0.0, 2.5, 7.25], np.float32))), 1.0) * 0.1


@pytest.mark.parametrize("device", DEVICES)
@settings(max_examples=40, deadline=None)
@given(
    n_thresholds=st_.sampled_from([1, 2, 15, 16, 17, 63, 64, 65, 200]),
    uniform=st_.booleans(),
    n_nodes=st_.integers(1, 300),
    seed=st_.integers(0, 2**16),
)
def test_node_levels_count_the_thresholds_at_or_below(device, n_thresholds, uniform, n_nodes, seed):
    """quantize_levels gives every node the number of thresholds <= its height (NaN: 0), whichever way it counts:
    sixteen nodes at a time against every threshold on the CPU up to 64 thresholds, the estimate-and-correct or
    binary search otherwise; heights on thresholds, between them, beyond both ends, signed zeros and NaN."""
    rng = np.random.default_rng(seed)
    if uniform:
        values = (np.arange(n_thresholds + 1) * 2.5 - 10.0).astype(np.float32)
    else:
        values = np.sort(rng.choice(np.arange(-500, 500), n_thresholds + 1, replace=False)).astype(np.float32)
    thresholds = thresholds_of(values)  # the reference's
    pool = np.concatenate([thresholds, values, [-0.0, 0.0, np.nan, -1e30, 1e30]]).astype(np.float32)
    heights = np.where(rng.random(n_nodes) < 0.5, rng.choice(pool, n_nodes),
                       rng.uniform(values[0] - 20, values[-1] + 20, n_nodes)).astype(np.float32)  # fmt: skip
    dev = resolve_device(device)
    levels = wp.zeros(n_nodes, dtype=wp.int32, device=dev)
    launch_chunked(stepped_kernels.quantize_levels, n=n_nodes,
                   inputs=[wp.array(heights, dtype=wp.float32, device=dev), _build_isovalue_struct(values, dev)],
                   outputs=[levels], device=dev)  # fmt: skip
    expected = np.where(np.isnan(heights), 0, np.searchsorted(thresholds, heights, side="right"))
    np.testing.assert_array_equal(levels.numpy(), expected)


def assert_stepped_as_the_generic_pass(t, values, gamma, device):
    """``stepped`` (its default output, which the CPU's native fast paths write) gives the faces, face levels,
    walls and vertex bits of the generic pass (``step_arrays`` with sources, then ``blend``); returns the mesh."""
    mesh = st.stepped(t, levels=values, gamma=gamma, device=device)
    dev = resolve_device(device)
    generic = step_arrays(t, values, device=dev, want_sources=True)
    np.testing.assert_array_equal(mesh.faces, generic.faces)
    np.testing.assert_array_equal(mesh.face_attributes["level"], generic.face_levels)
    np.testing.assert_array_equal(mesh.face_attributes["wall"], generic.face_walls)
    np.testing.assert_array_equal(mesh.vertices.view(np.int64), blend(t, generic, gamma, device=dev).view(np.int64))
    return mesh


@pytest.mark.parametrize("dy", [30.0, -30.0])
def test_flat_runs_come_out_as_the_generic_grid_pass_writes_them(device, dy):
    """emit_grid writes runs of plain nodes with flat cells in one native loop on the CPU (the default output:
    blended vertices, no sources); step_arrays with sources takes the generic path, which the reference tests
    check. Plateaus wide enough for runs across the 64-node chunks and up to the row ends, some exactly on a
    threshold (twins and peaks, which end a run), both windings: the same faces, levels, walls and vertex bits."""
    rows, cols = np.mgrid[0:90, 0:150].astype(np.float64)
    smooth = 40.0 * np.sin(rows / 17.0) * np.cos(cols / 23.0) + 0.3 * cols
    heights = np.floor(smooth / 5.0) * 5.0  # plateaus, every other one on a threshold (t_i = 5 + 10 i)
    heights[::7, ::11] += 0.25  # lone bumps inside plateaus
    values = np.arange(-60.0, 120.0, 10.0, dtype=np.float32)
    t = st.Terrain.from_heights(heights, spacing=(30.0, dy), origin=(394000.0, 3798000.0))
    assert_stepped_as_the_generic_pass(t, values, 1.0, device)
    flat = (heights[:-1, :-1] == heights[1:, 1:]) & (heights[:-1, :-1] == heights[:-1, 1:])
    assert (flat & (heights[:-1, :-1] == heights[1:, :-1])).mean() > 0.5  # the runs are there to take
