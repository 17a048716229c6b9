"""Terrain textures: topographic textures, texture layers, their operations, lenses, animation and draping.

Implements paper 004 (Döllner, Baumann & Hinrichs, *Texturing Techniques for Terrain Visualization*, IEEE
Visualization 2000): the four kinds of texture layer and their operations (§3.2.3), texture lenses (§5),
texture animation (§6) and topographic textures with self-shadowing and encoded normals (§7, Fig. 5, 7).
Image pyramids, texture trees and the level-of-detail traversal (§3.2.1-3.2.2, §4) live in
:mod:`stepterrain.texture_lod`. Typical use:

    shade = hillshade(stepterrain.sample_dem(), shadows=True)            # (H, W) float32 in [0, 1]
    mesh = drape(stepterrain.stepped(dem, interval=100.0), modulate(thematic, topographic_layer(dem)))

The per-pixel work runs in Warp (``kernels/texture.py``); self-shadowing sweeps digital lines along the
light's azimuth with a running horizon, one thread per line and O(1) per pixel, and gives exactly the answer of
a ray march from every pixel towards the light over the points of its straight line (each node taken sideways
onto it, its height interpolated linearly across it; ``tests/reference_texture.py``).
"""

from __future__ import annotations

import inspect
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from fractions import Fraction
from typing import Any, Literal

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._compaction import check_budget, count_buffer, exclusive_offsets
from ._device import MIN_THREAD_ELEMENTS, host_copy, launch, recycled_empty, resolve_device, scratch
from .errors import InvalidInputError, caller_stacklevel, counted, plain_repr
from .kernels import texture as texture_kernels
from .mesh import mesh_argument
from .stepped import LENS_TEXEL_BYTES, given_levels, one_of_interval_or_levels
from .terrain import (
    FLOAT32_MAX,
    Terrain,
    as_array,
    as_number,
    as_terrain,
    check_flag,
    real_numbers,
    real_vector,
)
from .terrain import finite_number as _finite
from .terrain import is_name as _is_name

__all__ = [
    "HILLSHADE_METHODS",
    "MAPLIBRE_METHODS",
    "LAYER_KINDS",
    "TextureLayer",
    "Pipeline",
    "TextureAnimation",
    "hillshade",
    "cast_shadows",
    "ambient_occlusion",
    "normal_map",
    "relight",
    "topographic_layer",
    "contour_layer",
    "terrain_layer",
    "blend",
    "weighted_add",
    "modulate",
    "adjust",
    "combine",
    "highlight_lens",
    "thematic_lens",
    "drape",
    "texture_uv",
]

HILLSHADE_METHODS: tuple[str, ...] = ("standard", "multidirectional", "combined", "igor")
#: MapLibre GL's ``hillshade-method`` values as ``hillshade(method=...)``: premultiplied RGBA overlays
MAPLIBRE_METHODS: tuple[str, ...] = ("maplibre-standard", "maplibre-basic", "maplibre-combined", "maplibre-igor",
                                     "maplibre-multidirectional")
MAPLIBRE_DEFAULTS = {"exaggeration": 0.5, "shadow_color": (0.0, 0.0, 0.0, 1.0),
                     "highlight_color": (1.0, 1.0, 1.0, 1.0), "accent_color": (0.0, 0.0, 0.0, 1.0)}
LAYER_KINDS: tuple[str, ...] = ("thematic", "luminance", "topographic", "visibility")
BLEND_MODES: tuple[str, ...] = ("blend", "add", "modulate")
DEFAULT_AZIMUTH = math.radians(315.0)
#: The luminance of an unlit (fully self-shaded) node in :func:`topographic_layer`: ambient + (1 − ambient) · shade.
DEFAULT_AMBIENT = 0.25
DEFAULT_ALTITUDE = math.radians(45.0)
# Adjacent sweep lines one CPU thread walks in lockstep (cache reuse; 1 on CUDA), by the sweep's major axis. Along
# rows (``major_j`` 0) a step's lines are neighbouring columns, one contiguous run: the more the better. Along
# columns they are neighbouring rows, a row's length apart, and every line beyond a few conflicts in the caches.
# 4096² of real relief, one core (RESULTS.md "Session 24"): along rows 87 ms with 64 lines, 57 ms with 1024; along
# columns 139-146 ms with 64, 102-126 ms with 16, 276 ms with 1024.
_LINES_PER_THREAD_CPU = {0: 1024, 1: 16}
# ... except where the rows lie a multiple of 4 KiB apart (a power-of-two width from 1024 floats): every row of a
# bundle then maps to the same L1 cache set, and 16 rows of heights plus 16 of the mask evict one another. 4096²,
# one core, azimuth 90° / 300°: 16 lines 95 / 105 ms, 8 lines 59 / 76 ms; 4000 wide: 53 / 58 ms against 55 / 82 ms.
_LINES_PER_THREAD_CPU_ALIASED_ROWS = 8
# The occlusion sweep's lines each keep a hull stack, so fewer lines along rows: at 2048², 16 directions, 1849 ms
# one line per thread, 980-1035 ms with 32-128 along rows and 8-32 along columns, 1299 ms with 4096 / 64.
_OCCLUSION_LINES_PER_THREAD_CPU = {0: 128, 1: 16}

LayerKind = Literal["thematic", "luminance", "topographic", "visibility"]
Extent = tuple[float, float, float, float]


# ---------------------------------------------------------------------------------------------- validation
def _grid_terrain(terrain: Any, spacing: Any, origin: Any = None) -> Terrain:
    t = as_terrain(terrain, spacing=spacing, origin=origin)
    if t.kind != "grid":
        raise InvalidInputError("topographic textures need a regular heightfield (an (H, W) array or a grid "
                                f"Terrain); got a {t.kind.upper()}")
    return t


def _azimuth(value: Any) -> float:
    """A finite azimuth in radians; one beyond two full turns is most likely degrees given as radians: warned."""
    azimuth = _finite(value, "azimuth")
    if abs(azimuth) > 4 * math.pi:  # two turns: degrees of any usual light (13° and up), not a computed angle
        warnings.warn(f"azimuth is in radians; got {azimuth:g}, more than two full turns. Degrees? Pass "
                      f"math.radians({azimuth:g}) = {math.radians(azimuth):.4f}", stacklevel=caller_stacklevel())
    return azimuth


def _turn(azimuth: float) -> float:
    """The azimuth less its whole turns, in float64, for the kernels that take the angle itself in float32 (igor,
    MapLibre): a warned-about 1e10 rad shaded as another angle there, and 1e300 as infinity (NaN)."""
    return math.fmod(azimuth, 2.0 * math.pi)


def _light(azimuth: float, altitude: float) -> tuple[float, float]:
    azimuth = _azimuth(azimuth)
    altitude = _finite(altitude, "altitude", lo=0.0, hi=math.pi / 2, unit="rad")
    return azimuth, altitude


#: Most azimuths ambient_occlusion sweeps (one per degree): each costs a pass over the image, and 10**9 ran
#: for days; more than one a degree changes nothing visible.
MAX_OCCLUSION_DIRECTIONS = 360

#: The steepest slope (rise over run, z_factor included) the float32 kernels take: its square stays finite.
_MAX_SLOPE = 1e18
#: The largest |height| (z_factor included) the float32 kernels take: Horn's sums of four stay finite.
_MAX_HEIGHT = FLOAT32_MAX / 8


def _height_grid(t: Terrain, z_factor: float, device: wp.Device) -> texture_kernels.HeightGrid:
    def build() -> wp.array:
        return wp.array(t.heights, dtype=wp.float32, device=device, copy=not device.is_cpu)

    try:
        lo, hi = t.finite_height_range  # every pixel is shaded, one on no triangle too
    except InvalidInputError:  # all nodata: nothing to shade
        lo = hi = 0.0
    rise, run = hi - lo, min(abs(t.spacing[0]), abs(t.spacing[1]))
    if float(z_factor) * rise / run > _MAX_SLOPE:  # squared in float32: beyond ~1e19 a flat grey image
        raise InvalidInputError(f"z_factor x height range / spacing must stay below {_MAX_SLOPE:g} (float32 "
                                f"slopes); got {float(z_factor):g} x {rise:g} / {run:g}")
    # a (near) flat grid passes the slope check at any magnitude, but the kernels' float32 sums and products
    # overflowed: Horn's c + 2f + k and the border's 2 · edge − next of heights near 3.4e38, z_factor / (8 dx) and
    # z_factor · h (the sweeps, the point light) of a huge z_factor; the images came out black or NaN
    peak = max(abs(lo), abs(hi))
    if peak > _MAX_HEIGHT:
        raise InvalidInputError(f"heights must stay within ±{_MAX_HEIGHT:.3g} for the texture kernels' float32 "
                                f"sums; got {lo:g} to {hi:g}")
    if float(z_factor) / (8.0 * run) > FLOAT32_MAX or float(z_factor) * max(peak, 1.0) > _MAX_HEIGHT:
        raise InvalidInputError(f"z_factor must keep z_factor / (8 x spacing) and z_factor x |heights| within "
                                f"float32 (below {_MAX_HEIGHT:.3g}); got z_factor {float(z_factor):g} with heights up "
                                f"to {peak:g} and spacing {run:g}")
    grid = texture_kernels.HeightGrid()
    grid.heights = t.cached(("texture.heights", str(device)), build)
    grid.rows, grid.cols = (int(n) for n in t.heights.shape)
    grid.spacing = wp.vec2(float(t.spacing[0]), float(t.spacing[1]))
    grid.z_factor = float(z_factor)
    grid.gradient_scale = wp.vec2(float(z_factor) / (8.0 * t.spacing[0]), float(z_factor) / (8.0 * t.spacing[1]))
    grid.has_nodata = int(t.has_nodata)
    return grid


def _output(shape: tuple[int, ...], np_dtype: Any, wp_dtype: Any, device: wp.Device,
            zero: bool = False) -> tuple[NDArray[Any] | None, wp.array]:
    """An output the kernels write straight into numpy memory on the CPU (copied back once on CUDA); a large one
    on memory a freed output left (:func:`stepterrain._device.recycled_empty`: no page faults of fresh memory)."""
    if device.is_cpu:
        host = recycled_empty(shape, np_dtype)
        if zero:
            host.fill(0)
        return host, wp.array(host, dtype=wp_dtype, device=device, copy=False)
    maker = wp.zeros if zero else wp.empty
    return None, maker(shape, dtype=wp_dtype, device=device)


def _result(host: NDArray[Any] | None, array: wp.array) -> NDArray[Any]:
    return host if host is not None else host_copy(array)


# ---------------------------------------------------------------------------------------------- §7 topographic
#: Bytes a DEM node the topographic functions take at their peak (output and working arrays, numpy's and Warp's),
#: measured as the process's peak RSS (VmHWM) over a 2000 x 2000 DEM and rounded up: hillshade 4.5 (5.7
#: multidirectional with shadows), 16.4 with a MapLibre method's RGBA; cast_shadows 1.1; ambient_occlusion 11.2;
#: normal_map 3.9; topographic_layer 13.7, 28.2 with occlusion (17.4 and 30.8 on a Terrain shaded the first time:
#: its heights' device copy, kept). Nothing was checked: a DEM loaded within the budget (4 bytes a node) made a
#: topographic layer of three times it.
_NODE_BYTES = {"hillshade": 7, "maplibre": 20, "cast_shadows": 2, "ambient_occlusion": 13, "normal_map": 5,
               "topographic_layer": 18, "occlusion": 15}


def _check_nodes(t: Terrain, nbytes: int, what: str) -> None:
    """``what`` of the DEM ``t`` at ``nbytes`` a node against the memory budget, before anything is allocated."""
    rows, cols = t.heights.shape
    check_budget(nbytes * rows * cols, f"{what} of a {cols} x {rows} DEM",
                 hint="crop or coarsen the DEM (Terrain.crop, Terrain.coarsen; --crop, --coarsen)")


def _check_topographic(t: Terrain, occlusion: bool) -> None:
    """:func:`topographic_layer`'s working memory (:data:`_NODE_BYTES`, more with ambient occlusion), checked before
    it shades (and by the texture CLI once its DEM is loaded)."""
    _check_nodes(t, _NODE_BYTES["topographic_layer"] + (_NODE_BYTES["occlusion"] if occlusion else 0),
                 "the topographic layer")


def hillshade(
    terrain: Terrain | ArrayLike,
    *,
    azimuth: float | None = None,
    altitude: float | None = None,
    z_factor: float = 1.0,
    method: str = "standard",
    shadows: bool = False,
    shadow_strength: float | None = None,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
    exaggeration: float | None = None,
    shadow_color: ArrayLike | None = None,
    highlight_color: ArrayLike | None = None,
    accent_color: ArrayLike | None = None,
) -> NDArray[np.float32]:
    """Hillshade of a heightfield from its full-resolution Horn gradients, optionally self-shadowed.

    Parameters
    ----------
    terrain : Terrain or (H, W) array_like
        Heights (NaN = nodata); a raw array takes ``spacing`` (dx, dy), default (1, 1).
    azimuth, altitude : float, optional
        Direction the light comes from: azimuth clockwise from north (+y), altitude above the horizon in
        [0, π/2], radians, not degrees: the defaults (None) are GDAL's ``-az 315 -alt 45``, ``math.radians(315)``
        and ``math.radians(45)`` (the CLI's ``--azimuth``/``--altitude`` take degrees). An azimuth beyond two
        turns (4π) is taken for degrees given by mistake and warned about (it is still used as radians). As
        gdaldem refuses ``-multidirectional`` with ``-az`` and ``-igor`` with ``-alt``, an azimuth given with
        ``method="multidirectional"`` (four fixed lights) or an altitude with ``"igor"`` (no altitude) is refused
        unless ``shadows=True``, which they aim.
    z_factor : float
        Vertical exaggeration applied to the heights (GDAL's ``-z``).
    method : "standard", "multidirectional", "combined" or "igor"
        GDAL's ``gdaldem hillshade`` variants: Lambert shading ``max(0, n·l)``; the USGS multidirectional
        blend of lights at 225°, 270°, 315° and 360° weighted by cos²(aspect − azimuth) (``-multidirectional``,
        MapLibre's ``hillshade-method: multidirectional``); slope and oblique shading combined,
        ``1 − angle(n, l) · slope / (π/2)²`` (``-combined``, MapLibre's ``combined``); Igor's shading
        ``1 − (slope / 90°) · (angle between the light's azimuth and the downhill aspect) / 180°``, which
        ignores the altitude (``-igor``, MapLibre's ``igor``; on non-square pixels gdaldem takes the aspect from
        unscaled pixel differences, this is the true downhill aspect). Or one of :data:`MAPLIBRE_METHODS`, MapLibre
        GL's own shader for its ``hillshade-method`` (``maplibre-standard`` is its legacy shading); these
        return an (H, W, 4) RGBA overlay, see Notes.
    shadows : bool
        Darken pixels that the terrain shadows from the light (see :func:`cast_shadows`) by ``shadow_strength``.
    shadow_strength : float, optional
        In [0, 1]: a shadowed pixel keeps ``1 − shadow_strength`` of its shade (default 1); refused without
        ``shadows=True`` (it would have no effect).
    spacing : (dx, dy), optional
        Node spacing of an array ``terrain`` (default (1, 1)); refused with a Terrain, which brings its own.
    device : warp device, optional
    exaggeration : float, optional
        MapLibre methods only: ``hillshade-exaggeration`` in [0, 1], default 0.5.
    shadow_color, highlight_color, accent_color : RGB or RGBA in [0, 1], optional
        MapLibre methods only (straight alpha; defaults black, white, black as in MapLibre's style spec). For
        ``maplibre-multidirectional`` shadow and highlight may be one colour per light.

    Returns
    -------
    (H, W) float32
        Shade in [0, 1], pixel (i, j) = grid node (i, j); NaN where the height is nodata. GDAL's byte output
        is ``1 + 254 · shade``.
    (H, W, 4) float32
        For the MapLibre methods: the hillshade layer's premultiplied RGBA, composited over a background as
        ``rgba + background · (1 − alpha)``; NaN where the height is nodata.

    Raises
    ------
    InvalidInputError
        Altitude outside [0°, 90°], non-finite azimuth, non-positive z factor, unknown method, bad heights; an
        argument the shading would ignore (see ``azimuth``, ``shadow_strength``).

    Notes
    -----
    Horn's 3 × 3 gradient with the signed spacing, so north-up rasters (dy < 0) shade like GDAL. The border is
    shaded as ``gdaldem hillshade -compute_edges`` shades it: a neighbour beyond an edge is extrapolated linearly
    (2 · edge − next inward), except beyond the left or right edge in the first and last rows, where the edge
    column repeats; a missing neighbour next to nodata takes the centre height. The MapLibre methods repeat the
    edge instead (MapLibre backfills a DEM tile's border with its nearest pixel).
    One thread per pixel, O(1) each.

    MapLibre methods follow ``src/shaders/glsl/hillshade.fragment.glsl`` of maplibre/maplibre-gl-js (commit
    27688c1c2109f2ebbf7f65a773ef88598a8df75b) on the same Horn gradient, read as MapLibre's ``deriv``
    (dz/dx, dz/dy southwards): ``maplibre-standard`` shades by slope (``atan(0.625 |∇z|)``, eased by the
    exaggeration) with ``1 − |aspect − azimuth| / π`` mixing shadow and highlight, over the accent colour;
    ``maplibre-basic`` is GDAL's Lambert shade of ``2 · exaggeration · ∇z`` mapped to shadow (below 0.5) or
    highlight (above); ``maplibre-multidirectional`` averages ``basic`` over the lights given as sequences of
    ``azimuth`` and ``altitude`` (shorter lists repeat their last value, as MapLibre does);
    ``maplibre-combined`` and ``maplibre-igor`` add a highlight to GDAL's shadings (the angle to the light is
    clamped at 90°). What MapLibre does to tiles is left out: the 8-bit encoding of ``deriv`` (and its
    clamp to ±4), the zoom-dependent exaggeration below zoom 15 and the Mercator latitude correction;
    ``spacing`` gives true ground distances instead. The light is anchored to the map.
    ``shadows=True`` applies to the grey methods only.

    References
    ----------
    Döllner, Baumann, Hinrichs: Texturing Techniques for Terrain Visualization, IEEE Vis 2000, §7.
    B. K. P. Horn: Hill shading and the reflectance map, Proc. IEEE 69(1), 1981. GDAL ``gdaldem``.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import hillshade
    >>> plane = np.zeros((5, 5), np.float32)
    >>> bool(np.allclose(hillshade(plane, altitude=np.pi / 2, device="cpu"), 1.0))
    True
    """
    t = _grid_terrain(terrain, spacing)
    _check_nodes(t, _NODE_BYTES["maplibre" if _is_name(method, MAPLIBRE_METHODS) else "hillshade"], "the hillshade")
    shadows = check_flag(shadows, "shadows")
    if shadow_strength is not None and not shadows:  # it was ignored: the shade came out the same whatever it was
        raise InvalidInputError(f"shadow_strength applies only with shadows=True (it darkens the shadowed pixels); "
                                f"got shadow_strength={shadow_strength!r} with shadows=False")
    if _is_name(method, MAPLIBRE_METHODS):
        if shadows:
            raise InvalidInputError(f"shadows=True applies to the grey methods {', '.join(HILLSHADE_METHODS)}; "
                                    f"got method={method!r} (an RGBA overlay)")
        return _maplibre_hillshade(t, DEFAULT_AZIMUTH if azimuth is None else azimuth,
                                   DEFAULT_ALTITUDE if altitude is None else altitude, z_factor, method, exaggeration,
                                   shadow_color, highlight_color, accent_color, device)
    if not _is_name(method, HILLSHADE_METHODS):
        raise InvalidInputError(f"method must be one of {', '.join(HILLSHADE_METHODS + MAPLIBRE_METHODS)}; "
                                f"got {method!r}")
    # an angle the shading ignores is refused, as gdaldem refuses -multidirectional with -az and -igor with -alt (and
    # the CLI its --azimuth and --altitude): the shade came out the same whatever was given; shadows it still aims
    ignored = {"multidirectional": ("azimuth", azimuth, "its four fixed lights, from azimuths 225°, 270°, 315° and "
                                                        "360°"),
               "igor": ("altitude", altitude, "the light's azimuth and the slope alone")}.get(method)
    if ignored is not None and ignored[1] is not None and not shadows:
        name, value, why = ignored
        raise InvalidInputError(f"{name} has no effect on method={method!r}, which shades by {why} (as gdaldem "
                                f"-{method}); it aims shadows=True only; got {name}={value!r} without shadows")
    azimuth = DEFAULT_AZIMUTH if azimuth is None else azimuth
    altitude = DEFAULT_ALTITUDE if altitude is None else altitude
    shadow_strength = 1.0 if shadow_strength is None else shadow_strength
    for name, value in (("exaggeration", exaggeration), ("shadow_color", shadow_color),
                        ("highlight_color", highlight_color), ("accent_color", accent_color)):
        if value is not None:
            raise InvalidInputError(f"{name} applies to the MapLibre methods ({', '.join(MAPLIBRE_METHODS)}); "
                                    f"got method={method!r}")
    azimuth, altitude = _light(azimuth, altitude)
    z_factor = _finite(z_factor, "z_factor", positive=True)
    shadow_strength = _finite(shadow_strength, "shadow_strength", lo=0.0, hi=1.0)
    dev = resolve_device(device)
    grid = _height_grid(t, z_factor, dev)
    host, out = _output(t.heights.shape, np.float32, wp.float32, dev)
    light = wp.vec3(math.sin(azimuth) * math.cos(altitude), math.cos(azimuth) * math.cos(altitude),
                    math.sin(altitude))
    if shadows and shadow_strength > 0:
        shadow = _shadow_array(t, grid, azimuth, altitude, dev)
    else:
        shadow = wp.empty((0, 0), dtype=wp.uint8, device=dev)
    runs = -(-grid.cols // texture_kernels.SHADE_RUN)
    launch(texture_kernels.shade_heights, dim=grid.rows * runs,
           inputs=[grid, light, float(altitude), _turn(azimuth), HILLSHADE_METHODS.index(method), shadow,
                   float(shadow_strength)],
           outputs=[out], device=dev)
    shade = _result(host, out)
    return shade


def _colours(value: ArrayLike | None, name: str, default: tuple[float, ...], many: bool) -> NDArray[np.float32]:
    """(n, 4) premultiplied RGBA from one RGB(A) colour or, when ``many``, a sequence of them."""
    raw = default if value is None else value
    what = "an RGB or RGBA colour" + (" or a sequence of them (one per light)" if many else "")
    nested = isinstance(raw, (Sequence, np.ndarray)) and not isinstance(raw, str) and len(raw) > 0 and all(
        isinstance(c, (Sequence, np.ndarray)) and not isinstance(c, str) for c in raw)
    rows = list(raw) if nested else [raw]
    if len(rows) > 1 and not many:
        raise InvalidInputError(f"{name} must be {what}; got {len(rows)} colours")
    colours = []
    for row in rows:
        try:  # real_numbers: np.asarray(row, dtype=float) took ("1", "0", "0") and (True, 0, 0) as numbers, and a
            # masked component as the value under its mask
            c = real_numbers(row, name, f"{what} of numbers in [0, 1]")
        except InvalidInputError:
            raise InvalidInputError(f"{name} must be {what} of numbers in [0, 1]; got {raw!r}") from None
        if c.shape not in ((3,), (4,)):
            raise InvalidInputError(f"{name} must be {what}; got {raw!r}")
        if not np.all(np.isfinite(c)) or c.min() < 0 or c.max() > 1:
            raise InvalidInputError(f"{name} components must lie in [0, 1]; got {raw!r}")
        rgba = np.append(c, 1.0) if c.shape == (3,) else c.copy()
        rgba[:3] *= rgba[3]  # premultiplied, as MapLibre's Color
        colours.append(rgba)
    return np.array(colours, dtype=np.float32)


def _angles(value: Any, name: str, many: bool, **bounds: Any) -> list[float]:
    """One angle, or (``many``) a sequence of them, each checked."""
    if isinstance(value, (Sequence, np.ndarray)) and not isinstance(value, str):
        if not many:
            raise InvalidInputError(f"{name} must be one angle (a sequence only with method="
                                    f"'maplibre-multidirectional'); got {value!r}")
        values = list(np.ravel(value))
    else:
        values = [value]
    if not values:
        raise InvalidInputError(f"{name} must hold at least one angle; got an empty sequence")
    if name == "azimuth":
        return [_azimuth(v) for v in values]
    return [_finite(v, name, **bounds) for v in values]


def _maplibre_hillshade(t: Terrain, azimuth: Any, altitude: Any, z_factor: float, method: str,
                        exaggeration: float | None, shadow_color: Any, highlight_color: Any, accent_color: Any,
                        device: wp.DeviceLike) -> NDArray[np.float32]:
    """MapLibre GL's hillshade layer colours (see :func:`hillshade`); lights padded with their last value."""
    many = method == "maplibre-multidirectional"
    azimuths = _angles(azimuth, "azimuth", many)
    altitudes = _angles(altitude, "altitude", many, lo=0.0, hi=math.pi / 2, unit="rad")
    z_factor = _finite(z_factor, "z_factor", positive=True)
    exaggeration = _finite(MAPLIBRE_DEFAULTS["exaggeration"] if exaggeration is None else exaggeration,
                           "exaggeration", lo=0.0, hi=1.0)
    shadows = _colours(shadow_color, "shadow_color", MAPLIBRE_DEFAULTS["shadow_color"], many)
    highlights = _colours(highlight_color, "highlight_color", MAPLIBRE_DEFAULTS["highlight_color"], many)
    accent = _colours(accent_color, "accent_color", MAPLIBRE_DEFAULTS["accent_color"], False)[0]
    n = max(len(azimuths), len(altitudes), len(shadows), len(highlights))

    def padded(values: Any) -> NDArray[Any]:
        values = np.asarray(values, dtype=np.float32)
        return np.concatenate([values, np.repeat(values[-1:], n - len(values), axis=0)])

    dev = resolve_device(device)
    style = texture_kernels.MapLibreStyle()
    style.method = MAPLIBRE_METHODS.index(method)
    style.exaggeration = exaggeration
    style.azimuths = wp.array(padded([_turn(a) for a in azimuths]), dtype=wp.float32, device=dev)
    style.altitudes = wp.array(padded(altitudes), dtype=wp.float32, device=dev)
    style.shadows = wp.array(padded(shadows), dtype=wp.vec4, device=dev)
    style.highlights = wp.array(padded(highlights), dtype=wp.vec4, device=dev)
    style.accent = wp.vec4(*(float(c) for c in accent))
    grid = _height_grid(t, z_factor, dev)
    host, out = _output((*t.heights.shape, 4), np.float32, wp.float32, dev)
    launch(texture_kernels.maplibre_shade_heights, dim=grid.rows * grid.cols, inputs=[grid, style],
           outputs=[out], device=dev)
    return _result(host, out)


#: A sideways step of the digital lines (in nodes) below which a node is not moved onto the straight line: float32
#: heights cannot tell it, and a light along an axis (``math.cos(math.pi / 2)`` = 6e-17) stays a plain row sweep.
_NEGLIGIBLE_SIDESTEP = 1e-6


def _unit_scale(t: Terrain, z_factor: float) -> float:
    """A power of two taking the larger of a grid's width, height and its height range (times ``z_factor``) to
    about 1, or 1 where that already lies within 2^±30 (the float32 sweeps' products and squares of world
    distances stay far inside float32's range there)."""
    rows, cols = t.heights.shape
    size = max(abs(float(t.spacing[0])) * max(cols - 1, 1), abs(float(t.spacing[1])) * max(rows - 1, 1))
    try:
        lo, hi = t.finite_height_range
        size = max(size, (float(hi) - float(lo)) * float(z_factor))
    except InvalidInputError:  # all nodata
        pass
    exponent = math.frexp(size)[1]
    return 1.0 if -30 <= exponent <= 30 else math.ldexp(1.0, -exponent)


def _sweep(shape: tuple[int, int], spacing: tuple[float, float], azimuth: float | tuple[float, float],
           altitude: float, device: wp.Device) -> tuple[texture_kernels.Sweep, int, bool]:
    """Digital sweep lines parallel to the light's azimuth (see kernels/texture.py), their count and whether every
    node lies on its straight line (``minor_error`` 0 at every major index, exactly: an axis or a diagonal, whose
    sweeps may skip the sideways steps); the azimuth in radians or as its (sine, cosine)."""
    rows, cols = shape
    dx, dy = spacing
    sin_az, cos_az = azimuth if isinstance(azimuth, tuple) else (math.sin(azimuth), math.cos(azimuth))
    toward_i = cos_az / dy  # index-space step towards the light
    toward_j = sin_az / dx
    sweep = texture_kernels.Sweep()
    # a diagonal light (the default 315°, equal |dx| and |dy|; sin and cos differ there in the last bit) sweeps
    # along rows, the faster axis on CPUs (see _LINES_PER_THREAD_CPU), at slope ±1 exactly: a diagonal's digital
    # lines are the same nodes in the same order along either axis
    if abs(toward_j) > abs(toward_i) * (1.0 + 1e-9):
        major_j, n_major, n_minor = 1, cols, rows
        slope, forward = toward_i / toward_j, -1 if toward_j > 0 else 1
    else:
        major_j, n_major, n_minor = 0, rows, cols
        slope, forward = toward_j / toward_i, -1 if toward_i > 0 else 1
        if abs(toward_i) <= abs(toward_j) * (1.0 + 1e-9):
            slope = math.copysign(1.0, slope)
    offsets, error = _digital_lines(n_major, slope)
    c_min = -int(offsets.max())
    c_max = n_minor - 1 - int(offsets.min())
    sweep.minor_offsets = wp.array(offsets, dtype=wp.int32, device=device)
    sweep.minor_error = wp.array(error, dtype=wp.float32, device=device)
    sweep.increasing = 1 if slope >= 0 else 0
    sweep.n_lines = c_max - c_min + 1
    sweep.major_j, sweep.n_major, sweep.n_minor = major_j, n_major, n_minor
    sweep.forward, sweep.c_min = forward, c_min
    sweep.away = wp.vec2(-sin_az, -cos_az)
    tan_altitude = math.tan(altitude) if altitude < math.pi / 2 else 3.0e38
    sweep.rise = wp.vec2(dx * -sin_az * tan_altitude, dy * -cos_az * tan_altitude)
    return sweep, sweep.n_lines, not error.any()


def compass(k: int, n: int) -> tuple[float, float]:
    """(sine, cosine) of the azimuth k/n of a turn, mirror-exact: reduced to the first octant by exact integer
    arithmetic, so azimuths mirrored across an axis or a diagonal (k/n against 1/2 − k/n, −k/n, 1/4 − k/n) give
    exactly the mirrored vectors (math.sin(π/2 − a) and math.cos(a) differ in the last bit, and a digital line
    rounded at a tie then took other nodes), and the diagonals equal sine and cosine."""
    m = (4 * k) % (4 * n)  # the azimuth in quarter turns is m / n
    quadrant, r = divmod(m, n)  # angle within the quadrant: r / n quarter turns
    if 2 * r == n:
        s = c = math.sqrt(0.5)
    elif 2 * r < n:
        s, c = math.sin(math.pi / 2 * r / n), math.cos(math.pi / 2 * r / n)
    else:
        c, s = math.sin(math.pi / 2 * (n - r) / n), math.cos(math.pi / 2 * (n - r) / n)
    return ((s, c), (c, -s), (-s, -c), (-c, s))[quadrant]


def _digital_lines(n_major: int, slope: float) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
    """The minor offsets of a digital line at each major index k (``Sweep.minor_offsets``): slope · (k − (n_major −
    1)/2) rounded to the nearest integer, halves towards 0, in float64 (slope ±1: ±k exactly); and how far they lie
    beyond that exact offset (``Sweep.minor_error``, in [-1/2, 1/2]; 0 on exact diagonals, which run through nodes,
    and below :data:`_NEGLIGIBLE_SIDESTEP`).

    The lines are anchored at the middle of the major axis and rounded symmetrically, so the same terrain laid out
    with its rows or columns reversed (dy or dx negated, a north-up raster against a south-up one) sweeps the same
    nodes: reversing the major axis maps k − (n − 1)/2 to its negative as the slope changes sign, reversing the
    minor axis negates the slope, and the rounding is odd. Anchored at k = 0 with ``floor(x + 0.5)`` the lines of
    the two layouts differed by the fraction of slope · (n − 1), and the shadows and occlusion with them. The
    sidesteps are odd too: the layouts with reversed rows or columns take their nodes the same way onto the same
    straight lines."""
    k = np.arange(n_major, dtype=np.float64)
    if abs(slope) == 1.0:  # exact diagonals: every line through nodes
        return (slope * k).astype(np.int32), np.zeros(n_major, np.float32)
    x = slope * (k - 0.5 * (n_major - 1))
    offsets = np.sign(x) * np.ceil(np.abs(x) - 0.5)
    error = (offsets - x).astype(np.float32)
    error[np.abs(error) < _NEGLIGIBLE_SIDESTEP] = 0.0  # a light along an axis (cos 90° = 6e-17): none
    return offsets.astype(np.int32), error


def _shadow_array(t: Terrain, grid: texture_kernels.HeightGrid, azimuth: float, altitude: float,
                  device: wp.Device, host: NDArray[np.uint8] | None = None) -> wp.array:
    """The shadow mask on the device (written into ``host`` on the CPU when given, else into a scratch array
    valid until the next call on this thread)."""
    if host is not None:
        out = wp.array(host, dtype=wp.uint8, device=device, copy=False)
    else:
        rows, cols = t.heights.shape
        out = scratch("texture.shadow", rows * cols, wp.uint8, device).reshape((rows, cols))
    if altitude >= math.pi / 2:
        out.zero_()
        return out
    sweep, n_lines, on_nodes = _sweep(t.heights.shape, t.spacing, azimuth, altitude, device)
    bundle = _LINES_PER_THREAD_CPU[sweep.major_j] if device.is_cpu else 1
    if device.is_cpu and sweep.major_j == 1 and grid.heights.strides[0] % 4096 == 0:
        bundle = _LINES_PER_THREAD_CPU_ALIASED_ROWS
    horizons = scratch("texture.horizons", n_lines, wp.float32, device)
    kernel = texture_kernels.SWEEP_SHADOWS[sweep.major_j, on_nodes]
    launch(kernel, dim=-(-n_lines // bundle), inputs=[grid, sweep, bundle, horizons],
           outputs=[out], device=device)
    return out


def _shadow_mask(t: Terrain, grid: texture_kernels.HeightGrid, azimuth: float, altitude: float,
                 device: wp.Device) -> NDArray[np.uint8]:
    host = recycled_empty(t.heights.shape, np.uint8) if device.is_cpu else None
    out = _shadow_array(t, grid, azimuth, altitude, device, host)
    return host if host is not None else host_copy(out)


def cast_shadows(
    terrain: Terrain | ArrayLike,
    *,
    azimuth: float = DEFAULT_AZIMUTH,
    altitude: float = DEFAULT_ALTITUDE,
    z_factor: float = 1.0,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> NDArray[np.uint8]:
    """Self-shadowing of a heightfield by a directional light (paper 004 §7.2, Fig. 5).

    Parameters
    ----------
    terrain, azimuth, altitude, z_factor, spacing, device
        As in :func:`hillshade`.

    Returns
    -------
    (H, W) uint8
        1 where the node is in the terrain's shadow, 0 where it is lit (and at nodata).

    Notes
    -----
    Sweep lines: digital lines parallel to the light's azimuth (along the dominant axis each visits one node
    per row or column; the minor index is ``c + round(slope · (k − (n − 1)/2))``, halves rounded towards 0,
    so the lines partition the grid and are the same nodes whichever way the rows and columns run).
    Each node stands for the point of the straight line (``c + slope · (k − (n − 1)/2)``) at its major index, at
    most half a node sideways: its height interpolated linearly towards the neighbour across the line (beyond the
    border or next to nodata extrapolated from the other neighbour), its t that point's. So a line's points are
    collinear, and a plane lit by the sun casts no shadow on itself: with the nodes' own heights a line stepping a
    node sideways rose by the cross slope of a node there, and bands of a lit slope across the light came out
    shadowed (about 4 % of a real DEM's nodes at 300°, against a bilinear ray march).
    One thread walks a line away from the light keeping the running horizon ``max(z + t·tan(altitude))``
    over the points seen so far (t = distance along the light's horizontal direction); a node is shadowed
    when that maximum exceeds its own value, i.e. when an earlier point of its line rises above the ray from
    its point to the light. O(1) per pixel, one pass; it equals the brute-force ray march from each pixel
    to the light over the points of its line, O(n) per pixel. Altitude 90° casts no shadow.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import cast_shadows
    >>> wall = np.zeros((3, 8), np.float32); wall[:, 2] = 10.0   # a wall west of the middle
    >>> cast_shadows(wall, azimuth=np.radians(270), altitude=np.radians(45), device="cpu")[1].tolist()
    [0, 0, 0, 1, 1, 1, 1, 1]
    """
    t = _grid_terrain(terrain, spacing)
    _check_nodes(t, _NODE_BYTES["cast_shadows"], "the shadow mask")
    azimuth, altitude = _light(azimuth, altitude)
    z_factor = _finite(z_factor, "z_factor", positive=True)
    dev = resolve_device(device)
    return _shadow_mask(t, _height_grid(t, z_factor, dev), azimuth, altitude, dev)


def ambient_occlusion(
    terrain: Terrain | ArrayLike,
    *,
    directions: int = 16,
    z_factor: float = 1.0,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> NDArray[np.float32]:
    """Horizon-based ambient occlusion: 1 − the mean of sin(horizon angle) over ``directions`` azimuths.

    Returns
    -------
    (H, W) float32
        1 on open ground (a plane, a peak), less in valleys and pits; NaN at nodata.

    Notes
    -----
    For each azimuth every sweep line is walked away from that direction keeping the upper convex hull of the
    nodes it has passed (a stack, amortised O(1) per node): the hull's last point is the node's horizon towards
    the azimuth. Each node is taken sideways onto its straight line first, as :func:`cast_shadows` takes it, so a
    plane's horizon is its rise that way at every node (the nodes' own heights, zig-zagging a node sideways, raised
    the horizons of a plane sloping across a direction: 0.69-0.73 for 0.7425 on a 45° slope). The stacks take one
    slot per node, allocated by count -> scan
    (``_compaction.exclusive_offsets``). Cost: O(directions · pixels). A CUDA thread walks one line; a CPU thread
    a bundle of adjacent lines in lockstep (neighbouring nodes one after another; the same values): 2048², 16
    directions, 0.81-0.86 s on one core, 1.85 s one line at a time. The lines are anchored at the grid's middle
    and rounded symmetrically (:func:`_digital_lines`), so one terrain gives the same occlusion laid out north-up
    (dy < 0) or south-up, with its columns either way; a mirrored terrain gives the mirror image where the
    directions are symmetric under that mirror (rows reversed, dy kept: an even count; transposed: a multiple of 4;
    :func:`compass` makes their vectors exact mirror images).

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import ambient_occlusion
    >>> bool(np.allclose(ambient_occlusion(np.zeros((6, 6)), directions=4, device="cpu"), 1.0))
    True
    """
    t = _grid_terrain(terrain, spacing)
    _check_nodes(t, _NODE_BYTES["ambient_occlusion"], "the ambient occlusion")
    if (isinstance(directions, bool) or not isinstance(directions, (int, np.integer))
            or not 1 <= directions <= MAX_OCCLUSION_DIRECTIONS):  # one sweep of launches per direction
        raise InvalidInputError(f"directions must be an int in [1, {MAX_OCCLUSION_DIRECTIONS}]; got {directions!r}")
    z_factor = _finite(z_factor, "z_factor", positive=True)
    dev = resolve_device(device)
    grid = _height_grid(t, z_factor, dev)
    # the sweep's float32 world units scaled by a power of two (exact) to a grid about 1 wide and high: tiny or huge
    # terrains (spacing 1e-23 m, heights 1e21 m) under- or overflowed rise² + run² (an occlusion of −inf, valleys
    # open) and the hull's cross products; the occlusion depends only on the shape
    scale = _unit_scale(t, z_factor)
    if scale != 1.0:
        grid.spacing = wp.vec2(float(t.spacing[0]) * scale, float(t.spacing[1]) * scale)
        grid.z_factor = float(z_factor) * scale
    host, occlusion = _output(t.heights.shape, np.float32, wp.float32, dev, zero=True)
    hull = scratch("texture.hull", t.heights.size, wp.vec2, dev)
    weight = 1.0 / int(directions)
    for k in range(int(directions)):  # one pass per direction (a handful), never per pixel
        sweep, n_lines, on_nodes = _sweep(t.heights.shape, t.spacing, compass(k, int(directions)), math.radians(45.0),
                                          dev)
        counts = count_buffer("texture.lines", n_lines, dev)
        launch(texture_kernels.count_line_nodes, dim=n_lines, inputs=[sweep], outputs=[counts], device=dev)
        offsets, _total = exclusive_offsets(counts, name="texture.lines")
        bundle = _OCCLUSION_LINES_PER_THREAD_CPU[sweep.major_j] if dev.is_cpu else 1
        tops = scratch("texture.tops", n_lines, wp.int32, dev)
        kernel = texture_kernels.SWEEP_OCCLUSION[sweep.major_j, on_nodes]
        launch(kernel, dim=-(-n_lines // bundle),
               inputs=[grid, sweep, bundle, offsets, weight, tops], outputs=[hull, occlusion], device=dev)
    ao = _result(host, occlusion)  # float32, the caller's: 1 - occlusion in place
    np.subtract(np.float32(1.0), ao, out=ao)
    ao[t.nodata_mask] = np.nan
    return ao


def normal_map(
    terrain: Terrain | ArrayLike,
    *,
    z_factor: float = 1.0,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> NDArray[np.uint8]:
    """Surface normals encoded as an RGB texture (paper 004 §7.4): ``round(n · 127.5 + 127.5)``, from the Horn
    gradient :func:`hillshade` shades (its border too), so :func:`relight` reproduces the hillshade.

    Parameters
    ----------
    terrain : Terrain or (H, W) array_like
    z_factor : float
        Vertical exaggeration of the heights (default 1), as :func:`hillshade` takes it.
    spacing : (dx, dy), optional
        Node spacing of an array ``terrain`` (default (1, 1)); refused with a Terrain, which brings its own.
    device : warp device, optional

    Returns
    -------
    (H, W, 3) uint8
        x (east), y (north), z (up) of the unit normal of each node; nodata encodes (0, 0, 1).

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import normal_map
    >>> normal_map(np.zeros((2, 2)), device="cpu")[0, 0].tolist()
    [128, 128, 255]
    """
    t = _grid_terrain(terrain, spacing)
    _check_nodes(t, _NODE_BYTES["normal_map"], "the normal map")
    z_factor = _finite(z_factor, "z_factor", positive=True)
    dev = resolve_device(device)
    grid = _height_grid(t, z_factor, dev)
    host, out = _output((*t.heights.shape, 3), np.uint8, wp.uint8, dev)
    launch(texture_kernels.encode_normals, dim=grid.rows * grid.cols, inputs=[grid], outputs=[out], device=dev)
    return _result(host, out)


def relight(
    normals: ArrayLike,
    *,
    azimuth: float | None = None,
    altitude: float | None = None,
    point: ArrayLike | None = None,
    terrain: Terrain | ArrayLike | None = None,
    z_factor: float = 1.0,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> NDArray[np.float32]:
    """Shade an RGB normal texture (:func:`normal_map`) by a new light without recomputing it (§7.4, Fig. 7).

    Parameters
    ----------
    normals : (H, W, 3) uint8
        The encoded normals.
    azimuth, altitude : float
        A directional light (radians), or
    point : (x, y, z)
        a point light in the terrain's world coordinates, z in the heights' units; needs ``terrain`` (the surface
        positions). With ``z_factor`` the scene is exaggerated as a whole: the surface (heights × z_factor, whose
        normals :func:`normal_map` encoded) and the light (z × z_factor), so a light 50 m above the ground stays
        50 m × z_factor above it.
    terrain, z_factor, spacing
        For a point light, the surface as given to :func:`normal_map`; ``z_factor`` must be a positive number
        with either light. ``terrain`` and ``spacing`` given with a directional light are refused (they would
        have no effect).
    device : warp device, optional

    Returns
    -------
    (H, W) float32
        ``max(0, n · l)`` per texel.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import normal_map, relight
    >>> rgb = normal_map(np.zeros((3, 3)), device="cpu")
    >>> round(float(relight(rgb, azimuth=0.0, altitude=np.pi / 2, device="cpu")[1, 1]), 3)
    1.0
    """
    rgb = as_array(normals, "normals", "an (H, W, 3) uint8 RGB texture")
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise InvalidInputError(f"normals must be an (H, W, 3) uint8 RGB texture; got {rgb.dtype} {rgb.shape}")
    z_factor = _finite(z_factor, "z_factor", positive=True)  # checked for a directional light too: text passed unread
    dev = resolve_device(device)
    host, out = _output(rgb.shape[:2], np.float32, wp.float32, dev)
    texels = wp.array(np.ascontiguousarray(rgb), dtype=wp.uint8, device=dev)
    if point is None:
        if azimuth is None or altitude is None:
            raise InvalidInputError("relight needs a directional light (azimuth and altitude) or a point light")
        unread = [name for name, value in (("terrain", terrain), ("spacing", spacing)) if value is not None]
        if unread:  # they were ignored: a caller who meant a point light got a directional shading without a word
            raise InvalidInputError(f"{' and '.join(unread)} appl{'y' if len(unread) > 1 else 'ies'} to a point "
                                    "light only (a directional light shades the normals alone); got "
                                    f"{' and '.join(unread)} with azimuth and altitude")
        azimuth, altitude = _light(azimuth, altitude)
        light = wp.vec3(math.sin(azimuth) * math.cos(altitude), math.cos(azimuth) * math.cos(altitude),
                        math.sin(altitude))
        launch(texture_kernels.relight_directional, dim=rgb.shape[0] * rgb.shape[1], inputs=[texels, light],
               outputs=[out], device=dev)
        return _result(host, out)
    if azimuth is not None or altitude is not None:
        raise InvalidInputError("give either a directional light (azimuth, altitude) or a point light, not both")
    if terrain is None:
        raise InvalidInputError("a point light needs terrain= (the surface positions of the texels)")
    position = real_vector(point, "point", "a finite (x, y, z)", 3)
    t = _grid_terrain(terrain, spacing)
    if t.heights.shape != rgb.shape[:2]:
        raise InvalidInputError(f"normals of shape {rgb.shape[:2]} do not match the terrain's {t.heights.shape} "
                                "nodes (mismatched size); relight the normal map of this terrain")
    grid = _height_grid(t, z_factor, dev)
    # the light is in world units, the surface shaded is the exaggerated one (heights x z_factor, which the normals
    # are of): its z is exaggerated with it, or a lamp 50 m above ground at z_factor 3 lit it from below (black)
    local = (float(position[0] - t.origin[0]), float(position[1] - t.origin[1]), float(position[2]) * z_factor)
    if max(abs(c) for c in local) > _MAX_SLOPE:  # |point - surface|² in float32 overflowed: a black image
        raise InvalidInputError(f"point must lie within {_MAX_SLOPE:g} of the terrain's origin (float32 "
                                f"distances, z x z_factor); got {tuple(float(c) for c in position)}"
                                f"{f' at z_factor {z_factor:g}' if z_factor != 1.0 else ''}")
    local = wp.vec3(*local)
    launch(texture_kernels.relight_point, dim=rgb.shape[0] * rgb.shape[1], inputs=[texels, grid, local],
           outputs=[out], device=dev)
    return _result(host, out)


# ---------------------------------------------------------------------------------------------- §3.2.3 layers
def _affine(extent: Extent, shape: tuple[int, int]) -> NDArray[np.float64]:
    """World (x, y, 1) -> texel (column, row, 1) of a north-up image covering ``extent``, centres at integers."""
    xmin, xmax, ymin, ymax = extent
    rows, cols = shape
    px = (xmax - xmin) / cols
    py = (ymax - ymin) / rows
    return np.array([[1.0 / px, 0.0, -xmin / px - 0.5], [0.0, -1.0 / py, ymax / py - 0.5], [0.0, 0.0, 1.0]])


def _check_extent(extent: Any, name: str = "extent") -> Extent:
    try:
        values = tuple(as_number(v) for v in extent)  # float() took "4" and True
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be (xmin, xmax, ymin, ymax); got {extent!r}") from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values) or values[0] >= values[1] \
            or values[2] >= values[3]:
        raise InvalidInputError(f"{name} must be finite (xmin, xmax, ymin, ymax) with xmin < xmax and "
                                f"ymin < ymax; got {extent!r}")
    return values  # type: ignore[return-value]


def _invertible(matrix: NDArray[np.float64]) -> bool:
    """Whether a finite 3 x 3 matrix has a finite inverse."""
    if not np.isfinite(matrix).all():
        return False
    try:
        with np.errstate(all="ignore"):
            return bool(np.isfinite(np.linalg.inv(matrix)).all())
    except np.linalg.LinAlgError:
        return False


def _masked_pixels(image: Any) -> NDArray[np.bool_] | None:
    """The (h, w) pixels a numpy masked array masks (any of its channels), None for another array or a mask of
    none: those are nodata, as a masked array's masked heights are (``terrain.unmasked``); ``np.asarray`` dropped the
    mask, and the values under it were drawn (an orthophoto read with ``rasterio``'s ``masked=True``: its collar
    opaque black) or refused as out of range (a fill value of 1e20)."""
    if not np.ma.isMaskedArray(image) or np.ma.getmask(image) is np.ma.nomask:
        return None
    mask = np.ma.getmaskarray(image)
    if mask.ndim == 3:
        mask = mask.any(axis=2)
    return mask if mask.any() else None


def _maximum(array: Any) -> float | None:
    """The largest value of ``array``, a masked array's largest unmasked one; None where it masks all."""
    top = array.max()
    return None if top is np.ma.masked else float(top)


def _image_argument(value: Any, name: str, expected: str) -> Any:
    """``value`` as an array for a layer's image: a numpy masked array as it is (its mask the layer's nodata,
    :func:`_masked_pixels`), anything else through ``as_array``."""
    return value if np.ma.isMaskedArray(value) else as_array(value, name, expected)


#: Bytes a pixel of :meth:`TextureLayer.rgba` at its peak: the float32 RGBA, the finite flags of its channels and the
#: nodata mask and its negation.
_RGBA_BYTES = 16 + 4 + 1 + 1

#: Texels of a band of rows :meth:`TextureLayer.to_uint8` composes at once, and the bytes a texel of it takes at its
#: peak: the RGB times alpha, one minus alpha and the background times it (12 + 4 + 12; 16 for RGBA times 255).
_UINT8_BAND_TEXELS = 1 << 14
_UINT8_BAND_BYTES = 12 + 4 + 12


@dataclass(frozen=True, eq=False)
class TextureLayer:
    """One texture layer (paper 004 §3.2.3): an image over a georeferenced extent, and its texture matrix.

    ``kind``: "thematic" (RGB or RGBA colour), "luminance" (one channel of brightness), "topographic"
    (shading, a luminance layer computed from the terrain, §7) or "visibility" (one channel of alpha, §5).
    ``image``: (h, w, 3|4) for thematic, (h, w) otherwise; uint8 (0-255) or float in [0, 1], NaN for nodata (a
    transparent pixel; a numpy masked array's masked pixels too, whatever values lie under the mask); row 0 is the
    north edge (ymax), column 0 the west edge; it is kept as given (a numpy memmap stays on disk), and its RGBA is
    cached only when the array is read-only (and not masked), so in-place edits show.
    ``extent``: (xmin, xmax, ymin, ymax) in world units, the outer edges of the pixels. ``matrix``: the 3 × 3
    texture matrix taking world (x, y, 1) to texel (column, row, 1) (affine: last row (0, 0, 1); texel centres at
    integers); ``None`` derives it from the extent. Moving a layer (a lens) changes only the matrix
    (:meth:`moved`). ``border``: what lies outside the image: "transparent" (partial coverage, §4) or "edge" (the
    edge texels repeat).
    """

    kind: LayerKind
    image: Any
    extent: Extent
    matrix: NDArray[np.float64] | None = None
    border: Literal["transparent", "edge"] = "transparent"
    name: str = ""
    _rgba_cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not _is_name(self.kind, LAYER_KINDS):
            raise InvalidInputError(f"layer kind must be one of {', '.join(LAYER_KINDS)}; got {self.kind!r}")
        image = self.image
        if not isinstance(image, np.ndarray):
            try:
                image = np.asarray(image)
            except ValueError:  # ragged rows
                raise InvalidInputError(f"{self.kind} layer image must be an array; got rows of different "
                                        "lengths") from None
            object.__setattr__(self, "image", image)
        if image.dtype != np.uint8 and not np.issubdtype(image.dtype, np.floating):
            raise InvalidInputError(f"{self.kind} layer image must be uint8 or float; got dtype {image.dtype}")
        if self.kind == "thematic":
            if image.ndim != 3 or image.shape[2] not in (3, 4):
                raise InvalidInputError(f"a thematic layer needs an (h, w, 3) RGB or (h, w, 4) RGBA image; "
                                        f"got shape {image.shape}")
        elif image.ndim != 2:
            raise InvalidInputError(f"a {self.kind} layer needs a one-channel (h, w) image; got shape {image.shape}")
        if image.shape[0] < 1 or image.shape[1] < 1:
            raise InvalidInputError(f"layer image must not be empty; got shape {image.shape}")
        object.__setattr__(self, "extent", _check_extent(self.extent))
        if self.matrix is None:
            matrix = _affine(self.extent, self.shape)
            if not _invertible(matrix):  # pixels too narrow (1 / width overflows) or too wide (it rounds to 0)
                raise InvalidInputError(f"extent {self.extent} over {self.shape[1]} x {self.shape[0]} pixels gives "
                                        "no finite, invertible texture matrix (world -> texel) in float64")
        else:
            # np.asarray(matrix, dtype=float) read "1" and True as 1.0, dropped an imaginary part and a mask
            matrix = real_numbers(self.matrix, "matrix", "a finite 3 x 3 texture matrix")
            if matrix.shape != (3, 3) or not np.isfinite(matrix).all():
                raise InvalidInputError(f"matrix must be a finite 3 x 3 texture matrix; got {self.matrix!r}")
            if not _invertible(matrix):  # blend, weighted_add, ... invert it (texel -> world): a LinAlgError
                raise InvalidInputError(f"matrix must be an invertible 3 x 3 texture matrix (world -> texel); got "
                                        f"{matrix.tolist()}")
            if not np.array_equal(matrix[2], (0.0, 0.0, 1.0)):
                # the kernels, texture_uv and the coverage test read texel (column, row) as its first two rows and
                # never divide by the third: 2 * M (the same map in homogeneous coordinates) sampled texels twice as
                # far, a perspective row was dropped, both silently
                raise InvalidInputError(f"matrix must be an affine texture matrix, its last row (0, 0, 1) (world (x, "
                                        f"y, 1) -> texel (column, row, 1)); got last row {matrix[2].tolist()}")
        object.__setattr__(self, "matrix", matrix)
        if not _is_name(self.border, ("transparent", "edge")):
            raise InvalidInputError(f"border must be 'transparent' or 'edge'; got {self.border!r}")
        if not isinstance(self.name, str):  # 5 or None was kept as the name (and as a draped material's)
            raise InvalidInputError(f"name must be a string; got {self.name!r}")

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w) of the image."""
        return int(self.image.shape[0]), int(self.image.shape[1])

    @property
    def pixel_size(self) -> tuple[float, float]:
        """(width, height) of a pixel in world units."""
        xmin, xmax, ymin, ymax = self.extent
        return (xmax - xmin) / self.shape[1], (ymax - ymin) / self.shape[0]

    def moved(self, dx: float, dy: float) -> TextureLayer:
        """The same layer shifted by (dx, dy) world units: a new texture matrix, the same image object (§5)."""
        dx = _finite(dx, "dx")
        dy = _finite(dy, "dy")
        shift = np.array([[1.0, 0.0, -dx], [0.0, 1.0, -dy], [0.0, 0.0, 1.0]])
        return replace(self, matrix=self.matrix @ shift, _rgba_cache={})

    def rgba(self) -> NDArray[np.float32]:
        """The image as (h, w, 4) float32 RGBA in [0, 1] (luminance: grey, opaque; visibility: white, alpha).

        Its 16 bytes per pixel (22 with the masks made while it is checked) are checked against the memory budget
        (:func:`stepterrain.set_memory_budget`) before anything is allocated: an
        :class:`~stepterrain.errors.OutputTooLargeError` (a memory-mapped gigapixel image ran out of memory instead)."""
        cached = self._rgba_cache.get("rgba")
        if cached is not None:
            return cached
        h, w = self.shape
        # the RGBA and, while it is checked, the per-channel finite flags and the per-pixel nodata mask
        check_budget(_RGBA_BYTES * h * w, f"the (h, w, 4) float32 RGBA of a {w} x {h} {self.kind} layer",
                     hint="crop or downsample the image (texture_lod.ImagePyramid serves a large one by level)")
        image = np.asarray(self.image)  # a masked array's values; its masked pixels are nodata below
        masked = _masked_pixels(self.image)
        out = np.ones((*self.shape, 4), dtype=np.float32)
        # the image goes straight into its channels, scaled there: a float32 copy of it and its scaled copy (12 + 12
        # bytes a pixel of RGB) were made first, and the finite pixels were copied out for their range (16 more), so
        # a layer checked as 16 bytes a pixel took 62
        if self.kind == "thematic":
            channels = out[..., : image.shape[2]]
            channels[...] = image
        elif self.kind == "visibility":
            channels = out[..., 3]
            channels[...] = image
        else:
            channels = out[..., :3]
            channels[...] = image[..., None]
        if image.dtype == np.uint8:
            channels /= np.float32(255.0)
        nodata = ~np.isfinite(out).all(axis=2)
        if masked is not None:
            nodata |= masked
        if nodata.any():
            # NaN is nodata, as in heights; an infinite value was taken for nodata too: a weight of inf left the
            # other layer as it was, an inf colour turned transparent
            infinite = np.isinf(out).any(axis=2)
            if masked is not None:  # whatever lies under the mask is no value of the layer
                infinite &= ~masked
            if infinite.any():
                first = tuple(int(k) for k in np.argwhere(infinite)[0])
                raise InvalidInputError(f"{self.kind} layer values must be finite or NaN (nodata); got an infinite "
                                        f"value at pixel {first}")
            out[nodata] = (1.0, 1.0, 1.0, 0.0)
        valid = ~nodata[..., None]  # the range of the pixels with data, read in place (no copy of them)
        lo = float(np.min(out, where=valid, initial=np.inf))
        hi = float(np.max(out, where=valid, initial=-np.inf))
        if lo < -1e-6 or hi > 1.0 + 1e-6:
            raise InvalidInputError(f"{self.kind} layer values must lie in [0, 1] (or uint8 0-255); got "
                                    f"[{lo:g}, {hi:g}]")
        np.clip(out, 0.0, 1.0, out=out)
        if not image.flags.writeable and not np.ma.isMaskedArray(self.image):  # a writeable image (kept as given), or
            # a masked array's mask, may change later: never cached
            out.setflags(write=False)  # handed out again and wrapped for the kernels: an edit would change them all
            self._rgba_cache["rgba"] = out
        return out

    def to_uint8(self, background: Sequence[float] | None = None) -> NDArray[np.uint8]:
        """The layer as uint8 RGBA, or RGB composited over ``background`` (r, g, b in [0, 1])."""
        if background is not None:
            try:  # real_numbers: np.asarray(..., float) took ("1", "0", "0") and (True, 0, 0) as numbers
                bg = real_numbers(background, "background", "(r, g, b) in [0, 1]").reshape(-1)
            except InvalidInputError:
                bg = np.full(0, np.nan)
            if bg.shape != (3,) or not (np.isfinite(bg).all() and (bg >= 0).all() and (bg <= 1).all()):
                raise InvalidInputError(f"background must be (r, g, b) in [0, 1]; got {background!r}")
        h, w = self.shape
        channels = 4 if background is None else 3
        band = max(1, _UINT8_BAND_TEXELS // max(w, 1))  # rows composed at once
        # what it keeps (the RGBA unless made already, the uint8 image) and a band's temporaries: composed whole, the
        # temporaries of the formula (12 to 16 bytes a texel each) took 54 bytes a texel of a layer checked as 22
        check_budget(_rgba_bytes(self) + channels * h * w + _UINT8_BAND_BYTES * min(band, h) * w,
                     f"the {w} x {h} uint8 {'RGBA' if background is None else 'RGB'} image of a {self.kind} layer",
                     hint="crop or downsample the image (texture_lod.ImagePyramid serves a large one by level)")
        rgba = self.rgba()
        out = np.empty((h, w, channels), dtype=np.uint8)
        if background is not None:
            bg = bg.astype(np.float32).reshape(1, 1, 3)
        for r0 in range(0, h, band):  # the one-pass formula's operations in its order, on a band of rows at a time
            part = rgba[r0 : r0 + band]
            if background is None:
                value = part * 255.0
            else:
                value = part[..., :3] * part[..., 3:]
                value += bg * (1.0 - part[..., 3:])
                np.clip(value, 0.0, 1.0, out=value)
                value *= 255.0
            np.round(value, out=value)
            out[r0 : r0 + band] = value  # the cast to uint8, as astype
        return out

    @property
    def frame(self) -> tuple[Extent, tuple[int, int]]:
        """(extent, shape): the layer's extent and image shape, the pixel grid results of operations on it (as their
        first layer) are computed on; those on a layer :meth:`moved` lie where its texels moved to (a north-up,
        axis-aligned texture matrix; a rotated, sheared or mirrored one is resampled onto this extent)."""
        return self.extent, self.shape


def terrain_extent(terrain: Terrain) -> Extent:
    """Image extent of a grid terrain with pixel-centre registration: the node extent plus half a cell."""
    xmin, xmax, ymin, ymax = terrain.extent
    hx, hy = abs(terrain.spacing[0]) / 2, abs(terrain.spacing[1]) / 2
    return xmin - hx, xmax + hx, ymin - hy, ymax + hy


def _north_up(terrain: Terrain, image: NDArray[Any]) -> NDArray[Any]:
    """A grid-ordered image (pixel (i, j) = node (i, j)) turned so row 0 is north and column 0 west."""
    if terrain.spacing[1] > 0:
        image = image[::-1]
    if terrain.spacing[0] < 0:
        image = image[:, ::-1]
    if np.ma.isMaskedArray(image):  # np.ascontiguousarray dropped the mask (the layer's nodata)
        return image.copy()
    return np.ascontiguousarray(image)


def terrain_layer(terrain: Terrain | ArrayLike, image: ArrayLike, kind: LayerKind = "thematic", *,
                  spacing: ArrayLike | None = None, name: str = "") -> TextureLayer:
    """A layer whose pixel (i, j) belongs to grid node (i, j) of ``terrain`` (same size, turned north-up).

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import terrain_layer
    >>> layer = terrain_layer(np.zeros((2, 3)), np.ones((2, 3)), "luminance")
    >>> layer.extent
    (-0.5, 2.5, -0.5, 1.5)
    """
    t = _grid_terrain(terrain, spacing)
    array = _image_argument(image, "image", "an (H, W) or (H, W, C) array on the terrain's nodes")
    if array.shape[:2] != t.heights.shape:
        raise InvalidInputError(f"image of shape {array.shape[:2]} does not match the terrain's "
                                f"{t.heights.shape} nodes (mismatched size)")
    return TextureLayer(kind, _north_up(t, array), terrain_extent(t), name=name)


def _unshaded(t: Terrain, azimuth: float | None, altitude: float | None, z_factor: float, shadows: bool,
              shadow_strength: float | None, device: wp.DeviceLike) -> NDArray[np.float32]:
    """:func:`topographic_layer`'s shade for ``method="none"``: 1 at every node (NaN at nodata), times
    ``1 − shadow_strength`` where :func:`cast_shadows` shadows it; the light is refused without shadows (it aims
    them only), as :func:`hillshade` refuses an angle its method ignores."""
    if not shadows:
        for name, value in (("azimuth", azimuth), ("altitude", altitude)):
            if value is not None:
                raise InvalidInputError(f"{name} has no effect on method='none' (no light shades the terrain); it "
                                        f"aims shadows=True only; got {name}={value!r} without shadows")
    if shadow_strength is not None and not shadows:  # as hillshade refuses it
        raise InvalidInputError(f"shadow_strength applies only with shadows=True (it darkens the shadowed pixels); "
                                f"got shadow_strength={shadow_strength!r} with shadows=False")
    shade = np.where(t.nodata_mask, np.float32(np.nan), np.float32(1.0)) if t.has_nodata else \
        np.ones(t.heights.shape, np.float32)
    if shadows:
        strength = _finite(shadow_strength, "shadow_strength", lo=0.0, hi=1.0)
        shadow = cast_shadows(t, azimuth=DEFAULT_AZIMUTH if azimuth is None else azimuth,
                              altitude=DEFAULT_ALTITUDE if altitude is None else altitude, z_factor=z_factor,
                              device=device)
        shade = shade * (1.0 - np.float32(strength) * shadow)
    else:
        _finite(z_factor, "z_factor", positive=True)  # checked as the hillshade checks it
    return shade


def topographic_layer(
    terrain: Terrain | ArrayLike,
    *,
    azimuth: float | None = None,
    altitude: float | None = None,
    z_factor: float = 1.0,
    method: Literal["standard", "multidirectional", "combined", "igor", "none"] = "standard",
    shadows: bool = True,
    shadow_strength: float | None = None,
    occlusion: float = 0.0,
    ambient: float = DEFAULT_AMBIENT,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> TextureLayer:
    """A topographic texture layer (§7): hillshade, self-shadowing and optional ambient occlusion.

    The luminance is ``ambient + (1 − ambient) · shade``; ``shadows`` (default True: self-shadowing on, unlike the
    CLI's opt-in ``texture --shadows``) darken by ``shadow_strength`` (default 0.6;
    refused with ``shadows=False``, where it would have no effect) and ``occlusion`` in [0, 1] mixes in
    horizon-based ambient occlusion (``1 − occlusion · (1 − ao)``). ``method`` is one of :data:`HILLSHADE_METHODS`
    (gdaldem's grey variants, as in :func:`hillshade`, which refuses the angles they ignore likewise), not a
    MapLibre method; ``azimuth`` and ``altitude`` default to GDAL's 315° and 45° (radians). ``method="none"``
    leaves the hillshade out: a shade of 1 at every node (NaN at nodata), so the layer is 1 where nothing darkens it,
    darkened by the shadows and the occlusion alone (the CLI's ``--hillshade none``); the light then aims the shadows
    only, and an azimuth or altitude without ``shadows`` is refused. Modulate a thematic layer with it
    (:func:`modulate`) as in Fig. 5.
    """
    t = _grid_terrain(terrain, spacing)
    shadows = check_flag(shadows, "shadows")
    if shadows and shadow_strength is None:
        shadow_strength = 0.6
    if _is_name(method, MAPLIBRE_METHODS):
        raise InvalidInputError(f"a topographic layer takes a grey method ({', '.join(HILLSHADE_METHODS)}); got "
                                f"{method!r}: its premultiplied RGBA overlay, with RGB divided by alpha, makes a "
                                "thematic layer")
    if not _is_name(method, (*HILLSHADE_METHODS, "none")):  # hillshade's refusal listed its MapLibre methods, not none
        raise InvalidInputError(f"method must be one of {', '.join(HILLSHADE_METHODS)} or none (no hillshade: the "
                                f"shadows and occlusion alone); got {method!r}")
    ambient = _finite(ambient, "ambient", lo=0.0, hi=1.0)
    occlusion = _finite(occlusion, "occlusion", lo=0.0, hi=1.0)
    _check_topographic(t, occlusion > 0)
    if _is_name(method, ("none",)):
        shade = _unshaded(t, azimuth, altitude, z_factor, shadows, shadow_strength, device)
    else:
        shade = hillshade(t, azimuth=azimuth, altitude=altitude, z_factor=z_factor, method=method, shadows=shadows,
                          shadow_strength=shadow_strength, device=device)
    luminance = ambient + (1.0 - ambient) * shade
    if occlusion > 0:
        ao = ambient_occlusion(t, z_factor=z_factor, device=device)
        luminance = luminance * (1.0 - occlusion * (1.0 - ao))
    return TextureLayer("topographic", _north_up(t, luminance.astype(np.float32)), terrain_extent(t),
                        name="topographic")


#: The colour of :func:`contour_layer`'s lines: a topographic map's contour brown.
CONTOUR_COLOR = (0.55, 0.32, 0.14)


#: Texels of a row one contour_layer thread draws on the CPU, sliding the heights along (amortises the per-thread
#: cost; on CUDA a thread draws one texel).
CONTOUR_RUN = 64


#: Bytes per texel of :func:`contour_layer`'s float32 RGBA (``stepterrain texture --contours`` counts it too).
_CONTOUR_TEXEL_BYTES = 16


def _coarser_than_nodes(t: Terrain, texel_size: float) -> float | None:
    """The smaller node spacing of the grid terrain ``t`` where ``texel_size`` exceeds it (beyond a part in 10^9: a
    texel size makes a texture finer, never coarser, either way), else None."""
    node = min(abs(float(t.spacing[0])), abs(float(t.spacing[1])))
    return node if texel_size > node * (1.0 + 1e-9) else None


def _texel_grid(t: Terrain, texel_size: float, name: str = "texel_size") -> tuple[Extent, tuple[int, int]]:
    """The pixel grid of a texture of ``texel_size`` texels over a grid terrain: its texture extent (the node extent
    plus half a cell, :func:`terrain_extent`) cut into whole texels no larger than ``texel_size`` (a size within a
    part in 10^9 of dividing it exactly divides it: 10 over a 30 m grid is three texels a cell), as
    (extent, (rows, cols)). A size so small that the texels of a side overflow float64 is refused naming ``name``
    (math.ceil raised an OverflowError: a traceback from ``stepterrain texture --texel-size 1e-320``)."""
    extent = terrain_extent(t)
    width, height = extent[1] - extent[0], extent[3] - extent[2]
    counts = [span / texel_size * (1.0 - 1e-9) for span in (width, height)]
    if not all(math.isfinite(n) for n in counts):
        raise InvalidInputError(f"{name} must be a positive size that cuts the terrain's {width:g} x {height:g} "
                                f"texture extent into a finite number of texels; got {texel_size:g}")
    cols, rows = (max(1, math.ceil(n)) for n in counts)
    return extent, (rows, cols)


def _texels(count: int) -> str:
    """A texel count as an error names it: its digits, or past 10^12 (a texel size of 1e-300 makes 300-digit counts,
    an error line of 950 characters) in floating point, ``5e+301``."""
    return str(count) if count < 10**12 else f"{float(count):.4g}"


def _texel_sampling(t: Terrain, extent: Extent, shape: tuple[int, int]) -> texture_kernels.TexelSampling:
    """Where the texel centres of the north-up pixel grid (extent, shape) fall among the terrain's nodes."""
    rows, cols = shape
    sampling = texture_kernels.TexelSampling()
    sampling.rows, sampling.cols = rows, cols
    (dx, dy), (ox, oy) = t.spacing, t.origin
    if shape == t.heights.shape and extent == terrain_extent(t):  # one texel per node: exactly on the nodes
        start = (0.0 if dx > 0 else cols - 1.0, rows - 1.0 if dy > 0 else 0.0)
        step = (1.0 if dx > 0 else -1.0, -1.0 if dy > 0 else 1.0)
    else:
        xmin, xmax, ymin, ymax = extent
        px, py = (xmax - xmin) / cols, (ymax - ymin) / rows
        start = ((xmin + px / 2 - ox) / dx, (ymax - py / 2 - oy) / dy)
        step = (px / dx, -py / dy)
    sampling.start = wp.vec2(*start)
    sampling.step = wp.vec2(*step)
    return sampling


def _contour_levels(interval: Any, levels: Any, base: Any) -> tuple[NDArray[np.float64], float, float]:
    """(explicit levels, base, interval): exactly one of ``interval`` (> 0) and ``levels`` (strictly increasing)."""
    one_of_interval_or_levels(interval, levels, "contour levels base + k * interval")
    if levels is None:
        return np.zeros(0, np.float64), _finite(base, "base"), _finite(interval, "interval", positive=True)
    values = given_levels(levels, base, "contour levels base + k * interval", "a sequence of contour heights",
                          "contour height")
    bad = np.flatnonzero(values[1:] <= values[:-1])
    if bad.size:
        i = int(bad[0]) + 1
        raise InvalidInputError(f"levels must be strictly increasing; got levels[{i - 1}]={values[i - 1]!r} and "
                                f"levels[{i}]={values[i]!r}")
    return np.ascontiguousarray(values), 0.0, 1.0


def _contour_colour(value: Any, name: str) -> tuple[float, float, float, float]:
    """A straight RGBA colour from RGB or RGBA in [0, 1], the error naming ``name``."""
    try:
        c = real_numbers(value, name, "an RGB or RGBA colour of numbers in [0, 1]").reshape(-1)
    except InvalidInputError:
        c = np.full(0, np.nan)
    if c.shape not in ((3,), (4,)) or not np.isfinite(c).all() or c.min() < 0 or c.max() > 1:
        raise InvalidInputError(f"{name} must be an RGB or RGBA colour of numbers in [0, 1]; got {value!r}")
    return tuple(float(v) for v in (c if c.size == 4 else np.append(c, 1.0)))  # type: ignore[return-value]


def contour_layer(
    terrain: Terrain | ArrayLike,
    *,
    interval: float | None = None,
    levels: ArrayLike | None = None,
    base: float = 0.0,
    width: float = 1.0,
    color: ArrayLike = CONTOUR_COLOR,
    index_every: int = 5,
    index_width: float | None = None,
    index_color: ArrayLike | None = None,
    texel_size: float | None = None,
    spacing: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> TextureLayer:
    """Contour lines as a thematic RGBA layer, its alpha the lines' coverage: lay it over other layers with
    :func:`blend` (``blend(texture, contours)``), drape it like any layer.

    Each texel samples the terrain's height at its centre, as the other layers place their texels (one texel per
    grid node by default, pixel (i, j) = node (i, j) turned north-up; with ``texel_size``, the bilinear
    interpolant at the centres of a finer grid), and its height's change per texel from the neighbouring texels
    (central differences; one-sided beside nodata and the border). A level passing ``d = |h - level| / |∇h|``
    texels away (the first-order distance) draws an anti-aliased line: alpha is the part of the texel a straight
    line ``width`` texels wide covers, > 0.5 exactly where d < width / 2 (lines at least one texel wide), 1 within
    (width - 1) / 2. Flat ground (∇h = 0) draws a line only exactly on a level (a plateau at a level is all line).
    Where several levels pass within a texel (slopes steeper than an interval per texel) the lines merge.

    Parameters
    ----------
    terrain : Terrain or (H, W) array_like
        Heights (NaN = nodata: no lines there, alpha 0, and none drawn towards it from its neighbours' NaN); a raw
        array takes ``spacing`` (dx, dy), default (1, 1).
    interval, levels : float or sequence of float
        Exactly one: the contour interval (levels ``base + k * interval``, every k) or explicit strictly increasing
        contour heights. For lines on a stepped mesh's walls, draw the thresholds its heights split at:
        ``levels=st.stepped.thresholds_of(st.isovalues(terrain.finite_height_range, interval=100.0))``
        (lines at ``base + k * interval`` lie in the middle of its terraces, on the continuous heightfield's
        contours).
    base : float
        With ``interval``: the height of line 0 (an index line).
    width : float
        Line width in texels, > 0 (thinner than a texel: fainter, alpha at most ``width``).
    color : RGB or RGBA in [0, 1]
        The lines' colour (straight alpha; an alpha < 1 scales the coverage). Default :data:`CONTOUR_COLOR`.
    index_every : int
        Every ``index_every``-th line (k divisible by it: ``base`` and every ``index_every * interval`` from it;
        with ``levels``, its positions 0, n, 2n, ...) is an index contour, drawn ``index_width`` wide in
        ``index_color``, as topographic maps draw them; 0 for none.
    index_width : float, optional
        Index lines' width in texels (default twice ``width``).
    index_color : RGB or RGBA in [0, 1], optional
        Index lines' colour (default ``color``, darker by 30%).
    texel_size : float, optional
        World units per texel (as ``stepterrain texture --texel-size``): the terrain's texture extent cut into whole
        texels no larger than it, no larger than the node spacing; default one texel per node. The heights are
        the bilinear interpolant's (nodata corners left out, their weight fading the alpha); in the half cell beyond
        the outer nodes, the edge's, as the other layers are sampled there.
    spacing : (dx, dy), optional
        Node spacing of an array ``terrain`` (default (1, 1)); refused with a Terrain, which brings its own.
    device : warp device, optional

    Returns
    -------
    TextureLayer
        ``thematic`` (h, w, 4) float32 straight RGBA over :func:`terrain_extent`, transparent between lines.

    Raises
    ------
    InvalidInputError
        Both or neither of ``interval`` and ``levels``; a non-positive or non-finite interval, width or
        index_width; levels empty, non-finite or not strictly increasing; ``base`` with ``levels``; a colour not
        RGB(A) in [0, 1]; ``index_every`` not a whole number >= 0; a texel_size not positive or larger than the
        node spacing; a terrain that is not a regular heightfield.
    OutputTooLargeError
        The float32 RGBA (16 bytes a texel) over the memory budget.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import contour_layer
    >>> ramp = np.tile(np.arange(8.0, dtype=np.float32), (3, 1))   # height = column
    >>> layer = contour_layer(ramp, interval=4.0, index_every=0, device="cpu")
    >>> layer.image[1, :, 3].round(2).tolist()
    [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    """
    t = _grid_terrain(terrain, spacing)
    values, base, interval = _contour_levels(interval, levels, base)
    width = _finite(width, "width", positive=True)
    index_width = 2.0 * width if index_width is None else _finite(index_width, "index_width", positive=True)
    rgba = _contour_colour(color, "color")
    index_rgba = (*(0.7 * c for c in rgba[:3]), rgba[3]) if index_color is None else \
        _contour_colour(index_color, "index_color")
    if isinstance(index_every, (bool, np.bool_)) or not isinstance(index_every, (int, np.integer)) or index_every < 0:
        raise InvalidInputError(
            f"index_every must be a whole number >= 0 (0: no index lines); got {plain_repr(index_every)}")
    if index_every > np.iinfo(np.int32).max:
        raise InvalidInputError(f"index_every must be below 2**31; got {plain_repr(index_every)}")
    if values.size == 0 and abs(base) > interval * 2.0**29:
        # the same levels and index lines from a base a whole number of periods (interval, times index_every with
        # index lines) nearer 0: the kernel's (h - base) / interval lost the heights' fraction of an interval to a
        # base far from them (1e17 over 100 m drew lines anywhere, 1e20 made every texel a line). Reduced exactly
        # (math.fmod by interval * index_every rounded in float64 moved every level by up to ulp(base): 0.85 of an
        # interval of 7.3 at 1e17), rounded once. A base within 2^29 intervals is used as given ((h - base) /
        # interval resolves 2^-24 of an interval there, as fine as the float32 line distance): the reduced one's
        # rounding put a height exactly on a level just below it, another line drawn (the same texels as before)
        period = Fraction(interval) * (int(index_every) if index_every > 0 else 1)
        base = float(Fraction(base) - math.trunc(Fraction(base) / period) * period)
    if texel_size is None:
        extent, shape = terrain_extent(t), t.heights.shape
    else:
        texel_size = _finite(texel_size, "texel_size", positive=True)
        node = _coarser_than_nodes(t, texel_size)
        if node is not None:
            raise InvalidInputError(f"texel_size must be no larger than the terrain's node spacing ({node:g}; None "
                                    f"is one texel per node): it makes the texture finer; got {texel_size:g}")
        extent, shape = _texel_grid(t, texel_size)
    rows, cols = (int(n) for n in shape)
    check_budget(_CONTOUR_TEXEL_BYTES * rows * cols,
                 f"the {_texels(cols)} x {_texels(rows)} float32 RGBA contour layer",
                 hint="give a larger texel_size (or crop the terrain)")
    dev = resolve_device(device)
    style = texture_kernels.ContourStyle()
    style.levels = wp.array(values, dtype=wp.float64, device=dev)
    style.base, style.interval = base, interval
    style.half_width, style.index_half_width = width / 2.0, index_width / 2.0
    style.index_every = int(index_every)
    style.color, style.index_color = wp.vec4(*rgba), wp.vec4(*index_rgba)
    grid = _height_grid(t, 1.0, dev)
    if dev.is_cpu:
        host = recycled_empty((rows, cols, 4), np.float32)
        out = wp.array(host, dtype=wp.vec4, device=dev, copy=False)
    else:
        host, out = None, wp.empty((rows, cols), dtype=wp.vec4, device=dev)
    run = CONTOUR_RUN if dev.is_cpu else 1  # texels of a row a thread draws
    launch(texture_kernels.draw_contours, dim=rows * -(-cols // run),
           inputs=[run, grid, _texel_sampling(t, extent, (rows, cols)), style], outputs=[out], device=dev,
           min_dim=max(1, MIN_THREAD_ELEMENTS // run))
    image = host if host is not None else host_copy(out).reshape(rows, cols, 4)
    return TextureLayer("thematic", image, extent, name="contours")


# ---------------------------------------------------------------------------------------------- operations
def _frame(extent: Extent, shape: tuple[int, int]) -> texture_kernels.PixelFrame:
    """Pixel centres relative to the local origin (xmin, ymax) of ``extent``: float32 stays precise for UTM."""
    xmin, xmax, ymin, ymax = extent
    rows, cols = shape
    frame = texture_kernels.PixelFrame()
    frame.rows, frame.cols = rows, cols
    px, py = (xmax - xmin) / cols, (ymax - ymin) / rows
    frame.origin = wp.vec2(px / 2, -py / 2)
    frame.pixel = wp.vec2(px, -py)
    return frame


def _local_matrix(matrix: NDArray[np.float64], extent: Extent) -> wp.mat33:
    """A texture matrix taking local coordinates (relative to (xmin, ymax) of ``extent``), composed in float64."""
    shift = np.array([[1.0, 0.0, extent[0]], [0.0, 1.0, extent[3]], [0.0, 0.0, 1.0]])
    return wp.mat33(*(matrix @ shift).reshape(-1).tolist())


def _as_layer(value: Any, like: TextureLayer | None, name: str) -> TextureLayer:
    if isinstance(value, TextureLayer):
        return value
    if like is None:
        raise InvalidInputError(f"{name} must be a TextureLayer (or an array alongside a TextureLayer); "
                                f"got {type(value).__name__}")
    array = _image_argument(value, name, f"a TextureLayer or an array of {like.shape} pixels")
    if array.shape[:2] != like.shape:
        raise InvalidInputError(f"{name} has shape {array.shape[:2]} but the layer it combines with has "
                                f"{like.shape} (mismatched size)")
    kind: LayerKind = "thematic" if array.ndim == 3 else "luminance"
    return _named(name, TextureLayer, kind, array, like.extent, matrix=like.matrix, border=like.border)


def _named(name: str, make: Any, *args: Any, **kwargs: Any) -> Any:
    """``make(*args, **kwargs)``, its InvalidInputError prefixed with the argument ``name``: a layer's checks name
    its kind ("visibility layer values must ..."), not the argument of an operation that was given the values."""
    try:
        return make(*args, **kwargs)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{name}: {exc}") from None


def _overlaps(layer: TextureLayer, extent: Extent) -> bool:
    if layer.border == "edge":
        return True
    inverse = np.linalg.inv(layer.matrix)
    rows, cols = layer.shape
    corners = np.array([[-0.5, -0.5, 1], [cols - 0.5, -0.5, 1], [-0.5, rows - 0.5, 1], [cols - 0.5, rows - 0.5, 1]])
    world = corners @ inverse.T
    xmin, xmax, ymin, ymax = extent
    return not (world[:, 0].max() <= xmin or world[:, 0].min() >= xmax or world[:, 1].max() <= ymin
                or world[:, 1].min() >= ymax)


def _is_grid(layer: TextureLayer, extent: Extent, shape: tuple[int, int]) -> bool:
    """Whether the layer's pixels are the pixel grid (extent, shape) itself (read as they are, not resampled).

    Besides the matrices agreeing to 1e-9, the layer's texel at each corner of the grid must lie within 1e-6 texel of
    the grid's own: the matrix entries scale as 1 / pixel size, so with pixels 10^9 world units wide a layer of twice
    (or any multiple of) the grid's extent passed the absolute test and its pixels were read as the grid's, unsampled.
    That 1e-6 is give or take float64's rounding of the corners (1e-5 texel at 0.1 mm pixels in UTM), and the grid's own
    matrix is the grid whatever its rounding.
    """
    if layer.shape != shape:
        return False
    grid = _affine(extent, shape)
    if np.array_equal(layer.matrix, grid):
        return True
    if not np.allclose(layer.matrix, grid, rtol=0, atol=1e-9):
        return False
    rows, cols = shape
    texels = np.array([[-0.5, -0.5, 1.0], [cols - 0.5, -0.5, 1.0], [-0.5, rows - 0.5, 1.0],
                       [cols - 0.5, rows - 0.5, 1.0]])
    world = texels @ np.linalg.inv(grid).T  # the grid's corners; the layer's texels there are the grid's own
    # give or take float64's rounding of the terms summed (xmin / pixel reaches 1e11 at 0.1 mm pixels in UTM)
    rounding = 16 * np.finfo(np.float64).eps * (np.abs(world) @ np.abs(layer.matrix).T)
    return bool((np.abs(world @ layer.matrix.T - texels) <= 1e-6 + rounding).all())


def _check_overlaps(layer: TextureLayer, extent: Extent, name: str) -> None:
    if not _overlaps(layer, extent):
        raise InvalidInputError(f"{name} covers none of the extent {extent} it is combined on (mismatched extent); "
                                "give layers over the same area, or border='edge'")


def _device_rgba(layer: TextureLayer, device: wp.Device, name: str, keep: bool = True) -> wp.array:
    """The layer's RGBA (its errors named ``name``) as a vec4 array on ``device``: the one cached beside the layer's
    cached RGBA (an image that cannot change), else a new one, cached there when ``keep``."""
    rgba = _named(name, layer.rgba)
    key = ("device", str(device))
    cached = layer._rgba_cache.get("rgba") is rgba
    image = layer._rgba_cache.get(key) if cached else None
    if image is None:
        image = wp.array(rgba, dtype=wp.vec4, device=device, copy=not device.is_cpu)
        if cached and keep:
            layer._rgba_cache[key] = image
    return image


def _sampled(layer: TextureLayer, extent: Extent, shape: tuple[int, int], device: wp.Device,
             name: str) -> wp.array:
    """The layer's RGBA on the pixel grid (extent, shape): the image itself when it already is that grid."""
    image = _device_rgba(layer, device, name)
    if _is_grid(layer, extent, shape):
        return image
    _check_overlaps(layer, extent, name)
    out = wp.empty(shape, dtype=wp.vec4, device=device)
    launch(texture_kernels.sample_layer, dim=shape[0] * shape[1],
           inputs=[_frame(extent, shape), image, _local_matrix(layer.matrix, extent),
                   0 if layer.border == "edge" else 1], outputs=[out], device=device)
    return out


def _rgba_bytes(layer: TextureLayer) -> int:
    """Bytes :meth:`TextureLayer.rgba` of ``layer`` allocates: none when cached, else its check's."""
    return 0 if "rgba" in layer._rgba_cache else _RGBA_BYTES * layer.shape[0] * layer.shape[1]


def _grid_bytes(layer: TextureLayer, extent: Extent, shape: tuple[int, int]) -> int:
    """Bytes :func:`_sampled` of ``layer`` onto the pixel grid (extent, shape) allocates: its RGBA, and the grid's
    float32 RGBA unless the layer is that grid."""
    return _rgba_bytes(layer) + (0 if _is_grid(layer, extent, shape) else 16 * shape[0] * shape[1])


def _check_operation(what: str, shape: tuple[int, int], nbytes: int) -> None:
    """A layer operation's ``nbytes`` (its layers' RGBA and resampled copies, its outputs) against the memory budget,
    before it allocates: each layer's RGBA alone was checked, so blend of three fresh layers, each within the budget,
    took three times it (the grid's RGBA of each, and the result's)."""
    check_budget(nbytes, f"{what} on a {shape[1]} x {shape[0]} texel grid",
                 hint="crop or downsample the layers (texture_lod.ImagePyramid serves a large one by level)")


def _composed_input(layer: TextureLayer | None, extent: Extent, shape: tuple[int, int], device: wp.Device,
                    name: str, raw: bool = False) -> tuple[wp.array, wp.mat33, int]:
    """A layer of :func:`_composed` as ``compose_texture`` takes it: its RGBA (or, ``raw``, its own uint8 pixels,
    mode 3, where it is that pixel grid), its local texture matrix and its mode (-1: no layer; 0: the layer is the
    pixel grid; 1 and 2: sampled with a transparent or an edge border), checked as :func:`_sampled` checks it."""
    identity = wp.mat33(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    if layer is None:
        return wp.empty((1, 1), dtype=wp.vec4, device=device), identity, -1
    same = _is_grid(layer, extent, shape)
    image = np.asarray(layer.image)
    if raw and same and image.dtype == np.uint8 and image.ndim == 3 and _masked_pixels(layer.image) is None:
        # read as rgba() reads it, without its floats (a masked array's mask: through rgba())
        return wp.array(np.ascontiguousarray(image), dtype=wp.uint8, device=device), identity, 3
    if not same:
        _check_overlaps(layer, extent, name)
    array = _device_rgba(layer, device, name, keep=False)  # not kept: the composed texture holds no float layers
    if same:
        return array, identity, 0
    return array, _local_matrix(layer.matrix, extent), 1 if layer.border == "transparent" else 2


def _composed(shading: TextureLayer, colours: TextureLayer | None, picture: TextureLayer | None, extent: Extent,
              shape: tuple[int, int], background: Sequence[float] | None, device: wp.DeviceLike = None
              ) -> NDArray[np.uint8]:
    """The texture :func:`_composed_pair` composes, alone."""
    return _composed_pair(shading, colours, picture, extent, shape, background, None, device)[0]


def _composed_pair(shading: TextureLayer, colours: TextureLayer | None, picture: TextureLayer | None, extent: Extent,
                   shape: tuple[int, int], background: Sequence[float] | None, over: Sequence[float] | None,
                   device: wp.DeviceLike = None) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None]:
    """The texture ``stepterrain texture`` composes, as uint8 on the pixel grid (extent, shape), in one kernel pass
    (``compose_texture``): the same values as the layer operations one at a time, each layer resampled onto the
    grid (``_sampled``) and clamped as a layer's RGBA is, then ``blend(colours, picture)`` (the picture alone
    without colours) and ``modulate(shading, that)`` (``modulate(colours, shading)`` without a picture; the
    shading alone without either), ``.to_uint8(background)``; without their float32 RGBA layers on the grid
    (16 bytes a texel each, several at once, and their checks): the uint8 image and the layers' own RGBA.

    :func:`_composed_pair` with ``background`` None and an ``over`` colour also returns the RGB texture over
    ``over`` from the same pass (``.to_uint8(over)``, byte for byte what :func:`_composed` over it gives): a DEM
    with nodata wants both, the RGBA file and the drape's RGB, and composing it twice took twice the kernel's time
    (8 s a pass at 77 M texels); else its second item is None."""
    dev = resolve_device(device)
    rows, cols = shape
    channels = 4 if background is None else 3
    host, target = _output((rows, cols, channels), np.uint8, wp.uint8, dev)
    both = background is None and over is not None
    if both:
        over_host, over_target = _output((rows, cols, 3), np.uint8, wp.uint8, dev)
    else:
        over_host, over_target = None, wp.empty((1, 1, 1), dtype=wp.uint8, device=dev)
    inputs = [_composed_input(shading, extent, shape, dev, "shading"),
              _composed_input(colours, extent, shape, dev, "colours")]
    picture_input = _composed_input(picture, extent, shape, dev, "picture", raw=True)
    no_bytes = wp.empty((1, 1, 1), dtype=wp.uint8, device=dev)
    if picture_input[2] == 3:
        picture_args = [wp.empty((1, 1), dtype=wp.vec4, device=dev), picture_input[0], *picture_input[1:]]
    else:
        picture_args = [picture_input[0], no_bytes, *picture_input[1:]]
    under = background if background is not None else over
    bg = wp.vec3(0.0, 0.0, 0.0) if under is None else wp.vec3(*(float(np.float32(v)) for v in under))
    launch(texture_kernels.compose_texture, dim=rows * cols,
           inputs=[_frame(extent, shape), *inputs[0], *inputs[1], *picture_args, bg,
                   2 if both else 0 if background is None else 1],
           outputs=[target, over_target], device=dev)
    return _result(host, target), (_result(over_host, over_target) if both else None)


def _finish(out: wp.array, extent: Extent, name: str, border: str = "transparent") -> TextureLayer:
    """The result of an operation: ``border`` its first layer's, so an operation on a lens (an 'edge' border: its
    outside value repeats) stays a lens; a transparent border left the terrain beyond the lens image's square
    untouched (an animated or dimmed highlight lens lit a square)."""
    return TextureLayer("thematic", host_copy(out), extent, border=border, name=name)


def _result_frame(layer: TextureLayer) -> tuple[Extent, tuple[int, int]]:
    """(extent, shape): the pixel grid an operation computes on when ``layer`` is its first layer: the layer's own
    texels where its texture matrix puts them. That is its :attr:`~TextureLayer.frame` unless it was moved
    (:meth:`TextureLayer.moved`: a lens following a point), then the extent its texels lie over (its matrix north-up
    and axis-aligned; a rotated, sheared or mirrored one is resampled onto its extent): resampled onto its unmoved
    extent, a lens moved by more than its radius came out as its rim alone."""
    extent, shape = layer.frame
    if np.array_equal(layer.matrix, _affine(extent, shape)):
        return extent, shape
    inverse = np.linalg.inv(layer.matrix)  # texel (column, row, 1) -> world (x, y, 1)
    if inverse[0, 1] != 0 or inverse[1, 0] != 0 or not (inverse[0, 0] > 0 and inverse[1, 1] < 0):
        return extent, shape
    rows, cols = shape
    own = (inverse[0, 2] - 0.5 * inverse[0, 0], inverse[0, 2] + (cols - 0.5) * inverse[0, 0],
           inverse[1, 2] + (rows - 0.5) * inverse[1, 1], inverse[1, 2] - 0.5 * inverse[1, 1])
    try:
        own = _check_extent(own)
    except InvalidInputError:  # moved past float64's range: left where it was, as before
        return extent, shape
    return (own, shape) if _invertible(_affine(own, shape)) else (extent, shape)


def blend(a: TextureLayer, b: TextureLayer | ArrayLike, weights: TextureLayer | ArrayLike | None = None, *,
          device: wp.DeviceLike = None) -> TextureLayer:
    """Texture layer blending (§3.2.3): ``a · (1 − w) + b · w`` per pixel, w the alpha of ``weights``.

    ``weights`` is a visibility layer (its alpha; a lens, §5), a thematic RGBA layer (its alpha) or an (h, w)
    array of weights: floats in [0, 1], uint8 0-255, or a bool mask (True weighs 1) (a layer without alpha,
    luminance or RGB, is refused: it would weigh 1; a uint8 array of 0 and 1 only, likely a mask weighing 1/255, is
    warned about);
    ``None`` uses ``b``'s own alpha. Every layer is sampled through its texture matrix onto ``a``'s pixels.
    Colours are straight (not premultiplied) alpha, and ``b`` is laid over ``a`` with coverage
    ``c = w · alpha_b`` (``c = alpha_b`` for ``weights=None``): alpha ``c + alpha_a · (1 − c)``, colour
    ``(c · b + (1 − c) · alpha_a · a) / alpha``; for opaque layers that is the formula above. So an opaque ``a``
    stays opaque, and a transparent pixel of ``b`` (nodata, outside its extent) leaves ``a`` as it is. The result
    lies on ``a``'s pixels with ``a``'s border (as :func:`weighted_add` and :func:`modulate` give their first layer's).

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import TextureLayer, blend
    >>> a = TextureLayer("thematic", np.zeros((2, 2, 3)), (0, 2, 0, 2))
    >>> out = blend(a, np.ones((2, 2, 3)), np.full((2, 2), 0.25), device="cpu")
    >>> out.rgba()[0, 0].tolist()
    [0.25, 0.25, 0.25, 1.0]
    """
    a = _as_layer(a, None, "a")
    b = _as_layer(b, a, "b")
    if weights is None:
        w = b
    elif isinstance(weights, TextureLayer):
        if weights.kind in ("luminance", "topographic") or (weights.kind == "thematic" and weights.image.shape[2] == 3):
            # its alpha, the weight, is 1 wherever it has data: the result was b there, its values unread
            raise InvalidInputError(f"weights must be a layer with an alpha (a visibility layer such as a "
                                    f"thematic_lens, or a thematic RGBA layer): blend weighs by its alpha; got a "
                                    f"{weights.kind} layer{' of RGB' if weights.kind == 'thematic' else ''}, opaque "
                                    "wherever it has data. For weights from its values make "
                                    "TextureLayer('visibility', values, extent)")
        w = weights
    else:
        array = _image_argument(weights, "weights", "a visibility layer or an (h, w) array")
        if array.ndim != 2:
            raise InvalidInputError(f"weights must be a visibility layer or an (h, w) array; got shape {array.shape}")
        if array.dtype == np.bool_:  # a mask (np.ma keeps its own mask): True weighs 1; a layer takes no bools, and
            # the way out of that refusal, .astype(np.uint8), weighed 1/255
            array = array.astype(np.float32)
        elif array.dtype == np.uint8 and array.size and _maximum(array) == 1:
            # most likely a mask saved as 0/1 (b all but invisible), but a faint 0-255 weight image may hold only
            # these (a fade's first frame): warned, weighed as given (a masked array masking all: no maximum, and
            # int() of it raised a MaskError)
            warnings.warn("weights is a uint8 array of 0 and 1 only: uint8 weights are 0-255, so 1 weighs 1/255 "
                          "(b all but invisible). A mask? Give it as bool or as floats in [0, 1], or uint8 255 for "
                          "a full weight", stacklevel=caller_stacklevel())
        w = _as_layer(_named("weights", TextureLayer, "visibility", array, a.extent, matrix=a.matrix)
                      if array.shape == a.shape else array, a, "weights")
    dev = resolve_device(device)
    extent, shape = _result_frame(a)
    _check_operation("blend", shape, sum(_grid_bytes(layer, extent, shape) for layer in (a, b, w))
                     + 16 * shape[0] * shape[1])
    out = wp.empty(shape, dtype=wp.vec4, device=dev)
    launch(texture_kernels.blend_layers, dim=shape[0] * shape[1],
           inputs=[_sampled(a, extent, shape, dev, "a"), _sampled(b, extent, shape, dev, "b"),
                   _sampled(w, extent, shape, dev, "weights"), 1 if weights is None else 0], outputs=[out], device=dev)
    return _finish(out, extent, "blend", a.border)


def weighted_add(layers: Sequence[TextureLayer | ArrayLike], weights: Sequence[float], *,
                 device: wp.DeviceLike = None) -> TextureLayer:
    """Weighted texture layer addition (§3.2.3, §6): ``Σ w_k · layer_k`` per pixel and channel, clamped to [0, 1].

    Every channel, alpha too, is added straight (not premultiplied), so the colour of a transparent pixel counts
    as much as an opaque one's; :meth:`TextureAnimation.frame` interpolates its keys premultiplied instead. The
    weights are any finite numbers within float32's range (the kernel's), one per layer. The sum runs in float32;
    where its partial sums could overflow (the weights' magnitudes add up past half float32's top) it runs in
    float64, compensated, so huge weights that cancel exactly (3e38 and −3e38 on one layer) leave the other
    terms, in any order.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import TextureLayer, weighted_add
    >>> a = TextureLayer("luminance", np.full((2, 2), 0.2), (0, 1, 0, 1))
    >>> round(float(weighted_add([a, a], [0.5, 2.0], device="cpu").rgba()[0, 0, 0]), 6)
    0.5
    """
    for name, value in (("layers", layers), ("weights", weights)):
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence | np.ndarray):
            raise InvalidInputError(f"weighted_add needs {name} as a sequence (one weight per layer); got "
                                    f"{type(value).__name__}")
    layers = list(layers)
    values = list(weights)
    if len(layers) < 1 or len(layers) != len(values):
        raise InvalidInputError(f"weighted_add needs one weight per layer; got {counted(len(layers), 'layer')} and "
                                f"{counted(len(values), 'weight')}")
    # within float32's range, as the kernel takes them: 1e39 became inf there and inf · 0 NaN, clamped to 0 (the sum
    # 1e39 · 0 + 1 · 0.5 came out 0)
    checked = [_finite(w, f"weights[{k}]", lo=-FLOAT32_MAX, hi=FLOAT32_MAX) for k, w in enumerate(values)]
    first = _as_layer(layers[0], None, "layers[0]")
    others = [_as_layer(layer, first, f"layers[{k + 1}]") for k, layer in enumerate(layers[1:])]
    dev = resolve_device(device)
    extent, shape = _result_frame(first)
    texels = shape[0] * shape[1]
    wide = math.fsum(abs(w) for w in checked) > FLOAT32_MAX / 2
    # the first layer on the grid, one other at a time, and the sums: a pair of float32 results (the zero layer and
    # the output of a lone layer), or the float64 sum and its compensation and the output
    _check_operation("weighted_add", shape, _grid_bytes(first, extent, shape)
                     + max((_grid_bytes(layer, extent, shape) for layer in others), default=0)
                     + (80 if wide else 32) * texels)
    total = _sampled(first, extent, shape, dev, "layers[0]")
    zero = wp.zeros(shape, dtype=wp.vec4, device=dev) if not others else None
    if zero is not None:
        out = wp.empty(shape, dtype=wp.vec4, device=dev)
        launch(texture_kernels.add_layers, dim=shape[0] * shape[1], inputs=[total, zero, checked[0], 0.0, 1],
               outputs=[out], device=dev)
        return _finish(out, extent, "add", first.border)
    if wide:
        # float32 partial sums could overflow: 3e38 + 3e38 − 3e38 − 3e38 became inf − 3e38 = inf, clamped to 1 (in
        # another order 0); in float64 every product is exact, no partial sum overflows, and the compensation keeps
        # a small term added before huge ones that cancel. The weights are the kernel's float32 ones, as in the
        # float32 sum: taken as given, 3e38 and float32(3e38) left 5.5e30 · layer, and their products were inexact
        # (a fused multiply-add, as CUDA compiles one, changed the compensated sum)
        wide, error = wp.zeros(shape, dtype=wp.vec4d, device=dev), wp.zeros(shape, dtype=wp.vec4d, device=dev)
        for k in range(len(checked)):
            sampled = total if k == 0 else _sampled(others[k - 1], extent, shape, dev, f"layers[{k}]")
            launch(texture_kernels.add_layer_wide, dim=shape[0] * shape[1],
                   inputs=[wide, error, sampled, float(np.float32(checked[k]))], outputs=[wide, error], device=dev)
        out = wp.empty(shape, dtype=wp.vec4, device=dev)
        launch(texture_kernels.clamp_wide, dim=shape[0] * shape[1], inputs=[wide, error], outputs=[out], device=dev)
        return _finish(out, extent, "add", first.border)
    weight_total = checked[0]
    for k, layer in enumerate(others):
        out = wp.empty(shape, dtype=wp.vec4, device=dev)
        # Σ w_k x_k built pairwise, unclamped until the last term
        launch(texture_kernels.add_layers, dim=shape[0] * shape[1],
               inputs=[total, _sampled(layer, extent, shape, dev, f"layers[{k + 1}]"), weight_total, checked[k + 1],
                       1 if k == len(others) - 1 else 0],
               outputs=[out], device=dev)
        total, weight_total = out, 1.0
    return _finish(total, extent, "add", first.border)


def modulate(a: TextureLayer, *others: TextureLayer | ArrayLike, device: wp.DeviceLike = None) -> TextureLayer:
    """Texture layer modulation (§3.2.3, §7): ``a.rgb · b.rgb · ...`` per pixel; alpha stays ``a``'s.

    Each other layer modulates as far as it covers a pixel, ``a.rgb · (1 − alpha_b + alpha_b · b.rgb)``: where it
    is transparent (outside its extent, nodata) ``a`` stays as it is.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import TextureLayer, modulate
    >>> a = TextureLayer("thematic", np.full((1, 1, 3), 0.5), (0, 1, 0, 1))
    >>> float(modulate(a, np.full((1, 1), 0.5), device="cpu").rgba()[0, 0, 0])
    0.25
    """
    a = _as_layer(a, None, "a")
    if not others:
        raise InvalidInputError("modulate needs at least two layers")
    dev = resolve_device(device)
    extent, shape = _result_frame(a)
    layers = [_as_layer(other, a, f"layer {k + 2}") for k, other in enumerate(others)]
    # ``a`` on the grid, one other layer at a time, and the result with the one before it
    _check_operation("modulate", shape, _grid_bytes(a, extent, shape)
                     + max(_grid_bytes(layer, extent, shape) for layer in layers)
                     + 16 * min(len(layers), 2) * shape[0] * shape[1])
    current = _sampled(a, extent, shape, dev, "a")
    for k, layer in enumerate(layers):
        out = wp.empty(shape, dtype=wp.vec4, device=dev)
        launch(texture_kernels.modulate_layers, dim=shape[0] * shape[1],
               inputs=[current, _sampled(layer, extent, shape, dev, f"layer {k + 2}")], outputs=[out], device=dev)
        current = out
    return _finish(current, extent, "modulate", a.border)


def adjust(
    layer: TextureLayer,
    *,
    alpha: float = 1.0,
    brightness: float = 1.0,
    contrast: float = 1.0,
    hue: float = 0.0,
    saturation: float = 1.0,
    gamma: float = 1.0,
    split: Literal["left", "right"] | None = None,
    split_position: float = 0.5,
    cutout: ArrayLike | None = None,
    device: wp.DeviceLike = None,
) -> TextureLayer:
    """The per-layer adjustments of a CesiumJS ``ImageryLayer``, as one per-pixel kernel.

    In Cesium's order (``sampleAndBlend`` of its GlobeFS.glsl since CesiumJS 1.53): gamma ``c^(1/γ)`` of the
    layer's colour, brightness ``c · b``, contrast ``0.5 + (c − 0.5) · k``, hue rotation by ``hue`` radians in
    YIQ, saturation ``mix(luma, c, s)`` with luma weights (0.2125, 0.7154, 0.0721), the result clamped to [0, 1]
    (as Cesium's framebuffer clamps it), then alpha × ``alpha``; ``split`` keeps the layer only left ("left") or
    right ("right") of the vertical line at ``split_position`` (a fraction of the width from the west edge, "left" the
    west side, for a mirrored texture matrix too); ``cutout`` =
    (xmin, xmax, ymin, ymax) world rectangle where the layer is transparent. Defaults (1, 1, 1, 0, 1, 1) leave
    the layer unchanged, as in Cesium. Cesium's ``czm_hue`` writes the YIQ matrices row by row into GLSL's
    column-major ``mat3``; here the textbook YIQ matrices are applied (hue 0 is the identity in both, and a
    hue turns the chroma about the luma axis).

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import TextureLayer, adjust
    >>> a = TextureLayer("thematic", np.full((1, 2, 3), 0.25), (0, 2, 0, 1))
    >>> out = adjust(a, brightness=2.0, split="left", device="cpu").rgba()
    >>> out[0, 0].tolist(), float(out[0, 1, 3])
    ([0.5, 0.5, 0.5, 1.0], 0.0)
    """
    layer = _as_layer(layer, None, "layer")
    params = texture_kernels.Adjustment()
    params.alpha = _finite(alpha, "alpha", lo=0.0, hi=1.0)
    params.brightness = _finite(brightness, "brightness", lo=0.0, hi=1e6)
    params.contrast = _finite(contrast, "contrast", lo=0.0, hi=1e6)
    # whole turns dropped in float64: beyond float32's range the angle reached the kernel as inf (cos and sin NaN:
    # a white layer came out black), and a large finite angle lost its fraction in float32
    params.hue = math.fmod(_finite(hue, "hue"), 2.0 * math.pi)
    params.saturation = _finite(saturation, "saturation", lo=0.0, hi=1e6)
    params.one_over_gamma = 1.0 / _finite(gamma, "gamma", positive=True)
    if split is not None and not _is_name(split, ("left", "right")):
        raise InvalidInputError(f"split must be None, 'left' or 'right'; got {split!r}")
    params.split_side = {None: 0, "left": -1, "right": 1}[split]
    params.split_position = _finite(split_position, "split_position", lo=0.0, hi=1.0)
    params.has_cutout = 0
    params.cutout = wp.vec4(0.0, 0.0, 0.0, 0.0)
    extent, shape = layer.frame
    if cutout is not None:
        box = _check_extent(cutout, "cutout")
        params.has_cutout = 1  # relative to the frame's local origin (xmin, ymax), like the pixel centres
        params.cutout = wp.vec4(box[0] - extent[0], box[1] - extent[0], box[2] - extent[3], box[3] - extent[3])
    dev = resolve_device(device)
    # on the layer's own texels, kept with its texture matrix and border: a moved lens resampled onto its unmoved
    # extent lost its hot spot, and an 'edge' border turned transparent (black when modulated), with the defaults too
    frame, own = _frame(extent, shape), _own_texels(layer, extent)
    _check_operation("adjust", shape, (_rgba_bytes(layer) if own is not None else _grid_bytes(layer, extent, shape))
                     + 16 * shape[0] * shape[1])
    if own is not None:
        frame.origin, frame.pixel = own
        image = _sampled(replace(layer, matrix=None), extent, shape, dev, "layer")
    else:  # a rotated texture matrix: resampled onto the layer's extent, whose pixel grid the kernel walks
        image = _sampled(layer, extent, shape, dev, "layer")
    out = wp.empty(shape, dtype=wp.vec4, device=dev)
    launch(texture_kernels.adjust_layer, dim=shape[0] * shape[1], inputs=[frame, image, params], outputs=[out],
           device=dev)
    if own is None:
        return _finish(out, layer.extent, "adjust", layer.border)
    return TextureLayer("thematic", host_copy(out), extent, matrix=layer.matrix, border=layer.border, name="adjust")


def _own_texels(layer: TextureLayer, extent: Extent) -> tuple[wp.vec2, wp.vec2] | None:
    """(origin, pixel) of the layer's texel centres in world units relative to (xmin, ymax) of ``extent``, as a
    :class:`PixelFrame` holds them, when its texture matrix is axis-aligned (else None)."""
    if np.array_equal(layer.matrix, _affine(extent, layer.shape)):
        frame = _frame(extent, layer.shape)  # the layer as made: exactly the frame its extent gives
        return frame.origin, frame.pixel
    inverse = np.linalg.inv(layer.matrix)  # texel (column, row, 1) -> world (x, y, 1)
    if inverse[0, 1] != 0 or inverse[1, 0] != 0:
        return None
    return (wp.vec2(inverse[0, 2] - extent[0], inverse[1, 2] - extent[3]),
            wp.vec2(inverse[0, 0], inverse[1, 1]))


def combine(a: TextureLayer, b: TextureLayer | ArrayLike, mode: str, *, weights: Any = None,
            device: wp.DeviceLike = None) -> TextureLayer:
    """One layer operation by name: "blend" (``weights`` = alpha layer), "add" (``weights`` = (w_a, w_b),
    default (1, 1)) or "modulate"."""
    if not _is_name(mode, BLEND_MODES):
        raise InvalidInputError(f"unknown blend mode {mode!r}; expected one of {', '.join(BLEND_MODES)}")
    if mode == "blend":
        return blend(a, b, weights, device=device)
    if mode == "add":
        return weighted_add([a, b], (1.0, 1.0) if weights is None else weights, device=device)
    if weights is not None:  # "modulate"
        raise InvalidInputError("mode 'modulate' takes no weights")
    return modulate(a, b, device=device)


@dataclass(frozen=True)
class Pipeline:
    """Layer operations applied one after another (§3.2.3: "the result of one layer operation can be piped
    as input to another"); immutable, each method returns a longer pipeline.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import Pipeline, TextureLayer
    >>> base = TextureLayer("thematic", np.full((1, 1, 3), 0.5), (0, 1, 0, 1))
    >>> steps = Pipeline().modulate(np.full((1, 1), 0.5)).adjust(brightness=2.0)
    >>> float(steps.apply(base, device="cpu").rgba()[0, 0, 0])
    0.5
    """

    steps: tuple[tuple[str, tuple, dict], ...] = ()

    def _then(self, name: str, *args: Any, **kwargs: Any) -> Pipeline:
        return Pipeline(self.steps + ((name, args, kwargs),))

    def blend(self, other: Any, weights: Any = None) -> Pipeline:
        return self._then("blend", other, weights)

    def add(self, other: Any, weights: Sequence[float] = (1.0, 1.0)) -> Pipeline:
        if (isinstance(weights, (str, bytes)) or not isinstance(weights, Sequence | np.ndarray)
                or (isinstance(weights, np.ndarray) and weights.ndim == 0) or len(weights) != 2):  # 0-d: no len()
            raise InvalidInputError(f"Pipeline.add needs weights (current, other); got {weights!r}")
        return self._then("add", other, tuple(weights))

    def modulate(self, *others: Any) -> Pipeline:
        if not others:  # was refused only at apply(), as "modulate needs at least two layers" of a pipeline that
            # supplies the current one
            raise InvalidInputError("Pipeline.modulate needs at least one layer to modulate the current one by; got "
                                    "none")
        return self._then("modulate", *others)

    def adjust(self, **params: Any) -> Pipeline:
        known = sorted(set(inspect.signature(adjust).parameters) - {"layer", "device"})
        unknown = sorted(set(params) - set(known))
        if unknown:  # a typo failed only at apply(), with Python's TypeError
            raise InvalidInputError(f"adjust has no parameter {unknown[0]!r}; expected some of {', '.join(known)}")
        return self._then("adjust", **params)

    def then(self, other: Pipeline) -> Pipeline:
        """This pipeline followed by ``other``."""
        if not isinstance(other, Pipeline):
            raise InvalidInputError(f"then() needs a Pipeline; got {type(other).__name__}")
        return Pipeline(self.steps + other.steps)

    def apply(self, layer: TextureLayer, *, device: wp.DeviceLike = None) -> TextureLayer:
        """Run the steps on ``layer``; the result is a thematic RGBA layer on ``layer``'s pixels."""
        current = _as_layer(layer, None, "layer")
        for name, args, kwargs in self.steps:
            if name == "blend":
                current = blend(current, args[0], args[1], device=device)
            elif name == "add":
                current = weighted_add([current, args[0]], args[1], device=device)
            elif name == "modulate":
                current = modulate(current, *args, device=device)
            else:
                current = adjust(current, device=device, **kwargs)
        return current


# ---------------------------------------------------------------------------------------------- §5 lenses
def _disc(resolution: int, edge: float) -> NDArray[np.float32]:
    """(r, r) weights: 1 inside the unit disc less ``edge``, falling smoothly to 0 at the disc's rim."""
    centres = (np.arange(resolution, dtype=np.float64) + 0.5) / resolution * 2.0 - 1.0
    radius = np.hypot(centres[None, :], centres[:, None])
    inner = 1.0 - edge
    x = np.clip((1.0 - radius) / max(edge, 1e-9), 0.0, 1.0) if edge > 0 else (radius <= 1.0).astype(float)
    weights = x * x * (3.0 - 2.0 * x)
    weights[radius <= inner] = 1.0
    return weights.astype(np.float32)


_MAX_LENS_RESOLUTION = 1 << 32  # far beyond any memory budget (those below it are refused by the budget)


def _lens_args(center: ArrayLike, radius: float, resolution: int, edge: float) -> tuple[Extent, int, float]:
    c = real_vector(center, "center", "a finite (x, y)", 2)
    radius = _finite(radius, "radius", positive=True)
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 4:
        raise InvalidInputError(f"resolution must be an int >= 4; got {plain_repr(resolution)}")
    if resolution > _MAX_LENS_RESOLUTION:  # the budget check's message overflowed float64 (10**400)
        raise InvalidInputError(f"resolution must be at most {_MAX_LENS_RESOLUTION} texels a side; got an int of "
                                f"{int(resolution).bit_length()} bits")
    check_budget(LENS_TEXEL_BYTES * int(resolution) ** 2, f"a lens image of resolution {int(resolution)}",
                 hint="lower the lens resolution")
    edge = _finite(edge, "edge", lo=0.0, hi=1.0)
    # the disc image covers the lens' bounding square plus one texel of border (outside value) on each side
    pad = radius * 2.0 / (resolution - 2)
    extent = (c[0] - radius - pad, c[0] + radius + pad, c[1] - radius - pad, c[1] + radius + pad)
    # a radius below float64's resolution at the centre: the extent collapsed (refused as a bad "extent", an argument
    # the caller never gave) or rounded to another size (a lens of another radius, silently)
    size = 2.0 * (radius + pad)
    if not all(math.isfinite(v) for v in extent) or any(
            abs((hi - lo) - size) > 1e-6 * size for lo, hi in ((extent[0], extent[1]), (extent[2], extent[3]))):
        raise InvalidInputError(f"radius must be large enough to place the lens' {int(resolution)} texels a side at "
                                f"center in float64 (and the lens finite); got radius {radius:g} at center "
                                f"({c[0]:g}, {c[1]:g})")
    return extent, int(resolution), edge


def highlight_lens(center: ArrayLike, radius: float, *, strength: float = 0.5, edge: float = 0.25,
                   resolution: int = 128) -> TextureLayer:
    """A highlight lens (§5, Fig. 3 centre): a luminance layer, 1 around the hot spot and ``1 − strength``
    elsewhere, with a smooth rim ``edge`` (a fraction of the radius). Modulate the terrain's layers with it;
    move it with :meth:`TextureLayer.moved` (only the texture matrix changes)."""
    extent, resolution, edge = _lens_args(center, radius, resolution, edge)
    strength = _finite(strength, "strength", lo=0.0, hi=1.0)
    disc = _disc(resolution - 2, edge)
    image = np.full((resolution, resolution), 1.0 - strength, dtype=np.float32)
    image[1:-1, 1:-1] = (1.0 - strength) + strength * disc
    return TextureLayer("luminance", image, extent, border="edge", name="highlight lens")


def thematic_lens(center: ArrayLike, radius: float, *, edge: float = 0.25, resolution: int = 128) -> TextureLayer:
    """A thematic lens (§5, Fig. 3 right): a visibility layer, alpha 1 in a circular hot spot and 0 outside,
    a low-resolution image (128² by default); blend two thematic layers with it (:func:`blend`)."""
    extent, resolution, edge = _lens_args(center, radius, resolution, edge)
    image = np.zeros((resolution, resolution), dtype=np.float32)
    image[1:-1, 1:-1] = _disc(resolution - 2, edge)
    return TextureLayer("visibility", image, extent, border="edge", name="thematic lens")


# ---------------------------------------------------------------------------------------------- §6 animation
@dataclass(frozen=True)
class TextureAnimation:
    """Texture animation (§6): keyframe layers of one image size with strictly increasing time stamps.

    Time t selects two consecutive layers with weights 1 − α and α (clamped to the first and last keyframe);
    :meth:`frame` adds them, no intermediate texture is stored. The addition is premultiplied by alpha (unlike
    :func:`weighted_add`, which adds each channel): alpha ``(1 − α) · alpha_k + α · alpha_k+1``, colour
    ``((1 − α) · alpha_k · layer_k + α · alpha_k+1 · layer_k+1) / alpha``, so a transparent key (nodata, or no
    water yet) fades the other key in or out without tinting its colour.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture import TextureAnimation, TextureLayer
    >>> keys = [TextureLayer("luminance", np.full((1, 1), v), (0, 1, 0, 1)) for v in (0.0, 1.0)]
    >>> anim = TextureAnimation(keys, (0.0, 10.0))
    >>> a, b, alpha = anim.at(2.5)
    >>> alpha, round(float(anim.frame(2.5, device="cpu").rgba()[0, 0, 0]), 6)
    (0.25, 0.25)
    """

    layers: Sequence[TextureLayer]
    times: Sequence[float]

    def __post_init__(self) -> None:
        if isinstance(self.layers, (str, bytes, TextureLayer)):
            layers = None
        else:
            try:
                layers = tuple(self.layers)
            except TypeError:  # not iterable: None, a number
                layers = None
        if layers is None:
            raise InvalidInputError(f"layers must be a sequence of TextureLayer keyframes; got "
                                    f"{type(self.layers).__name__}")
        if not layers:
            raise InvalidInputError("an animation needs at least one TextureLayer keyframe; got an empty sequence")
        for k, layer in enumerate(layers):
            if not isinstance(layer, TextureLayer):
                raise InvalidInputError(f"layers[{k}] must be a TextureLayer; got {type(layer).__name__}")
            if layer.shape != layers[0].shape:  # frame() resamples onto the earlier key: frames changed size
                raise InvalidInputError(f"layers[{k}] has shape {layer.shape} but layers[0] has {layers[0].shape} "
                                        "(mismatched size); keyframes must all be images of one size")
        many = f"{len(layers)} finite, strictly increasing numbers" if len(layers) > 1 else "1 finite number"
        expected = f"{many} (one per layer)"
        if self.times is None or isinstance(self.times, (str, bytes)):  # numpy's ValueError or TypeError otherwise
            raise InvalidInputError(f"times must be {expected}; got {self.times!r}")
        times = real_numbers(self.times, "times", expected).reshape(-1)
        if times.shape != (len(layers),):
            raise InvalidInputError(f"times must give one time stamp per layer ({len(layers)}); got {len(times)}")
        if not np.isfinite(times).all() or np.any(np.diff(times) <= 0):
            raise InvalidInputError(f"times must be finite and strictly increasing; got {times.tolist()}")
        object.__setattr__(self, "layers", layers)
        object.__setattr__(self, "times", tuple(times.tolist()))

    def _keys(self, t: float) -> tuple[int, int, float]:
        """(k, k + 1, α) of :meth:`at`: the keys' positions in ``layers``."""
        t = _finite(t, "t")
        times = self.times
        if t <= times[0] or len(times) == 1:
            return 0, min(1, len(times) - 1), 0.0
        if t >= times[-1]:
            return len(times) - 2, len(times) - 1, 1.0
        k = int(np.searchsorted(times, t, side="right")) - 1
        alpha = (t - times[k]) / (times[k + 1] - times[k])
        return k, k + 1, float(alpha)

    def at(self, t: float) -> tuple[TextureLayer, TextureLayer, float]:
        """(layer k, layer k + 1, α) with times[k] <= t <= times[k + 1]: draw them with 1 − α and α."""
        k, kb, alpha = self._keys(t)
        return self.layers[k], self.layers[kb], alpha

    def frame(self, t: float, *, device: wp.DeviceLike = None) -> TextureLayer:
        """The animated layer at time t: (1 − α) · layer k + α · layer k + 1, premultiplied by alpha, on layer k's
        pixel grid (the last key's own at and after its time), with the keys' border where they share it (animated
        lenses repeat their edge) and the key's own at its time."""
        # the keys by position: found by identity in ``layers``, a key shown twice (a cycle A, B, A, C) was taken
        # for its first showing, and a refusal of the key after it named the wrong one (layers[1] for layers[3])
        k, kb, alpha = self._keys(t)
        a, b = self.layers[k], self.layers[kb]
        if alpha == 1.0:  # at (or past) the last key: that key, on its own grid, as every other key time gives its
            # key; on the previous key's grid a key over another extent (a lens moved to follow a point) was lost
            a, k, alpha = b, kb, 0.0
        dev = resolve_device(device)
        extent, shape = _result_frame(a)
        out = wp.empty(shape, dtype=wp.vec4, device=dev)
        launch(texture_kernels.interpolate_layers, dim=shape[0] * shape[1],
               inputs=[_sampled(a, extent, shape, dev, f"layers[{k}]"),
                       _sampled(b, extent, shape, dev, f"layers[{kb}]"), alpha],
               outputs=[out], device=dev)
        # a key's border: lenses (an 'edge' border) animated stay lenses; at a key's time the key's own
        border = a.border if alpha == 0.0 or a.border == b.border else "transparent"
        return _finish(out, extent, "frame", border)


# ---------------------------------------------------------------------------------------------- draping
def texture_uv(points: ArrayLike, layer: TextureLayer) -> NDArray[np.float64]:
    """UV coordinates (OpenGL convention, v up) of world points (N, 2|3) in ``layer``'s image."""
    if not isinstance(layer, TextureLayer):
        raise InvalidInputError(f"layer must be a TextureLayer; got {type(layer).__name__}")
    xy = real_numbers(points, "points", "real (N, 2) or (N, 3) world coordinates")
    if xy.ndim != 2 or xy.shape[1] < 2:
        raise InvalidInputError(f"points must be (N, 2) or (N, 3); got shape {xy.shape}")
    bad = np.flatnonzero(~np.isfinite(xy[:, :2]).all(axis=1))
    if bad.size:  # NaN texture coordinates otherwise, silently
        raise InvalidInputError(f"points must have finite x and y; got point {bad[0]} at {xy[bad[0]].tolist()}")
    texel = xy[:, :2] @ layer.matrix[:2, :2].T + layer.matrix[:2, 2]
    rows, cols = layer.shape
    return np.column_stack([(texel[:, 0] + 0.5) / cols, 1.0 - (texel[:, 1] + 0.5) / rows])


def _covering_image(image: NDArray[np.uint8], layer: TextureLayer, vertices: NDArray[Any],
                    background: NDArray[np.float64]) -> tuple[NDArray[np.uint8], NDArray[np.float64]]:
    """``image`` grown by whole texels until it covers every vertex, filled as the layer's border says (its edge
    texels repeated, or transparent: the background), and the vertices' UVs in it. A texture sampler repeats the
    image past UV 0 and 1 (glTF's default, VTK's too), so a layer covering part of the mesh showed again over the
    rest of it."""
    rows, cols = layer.shape
    texel = vertices[:, :2] @ layer.matrix[:2, :2].T + layer.matrix[:2, 2]  # (column, row), centres at integers
    low, high = texel.min(axis=0), texel.max(axis=0)
    if high[0] < -0.5 or low[0] > cols - 0.5 or high[1] < -0.5 or low[1] > rows - 0.5:
        # no part of the mesh under the image: a mesh in other coordinates than the layer's (a pyvista grid at
        # (0, 0) under a DEM's layer in UTM) got a texture of the image's edge or the background, silently
        xy_low, xy_high = vertices[:, :2].min(axis=0), vertices[:, :2].max(axis=0)
        corners = np.array([[-0.5, -0.5], [cols - 0.5, rows - 0.5]]) - layer.matrix[:2, 2]
        world = np.linalg.solve(layer.matrix[:2, :2], corners.T).T
        (x0, y0), (x1, y1) = world.min(axis=0), world.max(axis=0)
        raise InvalidInputError(
            f"mesh must lie under the layer (in its world coordinates) to be draped; got a mesh over x "
            f"{xy_low[0]:.6g} to {xy_high[0]:.6g}, y {xy_low[1]:.6g} to {xy_high[1]:.6g}, wholly outside the "
            f"layer's image over x {x0:.6g} to {x1:.6g}, y {y0:.6g} to {y1:.6g}: make the mesh and the layer of one "
            "terrain (a pyvista grid with the DEM's origin and spacing, st.stepped(dem) of the layer's dem)")
    c0, c1 = min(0, math.floor(low[0])), max(cols - 1, math.ceil(high[0]))
    r0, r1 = min(0, math.floor(low[1])), max(rows - 1, math.ceil(high[1]))
    shape = (r1 - r0 + 1, c1 - c0 + 1, 3)
    check_budget(shape[0] * shape[1] * 3, f"the {shape[1]} x {shape[0]} texture covering the draped mesh",
                 hint="drape a layer that covers the mesh (or blend it onto one)")
    if layer.border == "edge":
        grown = np.pad(image, ((-r0, r1 - rows + 1), (-c0, c1 - cols + 1), (0, 0)), mode="edge")
    else:
        grown = np.empty(shape, dtype=np.uint8)
        grown[:] = np.round(background * 255.0).astype(np.uint8)  # what a transparent texel composites to
        grown[-r0 : -r0 + rows, -c0 : -c0 + cols] = image
    uv = np.column_stack([(texel[:, 0] - c0 + 0.5) / shape[1], 1.0 - (texel[:, 1] - r0 + 0.5) / shape[0]])
    return grown, uv


def drape(mesh: trimesh.Trimesh, layer: TextureLayer, *, background: Sequence[float] = (1.0, 1.0, 1.0),
          name: str = "terrain texture") -> trimesh.Trimesh:
    """The mesh with ``layer`` as its texture: UVs from the vertices' xy through the layer's texture matrix, the
    image (composited over ``background``) as the base colour of a PBR material (metallic 0, roughness 1), whose
    ``wrap`` is ("CLAMP_TO_EDGE", "CLAMP_TO_EDGE"): GLB/glTF exports give the texture a sampler clamped to the image's
    edges, and renders sample it so, so that the terrain's border does not blend with the opposite border's texels in
    the mipmaps.

    Works on any mesh of the library whose xy lie in the layer's world coordinates (stepped terrain, a
    heightfield, a TIN; a pyvista PolyData of triangles as its Trimesh, see
    :func:`~stepterrain.pyvista_accessor.from_polydata`). Export it with :func:`stepterrain.export.save_mesh` (GLB
    embeds the image) and render it with :func:`stepterrain.render.render_textured_mesh`.

    Its texture coordinates (72 bytes a vertex while made) and texture are checked against the memory budget
    (:func:`stepterrain.set_memory_budget`) before either is made: an :class:`~stepterrain.errors.OutputTooLargeError`.

    Examples
    --------
    >>> import numpy as np, stepterrain as st
    >>> from stepterrain.texture import TextureLayer, drape
    >>> mesh = st.heightfield_mesh(np.zeros((2, 2)))
    >>> textured = drape(mesh, TextureLayer("luminance", np.ones((2, 2)), (-0.5, 1.5, -0.5, 1.5)))
    >>> textured.visual.uv.tolist()[0]   # node (0, 0) at (0, 0): west, south (v up)
    [0.25, 0.25]
    """
    mesh = mesh_argument(mesh)  # a pyvista PolyData (grid.stepterrain.stepped's) as its Trimesh
    if not isinstance(layer, TextureLayer):
        raise InvalidInputError(f"layer must be a TextureLayer; got {type(layer).__name__}")
    if not isinstance(name, str):  # the material's name: a number or None went into the GLB as given
        raise InvalidInputError(f"name must be a string; got {name!r}")
    bg = real_vector(background, "background", "(r, g, b) in [0, 1]", 3)
    if bg.min() < 0 or bg.max() > 1:
        raise InvalidInputError(f"background must be (r, g, b) in [0, 1]; got {background!r}")
    rows, cols = layer.shape
    # the texture coordinates with the texture (its RGBA unless made already, the uint8 image) before either is made:
    # only the image was checked, and a large mesh's UVs took 72 bytes a vertex under a small texture
    check_budget(_UV_BYTES * len(mesh.vertices) + 3 * rows * cols + _rgba_bytes(layer),
                 f"the texture coordinates of {counted(len(mesh.vertices), 'vertex', 'vertices', grouped=True)} "
                 f"and the {cols} x {rows} texture of the draped mesh",
                 hint="drape a mesh of fewer vertices (a larger interval, a coarsened or cropped DEM, tiles)")
    return _draped(mesh, layer, layer.to_uint8(background=bg), bg, name)


#: Bytes a vertex :func:`texture_uv` takes at its peak: a float64 copy of the vertices (24), their texels (16) and
#: texel columns and UVs (16 each) made from them.
_UV_BYTES = 72


def _draped(mesh: trimesh.Trimesh, layer: TextureLayer, image: NDArray[np.uint8], bg: NDArray[np.float64],
            name: str) -> trimesh.Trimesh:
    """:func:`drape` given the layer's image, ``layer.to_uint8(background=bg)``, made already (the texture
    command's, composed as uint8 on the layer's grid)."""
    from PIL import Image

    vertices = np.asarray(mesh.vertices)
    uv = texture_uv(vertices, layer)
    if len(uv) and (uv.min() < 0.0 or uv.max() > 1.0):  # the mesh reaches past the image: its border decides there
        image, uv = _covering_image(image, layer, vertices, bg)
    picture = Image.fromarray(image)
    material = trimesh.visual.material.PBRMaterial(name=name, baseColorTexture=picture, metallicFactor=0.0,
                                                   roughnessFactor=1.0, doubleSided=True)
    out = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False,
                          metadata=dict(mesh.metadata))
    out.face_attributes = dict(mesh.face_attributes)
    out.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    # the UVs lie inside the image, which does not go on past its edges: glTF's default sampler (REPEAT both ways) and
    # VTK's blended the terrain's edge texels with the opposite edge's in the coarse mipmaps (a line of the wrong
    # colour along the border when zoomed out); the GLB's sampler and the render clamp both ways
    out.visual.material.wrap = ("CLAMP_TO_EDGE", "CLAMP_TO_EDGE")
    return out


def _lay_over_uint8(image: NDArray[np.uint8], layer: TextureLayer) -> None:
    """``layer`` (straight RGBA on the same pixel grid) laid over the uint8 RGB or RGBA ``image`` in place, as
    :func:`blend` lays ``b`` over ``a`` and ``to_uint8`` rounds it (``stepterrain texture --contours``): coverage c =
    the layer's alpha; alpha ``c + alpha_a (1 − c)``, colour ``(c · b + (1 − c) · alpha_a · a) / alpha``. One pass
    of ``lay_over_uint8`` on the CPU (both are host arrays), in float32 with NumPy's operations in NumPy's order (a
    banded NumPy pass took longer than drawing the contours: 33 ns a texel over RGB, 67 over RGBA, one core)."""
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] not in (3, 4) or image.shape[:2] != layer.shape:
        raise ValueError(f"_lay_over_uint8: an (h, w, 3|4) uint8 image on the layer's {layer.shape} grid; "
                         f"got {image.dtype} {image.shape}")
    device = resolve_device("cpu")
    top = wp.array(np.ascontiguousarray(layer.image, dtype=np.float32), dtype=wp.vec4, device=device, copy=False)
    under = wp.array(image, dtype=wp.uint8, device=device, copy=False)  # writes land in ``image``
    texels = image.shape[0] * image.shape[1]
    launch(texture_kernels.lay_over_uint8, dim=-(-texels // CONTOUR_RUN), inputs=[CONTOUR_RUN, top],
           outputs=[under], device=device, min_dim=max(1, MIN_THREAD_ELEMENTS // CONTOUR_RUN))
