"""pytest-benchmark of the texture kernels (paper 004): hillshade, sweep shadows, ambient occlusion, a layer
blend and the image pyramid, on the real Big Tujunga DEM cropped or mirror-tiled to 257² and 1025² (and 4096²
for hillshade, ``slow``), every Warp device present. ``extra_info`` records the device and pixels per second.

Not part of the test suite; enable benchmarking explicitly::

    pytest benchmarks/bench_texture.py -k small --benchmark-enable
    pytest benchmarks/bench_texture.py --benchmark-enable               # everything (minutes)

For the side-by-side comparison with gdaldem, NumPy and Pillow, see ``run_texture.py``.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from benchmarks.run_texture import tiled_dem  # noqa: E402
from stepterrain import texture as tx  # noqa: E402
from stepterrain._device import init_warp  # noqa: E402
from stepterrain.texture_lod import ImagePyramid, pyramid_shapes  # noqa: E402

init_warp()
DEVICES = ["cpu"] + [pytest.param(str(d), marks=pytest.mark.cuda, id=str(d)) for d in wp.get_cuda_devices()]
SIZES = [pytest.param(257, id="small-257"), pytest.param(1025, id="medium-1025", marks=pytest.mark.slow),
         pytest.param(4096, id="large-4096", marks=pytest.mark.slow)]
SPACING = (30.0, -30.0)


@functools.lru_cache(maxsize=3)
def heights(size: int) -> np.ndarray:
    return tiled_dem(size)


def timed(device: str, fn):
    def run():
        out = fn()
        wp.synchronize_device(device)
        return out

    run()  # compile and warm up
    return run


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("shadows", [False, True], ids=["plain", "shadows"])
def test_hillshade(benchmark, device, size, shadows):
    z = heights(size)
    benchmark(timed(device, lambda: tx.hillshade(z, spacing=SPACING, shadows=shadows, device=device)))
    benchmark.extra_info.update(device=device, pixels=z.size,
                                pixels_per_s=z.size / benchmark.stats.stats.median if benchmark.stats else None)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", SIZES[:2])
def test_ambient_occlusion(benchmark, device, size):
    z = heights(size)
    benchmark(timed(device, lambda: tx.ambient_occlusion(z, spacing=SPACING, directions=8, device=device)))
    benchmark.extra_info.update(device=device, pixels=z.size, directions=8)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", SIZES[:2])
def test_blend_with_lens(benchmark, device, size):
    z = heights(size)
    base = tx.terrain_layer(z, np.repeat(((z - z.min()) / np.ptp(z))[..., None], 3, 2).astype(np.float32),
                            spacing=SPACING)
    topo = tx.topographic_layer(z, spacing=SPACING, device=device)
    lens = tx.thematic_lens((size * 15.0, -size * 15.0), size * 5.0)
    benchmark(timed(device, lambda: tx.blend(base, topo, lens, device=device)))
    benchmark.extra_info.update(device=device, pixels=z.size)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("size", [pytest.param(1024, id="small-1024"),
                                  pytest.param(8192, id="large-8192", marks=pytest.mark.slow)])
def test_pyramid(benchmark, device, size):
    image = np.random.default_rng(0).integers(0, 256, (size, size, 3), dtype=np.uint8)

    def build():
        ImagePyramid.build(image, device=device).close()

    benchmark(timed(device, build))
    benchmark.extra_info.update(device=device, pixels=image.shape[0] * image.shape[1],
                                levels=len(pyramid_shapes(size, size)))


