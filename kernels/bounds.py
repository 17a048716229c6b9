"""Bounding shapes and refinement metrics of paper 003 (Adelsberger, §6-§7), as Warp device functions.

A node's bounding shape B is either a sphere (centre p, radius r) or a cone frustum about the node's radial
axis with concentrically curved top and bottom (radii |p| - h .. |p| + h, opening angle α around p/|p|).

* :func:`eye_distance_sphere`, :func:`eye_distance_cone`: d(v, B), the distance of the eye v to the shape
  (§7.2; the cone's six cases of Abb. 6).
* :func:`plane_distance_sphere`, :func:`plane_distance_cone`: the largest signed distance ⟨n, x⟩ + a over the
  shape (§7.3; the cone's three cases of Abb. 7). The smallest is minus the value for the inverted plane
  (-n, -a): the shape lies wholly on the outer side iff the inverted plane's value is < 0.
* :func:`refine_node`: μ = μ_geo · μ_dist · μ_clip (§7.4) > ε, each factor switchable in :class:`View`; it also
  says when a refining node's shape lies wholly inside the view, so that its descendants skip the clip test.

Shape parameters arrive as float32; every formula runs in float64, so the float32 saturation margin that the
preprocessing adds per level (relative 2^-20, paper §6: "Größenordnung 10^-6") always exceeds the rounding of
the metric and the computed metric stays saturated: parent >= child, hence no hanging nodes.

Planes use outward normals: a point x is inside the view frustum iff ⟨n_i, x⟩ + a_i <= 0 for all six i. The
plane loops read the planes with ``load`` of ``kernels/memory.py`` (no wrap of a negative index; k runs over
[0, len)).
"""

from __future__ import annotations

import warp as wp

from .memory import load

wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False})  # see kernels/__init__

FLOAT64_MAX = wp.constant(wp.float64(1.7976931348623157e308))


@wp.struct
class View:
    """What the refinement metric needs from a camera (eye and six planes, float64, planet-centred)."""

    eye: wp.vec3d
    planes: wp.array[wp.vec4d]  # (n_x, n_y, n_z, a): outward unit normal n and offset a
    distance_scale: wp.float64  # ℓ: μ_dist = (ℓ / d)^2, so `error` is the geometric error tolerated at d = ℓ
    error: wp.float64  # ε: a triangle refines when μ > ε (or ε == 0 and μ_clip == 1)
    flags: wp.vec4i  # (use_geometric, use_distance, use_clip, cone): each 1 or 0; cone 0 means spheres
    eye_length: wp.float64  # |eye| (hoisted out of the per-node cone formulas)
    eye_unit: wp.vec3d  # eye / |eye| (zero when the eye is the origin)


@wp.func
def to_vec3d(p: wp.vec3) -> wp.vec3d:
    """float32 point -> float64 point."""
    return wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))


@wp.func
def sin_cos(alpha: wp.float64) -> wp.vec2d:
    """(sin α, cos α): Taylor series below 0.05 rad (error < 1e-17, no libm call), libm above."""
    if alpha < wp.float64(0.05):
        a2 = alpha * alpha
        s = alpha * (wp.float64(1.0) - a2 / wp.float64(6.0) * (wp.float64(1.0) - a2 / wp.float64(20.0) * (
            wp.float64(1.0) - a2 / wp.float64(42.0))))
        c = wp.float64(1.0) - a2 / wp.float64(2.0) * (wp.float64(1.0) - a2 / wp.float64(12.0) * (
            wp.float64(1.0) - a2 / wp.float64(30.0) * (wp.float64(1.0) - a2 / wp.float64(56.0))))
        return wp.vec2d(s, c)
    return wp.vec2d(wp.sin(alpha), wp.cos(alpha))


@wp.func
def offset_angle(u_hat: wp.vec3d, p_hat: wp.vec3d, alpha_sc: wp.vec2d) -> wp.vec2d:
    """(sin γ, cos γ) of γ = β - α, β the angle between unit vectors u and p (no libm call): γ <= 0 iff
    sin γ <= 0 but at γ = π (:func:`within_opening` tells them apart), and γ < 90° iff cos γ > 0 (β, α in [0, π])."""
    cb = wp.dot(u_hat, p_hat)
    sb = wp.length(wp.cross(u_hat, p_hat))
    return wp.vec2d(sb * alpha_sc[1] - cb * alpha_sc[0], cb * alpha_sc[1] + sb * alpha_sc[0])


@wp.func
def within_opening(g: wp.vec2d, alpha_sc: wp.vec2d) -> wp.int32:
    """1 when γ = β - α <= 0 (β <= α), given (sin γ, cos γ) of :func:`offset_angle` and (sin α, cos α): sin γ <= 0,
    but for γ = π (β = π, α = 0: a point straight below the centre, opposite a cone of opening 0), where sin γ is 0
    as at γ = -π (β = 0, α = π). sin γ <= 0 with cos γ <= -1/2 is γ <= -2π/3, which needs cos α <= -1/2, or γ near
    π by rounding, with cos α near 1."""
    if g[0] > wp.float64(0.0):
        return 0
    if g[1] > wp.float64(-0.5) or alpha_sc[1] < wp.float64(0.5):
        return 1
    return 0


@wp.func
def rim_distance(v_len: wp.float64, g: wp.vec2d, t: wp.float64) -> wp.float64:
    """|v - t u| for a unit u at the angle γ from v, (sin γ, cos γ) = g: the law of cosines as
    sqrt((|v| - t)² + 2 |v| t (1 - cos γ)), with 1 - cos γ = sin² γ / (1 + cos γ) while cos γ > 0: the form
    |v|² - 2 |v| t cos γ + t² of paper 003 cancels to about sqrt(ε) |v| (1.5e-8 |v| too far) with the eye near
    the rim."""
    one_minus_cos = wp.float64(1.0) - g[1]
    if g[1] > wp.float64(0.0):
        one_minus_cos = g[0] * g[0] / (wp.float64(1.0) + g[1])
    radial = v_len - t
    return wp.sqrt(radial * radial + wp.float64(2.0) * v_len * t * one_minus_cos)


@wp.func
def eye_distance_sphere(p: wp.vec3d, r: wp.float64, eye: wp.vec3d) -> wp.float64:
    """d(v, B_sphere) = ||p - v|| - r, clamped at 0 (paper 003 §7.2)."""
    return wp.max(wp.length(p - eye) - r, wp.float64(0.0))


@wp.func
def eye_distance_cone(p: wp.vec3d, h: wp.float64, alpha: wp.float64, eye: wp.vec3d) -> wp.float64:
    """d(v, B_cone): the six cases of paper 003 Abb. 6 (§7.2); 0 when the eye lies inside."""
    p_len = wp.length(p)
    v_len = wp.length(eye)
    v_hat = wp.vec3d(0.0, 0.0, 0.0)
    if v_len > wp.float64(0.0):
        v_hat = eye / v_len
    return eye_distance_cone_unit(p / p_len, p_len, h, sin_cos(alpha), v_hat, v_len)


@wp.func
def eye_distance_cone_unit(p_hat: wp.vec3d, p_len: wp.float64, h: wp.float64, alpha_sc: wp.vec2d, v_hat: wp.vec3d,
                           v_len: wp.float64) -> wp.float64:
    """:func:`eye_distance_cone` with the axis p = p_len · p_hat, (sin α, cos α) and the eye v = v_len · v_hat
    given (each computed once per node / per view)."""
    top = p_len + h
    bottom = wp.max(p_len - h, wp.float64(0.0))
    if v_len <= wp.float64(0.0):
        return bottom
    g = offset_angle(v_hat, p_hat, alpha_sc)
    sin_g = g[0]
    cos_g = g[1]
    if within_opening(g, alpha_sc) != 0:  # β <= α: the eye lies above, inside or below the frustum
        if v_len > top:  # case 1: above the top
            return v_len - top
        if v_len < bottom:  # case 3: below the bottom
            return bottom - v_len
        return wp.float64(0.0)  # case 2: inside
    if cos_g > wp.float64(0.0):  # γ < 90°
        if v_len * cos_g >= bottom and v_len * cos_g <= top:  # case 5: t1 <= |v| <= t2, the mantle
            return v_len * sin_g
        if v_len * cos_g > top:  # case 4: |v| > t2, rim of the top
            return rim_distance(v_len, g, top)
    return rim_distance(v_len, g, bottom)  # case 6: rim of the bottom


@wp.func
def plane_distance_sphere(plane: wp.vec4d, p: wp.vec3d, r: wp.float64) -> wp.float64:
    """Largest signed distance ⟨n, x⟩ + a over the sphere: ⟨n, p⟩ + a + r (paper 003 §7.3)."""
    n = wp.vec3d(plane[0], plane[1], plane[2])
    return wp.dot(n, p) + plane[3] + r


@wp.func
def plane_distance_cone_unit(plane: wp.vec4d, p_hat: wp.vec3d, p_len: wp.float64, h: wp.float64,
                             alpha_sc: wp.vec2d) -> wp.float64:
    """:func:`plane_distance_cone` with the axis p = p_len · p_hat and (sin α, cos α) given."""
    n = wp.vec3d(plane[0], plane[1], plane[2])
    g = offset_angle(n, p_hat, alpha_sc)
    if within_opening(g, alpha_sc) != 0:  # case 1: γ <= 0, the top straight along n
        return plane[3] + (p_len + h)
    if g[1] >= wp.float64(0.0):  # case 2: 0 < γ <= 90°, the rim of the top
        return plane[3] + g[1] * (p_len + h)
    return plane[3] + g[1] * wp.max(p_len - h, wp.float64(0.0))  # case 3: the rim of the bottom


@wp.func
def plane_distance_cone(plane: wp.vec4d, p: wp.vec3d, h: wp.float64, alpha: wp.float64) -> wp.float64:
    """Largest signed distance ⟨n, x⟩ + a over the cone frustum: the three cases of Abb. 7 (§7.3)."""
    p_len = wp.length(p)
    return plane_distance_cone_unit(plane, p / p_len, p_len, h, sin_cos(alpha))


@wp.func
def inverted(plane: wp.vec4d) -> wp.vec4d:
    """The same plane with normal and offset negated."""
    return wp.vec4d(-plane[0], -plane[1], -plane[2], -plane[3])


#: :func:`sphere_view_side` / :func:`cone_view_side`: the shape lies wholly outside one plane of the view, or
#: wholly inside every plane (then so do the shapes nested in it: its descendants need no clip test).
OUTSIDE = wp.constant(1)
INSIDE = wp.constant(2)
#: Relative margin of the "wholly inside" test: far above the float64 rounding of the plane distances, so a
#: shape nested in one found inside is never found outside a plane by its own test.
INSIDE_MARGIN = wp.constant(wp.float64(1.000001))


@wp.func
def sphere_view_side(planes: wp.array[wp.vec4d], p: wp.vec3d, r: wp.float64) -> wp.int32:
    """:data:`OUTSIDE` when the bounding sphere lies wholly outside one of the six planes (the inverted-plane
    test: the largest distance over the sphere from the inverted plane is < 0), :data:`INSIDE` when it lies
    wholly inside every plane (with :data:`INSIDE_MARGIN`), else 0."""
    side = INSIDE
    k = wp.int32(0)
    while k < planes.shape[0]:
        plane = load(planes, k)
        centre = wp.dot(wp.vec3d(plane[0], plane[1], plane[2]), p) + plane[3]
        if centre > r:  # r - centre < 0: the inverted plane's largest distance, the same sign bit for bit
            return OUTSIDE
        if centre >= -r * INSIDE_MARGIN:
            side = 0
        k += 1
    return side


@wp.func
def cone_view_side(planes: wp.array[wp.vec4d], p: wp.vec3d, p_hat: wp.vec3d, p_len: wp.float64, h: wp.float64,
                   alpha: wp.float64, alpha_sc: wp.vec2d) -> wp.int32:
    """:func:`sphere_view_side` for a cone frustum, with p_hat, p_len and (sin α, cos α) given. "Inside" is
    judged by the ball below (a plane whose inner side holds the ball holds the frustum)."""
    # a ball about p holding the frustum: |x - p|² <= h² + (|p| + h) |p| α² (a quick accept / reject per
    # plane; the exact cases of Abb. 7 only for planes through that ball)
    ball = wp.sqrt(h * h + (p_len + h) * p_len * alpha * alpha) * wp.float64(1.000001)
    side = INSIDE
    k = wp.int32(0)
    while k < planes.shape[0]:
        plane = load(planes, k)
        centre = wp.dot(wp.vec3d(plane[0], plane[1], plane[2]), p) + plane[3]
        if centre > ball:
            return OUTSIDE
        if centre >= -ball * INSIDE_MARGIN:
            side = 0
            if centre >= -ball:
                if plane_distance_cone_unit(inverted(plane), p_hat, p_len, h, alpha_sc) < wp.float64(0.0):
                    return OUTSIDE
        k += 1
    return side


@wp.func
def triangle_outside_view(planes: wp.array[wp.vec4d], a: wp.vec3d, b: wp.vec3d, c: wp.vec3d) -> wp.int32:
    """1 when a flat triangle lies wholly outside one of the six planes (all three corners outside it)."""
    k = wp.int32(0)
    while k < planes.shape[0]:
        plane = load(planes, k)
        n = wp.vec3d(plane[0], plane[1], plane[2])
        if wp.dot(n, a) + plane[3] > wp.float64(0.0):
            if wp.dot(n, b) + plane[3] > wp.float64(0.0):
                if wp.dot(n, c) + plane[3] > wp.float64(0.0):
                    return 1
        k += 1
    return 0


@wp.func
def refine_side(side: wp.int32) -> wp.int32:
    """:func:`refine_node`'s answer after the clip test: 0 outside, 2 wholly inside, else 1."""
    if side == OUTSIDE:
        return 0
    if side == INSIDE:
        return 2
    return 1


@wp.func
def refine_node(
    eye: wp.vec3d, planes: wp.array[wp.vec4d], flags: wp.vec4i, distance_scale: wp.float64, error: wp.float64,
    e: wp.float32, p32: wp.vec3, r: wp.float32, h: wp.float32, alpha: wp.float32, factor: wp.float64,
    eye_length: wp.float64, eye_unit: wp.vec3d
) -> wp.int32:
    """The refinement rule μ > ε with μ = μ_geo · μ_dist · μ_clip · μ_user (§7.4; each factor 1 when switched
    off, μ_user = ``factor``); with ε == 0 every node not clipped refines. Returns 0 (no), 1 (refine) or 2
    (refine, and the clip test found the shape wholly inside the view: with nested shapes, so are all its
    descendants', whose clip test the caller may then switch off: the same decisions).

    Cheapest tests first: μ_geo, then an upper bound of μ_dist from the radial gap between the eye and the
    cone's shell (a lower bound of d), then the exact distance, and the six-plane clip test last. Each early
    "no" is a saturated predicate itself (nested shapes have nested radial ranges), so the rule stays
    saturated. The cone's |p|, p/|p| and (sin α, cos α) are computed once and shared by the distance and the
    clip test; |eye| and eye/|eye| come with the view."""
    p = to_vec3d(p32)
    if flags[3] != 0:
        return refine_cone(eye, eye_unit, eye_length, planes, flags, distance_scale, error, wp.float64(e), p,
                           wp.float64(h), wp.float64(alpha), factor)
    if error <= wp.float64(0.0):
        if flags[2] != 0:
            return refine_side(sphere_view_side(planes, p, wp.float64(r)))
        return 1
    mu = factor
    if flags[0] != 0:
        mu = mu * wp.float64(e)
    if mu <= error:
        if mu <= wp.float64(0.0) or flags[1] == 0:
            return 0
    if flags[1] != 0:
        d = eye_distance_sphere(p, wp.float64(r), eye)  # cones returned above, through refine_cone
        if d > wp.float64(0.0):  # d = 0, the eye inside the shape: μ_dist = ∞, refine (mu > 0 here)
            q = distance_scale / d
            mu = mu * q * q
            if mu <= error:
                return 0
        # (a finite stand-in, μ = 1e300, for the eye inside was no more than an ε of 1e300 or above: the node the
        # eye is in stayed unrefined)
    if flags[2] != 0:
        return refine_side(sphere_view_side(planes, p, wp.float64(r)))
    return 1


@wp.func
def refine_cone(
    eye: wp.vec3d, v_hat: wp.vec3d, v_len: wp.float64, planes: wp.array[wp.vec4d], flags: wp.vec4i,
    distance_scale: wp.float64, error: wp.float64, e: wp.float64, p: wp.vec3d, h: wp.float64, alpha: wp.float64,
    factor: wp.float64
) -> wp.int32:
    """:func:`refine_node` for cone frustums, the same decisions in the same order.

    Between the radial-gap reject and the exact distance (Abb. 6) a quick accept: the axis point p lies in the
    frustum, so d <= |eye - p|, and μ_dist with |eye - p| is a lower bound of the exact one; when it already
    exceeds ε the exact distance is not needed (most refining nodes of a distant view). μ_dist = (ℓ / d)² is
    compared as μ · ℓ² > ε · d² (a sign of d² - μ ℓ² / ε, without division or square roots)."""
    if error <= wp.float64(0.0):
        if flags[2] != 0:
            p_len0 = wp.length(p)
            return refine_side(cone_view_side(planes, p, p / p_len0, p_len0, h, alpha, sin_cos(alpha)))
        return 1
    mu = factor
    if flags[0] != 0:
        mu = mu * e
    if mu <= error:
        if mu <= wp.float64(0.0) or flags[1] == 0:
            return 0
    p_len = wp.length(p)
    p_hat = wp.vec3d(0.0, 0.0, 0.0)
    alpha_sc = wp.vec2d(0.0, 1.0)
    have_unit = wp.int32(0)
    if flags[1] != 0:
        # μ · (ℓ / d)² > ε compared as μ · ℓ² > ε · d²: no square root or division on the quick paths. An ε · d² that
        # overflows to inf is still right (the true one exceeds every finite μ · ℓ²); a μ · ℓ² that overflows is
        # not (inf <= inf kept every node unrefined, ℓ above ~1e154): then the quotient form, as the spheres'
        weighted = mu * distance_scale * distance_scale
        if weighted > FLOAT64_MAX:
            p_hat = p / p_len
            alpha_sc = sin_cos(alpha)
            have_unit = 1
            d = eye_distance_cone_unit(p_hat, p_len, h, alpha_sc, v_hat, v_len)
            if d > wp.float64(0.0):
                q = distance_scale / d
                if mu * q * q <= error:
                    return 0
        gap = wp.max(v_len - (p_len + h), (p_len - h) - v_len)
        if gap > wp.float64(0.0) and have_unit == 0:
            if weighted <= error * gap * gap:
                return 0
        far = eye - p
        if have_unit == 0 and weighted <= error * wp.dot(far, far):  # no quick accept: the exact distance
            p_hat = p / p_len
            alpha_sc = sin_cos(alpha)
            have_unit = 1
            d = eye_distance_cone_unit(p_hat, p_len, h, alpha_sc, v_hat, v_len)
            # d = 0, the eye inside the shape: μ_dist = ∞, refine (as the spheres), also where μ · ℓ²
            # underflowed to 0 (ℓ below 1e-154): 0 <= ε · 0 kept the node the eye is in unrefined
            if d > wp.float64(0.0):
                if weighted <= error * d * d:
                    return 0
    if flags[2] != 0:
        if have_unit == 0:
            p_hat = p / p_len
            alpha_sc = sin_cos(alpha)
        return refine_side(cone_view_side(planes, p, p_hat, p_len, h, alpha, alpha_sc))
    return 1


# ---------------------------------------------------------------------------------------------------------
# kernels used by tests and benchmarks to evaluate the formulas on many shapes at once
# ---------------------------------------------------------------------------------------------------------


@wp.kernel
def evaluate_shape_distances(
    thread_offset: wp.int32,
    centres: wp.array[wp.vec3d],
    params: wp.array[wp.vec3d],  # (r, h, alpha)
    eye: wp.vec3d,
    plane: wp.vec4d,
    # outputs
    distances_out: wp.array[wp.vec4d],  # (eye-sphere, eye-cone, plane-sphere max, plane-cone max)
):
    """One thread per shape: the four distance formulas for one eye and one plane."""
    i = wp.tid() + thread_offset
    p = centres[i]
    q = params[i]
    distances_out[i] = wp.vec4d(
        eye_distance_sphere(p, q[0], eye),
        eye_distance_cone(p, q[1], q[2], eye),
        plane_distance_sphere(plane, p, q[0]),
        plane_distance_cone(plane, p, q[1], q[2]),
    )
