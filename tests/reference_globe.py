"""Plain NumPy / Python references for the cube sphere of paper 003 (small grids only: loops per node).

Written independently of the kernels' index arithmetic: the hierarchy comes from explicitly bisecting
triangles from the roots (children (c, a, m), (b, c, m)), and node relations are collected from that tree,
keyed by the nodes' 3D cube points, so seams are handled by geometry rather than by folding formulas.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

# paper 003 §4 table: local (x, y, z) -> 3D, as rows (image of x, image of y, image of the normal)
FRAMES = {
    0: np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
    1: np.array([[0, 0, 1], [0, -1, 0], [1, 0, 0]]),
    2: np.array([[0, 0, -1], [-1, 0, 0], [0, 1, 0]]),
    3: np.array([[-1, 0, 0], [0, 0, -1], [0, -1, 0]]),
    4: np.array([[0, -1, 0], [0, 0, 1], [-1, 0, 0]]),
    5: np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]]),
}


def cube_point(face: int, i: int, j: int, cells: int) -> tuple[int, int, int]:
    """3D integer point of in-face node (i, j): x = 2j - N, y = 2i - N, z = N in the face frame."""
    local = np.array([2 * j - cells, 2 * i - cells, cells])
    return tuple(int(v) for v in local @ FRAMES[face])


def entries_by_point(cells: int) -> dict[tuple[int, int, int], list[int]]:
    """All entries (face, i, j flattened) of each cube point."""
    n = cells + 1
    out: dict[tuple[int, int, int], list[int]] = defaultdict(list)
    for f in range(6):
        for i in range(n):
            for j in range(n):
                out[cube_point(f, i, j, cells)].append(f * n * n + i * n + j)
    return out


def positions(heights: np.ndarray, cells: int, radius: float) -> np.ndarray:
    """(6 n², 3) float64 positions (R + z) w / |w| from the per-entry heights."""
    n = cells + 1
    out = np.empty((6 * n * n, 3))
    for f in range(6):
        for i in range(n):
            for j in range(n):
                w = np.array(cube_point(f, i, j, cells), dtype=np.float64)
                out[f * n * n + i * n + j] = (radius + heights[f * n * n + i * n + j]) * w / np.linalg.norm(w)
    return out


def splits(a: tuple[int, int], b: tuple[int, int]) -> bool:
    """Whether hypotenuse a-b has a grid node at its midpoint."""
    return (a[0] + b[0]) % 2 == 0 and (a[1] + b[1]) % 2 == 0


def bisection_tree(cells: int):
    """Walk the full bintree from the 12 roots. Returns (triangles per depth as point triples,
    children: point -> set of child points, hypotenuse: point -> (a, b) points)."""
    n = cells + 1
    children: dict = defaultdict(set)
    hypotenuse: dict = {}
    levels = []
    current = []
    for f in range(6):
        a, b, c, d = (0, 0), (cells, cells), (cells, 0), (0, cells)  # (i, j)
        current.append((f, a, b, c))
        current.append((f, b, a, d))
    depth_max = 2 * int(round(math.log2(cells)))
    for _ in range(depth_max + 1):
        levels.append(current)
        nxt = []
        for f, a, b, c in current:
            if not splits(a, b):
                continue
            m = ((a[0] + b[0]) // 2, (a[1] + b[1]) // 2)
            pm = cube_point(f, *m, cells)
            hypotenuse[pm] = (cube_point(f, *a, cells), cube_point(f, *b, cells))
            for child in ((f, c, a, m), (f, b, c, m)):
                ca, cb = child[1], child[2]
                if splits(ca, cb):
                    cm = ((ca[0] + cb[0]) // 2, (ca[1] + cb[1]) // 2)
                    children[pm].add(cube_point(f, *cm, cells))
                nxt.append(child)
        current = nxt
    del n
    return levels, children, hypotenuse


def node_parameters(pos32: np.ndarray, cells: int, exact: np.ndarray | None = None
                    ) -> dict[tuple[int, int, int], tuple[float, float, float, float]]:
    """Exact (float64, no margins) e, r, h, α per cube point from the float32 positions; e from ``exact`` (the float64
    positions of :func:`positions`, which the mesh's vertices have) when given."""
    by_point = entries_by_point(cells)
    p = {pt: pos32[entries[0]].astype(np.float64) for pt, entries in by_point.items()}
    q = p if exact is None else {pt: exact[entries[0]] for pt, entries in by_point.items()}
    _, children, hypotenuse = bisection_tree(cells)
    out: dict = {}

    def visit(pt):
        if pt in out:
            return out[pt]
        v = p[pt]
        a, b = hypotenuse[pt]
        e = float(np.linalg.norm(q[pt] - 0.5 * (q[a] + q[b])))
        r = h = alpha = 0.0
        for c in children.get(pt, ()):
            ce, cr, ch, ca = visit(c)
            pc = p[c]
            e = max(e, ce)
            r = max(r, float(np.linalg.norm(v - pc)) + cr)
            h = max(h, abs(float(np.linalg.norm(v)) - float(np.linalg.norm(pc))) + ch)
            cos = float(v @ pc) / (np.linalg.norm(v) * np.linalg.norm(pc))
            alpha = max(alpha, math.acos(min(1.0, cos)) + ca)
        out[pt] = (e, r, h, alpha)
        return out[pt]

    for pt in hypotenuse:
        visit(pt)
    return out


def descendants(pt, children) -> set:
    """Every node below ``pt`` in the hierarchy."""
    seen: set = set()
    stack = list(children.get(pt, ()))
    while stack:
        c = stack.pop()
        if c not in seen:
            seen.add(c)
            stack.extend(children.get(c, ()))
    return seen


# ------------------------------------------------------------------------------------------ shape distances
def cone_surface_samples(p: np.ndarray, h: float, alpha: float, count: int = 60) -> np.ndarray:
    """Points densely covering the surface of a cone frustum about p's radial axis (top, bottom, mantle)."""
    axis = p / np.linalg.norm(p)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    w = np.cross(axis, u)
    phi = np.linspace(0, 2 * np.pi, 2 * count, endpoint=False)
    theta = np.linspace(0, alpha, count)
    radii = np.linspace(np.linalg.norm(p) - h, np.linalg.norm(p) + h, count)
    pts = []
    for rad in (radii[0], radii[-1]):  # bottom and top caps
        t, f = np.meshgrid(theta, phi)
        d = (np.cos(t)[..., None] * axis + np.sin(t)[..., None] * (np.cos(f)[..., None] * u + np.sin(f)[..., None] * w))
        pts.append((rad * d).reshape(-1, 3))
    rr, f = np.meshgrid(radii, phi)  # mantle
    d = np.cos(alpha) * axis + np.sin(alpha) * (np.cos(f)[..., None] * u + np.sin(f)[..., None] * w)
    pts.append((rr[..., None] * d).reshape(-1, 3))
    return np.concatenate(pts)


def inside_cone(x: np.ndarray, p: np.ndarray, h: float, alpha: float) -> bool:
    """Whether point x lies inside the cone frustum."""
    r = np.linalg.norm(x)
    cos = float(x @ p) / (r * np.linalg.norm(p))
    return bool(math.acos(min(1.0, cos)) <= alpha and np.linalg.norm(p) - h <= r <= np.linalg.norm(p) + h)


def bilinear_latlon(z: np.ndarray, lat: np.ndarray, lon: np.ndarray, qlat: float, qlon: float) -> float:
    """Bilinear value of a regular, north-to-south, cell-centred global grid at (qlat, qlon) in degrees,
    wrapping in longitude; between the outer rows and the poles, blended to the row mean."""
    dlat = lat[0] - lat[1]
    dlon = lon[1] - lon[0]
    cols = len(lon)

    def row(k: int) -> float:
        fc = ((qlon - lon[0]) / dlon) % cols
        c0 = int(math.floor(fc)) % cols
        t = fc - math.floor(fc)
        return (1 - t) * z[k, c0] + t * z[k, (c0 + 1) % cols]

    fr = (lat[0] - qlat) / dlat
    if fr <= 0:
        w = (qlat - lat[0]) / (90.0 - lat[0])
        return (1 - w) * row(0) + w * z[0].mean()
    if fr >= len(lat) - 1:
        w = (lat[-1] - qlat) / (lat[-1] + 90.0)
        return (1 - w) * row(len(lat) - 1) + w * z[-1].mean()
    r0 = int(math.floor(fr))
    t = fr - r0
    return (1 - t) * row(r0) + t * row(r0 + 1)
