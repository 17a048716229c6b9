"""Global terrain on the cube sphere, and adaptive meshes of local DEMs (paper 003: Adelsberger, "Interaktive
Visualisierung von globalen Höhendaten unter Verwendung verbesserter Bounding Shapes", Uni Bonn, §3-§8).

    >>> globe = Globe.sample(face_size=33)                                     # doctest: +SKIP
    >>> mesh = globe.mesh(error=2000.0, camera=Camera(eye=(2e7, 0, 0), target=(0, 0, 0)))  # doctest: +SKIP

The earth is a cube of six (2^k+1)² grids projected onto the sphere (§4); each face is refined by
longest-edge bisection (§5.1), steered by saturated metrics on nested bounding spheres or cone frustums
(§6, §7), breadth-first on Warp with one count -> scan -> emit per level (§5.2), so the mesh has no hanging
nodes, also across the face seams. :func:`adaptive_mesh` runs the same hierarchy on one flat heightfield
(SOAR / RTIN) with a true vertical error bound; without a camera its refinement is one count -> scan -> emit
over the nodes (μ = e is a per-node predicate, and saturation makes the levels' walk unnecessary).

Precision: node positions are float32 relative to the planet centre (0.5 m resolution at the earth's radius);
the bounding shapes and view metrics run in float64 on those float32 inputs, and the per-level margins
(relative 2^-20, §6) keep saturation and nesting exact in floating point. Output mesh vertices are float64,
computed from the integer cube point: each lies at R + exaggeration·z from the centre to ~1e-15 relative. The
geometric error e is measured on those float64 vertices, not on the float32 positions (there it fell up to
0.65 m short of the mesh's own error), with the same bits on every copy of a seam node.
"""

from __future__ import annotations

import ctypes
import dataclasses
import functools
import inspect
import math
import mmap
from collections.abc import Callable, Iterable, Sequence
from importlib import resources
from typing import Any, Literal

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._compaction import MAX_INT32 as _MAX_INT32
from ._compaction import check_budget, count_buffer, exclusive_offsets, get_memory_budget
from ._device import (
    empty_shared,
    get_cpu_threads,
    host_copy,
    launch,
    launch_chunked,
    launch_each,
    resolve_device,
    scratch,
    to_device,
    to_numpy,
)
from .camera import _MAX_COORDINATE, Camera
from .errors import DataFileError, InvalidInputError, OutputTooLargeError, counted, plain_repr
from .io import _check_read_budget, _pam_root, _prj_beside, picture_uint8, world_file
from .kernels import bounds as bounds_kernels
from .kernels import compaction as compaction_kernels
from .kernels import cubesphere as cube_kernels
from .kernels.memory import vec3l
from .mesh import mesh_argument
from .stepped import LAND_START
from .terrain import (
    FLOAT32_MAX,
    Terrain,
    as_array,
    as_number,
    check_flag,
    check_origin,
    check_spacing,
    is_name,
    is_real_dtype,
    number_or_nan,
    real_numbers,
    unmasked,
    unwrapped_longitudes,
)

__all__ = ["Camera", "Globe", "adaptive_mesh", "drape_colors", "drape_texture", "elevation_colors", "look_from",
           "render_view", "EARTH_RADIUS", "METRICS"]

#: Mean earth radius in metres.
EARTH_RADIUS = 6_371_000.0
#: The built-in metric names (paper 003 §7.1-§7.3).
METRICS = ("geometric", "distance", "clip")
#: Bytes per node entry held on the device: height, float32 position, e, r, h, α.
_BYTES_PER_ENTRY = 4 + 12 + 16
_BYTES_PER_ANGLE_SLOT = 12 + 8 + 8  # the resampling's angle tables, over a quarter face
#: Bytes per vertex and per face of a mesh handed out: float64 position and int32 node entry; int64 corners and the
#: int32 cube face.
_MESH_VERTEX_BYTES = 24 + 4
_MESH_FACE_BYTES = 24 + 4
_SAMPLE_FILE = "global_relief_20min.npz"
#: The most cells a face edge (or a planar grid's padded side) may have: node entries and the corners packed
#: i << 16 | j are int32 in the kernels (6 · 16385² entries fit, 6 · 32769² do not; nor does 32768 << 16).
_MAX_CELLS = 1 << 14
#: The most triangles a refinement level may hold: its ``counts`` (2 per triangle and 2 more), their offsets and
#: the thread ids are int32 (2 · 1,073,741,822 + 2 = 2^31 - 1). The mesh's faces (one ``keep`` count each and one
#: more) stop at _MAX_INT32 - 1. Only a memory budget above ~50 GiB lets a view come near either.
_MAX_LEVEL_TRIANGLES = (_MAX_INT32 - 2) // 2
#: Planar meshes without a view refine in one pass over the nodes (False: the breadth-first levels; tests
#: compare both).
_NODE_PASS = True
_TRACK_MIN = 4096  # triangles of a level from which the clip metric's flags are tracked (see _extract)
#: On the CPU, the levels of at most this many triangles (while their leaves and new vertices fit in four times
#: as many slots) are refined by one single-thread launch (``refine_levels``) instead of a count -> scan -> emit
#: each; 0 switches that off. 2**17: a 200k-triangle view of the whole globe (levels up to 80k) in one launch, in
#: 22 MB of scratch; a larger view continues level by level from where the launch stopped.
_SMALL_LEVELS = 1 << 17
#: With several CPU threads the one launch splits (:func:`_refine_in_ranges`): a first launch refines the levels of
#: at most this many triangles, then the next level is cut into _RANGES_PER_THREAD ranges a thread, each refined to
#: the end in a launch of its own (0 switches the split off). A view whose levels stay below 2**14 triangles (up to
#: ~40k triangles, a few ms) is left whole: the split's launches and copy cost about a millisecond on the 2-core
#: box, which a 10k-triangle view (2 ms) does not win back.
_SPLIT_FIRST = 1 << 14
_RANGES_PER_THREAD = 4
#: On the CPU with several threads (``set_cpu_threads``), the view's passes split into ranges of at least this many
#: triangles or vertices (``launch_chunked``'s ``min_elements``): the refinement test and the vertex pass cost
#: 30-40 ns an element, the emit passes 12-20 ns, so smaller ranges than the stepped passes' pay for a split.
_SPLIT_REFINE = 4096
_SPLIT_EMIT = 8192

UserMetric = Callable[[NDArray[np.float64], NDArray[np.float64]], ArrayLike]




# ------------------------------------------------------------------------------------------ validation
def _face_cells(face_size: Any, name: str = "face_size") -> int:
    if isinstance(face_size, bool) or not isinstance(face_size, (int, np.integer)):
        raise InvalidInputError(f"{name} must be an int 2^k + 1 (e.g. 257, 1025); got {plain_repr(face_size)}")
    cells = int(face_size) - 1
    if cells < 2 or cells & (cells - 1):
        raise InvalidInputError(f"{name} must be 2^k + 1 with k >= 1 (3, 5, 9, ..., 1025); got {face_size}")
    if cells > _MAX_CELLS:  # 6 · 32769² entries wrap int32, as does 32768 << 16 in a packed corner
        raise InvalidInputError(f"{name} must be at most {_MAX_CELLS + 1} (int32 node entries); got {face_size}")
    return cells


def _number(value: Any, name: str, kind: str, ok: Callable[[float], bool], unit: str = "") -> float:
    """``value`` as a float, finite and ``ok``; else "``name`` must be a ``kind`` number``unit``" ("a ``kind`` finite
    number" for a number that is not, NaN or inf)."""
    try:
        v = as_number(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a {kind}number{unit}; got {plain_repr(value)}") from None
    if not (math.isfinite(v) and ok(v)):
        raise InvalidInputError(f"{name} must be a {kind}finite number{unit}; got {plain_repr(value)}")
    return v


def _positive(value: Any, name: str) -> float:
    return _number(value, name, "positive ", lambda v: v > 0)


def _nonzero(value: Any, name: str) -> float:
    return _number(value, name, "non-zero ", lambda v: v != 0)


def _error_value(error: Any) -> float:
    return _number(error, "error", "", lambda v: v >= 0, " >= 0 (metres)")


#: :meth:`Globe.from_latlon`'s bound on the radius and the relief: float32 node positions, and their differences.
_MAX_POSITION = float(np.finfo(np.float32).max) / 4


def _radius_value(radius: Any, name: str = "radius") -> float:
    """A positive ``radius`` within float32 node positions (:data:`_MAX_POSITION`), at least a normal float32: the
    bounding shapes and the metrics (paper 003 §6-§7) read the float32 positions, which below it lose their precision
    (subnormal) or become 0 (radius 1e-50: every node at the centre, the cones' axes NaN, the clip test keeping the
    whole globe in view)."""
    radius = _positive(radius, name)
    tiny = float(np.finfo(np.float32).tiny)
    if radius < tiny:
        raise InvalidInputError(f"{name} must be at least {tiny:.3g} m (a normal float32, as the node positions are "
                                f"stored); got {radius:g}")
    if radius > _MAX_POSITION:
        raise InvalidInputError(f"{name} must be at most {_MAX_POSITION:.2g} m (float32 node positions); got "
                                f"{radius:g}")
    return radius


def _exaggeration_value(exaggeration: Any, name: str = "exaggeration") -> float:
    """A positive ``exaggeration`` at least a normal float32: the kernels take it as float32 (1e-320 became 0, a
    flat globe)."""
    exaggeration = _positive(exaggeration, name)
    tiny = float(np.finfo(np.float32).tiny)
    if exaggeration < tiny:
        raise InvalidInputError(f"{name} must be at least {tiny:.3g} (a normal float32, as the kernels take it); got "
                                f"{exaggeration:g}")
    return exaggeration


def _check_view_metrics(names: set[str], users: list[UserMetric], camera: Camera | None) -> None:
    """Without a camera the distance and clip metrics are dropped (they measure its eye and view): metrics naming
    only them left nothing to steer the refinement, μ = 1 everywhere, and the mesh came out whole below error 1 and
    as the root triangles from it up, without a word. Refused; the default (all three) keeps the geometric metric
    without a camera, and ``metrics=()`` still asks for none."""
    if camera is None and names and "geometric" not in names and not users:
        given = " and ".join(repr(name) for name in METRICS if name in names)
        which = f"metrics {given} need" if len(names) > 1 else f"metric {given} needs"
        raise InvalidInputError(f"the {which} a camera (its eye and view; without one nothing would steer the "
                                f"refinement); got metrics of {given} alone and no camera: give a camera, add "
                                "'geometric', or metrics=() for none")


def _check_distance_scale(value: Any, camera: Camera | None, names: set[str]) -> None:
    """``distance_scale`` is ℓ of the distance metric alone: given without a camera or without that metric it changed
    nothing (the mesh came out the same whatever it was), so it is refused, as ``floor`` without ``solid=True``."""
    if value is not None and (camera is None or "distance" not in names):
        why = "without a camera" if camera is None else f"with metrics {', '.join(sorted(names))} (no 'distance')"
        raise InvalidInputError(f"distance_scale applies only with a camera and the 'distance' metric (ℓ of its "
                                f"error · (ℓ / d)²); got distance_scale={value!r} {why}")


def _metric_options(metrics: Sequence[Any] | str, bounds: str, planar: bool) -> tuple[set[str], list[UserMetric]]:
    if not is_name(bounds, ("cone", "sphere")):
        raise InvalidInputError(f"bounds must be 'cone' or 'sphere'; got {bounds!r}")
    if planar and bounds == "cone":
        raise InvalidInputError("bounds='cone' needs the sphere (cone frustums about radial axes); the planar "
                                "case supports bounds='sphere' only")
    if isinstance(metrics, str):
        metrics = (metrics,)
    if not isinstance(metrics, Iterable) or (isinstance(metrics, np.ndarray) and metrics.ndim == 0):  # no items
        raise InvalidInputError(f"metrics must be a sequence of names among {METRICS} or callables (() for none); "
                                f"got {metrics!r}")
    names: set[str] = set()
    users: list[UserMetric] = []
    for m in metrics:
        if callable(m):
            users.append(_user_metric(m))
        elif is_name(m, METRICS):
            names.add(m)
        else:
            raise InvalidInputError(f"metrics must be names among {METRICS} or callables; got {m!r}")
    return names, users


def _user_metric(fn: Any) -> UserMetric:
    """``fn`` when it can be called as ``fn(points, bounding_radius)``, else an InvalidInputError: a callable of
    another arity failed at the first level with Python's TypeError, naming no metric."""
    try:
        inspect.signature(fn).bind(None, None)
    except TypeError:
        raise InvalidInputError(f"a user metric must take two arguments (points (M, 3), bounding_radius (M,)); "
                                f"got {getattr(fn, '__name__', fn)!r} with signature {inspect.signature(fn)}") from None
    except ValueError:  # no signature to read (some builtins): the call itself decides
        pass
    return fn


def _height_grid(values: ArrayLike, name: str) -> NDArray[np.float32]:
    """A real (H, W) float32 grid with H, W >= 2 and no NaN or inf (the hierarchy has no nodata), or an
    InvalidInputError naming ``name`` (a masked array's masked entries are nodata, refused as such)."""
    z = as_array(unmasked(values), name, "a real (H, W) array with H, W >= 2")
    if z.ndim != 2 or min(z.shape) < 2 or not is_real_dtype(z.dtype):  # not bools, complex or durations
        raise InvalidInputError(f"{name} must be a real (H, W) array with H, W >= 2; got shape {z.shape}, "
                                f"dtype {z.dtype}")
    mask = np.ma.getmaskarray(values) if np.ma.isMaskedArray(values) else None
    if mask is not None and mask.any():  # reported as "NaN or infinite values" where the array held none
        bad = np.argwhere(mask)
        entries = counted(len(bad), "masked (nodata) entry", "masked (nodata) entries")
        raise InvalidInputError(f"{name} has {entries} (first at row {bad[0][0]}, column {bad[0][1]}); fill them "
                                "first (e.g. from neighbours)")
    if z.dtype.kind == "f" and z.dtype.itemsize > 4:  # finite beyond float32 overflowed to inf in the cast below
        big = np.isfinite(z) & (np.abs(z) > FLOAT32_MAX)
        if big.any():
            row, col = np.argwhere(big)[0]
            raise InvalidInputError(f"{name} must fit in float32 (|z| <= {FLOAT32_MAX:.3g} m); got {z[row, col]:g} "
                                    f"at row {row}, column {col}")
    z = z.astype(np.float32)
    if not np.isfinite(z).all():
        bad = np.argwhere(~np.isfinite(z))
        raise InvalidInputError(f"{name} has {counted(len(bad), 'NaN or infinite value')} (first at row {bad[0][0]}, "
                                f"column {bad[0][1]}); fill them first (e.g. from neighbours)")
    return z


def _latlon_axes(lat: ArrayLike, lon: ArrayLike, shape: tuple[int, int]) -> tuple[Any, ...]:
    """lat and lon as float64, then the rounding of each: the spacing of a float16 / float32 axis's dtype at its
    largest |value| (its values lie within half of it of their exact positions), else 0."""
    axes, roundings = [], []
    for name, axis in (("lat", lat), ("lon", lon)):
        raw = as_array(axis, name, "a 1-D array of numbers (degrees)")
        if not is_real_dtype(raw.dtype):  # not bools or durations (numpy counts timedelta64 as an integer)
            raise InvalidInputError(f"{name} must be numbers (degrees); got dtype {raw.dtype}")
        axes.append(raw.astype(np.float64))
        narrow = raw.dtype.kind == "f" and raw.dtype.itemsize < 8 and raw.size and np.isfinite(raw).all()
        roundings.append(float(np.spacing(np.abs(raw).max())) if narrow else 0.0)
    lat, given = axes
    lon = unwrapped_longitudes(given) if given.ndim == 1 and np.isfinite(given).all() else given  # [.., 179.5, -179.5]
    rows, cols = shape
    if lat.shape != (rows,) or lon.shape != (cols,):
        raise InvalidInputError(f"lat and lon must have lengths ({rows},) and ({cols},) matching elevation "
                                f"{shape}; got {lat.shape} and {lon.shape}")
    if not (np.isfinite(lat).all() and np.isfinite(lon).all()):
        raise InvalidInputError("lat and lon must be finite")
    same = np.flatnonzero((np.diff(lon) == 0) & (np.diff(given) != 0))  # 360° apart: unwrapping made them equal
    if len(same):  # else "repeats at index 1 (-180.0, -180.0)" of lon [-180, 180], values the caller never gave
        i = int(same[0])
        raise InvalidInputError(
            f"lon's neighbouring columns must be different meridians; got lon[{i}] = {given[i]:.9g} and lon[{i + 1}] = "
            f"{given[i + 1]:.9g}, {abs(given[i + 1] - given[i]):.9g}° apart: the same meridian twice"
            + (", a grid of no width" if cols == 2 else "; drop one of the two columns"))
    return lat, lon, *roundings


def _not_global(message: str) -> InvalidInputError:
    """:meth:`Globe.from_latlon`'s refusal of a grid that is no globe (its longitudes short of a turn, or its rows
    short of a pole), marked ``not_global``: the command line names its INPUT file's coverage instead (it matched
    the message's words before)."""
    return InvalidInputError(message, not_global=True)


def _regular_step(axis: NDArray[np.float64], name: str, rounding: float = 0.0) -> float:
    """The mean step of a strictly monotone, regular axis. ``rounding`` (see :func:`_latlon_axes`): each value
    lies within half of it of its exact position, so each step within one of the exact step."""
    steps = np.diff(axis)
    if not ((steps > 0).all() or (steps < 0).all()):
        # a zero step (a repeated value, e.g. an axis of zeros) is where it stops: np.sign(0) matched a first zero
        turns = np.flatnonzero((steps == 0) | (np.sign(steps) != np.sign(steps[0])))
        bad = int(turns[0]) + 1 if len(turns) else 0
        raise InvalidInputError(f"{name} must be strictly monotone; it repeats or turns at index {bad} "
                                f"({axis[max(bad - 1, 0)]}, {axis[bad]})")
    step = float(np.abs(steps).mean())
    if np.abs(np.abs(steps) - step).max() > 1e-6 * max(step, 1e-12) + 1e-9 + 2 * rounding:
        raise InvalidInputError(f"{name} must be regularly spaced; steps range from {np.abs(steps).min():.9g} "
                                f"to {np.abs(steps).max():.9g} degrees")
    return step


#: A closing longitude column may differ from the first by this much (metres) plus _CLOSING_RELATIVE of the height:
#: float rounding (float32 keeps 1 mm at 8 km), far below any elevation model's accuracy; more is inconsistent data
_CLOSING_TOLERANCE = 0.01
_CLOSING_RELATIVE = 1e-6


def _check_closing_column(z: NDArray[np.float32], lat: NDArray[np.float64], lon: NDArray[np.float64]) -> None:
    """Refuse a duplicated closing longitude column (``lon[-1] = lon[0] + 360``, ascending axes) whose heights are
    not those of the first column: the two are the same meridian, and dropping one would hide which is right."""
    first, last = z[:, 0].astype(np.float64), z[:, -1].astype(np.float64)
    gap = np.abs(last - first)
    allowed = _CLOSING_TOLERANCE + _CLOSING_RELATIVE * np.maximum(np.abs(first), np.abs(last))
    if (gap > allowed).any():
        worst = int(np.argmax(gap))
        raise InvalidInputError(
            f"elevation's closing column (lon {lon[-1]:.9g}) must repeat its first column (lon {lon[0]:.9g}), the same "
            f"meridian, within {_CLOSING_TOLERANCE:g} m; got {counted(int((gap > allowed).sum()), 'row')} that "
            f"{'differs' if (gap > allowed).sum() == 1 else 'differ'}, by up to {gap[worst]:.6g} m (at lat "
            f"{lat[worst]:.9g}: {last[worst]:.9g} m against {first[worst]:.9g} m): "
            "inconsistent data; fix the grid or drop one of the two columns")


# ------------------------------------------------------------------------------------------ Globe
class Globe:
    """A global elevation model on the cube sphere with its bisection hierarchy (paper 003 §4-§7).

    Build with :meth:`from_latlon` or :meth:`sample`; the constructor is internal. Preprocessing (resampling,
    projection, bottom-up parameters) runs once; :meth:`mesh` extracts a view-dependent mesh per call.

    Attributes
    ----------
    face_size : int
        Nodes per face edge, 2^k + 1.
    radius : float
        Sphere radius R in metres (R = √3·m, m the half side of the cube, §4).
    exaggeration : float
        Vertical exaggeration applied to the elevations.
    device : wp.Device
    """

    def __init__(self, grid: Any, exaggeration: float, device: wp.Device, source: str = "") -> None:
        self.cells = int(grid.cells)
        self.face_size = self.cells + 1
        self.levels = 2 * int(round(math.log2(self.cells)))
        self.radius = float(grid.radius)
        self.exaggeration = exaggeration
        self.device = device
        self.source = source
        self._grid = grid
        self._height_range: tuple[float, float] | None = None  # lowest, highest node: on the first mesh with a camera
        self._params = _node_parameters(grid, faces=6, levels=self.levels, device=device)

    def _check_eye(self, eye: tuple[float, float, float]) -> None:
        """Refuse an eye inside the planet: below the terrain surface in its direction (R plus the height
        interpolated from the four nodes of the grid cell around that direction, the lower of the cell's two
        triangulations: :meth:`_height_under`). That is the relief's height, not the mesh's: a full-resolution
        triangle is a flat chord between its nodes, which sags below the interpolated height between them (about
        L² / 8R for cells of side L: 30 m at face size 257 on the Earth, 2 km at 33; the embedded relief at 257 lay
        up to 90 m below it along random directions) and, where its nodes' heights differ a lot, lies off it either
        way (the gnomonic (u, v) are not the chord's barycentric coordinates): an eye just above the mesh there may
        be refused, one just below it passed."""
        if self._height_range is None:
            heights = host_copy(self._grid.heights)
            self._height_range = float(heights.min()), float(heights.max())
        lowest, highest = self._height_range
        distance = math.hypot(*eye)
        if distance > self.radius + highest:  # above every node: most views, no lookup (at the highest, looked up)
            return
        surface = self.radius + lowest
        if distance > 0:  # the terrain in the eye's direction (never below the lowest node): the bound within the
            # relief, and what the refusal of an eye below every node names (it named the lowest node, e.g. the
            # deepest trench's -8396 m for an eye 11 km under the Himalaya, where the terrain is +4821 m)
            surface = self.radius + self._height_under(np.asarray(eye, dtype=np.float64) / distance)
        if distance <= max(surface, 0.0):
            d = _printed_apart(distance, surface)
            spacing = math.ulp(max(distance, surface))
            # 1 km above a sphere of 1e20 m (look_from's altitude) rounded onto it: "|eye| = 1e20 m, the surface
            # there 1e20 m ... terrain +0.0 m; raise the eye" said nothing of why, nor by how much
            coarse = (f" by at least float64's spacing of numbers at this distance, {spacing:g} m (an eye closer "
                      "above the surface rounds onto it)") if spacing >= 1.0 and surface - distance < spacing else ""
            raise InvalidInputError(f"camera eye {eye} lies inside the planet, below the terrain surface in its "
                                    f"direction: |eye| = {distance:.{d}f} m, the surface there {surface:.{d}f} m from "
                                    f"the centre (radius {self.radius:.{d}f} m, terrain {surface - self.radius:+.{d}f} "
                                    f"m); raise the eye{coarse}")

    def _height_under(self, direction: NDArray[np.float64]) -> float:
        """The exaggerated terrain height at a unit ``direction``: the nodes of the grid cell around it, interpolated
        over each of the cell's two triangulations, the lower of the two (the hierarchy's finest triangles take one
        of them per cell)."""
        cells, n = self.cells, self.face_size
        frames = np.array([[_axis(c) for c in frame] for frame in cube_kernels.FACE_FRAMES], dtype=np.float64)
        face = int(np.argmax(frames[:, 2] @ direction))  # the face whose normal is closest: its cube plane
        x, y, z = frames[face] @ direction
        # gnomonic: the cube point N · (x / z, y / z) on the face; node (i, j) sits at (2j - N, 2i - N)
        fi = min(max((cells * y / z + cells) / 2.0, 0.0), float(cells))
        fj = min(max((cells * x / z + cells) / 2.0, 0.0), float(cells))
        i0, j0 = min(int(fi), cells - 1), min(int(fj), cells - 1)
        u, v = fi - i0, fj - j0  # along rows (i), along columns (j)
        first = face * n * n + i0 * n + j0
        rows = host_copy(self._grid.heights[first : first + n + 2]).astype(np.float64)
        return _cell_surface(rows[0], rows[1], rows[n], rows[n + 1], u, v)

    # -------------------------------------------------------------------------------------- builders
    @classmethod
    def from_latlon(
        cls,
        elevation: ArrayLike,
        lat: ArrayLike,
        lon: ArrayLike,
        *,
        face_size: int = 257,
        radius: float = EARTH_RADIUS,
        exaggeration: float = 1.0,
        device: wp.DeviceLike = None,
    ) -> Globe:
        """Resample a global lat/lon elevation grid onto the cube sphere and preprocess the hierarchy.

        Parameters
        ----------
        elevation : (H, W) array_like
            Elevation in metres, rows along ``lat``, columns along ``lon``. NaN is refused (fill it first).
        lat : (H,) array_like
            Latitudes in degrees, strictly monotone, regular (to the precision of their dtype: float32 axes
            are fine), reaching within one step of both poles (cell-centred like ETOPO, or node-registered
            including ±90).
        lon : (W,) array_like
            Longitudes in degrees, strictly monotone, regular, covering 360° (a duplicated closing column,
            e.g. -180 and 180, is dropped; its heights must repeat the first column's within 1 cm, else the
            data are inconsistent and refused). Interpolation wraps around the antimeridian. The axis may cross
            it ([0.5, ..., 179.5, -179.5, ..., -0.5]): it is unwrapped first, 360° added or subtracted where
            neighbours are more than 180° apart.
        face_size : int
            Nodes per face edge, 2^k + 1 (the paper uses 1025), at most 16385 (int32 node entries).
        radius : float
            Sphere radius R in metres, from float32's smallest normal (1.18e-38) to 8.5e37 (float32 node positions).
        exaggeration : float
            Vertical exaggeration (> 0): node radius R + exaggeration · z.
        device : Warp device, optional

        Returns
        -------
        Globe

        Raises
        ------
        InvalidInputError
            Bad face size, grid shape, axes not monotone / regular / global, a closing longitude column that
            differs from the first, NaN, infinite or masked elevation, radius or exaggeration not positive (or
            beyond float32 node positions).
        OutputTooLargeError
            The node arrays and three float32 copies of the grid (12 bytes a cell) would exceed the memory budget
            (checked before allocating them).

        Notes
        -----
        Bilinear in lat/lon on the node's direction (latitude and longitude in float32, within ~4e-7 rad,
        1e-4 of a 10' cell; interpolation weights in float64); between the outermost row and a pole the
        value blends linearly towards the pole value, the mean of that row (a row on the pole itself, ±90°, is
        that one point: its mean). Cost: O(6 n²) per step, about
        0.4 s CPU for 6 × 1025² on one core of the project's AMD EPYC box, 0.7–0.8 s on its earlier Intel Xeon
        (resampling, projection and all parameters; see benchmarks/RESULTS.md).

        Examples
        --------
        >>> import numpy as np
        >>> lat = np.linspace(89.5, -89.5, 180); lon = np.linspace(-179.5, 179.5, 360)
        >>> g = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=5, device="cpu")
        >>> m = g.mesh()
        >>> len(m.vertices), len(m.faces), bool(m.is_watertight)
        (98, 192, True)
        """
        cells = _face_cells(face_size)
        radius = _radius_value(radius)
        exaggeration = _exaggeration_value(exaggeration)
        z = _height_grid(elevation, "elevation")
        n_entries = 6 * (cells + 1) ** 2
        slots = (cells // 2 + 1) ** 2  # the angle tables cover a quarter face
        # the node arrays, the angle tables and three float32 copies of the grid at once: z, its contiguous copy
        # (reversed axes, a closing column dropped) or the one with the pole rows averaged, and the device's (the
        # grid's copies went uncounted: a 21600 x 43200 grid needs over 10 GiB for them, whatever the face size)
        check_budget(n_entries * _BYTES_PER_ENTRY + slots * _BYTES_PER_ANGLE_SLOT + 3 * z.size * z.itemsize,
                     f"a globe of face_size {cells + 1} from a {z.shape[0]}x{z.shape[1]} grid",
                     hint="use a smaller face_size or a coarser grid")
        relief = exaggeration * float(np.abs(z).max(initial=0.0))
        if relief > _MAX_POSITION:  # float32 node heights and positions, and their differences
            raise InvalidInputError(f"exaggeration · elevation must stay within ±{_MAX_POSITION:.2g} m (float32 node "
                                    f"positions); got {exaggeration:g} x {float(np.abs(z).max()):.9g} m")
        lowest = np.unravel_index(int(np.argmin(z)), z.shape)
        deepest = float(z[lowest])
        if radius + exaggeration * deepest <= 0:
            raise InvalidInputError(f"radius + exaggeration · elevation must stay > 0 (nodes beyond the centre turn "
                                    f"the mesh inside out); got {radius:.9g} + {exaggeration:.9g} x {deepest:.9g} = "
                                    f"{radius + exaggeration * deepest:.9g} m (row {lowest[0]}, column {lowest[1]})")
        lat, lon, lat_rounding, lon_rounding = _latlon_axes(lat, lon, z.shape)
        dlat = _regular_step(lat, "lat", lat_rounding)
        dlon = _regular_step(lon, "lon", lon_rounding)
        if lat[0] < lat[-1]:
            lat, z = lat[::-1], z[::-1]
        if lon[0] > lon[-1]:
            lon, z = lon[::-1], z[:, ::-1]
        if abs((lon[-1] - lon[0]) - 360.0) < 1e-6 * 360:  # node-registered with a closing column: the same meridian
            _check_closing_column(z, lat, lon)
            lon, z = lon[:-1], z[:, :-1]
        if np.abs(lat).max() > 90.0 + 1e-9:
            raise InvalidInputError(f"lat must lie in [-90, 90] degrees; got {lat[0]:.9g} to {lat[-1]:.9g}")
        if abs(len(lon) * dlon - 360.0) > 1e-6 * 360:
            raise _not_global(f"lon must cover 360 degrees (W · step = 360); got {len(lon)} x {dlon:.9g} = "
                              f"{len(lon) * dlon:.9g} degrees")
        if lat[0] < 90.0 - dlat - 1e-9 or lat[-1] > -90.0 + dlat + 1e-9:
            raise _not_global(f"lat must reach within one step ({dlat:.9g}°) of both poles; got "
                              f"{lat[0]:.9g} to {lat[-1]:.9g}")
        for row, pole in ((0, 90.0), (-1, -90.0)):
            # a row on a pole is one point: its value is the row's mean (the pole value below, as documented), not
            # the row sampled at the node's longitude (a pole row of 170 to 180 m put lon 0's 180 m at the pole)
            if abs(lat[row] - pole) <= 1e-9 and np.ptp(z[row]) > 0:
                z = np.array(z)
                z[row] = z[row].mean(dtype=np.float64)
        device = resolve_device(device)
        source = cube_kernels.LatLonGrid()
        source.elevation = wp.array(np.ascontiguousarray(z), dtype=wp.float32, device=device)
        source.lat0 = math.radians(lat[0])
        source.dlat = math.radians(dlat)
        # wrapped before the radians: an axis starting a billion degrees out keeps its fraction (lon + 1e9° was off
        # by a millimetre against lon + (1e9 mod 360)°)
        source.lon0 = math.radians((lon[0] + 180.0) % 360.0 - 180.0)
        source.dlon = math.radians(dlon)
        source.inv_dlat = 1.0 / source.dlat
        source.inv_dlon = 1.0 / source.dlon
        source.inv_cols = 1.0 / z.shape[1]
        source.north_pole = float(z[0].mean(dtype=np.float64))
        source.south_pole = float(z[-1].mean(dtype=np.float64))
        grid = cube_kernels.CubeSphereGrid()
        grid.cells = cells
        grid.n = cells + 1
        grid.planar = 0
        grid.radius = radius
        grid.spacing = wp.vec2d(1.0, 1.0)
        grid.rows_valid = grid.n
        grid.cols_valid = grid.n
        grid.heights = _node_array(n_entries, wp.float32, device)
        grid.positions = _node_array(n_entries, wp.vec3, device)
        lines = wp.empty(6 * grid.n, dtype=wp.vec3, device=device)
        launch_chunked(cube_kernels.longitude_lines, 6 * grid.n, [grid, source], [lines], device)
        tables = [wp.empty(slots, dtype=dtype, device=device) for dtype in (wp.vec3, wp.vec2, wp.float64)]
        launch_chunked(cube_kernels.angle_tables, slots, [cells], tables, device)
        grid.inverse_lengths = tables[2]  # kept: the geometric error's float64 positions read it
        launch_chunked(cube_kernels.resample_latlon, n_entries, [grid, source, float(exaggeration), lines, *tables],
                       [grid.heights, grid.positions], device)
        return cls(grid, exaggeration, device, source=f"lat/lon grid {z.shape[0]}x{z.shape[1]}")

    @classmethod
    def sample(cls, *, face_size: int = 257, radius: float = EARTH_RADIUS, exaggeration: float = 1.0,
               device: wp.DeviceLike = None) -> Globe:
        """The embedded global relief (ETOPO 2022 at 20 arc-minutes, see ``stepterrain/data/README.md``) on the cube
        sphere: :meth:`from_latlon` of :func:`load_global_relief`, ``face_size`` (default 257), ``radius`` (default
        :data:`EARTH_RADIUS`), ``exaggeration`` (default 1) and ``device`` as it takes them."""
        lat, lon, elevation = load_global_relief()
        globe = cls.from_latlon(elevation, lat, lon, face_size=face_size, radius=radius,
                                exaggeration=exaggeration, device=device)
        globe.source = "embedded ETOPO 2022 global relief, 20 arc-minutes"
        return globe

    # -------------------------------------------------------------------------------------- accessors
    @property
    def heights(self) -> NDArray[np.float32]:
        """(6, n, n) exaggerated node elevations in metres, read-only (on the CPU a view of the globe's own nodes)."""
        n = self.face_size
        return _read_only(host_copy(self._grid.heights).reshape(6, n, n))

    @property
    def positions(self) -> NDArray[np.float32]:
        """(6, n, n, 3) float32 node positions (planet-centred metres) used by the hierarchy, read-only (on the CPU
        a view of the globe's own nodes)."""
        n = self.face_size
        return _read_only(host_copy(self._grid.positions).reshape(6, n, n, 3))

    def node_parameters(self) -> dict[str, NDArray[np.float32]]:
        """Per node (6, n, n): geometric_error e, bounding_radius r, cone_height h, cone_angle α (radians)."""
        n = self.face_size
        values = host_copy(self._params.values)
        return {name: np.ascontiguousarray(values[:, k]).reshape(6, n, n)
                for k, name in enumerate(("geometric_error", "bounding_radius", "cone_height", "cone_angle"))}

    def __repr__(self) -> str:
        return (f"Globe(face_size={self.face_size}, radius={self.radius:g}, exaggeration={self.exaggeration:g}, "
                f"device={str(self.device)!r}, source={self.source!r})")

    # -------------------------------------------------------------------------------------- mesh
    def mesh(
        self,
        *,
        error: float = 0.0,
        camera: Camera | None = None,
        bounds: Literal["cone", "sphere"] = "cone",
        metrics: Sequence[str | UserMetric] = METRICS,
        distance_scale: float | None = None,
        cull: bool = True,
        per_face: bool = False,
    ) -> trimesh.Trimesh | list[trimesh.Trimesh]:
        """Extract an adaptive, crack-free mesh (paper 003 §5.2, §7).

        Parameters
        ----------
        error : float
            Refinement threshold ε >= 0: a triangle refines while μ(refinement node) > ε. Without a camera
            μ = e, the saturated geometric error in metres; with the distance metric μ = e · (ℓ / d)², so
            ``error`` is the error in metres tolerated at distance ℓ = ``distance_scale`` from the eye, and
            the tolerance grows with the square of the distance (§7.2). ``error=0`` refines every
            node not clipped: with no camera, the full-resolution sphere. e is the paper's one-level look-ahead
            error (§7.1: a node's distance from the midpoint of the edge it splits, saturated over its
            descendants), so every node left out has e <= ε, but its distance from the mesh sums the steps of the
            levels between: it may exceed ε (the embedded relief at face size 129: within ε up to 500 m, up to
            2.7 km from the mesh at 2 km). :func:`adaptive_mesh`'s planar e is the true vertical error, a bound.
            Default 0 (the CLI's ``globe --error`` defaults to 500).
        camera : Camera, optional
            Eye and frustum for the distance and clip metrics (ignored without one). The eye must lie above the
            terrain surface in its direction (radius plus the node heights interpolated there).
        bounds : "cone" or "sphere"
            Bounding shapes (§6): cone frustums about the radial axis, or spheres.
        metrics : names and callables
            Any of "geometric", "distance", "clip" (§7.1-§7.3), multiplied (§7.4). A callable
            ``f(points (M, 3) float64, bounding_radius (M,)) -> (M,)`` is a user metric multiplied in per level; it
            must not grow from a node to its children (saturated): where a triangle refined without its
            neighbour (a hanging node, a crack) the mesh is refused with an InvalidInputError naming it (the leaves
            of a refinement with a user metric are checked to share every inner edge).
        distance_scale : float, optional
            ℓ in metres (see ``error``); default: the eye's altitude above the sphere of radius R, at least
            one node spacing. Only with a camera and the distance metric (refused otherwise: it would change
            nothing).
        cull : bool
            With the clip metric and a camera, drop leaf triangles wholly outside the frustum (the mesh then
            has a border where the view ends; without culling it stays closed).
        per_face : bool
            Return six meshes, one per cube face, each with UV texture coordinates of its face (§5.3) and the
            whole mesh's bounds as ``metadata["shared_bounds"]`` and its own vertex and face counts and bounds as
            ``metadata["whole_part"]`` (:func:`~stepterrain.export.save_mesh` stores the six files alike by them,
            culled ones too: the seams stay welded).

        Returns
        -------
        trimesh.Trimesh (or a list of six)
            Welded: each node once, counter-clockwise seen from outside; ``face_attributes["cube_face"]``,
            ``metadata["node_entry"]`` (vertex -> node entry), ``metadata["levels"]`` (triangles per level),
            ``metadata["units"]`` "meters" (a ``.3mf`` declares them); with a camera ``metadata["eye"]`` (its eye,
            x, y, z: :func:`~stepterrain.export.save_mesh` stores a glTF's float32 positions relative to it unless
            given another ``origin``).

        Raises
        ------
        InvalidInputError
            Negative error, unknown bounds or metric names, a camera inside the planet (at or below the terrain
            surface in its direction, e.g. inside a mountain), metrics of 'distance' or 'clip' alone without a camera.
        OutputTooLargeError
            A refinement level or the mesh would exceed the memory budget, or the int32 counts of the kernels
            (a level of over 1,073,741,822 triangles, a mesh of 2^31 - 2 faces) whatever the budget.

        Examples
        --------
        >>> import numpy as np
        >>> lat = np.linspace(89.5, -89.5, 180); lon = np.linspace(-179.5, 179.5, 360)
        >>> g = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=9, device="cpu")
        >>> full = g.mesh()
        >>> len(full.faces) == 12 * 8**2 and full.euler_number == 2
        True
        """
        error = _error_value(error)
        cull, per_face = check_flag(cull, "cull"), check_flag(per_face, "per_face")
        names, users = _metric_options(metrics, bounds, planar=False)
        if camera is not None:
            if not isinstance(camera, Camera):
                raise InvalidInputError(f"camera must be a stepterrain.globe.Camera; got {type(camera).__name__}")
            self._check_eye(camera.eye)
        _check_view_metrics(names, users, camera)
        _check_distance_scale(distance_scale, camera, names)
        if distance_scale is None:
            altitude = np.linalg.norm(camera.eye) - self.radius if camera is not None else 0.0
            distance_scale = max(altitude, self.radius * math.pi / 2 / self.cells)
        view = _view(camera, error, names, bounds, _positive(distance_scale, "distance_scale"), self.device)
        mesh = _extract(self._grid, self._params, view, users, self.levels, faces=6,
                        cull=bool(cull and camera is not None and "clip" in names), per_face=per_face,
                        device=self.device)
        for part in mesh if per_face else [mesh]:  # its radius and heights: a 3MF declares the unit (it said mm)
            part.metadata["units"] = "meters"
        if camera is not None:  # save_mesh's default glTF origin: stored relative to the eye, a close view keeps
            # the vertices near it to float32's rounding of their distance from it (the bounds' centre: 0.3 m off)
            for part in mesh if per_face else [mesh]:
                part.metadata["eye"] = [float(c) for c in camera.eye]
        return mesh


# ------------------------------------------------------------------------------------------ shared machinery
def _read_only(array: NDArray[Any]) -> NDArray[Any]:
    """``array`` made read-only: on the CPU :func:`host_copy` is a view of the globe's own device array, and an
    edit through it changed every later mesh while the node parameters (errors, bounds) kept the old heights."""
    array.flags.writeable = False
    return array


def load_global_relief() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int16]]:
    """The embedded global relief grid: (lat, lon, elevation) with rows north to south."""
    try:
        with resources.files("stepterrain.data").joinpath(_SAMPLE_FILE).open("rb") as f, np.load(f) as data:
            return np.asarray(data["lat"]), np.asarray(data["lon"]), np.asarray(data["elevation"])
    except (OSError, KeyError) as exc:  # pragma: no cover - broken install
        raise DataFileError(f"the embedded global relief {_SAMPLE_FILE} cannot be read: {exc}") from exc


#: Host arrays of at least this many bytes are backed by transparent huge pages (2 MiB) where the kernel
#: allows it: the refinement's scattered loads into 100+ MB of node arrays then miss the TLB far less, and
#: a fresh allocation faults once per 2 MiB instead of once per 4 KiB.
_HUGE_PAGE = 1 << 21


def _node_array(n: int, dtype: Any, device: wp.Device, *, zero: bool = False, dense: int | None = None) -> wp.array:
    """``wp.empty(n, dtype)`` (``wp.zeros`` with ``zero``); on the CPU, large arrays in 2 MiB-aligned memory
    advised as huge pages (an anonymous map: zeros, each page written when first touched). ``dense``: only the
    first that many elements are advised (a padded planar input's rows; beyond them the kernels write a sparse
    few, each of which would fault in and clear a whole 2 MiB page)."""
    nbytes = n * wp.types.type_size_in_bytes(dtype)
    if not device.is_cpu or nbytes < 4 * _HUGE_PAGE or not hasattr(mmap, "MADV_HUGEPAGE"):
        return (wp.zeros if zero else wp.empty)(n, dtype=dtype, device=device)
    buffer = mmap.mmap(-1, nbytes + _HUGE_PAGE, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    address = ctypes.addressof(ctypes.c_char.from_buffer(buffer))
    offset = (-address) % _HUGE_PAGE
    advised = len(buffer) if dense is None else offset + dense * wp.types.type_size_in_bytes(dtype)
    advised = min(len(buffer), -(-advised // _HUGE_PAGE) * _HUGE_PAGE)
    try:
        if dense != 0:
            buffer.madvise(mmap.MADV_HUGEPAGE, 0, advised)
    except OSError:  # pragma: no cover - no THP in this kernel: ordinary pages
        pass
    scalar = {wp.float32: np.float32, wp.int32: np.int32}[getattr(dtype, "_wp_scalar_type_", dtype)]
    host = np.frombuffer(buffer, dtype=np.uint8, count=nbytes, offset=offset).view(scalar)
    return wp.array(host, dtype=dtype, shape=(n,), device=device, copy=False)  # keeps ``host`` (and the map)


def _written_rows(grid: Any) -> int:
    """Rows of a planar grid its kernels fill at the finest spacing: the input's, and the padding's below it that
    ``cube_kernels.padding_tier`` computes (those PADDING_WRITTEN or more below its last row are never read)."""
    return min(grid.n, grid.rows_valid + int(cube_kernels.PADDING_WRITTEN) - 1)


def _dense_entries(grid: Any) -> int:
    """Entries of a planar grid's rows that its kernels fill (the input's, and the padding's below it that
    ``cube_kernels.padding_tier`` computes at the finest spacing); below them only a sparse few. 0 when the
    input fills less than half of each row (a tall strip): a 2 MiB page would hold little more than the rows'
    starts."""
    if 2 * grid.cols_valid < grid.n:
        return 0
    return _written_rows(grid) * grid.n


def _printed_apart(below: float, above: float) -> int:
    """Decimals for an eye's refusal: one where that prints ``below`` (the eye) and ``above`` (the surface) apart, else
    as many as tell them apart (up to 17 significant digits; equal numbers, one). 0.1 m printed an eye 1 cm under the
    earth's surface as the surface, and every number of a unit globe as 1.0 or 0.0."""
    decimals = 1
    while below != above and f"{below:.{decimals}f}" == f"{above:.{decimals}f}" and decimals < 340:
        if decimals >= 17 - math.floor(math.log10(max(abs(below), abs(above)))):  # past float64's digits
            break
        decimals += 1
    return decimals


def _cell_surface(z00: float, z01: float, z10: float, z11: float, u: float, v: float) -> float:
    """The height at (u along rows, v along columns) in a grid cell of corner heights z00, z01 (next column), z10
    (next row), z11: interpolated over each of the cell's two triangulations, the lower of the two (the
    hierarchy's finest triangles take one of them per cell)."""
    main = z00 + v * (z01 - z00) + u * (z11 - z01) if v >= u else z00 + u * (z10 - z00) + v * (z11 - z10)
    anti = z00 + v * (z01 - z00) + u * (z10 - z00) if u + v <= 1 else z11 + (1 - v) * (z10 - z11) + \
        (1 - u) * (z01 - z11)
    return min(main, anti)


def _check_planar_eye(eye: tuple[float, float, float], z: NDArray[np.float32], spacing: tuple[float, float],
                      origin: tuple[float, float], highest: float) -> None:
    """Refuse a camera eye over the grid's rectangle at or below its surface (the height interpolated from the four
    nodes of the cell under the eye, the lower of the cell's two triangulations: never above the mesh's surface
    there). An eye beside the rectangle may be at any height."""
    ex, ey, ez = (float(c) for c in eye)
    if ez > highest:  # above every node: most views, no lookup
        return
    rows, cols = z.shape
    fi, fj = (ey - origin[1]) / spacing[1], (ex - origin[0]) / spacing[0]
    if not (0.0 <= fi <= rows - 1 and 0.0 <= fj <= cols - 1):
        return
    i0, j0 = min(int(fi), rows - 2), min(int(fj), cols - 2)
    cell = z[i0 : i0 + 2, j0 : j0 + 2].astype(np.float64)
    surface = _cell_surface(cell[0, 0], cell[0, 1], cell[1, 0], cell[1, 1], fi - i0, fj - j0)
    if ez <= surface:
        d = _printed_apart(ez, surface)
        raise InvalidInputError(f"camera eye {tuple(eye)} lies below the terrain surface: at (x, y) = ({ex:.1f}, "
                                f"{ey:.1f}) the surface is at z = {surface:.{d}f} m, the eye at z = {ez:.{d}f} m; "
                                "raise the eye (or move it off the grid's rectangle)")


def _planar_grid(z: NDArray[np.float32], spacing: tuple[float, float], valid: tuple[int, int], *, shapes: bool,
                 device: wp.Device, n: int | None = None) -> Any:
    """The planar grid of a (2^k + 1)² height array (padded beyond the ``valid`` rows and columns), or with ``n``
    of the input itself (shape ``valid``), padded here to n x n by repeating its edge at the entries anything
    reads (``cube_kernels.pad_heights``: not the whole square, which a long strip's would dwarf); node positions
    (j·dx, i·dy, z) only with ``shapes`` (else an empty array: see :func:`_node_parameters`)."""
    n = z.shape[0] if n is None else n
    grid = cube_kernels.CubeSphereGrid()
    grid.cells = n - 1
    grid.n = n
    grid.planar = 1
    grid.radius = 0.0
    grid.spacing = wp.vec2d(*spacing)
    grid.rows_valid, grid.cols_valid = valid
    grid.inverse_lengths = wp.empty(0, dtype=wp.float64, device=device)  # the cube's alone
    if z.shape == (n, n):
        grid.heights = to_device(z.reshape(-1), wp.float32, device)
    else:
        source = to_device(z.reshape(-1), wp.float32, device)
        grid.heights = _node_array(n * n, wp.float32, device, zero=True, dense=_dense_entries(grid))  # 0 where unread
        launch_chunked(cube_kernels.pad_heights, n * n, [grid, source], [grid.heights], device)
    grid.positions = wp.empty(n * n if shapes else 0, dtype=wp.vec3, device=device)
    if shapes:
        launch_chunked(cube_kernels.project_nodes, n * n, [grid], [grid.positions], device)
    return grid


def _node_parameters(grid: Any, *, faces: int, levels: int, device: wp.Device, shapes: bool = True) -> Any:
    """e, r, h, α for every node copy, bottom-up level by level (paper 003 §6, §7.1). ``shapes=False``
    (planar only): e alone, r = h = 0, without reading ``grid.positions``: all a mesh without a view needs."""
    n_entries = faces * grid.n * grid.n
    params = cube_kernels.NodeParameters()
    # a padded input's nodes far out in the padding are never written (cube_kernels.padding_tier) nor read: zeros,
    # not whatever the memory held
    padded = faces == 1 and (grid.rows_valid, grid.cols_valid) != (grid.n, grid.n)
    params.values = _node_array(n_entries, wp.vec4, device, zero=padded, dense=_dense_entries(grid) if padded else None)
    outputs = [params.values]
    launch_chunked(cube_kernels.zero_corners, 4 * faces, [grid.n], outputs, device)  # the rest is written below
    angles = int(faces == 6)
    for depth in range(levels - 1, -1, -1):
        if depth == levels - 1 and faces == 6:  # the leaves (half of all nodes): a lean kernel in memory order
            launch_chunked(cube_kernels.saturate_leaf_parameters, faces * grid.n * grid.n, [grid], outputs, device)
            continue
        if depth == levels - 2 and faces == 6 and levels >= 2:  # the 2 x 2 cell centres, likewise
            launch_chunked(cube_kernels.saturate_cell_centres, faces * grid.n * grid.n, [grid], outputs, device)
            continue
        if depth >= levels - 2 and faces == 1:  # planar: the two deepest levels likewise (the rows below a padded
            # input's last one by PADDING_WRITTEN or more are never read: cube_kernels.padding_tier)
            launch_chunked(cube_kernels.saturate_planar_fine, _written_rows(grid) * grid.n,
                           [grid, int(depth == levels - 2), int(shapes)], outputs, device)
            continue
        # α only on face 0 (it depends on the grid alone, and the cube's rotations map the faces onto each
        # other with their hierarchy); copied to the other faces below
        slots = faces * cube_kernels.depth_slots(depth)
        if padded:  # the nodes that may be written only (cube_kernels.padded_depth_box)
            slots = cube_kernels.padded_depth_slots(grid.cells, grid.rows_valid, grid.cols_valid, depth)
        launch_chunked(cube_kernels.saturate_node_parameters, slots,
               [grid, depth, angles, int(shapes), params], outputs, device)
    if angles:
        nn = grid.n * grid.n
        launch_chunked(cube_kernels.copy_cone_angles, nn, [nn], [params.values], device)
    return params


def _view(camera: Camera | None, error: float, names: set[str], bounds: str, scale: float,
          device: wp.Device) -> Any:
    view = bounds_kernels.View()
    view.error = error
    view.distance_scale = scale
    view.flags = wp.vec4i(int("geometric" in names), int(camera is not None and "distance" in names),
                          int(camera is not None and "clip" in names), 1 if bounds == "cone" else 0)
    view.eye_length = 0.0
    view.eye_unit = wp.vec3d(0.0, 0.0, 0.0)
    if camera is not None:
        view.eye = wp.vec3d(*camera.eye)
        eye_length = float(np.linalg.norm(camera.eye))
        view.eye_length = eye_length
        if eye_length > 0:
            view.eye_unit = wp.vec3d(*(np.asarray(camera.eye) / eye_length))
        view.planes = wp.array(camera.planes(), dtype=wp.vec4d, device=device)
    else:
        view.eye = wp.vec3d(0.0, 0.0, 0.0)
        view.planes = wp.zeros(0, dtype=wp.vec4d, device=device)
    return view


@functools.lru_cache(maxsize=16)
def _roots_and_corners(cells: int, n: int, faces: int, device: str) -> tuple[wp.array, wp.array]:
    """:func:`_root_triangles` and :func:`corner_entries` on ``device``, made once per grid size (the kernels only
    read them)."""
    return (wp.array(_root_triangles(cells, faces), dtype=wp.vec4i, device=device),
            wp.array(corner_entries(cells, n, faces), dtype=wp.int32, device=device))


def _root_triangles(cells: int, faces: int) -> NDArray[np.int32]:
    """Two counter-clockwise right triangles per face split by the main diagonal: (face, a, b, c), a-b the
    hypotenuse, corners packed i << 16 | j."""
    def pack(i: int, j: int) -> int:
        return (i << 16) | j

    roots = []
    for f in range(faces):
        roots.append([f, pack(0, 0), pack(cells, cells), pack(cells, 0)])
        roots.append([f, pack(cells, cells), pack(0, 0), pack(0, cells)])
    return np.asarray(roots, dtype=np.int32)


def corner_entries(cells: int, n: int, faces: int) -> NDArray[np.int32]:
    """Canonical entries of the grid corners: the 8 cube corners (faces=6) or the 4 planar corners."""
    if faces == 1:
        return np.array([0, cells, cells * n, cells * n + cells], dtype=np.int32)
    entries = set()
    for point in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3) * cells:
        entries.add(point_entry_np(point, cells, n))
    return np.array(sorted(entries), dtype=np.int32)


def _axis(code: int) -> NDArray[np.int64]:
    v = np.zeros(3, dtype=np.int64)
    v[abs(code) - 1] = 1 if code > 0 else -1
    return v


def point_entry_np(point: NDArray[np.int64], cells: int, n: int) -> int:
    """NumPy twin of ``cubesphere.point_entry`` for one cube point (used for the 8 corners)."""
    for f, frame in enumerate(cube_kernels.FACE_FRAMES):
        if int(_axis(frame[2]) @ point) == cells:
            x = int(_axis(frame[0]) @ point)
            y = int(_axis(frame[1]) @ point)
            return f * n * n + ((y + cells) // 2) * n + (x + cells) // 2
    raise AssertionError(f"{point} is not on the cube")  # pragma: no cover


def _host_int(array: wp.array, index: int) -> int:
    """One int32 of a device array on the host (on the CPU a zero-copy read, no slice object)."""
    if array.device.is_cpu:
        return int(array.numpy()[index])
    return int(array[index : index + 1].numpy()[0])


def _concat(chunks: list[wp.array], dtype: Any, device: wp.Device, *, share: bool = False) -> wp.array:
    """The chunks one after another in a new array; with ``share`` the one chunk that holds anything itself (no
    copy: for arrays read within the call, never one handed to the caller)."""
    filled = [c for c in chunks if c.shape[0]]
    if share and len(filled) == 1:
        return filled[0]
    total = sum(c.shape[0] for c in chunks)
    out = wp.empty(total, dtype=dtype, device=device)
    offset = 0
    for c in chunks:
        if c.shape[0]:
            wp.copy(out, c, dest_offset=offset, count=c.shape[0])
            offset += c.shape[0]
    return out


def _user_factors(users: list[UserMetric], grid: Any, host: tuple[NDArray[np.float32], NDArray[np.float32]],
                  triangles: wp.array, device: wp.Device, origin: tuple[float, float] = (0.0, 0.0)) -> wp.array:
    """Per triangle, the product of the user metrics at its refinement node (one vectorised call per level);
    ``host`` = the node positions and parameters on the host, copied once per mesh; ``origin`` is added to the
    points' x and y (a planar grid's positions are relative to its origin, the metric sees the mesh's)."""
    tris = host_copy(triangles).astype(np.int64)
    n = grid.n
    a, b = tris[:, 1], tris[:, 2]
    m = tris[:, 0] * n * n + (((a >> 16) + (b >> 16)) // 2) * n + ((a & 65535) + (b & 65535)) // 2
    points = host[0][m].astype(np.float64)
    if origin != (0.0, 0.0):
        points[:, :2] += origin
    radius = host[1][m, 1].astype(np.float64)
    factor = np.ones(len(m), dtype=np.float64)
    for fn in users:
        name, expected = getattr(fn, "__name__", fn), f"must return {len(m)} finite values >= 0"
        result = fn(points, radius)
        try:
            value = np.asarray(result)
            if value.dtype.kind not in "biufO":  # complex lost its imaginary part (a ComplexWarning); text
                raise TypeError
            value = value.astype(np.float64)
        except (TypeError, ValueError):  # text, ragged rows: numpy's conversion error named no metric
            raise InvalidInputError(f"user metric {name!r} {expected}; got {type(result).__name__} that is not "
                                    "numbers") from None
        if value.shape != (len(m),):
            raise InvalidInputError(f"user metric {name!r} {expected}; got shape {value.shape}")
        if not np.isfinite(value).all() or (value < 0).any():
            raise InvalidInputError(f"user metric {name!r} {expected}; got NaN, inf or negative values")
        # capped at float32's largest, which refines as inf does: the float32 cast below overflowed with a
        # RuntimeWarning, and a product beyond float64 (inf) times a later 0 was NaN
        with np.errstate(over="ignore"):
            factor = np.minimum(factor * value, FLOAT32_MAX)
    return wp.array(factor.astype(np.float32), dtype=wp.float32, device=device)


def _check_int32(count: int, limit: int, what: str, items: str, where: str) -> None:
    """Raise :class:`OutputTooLargeError` when ``count`` ``items`` exceed ``limit``, the most that int32 indices
    (named by ``where``) can hold: past it the kernels' counts and offsets would wrap, whatever the budget."""
    if count > limit:
        raise OutputTooLargeError(f"{what} would hold {count:,} {items}, over the {limit:,} that {where} (int32 in "
                                  "the kernels) can index, whatever the memory budget; raise the error or narrow "
                                  "the view")


def _planar_leaves(grid: Any, params: Any, use_geometric: int, error: float,
                   device: wp.Device) -> tuple[wp.array, wp.array, list[int]]:
    """Leaves and new vertex entries of a planar mesh without a view, in one pass over the nodes of the input's
    rectangle (a padded input's padding holds no vertex or face of the mesh)."""
    count = grid.rows_valid * grid.cols_valid
    counts = scratch("globe.nodes.counts", 2 * count + 2, wp.int32, device)  # the kernel writes every slot
    no_leaves = wp.empty(0, dtype=wp.vec4i, device=device)
    launch_chunked(cube_kernels.count_node_leaves, count, [grid, params, use_geometric, error, no_leaves], [counts],
                   device)
    offsets, total = exclusive_offsets(counts, "globe.nodes")
    n_leaves = _host_int(offsets, count + 1)
    check_budget(n_leaves * 16 + (total - n_leaves) * 28, "the planar mesh", hint="raise the error")
    leaves = wp.empty(n_leaves, dtype=wp.vec4i, device=device)
    entries = wp.empty(total - n_leaves, dtype=wp.int32, device=device)
    launch_chunked(cube_kernels.emit_node_leaves, count, [grid, params, use_geometric, error, counts, offsets],
                   [leaves, entries], device)
    padding = None
    if (grid.rows_valid, grid.cols_valid) != (grid.n, grid.n):  # the padding's refined nodes, in the levels too
        threads = 64
        padding = wp.empty((threads, 32), dtype=wp.int32, device=device)
        launch(cube_kernels.count_padding_levels, threads,
               [grid.n, -(-grid.n // threads), grid, params, use_geometric, error], [padding], device)
    return leaves, entries, _planar_levels(entries, grid.cells, device, padding)


def _planar_levels(entries: wp.array, cells: int, device: wp.Device, padding: wp.array | None = None) -> list[int]:
    """Triangles per level of a planar refinement from its refined nodes (the new vertices): two roots, then
    two children per triangle of each refined node's diamond (the counts the breadth-first levels report);
    ``padding``: the counts of a padded input's refined nodes beyond its rectangle (``count_padding_levels``)."""
    rows = 64
    counts = wp.empty((rows, 32), dtype=wp.int32, device=device)
    launch(cube_kernels.count_levels, rows, [entries.shape[0], -(-entries.shape[0] // rows), cells, entries],
           [counts], device)
    totals = counts.numpy().sum(axis=0)
    if padding is not None:
        totals = totals + padding.numpy().sum(axis=0)
    per_level = [2, *totals[1:].tolist()]
    while per_level and per_level[-1] == 0:
        per_level.pop()
    return per_level


def _one_launch_bytes(capacity: int, track: bool, cull: bool) -> int:
    """Scratch bytes of :func:`_refine_levels`: two level halves of 2·capacity triangles (and masks), and 4·capacity
    leaves (and masks) and new vertices."""
    return 4 * capacity * (20 if track else 16) + 4 * capacity * (24 if track and cull else 20)


def _level_outputs(name: str, parts: int, capacity: int, levels: int, *, track: bool, cull: bool, marks: bool,
                   device: wp.Device) -> list[wp.array]:
    """Scratch outputs of ``parts`` ``refine_levels`` launches of ``capacity`` (a part each, in the kernel's
    order): level halves and their masks, leaves and their masks, new vertices, per-level sizes, totals and the
    runs' marks; masks untracked, leaf masks without culling and marks when not asked for are empty."""
    room = 4 * capacity

    def part(key: str, n: int, dtype: Any, used: bool = True) -> wp.array:
        return scratch(f"{name}.{key}", parts * n, dtype, device) if used else wp.empty(0, dtype=dtype, device=device)

    return [part("levels", 4 * capacity, wp.vec4i), part("masks", 4 * capacity, wp.int32, track),
            part("leaves", room, wp.vec4i), part("leaf_masks", room, wp.int32, track and cull),
            part("entries", room, wp.int32), part("sizes", levels + 1, wp.int32), part("totals", 6, wp.int32),
            part("marks", levels + 2, wp.vec2i, marks)]


def _refine_levels(grid: Any, params: Any, view: Any, roots: wp.array, levels: int, capacity: int, *,
                   track: bool, cull: bool, leaf_chunks: list[wp.array], vertex_chunks: list[wp.array],
                   mask_chunks: list[wp.array | None], per_level: list[int], device: wp.Device,
                   name: str = "globe.fused") -> tuple[wp.array, wp.array | None, int, int]:
    """The levels of at most ``capacity`` triangles from the roots, while their leaves and new vertices fit in
    4·capacity slots, in one launch (``refine_levels``): appends their leaves (with their corner masks when
    tracked and culling), new vertices and level sizes; returns the next level's triangles, their masks (None
    when not tracked), its depth, and how many of the leaves have no corner known inside the view."""
    room = 4 * capacity
    none = wp.zeros(0, dtype=wp.int32, device=device)
    outputs = _level_outputs(name, 1, capacity, levels, track=track, cull=cull, marks=False, device=device)
    halves, half_masks, leaves, leaf_masks, entries, sizes, totals, _ = outputs
    launch(cube_kernels.refine_levels, 1,
           [grid, params, view, roots, none, 0, roots.shape[0], 0, levels, capacity, room],  # all roots, part 0
           outputs, device)
    n_leaves, n_entries, n_next, depth, start, unknown = (int(v) for v in host_copy(totals))
    leaf_chunks.append(leaves[:n_leaves])
    vertex_chunks.append(entries[:n_entries])
    mask_chunks.append(leaf_masks[:n_leaves] if track and cull else None)
    per_level.extend(int(v) for v in host_copy(sizes)[:depth])
    return halves[start:start + n_next], half_masks[start:start + n_next] if track else None, depth, unknown


def _refine_in_ranges(grid: Any, params: Any, view: Any, roots: wp.array, corners: wp.array, levels: int, *,
                      track: bool, cull: bool, threads: int, device: wp.Device
                      ) -> tuple[wp.array, wp.array | None, wp.array, list[int], int] | None:
    """:func:`_refine_levels` from the roots to the last level on several CPU threads, the same mesh.

    A first launch takes the levels of up to :data:`_SPLIT_FIRST` triangles; the next level is cut into
    contiguous ranges (:data:`_RANGES_PER_THREAD` a thread, each thread taking the next range when done) and each
    range is refined to the end in a launch of its own, a range's subtrees giving one contiguous run of every
    later level (see ``refine_levels``). One copy pass then lays the runs out level by level, range by range: the
    order of one launch. Returns the leaves, their masks (tracked and culled, else None), the new vertices,
    triangles per level and how many leaves have no corner known inside the view; None when a range did not fit
    in its share of the one launch's scratch (the caller refines in one launch, and level passes, instead)."""
    leaf_chunks: list[wp.array] = []
    vertex_chunks: list[wp.array] = []
    mask_chunks: list[wp.array | None] = []
    per_level: list[int] = []
    frontier, frontier_masks, start, unknown = _refine_levels(
        grid, params, view, roots, levels, max(roots.shape[0], min(_SPLIT_FIRST, _SMALL_LEVELS)), track=track,
        cull=cull, leaf_chunks=leaf_chunks, vertex_chunks=vertex_chunks, mask_chunks=mask_chunks, per_level=per_level,
        device=device, name="globe.split.first")
    first_leaves, first_entries, first_masks = leaf_chunks[0], vertex_chunks[0], mask_chunks[0]
    n = frontier.shape[0]
    if n == 0:  # the first launch reached the end
        return first_leaves, first_masks, _concat([corners, first_entries], wp.int32, device), per_level, unknown
    ranges = min(threads * _RANGES_PER_THREAD, n)
    # the ranges' levels together up to twice the one launch's, and room for each range's roots (the kernel copies
    # them in unchecked)
    capacity = max(-(-n // ranges), 2 * _SMALL_LEVELS // ranges)
    room = 4 * capacity
    if ranges * _one_launch_bytes(capacity, track, cull) > get_memory_budget():
        return None
    depth = levels - start  # the ranges' deepest level, counted from the frontier
    none = wp.zeros(0, dtype=wp.int32, device=device)
    outputs = _level_outputs("globe.split", ranges, capacity, depth, track=track, cull=cull, marks=True,
                             device=device)  # part k of each: range k's
    _, _, leaves, leaf_masks, entries, sizes, totals, marks = outputs
    cuts = [n * k // ranges for k in range(ranges + 1)]
    masks_in = frontier_masks if track else none
    tasks = [([grid, params, view, frontier, masks_in, cuts[k], cuts[k + 1] - cuts[k], k, depth, capacity, room],
              outputs) for k in range(ranges)]
    launch_each(cube_kernels.refine_levels, tasks, device)
    totals_host = host_copy(totals).reshape(ranges, 6)
    if (totals_host[:, 2] != 0).any():  # a range stopped early (its share of the scratch was too small)
        return None
    n_first, n_corners = first_leaves.shape[0], corners.shape[0]
    n_leaves, n_entries = (int(v) for v in totals_host[:, :2].sum(axis=0))
    leaves_out = wp.empty(n_first + n_leaves, dtype=wp.vec4i, device=device)
    entries_out = wp.empty(n_corners + first_entries.shape[0] + n_entries, dtype=wp.int32, device=device)
    masks_out = wp.empty(n_first + n_leaves, dtype=wp.int32, device=device) if track and cull else none
    if n_first:
        wp.copy(leaves_out, first_leaves, count=n_first)
        if track and cull:
            wp.copy(masks_out, first_masks, count=n_first)
    wp.copy(entries_out, corners, count=n_corners)
    if first_entries.shape[0]:
        wp.copy(entries_out, first_entries, dest_offset=n_corners, count=first_entries.shape[0])
    launch(cube_kernels.copy_runs, 2 * ranges * (depth + 1),
           [ranges, depth + 2, room, n_first, n_corners + first_entries.shape[0], marks, leaves, leaf_masks, entries],
           [leaves_out, masks_out, entries_out], device, min_dim=8)
    deepest = int(totals_host[:, 3].max())
    per_level.extend(host_copy(sizes).reshape(ranges, depth + 1).sum(axis=0)[:deepest].tolist())
    unknown += int(totals_host[:, 5].sum())
    return leaves_out, masks_out if track and cull else None, entries_out, per_level, unknown


def _extract(grid: Any, params: Any, view: Any, users: list[UserMetric], levels: int, *, faces: int, cull: bool,
             per_face: bool, device: wp.Device, origin: tuple[float, float] = (0.0, 0.0)
             ) -> trimesh.Trimesh | list[trimesh.Trimesh]:
    """Breadth-first refinement, one count -> scan -> emit per level (on the CPU the levels up to
    :data:`_SMALL_LEVELS` triangles in one launch, :func:`_refine_levels`), then vertices and faces."""
    n = grid.n
    triangles, corners = _roots_and_corners(grid.cells, n, faces, str(device))
    no_factors = wp.zeros(0, dtype=wp.float32, device=device)
    leaf_chunks: list[wp.array] = []
    vertex_chunks = [corners]
    per_level = []
    host = (host_copy(grid.positions), host_copy(params.values)) if users else None
    flags = view.flags
    # with the clip metric, the triangles of large levels carry which of their corners are known to lie inside
    # the view (tested once, as refinement nodes, where their positions are loaded anyway): with culling a leaf
    # with such a corner skips the test. They also carry whether an ancestor's bounding shape lies wholly inside
    # the view: then so does their node's, and its clip test is skipped. Level passes track from _TRACK_MIN
    # triangles (below, two arrays a level cost more than the tests they would save); the CPU's one-launch levels
    # (_refine_levels) track from the roots on, in their own buffers.
    none = wp.zeros(0, dtype=wp.int32, device=device)
    masks: wp.array | None = None  # of the current level's triangles, while tracked
    mask_chunks: list[wp.array | None] = []
    if _NODE_PASS and faces == 1 and not users and flags[0] != 0 and flags[1] == 0 and flags[2] == 0 \
            and view.error > 0:
        # planar, no view: μ = e per node, so one count -> scan -> emit over the nodes gives the same leaves
        # and vertices as the breadth-first levels below (in another order), without a pass per level (without
        # the geometric metric μ = 1 everywhere: the levels below, which still refine a padded input's border)
        leaves, entries, per_level = _planar_leaves(grid, params, int(flags[0]), float(view.error), device)
        leaf_chunks.append(leaves)
        vertex_chunks.append(entries)
        levels = -1  # the loop below has nothing left to do
    first_depth = 0
    split = None
    unknown = -1  # leaves with no corner known inside the view, when one tracked launch made them all
    if device.is_cpu and not users and levels >= 0 and _SMALL_LEVELS >= triangles.shape[0] \
            and _one_launch_bytes(_SMALL_LEVELS, bool(flags[2]), cull) <= get_memory_budget():
        # (under a budget too small for its scratch, the level passes alone: each checks its own level's size)
        threads = get_cpu_threads()
        if threads > 1 and _SPLIT_FIRST > 0:
            split = _refine_in_ranges(grid, params, view, triangles, corners, levels, track=bool(flags[2]),
                                      cull=cull, threads=threads, device=device)
        if split is not None:
            leaves, leaf_masks, entries, per_level, unknown = split
            leaf_chunks.append(leaves)
            vertex_chunks = [entries]  # the corners first, in an array of its own
            mask_chunks.append(leaf_masks)
            first_depth = levels + 1  # nothing left for the level passes
        else:
            triangles, masks, first_depth, unknown = _refine_levels(
                grid, params, view, triangles, levels, _SMALL_LEVELS, track=bool(flags[2]), cull=cull,
                leaf_chunks=leaf_chunks, vertex_chunks=vertex_chunks, mask_chunks=mask_chunks, per_level=per_level,
                device=device)
    level_scratch = 0
    for depth in range(first_depth, levels + 1):
        count = triangles.shape[0]
        if count == 0:
            break
        counts = scratch("globe.refine.counts", 2 * count + 2, wp.int32, device)  # the kernel writes every slot
        factors = _user_factors(users, grid, host, triangles, device, origin) if users else no_factors
        track = bool(flags[2]) and count >= _TRACK_MIN
        # the pool keeps each pass's counts, offsets and inside flags (scratch), sized by the largest level
        level_scratch = max(level_scratch, 8 * (2 * count + 2) + (4 * count if track else 0))
        if track and masks is None:
            masks = wp.zeros(count, dtype=wp.int32, device=device)  # nothing known yet
        elif not track:
            masks = None
        inside = scratch("globe.refine.inside", count, wp.int32, device) if track else none
        launch_chunked(cube_kernels.count_refinement, count,
                       [grid, params, view, triangles, int(depth < levels), factors, masks if track else none],
                       [counts, inside], device, min_elements=_SPLIT_REFINE)
        offsets, total = exclusive_offsets(counts, "globe.refine")
        refined = _host_int(offsets, count + 1)
        owned = total - refined
        if depth < levels:  # the children are the next level (checked before anything of theirs is allocated)
            _check_int32(2 * refined, _MAX_LEVEL_TRIANGLES, f"refinement level {depth + 1}", "triangles",
                         "its counts and offsets")
        check_budget((2 * refined + count) * (20 if track else 16) + owned * 28, f"refinement level {depth}",
                     hint="raise the error or narrow the view")
        children = wp.empty(2 * refined, dtype=wp.vec4i, device=device)
        leaves = wp.empty(count - refined, dtype=wp.vec4i, device=device)
        entries = wp.empty(owned, dtype=wp.int32, device=device)
        child_masks = wp.empty(2 * refined, dtype=wp.int32, device=device) if track else none
        leaf_masks = wp.empty(count - refined, dtype=wp.int32, device=device) if track else none
        launch_chunked(cube_kernels.emit_refinement, count,
                       [grid, triangles, counts, offsets, none if masks is None else masks, inside],
                       [children, leaves, entries, child_masks, leaf_masks], device, min_elements=_SPLIT_EMIT)
        leaf_chunks.append(leaves)
        vertex_chunks.append(entries)
        mask_chunks.append(leaf_masks if track and cull else None)
        per_level.append(count)
        triangles, masks = children, (child_masks if track else None)
    # the mesh itself, before its arrays: each level was checked on its own, but the leaves of every level and the
    # vertices together (float64 vertices, int64 faces) outgrew a budget that every level fitted
    n_leaves = sum(chunk.shape[0] for chunk in leaf_chunks)
    n_vertices = vertex_chunks[0].shape[0] if split is not None else sum(c.shape[0] for c in vertex_chunks)
    _check_int32(n_leaves, _MAX_INT32 - 1, "the mesh", "faces", "its face counts and offsets")
    whole = len(leaf_chunks) == 1 and unknown >= 0  # every leaf from the one tracked launch
    counted_faces = not (faces > 1 and (not cull or (whole and unknown == 0)))  # a count of the faces kept
    # the mesh's arrays and what the passes below hold beside them: the leaves of every level (and their joined
    # copy), the joined vertex entries, the per-node vertex ids, the keep counts and offsets and the leaf masks (the
    # mesh's own arrays alone were counted: a 12.6 M-face mesh checked as 504 MiB peaked at 1.1 GiB)
    leaf_bytes = 16 * (1 + (sum(1 for chunk in leaf_chunks if chunk.shape[0]) > 1))
    if counted_faces:
        leaf_bytes += 8 + 4 * any(chunk is not None for chunk in mask_chunks)
    vertex_bytes = _MESH_VERTEX_BYTES + (4 if split is None else 0)
    held = n_leaves * leaf_bytes + 4 * faces * n * n + level_scratch  # beside the mesh's arrays, in both checks
    check_budget(n_vertices * vertex_bytes + n_leaves * _MESH_FACE_BYTES + held,
                 f"the mesh ({n_vertices:,} vertices, up to {n_leaves:,} faces)",
                 hint="raise the error or narrow the view")
    leaves = _concat(leaf_chunks, wp.vec4i, device, share=True)  # read by the face passes only
    # (the one-launch split's entries come whole, the corners first, in a fresh array: no copy)
    entries = vertex_chunks[0] if split is not None else _concat(vertex_chunks, wp.int32, device)
    vertex_id = scratch("globe.vertex_id", faces * n * n, wp.int32, device)
    if users:  # a user metric that grows from a node to its children can refine a triangle without the neighbour
        # that owns its refinement node, whose vertex is then never emitted: its faces read an unwritten vertex_id
        # (a segmentation fault, or faces on another call's vertices); marked -1 here, refused after emit_faces
        vertex_id.fill_(-1)
    vertices = wp.empty(n_vertices, dtype=wp.vec3d, device=device)
    launch_chunked(cube_kernels.emit_vertices, n_vertices, [grid, entries], [vertex_id, vertices], device,
                   min_elements=_SPLIT_REFINE)
    if not counted_faces:
        keep = offsets = none  # nothing to cull, no padding: every leaf is a face (emit_faces' "every")
        n_faces = n_leaves
    else:
        keep = count_buffer("globe.keep", n_leaves, device)
        leaf_masks = none
        if whole and mask_chunks[0] is not None:
            leaf_masks = mask_chunks[0]
        elif any(chunk is not None for chunk in mask_chunks):  # per leaf; 0 (nothing known) for untracked levels
            leaf_masks = wp.zeros(leaves.shape[0], dtype=wp.int32, device=device)
            offset = 0
            for leaf_chunk, chunk in zip(leaf_chunks, mask_chunks, strict=True):  # one of each per level
                if chunk is not None and chunk.shape[0]:
                    wp.copy(leaf_masks, chunk, dest_offset=offset, count=chunk.shape[0])
                offset += leaf_chunk.shape[0]
        launch_chunked(cube_kernels.count_kept_faces, n_leaves, [grid, view, int(cull), leaves, leaf_masks], [keep],
                       device)
        offsets, n_faces = exclusive_offsets(keep, "globe.keep")
    culled = n_faces < n_leaves
    if culled:  # the kept faces as int32, then remapped onto the vertices still used, then as int64 (trimesh's);
        # the used flags, their offsets and the used vertices and entries (no wide faces: those are the int64 ones)
        check_budget(n_vertices * (vertex_bytes + 8 + 28) + n_faces * (12 + 4 + 12 + 24) + held,
                     f"the mesh ({n_vertices:,} vertices before culling, {n_faces:,} faces kept of {n_leaves:,})",
                     hint="raise the error or narrow the view")
    # nothing culled: the kernel writes the final int64 faces (trimesh's dtype; on the CPU straight into numpy), not
    # int32 ones to convert (2 ms of a 200k-face view); culled, int32 faces are compacted below, then converted
    wide_host, wide = empty_shared((0 if culled else n_faces, 3), np.int64, vec3l, device)
    faces_out = wp.empty(n_faces if culled else 0, dtype=wp.vec3i, device=device)
    face_index = wp.empty(n_faces, dtype=wp.int32, device=device)
    launch_chunked(cube_kernels.emit_faces, n_leaves, [grid, leaves, keep, offsets, vertex_id],
                   [faces_out, wide, face_index], device, min_elements=_SPLIT_EMIT)
    if users:
        emitted = host_copy(faces_out if culled else wide)
        if emitted.size and int(emitted.min()) < 0:
            names = ", ".join(repr(getattr(fn, "__name__", fn)) for fn in users)
            raise InvalidInputError(
                f"user metric {names} is not saturated: it grows from a node to its children somewhere, so a triangle "
                "refined without its neighbour and left a mesh node without a vertex; a user metric must not grow "
                "as the bounding spheres shrink (decide by the whole sphere, points and bounding_radius)"
            )
        # the refined triangle that owns the new node emits its vertex: the check above passes, and its coarser
        # neighbour across the hypotenuse keeps that edge whole, a hanging node (a crack) returned without a word
        hanging = wp.zeros(1, dtype=wp.int32, device=device)
        launch_chunked(cube_kernels.count_hanging_edges, n_leaves, [grid.cells, grid.planar, leaves, vertex_id],
                       [hanging], device, atomics=True)
        split_edges = int(hanging.numpy()[0])
        if split_edges:
            names = ", ".join(repr(getattr(fn, "__name__", fn)) for fn in users)
            edges = counted(split_edges, "edge", grouped=True)
            raise InvalidInputError(
                f"user metric {names} is not saturated: it grows from a node to its children somewhere, so a triangle "
                f"refined without its neighbour: a hanging node (a crack) on {edges} of the mesh; a user metric must "
                "not grow as the bounding spheres shrink (decide by the whole sphere, points and bounding_radius)"
            )
    if culled:  # drop the vertices no face uses any more
        used = count_buffer("globe.used", n_vertices, device)
        used.zero_()  # the flags and count_buffer's final 0
        launch_chunked(compaction_kernels.mark_used_vertices, n_faces, [faces_out], [used], device)
        used_offsets, n_used = exclusive_offsets(used, "globe.used")
        kept_vertices = wp.empty(n_used, dtype=wp.vec3d, device=device)
        kept_entries = wp.empty(n_used, dtype=wp.int32, device=device)
        launch_chunked(cube_kernels.emit_used_vertices, n_vertices, [vertices, entries, used, used_offsets],
               [kept_vertices, kept_entries], device)
        remapped = wp.empty(n_faces, dtype=wp.vec3i, device=device)
        launch_chunked(compaction_kernels.remap_faces, n_faces, [faces_out, used_offsets], [remapped], device)
        vertices, entries, faces_out = kept_vertices, kept_entries, remapped
    v = host_copy(vertices).reshape(-1, 3)
    f = host_copy(faces_out).reshape(-1, 3).astype(np.int64) if culled else to_numpy(wide_host, wide, (n_faces, 3))
    cube_face = host_copy(face_index)
    node_entry = host_copy(entries)
    metadata = {"levels": per_level, "node_entry": node_entry, "face_size": n}
    mesh = trimesh.Trimesh(v, f, process=False, face_attributes={"cube_face": cube_face}, metadata=metadata)
    if per_face:
        return _split_faces(mesh, n, grid.cells)
    return mesh


def _split_faces(mesh: trimesh.Trimesh, n: int, cells: int) -> list[trimesh.Trimesh]:
    """One mesh per cube face with UV = face-local (j, i) / N (paper 003 §5.3: one texture per face), each with
    the whole mesh's ``face_attributes`` and metadata, ``node_entry`` cut to its own vertices, and the whole mesh's
    bounds as ``metadata["shared_bounds"]``: :func:`~stepterrain.export.save_mesh` stores the six alike by them, so
    that a seam vertex's copies in two files are stored identically (each glTF about its own centre rounded them
    apart, by up to 0.25 m on the Earth: cracks along the cube edges). Each records itself as made, its vertex and
    face counts and bounds, as ``metadata["whole_part"]``: save_mesh stores a part so recorded by the shared bounds
    (and the eye they hold) however little of its face culling left, and a piece cut from it, or one moved or scaled
    (trimesh copies the metadata), by its own bounds where the shared ones would round it coarser. The UVs come
    with a plain matte material, the whole mesh's as save_mesh writes it (white, metallic 0, roughness 1), and no
    image: trimesh's placeholder (a grey 2 x 2 texture, filled in for UVs given alone) was embedded in the files and
    drawn by the renders, the faces dark grey where the whole mesh is white."""
    out = []
    cube_face = np.asarray(mesh.face_attributes["cube_face"])
    entry = np.asarray(mesh.metadata["node_entry"], dtype=np.int64)
    points = _cube_points(entry, n, cells)
    vertices = np.asarray(mesh.vertices)
    shared = {"shared_bounds": [vertices.min(axis=0).tolist(), vertices.max(axis=0).tolist()]} if len(vertices) else {}
    # alike for all six (one name), each its own copy: trimesh.util.concatenate keeps one; six of different names it
    # packed into a texture atlas with transparent padding and grey texels (its colour for an unset base colour; a set
    # one, white, made save_mesh's OBJ keep trimesh's specular Ks 0.4 instead of the matte 0)
    material = {"name": "globe", "metallicFactor": 0.0, "roughnessFactor": 1.0, "doubleSided": True}
    all_faces = np.asarray(mesh.faces)
    for f, frame in enumerate(cube_kernels.FACE_FRAMES):
        on = cube_face == f
        faces = all_faces[on]
        used, local = np.unique(faces.reshape(-1), return_inverse=True)
        x = points[used] @ _axis(frame[0])
        y = points[used] @ _axis(frame[1])
        uv = np.column_stack([(x + cells) / (2.0 * cells), (y + cells) / (2.0 * cells)])
        visual = trimesh.visual.TextureVisuals(uv=uv, material=trimesh.visual.material.PBRMaterial(**material))
        metadata = {**mesh.metadata, "node_entry": entry[used].astype(np.int32), "cube_face": f, **shared}
        part = vertices[used]
        if len(used):  # the part as made: save_mesh keeps the shared frame for it, however small culling left it
            metadata["whole_part"] = {"vertices": len(used), "faces": len(faces),
                                      "bounds": [part.min(axis=0).tolist(), part.max(axis=0).tolist()]}
        out.append(trimesh.Trimesh(part, local.reshape(-1, 3), process=False, visual=visual,
                                   metadata=metadata, face_attributes={"cube_face": cube_face[on]}))
    return out


def _cube_points(entry: NDArray[np.int64], n: int, cells: int) -> NDArray[np.int64]:
    """Integer cube points of entries (vectorised twin of ``cubesphere.cube_point`` for in-face nodes)."""
    nn = n * n
    face = entry // nn
    i = (entry - face * nn) // n
    j = (entry - face * nn) % n
    frames = np.array([[_axis(c) for c in frame] for frame in cube_kernels.FACE_FRAMES])  # (6, 3, 3)
    local = np.stack([2 * j - cells, 2 * i - cells, np.full_like(i, cells)], axis=1)
    return np.einsum("nk,nkd->nd", local, frames[face])


# ------------------------------------------------------------------------------------------ planar case
def adaptive_mesh(
    heights: ArrayLike | Terrain,
    *,
    error: float,
    spacing: float | tuple[float, float] | None = None,
    camera: Camera | None = None,
    origin: tuple[float, float] | None = None,
    metrics: Sequence[str | UserMetric] = METRICS,
    distance_scale: float | None = None,
    cull: bool = True,
    device: wp.DeviceLike = None,
) -> trimesh.Trimesh:
    """An adaptive RTIN / SOAR mesh of one heightfield: the hierarchy of paper 003 in the plane.

    Parameters
    ----------
    heights : (H, W) array_like or Terrain
        Heights in metres; row i at y = y0 + i·dy, column j at x = x0 + j·dx. Any size up to 16385 rows and
        columns: padded internally to (2^k + 1)² by repeating the edge, and the mesh is cut back to the input
        rectangle exactly. The padding is neither measured nor refined but where it meets the input's border, so
        a rectangle takes about the time its own nodes take (the memory budget still counts the padded square). A
        grid :class:`~stepterrain.Terrain` (``load_dem``'s) brings its own spacing and origin (a north-up DEM as
        it is: dy < 0, origin its north-west node).
    error : float
        Without a camera: the largest vertical distance allowed between any grid node and the mesh (a
        true bound, checked per triangle over every node it covers, not the 1-level look-ahead). With a
        camera: see :meth:`Globe.mesh` (spheres only).
    spacing : float or (dx, dy)
        Node spacing (default 1); either may be negative, as a north-up DEM's dy (rows running north to south):
        the vertices lie at the same positions as :func:`~stepterrain.heightfield_mesh`'s, the faces stay
        counter-clockwise seen from +z.
    camera : Camera, optional
        Eye and frustum in the mesh's coordinates (origin included). An eye over the grid's rectangle must lie
        above the terrain surface there (the heights interpolated under it); beside the rectangle, anywhere.
    origin : (x0, y0)
        Position of node (0, 0) (default (0, 0)).
    metrics, cull, device
        As for :meth:`Globe.mesh`; a user metric's points are in the mesh's coordinates (origin included), as the
        camera's.
    distance_scale : float, optional
        ℓ for the distance metric; default: the eye's height above the highest node, at least one spacing. Only
        with a camera and the distance metric (refused otherwise: it would change nothing).

    Returns
    -------
    trimesh.Trimesh
        Welded, counter-clockwise seen from +z, vertices at grid nodes;
        ``metadata["node_index"]`` gives each vertex's (row, column); a Terrain's CRS and source are its
        ``metadata["crs"]`` and ``["source"]``, as :func:`~stepterrain.stepped` records them.

    Raises
    ------
    InvalidInputError
        Not a real (H, W) array with H, W >= 2 (or a TIN Terrain), NaN, infinite or masked heights, bad spacing, an
        origin so far from zero for the spacing that float64 cannot keep the nodes apart, spacing or origin with a
        Terrain, negative error, a camera eye at or below the terrain surface, metrics of 'distance' or 'clip' alone
        without a camera.

    Examples
    --------
    >>> import numpy as np
    >>> z = np.add.outer(np.arange(9.0), np.arange(9.0))   # a plane: two triangles suffice
    >>> len(adaptive_mesh(z, error=0.01, device="cpu").faces)
    2
    """
    error = _error_value(error)
    cull = check_flag(cull, "cull")
    names, users = _metric_options(metrics, "sphere", planar=True)
    if isinstance(heights, Terrain):
        if heights.kind != "grid":
            raise InvalidInputError("heights must be an (H, W) array or a grid Terrain; got a TIN Terrain (the "
                                    "hierarchy needs a regular grid)")
        if spacing is not None or origin is not None:
            raise InvalidInputError("spacing/origin apply to raw (H, W) arrays only; the Terrain already has them")
        placed = {key: value for key, value in (("crs", heights.crs), ("source", heights.source)) if value}
        heights, spacing, origin = heights.heights, heights.spacing, heights.origin
    else:
        placed = {}
    z = _height_grid(heights, "heights")
    spacing = 1.0 if spacing is None else spacing
    origin = (0.0, 0.0) if origin is None else origin
    try:
        # one number: a 0-d array too (an .npz's np.load(...)["dx"], which heightfield_mesh takes; tuple() refused it)
        single = np.isscalar(spacing) or (isinstance(spacing, np.ndarray) and spacing.ndim == 0
                                          and is_real_dtype(spacing.dtype))
        dx, dy = (spacing, spacing) if single else tuple(spacing)  # type: ignore[misc]
    except (TypeError, ValueError):
        raise InvalidInputError(f"spacing must be a number or (dx, dy); got {spacing!r}") from None
    dx, dy = check_spacing(_nonzero(dx, "spacing dx"), _nonzero(dy, "spacing dy"))
    try:  # as_number: "12" was iterated as (1.0, 2.0) and True taken as 1.0
        ox, oy = (as_number(v) for v in origin)
    except (TypeError, ValueError):
        ox = oy = math.nan
    if not (math.isfinite(ox) and math.isfinite(oy)):
        raise InvalidInputError(f"origin must be 2 finite numbers (x0, y0); got {origin!r}")
    rows, cols = z.shape
    # the vertices are the nodes relative to the origin plus the origin, in float64: origin (1e20, 0) with spacing 1
    # put every column on one x, a mesh of zero area without a word, as a Terrain's grid would be but for this check
    check_origin((ox, oy), (dx, dy), z.shape)
    # a negative spacing (a north-up DEM's dy): the grid mirrored onto a positive one with the same nodes, its
    # origin the node at the low end (row i at y0 + i·dy is row rows-1-i of the mirror), meshed as that one, and
    # the vertices put back where the given grid has them; the mirror's faces are counter-clockwise seen from +z
    flip_x, flip_y = dx < 0, dy < 0
    user_origin = (ox, oy)
    if flip_x:
        z, ox, dx = z[:, ::-1], ox + (cols - 1) * dx, -dx
    if flip_y:
        z, oy, dy = z[::-1], oy + (rows - 1) * dy, -dy
    cells = 1 << max(1, math.ceil(math.log2(max(rows, cols) - 1)))
    if cells > _MAX_CELLS:  # before the padding: 32768 << 16 wraps the int32 packed corners
        raise InvalidInputError(f"heights must have at most {_MAX_CELLS + 1} rows and columns (padded to 2^k + 1 "
                                f"nodes, int32 packed corners); got shape {z.shape}")
    n = cells + 1
    check_budget(n * n * _BYTES_PER_ENTRY, f"an adaptive mesh of a {rows}x{cols} grid (padded to {n}x{n})",
                 hint="crop or coarsen the input (Terrain.crop, Terrain.coarsen)")
    highest = float(z.max()) if camera is not None else 0.0  # of the unpadded grid (the padding repeats its edges)
    if camera is not None:
        if not isinstance(camera, Camera):
            raise InvalidInputError(f"camera must be a stepterrain.globe.Camera; got {type(camera).__name__}")
        _check_planar_eye(camera.eye, z, (dx, dy), (ox, oy), highest)
        camera = dataclasses.replace(camera, eye=tuple(np.subtract(camera.eye, (ox, oy, 0.0))),
                                     target=tuple(np.subtract(camera.target, (ox, oy, 0.0))))
    device = resolve_device(device)
    _check_view_metrics(names, users, camera)
    _check_distance_scale(distance_scale, camera, names)  # before the grid's passes, as Globe.mesh checks it
    if distance_scale is None:
        above = camera.eye[2] - highest if camera is not None else 0.0
        distance_scale = max(above, dx, dy)
    distance_scale = _positive(distance_scale, "distance_scale")
    # without a view (no camera, or neither the distance nor the clip metric) and without user metrics, the
    # refinement reads e alone: the node positions and the bounding radii are not computed
    viewed = camera is not None and bool(names & {"distance", "clip"})
    shapes = bool(users) or viewed or error == 0.0
    grid = _planar_grid(z, (dx, dy), (rows, cols), shapes=shapes, device=device, n=n)
    levels = 2 * int(round(math.log2(cells)))
    params = _node_parameters(grid, faces=1, levels=levels, device=device, shapes=shapes)
    view = _view(camera, error, names, "sphere", distance_scale, device)
    mesh = _extract(grid, params, view, users, levels, faces=1,
                    cull=bool(cull and camera is not None and "clip" in names), per_face=False, device=device,
                    origin=(ox, oy))
    assert isinstance(mesh, trimesh.Trimesh)
    entry = np.asarray(mesh.metadata.pop("node_entry"))
    row, col = entry // n, entry % n
    if flip_y:
        row = rows - 1 - row
    if flip_x:
        col = cols - 1 - col
    mesh.metadata["node_index"] = np.column_stack([row, col])
    mesh.metadata.update(placed)  # a Terrain's CRS and source, as stepped's mesh records them (save_mesh writes them)
    mesh.face_attributes.pop("cube_face", None)
    if ox or oy:
        mesh.vertices = mesh.vertices + np.array([ox, oy, 0.0])
    if flip_x or flip_y:  # heightfield_mesh's x0 + j·dx, y0 + i·dy: not the mirror's, one rounding away
        vertices = np.array(mesh.vertices)
        if flip_x:
            vertices[:, 0] = user_origin[0] + col * -dx
        if flip_y:
            vertices[:, 1] = user_origin[1] + row * -dy
        mesh.vertices = vertices
    return mesh


# ------------------------------------------------------------------------------------------ colours
def elevation_colors(elevation: ArrayLike) -> NDArray[np.uint8]:
    """(V, 4) uint8 RGBA per vertex: sea floor in blues by depth, land by matplotlib's 'terrain' (land part);
    NaN (and a masked array's masked entries) transparent (0, 0, 0, 0).

    Examples
    --------
    >>> elevation_colors([-4000.0, 0.0, 3000.0]).shape
    (3, 4)
    """
    import matplotlib

    z = real_numbers(elevation, "elevation", "a (V,) array of heights in metres")
    if z.ndim != 1:
        raise InvalidInputError(f"elevation must be a (V,) array of heights in metres (one per vertex); got shape "
                                f"{z.shape}")
    rgba = np.empty((len(z), 4), dtype=np.float64)
    sea = z < 0
    rgba[sea] = matplotlib.colormaps["Blues"](np.clip(0.85 - 0.5 * (-z[sea] / 6000.0), 0.3, 0.85) ** 0.9)
    land = LAND_START["terrain"]  # its land part (the first quarter is sea blue)
    rgba[~sea] = matplotlib.colormaps["terrain"](land + (1.0 - land) * np.clip(z[~sea] / 5000.0, 0.0, 1.0))
    return np.round(rgba * 255).astype(np.uint8)


def _texture_pixels(image: ArrayLike | str) -> NDArray[np.uint8]:
    """An (H, W, 3|4) uint8 image from a path (16-bit greyscale files too, and a file's alpha band or transparent
    colour as (H, W, 4): :func:`~stepterrain.io.picture_uint8`) or an array."""
    return _texture_image(image)[0]


def _texture_image(image: ArrayLike | str) -> tuple[NDArray[np.uint8], Any, _Placement | None]:
    """:func:`_texture_pixels`' image, the PIL image a drape embeds as it is (:func:`_drape_texture`): that of a
    path to a JPEG file used as is (:func:`_kept_jpeg`), whose own bytes :func:`~stepterrain.export.save_mesh` then
    embeds (the 3840 x 1920 Blue Marble, 4.7 MB, was a 14.7 MB PNG in the GLB); else None (the pixels are
    embedded, as PNG), and where a georeferenced file's pixels lie (:func:`_plate_carree_placement`; None for an
    array or a file without georeferencing: plate carrée from 180° W)."""
    kept = placement = None
    if isinstance(image, (str, bytes)) or hasattr(image, "__fspath__"):
        import os
        from pathlib import Path

        from PIL import Image

        try:
            try:
                picture = Image.open(image)  # type: ignore[arg-type]
            except ValueError as exc:  # Pillow's header parsers: a PPM cut short, "Reached EOF while reading header"
                raise OSError(str(exc)) from exc  # a traceback: worded below as the file's other errors are
            except Image.DecompressionBombError as exc:  # not an OSError either: the full 21600 x 10800 Blue Marble
                raise OSError(f"{exc} (Pillow's decompression-bomb limit, PIL.Image.MAX_IMAGE_PIXELS): downsample "
                              "it, or raise that limit") from exc
            try:
                from .texture_lod import _tiff_as_stored

                _tiff_as_stored(picture)  # its stored pixels, as a PNG's or JPEG's: Pillow turns a TIFF by its tag
                placement = _plate_carree_placement(picture, image)  # from its header: refused before its pixels
                # its (H, W, 3|4) pixels against the memory budget, from the header, as texture_lod checks an image
                # before decoding it: a texture was decoded whole whatever the budget (--memory-budget 10MB decoded
                # an 8000 x 4000 JPEG, 96 MB of pixels, 500 MB peak with the drape)
                alpha = "A" in picture.getbands() or "transparency" in picture.info
                _check_read_budget(Path(os.fsdecode(image)), (4 if alpha else 3, picture.height, picture.width),
                                   np.dtype(np.uint8), "the texture",
                                   hint="downsample it first (resampled to fewer pixels)")
                if _kept_jpeg(picture):
                    picture.load()  # its pixels, and Pillow closes the file it opened
                    kept, image = picture, np.asarray(picture)
                else:
                    image = picture_uint8(picture, f"texture {str(image)!r}", alpha=True)
            finally:
                if kept is None:
                    picture.close()
        except OSError as exc:
            raise DataFileError(f"cannot read texture {image!r}: {exc}") from exc
        if placement is not None and placement.closing:  # a node-registered image's last column: its first's
            # meridian again. Kept, the two copies lay side by side in the texture (at Greenwich for a 0..360 one,
            # across the antimeridian for a -180..180 one), and the faces across them spanned a column more than
            # their longitudes; the first is kept (as Globe.from_latlon drops a grid's closing column)
            image, kept = np.asarray(image)[:, :-1], None
            placement = placement.without_closing_column()
        if placement is not None and placement.shift:  # a global GeoTIFF in longitudes 0..360: its columns put at
            # -180..180, as the drape reads them (to the nearest whole column; the UVs and colours take the rest)
            image, kept = np.roll(np.asarray(image), placement.shift, axis=1), None
    pixels = np.asarray(image)
    if pixels.ndim != 3 or pixels.shape[2] not in (3, 4) or min(pixels.shape[:2]) < 2:
        raise InvalidInputError(f"texture must be an (H, W, 3|4) image of at least 2 x 2 pixels; got shape "
                                f"{pixels.shape}")
    if pixels.dtype != np.uint8:
        if pixels.dtype.kind not in "fiu" or not np.isfinite(pixels).all() or pixels.min() < 0 or pixels.max() > 255:
            raise InvalidInputError(f"texture values must lie in [0, 255] (or [0, 1] floats); got dtype {pixels.dtype}")
        scale = 255.0 if pixels.dtype.kind == "f" and pixels.max() <= 1.0 else 1.0
        pixels = np.round(pixels.astype(np.float64) * scale).astype(np.uint8)
    return pixels, kept, placement


@dataclasses.dataclass(frozen=True)
class _Placement:
    """Where the pixels of a global texture file lie, from its georeferencing (:func:`_plate_carree_placement`):
    its columns rolled by ``shift`` (:func:`_texture_image`: the nearest whole column to 180° W first), and its
    original column 0's west edge at longitude ``west`` (the turn's nearest to 180° W), its row 0's north edge at
    latitude ``north``, its pixels ``sx`` by ``sy`` degrees, ``width`` x ``height`` of them. The image need not start
    at a whole column from 180° W, nor span exactly 360 x 180 degrees (a node-registered 361 x 181 one, its pixel
    centres on whole degrees, spans 361 x 181, until its closing column is dropped, :attr:`closing`): :meth:`columns`
    and :meth:`rows` put each pixel's centre where the georeferencing says, for the UVs (:func:`_drape_texture`) and
    the colours (:func:`drape_colors`) alike."""

    shift: int
    west: float
    north: float
    sx: float
    sy: float
    width: int
    height: int

    @property
    def closing(self) -> bool:
        """Whether the last column repeats the first's meridian, its centre a turn east of the first's (a
        node-registered image: 361 columns of 1° over 0..360 or -180..180), within float32's resolution of the UVs;
        :func:`_texture_image` drops it (:meth:`without_closing_column`)."""
        return self.width > 2 and abs(360.0 / self.sx - (self.width - 1)) <= self.width * 2.0**-24

    def without_closing_column(self) -> _Placement:
        """This placement of the image without its last column (:attr:`closing`): ``width`` - 1 columns in a turn,
        rolled by the nearest whole one to 180° W of those."""
        width = self.width - 1
        return dataclasses.replace(self, shift=round((self.west + 180.0) / self.sx) % width, width=width)

    @property
    def whole_columns(self) -> bool:
        """Whether the columns are plate carrée from 180° W (``shift`` whole columns of exactly 360° / ``width``),
        within float32's resolution of the UVs: a drape reads them as it reads a texture without georeferencing,
        bit for bit (the Blue Marble's GeoTIFF, a 0..360 one of even width)."""
        start = (self.west + 180.0) / self.sx
        return abs(start - round(start)) + abs(360.0 / self.sx - self.width) <= self.width * 2.0**-24

    @property
    def whole_rows(self) -> bool:
        """Whether the rows span 90° N to 90° S exactly (within float32's resolution of the UVs), as
        :attr:`whole_columns` for the columns."""
        return abs(90.0 - self.north) / self.sy + abs(180.0 / self.sy - self.height) <= self.height * 2.0**-24

    def columns(self, lon: NDArray[np.float64]) -> NDArray[np.float64]:
        """The rolled image's column coordinate (pixel edges: column j spans [j, j + 1), its centre j + 0.5) of
        longitudes ``lon`` in [-180, 180], near (``lon`` + 180) / 360 · ``width`` (within a few pixels: a seam's
        copy takes it + ``width``, :func:`_drape_texture`) and continuous over the globe but where the image's own
        edges meet, modulo ``width`` exact (a texture repeats in u): the georeferencing's column wrapped into
        one turn from column 0's centre; between the last column's centre and the first's a turn on (a gap, where
        the image spans less than 360°) the coordinate runs from the one to the other, as a sampler that repeats
        the image blends them; where it spans more by over a column, a longitude in both ends takes the image's
        first columns from column 0's centre on and its last ones west of there (each blend between neighbours in
        the image), the jump lying 5e-7 pixel west of column 0's centre: a pixel centre within a turn east of
        column 0's (by over 1e-6 pixel; one within that is column 0's meridian again) takes its own column,
        whatever the rounding of its longitude (the jump lay at column 0's centre itself: rounded a hair west,
        column 0's centre took the other copy's blend, a 5-pixel image of 3.625 pixels a turn). A node-registered
        image's overlap, a whole column, is dropped before: :attr:`closing`."""
        width = self.width
        period = 360.0 / self.sx  # pixels in a turn
        start = round((self.west + 180.0) / self.sx)  # its original column 0's in the turn's columns (shift mod W)
        q = (np.asarray(lon, dtype=np.float64) - self.west) / self.sx - 0.5  # from column 0's centre, in pixels
        gap = period - (width - 1)  # pixels of longitude from the last column's centre to the first's a turn on
        # the overlap's jump, a hair west of column 0's centre; where the image spans less, at that centre: the blend
        # across the gap reaches column 0's centre there, so the coordinate is continuous either side
        jump = -5e-7 if gap < 0 else 0.0
        turns = np.floor((q - jump) / period)
        q = q - turns * period  # within one turn of the jump: [jump, jump + period)
        if gap > 0:
            beyond = q > width - 1
            q = np.where(beyond, (width - 1) + (q - (width - 1)) / gap, q)
        return q + 0.5 + start + turns * width

    def rows(self, lat: NDArray[np.float64]) -> NDArray[np.float64]:
        """The row coordinate (pixel edges: row i spans [i, i + 1), its centre i + 0.5) of latitudes ``lat``,
        unclamped (a pole beyond the image's edge lies above row 0 or below row H)."""
        return (self.north - np.asarray(lat, dtype=np.float64)) / self.sy


def _plate_carree_placement(picture: Any, path: Any) -> _Placement | None:
    """Where a texture file's pixels lie (:class:`_Placement`: the columns to roll it by so that its column 0 starts
    at 180° W, to the nearest whole column, as the drape reads every texture, and the rest of its georeferencing),
    from its georeferencing: a GeoTIFF's tags (ModelPixelScale 33550 and ModelTiepoint 33922, or
    ModelTransformation 34264; GTModelTypeGeoKey and GTRasterTypeGeoKey in the GeoKeyDirectory 34735), GDAL's PAM
    file beside it (``earth.png.aux.xml``: its GeoTransform and SRS, where ``gdal_translate -of PNG`` or ``-of
    JPEG`` puts them), or a world file beside it (``.jgw``/``.pgw``/``.tfw``, ``.jpgw``..., ``.wld``; its CRS from
    a ``.prj``), as GDAL reads them (the PAM file first, then a GeoTIFF's tags, then the world file). Read from
    ``picture``'s header (a PIL image opened, not decoded) and the small files beside ``path``: no pixels, and no
    rasterio (the optional ``[geo]`` extra). None for an image without georeferencing (plate carrée from 180° W, as
    documented); a global one in longitudes 0..360 (or from any column) is rolled by the nearest whole column, and
    one whose west edge lies a fraction of a pixel from there (an odd width over 0..360, a node-registered image's
    half pixel), or that spans not quite 360 x 180 degrees (a node-registered 361 x 181 one), is placed by its UVs
    and colours (:meth:`_Placement.columns`, :meth:`_Placement.rows`): each pixel's centre where its
    georeferencing puts it. One whose georeferencing is no whole globe in degrees is refused before its pixels are
    read: a projected CRS, a regional extent (a DEM, an orthophoto), a rotated or south-up grid; each was draped over
    the whole globe from 180° W, without a word (a UTM orthophoto wrapped round the earth)."""
    import os
    import pathlib

    name = f"texture {str(path)!r}"
    image = pathlib.Path(os.fsdecode(path))
    root = _pam_root(image)  # read once: its GeoTransform, and its SRS for a world file's CRS
    tags = _geotiff_transform(picture) if getattr(picture, "format", None) == "TIFF" else None
    found = _aux_xml_transform(image, root)  # GDAL's PAM file first, before a GeoTIFF's tags too (GDAL_GEOREF_SOURCES)
    if found is not None and tags is not None:  # projected by its PAM file's SRS, .prj or tags: refused alike
        found = (found[0], found[1] or tags[1], found[2])
    if found is None:
        found = tags
    if found is None:
        found = _world_file_transform(image, root)
    if found is None:
        return None
    (a, b, west, d, e, north), projected, source = found
    if not all(map(math.isfinite, found[0])):  # GDAL reads a PAM file's or a GeoTIFF's NaN and inf as they are: the
        # west edge's round() raised Python's ValueError / OverflowError, and a NaN north edge passed the extent tests
        raise InvalidInputError(f"{name} must be georeferenced by finite numbers; got {source} with its upper-left "
                                f"corner at ({west:.6g}, {north:.6g}), pixel size ({a:.6g}, {e:.6g}) and rotation "
                                f"({b:.6g}, {d:.6g})")
    if projected:
        raise InvalidInputError(f"{name} must be a global plate-carrée image (longitude and latitude in degrees); got "
                                f"{source} in a projected CRS: reproject it first (`gdalwarp -dstalpha -t_srs "
                                "EPSG:4326 -te -180 -90 180 90 ...`)")
    width, height = picture.size
    if not (a > 0 and e < 0 and b == 0 and d == 0):
        raise InvalidInputError(f"{name} must be a global plate-carrée image, north-up (row 0 at 90N); got {source} "
                                f"with pixel size ({a:.6g}, {e:.6g}) and rotation ({b:.6g}, {d:.6g})")
    sx, sy = a, -e
    east, south = west + width * sx, north - height * sy
    # 1.5 pixels of slack either way (a node-registered image's extent lies half a pixel beyond the globe's each
    # way): each pixel is placed where its georeferencing says (_Placement), not stretched over 360 x 180 degrees
    if abs((east - west) - 360.0) > 1.5 * sx or abs((north - south) - 180.0) > 1.5 * sy or abs(north - 90) > 1.5 * sy:
        raise InvalidInputError(
            f"{name} must be a global plate-carrée image (360 x 180 degrees, row 0 at 90N); got {source} over "
            f"longitudes {west:.6g} to {east:.6g} and latitudes {south:.6g} to {north:.6g}: a regional image drapes "
            "a DEM of its region (`stepterrain texture DEM --image IMAGE`, st.texture_lod.image_layer)")
    # the turn's west edge nearest 180 W (a -180.5 one's, a node-registered image's, is not rolled by 359 columns)
    west -= 360.0 * round((west + 180.0) / 360.0)
    # rolled by the nearest whole column (an odd-width 0..360 image's 180 W is half-way); the UVs take the rest
    return _Placement(round((west + 180.0) / sx) % width, west, north, sx, sy, width, height)


def _geotiff_transform(picture: Any) -> tuple[tuple[float, ...], bool, str] | None:
    """A GeoTIFF's (a, b, c, d, e, f) geotransform (x = c + a·col + b·row, y = f + d·col + e·row at pixel corners),
    whether its GTModelTypeGeoKey says projected (1; 3, geocentric, alike: no degrees), and "a GeoTIFF"; None for
    a TIFF without a geotransform. A PixelIsPoint raster's tiepoint is a pixel's centre: moved to its corner, as
    GDAL does."""
    tags = picture.tag_v2
    keys = tags.get(34735)  # GeoKeyDirectory: (version, revision, minor, count, then key, location, count, value)
    geokeys = {}
    if isinstance(keys, tuple) and len(keys) >= 4:
        for k in range(4, len(keys) - 3, 4):
            if keys[k + 1] == 0:  # its value inline
                geokeys[keys[k]] = keys[k + 3]
    matrix, scale, tie = tags.get(34264), tags.get(33550), tags.get(33922)
    if isinstance(matrix, tuple) and len(matrix) >= 8:
        a, b, c, d, e, f = (float(matrix[i]) for i in (0, 1, 3, 4, 5, 7))
    elif isinstance(scale, tuple) and isinstance(tie, tuple) and len(scale) >= 2 and len(tie) >= 6:
        a, e = float(scale[0]), -float(scale[1])
        i, j, _, x, y, _ = (float(v) for v in tie[:6])
        b = d = 0.0
        c, f = x - i * a, y - j * e
    else:
        return None
    if geokeys.get(1025) == 2:  # GTRasterTypeGeoKey RasterPixelIsPoint
        c, f = c - (a + b) / 2, f - (d + e) / 2
    return (a, b, c, d, e, f), geokeys.get(1024) in (1, 3), "a GeoTIFF"


def _projected_beside(image: Any, root: Any) -> bool:
    """Whether the CRS of the image path ``image`` is projected: the ``SRS`` of its PAM file (``root``, parsed by
    :func:`~stepterrain.io._pam_root`), else the ``.prj`` io reads beside it (``ortho.prj``, ``ortho.PRJ``,
    ``ortho.jpg.prj``)."""
    srs = (root.findtext("SRS") or "").strip() if root is not None else ""
    if not srs:
        try:
            prj_file = _prj_beside(image)
            srs = "" if prj_file is None else prj_file.read_text(errors="replace")
        except (OSError, ValueError):
            srs = ""
    return srs.lstrip().upper().startswith(("PROJCS", "PROJCRS", "PROJECTEDCRS"))


def _aux_xml_transform(image: Any, root: Any) -> tuple[tuple[float, ...], bool, str] | None:
    """The geotransform in GDAL's PAM file ``root`` beside the image path ``image`` (``earth.png.aux.xml``, parsed by
    :func:`~stepterrain.io._pam_root`: its ``GeoTransform``, the six numbers c, a, b, f, d, e of the upper-left pixel's
    corner, as (a, b, c, d, e, f)), whether its ``SRS`` (else the ``.prj`` beside the image) names a projected CRS,
    and "a PAM file 'earth.png.aux.xml'"; None without one, or
    with one GDAL reads no geotransform from (none, not six numbers, or the identity, GDAL's default). A PNG or JPEG
    that GDAL wrote keeps its georeferencing there alone (no world file): a regional or projected one, or a global
    one in longitudes 0..360, was draped round the globe from 180° W, without a word."""
    text = root.findtext("GeoTransform") if root is not None else None
    try:
        c, a, b, f, d, e = (float(v) for v in (text or "").split(","))
    except ValueError:  # none, or not six numbers
        return None
    if (c, a, b, f, d, e) == (0.0, 1.0, 0.0, 0.0, 0.0, 1.0):  # GDAL's default geotransform: no georeferencing
        return None
    return (a, b, c, d, e, f), _projected_beside(image, root), f"a PAM file {image.name + '.aux.xml'!r}"


def _world_file_transform(image: Any, root: Any) -> tuple[tuple[float, ...], bool, str] | None:
    """The geotransform of the world file beside the image path ``image`` (:func:`~stepterrain.io.world_file`: the names
    GDAL looks for, ``.jgw`` for ``.jpg``, ``.jpgw``, ``.wld``; six numbers A, D, B, E, C, F, C and F at the
    upper-left pixel's centre), whether the ``SRS`` of the PAM file beside it (``ortho.png.aux.xml``, where
    ``gdal_translate -co WORLDFILE=YES`` writes it), else its ``.prj``, names a projected CRS, and the world file's
    name; None without one (or one that is not six numbers: GDAL ignores it too). (The PAM file's CRS was not read: a
    UTM image's world file was refused as one "over longitudes 376000 to 376360".) ``root``: the PAM file, as
    :func:`~stepterrain.io._pam_root` parsed it."""
    found = world_file(image)
    if found is None:
        return None
    (a, d, b, e, c, f), side = found
    projected = _projected_beside(image, root)
    corner = (a, b, c - (a + b) / 2, d, e, f - (d + e) / 2)  # the upper-left pixel's corner
    return corner, projected, f"a world file {side.name!r}"


def _kept_jpeg(picture: Any) -> bool:
    """Whether a drape embeds ``picture`` (a PIL image opened from a file, not yet decoded) as it is: an RGB JPEG
    (:func:`_texture_pixels` decodes it to its own pixels; a drape changes none, the antimeridian wraps by UVs past
    1) with no EXIF turn (its stored pixels are the texture; a viewer would turn the file's JPEG upright). A greyscale
    or CMYK JPEG, converted to RGB, and any other format are embedded as their pixels (PNG)."""
    return bool(picture.format == "JPEG" and picture.mode == "RGB" and picture.getexif().get(0x0112, 1) == 1)


def drape_texture(mesh: trimesh.Trimesh, image: ArrayLike | str) -> trimesh.Trimesh:
    """A copy of a globe mesh textured with a global plate-carrée image (paper 003 §5.3: a global texture
    draped by latitude and longitude), for GLB/glTF/OBJ export with the image embedded: the path of an RGB JPEG
    embeds the file's own bytes (the image is used as it is: see :func:`~stepterrain.export.save_mesh`'s Notes),
    any other image its pixels, as PNG (its alpha kept: an (H, W, 4) array's, a file's alpha band or transparent
    colour; the GLB/glTF/OBJ and a render give its transparent texels the colour of the opaque ones near them, see
    :func:`~stepterrain.io.fill_transparent`).

    Each vertex gets u = (λ + 180°) / 360°, v = (φ + 90°) / 180° from its direction (row 0 of the image at
    90° N, column 0 at 180° W; v up, as trimesh stores UVs). A file georeferenced as the whole globe in degrees is
    placed by it (:func:`drape_colors`): the UVs put each pixel's centre at the latitude and longitude its
    georeferencing gives, one off whole columns from 180° W too (an odd-width image over 0..360: its columns rolled
    by the nearest whole one, u offset by the rest) or not over exactly 360 x 180 degrees (a node-registered
    361 x 181 image, its pixel centres on whole degrees: v clamped to [0, 1] beyond its edge rows; its last column,
    the first's meridian again, is dropped, so that the embedded image holds each meridian once and every face spans
    the columns of its longitudes, Greenwich and the antimeridian too). A face across
    the antimeridian gets copies of its western corners at u + 1 (glTF's default REPEAT wrap), so no face spans the
    whole image (one off whole columns, where the image's own ends meet, spans up to a column and a half more: the
    longitudes both ends cover, or one column blending its ends); a corner
    at a pole gets a copy per face with the mean u of the face's other corners (the pole vertex itself serves the
    first such face, as does any vertex whose every face takes a copy: every vertex is a face's corner). A face the
    polar axis crosses elsewhere than at a corner (the coarsest mesh's: a cube face left as its two root triangles,
    their shared diagonal through the pole) is split there, a pole vertex as on every finer mesh: on an edge, in two
    (every face beside the edge), inside, in three; the first piece keeps the face's index, the others follow all
    faces, with its ``face_attributes`` (the two root triangles each side of a pole spanned 180 degrees of longitude,
    a u span of 0.5). The copies sit exactly on the original positions, so the surface stays crack-free; the mesh's
    vertices keep their indices, and faces, their order and ``face_attributes`` are unchanged but for such splits
    (``metadata["levels"]`` counts the faces as made; a ``per_face`` part's ``metadata["whole_part"]`` its new
    counts, so that :func:`~stepterrain.export.save_mesh` stores the six draped parts alike, seams welded). The
    material's ``wrap`` is ("REPEAT",
    "CLAMP_TO_EDGE"): GLB/glTF exports give the texture a sampler that repeats the image in u (longitude) and clamps
    it in v, and renders sample it so, so that no pole's colour blends with the other pole's in the mipmaps.

    Raises
    ------
    InvalidInputError
        ``mesh`` is not a trimesh.Trimesh, or the image is not (H, W, 3|4) with values in [0, 255].
    DataFileError
        The image file cannot be read.
    OutputTooLargeError
        The image file's pixels exceed the memory budget (:func:`stepterrain.set_memory_budget`), checked from its
        header before it is decoded; or the textured mesh's making would (about 150 bytes a face), checked before it.

    Examples
    --------
    >>> import numpy as np
    >>> lat = np.linspace(89.5, -89.5, 180); lon = np.linspace(-179.5, 179.5, 360)
    >>> g = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=9, device="cpu")
    >>> textured = drape_texture(g.mesh(), np.zeros((90, 180, 3), np.uint8))
    >>> len(textured.visual.uv) == len(textured.vertices) > len(g.mesh().vertices)
    True
    """
    mesh = mesh_argument(mesh)  # a pyvista PolyData (grid.stepterrain.stepped's) as its Trimesh
    return _drape_texture(mesh, *_texture_image(image))


#: Bytes :func:`_drape_texture` takes at its peak per vertex and per face of the mesh (the per-corner u and pole
#: flags, the seam's and poles' copies, the UVs and the copied vertices): 137 a face on cube-sphere meshes (two faces
#: a vertex), measured with tracemalloc at 49 152 to 786 432 faces, 145 with a placement= (the exact
#: georeferencing): 56 a vertex and 120 a face make 148 a face.
_DRAPE_VERTEX_BYTES, _DRAPE_FACE_BYTES = 56, 120


def _drape_texture(mesh: trimesh.Trimesh, pixels: NDArray[np.uint8], picture: Any = None,
                   placement: _Placement | None = None) -> trimesh.Trimesh:
    """:func:`drape_texture` of ``mesh`` (a Trimesh) with the texture's ``pixels``; ``picture``: the PIL image to
    embed instead of them, when the texture is a JPEG file's used as is, and ``placement``: where a georeferenced
    file's pixels lie (:func:`_texture_image`; None: plate carrée from 180° W)."""
    from PIL import Image

    # the UVs, seam and pole copies and their working arrays (and PIL's copy of the pixels): only an image file's
    # pixels were checked, and a large mesh's took 137 bytes a face (2 faces a vertex) unchecked
    check_budget(_DRAPE_VERTEX_BYTES * len(mesh.vertices) + _DRAPE_FACE_BYTES * len(mesh.faces)
                 + (pixels.nbytes if picture is None else 0),
                 f"draping a texture on a mesh of {len(mesh.faces):,} faces and {len(mesh.vertices):,} vertices",
                 hint="drape a coarser mesh (a smaller face_size or max_level)")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if bad.size:  # its texture coordinates would be NaN (drape_colors refuses such vertices too)
        raise InvalidInputError(f"mesh vertices must be finite to drape a texture; got vertex {bad[0]} at "
                                f"{vertices[bad[0]].tolist()}")
    horizontal = np.hypot(vertices[:, 0], vertices[:, 1])
    # relative to the vertex's height along the axis: within 1e-9 (an absolute length for |z| < 1) the ring round
    # each pole of a globe of radius 1e-8 became poles, and every vertex of one of radius 1e-12 (every u 0)
    pole = horizontal <= 1e-9 * np.abs(vertices[:, 2])
    lon = np.degrees(np.arctan2(vertices[:, 1], vertices[:, 0]))
    split = _split_at_poles(vertices, faces, pole, lon)
    if split is not None:  # a face the polar axis crosses (the coarsest mesh's), split at its pole
        vertices, faces, source, pole = split
        horizontal = np.hypot(vertices[:, 0], vertices[:, 1])
        lon = np.degrees(np.arctan2(vertices[:, 1], vertices[:, 0]))
    lat = np.degrees(np.arctan2(vertices[:, 2], horizontal))
    u = (lon + 180.0) / 360.0  # the seam's (the antimeridian's) u, whatever the texture's
    v = (lat + 90.0) / 180.0
    # a georeferenced file's pixels off whole columns (an odd-width 0..360 image) or not over exactly 360 x 180
    # degrees (a node-registered one): each pixel's centre where its georeferencing puts it (they were rolled by the
    # nearest whole column and stretched over the globe: up to a pixel off)
    height, width = np.asarray(pixels).shape[:2]
    texture_u = u if placement is None or placement.whole_columns else placement.columns(lon) / width
    if placement is not None and not placement.whole_rows:  # clamped: a pole beyond the image's edge takes its row
        v = np.clip(1.0 - placement.rows(lat) / height, 0.0, 1.0)
    corner_u = u[faces]
    corner_pole = pole[faces]
    # the antimeridian: a face whose non-pole corners span more than half the image wraps around
    lo = np.where(corner_pole, np.inf, corner_u).min(axis=1)
    hi = np.where(corner_pole, -np.inf, corner_u).max(axis=1)
    crossing = hi - lo > 0.5
    shift = crossing[:, None] & (corner_u < 0.5) & ~corner_pole
    # its western corners a turn on: the texture's u + 1 (its columns repeat), whatever the texture's placement
    corner_u = texture_u[faces] if texture_u is not u else corner_u
    corner_u = np.where(shift, corner_u + 1.0, corner_u)
    # the poles: the mean u of the face's other corners
    others = np.where(corner_pole, 0.0, corner_u).sum(axis=1) / np.maximum((~corner_pole).sum(axis=1), 1)
    corner_u = np.where(corner_pole, others[:, None], corner_u)
    # one copy per shifted vertex (shared by its faces), one per pole corner
    shifted = np.unique(faces[shift])
    shifted_index = np.full(len(vertices), -1, np.int64)
    shifted_index[shifted] = len(vertices) + np.arange(len(shifted))
    new_faces = np.where(shift, shifted_index[faces], faces)
    pole_rows, pole_cols = np.nonzero(corner_pole)
    new_faces[pole_rows, pole_cols] = len(vertices) + len(shifted) + np.arange(len(pole_rows))
    sources = np.concatenate([np.arange(len(vertices)), shifted, faces[pole_rows, pole_cols]])
    uv = np.column_stack([np.concatenate([texture_u, texture_u[shifted] + 1.0, corner_u[pole_rows, pole_cols]]),
                          v[sources]])
    # a vertex every face of which now uses a copy (a pole vertex, always) takes the place of its first copy: no face
    # used it, yet the GLB kept it (stepterrain info counted it) and trimesh's OBJ reader dropped it (the two read
    # back with other counts); the input's vertices keep their indices
    n = len(vertices)
    used = np.zeros(len(sources), dtype=bool)
    used[new_faces.reshape(-1)] = True
    unused = np.zeros(n, dtype=bool)
    unused[faces.reshape(-1)] = True
    unused &= ~used[:n]
    if unused.any():
        orphans = np.flatnonzero(unused)
        copied, first = np.unique(sources[n:], return_index=True)  # each original's first copy
        taken = n + first[np.searchsorted(copied, orphans)]
        uv[orphans] = uv[taken]
        kept = np.ones(len(sources), dtype=bool)
        kept[taken] = False
        index = np.cumsum(kept) - 1
        index[taken] = orphans
        new_faces = index[new_faces]
        sources, uv = sources[kept], uv[kept]
    out = trimesh.Trimesh(vertices[sources], new_faces, process=False, metadata=dict(mesh.metadata),
                          face_attributes={k: np.asarray(a)[source] if split is not None else np.asarray(a)
                                           for k, a in mesh.face_attributes.items()})  # fmt: skip
    out.metadata.pop("node_entry", None)  # vertex -> node entry does not hold for the copies
    made = out.metadata.get("whole_part")
    if isinstance(made, dict) and (made.get("vertices"), made.get("faces")) == (len(mesh.vertices), len(mesh.faces)):
        # a per-face part as made (Globe.mesh), draped: its copies and split points lie within its bounds, and
        # save_mesh keeps the set's frame for it by its new counts (by the old ones, a culled part draped was stored
        # about its own centre, the others about the eye: the seams came apart by up to 0.69 m)
        out.metadata["whole_part"] = {**made, "vertices": len(out.vertices), "faces": len(out.faces)}
    out.visual = trimesh.visual.TextureVisuals(uv=uv, image=picture if picture is not None else Image.fromarray(pixels))
    # the image wraps around in longitude, not from pole to pole: glTF's default sampler (REPEAT both ways) blended
    # each pole's texels with the other pole's in the mipmaps, a grey diamond at the north pole of the Blue Marble and
    # a dark spot at its white south pole (the GLB's sampler and the render clamp v)
    out.visual.material.wrap = ("REPEAT", "CLAMP_TO_EDGE")
    return out


def _split_at_poles(vertices: NDArray[np.float64], faces: NDArray[np.int64], pole: NDArray[np.bool_],
                    lon: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]] | None:
    """``vertices``, ``faces`` and the ``pole`` flags with each face that the polar axis crosses, not at a corner, split
    at the point where it does: one on an edge (every face beside that edge too) in two, one inside in three. The
    coarsest globe mesh leaves a cube face as its two root triangles, whose shared diagonal runs through the pole:
    each spans 180 degrees of longitude, and the drape's UVs, linear over a face, gave it a u span of 0.5 (the texture
    smeared across half the map, 90 degrees off along the diagonal) where a pole vertex, as on every finer mesh, takes
    the mean u of each face's other corners. The new points lie on the faces (on the edge, or in the face's plane) and
    are poles; the first piece of a face keeps its index, the others follow all faces in order. Returns the vertices
    (new points after the old ones), the faces, each face's original index and the pole flags; None where no face
    is split. Only faces whose corners' longitudes (``lon``, degrees) span 180 degrees or more, none a pole, are
    looked at (a face round the axis spans more, one with the axis on an edge 180): a few, at the antimeridian."""
    n, count = len(vertices), len(faces)
    # corner by corner (every drape pays this: np.ptp and .any along an axis of 3 took 18 ms of a 82 ms drape of
    # 196 608 faces, elementwise 2 ms)
    lon0, lon1, lon2 = lon[faces[:, 0]], lon[faces[:, 1]], lon[faces[:, 2]]
    span = np.maximum(np.maximum(lon0, lon1), lon2) - np.minimum(np.minimum(lon0, lon1), lon2)
    del lon0, lon1, lon2
    # (less a margin: a corner's longitude rounds, and the axis may pass within the tolerance below outside an edge)
    around = np.flatnonzero((span >= 180.0 - 1e-6) & ~(pole[faces[:, 0]] | pole[faces[:, 1]] | pole[faces[:, 2]]))
    del span
    corners = vertices[faces[around]]
    x, y = corners[..., 0], corners[..., 1]
    edge = x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y  # edge k (corner k to k + 1) against the axis
    area = edge.sum(axis=1)  # twice the face's area seen along the axis, signed
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = edge / area[:, None]  # 0 on the edge's line, 1 at the corner opposite it
    scale = np.abs(corners[..., :2]).max(axis=(1, 2), initial=0.0)
    on = weight <= 1e-9
    # on two edges' lines: at a corner, which is the pole itself; at the centre (a face through it): no pole
    crossed = (np.abs(area) > 1e-12 * scale**2) & (weight >= -1e-9).all(axis=1) & (on.sum(axis=1) <= 1)
    with np.errstate(invalid="ignore"):
        height = np.einsum("fk,fk->f", np.roll(weight, -1, axis=1), corners[..., 2])  # where the axis meets it
    crossed &= np.abs(height) > 1e-9 * scale
    if not crossed.any():
        return None
    points: list[NDArray[np.float64]] = []
    source = [np.arange(count)]
    faces = faces.copy()  # the mesh's own array, where it is int64
    inside = ~on.any(axis=1) & crossed
    if inside.any():  # in three at the point: the corners weighted by the edges opposite them
        p = n + np.arange(int(inside.sum()))
        points.append(np.einsum("fk,fkc->fc", np.roll(weight[inside], -1, axis=1), corners[inside]))
        rows = around[inside]
        a, b, c = faces[rows].T
        faces[rows] = np.column_stack([a, b, p])
        faces = np.concatenate([faces, np.column_stack([b, c, p]), np.column_stack([c, a, p])])
        source += [rows, rows]
    source = np.concatenate(source)
    rows, cols = np.nonzero(crossed[:, None] & on)
    ends = faces[around[rows][:, None], np.column_stack([cols, (cols + 1) % 3])]
    for a, b in np.unique(np.sort(ends, axis=1), axis=0):  # each edge the axis crosses, once, and the faces beside it
        start, step = vertices[a], vertices[b] - vertices[a]
        t = -float(start[:2] @ step[:2]) / float(step[:2] @ step[:2])
        points.append((start + t * step)[None])
        p = n + sum(len(q) for q in points) - 1
        for f in np.flatnonzero((faces == a).any(axis=1) & (faces == b).any(axis=1)):
            k = next(k for k in range(3) if {faces[f, k], faces[f, (k + 1) % 3]} == {a, b})
            first, second, third = faces[f, k], faces[f, (k + 1) % 3], faces[f, (k + 2) % 3]
            faces[f] = first, p, third
            faces = np.concatenate([faces, [[p, second, third]]])
            source = np.concatenate([source, source[f : f + 1]])
    added = np.concatenate(points)
    return (np.concatenate([vertices, added]), faces, source,
            np.concatenate([pole, np.ones(len(added), dtype=bool)]))


def drape_colors(vertices: ArrayLike, image: ArrayLike | str) -> NDArray[np.uint8]:
    """(V, 4) uint8 RGBA per vertex from a global plate-carrée image (row 0 at 90° N, column 0 at 180° W; a file
    georeferenced as the whole globe in degrees, 0..360 too, is placed by it, each pixel's centre at the latitude
    and longitude its georeferencing gives, off whole columns too (an odd-width 0..360 image) and over not quite
    360 x 180 degrees (a node-registered 361 x 181 image: its pixel centres on whole degrees, its edge rows at the
    poles, its last column, the first's meridian again, dropped; between the last column and the first of an image
    spanning less than 360°, the two are blended as a sampler repeating the image blends them); other georeferencing
    refused), bilinear at each vertex's direction (paper 003 §5.3: a global texture
    draped by latitude and longitude). An (H, W, 4) image's alpha is kept (bilinear; its colour is weighted by
    alpha, so that transparent texels' colour does not darken the opaque ones' next to them; a vertex of alpha 0 gets
    the colour of the opaque texels near it, :func:`~stepterrain.io.fill_transparent`, which its faces blend with
    their opaque corners'), an RGB image's is 255. A pole vertex (its direction along the axis, within 1e-9), at
    every longitude at once, gets its row's mean over all columns (alpha-weighted: the opaque texels' mean colour,
    and the mean alpha), as :meth:`Globe.from_latlon` gives a pole node its row's mean height: a uniform pole row (a
    node-registered image's) gives its own colour; a vertex off the pole, its longitude's.

    Raises
    ------
    InvalidInputError
        The image is not (H, W, 3|4) or cannot be read; ``vertices`` not (V, 3) (a mesh: pass ``mesh.vertices``),
        not finite or at the centre.
    OutputTooLargeError
        The image file's pixels exceed the memory budget, checked from its header before it is decoded.

    Examples
    --------
    >>> import numpy as np
    >>> lat = np.linspace(89.5, -89.5, 180); lon = np.linspace(-179.5, 179.5, 360)
    >>> mesh = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=9, device="cpu").mesh()
    >>> mesh.visual.vertex_colors = drape_colors(mesh.vertices, np.zeros((90, 180, 3), np.uint8))
    >>> mesh.visual.vertex_colors.shape == (len(mesh.vertices), 4)
    True
    """
    if isinstance(vertices, trimesh.Trimesh):  # drape_texture takes the mesh; this one read it as 'dtype object'
        raise InvalidInputError("vertices must be a (V, 3) array of planet-centred positions; got a "
                                "trimesh.Trimesh: pass its vertices, mesh.visual.vertex_colors = "
                                "drape_colors(mesh.vertices, image)")
    pixels, _, placement = _texture_image(image)
    return _drape_colors(vertices, pixels, placement)


def _drape_colors(vertices: ArrayLike, pixels: NDArray[np.uint8], placement: _Placement | None = None
                  ) -> NDArray[np.uint8]:
    """:func:`drape_colors` of ``vertices`` with the texture's ``pixels``, placed by ``placement`` (a georeferenced
    file's, :func:`_texture_image`; None: plate carrée from 180° W)."""
    v = real_numbers(vertices, "vertices", "a (V, 3) array of planet-centred positions")
    if v.ndim != 2 or v.shape[1] != 3:
        raise InvalidInputError(f"vertices must be a (V, 3) array of planet-centred positions; got shape {v.shape}")
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    bad = np.flatnonzero(~(np.isfinite(norm[:, 0]) & (norm[:, 0] > 0)))
    if bad.size:
        raise InvalidInputError(f"vertices must be finite and away from the centre; got vertex {bad[0]} at "
                                f"{v[bad[0]].tolist()}")
    d = v / norm
    lat = np.degrees(np.arcsin(np.clip(d[:, 2], -1, 1)))
    lon = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    h, w = pixels.shape[:2]
    if placement is None or placement.whole_rows:
        fy = np.clip((90.0 - lat) / 180.0 * h - 0.5, 0, h - 1)
    else:  # each pixel's centre where its georeferencing puts it (_Placement), as drape_texture's UVs
        fy = np.clip(placement.rows(lat) - 0.5, 0, h - 1)
    if placement is None or placement.whole_columns:
        fx = ((lon + 180.0) / 360.0 * w - 0.5) % w
    else:  # the columns wrap as a repeating sampler reads drape_texture's UVs there
        fx = (placement.columns(lon) - 0.5) % w
    y0 = np.minimum(np.floor(fy).astype(int), h - 2)
    x0 = np.floor(fx).astype(int) % w
    x1 = (x0 + 1) % w
    ty = (fy - y0)[:, None]
    tx = (fx - np.floor(fx))[:, None]
    # the four texels of each vertex, gathered once and only they made float64 (the whole image was: 5.6 GB of float64
    # for a 21600 x 10800 RGB, and as much again for its alpha)
    texels = [pixels[y, x].astype(np.float64) for y, x in ((y0, x0), (y0, x1), (y0 + 1, x0), (y0 + 1, x1))]
    # a pole (as drape_texture tells one: its horizontal part within 1e-9 of its length) lies at every longitude at
    # once: it takes its rows' mean over all columns (its alpha-weighted colour), as Globe.from_latlon gives a pole
    # node its row's mean height; it took the row's colour at longitude 0 (arctan2(0, 0)), one column's of many
    pole = np.hypot(d[:, 0], d[:, 1]) <= 1e-9 * np.abs(d[:, 2])
    if pole.any():
        for k, rows in enumerate((y0, y0, y0 + 1, y0 + 1)):
            texels[k][pole] = _row_means(pixels, rows[pole])
    top = (1 - tx) * texels[0][:, :3] + tx * texels[1][:, :3]
    bottom = (1 - tx) * texels[2][:, :3] + tx * texels[3][:, :3]
    rgb = (1 - ty) * top + ty * bottom
    if pixels.shape[2] == 3 or pixels[..., 3].min() == 255:  # opaque: alpha 255
        return np.column_stack([np.round(rgb).astype(np.uint8), np.full(len(v), 255, np.uint8)])
    # the texture's alpha, bilinear, and its colour weighted by alpha (premultiplied): a transparent texel's colour
    # (the black of nodata) does not bleed into its opaque neighbours'; a vertex among transparent texels only keeps
    # their plain bilinear colour. The alpha was dropped: transparent texels came out opaque in whatever RGB they hold
    corners = ((1 - ty) * (1 - tx), (1 - ty) * tx, ty * (1 - tx), ty * tx)
    weights = [w * texel[:, 3:] for w, texel in zip(corners, texels, strict=True)]
    alpha = sum(weights)
    covered = alpha[:, 0] > 0
    weighted = sum(w * texel[:, :3] for w, texel in zip(weights, texels, strict=True))
    rgb[covered] = weighted[covered] / alpha[covered]
    if not covered.all():  # a vertex among transparent texels: their colour (garbage, the magenta under a -dstalpha
        # nodata cap) blended into the opaque vertices' across its faces, in a render and in a viewer of its GLB; it
        # takes the colour of the opaque texels near it
        from .io import fill_transparent

        filled = fill_transparent(pixels)
        bare = ~covered
        near = [filled[y[bare], x[bare], :3].astype(np.float64)
                for y, x in ((y0, x0), (y0, x1), (y0 + 1, x0), (y0 + 1, x1))]
        if (pole & bare).any():  # a pole among transparent texels: the mean of its rows' filled colours
            for k, rows in enumerate((y0, y0, y0 + 1, y0 + 1)):
                near[k][pole[bare]] = _row_means(filled[..., :3], rows[pole & bare])
        rgb[bare] = sum(w[bare] * texel for w, texel in zip(corners, near, strict=True))
    return np.column_stack([np.round(rgb).astype(np.uint8), np.round(alpha[:, 0]).astype(np.uint8)])


def _row_means(pixels: NDArray[np.uint8], rows: NDArray[np.int64]) -> NDArray[np.float64]:
    """(len(rows), C) float64: each of ``rows`` of ``pixels`` (H, W, 3|4) averaged over its columns; an RGBA row's
    colour weighted by alpha (its opaque texels' mean colour; a transparent row's plain mean) and its mean alpha."""
    unique, inverse = np.unique(rows, return_inverse=True)
    means = np.empty((len(unique), pixels.shape[2]), dtype=np.float64)
    for k, row in enumerate(unique):  # a row or two: a pole's
        values = pixels[row].astype(np.float64)
        means[k] = values.mean(axis=0)
        if pixels.shape[2] == 4 and values[:, 3].sum() > 0:
            means[k, :3] = (values[:, :3] * values[:, 3:]).sum(axis=0) / values[:, 3].sum()
    return means[inverse.reshape(-1)]


def look_from(latitude: float, longitude: float, altitude: float, *, tilt: float = 0.0, heading: float = 0.0,
              fov: float = math.radians(30.0), aspect: float = 1.6, radius: float = EARTH_RADIUS,
              max_radius: float | None = None) -> Camera:
    """A camera at (latitude, longitude) in degrees (latitude in [-90, 90], longitude in [-360, 360]: east of
    Greenwich either way round), ``altitude`` metres above the sphere of ``radius`` (negative below it, above the
    centre: more than -``radius``),
    looking down (tilt 0) or tilted towards ``heading`` (degrees clockwise from north, any finite value: whole
    turns are taken off exactly) by ``tilt`` degrees, in [-90, 90] (90: the horizon; a negative tilt looks the
    other way, towards heading + 180).

    ``max_radius`` (metres, default ``radius``) is the largest distance of the surface from the centre, for a
    :class:`Globe` its ``radius`` plus its highest exaggerated node height (``globe.heights.max()``): the far
    plane lies at |eye| + max(|eye|, max_radius) + radius, beyond the far side of that sphere, so that an
    extreme vertical exaggeration is not clipped behind the limb; the near plane lies at a thousandth of the eye's
    height above that sphere (at least min(1 m, 10^-6 · radius)), so that it clips no terrain in front of the eye
    at any planet size or exaggeration.

    Examples
    --------
    >>> cam = look_from(0.0, 0.0, 1.0e7)
    >>> [round(v) for v in cam.eye]
    [16371000, 0, 0]
    """
    try:
        latitude, longitude = as_number(latitude), as_number(longitude)
    except (TypeError, ValueError):
        raise InvalidInputError(f"latitude and longitude must be numbers (degrees); got {latitude!r}, "
                                f"{longitude!r}") from None
    if not -90.0 <= latitude <= 90.0:
        raise InvalidInputError(f"latitude must lie in [-90, 90] degrees; got {latitude}")
    if not math.isfinite(longitude):
        raise InvalidInputError(f"longitude must be finite; got {longitude}")
    if not -360.0 <= longitude <= 360.0:  # 1e300 degrees gave a direction of no meaning (its radians round away)
        raise InvalidInputError(f"longitude must lie in [-360, 360] degrees; got {longitude:g}")
    for name, value in (("altitude", altitude), ("tilt", tilt), ("heading", heading)):
        if not math.isfinite(number_or_nan(value)):
            raise InvalidInputError(f"{name} must be a finite number; got {plain_repr(value)}")
    altitude, tilt, heading = float(altitude), float(tilt), float(heading)
    if not -90.0 <= tilt <= 90.0:  # 1e308 degrees gave a view of no meaning; past 90 the view looks up, off the globe
        raise InvalidInputError(f"tilt must lie in [-90, 90] degrees from straight down; got {tilt:g}")
    if abs(heading) >= 360.0:  # whole turns off, exactly (fmod is exact): radians(1e308) lost the direction
        heading = math.fmod(heading, 360.0)
    radius = _positive(radius, "radius")
    top = radius if max_radius is None else _positive(max_radius, "max_radius")
    if radius + altitude <= 0:  # the eye at the centre, or through it: (radius + altitude) · outward put an eye of
        # altitude -2R - 10 km 10 km above the antipode, looking up into space (an empty mesh, without a word)
        raise InvalidInputError(f"altitude must be more than -radius (metres above the sphere of radius {radius:g}; "
                                f"the eye at or beyond the centre lies on no side of it); got {altitude:g}")
    if abs(radius + altitude) > _MAX_COORDINATE:  # the Camera's coordinate bound, named by its inputs here
        raise InvalidInputError(f"radius + altitude must stay within {_MAX_COORDINATE:g} m of the centre; got "
                                f"{radius:g} + {altitude:g}")
    la, lo = math.radians(latitude), math.radians(longitude)
    outward = np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    north = np.cross(outward, east)
    eye = (radius + altitude) * outward
    hd, tl = math.radians(heading), math.radians(tilt)
    horizontal = math.cos(hd) * north + math.sin(hd) * east
    forward = -math.cos(tl) * outward + math.sin(tl) * horizontal
    up = math.cos(tl) * horizontal + math.sin(tl) * outward
    # the target a step along the view: at least 2^-20 of the eye's distance from the centre, so that target - eye
    # keeps the direction to ~2^-32 rad in float64 (a step of the altitude or 1 m rounded away against a large
    # radius: 10 m above a sphere of 1e17 m the view turned 0.17 rad off its tilt and heading, and 1 m above
    # one of 1e20 m the target was the eye, refused as a Camera's)
    target = eye + forward * max(altitude, 1.0, (radius + altitude) * 2.0**-20)
    distance = radius + altitude  # of the eye from the centre: every surface point lies within distance + top
    # the near plane at a thousandth of the eye's clearance above the sphere of max_radius (no surface point lies
    # closer), at least min(1 m, 1e-6 · radius): a fixed 1 m floor clipped the whole ground under the eye of a
    # small planet (radius 1, altitude 0.5), and an altitude-based near plane the top of an exaggerated peak
    near = max((distance - top) * 1e-3, min(1.0, radius * 1e-6))
    return Camera(eye=tuple(eye), target=tuple(target), up=tuple(up), fov=fov, aspect=aspect,
                  near=near, far=distance + max(distance, top) + radius)


def _unresolved_altitude(radius: float, altitude: float) -> str:
    """"" unless a non-zero ``altitude`` (metres above the sphere of ``radius``) rounds away in float64, the eye's
    distance ``radius + altitude`` the radius itself: 1 km above a sphere of 1e20 m, where float64's numbers lie
    16384 m apart (an eye on the sphere, below any terrain there: refused as "inside the planet", |eye| and the
    surface both 1e20 m). Then a usable range for a refusal's words: "{spacing} m at this radius, or a radius below
    {bound} m for this altitude" (either keeps at least half of the altitude)."""
    spacing = math.ulp(radius)
    if altitude == 0.0 or radius + altitude != radius:
        return ""
    bound = 2.0 ** (math.floor(math.log2(abs(altitude))) + 53)  # every radius below it: spacing <= |altitude|
    return f"{_shown(spacing, 1):g} m at this radius, or a radius below {_shown(bound, -1):g} m for this altitude"


def _shown(value: float, way: int) -> float:
    """``value`` to the 6 digits ``:g`` prints, rounded up (``way`` 1) or down (-1): a bound a message names holds as
    printed (2^62 printed 4.61169e18, yet a radius of 4.6116899e18 is not below it)."""
    shown = float(f"{value:.6g}")
    if (shown - value) * way < 0:
        shown += way * 10.0 ** (math.floor(math.log10(shown)) - 5)
    return shown


def render_view(mesh: trimesh.Trimesh, camera: Camera, *, window_size: tuple[int, int] | None = None,
                background: str = "black", show_edges: bool = False) -> NDArray[np.uint8]:
    """Render a globe mesh off-screen from ``camera``'s eye towards its target, with the camera's field of view
    (``camera.fov``, at most 179°, VTK's widest) and, by default, its ``viewport`` as the window (1280 x 800 for
    :func:`look_from`'s default aspect 1.6). A ``window_size`` of another aspect than the camera's shows the largest
    centred part of the camera's view with the window's aspect, never more: a mesh culled to the camera
    (``Globe.mesh(camera=...)``) fills the picture, with no cut-away ground at its edges. A window over the memory
    budget is refused (an OutputTooLargeError) before any work, as :func:`~stepterrain.render.render_mesh` refuses
    it."""
    from . import render
    from .export import _texture_copy

    # a per_face list, None: an AttributeError on .bounds; a pyvista PolyData as its Trimesh
    mesh = mesh_argument(mesh, hint=" (render the meshes of per_face=True one by one)")
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be a stepterrain.globe.Camera; got {type(camera).__name__}")
    # the window defaulted to 1280 x 800 whatever the camera: a portrait camera's culled mesh rendered with its
    # sides cut away (16 % of the picture black for a 9:16 camera)
    if window_size is None and not all(8 <= side <= 16384 for side in camera.viewport):
        raise InvalidInputError(f"camera viewport {camera.viewport[0]}x{camera.viewport[1]} is no window to render "
                                "(8 to 16384 pixels a side); give window_size")
    width, height, _ = render._check_window(camera.viewport if window_size is None else window_size, 1.0)
    # the camera's own field of view: a fixed 30° showed a narrower camera's culled mesh as a patch floating in the
    # black, and only the middle of a wider one's view. A window wider than the camera keeps the camera's
    # horizontal extent (its vertical one narrows): VTK's horizontal extent follows the window, and a wider one
    # showed the ground the camera had culled away at the picture's sides
    wider = width / height > camera.aspect
    view_angle = math.degrees(2.0 * math.atan(math.tan(camera.fov / 2.0) * camera.aspect * height / width)
                              if wider else camera.fov)
    lo, hi = render._VIEW_ANGLE_RANGE
    if not lo <= view_angle <= hi:  # VTK clamps its view angle to that range: another picture than the camera's
        raise InvalidInputError(f"camera fov must lie within [{lo:g}, {hi:g}] degrees to render (VTK's range); got "
                                f"{view_angle:.6g} degrees ({camera.fov:.6g} rad)"
                                + (f", narrowed to the {width}x{height} window, wider than the camera's aspect "
                                   f"{camera.aspect:.6g}" if wider else ""))
    # its copies for the render too, before the mesh is copied into the view's frame
    render._check_render_budget(width, height, mesh=(len(mesh.vertices), len(mesh.faces)))
    box = render._finite_bounds(np.asarray(mesh.vertices, dtype=np.float64), "mesh vertices")
    if box is None or len(mesh.faces) == 0:  # numpy's AxisError on the empty bounds (a view that clips everything)
        raise InvalidInputError(f"mesh has no faces with finite vertices; nothing to render (got "
                                f"{counted(len(mesh.faces), 'face')}: a view that clips every triangle gives an empty "
                                "mesh)")
    # rendered in the east / north / up frame of the ground under the view, so that the render's light comes from
    # the north-west of that ground, as over a local terrain (in the world frame it came from the north-west of the
    # equatorial plane: a close view over New Zealand was lit from below the horizon and came out dim)
    frame = _view_frame(camera)
    centre = box.mean(axis=0)
    local = _texture_copy(mesh)  # with the material's wrap, which PBRMaterial.copy drops: the poles blended
    local.vertices = (np.asarray(mesh.vertices, dtype=np.float64) - centre) @ frame.T
    local_box = render._finite_bounds(np.asarray(local.vertices))
    middle = local_box.mean(axis=0)  # render_mesh takes an explicit camera relative to the centre of ``bounds``
    eye, target = ((np.subtract(point, centre) @ frame.T) - middle for point in (camera.eye, camera.target))
    position = [tuple(eye), tuple(target), tuple(frame @ np.asarray(camera.up, dtype=np.float64))]
    return render.render_mesh(local, window_size=(width, height), camera=position, background=background,
                              bounds=local_box, show_edges=show_edges, view_angle=view_angle)


def _view_frame(camera: Camera) -> NDArray[np.float64]:
    """Rows east, north, up of the ground under ``camera``'s target (its eye's when the target is the centre)."""
    target = np.asarray(camera.target, dtype=np.float64)
    ground = target if np.linalg.norm(target) > 0.0 else np.asarray(camera.eye, dtype=np.float64)
    up = ground / np.linalg.norm(ground)
    east = np.cross((0.0, 0.0, 1.0), up)
    if np.linalg.norm(east) < 1e-9:  # over a pole: any east will do
        east = np.array([0.0, 1.0, 0.0])
    east /= np.linalg.norm(east)
    return np.stack([east, np.cross(up, east), up])
