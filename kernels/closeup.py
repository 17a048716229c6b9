"""Warp kernels of the 3D close-ups (paper 001, Trapp & Döllner 2019, §II.B, §II.D, §IV.A).

Geometry amplification and close-up transformation (§IV.A, Fig. 6, stage 1): every close-up k gets its own
copy of the geometry inside its ROI window, all close-ups in one launch, each element tagged with its layer
id k. Per vertex the mask factor m is read from the ROI mask by projective texture lookup (bilinear, the
mask spanning the ROI box), then C = m·M + (1 − m)·I and V_C = C·V_O (§II.B).

Culling (the paper's stated limitation, §IV.C: "the complete terrain geometry is rendered for each
close-up"): only faces with a vertex of m > 0 are emitted, by count -> scan -> emit; vertices that no
emitted face uses are dropped by a second count -> scan -> emit (the shared kernels of kernels/compaction.py),
and the faces are renumbered.

Anchors (§II.D): a fence strip per outline segment, from the ROI outline on the overview (V_O) to the
close-up's outline (M·V_O), its vertices carrying the normalized distance t = ‖V − V_O‖ / D_k and the
opacity of the 1D transfer function at t.

Conventions: every kernel takes ``thread_offset`` first (``stepterrain._device.launch``); float32 local
coordinates; close-up k's 4 x 4 matrix acts on column vectors (x, y, z, 1).
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})  # see kernels/__init__


@wp.struct
class CloseUpLayers:
    """Per close-up k: its matrix M, ROI box and mask (all masks packed row-major, row 0 at the lower y)."""

    matrices: wp.array[wp.mat44]
    boxes: wp.array[wp.vec4]  # (x0, y0, x1, y1) of the ROI box in local coordinates, x1 > x0, y1 > y0
    margins: wp.array[wp.vec4]  # how far outside each side (x0, y0, x1, y1) a point still lies on it (rounding)
    mask_info: wp.array[wp.vec3i]  # (offset into masks, rows, cols), rows and cols >= 2
    masks: wp.array[wp.float32]


@wp.struct
class TransferFunctions:
    """Per close-up k: a 1D opacity table sampled linearly over t in [0, 1] (``info[k]`` = offset, count)."""

    values: wp.array[wp.float32]
    info: wp.array[wp.vec2i]


@wp.func
def mask_factor(p: wp.vec3, k: wp.int32, layers: CloseUpLayers) -> wp.float32:
    """Bilinear lookup of close-up k's mask at p's xy; 0 outside the ROI box (and where u or v is not finite: a box
    that collapses to one float32 value gives 0 / 0 on its edge and ±inf beside it, which the comparisons must not
    let through to the int32 texel index, as ``ROI.factor`` takes it). A point within ``layers.margins[k]`` outside
    a side of the box lies on its rim, as in ``ROI.factor``: the world box's float64 rounding (which float32 keeps next
    to the local origin) and the float32 rounding of that side and of the points next to it (the far rim's node and
    box side round apart); each side its own, as a far side's rounding says nothing of a near one's."""
    box = layers.boxes[k]
    margin = layers.margins[k]
    if not (p[0] >= box[0] - margin[0] and p[0] <= box[2] + margin[2] and p[1] >= box[1] - margin[1]
            and p[1] <= box[3] + margin[3]):
        return 0.0
    u = (p[0] - box[0]) / (box[2] - box[0])
    v = (p[1] - box[1]) / (box[3] - box[1])
    if not (wp.isfinite(u) and wp.isfinite(v)):  # 0 / 0 on a collapsed box's edge, ±inf beside it (as ROI.factor)
        return 0.0
    u = wp.clamp(u, 0.0, 1.0)
    v = wp.clamp(v, 0.0, 1.0)
    info = layers.mask_info[k]
    rows = info[1]
    cols = info[2]
    fx = u * wp.float32(cols - 1)
    fy = v * wp.float32(rows - 1)
    j0 = wp.min(wp.int32(wp.floor(fx)), cols - 2)
    i0 = wp.min(wp.int32(wp.floor(fy)), rows - 2)
    tx = fx - wp.float32(j0)
    ty = fy - wp.float32(i0)
    base = info[0] + i0 * cols + j0
    m00 = layers.masks[base]
    m01 = layers.masks[base + 1]
    m10 = layers.masks[base + cols]
    m11 = layers.masks[base + cols + 1]
    bottom = m00 + tx * (m01 - m00)
    top = m10 + tx * (m11 - m10)
    return bottom + ty * (top - bottom)


@wp.func
def blend_transform(m: wp.float32, M: wp.mat44) -> wp.mat44:
    """C = m·M + (1 − m)·I: exactly M when m = 1, exactly I when m = 0."""
    return m * M + (1.0 - m) * wp.identity(n=4, dtype=wp.float32)


@wp.func
def apply(C: wp.mat44, p: wp.vec3) -> wp.vec3:
    """The affine transform C of point p (w = 1)."""
    q = C * wp.vec4(p[0], p[1], p[2], 1.0)
    return wp.vec3(q[0], q[1], q[2])


@wp.func
def transfer(t: wp.float32, k: wp.int32, tf: TransferFunctions) -> wp.float32:
    """Close-up k's transfer function at t (clamped to [0, 1]), linear between its table entries."""
    info = tf.info[k]
    n = info[1]
    if n == 1:
        return tf.values[info[0]]
    x = wp.clamp(t, 0.0, 1.0) * wp.float32(n - 1)
    i = wp.min(wp.int32(wp.floor(x)), n - 2)
    f = x - wp.float32(i)
    a = tf.values[info[0] + i]
    b = tf.values[info[0] + i + 1]
    return a + f * (b - a)


# ---------------------------------------------------------------------------------------------------------
# amplification, transformation and culling
# ---------------------------------------------------------------------------------------------------------


@wp.kernel
def transform_closeup_vertices(
    thread_offset: wp.int32,
    points: wp.array[wp.vec3],
    point_layer: wp.array[wp.int32],
    layers: CloseUpLayers,
    # outputs
    vertices_out: wp.array[wp.vec3],
    factors_out: wp.array[wp.float32],
):
    """One thread per (layer, vertex): the mask factor m and V_C = (m·M + (1 − m)·I)·V_O."""
    i = wp.tid() + thread_offset
    k = point_layer[i]
    p = points[i]
    m = mask_factor(p, k, layers)
    factors_out[i] = m
    vertices_out[i] = apply(blend_transform(m, layers.matrices[k]), p)


@wp.kernel
def transform_kept_vertices(
    thread_offset: wp.int32,
    points: wp.array[wp.vec3],
    point_layer: wp.array[wp.int32],
    factors: wp.array[wp.float32],
    matrices: wp.array[wp.mat44],
    # outputs
    vertices_out: wp.array[wp.vec3],
):
    """One thread per kept vertex whose m is known (it depends on the ROI only): V_C = (m·M + (1 − m)·I)·V_O,
    the same operations as :func:`transform_closeup_vertices` after its mask lookup."""
    i = wp.tid() + thread_offset
    vertices_out[i] = apply(blend_transform(factors[i], matrices[point_layer[i]]), points[i])


@wp.func
def face_in_roi(face: wp.vec3i, factors: wp.array[wp.float32]) -> wp.int32:
    """1 when a corner of the face has m > 0 (the face belongs to the close-up), else 0."""
    if factors[face[0]] > 0.0 or factors[face[1]] > 0.0 or factors[face[2]] > 0.0:
        return 1
    return 0


@wp.kernel
def count_closeup_faces(
    thread_offset: wp.int32,
    faces: wp.array[wp.vec3i],
    factors: wp.array[wp.float32],
    # outputs
    counts_out: wp.array[wp.int32],
):
    """One thread per (layer, face): 1 when the face has a corner with m > 0."""
    i = wp.tid() + thread_offset
    counts_out[i] = face_in_roi(faces[i], factors)


@wp.kernel
def emit_closeup_faces(
    thread_offset: wp.int32,
    faces: wp.array[wp.vec3i],
    factors: wp.array[wp.float32],
    offsets: wp.array[wp.int32],
    # outputs
    faces_out: wp.array[wp.vec3i],
    face_source_out: wp.array[wp.int32],
):
    """One thread per (layer, face): copy a counted face to its slot, with its input index."""
    i = wp.tid() + thread_offset
    if face_in_roi(faces[i], factors) == 1:
        slot = offsets[i]
        faces_out[slot] = faces[i]
        face_source_out[slot] = i


@wp.kernel
def emit_used_vertices(
    thread_offset: wp.int32,
    used: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    vertices: wp.array[wp.vec3],
    factors: wp.array[wp.float32],
    # outputs
    vertices_out: wp.array[wp.vec3],
    factors_out: wp.array[wp.float32],
    vertex_source_out: wp.array[wp.int32],
):
    """One thread per (layer, vertex): copy a used vertex, its m and its input index to its slot."""
    i = wp.tid() + thread_offset
    if used[i] == 1:
        slot = offsets[i]
        vertices_out[slot] = vertices[i]
        factors_out[slot] = factors[i]
        vertex_source_out[slot] = i


# ---------------------------------------------------------------------------------------------------------
# anchors
# ---------------------------------------------------------------------------------------------------------


@wp.kernel
def anchor_lengths(
    thread_offset: wp.int32,
    outline: wp.array[wp.vec3],
    outline_layer: wp.array[wp.int32],
    layers: CloseUpLayers,
    # outputs
    lengths_out: wp.array[wp.float32],
):
    """One thread per outline point: ‖M·V_O − V_O‖, the length of its anchor rung."""
    i = wp.tid() + thread_offset
    p = outline[i]
    lengths_out[i] = wp.length(apply(layers.matrices[outline_layer[i]], p) - p)


@wp.kernel
def emit_anchor_vertices(
    thread_offset: wp.int32,
    outline: wp.array[wp.vec3],
    outline_layer: wp.array[wp.int32],
    layers: CloseUpLayers,
    max_lengths: wp.array[wp.float32],
    tf: TransferFunctions,
    layer_rungs: wp.array[wp.int32],
    vertex_start: wp.array[wp.int32],
    # outputs
    vertices_out: wp.array[wp.vec3],
    distances_out: wp.array[wp.float32],
    opacities_out: wp.array[wp.float32],
):
    """One thread per outline point i: the rungs + 1 strip vertices of its close-up's ``layer_rungs`` from V_O to
    M·V_O, with t and opacity, at ``vertex_start[i]`` on (each close-up its own rung count, in one launch)."""
    i = wp.tid() + thread_offset
    k = outline_layer[i]
    rungs = layer_rungs[k]
    p = outline[i]
    q = apply(layers.matrices[k], p)
    d = max_lengths[k]
    start = vertex_start[i]
    for r in range(rungs + 1):
        s = wp.float32(r) / wp.float32(rungs)
        v = p + s * (q - p)
        t = wp.float32(0.0)
        if d > 0.0:
            t = wp.min(wp.length(v - p) / d, 1.0)
        slot = start + r
        vertices_out[slot] = v
        distances_out[slot] = t
        opacities_out[slot] = transfer(t, k, tf)


@wp.kernel
def emit_anchor_faces(
    thread_offset: wp.int32,
    segments: wp.array[wp.vec2i],
    outline_layer: wp.array[wp.int32],
    layer_rungs: wp.array[wp.int32],
    vertex_start: wp.array[wp.int32],
    face_start: wp.array[wp.int32],
    # outputs
    faces_out: wp.array[wp.vec3i],
):
    """One thread per outline segment (a, b) of one close-up: the 2·rungs triangles of its fence panel (its close-up's
    ``layer_rungs``), at ``face_start[i]`` on, between the rungs at ``vertex_start`` of a and b."""
    i = wp.tid() + thread_offset
    seg = segments[i]
    rungs = layer_rungs[outline_layer[seg[0]]]
    a = vertex_start[seg[0]]
    b = vertex_start[seg[1]]
    f = face_start[i]
    for r in range(rungs):
        faces_out[f + 2 * r] = wp.vec3i(a + r, b + r, b + r + 1)
        faces_out[f + 2 * r + 1] = wp.vec3i(a + r, b + r + 1, a + r + 1)
