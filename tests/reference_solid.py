"""NumPy reference of :func:`stepterrain.mesh.close_solid` and its helpers, as they were before the Warp kernels
(``kernels/solid.py``): close_solid, boundary_edges, exact_keys, _wall_pairs, _repeated_rows and _split_pinches,
verbatim (close_solid with two rules added since: a clockwise surface closed with its faces reversed, a floor on the
lowest point in float32 refused). Tests compare the kernels' results with these bit for bit;
``benchmarks/run_solid.py`` times them as what a NumPy user would otherwise have.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from stepterrain.errors import InvalidInputError
from stepterrain.terrain import FLOAT32_MAX


def exact_keys(xy: NDArray[np.float64]) -> NDArray[np.int64]:
    """Group ids of rows that are bit-identical (e.g. vertices sharing an exact xy).

    Rows are compared bit for bit (0.0 and -0.0 differ), sorted by their columns' bit patterns with one
    ``lexsort``: ids number the distinct rows in that order."""
    rows = np.ascontiguousarray(xy)
    if len(rows) == 0:
        return np.zeros(0, np.int64)
    bits = rows.view(np.dtype(f"u{rows.dtype.itemsize}")).reshape(len(rows), -1)
    order = np.lexsort(bits.T[::-1])
    ordered = bits[order]
    new = np.ones(len(rows), bool)
    new[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    ids = np.empty(len(rows), np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids


def boundary_edges(faces: NDArray[np.int64]) -> NDArray[np.int64]:
    """Directed edges (a, b), as wound in their face, that no other face uses: (B, 2), in face order.

    One sort of the undirected edge keys finds the keys that occur once (few: the boundary); the edges with
    one of those keys are then found through a bit table of their low bits and a binary search among the few
    candidates, so the sort needs no inverse (argsort) and no second pass over every key."""
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0:
        return np.zeros((0, 2), np.int64)
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    n = int(faces.max()) + 1
    # corner-major: key k * F + f is the edge leaving corner k of face f
    key = np.concatenate([np.minimum(u, v) * n + np.maximum(u, v) for u, v in ((a, b), (b, c), (c, a))])
    ordered = np.sort(key)
    once = np.ones(len(ordered), bool)
    repeated = ordered[1:] == ordered[:-1]
    once[1:] &= ~repeated
    once[:-1] &= ~repeated
    single = ordered[once]
    if len(single) == 0:
        return np.zeros((0, 2), np.int64)
    low = (1 << 22) - 1
    table = np.zeros(low + 1, bool)
    table[single & low] = True
    candidates = np.flatnonzero(table[key & low])
    at = np.minimum(np.searchsorted(single, key[candidates]), len(single) - 1)
    hit = candidates[single[at] == key[candidates]]
    corner, face = np.divmod(hit, len(faces))
    order = np.argsort(face * 3 + corner)  # face order, as the faces list their edges
    face, corner = face[order], corner[order]
    return np.column_stack([faces[face, corner], faces[face, (corner + 1) % 3]])


def close_solid(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    terrace_mask: NDArray[np.bool_],
    floor: float,
    turn: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_], int, NDArray[np.int64]]:
    """Close a height-function surface into a watertight solid with side skirts and a flat base at ``floor``.

    The base is the terraces (faces whose projections tile the domain) flattened to ``floor`` and reversed, one base
    vertex per surface vertex except that a wall's bottom and top (the faces not in ``terrace_mask``, in consecutive
    pairs as the step kernels emit them) share theirs; each boundary edge gets a vertical skirt down to the base. A
    vertical boundary edge (a wall's side on the domain boundary) joins the skirt of the boundary edge that follows
    it, so no zero-area face appears.

    Where the surface's boundary touches itself at a vertex (two triangles meeting only there, e.g. between
    nodata holes), that vertex is split first: each fan of faces around it gets its own copy (same position),
    and so does the base vertex below it, so every skirt and base edge keeps exactly two faces and the solid
    stays watertight (two volumes touching along a vertical segment, as a slicer expects).

    Zero-volume fins are removed first: where heights sit exactly on a threshold along a ridge line, two walls
    stand back to back on the same vertices (a terrace of zero width); both go, and so do vertices no face
    uses any more. (:func:`~stepterrain.stepped.stepped` steps a solid from heights moved off the thresholds, so
    its surfaces have no such fin, and no twin vertex whose vertical edge four walls share at a saddle.)

    Returns the new vertices (the surface's first, then the base), the faces (kept input faces first, then the
    added ones), the mask of input faces kept, the number of faces added, and per surface vertex the input vertex
    it is or copies (``len(source)`` surface vertices: per-vertex data such as colours follows them through it).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    given = vertices, faces, terrace_mask
    kept = np.ones(len(faces), bool)
    source = np.arange(len(vertices))
    walls = np.flatnonzero(~np.asarray(terrace_mask))
    if len(walls) >= 4 and len(walls) % 2 == 0:
        # walls are emitted as consecutive pairs (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom)
        first, second = walls[0::2], walls[1::2]
        quads = np.sort(np.column_stack([faces[first], faces[second][:, 2]]), axis=1)
        fin = _repeated_rows(quads)
        kept[first[fin]] = False
        kept[second[fin]] = False
    if not kept.all():
        faces = faces[kept]
        terrace_mask = np.asarray(terrace_mask)[kept]
        used = np.zeros(len(vertices), bool)
        used[faces.reshape(-1)] = True
        if not used.all():
            remap = np.cumsum(used) - 1
            faces = remap[faces]
            vertices = vertices[used]
            source = source[used]
    if not np.isfinite(floor):
        raise InvalidInputError(f"floor must be finite; got {floor}")
    if abs(floor) > FLOAT32_MAX:  # the mesh's float32 vertices (GPU, GLB) would hold -inf and NaN
        raise InvalidInputError(f"floor must fit in float32 (|x| < {FLOAT32_MAX:.2g}); got {floor:g}")
    zmin = float(vertices[:, 2].min()) if len(vertices) else 0.0
    if floor >= zmin:
        raise InvalidInputError(f"floor must lie below the lowest surface height {zmin}; got {floor}")
    with np.errstate(over="ignore"):  # added since: nor on it in float32 (an .stl's, a .glb's positions)
        low32 = np.float32(zmin)
    if np.float32(floor) >= low32:
        below = float(np.nextafter(low32, np.float32(-np.inf)))
        raise InvalidInputError(f"floor must lie below the lowest surface height {zmin} in float32 too (an .stl or a "
                                f".glb stores float32 positions: at most {below:.9g}); got {floor}, which rounds to "
                                f"{float(np.float32(floor)):.9g} in float32")
    edges = boundary_edges(faces)
    # added since: a surface wound clockwise seen from +z (its projected area, the shoelace sum over its boundary,
    # negative) is closed again with its faces reversed (once: ``turn``), so that the solid faces outward (inside out
    # before)
    o = vertices[edges[0, 0], :2] if len(edges) else np.zeros(2)
    a, b = vertices[edges[:, 0], :2] - o, vertices[edges[:, 1], :2] - o
    if turn and np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) < 0.0:
        return close_solid(given[0], given[1][:, ::-1], given[2], floor, turn=False)
    vertices, faces, fan, copied = _split_pinches(vertices, faces, edges, terrace_mask)
    split = len(copied) > 0
    if split:
        edges = boundary_edges(faces)
        source = np.concatenate([source, source[copied]])
    n = len(vertices)
    # a column (one base vertex) is a vertex, or the wall bottom and top that a vertical wall edge joins; a pinch's
    # copies keep their own. Keyed by xy alone, two vertices on one xy that no wall joins (a TIN's cliff: two points
    # on one xy, or a crossing on a zero-area face where another edge's crossing lies) shared a base vertex, and the
    # base under them folded onto a base edge used four times: a solid that leaked, without a warning
    keys = np.column_stack([vertices[:, :2], fan]) if split else vertices[:, :2]
    column = exact_keys(keys)
    pair = _wall_pairs(faces, terrace_mask, n)
    held = np.empty(int(column.max(initial=-1)) + 1, np.int64)
    held[column] = pair
    if (held[column] != pair).any():  # rare (a TIN's zero-area faces): the key sorts as before, only longer
        column = exact_keys(np.column_stack([keys, pair.astype(np.float64)]))
    n_columns = int(column.max()) + 1
    base_xy = np.empty((n_columns, 2), dtype=np.float64)
    base_xy[column] = vertices[:, :2]
    base_vertices = np.column_stack([base_xy, np.full(n_columns, floor)])
    base_index = n + column  # output index of each surface vertex's base copy

    terraces = faces[terrace_mask]
    base_faces = base_index[terraces][:, ::-1]
    ok = (
        (base_faces[:, 0] != base_faces[:, 1])
        & (base_faces[:, 1] != base_faces[:, 2])
        & (base_faces[:, 0] != base_faces[:, 2])
    )
    base_faces = base_faces[ok]

    a, b = edges[:, 0], edges[:, 1]
    vertical = column[a] == column[b]
    # the vertical boundary edge arriving at a vertex, if any: pred[top_or_bottom] = its start
    pred = np.full(n, -1, np.int64)
    pred[b[vertical]] = a[vertical]
    a, b = a[~vertical], b[~vertical]
    x = pred[a]
    has_x = x >= 0
    A, B = base_index[a], base_index[b]
    skirts = [np.stack([b, A, B], axis=1)]
    plain = ~has_x
    skirts.append(np.stack([b[plain], a[plain], A[plain]], axis=1))
    skirts.append(np.stack([b[has_x], a[has_x], x[has_x]], axis=1))
    skirts.append(np.stack([b[has_x], x[has_x], A[has_x]], axis=1))
    added = np.concatenate(skirts + [base_faces], axis=0)
    return np.concatenate([vertices, base_vertices]), np.concatenate([faces, added]), kept, len(added), source


def _wall_pairs(faces: NDArray[np.int64], terrace_mask: NDArray[np.bool_], n: int) -> NDArray[np.int64]:
    """Per vertex, the lower index of the wall bottom and top it pairs with through a vertical wall edge (itself when
    no wall's side joins it to another vertex). Walls come as consecutive pairs (u_top, v_top, v_bottom),
    (u_top, v_bottom, u_bottom): their vertical edges are (v_top, v_bottom) and (u_top, u_bottom); a vertex lies on
    one such edge at most (a crossing's bottom or top, a node over its twin)."""
    pair = np.arange(n, dtype=np.int64)
    walls = np.flatnonzero(~np.asarray(terrace_mask))
    if len(walls) == 0 or len(walls) % 2:
        return pair
    first, second = walls[0::2], walls[1::2]
    tops = np.concatenate([faces[first, 1], faces[second, 0]])
    bottoms = np.concatenate([faces[first, 2], faces[second, 2]])
    low = np.minimum(tops, bottoms)
    pair[tops] = low
    pair[bottoms] = low
    return pair


def _repeated_rows(rows: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Which rows of a (R, C) int array occur more than once (rows grouped by :func:`exact_keys`)."""
    ids = exact_keys(rows)
    return np.bincount(ids)[ids] > 1


def _cross(p: NDArray[np.float64], q: NDArray[np.float64]) -> float:
    return float(p[0] * q[1] - p[1] * q[0])


def _split_pinches(
    vertices: NDArray[np.float64], faces: NDArray[np.int64], edges: NDArray[np.int64], terrace_mask: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Give each fan of faces around a pinch vertex (one the boundary passes through more than once) its own copy.

    The corners at a pinch vertex v are joined into fans through the interior edges (v, w) they share (label
    propagation: at most one round per face around v). The fan with the smallest corner keeps v; the others get
    new vertices, appended, each moved 2 float32 steps of the largest |x|, |y| into its fan in x and y (unless the
    fan has a wall). Returns the vertices, the faces and, per vertex, the fan
    ordinal (0 for every vertex that is not such a copy), to keep the copies apart where rows are keyed by xy,
    and the vertex each appended copy copies (empty when none was split). ``edges`` are the surface's boundary
    edges (:func:`boundary_edges`).
    """
    n = len(vertices)
    fan = np.zeros(n, np.float64)
    none = np.zeros(0, np.int64)
    if len(edges) == 0:
        return vertices, faces, fan, none
    pinch = np.bincount(edges[:, 0], minlength=n) > 1
    if not pinch.any():
        return vertices, faces, fan, none
    fi, ji = np.nonzero(pinch[faces])
    v = faces[fi, ji]
    keys = np.concatenate([v * n + faces[fi, (ji + 1) % 3], v * n + faces[fi, (ji + 2) % 3]])
    _, edge_id = np.unique(keys, return_inverse=True)
    e1, e2 = np.split(edge_id.reshape(-1), 2)
    label = np.arange(len(v))
    while True:
        low = np.full(int(edge_id.max()) + 1, len(v))
        np.minimum.at(low, e1, label)
        np.minimum.at(low, e2, label)
        new = np.minimum(low[e1], low[e2])
        if np.array_equal(new, label):
            break
        label = new
    fans = np.unique(np.column_stack([v, label]), axis=0)
    rank = np.arange(len(fans)) - np.searchsorted(fans[:, 0], fans[:, 0])  # 0 for each vertex's first fan
    which = np.searchsorted(fans[:, 0] * len(v) + fans[:, 1], v * len(v) + label)
    copies = np.flatnonzero(rank > 0)
    new_index = np.full(len(fans), -1, np.int64)
    new_index[copies] = n + np.arange(len(copies))
    moved = rank[which] > 0
    added = vertices[fans[copies, 0]].copy()
    u = float(np.spacing(np.float32(np.abs(vertices[:, :2]).max())))
    for k, f in enumerate(copies):  # each copy into its fan (but one with a wall): 2 u along the signs of its faces'
        corners = moved & (which == f)  # mean direction from v
        if terrace_mask[fi[corners]].all():
            mean = (vertices[faces[fi[corners]], :2].mean(axis=1) - added[k, :2]).sum(axis=0)
            others = (v == v[corners][0]) & (which != f)

            def fits(to: NDArray[np.float64], corners=corners, others=others) -> bool:
                ok = True  # no face of the fan turned (float64, float32), the new position in no other fan's angle
                own = False  # and in its own fan's (closed) angle at v
                for face, j in zip(fi[corners], ji[corners], strict=True):
                    tri = vertices[faces[face], :2].copy()
                    area = _cross(tri[1] - tri[0], tri[2] - tri[0])
                    tri[j] = to
                    tri32 = tri.astype(np.float32).astype(np.float64)
                    ok &= area != 0 and _cross(tri[1] - tri[0], tri[2] - tri[0]) * area > 0
                    ok &= _cross(tri32[1] - tri32[0], tri32[2] - tri32[0]) * area > 0
                    o, a, b = vertices[faces[face], :2][[j, (j + 1) % 3, (j + 2) % 3]]
                    own |= _cross(a - o, to - o) * area >= 0 and _cross(o - b, to - b) * area >= 0
                for face, j in zip(fi[others], ji[others], strict=True):
                    o, a, b = vertices[faces[face], :2][[j, (j + 1) % 3, (j + 2) % 3]]
                    area = _cross(a - o, b - o)
                    ok &= not (_cross(a - o, to - o) * area > 0 and _cross(o - b, to - b) * area > 0)
                return bool(ok and own)

            to = added[k, :2] + 2.0 * u * np.sign(mean)
            if fits(to):
                added[k, :2] = to
                continue
            # refused (outside its angle: a one-triangle fan whose edge is the diagonal, or any fan on non-square
            # cells): along the mean direction instead, under the same guards
            size = np.abs(mean).max()
            if size > 0:
                to = added[k, :2] + 2.0 * u * mean / size
                if fits(to):
                    added[k, :2] = to
    faces = faces.copy()
    faces[fi[moved], ji[moved]] = new_index[which[moved]]
    vertices = np.concatenate([vertices, added])
    fan = np.concatenate([fan, rank[copies].astype(np.float64)])
    return vertices, faces, fan, fans[copies, 0]
