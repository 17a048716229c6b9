"""The planar case of paper 003: adaptive RTIN / SOAR meshes of one heightfield with a true error bound."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hst
from hypothesis.extra.numpy import arrays
from stepterrain.kernels import cubesphere as cs

from stepterrain.errors import InvalidInputError
from stepterrain.globe import Camera, adaptive_mesh
from stepterrain.mesh import boundary_edges

from .conftest import assert_valid_mesh
from .test_globe import shared_file


def dem(name: str, rows: int, cols: int, step: int = 1) -> np.ndarray:
    with np.load(shared_file(name)) as d:
        z = np.asarray(d["elevation"], dtype=np.float32)
    return np.ascontiguousarray(z[: rows * step : step, : cols * step : step])


def true_errors(mesh, heights: np.ndarray, spacing=(1.0, 1.0)) -> np.ndarray:
    """|z - mesh(x, y)| at every grid node, by linear interpolation on the mesh's triangles (matplotlib)."""
    import matplotlib.tri as mtri

    rows, cols = heights.shape
    v = np.asarray(mesh.vertices)
    tri = mtri.Triangulation(v[:, 0], v[:, 1], np.asarray(mesh.faces))
    interp = mtri.LinearTriInterpolator(tri, v[:, 2])
    i, j = np.mgrid[0:rows, 0:cols]
    z = interp(j * spacing[0], i * spacing[1])
    assert not np.ma.is_masked(z) or not z.mask.any(), "a grid node lies outside the mesh"
    return np.abs(np.asarray(z) - heights)


def assert_crack_free_rectangle(mesh, rows: int, cols: int, spacing=(1.0, 1.0)) -> None:
    """Edges used once lie on the rectangle's border (no hanging nodes inside); the mesh covers it exactly."""
    assert_valid_mesh(mesh)
    assert mesh.is_winding_consistent
    assert (mesh.face_normals[:, 2] > 0).all()
    edges = boundary_edges(np.asarray(mesh.faces))
    ends = np.asarray(mesh.vertices)[edges.reshape(-1)][:, :2].reshape(-1, 2, 2)
    w, h = (cols - 1) * spacing[0], (rows - 1) * spacing[1]
    on_x = np.isclose(ends[..., 0], 0) | np.isclose(ends[..., 0], w)
    on_y = np.isclose(ends[..., 1], 0) | np.isclose(ends[..., 1], h)
    same_side = (np.isclose(ends[:, 0, 0], ends[:, 1, 0]) & on_x.all(axis=1)) | (
        np.isclose(ends[:, 0, 1], ends[:, 1, 1]) & on_y.all(axis=1))
    assert same_side.all(), "an edge used by one face lies inside the rectangle (crack or hanging node)"
    projected = mesh.area_faces * mesh.face_normals[:, 2]
    assert projected.sum() == pytest.approx(w * h, rel=1e-9)


@pytest.mark.parametrize("error", [2.0, 5.0, 20.0])
def test_true_error_bound_on_big_tujunga(error, device):
    z = dem("big_tujunga_srtm_30m_utm11n.npz", 257, 257)
    mesh = adaptive_mesh(z, error=error, spacing=30.0, device=device)
    assert_crack_free_rectangle(mesh, 257, 257, (30.0, 30.0))
    worst = true_errors(mesh, z, (30.0, 30.0)).max()
    assert worst <= error + 1e-3
    assert worst > 0.5 * error  # not needlessly fine
    assert len(mesh.faces) < 2 * 256 * 256


def test_true_error_bound_on_front_range_padded():
    z = dem("front_range_srtmgl3_3arcsec.npz", 300, 190)  # not 2^k + 1: padded internally, cut back exactly
    dx, dy = 70.8, 92.7
    for error in (3.0, 10.0, 40.0):
        mesh = adaptive_mesh(z, error=error, spacing=(dx, dy), device="cpu")
        assert_crack_free_rectangle(mesh, 300, 190, (dx, dy))
        assert true_errors(mesh, z, (dx, dy)).max() <= error + 1e-3
        rows_cols = mesh.metadata["node_index"]
        assert rows_cols[:, 0].max() == 299 and rows_cols[:, 1].max() == 189


def test_fewer_triangles_for_larger_error():
    z = dem("big_tujunga_srtm_30m_utm11n.npz", 129, 129, step=2)
    counts = [len(adaptive_mesh(z, error=e, spacing=60.0).faces) for e in (0.0, 1.0, 5.0, 25.0, 100.0, 1e5)]
    assert counts[0] == 2 * 128 * 128
    assert counts == sorted(counts, reverse=True)
    assert counts[-1] == 2


@pytest.mark.parametrize(("rows", "cols", "error"), [(129, 129, 2.0), (100, 150, 5.0), (65, 65, 0.5)])
def test_node_pass_equals_breadth_first(monkeypatch, rows, cols, error):
    """Without a view the refinement runs as one pass over the nodes; it must give the breadth-first result."""
    import stepterrain.globe as globe_module

    z = dem("big_tujunga_srtm_30m_utm11n.npz", rows, cols)
    fast = adaptive_mesh(z, error=error, spacing=30.0)
    monkeypatch.setattr(globe_module, "_NODE_PASS", False)
    slow = adaptive_mesh(z, error=error, spacing=30.0)

    def triangles(mesh):
        corners = np.asarray(mesh.metadata["node_index"])[np.asarray(mesh.faces)]  # (F, 3, 2) rows, columns
        keys = corners[..., 0] * 100_000 + corners[..., 1]
        first = keys.argmin(axis=1)  # rotate each triangle to start at its smallest corner (keeps the winding)
        rotated = np.take_along_axis(keys, (first[:, None] + np.arange(3)) % 3, axis=1)
        return rotated[np.lexsort(rotated.T[::-1])]

    assert np.array_equal(triangles(fast), triangles(slow))
    assert fast.metadata["levels"] == slow.metadata["levels"]


@pytest.mark.parametrize(("rows", "cols"), [(129, 129), (100, 150), (3, 5)])
def test_errors_only_parameters_equal_the_full_ones(rows, cols):
    """Without a view adaptive_mesh computes e alone (no positions, r = h = 0): the same e, bit for bit, as
    the full (e, r, h) pass, padding and its straddle errors included."""
    import stepterrain.globe as globe_module
    from stepterrain._device import resolve_device

    z = dem("big_tujunga_srtm_30m_utm11n.npz", rows, cols)
    n = 1 + (1 << max(1, math.ceil(math.log2(max(rows, cols) - 1))))
    z = np.pad(z, ((0, n - rows), (0, n - cols)), mode="edge")
    levels = 2 * round(math.log2(n - 1))
    device = resolve_device("cpu")
    values = {}
    for shapes in (True, False):
        grid = globe_module._planar_grid(z, (30.0, 20.0), (rows, cols), shapes=shapes, device=device)
        assert grid.positions.shape[0] == (n * n if shapes else 0)
        params = globe_module._node_parameters(grid, faces=1, levels=levels, device=device, shapes=shapes)
        values[shapes] = params.values.numpy()
    assert np.array_equal(values[True][:, 0], values[False][:, 0])
    assert (values[True][:, 1] > 0).any()  # the full pass has radii; the errors-only pass none
    assert not values[False][:, 1:].any()


@wp.kernel
def _triangle_errors(grid: cs.CubeSphereGrid, corners: wp.array[wp.vec3i], errors: wp.array[wp.float64]):
    t = wp.tid()
    a = corners[3 * t]
    b = corners[3 * t + 1]
    c = corners[3 * t + 2]
    errors[t] = cs.triangle_true_error(grid, 0, wp.vec2i(a[0], a[1]), wp.vec2i(b[0], b[1]), wp.vec2i(c[0], c[1]))


def _brute_force_errors(z: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Largest |z - plane| over the grid nodes inside or on each triangle (barycentric weights per node)."""
    i, j = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    out = []
    for a, b, c in corners.reshape(-1, 3, 3)[:, :, :2].astype(np.int64):
        def edge(p, q):
            return (p[0] - i) * (q[1] - j) - (p[1] - j) * (q[0] - i)
        area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        wa, wb, wc = (edge(p, q) * np.sign(area) for p, q in ((b, c), (c, a), (a, b)))
        inside = (wa >= 0) & (wb >= 0) & (wc >= 0)
        plane = (wa * float(z[a[0], a[1]]) + wb * float(z[b[0], b[1]]) + wc * float(z[c[0], c[1]])) / abs(area)
        out.append(np.abs(z.astype(np.float64) - plane)[inside].max())
    return np.array(out)


def test_triangle_true_error_against_brute_force():
    """The planar e of a triangle: the largest vertical error over every node inside it, on the bisection's
    right triangles (axis-aligned and diagonal edges, whose row bounds are stepped) and on arbitrary ones
    (whose bounds are recomputed per row), in both orientations."""
    import stepterrain.globe as globe_module
    from stepterrain._device import resolve_device

    z = dem("big_tujunga_srtm_30m_utm11n.npz", 33, 33)
    rng = np.random.default_rng(7)
    triangles = []
    for s in (1, 2, 4, 8):  # bisection triangles: hypotenuse along an axis or a diagonal, both windings
        for (di, dj) in ((s, 0), (0, s), (s, s), (s, -s)):
            ci, cj = 16, 16
            a, b = (ci + di, cj + dj), (ci - di, cj - dj)
            for apex in ((ci + dj, cj - di), (ci - dj, cj + di)):
                triangles += [(a, b, apex), (b, a, apex)]
    for _ in range(60):  # arbitrary triangles, non-degenerate
        while True:
            p = rng.integers(0, 33, size=(3, 2))
            if (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[1, 1] - p[0, 1]) * (p[2, 0] - p[0, 0]) != 0:
                break
        triangles.append(tuple(map(tuple, p)))
    corners = np.array([[*q, 0] for tri in triangles for q in tri], dtype=np.int32)
    device = resolve_device("cpu")
    grid = globe_module._planar_grid(z, (1.0, 1.0), z.shape, shapes=False, device=device)
    errors = wp.zeros(len(triangles), dtype=wp.float64, device=device)
    wp.launch(_triangle_errors, dim=len(triangles), inputs=[grid, wp.array(corners, dtype=wp.vec3i, device=device)],
              outputs=[errors], device=device)
    np.testing.assert_allclose(errors.numpy(), _brute_force_errors(z, corners), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("node_pass", [True, False])
def test_padded_input_is_cut_back_whatever_the_metrics(monkeypatch, node_pass):
    """A 3 x 5 grid is padded to 5 x 5: the triangles straddling the input's border must refine even where the
    view clips them, a user metric is 0 or the geometric metric is off, or the mesh keeps the padding rows."""
    import stepterrain.globe as globe_module

    monkeypatch.setattr(globe_module, "_NODE_PASS", node_pass)
    z = np.arange(15, dtype=np.float32).reshape(3, 5)
    away = Camera(eye=(-100.0, -100.0, 50.0), target=(-200.0, -200.0, 0.0))  # sees none of the grid
    for options in ({"camera": away, "cull": False}, {"metrics": ("geometric", lambda p, r: np.zeros(len(p)))},
                    {"metrics": ()}, {"metrics": ("distance",), "camera": away}):  # (distance alone needs the camera)
        mesh = adaptive_mesh(z, error=2.0, **options)
        assert_crack_free_rectangle(mesh, 3, 5)
        assert mesh.metadata["node_index"][:, 0].max() == 2, options


def test_plane_and_origin():
    z = np.add.outer(np.arange(17.0), 2 * np.arange(17.0))
    mesh = adaptive_mesh(z, error=1e-3, spacing=(2.0, 3.0), origin=(100.0, 200.0))
    assert len(mesh.faces) == 2
    assert tuple(mesh.bounds[0]) == (100.0, 200.0, 0.0)
    assert tuple(mesh.bounds[1]) == (132.0, 248.0, 48.0)


def test_user_metric_sees_the_mesh_coordinates_with_the_origin():
    """A user metric received node positions relative to the grid's origin while the mesh (and the camera) are in
    world coordinates: a metric refining near a world point refined near the wrong one, silently. Now its points
    are the mesh's: the same mesh as the origin-free one shifted, and every point inside the mesh's extent."""
    z = dem("big_tujunga_srtm_30m_utm11n.npz", 65, 65)
    origin = (388000.0, 3798000.0)
    seen = []

    def west(points, radius, x0=0.0):
        seen.append(points[:, :2].copy())
        return (points[:, 0] < x0 + 600.0).astype(float)  # refine the western 20 columns only

    plain = adaptive_mesh(z, error=2.0, spacing=30.0, metrics=("geometric", west), device="cpu")
    seen.clear()
    shifted = adaptive_mesh(z, error=2.0, spacing=30.0, origin=origin,
                            metrics=("geometric", lambda p, r: west(p, r, origin[0])), device="cpu")
    points = np.concatenate(seen)
    assert (points >= origin).all() and (points <= np.add(origin, 64 * 30.0)).all()
    np.testing.assert_array_equal(shifted.faces, plain.faces)
    np.testing.assert_allclose(shifted.vertices, plain.vertices + [*origin, 0.0], rtol=0, atol=1e-6)


@settings(max_examples=25, suppress_health_check=[HealthCheck.too_slow])
@given(z=arrays(np.float32, hst.tuples(hst.integers(2, 20), hst.integers(2, 20)),
                elements=hst.floats(-100, 100, width=32)),
       error=hst.floats(0.0, 50.0))
def test_property_bound_and_crack_free(z, error):
    mesh = adaptive_mesh(z, error=error, spacing=1.0, device="cpu")
    rows, cols = z.shape
    assert_crack_free_rectangle(mesh, rows, cols)
    assert true_errors(mesh, z.astype(np.float64)).max() <= error + 1e-3


def test_camera_view_is_crack_free_and_clipped():
    z = dem("big_tujunga_srtm_30m_utm11n.npz", 257, 257)
    spacing = 30.0
    cam = Camera(eye=(1000.0, 1000.0, 3500.0), target=(4000.0, 4000.0, 1000.0), fov=math.radians(50))
    full = adaptive_mesh(z, error=5.0, spacing=spacing, camera=cam, cull=False)
    assert_crack_free_rectangle(full, 257, 257, (spacing, spacing))
    near_far = adaptive_mesh(z, error=5.0, spacing=spacing, camera=cam, metrics=("geometric", "distance"))
    plain = adaptive_mesh(z, error=5.0, spacing=spacing)
    assert len(near_far.faces) < len(plain.faces)
    culled = adaptive_mesh(z, error=5.0, spacing=spacing, camera=cam)
    planes = cam.planes()
    outside = (culled.vertices @ planes[:, :3].T + planes[:, 3]) > 0
    assert not outside[np.asarray(culled.faces)].all(axis=1).any(axis=1).any()
    assert len(culled.faces) < len(full.faces)


def test_bad_planar_input():
    with pytest.raises(InvalidInputError, match="heights must be a real"):
        adaptive_mesh(np.zeros(5), error=1.0)
    with pytest.raises(InvalidInputError, match="NaN.*row 1, column 2"):
        z = np.zeros((4, 4))
        z[1, 2] = np.nan
        adaptive_mesh(z, error=1.0)
    # the mask was dropped: -9999 meshed
    with pytest.raises(InvalidInputError, match=r"3 masked \(nodata\) entries .first at row 1, column 0"):
        adaptive_mesh(np.ma.masked_equal(np.where(np.eye(4, k=-1) > 0, -9999.0, 0.0), -9999.0), error=1.0)
    with pytest.raises(InvalidInputError, match="error must be"):
        adaptive_mesh(np.zeros((4, 4)), error=-1.0)
    with pytest.raises(InvalidInputError, match="spacing dx must be a non-zero"):
        adaptive_mesh(np.zeros((4, 4)), error=1.0, spacing=(0.0, 1.0))
    with pytest.raises(InvalidInputError, match="planar case supports bounds='sphere'"):
        from stepterrain.globe import _metric_options

        _metric_options(("geometric",), "cone", planar=True)


def test_a_north_up_dem_meshes_as_it_is_not_mirrored():
    """adaptive_mesh took positive spacing only and refused a Terrain: a north-up DEM (load_dem's, dy < 0, origin the
    north-west node) had to be handed over as heights[::-1] with the south-west node as origin, or came out mirrored
    north to south. A negative dy (or dx) and a grid Terrain now give the mesh of that flipped grid, each vertex at
    x0 + j·dx, y0 + i·dy of the node metadata["node_index"] names (as heightfield_mesh places it), at its height,
    counter-clockwise seen from +z; a camera and a user metric see the same world positions."""
    import stepterrain as st

    sample = st.sample_dem()
    z = np.ascontiguousarray(sample.heights[:70, :90])
    (x0, y0), (dx, dy) = sample.origin, sample.spacing
    assert dy < 0
    north_up = st.Terrain.from_heights(z, spacing=sample.spacing, origin=sample.origin)
    south_west = (x0, y0 + (z.shape[0] - 1) * dy)
    cam = Camera(eye=(x0 + 500.0, y0 - 300.0, 4000.0), target=(x0 + 1500.0, y0 - 1500.0, 1000.0), fov=math.radians(50))
    north = ("geometric", lambda p, r: 1.0 + (p[:, 1] + r > y0 - 600.0))  # saturated: the spheres are nested
    for options in ({}, {"camera": cam}, {"metrics": north}):
        flipped = adaptive_mesh(z[::-1], error=3.0, spacing=-dy, origin=south_west, **options)
        for mesh in (adaptive_mesh(north_up, error=3.0, **options),
                     adaptive_mesh(z, error=3.0, spacing=(dx, dy), origin=sample.origin, **options)):
            i, j = mesh.metadata["node_index"].T
            np.testing.assert_array_equal(mesh.vertices[:, 0], x0 + j * dx)
            np.testing.assert_array_equal(mesh.vertices[:, 1], y0 + i * dy)
            np.testing.assert_array_equal(mesh.vertices[:, 2], z[i, j])
            assert (mesh.face_normals[:, 2] > 0).all() and mesh.is_winding_consistent
            assert len(mesh.faces) == len(flipped.faces)
            same = {tuple(v) for v in np.round(mesh.vertices[mesh.faces].reshape(-1, 9), 6)}
            assert same == {tuple(v) for v in np.round(flipped.vertices[flipped.faces].reshape(-1, 9), 6)}
    # x mirrored as well: rows and columns both run the other way; the nodes and the true error bound hold
    mesh = adaptive_mesh(z, error=3.0, spacing=(-30.0, -30.0))
    i, j = mesh.metadata["node_index"].T
    np.testing.assert_array_equal(mesh.vertices[:, :2], np.column_stack([-30.0 * j, -30.0 * i]))
    assert (mesh.face_normals[:, 2] > 0).all()
    assert true_errors(mesh, z.astype(np.float64), (-30.0, -30.0)).max() <= 3.0 + 1e-3
    with pytest.raises(InvalidInputError, match="spacing/origin apply to raw .* the Terrain already has them"):
        adaptive_mesh(north_up, error=1.0, spacing=30.0)
    with pytest.raises(InvalidInputError, match="got a TIN Terrain"):
        adaptive_mesh(st.Terrain.from_mesh(st.heightfield_mesh(z[:4, :4])), error=1.0)
    with pytest.raises(InvalidInputError, match="spacing dx must be a non-zero finite number; got 0.0"):
        adaptive_mesh(z, error=1.0, spacing=(0.0, 1.0))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"origin": (float("nan"), 0.0)}, r"origin must be 2 finite numbers \(x0, y0\); got \(nan, 0.0\)"),
        ({"origin": (0.0, float("inf"))}, r"origin must be 2 finite numbers \(x0, y0\); got \(0.0, inf\)"),
        ({"origin": 1.0}, r"origin must be 2 finite numbers \(x0, y0\); got 1.0"),
        ({"origin": (1.0, 2.0, 3.0)}, r"origin must be 2 finite numbers \(x0, y0\); got \(1.0, 2.0, 3.0\)"),
        ({"origin": ("a", "b")}, r"origin must be 2 finite numbers \(x0, y0\); got \('a', 'b'\)"),
        # the string was iterated: origin (1.0, 2.0), silently; a bool was taken as 1.0
        ({"origin": "12"}, r"origin must be 2 finite numbers \(x0, y0\); got '12'"),
        ({"origin": (True, 0.0)}, r"origin must be 2 finite numbers \(x0, y0\); got \(True, 0.0\)"),
        ({"spacing": (1.0, 2.0, 3.0)}, r"spacing must be a number or \(dx, dy\); got \(1.0, 2.0, 3.0\)"),
        ({"spacing": (1.0,)}, r"spacing must be a number or \(dx, dy\); got \(1.0,\)"),
        # float32 node positions: 1e-300 became 0 (every node at x = 0, a zero-area mesh, silently)
        ({"spacing": 1e-300}, r"spacing must lie between 1e-30 and 1e\+30 in magnitude .*got \(1e-300, 1e-300\)"),
        ({"spacing": (1.0, 1e31)}, r"spacing must lie between 1e-30 and 1e\+30 in magnitude .*got \(1.0, 1e\+31\)"),
    ],
)
def test_bad_origin_or_spacing_is_refused_by_name(kwargs, match):
    # a NaN/inf origin gave non-finite vertices; the others raised TypeError/ValueError from unpacking
    with pytest.raises(InvalidInputError, match=match):
        adaptive_mesh(np.zeros((5, 5)), error=0.0, device="cpu", **kwargs)


def test_a_spacing_read_from_an_npz_is_one_number():
    """np.load(...)["dx"] is a 0-d array: heightfield_mesh takes it as one spacing, adaptive_mesh refused it ("spacing
    must be a number or (dx, dy); got array(70.8...)", tuple() of a 0-d array). It is that number now, the same mesh
    as the float's; a 0-d array of text or a bool is still no spacing (float() took np.array('30') and np.array(True)
    as 30.0 and 1.0 inside a pair)."""
    with np.load(shared_file("front_range_srtmgl3_3arcsec.npz")) as data:
        z, dx, dy = data["elevation"][:65, :65], data["dx_m"], data["dy_m"]
    assert dx.ndim == 0
    mesh = adaptive_mesh(z, spacing=dx, error=5.0, device="cpu")
    same = adaptive_mesh(z, spacing=float(dx), error=5.0, device="cpu")
    np.testing.assert_array_equal(mesh.vertices, same.vertices)
    np.testing.assert_array_equal(mesh.faces, same.faces)
    pair = adaptive_mesh(z, spacing=(dx, dy), error=5.0, device="cpu")
    assert np.ptp(pair.vertices[:, 1]) == pytest.approx(64 * float(dy))
    for bad in (np.array("30"), np.array(True), (np.array("30"), 1.0), (1.0, np.array(True))):
        with pytest.raises(InvalidInputError, match=r"^spacing (dx |dy )?must be a (non-zero )?number"):
            adaptive_mesh(z, spacing=bad, error=5.0, device="cpu")
