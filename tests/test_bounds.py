"""The bounding-shape metrics of paper 003 §7.2-§7.4 (``kernels/bounds.py``) against brute force on the sampled shape.

The cone frustum {x : max(|p| - h, 0) <= |x| <= |p| + h, ∠(x, p) <= α} is sampled densely on its boundary (the caps
at the bottom and top radius, the mantle at α), and the Warp values are compared with the extremes over the samples.
Every sample is a point of the shape, so the true distance to the eye is at most the smallest sampled one and the
true largest plane distance at least the largest sampled one: the conservative side is checked without tolerance
(beyond float rounding). The tight side allows the sampling's half spacing: the samples' azimuths include the plane
through the axis and the eye (or the plane normal), where the extremes lie, so the spacing in θ and in the radius is
what is left. The test_globe.py tests compare with the planar-section formulas for openings up to 1.5 rad; the
globe's cones open to about 2.9 rad (:func:`test_globe_child_shapes_nest_in_their_parents`), covered here up to π.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp
from hypothesis import example, given, settings
from hypothesis import strategies as hst
from stepterrain.kernels import bounds as bk

from stepterrain.globe import EARTH_RADIUS, Camera, Globe

from . import reference_globe as ref

R = EARTH_RADIUS
N_THETA, N_RADIUS, N_PHI = 400, 400, 48


def _frame(axis: np.ndarray, towards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors u, w completing ``axis``: u along the part of ``towards`` orthogonal to the axis (if any)."""
    u = towards - (towards @ axis) * axis
    if np.linalg.norm(u) < 1e-9 * max(np.linalg.norm(towards), 1e-300):
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(axis, helper)
    u = u / np.linalg.norm(u)
    return u, np.cross(axis, u)


def _frustum_boundary(p: np.ndarray, h: float, alpha: float, towards: np.ndarray
                      ) -> tuple[np.ndarray, float]:
    """(samples (K, 3) of the frustum's bottom cap, top cap and mantle; the half spacing in θ and in the radius along
    the azimuth of ``towards``, which the samples include)."""
    length = float(np.linalg.norm(p))
    axis = p / length
    u, w = _frame(axis, towards)
    top, bottom = length + h, max(length - h, 0.0)
    theta = np.linspace(0.0, alpha, N_THETA)
    phi = np.linspace(0.0, 2.0 * np.pi, N_PHI, endpoint=False)
    radii = np.linspace(bottom, top, N_RADIUS)

    def directions(t: np.ndarray, f: np.ndarray) -> np.ndarray:
        return (np.cos(t)[..., None] * axis
                + np.sin(t)[..., None] * (np.cos(f)[..., None] * u + np.sin(f)[..., None] * w))

    t, f = np.meshgrid(theta, phi)
    cap = directions(t, f).reshape(-1, 3)
    rr, f = np.meshgrid(radii, phi)
    mantle = rr.reshape(-1, 1) * directions(np.full(rr.size, alpha), f.reshape(-1))
    samples = np.concatenate([bottom * cap, top * cap, mantle])
    spacing = 0.5 * max(top * alpha / (N_THETA - 1), (top - bottom) / (N_RADIUS - 1))
    return samples, spacing


def _inside(x: np.ndarray, p: np.ndarray, h: float, alpha: float) -> bool:
    length, size = float(np.linalg.norm(p)), float(np.linalg.norm(x))
    if not max(length - h, 0.0) <= size <= length + h:
        return False
    return size == 0.0 or math.atan2(float(np.linalg.norm(np.cross(x, p))), float(x @ p)) <= alpha


def _distances(p: np.ndarray, h: float, alpha: float, eye: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """(eye-sphere, eye-cone, plane-sphere, plane-cone) of bk.evaluate_shape_distances for one shape (r = 0)."""
    device = wp.get_device("cpu")
    out = wp.empty(1, dtype=wp.vec4d, device=device)
    wp.launch(bk.evaluate_shape_distances, dim=1,
              inputs=[0, wp.array([p], dtype=wp.vec3d, device=device),
                      wp.array([(0.0, h, alpha)], dtype=wp.vec3d, device=device), wp.vec3d(*eye), wp.vec4d(*plane)],
              outputs=[out], device=device)
    return out.numpy()[0]


_direction = hst.tuples(*[hst.floats(-1.0, 1.0)] * 3).filter(lambda v: math.hypot(*v) > 0.1)
_length = hst.sampled_from([1.0, 1.0e3, R])
_height = hst.one_of(hst.just(0.0), hst.floats(1e-6, 0.02), hst.floats(0.02, 2.0))  # x |p|: h = 0 .. past the centre
_opening = hst.one_of(hst.just(0.0), hst.floats(1e-7, 0.05), hst.floats(0.05, math.pi),  # 0, Taylor, libm
                      hst.floats(-1e-6, 1e-6).map(lambda x: math.pi / 2 + x))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


@settings(max_examples=60, deadline=None)
@given(axis=_direction, length=_length, height=_height, alpha=_opening, where=hst.sampled_from(
    ["anywhere", "origin", "on the axis", "inside", "below the bottom", "near the mantle"]),
       direction=_direction, distance=hst.floats(0.0, 3.0), spin=hst.floats(0.0, 2.0 * math.pi))
# the eye straight below the centre, opposite a cone of opening 0 (γ = π: sin γ = 0 as inside the opening)
@example(axis=(0.0, 0.0, 1.0), length=1.0, height=0.0, alpha=0.0, where="on the axis", direction=(0.0, 0.0, 1.0),
         distance=0.0, spin=0.0)
# the eye on the bottom rim (the law of cosines' form gave 2^-16 for 1e-13)
@example(axis=(0.5, 0.875, 0.9375), length=1000.0, height=0.015625, alpha=0.0, where="inside",
         direction=(0.0, 0.0, 1.0), distance=0.0, spin=0.0)
# past the centre, behind a frustum whose bottom is clamped at the centre (h > |p|): the nearest point is the apex
@example(axis=(0.0, 0.0, 1.0), length=1.0, height=1.5, alpha=0.3, where="anywhere", direction=(0.1, 0.0, -1.0),
         distance=1.0, spin=0.0)
def test_property_cone_eye_distance_is_a_tight_lower_bound_of_the_sampled_frustum(axis, length, height, alpha, where,
                                                                                  direction, distance, spin):
    """d(v, B_cone) (Abb. 6) never exceeds the distance from the eye to any point of the frustum (0 with the eye
    inside) and is within the sampling's spacing of the smallest: openings 0 to π (and π/2 exactly), h = 0 up to
    twice |p| (the bottom at the centre), eyes at the centre, on the axis, inside, below the bottom and just off the
    mantle."""
    p = _unit(axis) * length
    h = height * length
    top, bottom = length + h, max(length - h, 0.0)
    axis_u = _unit(axis)
    u, w = _frame(axis_u, np.asarray(direction, dtype=np.float64))
    side = math.cos(spin) * u + math.sin(spin) * w  # a direction orthogonal to the axis
    if where == "anywhere":
        eye = _unit(direction) * distance * length
    elif where == "origin":
        eye = np.zeros(3)
    elif where == "on the axis":
        eye = axis_u * (distance - 1.0) * 2.0 * top  # in front of, inside, behind the frustum or past the centre
    elif where == "inside":
        theta = alpha * distance / 3.0
        eye = (bottom + (top - bottom) * (distance / 3.0)) * (math.cos(theta) * axis_u + math.sin(theta) * side)
    elif where == "below the bottom":
        theta = min(math.pi, alpha * distance)
        eye = bottom * (distance / 3.0) * (math.cos(theta) * axis_u + math.sin(theta) * side)
    else:  # just outside the mantle (β a little above α), at a radius around the frustum's
        theta = min(math.pi, alpha + 1e-3 * distance)
        eye = (0.5 + distance / 2.0) * top * (math.cos(theta) * axis_u + math.sin(theta) * side)
    got = _distances(p, h, alpha, eye, np.array([0.0, 0.0, 1.0, 0.0]))[1]
    samples, spacing = _frustum_boundary(p, h, alpha, eye)
    sampled = float(np.linalg.norm(samples - eye, axis=1).min())
    rounding = 1e-12 * (top + float(np.linalg.norm(eye)))
    if _inside(eye, p, h, alpha):
        assert got <= rounding
        return
    assert got <= sampled + rounding, f"d(v, B) = {got} exceeds the distance {sampled} to a point of the frustum"
    assert got >= sampled - spacing - rounding, f"d(v, B) = {got} far below the sampled distance {sampled}"


@settings(max_examples=60, deadline=None)
@given(axis=_direction, length=_length, height=_height, alpha=_opening, how=hst.sampled_from(
    ["any", "parallel to the axis", "along the axis", "against the axis", "at the rim", "at the bottom rim"]),
       direction=_direction, offset=hst.floats(-2.0, 2.0), tilt=hst.floats(-1e-3, 1e-3))
# n against the axis of a cone of opening 0 (γ = π): the bottom's point, not the top's
@example(axis=(0.0, 0.0, 1.0), length=1.0, height=0.5, alpha=0.0, how="against the axis", direction=(1.0, 0.0, 0.0),
         offset=0.0, tilt=0.0)
def test_property_cone_plane_distance_bounds_the_sampled_frustum_from_above(axis, length, height, alpha, how,
                                                                            direction, offset, tilt):
    """max ⟨n, x⟩ + a over the frustum (Abb. 7) is at least its value at every point of the frustum and within the
    sampling's spacing of the largest; so is minus the inverted plane's value below the smallest (the clip test's
    "wholly outside"). Normals anywhere, orthogonal to the axis (planes parallel to it), along and against it, and
    near the angles where the cases change (γ = 0: n at α from the axis; γ = 90°)."""
    axis_u = _unit(axis)
    p = axis_u * length
    h = height * length
    u, _ = _frame(axis_u, np.asarray(direction, dtype=np.float64))
    beta = {"any": None, "parallel to the axis": math.pi / 2, "along the axis": 0.0, "against the axis": math.pi,
            "at the rim": alpha + tilt, "at the bottom rim": alpha + math.pi / 2 + tilt}[how]
    if beta is None:
        n = _unit(direction)
    else:
        beta = min(max(beta, 0.0), math.pi)
        n = math.cos(beta) * axis_u + math.sin(beta) * u
    plane = np.array([*n, offset * length])
    got = _distances(p, h, alpha, np.zeros(3), plane)[3]
    got_inverted = _distances(p, h, alpha, np.zeros(3), -plane)[3]
    samples, spacing = _frustum_boundary(p, h, alpha, n)
    values = samples @ n + plane[3]
    rounding = 1e-12 * (length + h + abs(plane[3]))
    assert got >= values.max() - rounding, f"largest plane distance {got} below a point's {values.max()}"
    assert got <= values.max() + spacing + rounding
    assert -got_inverted <= values.min() + rounding, f"smallest plane distance {-got_inverted} above {values.min()}"
    assert -got_inverted >= values.min() - spacing - rounding


# ------------------------------------------------------------------------------------------ saturation of §7.4
@wp.kernel
def _refine_pairs(eye: wp.vec3d, eye_length: wp.float64, eye_unit: wp.vec3d, planes: wp.array[wp.vec4d],
                  flags: wp.vec4i, distance_scale: wp.float64, error: wp.float64, errors: wp.array[wp.float32],
                  centres: wp.array[wp.vec3], params: wp.array[wp.vec3], out: wp.array[wp.int32]):
    """refine_node of each shape (e, p, (r, h, α))."""
    i = wp.tid()
    q = params[i]
    out[i] = bk.refine_node(eye, planes, flags, distance_scale, error, errors[i], centres[i], q[0], q[1], q[2],
                            wp.float64(1.0), eye_length, eye_unit)


def _refine(eye, planes, flags, scale, error, errors, centres, params) -> np.ndarray:
    device = wp.get_device("cpu")
    out = wp.empty(len(errors), dtype=wp.int32, device=device)
    eye = np.asarray(eye, dtype=np.float64)
    length = float(np.linalg.norm(eye))
    wp.launch(_refine_pairs, len(errors),
              [wp.vec3d(*eye), length, wp.vec3d(*(eye / length if length > 0 else eye)),
               wp.array(planes, dtype=wp.vec4d, device=device), wp.vec4i(*flags), scale, error,
               wp.array(errors, dtype=wp.float32, device=device), wp.array(centres, dtype=wp.vec3, device=device),
               wp.array(params, dtype=wp.vec3, device=device)], [out], device=device)
    return out.numpy()


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(axis=-1))


@settings(max_examples=20, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), cone=hst.booleans(), metrics=hst.sampled_from(
    [(1, 1, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1), (0, 1, 0)]), altitude=hst.floats(-0.002, 3.0),
       spread=hst.floats(1e-5, 0.3))
def test_property_refinement_is_saturated_for_nested_shapes(seed, cone, metrics, altitude, spread):
    """§5.2 / §7.4: a child shape nested in its parent's (the parent's r, h, α enclosing the child's with the level's
    float32 margin, as the globe's preprocessing makes them, and e(parent) >= e(child)) never refines while its parent
    does not, through every quick reject and accept of refine_node, for eyes far away, near and inside the shapes; and
    a parent found wholly inside the view has no child clipped."""
    rng = np.random.default_rng(seed)
    count = 400
    margin = 2.0**-20
    child = rng.normal(size=(count, 3))
    child *= (R * (1.0 + rng.uniform(-0.002, 0.002, count)) / np.linalg.norm(child, axis=1))[:, None]
    parent = child + rng.normal(size=(count, 3)) * R * spread * rng.uniform(0.0, 1.0, (count, 1))
    child, parent = child.astype(np.float32), parent.astype(np.float32)
    c64, p64 = child.astype(np.float64), parent.astype(np.float64)
    c_len, p_len = np.linalg.norm(c64, axis=1), np.linalg.norm(p64, axis=1)
    child_params = np.column_stack([R * spread * rng.uniform(0, 0.5, count), R * spread * rng.uniform(0, 0.05, count),
                                    spread * rng.uniform(0, 0.5, count)]).astype(np.float32).astype(np.float64)
    absolute = p_len * 2.0**-22
    parent_params = np.column_stack([
        (np.linalg.norm(p64 - c64, axis=1) + child_params[:, 0]) * (1 + margin) + absolute,
        (np.abs(p_len - c_len) + child_params[:, 1]) * (1 + margin) + absolute,
        (_angle(p64, c64) + child_params[:, 2]) * (1 + margin) + 2.0**-22])
    child_errors = rng.uniform(0.0, 1e4, count).astype(np.float32)
    parent_errors = np.maximum(child_errors, rng.uniform(0.0, 1e4, count).astype(np.float32))
    eye = rng.normal(size=3)
    eye *= R * (1.0 + altitude) / np.linalg.norm(eye)
    target = child[rng.integers(count)].astype(np.float64)
    cam = Camera(eye=tuple(eye), target=tuple(target), up=tuple(rng.normal(size=3)), fov=float(rng.uniform(0.2, 2.0)),
                 aspect=float(rng.uniform(0.5, 2.0)), near=1.0,
                 far=float(np.linalg.norm(target - eye)) + float(rng.uniform(0.01, 3.0)) * R)
    planes = cam.planes()
    scale = max(abs(altitude) * R, 1e3)
    # ε about the median μ (the sphere's distance): half of the shapes refine
    mu = parent_errors.astype(np.float64) if metrics[0] else np.ones(count)
    if metrics[1]:
        mu = mu * (scale / np.maximum(np.linalg.norm(p64 - eye, axis=1) - parent_params[:, 0], 1.0)) ** 2
    error = float(np.median(mu))
    flags = (*metrics, int(cone))
    got_parent = _refine(eye, planes, flags, scale, error, parent_errors, parent, parent_params.astype(np.float32))
    got_child = _refine(eye, planes, flags, scale, error, child_errors, child, child_params.astype(np.float32))
    assert ((got_child == 0) | (got_parent != 0)).all(), \
        f"{int(((got_child != 0) & (got_parent == 0)).sum())} children refine below a parent that does not"
    assert 0 < (got_parent != 0).sum() < count  # both decisions occur
    if metrics[2]:
        unclipped = _refine(eye, planes, (*metrics[:2], 0, int(cone)), scale, error, child_errors, child,
                            child_params.astype(np.float32))
        inside = got_parent == 2
        assert ((got_child[inside] != 0) == (unclipped[inside] != 0)).all(), "a child clipped below a parent inside"


def test_globe_child_shapes_nest_in_their_parents():
    """The saturation of d(v, B) and of the clip test rests on B(child) ⊆ B(parent) (§6), on the float32 positions
    and parameters the metrics read: ‖p - c‖ + r(c) <= r(p), |c| + h(c) <= |p| + h(p), max(|c| - h(c), 0) >=
    max(|p| - h(p), 0) and ∠(p, c) + α(c) <= α(p), with no tolerance; and α stays below π, where the cone's case
    distinction by the sign of sin(β - α) holds."""
    g = Globe.sample(face_size=17, exaggeration=20.0, device="cpu")
    cells = g.cells
    pos = g.positions.reshape(-1, 3).astype(np.float64)
    params = {k: v.reshape(-1).astype(np.float64) for k, v in g.node_parameters().items()}
    r, h, alpha = params["bounding_radius"], params["cone_height"], params["cone_angle"]
    by_point = ref.entries_by_point(cells)
    _, children, _ = ref.bisection_tree(cells)
    pairs = np.array([(by_point[pt][0], by_point[c][0]) for pt, cs in children.items() for c in cs])
    k, c = pairs[:, 0], pairs[:, 1]
    p_len, c_len = np.linalg.norm(pos[k], axis=1), np.linalg.norm(pos[c], axis=1)
    assert (np.linalg.norm(pos[k] - pos[c], axis=1) + r[c] <= r[k]).all()
    assert (c_len + h[c] <= p_len + h[k]).all()
    assert (np.maximum(c_len - h[c], 0.0) >= np.maximum(p_len - h[k], 0.0)).all()
    assert (_angle(pos[k], pos[c]) + alpha[c] <= alpha[k]).all()
    assert 2.0 < alpha.max() < math.pi  # the coarse cones open far beyond π/2 (about 2.9 rad at fine grids)


# ------------------------------------------------------------------------------------------ camera frustum
@settings(max_examples=30, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), fov=hst.floats(0.05, 3.0), aspect=hst.floats(0.2, 5.0),
       height=hst.integers(1, 2000), scale=hst.sampled_from([1.0, R]))
def test_property_camera_frustum_corners_lie_on_their_planes_and_project_to_the_image_corners(seed, fov, aspect,
                                                                                             height, scale):
    """The frustum built from the camera's frame (corners eye + d (f ± tan(fov/2)·aspect·r ± tan(fov/2)·u), d = near,
    far) lies on the inner side of the six outward planes, each corner on exactly its three planes, and the corners
    project to the image corners (to the half pixel the viewport's rounding allows); points inside project into the
    image and lie inside all planes, points pushed out through one face lie outside that plane only."""
    rng = np.random.default_rng(seed)
    eye = rng.normal(size=3) * scale
    near = float(rng.uniform(0.01, 10.0)) * scale
    cam = Camera(eye=tuple(eye), target=tuple(eye + rng.normal(size=3) * scale), up=tuple(rng.normal(size=3)),
                 fov=fov, aspect=aspect, viewport=(max(1, round(height * aspect)), height), near=near,
                 far=near * float(rng.uniform(1.5, 100.0))) if round(height * aspect) >= 1 else None
    if cam is None or abs(cam.aspect * height - cam.viewport[0]) > 0.5:
        return
    planes = cam.planes()
    forward, right, up = cam.frame()
    tv = math.tan(fov / 2.0)
    th = tv * cam.aspect
    width, height = cam.viewport
    tol = 1e-9 * (np.abs(eye).max() + cam.far)
    for d, plane_index in ((cam.near, 4), (cam.far, 5)):
        for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
            corner = eye + d * (forward + sx * th * right + sy * tv * up)
            values = planes[:, :3] @ corner + planes[:, 3]
            on = {plane_index, 0 if sx < 0 else 1, 2 if sy < 0 else 3}
            assert all(abs(values[i]) <= tol for i in on), values
            assert all(values[i] < -1e-6 * d * min(th, tv, 1.0) for i in set(range(6)) - on), values
            px, depth = cam.project(corner)
            assert depth[0] == pytest.approx(d, rel=1e-9)
            assert px[0, 0] == pytest.approx(0.0 if sx < 0 else width, abs=0.5 + 1e-6 * width)
            assert px[0, 1] == pytest.approx(height if sy < 0 else 0.0, abs=1e-6 * height)
    # random points inside, and each pushed out through one side face
    d = rng.uniform(cam.near, cam.far, 50)
    s, t = rng.uniform(-1.0, 1.0, (2, 50))
    points = eye + d[:, None] * (forward + (s * th)[:, None] * right + (t * tv)[:, None] * up)
    assert (points @ planes[:, :3].T + planes[:, 3] <= tol).all()
    px, depth = cam.project(points)
    assert ((px[:, 0] >= -0.5 - 1e-6 * width) & (px[:, 0] <= width + 0.5 + 1e-6 * width)).all()
    assert ((px[:, 1] >= -1e-6 * height) & (px[:, 1] <= height * (1 + 1e-6))).all()
    for index, sign in enumerate((-1.0, 1.0, -1.0, 1.0)):  # left, right, bottom, top: 10 % past that face
        s_out, t_out = (np.full(50, 1.1 * sign), t) if index < 2 else (s, np.full(50, 1.1 * sign))
        out = eye + d[:, None] * (forward + (s_out * th)[:, None] * right + (t_out * tv)[:, None] * up)
        values = out @ planes[:, :3].T + planes[:, 3]
        assert (values[:, index] > 0).all(), f"plane {index}'s normal points inwards"
        assert (np.delete(values, index, axis=1) <= tol).all()


@pytest.mark.parametrize("scale", [1.0, 1e-100, 1e-200, 1e-300])
@pytest.mark.parametrize("cone", [0, 1])
def test_a_shape_holding_the_eye_refines_whatever_the_distance_scale(cone, scale):
    """§7.2: d(v, B) = 0 with the eye inside the shape, μ_dist = 1 / d² = ∞: the node refines whenever μ_geo > 0, as
    the spheres refine it. The cones compared μ · ℓ² <= ε · d² and kept the node unrefined once μ · ℓ² underflowed
    to 0 (ℓ below about 1e-162 here, a positive distance_scale that Globe.mesh takes): 0 <= ε · 0. A node beside the
    eye, 9000 km from it, stays unrefined (ℓ <= 1 m), as the paper's metric has it (μ_dist = (ℓ / d)² ≈ 0)."""
    eye = np.array([0.0, 0.0, R + 1.0])
    centres = np.array([[0.0, 0.0, R], [R, 0.0, 0.0]], dtype=np.float32)  # the eye 1 m above the first; far from both
    params = np.array([[100.0, 100.0, 1e-3]] * 2, dtype=np.float32)  # (r, h, α): the first shape holds the eye
    errors = np.array([5.0, 5.0], dtype=np.float32)
    got = _refine(eye, np.zeros((0, 4)), (1, 1, 0, cone), scale, 1e-3, errors, centres, params)
    assert got[0] == 1, f"the {'cone' if cone else 'sphere'} holding the eye did not refine at distance_scale {scale}"
    assert got[1] == 0  # μ = 5 (ℓ / 9e6 m)² <= 1e-3


@pytest.mark.parametrize("cone", [0, 1])
@pytest.mark.parametrize(("scale", "error"), [(1.0, 1e300), (1e160, 1.0), (1e200, 1e300), (1e155, 1e300)])
def test_huge_errors_and_distance_scales_decide_by_the_exact_metric(cone, scale, error):
    """μ = e · (ℓ / d)² > ε at the ends of float64. The spheres stood μ = 1e300 in for the eye inside the shape (μ_dist
    = ∞), so an ε of 1e300 or more kept the node the eye is in unrefined (Globe.mesh returned the 12 roots); the
    cones compared μ · ℓ² <= ε · d², which overflowed to inf <= inf for ℓ above ~1e154 and kept every node unrefined
    (the reference visit refines 754 triangles of the face-size-17 sample globe at ℓ = 1e160, ε = 1). Both decide
    as the exact metric now: the shape holding the eye refines whatever ε, a shape 9000 km off refines when
    5 · (ℓ / 9e6 m)² > ε (an overflow to inf included) and not otherwise."""
    eye = np.array([0.0, 0.0, R + 1.0])
    centres = np.array([[0.0, 0.0, R], [R, 0.0, 0.0]], dtype=np.float32)  # the eye 1 m above the first; far from both
    params = np.array([[100.0, 100.0, 1e-3]] * 2, dtype=np.float32)  # (r, h, α): the first shape holds the eye
    errors = np.array([5.0, 5.0], dtype=np.float32)
    got = _refine(eye, np.zeros((0, 4)), (1, 1, 0, cone), scale, error, errors, centres, params)
    d = math.dist(eye, centres[1].astype(np.float64)) - (100.0 if not cone else 0.0)  # about 9e6 m either way
    with np.errstate(over="ignore"):
        far = np.float64(5.0) * np.float64(scale / d) ** 2 > error
    assert got[0] == 1, f"the {'cone' if cone else 'sphere'} holding the eye did not refine at ε {error:g}"
    assert got[1] == int(far)
