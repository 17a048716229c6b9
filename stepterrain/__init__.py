"""stepterrain: NVIDIA Warp kernels that turn terrain data into meshes people can look at, measure and ship.

One entry point per capability (paper):

- stepped terrain (paper 000): :func:`stepped`, :func:`stepped_series`, :func:`circular_lens`
- global terrain on the cube sphere and planar adaptive meshes (paper 003): :class:`Globe`,
  :func:`adaptive_mesh`; one :class:`Camera` (stepterrain.camera) for the globe and the texture LOD
- close-ups, detail + overview (paper 001): :class:`CloseUp`, :class:`ROI`, :func:`render_closeups`
- terrain textures (paper 004): :func:`hillshade`, :func:`topographic_layer`, :func:`contour_layer`,
  :func:`drape`,
  :class:`ImagePyramid`, :class:`TextureTree` (the full set lives in :mod:`stepterrain.texture` and
  :mod:`stepterrain.texture_lod`)
- batches on Dask: :func:`batch`

    >>> import stepterrain as st
    >>> mesh = st.stepped(st.sample_dem(), interval=100.0)   # doctest: +SKIP

The globe, close-up and texture modules load on first use; stepped terrain and batches load with the package.
The pyvista accessor ``grid.stepterrain`` is a ``pyvista.accessors`` entry point: pyvista imports
:mod:`stepterrain.pyvista_accessor` the first time a dataset's ``.stepterrain`` is used, so ``import stepterrain``
does not import pyvista (VTK), and a pyvista user need not import stepterrain first.
"""

from __future__ import annotations

import importlib as _importlib
from types import ModuleType as _ModuleType
from typing import TYPE_CHECKING
from typing import Any as _Any

from ._signals import signals_held as _signals_held

# Ctrl-C while the dependencies load (a second or two) is held back until they are loaded: trimesh catches any
# exception of its optional imports, KeyboardInterrupt too, so a Ctrl-C then was ignored (the command ran on to
# its end) or broke trimesh ("TypeError: unsupported operand type(s) for |: 'ExceptionWrapper' ..." later on)
with _signals_held():
    from ._compaction import get_memory_budget, set_memory_budget
    from ._device import get_cpu_threads, get_output_pool_limit, set_cpu_threads, set_output_pool_limit
    from .batch import BatchReport
    from .errors import (
        DataFileError,
        DeviceError,
        InvalidInputError,
        MissingDependencyError,
        OutputTooLargeError,
        SchedulerError,
        StepTerrainError,
    )
    from .io import load_dem, sample_dem
    from .stepped import Lens, circular_lens, isovalues, stepped_series

    if TYPE_CHECKING:  # type checkers see the entry points
        from .batch import batch
        from .stepped import stepped
    else:  # the modules themselves, callable as their entry points (stepterrain._callable_module): st.batch(...) and
        # st.batch.LOCAL_CLUSTER_MALLOC, st.stepped(...) and st.stepped.thresholds_of all work
        from . import batch, stepped
    from .terrain import Terrain, heightfield_mesh

__version__ = "0.1.0"

#: Public names loaded from their capability module on first access (PEP 562).
_LAZY: dict[str, str] = {
    "Camera": "camera",
    **dict.fromkeys(("Globe", "adaptive_mesh", "look_from"), "globe"),
    **dict.fromkeys(("CloseUp", "ROI", "AnchorStyle", "render_closeups", "animate_closeups", "save_animation",
                     "closeup_scene"), "closeup"),
    **dict.fromkeys(("TextureLayer", "Pipeline", "TextureAnimation", "hillshade", "cast_shadows",
                     "ambient_occlusion", "normal_map", "relight", "topographic_layer", "contour_layer",
                     "terrain_layer", "drape", "highlight_lens", "thematic_lens"), "texture"),
    **dict.fromkeys(("ImagePyramid", "TextureTree", "PatchQuadtree"), "texture_lod"),
}


#: Submodules reachable as attributes without an explicit import (``st.export.save_mesh``, ``st.render``).
_SUBMODULES = frozenset({"camera", "closeup", "export", "globe", "mesh", "pyvista_accessor", "render",
                         "texture", "texture_lod"})


def __getattr__(name: str) -> _Any:
    if name in _SUBMODULES:
        return _importlib.import_module(f".{name}", __name__)
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public namespace (``dir(stepterrain)``, tab completion): :data:`__all__` (the lazy names too, unloaded),
    the submodules (loaded or not: :data:`_SUBMODULES`) and the module's dunders (``__version__``, ``__doc__``, ...);
    not the names the package's own code imports (``annotations``, ``Any``, ...) nor its private ones."""
    here = globals()
    modules = {name for name, value in here.items() if isinstance(value, _ModuleType) and not name.startswith("_")
               and value.__name__.startswith(f"{__name__}.")}  # its own submodules loaded with it (io, errors, ...)
    dunders = {name for name in here if name.startswith("__") and name.endswith("__")}
    return sorted(set(__all__) | _SUBMODULES | modules | dunders)


__all__ = [
    "BatchReport",
    "DataFileError",
    "DeviceError",
    "InvalidInputError",
    "Lens",
    "MissingDependencyError",
    "OutputTooLargeError",
    "SchedulerError",
    "StepTerrainError",
    "Terrain",
    "batch",
    "circular_lens",
    "get_cpu_threads",
    "get_memory_budget",
    "get_output_pool_limit",
    "heightfield_mesh",
    "isovalues",
    "load_dem",
    "sample_dem",
    "set_cpu_threads",
    "set_memory_budget",
    "set_output_pool_limit",
    "stepped",
    "stepped_series",
    *_LAZY,
]

# names the module's code imported for itself, kept out of its namespace (dir(), tab completion; __dir__ leaves them
# out too): the __future__ import's behaviour stays, and type checkers read TYPE_CHECKING by that name
del annotations, TYPE_CHECKING
