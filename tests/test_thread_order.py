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


@pytest.mark.parametrize("order", ORDERS)
def test_closeups_do_not_depend_on_the_thread_order(one_thread_at_a_time, order):
    """The close-ups' cull and compaction (count -> scan -> emit over the faces, mark_used_vertices' flags written by
    every face of a vertex, remap_faces in place) and their anchor strips."""
    from stepterrain.closeup import ROI, CloseUp, anchor_strips, closeup_layers

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=30, step=3)

    def make():  # a new terrain and new ROIs each time: the cull is cached per terrain and ROI objects
        t = st.Terrain.from_heights(heights, spacing=(90.0, -90.0), origin=(0.0, 2700.0))
        cus = [CloseUp(ROI.circle((900.0, 1500.0), 500.0, edge_width=150.0), rotation=(0.3, 0.7),
                       scale=(1.5, 2.0, 3.0), offset=(50.0, -30.0, 800.0)),
               CloseUp(ROI.ellipse((2300.0, 600.0), (300.0, 700.0)), scale=1.2, offset=(30.0, 30.0, 300.0))]
        layers = closeup_layers(t, cus, device="cpu")
        strips = anchor_strips(t, cus, device="cpu")
        return ([np.asarray(a).tobytes() for layer in layers
                 for a in (layer.vertices, layer.faces, layer.mask_factor, layer.original)],
                [np.asarray(s.vertices).tobytes() + np.asarray(s.faces).tobytes() for s in strips])

    ordinary = make()
    assert all(len(b) > 0 for b in ordinary[0])
    assert one_thread_at_a_time(order, make) == ordinary


@pytest.mark.filterwarnings("ignore:faces. the surface is wound clockwise")
@pytest.mark.parametrize("order", ORDERS)
def test_solid_hashed_buckets_do_not_depend_on_the_thread_order(one_thread_at_a_time, order, monkeypatch):
    """close_solid's atomic passes (count_keys, fill_buckets' and fill_corners' slots, last_wall_writes, column_reps'
    atomic min) through the hashed buckets of every key (LARGE_BUCKET 0): the order inside a bucket follows the
    thread order, the solid must not."""
    from stepterrain import mesh as mesh_module

    from .test_solid_kernels import _wall_fan

    vertices, faces, terrace = _wall_fan(60, ring=True, pinch=True, fins=0.1)
    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=24, step=5)
    monkeypatch.setattr(mesh_module, "LARGE_BUCKET", 0)

    def make():
        fan = [np.asarray(a).tobytes() if isinstance(a, np.ndarray) else a
               for a in mesh_module._close_solid(vertices, faces, terrace, -1.0, "cpu", turn=True)]  # fins: unchecked
        return fan, _mesh_bits(st.stepped(heights, interval=40.0, solid=True, device="cpu"))

    ordinary = make()
    assert one_thread_at_a_time(order, make) == ordinary


@pytest.mark.parametrize("order", ORDERS)
def test_texture_operations_do_not_depend_on_the_thread_order(one_thread_at_a_time, order):
    """The per-texel passes not in the test above: MapLibre's hillshade, relighting a normal map, the layer
    operations (blend, weighted add, modulate, adjust) and an image pyramid's area-weighted reductions."""
    from stepterrain.texture import TextureLayer, adjust, blend, modulate, relight, weighted_add
    from stepterrain.texture_lod import ImagePyramid

    heights = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=30, step=3).copy()
    rng = np.random.default_rng(3)
    a = TextureLayer("thematic", rng.random((23, 17, 3)), (0, 17, 0, 23))
    b = rng.random((23, 17, 3))
    picture = (rng.random((37, 29, 4)) * 255).astype(np.uint8)
    picture[..., 3][rng.random((37, 29)) < 0.3] = 0

    def make():
        rgb = st.normal_map(heights, device="cpu")
        out = [st.hillshade(heights, method="maplibre-combined", device="cpu"),
               relight(rgb, azimuth=1.0, altitude=0.6, device="cpu"),
               blend(a, b, rng_free_weights, device="cpu").rgba(),
               weighted_add([a, a], [0.5, 2.0], device="cpu").rgba(),
               modulate(a, rng_free_weights, device="cpu").rgba(),
               adjust(a, brightness=1.7, split="left", device="cpu").rgba()]
        with ImagePyramid.build(picture, device="cpu") as pyramid:
            out += [np.array(level) for level in pyramid.levels]
        return [np.asarray(x).tobytes() for x in out]

    rng_free_weights = np.linspace(0.0, 1.0, 23 * 17).reshape(23, 17)
    ordinary = make()
    assert one_thread_at_a_time(order, make) == ordinary
