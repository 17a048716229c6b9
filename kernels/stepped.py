"""Warp kernels of the stepped terrain (paper 000, Glander, Trapp & Döllner 2010, §3.1-3.3).

One pass quantizes every node to its level (§3.2, "vertex level"); a count -> scan -> emit pass over nodes
and edges allocates the welded output vertices (each node once, a *twin* below a node that sits exactly on a
threshold, and the wall bottom and top of every threshold crossing of every edge); a count -> scan -> emit
pass over triangles tessellates each triangle into horizontal terraces and vertical walls (§3.2, Fig. 2-3).
Both the count and the emit pass call :func:`step_triangle`, so they cannot disagree. On a grid the two count
passes are one kernel (:func:`count_grid`): a node's vertex slots and its cell's faces read the same four
levels; it keeps prefixes within chunks of nodes, so only the chunks' totals are scanned (:class:`Offsets`), and
the two emit passes are one kernel too (:func:`emit_grid`), which walks the same chunks, writing each node's
vertices and then its cell's faces, counting them as it writes them. A cell's face count is closed-form
(:func:`closed_form_faces`, shared with step_triangle) unless a corner sits on a crossed threshold; the chunks
holding such cells are counted by step_triangle's walk once the vertex offsets exist
(:func:`count_deferred_grid_faces`).

Hot loops index arrays through :mod:`.memory` (``load``/``store``: no negative-index wrap) and walk (i, j)
along with the node index instead of dividing it out.

Conventions (shared with ``stepterrain.stepped`` and ``tests/reference.py``):

* Every kernel takes ``thread_offset, count, chunk`` first: thread t handles the elements
  [(t + thread_offset)·chunk, … + chunk) ∩ [0, count) (``stepterrain._device.launch_chunked``: chunk is 64 on
  the CPU, where Warp copies a kernel's arguments for every thread, 256 for the grid passes quantize_levels,
  count_grid, count_deferred_grid_faces and emit_grid (``GRID_CHUNK_FACTOR``), and 1 on CUDA), so the CPU launcher
  can also split one pass over several cores.
* level(h) = the number of thresholds t_i <= h: a height exactly on a threshold belongs to the upper level.
* The crossings of an edge are stored lowest threshold first, two vertices each (wall bottom at α_j, wall
  top at α_j+1). When the upper endpoint lies exactly on its highest crossed threshold, that crossing's top
  *is* the endpoint and its bottom is the endpoint's twin (the last vertex the node owns), so no two output
  vertices share a position. A node on a threshold with every neighbour lower (a peak touching the
  threshold) keeps only its twin: its own terrace would have zero area.
* Per triangle, for each band k from the lowest to the highest level: the band's polygon (the triangle cut by
  the slab t_k-1 <= h < t_k, walked counter-clockwise from corner 0, repeated indices dropped) is fanned
  from its first vertex; then the wall of threshold k, from the crossing on the ascending edge (u) to the
  one on the descending edge (v): triangles (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom).
"""

from __future__ import annotations

from typing import Any

import warp as wp

from .memory import STREAM_MIN_BYTES, load, store, stream, stream_large, vec3l

wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False})  # see kernels/__init__

vec6i = wp.types.vector(length=6, dtype=wp.int32)


@wp.struct
class Isovalues:
    """The levels α_i (strictly increasing) and the thresholds t_i = (α_i + α_i+1) / 2 between them."""

    values: wp.array[wp.float32]
    thresholds: wp.array[wp.float32]
    # near-uniform thresholds (every gap within 25 % of their mean, the estimate within two levels of every
    # threshold's count): level_of starts from the linear estimate (h - first) · inv_gap + 1 and corrects it by
    # comparisons, instead of a binary search
    uniform: wp.int32
    first: wp.float32
    inv_gap: wp.float32


@wp.struct
class HeightField:
    """A regular grid: node n = i * cols + j sits at (j * dx, i * dy) in local coordinates."""

    heights: wp.array[wp.float32]
    levels: wp.array[wp.int32]
    rows: wp.int32
    cols: wp.int32
    spacing: wp.vec2
    flip: wp.int32  # 1 when dx * dy < 0: swap the winding so faces stay counter-clockwise seen from +z
    has_nodata: wp.int32  # 0 when every height is finite: every node and edge is used, no checks needed


@wp.struct
class TriangleNetwork:
    """A TIN with its edge table: faces index points, face_edges[f][k] is the edge from corner k to k+1."""

    points: wp.array[wp.vec3]
    heights: wp.array[wp.float32]
    levels: wp.array[wp.int32]
    faces: wp.array[wp.vec3i]
    face_edges: wp.array[wp.vec3i]
    edges: wp.array[wp.vec2i]
    point_used: wp.array[wp.int32]


@wp.struct
class Offsets:
    """A grid's vertex offsets, kept in two levels: slot s's first output vertex is ``local[s] + bases[s >> shift]``.

    count_grid writes each slot's exclusive prefix within its chunk of nodes (``local``) and each chunk's total as
    it counts, so only the chunk totals are scanned into ``bases`` (one int per 256 nodes on the CPU, instead of a
    scan over four ints per node: 12 ms of 180 at 2048²). A chunk holds 2^shift slots (CPU_CHUNK is a power of
    two; on CUDA a chunk is one node). :func:`offset_at` reads these or plain offsets (a TIN's). Measured in
    RESULTS.md "Session 20" (2048²/20: median 180 -> 175 ms, about 100 MB less scratch)."""

    local: wp.array[wp.int32]
    bases: wp.array[wp.int32]
    shift: wp.int32


@wp.struct
class DirectBlend:
    """The γ blend (§3.3) done as the vertex pass writes each vertex, for a scalar γ: world float64 positions
    streamed into ``vertices`` (:func:`blended`, the formula of blend_vertices, so the same bits), instead of
    the local positions and step heights that blend_vertices would read back. ``vertices`` is empty when the
    blend is left to blend_vertices; ``points`` / ``steps`` = 1 still write those arrays (a γ re-step, colours).
    Measured in RESULTS.md "Session 23"."""

    vertices: wp.array[wp.vec3d]
    gamma: wp.float32
    origin: wp.vec3d
    points: wp.int32
    steps: wp.int32


# ---------------------------------------------------------------------------------------------------------
# shared device functions
# ---------------------------------------------------------------------------------------------------------


@wp.func
def blended(p: wp.vec3, step_height: wp.float32, g: wp.float32, origin: wp.vec3d) -> wp.vec3d:
    """z = (1 - γ) z_original + γ z_step in float32, shifted back to world coordinates in float64."""
    z = (1.0 - g) * p[2] + g * step_height
    return wp.vec3d(wp.float64(p[0]) + origin[0], wp.float64(p[1]) + origin[1], wp.float64(z) + origin[2])


@wp.func
def put_vertex(
    slot: wp.int32,
    p: wp.vec3,
    step_height: wp.float32,
    points_out: wp.array[wp.vec3],
    step_heights_out: wp.array[wp.float32],
    direct: DirectBlend,
):
    """Write output vertex ``slot``: its local position and step height, or (``direct``) its blended world
    position."""
    if direct.vertices.shape[0] == 0:
        store(points_out, slot, p)
        store(step_heights_out, slot, step_height)
    else:
        if direct.points != 0:
            store(points_out, slot, p)
        if direct.steps != 0:
            store(step_heights_out, slot, step_height)
        stream_large(direct.vertices, slot, blended(p, step_height, direct.gamma, direct.origin))


@wp.func
def offset_at(offsets: wp.array[wp.int32], slot: wp.int32) -> wp.int32:
    """The first output vertex of count slot ``slot``: plain offsets (an exclusive scan)."""
    return load(offsets, slot)


@wp.func
def offset_at(offsets: Offsets, slot: wp.int32) -> wp.int32:  # noqa: F811
    """The first output vertex of count slot ``slot``: two-level offsets (see :class:`Offsets`)."""
    return load(offsets.local, slot) + load(offsets.bases, slot >> offsets.shift)


@wp.func
def level_of(h: wp.float32, iso: Isovalues) -> wp.int32:
    """Number of thresholds <= h: a height on a threshold belongs to the upper level. NaN gets 0.

    Near-uniform thresholds: the linear estimate, then compare-and-step to the exact count (one or two
    comparisons, predictable branches: 4.2 M nodes took 20-35 ms by binary search, see RESULTS); otherwise a
    binary search. Both return the exact count, whatever the estimate.
    """
    thresholds = iso.thresholds
    n = thresholds.shape[0]
    if iso.uniform != 0:
        x = (h - iso.first) * iso.inv_gap + 1.0
        k = wp.int32(0)
        if x >= wp.float32(n):
            k = n
        elif x >= 0.0:  # false for NaN
            k = wp.int32(x)
        elif wp.isnan(h):
            # nodata: NaN compares false, so the walk below went up through every threshold and back down. Checked
            # here, where only heights below the first threshold come: ahead of the estimate, the check cost every
            # finite height (quantizing 2048² on the CPU: 10 -> 12.5 ms)
            return 0
        while k < n:
            if load(thresholds, k) > h:
                break
            k += 1
        while k > 0:
            if load(thresholds, k - 1) <= h:
                break
            k -= 1
        return k
    lo = wp.int32(0)
    hi = n
    while lo < hi:
        mid = (lo + hi) // 2
        if load(thresholds, mid) <= h:
            lo = mid + 1
        else:
            hi = mid
    return lo


@wp.func
def on_threshold(h: wp.float32, level: wp.int32, thresholds: wp.array[wp.float32]) -> wp.int32:
    """1 when h lies exactly on the threshold just below its level."""
    if level > 0:
        if h == load(thresholds, level - 1):
            return 1
    return 0


@wp.func
def edge_vertex_count(
    a: wp.int32, b: wp.int32, heights: wp.array[wp.float32], levels: wp.array[wp.int32], iso: Isovalues
) -> wp.int32:
    """Output vertices an edge owns: two per crossed threshold, none for one whose top is the upper endpoint."""
    la = load(levels, a)
    lb = load(levels, b)
    if la == lb:
        return 0
    hi = b
    lhi = lb
    crossed = lb - la
    if la > lb:
        hi = a
        lhi = la
        crossed = la - lb
    return 2 * (crossed - on_threshold(load(heights, hi), lhi, iso.thresholds))


@wp.func
def edge_crossings(
    a: wp.int32,
    b: wp.int32,
    slot: wp.int32,
    heights: wp.array[wp.float32],
    levels: wp.array[wp.int32],
    iso: Isovalues,
    offsets: Any,
    stride: wp.int32,
) -> vec6i:
    """Edge a -> b, read once into registers: (level a, level b, its first crossing vertex, 1 if its top
    crossing is the upper end, that end's vertex, the end's twin).

    Node n's vertices start at slot ``n * stride``; its twin is the last one, one before slot ``n * stride + 1``.
    """
    la = load(levels, a)
    lb = load(levels, b)
    info = vec6i(la, lb, 0, 0, 0, 0)
    if la != lb:
        info[2] = offset_at(offsets, slot)
        hi = b
        lhi = lb
        if la > lb:
            hi = a
            lhi = la
        if on_threshold(load(heights, hi), lhi, iso.thresholds) != 0:
            info[3] = 1
            info[4] = offset_at(offsets, hi * stride)
            info[5] = offset_at(offsets, hi * stride + 1) - 1
    return info


@wp.func
def crossing_vertex(info: vec6i, j: wp.int32, top: wp.int32) -> wp.int32:
    """Output index of the wall bottom (top=0) or top (top=1) where the edge crosses threshold j."""
    llo = wp.min(info[0], info[1])
    lhi = wp.max(info[0], info[1])
    if info[3] != 0 and j == lhi - 1:
        if top == 1:
            return info[4]
        return info[5]
    return info[2] + 2 * (j - llo) + top


@wp.func
def write_face(
    write: wp.int32,
    slot: wp.int32,
    a: wp.int32,
    b: wp.int32,
    c: wp.int32,
    level: wp.int32,
    wall: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
):
    if write != 0:
        store(faces_out, slot, vec3l(wp.int64(a), wp.int64(b), wp.int64(c)))
        store(face_levels_out, slot, level)
        store(face_walls_out, slot, wp.uint8(wall))


@wp.func
def fan_push(
    v: wp.int32,
    state: wp.vec4i,
    level: wp.int32,
    write: wp.int32,
    face_base: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
) -> wp.vec4i:
    """Add vertex v to the terrace fan; state = (first, previous, vertices so far, faces so far)."""
    first = state[0]
    prev = state[1]
    n = state[2]
    count = state[3]
    if n == 0:
        return wp.vec4i(v, v, 1, count)
    if v == prev or v == first:
        return state
    if n >= 2:
        write_face(write, face_base + count, first, prev, v, level, 0, faces_out, face_levels_out, face_walls_out)
        count = count + 1
    return wp.vec4i(first, v, n + 1, count)


@wp.func
def walk_edge(
    info: vec6i,
    corner: wp.int32,
    k: wp.int32,
    state: wp.vec4i,
    write: wp.int32,
    face_base: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
) -> wp.vec4i:
    """Push the vertices band k's polygon has on the directed edge a -> b (vertex ``corner`` of a, then
    the crossings)."""
    la = info[0]
    lb = info[1]
    s = state
    if la == k:
        s = fan_push(corner, s, k, write, face_base, faces_out, face_levels_out, face_walls_out)
    if la < lb:
        if la <= k - 1 and k - 1 < lb:
            s = fan_push(crossing_vertex(info, k - 1, 1), s, k, write, face_base, faces_out, face_levels_out,
                         face_walls_out)  # fmt: skip
        if la <= k and k < lb:
            s = fan_push(crossing_vertex(info, k, 0), s, k, write, face_base, faces_out, face_levels_out,
                         face_walls_out)  # fmt: skip
    if la > lb:
        if lb <= k and k < la:
            s = fan_push(crossing_vertex(info, k, 0), s, k, write, face_base, faces_out, face_levels_out,
                         face_walls_out)  # fmt: skip
        if lb <= k - 1 and k - 1 < la:
            s = fan_push(crossing_vertex(info, k - 1, 1), s, k, write, face_base, faces_out, face_levels_out,
                         face_walls_out)  # fmt: skip
    return s


@wp.func
def wall_end(info: vec6i, j: wp.int32, ends: wp.vec4i) -> wp.vec4i:
    """Record the edge's crossing of threshold j as the wall's u (ascending) or v (descending) end."""
    la = info[0]
    lb = info[1]
    e = ends
    if la <= j and j < lb:
        e[0] = crossing_vertex(info, j, 1)
        e[1] = crossing_vertex(info, j, 0)
    if lb <= j and j < la:
        e[2] = crossing_vertex(info, j, 1)
        e[3] = crossing_vertex(info, j, 0)
    return e


@wp.func
def pick3(m: wp.int32, a: wp.int32, b: wp.int32, c: wp.int32) -> wp.int32:
    """a, b or c for m = 0, 1, 2 (selects, not an indexed vector: a variable index spills to the stack)."""
    return wp.where(m == 0, a, wp.where(m == 1, b, c))


@wp.func
def band_faces(
    triangle: wp.int32,
    ta: wp.int32,
    tb: wp.int32,
    tc: wp.int32,
    qa: wp.int32,
    qb: wp.int32,
    qc: wp.int32,
    qd: wp.int32,
    slot: wp.int32,
    level: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
) -> wp.int32:
    """Write one band of :func:`single_crossing` at ``slot``: the triangle (ta, tb, tc) when ``triangle``, else
    the quad (qa, qb, qc, qd) fanned from qa; return the faces written."""
    if triangle != 0:
        write_face(1, slot, ta, tb, tc, level, 0, faces_out, face_levels_out, face_walls_out)
        return 1
    write_face(1, slot, qa, qb, qc, level, 0, faces_out, face_levels_out, face_walls_out)
    write_face(1, slot + 1, qa, qc, qd, level, 0, faces_out, face_levels_out, face_walls_out)
    return 2


@wp.func
def single_crossing(
    v0: wp.int32,
    v1: wp.int32,
    v2: wp.int32,
    u0: wp.int32,
    u1: wp.int32,
    u2: wp.int32,
    x0: wp.int32,
    x1: wp.int32,
    x2: wp.int32,
    level: wp.int32,
    face_base: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
):
    """Emit the 5 faces of a triangle crossing only threshold ``level``, no corner on it, as step_triangle's walk
    does: the lower band's fan, the wall, the upper band's fan.

    v: the corners' vertices; u: 1 for a corner above the threshold; x: edge k's first vertex (its wall bottom,
    the top is x + 1), where edge k (corner k to k + 1) crosses.

    One corner m is alone on its side L: its band is the triangle (v_m, x_out, x_in) (edges out of and into m),
    the other band the quad (x_out, v_m+1, v_m+2, x_in); the walk from corner 0 starts both at the first of
    them it meets, so the rotations below are the walk's, picked by selects (the polygons were once built by
    a variable index into a vector: 8 % of a re-step went to the store-forwarding stalls that caused).
    """
    m = wp.int32(0)
    if u0 == u2:
        m = 1
    elif u0 == u1:
        m = 2
    lone = pick3(m, u0, u1, u2)
    vm = pick3(m, v0, v1, v2)
    x_out = pick3(m, x0, x1, x2)
    x_in = pick3(m, x2, x0, x1)
    # the lone band's triangle on side lone, from the walk: (v_m, x_out, x_in) for m = 0, else (x_in, v_m, x_out)
    t_out = x_out + lone
    t_in = x_in + lone
    ta = wp.where(m == 0, vm, t_in)
    tb = wp.where(m == 0, t_out, vm)
    tc = wp.where(m == 0, t_in, t_out)
    # the other band's quad on side 1 - lone: m = 0 (x_out, v1, v2, x_in), 1 (v0, x_in, x_out, v2),
    # 2 (v0, v1, x_in, x_out)
    side = 1 - lone
    q_out = x_out + side
    q_in = x_in + side
    qa = wp.where(m == 0, q_out, v0)
    qb = pick3(m, v1, q_in, v1)
    qc = pick3(m, v2, q_out, q_in)
    qd = pick3(m, q_in, v2, q_out)
    # the wall: from the ascending edge's crossing (u) to the descending one's (v)
    ub = wp.where(lone == 1, x_in, x_out)
    vb = wp.where(lone == 1, x_out, x_in)
    slot = face_base + band_faces(1 - lone, ta, tb, tc, qa, qb, qc, qd, face_base, level, faces_out, face_levels_out,
                                  face_walls_out)  # fmt: skip
    write_face(1, slot, ub + 1, vb + 1, vb, level, 1, faces_out, face_levels_out, face_walls_out)
    write_face(1, slot + 1, ub + 1, vb, ub, level, 1, faces_out, face_levels_out, face_walls_out)
    band_faces(lone, ta, tb, tc, qa, qb, qc, qd, slot + 2, level + 1, faces_out, face_levels_out, face_walls_out)


@wp.func
def closed_form_faces(heights: wp.array[wp.float32], thresholds: wp.array[wp.float32], c0: wp.int32,
                      c1: wp.int32, c2: wp.int32, l0: wp.int32, l1: wp.int32, l2: wp.int32) -> wp.int32:
    """Faces of triangle (c0, c1, c2) at levels (l0, l1, l2) where no vertex offsets are needed: 1 when flat,
    1 + 4 (lmax - lmin) when no corner above the lowest level lies on its threshold (see step_triangle); -1
    otherwise (a corner is aliased to a crossing, and only the walk counts the faces)."""
    lmin = wp.min(l0, wp.min(l1, l2))
    lmax = wp.max(l0, wp.max(l1, l2))
    if lmin == lmax:
        return 1
    if l0 > lmin:
        if on_threshold(load(heights, c0), l0, thresholds) != 0:
            return -1
    if l1 > lmin:
        if on_threshold(load(heights, c1), l1, thresholds) != 0:
            return -1
    if l2 > lmin:
        if on_threshold(load(heights, c2), l2, thresholds) != 0:
            return -1
    return 1 + 4 * (lmax - lmin)


@wp.func
def step_triangle(
    c0: wp.int32,
    c1: wp.int32,
    c2: wp.int32,
    s0: wp.int32,
    s1: wp.int32,
    s2: wp.int32,
    heights: wp.array[wp.float32],
    levels: wp.array[wp.int32],
    iso: Isovalues,
    offsets: Any,
    stride: wp.int32,
    write: wp.int32,
    face_base: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
) -> wp.int32:
    """Tessellate one counter-clockwise triangle into terraces and walls; return (and, if write, emit) its faces.

    c0, c1, c2 are node ids; s0, s1, s2 the vertex-offset slots of edges c0c1, c1c2, c2c0. Without a corner
    on a crossed threshold, band k's polygon has (corners at k) + 2 [k > lmin] + 2 [k < lmax] vertices, so
    the triangle yields 1 + 4 (lmax - lmin) faces (:func:`closed_form_faces`): the count pass uses that and walks
    only the rest. The walk reads each edge once (:func:`edge_crossings`) and then works in registers.
    """
    l0 = load(levels, c0)
    l1 = load(levels, c1)
    l2 = load(levels, c2)
    lmin = wp.min(l0, wp.min(l1, l2))
    lmax = wp.max(l0, wp.max(l1, l2))
    v0 = offset_at(offsets, c0 * stride)
    v1 = offset_at(offsets, c1 * stride)
    v2 = offset_at(offsets, c2 * stride)
    if lmin == lmax:
        write_face(write, face_base, v0, v1, v2, lmin, 0, faces_out, face_levels_out, face_walls_out)
        return 1
    closed = closed_form_faces(heights, iso.thresholds, c0, c1, c2, l0, l1, l2)
    if closed > 0:
        if write == 0:
            return closed
        if lmax == lmin + 1:
            # one threshold crossed, no corner on it (most crossing triangles of real terrain): the walk below
            # in closed form, same faces in the same order
            single_crossing(
                v0, v1, v2, l0 - lmin, l1 - lmin, l2 - lmin, offset_at(offsets, s0), offset_at(offsets, s1),
                offset_at(offsets, s2),
                lmin, face_base, faces_out, face_levels_out, face_walls_out,
            )  # fmt: skip
            return 5
    e0 = edge_crossings(c0, c1, s0, heights, levels, iso, offsets, stride)
    e1 = edge_crossings(c1, c2, s1, heights, levels, iso, offsets, stride)
    e2 = edge_crossings(c2, c0, s2, heights, levels, iso, offsets, stride)
    count = wp.int32(0)
    for k in range(lmin, lmax + 1):
        s = wp.vec4i(-1, -1, 0, count)
        s = walk_edge(e0, v0, k, s, write, face_base, faces_out, face_levels_out, face_walls_out)
        s = walk_edge(e1, v1, k, s, write, face_base, faces_out, face_levels_out, face_walls_out)
        s = walk_edge(e2, v2, k, s, write, face_base, faces_out, face_levels_out, face_walls_out)
        count = s[3]
        if k < lmax:
            ends = wall_end(e2, k, wall_end(e1, k, wall_end(e0, k, wp.vec4i(-1, -1, -1, -1))))
            if ends[0] != ends[2]:
                # wall of threshold k: (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom)
                base = face_base + count
                write_face(write, base, ends[0], ends[2], ends[3], k, 1, faces_out, face_levels_out, face_walls_out)
                write_face(write, base + 1, ends[0], ends[3], ends[1], k, 1, faces_out, face_levels_out,
                           face_walls_out)  # fmt: skip
                count = count + 2
    return count


@wp.func
def emit_edge_vertices(
    a: wp.int32,
    b: wp.int32,
    pa: wp.vec3,
    pb: wp.vec3,
    edge_source: wp.vec2i,
    first: wp.int32,
    heights: wp.array[wp.float32],
    levels: wp.array[wp.int32],
    iso: Isovalues,
    want_sources: wp.int32,
    direct: DirectBlend,
    points_out: wp.array[wp.vec3],
    step_heights_out: wp.array[wp.float32],
    sources_out: wp.array[wp.vec2i],
    betas_out: wp.array[wp.float32],
):
    """Write the wall bottom/top vertex pairs of edge a-b from index ``first``, lowest threshold first."""
    la = load(levels, a)
    lb = load(levels, b)
    if la == lb:
        return
    lo = a
    hi = b
    llo = la
    lhi = lb
    plo = pa
    phi = pb
    src = edge_source
    if la > lb:
        lo = b
        hi = a
        llo = lb
        lhi = la
        plo = pb
        phi = pa
        src = wp.vec2i(edge_source[1], edge_source[0])
    hlo = load(heights, lo)
    hhi = load(heights, hi)
    aliased = on_threshold(hhi, lhi, iso.thresholds)
    slot = first
    for j in range(llo, lhi - aliased):
        t = load(iso.thresholds, j)
        beta = (t - hlo) / (hhi - hlo)
        x = plo[0] + beta * (phi[0] - plo[0])
        y = plo[1] + beta * (phi[1] - plo[1])
        p = wp.vec3(x, y, t)
        put_vertex(slot, p, load(iso.values, j), points_out, step_heights_out, direct)
        put_vertex(slot + 1, p, load(iso.values, j + 1), points_out, step_heights_out, direct)
        if want_sources != 0:
            store(sources_out, slot, src)
            store(sources_out, slot + 1, src)
            store(betas_out, slot, beta)
            store(betas_out, slot + 1, beta)
        slot = slot + 2


@wp.func
def emit_node_vertices(
    n_source: wp.int32,
    p: wp.vec3,
    level: wp.int32,
    twin: wp.int32,
    peak: wp.int32,
    first: wp.int32,
    iso: Isovalues,
    want_sources: wp.int32,
    direct: DirectBlend,
    points_out: wp.array[wp.vec3],
    step_heights_out: wp.array[wp.float32],
    sources_out: wp.array[wp.vec2i],
    betas_out: wp.array[wp.float32],
):
    """Write a node's output vertex (and its twin one level below when it sits on a threshold)."""
    if peak != 0:
        put_vertex(first, p, load(iso.values, level - 1), points_out, step_heights_out, direct)
        if want_sources != 0:
            store(sources_out, first, wp.vec2i(n_source, n_source))
            store(betas_out, first, 0.0)
        return
    put_vertex(first, p, load(iso.values, level), points_out, step_heights_out, direct)
    if want_sources != 0:
        store(sources_out, first, wp.vec2i(n_source, n_source))
        store(betas_out, first, 0.0)
    if twin != 0:
        put_vertex(first + 1, p, load(iso.values, level - 1), points_out, step_heights_out, direct)
        if want_sources != 0:
            store(sources_out, first + 1, wp.vec2i(n_source, n_source))
            store(betas_out, first + 1, 0.0)


# ---------------------------------------------------------------------------------------------------------
# quantization
# ---------------------------------------------------------------------------------------------------------


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return 0;
#else
const int nt = thresholds.shape[0];
if (nt > 64) {
    return 0;
}
typedef float f16 __attribute__((ext_vector_type(16)));
typedef int i16 __attribute__((ext_vector_type(16)));
const float* h = heights.data;
const float* t = thresholds.data;
int* out = levels.data;
int m = start;
for (; m + 16 <= end; m += 16) {
    f16 hv;
    __builtin_memcpy(&hv, h + m, sizeof(hv));
    i16 k = (i16)(0);
    for (int i = 0; i < nt; ++i) {
        k -= (i16)((f16)(t[i]) <= hv);  // a true lane compares as -1
    }
    __builtin_memcpy(out + m, &k, sizeof(k));
}
for (; m < end; ++m) {
    const float hm = h[m];
    int k = 0;
    for (int i = 0; i < nt; ++i) {
        k += (t[i] <= hm);
    }
    out[m] = k;
}
return 1;
#endif
""")
def count_thresholds_below(
    heights: wp.array[wp.float32], thresholds: wp.array[wp.float32], levels: wp.array[wp.int32], start: wp.int32,
    end: wp.int32,
) -> wp.int32:  # pragma: no cover - native code
    """On the CPU with at most 64 thresholds: levels[m] = the number of thresholds <= heights[m] for m in [start,
    end), :func:`level_of`'s count (NaN compares false: 0), sixteen nodes at a time against every threshold
    (vector compares, no branches, no table lookups); returns 1. Otherwise (CUDA, more thresholds) 0: nothing
    written. 2048² with 20 steps: 8.3 -> 3.0-3.3 ms (RESULTS.md "Session 23")."""
    ...


@wp.kernel
def quantize_levels(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    heights: wp.array[wp.float32],
    iso: Isovalues,
    # outputs
    levels_out: wp.array[wp.int32],
):
    """One thread per node: its level, the index of the nearest isovalue (§3.2)."""
    n = (wp.tid() + thread_offset) * chunk
    end = wp.min(n + chunk, count)
    if count_thresholds_below(heights, iso.thresholds, levels_out, n, end) == 0:
        while n < end:
            store(levels_out, n, level_of(load(heights, n), iso))
            n += 1


# ---------------------------------------------------------------------------------------------------------
# regular grids: node n owns four vertex slots, 4n (itself and its twin), 4n+1 (edge to n+1), 4n+2 (edge
# to n+cols) and 4n+3 (diagonal to n+cols+1); edges are indexed implicitly, nothing is sorted
# ---------------------------------------------------------------------------------------------------------


@wp.func
def grid_finite(hf: HeightField, i: wp.int32, j: wp.int32) -> wp.int32:
    if i < 0 or j < 0 or i >= hf.rows or j >= hf.cols:
        return 0
    if wp.isfinite(load(hf.heights, i * hf.cols + j)):
        return 1
    return 0


@wp.func
def grid_edge_used(hf: HeightField, i: wp.int32, j: wp.int32, kind: wp.int32) -> wp.int32:
    """Edge ``kind`` (1 right, 2 down, 3 diagonal) of node (i, j): 1 when it exists, its ends are finite and
    one of its triangles has a finite third node."""
    if kind == 1:
        if j + 1 >= hf.cols:
            return 0
        if hf.has_nodata == 0:
            return 1
        third = grid_finite(hf, i + 1, j + 1) + grid_finite(hf, i - 1, j)
        return grid_finite(hf, i, j) * grid_finite(hf, i, j + 1) * wp.min(third, 1)
    if kind == 2:
        if i + 1 >= hf.rows:
            return 0
        if hf.has_nodata == 0:
            return 1
        third = grid_finite(hf, i + 1, j + 1) + grid_finite(hf, i, j - 1)
        return grid_finite(hf, i, j) * grid_finite(hf, i + 1, j) * wp.min(third, 1)
    if i + 1 >= hf.rows or j + 1 >= hf.cols:
        return 0
    if hf.has_nodata == 0:
        return 1
    third = grid_finite(hf, i, j + 1) + grid_finite(hf, i + 1, j)
    return grid_finite(hf, i, j) * grid_finite(hf, i + 1, j + 1) * wp.min(third, 1)


@wp.func
def grid_point(hf: HeightField, i: wp.int32, j: wp.int32, n: wp.int32) -> wp.vec3:
    """Node n = i * cols + j (the kernels walk i, j along with n: no integer division per element)."""
    return wp.vec3(wp.float32(j) * hf.spacing[0], wp.float32(i) * hf.spacing[1], load(hf.heights, n))


@wp.func
def next_node(ij: wp.vec2i, cols: wp.int32) -> wp.vec2i:
    """(i, j) of the next node in row-major order."""
    if ij[1] + 1 == cols:
        return wp.vec2i(ij[0] + 1, 0)
    return wp.vec2i(ij[0], ij[1] + 1)


@wp.func
def grid_incident(hf: HeightField, n: wp.int32, used: wp.int32, other: wp.int32, flags: wp.vec3i) -> wp.vec3i:
    """Fold an incident edge (to node other) into flags = (node used, a used neighbour is lower, one is not)."""
    f = flags
    if used != 0:
        f[0] = 1
        if load(hf.levels, other) < load(hf.levels, n):
            f[1] = 1
        else:
            f[2] = 1
    return f


@wp.func
def grid_node_flags(hf: HeightField, n: wp.int32) -> wp.vec3i:
    """(used by a finite triangle, has a used neighbour on a lower level, has one not lower) for node n."""
    cols = hf.cols
    i = n // cols
    j = n - i * cols
    f = wp.vec3i(0, 0, 0)
    f = grid_incident(hf, n, grid_edge_used(hf, i, j, 1), n + 1, f)
    f = grid_incident(hf, n, grid_edge_used(hf, i, j, 2), n + cols, f)
    f = grid_incident(hf, n, grid_edge_used(hf, i, j, 3), n + cols + 1, f)
    if j > 0:
        f = grid_incident(hf, n, grid_edge_used(hf, i, j - 1, 1), n - 1, f)
    if i > 0:
        f = grid_incident(hf, n, grid_edge_used(hf, i - 1, j, 2), n - cols, f)
        if j > 0:
            f = grid_incident(hf, n, grid_edge_used(hf, i - 1, j - 1, 3), n - cols - 1, f)
    return f


@wp.func
def node_vertex_count(used: wp.int32, twin: wp.int32, has_peer: wp.int32) -> wp.int32:
    """1 for a node, 2 with a twin, 1 for a peak on a threshold (its twin only), 0 when unused."""
    if used == 0:
        return 0
    if twin != 0 and has_peer == 0:
        return 1
    return 1 + twin


@wp.func
def grid_node_count(hf: HeightField, iso: Isovalues, n: wp.int32) -> wp.vec2i:
    """(vertices node n owns, 1 if it is a peak on its threshold)."""
    on = on_threshold(load(hf.heights, n), load(hf.levels, n), iso.thresholds)
    if hf.has_nodata == 0 and on == 0:
        return wp.vec2i(1, 0)
    f = grid_node_flags(hf, n)
    twin = on * f[1]
    peak = wp.int32(0)
    if twin != 0 and f[2] == 0:
        peak = 1
    return wp.vec2i(node_vertex_count(f[0], twin, f[2]), peak)


@wp.func
def grid_edge_count(hf: HeightField, iso: Isovalues, i: wp.int32, j: wp.int32, kind: wp.int32) -> wp.int32:
    if grid_edge_used(hf, i, j, kind) == 0:
        return 0
    a = i * hf.cols + j
    b = a + 1
    if kind == 2:
        b = a + hf.cols
    if kind == 3:
        b = a + hf.cols + 1
    if load(hf.levels, a) == load(hf.levels, b):
        return 0
    return edge_vertex_count(a, b, hf.heights, hf.levels, iso)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return wp::vec_t<3, wp::int32>(0, 0, 0);
#else
typedef int i16 __attribute__((ext_vector_type(16)));
typedef float f16 __attribute__((ext_vector_type(16)));
const int* L = levels.data;
const float* H = heights.data;
const float* T = thresholds.data;
int* out = local.data;
const bool aligned = (((unsigned long long)out) & 63) == 0;
const i16 lane = (i16){0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15};
int m = start;
int v = vertices;
int f = 0;
while (m < limit) {
    if (aligned && (m & 3) == 0 && m + 16 <= limit) {
        // sixteen nodes at once, by the closed form below: the prefix of them with no corner of their cell on the
        // threshold below its level (a flat cell needs only its own node off it: its other corners own nothing
        // here); their four slot prefixes by an in-register scan, streamed as 64-byte lines
        i16 a, r, d, g;
        f16 ha, hd;
        __builtin_memcpy(&a, L + m, sizeof(a));
        __builtin_memcpy(&r, L + m + 1, sizeof(r));
        __builtin_memcpy(&d, L + m + cols, sizeof(d));
        __builtin_memcpy(&g, L + m + cols + 1, sizeof(g));
        __builtin_memcpy(&ha, H + m, sizeof(ha));
        __builtin_memcpy(&hd, H + m + cols, sizeof(hd));
        // a height h on level x lies in [T[x - 1], T[x]) (thresholds strictly increasing), so it is on its
        // threshold exactly when it equals any threshold: those below the levels of the two rows, compared a
        // threshold at a time (one to three, mostly), or per lane where the rows span many levels
        i16 on_a = (i16)(0);
        i16 on_d = (i16)(0);
        const int lo = __builtin_reduce_min(a < d ? a : d);
        const int hi = __builtin_reduce_max(a > d ? a : d);
        if (hi - lo <= 8) {
            for (int x = lo > 0 ? lo - 1 : 0; x < hi; ++x) {
                const f16 tx = (f16)(T[x]);
                on_a |= (i16)(ha == tx);
                on_d |= (i16)(hd == tx);
            }
        } else {
            f16 ba, bd;
            for (int q = 0; q < 16; ++q) {
                const int xa = a[q];
                const int xd = d[q];
                ba[q] = xa > 0 ? T[xa - 1] : __builtin_nanf("");
                bd[q] = xd > 0 ? T[xd - 1] : __builtin_nanf("");
            }
            on_a = (i16)(ha == ba);
            on_d = (i16)(hd == bd);
        }
        const int ra = L[m + 16];
        const int rd = L[m + cols + 16];
        const int on_a16 = ra > 0 && H[m + 16] == T[ra - 1] ? -1 : 0;
        const int on_d16 = rd > 0 && H[m + cols + 16] == T[rd - 1] ? -1 : 0;
        // the right and diagonal neighbours' flags: on_a and on_d shifted by one lane
        const i16 on_r = __builtin_shufflevector(on_a, (i16)(on_a16), 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14,
                                                 15, 16);
        const i16 on_g = __builtin_shufflevector(on_d, (i16)(on_d16), 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14,
                                                 15, 16);
        const i16 flat = (r == a) & (d == a) & (g == a);
        const i16 bad = on_a | ((on_r | on_d | on_g) & ~flat);
        const int k = __builtin_reduce_min(bad != 0 ? lane : (i16)(16));
        if (k > 0) {
            const i16 dr = r - a;
            const i16 dd = d - a;
            const i16 dg = g - a;
            const i16 right = 2 * (dr < 0 ? -dr : dr);
            const i16 down = 2 * (dd < 0 ? -dd : dd);
            const i16 diagonal = 2 * (dg < 0 ? -dg : dg);
            const i16 own = 1 + right + down + diagonal;
            const i16 z = (i16)(0);
            i16 inc = own;
            inc += __builtin_shufflevector(z, inc, 0, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30);
            inc += __builtin_shufflevector(z, inc, 0, 0, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29);
            inc += __builtin_shufflevector(z, inc, 0, 0, 0, 0, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27);
            inc += __builtin_shufflevector(z, inc, 0, 0, 0, 0, 0, 0, 0, 0, 16, 17, 18, 19, 20, 21, 22, 23);
            const i16 s0 = inc - own + (i16)(v);
            const i16 s1 = s0 + 1;
            const i16 s2 = s1 + right;
            const i16 s3 = s2 + down;
            const i16 upper_hi = a > r ? (a > g ? a : g) : (r > g ? r : g);
            const i16 upper_lo = a < r ? (a < g ? a : g) : (r < g ? r : g);
            const i16 lower_hi = a > d ? (a > g ? a : g) : (d > g ? d : g);
            const i16 lower_lo = a < d ? (a < g ? a : g) : (d < g ? d : g);
            const i16 faces = 2 + 4 * (upper_hi - upper_lo) + 4 * (lower_hi - lower_lo);
            typedef int i32v __attribute__((ext_vector_type(32)));
            typedef int i64v __attribute__((ext_vector_type(64)));
            const i32v p01 = __builtin_shufflevector(s0, s1, 0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23,
                                                     8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
            const i32v p23 = __builtin_shufflevector(s2, s3, 0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23,
                                                     8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
            const i64v slots = __builtin_shufflevector(p01, p23,
                0, 1, 32, 33, 2, 3, 34, 35, 4, 5, 36, 37, 6, 7, 38, 39, 8, 9, 40, 41, 10, 11, 42, 43, 12, 13, 44, 45,
                14, 15, 46, 47, 16, 17, 48, 49, 18, 19, 50, 51, 20, 21, 52, 53, 22, 23, 54, 55, 24, 25, 56, 57,
                26, 27, 58, 59, 28, 29, 60, 61, 30, 31, 62, 63);
            if (k == 16) {
                const i16 line0 = __builtin_shufflevector(slots, slots, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13,
                                                          14, 15);
                const i16 line1 = __builtin_shufflevector(slots, slots, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26,
                                                          27, 28, 29, 30, 31);
                const i16 line2 = __builtin_shufflevector(slots, slots, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42,
                                                          43, 44, 45, 46, 47);
                const i16 line3 = __builtin_shufflevector(slots, slots, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58,
                                                          59, 60, 61, 62, 63);
                __builtin_nontemporal_store(line0, (i16*)(out + 4 * m));
                __builtin_nontemporal_store(line1, (i16*)(out + 4 * m + 16));
                __builtin_nontemporal_store(line2, (i16*)(out + 4 * m + 32));
                __builtin_nontemporal_store(line3, (i16*)(out + 4 * m + 48));
                v += inc[15];
                f += __builtin_reduce_add(faces);
                m += 16;
                continue;
            }
            // a prefix of them: its whole lines, then the last nodes' slots one by one
            int buffer[64];
            __builtin_memcpy(buffer, &slots, sizeof(buffer));
            const int groups = k >> 2;
            for (int q = 0; q < groups; ++q) {
                i16 line;
                __builtin_memcpy(&line, buffer + 16 * q, sizeof(line));
                __builtin_nontemporal_store(line, (i16*)(out + 4 * m + 16 * q));
            }
            for (int e = 16 * groups; e < 4 * k; ++e) {
                __builtin_nontemporal_store(buffer[e], out + 4 * m + e);
            }
            const i16 taken = lane < (i16)(k);
            v += __builtin_reduce_add(taken ? own : z);
            f += __builtin_reduce_add(taken ? faces : z);
            m += k;  // below limit still (k < 16, m + 16 <= limit): node m, the first not taken, goes to the code below
        }
    }
    // one node: when none of its cell's corners is on the threshold below its level, its vertices are the node,
    // two per threshold each owned edge crosses, and its cell's faces closed-form (count_grid's own counts);
    // otherwise count_grid's loop counts this node
    const int n = m;
    const int c = L[n];
    const int c01 = L[n + 1];
    const int c10 = L[n + cols];
    const int c11 = L[n + cols + 1];
    const bool on00 = c > 0 && H[n] == T[c - 1];
    const bool on01 = c01 > 0 && H[n + 1] == T[c01 - 1];
    const bool on10 = c10 > 0 && H[n + cols] == T[c10 - 1];
    const bool on11 = c11 > 0 && H[n + cols + 1] == T[c11 - 1];
    if (on00 | on01 | on10 | on11) {
        break;
    }
    const int right = 2 * (c01 > c ? c01 - c : c - c01);
    const int down = 2 * (c10 > c ? c10 - c : c - c10);
    const int diagonal = 2 * (c11 > c ? c11 - c : c - c11);
    const int upper_lo = c < c01 ? (c < c11 ? c : c11) : (c01 < c11 ? c01 : c11);
    const int upper_hi = c > c01 ? (c > c11 ? c : c11) : (c01 > c11 ? c01 : c11);
    const int lower_lo = c < c10 ? (c < c11 ? c : c11) : (c10 < c11 ? c10 : c11);
    const int lower_hi = c > c10 ? (c > c11 ? c : c11) : (c10 > c11 ? c10 : c11);
    int* o = out + 4 * n;
    __builtin_nontemporal_store(v, o);
    __builtin_nontemporal_store(v + 1, o + 1);
    __builtin_nontemporal_store(v + 1 + right, o + 2);
    __builtin_nontemporal_store(v + 1 + right + down, o + 3);
    v += 1 + right + down + diagonal;
    f += 2 + 4 * (upper_hi - upper_lo) + 4 * (lower_hi - lower_lo);
    ++m;
}
return wp::vec_t<3, wp::int32>(m - start, v - vertices, f);
#endif
""")
def count_plain_nodes(
    levels: wp.array[wp.int32], heights: wp.array[wp.float32], thresholds: wp.array[wp.float32],
    local: wp.array[wp.int32], start: wp.int32, limit: wp.int32, cols: wp.int32, vertices: wp.int32,
) -> wp.vec3i:  # pragma: no cover - native code
    """On the CPU, for :func:`count_grid` on a grid without nodata: the nodes from ``start`` (before ``limit``,
    which keeps every node's right and down neighbours in the grid) up to the first whose cell has a corner on
    the threshold below its level. Each such node owns one vertex and two per threshold each of its three edges
    crosses, and its cell's two triangles 1 + 4 (highest - lowest level) faces each (:func:`closed_form_faces`
    without a corner on a threshold). From a node whose prefixes start a 64-byte line, sixteen nodes at a time,
    flat or not: their counts by vector compares (a flat cell, all four on one level, needs only its own node off
    the threshold), their prefixes by an in-register scan, interleaved and streamed as four lines; the scalar
    loop takes the rest. A node is on its threshold when its height equals any threshold (its level's lies at or
    below it, the next above), so the two rows' heights are compared with the few thresholds below their levels,
    not with a threshold looked up per lane (that lookup alone took half of it). 2048² with 20 steps: count_grid
    23-26 -> 10-11 ms, fastest of replays on one core (until then only runs of flat nodes went sixteen at a time
    and every other node one at a time). Streams the nodes' four chunk-local prefixes (``vertices`` at
    ``start``) and returns (nodes taken, their vertices, their faces): (0, 0, 0) when ``start`` is not such a
    node, always on CUDA (count_grid's own loop counts every node there)."""
    ...


@wp.kernel
def count_grid(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    hf: HeightField,
    iso: Isovalues,
    # outputs
    local_out: wp.array[wp.int32],
    totals_out: wp.array[wp.int32],
    face_totals_out: wp.array[wp.int32],
    deferred_out: wp.array[wp.int32],
):
    """One thread per chunk of nodes: count the vertices of each node's four slots (itself and its three owned
    edges) and the faces of the cell below-right of it, which share the node's four level loads. Writes each
    slot's exclusive prefix within the chunk and the chunk's vertex and face totals (:class:`Offsets`: only the
    totals are scanned; emit_grid walks the same chunks and recounts its faces as it writes them, so no
    per-cell count is stored).

    A cell whose count needs the vertex offsets (a corner on a crossed threshold, or nodata in the grid) makes
    its chunk a 1 in ``deferred_out``: :func:`count_deferred_grid_faces` counts that chunk's faces once the
    offsets exist.
    """
    t = wp.tid() + thread_offset
    n = t * chunk
    end = wp.min(n + chunk, count)
    ij = wp.vec2i(n // hf.cols, n % hf.cols)
    deferred = wp.int32(0)
    vertices = wp.int32(0)  # the chunk's running sums
    faces_sum = wp.int32(0)
    while n < end:
        i = ij[0]
        j = ij[1]
        has_right = j + 1 < hf.cols
        has_down = i + 1 < hf.rows
        if hf.has_nodata == 0 and has_down:
            # the nodes up to one with a corner on a threshold at once, where native code does it
            run = count_plain_nodes(hf.levels, hf.heights, iso.thresholds, local_out, n,
                                    wp.min(end, n + hf.cols - 1 - j), hf.cols, vertices)  # fmt: skip
            if run[0] > 0:
                vertices += run[1]
                faces_sum += run[2]
                n += run[0]
                ij = wp.vec2i(i, j + run[0])
                continue
        if hf.has_nodata == 0:
            # every node and edge is used: plain nodes and edges within one level are counted here, without
            # the calls (Warp passes their struct arguments by value)
            level = load(hf.levels, n)
            node = wp.int32(1)
            if on_threshold(load(hf.heights, n), level, iso.thresholds) != 0:
                node = grid_node_count(hf, iso, n)[0]
            right = wp.int32(0)
            down = wp.int32(0)
            diagonal = wp.int32(0)
            l01 = level
            l10 = level
            l11 = level
            if has_right:
                l01 = load(hf.levels, n + 1)
                if l01 != level:
                    right = edge_vertex_count(n, n + 1, hf.heights, hf.levels, iso)
            if has_down:
                l10 = load(hf.levels, n + hf.cols)
                if l10 != level:
                    down = edge_vertex_count(n, n + hf.cols, hf.heights, hf.levels, iso)
                if has_right:
                    l11 = load(hf.levels, n + hf.cols + 1)
                    if l11 != level:
                        diagonal = edge_vertex_count(n, n + hf.cols + 1, hf.heights, hf.levels, iso)
            if has_right and has_down:
                faces = wp.int32(2)  # the common case: two terraces on one level
                if l01 != level or l10 != level or l11 != level:
                    # the cell's triangles (n00, n01, n11) and (n00, n11, n10); their counts ignore winding
                    upper = closed_form_faces(hf.heights, iso.thresholds, n, n + 1, n + hf.cols + 1, level, l01, l11)
                    lower = closed_form_faces(hf.heights, iso.thresholds, n, n + hf.cols + 1, n + hf.cols, level, l11,
                                              l10)  # fmt: skip
                    faces = upper + lower
                    if upper < 0 or lower < 0:
                        faces = 0
                        deferred = 1
                faces_sum += faces
        else:
            node = grid_node_count(hf, iso, n)[0]
            right = grid_edge_count(hf, iso, i, j, 1)
            down = grid_edge_count(hf, iso, i, j, 2)
            diagonal = grid_edge_count(hf, iso, i, j, 3)
            if has_right and has_down:
                deferred = 1
        # the four slots' prefixes within the chunk
        stream(local_out, 4 * n, vertices)
        stream(local_out, 4 * n + 1, vertices + node)
        stream(local_out, 4 * n + 2, vertices + node + right)
        stream(local_out, 4 * n + 3, vertices + node + right + down)
        vertices += node + right + down + diagonal
        n += 1
        ij = next_node(ij, hf.cols)
    store(totals_out, t, vertices)
    store(face_totals_out, t, faces_sum)  # replaced by count_deferred_grid_faces where deferred
    store(deferred_out, t, deferred)


@wp.func
def grid_flat_cell(hf: HeightField, n00: wp.int32) -> wp.int32:
    """The level of the cell below-right of node n00 when its four nodes are finite and on one level, else -1."""
    if hf.has_nodata != 0:
        return -1
    cols = hf.cols
    level = load(hf.levels, n00)
    if load(hf.levels, n00 + 1) != level or load(hf.levels, n00 + cols) != level:
        return -1
    if load(hf.levels, n00 + cols + 1) != level:
        return -1
    return level


@wp.func
def grid_cell_faces(
    hf: HeightField,
    iso: Isovalues,
    offsets: Any,
    i: wp.int32,
    j: wp.int32,
    write: wp.int32,
    face_base: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
) -> wp.int32:
    """Tessellate the two triangles (n00, n01, n11) and (n00, n11, n10) of cell (i, j)."""
    cols = hf.cols
    n00 = i * cols + j
    n01 = n00 + 1
    n10 = n00 + cols
    n11 = n10 + 1
    h_top = 4 * n00 + 1
    h_bottom = 4 * n10 + 1
    v_left = 4 * n00 + 2
    v_right = 4 * n01 + 2
    diag = 4 * n00 + 3
    upper = wp.int32(1)
    lower = wp.int32(1)
    if hf.has_nodata != 0:
        f00 = grid_finite(hf, i, j)
        f11 = grid_finite(hf, i + 1, j + 1)
        upper = f00 * f11 * grid_finite(hf, i, j + 1)
        lower = f00 * f11 * grid_finite(hf, i + 1, j)
    count = wp.int32(0)
    triangles = wp.int32(2)  # a runtime bound: one call site of step_triangle, not two unrolled copies
    for t in range(triangles):
        a = n00
        b = n01
        c = n11
        sa = h_top
        sb = v_right
        sc = diag
        valid = upper
        if t == 1:
            b = n11
            c = n10
            sa = diag
            sb = h_bottom
            sc = v_left
            valid = lower
        if hf.flip != 0:  # (a, c, b): edges a-c, c-b, b-a
            swap = b
            b = c
            c = swap
            swap = sa
            sa = sc
            sc = swap
        if valid != 0:
            la = load(hf.levels, a)
            if la == load(hf.levels, b) and la == load(hf.levels, c):
                # flat: the triangle itself, lifted to its level (step_triangle's first case, without the call)
                write_face(write, face_base + count, offset_at(offsets, 4 * a), offset_at(offsets, 4 * b),
                           offset_at(offsets, 4 * c),
                           la, 0, faces_out, face_levels_out, face_walls_out)  # fmt: skip
                count += 1
            else:
                count += step_triangle(
                    a, b, c, sa, sb, sc, hf.heights, hf.levels, iso, offsets, 4,
                    write, face_base + count, faces_out, face_levels_out, face_walls_out,
                )  # fmt: skip
    return count


@wp.kernel
def count_deferred_grid_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    hf: HeightField,
    iso: Isovalues,
    offsets: Offsets,
    deferred: wp.array[wp.int32],
    faces_dummy: wp.array[vec3l],
    levels_dummy: wp.array[wp.int32],
    walls_dummy: wp.array[wp.uint8],
    # outputs
    face_totals_out: wp.array[wp.int32],
):
    """The node chunks of :func:`count_grid` (same ``chunk``) again, where it deferred a cell: the chunk's face
    total, its cells counted by the walk (which needs the vertex offsets)."""
    t = wp.tid() + thread_offset
    if load(deferred, t) == 0:
        return
    n = t * chunk
    end = wp.min(n + chunk, count)
    ij = wp.vec2i(n // hf.cols, n % hf.cols)
    faces_sum = wp.int32(0)
    while n < end:
        if ij[0] + 1 < hf.rows and ij[1] + 1 < hf.cols:
            faces_sum += grid_cell_faces(hf, iso, offsets, ij[0], ij[1], 0, 0, faces_dummy, levels_dummy, walls_dummy)
        n += 1
        ij = next_node(ij, hf.cols)
    store(face_totals_out, t, faces_sum)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return 0;
#else
if (hf.has_nodata != 0 || want_sources != 0 || direct.vertices.shape[0] == 0 || direct.points != 0 ||
    direct.steps != 0 || i + 1 >= hf.rows) {
    return 0;
}
const int cols = hf.cols;
const int* lev = hf.levels.data;
const float* hts = hf.heights.data;
int stop = n + (cols - 1 - j);  // the last column has no cell
if (end < stop) {
    stop = end;
}
if (stop <= n) {
    return 0;
}
const int level = lev[n];
if (lev[n + 1] != level || lev[n + cols] != level || lev[n + cols + 1] != level) {
    return 0;
}
const float on = level > 0 ? iso.thresholds.data[level - 1] : -__builtin_inff();
if (hts[n] == on) {
    return 0;
}
// the run: flat cells of one level (neighbouring flat cells share two corners), nodes off the threshold
int m = n + 1;
while (m < stop && lev[m + 1] == level && lev[m + cols + 1] == level && hts[m] != on) {
    ++m;
}
const int k = m - n;
const int* local = offsets.local.data;
const int* bases = offsets.bases.data;
const int shift = offsets.shift;
const float dx = hf.spacing[0];
const float g = direct.gamma;
const float g1 = 1.0f - g;
const float lifted = g * iso.values.data[level];
const double ox = direct.origin[0];
const double y = (double)((float)i * hf.spacing[1]) + direct.origin[1];
const double oz = direct.origin[2];
const long long zero = (long long)(direct.vertices.ndim - 1);
long long v00 = (long long)(base + local[4 * n]);
int below = 4 * (n + cols);
long long v10 = (long long)(bases[below >> shift] + local[below]);
long long* vdst = reinterpret_cast<long long*>(&direct.vertices.data[v00][0]);
long long* fdst = reinterpret_cast<long long*>(&faces_out.data[face_base][0]);
int* ldst = face_levels_out.data + face_base;
// The same kinds of store as emit_grid's compiled generic path, whose lines these share at a run's ends: the
// vertices streamed from the size at which stream_large streams, the faces and face levels stored plainly at every
// size (store(); memory.py's stream_large says what streaming them cost). One loop per kind of vertex store: a
// run-time choice inside the loop was merged by clang into one plain store, and plain vertex stores into lines the
// generic path streams into took emit_grid at 2048^2 from 80 to 180 ms. The winding (hf.flip) is a compile-time
// choice as well, and each node's two faces go out as one 32-byte and one 16-byte store, its two face levels as one
// 8-byte store (six 8-byte and two 4-byte stores before, with a test of hf.flip a node: emit_grid at 2048^2 about
// 2 ms faster, RESULTS.md "Session 49").
typedef long long i64x4 __attribute__((ext_vector_type(4), aligned(8)));
typedef long long i64x2 __attribute__((ext_vector_type(2), aligned(8)));
const long long level2 = (long long)(((unsigned long long)(unsigned)level << 32) | (unsigned)level);
auto walk = [&](auto streamed, auto flipped) {  // on_t or off_t each
    for (int q = 0; q < k; ++q) {
        below += 4;
        const long long v11 = (long long)(bases[below >> shift] + local[below]);
        const long long v01 = v00 + 1;
        const float z = g1 * hts[n + q] + lifted;
        const double parts[3] = {(double)((float)(j + q) * dx) + ox, y, (double)z + oz};
        if constexpr (decltype(streamed)::on()) {
            long long bits[3];
            __builtin_memcpy(bits, parts, sizeof(bits));
            __builtin_nontemporal_store(bits[0] + zero, vdst);
            __builtin_nontemporal_store(bits[1] + zero, vdst + 1);
            __builtin_nontemporal_store(bits[2] + zero, vdst + 2);
        } else {
            __builtin_memcpy(vdst, parts, sizeof(parts));
        }
        if constexpr (decltype(flipped)::on()) {
            *reinterpret_cast<i64x4*>(fdst) = (i64x4){v00, v11, v01, v00};
            *reinterpret_cast<i64x2*>(fdst + 4) = (i64x2){v10, v11};
        } else {
            *reinterpret_cast<i64x4*>(fdst) = (i64x4){v00, v01, v11, v00};
            *reinterpret_cast<i64x2*>(fdst + 4) = (i64x2){v11, v10};
        }
        __builtin_memcpy(ldst, &level2, sizeof(level2));
        vdst += 3;
        fdst += 6;
        ldst += 2;
        v00 = v01;
        v10 = v11;
    }
};
struct on_t {
    static constexpr bool on() { return true; }
};
struct off_t {
    static constexpr bool on() { return false; }
};
if ((long long)direct.vertices.shape[0] * 24LL >= STREAM_MIN_BYTES) {
    if (hf.flip != 0) {
        walk(on_t{}, on_t{});
    } else {
        walk(on_t{}, off_t{});
    }
} else if (hf.flip != 0) {
    walk(off_t{}, on_t{});
} else {
    walk(off_t{}, off_t{});
}
__builtin_memset(face_walls_out.data + face_base, 0, 2 * (size_t)k);
return k;
#endif
""".replace("STREAM_MIN_BYTES", f"{STREAM_MIN_BYTES}LL"))
def emit_flat_run(
    hf: HeightField, iso: Isovalues, offsets: Offsets, direct: DirectBlend, want_sources: wp.int32,
    faces_out: wp.array[vec3l], face_levels_out: wp.array[wp.int32], face_walls_out: wp.array[wp.uint8],
    n: wp.int32, end: wp.int32, i: wp.int32, j: wp.int32, base: wp.int32, face_base: wp.int32,
) -> wp.int32:  # pragma: no cover - native code
    """On the CPU, for the default output (blended world vertices only, no sources) of a grid without nodata:
    emit_grid's nodes n, n+1, ... of row i (from column j, before ``end``) while each is a plain node (off the
    threshold, so it owns one vertex and its edges none) whose cell is flat, as emit_grid would write them
    (the vertex, then the cell's two faces), in one loop; return how many (0 on CUDA or otherwise)."""
    ...


@wp.kernel
def emit_grid(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    hf: HeightField,
    iso: Isovalues,
    offsets: Offsets,
    face_bases: wp.array[wp.int32],
    want_sources: wp.int32,
    direct: DirectBlend,
    # outputs
    points_out: wp.array[wp.vec3],
    step_heights_out: wp.array[wp.float32],
    sources_out: wp.array[wp.vec2i],
    betas_out: wp.array[wp.float32],
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
):
    """The node chunks of :func:`count_grid` (same ``chunk``) again, both emit passes in one walk: write the
    vertices of each node's four slots from their offsets, then the terrace and wall faces of the node's cell
    below-right, from the chunk's face base on, counting them as it goes (the same functions counted them).

    A flat cell's corners are the node's first vertex, the next node's (the slot after this node's last) and the
    two-level offsets of the two nodes below; a crossing cell reads its slots through ``offsets``. One walk
    instead of a vertex pass and a face pass (with a node-offset array between them) saved 14 ms of 85 at 2048²
    with 20 steps (RESULTS.md "Session 23").

    On the CPU the default output (blended vertices, no sources, no nodata) takes runs of plain nodes with flat
    cells in one native loop (:func:`emit_flat_run`): 84 % of a real DEM's cells are flat, in runs of about ten along
    a row. Fastest of 100 replays on one core of session 47's AMD EPYC: 512² (25 steps) 6.1-6.4 -> 5.6-5.9 ms,
    2048² (20 steps) 77-81 -> 66 ms."""
    t = wp.tid() + thread_offset
    n = t * chunk
    end = wp.min(n + chunk, count)
    ij = wp.vec2i(n // hf.cols, n % hf.cols)
    base = load(offsets.bases, t)
    face_base = load(face_bases, t)
    while n < end:
        run = emit_flat_run(hf, iso, offsets, direct, want_sources, faces_out, face_levels_out, face_walls_out, n, end,
                            ij[0], ij[1], base, face_base)  # fmt: skip
        if run > 0:
            n += run
            face_base += 2 * run
            ij = wp.vec2i(ij[0], ij[1] + run)
        if n >= end:  # the run took the chunk's last nodes
            break
        cols = hf.cols
        i = ij[0]
        j = ij[1]
        p = grid_point(hf, i, j, n)
        level = load(hf.levels, n)
        s0 = base + load(offsets.local, 4 * n)
        s1 = base + load(offsets.local, 4 * n + 1)
        s2 = base + load(offsets.local, 4 * n + 2)
        s3 = base + load(offsets.local, 4 * n + 3)
        s4 = load(offsets.bases, t + 1)  # the slot after this node's last: the next node's, or the next chunk's
        if n + 1 < end:
            s4 = base + load(offsets.local, 4 * n + 4)
        slots = wp.vec4i(s1, s2, s3, s4)  # (edge starts, then the end)
        first = s0
        owned = s1 - s0
        if owned == 1 and on_threshold(p[2], level, iso.thresholds) == 0:
            # a plain node, the common case: written here without the call
            put_vertex(first, p, load(iso.values, level), points_out, step_heights_out, direct)
            if want_sources != 0:
                store(sources_out, first, wp.vec2i(n, n))
                store(betas_out, first, 0.0)
        elif owned > 0:
            twin = wp.int32(0)
            peak = wp.int32(0)
            if owned == 2:
                twin = 1
            else:
                peak = grid_node_count(hf, iso, n)[1]
            emit_node_vertices(
                n, p, level, twin, peak, first, iso, want_sources, direct,
                points_out, step_heights_out, sources_out, betas_out,
            )  # fmt: skip
        for kind in range(1, 4):
            start = slots[kind - 1]
            if slots[kind] != start:
                bi = i
                bj = j + 1
                if kind == 2:
                    bi = i + 1
                    bj = j
                if kind == 3:
                    bi = i + 1
                b = bi * cols + bj
                emit_edge_vertices(
                    n, b, p, grid_point(hf, bi, bj, b), wp.vec2i(n, b), start, hf.heights, hf.levels, iso,
                    want_sources, direct, points_out, step_heights_out, sources_out, betas_out,
                )  # fmt: skip
        if i + 1 < hf.rows and j + 1 < cols:
            flat = grid_flat_cell(hf, n)
            if flat >= 0:
                # the common case, without the call: (n00, n01, n11) and (n00, n11, n10), lifted to their level
                v00 = wp.int64(s0)
                v01 = wp.int64(s4)
                v10 = wp.int64(offset_at(offsets, 4 * (n + cols)))
                v11 = wp.int64(offset_at(offsets, 4 * (n + cols + 1)))
                if hf.flip != 0:
                    store(faces_out, face_base, vec3l(v00, v11, v01))
                    store(faces_out, face_base + 1, vec3l(v00, v10, v11))
                else:
                    store(faces_out, face_base, vec3l(v00, v01, v11))
                    store(faces_out, face_base + 1, vec3l(v00, v11, v10))
                store(face_levels_out, face_base, flat)
                store(face_levels_out, face_base + 1, flat)
                store(face_walls_out, face_base, wp.uint8(0))
                store(face_walls_out, face_base + 1, wp.uint8(0))
                face_base += 2
            else:
                face_base += grid_cell_faces(hf, iso, offsets, i, j, 1, face_base, faces_out, face_levels_out,
                                             face_walls_out)  # fmt: skip
        n += 1
        ij = next_node(ij, cols)


# ---------------------------------------------------------------------------------------------------------
# triangulated irregular networks: a cached edge table
# ---------------------------------------------------------------------------------------------------------


@wp.kernel
def mark_tin_twins(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    tin: TriangleNetwork,
    iso: Isovalues,
    # outputs
    twins_out: wp.array[wp.int32],
    peers_out: wp.array[wp.int32],
):
    """One thread per edge: flag its upper end for a twin when it sits on the threshold the edge crosses,
    and flag each end whose neighbour is not lower (a node without one is a peak)."""
    e = (wp.tid() + thread_offset) * chunk
    end = wp.min(e + chunk, count)
    while e < end:
        ab = load(tin.edges, e)
        la = load(tin.levels, ab[0])
        lb = load(tin.levels, ab[1])
        if lb >= la:
            store(peers_out, ab[0], 1)
        if la >= lb:
            store(peers_out, ab[1], 1)
        if la != lb:
            hi = ab[1]
            lhi = lb
            if la > lb:
                hi = ab[0]
                lhi = la
            if on_threshold(load(tin.heights, hi), lhi, iso.thresholds) != 0:
                store(twins_out, hi, 1)
        e += 1


@wp.kernel
def count_tin_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    tin: TriangleNetwork,
    iso: Isovalues,
    twins: wp.array[wp.int32],
    peers: wp.array[wp.int32],
    # outputs
    counts_out: wp.array[wp.int32],
):
    """One thread per point, then per edge: count the output vertices it owns."""
    tid = (wp.tid() + thread_offset) * chunk
    end = wp.min(tid + chunk, count)
    while tid < end:
        n_points = tin.points.shape[0]
        if tid < n_points:
            store(counts_out, tid, node_vertex_count(load(tin.point_used, tid), load(twins, tid), load(peers, tid)))
        else:
            ab = load(tin.edges, tid - n_points)
            store(counts_out, tid, edge_vertex_count(ab[0], ab[1], tin.heights, tin.levels, iso))
        tid += 1


@wp.kernel
def emit_tin_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    tin: TriangleNetwork,
    iso: Isovalues,
    offsets: wp.array[wp.int32],
    twins: wp.array[wp.int32],
    want_sources: wp.int32,
    direct: DirectBlend,
    # outputs
    points_out: wp.array[wp.vec3],
    step_heights_out: wp.array[wp.float32],
    sources_out: wp.array[wp.vec2i],
    betas_out: wp.array[wp.float32],
):
    """One thread per point, then per edge: write its output vertices from its offset."""
    tid = (wp.tid() + thread_offset) * chunk
    end = wp.min(tid + chunk, count)
    while tid < end:
        n_points = tin.points.shape[0]
        first = load(offsets, tid)
        if load(offsets, tid + 1) == first:
            pass  # owns no vertex
        elif tid < n_points:
            twin = wp.int32(0)
            peak = wp.int32(0)
            if load(offsets, tid + 1) - first == 2:
                twin = 1
            elif load(twins, tid) != 0:
                peak = 1
            emit_node_vertices(
                tid,
                load(tin.points, tid),
                load(tin.levels, tid),
                twin,
                peak,
                first,
                iso,
                want_sources,
                direct,
                points_out,
                step_heights_out,
                sources_out,
                betas_out,
            )
        else:
            ab = load(tin.edges, tid - n_points)
            emit_edge_vertices(
                ab[0],
                ab[1],
                load(tin.points, ab[0]),
                load(tin.points, ab[1]),
                ab,
                first,
                tin.heights,
                tin.levels,
                iso,
                want_sources,
                direct,
                points_out,
                step_heights_out,
                sources_out,
                betas_out,
            )
        tid += 1


@wp.func
def tin_face_faces(
    tin: TriangleNetwork,
    iso: Isovalues,
    offsets: wp.array[wp.int32],
    f: wp.int32,
    write: wp.int32,
    face_base: wp.int32,
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
) -> wp.int32:
    n_points = tin.points.shape[0]
    c = load(tin.faces, f)
    e = load(tin.face_edges, f)
    return step_triangle(
        c[0],
        c[1],
        c[2],
        n_points + e[0],
        n_points + e[1],
        n_points + e[2],
        tin.heights,
        tin.levels,
        iso,
        offsets,
        1,
        write,
        face_base,
        faces_out,
        face_levels_out,
        face_walls_out,
    )


@wp.kernel
def count_tin_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    tin: TriangleNetwork,
    iso: Isovalues,
    offsets: wp.array[wp.int32],
    faces_dummy: wp.array[vec3l],
    levels_dummy: wp.array[wp.int32],
    walls_dummy: wp.array[wp.uint8],
    # outputs
    counts_out: wp.array[wp.int32],
):
    """One thread per triangle: count the terrace and wall faces it emits."""
    f = (wp.tid() + thread_offset) * chunk
    end = wp.min(f + chunk, count)
    while f < end:
        store(counts_out, f, tin_face_faces(tin, iso, offsets, f, 0, 0, faces_dummy, levels_dummy, walls_dummy))
        f += 1


@wp.kernel
def emit_tin_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    tin: TriangleNetwork,
    iso: Isovalues,
    offsets: wp.array[wp.int32],
    face_offsets: wp.array[wp.int32],
    # outputs
    faces_out: wp.array[vec3l],
    face_levels_out: wp.array[wp.int32],
    face_walls_out: wp.array[wp.uint8],
):
    """One thread per triangle: write its terrace and wall faces from its face offset."""
    f = (wp.tid() + thread_offset) * chunk
    end = wp.min(f + chunk, count)
    while f < end:
        if load(face_offsets, f + 1) != load(face_offsets, f):
            tin_face_faces(tin, iso, offsets, f, 1, load(face_offsets, f), faces_out, face_levels_out, face_walls_out)
        f += 1


# ---------------------------------------------------------------------------------------------------------
# the γ blend (§3.3)
# ---------------------------------------------------------------------------------------------------------


@wp.kernel
def blend_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    points: wp.array[wp.vec3],
    step_heights: wp.array[wp.float32],
    gammas: wp.array[wp.float32],
    gamma: wp.float32,
    origin: wp.vec3d,
    # outputs
    vertices_out: wp.array[wp.vec3d],
):
    """One thread per output vertex: z = (1 - γ) z_original + γ z_step, shifted back to world coordinates.

    ``gammas`` holds one γ per vertex, or is empty and the scalar ``gamma`` applies.
    """
    v = (wp.tid() + thread_offset) * chunk
    end = wp.min(v + chunk, count)
    while v < end:
        g = gamma
        if gammas.shape[0] > 0:
            g = load(gammas, v)
        stream(vertices_out, v, blended(load(points, v), load(step_heights, v), g, origin))
        v += 1


@wp.kernel
def interpolate_node_values(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    node_values: wp.array[wp.float32],
    sources: wp.array[wp.vec2i],
    betas: wp.array[wp.float32],
    # outputs
    values_out: wp.array[wp.float32],
):
    """One thread per output vertex: its value lerped from its source nodes with the crossing's β."""
    v = (wp.tid() + thread_offset) * chunk
    end = wp.min(v + chunk, count)
    while v < end:
        s = load(sources, v)
        b = load(betas, v)
        store(values_out, v, (1.0 - b) * load(node_values, s[0]) + b * load(node_values, s[1]))
        v += 1


@wp.kernel
def sample_lens(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    mask: wp.array2d[wp.float32],
    lower: wp.vec2,
    size: wp.vec2,
    points: wp.array[wp.vec3],
    # outputs
    values_out: wp.array[wp.float32],
):
    """One thread per output vertex: bilinear lookup of the lens mask (row 0 at lower y), clamped at the edges."""
    v = (wp.tid() + thread_offset) * chunk
    end = wp.min(v + chunk, count)
    while v < end:
        p = load(points, v)
        rows = mask.shape[0]
        cols = mask.shape[1]
        u = wp.clamp((p[0] - lower[0]) / size[0], 0.0, 1.0) * wp.float32(cols - 1)
        w = wp.clamp((p[1] - lower[1]) / size[1], 0.0, 1.0) * wp.float32(rows - 1)
        j0 = wp.min(wp.int32(u), cols - 1)
        i0 = wp.min(wp.int32(w), rows - 1)
        j1 = wp.min(j0 + 1, cols - 1)
        i1 = wp.min(i0 + 1, rows - 1)
        fu = u - wp.float32(j0)
        fw = w - wp.float32(i0)
        top = (1.0 - fu) * mask[i0, j0] + fu * mask[i0, j1]
        bottom = (1.0 - fu) * mask[i1, j0] + fu * mask[i1, j1]
        store(values_out, v, (1.0 - fw) * top + fw * bottom)
        v += 1
