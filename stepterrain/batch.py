"""Batch meshing on dask.distributed: many inputs, one stepped mesh file each, resumable and atomic.

Scales paper 000 (Glander, Trapp & Döllner, *3D Isocontours*, Eurographics 2010) from one terrain to many:
a folder of DEM tiles, a (T, H, W) time series (the paper's dynamic data, §4: every frame stepped with the
same isovalues, so levels do not jump between frames) or tiles cut from one large raster (neighbouring tiles
share their border nodes and their isovalues, so their stepped meshes weld without cracks, §3.2).

    from stepterrain.batch import batch
    report = batch("dem_tiles/", "out/", interval=50.0)                   # LocalCluster, one .glb per tile
    report = batch(load_dem("big.tif"), "out/", tile_size=1024, interval=100.0, scheduler="tcp://host:8786")

Each item runs as one dask task (``stepped`` + ``export.save_mesh``, written atomically), small ones (tiles of
64², say) several to a task, each still done, retried and reported on its own. A manifest in the
output folder records every finished item with a fingerprint of its input and options; a rerun skips items
whose output is complete (recorded, same fingerprint, file present with the recorded size) and redoes the
rest. Failures are retried (disk and network errors too), then reported with their reason; bad input data
fails its item without retries.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import gc
import hashlib
import json
import logging
import math
import os
import platform
import re
import shlex
import sys
import threading
import time
import warnings
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._callable_module import make_module_callable
from ._compaction import BUDGET_HINT, budget_hint, get_memory_budget
from ._files import GdalPath, as_path, gdal_path, local_archive
from ._signals import signals_held, terminal_signals_blocked_for_children
from ._warning_filters import FILTERS
from .errors import (
    DataFileError,
    InvalidInputError,
    MissingDependencyError,
    SchedulerError,
    StepTerrainError,
    caller_stacklevel,
    counted,
)
from .export import (
    _STL_OPEN_RE,
    _STL_ROUNDING_RE,
    _STL_ROUNDING_TOLERANCE,
    MESH_EXTENSIONS,
    _temporary_stem,
    atomic_path,
    json_metadata,
    probe_writable,
    replacing_without_flush,
    save_mesh,
    unwritable_reason,
)
from .io import GDAL_FORMATS, GZIP_FORMATS, SUPPORTED_EXTENSIONS, recorded_nodata
from .terrain import (
    FLOAT32_MAX,
    Terrain,
    _described,
    _used_span,
    check_flag,
    check_mapped,
    finite_number,
    finite_or_nan,
    finite_triangles,
    float32_heights,
    grid_surface_counts,
    lowest_used_height,
    number_or_nan,
    unmasked,
)

__all__ = [
    "batch",
    "BatchReport",
    "BatchItem",
    "ItemResult",
    "plan_items",
    "load_series",
    "MANIFEST_NAME",
    "LOCK_NAME",
    "overview_image",
    "start_local_cluster",
]

#: The sidecar manifest :func:`batch` keeps in the output folder (one JSON object, written atomically).
MANIFEST_NAME = "stepterrain-batch.json"
#: The lock file :func:`batch` holds in the output folder while it runs (its pid, host and start time inside), so
#: that a second run into the same folder is refused instead of rewriting the first one's manifest and outputs.
LOCK_NAME = ".stepterrain-batch.lock"
#: 2: entries keyed by output file name (``tile_r0_c0.glb``), so outputs of one item in several formats are each
#: recorded; 1 (read too): keyed by item, one format per folder
_MANIFEST_VERSION = 2
#: How the manifest's height ranges of a folder's files (key ``"ranges"``, :func:`_files_range`) are found; recorded
#: beside them as ``"ranges_version"``. Ranges of another version (or of none) are read again, not trusted: raise it
#: whenever what a file's range is, or how its :func:`_range_key` is made, changes
_RANGES_VERSION = 1
#: Terrains a serial run's height-range pass read (:func:`_file_range`), by item key, each with the warnings its read
#: gave: its item is stepped from that read (:func:`_run_serial`), its result holding those warnings
_Kept = dict[str, tuple[Terrain, tuple[str, ...]]]
_SCHEDULER_RE = re.compile(r"^(tcp|tls|inproc|ucx|ws|wss)://[^\s/:]+(:\d{1,5})?/?$")
#: The DEM files a folder source is read for: all but a .vrt, which in a folder of tiles is the mosaic of them
#: (gdalbuildvrt's), so its heights would be meshed twice (a .vrt named as a file, or in a glob, is read)
_FOLDER_EXTENSIONS = tuple(ext for ext in SUPPORTED_EXTENSIONS if ext != ".vrt")
#: The gzip files a folder source is read for, by their whole ending (``N46E007.hgt.gz``): of :data:`GZIP_FORMATS`
_FOLDER_GZIPS = tuple(ext + ".gz" for ext in GZIP_FORMATS)


def _gzip_raster(name: str) -> bool:
    """Whether the file ``name`` is a gzip of a raster load_dem reads (``N46E007.hgt.gz``, ``dem.tif.gz``)."""
    return name.lower().endswith(_FOLDER_GZIPS)


_MANIFEST_FLUSH_S = 1.0


# ---------------------------------------------------------------------------------------------- data types
@dataclass(frozen=True)
class BatchItem:
    """One unit of work: an input (a file, a frame of a series, or a window of a raster) and its output name.

    ``rows`` and ``cols`` are node ranges ``[start, stop)`` of a tile; neighbouring tiles overlap by one
    node row or column (their shared border).
    """

    key: str
    kind: Literal["file", "frame", "tile"]
    path: str | None = None
    index: int = 0
    rows: tuple[int, int] = (0, 0)
    cols: tuple[int, int] = (0, 0)
    tile: tuple[int, int] = (0, 0)


@dataclass(frozen=True)
class ItemResult:
    """What became of one item: ``status`` is ``"done"``, ``"skipped"`` (complete already) or ``"failed"``.

    ``seconds`` is the item's wall time on its worker, ``cpu_seconds`` the CPU time of the worker process
    meanwhile (all its threads).
    """

    key: str
    status: Literal["done", "skipped", "failed"]
    path: str | None = None
    error: str | None = None
    attempts: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0
    faces: int = 0
    vertices: int = 0
    bytes: int = 0
    #: the warnings a worker process raised for the item (each once), warned again in the caller's process
    warnings: tuple[str, ...] = ()


@dataclass
class BatchReport:
    """Outcome of :func:`batch`: one :class:`ItemResult` per item, in item order."""

    output_dir: Path
    results: list[ItemResult] = field(default_factory=list)
    seconds: float = 0.0
    scheduler: str = "serial"
    #: what else the run found in the output folder: an unreadable manifest, outputs in another format
    notes: list[str] = field(default_factory=list)
    #: what the items are: ``"tile"`` (of one raster), ``"file"`` (of a folder or list) or ``"frame"`` (of a series);
    #: None when not known (a report made by hand: :func:`overview_image` then goes by the outputs' names)
    kind: Literal["tile", "file", "frame"] | None = None

    @property
    def done(self) -> list[ItemResult]:
        return [r for r in self.results if r.status == "done"]

    @property
    def skipped(self) -> list[ItemResult]:
        return [r for r in self.results if r.status == "skipped"]

    @property
    def failed(self) -> list[ItemResult]:
        return [r for r in self.results if r.status == "failed"]

    @property
    def ok(self) -> bool:
        """True when every item is done or was complete already."""
        return not self.failed

    def summary(self) -> str:
        """A few lines: counts, time, then one line per failure with its reason."""
        lines = [
            f"{len(self.done)} written, {len(self.skipped)} complete already (skipped), {len(self.failed)} failed "
            f"of {counted(len(self.results), 'item')} in {self.seconds:.1f} s on {self.scheduler}; output "
            f"{self.output_dir}"
        ]
        lines += [f"  {_failure_line(r)}" for r in self.failed]
        lines += [f"  note: {note}" for note in self.notes]
        return "\n".join(lines)


@dataclass(frozen=True)
class _Frame:
    """Where a DEM file in degrees lies in the local metres that a folder's (or list's) files in one geographic CRS
    share, those :func:`~stepterrain.io.load_dem` reads their mosaic in (:func:`~stepterrain.io.shared_degree_frame`):
    ``own`` the spacing load_dem gives the file alone, ``spacing`` and ``origin`` its nodes' in the shared frame, whose
    ``crs`` and ``source`` it takes."""

    own: tuple[float, float]
    spacing: tuple[float, float]
    origin: tuple[float, float]
    crs: str | None
    source: str
    #: the file's (rows, cols) as its header gives them, for :func:`_seams_moved`; out of the repr, which the
    #: fingerprint hashes, so that it stays the one of runs made before it existed
    shape: tuple[int, int] | None = dataclasses.field(default=None, repr=False)


@dataclass(frozen=True)
class _Options:
    """The stepping and export options every item shares (part of each item's fingerprint)."""

    interval: float | None
    levels: tuple[float, ...] | None
    base: float
    gamma: float
    colors: str | None
    solid: bool
    floor: float | None
    ext: str
    device: str | None
    metadata: tuple[tuple[str, Any], ...]
    #: the DEM files' height unit (:func:`~stepterrain.io.load_dem`'s ``height_unit``); out of the repr, so that a
    #: run without it keeps the fingerprints of runs made before it existed (:func:`_fingerprints` adds it when set)
    height_unit: str | None = dataclasses.field(default=None, repr=False)
    #: DEM files without georeferencing: their (dx, dy) cell size in metres, rows north to south (``spacing=``), and
    #: the N of ``coarsen=``, applied to each file as it is read; out of the repr as ``height_unit`` (the
    #: metadata's ``spacing`` and ``coarsen``, part of the repr, record them for the fingerprint)
    file_spacing: tuple[float, float] | None = dataclasses.field(default=None, repr=False)
    coarsen: int | None = dataclasses.field(default=None, repr=False)
    #: the GDAL raster band the DEM files' heights are read from (:func:`~stepterrain.io.load_dem`'s ``band``), None for
    #: the first; out of the repr as ``height_unit`` (:func:`_fingerprints` adds it when set)
    band: int | None = dataclasses.field(default=None, repr=False)
    #: the RGB encoding of PNG terrain tiles (:func:`~stepterrain.io.load_dem`'s ``height_encoding``); out of the repr
    #: as ``height_unit`` (:func:`_fingerprints` adds it when set)
    height_encoding: str | None = dataclasses.field(default=None, repr=False)
    #: the values marking the DEM files' missing cells besides their own nodata (:func:`~stepterrain.io.load_dem`'s
    #: ``nodata``); out of the repr as ``height_unit`` (the metadata's ``nodata`` records it for the fingerprint)
    nodata: tuple[float, ...] = dataclasses.field(default=(), repr=False)
    #: the caller's working folder, set for dask workers (:func:`_run_dask`): a relative output folder or DEM file
    #: is resolved against it on a worker that runs in another folder (:func:`_on_worker`); out of the repr
    cwd: str | None = dataclasses.field(default=None, repr=False)
    #: the items are several DEM files (a folder's or a list's), whose meshes are meant to lie side by side: one read
    #: from degrees, in local metres of its own, is warned of (:func:`_run_item`); out of the repr
    several_files: bool = dataclasses.field(default=False, repr=False)
    #: by item key, the DEM files in degrees placed in the local metres of their mosaic (:func:`_degree_frames`), a
    #: frame that depends on the other files; out of the repr (:func:`_fingerprints` adds each item's own)
    frames: tuple[tuple[str, _Frame], ...] = dataclasses.field(default=(), repr=False)

    def frame_of(self, key: str) -> _Frame | None:
        """The frame of the item ``key`` (:attr:`frames`), None for an item in its own: looked up in a dict made once,
        not one made per item (a batch of N files made N dicts of N entries)."""
        return self._frames_by_key.get(key)

    @functools.cached_property
    def _frames_by_key(self) -> dict[str, _Frame]:
        return dict(self.frames)


def _on_worker(path: str, cwd: str | None) -> str:
    """``path`` as the caller meant it, on a worker whose working folder is not the caller's ``cwd`` (dask workers
    started elsewhere, by ssh or systemd): a relative path resolved against ``cwd``; as given otherwise (the serial run,
    a LocalCluster's workers), so that the outputs and error messages are the serial run's. A GDAL virtual path or
    URL: :func:`_virtual_from` (a URL was joined to ``cwd``, and ``/vsizip/t.zip/a.tif`` kept, its zip looked for in
    the worker's folder)."""
    if cwd is None or os.getcwd() == cwd:
        return path
    virtual = _virtual_from(path, cwd)
    if virtual is not None:
        return virtual
    return path if os.path.isabs(path) else os.path.join(cwd, path)


def _virtual_from(path: str, cwd: str) -> str | None:
    """The GDAL virtual path or URL ``path`` as read from the folder ``cwd``: the relative local archive of
    ``/vsizip/t.zip/a.tif`` (``/vsigzip/``, ``/vsitar/`` ...) made absolute, ``/vsizip//cwd/t.zip/a.tif``; an absolute
    or remote one (a URL, ``/vsicurl/...``) as given. None for a local path."""
    virtual = gdal_path(path)
    if virtual is None:
        return None
    archive = local_archive(virtual)
    if archive is None or os.path.isabs(archive):
        return path
    head = path.index("/", 1) + 1  # after the file system's prefix (/vsizip/), where local_archive found the archive
    head += path[head:head + 1] == "{"  # within GDAL's braces round it (/vsizip/{t.zip}/a.tif)
    return path[:head] + os.path.abspath(os.path.join(cwd, archive)) + path[head + len(archive):]


@dataclass(frozen=True, eq=False)
class _Source:
    """Heights that frame and tile items slice: (H, W) or (T, H, W), with the raster's geometry. Compared and hashed
    by identity (it holds an array)."""

    heights: NDArray[np.float32]
    spacing: tuple[float, float]
    origin: tuple[float, float]
    crs: str | None
    name: str
    #: (frame, row, col) of ``heights[0, 0(, 0)]`` in the whole source: a worker receives only its item's block
    offset: tuple[int, int, int] = (0, 0, 0)
    #: (min, max) of the whole source when a check found them without nodata (:func:`_shared_levels` reuses them)
    height_range: tuple[float, float] | None = None
    #: tiles: (lowest, highest) corner of the whole raster's surface, export.save_mesh's ``shared_bounds``, so
    #: that every tile stores the vertices it shares with its neighbours identically (glTF: float32 about one
    #: origin; PLY: float32 or float64, read back identically)
    bounds: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None


def _item_source(source: _Source, item: BatchItem) -> _Source:
    """The block of ``source`` that ``item`` reads (a view), so each dask task ships only its own heights."""
    if item.kind == "frame":
        return dataclasses.replace(source, heights=source.heights[item.index : item.index + 1],
                                   offset=(item.index, 0, 0))  # fmt: skip
    (r0, r1), (c0, c1) = item.rows, item.cols
    # with a ring of one node around the tile where the raster has one: a solid tile moves its heights on a threshold
    # by τ, which depends on each node's 8 neighbours (see _tile_off_thresholds)
    r0, c0 = max(r0 - 1, 0), max(c0 - 1, 0)
    return dataclasses.replace(source, heights=source.heights[r0 : r1 + 1, c0 : c1 + 1], offset=(0, r0, c0))


# ---------------------------------------------------------------------------------------------- planning
def plan_items(
    source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]] | Terrain | ArrayLike,
    *,
    tile_size: int | tuple[int, int] | None = None,
    height_unit: str | None = None,
    band: int | None = None,
    crop: ArrayLike | None = None,
    height_encoding: str | None = None,
    nodata: float | Sequence[float] | None = None,
) -> tuple[list[BatchItem], _Source | None]:
    """The items :func:`batch` would run for ``source`` (see there; ``nodata``: its files', read here for a series or
    a raster to tile), and the in-memory source they slice. A GeoTIFF
    (or another GDAL raster) cut into tiles is read only in the window of ``crop`` (load_dem's ``crop``: its nodes
    are those :meth:`Terrain.crop` keeps); other sources ignore it (:func:`batch` crops them after).

    Examples
    --------
    >>> import numpy as np
    >>> items, _ = plan_items(np.zeros((9, 9), np.float32), tile_size=4)
    >>> [(i.key, i.rows, i.cols) for i in items][:2]
    [('tile_r0_c0', (0, 5), (0, 5)), ('tile_r0_c1', (0, 5), (4, 9))]
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(os.fspath(source))
        virtual = _virtual_source(source)
        if virtual is not None:  # a raster GDAL reads in a zip or at a URL: one file item, or cut into tiles
            if tile_size is None:
                return _file_items([virtual]), None
            path = virtual
        elif path.is_dir():
            if tile_size is not None:
                raise InvalidInputError(
                    f"tile_size applies to one raster, not to a folder of tiles; got a folder {str(path)!r}"
                )
            # a broken link too (is_file() is False for it): an item that fails "does not exist", not a tile left
            # out without a word
            found = [p for p in path.iterdir() if (p.is_file() or (p.is_symlink() and not p.exists()))
                     and (p.suffix.lower() in _FOLDER_EXTENSIONS or _gzip_raster(p.name))]
            # hidden files left out, as the shell glob tiles/*.tif leaves them: macOS's AppleDouble "._t.tif" beside
            # every tile on a FAT/exFAT drive was an item each, failing as unreadable (exit status 1)
            files = sorted(p for p in found if not p.name.startswith("."))
            if not files:
                hidden = len(found) - len(files)
                raise InvalidInputError(
                    f"source folder {str(path)!r} holds no DEM file; expected files ending in "
                    f"{', '.join(_FOLDER_EXTENSIONS)} or {', '.join(_FOLDER_GZIPS)} (a .vrt is read only when named"
                    + (f"; {hidden} hidden file{'s' * (hidden != 1)}, named with a leading '.', left out"
                       if hidden else "") + ")"
                )
            # a gzip (N46E007.hgt.gz) as load_dem reads it: named as the file inside (its output N46E007.glb), its
            # path the .gz's (its fingerprint stats the .gz and the inner file's sidecars beside it)
            from .io import gzip_member

            return _file_items([gzip_member(f) if _gzip_raster(f.name) else f for f in files]), None
        if virtual is None and not path.exists():
            raise DataFileError(f"source {str(path)!r} does not exist (expected a DEM file or a folder of tiles)"
                                + _unmatched_glob(path))
        from .io import read_dem

        if tile_size is None:
            series = load_series(path, nodata) if path.suffix.lower() in (".npy", ".npz") else None
            if series is not None:
                if height_unit is not None:
                    raise InvalidInputError(
                        f"height_unit applies to DEM files, read by load_dem; a (T, H, W) series {str(path)!r} is "
                        f"read as stored; got height_unit={height_unit!r}"
                    )
                if height_encoding is not None:  # as load_dem refuses it for a file that is no PNG
                    raise InvalidInputError(
                        f"height_encoding applies to RGB PNG tiles; the (T, H, W) series {str(path)!r} holds "
                        f"heights; got height_encoding={height_encoding!r}"
                    )
                if band is not None and band != 1:  # as load_dem refuses a band of a format with one
                    raise InvalidInputError(
                        f"band applies to GDAL rasters only; the (T, H, W) series "
                        f"{str(path)!r} holds one band, got band={band}"
                    )
                # a file's rows run north to south, as load_dem reads a 2-D file: spacing (1, -1)
                return _frame_items(series), _Source(series, (1.0, -1.0), (0.0, 0.0), None, path.name)
            raise InvalidInputError(
                f"source {str(path)!r} is one 2-D raster: give tile_size (the CLI's --tile) to cut it into tiles"
            )
        try:
            # a GDAL raster's crop: its window only (other files are cropped by _reshaped_source)
            window = crop if path.suffix.lower() in GDAL_FORMATS else None
            terrain = read_dem(path, height_unit=height_unit, band=1 if band is None else band, crop=window,
                               refuse=lambda whole: _check_crop(whole, crop), height_encoding=height_encoding,
                               nodata=nodata)
        except DataFileError:
            # a (T, H, W) series file with tile_size said "cannot read ...: expected a 2-D (H, W) elevation grid",
            # as if the file were broken; a series in memory says what the option is for
            series = _series_or_none(path, nodata)
            if series is not None:
                raise InvalidInputError(
                    f"tile_size applies to one (H, W) raster; got a (T, H, W) series {series.shape} in "
                    f"{str(path)!r}: leave tile_size (the CLI's --tile) out to mesh one item per frame"
                ) from None
            raise
        return _tile_items(terrain.heights.shape, tile_size), _terrain_source(terrain)
    if isinstance(source, Terrain):
        if source.kind != "grid":
            raise InvalidInputError("batch tiles a grid Terrain; got a TIN (kind 'tin')")
        if tile_size is None:
            raise InvalidInputError(
                "source is one raster (a Terrain): give tile_size (the CLI's --tile) to cut it into tiles")
        return _tile_items(source.heights.shape, tile_size), _terrain_source(source)
    if isinstance(source, Sequence) and not isinstance(source, np.ndarray) and source and all(
        isinstance(s, (str, os.PathLike)) for s in source
    ):
        # a raster in a zip or at a URL (/vsizip/..., https://..., a .zip of one) as GDAL reads it: a GdalPath
        files = [_virtual_source(s) or Path(os.fspath(s)) for s in source]
        # checked here, as one file or a folder is: a folder among them was named "must end in .npy ...", a missing
        # file failed as an item after the cluster had started and the others were written, and a file given twice
        # (tiles/*.tif tiles/a.tif) was refused as two files writing one output, "rename one"
        folder = next((f for f in files if f.is_dir()), None)
        if folder is not None:
            raise InvalidInputError(
                f"source lists the folder {str(folder)!r} among DEM files; give the folder alone (one item per file "
                f"in it), or its files")
        # a .zip or .gz that is no file here is missing (one that is was read as its raster): it was "must end in ..."
        bad = [str(f) for f in files if f.suffix.lower() not in (*SUPPORTED_EXTENSIONS, ".zip", ".gz")]
        if bad:
            raise InvalidInputError(
                f"source files must end in {', '.join(SUPPORTED_EXTENSIONS)} (or name a GDAL virtual path, a URL, a "
                f"gzip of one raster, {', '.join(_FOLDER_GZIPS)}, or a .zip holding one raster); got {bad[0]!r}"
                + (f" and {len(bad) - 1} more" if len(bad) > 1 else "")
            )
        missing = [str(f) for f in files if not isinstance(f, GdalPath) and not f.exists()]
        if missing:
            raise DataFileError(f"source file {missing[0]!r} does not exist"
                                + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else "")
                                + _unmatched_glob(Path(missing[0])))
        seen: dict[Path, Path] = {}
        for f in files:
            same = seen.setdefault(Path(os.fspath(f)) if isinstance(f, GdalPath) else f.resolve(), f)
            if same is not f:
                twice = repr(str(f)) if str(same) == str(f) else f"as {str(same)!r} and {str(f)!r}"
                raise InvalidInputError(f"source names one file twice, {twice}; give each file once")
        return _file_items(files), None
    expected = "source must be a folder, a list of DEM files, a Terrain, an (H, W) raster or a (T, H, W) series"
    check_mapped(source, "source")  # np.load(mmap_mode="r"): the float32 copy below reads it all into memory
    try:
        array = np.asarray(unmasked(source))  # a masked array's masked entries are nodata (NaN), as in a Terrain
    except ValueError:  # frames of different shapes (numpy's "inhomogeneous shape")
        raise InvalidInputError(f"{expected}; got a {type(source).__name__} whose items differ in shape") from None
    if array.dtype.kind not in "iuf" or array.ndim not in (2, 3):  # bools are no heights, as in a Terrain
        raise InvalidInputError(
            f"{expected}; got {type(source).__name__} with shape {getattr(array, 'shape', None)}, dtype {array.dtype}"
        )
    heights = float32_heights(array, "source")  # 1e300 refused here: the cast would make it inf, each item "infinite"
    if heights.ndim == 3:
        if tile_size is not None:
            raise InvalidInputError(f"tile_size applies to one (H, W) raster; got a (T, H, W) series {heights.shape}")
        if heights.shape[0] < 1 or min(heights.shape[1:]) < 2:  # up front, as load_series refuses such a file
            raise InvalidInputError(f"source (a (T, H, W) series) needs at least one frame of at least 2 x 2 nodes; "
                                    f"got shape {heights.shape}")
        # an infinity up front, as the checks above: not one item failing later
        ranges = [finite_or_nan(frame, f"source frame {k}") for k, frame in enumerate(heights)]
        known = None if not ranges or any(math.isnan(lo) for lo, _ in ranges) else (  # NaN: a frame has nodata
            min(lo for lo, _ in ranges), max(hi for _, hi in ranges))
        return _frame_items(heights), _Source(heights, (1.0, 1.0), (0.0, 0.0), None, "series", height_range=known)
    if tile_size is None:
        raise InvalidInputError(
            f"source is one (H, W) raster {heights.shape}: give tile_size (the CLI's --tile) to cut it into tiles")
    items = _tile_items(heights.shape, tile_size)  # first: a (0, 0) raster reached min(), numpy's ValueError
    lo, hi = finite_or_nan(heights, "source")
    known = None if math.isnan(lo) else (lo, hi)
    return items, _Source(heights, (1.0, 1.0), (0.0, 0.0), None, "raster", height_range=known)


def _unmatched_glob(path: Path) -> str:
    """What to add to "does not exist" of a path that holds a shell wildcard: the shell passes a glob that matches
    no file on as written (tiles/n3*.tif), which read as the name of a file."""
    return ("; it reads as a shell glob that matched no file (the shell passes such a pattern on as written)"
            if any(ch in path.name for ch in "*?[") else "")


def load_series(path: str | os.PathLike[str],
                nodata: float | Sequence[float] | None = None) -> NDArray[np.float32] | None:
    """A (T, H, W) float32 stack from a ``.npy`` or ``.npz`` file (one 3-D array), or ``None`` if it holds 2-D.

    The file is read as :func:`~stepterrain.io.load_dem` reads a 2-D one: in an ``.npz`` the key it reads
    (``heights``, ``elevation`` or ``z``) decides when there is one (a 2-D ``elevation`` beside a 3-D texture is
    one raster), and a ``nodata`` number marks missing cells, and so do a boolean ``mask`` (True = missing) and
    ``valid`` (True = present), either or both, each of the series' (T, H, W) shape (one per frame) or of one frame's
    (H, W) (the same cells in every frame); those cells and non-finite heights become NaN (nodata).
    A finite height beyond float32, a series that is all nodata, a ``nodata`` that is not one number, a ``mask`` or
    ``valid`` that is not a boolean array of one of those shapes, and a file
    that is truncated or declares more data than it holds are a :class:`~stepterrain.errors.DataFileError`; so is
    an ``.npz`` series with a ``transform`` or other georeferencing keys (``crs``, ``dx``/``dy``,
    ``spacing``/``origin``, ``x``/``y``, ``lat``/``lon``, ...): a series is meshed unreferenced, as 1 m cells at
    (0, 0), and those keys were ignored without a word. An ``.npz``'s ``units`` converts the heights to metres as
    :func:`~stepterrain.io.load_dem` converts them (a unit it does not know is a DataFileError). ``nodata``:
    value(s) marking missing cells besides the file's own, as load_dem's ``nodata`` (compared in the stored dtype;
    not a real number: an InvalidInputError)."""
    from .io import (
        _heights_in_metres,
        _npz_text,
        check_nodata,
        nodata_as_nan,
        npz_georeference_keys,
        npz_missing,
        npz_nodata,
        read_npy,
        read_npz,
        refuse_npz_scaling,
    )

    given = check_nodata(nodata)
    file = Path(os.fspath(path))
    loaded = read_npy(file, mmap_mode="r") if file.suffix.lower() == ".npy" else read_npz(file)
    missing = None
    if isinstance(loaded, np.ndarray):
        stack, what, nodata = loaded, "array", None
    else:
        key = _series_key(loaded)
        if key is None or loaded[key].ndim != 3:
            return None
        unread = [name for name in loaded if name == "transform"] + npz_georeference_keys(loaded)
        if unread:  # np.savez(heights=stack, transform=..., crs=...) was meshed as 1 m cells at (0, 0)
            raise DataFileError(
                f"cannot read {str(file)!r}: a (T, H, W) series is meshed unreferenced, as 1 m cells at (0, 0) "
                f"(load_series reads no georeferencing); got {', '.join(map(repr, unread))} beside {key!r}, which "
                "would be ignored: drop those keys to mesh it unreferenced, or save each frame as a 2-D .npz with its "
                "georeferencing for load_dem (a folder of them is a batch source)"
            )
        refuse_npz_scaling(loaded, key, file)  # as load_dem refuses a scale it does not read
        stack, what, nodata = loaded[key], repr(key), npz_nodata(loaded.get("nodata"), file)
    if stack.ndim != 3:
        return None
    if stack.dtype.kind not in "iuf" or min(stack.shape) < 1 or stack.shape[1] < 2 or stack.shape[2] < 2:
        raise DataFileError(f"{str(file)!r} holds a (T, H, W) array of shape {stack.shape}, dtype {stack.dtype}; "
                            "expected real heights with H, W >= 2")
    if not isinstance(loaded, np.ndarray):  # a mask's cells were read as heights (0 or -32768 pits) in every frame
        missing = npz_missing(loaded, key, file, series=True)
    heights = nodata_as_nan(stack, file, what, nodata, missing, given=given)  # as load_dem reads a 2-D file
    if not isinstance(loaded, np.ndarray):  # 'units' = "ft" was meshed as metres, 3.3 times too high
        heights, _ = _heights_in_metres(heights, _npz_text(loaded, "units", file), file, "its 'units'")
    return heights


def _series_key(arrays: Mapping[str, Any]) -> str | None:
    """The member of an .npz's ``arrays`` (anything with an ``ndim`` by key) that :func:`load_series` reads as the
    heights (a series where it is 3-D): the key load_dem reads (``elevation`` ..., 2-D or 3-D here) decides, not
    any 3-D member; without one, the first 3-D member that is no mask or georeferencing (a (T, H, W) mask is no
    series of heights); else None."""
    from .io import _NPZ_NOT_HEIGHTS, npz_heights_key

    key = npz_heights_key(arrays, (2, 3))
    if key is None:
        key = next((k for k in arrays if arrays[k].ndim == 3 and k not in _NPZ_NOT_HEIGHTS), None)
    return key


def _series_or_none(path: Path, nodata: float | Sequence[float] | None = None) -> NDArray[np.float32] | None:
    """The (T, H, W) series in an .npy or .npz file that load_dem refused, else None (not a series, or no good)."""
    if path.suffix.lower() not in (".npy", ".npz"):
        return None
    try:
        return load_series(path, nodata)
    except DataFileError:
        return None


def _virtual_source(source: str | os.PathLike[str]) -> Path | None:
    """The file a source names through GDAL (:func:`~stepterrain.io.dem_path`): a ``/vsizip/...`` path or a URL, or
    a local ``.zip`` of one raster (one of several is refused, naming them: a zip is no folder of tiles here) or a
    local ``.gz`` of one (:func:`~stepterrain.io.gzip_member`); None
    for a local file or folder."""
    from .io import dem_path

    text = os.fspath(source)
    if not isinstance(text, str):
        return None
    if isinstance(source, GdalPath) or gdal_path(text) is not None or (text.lower().endswith((".zip", ".gz"))
                                                                       and os.path.isfile(text)):
        return dem_path(source)
    return None


def _one_raster_file(path: Path) -> bool:
    """Whether ``path`` is a DEM file holding one (H, W) raster: not a folder, nor a (T, H, W) series (an ``.npy``'s
    or ``.npz``'s headers read only: the CLI read an .npz whole here, then again as the series or the raster item).
    False when it cannot tell (a file whose headers it cannot read): the single-file source says why."""
    suffix = path.suffix.lower()
    if not path.is_file() or suffix not in SUPPORTED_EXTENSIONS:
        return False
    if suffix not in (".npy", ".npz"):
        return True
    from .io import npz_member_ndims, read_npy

    try:
        if suffix == ".npy":
            return read_npy(path, mmap_mode="r").ndim == 2
        ndims = npz_member_ndims(path)  # the headers only: a series is read once, by plan_items; a raster by its item
    except (DataFileError, InvalidInputError):
        return False
    if isinstance(ndims, int):  # an .npy under an .npz name
        return ndims != 3
    # load_series's choice of the heights (None: one raster), from the members' dimensions
    shaped = {name: np.empty((0,) * ndim) for name, ndim in ndims.items()}
    key = _series_key(shaped)
    return key is None or shaped[key].ndim != 3


def _terrain_source(terrain: Terrain) -> _Source:
    known = None if terrain.has_nodata else terrain.height_range  # both cached by Terrain.from_heights
    return _Source(terrain.heights, terrain.spacing, terrain.origin, terrain.crs, terrain.source or "raster",
                   height_range=known)  # fmt: skip


def _file_items(files: Sequence[Path]) -> list[BatchItem]:
    # names compared in lower case: on a case-insensitive file system (macOS, Windows) A.tif's output A.glb and
    # a.tif's a.glb are one file, the second item overwriting the first (and resumed from its manifest entry)
    stems = [f.stem.lower() for f in files]
    duplicated = {s for s in stems if stems.count(s) > 1}
    keys = [f.name.replace(".", "_") if f.stem.lower() in duplicated else f.stem for f in files]
    if len({k.lower() for k in keys}) != len(keys):  # the same file twice, a.npy beside a.npz (a_npy, a_npz) and
        first: dict[str, tuple[str, Path]] = {}  # a_npy.tif, or A.tif beside a.tif
        for key, f in zip(keys, files, strict=True):
            if key.lower() in first:
                other, earlier = first[key.lower()]
                outputs = (f"both write the output {key!r}" if other == key else f"write the outputs {other!r} and "
                           f"{key!r}, one file on a case-insensitive file system (macOS, Windows)")
                raise InvalidInputError(f"source files {str(earlier)!r} and {str(f)!r} would {outputs} (outputs are "
                                        "named after their files); rename one")
            first[key.lower()] = (key, f)
    return [BatchItem(key=k, kind="file", path=str(f)) for k, f in zip(keys, files, strict=True)]


def _frame_items(stack: NDArray[np.float32]) -> list[BatchItem]:
    width = max(4, len(str(len(stack) - 1)))
    return [BatchItem(key=f"frame_{i:0{width}d}", kind="frame", index=i) for i in range(len(stack))]


def _tile_items(shape: tuple[int, ...], tile_size: int | tuple[int, int]) -> list[BatchItem]:
    rows, cols = int(shape[0]), int(shape[1])
    try:
        sizes = (int(tile_size), int(tile_size)) if np.ndim(tile_size) == 0 else tuple(int(s) for s in tile_size)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InvalidInputError(f"tile_size must be an int or (rows, cols) of cells; got {tile_size!r}") from exc
    given = [tile_size] if np.ndim(tile_size) == 0 else list(tile_size)
    if (len(sizes) != 2 or min(sizes) < 1 or isinstance(tile_size, bool)
            or any(isinstance(g, (float, np.floating)) and g != int(g) for g in given)  # 2.5 is no tile size
            or any(isinstance(g, (str, bytes, bool, np.bool_)) for g in given)):  # int("4") took text as a number
        raise InvalidInputError(f"tile_size must be a positive int or (rows, cols) of cells; got {tile_size!r}")
    if rows < 2 or cols < 2:
        raise InvalidInputError(f"a raster to tile needs at least 2 x 2 nodes; got {rows} x {cols}")
    th, tw = sizes
    n_r, n_c = -(-(rows - 1) // th), -(-(cols - 1) // tw)  # ceil in ints: (rows - 1) / 10**400 was 0.0
    wr, wc = len(str(n_r - 1)), len(str(n_c - 1))
    items = []
    for r in range(n_r):  # tiles, not cells: a handful to thousands
        for c in range(n_c):
            r0, c0 = r * th, c * tw
            items.append(BatchItem(
                key=f"tile_r{r:0{wr}d}_c{c:0{wc}d}", kind="tile", rows=(r0, min(r0 + th, rows - 1) + 1),
                cols=(c0, min(c0 + tw, cols - 1) + 1), tile=(r, c),
            ))  # fmt: skip
    return items


# ---------------------------------------------------------------------------------------------- one item
def _item_terrain(item: BatchItem, source: _Source | None, height_unit: str | None = None,
                  spacing: tuple[float, float] | None = None, coarsen: int | None = None,
                  band: int | None = None, height_encoding: str | None = None,
                  nodata: Sequence[float] = ()) -> Terrain:
    if item.kind == "file":
        from .io import read_dem

        # a file of nodata only (a tile of sea cut from a coastal raster) is read, all NaN: an empty item, as a tile
        # of one raster is, not refused as not elevation data as load_dem refuses it
        terrain = read_dem(item.path, height_unit=height_unit, band=1 if band is None else band,  # type: ignore[arg-type]
                           nodata_only=True, height_encoding=height_encoding, nodata=nodata or None)
        if spacing is not None:
            _check_unreferenced(terrain.crs, terrain.spacing, terrain.origin, str(item.path))
            terrain = Terrain.from_heights(terrain.heights, spacing=spacing, source=terrain.source,
                                           height_unit=terrain.height_unit)  # fmt: skip
        if coarsen is None:
            return terrain
        return _coarsened(terrain, coarsen, empty=True)
    assert source is not None
    frame0, row0, col0 = source.offset
    if item.kind == "frame":
        return Terrain.from_heights(source.heights[item.index - frame0], spacing=source.spacing,
                                    origin=source.origin, source=f"{source.name}[{item.index}]")  # fmt: skip
    (r0, r1), (c0, c1) = item.rows, item.cols
    dx, dy = source.spacing
    return Terrain.from_heights(
        source.heights[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0],
        spacing=source.spacing,
        origin=(source.origin[0] + c0 * dx, source.origin[1] + r0 * dy),
        crs=source.crs,
        source=f"{source.name}[{r0}:{r1}, {c0}:{c1}]",
        _placed=True,  # the source Terrain's placement, cut: its CRS not looked up (nor its map scale warned) again
    )


def _tile_off_thresholds(item: BatchItem, source: _Source, terrain: Terrain, options: _Options) -> Terrain:
    """A solid tile's heights moved off the thresholds as the whole raster's solid moves them: τ (see
    :func:`~stepterrain.stepped._off_thresholds`) depends on each node's 8 neighbours and on the float32 step of the
    coordinates, so a node on a tile's edge, stepped from the tile alone, got another τ in each of the tiles that
    share it (their walls along that edge no longer matched; at γ < 1 the node's height neither). Here τ comes from
    the tile with a ring of one node of the raster around it (``_item_source`` ships it) and from the whole raster's
    coordinates: the same in every tile, and the whole raster's."""
    from .stepped import _off_thresholds, isovalues

    if source.bounds is None:
        return terrain
    _, row0, col0 = source.offset
    (r0, r1), (c0, c1) = item.rows, item.cols
    rows, cols = source.heights.shape[-2:]
    h0, h1 = max(r0 - 1, row0), min(r1 + 1, row0 + rows)
    w0, w1 = max(c0 - 1, col0), min(c1 + 1, col0 + cols)
    (dx, dy), (x0, y0) = source.spacing, source.origin
    ring = Terrain.from_heights(source.heights[h0 - row0 : h1 - row0, w0 - col0 : w1 - col0], spacing=source.spacing,
                                origin=(x0 + w0 * dx, y0 + h0 * dy))  # fmt: skip
    (xmin, ymin, _), (xmax, ymax, _) = source.bounds
    magnitude = max(abs(xmin), abs(xmax), abs(ymin), abs(ymax), xmax - xmin, ymax - ymin)
    values = isovalues(terrain.height_range, interval=options.interval, levels=options.levels, base=options.base)
    # a height left on its threshold unsaid (stepped says so for the tile itself): no catch_warnings block, whose
    # lock (the process's filters) ran the tiles of dask's threaded workers one at a time
    moved = _off_thresholds(ring, values, magnitude, warn=False)
    if moved is ring:
        return terrain
    heights = moved.heights[r0 - h0 : r1 - h0, c0 - w0 : c1 - w0]
    return Terrain.from_heights(heights, spacing=terrain.spacing, origin=terrain.origin, crs=terrain.crs,
                                source=terrain.source)  # fmt: skip


def _tile_borders_on_grid(mesh: Any, item: BatchItem, source: _Source, terrain: Terrain) -> Any:
    """``mesh`` (a tile stepped from ``terrain``) with the vertices on its last node column and row at the whole
    raster's x = x0 + c dx and y = y0 + r dy, the float64 values the neighbouring tiles' origins have there.

    :func:`~stepterrain.stepped` places a node at its terrain's origin plus the float32 local coordinate
    ``float32(j) * float32(dx)``: exact for a spacing such as 30 m, but for one such as 70.827 m (a raster in
    degrees as local metres) the tile's last column landed up to half a float32 step of the tile's extent (0.27 mm
    for 200 cells) off its right neighbour's first column, which lies at that neighbour's origin: the tiles'
    shared vertices differed in x (and y), in .ply by those bits, in .glb by a float32 step, and did not weld. Every
    vertex of those columns (nodes, wall crossings on the border's edges, a solid's skirt) has exactly that local
    coordinate, so those are moved, by at most that rounding; the first column and row lie at the origin already.
    """
    return _last_nodes_at(mesh, terrain, _tile_last_nodes(item, source))


def _tile_last_nodes(item: BatchItem, source: _Source) -> tuple[float, float]:
    """The whole raster's x of a tile's last node column and y of its last row, x0 + c dx and y0 + r dy: where
    :func:`_item_terrain` puts its right and lower neighbours' origins."""
    (_, r1), (_, c1) = item.rows, item.cols
    (dx, dy), (x0, y0) = source.spacing, source.origin
    return x0 + (c1 - 1) * dx, y0 + (r1 - 1) * dy


def _frame_borders_on_grid(mesh: Any, terrain: Terrain, frame: _Frame) -> Any:
    """``mesh`` (a file in degrees stepped in its folder's shared ``frame``, :func:`_in_frame`) with the vertices on
    its last node column and row where :func:`~stepterrain.io.shared_degree_frame` puts the first column and row of
    the file beside it, ``dx * k`` (``k`` a whole number of the mosaic's nodes), as :func:`_tile_borders_on_grid`
    does for tiles: neighbouring SRTM tiles' seams lay up to half a float32 step of a file's extent apart (0.12 mm
    for 60 cells of 70.6 m). A file off the mosaic's lattice (another resolution, a coarsened one) is left as is."""
    if terrain.spacing != frame.spacing:
        return mesh
    exact = _frame_last_nodes(frame, terrain.heights.shape)
    return mesh if exact is None else _last_nodes_at(mesh, terrain, exact)


def _frame_last_nodes(frame: _Frame, shape: tuple[int, ...]) -> tuple[float, float] | None:
    """Where :func:`_frame_borders_on_grid` puts the last node column and row of a file of ``shape`` (rows, cols) at
    ``frame``'s spacing: ``dx * (k + cols - 1)``, ``dy * (k + rows - 1)``; None for a file off the mosaic's lattice."""
    exact = []
    for origin, step, n in zip(frame.origin, frame.spacing, shape[::-1], strict=True):
        k = origin / step
        if k != round(k):
            return None
        exact.append(step * float(round(k) + n - 1))
    return exact[0], exact[1]


def _stepped_last_nodes(origin: tuple[float, float], spacing: tuple[float, float],
                        shape: tuple[int, ...]) -> tuple[float, float]:
    """The x of the last node column and the y of the last node row of a grid of ``shape`` (rows, cols) as
    :func:`~stepterrain.stepped` places them: its origin plus the float32 local coordinate
    ``float32(n - 1) * float32(dx)``."""
    rows, cols = shape
    return tuple(origin[axis] + np.float64(np.float32(n - 1) * np.float32(spacing[axis]))  # type: ignore[return-value]
                 for axis, n in ((0, cols), (1, rows)))  # fmt: skip


def _seams_moved(item: BatchItem, source: _Source | None, options: _Options) -> bool:
    """Whether :func:`_run_item` moves ``item``'s last node column or row onto its neighbour's first
    (:func:`_tile_borders_on_grid`, :func:`_frame_borders_on_grid`), from its placement alone, before it is stepped:
    a tile or a file of a mosaic in degrees whose spacing float32 does not hold (70.827 m), not one at 30 m, a
    series' frame or a file in its own frame. Such an item's fingerprint holds a mark (:func:`_fingerprints`), so
    that a resumed run made before its seams were moved redoes it, and only it."""
    if item.kind == "tile" and source is not None:
        (r0, r1), (c0, c1) = item.rows, item.cols
        (dx, dy), (x0, y0) = source.spacing, source.origin
        stepped_at = _stepped_last_nodes((x0 + c0 * dx, y0 + r0 * dy), source.spacing, (r1 - r0, c1 - c0))
        return stepped_at != _tile_last_nodes(item, source)
    frame = options.frame_of(item.key) if item.kind == "file" else None
    # a coarsened file lies off the mosaic's spacing (_in_frame: its own times N), which _frame_borders_on_grid leaves
    if frame is None or frame.shape is None or options.coarsen not in (None, 1):
        return False
    exact = _frame_last_nodes(frame, frame.shape)
    return exact is not None and _stepped_last_nodes(frame.origin, frame.spacing, frame.shape) != exact


def _last_nodes_at(mesh: Any, terrain: Terrain, exact: tuple[float, float]) -> Any:
    """``mesh`` (stepped from the grid ``terrain``) with the vertices :func:`~stepterrain.stepped` put on the grid's
    last node column (x: its origin plus ``float32(j) * float32(dx)``, as the kernel computes it) at ``exact[0]``,
    and those on its last row at ``exact[1]``."""
    stepped_at = _stepped_last_nodes(terrain.origin, terrain.spacing, terrain.heights.shape)
    vertices = mesh.vertices  # moved in place: a copy and its assignment back were 23 ms of 1.6 M vertices, now 8
    for axis in (0, 1):
        computed = stepped_at[axis]
        if computed != exact[axis]:
            hit = np.flatnonzero(vertices.view(np.ndarray)[:, axis] == computed)  # trimesh's TrackedArray: slower
            if len(hit):
                vertices[hit, axis] = exact[axis]  # through the TrackedArray: the mesh's cache sees the change
    return mesh


def _check_unreferenced(crs: str | None, spacing: tuple[float, float], origin: tuple[float, float], name: str) -> None:
    """An InvalidInputError naming ``spacing=`` when a DEM file places its nodes itself (load_dem reads a file
    without georeferencing as 1 m cells at (0, 0), rows north to south: io.own_placement)."""
    from .io import own_placement

    placed = own_placement(crs, spacing, origin)
    if placed is not None:
        raise InvalidInputError(
            f"spacing applies to DEM files with no georeferencing (.npy, a PNG heightmap, a GeoTIFF without a "
            f"geotransform); {name!r} places its nodes itself: {placed}")


def _file_spacing(spacing: ArrayLike) -> tuple[float, float]:
    """``spacing=`` for DEM files without georeferencing: one cell size D or (dx, dy), positive metres, as the
    Terrain spacing (dx, -dy) (rows north to south, as load_dem reads them)."""
    try:
        values = np.asarray(spacing, np.float64).reshape(-1)
    except (TypeError, ValueError):
        values = np.array([])
    if isinstance(spacing, (str, bytes, bool)) or values.size not in (1, 2) or not np.all(np.isfinite(values)) or (
            values.min() <= 0):
        raise InvalidInputError(f"spacing must be one cell size D or (dx, dy) in positive metres for DEM files with "
                                f"no georeferencing (rows run north to south); got {spacing!r}")
    return float(values[0]), -float(values[-1])


def _coarse_geometry(terrain: Terrain, factor: int) -> Any:
    """``terrain._coarse_geometry(factor)``, its refusal named as :func:`_coarsened` names it."""
    try:
        return terrain._coarse_geometry(factor)
    except InvalidInputError as exc:
        raise InvalidInputError(f"coarsen={factor}: {exc}") from None


def _coarsened(terrain: Terrain, factor: int, *, empty: bool = False) -> Terrain:
    """``terrain.coarsen(factor)`` (block means), its refusal naming ``coarsen``. ``empty``: a grid whose blocks hold
    no finite node (nodata only, or its finite nodes all in the last rows and columns, beyond the last whole block)
    becomes a coarse grid of nodata, an empty item (as a file or frame of nodata only is), where coarsen refuses it:
    a coast tile whose land lay in its last row failed its item, and such a frame of a series the whole batch (found
    by the coarsening itself: its blocks' means all NaN, no pass over the heights before it)."""
    try:
        return terrain._coarsen(factor, empty_ok=empty)
    except InvalidInputError as exc:
        raise InvalidInputError(f"coarsen={factor}: {exc}") from None


def _of_files(source: Any) -> bool:
    """Whether a batch ``source`` names DEM files (a path, a glob, a folder, or a list of paths), which load_dem reads:
    what ``height_unit`` and ``band`` apply to."""
    return isinstance(source, (str, os.PathLike)) or (
        isinstance(source, (list, tuple)) and all(isinstance(f, (str, os.PathLike)) for f in source))


def _check_crop(terrain: Terrain, crop: ArrayLike) -> tuple[tuple[float, float, float, float], tuple[int, int],
                                                           tuple[int, int]]:
    """:meth:`Terrain._crop_nodes` of ``crop`` for ``terrain``: :meth:`Terrain.crop`'s refusals but that of nodata
    only, named as :func:`_reshaped_source` names them (a GeoTIFF read only in the crop's window is checked so
    first)."""
    try:
        return terrain._crop_nodes(crop)
    except InvalidInputError as exc:
        raise InvalidInputError(f"crop {exc}") from None  # "crop extent (...) holds 0 x 0 nodes ..."


def _reshaped_source(src: _Source, crop: ArrayLike | None, coarsen: int | None) -> _Source:
    """``src`` cropped to ``crop`` (:meth:`Terrain.crop`), then coarsened ``coarsen`` times (:meth:`Terrain.coarsen`,
    block means): one raster before it is cut into tiles, so that the tiles still share their border nodes (tiles
    coarsened one by one would not: a tile's blocks start at its own first node), or every frame of a series alike."""
    series = src.heights.ndim == 3
    # the geometry from a probe of the source's shape whose heights are one zero, broadcast (a series' frames share
    # it; a frame of nodata only is an empty item, which Terrain.crop and .coarsen would refuse): a full-size grid of
    # zeros, checked and cropped and coarsened, cost 20 ms to 200 ms at 4000 x 4000 for a few numbers
    probe = Terrain._geometry_only(src.heights.shape[-2:], src.spacing, src.origin,
                                   src.crs)  # the CRS for crop's refusal of an extent in degrees
    heights = src.heights
    if crop is not None:
        _, (i0, i1), (j0, j1) = _check_crop(probe, crop)
        (dx, dy), (ox, oy) = src.spacing, src.origin
        i1, j1 = i1 + 1, j1 + 1
        heights = heights[..., i0:i1, j0:j1]
        probe = Terrain._geometry_only((i1 - i0, j1 - j0), src.spacing, (ox + j0 * dx, oy + i0 * dy), src.crs)
        if not np.isfinite(heights).any():
            raise InvalidInputError(f"crop extent {tuple(float(v) for v in np.asarray(crop, np.float64).reshape(-1))}"
                                    f" holds only nodata of the source ({i1 - i0} x {j1 - j0} nodes)")
    spacing, origin = probe.spacing, probe.origin
    if coarsen is not None:
        _, shape, spacing, origin = _coarse_geometry(probe, coarsen)
        frames = []
        for frame in (heights if series else heights[None]):
            if np.isfinite(frame).any():
                frames.append(_coarsened(Terrain.from_heights(frame, spacing=probe.spacing, origin=probe.origin),
                                         coarsen, empty=series).heights)  # a frame whose land it drops: empty too
            else:  # nodata only: stays so, an empty item
                frames.append(np.full(shape, np.nan, np.float32))
        heights = np.stack(frames) if series else frames[0]
    return dataclasses.replace(src, heights=np.ascontiguousarray(heights), spacing=spacing, origin=origin,
                               height_range=None)


def _has_surface(terrain: Terrain) -> bool:
    """Whether some triangle of the grid has three finite heights."""
    if not terrain.has_nodata:
        return True
    upper, lower = finite_triangles(np.isfinite(terrain.heights))
    return bool(upper.any() or lower.any())


#: glTF extras keys stepterrain writes on every batch output (stepped's and batch's own; :func:`_item_metadata`
#: adds the item's): a ``metadata`` key among them is refused. ``generator`` is not: the caller's names the program
_LIBRARY_KEYS: frozenset[str] = frozenset(
    ("isovalues", "gamma", "source", "crs", "floor", "interval", "base", "empty", "batch_item")
)


def _item_metadata(item: BatchItem) -> dict[str, Any]:
    meta: dict[str, Any] = {"batch_item": item.key}
    if item.kind == "tile":
        meta.update(tile_row=item.tile[0], tile_col=item.tile[1], node_rows=list(item.rows), node_cols=list(item.cols))
    elif item.kind == "frame":
        meta["frame"] = item.index
    else:
        meta["input"] = item.path
    return meta


# errno values of an OSError worth another attempt: the medium or the network, not the data or a permission
_TRANSIENT_ERRNOS = frozenset(
    getattr(errno, name) for name in ("EIO", "ENOSPC", "EDQUOT", "EAGAIN", "EBUSY", "EINTR", "ETIMEDOUT", "ESTALE",
                                      "ENOMEM", "ECONNRESET", "ENETDOWN", "EREMOTEIO")
    if hasattr(errno, name)
)


def _transient(exc: BaseException) -> bool:
    """True when an OSError with a transient errno lies under ``exc`` (its chain of causes and contexts)."""
    seen: set[int] = set()
    cause: BaseException | None = exc
    while cause is not None and id(cause) not in seen:
        seen.add(id(cause))
        if isinstance(cause, OSError) and cause.errno in _TRANSIENT_ERRNOS:
            return True
        cause = cause.__cause__ or cause.__context__
    return False


class _BudgetLease:
    """The memory budget of the items one worker process runs at once. A dask worker of several threads ran them
    concurrently, each setting the process-wide budget and restoring the one it found: the second found the first's,
    so the worker kept a client's budget for good, and an item stepped under the budget another item had just put
    back (or another client's). Here the first item in sets its budget and the last one out restores the process's;
    an item with another budget (another client's) waits until the items under the one set are done, and items of
    the budget set wait behind it (so that it is not kept waiting for ever)."""

    def __init__(self) -> None:
        self._changed = threading.Condition()
        self._budget: int | None = None  # set while items hold it
        self._holders = 0
        self._previous = 0  # the process's own, restored by the last holder
        self._others = 0  # items waiting for a budget other than the one set

    @contextmanager
    def hold(self, budget: int) -> Iterator[None]:
        from ._compaction import set_memory_budget

        with self._changed:
            # counted in _others whenever it waits for another budget: an item that first waited behind one (its
            # own budget set) and then found another's set (that item took the worker first) waited uncounted, and
            # the other budget's items that kept arriving joined ahead of it, one after another
            other = False
            try:
                while self._holders and (self._budget != budget or (self._others and not other)):
                    if self._budget != budget and not other:
                        other = True
                        self._others += 1
                    self._changed.wait()
            finally:
                if other:
                    self._others -= 1
                    self._changed.notify_all()  # items of the budget set waited behind it
            if not self._holders:
                self._previous, self._budget = set_memory_budget(budget), budget
            self._holders += 1
        try:
            yield
        finally:
            with self._changed:
                self._holders -= 1
                if not self._holders:
                    set_memory_budget(self._previous)
                    self._budget = None
                    self._changed.notify_all()


_BUDGET_LEASE = _BudgetLease()
#: Held while an item's warnings are recorded (:func:`run_item`): Python's warning filters and display are the
#: process's, and ``warnings.catch_warnings`` puts back what it found on exit. Two serial runs in two threads recorded
#: at once: the second put back the first's recorder, so that every later warning of the process went into a list
#: nobody read, and the "default" filter stayed before the user's own.
_RECORDING = FILTERS  # the lock of every warning block of the library (stepterrain._warning_filters), re-entrant


def run_item(
    item: BatchItem, source: _Source | None, options: _Options, output_dir: str, cpu_threads: int | None = None,
    memory_budget: int | None = None, record_warnings: bool = False, terrain: Terrain | None = None,
) -> ItemResult:
    """Step one item and write its mesh (atomically); the task each dask worker runs.

    ``memory_budget``: the caller's :func:`~stepterrain.get_memory_budget`, set in the worker's process for this
    item and restored after it (a worker process has its own, the default, otherwise); items a worker's threads run at
    once share it when it is the same, and one with another waits for the others to finish (:class:`_BudgetLease`).
    ``cpu_threads`` is set only in the LocalCluster's workers of one thread each (and not restored).
    ``record_warnings``: the item's warnings go into its result's ``warnings`` instead of the worker's stderr (for
    single-threaded worker processes and the serial run: Python records a process's warnings, so items recorded in
    several threads of one process, serial runs in threads, run one at a time). ``terrain``: the item's heights
    read already in this process (a file's, by the serial run's height-range pass), not read again.

    Bad input data (:class:`~stepterrain.errors.StepTerrainError`) gives a ``failed`` result at once, unless
    a transient OSError lies under it (EIO, ENOSPC, ETIMEDOUT, ...: a disk or network hiccup while reading or
    writing); that and any other exception propagate so the scheduler retries the task.
    """
    from ._compaction import budget_value
    from ._device import set_cpu_threads

    start, cpu_start = time.perf_counter(), time.process_time()
    if cpu_threads is not None:
        set_cpu_threads(cpu_threads)
    # the caller's budget for this item only: a remote worker kept it for other clients' tasks afterwards
    read = {} if terrain is None else {"terrain": terrain}
    with nullcontext() if memory_budget is None else _BUDGET_LEASE.hold(budget_value(memory_budget)):
        if record_warnings:  # a worker process printed them as "<dask's file>:768: UserWarning: ..." + a source line
            with _RECORDING, warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("default")
                result = _run_item(item, source, options, output_dir, start, cpu_start, **read)
            said = tuple(dict.fromkeys(str(w.message) for w in caught))
            return dataclasses.replace(result, warnings=said) if said else result
        return _run_item(item, source, options, output_dir, start, cpu_start, **read)


def _run_item(item: BatchItem, source: _Source | None, options: _Options, output_dir: str, start: float,
              cpu_start: float, *, terrain: Terrain | None = None) -> ItemResult:
    import trimesh

    from .stepped import stepped

    target = Path(output_dir) / f"{item.key}{options.ext}"  # as reported: the caller's path
    # a worker started in another folder than the caller's read tiles/a.tif and wrote out/ there: relative to its own
    written = Path(_on_worker(output_dir, options.cwd)) / target.name
    read = item if item.path is None else dataclasses.replace(item, path=_on_worker(item.path, options.cwd))
    try:
        if terrain is None:
            terrain = _item_terrain(read, source, options.height_unit, options.file_spacing, options.coarsen,
                                    options.band, options.height_encoding, options.nodata)  # fmt: skip
        frame = options.frame_of(item.key)
        if frame is not None:
            terrain = _in_frame(terrain, frame)
        elif options.several_files and item.kind == "file":
            _warn_own_local_metres(terrain, options.coarsen)
        metadata = {"generator": "stepterrain.batch", **dict(options.metadata), **_item_metadata(item)}
        if not _has_surface(terrain):
            # an item with no triangle of three finite heights (sea off a coast, a gap in a series, a tile file of
            # sea): an empty mesh, as stepped() gives for finite nodes that make no triangle, also for a solid (which
            # stepped refuses), marked "empty" whether the item is a piece of one source or a file of a folder
            mesh = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
            metadata["empty"] = "no triangle with three finite heights (nodata)"
        else:
            if options.solid and item.kind == "tile" and source is not None:
                terrain = _tile_off_thresholds(item, source, terrain, options)
            mesh = stepped(
                terrain, interval=options.interval, levels=options.levels, base=options.base, gamma=options.gamma,
                colors=options.colors, solid=options.solid, floor=options.floor, device=options.device,
            )  # fmt: skip
            if item.kind == "tile" and source is not None:
                mesh = _tile_borders_on_grid(mesh, item, source, terrain)
            elif frame is not None:
                mesh = _frame_borders_on_grid(mesh, terrain, frame)
        with replacing_without_flush():  # a tile a crash empties fails the manifest's size check: redone, not lost
            save_mesh(mesh, written, metadata=metadata, shared_bounds=None if source is None else source.bounds)
        n_faces, n_vertices = len(mesh.faces), len(mesh.vertices)
    except StepTerrainError as exc:
        if _transient(exc):
            raise  # a disk or network hiccup under the library's error (e.g. EIO, ENOSPC): retried like any other
        return ItemResult(item.key, "failed", error=f"{_error_name(exc)}: {exc}", attempts=1,
                          seconds=time.perf_counter() - start, cpu_seconds=time.process_time() - cpu_start)  # fmt: skip
    # A Trimesh refers to itself (its visuals, caches and query helpers hold the mesh), so only the cyclic
    # garbage collector frees its arrays, and by then it has often moved them to its oldest generation: a worker
    # held 1.7 GB of dead 1024² tiles instead of 0.36 GB. The mesh is still young here, and collecting the young
    # generations frees it at once for a fraction of a millisecond.
    del mesh, terrain
    gc.collect(1)
    return ItemResult(
        item.key, "done", path=str(target), attempts=1, seconds=time.perf_counter() - start,
        cpu_seconds=time.process_time() - cpu_start, faces=n_faces, vertices=n_vertices,
        bytes=written.stat().st_size,
    )  # fmt: skip


def _error_name(exc: BaseException) -> str:
    """The name a failed item's error gives ``exc``'s class: its first public one (io's ``_NotDegrees``, a grid in
    degrees whose nodes are none, is a DataFileError to the caller)."""
    return next(c.__name__ for c in type(exc).__mro__ if not c.__name__.startswith("_"))


def _degree_frames(items: Sequence[BatchItem]) -> tuple[tuple[str, _Frame], ...]:
    """The frames of the file items in degrees (:class:`_Frame`), by key: the files of one geographic CRS, two or more,
    placed in the local metres of their mosaic (:func:`~stepterrain.io.shared_degree_frame`), from their headers, so
    that their meshes lie side by side and weld where neighbours share border nodes, as a projected folder's do and as
    the tiles of their ``.vrt`` cut with ``tile_size`` do. load_dem placed each in local metres of its own, node
    (0, 0) at its first node: the meshes of a folder of SRTM tiles lay on top of one another at (0, 0). None for a file
    load_dem does not read through GDAL (an .npz in degrees), a rotated grid, nor one alone in its CRS: each stays in
    its own frame (and :func:`_warn_own_local_metres` says so). Files in two or more geographic CRSs make a frame per
    CRS, whose meshes overlap at (0, 0): a warning says so once, naming the CRSs. So does one for files in two or
    more CRSs of which one is projected (:func:`_warn_projected_crss`)."""
    from .io import _placement, raster_header, shared_degree_frame

    groups: dict[str, list[tuple[BatchItem, tuple[float, ...], tuple[int, int]]]] = {}
    projected: list[str] = []  # the CRS of each file in a projected one, for the warning that they do not line up
    for item in items:
        header = raster_header(item.path) if item.kind == "file" and item.path is not None else None
        if header is not None and header[1]:
            groups.setdefault(header[0], []).append((item, header[2], header[3]))
        elif header is not None:
            projected.append(header[0])
    _warn_projected_crss(projected, {crs: len(found) for crs, found in groups.items()})
    frames: list[tuple[str, _Frame]] = []
    placed_in: list[str] = []  # the CRSs of the frames, for the warning that they do not line up
    for crs, found in groups.items():
        group: list[tuple[BatchItem, tuple[float, ...], tuple[int, int]]] = []
        own: list[tuple[float, float]] = []
        with _RECORDING, warnings.catch_warnings():  # each file's own read warns of its own metres, not this
            warnings.simplefilter("ignore")
            for item, g, shape in found:
                try:
                    own.append(_placement(Path(str(item.path)), shape, np.array(g, np.float64), crs, geographic=True,
                                          metres=None, height_unit=None).spacing)  # fmt: skip
                except StepTerrainError:  # a file load_dem refuses (a zero pixel size, latitudes beyond 90): out of
                    continue  # the mosaic (a zero step ended the run in it), its item fails as its read says why
                group.append((item, g, shape))
        if len(group) < 2:
            continue
        try:
            _, frame_crs, source, placed = shared_degree_frame(crs, [g for _, g, _ in group], [s for _, _, s in group])
        except StepTerrainError:  # the union is no degrees (over 360 of longitude): each file in its own frame
            _warn_antimeridian(crs, group, placed=False)
            continue
        _warn_antimeridian(crs, group, placed=True)
        for (item, _, shape), spacing_own, (spacing, origin) in zip(group, own, placed, strict=True):
            name = Path(str(item.path)).name
            frames.append((item.key, _Frame(spacing_own, spacing, origin, frame_crs, f"{name}, placed in {source}",
                                            shape=(int(shape[0]), int(shape[1])))))  # fmt: skip
        placed_in.append(f"{crs} ({len(group)} files)")
    if len(placed_in) > 1:  # each frame's node (0, 0) at its own mosaic's top-left node: the meshes overlap
        warnings.warn(
            f"the DEM files in degrees are in {len(placed_in)} geographic CRSs ({', '.join(placed_in)}): each CRS's "
            "files are placed in the local metres of their own mosaic (node (0, 0) at its top-left node), so the "
            "meshes of one CRS neither line up nor weld with those of another: to step them as one surface, warp "
            "them to one CRS first (gdalwarp -dstalpha -t_srs EPSG:4326; -dstalpha marks the cells outside the files "
            "missing: without it, and without a nodata value of the files, they are 0 m)",
            stacklevel=caller_stacklevel(),
        )
    return tuple(frames)


def _warn_projected_crss(projected: Sequence[str], geographic: Mapping[str, int]) -> None:
    """Warn once when a folder's files lie in two or more CRSs, one of them projected: ``projected``, the CRS of each
    file in a projected one, ``geographic``, the number of files in each geographic CRS. Each file's mesh lies in
    its own CRS's coordinates as load_dem places it (a projected CRS's metres,
    :func:`~stepterrain.io.projected_frame_crs`; files in degrees in local metres of their mosaic, node (0, 0) at
    its top-left node), so the meshes of files in
    UTM zones 10 and 11, or in a UTM zone and in degrees, lay hundreds of kilometres apart or on top of one another
    without a word, where files in two geographic CRSs were warned of. CRSs are told apart as rasterio compares them
    (EPSG:32611 and its ESRI WKT are one)."""
    from .io import _crs_object, projected_frame_crs

    counts: dict[str, int] = {}
    for crs in projected:
        placed = projected_frame_crs(crs)
        parsed = _crs_object(placed)
        same = next((known for known in counts if known == placed or (
            parsed is not None and _crs_object(known) == parsed)), placed)  # fmt: skip
        counts[same] = counts.get(same, 0) + 1
    if not counts or len(counts) + len(geographic) < 2:
        return

    named = [f"{crs} ({counted(n, 'file')})" for crs, n in counts.items()]
    named += [f"{crs} ({counted(n, 'file')} in degrees)" for crs, n in geographic.items()]
    target = max(counts, key=lambda crs: counts[crs])
    warnings.warn(
        f"the DEM files are in {len(named)} CRSs ({', '.join(named)}): each file's mesh lies in its own CRS's "
        "coordinates (a projected CRS's metres; files in degrees in local metres of their own, node (0, 0) at "
        "their mosaic's top-left node), so the meshes of one CRS neither line up nor weld with those of another: to "
        f"step them as one surface, warp them to one CRS first (gdalwarp -dstalpha -t_srs {shlex.quote(target)} "
        "FILE OUT.tif)",  # quoted: a CRS without an EPSG code is named by its WKT
        stacklevel=caller_stacklevel(),
    )


def _warn_antimeridian(crs: str, group: Sequence[tuple[BatchItem, Sequence[float], tuple[int, int]]], *,
                       placed: bool) -> None:
    """Warn when the files in degrees of ``group`` (item, geotransform, shape) in ``crs`` lie either side of the
    antimeridian, or in two longitude conventions (-180 to 180 and 0 to 360): their mosaic would be narrower by over
    half the globe wrapped across it than as the ``.vrt`` of ``gdalbuildvrt`` lays them, from their westmost to their
    eastmost cell. ``placed``: their shared frame, that .vrt's, puts the two sides a whole parallel apart; else their
    union spanned more than 360 degrees of longitude, and each file was left in local metres of its own. It names the
    ``+lon_wrap`` that joins the sides: 180 (0 to 360) across the antimeridian, 0 (-180 to 180) for files in 0 to 360
    either side of the prime meridian (lon 359.9 to 360 and 0 to 0.1), which 0 to 360 leaves a parallel apart."""
    spans = sorted((min(g[0], g[0] + w * g[1]), max(g[0], g[0] + w * g[1]), Path(str(item.path)).name)
                   for item, g, (_, w) in group)  # fmt: skip
    reach, gap, split = spans[0][1], -math.inf, 0  # the widest gap between the files, and the first file past it
    for i, (west, east, _) in enumerate(spans[1:], start=1):
        if west - reach > gap:
            gap, split = west - reach, i
        reach = max(reach, east)
    wrapped = 360.0 - (reach - spans[0][0])  # the gap across the antimeridian (negative: the union is over 360)
    if gap - max(wrapped, 0.0) <= 180.0:
        return

    # the sides joined, the western one's longitudes 360 on, from a west edge in [0, 360): over half the globe
    # narrower than the gap, so within 0 to 360 (the antimeridian between the sides) or 180 to 540 (-180 to 180)
    lo = min(min(w for w, _, _ in spans[split:]), min(w for w, _, _ in spans[:split]) + 360.0)
    hi = max(max(e for _, e, _ in spans[split:]), max(e for _, e, _ in spans[:split]) + 360.0)
    hi -= math.floor((lo + 1e-9) / 360.0) * 360.0  # longitudes -360 to 0 alike
    wrap, seam = (180.0, "the antimeridian") if hi <= 360.0 + 1e-9 else (
        0.0, "the prime meridian, where longitudes 0 to 360 wrap as -180 to 180 wrap at the antimeridian")
    convention = "0 to 360" if wrap else "-180 to 180"

    def named(side: Sequence[tuple[float, float, str]]) -> str:
        names = ", ".join(n for _, _, n in side[:3]) + (f" and {len(side) - 3} more" if len(side) > 3 else "")
        return f"{names} (lon {min(w for w, _, _ in side):.9g} to {max(e for _, e, _ in side):.9g})"

    how = (f"their mosaic's local metres, as in the .vrt gdalbuildvrt makes of them, put the two sides {gap:.9g} "
           "degrees of longitude apart, so their meshes lie a whole parallel apart and do not weld"
           if placed else "together they span more than 360 degrees of longitude, so each file is placed in local "
           "metres of its own (node (0, 0) at its first node), their meshes on top of one another")
    warnings.warn(
        f"the DEM files in degrees {named(spans[:split])} and {named(spans[split:])} in {crs} lie either side of "
        f"{seam}, or in two longitude conventions (-180 to 180 and 0 to 360): {how}; to step them as one surface, "
        f"give each file longitudes {convention} first (gdalwarp -dstalpha -t_srs '+proj=longlat +datum=WGS84 "
        f"+lon_wrap={wrap:g}'), or step each side as a folder of its own",
        stacklevel=caller_stacklevel(),
    )


def _in_frame(terrain: Terrain, frame: _Frame) -> Terrain:
    """``terrain`` (a file in degrees as :func:`_item_terrain` read it: load_dem's own local metres, perhaps coarsened)
    moved into its folder's shared frame: its nodes where ``frame`` puts the file's, the mosaic's CRS; an
    unchanged file's spacing and origin exactly the frame's. The heights are borrowed, not copied: the read terrain
    is dropped for this one (a 3601² SRTM tile held twice was 52 MB more)."""
    (ox, oy), (kx, ky) = terrain.origin, frame.own
    spacing = (frame.spacing[0] * (terrain.spacing[0] / kx), frame.spacing[1] * (terrain.spacing[1] / ky))
    origin = (frame.origin[0] + frame.spacing[0] * (ox / kx), frame.origin[1] + frame.spacing[1] * (oy / ky))
    return Terrain.from_heights(terrain.heights, spacing=spacing, origin=origin, crs=frame.crs, source=frame.source,
                                height_unit=terrain.height_unit, _placed=True, _borrow=True)  # fmt: skip


def _warn_own_local_metres(terrain: Terrain, coarsen: int | None = None) -> None:
    """Warn when a DEM file of several was read from degrees (:func:`~stepterrain.io.load_dem`: local metres of its
    own, node (0, 0) at its first node, its own ``+proj=eqc`` CRS) and left there, out of the shared frame of
    :func:`_degree_frames` (an .npz in degrees, a file alone in its geographic CRS): its mesh lies at (0, 0), and does
    not weld with neighbours that share its border nodes. One message for every file, so a run says it once.
    ``coarsen``: the file's factor, whose first node, a block's mean, lies half a block from node (0, 0)."""
    from .io import _lonlat_grid

    if terrain.kind != "grid":
        return
    half = 0.0 if coarsen is None else (coarsen - 1) / 2 / coarsen  # Terrain.coarsen's origin, in coarse cells
    first = tuple(half * step for step in terrain.spacing)
    at_its_own = all(math.isclose(o, f, rel_tol=1e-9) for o, f in zip(terrain.origin, first, strict=True))
    if at_its_own and _lonlat_grid(terrain) is not None:
        warnings.warn(
            "DEM files in degrees that GDAL does not read (an .npz), one alone in its geographic CRS, or files whose "
            "mosaic would span more than 360 degrees of longitude, are not placed in the local metres the other "
            "files in degrees share: each is placed in local metres of its own "
            "(node (0, 0) at its first node, the +proj=eqc CRS of its mesh's metadata), so their meshes neither line "
            "up nor weld where neighbours share their border nodes: to step them as one surface, convert them to "
            "GeoTIFFs (gdal_translate), or mosaic them (gdalbuildvrt tiles.vrt "
            "FILES) and cut the .vrt into tiles of tile_size cells, or warp them into one "
            "projected raster (gdalwarp -dstalpha -t_srs EPSG:... FILES dem.tif; -dstalpha marks the cells between "
            "and around the files missing: without it, and without a nodata value of the files, they are 0 m) and "
            "cut that (files reprojected one by one lie in place but share no nodes with their neighbours)",
            stacklevel=2,
        )


# ---------------------------------------------------------------------------------------------- resume
def _fingerprints(items: Sequence[BatchItem], source: _Source | None, options: _Options,
                  identities: Mapping[str, str] | None = None) -> dict[str, str]:
    """Per item: a hash of its input (file identity or the sliced heights) and the shared options.

    The device is left out: every device gives the same bits (kernels/__init__), so a run resumed on another
    machine or device keeps what is done. ``identities``: the file items' :func:`_file_identities` when the caller
    has them already (a folder's run, which keys the files' height ranges by them too), else found here."""
    shared = repr(dataclasses.replace(options, device=None))
    if options.height_unit is not None:
        shared += f"|height_unit={options.height_unit!r}"
    if options.band is not None:
        shared += f"|band={options.band!r}"
    if options.height_encoding is not None:
        shared += f"|height_encoding={options.height_encoding!r}"
    head = json.dumps([shared, _source_identity(source)], sort_keys=True).encode()
    out = {}
    if identities is None:
        identities = _file_identities(items)
    for item in items:  # per item, not per cell: hashing is vectorised over each item's bytes
        h = hashlib.blake2b(head, digest_size=16)
        # a file by its absolute path, as _file_identity names it: the same folder given as "tiles" and then as
        # "/data/tiles" (or from another working folder) redid every item
        h.update(repr(item if item.path is None else dataclasses.replace(item, path=_absolute(item.path)))
                 .encode())  # fmt: skip
        if item.kind == "file":
            h.update(identities[item.key].encode())
            frame = options.frame_of(item.key)
            if frame is not None:  # placed by the other files too: redone when their mosaic's frame moves it
                h.update(repr(frame).encode())
        elif source is not None:
            ring = int(options.solid)  # a solid tile's τ reads the ring of nodes around it (_tile_off_thresholds)
            (r0, r1), (c0, c1) = (item.rows, item.cols) if item.kind == "tile" else ((0, 0), (0, 0))
            block = source.heights[item.index] if item.kind == "frame" else source.heights[
                max(r0 - ring, 0):r1 + ring, max(c0 - ring, 0):c1 + ring]  # fmt: skip
            h.update(np.ascontiguousarray(block).tobytes())
        if _seams_moved(item, source, options):
            # its last node column or row moved onto its neighbour's first: an item written before that was done has
            # seams the new neighbours' do not meet, so it is redone; the other items keep their fingerprints
            h.update(b"|seams on the lattice")
        out[item.key] = h.hexdigest()
    return out


def _absolute(path: str) -> str:
    """A file item's path made absolute for its fingerprint; a GDAL virtual path or URL by :func:`_virtual_from`
    (os.path.abspath turned ``/vsizip//data/a.zip/t.tif`` into another path and a URL into one under the working
    folder), a relative archive's path made absolute as a plain file's is."""
    virtual = _virtual_from(path, os.getcwd())
    return virtual if virtual is not None else os.path.abspath(path)


#: Files beside a GeoTIFF (or another raster of :data:`~stepterrain.io.GDAL_FORMATS`) that GDAL reads with it when
#: load_dem opens it (``{name}``: the file's name, ``{stem}``:
#: without its extension), matched in any case: the PAM .aux.xml (georeferencing, CRS, nodata, scale and offset,
#: over the file's own), a .msk mask, a MapInfo .tab or a world file (the georeferencing of a TIFF without its
#: own), RPCs (which make load_dem refuse it) and the .prj load_dem reads itself (the CRS of a world file's grid)
_GEOTIFF_SIDECARS: tuple[str, ...] = (
    "{name}.aux.xml", "{stem}.aux", "{name}.msk", "{stem}.tab", "{stem}.tfw", "{stem}.tifw", "{stem}.tiffw",
    "{stem}.wld", "{stem}.rpb", "{stem}_rpc.txt", "{stem}.imd", "{stem}.prj", "{name}.prj",
    "{stem}.hdr", "{stem}.stx", "{stem}.blw", "{stem}.rrd",  # a .bil/.flt's header and statistics, an .img's overviews
)
#: Files beside a PNG that load_dem reads with it: the world file and .prj that place a terrain tile
#: (``height_encoding``), and the .aux.xml whose nodata it reads and scale it refuses for a greyscale heightmap
_PNG_SIDECARS: tuple[str, ...] = (
    "{stem}.pgw", "{stem}.pngw", "{stem}.wld", "{stem}.prj", "{name}.prj", "{name}.aux.xml",
)


def _file_identities(items: Sequence[BatchItem]) -> dict[str, str]:
    """:func:`_file_identity` of each file item, by its key: once per run, for its fingerprint and its key in the
    manifest's height ranges alike."""
    listings: dict[str, dict[str, list[str]] | None] = {}  # folder -> lower-case name -> names: one listing per folder
    return {item.key: _file_identity(item.path, listings) for item in items  # type: ignore[arg-type]
            if item.kind == "file"}


def _file_identity(path: str, listings: dict[str, dict[str, list[str]] | None],
                   seen: frozenset[str] = frozenset()) -> str:
    """A file item's input as the fingerprint sees it: path, size, mtime, ctime and inode of the file, of the
    sidecar files GDAL reads with a GeoTIFF or another GDAL raster (:data:`_GEOTIFF_SIDECARS`) or load_dem with a PNG
    (:data:`_PNG_SIDECARS`: a terrain tile's world file and .prj), and of the files
    a .vrt reads its heights from (:func:`_vrt_sources`, with their sidecars: a source tile rewritten under an
    unchanged .vrt redoes its item).

    ctime and inode catch a file rewritten with its size and mtime kept (``cp -p``, ``os.utime``, ``touch -r``):
    every write or metadata change sets ctime on Linux and macOS (on Windows ``st_ctime`` is the creation time,
    which a rewrite in place keeps). Renaming, moving or restoring a file from a backup changes them too, so its
    item is redone once: stat calls, no read of the data. ``listings`` caches each folder's names."""
    def identity(file: str) -> str:
        try:
            st = os.stat(file)
        except OSError:
            return f"{file}|unreadable"
        return f"{file}|{st.st_size}|{st.st_mtime_ns}|{st.st_ctime_ns}|{st.st_ino}"

    virtual = gdal_path(path)
    if virtual is not None:  # the local archive it lies in (a zip's, a gzip's), else its path alone (a URL)
        archive = local_archive(virtual)
        return f"{path}|" + (identity(os.path.abspath(archive)) if archive else "remote")
    file = os.path.abspath(path)
    parts = [identity(file)]
    folder, name = os.path.split(file)
    if _gzip_raster(name):  # N46E007.hgt.gz: the sidecars of the file inside, beside it (dem.prj of dem.asc.gz)
        name = name[:-3]
    stem, ext = os.path.splitext(name)
    sidecars = _GEOTIFF_SIDECARS if ext.lower() in GDAL_FORMATS else _PNG_SIDECARS if ext.lower() == ".png" else ()
    if sidecars:
        if folder not in listings:
            names: dict[str, list[str]] | None = {}
            try:
                for entry in os.listdir(folder):
                    names.setdefault(entry.lower(), []).append(entry)  # type: ignore[union-attr]
            except OSError:
                names = None
            listings[folder] = names
        found = listings[folder]
        if found is None:
            parts.append("unlistable")
        for pattern in sidecars if found is not None else ():
            for side in sorted(found.get(pattern.format(name=name, stem=stem).lower(), ())):
                parts.append(identity(os.path.join(folder, side)))
    if ext.lower() == ".vrt" and file not in seen:  # GDAL refuses a .vrt that names itself; not followed round
        sources = _vrt_sources(file)
        if sources is None:
            parts.append("sources unlisted")
        for source in sources or ():
            parts.append(f"<{_file_identity(source, listings, seen | {file})}>")
    return "|".join(parts)


def _vrt_sources(file: str) -> list[str] | None:
    """The files GDAL reads for the .vrt ``file`` but itself (rasterio's ``dataset.files``: its sources' rasters,
    made absolute as GDAL finds them), sorted; None when GDAL cannot open it (its item fails with the reason)."""
    try:
        from .io import open_raster

        with open_raster(file) as dataset:
            files = dataset.files
    except Exception:  # noqa: BLE001 - no rasterio, or a .vrt GDAL refuses: the item's read says why
        return None
    here = os.path.abspath(file)
    return sorted({os.path.abspath(f) if gdal_path(f) is None else f for f in files} - {here})


def _source_identity(source: _Source | None) -> Any:
    if source is None:
        return None
    # the tiles' shared bounds decide how a glTF or PLY stores the coordinates: a tile written without them (or
    # with others) does not weld exactly with one written with them
    return [list(source.heights.shape), list(source.spacing), list(source.origin), source.crs, source.bounds]


def _read_manifest(output_dir: Path) -> tuple[dict[str, Any], dict[str, Any], str | None]:
    """The manifest's entries by output file name, the height ranges of a folder's files it records
    (:func:`_read_ranges`), and why it could not be used (None when it could, or when there is none): a manifest
    that is cut short, edited into something else or of an unknown version is replaced. Read once per run, with the
    folder locked."""
    path = output_dir / MANIFEST_NAME
    replaced = "; it is written afresh, recording this run's outputs only"
    if path.is_dir():  # it could not be written at the end either: refused before any item runs
        raise DataFileError(f"the manifest {str(path)!r} is a folder; expected a file (or none): move the folder away")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}, {}, None
    except OSError as exc:
        return {}, {}, f"the manifest {MANIFEST_NAME} could not be read ({exc.strerror or exc}){replaced}"
    except ValueError as exc:  # also UnicodeDecodeError
        return {}, {}, f"the manifest {MANIFEST_NAME} is not valid JSON (cut short or edited: {exc}){replaced}"
    ranges = _read_ranges(data)
    version = data.get("version") if isinstance(data, dict) else None
    items = data.get("items") if isinstance(data, dict) else None
    if version not in (1, _MANIFEST_VERSION) or not isinstance(items, dict):
        got = f"version {version!r}" if isinstance(data, dict) else f"a JSON {type(data).__name__}"
        return {}, ranges, (f"the manifest {MANIFEST_NAME} is not one this stepterrain reads (expected an object with "
                            f"version 1 or {_MANIFEST_VERSION} and its items; got {got}){replaced}")  # fmt: skip
    if version == 1:  # keyed by item: key its entries by the file each names
        items = {e["file"]: e for e in items.values() if isinstance(e, dict) and isinstance(e.get("file"), str)}
    return items, ranges, None


def _write_manifest(output_dir: Path, entries: Mapping[str, Any], ranges: Mapping[str, Any] | None = None) -> None:
    """The manifest: its items, and the height ranges of a folder's files (:func:`_files_range`) when given, with
    the :data:`_RANGES_VERSION` they were found by."""
    data: dict[str, Any] = {"version": _MANIFEST_VERSION, "items": entries}
    if ranges is not None:
        data["ranges_version"] = _RANGES_VERSION
        data["ranges"] = ranges
    with atomic_path(output_dir / MANIFEST_NAME) as tmp:
        tmp.write_text(json.dumps(data, indent=1), encoding="utf-8")


def _read_ranges(data: Any) -> dict[str, Any]:
    """The height ranges of a folder's files a manifest's JSON ``data`` records (:func:`_files_range`), by
    :func:`_range_key`: ``[min, max]`` or None (no surface). Empty when there are none, or when they were recorded
    under another :data:`_RANGES_VERSION` (or none: a manifest written before it existed), found otherwise than
    this stepterrain finds them, so read again rather than trusted; an entry of another form is left out."""
    if not isinstance(data, dict) or data.get("ranges_version") != _RANGES_VERSION:
        return {}
    found = data.get("ranges")
    if not isinstance(found, dict):
        return {}
    out: dict[str, Any] = {}
    for key, value in found.items():
        if value is None:
            out[key] = None
        elif (isinstance(value, list) and len(value) == 2
              and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
              and value[0] <= value[1]):  # fmt: skip
            out[key] = [float(value[0]), float(value[1])]
    return out


def _range_key(identity: str, options: _Options) -> str:
    """A file's key in the manifest's height ranges: its ``identity`` as the fingerprint sees it
    (:func:`_file_identity`: path, size, mtime, ctime and inode, and its GDAL sidecars' and a .vrt's sources') and
    the options its heights are read with."""
    read = [options.height_unit, options.band, options.coarsen,
            None if options.file_spacing is None else list(options.file_spacing)]  # fmt: skip
    if options.height_encoding is not None:  # the keys of runs without it unchanged
        read.append(options.height_encoding)
    if options.nodata:  # the cells read as missing: another height range (the keys of runs without it unchanged)
        read.append(["nodata", list(options.nodata)])
    return hashlib.blake2b(json.dumps([identity, read]).encode(), digest_size=16).hexdigest()


def _is_complete(entry: Any, fingerprint: str, output_dir: Path, name: str) -> bool:
    """Recorded as the file ``name`` with the same fingerprint, and that file is there with the recorded size."""
    if not isinstance(entry, dict) or entry.get("fingerprint") != fingerprint or entry.get("file") != name:
        return False
    bytes_ = entry.get("bytes")
    if isinstance(bytes_, bool) or not isinstance(bytes_, int):
        return False
    try:
        return (output_dir / name).stat().st_size == bytes_
    except OSError:
        return False


def _check_output_dir(output_dir: str | os.PathLike[str]) -> tuple[Path, list[Path]]:
    """The output folder, made if missing, and the folders this made (deepest first) so that a run that fails
    before writing anything can take them away again."""
    folder = as_path(output_dir, "output_dir")
    made = []
    try:  # a name too long for the file system (ENAMETOOLONG) raised os.stat's bare OSError from exists()
        if folder.exists() and not folder.is_dir():
            raise DataFileError(f"output_dir {str(folder)!r} exists and is not a folder")
        # made where symbolic links lead, as export.atomic_path makes a file's: a dangling link to a folder
        # (out -> /data/new, or one on the way) was refused "cannot create the output folder 'out': File exists"
        # (mkdir of the link's own name)
        resolved = Path(os.path.realpath(folder))
        for path in (resolved, *resolved.parents):
            if path.exists():
                break
            made.append(path)
    except OSError as exc:
        if isinstance(exc, DataFileError):
            raise
        raise DataFileError(f"cannot create the output folder {str(folder)!r}: {exc.strerror or exc}") from exc
    try:
        resolved.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # unwritable_reason: /proc said "No such file or directory" of itself
        raise DataFileError(f"cannot create the output folder {str(folder)!r}: "
                            f"{unwritable_reason(exc, folder)}") from exc
    error = probe_writable(folder)
    if error is not None:
        raise DataFileError(f"output folder {str(folder)!r} is not writable: {error.strerror or error}") from error
    return folder, made


#: export.atomic_path's temporary files: ``.<name>.<tempfile's 8 random characters>.tmp`` beside ``<name>``
_PARTIAL_RE = re.compile(r"^\.(.+)\.[a-z0-9_]{8}\.tmp$")


def _remove_partial(folder: Path, names: Sequence[str]) -> None:
    """Remove what a killed run left half-written: the temporary files of ``names`` (this run's outputs and the
    manifest) in ``folder``. A rerun writes every one of them afresh, so none of those is in use. A name too long for
    its temporary file's is cut there as atomic_path cuts it (a 250-byte file name's partial file stayed)."""
    wanted = {_temporary_stem(name) for name in names}
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        found = _PARTIAL_RE.match(entry.name)
        if found and found[1] in wanted and entry.is_file(follow_symlinks=False):
            try:
                os.unlink(entry.path)
            except OSError:
                pass


class _FolderLock:
    """An exclusive lock on an output folder: :data:`LOCK_NAME` locked with ``flock`` (``msvcrt.locking`` on
    Windows), so the operating system lets it go when the process dies: a lock file a killed run left is taken over,
    never mistaken for a run in progress. The file names its holder; :meth:`release` removes it."""

    #: the byte Windows locks: beyond the holder's text, which the refused run reads
    _WINDOWS_BYTE = 4096

    def __init__(self, folder: Path) -> None:
        self.path = folder / LOCK_NAME
        self.fd: int | None = None
        #: set when the folder's file system has no locks (some network and FUSE mounts): the run goes on unlocked
        self.note: str | None = None
        for _ in range(8):  # another run may remove the file between our open and our lock: then once more
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise DataFileError(
                    f"cannot create the lock file {str(self.path)!r} in the output folder "
                    f"{str(folder)!r}: {exc.strerror or exc}"
                ) from exc
            locked = self._lock(fd)
            if locked is None:
                self.note = (f"the file system of the output folder {str(folder)!r} does not support file locks: "
                             "another batch run into it at the same time would not be refused")  # fmt: skip
            elif not locked:
                holder = self._holder(fd)
                os.close(fd)
                raise DataFileError(
                    f"output folder {str(folder)!r} is in use by another stepterrain batch run ({holder}); wait for "
                    f"it to finish or write to another folder (its lock file: {LOCK_NAME})"
                )
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except OSError:
                same = False
            if same:
                self.fd = fd
                started = time.strftime("%Y-%m-%d %H:%M:%S %z")
                holder = f"pid {os.getpid()} on {platform.node() or 'this host'}, started {started}".encode()
                os.ftruncate(fd, 0)
                os.lseek(fd, 0, os.SEEK_SET)
                os.write(fd, holder)
                return
            os.close(fd)  # the file we locked was removed by the run that held it: lock the new one
        raise DataFileError(
            f"cannot lock the output folder {str(folder)!r}: its lock file {LOCK_NAME} keeps being "
            "replaced by other runs"
        )

    @classmethod
    def _lock(cls, fd: int) -> bool | None:
        """Lock ``fd`` without waiting: False when another open file holds the lock, None when the file system has
        no locks."""
        try:
            import fcntl
        except ImportError:  # Windows
            import msvcrt

            os.lseek(fd, cls._WINDOWS_BYTE, os.SEEK_SET)
            try:
                msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)  # type: ignore[attr-defined]
            except OSError:
                return False
            return True
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return False
            if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                return None
            raise DataFileError(f"cannot lock {LOCK_NAME} in the output folder: {exc.strerror or exc}") from exc
        return True

    @staticmethod
    def _holder(fd: int) -> str:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            text = os.read(fd, 512)
        except OSError:
            text = b""
        return text.decode("utf-8", "replace").strip() or "its pid unknown"

    def release(self) -> None:
        """Remove the lock file and let the lock go; a second call does nothing."""
        if self.fd is None:
            return
        fd, self.fd = self.fd, None
        try:
            os.unlink(self.path)  # while locked: a run that opened this file finds it gone and makes a new one
        except OSError:
            pass  # Windows removes no open file; the next run locks it anew
        os.close(fd)  # lets the lock go


def _remove_empty(folders: Sequence[Path]) -> None:
    """Remove the folders (deepest first) that are still empty."""
    for path in folders:
        try:
            path.rmdir()
        except OSError:
            return


def _check_ext(ext: str) -> str:
    if not isinstance(ext, str):
        raise InvalidInputError(f"format must be a mesh extension such as '.glb'; got {type(ext).__name__}")
    norm = ext.lower() if ext.startswith(".") else f".{ext.lower()}"
    if norm not in MESH_EXTENSIONS:
        raise InvalidInputError(f"format must be one of {', '.join(MESH_EXTENSIONS)}; got {ext!r}")
    return norm


# ---------------------------------------------------------------------------------------------- schedulers
#: dask settings of the default LocalCluster. The workers' statistical profiler samples every thread's stack
#: every 10 ms (about 15 % of the CPU time of a 1024² tile) and the event-loop tick, memory and system monitors
#: wake up 50, 10 and 2 times a second; meshing tasks of a second or more need none of that.
LOCAL_CLUSTER_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "200ms",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    # no pause at 80 % of the memory limit: with LOCAL_CLUSTER_MALLOC a worker keeps the memory of its last tile
    # for the next, so its resident size need not fall after a tile, and a paused worker would never resume (the
    # nanny still restarts a worker beyond 95 %, as a tile that large would reach anyway)
    "distributed.worker.memory.pause": False,
}


#: glibc malloc settings of the default LocalCluster's workers (environment variables read when a process
#: starts; dask sets them through ``distributed.nanny.pre-spawn-environ``). dask's own default,
#: ``MALLOC_TRIM_THRESHOLD_=65536``, hands freed memory back to the system at once, and arrays above glibc's
#: 32 MB ceiling for heap blocks are mapped afresh anyway: each tile then pays a page fault for every page of
#: its output arrays (a 1024² tile's faces alone are 78 MB). Blocks up to 1 GB from the heap, and up to 1 GB of
#: freed memory kept for the next tile: 1024² tiles took 12 % less CPU time than with glibc's defaults, 19 % less
#: than with dask's (one core, medians of 14 tiles each). The memory a worker keeps is what its largest tile used,
#: so the cluster does not pause workers at 80 % of their memory limit (:data:`LOCAL_CLUSTER_CONFIG`).
LOCAL_CLUSTER_MALLOC: dict[str, int] = {"MALLOC_MMAP_THRESHOLD_": 1 << 30, "MALLOC_TRIM_THRESHOLD_": 1 << 30}


def _silence_dask_logs() -> list[tuple[logging.Logger, int]]:
    """Turn dask.distributed's loggers in this process off; return their levels before."""
    loggers = [logging.getLogger("distributed")] + [
        logger for name, logger in list(logging.root.manager.loggerDict.items())
        if name.startswith("distributed.") and isinstance(logger, logging.Logger) and logger.level != logging.NOTSET
    ]  # fmt: skip
    levels = [(logger, logger.level) for logger in loggers]
    for logger, _level in levels:
        logger.setLevel(logging.CRITICAL + 1)
    return levels


#: The blocks of :func:`_dask_logs_silenced` running in this process (every thread), and the levels the loggers had
#: before the first: the last block out puts them back.
_LOGS_SILENCED = threading.Lock()
_logs_silenced_blocks = 0
_logs_levels: dict[logging.Logger, int] = {}


@contextmanager
def _dask_logs_silenced(client: Any = None) -> Iterator[None]:
    """Nothing logged by dask.distributed's loggers in this process while the block runs (their levels put back
    after it), nor, given the default LocalCluster's client, by its worker processes, which are closed in the block
    (a worker whose scheduler went down before it logged "Failed to communicate with scheduler during heartbeat").

    The loggers are the process's: blocks in several threads at once (runs in two threads closing their clusters)
    keep them off until the last one ends, which puts back the levels they had before the first (each putting back
    the levels it found left them off for good when two overlapped)."""
    global _logs_silenced_blocks
    with _LOGS_SILENCED:
        for logger, level in _silence_dask_logs():  # a logger already off keeps the level saved by the first block
            _logs_levels.setdefault(logger, level)
        _logs_silenced_blocks += 1
    try:
        if client is not None:
            try:
                client.run(_silence_dask_logs, on_error="ignore", callback_timeout=5)
            except Exception:  # noqa: BLE001 - its workers' last words are all it costs
                pass
        yield
    finally:
        with _LOGS_SILENCED:
            _logs_silenced_blocks -= 1
            if _logs_silenced_blocks == 0:
                for logger, level in _logs_levels.items():
                    logger.setLevel(level)
                _logs_levels.clear()


def start_local_cluster(workers: int) -> Any:
    """The default cluster of :func:`batch`: ``workers`` processes of one thread each, profiler off, quiet logs,
    malloc tuned for tile-sized arrays (:data:`LOCAL_CLUSTER_MALLOC`).

    Raises
    ------
    SchedulerError
        The worker processes cannot be started.
    """
    import dask
    from distributed.utils import LoopRunner

    # the cluster's event loop thread, made with SIGINT and SIGHUP blocked: the workers, which it (and the threads it
    # makes) spawns, inherit the mask and never see the terminal's Ctrl-C or hang-up (this process closes them); this
    # thread's own mask is back before the workers start, so a second Ctrl-C still ends a start that hangs
    with terminal_signals_blocked_for_children():
        runner = LoopRunner(asynchronous=False)
        runner.start()
    environ = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **LOCAL_CLUSTER_MALLOC}
    # a nanny takes a pre-spawn variable from this process's os.environ before the configuration, and writes its
    # own into os.environ when it spawns its worker: after any earlier LocalCluster of the session (dask's
    # MALLOC_TRIM_THRESHOLD_=65536 left in os.environ) the configuration below was ignored, and this cluster's
    # values stayed in the caller's environment (its later subprocesses started with them). Set for the start
    # only, then put back as they were; one start at a time in the process: two threads starting clusters at once
    # each put back what they had found, so the second put back the first's variables (and dask configuration) after
    # the first had put back the caller's, and they stayed for good
    with _CLUSTER_START:
        return _started_local_cluster(workers, environ, runner)


#: Held while :func:`start_local_cluster` has :data:`LOCAL_CLUSTER_MALLOC` in os.environ (and dask's configuration set).
_CLUSTER_START = threading.Lock()


def _started_local_cluster(workers: int, environ: dict[str, Any], runner: Any) -> Any:
    """:func:`start_local_cluster`'s LocalCluster, started with :data:`LOCAL_CLUSTER_MALLOC` set in os.environ and the
    nannies' configuration set, both put back as they were after (``runner``: its event loop, stopped after)."""
    import dask
    from distributed import LocalCluster

    before = {key: os.environ.get(key) for key in LOCAL_CLUSTER_MALLOC}
    try:
        os.environ.update({key: str(value) for key, value in LOCAL_CLUSTER_MALLOC.items()})
        # the nannies hand this configuration to their workers, and set the environment before they start them
        with dask.config.set({**LOCAL_CLUSTER_CONFIG, "distributed.nanny.pre-spawn-environ": environ}):
            return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                                silence_logs=logging.ERROR, loop=runner.loop)  # fmt: skip
    except (OSError, RuntimeError, TimeoutError) as exc:
        raise SchedulerError(
            f"cannot start a LocalCluster of {workers} worker processes: {exc} (from a script, call batch() under "
            "`if __name__ == '__main__':`: the workers start by importing the script)"
        ) from exc
    finally:
        _restore_environ(before)
        runner.stop()  # this one's share of the loop: it runs on until the cluster (and its clients) let it go


def _restore_environ(before: Mapping[str, str | None]) -> None:
    """Put the variables of ``before`` back in os.environ as they were (None: not set)."""
    for key, value in before.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


def _scheduler_error(scheduler: Any) -> InvalidInputError:
    return InvalidInputError(
        "scheduler must be None (a LocalCluster), 'serial', a dask Client or an address such as "
        f"'tcp://host:8786'; got {scheduler!r}"
    )


def _check_scheduler(scheduler: Any) -> None:
    """Refuse a scheduler that cannot be one (a malformed address, a number) without importing dask: a typo is
    the first thing to hear about, before any output folder is made."""
    if isinstance(scheduler, str):
        if scheduler != "serial" and not _SCHEDULER_RE.match(scheduler):
            raise _scheduler_error(scheduler)
    elif scheduler is not None and not callable(getattr(scheduler, "submit", None)):
        raise _scheduler_error(scheduler)  # not a Client


#: The longest wait for a scheduler: far longer ones (1e300 s) overflowed into a wait without end in dask.
MAX_CONNECT_TIMEOUT = 86400.0


class _SyncCancelFilter(logging.Filter):
    """Drops the one record of dask's ``distributed.utils.sync`` interrupted before its call started: its ``cancel``
    callback reads its ``future`` before that is set ("NameError: cannot access free variable 'future' where it is not
    associated with a value"), which tornado logs with its traceback (an upstream bug, distributed 2026.8)."""

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        if not isinstance(error, NameError) or error.__traceback__ is None:
            return True
        last = error.__traceback__
        while last.tb_next is not None:
            last = last.tb_next
        code = last.tb_frame.f_code
        return not (code.co_name == "cancel" and Path(code.co_filename).parts[-2:] == ("distributed", "utils.py"))


_SYNC_CANCEL_FILTER = _SyncCancelFilter()


def _quiet_dask_sync_cancel() -> None:
    """Keep tornado's log of this process from printing dask's `sync` cancel NameError (:class:`_SyncCancelFilter`).
    SIGTERM or Ctrl-C while `stepterrain batch` waited on a dask call that the client's busy event loop had not
    started yet printed that traceback after "stepterrain: terminated". Once a process: adding the filter again
    keeps one."""
    logging.getLogger("tornado.application").addFilter(_SYNC_CANCEL_FILTER)


def _connect(
    scheduler: Any, workers: int, connect_timeout: float
) -> tuple[Any, Any, str, bool]:
    """(client, cluster to close or None, description, whether the workers are this machine's processes)."""
    _check_scheduler(scheduler)
    try:
        from distributed import Client
    except ImportError as exc:
        raise MissingDependencyError(
            "batch on dask needs dask and distributed: pip install 'stepterrain[batch]' "
            "(or pass scheduler='serial')"
        ) from exc
    _quiet_dask_sync_cancel()
    if isinstance(scheduler, Client):
        address = scheduler.scheduler.address if scheduler.scheduler else "?"
        _require_workers(scheduler, f"the dask client's scheduler {address}", connect_timeout)
        return scheduler, None, f"dask client {address}", False
    if scheduler is None:
        client = cluster = None
        try:
            with signals_held():  # Ctrl-C as the workers start: the cluster is closed below, not left half made
                cluster = start_local_cluster(workers)
                client = Client(cluster, timeout=connect_timeout)
        except BaseException:
            with _dask_logs_silenced():
                if client is not None:
                    client.close()
                if cluster is not None:
                    cluster.close()
            raise
        return client, cluster, f"LocalCluster ({counted(workers, 'worker process', 'worker processes')})", True
    if not isinstance(scheduler, str):
        raise _scheduler_error(scheduler)  # has .submit but is no dask Client
    try:
        client = Client(scheduler, timeout=connect_timeout)
    except (OSError, TimeoutError) as exc:
        raise SchedulerError(
            f"cannot reach the dask scheduler {scheduler!r} within connect_timeout={connect_timeout:g} s: "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    except Exception as exc:  # something else answers there: an HTTP reply read as a frame length of 3 EiB
        raise SchedulerError(
            f"{scheduler!r} answered, but not as a dask scheduler ({type(exc).__name__}: {exc}); check the port: "
            "a scheduler listens on 8786 by default, its HTTP dashboard on 8787"
        ) from exc
    try:
        _require_workers(client, f"the dask scheduler {scheduler!r}", connect_timeout)
    except BaseException:
        client.close()
        raise
    return client, None, f"dask scheduler {scheduler}", False


def _require_workers(client: Any, what: str, connect_timeout: float) -> None:
    """Wait up to ``connect_timeout`` for the cluster's first worker. A scheduler without workers left a folder's
    items waiting for ever, and tiles or frames failed after the timeout with dask's bare "TimeoutError: No valid
    workers found" (from scattering their heights)."""
    try:
        client.wait_for_workers(1, timeout=connect_timeout)
    except TimeoutError as exc:
        raise SchedulerError(
            f"{what} has no worker: none joined within connect_timeout={connect_timeout:g} s; start workers "
            "(`dask worker <address>`) or give them longer to join (a larger connect_timeout)"
        ) from exc


# ---------------------------------------------------------------------------------------------- public API
def batch(
    source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]] | Terrain | ArrayLike,
    output_dir: str | os.PathLike[str],
    *,
    format: str = ".glb",
    tile_size: int | tuple[int, int] | None = None,
    interval: float | None = None,
    levels: ArrayLike | None = None,
    base: float = 0.0,
    gamma: float = 1.0,
    colors: str | None = None,
    solid: bool = False,
    floor: float | None = None,
    spacing: ArrayLike | None = None,
    origin: ArrayLike | None = None,
    crop: ArrayLike | None = None,
    coarsen: int | None = None,
    scheduler: Any = None,
    workers: int = 2,
    retries: int = 2,
    resume: bool = True,
    connect_timeout: float = 10.0,
    progress: bool | Callable[[str], str] = False,
    metadata: Mapping[str, Any] | None = None,
    height_unit: str | None = None,
    band: int | None = None,
    device: wp.DeviceLike = None,
    overview_size: tuple[int, int] | None = None,
    height_encoding: str | None = None,
    nodata: float | Sequence[float] | None = None,
    overview_z_scale: float | None = None,
) -> BatchReport:
    """Step many terrains, one mesh file each, on dask.distributed (or serially).

    Parameters
    ----------
    source
        A folder of DEM files (those :func:`~stepterrain.io.load_dem` reads, ``SUPPORTED_EXTENSIONS``, but a
        ``.vrt``, which beside tiles is their mosaic: name it to read it; hidden ones left out as a shell glob leaves
        them: macOS's ``._dem.tif`` companions; one output per file, named after it: ``dem.tif`` writes
        ``dem.glb``, files sharing a stem in any case their whole names, ``a.npy`` and ``A.npz`` ``a_npy`` and
        ``A_npz``; two that would still write one file where case is ignored are refused; files in degrees that
        GDAL reads, two or more in one geographic CRS, are placed in the local metres of their mosaic, as tiles of it:
        :func:`_degree_frames`), a list of DEM files,
        a ``.npy``/``.npz`` file holding one (T, H, W) series (read as :func:`load_series` reads it: NaN, inf and
        an ``.npz``'s ``nodata`` value, ``mask`` and ``valid`` mark nodata) or a (T, H, W) array (one output per frame,
        ``frame_0000`` ...), or one raster (a ``.tif``/``.npz``/... file, a grid :class:`Terrain` or an (H, W)
        array) cut into tiles of ``tile_size`` cells (``tile_r0_c0`` ...; neighbours share border nodes).
    output_dir : str or path-like
        Created if missing; must be writable. Also holds the manifest :data:`MANIFEST_NAME`, and while the run
        lasts its lock file :data:`LOCK_NAME`: one run at a time per folder.
    format : str
        Output extension: ``.glb`` ``.gltf`` ``.obj`` ``.ply`` ``.stl`` ``.3mf``.
    tile_size : int or (rows, cols)
        Cells per tile when ``source`` is one raster (no default: needed for one; the CLI's ``batch --tile``
        defaults to 256 for the embedded DEM).
    interval, levels, base, gamma, colors, solid, floor
        As in :func:`~stepterrain.stepped` (``gamma`` a scalar, ``colors`` a colormap name, default None: no
        colours; the CLI's ``batch --colormap`` defaults to 'terrain', none for ``.stl``). For series and
        tiles the isovalues come from the whole source's height range, so every item shares them (tiles
        weld, frames keep their levels). A folder's files (or a list's) share them too: with ``colors``, ``solid``
        or neither ``interval`` nor ``levels``, every file is read once before the items run (one at a time, as its
        item reads it: ``height_unit``, ``band``, ``spacing``, ``coarsen``; a file of nodata only, or one that
        cannot be read, left out; a file whose range the folder's manifest records, unchanged since, not read
        again; one file run serially stepped from that read, not read twice) for the height range of all of them,
        the isovalues of ``interval`` (without ``interval`` and ``levels``: :func:`~stepterrain.stepped.nice_interval`
        of that range, as :func:`~stepterrain.stepped` picks it for one raster, recorded as ``interval`` and ``base``
        in every output's metadata) over it given to every file, so that a height has one colour in every file (a
        file stepped alone spread the colormap over its own levels: colour seams between neighbouring tiles), the
        geometry unchanged. A solid tile, frame or
        file is closed on its own (skirts along its edges and a flat base), without ``floor`` at the one the whole
        source's solid has in :func:`~stepterrain.stepped` (the whole raster, the series as one raster, or all the
        files: one interval under the lowest isovalue of all), so every item stands on the same base. For each
        file's own levels and floor, step the files one by one (:func:`~stepterrain.stepped`, ``stepterrain
        steps``); ``levels`` and ``floor`` given are every file's as they are.
    spacing, origin : (dx, dy), (x0, y0)
        Grid geometry of an array source (default (1, 1) and (0, 0)). ``spacing`` also applies to DEM files with no
        georeferencing (.npy, a PNG heightmap, a GeoTIFF without a geotransform; a folder's, a list's, one raster's
        to tile or a series file's), which load_dem reads as 1 m cells: one cell size D or (dx, dy), positive
        metres, rows running north to south as load_dem reads them (the Terrain's spacing ``(dx, -dy)``, recorded as
        ``spacing`` in every output's metadata); a file that places its nodes itself is refused (in a folder or
        list: its item fails, naming it). ``origin`` applies to arrays only.
    crop : (xmin, xmax, ymin, ymax), optional
        Keep the source's nodes inside this extent (:meth:`~stepterrain.terrain.Terrain.crop`, in the source's
        coordinates) before it is cut into tiles (``tile_size`` counts the cropped raster's cells), or in every frame
        of a series. A GeoTIFF (or another GDAL raster) to tile (without ``spacing``) is read only in the crop's window
        (:func:`~stepterrain.io.load_dem`'s ``crop``): a part of a raster too big for the memory budget. Not for a
        folder or list of DEM files, which each cover their own extent. Recorded as ``crop`` in every output's
        metadata.
    coarsen : int, optional
        Average N x N blocks of nodes into one (:meth:`~stepterrain.terrain.Terrain.coarsen`, nodata ignored),
        after ``crop``: one raster before it is cut into tiles (``tile_size`` counts coarse cells), so that the
        tiles still share their border nodes and weld (tiles coarsened one by one would not), every frame of a
        series, each file of a folder or list as it is read (after ``spacing``). Recorded as ``coarsen`` in every
        output's metadata.
    scheduler
        ``None``: a LocalCluster of ``workers`` processes (one thread each). ``"serial"``: this process, no dask. An
        address ``"tcp://host:port"``: an existing cluster, reached (and its first worker found: a Client's too) within
        ``connect_timeout`` seconds. A ``distributed.Client``: used as is, not closed. Every worker steps under this
        process's memory budget (:func:`stepterrain.set_memory_budget`), set in the worker before each item. The
        LocalCluster's workers record each item's warnings, which are warned again in this process (other clusters'
        workers print theirs); STL's float32 rounding (UTM coordinates), which every tile of a raster meets alike, is
        warned once for the run, with the number of outputs it moved, as are ``.stl`` outputs that read back open
        (a solid's pinch copies at UTM coordinates; each item's own message stays in its :class:`ItemResult`'s
        ``warnings``).
    workers : int
        Worker processes of the LocalCluster, at most one per item to run (a LocalCluster gives each worker
        1/n_workers of the machine's memory as its limit: idle workers took the busy ones' share).
    retries : int
        Extra attempts for an item whose task raised (worker lost, disk error). Bad input data (an
        unreadable tile) fails at once.
    connect_timeout : float
        Seconds to connect to the scheduler (a ``"tcp://host:port"`` one and its first worker, a Client's first
        worker, or the LocalCluster started) before giving up (see ``scheduler``; default 10); also the longest wait
        for a worker to take again the heights of an item whose worker was lost (the item fails then).
    resume : bool
        Skip items already complete in ``output_dir`` (see Notes); ``False`` redoes everything.
    progress : bool or callable
        A tqdm progress bar on stderr, which writes each failed item's line (the one of
        :meth:`BatchReport.summary`) as the item fails; a callable ``line -> str`` draws the bar and rewords those
        lines (the command line prefixes them and spells library arguments as its options). A folder's files read
        for their shared height range (more than one) get a bar of their own first. Without ``interval`` and
        ``levels``, the interval chosen is said once on stderr (a line of its own, reworded alike) before the items
        run. Default False: no bar (the CLI's ``batch`` shows one unless ``-q``).
    metadata : mapping, optional
        Added to every output's glTF ``extras``: JSON values (str, number, bool, None, lists and dicts of those
        with string keys), numpy scalars and arrays included, as in :func:`~stepterrain.export.save_mesh`;
        anything else is refused before any work, naming its key. Keys stepterrain writes itself are refused too:
        ``isovalues``, ``gamma``, ``source``, ``crs``, ``floor``, ``interval`` and ``base`` (recorded when the
        isovalues are ``base + k * interval``), ``empty``, ``batch_item`` and each item's own (``input`` for a
        file, ``frame``, or ``tile_row``, ``tile_col``, ``node_rows``, ``node_cols``); a ``generator`` given
        replaces ``"stepterrain.batch"``.
    height_unit : str, optional
        The unit of the heights in DEM files (a folder, a list, or one raster file cut into tiles), as
        :func:`~stepterrain.io.load_dem` takes it: for files that name none or name one it does not know.
        Not for arrays, Terrains or (T, H, W) series, whose heights are used as they are.
    band : int, optional
        The 1-based band of the DEM files (a folder, a list, or one raster file cut into tiles) to read the heights
        from, as :func:`~stepterrain.io.load_dem` takes it (default: the first): a GeoTIFF's (or another GDAL
        raster's: ``.img``, ``.vrt``, ...); a ``.npy``, ``.npz`` or PNG holds one band and refuses another (in a folder
        or list: its item fails, naming it). Recorded as
        ``band`` in every output's metadata. Not for arrays, Terrains or (T, H, W) series.
    height_encoding : str, optional
        The RGB encoding of PNG terrain tiles among the DEM files, as :func:`~stepterrain.io.load_dem` takes it:
        ``"terrain-rgb"`` or ``"terrarium"`` (a file that is no PNG refuses it: its item fails, naming it). Recorded
        as ``height_encoding`` in every output's metadata. Not for arrays, Terrains or (T, H, W) series.
    nodata : float or sequence of floats, optional
        Value(s) marking missing cells of every DEM file (a folder, a list, one raster file cut into tiles, or a
        (T, H, W) series file) besides each file's own nodata and mask, as :func:`~stepterrain.io.load_dem` takes
        it (compared with the values as stored); the shared levels' height range is read with it too. Recorded as
        ``nodata`` (a list of its finite values: NaN and inf mark no cell) in every output's metadata. Not for
        arrays or Terrains (their NaN are missing).
    device : warp device, optional
        Where each worker runs the kernels (default: Warp's default device on that worker): a name ("cpu",
        "cuda:0") or a ``warp.Device``. With ``scheduler="serial"`` the items run in this process, so an unknown or
        absent device is refused (a :class:`~stepterrain.errors.DeviceError`) before any work.
    overview_size : (width, height), optional
        The ``window_size`` of an :func:`overview_image` (its defaults otherwise) to be rendered from the report:
        its render is checked against the memory budget before any item runs, counting at least the surface of
        every tile it shows (the mosaic of up to 64) or of the largest frame of its contact sheet, so that a render
        over the budget is refused (an :class:`~stepterrain.errors.OutputTooLargeError`) before the items are
        stepped and written, not after. A folder's or list's files are read only by the items: their overview is
        checked when it is rendered.
    overview_z_scale : float, optional
        With ``overview_size`` only: the ``z_scale`` of that :func:`overview_image` (default 2), checked before any item
        runs as well: a positive finite number, and for a raster or series one that keeps the z-scaled height of
        the meshes it shows (at least that of their nodes, and a solid's floor) within what the render can frame
        (``--z-scale 1e308`` wrote every mesh, then the render refused it).

    Returns
    -------
    BatchReport
        One :class:`ItemResult` per item; ``report.ok`` is False when any item failed.

    Warns
    -----
    UserWarning
        The items' own warnings (load_dem's, stepped's), each message once; those of the mosaic of DEM files in
        degrees (their local metres' error, as load_dem warns of the mosaic's ``.vrt``); and, once, that DEM files in
        degrees are left in local metres of their own (an .npz, a file alone in its geographic CRS: node (0, 0) at
        its first node), so their meshes neither line up nor weld (mosaic them with ``gdalbuildvrt`` and cut the
        ``.vrt`` into tiles instead); once, that DEM files in degrees are in two or more geographic CRSs, placed in
        a frame each, whose meshes overlap (warp them to one CRS first); once, that DEM files are in two or more
        CRSs of which one is projected (UTM zones 10 and 11, or a UTM zone and degrees; one CRS named two ways, by
        its EPSG code and its WKT, is one), each mesh in its own CRS's coordinates, so they do not line up (warp
        them to one CRS first).

    Raises
    ------
    InvalidInputError
        Unknown format, bad source (an array with an infinite height, or a finite one beyond float32, included;
        NaN is nodata; a list of files holding a folder or one file twice), tile size, isovalues, scheduler address
        or ``metadata`` (not a mapping of JSON values); a ``floor`` not below the lowest point of the stepped
        surface of every tile, frame or file (a folder's: naming the file with the lowest surface); a Terrain with
        a visual (vertex colours or UVs, which its tiles would lose) unless ``colors`` or ``solid`` is given.
    DataFileError
        The source (or a file of a list of them) does not exist, or ``output_dir`` cannot be created or written,
        or another batch run is using it (before any work; the message names that run's pid, host and start
        time).
    SchedulerError
        The scheduler at ``scheduler`` cannot be reached within ``connect_timeout``, or it (or a Client's) has no
        worker within that time.
    MissingDependencyError
        dask/distributed are not installed (``scheduler="serial"`` needs neither).
    OutputTooLargeError
        With ``overview_size``: the overview's render would exceed the memory budget (before any item runs).

    Notes
    -----
    An item is complete when the manifest records its output file with the same fingerprint (its input: the file's
    absolute path, size, mtime, ctime and inode, and those of the sidecar files GDAL reads with a GeoTIFF or another
    GDAL raster: world file, ``.aux.xml``, ``.msk``, ``.tab``, RPCs, ``.prj``, a ``.bil``'s ``.hdr``, and a ``.vrt``'s
    source rasters (GDAL's file list of it); or a hash of its
    heights; and the options but the device, which does not change a bit of the output; the isovalues and floor a
    folder's files share among them, so that a file whose heights reach a new level redoes every file, and a file
    rewritten within the levels only its own item) and that file exists with the recorded size. The manifest also
    records the height range of each file of a folder, by the file's identity as the fingerprint sees it and the
    options it is read with, so that a rerun reads only the files changed since for the shared range (ranges
    recorded under another ``ranges_version``, found otherwise, are read again). The ctime
    catches a file rewritten with its size and mtime kept (``cp -p``) on Linux and macOS, not on Windows, where it is
    the creation time; a file renamed, moved or restored from a backup (and every file item of a run made before
    stepterrain recorded ctime and inode) is redone once. The manifest records each file, so an item's outputs in two
    formats (a ``.glb`` run, then a ``.ply`` one into the same folder) are both kept and complete; ``report.notes`` says
    when the folder holds these items in another format too, when it holds outputs of items this run does not have (an
    earlier run's other tile size or source: left as they were), when a failed item keeps an earlier run's output, and
    when the manifest could not be read (cut short or edited by hand: every item is redone and the manifest written
    afresh). Every file is written to a temporary file and renamed, and the manifest is updated only after the rename,
    so a killed run leaves complete outputs or none and a rerun redoes only what is missing (removing the temporary
    files the killed run left half-written). Tiles are written with the whole raster's bounds as
    :func:`~stepterrain.export.save_mesh`'s ``shared_bounds`` (one glTF node translation, one PLY coordinate type for
    all), and a tile's vertices on its last node column and row lie at the whole raster's x0 + c dx and y0 + r dy, as
    its neighbour's first (not at the tile's origin plus a float32 offset: a spacing such as 70.827 m left the seams
    a fraction of a millimetre apart; files in degrees placed in their mosaic alike), so a vertex two tiles share is
    stored as the same bits in both and the tiles weld exactly (such a tile, or file, whose seam this moves has a
    fingerprint of its own, :func:`_seams_moved`: resuming a run made before the seams were moved redoes those items,
    not a mix of old and new seams, and skips the rest, tiles at 30 m say; one whose last column is nodata, or an
    empty one, is redone too, unchanged); glTF's float32
    positions are then relative to the centre of the raster's bounds (about 8 mm resolution 100 km from it). A tile,
    frame or file of a folder with no triangle of three finite heights (sea off a coast, a tile file of sea cut from a
    coastal raster, all nodata, which :func:`~stepterrain.io.load_dem` refuses on its own as not elevation data) is
    written as an empty mesh, its ``extras`` saying ``"empty"``, and counts as done (a rerun skips it), also for a
    solid. Cost per item: one :func:`~stepterrain.stepped` (O(nodes + output)) plus the export; the items run
    independently, so the run scales with the workers until the disk or the scheduler saturates. The default
    LocalCluster starts its worker processes by *spawn*: a script that calls :func:`batch` needs the usual
    ``if __name__ == "__main__":`` guard.

    References
    ----------
    T. Glander, M. Trapp, J. Döllner: 3D Isocontours - Real-time Generation and Visualization of 3D Stepped
    Terrain Models. Eurographics 2010 (short papers), §3.2 and §4. doi:10.2312/egsh.20101049

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> from stepterrain.batch import batch
    >>> z = np.add.outer(np.arange(9.0), np.arange(9.0))
    >>> report = batch(z, tempfile.mkdtemp(), tile_size=4, interval=2.0, format=".ply", scheduler="serial")
    >>> report.ok, len(report.done)
    (True, 4)
    """
    start = time.perf_counter()
    ext = _check_ext(format)
    for name, value in (("retries", retries), ("workers", workers)):
        least = 0 if name == "retries" else 1
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise InvalidInputError(f"{name} must be an int >= {least}; got {value!r}")
    # Python ints: retries + 2 in a numpy uint64 (2**64 - 1) wrapped to 1, so no attempt ran and every item "failed"
    # with an empty error (and numpy's overflow warning)
    retries, workers = int(retries), int(workers)
    timeout, gamma_value = number_or_nan(connect_timeout), number_or_nan(gamma)  # True is no 1 second, no γ = 1
    if not 0 < timeout <= MAX_CONNECT_TIMEOUT:  # NaN and inf fail the comparisons
        raise InvalidInputError(f"connect_timeout must be a positive number of seconds up to {MAX_CONNECT_TIMEOUT:g} "
                                f"(a day); got {connect_timeout!r}")
    if not 0.0 <= gamma_value <= 1.0:
        raise InvalidInputError(f"gamma must be a number in [0, 1] for batch (per-node γ, callables and lenses do "
                                f"not tile); got {_described(gamma)}")  # an array printed all its rows
    if colors is not None and not isinstance(colors, str):
        raise InvalidInputError(f"colors must be a matplotlib colormap name for batch; got {type(colors).__name__}")
    extras = json_metadata(metadata)  # plain JSON values, so the fingerprint's repr and the workers see those
    check_flag(solid, "solid")
    check_flag(resume, "resume")
    if not callable(progress):
        check_flag(progress, "progress")
    if device is not None:
        if not isinstance(device, (str, wp.Device)):  # str() of it reached every item, each failing alike
            raise InvalidInputError(
                f"device must be a Warp device name ('cpu', 'cuda:0'), a warp.Device or None; got {device!r:.80}")
        if isinstance(scheduler, str) and scheduler == "serial":  # the items run here: refused once, not per item
            from ._device import resolve_device

            resolve_device(device)
    if overview_z_scale is not None and overview_size is None:  # checked for a render that is not to be
        raise InvalidInputError(f"overview_z_scale applies only with overview_size (the overview to render); got "
                                f"overview_z_scale={overview_z_scale!r} without it")
    if floor is not None and not solid:
        raise InvalidInputError("floor applies only with solid=True")
    if floor is not None:
        floor = finite_number(floor, "floor")
    if floor is not None and abs(floor) > FLOAT32_MAX:
        raise InvalidInputError(f"floor must fit in float32 (|x| < {FLOAT32_MAX:.2g}); got {floor:g}")
    if coarsen is not None and (isinstance(coarsen, (bool, np.bool_)) or not isinstance(coarsen, (int, np.integer))
                                or coarsen < 1):
        raise InvalidInputError(f"coarsen must be a positive integer (nodes per new node along each axis); "
                                f"got {coarsen!r}")
    coarsen = None if coarsen is None else int(coarsen)
    if height_unit is not None:
        from .io import check_height_unit

        height_unit = check_height_unit(height_unit)
        if not _of_files(source):
            raise InvalidInputError(
                f"height_unit applies to DEM files, read by load_dem; got a {type(source).__name__} source "
                f"(its heights are used as they are)"
            )
    if band is not None:
        from .io import check_band

        band = check_band(band)
        if not _of_files(source):
            raise InvalidInputError(
                f"band applies to DEM files (a GeoTIFF's bands), read by load_dem; got a {type(source).__name__} "
                f"source, which holds one band; got band={band}"
            )
    if nodata is not None:
        from .io import check_nodata

        given = check_nodata(nodata)
        if not _of_files(source):
            raise InvalidInputError(
                f"nodata applies to DEM files, read by load_dem; got a {type(source).__name__} source (its NaN "
                f"heights are its missing cells); got nodata={nodata!r}"
            )
    else:
        given = ()
    if height_encoding is not None:
        from .io import check_height_encoding

        height_encoding = check_height_encoding(height_encoding, height_unit)  # a unit checked above
        if not _of_files(source):
            raise InvalidInputError(
                f"height_encoding applies to RGB PNG tile files, read by load_dem; got a {type(source).__name__} "
                f"source, which holds heights; got height_encoding={height_encoding!r}"
            )
    if isinstance(source, Terrain) and source.visual is not None and colors is None and not solid:
        # stepped() carries a grid's vertex colours or UVs onto its steps; the tiles, cut from the heights alone,
        # were written grey without a word
        raise InvalidInputError(
            f"source is a Terrain with a visual ({type(source.visual).__name__}), which batch does not cut into "
            "tiles: its tiles would lose the colours stepped() carries over; give colors= (a colormap name) or a "
            "Terrain without a visual"
        )
    # a GDAL raster to tile with crop is read only in the crop's window (a crop of one over the memory budget), but
    # for a spacing=, which places the raster (and so the crop) anew after it is read
    windowed = crop is not None and spacing is None and tile_size is not None and isinstance(
        source, (str, os.PathLike)) and Path(os.fspath(source)).suffix.lower() in GDAL_FORMATS
    items, src = plan_items(source, tile_size=tile_size, height_unit=height_unit, band=band,
                            crop=crop if windowed else None, height_encoding=height_encoding, nodata=given or None)
    own = _LIBRARY_KEYS | {key for item in items[:1] for key in _item_metadata(item)}
    if taken := sorted(set(extras) & own):  # the library's value replaced the caller's without a word, or the
        raise InvalidInputError(  # caller's the mesh's own (isovalues, gamma, CRS)
            f"metadata keys {', '.join(map(repr, taken))} are written by stepterrain itself on these outputs "
            f"(its keys: {', '.join(sorted(own))}); give yours other names"
        )
    files = isinstance(source, (str, os.PathLike)) or (isinstance(source, (list, tuple)) and src is None)
    file_spacing = None
    recorded: dict[str, Any] = {}  # the file options, as steps, closeup and texture record them
    if band is not None:  # which of the files' bands the heights are
        recorded["band"] = band
    if height_encoding is not None:  # the colours the files' heights were decoded from
        recorded["height_encoding"] = height_encoding
    if finite := recorded_nodata(given):  # the values read as missing besides the files' own nodata
        recorded["nodata"] = finite
    if origin is not None and (files or src is None or not isinstance(source, np.ndarray | list | tuple)):
        raise InvalidInputError("origin applies to an array source; a file, a folder or a Terrain has its own")
    if spacing is not None and files:  # a file without georeferencing: load_dem's 1 m cells, rows north to south
        file_spacing = _file_spacing(spacing)
        recorded["spacing"] = list(file_spacing)
        if src is not None:  # one raster to tile, or a series file: read already
            _check_unreferenced(src.crs, src.spacing, src.origin, os.fspath(source))  # type: ignore[arg-type]
            src = dataclasses.replace(src, spacing=file_spacing)
            file_spacing = None
    elif spacing is not None or origin is not None:
        if src is None or not isinstance(source, np.ndarray | list | tuple):
            raise InvalidInputError(
                "spacing and origin apply to an array source or to DEM files with no georeferencing; a Terrain has "
                "its own")
        probe = Terrain.from_heights(np.zeros((2, 2), np.float32), spacing=spacing if spacing is not None else (1, 1),
                                     origin=origin if origin is not None else (0, 0))  # fmt: skip
        src = dataclasses.replace(src, spacing=probe.spacing, origin=probe.origin)
    if crop is not None and src is None:
        raise InvalidInputError(
            f"crop applies to one raster (cut into tiles with tile_size) or a (T, H, W) series; the files of a "
            f"{'folder' if isinstance(source, (str, os.PathLike)) else 'list'} each cover their own extent: crop them "
            f"one by one, or give one raster with tile_size; got crop={crop!r}")
    if src is not None and (crop is not None or coarsen is not None):  # before tiling: the tiles still weld
        src = _reshaped_source(src, None if windowed else crop, coarsen)
        items = _tile_items(src.heights.shape, tile_size) if items and items[0].kind == "tile" else _frame_items(
            src.heights)  # type: ignore[arg-type]
    if crop is not None:
        recorded["crop"] = [float(v) for v in np.asarray(crop, np.float64).reshape(-1)]
    if coarsen is not None:
        recorded["coarsen"] = coarsen
    if taken := sorted(set(extras) & set(recorded)):
        raise InvalidInputError(f"metadata keys {', '.join(map(repr, taken))} are written by stepterrain itself on "
                                f"these outputs (the {', '.join(f'{k}=' for k in taken)} given); give yours other "
                                "names")
    # with the shared levels' default interval, before the floor: without it a solid's default floor was a tenth of
    # the levels' span down, not one interval (952.5 m for tiles where stepped() puts the whole at 975 m)
    chosen = interval is None and levels is None  # the default interval, said once before the items run
    level_values, z_range, interval, lowest = _levels_and_range(src, interval, levels, base)
    if src is not None and items and items[0].kind == "tile" and z_range is not None:
        src = dataclasses.replace(src, bounds=_raster_bounds(src, z_range))
    if floor is not None and solid and src is not None and level_values is not None:
        # heights at hand: refused once, not per item
        _check_floor_over(lowest, src.name, level_values, gamma_value, float(floor))
    elif solid and src is not None and level_values is not None:  # every tile or frame on the whole source's floor
        floor = _floor_under(lowest, level_values, gamma_value, None if interval is None else float(interval))
    if src is None:  # no shared height range yet: check interval/levels/base now, not once per item (neither given:
        from .stepped import isovalues  # the default interval over all files, found with their range below)

        isovalues((0.0, 0.0), interval=1.0 if interval is None and levels is None else interval, levels=levels,
                  base=base)  # fmt: skip
    if colors is not None:
        from .stepped import colormap

        colormap(colors)  # an unknown colormap fails here, not in every task
    options = _Options(
        interval=None if level_values is not None else (None if interval is None else float(interval)),
        levels=level_values if level_values is not None else (
            None if levels is None else tuple(float(v) for v in np.asarray(levels, np.float64).reshape(-1))),
        base=0.0 if level_values is not None else float(base),  # shared levels hold the base already
        gamma=gamma_value, colors=colors, solid=bool(solid),
        floor=None if floor is None else float(floor), ext=ext, device=None if device is None else str(device),
        metadata=tuple(sorted({**extras, **recorded}.items())), height_unit=height_unit,
        file_spacing=file_spacing, coarsen=coarsen if src is None else None,  # a source's: coarsened already
        band=band, height_encoding=height_encoding, nodata=given,
        several_files=sum(item.kind == "file" for item in items) > 1,
    )  # fmt: skip
    if interval is not None:  # the isovalues are base + k * interval: both recorded (a long list keeps its ends only)
        steps = (("interval", float(interval)), ("base", float(base)))
        options = dataclasses.replace(options, metadata=options.metadata + steps)
    if overview_size is not None:  # before any item runs (once refused only after every item was written)
        _check_overview(items, src, overview_size, 2.0 if overview_z_scale is None else overview_z_scale,
                        level_values, gamma_value, options.floor)
    _check_scheduler(scheduler)
    folder, made = _check_output_dir(output_dir)
    lock = _FolderLock(folder)  # before anything is read or removed there: another run may be writing it
    try:
        manifest = _read_manifest(folder)  # once: its items and the files' recorded ranges (a folder's refused here)
        ranges = None  # the files' height ranges to record in the manifest (None: none, or a tiles or series run)
        identities = None
        kept: _Kept | None = None
        # the warnings the files' range pass said (load_dem's of each file): their items' reads give them again, in
        # a worker or from the kept read, and each was said twice, before and after the progress bar started
        said: set[str] = set()
        if src is None and items:  # a folder's or list's files: one height range, so one set of levels and one floor
            # (after the cheap checks and the output folder's, locked: every file is read, and a bad scheduler
            # address, an output_dir that is a file or one another run was writing was refused only after that)
            recorded = manifest[1]  # each unchanged file's, not read again
            identities = _file_identities(items)  # stat'd once: for the ranges' keys and the fingerprints
            if options.several_files:  # files in degrees: placed in the local metres of their mosaic
                options = dataclasses.replace(options, frames=_degree_frames(items))
            # one file stepped in this process: its range pass's read is its item's (not two reads of one file);
            # several are read one at a time, not all held until their items run
            serial = isinstance(scheduler, str) and scheduler == "serial"
            kept = {} if serial and len(items) == 1 else None
            try:
                options, ranges, z_range = _files_levels(
                    items, options, None if interval is None else float(interval), levels, base, retries,
                    bool(progress), recorded, identities, kept, said)  # fmt: skip
            except BaseException:
                lock.release()
                _remove_empty(made)  # nothing was written: leave no empty output folder behind
                raise
            if ranges is None and recorded:  # no file read (no colours, no solid): the recorded ranges stay, for
                ranges = (recorded, False)  # the next run that needs them (they were dropped with the manifest)
            if chosen and z_range is not None:
                interval = dict(options.metadata)["interval"]
                level_values = options.levels
        shared = level_values or options.levels  # a folder's: over its files' range
        if not chosen and z_range is not None and shared:  # isovalues given: one flat terrace is said, once
            from .stepped import _one_level

            span = f"{shared[0]:g}" if len(shared) == 1 else f"{shared[0]:g} to {shared[-1]:g}"
            given = f"levels= {span}" if levels is not None else f"interval= {float(interval):g} ({span})"  # type: ignore[arg-type]
            if (why := _one_level(*z_range, shared, given, gamma_value)) is not None:
                warnings.warn(why, stacklevel=2)
        if chosen and z_range is not None and progress:  # as `stepterrain steps` says it, once
            _say_interval(progress, float(interval), len(level_values or ()), z_range)  # type: ignore[arg-type]
        run = dict(scheduler=scheduler, workers=workers, retries=retries, resume=resume, timeout=timeout)
        return _run_locked(items, src, options, folder, made, lock, progress=progress, start=start, ranges=ranges,
                           read=manifest, identities=identities, kept=kept, said=said, **run)
    finally:
        lock.release()


def _say_interval(progress: bool | Callable[[str], str], interval: float, n_levels: int,
                  z_range: tuple[float, float]) -> None:
    """Say on stderr the default interval :func:`batch` chose (neither ``interval`` nor ``levels`` given), as
    ``stepterrain steps`` says its own: through ``progress`` when it rewords lines (the CLI's options)."""
    from .stepped import TARGET_STEPS

    lo, hi = z_range
    line = (f"no interval= or levels= given: using interval={interval:g}, a round interval giving "
            f"{counted(n_levels, 'level')} over heights {lo:g} to {hi:g} (aim ~{TARGET_STEPS} steps)")
    print(progress(line) if callable(progress) else f"stepterrain batch: {line}", file=sys.stderr, flush=True)


def _run_locked(
    items: Sequence[BatchItem],
    src: _Source | None,
    options: _Options,
    folder: Path,
    made: Sequence[Path],
    lock: _FolderLock,
    *,
    scheduler: Any,
    workers: int,
    retries: int,
    resume: bool,
    timeout: float,
    progress: bool | Callable[[str], str],
    start: float,
    read: tuple[dict[str, Any], dict[str, Any], str | None],
    ranges: tuple[dict[str, Any], bool] | None = None,
    identities: Mapping[str, str] | None = None,
    kept: _Kept | None = None,
    said: Iterable[str] = (),
) -> BatchReport:
    """:func:`batch` once the arguments are checked and the output folder is locked; ``ranges``: the files' height
    ranges to record in the manifest (:func:`_files_range`) and whether they differ from those it records;
    ``read``: :func:`_read_manifest` of the folder; ``identities``: the file items'
    :func:`_file_identities` (found here when not given); ``kept``: terrains the range pass read, by item key, for
    the serial run's items; ``said``: the messages of warnings said already (the files' range pass's), not said
    again when an item's result gives them."""
    ext = options.ext
    outputs = [f"{item.key}{ext}" for item in items]
    _remove_partial(folder, outputs + [MANIFEST_NAME])

    fingerprints = _fingerprints(items, src, options, identities)
    # read without resume too: the entries of other items and other formats stay recorded
    manifest, _, manifest_note = read
    notes = [note for note in (lock.note, manifest_note) if note is not None]
    results: dict[str, ItemResult] = {}
    todo = []
    for item in items:
        name = f"{item.key}{ext}"
        if resume and _is_complete(manifest.get(name), fingerprints[item.key], folder, name):
            entry = manifest[name]  # its counts as recorded (a skipped item reported 0 faces and 0 vertices)
            counts = {k: entry[k] for k in ("faces", "vertices")
                      if isinstance(entry.get(k), int) and not isinstance(entry[k], bool) and entry[k] >= 0}
            results[item.key] = ItemResult(item.key, "skipped", path=str(folder / name), bytes=entry["bytes"],
                                           **counts)  # fmt: skip
        else:
            todo.append(item)
            manifest.pop(name, None)
    keys = {item.key for item in items}
    others = sorted({Path(n).suffix for n in manifest if Path(n).suffix != ext and Path(n).stem in keys})
    if others:
        count = sum(1 for n in manifest if Path(n).suffix in others and Path(n).stem in keys)
        notes.append(f"the manifest also records {counted(count, 'output')} of these items in another format "
                     f"({', '.join(others)}), kept beside this run's {ext} files")  # fmt: skip
    # outputs of items this run does not have (an earlier run's other tile size or source): they stayed, unsaid, and
    # out/*.glb then loaded overlapping stale tiles with this run's
    strangers = sorted(n for n in manifest if Path(n).stem not in keys and (folder / n).exists())
    if strangers:
        shown = ", ".join(strangers[:3]) + (", ..." if len(strangers) > 3 else "")
        notes.append(f"the folder holds {counted(len(strangers), 'recorded output')} of items this run does not have "
                     f"({shown}), from an earlier run with another source or tile size: left as they were")  # fmt: skip
    # outputs an earlier run left of the items this run writes: one that fails keeps it, made with other input or
    # options (or never recorded), and out/*.glb loaded it with this run's outputs without a word
    # (a folder of that name is none: its item fails, naming it, and was said to keep "an earlier run's output")
    earlier = {item.key for item in todo
               if os.path.lexists(folder / f"{item.key}{ext}") and not os.path.isdir(folder / f"{item.key}{ext}")}

    recorder = _Recorder(folder, manifest, fingerprints, ranges)
    serial = isinstance(scheduler, str) and scheduler == "serial"
    # a nanny writes its pre-spawn variables into os.environ again when it restarts a worker that died: put back
    # when the default cluster is closed, as start_local_cluster puts them back once its workers have started
    environ = {key: os.environ.get(key) for key in LOCAL_CLUSTER_MALLOC}
    # no more LocalCluster workers than items to run: each extra one took seconds to start, and a LocalCluster gives
    # each worker 1/n_workers of the machine's memory as its limit (workers=8 for two files: an eighth each)
    workers = min(workers, len(todo))
    try:
        connection = None if serial or not todo else _connect(scheduler, workers, timeout)
    except BaseException:
        lock.release()
        _remove_empty(made)  # nothing was written: leave no empty output folder behind
        raise
    description = "serial" if connection is None else connection[2]
    bar = _progress_bar(len(items), len(results), bool(progress))
    reworded = progress if callable(progress) else None
    stream: Iterable[ItemResult] = ()
    salvage: list[ItemResult] = []  # results that had reached this process when the run was interrupted
    try:
        if connection is None:
            stream = _run_serial(todo, src, options, folder, retries, kept)
        else:
            stream = _run_dask(todo, src, options, folder, connection, retries, timeout, salvage)
        hint = budget_hint()
        level = caller_stacklevel()  # the caller's line, as save_mesh and load_dem point their warnings
        rounded: list[str] = []  # STL's float32 rounding, one message per tile of a UTM raster: said once below
        opened: list[str] = []  # and the .stl files that read back open (a solid's pinches at UTM), said once too
        shown = set(said)  # a message many items give alike, once (the serial run's recording of each item
        # reset Python's registry of warnings already shown, so its "default" filter repeated it for every item)
        for result in stream:
            if result.error and hint != BUDGET_HINT and BUDGET_HINT in result.error:
                # a worker process's refusal gives the library's hint: this process's (the CLI's option) instead,
                # for the progress bar, the report and its summary alike
                result = dataclasses.replace(result, error=result.error.replace(BUDGET_HINT, hint))
            results[result.key] = result
            recorder.add(result)
            for message in result.warnings:  # a worker process's (or this one's, serial), said here
                if _STL_ROUNDING_RE.search(message):
                    rounded.append(message)
                elif _STL_OPEN_RE.search(message):
                    opened.append(message)
                elif message not in shown:
                    shown.add(message)
                    warnings.warn(message, stacklevel=level)
            _tick(bar, result, reworded)
        if rounded:
            warnings.warn(_rounding_summary(rounded, sum(r.status == "done" for r in results.values())),
                          stacklevel=level)  # fmt: skip
        if opened:
            warnings.warn(_open_summary(opened, sum(r.status == "done" for r in results.values())), stacklevel=level)
    finally:
        # the default LocalCluster's scheduler runs in this process: as it went down under an interrupted run, it
        # logged a CRITICAL traceback for each task still reported to the closed client and an ERROR listing every
        # heights block its workers held (hundreds of kB on the terminal after Ctrl-C); after a run of many items,
        # interrupted or not, a worker logged "ERROR - Failed to communicate with scheduler during heartbeat" and
        # its traceback as the cluster closed. None of them the user's: the cluster is closed in silence
        # Ctrl-C (SIGTERM, SIGHUP) held back while the run is wound up, raised after it: one that came as the run
        # ended (or a second one during an interrupted run's clean-up) stopped the manifest's last rewrite, and
        # the run's outputs, written and complete, were left unrecorded for a rerun to redo
        with signals_held():
            own = connection is not None and connection[1] is not None
            with _dask_logs_silenced(connection[0]) if own else nullcontext():  # type: ignore[index]
                if connection is not None and isinstance(stream, Generator):
                    # interrupted in this loop (Ctrl-C as a result was recorded): the generator cancels its tasks now,
                    # while the client is open; closed by the garbage collector after it, it failed ("Exception ignored
                    # in: <generator object _run_dask>" ... "RuntimeError: IOLoop is closed") and left them running
                    stream.close()
                for result in salvage:  # finished before the interrupt: recorded, so that a rerun does not redo them
                    recorder.add(result)
                recorder.flush()
                if bar is not None:
                    bar.close()
                if connection is not None:
                    try:
                        _disconnect(scheduler, connection)
                    finally:
                        if connection[1] is not None:  # the default LocalCluster, closed
                            _restore_environ(environ)
            # a worker killed while writing (its items run again, or its cluster closed under an interrupted run: the
            # partial file stayed until a rerun) left its temporary file: the folder is still ours
            _remove_partial(folder, outputs + [MANIFEST_NAME])
    if recorder.unrecorded is not None:
        notes.append(recorder.unrecorded)
    kept = [f"{i.key}{ext}" for i in items if i.key in earlier and results[i.key].status == "failed"]
    if kept:
        shown = ", ".join(kept[:3]) + (", ..." if len(kept) > 3 else "")
        notes.append(f"the folder still holds an earlier run's output of {counted(len(kept), 'failed item')} "
                     f"({shown}), made with that run's input and options, not this one's: redo or remove them before "
                     "using the folder")
    report = BatchReport(folder, [results[i.key] for i in items if i.key in results],
                         time.perf_counter() - start, description, notes,
                         kind=items[0].kind if items else None)  # fmt: skip
    return report


def _rounding_summary(messages: Sequence[str], written: int) -> str:
    """One warning for the items' STL float32 rounding warnings (each item's stays in its result's ``warnings``): a
    batch of UTM tiles warned once per tile, thousands of lines saying the same."""
    if len(messages) == 1:
        return messages[0]
    worst = max(messages, key=lambda m: float(_STL_ROUNDING_RE.search(m)["error"]))  # type: ignore[index]
    return (f"{len(messages)} of the {written} .stl outputs written have vertices that float32 moves by more than "
            f"{_STL_ROUNDING_TOLERANCE:g}; the worst, {worst}")


def _open_summary(messages: Sequence[str], written: int) -> str:
    """One warning for the items' warnings that their ``.stl`` reads back open (each item's stays in its result's
    ``warnings``): a batch of UTM solid tiles with nodata voids warned once per tile."""
    if len(messages) == 1:
        return messages[0]
    worst = max(messages, key=lambda m: int(_STL_OPEN_RE.search(m)["edges"]))  # type: ignore[index]
    return (f"{len(messages)} of the {written} .stl outputs written read back open where corners are merged by "
            f"position; the worst, {worst}")


def _shared_levels(
    src: _Source | None, interval: float | None, levels: ArrayLike | None, base: float
) -> tuple[float, ...] | None:
    """Isovalues over the whole series or raster, so every frame or tile uses the same ones."""
    return _levels_and_range(src, interval, levels, base)[0]


def _raster_bounds(
    src: _Source, z_range: tuple[float, float]
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The lowest and highest corner of the whole raster: its xy extent, and in z its finite heights' range."""
    (dx, dy), (x0, y0) = src.spacing, src.origin
    rows, cols = src.heights.shape[-2:]
    xs, ys = sorted((x0, x0 + (cols - 1) * dx)), sorted((y0, y0 + (rows - 1) * dy))
    return (xs[0], ys[0], z_range[0]), (xs[1], ys[1], z_range[1])


def _levels_and_range(
    src: _Source | None, interval: float | None, levels: ArrayLike | None, base: float
) -> tuple[tuple[float, ...] | None, tuple[float, float] | None, float | None, float | None]:
    """:func:`_shared_levels`, the (min, max) of the heights they came from (those a triangle uses, as
    :attr:`~stepterrain.terrain.Terrain.height_range`; None without a source), the interval: ``interval``, or
    without it and ``levels`` the default one for that range; and the lowest height a triangle uses
    (:func:`~stepterrain.terrain.lowest_used_height`, for a solid's floor: :func:`_floor_under`,
    :func:`_check_floor_over`; None where no triangle has three finite heights), found in the same pass as the range
    (a solid's source with nodata was read twice)."""
    if src is None:
        return None, None, interval, None
    from .stepped import _default_isovalues, isovalues

    if src.height_range is not None:  # found by the source's checks: no further pass, no copy
        lo, hi = src.height_range
        lowest = lowest_used_height(src.heights, src.height_range)  # its min (rows of one node: no triangle)
    else:  # nodata (or a series file): the range of the nodes a triangle uses, as stepped() takes it; a series'
        # frame by frame (used_height_range reads a stack so), as stepped_series takes a stack's
        used, any_used = _used_span(src.heights)
        if used is None:
            raise InvalidInputError(f"source {src.name!r} holds no finite height")
        lo, hi = used
        lowest = lo if any_used else None  # (no triangle: the range is that of the finite heights)
    if interval is None and levels is None:
        interval, found = _default_isovalues(lo, hi, base)
    else:
        found = isovalues((lo, hi), interval=interval, levels=levels, base=base)
    return tuple(float(v) for v in found), (lo, hi), interval, lowest


def _files_range(
    items: Sequence[BatchItem], options: _Options, retries: int, progress: bool,
    cached: Mapping[str, Any], identities: Mapping[str, str], kept: _Kept | None = None,
    said: set[str] | None = None,
) -> tuple[tuple[tuple[float, float], str] | None, dict[str, Any]]:
    """The (min, max) of the heights a triangle uses over every file of a folder or list (each file's
    :attr:`~stepterrain.terrain.Terrain.height_range`, read as its item reads it: ``height_unit``, ``band``,
    ``spacing``, ``coarsen``), and the file holding the lowest (None when no file has a triangle of three finite
    heights); and each file's range by :func:`_range_key` (``[min, max]``, None for no surface; not a file that
    could not be read), for the manifest. A file whose key ``cached`` holds (the manifest of an earlier run: the same
    file, unchanged, read with the same options) is not read again; every other one is, one file in memory at a
    time, read once more than its item reads it. A file that cannot be read (a
    :class:`~stepterrain.errors.StepTerrainError`, which fails its item without retries) is left out, its item
    failing with the reason; a transient OSError under the read (EIO, ETIMEDOUT, ...: a disk or network
    hiccup) is retried ``retries`` times, then raised: levels from the other files alone would differ from those of
    a run that read it. ``identities``: the files' :func:`_file_identities`. ``kept``:
    where the terrains read go, by item key, for items that run in this process after (:func:`_run_serial`), so
    that a file is read once (the caller asks for it for one file only: not every file of a folder in memory).
    ``said``: the messages of the warnings the reads gave, each said once (:func:`_file_range`), go into it."""
    said = set() if said is None else said
    keys = [_range_key(identities[item.key], options) for item in items]
    bar = None
    unread = sum(key not in cached for key in keys)
    if progress and unread > 1:
        from tqdm.auto import tqdm

        bar = tqdm(total=unread, desc="stepterrain batch: height range", unit="file")
    lo, hi, lowest = math.inf, -math.inf, ""
    ranges: dict[str, Any] = {}
    try:
        for item, key in zip(items, keys, strict=True):
            if key in cached:  # recorded by an earlier run: the same file, read alike
                found = cached[key]
            else:
                found = _file_range(item, options, retries, kept, said=said)
                if bar is not None:
                    bar.update(1)
                if found is ...:  # unreadable: its item fails with the reason; no range recorded
                    continue
            ranges[key] = found
            if found is not None:  # an empty item (nodata only) moves no level
                a, b = found
                if a < lo:
                    lo, lowest = a, str(item.path)
                hi = max(hi, b)
    finally:
        if bar is not None:
            bar.close()
    return (None if lowest == "" else ((lo, hi), lowest)), ranges


def _file_range(item: BatchItem, options: _Options, retries: int, kept: _Kept | None = None, *,
                said: set[str]) -> Any:
    """:func:`_files_range`'s read of one file: ``[min, max]`` of its heights a triangle uses, None for no surface,
    ``...`` for a file that cannot be read (its item fails with the reason); a transient OSError retried ``retries``
    times, then raised. The terrain read goes into ``kept`` (by the item's key) when given, with its read's warnings:
    it is the item's, read as the item reads it. The read's warnings are said here (a read that failed included),
    each message once: those ``said`` holds already are not, and those said go into it, so that the item's own read
    (a worker's, warned again in this process by :func:`_run_locked`) does not say them a second time."""
    for attempt in range(retries + 1):
        caught: list[warnings.WarningMessage] = []
        try:
            try:  # recorded, as run_item records its item's read: its warnings are its result's too (kept)
                with _RECORDING, warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("default")
                    terrain = _item_terrain(item, None, options.height_unit, options.file_spacing,
                                            options.coarsen, options.band, options.height_encoding,
                                            options.nodata)  # fmt: skip
            finally:
                for w in caught:
                    if str(w.message) in said:
                        continue
                    said.add(str(w.message))
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        except StepTerrainError as exc:  # its item fails with it (an unreadable file), as it fails there
            if _transient(exc) and attempt < retries:
                continue
            if _transient(exc):
                raise DataFileError(
                    f"cannot read {item.path!r} for the height range every file's levels come from "
                    f"({type(exc).__name__}: {exc}); run again when it can be read") from exc
            return ...
        if kept is not None:
            kept[item.key] = (terrain, tuple(dict.fromkeys(str(w.message) for w in caught)))
        if not _has_surface(terrain):
            return None
        return [float(v) for v in terrain.height_range]
    raise AssertionError("unreachable")  # the last attempt returns or raises


def _files_levels(
    items: Sequence[BatchItem], options: _Options, interval: float | None, levels: ArrayLike | None, base: float,
    retries: int, progress: bool, cached: Mapping[str, Any], identities: Mapping[str, str],
    kept: _Kept | None = None, said: set[str] | None = None,
) -> tuple[_Options, tuple[dict[str, Any], bool] | None, tuple[float, float] | None]:
    """``options`` with the levels and floor every file of a folder or list shares, as tiles of one raster share
    them (:func:`_levels_and_range`, :func:`_floor_under`): the isovalues of ``interval`` over the height range of
    all files (:func:`_files_range`; explicit ``levels`` as given), so that a height gets one colour in every file,
    and a solid's default floor under the lowest of all files, so that every file stands on one base; an explicit
    ``floor`` checked against every file here, refused once before any item runs, naming the file whose surface it
    does not lie below. Without ``interval`` and ``levels``, the default interval over that range
    (:func:`~stepterrain.stepped.nice_interval`, as :func:`~stepterrain.stepped` picks it for one raster), recorded
    in the metadata as tiles of one raster record theirs. The files are read only when that matters: a colormap over
    ``interval`` levels, a solid, or no interval yet; a file whose range the manifest records (``cached``, by
    :func:`_range_key`) is not read again. ``options`` as they are when no file has a surface (every item is
    empty). Also the files' ranges for the manifest and whether they differ from ``cached`` (None: none read), and
    the height range of all files (None: none read, or no surface). ``identities``, ``kept``, ``said``:
    :func:`_files_range`'s.
    """
    if not (options.solid or (options.colors is not None and levels is None) or (interval is None and levels is None)):
        return options, None, None  # explicit levels without a solid: every file has them already; no colours: none
    found, ranges = _files_range(items, options, retries, progress, cached, identities, kept, said)
    changed = dict(cached) != ranges  # a range added, dropped or changed
    if found is None:
        return options, (ranges, changed), None
    (lo, hi), lowest = found
    from .stepped import _default_isovalues, isovalues

    if levels is None:
        if interval is None:  # steps' default for one raster, over all the files
            interval, found = _default_isovalues(lo, hi, base)
            steps = (("interval", float(interval)), ("base", float(base)))
            options = dataclasses.replace(options, metadata=options.metadata + steps)
        else:
            found = isovalues((lo, hi), interval=interval, base=base)
        values = tuple(float(v) for v in found)
        options = dataclasses.replace(options, interval=None, levels=values, base=0.0)
    else:
        values = options.levels  # type: ignore[assignment]
    if options.solid and options.floor is not None:
        _check_floor_over(lo, f"{lowest!r} (the lowest of the {counted(len(items), 'file')}, which share one floor)",
                          values, options.gamma, options.floor)  # fmt: skip
    elif options.solid:
        options = dataclasses.replace(options, floor=_floor_under(lo, values, options.gamma, interval))
    return options, (ranges, changed), (lo, hi)


def _floor_under(h: float | None, values: tuple[float, ...], gamma: float, interval: float | None) -> float | None:
    """The default floor of a solid over the whole source, :func:`~stepterrain.stepped`'s for the whole raster: one
    interval (without one, a tenth of the levels' span) below the lowest isovalue or the lowest vertex of the whole
    stepped surface, ``h`` the lowest height a triangle uses over the whole source (a raster, a series, or every file
    of a folder: :func:`_levels_and_range`, :func:`_files_range`). Each tile or frame stepped alone put its floor
    under its *own* lowest vertex, and without the interval (the items get the shared levels) a tenth of the span
    down: tiles that did not meet at their base, and under a floor other than the whole raster's. None when no
    triangle has three finite heights (``h`` None)."""
    if h is None:
        return None
    from .stepped import default_floor, stepped_height

    values32 = np.asarray(values, np.float32)
    return default_floor(values32, stepped_height(h, values32, gamma)[0], interval)


def _check_floor_over(h: float | None, name: str, values: tuple[float, ...], gamma: float, floor: float) -> None:
    """Refuse a solid's floor that is not below the lowest point of every frame's or tile's stepped surface, ``h``
    the lowest height a triangle uses over the whole source (:func:`_levels_and_range`), ``name`` the source (or, in
    a folder, the file) holding it.

    That point is (1 − γ) h + γ α(h) in float32 (:func:`~stepterrain.stepped.stepped_height`) at the lowest height
    h of a node that a triangle with three finite heights uses, α(h) the isovalue it snaps to (monotone in h, and so
    is each float32 rounding, so no vertex lies lower); tiles share their border nodes, so their triangles are the
    raster's. The floor ``close_solid`` checks per item, known here at once."""
    if h is None:
        return  # no surface at all: each item says so
    from .mesh import float32_floor_clash
    from .stepped import stepped_height

    # the vertex as the kernel blends it, in float32: the float64 value of the blend let a floor through that lay on
    # it (or above it) in float32, and close_solid refused it in the item holding the lowest point, the others written
    lowest, alpha = stepped_height(h, np.asarray(values, np.float32), gamma)
    if floor >= lowest:  # a floor on the point itself is refused once, up front
        raise InvalidInputError(
            f"floor (the CLI's --floor) must lie below the lowest point {lowest:.9g} of the stepped surface of "
            f"{name} (its lowest height {h:g} on the isovalue {alpha:g}, γ = {gamma:g}); got {floor:.9g}"
        )
    clash = float32_floor_clash(floor, lowest)
    if clash:  # below it, but on it in float32: close_solid refuses it in every item that has it
        raise InvalidInputError(f"floor (the CLI's --floor) must lie below the lowest point {lowest:.9g} of the "
                                f"stepped surface of {name}{clash}")


class _Recorder:
    """Keeps the manifest: finished items are added and the file is rewritten at most once a second.

    A rewrite that fails (a full disk, a folder gone read-only) does not end the run: the outputs are written
    atomically and complete without it, and a rerun redoes what it does not record. The entries stay to write at
    the next flush; :attr:`unrecorded` says how many outputs of this run the manifest on disk lacks, and why."""

    def __init__(self, folder: Path, entries: dict[str, Any], fingerprints: Mapping[str, str],
                 ranges: tuple[dict[str, Any], bool] | None = None) -> None:
        self.folder, self.entries, self.fingerprints = folder, entries, fingerprints
        self.ranges = None if ranges is None else ranges[0]  # a folder's files' height ranges, recorded with them
        self.last = 0.0
        self.pending = 0  # outputs of this run added since the manifest was last written
        # ranges the manifest does not record yet: a rerun whose every item is skipped writes them too
        self.ranges_pending = ranges is not None and ranges[1]
        self.error: str | None = None  # why the last rewrite failed (None: it did not)

    def add(self, result: ItemResult) -> None:
        if result.status != "done" or result.path is None:
            return
        name = Path(result.path).name  # by file: the item's outputs in other formats keep their entries
        self.entries[name] = {
            "fingerprint": self.fingerprints[result.key],
            "file": name,
            "bytes": result.bytes,
            "faces": result.faces,
            "vertices": result.vertices,
        }
        self.pending += 1
        if time.monotonic() - self.last > _MANIFEST_FLUSH_S:
            self.flush()

    def flush(self) -> None:
        if self.pending or self.ranges_pending:  # entries (or ranges) added since the manifest was last written
            try:
                if self.ranges is None:
                    _write_manifest(self.folder, self.entries)
                else:
                    _write_manifest(self.folder, self.entries, self.ranges)
            except OSError as exc:  # also the DataFileError of atomic_path: ENOSPC ended the whole run, unattributed
                self.error = exc.strerror or str(exc)
            else:
                self.pending, self.ranges_pending, self.error = 0, False, None
            self.last = time.monotonic()

    @property
    def unrecorded(self) -> str | None:
        """A note when the manifest on disk lacks outputs of this run (its last rewrite failed), else None."""
        if self.error is None or not self.pending:  # the ranges alone: read again by the next run
            return None
        return (f"the manifest {MANIFEST_NAME} could not be written ({self.error}): it does not record "
                f"{counted(self.pending, 'output')} of this run (written complete), which a rerun redoes")


def _progress_bar(total: int, initial: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc="stepterrain batch", unit="item")


def _tick(bar: Any, result: ItemResult, reworded: Callable[[str], str] | None = None) -> None:
    if bar is not None:
        bar.update(1)
        if result.status == "failed":
            line = _failure_line(result)
            # tqdm writes to stdout by default
            bar.write(line if reworded is None else reworded(line), file=sys.stderr)


def _failure_line(result: ItemResult) -> str:
    """A failed item's line, as the progress bar writes it and :meth:`BatchReport.summary` lists it."""
    return f"failed {result.key}: {result.error} (after {counted(result.attempts, 'attempt')})"


def _run_serial(
    todo: Iterable[BatchItem], src: _Source | None, options: _Options, folder: Path, retries: int,
    kept: _Kept | None = None,
) -> Iterable[ItemResult]:
    """The items one after the other in this process; ``kept``: terrains read already (:func:`_files_range`), by
    item key, with their read's warnings (in the item's result, as its own read's would be), each taken out as its
    item runs (so that it is freed after)."""
    for item in todo:  # its warnings recorded, said by the caller as a worker process's are (STL's rounding once)
        terrain, read = (None, ()) if not kept else kept.pop(item.key, (None, ()))
        result = _run_retried(item, src, options, str(folder), retries, record_warnings=True, terrain=terrain)
        del terrain
        if read:
            result = dataclasses.replace(result, warnings=tuple(dict.fromkeys(read + result.warnings)))
        yield result


def _run_retried(item: BatchItem, source: _Source | None, options: _Options, output_dir: str, retries: int,
                 **kwargs: Any) -> ItemResult:
    """:func:`run_item` up to ``retries + 1`` times in this process, as the serial run and a task of several items
    run each item: an exception is retried, then reported as the item's failure like a failed dask task."""
    error = ""
    for attempt in range(1, retries + 2):
        try:
            result = run_item(item, source, options, output_dir, **kwargs)
        except Exception as exc:  # noqa: BLE001 - retried, then reported like a failed dask task
            error = f"{type(exc).__name__}: {exc}"
            continue
        return dataclasses.replace(result, attempts=attempt)
    return ItemResult(item.key, "failed", error=error, attempts=retries + 1)


def run_items(
    items: Sequence[BatchItem], sources: Sequence[_Source | None], options: _Options, output_dir: str,
    retries: int, cpu_threads: int | None = None, memory_budget: int | None = None, record_warnings: bool = False,
) -> list[ItemResult]:
    """Several small items in one dask task (:func:`_task_groups`), one after the other, each with its own block of
    the heights (``sources``, or Nones): one :class:`ItemResult` per item, in order. An item whose
    :func:`run_item` raises is retried here up to ``retries`` times and then reported failed, as the serial run
    does, so that one item's error neither fails nor redoes the others of its task."""
    return [_run_retried(item, source, options, output_dir, retries, cpu_threads=cpu_threads,
                         memory_budget=memory_budget, record_warnings=record_warnings)
            for item, source in zip(items, sources, strict=True)]  # fmt: skip


#: Nodes of heights a dask task of small items reaches before it takes no more (:func:`_task_groups`): a task costs
#: the scheduler and its worker some milliseconds, more than stepping and writing a tile of 64² (~2 ms on one
#: core), so hundreds of small tiles ran several times slower on the LocalCluster than serially.
_TASK_NODES = 1 << 18
#: Tasks per worker thread the grouping leaves at least (work to balance between the workers, progress to show).
_TASKS_PER_THREAD = 4


def _item_nodes(item: BatchItem, source: _Source | None) -> int:
    """About how many height nodes ``item`` steps: a tile's or frame's exactly; a file's from its size (an .npy's
    4 bytes a node, as float32; a compressed file's 1 byte a node, as a DEM compresses up to about 4 times; a file that
    cannot be read counts as large, a task of its own)."""
    if item.kind == "tile":
        return (item.rows[1] - item.rows[0]) * (item.cols[1] - item.cols[0])
    if item.kind == "frame" and source is not None:
        return int(np.prod(source.heights.shape[1:]))
    try:
        size = os.stat(item.path).st_size  # type: ignore[arg-type]
    except (OSError, TypeError):
        return _TASK_NODES
    return size // 4 if str(item.path).lower().endswith(".npy") else size


def _task_groups(todo: Sequence[BatchItem], source: _Source | None, threads: int) -> list[list[BatchItem]]:
    """``todo`` in consecutive groups, one dask task each: small items together, up to :data:`_TASK_NODES` nodes a
    task, and never so few tasks that a worker thread gets fewer than :data:`_TASKS_PER_THREAD`; a large item is a
    task of its own."""
    most = max(1, -(-len(todo) // (_TASKS_PER_THREAD * max(1, threads))))  # items per task
    groups: list[list[BatchItem]] = []
    group: list[BatchItem] = []
    nodes = 0
    for item in todo:
        n = _item_nodes(item, source)
        if group and (nodes + n > _TASK_NODES or len(group) >= most):
            groups.append(group)
            group, nodes = [], 0
        group.append(item)
        nodes += n
    if group:
        groups.append(group)
    return groups


def _run_dask(
    todo: Sequence[BatchItem],
    src: _Source | None,
    options: _Options,
    folder: Path,
    connection: tuple[Any, Any, str, bool],
    retries: int,
    timeout: float = 10.0,
    salvage: list[ItemResult] | None = None,
) -> Iterable[ItemResult]:
    """The items' results as their tasks finish; ``timeout``: the longest wait for a worker to take the heights of
    an item whose worker died (batch's ``connect_timeout``).

    Small items run several to a task (:func:`_task_groups`, :func:`run_items`); a task of several that does not
    finish (its worker died) is submitted again item by item, so a failure stays the item's own. ``salvage``: where
    the results that had reached this process but were not yet yielded go when the caller stops reading
    (Ctrl-C), so that it can record them."""
    from distributed import as_completed

    client, _cluster, _description, local = connection
    options = dataclasses.replace(options, cwd=os.getcwd())  # relative paths resolved on workers elsewhere
    nthreads = client.nthreads()  # every worker's (scheduler_info lists only the first 5 in some dask versions)
    workers = max(1, len(nthreads)) if local else 1
    threads = max(1, sum(nthreads.values()))
    cpu_threads = max(1, (os.cpu_count() or 1) // workers) if local else None
    memory_budget = get_memory_budget()  # this process's: worker processes have their own (the default)

    def submit(group: list[BatchItem], block: Any) -> Any:
        key = f"stepterrain-batch-{group[0].key}{f'+{len(group) - 1}' if len(group) > 1 else ''}-{os.getpid()}-" \
              f"{time.monotonic_ns()}"
        if len(group) > 1:  # each item retried in the task: one that raises leaves the others' results
            return client.submit(run_items, group, block if block is not None else [None] * len(group), options,
                                 str(folder), retries, cpu_threads, memory_budget, local, pure=False, key=key)
        return client.submit(run_item, group[0], block, options, str(folder), cpu_threads, memory_budget, local,
                             retries=retries, pure=False, key=key)  # fmt: skip

    def heights(group: list[BatchItem]) -> Any:  # what a task of the group reads: one block, or a list of them
        assert src is not None
        return _item_source(src, group[0]) if len(group) == 1 else [_item_source(src, item) for item in group]

    groups = _task_groups(todo, src, threads)
    blocks: list[Any] | None = None
    futures: dict[Any, list[BatchItem]] = {}
    pending: list[ItemResult] = []  # the finished task's results not yet yielded
    completed = None
    # A worker that dies (killed for memory, a crash) takes the blocks scattered to it along: the scheduler cannot
    # run their tasks again and cancels them. Those items are scattered and submitted again, up to `retries` times;
    # they "failed: cancelled" after 0 attempts, about half a LocalCluster's items when one of its two workers died.
    lost: dict[str, int] = {}
    try:
        with signals_held():  # Ctrl-C here cancels all of them below, not those submitted so far
            # each task gets its own block of the heights (scattered once), not the whole raster on every worker
            blocks = client.scatter([heights(g) for g in groups], hash=False) if src is not None else None
            futures = {submit(g, blocks[k] if blocks is not None else None): g for k, g in enumerate(groups)}
        # results are gathered on the client's event loop as tasks finish (no blocking round trip per future
        # from this thread); a task that raised asks for its exception (rare: one round trip)
        completed = as_completed(futures, with_results=True, raise_errors=False)
        for future, result in completed:
            group = futures.pop(future)
            if len(group) > 1 and future.status != "finished":  # its worker died: each item on its own now
                again = [(item, future.status) for item in group]
            elif future.status == "cancelled" and lost.get(group[0].key, 0) < retries:
                again = [(group[0], "cancelled")]
            else:
                again = []
            for item, status in again:
                if status == "cancelled":
                    lost[item.key] = lost.get(item.key, 0) + 1
                try:  # no worker left (all died) waited for ever
                    block = None if src is None else client.scatter(_item_source(src, item), hash=False,
                                                                    timeout=timeout)  # fmt: skip
                except TimeoutError:
                    yield ItemResult(item.key, "failed", attempts=lost.get(item.key, 0), error=(
                        f"cancelled: its worker was lost, and no worker took its heights within {timeout:g} s"))
                    continue
                resubmitted = submit([item], block)
                futures[resubmitted] = [item]
                completed.add(resubmitted)
            if again:
                continue
            item = group[0]
            if future.status == "error":
                exc = future.exception()
                yield ItemResult(item.key, "failed", error=f"{type(exc).__name__}: {exc}", attempts=retries + 1)
            elif future.status == "cancelled":
                yield ItemResult(item.key, "failed", attempts=lost.get(item.key, 0),
                                 error="cancelled" + (" (its worker was lost each time)" if item.key in lost else ""))
            else:
                pending = list(result) if len(group) > 1 else [result]
                while pending:  # each kept there until the caller has taken it (salvaged if it stops meanwhile)
                    yield dataclasses.replace(pending[0], attempts=pending[0].attempts + lost.get(pending[0].key, 0))
                    pending.pop(0)
    except BaseException:  # also GeneratorExit: the caller stopped reading (Ctrl-C in its loop), see _run_locked
        if salvage is not None:  # finished, and in this process: recorded by the caller, not redone by a rerun
            salvage.extend(pending)
            for future, result in completed.next_batch(block=False) if completed is not None else ():
                if future.status == "finished":
                    group = futures.pop(future, None)
                    salvage.extend(result if group is not None and len(group) > 1 else [result])
        # the unfinished tasks and the heights scattered for them: the scheduler forgets them before the client
        # closes, instead of reporting them to a client gone (a CRITICAL traceback each) and of losing its
        # workers' scattered data as the cluster closes (an ERROR listing every block)
        client.cancel(list(futures) + list(blocks or ()))
        raise


def _disconnect(scheduler: Any, connection: tuple[Any, Any, str, bool]) -> None:
    """Close what :func:`_connect` opened (a client handed in by the caller stays open)."""
    client, cluster, _description, _local = connection
    if cluster is not None:
        client.close()
        cluster.close()
    elif not _is_client(scheduler):
        client.close()


def _is_client(obj: Any) -> bool:
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover
        return False
    return isinstance(obj, Client)


# ---------------------------------------------------------------------------------------------- overview
#: What makes an overview's meshes smaller, in the budget's hint of :func:`_check_overview`.
_OVERVIEW_HINT = "give coarsen= or a crop= (fewer nodes per item), or render no overview"
#: The outputs :func:`overview_image` reads by default: a mosaic's tiles, a contact sheet's items.
_MOSAIC_ITEMS, _SHEET_ITEMS = 64, 16


def _sheet_grid(n_items: int) -> tuple[int, int]:
    """(rows, cols) of :func:`overview_image`'s contact sheet of ``n_items`` cells (and :func:`_check_overview`'s)."""
    cols = math.ceil(math.sqrt(n_items))
    return math.ceil(n_items / cols), cols


def _check_overview(items: Sequence[BatchItem], src: _Source | None, overview_size: Any, z_scale: Any = 2.0,
                    values: tuple[float, ...] | None = None, gamma: float = 1.0, floor: float | None = None) -> None:
    """:func:`batch`'s ``overview_size`` and ``overview_z_scale``: the render of :func:`overview_image` (its
    defaults but ``z_scale``) of these items, every one written, checked from the plan before any item runs: against
    the memory budget, the mosaic of the first :data:`_MOSAIC_ITEMS` tiles (their surfaces together), or the largest
    of the first :data:`_SHEET_ITEMS` frames in its cell of the contact sheet; and ``z_scale`` against the height
    the render frames (:func:`_check_overview_reach`; ``values``, ``gamma`` and ``floor``: the items' shared
    isovalues, γ and a solid's floor). A folder's files (``src`` None) are read by the items only: not checked."""
    from . import render

    try:
        width, height, _ = render._check_window(overview_size, z_scale)
    except InvalidInputError as exc:  # window_size and z_scale are overview_image's names for them
        raise InvalidInputError(str(exc).replace("window_size", "overview_size", 1).replace(
            "z_scale", "overview_z_scale", 1)) from None
    render._check_render_budget(width, height, "overview_size")  # the window alone, as overview_image checks it
    if src is None or not items:
        return
    name = "overview_size"
    if items[0].kind == "tile":
        tiles = [src.heights[i.rows[0] : i.rows[1], i.cols[0] : i.cols[1]] for i in items[:_MOSAIC_ITEMS]]
        counts = [grid_surface_counts(tile) for tile in tiles]
        mesh = (sum(v for v, _ in counts), sum(f for _, f in counts))
        # the mosaic is one render of the tiles it shows: the nodes their triangles use
        used = [span for span, some in map(_used_span, tiles) if some and span is not None]
        spans = [(min(lo for lo, _ in used), max(hi for _, hi in used))] if used else []
    else:  # each frame is rendered on its own, in a cell of the window (overview_image's grid; 8 pixels at least)
        shown = items[:_SHEET_ITEMS]
        mesh = max((grid_surface_counts(src.heights[i.index]) for i in shown), key=lambda vf: (vf[1], vf[0]))
        rows, cols = _sheet_grid(len(shown))
        width, height = max(-(-width // cols), 8), max(-(-height // rows), 8)
        name = "contact-sheet cell"
        spans = [span for span, some in (_used_span(src.heights[i.index]) for i in shown) if some and span]
    if values is not None:
        _check_overview_reach(spans, float(z_scale), np.asarray(values, np.float32), gamma, floor)
    render._check_render_budget(width, height, name, mesh=mesh, mesh_hint=_OVERVIEW_HINT, at_least=True)


def _check_overview_reach(spans: Sequence[tuple[float, float]], z_scale: float, values: NDArray[np.float32],
                          gamma: float, floor: float | None) -> None:
    """Refuse a ``z_scale`` that makes some render of an overview (``spans``: the (min, max) of the heights of the
    nodes a triangle uses in each render's meshes) taller than :func:`~stepterrain.render.render_mesh` frames: the mesh
    spans at least its nodes' stepped heights (:func:`~stepterrain.stepped.stepped_height`, monotone in h) and, for a
    solid, the ``floor`` under them; z-scaled about its centre, half of that beyond ±render._MAX_REACH is refused
    there, after every item was stepped and written."""
    from .render import _MAX_REACH
    from .stepped import stepped_height

    tallest = 0.0
    for span in spans:
        top = stepped_height(span[1], values, gamma)[0]
        bottom = floor if floor is not None else stepped_height(span[0], values, gamma)[0]
        tallest = max(tallest, top - bottom)
    with np.errstate(over="ignore"):
        reach = float(np.float64(tallest) / 2.0 * np.float64(z_scale))
    if reach > _MAX_REACH:
        raise InvalidInputError(
            f"overview_z_scale must keep the overview's meshes (at least {tallest:g} tall) within ±{_MAX_REACH:g} of "
            f"their centre once z-scaled, where the render's squared camera distances overflow float64: at most "
            f"{2.0 * _MAX_REACH / tallest:.3g}; got {z_scale:g}")


def overview_image(
    report: BatchReport,
    *,
    window_size: tuple[int, int] = (1280, 800),
    mosaic: bool | None = None,
    max_items: int = _MOSAIC_ITEMS,
    z_scale: float = 2.0,
    camera: Any = "oblique",
) -> NDArray[np.uint8]:
    """An off-screen picture of a batch's outputs: the welded mosaic of tiles, or a contact sheet of items.

    ``mosaic`` (default: when the items are tiles of one raster, not the files of a folder whatever their names)
    renders the outputs together in world coordinates, each
    tile tinted a little differently so the seams show; otherwise up to 16 items are rendered side by side, in
    cells sharing the window (an empty item's, a frame or file of nodata only, stays blank; so does, with a warning,
    one too thin to see in its cell, or an explicit camera shows it under a pixel there, unless no item is drawn:
    then render_mesh's refusal is raised). The picture is
    ``window_size`` (H = its height, W = its width) either way.
    At most ``max_items`` outputs are read (the first, in item order: a mosaic of more tiles shows only part of the
    raster, with a warning saying so), after the window is checked against the memory budget (an
    OutputTooLargeError, as :func:`stepterrain.render.render_mesh` raises). ``camera`` is render_mesh's ("oblique",
    "top", (azimuth, elevation) in radians), for the mosaic and for each cell of a contact sheet alike; an explicit
    position is relative to the centre of what is rendered (the mosaic, or each item).
    """
    import trimesh

    from . import render
    from .export import read_mesh

    width, height, _ = render._check_window(window_size, z_scale)  # the contact sheet's w // cols truncated 64.7
    render._check_render_budget(width, height)  # before any output is read
    render._camera_position(camera, np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]), 1.0)  # its refusal, likewise
    if isinstance(max_items, bool) or not isinstance(max_items, (int, np.integer)) or max_items < 1:
        # -1 dropped the last output silently, 0 said "wrote no output", "3" raised a slicing TypeError
        raise InvalidInputError(f"max_items must be an int >= 1; got {max_items!r}")
    if mosaic is not None:
        check_flag(mosaic, "mosaic")  # "no" was truthy: a mosaic
    written = [Path(r.path) for r in report.results if r.status in ("done", "skipped") and r.path]
    paths = written[:max_items]
    if not paths:
        raise InvalidInputError("the batch wrote no output to show")
    if mosaic is None:  # by the items: a folder of a user's tile_*.tif files was drawn as one mesh, not a sheet
        mosaic = report.kind == "tile" if report.kind is not None else all(
            re.fullmatch(r"tile_r\d+_c\d+", Path(p).stem) for p in paths)
    if mosaic and len(written) > len(paths):  # a jagged strip of the raster's first tile rows, said nowhere
        warnings.warn(f"the overview's mosaic shows the first {len(paths)} of the {len(written)} outputs: the rest of "
                      "the raster is left out of the picture; give a larger max_items= or tile_size (fewer tiles)",
                      stacklevel=2)
    meshes = [read_mesh(p) for p in (paths if mosaic else paths[:_SHEET_ITEMS])]  # a 3MF's colours too
    if not any(len(mesh.faces) for mesh in meshes):  # render_mesh's "mesh has no faces", after the whole run
        raise InvalidInputError(f"every output the overview shows ({len(meshes)} of {len(written)}) is an empty mesh "
                                "(no triangle with three finite heights: nodata only); nothing to render")
    if mosaic:
        tints = np.array([[0.93, 0.93, 0.93], [1.0, 1.0, 1.0]])
        parts = []
        for k, (mesh, path) in enumerate(zip(meshes, paths, strict=True)):
            found = re.match(r"tile_r(\d+)_c(\d+)$", Path(path).stem)
            parity = (int(found[1]) + int(found[2])) % 2 if found else k % 2  # a checkerboard of tiles
            rgb = _base_rgb(mesh) * tints[parity]
            rgba = np.c_[rgb, np.full(len(rgb), 255)].astype(np.uint8)
            mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=rgba)
            parts.append(mesh)
        return render.render_mesh(trimesh.util.concatenate(parts), window_size=(width, height), z_scale=z_scale,
                                  camera=camera)
    rows, cols = _sheet_grid(len(meshes))
    # the cells share the window's pixels exactly: width // cols per cell made the sheet narrower or shorter than
    # window_size (1280 x 798 for 1280 x 800 and 10 items), and a 16-pixel floor per cell wider or taller (64 x 48
    # for 40 x 40); a cell below the 8 pixels a render takes is rendered at 8 and scaled down to it
    xs = [c * width // cols for c in range(cols + 1)]
    ys = [r * height // rows for r in range(rows + 1)]
    sheet = np.full((height, width, 3), 255, np.uint8)
    thin: list[tuple[str, int, int, InvalidInputError]] = []  # items too thin to see in their cells
    for k, mesh in enumerate(meshes):
        if len(mesh.faces) == 0:  # an empty item (a frame or file of nodata only): its cell stays blank (it failed
            # the sheet)
            continue
        r, c = divmod(k, cols)
        w, h = xs[c + 1] - xs[c], ys[r + 1] - ys[r]
        try:
            picture = render.render_mesh(mesh, window_size=(max(w, 8), max(h, 8)), z_scale=z_scale,
                                         camera=camera)[..., :3]
        except InvalidInputError as exc:  # one item too thin to see in its cell (a strip of a file seen from above)
            # (or an explicit camera's too small) lost the whole sheet, after the run, for one cell; told by the
            # error's flag, not by words of its message
            if not exc.too_small_to_see:
                raise
            thin.append((Path(paths[k]).name, w, h, exc))
            continue
        if picture.shape[:2] != (h, w):
            from PIL import Image

            picture = np.asarray(Image.fromarray(picture).resize((w, h), Image.Resampling.LANCZOS))
        sheet[ys[r] : ys[r + 1], xs[c] : xs[c + 1]] = picture
    if thin and len(thin) == sum(1 for mesh in meshes if len(mesh.faces)):  # nothing drawn: a blank picture
        raise thin[0][3]
    for name, w, h, exc in thin:
        warnings.warn(f"the overview's cell of {name} ({w} x {h} pixels) is left blank: {exc}", stacklevel=2)
    return sheet


def _base_rgb(mesh: Any) -> NDArray[np.float64]:
    """(V, 3) colours in 0-255: the mesh's vertex colours, else a light tan."""
    colors = getattr(mesh.visual, "vertex_colors", None) if mesh.visual.kind == "vertex" else None
    if colors is not None and len(colors) == len(mesh.vertices):
        return np.asarray(colors, np.float64)[:, :3]
    return np.tile(np.array([[222.0, 205.0, 170.0]]), (len(mesh.vertices), 1))


make_module_callable(__name__)  # st.batch(...) runs batch(); st.batch.LOCAL_CLUSTER_MALLOC reads the module
