"""The mesh-level helpers every capability shares.

``close_solid`` turns a stepped (or any height-function) surface into a watertight solid; ``exact_keys``
groups bit-identical rows (vertices sharing an xy); ``boundary_edges`` lists the edges used by one face only;
``track``/``reclaim_dropped`` free the meshes ``stepped`` returned once the caller drops them (a Trimesh is a
reference cycle of trimesh's own, which only the cyclic collector frees otherwise).
No Python loop over faces or vertices: the per-face work (the boundary, the fins, the base) runs in the Warp kernels
of ``kernels/solid.py`` (count -> scan -> emit, on the CPU or CUDA), the rest is vectorised numpy.

    vertices, faces, kept, added, source = close_solid(mesh.vertices, mesh.faces, terrace_mask, floor=0.0)
"""

from __future__ import annotations

import gc
import itertools
import sys
import threading
import types
import warnings
import weakref
from typing import Any

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._compaction import MAX_INT32
from ._device import (
    chunked_threads,
    empty_shared,
    init_warp,
    launch_chunked,
    read_int32,
    resolve_device,
    to_device,
    to_numpy,
)
from .errors import InvalidInputError, OutputTooLargeError, caller_stacklevel, counted
from .kernels import solid as kernels
from .terrain import FLOAT32_MAX, finite_number, real_numbers

__all__ = ["close_solid", "boundary_edges", "exact_keys", "mesh_argument", "check_face_indices"]


def mesh_argument(mesh: Any, name: str = "mesh", hint: str = "") -> trimesh.Trimesh:
    """``mesh`` as a ``trimesh.Trimesh``: itself, or a ``pyvista.PolyData`` of triangles (``grid.stepterrain.stepped``'s
    result) converted by :func:`stepterrain.pyvista_accessor.from_polydata` (colours, level/wall, metadata kept);
    else an InvalidInputError naming ``name`` (``hint`` added to it). pyvista is imported only for its own objects.
    """
    if isinstance(mesh, trimesh.Trimesh):
        return mesh
    if type(mesh).__module__.split(".")[0] == "pyvista":  # imported already: the object is pyvista's
        import pyvista as pv

        if isinstance(mesh, pv.PolyData):
            from .pyvista_accessor import from_polydata

            return from_polydata(mesh, name)
        # a grid (ImageData, ...): its surface, or its steps, is a PolyData; only the accessor's grids have steps (a
        # MultiBlock, pv.read's of a GLB, or an UnstructuredGrid was told of a .stepterrain it does not have)
        steps = (f", or its steps, {name}.stepterrain.stepped(...)"
                 if isinstance(mesh, (pv.ImageData, pv.RectilinearGrid, pv.StructuredGrid)) else "")
        hint = (f" (a pyvista.{type(mesh).__name__}: pass its surface, {name}.extract_surface().triangulate()"
                f"{steps}){hint}")
    raise InvalidInputError(f"{name} must be a trimesh.Trimesh or a pyvista.PolyData of triangles{hint}; got "
                            f"{type(mesh).__name__}")


def face_outside(faces: NDArray[Any], vertex_count: int) -> int | None:
    """The first of ``faces`` (F, 3) with an index outside the ``vertex_count`` vertices, else None."""
    if len(faces) == 0:
        return None
    if faces.dtype == np.int64 and faces.flags.c_contiguous:
        # one reduction instead of min and max: as uint64 a negative index is >= 2**63, beyond any vertex count
        if int(faces.view(np.uint64).max()) < vertex_count:
            return None
    elif faces.min() >= 0 and faces.max() < vertex_count:
        return None
    return int(np.flatnonzero(((faces < 0) | (faces >= vertex_count)).any(axis=1))[0])


def check_face_indices(faces: ArrayLike, vertex_count: int, name: str, noun: str = "vertex",
                       plural: str = "vertices") -> None:
    """Refuse ``faces`` (F, 3) that are no whole numbers or that index outside the ``vertex_count`` vertices (named
    ``noun``, ``plural``) with an InvalidInputError naming ``name``, the range and the first such face: a
    ``process=False`` Trimesh (or a PolyData) keeps them, and VTK read them from outside its point buffer (garbage
    triangles, or a crash), writers put them in the file as they were. The one check of save_mesh, render and the
    pyvista accessor (each had its own, with a message of its own)."""
    indices = np.asarray(faces)
    if indices.size and indices.dtype.kind not in "iu":
        raise InvalidInputError(f"{name} must hold whole-number indices of its {plural}; got dtype {indices.dtype}")
    bad = face_outside(indices.reshape(-1, 3), vertex_count)
    if bad is None:
        return
    within = (f"its {counted(vertex_count, noun, plural)} (0 .. {vertex_count - 1})" if vertex_count
              else f"{plural}, and it has none")
    raise InvalidInputError(f"{name} must index {within}; face {bad} is {indices.reshape(-1, 3)[bad].tolist()}")


def release(mesh: trimesh.Trimesh) -> None:
    """Empty ``mesh``, a Trimesh the library made for itself and is done with, so that reference counting frees it.

    A Trimesh refers to itself (its visuals, ``ray``, ``permutate`` and ``nearest`` hold it), so a dropped one waits
    for Python's cyclic collector, and with it the arrays it holds: a stepped mesh's large arrays are lent from the
    output pool (:func:`~stepterrain.set_output_pool_limit`), and until they return every call takes fresh memory. An
    array another object still shares (a PolyData's points) stays alive through that object alone."""
    mesh.__dict__.clear()


#: Weak references to the latest meshes the library returned (:func:`track`), newest last.
_RECENT: list[_Ref] = []
#: How many :data:`_RECENT` keeps: a loop ``mesh = stepped(...)`` still holds the previous mesh while the next call
#: runs, so the one before it is the first it has dropped.
RECENT_MAX = 4
#: The most objects :func:`_component` visits from a mesh before it gives up (a user's metadata may be big).
COMPONENT_MAX = 20_000
_RECENT_LOCK = threading.Lock()
#: ``Py_TPFLAGS_HEAPTYPE``: a class made by a ``class`` statement, whose ``__dict__`` slot is the interpreter's own.
_HEAP_TYPE = 1 << 9
#: Not followed when looking for a mesh's own cycle: shared by everything, never part of one mesh's cycle.
_SHARED = (type, types.ModuleType, types.FunctionType, types.BuiltinFunctionType, types.CodeType)


class _Ref(weakref.ref):
    """The library's own weak reference to a mesh it returned. A subclass: CPython hands every caller of
    ``weakref.ref(obj)`` (no callback) one shared object, so with a plain ref a user's would be ours and
    ``weakref.getweakrefcount`` could not tell that the user keeps one (:func:`_dropped_component`)."""

    __slots__ = ()


class _Probe:
    """A fresh object, held as each member is: its reference count calibrates :func:`_dropped_component`."""


def track(mesh: trimesh.Trimesh) -> None:
    """Remember ``mesh``, a Trimesh about to be returned to the caller, for :func:`reclaim_dropped` (weakly)."""
    with _RECENT_LOCK:
        _RECENT.append(_Ref(mesh))
        del _RECENT[:-RECENT_MAX]


def reclaim_dropped() -> None:
    """Free now the meshes :func:`track` remembered that the caller has dropped, instead of when the cyclic collector
    runs: their large arrays then serve this call (the output pool, :func:`~stepterrain.set_output_pool_limit`).

    A ``trimesh.Trimesh`` refers to itself from ``__init__`` on: its ``visual``, ``ray`` (and the ``ray``'s cache's
    ``id_function``, the mesh's bound ``__hash__``), ``permutate`` and ``nearest`` hold it, so a mesh the caller drops
    is a reference cycle, and its vertices, faces and attributes wait for a collection (a re-stepping loop that never
    calls ``gc.collect()`` took fresh memory, with its page faults, every call). A mesh is freed here only when
    nothing outside its cycle refers to it or to any object of the cycle (:func:`_dropped_component`), the test the
    cyclic collector makes, and when no one could see the difference from a collection: no weak reference but the
    library's own names an object of the cycle (the collector clears those first) and none has a finalizer
    (``__del__``, a generator: the collector runs those on the whole cycle first). Such a mesh nobody can reach any
    more, and emptying it (what the collector does) is seen by no one. A mesh still held, or one whose ``visual`` or
    ``ray`` is, stays as it is; so does every mesh on a free-threaded Python (no GIL: the check could not be made at
    one instant)."""
    if not getattr(sys, "_is_gil_enabled", lambda: True)():
        return
    with _RECENT_LOCK:
        refs = list(_RECENT)
    done = {id(ref) for ref in refs if _reclaim(ref)}
    if done:
        with _RECENT_LOCK:
            _RECENT[:] = [ref for ref in _RECENT if id(ref) not in done]


def _reclaim(ref: _Ref) -> bool:
    """Empty the mesh ``ref`` refers to if its cycle is unreachable (:func:`_dropped_component`); True when the mesh
    is gone (freed now, or before)."""
    members = _dropped_component(ref)
    if members is None:
        return ref() is None
    for member in members:  # what the collector's tp_clear does: every reference out of the cycle goes
        own = _own_dict(member)
        if own is not None:
            own.clear()
    return True


def _own_dict(obj: Any) -> dict | None:
    """``obj``'s own instance dictionary, read through the interpreter's ``__dict__`` slot of its type; None for an
    object without one. Not ``obj.__dict__``: a bound method, a weak proxy (or a class's ``__dict__`` property)
    answer with another object's, one a caller may keep, and no code of ``obj``'s runs here."""
    for klass in type(obj).__mro__:
        slot = vars(klass).get("__dict__")
        if slot is not None:
            generic = isinstance(slot, types.GetSetDescriptorType) and klass.__flags__ & _HEAP_TYPE  # a class's
            own = slot.__get__(obj) if generic else None
            return own if type(own) is dict else None
    return None


def _dropped_component(ref: _Ref) -> list[Any] | None:
    """The objects of the reference cycle through the mesh ``ref`` refers to (its strongly connected component among
    the objects the collector tracks), if nothing outside them refers to any of them; None otherwise (the mesh is
    gone, still reachable, weakly referred to by someone else, in a cycle with a finalizer, or more than
    :data:`COMPONENT_MAX` objects away from its own).

    The collector's test on a subset: an object's reference count minus the references from the other members is
    what refers to it from outside, so all zero means no one outside can reach the members. Only references this
    function itself holds are discounted, measured on a :class:`_Probe` held exactly as every member is (so the count
    does not depend on how the interpreter counts its own stack); a reference this misses (an extension's object
    that does not report it) only makes a mesh look held, never dropped.

    The references between the members and every count are taken at one instant, in one call that runs no Python
    code (``list`` over ``map``/``starmap`` of C functions: the GIL is not given up, and a collection, with the
    finalizers it runs, can start only at the allocation before the walk, so no other thread, signal handler or
    finalizer runs in between; CPython with a GIL): counted one by one, a holder that another thread
    moves from one member to the next (``v = mesh.visual; del mesh``) could be missed at every count. Were the graph
    walked by :func:`_component` stale by then, the check still holds for the members it names: none of them is
    referred to from outside at that instant, so none can be reached after it."""
    members = _component(ref)
    if members is None:
        return None
    held = (*members, _Probe())
    del members
    # one instant: the referents first (the only allocation that may start a collection happens before the walk),
    # then the counts; the flat list of referents adds one reference per entry, hence the 2 * inside below
    snapshot = list(itertools.chain(itertools.starmap(gc.get_referents, (held,)),
                                    map(sys.getrefcount, held), map(weakref.getweakrefcount, held)))
    referents, counts, weak = snapshot[0], snapshot[1:len(held) + 1], snapshot[len(held) + 1:]
    inside: dict[int, int] = {}
    for target in referents:
        inside[id(target)] = inside.get(id(target), 0) + 1
    del referents, snapshot
    ours = counts[-1]  # the probe: referred to by nothing but this function
    root = ref()
    for member, count, weakrefs in zip(held[:-1], counts[:-1], weak[:-1], strict=True):
        outside = count - ours - 2 * inside.get(id(member), 0)
        if outside or weakrefs != (member is root) or hasattr(type(member), "__del__"):
            return None
    return list(held[:-1])


def _component(ref: _Ref) -> list[Any] | None:
    """The strongly connected component of ``ref()`` among the objects the collector tracks (None when the mesh is
    gone or its graph too big)."""
    root = ref()
    if root is None:
        return None
    found: dict[int, Any] = {id(root): root}
    edges: dict[int, list[int]] = {}
    stack = [root]
    del root
    while stack:
        obj = stack.pop()
        out = edges[id(obj)] = []
        for child in gc.get_referents(obj):
            if gc.is_tracked(child) and not isinstance(child, _SHARED):
                out.append(id(child))
                if id(child) not in found:
                    found[id(child)] = child
                    stack.append(child)
        if len(found) > COMPONENT_MAX:
            return None
    into: dict[int, list[int]] = {}
    for source, targets in edges.items():
        for target in targets:
            into.setdefault(target, []).append(source)
    start = id(ref())
    back, stack_ids = {start}, [start]
    while stack_ids:
        for source in into.get(stack_ids.pop(), ()):
            if source not in back:
                back.add(source)
                stack_ids.append(source)
    return [found[key] for key in back]


def exact_keys(xy: NDArray[np.float64]) -> NDArray[np.int64]:
    """Group ids of rows that are bit-identical (e.g. vertices sharing an exact xy).

    Rows are compared bit for bit (0.0 and -0.0 differ), sorted by their columns' bit patterns with one
    ``lexsort``: ids number the distinct rows in that order."""
    rows = np.ascontiguousarray(xy)
    if len(rows) == 0:
        return np.zeros(0, np.int64)
    bits = rows.view(np.dtype(f"u{rows.dtype.itemsize}")).reshape(len(rows), -1)
    columns = [bits[:, k] for k in range(bits.shape[1])]
    order = np.lexsort(columns[::-1])
    new = np.zeros(len(rows), bool)  # where the sorted row changes: a gather per column, not of the whole rows
    new[0] = True
    for column in columns:
        ordered = column[order]
        new[1:] |= ordered[1:] != ordered[:-1]
        del ordered
    ids = np.empty(len(rows), np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids


def _device_of(device: wp.DeviceLike) -> wp.Device:
    """Where the kernels run: ``device`` (a DeviceError naming the devices there are otherwise), the CPU for None."""
    init_warp()
    return wp.get_device("cpu") if device is None else resolve_device(device)


def _empty(n: int, np_dtype: Any, dtype: Any, device: wp.Device, *, zero: bool = False) -> wp.array:
    """A work array of ``n`` elements: on the CPU a numpy buffer wrapped without a copy (so that tracemalloc, which
    tests/test_solid_budget.py measures the peak with, sees it), on CUDA Warp's. A vector ``dtype`` takes a numpy
    sub-array dtype, e.g. ``(np.int32, 4)`` for ``wp.vec4i``."""
    if device.is_cpu:
        host = np.zeros(n, np_dtype) if zero else np.empty(n, np_dtype)
        return wp.array(host, dtype=dtype, device=device, copy=False)
    return wp.zeros(n, dtype=dtype, device=device) if zero else wp.empty(n, dtype=dtype, device=device)


def _offsets(counts: wp.array) -> wp.array:
    """The exclusive prefix sum of ``counts`` (n + 1, the last 0)."""
    offsets = _empty(counts.shape[0], np.int32, wp.int32, counts.device)
    wp.utils.array_scan(counts, offsets, inclusive=False)
    return offsets


def _scan(counts: wp.array) -> tuple[wp.array, int]:
    """:func:`_offsets` of ``counts`` and their total (the pass's one host sync)."""
    offsets = _offsets(counts)
    return offsets, read_int32(offsets, counts.shape[0] - 1)


def _key_offsets(keys: wp.array, n: int, device: wp.Device) -> wp.array:
    """Where the bucket of each key of ``keys`` (ints in [0, n)) starts: the exclusive scan of the key counts
    (kernels/solid.py: count_keys). Their total is ``len(keys)``: no host sync."""
    counts = _empty(n + 1, np.int32, wp.int32, device, zero=True)
    launch_chunked(kernels.count_keys, keys.shape[0], [keys], [counts], device, atomics=True)
    return _offsets(counts)


def _buckets(keys: wp.array, n: int, device: wp.Device) -> tuple[wp.array, wp.array]:
    """The items of ``keys`` (ints in [0, n)) grouped by key, without a sort (kernels/solid.py: count_keys,
    fill_buckets): the bucket of key k is ``items[offsets[k]:offsets[k + 1]]``, in no particular order."""
    offsets = _key_offsets(keys, n, device)
    cursor = _empty(n, np.int32, wp.int32, device, zero=True)
    items = _empty(keys.shape[0], np.int32, wp.int32, device)
    launch_chunked(kernels.fill_buckets, keys.shape[0], [keys, offsets], [cursor, items], device, atomics=True)
    return offsets, items


#: Buckets (the wall pairs of one smallest vertex, the vertices of one pair group) of more than this many items are
#: searched through a hash of the items' whole key instead (kernels/solid.py: hash_fin_keys, hash_column_keys): a
#: scan of its bucket per item is quadratic in it. A stepped surface's buckets hold one or two; a fan of walls on one
#: vertex (a direct call) as many as it has walls.
LARGE_BUCKET = 32


def _check_face_count(faces: NDArray[np.int64]) -> None:
    """An OutputTooLargeError where the kernels cannot index ``faces``' 3 corners a face with int32."""
    if 3 * len(faces) > MAX_INT32:
        raise OutputTooLargeError(f"faces: the kernels index at most {MAX_INT32 // 3:,} faces with int32; got "
                                  f"{len(faces):,}")


def _flat_faces(faces: NDArray[np.int64], device: wp.Device) -> wp.array:
    """``faces`` as the kernels read them: a flat int32 array on ``device``."""
    _check_face_count(faces)
    return to_device(faces.reshape(-1), wp.int32, device)


def _narrow_faces(faces: NDArray[np.int64], device: wp.Device) -> tuple[wp.array, int, int]:
    """:func:`_flat_faces` of int64 ``faces`` and their smallest and largest index, in one pass
    (kernels/solid.py: narrow_faces); (0, 0) where there is no face."""
    _check_face_count(faces)
    count = 3 * len(faces)
    flat = _empty(count, np.int32, wp.int32, device)
    if count == 0:
        return flat, 0, 0
    threads = chunked_threads(count, device)
    low = _empty(threads, np.int64, wp.int64, device)
    high = _empty(threads, np.int64, wp.int64, device)
    launch_chunked(kernels.narrow_faces, count, [to_device(faces.reshape(-1), wp.int64, device)], [flat, low, high],
                   device)
    return flat, int(low.numpy().min()), int(high.numpy().max())


def _boundary(faces: wp.array, n: int, device: wp.Device) -> NDArray[np.int64]:
    """The boundary edges of the flat int32 ``faces`` (indices in [0, n)), as :func:`boundary_edges` gives them."""
    count = faces.shape[0] // 3
    if count == 0:
        return np.zeros((0, 2), np.int64)
    # the scan of the corner counts with one spare key (n + 2 entries, the last two 0): each bucket's end one place
    # on, which fill_corners counts down to its start (kernels/solid.py: then vertex v's corners are
    # corners[ends[v + 1]:ends[v + 2]])
    ends = _key_offsets(faces, n + 1, device)
    corners = _empty(faces.shape[0], (np.int32, 2), wp.vec2i, device)
    launch_chunked(kernels.fill_corners, count, [faces], [ends, corners], device, atomics=True)
    threads = chunked_threads(count, device)
    counts = _empty(threads + 1, np.int32, wp.int32, device, zero=True)
    flags = _empty(count, np.int32, wp.int32, device)
    launch_chunked(kernels.count_boundary, count, [faces, ends, corners], [flags, counts], device)
    del ends, corners
    starts, total = _scan(counts)
    if 2 * total > MAX_INT32:  # emit_boundary writes edge o at 2·o in int32
        raise OutputTooLargeError(f"faces: the kernels index at most {MAX_INT32 // 2:,} boundary edges with int32; got "
                                  f"{total:,}")
    edges = _empty(2 * total, np.int64, wp.int64, device)
    launch_chunked(kernels.emit_boundary, count, [faces, flags, starts], [edges], device)
    return edges.numpy().reshape(total, 2)


def _face_indices(faces: Any, n_vertices: int | None = None) -> NDArray[np.int64]:
    """``faces`` as an (F, 3) int64 array, else an :class:`InvalidInputError`: integers as they are, floats where
    each is a whole number (faces read back from a text file, as before), other floats (1.5 was truncated to another
    vertex without a word, NaN named as index -2^63) and bools refused. An empty list (numpy's float64) is no faces.
    An index beyond int64 (uint64, a float) is named as given: an InvalidInputError naming the ``n_vertices`` where
    they are known (close_solid's), else the kernels' OutputTooLargeError (boundary_edges')."""
    array = np.asarray(faces)
    if array.size and array.dtype.kind == "f":
        whole = np.isfinite(array) & (array == np.trunc(array))
        if not whole.all():
            at = tuple(int(k) for k in np.argwhere(~whole)[0])
            raise InvalidInputError(f"faces must hold whole vertex indices; got {float(array[at])} at {at}")
    elif array.size and array.dtype.kind not in "iu":  # bools, text, objects
        raise InvalidInputError(f"faces must be an (F, 3) integer array of vertex indices; got dtype {array.dtype}")
    if array.size and array.dtype.kind == "f" and array.min() < 0:  # -1e20: the cast to int64 named -2^63
        at = tuple(int(k) for k in np.unravel_index(int(np.argmin(array)), array.shape))
        raise InvalidInputError(f"faces must hold vertex indices >= 0; got {float(array[at])} at {at}")
    if array.size and array.dtype.kind in "fu" and array.max() >= 2.0**63:  # int64's cast wrapped them round to
        at = tuple(int(k) for k in np.unravel_index(int(np.argmax(array)), array.shape))  # -2^63, named as such
        if n_vertices is not None:
            raise InvalidInputError(f"faces must index the {counted(n_vertices, 'vertex', 'vertices')} "
                                    f"(0 .. {n_vertices - 1}); got {array[at]} at {at}")
        raise OutputTooLargeError(f"faces: the kernels index vertices up to {MAX_INT32 - 3:,} with int32; got "
                                  f"{array[at]} at {at}")
    if array.size == 0 and array.ndim == 1:  # an empty list: no faces, as the docstring says (not shape (0,))
        array = array.reshape(0, 3)
    array = array.astype(np.int64, copy=False)
    if array.ndim != 2 or array.shape[1] != 3:  # the kernels read the faces as flat rows of three
        raise InvalidInputError(f"faces must be an (F, 3) array of vertex indices; got shape {array.shape}")
    return array


def boundary_edges(faces: NDArray[np.int64], device: wp.DeviceLike = None) -> NDArray[np.int64]:
    """Directed edges (a, b), as wound in their face, that no other face uses: (B, 2), in face order.

    An edge is on the boundary when exactly one half-edge of the mesh has its undirected key; the kernels count
    those among the corners at one of its ends (kernels/solid.py: a vertex -> corner table built without a sort,
    then count -> scan -> emit over the faces; faces whose largest index is over 3 per face, as a few faces of a large
    mesh, number the vertices they use first, with np.unique's sort). ``device``: where the kernels run (the CPU by
    default)."""
    faces = _face_indices(faces)
    device = _device_of(device)  # before the empty answer: a misspelt device passed with no faces, to fail later
    if len(faces) == 0:
        return np.zeros((0, 2), np.int64)
    if faces.min() < 0:
        raise InvalidInputError(f"faces must hold vertex indices >= 0; got {int(faces.min())}")
    if faces.max() > MAX_INT32 - 3:  # _boundary's corner table has n + 2 = largest index + 3 entries, an int32 shape
        raise OutputTooLargeError(f"faces: the kernels index vertices up to {MAX_INT32 - 3:,} with int32; got "
                                  f"{int(faces.max()):,}")
    n = int(faces.max()) + 1
    if n > 3 * len(faces):  # sparse indices: the corner table by the largest index would be mostly empty (one face
        # [0, 1, 2**30] took 4 GiB), so it is by the vertices used, numbered in order (the same edges, in face order)
        used, compact = np.unique(faces, return_inverse=True)
        return used[_boundary(_flat_faces(compact.reshape(faces.shape), device), len(used), device)]
    return _boundary(_flat_faces(faces, device), n, device)


def _fins(faces: wp.array, walls: NDArray[np.int64], n: int, device: wp.Device) -> NDArray[np.bool_]:
    """Per wall pair (``walls``' faces in consecutive pairs), whether another pair stands on the same four vertices
    (kernels/solid.py: wall_quads, a table of the pairs by their smallest vertex, find_fins)."""
    first = to_device(walls[0::2], wp.int32, device)
    second = to_device(walls[1::2], wp.int32, device)
    count = first.shape[0]
    quads = _empty(count, (np.int32, 4), wp.vec4i, device)
    keys = _empty(count, np.int32, wp.int32, device)
    launch_chunked(kernels.wall_quads, count, [faces, first, second], [quads, keys], device)
    offsets, pairs = _buckets(keys, n, device)
    fins = _empty(count, np.uint8, wp.uint8, device)
    deferred = _empty(1, np.int32, wp.int32, device, zero=True)
    launch_chunked(kernels.find_fins, count, [quads, offsets, pairs, LARGE_BUCKET], [fins, deferred], device)
    del offsets, pairs
    if read_int32(deferred, 0):  # a vertex in more than LARGE_BUCKET quads: those pairs by a hash of the whole quad
        launch_chunked(kernels.hash_fin_keys, count, [quads, fins], [keys], device)
        offsets, pairs = _buckets(keys, 2 * count, device)
        launch_chunked(kernels.find_fins_hashed, count, [quads, keys, offsets, pairs], [fins], device)
    return fins.numpy().view(np.bool_)


def _pairs(faces: wp.array, terrace_mask: NDArray[np.bool_], n: int, device: wp.Device) -> wp.array:
    """Per vertex, the lower index of the wall bottom and top it pairs with through a vertical wall edge (itself when
    no wall's side joins it to another vertex), int32 on ``device``. Walls come as consecutive pairs (u_top, v_top,
    v_bottom), (u_top, v_bottom, u_bottom): their vertical edges are (v_top, v_bottom) and (u_top, u_bottom); a vertex
    lies on one such edge at most (a crossing's bottom or top, a node over its twin). Should one lie on several
    (any other mesh), the last in the order tops of the first faces, of the second faces, then bottoms likewise wins
    (kernels/solid.py: last_wall_writes, wall_pairs)."""
    walls = np.flatnonzero(~terrace_mask)
    if len(walls) == 0 or len(walls) % 2:
        walls = walls[:0]
    first = to_device(walls[0::2], wp.int32, device)
    second = to_device(walls[1::2], wp.int32, device)
    count = first.shape[0]
    winner = _empty(n, np.int32, wp.int32, device)
    winner.fill_(-1)
    launch_chunked(kernels.last_wall_writes, count, [faces, first, second], [winner], device, atomics=True)
    pair = _empty(n, np.int32, wp.int32, device)
    launch_chunked(kernels.wall_pairs, n, [faces, first, second, winner, count], [pair], device)
    return pair


def _columns(vertices: NDArray[np.float64], fan: NDArray[np.float64] | None, pair: wp.array,
             device: wp.Device) -> tuple[NDArray[np.int64], wp.array, int]:
    """Per vertex its column, in int64 on the host and int32 on ``device``, and the number of columns: the vertices
    with the same (x, y, [fan], pair) compared bit for bit share one. No sort: the pair groups as buckets (a column
    lies in one), the smallest vertex of each column found in its bucket (kernels/solid.py: column_leaders), and the
    columns numbered in the order of their smallest vertex (a scan of the leaders, number_columns)."""
    n = len(vertices)
    if n == 0:
        return np.zeros(0, np.int64), _empty(0, np.int32, wp.int32, device), 0
    offsets, members = _buckets(pair, n, device)
    bits = to_device(np.ascontiguousarray(vertices).view(np.int64).reshape(-1), wp.int64, device)
    fans = to_device(fan.view(np.int64) if fan is not None else np.zeros(0, np.int64), wp.int64, device)
    leader = _empty(n, np.int32, wp.int32, device)
    starts = _empty(n, np.int32, wp.int32, device)
    deferred = _empty(1, np.int32, wp.int32, device, zero=True)
    launch_chunked(kernels.column_leaders, n, [bits, fans, pair, offsets, members, LARGE_BUCKET],
                   [leader, starts, deferred], device)
    del offsets, members
    if read_int32(deferred, 0):  # a pair group of more than LARGE_BUCKET vertices: those by a hash of their key
        keys = _empty(n, np.int32, wp.int32, device)
        launch_chunked(kernels.hash_column_keys, n, [bits, fans, pair, leader], [keys], device)
        offsets, members = _buckets(keys, 2 * n, device)
        rep = _empty(n, np.int32, wp.int32, device)
        low = _empty(n, np.int32, wp.int32, device)
        low.fill_(n)
        launch_chunked(kernels.column_reps, n, [bits, fans, pair, leader, keys, offsets, members], [rep, low], device,
                       atomics=True)
        del keys, offsets, members
        launch_chunked(kernels.deferred_leaders, n, [rep, low], [leader, starts], device)
        del rep, low
    del bits, fans
    wp.utils.array_scan(starts, starts, inclusive=True)
    ids = _empty(n, np.int64, wp.int64, device)
    ids32 = _empty(n, np.int32, wp.int32, device)
    launch_chunked(kernels.number_columns, n, [leader, starts], [ids, ids32], device)
    return ids.numpy(), ids32, read_int32(starts, n - 1)  # the leaders' count


def _projected_area(vertices: NDArray[np.float64], edges: NDArray[np.int64]) -> float:
    """Twice the signed area of the surface's projection on the xy plane, from its boundary ``edges`` (Green's
    theorem, the shoelace sum of (a - o) × (b - o) over each boundary edge (a, b), o its first vertex): the faces'
    (b - a) × (c - a) summed, where the surface is wound consistently (each interior edge's two half-edges cancel),
    in O(boundary) where the faces' sum took 0.1-0.4 s at 3 M faces. Positive where the surface is wound
    counter-clockwise seen from +z (normals up, as the step kernels emit it), negative where clockwise; 0 without a
    boundary. A vertical edge (a wall's side) adds exactly 0."""
    if len(edges) == 0:
        return 0.0
    o = vertices[edges[0, 0], :2]
    a = vertices[edges[:, 0], :2] - o
    b = vertices[edges[:, 1], :2] - o
    return float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))


def _rounding_scale(x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[float, float]:
    """The scale and floor of :func:`_face_areas`' margins for a surface of coordinates ``x``, ``y``: 2^-20 times
    its xy extent, or a float32 step u of its largest |x|, |y| where every x and y is a float32 value, whichever is
    larger, and 2 u^2 (0 in float64)."""
    scale = 2.0**-20 * (max(float(np.ptp(x)), float(np.ptp(y))) if len(x) else 0.0)
    step32 = 0.0  # a float32 step of the largest |x|, |y| where the positions are float32 values, else 0
    if len(x) and np.array_equal(x.astype(np.float32), x) and np.array_equal(y.astype(np.float32), y):
        step32 = float(np.spacing(np.float32(max(float(np.abs(x).max()), float(np.abs(y).max())))))
    return max(scale, step32), 2.0 * step32 * step32


def _rounding_frame(vertices: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], float, float]:
    """The x and y columns of ``vertices`` gathered contiguous (0.05 s per million faces, not 0.2 s, for the gathers
    by face that follow) and their :func:`_rounding_scale`: what :func:`_face_areas` and :func:`_overlaps` share."""
    x = np.ascontiguousarray(vertices[:, 0])
    y = np.ascontiguousarray(vertices[:, 1])
    return x, y, *_rounding_scale(x, y)


#: Faces :func:`_face_areas` gathers the corners of at once: a dozen temporaries of a block, not of the whole mesh
#: (2.6 GB at 30 M faces). (:func:`_overlaps` gathers by blocks of 4 :data:`OVERLAP_BLOCK` faces.)
AREA_BLOCK = 1 << 20


def _block_areas(bx: NDArray[np.float64], by: NDArray[np.float64], cx: NDArray[np.float64],
                 cy: NDArray[np.float64], scale: float, floor32: float, area: NDArray[np.float64],
                 margin: NDArray[np.float64]) -> None:
    """:func:`_face_areas` of a block of faces from their edges b - a, c - a (``bx``, ``by``, ``cx``, ``cy``), written
    into ``area`` and ``margin``."""
    np.multiply(bx, cy, out=area)
    area -= by * cx
    np.abs(bx, out=margin)
    margin += np.abs(by)
    margin += np.abs(cx)
    margin += np.abs(cy)
    margin *= scale
    margin += floor32


def _face_areas(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> tuple[NDArray[np.float64],
                                                                                 NDArray[np.float64]]:
    """Per face twice its signed projected area on the xy plane, (b - a) × (c - a) (positive: counter-clockwise
    seen from +z, facing up), and the margin within which its sign is rounding's: 2^-20 times the surface's xy
    extent times the face's two edges from a (|Δx| + |Δy|), the change of the area by moves of the corners of a few
    float32 steps of the extent (an .stl or a .glb stores float32 positions: a face within it has no orientation
    there, e.g. a sliver a stepped surface's float32 crossings turned over). Where every x and y is a float32 value
    (the surface came through float32), at least the change by moves of half a float32 step of the largest |x|, |y|
    (u) each: u times the two edges plus 2 u^2; float32 steps grow with the coordinates, not the extent (0.25 at a
    UTM northing of 4 000 000, where a 60 m surface's 2^-20 extent is 6e-5). Float64 input keeps the extent's margin
    (its own steps are 2^-29 of float32's), so an overhang at UTM coordinates in float64 stays detected. Vertical
    faces (walls) give 0."""
    x, y, scale, floor32 = _rounding_frame(vertices)
    area = np.empty(len(faces))
    margin = np.empty(len(faces))
    for start in range(0, len(faces), AREA_BLOCK):  # by blocks of faces
        block = slice(start, start + AREA_BLOCK)
        a, b, c = (np.ascontiguousarray(faces[block, k]) for k in range(3))
        ax, ay = x[a], y[a]
        bx, by, cx, cy = x[b], y[b], x[c], y[c]
        bx -= ax
        by -= ay
        cx -= ax
        cy -= ay
        _block_areas(bx, by, cx, cy, scale, floor32, area[block], margin[block])
    return area, margin


#: Faces whose candidate points :func:`_overlaps` tests at once (about 4 cells a face, 4 OVERLAP_BLOCK (face, cell)
#: pairs a block: some 100 MB of temporaries).
OVERLAP_BLOCK = 1 << 16
#: The barycentric weights of the point inside each face that :func:`_overlaps` tests: off the centre and off the
#: lines through a grid cell's corners and halves, where a face of a grid folded over itself has its centre.
INNER_POINT = np.array([0.45, 0.33, 0.22])


def _overlaps(vertices: NDArray[np.float64], faces: NDArray[np.int64], edges: NDArray[np.int64],
              numbering: NDArray[np.int64] | None = None,
              areas: list[tuple[NDArray[np.float64], NDArray[np.float64]]] | None = None) -> str | None:
    """The refusal's message where parts of a surface lie one above the other in xy though no face is turned over
    (two pieces stacked, a spiral ramp, an unmerged surface whose folded faces were each turned up alone), else
    None. A height field's faces cover each point of the ground once: no vertex or edge midpoint of its boundary
    (``edges``) and no inner point (:data:`INNER_POINT`) of a face beside the boundary lies strictly inside another
    face's projection.
    Strictly: beyond :func:`_face_areas`' margin on each of the face's three edges (the edge's and the point's
    |Δx| + |Δy| from the edge's start, times its scale; a point on an edge or a corner, a wall's foot, a
    float32-rounded crossing is inside none), and only faces with an orientation beyond their margin hold points
    (walls and slivers cover nothing). Where the surface's parts overlap, the ground covered twice is bounded by the
    boundary's projection: a boundary vertex lies in it (inside a face of the other part), or the boundary runs over
    the other part's boundary (stacked copies: the inner points of the faces beside it lie inside the other's
    faces), or two boundary edges only cross (found where a midpoint lies past the crossing, e.g. two thin strips
    crossing like a plus sign; not found otherwise). The candidates are the points in
    the cells of a uniform grid (cells about a median face across, or wider: at most ~1 a point) that each face's
    bounding box covers. ``numbering``: the faces' numbers in the message (the given faces' before the fins went),
    else their indices. ``areas``: [:func:`_face_areas` of these vertices and faces] where the caller has them,
    handed over (popped: freed here once used), else they are computed here from the corners. Each face's corners
    are gathered once, by blocks of faces, and its bounding boxes and cells computed by blocks where they are used
    (they were held for every face, 64 bytes a face). Measured on the sample DEM's height field (1.54 M faces, 2
    busy cores): 0.2-0.5 s (0.23 s of CPU time, as before), a peak of about 90 bytes a face beside its arguments,
    its own face areas included (175 before); an unmerged surface (every vertex on the boundary, every face beside
    it) of as many faces: 4-6 s of CPU time (as before), 480 bytes a face (560 before)."""
    x, y, scale, floor32 = _rounding_frame(vertices)
    rim = np.zeros(len(vertices), bool)  # the boundary's vertices
    rim[edges.reshape(-1)] = True

    def gather(pick: NDArray[np.int64] | None) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]],
                                                         NDArray[np.bool_]]:
        """The x and y of the corners of faces ``pick`` (None: all), each corner's contiguous (an (F, 3) gather and
        reductions along its rows took 3 times as long), and whether each face lies beside the boundary; by blocks
        of faces (a few MB of temporaries)."""
        n = len(faces) if pick is None else len(pick)
        corners_x, corners_y = [np.empty(n) for _ in range(3)], [np.empty(n) for _ in range(3)]
        beside = np.empty(n, bool)
        for start in range(0, n, step):
            block = slice(start, start + step)
            rows = faces[block] if pick is None else faces[pick[block]]
            for e in range(3):
                corner = np.ascontiguousarray(rows[:, e])
                np.take(x, corner, out=corners_x[e][block])
                np.take(y, corner, out=corners_y[e][block])
                if e == 0:
                    np.take(rim, corner, out=beside[block])
                else:
                    beside[block] |= rim[corner]
        return corners_x, corners_y, beside

    step = 4 * OVERLAP_BLOCK  # faces a block in the passes over every face
    areas_given = bool(areas)
    if areas_given:
        area, margin = areas.pop()
    else:  # from the corners gathered once, as _face_areas computes them
        corners_x, corners_y, beside = gather(None)
        area, margin = np.empty(len(faces)), np.empty(len(faces))
        for start in range(0, len(faces), step):
            block = slice(start, start + step)
            ax, ay = corners_x[0][block], corners_y[0][block]
            _block_areas(corners_x[1][block] - ax, corners_y[1][block] - ay, corners_x[2][block] - ax,
                         corners_y[2][block] - ay, scale, floor32, area[block], margin[block])
    solid: NDArray[np.int64] | None = np.flatnonzero(np.abs(area) > margin)
    n_solid = len(solid)
    if n_solid < 2:
        return None
    if n_solid == len(faces):
        solid = None  # every face: indices of their own
    # the faces' orientations as ±1 in a byte (a float64 ±1 before: the test's products are the same)
    sign = np.sign(area if solid is None else area[solid]).astype(np.int8)
    del area, margin
    if areas_given:
        corners_x, corners_y, beside = gather(solid)
    elif solid is not None:  # only faces with an orientation hold points
        corners_x, corners_y = [c[solid] for c in corners_x], [c[solid] for c in corners_y]
        beside = beside[solid]
    inner = np.flatnonzero(beside)  # the faces beside the boundary
    del beside
    points = np.flatnonzero(rim)
    n_points = len(points)
    # the boundary's vertices, then a point inside each face beside the boundary, off its centre (a centre lies on
    # the diagonal of a grid cell split the other way: an unmerged grid folded over itself hid there)
    # (and the boundary edges' midpoints: two thin strips crossing like a plus sign hold no corner of the other)
    px = np.concatenate([x[points], 0.5 * (x[edges[:, 0]] + x[edges[:, 1]]),
                         sum(w * c[inner] for w, c in zip(INNER_POINT, corners_x, strict=True))])
    py = np.concatenate([y[points], 0.5 * (y[edges[:, 0]] + y[edges[:, 1]]),
                         sum(w * c[inner] for w, c in zip(INNER_POINT, corners_y, strict=True))])
    owner = np.concatenate([np.full(n_points + len(edges), -1), inner])  # per point, the face it is the inner point of
    del inner

    def box(k: slice) -> tuple[NDArray[np.float64], ...]:
        """The xy bounding boxes (low x, high x, low y, high y) of faces ``k``, by pairwise minima and maxima."""
        xs, ys = [c[k] for c in corners_x], [c[k] for c in corners_y]
        return (np.minimum(np.minimum(xs[0], xs[1]), xs[2]), np.maximum(np.maximum(xs[0], xs[1]), xs[2]),
                np.minimum(np.minimum(ys[0], ys[1]), ys[2]), np.maximum(np.maximum(ys[0], ys[1]), ys[2]))

    x0, y0 = float(px.min()), float(py.min())
    width, height = float(px.max()) - x0, float(py.max()) - y0
    low_x, high_x, low_y, high_y = box(slice(None, None, max(1, n_solid // 100_000)))  # a sample's
    size = np.maximum(high_x - low_x, high_y - low_y)
    # at most ~1 cell a point, and at most 8 a point along the longer side where the points lie on a line
    cell = max(float(np.median(size)), float(np.sqrt(width * height / len(px))),
               max(width, height) / (8.0 * len(px) + 1024.0)) or 1.0
    del size
    nx, ny = int(width / cell) + 1, int(height / cell) + 1

    def column(v: NDArray[np.float64], origin: float, count: int) -> NDArray[np.int64]:
        # monotonic: a box holds its points; a face's box may reach past the points' (clipped)
        return np.clip(np.floor((v - origin) / cell), 0, count - 1).astype(np.int64)

    def cells_of(k: slice) -> tuple[NDArray[np.float64], ...]:
        """Faces ``k``'s boxes, and the first and last cell columns and rows each covers."""
        low_x, high_x, low_y, high_y = box(k)
        return (low_x, high_x, low_y, high_y, column(low_x, x0, nx), column(high_x, x0, nx),
                column(low_y, y0, ny), column(high_y, y0, ny))

    key = column(py, y0, ny) * nx + column(px, x0, nx)
    order = np.argsort(key, kind="stable")
    starts = np.zeros(nx * ny + 1, np.int64)
    np.cumsum(np.bincount(key, minlength=nx * ny), out=starts[1:])
    del key
    over = np.zeros(len(faces), bool)

    def runs(counts: NDArray[np.int64]) -> NDArray[np.int64]:  # 0 .. c - 1 for each count c, concatenated
        ends = np.cumsum(counts)
        return np.arange(int(ends[-1]) if len(ends) else 0) - np.repeat(ends - counts, counts)

    # by blocks of about OVERLAP_BLOCK x 4 (face, cell) pairs: a few faces far wider than a cell (a TIN's big
    # triangles beside its small ones) fill a block of their own
    reach = np.empty(n_solid, np.int64)  # the cells each face's box covers, summed
    for start in range(0, n_solid, step):
        ix0, ix1, iy0, iy1 = cells_of(slice(start, start + step))[4:]
        np.multiply(ix1 - ix0 + 1, iy1 - iy0 + 1, out=reach[start:start + step])
    np.cumsum(reach, out=reach)
    bounds = np.unique(np.searchsorted(reach, np.arange(0, int(reach[-1]), 4 * OVERLAP_BLOCK), "right"))
    del reach
    for start, stop in zip(bounds, [*bounds[1:], n_solid], strict=True):
        low_x, high_x, low_y, high_y, ix0, ix1, iy0, iy1 = cells_of(slice(start, stop))
        wide = ix1 - ix0 + 1
        cells = wide * (iy1 - iy0 + 1)
        local = np.repeat(np.arange(stop - start), cells)  # the faces by their place in the block
        j = runs(cells)
        w = wide[local]
        c = (iy0[local] + j // w) * nx + ix0[local] + j % w
        del j, w
        counts = starts[c + 1] - starts[c]
        local = np.repeat(local, counts)
        point = order[np.repeat(starts[c], counts) + runs(counts)]
        del c, counts
        # first within the face's box, strictly (a point strictly inside is), and not its own inner point: about a
        # dozen candidates a face come down to one or two
        qx, qy = px[point], py[point]
        near = (qx > low_x[local]) & (qx < high_x[local]) & (qy > low_y[local]) & (qy < high_y[local])
        face = local + start
        near &= owner[point] != face
        face, point, qx, qy = face[near], point[near], qx[near], qy[near]
        del near, local
        inside = np.ones(len(face), bool)
        for e in range(3):
            ax, ay = corners_x[e][face], corners_y[e][face]
            bx, by = corners_x[(e + 1) % 3][face] - ax, corners_y[(e + 1) % 3][face] - ay
            dx, dy = qx - ax, qy - ay
            turn = (bx * dy - by * dx) * sign[face]
            inside &= turn > scale * (np.abs(bx) + np.abs(by) + np.abs(dx) + np.abs(dy)) + floor32
        if inside.any():
            hit = face[inside]
            within = owner[point[inside]]
            within = within[within >= 0]
            over[hit if solid is None else solid[hit]] = True
            over[within if solid is None else solid[within]] = True
    if not over.any():
        return None
    first = int(np.argmax(over))
    cx, cy = vertices[faces[first], :2].mean(axis=0)
    number = int(numbering[first]) if numbering is not None else first
    return (f"faces must project one-to-one onto the xy plane (a height field's surface: one face over each point "
            f"of the ground); got {counted(int(over.sum()), 'face')} overlapping others in xy (counted where a "
            f"boundary of the surface lies over or under them: parts of it one above the other with no face turned "
            f"over, e.g. pieces stacked, a spiral ramp, or an unmerged surface folded over itself), the first face "
            f"{number} at x, y = {cx:.9g}, {cy:.9g}: its solid would intersect itself")


def _orient_pieces(vertices: NDArray[np.float64], faces: NDArray[np.int64], area: NDArray[np.float64],
                   margin: NDArray[np.float64]) -> tuple[NDArray[np.int64], int, int] | str | None:
    """The faces of a surface with faces facing up and faces facing down (beyond their ``margin``), each connected
    piece (faces joined through edges; scipy's ``connected_components`` over the face pairs of each edge, found by a
    sort of the undirected edge keys) turned to face up: the faces with the pieces facing down reversed, the number
    of pieces turned and of pieces in all. A piece faces the way of its summed signed projected ``area`` (its
    boundary's area). The refusal's message instead (the caller refuses faces wound against their neighbours
    first): a closed piece beside open ones (no boundary edge: its base would be its faces flattened twice over) or
    a piece with faces facing against it (an overhang: the surface folds over itself, its projection covers some
    ground twice, and the solid would intersect itself). None where every piece is closed (a closed mesh, refused
    as such later)."""
    from scipy.sparse import coo_matrix  # a dependency; imported here, not with the package (~0.1 s)
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    f = len(faces)
    # in place and freed as soon as done (a face's owner in int32: faces fit int32 three times over): at most ~76
    # bytes a face beside the faces and their areas, where the keys' and owners' temporaries peaked at 160
    ends = np.roll(faces, -1, axis=1)
    keys = np.minimum(faces, ends)
    np.maximum(faces, ends, out=ends)
    keys *= n
    keys += ends
    del ends
    keys = keys.reshape(-1)
    order = np.argsort(keys)
    keys = keys[order]
    same = keys[1:] == keys[:-1]
    del keys
    order //= 3
    owner = order.astype(np.int32)
    del order
    graph = coo_matrix((np.ones(int(same.sum()), np.int8), (owner[:-1][same], owner[1:][same])), shape=(f, f))
    count, label = connected_components(graph, directed=False)
    del graph
    single = np.ones(3 * f, bool)  # a half-edge whose edge no other face uses: on the boundary
    single[1:][same] = False
    single[:-1][same] = False
    open_piece = np.zeros(count, bool)
    open_piece[label[owner[single]]] = True
    if not open_piece.any():
        return None

    def where(face: int) -> str:  # the face and its centre in xy
        x, y = vertices[faces[face], :2].mean(axis=0)
        return f"the first face {face} at x, y = {x:.9g}, {y:.9g}"

    if not open_piece.all():
        in_closed = ~open_piece[label]  # the faces of closed pieces
        face = int(np.argmax(in_closed))
        return (f"faces: close_solid skirts a surface's boundary down to the floor; got "
                f"{counted(int(np.count_nonzero(~open_piece)), 'closed piece')} "
                f"({counted(int(np.count_nonzero(in_closed)), 'face')}, no boundary edge: a solid already; "
                f"{where(face)}) beside {counted(int(open_piece.sum()), 'open one')}: close the open pieces without it")
    up = np.bincount(label, weights=area, minlength=count) >= 0.0
    against = np.where(up[label], area < -margin, area > margin)
    if against.any():
        face = int(np.argmax(against))
        pieces = np.unique(label[against])
        return (f"faces must project one-to-one onto the xy plane (a height field's surface, each piece facing up or "
                f"down throughout); got {counted(int(against.sum()), 'face')} folding over (an overhang: facing "
                f"against the rest of its piece) in {counted(len(pieces), 'piece')}, {where(face)}: its solid would "
                f"intersect itself")
    down = ~up[label]
    turned = faces.copy()
    turned[down] = turned[down][:, ::-1]
    return turned, int(np.count_nonzero(~up)), count


def float32_floor_clash(floor: float, lowest: float) -> str:
    """The end of the refusal of a solid's ``floor`` that lies below the surface's ``lowest`` point in float64 but
    on it in float32 (" in float32 too (...: at most F); got ..., which rounds to ... in float32"); the empty string
    where it lies below in float32 too. On it in float32, the base lies on the lowest point in an .stl or a .glb (and
    on the GPU): no thickness there. :func:`close_solid`'s rule, which :func:`~stepterrain.stepped.stepped` and
    :func:`~stepterrain.batch.batch` apply before stepping. ``floor`` fits in float32 (checked first); every such
    floor lies below a ``lowest`` beyond float32 (its float32 value inf)."""
    with np.errstate(over="ignore"):
        low32 = np.float32(lowest)
    if np.float32(floor) < low32:
        return ""
    return (f" in float32 too (an .stl or a .glb stores float32 positions: at most "
            f"{float(np.nextafter(low32, np.float32(-np.inf))):.9g}); got {float(floor)!r}, which rounds to "
            f"{float(np.float32(floor)):.9g} in float32")


def close_solid(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    terrace_mask: NDArray[np.bool_],
    floor: float,
    device: wp.DeviceLike = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_], int, NDArray[np.int64]]:
    """Close a height-function surface into a watertight solid with side skirts and a flat base at ``floor``.

    The base is the terraces (faces whose projections tile the domain) flattened to ``floor`` and reversed, one base
    vertex per surface vertex except that a wall's bottom and top (the faces not in ``terrace_mask``, in consecutive
    pairs as the step kernels emit them) share theirs; each boundary edge gets a vertical skirt down to the base. A
    vertical boundary edge (a wall's side on the domain boundary) joins the skirt of the boundary edge that follows
    it, so no zero-area face appears. ``floor`` must lie below the surface's lowest point, in float32 too (a base
    that rounds onto it has no thickness there in an .stl or a .glb: :func:`float32_floor_clash`).

    Where the surface's boundary touches itself at a vertex (two triangles meeting only there, e.g. between
    nodata holes), that vertex is split first: each fan of faces around it gets its own copy, and so does the base
    vertex below it, so every skirt and base edge keeps exactly two faces and the solid stays watertight. A copy
    (but for the first fan's, one in a fan with a wall, and one whose move would turn a face over, leave its own fan
    or reach another, e.g. on a grid of cells under 2 u) moves into its fan by 2 float32 steps u of the largest
    |x|, |y| in x and y (or, where that diagonal move is refused, e.g. it misses a one-triangle fan's angle, by a
    hair on square cells, by degrees on non-square ones, along the fan's mean direction, the larger component 2 u,
    under the same guards: :func:`_split_pinches`; u = 2^-9 m at 12 km, 0.5 m at UTM northings): an
    ``.stl``, whose
    readers merge corners by float32 position, then keeps the sides apart and reads back watertight too (on one
    position its vertical skirt edge had four faces). The volume moves by at most 2√2 u times the fan's outline
    times its height above ``floor`` per copy.

    Zero-volume fins are removed first: where heights sit exactly on a threshold along a ridge line, two walls
    stand back to back on the same vertices (a terrace of zero width); both go, and so do vertices no face
    uses any more. (:func:`~stepterrain.stepped.stepped` steps a solid from heights moved off the thresholds, so
    its surfaces have no such fin, and no twin vertex whose vertical edge four walls share at a saddle.)

    The boundary, the fins and the base run in the kernels of ``kernels/solid.py`` on ``device`` (the CPU by
    default; :func:`~stepterrain.stepped.stepped` passes its own); the result is the same on every device.

    Returns the new vertices (the surface's first, then the base), the faces (kept input faces first, then the
    added ones), the mask of input faces kept, the number of faces added, and per surface vertex the input vertex
    it is or copies (``len(source)`` surface vertices: per-vertex data such as colours follows them through it).
    The solid faces outward (its volume positive) either way the surface is wound: a surface wound clockwise seen
    from +z (its signed projected area, from its boundary, negative: e.g. a TIN's faces flipped, a stepped surface
    through trimesh's ``invert``) is closed with every face reversed (``faces[:, ::-1]``: the solid of the surface
    wound counter-clockwise, bit for bit), with a warning. A surface whose pieces (faces joined through edges: two
    tiles of a TIN, or two fans meeting at one vertex) are wound opposite ways, some faces facing up and some down,
    has each piece facing down closed reversed on its own, with a warning counting them: every piece comes out
    outward.
    The base vertices follow the surface's order: one per column (the surface vertices that share it), in the order
    of each column's smallest surface vertex.

    A foreign surface (a TIN read from a file) must be an oriented manifold with a boundary, else its solid would leak
    or be wound inconsistently without a word: a face with a repeated vertex, an edge run the same way by two faces (a
    face wound against its neighbour, a duplicate face, an edge of three or more faces) and a closed mesh (no boundary
    edge: a solid already) are refused, by an InvalidInputError naming them (a sort of the directed edges, O(F log F);
    :func:`~stepterrain.stepped.stepped` closes its own surfaces without it). So are, where some faces face up and some
    down (each face's signed projected area, beyond its float32 rounding: 0.05-0.1 s per million faces; only then the
    pieces, by a sort of the edges: about 1.5 s per million faces), a closed piece beside open ones (a box beside a TIN:
    its faces would be flattened onto the base twice over) and an overhang, a piece with faces facing against the rest
    of it (it folds over itself: its solid would intersect itself), named by how many faces fold and the first one's x,
    y. So are, last, parts of the surface one above the other with no face turned over (two pieces stacked, a spiral
    ramp, an unmerged surface folded over itself: each face a piece of its own, turned up alone), whose solids would
    intersect themselves too: found where a vertex or edge midpoint of the boundary, or a point inside a face beside
    it, lies strictly inside another face's projection (beyond the float32 margin above; :func:`_overlaps`, a grid
    of cells over those points: about 0.4 s per million faces, on every foreign surface), named by how many faces
    overlap and the first one's x, y. Holes, vertices no face uses, unmerged vertices (one copy per face: not merged,
    each face closed as its own prism) and several pieces side by side are closed as they are. Not detected: two
    parts whose boundaries only cross, no boundary vertex, boundary edge midpoint or inner point of a face beside a
    boundary inside the other (no surface seen so far).
    """
    return _close_solid(vertices, faces, terrace_mask, floor, device, turn=True, check=True)


def _check_surface(faces: NDArray[np.int64], n: int) -> None:
    """Refuse ``faces`` (over ``n`` vertices) that are no oriented manifold surface, whose solid would leak or be
    wound inconsistently: a face with a repeated vertex, or a directed edge (a, b) in two faces (a face wound against
    its neighbour, a duplicate face, or an edge of three or more faces: two of them run it the same way). O(F log F):
    a sort of the 3 F directed edge keys (n < 2^31: a·n + b fits in int64)."""
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    if repeated.any():
        first = int(np.argmax(repeated))
        raise InvalidInputError(f"faces must each join three distinct vertices; got "
                                f"{counted(int(repeated.sum()), 'face')} with a repeated vertex, the first face "
                                f"{first}: {faces[first].tolist()}")
    keys = (faces * n + np.roll(faces, -1, axis=1)).reshape(-1)
    keys.sort()
    twice = keys[1:][keys[1:] == keys[:-1]]
    if len(twice):
        a, b = divmod(int(twice[0]), n)
        raise InvalidInputError(f"faces must form an oriented manifold surface (each edge in at most two faces, wound "
                                f"opposite ways); got {counted(len(np.unique(twice)), 'edge')} used twice the same way "
                                f"(a face wound against its neighbour, a duplicate face or an edge of three or more "
                                f"faces), the first ({a}, {b}); a stepped surface whose heights lie on its "
                                f"thresholds makes such walls: stepped(..., solid=True) moves them off first")


def _close_solid(vertices: Any, faces: Any, terrace_mask: Any, floor: float, device: wp.DeviceLike, turn: bool,
                 check: bool = False
                 ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_], int, NDArray[np.int64]]:
    """:func:`close_solid`; ``turn``: a clockwise surface is closed again with its faces reversed (once); ``check``: the
    surface (a foreign one) is refused where it is no oriented manifold with a boundary (:func:`_check_surface`), has a
    closed piece beside open ones or folds over itself, and its pieces facing down are turned each
    (:func:`_orient_pieces`, with ``turn``; :func:`~stepterrain.stepped.stepped` passes its own surfaces, manifold by
    construction once moved off the thresholds, unchecked)."""
    vertices = real_numbers(vertices, "vertices", "an (N, 3) array of x, y, z")
    faces = _face_indices(faces, len(vertices) if vertices.ndim else None)
    if vertices.ndim != 2 or vertices.shape[1] != 3:  # the kernels read them as flat rows of three
        raise InvalidInputError(f"vertices must be an (N, 3) array of x, y, z; got shape {vertices.shape}")
    if len(vertices) == 0:
        raise InvalidInputError("vertices: close_solid needs a surface to close; got no vertex")
    if check and len(faces) == 0:  # (before the floor's check, which would judge vertices no face uses)
        raise InvalidInputError("faces: close_solid skirts a surface's boundary down to the floor; got a surface of "
                                "no faces")
    bad = int(np.count_nonzero(~np.isfinite(vertices)))
    if bad:  # NaN reached the solid's vertices, the base and its floor check without a word
        raise InvalidInputError(f"vertices must be finite; got {counted(bad, 'NaN or infinite coordinate')}")
    floor = finite_number(floor, "floor")
    if 3 * len(vertices) > MAX_INT32:  # their coordinates, flat, at 3·i in int32 (and pinch copies are checked later)
        raise OutputTooLargeError(f"vertices: the kernels index at most {MAX_INT32 // 3:,} vertices with int32; got "
                                  f"{len(vertices):,}")
    device = _device_of(device)
    flat, low, high = _narrow_faces(faces, device)
    if low < 0 or high >= len(vertices):  # (0, 0) without faces
        raise InvalidInputError(f"faces must index the {counted(len(vertices), 'vertex', 'vertices')} "
                                f"(0 .. {len(vertices) - 1}); got indices {low} .. {high}")
    terrace_mask = np.asarray(terrace_mask)
    if terrace_mask.dtype != np.bool_ or terrace_mask.shape != (len(faces),):  # the kernels read one byte a face
        raise InvalidInputError(f"terrace_mask must be a bool array of one flag per face ({len(faces)}); got "
                                f"{terrace_mask.dtype} of shape {terrace_mask.shape}")
    given = vertices, faces, terrace_mask  # a clockwise surface is closed again from them, its faces reversed
    areas: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []  # _face_areas(*given[:2]) for _overlaps
    kept = np.ones(len(faces), bool)
    source = np.arange(len(vertices))
    walls = np.flatnonzero(~terrace_mask)
    if len(walls) >= 4 and len(walls) % 2 == 0:
        # walls are emitted as consecutive pairs (u_top, v_top, v_bottom), (u_top, v_bottom, u_bottom)
        fin = _fins(flat, walls, len(vertices), device)
        if fin.any():  # rare: stepped() steps solids off the thresholds
            kept[walls[0::2][fin]] = False
            kept[walls[1::2][fin]] = False
    del walls
    if not kept.all():
        faces = faces[kept]
        if len(faces) == 0:  # fins only: nothing left to close (numpy's ValueError on an empty column.max())
            raise InvalidInputError("faces: close_solid needs a surface to close; every face was a zero-volume fin "
                                    "(two walls back to back on the same vertices)")
        terrace_mask = terrace_mask[kept]
        used = np.zeros(len(vertices), bool)
        used[faces.reshape(-1)] = True
        if not used.all():
            remap = np.cumsum(used) - 1
            faces = remap[faces]
            vertices = vertices[used]
            source = source[used]
        flat = _flat_faces(faces, device)
    if abs(floor) > FLOAT32_MAX:  # the mesh's float32 vertices (GPU, GLB) would hold -inf and NaN
        raise InvalidInputError(f"floor must fit in float32 (|x| < {FLOAT32_MAX:.2g}); got {floor:g}")
    zmin = float(vertices[:, 2].min()) if len(vertices) else 0.0
    if floor >= zmin:
        raise InvalidInputError(f"floor must lie below the lowest surface height {zmin}; got {floor}")
    clash = float32_floor_clash(floor, zmin)
    if clash:
        raise InvalidInputError(f"floor must lie below the lowest surface height {zmin}{clash}")
    edges = _boundary(flat, len(vertices), device)
    if turn and check:  # a foreign surface with faces facing up and faces facing down: pieces wound opposite ways
        # (turned, each), a closed piece beside open ones or an overhang (refused). stepped()'s faces never face
        # down (its walls are vertical: 0), so it skips this (and a stepped surface reversed faces down throughout)
        area, margin = _face_areas(given[0], given[1])
        if kept.all():  # the faces _overlaps checks (its vertices too: a fin's removal dropped vertices, whose
            # extent the margins scale with): handed over, not computed twice (0.1-0.2 s per million faces)
            areas = [(area, margin)]
        if np.any(area < -margin) and np.any(area > margin):
            pieces = _orient_pieces(given[0], given[1], area, margin)
            if isinstance(pieces, str):  # faces wound against their neighbours (a piece facing both ways too) are
                # refused as such first, once the fins are gone (walls back to back run their edges twice the same way)
                _check_surface(source[faces], len(given[0]))
                raise InvalidInputError(pieces)
            if pieces is not None:
                turned, count, total = pieces
                stacklevel = caller_stacklevel()
                solid = _close_solid(given[0], turned, given[2], floor, device, turn=False, check=check)
                warnings.warn(f"faces: {counted(count, 'piece')} of the surface's {total} (connected through "
                              f"their edges) {'is' if count == 1 else 'are'} wound clockwise seen from +z (normals "
                              f"pointing down); close_solid closes {'it' if count == 1 else 'them'} with their faces "
                              f"reversed, so that the solid faces outward (its volume positive)",
                              stacklevel=stacklevel)
                return solid
        del area, margin
    # wound clockwise seen from +z (a TIN's faces flipped): the skirts and base follow the surface's winding, so its
    # solid came out inside out (watertight and consistently wound, but its volume negative, its normals inward)
    if turn and _projected_area(vertices, edges) < 0.0:
        # closed again from the given faces reversed: the fins and the walls' pairs are read from the step kernels'
        # layout, which a stepped surface through trimesh's invert has reversed (its solid leaked); warned once it
        # closed (a surface refused by the check after the turn got the warning first, then the refusal)
        areas.clear()  # the given faces' areas, of no use to the reversed faces' closing (16 bytes a face held)
        stacklevel = caller_stacklevel()
        solid = _close_solid(given[0], np.ascontiguousarray(given[1][:, ::-1]), given[2], floor, device, turn=False,
                             check=check)
        warnings.warn(f"faces: the surface is wound clockwise seen from +z (its normals point down; "
                      f"{counted(len(faces), 'face')}); close_solid closes it with every face reversed, so that the "
                      "solid faces outward (its volume positive, the surface's faces in it reversed)",
                      stacklevel=stacklevel)
        return solid
    if check:  # after the fins (walls back to back share their edges with the terraces beside them) and the turn (a
        # stepped surface reversed finds its fins only once turned back)
        _check_surface(faces, len(vertices))
        if len(edges) == 0:
            raise InvalidInputError(f"faces: close_solid skirts a surface's boundary down to the floor; got a closed "
                                    f"mesh ({counted(len(faces), 'face')}, no boundary edge): a solid already")
        overlap = _overlaps(vertices, faces, edges, None if kept.all() else np.flatnonzero(kept), areas)
        del areas
        if overlap is not None:
            raise InvalidInputError(overlap)
    vertices, faces, fan, copied = _split_pinches(vertices, faces, edges, terrace_mask)
    split = len(copied) > 0
    if split:
        flat = _flat_faces(faces, device)
        edges = _boundary(flat, len(vertices), device)
        source = np.concatenate([source, source[copied]])
    n = len(vertices)
    # a column (one base vertex) is a vertex, or the wall bottom and top that a vertical wall edge joins; a pinch's
    # copies keep their own. Keyed by xy alone, two vertices on one xy that no wall joins (a TIN's cliff: two points
    # on one xy, or a crossing on a zero-area face where another edge's crossing lies) shared a base vertex, and the
    # base under them folded onto a base edge used four times: a solid that leaked, without a warning. So the key is
    # (x, y, [fan], pair): the vertices of one xy share a column when they share their wall pair (a wall's bottom
    # and top, or one vertex). A column lies in one pair group, so the pair groups as buckets find them without a
    # sort; they are numbered in the order of their smallest vertex (the base follows the surface's order).
    if 3 * n > MAX_INT32:  # the pinches' copies added vertices: _columns reads each one's coordinates at 3·i
        raise OutputTooLargeError(f"vertices: the kernels index at most {MAX_INT32 // 3:,} vertices with int32; got "
                                  f"{n:,} with the copies of the surface's pinch vertices")
    pair = _pairs(flat, terrace_mask, n, device)
    column, column32, n_columns = _columns(vertices, fan if split else None, pair, device)
    del pair
    if 3 * (n + n_columns) > MAX_INT32 or 3 * (2 * len(faces) + 3 * len(edges)) > MAX_INT32:
        raise OutputTooLargeError(f"the solid of {len(faces):,} faces and {n:,} vertices would have more faces or "
                                  f"vertices than the kernels index with int32 (3 per face or vertex)")

    # the outputs as stepped()'s: written in place on the CPU, one host copy from CUDA (_device.empty_shared)
    host, written = empty_shared((3 * (n + n_columns),), np.float64, wp.float64, device)
    launch_chunked(kernels.emit_vertices, n, [to_device(vertices.reshape(-1), wp.float64, device), column32,
                                              float(floor)], [written], device)
    out_vertices = to_numpy(host, written, written.shape).reshape(-1, 3)
    del host, written

    terrace = to_device(terrace_mask.view(np.uint8), wp.uint8, device)
    count = len(faces)
    threads = chunked_threads(count, device)
    counts = _empty(threads + 1, np.int32, wp.int32, device, zero=True)
    launch_chunked(kernels.count_base_faces, count, [flat, terrace, column32], [counts], device)
    starts, n_base = _scan(counts)
    del counts

    a, b = edges[:, 0], edges[:, 1]
    vertical = column[a] == column[b]
    # the vertical boundary edge arriving at a vertex, if any: pred[top_or_bottom] = its start
    pred = np.full(n, -1, np.int64)
    pred[b[vertical]] = a[vertical]
    a, b = a[~vertical], b[~vertical]
    x = pred[a]
    del pred
    has_x = x >= 0
    A, B = n + column[a], n + column[b]  # the base vertices under a and b
    plain = ~has_x
    m, p = len(a), int(plain.sum())
    h = m - p
    n_skirts = m + p + 2 * h
    host, written = empty_shared((3 * (len(faces) + n_skirts + n_base),), np.int64, wp.int64, device)
    launch_chunked(kernels.emit_faces, count, [flat, terrace, column32, starts, n, len(faces) + n_skirts], [written],
                   device)
    out_faces = to_numpy(host, written, written.shape).reshape(-1, 3)
    del host, written
    # skirts: every [b, A, B], then [b, a, A] where no vertical edge arrives at a, else [b, a, x] and [b, x, A]
    skirts = out_faces[len(faces):len(faces) + n_skirts]
    skirts[:m] = np.stack([b, A, B], axis=1)
    skirts[m:m + p] = np.stack([b[plain], a[plain], A[plain]], axis=1)
    skirts[m + p:m + p + h] = np.stack([b[has_x], a[has_x], x[has_x]], axis=1)
    skirts[m + p + h:] = np.stack([b[has_x], x[has_x], A[has_x]], axis=1)
    return out_vertices, out_faces, kept, n_skirts + n_base, source


#: How far :func:`_split_pinches` moves a pinch vertex's copy into its own fan, in x and in y: in float32 steps of the
#: surface's largest |x| or |y| (two: the float32 values of the copy and of the vertex it copies differ, whatever
#: their rounding).
PINCH_STEPS = 2.0


def _split_pinches(
    vertices: NDArray[np.float64], faces: NDArray[np.int64], edges: NDArray[np.int64], terrace_mask: NDArray[np.bool_]
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Give each fan of faces around a pinch vertex (one the boundary passes through more than once) its own copy.

    The corners at a pinch vertex v are joined into fans through the interior edges (v, w) they share: the
    connected components of the graph of corners and edges (scipy's ``connected_components``, linear; the label
    propagation before took one round per face around v, quadratic in a big fan), each labelled by its smallest
    corner. The fan with the smallest corner keeps v; the others get new vertices, appended, each moved into its
    own fan by :data:`PINCH_STEPS` float32 steps u of the surface's largest |x| or |y|, in x and in y (the signs of
    its faces' mean direction from v: into a grid cell, along its diagonal), so that an ``.stl`` (float32, corners
    merged by position) keeps the sides apart too; a copy whose fan has a wall (``terrace_mask`` False) stays on v,
    its wall's vertical edge vertical, and so does one whose move would turn a face of its fan over or flatten it
    (in float64 or float32: 2 u is a metre at UTM northings, a 1 m grid's cell), leave its own fan's angle at v or
    land in another fan's; one whose diagonal move is refused (e.g. it misses a one-triangle fan's angle: by a hair
    where the fan's edge is the diagonal, by degrees on non-square cells) tries the fan's mean direction instead, its
    larger component :data:`PINCH_STEPS` u, under the same guards.
    Returns the vertices, the faces and, per vertex, the fan ordinal (0 for every vertex that is not such a copy),
    to keep the copies apart where rows are keyed by xy, and the vertex each appended copy copies (empty when none
    was split). ``edges`` are the surface's boundary edges (:func:`boundary_edges`).
    """
    from scipy.sparse import coo_matrix  # a dependency; imported here, not with the package (~0.1 s)
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    fan = np.zeros(n, np.float64)
    none = np.zeros(0, np.int64)
    if len(edges) == 0:
        return vertices, faces, fan, none
    pinch = np.bincount(edges[:, 0], minlength=n) > 1
    if not pinch.any():
        return vertices, faces, fan, none
    fi, ji = np.nonzero(pinch[faces])
    v = faces[fi, ji]
    keys = np.concatenate([v * n + faces[fi, (ji + 1) % 3], v * n + faces[fi, (ji + 2) % 3]])
    _, edge_id = np.unique(keys, return_inverse=True)
    edge_id = edge_id.reshape(-1)
    corners = np.tile(np.arange(len(v)), 2)
    # nodes: the corners, then the edges (v, w) after them; each corner joins its face's two edges at v
    graph = coo_matrix((np.ones(len(corners), np.int8), (corners, len(v) + edge_id)),
                       shape=(len(v) + int(edge_id.max()) + 1,) * 2)
    _, component = connected_components(graph, directed=False)
    component = component[:len(v)]
    smallest = np.full(int(component.max()) + 1, len(v))
    np.minimum.at(smallest, component, np.arange(len(v)))
    label = smallest[component]
    # the fans (v, label) in lexical order, as one int64 key each (label < len(v)): unique's axis=0 sorted them as
    # void rows, about 10 times slower
    fan_keys, which = np.unique(v * len(v) + label, return_inverse=True)
    fans = np.column_stack(np.divmod(fan_keys, len(v)))
    rank = np.arange(len(fans)) - np.searchsorted(fans[:, 0], fans[:, 0])  # 0 for each vertex's first fan
    copies = np.flatnonzero(rank > 0)
    new_index = np.full(len(fans), -1, np.int64)
    new_index[copies] = n + np.arange(len(copies))
    moved = rank[which] > 0
    # each copy moves into its own fan, PINCH_STEPS float32 steps u of the largest |x|, |y| along x and y (the signs
    # of the fan's mean direction from v: a grid cell's diagonal): after float32 rounding (.stl, no indices) the copies
    # lie on distinct positions, and a reader that merges corners by position keeps the sides apart
    # (a copy in a wall's fan stays: its wall's vertical edge, whose ends share a column, stays vertical)
    toward = np.zeros((len(copies), 2))
    centroid = vertices[faces[fi[moved]], :2].mean(axis=1) - vertices[v[moved], :2]  # faces: the input's
    np.add.at(toward, new_index[which[moved]] - n, centroid)
    walled = np.zeros(len(copies), bool)
    walled[new_index[which[moved]][~terrace_mask[fi[moved]]] - n] = True
    toward[walled] = 0.0
    u = float(np.spacing(np.float32(np.abs(vertices[:, :2]).max())))
    added = vertices[fans[copies, 0]]  # a fancy-indexed copy
    added[:, :2] += PINCH_STEPS * u * np.sign(toward)
    # the move must keep each face of its fan the way it faces (in float64 and in float32) and must not land in another
    # fan's angle at v (2 u is a metre at UTM northings: past a 1 m grid's cell, across a sliver terrace by an
    # isoline; an obtuse TIN fan's mean direction can point into the other fan); where it would, or a face of the fan
    # has no xy area, the copy stays on v
    def orient(q: NDArray[np.float64], r: NDArray[np.float64], s: NDArray[np.float64]) -> NDArray[np.float64]:
        return (r[:, 0] - q[:, 0]) * (s[:, 1] - q[:, 1]) - (r[:, 1] - q[:, 1]) * (s[:, 0] - q[:, 0])

    o = vertices[v, :2]
    a, b = vertices[faces[fi, (ji + 1) % 3], :2], vertices[faces[fi, (ji + 2) % 3], :2]
    side = np.sign(orient(o, a, b))  # per corner at a pinch vertex
    k = new_index[which[moved]] - n
    f32 = lambda x: x.astype(np.float32).astype(np.float64)  # noqa: E731  (as the .stl has them)
    # each copy against every corner at its vertex (the pinch vertices' fans are few and small)
    order = np.argsort(v, kind="stable")
    lo = np.searchsorted(v[order], fans[copies, 0], "left")
    count = np.searchsorted(v[order], fans[copies, 0], "right") - lo
    pair = np.repeat(np.arange(len(copies)), count)
    corner = order[np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + np.repeat(lo, count)]
    other = which[corner] != copies[pair]
    pair, corner = pair[other], corner[other]

    def refused(xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Per copy, whether its move to ``xy`` turns or flattens a face of its fan, leaves its fan's angle or lands
        in another fan's."""
        p = xy[k]
        keeps = ((side[moved] != 0) & (np.sign(orient(p, a[moved], b[moved])) == side[moved])
                 & (np.sign(orient(f32(p), f32(a[moved]), f32(b[moved]))) == side[moved]))
        stay = np.zeros(len(copies), bool)
        np.logical_or.at(stay, k, ~keeps)
        # ... and must land in its own fan's angle at v (a face's closed angle; with the face kept, inside that
        # face): the signs of a thin TIN fan's mean direction can point out of it, into another face of the surface
        within = ((orient(o[moved], a[moved], p) * side[moved] >= 0)
                  & (orient(b[moved], o[moved], p) * side[moved] >= 0))
        own = np.zeros(len(copies), bool)
        np.logical_or.at(own, k, within)
        stay |= ~own
        q = xy[pair]
        inside = ((orient(o[corner], a[corner], q) * side[corner] > 0)
                  & (orient(b[corner], o[corner], q) * side[corner] > 0))
        np.logical_or.at(stay, pair, inside)
        return stay

    stay = refused(added[:, :2])
    # a copy whose diagonal move is refused (it misses its fan's angle: a fan of one grid triangle, voids north and
    # south of the node, whose edge is the diagonal up to float32's rounding of the stepped crossings on it, or, on
    # non-square cells, 71 x 93 m at the Front Range's SRTM 3", by degrees: copies stayed, the .stl open there) moves
    # along its fan's mean direction instead, its larger component PINCH_STEPS u, under the same guards: inside the
    # angle of any fan whose angle at v is under 180 degrees (a sum of directions in a convex cone), its float32
    # position still distinct. As for the diagonal, the guards see the fan's other corners unmoved: where one is a
    # pinch vertex whose copy moves too, only a face a few u across could still turn (a case no test has met)
    size = np.abs(toward).max(axis=1)
    retry = np.flatnonzero(stay & (size > 0))
    if len(retry):
        along = added[:, :2].copy()
        along[retry] = (vertices[fans[copies[retry], 0], :2]
                        + PINCH_STEPS * u * toward[retry] / size[retry, None])
        moves = retry[~refused(along)[retry]]
        added[moves, :2] = along[moves]
        stay[moves] = False
    added[stay, :2] = vertices[fans[copies[stay], 0], :2]
    faces = faces.copy()
    faces[fi[moved], ji[moved]] = new_index[which[moved]]
    vertices = np.concatenate([vertices, added])
    fan = np.concatenate([fan, rank[copies].astype(np.float64)])
    return vertices, faces, fan, fans[copies, 0]
