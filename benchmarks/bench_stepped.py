"""pytest-benchmark of the Warp step tessellation: count -> scan -> emit, the γ blend, ``stepped`` in total.

Heights are a real DEM (Big Tujunga, SRTM 30 m) cropped or mirror-tiled to 257², 1025² and 2049² nodes, plus
the real DEMs of ``shared/data`` at their native size; 5, 20 and 50 equal steps over the height range; every
Warp device present (cpu, cuda:N). Kernels are compiled and warmed up before timing, and every timed function
ends with ``wp.synchronize_device``. ``benchmark.extra_info`` records the device, the output size and the
output triangles per second.

Not part of the test suite (``testpaths`` is tests and stepterrain); pytest collects it when named, or from
``pytest benchmarks`` (``python_files`` includes ``bench_*.py``). The project's ``addopts`` disable
benchmarking; enable it::

    pytest benchmarks/bench_stepped.py -k small --benchmark-enable     # 257² only: ~30 s
    pytest benchmarks/bench_stepped.py --benchmark-enable              # everything (2049²: minutes)
    pytest benchmarks/bench_stepped.py -k "small and cpu and 20steps" --benchmark-enable

The big sizes and the native DEMs carry the ``slow`` marker as well (``-m "not slow"``). For the
side-by-side comparison with VTK and NumPy, see ``run_stepped.py``.
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

import stepterrain  # noqa: E402
from benchmarks import baselines  # noqa: E402
from stepterrain._device import init_warp, resolve_device  # noqa: E402
from stepterrain.stepped import blend, step_arrays  # noqa: E402

CASES = [
    pytest.param("257", id="small-257"),
    pytest.param("1025", id="medium-1025", marks=pytest.mark.slow),
    pytest.param("2049", id="large-2049", marks=pytest.mark.slow),
    *(pytest.param(name, id=f"dem-{name}", marks=pytest.mark.slow) for name in baselines.REAL_DEMS),
]
STEPS = [5, 20, 50]
ROUNDS = {"257": 20, "1025": 5, "2049": 3}  # native DEMs (~0.6-0.8 M nodes): 5

init_warp()
DEVICES = ["cpu"] + [pytest.param(str(d), marks=pytest.mark.cuda, id=str(d)) for d in wp.get_cuda_devices()]


@functools.lru_cache(maxsize=4)
def _inputs(case: str) -> tuple[np.ndarray, tuple[float, float]]:
    if case.isdigit():
        return baselines.grid_heights(int(case))
    return baselines.real_dem(case)


@functools.cache
def _compiled(device: str) -> wp.Device:
    """Resolve the device and compile/warm every kernel of the path on a small grid."""
    dev = resolve_device(device)
    heights, spacing = baselines.grid_heights(33)
    stepterrain.stepped(heights, interval=50.0, spacing=spacing, device=dev)
    wp.synchronize_device(dev)
    return dev


def _record(benchmark, dev: wp.Device, faces: int, vertices: int, levels: int) -> None:
    benchmark.extra_info.update(
        device=str(dev),
        device_name=getattr(dev, "name", str(dev)),
        triangles=int(faces),
        vertices=int(vertices),
        levels=int(levels),
    )


def _rate(benchmark, faces: int) -> None:
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None and stats.stats.median > 0:
        benchmark.extra_info["triangles_per_s"] = faces / stats.stats.median


def _run(benchmark, fn, case: str) -> None:
    benchmark.pedantic(fn, rounds=ROUNDS.get(case, 5), iterations=1, warmup_rounds=1)


@pytest.mark.parametrize("steps", STEPS, ids=[f"{s}steps" for s in STEPS])
@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("device", DEVICES)
def test_count_scan_emit(benchmark, device: str, case: str, steps: int) -> None:
    """``step_arrays``: quantize, then the vertex and face count -> scan -> emit passes (heights on device)."""
    dev = _compiled(device)
    heights, spacing = _inputs(case)
    values = baselines.steps_isovalues(heights, steps)
    terrain = stepterrain.Terrain.from_heights(heights, spacing=spacing)
    benchmark.group = f"count_scan_emit {case} {steps}steps"
    out = {}

    def run() -> None:
        out["arrays"] = None
        out["arrays"] = step_arrays(terrain, values, device=dev)
        wp.synchronize_device(dev)

    _run(benchmark, run, case)
    arrays = out["arrays"]
    _record(benchmark, dev, arrays.face_count, arrays.vertex_count, len(values))
    _rate(benchmark, arrays.face_count)


@pytest.mark.parametrize("steps", STEPS, ids=[f"{s}steps" for s in STEPS])
@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("device", DEVICES)
def test_blend(benchmark, device: str, case: str, steps: int) -> None:
    """The γ blend alone (γ = 0.5 scalar) to float64 world positions in numpy: a change of γ."""
    dev = _compiled(device)
    heights, spacing = _inputs(case)
    values = baselines.steps_isovalues(heights, steps)
    terrain = stepterrain.Terrain.from_heights(heights, spacing=spacing)
    arrays = step_arrays(terrain, values, device=dev)
    benchmark.group = f"blend {case} {steps}steps"

    def run() -> None:
        blend(terrain, arrays, 0.5, device=dev)
        wp.synchronize_device(dev)

    _run(benchmark, run, case)
    _record(benchmark, dev, arrays.face_count, arrays.vertex_count, len(values))
    _rate(benchmark, arrays.face_count)


@pytest.mark.parametrize("steps", STEPS, ids=[f"{s}steps" for s in STEPS])
@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("device", DEVICES)
def test_stepped_total(benchmark, device: str, case: str, steps: int) -> None:
    """``stepterrain.stepped`` end to end from the raw heights to a ``trimesh.Trimesh``."""
    dev = _compiled(device)
    heights, spacing = _inputs(case)
    values = baselines.steps_isovalues(heights, steps)
    benchmark.group = f"stepped {case} {steps}steps"
    out = {}

    def run() -> None:
        out["mesh"] = None
        out["mesh"] = stepterrain.stepped(heights, levels=values, spacing=spacing, device=dev)
        wp.synchronize_device(dev)

    _run(benchmark, run, case)
    mesh = out["mesh"]
    _record(benchmark, dev, len(mesh.faces), len(mesh.vertices), len(values))
    _rate(benchmark, len(mesh.faces))
