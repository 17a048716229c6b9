"""The library called from several threads at once (a ThreadPoolExecutor, dask's threaded scheduler, a web service).

Python's warning filters and display are the process's: ``warnings.catch_warnings`` swaps the filter list (and
``showwarning``) and puts back what it found on exit, so two blocks in two threads that enter and leave in the order
first in, second in, first out, second out leave the first block's filters (an "ignore") in the process for good.
Every such block of the library holds one lock (``stepterrain._warning_filters.FILTERS``); each test here runs two of
them in that order (the first waits, a second at most, until the second is inside) and checks the filters after.
"""

from __future__ import annotations

import os
import threading
import warnings
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from stepterrain import batch as batch_module
from stepterrain import export, io
from stepterrain.terrain import Terrain


def _interleaved(first, second) -> list[BaseException]:
    """Run ``first(hook)`` and ``second(hook)`` in two threads, each calling ``hook()`` inside its warning block: the
    first's hook waits (up to a second) until the second is inside, the second's until the first has returned. Without
    a lock between them that is first in, second in, first out, second out; with one, the second waits for the
    first and the hooks time out. Returns the exceptions the threads raised."""
    first_in, second_in, first_done = threading.Event(), threading.Event(), threading.Event()
    errors: list[BaseException] = []

    def first_hook() -> None:
        first_in.set()
        second_in.wait(1.0)

    def second_hook() -> None:
        second_in.set()
        first_done.wait(1.0)

    def run_first() -> None:
        try:
            first(first_hook)
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)
        finally:
            first_in.set()
            first_done.set()

    def run_second() -> None:
        first_in.wait(5.0)
        try:
            second(second_hook)
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    threads = [threading.Thread(target=run_first), threading.Thread(target=run_second)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(20)
        assert not thread.is_alive(), "a warning block deadlocked"
    return errors


@pytest.fixture
def blocks(tmp_path, monkeypatch):
    """The library's warning blocks by name, each a function of a hook it calls inside its block."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_origin

    tif = tmp_path / "dem.tif"
    with rasterio.open(tif, "w", driver="GTiff", height=4, width=5, count=1, dtype="float32", crs="EPSG:32611",
                       transform=from_origin(0, 40, 10, 10)) as out:
        out.write(np.arange(20, dtype=np.float32).reshape(1, 4, 5))
    jpeg = tmp_path / "texture.jpg"
    Image.fromarray((np.arange(8 * 8 * 3) % 251).astype(np.uint8).reshape(8, 8, 3)).save(jpeg)
    hooks: dict[str, object] = {}
    real_rasterio_open, real_image_open = rasterio.open, Image.open

    def rasterio_open(*args, **kwargs):
        hooks[threading.get_ident()]()
        return real_rasterio_open(*args, **kwargs)

    def image_open(*args, **kwargs):
        hooks[threading.get_ident()]()
        return real_image_open(*args, **kwargs)

    monkeypatch.setattr(rasterio, "open", rasterio_open)
    monkeypatch.setattr(Image, "open", image_open)

    def hooked(call):
        def run(hook):
            hooks[threading.get_ident()] = hook
            call()
        return run

    def open_raster():
        with io.open_raster(tif) as dataset:
            assert dataset.count == 1

    def source_jpeg():
        hooks[threading.get_ident()] = lambda: None  # the caller's own open
        with real_image_open(jpeg) as image:
            image.load()
            hooks[threading.get_ident()] = hooks.pop(-threading.get_ident())
            assert export._source_jpeg(image) == jpeg.read_bytes()

    def side_file_crs():
        export._check_side_file_crs(tif, tmp_path / "dem.tif.aux.xml", rasterio.crs.CRS.from_epsg(32611), tif)

    def with_own_hook(call):
        def run(hook):
            hooks[-threading.get_ident()] = hook
            call()
        return run

    return {"open_raster": hooked(open_raster), "source_jpeg": with_own_hook(source_jpeg),
            "side_file_crs": hooked(side_file_crs)}


@pytest.mark.parametrize(("first", "second"), [
    ("source_jpeg", "open_raster"),  # a textured glTF saved while a DEM is read
    ("side_file_crs", "source_jpeg"),
])
def test_warning_blocks_in_two_threads_leave_the_process_filters_as_they_were(blocks, first, second):
    """export._source_jpeg (a glTF's JPEG texture) and export._check_side_file_crs (a GeoTIFF with an ob_tran CRS)
    swapped the filters without the lock io.open_raster and batch's recording held: overlapped with another block they
    left their "ignore" in the process for good, and every later warning of the process (or DecompressionBombWarning)
    was lost. (batch._tile_off_thresholds had such a block too; it has none now: see the test after this one.)"""
    before, display = list(warnings.filters), warnings.showwarning
    errors = _interleaved(blocks[first], blocks[second])
    after, shown = list(warnings.filters), warnings.showwarning
    warnings.filters[:] = before  # for the tests after this one, also when it fails
    warnings.showwarning = display
    assert errors == []
    assert after == before
    assert shown is display


def _threshold_raster():
    """A raster on levels a few float32 steps apart at the top (thresholds -10, 0.5, 1.0 and the next float32 value
    after 1.0), its heights on every threshold: those on 1.0 stay there (its next float32 value is the next threshold,
    which :func:`stepterrain.stepped._off_thresholds` warns of), the others move up by τ. Its 4 tiles, the source
    with its bounds, and the options a solid tile reads."""
    from stepterrain.stepped import thresholds_of

    levels = np.array([-20.0, 0.0, np.nextafter(np.float32(1), np.float32(0)), 1.0, 1.0 + 2.0**-22], np.float32)
    thresholds = thresholds_of(levels)
    assert thresholds.tolist() == [-10.0, np.float32(0.5) - 2.0**-25, 1.0, 1.0 + 2.0**-23]
    heights = np.random.default_rng(3).choice(np.array([-15.0, *thresholds[:3], 0.25, 3.0], np.float32), (9, 9))
    terrain = Terrain.from_heights(heights.astype(np.float32), spacing=(10.0, 10.0), origin=(500.0, 700.0))
    items, src = batch_module.plan_items(terrain, tile_size=4)
    src = batch_module.dataclasses.replace(src, bounds=batch_module._raster_bounds(src, terrain.height_range))
    options = SimpleNamespace(interval=None, levels=tuple(float(v) for v in levels), base=0.0)
    return items, src, options


def test_solid_tiles_move_their_heights_in_threads_while_another_holds_the_warning_lock():
    """batch._tile_off_thresholds (every solid tile of a raster, on dask's threaded workers) held the library's
    warning lock (stepterrain._warning_filters.FILTERS) around its threshold pass, in a catch_warnings block only to
    hide the warning of a height left on its threshold: the workers ran those passes one at a time, and behind any
    other warning block of the process. The pass now says nothing itself (_off_thresholds(warn=False)) and takes no
    lock: two tiles' passes in two threads finish while a third thread holds the lock with a recorder of every
    warning installed, which records none of theirs (nothing leaked into another thread's block); each tile's heights
    are the serial pass's bit for bit, and the process's filters are as they were."""
    from stepterrain._warning_filters import FILTERS

    items, src, options = _threshold_raster()

    def moved(item):
        return batch_module._tile_off_thresholds(item, batch_module._item_source(src, item),
                                                 batch_module._item_terrain(item, src), options).heights

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        serial = [moved(item) for item in items]
    assert said == []  # the tile's own stepped() says it, not its threshold pass
    cut = [batch_module._item_terrain(item, src).heights for item in items]
    assert sum(int((a != b).sum()) for a, b in zip(serial, cut, strict=True)) > 0  # some heights moved
    assert all(np.array_equal(a[b == 1.0], b[b == 1.0]) for a, b in zip(serial, cut, strict=True))  # those stay
    assert any((b == 1.0).any() for b in cut)

    before, display = list(warnings.filters), warnings.showwarning
    inside, release = threading.Event(), threading.Event()
    recorded: list[warnings.WarningMessage] = []

    def hold() -> None:
        with FILTERS, warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            inside.set()
            release.wait(20)
            recorded.extend(caught)

    got: dict[str, np.ndarray] = {}
    done = [threading.Event() for _ in range(2)]

    def step(k: int) -> None:
        try:
            for item in items[k::2]:
                got[item.key] = moved(item)
        finally:
            done[k].set()

    holder = threading.Thread(target=hold)
    holder.start()
    try:
        assert inside.wait(10)
        workers = [threading.Thread(target=step, args=(k,)) for k in range(2)]
        for worker in workers:
            worker.start()
        finished = [event.wait(10) for event in done]  # before: each waited for the lock, until released below
    finally:
        release.set()
        holder.join(20)
    for worker in workers:
        worker.join(20)
    after, shown = list(warnings.filters), warnings.showwarning
    warnings.filters[:] = before  # for the tests after this one, also when it fails
    warnings.showwarning = display
    assert finished == [True, True]
    assert recorded == []
    assert {item.key: got[item.key].tobytes() for item in items} == {
        item.key: heights.tobytes() for item, heights in zip(items, serial, strict=True)}
    assert after == before and shown is display


def test_local_clusters_started_in_two_threads_leave_the_environment_as_it_was(monkeypatch):
    """start_local_cluster sets LOCAL_CLUSTER_MALLOC in os.environ while the workers start and puts back what it found:
    two threads starting clusters at once (two batches of a service) left the variables in the process for good (its
    later subprocesses started with them), as the second put back the first's after the first had put back the
    caller's. The cluster here is a stand-in that sees the variables and calls the hook as it starts."""
    distributed = pytest.importorskip("distributed")
    hooks: dict[int, object] = {}
    seen: list[bool] = []

    class Started:
        def __init__(self, **kwargs):
            seen.append(all(os.environ.get(key) == str(value)
                            for key, value in batch_module.LOCAL_CLUSTER_MALLOC.items()))
            hooks[threading.get_ident()]()

    monkeypatch.setattr(distributed, "LocalCluster", Started)
    for key in batch_module.LOCAL_CLUSTER_MALLOC:
        monkeypatch.delenv(key, raising=False)

    def start(hook):
        hooks[threading.get_ident()] = hook
        assert isinstance(batch_module.start_local_cluster(1), Started)

    assert _interleaved(start, start) == []
    assert seen == [True, True]
    assert {key: os.environ.get(key) for key in batch_module.LOCAL_CLUSTER_MALLOC} == dict.fromkeys(
        batch_module.LOCAL_CLUSTER_MALLOC)


def _digest(*arrays) -> str:
    import hashlib

    digest = hashlib.sha1()
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def test_calls_in_eight_threads_give_each_the_serial_result_and_leave_held_outputs_alone(monkeypatch):
    """stepped (terraces and solids), heightfield_mesh, close_solid, a Globe's meshes (a shared Globe), adaptive_mesh
    and texture layers through a Pipeline, each called with its own inputs from 8 threads at once on one shared
    Terrain, while another thread changes the CPU thread count and memory budget: every output is the serial call's
    bit for bit, and the outputs the threads keep are unchanged after every later call (the output pool lends every
    mesh array here, RECYCLE_MIN_BYTES lowered, and the dropped ones' memory serves later calls; the larger passes over
    the 214 x 399 grid split over up to 4 threads as the setting changes)."""
    import stepterrain as st
    from stepterrain import _device
    from stepterrain.globe import Globe, look_from
    from stepterrain.mesh import close_solid
    from stepterrain.texture import Pipeline

    monkeypatch.setattr(_device, "RECYCLE_MIN_BYTES", 1 << 12)
    previous_threads, previous_budget = _device._cpu_threads, st.get_memory_budget()
    dem = st.sample_dem()
    rows, cols = dem.heights.shape
    terrain = Terrain.from_heights(dem.heights[: rows // 3, : cols // 3], spacing=dem.spacing, origin=(0.0, 0.0))
    globe = Globe.sample(face_size=33)

    def call(kind: str, k: int):
        if kind == "stepped":
            mesh = st.stepped(terrain, interval=25.0 + 5 * k)
            return mesh, (mesh.vertices, mesh.faces)
        if kind == "solid":
            mesh = st.stepped(terrain, interval=60.0 + 10 * k, solid=True)
            return mesh, (mesh.vertices, mesh.faces)
        if kind == "heightfield":
            mesh = st.heightfield_mesh(terrain.heights[k:, k:])
            return mesh, (mesh.vertices, mesh.faces)
        if kind == "close_solid":
            # (heights off the thresholds: the sample DEM's whole metres on them make walls close_solid refuses)
            mesh = st.stepped(terrain.heights + 0.25, spacing=terrain.spacing, interval=40.0 + 10 * k)
            out = close_solid(mesh.vertices, mesh.faces, mesh.face_normals[:, 2] > 0.5,
                              float(mesh.vertices[:, 2].min()) - 10.0)
            return out, out[:3]
        if kind == "globe":
            camera = look_from(10.0 * k, 20.0 * k, 2.0e6) if k % 2 else None
            mesh = globe.mesh(error=4000.0 + 1000 * k, camera=camera)
            return mesh, (mesh.vertices, mesh.faces)
        if kind == "adaptive":
            mesh = st.adaptive_mesh(terrain, error=5.0 + 3 * k)
            return mesh, (mesh.vertices, mesh.faces)
        base = st.topographic_layer(terrain, azimuth=0.3 * k)
        layer = Pipeline().modulate(st.hillshade(terrain, azimuth=0.5 + 0.2 * k)).adjust(brightness=1.0 + 0.1 * k)
        layer = layer.apply(base)
        return layer, (layer.image,)

    calls = [(kind, k) for k in range(3) for kind in
             ("stepped", "solid", "heightfield", "close_solid", "globe", "adaptive", "texture")]
    serial = {}
    for key in calls:
        _, arrays = call(*key)
        serial[key] = _digest(*arrays)
    stop = threading.Event()

    def change_settings() -> None:
        k = 0
        while not stop.is_set():
            st.set_cpu_threads(1 + k % 4)
            st.set_memory_budget((4 + k % 4) << 30)
            k += 1
            stop.wait(0.002)

    changer = threading.Thread(target=change_settings)
    changer.start()
    try:
        from concurrent.futures import ThreadPoolExecutor

        held, got = {}, {}
        order = [calls[k] for k in np.random.default_rng(1).permutation(len(calls))]
        with ThreadPoolExecutor(8) as pool:
            futures = {key: pool.submit(call, *key) for key in order}
            for key in order:
                made, arrays = futures[key].result(timeout=120)
                got[key] = _digest(*arrays)
                if key[1] != 1:  # kept; the others dropped, their memory lent again
                    held[key] = (made, arrays)
                del made, arrays
        for key in calls[:7]:  # more calls after all: lent the dropped outputs' memory
            call(*key)
    finally:
        stop.set()
        changer.join(10)
        st.set_cpu_threads(previous_threads)
        st.set_memory_budget(previous_budget)
    assert {key: got[key] == serial[key] for key in calls} == dict.fromkeys(calls, True)
    assert {key: _digest(*held[key][1]) == serial[key] for key in held} == dict.fromkeys(held, True)


def test_the_signal_helpers_off_the_main_thread_run_their_block_and_change_nothing():
    """signals_held and terminal_signals_blocked_for_children (a batch's LocalCluster start, the package's imports,
    VTK's load) called from a worker thread (a batch started by a web service) run their block: Python handles signals
    in the main thread only (signal.signal raises ValueError elsewhere), so they hold back nothing there, and this
    thread's signal mask (inherited by what it starts) stays as it was."""
    import signal

    from stepterrain._signals import signals_held, terminal_signals_blocked_for_children

    handlers = {number: signal.getsignal(number) for number in (signal.SIGINT, signal.SIGTERM)}
    seen: list[object] = []

    def work() -> None:
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, []) if hasattr(signal, "pthread_sigmask") else None
        with signals_held(), terminal_signals_blocked_for_children():
            seen.append({number: signal.getsignal(number) for number in handlers})
            if mask is not None:
                seen.append(signal.pthread_sigmask(signal.SIG_BLOCK, []) == mask)
        seen.append("done")

    thread = threading.Thread(target=work)
    thread.start()
    thread.join(10)
    assert seen[0] == handlers and seen[-1] == "done" and all(flag is True for flag in seen[1:-1])
    assert {number: signal.getsignal(number) for number in handlers} == handlers
