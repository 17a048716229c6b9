"""The unchecked accessors of stepterrain.kernels.memory: what they read and write, that Warp's debug mode checks
their indices (and finds none out of range in the stepped kernels), streaming stores and their fence."""

from __future__ import annotations

import glob
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap

import numpy as np
import pytest
import warp as wp
from stepterrain.kernels.memory import STREAM_MIN_BYTES, drain_streams, load, store, stream, stream_large, vec3l

from stepterrain import _device

wp.config.quiet = True


@wp.kernel
def _copy_reversed(a: wp.array[wp.int32], b: wp.array[wp.vec3], out_a: wp.array[wp.int32], out_b: wp.array[wp.vec3]):
    i = wp.tid()
    n = a.shape[0]
    store(out_a, n - 1 - i, load(a, i) * 2)
    store(out_b, n - 1 - i, load(b, i) + wp.vec3(1.0, 2.0, 3.0))


@wp.kernel
def _stream_rows(thread_offset: wp.int32, count: wp.int32, chunk: wp.int32, out: wp.array[wp.vec3d]):
    i = (wp.tid() + thread_offset) * chunk
    end = wp.min(i + chunk, count)
    while i < end:
        stream(out, i, wp.vec3d(wp.float64(i), wp.float64(-i), 0.5))
        i += 1


def _copies(put):
    """A kernel copying vec3d, vec3l and int32 rows with ``put`` (stream or stream_large)."""

    @wp.kernel(module="unique")
    def copies(
        doubles: wp.array[wp.vec3d],
        longs: wp.array[vec3l],
        ints: wp.array[wp.int32],
        doubles_out: wp.array[wp.vec3d],
        longs_out: wp.array[vec3l],
        ints_out: wp.array[wp.int32],
    ):
        i = wp.tid()
        put(doubles_out, i, load(doubles, i))
        put(longs_out, i, vec3l(longs[i][0], longs[i][1], longs[i][2]))
        put(ints_out, i, load(ints, i))

    return copies


_stream_copies = _copies(stream)
_stream_large_copies = _copies(stream_large)


@pytest.mark.parametrize(("kernel", "destination"), [(_stream_copies, "small"), (_stream_large_copies, "small"),
                                                     (_stream_large_copies, "large")])  # fmt: skip
def test_streamed_values_keep_every_bit(device, kernel, destination):
    """stream() and stream_large() of vec3d (through its bits), vec3l and int32 write exactly what they are given:
    signed zeros, NaN payloads, infinities, subnormals, int64 beyond 2^53 and negative values; stream_large into a
    destination below STREAM_MIN_BYTES (stored plainly on the CPU) and into one of at least that size (streamed)."""
    rng = np.random.default_rng(5)
    n = 4099
    doubles = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-300, 300, (n, 3))
    doubles[:6, 0] = [-0.0, np.inf, -np.inf, 5e-324, -5e-324, np.nan]
    doubles[6, :] = np.frombuffer(np.array([0x7FF8_0000_DEAD_BEEF] * 3, np.int64).tobytes(), np.float64)
    longs = rng.integers(-(2**62), 2**62, (n, 3), dtype=np.int64)
    longs[0] = [2**53 + 1, -(2**63), 2**63 - 1]
    ints = rng.integers(-(2**31), 2**31, n, dtype=np.int64).astype(np.int32)
    sizes = [n] * 3
    if destination == "large":  # only the first n elements are written
        sizes = [max(n, -(-STREAM_MIN_BYTES // item)) for item in (24, 24, 4)]
    outs = [wp.zeros(m, dtype=t, device=device) for m, t in zip(sizes, (wp.vec3d, vec3l, wp.int32), strict=True)]
    assert (min(outs[k].capacity for k in range(3)) >= STREAM_MIN_BYTES) == (destination == "large")
    wp.launch(kernel, dim=n, inputs=[wp.array(doubles, dtype=wp.vec3d, device=device),
              wp.array(longs, dtype=vec3l, device=device), wp.array(ints, device=device)], outputs=outs,
              device=device)  # fmt: skip
    wp.launch(drain_streams, dim=1, device=device)
    np.testing.assert_array_equal(outs[0].numpy()[:n].view(np.int64), doubles.view(np.int64))
    np.testing.assert_array_equal(outs[1].numpy()[:n], longs)
    np.testing.assert_array_equal(outs[2].numpy()[:n], ints)


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64") or shutil.which("objdump") is None,
                    reason="reads x86-64 machine code with objdump")
def test_stream_large_compiles_to_streaming_stores():
    """The CPU build of a kernel putting a vec3d, a vec3l and an int32 with stream_large holds a streaming store
    (movnti, or AMD's movntsd for a double) for each of their seven 8- and 4-byte parts. clang used to merge the
    vec3l's and the int32's stores with the plain stores of stream_large's other branch into plain stores, leaving
    the three of the vec3d's bits."""
    module = _stream_large_copies.module
    wp.load_module(module, device="cpu")
    (build,) = [e for e in module.execs.values() if e is not None]
    folder = f"wp_{module.name}_{build.module_hash.hex()[:7]}*"
    objects = glob.glob(os.path.join(wp.config.kernel_cache_dir, folder, "*.o"))
    assert objects, "the module's object file is not in the kernel cache"
    code = subprocess.run(["objdump", "-d", "--no-show-raw-insn", objects[0]], capture_output=True, text=True,
                          check=True).stdout  # fmt: skip
    functions = re.split(r"\n(?=[0-9a-f]+ <)", code)
    forward = [part for part in functions if re.match(r"[0-9a-f]+ <\w*copies_\w*_cpu_forward>", part)]
    assert len(forward) == 1
    assert len(re.findall(r"\tmovnt(?:i|sd)\s", forward[0])) >= 7


def test_load_and_store_match_numpy(device):
    a = np.arange(100, dtype=np.int32) * 3 - 50
    b = np.random.default_rng(0).random((100, 3)).astype(np.float32)
    out_a = wp.zeros(100, dtype=wp.int32, device=device)
    out_b = wp.zeros(100, dtype=wp.vec3, device=device)
    wp.launch(_copy_reversed, dim=100, inputs=[wp.array(a, device=device), wp.array(b, dtype=wp.vec3, device=device)],
              outputs=[out_a, out_b], device=device)  # fmt: skip
    np.testing.assert_array_equal(out_a.numpy(), (a * 2)[::-1])
    np.testing.assert_array_equal(out_b.numpy(), (b + np.float32([1, 2, 3]))[::-1])



@wp.kernel
def _transpose2(a: wp.array2d[wp.float32], m: wp.array2d[wp.uint8], out_a: wp.array2d[wp.float32],
                out_m: wp.array2d[wp.uint8]):
    i, j = wp.tid()
    store(out_a, j, i, load(a, i, j) + 1.0)
    store(out_m, j, i, load(m, i, j) + wp.uint8(1))


def test_2d_load_and_store_follow_the_strides(device):
    """load(a, i, j) / store(a, i, j, v) address (i, j) through the byte strides: a view with a row step and a
    column step reads the right elements."""
    base = np.arange(13 * 22, dtype=np.float32).reshape(13, 22) * 0.5 - 7.0
    view = base[1::2, ::3]  # (6, 8), strides (176, 12) bytes
    mask = (np.arange(13 * 22).reshape(13, 22) % 251).astype(np.uint8)[1::2, ::3]
    a = wp.array(view, dtype=wp.float32, device="cpu", copy=False) if device == "cpu" else \
        wp.array(np.ascontiguousarray(view), dtype=wp.float32, device=device)
    if device == "cpu":
        assert a.strides == (176, 12)
    m = wp.array(np.ascontiguousarray(mask), dtype=wp.uint8, device=device)
    out_a = wp.zeros((8, 6), dtype=wp.float32, device=device)
    out_m = wp.zeros((8, 6), dtype=wp.uint8, device=device)
    wp.launch(_transpose2, dim=(6, 8), inputs=[a, m], outputs=[out_a, out_m], device=device)
    np.testing.assert_array_equal(out_a.numpy(), view.T + 1.0)
    np.testing.assert_array_equal(out_m.numpy(), mask.T + 1)

def test_streamed_output_is_complete_on_several_threads(device):
    """A fenced streaming launch split over two CPU threads writes every element (CUDA stores plainly)."""
    n = 200_003
    out = wp.full(n, wp.vec3d(7.0, 7.0, 7.0), dtype=wp.vec3d, device=device)
    before = _device.get_cpu_threads()
    _device.set_cpu_threads(2)
    try:
        _device.launch_chunked(_stream_rows, n=n, inputs=[], outputs=[out], device=wp.get_device(device),
                               min_elements=1 << 10, fence=True)  # fmt: skip
    finally:
        _device.set_cpu_threads(before)
    i = np.arange(n, dtype=np.float64)
    np.testing.assert_array_equal(out.numpy(), np.stack([i, -i, np.full(n, 0.5)], axis=1))
    wp.launch(drain_streams, dim=1, device=device)  # also a plain launch


def test_to_device_makes_strided_warp_arrays_contiguous():
    """load() ignores strides, so every array handed to a kernel is contiguous: a strided view is copied."""
    base = wp.array(np.arange(20, dtype=np.float32), device="cpu")
    view = base[::2]
    assert not view.is_contiguous
    got = _device.to_device(view, wp.float32, wp.get_device("cpu"))
    assert got.is_contiguous
    np.testing.assert_array_equal(got.numpy(), np.arange(0, 20, 2, dtype=np.float32))
    assert _device.to_device(base, wp.float32, wp.get_device("cpu")) is base


def _script(folder: str, code: str, debug: bool) -> str:
    """``code`` written to a script in ``folder`` (a file: Warp reads a kernel's source from it), Warp in debug mode
    (kernels compiled with their assertions) or not."""
    prelude = "import warp as wp\nwp.config.quiet = True\n" + ("wp.config.mode = 'debug'\n" if debug else "")
    script = os.path.join(folder, f"script_{'debug' if debug else 'release'}.py")
    with open(script, "w") as f:
        f.write(prelude + textwrap.dedent(code))
    return script


def _run(code: str, *args: str, debug: bool = True) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter, Warp in debug mode or not."""
    with tempfile.TemporaryDirectory() as tmp:
        return subprocess.run([sys.executable, _script(tmp, code, debug), *args], capture_output=True, text=True,
                              timeout=600)


def _run_debug_and_release(code: str, debug_out: str, release_out: str, *args: str):
    """``_run(code, debug_out, *args)`` and ``_run(code, release_out, *args, debug=False)`` in two interpreters at
    once (one after the other, each waited on, took twice the time on two cores): their CompletedProcesses."""
    with tempfile.TemporaryDirectory() as tmp:
        started = [subprocess.Popen([sys.executable, _script(tmp, code, debug), out, *args], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
                   for debug, out in ((True, debug_out), (False, release_out))]
        try:
            outputs = [p.communicate(timeout=600) for p in started]  # read as they run: no pipe fills up
            return tuple(subprocess.CompletedProcess(p.args, p.returncode, *out)
                         for p, out in zip(started, outputs, strict=True))
        finally:
            for p in started:
                if p.poll() is None:
                    p.kill()
                    p.communicate()


def test_debug_mode_catches_an_index_out_of_range():
    """The accessors' assertion is live in Warp's debug mode: the check the next test relies on can fail."""
    result = _run("""
        import numpy as np
        from stepterrain.kernels.memory import load, store

        @wp.kernel
        def k(a: wp.array[wp.int32], i: wp.int32, out: wp.array[wp.int32]):
            store(out, 0, load(a, i))

        a = wp.array(np.arange(4, dtype=np.int32), device="cpu")
        out = wp.zeros(1, dtype=wp.int32, device="cpu")
        wp.launch(k, dim=1, inputs=[a, 3, out], device="cpu")
        print("in range", out.numpy()[0], flush=True)
        wp.launch(k, dim=1, inputs=[a, 4, out], device="cpu")
    """)
    assert "in range 3" in result.stdout
    assert "Assertion failed" in result.stderr and "a.shape[0]" in result.stderr


def test_stepped_kernels_stay_in_range_in_debug_mode():
    """The stepped kernels on grids with nodata, aliased heights (integers on thresholds), flipped spacing,
    non-uniform levels, a solid and a TIN, compiled with their index assertions: none fires, and the meshes
    equal the release build's."""
    code = """
        import sys
        import numpy as np
        import stepterrain as st

        rng = np.random.default_rng(1)
        h = np.round(rng.random((33, 41)) * 40).astype(np.float32)
        h[5:9, 7:12] = np.nan
        tin = st.heightfield_mesh(np.round(rng.random((20, 25)) * 40).astype(np.float32), spacing=(1.0, 1.0))
        meshes = [
            st.stepped(h, interval=5.0, spacing=(2.0, 3.0), gamma=0.5),
            st.stepped(h, levels=[0, 3, 10, 11, 30], spacing=(2.0, -3.0), solid=True),
            st.stepped(tin, interval=5.0),
        ]
        np.savez(sys.argv[1], *[np.concatenate([m.vertices.ravel(), m.faces.ravel()]) for m in meshes])
    """
    with tempfile.TemporaryDirectory() as tmp:
        debug_out, release_out = os.path.join(tmp, "debug.npz"), os.path.join(tmp, "release.npz")
        debug, release = _run_debug_and_release(code, debug_out, release_out)
        assert debug.returncode == 0 and "Assertion failed" not in debug.stderr, debug.stderr[-2000:]
        assert release.returncode == 0, release.stderr[-2000:]
        with np.load(debug_out) as d, np.load(release_out) as r:
            assert d.files == r.files
            for name in d.files:
                np.testing.assert_array_equal(d[name], r[name])


def test_globe_kernels_stay_in_range_in_debug_mode():
    """The cube-sphere refinement and mesh output (cones and spheres, with and without a view, per face; the CPU's
    one-launch levels, whole and split into ranges, and the level passes CUDA takes) and the planar RTIN,
    compiled with their index assertions: none fires, and the meshes equal the release build's."""
    from tests.conftest import real_dem, shared_file

    relief = shared_file("global_relief_1deg.npz")
    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=65, step=3)
    code = """
        import sys
        import numpy as np
        import stepterrain.globe as globe_module
        from stepterrain.globe import EARTH_RADIUS, Globe, adaptive_mesh, look_from

        with np.load(sys.argv[2]) as d:
            g = Globe.from_latlon(d["elevation"], d["lat"], d["lon"], face_size=33, exaggeration=20.0, device="cpu")
        camera = look_from(30.0, 10.0, 2.0 * EARTH_RADIUS, tilt=20.0, aspect=1.6)
        meshes = []
        # one launch; split into ranges (run one after another in debug mode); level passes; a launch stopping early
        whole = globe_module._SMALL_LEVELS
        for small, threads, first in ((whole, 1, 1024), (whole, 3, 16), (0, 1, 1024), (64, 1, 1024)):
            globe_module._SMALL_LEVELS, globe_module._SPLIT_FIRST = small, first
            globe_module.get_cpu_threads = lambda threads=threads: threads
            meshes += [g.mesh(error=20000.0), g.mesh(error=3000.0, camera=camera),
                       g.mesh(error=3000.0, camera=camera, bounds="sphere"),
                       g.mesh(error=3000.0, camera=camera, cull=False)]
        flat = lambda p, r: np.ones(len(p))  # a user metric: the hanging-node check (count_hanging_edges) runs
        meshes += [*g.mesh(error=8000.0, per_face=True), g.mesh(error=3000.0, camera=camera, metrics=(
                       "geometric", "distance", "clip", flat)),
                   adaptive_mesh(np.load(sys.argv[3]), error=5.0, spacing=30.0, device="cpu"),
                   adaptive_mesh(np.load(sys.argv[3])[:50, :61], error=5.0, spacing=30.0, metrics=("geometric", flat),
                                 device="cpu")]
        np.savez(sys.argv[1], *[np.concatenate([m.vertices.ravel(), m.faces.ravel()]) for m in meshes])
    """
    with tempfile.TemporaryDirectory() as tmp:
        heights = os.path.join(tmp, "dem.npy")
        np.save(heights, dem[:65, :65])
        debug_out, release_out = os.path.join(tmp, "debug.npz"), os.path.join(tmp, "release.npz")
        debug, release = _run_debug_and_release(code, debug_out, release_out, str(relief), heights)
        assert debug.returncode == 0 and "Assertion failed" not in debug.stderr, debug.stderr[-2000:]
        assert release.returncode == 0, release.stderr[-2000:]
        with np.load(debug_out) as d, np.load(release_out) as r:
            assert d.files == r.files
            for name in d.files:
                np.testing.assert_array_equal(d[name], r[name])


def test_texture_kernels_stay_in_range_in_debug_mode():
    """The hillshade (the vector rows and the careful border and nodata path), the shadow sweeps along rows
    and along columns (bundles of several lines) and the occlusion sweeps, compiled with their index assertions:
    none fires, and the images equal the release build's."""
    from tests.conftest import real_dem

    dem = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=96, step=1)
    code = """
        import sys
        import numpy as np
        from stepterrain.texture import ambient_occlusion, cast_shadows, hillshade

        z = np.load(sys.argv[2])
        holes = z.copy()
        holes[10:14, 30:33] = np.nan
        images = [ambient_occlusion(heights, spacing=spacing, directions=5, device="cpu")
                  for heights, spacing in ((z, (30.0, -30.0)), (holes, (20.0, 45.0)))]
        for az in (0.0, 45.0, 90.0, 200.0, 315.0):
            for heights, spacing in ((z, (30.0, -30.0)), (holes, (20.0, 45.0)), (z[:40, :91], (30.0, 30.0))):
                images += [hillshade(heights, spacing=spacing, azimuth=np.radians(az), shadows=True,
                                     shadow_strength=0.4, device="cpu"),
                           cast_shadows(heights, spacing=spacing, azimuth=np.radians(az), altitude=np.radians(15),
                                        device="cpu")]
        np.savez(sys.argv[1], *images)
    """
    with tempfile.TemporaryDirectory() as tmp:
        heights = os.path.join(tmp, "dem.npy")
        np.save(heights, np.tile(dem[:96, :96], (1, 12)))  # 96 x 1152: more than 16 lines each way
        debug_out, release_out = os.path.join(tmp, "debug.npz"), os.path.join(tmp, "release.npz")
        debug, release = _run_debug_and_release(code, debug_out, release_out, heights)
        assert debug.returncode == 0 and "Assertion failed" not in debug.stderr, debug.stderr[-2000:]
        assert release.returncode == 0, release.stderr[-2000:]
        with np.load(debug_out) as d, np.load(release_out) as r:
            assert d.files == r.files
            for name in d.files:
                np.testing.assert_array_equal(d[name].view(np.uint8), r[name].view(np.uint8))
