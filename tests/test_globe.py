"""Global terrain on the cube sphere (paper 003): grid, hierarchy parameters, metrics, refinement, bad input."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import Phase, given, settings
from hypothesis import strategies as hst
from stepterrain.kernels import bounds as bk
from stepterrain.kernels import cubesphere as cs

from stepterrain import globe as globe_module
from stepterrain.errors import InvalidInputError, OutputTooLargeError
from stepterrain.globe import EARTH_RADIUS, Camera, Globe, adaptive_mesh, load_global_relief, look_from

from . import reference_globe as ref
from .conftest import SHARED_DATA, assert_valid_mesh, needs_render, real_dem

# shared/data beside the project; a worktree one level deeper (wt/<name>) finds it one level up
_DATA_DIRS = [SHARED_DATA, Path(__file__).resolve().parents[3] / "shared" / "data"]


def shared_file(name: str) -> Path:
    for folder in _DATA_DIRS:
        if (folder / name).exists():
            return folder / name
    pytest.skip(f"shared data {name} not found in {[str(d) for d in _DATA_DIRS]}")

R = EARTH_RADIUS
LAT1 = np.linspace(89.5, -89.5, 180)
LON1 = np.linspace(-179.5, 179.5, 360)


def real_1deg() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    with np.load(shared_file("global_relief_1deg.npz")) as d:
        return np.asarray(d["lat"]), np.asarray(d["lon"]), np.asarray(d["elevation"])


@pytest.fixture(scope="module")
def small_globe() -> Globe:
    lat, lon, z = real_1deg()
    return Globe.from_latlon(z, lat, lon, face_size=17, exaggeration=20.0, device="cpu")


@pytest.fixture(scope="module")
def sample_globe() -> Globe:
    return Globe.sample(face_size=65, device="cpu")


def welded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    m = mesh.copy()
    m.merge_vertices(digits_vertex=3)
    return m


# ------------------------------------------------------------------------------------------ 1. grid
@pytest.mark.parametrize("face_size", [3, 5, 9, 33])
def test_full_resolution_sphere(face_size, device):
    lat, lon, z = real_1deg()
    g = Globe.from_latlon(z, lat, lon, face_size=face_size, exaggeration=10.0, device=device)
    m = g.mesh()
    cells = face_size - 1
    assert_valid_mesh(m)
    assert len(m.vertices) == 6 * cells**2 + 2
    assert len(m.faces) == 12 * cells**2
    assert m.is_watertight and m.is_winding_consistent and m.euler_number == 2
    assert m.volume > 0  # counter-clockwise seen from outside
    # already welded: merging by position changes nothing
    assert len(welded(m).vertices) == len(m.vertices)
    # every vertex at R + exaggeration * z
    heights = g.heights.reshape(-1)[m.metadata["node_entry"]].astype(np.float64)
    radius = np.linalg.norm(m.vertices, axis=1)
    np.testing.assert_allclose(radius, R + heights, rtol=0, atol=1e-9 * R)


def test_exaggeration_scales_the_input_sample(device):
    """Issue 3 §6: every vertex at R + exaggeration · z, with z the bilinear sample of the INPUT (the heights
    of the same grid at exaggeration 1), not ``g.heights``, which already holds the exaggeration."""
    lat = np.linspace(88.0, -88.0, 45)  # 4° cells, centre-registered
    lon = np.linspace(-178.0, 178.0, 90)
    la, lo = np.meshgrid(np.radians(lat), np.radians(lon), indexing="ij")
    z = 300.0 + 2000.0 * np.cos(la) * np.cos(lo) - 700.0 * np.sin(2.0 * la) * np.sin(3.0 * lo)
    plain = Globe.from_latlon(z, lat, lon, face_size=9, exaggeration=1.0, device=device)
    steep = Globe.from_latlon(z, lat, lon, face_size=9, exaggeration=10.0, device=device)
    z_input = plain.heights.astype(np.float64)
    assert np.ptp(z_input) > 1000.0  # the field is not flat: a wrong factor cannot hide
    # heights: 10 × the input sample, rounded once to float32 (half an ulp, 2^-24 relative)
    np.testing.assert_allclose(steep.heights, 10.0 * z_input, rtol=2.0**-23, atol=0)
    m = steep.mesh()
    assert len(m.vertices) == 6 * 8**2 + 2
    radius = np.linalg.norm(m.vertices, axis=1)
    expected = R + 10.0 * z_input.reshape(-1)[m.metadata["node_entry"]]
    # float32 heights (|10 z| < 3e4 m: ulp <= 2e-3 m) and float64 positions at R (~1e-15 relative)
    np.testing.assert_allclose(radius, expected, rtol=0, atol=1e-9 * R + 2.0**-23 * 10.0 * np.abs(z_input).max())


def test_seam_copies_are_bit_identical(small_globe):
    g = small_globe
    cells = g.cells
    pos = g.positions.reshape(-1, 3)
    heights = g.heights.reshape(-1)
    params = {k: v.reshape(-1) for k, v in g.node_parameters().items()}
    shared = 0
    for entries in ref.entries_by_point(cells).values():
        if len(entries) > 1:
            shared += 1
            assert (pos[entries] == pos[entries[0]]).all()
            assert (heights[entries] == heights[entries[0]]).all()
            for values in params.values():
                assert (values[entries] == values[entries[0]]).all()
    assert shared == 12 * (cells - 1) + 8  # edge nodes and corners


def test_positions_match_reference_projection(small_globe):
    g = small_globe
    expected = ref.positions(g.heights.reshape(-1).astype(np.float64), g.cells, g.radius)
    np.testing.assert_allclose(g.positions.reshape(-1, 3), expected, rtol=0, atol=1.0)  # float32 at R


def test_resampling_matches_bilinear_reference():
    lat, lon, z = real_1deg()
    g = Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")
    heights = g.heights.reshape(-1)
    for point, entries in ref.entries_by_point(8).items():
        w = np.array(point, dtype=np.float64)
        w /= np.linalg.norm(w)
        qlat = math.degrees(math.asin(w[2]))
        qlon = math.degrees(math.atan2(w[1], w[0]))
        expected = ref.bilinear_latlon(z.astype(np.float64), lat, lon, qlat, qlon)
        assert heights[entries[0]] == pytest.approx(expected, abs=0.05)


@wp.kernel
def direct_resampling(grid: cs.CubeSphereGrid, source: cs.LatLonGrid, exaggeration: wp.float32,
                      heights: wp.array[wp.float32], positions: wp.array[wp.vec3]):
    """Each node straight from its cube point: two atan2 calls and the direction's own square root (what
    resample_latlon reads from its tables)."""
    entry = wp.tid()
    nn = grid.n * grid.n
    face = entry // nn
    i = (entry - face * nn) // grid.n
    j = entry - face * nn - i * grid.n
    point = cs.cube_point(face, i, j, grid.cells)
    x = wp.float32(point[0])
    y = wp.float32(point[1])
    lat = cs.fast_atan2f(wp.float32(point[2]), wp.sqrt(x * x + y * y))
    z = exaggeration * cs.sample_latlon(source, lat, cs.longitude_weights(source, point))
    heights[entry] = z
    p = (grid.radius + wp.float64(z)) * cs.node_direction(point)
    positions[entry] = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))


@pytest.mark.parametrize("face_size", [3, 17, 65])
def test_tabled_resampling_is_the_direct_evaluation_bit_for_bit(monkeypatch, face_size):
    # resample_latlon reads each node's angles from tables over a quarter face (symmetry: |x|, |y|, sign of z)
    lat, lon, z = real_1deg()
    handed = {}
    launch = globe_module.launch_chunked

    def spy(kernel, n, inputs, outputs, device):
        if kernel is cs.resample_latlon:
            handed["inputs"] = inputs
        launch(kernel, n, inputs, outputs, device)

    monkeypatch.setattr(globe_module, "launch_chunked", spy)
    g = Globe.from_latlon(z, lat, lon, face_size=face_size, exaggeration=2.5, device="cpu")
    grid, source, exaggeration = handed["inputs"][:3]
    count = 6 * face_size**2
    heights = wp.empty(count, dtype=wp.float32, device="cpu")
    positions = wp.empty(count, dtype=wp.vec3, device="cpu")
    wp.launch(direct_resampling, count, [grid, source, exaggeration], [heights, positions], device="cpu")
    np.testing.assert_array_equal(g.heights.reshape(-1).view(np.uint32), heights.numpy().view(np.uint32))
    np.testing.assert_array_equal(g.positions.reshape(-1, 3).view(np.uint32), positions.numpy().view(np.uint32))


def test_resampling_wraps_longitude_and_handles_poles():
    # a field that is smooth on the sphere: z = 1000 * x-component of the direction
    lat = np.linspace(89.75, -89.75, 360)
    lon = np.linspace(0.25, 359.75, 720)  # starts at 0, not -180: wrap-around must still hold
    la, lo = np.meshgrid(np.radians(lat), np.radians(lon), indexing="ij")
    z = 1000.0 * np.cos(la) * np.cos(lo)
    g = Globe.from_latlon(z, lat, lon, face_size=17, device="cpu")
    pos = g.positions.reshape(-1, 3).astype(np.float64)
    direction = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    np.testing.assert_allclose(g.heights.reshape(-1), 1000.0 * direction[:, 0], atol=2.0)
    # ascending lat and a closing longitude column give the same globe
    lon_closed = np.append(lon, lon[0] + 360.0)
    z_closed = np.concatenate([z, z[:, :1]], axis=1)
    g2 = Globe.from_latlon(z_closed[::-1], lat[::-1], lon_closed, face_size=17, device="cpu")
    np.testing.assert_array_equal(g2.heights, g.heights)


# ------------------------------------------------------------------------------------------ 2. hierarchy
def test_hierarchy_matches_reference_and_is_saturated_and_nested(small_globe):
    g = small_globe
    cells = g.cells
    pos32 = g.positions.reshape(-1, 3)
    params = {k: v.reshape(-1).astype(np.float64) for k, v in g.node_parameters().items()}
    by_point = ref.entries_by_point(cells)
    # e on the float64 positions the mesh's vertices have; r, h, α on the float32 ones the metrics see
    exact = ref.node_parameters(pos32, cells, ref.positions(g.heights.reshape(-1).astype(np.float64), cells, g.radius))
    _, children, _ = ref.bisection_tree(cells)
    p = {pt: pos32[e[0]].astype(np.float64) for pt, e in by_point.items()}
    assert len(exact) == 6 * cells**2 + 2 - 8  # every node but the cube corners refines a triangle
    for pt, (e, r, h, alpha) in exact.items():
        k = by_point[pt][0]
        got = [params[name][k] for name in ("geometric_error", "bounding_radius", "cone_height", "cone_angle")]
        # kernel values are the exact ones plus the level-wise margin (relative 2^-20 per level, tiny absolute)
        for value, want, absolute in zip(got, (e, r, h, alpha), (1e-6 * R, 1e-5 * R, 1e-5 * R, 1e-5), strict=True):
            assert want - 1e-9 * (want + 1) <= value <= want * (1 + 1e-4) + absolute
        # saturation e(parent) >= e(child), and nesting of every descendant vertex, in float64 on the float32
        # positions the metric uses: no tolerance
        v = p[pt]
        for c in children.get(pt, ()):
            kc = by_point[c][0]
            assert params["geometric_error"][k] >= params["geometric_error"][kc]
            assert params["bounding_radius"][k] >= params["bounding_radius"][kc]
        for d in ref.descendants(pt, children):
            x = p[d]
            assert np.linalg.norm(x - v) <= params["bounding_radius"][k]
            assert abs(np.linalg.norm(x) - np.linalg.norm(v)) <= params["cone_height"][k]
            angle = math.atan2(np.linalg.norm(np.cross(v, x)), v @ x)
            assert angle <= params["cone_angle"][k]


# ------------------------------------------------------------------------------------------ 3. metrics
def _distances(centres, params, eye, plane):
    import warp as wp
    from stepterrain.kernels import bounds as bk

    from stepterrain._device import resolve_device

    device = resolve_device("cpu")
    out = wp.empty(len(centres), dtype=wp.vec4d, device=device)
    wp.launch(bk.evaluate_shape_distances, dim=len(centres),
              inputs=[0, wp.array(centres, dtype=wp.vec3d, device=device),
                      wp.array(params, dtype=wp.vec3d, device=device),
                      wp.vec3d(*eye), wp.vec4d(*plane)], outputs=[out], device=device)
    return out.numpy()


def _eye_case(eye, p, h, alpha):
    beta = math.atan2(np.linalg.norm(np.cross(eye, p)), eye @ p)
    v, pl = np.linalg.norm(eye), np.linalg.norm(p)
    if beta <= alpha:
        return 1 if v > pl + h else 3 if v < pl - h else 2
    gamma = beta - alpha
    if gamma < math.pi / 2:
        t1, t2 = (pl - h) / math.cos(gamma), (pl + h) / math.cos(gamma)
        if t1 <= v <= t2:
            return 5
        if v > t2:
            return 4
    return 6


def test_eye_distance_formulas_agree_with_brute_force_in_all_six_cases():
    rng = np.random.default_rng(3)
    p = np.array([0.0, 0.0, 10.0])
    h, alpha = 1.0, 0.3
    eyes = []
    cases = set()
    while len(eyes) < 120:
        eye = rng.normal(size=3) * rng.uniform(1, 20)
        if ref.inside_cone(eye, p, h, alpha) and len([e for e in eyes if ref.inside_cone(e, p, h, alpha)]) > 10:
            continue
        eyes.append(eye)
        cases.add(_eye_case(eye, p, h, alpha))
    for eye in ([0.0, 0.0, 10.2], [0.0, 0.5, 5.0], [0.0, 0.2, 14.0], [0.0, 6.0, 12.0], [0.0, 5.0, 9.0],
                [0.0, 3.0, -4.0]):
        eyes.append(np.array(eye))
        cases.add(_eye_case(eyes[-1], p, h, alpha))
    assert cases == {1, 2, 3, 4, 5, 6}
    samples = ref.cone_surface_samples(p, h, alpha, count=120)
    for eye in eyes:
        got = _distances([p], [(2.0, h, alpha)], eye, (0, 0, 1, 0))[0]
        brute = 0.0 if ref.inside_cone(eye, p, h, alpha) else np.linalg.norm(samples - eye, axis=1).min()
        assert got[1] == pytest.approx(brute, abs=0.02 + 1e-3 * brute)
        assert got[0] == pytest.approx(max(np.linalg.norm(p - eye) - 2.0, 0.0))


def test_plane_distance_formulas_agree_with_brute_force_in_all_three_cases():
    rng = np.random.default_rng(4)
    p = np.array([3.0, -2.0, 9.0])
    h, alpha = 0.8, 0.25
    samples = ref.cone_surface_samples(p, h, alpha, count=150)
    axis = p / np.linalg.norm(p)
    cases = set()
    for _ in range(60):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        a = rng.uniform(-12, 12)
        gamma = math.acos(np.clip(n @ axis, -1, 1)) - alpha
        cases.add(1 if gamma <= 0 else 2 if gamma <= math.pi / 2 else 3)
        got = _distances([p], [(1.0, h, alpha)], (0, 0, 0), (*n, a))[0]
        assert got[3] == pytest.approx((samples @ n + a).max(), abs=2e-3)
        assert got[2] == pytest.approx(n @ p + a + 1.0)
        # inverted-plane test: max over the inverted plane is minus the min
        inv = _distances([p], [(1.0, h, alpha)], (0, 0, 0), (*(-n), -a))[0]
        assert -inv[3] == pytest.approx((samples @ n + a).min(), abs=2e-3)
    assert cases == {1, 2, 3}


def _cone_eye_distance_2d(p, h, alpha, eye) -> float:
    """d(eye, cone frustum) by reduction to the plane through the axis and the eye: the frustum's section is
    {ρ (cos θ, sin θ): ρ in [bottom, top], |θ| <= α}; an eye at angle β <= α from the axis is above, inside or below
    it; one further off is nearest to the edge θ = α, a segment (the arcs' nearest points are its ends)."""
    length = float(np.linalg.norm(p))
    top, bottom = length + h, max(length - h, 0.0)
    v = float(np.linalg.norm(eye))
    if v == 0.0:
        return bottom
    beta = math.atan2(float(np.linalg.norm(np.cross(eye, p))), float(eye @ p))
    if beta <= alpha:
        return max(v - top, bottom - v, 0.0)
    q = np.array([v * math.cos(beta), v * math.sin(beta)])
    u = np.array([math.cos(alpha), math.sin(alpha)])
    a, b = bottom * u, top * u
    span = float((b - a) @ (b - a))  # 0 for h = 0: the segment is a point
    s = float(np.clip((q - a) @ (b - a) / span, 0.0, 1.0)) if span > 0 else 0.0
    return float(np.linalg.norm(q - a - s * (b - a)))


def _cone_plane_max(p, h, alpha, plane):
    """max of ⟨n, x⟩ + a over the cone frustum (per plane of a (K, 4) stack): over the directions within α of the
    axis ⟨n, d⟩ peaks at cos(max(angle(n, axis) − α, 0)), taken at the top radius when positive, else at the
    bottom."""
    plane = np.asarray(plane, dtype=np.float64)
    n, a = plane[..., :3], plane[..., 3]
    length = float(np.linalg.norm(p))
    top, bottom = length + h, max(length - h, 0.0)
    c = np.cos(np.maximum(np.arctan2(np.linalg.norm(np.cross(n, p), axis=-1), n @ p) - alpha, 0.0))
    return a + np.where(c >= 0, top * c, bottom * c)


_unit = hst.tuples(*[hst.floats(-1.0, 1.0)] * 3).filter(lambda v: math.hypot(*v) > 0.1)


@settings(max_examples=40, deadline=None)
@given(axis=_unit, length=hst.floats(0.1, 1000.0), height=hst.floats(1e-4, 3.0), alpha=hst.floats(0.0, 1.5),
       eye_dir=_unit, eye_at=hst.floats(0.0, 3.0), normal=_unit, offset=hst.floats(-3.0, 3.0))
def test_property_shape_distances_equal_the_planar_section_reference(axis, length, height, alpha, eye_dir, eye_at,
                                                                     normal, offset):
    """Random cone frustums (h up to 3 |p|: the bottom clamped at the centre; opening up to 1.5 rad), eyes anywhere
    (the centre and the axis included) and planes: d(v, B) and the largest plane distance equal the exact references
    of the frustum's planar section, and the sphere's are ‖p − v‖ − r (at least 0) and ⟨n, p⟩ + a + r."""
    p = np.asarray(axis) / np.linalg.norm(axis) * length
    h = height * length
    eye = np.asarray(eye_dir) / np.linalg.norm(eye_dir) * eye_at * length
    if eye_at < 0.05:
        eye = np.zeros(3)
    n = np.asarray(normal) / np.linalg.norm(normal)
    plane = (*n, offset * length)
    r = 0.5 * length
    got = _distances([p], [(r, h, alpha)], eye, plane)[0]
    scale = length + h + float(np.linalg.norm(eye))
    assert got[0] == pytest.approx(max(float(np.linalg.norm(p - eye)) - r, 0.0), abs=1e-12 * scale)
    assert got[1] == pytest.approx(_cone_eye_distance_2d(p, h, alpha, eye), abs=1e-9 * scale)
    assert got[2] == pytest.approx(float(n @ p) + plane[3] + r, abs=1e-12 * scale)
    assert got[3] == pytest.approx(_cone_plane_max(p, h, alpha, plane), abs=1e-9 * scale)
    # the smallest signed distance is minus the inverted plane's largest
    inverted = _distances([p], [(r, h, alpha)], eye, tuple(-np.asarray(plane)))[0]
    assert -inverted[3] <= got[3] + 1e-9 * scale


@wp.kernel
def _view_sides(planes: wp.array[wp.vec4d], centres: wp.array[wp.vec3d], params: wp.array[wp.vec3d],
                sides: wp.array[wp.vec2i]):
    """sphere_view_side and cone_view_side of each shape (r, h, α)."""
    i = wp.tid()
    p = centres[i]
    q = params[i]
    p_len = wp.length(p)
    sides[i] = wp.vec2i(bk.sphere_view_side(planes, p, q[0]),
                        bk.cone_view_side(planes, p, p / p_len, p_len, q[1], q[2], bk.sin_cos(q[2])))


@settings(max_examples=25, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), fov=hst.floats(0.2, 2.0), aspect=hst.floats(0.3, 3.0),
       spread=hst.floats(0.01, 2.0), wide=hst.booleans())
def test_property_view_sides_of_shapes_agree_with_their_exact_plane_distances(seed, fov, aspect, spread, wide):
    """The clip test of 200 random spheres and cone frustums against a random view frustum: a shape said to lie wholly
    outside lies outside one plane (its exact smallest distance to it >= 0: nothing visible is culled), one said to
    lie wholly inside lies inside every plane (its descendants skip the clip test), and a shape wholly outside one
    plane is said so (the test is exact per plane)."""
    rng = np.random.default_rng(seed)
    eye = rng.normal(size=3) * 3.0
    cam = Camera(eye=tuple(eye), target=tuple(rng.normal(size=3)), up=tuple(rng.normal(size=3)), fov=fov,
                 aspect=aspect, near=0.05, far=float(rng.uniform(2.0, 12.0)))
    planes = cam.planes().astype(np.float64)
    count = 200
    centres = rng.normal(size=(count, 3)) * 3.0
    length = np.linalg.norm(centres, axis=1)
    params = np.column_stack([length * spread * rng.uniform(0.0, 1.0, count),
                              length * spread * rng.uniform(0.0, 1.5 if wide else 0.2, count),
                              rng.uniform(0.0, 1.4 if wide else spread * 0.2, count)])
    device = wp.get_device("cpu")
    sides = wp.empty(count, dtype=wp.vec2i, device=device)
    wp.launch(_view_sides, count, [wp.array(planes, dtype=wp.vec4d, device=device),
                                   wp.array(centres, dtype=wp.vec3d, device=device),
                                   wp.array(params, dtype=wp.vec3d, device=device)], [sides], device=device)
    sides = sides.numpy()
    outside, inside = int(bk.OUTSIDE), int(bk.INSIDE)
    for k in range(count):
        p, (r, h, alpha) = centres[k], params[k]
        tol = 1e-9 * (np.linalg.norm(p) + r + h + 1.0)
        sphere_max = planes[:, :3] @ p + planes[:, 3] + r  # per plane: the largest and smallest signed distance
        sphere_min = sphere_max - 2 * r
        cone_max = _cone_plane_max(p, h, alpha, planes)
        cone_min = -_cone_plane_max(p, h, alpha, -planes)
        for side, lo, hi in ((sides[k][0], sphere_min, sphere_max), (sides[k][1], cone_min, cone_max)):
            if side == outside:
                assert (lo >= -tol).any(), f"shape {k} culled though it reaches into every half-space"
            elif side == inside:
                assert (hi <= tol).all(), f"shape {k} said inside though it reaches out of a plane"
            assert side == outside or not (lo > tol).any(), f"shape {k} wholly outside a plane but not culled"


def test_camera_planes_contain_what_it_sees():
    cam = Camera(eye=(0.0, -10.0, 0.0), target=(0.0, 0.0, 0.0), fov=math.radians(60), aspect=1.5, near=1.0,
                 far=50.0)
    planes = cam.planes()
    assert planes.shape == (6, 4)
    np.testing.assert_allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0)
    inside = np.array([[0, 0, 0], [2, 5, 1], [0, 39, 0]])
    outside = np.array([[0, -10.5, 0], [0, 45, 0], [30, 0, 0], [0, 0, 30]])
    assert ((inside @ planes[:, :3].T + planes[:, 3]) <= 0).all()
    assert (((outside @ planes[:, :3].T + planes[:, 3]) > 0).any(axis=1)).all()


# ------------------------------------------------------------------------------------------ 4. refinement
def _triangles_as_points(mesh, g):
    pts = ref_points = {}
    del pts
    entries = mesh.metadata["node_entry"]
    n = g.face_size
    keys = []
    for face in np.asarray(mesh.faces):
        tri = []
        for v in face:
            e = int(entries[v])
            tri.append(ref.cube_point(e // (n * n), (e % (n * n)) // n, e % n, g.cells))
        keys.append(tuple(sorted(tri)))
    del ref_points
    return sorted(keys)


def test_refinement_matches_reference_visit(small_globe):
    """The breadth-first Warp refinement equals the recursive visit of §5.2 run on the same parameters."""
    g = small_globe
    params = {k: v.reshape(-1) for k, v in g.node_parameters().items()}
    pos = g.positions.reshape(-1, 3).astype(np.float64)
    n = g.face_size
    eps = 200.0
    levels, _, _ = ref.bisection_tree(g.cells)
    # recursive visit with μ = e
    out = []

    def visit(f, a, b, c):
        if ref.splits(a, b):
            m = ((a[0] + b[0]) // 2, (a[1] + b[1]) // 2)
            if params["geometric_error"][f * n * n + m[0] * n + m[1]] > eps:
                visit(f, c, a, m)
                visit(f, b, c, m)
                return
        out.append(tuple(sorted(ref.cube_point(f, *q, g.cells) for q in (a, b, c))))

    for f, a, b, c in levels[0]:
        visit(f, a, b, c)
    mesh = g.mesh(error=eps)
    assert _triangles_as_points(mesh, g) == sorted(out)
    del pos


def _reference_refines(p, e, r, h, alpha, eye, planes, error, scale, cone) -> bool:
    """μ = e · (ℓ / d)² > ε (§7.2, §7.4; d = 0, the eye inside the shape: refine unless e = 0) and the shape not
    wholly outside a frustum plane (§7.3), with the exact distances of the shape (the references above)."""
    if e <= 0.0:
        return False
    if cone:
        d = _cone_eye_distance_2d(p, h, alpha, eye)
        lowest = -_cone_plane_max(p, h, alpha, -planes)
    else:
        d = max(float(np.linalg.norm(p - eye)) - r, 0.0)
        lowest = planes[:, :3] @ p + planes[:, 3] - r
    if d > 0.0 and e * (scale / d) ** 2 <= error:
        return False
    return not (lowest > 0.0).any()


@settings(max_examples=8, deadline=None)
@given(distance=hst.floats(1.02, 3.0), lon=hst.floats(-math.pi, math.pi), lat=hst.floats(-1.5, 1.5),
       log_error=hst.floats(2.0, 6.0), cone=hst.booleans(), seed=hst.integers(0, 2**32 - 1))
def test_property_refinement_with_a_camera_matches_the_reference_visit(small_globe, distance, lon, lat, log_error,
                                                                      cone, seed):
    """Random views of the globe, geometric, distance and clip metrics on cones or spheres: the Warp refinement (with
    its quick rejects and accepts, its clip test skipped below shapes found inside) equals the recursive visit of §5.2
    deciding each node by the exact μ = e · (ℓ / d)² > ε and the exact clip test, on the same node parameters."""
    g = small_globe
    error = 10.0**log_error  # the node errors span about 1e3 to 1e6 m (curvature and 20x relief)
    rng = np.random.default_rng(seed)
    params = {k: v.reshape(-1).astype(np.float64) for k, v in g.node_parameters().items()}
    pos = g.positions.reshape(-1, 3).astype(np.float64)
    n = g.face_size
    eye = distance * R * np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    cam = Camera(eye=tuple(eye), target=tuple(rng.normal(size=3) * 0.5 * R), up=tuple(rng.normal(size=3)),
                 fov=float(rng.uniform(0.3, 1.2)), aspect=float(rng.uniform(0.5, 2.0)), near=1.0,
                 far=float(rng.uniform(1.0, 4.0)) * R)
    planes = cam.planes().astype(np.float64)
    scale = float(np.linalg.norm(eye)) - R
    levels, _, _ = ref.bisection_tree(g.cells)
    out = []

    def visit(f, a, b, c):
        if ref.splits(a, b):
            m = ((a[0] + b[0]) // 2, (a[1] + b[1]) // 2)
            k = f * n * n + m[0] * n + m[1]
            if _reference_refines(pos[k], params["geometric_error"][k], params["bounding_radius"][k],
                                  params["cone_height"][k], params["cone_angle"][k], eye, planes, error, scale, cone):
                visit(f, c, a, m)
                visit(f, b, c, m)
                return
        out.append(tuple(sorted(ref.cube_point(f, *q, g.cells) for q in (a, b, c))))

    for f, a, b, c in levels[0]:
        visit(f, a, b, c)
    mesh = g.mesh(error=error, camera=cam, bounds="cone" if cone else "sphere", distance_scale=scale, cull=False)
    assert _triangles_as_points(mesh, g) == sorted(out)


def _assert_culled_exactly(closed, culled, cam):
    """The culled mesh is the closed mesh less exactly its triangles wholly outside one frustum plane."""
    def key(m, keep=None):
        faces = np.asarray(m.faces) if keep is None else np.asarray(m.faces)[keep]
        return {tuple(sorted(t)) for t in np.asarray(m.metadata["node_entry"])[faces].tolist()}

    planes = cam.planes()
    corner_out = (closed.vertices @ planes[:, :3].T + planes[:, 3]) > 0  # (V, 6)
    outside = corner_out[np.asarray(closed.faces)].all(axis=1).any(axis=1)
    assert key(culled) == key(closed, ~outside)


@pytest.mark.parametrize("track_min", [1, 64, None])
def test_culling_keeps_exactly_the_triangles_not_wholly_outside(sample_globe, monkeypatch, track_min):
    """Views whose planes cut through many leaves: leaves known inside (their corners tested as refinement
    nodes) skip the test, the others are tested, and the result is the closed mesh less exactly the
    triangles wholly outside a plane; level by level with every level tracked or the small ones not, and by
    default (on the CPU the one-launch levels, tracked from the roots)."""
    import stepterrain.globe as globe_module

    if track_min is not None:
        monkeypatch.setattr(globe_module, "_SMALL_LEVELS", 0)  # the level passes, as on CUDA
        monkeypatch.setattr(globe_module, "_TRACK_MIN", track_min)
    g = sample_globe
    for lat, lon, altitude, tilt, fov in ((46.0, 9.0, 400_000.0, 60.0, 0.5), (0.0, 0.0, 2 * R, 0.0, 0.2),
                                          (-60.0, 120.0, 50_000.0, 75.0, 1.0), (89.0, 45.0, R, 10.0, 0.3)):
        cam = look_from(lat, lon, altitude, tilt=tilt, fov=fov, aspect=1.5)
        for bounds in ("cone", "sphere"):
            closed = g.mesh(error=50.0, camera=cam, bounds=bounds, cull=False)
            culled = g.mesh(error=50.0, camera=cam, bounds=bounds)
            assert 0 < len(culled.faces) < len(closed.faces)
            _assert_culled_exactly(closed, culled, cam)


def _mesh_key(mesh):
    return (np.asarray(mesh.metadata["node_entry"])[np.asarray(mesh.faces)].tolist(),
            np.asarray(mesh.vertices).tobytes(), mesh.metadata["levels"])


@pytest.mark.parametrize("bounds", ["cone", "sphere"])
def test_skipping_the_clip_test_inside_the_view_changes_nothing(sample_globe, monkeypatch, bounds):
    """Below a node whose shape lies wholly inside the view (tracked levels) the clip test is skipped: the
    meshes, culled or not, at ε > 0 and ε = 0, are those of the refinement that tests every node (level passes,
    nothing tracked), whether the level passes track every level or the CPU's one launch tracks them."""
    import stepterrain.globe as globe_module

    g = sample_globe
    views = [look_from(46.0, 9.0, 400_000.0, tilt=60.0, fov=0.5, aspect=1.5),
             look_from(0.0, 0.0, 2 * R, fov=0.2, aspect=1.5),  # a limb view: the planes cut the planet
             look_from(30.0, 10.0, 3 * R, aspect=1.6),  # the whole planet inside the view
             look_from(-60.0, 120.0, 50_000.0, tilt=75.0, fov=1.0, aspect=1.5)]
    skipped = 0
    for cam in views:
        for error, cull in ((30.0, True), (30.0, False), (0.0, True)):
            monkeypatch.setattr(globe_module, "_SMALL_LEVELS", 0)  # level passes only
            monkeypatch.setattr(globe_module, "_TRACK_MIN", 1 << 40)  # nothing tracked: every node tested
            tested = g.mesh(error=error, camera=cam, bounds=bounds, cull=cull)
            monkeypatch.setattr(globe_module, "_TRACK_MIN", 1)  # every level tracked
            tracked = g.mesh(error=error, camera=cam, bounds=bounds, cull=cull)
            monkeypatch.undo()  # the defaults: on the CPU one launch, tracked from the roots
            at_once = g.mesh(error=error, camera=cam, bounds=bounds, cull=cull)
            assert _mesh_key(tracked) == _mesh_key(tested)
            assert _mesh_key(at_once) == _mesh_key(tested)
            skipped += len(tracked.faces)
    assert skipped > 0


def _one_launch_cases() -> list[dict]:
    """Views for the one-launch tests: close and far, culled or not, error 0, spheres, no camera, no clip."""
    close = look_from(46.0, 9.0, 400_000.0, tilt=60.0, fov=0.5, aspect=1.5)
    far = look_from(30.0, 10.0, 3 * R, aspect=1.6)
    return [dict(error=30.0, camera=close), dict(error=30.0, camera=close, cull=False),
            dict(error=0.0, camera=close), dict(error=200.0, camera=far, bounds="sphere"),
            dict(error=500.0), dict(error=100.0, camera=far, metrics=("geometric", "distance")),
            dict(error=2.0, camera=far), dict(error=2.0, camera=far, cull=False)]


@pytest.mark.parametrize("small", [1, 64, 4096, 1 << 17])
def test_levels_in_one_launch_give_the_same_mesh(sample_globe, monkeypatch, small):
    """On the CPU the levels up to ``_SMALL_LEVELS`` triangles are refined by one single-thread launch, which
    tracks the corner masks from the roots on: the same triangles, vertices, order, per-level counts and culled
    faces as a count -> scan -> emit per level, whether the launch stops early (1, 64, 4096: the level passes
    take over, with its masks) or takes every view whole (2**17). One thread: with several the launch splits (the
    next test)."""
    import stepterrain as st

    g = sample_globe
    previous = st.set_cpu_threads(1)
    try:
        for kwargs in _one_launch_cases():
            monkeypatch.setattr(globe_module, "_SMALL_LEVELS", 0)
            levelwise = g.mesh(**kwargs)
            monkeypatch.setattr(globe_module, "_SMALL_LEVELS", small)
            at_once = g.mesh(**kwargs)
            assert _mesh_key(at_once) == _mesh_key(levelwise)
            assert np.array_equal(at_once.face_attributes["cube_face"], levelwise.face_attributes["cube_face"])
    finally:
        st.set_cpu_threads(previous)


@pytest.mark.parametrize("threads", [2, 3])
@pytest.mark.parametrize(("first", "small", "split"), [(16, 1 << 17, True), (1024, 1 << 17, True),
                                                        (16, 64, False), (12, 1 << 17, True)])
def test_the_one_launch_split_into_ranges_gives_the_same_mesh(sample_globe, monkeypatch, threads, first, small,
                                                                split):
    """With several CPU threads the one launch splits: a first launch up to ``_SPLIT_FIRST`` triangles, then ranges
    of the next level refined to the end one launch each, their runs laid out level by level. The triangles,
    vertices, order, per-level counts and cube faces equal one thread's one launch; when the ranges' share of the
    scratch is too small (``_SMALL_LEVELS`` 64) the split gives up and the one launch and level passes take over."""
    import stepterrain as st

    g = sample_globe
    cases = _one_launch_cases()
    previous = st.set_cpu_threads(1)
    try:
        alone = [g.mesh(**kwargs) for kwargs in cases]
        monkeypatch.setattr(globe_module, "_SPLIT_FIRST", first)
        monkeypatch.setattr(globe_module, "_SMALL_LEVELS", small)
        outcomes = []
        real = globe_module._refine_in_ranges

        def spy(*args, **kwargs):
            out = real(*args, **kwargs)
            outcomes.append(out is not None)
            return out

        monkeypatch.setattr(globe_module, "_refine_in_ranges", spy)
        st.set_cpu_threads(threads)
        split_meshes = [g.mesh(**kwargs) for kwargs in cases]
    finally:
        st.set_cpu_threads(previous)
    assert len(outcomes) == len(cases) and all(done == split for done in outcomes)
    for one, many in zip(alone, split_meshes, strict=True):
        assert _mesh_key(many) == _mesh_key(one)
        assert np.array_equal(many.face_attributes["cube_face"], one.face_attributes["cube_face"])
    # the split's new vertices are the mesh's own array, not the cached corner entries
    assert not np.shares_memory(split_meshes[4].metadata["node_entry"], alone[4].metadata["node_entry"])


def test_the_split_one_launch_on_a_planar_view_gives_the_same_mesh(monkeypatch):
    """The planar adaptive mesh with a camera takes the one launch too (two roots): split into ranges, the same."""
    import stepterrain as st

    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=257, step=1)
    camera = Camera(eye=(3000.0, -2000.0, 4000.0), target=(3800.0, 3800.0, 900.0), fov=0.9, aspect=1.4,
                    near=1.0, far=20_000.0)
    previous = st.set_cpu_threads(1)
    try:
        alone = adaptive_mesh(dem, error=2.0, spacing=30.0, camera=camera)
        monkeypatch.setattr(globe_module, "_SPLIT_FIRST", 16)
        st.set_cpu_threads(2)
        split = adaptive_mesh(dem, error=2.0, spacing=30.0, camera=camera)
    finally:
        st.set_cpu_threads(previous)
    assert len(alone.faces) > 1000
    assert np.array_equal(split.vertices, alone.vertices) and np.array_equal(split.faces, alone.faces)
    assert split.metadata["levels"] == alone.metadata["levels"]


@pytest.mark.parametrize("threads", [2, 3])
def test_views_split_over_cpu_threads_give_the_same_mesh(sample_globe, monkeypatch, threads):
    """The view's passes split over several CPU threads from _SPLIT_REFINE / _SPLIT_EMIT elements a range: with
    ranges of 64 elements (every pass of every level split, chunk boundaries inside the levels) the triangles,
    vertices and their order are those of one thread: far and close views, culled or not, cones and spheres."""
    import stepterrain as st

    g = sample_globe
    close = look_from(46.0, 9.0, 400_000.0, tilt=60.0, fov=0.5, aspect=1.5)
    far = look_from(30.0, 10.0, 3 * R, aspect=1.6)
    cases = [dict(error=10.0, camera=far), dict(error=10.0, camera=far, cull=False),
             dict(error=5.0, camera=close, bounds="sphere"), dict(error=0.0, camera=close), dict(error=50.0)]
    monkeypatch.setattr(globe_module, "_SMALL_LEVELS", 0)  # every level a count -> scan -> emit of its own
    previous = st.set_cpu_threads(1)
    try:
        alone = [g.mesh(**kwargs) for kwargs in cases]
        monkeypatch.setattr(globe_module, "_SPLIT_REFINE", 64)
        monkeypatch.setattr(globe_module, "_SPLIT_EMIT", 64)
        st.set_cpu_threads(threads)
        split = [g.mesh(**kwargs) for kwargs in cases]
    finally:
        st.set_cpu_threads(previous)
    for one, many in zip(alone, split, strict=True):
        assert len(one.faces) > 2000
        assert _mesh_key(many) == _mesh_key(one)
        assert np.array_equal(many.face_attributes["cube_face"], one.face_attributes["cube_face"])


@settings(max_examples=10, phases=[Phase.explicit, Phase.reuse, Phase.generate], deadline=None)
@given(distance=hst.floats(1.05, 4.0), lon=hst.floats(-math.pi, math.pi), lat=hst.floats(-1.4, 1.4),
       error=hst.floats(5.0, 2000.0), cone=hst.booleans(), cull=hst.booleans(), first=hst.integers(12, 600),
       threads=hst.integers(2, 4), per_thread=hst.integers(1, 6))
def test_random_views_split_into_ranges_equal_one_thread(sample_globe, distance, lon, lat, error, cone, cull, first,
                                                         threads, per_thread):
    """Random views, split into ranges after a first launch of any size, over 2-4 threads and 1-6 ranges a
    thread: the mesh of one thread, byte for byte."""
    import stepterrain as st

    eye = distance * R * np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    cam = Camera(eye=tuple(eye), target=(0.0, 0.0, 0.0), fov=0.8, aspect=1.5, near=1.0, far=5.0 * R)
    kwargs = dict(error=error, camera=cam, bounds="cone" if cone else "sphere", cull=cull)
    saved = globe_module._SPLIT_FIRST, globe_module._RANGES_PER_THREAD
    previous = st.set_cpu_threads(1)
    try:
        alone = sample_globe.mesh(**kwargs)
        globe_module._SPLIT_FIRST, globe_module._RANGES_PER_THREAD = first, per_thread
        st.set_cpu_threads(threads)
        split = sample_globe.mesh(**kwargs)
    finally:
        st.set_cpu_threads(previous)
        globe_module._SPLIT_FIRST, globe_module._RANGES_PER_THREAD = saved
    assert _mesh_key(split) == _mesh_key(alone)
    assert np.array_equal(split.face_attributes["cube_face"], alone.face_attributes["cube_face"])


@settings(max_examples=12, phases=[Phase.explicit, Phase.reuse, Phase.generate])
@given(distance=hst.floats(1.05, 4.0), lon=hst.floats(-math.pi, math.pi), lat=hst.floats(-1.4, 1.4),
       error=hst.floats(20.0, 2000.0), cone=hst.booleans(), seed=hst.integers(0, 10**6))
def test_random_views_are_crack_free(sample_globe, distance, lon, lat, error, cone, seed):
    g = sample_globe
    rng = np.random.default_rng(seed)
    eye = distance * R * np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    target = rng.normal(size=3) * 0.5 * R
    cam = Camera(eye=tuple(eye), target=tuple(target), up=tuple(rng.normal(size=3)), fov=rng.uniform(0.3, 1.2),
                 aspect=rng.uniform(0.5, 2.0), near=1.0, far=rng.uniform(0.5, 5.0) * R)
    bounds = "cone" if cone else "sphere"
    closed = g.mesh(error=error, camera=cam, bounds=bounds, cull=False)
    assert_valid_mesh(closed)
    assert closed.is_watertight and closed.is_winding_consistent and closed.euler_number == 2
    assert len(welded(closed).vertices) == len(closed.vertices)  # no duplicated node, hence no crack
    culled = g.mesh(error=error, camera=cam, bounds=bounds)
    if len(culled.faces):
        assert_valid_mesh(culled)
        planes = cam.planes()
        corner_out = (culled.vertices @ planes[:, :3].T + planes[:, 3]) > 0  # (V, 6)
        wholly = corner_out[np.asarray(culled.faces)].all(axis=1).any(axis=1)
        assert not wholly.any(), "a triangle wholly outside the frustum survived culling"
    _assert_culled_exactly(closed, culled, cam)
    # larger error: no more triangles; farther eye (distance metric, same ℓ): no more triangles
    assert len(g.mesh(error=2 * error, camera=cam, bounds=bounds, cull=False).faces) <= len(closed.faces)
    far = Camera(eye=tuple(2 * eye), target=cam.target, up=cam.up, fov=cam.fov, aspect=cam.aspect, near=cam.near,
                 far=cam.far)
    scale = np.linalg.norm(eye) - R
    options = {"error": error, "bounds": bounds, "distance_scale": scale, "metrics": ("geometric", "distance")}
    assert len(g.mesh(camera=far, **options).faces) <= len(g.mesh(camera=cam, **options).faces)


def test_geometric_error_alone_decreases_with_error(sample_globe):
    counts = [len(sample_globe.mesh(error=e).faces) for e in (0, 50, 200, 1000, 5000, 1e7)]
    assert counts == sorted(counts, reverse=True)
    assert counts[0] == 12 * 64**2 and counts[-1] == 12


def test_cones_need_fewer_triangles_than_spheres(sample_globe):
    cam = Camera(eye=(1.15 * R, 0.0, 0.3 * R), target=(0.0, 0.0, 0.0), fov=0.7)
    cones = len(sample_globe.mesh(error=100.0, camera=cam, bounds="cone").faces)
    spheres = len(sample_globe.mesh(error=100.0, camera=cam, bounds="sphere").faces)
    assert cones < spheres


def test_metrics_switch_and_user_metric(sample_globe):
    cam = Camera(eye=(1.5 * R, 0.0, 0.0), target=(0.0, 0.0, 0.0), fov=0.5)
    geo = sample_globe.mesh(error=500.0, metrics=("geometric",), camera=cam)
    assert len(geo.faces) == len(sample_globe.mesh(error=500.0).faces)
    clip = sample_globe.mesh(error=500.0, metrics=("geometric", "clip"), camera=cam)
    assert len(clip.faces) < len(geo.faces)

    def northern(points, radius):
        return (points[:, 2] + radius > 0).astype(float)  # saturated: a parent's sphere holds its children's

    north = sample_globe.mesh(error=500.0, metrics=("geometric", northern))
    assert 0 < len(north.faces) < len(geo.faces)
    assert north.is_watertight
    south_centres = north.triangles_center[:, 2] < -0.3 * R
    assert north.area_faces[south_centres].min() > geo.area_faces.min()


def test_per_face_meshes_have_uv(sample_globe):
    parts = sample_globe.mesh(error=300.0, per_face=True)
    whole = sample_globe.mesh(error=300.0)
    assert len(parts) == 6
    assert sum(len(p.faces) for p in parts) == len(whole.faces)
    for p in parts:
        uv = p.visual.uv
        assert uv.shape == (len(p.vertices), 2) and uv.min() >= 0 and uv.max() <= 1
        assert p.is_winding_consistent


def test_per_face_meshes_carry_the_documented_attributes(small_globe):
    """Globe.mesh documents face_attributes["cube_face"], metadata["node_entry"] and metadata["levels"] for the
    list of six too; the per-face meshes had metadata {"cube_face": f} alone, so their vertices could not be
    coloured by elevation (globe.heights at node_entry) as the whole mesh's are."""
    camera = look_from(46.0, 9.0, 4.0e6)
    whole = small_globe.mesh(error=20.0, camera=camera)
    parts = small_globe.mesh(error=20.0, camera=camera, per_face=True)
    position = dict(zip(whole.metadata["node_entry"].tolist(), map(tuple, whole.vertices), strict=True))
    heights = small_globe.heights.reshape(-1)
    for f, part in enumerate(parts):
        entry = part.metadata["node_entry"]
        assert entry.shape == (len(part.vertices),) and part.metadata["cube_face"] == f
        assert [position[e] for e in entry.tolist()] == list(map(tuple, part.vertices))
        assert np.isfinite(heights[entry]).all()
        assert (part.face_attributes["cube_face"] == f).all() and len(part.face_attributes["cube_face"]) == len(
            part.faces)
        assert part.metadata["levels"] == whole.metadata["levels"]
        assert part.metadata["face_size"] == small_globe.face_size
        assert part.metadata["whole_part"] == {"vertices": len(part.vertices), "faces": len(part.faces), "bounds": [
            part.vertices.min(axis=0).tolist(), part.vertices.max(axis=0).tolist()]}  # save_mesh: the set's frame


def test_cpu_and_cuda_agree(device):
    lat, lon, z = real_1deg()
    g = Globe.from_latlon(z, lat, lon, face_size=33, device=device)
    cam = Camera(eye=(1.3 * R, 0.2 * R, 0.1 * R), target=(0.0, 0.0, 0.0))
    m = g.mesh(error=100.0, camera=cam)
    g_cpu = Globe.from_latlon(z, lat, lon, face_size=33, device="cpu")
    m_cpu = g_cpu.mesh(error=100.0, camera=cam)
    # kernels compile without FMA contraction (kernels/__init__): the two backends give the same bits
    np.testing.assert_array_equal(g.heights, g_cpu.heights)
    np.testing.assert_array_equal(m.faces, m_cpu.faces)
    np.testing.assert_array_equal(m.vertices, m_cpu.vertices)


def test_colours_by_elevation_and_draped_image(small_globe):
    from stepterrain.globe import drape_colors, elevation_colors

    mesh = small_globe.mesh(error=500.0)
    image = np.zeros((90, 180, 3), np.uint8)
    image[:, :90] = (255, 0, 0)  # western hemisphere red
    image[:, 90:] = (0, 0, 255)  # eastern blue
    colours = drape_colors(mesh.vertices, image)
    lon = np.degrees(np.arctan2(mesh.vertices[:, 1], mesh.vertices[:, 0]))
    west, east = (lon < -10) & (lon > -170), (lon > 10) & (lon < 170)
    assert (colours[west, 0] == 255).all() and (colours[east, 2] == 255).all()
    heights = np.array([-5000.0, -10.0, 10.0, 4000.0])
    rgba = elevation_colors(heights)
    assert rgba.shape == (4, 4) and rgba.dtype == np.uint8
    assert rgba[0, 2] > rgba[0, 0] and rgba[3, 0] > rgba[2, 0]  # sea blue; high land lighter than lowland
    cam = look_from(45.0, 90.0, 1.0e6, tilt=30.0, heading=90.0)
    assert np.linalg.norm(cam.eye) == pytest.approx(R + 1.0e6)
    with pytest.raises(InvalidInputError, match="texture must be"):
        drape_colors(mesh.vertices, np.zeros((4, 4)))
    with pytest.raises(InvalidInputError, match=r"vertices must be a \(V, 3\) array .*; got shape \(5, 2\)"):
        drape_colors(np.ones((5, 2)), image)
    with pytest.raises(InvalidInputError, match=r"vertices must be finite and away from the centre; got vertex 1"):
        drape_colors([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], image)
    with pytest.raises(InvalidInputError, match=r"latitude must lie in \[-90, 90\] degrees; got 100.0"):
        look_from(100.0, 0.0, 1.0e6)


def test_drape_colors_keeps_a_textures_alpha(small_globe):
    """An RGBA texture with transparent nodata (here the eastern hemisphere: alpha 0, black) draped as vertex colours
    came out opaque (alpha 255 everywhere: drape_colors dropped the alpha, though drape_texture keeps it), the
    transparent half black. The alpha is kept, bilinear as the colour is (the same as draping the alpha as a grey
    RGB image), and the colour is weighted by it: no vertex near the edge is darkened by the transparent black."""
    from stepterrain.globe import drape_colors

    vertices = small_globe.mesh(error=500.0).vertices
    image = np.zeros((90, 180, 4), np.uint8)
    image[:, :90] = (255, 0, 0, 255)  # the western hemisphere opaque red, the eastern transparent
    colours = drape_colors(vertices, image)
    lon = np.degrees(np.arctan2(vertices[:, 1], vertices[:, 0]))
    assert (colours[(lon > 10) & (lon < 170), 3] == 0).all() and (colours[(lon < -10) & (lon > -170), 3] == 255).all()
    alpha = image[..., 3]
    np.testing.assert_array_equal(colours[:, 3], drape_colors(vertices, np.dstack([alpha] * 3))[:, 0])
    seen = colours[:, 3] > 0
    assert 0 < (seen & (colours[:, 3] < 255)).sum() and (colours[seen, :3] == (255, 0, 0)).all()  # edge: no fringe
    # an opaque RGBA image is its RGB; a uniform alpha keeps the colours of the RGB
    rgb = np.random.default_rng(5).integers(0, 256, (90, 180, 3), dtype=np.uint8)
    opaque = drape_colors(vertices, rgb)
    assert (opaque[:, 3] == 255).all()
    np.testing.assert_array_equal(drape_colors(vertices, np.dstack([rgb, np.full((90, 180), 255, np.uint8)])), opaque)
    half = drape_colors(vertices, np.dstack([rgb, np.full((90, 180), 128, np.uint8)]))
    np.testing.assert_array_equal(half[:, :3], opaque[:, :3])
    assert (half[:, 3] == 128).all()


def test_a_16_bit_grayscale_texture_file_is_read_by_its_range(tmp_path):
    """Pillow's convert("RGB") of a 16-bit grayscale PNG (mode I;16) saturates every value above 255: a relief
    texture came out 99.6 % white, silently, in drape_colors / drape_texture and `stepterrain globe --texture`.
    It is read to 8 bits by its full range now (as Pillow reads 16-bit RGB); a float image is refused by name."""
    from PIL import Image

    from stepterrain.globe import _texture_pixels, drape_colors

    ramp = np.round(np.linspace(0, 65535, 32 * 64)).astype(np.uint16).reshape(32, 64)
    Image.fromarray(ramp).save(tmp_path / "relief16.png")
    Image.fromarray((ramp // 257).astype(np.uint8)).save(tmp_path / "relief8.png")
    pixels = _texture_pixels(tmp_path / "relief16.png")
    assert pixels.shape == (32, 64, 3) and pixels.dtype == np.uint8
    assert np.abs(pixels.astype(int) - _texture_pixels(tmp_path / "relief8.png")).max() <= 1
    vertices = np.array([[0.0, 0.0, R], [0.0, 0.0, -R], [R, 0.0, 0.0]])
    np.testing.assert_allclose(drape_colors(vertices, tmp_path / "relief16.png").astype(int),
                               drape_colors(vertices, tmp_path / "relief8.png").astype(int), atol=1)
    Image.fromarray(np.full((8, 8), 0.5, np.float32)).save(tmp_path / "float.tif")
    with pytest.raises(InvalidInputError, match="texture .*float.tif' must be an 8-bit or 16-bit image; got Pillow "
                                                "mode F"):
        _texture_pixels(tmp_path / "float.tif")


@pytest.mark.parametrize("elevation, expected", [
    (5.0, r"got shape \(\)"), (np.zeros((3, 3)), r"got shape \(3, 3\)"), (["a"], "got dtype <U1"),
    (None, "got dtype object"), ([[1.0], [1.0, 2.0]], "got rows of different lengths"),
    (np.ones(3, complex), "got dtype complex128")])
def test_elevation_colors_refuses_what_is_not_one_height_per_vertex(elevation, expected):
    # a scalar or None raised len()'s TypeError, a 2-D array an IndexError, text numpy's ValueError, and complex
    # heights lost their imaginary part
    from stepterrain.globe import elevation_colors

    with pytest.raises(InvalidInputError, match=rf"elevation must be a \(V,\) array of heights in metres.*{expected}"):
        elevation_colors(elevation)
    assert elevation_colors(np.ma.masked_array([1.0, 2.0], [True, False]))[0].tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize("vertices", [[[1.0, 2.0, 3.0], [1.0, 2.0]], [["a", "b", "c"]], np.ones((2, 3), complex)])
def test_drape_colors_refuses_vertices_that_are_not_real_numbers(vertices):
    from stepterrain.globe import drape_colors

    with pytest.raises(InvalidInputError, match=r"vertices must be a \(V, 3\) array of planet-centred positions"):
        drape_colors(vertices, np.zeros((4, 8, 3), np.uint8))
    with pytest.raises(InvalidInputError, match=r"longitude must be finite; got inf"):
        look_from(0.0, float("inf"), 1.0e6)


def test_drape_texture_refuses_a_non_finite_vertex_and_ragged_grids_are_named():
    """A NaN vertex got NaN texture coordinates without a word; ragged rows raised numpy's 'inhomogeneous
    shape' ValueError in from_latlon and adaptive_mesh."""
    from stepterrain.globe import drape_texture

    mesh = trimesh.Trimesh([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, np.nan]], [[0, 1, 2]], process=False)
    with pytest.raises(InvalidInputError, match=r"mesh vertices must be finite to drape a texture; got vertex 2"):
        drape_texture(mesh, np.zeros((4, 8, 3), np.uint8))
    with pytest.raises(InvalidInputError, match="elevation must be a real .* rows of different lengths"):
        Globe.from_latlon([[1.0, 2.0], [3.0]], LAT1, LON1, face_size=9)
    with pytest.raises(InvalidInputError, match="heights must be a real .* rows of different lengths"):
        adaptive_mesh([[1.0, 2.0], [3.0]], error=0.1)


def test_draped_texture_keeps_the_surface_and_wraps_the_antimeridian(small_globe, tmp_path):
    from stepterrain.globe import drape_colors, drape_texture

    mesh = small_globe.mesh(error=0.0)
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (45, 90, 3), dtype=np.uint8)
    textured = drape_texture(mesh, image)
    # the same triangles at the same positions, in the same order; copies only add vertices
    np.testing.assert_array_equal(textured.vertices[textured.faces], mesh.vertices[mesh.faces])
    assert len(textured.vertices) > len(mesh.vertices)
    np.testing.assert_array_equal(textured.face_attributes["cube_face"], mesh.face_attributes["cube_face"])
    uv = textured.visual.uv
    span = np.ptp(uv[textured.faces][:, :, 0], axis=1)
    assert span.max() < 0.25  # no face spans the image (the antimeridian and the poles wrap)
    assert uv[:, 0].min() >= 0.0 and uv[:, 0].max() < 1.5 and 0.0 <= uv[:, 1].min() and uv[:, 1].max() <= 1.0
    # u, v are longitude and latitude (computed independently here with arcsin)
    d = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    away = np.hypot(d[:, 0], d[:, 1]) > 1e-6
    lat = np.degrees(np.arcsin(d[:, 2]))
    lon = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    np.testing.assert_allclose(uv[: len(mesh.vertices)][away, 1], (lat[away] + 90) / 180, atol=1e-12)
    np.testing.assert_allclose(uv[: len(mesh.vertices)][away, 0], (lon[away] + 180) / 360, atol=1e-12)
    # the texture seen through the UVs is the image drape_colors samples at the vertices
    h, w = image.shape[:2]
    fx = (uv[:, 0] % 1.0) * w - 0.5
    fy = (1.0 - uv[:, 1]) * h - 0.5
    inner = (fx > 0.5) & (fx < w - 1.5) & (fy > 0.5) & (fy < h - 1.5)
    x0, y0 = np.floor(fx[inner]).astype(int), np.floor(fy[inner]).astype(int)
    tx, ty = (fx[inner] - x0)[:, None], (fy[inner] - y0)[:, None]
    p = image.astype(np.float64)
    top = (1 - tx) * p[y0, x0] + tx * p[y0, x0 + 1]
    seen = (1 - ty) * top + ty * ((1 - tx) * p[y0 + 1, x0] + tx * p[y0 + 1, x0 + 1])
    draped = drape_colors(textured.vertices[inner], image)[:, :3].astype(np.float64)
    assert np.abs(seen - draped).max() <= 1.0
    # the image travels in the GLB
    from stepterrain.export import save_mesh

    back = trimesh.load(save_mesh(textured, tmp_path / "earth.glb"), force="mesh", process=False)
    assert back.visual.material.baseColorTexture.size == (90, 45)
    with pytest.raises(InvalidInputError, match="texture must be"):
        drape_texture(mesh, np.zeros((4, 4)))
    with pytest.raises(InvalidInputError, match="mesh must be a trimesh.Trimesh"):
        drape_texture(mesh.vertices, image)


def test_sample_loads_the_embedded_grid():
    lat, lon, z = load_global_relief()
    assert z.shape == (540, 1080) and lat[0] > lat[-1] and lon[0] < lon[-1]
    g = Globe.sample(face_size=9, device="cpu")
    assert -11000 < g.heights.min() < 0 < g.heights.max() < 9000
    assert "Globe(face_size=9" in repr(g)


# ------------------------------------------------------------------------------------------ 7. bad input
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"face_size": 100}, "face_size must be 2"),
        ({"face_size": 2}, "face_size must be 2"),
        ({"face_size": 9.0}, "face_size must be an int"),
        ({"radius": 0.0}, "radius must be a positive"),
        ({"radius": -5.0}, "radius must be a positive"),
        ({"exaggeration": float("nan")}, "exaggeration must be a positive"),
    ],
)
def test_bad_globe_arguments(kwargs, match):
    args = {"face_size": 9, **kwargs}
    with pytest.raises(InvalidInputError, match=match):
        Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, device="cpu", **args)


def test_bad_latlon_grids():
    z = np.zeros((180, 360))
    with pytest.raises(InvalidInputError, match="lat must be strictly monotone"):
        Globe.from_latlon(z, np.r_[LAT1[:90], LAT1[:90]], LON1, face_size=9)
    with pytest.raises(InvalidInputError, match="lon must cover 360"):
        Globe.from_latlon(z[:, :180], LAT1, LON1[:180], face_size=9)
    with pytest.raises(InvalidInputError, match="both poles"):
        Globe.from_latlon(z[:90], LAT1[:90], LON1, face_size=9)
    with pytest.raises(InvalidInputError, match="regularly spaced"):
        Globe.from_latlon(z, np.r_[LAT1[:-1], -89.9], LON1, face_size=9)
    with pytest.raises(InvalidInputError, match=r"lat must lie in \[-90, 90\] degrees; got 90.5 to -88.5"):
        Globe.from_latlon(z, LAT1 + 1.0, LON1, face_size=9)
    with pytest.raises(InvalidInputError, match="lengths"):
        Globe.from_latlon(z, LAT1[:-1], LON1, face_size=9)
    nan = z.copy()
    nan[10, 20] = np.nan
    with pytest.raises(InvalidInputError, match="NaN.*row 10, column 20"):
        Globe.from_latlon(nan, LAT1, LON1, face_size=9)


def test_float32_axes_are_regular_to_their_precision():
    """lat / lon stored as float32 (as netCDF and many .npz grids hold them) were refused as not regularly spaced:
    the 10' grid's steps vary by an ulp of 180 in float32 (1.5e-5 degrees), above the 1e-6 relative margin. Read
    from float32 axes, the globe is that of the float64 axes up to the axes' own rounding."""
    with np.load(shared_file("global_relief.npz")) as d:
        lat, lon, z = np.asarray(d["lat"]), np.asarray(d["lon"]), np.asarray(d["elevation"])
    exact = Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")
    rounded = Globe.from_latlon(z, lat.astype(np.float32), lon.astype(np.float32), face_size=9, device="cpu")
    np.testing.assert_allclose(rounded.heights, exact.heights, rtol=0, atol=0.5)
    with pytest.raises(InvalidInputError, match="lat must be regularly spaced"):  # still refused when irregular
        lat32 = lat.astype(np.float32)
        lat32[5] += np.float32(1e-3)
        Globe.from_latlon(z, lat32, lon.astype(np.float32), face_size=9, device="cpu")


@pytest.mark.parametrize("result, match", [
    (lambda p, r: ["a"] * len(p), "got list that is not numbers"),
    (lambda p, r: None, r"got shape \(\)"),
    (lambda p, r: np.ones(3), r"got shape \(3,\)"),
    (lambda p, r: np.full(len(p), np.nan), "got NaN, inf or negative values"),
    # complex values lost their imaginary part (numpy's ComplexWarning) and refined by the real part, silently
    (lambda p, r: np.ones(len(p), complex), "got ndarray that is not numbers"),
])
def test_a_user_metric_returning_no_numbers_is_named(small_globe, result, match):
    """Text or None raised numpy's 'could not convert string to float' / TypeError, naming no metric."""
    def odd(points, radius):
        return result(points, radius)

    with pytest.raises(InvalidInputError, match=rf"user metric 'odd' must return \d+ finite values >= 0; {match}"):
        small_globe.mesh(error=100.0, metrics=("geometric", odd))


def test_bad_mesh_arguments(small_globe):
    g = small_globe
    with pytest.raises(InvalidInputError, match="error must be"):
        g.mesh(error=-1.0)
    with pytest.raises(InvalidInputError, match="bounds must be"):
        g.mesh(bounds="box")
    with pytest.raises(InvalidInputError, match="metrics must be"):
        g.mesh(metrics=("geometric", "screen"))
    with pytest.raises(InvalidInputError, match="inside the planet"):
        g.mesh(camera=Camera(eye=(0.5 * R, 0.0, 0.0), target=(0.0, 0.0, 0.0)))
    with pytest.raises(InvalidInputError, match="eye and target"):
        Camera(eye=(1.0, 2.0, 3.0), target=(1.0, 2.0, 3.0))
    with pytest.raises(InvalidInputError, match="parallel"):
        Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0))
    with pytest.raises(InvalidInputError, match="fov"):
        Camera(eye=(3.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), fov=4.0)
    with pytest.raises(InvalidInputError, match="near < far"):
        Camera(eye=(3.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), near=5.0, far=1.0)
    for aspect in (float("inf"), float("nan"), 0.0):  # checked before the default viewport is derived from it
        with pytest.raises(InvalidInputError, match="aspect must be a positive number"):
            Camera(eye=(3.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), aspect=aspect)
    for metrics in (None, 5):
        with pytest.raises(InvalidInputError, match="metrics must be a sequence"):
            g.mesh(metrics=metrics)
    eye, target = (3.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    for name, value in (("fov", "a"), ("near", "1"), ("near", None), ("far", True)):
        with pytest.raises(InvalidInputError, match=f"Camera {name} must be a number"):
            Camera(eye=eye, target=target, **{name: value})
    for bad_eye in ("abc", (0.0, 0.0, 1e300)):  # a huge eye overflowed the norms: "up ... parallel" before
        with pytest.raises(InvalidInputError, match="Camera eye must be 3 finite numbers within"):
            Camera(eye=bad_eye, target=target)
    for viewport in ((float("inf"), 2), (True, True), (640.5, 480), ("a", 2)):
        with pytest.raises(InvalidInputError, match="Camera viewport must be"):
            Camera(eye=eye, target=target, viewport=viewport)
    assert Camera(eye=eye, target=target, viewport=(640.0, 480), near=1, far=10).viewport == (640, 480)


@pytest.mark.parametrize("name", ["fov", "near", "far"])
def test_camera_fov_near_and_far_are_checked_as_aspect_is(name):
    """fov, near and far had their own isinstance check: a 0-d array or a Fraction was refused ("must be a number")
    where aspect took it, and NaN or inf was reported as an interval, not as not finite."""
    from fractions import Fraction

    eye, target = (0.0, -10.0, 5.0), (0.0, 0.0, 0.0)
    default = getattr(Camera(eye=eye, target=target), name)
    for same in (np.array(default), Fraction(default), np.float32(default) if name == "near" else default):
        value = getattr(Camera(eye=eye, target=target, **{name: same}), name)
        assert type(value) is float and value == pytest.approx(default)
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(InvalidInputError, match=rf"^Camera {name} must be finite; got {bad!r}$"):
            Camera(eye=eye, target=target, **{name: bad})


def test_memory_budget_refuses_before_allocating():
    import stepterrain._compaction as compaction

    previous = compaction.set_memory_budget(1 << 20)
    try:
        # 6 x 1025² entries of 32 bytes, the resampling's angle tables (513² slots of 28 bytes) and three float32
        # copies of the 180 x 360 grid
        with pytest.raises(OutputTooLargeError,
                           match="face_size 1025 from a 180x360 grid would need 200.1 MiB.*smaller face_size"):
            Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=1025)
    finally:
        compaction.set_memory_budget(previous)


def test_a_budget_below_the_one_launch_scratch_falls_back_to_level_passes(sample_globe):
    """The CPU's one-launch levels need 22 MB of scratch: under a smaller memory budget a view still meshes (level
    by level, each level checked on its own), the same mesh."""
    import stepterrain._compaction as compaction
    import stepterrain.globe as globe_module

    close = look_from(46.0, 9.0, 400_000.0, tilt=60.0, fov=0.5, aspect=1.5)
    assert globe_module._one_launch_bytes(globe_module._SMALL_LEVELS, True, True) > 8 << 20
    at_once = sample_globe.mesh(error=30.0, camera=close)
    previous = compaction.set_memory_budget(8 << 20)
    try:
        levelwise = sample_globe.mesh(error=30.0, camera=close)
    finally:
        compaction.set_memory_budget(previous)
    assert len(at_once.faces) > 100
    assert _mesh_key(levelwise) == _mesh_key(at_once)


def test_latlon_axes_that_are_not_numbers_are_refused_by_name(tmp_path, capsys):
    from stepterrain.cli import main

    z = np.zeros((180, 360))
    with pytest.raises(InvalidInputError, match=r"lat must be numbers \(degrees\); got dtype <U1"):
        Globe.from_latlon(z, np.full(180, "a"), LON1, face_size=9)
    with pytest.raises(InvalidInputError, match=r"lon must be numbers \(degrees\); got dtype object"):
        Globe.from_latlon(z, LAT1, [None] * 360, face_size=9)
    grid = tmp_path / "grid.npz"  # the CLI reads the axes from a file: exit 2, one line, no traceback
    np.savez(grid, elevation=z.astype(np.float32), lat=np.full(180, "a"), lon=LON1)
    assert main(["-q", "globe", str(grid), "--face-size", "5", "-o", str(tmp_path / "x.glb")]) == 2
    assert capsys.readouterr().err.strip() == "stepterrain globe: error: lat must be numbers (degrees); got dtype <U1"


@pytest.mark.parametrize("name", ["altitude", "tilt", "heading"])
@pytest.mark.parametrize("value", [float("inf"), float("nan"), "north"])
def test_look_from_refuses_a_non_finite_altitude_tilt_or_heading_by_name(name, value):
    args = {"altitude": 1.0e7, "tilt": 10.0, "heading": 0.0, name: value}
    with pytest.raises(InvalidInputError, match=rf"^{name} must be a finite number; got {value!r}$"):
        look_from(0.0, 0.0, args.pop("altitude"), **args)


def test_globe_cli_heading_inf_exits_2_naming_it(tmp_path, capsys):
    from stepterrain.cli import main

    assert main(["-q", "globe", "--face-size", "5", "--heading", "inf", "-o", str(tmp_path / "x.glb")]) == 2
    assert capsys.readouterr().err.strip() == "stepterrain globe: error: --heading must be a finite number; got inf"


@pytest.mark.parametrize("elevation, exaggeration", [(3.0e38, 1.0), (1.0e30, 1.0e10)])
def test_elevation_overflowing_float32_nodes_is_refused(elevation, exaggeration):
    # the pole value (a float32 mean) and exaggeration * z overflowed to inf: a mesh with non-finite vertices
    z = np.full((180, 360), elevation)
    with pytest.raises(InvalidInputError, match=r"exaggeration · elevation must stay within ±8.5e\+37 m .*; got "):
        Globe.from_latlon(z, LAT1, LON1, face_size=5, exaggeration=exaggeration, device="cpu")
    ok = Globe.from_latlon(np.full((180, 360), 1.0e37), LAT1, LON1, face_size=5, device="cpu")
    assert np.isfinite(ok.positions).all() and np.isfinite(ok.mesh().vertices).all()


def test_elevation_reaching_through_the_centre_is_refused():
    # radius + exaggeration * z <= 0 put nodes through the centre: an inside-out mesh (negative volume)
    z = np.zeros((180, 360))
    z[100, 200] = -3.2e6
    with pytest.raises(InvalidInputError, match=r"radius \+ exaggeration · elevation must stay > 0 .*; got "
                                                r"6371000 \+ 2 x -3200000 = -29000 m \(row 100, column 200\)"):
        Globe.from_latlon(z, LAT1, LON1, face_size=5, exaggeration=2.0, device="cpu")
    ok = Globe.from_latlon(z, LAT1, LON1, face_size=5, device="cpu").mesh()
    assert ok.volume > 0


@pytest.mark.parametrize("shift", [360.0, 1e6, 1e9, -7.2e6])
def test_a_longitude_axis_far_out_gives_the_globe_of_its_wrapped_axis(shift):
    """lon + shift is the grid of lon + (shift mod 360): the same mesh bit for bit, even a billion degrees out
    (lon0 is wrapped before its conversion to radians)."""
    z = np.random.default_rng(7).uniform(-4000.0, 4000.0, (180, 360))
    wrapped = Globe.from_latlon(z, LAT1, LON1 + shift % 360.0, face_size=17, device="cpu").mesh()
    far = Globe.from_latlon(z, LAT1, LON1 + shift, face_size=17, device="cpu").mesh()
    np.testing.assert_array_equal(far.vertices, wrapped.vertices)
    np.testing.assert_array_equal(far.faces, wrapped.faces)


def test_complex_elevations_are_refused():
    with pytest.raises(InvalidInputError, match="elevation must be a real"):
        Globe.from_latlon(np.zeros((180, 360), complex), LAT1, LON1, face_size=5, device="cpu")
    with pytest.raises(InvalidInputError, match="heights must be a real"):
        from stepterrain import adaptive_mesh

        adaptive_mesh(np.zeros((9, 9), complex), error=1.0)


@pytest.mark.parametrize("flag", ["no", 1, None])
def test_mesh_flags_must_be_bools(small_globe, flag):
    # per_face="no" returned six meshes (a non-empty string is true), cull="no" culled
    for name in ("per_face", "cull"):
        with pytest.raises(InvalidInputError, match=rf"{name} must be True or False; got {flag!r}"):
            small_globe.mesh(**{name: flag})
    with pytest.raises(InvalidInputError, match=rf"cull must be True or False; got {flag!r}"):
        adaptive_mesh(np.zeros((5, 5)), error=1.0, cull=flag)
    assert isinstance(small_globe.mesh(error=1e9, per_face=np.bool_(False)), trimesh.Trimesh)


def test_render_view_refuses_what_it_cannot_render(small_globe):
    """An empty mesh (a view that clips every triangle, which Globe.mesh returns as it is) raised numpy's AxisError
    from the bounds; a per_face list, None or a camera that is no Camera raised AttributeErrors."""
    from stepterrain.globe import render_view

    camera = look_from(0.0, 0.0, 1.0e6, tilt=89.0)  # looks over the horizon: nothing in view
    empty = small_globe.mesh(error=10.0, camera=camera)
    assert len(empty.faces) == 0
    with pytest.raises(InvalidInputError, match="mesh has no faces with finite vertices; nothing to render"):
        render_view(empty, camera, window_size=(64, 64))
    with pytest.raises(InvalidInputError, match="mesh must be a trimesh.Trimesh .*; got list"):
        render_view(small_globe.mesh(per_face=True), camera, window_size=(64, 64))
    with pytest.raises(InvalidInputError, match="mesh must be a trimesh.Trimesh .*; got NoneType"):
        render_view(None, camera, window_size=(64, 64))
    with pytest.raises(InvalidInputError, match="camera must be a stepterrain.globe.Camera; got tuple"):
        render_view(small_globe.mesh(), (0.0, 0.0, 1.0), window_size=(64, 64))


@needs_render
def test_a_low_tilted_view_renders_the_same_culled_or_not(sample_globe):
    """The cull drops only triangles outside the view, so it must not change the picture. The render's near plane
    sat at half the distance to the nearest corner of the mesh's box: 1,000-3,000 km out for a view from 400 km
    up, so the nearer terrain was clipped away and the inside of the globe's far side showed through (the help's
    Alps example: a dark picture with a bright band, and a different one with --no-cull)."""
    from stepterrain.globe import render_view

    camera = look_from(46.0, 9.0, 400_000.0, tilt=60.0, aspect=1.6)
    culled = sample_globe.mesh(error=20.0, camera=camera)
    whole = sample_globe.mesh(error=20.0, camera=camera, cull=False)
    assert len(culled.faces) < len(whole.faces)
    images = [render_view(m, camera, window_size=(160, 100)).astype(int) for m in (culled, whole)]
    assert (np.abs(images[0] - images[1]).max(axis=2) > 8).mean() < 0.002
    # and what it shows is the near side: every front-facing triangle the eye sees, not the far side's inside
    eye = np.asarray(camera.eye)
    front = np.einsum("fj,fj->f", culled.face_normals, eye - culled.triangles_center) > 0
    near_side = culled.copy()
    near_side.update_faces(front)
    near_side.remove_unreferenced_vertices()
    alone = render_view(near_side, camera, window_size=(160, 100)).astype(int)
    assert (np.abs(images[0] - alone).max(axis=2) > 8).mean() < 0.002


@needs_render
def test_views_are_lit_alike_in_both_hemispheres():
    """render_view lights the scene from the north-west of the ground under the view, as render_mesh lights a local
    terrain. In the world frame the light came from the north-west of the equatorial plane, so a view of the
    southern hemisphere was lit from below its horizon and came out dim (New Zealand from 600 km)."""
    from stepterrain.globe import render_view

    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    flat = Globe.from_latlon(np.zeros((180, 360), np.float32), lat, lon, face_size=33, device="cpu")
    brightness = []
    for latitude, heading in ((45.0, 0.0), (-45.0, 180.0)):  # mirror images of each other across the equator
        camera = look_from(latitude, 10.0, 500_000.0, tilt=30.0, heading=heading, aspect=1.6)
        brightness.append(render_view(flat.mesh(), camera, window_size=(160, 100)).mean())
    assert brightness[0] > 60
    assert 0.9 < brightness[1] / brightness[0] < 1.1, brightness


def test_look_from_far_plane_covers_an_extremely_exaggerated_globe():
    """The far plane lay at 2·|eye| + R whatever the relief: at an extreme exaggeration the far side's summits
    (behind the limb) lay beyond it and the clip metric cut them off. With max_radius (the globe's radius plus its
    highest exaggerated node) every node lies between the near and the far plane, and the culled mesh keeps them."""
    z = np.zeros((180, 360), np.float32)
    z[:, :10] = z[:, -10:] = 1000.0  # a plateau on the far side from lon 0: lon 170.5 to 180 to -170.5
    g = Globe.from_latlon(z, np.linspace(89.5, -89.5, 180), np.linspace(-179.5, 179.5, 360), face_size=17,
                          exaggeration=20_000.0, device="cpu")  # 20 000 km of relief: over three earth radii
    top = g.radius + float(g.heights.max())
    assert top > 4 * R
    nodes = g.positions.reshape(-1, 3).astype(np.float64)
    for lat, lon, altitude in ((0.0, 0.0, 2 * R), (10.0, -20.0, R)):
        plain = look_from(lat, lon, altitude)
        depth = (nodes - plain.eye) @ plain.frame()[0]
        assert depth.max() > plain.far  # the old far plane: the plateau's top beyond it
        cam = look_from(lat, lon, altitude, max_radius=top)
        depth = (nodes - cam.eye) @ cam.frame()[0]
        assert cam.near <= depth.min() and depth.max() < cam.far
        planes = cam.planes()
        assert np.all(nodes @ planes[4, :3] + planes[4, 3] <= 0) and np.all(nodes @ planes[5, :3] + planes[5, 3] <= 0)
        # the clip metric and culling, their side planes out of the way (a 179° view): near and far decide
        full = len(g.mesh(error=0.0).faces)
        for camera, whole in ((plain, False), (cam, True)):
            wide = dataclasses.replace(camera, fov=math.radians(179.0))
            faces = len(g.mesh(error=0.0, camera=wide, metrics=("geometric", "clip"), cull=True).faces)
            assert (faces == full) is whole, (faces, full)
    assert look_from(0.0, 0.0, 2 * R, max_radius=R).far == look_from(0.0, 0.0, 2 * R).far == 7 * R
    with pytest.raises(InvalidInputError, match="max_radius must be a positive finite number"):
        look_from(0.0, 0.0, 2 * R, max_radius=-1.0)
