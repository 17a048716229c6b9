"""The recycling pool of large outputs (``_device._RecyclingPool``): a dropped mesh's memory serves the next
call, and never while any array on it lives."""

from __future__ import annotations

import gc
import pickle
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import trimesh

import stepterrain as st
import stepterrain.export
from stepterrain import _device
from stepterrain.errors import InvalidInputError


@pytest.fixture
def small_outputs(monkeypatch):
    """Every output of 1 kB or more comes from a fresh pool (the default threshold is 8 MB)."""
    pool = _device._RecyclingPool(64 << 20)
    monkeypatch.setattr(_device, "RECYCLE_MIN_BYTES", 1024)
    monkeypatch.setattr(_device, "OUTPUTS", pool)
    return pool


def _heights(seed: int, n: int = 40) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.cumsum(np.cumsum(rng.normal(size=(n, n)), 0), 1).astype(np.float32)


def test_a_dropped_array_s_memory_serves_the_next_of_similar_size(small_outputs):
    a = _device.recycled_empty((1000, 3), np.int64)
    assert isinstance(a.base, _device._Loan) and a.flags.writeable
    address = a.ctypes.data
    del a
    assert small_outputs.free_bytes >= 24_000
    b = _device.recycled_empty((900, 3), np.float64)  # smaller, same block
    assert b.ctypes.data == address and small_outputs.free_bytes == 0
    c = _device.recycled_empty((1000, 3), np.int64)  # b is alive: fresh memory
    assert not np.shares_memory(b, c)
    tiny = _device.recycled_empty((10,), np.int64)  # below the threshold: plain numpy
    assert tiny.base is None


def test_a_much_smaller_request_does_not_take_a_large_block(small_outputs):
    big = _device.recycled_empty((1 << 20,), np.uint8)
    address = big.ctypes.data
    del big
    small = _device.recycled_empty((4096,), np.uint8)
    assert small.ctypes.data != address and small_outputs.free_bytes > 1 << 20


def test_views_keep_the_block_on_loan(small_outputs):
    a = _device.recycled_empty((4096,), np.int64)
    a[:] = np.arange(4096)
    view = a[100:200]
    del a
    assert small_outputs.free_bytes == 0  # the view still refers to the block
    b = _device.recycled_empty((4096,), np.int64)
    b[:] = -1
    np.testing.assert_array_equal(view, np.arange(100, 200))
    assert not np.shares_memory(view, b)
    del view
    assert small_outputs.free_bytes > 0


def test_a_kept_mesh_is_untouched_by_later_calls(small_outputs):
    kept = st.stepped(_heights(1), interval=2.0)
    vertices, faces = kept.vertices.copy(), kept.faces.copy()
    assert isinstance(np.asarray(kept.faces).base.base, _device._Loan)  # trimesh's view of the lent array
    for seed in range(2, 6):  # each dropped at once: its memory serves the next
        mesh = st.stepped(_heights(seed), interval=2.0)
        assert not np.shares_memory(mesh.faces, kept.faces)
        assert not np.shares_memory(mesh.vertices, kept.vertices)
        del mesh
        gc.collect()
    np.testing.assert_array_equal(kept.vertices, vertices)
    np.testing.assert_array_equal(kept.faces, faces)


def test_stepping_and_saving_never_keep_a_dropped_mesh_from_the_young_collection(small_outputs, tmp_path):
    """The pattern of ``stepterrain.batch``: step, save, drop, collect the young generations. Nothing the pool
    does in between may move the live mesh to the oldest generation, where that collection cannot free it."""
    h = _heights(3, 64)
    for k in range(12):
        mesh = st.stepped(h, interval=1.0)
        st.export.save_mesh(mesh, tmp_path / "tile.glb")  # its positions and indices come from the pool too
        per_mesh = small_outputs._lent
        del mesh
        gc.collect(1)
        assert small_outputs._lent == 0, f"iteration {k}: {small_outputs._lent:,} bytes still lent"
    assert 0 < per_mesh <= small_outputs.free_bytes


def test_recycled_and_fresh_outputs_are_identical(small_outputs, monkeypatch):
    h = _heights(9, 64)
    pooled = [st.stepped(h, interval=1.5, gamma=0.5) for _ in range(3)]  # the later ones on recycled memory
    del pooled[1:]
    gc.collect()
    again = st.stepped(h, interval=1.5, gamma=0.5)
    monkeypatch.setattr(_device, "RECYCLE_MIN_BYTES", 1 << 62)  # plain numpy memory
    fresh = st.stepped(h, interval=1.5, gamma=0.5)
    assert not isinstance(np.asarray(fresh.faces).base.base, _device._Loan)
    for mesh in (pooled[0], again):
        np.testing.assert_array_equal(mesh.vertices, fresh.vertices)
        np.testing.assert_array_equal(mesh.faces, fresh.faces)
        np.testing.assert_array_equal(mesh.face_attributes["level"], fresh.face_attributes["level"])
        np.testing.assert_array_equal(mesh.face_attributes["wall"], fresh.face_attributes["wall"])


def test_pooled_arrays_pickle_and_copy_as_plain_arrays(small_outputs):
    a = _device.recycled_empty((2000, 3), np.float64)
    a[:] = np.arange(6000).reshape(-1, 3)
    back = pickle.loads(pickle.dumps(a))
    np.testing.assert_array_equal(back, a)
    assert back.base is None or not np.shares_memory(back, a)


def test_the_limit_bounds_what_waits_and_zero_keeps_none(small_outputs):
    small_outputs.limit = 100_000
    arrays = [_device.recycled_empty((8000,), np.float64) for _ in range(4)]  # 72 kB blocks
    del arrays
    assert 0 < small_outputs.free_bytes <= 100_000
    previous = st.set_output_pool_limit(0)  # the global pool is the fixture's
    assert previous == 100_000 and small_outputs.free_bytes == 0
    a = _device.recycled_empty((8000,), np.float64)
    del a
    assert small_outputs.free_bytes == 0


@pytest.mark.parametrize("bad", [-1, 1.5, "1GB", None, True])
def test_set_output_pool_limit_refuses_what_is_not_a_byte_count(bad):
    with pytest.raises(InvalidInputError, match="nbytes must be a non-negative int"):
        st.set_output_pool_limit(bad)


def test_threads_borrowing_at_once_get_their_own_memory(small_outputs):
    inputs = [_heights(seed, 48) for seed in range(8)]
    expected = [st.stepped(h, interval=1.0) for h in inputs]
    expected = [(m.vertices.copy(), m.faces.copy()) for m in expected]
    gc.collect()

    def run(k: int) -> tuple[np.ndarray, np.ndarray]:
        for _ in range(3):
            mesh = st.stepped(inputs[k], interval=1.0)
        return mesh.vertices.copy(), mesh.faces.copy()

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(run, range(8)))
    for (v, f), (ev, ef) in zip(results, expected, strict=True):
        np.testing.assert_array_equal(v, ev)
        np.testing.assert_array_equal(f, ef)


def test_a_loan_returned_inside_take_does_not_shift_the_block_taken():
    """A loan may die inside ``_take`` on the same thread (a collection run by one of its allocations frees a dropped
    mesh; the RLock lets its finalizer in). Its return trimmed the oldest free block off the front of the list between
    ``_take`` choosing index k and popping it: the pop took the next block, smaller than asked for, and the new output
    was laid over too little memory. Here the chosen block's ``nbytes``, read by the choice, drops the last reference
    to a loan (its real finalizer runs)."""
    mib = 1 << 20
    pool = _device._RecyclingPool(23 * mib)
    loans = [pool.empty((_device.RECYCLE_MIN_BYTES,), np.uint8)]  # a block on loan
    assert isinstance(loans[0].base, _device._Loan)
    reads = []

    class Chosen(np.ndarray):
        @property
        def nbytes(self):  # the comprehension reads it, then min's key: the loan dies there
            reads.append(1)
            if len(reads) == 2:
                loans.clear()
            return super().nbytes

    small = np.empty(5 * mib, np.uint8)  # oldest: too small, trimmed first
    chosen = np.empty(10 * mib, np.uint8).view(Chosen)
    smaller = np.empty(8 * mib + 1, np.uint8)  # too small for the request
    with pool._lock:
        pool._free[:] = [small, chosen, smaller]
        pool.limit = 28 * mib  # the returned 9 MiB block pushes them past it: the oldest (5 MiB) is trimmed
    taken = int(pool.empty((10 * mib,), np.uint8).ctypes.data)  # only its address: reading it past 8 MiB crashed
    assert len(reads) >= 2 and not loans  # the loan died inside _take
    assert taken != int(smaller.ctypes.data), "a 10 MiB output laid over the 8 MiB block"
    assert taken == int(chosen.ctypes.data)
    assert all(b.nbytes >= 0 for b in pool._free) and pool.free_bytes <= pool.limit


@pytest.fixture
def no_collector():
    """Python's automatic collection off (a loop between two collections), the remembered meshes forgotten."""
    from stepterrain import mesh as mesh_helpers

    gc.collect()
    mesh_helpers._RECENT.clear()
    gc.disable()
    try:
        yield
    finally:
        gc.enable()
        mesh_helpers._RECENT.clear()


def _loan(mesh: trimesh.Trimesh) -> _device._Loan:
    """The owner of the block under ``mesh.faces``: alive while the mesh (or an array on the block) is."""
    owner = mesh.faces
    while not isinstance(owner, _device._Loan):
        owner = owner.base
    return owner


def test_a_loop_that_never_collects_reuses_the_meshes_it_dropped(small_outputs, no_collector):
    """``mesh = stepped(...)`` in a slider loop: each dropped Trimesh is a reference cycle (trimesh's visual, ray,
    permutate and nearest hold the mesh), which kept its lent arrays until the collector ran, so every call took
    fresh memory. A later call frees the meshes the caller dropped, and their memory serves it."""
    import weakref

    h = _heights(4, 64)
    dropped, mesh = [], None
    for k in range(6):
        mesh = st.stepped(h, interval=1.0 + 0.25 * (k % 2))
        dropped.append(weakref.ref(_loan(mesh)))  # not the mesh's: a weakref to a cycle leaves it to the collector
        if k == 0:
            per_mesh = small_outputs._lent
    assert [ref() is None for ref in dropped] == [True] * 4 + [False, False]  # the previous one is held while the
    assert small_outputs._lent <= 2 * per_mesh  # last call runs; the others came back to the pool
    np.testing.assert_array_equal(mesh.vertices, st.stepped(h, interval=1.25).vertices)


def test_stepped_series_reuses_the_frames_the_caller_dropped(small_outputs, no_collector):
    import weakref

    frames = [_heights(seed, 48) for seed in range(6)]
    refs = [weakref.ref(_loan(mesh)) for mesh in st.stepped_series(frames, interval=1.0)]
    assert sum(ref() is None for ref in refs) >= 3


def _reachable(mesh, how):
    """Something the caller keeps that reaches ``mesh`` (and no reference to ``mesh`` itself)."""
    return {"visual": lambda: mesh.visual, "ray": lambda: mesh.ray, "method": lambda: mesh.copy,
            "list": lambda: [mesh], "nearest": lambda: mesh.nearest}[how]()


@pytest.mark.parametrize("how", ["mesh", "visual", "ray", "method", "list", "nearest"])
def test_a_mesh_still_reachable_stays_whole_through_later_calls(small_outputs, no_collector, tmp_path, how):
    h = _heights(6, 48)
    mesh = st.stepped(h, interval=1.0, colors="terrain")
    area = mesh.area  # cached
    expected = (mesh.vertices.copy(), mesh.faces.copy(), mesh.visual.vertex_colors.copy(),
                {k: v.copy() for k, v in mesh.face_attributes.items()}, dict(mesh.metadata))
    keep = mesh if how == "mesh" else _reachable(mesh, how)
    del mesh
    for k in range(4):
        st.stepped(_heights(10 + k, 48), interval=1.0, colors="terrain")
    mesh = {"mesh": lambda: keep, "visual": lambda: keep.mesh, "ray": lambda: keep.mesh,
            "method": lambda: keep.__self__, "list": lambda: keep[0], "nearest": lambda: keep._mesh}[how]()
    vertices, faces, colors, attributes, metadata = expected
    np.testing.assert_array_equal(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.faces, faces)
    np.testing.assert_array_equal(mesh.visual.vertex_colors, colors)
    assert mesh.face_attributes.keys() == attributes.keys()
    for key, value in attributes.items():
        np.testing.assert_array_equal(mesh.face_attributes[key], value)
    assert mesh.metadata == metadata
    assert mesh.visual.mesh is mesh and mesh.ray.mesh is mesh and mesh.area == area
    copied = mesh.copy()
    np.testing.assert_array_equal(copied.vertices, vertices)
    mesh.export(tmp_path / "kept.ply")
    assert (tmp_path / "kept.ply").stat().st_size > 0


def test_an_array_kept_from_a_dropped_mesh_keeps_its_memory(small_outputs, no_collector):
    """The mesh goes, but not the memory under an array the caller kept from it: no later call writes there."""
    h = _heights(7, 64)
    mesh = st.stepped(h, interval=1.0)
    vertices, faces = mesh.vertices, mesh.faces
    expected = vertices.copy(), faces.copy()
    del mesh
    for k in range(4):
        st.stepped(_heights(20 + k, 64), interval=1.0)
    np.testing.assert_array_equal(vertices, expected[0])
    np.testing.assert_array_equal(faces, expected[1])


def test_a_dropped_mesh_a_weakref_still_names_is_never_seen_emptied(small_outputs, no_collector):
    """The collector clears every weak reference to a cycle before it empties it; freeing a mesh here must not hand
    a user's ``weakref.ref`` (the very object ``weakref.ref`` shares between callers) an emptied Trimesh. A list that
    refers to itself and to the mesh keeps the mesh alive after its ``__dict__`` goes."""
    import weakref

    h = _heights(8, 48)
    mesh = st.stepped(h, interval=1.0)
    expected = mesh.vertices.copy()
    ring: list = []
    ring += [ring, mesh]
    mesh.metadata["ring"] = ring
    ref, cache = weakref.ref(mesh), weakref.WeakValueDictionary({"tile": mesh})
    del mesh, ring
    for k in range(4):
        st.stepped(_heights(30 + k, 48), interval=1.0)
    seen = ref()
    assert seen is None or np.array_equal(seen.vertices, expected), "a weakref handed out an emptied mesh"
    seen = cache.get("tile")
    assert seen is None or np.array_equal(seen.vertices, expected)


class _Owner:
    """Refers back to its mesh and, when finalized, keeps it (``__del__`` may resurrect, PEP 442)."""

    kept: list = []

    def __init__(self, mesh):
        self.mesh = mesh

    def __del__(self):
        _Owner.kept.append(getattr(self, "mesh", None))


def test_a_finalizer_in_a_dropped_mesh_s_cycle_sees_it_whole(small_outputs, no_collector):
    """The collector runs the finalizers of a cycle before it empties it, so a ``__del__`` sees (and may keep) the
    mesh whole; a cycle with a finalizer is left to the collector."""
    h = _heights(9, 48)
    mesh = st.stepped(h, interval=1.0)
    expected = mesh.vertices.copy()
    mesh.metadata["owner"] = _Owner(mesh)
    _Owner.kept.clear()
    del mesh
    for k in range(4):
        st.stepped(_heights(40 + k, 48), interval=1.0)
    gc.collect()
    assert len(_Owner.kept) == 1 and _Owner.kept[0] is not None, "the finalizer found its mesh gone"
    np.testing.assert_array_equal(_Owner.kept[0].vertices, expected)
    _Owner.kept.clear()


def test_a_reference_moving_between_members_while_they_are_counted_keeps_the_mesh(small_outputs, no_collector):
    """Another thread may run between two reference counts of the check: here (a profile hook stands in for the
    thread switch, deterministically) a holder keeps the mesh or its visual, always the one not being counted at the
    moment. Counted one by one each looks unreferenced from outside, though one of them is held at every instant."""
    import sys
    import weakref

    from stepterrain import mesh as mesh_helpers

    h = _heights(11, 48)
    mesh = st.stepped(h, interval=1.0)
    expected = mesh.vertices.copy()
    visual = mesh.visual
    held = [visual]
    del mesh, visual

    def hook(frame, event, arg):
        if event == "c_call" and arg is sys.getrefcount:
            member = frame.f_locals.get("member")
            whole, part = held[0] if isinstance(held[0], trimesh.Trimesh) else held[0].mesh, None
            part = whole.visual
            if member is whole:
                held[0] = part
            elif member is part:
                held[0] = whole
            del whole, part, member

    sys.setprofile(hook)
    try:
        mesh_helpers.reclaim_dropped()
    finally:
        sys.setprofile(None)
    kept = held[0] if isinstance(held[0], trimesh.Trimesh) else getattr(held[0], "mesh", None)
    assert kept is not None, "the mesh was emptied while a holder could reach it"
    np.testing.assert_array_equal(kept.vertices, expected)
    assert weakref.getweakrefcount(kept) >= 1


class _Holder:
    """Refers to a mesh; its bound method is the callback of a weak proxy the mesh keeps."""

    def __init__(self, mesh):
        self.mesh = mesh

    def gone(self, proxy):
        pass


def test_freeing_a_dropped_mesh_empties_only_objects_of_its_cycle(small_outputs, no_collector):
    """A weak proxy in the mesh's cycle (through its callback) answers ``__dict__`` with its referent's, an object
    the caller keeps: freeing the cycle must empty the cycle's own objects, never what a member forwards to."""
    import weakref

    class Settings:
        pass

    settings = Settings()
    settings.scale = 2.5
    mesh = st.stepped(_heights(12, 48), interval=1.0)
    mesh.metadata["settings"] = weakref.proxy(settings, _Holder(mesh).gone)
    del mesh
    for k in range(4):
        st.stepped(_heights(50 + k, 48), interval=1.0)
    assert vars(settings) == {"scale": 2.5}, "a live object was emptied"
