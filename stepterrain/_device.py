"""Device resolution and numpy <-> ``wp.array`` conversion.

Every kernel caller goes through here: ``resolve_device`` turns ``device=None | "cpu" | "cuda:0" | wp.Device``
(or the device of an input that is already a ``wp.array``) into a ``wp.Device``; ``to_device`` converts once
(contiguous float32/int32, no copy on the CPU when the layout already fits); ``empty_shared`` allocates outputs
that kernels write straight into numpy memory on the CPU, large ones on memory that freed outputs left
(``recycled_empty``, the pool :data:`OUTPUTS`).
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
import tempfile
import threading
import weakref
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import numpy as np
import warp as wp

from .errors import DeviceError, InvalidInputError
from .kernels import memory as memory_kernels

_init_lock = threading.Lock()
_pools = threading.local()
_cpu_threads: int | None = None
_executor: ThreadPoolExecutor | None = None
_executor_lock = threading.Lock()  # guards _executor: see _submit
_loaded: set[tuple[int, str]] = set()
MIN_THREAD_ELEMENTS = 1 << 15  # below this many elements per thread a launch stays on one thread
#: Elements per thread of a chunked kernel on the CPU. Warp copies a kernel's arguments (structs of arrays,
#: often ~1 kB) for every thread, so on the CPU each thread runs a chunk of elements; on CUDA every element
#: is its own thread.
CPU_CHUNK = 64
#: The chunk of the stepped grid passes (quantize, count, emit) on the CPU, in CPU_CHUNKs: Warp copies emit_grid's
#: ~1 kB of arguments for each of its threads, whose nodes go fast (native runs), so they take 256 nodes a thread
#: (2048², 20 steps: whole calls about 2 ms of 78 faster, RESULTS.md "Session 49").
GRID_CHUNK_FACTOR = 4
#: Warp launches CPU kernels with this block_dim (its default there); the module variant to pre-load.
CPU_LAUNCH_BLOCK_DIM = 1
_initialised = False
_NP_DTYPES = {
    wp.float32: np.float32,
    wp.float64: np.float64,
    wp.int32: np.int32,
    wp.int64: np.int64,
    wp.uint8: np.uint8,
    wp.int8: np.int8,
    wp.uint32: np.uint32,
    wp.int16: np.int16,
}


def quiet_warp() -> None:
    """Silence Warp's start-up and module-load lines (``log_level`` in Warp >= 1.12, ``quiet`` before)."""
    if hasattr(wp, "LOG_ERROR") and hasattr(wp.config, "log_level"):
        wp.config.log_level = wp.LOG_ERROR
    else:  # pragma: no cover - older Warp
        wp.config.quiet = True


def init_warp() -> None:
    """Initialise Warp once, quietly unless STEPTERRAIN_VERBOSE is set."""
    global _initialised
    if _initialised:
        return
    with _init_lock:
        if not _initialised:
            if os.environ.get("STEPTERRAIN_VERBOSE"):
                wp.init()
            else:
                quiet_warp()
                _init_filtering_stderr()
            _initialised = True


def _init_filtering_stderr() -> None:
    """``wp.init()`` with the native "CUDA driver not found" line dropped on machines without a GPU.

    Warp's native library writes it straight to file descriptor 2, past Python's logging and
    ``wp.config.log_level``; every other line it writes is passed through unchanged, also when ``wp.init()``
    raises (its native error lines explain the exception). Without a stderr to filter (``sys.stderr`` None, as
    under pythonw or a service; no file descriptor 2) or a temporary file to capture into (no writable temporary
    folder), ``wp.init()`` runs unfiltered: ``sys.stderr.flush()`` on None raised AttributeError, and a failed
    TemporaryFile its OSError, from every stepterrain call that needs a device.
    """
    stderr = sys.stderr
    try:
        if stderr is None:
            raise ValueError("no sys.stderr")
        stderr.flush()
        capture = tempfile.TemporaryFile(mode="w+b")
    except (OSError, ValueError, AttributeError):  # nothing to filter, or nowhere to capture it
        wp.init()
        return
    with capture:
        try:
            saved = os.dup(2)
        except OSError:  # no file descriptor 2 (embedded interpreters)
            wp.init()
            return
        os.dup2(capture.fileno(), 2)
        try:
            wp.init()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            kept = [
                line
                for line in capture.read().decode(errors="replace").splitlines(keepends=True)
                if "NVIDIA CUDA driver" not in line
            ]
            if kept:
                stderr.write("".join(kept))


def resolve_device(device: wp.DeviceLike = None, *arrays: Any) -> wp.Device:
    """Return the Warp device to run on.

    An input that already is a ``wp.array`` decides (device follows data); otherwise ``device`` is used,
    and ``None`` means Warp's default device (``cuda:0`` where CUDA is present, else ``cpu``).

    Raises
    ------
    DeviceError
        The device name is unknown or not present, or the inputs live on different devices.
    """
    init_warp()
    if not arrays and type(device) is wp.Device:  # a device Warp made (the common call): what wp.get_device returns
        return device
    data_devices = {str(a.device) for a in arrays if isinstance(a, wp.array)}
    if len(data_devices) > 1:
        raise DeviceError(f"inputs live on different devices: {sorted(data_devices)}; move them to one device")
    if data_devices:
        name = data_devices.pop()
        if device is not None and str(resolve_device(device)) != name:  # a bad name named as below, not Warp's error
            raise DeviceError(f"device={device!r} but the input arrays live on {name!r}")
        return wp.get_device(name)
    if str(device).startswith("cuda") and not wp.is_cuda_available():
        # refused before wp.get_device, which asks the missing driver for a context and prints native errors
        raise DeviceError(f"device={device!r} needs a CUDA GPU, and Warp finds none on this machine "
                          f"(available: {', '.join(str(d) for d in wp.get_devices())})")
    try:
        return wp.get_device(device)
    except Exception as exc:  # warp raises ValueError/RuntimeError depending on version
        available = [str(d) for d in wp.get_devices()]
        raise DeviceError(f"device must be one of {available} (or None); got {device!r}") from exc


def to_device(array: Any, dtype: Any, device: wp.Device) -> wp.array:
    """Convert ``array`` to a contiguous ``wp.array`` of ``dtype`` on ``device`` (no copy when it already fits).

    Contiguous always: the kernels index with ``stepterrain.kernels.memory.load``, which ignores strides.
    """
    if isinstance(array, wp.array):
        if array.dtype == dtype and str(array.device) == str(device) and array.is_contiguous:
            return array
        array = array.numpy()
    scalar = getattr(dtype, "_wp_scalar_type_", dtype)
    np_dtype = _NP_DTYPES[scalar]
    host = np.ascontiguousarray(array, dtype=np_dtype)
    return wp.array(host, dtype=dtype, device=device, copy=not device.is_cpu)


def empty_shared(
    shape: tuple[int, ...], np_dtype: Any, wp_dtype: Any, device: wp.Device, *, streamed: bool = False
) -> tuple[np.ndarray | None, wp.array]:
    """Allocate an output that ends up in numpy.

    On the CPU the ``wp.array`` wraps the numpy buffer (kernels write straight into it, no copy); on CUDA
    the numpy half is ``None`` and the caller copies with ``.numpy()`` once the kernels are done. ``streamed``:
    a kernel writes it with streaming stores, so its pages are mapped first where they are new (see
    :func:`touch_pages`).
    """
    if device.is_cpu:
        host = recycled_empty(shape, np_dtype, touched=streamed)
        return host, wp.array(host, dtype=wp_dtype, device=device, copy=False)
    n = shape[0]
    return None, wp.empty(n, dtype=wp_dtype, device=device)


class _Loan:
    """The owner of a block lent by :class:`_RecyclingPool`: every numpy array on the block refers to it."""

    __slots__ = ("__array_interface__", "__weakref__")


class _RecyclingPool:
    """Large output arrays on memory that earlier outputs freed.

    glibc maps every block of 32 MB or more afresh and unmaps it when freed, so each large output costs a
    page fault per 4 kB page on its first write; on a VM that is 1-6 GB/s against 11-17 GB/s for memory
    already touched. Outputs handed to the caller (a stepped mesh's vertices and faces) are numpy arrays on
    blocks lent from here: an array's base is a :class:`_Loan`, and when the last array on it is gone the block
    returns to the pool for the next call of similar size. At most ``limit`` bytes wait unused (the oldest
    freed first); arrays below :data:`RECYCLE_MIN_BYTES` come from numpy as usual.
    """

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._free: list[np.ndarray] = []  # uint8 blocks, oldest returned first
        self._lent = 0  # bytes of blocks on loan
        self._lock = threading.RLock()  # a loan may die (and return) inside take(), on the same thread
        self._taking = False  # inside _take: a block returned then is appended, not trimmed (see _give_back)

    def empty(self, shape: tuple[int, ...], dtype: Any, touched: bool = False) -> np.ndarray:
        dtype = np.dtype(dtype)
        nbytes = math.prod(int(n) for n in shape) * dtype.itemsize
        if nbytes < RECYCLE_MIN_BYTES or self.limit <= 0:
            fresh = np.empty(shape, dtype=dtype)
            if touched:
                touch_pages(fresh)
            return fresh
        # No collection here: a dropped trimesh is a reference cycle that frees its arrays when the collector
        # runs (or stepped() frees it: mesh.reclaim_dropped), but collecting now would also move the meshes still in
        # use (one being saved) to the oldest generation, which only a full collection frees (a loop of 1024² tiles
        # then held 146 MB more per tile).
        block = self._take(nbytes)
        if block is None:  # room for a slightly larger call next time (pages never written cost nothing)
            block = np.empty(nbytes + nbytes // 8, dtype=np.uint8)
            if touched:  # a recycled block was written before: its pages are mapped
                touch_pages(block[:nbytes])
        loan = _Loan()
        loan.__array_interface__ = {
            "shape": tuple(int(n) for n in shape),
            "typestr": dtype.str,
            "data": (block.ctypes.data, False),
            "version": 3,
        }
        with self._lock:
            self._lent += block.nbytes
        weakref.finalize(loan, self._give_back, block).atexit = False
        return np.asarray(loan)

    def _take(self, nbytes: int) -> np.ndarray | None:
        with self._lock:
            self._taking = True
            try:
                fits = [k for k, b in enumerate(self._free) if nbytes <= b.nbytes <= 2 * nbytes + (1 << 20)]
                if not fits:
                    return None
                k = min(fits, key=lambda k: self._free[k].nbytes)
                return self._free.pop(k)
            finally:
                self._taking = False
                self._trim()

    def _give_back(self, block: np.ndarray) -> None:
        with self._lock:
            self._lent -= block.nbytes
            self._free.append(block)  # at the end: the indices _take may hold stay valid
            if not self._taking:  # a loan that died inside _take (a collection there, same thread): trimmed after
                self._trim()  # it, since trimming pops the front and _take's k then named the next block

    def _trim(self) -> None:
        total = self.free_bytes
        while self._free and total > self.limit:
            total -= self._free.pop(0).nbytes

    @property
    def free_bytes(self) -> int:
        with self._lock:
            return sum(b.nbytes for b in self._free)


#: Outputs of at least this many bytes come from :data:`OUTPUTS`.
RECYCLE_MIN_BYTES = 8 << 20
OUTPUTS = _RecyclingPool(1 << 30)


def get_output_pool_limit() -> int:
    """Bytes of freed large outputs kept for reuse (default 1 GiB; see :func:`set_output_pool_limit`)."""
    return OUTPUTS.limit


def set_output_pool_limit(nbytes: int) -> int:
    """Keep at most ``nbytes`` of freed large outputs for the next call to reuse; returns the previous limit.

    A stepped mesh's vertex and face arrays (from 8 MB) are lent from a pool: when the mesh is gone, its
    memory serves the next mesh of similar size instead of going back to the operating system, which saves
    the page faults of fresh memory (a 1024² batch tile is stepped and written in 10-13 % less time on a VM).
    A dropped trimesh is a reference cycle: the next ``stepped()`` call frees the meshes the last few calls returned
    once nothing refers to them (no weak reference either); any other is freed when Python's cyclic collector runs
    (``del mesh; gc.collect()``).
    The price is that up to ``nbytes`` stay with the process after the meshes are dropped; 0 keeps none (and frees
    what is kept now).

    Examples
    --------
    >>> import stepterrain as st
    >>> previous = st.set_output_pool_limit(0)
    >>> st.get_output_pool_limit()
    0
    >>> _ = st.set_output_pool_limit(previous)
    """
    if isinstance(nbytes, bool) or not isinstance(nbytes, (int, np.integer)) or nbytes < 0:
        raise InvalidInputError(f"nbytes must be a non-negative int of bytes (0 keeps none); got {nbytes!r}")
    with OUTPUTS._lock:
        previous, OUTPUTS.limit = OUTPUTS.limit, int(nbytes)
        OUTPUTS._trim()
    return previous


def recycled_empty(shape: tuple[int, ...], dtype: Any, *, touched: bool = False) -> np.ndarray:
    """``np.empty(shape, dtype)``, on memory a freed output left when it is large (see :class:`_RecyclingPool`);
    ``touched``: with its pages mapped (:func:`touch_pages`), for streaming stores."""
    return OUTPUTS.empty(shape, dtype, touched)


def to_numpy(host: np.ndarray | None, array: wp.array, shape: tuple[int, ...]) -> np.ndarray:
    """The numpy result of an :func:`empty_shared` pair."""
    if host is not None:
        return host
    return host_copy(array).reshape(shape)


_PAGE = 4096
#: Device-to-host copies of at least this many bytes fault their fresh destination in first (one thread per
#: :data:`PREFAULT_SPAN` bytes, at most 8). From 32 MB up glibc always maps fresh pages for an array; below,
#: freed memory comes back and ``.numpy()`` is as fast (measured on an H100 machine: 0.5-16 MB within 10 %
#: either way; 64 MB 13 ms against 47 ms; 314 MB 38 ms against 223 ms).
PREFAULT_BYTES = 32 << 20
PREFAULT_SPAN = 16 << 20


def host_copy(array: wp.array) -> np.ndarray:
    """``array`` as a numpy array the caller owns: a view on the CPU, a fresh copy from a CUDA device.

    A CUDA copy into fresh pageable memory lets the driver fault every destination page in its copy loop:
    1.4 GB/s on an H100 machine (314 MB of stepped faces in 223 ms). Faulting the pages in first from up to
    8 threads (the kernel zeroes them in parallel), then copying, took the same 314 MB in 47.5 ms there:
    touching takes 49.6 ms from 1 thread and 10.7 ms from 8, and the copy itself takes 21 ms.
    """
    if array.device.is_cpu or array.size * wp.types.type_size_in_bytes(array.dtype) < PREFAULT_BYTES:
        return array.numpy()
    return _copy_to_fresh_host(array)


def _copy_to_fresh_host(array: wp.array) -> np.ndarray:
    """The copy half of :func:`host_copy` (any device; the tests run it on CPU arrays)."""
    scalar = getattr(array.dtype, "_wp_scalar_type_", array.dtype)
    shape = (*array.shape, *getattr(array.dtype, "_shape_", ()))
    host = np.empty(shape, dtype=_NP_DTYPES[scalar])
    flat = host.reshape(-1).view(np.uint8)
    _prefault(flat, max(1, min(8, os.cpu_count() or 1, flat.size // PREFAULT_SPAN)))
    wp.copy(wp.array(host, dtype=array.dtype, shape=array.shape, device="cpu", copy=False), array)
    return host


def _prefault(flat: np.ndarray, workers: int = 1) -> None:
    """Touch one byte per page of ``flat`` (fresh memory), split over ``workers`` threads (numpy releases the
    GIL)."""
    if flat.size == 0:
        return
    if workers < 2:
        flat[::_PAGE] = 0
        return
    span = -(-flat.size // workers)
    span += (-span) % _PAGE  # page-aligned slices
    parts = [flat[start : start + span : _PAGE] for start in range(0, flat.size, span)]
    futures = _submit(len(parts) - 1, [(part.fill, 0) for part in parts[1:]])
    parts[0].fill(0)
    for future in futures:
        future.result()


def touch_pages(host: np.ndarray) -> None:
    """Write one byte per page of a fresh output buffer (its contents are undefined anyway) before a kernel
    streams into it.

    Streaming (non-temporal) stores into pages not yet mapped are slow on this project's VMs: 6.5 M vec3d
    streamed in 46-83 ms into fresh numpy memory and 8-10 ms into touched memory, against 24 ms with plain
    stores into fresh memory (session 23, Intel Xeon VM, `/work/scratch/nt2.py`). Touching first costs the page
    faults the plain stores would have taken. :class:`_RecyclingPool` touches only blocks new to it.
    """
    flat = host.reshape(-1).view(np.uint8)
    _prefault(flat)
    if flat.size:
        flat[-1] = 0  # the last page, where the buffer does not start on a page boundary


def scratch(name: str, n: int, dtype: Any, device: wp.Device, *, streamed: bool = False) -> wp.array:
    """A reusable work array of ``n`` elements (contents undefined), kept per thread, device and name.

    Large fresh allocations cost page faults on every call (the allocator hands them back to the OS when
    freed); counts, offsets and other intermediates of a pass reuse the same memory instead, growing it when
    a larger input comes. The array is valid until the next request of the same name on this thread.
    :func:`release_scratch` frees the pool. ``streamed``: a kernel writes it with streaming stores, so a new
    array's pages are mapped first (:func:`touch_pages`).
    """
    pool = getattr(_pools, "arrays", None)
    if pool is None:
        pool = _pools.arrays = {}
        _pools.views = {}
    key = (name, str(device))
    array = pool.get(key)
    if array is None or array.dtype != dtype or array.shape[0] < n:
        array = wp.empty(max(int(n * 1.125), 1), dtype=dtype, device=device)
        if streamed and device.is_cpu:
            touch_pages(array.numpy())
        pool[key] = array
    # the view of the last request, when it asked for as many elements of the same array: a re-step asks for the
    # same sizes again, and a wp.array slice costs a few microseconds (about ten per call of stepped())
    last = _pools.views.get(key)
    if last is not None and last[0] is array and last[1] == n:
        return last[2]
    view = array[:n]
    _pools.views[key] = (array, n, view)
    return view


_NO_ELEMENTS: dict[tuple[Any, str], wp.array] = {}


def no_elements(dtype: Any, device: wp.Device) -> wp.array:
    """A zero-length array of ``dtype`` on ``device``, made once: the argument of an output a kernel does not write
    (``wp.empty(0)`` costs about 3 microseconds a call)."""
    key = (dtype, str(device))
    array = _NO_ELEMENTS.get(key)
    if array is None:
        array = _NO_ELEMENTS[key] = wp.empty(0, dtype=dtype, device=device)
    return array


def release_scratch() -> None:
    """Free this thread's scratch arrays (see :func:`scratch`) and the kernel structs kept with them
    (:func:`thread_structs`)."""
    _pools.arrays = {}
    _pools.views = {}
    _pools.structs = _Structs()


@contextmanager
def scratch_aside() -> Iterator[None]:
    """Run a block with an empty scratch pool and kept structs of its own on this thread, the caller's put back after.

    For a caller's code run while this thread's scratch arrays hold a pass's results (:func:`scratch`: valid until
    the next request of the same name): a γ callable that itself steps a terrain (or drapes, or meshes a globe)
    requested the same names, and overwrote the points, step heights and sources the call that called it read after
    it returned (wrong vertices and colours, silently)."""
    names = ("arrays", "views", "structs")
    saved = {name: getattr(_pools, name, None) for name in names}
    release_scratch()
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                if hasattr(_pools, name):
                    delattr(_pools, name)
            else:
                setattr(_pools, name, value)


class _Structs(dict[Any, Any]):
    """A thread's kept kernel structs: a dict that a weak reference can name, so that a kept entry's weakref callback
    (e.g. forgetting a dropped terrain's struct) refers to its dict weakly. Through a strong reference the dict, the
    entry, its weakref and the callback formed a cycle: the struct and the scratch arrays it names (8.6 MiB of levels
    for a 1500 x 1500 grid) outlived :func:`release_scratch` and the thread's exit until the cyclic gc ran."""

    __slots__ = ("__weakref__",)


def thread_structs() -> dict[Any, Any]:
    """This thread's kernel argument structs kept between calls, by the caller's key (a struct refers to this thread's
    scratch arrays, so it is this thread's; :func:`release_scratch` drops them with the arrays). Weakly referable: a
    callback kept in it names it through ``weakref.ref`` (a strong reference would make a cycle that keeps it and
    its arrays past :func:`release_scratch` and the thread's exit, until the cyclic gc runs)."""
    structs = getattr(_pools, "structs", None)
    if structs is None:
        structs = _pools.structs = _Structs()
    return structs


def read_int32(array: wp.array, index: int) -> int:
    """``int(array[index])`` of an int32 array, synchronising with its device: on the CPU read in place (a slice and
    ``.numpy()`` cost about 6 microseconds there), on CUDA through a one-element copy."""
    if array.device.is_cpu and array.dtype == wp.int32 and array.ndim == 1 and array.is_contiguous:
        return ctypes.c_int32.from_address(array.ptr + 4 * index).value
    return int(array[index : index + 1].numpy()[0])


def zero_int32(array: wp.array, index: int) -> None:
    """``array[index] = 0`` of an int32 array, in place on the CPU (no slice, no memset launch)."""
    if array.device.is_cpu and array.dtype == wp.int32 and array.ndim == 1 and array.is_contiguous:
        ctypes.c_int32.from_address(array.ptr + 4 * index).value = 0
    else:
        array[index : index + 1].zero_()


def get_cpu_threads() -> int:
    """Threads a CPU pass is split over: :func:`set_cpu_threads`, else the cores this process may use."""
    if _cpu_threads is not None:
        return _cpu_threads
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _launch_threads() -> int:
    """CPU launches that may run at once: :func:`get_cpu_threads`, but one in Warp's debug mode, whose CPU kernels
    (Warp 1.19) share one static tile-storage pointer, so that two launches at once crash."""
    return 1 if wp.config.mode == "debug" else get_cpu_threads()


def set_cpu_threads(threads: int | None) -> int | None:
    """Split CPU passes over ``threads`` threads (``None``: every core this process may use); returns the old value.

    Warp's CPU backend runs a launch on one thread; stepterrain's kernels take a ``thread_offset`` so one pass
    can run as several launches on disjoint ranges at once (Warp releases the GIL while a kernel runs). The
    output does not depend on the thread count. The setting is the process's: calls in other threads split the passes
    they start after it this way, and a pass under way keeps its split (tests/test_threads.py changes it while eight
    threads step, mesh and texture).
    """
    global _cpu_threads
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1):
        raise InvalidInputError(f"threads must be a positive int or None; got {threads!r}")
    previous, _cpu_threads = _cpu_threads, None if threads is None else int(threads)  # a numpy int is an int too
    return previous


def _submit(count: int, calls: list[tuple[Any, ...]]) -> list[Future]:
    """Submit each ``(function, *arguments)`` of ``calls`` to the shared pool (grown to at least ``count`` threads)
    that split CPU passes and page touching run on, beside the calling thread; return their futures.

    Under a lock: two threads growing the pool at once each made an executor (one was lost with its threads), and
    a replaced executor was never shut down. A replaced one is shut down without waiting: its queued work still
    runs, then its threads exit; nothing is submitted to it after, since every submission takes the lock."""
    global _executor
    with _executor_lock:
        if _executor is None or _executor._max_workers < count:
            replaced, _executor = _executor, ThreadPoolExecutor(max_workers=count, thread_name_prefix="stepterrain")
            if replaced is not None:
                replaced.shutdown(wait=False)
        return [_executor.submit(*call) for call in calls]


def _launch_range(kernel: Any, dim: int, inputs: list, outputs: list, device: wp.Device, fence: bool) -> None:
    wp.launch(kernel, dim=dim, inputs=inputs, outputs=outputs, device=device)
    if fence:  # on the thread that ran the range: its streaming stores, ordered before anyone reads them
        wp.launch(memory_kernels.drain_streams, dim=1, device=device)


def _preload(kernel: Any, device: wp.Device) -> None:
    key = (id(kernel.module), str(device))
    if key not in _loaded:  # compile/load once before several threads use the module
        # the variant wp.launch runs on the CPU (block_dim 1); a bare load(device) would compile another one,
        # for the module's default block_dim, that no launch uses (a second full compile on a cold cache)
        kernel.module.load(device, CPU_LAUNCH_BLOCK_DIM)
        _loaded.add(key)


def launch(
    kernel: Any,
    dim: int,
    inputs: list,
    outputs: list,
    device: wp.Device,
    *,
    min_dim: int = MIN_THREAD_ELEMENTS,
    fence: bool = False,
) -> None:
    """``wp.launch`` of a stepterrain kernel (``thread_offset`` first) over ``dim`` threads.

    On CUDA: one launch. On the CPU: split into up to :func:`get_cpu_threads` contiguous ranges of at least
    ``min_dim`` threads that run at once, each range's results written by its own threads only
    (count -> scan -> emit keeps them disjoint). ``fence``: the kernel writes with streaming stores
    (``stepterrain.kernels.memory.stream``); on the CPU each thread fences after its range.
    """
    if dim <= 0:
        return
    fence = fence and device.is_cpu
    workers = 1 if not device.is_cpu else min(_launch_threads(), dim // min_dim)
    if workers <= 1:
        _launch_range(kernel, dim, [0, *inputs], outputs, device, fence)
        return
    _preload(kernel, device)
    if fence:
        _preload(memory_kernels.drain_streams, device)
    bounds = [dim * k // workers for k in range(workers + 1)]
    futures = _submit(workers - 1, [
        (_launch_range, kernel, bounds[k + 1] - bounds[k], [bounds[k], *inputs], outputs, device, fence)
        for k in range(1, workers)
    ])
    _launch_range(kernel, bounds[1], [0, *inputs], outputs, device, fence)
    for future in futures:
        future.result()


def launch_each(kernel: Any, tasks: list[tuple[list, list]], device: wp.Device) -> None:
    """One single-thread launch of ``kernel`` (``thread_offset`` first, dim 1) per ``(inputs, outputs)`` task.

    On the CPU the tasks run on up to :func:`get_cpu_threads` threads at once, each thread taking the next task
    when it is done with one (tasks of uneven length balance); what one task writes must not overlap what another
    reads or writes (tasks may share arrays, each writing its own part). On CUDA they are queued one after another.
    """
    workers = min(_launch_threads(), len(tasks)) if device.is_cpu else 1
    if workers <= 1:
        for inputs, outputs in tasks:
            _launch_range(kernel, 1, [0, *inputs], outputs, device, False)
        return
    _preload(kernel, device)
    queue = iter(tasks)  # a list iterator's next is atomic under the GIL

    def drain() -> None:
        for inputs, outputs in queue:
            _launch_range(kernel, 1, [0, *inputs], outputs, device, False)

    futures = _submit(workers - 1, [(drain,)] * (workers - 1))
    drain()
    for future in futures:
        future.result()


def _chunk(device: wp.Device, scale: int = 1) -> int:
    """Elements per thread of :func:`launch_chunked` on ``device``: ``scale`` CPU chunks on the CPU."""
    return CPU_CHUNK * scale if device.is_cpu else 1


def chunk_shift(device: wp.Device, scale: int = 1) -> int:
    """log2 of the chunk :func:`launch_chunked` gives each thread on ``device`` (``scale`` as there): the stepped
    grid passes find a slot's chunk by a shift (kernels/stepped.py, Offsets), so :data:`CPU_CHUNK` must be a power
    of two."""
    chunk = _chunk(device, scale)
    if chunk <= 0 or chunk & (chunk - 1):
        raise ValueError(f"stepterrain._device.CPU_CHUNK must be a power of two; got {CPU_CHUNK}")
    return chunk.bit_length() - 1


def chunked_threads(n: int, device: wp.Device, scale: int = 1) -> int:
    """Threads :func:`launch_chunked` runs over ``n`` elements (``scale`` as there): thread t has chunk t
    (per-thread outputs)."""
    return -(-n // _chunk(device, scale))


def launch_chunked(kernel: Any, n: int, inputs: list, outputs: list, device: wp.Device, *,
                   min_elements: int = MIN_THREAD_ELEMENTS, fence: bool = False, atomics: bool = False,
                   scale: int = 1) -> None:
    """:func:`launch` of a chunked kernel over ``n`` elements.

    A chunked kernel takes ``thread_offset, count, chunk`` first; thread t handles the elements
    [(t + thread_offset)·chunk, … + chunk) ∩ [0, count). chunk is :data:`CPU_CHUNK` on the CPU, 1 on CUDA. On the
    CPU a range gets at least ``min_elements`` elements: lower it for kernels that spend long on each element
    (a split costs a Python launch, about 0.1 ms), so that their mid-sized passes use every core too.
    ``atomics``: the kernel updates shared elements with Warp's atomics (``wp.atomic_add``, ``atomic_max``), which
    are atomic on CUDA but plain read-modify-writes on the CPU: there it runs as one range (ranges launched at
    once on several threads lost updates: counts too small, and the slots scanned from them written past their end).
    ``scale``: each thread takes ``scale`` CPU chunks (the stepped grid passes, :data:`GRID_CHUNK_FACTOR`); one
    element a thread on CUDA all the same.
    """
    chunk = _chunk(device, scale)
    if atomics and device.is_cpu:
        min_elements = max(min_elements, n + chunk)
    launch(kernel, chunked_threads(n, device, scale), [n, chunk, *inputs], outputs, device,
           min_dim=max(1, min_elements // chunk), fence=fence)

