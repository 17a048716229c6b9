"""Stepped (terraced) terrain: vertex quantization, per-triangle step tessellation and the γ blend.

Implements paper 000 (Glander, Trapp & Döllner, *3D Isocontours – Real-time Generation and Visualization
of 3D Stepped Terrain Models*, Eurographics 2010): isovalues and thresholds (§3.1), vertex quantization and
step tessellation with terraces and walls (§3.2, Fig. 2-3), the γ interpolation schema (§3.3), lenses and
dynamic data (§4). Typical use:

    mesh = stepterrain.stepped(stepterrain.sample_dem(), interval=100.0)
    stepterrain.export.save_mesh(mesh, "steps.glb")  # y-up, as glTF viewers expect (trimesh's export keeps z up)

``stepterrain.stepped`` is this module, callable as its function :func:`stepped` (stepterrain._callable_module), so
``stepterrain.stepped.thresholds_of`` (any name here) works too.

Instead of the paper's geometry shader, which emits a triangle soup per frame, the tessellation runs as
count -> scan -> emit in Warp (kernels/stepped.py) and yields one welded, indexed mesh: the wall bottom and top
where a threshold crosses an input edge are shared by both triangles of the edge, so the result is crack-free by
construction. A TIN counts and emits its vertices and its faces in two such passes; a grid counts both in one walk
over chunks of nodes (only the chunk totals are scanned) and emits both in another (see :func:`step_arrays`).
"""

from __future__ import annotations

import math
import numbers
import struct
import warnings
import weakref
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._callable_module import make_module_callable
from ._compaction import MAX_INT32 as _MAX_INT32
from ._compaction import SMALLER_HINT, budget_value, check_budget, count_buffer, exclusive_offsets
from ._device import (
    GRID_CHUNK_FACTOR,
    chunk_shift,
    chunked_threads,
    empty_shared,
    host_copy,
    launch_chunked,
    no_elements,
    recycled_empty,
    resolve_device,
    scratch,
    scratch_aside,
    thread_structs,
    to_device,
    to_numpy,
)
from .errors import InvalidInputError, OutputTooLargeError, caller_stacklevel, counted, plain_repr
from .kernels import stepped as stepped_kernels
from .mesh import float32_floor_clash, reclaim_dropped, track
from .terrain import (
    FLOAT32_MAX,
    Terrain,
    _first_bool,
    _pair,
    _used_span,
    as_array,
    as_number,
    as_terrain,
    check_flag,
    check_spacing,
    finite_number,
    first_index,
    is_real_dtype,
    real_numbers,
    unmasked,
    unshared,
)

__all__ = ["stepped", "stepped_series", "isovalues", "nice_interval", "Lens", "circular_lens", "GammaLike"]

MAX_LEVELS = 1_000_000

#: The further advice of a grid too large for one call's int32 indices (after :data:`SMALLER_HINT`).
_TILES_HINT = ", or step it in tiles (stepterrain.batch)"

# bytes per output vertex / face while a mesh is being built (device work arrays + the numpy result)
_VERTEX_BYTES = 12 + 4 + 24
_SOURCE_BYTES = 8 + 4
_FACE_BYTES = 24 + 4 + 1
#: Per vertex with colors=: its RGBA and the level index _assemble looks it up by (int64).
_COLOR_BYTES = 4 + 8
#: Per output face of a face-coloured TIN: the terrain face it was cut from (int64) and its RGBA (_carry_visual).
_FACE_SOURCE_BYTES = 8 + 4
#: A solid's bytes (:func:`solid_bytes`) per vertex of the closed mesh: its position (float64) and what a visual adds
#: (RGBA, or a UV in float64); per face of it: the face, level and wall as ``_FACE_BYTES`` and a face colour.
_SOLID_VERTEX_BYTES = 24 + 16
_SOLID_FACE_BYTES = _FACE_BYTES + 4
#: close_solid's work arrays per surface face and vertex beside the closed mesh at its peak (the faces as the kernels'
#: flat int32, the terrace mask, each vertex's column in int64 and int32, and the base faces' offsets; before the mesh
#: exists, the boundary pass's vertex -> corner table, 24 bytes a face, and the int32 faces weigh less than it), and a
#: fixed part where there is a face (small arrays). tracemalloc peaks stay below these (tests/test_solid_budget.py;
#: close_solid alone on the sample DEM at 50 m: 72 MB of work arrays for 3.2 M faces and 1.6 M vertices, 22 bytes a
#: face, where the NumPy sorts took 315 MB, 98 bytes a face).
_SOLID_WORK_FACE_BYTES = 24
_SOLID_WORK_VERTEX_BYTES = 16
_SOLID_WORK_FIXED = 64 << 10
#: Nodes of a grid with nodata that :func:`solid_boundary_edges` reads at a time (its masks and the candidate cells'
#: temporaries stay a few MiB, whatever the grid's size).
_SOLID_BOUNDARY_BLOCK = 1 << 18


def _let_trimesh_write_bool_ply() -> None:
    """Let ``mesh.export("x.ply")`` (trimesh's own writer) write a stepped mesh.

    trimesh's PLY writer names each attribute's PLY type from a table of numpy dtypes that has no bool, so a
    stepped mesh, whose ``face_attributes["wall"]`` is a bool mask, raised ``KeyError: 'b1'`` there. A numpy bool
    is one byte, 0 or 1: PLY's ``uchar``, which the writer then packs byte for byte. ``setdefault`` leaves a
    trimesh that knows bools alone, and a trimesh without the table (another layout) is left as it is."""
    table = getattr(getattr(getattr(trimesh, "exchange", None), "ply", None), "_inverse_dtypes", None)
    if isinstance(table, dict):
        table.setdefault("b1", "uchar")


_let_trimesh_write_bool_ply()


@dataclass(frozen=True, eq=False)
class Lens:
    """A γ mask over the terrain's xy extent (paper 000 §4, Fig. 4).

    ``mask`` (h, w) holds γ in [0, 1] (0 = original terrain, 1 = fully stepped); row 0 lies at the *lower*
    y of ``extent`` = (xmin, xmax, ymin, ymax) in world units (``None``: the terrain's extent). It is sampled
    bilinearly at every output vertex, so walls stay vertical; beyond ``extent`` a vertex takes the value of the
    nearest mask edge (the sampler clamps), so a mask over part of the terrain holds its border value elsewhere.
    The sampler works in float32: :func:`stepped` refuses an extent wider or taller than float32 holds (3.4e+38).
    Lenses compare and hash by identity, as :class:`~stepterrain.closeup.ROI` does (the generated field-wise ``==``
    raised numpy's "truth value ... is ambiguous" on their masks, and ``hash`` "unhashable type").
    """

    mask: NDArray[np.float32]
    extent: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        mask = as_array(unmasked(self.mask), "lens mask", "a real (h, w) array")  # a masked entry is NaN: refused
        real = mask.dtype != bool and mask.dtype.kind in "iuf"  # complex: numpy dropped the imaginary part
        if mask.ndim != 2 or min(mask.shape) < 1 or not real:
            raise InvalidInputError(
                f"lens mask must be a real (h, w) array; got shape {mask.shape}, dtype {mask.dtype}"
            )
        # the caller's array, changed later, would bypass the checks below
        mask = unshared(np.ascontiguousarray(mask, dtype=np.float32), self.mask, mask)
        mask.flags.writeable = False
        if not np.all(np.isfinite(mask)):  # NaN, also a masked entry
            at = first_index(~np.isfinite(mask))
            raise InvalidInputError(f"lens mask values must lie in [0, 1]; got {float(mask[at])} at index {at}")
        if mask.min() < 0.0 or mask.max() > 1.0:
            raise InvalidInputError(f"lens mask values must lie in [0, 1]; got range [{mask.min()}, {mask.max()}]")
        object.__setattr__(self, "mask", mask)
        if self.extent is not None:
            try:
                ext = tuple(as_number(v) for v in self.extent)
            except (TypeError, ValueError):
                ext = ()  # not numbers: refused below
            if len(ext) != 4 or not np.all(np.isfinite(ext)) or ext[1] <= ext[0] or ext[3] <= ext[2]:
                raise InvalidInputError(
                    f"lens extent must be (xmin, xmax, ymin, ymax) with max > min; got {self.extent!r}"
                )
            object.__setattr__(self, "extent", ext)


#: Peak bytes per texel while a lens mask is computed (float64 distances and smoothstep temporaries): 40 measured
#: for circular_lens and texture's lenses; checked against the memory budget before allocating.
LENS_TEXEL_BYTES = 48


GammaLike = float | ArrayLike | Callable[[NDArray[np.float64]], ArrayLike] | Lens


def circular_lens(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    center: tuple[float, float],
    radius: float,
    *,
    edge_width: float | None = None,
    inside: float = 0.0,
    outside: float = 1.0,
    resolution: int = 512,
    spacing: ArrayLike | None = None,
    origin: ArrayLike | None = None,
) -> Lens:
    """A soft-edged circular lens: γ = ``inside`` within ``radius`` of ``center``, ``outside`` beyond.

    The transition is a smoothstep over ``edge_width`` (default radius / 4) centred on the circle. With the
    defaults the original terrain shows inside the lens and the steps outside (paper 000 §4, Fig. 4). The mask
    holds ``resolution`` x ``resolution`` samples (an int, 3 at least: a 2 x 2 mask holds only the square's corners,
    all beyond the lens) over the lens's square (the circle and its soft edge, clipped to the terrain's extent; the
    whole extent where the lens misses the terrain), and γ beyond that square is ``outside``: a small lens on a
    large DEM is as smooth as a large one.

    ``center`` and ``radius`` are in the terrain's xy coordinates: for a raw (H, W) array give the ``spacing`` and
    ``origin`` that :func:`stepped` is given (a lens built over the unit-spaced array and applied to
    ``stepped(h, spacing=(30, 30), ...)`` lies where the center names in unit cells, not metres). A lens that lies
    wholly outside the terrain's extent warns (γ is ``outside`` everywhere: the lens changes nothing).

    Examples
    --------
    >>> import numpy as np, stepterrain as st
    >>> lens = st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), 1.0)
    >>> float(lens.mask.min()), float(lens.mask.max())
    (0.0, 1.0)
    """
    t = as_terrain(terrain, spacing=spacing, origin=origin)
    try:
        cx, cy = (as_number(c) for c in center)  # text ("12" unpacked to 1, 2) and bools are slips
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"lens center must be (x, y); got {center!r}") from exc
    if not (np.isfinite(cx) and np.isfinite(cy)):
        raise InvalidInputError(f"lens center must be finite; got {center!r}")
    radius = finite_number(radius, "lens radius")
    if radius <= 0:
        raise InvalidInputError(f"lens radius must be a positive finite number; got {radius}")
    width = radius / 4.0 if edge_width is None else finite_number(edge_width, "lens edge_width")
    if width < 0:
        raise InvalidInputError(f"lens edge_width must be >= 0; got {edge_width}")
    for name, value in (("inside", inside), ("outside", outside)):
        if not 0.0 <= finite_number(value, f"lens {name}") <= 1.0:
            raise InvalidInputError(f"lens {name} must lie in [0, 1]; got {value}")
    # 3 at least: a 2 x 2 mask has its samples only at the corners of the lens's square, all beyond the lens's reach
    # (:func:`_lens_box`), so it was `outside` everywhere: a lens on the terrain that changed nothing, unsaid
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 3:
        raise InvalidInputError(f"lens resolution must be an int >= 3; got {plain_repr(resolution)}")
    check_budget(LENS_TEXEL_BYTES * int(resolution) ** 2, f"a lens mask of resolution {int(resolution)}",
                 hint="lower the lens resolution")
    n = int(resolution)
    ex0, ex1, ey0, ey1 = t.extent
    if math.hypot(max(ex0 - cx, 0.0, cx - ex1), max(ey0 - cy, 0.0, cy - ey1)) >= radius + width / 2.0:
        hint = (" (a raw array's coordinates are its column and row unless spacing=/origin= are given, as stepped "
                "takes them)" if t.kind == "grid" and not isinstance(terrain, Terrain) and spacing is None
                and origin is None else "")
        warnings.warn(f"circular_lens: the lens at ({cx:.9g}, {cy:.9g}), radius {radius:.9g}, lies outside the "
                      f"terrain's extent x {ex0:.9g} to {ex1:.9g}, y {ey0:.9g} to {ey1:.9g}: gamma is `outside` "
                      f"({float(outside):g}) everywhere{hint}", stacklevel=caller_stacklevel())
    xmin, xmax, ymin, ymax = _lens_box(t.extent, (cx, cy), radius + width / 2.0, n)
    xs = np.linspace(xmin, xmax, n)
    ys = np.linspace(ymin, ymax, n)
    d = np.hypot(xs[None, :] - cx, ys[:, None] - cy)
    if width > 0:
        with np.errstate(over="ignore"):  # a subnormal width (1e-320) overflows to ±inf, which the clip takes to 0 or 1
            s = np.clip((d - (radius - width / 2)) / width, 0.0, 1.0)
        s = s * s * (3.0 - 2.0 * s)
    else:
        s = (d > radius).astype(np.float64)
    mask = float(inside) + (float(outside) - float(inside)) * s
    return Lens(mask.astype(np.float32), (xmin, xmax, ymin, ymax))


def _lens_box(
    extent: tuple[float, float, float, float], center: tuple[float, float], reach: float, n: int
) -> tuple[float, float, float, float]:
    """The part of ``extent`` a circular lens's mask covers: the square around ``center`` whose border samples lie
    beyond ``reach`` (radius + half the soft edge, where γ is ``outside`` exactly), clipped to the terrain's extent;
    the terrain's whole extent where the square misses it. The mask is clamped to its border values beyond its extent
    (kernels/stepped.py, sample_lens), so a small lens on a large DEM keeps its ``resolution`` samples on the lens
    rather than spreading them over the whole terrain."""
    xmin, xmax, ymin, ymax = extent
    if xmax <= xmin:
        xmax = xmin + 1.0
    if ymax <= ymin:
        ymax = ymin + 1.0
    cx, cy = center
    half = reach * (1.0 + 2.0 / (n - 1))  # a sample's spacing beyond the reach: the border samples are `outside`
    bx0, bx1, by0, by1 = max(xmin, cx - half), min(xmax, cx + half), max(ymin, cy - half), min(ymax, cy + half)
    if not (bx1 > bx0 and by1 > by0) or not all(np.isfinite((bx0, bx1, by0, by1))):
        return xmin, xmax, ymin, ymax  # the lens misses the terrain (or a subnormal reach): γ is `outside` everywhere
    return bx0, bx1, by0, by1


#: Steps aimed at by :func:`nice_interval` (the CLI's default when neither --interval nor --levels is given).
TARGET_STEPS = 15


def nice_interval(height_range: tuple[float, float], target: int = TARGET_STEPS) -> float:
    """A round interval (1, 2, 2.5 or 5 times a power of ten) giving about ``target`` steps over the range, and
    no finer than float32 resolves at the heights: at least 8 float32 steps of the larger |height| (the kernels'
    isovalues are float32, and :func:`isovalues` refuses levels too close to be told apart), so heights from 1e7 to
    1e7 + 3 get 10, where ~15 steps (0.2) would be refused.

    >>> nice_interval((315.0, 2295.0))
    100.0
    >>> nice_interval((0.0, 1.0))
    0.05
    >>> nice_interval((1e7, 1e7 + 3.0))
    10.0

    A flat range (min == max) gives 1.0. A ``height_range`` that is not finite (min, max) with min <= max, or a
    ``target`` that is not a positive number, is an :class:`InvalidInputError`.
    """
    if isinstance(target, (bool, np.bool_)):  # True was taken as 1 step
        raise InvalidInputError(f"target must be a positive number of steps; got {plain_repr(target)}")
    target = finite_number(target, "target", positive=True)
    try:
        lo, hi = (as_number(v) for v in height_range)
    except (TypeError, ValueError):  # text, bools, one or three values
        raise InvalidInputError(f"height_range must be (min, max) heights; got {height_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise InvalidInputError(f"height_range must be finite (min, max) with min <= max; got {height_range!r}")
    span = hi - lo
    if not math.isfinite(span) or span <= 0:  # flat, or beyond float64 (-1e308, 1e308)
        return 1.0
    exponent = math.floor(math.log10(span / target))
    candidates = [m * 10.0**e for e in (exponent - 1, exponent, exponent + 1) for m in (1.0, 2.0, 2.5, 5.0)]
    best = min(candidates, key=lambda c: abs(math.log(span / c / target)))
    # 8 float32 steps: one more binade above the heights (the top isovalue) doubles the step, and rounding
    # base + k * interval to float32 takes one more, leaving the levels at least 2 steps apart (_unseparated)
    # float32's step at the larger |height|: np.spacing of the float32 maximum is inf (its next float32 up), which
    # made the default interval of heights near 3.4e38 an OverflowError; the step below the maximum is the same
    top = np.float32(max(abs(lo), abs(hi)))
    with np.errstate(over="ignore"):
        step = np.spacing(top)
    finest = 8.0 * float(top - np.nextafter(top, np.float32(0.0)) if np.isinf(step) else step)
    if best < finest:
        low = math.floor(math.log10(finest))
        best = min(c for c in (m * 10.0**e for e in (low, low + 1) for m in (1.0, 2.0, 2.5, 5.0)) if c >= finest)
    return float(f"{best:.6g}")


def one_of_interval_or_levels(interval: Any, levels: Any, uniform: str) -> None:
    """An InvalidInputError unless exactly one of ``interval`` and ``levels`` is given; ``uniform`` names what
    ``interval=`` gives, in the error (:func:`isovalues`; the texture's contour levels)."""
    if (interval is None) == (levels is None):
        given = "None" if levels is None else "[...]"
        raise InvalidInputError(f"give exactly one of interval= ({uniform}) or levels= (explicit, strictly "
                                f"increasing); got interval={interval!r}, levels={given}")


def given_levels(levels: Any, base: Any, uniform: str, expected: str, item: str) -> NDArray[np.float64]:
    """Explicit ``levels`` as float64, checked: 1-D, at least one, finite real numbers, and ``base`` left at 0 (levels
    are absolute: an offset was a slip). ``uniform`` names what ``interval=`` gives instead, ``expected`` what a
    sequence of levels is and ``item`` one of them, in the errors (:func:`isovalues`; the texture's contour levels)."""
    if not (isinstance(base, numbers.Real) and not isinstance(base, (bool, np.bool_)) and base == 0.0):
        raise InvalidInputError(f"base applies only to interval= ({uniform}), not to levels=; got base={base!r} with "
                                "levels")
    # real numbers only: text ("5"), bools and complex values are slips, a masked entry is NaN (refused below)
    values = real_numbers(levels, "levels", expected)
    if values.ndim > 1:
        raise InvalidInputError(f"levels must be a 1-D sequence of {item}s; got shape {values.shape}")
    values = values.reshape(-1)
    if values.size == 0:
        raise InvalidInputError(f"levels must hold at least one {item}; got an empty sequence")
    if not np.all(np.isfinite(values)):
        raise InvalidInputError(f"levels must be finite; got {values.tolist()[:10]}")
    return values


def _default_isovalues(
    lo: float, hi: float, base: Any, *, interval_name: str = "interval=", levels_name: str = "levels="
) -> tuple[float, NDArray[np.float32]]:
    """The default interval over the heights ``lo`` to ``hi`` (:func:`nice_interval`, used when neither an interval
    nor levels is given) and its :func:`isovalues` from ``base``. A refusal of it (heights near the float32 maximum,
    whose round interval's top isovalue lies beyond it) named an interval the caller never gave: it says the interval
    was picked, naming the caller's options ``interval_name``/``levels_name`` (``--interval``/``--levels`` for the
    command line); a ``base`` refused is raised as it is."""
    interval = nice_interval((lo, hi))
    try:
        values = isovalues((lo, hi), interval=interval, base=base)
    except InvalidInputError as exc:
        if not str(exc).startswith("interval"):  # a base refused: named as it is
            raise
        raise InvalidInputError(f"no {interval_name} or {levels_name} given, and the round interval {interval:g} "
                                f"picked for heights {lo:g} to {hi:g} is refused: {exc}; give {levels_name} (explicit "
                                f"isovalues) or an {interval_name} that fits") from None
    return interval, values


def _one_level(lo: float, hi: float, values: ArrayLike, given: str, gamma: float = 1.0,
               lens: bool = False) -> str | None:
    """Why the heights ``lo`` to ``hi`` step onto one isovalue of ``values`` (no threshold between two of them,
    :func:`thresholds_of`, lies within the heights: heights outside the levels clamp to the end ones), None when they
    step onto several. Levels as the kernels find them (``level_of``: the thresholds at or below a float32 height).
    ``given`` names the isovalues as the caller gave them (``levels 5000 to 6000``): levels typed in another unit,
    or an interval larger than the relief, gave a flat plate at a height the terrain never reaches, unsaid. None
    too for flat heights (``lo == hi``: one terrace whatever the isovalues) and for ``gamma`` 0 in float32 (the
    original terrain); ``gamma`` < 1 blends the relief toward the level (§3.3), no plate; ``lens``: γ = ``gamma``
    outside a lens, the original terrain inside."""
    levels = np.asarray(values, np.float32).reshape(-1)
    g = float(np.float32(gamma))
    if levels.size == 0 or not lo < hi or not g > 0.0:
        return None
    thresholds = thresholds_of(levels)
    below, above = (int(np.searchsorted(thresholds, np.float32(h), side="right")) for h in (lo, hi))
    if below != above:
        return None
    level = float(levels[below])
    shape = f"one flat terrace at {level:g}" if g == 1.0 else f"its heights pulled toward {level:g} (γ = {gamma:g})"
    return (f"every height ({lo:g} to {hi:g}) steps onto the one isovalue {level:g} of the {given}: the stepped "
            f"terrain has no step, {shape}{' outside the lens' if lens else ''}; give isovalues two of which have "
            "their midpoint within the heights")


def isovalues(
    height_range: tuple[float, float],
    *,
    interval: float | None = None,
    levels: ArrayLike | None = None,
    base: float = 0.0,
) -> NDArray[np.float32]:
    """The isovalues α_i: the fewest ``base + k * interval`` covering ``height_range`` (in float32, as the kernels
    compare), or the explicit ``levels``.

    Raises
    ------
    InvalidInputError
        Both or neither of ``interval`` and ``levels``; ``base`` other than 0 with ``levels``; a non-finite or
        non-positive interval; levels that are empty, non-finite or not strictly increasing (also after rounding
        to float32), or two of them (or two isovalues of an interval) that are neighbouring float32 values (the
        threshold between them would round onto the lower one); a ``height_range`` that is not finite (min, max)
        with min <= max, or spans more than float32 holds (max - min > 3.4e38: the step kernels take height
        differences in float32); a ``base`` beyond float32, or more than 2**53 intervals from zero and from the
        heights (float64 rounds it by more than an interval: bring it closer to the heights).

    Examples
    --------
    >>> import stepterrain as st
    >>> st.isovalues((3.0, 21.0), interval=10.0).tolist()
    [0.0, 10.0, 20.0, 30.0]
    """
    one_of_interval_or_levels(interval, levels, "uniform isovalues base + k * interval")
    try:
        lo, hi = (as_number(v) for v in height_range)
    except (TypeError, ValueError):  # text, bools, an int beyond float64 (10**400): as_number refuses them
        raise InvalidInputError(f"height_range must be (min, max) heights; got {height_range!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise InvalidInputError(f"height_range must be finite (min, max) with min <= max; got {height_range!r}")
    if levels is not None:
        values64 = given_levels(levels, base, "uniform isovalues base + k * interval", "a sequence of numbers",
                                "isovalue")
        if np.abs(values64).max() > FLOAT32_MAX:
            raise InvalidInputError(f"levels must fit in float32 (|x| < 3.4e+38); got {values64.tolist()[:10]}")
        values = values64.astype(np.float32)
        bad = np.flatnonzero(values[1:] <= values[:-1])  # np.diff overflowed (and warned) from -3.4e38 to 3.4e38
        if bad.size:
            i = int(bad[0]) + 1
            if values64[i] > values64[i - 1]:  # increasing as given, equal once rounded to the kernels' float32
                a, b = float(values64[i - 1]), float(values64[i])
                raise InvalidInputError(
                    f"levels must be strictly increasing in float32 (the step kernels' precision); levels[{i - 1}]="
                    f"{a!r} and levels[{i}]={b!r} both round to {float(values[i])!r}"
                )
            shown = values64.tolist() if values64.size <= 10 else values64[max(0, i - 3) : i + 3].tolist()
            raise InvalidInputError(f"levels must be strictly increasing; got {shown} (index {i})")
        if values.size > MAX_LEVELS:
            raise InvalidInputError(f"at most {MAX_LEVELS} levels are supported; got {values.size}")
        close = _unseparated(values)
        if close is not None:
            raise InvalidInputError(
                f"levels must be more than one float32 step apart (the threshold between two levels, their midpoint, "
                f"must lie above the lower one); levels[{close}]={float(values64[close])!r} and levels[{close + 1}]="
                f"{float(values64[close + 1])!r} are neighbouring float32 values, {float(values[close])!r} and "
                f"{float(values[close + 1])!r}: the threshold rounds onto the lower level, whose heights would step up"
            )
        return _check_span(lo, hi, values)
    try:
        step = as_number(interval)
        base = as_number(base)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"interval and base must be numbers; got interval={interval!r}, base={base!r}") from exc
    if not np.isfinite(step) or step <= 0:
        raise InvalidInputError(f"interval must be a positive finite number; got {plain_repr(interval)}")
    if not np.isfinite(base):
        raise InvalidInputError(f"base must be finite; got {plain_repr(base)}")
    # what follows depends on these four floats alone: a re-step going back and forth between a few intervals takes
    # its isovalues from _UNIFORM (a copy: the caller may write to it), keyed by their bits (-0.0 is not 0.0); a call
    # that raises is not kept, so it raises again
    key = _UNIFORM_KEY.pack(lo, hi, step, base)
    known = _UNIFORM.get(key)
    if known is not None:
        return known.copy()
    values = _uniform_isovalues(lo, hi, step, base)
    if values.size <= _UNIFORM_SIZE:
        if len(_UNIFORM) >= _UNIFORM_KEPT:
            _UNIFORM.clear()
        _UNIFORM[key] = values.copy()
    return values


#: The isovalues of :func:`isovalues`' ``interval`` by (lo, hi, interval, base) bits: at most _UNIFORM_KEPT
#: results of at most _UNIFORM_SIZE levels (a 512² re-step computed them again in 0.03 ms hot, 0.15-0.19 ms as the
#: first call after a gc.collect())
_UNIFORM: dict[bytes, NDArray[np.float32]] = {}
_UNIFORM_KEY = struct.Struct("<4d")
_UNIFORM_KEPT = 16
_UNIFORM_SIZE = 4096


def _uniform_isovalues(lo: float, hi: float, step: float, base: float) -> NDArray[np.float32]:
    """:func:`isovalues` of ``interval=step`` with ``base`` over the heights [lo, hi], the checked floats."""
    k0f, k1f = (lo - base) / step, (hi - base) / step
    if not (math.isfinite(k0f) and math.isfinite(k1f)):  # a subnormal interval (1e-320), or base far from the heights
        raise InvalidInputError(
            f"interval={step:g} with base={base:g} over heights [{lo:g}, {hi:g}] gives more levels than float64 can "
            f"count; at most {MAX_LEVELS:,} are supported"
        )
    if abs(base) > FLOAT32_MAX:  # base + k * interval was 0 there: 1e39 + (-1e39 + 1) rounds to 1e39 + -1e39
        raise InvalidInputError(
            f"base must fit in float32 (|x| < 3.4e+38), as the isovalues it offsets do; got {base:g}"
        )
    k0, k1 = math.floor(k0f), math.ceil(k1f)
    if k1 - k0 + 1 > MAX_LEVELS:
        count = k1 - k0 + 1  # written out where rounding would hide how far over the limit it is (1e+06: 1,000,001)
        raise InvalidInputError(
            f"interval={step:g} over heights [{lo:g}, {hi:g}] gives "
            f"{f'{count:,}' if count < 10**9 else f'{float(count):.3g}'} levels; at most {MAX_LEVELS:,} are supported"
        )
    far = max(abs(k0f), abs(k1f))
    if far > _EXACT_COUNT and abs(base) > step * _EXACT_COUNT:  # base's rounding error alone exceeds an interval:
        # base + k * interval near the heights cancels to that error (base=1e20, interval=1 gave [0.0, 0.0])
        raise InvalidInputError(  # the heights are not named: batch checks its arguments over heights [0, 0]
            f"interval={step:g} with base={base:g}, more than 2**53 intervals from zero: float64 rounds it by more "
            "than an interval, so the isovalues near the heights cannot be computed; bring base closer to the heights"
        )
    for widened in (False, True):
        values64 = base + np.arange(k0, k1 + 1, dtype=np.float64) * step
        if np.abs(values64).max() > FLOAT32_MAX:
            raise InvalidInputError(
                f"interval={step} with base={base} gives isovalues beyond float32 (|x| < 3.4e+38); "
                f"got [{values64[0]}, {values64[-1]}]"
            )
        values = values64.astype(np.float32)
        below, above = values[0] > np.float32(lo), values[-1] < np.float32(hi)  # float32 rounding is monotone
        if not (below or above) or widened:
            break
        # the heights were lost in lo - base (interval=3.4e38, base=-3.4e38 over [1000, 1011]: k0 = k1 = 1, the one
        # isovalue 0 below them): one more interval on the short side covers them
        k0, k1 = k0 - int(below), k1 + int(above)
    if below or above:
        raise InvalidInputError(
            f"interval={step} with base={base} gives isovalues [{values[0]}, {values[-1]}] that do not cover the "
            f"heights [{lo}, {hi}] in float32; bring base closer to the heights"
        )
    if values.size > 1 and (values[1:] <= values[:-1]).any():  # finite: np.diff(values) <= 0, without its copies
        raise InvalidInputError(f"interval={step} is too small for float32 heights around {hi}")
    close = _unseparated(values)
    if close is not None:
        a, b = float(values[close]), float(values[close + 1])
        raise InvalidInputError(
            f"interval={step:g} is too small for float32 heights around {a:g}: the isovalues {a!r} and {b!r} are "
            f"neighbouring float32 values, so the threshold between them (their midpoint) rounds onto the lower one, "
            f"whose heights would step up; use an interval of at least {2 * (b - a):g} there"
        )
    # the fewest that cover them: (lo - base) / interval rounds in float64 (0.7 / 0.1 = 6.999999999999999), and floor
    # and ceil of a quotient a hair off an integer added a level no height reaches below or above them (heights 0.7
    # to 1.0 at interval 0.1 got an empty level 0.6: level indices from 1, colours shifted, a solid's default floor
    # two intervals down, where heights 7 to 10 at interval 1 got none); in float32, as the kernels compare; after
    # the checks above, so that they refuse what they refused before
    first = int(np.searchsorted(values, np.float32(lo), side="right")) - 1  # the last value at or below lo
    last = int(np.searchsorted(values, np.float32(hi), side="left"))  # the first value at or above hi
    values = values[max(first, 0) : last + 1]
    return _check_span(lo, hi, values)


#: The largest count of intervals float64 holds exactly (2**53): a base that many intervals from zero and from the
#: heights rounds by more than an interval, and ``base + k * interval`` near the heights cancels to that error.
_EXACT_COUNT = 2.0**53


def _unseparated(values: NDArray[np.float32]) -> int | None:
    """The first i whose threshold t_i rounds onto α_i, or None. Only neighbouring float32 values do that (their
    midpoint is a tie, rounded to the even one; between levels two or more float32 steps apart there is a float32
    value the midpoint rounds to): a height exactly on α_i then sits on t_i and steps up to α_i+1 (a flat terrain at
    1e7 with levels [1e7, 1e7 + 1] came back at 1e7 + 1), and where t_i+1 rounds down onto α_i+1 as well the band of
    α_i+1 is empty (t_i = t_i+1: walls stacked on one crossing, a zero-width terrace between them)."""
    if values.size < 2:
        return None
    close = np.flatnonzero(thresholds_of(values) <= values[:-1])
    return int(close[0]) if close.size else None


def _check_span(lo: float, hi: float, values: NDArray[np.float32]) -> NDArray[np.float32]:
    """``values`` when the heights' differences, which the step kernels take in float32 (a crossed threshold lies
    between the edge's two heights), stay finite: heights from -2e38 to 2e38 put a wall's crossing at β = 2e38 / inf
    = 0 instead of 0.5, and from -3e38 to 3e38 at NaN (inf / inf), in a mesh returned without an error."""
    if hi - lo > FLOAT32_MAX:
        raise InvalidInputError(
            f"heights [{lo:g}, {hi:g}] span {hi - lo:.3g}, beyond float32 (3.4e+38): the step kernels take height "
            "differences in float32"
        )
    return values


@dataclass
class StepArrays:
    """The raw result of the two count -> scan -> emit passes (device arrays, local coordinates)."""

    points: wp.array | None  # (V,) vec3: x, y local; z at γ = 0 (None when the pass blended directly)
    step_heights: wp.array | None  # (V,) float32: z at γ = 1, the vertex's isovalue (None: blended, no colours)
    vertices: NDArray[np.float64] | None  # (V, 3) world positions, blended in the pass (step_arrays' gamma)
    sources: wp.array | None  # (V,) vec2i: input nodes the vertex lies between
    betas: wp.array | None  # (V,) float32: position between them
    faces: NDArray[np.int64]
    face_levels: NDArray[np.int32]
    face_walls: NDArray[np.bool_]
    vertex_count: int
    face_count: int
    face_sources: NDArray[np.int64] | None = None  # (F,) the terrain face (a TIN's) each output face was cut from


def thresholds_of(values: NDArray[np.float32]) -> NDArray[np.float32]:
    """t_i = (α_i + α_i+1) / 2, computed in float64 and rounded once to float32: the thresholds :func:`stepped`
    steps at. ``values``: the isovalues, a float32 array (as :func:`isovalues` gives them) or a sequence or array of
    other real numbers, taken as float32 first as the kernels take levels (a float64 array was averaged as it was, and
    its thresholds could lie one float32 step off the kernels')."""
    # a list raised AttributeError ('list' object has no attribute 'astype')
    if not (isinstance(values, np.ndarray) and values.dtype == np.float32):
        numbers = real_numbers(values, "values", "a 1-D sequence of isovalues")
        if numbers.ndim != 1:
            raise InvalidInputError(f"values must be a 1-D sequence of isovalues; got shape {numbers.shape}")
        values = numbers.astype(np.float32)
    v64 = values.astype(np.float64)
    return ((v64[:-1] + v64[1:]) * 0.5).astype(np.float32)


#: Isovalue structs by (values, device): a re-step that goes back and forth between a few intervals reuses their
#: uploads (0.18 ms of a 9.6 ms 512² re-step). The kernels only read them.
_ISOVALUES: dict[tuple[bytes, str], stepped_kernels.Isovalues] = {}
_ISOVALUES_KEPT = 16


def _isovalue_struct(values: NDArray[np.float32], device: wp.Device) -> stepped_kernels.Isovalues:
    # built from the float32 values it is keyed by: thresholds taken from float64 values (step_arrays given them)
    # can round otherwise, and were then served to every later call with the same float32 values
    values = np.ascontiguousarray(values, dtype=np.float32)
    if len(values) > 4096:  # not worth keeping
        return _build_isovalue_struct(values, device)
    key = (values.tobytes(), str(device))
    iso = _ISOVALUES.get(key)
    if iso is None:
        iso = _build_isovalue_struct(values, device)
        if len(_ISOVALUES) >= _ISOVALUES_KEPT:
            _ISOVALUES.clear()
        _ISOVALUES[key] = iso
    return iso


def _build_isovalue_struct(values: NDArray[np.float32], device: wp.Device) -> stepped_kernels.Isovalues:
    thresholds = thresholds_of(values)
    iso = stepped_kernels.Isovalues()
    iso.values = wp.array(values, dtype=wp.float32, device=device)
    iso.thresholds = wp.array(thresholds, dtype=wp.float32, device=device)
    iso.uniform, iso.first, iso.inv_gap = 0, 0.0, 0.0
    gaps = np.diff(thresholds.astype(np.float64))
    if len(gaps) and np.all(np.abs(gaps - gaps.mean()) <= 0.25 * gaps.mean()):
        first, inv_gap = float(thresholds[0]), float(1.0 / gaps.mean())
        # the kernel's inv_gap is float32: gaps below 2.9e-39 (subnormal heights) have none, the binary search serves
        # them (the cast to inf warned "overflow encountered in cast", an error under -W error)
        if inv_gap <= FLOAT32_MAX and _estimate_error(thresholds, np.float32(first),
                                                      np.float32(inv_gap)) <= _ESTIMATE_ERROR_MAX:
            iso.uniform, iso.first, iso.inv_gap = 1, first, inv_gap
    return iso


#: How many levels level_of's linear estimate (kernels/stepped.py) may miss a threshold's count by for
#: :func:`_build_isovalue_struct` to take it; beyond, a binary search.
_ESTIMATE_ERROR_MAX = 2


def _estimate_error(thresholds: NDArray[np.float32], first: np.float32, inv_gap: np.float32) -> int:
    """The most level_of's linear estimate ``(h - first) * inv_gap + 1`` (float32, as the kernel computes it) misses
    the count of thresholds <= h by at a threshold h (between two thresholds, by at most one more): the walk from the
    estimate to the exact level takes that many steps. Gaps each within 25 % of their mean do not bound it: their
    differences add up (thousands of levels in two intervals, or log-spaced, put it hundreds of levels off)."""
    n = len(thresholds)
    with np.errstate(over="ignore", invalid="ignore"):  # thresholds spanning beyond float32 (-3e38 to 3e38): inf, n
        x = (thresholds - first) * inv_gap + np.float32(1.0)
        estimate = np.clip(x, np.float32(0.0), np.float32(n)).astype(np.int64)  # level_of's k: 0, int(x) or n
    return int(np.abs(estimate - np.arange(1, n + 1)).max())


def _grid_struct(terrain: Terrain, device: wp.Device) -> stepped_kernels.HeightField:
    """The grid's kernel struct: the terrain's heights (a frozen Terrain's upload) and this thread's levels scratch.
    The last one a thread built is kept (:func:`~stepterrain._device.thread_structs`) while its terrain lives and
    the levels are the same array (a re-step of one terrain: building it took 0.1 ms as the first struct after a
    gc.collect()); a struct built for another terrain replaces it."""
    rows, cols = terrain.heights.shape
    levels = scratch("stepped.levels", rows * cols, wp.int32, device)  # recomputed by every pass
    structs = thread_structs()
    key = ("stepped.grid", str(device))
    kept = structs.get(key)
    if kept is not None and kept[0]() is terrain and kept[1].levels is levels:
        return kept[1]
    hf = stepped_kernels.HeightField()
    hf.heights = terrain.cached(
        ("heights", str(device)), lambda: to_device(terrain.heights.reshape(-1), wp.float32, device)
    )
    hf.levels = levels
    hf.rows = rows
    hf.cols = cols
    hf.spacing = wp.vec2(terrain.spacing[0], terrain.spacing[1])
    hf.flip = 1 if terrain.spacing[0] * terrain.spacing[1] < 0 else 0
    hf.has_nodata = int(terrain.has_nodata)

    # the terrain is gone: its heights are not kept alive by the struct. The callback names the dict weakly (a
    # strong reference closed a cycle dict -> entry -> weakref -> callback -> dict, which kept the struct and its
    # levels scratch past release_scratch() and the thread's exit until the cyclic gc ran)
    owner = weakref.ref(structs)

    def forget(ref: weakref.ref, owner: weakref.ref = owner, key: tuple = key) -> None:
        kept = owner()
        if kept is not None and kept.get(key, (None,))[0] is ref:
            kept.pop(key, None)

    structs[key] = (weakref.ref(terrain, forget), hf)
    return hf


def _offsets_struct(local: wp.array, bases: wp.array, shift: int, device: wp.Device) -> stepped_kernels.Offsets:
    """The grid passes' Offsets of this thread's scratch ``local`` and ``bases``: the last one kept while they are
    the same arrays (a re-step of one terrain; :func:`~stepterrain._device.thread_structs`)."""
    structs = thread_structs()
    key = ("stepped.offsets", str(device))
    kept = structs.get(key)
    if kept is not None and kept.local is local and kept.bases is bases and kept.shift == shift:
        return kept
    offsets = stepped_kernels.Offsets()
    offsets.local, offsets.bases, offsets.shift = local, bases, shift
    structs[key] = offsets
    return offsets


def _tin_struct(terrain: Terrain, device: wp.Device) -> stepped_kernels.TriangleNetwork:
    def build() -> tuple[wp.array, ...]:
        return (
            to_device(terrain.local_points(), wp.vec3, device),
            to_device(terrain.heights, wp.float32, device),
            to_device(terrain.faces.astype(np.int32), wp.vec3i, device),
            to_device(terrain.face_edges, wp.vec3i, device),
            to_device(terrain.edges, wp.vec2i, device),
            to_device(terrain.point_used, wp.int32, device),
        )

    # the uploads are the terrain's (read-only to the kernels); the levels every pass writes are this thread's
    # scratch, as a grid's: a cached levels array was shared by two threads stepping the same TIN at once
    tin = stepped_kernels.TriangleNetwork()
    tin.points, tin.heights, tin.faces, tin.face_edges, tin.edges, tin.point_used = terrain.cached(
        ("tin", str(device)), build
    )
    tin.levels = scratch("stepped.levels", len(terrain.heights), wp.int32, device)  # recomputed by every pass
    return tin


def step_arrays(
    terrain: Terrain,
    values: NDArray[np.float32],
    *,
    device: wp.Device,
    want_sources: bool = False,
    memory_budget: int | None = None,
    gamma: float | None = None,
    want_steps: bool = False,
    extra_vertex_bytes: int = 0,
    want_face_sources: bool = False,
    solid_boundary: int | None = None,
    hint: str | None = None,
) -> StepArrays:
    """Run the vertex and face count -> scan -> emit passes; see kernels/stepped.py for the conventions.

    The device arrays of the result (points, step heights, sources, betas) are scratch buffers, valid until
    the next call on this thread; the numpy face arrays are the caller's. ``gamma`` (a checked scalar): the
    vertex pass blends as it writes (kernels/stepped.py, DirectBlend) into ``vertices``, the world positions
    :func:`blend` would give, and writes no ``points`` (``step_heights`` only with ``want_steps``).
    ``extra_vertex_bytes``: what the caller adds per vertex (colours), counted against ``memory_budget`` too.
    ``want_face_sources``: a TIN's result also holds, per output face, the terrain face it was cut from (each
    triangle's faces lie at its offset of the face scan), for face colours carried over.
    ``solid_boundary``: for a solid, the most boundary edges its surface can have (:func:`solid_boundary_edges`);
    the solid's skirt and base (:func:`solid_bytes`) are then checked against the budget with the surface.
    ``hint``: what makes the output smaller, in a refusal over the budget or int32's reach, in place of
    :data:`SMALLER_HINT` and the tiles of stepterrain.batch (a caller whose own options do it: a stepped close-up).
    """
    smaller = SMALLER_HINT + _TILES_HINT if hint is None else hint
    budget_hint = SMALLER_HINT if hint is None else hint  # the memory budget's refusal (without the tiles)
    iso = _isovalue_struct(values, device)
    grid = terrain.kind == "grid"
    topo: Any = _grid_struct(terrain, device) if grid else _tin_struct(terrain, device)
    n_nodes = terrain.heights.size
    scale = GRID_CHUNK_FACTOR if grid else 1  # the grid passes' chunk (count_grid's Offsets take its shift)
    # vertex quantization (§3.2): every node's level
    launch_chunked(
        stepped_kernels.quantize_levels,
        n=n_nodes,
        inputs=[topo.heights, iso],
        outputs=[topo.levels],
        device=device,
        scale=scale,
    )
    empty_faces = no_elements(stepped_kernels.vec3l, device)
    empty_levels = no_elements(wp.int32, device)
    empty_walls = no_elements(wp.uint8, device)
    if grid:
        # pass 1 on a grid, one kernel over chunks of nodes: vertices (nodes, their twins, wall bottom/top pairs per
        # edge crossing) as prefixes within each chunk, and the chunk's vertex and face totals; only the totals
        # are scanned (kernels/stepped.py, Offsets). The faces of chunks with a cell that needs the vertex offsets
        # to be counted are counted after that scan.
        n_slots, n_cells = 4 * n_nodes, (topo.rows - 1) * (topo.cols - 1)
        if n_slots > _MAX_INT32:  # the kernels index slot 4·n (+ 0..3) in int32: past it count_grid wrote out of bounds
            raise OutputTooLargeError(
                f"a grid of {topo.rows} x {topo.cols} nodes needs {n_slots:,} int32 vertex slots (4 a node), more "
                f"than the {_MAX_INT32:,} one call can index; {smaller}"
            )
        n_chunks = chunked_threads(n_nodes, device, scale)
        local = scratch("stepped.vertices.local", n_slots, wp.int32, device, streamed=True)
        totals = count_buffer("stepped.vertices", n_chunks, device)
        face_totals = count_buffer("stepped.faces", n_chunks, device)
        deferred = scratch("stepped.deferred", n_chunks, wp.int32, device)
        launch_chunked(stepped_kernels.count_grid, n=n_nodes, inputs=[topo, iso],
                       outputs=[local, totals, face_totals, deferred], device=device, fence=True,
                       scale=scale)  # fmt: skip  # streams local
        bases, vertex_count = exclusive_offsets(totals, "stepped.vertices")
        offsets = _offsets_struct(local, bases, chunk_shift(device, scale) + 2, device)  # 4 slots a node
        _check_vertex_total(totals, n_nodes, n_slots, len(values), hint)
        launch_chunked(
            stepped_kernels.count_deferred_grid_faces,
            n=n_nodes,
            inputs=[topo, iso, offsets, deferred, empty_faces, empty_levels, empty_walls],
            outputs=[face_totals],
            device=device,
            scale=scale,
        )
        face_counts = face_totals
        face_offsets, face_count = exclusive_offsets(face_totals, "stepped.faces")
    else:
        n_slots = n_nodes + len(terrain.edges)
        n_cells = len(terrain.faces)
        twins = wp.zeros(n_nodes, dtype=wp.int32, device=device)
        peers = wp.zeros(n_nodes, dtype=wp.int32, device=device)
        launch_chunked(
            stepped_kernels.mark_tin_twins,
            n=len(terrain.edges),
            inputs=[topo, iso],
            outputs=[twins, peers],
            device=device,
        )
        # pass 1: vertices (nodes, their twins, wall bottom/top pairs per edge crossing)
        counts = count_buffer("stepped.vertices", n_slots, device)
        launch_chunked(stepped_kernels.count_tin_vertices, n=n_slots, inputs=[topo, iso, twins, peers],
                       outputs=[counts], device=device)  # fmt: skip
        offsets, vertex_count = exclusive_offsets(counts, "stepped.vertices")
        _check_vertex_total(counts, n_nodes, n_slots, len(values), hint)
        # pass 2: faces (terraces and walls per triangle), counted against the vertex offsets
        face_counts = count_buffer("stepped.faces", n_cells, device)
        launch_chunked(
            stepped_kernels.count_tin_faces,
            n=n_cells,
            inputs=[topo, iso, offsets, empty_faces, empty_levels, empty_walls],
            outputs=[face_counts],
            device=device,
        )
        face_offsets, face_count = exclusive_offsets(face_counts, "stepped.faces")
    want_face_sources = want_face_sources and not grid
    # per triangle and band a polygon of at most 5 vertices (3 terraces), 2 wall faces per threshold
    _check_int32_total(face_counts, (2 if grid else 1) * n_cells * 5 * len(values), "faces", hint)

    vertex_bytes = _VERTEX_BYTES + (_SOURCE_BYTES if want_sources else 0) + int(extra_vertex_bytes)
    face_bytes = _FACE_BYTES + (_FACE_SOURCE_BYTES if want_face_sources else 0)
    surface_bytes = vertex_count * vertex_bytes + face_count * face_bytes
    if solid_boundary is None:
        check_budget(surface_bytes, f"the stepped mesh ({vertex_count:,} vertices, {face_count:,} faces)",
                     memory_budget, hint=budget_hint, mesh=(vertex_count, face_count))
    else:
        check_budget(
            surface_bytes + solid_bytes(vertex_count, face_count, solid_boundary),
            f"the stepped solid (a surface of {vertex_count:,} vertices and {face_count:,} faces, up to "
            f"{solid_boundary:,} boundary edges for its skirt, and its base)",
            # the most the closed solid has: a --png render's advice from the surface's counts alone was too low for
            # the solid (steps --solid --png refused again after its budget was raised)
            memory_budget, hint=budget_hint, mesh=_solid_counts(vertex_count, face_count, solid_boundary),
        )
    face_sources = None
    if want_face_sources:
        face_sources = np.repeat(np.arange(n_cells, dtype=np.int64), np.diff(host_copy(face_offsets)[:n_cells + 1]))

    direct = stepped_kernels.DirectBlend()
    direct.points, direct.steps = 1, 1
    vertices_np = None
    if gamma is not None:
        vertices_np, direct.vertices = empty_shared((vertex_count, 3), np.float64, wp.vec3d, device, streamed=True)
        direct.gamma, direct.origin, direct.points, direct.steps = gamma, _local_origin3(terrain), 0, int(want_steps)
    else:
        direct.vertices = no_elements(wp.vec3d, device)
    points = scratch("stepped.points", vertex_count * direct.points, wp.vec3, device)
    step_heights = scratch("stepped.step_heights", vertex_count * direct.steps, wp.float32, device)
    n_src = vertex_count if want_sources else 0
    sources = scratch("stepped.sources", n_src, wp.vec2i, device)
    betas = scratch("stepped.betas", n_src, wp.float32, device)
    # the face pass streams faces and levels (kernels/memory.py, stream), as the direct blend does the vertices
    faces_np, faces_wp = empty_shared((face_count, 3), np.int64, stepped_kernels.vec3l, device, streamed=True)
    levels_np, levels_wp = empty_shared((face_count,), np.int32, wp.int32, device, streamed=True)
    walls_np, walls_wp = empty_shared((face_count,), np.uint8, wp.uint8, device)
    vertex_outputs = [points, step_heights, sources, betas]
    face_outputs = [faces_wp, levels_wp, walls_wp]
    if grid:  # both emit passes in one walk over the count's chunks of nodes
        launch_chunked(stepped_kernels.emit_grid, n=n_nodes, inputs=[topo, iso, offsets, face_offsets,
                       int(want_sources), direct], outputs=vertex_outputs + face_outputs, device=device,
                       fence=True, scale=scale)  # fmt: skip
    else:
        launch_chunked(stepped_kernels.emit_tin_vertices, n=n_slots, inputs=[topo, iso, offsets, twins,
                       int(want_sources), direct], outputs=vertex_outputs, device=device,
                       fence=gamma is not None)  # fmt: skip
        launch_chunked(stepped_kernels.emit_tin_faces, n=n_cells, inputs=[topo, iso, offsets, face_offsets],
                       outputs=face_outputs, device=device, fence=True)  # fmt: skip
    return StepArrays(
        points=points if direct.points else None,
        step_heights=step_heights if direct.steps else None,
        vertices=None if vertices_np is None else to_numpy(vertices_np, direct.vertices, (vertex_count, 3)),
        sources=sources if want_sources else None,
        betas=betas if want_sources else None,
        faces=to_numpy(faces_np, faces_wp, (face_count, 3)),
        face_levels=to_numpy(levels_np, levels_wp, (face_count,)),
        face_walls=to_numpy(walls_np, walls_wp, (face_count,)).view(np.bool_),
        vertex_count=vertex_count,
        face_count=face_count,
        face_sources=face_sources,
    )


def solid_boundary_edges(t: Terrain, values: NDArray[np.float32]) -> int:
    """At most how many boundary edges the stepped surface of ``t`` has (the edges a solid's skirt hangs from), from
    the heights alone, before stepping: per terrain edge that can lie on the boundary of the triangles, 2 k + 3 for its
    k crossed thresholds (k walls' vertical sides and the k + 1 pieces between them, and a twin's vertical edge at
    either end; §3.2: a node's level is the count of thresholds at or below its height). A grid's candidates are its
    outer ring and every side and diagonal of a cell with both heights and nodata; a TIN's, the edges of one face. An
    edge with a nodata end is in no triangle."""
    thresholds = thresholds_of(values)

    def edges(a: NDArray[np.float32], b: NDArray[np.float32]) -> int:
        ok = np.isfinite(a) & np.isfinite(b)
        a, b = a[ok], b[ok]
        k = np.abs(np.searchsorted(thresholds, a, side="right") - np.searchsorted(thresholds, b, side="right"))
        return int(2 * k.sum(dtype=np.int64)) + 3 * len(k)

    if t.kind != "grid":
        if t.edges is None or t.face_edges is None or len(t.edges) == 0:
            return 0
        once = np.bincount(t.face_edges.reshape(-1), minlength=len(t.edges)) == 1
        ends = t.edges[once]
        return edges(t.heights[ends[:, 0]], t.heights[ends[:, 1]])
    h = t.heights
    if h.shape[0] < 2 or h.shape[1] < 2:
        return 0
    total = (edges(h[0, :-1], h[0, 1:]) + edges(h[-1, :-1], h[-1, 1:])
             + edges(h[:-1, 0], h[1:, 0]) + edges(h[:-1, -1], h[1:, -1]))  # fmt: skip
    if t.has_nodata:  # a hole's boundary runs along the cells that touch it and hold a height too (the edges of a
        # cell wholly nodata count nothing); rows a block at a time: this runs before the budget is checked, and a
        # sea of nodata made index and height arrays for each of its cells (~30 bytes a node)
        block = max(1, _SOLID_BOUNDARY_BLOCK // h.shape[1])
        for r0 in range(0, h.shape[0] - 1, block):
            rows = h[r0:r0 + block + 1]  # the cells of rows r0 .. r0 + block - 1 and their lower and upper nodes
            bad = ~np.isfinite(rows)
            cell_bad = bad[:-1, :-1] | bad[1:, :-1] | bad[:-1, 1:] | bad[1:, 1:]
            cell_bad &= ~(bad[:-1, :-1] & bad[1:, :-1] & bad[:-1, 1:] & bad[1:, 1:])
            r, c = np.nonzero(cell_bad)
            h00, h01, h10, h11 = rows[r, c], rows[r, c + 1], rows[r + 1, c], rows[r + 1, c + 1]
            total += sum(edges(a, b) for a, b in ((h00, h01), (h10, h11), (h00, h10), (h01, h11), (h00, h11),
                                                  (h01, h10)))
    return total


def _solid_counts(vertex_count: int, face_count: int, boundary_edges: int) -> tuple[int, int]:
    """The most (vertices, faces) :func:`~stepterrain.mesh.close_solid` gives a stepped surface of ``vertex_count``
    vertices and ``face_count`` faces with at most ``boundary_edges`` boundary edges: its copy of the surface, at
    most one copy of a vertex per boundary edge at a pinch and one base vertex per vertex; a base face per terrace
    and at most 3 skirt faces per boundary edge."""
    v, f, b = int(vertex_count), int(face_count), int(boundary_edges)
    return 2 * (v + b), f + (f + 3 * b)


def solid_bytes(vertex_count: int, face_count: int, boundary_edges: int) -> int:
    """At most the bytes :func:`~stepterrain.mesh.close_solid` and :func:`stepped`'s assembly allocate to close a
    stepped surface of ``vertex_count`` vertices and ``face_count`` faces with at most ``boundary_edges`` boundary
    edges (:func:`solid_boundary_edges`) into a solid, beyond the surface's own arrays: the closed mesh (its most
    vertices and faces, :func:`_solid_counts`) with its levels, walls and visual, and the work arrays of building
    it."""
    v, f = int(vertex_count), int(face_count)
    vertices, faces = _solid_counts(v, f, boundary_edges)
    work = _SOLID_WORK_FACE_BYTES * f + _SOLID_WORK_VERTEX_BYTES * v + (_SOLID_WORK_FIXED if f else 0)
    return vertices * _SOLID_VERTEX_BYTES + faces * _SOLID_FACE_BYTES + work


def _check_vertex_total(counts: wp.array, n_nodes: int, n_slots: int, n_levels: int, hint: str | None = None) -> None:
    # at most 2 per node and 2 per crossed threshold per edge
    _check_int32_total(counts, 2 * n_nodes + 2 * (n_levels - 1) * (n_slots - n_nodes), "vertices", hint)


def _check_int32_total(counts: wp.array, bound: int, what: str, hint: str | None = None) -> None:
    """Refuse a count pass whose int32 scan may have wrapped: where ``bound`` (the most the counts can add up
    to) exceeds int32, they are summed in int64 on the host, and a total beyond int32 raises with its size and
    ``hint`` (default :data:`SMALLER_HINT`)."""
    if bound <= _MAX_INT32:
        return
    total = int(host_copy(counts).sum(dtype=np.int64))
    if total > _MAX_INT32:
        raise OutputTooLargeError(
            f"the stepped mesh would have {total:,} {what}, more than the {_MAX_INT32:,} one call can index; "
            + (SMALLER_HINT if hint is None else hint)
        )


def _local_origin3(terrain: Terrain) -> wp.vec3d:
    ox, oy = terrain.local_origin
    return wp.vec3d(ox, oy, 0.0)


def blend(
    terrain: Terrain,
    arrays: StepArrays,
    gamma: GammaLike,
    *,
    device: wp.Device,
) -> NDArray[np.float64]:
    """World vertex positions (V, 3) float64 for γ: a scalar, per-node values, a callable or a :class:`Lens`."""
    n = arrays.vertex_count
    gammas = no_elements(wp.float32, device)
    scalar = 1.0
    origin = _local_origin3(terrain)
    plain = _plain_gamma(gamma)
    if plain is not None:
        scalar = plain
    elif isinstance(gamma, Lens):
        lower, size = _lens_frame(terrain, gamma)  # within float32 (_check_lens_reach)
        gammas = wp.empty(n, dtype=wp.float32, device=device)
        launch_chunked(
            stepped_kernels.sample_lens,
            n=n,
            inputs=[
                to_device(gamma.mask, wp.float32, device).reshape(gamma.mask.shape),
                wp.vec2(*lower),
                wp.vec2(*size),
                arrays.points,
            ],
            outputs=[gammas],
            device=device,
        )
    elif callable(gamma):
        original = np.empty((n, 3), dtype=np.float64)
        original[:] = host_copy(arrays.points)
        original[:, 0] += terrain.local_origin[0]
        original[:, 1] += terrain.local_origin[1]
        try:
            with scratch_aside():  # the passes' scratch arrays, read below and by _assemble, stay this call's
                result = gamma(original)
        except Exception as exc:  # the caller's error, named as gamma's: it surfaced from deep inside stepped()
            raise InvalidInputError(
                f"gamma, a callable of the (V, 3) output vertex positions, raised {type(exc).__name__}: {exc}"
            ) from exc
        values = _gamma_floats(result, "gamma(points)")
        gammas = wp.array(_check_gamma_values(values, (n,), "gamma(points)"), dtype=wp.float32, device=device)
    elif _gamma_ndim(gamma) == 0:
        scalar = float(_check_gamma_values(_gamma_floats(gamma, "gamma"), (), "gamma"))
    else:
        values = _gamma_floats(gamma, "gamma")
        if values.shape == terrain.shape:
            values = _unread_nan_filled(terrain, values)
        node_values = _check_gamma_values(values, terrain.shape, "gamma")
        gammas = wp.empty(n, dtype=wp.float32, device=device)
        launch_chunked(
            stepped_kernels.interpolate_node_values,
            n=n,
            inputs=[to_device(node_values.reshape(-1), wp.float32, device), arrays.sources, arrays.betas],
            outputs=[gammas],
            device=device,
        )
    vertices_np, vertices_wp = empty_shared((n, 3), np.float64, wp.vec3d, device, streamed=True)
    launch_chunked(
        stepped_kernels.blend_vertices,
        n=n,
        inputs=[arrays.points, arrays.step_heights, gammas, scalar, origin],
        outputs=[vertices_wp],
        device=device,
        fence=True,
    )
    return to_numpy(vertices_np, vertices_wp, (n, 3))


def _unread_nan_filled(terrain: Terrain, values: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-node γ ``values`` (the terrain's shape) with 0 for NaN where no output vertex reads the node: nodata (γ
    computed from h), a grid node with a height on no triangle with three finite heights (a lone pixel in a void:
    :func:`~stepterrain.terrain.used_nodes`, as the step kernels take edges only from such triangles), a TIN point on
    no kept face (one left by ``mesh.update_faces``, or welded into an earlier copy). NaN at a node the surface uses
    stays, for :func:`_check_gamma_values` to refuse with its index."""
    nan = np.isnan(values)
    if not nan.any():
        return values
    return np.where(nan & ~terrain._used_mask(), 0.0, values)


def _gamma_floats(value: Any, name: str) -> NDArray[np.float64]:
    """γ (``name`` "gamma") or a γ callable's result ("gamma(points)") as float64 through :func:`real_numbers`:
    text ("0.5"), bools and complex values are refused (numpy took them, dropping an imaginary part), and a masked
    entry is NaN, refused by :func:`_check_gamma_values` (numpy dropped the mask)."""
    expected = ("a number in [0, 1], an array of them, a callable or a Lens" if name == "gamma"
                else "a number in [0, 1] per output vertex")
    try:
        return real_numbers(value, name, expected)
    except InvalidInputError:
        if isinstance(value, np.ndarray):  # real_numbers names its dtype or the bool, which its repr may not show
            raise
        raise InvalidInputError(f"{name} must be {expected}; got {value!r:.80}") from None
    except Exception as exc:  # an object numpy cannot read (a GPU tensor's __array__ raises TypeError): name it
        raise InvalidInputError(f"{name} must be {expected}; got a {type(value).__name__} that numpy cannot read "
                                f"({type(exc).__name__}: {exc})") from exc


def _check_gamma_values(values: NDArray[np.float64], shape: tuple[int, ...], name: str) -> NDArray[np.float32]:
    if values.shape != shape:
        if name != "gamma":  # a callable's result
            what = f"shape {shape} (one γ per output vertex)"
        else:
            what = ("a scalar" if shape == ()
                    else f"shape {shape} (one γ per terrain node) or a scalar, a callable or a Lens")
        raise InvalidInputError(f"{name} must be {what}; got shape {values.shape}")
    if values.size and not np.isfinite(values).all():  # NaN: also a masked entry
        at = first_index(~np.isfinite(values))
        raise InvalidInputError(f"{name} must lie in [0, 1] (0 = original, 1 = stepped); got {float(values[at])}"
                                + (f" at index {at}" if at else ""))
    if values.size and (values.min() < 0.0 or values.max() > 1.0):
        raise InvalidInputError(f"{name} must lie in [0, 1] (0 = original, 1 = stepped); got values in "
                                f"[{values.min()}, {values.max()}]")
    return np.require(values.astype(np.float32), requirements="C")


def _gamma_ndim(gamma: GammaLike) -> int:
    """0 for a scalar γ, the array's dimensions otherwise; a ragged sequence is an :class:`InvalidInputError`."""
    try:
        return int(np.ndim(gamma))
    except Exception:  # ragged nested sequences (ValueError), an unreadable object: _gamma_floats names them
        return _gamma_floats(gamma, "gamma").ndim


def _plain_gamma(gamma: GammaLike) -> float | None:
    """A Python float γ in [0, 1] as the checked scalar (``_check_gamma_values`` of it: its float32 value), else None
    for the full checks (NaN fails here too). The common case of a re-step, without their numpy calls: 5 µs of a
    512² re-step when hot, several times that when the caches are cold (RESULTS.md "Session 26")."""
    if type(gamma) is float and 0.0 <= gamma <= 1.0:
        return float(np.float32(gamma))
    return None


def _direct_blend(gamma: GammaLike, colors: Any) -> dict[str, Any]:
    """:func:`step_arrays`' keywords for a scalar γ, checked: the vertex pass blends as it writes (one pass over
    the vertices instead of two; at 2048² with 20 steps blend_vertices took 17 ms); step heights only for
    colours. Other γ (per node, a callable, a lens) are left to :func:`blend`."""
    plain = _plain_gamma(gamma)
    if plain is not None:
        return {"gamma": plain, "want_steps": colors is not None}
    if isinstance(gamma, Lens) or callable(gamma) or _gamma_ndim(gamma) != 0:
        return {}
    return {"gamma": float(_check_gamma_values(_gamma_floats(gamma, "gamma"), (), "gamma")),
            "want_steps": colors is not None}  # fmt: skip


def _stepped_arrays(t: Terrain, values: NDArray[np.float32], gamma: GammaLike, colors: Any, device: wp.Device,
                    memory_budget: int | None = None, solid: bool = False,
                    hint: str | None = None) -> tuple[StepArrays, NDArray[np.float64]]:
    """The passes of :func:`stepped` and :func:`stepped_series`: the arrays and the blended world vertices (a
    scalar γ blended in the vertex pass, any other by :func:`blend`); the colours, and a ``solid``'s skirt and base,
    counted against the budget."""
    if isinstance(gamma, Lens):
        _check_lens_reach(t, gamma)  # before the passes: blend samples it in float32
    arrays = step_arrays(t, values, device=device, want_sources=_needs_sources(t, gamma, colors),
                         memory_budget=memory_budget, extra_vertex_bytes=0 if colors is None else _COLOR_BYTES,
                         want_face_sources=colors is None and t.face_index is not None,
                         solid_boundary=solid_boundary_edges(t, values) if solid else None, hint=hint,
                         **_direct_blend(gamma, colors))  # fmt: skip
    vertices = arrays.vertices if arrays.vertices is not None else blend(t, arrays, gamma, device=device)
    return arrays, vertices


def _lens_frame(terrain: Terrain, lens: Lens) -> tuple[tuple[float, float], tuple[float, float]]:
    """The lower corner of ``lens``'s extent relative to the terrain's local origin and the extent's size, in float64,
    as :func:`blend` passes them to kernels/stepped.py's sample_lens (a size below 1e-30 raised to it)."""
    xmin, xmax, ymin, ymax = lens.extent if lens.extent is not None else terrain.extent
    ox, oy = terrain.local_origin
    return (xmin - ox, ymin - oy), (max(xmax - xmin, 1e-30), max(ymax - ymin, 1e-30))


def _check_lens_reach(terrain: Terrain, lens: Lens) -> None:
    """Refuse a lens whose extent is wider or taller than float32 holds: sample_lens takes its size in float32, and
    an infinite size put every vertex at the mask's first column or row ((p - lower) / inf = 0; with an infinite
    corner too, inf / inf = NaN), a wrong γ without a word (an extent of ±2e38 read the mask's corner, not its centre
    over the terrain). A corner beyond float32 with a size within it is no error: the corner is ±inf in float32,
    (p - lower) / size = ∓inf, and every vertex takes the mask edge facing the terrain, as it should (the lens lies
    wholly to one side: the vertices' local x, y are float32)."""
    _, (width, height) = _lens_frame(terrain, lens)
    if max(width, height) > FLOAT32_MAX:
        extent = lens.extent if lens.extent is not None else terrain.extent
        raise InvalidInputError(
            f"gamma: the lens extent (xmin, xmax, ymin, ymax) must be at most {FLOAT32_MAX:.8g} wide and tall (the "
            f"lens is sampled in float32); got {tuple(float(v) for v in extent)!r}, {width:.8g} wide and "
            f"{height:.8g} tall"
        )


def _needs_sources(terrain: Terrain, gamma: GammaLike, colors: Any) -> bool:
    if type(gamma) is float and terrain.visual is None:  # a scalar γ, nothing carried over
        return False
    per_node_gamma = not isinstance(gamma, Lens) and not callable(gamma) and _gamma_ndim(gamma) > 0
    # face colours follow the faces (StepArrays.face_sources), not the vertices
    carries_visual = terrain.visual is not None and colors is None and terrain.face_index is None
    return per_node_gamma or carries_visual


#: Where a colormap's land colours start: matplotlib's 'terrain' spends its first quarter on sea blues, which
#: would paint the lowest land levels as water. Shared by :func:`stepped`, ``batch`` and the CLI.
LAND_START: dict[str, float] = {"terrain": 0.25}


def land_range(name: str) -> tuple[float, float]:
    """The part (lo, hi) of the colormap ``name`` holding its land colours: from :data:`LAND_START` up for a map
    listed there, and its mirror, up to ``1 - LAND_START``, for the reversed map (matplotlib's ``"<name>_r"``, whose
    sea blues are its last quarter: 'terrain_r' drew the highest ground as water); (0, 1) for any other."""
    if isinstance(name, str) and name.endswith("_r") and name[:-2] in LAND_START:
        return 0.0, 1.0 - LAND_START[name[:-2]]
    return (LAND_START.get(name, 0.0) if isinstance(name, str) else 0.0), 1.0


def colormap(name: str, *, argument: str = "colors", hint: str = "") -> tuple[Any, float, float]:
    """The matplotlib colormap ``name`` and the part (lo, hi) of it holding its land colours (:func:`land_range`); an
    unknown name is an :class:`InvalidInputError` naming ``argument`` (and ``hint``, e.g. " or 'none'")."""
    import matplotlib

    try:
        cmap = matplotlib.colormaps[name]
    except (KeyError, TypeError):  # TypeError: an unhashable value (a list, an array) as the name
        raise InvalidInputError(
            f"{argument} must name a matplotlib colormap (e.g. 'terrain', 'viridis'){hint}; got {name!r}"
        ) from None
    return (cmap, *land_range(name))


def colormap_samples(name: str, n_levels: int, *, argument: str = "colors") -> NDArray[np.float64]:
    """(L, 4) float RGBA sampled evenly from the land part of a matplotlib colormap (:func:`land_range`)."""
    cmap, lo, hi = colormap(name, argument=argument)
    samples = np.linspace(lo, hi, n_levels) if n_levels > 1 else np.array([(lo + hi) / 2])
    return np.asarray(cmap(samples), dtype=np.float64)


def _level_colors(colors: Any, n_levels: int) -> NDArray[np.uint8]:
    """An (L, 4) uint8 table: a matplotlib colormap name, or explicit (L, 3|4) colors (0-1 floats or 0-255)."""
    if isinstance(colors, str):
        return (colormap_samples(colors, n_levels) * 255 + 0.5).astype(np.uint8)
    table = as_array(colors, "colors", f"a colormap name or one RGB(A) row per isovalue, shape ({n_levels}, 3|4)")
    if table.ndim != 2 or table.shape[0] != n_levels or table.shape[1] not in (3, 4):
        raise InvalidInputError(
            f"colors must be a colormap name or one RGB(A) row per isovalue, shape ({n_levels}, 3|4); "
            f"got shape {table.shape}"
        )
    # np.asarray dropped a masked array's mask (the values under it coloured their levels) and made a bool beside
    # numbers 1 ([1, True, 0] a near-black green): refused, as every other numeric argument refuses them
    masked = np.ma.getmaskarray(colors) if np.ma.isMaskedArray(colors) else None
    if masked is not None and masked.any():
        raise InvalidInputError(f"colors must be numbers (0-1 floats or 0-255 integers); got a masked entry at index "
                                f"{first_index(masked)}")
    at = _first_bool(colors) if isinstance(colors, (list, tuple)) else None
    if at is not None:
        raise InvalidInputError(f"colors must be numbers (0-1 floats or 0-255 integers); got a bool ({at[1]!r}) at "
                                f"index {at[0]}")
    if np.issubdtype(table.dtype, np.floating):
        if not np.all(np.isfinite(table)) or table.min() < 0 or table.max() > 1:
            raise InvalidInputError(f"float colors must lie in [0, 1]; got values from {table.min()} to {table.max()}")
        table = (table * 255 + 0.5).astype(np.uint8)
    elif is_real_dtype(table.dtype) and table.dtype != np.uint8:  # other integers (not timedelta64, not bools)
        if table.min() < 0 or table.max() > 255:
            raise InvalidInputError(f"integer colors must lie in [0, 255]; got values from {table.min()} to "
                                    f"{table.max()}")
    elif not np.issubdtype(table.dtype, np.uint8):
        raise InvalidInputError(f"colors must be numbers (0-1 floats or 0-255 integers); got dtype {table.dtype}")
    table = table.astype(np.uint8)
    if table.shape[1] == 3:
        table = np.concatenate([table, np.full((n_levels, 1), 255, np.uint8)], axis=1)
    return table


def _check_carried_visual(terrain: Terrain) -> None:
    """Refuse, before the passes, texture coordinates :func:`_carry_visual` cannot interpolate: not one (u, v) row
    per TIN vertex or grid node (trimesh keeps a short ``visual.uv``; indexing it raised an IndexError after the
    kernels ran); and face colours with no row for some face, or vertex colours with fewer rows than the points (a
    ``ColorVisuals(face_colors=...)`` or ``ColorVisuals(vertex_colors=...)`` built apart from the mesh keeps the rows
    given; short vertex colours are welded by position alone, which gave a point a coincident one's colour)."""
    visual = terrain.visual
    if terrain.face_index is not None and len(terrain.face_index):
        n_colors, needed = len(visual.face_colors), int(terrain.face_index.max()) + 1
        if n_colors < needed:
            raise InvalidInputError(
                f"terrain mesh visual.face_colors must hold one RGBA row per face (at least {needed}) to be carried "
                f"onto the steps; got {counted(n_colors, 'row')} (give colors= to colour the steps instead)"
            )
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        n_colors, needed = len(visual.vertex_colors), terrain.heights.size  # a TIN's points, a grid's nodes
        if n_colors < needed:  # _carry_visual indexes them by point: numpy's IndexError after the passes
            named = "terrain mesh" if terrain.kind == "tin" else "terrain"
            raise InvalidInputError(
                f"{named} visual.vertex_colors must hold one RGBA row per vertex (at least {needed}) to be "
                f"carried onto the steps; got {counted(n_colors, 'row')} (give colors= to colour the steps instead)"
            )
    if isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        uv, needed = np.asarray(visual.uv), terrain.heights.size  # a TIN's points, a grid's nodes (len(points): None)
        if uv.ndim != 2 or len(uv) != needed:
            named = "terrain mesh" if terrain.kind == "tin" else "terrain"
            raise InvalidInputError(
                f"{named} visual.uv must hold one (u, v) row per vertex, shape ({needed}, 2), to be carried onto the "
                f"steps; got shape {uv.shape} (give colors= to colour the steps instead)"
            )


def _carry_visual(terrain: Terrain, arrays: StepArrays) -> Any:
    """Input vertex colors or UVs interpolated onto the output vertices with the crossings' β; a TIN's face colours
    onto the faces cut from each of its triangles (terraces and walls alike)."""
    visual = terrain.visual
    if terrain.face_index is not None and arrays.face_sources is not None:
        rgba = np.asarray(visual.face_colors, dtype=np.uint8)
        return trimesh.visual.ColorVisuals(face_colors=rgba[terrain.face_index[arrays.face_sources]])
    if arrays.sources is None:
        return None
    sources = host_copy(arrays.sources)
    betas = host_copy(arrays.betas).astype(np.float64)[:, None]
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        rgba = np.asarray(visual.vertex_colors, dtype=np.float64)
        mixed = (1 - betas) * rgba[sources[:, 0]] + betas * rgba[sources[:, 1]]
        return trimesh.visual.ColorVisuals(vertex_colors=np.clip(mixed + 0.5, 0, 255).astype(np.uint8))
    if isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        uv = np.asarray(visual.uv, dtype=np.float64)
        mixed = (1 - betas) * uv[sources[:, 0]] + betas * uv[sources[:, 1]]
        return trimesh.visual.TextureVisuals(uv=mixed, material=visual.material)
    return None


def stepped(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    *,
    interval: float | None = None,
    levels: ArrayLike | None = None,
    base: float = 0.0,
    gamma: GammaLike = 1.0,
    colors: str | ArrayLike | None = None,
    solid: bool = False,
    floor: float | None = None,
    spacing: ArrayLike | None = None,
    origin: ArrayLike | None = None,
    memory_budget: int | None = None,
    device: wp.DeviceLike = None,
    _budget_hint: str | None = None,
) -> trimesh.Trimesh:
    """Stepped terrain: quantize heights to isovalues and tessellate every triangle into terraces and walls.

    Parameters
    ----------
    terrain : Terrain, trimesh.Trimesh or (H, W) array_like
        A heightfield (NaN = nodata, giving holes), a :class:`Terrain` from :func:`load_dem`, or a TIN whose
        faces project one-to-one onto the xy plane.
    interval, levels, base
        Exactly one of ``interval`` (uniform isovalues ``base + k * interval`` covering the heights) or
        ``levels`` (explicit, strictly increasing; non-uniform allowed), with no default (the CLI's ``steps``
        picks a round ``--interval`` giving about 15 steps). Heights outside the levels clamp to the end levels.
    gamma : float, (H, W) / (N,) array, callable or Lens
        The blend of §3.3 in [0, 1]: 0 = original surface, 1 = fully stepped. An array gives one γ per
        terrain node (interpolated onto wall vertices with the crossing's β; NaN where no vertex reads it: a nodata
        node, a node with a height on no triangle with three finite heights, a TIN point on no face); a callable
        receives the
        (V, 3) world positions of the output vertices on the original surface and returns (V,) values;
        a :class:`Lens` (see :func:`circular_lens`) is a γ image over the xy extent.
    colors : str or (L, 3|4) array, optional
        Hypsometric vertex colors by level: a matplotlib colormap name (sampled evenly over its land colours:
        'terrain' without its sea-blue first quarter, see :data:`LAND_START`) or one color per isovalue. By default
        the input's vertex colors or UVs (a TIN with a visual) are carried over, and a TIN's face colours onto the
        faces cut from each triangle; on a solid the skirt and base are grey, or take the UVs of the surface above them.
        (The CLI's ``steps --colormap`` defaults to 'terrain': ``colors="terrain"`` here.)
    solid : bool
        Close the surface with side skirts and a flat base at ``floor`` (default: one interval below the
        lowest isovalue or the lower surface that γ < 1 gives under explicit ``levels``; with ``levels``, a
        tenth of their span, at least 0.1; at least one float32 step: :func:`default_floor`): a watertight,
        consistently wound volume for 3D printing, also where heights sit on a threshold (they are stepped from a
        little above it: see Notes), and over a TIN's seams (points kept apart for their vertex colours or UVs are
        welded by position, taking the first copy's: one colour or UV per vertex, so the faces beside a seam blend
        the colours or smear the texture, with a warning). A ``floor`` not below the surface's lowest point (in
        float32 too: a floor that rounds onto it leaves the solid no thickness there in an .stl or a .glb) is
        refused; before stepping where the heights tell that point (the lowest height a triangle uses blended with
        its isovalue at a scalar γ; with a varying γ, a floor above both).
    floor : float, optional
        The base height of a ``solid`` (default above); refused without ``solid=True``.
    spacing, origin : (dx, dy), (x0, y0)
        Grid geometry when ``terrain`` is a raw array (default (1, 1) and (0, 0)).
    memory_budget : int, optional
        Bytes the output may take (default :func:`get_memory_budget`); checked after the count pass, before the
        output is allocated: vertices, faces and their work arrays, and the colours when ``colors`` is given. A
        solid counts its skirt and base too, with the work of building them (at most
        :func:`~stepterrain.stepped.solid_bytes`: about 4-5 times the surface's bytes, the skirt's share growing
        with the levels crossed along the boundary), before the surface is allocated.
    device : warp device, optional
        ``"cpu"``, ``"cuda:0"``, ... (default: Warp's default device).

    Returns
    -------
    trimesh.Trimesh
        One welded, indexed mesh (``process=False``). ``face_attributes["level"]`` holds each face's level
        index (a wall's lower level; -1 on a solid's skirts and base, which ``wall`` does not mark) and
        ``face_attributes["wall"]`` marks walls. ``metadata`` records the isovalues, γ, source and CRS (a
        ``trimesh.Trimesh`` TIN's: its own ``metadata["crs"]`` and ``["source"]``, as a file read back by
        :func:`~stepterrain.export.read_mesh` names them, which :meth:`Terrain.from_mesh` carries; a CRS in degrees
        or feet as the local metres' or metre twin it places the points in).

    Raises
    ------
    InvalidInputError
        Bad heights, isovalues, γ, colors or floor (see :func:`isovalues`).
    OutputTooLargeError
        The predicted output exceeds the memory budget, or what one call's int32 indices hold (2^31 - 1 vertices
        or faces; a grid of at most 2^29 - 1 nodes, 4 vertex slots a node), whatever the budget.

    Notes
    -----
    Every node snaps to its nearest isovalue; a height exactly on a threshold t_i = (α_i + α_i+1) / 2 belongs to the
    upper level (real DEMs with integer heights hit thresholds often; the rule is applied identically in every pass).
    Where such heights line a ridge, the upper level's terrace has zero width and two walls stand back to back
    (edge-manifold holds wherever no height sits on a threshold). A solid is watertight and consistently wound whatever
    the heights: it is stepped from the heights with those on a threshold moved up by τ (the same level, so at γ = 1
    every node keeps its isovalue bit for bit, and only the walls' crossings next to such a node move; at γ < 1 the node
    by (1 - γ) τ), so its top is the stepped surface of the heights so nudged and the surface without ``solid`` is
    unchanged. τ is the least that keeps those crossings 4 float32 steps of the coordinates from the node in x or y (at
    most a quarter of the gap to the next threshold, above the last half the way to the top isovalue; see
    ``_off_thresholds``: a few cm in local coordinates, up to metres in UTM ones), so that an ``.stl`` (float32 world
    coordinates) read back with its corners merged by position is watertight too (where γ = 0 a wall has zero height:
    :func:`~stepterrain.export.save_mesh` leaves its triangles, of no area, out of the ``.stl``; any wall within
    float32 rounding of a node or of another wall, as on a 1 m grid at UTM northings, merges there whatever τ, and
    ``save_mesh`` warns: ``.3mf``, ``.ply`` and ``.obj`` keep it watertight); where τ does not
    fit, one float32 step (``np.nextafter``), and only levels a few float32 steps apart, where the next float32 value
    up is itself a threshold, leave such a height as it is, with a warning that the solid may leak there; where two
    nodata holes meet at a single node, that node gets one copy per side, so the solid stays watertight there (each
    copy but the first moved 2 float32 steps of the coordinates into its own cell, so that the ``.stl`` is too, unless
    its side has a wall there or the move would turn a triangle over or leave its side: then it stays). Each
    edge crossing a threshold owns a wall bottom and top vertex, shared by both triangles of the edge, so the mesh is
    crack-free: its boundary lies on the input's boundary, terraces face +z and walls face the lower terrace. Cost:
    O(nodes + edges + output) on the device, two host syncs.

    A ``trimesh.Trimesh`` refers to itself (trimesh's ``visual``, ``ray``, ``permutate`` and ``nearest`` hold
    it), so a mesh you drop would wait for Python's cyclic garbage collector, often late: re-stepping a 512²
    terrain 60 times in a loop held about 1 GB. Each call therefore frees the meshes the last few calls returned
    that nothing outside their own cycle refers to any more (a mesh you keep, or whose ``visual`` or ``ray`` you
    keep, is untouched; one you hold a weak reference to is left to the collector), and their large arrays serve
    it (see :func:`set_output_pool_limit`): in a loop ``mesh = stepped(...)``, the mesh before last.

    References
    ----------
    T. Glander, M. Trapp, J. Döllner: 3D Isocontours - Real-time Generation and Visualization of 3D Stepped
    Terrain Models. Eurographics 2010 (short papers), §3-4. doi:10.2312/egsh.20101049

    Examples
    --------
    >>> import stepterrain as st
    >>> mesh = st.stepped(st.heightfield_mesh([[0.0, 1.0, 2.0], [1.0, 2.0, 3.0]]), interval=1.0)
    >>> bool(mesh.is_winding_consistent)
    True
    >>> sorted(set(mesh.vertices[:, 2].tolist()))
    [0.0, 1.0, 2.0, 3.0]
    """
    check_flag(solid, "solid")
    if floor is not None and not solid:  # before any work: the budget's or a kernel's refusal came first
        raise InvalidInputError("floor applies only with solid=True")
    reclaim_dropped()  # the meshes earlier calls returned that the caller dropped: their memory serves this one
    t = as_terrain(terrain, spacing=spacing, origin=origin, borrow=True)  # lives only within this call
    dev = resolve_device(device)
    if memory_budget is not None:
        budget_value(memory_budget)  # before any work
    values = isovalues(t.height_range, interval=interval, levels=levels, base=base)
    if colors is not None:  # before the passes (a few rows): a colormap misnamed or a row short was refused only
        _level_colors(colors, len(values))  # after the whole terrain had been stepped
    if t.visual is not None and colors is None:
        _check_carried_visual(t)
    if solid and floor is not None:
        _refuse_floor_above_surface(t, values, gamma, floor)  # before stepping; close_solid has the final word
    if solid:
        welded = t._welded_by_position()
        if welded is not t and colors is None:
            _warn_seams_welded(t, welded)
        t = _off_thresholds(welded, values)
    # _budget_hint (private): a caller's own advice in a refusal over the budget (closeup: its interval and ROI)
    arrays, vertices = _stepped_arrays(t, values, gamma, colors, dev, memory_budget, solid, _budget_hint)
    # a TIN's CRS and source: Terrain.from_mesh reads them from its metadata, _assemble records them
    return _assemble(
        t, arrays, vertices, values, gamma=gamma, colors=colors, solid=solid, floor=floor, interval=interval,
        device=dev,
    )


def _warn_seams_welded(seamed: Terrain, welded: Terrain) -> None:
    """Warn that a solid of a TIN with seams (points kept apart for their vertex colours or UVs) carries, at each seam
    point, its first copy's colour or UV (:meth:`Terrain._welded_by_position`): the faces beside the seam blend them,
    and a texture stretches across its atlas there (a glTF's primitives packed into one, an OBJ's charts)."""
    merged = int(np.count_nonzero(seamed.point_used)) - int(np.count_nonzero(welded.point_used))
    uv = isinstance(seamed.visual, trimesh.visual.TextureVisuals)
    what, one, effect = ("UVs", "UV", "the texture smears") if uv else ("vertex colours", "colour", "the colours blend")
    warnings.warn(
        f"terrain: {merged} points of the TIN coincide with others but differ in their {what} (seams: a glTF's "
        f"primitives, an OBJ's texture charts, a soup with a colour per corner); the solid is closed over them welded "
        f"(one {one} per vertex of a watertight mesh), each taking its first copy's {one}, so {effect} over the faces "
        "beside those seams. Step without solid=True to keep the seams on the surface.",
        stacklevel=caller_stacklevel(),
    )


def snapped_isovalue(h: np.float32, values: NDArray[np.float32]) -> np.float32:
    """The isovalue the float32 height ``h`` snaps to (§3.2: the nearest; on a threshold, the upper one), as
    kernels/stepped.py's quantize_levels picks it."""
    return values[np.searchsorted(thresholds_of(values), h, side="right")]


def stepped_height(h: float, values: NDArray[np.float32], gamma: float) -> tuple[float, float]:
    """``(z, α)``: the stepped surface's vertex of a node of height ``h`` at a scalar γ, and α, the isovalue h snaps
    to: (1 − γ) h + γ α in float32, as kernels/stepped.py's ``blended`` computes it (compiled without contracted
    multiply-adds, alike on the CPU and a GPU), not the blend's float64 value, which that vertex can lie a float32
    step below. Monotone in h: of the lowest height a triangle uses, the surface's lowest vertex (a batch's shared
    floor and its check, where :func:`lowest_surface` gives a margin instead)."""
    h32 = np.float32(h)
    alpha = snapped_isovalue(h32, values)
    g = np.float32(gamma)
    return float((np.float32(1.0) - g) * h32 + g * alpha), float(alpha)


def lowest_surface(h: float, values: NDArray[np.float32], gamma: float | None) -> tuple[float, float, float]:
    """``(lowest, α, margin)``: the stepped surface's lowest point when ``h`` is the lowest height a triangle uses,
    α the isovalue h snaps to (monotone in h: no node and no wall vertex lies lower at the same γ), and the float32
    rounding of the kernel's blend. ``gamma``: a scalar in [0, 1], (1 − γ) h + γ α, exact (margin 0) at γ = 0 and
    1; None for a per-node γ (an array, a callable, a lens), at most max(h, α). A solid's floor at or above
    ``lowest + margin`` cannot lie below the surface (:func:`stepped` and :func:`~stepterrain.batch.batch` refuse
    it before stepping; :func:`~stepterrain.mesh.close_solid` has the final word)."""
    h32 = np.float32(h)
    alpha = snapped_isovalue(h32, values)
    top = max(abs(h32), abs(alpha))
    with np.errstate(over="ignore"):  # np.spacing of the float32 maximum (a void of -3.4e38 read as a height) is
        step = np.spacing(top)  # inf, with numpy's "overflow encountered in spacing" warning: the step below it
    margin = 4.0 * float(top - np.nextafter(top, np.float32(0.0)) if np.isinf(step) else step)
    if gamma is None:
        return max(float(h32), float(alpha)), float(alpha), margin
    if gamma in (0.0, 1.0):  # (1 - γ) h + γ α is h or α, in float32 as the kernel computes it
        return (float(alpha) if gamma == 1.0 else float(h32)), float(alpha), 0.0
    return (1.0 - gamma) * float(h32) + gamma * float(alpha), float(alpha), margin


def default_floor(values: NDArray[np.float32], lowest_vertex: float, interval: float | None) -> float:
    """A solid's default base height: one ``interval`` below the lowest isovalue α_0 or the lowest surface vertex
    ``lowest_vertex``, whichever is lower (with explicit levels and γ < 1, heights under α_0 pull the surface below
    it); without an interval a tenth of the levels' span (at least 0.1) below it; at least one float32 step below
    it, and at most down to -3.4e38. :func:`stepped` closes a solid there; :func:`~stepterrain.batch.batch` closes
    every tile or frame at the one its whole source gives.

    The float32 step: where the interval or the tenth is below float32's (or float64's) resolution of the heights
    (a single level at 1e16, an interval of 2 at 1e8 or 1e20), the floor came out on the lowest point in float32
    (the base on the lowest terrace in a .glb or .stl: a solid of no thickness there) or in float64, and
    :func:`~stepterrain.mesh.close_solid` refused the floor the caller never gave."""
    lowest = min(float(values[0]), lowest_vertex)
    if interval:
        floor = lowest - float(interval)
    else:  # levels spanning more than float32 holds (-3e38 to 3e38): their span in float64, not inf
        with np.errstate(over="ignore"):
            span = float(np.ptp(values))
        if not math.isfinite(span):
            span = float(values[-1]) - float(values[0])
        floor = lowest - max(span, 1.0) * 0.1
    with np.errstate(over="ignore"):  # a float32 value under lowest's float32 value (-inf under -3.4e38)
        below = np.nextafter(np.float32(lowest), np.float32(-np.inf))
    if np.isfinite(below):
        floor = min(floor, float(below))
    if floor < -FLOAT32_MAX < lowest:  # a tenth of such a span reaches beyond float32: its lowest value
        floor = -FLOAT32_MAX
    return floor


def _refuse_floor_above_surface(t: Terrain, values: NDArray[np.float32], gamma: GammaLike, floor: Any) -> None:
    """Refuse, before stepping, a solid's ``floor`` that surely lies at or above the stepped surface's lowest point
    (:func:`lowest_surface` of the lowest height a triangle uses): stepping a large terrain (with its warnings) only to
    be refused by :func:`~stepterrain.mesh.close_solid` wasted the work. A floor that is not a finite float32
    number is refused here too, as :func:`~stepterrain.mesh.close_solid` refuses it (it stepped the whole terrain
    first); a γ out of range is left to the checks after stepping."""
    try:
        floor_z = as_number(floor)
    except (TypeError, ValueError, OverflowError):
        raise InvalidInputError(f"floor must be a number (the base height of the solid); got {floor!r}") from None
    if not math.isfinite(floor_z):
        raise InvalidInputError(f"floor must be finite; got {floor_z}")
    if abs(floor_z) > FLOAT32_MAX:  # the mesh's float32 vertices would hold -inf and NaN
        raise InvalidInputError(f"floor must fit in float32 (|x| < {FLOAT32_MAX:.2g}); got {floor_z:g}")
    g: float | None = None
    if not callable(gamma) and not isinstance(gamma, Lens) and _gamma_ndim(gamma) == 0:
        try:
            g = as_number(gamma)
        except (TypeError, ValueError, OverflowError):
            return
        if not 0.0 <= g <= 1.0:
            return
    if not t._has_triangles():
        return  # no surface: refused after stepping, as it says
    h = t.height_range[0]  # of the nodes a triangle with three finite heights uses (a TIN's used points)
    lowest, alpha, margin = lowest_surface(h, values, g)
    if floor_z < lowest + margin:
        clash = float32_floor_clash(floor_z, lowest + margin)
        if clash:  # below it in float64, on it in float32: close_solid's rule (no thickness in an .stl)
            raise InvalidInputError(f"floor must lie below the lowest surface height {lowest:.9g}{clash}")
        return
    if g is not None:
        raise InvalidInputError(
            f"floor must lie below the lowest surface height {lowest:.9g} (the lowest height {float(np.float32(h)):g} "
            f"on the isovalue {alpha:g}, γ = {g:g}); got {floor_z:.9g}")
    raise InvalidInputError(
        f"floor must lie below the lowest surface height, at most {lowest:.9g} (the lowest height "
        f"{float(np.float32(h)):g} and its isovalue {alpha:g}, γ varying in [0, 1]); got {floor_z:.9g}")


#: How many float32 steps of the output's coordinates (:func:`_off_thresholds`) a wall crossing next to a node moved off
#: a threshold keeps from that node and from the edge's other end, in x or y: apart still once ``.stl`` (float32,
#: world coordinates) and the readers and slicers that merge its corners by position have rounded them.
OFF_THRESHOLD_STEPS = 4.0


def _off_thresholds(t: Terrain, values: NDArray[np.float32], magnitude: float = 0.0, *, warn: bool = True) -> Terrain:
    """The terrain a solid is stepped from: ``t`` itself, or, where a height the surface uses sits exactly on a
    threshold t_i = (α_i + α_i+1) / 2, a copy with such heights moved up by τ, the least that puts every wall
    crossing on the node's edges :data:`OFF_THRESHOLD_STEPS` float32 steps of the coordinates (world or local,
    whichever is coarser) from the node and from the edge's other end, in x or y: τ ≥ k u |Δh| / (L - k u) over the
    node's edges to a lower neighbour (u the float32 step, L the edge's larger xy extent), at least one float32 step
    (``np.nextafter``) and at most a quarter of the gap to the next threshold (above the last one: half the way to
    the top isovalue).

    A height on a threshold belongs to the upper level, and so does t_i + τ: every node keeps its level (at γ = 1 its
    isovalue, bit for bit); only the walls' crossings on its edges move, by τ / |Δh| of the edge (at γ < 1 the node by
    (1 - γ) τ). The surface then has no twin vertex and no zero-width terrace: two walls back to back on a ridge of
    such heights, or four meeting on one node's vertical edge at a saddle, left solids that were not watertight (about
    a third of small random integer grids stepped with interval 2, and the embedded DEM at intervals 20, 50 and 100
    with base 0). One float32 step kept the indexed solid watertight, but a wall's top vertex then lay within float32
    rounding of the node, at the same height at γ = 1: an ``.stl`` (no indices; float32 world coordinates) read back
    with its corners merged by position had degenerate faces and open edges (a 167² crop of the embedded DEM at
    interval 100: 2128 such pairs). Where τ cannot keep those distances below a quarter of the gap (levels
    close together, coordinates too coarse for the edges), the height moves by one float32 step (the indexed solid is
    watertight; its ``.stl`` may merge there); where that next float32 value is itself a threshold (levels a few
    float32 steps apart), the height stays, with a warning that the solid may leak there. ``magnitude``: a least
    coordinate magnitude for the float32 step (a tile of a raster: the whole raster's, so that the nodes two tiles
    share get one τ in both, see ``batch``). ``warn``: False leaves a height that stays on its threshold unsaid (a
    batch tile's ring: the tile's own stepped() says it), without a ``warnings.catch_warnings`` block (the process's
    filters, under a lock that dask's threaded workers would take one at a time)."""
    thresholds = thresholds_of(values)
    # only the heights the surface uses: a TIN's unused points and a grid's nodes isolated by nodata are in no mesh
    # (they warned that the solid may leak where it has no vertex)
    on = t._used_nodes_in(thresholds)
    if on.size == 0:
        return t
    heights = t.heights
    up = np.nextafter(heights.reshape(-1)[on], np.float32(np.inf))
    stays = np.isin(up, thresholds)
    if stays.any():
        if warn:
            warnings.warn(
                "some heights sit exactly on a threshold (α_i + α_i+1) / 2 that lies one float32 step below the "
                "next; the solid may not be watertight there. Give levels further apart.",
                stacklevel=caller_stacklevel(),
            )
        on, up = on[~stays], up[~stays]
    if on.size:
        up = _off_threshold_heights(t, thresholds, on, up, magnitude, top=float(values[-1]))
    nudged = heights.copy()
    nudged.reshape(-1)[on] = up
    if t.kind == "grid":  # a fresh cache: the uploads, nodata flag and ranges belong to the heights
        return replace(t, heights=nudged, _device_cache={}, _owned=True)
    points = t.points.copy()  # a TIN's heights are its points' z as float32
    points[on, 2] = up
    return replace(t, heights=nudged, points=points, _device_cache={}, _owned=True)


def _off_threshold_heights(
    t: Terrain, thresholds: NDArray[np.float32], on: NDArray[np.intp], up: NDArray[np.float32],
    magnitude: float = 0.0, *, top: float,
) -> NDArray[np.float32]:
    """The heights t_i + τ the nodes ``on`` (flat indices, each exactly on a threshold) are stepped from, in place of
    their next float32 values ``up`` where τ fits (see :func:`_off_thresholds`). ``top``: the highest isovalue; the
    last threshold's gap is twice its distance to it (an interval of uniform levels), as if the next one lay there."""
    flat = t.heights.reshape(-1)
    h_a = flat[on].astype(np.float64)
    x0, x1, y0, y1 = t.extent
    ox, oy = t.local_origin
    # the coarser float32 step of the world coordinates (.stl) and of the local ones the kernels compute in
    magnitude = max(magnitude, abs(x0), abs(x1), abs(y0), abs(y1), abs(x1 - ox), abs(x0 - ox), abs(y1 - oy),
                    abs(y0 - oy))
    ku = OFF_THRESHOLD_STEPS * float(np.spacing(np.float32(magnitude)))
    # each node's edges (a grid's 8 neighbours: either diagonal), as (node index in on, other end, L)
    if t.kind == "grid":
        rows, cols = t.heights.shape
        r, c = np.divmod(on, cols)
        dx, dy = abs(float(t.spacing[0])), abs(float(t.spacing[1]))
        idx, other, length = [], [], []
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr == dc == 0:
                    continue
                inside = (r + dr >= 0) & (r + dr < rows) & (c + dc >= 0) & (c + dc < cols)
                k = np.flatnonzero(inside)
                idx.append(k)
                other.append((r[k] + dr) * cols + c[k] + dc)
                length.append(np.full(k.size, max(dx * abs(dc), dy * abs(dr))))
        a, b, lengths = np.concatenate(idx), np.concatenate(other), np.concatenate(length)
    else:
        position = np.full(len(flat), -1, np.int64)
        position[on] = np.arange(on.size)
        edges = t.edges.astype(np.int64)
        pairs = np.concatenate([edges, edges[:, ::-1]])
        pairs = pairs[position[pairs[:, 0]] >= 0]
        a, b = position[pairs[:, 0]], pairs[:, 1]
        delta = np.abs(t.points[pairs[:, 0], :2] - t.points[b, :2])
        lengths = delta.max(axis=1)
    h_b = flat[b].astype(np.float64)
    crossing = np.isfinite(h_b) & (h_b < h_a[a])  # a wall stands on the edge: its other end lies below t_i
    a, h_b, lengths = a[crossing], h_b[crossing], lengths[crossing]
    # the other end moved up too where it sits on a lower threshold (at most a quarter of its gap)
    gaps = np.diff(thresholds.astype(np.float64))
    # a quarter of the gap up to the next threshold; the last one's: half its way to the top isovalue (without a
    # bound, τ there grew with the drop to the lowest neighbour: 525 m over a 1050 m cliff at levels 0 and 100, the
    # node at γ = 0.5 262.5 m up)
    quarter = np.append(gaps, 2.0 * (top - float(thresholds[-1]))) / 4.0
    slot = np.searchsorted(thresholds, h_b.astype(np.float32))
    found = slot < len(thresholds)
    on_b = np.zeros(h_b.size, bool)
    on_b[found] = thresholds[slot[found]] == h_b[found].astype(np.float32)
    rise_b = np.where(on_b, quarter[np.minimum(slot, len(quarter) - 1)], 0.0)
    drop = h_a[a] - h_b  # t_i - h_b, before any move
    with np.errstate(divide="ignore", invalid="ignore"):
        # from the node: τ L >= k u (τ + drop); from the other end: (drop - rise_b) L >= k u (τ + drop)
        need = np.where(lengths > ku, ku * drop / (lengths - ku), np.inf)
        room = np.where(lengths > ku, (drop - rise_b) * lengths / ku - drop, -np.inf)
    lower = np.zeros(on.size)
    np.maximum.at(lower, a, need)
    upper = np.full(on.size, np.inf)
    np.minimum.at(upper, a, room)
    level = np.searchsorted(thresholds, flat[on])  # each node's own threshold
    upper = np.minimum(upper, quarter[level])
    fits = np.isfinite(lower) & (lower <= upper)
    moved = (h_a + lower).astype(np.float32)
    moved = np.where(moved.astype(np.float64) < h_a + lower, np.nextafter(moved, np.float32(np.inf)), moved)
    moved = np.maximum(moved, up)  # at least one float32 step
    fits &= np.isfinite(moved) & (moved.astype(np.float64) - h_a <= upper + np.spacing(moved))
    return np.where(fits, moved, up).astype(np.float32)


def _assemble(
    t: Terrain,
    arrays: StepArrays,
    vertices: NDArray[np.float64],
    values: NDArray[np.float32],
    *,
    gamma: GammaLike,
    colors: Any,
    solid: bool,
    floor: float | None,
    interval: float | None,
    device: wp.Device | None = None,
) -> trimesh.Trimesh:
    faces = arrays.faces
    face_levels = arrays.face_levels
    face_walls = arrays.face_walls
    metadata: dict[str, Any] = {
        "generator": "stepterrain.stepped",
        "isovalues": values.tolist() if values.size <= 4096 else [float(values[0]), float(values[-1])],
        "gamma": float(gamma)
        if np.ndim(gamma) == 0 and not callable(gamma) and not isinstance(gamma, Lens)
        else "varying",
    }
    if t.source:
        metadata["source"] = t.source
    if t.crs:
        metadata["crs"] = t.crs
    vertex_colors = None
    if colors is not None:
        table = _level_colors(colors, len(values))
        vertex_levels = np.searchsorted(values, host_copy(arrays.step_heights))
        vertex_colors = np.take(table, vertex_levels, axis=0, mode="clip",
                                out=recycled_empty((len(vertex_levels), table.shape[1]), np.uint8))
    carried = None  # the input's vertex colours or UVs on the output vertices
    if vertex_colors is None and t.visual is not None:
        carried = _carry_visual(t, arrays)
    if solid:
        from .mesh import _close_solid

        if len(faces) == 0:
            raise InvalidInputError("solid=True needs a surface to close; the terrain has no triangle with three "
                                    "finite heights (all cells touch nodata)")
        try:  # faces, hence vertices (checked above)
            floor_z = (default_floor(values, float(vertices[:, 2].min()), interval) if floor is None
                       else as_number(floor))
        except (TypeError, ValueError, OverflowError):
            raise InvalidInputError(f"floor must be a number (the base height of the solid); got {floor!r}") from None
        vertices, faces, kept, extra, source = _close_solid(vertices, faces, ~face_walls, floor_z, device, turn=True)
        face_levels = np.concatenate([face_levels[kept], np.full(extra, -1, np.int32)])
        face_walls = np.concatenate([face_walls[kept], np.zeros(extra, bool)])
        if vertex_colors is not None:  # a surface vertex (or its copy at a pinch) keeps its colour; the base is grey
            skirt = np.tile(np.array([[96, 96, 96, 255]], np.uint8), (len(vertices) - len(source), 1))
            vertex_colors = np.concatenate([vertex_colors[source], skirt])
        if carried is not None:
            carried = _solid_visual(carried, vertices, source, kept, extra)
        metadata["floor"] = floor_z
    mesh = trimesh.Trimesh(
        vertices,
        faces,
        process=False,
        face_attributes={"level": face_levels, "wall": face_walls},
        metadata=metadata,
    )
    if vertex_colors is not None:
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=vertex_colors)
    elif carried is not None:
        mesh.visual = carried
    track(mesh)  # freed by a later call once the caller drops it (reclaim_dropped), not only by the collector
    return mesh


def _solid_visual(carried: Any, vertices: NDArray[np.float64], source: NDArray[np.int64], kept: NDArray[np.bool_],
                  extra: int) -> Any:
    """The carried visual of a surface on its solid (:func:`~stepterrain.mesh.close_solid`'s ``vertices``, the
    surface's first, ``source``, the surface vertex each of those is or copies, ``kept``, the surface faces kept, and
    ``extra``, the skirt and base faces after them): vertex or face colours with a grey skirt and base, as ``colors=``
    gives them; UVs with each skirt and base vertex taking those of a surface vertex on its xy (the texture runs
    straight down the skirt)."""
    n = len(source)
    if isinstance(carried, trimesh.visual.ColorVisuals) and carried.kind == "face":
        skirt = np.tile(np.array([[96, 96, 96, 255]], np.uint8), (extra, 1))
        return trimesh.visual.ColorVisuals(face_colors=np.concatenate([carried.face_colors[kept], skirt]))
    if isinstance(carried, trimesh.visual.ColorVisuals):
        skirt = np.tile(np.array([[96, 96, 96, 255]], np.uint8), (len(vertices) - n, 1))
        return trimesh.visual.ColorVisuals(vertex_colors=np.concatenate([carried.vertex_colors[source], skirt]))
    from .mesh import exact_keys

    uv = carried.uv[source]
    keys = exact_keys(vertices[:, :2])
    above = np.empty(int(keys.max()) + 1, np.int64)
    above[keys[:n]] = np.arange(n)  # a surface vertex per xy (every base vertex lies under one)
    return trimesh.visual.TextureVisuals(uv=np.concatenate([uv, uv[above[keys[n:]]]]), material=carried.material)


def _stack_ranges(stack: NDArray[Any]) -> tuple[float | None, float | None, tuple[float, float] | None,
                                                NDArray[np.bool_], NDArray[np.bool_]]:
    """Of a (T, H, W) stack, frame by frame: (lo, hi) of its finite heights (None, None when it has none), the range
    of the heights a triangle with three finite heights uses in some frame (:func:`used_height_range` of the stack;
    the finite range where no triangle has three; None without a finite height), and per frame whether it holds an
    infinity or a finite value beyond float32 (``bad``) and whether it holds no finite height (``empty``). A frame at
    a time: the whole stack's finite mask and the copy of its finite heights held as much memory as the stack again
    (a memory-mapped series was read into memory whole before its first frame)."""
    n = len(stack)
    bad, empty = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    lo = hi = used_lo = used_hi = None
    for k in range(n):
        frame = np.asarray(stack[k])
        finite = np.isfinite(frame)
        whole = bool(finite.all())
        if not frame.size or (not whole and not finite.any()):  # a frame of no node is all() finite: none is
            empty[k] = True
            bad[k] = bool(np.isinf(frame).any())  # NaN and an infinity: refused for the infinity, as stepped() does
            continue
        values = frame if whole else frame[finite]
        f_lo, f_hi = float(values.min()), float(values.max())
        lo, hi = (f_lo, f_hi) if lo is None else (min(lo, f_lo), max(hi, f_hi))
        bad[k] = (not whole and bool(np.isinf(frame).any())) or max(-f_lo, f_hi) > FLOAT32_MAX
        # without nodata every node of a grid of 2 x 2 or more is a triangle's: its range, no second pass
        span, any_used = ((f_lo, f_hi), min(frame.shape) >= 2) if whole else _used_span(frame)
        if any_used and span is not None:
            used_lo, used_hi = (span if used_lo is None else (min(used_lo, span[0]), max(used_hi, span[1])))
    used = (lo, hi) if used_lo is None or lo is None else (used_lo, used_hi)
    return lo, hi, (None if lo is None else used), bad, empty


def stepped_series(
    frames: ArrayLike | Iterable[ArrayLike],
    *,
    interval: float | None = None,
    levels: ArrayLike | None = None,
    base: float = 0.0,
    gamma: GammaLike = 1.0,
    colors: str | ArrayLike | None = None,
    spacing: ArrayLike | None = None,
    origin: ArrayLike | None = None,
    progress: bool = False,
    device: wp.DeviceLike = None,
) -> Iterator[trimesh.Trimesh]:
    """Step a time series of heightfields (T, H, W) frame by frame (paper 000 §4, dynamic data).

    Kernels compile once; each frame reuses the work buffers of the previous one (the scratch pool). With
    ``interval`` the isovalues lie on one grid, ``base + k * interval``, so a height steps to the same level
    height in every frame. Frames given as one (T, H, W) array (numpy or Warp) share one list of isovalues (from
    the stack's overall height range), so level indices (``face_attributes["level"]``) and ``colors`` agree between
    frames too. Frames from another iterable are not known ahead: each frame's isovalues span its own height range, so
    their geometry agrees but level indices and colours are counted per frame; pass ``levels=`` (or one array)
    for colours that agree over the series. An iterable may also yield :class:`Terrain` objects or trimesh TINs,
    taken as :func:`stepped` takes them (their own spacing and origin; ``spacing``/``origin`` apply to raw arrays
    only, (1, 1) and (0, 0) when not given). A stack is read a frame at a time (its height range too): a memory-mapped
    one (``np.load(path, mmap_mode="r")``) has each frame's float32 copy checked against the memory budget, as
    :func:`stepped` checks a mapped frame's.

    Examples
    --------
    >>> import numpy as np, stepterrain as st
    >>> frames = np.random.default_rng(0).random((3, 8, 8))
    >>> [m.is_winding_consistent for m in st.stepped_series(frames, interval=0.25)]
    [True, True, True]

    A frame with bad heights, or with no finite height at all (as :func:`stepped` refuses such a terrain), is an
    :class:`InvalidInputError` naming its index (``frames[k]``): for a (T, H, W) stack before the first frame,
    for an iterable when that frame is reached; so is, for an iterable, ``gamma`` or ``colors`` that does not fit
    a frame (its shape, its own count of isovalues), and for a stack a ``gamma`` that fails on a frame after the
    first (an array NaN at a node that frame's surface uses, a callable that fails on its points).
    """
    check_flag(progress, "progress")
    if spacing is not None:  # once, so that their errors name no frame
        check_spacing(*_pair(spacing, "spacing", nonzero=True))
    if origin is not None:
        _pair(origin, "origin", nonzero=False, scalar=False)
    dev = resolve_device(device)
    stack = None
    if isinstance(frames, wp.array):  # a (T, H, W) warp array is a stack too: it was refused as "not iterable"
        frames = frames.numpy()
    if isinstance(frames, np.ndarray) or (hasattr(frames, "shape") and hasattr(frames, "__array__")):
        # a memory map stays one: each frame's Terrain checks its float32 copy against the memory budget, as stepped()
        # of a mapped frame does (np.asarray made it a plain array, read in full)
        stack = frames if isinstance(frames, np.memmap) else np.asarray(unmasked(frames))
        if stack.ndim != 3:
            raise InvalidInputError(f"frames must be a (T, H, W) stack; got shape {stack.shape}")
        if len(stack) == 0:  # it said "frames hold no finite height"
            raise InvalidInputError(f"frames must hold at least one frame; got shape {stack.shape}")
        if not is_real_dtype(stack.dtype):
            raise InvalidInputError(f"frames must be a real-valued (T, H, W) stack; got dtype {stack.dtype}")
        lo, hi, used, bad, empty = _stack_ranges(stack)
        if lo is None and not bad.any():  # an infinity is named below, as stepped() of its frame names it
            raise InvalidInputError("frames hold no finite height")
        # frames whose heights their Terrain refuses (an infinity, a finite value beyond float32), refused here before
        # the first frame as the docstring says: they were refused only when reached, after the frames before them,
        # and a value beyond float32 reached isovalues() first, whose error blamed the interval and named no frame
        first = np.flatnonzero(bad | empty)
        if first.size:
            k = int(first[0])
            if empty[k] and not bad[k]:  # its mesh would be empty: stepped() and a list of frames refuse such a frame
                raise InvalidInputError(f"frames[{k}]: terrain has no finite height (all nodata)")
            try:
                Terrain.from_heights(stack[k])
            except InvalidInputError as exc:
                raise InvalidInputError(f"frames[{k}]: {exc}") from None
        # the isovalues span the heights a triangle uses, as each frame's Terrain.height_range (a node on none is in
        # no mesh): a lone pixel in a void moved every frame's levels and colours; without nodata, the finite range
        # of the float32 heights every frame is stepped from (its Terrain's): a float64 height 1e-9 above an
        # isovalue, which float32 rounds onto it, added a level no vertex reaches (other colours and level indices
        # than stepped() of the frame). Rounding is monotone, so the range rounded is the float32 heights' range;
        # within float32 (heights beyond it were refused above)
        used = tuple(float(np.float32(v)) for v in (used or (lo, hi)))
        values = isovalues(used, interval=interval, levels=levels, base=base)
        if colors is not None:  # before the first frame's passes, as stepped() checks them: every frame shares them
            _level_colors(colors, len(values))
        iterable: Iterable[ArrayLike] = stack
    else:
        values = None
        iterable = frames
        if isinstance(frames, (str, bytes)) or not isinstance(frames, Iterable):
            raise InvalidInputError(f"frames must be a (T, H, W) stack or an iterable of (H, W) heightfields; got "
                                    f"{type(frames).__name__}")
    if progress:
        from tqdm.auto import tqdm

        iterable = tqdm(iterable, total=len(stack) if stack is not None else None, desc="stepping frames", unit="frame")
    for k, frame in enumerate(iterable):
        # a fresh Terrain per frame: what it caches (the heights' upload, whether they hold nodata) belongs to
        # its own heights; the work arrays of the passes come from the per-thread scratch pool, reused
        try:
            # one frame's call; a Terrain or a TIN per frame is taken as stepped() takes it ("got dtype object")
            t = as_terrain(frame, spacing=spacing, origin=origin, borrow=True)
            height_range = t.height_range if values is None else None  # all nodata: an error, as in stepped()
        except InvalidInputError as exc:  # the frame's heights (spacing and origin were checked above)
            raise InvalidInputError(f"frames[{k}]: {exc}") from None
        frame_values = values
        if height_range is not None:  # an iterable's frame: its own isovalues
            try:
                frame_values = isovalues(height_range, interval=interval, levels=levels, base=base)
            except InvalidInputError as exc:  # what does not fit the arguments fails at the first frame, as for
                # stepped(); a later frame fails for its own heights (an interval too fine for float32 there): named
                if k == 0:
                    raise
                raise InvalidInputError(f"frames[{k}] (heights {height_range[0]:g} to {height_range[1]:g}): {exc}") \
                    from None
        try:
            if t.visual is not None and colors is None:
                _check_carried_visual(t)
            reclaim_dropped()  # the frames the caller is done with: their memory serves this one
            arrays, vertices = _stepped_arrays(t, frame_values, gamma, colors, dev)
            mesh = _assemble(
                t, arrays, vertices, frame_values, gamma=gamma, colors=colors, solid=False, floor=None,
                interval=interval,
            )  # fmt: skip
        except InvalidInputError as exc:  # e.g. colors with a row per isovalue of another frame: name this frame
            if values is not None:  # a stack: every frame shares the isovalues and the shape, so what does not fit
                # them fails at the first frame, as for stepped(); a later frame fails for what is its own (a γ array
                # NaN where frame 0 had nodata, a γ callable failing on its points), which names the frame
                if k == 0:
                    raise
                raise InvalidInputError(f"frames[{k}]: {exc}") from exc.__cause__
            # the cause kept: a gamma callable's own exception
            raise InvalidInputError(f"frames[{k}] ({counted(len(frame_values), 'isovalue')}, shape {t.shape}): {exc}") \
                from exc.__cause__
        yield mesh


make_module_callable(__name__)  # st.stepped(...) runs stepped(); st.stepped.thresholds_of reads the module
