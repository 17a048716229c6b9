"""Independent NumPy reference of the step tessellation (paper 000 §3.1-3.3), vectorised over triangles.

It follows the written conventions of ``kernels/stepped.py`` (level = number of thresholds <= h; wall
bottom/top per edge crossing; a node on its threshold gets a twin; per band a counter-clockwise polygon
walk fanned from its first vertex; then the wall) but shares no code with it: numpy searchsorted, unique
and masked gathers instead of Warp kernels, its own vertex numbering. Tests match vertices by key
(source nodes, height at γ = 0, height at γ = 1) and then compare faces exactly.

Also used by ``benchmarks/`` as "what a NumPy user would write".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass
class ReferenceResult:
    points: NDArray[np.float64]  # (V, 3) x, y, z at γ = 0
    step_heights: NDArray[np.float64]  # (V,) z at γ = 1
    keys: NDArray[np.float64]  # (V, 4) lo, hi, z0 (float32 value), zs (float32 value)
    faces: NDArray[np.int64]  # (F, 3) in the kernels' order
    face_levels: NDArray[np.int64]
    face_walls: NDArray[np.bool_]


def thresholds_of(values: NDArray[np.float32]) -> NDArray[np.float32]:
    v = values.astype(np.float64)
    return ((v[:-1] + v[1:]) * 0.5).astype(np.float32)


def grid_tin(heights: NDArray[np.float32], spacing=(1.0, 1.0)) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """Local points (N, 3) float32 and valid faces of a grid, triangulated like ``heightfield_mesh``."""
    rows, cols = heights.shape
    dx, dy = spacing
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    points = np.stack([j.reshape(-1) * np.float32(dx), i.reshape(-1) * np.float32(dy), heights.reshape(-1)], axis=1)
    ii, jj = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    n00 = (ii * cols + jj).reshape(-1)
    tri = np.empty((len(n00), 2, 3), np.int64)
    tri[:, 0] = np.stack([n00, n00 + 1, n00 + cols + 1], 1)
    tri[:, 1] = np.stack([n00, n00 + cols + 1, n00 + cols], 1)
    faces = tri.reshape(-1, 3)
    if dx * dy < 0:
        faces = faces[:, [0, 2, 1]]
    finite = np.isfinite(points[:, 2])
    faces = faces[finite[faces].all(axis=1)]
    return points.astype(np.float32), faces


def step_reference(
    points: NDArray[np.float32], faces: NDArray[np.int64], values: NDArray[np.float32]
) -> ReferenceResult:
    """Stepped mesh of a TIN (points local float32, faces counter-clockwise) for isovalues ``values``."""
    values = np.asarray(values, np.float32)
    thr = thresholds_of(values)
    h = points[:, 2].astype(np.float32)
    lev = np.searchsorted(thr, h, side="right").astype(np.int64)
    on_thr = np.zeros(len(h), bool)
    has_below = lev > 0
    on_thr[has_below] = h[has_below] == thr[lev[has_below] - 1]

    # edges of the valid faces, and per face the edge from corner k to k+1
    n = len(points)
    d = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    ekey = np.minimum(d[:, 0], d[:, 1]) * n + np.maximum(d[:, 0], d[:, 1])
    ukey, einv = np.unique(ekey, return_inverse=True)
    ea, eb = ukey // n, ukey % n
    face_edge = einv.reshape(-1, 3)

    # vertex layout (reference's own): node, twin, then every edge's crossings
    used = np.zeros(n, bool)
    used[faces.reshape(-1)] = True
    lo = np.where(lev[ea] <= lev[eb], ea, eb)
    hi = np.where(lev[ea] <= lev[eb], eb, ea)
    crossed = lev[hi] - lev[lo]
    alias = (crossed > 0) & on_thr[hi]
    twin = np.zeros(n, bool)
    twin[hi[alias]] = True
    # a peak on its threshold (no neighbour at its level or above) keeps only the twin
    peer = np.zeros(n, bool)
    peer[ea[lev[eb] >= lev[ea]]] = True
    peer[eb[lev[ea] >= lev[eb]]] = True
    own = used & ~(twin & ~peer)
    node_index = np.full(n, -1, np.int64)
    node_index[own] = np.arange(own.sum())
    twin_index = np.full(n, -1, np.int64)
    twin_index[twin] = own.sum() + np.arange(twin.sum())
    peak = twin & ~peer
    node_index[peak] = twin_index[peak]
    edge_count = 2 * (crossed - alias)
    edge_base = own.sum() + twin.sum() + np.concatenate([[0], np.cumsum(edge_count)[:-1]])
    total = int(own.sum() + twin.sum() + edge_count.sum())

    pts = np.zeros((total, 3))
    zs = np.zeros(total)
    keys = np.zeros((total, 4))
    un = np.flatnonzero(own)
    pts[node_index[un]] = points[un]
    zs[node_index[un]] = values[lev[un]]
    keys[node_index[un]] = np.stack([un, un, h[un], values[lev[un]]], 1)
    tn = np.flatnonzero(twin)
    pts[twin_index[tn]] = points[tn]
    zs[twin_index[tn]] = values[lev[tn] - 1]
    keys[twin_index[tn]] = np.stack([tn, tn, h[tn], values[lev[tn] - 1]], 1)
    # crossings: expand (edge, j) pairs
    e_rep = np.repeat(np.arange(len(ukey)), crossed)
    j = lev[lo][e_rep] + (np.arange(len(e_rep)) - np.repeat(np.cumsum(crossed) - crossed, crossed))
    keep = ~(alias[e_rep] & (j == lev[hi][e_rep] - 1))
    e_rep, j = e_rep[keep], j[keep]
    slot = edge_base[e_rep] + 2 * (j - lev[lo][e_rep])
    plo, phi = points[lo[e_rep]].astype(np.float64), points[hi[e_rep]].astype(np.float64)
    t = thr[j].astype(np.float64)
    beta = (t - plo[:, 2]) / (phi[:, 2] - plo[:, 2])
    xy = plo[:, :2] + beta[:, None] * (phi[:, :2] - plo[:, :2])
    for top in (0, 1):
        pts[slot + top, :2] = xy
        pts[slot + top, 2] = t
        zs[slot + top] = values[j + top]
        keys[slot + top] = np.stack([lo[e_rep], hi[e_rep], thr[j], values[j + top]], 1)

    def crossing(edge: np.ndarray, jj: np.ndarray, top: int) -> np.ndarray:
        aliased = alias[edge] & (jj == lev[hi[edge]] - 1)
        own = edge_base[edge] + 2 * (jj - lev[lo[edge]]) + top
        corner = node_index[hi[edge]] if top else twin_index[hi[edge]]
        return np.where(aliased, corner, own)

    corners = faces
    cl = lev[corners]
    lmin, lmax = cl.min(1), cl.max(1)
    out_faces, out_key, out_level, out_wall = [], [], [], []
    fid = np.arange(len(faces))
    for r in range(int((lmax - lmin).max()) + 1 if len(faces) else 0):
        sel = np.flatnonzero(lmax - lmin >= r)
        k = lmin[sel] + r
        # polygon candidates: 3 edges x (corner, first crossing, second crossing)
        cand = np.full((len(sel), 9), -1, np.int64)
        for c in range(3):
            a, b = corners[sel, c], corners[sel, (c + 1) % 3]
            la, lb = lev[a], lev[b]
            e = face_edge[sel, c]
            cand[:, 3 * c] = np.where(la == k, node_index[a], -1)
            up, down = la < lb, la > lb
            first = np.full(len(sel), -1, np.int64)
            second = np.full(len(sel), -1, np.int64)
            m = up & (la <= k - 1) & (k - 1 < lb)
            first[m] = crossing(e[m], (k - 1)[m], 1)
            m = up & (la <= k) & (k < lb)
            second[m] = crossing(e[m], k[m], 0)
            m = down & (lb <= k) & (k < la)
            first[m] = crossing(e[m], k[m], 0)
            m = down & (lb <= k - 1) & (k - 1 < la)
            second[m] = crossing(e[m], (k - 1)[m], 1)
            cand[:, 3 * c + 1] = first
            cand[:, 3 * c + 2] = second
        # compact, drop repeats of the previous vertex and of the first one
        order = np.argsort(cand < 0, axis=1, kind="stable")
        cand = np.take_along_axis(cand, order, axis=1)
        poly = np.full_like(cand, -1)
        count = np.zeros(len(sel), np.int64)
        first_v = cand[:, 0]
        prev = np.full(len(sel), -2, np.int64)
        for s in range(9):
            v = cand[:, s]
            ok = (v >= 0) & (v != prev) & ((count == 0) | (v != first_v))
            poly[ok, count[ok]] = v[ok]
            count += ok
            prev = np.where(ok, v, prev)
        for m in range(1, 8):
            has = count >= m + 2
            if not has.any():
                break
            rows = np.flatnonzero(has)
            out_faces.append(np.stack([poly[rows, 0], poly[rows, m], poly[rows, m + 1]], 1))
            out_key.append(
                np.stack(
                    [fid[sel[rows]], np.full(len(rows), r), np.zeros(len(rows), np.int64), np.full(len(rows), m)], 1
                )
            )
            out_level.append(k[rows])
            out_wall.append(np.zeros(len(rows), bool))
        # wall of threshold k where the triangle reaches above it
        wsel = np.flatnonzero(k < lmax[sel])
        if len(wsel):
            kk = k[wsel]
            ut = np.full(len(wsel), -1, np.int64)
            ub, vt, vb = ut.copy(), ut.copy(), ut.copy()
            for c in range(3):
                a, b = corners[sel[wsel], c], corners[sel[wsel], (c + 1) % 3]
                la, lb = lev[a], lev[b]
                e = face_edge[sel[wsel], c]
                m = (la <= kk) & (kk < lb)
                ut[m], ub[m] = crossing(e[m], kk[m], 1), crossing(e[m], kk[m], 0)
                m = (lb <= kk) & (kk < la)
                vt[m], vb[m] = crossing(e[m], kk[m], 1), crossing(e[m], kk[m], 0)
            real = ut != vt
            rows = np.flatnonzero(real)
            for part, tri in enumerate((np.stack([ut, vt, vb], 1), np.stack([ut, vb, ub], 1))):
                out_faces.append(tri[rows])
                out_key.append(
                    np.stack(
                        [
                            fid[sel[wsel[rows]]],
                            np.full(len(rows), r),
                            np.ones(len(rows), np.int64),
                            np.full(len(rows), part),
                        ],
                        1,
                    )
                )
                out_level.append(kk[rows])
                out_wall.append(np.ones(len(rows), bool))
    if out_faces:
        all_faces = np.concatenate(out_faces)
        key = np.concatenate(out_key)
        order = np.lexsort((key[:, 3], key[:, 2], key[:, 1], key[:, 0]))
        all_faces, level, wall = all_faces[order], np.concatenate(out_level)[order], np.concatenate(out_wall)[order]
    else:
        all_faces, level, wall = np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, bool)
    return ReferenceResult(pts, zs, keys, all_faces, level, wall)


def _used_values(heights: NDArray) -> tuple[NDArray, NDArray]:
    """(heights of the nodes a triangle with three finite heights uses, finite heights) over every (H, W) frame of
    ``heights`` (an (H, W) grid or a (..., H, W) stack), in the input's dtype: each frame's faces from
    :func:`grid_tin` (its own triangulation, finite faces only), the nodes they name."""
    frames = np.asarray(heights).reshape((-1, *np.shape(heights)[-2:]))
    used = []
    for frame in frames:
        with np.errstate(over="ignore"):  # grid_tin's float32 points; its faces are those of the heights as given
            faces = grid_tin(frame)[1]
        named = np.zeros(frame.size, bool)
        named[faces.reshape(-1)] = True
        used.append(frame.reshape(-1)[named])
    finite = frames[np.isfinite(frames)]
    return np.concatenate(used) if used else finite[:0], finite


def used_height_range_reference(heights: NDArray) -> tuple[float, float] | None:
    """``terrain.used_height_range``, written with the whole grid or stack at once: (min, max) of the heights a
    triangle with three finite heights uses in some frame; of the finite heights where no triangle has three; None
    when no height is finite."""
    used, finite = _used_values(heights)
    values = used if used.size else finite
    return (float(values.min()), float(values.max())) if values.size else None


def lowest_used_height_reference(heights: NDArray) -> float | None:
    """``terrain.lowest_used_height`` without a known range: the lowest height a triangle with three finite heights
    uses in some frame; None when no triangle has three."""
    used = _used_values(heights)[0]
    return float(used.min()) if used.size else None
