"""Every kernel module compiles for CUDA (sm_90, through NVRTC), also on machines without a GPU.

CI has no GPU; this proves on every run that each module's CUDA code still generates and compiles (no
CPU-only constructs), as the house rule "every kernel must also run on CUDA" requires. Where a GPU is present
the whole suite also runs on it (the ``device`` fixture and Warp's default device; it passed on an H100, see
benchmarks/RESULTS.md "Session 5"). Skipped where this Warp build has no NVRTC.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest
import warp as wp

MODULES = ["stepped", "closeup", "texture", "cubesphere", "bounds", "compaction", "memory", "solid"]


def _nvrtc_archs() -> set[int]:
    wp.init()
    runtime = wp._src.context.runtime
    return set(getattr(runtime, "nvrtc_supported_archs", None) or ())


@pytest.mark.parametrize("name", MODULES)
def test_kernel_module_compiles_for_cuda(name):
    """Compiled into Warp's kernel cache (``wp.config.kernel_cache_dir``, one folder per Warp version), as the CPU
    kernels are: a binary is named by the hash of the module's code and options, so a module changed since its last
    compile is compiled again, and one unchanged is not (a fresh temporary folder compiled all eight on every run,
    about a minute on two cores)."""
    archs = _nvrtc_archs()
    if 90 not in archs:
        pytest.skip("this Warp build cannot compile for CUDA sm_90 (no NVRTC)")
    module = importlib.import_module(f"stepterrain.kernels.{name}")
    artifacts = wp.compile_aot_module(module.__name__, arch=90)
    compiled = [p for p in map(Path, artifacts) if p.suffix in (".cubin", ".ptx") and p.is_file()]
    assert compiled, f"no CUDA binary written for {name}: {artifacts}"
    assert all(".sm90." in p.name or "sm_90" in p.name for p in compiled), compiled


def test_every_kernel_module_is_compiled_above():
    """MODULES names every module of ``stepterrain.kernels`` that defines a kernel or device function: a new module
    left out would never be compiled for CUDA here."""
    import pkgutil

    import stepterrain.kernels as package

    with_device_code = set()
    for info in pkgutil.iter_modules(package.__path__):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        if any(isinstance(v, (wp.Kernel, wp.Function)) for v in vars(module).values()):
            with_device_code.add(info.name)
    assert with_device_code, "no kernel module found"
    assert with_device_code <= set(MODULES), f"not compiled for CUDA: {sorted(with_device_code - set(MODULES))}"
