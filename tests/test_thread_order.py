"""Kernel results do not depend on the order their threads run in.

On the CPU a launch runs its threads one after another in index order (``launch_chunked(..., atomics=True)`` as one
range); on CUDA they run at once, in any order, one element a thread. Here every launch is split into one-thread
launches, one element each (``CPU_CHUNK`` 1, a CUDA thread's share; the texture sweeps' bundles and contour runs 1,
as on CUDA), and run in reversed or shuffled thread order: a thread that read what another writes in the same
launch, a result that kept an atomic's slot order, or a chunk boundary assumption would change the output. The
stepped meshes (grid, nodata, TIN, solid), the globe (its resampling and saturation, the level passes and the
output, a view culled and not) and a padded planar mesh, and the textures (hillshade with shadows, ambient
occlusion, contours, normals) are bit-identical to the ordinary CPU run's.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp
from stepterrain.kernels import memory as memory_kernels

import stepterrain as st
from stepterrain import _device
from stepterrain import globe as globe_module
from stepterrain import texture as texture_module
from stepterrain.globe import Globe, adaptive_mesh, look_from

from .conftest import real_dem

ORDERS = ["reversed", "shuffled"]


def _thread_order(order: str, dim: int) -> np.ndarray:
    if order == "reversed":
        return np.arange(dim)[::-1]
    return np.random.default_rng(dim).permutation(dim)


@pytest.fixture
def one_thread_at_a_time(monkeypatch):
    """Returns ``run(order, make)``: ``make()`` with every CPU launch's threads run one at a time in ``order``
    (each thread a launch of its own, ``thread_offset`` its index), one element a thread."""

    def run(order, make):
        def launch_range(kernel, dim, inputs, outputs, device, fence):
            first = inputs[0]
            for t in _thread_order(order, dim):
                wp.launch(kernel, dim=1, inputs=[first + int(t), *inputs[1:]], outputs=outputs, device=device)
            if fence:
                wp.launch(memory_kernels.drain_streams, dim=1, device=device)

        with monkeypatch.context() as patch:
            patch.setattr(_device, "_launch_range", launch_range)
            patch.setattr(_device, "CPU_CHUNK", 1)
            patch.setattr(texture_module, "_LINES_PER_THREAD_CPU", {0: 1, 1: 1})
            patch.setattr(texture_module, "_LINES_PER_THREAD_CPU_ALIASED_ROWS", 1)
            patch.setattr(texture_module, "_OCCLUSION_LINES_PER_THREAD_CPU", {0: 1, 1: 1})
            patch.setattr(texture_module, "CONTOUR_RUN", 1)
            patch.setattr(globe_module, "_SMALL_LEVELS", 0)  # CUDA's level passes, not the CPU's one launch
            previous = st.set_cpu_threads(1)
            try:
                return make()
            finally:
                st.set_cpu_threads(previous)

    return run


@wp.kernel
def _add_to_previous(thread_offset: wp.int32, count: wp.int32, chunk: wp.int32, values: wp.array[wp.int32]):
    """A kernel that depends on the thread order: element t reads element t - 1, written in the same launch."""
    first = (wp.tid() + thread_offset) * chunk
    t = first
    while t < wp.min(first + chunk, count):
        if t > 0:
            values[t] = values[t - 1] + 1
        t += 1


@pytest.mark.parametrize("order", ORDERS)
def test_the_permuted_launches_expose_a_read_of_another_threads_write(one_thread_at_a_time, order):
    """The harness's check: a kernel that reads what an earlier thread writes gives 0, 1, 2, ... in index order
    and something else in another order."""

    def prefix():
        values = wp.zeros(50, dtype=wp.int32, device="cpu")
        _device.launch_chunked(_add_to_previous, 50, [], [values], wp.get_device("cpu"))
        return values.numpy()

    assert np.array_equal(prefix(), np.arange(50))
    assert not np.array_equal(one_thread_at_a_time(order, prefix), np.arange(50))


def _mesh_bits(mesh):
    return (np.asarray(mesh.vertices).tobytes(), np.asarray(mesh.faces).tobytes(),
            {k: np.asarray(v).tobytes() for k, v in mesh.face_attributes.items()})


@pytest.mark.parametrize("order", ORDERS)
def test_stepped_meshes_do_not_depend_on_the_thread_order(one_thread_at_a_time, order):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=5).copy()
    heights[5:8, 10:14] = np.nan
    tin = st.heightfield_mesh(heights[:12, :12])

    def make():
        return [st.stepped(heights, interval=40.0, gamma=0.8, device="cpu"),
                st.stepped(heights, interval=40.0, solid=True, device="cpu"),
                st.stepped(tin, interval=40.0, colors="terrain")]

    ordinary = make()
    permuted = one_thread_at_a_time(order, make)
    assert all(len(m.faces) > 100 for m in ordinary)
    for a, b in zip(ordinary, permuted, strict=True):
        assert _mesh_bits(b) == _mesh_bits(a)
        assert np.array_equal(a.visual.vertex_colors, b.visual.vertex_colors)


@pytest.mark.parametrize("order", ORDERS)
def test_globe_meshes_do_not_depend_on_the_thread_order(one_thread_at_a_time, order):
    close = look_from(46.0, 9.0, 2_000_000.0, tilt=40.0, fov=0.8, aspect=1.5)
    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=27, step=3)[:20]

    def make():
        g = Globe.sample(face_size=17, exaggeration=20.0, device="cpu")
        meshes = [g.mesh(error=2000.0, camera=close), g.mesh(error=2000.0, camera=close, cull=False),
                  g.mesh(error=5000.0), adaptive_mesh(dem, error=2.0, spacing=30.0)]
        nodes = [g.heights.tobytes(), g.positions.tobytes()]
        nodes += [np.asarray(v).tobytes() for _, v in sorted(g.node_parameters().items())]
        return nodes, meshes

    nodes, ordinary = make()
    permuted_nodes, permuted = one_thread_at_a_time(order, make)
    assert permuted_nodes == nodes  # the resampling and the saturated (e, r, h, α), seam copies too
    assert all(len(m.faces) > 50 for m in ordinary)
    for a, b in zip(ordinary, permuted, strict=True):
        assert _mesh_bits(b) == _mesh_bits(a)
        entries = [np.asarray(m.metadata.get("node_entry", [])) for m in (a, b)]  # (the planar mesh has none)
        assert np.array_equal(*entries)
        assert a.metadata["levels"] == b.metadata["levels"]


@pytest.mark.parametrize("order", ORDERS)
def test_textures_do_not_depend_on_the_thread_order(one_thread_at_a_time, order):
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=30, step=3).copy()
    heights[4:7, 20:23] = np.nan

    def make():
        return [st.hillshade(heights, shadows=True, azimuth=math.radians(300.0), altitude=math.radians(20.0),
                             device="cpu"),
                st.ambient_occlusion(heights, directions=4, device="cpu"),
                st.normal_map(heights, device="cpu"),
                st.contour_layer(heights, interval=20.0, device="cpu").image]

    ordinary = make()
    permuted = one_thread_at_a_time(order, make)
    for a, b in zip(ordinary, permuted, strict=True):
        assert np.asarray(a).tobytes() == np.asarray(b).tobytes()
