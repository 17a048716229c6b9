"""Device-to-host copies (``_device.host_copy``): every dtype the kernels emit comes back with the right shape,
dtype and values, on the CPU (where CI runs the copy path explicitly) and on any CUDA device present."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp
from stepterrain.kernels.stepped import vec3l

from stepterrain import _device

CASES = [
    (wp.vec3d, (1000,), np.float64, (1000, 3)),
    (vec3l, (777,), np.int64, (777, 3)),
    (wp.vec3, (5,), np.float32, (5, 3)),
    (wp.vec2i, (9,), np.int32, (9, 2)),
    (wp.int32, (33, 17), np.int32, (33, 17)),
    (wp.uint8, (4099,), np.uint8, (4099,)),
    (wp.float32, (0,), np.float32, (0,)),
]


@pytest.mark.parametrize(("dtype", "shape", "np_dtype", "np_shape"), CASES, ids=[str(c[1]) for c in CASES])
def test_copy_to_fresh_host_keeps_dtype_shape_and_values(device, dtype, shape, np_dtype, np_shape):
    rng = np.random.default_rng(7)
    expected = (rng.random(np_shape) * 250).astype(np_dtype)
    source = wp.array(expected, dtype=dtype, device=device)
    out = _device._copy_to_fresh_host(source)
    assert out.dtype == np_dtype and out.shape == np_shape
    np.testing.assert_array_equal(out, expected)
    if np.prod(np_shape):
        assert not np.shares_memory(out, expected)


def test_host_copy_is_a_view_on_the_cpu_and_owned_on_cuda(device):
    source = wp.array(np.arange(3 * (_device.PREFAULT_BYTES // 24 + 10), dtype=np.float64).reshape(-1, 3),
                      dtype=wp.vec3d, device=device)
    out = _device.host_copy(source)
    np.testing.assert_array_equal(out.reshape(-1), np.arange(out.size, dtype=np.float64))
    if wp.get_device(device).is_cpu:  # a zero-copy view of the kernel's output
        assert np.shares_memory(out, source.numpy())
    else:  # a fresh array the caller owns, faulted in before the copy
        source.fill_(wp.vec3d(0.0, 0.0, 0.0))
        assert out[-1, -1] == out.size - 1


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
def test_prefault_touches_every_page(workers):
    flat = np.full(5 * 4096 * workers + 123, 7, np.uint8)
    _device._prefault(flat, workers)
    assert (flat[::4096] == 0).all()  # one byte per page written ...
    assert (np.delete(flat, np.arange(0, flat.size, 4096)) == 7).all()  # ... and nothing else


@wp.kernel
def _write_index(thread_offset: wp.int32, values: wp.array[wp.int32]):
    t = wp.tid() + thread_offset
    values[t] = t


def test_split_cpu_launch_loads_only_the_variant_that_runs():
    """A CPU launch split over threads pre-loads its module once, as the block_dim-1 variant that wp.launch runs
    on the CPU. It used to load the module's default block_dim too, a second full compile on a cold kernel
    cache that no launch ever used (the CLI's first run compiled the stepped kernels twice: 34 s, not 19 s)."""
    n = 4 * _device.MIN_THREAD_ELEMENTS
    out = wp.zeros(n, dtype=wp.int32, device="cpu")
    previous = _device.set_cpu_threads(4)
    try:
        _device.launch(_write_index, n, [], [out], wp.get_device("cpu"))
    finally:
        _device.set_cpu_threads(previous)
    np.testing.assert_array_equal(out.numpy(), np.arange(n))
    assert {block_dim for _context, block_dim in _write_index.module.execs} == {_device.CPU_LAUNCH_BLOCK_DIM}
