"""Warp kernels of the cube-sphere grid and its longest-edge bisection hierarchy (paper 003, Adelsberger, §4-§7).

Conventions (shared with ``stepterrain.globe`` and ``tests/reference_globe.py``):

* Six faces of n = N + 1 nodes per edge, N = 2^k. Node (face, i, j) is *entry* face·n² + i·n + j; row i runs
  along the face's local y axis, column j along its local x axis. Face-local integer coordinates are
  X = 2j - N, Y = 2i - N, so the cube is [-N, N]³ and a node's cube point is X·x_f + Y·y_f + N·n_f with the
  face frame (x_f, y_f, n_f) of :data:`FACE_FRAMES` (paper 003 §4, table and Abb. 1; face f is the paper's
  side f + 1). Every frame is a rotation, so counter-clockwise in (X, Y) is counter-clockwise from outside.
* Projection v = (R + z) · w / ||w|| (§4, R = √3·m with m = half the cube side): w is the integer cube point,
  so a node shared by two or three faces has the same w on each, and its float64 direction and float32
  position are bit-identical on every copy.
* Longest-edge bisection (§5.1, Abb. 3): each face starts as the two right triangles split by its main
  diagonal (0, 0)-(N, N). A triangle is (face, a, b, c) with hypotenuse a-b and apex c, each corner packed as
  i << 16 | j (no integer division on the hot path); its refinement node is m = (a + b) / 2 and its children
  are (c, a, m) and (b, c, m), which keeps the winding. A triangle
  at depth d has its refinement node at depth d; depth 2k triangles are the grid's cells' halves.
* Node depth: with s the largest power of two dividing both i and j, a node with both i/s and j/s odd is a
  *diagonal* node (the centre of a 2s square, depth 2(k-1-log2 s)); otherwise an *axis* node (the midpoint of
  an axis-parallel edge of length 2s, depth one more). The four children of a diagonal node are (i ± s, j),
  (i, j ± s); of an axis node (i ± s/2, j ± s/2) (none when s = 1). Children across a face border are
  folded onto the neighbouring face, so the hierarchy runs across seams (§5.1: "Ränder gibt es nicht").
* Every kernel takes ``thread_offset, count, chunk`` first: thread t handles elements
  [(t + thread_offset)·chunk, ... + chunk) ∩ [0, count) (``stepterrain._device.launch`` splits the threads over
  CPU cores). chunk is 1 on CUDA; on the CPU it is large, because Warp copies a kernel's arguments (here
  structs of arrays, about 1 kB) once per thread.
* The planar case (``planar = 1``): one face, positions (j·dx, i·dy, z), no folding; children and apexes
  outside the grid do not exist.
* The refinement and mesh-output kernels (and the functions they call) index their 1-D arrays with
  ``load(a, i)`` / ``store(a, i, v)`` of ``kernels/memory.py``, not Warp's ``a[i]``, which wraps a negative i
  (a sign test and an add per access on the CPU): every array there is 1-D and contiguous and every index
  lies in [0, len). The far view of ``benchmarks/run_globe.py`` (~200k triangles, one core) spent 31 ms in
  these kernels with ``a[i]`` and 27 ms with load/store (best of 30 meshes, median of 4 rounds; the same
  output).
"""

from __future__ import annotations

from typing import Any, Final

import warp as wp

from . import bounds
from .memory import load, store, vec3l

wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False})  # see kernels/__init__

#: Face frames (paper 003 §4 table): per face the images of the local x axis, local y axis and the outward
#: normal as signed axis codes (+1 = +X, -2 = -Y, 3 = +Z, ...). Side 1 (x, y, z); side 2 (z, -y, x);
#: side 3 (-y, z, -x); side 4 (-x, -z, -y); side 5 (-z, -x, y); side 6 (y, x, -z).
FACE_FRAMES: Final = ((1, 2, 3), (3, -2, 1), (-3, -1, 2), (-1, -3, -2), (-2, 3, -1), (2, 1, -3))


#: Saturation margin added per level to r, h and α (paper 003 §6: "eine kleine Korrektur ... 10^-6").
RELATIVE_MARGIN = wp.constant(wp.float64(2.0**-20))
ABSOLUTE_MARGIN = wp.constant(wp.float64(2.0**-22))
#: e of a planar triangle that straddles a padded input's border (:func:`straddles_input`); saturated, so every
#: node whose e reaches it refines whatever the view or user metrics say (else the mesh would keep the padding).
#: Nodes store e in float32: the refinement test compares with half of it, clear of that rounding.
STRADDLE_ERROR = wp.constant(wp.float64(3.0e38))
#: e of a planar triangle wholly in a padded input's padding (below its last row or right of its last column, or
#: off the grid): negative, so saturation's max passes it over wherever a real error meets it. A node whose e
#: stays negative (its diamond and all its descendants' in the padding) never refines, whatever the view, the
#: user metrics or an error of 0 say: its triangles would be dropped from the mesh anyway, and no error was
#: measured over them (the padding's heights are no input).
PADDING_ERROR = wp.constant(wp.float64(-1.0))
#: How far (in units of a node's spacing s) below the input's last row or right of its last column a planar
#: node's diamond and all its descendants' reach at most: 3s (a diagonal node's children, axis nodes at s, reach
#: 2s, their children s/2 further, and so on), one s spare. A node that far out is all padding (see
#: :func:`padding_tier`); its children lie within s of it with half its spacing or more, so within
#: :data:`PADDING_WRITTEN` of theirs.
PADDING_REACH = wp.constant(4)
PADDING_WRITTEN = wp.constant(10)
#: :func:`edge_slope` of an edge whose bound does not move by a whole number of columns per row.
NO_SLOPE = wp.constant(1 << 30)


#: How many elements ahead the CPU's scattered loops prefetch (see :func:`prefetch`).
PREFETCH_AHEAD = wp.constant(16)


# A refinement level, or the vertices and faces of a mesh, visit nodes scattered over ~100 MB of node arrays:
# each load misses the caches, and a loop whose body is longer than the core's reorder window keeps one or two
# misses in flight. Prefetching the node PREFETCH_AHEAD elements ahead keeps more in flight: a random gather of
# 400k vec4 from 6 x 1025² of them took 40 ms, 15 ms with a prefetch 8 or 16 ahead, and the far view of
# benchmarks/run_globe.py spends 40-50 ms in its kernels instead of 65-75 (16 ahead; 8 and 32 do less well).
# A prefetch never faults and changes no result (an address past the array is harmless); CUDA, whose threads
# each take one element, compiles it to nothing.
@wp.func_native("""
#if !defined(__CUDA_ARCH__)
if (write) __builtin_prefetch(a.data + i, 1, 3); else __builtin_prefetch(a.data + i, 0, 3);
#endif
""")
def prefetch(a: wp.array[Any], i: wp.int32, write: wp.int32):  # pragma: no cover - native code
    """Hint the CPU to load element ``i`` of the 1-D array ``a`` into its caches, to be read (``write`` = 0) or
    written (1); a no-op on CUDA. ``write`` is a literal at every call, so the branch folds away."""
    ...


@wp.struct
class CubeSphereGrid:
    """The nodes: N cells per face edge, heights (exaggerated, metres) and float32 positions per entry."""

    cells: wp.int32  # N = 2^k
    n: wp.int32  # N + 1 nodes per face edge
    planar: wp.int32  # 1: one flat face (paper 003 in the plane, SOAR/RTIN), 0: the six cube faces
    radius: wp.float64  # R, metres
    spacing: wp.vec2d  # planar only: (dx, dy)
    rows_valid: wp.int32  # planar only: rows of the input before padding to n (n when not padded)
    cols_valid: wp.int32  # planar only: columns of the input before padding to n
    heights: wp.array[wp.float32]  # per entry: exaggerated elevation z
    positions: wp.array[wp.vec3]  # per entry: planet-centred (planar: local) position, float32
    # the cube: 1 / ||w|| per quarter-face slot (|2j - N| / 2)·(N/2 + 1) + |2i - N| / 2 (angle_tables'; planar: empty)
    inverse_lengths: wp.array[wp.float64]


@wp.struct
class NodeParameters:
    """Per entry, computed bottom-up (§6, §7.1): (e, r, h, α) packed in one vec4, so a node's parameters are
    one 16-byte load (one cache line) on the refinement's scattered accesses; identical on the copies of a
    seam node."""

    values: wp.array[wp.vec4]  # (geometric error e, bounding-sphere radius r, cone height h, cone angle α)


@wp.struct
class LatLonGrid:
    """A global elevation grid, rows north to south, columns west to east, regular in degrees (as radians)."""

    elevation: wp.array2d[wp.float32]
    lat0: wp.float64  # latitude of row 0's centre (the northernmost row)
    dlat: wp.float64  # > 0: radians per row, southwards
    lon0: wp.float64  # longitude of column 0's centre
    dlon: wp.float64  # > 0: radians per column, eastwards
    inv_dlat: wp.float64  # 1 / dlat
    inv_dlon: wp.float64  # 1 / dlon
    inv_cols: wp.float64  # 1 / number of columns
    north_pole: wp.float32  # mean of row 0: the value at 90° N
    south_pole: wp.float32  # mean of the last row: the value at 90° S


# ---------------------------------------------------------------------------------------------------------
# grid geometry
# ---------------------------------------------------------------------------------------------------------


@wp.func
def frame_rotate(face: wp.int32, q: wp.vec3i) -> wp.vec3i:
    """Face-local (x, y, z) -> 3D: the rows of the paper's table (§4; :data:`FACE_FRAMES`).

    Three scalars chosen per face and one vector built at the end: a vector returned from each branch compiled
    (CPU) to a jump table storing its parts to the stack and one wider load of them, a store-forwarding stall
    on every call (in the far view's profile 17 % of emit_vertices' samples and 6 % of count_refinement's, via
    owns_refinement_node; the far view's emit_vertices 3.1 -> 2.0 ms, count_refinement 16.3 -> 15.3 ms)."""
    x = q[1]  # face 5
    y = q[0]
    z = -q[2]
    if face == 0:
        x = q[0]
        y = q[1]
        z = q[2]
    elif face == 1:
        x = q[2]
        y = -q[1]
        z = q[0]
    elif face == 2:
        x = -q[1]
        y = q[2]
        z = -q[0]
    elif face == 3:
        x = -q[0]
        y = -q[2]
        z = -q[1]
    elif face == 4:
        x = -q[2]
        y = -q[0]
        z = q[1]
    return wp.vec3i(x, y, z)


@wp.func
def frame_unrotate(face: wp.int32, p: wp.vec3i) -> wp.vec3i:
    """3D -> face-local (x, y, z): the inverse (transpose) of :func:`frame_rotate` (scalars chosen per face,
    as there)."""
    x = p[1]  # face 5
    y = p[0]
    z = -p[2]
    if face == 0:
        x = p[0]
        y = p[1]
        z = p[2]
    elif face == 1:
        x = p[2]
        y = -p[1]
        z = p[0]
    elif face == 2:
        x = -p[2]
        y = -p[0]
        z = p[1]
    elif face == 3:
        x = -p[0]
        y = -p[2]
        z = -p[1]
    elif face == 4:
        x = -p[1]
        y = p[2]
        z = -p[0]
    return wp.vec3i(x, y, z)


@wp.func
def local_point(i: wp.int32, j: wp.int32, cells: wp.int32) -> wp.vec3i:
    """Face-local cube point (2j - N, 2i - N, N) of node (i, j); a node up to one face width outside the face
    is folded over the edge onto the neighbouring face's plane."""
    x = 2 * j - cells
    y = 2 * i - cells
    z = cells
    if x > cells:
        z = 2 * cells - x
        x = cells
    elif x < -cells:
        z = 2 * cells + x
        x = -cells
    if y > cells:
        z = 2 * cells - y
        y = cells
    elif y < -cells:
        z = 2 * cells + y
        y = -cells
    return wp.vec3i(x, y, z)


@wp.func
def cube_point(face: wp.int32, i: wp.int32, j: wp.int32, cells: wp.int32) -> wp.vec3i:
    """Integer 3D cube point of face node (i, j) (folded over the edge when just outside the face)."""
    return frame_rotate(face, local_point(i, j, cells))


@wp.func
def point_entry(point: wp.vec3i, cells: wp.int32, n: wp.int32) -> wp.int32:
    """The canonical entry of a cube point: on the lowest-numbered face that holds it."""
    for f in range(6):
        q = frame_unrotate(f, point)
        if q[2] == cells:
            return f * n * n + ((q[1] + cells) // 2) * n + (q[0] + cells) // 2
    return -1


@wp.func
def node_entry(cells: wp.int32, planar: wp.int32, face: wp.int32, i: wp.int32, j: wp.int32) -> wp.int32:
    """Entry of face node (i, j), canonical on seams (folded over the edge when just outside the face).

    Plain values rather than the grid struct: Warp passes structs to functions by value."""
    n = cells + 1
    if planar != 0 or (i > 0 and i < cells and j > 0 and j < cells):
        return face * n * n + i * n + j
    return point_entry(cube_point(face, i, j, cells), cells, n)


@wp.func
def node_direction(point: wp.vec3i) -> wp.vec3d:
    """w / ||w|| in float64 from the integer cube point (exact sum of squares: bit-identical on seams)."""
    w = wp.vec3d(wp.float64(point[0]), wp.float64(point[1]), wp.float64(point[2]))
    return w * (wp.float64(1.0) / wp.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]))


@wp.func
def entry_position64(grid: CubeSphereGrid, entry: wp.int32) -> wp.vec3d:
    """float64 position of an entry: (R + z) · w / ||w|| (paper 003 §4), or (j·dx, i·dy, z) in the plane.

    ``entry`` >= 0, so truncating ``/`` and a multiply-subtract give face, i and j: Warp's ``//`` and ``%`` add
    sign corrections, and ``%`` a second division (the far view's emit_vertices 2.0 -> 1.85 ms)."""
    nn = grid.n * grid.n
    face = entry / nn
    rest = entry - face * nn
    i = rest / grid.n
    j = rest - i * grid.n
    z = wp.float64(load(grid.heights, entry))
    if grid.planar != 0:
        return wp.vec3d(wp.float64(j) * grid.spacing[0], wp.float64(i) * grid.spacing[1], z)
    return (grid.radius + z) * node_direction(cube_point(face, i, j, grid.cells))


@wp.func
def face_position64(grid: CubeSphereGrid, i: wp.int32, j: wp.int32, z: wp.float32) -> wp.vec3d:
    """float64 position (R + z) · w / ||w|| of face node (i, j) in its face's own frame: the bits of
    :func:`entry_position64` up to the cube's rotation onto the face (a signed permutation), with 1 / ||w|| read from
    ``grid.inverse_lengths`` (the same division of the same exact integer sum as :func:`node_direction`'s)."""
    x = 2 * j - grid.cells
    y = 2 * i - grid.cells
    slot = (wp.abs(x) >> 1) * ((grid.cells >> 1) + 1) + (wp.abs(y) >> 1)
    w = wp.vec3d(wp.float64(x), wp.float64(y), wp.float64(grid.cells))
    return (grid.radius + wp.float64(z)) * (w * load(grid.inverse_lengths, slot))


@wp.func
def planet_vector(face: wp.int32, q: wp.vec3d) -> wp.vec3d:
    """A face-local float64 vector in the planet frame: :func:`frame_rotate`'s signed permutation (exact)."""
    x = q[1]  # face 5
    y = q[0]
    z = -q[2]
    if face == 0:
        x = q[0]
        y = q[1]
        z = q[2]
    elif face == 1:
        x = q[2]
        y = -q[1]
        z = q[0]
    elif face == 2:
        x = -q[1]
        y = q[2]
        z = -q[0]
    elif face == 3:
        x = -q[0]
        y = -q[2]
        z = -q[1]
    elif face == 4:
        x = -q[2]
        y = -q[0]
        z = q[1]
    return wp.vec3d(x, y, z)


@wp.func
def look_ahead_error(grid: CubeSphereGrid, face: wp.int32, i: wp.int32, j: wp.int32, a: wp.vec2i,
                     b: wp.vec2i) -> wp.float64:
    """The 1-level look-ahead error |v - (a + b)/2| of face node (i, j) splitting the hypotenuse (a, b) on the cube
    (§7.1, Abb. 5b), on the float64 positions the mesh's vertices have (:func:`face_position64`). The float32
    ``grid.positions`` round each coordinate by up to 0.25 m at the earth's radius, and e measured on them fell up
    to 0.65 m short of the mesh's own error.

    The difference is turned into the planet frame (exact) before its length: the copies of a seam node, each in
    its own face's frame, see its components permuted and sign-flipped, and summed in that order (CUDA fuses the
    multiply-adds, NVRTC's ``--fmad=true``) their e could part by a bit, one side of the seam refining and the
    other not; in one frame every copy does the same arithmetic on the same bits (:class:`NodeParameters`), which
    are those of :func:`entry_position64`'s vertices."""
    n = grid.n
    base = face * n * n
    v = face_position64(grid, i, j, load(grid.heights, base + i * n + j))
    pa = face_position64(grid, a[0], a[1], load(grid.heights, base + a[0] * n + a[1]))
    pb = face_position64(grid, b[0], b[1], load(grid.heights, base + b[0] * n + b[1]))
    return wp.length(planet_vector(face, v - wp.float64(0.5) * (pa + pb)))


@wp.func
def in_grid(grid: CubeSphereGrid, i: wp.int32, j: wp.int32) -> wp.int32:
    """1 when (i, j) lies on the face (always 1 on the cube, where outside nodes fold onto a neighbour)."""
    if grid.planar == 0:
        return 1
    if i >= 0 and i <= grid.cells and j >= 0 and j <= grid.cells:
        return 1
    return 0


# ---------------------------------------------------------------------------------------------------------
# resampling and projection (§4)
# ---------------------------------------------------------------------------------------------------------


@wp.func
def column_weights(source: LatLonGrid, lon: wp.float64) -> wp.vec3:
    """(c0, c1, t) of linear interpolation in longitude, wrapping around the antimeridian (columns as floats:
    exact below 2^24)."""
    cols = source.elevation.shape[1]
    fc = (lon - source.lon0) * source.inv_dlon
    fc = fc - wp.floor(fc * source.inv_cols) * wp.float64(cols)
    c0 = wp.int32(wp.floor(fc))
    t = wp.float32(fc - wp.float64(c0))
    if c0 >= cols:
        c0 = c0 - cols
    if c0 < 0:
        c0 = c0 + cols
    c1 = c0 + 1
    if c1 >= cols:
        c1 = 0
    return wp.vec3(wp.float32(c0), wp.float32(c1), t)


@wp.func
def sample_row(source: LatLonGrid, row: wp.int32, cw: wp.vec3) -> wp.float32:
    """Linear interpolation along one row with the weights of :func:`column_weights`."""
    return (1.0 - cw[2]) * source.elevation[row, wp.int32(cw[0])] + cw[2] * source.elevation[row, wp.int32(cw[1])]


@wp.func
def atan2_core(ax: wp.float32, ay: wp.float32) -> wp.float32:
    """atan2(ay, ax) for ax, ay >= 0 in float32 without a libm call: reduction to |t| <= tan(π/8), odd degree-11
    polynomial (least-squares fit, truncation < 5e-10 rad, below float32 rounding: within ~2 ulp of atan2).
    The first quadrant of :func:`fast_atan2f`, a function of |x| and |y| only: what :func:`angle_tables` keeps."""
    hi = wp.max(ax, ay)
    if hi == wp.float32(0.0):
        return wp.float32(0.0)
    t = wp.min(ax, ay) / hi
    base = wp.float32(0.0)
    if t > wp.float32(0.41421356):
        t = (t - wp.float32(1.0)) / (t + wp.float32(1.0))
        base = wp.float32(0.78539816)
    t2 = t * t
    poly = wp.float32(-0.06030872464) * t2 + wp.float32(0.1056963349)
    poly = poly * t2 - wp.float32(0.1423923555)
    poly = poly * t2 + wp.float32(0.199981622)
    poly = poly * t2 - wp.float32(0.3333330783)
    r = base + t * (poly * t2 + wp.float32(1.0))
    if ay > ax:
        r = wp.float32(1.5707963) - r
    return r


@wp.func
def atan2_quadrant(core: wp.float32, y: wp.float32, x: wp.float32) -> wp.float32:
    """atan2(y, x) from its first-quadrant value :func:`atan2_core` (|x|, |y|): exact sign and π steps."""
    r = core
    if x < wp.float32(0.0):
        r = wp.float32(3.1415927) - r
    if y < wp.float32(0.0):
        r = -r
    return r


@wp.func
def fast_atan2f(y: wp.float32, x: wp.float32) -> wp.float32:
    """float32 atan2 without a libm call (:func:`atan2_core` of |x|, |y|, then the quadrant)."""
    return atan2_quadrant(atan2_core(wp.abs(x), wp.abs(y)), y, x)


@wp.func
def longitude_weights(source: LatLonGrid, point: wp.vec3i) -> wp.vec3:
    """The column weights (:func:`column_weights`) of the longitude of an integer cube point. On the four
    equatorial faces they depend on one face-local coordinate only, so :func:`resample_latlon` reads them from a
    table of those lines (:func:`longitude_lines`)."""
    return column_weights(source, wp.float64(fast_atan2f(wp.float32(point[1]), wp.float32(point[0]))))


@wp.func
def sample_latlon(source: LatLonGrid, lat32: wp.float32, cw: wp.vec3) -> wp.float32:
    """Bilinear elevation at float32 latitude ``lat32`` and the column weights ``cw`` of the longitude; between
    the first (last) row and the pole, a blend towards the pole value.

    Latitude and longitude in float32 (atan2 is scale-free, so straight from the integer point): their
    rounding, ~1e-7 rad or < 1 m on the earth, is 1e-4 of a 10' source cell, far below the bilinear model's
    own error; the same integer point gives the same value on every seam copy."""
    rows = source.elevation.shape[0]
    half_pi = wp.float64(1.5707963267948966)
    lat = wp.float64(lat32)
    fr = (source.lat0 - lat) * source.inv_dlat
    if fr <= wp.float64(0.0):
        span = half_pi - source.lat0
        w = wp.float32(0.0)
        if span > wp.float64(0.0):
            w = wp.float32(wp.clamp((lat - source.lat0) / span, wp.float64(0.0), wp.float64(1.0)))
        return (1.0 - w) * sample_row(source, 0, cw) + w * source.north_pole
    last = wp.float64(rows - 1)
    if fr >= last:
        lat_last = source.lat0 - last * source.dlat
        span = lat_last + half_pi
        w = wp.float32(0.0)
        if span > wp.float64(0.0):
            w = wp.float32(wp.clamp((lat_last - lat) / span, wp.float64(0.0), wp.float64(1.0)))
        return (1.0 - w) * sample_row(source, rows - 1, cw) + w * source.south_pole
    r0 = wp.int32(wp.floor(fr))
    r0 = wp.min(r0, rows - 2)
    t = wp.float32(fr - wp.float64(r0))
    return (1.0 - t) * sample_row(source, r0, cw) + t * sample_row(source, r0 + 1, cw)


@wp.func
def line_axis(face: wp.int32) -> wp.int32:
    """0: the face's longitude lines are its rows (its local x axis runs along ±z), 1: its columns, -1: a polar
    face (its normal is ±z)."""
    if frame_rotate(face, wp.vec3i(1, 0, 0))[2] != 0:
        return 0
    if frame_rotate(face, wp.vec3i(0, 1, 0))[2] != 0:
        return 1
    return -1


@wp.kernel
def longitude_lines(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    source: LatLonGrid,
    # outputs
    lines_out: wp.array[wp.vec3],  # per face and k < n: :func:`longitude_weights` of row k or column k
):
    """One thread per (face, k): the longitude line k of an equatorial face (unused on the polar faces)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    slot = first
    while slot < last:
        face = slot / grid.n
        k = slot - face * grid.n
        axis = line_axis(face)
        line = wp.vec3(0.0, 0.0, 0.0)
        if axis == 0:
            line = longitude_weights(source, cube_point(face, k, 0, grid.cells))
        elif axis == 1:
            line = longitude_weights(source, cube_point(face, 0, k, grid.cells))
        lines_out[slot] = line
        slot += 1


# A node (i, j) of any face lies at the integer cube point ±(2j - N)·x_f ± (2i - N)·y_f ± N·n_f, so every angle
# the resampling needs is a function of U = |2i - N|, V = |2j - N| and the face's orientation, up to exact sign
# and π steps: the latitude atan2(z, ρ) is odd in z and depends on x and y only through x² + y²; the longitude
# atan2(y, x) is atan2_core(|x|, |y|) put in its quadrant. One table over the quarter face (U, V even, as N is)
# serves all six faces: 6·(N + 1)² atan2 calls (two per polar node) become (N/2 + 1)² · 5.
@wp.kernel
def angle_tables(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    cells: wp.int32,  # N, even
    # outputs, per slot (U/2)·(N/2 + 1) + V/2
    polar_out: wp.array[wp.vec3],  # polar faces: (latitude at z = N, atan2_core(V, U), atan2_core(U, V))
    equatorial_out: wp.array[wp.vec2],  # equatorial faces: latitude at |z| = V, ρ(U); at |z| = U, ρ(V)
    inverse_length_out: wp.array[wp.float64],  # 1 / ||w||, ||w||² = N² + U² + V² (exact integers in float64)
):
    """One thread per slot of the quarter face: the latitudes atan2(z, ρ) (ρ = √(x² + y²) in float32: exact
    squares and sum below 2^24, the same for every order and sign of x and y) and the first-quadrant longitudes
    that :func:`resample_latlon` reads instead of computing them (the same functions of the same float32
    values, so the same bits), and the inverse length of :func:`node_direction`'s w."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    half = cells / 2 + 1
    nf = wp.float32(cells)
    slot = first
    while slot < last:
        p = slot / half
        q = slot - p * half
        u = wp.float32(2 * p)
        v = wp.float32(2 * q)
        polar_out[slot] = wp.vec3(atan2_core(wp.sqrt(v * v + u * u), nf), atan2_core(v, u), atan2_core(u, v))
        equatorial_out[slot] = wp.vec2(atan2_core(wp.sqrt(nf * nf + u * u), v),
                                       atan2_core(wp.sqrt(nf * nf + v * v), u))
        ud = wp.float64(2 * p)
        vd = wp.float64(2 * q)
        nd = wp.float64(cells)
        inverse_length_out[slot] = wp.float64(1.0) / wp.sqrt(vd * vd + ud * ud + nd * nd)
        slot += 1


@wp.kernel
def resample_latlon(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    source: LatLonGrid,
    exaggeration: wp.float32,
    lines: wp.array[wp.vec3],  # of longitude_lines
    polar: wp.array[wp.vec3],  # of angle_tables
    equatorial: wp.array[wp.vec2],
    inverse_length: wp.array[wp.float64],
    # outputs
    heights_out: wp.array[wp.float32],
    positions_out: wp.array[wp.vec3],
):
    """One thread per entry: bilinear elevation at the node's direction times the exaggeration, and the
    projected position v = (R + z) · w / ||w|| rounded to float32 (§4). The angles come from the tables of
    :func:`angle_tables` and :func:`longitude_lines`: the same float32 values as :func:`fast_atan2f` of the
    node's cube point would give, without an atan2 per node."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    if first >= last:
        return
    # (face, i, j) once per chunk, then stepped along the rows; the cube point is X·x_f + Y·y_f + N·n_f with
    # the face's axes (the same integers as cube_point, whose per-node branches cost more than the rest)
    nn = grid.n * grid.n
    half = grid.cells / 2 + 1
    face = first / nn
    rest = first - face * nn
    i = rest / grid.n
    j = rest - i * grid.n
    x_axis = frame_rotate(face, wp.vec3i(1, 0, 0))
    y_axis = frame_rotate(face, wp.vec3i(0, 1, 0))
    normal = frame_rotate(face, wp.vec3i(0, 0, 1))
    axis = line_axis(face)
    entry = first
    while entry < last:
        point = (2 * j - grid.cells) * x_axis + (2 * i - grid.cells) * y_axis + grid.cells * normal
        slot = (wp.abs(2 * i - grid.cells) / 2) * half + wp.abs(2 * j - grid.cells) / 2
        direction = wp.vec3d(wp.float64(point[0]), wp.float64(point[1]), wp.float64(point[2]))
        direction = direction * inverse_length[slot]
        cw = wp.vec3(0.0, 0.0, 0.0)
        lat = wp.float32(0.0)
        if axis == 0:  # z = ±(2j - N), ρ from U
            cw = lines[face * grid.n + i]
            lat = equatorial[slot][0]
        elif axis == 1:  # z = ±(2i - N), ρ from V
            cw = lines[face * grid.n + j]
            lat = equatorial[slot][1]
        else:  # polar: |x| is V where the face's x axis is the cube's ±x, else U
            angles = polar[slot]
            core = angles[2]
            if x_axis[0] != 0:
                core = angles[1]
            lon = atan2_quadrant(core, wp.float32(point[1]), wp.float32(point[0]))
            cw = column_weights(source, wp.float64(lon))
            lat = angles[0]
        if point[2] < 0:
            lat = -lat
        z = exaggeration * sample_latlon(source, lat, cw)
        heights_out[entry] = z
        p = (grid.radius + wp.float64(z)) * direction
        positions_out[entry] = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
        j += 1
        if j == grid.n:
            j = 0
            i += 1
            if i == grid.n:
                i = 0
                face += 1
                x_axis = frame_rotate(face, wp.vec3i(1, 0, 0))
                y_axis = frame_rotate(face, wp.vec3i(0, 1, 0))
                normal = frame_rotate(face, wp.vec3i(0, 0, 1))
                axis = line_axis(face)
        entry += 1


@wp.func
def lowest_bit(k: wp.int32) -> wp.int32:
    """The largest power of two dividing k > 0."""
    return k & (-k)


@wp.func
def padding_row_unread(grid: CubeSphereGrid, i: wp.int32) -> wp.int32:
    """1 when no node of row i of a padded planar input is read (:func:`padding_tier` 2 for all: below the input
    by PADDING_WRITTEN times the row's lowest bit or more, which bounds the spacing of every node in it)."""
    if i >= grid.rows_valid and i - grid.rows_valid + 1 >= PADDING_WRITTEN * lowest_bit(i):
        return 1
    return 0


@wp.func
def padding_entry_step(grid: CubeSphereGrid, i: wp.int32, j: wp.int32, row_unread: wp.int32):
    """Stepping over a padded planar input's entries in memory order: (1 when node (i, j) is read, entries to the
    next one that may be): to the next row from a row that nothing reads (:func:`padding_row_unread`), from
    column j to j + lowest_bit(j) where j lies so far right that it and the columns in between (smaller lowest
    bits, further out) are not read, else 1."""
    if row_unread != 0:
        return wp.int32(0), grid.n - j
    read = wp.int32(0)
    bits = i | j
    if bits == 0:
        read = 1
    elif padding_tier(grid, i, j, lowest_bit(bits)) < 2:
        read = 1
    step = wp.int32(1)
    if j >= grid.cols_valid and j - grid.cols_valid + 1 >= PADDING_WRITTEN * lowest_bit(j):
        step = lowest_bit(j)
    return read, step


@wp.kernel
def project_nodes(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    # outputs
    positions_out: wp.array[wp.vec3],
):
    """One thread per entry: v = (R + z) · w / ||w|| rounded to float32 (planar: (j·dx, i·dy, z)). A padded planar
    input's nodes that nothing reads (:func:`padding_tier` 2) are stepped over, not written: whole rows, and
    from column j to j + lowest_bit(j) (the spacing of a node is at most the lowest bit of its row and column)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    entry = first
    if grid.planar == 0 or (grid.rows_valid == grid.n and grid.cols_valid == grid.n):
        while entry < last:
            p = entry_position64(grid, entry)
            positions_out[entry] = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
            entry += 1
        return
    i = entry / grid.n
    j = entry - i * grid.n
    beyond_i = padding_row_unread(grid, i)
    while entry < last:
        read = wp.int32(0)
        step = wp.int32(0)
        read, step = padding_entry_step(grid, i, j, beyond_i)
        if read != 0:
            p = entry_position64(grid, entry)
            positions_out[entry] = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
        entry += step
        j += step
        if j >= grid.n:
            j = 0
            i += 1
            beyond_i = padding_row_unread(grid, i)


@wp.kernel
def pad_heights(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,  # planar, padded (its heights are the output)
    source: wp.array[wp.float32],  # the input's rows_valid x cols_valid heights, row-major
    # outputs
    heights_out: wp.array[wp.float32],  # n·n entries (grid.heights)
):
    """A padded planar input's heights (count = n·n entries): node (min(i, last row), min(j, last column)) of the
    input, the edge repeated, at every entry that anything reads (:func:`padding_tier` below 2: the input's
    rectangle, and the padding's nodes that may reach it); the rest, all but a band of the padding, is stepped
    over as in :func:`project_nodes` and never written (a 50 x 16385 strip's padded square holds 268 M nodes)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    entry = first
    i = entry / grid.n
    j = entry - i * grid.n
    beyond_i = padding_row_unread(grid, i)
    while entry < last:
        read = wp.int32(0)
        step = wp.int32(0)
        read, step = padding_entry_step(grid, i, j, beyond_i)
        if read != 0:
            row = wp.min(i, grid.rows_valid - 1)
            col = wp.min(j, grid.cols_valid - 1)
            heights_out[entry] = load(source, row * grid.cols_valid + col)
        entry += step
        j += step
        if j >= grid.n:
            j = 0
            i += 1
            beyond_i = padding_row_unread(grid, i)


# ---------------------------------------------------------------------------------------------------------
# hierarchy parameters, bottom-up (§6, §7.1)
# ---------------------------------------------------------------------------------------------------------


@wp.func
def depth_node(depth: wp.int32, tid: wp.int32, cells: wp.int32) -> wp.vec4i:
    """Thread ``tid`` of the launch over ``depth`` -> (face, i, j, kind), or kind -1 for a padding thread.

    Shifts and masks only (integer division is the costliest step of a CPU thread): per face 4^t slots at an
    even depth (q² diagonal nodes, q = 2^t), 4^(t+1) at an odd one (two orientations of q x 2q slots for
    q x (q + 1) axis nodes; the rest pad). kind 0/1: diagonal node whose hypotenuse is the main / anti
    diagonal of its 2s square; 2: axis node with its hypotenuse along i; 3: along j."""
    t = depth >> 1
    s = cells >> (t + 1)
    if (depth & 1) == 0:
        shift = 2 * t
        face = tid >> shift
        local = tid & ((1 << shift) - 1)
        a = local >> t
        b = local & ((1 << t) - 1)
        kind = wp.int32(1)
        if ((a + b) & 1) == 0:
            kind = 0
        return wp.vec4i(face, s * (2 * a + 1), s * (2 * b + 1), kind)
    shift = 2 * t + 2
    face = tid >> shift
    local = tid & ((1 << shift) - 1)
    orientation = local >> (2 * t + 1)
    rest = local & ((1 << (2 * t + 1)) - 1)
    if orientation == 0:  # i = s(2a + 1), j = 2sb: b runs fastest, along a row
        a = rest >> (t + 1)
        b = rest & ((1 << (t + 1)) - 1)
        if b > (1 << t):
            return wp.vec4i(face, 0, 0, -1)
        return wp.vec4i(face, s * (2 * a + 1), 2 * s * b, 2)
    b = rest >> t  # i = 2sb, j = s(2a + 1): a runs fastest, along a row (memory order)
    a = rest & ((1 << t) - 1)
    if b > (1 << t):
        return wp.vec4i(face, 0, 0, -1)
    return wp.vec4i(face, 2 * s * b, s * (2 * a + 1), 3)


def depth_slots(depth: int) -> int:
    """Threads per face of the launch over ``depth`` (host side twin of :func:`depth_node`)."""
    t = depth >> 1
    return 1 << (2 * t) if depth % 2 == 0 else 1 << (2 * t + 2)


@wp.func
def padded_depth_box(cells: wp.int32, rows_valid: wp.int32, cols_valid: wp.int32, depth: wp.int32) -> wp.vec4i:
    """A padded planar input's launch over ``depth``: the nodes that :func:`padding_tier` writes lie in rows
    i <= rows_valid - 2 + PADDING_WRITTEN·s and columns j <= cols_valid - 2 + PADDING_WRITTEN·s; the counts of
    :func:`depth_node`'s a and b there: (A, B) at an even depth (i = s(2a + 1), j = s(2b + 1)); at an odd one
    (A, B) of the axis nodes along i (i = s(2a + 1), j = 2sb), then (B', A') of those along j (i = 2sb,
    j = s(2a + 1))."""
    t = depth >> 1
    q = 1 << t
    s = cells >> (t + 1)
    rows = wp.min(cells, rows_valid - 2 + PADDING_WRITTEN * s)
    cols = wp.min(cells, cols_valid - 2 + PADDING_WRITTEN * s)
    odd_i = wp.min(q, (rows / s + 1) / 2)  # a with s(2a + 1) <= rows
    odd_j = wp.min(q, (cols / s + 1) / 2)
    if (depth & 1) == 0:
        return wp.vec4i(odd_i, odd_j, 0, 0)
    return wp.vec4i(odd_i, wp.min(q, cols / (2 * s)) + 1, wp.min(q, rows / (2 * s)) + 1, odd_j)


def padded_depth_slots(cells: int, rows_valid: int, cols_valid: int, depth: int) -> int:
    """Threads of a padded planar input's launch over ``depth`` (host side twin of :func:`padded_depth_box`)."""
    t = depth >> 1
    q = 1 << t
    s = cells >> (t + 1)
    rows = min(cells, rows_valid - 2 + int(PADDING_WRITTEN) * s)
    cols = min(cells, cols_valid - 2 + int(PADDING_WRITTEN) * s)
    odd_i = min(q, (rows // s + 1) // 2)
    odd_j = min(q, (cols // s + 1) // 2)
    if depth % 2 == 0:
        return odd_i * odd_j
    return odd_i * (min(q, cols // (2 * s)) + 1) + (min(q, rows // (2 * s)) + 1) * odd_j


@wp.func
def padded_depth_node(depth: wp.int32, tid: wp.int32, cells: wp.int32, box: wp.vec4i) -> wp.vec4i:
    """:func:`depth_node` of a padded planar input's launch over ``depth`` (:func:`padded_depth_box`): the same
    (face 0, i, j, kind), over the box of nodes that may be written only."""
    t = depth >> 1
    s = cells >> (t + 1)
    if (depth & 1) == 0:
        a = tid / box[1]
        b = tid - a * box[1]
        kind = wp.int32(1)
        if ((a + b) & 1) == 0:
            kind = 0
        return wp.vec4i(0, s * (2 * a + 1), s * (2 * b + 1), kind)
    along_i = box[0] * box[1]
    if tid < along_i:
        a = tid / box[1]
        b = tid - a * box[1]
        return wp.vec4i(0, s * (2 * a + 1), 2 * s * b, 2)
    rest = tid - along_i
    b = rest / box[3]
    a = rest - b * box[3]
    return wp.vec4i(0, 2 * s * b, s * (2 * a + 1), 3)


@wp.func
def hypotenuse_offset(kind: wp.int32, s: wp.int32) -> wp.vec2i:
    """(di, dj) from a node to one end of its hypotenuse; the other end is at minus it."""
    if kind == 0:
        return wp.vec2i(s, s)
    if kind == 1:
        return wp.vec2i(s, -s)
    if kind == 2:
        return wp.vec2i(s, 0)
    return wp.vec2i(0, s)


@wp.func
def child_offset(kind: wp.int32, s: wp.int32, k: wp.int32) -> wp.vec2i:
    """(di, dj) from a node to its k-th child (k < 4); (0, 0) when it has none (axis node with s = 1).

    Diagonal nodes (kind 0, 1): (s, 0), (-s, 0), (0, s), (0, -s); axis nodes: (±s/2, ±s/2). Arithmetic rather
    than branches with returns (cheaper in the CPU backend's code)."""
    lo = k & 1
    hi = k >> 1
    sign = 1 - 2 * lo
    h = s >> 1
    di = wp.where(kind <= 1, sign * s * (1 - hi), h * (1 - 2 * hi))
    dj = wp.where(kind <= 1, sign * s * hi, h * sign)
    return wp.vec2i(di, dj)


@wp.func
def node_spacing(depth: wp.int32, cells: wp.int32) -> wp.int32:
    """s of the nodes at ``depth``."""
    return cells >> (depth // 2 + 1)


@wp.func
def straddles_input(grid: CubeSphereGrid, a: wp.vec2i, b: wp.vec2i, c: wp.vec2i) -> wp.int32:
    """Planar, padded input: 1 when the triangle reaches outside the input rectangle while its bounding box
    overlaps the rectangle's interior (it must refine until it lies wholly inside or wholly outside)."""
    last_i = grid.rows_valid - 1
    last_j = grid.cols_valid - 1
    i0 = wp.min(a[0], wp.min(b[0], c[0]))
    i1 = wp.max(a[0], wp.max(b[0], c[0]))
    j0 = wp.min(a[1], wp.min(b[1], c[1]))
    j1 = wp.max(a[1], wp.max(b[1], c[1]))
    if i1 <= last_i and j1 <= last_j:
        return 0
    if i0 >= last_i or j0 >= last_j:
        return 0
    return 1


@wp.func
def in_padding(grid: CubeSphereGrid, a: wp.vec2i, b: wp.vec2i, c: wp.vec2i) -> wp.int32:
    """Planar, padded input: 1 when the triangle lies wholly in the padding (at or below the input's last row, or
    at or right of its last column: no input node inside it but on that border, whose nodes its neighbour inside
    covers); the mesh drops such a triangle (:func:`count_kept_faces`, the same test)."""
    i0 = wp.min(a[0], wp.min(b[0], c[0]))
    j0 = wp.min(a[1], wp.min(b[1], c[1]))
    if i0 >= grid.rows_valid - 1 or j0 >= grid.cols_valid - 1:
        return 1
    return 0


@wp.func
def padding_tier(grid: CubeSphereGrid, i: wp.int32, j: wp.int32, s: wp.int32) -> wp.int32:
    """Planar, padded input: what the node parameters do with node (i, j) of spacing s. 0: computed (its
    diamond or a descendant's may reach into the input); 1: all padding, written as :data:`PADDING_ERROR`
    without reading anything (a computed node may read it as a child, the refinement as a refinement node); 2:
    never read by anything (no computed node has it as a child, no refining node's triangles contain it), not
    written. Always 0 on an input that needs no padding."""
    out = i - grid.rows_valid + 1
    out_j = j - grid.cols_valid + 1
    if out_j > out:
        out = out_j
    if out < PADDING_REACH * s:
        return 0
    if out < PADDING_WRITTEN * s:
        return 1
    return 2


@wp.func
def edge_bound(w: wp.int32, step: wp.int32) -> wp.int32:
    """The bound that w + k·step >= 0 puts on k: k >= it (step > 0) or k <= it (step < 0); 0 for step 0
    (exact: float64 quotients of small integers, which are exact or far from the next integer)."""
    if step > 0:
        return wp.int32(wp.ceil(wp.float64(-w) / wp.float64(step)))
    if step < 0:
        return wp.int32(wp.floor(wp.float64(w) / wp.float64(-step)))
    return 0


@wp.func
def edge_slope(delta: wp.int32, step: wp.int32) -> wp.int32:
    """How much :func:`edge_bound` changes from one row to the next when w changes by ``delta``: -delta / step
    when that is an integer (then ceil and floor move by it exactly); 0 for step 0; otherwise a flag value
    (:data:`NO_SLOPE`: recompute the bound per row). The bisection's triangles have axis-aligned and diagonal
    edges only, whose slopes are 0 or ±1."""
    if step == 0:
        return 0
    if delta % step != 0:
        return NO_SLOPE
    return -(delta / step)


@wp.func
def row_bound(bound: wp.int32, slope: wp.int32, w: wp.int32, step: wp.int32, first: wp.int32) -> wp.int32:
    """This row's :func:`edge_bound`: computed on the ``first`` row and where the edge has no slope, else the
    previous row's stepped by the slope."""
    if first != 0 or slope == NO_SLOPE:
        return edge_bound(w, step)
    return bound + slope


@wp.func
def edge_limits(w: wp.int32, step: wp.int32, bound: wp.int32, lo: wp.int32, hi: wp.int32):
    """[lo, hi] narrowed to the k with w + k·step >= 0, given the edge's :func:`edge_bound`."""
    if step > 0:
        lo = wp.max(lo, bound)
    elif step < 0:
        hi = wp.min(hi, bound)
    elif w < 0:
        hi = lo - 1
    return lo, hi


@wp.func
def triangle_true_error(grid: CubeSphereGrid, face: wp.int32, a: wp.vec2i, b: wp.vec2i, c: wp.vec2i) -> wp.float64:
    """Planar only: the largest vertical distance between a grid node inside triangle (a, b, c) and the
    triangle's plane (:data:`PADDING_ERROR` when the triangle leaves the grid or lies in a padded input's
    padding, :data:`STRADDLE_ERROR` when it straddles the input's border)."""
    if in_grid(grid, c[0], c[1]) == 0 or in_padding(grid, a, b, c) != 0:
        return PADDING_ERROR
    if straddles_input(grid, a, b, c) != 0:
        return STRADDLE_ERROR
    base = face * grid.n * grid.n
    za = wp.float64(grid.heights[base + a[0] * grid.n + a[1]])
    zb = wp.float64(grid.heights[base + b[0] * grid.n + b[1]])
    zc = wp.float64(grid.heights[base + c[0] * grid.n + c[1]])
    area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    sign = wp.int32(1)
    if area < 0:
        sign = -1
    inv_signed = wp.float64(1.0) / wp.float64(area * sign)  # the weights below carry the sign
    i0 = wp.min(a[0], wp.min(b[0], c[0]))
    i1 = wp.max(a[0], wp.max(b[0], c[0]))
    j0 = wp.min(a[1], wp.min(b[1], c[1]))
    j1 = wp.max(a[1], wp.max(b[1], c[1]))
    # edge functions (times the orientation sign) stepped along each row: exact integers, the same values as
    # evaluating them per node; a row meets the triangle in one interval, so leave the row once past it
    step_a = (c[0] - b[0]) * sign
    step_b = (a[0] - c[0]) * sign
    step_c = (b[0] - a[0]) * sign
    worst = wp.float64(0.0)
    dz = (wp.float64(step_a) * za + wp.float64(step_b) * zb + wp.float64(step_c) * zc) * inv_signed
    dz2 = dz + dz
    # each edge function's bound on the row's interval, from one division at the first row and then stepped
    # by its integer slope (the same integers as a division per edge and row, without three divisions a row)
    slope_a = edge_slope((b[1] - c[1]) * sign, step_a)  # w's change per row: minus the j coefficient
    slope_b = edge_slope((c[1] - a[1]) * sign, step_b)
    slope_c = edge_slope((a[1] - b[1]) * sign, step_c)
    bound_a = wp.int32(0)
    bound_b = wp.int32(0)
    bound_c = wp.int32(0)
    # a for loop on purpose: as a while loop (see the chunk loops) this function measured 5-15 % slower
    for i in range(i0, i1 + 1):
        wa = ((b[0] - i) * (c[1] - j0) - (b[1] - j0) * (c[0] - i)) * sign
        wb = ((c[0] - i) * (a[1] - j0) - (c[1] - j0) * (a[0] - i)) * sign
        wc = ((a[0] - i) * (b[1] - j0) - (a[1] - j0) * (b[0] - i)) * sign
        # the row's interval inside the triangle, [j0 + lo, j0 + hi]: each edge function w + k·step >= 0
        first = wp.where(i == i0, 1, 0)
        bound_a = row_bound(bound_a, slope_a, wa, step_a, first)
        bound_b = row_bound(bound_b, slope_b, wb, step_b, first)
        bound_c = row_bound(bound_c, slope_c, wc, step_c, first)
        lo = wp.int32(0)
        hi = j1 - j0
        lo, hi = edge_limits(wa, step_a, bound_a, lo, hi)
        lo, hi = edge_limits(wb, step_b, bound_b, lo, hi)
        lo, hi = edge_limits(wc, step_c, bound_c, lo, hi)
        row = base + i * grid.n + j0
        wa += lo * step_a
        wb += lo * step_b
        wc += lo * step_c
        if lo > hi:
            continue
        # the plane along the row, stepped: off the per-node formula by a few ulp (~1e-13 m), far inside
        # the 2^-22 relative margin of e
        z = (wp.float64(wa) * za + wp.float64(wb) * zb + wp.float64(wc) * zc) * inv_signed
        # two nodes per step with two running maxima (shorter dependency chains)
        z1 = z + dz
        other = wp.float64(0.0)
        k = lo
        while k < hi:
            worst = wp.max(worst, wp.abs(wp.float64(grid.heights[row + k]) - z))
            other = wp.max(other, wp.abs(wp.float64(grid.heights[row + k + 1]) - z1))
            z += dz2
            z1 += dz2
            k += 2
        if k == hi:
            worst = wp.max(worst, wp.abs(wp.float64(grid.heights[row + k]) - z))
        worst = wp.max(worst, other)
    return worst


@wp.func
def leg_midpoint(p: wp.vec2i, q: wp.vec2i) -> wp.vec2i:
    """The grid node halfway between p and q, or (-1, -1) when the midpoint is not a node."""
    si = p[0] + q[0]
    sj = p[1] + q[1]
    if ((si | sj) & 1) != 0:
        return wp.vec2i(-1, -1)
    return wp.vec2i(si >> 1, sj >> 1)


@wp.func
def midpoint_error(heights: wp.array[wp.float32], n: wp.int32, base: wp.int32, p: wp.vec2i, q: wp.vec2i,
                   zp: wp.float64, zq: wp.float64) -> wp.float64:
    """Vertical distance of the node at the midpoint of edge (p, q) from the edge (0 when it is no node)."""
    mid = leg_midpoint(p, q)
    if mid[0] < 0:
        return wp.float64(0.0)
    z = wp.float64(heights[base + mid[0] * n + mid[1]])
    return wp.abs(z - (zp + zq) * wp.float64(0.5))


@wp.func
def small_triangle_error(grid: CubeSphereGrid, face: wp.int32, a: wp.vec2i, b: wp.vec2i, c: wp.vec2i) -> wp.float64:
    """:func:`triangle_true_error` of a triangle of the two deepest levels (s = 1), whose only nodes are its
    corners and its edges' integer midpoints, in closed form: bit-identical (the corners' weights are |area|
    and the midpoints' |area| / 2, powers of two, so the barycentric formula gives exactly (z_p + z_q) / 2)
    without the branchy row scan, which costs ~100 ns per triangle in mispredictions."""
    if in_grid(grid, c[0], c[1]) == 0 or in_padding(grid, a, b, c) != 0:
        return PADDING_ERROR
    if straddles_input(grid, a, b, c) != 0:
        return STRADDLE_ERROR
    n = grid.n
    base = face * n * n
    za = wp.float64(grid.heights[base + a[0] * n + a[1]])
    zb = wp.float64(grid.heights[base + b[0] * n + b[1]])
    zc = wp.float64(grid.heights[base + c[0] * n + c[1]])
    worst = midpoint_error(grid.heights, n, base, a, b, za, zb)
    worst = wp.max(worst, midpoint_error(grid.heights, n, base, a, c, za, zc))
    return wp.max(worst, midpoint_error(grid.heights, n, base, b, c, zb, zc))


@wp.func
def direction_angle(w: wp.vec3d, u: wp.vec3d) -> wp.float64:
    """An upper bound of the angle between two integer cube points (exact products): tan θ while it is below
    0.05 (over by < θ³/3, no libm call), else atan2."""
    cross = wp.length(wp.cross(w, u))
    dot = wp.dot(w, u)
    if cross < wp.float64(0.05) * dot:
        return cross / dot
    return wp.atan2(cross, dot)


@wp.func
def to_vec3d_i(p: wp.vec3i) -> wp.vec3d:
    """Integer point -> float64 point (exact)."""
    return wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))


@wp.kernel
def saturate_leaf_parameters(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    # outputs
    values_out: wp.array[wp.vec4],
):
    """The deepest level on the cube (s = 1 axis nodes, half of all nodes): one thread per chunk of entries in
    memory order, (face, i, j) stepped along the rows; the leaves ((i + j) odd) get e = |v - (a + b)/2| and
    r = h = α = 0, exactly as :func:`saturate_node_parameters` computes them, without its slot decoding and
    empty children loop."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    if first >= last:
        return
    n = grid.n
    nn = n * n
    face = first / nn
    rest = first - face * nn
    i = rest / n
    j = rest - i * n
    entry = first
    while entry < last:
        if ((i + j) & 1) != 0:
            step = wp.vec2i(0, 1)  # i even, j odd: the hypotenuse runs along j
            if (i & 1) != 0:
                step = wp.vec2i(1, 0)  # i odd, j even: along i
            node = wp.vec2i(i, j)
            e = look_ahead_error(grid, face, i, j, node + step, node - step)
            values_out[entry] = wp.vec4(wp.float32(e * (wp.float64(1.0) + ABSOLUTE_MARGIN)), 0.0, 0.0, 0.0)
        j += 1
        if j == n:
            j = 0
            i += 1
            if i == n:
                i = 0
                face += 1
        entry += 1


@wp.kernel
def saturate_cell_centres(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    # outputs
    values_out: wp.array[wp.vec4],
):
    """The second-deepest level on the cube (s = 1 diagonal nodes: i and j odd, the centres of 2 x 2 cells),
    in memory order like :func:`saturate_leaf_parameters`: the same float64 formulas as
    :func:`saturate_node_parameters` on the four leaf children (i ± 1, j), (i, j ± 1) (always on the same face;
    their r, h, α are 0), so the results are bit-identical to it; α on face 0 only."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    if first >= last:
        return
    n = grid.n
    cells = grid.cells
    nn = n * n
    face = first / nn
    rest = first - face * nn
    i = rest / n
    j = rest - i * n
    entry = first
    while entry < last:
        if (i & j & 1) != 0:
            kind = ((i >> 1) + (j >> 1)) & 1
            dj = wp.int32(1)  # kind 0: a = (i + 1, j + 1)
            if kind != 0:
                dj = -1  # kind 1: a = (i + 1, j - 1)
            v = bounds.to_vec3d(grid.positions[entry])
            z_v = wp.float64(grid.heights[entry])
            e = look_ahead_error(grid, face, i, j, wp.vec2i(i + 1, j + dj), wp.vec2i(i - 1, j - dj))
            w_v = to_vec3d_i(wp.vec3i(2 * j - cells, 2 * i - cells, cells))
            r = wp.float64(0.0)
            h = wp.float64(0.0)
            alpha = wp.float64(0.0)
            for k in range(4):
                d = child_offset(0, 1, k)
                child = entry + d[0] * n + d[1]
                c = bounds.to_vec3d(grid.positions[child])
                # the children are leaves (r = h = α = 0): max |v - c| is the square root of the largest square
                # (sqrt is monotone and correctly rounded: the same value with one sqrt instead of four)
                e = wp.max(e, wp.float64(values_out[child][0]))
                r = wp.max(r, wp.dot(v - c, v - c))
                h = wp.max(h, wp.abs(z_v - wp.float64(grid.heights[child])))
                if face == 0:
                    w_c = to_vec3d_i(wp.vec3i(2 * (j + d[1]) - cells, 2 * (i + d[0]) - cells, cells))
                    alpha = wp.max(alpha, direction_angle(w_v, w_c))
            r = wp.sqrt(r)
            out = wp.vec4(wp.float32(e * (wp.float64(1.0) + ABSOLUTE_MARGIN)), 0.0, 0.0, 0.0)
            scale = (grid.radius + wp.abs(z_v)) * ABSOLUTE_MARGIN
            out[1] = wp.float32(r * (wp.float64(1.0) + RELATIVE_MARGIN) + scale)
            out[2] = wp.float32(h * (wp.float64(1.0) + RELATIVE_MARGIN) + scale)
            if face == 0:
                out[3] = wp.float32(alpha * (wp.float64(1.0) + RELATIVE_MARGIN) + ABSOLUTE_MARGIN)
            values_out[entry] = out
        j += 1
        if j == n:
            j = 0
            i += 1
            if i == n:
                i = 0
                face += 1
        entry += 1


@wp.kernel
def saturate_planar_fine(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    centres: wp.int32,  # 0: the deepest level (s = 1 axis nodes, (i + j) odd); 1: the 2 x 2 cell centres
    shapes: wp.int32,  # 1: r and h too; 0: e alone (r = h = 0; grid.positions is not read)
    # outputs
    values_out: wp.array[wp.vec4],
):
    """The planar case's two deepest levels in memory order (like :func:`saturate_leaf_parameters` on the
    cube): the same values as :func:`saturate_node_parameters` would give (true error of both triangles of the
    diamond by :func:`small_triangle_error`, the closed form of :func:`triangle_true_error` at s = 1; r over
    the four leaf children of a cell centre), without its slot decoding, padding slots and children loop."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    if first >= last:
        return
    n = grid.n
    i = first / n
    j = first - i * n
    entry = first
    while entry < last:
        hyp = wp.vec2i(0, 0)
        if centres == 0:
            if ((i + j) & 1) != 0:
                hyp = wp.vec2i(i & 1, j & 1)  # i odd: along i (kind 2); j odd: along j (kind 3)
        elif (i & j & 1) != 0:
            hyp = wp.vec2i(1, 1)
            if (((i >> 1) + (j >> 1)) & 1) != 0:
                hyp = wp.vec2i(1, -1)
        tier = wp.int32(0)
        if hyp[0] != 0 or hyp[1] != 0:
            tier = padding_tier(grid, i, j, 1)
            if tier == 1:
                values_out[entry] = wp.vec4(wp.float32(PADDING_ERROR), 0.0, 0.0, 0.0)
        if tier == 0 and (hyp[0] != 0 or hyp[1] != 0):
            a = wp.vec2i(i + hyp[0], j + hyp[1])
            b = wp.vec2i(i - hyp[0], j - hyp[1])
            apex = wp.vec2i(i + hyp[1], j - hyp[0])
            mate = wp.vec2i(i - hyp[1], j + hyp[0])
            e = wp.max(small_triangle_error(grid, 0, a, b, apex), small_triangle_error(grid, 0, a, b, mate))
            out = wp.vec4(0.0, 0.0, 0.0, 0.0)
            if centres != 0:
                v = wp.vec3d(0.0, 0.0, 0.0)
                if shapes != 0:
                    v = bounds.to_vec3d(grid.positions[entry])
                r = wp.float64(0.0)
                for k in range(4):
                    d = child_offset(0, 1, k)
                    child = entry + d[0] * n + d[1]
                    q = values_out[child]
                    e = wp.max(e, wp.float64(q[0]))
                    if shapes != 0 and q[0] >= wp.float32(0.0):  # (a child all padding never refines: no radius)
                        r = wp.max(r, wp.length(v - bounds.to_vec3d(grid.positions[child])) + wp.float64(q[1]))
                if shapes != 0:
                    scale = wp.length(v) * ABSOLUTE_MARGIN
                    out[1] = wp.float32(r * (wp.float64(1.0) + RELATIVE_MARGIN) + scale)
                    out[2] = wp.float32(scale)  # h = 0 on a plane: 0·(1 + margin) + scale, the same bits
            out[0] = wp.float32(e * (wp.float64(1.0) + ABSOLUTE_MARGIN))
            values_out[entry] = out
        j += 1
        if j - grid.cols_valid + 1 >= PADDING_WRITTEN and j < n:  # the rest of the row: tier 2 (s = 1)
            entry += n - j
            j = n
        if j == n:
            j = 0
            i += 1
        entry += 1


@wp.kernel
def saturate_node_parameters(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    depth: wp.int32,
    angles: wp.int32,  # 1: compute α (face 0 only; by the cube's rotation symmetry the other faces copy it)
    shapes: wp.int32,  # 1: r and h too; 0 (planar only): e alone (r = h = 0; grid.positions is not read)
    params: NodeParameters,  # read: the children's values (depth + 1, already done)
    # outputs
    values_out: wp.array[wp.vec4],  # (e, r, h, α) per entry (the same array as params.values)
):
    """One thread per node copy at ``depth``: e, r, h, α as the max over its children plus its own share,
    with the level-wise margin that keeps saturation and nesting true in floating point (§6, §7.1).

    e from the float64 positions (:func:`look_ahead_error`); r from the float32 positions (in float64); h from
    the heights, h(v) = max |z_v - z_c| + h(c) (§6); α from the nodes' exact cube directions. The absolute margin
    |v| · 2^-22 per level covers the float32 rounding of the positions r sees (< 0.45 m per node at the earth's
    radius); e, on the float64 positions, is rounded up by the same factor into float32."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    padded = wp.int32(0)
    box = wp.vec4i(0, 0, 0, 0)
    if grid.planar != 0 and (grid.rows_valid < grid.n or grid.cols_valid < grid.n):
        padded = 1
        box = padded_depth_box(grid.cells, grid.rows_valid, grid.cols_valid, depth)
    slot = first
    while slot < last:
        node = wp.vec4i(0, 0, 0, 0)
        if padded != 0:
            node = padded_depth_node(depth, slot, grid.cells, box)
        else:
            node = depth_node(depth, slot, grid.cells)
        slot += 1  # here, not at the end: a padding slot's continue below must not skip it
        kind = node[3]
        if kind < 0:
            continue
        face = node[0]
        i = node[1]
        j = node[2]
        s = node_spacing(depth, grid.cells)
        nn = grid.n * grid.n
        base = face * nn
        entry = base + i * grid.n + j
        if grid.planar != 0:
            tier = padding_tier(grid, i, j, s)
            if tier == 1:
                values_out[entry] = wp.vec4(wp.float32(PADDING_ERROR), 0.0, 0.0, 0.0)
            if tier != 0:
                continue
        with_angle = wp.int32(0)
        if angles != 0 and face == 0:
            with_angle = 1
        v = wp.vec3d(0.0, 0.0, 0.0)
        if shapes != 0:
            v = bounds.to_vec3d(grid.positions[entry])
        z_v = wp.float64(grid.heights[entry])
        # 1-level look-ahead error of the hypotenuse (a, b) (§7.1, Abb. 5b)
        hyp = hypotenuse_offset(kind, s)
        a = wp.vec2i(i + hyp[0], j + hyp[1])
        b = wp.vec2i(i - hyp[0], j - hyp[1])
        e = wp.float64(0.0)
        w_v = wp.vec3d(0.0, 0.0, 0.0)
        if grid.planar != 0:
            # planar: the true vertical error of both triangles of the diamond (never above the bound)
            apex = wp.vec2i(i + hyp[1], j - hyp[0])
            mate = wp.vec2i(i - hyp[1], j + hyp[0])
            # (s >= 2 here: the planar levels with s = 1 are saturate_planar_fine's)
            e = wp.max(triangle_true_error(grid, face, a, b, apex), triangle_true_error(grid, face, a, b, mate))
        else:
            e = look_ahead_error(grid, face, i, j, a, b)
            if with_angle != 0:
                w_v = to_vec3d_i(local_point(i, j, grid.cells))  # angles are invariant under the face's rotation
        r = wp.float64(0.0)
        h = wp.float64(0.0)
        alpha = wp.float64(0.0)
        has_children = wp.int32(0)
        for k in range(4):
            d = child_offset(kind, s, k)
            if d[0] != 0 or d[1] != 0:
                ci = i + d[0]
                cj = j + d[1]
                if grid.planar == 0 or (ci >= 0 and ci <= grid.cells and cj >= 0 and cj <= grid.cells):
                    has_children = 1
                    child = wp.int32(0)
                    child_local = wp.int32(0)  # the child's (i, j) on its own face: where face 0 keeps its α
                    if grid.planar != 0 or (ci > 0 and ci < grid.cells and cj > 0 and cj < grid.cells):
                        child_local = ci * grid.n + cj
                        child = base + child_local
                    else:
                        child = point_entry(cube_point(face, ci, cj, grid.cells), grid.cells, grid.n)
                        child_local = child % nn
                    q = params.values[child]
                    e = wp.max(e, wp.float64(q[0]))
                    if shapes != 0 and q[0] >= wp.float32(0.0):  # (a child all padding never refines: no radius)
                        c = bounds.to_vec3d(grid.positions[child])
                        r = wp.max(r, wp.length(v - c) + wp.float64(q[1]))
                    if grid.planar == 0:
                        dz = wp.abs(z_v - wp.float64(grid.heights[child]))
                        h = wp.max(h, dz + wp.float64(q[2]))
                        if with_angle != 0:
                            w_c = to_vec3d_i(local_point(ci, cj, grid.cells))
                            angle = direction_angle(w_v, w_c) + wp.float64(params.values[child_local][3])
                            alpha = wp.max(alpha, angle)
        # rounding e up keeps "e <= error" a true statement about the float64 error
        out = wp.vec4(wp.float32(e * (wp.float64(1.0) + ABSOLUTE_MARGIN)), 0.0, 0.0, 0.0)
        if has_children != 0 and shapes != 0:
            scale = (grid.radius + wp.abs(z_v)) * ABSOLUTE_MARGIN
            if grid.planar != 0:
                scale = wp.length(v) * ABSOLUTE_MARGIN
            out[1] = wp.float32(r * (wp.float64(1.0) + RELATIVE_MARGIN) + scale)
            out[2] = wp.float32(h * (wp.float64(1.0) + RELATIVE_MARGIN) + scale)
            if with_angle != 0:
                out[3] = wp.float32(alpha * (wp.float64(1.0) + RELATIVE_MARGIN) + ABSOLUTE_MARGIN)
        values_out[entry] = out


# ---------------------------------------------------------------------------------------------------------
# refinement, breadth-first, one count -> scan -> emit per level (§5.2)
# ---------------------------------------------------------------------------------------------------------


@wp.func
def unpack(corner: wp.int32) -> wp.vec2i:
    """Packed corner i << 16 | j -> (i, j)."""
    return wp.vec2i(corner >> 16, corner & 65535)


@wp.func
def pack(i: wp.int32, j: wp.int32) -> wp.int32:
    """(i, j) -> i << 16 | j."""
    return (i << 16) | j


@wp.func
def owns_refinement_node(cells: wp.int32, planar: wp.int32, face: wp.int32, a: wp.vec2i, b: wp.vec2i,
                         c: wp.vec2i) -> wp.int32:
    """1 when this triangle, rather than its diamond mate across the hypotenuse, emits the new vertex: the
    one whose apex has the smaller cube point (lexicographic); a triangle without a mate owns it."""
    mi = a[0] + b[0] - c[0]
    mj = a[1] + b[1] - c[1]
    if planar != 0:
        if mi < 0 or mi > cells or mj < 0 or mj > cells:
            return 1
        if pack(c[0], c[1]) < pack(mi, mj):
            return 1
        return 0
    if mi >= 0 and mi <= cells and mj >= 0 and mj <= cells:
        # both on this face: compare the rotated difference of the face-local points (one rotation)
        d = frame_rotate(face, wp.vec3i(2 * (c[1] - mj), 2 * (c[0] - mi), 0))
        for k in range(3):
            if d[k] < 0:
                return 1
            if d[k] > 0:
                return 0
        return 0
    own = cube_point(face, c[0], c[1], cells)
    mate = cube_point(face, mi, mj, cells)
    for k in range(3):
        if own[k] < mate[k]:
            return 1
        if own[k] > mate[k]:
            return 0
    return 0


@wp.kernel
def zero_corners(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    n: wp.int32,
    # outputs
    values_out: wp.array[wp.vec4],
):
    """One thread per face corner (count = 4 · faces): (e, r, h, α) = 0. The corners are the roots' vertices,
    nodes of no level; every other entry is written by its level's kernel (no memset of the whole array)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    k = first
    while k < last:
        corner = k & 3
        entry = (k >> 2) * n * n + (corner >> 1) * (n - 1) * n + (corner & 1) * (n - 1)
        values_out[entry] = wp.vec4(0.0, 0.0, 0.0, 0.0)
        k += 1


@wp.kernel
def copy_cone_angles(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    nn: wp.int32,
    # outputs
    values: wp.array[wp.vec4],
):
    """One thread per entry of face 0 (count = nn): its α to the same (i, j) on faces 1-5 (the cube's rotations
    map the faces onto each other with their hierarchy, so α depends on (i, j) alone)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    k = first
    while k < last:
        alpha = values[k][3]
        for f in range(1, 6):
            v = values[f * nn + k]
            v[3] = alpha
            values[f * nn + k] = v
        k += 1


@wp.func
def point_inside_view(planes: wp.array[wp.vec4d], p: wp.vec3d) -> wp.int32:
    """1 when p lies on the inner side of every plane: ⟨n, p⟩ + a > 0 for none of them, the same expression
    as :func:`stepterrain.kernels.bounds.triangle_outside_view`'s per-corner test (so a triangle whose three
    corners pass here is never found outside a plane there)."""
    k = wp.int32(0)
    while k < planes.shape[0]:
        plane = load(planes, k)
        if wp.dot(wp.vec3d(plane[0], plane[1], plane[2]), p) + plane[3] > wp.float64(0.0):
            return 0
        k += 1
    return 1


@wp.func
def refinement_entry(n: wp.int32, tri: wp.vec4i) -> wp.int32:
    """Entry of a triangle's refinement node, the midpoint of its hypotenuse (on its own face)."""
    a = unpack(tri[1])
    b = unpack(tri[2])
    return tri[0] * n * n + ((a[0] + b[0]) >> 1) * n + ((a[1] + b[1]) >> 1)


@wp.func
def needs_position(flags: wp.vec4i, error: wp.float64) -> wp.int32:
    """0 when the refinement needs no node position (no distance or clip metric, ε > 0): μ = e · factor."""
    if flags[1] == 0 and flags[2] == 0 and error > wp.float64(0.0):
        return 0
    return 1


@wp.func
def refine_decision(planar: wp.int32, eye: wp.vec3d, planes: wp.array[wp.vec4d], flags: wp.vec4i,
                    distance_scale: wp.float64, error: wp.float64, eye_length: wp.float64, eye_unit: wp.vec3d,
                    need_position: wp.int32, q: wp.vec4, p: wp.vec3, factor: wp.float64,
                    deep_inside: wp.int32) -> wp.int32:
    """Whether a triangle refines, from its refinement node's (e, r, h, α) ``q`` and position ``p``: 0 no, 1 yes,
    3 yes and the node's shape lies wholly inside the view. ``deep_inside``: an ancestor's shape lies wholly
    inside the view, so this node's clip test is skipped (the same decision)."""
    e = q[0]
    refine = wp.int32(0)
    if planar != 0 and e < wp.float32(0.0):
        return 0  # in a padded input's padding, with all its descendants
    if need_position == 0:
        # no view: μ = e (· user factor); skip the loads of the shape parameters (memory-bound)
        mu = factor
        if flags[0] != 0:
            mu = mu * wp.float64(e)
        if mu > error:
            refine = 1
    else:
        tested = flags
        if deep_inside != 0:
            tested[2] = 0
        refine = bounds.refine_node(eye, planes, tested, distance_scale, error, e, p, q[1], q[2], q[3], factor,
                                    eye_length, eye_unit)
        if refine == 2 or (refine != 0 and deep_inside != 0):
            refine = 3  # refines, its shape inside the view
    if refine == 0 and planar != 0 and wp.float64(e) >= wp.float64(0.5) * STRADDLE_ERROR:
        refine = 1  # a padded input's border: refine until inside or outside it, even out of view
    return refine


@wp.kernel
def count_refinement(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    params: NodeParameters,
    view: bounds.View,
    triangles: wp.array[wp.vec4i],
    can_refine: wp.int32,
    user_factors: wp.array[wp.float32],
    masks: wp.array[wp.int32],  # per triangle, or empty (not tracked): emit_refinement's masks; bit 3 set when
                                # an ancestor's shape lies wholly inside the view (so does this node's)
    # outputs
    counts_out: wp.array[wp.int32],  # 2·count + 2: refine flags, 0, owner flags, 0 (one scan for both)
    inside_out: wp.array[wp.int32],  # per refining triangle (or empty: not tracked): bit 0 set when its
                                     # refinement node lies inside every plane of the view (see
                                     # :func:`point_inside_view`), bit 1 when the node's shape does
):
    """One thread per triangle: 1 when it refines (its refinement node's metric exceeds the error), and
    whether it emits that node as a new vertex; with ``inside_out``, whether that node and its shape lie in
    the view. A triangle whose mask says an ancestor's shape lies inside the view skips the clip test (its
    node's shape is nested in that one: the same decision)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    tracked = inside_out.shape[0] > 0
    need_position = needs_position(view.flags, view.error)
    # software pipelining: the scattered loads of triangle t + 1's node (q, p) are issued before triangle t's
    # metric runs, so the memory latency overlaps the arithmetic (the loop is latency-bound otherwise)
    q_next = wp.vec4(0.0, 0.0, 0.0, 0.0)
    p_next = wp.vec3(0.0, 0.0, 0.0)
    if can_refine != 0 and first < last:
        q_next = load(params.values, refinement_entry(grid.n, load(triangles, first)))
        if need_position != 0:
            p_next = load(grid.positions, refinement_entry(grid.n, load(triangles, first)))
    t = first
    while t < last:
        tri = load(triangles, t)
        refine = wp.int32(0)
        owner = wp.int32(0)
        q = q_next
        p = p_next
        if can_refine != 0:
            if t + PREFETCH_AHEAD < count:
                m_ahead = refinement_entry(grid.n, load(triangles, t + PREFETCH_AHEAD))
                prefetch(params.values, m_ahead, 0)
                if need_position != 0:
                    prefetch(grid.positions, m_ahead, 0)
            if t + 1 < last:
                m_next = refinement_entry(grid.n, load(triangles, t + 1))
                q_next = load(params.values, m_next)
                if need_position != 0:
                    p_next = load(grid.positions, m_next)
            a = unpack(tri[1])
            b = unpack(tri[2])
            factor = wp.float64(1.0)
            if user_factors.shape[0] > 0:
                factor = wp.float64(load(user_factors, t))
            deep_inside = wp.int32(0)
            if tracked:
                if (load(masks, t) & 8) != 0:
                    deep_inside = 1
            refine = refine_decision(grid.planar, view.eye, view.planes, view.flags, view.distance_scale, view.error,
                                     view.eye_length, view.eye_unit, need_position, q, p, factor, deep_inside)
            if refine != 0:
                owner = owns_refinement_node(grid.cells, grid.planar, tri[0], a, b, unpack(tri[3]))
                if tracked:
                    store(inside_out, t, node_inside_flags(refine, view.planes, p))
                refine = 1
        store(counts_out, t, refine)
        store(counts_out, count + 1 + t, owner)
        t += 1
    if first == 0:
        store(counts_out, count, 0)
        store(counts_out, 2 * count + 1, 0)


@wp.func
def node_active(values: wp.array[wp.vec4], n: wp.int32, use_geometric: wp.int32, error: wp.float64, i: wp.int32,
                j: wp.int32) -> wp.int32:
    """Planar, no view: 1 when the triangles whose refinement node is (i, j) refine (μ = e > ε, or a padded
    input's border, as in :func:`refine_decision`); 0 when (i, j) is no grid node (a half-integer midpoint is
    passed as -1)."""
    if i < 0 or j < 0:
        return 0
    e = wp.float64(load(values, i * n + j)[0])
    if e < wp.float64(0.0):
        return 0  # in a padded input's padding (see PADDING_ERROR)
    mu = wp.float64(1.0)
    if use_geometric != 0:
        mu = e
    if mu > error or e >= wp.float64(0.5) * STRADDLE_ERROR:  # an error >= STRADDLE_ERROR kept the padding
        return 1
    return 0


@wp.func
def node_hypotenuse(i: wp.int32, j: wp.int32) -> wp.vec2i:
    """(di, dj) from node (i, j) to one end of the hypotenuse of its diamond (:func:`hypotenuse_offset` of its
    kind and spacing); (0, 0) for the four corners of the grid, which refine nothing."""
    bits = i | j
    if bits == 0:
        return wp.vec2i(0, 0)
    s = bits & (-bits)  # the largest power of two dividing both i and j
    if (i & s) != 0 and (j & s) != 0:  # diagonal node: the centre of a 2s square
        if ((i ^ j) & (2 * s)) == 0:  # kind 0: ((i / s) >> 1) + ((j / s) >> 1) even
            return wp.vec2i(s, s)
        return wp.vec2i(s, -s)
    if (i & s) != 0:  # axis node, hypotenuse along i
        return wp.vec2i(s, 0)
    return wp.vec2i(0, s)


@wp.func
def leaf_child(grid: CubeSphereGrid, values: wp.array[wp.vec4], use_geometric: wp.int32, error: wp.float64,
               c: wp.vec2i, a: wp.vec2i) -> wp.int32:
    """1 when the child (c, a, m) of a refining triangle is a leaf: its refinement node mid(c, a) is no node
    (the finest level) or does not refine."""
    mid = leg_midpoint(c, a)
    return 1 - node_active(values, grid.n, use_geometric, error, mid[0], mid[1])


@wp.func
def ccw_leaf(x: wp.vec2i, y: wp.vec2i, z: wp.vec2i) -> wp.vec4i:
    """Leaf (0, x, y, z) packed, with the roots' winding (negative (i, j) area, counter-clockwise from +z)."""
    area = (y[0] - x[0]) * (z[1] - x[1]) - (y[1] - x[1]) * (z[0] - x[0])
    if area > 0:
        return wp.vec4i(0, pack(y[0], y[1]), pack(x[0], x[1]), pack(z[0], z[1]))
    return wp.vec4i(0, pack(x[0], x[1]), pack(y[0], y[1]), pack(z[0], z[1]))


@wp.func
def node_leaves(grid: CubeSphereGrid, values: wp.array[wp.vec4], use_geometric: wp.int32, error: wp.float64,
                i: wp.int32, j: wp.int32, hyp: wp.vec2i, active: wp.int32, emit: wp.int32,
                leaves_out: wp.array[wp.vec4i], at: wp.int32) -> wp.int32:
    """Planar, no view: the leaf triangles node (i, j) accounts for, counted (emit 0) or written from ``at``.

    A refining node (every triangle of its diamond refines, by saturation all of them exist) owns the children
    of its diamond's triangles that are leaves; the centre, when it does not refine, owns the two roots.
    ``hyp`` and ``active``: :func:`node_hypotenuse` and :func:`node_active` of the node (not a corner)."""
    m = wp.vec2i(i, j)
    a = wp.vec2i(i + hyp[0], j + hyp[1])
    b = wp.vec2i(i - hyp[0], j - hyp[1])
    count = wp.int32(0)
    if active == 0:
        if 2 * i == grid.cells and 2 * j == grid.cells:  # the grid's centre: the roots are leaves
            if emit != 0:
                store(leaves_out, at, ccw_leaf(a, b, wp.vec2i(i + hyp[1], j - hyp[0])))
                store(leaves_out, at + 1, ccw_leaf(a, b, wp.vec2i(i - hyp[1], j + hyp[0])))
            return 2
        return 0
    for side in range(2):
        sign = 1 - 2 * side
        c = wp.vec2i(i + sign * hyp[1], j - sign * hyp[0])
        if in_grid(grid, c[0], c[1]) != 0:
            if leaf_child(grid, values, use_geometric, error, c, a) != 0:
                if emit != 0:
                    store(leaves_out, at + count, ccw_leaf(c, a, m))
                count += 1
            if leaf_child(grid, values, use_geometric, error, b, c) != 0:
                if emit != 0:
                    store(leaves_out, at + count, ccw_leaf(b, c, m))
                count += 1
    return count


#: Per-level counters of :func:`count_levels` (levels = 2 log2 N <= 30 with corners packed in 16 bits).
vec32i = wp.types.vector(length=32, dtype=wp.int32)


@wp.func
def refined_node_level(cells: wp.int32, i: wp.int32, j: wp.int32) -> wp.vec2i:
    """(level, triangles) that refined node (i, j) adds to a planar refinement's counts: its diamond's triangles
    (2, or 1 on the grid's border) each give two triangles one level below its depth."""
    hyp = node_hypotenuse(i, j)
    size = wp.max(wp.abs(hyp[0]), wp.abs(hyp[1]))
    depth = wp.int32(0)
    while (cells >> (depth + 1)) > size:
        depth += 1
    depth = 2 * depth
    sides = wp.int32(2)
    if hyp[0] == 0 or hyp[1] == 0:
        depth += 1
        across = i
        if hyp[0] != 0:
            across = j
        if across == 0 or across == cells:
            sides = 1
    return wp.vec2i(depth + 1, 2 * sides)


@wp.kernel
def count_levels(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,  # large: a few threads, each with its own row of counters (no atomics; Warp's CPU ones are not)
    cells: wp.int32,
    entries: wp.array[wp.int32],  # the refined nodes (new vertices) of a planar refinement, entry = i·n + j
    # outputs
    level_counts: wp.array2d[wp.int32],  # (threads, 32): per thread, triangles per level from its entries
):
    """Triangles per level of a planar refinement from its refined nodes (:func:`refined_node_level`)."""
    t = wp.tid() + thread_offset
    first = t * chunk
    last = wp.min(first + chunk, count)
    acc = vec32i()
    n = cells + 1
    k = first
    while k < last:
        entry = load(entries, k)
        i = entry / n
        j = entry - i * n
        level = refined_node_level(cells, i, j)
        acc[level[0]] = acc[level[0]] + level[1]
        k += 1
    for d in range(32):
        level_counts[t, d] = acc[d]


@wp.kernel
def count_padding_levels(
    thread_offset: wp.int32,
    count: wp.int32,  # the grid's rows
    chunk: wp.int32,  # rows per thread (a few threads, each with its own row of counters)
    grid: CubeSphereGrid,
    params: NodeParameters,
    use_geometric: wp.int32,
    error: wp.float64,
    # outputs
    level_counts: wp.array2d[wp.int32],  # (threads, 32): per thread, triangles per level
):
    """:func:`count_levels` of the refined nodes in a padded input's padding (beyond its last row or column),
    which :func:`count_node_leaves` leaves out: the breadth-first refinement visits their triangles too. Only
    the nodes that :func:`padding_tier` computes can refine; the rest are stepped over (a row at a time, or
    from column j to j + lowest_bit(j), past nodes whose spacing, at most their lowest bit, puts them beyond
    :data:`PADDING_REACH`), so the pass costs about the padding's border, not its area."""
    t = wp.tid() + thread_offset
    first = t * chunk
    last = wp.min(first + chunk, count)
    acc = vec32i()
    last_i = grid.rows_valid - 1
    last_j = grid.cols_valid - 1
    i = first
    while i < last:
        if i > last_i and i - last_i >= PADDING_REACH * lowest_bit(i):
            i += 1  # every node of the row has a spacing of at most lowest_bit(i): all beyond reach
            continue
        j = wp.int32(0)
        if i <= last_i:
            j = last_j + 1
        while j < grid.n:
            hyp = node_hypotenuse(i, j)
            s = wp.max(wp.abs(hyp[0]), wp.abs(hyp[1]))
            if s > 0 and padding_tier(grid, i, j, s) == 0:
                if node_active(params.values, grid.n, use_geometric, error, i, j) != 0:
                    level = refined_node_level(grid.cells, i, j)
                    acc[level[0]] = acc[level[0]] + level[1]
            if j > last_j and j - last_j >= PADDING_REACH * lowest_bit(j):
                j += lowest_bit(j)  # the columns before j + lowest_bit(j) have smaller spacings, and lie further out
            else:
                j += 1
        i += 1
    for d in range(32):
        level_counts[t, d] = acc[d]


@wp.kernel
def count_node_leaves(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    params: NodeParameters,
    use_geometric: wp.int32,
    error: wp.float64,
    no_leaves: wp.array[wp.vec4i],  # empty (the shared counting / emitting function writes nothing here)
    # outputs
    counts_out: wp.array[wp.int32],  # 2·count + 2: leaves per node, 0, 1 per refining node (a vertex), 0
):
    """Planar without a view: the breadth-first refinement in one pass over the nodes (memory order). With μ = e
    a node's decision does not depend on the path to it, and saturation makes every triangle of a refining
    node's diamond exist, so each node counts its leaves and whether it becomes a vertex on its own.

    The nodes of the input's rectangle only (count = rows_valid · cols_valid, slot k = i · cols_valid + j): a
    node beyond it (in a padded input's padding) is a corner of no triangle the mesh keeps, nor are its leaves."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    if first >= last:
        return
    cols = grid.cols_valid
    i = first / cols
    j = first - i * cols
    entry = first
    while entry < last:
        leaves = wp.int32(0)
        vertex = wp.int32(0)
        hyp = node_hypotenuse(i, j)
        if hyp[0] != 0 or hyp[1] != 0:
            vertex = node_active(params.values, grid.n, use_geometric, error, i, j)
            if vertex != 0 or (2 * i == grid.cells and 2 * j == grid.cells):
                leaves = node_leaves(grid, params.values, use_geometric, error, i, j, hyp, vertex, 0, no_leaves, 0)
        store(counts_out, entry, leaves)
        store(counts_out, count + 1 + entry, vertex)
        j += 1
        if j == cols:
            j = 0
            i += 1
        entry += 1
    if first == 0:
        store(counts_out, count, 0)
        store(counts_out, 2 * count + 1, 0)


@wp.kernel
def emit_node_leaves(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    params: NodeParameters,
    use_geometric: wp.int32,
    error: wp.float64,
    counts: wp.array[wp.int32],  # of count_node_leaves
    offsets: wp.array[wp.int32],  # their exclusive scan
    # outputs
    leaves_out: wp.array[wp.vec4i],
    vertex_entries_out: wp.array[wp.int32],
):
    """One pass over the nodes (those of :func:`count_node_leaves`): each node's leaves from its offset, and its
    entry when it becomes a vertex."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    if first >= last:
        return
    cols = grid.cols_valid
    i = first / cols
    j = first - i * cols
    slot = first
    while slot < last:
        vertex = load(counts, count + 1 + slot)
        if load(counts, slot) != 0:
            node_leaves(grid, params.values, use_geometric, error, i, j, node_hypotenuse(i, j), vertex, 1, leaves_out,
                        load(offsets, slot))
        if vertex != 0:
            store(vertex_entries_out, load(offsets, count + 1 + slot) - load(offsets, count + 1), i * grid.n + j)
        j += 1
        if j == cols:
            j = 0
            i += 1
        slot += 1


@wp.func
def node_inside_flags(refine: wp.int32, planes: wp.array[wp.vec4d], p: wp.vec3) -> wp.int32:
    """A refining node's inside flags (see count_refinement's ``inside_out``): 3 when refine_decision found its
    shape wholly inside the view (so is the node), else bit 0 when the node lies inside every plane."""
    if refine == 3:
        return 3
    return point_inside_view(planes, bounds.to_vec3d(p))


@wp.func
def child_masks(mask: wp.int32, node_inside: wp.int32) -> wp.vec2i:
    """The corner masks of children (c, a, m) and (b, c, m) of a triangle with corner mask ``mask`` whose node m
    has the inside flags ``node_inside``: bit k - 1 a corner known inside; bit 3, an ancestor's shape inside."""
    node = ((node_inside & 1) << 2) | (mask & 8) | ((node_inside & 2) << 2)  # m's bit, deep inside
    return wp.vec2i(((mask >> 2) & 1) | ((mask & 1) << 1) | node, ((mask >> 1) & 3) | node)


@wp.func
def child_triangle(tri: wp.vec4i, mid: wp.int32, k: wp.int32) -> wp.vec4i:
    """Child k of triangle (face, a, b, c) with its packed refinement node ``mid`` = m: (c, a, m) or (b, c, m)."""
    if k == 0:
        return wp.vec4i(tri[0], tri[3], tri[1], mid)
    return wp.vec4i(tri[0], tri[2], tri[3], mid)


@wp.kernel
def emit_refinement(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    triangles: wp.array[wp.vec4i],
    counts: wp.array[wp.int32],  # of count_refinement: refine flags, 0, owner flags, 0
    offsets: wp.array[wp.int32],  # their exclusive scan: offsets[count + 1] = the number of refined triangles
    masks: wp.array[wp.int32],  # per triangle, or all three empty (not tracked): its corners known inside
    inside: wp.array[wp.int32],  # of count_refinement: its refinement node lies inside the view
    # outputs
    children_out: wp.array[wp.vec4i],
    leaves_out: wp.array[wp.vec4i],
    vertex_entries_out: wp.array[wp.int32],
    child_masks_out: wp.array[wp.int32],
    leaf_masks_out: wp.array[wp.int32],
):
    """One thread per triangle: its two children (c, a, m), (b, c, m) to the next level, or itself to the
    leaves; the owner of a new refinement node writes its canonical entry. With ``masks``, the corner masks
    follow the corners: bit k - 1 set when corner ``tri[k]`` is known to lie inside the view (a corner of a
    triangle is a corner of its parent or the parent's refinement node, whose test count_refinement made);
    bit 3, "an ancestor's shape lies inside the view", passes to every descendant."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    track = masks.shape[0] > 0
    t = first
    while t < last:
        tri = load(triangles, t)
        if load(counts, t) != 0:
            a = unpack(tri[1])
            b = unpack(tri[2])
            mi = (a[0] + b[0]) >> 1
            mj = (a[1] + b[1]) >> 1
            m = pack(mi, mj)
            k = 2 * load(offsets, t)
            store(children_out, k, child_triangle(tri, m, 0))
            store(children_out, k + 1, child_triangle(tri, m, 1))
            if track:
                pair = child_masks(load(masks, t), load(inside, t))
                store(child_masks_out, k, pair[0])  # (c, a, m)
                store(child_masks_out, k + 1, pair[1])  # (b, c, m)
            if load(counts, count + 1 + t) != 0:
                store(vertex_entries_out, load(offsets, count + 1 + t) - load(offsets, count + 1),
                      node_entry(grid.cells, grid.planar, tri[0], mi, mj))
        else:
            slot = t - load(offsets, t)
            store(leaves_out, slot, tri)
            if track:
                store(leaf_masks_out, slot, load(masks, t))
        t += 1


@wp.kernel
def refine_levels(
    thread_offset: wp.int32,
    grid: CubeSphereGrid,
    params: NodeParameters,
    view: bounds.View,
    roots: wp.array[wp.vec4i],
    root_masks: wp.array[wp.int32],  # the roots' corner masks when tracked, or empty: nothing known (0)
    first_root: wp.int32,  # the roots are roots[first_root : first_root + root_count]
    root_count: wp.int32,
    part: wp.int32,  # which part of each output this launch writes (several launches share the arrays)
    levels: wp.int32,  # the deepest level: its triangles do not refine
    capacity: wp.int32,  # levels of at most this many triangles are refined here
    room: wp.int32,  # while their leaves and new vertices fit in this many slots
    # outputs, each in parts of the size given (the part ``part`` written here)
    level_out: wp.array[wp.vec4i],  # 4·capacity: two halves, one level's triangles and the next's in turn
    level_masks_out: wp.array[wp.int32],  # 4·capacity, the triangles' corner masks; or empty: not tracked
    leaves_out: wp.array[wp.vec4i],  # room
    leaf_masks_out: wp.array[wp.int32],  # room, the leaves' corner masks (for the cull); or empty
    vertex_entries_out: wp.array[wp.int32],  # room
    per_level_out: wp.array[wp.int32],  # levels + 1: triangles per level refined here
    totals_out: wp.array[wp.int32],  # 6: leaves, new vertices, triangles of the next level, its depth, its start
                                     # (in level_out), leaves whose mask is 0 (no corner known inside the view)
    marks_out: wp.array[wp.vec2i],  # levels + 2, or empty: (leaves, new vertices) written before each level
                                    # and after the last (where each level's run of them starts and ends)
):
    """The CPU's levels in one thread and one launch: :func:`count_refinement` and :func:`emit_refinement` of
    every level from the roots while a level holds at most ``capacity`` triangles and its leaves and new
    vertices fit in ``room``, appending children, leaves and new vertices in the order the level passes write
    them (the same mesh). A level pass costs a few launches, a scan and a host read of its total, and a second
    walk over its triangles to emit them; here a level costs one walk. With ``level_masks_out`` the corner
    masks are tracked as :func:`emit_refinement` tracks them (from the roots on, nothing known there), the
    refinement loads are software-pipelined as in :func:`count_refinement`.

    The roots may be any level's triangles (with their masks): a contiguous range of a level is a subtree
    forest whose triangles come, on every later level, as one contiguous run in the level passes' order, so
    launches over consecutive ranges, their runs interleaved level by level (``marks_out``), give the same mesh
    as one launch over the whole level."""
    if wp.tid() + thread_offset != 0:
        return
    need_position = needs_position(view.flags, view.error)
    track = level_masks_out.shape[0] > 0
    keep_leaf_masks = leaf_masks_out.shape[0] > 0
    n_cur = root_count
    cur = part * 4 * capacity  # start of the current level's half of level_out
    nxt = cur + 2 * capacity
    base = part * room  # of leaves_out, leaf_masks_out and vertex_entries_out
    level_base = part * (levels + 1)
    marks_base = part * (levels + 2)
    k = wp.int32(0)
    while k < n_cur:
        store(level_out, cur + k, load(roots, first_root + k))
        if track:
            root_mask = wp.int32(0)
            if root_masks.shape[0] > 0:
                root_mask = load(root_masks, first_root + k)
            store(level_masks_out, cur + k, root_mask)
        k += 1
    keep_marks = marks_out.shape[0] > 0
    n_leaves = wp.int32(0)
    n_unknown = wp.int32(0)
    n_entries = wp.int32(0)
    depth = wp.int32(0)
    while depth <= levels and n_cur > 0 and n_cur <= capacity and n_leaves + n_cur <= room \
            and n_entries + n_cur <= room:
        store(per_level_out, level_base + depth, n_cur)
        if keep_marks:
            store(marks_out, marks_base + depth, wp.vec2i(n_leaves, n_entries))
        can_refine = depth < levels
        q_next = wp.vec4(0.0, 0.0, 0.0, 0.0)
        p_next = wp.vec3(0.0, 0.0, 0.0)
        if can_refine:
            m0 = refinement_entry(grid.n, load(level_out, cur))
            q_next = load(params.values, m0)
            if need_position != 0:
                p_next = load(grid.positions, m0)
        n_next = wp.int32(0)
        t = wp.int32(0)
        while t < n_cur:
            tri = load(level_out, cur + t)
            q = q_next
            p = p_next
            mask = wp.int32(0)
            if track:
                mask = load(level_masks_out, cur + t)
            refine = wp.int32(0)
            if can_refine:
                if t + PREFETCH_AHEAD < n_cur:
                    m_ahead = refinement_entry(grid.n, load(level_out, cur + t + PREFETCH_AHEAD))
                    prefetch(params.values, m_ahead, 0)
                    if need_position != 0:
                        prefetch(grid.positions, m_ahead, 0)
                if t + 1 < n_cur:
                    m_next = refinement_entry(grid.n, load(level_out, cur + t + 1))
                    q_next = load(params.values, m_next)
                    if need_position != 0:
                        p_next = load(grid.positions, m_next)
                deep_inside = wp.int32(0)
                if (mask & 8) != 0:
                    deep_inside = 1
                refine = refine_decision(grid.planar, view.eye, view.planes, view.flags, view.distance_scale,
                                         view.error, view.eye_length, view.eye_unit, need_position, q, p,
                                         wp.float64(1.0), deep_inside)
            if refine != 0:
                a = unpack(tri[1])
                b = unpack(tri[2])
                mi = (a[0] + b[0]) >> 1
                mj = (a[1] + b[1]) >> 1
                mid = pack(mi, mj)
                store(level_out, nxt + n_next, child_triangle(tri, mid, 0))
                store(level_out, nxt + n_next + 1, child_triangle(tri, mid, 1))
                if track:  # emit_refinement's masks, with count_refinement's inside flags
                    pair = child_masks(mask, node_inside_flags(refine, view.planes, p))
                    store(level_masks_out, nxt + n_next, pair[0])
                    store(level_masks_out, nxt + n_next + 1, pair[1])
                n_next += 2
                if owns_refinement_node(grid.cells, grid.planar, tri[0], a, b, unpack(tri[3])) != 0:
                    store(vertex_entries_out, base + n_entries, node_entry(grid.cells, grid.planar, tri[0], mi, mj))
                    n_entries += 1
            else:
                store(leaves_out, base + n_leaves, tri)
                if keep_leaf_masks:
                    store(leaf_masks_out, base + n_leaves, mask)
                if mask == 0:
                    n_unknown += 1
                n_leaves += 1
            t += 1
        swap = cur
        cur = nxt
        nxt = swap
        n_cur = n_next
        depth += 1
    if keep_marks:  # the levels it did not reach: no triangles, empty runs
        d = depth
        while d <= levels + 1:
            store(marks_out, marks_base + d, wp.vec2i(n_leaves, n_entries))
            if d <= levels:
                store(per_level_out, level_base + d, 0)
            d += 1
    store(totals_out, part * 6 + 0, n_leaves)
    store(totals_out, part * 6 + 1, n_entries)
    store(totals_out, part * 6 + 2, n_cur)
    store(totals_out, part * 6 + 3, depth)
    store(totals_out, part * 6 + 4, cur)
    store(totals_out, part * 6 + 5, n_unknown)


@wp.kernel
def copy_runs(
    thread_offset: wp.int32,
    parts: wp.int32,  # refine_levels launches, over consecutive ranges of one level
    slots: wp.int32,  # marks per part (its levels + 2)
    room: wp.int32,  # leaves and new vertices per part
    leaves_at: wp.int32,  # where the first part's first leaf goes in leaves_out
    entries_at: wp.int32,  # where its first new vertex goes in entries_out
    marks: wp.array[wp.vec2i],  # refine_levels' marks_out, with the levels a part did not reach filled
    leaves: wp.array[wp.vec4i],
    leaf_masks: wp.array[wp.int32],  # or empty (then leaf_masks_out too)
    entries: wp.array[wp.int32],
    # outputs
    leaves_out: wp.array[wp.vec4i],
    leaf_masks_out: wp.array[wp.int32],
    entries_out: wp.array[wp.int32],
):
    """One thread per part, level and kind (leaves with their masks, or new vertices), parts slowest: copies
    that part's run of that level where one launch over the whole level would have written it (level by level,
    part by part), finding the place by summing the runs before it."""
    t = wp.tid() + thread_offset
    run_levels = slots - 1  # a part's levels: each has a run of leaves and one of new vertices (maybe empty)
    g = t / (2 * run_levels)
    d = (t / 2) - g * run_levels
    kind = t - (t / 2) * 2
    start = load(marks, g * slots + d)[kind]
    length = load(marks, g * slots + d + 1)[kind] - start
    if length == 0:
        return
    dest = leaves_at
    if kind == 1:
        dest = entries_at
    e = wp.int32(0)
    while e <= d:  # the runs before it: every part's at the levels above, and the earlier parts' at its level
        h = wp.int32(0)
        while h < parts and (e < d or h < g):
            dest += load(marks, h * slots + e + 1)[kind] - load(marks, h * slots + e)[kind]
            h += 1
        e += 1
    k = wp.int32(0)
    source = g * room + start
    if kind == 0:
        masks = leaf_masks.shape[0] > 0
        while k < length:
            store(leaves_out, dest + k, load(leaves, source + k))
            if masks:
                store(leaf_masks_out, dest + k, load(leaf_masks, source + k))
            k += 1
    else:
        while k < length:
            store(entries_out, dest + k, load(entries, source + k))
            k += 1


@wp.kernel
def emit_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    entries: wp.array[wp.int32],
    # outputs
    vertex_id_out: wp.array[wp.int32],
    vertices_out: wp.array[wp.vec3d],
):
    """One thread per output vertex: its float64 position, and its index in the entry -> vertex table."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    k = first
    while k < last:
        if k + PREFETCH_AHEAD < count:
            ahead = load(entries, k + PREFETCH_AHEAD)
            prefetch(vertex_id_out, ahead, 1)
            prefetch(grid.heights, ahead, 0)
        entry = load(entries, k)
        store(vertex_id_out, entry, k)
        store(vertices_out, k, entry_position64(grid, entry))
        k += 1


@wp.func
def corner_entry(n: wp.int32, face: wp.int32, corner: wp.int32) -> wp.int32:
    """Entry of a packed corner on ``face`` (its copy there, not the canonical one of a seam node)."""
    ij = unpack(corner)
    return face * n * n + ij[0] * n + ij[1]


@wp.func
def corner_position(positions: wp.array[wp.vec3], n: wp.int32, face: wp.int32, corner: wp.int32) -> wp.vec3d:
    """float64 copy of the float32 position of a packed corner."""
    return bounds.to_vec3d(load(positions, corner_entry(n, face, corner)))


@wp.kernel
def count_kept_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    view: bounds.View,
    cull: wp.int32,
    leaves: wp.array[wp.vec4i],
    masks: wp.array[wp.int32],  # per leaf, or empty: corners known inside the view (emit_refinement)
    # outputs
    counts_out: wp.array[wp.int32],
):
    """One thread per leaf triangle: 0 when culling is on and the triangle lies wholly outside a plane, or
    when it lies in the padding of a planar input. A leaf with a corner known to lie inside every plane is
    kept without loading its corners: lying wholly outside a plane needs all three corners outside it."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    t = first
    while t < last:
        if cull != 0 and t + PREFETCH_AHEAD < count:
            known = wp.int32(0)  # a corner known inside: kept without loading its corners
            if masks.shape[0] > 0:
                known = load(masks, t + PREFETCH_AHEAD)
            if known == 0:
                ahead = load(leaves, t + PREFETCH_AHEAD)
                for c in range(1, 4):
                    prefetch(grid.positions, corner_entry(grid.n, ahead[0], ahead[c]), 0)
        keep = wp.int32(1)
        tri = load(leaves, t)
        if grid.planar != 0 and (grid.rows_valid < grid.n or grid.cols_valid < grid.n):
            lo = wp.min(unpack(tri[1]), wp.min(unpack(tri[2]), unpack(tri[3])))
            if lo[0] >= grid.rows_valid - 1 or lo[1] >= grid.cols_valid - 1:
                keep = 0  # in the padding
        known_inside = wp.int32(0)
        if masks.shape[0] > 0:
            if load(masks, t) != 0:
                known_inside = 1
        if cull != 0 and keep != 0 and known_inside == 0:
            if bounds.triangle_outside_view(view.planes, corner_position(grid.positions, grid.n, tri[0], tri[1]),
                                            corner_position(grid.positions, grid.n, tri[0], tri[2]),
                                            corner_position(grid.positions, grid.n, tri[0], tri[3])) != 0:
                keep = 0
        store(counts_out, t, keep)
        t += 1


@wp.kernel
def count_hanging_edges(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    cells: wp.int32,
    planar: wp.int32,
    leaves: wp.array[wp.vec4i],
    vertex_id: wp.array[wp.int32],  # per canonical entry: its vertex, -1 for a node with none
    # outputs
    hanging_out: wp.array[wp.int32],  # (1,): leaf edges whose midpoint is a vertex (atomic)
):
    """One thread per leaf: its edges whose midpoint node has a vertex. The first node inserted inside an edge of
    the bisection is its midpoint, so the leaves tile without a hanging node iff no leaf edge's midpoint is a vertex
    (on the sphere, or the padded square: a midpoint on the border has its vertex only when split there too)."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    t = first
    while t < last:
        tri = load(leaves, t)
        hanging = wp.int32(0)
        for e in range(3):
            p = unpack(tri[1 + e])
            q = unpack(tri[1 + (e + 1) % 3])
            si = p[0] + q[0]
            sj = p[1] + q[1]
            if (si & 1) == 0 and (sj & 1) == 0:
                if load(vertex_id, node_entry(cells, planar, tri[0], si >> 1, sj >> 1)) >= 0:
                    hanging += 1
        if hanging > 0:
            wp.atomic_add(hanging_out, 0, hanging)
        t += 1


@wp.func
def canonical_corner_entry(cells: wp.int32, planar: wp.int32, face: wp.int32, corner: wp.int32) -> wp.int32:
    """Canonical entry of a packed corner (a seam node's one entry, see :func:`node_entry`)."""
    ij = unpack(corner)
    return node_entry(cells, planar, face, ij[0], ij[1])


@wp.func
def corner_vertex(cells: wp.int32, planar: wp.int32, vertex_id: wp.array[wp.int32], face: wp.int32,
                  corner: wp.int32) -> wp.int32:
    """Output vertex of a packed corner (through its canonical entry)."""
    return load(vertex_id, canonical_corner_entry(cells, planar, face, corner))


@wp.kernel
def emit_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    grid: CubeSphereGrid,
    leaves: wp.array[wp.vec4i],
    keep: wp.array[wp.int32],  # count_kept_faces' flags, or empty: every leaf kept
    offsets: wp.array[wp.int32],  # their exclusive scan (or empty)
    vertex_id: wp.array[wp.int32],
    # outputs
    faces_out: wp.array[wp.vec3i],  # or empty: then wide_out
    wide_out: wp.array[vec3l],  # or empty: the faces as int64, trimesh's dtype, when they are final (no cull)
    face_index_out: wp.array[wp.int32],
):
    """One thread per leaf triangle: its kept face as output vertex indices, and its cube face."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    wide = wide_out.shape[0] > 0
    every = keep.shape[0] == 0
    t = first
    while t < last:
        if t + PREFETCH_AHEAD < count:
            ahead = load(leaves, t + PREFETCH_AHEAD)
            for c in range(1, 4):
                prefetch(vertex_id, canonical_corner_entry(grid.cells, grid.planar, ahead[0], ahead[c]), 0)
        if every or load(keep, t) != 0:
            tri = load(leaves, t)
            k = t
            if not every:
                k = load(offsets, t)
            a = corner_vertex(grid.cells, grid.planar, vertex_id, tri[0], tri[1])
            b = corner_vertex(grid.cells, grid.planar, vertex_id, tri[0], tri[2])
            c = corner_vertex(grid.cells, grid.planar, vertex_id, tri[0], tri[3])
            if wide:
                store(wide_out, k, vec3l(wp.int64(a), wp.int64(b), wp.int64(c)))
            else:
                store(faces_out, k, wp.vec3i(a, b, c))
            store(face_index_out, k, tri[0])
        t += 1


@wp.kernel
def emit_used_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    vertices: wp.array[wp.vec3d],
    entries: wp.array[wp.int32],
    used: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    # outputs
    vertices_out: wp.array[wp.vec3d],
    entries_out: wp.array[wp.int32],
):
    """One thread per vertex: copy it to its compacted slot when a face uses it."""
    first = (wp.tid() + thread_offset) * chunk
    last = wp.min(first + chunk, count)
    k = first
    while k < last:
        if load(used, k) != 0:
            store(vertices_out, load(offsets, k), load(vertices, k))
            store(entries_out, load(offsets, k), load(entries, k))
        k += 1
