"""Terrain inputs normalised once: a regular heightfield or a TIN, with extent, nodata and device caches.

A :class:`Terrain` is what every capability consumes. Heightfields keep their grid (edges are indexed
implicitly by the kernels); a TIN gets its edge table built once and cached. Coordinates are made relative
to a local origin before they reach a kernel (float32 on the device), and shifted back in float64.

    >>> import stepterrain as st
    >>> t = st.Terrain.from_heights([[0.0, 1.0], [2.0, 3.0]], spacing=(10.0, 10.0))
    >>> t.shape, t.extent
    ((2, 2), (0.0, 10.0, 0.0, 10.0))
"""

from __future__ import annotations

import math
import numbers
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import InitVar, dataclass, field, replace
from typing import Any, Literal

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from ._compaction import check_budget
from .errors import InvalidInputError, counted, plain_repr

__all__ = ["Terrain", "heightfield_mesh", "as_terrain"]

#: The largest float32: the kernels get heights and isovalues in float32, so inputs beyond it are refused.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _pair(value: Any, name: str, *, nonzero: bool, scalar: bool = True) -> tuple[float, float]:
    """``value`` as two finite floats (x, y). One number stands for both where ``scalar`` (a spacing, a size);
    a point (an origin, a centre) needs both. A one-element sequence ((5,), [5]) is refused either way: it is a
    pair missing its y, which was silently taken as (5, 5)."""
    try:  # text ("30"), bools, complex, objects, ragged: not numbers; a masked entry is NaN, refused below
        array = real_numbers(value, name, "a pair of numbers (x, y)")
    except (TypeError, ValueError) as exc:  # the value, which says more than real_numbers' dtype
        raise InvalidInputError(f"{name} must be a pair of numbers (x, y); got {value!r}") from exc
    if array.ndim == 0 and scalar:
        array = np.repeat(array, 2)
    arr = array.reshape(-1)
    if array.ndim == 0 or arr.size != 2:
        also = " (or one number for both)" if scalar else ""
        raise InvalidInputError(f"{name} must be a pair of finite numbers (x, y){also}; got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{name} must be a pair of finite numbers (x, y); got {value!r}")
    if nonzero and np.any(arr == 0):
        raise InvalidInputError(f"{name} must be non-zero in x and y; got {tuple(arr.tolist())}")
    return float(arr[0]), float(arr[1])


#: Node spacings must lie within these magnitudes: the kernels place nodes at (j·dx, i·dy) in float32, which
#: rounds a spacing below ~1e-38 to zero (every node at one point: a flat, zero-area mesh) and overflows far above.
SPACING_RANGE = (1e-30, 1e30)


def check_spacing(dx: float, dy: float, name: str = "spacing") -> tuple[float, float]:
    """``(dx, dy)`` when both magnitudes lie in :data:`SPACING_RANGE`, else an :class:`InvalidInputError`."""
    lo, hi = SPACING_RANGE
    for value in (dx, dy):
        if not lo <= abs(value) <= hi:
            raise InvalidInputError(
                f"{name} must lie between {lo:g} and {hi:g} in magnitude (nodes are placed in float32); "
                f"got {(dx, dy)}"
            )
    return dx, dy


#: a grid's farthest node may lie at most this many spacings from zero: float64 then places every node to 1e-4 of
#: a spacing (2**-52 * 4.5e11 = 1e-4). An origin of 1e17 with spacing 1 put neighbouring nodes on one float64 value:
#: a mesh of zero area, silently
_MAX_NODE_SPACINGS = 4.5e11


def grid_geometry(spacing: Any, origin: Any, shape: tuple[int, ...]) -> tuple[tuple[float, float], tuple[float, float]]:
    """A grid's ``spacing`` (a non-zero pair within :data:`SPACING_RANGE`) and ``origin`` (a finite pair) checked,
    and the nodes of a grid of ``shape`` not too far from zero for float64 (:func:`check_origin`)."""
    spacing = check_spacing(*_pair(spacing, "spacing", nonzero=True))
    origin = _pair(origin, "origin", nonzero=False, scalar=False)
    check_origin(origin, spacing, shape)
    return spacing, origin


def check_origin(origin: tuple[float, float], spacing: tuple[float, float], shape: tuple[int, ...]) -> None:
    """An :class:`InvalidInputError` when a grid's nodes ``origin + (j * dx, i * dy)`` lie so far from zero that
    float64 cannot keep neighbouring nodes apart (see :data:`_MAX_NODE_SPACINGS`)."""
    for axis, (x0, d, n) in enumerate(zip(origin, spacing, (shape[1], shape[0]), strict=True)):
        far = abs(x0) + (n - 1) * abs(d)
        if far > _MAX_NODE_SPACINGS * abs(d):
            raise InvalidInputError(
                f"origin {tuple(origin)} lies too far from zero for spacing {tuple(spacing)}: float64 cannot keep "
                f"the nodes {'xy'[axis]} apart out there (at most {_MAX_NODE_SPACINGS:.2g} spacings from zero; the "
                f"farthest node is {far / abs(d):.3g}); make the coordinates relative to a nearer origin"
            )


def finite_triangles(finite: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Per cell of the last two axes, whether its triangles (n00, n01, n11) and (n00, n11, n10), as
    kernels/stepped.py cuts it, have three finite heights (``finite``: the nodes')."""
    n00, n01, n11, n10 = finite[..., :-1, :-1], finite[..., :-1, 1:], finite[..., 1:, 1:], finite[..., 1:, :-1]
    return n00 & n01 & n11, n00 & n11 & n10


def lowest_used_height(heights: NDArray[Any], height_range: tuple[float, float] | None = None) -> float | None:
    """The lowest height of a grid node (or of a (T, H, W) stack's) that a triangle with three finite heights uses;
    None when no triangle has. Nodes beside nodata that no such triangle uses are in no stepped mesh.
    ``height_range``: the heights' (min, max) when they hold no nodata, known to the caller: on a grid of at least
    2 x 2 every node is then a triangle's, and its min is the answer without a pass. A stack is read a frame at a
    time (:func:`_by_frame`): a memory map is not read into memory whole. Integer heights give a float too."""
    if height_range is not None and min(heights.shape[-2:]) >= 2:
        return float(height_range[0])
    if _by_frame(heights):  # a frame's masks at a time: the stack's held as much memory as a float32 stack again
        lows = [low for low in map(lowest_used_height, _frames(heights)) if low is not None]
        return min(lows) if lows else None
    used = used_nodes(np.isfinite(heights))
    if not used.any():
        return None
    if np.asarray(heights).dtype.kind in "biu":  # every node finite: on a grid with a triangle every node is one's;
        return float(np.min(heights))  # initial=np.inf cannot be cast to an integer dtype (numpy's OverflowError)
    return float(np.min(heights, where=used, initial=np.inf))


def used_height_range(heights: NDArray[Any]) -> tuple[float, float] | None:
    """(min, max) of the grid nodes (of a (T, H, W) stack's frames) that a triangle with three finite heights uses;
    of the finite heights where no triangle has three (a mesh without faces); None when no height is finite.
    :attr:`Terrain.height_range` of a grid with nodata: a node on no triangle is in no stepped mesh. A stack is read a
    frame at a time (:func:`_by_frame`), as :func:`~stepterrain.stepped_series` reads it."""
    return _used_span(heights)[0]


def _used_span(heights: NDArray[Any]) -> tuple[tuple[float, float] | None, bool]:
    """(:func:`used_height_range`, whether a triangle with three finite heights uses some node) in one pass over
    the triangles: :class:`Terrain` keeps both, so that a solid's floor check asks the grid's triangles no second
    time. A stack a frame at a time (:func:`_by_frame`)."""
    if _by_frame(heights):
        return _stack_span(heights)
    finite = np.isfinite(heights)
    if finite.all():  # every node is a triangle's (or, under 2 x 2, none is: the finite heights): no masks
        return (float(heights.min()), float(heights.max())), min(heights.shape[-2:]) >= 2
    used = used_nodes(finite)
    any_used = bool(used.any())
    if not any_used:
        used = finite
        if not used.any():
            return None, False
    return ((float(np.min(heights, where=used, initial=np.inf)), float(np.max(heights, where=used, initial=-np.inf))),
            any_used)


def _by_frame(heights: Any) -> bool:
    """Whether :func:`used_height_range` and :func:`lowest_used_height` take ``heights`` a frame at a time: a numpy
    array (a memory map too; not a masked one, whose reductions skip its mask) of (T, H, W) or more axes with some
    node. Its whole finite and triangle masks held 1.25 times a float32 stack's memory again, and a memory-mapped
    stack was read whole before its first frame; a frame's masks are a quarter of the frame's memory each. Each
    frame's (min, max) combined is the whole stack's: the values of the whole-stack pass, the sign of a zero extreme
    that of the first frame holding it (as stepped_series' ``_stack_ranges`` takes it; the whole-stack pass's depended
    on numpy's loop: float16 kept the first of -0.0 and 0.0, float64 the last)."""
    return (isinstance(heights, np.ndarray) and not np.ma.isMaskedArray(heights) and heights.ndim >= 3
            and heights.size > 0)


def _frames(heights: NDArray[Any]) -> Iterator[NDArray[Any]]:
    """The (H, W) frames of a stack of ``heights`` (..., H, W), one at a time (views: a memory map's frame is read
    when it is reduced)."""
    for index in np.ndindex(heights.shape[:-2]):
        yield heights[index]


def _stack_span(heights: NDArray[Any]) -> tuple[tuple[float, float] | None, bool]:
    """:func:`_used_span` of a stack from its frames' (:func:`_by_frame`): the range of the nodes a triangle uses in
    some frame; where no frame has such a triangle, every frame's span is its finite range, and theirs is the stack's
    finite range."""
    used: list[tuple[float, float]] = []
    finite: list[tuple[float, float]] = []
    for frame in _frames(heights):
        span, any_used = _used_span(frame)
        if span is not None:
            (used if any_used else finite).append(span)
    spans = used or finite
    if not spans:
        return None, False
    return (min(lo for lo, _ in spans), max(hi for _, hi in spans)), bool(used)


def _min_max(values: NDArray[Any]) -> tuple[float, ...]:
    """(min, max) of ``values`` as floats; () of none."""
    return (float(values.min()), float(values.max())) if values.size else ()


def used_nodes(finite: NDArray[np.bool_],
               triangles: tuple[NDArray[np.bool_], NDArray[np.bool_]] | None = None) -> NDArray[np.bool_]:
    """Per grid node (of the last two axes of ``finite``, the nodes' finite flags), whether a triangle with three
    finite heights uses it: the nodes of a stepped mesh. A finite node whose every cell touches nodata is in none.
    ``triangles``: :func:`finite_triangles` of ``finite`` where the caller has them already."""
    upper, lower = finite_triangles(finite) if triangles is None else triangles
    used = np.zeros_like(finite)
    used[..., :-1, :-1] |= upper | lower
    used[..., :-1, 1:] |= upper
    used[..., 1:, 1:] |= upper | lower
    used[..., 1:, :-1] |= lower
    return used


def grid_surface_counts(heights: NDArray[np.float32], has_nodata: bool | None = None) -> tuple[int, int]:
    """(vertices, faces) of the surface of an (H, W) grid of heights, the fewest its stepped mesh has: a vertex per
    node a triangle with three finite heights uses, a terrace face per such triangle (walls and twins add more).
    ``has_nodata``: whether some height is NaN, where the caller knows (:attr:`Terrain.has_nodata`)."""
    rows, cols = heights.shape
    finite = None
    if has_nodata is None:
        finite = np.isfinite(heights)
        has_nodata = not finite.all()
    if not has_nodata:
        return rows * cols, 2 * (rows - 1) * (cols - 1)
    if finite is None:
        finite = np.isfinite(heights)
    upper, lower = finite_triangles(finite)
    used = used_nodes(finite, (upper, lower))  # the nodes of those triangles, which are not asked again
    return int(np.count_nonzero(used)), int(np.count_nonzero(upper)) + int(np.count_nonzero(lower))


def is_real_dtype(dtype: np.dtype) -> bool:
    """True for a dtype of real numbers: signed or unsigned integers and floats, not bools. ``np.issubdtype(dtype,
    np.integer)`` also holds for ``timedelta64`` (numpy makes it a subtype of signedinteger): durations were taken
    as heights, levels and γ, and a (T, H, W) stack of them raised a TypeError."""
    return dtype.kind in "iuf"


def unmasked(values: Any) -> Any:
    """A numpy masked array with its masked entries as NaN (nodata), in float; anything else as it is.
    ``np.asarray`` drops the mask, which would step the values under it as real heights."""
    if not np.ma.isMaskedArray(values):
        return values
    if np.issubdtype(values.dtype, np.floating):
        return np.ma.filled(values, np.nan)
    if is_real_dtype(values.dtype):  # integers (floats are filled above)
        return np.ma.filled(values.astype(np.float64), np.nan)
    return np.ma.getdata(values)  # not real numbers: refused by the caller's dtype check


class _TooLarge(ValueError):
    """:func:`as_number`'s error for a number beyond float64 (10**400)."""


def as_number(value: Any) -> float:
    """``float(value)`` for a real number; a TypeError for text and bools, which ``float`` would also take ("1",
    True) and which are slips (a value read from a file or a flag in the wrong place), not numbers. An integer
    beyond float64 (10**400) is a ValueError: ``float``'s OverflowError is none, and went past callers that
    catch (TypeError, ValueError)."""
    if isinstance(value, (str, bytes, bool, np.bool_)) or (isinstance(value, np.ndarray) and value.dtype.kind in "bSU"):
        raise TypeError(f"not a number: {value!r}")  # a 0-d array of text or a bool too: float() takes them alike
    try:
        return float(value)
    except OverflowError:
        kind = "an integer" if isinstance(value, numbers.Integral) else "a number"
        raise _TooLarge(f"{kind} too large for a float (beyond ±{sys.float_info.max:.2g})") from None


def number_or_nan(value: Any) -> float:
    """``value`` as a float when :func:`as_number` takes it, else NaN (text, a bool, an int beyond float64, not a
    number at all), which the caller's range check then refuses in its own words."""
    try:
        return as_number(value)
    except (TypeError, ValueError):
        return math.nan


def finite_number(value: Any, name: str, *, positive: bool = False, lo: float | None = None,
                  hi: float | None = None, unit: str = "") -> float:
    """``value`` as a finite float (within [lo, hi], positive if asked), else an :class:`InvalidInputError`
    naming ``name``; ``unit="rad"`` shows an angle's bounds in degrees as well."""
    try:
        number = as_number(value)
    except _TooLarge as exc:  # its 400 digits would say less
        raise InvalidInputError(f"{name} must be finite; got {exc}") from None
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number; got {plain_repr(value)}") from None
    if not math.isfinite(number):
        raise InvalidInputError(f"{name} must be finite; got {plain_repr(value)}")
    if positive and number <= 0:
        raise InvalidInputError(f"{name} must be positive; got {number}")
    if (lo is not None and number < lo) or (hi is not None and number > hi):
        shown = f"{math.degrees(number):g} degrees" if unit == "rad" else f"{number:g}"
        if lo is not None and hi is not None:
            span = (f"lie in [{math.degrees(lo):g}, {math.degrees(hi):g}] degrees ([{lo:g}, {hi:g}] radians)"
                    if unit == "rad" else f"lie in [{lo:g}, {hi:g}]")
        else:  # one bound
            sign, bound = (">=", lo) if hi is None else ("<=", hi)
            span = (f"be {sign} {math.degrees(bound):g} degrees ({bound:g} radians)" if unit == "rad"
                    else f"be {sign} {bound:g}")
        raise InvalidInputError(f"{name} must {span}; got {shown}")
    return number


def check_flag(value: Any, name: str) -> bool:
    """``value`` when it is a bool (Python's or numpy's), else an :class:`InvalidInputError` naming ``name``: a
    string such as "no" is true to Python, and would switch the option on."""
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidInputError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def optional_text(value: Any, name: str, what: str) -> str | None:
    """``value`` when it is a str or None, else an :class:`InvalidInputError` naming ``name``: a number or an
    object there was stored as it is and reached the mesh metadata (and the files written from it)."""
    if value is not None and not isinstance(value, str):
        raise InvalidInputError(f"{name} must be a str ({what}) or None; got {value!r:.80}")
    return value


def is_name(value: Any, names: Sequence[str | None]) -> bool:
    """Whether ``value`` is one of ``names`` (None too when it is among them): ``value in names`` compared an
    array with each name, and numpy's "truth value of an array is ambiguous" ValueError escaped."""
    return (value is None and None in names) or (isinstance(value, str) and value in names)


def as_array(values: Any, name: str, expected: str) -> NDArray[Any]:
    """``np.asarray(values)``, else an InvalidInputError "``name`` must be ``expected``; got rows of different
    lengths": numpy's "inhomogeneous shape" ValueError for ragged nested lists named no argument."""
    try:
        return np.asarray(values)
    except ValueError:  # ragged rows
        raise InvalidInputError(f"{name} must be {expected}; got rows of different lengths") from None


def real_numbers(values: ArrayLike, name: str, expected: str) -> NDArray[np.float64]:
    """``values`` as float64 when they are real numbers (a masked array's masked entries NaN), else an
    InvalidInputError "``name`` must be ``expected``": text and ragged rows raised numpy's ValueError, complex
    values lost their imaginary part, a bool beside numbers in a list ((True, 2.0)) became 1.0. An object array
    (numpy's dtype for an int beyond int64, 10**20) is read number by number through :func:`as_number`."""
    array = as_array(unmasked(values), name, expected)
    if array.dtype == object:
        return _object_numbers(array, name, expected)
    if not is_real_dtype(array.dtype):
        raise InvalidInputError(f"{name} must be {expected} (real numbers); got dtype {array.dtype}")
    at = _first_bool(values) if isinstance(values, (list, tuple)) else None
    if at is not None:
        raise InvalidInputError(f"{name} must be {expected} (real numbers); got a bool ({at[1]!r}) at index {at[0]}")
    return array.astype(np.float64)


def real_vector(value: Any, name: str, expected: str, size: int) -> NDArray[np.float64]:
    """``value`` as ``size`` finite float64 numbers (flattened), else an InvalidInputError "``name`` must be
    ``expected``; got ``value``": ``np.asarray(value, dtype=float)`` raised numpy's ValueError for text and took
    True as 1."""
    try:
        array = real_numbers(value, name, expected).reshape(-1)
    except InvalidInputError:
        array = np.full(0, np.nan)
    if array.shape != (size,) or not np.isfinite(array).all():
        raise InvalidInputError(f"{name} must be {expected}; got {value!r}")
    return array


def _first_bool(values: list[Any] | tuple[Any, ...], at: tuple[int, ...] = ()) -> tuple[tuple[int, ...], Any] | None:
    """The index and value of the first bool in nested lists and tuples (numpy bool arrays in them too), else
    None: numpy turns it into a number beside numbers."""
    for k, value in enumerate(values):
        if isinstance(value, (bool, np.bool_)):
            return (*at, k), value
        if isinstance(value, (list, tuple)):
            found = _first_bool(value, (*at, k))
            if found is not None:
                return found
        elif isinstance(value, np.ndarray) and value.dtype == bool and value.size:
            return (*at, k, *(0,) * value.ndim), value.flat[0]
    return None


def _object_numbers(array: NDArray[np.object_], name: str, expected: str) -> NDArray[np.float64]:
    """An object array's values as float64 through :func:`as_number`, else an InvalidInputError naming the first
    value that is not a real number (text, a bool, None, a sequence) or is an integer beyond float64, and its
    index."""
    out = np.empty(array.shape, np.float64)
    flat = out.reshape(-1)
    for k, value in enumerate(array.reshape(-1)):
        try:
            if isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray) and value.ndim):
                raise TypeError("a sequence")  # a row of a ragged object array: float() took a one-element one
            flat[k] = as_number(value)
        except (TypeError, ValueError) as exc:
            at = "" if array.ndim == 0 else f" at index {tuple(int(i) for i in np.unravel_index(k, array.shape))}"
            if isinstance(exc, _TooLarge):
                raise InvalidInputError(f"{name} must be {expected}; got {exc}{at}") from None
            got = f"a bool ({value!r})" if isinstance(value, (bool, np.bool_)) else f"dtype object: {value!r}"
            raise InvalidInputError(f"{name} must be {expected} (real numbers); got {got}{at}") from None
    return out


def unshared(out: NDArray[Any], given: Any, seen: NDArray[Any]) -> NDArray[Any]:
    """``out``, copied when it shares memory with ``seen``, the array numpy made of the caller's ``given``: an
    ndarray's buffer, or the one an array-like exposes (a memoryview, an object with ``__array__`` such as an
    xarray DataArray or a DataFrame). What is checked and cached must not see the caller's later changes; a list
    or tuple was copied by numpy already."""
    if not isinstance(given, (list, tuple)) and np.may_share_memory(out, seen):
        return out.copy()
    return out


def check_mapped(array: Any, name: str) -> None:
    """An :class:`~stepterrain.errors.OutputTooLargeError` naming ``name``, the shape and the bytes when ``array`` is a
    memory map (``np.load(..., mmap_mode="r")``, ``np.memmap``) whose float32 copy exceeds the memory budget
    (:func:`stepterrain.set_memory_budget`): the map's data is on disk, and the copy read all of it into memory
    whatever the budget said. Anything else passes (its data is in memory already)."""
    if isinstance(array, np.memmap):
        check_budget(
            array.size * 4,
            f"reading {name} (a memory-mapped array of shape {tuple(array.shape)}, {array.dtype}) into memory as "
            "float32",
            hint="slice the map to the region needed first (a slice of a map stays on disk)",
        )


def unwrapped_longitudes(lon: NDArray[np.float64]) -> NDArray[np.float64]:
    """A longitude axis (degrees, 1-D) with its jumps across the antimeridian taken out: where neighbours differ by
    more than 180°, a whole multiple of 360° is added or subtracted from there on (as ``np.unwrap`` with period 360,
    but in exact multiples), so [178, 179, 180, -179] is [178, 179, 180, 181] and [358, 359, 0, 1] is
    [358, 359, 360, 361], steps of 1°. Neighbouring columns are thus never more than 180° apart; an axis without
    such a jump is returned as is, and one that is uneven stays uneven (a jump of 300° becomes one of -60°)."""
    with np.errstate(over="ignore", invalid="ignore"):  # steps beyond float64 (1e308 to -1e308): left to the caller
        turns = -np.round(np.diff(lon) / 360.0)
    if not turns.any() or not np.isfinite(turns).all():
        return lon
    return lon + 360.0 * np.concatenate(([0.0], np.cumsum(turns)))


def sorted_unique(values: NDArray[np.integer]) -> NDArray[np.integer]:
    """``np.unique(values)`` of integers (flattened, sorted, each value once) by a sort and a neighbour compare:
    numpy 2.x hashes integers for a value-only ``np.unique``, 5-7x slower than this for a close-up's 0.6-1.4M face
    corners (int64) of the shared DEM, ~70x for 3M distinct int64 keys. (Floats would keep each NaN, which
    ``np.unique`` collapses: integers only.)"""
    ordered = np.sort(values, axis=None)
    keep = np.empty(ordered.size, dtype=bool)
    keep[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=keep[1:])
    return ordered[keep]


def first_index(mask: NDArray[np.bool_]) -> tuple[int, ...]:
    """The index of the first true entry of a non-empty ``mask`` with one (row-major), for error messages."""
    return tuple(int(i) for i in np.argwhere(mask)[0])


def first_beyond_float32(array: NDArray[Any]) -> tuple[float, tuple[int, ...]]:
    """The first finite value of ``array`` that float32 cannot hold (a cast makes it infinite), and its index.
    For the error path only: it is a full pass, which :func:`float32_heights` takes only after the cast overflowed."""
    with np.errstate(over="ignore"):
        overflowed = np.isinf(np.asarray(array, dtype=np.float32)) & np.isfinite(array)
    at = first_index(overflowed)
    return float(array[at]), at


def float32_heights(array: NDArray[Any], name: str) -> NDArray[np.float32]:
    """``array`` (real numbers) as C-contiguous float32. A finite value beyond float32's range (1e300 in float64)
    is an InvalidInputError naming ``name``, the value and its index, not an infinity with numpy's "overflow
    encountered in cast" warning; the common path costs only the cast (the overflow is trapped by np.errstate)."""
    if array.dtype.kind != "f" or array.dtype.itemsize <= 4:  # integers and float16/32 always fit
        return np.ascontiguousarray(array, dtype=np.float32)
    try:
        with np.errstate(over="raise"):
            return np.ascontiguousarray(array, dtype=np.float32)
    except FloatingPointError:
        value, at = first_beyond_float32(array)
        raise InvalidInputError(f"{name} must fit in float32 (|h| < {FLOAT32_MAX:.2g}); got {value!r} at index {at}, "
                                "finite but beyond float32's range") from None


def finite_or_nan(heights: NDArray[np.floating], name: str) -> tuple[float, float]:
    """The min and max of float ``heights`` (NaN when there is nodata), else an :class:`InvalidInputError` naming
    ``name`` and the index of the first infinite value: two passes that also find an infinite value, instead of
    an isinf pass and a mask (that runs only when the min or max is not finite)."""
    lo, hi = float(heights.min()), float(heights.max())  # NaN propagates through both, and an infinity shows in one
    if not (math.isfinite(lo) and math.isfinite(hi)) and np.isinf(heights).any():
        bad = first_index(np.isinf(heights))
        raise InvalidInputError(f"{name} must be finite or NaN (nodata); got an infinite value at index {bad}")
    return lo, hi


def _heights_array(
    heights: ArrayLike, name: str = "heights", *, borrow: bool = False
) -> tuple[NDArray[np.float32], float, float]:
    """The heights as a C-contiguous float32 array the Terrain owns, and their min and max (NaN when there is
    nodata; :func:`finite_or_nan`). A finite value beyond float32 is trapped in the cast (:func:`float32_heights`),
    so it is not reported as infinite. ``borrow``: float32 C-contiguous heights are not copied (see
    :func:`as_terrain`). A memory map is checked against the memory budget first (:func:`check_mapped`)."""
    check_mapped(heights, name)
    arr = as_array(unmasked(heights), name, "a real-valued (H, W) array")
    if not is_real_dtype(arr.dtype):
        raise InvalidInputError(f"{name} must be a real-valued (H, W) array; got dtype {arr.dtype}")
    at = _first_bool(heights) if isinstance(heights, (list, tuple)) else None  # numpy made True a height of 1
    if at is not None:
        raise InvalidInputError(f"{name} must be a real-valued (H, W) array; got a bool ({at[1]!r}) at index {at[0]}")
    if arr.ndim != 2:
        raise InvalidInputError(f"{name} must be a 2-D (H, W) array; got shape {arr.shape}")
    if arr.shape[0] < 2 or arr.shape[1] < 2:
        raise InvalidInputError(f"{name} needs at least 2 x 2 nodes; got shape {arr.shape}")
    out = float32_heights(arr, name)
    if not borrow:
        out = unshared(out, heights, arr)  # the Terrain's caches must not see later changes
    lo, hi = finite_or_nan(out, name)
    return out, lo, hi


def _in_metres(shape: tuple[int, ...], spacing: tuple[float, float], origin: tuple[float, float], crs: str | None,
               source: str | None, height_unit: str | None = None,
               ) -> tuple[tuple[float, float], tuple[float, float], str | None, str | None]:
    """(spacing, origin, crs, source) of a grid as the Terrain keeps them: a geographic ``crs``'s degrees made local
    metres as load_dem makes a file's (:func:`stepterrain.io.degrees_as_local_metres`), a projected one's feet (or
    another unit) made metres as load_dem makes them (:func:`stepterrain.io.units_as_metres`, which warns when
    ``height_unit`` is None), anything else as given; a projected one's map scale over the grid checked as load_dem
    checks a file's (:func:`stepterrain.io.check_projected_scale`)."""
    if not crs:
        return spacing, origin, crs, source
    from .io import check_projected_scale, degrees_as_local_metres, units_as_metres  # io imports this module

    size = (int(shape[0]), int(shape[1]))
    placed = degrees_as_local_metres(size, spacing, origin, crs, source)
    if placed is None:
        placed = units_as_metres(spacing, origin, crs, source, height_unit)
        check_projected_scale(size, spacing, origin, crs, source)  # in the CRS's unit, as given: after, as load_dem
    return (spacing, origin, crs, source) if placed is None else placed


def _grid_fields(
    heights: ArrayLike, spacing: Any, origin: Any, crs: str | None, source: str | None, *, borrow: bool = False,
    placed: bool = False, height_unit: str | None = None,
) -> tuple[NDArray[np.float32], tuple[float, float], tuple[float, float], str | None, str | None, dict[str, Any]]:
    """A grid Terrain's (heights, spacing, origin, crs, source) checked as :meth:`Terrain.from_heights` and a grid
    built directly keep them (:func:`_heights_array`, :func:`grid_geometry`, :func:`_in_metres`), and its first
    cache entries: the checks' min and max answer has_nodata and, without nodata, height_range (no further passes).
    ``placed``: ``crs``, ``spacing`` and ``origin`` are a placed grid's already (a Terrain's own, crop or coarsened,
    or load_dem's placement of a file): :func:`_in_metres`, which would look the CRS up again, is skipped."""
    array, lo, hi = _heights_array(heights, borrow=borrow)
    spacing, origin = grid_geometry(spacing, origin, array.shape)
    if not placed:
        spacing, origin, crs, source = _in_metres(array.shape, spacing, origin, crs, source, height_unit)
    cache: dict[str, Any] = {"has_nodata": math.isnan(lo)}
    if not math.isnan(lo):
        cache["height_range"] = (lo, hi)
    return array, spacing, origin, crs, source, cache


def _placed_metadata(t: Terrain) -> dict[str, Any]:
    """A Terrain's CRS and source, those set, as a mesh's metadata records them (as stepped's mesh does): a file of
    dem.mesh() named no CRS."""
    return {key: value for key, value in (("crs", t.crs), ("source", t.source)) if value}


def _metadata_text(mesh: trimesh.Trimesh, key: str) -> str | None:
    """A mesh's ``metadata[key]`` when it is text that is not blank (a file's CRS or source, as
    :func:`_placed_metadata` records them), else None: other values (numbers, objects a loader left) name nothing."""
    value = mesh.metadata.get(key)
    return value if isinstance(value, str) and value.strip() else None


def _described(value: Any) -> str:
    """A short description of an argument's value for an error message: an array's shape and dtype, else its repr."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}, dtype {value.dtype}"
    return f"{value!r:.80}"


@dataclass(frozen=True, eq=False)
class Terrain:
    """A terrain surface ready for the kernels.

    ``kind == "grid"``: ``heights`` (H, W) float32 (NaN = nodata); node (i, j) lies at
    ``origin + (j * dx, i * dy)``; ``dx`` or ``dy`` may be negative (north-up rasters have ``dy < 0``).
    ``kind == "tin"``: ``points`` (N, 3) float64 and ``faces`` (F, 3) int64, wound counter-clockwise seen
    from +z, with the edge table ``edges`` (E, 2) and ``face_edges`` (F, 3) built once. The arrays are
    read-only (the caches derive from them): build a new Terrain for changed heights. Built directly
    (``Terrain(kind=..., heights=...)``, or by ``dataclasses.replace``) it is checked as :meth:`from_heights` and
    :meth:`from_mesh` check (an :class:`InvalidInputError` naming the field: heights not a real (H, W) array of at
    least 2 x 2 nodes, infinite or beyond float32; spacing not a non-zero pair; origin not a finite pair; a TIN
    without points (N, 3) and faces (F, 3), whose edge tables are then rebuilt and whose ``heights`` must be None or
    its points' z) and takes a float32 copy of the arrays given, so that the caller's later changes to them cannot
    reach the cached uploads, nodata flag and height range; :meth:`from_heights` and :meth:`from_mesh` copy once
    while checking. ``height_unit`` is the length unit a grid's (or TIN's) heights were read in, as its source
    named it (:func:`~stepterrain.io.load_dem`: ``height_unit=`` or the file's own; "ft", "m"), the heights being metres
    since; None when no unit was named: the heights are as stored. ``face_index``: a TIN's faces' rows in the mesh
    given (faces with nodata left out), kept where its visual holds face colours, which the steps carry (else None).
    """

    kind: Literal["grid", "tin"]
    heights: NDArray[np.float32]
    spacing: tuple[float, float] = (1.0, 1.0)
    origin: tuple[float, float] = (0.0, 0.0)
    points: NDArray[np.float64] | None = None
    faces: NDArray[np.int64] | None = None
    edges: NDArray[np.int32] | None = None
    face_edges: NDArray[np.int32] | None = None
    point_used: NDArray[np.int32] | None = None
    crs: str | None = None
    source: str | None = None
    visual: Any = None
    height_unit: str | None = None
    face_index: NDArray[np.int64] | None = None
    _device_cache: dict = field(default_factory=dict, repr=False, compare=False)
    _owned: InitVar[bool] = False  # the constructors' own arrays (or a borrow within one call): no copy

    def __post_init__(self, _owned: bool) -> None:
        if not _owned:  # built directly (or by dataclasses.replace): checked as the constructors check, copied once
            self._check_direct()
            _owned = True
        # what the caches hold (nodata flag, device uploads, edge tables) derives from these arrays: read-only
        # views, so that changing them in place raises instead of stepping stale caches. Arrays a caller gave
        # Terrain(...) directly are copied first: a read-only view of them still changed with the caller's array
        # while the caches kept the old heights (a stepped mesh clamped to the old height range, silently)
        for name in ("heights", "points", "faces", "edges", "face_edges", "point_used", "face_index"):
            array = getattr(self, name)
            if not isinstance(array, np.ndarray):
                continue
            if not _owned:
                array = array.copy()
            if array.flags.writeable:
                array = array.view()
                array.flags.writeable = False
            object.__setattr__(self, name, array)

    def _check_direct(self) -> None:
        """Check and normalise the fields of a Terrain built directly, as :meth:`from_heights` and
        :meth:`from_mesh` do: lists, 1-D arrays, text spacings and the like reached the kernels and failed there
        (or were meshed wrongly: a 3-number spacing, a zero one). The arrays become the Terrain's own copies, and
        the caches start empty (``dataclasses.replace`` passed the old terrain's)."""
        set_field = object.__setattr__
        if not isinstance(self.kind, str) or self.kind not in ("grid", "tin"):
            raise InvalidInputError(f"kind must be 'grid' or 'tin'; got {self.kind!r}")
        set_field(self, "crs", optional_text(self.crs, "crs", "e.g. 'EPSG:32611'"))
        set_field(self, "source", optional_text(self.source, "source", "where the terrain comes from"))
        set_field(self, "height_unit", optional_text(self.height_unit, "height_unit", "the unit the heights were read "
                                                     "in, e.g. 'ft'"))
        set_field(self, "_device_cache", {})
        if self.visual is not None and not isinstance(self.visual, trimesh.visual.base.Visuals):
            # any object was taken and ignored: a grid's or TIN's steps came out without the colours meant
            raise InvalidInputError(f"visual must be a trimesh visual (trimesh.visual.ColorVisuals or TextureVisuals) "
                                    f"or None; got {_described(self.visual)}")
        if self.kind == "grid":
            extra = [name for name in ("points", "faces", "edges", "face_edges", "point_used", "face_index")
                     if getattr(self, name) is not None]
            if extra:
                raise InvalidInputError(f"a Terrain of kind 'grid' takes heights, spacing and origin; got "
                                        f"{', '.join(extra)} too (a TIN's fields: use kind='tin' or Terrain.from_mesh)")
            array, spacing, origin, crs, source, cache = _grid_fields(self.heights, self.spacing, self.origin,
                                                                      self.crs, self.source,
                                                                      height_unit=self.height_unit)
            set_field(self, "heights", array)  # a copy: unshared with the array given
            set_field(self, "spacing", spacing)
            set_field(self, "origin", origin)
            set_field(self, "crs", crs)
            set_field(self, "source", source)
            self._device_cache.update(cache)
            return
        if self.points is None or self.faces is None:
            raise InvalidInputError("a Terrain of kind 'tin' needs points (N, 3) and faces (F, 3); got "
                                    f"points {_described(self.points)}, faces {_described(self.faces)}: build it with "
                                    "Terrain.from_mesh(trimesh.Trimesh(points, faces, process=False))")
        points = real_numbers(self.points, "points", "an (N, 3) array of x, y, z")
        if points.ndim != 2 or points.shape[1] != 3:
            raise InvalidInputError(f"points must be an (N, 3) array of x, y, z; got shape {points.shape}")
        faces = np.asarray(unmasked(self.faces))
        if faces.dtype.kind not in "iu" or faces.ndim != 2 or faces.shape[1] != 3:  # not bools, not timedelta64
            raise InvalidInputError(f"faces must be an (F, 3) integer array of point indices; got shape {faces.shape}, "
                                    f"dtype {faces.dtype}")
        if self.heights is not None:
            given = np.asarray(unmasked(self.heights))
            with np.errstate(over="ignore"):  # a point on no face may lie beyond float32 (inf, as _build_tin makes it)
                z32 = points[:, 2].astype(np.float32)
            if given.shape != (len(points),) or not np.array_equal(given, z32,
                                                                   equal_nan=given.dtype.kind == "f"):
                raise InvalidInputError(f"heights of a Terrain of kind 'tin' are its points' z (None to take them); "
                                        f"got {_described(self.heights)} that differs from points[:, 2]")
        built = Terrain._build_tin(trimesh.Trimesh(points, faces, process=False), self.visual, self.source,
                                   self.crs, self.height_unit)
        # rebuilt; crs and source as from_mesh makes them (degrees or feet made metres)
        for name in ("heights", "points", "faces", "edges", "face_edges", "point_used", "crs", "source"):
            set_field(self, name, getattr(built, name))
        set_field(self, "face_index", None if built.face_index is None else
                  _given_face_index(self.face_index, len(faces), self.visual)[built.face_index])
        set_field(self, "spacing", (1.0, 1.0))
        set_field(self, "origin", (0.0, 0.0))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_heights(
        cls,
        heights: ArrayLike,
        *,
        spacing: ArrayLike = (1.0, 1.0),
        origin: ArrayLike = (0.0, 0.0),
        crs: str | None = None,
        source: str | None = None,
        height_unit: str | None = None,
        _borrow: bool = False,
        _placed: bool = False,
    ) -> Terrain:
        """A regular heightfield: ``heights`` (H, W), NaN for nodata; ``spacing`` (dx, dy) non-zero;
        ``height_unit`` the length unit the heights were read in, now metres (see the class). A geographic ``crs``
        (EPSG:4326, ...) makes ``spacing`` and ``origin`` degrees, read into local metres as
        :func:`~stepterrain.io.load_dem` reads a file in degrees (origin (0, 0) at node (0, 0), a spherical
        ``+proj=eqc`` crs, the degrees in ``source``): the same Terrain as load_dem of the grid saved as a GeoTIFF.
        So does a projected (or local engineering) ``crs`` in a unit other than the metre (EPSG:2229, US survey
        feet): ``spacing`` and ``origin`` are in that unit, as the CRS's coordinates are, and become metres, ``crs``
        the same projection in metres (EPSG:26945) and ``source`` names the unit, as load_dem reads such a file
        (with rasterio to look the unit up; without it they are kept as given). The heights are not converted:
        they are metres whatever ``height_unit`` names (unlike ``load_dem(height_unit=...)``, which converts a
        file's); without ``height_unit`` a grid so converted warns that its heights are taken as given, as
        load_dem warns of a file's (heights in feet are the caller's to convert: ``heights * 1200 / 3937``,
        ``height_unit="US survey foot"``). A projected ``crs`` whose map scale over the grid is more than 1 % off
        the ground somewhere (Web Mercator far from the equator) warns, at the caller's line, as load_dem warns of
        such a file.
        (``_borrow`` is internal: see :func:`as_terrain`; so is ``_placed``: ``crs``, ``spacing`` and ``origin`` of a
        grid placed already, a Terrain's own or :func:`~stepterrain.io.load_dem`'s, not looked up again.)"""
        crs = optional_text(crs, "crs", "e.g. 'EPSG:32611'")
        source = optional_text(source, "source", "where the heights come from, e.g. a file name")
        height_unit = optional_text(height_unit, "height_unit", "the unit the heights were read in, e.g. 'ft'")
        array, spacing, origin, crs, source, cache = _grid_fields(heights, spacing, origin, crs, source, borrow=_borrow,
                                                                  placed=_placed, height_unit=height_unit)
        terrain = cls(
            kind="grid",
            heights=array,
            spacing=spacing,
            origin=origin,
            crs=crs,
            source=source,
            height_unit=height_unit,
            _owned=True,
        )
        terrain._device_cache.update(cache)  # has_nodata and height_range from the checks: no further passes
        return terrain

    @classmethod
    def from_mesh(cls, mesh: trimesh.Trimesh, *, source: str | None = None, height_unit: str | None = None
                  ) -> Terrain:
        """A TIN from a ``trimesh.Trimesh`` whose faces project one-to-one onto the xy plane.

        Faces touching a non-finite height are dropped (nodata), and a point on no kept face is in no mesh (its x, y
        and z unchecked: an unreferenced vertex, a void written as NaN, NaN, NaN); faces wound clockwise seen from
        above (the whole mesh, or some of its faces: tiles from exporters of opposite conventions, merged) are turned
        up; points that
        coincide (the same x, y and z, and vertex colour or UV) are welded, so a triangle soup (an STL file) or a
        mesh of several parts (a glTF's primitives) steps as one welded surface, and its solid has no walls inside
        (a per-node γ array is read at the first of such points; vertex colours built apart from the mesh with fewer
        rows than its points weld by position alone, and :func:`~stepterrain.stepped.stepped` refuses them);
        faces that fold over in projection, faces that overlap others in xy (two sheets one above the other, a
        spiral ramp over itself, a triangle inside another's face: an intersection of positive area; faces that
        only touch, at a corner or along an edge, are fine) and edges shared by more than two faces are refused,
        the error naming two overlapping faces and a point of xy inside both. The result
        (edge table and device uploads included) is cached on the mesh and reused while its vertices, faces,
        visual, CRS and source stay the same.

        The mesh's ``metadata["crs"]`` and ``["source"]`` (a file read back with
        :func:`~stepterrain.export.read_mesh`, a :meth:`mesh` or stepped mesh: text, not blank) become the TIN's
        ``crs`` and ``source`` (``source`` given here wins), so every mesh made of it (:func:`~stepterrain.stepped`,
        close-ups, drapes) names them as a grid's do. A geographic CRS (EPSG:4326, ...) makes the points' x and y
        degrees, read into local metres as :meth:`from_heights` reads a grid's (a spherical ``+proj=eqc`` crs true at
        their middle latitude, (0, 0) at their lowest longitude and latitude, the degrees in ``source``; longitudes
        across the antimeridian unwrapped; the same warnings, and a refusal of x and y that are no degrees); a
        projected (or local engineering) CRS in a unit other than the metre (EPSG:2229, US survey feet) makes them
        metres, ``crs`` its metre twin (EPSG:26945), as a grid's spacing and origin in it become (with rasterio to
        look the unit up). The heights (z) are not converted: without ``height_unit`` (the unit they were read in,
        as :meth:`from_heights` takes it) a TIN so converted warns that they are taken as given, as metres. A
        projected CRS's map scale over the points is checked as load_dem checks a grid's (a warning when it is far
        from 1: Web Mercator far from the equator).
        """
        if not isinstance(mesh, trimesh.Trimesh):
            raise InvalidInputError(f"terrain mesh must be a trimesh.Trimesh; got {type(mesh).__name__}")
        source = optional_text(source, "source", "where the mesh comes from, e.g. a file name")
        height_unit = optional_text(height_unit, "height_unit", "the unit the heights were read in, e.g. 'ft'")
        crs, named = (_metadata_text(mesh, key) for key in ("crs", "source"))
        source = named if source is None else source
        visual = mesh.visual if mesh.visual.defined else None
        # the visual's data too (trimesh hashes a visual's arrays, as it does the mesh's): its vertex colours or UVs
        # decide which coinciding points are welded, and the visual object stays the same when they are set anew
        # (mesh.visual.vertex_colors = ...): a seam they opened later was stepped welded, with the old colours' weld
        key = (hash(mesh), None if visual is None else hash(visual))
        cached = getattr(mesh, "_stepterrain_terrain", None)
        # the CRS and source as given, not the TIN's (degrees or feet made metres name the metres' CRS)
        given = (visual, source, crs, height_unit)
        if (cached is not None and cached[0] == key and cached[2][0] is visual and cached[2][1:] == given[1:]):
            return cached[1]
        terrain = cls._build_tin(mesh, visual, source, crs, height_unit)
        mesh._stepterrain_terrain = (key, terrain, given)
        return terrain

    @classmethod
    def _build_tin(cls, mesh: trimesh.Trimesh, visual: Any, source: str | None, crs: str | None,
                   height_unit: str | None = None) -> Terrain:
        points = np.array(mesh.vertices, dtype=np.float64)
        faces = np.array(mesh.faces, dtype=np.int64).reshape(-1, 3)
        if len(faces) == 0:
            cloud = (f"; got {counted(len(points), 'point')} without faces (a point cloud, as a .ply or .xyz of "
                     "survey points reads): triangulate them in xy first, e.g. mesh = trimesh.Trimesh(mesh.vertices, "
                     "scipy.spatial.Delaunay(mesh.vertices[:, :2] - mesh.vertices[:, :2].min(axis=0)).simplices)"
                     if len(points) >= 3 else "")
            raise InvalidInputError(f"terrain mesh has no faces; expected a triangulated surface{cloud}")
        outside = (faces < 0) | (faces >= len(points))  # numpy would wrap -1 silently, and raise IndexError beyond
        if outside.any():
            bad = int(np.flatnonzero(outside.any(axis=1))[0])
            raise InvalidInputError(
                f"terrain mesh faces must index its vertices (0 to {len(points) - 1}); face {bad} is "
                f"{faces[bad].tolist()}; the mesh has {counted(len(points), 'vertex', 'vertices')}"
            )
        repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
        if repeated.any():
            bad = int(np.flatnonzero(repeated)[0])
            raise InvalidInputError(
                f"terrain mesh faces must have three distinct vertices; face {bad} is {faces[bad].tolist()} "
                f"({counted(int(repeated.sum()), 'such face')}): drop them first, e.g. "
                "mesh.update_faces(mesh.faces[:, 0] != mesh.faces[:, 1]) and the like"
            )
        z_ok = np.isfinite(points[:, 2])
        valid = z_ok[faces].all(axis=1)
        faces = faces[valid]
        if len(faces) == 0:
            raise InvalidInputError("terrain mesh has no face with three finite heights")
        # the points on a kept face only: a point on no face, or only on faces dropped for a nodata height (a vertex
        # written as NaN, NaN, NaN), is in no mesh; the whole mesh was refused for its x or y, or its z beyond float32
        too_large = np.flatnonzero(z_ok & (np.abs(points[:, 2]) > FLOAT32_MAX))
        too_large = too_large[np.isin(too_large, faces)]
        if too_large.size:  # the kernels get float32 heights
            k = int(too_large[0])
            raise InvalidInputError(
                f"terrain mesh heights must fit in float32 (|z| < 3.4e+38); vertex {k} has z={float(points[k, 2])!r}"
            )
        xy_bad = np.flatnonzero(~np.isfinite(points[:, :2]).all(axis=1))
        xy_bad = xy_bad[np.isin(xy_bad, faces)]
        if xy_bad.size:
            k = int(xy_bad[0])
            raise InvalidInputError(f"terrain mesh vertices on a face with finite heights must have finite x and y; "
                                    f"vertex {k} is {points[k].tolist()}")
        if crs:  # degrees or feet made metres, as a grid's (before any check of the points' extent or areas)
            from .io import points_as_metres  # io imports this module

            used = np.zeros(len(points), dtype=bool)
            used[faces.reshape(-1)] = True
            placed = points_as_metres(points[:, :2], used, crs, source, height_unit, faces)
            if placed is not None:
                points[:, :2], crs, source = placed
        xy = points[:, :2]
        point_used = np.zeros(len(points), dtype=np.int32)
        point_used[faces.reshape(-1)] = 1
        used_xy = xy[point_used != 0]  # the kept faces' extent: a stray point must not widen the tolerance
        with np.errstate(over="ignore"):  # a span beyond float64 (x from -1e308 to 1e308) is inf: refused below
            span = np.ptp(used_xy, axis=0)
        if (span > FLOAT32_MAX).any():  # the kernels get xy relative to the lower-left corner in float32
            raise InvalidInputError(
                f"terrain mesh x and y must span at most {FLOAT32_MAX:.2g} (float32 coordinates relative to its "
                f"corner); got x over {span[0]:.6g}, y over {span[1]:.6g}"
            )
        a, b, c = xy[faces[:, 0]], xy[faces[:, 1]], xy[faces[:, 2]]  # after the span check: differences are finite
        area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        scale = max(float(span[0] * span[1]), 1e-300)
        tol = 1e-12 * scale
        positive, negative = area2 > tol, area2 < -tol
        flipped = bool(negative.sum() > positive.sum())
        if flipped:
            faces = faces[:, ::-1].copy()
            positive, negative = negative, positive
        if not positive.any():  # zero-area slivers beside real faces are stepped; a TIN of nothing else is a line
            raise InvalidInputError(
                f"terrain mesh faces must project one-to-one onto the xy plane; none of its "
                f"{counted(len(faces), 'face')} with finite heights has an area in xy (the points lie on a line or at "
                f"one point: x over {span[0]:.6g}, y over {span[1]:.6g}), so it is no height field"
                f"{_y_up_hint(points, faces, flipped)}"
            )
        folded: Callable[[], InvalidInputError] | None = None
        if negative.any():
            def refusal(turned: NDArray[np.int64] = faces) -> InvalidInputError:
                """The refusal of the fold, made only when refused (its hints take passes over every face: 0.13 s
                and ~200 MB a million faces, on a TIN that then steps), of the faces as wound before the turn below."""
                given = turned.copy()
                given[negative] = given[negative, ::-1]
                used = np.zeros(len(points), dtype=np.int32)  # point_used before welding
                used[given.reshape(-1)] = 1
                return InvalidInputError(
                    _folded_message(points, given, negative, np.flatnonzero(valid), flipped, source)
                    + _y_up_hint(points, given, flipped) + _float32_hint(points, used))

            folded = refusal
            # Faces wound down that overlap no other face are only wound the other way (tiles from exporters of
            # opposite conventions, merged): turned up. A face that folds over shares an edge with a neighbour, run
            # the other way; turned, the two run it the same way in xy (refused here, also where the points are kept
            # apart, as in a soup with a colour per corner) and the edge table refuses it as well, as the overlap
            # check refuses a face turned onto another one: either way the fold is refused.
            faces[negative] = faces[negative, ::-1]  # faces is this call's own (np.array, masked, flipped copies)
            positive = positive | negative
            if _same_way_in_xy(xy, faces[positive]):
                raise folded()
        welded = _welded(points, faces, visual)
        try:
            edges, face_edges = _edge_table(welded, len(points), np.flatnonzero(valid))
        except InvalidInputError:
            if folded is not None:
                raise folded() from None
            if welded is faces:
                raise
            # coincident points kept apart (two copies of a face, welded, share their edges): as given, the overlap
            # check below names the faces
            edges, face_edges = _edge_table(faces, len(points), np.flatnonzero(valid))
        else:
            if welded is not faces:
                faces = welded
                point_used[:] = 0
                point_used[faces.reshape(-1)] = 1
        corner = used_xy.min(axis=0)
        with np.errstate(over="ignore"):  # a stray point (on no kept face) far away may go to inf: no face's
            overlap = _overlap_in_xy(xy - corner, faces, positive, face_edges, len(edges))
        if overlap is not None and folded is not None:
            raise folded()
        if overlap is not None:  # faces that do not fold, stacked or wrapped over each other (see _overlap_in_xy)
            first, second, point, count = overlap
            kept = np.flatnonzero(valid)  # the faces' indices in the mesh given
            x, y = point + corner
            named = "terrain mesh" if source is None else f"terrain mesh (from {source!r})"
            raise InvalidInputError(
                f"{named} faces must project one-to-one onto the xy plane; faces {int(kept[first])} and "
                f"{int(kept[second])} overlap in xy around ({x:.10g}, {y:.10g}) (at least {count} of its {len(faces)} "
                "faces with finite heights overlap another: two sheets one above the other, or a surface that wraps "
                f"over itself){_y_up_hint(points, faces, flipped)}{_float32_hint(points, point_used)}"
            )
        with np.errstate(over="ignore"):  # a point on no face beyond float32 (refused above on a kept face): inf,
            # which no pass reads (its "overflow encountered in cast" warning was an error under -W error)
            heights = np.ascontiguousarray(points[:, 2], dtype=np.float32)
        return cls(
            kind="tin",
            heights=heights,
            points=points,
            faces=faces,
            edges=edges,
            face_edges=face_edges,
            point_used=point_used,
            crs=crs,
            source=source,
            visual=visual,
            height_unit=height_unit,
            # which input face each kept face is, for the face colours the steps carry (stepped._carry_visual)
            face_index=np.flatnonzero(valid) if _face_coloured(visual) else None,
            _owned=True,
        )

    # ------------------------------------------------------------------ properties
    @property
    def shape(self) -> tuple[int, ...]:
        """(H, W) for a grid, (N,) points for a TIN."""
        return tuple(self.heights.shape)

    @property
    def nodata_mask(self) -> NDArray[np.bool_]:
        """True where the height is nodata (NaN)."""
        return ~np.isfinite(self.heights)

    @property
    def has_nodata(self) -> bool:
        """True when some height is nodata (NaN); computed once per terrain (NaN propagates through min: one
        pass, no temporary mask)."""
        return bool(self.cached("has_nodata", lambda: bool(np.isnan(self.heights.min()))))

    def used_heights(self) -> NDArray[np.float32]:
        """The heights the surface is made of (a copy): a grid's nodes on a triangle with three finite heights
        (:func:`used_nodes`; all of them without nodata), a TIN's points on kept faces."""
        if self.kind == "grid" and not self.has_nodata:
            return self.heights.reshape(-1).copy()
        return self.heights[self._used_mask()]

    def _used_mask(self) -> NDArray[np.bool_]:
        """Per node (the grid's shape; a TIN's point), whether the surface uses it (:meth:`used_heights`): a grid's
        node on a triangle with three finite heights (:func:`used_nodes`), a TIN's point on a kept face."""
        if self.kind == "tin":
            return self.point_used != 0
        return used_nodes(np.isfinite(self.heights))

    @property
    def height_range(self) -> tuple[float, float]:
        """(min, max) of the heights the surface is made of (:meth:`used_heights`: a grid's node on no triangle with
        three finite heights, a TIN's point on no kept face, is in no mesh and would move the isovalues, the colours by
        level and a solid's floor); of a grid's finite heights where no triangle has three (its mesh is empty);
        computed once per terrain. A grid without nodata takes two passes and no copy."""

        def compute() -> tuple[float, ...]:
            if self.kind == "grid":
                if not self.has_nodata:
                    return float(self.heights.min()), float(self.heights.max())
                return self._used_span()[0] or ()
            return _min_max(self.used_heights())

        return self._cached_range("height_range", compute)

    def _used_span(self) -> tuple[tuple[float, float] | None, bool]:
        """A grid's :func:`_used_span` (its used range, whether some triangle has three finite heights); computed
        once per terrain (the heights are read-only): :attr:`height_range` and :meth:`_has_triangles` of a grid with
        nodata share its pass over the triangles."""
        return self.cached("used_span", lambda: _used_span(self.heights))

    def _has_triangles(self) -> bool:
        """Whether the surface has a face: a grid triangle with three finite heights (every grid without nodata has
        one), a TIN's kept face."""
        if self.kind == "tin":
            return bool(self.point_used.any())
        return not self.has_nodata or self._used_span()[1]

    def _welded_by_position(self) -> Terrain:
        """The terrain a solid is closed over: a TIN whose coinciding points were kept apart for their vertex colours
        or UVs (seams: :func:`_welded`) with those points welded by position alone, each seam's corners taking the
        colour or UV of the first copy; itself otherwise. The seams' boundary edges were closed by skirts down to the
        base on both sides, inside the solid (two bodies back to back; a soup with a colour per corner, a prism under
        every face), whose ``.stl``, its corners merged by position, read back not watertight. Computed once per
        terrain (a hash of the points and a new edge table: about 1.5 s a million faces, more than the solid's
        stepping; a mesh's Terrain is cached on it, so every solid of one mesh shares it)."""
        if self.kind != "tin" or self.visual is None:
            return self
        welded = self.cached("welded_by_position", self._build_welded_by_position)
        return self if welded is False else welded

    def _build_welded_by_position(self) -> Terrain | Literal[False]:
        """:meth:`_welded_by_position`'s terrain, False where it is ``self`` (no cycle through the cache)."""
        faces = _welded(self.points, self.faces, None)
        if faces is self.faces or np.array_equal(faces, self.faces):  # equal: points kept apart by a face of no
            return False  # area, which every weld keeps apart (no seam)
        try:
            edges, face_edges = _edge_table(faces, len(self.points))
        except InvalidInputError:  # welded, the seam's sides overlap (not a height field by position): kept apart
            return False
        point_used = np.zeros(len(self.points), dtype=np.int32)
        point_used[faces.reshape(-1)] = 1
        return replace(self, faces=faces, edges=edges, face_edges=face_edges, point_used=point_used,
                       _device_cache={}, _owned=True)

    def _used_nodes_in(self, values: ArrayLike) -> NDArray[np.intp]:
        """The flat indices of the nodes (a TIN's points) the surface uses (:meth:`used_heights`) whose height is one
        of ``values``, without copying the used heights: a grid's heights are compared where they lie, and only when
        one of ``values`` is among them and the grid has nodata are its triangles asked whether one uses such a node."""
        on = np.flatnonzero(np.isin(self.heights.reshape(-1), values))  # NaN (nodata) is in no values
        if self.kind == "tin":
            return on[self.point_used[on] != 0]
        if on.size == 0 or not self.has_nodata:
            return on
        return on[self._used_mask().reshape(-1)[on]]

    @property
    def finite_height_range(self) -> tuple[float, float]:
        """(min, max) of every finite height, a grid's nodes on no triangle included (a texture shades every pixel;
        :attr:`height_range` is the stepped surface's); computed once per terrain. A TIN's is its height_range."""
        if self.kind == "tin" or not self.has_nodata:
            return self.height_range
        return self._cached_range("finite_height_range", lambda: _min_max(self.heights[np.isfinite(self.heights)]))

    def _cached_range(self, key: str, compute: Any) -> tuple[float, float]:
        """``compute()``'s (min, max), computed once per terrain (``key``); () from it: no finite height, refused."""
        lo_hi = self.cached(key, compute)
        if not lo_hi:
            raise InvalidInputError("terrain has no finite height (all nodata)")
        return lo_hi

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) in world units (a TIN's computed once: its points are read-only)."""
        if self.kind == "tin":  # over every used point: ~11 ms a call at 1 M faces, which each close-up paid
            return self.cached("extent", self._tin_extent)
        h, w = self.heights.shape
        xs = (self.origin[0], self.origin[0] + (w - 1) * self.spacing[0])
        ys = (self.origin[1], self.origin[1] + (h - 1) * self.spacing[1])
        return (min(xs), max(xs), min(ys), max(ys))

    def __repr__(self) -> str:
        """A line naming the terrain: kind, shape (a TIN's points and faces), a grid's spacing and origin, the range
        of its finite heights (:attr:`finite_height_range`, computed once per terrain), whether it has nodata, and
        its height unit, CRS and source where known (a long PROJ string or WKT cut short). The dataclass's repr
        printed every array whole."""
        def short(text: str, limit: int = 60) -> str:
            return repr(text if len(text) <= limit else text[:limit - 3] + "...")

        if self.kind == "grid":
            parts = [f"shape={self.shape}", f"spacing=({self.spacing[0]:.10g}, {self.spacing[1]:.10g})",
                     f"origin=({self.origin[0]:.10g}, {self.origin[1]:.10g})"]
        else:
            parts = [f"points={len(self.points)}", f"faces={len(self.faces)}"]
        try:
            lo, hi = self.finite_height_range
            parts.append(f"heights=({lo:.10g}, {hi:.10g})")
        except InvalidInputError:  # all nodata
            parts.append("heights=()")
        parts.append(f"nodata={self.has_nodata}")
        parts += [f"{name}={short(value)}" for name, value in
                  (("height_unit", self.height_unit), ("crs", self.crs), ("source", self.source)) if value is not None]
        return f"Terrain(kind={self.kind!r}, {', '.join(parts)})"

    def _tin_extent(self) -> tuple[float, float, float, float]:
        used = self.points[self.point_used.astype(bool)]
        return (float(used[:, 0].min()), float(used[:, 0].max()), float(used[:, 1].min()), float(used[:, 1].max()))

    @property
    def local_origin(self) -> tuple[float, float]:
        """World position of local (0, 0): the grid origin, or the lower-left corner of the TIN's points on a
        kept face (a stray point elsewhere would cost the float32 local coordinates their precision)."""
        if self.kind == "grid":
            return self.origin
        return self.cached("local_origin", lambda: self.extent[::2])  # (xmin, ymin)

    def local_points(self) -> NDArray[np.float32]:
        """TIN points relative to :attr:`local_origin`, float32 (N, 3)."""
        ox, oy = self.local_origin
        local = np.empty((len(self.points), 3), dtype=np.float32)
        with np.errstate(over="ignore"):  # a point on no kept face far away goes to ±inf: no edge reads it
            local[:, 0] = self.points[:, 0] - ox
            local[:, 1] = self.points[:, 1] - oy
        local[:, 2] = self.heights
        return local

    def cached(self, key: Any, build: Any) -> Any:
        """Per-terrain cache (device uploads, edge tables): ``build()`` runs once per key."""
        value = self._device_cache.get(key)
        if value is None:
            value = build()
            self._device_cache[key] = value
        return value

    def mesh(self) -> trimesh.Trimesh:
        """The terrain as a ``trimesh.Trimesh`` (see :func:`heightfield_mesh`)."""
        if self.kind == "tin":  # its CRS and source, as heightfield_mesh records a grid's
            return trimesh.Trimesh(self.points, self.faces, process=False, metadata=_placed_metadata(self))
        return heightfield_mesh(self)

    # ------------------------------------------------------------------ smaller grids
    def crop(self, extent: ArrayLike) -> Terrain:
        """The grid's nodes inside ``extent`` = (xmin, xmax, ymin, ymax), in the terrain's own coordinates (those
        of :attr:`extent` and ``stepterrain info``; a geographic DEM's local metres), bounds included; a node at most
        half a centimetre (and a hundredth of a step) outside is kept too, as the rounding of a coordinate typed back
        from ``stepterrain info``'s 2 decimals.

        The nodes keep their positions and heights: ``origin`` becomes the first kept node's position, ``spacing``,
        ``crs``, ``source`` and ``height_unit`` stay, so a cropped mesh lies on the uncropped one: its nodes exactly
        where the spacing adds up exactly (a whole-metre one, as a UTM DEM's), its wall crossings, and the nodes of a
        spacing such as 0.3 m or a geographic DEM's metres, to float32 rounding (coordinates about another local
        origin: some 6e-8 of the grid's extent, half a millimetre over 10 km). A grid too big to step or mesh whole
        (an :class:`~stepterrain.errors.OutputTooLargeError`) can be cropped to the part that matters, here or with
        ``--crop`` on the command line.

        Raises
        ------
        InvalidInputError
            A TIN, an ``extent`` that is not four finite numbers with xmin <= xmax and ymin <= ymax, one that holds
            fewer than 2 x 2 nodes of the grid (one in degrees of a DEM read from degrees is named with its metres),
            or only nodata.

        Examples
        --------
        >>> t = Terrain.from_heights(np.arange(20.0).reshape(4, 5), spacing=(10.0, 10.0))
        >>> c = t.crop((10.0, 30.0, 0.0, 15.0))
        >>> c.shape, c.origin, c.extent
        ((2, 3), (10.0, 0.0), (10.0, 30.0, 0.0, 10.0))
        """
        bounds, (i0, i1), (j0, j1) = self._crop_nodes(extent)
        kept = self.heights[i0:i1 + 1, j0:j1 + 1]
        if not np.isfinite(kept).any():
            raise crop_of_nodata(bounds, kept.shape)
        (dx, dy), (ox, oy) = self.spacing, self.origin
        return self._subgrid(kept, (dx, dy), (ox + j0 * dx, oy + i0 * dy))

    def _crop_nodes(self, extent: ArrayLike) -> tuple[tuple[float, float, float, float], tuple[int, int],
                                                      tuple[int, int]]:
        """The ``extent`` of :meth:`crop` checked, as 4 floats, and the first and last row and column of the nodes it
        keeps, ``(bounds, (i0, i1), (j0, j1))``; its refusals but that of nodata only (:func:`crop_of_nodata`). Only
        the grid's shape, spacing, origin and crs are read (no height): :func:`~stepterrain.io.load_dem` asks it of a
        :meth:`_geometry_only` grid (the whole grid of a GeoTIFF before it reads its window; batch's crop)."""
        self._grid_only("crop", "cut its mesh instead, e.g. with trimesh's slice_plane")
        try:
            bounds = real_numbers(extent, "extent", "(xmin, xmax, ymin, ymax)")
        except InvalidInputError:
            bounds = np.array([])
        if bounds.shape != (4,) or not np.all(np.isfinite(bounds)) or bounds[0] > bounds[1] or bounds[2] > bounds[3]:
            raise InvalidInputError(f"extent must be 4 finite numbers (xmin, xmax, ymin, ymax), xmin <= xmax and "
                                    f"ymin <= ymax, in the terrain's coordinates (its extent is "
                                    f"{self._extent_text()}); got {extent!r}")
        (rows, cols), (dx, dy), (ox, oy) = self.heights.shape, self.spacing, self.origin
        j0, j1 = _node_span(float(bounds[0]), float(bounds[1]), ox, dx, cols)
        i0, i1 = _node_span(float(bounds[2]), float(bounds[3]), oy, dy, rows)
        if j1 - j0 < 1 or i1 - i0 < 1:
            from .io import extent_in_degrees_as_metres

            degrees = extent_in_degrees_as_metres(self, [float(v) for v in bounds])
            raise InvalidInputError(
                f"extent {tuple(float(v) for v in bounds)} (xmin, xmax, ymin, ymax) holds "
                f"{max(i1 - i0 + 1, 0)} x {max(j1 - j0 + 1, 0)} nodes of the grid, fewer than the 2 x 2 a mesh needs; "
                f"the terrain's extent is {self._extent_text()}, spacing {self.spacing}" + (
                    "" if degrees is None else "; it looks like degrees, but a DEM in degrees is read as local metres: "
                    "those degrees are ({:.2f}, {:.2f}, {:.2f}, {:.2f})".format(*degrees[1])))
        return (float(bounds[0]), float(bounds[1]), float(bounds[2]), float(bounds[3])), (i0, i1), (j0, j1)

    def coarsen(self, factor: int, *, method: Literal["mean", "nearest"] = "mean") -> Terrain:
        """A grid ``factor`` times coarser in x and y: for a DEM too big to step or mesh whole, or more detail than
        a view needs (``--coarsen`` on the command line).

        Parameters
        ----------
        factor : int
            Nodes per new node along each axis (>= 1; 1 gives the terrain itself).
        method : {"mean", "nearest"}
            ``"mean"`` (default): each new node is the mean of a ``factor`` x ``factor`` block of nodes, placed at
            the block's centre, nodata ignored (a block of nodata only stays nodata), as ``gdalwarp -r average``
            averages whole cells; rows and columns beyond the last whole block are dropped. ``"nearest"``: every
            ``factor``-th node from node (0, 0), heights unchanged (peaks between them are lost), as
            ``gdal_translate -r nearest``.

        ``crs``, ``source`` and ``height_unit`` stay; ``spacing`` grows ``factor`` times.

        Raises
        ------
        InvalidInputError
            A TIN, ``factor`` not a positive integer or so large that fewer than 2 x 2 nodes remain, an unknown
            ``method``, a result of nodata only.

        Examples
        --------
        >>> t = Terrain.from_heights(np.arange(16.0).reshape(4, 4), spacing=(10.0, 10.0))
        >>> m = t.coarsen(2)
        >>> m.heights.tolist(), m.spacing, m.origin
        ([[2.5, 4.5], [10.5, 12.5]], (20.0, 20.0), (5.0, 5.0))
        >>> t.coarsen(3, method="nearest").heights.tolist()
        [[0.0, 3.0], [12.0, 15.0]]
        """
        return self._coarsen(factor, method)

    def _coarsen(self, factor: int, method: str = "mean", *, empty_ok: bool = False) -> Terrain:
        """:meth:`coarsen`; ``empty_ok``: a result of nodata only is returned (a grid of NaN: a batch's empty item),
        not refused, with no pass over the heights beyond the coarsening's own."""
        f, shape, spacing, origin = self._coarse_geometry(factor, method)
        if f == 1:
            return self
        if method == "nearest":
            kept = self.heights[::f, ::f]
            if not empty_ok:
                self._some_finite(kept, f, method)
            return self._subgrid(kept, spacing, origin)
        h, w = shape
        total = np.zeros((h, w), dtype=np.float64)
        count = np.zeros((h, w), dtype=np.int64)
        for r in range(f):  # a block row at a time: temporaries of 1/f of the grid, not the grid in float64
            block = self.heights[r:h * f:f, :w * f].reshape(h, w, f)
            finite = np.isfinite(block)
            total += np.where(finite, block, 0.0).sum(axis=2, dtype=np.float64)
            count += finite.sum(axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = (total / count).astype(np.float32)
        if not empty_ok:
            self._some_finite(mean, f, method)
        return self._subgrid(mean, spacing, origin)

    def _coarse_geometry(self, factor: int, method: str = "mean") -> tuple[int, tuple[int, int], tuple[float, float],
                                                                             tuple[float, float]]:
        """:meth:`coarsen`'s factor, shape, spacing and origin, its refusals of ``factor`` and ``method`` included,
        from the grid's geometry alone (no height read); factor 1: the grid's own."""
        self._grid_only("coarsen", "simplify its mesh instead, e.g. with adaptive_mesh on a grid")
        if isinstance(factor, (bool, np.bool_)) or not isinstance(factor, numbers.Integral) or factor < 1:
            raise InvalidInputError(f"factor must be a positive integer (nodes per new node along each axis); "
                                    f"got {factor!r}")
        if not isinstance(method, str) or method not in ("mean", "nearest"):  # an array of names: numpy's ValueError
            raise InvalidInputError(f"method must be 'mean' or 'nearest'; got {method!r}")
        f = int(factor)
        (rows, cols), (dx, dy), (ox, oy) = self.heights.shape, self.spacing, self.origin
        if f == 1:
            return f, (rows, cols), (dx, dy), (ox, oy)
        shape = (rows // f, cols // f) if method == "mean" else ((rows - 1) // f + 1, (cols - 1) // f + 1)
        if min(shape) < 2:
            raise InvalidInputError(f"factor {f} leaves {shape[0]} x {shape[1]} nodes of the {rows} x {cols} grid "
                                    f"({method}), fewer than the 2 x 2 a mesh needs")
        if method == "nearest":
            return f, shape, (f * dx, f * dy), (ox, oy)
        half = (f - 1) / 2
        return f, shape, (f * dx, f * dy), (ox + half * dx, oy + half * dy)

    @classmethod
    def _geometry_only(cls, shape: tuple[int, int], spacing: tuple[float, float], origin: tuple[float, float],
                       crs: str | None, *, source: str | None = None, height_unit: str | None = None) -> Terrain:
        """A grid of ``shape`` nodes whose heights are one zero, broadcast (no allocation, no pass): for
        :meth:`_crop_nodes` and :meth:`_coarse_geometry` of heights held elsewhere (a series' frames); ``spacing`` and
        ``origin`` checked as :meth:`from_heights` checks them."""
        spacing, origin = grid_geometry(spacing, origin, shape)
        terrain = cls(kind="grid", heights=np.broadcast_to(np.float32(0.0), shape), spacing=spacing, origin=origin,
                      crs=crs, source=source, height_unit=height_unit, _owned=True)
        terrain._device_cache["has_nodata"] = False
        terrain._device_cache["height_range"] = (0.0, 0.0)
        return terrain

    def _some_finite(self, coarse: NDArray[np.float32], factor: int, method: str) -> None:
        """An InvalidInputError when the coarse grid holds only nodata (its finite nodes all in the rows and columns
        it leaves out), as crop refuses an extent of nodata only."""
        if not np.isfinite(coarse).any():
            rows, cols = self.heights.shape
            raise InvalidInputError(f"factor {factor} ({method}) leaves only nodata of the {rows} x {cols} grid: its "
                                    f"finite nodes lie in the rows and columns the {coarse.shape[0]} x "
                                    f"{coarse.shape[1]} coarse nodes leave out")

    def _grid_only(self, what: str, instead: str) -> None:
        if self.kind != "grid":
            raise InvalidInputError(f"{what} applies to a grid Terrain; got a TIN ({instead})")

    def _extent_text(self) -> str:
        return "(" + ", ".join(f"{v:.10g}" for v in self.extent) + ")"

    def _subgrid(self, heights: NDArray[np.float32], spacing: tuple[float, float],
                 origin: tuple[float, float]) -> Terrain:
        return Terrain.from_heights(np.ascontiguousarray(heights), spacing=spacing, origin=origin, crs=self.crs,
                                    source=self.source, height_unit=self.height_unit, _placed=True)  # its own CRS


def crop_of_nodata(bounds: tuple[float, ...], shape: tuple[int, ...]) -> InvalidInputError:
    """:meth:`Terrain.crop`'s refusal of an extent (``bounds``, checked) whose kept nodes (``shape``) are all
    nodata."""
    return InvalidInputError(f"extent {tuple(bounds)} holds only nodata ({shape[0]} x {shape[1]} nodes)")


#: How far outside ``Terrain.crop``'s extent a node may lie and still be kept, in coordinate units: the rounding of
#: the coordinates ``stepterrain info`` prints (2 decimals from 1e4 up, 6 significant digits below) and crop's messages
#: (10 significant digits) that a user types back; at most :data:`_CROP_SLACK_STEPS` of a step, at least 1e-9 of one.
_CROP_SLACK = 0.005
_CROP_SLACK_STEPS = 0.01


def _node_span(lo: float, hi: float, origin: float, step: float, n: int) -> tuple[int, int]:
    """First and last of the ``n`` node indices k with lo <= origin + k·step <= hi (a bound within
    :data:`_CROP_SLACK` beside a node still takes it: the rounding of a coordinate typed back, half a centimetre of
    the UTM origin `stepterrain info` prints to 2 decimals was 1e-4 of a 30 m step); last < first when none."""
    a, b = (lo - origin) / step, (hi - origin) / step  # inf for a bound of 1e300 over a spacing of 1e-10
    if step < 0:
        a, b = b, a
    slack = max(1e-9, min(_CROP_SLACK / abs(step), _CROP_SLACK_STEPS))  # in steps
    first = max(0, math.ceil(min(max(a - slack, -1.0), n)))  # clamped before ceil/floor: inf has no integer
    last = min(n - 1, math.floor(max(min(b + slack, n), -1.0)))
    return int(first), int(last)


#: folded faces named by index in the refusal (the count gives the rest)
_FOLDS_NAMED = 5


def _y_up_hint(points: NDArray[np.float64], faces: NDArray[np.int64], flipped: bool = False) -> str:
    """What to add to the refusal of a TIN that is a height field along y, not z: a terrain read from a file with y
    up (Blender's OBJ export by default, three.js' exporters; OBJ, PLY and STL have no axis convention, and read_mesh
    gives their coordinates as stored, while it turns a glTF, y-up by its spec, z-up itself), which folds or lies on
    a line in xy. Told apart by the faces' areas seen along each axis (signed: a surface facing up one axis), the
    largest along y; "" for other meshes. The turn named follows the way the faces face (as the file winds them:
    ``flipped``, the caller reversed them), counter-clockwise seen from above as glTF and most exporters wind them:
    along +y, +90 degrees about x; along -y, a terrain's heights run down y (a glTF holding z up against its spec, as
    trimesh's own export writes a z-up mesh, which read_mesh turned as y-up), -90 degrees: the +90 degree turn stepped
    such a terrain upside down (its heights negated) without a word."""
    corners = points[faces]
    with np.errstate(over="ignore", invalid="ignore"):
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        signed = normal.sum(axis=0)
        net, total = np.abs(signed), np.abs(normal).sum(axis=0)
    if not (net[1] > max(net[0], net[2]) and net[1] > 0.5 * total[1]):  # NaN (inf coordinates) too
        return ""
    if (signed[1] < 0) != flipped:  # heights down y: a z-up glTF (against glTF's spec) that read_mesh turned
        return (". Its faces face along y more than along z, as a terrain's do in a file with y up, but down y, as "
                "when a glTF holds its terrain z up against glTF's spec (trimesh's own export of a z-up mesh writes "
                "it so) and read_mesh turned it as y-up: if it is one, turn it z-up, "
                "mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))")
    return (". Its faces face along y more than along z, as a terrain's do in a file with y up (Blender's OBJ "
            "export, three.js' exporters; read_mesh gives an OBJ's, PLY's or STL's coordinates as stored, and turns a "
            "glTF z-up): if it is one, turn it z-up, "
            "mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])), as Blender does on "
            "import")


def _float32_hint(points: NDArray[np.float64], point_used: NDArray[np.int32]) -> str:
    """What to add to the refusal of a TIN that folds or overlaps in xy when its used points' x and y are all float32
    values at map coordinates, where float32's steps are coarse (0.25 m at a UTM northing): a glTF or STL written by
    another program without a local origin rounded the points, which folds the faces of a dense TIN. "" otherwise."""
    xy = points[point_used != 0, :2]
    with np.errstate(over="ignore", invalid="ignore"):
        if not len(xy) or not np.array_equal(xy.astype(np.float32), xy):
            return ""
        step = float(np.spacing(np.float32(np.abs(xy).max())))
    if step < 1e-3:
        return ""
    return (f". Its x and y are all float32 values (as glTF and STL store them), which at these coordinates lie "
            f"{step:.3g} apart: the file rounded the points, which folds faces of a dense TIN; a Delaunay "
            "triangulation of the points in xy (scipy.spatial.Delaunay, taken from their corner) meshes them as they "
            "are, or have the TIN written relative to a local origin (or as .ply or .obj, in float64)")


def _folded_message(
    points: NDArray[np.float64], faces: NDArray[np.int64], negative: NDArray[np.bool_], kept: NDArray[np.int64],
    flipped: bool, source: str | None,
) -> str:
    """The refusal of a TIN some of whose faces fold over in xy (``negative``: wound against the rest, ``faces``
    already turned to the majority's winding, ``flipped`` when they were), naming how many fold, the first few by
    their index in the mesh given (``kept``: the kept faces' indices there), a point of xy inside the first, and
    ways out: quadric decimation of a DEM's TIN (trimesh's simplify_quadric_decimation) folds a few faces where it
    moves a vertex across an edge, and the faces round such a vertex then overlap their other neighbours too, so
    dropping the folded faces alone is refused by the overlap check; dropping every face touching one, or a 2-D
    Delaunay triangulation of the points, was accepted for the real DEM's decimations. The Delaunay is taken from the
    points' corner: on map coordinates as given (UTM, x ~ 5e5 and y ~ 4e6 m) Qhull folds a few faces of a dense
    TIN itself (3 of 400 k for 200 k points over 2 km), and the mesh printed as the way out was refused in turn."""
    folded = np.flatnonzero(negative)
    named = [int(kept[k]) for k in folded[:_FOLDS_NAMED]]
    listed = ", ".join(map(str, named)) + (", ..." if len(folded) > _FOLDS_NAMED else "")
    x, y = points[faces[folded[0]], :2].mean(axis=0)
    what = "terrain mesh" if source is None else f"terrain mesh (from {source!r})"
    sign = ">" if flipped else "<"  # the folded faces' normals point against the rest's
    return (
        f"{what} faces must project one-to-one onto the xy plane; {len(folded)} of its {len(faces)} faces with finite "
        f"heights fold over (wound against the rest): face{'s' if len(folded) > 1 else ''} {listed}, the first around "
        f"({x:.10g}, {y:.10g}). Decimation that moves vertices (e.g. trimesh's simplify_quadric_decimation) folds a "
        "face where it moves a vertex across an edge, and the faces around it then overlap others, so dropping only "
        "the folded faces is not enough: re-triangulate the points in xy, e.g. mesh = trimesh.Trimesh(mesh.vertices, "
        "scipy.spatial.Delaunay(mesh.vertices[:, :2] - mesh.vertices[:, :2].min(axis=0)).simplices) (it covers the "
        "points' convex hull; taken from their corner, as Qhull folds a few faces at map coordinates such as UTM's); "
        "or drop every "
        "face touching a folded one (small holes): mesh.update_faces(~np.isin(mesh.faces, "
        f"mesh.faces[mesh.face_normals[:, 2] {sign} 0]).any(axis=1)); or mesh the grid with stepterrain.adaptive_mesh "
        "(an RTIN within a vertical error bound, which never folds)"
    )


def _given_face_index(given: Any, n_faces: int, visual: Any) -> NDArray[np.int64]:
    """The row of a face-coloured ``visual`` each of the ``n_faces`` faces given to ``Terrain(kind='tin', ...)`` has:
    ``given`` (a TIN's own face_index, as ``dataclasses.replace`` passes it: its faces are the kept ones, its visual
    the mesh's, faces with nodata included), or one row per face where None. Checked: an index rebuilt from the
    faces alone shifted the colours of every face after a dropped one, silently."""
    n_colors = len(visual.face_colors)
    if given is None:
        if n_colors != n_faces:
            raise InvalidInputError(
                f"a Terrain of kind 'tin' with face colours needs one visual.face_colors row per face ({n_faces}), "
                f"or face_index naming each face's row; got {counted(n_colors, 'row')} and no face_index"
            )
        return np.arange(n_faces, dtype=np.int64)
    index = np.asarray(unmasked(given))
    if (index.dtype.kind not in "iu" or index.shape != (n_faces,)
            or (n_faces and (index.min() < 0 or index.max() >= n_colors))):
        raise InvalidInputError(
            f"face_index must hold, per face, its row of visual.face_colors: shape ({n_faces},), integers from 0 to "
            f"{n_colors - 1}; got {_described(given)}"
        )
    return index.astype(np.int64)


def _face_coloured(visual: Any) -> bool:
    """Whether a TIN's ``visual`` holds face colours (one per face of the mesh given)."""
    return isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "face"


def _welded(points: NDArray[np.float64], faces: NDArray[np.int64], visual: Any) -> NDArray[np.int64]:
    """``faces`` with the points they use that coincide (the same x, y and z, and the same vertex colour or UV where
    ``visual`` carries them onto the steps) replaced by the first of them. A TIN read from STL (a triangle soup: three
    points of its own per face), or from a glTF of several primitives (each with its own copies of the points on
    their seams), is then stepped as the surface it is: one welded mesh, and a solid without walls round every face
    (or seam) inside it. A face two of whose corners coincide (zero area) keeps them apart, and so does every point
    coinciding with them."""
    used = np.flatnonzero(np.bincount(faces.reshape(-1), minlength=len(points)))  # not np.unique: 70x slower
    columns = [points[used] + 0.0]  # -0.0 as 0.0
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        colors = np.asarray(visual.vertex_colors)
        if len(colors) >= len(points):  # else short (built apart from the mesh): welded by position, the colours
            columns.append(colors.astype(np.float64)[used])  # refused before stepping (stepped._check_carried_visual)
    elif isinstance(visual, trimesh.visual.TextureVisuals) and visual.uv is not None:
        uv = np.asarray(visual.uv)
        if uv.ndim != 2 or len(uv) != len(points):  # refused before stepping (_check_carried_visual)
            return faces
        columns.append(uv.astype(np.float64)[used])
    bits = np.ascontiguousarray(np.column_stack(columns)).view(np.uint64)  # equal keys: equal bits
    mixed = np.zeros(len(bits), dtype=np.uint64)
    for k in range(bits.shape[1]):  # a hash of the key: sorted by it, equal keys lie together (unless a collision
        # interleaves two keys: a weld missed, never a wrong one)
        mixed = (mixed ^ bits[:, k]) * np.uint64(0x9E3779B97F4A7C15)
        mixed ^= mixed >> np.uint64(29)
    if not (np.diff(np.sort(mixed)) == 0).any():  # no two keys alike (most TINs): nothing to weld
        return faces
    order = np.argsort(mixed)
    ordered = bits[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    starts = np.flatnonzero(first)
    canonical = np.arange(len(points))
    canonical[used[order]] = np.repeat(used[np.minimum.reduceat(order, starts)], np.diff(np.append(starts, len(order))))
    welded = canonical[faces]
    degenerate = (welded[:, 0] == welded[:, 1]) | (welded[:, 1] == welded[:, 2]) | (welded[:, 0] == welded[:, 2])
    if degenerate.any():  # the points that would coincide in such a face stay apart (its third corner is welded)
        corners = welded[degenerate]
        twice = np.where(corners[:, 1] == corners[:, 2], corners[:, 1], corners[:, 0])
        apart = np.isin(canonical, twice)
        canonical[apart] = np.flatnonzero(apart)
        welded = canonical[faces]
    return welded


def _same_way_in_xy(xy: NDArray[np.float64], faces: NDArray[np.int64]) -> bool:
    """Whether two of ``faces`` (of positive area, wound counter-clockwise) run an edge between the same two xy
    positions the same way: in a TIN that projects one-to-one every edge inside has one face on either side, which
    run it opposite ways, so the two overlap (a fold turned up lies over the neighbour it folded across)."""
    label = _xy_labels(xy)
    keys = np.sort((label[faces] * len(xy) + label[np.roll(faces, -1, axis=1)]).reshape(-1))  # corner k to k + 1
    return bool((keys[1:] == keys[:-1]).any())


def _edge_table(faces: NDArray[np.int64], n_points: int,
                kept: NDArray[np.int64] | None = None) -> tuple[NDArray[np.int32], NDArray[np.int32]]:
    """Unique undirected edges and, per face, the edge from corner k to corner k+1. An edge used twice in the same
    direction is refused naming the two faces (by their index in the mesh given: ``kept[k]`` for face k where
    given) and the edge's points."""
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    dkey = np.sort(directed[:, 0] * n_points + directed[:, 1])  # not np.unique: numpy 2.4 hashes, 70x slower
    if (dkey[1:] == dkey[:-1]).any():
        order = np.argsort(directed[:, 0] * n_points + directed[:, 1], kind="stable")
        twice = int(np.flatnonzero(dkey[1:] == dkey[:-1])[0])
        first, second = (int(order[k]) // 3 for k in (twice, twice + 1))
        copies = sorted(faces[first].tolist()) == sorted(faces[second].tolist())
        way_out = " (two copies of one face: drop one, e.g. mesh.update_faces(mesh.unique_faces()))" if copies else ""
        start, end = (int(v) for v in directed[order[twice]])
        if kept is not None:
            first, second = int(kept[first]), int(kept[second])
        raise InvalidInputError(
            "terrain mesh faces must project one-to-one onto the xy plane; an edge is used twice in the same "
            f"direction (overlapping or inconsistently wound faces): faces {first} and {second} both run from point "
            f"{start} to point {end}{way_out}"
        )
    lo = directed.min(axis=1)
    hi = directed.max(axis=1)
    key = lo * n_points + hi
    unique, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    if (counts > 2).any():
        raise InvalidInputError("terrain mesh has an edge shared by more than two faces; expected a 2-manifold TIN")
    edges = np.stack([unique // n_points, unique % n_points], axis=1).astype(np.int32)
    return edges, inverse.reshape(-1, 3).astype(np.int32)


#: faces overlap in xy when each pokes more than this fraction of the smaller one's size (the larger side of its
#: bounding box) past every edge line of the other: faces that abut along an edge, meet at a corner or touch along
#: collinear boundaries (T-junctions, a point rounded onto a neighbour's edge) do not overlap
_OVERLAP_DEPTH = 1e-6
#: candidate pairs of faces made and tested at once (about 0.5 kB each while tested)
_PAIR_CHUNK = 1 << 18


def _overlap_in_xy(
    xy: NDArray[np.float64], faces: NDArray[np.int64], positive: NDArray[np.bool_], face_edges: NDArray[np.int32],
    n_edges: int,
) -> tuple[int, int, NDArray[np.float64], int] | None:
    """Two faces of positive area whose projections overlap (an intersection of positive area), else None:
    (face, face, a point of xy inside both, how many faces were found overlapping another: a lower bound, as the
    faces inside two stacked sheets are not tested). ``faces`` are wound counter-clockwise (``positive``: of
    positive area), ``xy`` the points relative to the faces' lower-left corner.

    Faces wound alike that share their interior edges with opposite windings (:func:`_edge_table`) cover each
    point of the plane w times, w changing only across their boundary edges. A region where w >= 2 has a corner on
    a boundary edge, and a face along that edge overlaps another face there. So only the faces with a boundary edge
    are tested, against every face whose bounding box overlaps theirs, each pair by its six edge lines (separating
    axes). Pairs come from a uniform grid in levels: each face lies in the level whose cells are at least its size,
    so in at most 2 x 2 cells, and a pair is met in the coarser face's level. Two sheets one above the other, a
    spiral ramp over itself, an island inside another face: their boundary faces overlap. A welded TIN has few
    boundary faces: the cost is one pass over all faces' bounding boxes and one over the points (about 0.1 s for
    a million faces); a triangle soup's faces are welded by their xy first (:func:`_unmatched_in_xy`)."""
    kept = np.flatnonzero(positive)
    if len(kept) < 2:
        return None
    if len(kept) < len(faces):
        faces, face_edges = faces[kept], face_edges[kept]
    corners = faces.T.copy()  # (3, m): contiguous columns, each reduction below a pass over plain arrays
    once = np.bincount(face_edges.reshape(-1), minlength=n_edges) == 1  # edges of one face of positive area
    edge_once = once[face_edges]
    on_boundary = edge_once[:, 0] | edge_once[:, 1] | edge_once[:, 2]
    if on_boundary.sum() * 8 > len(faces):  # a triangle soup, or sheets not welded: their own points' edges
        on_boundary = _unmatched_in_xy(xy, faces)
    lo, hi = np.empty((2, len(faces))), np.empty((2, len(faces)))  # the faces' bounding boxes, x and y rows
    for axis in range(2):
        coordinate = np.ascontiguousarray(xy[:, axis])
        c0, c1, c2 = coordinate[corners[0]], coordinate[corners[1]], coordinate[corners[2]]
        np.minimum(np.minimum(c0, c1, out=lo[axis]), c2, out=lo[axis])
        np.maximum(np.maximum(c0, c1, out=hi[axis]), c2, out=hi[axis])
    size = np.maximum(hi[0] - lo[0], hi[1] - lo[1])
    extent = np.array([hi[0].max(), hi[1].max()])  # xy is relative to the lower-left corner
    span = float(extent.max())
    # the cells: a little over a face size (of a sample), at most about 2**20 a side. Few boundary faces (a welded
    # TIN): cells that hold 99 % of the faces, so that few levels make few passes over the points; many (a triangle
    # soup): the median size, so that a cell holds few faces to test
    boundary = np.flatnonzero(on_boundary)
    share = 99 if len(boundary) * 8 < len(faces) else 50
    cell = max(1.01 * float(np.percentile(size[:: max(len(size) // 65536, 1)], share)), span * 2.0**-20)
    level = np.zeros(len(size), dtype=np.int64)
    if size.max() > cell:  # faces of several sizes (a regular grid's are all within one cell)
        level = np.maximum(np.ceil(np.log2(size / cell)), 0).astype(np.int64)
        level += cell * np.exp2(level) < size  # log2's rounding: every face within its level's cells
    hits = []
    searches = []
    for lv in np.flatnonzero(np.bincount(level)):
        # the pairs whose coarser face lies in this level: boundary faces of this level or finer against the
        # faces of this level, and boundary faces of this level against finer faces that are not on the boundary
        # (a finer boundary face meets them in the first search). Two searches, not boundary faces of this level
        # or finer against all faces of this level or finer: in a cell of this level, that paired every fine
        # boundary face with every fine face (an RTIN with a flat area's large faces on its boundary and a rough
        # one's small faces: seconds, growing as the cube of the grid's side)
        searches.append((lv, boundary[level[boundary] <= lv], level == lv))
        coarse = boundary[level[boundary] == lv]
        if len(coarse):
            searches.append((lv, coarse, (level < lv) & ~on_boundary))
    for lv, queries, others in searches:
        if len(queries) == 0 or not others.any():
            continue
        for a, b in _box_pairs(lo, hi, queries, others, cell * 2.0**lv, extent, xy, corners[0]):
            keep = (a != b) & (np.maximum(level[a], level[b]) == lv)
            # a pair of two boundary faces of this level meets from both sides: tested once
            keep &= ~((b < a) & on_boundary[b] & (level[a] == lv))
            a, b = a[keep], b[keep]
            depth = _OVERLAP_DEPTH * np.minimum(size[a], size[b]) + 1e-12 * span
            overlap = _triangles_overlap(xy[faces[a]], xy[faces[b]], depth)
            if overlap.any():
                hits.append(np.stack([a[overlap], b[overlap]], axis=1))
    if not hits:
        return None
    found = np.sort(np.concatenate(hits), axis=1)
    one, two = found[np.lexsort((found[:, 1], found[:, 0]))[0]]  # the lowest pair: the same on every run
    point = _overlap_point(xy[faces[one]], xy[faces[two]])
    return int(kept[one]), int(kept[two]), point, len(np.unique(found))


def _xy_labels(xy: NDArray[np.float64]) -> NDArray[np.int64]:
    """Per point, a label shared by the points of the same xy (compared as numbers: -0.0 is 0.0), in xy order."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    step = xy[order[1:]] != xy[order[:-1]]
    label = np.empty(len(xy), dtype=np.int64)
    label[order] = np.cumsum(np.r_[False, step[:, 0] | step[:, 1]])
    return label


def _unmatched_in_xy(xy: NDArray[np.float64], faces: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Per face (counter-clockwise, of positive area), whether it has an edge that no other face crosses to: the
    faces' corners welded by their xy, an edge used by exactly two faces in opposite directions is shared, any other
    is a boundary (a triangle soup has few once welded; sheets stacked on one xy grid share edges in one direction).
    The plane's cover by the faces changes only across the boundaries, as :func:`_overlap_in_xy` needs."""
    label = _xy_labels(xy)
    start, end = label[faces], label[np.roll(faces, -1, axis=1)]  # corner k to corner k + 1
    key = np.minimum(start, end) * len(xy) + np.maximum(start, end)
    sorted_at = np.argsort(key.reshape(-1))
    key_sorted = key.reshape(-1)[sorted_at]
    forward = (start < end).reshape(-1)[sorted_at]
    first = np.r_[True, key_sorted[1:] != key_sorted[:-1]]
    group = np.cumsum(first) - 1
    uses = np.bincount(group)
    ahead = np.bincount(group, weights=forward)
    shared = (uses == 2) & (ahead == 1)  # one face each way
    unmatched = np.empty(key.size, dtype=bool)
    unmatched[sorted_at] = ~shared[group]
    unmatched = unmatched.reshape(-1, 3)
    return unmatched[:, 0] | unmatched[:, 1] | unmatched[:, 2]


def _box_pairs(lo: NDArray[np.float64], hi: NDArray[np.float64], queries: NDArray[np.int64],
               others: NDArray[np.bool_], width: float, extent: NDArray[np.float64], xy: NDArray[np.float64],
               anchor: NDArray[np.int64]):
    """Chunks (a, b) of the pairs of a face in ``queries`` and one in ``others`` (a mask) whose bounding boxes
    (``lo``, ``hi``: (2, m), x and y rows) overlap with positive area, each pair once, from a grid of square cells
    of side ``width`` over [0, ``extent``]. A box covers the cells that its interior meets; a pair is kept in the
    cell of its common part's lower-left corner only. The faces of ``others`` are at most ``width`` in size, and
    each has its point ``anchor`` (of ``xy``): its box lies within a cell of that point's."""
    side = int(extent[0] // width) + 3  # cells -1 to side - 2 along x: a dilation stays in the table
    rows = int(extent[1] // width) + 3

    def cells(ids: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        first = np.floor(lo[:, ids] / width).astype(np.int64)
        n = np.maximum(np.ceil(hi[:, ids] / width).astype(np.int64) - 1, first) - first + 1
        count = n[0] * n[1]
        owner = np.repeat(np.arange(len(ids)), count)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)
        return ids[owner], first[0, owner] + 1 + k % n[0, owner] + (first[1, owner] + 1 + k // n[0, owner]) * side

    q_face, q_key = cells(queries)
    # the others near a query's cell (their anchor within one cell of it): a welded TIN's boundary faces lie in few
    # cells, so a pass over the points leaves few faces
    near_keys = np.unique(q_key)
    near_keys = np.unique((near_keys[:, None] + (np.array([-1, 0, 1])[:, None] * side + [-1, 0, 1]).ravel()).ravel())
    candidates = np.flatnonzero(others)
    anchors = anchor[candidates] if len(candidates) < len(xy) // 2 else None  # few: their points only
    points = xy if anchors is None else xy[anchors]
    # a stray point's too (no face's; fmax takes a NaN x or y of one to -1, where np.clip kept it NaN and the int64
    # key of it indexed the table far out of bounds)
    point_cell = np.fmin(np.fmax(np.floor(points / width), -1.0), [side - 2, rows - 2])
    point_key = (point_cell.astype(np.int64) + 1) @ np.array([1, side])
    if side * rows <= 8 * len(anchor) + (1 << 20):
        table = np.zeros(side * rows, dtype=bool)
        table[near_keys] = True
        point_near = table[point_key]
    else:
        point_near = np.isin(point_key, near_keys)
    o_face, o_key = cells(candidates[point_near if anchors is not None else point_near[anchor[candidates]]])
    flip = len(q_key) > len(o_key)  # sort the smaller side, look the larger one up in it
    s_face, s_key, l_face, l_key = (o_face, o_key, q_face, q_key) if not flip else (q_face, q_key, o_face, o_key)
    order = np.argsort(s_key, kind="stable")
    s_face, s_key = s_face[order], s_key[order]
    start = np.searchsorted(s_key, l_key, side="left")
    count = np.searchsorted(s_key, l_key, side="right") - start
    has = np.flatnonzero(count)
    l_face, l_key, start, count = l_face[has], l_key[has], start[has], count[has]
    total = np.cumsum(count)
    begin = 0
    while begin < len(count):  # chunks of about _PAIR_CHUNK pairs
        before = total[begin - 1] if begin else 0
        end = max(int(np.searchsorted(total, before + _PAIR_CHUNK, side="right")), begin + 1)
        n = count[begin:end]
        row = np.repeat(np.arange(begin, end), n)
        at = start[row] + np.arange(len(row)) - np.repeat(np.cumsum(n) - n, n)
        a, b = l_face[row], s_face[at]
        if flip:
            a, b = b, a
        both_lo, both_hi = np.maximum(lo[:, a], lo[:, b]), np.minimum(hi[:, a], hi[:, b])
        meet = (both_lo[0] < both_hi[0]) & (both_lo[1] < both_hi[1])
        corner = np.maximum(np.maximum(np.floor(lo[:, a] / width), np.floor(lo[:, b] / width)),
                            np.minimum(np.floor(both_lo / width), np.ceil(both_hi / width) - 1)).astype(np.int64) + 1
        meet &= corner[0] + corner[1] * side == l_key[row]
        yield a[meet], b[meet]
        begin = end


def _triangles_overlap(a: NDArray[np.float64], b: NDArray[np.float64], depth: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Per pair of counter-clockwise triangles (k, 3, 2), whether each pokes more than ``depth`` past every edge
    line of the other: no edge line separates them (separating axes), so their intersection has positive area."""

    def apart(t: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether an edge line of t has u on its outer side, within depth."""
        out = np.zeros(len(t), dtype=bool)
        for i in range(3):  # the three edges, each vectorised over the pairs
            edge = t[:, (i + 1) % 3] - t[:, i]
            rel = u - t[:, i, None]
            inward = edge[:, None, 0] * rel[..., 1] - edge[:, None, 1] * rel[..., 0]  # |edge| x distance inside
            out |= inward.max(axis=1) <= depth * np.hypot(edge[:, 0], edge[:, 1])
        return out

    return ~apart(a, b) & ~apart(b, a)


def _overlap_point(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """A point inside both counter-clockwise triangles a and b (3, 2) that overlap: the centroid of a clipped by
    b's three edge lines (Sutherland-Hodgman)."""
    polygon = list(a)
    for i in range(3):
        p, q = b[i], b[(i + 1) % 3]
        side = [float((q[0] - p[0]) * (v[1] - p[1]) - (q[1] - p[1]) * (v[0] - p[0])) for v in polygon]
        clipped = []
        for k, v in enumerate(polygon):
            w, sv, sw = polygon[k - 1], side[k], side[k - 1]
            if (sv >= 0) != (sw >= 0):  # the edge w-v crosses the line
                clipped.append(w + (v - w) * (sw / (sw - sv)))
            if sv >= 0:
                clipped.append(v)
        polygon = clipped
    ring = np.array(polygon) if polygon else a
    x, y = ring[:, 0], ring[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    if abs(cross.sum()) <= 0:
        return ring.mean(axis=0)
    return np.array([((x + np.roll(x, -1)) * cross).sum(), ((y + np.roll(y, -1)) * cross).sum()]) / (3 * cross.sum())


#: Bytes a grid node of :func:`heightfield_mesh` takes at its peak (RSS measured on 2000² grids): the int64 faces (two
#: per cell, 48 bytes) and the float64 vertices (24) it returns, and the index grids, corner indices and stacked
#: columns they are built from (~72). With nodata, the kept faces and vertices are copied once more (~48). A DEM
#: read under the budget (4 bytes a node) made a mesh of ~36 times its size without a check.
_HEIGHTFIELD_NODE_BYTES = 144
_HEIGHTFIELD_NODATA_BYTES = 52


def grid_faces(rows: int, cols: int, flip: bool = False) -> NDArray[np.int64]:
    """Two triangles per cell, (n00, n01, n11) and (n00, n11, n10), cells row-major (reversed when flip)."""
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    n00 = (i * cols + j).reshape(-1)
    n01, n10, n11 = n00 + 1, n00 + cols, n00 + cols + 1
    faces = np.empty((len(n00), 2, 3), dtype=np.int64)
    faces[:, 0] = np.stack([n00, n01, n11], axis=1)
    faces[:, 1] = np.stack([n00, n11, n10], axis=1)
    faces = faces.reshape(-1, 3)
    return faces[:, [0, 2, 1]] if flip else faces


def check_heightfield_budget(t: Terrain) -> None:
    """The memory budget check of :func:`heightfield_mesh` for the grid terrain ``t``, for a caller to make before
    the work that precedes the mesh (``stepterrain texture --mesh`` shades the texture first)."""
    rows, cols = t.heights.shape
    per_node = _HEIGHTFIELD_NODE_BYTES + (_HEIGHTFIELD_NODATA_BYTES if t.has_nodata else 0)
    check_budget(per_node * rows * cols, f"the heightfield mesh of a {rows} x {cols} grid",
                 hint="crop or coarsen the terrain (Terrain.crop, Terrain.coarsen; --crop, --coarsen)")


def heightfield_mesh(
    heights: ArrayLike | Terrain,
    *,
    spacing: ArrayLike | None = None,
    origin: ArrayLike | None = None,
) -> trimesh.Trimesh:
    """Triangulate a regular heightfield.

    Parameters
    ----------
    heights : (H, W) array_like or grid Terrain
        Heights; NaN marks nodata (so do a numpy masked array's masked entries). A grid :class:`Terrain`
        (``load_dem``'s) brings its own spacing and origin (as :meth:`Terrain.mesh`).
    spacing : (dx, dy)
        Node spacing (default (1, 1)); x runs along columns, y along rows. Either may be negative (then the winding
        is swapped so faces stay counter-clockwise seen from +z).
    origin : (x0, y0)
        World position of node (0, 0) (default (0, 0)).

    Returns
    -------
    trimesh.Trimesh
        Vertex k is grid node k in row-major order, z = height; two triangles per cell, wound
        counter-clockwise seen from +z. With nodata, no face touches a NaN node and the NaN nodes are
        removed (``metadata["node_index"]`` maps vertices back to grid nodes). A Terrain's CRS and source are its
        ``metadata["crs"]`` and ``["source"]``, as :func:`~stepterrain.stepped` records them.

    Raises
    ------
    InvalidInputError
        ``heights`` is not a real (H, W) array with H, W >= 2 (or a grid Terrain), has infinite values or finite
        ones beyond float32, or ``spacing`` has a zero; spacing or origin given with a Terrain.
    OutputTooLargeError
        The mesh (about 144 bytes a grid node while it is built, more with nodata) exceeds the memory budget
        (:func:`stepterrain.set_memory_budget`); checked before anything is allocated.

    Examples
    --------
    >>> import numpy as np, stepterrain as st
    >>> m = st.heightfield_mesh(np.zeros((3, 4)), spacing=(2.0, 1.0))
    >>> len(m.vertices), len(m.faces), float(m.area)
    (12, 12, 12.0)
    >>> bool((m.face_normals[:, 2] > 0).all())
    True
    """
    if isinstance(heights, Terrain):  # was read as an array: "dtype object", naming no way out
        if heights.kind != "grid":
            raise InvalidInputError("heights must be an (H, W) array or a grid Terrain; got a TIN Terrain (its mesh "
                                    "is terrain.mesh())")
        if spacing is not None or origin is not None:
            raise InvalidInputError("spacing/origin apply to a raw (H, W) array; the Terrain has its own")
        t = heights
    else:
        t = Terrain.from_heights(heights, spacing=(1.0, 1.0) if spacing is None else spacing,
                                 origin=(0.0, 0.0) if origin is None else origin)
    check_heightfield_budget(t)
    rows, cols = t.heights.shape
    dx, dy = t.spacing
    faces = grid_faces(rows, cols, flip=dx * dy < 0)
    j, i = np.meshgrid(np.arange(cols), np.arange(rows))
    vertices = np.stack(
        [t.origin[0] + j.reshape(-1) * dx, t.origin[1] + i.reshape(-1) * dy, t.heights.reshape(-1).astype(np.float64)],
        axis=1,
    )
    metadata: dict[str, Any] = {"grid_shape": (rows, cols), "spacing": (dx, dy), "origin": t.origin,
                                **_placed_metadata(t)}
    vertices, faces, kept = without_nan_nodes(vertices, faces)
    if kept is not None:
        metadata["node_index"] = kept
    return trimesh.Trimesh(vertices, faces, process=False, metadata=metadata)


def without_nan_nodes(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> tuple[
        NDArray[np.float64], NDArray[np.int64], NDArray[np.int64] | None]:
    """(vertices, faces, kept) of a grid mesh whose nodata nodes have z = NaN: no face touches a NaN vertex and the
    vertices no face uses go, ``kept`` their old indices (None, and the arrays as given, when every z is finite)."""
    finite = np.isfinite(vertices[:, 2])
    if finite.all():
        return vertices, faces, None
    faces = faces[finite[faces].all(axis=1)]
    keep = np.zeros(len(vertices), dtype=bool)
    keep[faces.reshape(-1)] = True
    faces = (np.cumsum(keep) - 1)[faces]
    return vertices[keep], faces, np.flatnonzero(keep)


def as_terrain(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    *,
    spacing: ArrayLike | None = None,
    origin: ArrayLike | None = None,
    borrow: bool = False,
) -> Terrain:
    """Normalise any accepted terrain input: a :class:`Terrain`, a ``trimesh.Trimesh`` TIN or an (H, W) array.

    ``borrow``: a float32, C-contiguous (H, W) array is used as it is, not copied, for a Terrain that lives only
    within the caller's call (``stepped`` from a raw array: its copy was 2.3 ms of a 2048² call). The Terrain still
    holds a read-only view; the caller's array keeps its flags."""
    if isinstance(terrain, Terrain):
        if spacing is not None or origin is not None:
            raise InvalidInputError("spacing/origin apply to raw (H, W) arrays only; the Terrain already has them")
        return terrain
    if isinstance(terrain, trimesh.Trimesh):
        if spacing is not None or origin is not None:
            raise InvalidInputError("spacing/origin apply to raw (H, W) arrays only, not to a trimesh TIN")
        return Terrain.from_mesh(terrain)
    if isinstance(terrain, (trimesh.Scene, trimesh.parent.Geometry)):  # numpy made a 0-d object array of it
        hint = (" (trimesh.load gives one for a glTF/GLB; read the file with stepterrain.export.read_mesh(path): one "
                "mesh, z up, where trimesh.load(path, force='mesh') and scene.to_mesh() give glTF's y-up world, a "
                "terrain on its edge)" if isinstance(terrain, trimesh.Scene) else "")
        raise InvalidInputError(f"terrain must be an (H, W) array, a Terrain or a trimesh.Trimesh TIN; got a "
                                f"{type(terrain).__module__}.{type(terrain).__name__}{hint}")
    if type(terrain).__module__.split(".")[0] == "pyvista":  # not imported here: import stepterrain leaves VTK alone
        # numpy made a 0-d object array of a pyvista dataset too ("got dtype object"), naming neither it nor the way
        kind = type(terrain).__name__  # from pyvista to what stepterrain takes
        hint = (" (pass grid.stepterrain.terrain(), or step it where it is with grid.stepterrain.stepped(...))"
                if kind in ("ImageData", "RectilinearGrid", "StructuredGrid") else
                " (a TIN: pass stepterrain.pyvista_accessor.from_polydata(mesh.triangulate()), which keeps its "
                "colours)" if kind == "PolyData" else "")
        raise InvalidInputError(f"terrain must be an (H, W) array, a Terrain or a trimesh.Trimesh TIN; got a "
                                f"pyvista.{kind}{hint}")
    if isinstance(terrain, (str, bytes)) or hasattr(terrain, "__fspath__"):
        raise InvalidInputError(
            f"terrain must be an (H, W) array, a Terrain or a trimesh.Trimesh; got a path {terrain!r} "
            "(load it first with stepterrain.load_dem)"
        )
    return Terrain.from_heights(
        terrain,
        spacing=(1.0, 1.0) if spacing is None else spacing,
        origin=(0.0, 0.0) if origin is None else origin,
        _borrow=borrow,
    )
