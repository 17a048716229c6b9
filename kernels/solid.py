"""Warp kernels that close a stepped surface into a watertight solid (``stepterrain.mesh.close_solid``, behind
``stepped(..., solid=True)``: side skirts from the boundary down to a flat base). Paper 000 (Glander, Trapp &
Döllner 2010) steps the surface only and has no section on solids; this is stepterrain's own addition, for printing.

Everything here is integer bookkeeping over the surface's faces, count -> scan -> emit as elsewhere:

* a vertex -> corner table (CSR) without a sort: :func:`count_keys` counts the corners at each vertex (atomic adds),
  an exclusive scan gives each vertex its bucket, :func:`fill_corners` drops each corner, as its face's next and
  previous vertex, into its vertex's bucket by counting the bucket's end down to its start (atomic adds of -1: no
  cursor array; the order inside a bucket may differ between runs, only counts are read from it).
  :func:`fill_buckets` does the same for any int keys, through an atomic cursor.
* boundary edges: a half-edge (a, b) is on the boundary iff exactly one half-edge of the mesh has the undirected key
  {a, b}; :func:`is_boundary` counts them among the corners of a or b, whichever has fewer. :func:`count_boundary`
  flags them per face and counts them per thread, :func:`emit_boundary` writes them in face and corner order.
* fins (two walls back to back on the same four vertices): :func:`wall_quads` sorts each wall pair's four vertices,
  a CSR keyed by each quad's smallest vertex groups the candidates, :func:`find_fins` flags the repeated quads.
  A bucket of more than ``limit`` pairs (a fan of walls on one vertex: a scan of it per pair would be quadratic)
  is deferred: its pairs are bucketed again by a hash of the whole quad (:func:`hash_fin_keys`, MurmurHash3's mix;
  every other pair keeps a bucket of its own, so a stepped surface's pass is left as it was, its reads in the
  surface's order) and :func:`find_fins_hashed` scans those buckets, stopping at the first twin.
* columns (one base vertex each): :func:`last_wall_writes` and :func:`wall_pairs` join each wall's bottom and top
  through its vertical edges (a pair group: the vertices sharing a pair value). A column is the vertices of one pair
  group with the same (x, y, [fan]) bit for bit, so no sort is needed: the pair groups as buckets
  (:func:`count_keys`, :func:`fill_buckets`), :func:`column_leaders` finds each vertex's smallest fellow in its
  bucket, and a scan of the leaders and :func:`number_columns` number the columns in the order of their smallest
  vertex (the base vertices follow the surface's order). A pair group of more than ``limit`` vertices is deferred
  likewise: bucketed by a hash of (x, y, [fan], pair) (:func:`hash_column_keys`), each vertex's first fellow in its
  bucket is its column's representative (:func:`column_reps`, the same for the whole column however big) and an
  atomic min there its leader (:func:`deferred_leaders`): linear where a scan per vertex was quadratic.
  :func:`narrow_faces` turns the int64 faces into the kernels' int32 and finds their index range in the same pass.
* the closed mesh: :func:`emit_vertices` copies the surface's vertices and writes each column's base vertex,
  :func:`count_base_faces` and :func:`emit_faces` copy the faces and write the terraces flattened and reversed, but
  for those a column collapses to zero area (the skirts between them are few: numpy writes them).

Kernels take ``thread_offset, count, chunk`` first (``stepterrain._device.launch_chunked``). Faces are flat int32
arrays (3 per face); indices fit int32 (``close_solid`` checks).
"""

from __future__ import annotations

import warp as wp

from .memory import load, store

wp.set_module_options({"enable_backward": False})  # integer work only: no adjoints, nothing to contract

# MurmurHash3's 32-bit constants (as wp.uint32 constants: a literal above 2^31 would go through int32)
MURMUR_C1 = wp.constant(wp.uint32(0xCC9E2D51))
MURMUR_C2 = wp.constant(wp.uint32(0x1B873593))
MURMUR_N = wp.constant(wp.uint32(0xE6546B64))
MURMUR_F1 = wp.constant(wp.uint32(0x85EBCA6B))
MURMUR_F2 = wp.constant(wp.uint32(0xC2B2AE35))


@wp.kernel
def count_keys(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    keys: wp.array[wp.int32],
    # outputs
    counts_out: wp.array[wp.int32],
):
    """One element per item: add one to its key's count (``counts_out`` zeroed first)."""
    first = (wp.tid() + thread_offset) * chunk
    t = first
    last = wp.min(first + chunk, count)
    while t < last:
        wp.atomic_add(counts_out, load(keys, t), 1)
        t += 1


@wp.kernel
def fill_buckets(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    keys: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    # outputs
    cursor_out: wp.array[wp.int32],
    items_out: wp.array[wp.int32],
):
    """One element per item: write its index into its key's bucket (``offsets``: the exclusive scan of the key
    counts; ``cursor_out`` zeroed first)."""
    first = (wp.tid() + thread_offset) * chunk
    t = first
    last = wp.min(first + chunk, count)
    while t < last:
        k = load(keys, t)
        slot = wp.atomic_add(cursor_out, k, 1)
        items_out[load(offsets, k) + slot] = t
        t += 1


@wp.kernel
def fill_corners(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    # outputs
    ends_out: wp.array[wp.int32],
    items_out: wp.array[wp.vec2i],
):
    """One element per face: drop each corner into its vertex's bucket as (next vertex, previous vertex) of the
    face, from the bucket's end down. ``ends_out`` (n + 2) holds the exclusive scan of the corner counts per vertex
    (n + 2 of them, the last two 0) one place on: vertex v's bucket ends at ``ends_out[v + 1]``, which counts down
    to where it starts. After the pass v's bucket is ``items_out[ends_out[v + 1]:ends_out[v + 2]]``: no cursor
    array, and one read-modify-write a corner."""
    first = (wp.tid() + thread_offset) * chunk
    f = first
    last = wp.min(first + chunk, count)
    while f < last:
        a = load(faces, 3 * f)
        b = load(faces, 3 * f + 1)
        c = load(faces, 3 * f + 2)
        store(items_out, wp.atomic_add(ends_out, a + 1, -1) - 1, wp.vec2i(b, c))
        store(items_out, wp.atomic_add(ends_out, b + 1, -1) - 1, wp.vec2i(c, a))
        store(items_out, wp.atomic_add(ends_out, c + 1, -1) - 1, wp.vec2i(a, b))
        f += 1


@wp.func
def used_once(corners: wp.array[wp.vec2i], s: wp.int32, end: wp.int32, u: wp.int32, w: wp.int32) -> wp.int32:
    """1 where exactly one half-edge of the mesh has the undirected key {u, w}, counted among u's corners
    ``corners[s:end]`` (stops at the second), else 0: a corner whose next vertex is w starts (u, w), one whose
    previous vertex is w ends (w, u); a degenerate (u, u) is counted once, by its start. Branch-free counting."""
    back = wp.where(u != w, 1, 0)
    n = wp.int32(0)
    while s < end and n < 2:
        c = load(corners, s)
        n += wp.where(c[0] == w, 1, 0) + wp.where(c[1] == w, back, 0)
        s += 1
    return wp.where(n == 1, 1, 0)


@wp.func
def is_boundary(corners: wp.array[wp.vec2i], a: wp.int32, b: wp.int32, start_a: wp.int32, end_a: wp.int32,
                start_b: wp.int32, end_b: wp.int32) -> wp.int32:
    """:func:`used_once` of the half-edge (a, b), counted among the corners of a or b (``corners[start_a:end_a]``,
    ``corners[start_b:end_b]``), whichever has fewer (a fan's hub is never scanned once per spoke)."""
    if end_b - start_b < end_a - start_a:
        return used_once(corners, start_b, end_b, b, a)
    return used_once(corners, start_a, end_a, a, b)


@wp.kernel
def count_boundary(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    starts: wp.array[wp.int32],
    corners: wp.array[wp.vec2i],
    # outputs
    flags_out: wp.array[wp.int32],
    counts_out: wp.array[wp.int32],
):
    """One element per face: ``flags_out[f]`` has bit j set where the half-edge leaving corner j is a boundary edge
    (its undirected key used once); ``counts_out[thread]`` counts them over the thread's chunk. Vertex v's corners
    are ``corners[starts[v + 1]:starts[v + 2]]`` (:func:`fill_corners`' ``ends_out``); each of the face's three
    vertices' bucket is read once."""
    first = (wp.tid() + thread_offset) * chunk
    f = first
    last = wp.min(first + chunk, count)
    total = wp.int32(0)
    while f < last:
        a = load(faces, 3 * f)
        b = load(faces, 3 * f + 1)
        c = load(faces, 3 * f + 2)
        start_a = load(starts, a + 1)
        end_a = load(starts, a + 2)
        start_b = load(starts, b + 1)
        end_b = load(starts, b + 2)
        start_c = load(starts, c + 1)
        end_c = load(starts, c + 2)
        x = is_boundary(corners, a, b, start_a, end_a, start_b, end_b)
        y = is_boundary(corners, b, c, start_b, end_b, start_c, end_c)
        z = is_boundary(corners, c, a, start_c, end_c, start_a, end_a)
        total += x + y + z
        store(flags_out, f, x | (y << 1) | (z << 2))
        f += 1
    counts_out[wp.tid() + thread_offset] = total


@wp.kernel
def emit_boundary(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    flags: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    # outputs
    edges_out: wp.array[wp.int64],
):
    """One element per face: its boundary edges (a, b), as wound, from the thread's offset on (flat: 2 per edge)."""
    first = (wp.tid() + thread_offset) * chunk
    f = first
    last = wp.min(first + chunk, count)
    o = load(offsets, wp.tid() + thread_offset)
    while f < last:
        bits = load(flags, f)
        for j in range(3):
            if bits & (1 << j):
                edges_out[2 * o] = wp.int64(load(faces, 3 * f + j))
                edges_out[2 * o + 1] = wp.int64(load(faces, 3 * f + (j + 1) % 3))
                o += 1
        f += 1


@wp.kernel
def wall_quads(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    first_walls: wp.array[wp.int32],
    second_walls: wp.array[wp.int32],
    # outputs
    quads_out: wp.array[wp.vec4i],
    keys_out: wp.array[wp.int32],
):
    """One element per wall pair (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom): its four vertices (the
    first face's and the second's last) sorted, and the smallest as its key."""
    first = (wp.tid() + thread_offset) * chunk
    p = first
    last = wp.min(first + chunk, count)
    while p < last:
        f = load(first_walls, p)
        g = load(second_walls, p)
        a = load(faces, 3 * f)
        b = load(faces, 3 * f + 1)
        c = load(faces, 3 * f + 2)
        d = load(faces, 3 * g + 2)
        # a sorting network of four
        lo = wp.min(a, b)
        b = wp.max(a, b)
        a = lo
        lo = wp.min(c, d)
        d = wp.max(c, d)
        c = lo
        lo = wp.min(a, c)
        c = wp.max(a, c)
        a = lo
        lo = wp.min(b, d)
        d = wp.max(b, d)
        b = lo
        lo = wp.min(b, c)
        c = wp.max(b, c)
        b = lo
        q = wp.vec4i(a, b, c, d)
        quads_out[p] = q
        keys_out[p] = q[0]
        p += 1


@wp.kernel
def find_fins(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    quads: wp.array[wp.vec4i],
    offsets: wp.array[wp.int32],
    pairs: wp.array[wp.int32],
    limit: wp.int32,
    # outputs
    fins_out: wp.array[wp.uint8],
    deferred_out: wp.array[wp.int32],
):
    """One element per wall pair: 1 where another pair has the same sorted quad (found in the bucket of the quad's
    smallest vertex), else 0; 2 (deferred to :func:`find_fins_hashed`) where that bucket holds more than ``limit``
    pairs, and then ``deferred_out[0]`` = 1 (every writer writes the same value: no atomic needed)."""
    first = (wp.tid() + thread_offset) * chunk
    p = first
    last = wp.min(first + chunk, count)
    while p < last:
        q = quads[p]
        hit = wp.uint8(0)
        s = load(offsets, q[0])
        end = load(offsets, q[0] + 1)
        if end - s > limit:
            hit = wp.uint8(2)
            deferred_out[0] = 1
            s = end
        while s < end:
            r = load(pairs, s)
            if r != p:
                o = quads[r]
                if o[1] == q[1] and o[2] == q[2] and o[3] == q[3]:
                    hit = wp.uint8(1)
                    s = end
            s += 1
        fins_out[p] = hit
        p += 1


@wp.func
def mix(h: wp.uint32, k: wp.uint32) -> wp.uint32:
    """One step of MurmurHash3's 32-bit block mix: ``k`` folded into ``h``."""
    k = k * MURMUR_C1
    k = (k << wp.uint32(15)) | (k >> wp.uint32(17))
    k = k * MURMUR_C2
    h = h ^ k
    h = (h << wp.uint32(13)) | (h >> wp.uint32(19))
    return h * wp.uint32(5) + MURMUR_N


@wp.func
def mix64(h: wp.uint32, k: wp.int64) -> wp.uint32:
    """:func:`mix` of both halves of ``k``."""
    h = mix(h, wp.uint32(k & wp.int64(0xFFFFFFFF)))
    return mix(h, wp.uint32((k >> wp.int64(32)) & wp.int64(0xFFFFFFFF)))


@wp.func
def finish(h: wp.uint32, size: wp.int32) -> wp.int32:
    """MurmurHash3's final avalanche of ``h``, reduced to [0, size)."""
    h = h ^ (h >> wp.uint32(16))
    h = h * MURMUR_F1
    h = h ^ (h >> wp.uint32(13))
    h = h * MURMUR_F2
    h = h ^ (h >> wp.uint32(16))
    return wp.int32(h % wp.uint32(size))


@wp.kernel
def hash_fin_keys(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    quads: wp.array[wp.vec4i],
    fins: wp.array[wp.uint8],
    # outputs
    keys_out: wp.array[wp.int32],
):
    """One element per wall pair: the bucket :func:`find_fins_hashed` looks in, of the ``2 count`` buckets: a pair that
    :func:`find_fins` deferred gets count + a hash of its whole sorted quad (equal quads share it), any other one its
    own bucket p."""
    first = (wp.tid() + thread_offset) * chunk
    p = first
    last = wp.min(first + chunk, count)
    while p < last:
        k = p
        if fins[p] == wp.uint8(2):
            q = quads[p]
            h = mix(mix(mix(mix(wp.uint32(0), wp.uint32(q[0])), wp.uint32(q[1])), wp.uint32(q[2])), wp.uint32(q[3]))
            k = count + finish(h, count)
        keys_out[p] = k
        p += 1


@wp.kernel
def find_fins_hashed(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    quads: wp.array[wp.vec4i],
    keys: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    pairs: wp.array[wp.int32],
    # outputs
    fins_out: wp.array[wp.uint8],
):
    """One element per wall pair: where :func:`find_fins` deferred it (2), 1 where another pair in its hashed bucket
    (:func:`hash_fin_keys`) has the same sorted quad, else 0; stops at the first (a repeated quad finds its twin at
    once, however often it repeats)."""
    first = (wp.tid() + thread_offset) * chunk
    p = first
    last = wp.min(first + chunk, count)
    while p < last:
        if fins_out[p] == wp.uint8(2):
            q = quads[p]
            hit = wp.uint8(0)
            k = load(keys, p)
            s = load(offsets, k)
            end = load(offsets, k + 1)
            while s < end:
                r = load(pairs, s)
                if r != p:
                    o = quads[r]
                    if o[0] == q[0] and o[1] == q[1] and o[2] == q[2] and o[3] == q[3]:
                        hit = wp.uint8(1)
                        s = end
                s += 1
            fins_out[p] = hit
        p += 1


@wp.kernel
def emit_vertices(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    vertices: wp.array[wp.float64],
    column: wp.array[wp.int32],
    floor: wp.float64,
    # outputs
    vertices_out: wp.array[wp.float64],
):
    """One element per surface vertex (flat, 3 per vertex): itself, and its column's base vertex after the ``count``
    surface vertices (its x, y at ``floor``). The vertices of a column share their x and y bit for bit, so its
    writers write the same values."""
    first = (wp.tid() + thread_offset) * chunk
    i = first
    last = wp.min(first + chunk, count)
    while i < last:
        x = load(vertices, 3 * i)
        y = load(vertices, 3 * i + 1)
        vertices_out[3 * i] = x
        vertices_out[3 * i + 1] = y
        vertices_out[3 * i + 2] = load(vertices, 3 * i + 2)
        o = 3 * (count + load(column, i))
        vertices_out[o] = x
        vertices_out[o + 1] = y
        vertices_out[o + 2] = floor
        i += 1


@wp.func
def base_face_ok(faces: wp.array[wp.int32], terrace: wp.array[wp.uint8], column: wp.array[wp.int32],
                 f: wp.int32) -> wp.bool:
    """Whether face f is a terrace whose three columns differ (its base face has an area)."""
    if terrace[f] == wp.uint8(0):
        return False
    a = load(column, load(faces, 3 * f))
    b = load(column, load(faces, 3 * f + 1))
    c = load(column, load(faces, 3 * f + 2))
    return a != b and b != c and a != c


@wp.kernel
def count_base_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    terrace: wp.array[wp.uint8],
    column: wp.array[wp.int32],
    # outputs
    counts_out: wp.array[wp.int32],
):
    """One element per face: ``counts_out[thread]`` counts the base faces of the thread's chunk."""
    first = (wp.tid() + thread_offset) * chunk
    f = first
    last = wp.min(first + chunk, count)
    total = wp.int32(0)
    while f < last:
        if base_face_ok(faces, terrace, column, f):
            total += 1
        f += 1
    counts_out[wp.tid() + thread_offset] = total


@wp.kernel
def emit_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    terrace: wp.array[wp.uint8],
    column: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    first_base_vertex: wp.int64,
    first_base_face: wp.int32,
    # outputs
    faces_out: wp.array[wp.int64],
):
    """One element per face (flat, 3 per face): the face itself, and a terrace's base face from the thread's offset
    on after ``first_base_face`` faces: its columns' base vertices (``first_base_vertex`` + column) in reverse
    order."""
    first = (wp.tid() + thread_offset) * chunk
    f = first
    last = wp.min(first + chunk, count)
    o = first_base_face + load(offsets, wp.tid() + thread_offset)
    while f < last:
        a = load(faces, 3 * f)
        b = load(faces, 3 * f + 1)
        c = load(faces, 3 * f + 2)
        faces_out[3 * f] = wp.int64(a)
        faces_out[3 * f + 1] = wp.int64(b)
        faces_out[3 * f + 2] = wp.int64(c)
        if base_face_ok(faces, terrace, column, f):
            faces_out[3 * o] = first_base_vertex + wp.int64(load(column, c))
            faces_out[3 * o + 1] = first_base_vertex + wp.int64(load(column, b))
            faces_out[3 * o + 2] = first_base_vertex + wp.int64(load(column, a))
            o += 1
        f += 1


@wp.kernel
def last_wall_writes(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    first_walls: wp.array[wp.int32],
    second_walls: wp.array[wp.int32],
    # outputs
    winner_out: wp.array[wp.int32],
):
    """One element per wall pair p of ``count``: the vertical edges (v_top, v_bottom) of its first face and
    (u_top, u_bottom) of its second are written to their ends, tops first, in the order top p, top count + p,
    bottom 2 count + p, bottom 3 count + p; ``winner_out`` (-1 first) keeps each vertex's last write (the one a
    sequential ``pair[tops] = low; pair[bottoms] = low`` keeps)."""
    first = (wp.tid() + thread_offset) * chunk
    p = first
    last = wp.min(first + chunk, count)
    while p < last:
        f = load(first_walls, p)
        g = load(second_walls, p)
        wp.atomic_max(winner_out, load(faces, 3 * f + 1), p)
        wp.atomic_max(winner_out, load(faces, 3 * g), count + p)
        wp.atomic_max(winner_out, load(faces, 3 * f + 2), 2 * count + p)
        wp.atomic_max(winner_out, load(faces, 3 * g + 2), 3 * count + p)
        p += 1


@wp.kernel
def wall_pairs(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int32],
    first_walls: wp.array[wp.int32],
    second_walls: wp.array[wp.int32],
    winner: wp.array[wp.int32],
    pairs: wp.int32,
    # outputs
    pair_out: wp.array[wp.int32],
):
    """One element per vertex: the lower end of the vertical wall edge last written to it (:func:`last_wall_writes`
    over ``pairs`` wall pairs), else itself."""
    first = (wp.tid() + thread_offset) * chunk
    v = first
    last = wp.min(first + chunk, count)
    while v < last:
        w = load(winner, v)
        low = v
        if w >= 0:
            k = w % (2 * pairs)
            if k < pairs:
                f = load(first_walls, k)
                low = wp.min(load(faces, 3 * f + 1), load(faces, 3 * f + 2))
            else:
                g = load(second_walls, k - pairs)
                low = wp.min(load(faces, 3 * g), load(faces, 3 * g + 2))
        pair_out[v] = low
        v += 1


@wp.kernel
def column_leaders(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    bits: wp.array[wp.int64],
    fan: wp.array[wp.int64],
    pair: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    members: wp.array[wp.int32],
    limit: wp.int32,
    # outputs
    leader_out: wp.array[wp.int32],
    starts_out: wp.array[wp.int32],
    deferred_out: wp.array[wp.int32],
):
    """One element per vertex v: ``leader_out[v]``, the smallest vertex of its column, and ``starts_out[v]``, 1 where
    that is v itself, else 0. A column is the vertices of one pair group (``members[offsets[k]:offsets[k + 1]]``, the
    vertices whose ``pair`` is k) with the same x, y and fan bit for bit: no sort, a scan of v's own group (two
    vertices, a wall's bottom and top, where the step kernels made it). A group of more than ``limit`` vertices is
    deferred to :func:`column_reps` (a scan per member would be quadratic in it): ``leader_out[v]`` = -1 and
    ``deferred_out[0]`` = 1 (every writer writes the same value: no atomic needed). ``bits``: the vertices' float64
    bit patterns (3 per vertex); ``fan``: likewise, or empty (no pinch was split)."""
    first = (wp.tid() + thread_offset) * chunk
    v = first
    last = wp.min(first + chunk, count)
    fans = fan.shape[0] > 0
    while v < last:
        k = load(pair, v)
        x = bits[3 * v]
        y = bits[3 * v + 1]
        best = v
        s = load(offsets, k)
        end = load(offsets, k + 1)
        if end - s > limit:
            best = -1
            deferred_out[0] = 1
            s = end
        while s < end:
            u = load(members, s)
            if u < best and bits[3 * u] == x and bits[3 * u + 1] == y:
                if not fans:
                    best = u
                elif fan[u] == fan[v]:
                    best = u
            s += 1
        leader_out[v] = best
        starts_out[v] = wp.where(best == v, 1, 0)
        v += 1


@wp.func
def same_column(bits: wp.array[wp.int64], fan: wp.array[wp.int64], pair: wp.array[wp.int32], u: wp.int32,
                v: wp.int32) -> wp.bool:
    """Whether vertices u and v have the same (x, y, [fan], pair) bit for bit."""
    if load(pair, u) != load(pair, v) or bits[3 * u] != bits[3 * v] or bits[3 * u + 1] != bits[3 * v + 1]:
        return False
    if fan.shape[0] > 0:
        return fan[u] == fan[v]
    return True


@wp.kernel
def hash_column_keys(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    bits: wp.array[wp.int64],
    fan: wp.array[wp.int64],
    pair: wp.array[wp.int32],
    leader: wp.array[wp.int32],
    # outputs
    keys_out: wp.array[wp.int32],
):
    """One element per vertex v: the bucket :func:`column_reps` looks in, of the ``2 count`` buckets: a vertex that
    :func:`column_leaders` deferred gets count + a hash of its (x, y, [fan], pair) (a column shares it), any other one
    its own bucket v."""
    first = (wp.tid() + thread_offset) * chunk
    v = first
    last = wp.min(first + chunk, count)
    fans = fan.shape[0] > 0
    while v < last:
        k = v
        if load(leader, v) < 0:
            h = mix64(mix64(mix(wp.uint32(0), wp.uint32(load(pair, v))), bits[3 * v]), bits[3 * v + 1])
            if fans:
                h = mix64(h, fan[v])
            k = count + finish(h, count)
        keys_out[v] = k
        v += 1


@wp.kernel
def column_reps(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    bits: wp.array[wp.int64],
    fan: wp.array[wp.int64],
    pair: wp.array[wp.int32],
    leader: wp.array[wp.int32],
    keys: wp.array[wp.int32],
    offsets: wp.array[wp.int32],
    members: wp.array[wp.int32],
    # outputs
    rep_out: wp.array[wp.int32],
    low_out: wp.array[wp.int32],
):
    """One element per vertex v that :func:`column_leaders` deferred: ``rep_out[v]``, the first vertex of its column
    in its hashed bucket (:func:`hash_column_keys`; the same for the whole column, found at once however big the
    column), and the smallest vertex of each column kept at its representative (``low_out``, ``count`` first; an
    atomic min)."""
    first = (wp.tid() + thread_offset) * chunk
    v = first
    last = wp.min(first + chunk, count)
    while v < last:
        if load(leader, v) < 0:
            k = load(keys, v)
            s = load(offsets, k)
            end = load(offsets, k + 1)
            rep = v
            while s < end:
                u = load(members, s)
                if same_column(bits, fan, pair, u, v):
                    rep = u
                    s = end
                s += 1
            rep_out[v] = rep
            wp.atomic_min(low_out, rep, v)
        v += 1


@wp.kernel
def deferred_leaders(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    rep: wp.array[wp.int32],
    low: wp.array[wp.int32],
    # outputs
    leader_out: wp.array[wp.int32],
    starts_out: wp.array[wp.int32],
):
    """One element per vertex v that :func:`column_leaders` deferred (``leader_out[v]`` = -1): its leader, the
    smallest vertex of its column (:func:`column_reps`), and ``starts_out[v]`` as column_leaders gives it."""
    first = (wp.tid() + thread_offset) * chunk
    v = first
    last = wp.min(first + chunk, count)
    while v < last:
        if load(leader_out, v) < 0:
            best = load(low, load(rep, v))
            leader_out[v] = best
            starts_out[v] = wp.where(best == v, 1, 0)
        v += 1


@wp.kernel
def number_columns(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    leader: wp.array[wp.int32],
    ranks: wp.array[wp.int32],
    # outputs
    ids_out: wp.array[wp.int64],
    ids32_out: wp.array[wp.int32],
):
    """One element per vertex: its column, the number of leaders (:func:`column_leaders`) up to its own less one
    (``ranks``: the inclusive scan of their starts), so the columns are numbered in the order of their smallest
    vertex; in int64 and in int32."""
    first = (wp.tid() + thread_offset) * chunk
    v = first
    last = wp.min(first + chunk, count)
    while v < last:
        c = load(ranks, load(leader, v)) - 1
        ids_out[v] = wp.int64(c)
        ids32_out[v] = c
        v += 1


@wp.kernel
def narrow_faces(
    thread_offset: wp.int32,
    count: wp.int32,
    chunk: wp.int32,
    faces: wp.array[wp.int64],
    # outputs
    faces_out: wp.array[wp.int32],
    low_out: wp.array[wp.int64],
    high_out: wp.array[wp.int64],
):
    """One element per index of the flat int64 ``faces``: it as int32 (wrapped where it does not fit: the caller
    refuses those from the thread's smallest and largest index, ``low_out`` and ``high_out``)."""
    first = (wp.tid() + thread_offset) * chunk
    t = first
    last = wp.min(first + chunk, count)
    low = faces[first]
    high = low
    while t < last:
        v = faces[t]
        low = wp.min(low, v)
        high = wp.max(high, v)
        faces_out[t] = wp.int32(v)
        t += 1
    low_out[wp.tid() + thread_offset] = low
    high_out[wp.tid() + thread_offset] = high
