"""Regression tests for bugs found in the device helpers (_device.py): each fails without its fix."""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

import stepterrain._device as device_module


class _SlowExecutor(ThreadPoolExecutor):
    """A ThreadPoolExecutor that records itself and takes a moment to start: it holds the window between another
    thread's 'no pool yet' and its own assignment open."""

    made: list[ThreadPoolExecutor] = []

    def __init__(self, *args, **kwargs):
        time.sleep(0.02)
        super().__init__(*args, **kwargs)
        _SlowExecutor.made.append(self)


@pytest.fixture
def fresh_pool(monkeypatch):
    """No shared pool, pools recorded; afterwards every pool the test made is shut down and the previous restored."""
    _SlowExecutor.made = []
    monkeypatch.setattr(device_module, "ThreadPoolExecutor", _SlowExecutor)
    monkeypatch.setattr(device_module, "_executor", None)
    yield _SlowExecutor.made
    for pool in _SlowExecutor.made:
        pool.shutdown(wait=True)


def test_threads_growing_the_shared_pool_at_once_leave_one_pool_and_shut_down_the_rest(fresh_pool):
    """Eight threads asking for 1..8 helpers at once each saw no pool and made one: seven pools were lost with
    their idle threads, and a pool replaced by a larger one was never shut down. Now the pool is grown under a
    lock, a replaced pool is shut down once its queued work is done, and every part is still touched."""
    start = threading.Barrier(8)
    buffers = {workers: np.ones(workers * 4 * device_module._PAGE, np.uint8) for workers in range(2, 10)}

    def touch(workers: int) -> None:  # page touching over ``workers`` threads: workers - 1 helpers
        start.wait()
        device_module._prefault(buffers[workers], workers)

    threads = [threading.Thread(target=touch, args=(workers,)) for workers in buffers]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    for flat in buffers.values():  # every helper's part was touched
        assert not flat[:: device_module._PAGE].any() and flat.sum() == flat.size - flat.size // device_module._PAGE
    current = device_module._executor
    assert current in fresh_pool
    assert current._max_workers >= 8
    assert not current._shutdown
    replaced = [pool for pool in fresh_pool if pool is not current]
    assert all(pool._shutdown for pool in replaced), f"{sum(not p._shutdown for p in replaced)} pools left running"
    device_module._prefault(np.ones(16 * device_module._PAGE, np.uint8), 4)  # fewer helpers: the same pool
    assert device_module._executor is current


@pytest.mark.parametrize("device", ["nonsense", "cuda:7", 5])
def test_resolve_device_names_a_bad_device_beside_input_arrays(device):
    """With input arrays, ``device=`` was passed to ``wp.get_device`` unchecked: an unknown name (or CUDA on a machine
    without it) raised Warp's bare ValueError / RuntimeError instead of the DeviceError the docstring promises."""
    import warp as wp

    from stepterrain.errors import DeviceError

    array = wp.zeros(3, dtype=wp.float32, device="cpu")
    with pytest.raises(DeviceError, match="device"):
        device_module.resolve_device(device, array)
    assert str(device_module.resolve_device("cpu", array)) == "cpu"  # the arrays' own device is still accepted


def _fake_init(calls, native="", error=None):
    """A stand-in for ``wp.init`` that writes ``native`` straight to file descriptor 2, as Warp's native library
    does, then raises ``error`` (if any)."""

    def init():
        calls.append(True)
        if native:
            os.write(2, native.encode())
        if error is not None:
            raise error

    return init


def test_warp_starts_where_sys_stderr_is_none(monkeypatch):
    """pythonw and services run with ``sys.stderr`` None: ``sys.stderr.flush()`` raised AttributeError from every
    call that resolves a device, so no stepterrain function worked there."""
    calls: list[bool] = []
    monkeypatch.setattr(device_module.wp, "init", _fake_init(calls))
    monkeypatch.setattr(sys, "stderr", None)
    device_module._init_filtering_stderr()
    assert calls == [True]


def test_warp_starts_unfiltered_without_a_temporary_folder(monkeypatch):
    """No writable temporary folder (a read-only container): TemporaryFile's OSError went out of every call that
    resolves a device (and leaked the duplicate of file descriptor 2); Warp starts unfiltered instead."""
    def no_temporary(*args, **kwargs):
        raise FileNotFoundError(2, "No usable temporary directory found")

    calls: list[bool] = []
    monkeypatch.setattr(device_module.wp, "init", _fake_init(calls))
    monkeypatch.setattr(tempfile, "TemporaryFile", no_temporary)
    before = len(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else None
    device_module._init_filtering_stderr()
    assert calls == [True]
    if before is not None:
        assert len(os.listdir("/proc/self/fd")) == before


def test_warps_native_lines_before_a_failed_start_reach_stderr(monkeypatch, capfd):
    """The lines Warp's native library wrote before ``wp.init()`` raised (the reason it failed) were captured and
    dropped with the exception; only the CUDA-driver notice is filtered, and file descriptor 2 is back."""
    calls: list[bool] = []
    native = "Warp NVIDIA CUDA driver not found\nWarp error: cannot load the kernel cache at /nowhere\n"
    monkeypatch.setattr(device_module.wp, "init", _fake_init(calls, native, RuntimeError("Warp failed to start")))
    with pytest.raises(RuntimeError, match="failed to start"):
        device_module._init_filtering_stderr()
    os.write(2, b"fd 2 restored\n")
    err = capfd.readouterr().err
    assert "cannot load the kernel cache at /nowhere" in err
    assert "NVIDIA CUDA driver" not in err
    assert "fd 2 restored" in err


def test_boundary_edges_refuses_a_bad_device_with_no_faces_too():
    """An empty face list returned its empty answer before the device was looked at: a misspelt device passed
    silently, to fail only once a mesh had faces."""
    from stepterrain.errors import DeviceError
    from stepterrain.mesh import boundary_edges

    assert boundary_edges(np.zeros((0, 3), np.int64), device="cpu").shape == (0, 2)
    for faces in (np.zeros((0, 3), np.int64), np.array([[0, 1, 2]])):
        with pytest.raises(DeviceError, match="device"):
            boundary_edges(faces, device="gpu")
