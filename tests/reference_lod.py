"""Reference e(N) of :class:`~stepterrain.texture_lod.PatchQuadtree`: the per-patch computation the library used until
it measured a level's patches of one shape and sample pattern in one pass (``_approximation_errors``), kept verbatim
(as of the crack stitching, which made a patch sample the grid's multiples of its stride: the block's ``corner``) so
the batched pass can be checked against it bit for bit."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray


def samples_reference(first: int, last: int, stride: int) -> NDArray[np.intp]:
    """The grid lines a patch over ``first``..``last`` draws at ``stride``: the multiples of the stride within it
    (counted from the grid's first line) and its two ends."""
    start = -(-first // stride) * stride
    return np.unique(np.r_[first, np.arange(start, last + 1, stride), last]).astype(np.intp)


def approximation_error_reference(block: NDArray[np.float32], stride: int, spacing: tuple[float, float] = (1.0, 1.0),
                                  corner: tuple[int, int] = (0, 0)) -> float:
    """e(N) of one patch (the library's per-patch computation before session 45): max |h − G(N)| over the block's
    nodes with data and where a narrow coarse cell's diagonal crosses the terrain's edges
    (:func:`diagonal_gap_reference`), h the terrain's mesh and G(N) the mesh :func:`paint_with_textures` draws
    (the block's rows and columns of :func:`samples_reference`, ``corner`` the grid node of its first row and column,
    two triangles a cell split along (r, c)-(r+1, c+1) as
    :func:`~stepterrain.terrain.grid_faces`; a triangle with a nodata corner is not drawn): the largest vertical
    distance between the two surfaces, which lies at one of those points.

    A node with data that no drawn triangle covers (the approximation's hole around a nodata node is wider than the
    terrain's) counts as the coarse cell's diagonal, stride × hypot(dx, dy) in world units: γ(N) then refines the
    patch once that hole spans more than γ_user pixels on screen (its vertical distance is undefined). So does a
    nodata node that a drawn triangle covers (a void inside coarse cells whose corners have data, drawn over as
    ground): it counted 0, and a flat DEM with a lake of nodata drew its root, the lake covered, from any distance."""
    if stride <= 1:
        return 0.0
    z = np.asarray(block, dtype=np.float64)
    rows, cols = z.shape
    ri = samples_reference(corner[0], corner[0] + rows - 1, stride) - corner[0]
    ci = samples_reference(corner[1], corner[1] + cols - 1, stride) - corner[1]
    coarse = z[np.ix_(ri, ci)]
    if len(ri) == 1 or len(ci) == 1:
        return float(np.nanmax(np.abs(z - np.nanmean(coarse)))) if np.isfinite(z).any() else 0.0
    def cells(index: NDArray[np.intp], at: NDArray[np.intp], side: Any) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Each node's coarse cell along one axis (the one on ``side`` for a node on a coarse line), and its fraction
        across that cell."""
        k = np.clip(np.searchsorted(index, at, side=side) - 1, 0, len(index) - 2)
        return k, (at - index[k]) / (index[k + 1] - index[k])

    def planes(k: NDArray[np.intp], m: NDArray[np.intp], fr: NDArray[np.float64], fc: NDArray[np.float64]) -> tuple:
        """The heights of the cell's two triangles at each node: (n00, n01, n11), drawn where fc >= fr, and (n00, n11,
        n10), drawn where fc <= fr (NaN where a corner is nodata)."""
        a, b = coarse[k][:, m], coarse[k][:, m + 1]
        cc, d = coarse[k + 1][:, m], coarse[k + 1][:, m + 1]
        return a + (b - a) * fc + (d - b) * fr, a + (cc - a) * fr + (d - cc) * fc

    r = np.arange(rows)
    c = np.arange(cols)
    if np.isfinite(coarse).all():  # every triangle drawn: a node's own cell covers it
        (k, fr), (m, fc) = cells(ri, r, "right"), cells(ci, c, "right")
        fr, fc = fr[:, None], fc[None, :]
        upper, lower = planes(k, m, fr, fc)
        diff = np.abs(z - np.where(fc >= fr, upper, lower))
        error = max(float(np.nanmax(diff)) if np.isfinite(diff).any() else 0.0, diagonal_gap_reference(z, ri, ci))
        if not np.isfinite(z).all():  # a void inside the coarse cells (their corners have data): drawn over
            error = max(error, stride * math.hypot(*spacing))
        return error
    worst = np.zeros(z.shape)
    covered = np.zeros(z.shape, dtype=bool)
    # a node on a coarse row or column lies in the cells on both sides of it: where one side's triangle is not drawn
    # (a nodata corner), the other may cover it, so both sides are tried
    for side_r in ("left", "right"):
        k, fr = cells(ri, r, side_r)
        fr = fr[:, None]
        for side_c in ("left", "right"):
            m, fc = cells(ci, c, side_c)
            fc = fc[None, :]
            upper, lower = planes(k, m, fr, fc)
            for inside, value in ((fc >= fr, upper), (fc <= fr, lower)):
                drawn = inside & np.isfinite(value)  # NaN where a corner is nodata
                with np.errstate(invalid="ignore"):
                    np.fmax(worst, np.where(drawn, np.abs(z - value), 0.0), out=worst)
                covered |= drawn
    data = np.isfinite(z)
    error = float(worst[data & covered].max()) if (data & covered).any() else 0.0
    error = max(error, diagonal_gap_reference(z, ri, ci))
    if (data != covered).any():  # terrain with data left undrawn, or a void drawn over
        error = max(error, stride * math.hypot(*spacing))
    return error


def diagonal_gap_reference(z: NDArray[np.float64], ri: NDArray[np.intp], ci: NDArray[np.intp]) -> float:
    """max |h − G(N)| where the diagonal of a coarse cell that is not square crosses the terrain's edges, for
    :func:`approximation_error_reference` (0 where every coarse cell is square).

    The two meshes differ linearly on each piece of their overlay, so the largest difference lies at a node or where a
    coarse edge crosses a terrain edge. A coarse cell's sides run along the terrain's rows and columns, and a square
    one's diagonal along the terrain's diagonals through its nodes; but the first and last rows and columns of coarse
    cells are narrower than the stride where the patch's ends are no multiples of it, and their diagonals cross the
    terrain's rows, columns and diagonals between nodes, where the surfaces may lie farther apart than at any node (Big
    Tujunga, leaf_size 8: 820 of 21845 patches' e(N) fell short, by up to 7 m of 25.5). A crossing whose terrain
    triangle has a nodata corner, or whose coarse diagonal is not drawn (a nodata end, or both its cell's triangles not
    drawn), is skipped (the node rules of :func:`approximation_error_reference` count those)."""
    heights, widths = np.diff(ri), np.diff(ci)
    worst = 0.0
    for h in np.unique(heights):
        for w in np.unique(widths):
            if h == w:
                continue
            # the diagonal (r, c) = t · (h, w) crosses the terrain's rows at t = i / h, its columns at j / w and its
            # diagonals at k / |w − h|
            skew = abs(int(w) - int(h))
            t = np.unique(np.concatenate([np.arange(1, h) / h, np.arange(1, w) / w, np.arange(1, skew) / skew]))
            if not len(t):
                continue
            k, m = np.nonzero(heights == h)[0], np.nonzero(widths == w)[0]
            r = ri[k][:, None, None] + t * h  # (cells' rows, cells' columns, crossings)
            c = ci[m][None, :, None] + t * w
            i0 = np.clip(np.floor(r).astype(np.intp), 0, z.shape[0] - 2)
            j0 = np.clip(np.floor(c).astype(np.intp), 0, z.shape[1] - 2)
            fr, fc = r - i0, c - j0
            a, b, cc, d = z[i0, j0], z[i0, j0 + 1], z[i0 + 1, j0], z[i0 + 1, j0 + 1]
            terrain = np.where(fc >= fr, a + (b - a) * fc + (d - b) * fr, a + (cc - a) * fr + (d - cc) * fc)
            start = z[np.ix_(ri[k], ci[m])][..., None]
            end = z[np.ix_(ri[k] + h, ci[m] + w)][..., None]
            gap = np.abs(terrain - (start + (end - start) * t))
            # the diagonal is drawn where one of its cell's two triangles is: both other corners nodata, it is not
            drawn = np.isfinite(z[np.ix_(ri[k], ci[m] + w)]) | np.isfinite(z[np.ix_(ri[k] + h, ci[m])])
            gap = np.where(drawn[..., None], gap, np.nan)
            if np.isfinite(gap).any():
                worst = max(worst, float(np.nanmax(gap)))
    return worst
