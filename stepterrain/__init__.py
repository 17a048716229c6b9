"""stepterrain: NVIDIA Warp kernels that turn terrain data into meshes people can look at, measure and ship.

    >>> import stepterrain as st
    >>> mesh = st.stepped(st.sample_dem(), interval=100.0)   # doctest: +SKIP
"""

from __future__ import annotations

from ._compaction import get_memory_budget, set_memory_budget
from ._device import get_cpu_threads, set_cpu_threads
from .errors import (
    DataFileError,
    DeviceError,
    InvalidInputError,
    MissingDependencyError,
    OutputTooLargeError,
    StepTerrainError,
)
from .io import load_dem, sample_dem
from .stepped import Lens, circular_lens, isovalues, stepped, stepped_series
from .terrain import Terrain, heightfield_mesh

__version__ = "0.1.0"

__all__ = [
    "DataFileError",
    "DeviceError",
    "InvalidInputError",
    "Lens",
    "MissingDependencyError",
    "OutputTooLargeError",
    "StepTerrainError",
    "Terrain",
    "circular_lens",
    "get_cpu_threads",
    "get_memory_budget",
    "heightfield_mesh",
    "isovalues",
    "load_dem",
    "sample_dem",
    "set_cpu_threads",
    "set_memory_budget",
    "stepped",
    "stepped_series",
]

