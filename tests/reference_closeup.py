"""A plain NumPy reference of the close-up transform and culling (paper 001 §II.B), written independently.

It runs over the *whole* terrain mesh, as the paper does (every close-up sees every triangle), so it also
checks that the library's ROI windows lose nothing.
"""

from __future__ import annotations

import math

import numpy as np


def bilinear_mask(mask: np.ndarray, box: tuple[float, float, float, float], x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """m at world (x, y): the mask's texels spread over box (xmin, xmax, ymin, ymax), row 0 at ymin; 0 outside."""
    xmin, xmax, ymin, ymax = box
    rows, cols = mask.shape
    out = np.zeros(len(x))
    for n in range(len(x)):  # plainly, one point at a time
        u = (x[n] - xmin) / (xmax - xmin)
        v = (y[n] - ymin) / (ymax - ymin)
        if not (0 <= u <= 1 and 0 <= v <= 1):
            continue
        fx, fy = u * (cols - 1), v * (rows - 1)
        j = min(int(math.floor(fx)), cols - 2)
        i = min(int(math.floor(fy)), rows - 2)
        tx, ty = fx - j, fy - i
        out[n] = ((1 - tx) * (1 - ty) * mask[i, j] + tx * (1 - ty) * mask[i, j + 1]
                  + (1 - tx) * ty * mask[i + 1, j] + tx * ty * mask[i + 1, j + 1])
    return out


def close_up_matrix(cx: float, cy: float, cz: float, alpha: float, beta: float, scale, offset) -> np.ndarray:
    """M = T(O + p)·R_z(β)·R_x(α)·S·T(−O) built from elementary 4 x 4 matrices."""

    def translate(v):
        m = np.eye(4)
        m[:3, 3] = v
        return m

    rx = np.eye(4)
    rx[1:3, 1:3] = [[math.cos(alpha), -math.sin(alpha)], [math.sin(alpha), math.cos(alpha)]]
    rz = np.eye(4)
    rz[0:2, 0:2] = [[math.cos(beta), -math.sin(beta)], [math.sin(beta), math.cos(beta)]]
    s = np.diag([*scale, 1.0])
    o = np.array([cx, cy, cz])
    return translate(o + np.asarray(offset)) @ rz @ rx @ s @ translate(-o)


def transform(vertices: np.ndarray, m: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """V_C = (m·M + (1 − m)·I)·V_O per vertex, float64."""
    out = np.empty_like(vertices, dtype=np.float64)
    for n in range(len(vertices)):
        c = m[n] * matrix + (1 - m[n]) * np.eye(4)
        out[n] = (c @ np.append(vertices[n], 1.0))[:3]
    return out


def culled_faces(faces: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Indices of the faces with a corner of m > 0."""
    return np.array([f for f in range(len(faces)) if max(m[faces[f]]) > 0], dtype=np.int64)


def surface_heights(vertices: np.ndarray, faces: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height of the mesh surface at world points xy (N, 2): the plane of a triangle whose xy holds the point
    (brute force over every triangle, barycentric); NaN where none does."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    a, b, c = corners[:, 0, :2], corners[:, 1, :2], corners[:, 2, :2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    out = np.full(len(xy), np.nan)
    for n, p in enumerate(np.asarray(xy, dtype=np.float64)):  # plainly, one point at a time
        u = ((p[0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (p[1] - a[:, 1])) / det
        v = ((b[:, 0] - a[:, 0]) * (p[1] - a[:, 1]) - (p[0] - a[:, 0]) * (b[:, 1] - a[:, 1])) / det
        inside = np.flatnonzero((u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9))
        if len(inside):
            f = inside[0]
            z = corners[f, :, 2]
            out[n] = z[0] + u[f] * (z[1] - z[0]) + v[f] * (z[2] - z[0])
    return out


def nodata_gradient(heights: np.ndarray, dy: float, dx: float) -> tuple[np.ndarray, np.ndarray]:
    """(dh/dy, dh/dx) of a grid with NaN for nodata, node by node and axis by axis: the central difference where both
    neighbours have a height, else the one-sided difference to the one that has; NaN where none has (or the node is
    nodata). Steps are signed: the derivatives are along the world's +y and +x."""
    h = np.asarray(heights, dtype=np.float64)
    rows, cols = h.shape
    out = np.full((2, rows, cols), np.nan)
    for i in range(rows):  # plainly, one node at a time
        for j in range(cols):
            if math.isnan(h[i, j]):
                continue
            for axis, (di, dj), step in ((0, (1, 0), dy), (1, (0, 1), dx)):
                before = h[i - di, j - dj] if i - di >= 0 and j - dj >= 0 else math.nan
                after = h[i + di, j + dj] if i + di < rows and j + dj < cols else math.nan
                if not math.isnan(before) and not math.isnan(after):
                    out[axis, i, j] = (after - before) / (2.0 * step)
                elif not math.isnan(after):
                    out[axis, i, j] = (after - h[i, j]) / step
                elif not math.isnan(before):
                    out[axis, i, j] = (h[i, j] - before) / step
    return out[0], out[1]


def drawn_min_height(heights: np.ndarray) -> float:
    """The close-up's pivot height: the lowest height of a grid node on a drawn triangle, one whose three corners
    have finite heights; each cell (i, j) cut into (n00, n01, n11) and (n00, n11, n10). A finite node on no such
    triangle is in no mesh. Where no triangle is drawn, the lowest finite height."""
    h = np.asarray(heights, dtype=np.float64)
    rows, cols = h.shape
    index = np.arange(rows * cols).reshape(rows, cols)
    n00, n01 = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    n11, n10 = index[1:, 1:].ravel(), index[1:, :-1].ravel()
    triangles = np.concatenate([np.stack([n00, n01, n11], axis=1), np.stack([n00, n11, n10], axis=1)])
    flat = h.ravel()
    drawn = triangles[np.isfinite(flat[triangles]).all(axis=1)]
    return float(flat[np.unique(drawn)].min()) if len(drawn) else float(np.nanmin(h))
