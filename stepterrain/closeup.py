"""3D close-ups: detail+overview views of a terrain (paper 001).

Implements Trapp & Döllner, *Interactive Close-Up Rendering for Detail+Overview Visualization of 3D Digital
Terrain Models* (IV 2019, doi:10.1109/IV.2019.00053): the close-up model M = R(α, β)·S(sx, sy, sz)·T(p) with
a ROI mask and a color (§II.B), overview-dependent and overview-independent close-ups (§II.C), anchors whose
transparency follows a 1D transfer function of the normalized ‖V_O − V_C‖ (§II.D, Fig. 4), ROIs from a shape
library, painted or generated from terrain features (§III.A), active/inactive depictions and automatic
rotation (§III.B, Fig. 5), and layered rendering with image-based compositing (§IV, Fig. 6). Typical use:

    cu = CloseUp(ROI.circle((390000.0, 3798000.0), 2000.0), scale=2.0, offset=(0.0, 0.0, 3000.0))
    image = render_closeups(stepterrain.sample_dem(), [cu])

Where the paper renders the whole terrain once per close-up (its stated limitation, §IV.C), each close-up
here is cut to its ROI window before the Warp kernels run (kernels/closeup.py), and the kernels cull it to
the faces with m > 0 by count -> scan -> emit, so a close-up costs in proportion to its ROI.
"""

from __future__ import annotations

import hashlib
import inspect
import math
import os
import struct
import warnings
from collections.abc import MutableMapping, Sequence
from dataclasses import KW_ONLY, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._compaction import MAX_INT32 as _MAX_INT32
from ._compaction import budget_value, check_budget, count_buffer, exclusive_offsets
from ._device import host_copy, launch, launch_chunked, resolve_device, to_device
from ._memo import MISSING, Same, derived, keep, recall
from .camera import QUARTER_TURN
from .errors import (
    DataFileError,
    InvalidInputError,
    MissingDependencyError,
    OutputTooLargeError,
    caller_stacklevel,
    counted,
    plain_repr,
)
from .io import degrees_hint
from .kernels import closeup as closeup_kernels
from .kernels import compaction as compaction_kernels
from .mesh import release
from .stepped import land_range
from .terrain import (
    FLOAT32_MAX,
    Terrain,
    _edge_table,
    _pair,
    as_array,
    as_terrain,
    check_flag,
    finite_number,
    finite_triangles,
    grid_faces,
    is_name,
    number_or_nan,
    real_numbers,
    real_vector,
    sorted_unique,
    used_nodes,
)

__all__ = [
    "ROI",
    "AnchorStyle",
    "CloseUp",
    "CloseUpLayer",
    "AnchorStrip",
    "TRANSFER_PRESETS",
    "transfer_function",
    "closeup_matrix",
    "closeup_layers",
    "anchor_strips",
    "composite",
    "render_closeups",
    "closeup_scene",
    "animate_closeups",
    "save_animation",
    "max_closeups",
]

#: Opacity tables of the anchor transfer-function presets (Fig. 4), sampled linearly over t in [0, 1]:
#: t = 0 at the ROI on the overview, t = 1 at the close-up.
TRANSFER_PRESETS: dict[str, tuple[float, ...]] = {
    "opaque": (0.85, 0.85),  # a solid fence: strongest referencing, most occlusion
    "linear": (0.85, 0.0),  # solid at the ROI, fading out towards the close-up
    "inverse": (0.0, 0.85),  # clear at the ROI (overview unoccluded), solid at the close-up
    "ends": (0.85, 0.0, 0.85),  # marked at both ends, clear in the middle
    "hidden": (0.0, 0.0),  # no anchor
}

#: Colors given to close-ups without one, in order (matplotlib tab10).
PALETTE = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#17becf", "#e377c2", "#bcbd22")

_MIN_PIXELS_PER_CLOSEUP = 64  # a close-up needs at least a 64 x 64 pixel share of the window
_MAX_CLOSEUPS = 16


# ------------------------------------------------------------------------------------------------ helpers
_MAX_MASK_RESOLUTION = 16385  # texels along each side of a shape mask: 1 GiB of float32 at most
#: The smallest positive float32 (a subnormal): a height band's edge below it is 0 in the float32 ramp.
_FLOAT32_SMALLEST = float(np.finfo(np.float32).smallest_subnormal)
_MAX_SCALE = 1e6  # close-up scale and offset bounds: transformed positions stay finite in float32
_MAX_OFFSET = 1e12
#: largest |angle| of a close-up's rotation and billboard azimuth, radians (1024 turns): 1e308 was taken, and a spin
#: added to an angle that large was lost to rounding (the animation stood still); a larger value is likely degrees
_MAX_ANGLE = 2 * math.pi * 1024


def _finite(value: Any, name: str) -> float:
    """:func:`~stepterrain.terrain.finite_number` (of any sign) in the words these arguments have always used:
    "``name`` must be a finite number" for text, NaN and inf alike."""
    try:
        return finite_number(value, name)
    except InvalidInputError:
        raise InvalidInputError(f"{name} must be a finite number; got {plain_repr(value)}") from None


def _numbers(value: Any) -> NDArray[np.float64]:
    """``value`` as a flat float64 array; [nan] when it is not real numbers (text such as "2", bools, complex,
    ragged rows: refused as :func:`~stepterrain.terrain.real_numbers` refuses them), so that the caller's check
    refuses it in its own words."""
    try:
        return real_numbers(value, "value", "numbers").reshape(-1)
    except (InvalidInputError, TypeError):
        return np.array([math.nan])


def _scale3(value: Any, name: str) -> NDArray[np.float64]:
    """(sx, sy, sz) from one finite number or three (a close-up's scale), else an InvalidInputError naming
    ``name``."""
    s = _numbers(value)  # [nan] when not numbers ("2", True)
    if s.size == 1:
        s = np.repeat(s, 3)
    if s.size != 3 or not np.all(np.isfinite(s)):
        raise InvalidInputError(f"{name} must be a finite number or (sx, sy, sz); got {value!r}")
    return s


def _closeup_scale(value: Any, name: str) -> NDArray[np.float64]:
    """A close-up's (sx, sy, sz) (:func:`_scale3`): sx, sy > 0, sz >= 0 (0 flattens), none past :data:`_MAX_SCALE`
    (float32 positions on the device), else an InvalidInputError naming ``name``."""
    s = _scale3(value, name)
    if s[0] <= 0 or s[1] <= 0 or s[2] < 0:
        raise InvalidInputError(f"{name} must be positive (sx, sy > 0; sz >= 0, 0 flattens); got {tuple(s.tolist())}")
    if s.max() > _MAX_SCALE:  # float32 positions on the device
        raise InvalidInputError(f"{name} must be at most {_MAX_SCALE:g}; got {tuple(s.tolist())}")
    return s


def _outline_level(value: Any, name: str) -> float:
    """A mask value whose contour is an outline: a number in (0, 1) (m lies in [0, 1]), else an InvalidInputError
    naming ``name``; :meth:`ROI.outline` and :class:`AnchorStyle` take the same levels."""
    level = number_or_nan(value)
    if not 0 < level < 1:
        raise InvalidInputError(f"{name} must be a number in (0, 1); got {plain_repr(value)}")
    return level


def _seconds(time: Any) -> float:
    """An animation time in seconds: any number but NaN (inf: every spin has ended)."""
    t = number_or_nan(time)
    if math.isnan(t):
        raise InvalidInputError(f"time must be a number of seconds (not NaN); got {plain_repr(time)}")
    return t


def _smooth_edge(distance: NDArray[np.float64], edge_width: float, closed: bool = False) -> NDArray[np.float32]:
    """m from a signed distance (negative inside): 1 for d <= -edge_width, 0 for d >= 0, smoothstep between.

    A hard edge (``edge_width`` 0) with ``closed`` counts the shape's boundary (d = 0) as inside: a rectangle's
    boundary is its box's own rim, where the mask's outer texels lie, and with them at 0 a hard rectangle over a
    terrain's whole extent had m = 0 at every rim node (a 2 x 2 grid's all four) and was refused as holding no
    terrain. A curved shape stays open: its boundary touches the box rim at single texels only, which as 1 would
    stick out as one-texel spikes."""
    if edge_width <= 0:
        return (distance <= 0 if closed else distance < 0).astype(np.float32)
    with np.errstate(over="ignore"):
        x = np.clip(-distance / edge_width, 0.0, 1.0)
    return (x * x * (3.0 - 2.0 * x)).astype(np.float32)


def _check_edge_width(width: float, depth: float, what: str) -> None:
    """A soft edge wider than the shape is deep leaves m below 1 everywhere: a close-up with no content."""
    if width > depth:
        raise InvalidInputError(f"edge_width must be at most {what} ({depth:g}), where m reaches 1; got {width:g}")


def _mask_grid(resolution: int) -> tuple[int, int]:
    """(rows, cols) of a shape mask: ``resolution`` texels along each side, odd, 3 to 16385 (texels as long as the
    side over which they spread). Square texels left the shorter side of an elongated shape a handful of texels:
    a 10000 x 100 rectangle got 3 rows (its rim and centre), so m was a tent, 0.2 at 10 m inside its long edge
    instead of 1, and its outline ran at half its width."""
    if isinstance(resolution, (bool, np.bool_)) or not isinstance(resolution, (int, np.integer)):
        raise InvalidInputError(f"mask resolution must be a whole number of texels; got {plain_repr(resolution)}")
    resolution = int(resolution)
    if not 3 <= resolution <= _MAX_MASK_RESOLUTION:
        raise InvalidInputError(f"mask resolution must lie in [3, {_MAX_MASK_RESOLUTION}] texels per side; got "
                                f"{resolution}")
    return resolution | 1, resolution | 1


def _texel_xy(center: tuple[float, float], size: tuple[float, float], rows: int, cols: int):
    xs = np.linspace(-size[0] / 2, size[0] / 2, cols)
    ys = np.linspace(-size[1] / 2, size[1] / 2, rows)
    return np.meshgrid(xs, ys)  # (rows, cols) offsets from the centre, row 0 at the lower y


def _ellipse_distance(x: NDArray[np.float64], y: NDArray[np.float64], a: float, b: float) -> NDArray[np.float64]:
    """Signed distance (negative inside) to the ellipse with semi-axes a, b: the nearest point on it by a fixed-point
    iteration on its evolute (C. Chatfield's), converged to float64 rounding in a few steps. The scaled radius
    (hypot(x/a, y/b) − 1)·min(a, b) stood in for it and made the soft edge a/b times wider at the ends of the major
    axis than ``edge_width`` (a 5:1 ellipse's edge of 100 m was 500 m there)."""
    px, py = np.abs(x), np.abs(y)
    tx = np.full(px.shape, math.sqrt(0.5))
    ty = tx.copy()
    for _ in range(12):
        ex = (a * a - b * b) * tx**3 / a  # the evolute's point for the current estimate
        ey = (b * b - a * a) * ty**3 / b
        r = np.hypot(a * tx - ex, b * ty - ey)
        qx, qy = px - ex, py - ey
        q = np.hypot(qx, qy)
        with np.errstate(divide="ignore", invalid="ignore"):
            nx = np.clip((qx * r / q + ex) / a, 0.0, 1.0)
            ny = np.clip((qy * r / q + ey) / b, 0.0, 1.0)
        norm = np.hypot(nx, ny)
        ok = (q > 0) & (norm > 0)
        tx = np.where(ok, nx / np.where(ok, norm, 1.0), tx)
        ty = np.where(ok, ny / np.where(ok, norm, 1.0), ty)
    distance = np.hypot(px - a * tx, py - b * ty)
    inside = (px / a) ** 2 + (py / b) ** 2 < 1.0
    return np.where(inside, -distance, distance)


def _box_distance(x: NDArray[np.float64], y: NDArray[np.float64], hx: float, hy: float) -> NDArray[np.float64]:
    qx, qy = np.abs(x) - hx, np.abs(y) - hy
    outside = np.hypot(np.maximum(qx, 0), np.maximum(qy, 0))
    return outside + np.minimum(np.maximum(qx, qy), 0)


# ------------------------------------------------------------------------------------------------ ROI
@dataclass(frozen=True, eq=False)
class ROI:
    """A region of interest (§III.A): origin O, the size of its box and a mask over that box.

    ``mask`` (rows, cols) holds the mask factor m in [0, 1] at texels spread evenly over the box
    ``center ± size / 2`` (corners included); row 0 lies at the *lower* y. Between texels m is bilinear, and
    0 outside the box. Build one from the shape library (:meth:`circle`, :meth:`ellipse`, :meth:`rectangle`,
    :meth:`rounded_rectangle`), a painted array (:meth:`painted`) or terrain features (:meth:`height_band`,
    :meth:`slope_above`, :meth:`stepped_level`).
    """

    center: tuple[float, float]
    size: tuple[float, float]
    mask: NDArray[np.float32]
    shape: str = "painted"

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _pair(self.center, "ROI center", nonzero=False, scalar=False))
        size = _pair(self.size, "ROI size", nonzero=False)
        if min(size) <= 0 or max(size) > _MAX_OFFSET:  # float32 positions on the device
            raise InvalidInputError(f"ROI size must be positive (width, height) up to {_MAX_OFFSET:g}; got {size}")
        object.__setattr__(self, "size", size)
        try:
            mask = np.asarray(self.mask)
        except ValueError:  # ragged rows
            raise InvalidInputError("ROI mask must be a real (rows, cols) array; got rows of different "
                                    "lengths") from None
        if mask.dtype == object or np.issubdtype(mask.dtype, np.complexfloating) or not (
                np.issubdtype(mask.dtype, np.number) or mask.dtype == bool):  # complex lost its imaginary part
            raise InvalidInputError(f"ROI mask must be a real (rows, cols) array; got dtype {mask.dtype}")
        if mask.ndim != 2 or mask.shape[0] < 2 or mask.shape[1] < 2:
            raise InvalidInputError(f"ROI mask must be a 2-D array of at least 2 x 2 texels; got shape {mask.shape}")
        # an own copy (ascontiguousarray would alias a float32 caller array): the frozen ROI's mask must not
        # change behind the caches keyed by the ROI, nor the caller's array become read-only
        dtype = mask.dtype
        mask = np.array(mask, dtype=np.float32, order="C", copy=True)
        if not np.all(np.isfinite(mask)):
            raise InvalidInputError("ROI mask values must be finite, in [0, 1]; got NaN or inf")
        if mask.min() < 0.0 or mask.max() > 1.0:
            raise InvalidInputError(f"ROI mask values must lie in [0, 1]; got range [{float(mask.min())}, "
                                    f"{float(mask.max())}] ({_mask_hint(dtype, float(mask.min()), float(mask.max()))})")
        mask.setflags(write=False)
        object.__setattr__(self, "mask", mask)

    # -------------------------------------------------------------------------- shape library
    @classmethod
    def circle(cls, center: ArrayLike, radius: float, *, edge_width: float | None = None,
               resolution: int = 129) -> ROI:
        """A disc of ``radius`` about ``center``; m falls from 1 to 0 over ``edge_width`` inside the rim.

        ``edge_width`` defaults to radius / 5 (0 gives a hard edge, softened only by the bilinear lookup) and may be
        at most the radius (a wider edge would keep m below 1 everywhere).

        Examples
        --------
        >>> roi = ROI.circle((0.0, 0.0), 10.0)
        >>> float(roi.mask[64, 64]), float(roi.mask[0, 0])
        (1.0, 0.0)
        """
        r = finite_number(radius, "ROI radius", positive=True)
        return cls.ellipse(center, (r, r), edge_width=edge_width, resolution=resolution)._named("circle")

    @classmethod
    def ellipse(cls, center: ArrayLike, radii: ArrayLike, *, edge_width: float | None = None,
                resolution: int = 129) -> ROI:
        """An axis-aligned ellipse with semi-axes ``radii`` = (a, b); soft edge as in :meth:`circle`."""
        a, b = _pair(radii, "ROI radii", nonzero=False)
        if min(a, b) <= 0:
            raise InvalidInputError(f"ROI radii must be positive; got {(a, b)}")
        if max(a, b) > _MAX_OFFSET / 2:  # refused by ROI below, after the mask over an inf box warned
            raise InvalidInputError(f"ROI size must be positive (width, height) up to {_MAX_OFFSET:g}; got radii "
                                    f"{(a, b)}, a box {2 * a:g} x {2 * b:g}")
        width = min(a, b) / 5 if edge_width is None else finite_number(edge_width, "edge_width", lo=0.0)
        _check_edge_width(width, min(a, b), "the shorter semi-axis")
        size = (2 * a, 2 * b)
        rows, cols = _mask_grid(resolution)
        x, y = _texel_xy((0, 0), size, rows, cols)
        distance = np.hypot(x, y) - a if a == b else _ellipse_distance(x, y, a, b)
        return cls(center, size, _smooth_edge(distance, width), "ellipse")

    @classmethod
    def rectangle(cls, center: ArrayLike, size: ArrayLike, *, edge_width: float | None = None,
                  resolution: int = 129) -> ROI:
        """An axis-aligned rectangle of ``size`` = (width, height); soft edge (default min side / 10). A hard edge
        (``edge_width`` 0) is closed: m = 1 on the box's rim too, so a box over the terrain's whole extent holds all
        of it."""
        return cls.rounded_rectangle(center, size, corner_radius=0.0, edge_width=edge_width,
                                     resolution=resolution)._named("rectangle")

    @classmethod
    def rounded_rectangle(cls, center: ArrayLike, size: ArrayLike, *, corner_radius: float | None = None,
                          edge_width: float | None = None, resolution: int = 129) -> ROI:
        """A rectangle whose corners are arcs of ``corner_radius`` (default min side / 5)."""
        w, h = _pair(size, "ROI size", nonzero=False)
        if min(w, h) <= 0:
            raise InvalidInputError(f"ROI size must be positive (width, height); got {(w, h)}")
        rc = min(w, h) / 5 if corner_radius is None else finite_number(corner_radius, "corner_radius", lo=0.0)
        if rc > min(w, h) / 2:
            raise InvalidInputError(f"corner_radius must be at most half the shorter side {min(w, h) / 2}; got {rc}")
        width = min(w, h) / 10 if edge_width is None else finite_number(edge_width, "edge_width", lo=0.0)
        _check_edge_width(width, min(w, h) / 2, "half the shorter side")
        rows, cols = _mask_grid(resolution)
        x, y = _texel_xy((0, 0), (w, h), rows, cols)
        distance = _box_distance(x, y, w / 2 - rc, h / 2 - rc) - rc
        return cls(center, (w, h), _smooth_edge(distance, width, closed=True), "rounded_rectangle")

    def _named(self, shape: str) -> ROI:
        return replace(self, shape=shape)

    # -------------------------------------------------------------------------- painted
    @classmethod
    def painted(cls, mask: ArrayLike, center: ArrayLike, size: ArrayLike, *, top_row_north: bool = True) -> ROI:
        """A painted mask (§III.A.2): any grayscale image, floats in [0, 1], 8-bit (divided by 255) or 16-bit
        (uint16, divided by 65535, as a 16-bit PNG or TIFF reads); other integers and booleans are taken as they
        are (0 and 1).

        With ``top_row_north`` (the default, as images are drawn) row 0 is the *upper* y of the box.
        """
        try:
            arr = np.asarray(mask)
        except ValueError as exc:  # ragged rows
            raise InvalidInputError(f"painted mask must be a (rows, cols) array; got rows of different lengths "
                                    f"({exc})") from None
        if arr.ndim == 3 and arr.shape[2] in (3, 4):
            raise InvalidInputError(f"painted mask must be grayscale (rows, cols); got an RGB(A) image {arr.shape}")
        if np.issubdtype(arr.dtype, np.integer) and arr.dtype.itemsize == 1:
            arr = arr.astype(np.float32) / 255.0
        elif arr.dtype == np.uint16:  # a 16-bit image: refused as "divide an 8-bit mask by 255"
            arr = arr.astype(np.float32) / 65535.0
        if arr.ndim == 2 and check_flag(top_row_north, "top_row_north"):
            arr = arr[::-1]
        return cls(center, size, arr, "painted")

    # -------------------------------------------------------------------------- generated
    @classmethod
    def height_band(cls, terrain: Terrain | ArrayLike, low: float, high: float, *, edge: float = 0.0,
                    region: ArrayLike | None = None) -> ROI:
        """A generated mask (§III.A.3): m = 1 where low <= height <= high, ramping to 0 over ``edge`` metres.

        The mask is the terrain grid itself (one texel per node), over the terrain's extent or the
        sub-``region`` (xmin, xmax, ymin, ymax).
        """
        lo, hi = _finite(low, "height band low"), _finite(high, "height band high")
        if hi < lo:
            raise InvalidInputError(f"height band must be finite with low <= high; got ({low}, {high})")
        edge = finite_number(edge, "edge", lo=0.0)
        heights, center, size = _terrain_window(terrain, region)
        if edge >= _FLOAT32_SMALLEST:  # a smaller edge is 0 in float32 (0 / 0 at the bounds): the hard band, its limit
            # the float32 heights' ramp, in float64 where its bounds pass float32's range: they were inf, and the
            # mask inf / inf = NaN -> 0 everywhere (an empty ROI) with RuntimeWarnings
            wide = max(abs(lo - edge), abs(hi + edge)) > FLOAT32_MAX
            h = heights.astype(np.float64) if wide else heights
            with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
                m = np.clip((h - (lo - edge)) / edge, 0, 1) * np.clip(((hi + edge) - h) / edge, 0, 1)
        else:  # bounds clamped to float32's range (they overflowed in the comparison's cast), which compares alike
            m = ((heights >= max(lo, -FLOAT32_MAX)) & (heights <= min(hi, FLOAT32_MAX))).astype(np.float32)
        return cls(center, size, np.nan_to_num(m, nan=0.0), "height_band")

    @classmethod
    def slope_above(cls, terrain: Terrain | ArrayLike, degrees: float, *, edge: float = 0.0,
                    region: ArrayLike | None = None) -> ROI:
        """A generated mask: m = 1 where the slope exceeds ``degrees``, ramping over ``edge`` degrees.

        The slope is the terrain's (central differences of its heights, as :meth:`height_band`'s grid, one texel per
        node), also along the edge of a sub-``region``; next to nodata the one-sided difference to the neighbour with
        a height. m = 0 at nodata nodes and where a node has no neighbour with a height along an axis."""
        d = _finite(degrees, "slope threshold")
        if not 0 <= d < 90:
            raise InvalidInputError(f"slope threshold must lie in [0, 90) degrees; got {degrees}")
        edge = finite_number(edge, "edge", lo=0.0)
        t = as_terrain(terrain)
        dx, dy = abs(t.spacing[0]), abs(t.spacing[1])
        slope, center, size = _terrain_window(t, region, field=lambda h: np.degrees(_slope(h, dx, dy)))
        with np.errstate(invalid="ignore", over="ignore"):  # over: a subnormal edge (±inf, clipped as meant)
            m = np.clip((slope - d) / edge, 0, 1) if edge > 0 else (slope > d).astype(np.float32)
        return cls(center, size, np.nan_to_num(m, nan=0.0), "slope_above")

    @classmethod
    def stepped_level(cls, terrain: Terrain | ArrayLike, level: int, *, interval: float | None = None,
                      levels: ArrayLike | None = None, base: float = 0.0, region: ArrayLike | None = None) -> ROI:
        """A generated mask: the nodes whose stepped level (paper 000) is ``level`` (an isovalue index). A level
        that holds no height of the terrain (of the ``region``) is refused, naming the levels that do."""
        from .stepped import isovalues, thresholds_of

        t = as_terrain(terrain)
        values = np.asarray(isovalues(t.height_range, interval=interval, levels=levels, base=base), np.float32)
        if isinstance(level, (bool, np.bool_)) or not isinstance(level, (int, np.integer)):
            raise InvalidInputError(f"level must be a whole isovalue index; got {plain_repr(level)}")
        level = int(level)
        if not 0 <= level < len(values):
            raise InvalidInputError(f"level must index the {counted(len(values), 'isovalue')} (0..{len(values) - 1}); "
                                    f"got {level}")
        # the stepped kernels' float32 thresholds: a height on one belongs to the upper level there and here (their
        # float64 midpoints put a height between the two roundings on the other side)
        thresholds = thresholds_of(values)
        low = -np.inf if level == 0 else thresholds[level - 1]
        high = np.inf if level == len(values) - 1 else thresholds[level]
        heights, center, size = _terrain_window(t, region)
        with np.errstate(invalid="ignore"):
            m = ((heights >= low) & (heights < high)).astype(np.float32)
        if not m.any():  # an empty ROI was refused only when it met the terrain, as "holds no terrain"
            finite = heights[np.isfinite(heights)]
            held = np.unique(np.searchsorted(thresholds, finite, side="right")) if len(thresholds) else \
                np.zeros(min(len(finite), 1), np.int64)
            where = "the terrain"
            if region is not None:  # checked by _terrain_window: four numbers
                r = np.asarray(region, np.float64).reshape(-1)
                where += f" in region x [{r[0]:g}, {r[1]:g}], y [{r[2]:g}, {r[3]:g}]"
            them = (f"the levels that hold terrain there are {_index_ranges(held)}" if len(held)
                    else "it has no finite height")
            raise InvalidInputError(f"level {level} (isovalue {float(values[level]):g}) holds no height of {where}, so "
                                    f"the ROI would be empty; {them}")
        return cls(center, size, m, "stepped_level")

    # -------------------------------------------------------------------------- geometry
    @property
    def origin(self) -> tuple[float, float]:
        """The ROI origin O (§II.B): the centre of its box, the pivot of the close-up transform."""
        return self.center

    @property
    def box(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the ROI box in world units."""
        (cx, cy), (w, h) = self.center, self.size
        return (cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2)

    @property
    def _margin(self) -> float:
        """How far outside its box a point still lies on its rim: a few units in the last place of the box's
        coordinates. The box is ``center ± size / 2``, rounded: a box built from a terrain's extent (its centre and
        size; so are the generated masks' over a whole terrain) could lie one ulp inside it, and a whole rim row of
        nodes fell outside (m = 0 under a hard-edged rectangle, the row left on the terrain below the close-up)."""
        return 4.0 * float(np.spacing(max(abs(v) for v in self.box)))

    def factor(self, xy: ArrayLike) -> NDArray[np.float64]:
        """The mask factor m at world points ``xy`` (N, 2): bilinear, 0 outside the box (NumPy, float64); a point on
        the box's rim to its rounding (:attr:`_margin`) takes the rim's value."""
        p = _numbers(xy)  # [nan] when not numbers
        try:
            shape = np.shape(xy)
        except ValueError:  # ragged rows: [nan] above
            shape = ()
        # a NaN point indexed the mask at -2^63 (an IndexError); (2, N) rows of x and of y were read as N pairs
        if p.size % 2 or np.isnan(p).any() or (len(shape) > 1 and shape[-1] != 2):
            raise InvalidInputError(f"ROI factor points must be (N, 2) numbers (x, y), not NaN; got "
                                    f"{f'shape {shape}' if len(shape) > 1 else repr(xy)}")
        p = p.reshape(-1, 2)
        xmin, xmax, ymin, ymax = self.box
        rows, cols = self.mask.shape
        margin = self._margin
        with np.errstate(invalid="ignore", divide="ignore"):  # a box collapsed by rounding: NaN, outside
            u = (p[:, 0] - xmin) / (xmax - xmin)
            v = (p[:, 1] - ymin) / (ymax - ymin)
        inside = ((p[:, 0] >= xmin - margin) & (p[:, 0] <= xmax + margin) & (p[:, 1] >= ymin - margin)
                  & (p[:, 1] <= ymax + margin) & np.isfinite(u) & np.isfinite(v))
        u, v = np.where(inside, u, 0.0), np.where(inside, v, 0.0)
        fx, fy = np.clip(u, 0, 1) * (cols - 1), np.clip(v, 0, 1) * (rows - 1)
        j0 = np.minimum(np.floor(fx).astype(np.int64), cols - 2)
        i0 = np.minimum(np.floor(fy).astype(np.int64), rows - 2)
        tx, ty = fx - j0, fy - i0
        m = self.mask.astype(np.float64)
        bottom = m[i0, j0] + tx * (m[i0, j0 + 1] - m[i0, j0])
        top = m[i0 + 1, j0] + tx * (m[i0 + 1, j0 + 1] - m[i0 + 1, j0])
        return np.where(inside, bottom + ty * (top - bottom), 0.0)

    def outline(self, level: float = 0.5) -> list[NDArray[np.float64]]:
        """The ROI outline: polylines (P, 2) in world xy where m crosses ``level`` in (0, 1) (closed ones repeat
        p0)."""
        level = _outline_level(level, "ROI outline level")  # as AnchorStyle.outline_level
        cache = self.__dict__.setdefault("_outlines", {})
        if level not in cache:
            cache[level] = self._outline(level)
        return [line.copy() for line in cache[level]]

    def _outline(self, level: float) -> list[NDArray[np.float64]]:
        import contourpy

        xmin, xmax, ymin, ymax = self.box
        rows, cols = self.mask.shape
        padded = np.pad(self.mask, 1)  # so outlines touching the box edge close
        xs = np.linspace(xmin, xmax, cols)
        ys = np.linspace(ymin, ymax, rows)
        dx = xs[1] - xs[0]
        dy = ys[1] - ys[0]
        xs = np.concatenate([[xmin - dx], xs, [xmax + dx]])
        ys = np.concatenate([[ymin - dy], ys, [ymax + dy]])
        gen = contourpy.contour_generator(xs, ys, padded, line_type=contourpy.LineType.Separate)
        lines = [np.asarray(line, dtype=np.float64) for line in gen.lines(level) if len(line) >= 3]
        for line in lines:  # the padding ring lies outside the box: pull those points onto its edge
            np.clip(line[:, 0], xmin, xmax, out=line[:, 0])
            np.clip(line[:, 1], ymin, ymax, out=line[:, 1])
        return lines


def _index_ranges(indices: NDArray[np.integer]) -> str:
    """Sorted distinct indices as runs for a message: [1, 2, 3, 5] -> "1..3, 5"."""
    runs: list[list[int]] = []
    for i in indices.tolist():
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ", ".join(f"{a}" if a == b else f"{a}..{b}" for a, b in runs)


def _gradient(heights: NDArray[np.floating], dy: float, dx: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(dh/dy along rows, dh/dx along columns) of a grid with NaN for nodata: ``np.gradient``'s central differences
    (one-sided at the grid's edges) and, next to a hole, the one-sided difference to the finite neighbour (a central
    difference there was NaN: slope 0 and aspect north, silently). NaN at a nodata node (np.gradient spanned it
    from its neighbours) and where no neighbour along an axis has a height (both missing, or the one at the grid's
    edge)."""
    h = heights.astype(np.float64)
    grads = list(np.gradient(h, dy, dx))
    missing = np.isnan(h)
    if not missing.any():
        return grads[0], grads[1]
    for axis, step in ((0, dy), (1, dx)):  # the two axes, each one vectorised pass
        g = grads[axis]
        hole = np.isnan(g) & ~missing
        diff = np.diff(h, axis=axis) / step  # (h[k + 1] - h[k]) / step, as np.gradient's one-sided edges
        pad = np.full_like(np.take(h, [0], axis=axis), np.nan)
        forward = np.concatenate([diff, pad], axis=axis)  # at node k: towards k + 1
        backward = np.concatenate([pad, diff], axis=axis)  # at node k: from k - 1
        grads[axis] = np.where(missing, np.nan, np.where(hole, np.where(np.isnan(forward), backward, forward), g))
    return grads[0], grads[1]


def _slope(heights: NDArray[np.float32], dx: float, dy: float) -> NDArray[np.float64]:
    gy, gx = _gradient(heights, dy, dx)
    return np.arctan(np.hypot(gx, gy))


def _terrain_window(terrain: Terrain | ArrayLike, region: ArrayLike | None, field: Any = None):
    """Heights of a grid terrain (rows at increasing y) over its extent or a region, with the box centre/size.

    ``field``: a function of a block of those heights (e.g. the slope) returned instead of the heights; it sees the
    region with one more node on each side where the terrain has one and is then cut to the region, so a gradient
    at the region's edge is the terrain's own (central differences), not a one-sided one inside the region."""
    t = as_terrain(terrain)
    if t.kind != "grid":
        raise InvalidInputError("generated ROI masks need a grid terrain (a DEM); got a TIN")
    heights = t.heights
    dx, dy = t.spacing
    if dy < 0:
        heights = heights[::-1]
    if dx < 0:
        heights = heights[:, ::-1]
    xmin, xmax, ymin, ymax = t.extent
    if region is not None:
        bounds = _numbers(region)  # [nan] when not numbers ("0", True)
        if bounds.size != 4:
            raise InvalidInputError(f"region must be (xmin, xmax, ymin, ymax); got {region!r}")
        rx0, rx1, ry0, ry1 = (float(v) for v in bounds)
        if not (rx0 < rx1 and ry0 < ry1) or not np.all(np.isfinite([rx0, rx1, ry0, ry1])):
            raise InvalidInputError(f"region must be finite (xmin, xmax, ymin, ymax) with max > min; got {region!r}")
        cols = np.arange(heights.shape[1])
        rows = np.arange(heights.shape[0])
        xs = xmin + cols * abs(dx)
        ys = ymin + rows * abs(dy)
        cj = np.flatnonzero((xs >= rx0) & (xs <= rx1))
        ri = np.flatnonzero((ys >= ry0) & (ys <= ry1))
        if len(cj) < 2 or len(ri) < 2:
            raise InvalidInputError(
                f"region {tuple(region)} covers fewer than 2 x 2 terrain nodes of the extent "
                f"{(xmin, xmax, ymin, ymax)}")
        r0, r1 = max(ri[0] - 1, 0), min(ri[-1] + 2, heights.shape[0])  # one node of margin for ``field``
        c0, c1 = max(cj[0] - 1, 0), min(cj[-1] + 2, heights.shape[1])
        inner = (slice(ri[0] - r0, ri[-1] + 1 - r0), slice(cj[0] - c0, cj[-1] + 1 - c0))
        heights = heights[r0:r1, c0:c1]
        xmin, xmax, ymin, ymax = xs[cj[0]], xs[cj[-1]], ys[ri[0]], ys[ri[-1]]
    else:
        inner = (slice(None), slice(None))
    values = heights if field is None else field(heights)
    center = ((xmin + xmax) / 2, (ymin + ymax) / 2)
    return np.ascontiguousarray(values[inner]), center, (xmax - xmin, ymax - ymin)


# ------------------------------------------------------------------------------------------------ anchors
def transfer_function(spec: str | ArrayLike) -> NDArray[np.float32]:
    """The opacity table of an anchor transfer function: a preset name or (K,) opacities in [0, 1].

    Examples
    --------
    >>> transfer_function("linear").tolist()
    [0.8500000238418579, 0.0]
    """
    if isinstance(spec, str):
        if spec not in TRANSFER_PRESETS:
            raise InvalidInputError(f"anchor transparency must be one of {sorted(TRANSFER_PRESETS)} or an "
                                    f"opacity table; got {spec!r}")
        return np.asarray(TRANSFER_PRESETS[spec], dtype=np.float32)
    try:
        shape = np.shape(spec)
    except ValueError:  # ragged rows: refused by _numbers below
        shape = ()
    if len(shape) > 1 and max(shape, default=0) != np.prod(shape):  # (t, opacity) pairs were flattened into a table
        raise InvalidInputError(f"anchor transparency table must be (K,) opacities, spread evenly over t in [0, 1]; "
                                f"got an array of shape {shape} (pairs of t and opacity? give the opacities at K "
                                "evenly spaced t)")
    table = _numbers(spec)  # [nan] when not numbers (["0", "1"], bools): refused below
    if table.size < 1 or not np.all(np.isfinite(table)) or table.min() < 0 or table.max() > 1:
        raise InvalidInputError(f"anchor transparency table must hold opacities in [0, 1]; got {spec!r}")
    return table.astype(np.float32)


@dataclass(frozen=True)
class AnchorStyle:
    """How a close-up's anchor is drawn (§II.D, Fig. 4; inactive depictions of Fig. 5).

    ``transparency``: a :data:`TRANSFER_PRESETS` name or an opacity table over t in [0, 1] (t = 0 at the ROI,
    1 at the close-up). ``rungs``: strip rows between ROI and close-up. ``inactive``: how an inactive
    close-up's anchor looks: "hidden" (Fig. 5a), "gray" (Fig. 5b) or "faint" (Fig. 5c, a quarter of the
    opacity). ``outline_level``: the mask value whose contour is the ROI outline. ``band``: also draw the
    soft-edge faces (0 < m < 1), stretched between ROI and close-up by C, as part of the anchor, as the
    paper's SPFR does (its quality then depends on the vertex density, §IV.C); by default the anchor is the
    strip alone and the close-up shows every face with a corner of m >= ``outline_level`` fully transformed.
    ``simplify``: the fence's outline points are thinned (Douglas-Peucker, in 3D on the terrain) so that no
    rung strays more than this fraction of the ROI mask's texel from the fence through every outline point
    (the close-up's scale accounted for); 0 keeps every point. Narrow panels are what software rasterisers
    pay for (each 1-2 pixel wide sliver walks its own pixel blocks), so the default 0.25 texel costs no visible
    detail and about half the anchor pass.
    """

    transparency: str | tuple[float, ...] = "linear"
    rungs: int = 8
    inactive: Literal["hidden", "gray", "faint"] = "faint"
    outline_level: float = 0.5
    band: bool = False
    simplify: float = 0.25

    def __post_init__(self) -> None:
        table = transfer_function(self.transparency)
        if not isinstance(self.transparency, str):
            object.__setattr__(self, "transparency", tuple(float(v) for v in table))
        if isinstance(self.rungs, bool) or not isinstance(self.rungs, (int, np.integer)) or not 1 <= self.rungs <= 256:
            raise InvalidInputError(f"anchor rungs must be an int in [1, 256]; got {self.rungs!r}")
        if not is_name(self.inactive, ("hidden", "gray", "faint")):
            raise InvalidInputError(f"anchor inactive must be 'hidden', 'gray' or 'faint'; got {self.inactive!r}")
        object.__setattr__(self, "band", check_flag(self.band, "anchor band"))
        object.__setattr__(self, "outline_level", _outline_level(self.outline_level, "anchor outline_level"))
        object.__setattr__(self, "simplify", finite_number(self.simplify, "anchor simplify (mask texels)", lo=0.0,
                                                          hi=4.0))

    @property
    def table(self) -> NDArray[np.float32]:
        """The opacity table (K,)."""
        return transfer_function(self.transparency)


def _mask_hint(dtype: np.dtype, lo: float, hi: float) -> str:
    """What to do with a mask whose values leave [0, 1]: the scale of its image's bit depth, from its dtype (a uint8
    or uint16 image) or else from its range (an image's values as floats)."""
    if dtype in (np.uint8, np.uint16):
        article, top = ("an 8", 255) if dtype == np.uint8 else ("a 16", 65535)
        return f"{article}-bit {dtype} mask: divide it by {top}, or give it to ROI.painted, which does"
    if lo >= 0 and hi <= 255:
        return "an 8-bit image's values: divide them by 255"
    if lo >= 0 and hi <= 65535:
        return "a 16-bit image's values: divide them by 65535"
    return "scale it to [0, 1]"


# ------------------------------------------------------------------------------------------------ close-up
def _color(value: Any, name: str) -> tuple[float, float, float]:
    import matplotlib.colors

    refusal = f"{name} must be a matplotlib color (name, '#rrggbb' or RGB in [0, 1]); got {value!r}"
    try:
        rgb = tuple(float(c) for c in matplotlib.colors.to_rgb(value))
    except (ValueError, TypeError) as exc:
        raise InvalidInputError(refusal) from exc
    if not all(0.0 <= c <= 1.0 for c in rgb):  # matplotlib takes NaN in a tuple: a colour cast from NaN, with a warning
        raise InvalidInputError(refusal)
    return rgb  # type: ignore[return-value]


@dataclass(frozen=True, eq=False)
class CloseUp:
    """A 3D close-up (§II.B): its ROI, the transform M = R(α, β)·S(sx, sy, sz)·T(p), a color and a state.

    Parameters
    ----------
    roi : ROI
        Where the close-up comes from; its centre O is the pivot of the rotation and the scaling.
    rotation : (α, β), radians
        α tilts about the x axis, β turns about the vertical axis (the paper's y, our z); each within ±2π·1024.
    scale : s or (sx, sy, sz)
        sx, sy > 0 scale the ROI's extent; sz >= 0 its heights (sz = 0: a flat close-up, Fig. 1). Default 1: the
        ROI's own size (the CLI's ``closeup --scale`` defaults to 1.5).
    offset : (dx, dy, dz), world units
        Displacement of the close-up from its ROI (dz > 0 lifts it above the terrain). Default (0, 0, 0): in place,
        on its ROI (the CLI's ``closeup --offset`` defaults to a lift of a fifth of the extent's longer side, at
        least 0.3 of its north-south depth).
    color : matplotlib color, optional
        Ties close-up and ROI together (P2); default: the palette by position.
    active : bool
        Inactive close-ups draw their anchor as ``anchor.inactive`` says (Fig. 5).
    anchor : AnchorStyle
    spin : (turns per second, repetitions), optional
        Automatic rotation about the vertical axis for animations (§III.B); default None: no spin (the CLI's
        ``closeup --spin`` defaults to 0.25 turns per second).
    view : "overview" or "billboard"
        Overview-dependent (same camera as the overview) or overview-independent: an orthographic image
        from the fixed direction ``billboard_view`` (azimuth, elevation; radians, the elevation in [-π/2, π/2]),
        placed where the close-up is (§II.C). The azimuth is the direction the view comes *from*, clockwise from
        north (+y), as a camera's in :func:`stepterrain.render.render_mesh`: 0 looks from the north, π/2 from
        the east, π (the default, at 89° elevation: nearly from above) from the south. A spinning billboard keeps
        one size and place over its spin: it is fitted from its content's bounding cylinder about the spin axis,
        which turning keeps, so it comes out somewhat smaller than the same close-up still (fitted to its box).
    billboard_view : (azimuth, elevation), radians
        A billboard's view direction (see ``view``); default (π, 89°). Ignored with ``view="overview"``.
    stepped : float, optional
        MPFR (§IV.A): the close-up shows the stepped terrain (paper 000) at this interval, γ = ``gamma``, its
        levels colored by ``cmap``, else by the colormap the render or scene was given (``cmap`` of
        :func:`render_closeups`, :func:`closeup_scene`; the CLI's ``--colormap``).
    gamma : float
        The γ blend of a ``stepped`` close-up (paper 000 §3.3), in [0, 1]; default 1: fully stepped.
    scalars : None, "height", "slope" or "aspect"
        The data layer colored by ``cmap`` (None: the overview's mapping); slope and aspect need a grid terrain.
        Next to nodata the gradient takes the one-sided difference to the neighbour with a height; a node with
        none along an axis (both neighbours missing) has no slope or aspect and shows in the colormap's "bad"
        color (matplotlib's default: black), not as flat or facing north; so does the aspect of flat ground,
        which has no downhill direction (it showed as south).
    cmap : str, optional
        The colormap of the close-up's ``scalars`` and ``stepped`` levels; default None: "terrain", "magma" or
        "twilight" for its height, slope or aspect ``scalars``, the render's or scene's for its ``stepped`` levels.
    texture : (h, w, 3|4) uint8 image, optional
        An aerial image over the terrain's extent (row 0 at the north, i.e. the upper y) draped over the
        close-up instead (MPFR with a surface texture, §IV.B); sampled bilinearly per vertex. Its outer pixel
        edges lie on :func:`~stepterrain.texture.terrain_extent` (a grid's node extent plus half a cell, a TIN's
        point extent), as :func:`~stepterrain.texture.terrain_layer` places an image: an image of one pixel a node
        has each pixel centred on its node. Kept as a
        read-only copy of its RGB channels: changing the caller's array afterwards does not change the close-up.
    """

    roi: ROI
    _: KW_ONLY  # everything after the ROI by name, as documented
    rotation: tuple[float, float] = (0.0, 0.0)
    scale: float | tuple[float, float, float] = 1.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    color: Any = None
    active: bool = True
    anchor: AnchorStyle = field(default_factory=AnchorStyle)
    spin: tuple[float, int] | None = None
    view: Literal["overview", "billboard"] = "overview"
    billboard_view: tuple[float, float] = (math.pi, math.radians(89.0))
    stepped: float | None = None
    gamma: float = 1.0
    scalars: Literal["height", "slope", "aspect"] | None = None
    cmap: str | None = None
    texture: Any = None

    def __post_init__(self) -> None:
        if self.texture is not None:  # a private read-only copy: the caller changing their array leaves it be
            texture = _check_texture(self.texture, "close-up texture")
            if np.may_share_memory(texture, self.texture):
                texture = texture.copy()
            texture.flags.writeable = False
            object.__setattr__(self, "texture", texture)
        if not isinstance(self.roi, ROI):
            raise InvalidInputError(f"close-up roi must be a stepterrain.closeup.ROI; got {type(self.roi).__name__}")
        rot = real_vector(self.rotation, "close-up rotation", "finite (α, β) in radians", 2)
        if np.abs(rot).max() > _MAX_ANGLE:
            raise InvalidInputError(f"close-up rotation must be (α, β) in radians, each within ±{_MAX_ANGLE:.6g} (1024 "
                                    f"turns; degrees? use math.radians); got {tuple(rot.tolist())}")
        object.__setattr__(self, "rotation", (float(rot[0]), float(rot[1])))
        s = _closeup_scale(self.scale, "close-up scale")
        object.__setattr__(self, "scale", tuple(float(v) for v in s))
        p = _numbers(self.offset)
        if p.size != 3 or not np.all(np.isfinite(p)) or np.abs(p).max() > _MAX_OFFSET:
            raise InvalidInputError(f"close-up offset must be finite (dx, dy, dz) metres, each within "
                                    f"±{_MAX_OFFSET:g}; got {self.offset!r}")
        object.__setattr__(self, "offset", tuple(float(v) for v in p))
        if self.color is not None:
            object.__setattr__(self, "color", _color(self.color, "close-up color"))
        object.__setattr__(self, "active", check_flag(self.active, "close-up active"))
        if not isinstance(self.anchor, AnchorStyle):
            raise InvalidInputError(f"close-up anchor must be an AnchorStyle; got {type(self.anchor).__name__}")
        if self.spin is not None:
            spin = _numbers(self.spin)  # [nan] when not numbers
            if spin.size != 2 or not float(spin[1]).is_integer():  # 2.7 repetitions were cut to 2
                raise InvalidInputError(
                    f"close-up spin must be (turns per second, whole repetitions); got {self.spin!r}")
            speed, reps = float(spin[0]), int(spin[1])
            if not math.isfinite(speed) or speed == 0 or reps < 1:
                raise InvalidInputError(f"close-up spin needs a finite non-zero speed and repetitions >= 1; "
                                        f"got {self.spin!r}")
            object.__setattr__(self, "spin", (speed, reps))
        if not is_name(self.view, ("overview", "billboard")):
            raise InvalidInputError(f"close-up view must be 'overview' or 'billboard'; got {self.view!r}")
        bv = real_vector(self.billboard_view, "billboard_view", "finite (azimuth, elevation)", 2)
        if abs(bv[0]) > _MAX_ANGLE or not abs(bv[1]) <= QUARTER_TURN:
            raise InvalidInputError(f"billboard_view must be (azimuth, elevation) in radians, the azimuth within "
                                    f"±{_MAX_ANGLE:.6g} (1024 turns) and the elevation in [-π/2, π/2]; got "
                                    f"{tuple(bv.tolist())}")
        object.__setattr__(self, "billboard_view", (float(bv[0]), float(bv[1])))
        if self.stepped is not None:
            object.__setattr__(self, "stepped", finite_number(self.stepped, "close-up stepped interval", positive=True))
        gamma = number_or_nan(self.gamma)
        if not 0.0 <= gamma <= 1.0:
            raise InvalidInputError(f"close-up gamma must lie in [0, 1]; got {self.gamma!r}")
        object.__setattr__(self, "gamma", gamma)
        _check_scalars(self.scalars, "close-up scalars")
        if self.cmap is not None:
            from .stepped import colormap

            colormap(self.cmap, argument="close-up cmap")  # an unknown name now, not at the first render

    def turn(self, time: float) -> float:
        """β at ``time`` seconds of an animation: the spin starts at time 0 (before it the close-up stands at its
        rotation), adds whole turns, then stops after the repetitions."""
        time = _seconds(time)
        if self.spin is None:
            return self.rotation[1]
        speed, reps = self.spin
        # clamped below at 0: a negative time gave the turn of the positive one (copysign drops the sign of time)
        turns = min(max(abs(speed) * float(time), 0.0), float(reps))
        return self.rotation[1] + math.copysign(2 * math.pi * turns, speed)

    def matrix(self, pivot_z: float = 0.0, *, time: float = 0.0) -> NDArray[np.float64]:
        """M as a 4 x 4 matrix on world column vectors (x, y, z, 1); see :func:`closeup_matrix`."""
        key = (finite_number(pivot_z, "pivot_z"), _seconds(time))  # NaN gave a NaN matrix
        cache = self.__dict__.setdefault("_matrices", {})  # a frame asks several times (layers, anchors, memo)
        m = cache.get(key)
        if m is None:
            if len(cache) >= 8:
                cache.clear()
            m = cache[key] = closeup_matrix(self.roi.center, pivot_z, self.rotation[0], self.turn(time), self.scale,
                                            self.offset)
        return m.copy()


def closeup_matrix(center: ArrayLike, pivot_z: float, alpha: float, beta: float, scale: ArrayLike,
                   offset: ArrayLike) -> NDArray[np.float64]:
    """The close-up transform M = T(O + p)·R_z(β)·R_x(α)·S(s)·T(−O) (4 x 4, float64).

    This is the paper's M = R(α, β)·S(sx, sy, sz)·T(p) (§II.B) taken about the ROI origin O = (cx, cy,
    pivot_z), with the translation written after the rotation and scaling (R·S·T(q) = T(R·S·q)·R·S), so
    ``offset`` is a plain world displacement.

    Examples
    --------
    >>> M = closeup_matrix((10.0, 0.0), 0.0, 0.0, 0.0, (2.0, 2.0, 2.0), (0.0, 0.0, 5.0))
    >>> (M @ [11.0, 0.0, 1.0, 1.0]).tolist()
    [12.0, 0.0, 7.0, 1.0]

    Each argument is checked by name (finite real numbers, the shapes above): an InvalidInputError otherwise.
    """
    cx, cy = _pair(center, "center", nonzero=False, scalar=False)
    pivot_z, alpha, beta = (finite_number(v, n) for v, n in ((pivot_z, "pivot_z"), (alpha, "alpha"), (beta, "beta")))
    s = _scale3(scale, "scale")
    p = real_vector(offset, "offset", "finite (dx, dy, dz)", 3)
    (sx, sy, sz), (px, py, pz) = s.tolist(), p.tolist()
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    rz = np.array([[cb, -sb, 0], [sb, cb, 0], [0, 0, 1]])
    linear = rz @ rx @ np.diag([sx, sy, sz])
    o = np.array([cx, cy, pivot_z])
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = o + np.array([px, py, pz]) - linear @ o
    return m


def max_closeups(window_size: tuple[int, int]) -> int:
    """How many close-ups a window holds: one per 64 x 64 pixels, at most 16 (P4: close-ups stay sparse).
    ``window_size`` is checked as :func:`render_closeups` checks it."""
    w, h = _window(window_size)
    return max(0, min(_MAX_CLOSEUPS, (w // _MIN_PIXELS_PER_CLOSEUP) * (h // _MIN_PIXELS_PER_CLOSEUP)))


def _check_closeups(closeups: Sequence[CloseUp] | CloseUp) -> list[CloseUp]:
    if isinstance(closeups, CloseUp):
        closeups = [closeups]
    try:
        items = list(closeups)
    except TypeError as exc:
        raise InvalidInputError(f"closeups must be a sequence of CloseUp; got {type(closeups).__name__}") from exc
    for i, cu in enumerate(items):
        if not isinstance(cu, CloseUp):
            raise InvalidInputError(f"closeups[{i}] must be a CloseUp; got {type(cu).__name__}")
    return items


def _check_in_terrain(terrain: Terrain, closeups: Sequence[CloseUp]) -> None:
    xmin, xmax, ymin, ymax = terrain.extent
    for i, cu in enumerate(closeups):
        bx0, bx1, by0, by1 = cu.roi.box
        if bx1 < xmin or bx0 > xmax or by1 < ymin or by0 > ymax:
            raise InvalidInputError(
                f"{_roi_box_named(i, cu)} lies outside the terrain's extent x [{xmin:g}, {xmax:g}], y [{ymin:g}, "
                f"{ymax:g}]{degrees_hint(terrain, (bx0, bx1, by0, by1))}")


# ------------------------------------------------------------------------------------------------ geometry
@dataclass
class _Source:
    """One close-up's input geometry (local coordinates), before the kernels."""

    points: NDArray[np.float32]
    faces: NDArray[np.int32]
    source_faces: NDArray[np.int64]
    colors: NDArray[np.uint8] | None = None
    scalars: NDArray[np.float32] | None = None


#: The most bytes, and entries, the per-terrain cache of close-up sources keeps (the current call's always kept).
#: It held up to 64 sources whatever their size, then was emptied: a ROI dragged over the embedded DEM (a quarter
#: of its width) kept 255 MB of sources of positions left behind, and the clearing rebuilt the still ones too.
_SOURCES_BYTES = 64 << 20
_SOURCES_ENTRIES = 64


#: The most sets of close-up sources whose concatenated inputs and uploads are kept. Kept while their sources were (up
#: to 64 sets), they held ~1.5 times the sources' bytes beside them, past the bound above (a ROI dragged over the
#: embedded DEM: 98 MiB beside 63 MiB of sources); made again from cached sources, they cost a concatenation.
_JOINED_SETS = 8


def _source_bytes(src: _Source) -> int:
    return sum(a.nbytes for a in (src.points, src.faces, src.source_faces, src.colors, src.scalars) if a is not None)


def _trim_sources(cache: dict[Any, _Source], current: set[Any]) -> None:
    """Drop the least recently used sources of ``cache`` (in use order, oldest first) until they hold at most
    :data:`_SOURCES_BYTES` and :data:`_SOURCES_ENTRIES` entries in all; those of the current call (``current``)
    stay, whatever they hold."""
    # list(): snapshots in one step, so that another thread's close-ups on the same terrain do not break the loops
    total = sum(_source_bytes(src) for src in list(cache.values()))
    for key in list(cache):
        if total <= _SOURCES_BYTES and len(cache) <= _SOURCES_ENTRIES:
            break
        if key not in current:
            src = cache.pop(key, None)
            total -= 0 if src is None else _source_bytes(src)


def _grid_window(terrain: Terrain, box: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
    """Node index window (i0, i1, j0, j1), inclusive, covering the ROI box plus one node."""
    rows, cols = terrain.heights.shape
    (ox, oy), (dx, dy) = terrain.origin, terrain.spacing
    ju = sorted(((box[0] - ox) / dx, (box[1] - ox) / dx))
    iu = sorted(((box[2] - oy) / dy, (box[3] - oy) / dy))
    j0 = int(np.clip(math.floor(ju[0]) - 1, 0, cols - 1))
    j1 = int(np.clip(math.ceil(ju[1]) + 1, 0, cols - 1))
    i0 = int(np.clip(math.floor(iu[0]) - 1, 0, rows - 1))
    i1 = int(np.clip(math.ceil(iu[1]) + 1, 0, rows - 1))
    return i0, i1, j0, j1


def _grid_source(terrain: Terrain, box: tuple[float, float, float, float]) -> _Source:
    """The terrain grid's nodes and faces inside the ROI window (the overview's own triangles: SPFR)."""
    rows, cols = terrain.heights.shape
    i0, i1, j0, j1 = _grid_window(terrain, box)
    if i1 <= i0 or j1 <= j0:
        return _Source(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros(0, np.int64))
    dx, dy = terrain.spacing
    h = terrain.heights[i0: i1 + 1, j0: j1 + 1]
    wr, wc = h.shape
    jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
    points = np.empty((wr * wc, 3), np.float32)
    points[:, 0] = (jj * dx).reshape(-1)
    points[:, 1] = (ii * dy).reshape(-1)
    points[:, 2] = h.reshape(-1)
    faces = grid_faces(wr, wc, flip=dx * dy < 0)
    ci, cj = np.meshgrid(np.arange(i0, i1), np.arange(j0, j1), indexing="ij")
    cell = (ci * (cols - 1) + cj).reshape(-1)
    source = (2 * cell[:, None] + np.arange(2)[None, :]).reshape(-1)
    if terrain.has_nodata:
        ok = np.isfinite(points[:, 2])[faces].all(axis=1)
        faces, source = faces[ok], source[ok]
        source = _mesh_face_index(terrain, source, i0, i1)
    return _Source(points, faces.astype(np.int32), source.astype(np.int64))


def _mesh_face_index(terrain: Terrain, grid_face: NDArray[np.int64], i0: int, i1: int) -> NDArray[np.int64]:
    """The index in ``Terrain.mesh()`` of grid faces 2·cell + t (all drawn: no nodata corner) of the cell rows
    i0..i1 − 1: that mesh leaves out the faces with a nodata corner, so the faces after one move down (2·cell + t
    named another face of the overview, or none). The drawn faces before each cell row are counted once per
    terrain; within the window's rows, from column 0."""
    finite = np.isfinite(terrain.heights)

    def drawn(rows: slice) -> NDArray[np.bool_]:  # (cell rows, 2·(cols − 1)): face 2·j + t of each row drawn
        upper, lower = finite_triangles(finite[rows.start: rows.stop + 1])
        return np.stack([upper, lower], axis=2).reshape(len(upper), -1)

    def row_starts() -> NDArray[np.int64]:
        per_row = drawn(slice(0, finite.shape[0] - 1)).sum(axis=1)
        return np.concatenate([[0], np.cumsum(per_row)]).astype(np.int64)

    starts = terrain.cached(("closeup", "drawn-face-rows"), row_starts)
    window = drawn(slice(i0, i1))
    before = np.cumsum(window, axis=1) - window  # drawn faces before each one in its row
    per_row = window.shape[1]
    row, within = np.divmod(grid_face, per_row)
    return starts[row] + before[row - i0, within]


def _tin_source(terrain: Terrain, box: tuple[float, float, float, float]) -> _Source:
    """The TIN's faces whose xy bounding box meets the ROI box (local coordinates)."""
    points = terrain.local_points()
    ox, oy = terrain.local_origin
    faces = terrain.faces
    fx, fy = points[faces, 0], points[faces, 1]
    keep = ((fx.max(1) >= box[0] - ox) & (fx.min(1) <= box[1] - ox)
            & (fy.max(1) >= box[2] - oy) & (fy.min(1) <= box[3] - oy))
    chosen = faces[keep]
    used, inverse = np.unique(chosen.reshape(-1), return_inverse=True)
    return _Source(points[used], inverse.reshape(-1, 3).astype(np.int32), np.flatnonzero(keep).astype(np.int64))


#: how far past the ROI box (a fraction of the TIN's xy span and of the box's size) a TIN face's xy bounding box may
#: lie and still be stepped for a stepped close-up: the cull's float32 test (kernels/closeup.py, mask_factor) and the
#: float32 wall crossings round by a few ulps, so a face just outside the box in float64 could keep a corner
_TIN_WINDOW_MARGIN = 1e-5


def _tin_face_boxes(terrain: Terrain) -> tuple[Any, ...]:
    """Per TIN face its local xy bounding box (x0, x1, y0, y1; float32, as the culls compare them), and the TIN's
    largest local coordinate: built once per terrain, so a stepped close-up compares boxes only."""
    points = terrain.local_points()
    fx, fy = points[terrain.faces, 0], points[terrain.faces, 1]
    span = float(np.abs(points[terrain.point_used != 0, :2]).max())
    return fx.min(1), fx.max(1), fy.min(1), fy.max(1), span


def _tin_point_faces(terrain: Terrain) -> tuple[NDArray[np.int64], NDArray[np.int32]]:
    """The faces around each TIN point (CSR: point p's are ``faces[starts[p]:starts[p + 1]]``), built once."""
    corners = terrain.faces.reshape(-1)
    order = np.argsort(corners, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(corners, minlength=len(terrain.points)))]).astype(np.int64)
    return starts, (order // 3).astype(np.int32)


def _tin_window(terrain: Terrain, box: tuple[float, float, float, float]) -> Terrain | None:
    """The part of a TIN that a stepped close-up of ``box`` can keep: the faces whose xy bounding box meets the
    box (with a margin for float32 rounding), and every face around their points, so that the stepped kernels see
    the whole neighbourhood of each such point (its twin and peak flags, kernels/stepped.py, mark_tin_twins, come
    from all its edges). Points and faces keep their order (the edge table too: it is sorted by point pair), and
    the local origin is the whole TIN's, so the faces that can touch the box step to the very vertices, faces and
    order that stepping the whole TIN gives; the cull keeps no other face (their corners lie outside the box).
    None when no face meets the box."""
    ox, oy = terrain.local_origin
    faces = terrain.faces
    x0, x1, y0, y1, span = terrain.cached(("closeup", "tin-face-boxes"), lambda: _tin_face_boxes(terrain))
    pad = _TIN_WINDOW_MARGIN * max(span, box[1] - box[0], box[3] - box[2])
    near = np.flatnonzero((x1 >= box[0] - ox - pad) & (x0 <= box[1] - ox + pad)
                          & (y1 >= box[2] - oy - pad) & (y0 <= box[3] - oy + pad))
    if not len(near):
        return None
    starts, point_faces = terrain.cached(("closeup", "tin-point-faces"), lambda: _tin_point_faces(terrain))
    corners = sorted_unique(faces[near])
    first, count = starts[corners], starts[corners + 1] - starts[corners]
    at = np.repeat(first - np.concatenate([[0], np.cumsum(count)[:-1]]), count) + np.arange(count.sum())
    chosen = faces[sorted_unique(point_faces[at])]  # the faces around the near faces' points, in the TIN's order
    used = sorted_unique(chosen)  # sorted: the points' order kept
    index = np.empty(len(terrain.points), dtype=np.int64)
    index[used] = np.arange(len(used))
    sub_faces = index[chosen]
    edges, face_edges = _edge_table(sub_faces, len(used))
    window = Terrain(kind="tin", heights=terrain.heights[used].copy(), points=terrain.points[used], faces=sub_faces,
                     edges=edges, face_edges=face_edges, point_used=np.ones(len(used), np.int32),
                     source=terrain.source, _owned=True)
    window.cached("local_origin", lambda: (ox, oy))  # the whole TIN's: the same float32 local points
    return window


#: What makes a stepped close-up smaller, in place of :func:`~stepterrain.stepped.stepped`'s advice ("coarsen the
#: isovalues": no close-up option) when its window goes over the memory budget; the command line spells it with its
#: options (cli._OPTION_PHRASES).
STEPPED_CLOSEUP_HINT = ("step the close-up at a larger interval (CloseUp.stepped) or give it a smaller ROI, or crop or "
                        "coarsen the terrain (Terrain.crop, Terrain.coarsen)")


def _stepped_source(terrain: Terrain, cu: CloseUp, colors: str, device: wp.Device,
                    memory_budget: int | None = None) -> _Source:
    """MPFR: the stepped terrain (paper 000) of the ROI window, hypsometric colors, isovalues of the whole terrain;
    refused over ``memory_budget`` (closeup_layers', else the global one) with :data:`STEPPED_CLOSEUP_HINT`."""
    from .stepped import isovalues, stepped

    values = isovalues(terrain.height_range, interval=cu.stepped)
    if terrain.kind == "grid":
        i0, i1, j0, j1 = _grid_window(terrain, cu.roi.box)
        dx, dy = terrain.spacing
        if i1 <= i0 or j1 <= j0 or not np.isfinite(terrain.heights[i0: i1 + 1, j0: j1 + 1]).any():
            # no terrain under the ROI (nodata): no geometry, as for a continuous close-up (closeup_layers names it);
            # the stepped window raised "terrain has no finite height (all nodata)" of a terrain that has heights
            return _Source(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros(0, np.int64))
        window = Terrain.from_heights(terrain.heights[i0: i1 + 1, j0: j1 + 1], spacing=(dx, dy),
                                      origin=(terrain.origin[0] + j0 * dx, terrain.origin[1] + i0 * dy))
    else:
        window = _tin_window(terrain, cu.roi.box)
        if window is None:  # no face under the ROI box: no geometry (closeup_layers names it)
            return _Source(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros(0, np.int64))
    table = _colors_for(np.asarray(values, np.float32), colors, float(values[0]), float(values[-1]))
    # stepped's own advice ("coarsen the isovalues", "step it in tiles") names what a stepped() caller can change:
    # the close-up's is given to it instead
    mesh = stepped(window, levels=values, gamma=float(cu.gamma), colors=table, memory_budget=memory_budget,
                   device=device, _budget_hint=STEPPED_CLOSEUP_HINT)
    ox, oy = terrain.local_origin
    points = np.asarray(mesh.vertices, dtype=np.float64) - [ox, oy, 0.0]
    rgb = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(np.uint8)
    source = _Source(points.astype(np.float32), np.asarray(mesh.faces, np.int32),
                     np.full(len(mesh.faces), -1, np.int64), colors=rgb)
    release(mesh)  # copied from: its arrays go now, not when the cyclic collector runs
    return source


@dataclass(frozen=True, eq=False)
class CloseUpLayer:
    """The culled, transformed geometry of one close-up (world coordinates, float64).

    ``mask_factor`` (V,) holds m per vertex, ``original`` (V, 3) V_O, ``faces`` index ``vertices``;
    ``source_faces`` (F,) are the faces' indices in the overview mesh (``Terrain.mesh()``; grid face
    2·cell + t, cells row-major, for a DEM; −1 for an MPFR stepped close-up); ``colors`` (V, 3) uint8 or None;
    ``scalars`` (V,) the close-up's own ``scalars`` (metres, or radians for slope and aspect; NaN where the nearest
    node has no gradient) or None.
    Everything but ``vertices`` and ``matrix`` depends on the ROI only and is shared, read-only, by the layers
    of every call with the same ROI objects (the cull is kept; only M is applied again).
    Layers compare and hash by identity, as :class:`ROI` does (the generated field-wise ``==`` raised numpy's "truth
    value ... is ambiguous" on their arrays, and ``hash`` "unhashable type").
    """

    index: int
    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    mask_factor: NDArray[np.float32]
    original: NDArray[np.float64]
    source_faces: NDArray[np.int64]
    colors: NDArray[np.uint8] | None
    scalars: NDArray[np.float32] | None
    matrix: NDArray[np.float64]

    def mesh(self) -> trimesh.Trimesh:
        """The layer as a ``trimesh.Trimesh`` (vertex attribute ``mask_factor``, vertex colors if any)."""
        kwargs: dict[str, Any] = {}
        if self.colors is not None:
            kwargs["vertex_colors"] = self.colors
        return trimesh.Trimesh(self.vertices, self.faces, process=False,
                               vertex_attributes={"mask_factor": self.mask_factor},
                               metadata={"closeup": self.index, "source_faces": self.source_faces}, **kwargs)


_ROI_UPLOADS: dict[Any, Any] = {}


def _layers_struct(closeups: Sequence[CloseUp], matrices: Sequence[NDArray[np.float64]],
                   local_origin: tuple[float, float], device: wp.Device) -> closeup_kernels.CloseUpLayers:
    texels = sum(cu.roi.mask.size for cu in closeups)
    if texels > _MAX_INT32:  # packed in one array: int32 offsets and row · cols + column in the kernels' lookup
        raise OutputTooLargeError(f"the close-ups' masks hold {texels:,} texels together, over the {_MAX_INT32:,} that "
                                  "the kernels' int32 indices can hold; use coarser masks or fewer close-ups")
    ox, oy = local_origin
    shift = np.eye(4)
    shift[:2, 3] = (ox, oy)
    unshift = np.linalg.inv(shift)
    layers = closeup_kernels.CloseUpLayers()
    local = np.stack([unshift @ m @ shift for m in matrices]) if matrices else np.zeros((0, 4, 4))
    layers.matrices = wp.array(local.astype(np.float32), dtype=wp.mat44, device=device)
    # the ROI boxes and masks (read-only arrays of frozen ROIs) are uploaded once per set of ROIs
    rois = tuple(cu.roi for cu in closeups)

    def upload() -> tuple[wp.array, wp.array, wp.array]:
        boxes = np.array([[b[0] - ox, b[2] - oy, b[1] - ox, b[3] - oy] for b in (r.box for r in rois)],
                         dtype=np.float32).reshape(-1, 4)
        sizes = [r.mask.size for r in rois]
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32) if sizes else np.zeros(0, np.int32)
        info = np.array([[s, *r.mask.shape] for s, r in zip(starts, rois, strict=True)],
                        dtype=np.int32).reshape(-1, 3)
        packed = np.concatenate([r.mask.reshape(-1) for r in rois]) if rois else np.zeros(1, np.float32)
        # the world box's float64 rounding, and the float32 rounding of the local box and of the points it is compared
        # with (each half an ulp of its float32 coordinate): the far rim's node j·dx and box side x1 - ox rounded one
        # float32 ulp apart, past a margin of the world's rounding alone, and the rim row had m = 0. Per side: the
        # ulps of the farthest side on every side (4 m for a box reaching 2e7 m west) lifted the nodes past a near one
        margins = (np.array([r._margin for r in rois], dtype=np.float64)[:, None]
                   + 2.0 * np.spacing(np.abs(boxes)).astype(np.float64)).astype(np.float32).reshape(-1, 4)
        return (wp.array(boxes, dtype=wp.vec4, device=device), wp.array(margins, dtype=wp.vec4, device=device),
                wp.array(info, dtype=wp.vec3i, device=device),
                wp.array(packed.astype(np.float32), dtype=wp.float32, device=device))

    key = (tuple(id(r) for r in rois), float(ox), float(oy), str(device))
    layers.boxes, layers.margins, layers.mask_info, layers.masks = derived(_ROI_UPLOADS, key, rois, upload)
    return layers


def _transfer_struct(closeups: Sequence[CloseUp], device: wp.Device) -> closeup_kernels.TransferFunctions:
    tables = [cu.anchor.table for cu in closeups] or [np.zeros(1, np.float32)]
    counts = np.array([len(t) for t in tables], np.int32)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32)
    tf = closeup_kernels.TransferFunctions()
    tf.values = wp.array(np.concatenate(tables).astype(np.float32), dtype=wp.float32, device=device)
    tf.info = wp.array(np.stack([starts, counts], axis=1), dtype=wp.vec2i, device=device)
    return tf


def _pivot_z(terrain: Terrain) -> float:
    return terrain.height_range[0]


def _vertex_scalars(terrain: Terrain, points_local: NDArray[np.float32], kind: str) -> NDArray[np.float32]:
    """Height, slope (radians) or aspect (radians clockwise from north) at local points, from the grid (the nearest
    node's, its gradient as :func:`_gradient` takes it next to nodata); NaN where that node has no gradient (a
    nodata node, or no neighbour with a height along an axis), and the aspect of flat ground (no downhill
    direction), which :func:`_colors_for` shows in the colormap's "bad" color rather than as slope 0 or an aspect."""
    if kind == "height" or terrain.kind != "grid":
        return points_local[:, 2].astype(np.float32)
    dx, dy = terrain.spacing

    def field() -> NDArray[np.float64]:  # once per terrain and kind, not per call (frames, close-ups)
        gy, gx = _gradient(terrain.heights, dy, dx)
        if kind == "slope":
            return np.arctan(np.hypot(gx, gy))
        aspect = np.mod(np.arctan2(-gx, -gy), 2 * np.pi)  # the downhill direction, clockwise from north
        # flat ground has no downhill direction (as gdaldem's aspect marks it): arctan2(-0, -0) said south, silently
        return np.where((gx == 0) & (gy == 0), np.nan, aspect)

    field_ = terrain.cached(("closeup", "scalar-field", kind), field)
    j = np.clip(np.rint(points_local[:, 0] / dx).astype(np.int64), 0, field_.shape[1] - 1)
    i = np.clip(np.rint(points_local[:, 1] / dy).astype(np.int64), 0, field_.shape[0] - 1)
    return field_[i, j].astype(np.float32)


def _overview_rgb(t: Terrain, mesh: trimesh.Trimesh, scalars: str | None, cmap: str,
                  image_texture: Any) -> NDArray[np.uint8] | None:
    """The overview's vertex colours: an aerial image, else a colormap of its scalars, else None (plain); an image
    with alpha laid over the colormap (or the plain tan)."""
    if image_texture is not None and image_texture.shape[2] == 3:
        return _texture_rgb(t, image_texture, np.asarray(mesh.vertices)[:, :2])
    colors = None
    if scalars is not None:
        local = (np.asarray(mesh.vertices, np.float64) - [*t.local_origin, 0.0]).astype(np.float32)
        colors = _colors_for(_vertex_scalars(t, local, scalars), cmap, *_scalar_range(t, scalars))
    if image_texture is None:
        return colors
    return _texture_rgb(t, image_texture, np.asarray(mesh.vertices)[:, :2], colors)


def closeup_layers(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    closeups: Sequence[CloseUp] | CloseUp,
    *,
    time: float = 0.0,
    colors: str = "terrain",
    memory_budget: int | None = None,
    device: wp.DeviceLike = None,
) -> list[CloseUpLayer]:
    """Amplify, transform and cull the geometry of every close-up in one pass of Warp kernels (§II.B, §IV.A).

    Parameters
    ----------
    terrain : Terrain, trimesh.Trimesh or (H, W) array_like
        The overview's terrain.
    closeups : CloseUp or sequence of CloseUp
    time : float
        Animation time in seconds (spinning close-ups turn, see :meth:`CloseUp.turn`).
    colors : str
        Colormap of the levels of the stepped close-ups (MPFR) that name no ``cmap`` of their own;
        :func:`render_closeups` and :func:`closeup_scene` give theirs.
    memory_budget : int, optional
        Bytes the output may take (default :func:`stepterrain.get_memory_budget`).
    device : warp device, optional

    Returns
    -------
    list of CloseUpLayer
        One per close-up, in order: the faces with a corner of m > 0, their used vertices V_C =
        (m·M + (1 − m)·I)·V_O, m and V_O.

    Raises
    ------
    InvalidInputError
        A close-up's ROI lies outside the terrain or holds none of it (its mask 0 at every node with a height: a
        ROI smaller than the grid spacing, between nodes, or over nodata), or a bad close-up.
    OutputTooLargeError
        The close-ups' source geometry exceeds the memory budget, or the 2^31 - 1 points or faces that the cull's
        int32 indices hold.

    Notes
    -----
    Each close-up starts from the terrain's own triangles inside its ROI window (a DEM: index arithmetic;
    a TIN: a bounding-box test), or from the stepped terrain of that window (MPFR). One launch transforms
    every close-up's vertices (layer id per vertex), then count -> scan -> emit keeps the faces with m > 0 and
    a second one the vertices they use. Cost: proportional to the ROI windows, not to the terrain.

    Examples
    --------
    >>> import numpy as np
    >>> cu = CloseUp(ROI.circle((5.0, 5.0), 3.0), scale=2.0, offset=(0.0, 0.0, 10.0))
    >>> layer = closeup_layers(np.zeros((11, 11), np.float32), [cu], device="cpu")[0]
    >>> bool((layer.mask_factor[layer.faces].max(axis=1) > 0).all()), float(layer.vertices[:, 2].max())
    (True, 10.0)
    """
    t = as_terrain(terrain)
    items = _check_closeups(closeups)
    _check_in_terrain(t, items)
    _check_grid_scalars(t, None, items)
    if any(cu.stepped is not None and cu.cmap is None for cu in items):  # named here, not as a close-up's "cmap"
        from .stepped import colormap

        colormap(colors, argument="colors")
    device = resolve_device(device)
    if memory_budget is not None:
        budget_value(memory_budget)  # before any work
    pivot = _pivot_z(t)
    matrices = [cu.matrix(pivot, time=time) for cu in items]
    if not items:
        return []
    sources: list[_Source] = []
    # a close-up's input geometry depends on its ROI box and mapping only, not on M: frames that move or turn
    # a close-up re-use it (a small per-terrain cache, least recently used first out)
    cache = t.cached(("closeup", "sources"), dict)
    keys = []
    for cu in items:  # one window per close-up (a handful): no loop over cells or vertices
        key = (cu.roi.box, cu.stepped, cu.gamma if cu.stepped is not None else None,
               (cu.cmap or colors) if cu.stepped is not None else None, cu.scalars, str(device))
        keys.append(key)
        src = cache.pop(key, None)  # put back last: the most recently used
        if src is not None:
            cache[key] = src
        else:
            if cu.stepped is not None:
                src = _stepped_source(t, cu, cu.cmap or colors, device, memory_budget)
            elif t.kind == "grid":
                src = _grid_source(t, cu.roi.box)
            else:
                src = _tin_source(t, cu.roi.box)
            if cu.scalars is not None:
                src.scalars = _vertex_scalars(t, src.points, cu.scalars)
            cache[key] = src
        sources.append(src)
    _trim_sources(cache, set(keys))
    total_points, total_faces = sum(len(src.points) for src in sources), sum(len(src.faces) for src in sources)
    check_budget(total_points * _CULL_POINT_BYTES + total_faces * _CULL_FACE_BYTES, "close-up geometry",
                 memory_budget, hint="use smaller ROIs or fewer close-ups")
    for items_name, count in (("points", total_points), ("faces", total_faces)):
        if count + 1 > _MAX_INT32:  # past it the int32 faces, counts and offsets wrap, whatever the budget allows
            raise OutputTooLargeError(f"close-up geometry would hold {count:,} source {items_name}, over the "
                                      f"{_MAX_INT32 - 1:,} that the cull's int32 indices can hold, whatever the memory "
                                      "budget; use smaller ROIs or fewer close-ups")
    # the concatenated inputs and their uploads, kept for the same sources (the kernels only read them)
    def join() -> tuple[Any, ...]:
        n_points = np.array([len(s.points) for s in sources])
        n_faces = np.array([len(s.faces) for s in sources])
        point_start = np.concatenate([[0], np.cumsum(n_points)[:-1]])
        points = np.concatenate([s.points for s in sources]).astype(np.float32)
        faces = np.concatenate([s.faces + ps for s, ps in zip(sources, point_start, strict=True)]).astype(np.int32)
        point_layer = np.repeat(np.arange(len(items), dtype=np.int32), n_points)
        uploads = (to_device(points.reshape(-1, 3), wp.vec3, device), to_device(point_layer, wp.int32, device),
                   to_device(faces.reshape(-1, 3), wp.vec3i, device))
        return n_faces, point_start, points, faces, point_layer, uploads

    joined_key = ("closeup", "joined", tuple(id(src) for src in sources), str(device))
    joined = derived(t.cached(("closeup", "joined"), dict), joined_key, tuple(sources), join, limit=_JOINED_SETS)
    n_faces, point_start, points, faces, point_layer, (points_wp, layer_wp, faces_wp) = joined
    n, nf = len(points), len(faces)
    layers = _layers_struct(items, matrices, t.local_origin, device)
    ox, oy = t.local_origin

    # which faces and vertices a close-up keeps depends on its ROI mask and its source geometry only, not on M:
    # the cull (count -> scan -> emit) runs once per set of sources and ROIs; a frame that moves or turns the
    # close-ups transforms the kept vertices only (the same kernel on the same points: the same V_C)
    rois = tuple(cu.roi for cu in items)
    fresh: list[NDArray[np.float64]] = []  # the cull's own transformed vertices, when it runs in this call

    def cull() -> tuple[Any, ...]:
        transformed = wp.empty(n, dtype=wp.vec3, device=device)
        factors = wp.empty(n, dtype=wp.float32, device=device)
        launch(closeup_kernels.transform_closeup_vertices, n, [points_wp, layer_wp, layers], [transformed, factors],
               device)
        counts = count_buffer("closeup.faces", nf, device)
        launch(closeup_kernels.count_closeup_faces, nf, [faces_wp, factors], [counts], device)
        offsets, face_count = exclusive_offsets(counts, "closeup.faces")
        faces_out = wp.empty(max(face_count, 1), dtype=wp.vec3i, device=device)
        face_source = wp.empty(max(face_count, 1), dtype=wp.int32, device=device)
        launch(closeup_kernels.emit_closeup_faces, nf, [faces_wp, factors, offsets], [faces_out, face_source],
               device)
        used = count_buffer("closeup.vertices", n, device)
        used.zero_()
        launch_chunked(compaction_kernels.mark_used_vertices, face_count, [faces_out], [used], device)
        voffsets, vertex_count = exclusive_offsets(used, "closeup.vertices")
        vertices_out = wp.empty(max(vertex_count, 1), dtype=wp.vec3, device=device)
        factors_out = wp.empty(max(vertex_count, 1), dtype=wp.float32, device=device)
        vertex_source = wp.empty(max(vertex_count, 1), dtype=wp.int32, device=device)
        launch(closeup_kernels.emit_used_vertices, n, [used, voffsets, transformed, factors],
               [vertices_out, factors_out, vertex_source], device)
        launch_chunked(compaction_kernels.remap_faces, face_count, [faces_out, voffsets], [faces_out], device)

        fresh.append(_world(host_copy(vertices_out[:vertex_count]), ox, oy))
        m_all = host_copy(factors_out[:vertex_count]).copy()
        src_v = host_copy(vertex_source[:vertex_count]).copy()
        f_all = host_copy(faces_out[:face_count]).astype(np.int64)
        src_f = host_copy(face_source[:face_count])
        kept_points = points[src_v]
        originals = kept_points.astype(np.float64) + [ox, oy, 0.0]
        v_layer = point_layer[src_v]
        f_layer = point_layer[faces[src_f, 0]] if face_count else np.zeros(0, np.int32)
        v_bounds = np.searchsorted(v_layer, np.arange(len(items) + 1))
        f_bounds = np.searchsorted(f_layer, np.arange(len(items) + 1))
        face_start = np.concatenate([[0], np.cumsum(n_faces)[:-1]])
        parts = []
        for k, src in enumerate(sources):
            vs, ve, fs, fe = v_bounds[k], v_bounds[k + 1], f_bounds[k], f_bounds[k + 1]
            local_src = src_v[vs:ve] - point_start[k]
            static = {
                "faces": f_all[fs:fe] - vs,
                "mask_factor": m_all[vs:ve],
                "original": originals[vs:ve],
                "source_faces": src.source_faces[src_f[fs:fe] - face_start[k]],
                "colors": None if src.colors is None else src.colors[local_src],
                "scalars": None if src.scalars is None else src.scalars[local_src],
            }
            for value in static.values():  # shared by the layers of every frame of these close-ups: read-only
                if value is not None:
                    value.setflags(write=False)
            parts.append(((vs, ve), static))
        return (wp.array(kept_points, dtype=wp.vec3, device=device),
                wp.array(v_layer, dtype=wp.int32, device=device), wp.array(m_all, dtype=wp.float32, device=device),
                parts)

    cull_key = (joined_key, tuple(id(r) for r in rois))
    kept_points_wp, kept_layer_wp, kept_factors_wp, parts = derived(t.cached(("closeup", "cull"), dict), cull_key,
                                                                    (joined, *rois), cull)
    for k, (_, static) in enumerate(parts):  # an empty close-up was drawn as a fence about nothing, without a word
        if not len(static["faces"]):
            raise InvalidInputError(_no_terrain_message(t, k, items[k]))
    if fresh:
        v_all = fresh[0]
    else:
        vertex_count = kept_points_wp.shape[0]
        vertices_out = wp.empty(max(vertex_count, 1), dtype=wp.vec3, device=device)
        launch(closeup_kernels.transform_kept_vertices, vertex_count,
               [kept_points_wp, kept_layer_wp, kept_factors_wp, layers.matrices], [vertices_out], device)
        v_all = _world(host_copy(vertices_out[:vertex_count]), ox, oy)
    return [CloseUpLayer(index=k, vertices=v_all[vs:ve], matrix=matrices[k], **static)
            for k, ((vs, ve), static) in enumerate(parts)]


#: Bytes :func:`closeup_layers` holds at once per source point and per source face, every one kept (the cull's peak):
#: the joined inputs (float32 points, int32 layer, int32 faces), the cull pass (transformed points, mask factors, used
#: flags and offsets, the kept vertices, factors and sources; face counts and offsets, kept faces and their sources),
#: and its host results (float64 vertices and originals, the kept float32 points, factors, sources and layers and
#: their uploads, colors and scalars; int64 faces and their per-layer copy, face layers, int64 source faces). Only
#: the joined inputs were counted (32 and 28 bytes): a stepped close-up of 2.2 M points and 4.4 M faces checked as
#: 183 MiB took 736 MiB.
_CULL_POINT_BYTES = (12 + 4) + (12 + 4 + 8 + 12 + 4 + 4) + (24 + 24 + 12 + 12 + 4 + 4 + 4 + 4 + 4 + 4 + 3 + 4)
_CULL_FACE_BYTES = 12 + (8 + 12 + 4) + (24 + 24 + 4 + 8)


def _roi_box_named(k: int, cu: CloseUp) -> str:
    """Close-up k and its ROI's box, as the close-ups' errors begin."""
    bx0, bx1, by0, by1 = cu.roi.box
    return f"closeups[{k}]: ROI box x [{bx0:g}, {bx1:g}], y [{by0:g}, {by1:g}]"


def _node_word(t: Terrain) -> str:
    """What the close-ups' errors call one of ``t``'s nodes."""
    return "grid node" if t.kind == "grid" else "TIN point"


def _no_terrain_message(t: Terrain, k: int, cu: CloseUp) -> str:
    """Why close-up k has no geometry: its mask is 0 at every node (point) of a triangle with three heights under
    it; where some node with a height has m > 0 but joins no such triangle (a grid node with nodata all around it, a
    TIN point on no face), that is named: the message said its mask was 0 at every node with a height. Otherwise it
    says what the box holds (no node, only nodata, or nodes with a height where m = 0): it guessed "a ROI smaller
    than the grid spacing" of any box, also of one over the whole terrain whose hard edge left m = 0 on its rim."""
    where = _node_word(t)
    head = f"{_roi_box_named(k, cu)} holds no terrain: "
    lone = _lone_heights_under(t, cu.roi)
    if lone:  # it said "its mask is 0 at every grid node with a height" of nodes with a height inside the ROI
        around = f": nodata around {'it' if lone == 1 else 'them'}" if t.kind == "grid" else ""
        nodes = counted(lone, f"{where} with a height", f"{where}s with a height")
        return (head + f"its mask is above 0 only at {nodes} that {'joins' if lone == 1 else 'join'} no triangle "
                f"with three heights (the overview has no surface there{around}); move it onto the terrain")
    xy, heights = _nodes_in_box(t, cu.roi.box)
    finite = np.isfinite(heights)
    if not len(xy):
        spacing = (f"the grid spacing {abs(t.spacing[0]):g} x {abs(t.spacing[1]):g}" if t.kind == "grid"
                   else "the TIN's point spacing")
        why = f"its box holds no {where} (it lies between the nodes, at {spacing})"
    elif not finite.any():
        why = f"the {counted(len(xy), where)} in its box {'is' if len(xy) == 1 else 'are'} nodata"
    else:
        n = int(finite.sum())
        why = (f"the ROI's mask factor m is 0 at {'the' if n == 1 else 'all'} "
               f"{counted(n, f'{where} with a height', f'{where}s with a height')} in its box")
    return (head + f"its mask is 0 at every {where} with a height ({why}); make it larger or move it onto the "
            "terrain")


def _nodes_in_box(t: Terrain, box: tuple[float, float, float, float]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
    """The world xy (N, 2) and heights (N,) of the grid nodes (TIN points) inside ``box``, rim included (error
    path only)."""
    if t.kind == "grid":
        i0, i1, j0, j1 = _grid_window(t, box)
        jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
        xy = np.column_stack([t.origin[0] + jj.reshape(-1) * t.spacing[0],
                              t.origin[1] + ii.reshape(-1) * t.spacing[1]])
        heights = t.heights[i0: i1 + 1, j0: j1 + 1].reshape(-1)
    else:
        xy, heights = t.points[:, :2].astype(np.float64), t.heights
    inside = (xy[:, 0] >= box[0]) & (xy[:, 0] <= box[1]) & (xy[:, 1] >= box[2]) & (xy[:, 1] <= box[3])
    return xy[inside], heights[inside]


def _check_content(t: Terrain, items: Sequence[CloseUp], layers: Sequence[CloseUpLayer]) -> None:
    """An InvalidInputError for a close-up that would be drawn without content: without ``anchor.band`` its content
    is the faces with a corner of m >= ``anchor.outline_level`` (:func:`_content_faces`), and a ROI that reaches the
    terrain with its soft edge only (its centre just off the extent's edge, its core over nodata or between the
    nodes) has none. The render came out as the overview alone (or with a fence about nothing), without a word."""
    for k, (cu, layer) in enumerate(zip(items, layers, strict=True)):
        top = float(layer.mask_factor.max()) if len(layer.mask_factor) else 0.0
        if cu.anchor.band or top >= cu.anchor.outline_level:
            continue
        raise InvalidInputError(
            f"{_roi_box_named(k, cu)} reaches the terrain with its soft edge only: its mask is at most {top:.3g} at "
            f"every {_node_word(t)} with a height under it, below the anchor's "
            f"outline_level {cu.anchor.outline_level:g}, so the close-up would have no content; move its centre onto "
            f"the terrain (off its edge, off nodata) or make it larger")


def _lone_heights_under(t: Terrain, roi: ROI) -> int:
    """How many nodes (points) with a height, inside ``roi``'s box, have a mask factor above 0 but lie on no triangle
    with three heights (error path only: a pass over the box's nodes)."""
    if t.kind == "grid":
        rows, cols = t.heights.shape
        i0, i1, j0, j1 = _grid_window(t, roi.box)
        r0, c0 = max(i0 - 1, 0), max(j0 - 1, 0)  # a node's triangles reach one node beyond the window
        finite = np.isfinite(t.heights[r0: min(i1 + 2, rows), c0: min(j1 + 2, cols)])
        window = (slice(i0 - r0, i1 + 1 - r0), slice(j0 - c0, j1 + 1 - c0))
        lone = (finite & ~used_nodes(finite))[window].reshape(-1)
        jj, ii = np.meshgrid(np.arange(j0, j1 + 1), np.arange(i0, i1 + 1))
        xy = np.column_stack([t.origin[0] + jj.reshape(-1) * t.spacing[0], t.origin[1] + ii.reshape(-1) * t.spacing[1]])
    else:
        xy = t.points[:, :2]
        lone = np.isfinite(t.heights) & (t.point_used == 0)
    if not lone.any():
        return 0
    return int((roi.factor(xy[lone]) > 0).sum())


def _world(local: NDArray[np.float32], ox: float, oy: float) -> NDArray[np.float64]:
    """Local float32 points (N, 3) as world float64 (the local origin added back to x and y)."""
    v = local.astype(np.float64)
    v[:, 0] += ox
    v[:, 1] += oy
    return v


# ------------------------------------------------------------------------------------------------ anchors
@dataclass(frozen=True, eq=False)
class AnchorStrip:
    """One close-up's anchor fence (§II.D): vertices from V_O (t = 0) to M·V_O, t and opacity per vertex.

    ``vertices`` (V, 3) world; ``faces`` (F, 3); ``distance`` (V,) the normalized ‖V − V_O‖ in [0, 1];
    ``opacity`` (V,) the transfer function at ``distance``; ``color`` RGB in [0, 1]; ``rungs``: V = P·(rungs + 1)
    for P outline points, point i's vertices at i·(rungs + 1) + r; ``max_length``: D, the normalization.
    Strips compare and hash by identity, as :class:`CloseUpLayer` does (they hold arrays too).
    """

    index: int
    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    distance: NDArray[np.float32]
    opacity: NDArray[np.float32]
    color: tuple[float, float, float]
    rungs: int
    max_length: float


def _nearest_vertex_heights(pts: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """The z of the point of ``pts`` (P, 3) nearest to each of ``xy`` (N, 2) in projection."""
    from scipy.spatial import cKDTree  # a dependency, imported where used

    return pts[cKDTree(pts[:, :2]).query(xy)[1], 2]


def _tin_heights(terrain: Terrain, xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Heights of a TIN's drawn triangles at world ``xy`` (N, 2): each point's triangle found in projection and its
    plane interpolated barycentrically (the nearest vertex's height left a fence foot above or below a coarse
    TIN's face); points outside every triangle take the nearest used vertex's height.

    Vectorised point location: the triangles whose box meets the points' box are binned on a uniform grid of cells
    about one median triangle wide (each in every cell its box covers, clipped to the points' box), each point is
    tested against the triangles of its cell, and the triangle that holds it most (largest smallest barycentric
    coordinate, within 1e-9) wins."""
    pts, faces = terrain.points, terrain.faces
    if len(xy) == 0:
        return np.zeros(0)
    z = _nearest_vertex_heights(pts[terrain.point_used.astype(bool)], xy)
    x0, y0 = xy.min(axis=0)
    x1, y1 = xy.max(axis=0)
    fx, fy = pts[:, 0][faces], pts[:, 1][faces]
    lo_x, hi_x, lo_y, hi_y = fx.min(axis=1), fx.max(axis=1), fy.min(axis=1), fy.max(axis=1)
    cand = np.flatnonzero((hi_x >= x0) & (lo_x <= x1) & (hi_y >= y0) & (lo_y <= y1))
    if cand.size == 0:
        return z
    lo_x, hi_x, lo_y, hi_y = lo_x[cand], hi_x[cand], lo_y[cand], hi_y[cand]
    span = max(x1 - x0, y1 - y0)
    cell = max(float(np.median(np.maximum(hi_x - lo_x, hi_y - lo_y))), span / 4096, 1e-300)

    def cells(v: NDArray[np.float64], v0: float, n: int) -> NDArray[np.int64]:  # monotone in v: a box holds its points
        return np.clip(np.floor((v - v0) / cell), 0, n - 1).astype(np.int64)

    while True:  # cells twice as wide while a few large triangles among many small ones would fill too many cells
        nx, ny = int((x1 - x0) // cell) + 1, int((y1 - y0) // cell) + 1
        cx0, cx1, cy0, cy1 = cells(lo_x, x0, nx), cells(hi_x, x0, nx), cells(lo_y, y0, ny), cells(hi_y, y0, ny)
        wide = cx1 - cx0 + 1
        count = wide * (cy1 - cy0 + 1)
        if count.sum() <= 16 * (len(cand) + len(xy)) or nx * ny == 1:
            break
        cell *= 2
    k = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)  # index in the triangle's block
    wide_r = np.repeat(wide, count)
    binned = (np.repeat(cy0, count) + k // wide_r) * nx + np.repeat(cx0, count) + k % wide_r
    order = np.argsort(binned, kind="stable")
    binned, binned_face = binned[order], np.repeat(cand, count)[order]
    foot_cell = cells(xy[:, 1], y0, ny) * nx + cells(xy[:, 0], x0, nx)
    start = np.searchsorted(binned, foot_cell, side="left")
    n = np.searchsorted(binned, foot_cell, side="right") - start
    foot = np.repeat(np.arange(len(xy)), n)  # (foot, triangle) pairs to test
    tri = faces[binned_face[np.repeat(start, n) + np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)]]
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    px, py = xy[foot, 0] - a[:, 0], xy[foot, 1] - a[:, 1]
    bx, by, qx, qy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1], c[:, 0] - a[:, 0], c[:, 1] - a[:, 1]
    det = bx * qy - qx * by  # > 0: the TIN is wound counter-clockwise; zero-area slivers are skipped
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = (px * qy - qx * py) / det, (bx * py - px * by) / det  # the weights of b and c
    score = np.where(det > 0, np.minimum(np.minimum(u, v), 1 - u - v), -np.inf)
    best = np.lexsort((-score, foot))
    first = best[np.unique(foot[best], return_index=True)[1]]  # each foot's most-inside triangle
    held = first[score[first] >= -1e-9]
    z[foot[held]] = a[held, 2] + u[held] * (b[held, 2] - a[held, 2]) + v[held] * (c[held, 2] - a[held, 2])
    return z


def _heights_at(terrain: Terrain, xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Terrain heights at world xy on the overview mesh's own triangles: for a grid each cell split along its
    diagonal from node (i, j) to (i + 1, j + 1), as :func:`~stepterrain.terrain.grid_faces` splits it (a bilinear
    height left an anchor's foot up to a few metres above or below the drawn surface), over nodata (no drawn
    triangle) the height of the nearest node that has one; for a TIN the triangle holding the point
    (:func:`_tin_heights`; outside every triangle the nearest vertex's height)."""
    if terrain.kind != "grid":
        return _tin_heights(terrain, xy)
    rows, cols = terrain.heights.shape
    (ox, oy), (dx, dy) = terrain.origin, terrain.spacing
    fx = np.clip((xy[:, 0] - ox) / dx, 0, cols - 1)
    fy = np.clip((xy[:, 1] - oy) / dy, 0, rows - 1)
    j0 = np.minimum(np.floor(fx).astype(np.int64), cols - 2)
    i0 = np.minimum(np.floor(fy).astype(np.int64), rows - 2)
    tx, ty = fx - j0, fy - i0
    h = terrain.heights
    h00, h01 = h[i0, j0].astype(np.float64), h[i0, j0 + 1].astype(np.float64)
    h10, h11 = h[i0 + 1, j0].astype(np.float64), h[i0 + 1, j0 + 1].astype(np.float64)
    z = np.where(tx >= ty, h00 + tx * (h01 - h00) + ty * (h11 - h01),  # triangle (n00, n01, n11)
                 h00 + ty * (h10 - h00) + tx * (h11 - h10))  # triangle (n00, n11, n10)
    hole = ~np.isfinite(z)
    if hole.any():  # no drawn triangle there: the nearest node with a height on the hole's rim (the lowest height of
        z[hole] = _nearest_vertex_heights(_nodata_rim(terrain), xy[hole])  # the terrain dropped the fence to it)
    return z


def _nodata_rim(terrain: Terrain) -> NDArray[np.float64]:
    """World points (P, 3) of a grid's nodes with a height next to nodata (8-neighbourhood), once per terrain: the
    nearest of them to a point over a hole is its nearest node with a height."""

    def build() -> NDArray[np.float64]:
        missing = np.pad(~np.isfinite(terrain.heights), 1)
        near = np.zeros_like(missing)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                near |= np.roll(np.roll(missing, di, axis=0), dj, axis=1)
        i, j = np.nonzero(near[1:-1, 1:-1] & ~missing[1:-1, 1:-1])
        (ox, oy), (dx, dy) = terrain.origin, terrain.spacing
        return np.column_stack([ox + j * dx, oy + i * dy, terrain.heights[i, j].astype(np.float64)])

    return terrain.cached(("closeup", "nodata-rim"), build)


def _closeup_color(cu: CloseUp, k: int) -> tuple[float, float, float]:
    return cu.color if cu.color is not None else _color(PALETTE[k % len(PALETTE)], "color")


def anchor_strips(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    closeups: Sequence[CloseUp] | CloseUp,
    *,
    time: float = 0.0,
    device: wp.DeviceLike = None,
) -> list[AnchorStrip]:
    """The anchor fence of every close-up (§II.D), built by Warp kernels in one launch per stage.

    The ROI outline (the contour of the mask at ``anchor.outline_level``) is laid on the overview's terrain
    (V_O: the height of the drawn triangle under each point; over a DEM's nodata, the nearest node's with a height;
    on a TIN, a point outside every triangle takes the nearest vertex's height), cut at the edge of the terrain's
    extent, which closes it where the ROI reaches past it (the fence frames the close-up's content); each outline
    point gets a rung of ``anchor.rungs`` + 1 vertices up to M·V_O, consecutive points a fence panel.
    t = ‖V − V_O‖ / D with D the longest rung of the close-up, and the opacity is the transfer function at t
    (Fig. 4).

    Examples
    --------
    >>> import numpy as np
    >>> cu = CloseUp(ROI.circle((5.0, 5.0), 3.0), offset=(0.0, 0.0, 10.0))
    >>> strip = anchor_strips(np.zeros((11, 11), np.float32), [cu], device="cpu")[0]
    >>> float(strip.distance.min()), float(strip.distance.max())
    (0.0, 1.0)
    """
    t = as_terrain(terrain)
    items = _check_closeups(closeups)
    _check_in_terrain(t, items)
    if not items:
        return []
    device = resolve_device(device)
    pivot = _pivot_z(t)
    matrices = [cu.matrix(pivot, time=time) for cu in items]
    ox, oy = t.local_origin
    # the outline laid on the terrain, its uploads and the fence faces depend on the ROIs and anchor styles only,
    # not on M: made once per set of them; a frame emits the strip vertices (and their t) for its M
    rois = tuple(cu.roi for cu in items)
    key = (tuple(id(r) for r in rois), tuple(cu.anchor for cu in items), tuple(cu.scale for cu in items),
           str(device))  # the scale sets how far the outline is thinned
    fixed = derived(t.cached(("closeup", "anchor-static"), dict), key, rois, lambda: _anchor_static(t, items, device))
    if fixed is None:
        return [AnchorStrip(k, np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.float32),
                            np.zeros(0, np.float32), _closeup_color(cu, k), cu.anchor.rungs, 0.0)
                for k, cu in enumerate(items)]
    total, (nv, layer_rungs_wp, vertex_start_wp), outline_layer, outline_wp, layer_wp, tf, v_bounds, layer_faces = \
        fixed
    layers = _layers_struct(items, matrices, t.local_origin, device)
    lengths = wp.empty(total, dtype=wp.float32, device=device)
    launch(closeup_kernels.anchor_lengths, total, [outline_wp, layer_wp, layers], [lengths], device)
    max_len = np.zeros(len(items), np.float32)
    np.maximum.at(max_len, outline_layer, lengths.numpy())
    vertices = wp.empty(nv, dtype=wp.vec3, device=device)
    distance = wp.empty(nv, dtype=wp.float32, device=device)
    opacity = wp.empty(nv, dtype=wp.float32, device=device)
    launch(closeup_kernels.emit_anchor_vertices, total,
           [outline_wp, layer_wp, layers, to_device(max_len, wp.float32, device), tf, layer_rungs_wp, vertex_start_wp],
           [vertices, distance, opacity], device)
    v = _world(host_copy(vertices), ox, oy)
    d, a = distance.numpy(), opacity.numpy()
    return [
        AnchorStrip(k, v[v_bounds[k]: v_bounds[k + 1]], layer_faces[k], d[v_bounds[k]: v_bounds[k + 1]],
                    a[v_bounds[k]: v_bounds[k + 1]], _closeup_color(cu, k), cu.anchor.rungs, float(max_len[k]))
        for k, cu in enumerate(items)
    ]


def simplify_polyline(points: ArrayLike, tolerance: float) -> NDArray[np.bool_]:
    """Douglas-Peucker: which of the polyline's points (N, D) to keep so that every dropped point lies within
    ``tolerance`` of the segment between its kept neighbours (the ends are always kept)."""
    p = np.asarray(points, dtype=np.float64)
    keep = np.zeros(len(p), bool)
    if len(p) == 0:
        return keep
    keep[[0, -1]] = True
    stack = [(0, len(p) - 1)]
    while stack:  # one numpy step per kept point: a few hundred per outline
        i, j = stack.pop()
        if j - i < 2:
            continue
        a, ab = p[i], p[j] - p[i]
        rel = p[i + 1: j] - a
        length2 = float(ab @ ab)
        along = np.clip(rel @ ab / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(rel))
        dist = np.linalg.norm(rel - along[:, None] * ab, axis=1)
        worst = int(np.argmax(dist))
        if dist[worst] > tolerance:
            m = i + 1 + worst
            keep[m] = True
            stack += [(i, m), (m, j)]
    return keep


def _fence_tolerance(cu: CloseUp) -> float:
    """World distance to which an anchor's outline is thinned: ``anchor.simplify`` mask texels, divided by the
    close-up's largest scale (a rung at s is the outline under (1 - s)·I + s·M, whose linear part stretches by
    at most max(1, |s_x|, |s_y|, |s_z|): no rung strays further than the texel fraction)."""
    if cu.anchor.simplify <= 0:
        return 0.0
    rows, cols = cu.roi.mask.shape
    xmin, xmax, ymin, ymax = cu.roi.box
    texel = min((xmax - xmin) / max(cols - 1, 1), (ymax - ymin) / max(rows - 1, 1))
    return cu.anchor.simplify * texel / max(1.0, *(abs(float(v)) for v in cu.scale))


def _perimeter_position(p: NDArray[np.float64], box: tuple[float, float, float, float]) -> NDArray[np.float64]:
    """Arc length of points on the rectangle ``box`` (xmin, xmax, ymin, ymax) counter-clockwise from its lower-left
    corner (each point taken on its nearest side)."""
    x0, x1, y0, y1 = box
    w, h = x1 - x0, y1 - y0
    x, y = np.clip(p[:, 0], x0, x1), np.clip(p[:, 1], y0, y1)
    gaps = np.stack([y - y0, x1 - x, y1 - y, x - x0], axis=1)  # bottom, right, top, left
    arc = np.stack([x - x0, w + (y - y0), w + h + (x1 - x), 2 * w + h + (y1 - y)], axis=1)
    return arc[np.arange(len(p)), np.argmin(gaps, axis=1)]


def _perimeter_path(s0: float, s1: float, box: tuple[float, float, float, float]) -> NDArray[np.float64]:
    """The rectangle's boundary from arc length s0 to s1 (counter-clockwise, past the start when s1 <= s0), corners
    included."""
    x0, x1, y0, y1 = box
    w, h = x1 - x0, y1 - y0
    total = 2 * (w + h)
    if s1 <= s0:
        s1 += total
    corners = np.array([w, w + h, 2 * w + h, total])
    arcs = [s0, *(c + n * total for n in (0, 1) for c in corners if s0 < c + n * total < s1), s1]

    def at(s: float) -> tuple[float, float]:
        s = s % total
        if s <= w:
            return (x0 + s, y0)
        if s <= w + h:
            return (x1, y0 + s - w)
        if s <= 2 * w + h:
            return (x1 - (s - w - h), y1)
        return (x0, y1 - (s - 2 * w - h))

    return np.array([at(s) for s in arcs])


def _clip_outline(lines: list[NDArray[np.float64]], roi: ROI, level: float,
                  box: tuple[float, float, float, float]) -> list[NDArray[np.float64]]:
    """The outline of the ROI's part over the rectangle ``box`` (the terrain's extent): the outline's pieces inside
    it (segments cut by Liang-Barsky) and the stretches of the box's boundary where m >= ``level`` (the ROI cut by
    the terrain's edge), as polylines. Lines wholly inside come back unchanged; with no outline point outside, the
    same lines."""
    x0, x1, y0, y1 = box
    if not lines or all(((ln[:, 0] >= x0) & (ln[:, 0] <= x1) & (ln[:, 1] >= y0) & (ln[:, 1] <= y1)).all()
                        for ln in lines):
        return lines
    pieces: list[NDArray[np.float64]] = []
    ends: list[NDArray[np.float64]] = []  # points where the outline meets the box's boundary
    for line in lines:
        p, d = line[:-1], np.diff(line, axis=0)
        t0, t1 = np.zeros(len(p)), np.ones(len(p))
        visible = np.ones(len(p), bool)
        for pk, qk in ((-d[:, 0], p[:, 0] - x0), (d[:, 0], x1 - p[:, 0]), (-d[:, 1], p[:, 1] - y0),
                       (d[:, 1], y1 - p[:, 1])):
            with np.errstate(divide="ignore", invalid="ignore"):
                r = qk / pk
            visible &= ~((pk == 0) & (qk < 0))
            t0 = np.where(pk < 0, np.maximum(t0, r), t0)
            t1 = np.where(pk > 0, np.minimum(t1, r), t1)
        visible &= t0 < t1
        start, stop = p + t0[:, None] * d, p + t1[:, None] * d
        run: list[NDArray[np.float64]] = []
        runs: list[list[NDArray[np.float64]]] = []
        last_full: set[int] = set()  # the previous visible segment, when it reached its end point
        for i in np.flatnonzero(visible):  # a few hundred segments of a cut outline
            if not run or t0[i] > 0 or i - 1 not in last_full:
                if run:
                    runs.append(run)
                run = [start[i]]
            run.append(stop[i])
            last_full = {i} if t1[i] >= 1 else set()
        if run:
            runs.append(run)
        closed = len(line) > 2 and np.array_equal(line[0], line[-1])
        if closed and len(runs) > 1 and visible[0] and t0[0] <= 0 and visible[-1] and t1[-1] >= 1:
            runs[0] = runs.pop()[:-1] + runs[0]  # the run through the closing point is one
        for r in runs:
            piece = np.array(r)
            pieces.append(piece)
            if not np.array_equal(piece[0], piece[-1]):
                ends += [piece[0], piece[-1]]
    # the boundary between consecutive meeting points (all of it when there are none) belongs to the ROI's part
    # where m >= level at its middle; but not where an outline piece already runs along it (a ROI whose box edge
    # is the terrain's: that stretch of fence was drawn twice, once with the outline and once with the boundary)
    covered = _along_boundary(pieces, box)
    total = 2 * (x1 - x0 + y1 - y0)
    arcs = np.unique(np.concatenate([_perimeter_position(np.array(ends), box) if ends else np.zeros(1),
                                     covered.reshape(-1) % total]))
    for s0, s1 in zip(arcs, np.roll(arcs, -1), strict=True):
        mid = s0 + ((s1 - s0) % total or total) / 2  # one stretch: all the way round
        if ((covered[:, 0] < mid % total) & (mid % total < covered[:, 1])).any():
            continue
        if _holds(_perimeter_path(mid, mid, box)[0], lines, roi, level, 1e-9 * (x1 - x0 + y1 - y0)):
            pieces.append(_perimeter_path(s0, s1, box))
    return [piece for piece in pieces if len(piece) > 1]


def _holds(q: NDArray[np.float64], lines: list[NDArray[np.float64]], roi: ROI, level: float, tol: float) -> bool:
    """Whether point q lies in the ROI's part where m >= ``level`` as its outline ``lines`` (closed: the mask is padded
    with 0) bound it: inside an odd number of them (even-odd rule). The outline is contourpy's piecewise linear
    contour, not the bilinear m's level curve: m at a point near the outline can fall on the other side of it, and a
    boundary stretch between two meeting points of the fence was left open (or fenced where the ROI does not hold
    it). On an outline line itself (within ``tol``), m decides."""
    x, y = float(q[0]), float(q[1])
    inside = False
    for line in lines:
        a, b = line[:-1], line[1:]
        ab = b - a
        length2 = np.einsum("ij,ij->i", ab, ab)
        with np.errstate(divide="ignore", invalid="ignore"):
            along = np.clip(np.where(length2 > 0, ((q - a) * ab).sum(axis=1) / length2, 0.0), 0.0, 1.0)
        if len(a) and float(np.hypot(*(a + along[:, None] * ab - q).T).min()) <= tol:
            return bool(roi.factor(q[None, :])[0] >= level)
        crosses = (a[:, 1] > y) != (b[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xi = a[:, 0] + (y - a[:, 1]) * ab[:, 0] / ab[:, 1]
        inside ^= bool(np.count_nonzero(crosses & (x < xi)) % 2)
    return inside


def _along_boundary(pieces: list[NDArray[np.float64]], box: tuple[float, float, float, float]) -> NDArray[np.float64]:
    """(K, 2) intervals lo < hi of arc length on the rectangle ``box`` (as :func:`_perimeter_position` counts it) of
    the polylines' segments that lie along one of its sides (both ends on it, to a rounding of its size)."""
    x0, x1, y0, y1 = box
    w, h = x1 - x0, y1 - y0
    tol = 1e-9 * (w + h)
    intervals = [np.zeros((0, 2))]
    for piece in pieces:
        a, b = piece[:-1], piece[1:]
        for on, pos in ((lambda p: np.abs(p[:, 1] - y0) <= tol, lambda p: p[:, 0] - x0),  # bottom, right, top, left
                        (lambda p: np.abs(p[:, 0] - x1) <= tol, lambda p: w + (p[:, 1] - y0)),
                        (lambda p: np.abs(p[:, 1] - y1) <= tol, lambda p: w + h + (x1 - p[:, 0])),
                        (lambda p: np.abs(p[:, 0] - x0) <= tol, lambda p: 2 * w + h + (y1 - p[:, 1]))):
            along = on(a) & on(b)
            if along.any():
                ends = np.sort(np.stack([pos(a[along]), pos(b[along])], axis=1), axis=1)
                intervals.append(ends[ends[:, 1] - ends[:, 0] > tol])
    return np.concatenate(intervals)


def _anchor_static(t: Terrain, items: Sequence[CloseUp], device: wp.Device) -> tuple[Any, ...] | None:
    """The M-independent part of :func:`anchor_strips`: the outline points on the terrain (uploaded), their
    close-up ids, the transfer tables, and each strip's faces (read-only); None when no ROI has an outline.
    An outline beyond the terrain's extent is cut at its edge, and the edge closes it where the ROI holds it
    (:func:`_clip_outline`): no fence stands where there is no terrain and no close-up."""
    ox, oy = t.local_origin
    extent = t.extent
    outlines = [(k, line) for k, cu in enumerate(items)
                for line in _clip_outline(cu.roi.outline(cu.anchor.outline_level), cu.roi, cu.anchor.outline_level,
                                          extent)]
    if not outlines:
        return None
    # the terrain under every outline point at once (a TIN locates every point's triangle in one pass)
    all_z = np.split(_heights_at(t, np.concatenate([line for _, line in outlines])),
                     np.cumsum([len(line) for _, line in outlines])[:-1])
    tolerances = [_fence_tolerance(cu) for cu in items]
    points, layer_ids, segments, heights = [], [], [], []
    total = 0
    for (k, line), z_line in zip(outlines, all_z, strict=True):  # per outline line: a handful
        if tolerances[k] > 0:
            keep = simplify_polyline(np.column_stack([line, z_line]), tolerances[k])
            line, z_line = line[keep], z_line[keep]
        idx = np.arange(total, total + len(line))
        segments.append(np.stack([idx[:-1], idx[1:]], axis=1))
        points.append(line)
        heights.append(z_line)
        layer_ids.append(np.full(len(line), k, np.int32))
        total += len(line)
    xy = np.concatenate(points)
    z = np.concatenate(heights)
    outline = np.column_stack([xy[:, 0] - ox, xy[:, 1] - oy, z]).astype(np.float32)
    outline_layer = np.concatenate(layer_ids)
    seg = np.concatenate(segments).astype(np.int32)
    # each close-up its own anchor.rungs, still one launch: per point its first strip vertex, per segment its first
    # face (every strip was given the largest rung count of the call, and AnchorStrip.rungs said so)
    layer_rungs = np.array([cu.anchor.rungs for cu in items], np.int64)
    point_rungs = layer_rungs[outline_layer]
    vertex_start = np.concatenate([[0], np.cumsum(point_rungs + 1)])  # (points + 1,): the last is the total
    seg_layer = outline_layer[seg[:, 0]]
    face_start = np.concatenate([[0], np.cumsum(2 * layer_rungs[seg_layer])])
    layer_rungs_wp = to_device(layer_rungs.astype(np.int32), wp.int32, device)
    vertex_start_wp = to_device(vertex_start[:-1].astype(np.int32), wp.int32, device)
    layer_wp = wp.array(outline_layer, dtype=wp.int32, device=device)
    faces = wp.empty(int(face_start[-1]), dtype=wp.vec3i, device=device)
    launch(closeup_kernels.emit_anchor_faces, len(seg),
           [to_device(seg, wp.vec2i, device), layer_wp, layer_rungs_wp, vertex_start_wp,
            to_device(face_start[:-1].astype(np.int32), wp.int32, device)], [faces], device)
    f = host_copy(faces).astype(np.int64)
    v_bounds = vertex_start[np.searchsorted(outline_layer, np.arange(len(items) + 1))]
    f_bounds = face_start[np.searchsorted(seg_layer, np.arange(len(items) + 1))]
    layer_faces = []
    for k in range(len(items)):
        fk = f[f_bounds[k]: f_bounds[k + 1]] - v_bounds[k]
        fk.setflags(write=False)
        layer_faces.append(fk)
    outline_wp = wp.array(outline, dtype=wp.vec3, device=device)
    return (total, (int(vertex_start[-1]), layer_rungs_wp, vertex_start_wp), outline_layer, outline_wp, layer_wp,
            _transfer_struct(items, device), v_bounds, layer_faces)


# ------------------------------------------------------------------------------------------------ compositing
def composite(
    base: NDArray[np.uint8],
    base_depth: NDArray[np.float32],
    layers: Sequence[tuple[NDArray[Any], NDArray[np.float32], NDArray[np.float32], bool, bool]],
) -> NDArray[np.uint8]:
    """Image-based compositing in the order of generation (§IV.B).

    Parameters
    ----------
    base : (H, W, 3) uint8
        The overview pass (background included).
    base_depth : (H, W) float32
        Its depth (inf where empty).
    layers : sequence of (color, alpha, depth, depth_test, writes_depth)
        ``color`` (H, W, 3) uint8 or float in [0, 255], ``alpha`` (H, W) in [0, 1] or a bool mask (0 where the layer is
        empty), ``depth`` (H, W). A layer shows where alpha > 0 and, with ``depth_test``, where its depth is
        below the depth so far; ``writes_depth`` layers then replace that depth.

    Returns
    -------
    (H, W, 3) uint8
        C ← a·c + (1 − a)·C per layer, a = alpha·visible; with no layers exactly ``base``.

    Raises
    ------
    InvalidInputError
        A base that is not (H, W, 3) uint8, a layer not of five items or of other shapes, a colour outside
        [0, 255], an alpha outside [0, 1] (NaN included), a NaN depth, a depth_test or writes_depth not a bool.

    Examples
    --------
    >>> import numpy as np
    >>> base = np.zeros((2, 2, 3), np.uint8); depth = np.ones((2, 2), np.float32)
    >>> red = np.full((2, 2, 3), 200.0); alpha = np.array([[1.0, 0.5], [0.0, 1.0]], np.float32)
    >>> composite(base, depth, [(red, alpha, np.full((2, 2), 0.5, np.float32), True, False)])[..., 0].tolist()
    [[200, 100], [0, 200]]
    """
    # ragged nested lists raised numpy's "inhomogeneous shape" ValueError, naming no argument
    out = as_array(base, "base", "an (H, W, 3) uint8 image")
    if out.ndim != 3 or out.shape[2] != 3:
        raise InvalidInputError(f"base must be an (H, W, 3) image; got shape {out.shape}")
    if out.dtype != np.uint8:  # cast as it was, 300 came out 44 (and 100.7 100 outside the layers, 101 inside)
        raise InvalidInputError(f"base must be an (H, W, 3) uint8 image; got dtype {out.dtype}")
    if isinstance(layers, (str, bytes)) or not isinstance(layers, Sequence):
        raise InvalidInputError(f"layers must be a sequence of (color, alpha, depth, depth_test, writes_depth); got "
                                f"{type(layers).__name__}")
    if not layers:
        return out.astype(np.uint8, copy=True)
    shape = out.shape[:2]
    base_depth = as_array(base_depth, "base_depth", f"an {shape} array of depths")
    if np.shape(base_depth) != shape:
        raise InvalidInputError(f"base_depth must be {shape}; got {np.shape(base_depth)}")
    _check_depths(base_depth, "base_depth")
    full = (0, 0, shape[1], shape[0])
    boxed = []
    for i, layer in enumerate(layers):
        text = isinstance(layer, (str, bytes))
        if text or not isinstance(layer, Sequence) or len(layer) != 5:
            got = f"{len(layer)} items" if isinstance(layer, Sequence) and not text else type(layer).__name__
            raise InvalidInputError(f"layer {i} must be (color, alpha, depth, depth_test, writes_depth); got {got}")
        c, alpha, z, depth_test, writes_depth = layer
        c = as_array(c, f"layer {i} color", f"an {out.shape} image")
        alpha = as_array(alpha, f"layer {i} alpha", f"an {shape} array in [0, 1]")
        z = as_array(z, f"layer {i} depth", f"an {shape} array of depths")
        if alpha.dtype == np.bool_:  # a coverage mask (np.isfinite(depth)): 0 or 1, as it always composited
            alpha = alpha.astype(np.float32)
        if c.shape != out.shape or alpha.shape != shape or z.shape != shape:
            raise InvalidInputError(f"layer {i} must hold an {out.shape} color, {shape} alpha and depth; got "
                                    f"{c.shape}, {alpha.shape}, {z.shape}")
        # out of their ranges they were clipped or cast silently: alpha 2 doubled the colour, NaN alpha made black
        _check_range(c, f"layer {i} color", 255.0)
        _check_range(alpha, f"layer {i} alpha", 1.0)
        _check_depths(z, f"layer {i} depth")
        boxed.append((c, alpha, z, check_flag(depth_test, f"layer {i} depth_test"),
                      check_flag(writes_depth, f"layer {i} writes_depth"), full))
    return _composite_boxed(out, base_depth, boxed)


def _check_range(values: NDArray[Any], name: str, top: float) -> None:
    """An InvalidInputError naming ``name`` unless ``values`` are real numbers in [0, ``top``] (none NaN)."""
    v = real_numbers(values, name, f"real numbers in [0, {top:g}]")
    if v.size and not (np.isfinite(v).all() and v.min() >= 0.0 and v.max() <= top):
        finite = v[np.isfinite(v)]
        got = "NaN or infinite values" if finite.size < v.size else f"values from {finite.min():g} to {finite.max():g}"
        raise InvalidInputError(f"{name} must lie in [0, {top:g}]; got {got}")


def _check_depths(values: Any, name: str) -> None:
    """An InvalidInputError naming ``name`` unless ``values`` are real depths, none NaN (inf: empty)."""
    if np.isnan(real_numbers(values, name, "real depths (inf where empty)")).any():
        raise InvalidInputError(f"{name} must be real depths (inf where empty), not NaN; got NaN")


def _composite_boxed(
    base: NDArray[np.uint8],
    base_depth: NDArray[np.float32],
    layers: Sequence[tuple[NDArray[Any], NDArray[np.float32], NDArray[np.float32], bool, bool,
                           tuple[int, int, int, int]]],
) -> NDArray[np.uint8]:
    """:func:`composite` of layers that each cover only a pixel box: (color, alpha, depth, depth_test,
    writes_depth, (col0, row0, col1, row1)), the images of shape (row1 − row0, col1 − col0) (color may also
    be one (3,) color for the whole box). Outside its box a layer is empty (alpha 0). The result is
    :func:`composite` of the same layers padded to the window, bit for bit: outside every box the base
    comes back unchanged, and inside the boxes the same float32 formula runs in the same order."""
    out = np.asarray(base)
    shape = out.shape[:2]
    work: list[tuple[Any, ...]] = []
    for i, (c, alpha, z, depth_test, writes_depth, (c0, r0, c1, r1)) in enumerate(layers):
        alpha = np.asarray(alpha, dtype=np.float32)
        if not (0 <= c0 <= c1 <= shape[1] and 0 <= r0 <= r1 <= shape[0]) or alpha.shape != (r1 - r0, c1 - c0):
            raise InvalidInputError(f"layer {i}: box {(c0, r0, c1, r1)} must lie in the {shape[1]}x{shape[0]} "
                                    f"image and match its alpha; got alpha of shape {alpha.shape}")
        if alpha.size == 0:
            continue
        rows = np.flatnonzero(alpha.any(axis=1))
        if len(rows) == 0:
            continue
        cols = np.flatnonzero(alpha[rows[0]: rows[-1] + 1].any(axis=0))
        inner = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))  # where the layer has pixels
        c = np.asarray(c)
        work.append((c if c.ndim == 1 else c[inner], alpha[inner], np.asarray(z, dtype=np.float32)[inner],
                     depth_test, writes_depth, (r0 + rows[0], c0 + cols[0])))
    result = out.astype(np.uint8, copy=True)
    if not work:
        return result
    top = min(w[5][0] for w in work)
    left = min(w[5][1] for w in work)
    bottom = max(w[5][0] + w[1].shape[0] for w in work)
    right = max(w[5][1] + w[1].shape[1] for w in work)
    union = (slice(top, bottom), slice(left, right))  # float32 only where some layer has pixels
    color = out[union].astype(np.float32)
    depth = np.asarray(base_depth, dtype=np.float32)[union].copy()
    for c, alpha, z, depth_test, writes_depth, (r, col) in work:
        box = (slice(r - top, r - top + alpha.shape[0]), slice(col - left, col - left + alpha.shape[1]))
        a = alpha * (z < depth[box]) if depth_test else alpha
        target = color[box]
        # target += a·(c − target): the same float32 operations, channel by channel (NumPy's inner loops then
        # run along the rows, not over 3 channels) and in place
        step = np.empty(a.shape, np.float32)
        for ch in range(3):
            np.subtract(c[ch] if c.ndim == 1 else c[..., ch], target[..., ch], out=step, dtype=np.float32)
            step *= a
            target[..., ch] += step
        if writes_depth:
            np.copyto(depth[box], z, where=a > 0)
    np.rint(color, out=color)
    np.clip(color, 0, 255, out=color)
    result[union] = color  # float32 -> uint8 as astype(np.uint8)
    return result


# ------------------------------------------------------------------------------------------------ rendering
_LUTS: dict[tuple[str, int], NDArray[np.uint8]] = {}


def _colors_for(mesh_values: NDArray[np.float32], cmap: str, vmin: float, vmax: float) -> NDArray[np.uint8]:
    import matplotlib

    try:
        table = matplotlib.colormaps[cmap]
    except (KeyError, TypeError):  # TypeError: an unhashable value (a list, an array) as the name
        raise InvalidInputError(f"cmap must name a matplotlib colormap; got {cmap!r}") from None
    span = vmax - vmin if vmax > vmin else 1.0
    x = np.clip((mesh_values - vmin) / span, 0, 1)
    lo, hi = land_range(cmap)  # the colormap's land part (stepped.land_range: 'terrain' skips its sea blues)
    if (lo, hi) != (0.0, 1.0):
        x = lo + (hi - lo) * x
    # = (table(x)[:, :3] * 255 + 0.5).astype(uint8), entry by entry: matplotlib looks a float x up in its
    # N-entry table at int(x·N) (x·N in x's dtype, N itself mapped to N − 1, NaN to the "bad" color); the
    # table is converted to uint8 once instead of every vertex's RGBA
    key = (cmap, table.N)
    lut = _LUTS.get(key)
    if lut is None:
        entries = np.asarray(table(np.arange(table.N)))[:, :3]
        bad = np.asarray(table(np.array([np.nan])))[:, :3]
        lut = _LUTS[key] = (np.concatenate([entries, bad]) * 255 + 0.5).astype(np.uint8)
    xa = np.array(x, copy=True)
    xa *= table.N
    xa[xa == table.N] = table.N - 1
    index = np.where(np.isnan(xa), table.N, xa).astype(np.int64)
    return lut[index]


def _scalar_range(terrain: Terrain, kind: str) -> tuple[float, float]:
    if kind == "height":
        return terrain.height_range
    if kind == "aspect":
        return 0.0, 2 * math.pi
    return 0.0, math.radians(60.0)


_DEFAULT_CMAPS = {"height": "terrain", "slope": "magma", "aspect": "twilight"}


def _check_texture(image: Any, name: str, alpha: bool = False) -> NDArray[np.uint8]:
    """``image`` as a contiguous (h, w, 3) uint8 array, (h, w, 4) with ``alpha`` where some alpha is below 255."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.shape[0] < 2 or arr.shape[1] < 2:
        raise InvalidInputError(f"{name} must be an (h, w, 3|4) image of at least 2 x 2 pixels; got shape {arr.shape}")
    if arr.dtype != np.uint8:
        raise InvalidInputError(f"{name} must be uint8 (0-255); got dtype {arr.dtype}")
    if alpha and arr.shape[2] == 4 and int(arr[..., 3].min()) < 255:
        return np.ascontiguousarray(arr)
    return np.ascontiguousarray(arr[..., :3])


def _texture_rgb(terrain: Terrain, image: NDArray[np.uint8], xy: NDArray[np.float64],
                 under: NDArray[np.uint8] | None = None) -> NDArray[np.uint8]:
    """Bilinear samples of an image spread over the terrain's extent (row 0 at the upper y) at world xy. An (h, w, 4)
    image is sampled premultiplied and laid over ``under`` (V, 3) (None: the plain tan of an uncoloured mesh) by its
    alpha: its transparent texels show what lies under them.

    The image's outer pixel EDGES lie on :func:`~stepterrain.texture.terrain_extent` (a grid's node extent plus half
    a cell; a TIN's point extent), as :func:`~stepterrain.texture.terrain_layer` and
    :class:`~stepterrain.texture_lod.ImagePyramid` place an image: pixel (i, j)'s centre at x = xmin + (j + ½)·width
    / w; an image of one pixel a node puts each pixel's centre on its node. Beyond the outer pixel centres the edge
    pixels hold (clamp to edge). The first and last pixel centres sat on the corner nodes: a quarter of a cell off
    near the edges at two pixels a node, 0.85 of a cell at 0.37."""
    if terrain.kind == "grid":
        from .texture import terrain_extent

        xmin, xmax, ymin, ymax = terrain_extent(terrain)
    else:
        xmin, xmax, ymin, ymax = terrain.extent
    h, w = image.shape[:2]
    fx = np.clip((xy[:, 0] - xmin) / max(xmax - xmin, 1e-12) * w - 0.5, 0, w - 1)
    fy = np.clip((ymax - xy[:, 1]) / max(ymax - ymin, 1e-12) * h - 0.5, 0, h - 1)
    j0 = np.minimum(np.floor(fx).astype(np.int64), w - 2)
    i0 = np.minimum(np.floor(fy).astype(np.int64), h - 2)
    tx, ty = (fx - j0)[:, None], (fy - i0)[:, None]
    rgba = image.shape[2] == 4

    def texels(i: NDArray[np.int64], j: NDArray[np.int64]) -> NDArray[np.float32]:
        # the texels sampled, in float32 (the whole image was converted, and premultiplied, for every frame)
        texel = image[i, j].astype(np.float32)
        if rgba:  # premultiplied: a transparent texel's colour does not bleed into its neighbours
            texel[:, :3] *= texel[:, 3:] / 255.0
        return texel

    c00, c01, c10, c11 = texels(i0, j0), texels(i0, j0 + 1), texels(i0 + 1, j0), texels(i0 + 1, j0 + 1)
    top = c00 + tx * (c01 - c00)
    bottom = c10 + tx * (c11 - c10)
    sampled = top + ty * (bottom - top)
    if rgba:
        from .render import _DEFAULT_COLOR

        below = (np.asarray(under, np.float32) if under is not None
                 else np.float32(255.0) * np.asarray(_DEFAULT_COLOR, np.float32))
        sampled = sampled[:, :3] + (1.0 - sampled[:, 3:] / 255.0) * below
    return np.clip(np.rint(sampled), 0, 255).astype(np.uint8)


def _layer_rgb(terrain: Terrain, layer: CloseUpLayer, cu: CloseUp, overview: tuple[str | None, str, Any]
               ) -> NDArray[np.uint8] | None:
    if cu.texture is not None:
        return _texture_rgb(terrain, cu.texture, layer.original[:, :2])
    if layer.scalars is not None and cu.scalars is not None:
        lo, hi = _scalar_range(terrain, cu.scalars)
        return _colors_for(layer.scalars, cu.cmap or _DEFAULT_CMAPS[cu.scalars], lo, hi)
    if layer.colors is not None:
        return layer.colors
    scalars, cmap, texture = overview
    if texture is not None and texture.shape[2] == 3:
        return _texture_rgb(terrain, texture, layer.original[:, :2])
    colors = None
    if scalars is not None:
        values = _vertex_scalars(terrain, (layer.original - [*terrain.local_origin, 0.0]).astype(np.float32), scalars)
        lo, hi = _scalar_range(terrain, scalars)
        colors = _colors_for(values, cmap, lo, hi)
    if texture is None:
        return colors
    return _texture_rgb(terrain, texture, layer.original[:, :2], colors)  # laid over the mapping by its alpha


def _gray(rgb: tuple[float, float, float]) -> tuple[float, float, float]:
    """The inactive anchor's color (Fig. 5b): a mid gray as light as the close-up color."""
    g = float(np.clip(0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2], 0.35, 0.75))
    return (g, g, g)


def _content_faces(layer: CloseUpLayer, cu: CloseUp) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The faces drawn as the close-up's content and those drawn with its anchor (the soft edge, with ``band``)."""
    f = layer.faces
    if cu.anchor.band:  # the paper's SPFR: m = 1 is the close-up, 0 < m < 1 joins the anchor
        full = layer.mask_factor >= 1.0
        inner = full[f[:, 0]] & full[f[:, 1]] & full[f[:, 2]]
        return f[inner], f[~inner]
    # the close-up up to its outline, fully transformed; the strip is the whole anchor
    seen = layer.mask_factor >= cu.anchor.outline_level
    inner = seen[f[:, 0]] | seen[f[:, 1]] | seen[f[:, 2]]
    return f[inner], f[:0]


def _drawn_bounds(layer: CloseUpLayer, cu: CloseUp, used: NDArray[np.int64] | None = None,
                  transformed: NDArray[np.float64] | None = None) -> NDArray[np.float64] | None:
    """(2, 3) bounds of a close-up's content where it is drawn: without ``anchor.band`` its faces up to the outline
    fully transformed (M·V_O, up to a cell times the scale beyond the blended V_C of its outermost vertices), else
    (and for a billboard, drawn apart) the blended vertices V_C. ``used``: the vertices of the content faces;
    ``transformed``: M·V_O of every vertex of the layer, when known."""
    from .render import _finite_bounds

    if cu.anchor.band or cu.view == "billboard":
        return _finite_bounds(layer.vertices)
    if used is None:
        used = sorted_unique(_content_faces(layer, cu)[0])  # not np.unique: it hashes, 5-7x slower
    if len(used) == 0:
        return _finite_bounds(layer.vertices)
    if transformed is not None:
        return _finite_bounds(transformed[used])
    return _finite_bounds(layer.original[used] @ layer.matrix[:3, :3].T + layer.matrix[:3, 3])


def _content_split(t: Terrain, layer: CloseUpLayer, cu: CloseUp
                   ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`_content_faces` of a layer (content and band faces) and the vertices of its content faces, kept per
    culled layer when its arrays are the read-only ones :func:`closeup_layers` shares between frames (it does not
    depend on M)."""
    f = layer.faces

    def split() -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
        content, band = _content_faces(layer, cu)
        return content, band, sorted_unique(content)

    if not _shared_layer(layer):
        return split()
    key = ("split", id(f), id(layer.mask_factor), cu.anchor.band, cu.anchor.outline_level)
    return derived(t.cached(("closeup", "derived"), dict), key, (f, layer.mask_factor), split)


def _shared_layer(layer: CloseUpLayer) -> bool:
    """Whether a culled layer's arrays are the read-only ones :func:`closeup_layers` shares between frames (what is
    derived from them may be kept per layer); a user's writable copy may change under a memo."""
    return not (layer.faces.flags.writeable or layer.mask_factor.flags.writeable or layer.original.flags.writeable)


def _frame_geometry(t: Terrain, items: Sequence[CloseUp], layers: Sequence[CloseUpLayer],
                    strips: Sequence[AnchorStrip], scalars: str | None, cmap: str, image_texture: Any
                    ) -> tuple[dict[int, Any], dict[int, Any], dict[int, Any], dict[int, Any]]:
    """The camera-independent part of a frame: per close-up its anchor mesh (values t), its content mesh
    (rgb) or billboard, and the bounds of its content where it is drawn (:func:`_drawn_bounds`). What does not
    depend on M (which faces are content, the vertex colors) is kept per culled layer (the read-only arrays
    :func:`closeup_layers` shares between frames)."""
    anchors: dict[int, Any] = {}
    contents: dict[int, Any] = {}
    boards: dict[int, Any] = {}
    drawn: dict[int, Any] = {}
    memo = t.cached(("closeup", "derived"), dict)
    overview = (scalars, cmap, image_texture)
    for k, (cu, layer, strip) in enumerate(zip(items, layers, strips, strict=True)):
        show_anchor = cu.active or cu.anchor.inactive != "hidden"
        shared = _shared_layer(layer)
        content_faces, band_faces, used = _content_split(t, layer, cu)
        if cu.anchor.band:
            content_vertices = layer.vertices
        else:
            content_vertices = layer.original @ layer.matrix[:3, :3].T
            content_vertices += layer.matrix[:3, 3]
        drawn[k] = _drawn_bounds(layer, cu, used, content_vertices)
        if show_anchor:
            nv = len(strip.vertices)
            if len(band_faces):  # soft-edge faces: t from ‖V_C − V_O‖ normalized by the longest rung
                d = np.linalg.norm(layer.vertices - layer.original, axis=1)
                t_band = np.clip(d / strip.max_length, 0, 1) if strip.max_length > 0 else np.zeros(len(d))
                vertices = np.concatenate([strip.vertices, layer.vertices])
                faces = np.concatenate([strip.faces, band_faces + nv])
                tvals = np.concatenate([strip.distance, t_band]).astype(np.float32)
            else:
                vertices, faces, tvals = strip.vertices, strip.faces, strip.distance
            if len(faces):
                anchors[k] = (vertices, faces, {"values": tvals})
        if len(content_faces):
            if shared and cu.texture is None and image_texture is None:  # textures may change in place: not kept
                key = ("rgb", id(layer.original), id(layer.colors), id(layer.scalars), cu.scalars, cu.cmap, scalars,
                       cmap)
                rgb = derived(memo, key, (layer.original, layer.colors, layer.scalars),
                               lambda layer=layer, cu=cu: _layer_rgb(t, layer, cu, overview))
            else:
                rgb = _layer_rgb(t, layer, cu, overview)
            if cu.view == "billboard":
                top = strip.vertices[strip.rungs:: strip.rungs + 1] if len(strip.vertices) else layer.vertices
                boards[k] = (content_vertices, content_faces, rgb, top)
            else:
                contents[k] = (content_vertices, content_faces, {"rgb": rgb})
    return anchors, contents, boards, drawn


def render_closeups(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    closeups: Sequence[CloseUp] | CloseUp = (),
    *,
    window_size: tuple[int, int] = (1280, 720),
    camera: Any = "oblique",
    z_scale: float = 1.0,
    scalars: Literal["height", "slope", "aspect"] | None = "height",
    cmap: str = "terrain",
    background: Any = "white",
    texture: ArrayLike | None = None,
    time: float = 0.0,
    bounds: ArrayLike | None = None,
    renderer: Any = None,
    reuse_overview: bool = False,
    reuse_closeups: bool = True,
    merge_passes: bool = True,
    timings: dict[str, float] | None = None,
    device: wp.DeviceLike = None,
    view_angle: float = 30.0,
) -> NDArray[np.uint8]:
    """Render the overview with its close-ups: layered passes into color + depth, then compositing (§IV).

    Parameters
    ----------
    terrain : Terrain, trimesh.Trimesh or (H, W) array_like
        The overview.
    closeups : CloseUp or sequence of CloseUp
        At most :func:`max_closeups` of the window.
    window_size : (width, height)
    camera : "oblique", "top", (azimuth, elevation) or a pyvista camera position
        As in :func:`stepterrain.render.render_mesh`, fitted to ``bounds`` (default: overview, close-ups and
        anchors together); an explicit position is relative to the centre of that box, as render_mesh's to the
        centre of its ``bounds``; one that sees none of the overview, close-ups and anchors gives a warning (the image
        is the background alone), not an error as in render_mesh: a camera path may look away for a frame.
    z_scale : float
        Vertical exaggeration of the render; default 1, true proportions (the CLI's ``closeup --z-scale``
        defaults to 2).
    scalars, cmap
        The overview's data mapping: "height", "slope", "aspect" through ``cmap``, or None (uniform tan).
        Close-ups use it too unless they set their own (SPFR); stepped close-ups (MPFR) color their levels through
        ``cmap`` unless they name their own. Slope and aspect need a grid terrain (a DEM); on a TIN they raise an
        InvalidInputError. Next to nodata they use the one-sided difference; a node without a neighbour with a
        height along an axis shows in ``cmap``'s "bad" color, and so does the aspect of flat ground (no downhill
        direction).
    texture : (h, w, 3|4) uint8, optional
        An aerial image over the terrain's extent (row 0 at the upper y; its outer pixel edges on
        :func:`~stepterrain.texture.terrain_extent`, as a close-up's ``texture``) draped over the overview instead.
        Its alpha, where below 255, lays it over the overview's own mapping (``scalars`` through ``cmap``, or the
        plain tan): transparent texels (nodata, outside the image's footprint) show that mapping, not their RGB.
    time : float
        Animation time (spinning close-ups).
    renderer : stepterrain.render.LayeredRenderer, optional
        Reuse a renderer (and its uploaded overview) across frames; its window, z_scale and background must be
        ``window_size``, ``z_scale`` and ``background`` (else an InvalidInputError).
    reuse_overview : bool
        With a reused ``renderer``: keep the overview pass of the previous frame when neither the camera, the
        frame box nor the overview changed (only the close-ups move); the images are the same either way.
    reuse_closeups : bool
        Keep the transformed and culled close-ups and anchors of the previous frame on this terrain when the
        close-ups are the same objects with the same M at ``time`` (a moving camera over still close-ups:
        only the camera-dependent passes and the compositing run); the images are the same either way.
    merge_passes : bool
        Render the anchors (and the close-ups) whose screen boxes do not overlap in one pass and split the
        images by those boxes: the layers come out as from one pass each (to a gray level of rounding at a
        few pixels), with fewer passes.
    timings : dict, optional
        Filled with seconds spent in "transform", "render" and "composite".
    background : color
        The image's background (default "white"), any pyvista color as in :func:`stepterrain.render.render_mesh`.
    bounds : (2, 3) array_like, optional
        A world-space box [(xmin, ymin, zmin), (xmax, ymax, zmax)] the camera frames instead of the overview,
        close-ups and anchors together: the same box for every frame of an animation keeps the camera still.
    device : warp device, optional
        Where the close-ups (a stepped one's terraces included) and their anchors are built: amplified,
        transformed and culled (:func:`closeup_layers`, :func:`anchor_strips`; default: Warp's default device).
    view_angle : float
        The camera's vertical field of view in degrees, in [1e-8, 179], as in
        :func:`stepterrain.render.render_mesh` (default 30); a fitted camera frames the box with it.

    Returns
    -------
    (H, W, 3) uint8

    Raises
    ------
    InvalidInputError
        Too many close-ups for the window, a ROI outside the terrain or reaching it with its soft edge only (m below
        ``anchor.outline_level`` at every node under it, without ``anchor.band``: no content to draw), a camera
        fitted to the overview and close-ups (no ``bounds``) that would show the overview under a pixel (a
        close-up moved absurdly far), bad options.
    OutputTooLargeError
        The window's passes (about 64 bytes per pixel) exceed the memory budget, checked before any work.
    MissingDependencyError
        No off-screen OpenGL context.

    Notes
    -----
    Passes, in the order of generation: the overview; then per close-up its anchor (the fence strip, and with
    ``anchor.band`` the soft-edge faces with 0 < m < 1; unlit, in the close-up's color, opacity = transfer function
    of t per pixel, depth-tested against what lies below) and its content (the faces with a corner of m >=
    ``anchor.outline_level`` fully transformed, with ``anchor.band`` those with m = 1; lit, drawn over what lies
    below: of overlapping close-ups the later one in ``closeups`` is on top). A billboard close-up's content is an
    orthographic render from ``billboard_view`` pasted over the screen box of its transformed outline. With no
    close-ups the result is the overview pass itself. Anchor and content passes are read back and composited only
    inside their screen boxes (the projected corners of their bounds: no fragment falls outside), so their cost
    beyond rasterising follows their size on screen, not the window's; the images equal full-window passes and
    compositing bit for bit.
    """
    import time as _time

    from . import render

    t = as_terrain(terrain)
    items = _check_closeups(closeups)
    width, height = _window(window_size)
    render._check_render_budget(width, height, layered=True)  # before the close-ups are transformed and culled
    limit = max_closeups((width, height))
    if len(items) > limit:
        raise InvalidInputError(
            f"too many close-ups for a {width}x{height} window: {len(items)}; it holds at most {limit} "
            f"(one per {_MIN_PIXELS_PER_CLOSEUP}x{_MIN_PIXELS_PER_CLOSEUP} pixels, at most {_MAX_CLOSEUPS})")
    _check_scalars(scalars)
    _check_cmap(cmap)
    _check_in_terrain(t, items)
    _check_grid_scalars(t, scalars, items)
    # before any work: "no" is true to Python (merge_passes="no" merged), and a list for timings raised its
    # TypeError after every pass was rendered
    reuse_overview = check_flag(reuse_overview, "reuse_overview")
    reuse_closeups = check_flag(reuse_closeups, "reuse_closeups")
    merge_passes = check_flag(merge_passes, "merge_passes")
    if timings is not None and not isinstance(timings, MutableMapping):
        raise InvalidInputError(f"timings must be a dict (filled with seconds per step) or None; got "
                                f"{type(timings).__name__}")
    image_texture = None if texture is None else _check_texture(texture, "texture", alpha=True)
    box = None if bounds is None else render._check_box(bounds, "bounds")  # before any work; text was taken
    if box is not None and render._fitted_camera(camera):  # a fitted camera: not to a point
        render._check_fitted_box(box, "bounds")
    view_angle = _check_view(width, height, camera, z_scale, background, view_angle)
    if renderer is not None:  # a pyvista Plotter raised AttributeError ('size') after the close-ups were culled
        if not isinstance(renderer, render.LayeredRenderer):
            raise InvalidInputError(f"renderer must be a stepterrain.render.LayeredRenderer (or None); got "
                                    f"{type(renderer).__name__}")
        renderer._check_open()
    clock = timings if timings is not None else {}
    start = _time.perf_counter()
    pivot = _pivot_z(t)
    matrices = [cu.matrix(pivot, time=time) for cu in items]
    # per terrain, the last geometry of each set of close-ups (a few sets: e.g. scenes shown in turn); an entry
    # holds the objects it depends on weakly (as _memo.derived), and goes once one is gone: held strongly, a loop
    # over new close-ups kept the last 8 frames' close-ups, masks, uploads and culls alive
    memo = t.cached(("closeup", "frame"), dict)
    memo_key = (tuple(id(cu) for cu in items), scalars, cmap, str(resolve_device(device)), id(texture))
    # the texture held beside the close-ups (swept as they are): held apart, an entry whose texture was gone stayed
    # (a new image each frame, a video draped: 8 frames' geometry kept)
    last = recall(memo, memo_key, (*items, texture)) if reuse_closeups else MISSING
    if last is not MISSING and all(np.array_equal(a, b) for a, b in zip(last[0], matrices, strict=True)):
        layers, strips, anchors, contents, boards, drawn = last[1]
        if image_texture is not None or any(cu.texture is not None for cu in items):
            # an image may have changed in place since (the same object): its colors are sampled again
            anchors, contents, boards, drawn = _frame_geometry(t, items, layers, strips, scalars, cmap, image_texture)
    else:
        layers = closeup_layers(t, items, time=time, colors=cmap, device=device)
        _check_content(t, items, layers)
        strips = anchor_strips(t, items, time=time, device=device)
        anchors, contents, boards, drawn = _frame_geometry(t, items, layers, strips, scalars, cmap, image_texture)
        keep(memo, memo_key, (*items, texture), (matrices, (layers, strips, anchors, contents, boards, drawn)),
             limit=8)
    clock["transform"] = _time.perf_counter() - start

    start = _time.perf_counter()
    own = renderer is None
    if own:
        renderer = render.LayeredRenderer(window_size=(width, height), background=background, z_scale=z_scale)
    else:  # the renderer's window and scale are the image's: others asked for were silently not given
        if tuple(renderer.size) != (width, height):
            raise InvalidInputError(f"window_size {width}x{height} differs from the renderer's window "
                                    f"{renderer.size[0]}x{renderer.size[1]}; give the renderer's size")
        if render._check_window((width, height), z_scale)[2] != renderer.z_scale:
            raise InvalidInputError(f"z_scale {z_scale!r} differs from the renderer's z_scale {renderer.z_scale!r}")
        render._check_background(renderer._pv, background)
        if renderer._pv.Color(background) != renderer._pv.Color(renderer.background):
            raise InvalidInputError(f"background {background!r} differs from the renderer's background "
                                    f"{renderer.background!r}")
    try:
        # an image's content, not only its identity: a texture edited in place is drawn anew on a reused renderer.
        # A read-only one (a caller's promise, as render._frozen takes it) is known by its identity, without hashing
        # its pixels every frame (22 MB for a 3840 x 1920 image)
        texture_key = None
        if image_texture is not None:
            texture_key = (Same(texture), image_texture.shape,
                           None if render._frozen(texture) else hashlib.blake2b(image_texture).hexdigest())
        # the terrain and texture themselves, not their ids: the renderer keeps the key after the call, and a
        # terrain made from a raw array for the next call got the freed one's id and was drawn as the old overview
        overview_key = ("overview", Same(t), scalars, cmap, texture_key)
        if not renderer.has("overview", overview_key):
            mesh = t.mesh()
            rgb = _overview_rgb(t, mesh, scalars, cmap, image_texture)
            renderer.set_mesh("overview", mesh.vertices, mesh.faces, rgb=rgb, key=overview_key)
        fitted = box is None and render._fitted_camera(camera)
        if box is None:
            boxes = [renderer.bounds_of("overview")]
            for k, strip in enumerate(strips):  # the close-ups where they are drawn (not their blended V_C)
                boxes += [b for b in (drawn[k], render._finite_bounds(strip.vertices)) if b is not None]
            box = np.array([np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)])
        if fitted and items:  # before set_view: its own check of a box too thin to see named "the mesh" and a
            # z_scale for a close-up lifted absurdly high (animate_closeups named the close-up, checking it first)
            _check_framed(t, items, drawn, box, camera, (width, height), renderer.z_scale, view_angle)
        renderer.set_view(camera, box, view_angle=view_angle)
        if not render._fitted_camera(camera):
            _warn_unseen(renderer, camera, drawn, strips)
        base, base_depth = renderer.render(["overview"], reuse=reuse_overview)
        # each layer comes back cut to its screen box: read-backs and compositing follow its size on screen
        anchor_images = renderer.render_layers("anchor", anchors, merge=merge_passes, crop=True)
        content_images = renderer.render_layers("closeup", contents, merge=merge_passes, crop=True)
        passes = []
        for k, cu in enumerate(items):  # compositing in the order of generation: anchor k, then close-up k
            if k in anchor_images:
                tex, z, rect = anchor_images[k]
                color = _closeup_color(cu, k)
                anchor_color = _gray(color) if (not cu.active and cu.anchor.inactive == "gray") else color
                # the transfer function per pixel at its t (a gray level: one table entry per level, the same
                # np.interp values as per pixel), 0 where the anchor has no fragment
                levels = np.interp(np.arange(256) / 255.0, np.linspace(0, 1, len(cu.anchor.table)),
                                   cu.anchor.table).astype(np.float32)
                alpha = np.where(z < np.inf, levels[tex[..., 0]], np.float32(0))
                if not cu.active and cu.anchor.inactive == "faint":
                    alpha *= 0.25
                passes.append((np.asarray(anchor_color, np.float32) * 255, alpha, z, True, False, rect))
            if k in boards:  # a spinning one sized by what turning keeps (its cylinder about the spin axis)
                axis = None if cu.spin is None else np.add(cu.roi.center, cu.offset[:2])
                image, coverage, z = renderer.render_billboard(*boards[k][:3], cu.billboard_view, boards[k][3],
                                                               axis=axis)
                passes.append((image, coverage.astype(np.float32), z, False, True, (0, 0, width, height)))
            elif k in content_images:
                image, z, rect = content_images[k]
                passes.append((image, (z < np.inf).astype(np.float32), z, False, True, rect))
        clock["render"] = _time.perf_counter() - start
        start = _time.perf_counter()
        result = _composite_boxed(base, base_depth, passes) if passes else base.copy()
        clock["composite"] = _time.perf_counter() - start
        return result
    finally:
        if own:
            renderer.close()


def _check_view(width: int, height: int, camera: Any, z_scale: Any, background: Any, view_angle: Any) -> float:
    """The render's ``view_angle`` (degrees), once ``camera``, ``z_scale``, ``background`` and ``view_angle`` are
    checked as the renderer and its :meth:`~stepterrain.render.LayeredRenderer.set_view` check them, else their
    InvalidInputError: those came after the close-ups and anchors were transformed and culled (and in
    :func:`animate_closeups` after the box was fitted over every turn of the spin)."""
    from . import render

    view_angle = render._check_view_angle(view_angle)
    render._check_window((width, height), z_scale)
    render._check_background(render._import_pyvista(), background)
    # a name, angles or a position: refused as set_view refuses them (the box it frames comes later)
    render._camera_position(camera, np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), width / height, view_angle)
    return view_angle


def _warn_unseen(renderer: Any, camera: Any, drawn: dict[int, Any], strips: Sequence[AnchorStrip]) -> None:
    """A warning when the explicit ``camera`` position set on ``renderer`` sees none of the overview, the close-ups
    (``drawn``: their bounds where drawn) and their anchors: the image is the background alone. It came back so
    without a word (render_mesh refuses such a camera); a warning, not an error, as a camera path (a fly-through,
    frame by frame on one renderer) may look away for a frame. The message names no frame: Python shows it once
    per camera."""
    from .render import _finite_bounds

    parts = [renderer.bounds_of("overview")] + [b for b in drawn.values() if b is not None]
    parts += [b for b in (_finite_bounds(strip.vertices) for strip in strips) if b is not None]
    if all(renderer._misses(b) for b in parts):
        warnings.warn(f"camera [(eye), (focal point), (view up)] sees none of the overview, its close-ups and "
                      f"anchors: the image is the background alone (the position is taken relative to the centre of "
                      f"the framed box, z times z_scale); got {camera!r}", stacklevel=caller_stacklevel())


def _check_framed(t: Terrain, items: Sequence[CloseUp], drawn: dict[int, Any], box: NDArray[np.float64],
                  camera: Any, size: tuple[int, int], z_scale: float, view_angle: float) -> None:
    """An InvalidInputError when the fitted ``camera`` (a name or angles) framing ``box``, the overview and its
    close-ups together, shows the overview as under a pixel both ways: a close-up moved absurdly far (offset 1e7 m
    from an 80 m terrain) widened the box until the overview and the close-up both came out under a pixel, and the
    image was blank without a word (the fitted camera's own check looks at the whole box, which is wide enough). As
    that check refuses a box too thin to see, this refuses a frame that loses the terrain; the close-up contents
    (``drawn``: their bounds where drawn) under a pixel are named with it, and the close-up that reaches farthest
    with its offset, or with its scale where its own size (scale 1e6), not its offset, takes it that far. A tiny
    close-up over a visible overview (scale 1e-3) is the caller's choice and drawn as before; with ``bounds`` (or an
    explicit camera position) the framing is the caller's, and what falls outside it or under a pixel is not drawn,
    as before. Sizes are those of the parts' bounding boxes, an upper bound of what they cover."""
    from .render import _box_corners, _camera_position, _pixel_extent

    xmin, xmax, ymin, ymax = t.extent
    zmin, zmax = t.height_range
    overview = np.array([[xmin, ymin, zmin], [xmax, ymax, zmax]])
    origin = np.asarray(box, np.float64).mean(axis=0)

    def local(bounds: Any) -> NDArray[np.float64]:  # as LayeredRenderer.set_view: relative, z scaled
        corners = _box_corners(np.asarray(bounds, np.float64) - origin)
        corners[:, 2] *= z_scale
        return corners

    position = _camera_position(camera, local(box), size[0] / size[1], view_angle)
    small = []
    parts = [("the overview", overview)] + [(f"closeups[{k}]'s content", drawn[k]) for k in range(len(items))
                                             if drawn.get(k) is not None]
    for name, bounds in parts:
        extent = max(_pixel_extent(local(bounds), position, size, view_angle))
        if extent < 1.0:
            small.append(f"{name} ({extent:.2g} px)")
    if not small or not small[0].startswith("the overview"):
        return
    centre = overview.mean(axis=0)
    reach = [0.0 if drawn.get(k) is None else float(np.abs(np.asarray(drawn[k]) - centre).max())
             for k in range(len(items))]
    far = int(np.argmax(reach))
    lo, hi = box
    framed = (f"the camera fitted to the overview and its close-ups would show {' and '.join(small)} under a pixel: "
              f"the framed box x [{lo[0]:.6g}, {hi[0]:.6g}], y [{lo[1]:.6g}, {hi[1]:.6g}], z [{lo[2]:.6g}, "
              f"{hi[2]:.6g}] is that large because closeups[{far}]")
    if float(np.abs(items[far].offset).max()) < reach[far] / 2:
        # its own size, not where it was moved, reaches that far: a scale of 1e6 with a small offset was told to
        # "move it nearer" (the CLI: "give it a smaller --offset", of the offset it was given)
        content = np.asarray(drawn[far], np.float64)
        across = float((content[1] - content[0]).max())
        raise InvalidInputError(f"{framed} (scale {tuple(float(v) for v in items[far].scale)}) is drawn "
                                f"{across:.3g} across, reaching {reach[far]:.3g} from the terrain's centre; scale it "
                                "down, or frame what to see with bounds")
    raise InvalidInputError(
        f"{framed} (offset {tuple(float(v) for v in items[far].offset)}) is drawn {reach[far]:.3g} from the "
        "terrain's centre; move it nearer, or frame what to see with bounds")


def _check_scalars(scalars: Any, name: str = "scalars") -> None:
    if not is_name(scalars, (None, "height", "slope", "aspect")):
        raise InvalidInputError(f"{name} must be None, 'height', 'slope' or 'aspect'; got {scalars!r}")


def _check_cmap(cmap: Any) -> None:
    """The overview's (and the stepped close-ups') colormap, named as ``cmap``; closeup_layers named it "colors"."""
    from .stepped import colormap

    colormap(cmap, argument="cmap")


def _check_grid_scalars(terrain: Terrain, scalars: str | None, items: Sequence[CloseUp]) -> None:
    """Slope and aspect come from a grid's gradient: on a TIN they were its heights (one color), silently."""
    if terrain.kind == "grid":
        return
    named = [("scalars", scalars), *((f"closeups[{i}].scalars", cu.scalars) for i, cu in enumerate(items))]
    for name, kind in named:
        if kind in ("slope", "aspect"):
            raise InvalidInputError(f"{name}={kind!r} needs a grid terrain (a DEM), whose gradient gives it; got a "
                                    "TIN (use 'height' or None)")


def _window(window_size: Any) -> tuple[int, int]:
    """(width, height) checked as every render checks it (:func:`stepterrain.render._check_window`)."""
    from .render import _check_window

    width, height, _ = _check_window(window_size, 1.0)
    return width, height


def closeup_scene(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    closeups: Sequence[CloseUp] | CloseUp,
    *,
    scalars: Literal["height", "slope", "aspect"] | None = "height",
    cmap: str = "terrain",
    time: float = 0.0,
    device: wp.DeviceLike = None,
) -> trimesh.Trimesh:
    """Overview, close-ups and anchors as one colored mesh for export (GLB, PLY, ...).

    The close-ups are their culled layers as the kernels emit them (the soft edge stretched by C, so each
    close-up hangs from its ROI as one connected surface); anchors carry their color and, in the alpha of
    their vertex colors, the transfer function's opacity; an inactive close-up's anchor is depicted as
    ``anchor.inactive`` says, as :func:`render_closeups` draws it (left out, gray, or a quarter of the opacity).
    ``face_attributes["layer"]``: 0 for the overview, 2k + 1 for close-up k, 2k + 2 for its anchor. ``scalars`` and
    ``cmap`` map the overview and the close-ups as in :func:`render_closeups` (stepped close-ups included).
    ``metadata`` holds the number of close-ups, the terrain's source and, where it has one, its CRS.

    Examples
    --------
    >>> import numpy as np
    >>> cu = CloseUp(ROI.circle((5.0, 5.0), 3.0), offset=(0.0, 0.0, 10.0))
    >>> scene = closeup_scene(np.zeros((11, 11), np.float32), [cu], device="cpu")
    >>> sorted(set(scene.face_attributes["layer"].tolist()))
    [0, 1, 2]
    """
    _check_scalars(scalars)
    _check_cmap(cmap)
    t = as_terrain(terrain)
    items = _check_closeups(closeups)
    _check_grid_scalars(t, scalars, items)
    mesh = t.mesh()
    overview_rgb = _overview_rgb(t, mesh, scalars, cmap, None)
    parts = [(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64),
              _rgba(overview_rgb, len(mesh.vertices), _color("#dcd1bd", "color")), 0)]
    layers = closeup_layers(t, items, time=time, colors=cmap, device=device)
    _check_content(t, items, layers)
    strips = anchor_strips(t, items, time=time, device=device)
    for k, (cu, layer, strip) in enumerate(zip(items, layers, strips, strict=True)):
        rgb = _layer_rgb(t, layer, cu, (scalars, cmap, None))
        parts.append((layer.vertices, layer.faces, _rgba(rgb, len(layer.vertices), _closeup_color(cu, k)), 2 * k + 1))
        if not cu.active and cu.anchor.inactive == "hidden":  # an inactive close-up's anchor as the render draws it
            continue  # (Fig. 5): hidden, gray or faint; the scene had every anchor as an active one's
        gray = not cu.active and cu.anchor.inactive == "gray"
        rgba = _rgba(None, len(strip.vertices), _gray(strip.color) if gray else strip.color)
        opacity = strip.opacity * (0.25 if not cu.active and cu.anchor.inactive == "faint" else 1.0)
        rgba[:, 3] = np.clip(np.rint(opacity * 255), 0, 255).astype(np.uint8)
        parts.append((strip.vertices, strip.faces, rgba, 2 * k + 2))
    parts = [p for p in parts if len(p[1])]
    starts = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    vertices = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([p[1] + s for p, s in zip(parts, starts, strict=True)])
    colors = np.concatenate([p[2] for p in parts])
    layer_ids = np.concatenate([np.full(len(p[1]), p[3], np.int32) for p in parts])
    return trimesh.Trimesh(vertices, faces, process=False, vertex_colors=colors,
                           face_attributes={"layer": layer_ids},
                           metadata={"closeups": len(items), "source": t.source or "array",
                                     **({"crs": t.crs} if t.crs else {})})


def _rgba(rgb: NDArray[np.uint8] | None, n: int, fallback: tuple[float, float, float]) -> NDArray[np.uint8]:
    out = np.empty((n, 4), np.uint8)
    out[:, :3] = rgb[:, :3] if rgb is not None else np.rint(np.asarray(fallback) * 255).astype(np.uint8)
    out[:, 3] = 255
    return out


def animate_closeups(
    terrain: Terrain | trimesh.Trimesh | ArrayLike,
    closeups: Sequence[CloseUp] | CloseUp,
    *,
    frames: int = 24,
    fps: float = 12.0,
    window_size: tuple[int, int] = (640, 400),
    device: wp.DeviceLike = None,
    progress: bool = False,
    **options: Any,
) -> list[NDArray[np.uint8]]:
    """Frames of the spinning close-ups (§III.B): frame i at time i / fps, one renderer and camera for all.

    The camera frames the overview, every close-up and its anchor at every frame's turn (the box swept by the spin;
    each part bounded as :func:`render_closeups` bounds it), so the view stays still while the close-ups rotate, and
    a close-up that does not spin comes out as render_closeups draws it. ``options`` go to :func:`render_closeups`
    (``z_scale``, ``scalars``, ``cmap``, ``camera``, ``bounds``, ...), all but those set per frame here: ``time``,
    ``renderer`` and ``reuse_overview``. ``window_size`` defaults to 640 x 400 (the CLI's ``closeup --size``:
    1280 x 720, as :func:`render_closeups`'). ``progress``: a tqdm bar of the frames on stderr. Every frame is kept
    (frames x width x height x 3 bytes, checked against :func:`stepterrain.set_memory_budget` before the first, as
    is the renderer's window).
    """
    from . import render

    for name in ("time", "renderer", "reuse_overview"):  # render_closeups' TypeError named neither the cause nor us
        if name in options:
            raise InvalidInputError(f"animate_closeups sets {name} for each frame itself (frame i at time i / fps, "
                                    f"one renderer); got {name}={options[name]!r}")
    # render_closeups' TypeError for an option it does not take came at the first frame, after the box was fitted
    takes = inspect.signature(render_closeups).parameters
    for name in options:
        if name not in takes:
            raise InvalidInputError(f"animate_closeups passes options to render_closeups, which takes no {name!r}; "
                                    f"got {name}={options[name]!r:.80}")
    t = as_terrain(terrain)
    items = _check_closeups(closeups)
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
        raise InvalidInputError(f"frames must be a positive int; got {plain_repr(frames)}")
    fps = finite_number(fps, "fps", positive=True)
    width, height = _window(window_size)
    check_budget(int(frames) * width * height * 3, f"{int(frames)} frames of {width} x {height} pixels",
                 hint="render fewer or smaller frames")  # every frame is kept: refused before the first render
    render._check_render_budget(width, height, layered=True)
    if not math.isfinite((int(frames) - 1) / fps):  # a subnormal fps: frame times overflowed (RuntimeWarnings), NaN
        raise InvalidInputError(f"fps must be large enough that frame {int(frames) - 1}'s time (frame / fps seconds) "
                                f"is finite; got {fps:g}")
    times = np.arange(frames) / fps
    # render_closeups' checks of the frames' options, before the close-ups are transformed for every turn of the spin
    # below: they came at the first frame, after that work
    _check_scalars(options.get("scalars", "height"))
    _check_cmap(options.get("cmap", "terrain"))
    if options.get("texture") is not None:
        _check_texture(options["texture"], "texture", alpha=True)
    _check_view(width, height, options.get("camera", "oblique"), options.get("z_scale", 1.0),
                options.get("background", "white"), options.get("view_angle", render._VIEW_ANGLE))
    box = options.pop("bounds", None)
    camera = options.get("camera", "oblique")
    first_drawn: dict[int, Any] | None = None  # frame 0's close-ups where drawn, when the box is fitted here
    if box is None:  # the box swept by the close-ups, at every frame's turns (9 evenly spaced times could all fall on
        boxes = []  # the same phase of a spin and miss the turned close-up), and the terrain
        turns = np.array([[cu.turn(float(time)) for cu in items] for time in times]).reshape(len(times), -1)
        _, first = np.unique(turns, axis=0, return_index=True)  # frames with the same turns: the same geometry
        for time in times[np.sort(first)]:
            layers = closeup_layers(t, items, time=float(time), colors=options.get("cmap", "terrain"),
                                    device=device)  # the stepped sources the frames use, kept for them
            drawn = {}
            # and the anchors, as render_closeups frames them: left out, the fence above a band's or a billboard's
            # blended vertices (its top at M·V_O of the outline, beyond them) stood past the box, and a still
            # close-up's animation was framed otherwise than its render_closeups picture
            strips = anchor_strips(t, items, time=float(time), device=device)
            for k, (cu, layer, strip) in enumerate(zip(items, layers, strips, strict=True)):
                # where the close-up is drawn, as render_closeups frames it (its face split kept for the frames)
                used = None if cu.anchor.band or cu.view == "billboard" else _content_split(t, layer, cu)[2]
                bounds = drawn[k] = _drawn_bounds(layer, cu, used)
                boxes += [b for b in (bounds, render._finite_bounds(strip.vertices)) if b is not None]
            if first_drawn is None:  # times[0] = 0 comes first
                first_drawn = drawn
        # the overview as render_closeups frames it, by its mesh's bounds: the extent held a DEM's nodata rim, and the
        # animation was framed wider than the still render of the same close-ups
        boxes.append(t.cached(("closeup", "overview-bounds"),
                              lambda: render._finite_bounds(np.asarray(t.mesh().vertices, np.float64))))
        box = np.array([np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)])
    if first_drawn is not None and render._fitted_camera(camera) and items:
        # the box fitted here, checked as render_closeups checks its own, before any frame
        z_scale = render._check_window((width, height), options.get("z_scale", 1.0))[2]
        view_angle = render._check_view_angle(options.get("view_angle", render._VIEW_ANGLE))
        _check_framed(t, items, first_drawn, box, camera, (width, height), z_scale, view_angle)
    renderer = render.LayeredRenderer(window_size=(width, height), background=options.get("background", "white"),
                                      z_scale=options.get("z_scale", 1.0))  # render_closeups checks it is this one
    steps: Any = times
    if check_flag(progress, "progress"):  # a long animation (thousands of frames) ran for minutes without a word
        from tqdm.auto import tqdm

        steps = tqdm(times, desc="close-up frames", unit="frame")
    try:
        return [render_closeups(t, items, window_size=window_size, time=float(time), bounds=box, renderer=renderer,
                                reuse_overview=True,
                                device=device, **options) for time in steps]
    finally:
        renderer.close()


def _check_frames(frames: Any) -> list[NDArray[np.uint8]]:
    """``frames`` as (H, W, 3) or (H, W, 4) uint8 images of one size, as given (contiguous): a float or 2-D frame
    would be cast or cut silently. :func:`_animation_frames` decides what becomes of an alpha channel."""
    if isinstance(frames, np.ndarray) and frames.ndim == 4:
        frames = list(frames)
    if not isinstance(frames, Sequence) or isinstance(frames, (str, bytes)):
        raise InvalidInputError(f"frames must be a sequence of (H, W, 3|4) uint8 images; got {type(frames).__name__}")
    if len(frames) == 0:
        raise InvalidInputError("no frames to write")
    stack = []
    for k, frame in enumerate(frames):
        array = frame if isinstance(frame, np.ndarray) else None
        if array is None or array.dtype != np.uint8 or array.ndim != 3 or array.shape[2] not in (3, 4) \
                or min(array.shape[:2]) < 1:
            got = (f"{type(frame).__name__}" if array is None
                   else f"shape {array.shape}, dtype {array.dtype}")
            raise InvalidInputError(f"frames[{k}] must be an (H, W, 3|4) uint8 image (as render_closeups returns); "
                                    f"got {got}")
        if stack and array.shape[:2] != stack[0].shape[:2]:
            raise InvalidInputError(f"frames must share one size; frames[0] is {stack[0].shape[:2]}, frames[{k}] "
                                    f"{array.shape[:2]}")
        stack.append(np.ascontiguousarray(array))
    return stack


def _animation_frames(stack: list[NDArray[np.uint8]], suffix: str) -> tuple[list[NDArray[np.uint8]], list[str]]:
    """The frames as the format of ``suffix`` stores them, and what was lost on the way (warnings to give). The alpha
    of RGBA frames was dropped without a word: a transparent background was written opaque, in whatever colour its
    hidden pixels held. Frames all opaque (no alpha, or alpha 255 everywhere) are RGB, the file the same as of their
    RGB. Otherwise a GIF keeps 1-bit transparency: alpha below 128 is transparent (its colour, hidden, set to black
    so frames alike look alike), 128 and above opaque, with a warning when some alpha lay between 0 and 255; an MP4
    (H.264) holds no transparency: the alpha is dropped, with a warning."""
    clear = sum(f.shape[2] == 4 and not bool((f[..., 3] == 255).all()) for f in stack)
    if not clear:
        return [f if f.shape[2] == 3 else np.ascontiguousarray(f[..., :3]) for f in stack], []
    if suffix == ".mp4":
        return [np.ascontiguousarray(f[..., :3]) for f in stack], [
            f"an MP4 (H.264) holds no transparency: the alpha of {counted(clear, 'frame')} (below 255 in places) is "
            "dropped, their pixels drawn opaque in their RGB colours; save a GIF to keep 1-bit transparency, or "
            "composite the frames over a background first"]
    frames, partial = [], 0
    for frame in stack:
        rgba = np.empty((*frame.shape[:2], 4), np.uint8)
        rgba[..., :3] = frame[..., :3]
        if frame.shape[2] == 3:
            rgba[..., 3] = 255
        else:
            alpha = frame[..., 3]
            partial += int(np.count_nonzero((alpha > 0) & (alpha < 255)))
            hidden = alpha < 128
            rgba[..., 3] = np.where(hidden, 0, 255)
            rgba[hidden, :3] = 0
        frames.append(rgba)
    notes = [f"a GIF stores 1-bit transparency: {counted(partial, 'pixel')} of partial alpha (between 0 and 255) "
             "made transparent (alpha below 128) or opaque (128 and above)"] if partial else []
    return frames, notes


def _browser_slow_frames(frames: Sequence[NDArray[np.uint8]], fps: float) -> int:
    """How many frames of the GIF :func:`_write_gif` writes last 1 hundredth of a second (runs of identical frames,
    one GIF frame, merged first): browsers play such a delay as 10 hundredths."""
    delays = _gif_delays(len(frames), fps)
    if len(frames) < 2 or min(delays) > 1:  # a still, or fps <= 50: no frame can be that short
        return 0
    count, run = 0, delays[0]
    for k in range(1, len(frames)):
        if np.array_equal(frames[k], frames[k - 1]):
            run += delays[k]
        else:
            count, run = count + (run < 2), delays[k]
    return count + (run < 2)


#: Frame rates each animation format stores: a GIF's frame delay is a whole number of hundredths of a second, 1 to
#: 65535 (frame k starts at k / fps, rounded to hundredths: :func:`_gif_delays`); ffmpeg wrote an MP4 below about
#: 1e-4 fps as a broken file without an error
_GIF_DELAYS = (1, 65535)
_MP4_FPS = (1e-3, 1e3)


def _check_fps(fps: Any, suffix: str, name: str = "fps") -> float:
    """``fps`` as a float when the animation format of ``suffix`` (".gif" or ".mp4") can store that frame rate, else
    an InvalidInputError naming ``name``: Pillow raised an OverflowError for a GIF delay past 655.35 s and wrote 0
    (a player's default rate) for more than 100 fps; ffmpeg left a broken MP4 below 1e-4 fps."""
    fps = finite_number(fps, name, positive=True)
    if suffix == ".gif":
        lo, hi = _GIF_DELAYS
        delay = 100.0 / fps  # inf for a subnormal fps: int() raised OverflowError
        if not (math.isfinite(delay) and lo <= int(delay) <= hi):
            raise InvalidInputError(f"{name} must lie in [{100.0 / hi:.4g}, {100.0 / lo:g}] frames per second for a "
                                    f"GIF (its frame delays are whole hundredths of a second, {lo} to {hi}); got "
                                    f"{fps:g}")
    elif not _MP4_FPS[0] <= fps <= _MP4_FPS[1]:
        raise InvalidInputError(f"{name} must lie in [{_MP4_FPS[0]:g}, {_MP4_FPS[1]:g}] frames per second for an MP4; "
                                f"got {fps:g}")
    return fps


def save_animation(frames: Sequence[NDArray[np.uint8]], path: str | os.PathLike[str], *, fps: float = 12.0,
                   palette: Literal["shared", "per-frame"] = "shared") -> Path:
    """Write frames, (H, W, 3) or (H, W, 4) uint8, as a looping GIF (through Pillow) or an MP4 (through imageio's
    ffmpeg), by extension, atomically.

    ``fps`` must be a rate the format stores: [0.001526, 100] for a GIF (frame delays in whole hundredths of a
    second), [0.001, 1000] for an MP4. An MP4 keeps the frame size, which must be even both ways (H.264); a GIF
    takes any size up to 65535 pixels each way. A GIF's frame k starts at k / fps rounded to the nearest hundredth
    of a second, and identical consecutive frames are one GIF frame as long as all of them (refused past a GIF
    delay's 655.35 s). Browsers (Chrome, Firefox, Safari) play a GIF delay of 1 hundredth as 10: above 50 fps some
    frames are that short, and a warning says the GIF plays slower there (50 fps or less, or an MP4, plays at its
    speed everywhere).

    Transparency: a GIF keeps it, 1-bit: where an RGBA frame's alpha is below 128 the frame is transparent (each
    frame replaces the last: disposal 2), elsewhere opaque; alpha between 0 and 255 is rounded so, with a warning.
    An MP4 (H.264) holds none: RGBA frames with alpha below 255 are written as their RGB, with a warning. Frames
    all opaque write as their RGB, without one. (imageio's ``imread(gif, index=None)`` cannot stack the frames of a
    GIF with transparency, reading the first as RGB and the rest as RGBA: read them one by one, or with Pillow.)

    Colours: a GIF holds at most 256 colours a frame. ``palette="shared"`` (the default) gives the opaque frames of a
    GIF one palette (:func:`_shared_palette`: their own colours when they have 256 or fewer between them, else
    Pillow's octree fitted to all of them, undithered), so what stays still from frame to frame keeps its colours
    and is coded once; ``"per-frame"`` fits each frame a palette of its own (Pillow's), which suits frames whose
    colours change entirely. Frames with transparency always take their own. Each frame with its own palette, the
    24 frames of docs/closeup_spin.gif took 423 kB and the 48 of docs/dynamic_peaks.gif 472 kB (the still terrain
    coded anew in every frame); one palette shrinks them to a fraction, within a few levels of full colour."""
    from .export import atomic_path

    if palette not in ("shared", "per-frame"):
        raise InvalidInputError(f"palette must be 'shared' or 'per-frame'; got {palette!r}")
    target, suffix, fps, stack, notes = _check_animation(frames, path, fps)
    if suffix == ".gif" and (short := _browser_slow_frames(stack, fps)):
        notes.append(f"fps {fps:g}: {counted(short, 'GIF frame')} of the animation {'lasts' if short == 1 else 'last'} "
                     "1 hundredth of a second, which browsers (Chrome, Firefox, Safari) play as 10 hundredths: it "
                     "plays slower there than asked; an fps of 50 or less (or an MP4) plays at its speed everywhere")
    for note in notes:
        warnings.warn(f"save_animation: {note}", stacklevel=caller_stacklevel())
    import imageio.v3 as iio

    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError as exc:
            raise MissingDependencyError("MP4 output needs imageio-ffmpeg: pip install 'stepterrain[video]'") from exc
    with atomic_path(target) as tmp:
        try:
            if suffix == ".gif":
                _write_gif(stack, tmp, fps, shared=palette == "shared")
            else:
                iio.imwrite(tmp, np.stack(stack), extension=".mp4", plugin="FFMPEG", fps=fps, codec="libx264",
                            macro_block_size=2,  # keep the frame size (H.264 needs it even only)
                            output_params=["-f", "mp4"])  # the .tmp suffix would not tell ffmpeg the container
                unfinished = _unfinished_mp4(tmp)
                if unfinished is not None:
                    raise DataFileError(f"cannot write {str(target)!r}: ffmpeg did not finish the MP4 ({unfinished}; "
                                        f"a full disk? ffmpeg's messages above say why)")
        except OSError as exc:
            if isinstance(exc, DataFileError):
                raise
            raise DataFileError(f"cannot write {str(target)!r}: {exc.strerror or exc}") from exc
    return target


def _check_animation(
    frames: Any, path: Any, fps: Any
) -> tuple[Path, str, float, list[NDArray[np.uint8]], list[str]]:
    """Every check :func:`save_animation` makes before it writes: the target path, its suffix (".gif" or ".mp4"), the
    fps as a float, the frames as the format stores them and what they lose on the way (:func:`_animation_frames`),
    else an InvalidInputError. A caller writing other files
    with the animation (the CLI's ``closeup``: a mesh, a PNG) runs it first: a GIF refused for its runs of identical
    frames left the other files written (the old ones replaced), though the run failed."""
    from .export import _target

    target = _target(path)  # 5 or b"x.gif" raised pathlib's TypeError
    suffix = target.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise InvalidInputError(f"animation path must end in .gif or .mp4; got {str(path)!r}")
    fps = _check_fps(fps, suffix)
    stack, notes = _animation_frames(_check_frames(frames), suffix)
    if suffix == ".mp4":
        _check_mp4_size(stack[0].shape[1], stack[0].shape[0], "frames")
    else:
        _check_gif_size(stack[0].shape[1], stack[0].shape[0], "frames")
        _check_gif_runs(stack, fps)
    return target, suffix, fps, stack, notes


def _check_mp4_size(width: int, height: int, name: str) -> None:
    """An InvalidInputError unless an MP4's frames have an even width and height: H.264 in 4:2:0 colour (what players
    take) codes whole 2 x 2 blocks, and imageio resized a 321 x 241 frame to 322 x 242 (every frame stretched, the
    video not the size asked for) with only a printed warning."""
    if width % 2 or height % 2:
        raise InvalidInputError(f"{name} of an MP4 must have an even width and height (H.264 codes 2 x 2 colour "
                                f"blocks; a GIF takes any size up to 65535); got {width}x{height}")


def _check_gif_size(width: int, height: int, name: str) -> None:
    """An InvalidInputError unless a GIF stores frames of this size: its width and height are 16-bit numbers (at most
    65535); Pillow raised a bare OverflowError for a wider or taller frame (which :func:`_write_gif`'s backstop for
    merged delays would have reported as an fps too slow)."""
    top = _GIF_DELAYS[1]  # a GIF's 16-bit fields: its delays and its sizes
    if width > top or height > top:
        raise InvalidInputError(f"{name} of a GIF must be at most {top} pixels each way (its sizes are 16-bit "
                                f"numbers); got {width}x{height}")


def _packed(frame: NDArray[np.uint8]) -> NDArray[np.uint32]:
    """Each pixel's RGB as one 24-bit number."""
    rgb = frame.astype(np.uint32)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]


def _shared_palette(frames: Sequence[NDArray[np.uint8]]) -> list[Any]:
    """The RGB ``frames`` as Pillow "P" images in one palette: their own colours, exactly, when they have 256 or fewer
    between them (frames already in one palette keep it), else Pillow's fast octree fitted to every other pixel of
    every other row of every frame, each pixel its nearest colour, undithered (dithering speckles the still parts
    differently in each frame)."""
    from PIL import Image

    seen: NDArray[np.uint32] = np.empty(0, np.uint32)
    for frame in frames:  # the colours until there are too many for a palette
        seen = np.union1d(seen, _packed(frame))
        if len(seen) > 256:
            sample = np.concatenate([f[::2, ::2] for f in frames], axis=0)
            palette = Image.fromarray(np.ascontiguousarray(sample)).quantize(256, method=Image.Quantize.FASTOCTREE)
            return [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    rgb = np.stack([(seen >> 16) & 255, (seen >> 8) & 255, seen & 255], axis=1).astype(np.uint8)
    pictures = []
    for frame in frames:  # Pillow's quantize(palette=) finds a near colour, not always the same one
        index = np.searchsorted(seen, _packed(frame)).astype(np.uint8)
        picture = Image.frombytes("P", (index.shape[1], index.shape[0]), index.tobytes())
        picture.putpalette(rgb.tobytes())
        pictures.append(picture)
    return pictures


def _write_gif(frames: Sequence[NDArray[np.uint8]], tmp: Path, fps: float, shared: bool = False) -> None:
    """The frames as a looping GIF at ``tmp``, written by Pillow, each frame's delay rounded so that frame k starts at
    k / fps (:func:`_gif_delays`; imageio's pillow plugin gave every frame int(100 / fps) hundredths). Through
    imageio a failed write (a full disk) kept the plugin's frames queued: its ``__del__`` wrote them once more and
    printed a second traceback ("Exception ignored in PluginV3.__del__") after the error."""
    from PIL import Image

    delays = _gif_delays(len(frames), fps)
    if shared and frames[0].shape[2] == 3:  # opaque frames (RGBA ones hold transparency: Pillow's palettes)
        pictures = _shared_palette(frames)
    else:
        pictures = [Image.fromarray(frame) for frame in frames]
    more = {"save_all": True, "append_images": pictures[1:]} if len(pictures) > 1 else {}
    if more and frames[0].shape[2] == 4:  # transparent frames: each replaces the last (disposal 0 kept the last
        # frame's pixels under a transparent one, and Pillow's delta frames drew unchanged pixels transparent over it)
        more["disposal"] = 2
    with open(tmp, "wb") as fh:
        try:
            pictures[0].save(fh, format="GIF", duration=[10 * d for d in delays] if more else 10 * delays[0],
                             loop=0, **more)
        except (OverflowError, struct.error) as exc:  # frames alike once quantized, merged past 655.35 s (Pillow
            # 13 packs a delay with int.to_bytes, older ones with struct.pack)
            raise InvalidInputError(f"fps {fps:g} shows frames that are alike in a GIF's colours for longer than a "
                                    f"GIF frame's longest delay ({_GIF_DELAYS[1] / 100:g} s): give a higher fps")\
                from exc


def _gif_delays(count: int, fps: float) -> list[int]:
    """The delays of ``count`` GIF frames at ``fps``, in hundredths of a second: frame k starts at k / fps rounded
    to the nearest hundredth (Pillow's int(100 / fps) for each frame played 12 fps at 12.5 and 60 at 100), each
    clipped to the delays a GIF stores (:data:`_GIF_DELAYS`; :func:`_check_fps` keeps 100 / fps in [1, 65536))."""
    starts = [math.floor(100.0 * k / fps + 0.5) for k in range(count + 1)]
    lo, hi = _GIF_DELAYS
    return [min(max(b - a, lo), hi) for a, b in zip(starts, starts[1:], strict=False)]


def _check_gif_runs(frames: Sequence[NDArray[np.uint8]], fps: float) -> None:
    """An InvalidInputError when a run of identical frames would last longer than a GIF frame's longest delay:
    Pillow writes such a run as one frame with the run's delays added, and raised a bare OverflowError past
    655.35 s (after every frame of an animation was rendered)."""
    delays = _gif_delays(len(frames), fps)
    if len(frames) * max(delays) <= _GIF_DELAYS[1]:  # no run can be too long: the frames are not compared
        return
    start = 0
    for k in range(1, len(frames) + 1):
        if k < len(frames) and np.array_equal(frames[k], frames[start]):
            continue
        total = sum(delays[start:k])
        if total > _GIF_DELAYS[1]:
            raise InvalidInputError(f"fps {fps:g} shows frames[{start}] to frames[{k - 1}] (identical: one GIF frame) "
                                    f"for {total / 100:g} s, longer than a GIF frame's longest delay "
                                    f"({_GIF_DELAYS[1] / 100:g} s): give a higher fps or fewer identical frames")
        start = k


def _unfinished_mp4(file: Path) -> str | None:
    """Why the MP4 ffmpeg wrote at ``file`` is incomplete, else None: its top-level boxes must fill the file exactly
    and hold the media ('mdat') and the index ('moov', written last). ffmpeg that failed (ENOSPC while muxing or
    writing the trailer) exited with an error that imageio-ffmpeg does not check: the truncated file, empty or
    without its index, replaced the old output as if written."""
    import struct

    size = file.stat().st_size
    found: set[bytes] = set()
    with open(file, "rb") as fh:
        at = 0
        while at < size:
            head = fh.read(8)
            if len(head) < 8:
                return f"{size:,} bytes, cut in a box header"
            length, kind = struct.unpack(">I4s", head)
            if length == 1:  # a 64-bit size follows
                extra = fh.read(8)
                if len(extra) < 8:
                    return f"{size:,} bytes, cut in a box header"
                length = struct.unpack(">Q", extra)[0]
            elif length == 0:  # the box runs to the end of the file
                length = size - at
            if length < 8 or at + length > size:
                return f"{size:,} bytes, its {kind.decode('latin-1')!r} box cut short"
            found.add(kind)
            at += length
            fh.seek(at)
    missing = [name for name in ("mdat", "moov") if name.encode() not in found]
    if missing:
        return f"{size:,} bytes, without its {' and '.join(repr(name) for name in missing)} box"
    return None
