"""Warp kernels of the terrain textures (paper 004, Döllner, Baumann & Hinrichs 2000, §3.2, §5-7).

Topographic textures (§7): Horn-gradient hillshade in the GDAL conventions (standard, multidirectional,
combined, igor) and MapLibre GL's hillshade methods as premultiplied RGBA (its hillshade.fragment.glsl),
self-shadowing by sweeping digital lines along the light's azimuth with a running horizon (one thread per line,
O(1) per pixel, §7.2 and Fig. 5), horizon-based ambient occlusion with a per-line convex hull, normals encoded
as RGB and relit by a directional or a point light (§7.4, Fig. 7). Layer operations (§3.2.3):
sampling a layer through its texture matrix, blending by an alpha layer, weighted addition, modulation and the
per-layer adjustments of CesiumJS imagery layers. Image pyramids (§3.2.1): area-weighted halving of any size.

Conventions (shared with ``stepterrain.texture`` and ``tests/reference_texture.py``):

* Every kernel takes ``thread_offset`` first: thread k handles element ``wp.tid() + thread_offset``
  (``stepterrain._device.launch`` splits a CPU pass over several cores).
* Grid node (i, j) sits at local (j * dx, i * dy); ``dx`` or ``dy`` may be negative (north-up rasters have
  dy < 0). World +y is north; azimuths are clockwise from north, altitudes above the horizon, radians.
* Images are (H, W) or (H, W, 4) float32 RGBA in [0, 1], pixel (i, j) = grid node (i, j).
* A sweep line is a digital line: along its major axis it visits every index once; its minor index is
  ``c + minor_offsets[major]`` with ``minor_offsets[k] = round(slope * (k - (n_major - 1) / 2))``, halves towards
  0 (``stepterrain.texture._digital_lines``), so lines with consecutive integer ``c`` partition the grid. The ray of
  a node towards the light visits the nodes of its own line. Distances along the light are measured from the
  grid's centre: with the lines' symmetric rounding, a layout with its rows or columns reversed (dy or dx
  negated) sweeps the same nodes with the same float32 values.
"""

from __future__ import annotations

import warp as wp

from .memory import load, store

wp.set_module_options({"enable_backward": False, "optimization_level": 3, "fuse_fp": False})  # see kernels/__init__

HALF_PI_SQUARED_INV = 0.40528473456935108  # 1 / (pi / 2)^2, GDAL's INV_SQUARE_OF_HALF_PI
SHADE_RUN = wp.constant(64)  # pixels of a row one hillshade thread shades (amortises the per-thread cost on CPUs)


@wp.struct
class HeightGrid:
    """A regular heightfield: node (i, j) at local (j * dx, i * dy), heights scaled by ``z_factor``."""

    heights: wp.array2d[wp.float32]
    rows: wp.int32
    cols: wp.int32
    spacing: wp.vec2
    z_factor: wp.float32
    gradient_scale: wp.vec2  # (z_factor / (8 dx), z_factor / (8 dy)): Horn's weights as one multiply
    has_nodata: wp.int32  # 0 when every height is finite: the kernels skip their NaN checks


@wp.struct
class Sweep:
    """Digital lines parallel to the light's azimuth, walked away from the light.

    ``major_j`` 1: lines advance along columns (j is the major index), 0: along rows. ``forward`` +1 walks the
    major index upwards, -1 downwards. Line k has minor index ``k + c_min + minor_offsets[major]``.
    ``away`` is the horizontal unit vector pointing away from the light (world x, y).
    """

    minor_offsets: wp.array[wp.int32]
    # minor_offsets[k] less the straight line's exact minor offset at major index k (in [-0.5, 0.5]; 0 on a diagonal)
    minor_error: wp.array[wp.float32]
    n_lines: wp.int32
    increasing: wp.int32  # 1 when minor_offsets never decreases (slope >= 0), 0 when it never increases
    major_j: wp.int32
    n_major: wp.int32
    n_minor: wp.int32
    forward: wp.int32
    c_min: wp.int32
    away: wp.vec2
    rise: wp.vec2  # tan(altitude) * distance away from the light per column (x) and per row (y) index


@wp.struct
class Adjustment:
    """Per-layer adjustments of a CesiumJS imagery layer, plus the layer's split and cutout."""

    alpha: wp.float32
    brightness: wp.float32
    contrast: wp.float32
    hue: wp.float32
    saturation: wp.float32
    one_over_gamma: wp.float32
    split_side: wp.int32  # 0 none, -1 keep u < split_position, +1 keep u >= split_position
    split_position: wp.float32
    has_cutout: wp.int32
    cutout: wp.vec4  # (xmin, xmax, ymin, ymax) in world units, made transparent


@wp.struct
class PixelFrame:
    """Where pixel centres lie: pixel (i, j) at world (x0 + j * px, y0 + i * py)."""

    rows: wp.int32
    cols: wp.int32
    origin: wp.vec2
    pixel: wp.vec2


@wp.struct
class MapLibreStyle:
    """A MapLibre GL hillshade layer's paint: its method, ``hillshade-exaggeration``, the lights
    (``hillshade-illumination-direction`` / ``-altitude``, radians) with their shadow and highlight colours, and
    the accent colour; colours premultiplied RGBA, as MapLibre hands them to its shader."""

    method: wp.int32  # 0 standard (legacy), 1 basic, 2 combined, 3 igor, 4 multidirectional
    exaggeration: wp.float32
    azimuths: wp.array(dtype=wp.float32)
    altitudes: wp.array(dtype=wp.float32)
    shadows: wp.array(dtype=wp.vec4)
    highlights: wp.array(dtype=wp.vec4)
    accent: wp.vec4


@wp.func
def pixel_of(n: wp.int32, cols: wp.int32):
    """(row, column) of element ``n`` of a row-major image ``cols`` wide: a per-pixel thread's pixel."""
    i = n // cols
    return i, n - i * cols


# ---------------------------------------------------------------------------------------------------------
# topographic textures
# ---------------------------------------------------------------------------------------------------------


@wp.func
def window_height(grid: HeightGrid, i: wp.int32, j: wp.int32, di: wp.int32, dj: wp.int32, centre: wp.float32,
                  extrapolate: wp.int32) -> wp.float32:
    """Height of the neighbour (i + di, j + dj) of node (i, j); ``centre`` where it is nodata (NaN).

    Beyond the grid, with ``extrapolate`` as ``gdaldem -compute_edges`` takes it: beyond the first or last row
    2 · edge − next along the column (GDAL's ``INTERPOL``), the column clamped to the grid; beyond the first or
    last column 2 · edge − next along the row, except in the first and last rows, where the edge column is
    repeated (GDAL's ``jmin = j``); ``centre`` where that is nodata. Without, the nearest edge node (MapLibre
    backfills a DEM tile's border with its nearest pixel)."""
    ii = i + di
    jj = j + dj
    value = wp.float32(0.0)
    if extrapolate == 0 or (ii >= 0 and ii < grid.rows and jj >= 0 and jj < grid.cols):
        value = grid.heights[wp.clamp(ii, 0, grid.rows - 1), wp.clamp(jj, 0, grid.cols - 1)]
    elif ii < 0 or ii >= grid.rows:
        edge = wp.clamp(ii, 0, grid.rows - 1)
        inner = wp.where(ii < 0, 1, grid.rows - 2)
        column = wp.clamp(jj, 0, grid.cols - 1)
        value = 2.0 * grid.heights[edge, column] - grid.heights[inner, column]
    else:
        edge = wp.clamp(jj, 0, grid.cols - 1)
        if i == 0 or i == grid.rows - 1:
            value = grid.heights[ii, edge]
        else:
            inner = wp.where(jj < 0, 1, grid.cols - 2)
            value = 2.0 * grid.heights[ii, edge] - grid.heights[ii, inner]
    if wp.isnan(value):
        return centre
    return value


@wp.func
def horn_gradient(grid: HeightGrid, i: wp.int32, j: wp.int32, extrapolate: wp.int32) -> wp.vec2:
    """(dz/dx, dz/dy) at node (i, j) by Horn's 3 x 3 weights, times the z factor (world units); the window's
    missing neighbours as :func:`window_height` takes them (``extrapolate``: gdaldem's border)."""
    e = grid.heights[i, j]
    a = window_height(grid, i, j, -1, -1, e, extrapolate)
    b = window_height(grid, i, j, -1, 0, e, extrapolate)
    c = window_height(grid, i, j, -1, 1, e, extrapolate)
    d = window_height(grid, i, j, 0, -1, e, extrapolate)
    f = window_height(grid, i, j, 0, 1, e, extrapolate)
    g = window_height(grid, i, j, 1, -1, e, extrapolate)
    h = window_height(grid, i, j, 1, 0, e, extrapolate)
    k = window_height(grid, i, j, 1, 1, e, extrapolate)
    return horn_weights(grid.gradient_scale, a, b, c, d, f, g, h, k)


@wp.func
def horn_weights(
    scale: wp.vec2,
    a: wp.float32,
    b: wp.float32,
    c: wp.float32,
    d: wp.float32,
    f: wp.float32,
    g: wp.float32,
    h: wp.float32,
    k: wp.float32,
) -> wp.vec2:
    """Horn's gradient of the window a b c / d e f / g h k (row i-1 first), times the z factor."""
    dzdx = ((c + 2.0 * f + k) - (a + 2.0 * d + g)) * scale[0]
    dzdy = ((g + 2.0 * h + k) - (a + 2.0 * b + c)) * scale[1]
    return wp.vec2(dzdx, dzdy)


@wp.func
def light_vector(azimuth: wp.float32, altitude: wp.float32) -> wp.vec3:
    """Unit vector towards a light at ``azimuth`` (clockwise from north) and ``altitude``."""
    return wp.vec3(wp.sin(azimuth) * wp.cos(altitude), wp.cos(azimuth) * wp.cos(altitude), wp.sin(altitude))


@wp.func
def surface_normal(gradient: wp.vec2) -> wp.vec3:
    """Unit normal (-p, -q, 1) / sqrt(1 + p^2 + q^2) of a surface with gradient (p, q)."""
    return wp.normalize(wp.vec3(-gradient[0], -gradient[1], 1.0))


@wp.func
def shade_at(gradient: wp.vec2, light: wp.vec3, method: wp.int32, altitude: wp.float32,
             azimuth: wp.float32) -> wp.float32:
    """Hillshade in [0, 1]: 0 standard (Lambert, clamped), 1 multidirectional, 2 combined, 3 igor (GDAL's
    variants, also MapLibre's ``hillshade-method``)."""
    if method == 3:
        # GDAL -igor: 1 - (slope / 90 deg) * (angle between the light's azimuth and the downhill aspect) / 180 deg
        slope = wp.atan(wp.length(gradient))
        diff = wp.abs(azimuth - wp.atan2(-gradient[0], -gradient[1]))
        diff = diff - 6.283185307179586 * wp.floor(diff / 6.283185307179586)
        if diff > 3.141592653589793:
            diff = 6.283185307179586 - diff
        return 1.0 - slope / 1.5707963267948966 * diff / 3.141592653589793
    if method == 1:
        n = surface_normal(gradient)
        # GDAL's multidirectional (after USGS OF 92-422): four lights at 225, 270, 315, 360 degrees, each
        # weighted by cos^2(aspect - azimuth), aspect the downhill azimuth (the weights sum to 2).
        p = gradient[0]
        q = gradient[1]
        pp_qq = p * p + q * q
        if pp_qq == 0.0:
            return wp.sin(altitude)
        total = wp.float32(0.0)
        for k in range(4):
            az = (225.0 + 45.0 * float(k)) * 0.017453292519943295
            s = wp.max(wp.dot(n, light_vector(az, altitude)), 0.0)
            # cos^2(aspect - az) with aspect = atan2(-p, -q): ((-p, -q) . (sin az, cos az))^2 / |grad|^2
            along = p * wp.sin(az) + q * wp.cos(az)
            total += s * along * along / pp_qq
        return 0.5 * total
    cos_incidence = (light[2] - gradient[0] * light[0] - gradient[1] * light[1]) / wp.sqrt(
        1.0 + gradient[0] * gradient[0] + gradient[1] * gradient[1])
    if method == 2:
        # GDAL -combined: 1 - (angle between normal and light) * slope / (pi / 2)^2
        slope = wp.atan(wp.length(gradient))
        value = 1.0 - wp.acos(wp.clamp(cos_incidence, -1.0, 1.0)) * slope * HALF_PI_SQUARED_INV
        return wp.clamp(value, 0.0, 1.0)
    return wp.max(cos_incidence, 0.0)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return 0;
#else
if (heights.strides[1] != (int)sizeof(float) || out.strides[1] != (int)sizeof(float)
        || (shadowed && shadow.strides[1] != 1)) {
    return 0;
}
typedef float f16 __attribute__((ext_vector_type(16)));
typedef int i16 __attribute__((ext_vector_type(16)));
typedef unsigned char u16 __attribute__((ext_vector_type(16)));
const char* base = reinterpret_cast<const char*>(heights.data);
const float* up = reinterpret_cast<const float*>(base + (long long)(i - 1) * heights.strides[0]);
const float* mid = reinterpret_cast<const float*>(base + (long long)i * heights.strides[0]);
const float* down = reinterpret_cast<const float*>(base + (long long)(i + 1) * heights.strides[0]);
float* row = reinterpret_cast<float*>(reinterpret_cast<char*>(out.data) + (long long)i * out.strides[0]);
const unsigned char* dark = nullptr;
if (shadowed) {
    dark = reinterpret_cast<const unsigned char*>(shadow.data) + (long long)i * shadow.strides[0];
}
const float s0 = scale[0], s1 = scale[1], l0 = light[0], l1 = light[1], l2 = light[2];
const float keep = 1.0f - strength;
int j = lo;
for (; j + 16 <= hi; j += 16) {
    f16 a, b, c, d, f, g, h, k;
    __builtin_memcpy(&a, up + j - 1, sizeof(a));
    __builtin_memcpy(&b, up + j, sizeof(b));
    __builtin_memcpy(&c, up + j + 1, sizeof(c));
    __builtin_memcpy(&d, mid + j - 1, sizeof(d));
    __builtin_memcpy(&f, mid + j + 1, sizeof(f));
    __builtin_memcpy(&g, down + j - 1, sizeof(g));
    __builtin_memcpy(&h, down + j, sizeof(h));
    __builtin_memcpy(&k, down + j + 1, sizeof(k));
    const f16 p = ((c + 2.0f * f + k) - (a + 2.0f * d + g)) * s0;
    const f16 q = ((g + 2.0f * h + k) - (a + 2.0f * b + c)) * s1;
    const f16 v = (l2 - p * l0 - q * l1) / __builtin_elementwise_sqrt(1.0f + p * p + q * q);
    i16 bits = __builtin_bit_cast(i16, v) & (i16)(v >= 0.0f);  // max(v, 0): v >= 0 ? v : +0 (NaN: +0)
    if (shadowed) {
        u16 s;
        __builtin_memcpy(&s, dark + j, sizeof(s));
        const i16 lit = (i16)(__builtin_convertvector(s, i16) == 0);
        const i16 dimmed = __builtin_bit_cast(i16, __builtin_bit_cast(f16, bits) * keep);
        bits = (bits & lit) | (dimmed & ~lit);
    }
    __builtin_memcpy(row + j, &bits, sizeof(bits));
}
for (; j < hi; ++j) {
    const float a = up[j - 1], b = up[j], c = up[j + 1], d = mid[j - 1], f = mid[j + 1];
    const float g = down[j - 1], h = down[j], k = down[j + 1];
    const float p = ((c + 2.0f * f + k) - (a + 2.0f * d + g)) * s0;
    const float q = ((g + 2.0f * h + k) - (a + 2.0f * b + c)) * s1;
    const float v = (l2 - p * l0 - q * l1) / ::sqrtf(1.0f + p * p + q * q);
    float value = v >= 0.0f ? v : 0.0f;
    if (shadowed && dark[j] != 0) {
        value = value * keep;
    }
    row[j] = value;
}
return 1;
#endif
""")
def shade_interior_run(
    heights: wp.array2d[wp.float32], shadow: wp.array2d[wp.uint8], shadowed: wp.bool, strength: wp.float32,
    i: wp.int32, lo: wp.int32, hi: wp.int32, scale: wp.vec2, light: wp.vec3, out: wp.array2d[wp.float32],
) -> wp.int32:  # pragma: no cover - native code
    """On the CPU: the standard hillshade of interior pixels (i, lo..hi-1) of an interior row without nodata,
    sixteen at a time (vector loads, IEEE division and square root: the same values, bit for bit, as
    :func:`shade_heights`' loop, in the same order of operations, which ``fuse_fp=False`` keeps), times
    ``1 - strength`` where ``shadow`` marks them; returns 1. Otherwise (CUDA, or rows that are not contiguous)
    0: nothing written."""
    ...


@wp.kernel
def shade_heights(
    thread_offset: wp.int32,
    grid: HeightGrid,
    light: wp.vec3,
    altitude: wp.float32,
    azimuth: wp.float32,
    method: wp.int32,
    shadow: wp.array2d[wp.uint8],
    shadow_strength: wp.float32,
    # outputs
    shade_out: wp.array2d[wp.float32],
):
    """One thread per run of up to SHADE_RUN pixels of a row: their hillshade in [0, 1], times
    1 - shadow_strength where ``shadow`` (same shape, or 0 x 0 for none) marks them shadowed; NaN at nodata.

    Interior pixels slide the 3 x 3 window along the row (three new heights per pixel); the border and the
    neighbours of nodata take the careful path (gdaldem -compute_edges: :func:`window_height`)."""
    t = wp.tid() + thread_offset
    runs = (grid.cols + SHADE_RUN - 1) // SHADE_RUN
    i = t // runs
    j0 = (t - i * runs) * SHADE_RUN
    j1 = wp.min(j0 + SHADE_RUN, grid.cols)
    shadowed = shadow.shape[0] == grid.rows
    heights = grid.heights
    scale = grid.gradient_scale
    interior_row = i > 0 and i < grid.rows - 1
    if grid.has_nodata == 0 and interior_row and method == 0:
        # the common case: no nodata, standard shading; a tight loop over the run's interior pixels
        lo = wp.max(j0, 1)
        hi = wp.min(j1, grid.cols - 1)
        j = lo
        if shade_interior_run(heights, shadow, shadowed, shadow_strength, i, lo, hi, scale, light, shade_out) != 0:
            j = hi  # the CPU's vector rows did it
        # CUDA (and rows that are not contiguous): the window slides along the row, three new heights a pixel
        # (unchecked loads and stores, kernels/memory.py: every index here is inside the grid)
        a = wp.float32(0.0)
        d = wp.float32(0.0)
        g = wp.float32(0.0)
        b = wp.float32(0.0)
        e = wp.float32(0.0)
        h = wp.float32(0.0)
        if j < hi:
            a = load(heights, i - 1, j - 1)
            d = load(heights, i, j - 1)
            g = load(heights, i + 1, j - 1)
            b = load(heights, i - 1, j)
            e = load(heights, i, j)
            h = load(heights, i + 1, j)
        while j < hi:  # (a while loop: Warp's dynamic range() costs about 3 ns an iteration on the CPU)
            c = load(heights, i - 1, j + 1)
            f = load(heights, i, j + 1)
            k = load(heights, i + 1, j + 1)
            p = ((c + 2.0 * f + k) - (a + 2.0 * d + g)) * scale[0]
            q = ((g + 2.0 * h + k) - (a + 2.0 * b + c)) * scale[1]
            value = wp.max((light[2] - p * light[0] - q * light[1]) / wp.sqrt(1.0 + p * p + q * q), 0.0)
            if shadowed:
                if load(shadow, i, j) != wp.uint8(0):
                    value = value * (1.0 - shadow_strength)
            store(shade_out, i, j, value)
            a = b
            b = c
            d = e
            e = f
            g = h
            h = k
            j += 1
        for side in range(2):  # the row's border pixels, if this run holds them
            j = wp.where(side == 0, 0, grid.cols - 1)
            if j >= j0 and j < j1:
                value = shade_at(horn_gradient(grid, i, j, 1), light, method, altitude, azimuth)
                if shadowed:
                    if shadow[i, j] != wp.uint8(0):
                        value = value * (1.0 - shadow_strength)
                shade_out[i, j] = value
        return
    # window columns j-1 and j (rows i-1, i, i+1), loaded once and slid
    a = wp.float32(0.0)
    d = wp.float32(0.0)
    g = wp.float32(0.0)
    b = wp.float32(0.0)
    e = wp.float32(0.0)
    h = wp.float32(0.0)
    if interior_row and j0 > 0:
        a = heights[i - 1, j0 - 1]
        d = heights[i, j0 - 1]
        g = heights[i + 1, j0 - 1]
    if interior_row:
        b = heights[i - 1, j0]
        e = heights[i, j0]
        h = heights[i + 1, j0]
    j = j0
    while j < j1:
        value = wp.float32(0.0)
        if interior_row and j > 0 and j < grid.cols - 1:
            c = heights[i - 1, j + 1]
            f = heights[i, j + 1]
            k = heights[i + 1, j + 1]
            gradient = horn_weights(scale, a, b, c, d, f, g, h, k)
            if wp.isnan(e):
                value = e
            elif wp.isnan(gradient[0]) or wp.isnan(gradient[1]):
                value = shade_at(horn_gradient(grid, i, j, 1), light, method, altitude, azimuth)
            elif method == 0:  # the common case inline: max(0, n . l)
                value = wp.max((light[2] - gradient[0] * light[0] - gradient[1] * light[1])
                               / wp.sqrt(1.0 + gradient[0] * gradient[0] + gradient[1] * gradient[1]), 0.0)
            else:
                value = shade_at(gradient, light, method, altitude, azimuth)
            a = b
            b = c
            d = e
            e = f
            g = h
            h = k
        else:
            centre = heights[i, j]
            if wp.isnan(centre):
                value = centre
            else:
                value = shade_at(horn_gradient(grid, i, j, 1), light, method, altitude, azimuth)
            if interior_row and j + 1 < grid.cols:  # entering the interior: load the window's columns j, j+1
                a = heights[i - 1, j]
                d = centre
                g = heights[i + 1, j]
                b = heights[i - 1, j + 1]
                e = heights[i, j + 1]
                h = heights[i + 1, j + 1]
        if shadowed:
            if shadow[i, j] != wp.uint8(0):
                value = value * (1.0 - shadow_strength)
        shade_out[i, j] = value
        j += 1


# ---------------------------------------------------------------------------------------------------------
# MapLibre GL's hillshade methods (src/shaders/glsl/hillshade.fragment.glsl of maplibre/maplibre-gl-js at
# commit 27688c1c2109f2ebbf7f65a773ef88598a8df75b). ``deriv`` is MapLibre's (dz/dx east, dz/dy south): the
# Horn gradient (p, q) as (p, -q). The result is the layer's premultiplied RGBA fragment colour.
# ---------------------------------------------------------------------------------------------------------
@wp.func
def glsl_mod(x: wp.float32, y: wp.float32) -> wp.float32:
    """GLSL's mod: x - y * floor(x / y) (the sign of y, unlike C's fmod)."""
    return x - y * wp.floor(x / y)


@wp.func
def maplibre_aspect(deriv: wp.vec2) -> wp.float32:
    """MapLibre's get_aspect: atan(deriv.y, -deriv.x), +-pi/2 where deriv.x is 0."""
    if deriv[0] != 0.0:
        return wp.atan2(deriv[1], -deriv[0])
    if deriv[1] > 0.0:
        return 1.5707963267948966
    return -1.5707963267948966


@wp.func
def maplibre_cang(deriv: wp.vec2, azimuth: wp.float32, altitude: wp.float32) -> wp.float32:
    """cos(angle between normal and light) as MapLibre's basic/combined/multidirectional write it."""
    cos_az = wp.cos(azimuth + 3.141592653589793)
    sin_az = wp.sin(azimuth + 3.141592653589793)
    cos_alt = wp.cos(altitude)
    sin_alt = wp.sin(altitude)
    return (sin_alt - (deriv[1] * cos_az * cos_alt - deriv[0] * sin_az * cos_alt)) / wp.sqrt(
        1.0 + wp.dot(deriv, deriv))


@wp.func
def maplibre_two_tone(cang: wp.float32, shadow: wp.vec4, highlight: wp.vec4) -> wp.vec4:
    """basic: shade = clamp(cang, 0, 1); highlight * (2 shade - 1) above 0.5, shadow * (1 - 2 shade) below."""
    shade = wp.clamp(cang, 0.0, 1.0)
    if shade > 0.5:
        return highlight * (2.0 * shade - 1.0)
    return shadow * (1.0 - 2.0 * shade)


@wp.func
def maplibre_colour(deriv_in: wp.vec2, style: MapLibreStyle) -> wp.vec4:
    """One pixel of a MapLibre hillshade layer (see the shader's standard_, basic_, combined_, igor_ and
    multidirectional_hillshade)."""
    if style.method == 0:  # MapLibre's legacy ("standard") shading
        slope = wp.atan(0.625 * wp.length(deriv_in))
        aspect = maplibre_aspect(deriv_in)
        intensity = style.exaggeration
        base = 1.875 - intensity * 1.75
        max_value = 1.5707963267948966
        scaled = slope
        if intensity != 0.5:
            scaled = (wp.pow(base, slope) - 1.0) / (wp.pow(base, max_value) - 1.0) * max_value
        weight = wp.clamp(intensity * 2.0, 0.0, 1.0)
        accent = (1.0 - wp.cos(scaled)) * style.accent * weight
        shade = wp.abs(glsl_mod((aspect + style.azimuths[0] + 3.141592653589793) / 3.141592653589793 + 0.5, 2.0)
                       - 1.0)
        shade_colour = wp.lerp(style.shadows[0], style.highlights[0], shade) * wp.sin(scaled) * weight
        return accent * (1.0 - shade_colour[3]) + shade_colour
    deriv = deriv_in * style.exaggeration * 2.0
    if style.method == 1:
        return maplibre_two_tone(maplibre_cang(deriv, style.azimuths[0], style.altitudes[0]), style.shadows[0],
                                 style.highlights[0])
    if style.method == 4:  # the average of basic over every light
        total = wp.vec4(0.0)
        n = style.azimuths.shape[0]
        for k in range(n):
            total += maplibre_two_tone(maplibre_cang(deriv, style.azimuths[k], style.altitudes[k]),
                                       style.shadows[k], style.highlights[k])
        return total / float(n)
    steepness = wp.atan(wp.length(deriv))
    if style.method == 2:
        angle = wp.clamp(wp.acos(wp.clamp(maplibre_cang(deriv, style.azimuths[0], style.altitudes[0]), -1.0, 1.0)),
                         0.0, 1.5707963267948966)
        scale = steepness * 0.40528473456935108  # 4 / pi^2
        return style.shadows[0] * (angle * scale) + style.highlights[0] * ((1.5707963267948966 - angle) * scale)
    # 3: igor
    slope_strength = steepness * 0.6366197723675814  # 2 / pi
    aspect_strength = 1.0 - wp.abs(glsl_mod((maplibre_aspect(deriv) + style.azimuths[0] + 3.141592653589793)
                                            / 3.141592653589793 + 0.5, 2.0) - 1.0)
    return (style.shadows[0] * (slope_strength * aspect_strength)
            + style.highlights[0] * (slope_strength * (1.0 - aspect_strength)))


@wp.kernel
def maplibre_shade_heights(
    thread_offset: wp.int32,
    grid: HeightGrid,
    style: MapLibreStyle,
    # outputs
    rgba_out: wp.array3d[wp.float32],
):
    """One thread per pixel: the MapLibre hillshade layer's premultiplied RGBA from the full-resolution Horn
    gradient (beyond the border the edge repeats, next to nodata the centre height: :func:`window_height`); NaN
    at nodata."""
    i, j = pixel_of(wp.tid() + thread_offset, grid.cols)
    colour = wp.vec4(wp.nan)
    if not wp.isnan(grid.heights[i, j]):
        gradient = horn_gradient(grid, i, j, 0)
        colour = maplibre_colour(wp.vec2(gradient[0], -gradient[1]), style)
    for c in range(4):
        rgba_out[i, j, c] = colour[c]


@wp.kernel
def encode_normals(
    thread_offset: wp.int32,
    grid: HeightGrid,
    # outputs
    rgb_out: wp.array3d[wp.uint8],
):
    """One thread per node: its unit normal (x east, y north, z up) as RGB, n * 127.5 + 127.5 rounded; the
    gradient of :func:`shade_heights` (gdaldem's border), so that relighting gives the hillshade."""
    i, j = pixel_of(wp.tid() + thread_offset, grid.cols)
    normal = wp.vec3(0.0, 0.0, 1.0)
    if not wp.isnan(grid.heights[i, j]):
        normal = surface_normal(horn_gradient(grid, i, j, 1))
    for c in range(3):
        rgb_out[i, j, c] = wp.uint8(wp.int32(wp.floor(normal[c] * 127.5 + 128.0)))


@wp.func
def decode_normal(rgb: wp.array3d[wp.uint8], i: wp.int32, j: wp.int32) -> wp.vec3:
    """The unit normal an RGB texel encodes."""
    v = wp.vec3(float(rgb[i, j, 0]), float(rgb[i, j, 1]), float(rgb[i, j, 2]))
    return wp.normalize(v / 127.5 - wp.vec3(1.0, 1.0, 1.0))


@wp.kernel
def relight_directional(
    thread_offset: wp.int32,
    rgb: wp.array3d[wp.uint8],
    light: wp.vec3,
    # outputs
    shade_out: wp.array2d[wp.float32],
):
    """One thread per texel: max(0, n . l) for a directional light (the normal texture is not recomputed)."""
    i, j = pixel_of(wp.tid() + thread_offset, rgb.shape[1])
    shade_out[i, j] = wp.max(wp.dot(decode_normal(rgb, i, j), light), 0.0)


@wp.kernel
def relight_point(
    thread_offset: wp.int32,
    rgb: wp.array3d[wp.uint8],
    grid: HeightGrid,
    light_position: wp.vec3,
    # outputs
    shade_out: wp.array2d[wp.float32],
):
    """One thread per texel: max(0, n . l) with l the unit vector from the texel's surface point to the light."""
    i, j = pixel_of(wp.tid() + thread_offset, rgb.shape[1])
    h = grid.heights[i, j]
    if wp.isnan(h):
        shade_out[i, j] = h
        return
    point = wp.vec3(float(j) * grid.spacing[0], float(i) * grid.spacing[1], h * grid.z_factor)
    to_light = light_position - point
    if wp.dot(to_light, to_light) < 1.0e-30:  # its square near or below float32's smallest: divided by its largest
        m = wp.max(wp.max(wp.abs(to_light[0]), wp.abs(to_light[1])), wp.abs(to_light[2]))  # component first
        if m == 0.0:
            shade_out[i, j] = 1.0
            return
        to_light = to_light / m
    shade_out[i, j] = wp.max(wp.dot(decode_normal(rgb, i, j), wp.normalize(to_light)), 0.0)


@wp.func
def first_major(sweep: Sweep, value: wp.int32, strict: wp.int32) -> wp.int32:
    """The first major index m whose offset passes ``value`` (binary search; offsets are monotone): for
    increasing offsets the first with offset >= value (> when strict), for decreasing the first with
    offset <= value (< when strict)."""
    lo = wp.int32(0)
    hi = sweep.n_major
    while lo < hi:
        mid = (lo + hi) // 2
        r = sweep.minor_offsets[mid]
        passed = False
        if sweep.increasing == 1:
            passed = r > value or (r == value and strict == 0)
        else:
            passed = r < value or (r == value and strict == 0)
        if passed:
            hi = mid
        else:
            lo = mid + 1
    return lo


@wp.func
def line_span(sweep: Sweep, line: wp.int32) -> wp.vec2i:
    """[first, last) major indices where line ``line`` lies inside the grid (its minor index in range)."""
    base = line + sweep.c_min
    low = -base  # minor index >= 0  <=>  offset >= -base
    high = sweep.n_minor - 1 - base  # minor index < n_minor  <=>  offset <= high
    if sweep.increasing == 1:
        return wp.vec2i(first_major(sweep, low, 0), first_major(sweep, high, 1))
    return wp.vec2i(first_major(sweep, high, 0), first_major(sweep, low, 1))


@wp.func
def walk_major(sweep: Sweep, span: wp.vec2i, k: wp.int32) -> wp.int32:
    """The k-th major index of a span in walking order (away from the light)."""
    if sweep.forward > 0:
        return span[0] + k
    return span[1] - 1 - k


@wp.func
def line_point(grid: HeightGrid, major_j: wp.int32, i: wp.int32, j: wp.int32, error: wp.float32) -> wp.vec2:
    """(row, column) of the point of node (i, j)'s straight line at its major index (``error`` less along the minor
    axis), from the grid's centre in nodes: the same float32 values whichever way the rows and columns run."""
    fi = float(i) - 0.5 * float(grid.rows - 1)
    fj = float(j) - 0.5 * float(grid.cols - 1)
    if major_j == 0:
        fj = fj - error
    else:
        fi = fi - error
    return wp.vec2(fi, fj)


@wp.func
def distance_away(grid: HeightGrid, sweep: Sweep, f: wp.vec2) -> wp.float32:
    """How far the point ``f`` of a straight line (:func:`line_point`) lies along the away-from-light direction
    (world units, from the grid's centre)."""
    return f[1] * grid.spacing[0] * sweep.away[0] + f[0] * grid.spacing[1] * sweep.away[1]


@wp.func
def node_at_minor(grid: HeightGrid, major_j: wp.int32, i: wp.int32, j: wp.int32, minor: wp.int32) -> wp.float32:
    """The height at minor index ``minor`` (inside the grid) of node (i, j)'s major index."""
    if major_j == 0:
        return load(grid.heights, i, minor)
    return load(grid.heights, minor, j)


@wp.func
def across_line(grid: HeightGrid, sweep: Sweep, major_j: wp.int32, i: wp.int32, j: wp.int32, minor: wp.int32,
                side: wp.int32, h: wp.float32) -> wp.float32:
    """The height's change per minor index from node (i, j) (height ``h``, minor index ``minor``) towards ``side``
    (±1): to that neighbour, else (beyond the border or at nodata) extrapolated from the opposite one, as gdaldem's
    border is (linearly), else 0."""
    ahead = minor + side
    if ahead >= 0 and ahead < sweep.n_minor:
        value = node_at_minor(grid, major_j, i, j, ahead)
        if grid.has_nodata == 0 or not wp.isnan(value):
            return value - h
    behind = minor - side
    if behind >= 0 and behind < sweep.n_minor:
        value = node_at_minor(grid, major_j, i, j, behind)
        if grid.has_nodata == 0 or not wp.isnan(value):
            return h - value
    return wp.float32(0.0)


def _variant_name(kernel: str, major_j: int, on_nodes: bool) -> str:
    return f"{kernel}_{('rows', 'columns')[major_j]}{'_on_nodes' if on_nodes else ''}"


def _sweep_shadows(major_j: int, on_nodes: bool) -> wp.Kernel:
    """The shadow sweep kernel (:data:`SWEEP_SHADOWS`) compiled for one sweep: ``major_j`` 0 (lines advancing along
    rows) or 1 (columns); ``on_nodes`` True where every node lies on its straight line (``Sweep.minor_error`` 0 at
    every major index: a light along an axis, or a diagonal of square cells), which reads no sideways steps. Both
    are ``wp.static``, each variant's loop compiled for its own case: with the sweep's ``major_j`` read at every
    node and the zero steps read and applied, 4096² on one core took 20° 78 -> 50 ms, 300° ~148 -> ~110 ms,
    315° 59 -> 37 ms, 90° 71 -> 44 ms (best of 7, two rounds); the same bits."""

    @wp.kernel(name=_variant_name("sweep_shadows", major_j, on_nodes))
    def sweep_shadows(
        thread_offset: wp.int32,
        grid: HeightGrid,
        sweep: Sweep,
        lines_per_thread: wp.int32,
        horizons: wp.array[wp.float32],
        # outputs
        shadow_out: wp.array2d[wp.uint8],
    ):
        """One thread per bundle of ``lines_per_thread`` adjacent sweep lines (1 on CUDA: one thread per line),
        walked away from the light in lockstep, each line keeping its running horizon max(h + t tan(alt)).

        A node is in shadow when an earlier point of its line lies above the ray from its point to the light, i.e.
        when h_q + t_q tan(alt) > h_p + t_p tan(alt) for some earlier q: O(1) per node; every node stands for the
        point of its straight line at its major index (:func:`line_point`, its height interpolated across the line
        by :func:`across_line`), the rise measured from the grid's centre as in :func:`distance_away`. Walking a
        bundle in lockstep touches neighbouring nodes one after another (cache lines are reused on CPUs).
        """
        first = (wp.tid() + thread_offset) * lines_per_thread
        last = wp.min(first + lines_per_thread, sweep.n_lines)
        for line in range(first, last):
            horizons[line] = wp.float32(-3.0e38)
        span_first = line_span(sweep, first)
        span_last = line_span(sweep, last - 1)
        span = wp.vec2i(wp.min(span_first[0], span_last[0]), wp.max(span_first[1], span_last[1]))
        # the rise of line_point's point, t tan(alt) = column * rise[0] + row * rise[1]: the major index's term
        # once per major index, the minor index's at each node (the same products and sum: addition commutes)
        centre_minor = 0.5 * float(grid.cols - 1)
        rise_minor = sweep.rise[0]
        if wp.static(major_j == 1):
            centre_minor = 0.5 * float(grid.rows - 1)
            rise_minor = sweep.rise[1]
        k = wp.int32(0)
        while k < span[1] - span[0]:
            major = walk_major(sweep, span, k)
            offset = sweep.c_min + sweep.minor_offsets[major]
            line = wp.max(first, -offset)
            hi = wp.min(last, sweep.n_minor - offset)
            rise_major = (float(major) - 0.5 * float(grid.rows - 1)) * sweep.rise[1]
            if wp.static(major_j == 1):
                rise_major = (float(major) - 0.5 * float(grid.cols - 1)) * sweep.rise[0]
            # each node taken to its straight line's point at this major index (the same sideways step for every
            # line): its height interpolated linearly towards the minor neighbour across the line, its distance the
            # point's; the node's own height and position zig-zagged a node sideways, and a plane sloping across the
            # light shadowed itself in bands
            error = wp.float32(0.0)
            if wp.static(not on_nodes):
                error = load(sweep.minor_error, major)
            side = wp.where(error > 0.0, -1, 1)
            weight = wp.abs(error)
            while line < hi:
                minor = line + offset
                i = minor
                j = major
                if wp.static(major_j == 0):
                    i = major
                    j = minor
                h = load(grid.heights, i, j)  # (unchecked, kernels/memory.py: the span keeps (i, j) in the grid)
                if grid.has_nodata != 0 and wp.isnan(h):
                    store(shadow_out, i, j, wp.uint8(0))
                else:
                    if wp.static(not on_nodes):
                        if weight != 0.0:
                            h = h + weight * across_line(grid, sweep, wp.static(major_j), i, j, minor, side, h)
                    g = h * grid.z_factor + (((float(minor) - centre_minor) - error) * rise_minor + rise_major)
                    if g < load(horizons, line):
                        store(shadow_out, i, j, wp.uint8(1))
                    else:
                        store(shadow_out, i, j, wp.uint8(0))
                        store(horizons, line, g)
                line += 1
            k += 1

    return sweep_shadows


#: The shadow sweep kernels by (``Sweep.major_j``, on_nodes): see :func:`_sweep_shadows`.
SWEEP_SHADOWS = {(major_j, on_nodes): _sweep_shadows(major_j, on_nodes) for major_j in (0, 1)
                 for on_nodes in (False, True)}


@wp.kernel
def count_line_nodes(
    thread_offset: wp.int32,
    sweep: Sweep,
    # outputs
    counts: wp.array[wp.int32],
):
    """One thread per sweep line: how many grid nodes it visits (its horizon stack's size)."""
    line = wp.tid() + thread_offset
    span = line_span(sweep, line)
    counts[line] = span[1] - span[0]


def _sweep_occlusion(major_j: int, on_nodes: bool) -> wp.Kernel:
    """The occlusion sweep kernel (:data:`SWEEP_OCCLUSION`) compiled for one sweep, as :func:`_sweep_shadows`
    compiles the shadow sweep's."""

    @wp.kernel(name=_variant_name("sweep_occlusion", major_j, on_nodes))
    def sweep_occlusion(
        thread_offset: wp.int32,
        grid: HeightGrid,
        sweep: Sweep,
        lines_per_thread: wp.int32,
        offsets: wp.array[wp.int32],
        weight: wp.float32,
        tops: wp.array[wp.int32],
        # outputs
        hull_out: wp.array[wp.vec2],
        occlusion_out: wp.array2d[wp.float32],
    ):
        """One thread per bundle of ``lines_per_thread`` adjacent sweep lines (1 on CUDA), walked in lockstep as in
        the shadow sweep (:func:`_sweep_shadows`), whose loop it repeats (the bundle span and the node's (i, j) as
        shared functions made the occlusion 6-10 % slower, RESULTS.md "Session 24"; the hull step as one, 3-5 %):
        the horizon angle of each node towards the light side (the upper convex hull of its line's earlier points,
        each node taken onto its straight line as there, a stack at ``offsets[line]`` whose last index is
        ``tops[line]``, amortised O(1)); adds weight * sin(horizon angle), at least 0, to ``occlusion_out``. Each
        line sees its nodes in the same order as when walked alone, so the values do not depend on the bundle."""
        first = (wp.tid() + thread_offset) * lines_per_thread
        last = wp.min(first + lines_per_thread, sweep.n_lines)
        for line in range(first, last):
            store(tops, line, -1)  # index of the hull's last point, relative to the line's base
        span_first = line_span(sweep, first)
        span_last = line_span(sweep, last - 1)
        span = wp.vec2i(wp.min(span_first[0], span_last[0]), wp.max(span_first[1], span_last[1]))
        k = wp.int32(0)
        while k < span[1] - span[0]:
            major = walk_major(sweep, span, k)
            offset = sweep.c_min + sweep.minor_offsets[major]
            line = wp.max(first, -offset)
            hi = wp.min(last, sweep.n_minor - offset)
            error = wp.float32(0.0)  # each node taken onto its straight line, as the shadow sweep takes it
            if wp.static(not on_nodes):
                error = load(sweep.minor_error, major)
            side = wp.where(error > 0.0, -1, 1)
            sideways = wp.abs(error)
            while line < hi:
                minor = line + offset
                i = minor
                j = major
                if wp.static(major_j == 0):
                    i = major
                    j = minor
                h = load(grid.heights, i, j)  # (unchecked, kernels/memory.py: the span keeps (i, j) in the grid)
                if not wp.isnan(h):
                    base = load(offsets, line)
                    top = load(tops, line)
                    if wp.static(not on_nodes):
                        if sideways != 0.0:
                            h = h + sideways * across_line(grid, sweep, wp.static(major_j), i, j, minor, side, h)
                    p = wp.vec2(distance_away(grid, sweep, line_point(grid, wp.static(major_j), i, j, error)),
                                h * grid.z_factor)
                    # drop hull points that are not above the segment from their predecessor to p
                    while top >= 1:
                        a = load(hull_out, base + top - 1)
                        b = load(hull_out, base + top)
                        cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
                        if cross >= 0.0:
                            top -= 1
                        else:
                            break
                    if top >= 0:
                        q = load(hull_out, base + top)
                        rise = q[1] - p[1]
                        run = p[0] - q[0]
                        if rise > 0.0 and run > 0.0:
                            store(occlusion_out, i, j,
                                  load(occlusion_out, i, j) + weight * rise / wp.sqrt(rise * rise + run * run))
                    top += 1
                    store(hull_out, base + top, p)
                    store(tops, line, top)
                line += 1
            k += 1

    return sweep_occlusion


#: The occlusion sweep kernels by (``Sweep.major_j``, on_nodes): see :func:`_sweep_occlusion`.
SWEEP_OCCLUSION = {(major_j, on_nodes): _sweep_occlusion(major_j, on_nodes) for major_j in (0, 1)
                   for on_nodes in (False, True)}


# ---------------------------------------------------------------------------------------------------------
# layers and operations (RGBA float32 images)
# ---------------------------------------------------------------------------------------------------------


@wp.func
def texel(image: wp.array2d[wp.vec4], i: wp.int32, j: wp.int32, border: wp.int32) -> wp.vec4:
    """Texel (i, j); outside the image: the nearest edge texel (border 0) or transparent (border 1)."""
    rows = image.shape[0]
    cols = image.shape[1]
    if border == 1:
        if i < 0 or i >= rows or j < 0 or j >= cols:
            return wp.vec4(0.0, 0.0, 0.0, 0.0)
    return image[wp.clamp(i, 0, rows - 1), wp.clamp(j, 0, cols - 1)]


@wp.func
def sample_at(frame: PixelFrame, image: wp.array2d[wp.vec4], matrix: wp.mat33, border: wp.int32, i: wp.int32,
              j: wp.int32) -> wp.vec4:
    """The layer's image sampled bilinearly at the centre of pixel (i, j) of ``frame`` through the layer's texture
    matrix (world (x, y, 1) -> texel (column, row, 1), texel centres at integers). The colours are interpolated
    premultiplied by alpha (the straight colour of a transparent texel does not bleed into its neighbours') and
    returned straight; where all four texels are transparent, their colours mixed, alpha 0."""
    world = wp.vec3(frame.origin[0] + float(j) * frame.pixel[0], frame.origin[1] + float(i) * frame.pixel[1], 1.0)
    t = matrix * world
    u = t[0]
    v = t[1]
    rows = image.shape[0]
    cols = image.shape[1]
    if border == 1:  # half a texel beyond the outer centres still belongs to the image (edge texels)
        if u < -0.5 or v < -0.5 or u > float(cols) - 0.5 or v > float(rows) - 0.5:
            return wp.vec4(0.0, 0.0, 0.0, 0.0)
    u = wp.clamp(u, 0.0, float(cols - 1))
    v = wp.clamp(v, 0.0, float(rows - 1))
    j0 = wp.int32(wp.floor(u))
    i0 = wp.int32(wp.floor(v))
    fu = u - float(j0)
    fv = v - float(i0)
    t00 = texel(image, i0, j0, 0)
    t01 = texel(image, i0, j0 + 1, 0)
    t10 = texel(image, i0 + 1, j0, 0)
    t11 = texel(image, i0 + 1, j0 + 1, 0)
    w00 = (1.0 - fu) * (1.0 - fv)
    w01 = fu * (1.0 - fv)
    w10 = (1.0 - fu) * fv
    w11 = fu * fv
    k00 = t00[3] * w00
    k01 = t01[3] * w01
    k10 = t10[3] * w10
    k11 = t11[3] * w11
    alpha = k00 + k01 + k10 + k11
    straight = t00 * w00 + t01 * w01 + t10 * w10 + t11 * w11
    if alpha > 0.0:
        # each texel's share of the alpha, then its colour times it: a texel alone with alpha (at its centre, beside
        # transparent ones) has share 1 exactly and keeps its colour bit for bit; the premultiplied sum divided by
        # alpha (c * a / a) moved it by an ulp, and to_uint8 rounded a colour near a half step the other way
        rgb = (wp.vec3(t00[0], t00[1], t00[2]) * (k00 / alpha) + wp.vec3(t01[0], t01[1], t01[2]) * (k01 / alpha)
               + wp.vec3(t10[0], t10[1], t10[2]) * (k10 / alpha) + wp.vec3(t11[0], t11[1], t11[2]) * (k11 / alpha))
        return wp.vec4(rgb[0], rgb[1], rgb[2], alpha)
    return wp.vec4(straight[0], straight[1], straight[2], 0.0)


@wp.kernel
def sample_layer(
    thread_offset: wp.int32,
    frame: PixelFrame,
    image: wp.array2d[wp.vec4],
    matrix: wp.mat33,
    border: wp.int32,
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per output pixel: the layer's image sampled bilinearly at the pixel centre (:func:`sample_at`)."""
    i, j = pixel_of(wp.tid() + thread_offset, frame.cols)
    rgba_out[i, j] = sample_at(frame, image, matrix, border, i, j)


@wp.func
def blend_over(x: wp.vec4, y: wp.vec4, w: wp.float32, own_alpha: wp.int32) -> wp.vec4:
    """One pixel of :func:`blend_layers`: y laid over x with coverage w * alpha_y (alpha_y alone when
    ``own_alpha``)."""
    c = y[3]
    if own_alpha == 0:
        c = w * y[3]
    under = x[3] * (1.0 - c)
    alpha = c + under
    if alpha > 0.0:  # shares of the alpha: c = 0 (nothing laid over) leaves x bit for bit, under = 0 gives y
        rgb = wp.vec3(y[0], y[1], y[2]) * (c / alpha) + wp.vec3(x[0], x[1], x[2]) * (under / alpha)
        return wp.vec4(rgb[0], rgb[1], rgb[2], alpha)
    mixed = x * (1.0 - w) + y * w
    return wp.vec4(mixed[0], mixed[1], mixed[2], 0.0)


@wp.func
def modulated(x: wp.vec4, y: wp.vec4) -> wp.vec4:
    """One pixel of :func:`modulate_layers`: x.rgb * (1 - y.alpha + y.alpha * y.rgb), alpha x.alpha."""
    keep = 1.0 - y[3]
    return wp.vec4(x[0] * (keep + y[3] * y[0]), x[1] * (keep + y[3] * y[1]), x[2] * (keep + y[3] * y[2]), x[3])


@wp.kernel
def blend_layers(
    thread_offset: wp.int32,
    a: wp.array2d[wp.vec4],
    b: wp.array2d[wp.vec4],
    weights: wp.array2d[wp.vec4],
    own_alpha: wp.int32,
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per pixel (§3.2.3 blending, straight alpha): b laid over a with coverage c = w * alpha_b, w the
    alpha of ``weights`` at the pixel (1 when ``own_alpha``: b's alpha alone): alpha c + alpha_a (1 - c), colour
    (c b + (1 - c) alpha_a a) / alpha; a (1 - w) + b w for opaque layers. A transparent pixel of b (nodata,
    outside its extent) leaves a as it is; where both are transparent the colours are mixed by w."""
    i, j = pixel_of(wp.tid() + thread_offset, a.shape[1])
    rgba_out[i, j] = blend_over(a[i, j], b[i, j], weights[i, j][3], own_alpha)


@wp.kernel
def add_layers(
    thread_offset: wp.int32,
    a: wp.array2d[wp.vec4],
    b: wp.array2d[wp.vec4],
    weight_a: wp.float32,
    weight_b: wp.float32,
    clamp: wp.int32,
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per pixel: weight_a a + weight_b b (weighted addition), each channel clamped to [0, 1] when
    ``clamp`` is 1 (the last term of a sum)."""
    i, j = pixel_of(wp.tid() + thread_offset, a.shape[1])
    s = a[i, j] * weight_a + b[i, j] * weight_b
    if clamp == 0:
        rgba_out[i, j] = s
        return
    rgba_out[i, j] = wp.vec4(wp.clamp(s[0], 0.0, 1.0), wp.clamp(s[1], 0.0, 1.0), wp.clamp(s[2], 0.0, 1.0),
                             wp.clamp(s[3], 0.0, 1.0))


@wp.func
def neumaier_step(s: wp.float64, c: wp.float64, t: wp.float64) -> wp.vec2d:
    """(s + t, c + the rounding error of s + t): one step of Neumaier's compensated sum (the error is exact)."""
    n = s + t
    e = (t - n) + s
    if wp.abs(s) >= wp.abs(t):
        e = (s - n) + t
    return wp.vec2d(n, c + e)


@wp.kernel
def add_layer_wide(
    thread_offset: wp.int32,
    total: wp.array2d[wp.vec4d],
    error: wp.array2d[wp.vec4d],
    b: wp.array2d[wp.vec4],
    weight_b: wp.float64,
    # outputs
    total_out: wp.array2d[wp.vec4d],
    error_out: wp.array2d[wp.vec4d],
):
    """One thread per pixel: total + weight_b b in float64, compensated (Neumaier), for a weighted addition whose
    float32 partial sums could overflow: a float32 weight times a channel in [0, 1] is exact in float64, n such
    terms stay far below its range, and ``error`` keeps what each addition rounded off, so terms that cancel
    exactly (3e38 and −3e38 times one layer) leave the small ones in any order. The outputs may be the inputs."""
    i, j = pixel_of(wp.tid() + thread_offset, b.shape[1])
    v = b[i, j]
    s = total[i, j]
    c = error[i, j]
    r = neumaier_step(s[0], c[0], wp.float64(v[0]) * weight_b)
    g = neumaier_step(s[1], c[1], wp.float64(v[1]) * weight_b)
    u = neumaier_step(s[2], c[2], wp.float64(v[2]) * weight_b)
    a = neumaier_step(s[3], c[3], wp.float64(v[3]) * weight_b)
    total_out[i, j] = wp.vec4d(r[0], g[0], u[0], a[0])
    error_out[i, j] = wp.vec4d(r[1], g[1], u[1], a[1])


@wp.kernel
def clamp_wide(
    thread_offset: wp.int32,
    total: wp.array2d[wp.vec4d],
    error: wp.array2d[wp.vec4d],
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per pixel: the compensated sum of :func:`add_layer_wide` (total + error) rounded to float32,
    each channel clamped to [0, 1]."""
    i, j = pixel_of(wp.tid() + thread_offset, total.shape[1])
    s = total[i, j] + error[i, j]
    rgba_out[i, j] = wp.vec4(wp.clamp(wp.float32(s[0]), 0.0, 1.0), wp.clamp(wp.float32(s[1]), 0.0, 1.0),
                             wp.clamp(wp.float32(s[2]), 0.0, 1.0), wp.clamp(wp.float32(s[3]), 0.0, 1.0))


@wp.kernel
def interpolate_layers(
    thread_offset: wp.int32,
    a: wp.array2d[wp.vec4],
    b: wp.array2d[wp.vec4],
    t: wp.float32,
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per pixel: (1 - t) a + t b interpolated premultiplied (§6 keyframes): alpha
    (1 - t) alpha_a + t alpha_b, colour ((1 - t) alpha_a a + t alpha_b b) / alpha, so a transparent key (nodata)
    fades the other out without tinting it; where both are transparent the colours are mixed straight."""
    i, j = pixel_of(wp.tid() + thread_offset, a.shape[1])
    x = a[i, j]
    y = b[i, j]
    wa = (1.0 - t) * x[3]
    wb = t * y[3]
    alpha = wa + wb
    if alpha > 0.0:  # shares of the alpha: at a key's time (t 0, or a transparent other key) the key bit for bit
        rgb = wp.vec3(x[0], x[1], x[2]) * (wa / alpha) + wp.vec3(y[0], y[1], y[2]) * (wb / alpha)
        rgba_out[i, j] = wp.vec4(wp.clamp(rgb[0], 0.0, 1.0), wp.clamp(rgb[1], 0.0, 1.0), wp.clamp(rgb[2], 0.0, 1.0),
                                 wp.min(alpha, 1.0))
    else:
        mixed = x * (1.0 - t) + y * t
        rgba_out[i, j] = wp.vec4(mixed[0], mixed[1], mixed[2], 0.0)


@wp.kernel
def modulate_layers(
    thread_offset: wp.int32,
    a: wp.array2d[wp.vec4],
    b: wp.array2d[wp.vec4],
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per pixel: a.rgb * b.rgb, alpha a.alpha (modulation, e.g. by a topographic layer), by b as far
    as it covers the pixel: a.rgb * (1 - b.alpha + b.alpha * b.rgb), so a transparent pixel of b (outside its
    extent, nodata) leaves a as it is."""
    i, j = pixel_of(wp.tid() + thread_offset, a.shape[1])
    rgba_out[i, j] = modulated(a[i, j], b[i, j])


@wp.func
def clamped(c: wp.vec4) -> wp.vec4:
    """Each channel clamped to [0, 1], as a layer's RGBA is (``TextureLayer.rgba``)."""
    return wp.vec4(wp.clamp(c[0], 0.0, 1.0), wp.clamp(c[1], 0.0, 1.0), wp.clamp(c[2], 0.0, 1.0),
                   wp.clamp(c[3], 0.0, 1.0))


@wp.func
def layer_at(frame: PixelFrame, image: wp.array2d[wp.vec4], matrix: wp.mat33, mode: wp.int32, i: wp.int32,
             j: wp.int32) -> wp.vec4:
    """A layer at pixel (i, j) of ``frame``: its own texel (mode 0: the layer is that pixel grid), sampled
    bilinearly with a transparent border (mode 1) or with its edge texels repeated (mode 2)."""
    if mode == 0:
        return image[i, j]
    return sample_at(frame, image, matrix, wp.where(mode == 1, 1, 0), i, j)


@wp.func
def byte_texel(image: wp.array3d[wp.uint8], i: wp.int32, j: wp.int32) -> wp.vec4:
    """Texel (i, j) of a uint8 RGB or RGBA image on the output's own pixel grid (:func:`layer_at`'s mode 0), each
    channel / 255 as ``TextureLayer.rgba`` reads it, opaque without alpha."""
    alpha = 1.0
    if image.shape[2] == 4:
        alpha = float(image[i, j, 3]) / 255.0
    return wp.vec4(float(image[i, j, 0]) / 255.0, float(image[i, j, 1]) / 255.0, float(image[i, j, 2]) / 255.0,
                   alpha)


@wp.func
def unit_to_uint8(x: wp.float32) -> wp.uint8:
    """NumPy's ``np.round(np.clip(x, 0, 1) * 255).astype(np.uint8)`` in float32 (halves to even)."""
    return wp.uint8(wp.int32(wp.rint(wp.clamp(x, 0.0, 1.0) * 255.0)))


@wp.func
def write_over_background(c: wp.vec4, background: wp.vec3, image: wp.array3d[wp.uint8], i: wp.int32, j: wp.int32):
    """Texel (i, j) of ``image``: the RGB of ``c`` composited over ``background`` by its alpha, as uint8
    (:func:`unit_to_uint8`; ``TextureLayer.to_uint8``'s)."""
    a = c[3]
    for k in range(3):
        image[i, j, k] = unit_to_uint8(c[k] * a + background[k] * (1.0 - a))


@wp.kernel
def compose_texture(
    thread_offset: wp.int32,
    frame: PixelFrame,
    shading: wp.array2d[wp.vec4],
    shading_matrix: wp.mat33,
    shading_mode: wp.int32,
    colours: wp.array2d[wp.vec4],
    colours_matrix: wp.mat33,
    colours_mode: wp.int32,
    picture: wp.array2d[wp.vec4],
    picture_bytes: wp.array3d[wp.uint8],
    picture_matrix: wp.mat33,
    picture_mode: wp.int32,
    background: wp.vec3,
    over_background: wp.int32,
    # outputs
    image_out: wp.array3d[wp.uint8],
    over_out: wp.array3d[wp.uint8],
):
    """One thread per texel of ``frame``: the topographic texture composed in one pass, as the layer operations
    compose it one layer at a time (``stepterrain texture``): the shading (a topographic layer) and the colours
    (a thematic layer) sampled onto the texel and clamped to [0, 1] (each a layer of its own there); a picture
    laid over the colours (:func:`blend_over` by its own alpha; alone without colours) and modulated by the
    shading (:func:`modulated`; the colours modulated by it without a picture; the shading alone without either);
    written as uint8, ``rint(255 * c)`` of each channel clamped, RGBA, or RGB composited over ``background`` when
    ``over_background`` is 1 (``TextureLayer.to_uint8``); when it is 2, both: the RGBA to ``image_out`` and the RGB
    over ``background`` to ``over_out`` (a DEM with nodata: the texture file's and the drape's, one pass). A mode
    is :func:`layer_at`'s, -1 for a layer not given; ``picture_mode`` 3 reads ``picture_bytes`` (uint8 on the texel
    grid) instead of ``picture``."""
    i, j = pixel_of(wp.tid() + thread_offset, frame.cols)
    c = clamped(layer_at(frame, shading, shading_matrix, shading_mode, i, j))
    if picture_mode >= 0:
        p = wp.vec4(0.0)
        if picture_mode == 3:
            p = byte_texel(picture_bytes, i, j)
        else:
            p = layer_at(frame, picture, picture_matrix, picture_mode, i, j)
        if colours_mode >= 0:
            h = clamped(layer_at(frame, colours, colours_matrix, colours_mode, i, j))
            p = clamped(blend_over(h, p, p[3], 1))
        c = clamped(modulated(c, p))
    elif colours_mode >= 0:
        h = clamped(layer_at(frame, colours, colours_matrix, colours_mode, i, j))
        c = clamped(modulated(h, c))
    if over_background == 1:
        write_over_background(c, background, image_out, i, j)
    else:
        for k in range(4):
            image_out[i, j, k] = wp.uint8(wp.rint(c[k] * 255.0))
        if over_background == 2:
            write_over_background(c, background, over_out, i, j)


@wp.func
def rotate_hue(rgb: wp.vec3, angle: wp.float32) -> wp.vec3:
    """Rotate the hue by ``angle`` radians in YIQ space (the chroma plane), keeping luma Y."""
    y = 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]
    ci = 0.595716 * rgb[0] - 0.274453 * rgb[1] - 0.321263 * rgb[2]
    cq = 0.211456 * rgb[0] - 0.522591 * rgb[1] + 0.311135 * rgb[2]
    c = wp.cos(angle)
    s = wp.sin(angle)
    i2 = ci * c - cq * s
    q2 = ci * s + cq * c
    return wp.vec3(y + 0.9563 * i2 + 0.6210 * q2, y - 0.2721 * i2 - 0.6474 * q2, y - 1.1070 * i2 + 1.7046 * q2)


@wp.kernel
def adjust_layer(
    thread_offset: wp.int32,
    frame: PixelFrame,
    image: wp.array2d[wp.vec4],
    adjustment: Adjustment,
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per pixel: CesiumJS's imagery-layer adjustments in its order (gamma on the sampled colour, then
    brightness, contrast, hue, saturation; clamped to [0, 1] last, as Cesium's framebuffer clamps), then alpha, the
    split (keep one side of a vertical line) and the cutout rectangle."""
    i, j = pixel_of(wp.tid() + thread_offset, frame.cols)
    x = image[i, j]
    rgb = wp.vec3(x[0], x[1], x[2])  # in [0, 1], as TextureLayer.rgba clamps it
    if adjustment.one_over_gamma != 1.0:  # pow(color, vec3(oneOverGamma)), first since CesiumJS 1.53
        rgb = wp.vec3(wp.pow(rgb[0], adjustment.one_over_gamma), wp.pow(rgb[1], adjustment.one_over_gamma),
                      wp.pow(rgb[2], adjustment.one_over_gamma))
    rgb = rgb * adjustment.brightness  # mix(0, color, brightness)
    rgb = wp.vec3(0.5, 0.5, 0.5) + (rgb - wp.vec3(0.5, 0.5, 0.5)) * adjustment.contrast
    if adjustment.hue != 0.0:
        rgb = rotate_hue(rgb, adjustment.hue)
    luma = wp.dot(rgb, wp.vec3(0.2125, 0.7154, 0.0721))
    rgb = wp.vec3(luma, luma, luma) + (rgb - wp.vec3(luma, luma, luma)) * adjustment.saturation
    rgb = wp.vec3(wp.clamp(rgb[0], 0.0, 1.0), wp.clamp(rgb[1], 0.0, 1.0), wp.clamp(rgb[2], 0.0, 1.0))
    alpha = x[3] * adjustment.alpha
    if adjustment.split_side != 0:
        west = j  # columns counted from the west: a mirrored texture (pixel width < 0) has column 0 in the east
        if frame.pixel[0] < 0.0:
            west = frame.cols - 1 - j
        u = (float(west) + 0.5) / float(frame.cols)
        if adjustment.split_side < 0 and u >= adjustment.split_position:
            alpha = 0.0
        if adjustment.split_side > 0 and u < adjustment.split_position:
            alpha = 0.0
    if adjustment.has_cutout == 1:
        wx = frame.origin[0] + float(j) * frame.pixel[0]
        wy = frame.origin[1] + float(i) * frame.pixel[1]
        box = adjustment.cutout
        if wx >= box[0] and wx <= box[1] and wy >= box[2] and wy <= box[3]:
            alpha = 0.0
    rgba_out[i, j] = wp.vec4(rgb[0], rgb[1], rgb[2], alpha)


# ---------------------------------------------------------------------------------------------------------
# image pyramid
# ---------------------------------------------------------------------------------------------------------


@wp.func
def overlap(s: wp.int64, m: wp.int64, r: wp.int64, n: wp.int64) -> wp.int64:
    """Length of source pixel s ([s m, (s+1) m)) inside target pixel r ([r n, (r+1) n)), in those units (the
    weight of s in r is this over n)."""
    lo = wp.max(s * m, r * n)
    hi = wp.min((s + wp.int64(1)) * m, (r + wp.int64(1)) * n)
    if hi <= lo:
        return wp.int64(0)
    return hi - lo


@wp.kernel
def reduce_band(
    thread_offset: wp.int32,
    src: wp.array3d[wp.uint8],
    src_row0: wp.int64,
    src_col0: wp.int64,
    src_shape: wp.vec2i,
    dst_row0: wp.int64,
    dst_col0: wp.int64,
    dst_shape: wp.vec2i,
    # outputs
    dst_out: wp.array3d[wp.uint8],
):
    """One thread per target pixel of a band: the area-weighted mean of the source pixels it covers.

    Target pixel r along an axis of n source and m target pixels covers source [r n / m, (r + 1) n / m), so
    the image mean is kept exactly (up to the rounding to uint8) for odd sizes too; 2:1 is a 2 x 2 box.
    The weighted sum is exact, in int64 (the weights are integer overlaps over n_rows n_cols), and rounded half
    up, floor(mean + 0.5), as the 2 x 2 box path. ``src`` holds source rows from ``src_row0`` and columns from
    ``src_col0``, ``dst_out`` target rows from ``dst_row0`` and columns from ``dst_col0`` (a window of the level:
    its pixels are those of the whole level's, the sizes ``src_shape`` and ``dst_shape`` being the levels').

    An image with alpha (2 channels, grey + alpha, or 4, RGBA; straight alpha) averages its colour weighted by
    alpha, sum(w a c) / sum(w a) (premultiplied, then divided by the mean alpha): the colour of transparent pixels
    (a nodata collar's black) bled into the edge pixels of every coarser level, a dark rim. Where every pixel
    covered is transparent, the plain mean. An opaque image gets exactly the plain mean.
    """
    t = wp.tid() + thread_offset
    cols = dst_out.shape[1]
    channels = dst_out.shape[2]
    alpha = channels - 1 if channels == 2 or channels == 4 else -1  # the alpha channel, or none
    local_r, local_c = pixel_of(t, cols)
    r = wp.int64(local_r) + dst_row0
    c = wp.int32(wp.int64(local_c) + dst_col0)
    n_rows = wp.int64(src_shape[0])
    m_rows = wp.int64(dst_shape[0])
    n_cols = wp.int64(src_shape[1])
    m_cols = wp.int64(dst_shape[1])
    first = wp.int32(src_row0)
    first_col = wp.int32(src_col0)
    if n_rows == wp.int64(2) * m_rows and n_cols == wp.int64(2) * m_cols:
        # even sizes: the 2 x 2 box in integers, (sum + 2) // 4 = floor(mean + 0.5), as the general path gives
        sr = wp.int32(r) * 2 - first
        sc = c * 2 - first_col
        a00 = wp.int32(1)
        a01 = wp.int32(1)
        a10 = wp.int32(1)
        a11 = wp.int32(1)
        coverage = wp.int32(4)  # sum of the weights: 4 x 1 without alpha
        if alpha >= 0:
            a00 = wp.int32(src[sr, sc, alpha])
            a01 = wp.int32(src[sr, sc + 1, alpha])
            a10 = wp.int32(src[sr + 1, sc, alpha])
            a11 = wp.int32(src[sr + 1, sc + 1, alpha])
            coverage = a00 + a01 + a10 + a11
            if coverage == 0:  # all transparent: the plain mean
                a00 = wp.int32(1)
                a01 = wp.int32(1)
                a10 = wp.int32(1)
                a11 = wp.int32(1)
                coverage = wp.int32(4)
        ch = wp.int32(0)
        while ch < channels:  # (a while loop: Warp's dynamic range() costs about 3 ns an iteration on the CPU)
            if ch == alpha or alpha < 0:
                box = (wp.int32(src[sr, sc, ch]) + wp.int32(src[sr, sc + 1, ch]) + wp.int32(src[sr + 1, sc, ch])
                       + wp.int32(src[sr + 1, sc + 1, ch]) + 2)
                dst_out[local_r, local_c, ch] = wp.uint8(box // 4)
            else:
                weighted = (a00 * wp.int32(src[sr, sc, ch]) + a01 * wp.int32(src[sr, sc + 1, ch])
                            + a10 * wp.int32(src[sr + 1, sc, ch]) + a11 * wp.int32(src[sr + 1, sc + 1, ch]))
                dst_out[local_r, local_c, ch] = wp.uint8((2 * weighted + coverage) // (2 * coverage))
            ch += 1
        return
    c64 = wp.int64(c)
    s_row_lo = wp.int32((r * n_rows) // m_rows)
    s_row_hi = wp.int32(((r + wp.int64(1)) * n_rows - wp.int64(1)) // m_rows)
    s_col_lo = wp.int32((c64 * n_cols) // m_cols)
    s_col_hi = wp.int32(((c64 + wp.int64(1)) * n_cols - wp.int64(1)) // m_cols)
    area = n_rows * n_cols  # the weights' common denominator: the sum is at most 255 area, exact in int64
    weight_sum = area  # the colour's denominator: sum(w a), at most 255 area (sums at most 255^2 area: exact)
    weigh = wp.int32(0)
    alpha_total = wp.int64(0)  # sum(w a): the alpha channel's own weighted sum, taken once
    if alpha >= 0:
        for sr in range(s_row_lo, s_row_hi + 1):
            wr = overlap(wp.int64(sr), m_rows, r, n_rows)
            row_sum = wp.int64(0)
            for sc in range(s_col_lo, s_col_hi + 1):
                row_sum += overlap(wp.int64(sc), m_cols, c64, n_cols) * wp.int64(src[sr - first, sc - first_col, alpha])
            alpha_total += wr * row_sum
        if alpha_total > wp.int64(0):
            weigh = wp.int32(1)
            weight_sum = alpha_total
        # else all transparent: the plain mean (over area)
    for ch in range(channels):
        total = alpha_total  # the alpha channel: summed above
        by_alpha = weigh == 1 and ch != alpha
        if ch != alpha:
            total = wp.int64(0)
            for sr in range(s_row_lo, s_row_hi + 1):
                wr = overlap(wp.int64(sr), m_rows, r, n_rows)
                row_sum = wp.int64(0)
                for sc in range(s_col_lo, s_col_hi + 1):
                    value = wp.int64(src[sr - first, sc - first_col, ch])
                    if by_alpha:
                        value = value * wp.int64(src[sr - first, sc - first_col, alpha])
                    row_sum += overlap(wp.int64(sc), m_cols, c64, n_cols) * value
                total += wr * row_sum
        denominator = weight_sum if by_alpha else area
        dst_out[local_r, local_c, ch] = wp.uint8((wp.int64(2) * total + denominator) // (wp.int64(2) * denominator))


# ---------------------------------------------------------------------------------------------------------
# contour lines
# ---------------------------------------------------------------------------------------------------------


@wp.struct
class TexelSampling:
    """Where texel (r, c) of a north-up texture samples a :class:`HeightGrid`: at node coordinates
    ``start + (c * step[0], r * step[1])`` (column u, row v; integers are nodes), bilinearly."""

    rows: wp.int32
    cols: wp.int32
    start: wp.vec2
    step: wp.vec2


@wp.struct
class ContourStyle:
    """Contour levels and how their lines are drawn: uniform ``base + k * interval`` when ``levels`` is empty, else
    the explicit strictly increasing ``levels``; line k is an index line when ``index_every`` > 0 divides k (k
    from 0 at ``base``, or the position in ``levels``). Widths are halved, in texels; colours straight RGBA."""

    levels: wp.array[wp.float64]
    base: wp.float64
    interval: wp.float64
    half_width: wp.float32
    index_half_width: wp.float32
    index_every: wp.int32
    color: wp.vec4
    index_color: wp.vec4


@wp.func
def texel_slope(before: wp.vec2, centre: wp.float32, after: wp.vec2) -> wp.float32:
    """Height change per texel along one axis: the central difference, one-sided where a neighbour has no data
    (beyond the texture, nodata), 0 where neither has."""
    if before[1] > 0.0 and after[1] > 0.0:
        return (after[0] - before[0]) * 0.5
    if after[1] > 0.0:
        return after[0] - centre
    if before[1] > 0.0:
        return centre - before[0]
    return 0.0


@wp.func
def texel_gradient_norm(gx: wp.float32, gy: wp.float32) -> wp.float32:
    """sqrt(gx² + gy²) without the squares' under- or overflow: below ~1e-19 per texel they squared to 0 (flat
    ground: no line), above ~1.8e19 to inf (every level at distance 0: all line); there both are divided by the
    larger first. Elsewhere the plain formula, its float32 values as they were."""
    s = gx * gx + gy * gy
    if s >= 1.0e-30 and s <= 1.0e30:
        return wp.sqrt(s)
    m = wp.max(wp.abs(gx), wp.abs(gy))
    if m == 0.0:
        return 0.0
    u = gx / m
    v = gy / m
    return m * wp.sqrt(u * u + v * v)


@wp.func
def line_coverage(distance: wp.float32, half_width: wp.float32) -> wp.float32:
    """The part of a texel (a unit box) that a straight line ``2 * half_width`` texels wide covers, its centre line
    ``distance`` texels from the texel's centre, across the line: > 0.5 exactly when distance < half_width (for
    lines at least a texel wide), 1 within half_width - 0.5."""
    return wp.clamp(wp.min(distance + half_width, 0.5) - wp.max(distance - half_width, -0.5), 0.0, 1.0)


@wp.func
def level_distance(gap: wp.float64, slope: wp.float32) -> wp.float32:
    """Texels from a texel to a level ``gap`` (>= 0) height units away where the height changes by ``slope`` per
    texel: gap / slope, the first-order estimate; on flat ground (slope 0) 0 exactly on the level, else far."""
    if slope > 0.0:
        return wp.min(wp.float32(gap / wp.float64(slope)), 1.0e30)
    if gap == wp.float64(0.0):
        return 0.0
    return 1.0e30


@wp.func
def is_index_line(k: wp.float64, every: wp.int32) -> wp.bool:
    """Whether line k (a whole number, any sign) is an index line: ``every`` > 0 divides it."""
    if every <= 0:
        return False
    n = wp.float64(every)
    return k - n * wp.floor(k / n) == wp.float64(0.0)


@wp.func
def contour_line(style: ContourStyle, index: wp.bool, gap: wp.float64, slope: wp.float32, best: wp.vec4) -> wp.vec4:
    """``best`` (straight RGBA, alpha the coverage) or the line's, ``gap`` height units away (an index line if
    ``index``), where it covers more."""
    half = wp.where(index, style.index_half_width, style.half_width)
    colour = wp.where(index, style.index_color, style.color)
    coverage = line_coverage(level_distance(gap, slope), half) * colour[3]
    if coverage > best[3]:
        return wp.vec4(colour[0], colour[1], colour[2], coverage)
    return best


@wp.func
def sample_axis(start: wp.float32, step: wp.float32, k: wp.int32, n: wp.int32):
    """One axis of where texel index ``k`` samples the grid (:class:`TexelSampling`): (node index 0, node index 1,
    fraction) among ``n`` nodes, the coordinate ``start + k * step`` clamped to the grid."""
    x = wp.clamp(start + float(k) * step, 0.0, float(n - 1))
    i0 = wp.int32(wp.floor(x))
    return i0, wp.min(i0 + 1, n - 1), x - float(i0)


@wp.func
def bilinear_height(heights: wp.array2d[wp.float32], nodata: wp.int32, i0: wp.int32, i1: wp.int32, fv: wp.float32,
                    j0: wp.int32, j1: wp.int32, fu: wp.float32) -> wp.vec2:
    """(height, weight of data) of the grid's bilinear interpolant at the node coordinates whose two
    :func:`sample_axis` parts are given: the corners with data weighted and renormalised, so a nodata (NaN) corner
    spreads no NaN; (0, 0) where no corner of non-zero weight has data. Without ``nodata`` (a grid without NaN) no
    branches, the same values (but for the sign of a zero height, which draws the same lines): a corner of weight 0
    adds a zero, and a texel on a node (both fractions 0: every texel at one texel per node) reads that node."""
    if nodata == 0:
        if fu == 0.0 and fv == 0.0:
            return wp.vec2(load(heights, i0, j0), 1.0)
        w0 = (1.0 - fv) * (1.0 - fu)
        w1 = (1.0 - fv) * fu
        w2 = fv * (1.0 - fu)
        w3 = fv * fu
        total = wp.float32(0.0) + w0 * load(heights, i0, j0)
        total = total + w1 * load(heights, i0, j1)
        total = total + w2 * load(heights, i1, j0)
        total = total + w3 * load(heights, i1, j1)
        weight = wp.float32(0.0) + w0
        weight = weight + w1
        weight = weight + w2
        weight = weight + w3
        return wp.vec2(total / weight, weight)
    total = wp.float32(0.0)
    weight = wp.float32(0.0)
    w = (1.0 - fv) * (1.0 - fu)
    if w > 0.0:
        h = load(heights, i0, j0)
        if not wp.isnan(h):
            total += w * h
            weight += w
    w = (1.0 - fv) * fu
    if w > 0.0:
        h = load(heights, i0, j1)
        if not wp.isnan(h):
            total += w * h
            weight += w
    w = fv * (1.0 - fu)
    if w > 0.0:
        h = load(heights, i1, j0)
        if not wp.isnan(h):
            total += w * h
            weight += w
    w = fv * fu
    if w > 0.0:
        h = load(heights, i1, j1)
        if not wp.isnan(h):
            total += w * h
            weight += w
    if weight > 0.0:
        return wp.vec2(total / weight, weight)
    return wp.vec2(0.0, 0.0)


@wp.func
def on_grid(start: wp.float32, step: wp.float32, texels: wp.int32, nodes: wp.int32) -> wp.bool:
    """Whether the first and the last of ``texels`` coordinates ``start + k * step`` lie on the ``nodes`` of a grid
    axis (a whole ``start`` and a step of +-1: all of them then, unclamped)."""
    last = start + float(texels - 1) * step
    return start >= 0.0 and start <= float(nodes - 1) and last >= 0.0 and last <= float(nodes - 1)


@wp.func
def line_near(gap: wp.float64, slope: wp.float32, slope64: wp.float64, reach: wp.float64) -> wp.bool:
    """Whether a level ``gap`` height units away may cover some of the texel; False where it surely covers none:
    gap > reach * slope, reach the widest line's half width plus half a texel, times 1 + 2^-20 (more than the
    roundings of reach * slope, of gap / slope and of its float32), so that :func:`level_distance` is more than half
    a texel beyond either half width (:func:`line_coverage` 0). Saves the line's division, and its index test, on
    most texels."""
    if slope > 0.0:
        if gap > reach * slope64:
            return False
    return True


@wp.func
def index_lines(k: wp.float64, every: wp.int32, inverse: wp.float64) -> wp.vec2i:
    """(:func:`is_index_line` of line k, of line k + 1) as 0 or 1, without its division where that is exact
    (|k| < 2^51, ``inverse`` = 1 / every): ``every`` divides a whole number m exactly when
    m == every * round(m * inverse), the quotient then within far less than half of a whole number of
    m * inverse."""
    if every <= 0:
        return wp.vec2i(0, 0)
    n = wp.float64(every)
    if wp.abs(k) < wp.float64(2251799813685248.0):
        k1 = k + wp.float64(1.0)
        return wp.vec2i(wp.where(k - n * wp.round(k * inverse) == wp.float64(0.0), 1, 0),
                        wp.where(k1 - n * wp.round(k1 * inverse) == wp.float64(0.0), 1, 0))
    return wp.vec2i(wp.where(is_index_line(k, every), 1, 0),
                    wp.where(is_index_line(k + wp.float64(1.0), every), 1, 0))


@wp.func
def draw_level_pair(style: ContourStyle, k: wp.float64, below: wp.bool, gap_below: wp.float64, above: wp.bool,
                    gap_above: wp.float64, slope: wp.float32, reach: wp.float64, inverse: wp.float64,
                    best: wp.vec4) -> wp.vec4:
    """:func:`contour_line` of line k ``gap_below`` under the texel's height (if ``below``: there is one), then of
    line k + 1 ``gap_above`` over it (if ``above``), the same values in the same order; a line :func:`line_near`
    rules out skipped."""
    slope64 = wp.float64(slope)
    near_below = below and line_near(gap_below, slope, slope64, reach)
    near_above = above and line_near(gap_above, slope, slope64, reach)
    if near_below or near_above:
        index = index_lines(k, style.index_every, inverse)
        if near_below:
            best = contour_line(style, index[0] != 0, gap_below, slope, best)
        if near_above:
            best = contour_line(style, index[1] != 0, gap_above, slope, best)
    return best


@wp.kernel
def draw_contours(
    thread_offset: wp.int32,
    run: wp.int32,
    grid: HeightGrid,
    sampling: TexelSampling,
    style: ContourStyle,
    # outputs
    rgba_out: wp.array2d[wp.vec4],
):
    """One thread per run of up to ``run`` texels of a row (on CUDA 1: a thread a texel, neighbours' stores
    adjacent; on the CPU ``stepterrain.texture.CONTOUR_RUN``). A texel's height is the bilinear interpolant at its
    centre, and its change per texel the central differences of the neighbouring texels' heights; the two levels
    around the height (the one at or below, the one above) each drawn as an anti-aliased line of its width by the
    distance |h - level| / |grad h| texels; the stronger kept, straight colour, alpha its coverage times the
    centre's weight of data (0 over nodata).

    The heights slide along the row (three new samples a texel, not five: the texel right of the centre, the ones
    above and below it; at one texel per node without nodata, three reads), each row's part of the sampling is
    computed once, and a level surely too far to draw
    (:func:`line_near`) is skipped before its float64 division (3-4x faster on the CPU than a thread a texel that
    did all of that per texel; the same values)."""
    t = wp.tid() + thread_offset
    runs = (sampling.cols + run - 1) // run
    r = t // runs
    c0 = (t - r * runs) * run
    c1 = wp.min(c0 + run, sampling.cols)
    heights = grid.heights
    nodata = grid.has_nodata
    x0 = sampling.start[0]
    dx = sampling.step[0]
    i0, i1, fv = sample_axis(sampling.start[1], sampling.step[1], r, grid.rows)
    a0, a1, fa = sample_axis(sampling.start[1], sampling.step[1], r - 1, grid.rows)  # the row above
    b0, b1, fb = sample_axis(sampling.start[1], sampling.step[1], r + 1, grid.rows)  # the row below
    has_up = r > 0
    has_down = r + 1 < sampling.rows
    widest = wp.max(style.half_width, style.index_half_width)  # line_near's reach, a hair beyond widest + 1/2
    reach = (wp.float64(widest) + wp.float64(0.5)) * wp.float64(1.00000095367431640625)
    if widest >= 1.0e29:  # level_distance's 1e30 cap could leave such lines drawn: never skip
        reach = wp.float64(wp.inf)
    inverse = wp.float64(1.0) / wp.float64(wp.max(style.index_every, 1))  # index_lines' reciprocal
    n = style.levels.shape[0]
    none = wp.vec2(0.0, 0.0)
    # one texel per node (every texel centre on a node inside the grid, no nodata): the heights are the nodes'
    y0 = sampling.start[1]
    dy = sampling.step[1]
    on_nodes = (nodata == 0 and wp.abs(dx) == 1.0 and wp.abs(dy) == 1.0 and x0 == wp.floor(x0)
                and y0 == wp.floor(y0) and on_grid(x0, dx, sampling.cols, grid.cols)
                and on_grid(y0, dy, sampling.rows, grid.rows))
    step = wp.int32(dx)
    j0, j1, fu = sample_axis(x0, dx, c0, grid.cols)
    left = none
    if c0 > 0:
        l0, l1, fl = sample_axis(x0, dx, c0 - 1, grid.cols)
        left = bilinear_height(heights, nodata, i0, i1, fv, l0, l1, fl)
    centre = bilinear_height(heights, nodata, i0, i1, fv, j0, j1, fu)
    c = c0
    while c < c1:
        right = none
        n0 = j0
        n1 = j1
        fn = fu
        if c + 1 < sampling.cols:
            if on_nodes:  # bilinear_height's read of a node, without sample_axis
                n0 = j0 + step
                right = wp.vec2(load(heights, i0, n0), 1.0)
            else:
                n0, n1, fn = sample_axis(x0, dx, c + 1, grid.cols)
                right = bilinear_height(heights, nodata, i0, i1, fv, n0, n1, fn)
        best = wp.vec4(style.color[0], style.color[1], style.color[2], 0.0)
        if centre[1] > 0.0:
            h = centre[0]
            up = none
            down = none
            if on_nodes:
                if has_up:
                    up = wp.vec2(load(heights, a0, j0), 1.0)
                if has_down:
                    down = wp.vec2(load(heights, b0, j0), 1.0)
            else:
                if has_up:
                    up = bilinear_height(heights, nodata, a0, a1, fa, j0, j1, fu)
                if has_down:
                    down = bilinear_height(heights, nodata, b0, b1, fb, j0, j1, fu)
            gx = texel_slope(left, h, right)
            gy = texel_slope(up, h, down)
            slope = texel_gradient_norm(gx, gy)
            h64 = wp.float64(h)
            if n == 0:
                q = (h64 - style.base) / style.interval
                k = wp.floor(q)
                best = draw_level_pair(style, k, True, (q - k) * style.interval, True,
                                       (k + wp.float64(1.0) - q) * style.interval, slope, reach, inverse, best)
            else:
                lo = wp.int32(0)  # the first level above h: binary search
                hi = n
                while lo < hi:
                    mid = (lo + hi) // 2
                    if style.levels[mid] <= h64:
                        lo = mid + 1
                    else:
                        hi = mid
                below = wp.float64(0.0)  # line lo - 1 (none below the first level), then line lo (none above the last)
                above = wp.float64(0.0)
                if lo > 0:
                    below = h64 - style.levels[lo - 1]
                if lo < n:
                    above = style.levels[lo] - h64
                best = draw_level_pair(style, wp.float64(lo - 1), lo > 0, below, lo < n, above, slope, reach, inverse,
                                       best)
            best = wp.vec4(best[0], best[1], best[2], best[3] * wp.min(centre[1], 1.0))
        store(rgba_out, r, c, best)
        left = centre
        centre = right
        j0 = n0
        j1 = n1
        fu = fn
        c += 1


@wp.kernel
def lay_over_uint8(
    thread_offset: wp.int32,
    run: wp.int32,
    layer: wp.array2d[wp.vec4],
    # outputs
    image: wp.array3d[wp.uint8],
):
    """Straight RGBA ``layer`` laid over the uint8 RGB or RGBA ``image`` (same rows and columns) in place, a thread a
    run of ``run`` texels of the image in row-major order, in float32, each formula evaluated in the order written
    here (as NumPy evaluated it: ``stepterrain.texture.blend`` laying ``b`` over ``a``, ``to_uint8`` rounding):
    coverage c = the layer's alpha; over RGB the colour ``b * c + a * (1 - c)``; over RGBA alpha
    ``c + alpha_a * (1 - c)`` and colour ``b * (c / alpha) + a * (alpha_a * (1 - c) / alpha)`` (``a`` where alpha is 0);
    rounded half to even."""
    cols = layer.shape[1]
    total = layer.shape[0] * cols
    first = (wp.tid() + thread_offset) * run
    last = wp.min(first + run, total)
    n = first
    while n < last:
        r = n // cols
        c = n - r * cols
        top = layer[r, c]
        cover = top[3]
        rest = 1.0 - cover
        if image.shape[2] == 3:
            for ch in range(3):
                under = wp.float32(image[r, c, ch]) / 255.0
                image[r, c, ch] = unit_to_uint8(top[ch] * cover + under * rest)
        else:
            alpha_a = wp.float32(image[r, c, 3]) / 255.0
            kept = alpha_a * rest
            alpha = cover + kept
            for ch in range(3):
                under = wp.float32(image[r, c, ch]) / 255.0
                value = under
                if alpha > 0.0:  # blend_over's shares of the alpha
                    value = top[ch] * (cover / alpha) + under * (kept / alpha)
                image[r, c, ch] = unit_to_uint8(value)
            image[r, c, 3] = unit_to_uint8(alpha)
        n += 1
