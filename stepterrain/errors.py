"""The one exception hierarchy of stepterrain.

Every error the library raises on purpose derives from :class:`StepTerrainError` and also from the
builtin a caller would catch (``ValueError``, ``RuntimeError``, ``ImportError``, ``MemoryError``,
``OSError``), so ``except ValueError`` keeps working for code that does not know stepterrain.
Messages say what was expected, what was got, and where.
"""

from __future__ import annotations

__all__ = [
    "StepTerrainError",
    "InvalidInputError",
    "DeviceError",
    "MissingDependencyError",
    "OutputTooLargeError",
    "DataFileError",
    "SchedulerError",
]


class StepTerrainError(Exception):
    """Base class of every error stepterrain raises on purpose."""


class InvalidInputError(StepTerrainError, ValueError):
    """An argument has the wrong shape, dtype, range or order (named in the message)."""


class DeviceError(StepTerrainError, RuntimeError):
    """A Warp device cannot be used (unknown name, CUDA absent, arrays on two devices)."""


class MissingDependencyError(StepTerrainError, ImportError):
    """An optional dependency is needed at this point; the message gives the pip command."""


class OutputTooLargeError(StepTerrainError, MemoryError):
    """The predicted output (known after the count pass) exceeds the configured memory budget."""


class DataFileError(StepTerrainError, OSError):
    """A file does not exist, cannot be read, is not elevation data, or cannot be written."""


class SchedulerError(StepTerrainError, ConnectionError):
    """A dask scheduler cannot be reached (address, timeout and cause in the message)."""
