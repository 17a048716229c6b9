"""Bugs found by a hunt over the caches, reused buffers and concurrency (issue h4: stale or aliased results,
results changed by later calls, calls from several threads, caches that grow without bound), one test each."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import stepterrain as st

from .conftest import needs_render


def _bumps(n: int, seed: int) -> np.ndarray:
    x = np.linspace(0.0, 4.0, n)
    noise = np.random.default_rng(seed).random((n, n))
    return (np.sin(x)[:, None] * np.cos(x)[None, :] * 50.0 + noise).astype(np.float32)


def _same_in_threads(call, jobs, *, threads: int = 4, rounds: int = 3) -> None:
    """``call(job)`` for every job from ``threads`` threads at once gives what the calls gave one after another
    (``call`` returns a tuple of arrays, copied)."""
    expected = [call(job) for job in jobs]
    for _ in range(rounds):
        with ThreadPoolExecutor(threads) as pool:
            got = list(pool.map(call, jobs))
        for k, (want, have) in enumerate(zip(expected, got, strict=True)):
            for a, b in zip(want, have, strict=True):
                assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), f"job {k} differs in a thread"


def test_one_tin_stepped_from_several_threads_at_once():
    """A TIN's per-terrain device cache held the ``levels`` array every pass writes (each node's level), so two
    threads stepping the same TIN Terrain at once (different intervals) wrote each other's levels: 6 of 8 meshes
    differed from the same calls made one after another. A grid's levels were this thread's scratch already. The
    fix keeps the uploads per terrain and takes the levels from the thread's scratch pool."""
    tin = st.Terrain.from_mesh(st.heightfield_mesh(_bumps(200, 1)))

    def call(interval: float) -> tuple[np.ndarray, ...]:
        mesh = st.stepped(tin, interval=interval, device="cpu")
        return mesh.vertices.copy(), mesh.faces.copy(), mesh.face_attributes["level"].copy()

    _same_in_threads(call, [3.0, 5.0, 7.0, 11.0] * 2)


def test_terrain_built_directly_does_not_follow_the_callers_array():
    """``Terrain(kind="grid", heights=h)`` kept a read-only *view* of the caller's writeable ``h``: after ``h += 100``
    the terrain's heights changed but its caches (height range, nodata flag; the upload on a GPU) did not, and
    stepped() quantized to the old isovalues, silently clamping every vertex to the old range. The terrain now takes
    a copy of arrays given to the constructor, so it steps the heights it was built with."""
    heights = _bumps(40, 3)
    given = heights.copy()
    terrain = st.Terrain(kind="grid", heights=heights)
    first = st.stepped(terrain, interval=5.0, device="cpu")
    heights += 100.0
    np.testing.assert_array_equal(terrain.heights, given)
    again = st.stepped(terrain, interval=5.0, device="cpu")
    np.testing.assert_array_equal(again.vertices, first.vertices)
    np.testing.assert_array_equal(again.faces, first.faces)
    assert not terrain.heights.flags.writeable


@needs_render
def test_reused_renderer_draws_each_new_terrain_not_the_previous_one():
    """render_closeups keyed the overview it left on a reused renderer by ``id(t)``. Given a raw (H, W) array, each
    call makes its own Terrain, which is freed when the call returns, and the next call's Terrain usually gets the
    same id: a second, different heightfield was drawn as the first one's overview (found by rendering two arrays
    in turn on one renderer and comparing with fresh renders). The key now holds the terrain (and the texture)
    itself, compared by identity."""
    from stepterrain import render
    from stepterrain.closeup import render_closeups

    size = (160, 120)
    first = _bumps(24, 4)
    second = (first[::-1] * 0.3 + 20.0).astype(np.float32)
    box = np.array([[0.0, 0.0, -60.0], [23.0, 23.0, 80.0]])
    fresh = [render_closeups(h, [], window_size=size, bounds=box, device="cpu") for h in (first, second)]
    assert not np.array_equal(fresh[0], fresh[1])
    renderer = render.LayeredRenderer(window_size=size)
    try:
        for k in range(4):  # the terrains in turn: each is made anew from its array, so each call must draw it
            image = render_closeups((first, second)[k % 2].copy(), [], window_size=size, bounds=box,
                                    renderer=renderer, device="cpu")  # fmt: skip
            np.testing.assert_array_equal(image, fresh[k % 2], err_msg=f"call {k} drew another terrain")
    finally:
        renderer.close()


def test_globe_heights_and_positions_cannot_change_the_globe():
    """Globe.heights and Globe.positions were, on the CPU, writeable views of the globe's own device arrays (Warp's
    ``.numpy()``): ``g.heights[...] = 0`` changed every later mesh of the globe, whose node parameters (errors,
    bounding spheres) still held the old heights. They are now read-only; the globe's meshes stay the same."""
    from stepterrain.globe import Globe

    globe = Globe.sample(face_size=17, device="cpu")
    before = globe.mesh(error=1e5)
    for array in (globe.heights, globe.positions):
        assert not array.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            array[...] = 0
    after = globe.mesh(error=1e5)
    np.testing.assert_array_equal(after.vertices, before.vertices)
    np.testing.assert_array_equal(after.faces, before.faces)


def test_closeup_sources_cache_is_bounded_in_bytes_and_keeps_its_hits(monkeypatch):
    """The per-terrain close-up sources were kept up to 64 whatever their size, then all dropped: a ROI dragged over
    the embedded DEM kept ~4 MB per position left behind (255 MB after 60), and the clearing rebuilt the still
    close-up's source too. Now least recently used first out past a byte bound; a re-render (other times, the
    still close-up) still finds its sources: one build per distinct ROI box."""
    from stepterrain import closeup as closeup_module
    from stepterrain.closeup import ROI, CloseUp, closeup_layers

    t = st.sample_dem()
    xmin, xmax, ymin, ymax = t.extent
    radius = 0.12 * (xmax - xmin)
    builds = []
    build = closeup_module._grid_source
    monkeypatch.setattr(closeup_module, "_grid_source", lambda *a, **k: builds.append(a[1]) or build(*a, **k))
    still = CloseUp(ROI.circle((xmin + 0.7 * (xmax - xmin), (ymin + ymax) / 2), radius), offset=(0, 0, 500.0))
    cache = t.cached(("closeup", "sources"), dict)
    positions = 24
    for i in range(positions):
        dragged = CloseUp(ROI.circle((xmin + radius * (1 + 0.03 * i), (ymin + ymax) / 2), radius),
                          offset=(0, 0, 500.0))
        for time in (0.0, 1.0):  # an animated re-render of the same frame
            closeup_layers(t, [dragged, still], time=time, device="cpu")
        held = sum(closeup_module._source_bytes(src) for src in cache.values())
        assert held <= closeup_module._SOURCES_BYTES, f"{held / 2**20:.0f} MiB of sources after {i + 1} positions"
    assert len(builds) == len(set(builds)) == positions + 1  # every ROI box built once, the still one too


def test_identity_memo_from_several_threads_gives_each_caller_the_value_of_its_own_objects():
    """_memo.derived / recall / keep, shared by threads (close-ups of one terrain drawn from a pool): objects die and
    new ones take their ids while other threads sweep, clear and put entries under the same keys. A sweep may drop an
    entry another thread just put (it is made again), but no caller gets a value made from other objects: an entry's
    objects and value are one tuple, put and read in one step."""
    import sys
    import threading

    from stepterrain._memo import derived

    class Obj:
        pass

    memo: dict = {}
    wrong: list = []

    def worker(seed: int) -> None:
        rng = np.random.default_rng(seed)
        pool = [Obj() for _ in range(4)]
        for _ in range(3000):
            if rng.random() < 0.1:  # an object gone, a new one in its place (often at the freed id)
                pool[int(rng.integers(4))] = Obj()
            obj = pool[int(rng.integers(4))]
            got = derived(memo, ("k", int(rng.integers(3))), (obj,), lambda obj=obj: (np.array([id(obj)]), obj),
                          limit=3)
            if got[1] is not obj or got[0][0] != id(obj):
                wrong.append(seed)

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=worker, args=(seed,)) for seed in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        sys.setswitchinterval(interval)
    assert not wrong, f"{len(wrong)} calls got a value made from other objects"


def test_closeup_joined_inputs_are_not_kept_for_every_cached_source():
    """The concatenated inputs and their uploads of each set of close-up sources ("joined", ~1.5 times the sources'
    bytes) were kept while the sources were, up to 64 sets: a ROI dragged over the embedded DEM held 98 MiB of them
    beside the 63 MiB of sources the 64 MiB bound allows (161 MiB). They are cheap to make again from the cached
    sources (a concatenation and an upload), so only the last few sets keep them."""
    import gc

    import warp as wp

    from stepterrain import closeup as closeup_module
    from stepterrain.closeup import ROI, CloseUp, closeup_layers

    def held(value) -> int:
        if isinstance(value, np.ndarray):
            return value.nbytes
        if isinstance(value, wp.array):
            return value.capacity
        return sum(held(v) for v in value) if isinstance(value, (tuple, list)) else 0

    t = st.sample_dem()
    xmin, xmax, ymin, ymax = t.extent
    radius = 0.08 * (xmax - xmin)
    sources = t.cached(("closeup", "sources"), dict)
    joined = t.cached(("closeup", "joined"), dict)
    sets = closeup_module._JOINED_SETS + 4  # more than are kept (20 sets took 14 s in a loaded full run)
    for i in range(sets):
        dragged = CloseUp(ROI.circle((xmin + radius * (1 + 0.1 * i), (ymin + ymax) / 2), radius),
                          offset=(0, 0, 500.0))
        closeup_layers(t, [dragged], device="cpu")
        del dragged
        gc.collect()
    assert len(sources) == sets  # the sources stay cached (within their byte bound) as before
    largest = max(held(entry[1]) for entry in joined.values())
    assert len(joined) <= closeup_module._JOINED_SETS
    assert sum(held(entry[1]) for entry in joined.values()) <= closeup_module._JOINED_SETS * largest
