"""Plain NumPy references for the texture kernels (paper 004): written independently, slow, obvious.

* ``hillshade_reference``: Horn gradients with ``gdaldem -compute_edges``' border (linear extrapolation beyond an
  edge, the edge column repeated in the first and last rows), the GDAL variants in float64. ``maplibre_reference``
  repeats the edge, as MapLibre's backfilled DEM border does.
* ``shadows_reference``: brute-force ray march from every node towards the light over the nodes of its
  digital line (O(n) per node), in float64, each node taken sideways onto the straight line (linear interpolation
  towards the neighbour across it).
* ``occlusion_reference``: the horizon angle of every node over all earlier nodes of its line, per direction (the
  nodes taken onto the straight line as for the shadows).
* ``reduce_reference``: the area-weighted halving of an image axis by axis, in float64 (colour weighted by alpha in
  an image with alpha).
* ``reduce_rounded_reference``: the same halving in exact rationals, rounded half up to integers.
* ``maplibre_reference``: MapLibre GL's hillshade methods transcribed from its fragment shader, in float64.
"""

from __future__ import annotations

import math
import os
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

AZIMUTH = math.radians(315.0)
ALTITUDE = math.radians(45.0)


def find_shared(name: str) -> Path:
    """A file of the team's shared/data: $STEPTERRAIN_SHARED_DATA, else the first shared/data above the tests
    (the repository may be a worktree a level deeper than main); skip with the reason when it is absent."""
    candidates = [Path(os.environ["STEPTERRAIN_SHARED_DATA"])] if os.environ.get("STEPTERRAIN_SHARED_DATA") else []
    candidates += [parent / "shared" / "data" for parent in Path(__file__).resolve().parents]
    for folder in candidates:
        if (folder / name).exists():
            return folder / name
    pytest.skip(f"shared data {name} not found in any shared/data above {Path(__file__).parent}")


def real_dem_crop(name: str, size: int = 96, step: int = 4) -> np.ndarray:
    """A subsampled crop (size x size nodes, every ``step``-th node) of a real DEM in shared/data."""
    with np.load(find_shared(name)) as data:
        z = np.asarray(data["elevation"], dtype=np.float32)
    return np.ascontiguousarray(z[: size * step : step, : size * step : step])


def _gdal_neighbour(z: np.ndarray, di: int, dj: int) -> np.ndarray:
    """Neighbour (i + di, j + dj) of every node as gdaldem -compute_edges takes it (GDALGeneric3x3Processing):
    beyond the first/last row 2 * edge - next in the same (clamped) column; beyond the first/last column
    2 * edge - next in the same row, but in the first and last rows the edge column itself (its jmin = j); NaN
    where that touches nodata."""
    rows, cols = z.shape
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    ii, jj = i + di, j + dj
    ic, jc = np.clip(ii, 0, rows - 1), np.clip(jj, 0, cols - 1)
    out = z[ic, jc].copy()
    beyond_row = (ii < 0) | (ii >= rows)
    inner_row = np.where(ii < 0, 1, rows - 2)
    out[beyond_row] = (2 * z[ic, jc] - z[inner_row, jc])[beyond_row]
    beyond_col = ~beyond_row & ((jj < 0) | (jj >= cols))
    inner_col = np.where(jj < 0, 1, cols - 2)
    first_or_last = (i == 0) | (i == rows - 1)
    sideways = np.where(first_or_last, z[ic, jc], 2 * z[ic, jc] - z[ic, inner_col])
    out[beyond_col] = sideways[beyond_col]
    return out


def horn(heights: np.ndarray, spacing: tuple[float, float], z_factor: float = 1.0,
         edges: str = "repeat") -> tuple[np.ndarray, np.ndarray]:
    """Horn's gradient (dz/dx, dz/dy); beyond the border the edge repeats (``edges="repeat"``, MapLibre) or as
    gdaldem -compute_edges (``"gdal"``); a missing neighbour next to nodata takes the centre height."""
    z = np.asarray(heights, dtype=np.float64)
    centre = z.copy()
    padded = np.pad(z, 1, mode="edge")
    rows, cols = z.shape

    def at(di: int, dj: int) -> np.ndarray:
        if edges == "gdal":
            window = _gdal_neighbour(z, di, dj)
        else:
            window = padded[1 + di: 1 + di + rows, 1 + dj: 1 + dj + cols]
        return np.where(np.isnan(window), centre, window)

    a, b, c = at(-1, -1), at(-1, 0), at(-1, 1)
    d, f = at(0, -1), at(0, 1)
    g, h, k = at(1, -1), at(1, 0), at(1, 1)
    dx, dy = spacing
    p = ((c + 2 * f + k) - (a + 2 * d + g)) / (8 * dx) * z_factor
    q = ((g + 2 * h + k) - (a + 2 * b + c)) / (8 * dy) * z_factor
    return p, q


def lambert(p: np.ndarray, q: np.ndarray, azimuth: float, altitude: float) -> np.ndarray:
    light = (math.sin(azimuth) * math.cos(altitude), math.cos(azimuth) * math.cos(altitude), math.sin(altitude))
    return (-p * light[0] - q * light[1] + light[2]) / np.sqrt(1 + p * p + q * q)


def hillshade_reference(heights, spacing=(1.0, 1.0), azimuth=AZIMUTH, altitude=ALTITUDE,
                        z_factor=1.0, method="standard") -> np.ndarray:
    p, q = horn(heights, spacing, z_factor, edges="gdal")
    cos_i = lambert(p, q, azimuth, altitude)
    if method == "standard":
        out = np.maximum(cos_i, 0.0)
    elif method == "igor":
        slope = np.degrees(np.arctan(np.hypot(p, q)))
        diff = np.abs((np.degrees(azimuth - np.arctan2(-p, -q)) + 180.0) % 360.0 - 180.0)
        out = 1 - slope / 90 * diff / 180
    elif method == "combined":
        slope = np.arctan(np.hypot(p, q))
        out = np.clip(1 - np.arccos(np.clip(cos_i, -1, 1)) * slope / (math.pi / 2) ** 2, 0, 1)
    else:
        g2 = p * p + q * q
        total = np.zeros_like(p)
        for az_deg in (225, 270, 315, 360):
            az = math.radians(az_deg)
            shade = np.maximum(lambert(p, q, az, altitude), 0.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                total += shade * (p * math.sin(az) + q * math.cos(az)) ** 2 / g2
        out = np.where(g2 == 0, math.sin(altitude), 0.5 * total)
    return np.where(np.isnan(np.asarray(heights, dtype=np.float64)), np.nan, out)


def line_geometry(shape, spacing, azimuth):
    """Major axis, walking direction, digital-line offsets and the away-from-light unit vector (the azimuth in
    radians or as its (sin, cos)), and the straight lines' exact offsets (float64; the digital ones on a diagonal,
    whose lines run through nodes). The lines are
    anchored at the middle of the major axis and rounded symmetrically, so a layout with reversed rows or columns
    (dy or dx negated) has the same lines through the same terrain."""
    rows, cols = shape
    dx, dy = spacing
    sin_az, cos_az = azimuth if isinstance(azimuth, tuple) else (math.sin(azimuth), math.cos(azimuth))
    ti, tj = cos_az / dy, sin_az / dx
    if abs(tj) >= abs(ti):
        major_j, n_major, n_minor, slope, forward = True, cols, rows, ti / tj, (-1 if tj > 0 else 1)
    else:
        major_j, n_major, n_minor, slope, forward = False, rows, cols, tj / ti, (-1 if ti > 0 else 1)
    k = np.arange(n_major, dtype=np.float64)
    if max(abs(ti), abs(tj)) <= min(abs(ti), abs(tj)) * (1 + 1e-9):  # a diagonal: exactly through nodes
        offsets = (np.sign(slope) * k).astype(np.int64)
        exact = offsets.astype(np.float64)
    else:  # nearest to the line through the middle of the major axis, halves towards it (symmetric under flips)
        x = slope * (k - (n_major - 1) / 2)
        offsets = np.where(x >= 0, np.ceil(x - 0.5), np.floor(x + 0.5)).astype(np.int64)
        exact = x
    away = (-sin_az, -cos_az)
    return major_j, n_major, n_minor, forward, offsets, away, exact


def _line_nodes(shape, spacing, azimuth):
    """For every node: its list of earlier nodes on its line (nearest first), as index arrays per step."""
    major_j, n_major, n_minor, forward, offsets, away, _exact = line_geometry(shape, spacing, azimuth)
    rows, cols = shape
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    major = j if major_j else i
    minor = i if major_j else j
    c = minor - offsets[major]
    steps = []
    for s in range(1, n_major):
        m2 = major + forward * -s  # towards the light: against the walking direction
        inside = (m2 >= 0) & (m2 < n_major)
        m2c = np.clip(m2, 0, n_major - 1)
        b2 = c + offsets[m2c]
        inside &= (b2 >= 0) & (b2 < n_minor)
        b2c = np.clip(b2, 0, n_minor - 1)
        ii, jj = (b2c, m2c) if major_j else (m2c, b2c)
        steps.append((inside, ii, jj))
    return steps, away


def _on_straight_lines(z, spacing, azimuth):
    """Every node taken sideways (along the minor axis) onto the straight line its digital line follows: its height
    interpolated linearly towards the neighbour across the line (beyond the border or at nodata extrapolated from
    the opposite neighbour, else its own) and its (i, j) there, as float64 arrays."""
    major_j, n_major, n_minor, _forward, offsets, _away, exact = line_geometry(z.shape, spacing, azimuth)
    k = np.arange(n_major, dtype=np.float64)
    error = (offsets - exact).astype(np.float32).astype(np.float64)  # as the kernel holds it
    error[np.abs(error) < 1e-6] = 0.0  # a millionth of a node sideways (a light along an axis): not moved
    zz = z.T if major_j else z  # (major, minor)
    e = error[:, None]
    side = np.where(e > 0, -1, 1) * np.ones_like(zz, dtype=np.int64)
    minor = np.arange(n_minor)[None, :] + 0 * side

    def at(m):
        inside = (m >= 0) & (m < n_minor)
        return np.where(inside, zz[np.arange(n_major)[:, None], np.clip(m, 0, n_minor - 1)], np.nan)

    ahead, behind = at(minor + side), at(minor - side)
    change = np.where(np.isfinite(ahead), ahead - zz, np.where(np.isfinite(behind), zz - behind, 0.0))
    h = np.where(e != 0, zz + np.abs(e) * change, zz)
    position = minor - e
    major = np.broadcast_to(k[:, None], zz.shape)
    if major_j:
        return h.T, position.T, major.T
    return h, major, position


def shadows_reference(heights, spacing=(1.0, 1.0), azimuth=AZIMUTH, altitude=ALTITUDE,
                      z_factor=1.0) -> np.ndarray:
    """A node is in shadow when an earlier point of its line rises above the ray from its point to the light; every
    node is taken onto its straight line first (:func:`_on_straight_lines`), so the points of a line are collinear."""
    raw = np.asarray(heights, dtype=np.float64) * z_factor
    dx, dy = spacing
    steps, away = _line_nodes(raw.shape, spacing, azimuth)
    z, i, j = _on_straight_lines(raw, spacing, azimuth)
    z = np.where(np.isfinite(raw), z, np.nan)
    t = j * dx * away[0] + i * dy * away[1]
    tan = math.tan(altitude)
    shadow = np.zeros(z.shape, dtype=bool)
    for inside, ii, jj in steps:  # march every ray one node further towards the light
        hq = z[ii, jj]
        ray = z + (t - t[ii, jj]) * tan  # height of the ray from the node at the earlier node's distance
        shadow |= inside & np.isfinite(hq) & (hq > ray)
    shadow &= np.isfinite(z)
    return shadow.astype(np.uint8)


def compass(k, n):
    """(sin, cos) of k/n of a turn through the symmetries of the square: the angle within its quarter turn is taken
    from the nearer axis (a diagonal is sqrt(1/2) twice), so mirrored directions are exact mirror images."""
    quarter, r = divmod((4 * k) % (4 * n), n)
    near = min(r, n - r)
    a, b = math.sin(math.pi / 2 * near / n), math.cos(math.pi / 2 * near / n)
    s, c = (a, b) if 2 * r < n else (b, a) if 2 * r > n else (math.sqrt(0.5), math.sqrt(0.5))
    for _ in range(quarter):  # a quarter turn clockwise: (sin, cos) -> (cos, -sin)
        s, c = c, -s
    return s, c


def occlusion_reference(heights, spacing=(1.0, 1.0), directions=16, z_factor=1.0) -> np.ndarray:
    raw = np.asarray(heights, dtype=np.float64) * z_factor
    dx, dy = spacing
    total = np.zeros(raw.shape)
    for k in range(directions):
        steps, away = _line_nodes(raw.shape, spacing, compass(k, directions))
        z, i, j = _on_straight_lines(raw, spacing, compass(k, directions))  # every node onto its straight line
        z = np.where(np.isfinite(raw), z, np.nan)
        t = j * dx * away[0] + i * dy * away[1]
        best = np.full(z.shape, -np.inf)
        for inside, ii, jj in steps:
            hq = z[ii, jj]
            run = t - t[ii, jj]
            with np.errstate(invalid="ignore", divide="ignore"):
                tangent = np.where(inside & np.isfinite(hq) & (run > 0), (hq - z) / run, -np.inf)
            best = np.maximum(best, tangent)
        with np.errstate(invalid="ignore"):
            sine = np.where(best > 0, best / np.sqrt(1 + best * best), 0.0)
        total += sine / directions
    return np.where(np.isfinite(raw), 1 - total, np.nan)


def reduce_axis(image: np.ndarray, axis: int) -> np.ndarray:
    """Area-weighted halving along ``axis``: m = ceil(n / 2) targets, target r covers [r n/m, (r+1) n/m)."""
    a = np.moveaxis(np.asarray(image, dtype=np.float64), axis, 0)
    n = a.shape[0]
    m = max(1, (n + 1) // 2)
    out = np.zeros((m, *a.shape[1:]))
    for r in range(m):
        lo, hi = r * n / m, (r + 1) * n / m
        for s in range(int(math.floor(lo)), int(math.ceil(hi))):
            w = min(s + 1, hi) - max(s, lo)
            if w > 0:
                out[r] += a[s] * w / (n / m)
    return np.moveaxis(out, 0, axis)


def _has_alpha(image: np.ndarray) -> bool:
    """Whether a pyramid image carries alpha: 2 channels (grey + alpha) or 4 (RGBA), straight alpha."""
    return np.ndim(image) == 3 and np.shape(image)[2] in (2, 4)


def reduce_reference(image: np.ndarray) -> np.ndarray:
    """One pyramid level down (both axes), float64 before rounding. With alpha the colour is averaged weighted by
    alpha (premultiplied mean / mean alpha), the plain mean where every pixel covered is transparent."""
    plain = reduce_axis(reduce_axis(image, 0), 1)
    if not _has_alpha(image):
        return plain
    a = np.asarray(image, dtype=np.float64)
    premultiplied = reduce_axis(reduce_axis(a[..., :-1] * a[..., -1:], 0), 1)
    coverage = plain[..., -1:]
    colour = np.where(coverage > 0, premultiplied / np.where(coverage > 0, coverage, 1.0), plain[..., :-1])
    return np.concatenate([colour, coverage], axis=2)


def _reduce_exact(image: np.ndarray) -> np.ndarray:
    """The area-weighted halving in exact rationals (an object array of Fractions), unrounded."""
    a = np.asarray(image).astype(object)  # Python ints
    for axis in (0, 1):
        a = np.moveaxis(a, axis, 0)
        n = a.shape[0]
        m = max(1, (n + 1) // 2)
        out = np.empty((m, *a.shape[1:]), dtype=object)
        for r in range(m):
            lo, hi = Fraction(r * n, m), Fraction((r + 1) * n, m)
            total = Fraction(0)
            for s in range(math.floor(lo), math.ceil(hi)):
                w = min(s + 1, hi) - max(s, lo)
                if w > 0:
                    total = total + a[s] * (w / (hi - lo))
            out[r] = total
        a = np.moveaxis(out, 0, axis)
    return a


def reduce_rounded_reference(image: np.ndarray) -> np.ndarray:
    """One pyramid level down as reduce_reference (colour weighted by alpha in an image with alpha), but in exact
    rationals (Python Fractions), then rounded half up, floor(mean + 1/2), to int64: no float sum decides which way a
    tie goes."""
    mean = _reduce_exact(image)
    if _has_alpha(image):
        ints = np.asarray(image).astype(object)
        premultiplied = _reduce_exact(ints[..., :-1] * ints[..., -1:])
        coverage = mean[..., -1:]
        covered = np.vectorize(lambda v: v > 0, otypes=[bool])(coverage)
        ratio = np.empty(premultiplied.shape, dtype=object)
        for index in np.ndindex(premultiplied.shape):
            cover = coverage[index[:-1] + (0,)]
            ratio[index] = premultiplied[index] / cover if covered[index[:-1] + (0,)] else mean[index]
        mean = np.concatenate([ratio, coverage], axis=2)
    return np.vectorize(lambda v: math.floor(v + Fraction(1, 2)), otypes=[np.int64])(mean)


def maplibre_reference(heights, spacing=(1.0, 1.0), method="standard", azimuths=(AZIMUTH,), altitudes=(ALTITUDE,),
                       exaggeration=0.5, shadows=((0, 0, 0, 1),), highlights=((1, 1, 1, 1),), accent=(0, 0, 0, 1),
                       z_factor=1.0) -> np.ndarray:
    """MapLibre GL's hillshade layer, (H, W, 4) premultiplied RGBA in float64, transcribed from
    src/shaders/glsl/hillshade.fragment.glsl of maplibre/maplibre-gl-js (commit
    27688c1c2109f2ebbf7f65a773ef88598a8df75b). Colours are given premultiplied (as MapLibre's uniforms);
    ``deriv`` is the Horn gradient towards east and south. Shorter light lists repeat their last entry."""
    p, q = horn(heights, spacing, z_factor)
    n = max(len(azimuths), len(altitudes), len(shadows), len(highlights))

    def pad(values):
        values = list(values)
        return values + [values[-1]] * (n - len(values))

    azimuths, altitudes, shadows, highlights = pad(azimuths), pad(altitudes), pad(shadows), pad(highlights)
    colour = [np.asarray(c, dtype=np.float64)[None, None, :] for c in (*shadows, *highlights, accent)]
    shadow, highlight, accent_c = colour[0], colour[n], colour[-1]

    def glsl_mod(x, y):
        return x - y * np.floor(x / y)

    def get_aspect(x, y):
        with np.errstate(invalid="ignore"):
            return np.where(x != 0.0, np.arctan2(y, -x), np.pi / 2 * np.where(y > 0.0, 1.0, -1.0))

    def cang_of(x, y, az, alt):
        az = az + np.pi
        return (math.sin(alt) - (y * math.cos(az) * math.cos(alt) - x * math.sin(az) * math.cos(alt))) / np.sqrt(
            1.0 + x * x + y * y)

    def basic(x, y, az, alt, sh, hi):
        shade = np.clip(cang_of(x, y, az, alt), 0.0, 1.0)[..., None]
        return np.where(shade > 0.5, hi * (2 * shade - 1), sh * (1 - 2 * shade))

    x, y = p, -q
    if method == "standard":
        slope = np.arctan(0.625 * np.hypot(x, y))
        aspect = get_aspect(x, y)
        intensity = exaggeration
        base = 1.875 - intensity * 1.75
        max_value = 0.5 * np.pi
        scaled = ((base ** slope - 1) / (base ** max_value - 1)) * max_value if intensity != 0.5 else slope
        weight = min(max(intensity * 2.0, 0.0), 1.0)
        accent_colour = (1 - np.cos(scaled))[..., None] * accent_c * weight
        shade = np.abs(glsl_mod((aspect + azimuths[0] + np.pi) / np.pi + 0.5, 2.0) - 1.0)[..., None]
        shade_colour = (shadow * (1 - shade) + highlight * shade) * np.sin(scaled)[..., None] * weight
        out = accent_colour * (1 - shade_colour[..., 3:]) + shade_colour
    else:
        x, y = x * exaggeration * 2, y * exaggeration * 2
        steep = np.arctan(np.hypot(x, y))[..., None]
        if method == "basic":
            out = basic(x, y, azimuths[0], altitudes[0], shadow, highlight)
        elif method == "multidirectional":
            out = sum(basic(x, y, azimuths[k], altitudes[k], colour[k], colour[n + k]) for k in range(n)) / n
        elif method == "combined":
            angle = np.clip(np.arccos(np.clip(cang_of(x, y, azimuths[0], altitudes[0]), -1, 1)), 0, np.pi / 2)
            angle = angle[..., None]
            out = shadow * angle * steep * 4 / np.pi ** 2 + highlight * (np.pi / 2 - angle) * steep * 4 / np.pi ** 2
        elif method == "igor":
            slope_strength = steep * 2 / np.pi
            aspect_strength = 1 - np.abs(glsl_mod((get_aspect(x, y) + azimuths[0] + np.pi) / np.pi + 0.5, 2) - 1)
            aspect_strength = aspect_strength[..., None]
            out = shadow * slope_strength * aspect_strength + highlight * slope_strength * (1 - aspect_strength)
        else:
            raise ValueError(method)
    nodata = np.isnan(np.asarray(heights, dtype=np.float64))
    return np.where(nodata[..., None], np.nan, out)


def shadows_continuous(heights, spacing=(1.0, 1.0), azimuth=AZIMUTH, altitude=ALTITUDE, step=0.25) -> np.ndarray:
    """The shadow by definition: a node is shadowed when the terrain (bilinear between nodes) rises above the ray
    from it towards the light somewhere inside the grid, marched in steps of ``step`` of the smaller spacing."""
    z = np.asarray(heights, dtype=np.float64)
    rows, cols = z.shape
    dx, dy = spacing
    i, j = np.meshgrid(np.arange(rows, dtype=np.float64), np.arange(cols, dtype=np.float64), indexing="ij")
    di, dj = math.cos(azimuth) / dy, math.sin(azimuth) / dx  # index steps per world unit towards the light
    tan = math.tan(altitude)
    shadow = np.zeros(z.shape, dtype=bool)
    ds = step * min(abs(dx), abs(dy))
    d = ds
    while True:
        ii, jj = i + di * d, j + dj * d
        inside = (ii >= 0) & (ii <= rows - 1) & (jj >= 0) & (jj <= cols - 1)
        if not inside.any():
            return shadow.astype(np.uint8)
        i0 = np.clip(np.floor(ii).astype(int), 0, rows - 2)
        j0 = np.clip(np.floor(jj).astype(int), 0, cols - 2)
        fi, fj = ii - i0, jj - j0
        h = (z[i0, j0] * (1 - fi) * (1 - fj) + z[i0 + 1, j0] * fi * (1 - fj) + z[i0, j0 + 1] * (1 - fi) * fj
             + z[i0 + 1, j0 + 1] * fi * fj)
        shadow |= inside & (h > z + d * tan)
        d += ds
