"""The one exception hierarchy of stepterrain.

Every error the library raises on purpose derives from :class:`StepTerrainError` and also from the
builtin a caller would catch (``ValueError``, ``RuntimeError``, ``ImportError``, ``MemoryError``,
``OSError``), so ``except ValueError`` keeps working for code that does not know stepterrain.
Messages say what was expected, what was got, and where.
"""

from __future__ import annotations

import os
import sys
from typing import Any

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


def _reduced(error: BaseException) -> tuple[Any, ...]:
    """``__reduce__`` of an error class whose ``__init__`` takes keywords: pickled as ``type(error)(*args)`` and the
    instance's attributes, as BaseException pickles, but said by the class. tblib (which dask.distributed installs to
    send errors between processes) takes a class whose ``__init__`` is its own and whose ``__reduce__`` is
    BaseException's for one whose arguments cannot be trusted and rebuilds it by ``__new__`` alone, which a
    MemoryError subclass refuses ("MemoryError.__new__(OutputTooLargeError) is not safe"): a dask worker's
    OutputTooLargeError came back as that TypeError."""
    return type(error), error.args, error.__dict__ or None


class InvalidInputError(StepTerrainError, ValueError):
    """An argument has the wrong shape, dtype, range or order (named in the message).

    Attributes
    ----------
    not_global : bool
        True on :meth:`~stepterrain.globe.Globe.from_latlon`'s refusal of a grid that is no globe (its longitudes
        short of a turn, or its rows short of a pole), for which the command line names its INPUT file's coverage
        instead; False (the default) on every other refusal.
    too_small_to_see : bool
        True on :func:`~stepterrain.render.render_mesh`'s refusal of a mesh it would show under a pixel (its box
        less than a pixel wide or tall from the camera, or its faces slivers covering less than a pixel in all: too
        small or too thin to see, it would render blank), for which :func:`~stepterrain.batch.overview_image` leaves
        that item's cell of a contact sheet blank instead; False (the default) on every other refusal.

    Both are set with keywords: ``InvalidInputError(message, not_global=True)``.
    """

    not_global: bool = False
    too_small_to_see: bool = False

    def __init__(self, *args: object, not_global: bool = False, too_small_to_see: bool = False) -> None:
        super().__init__(*args)
        self.not_global = bool(not_global)
        self.too_small_to_see = bool(too_small_to_see)

    __reduce__ = _reduced


class DeviceError(StepTerrainError, RuntimeError):
    """A Warp device cannot be used (unknown name, CUDA absent, arrays on two devices)."""


class MissingDependencyError(StepTerrainError, ImportError):
    """An optional dependency is needed at this point; the message gives the pip command."""


class OutputTooLargeError(StepTerrainError, MemoryError):
    """The predicted output (known after the count pass) exceeds the configured memory budget.

    Attributes
    ----------
    nbytes : int or None
        The bytes the refused output would need, where the refusal is the memory budget's
        (:func:`~stepterrain._compaction.check_budget`'s); None (the default) for other refusals (an int32 index
        limit, a cache's budget).
    mesh : tuple of int or None
        The (vertices, faces) of the mesh refused, where the output refused is a mesh of known size: the command
        line's advice for a run that renders that mesh too names the budget both need; None (the default) otherwise.
    advice : str or None
        The words the message ends in that advise a budget (" to at least 30MiB", after the hint "raise the budget
        (...)"), where it ends in them (the memory budget's refusal, for a need up to 1024 TiB); None (the default)
        where it ends otherwise. The command line's advice for a run that renders the mesh too replaces them, the
        rest of the message kept (it matched the message's end against a figure of ``nbytes`` before).

    Each is set with its keyword: ``OutputTooLargeError(message, nbytes=..., mesh=(vertices, faces), advice=...)``.
    """

    nbytes: int | None = None
    mesh: tuple[int, int] | None = None
    advice: str | None = None

    def __init__(self, *args: object, nbytes: int | None = None, mesh: tuple[int, int] | None = None,
                 advice: str | None = None) -> None:
        super().__init__(*args)
        self.nbytes = None if nbytes is None else int(nbytes)
        self.mesh = None if mesh is None else (int(mesh[0]), int(mesh[1]))
        self.advice = None if not advice else str(advice)

    __reduce__ = _reduced


class DataFileError(StepTerrainError, OSError):
    """A file does not exist, cannot be read, is not elevation data, or cannot be written."""


class SchedulerError(StepTerrainError, ConnectionError):
    """A dask scheduler cannot be reached (address, timeout and cause in the message)."""


def caller_stacklevel() -> int:
    """The ``stacklevel`` for a warning issued by the caller of this function that points at the first frame outside
    the stepterrain package: the user's call, however deep the warning sits (a fixed level pointed into the library
    when a public function was reached through another, e.g. load_dem through batch or the CLI)."""
    package = os.path.dirname(os.path.abspath(__file__)) + os.sep  # its subpackage stepterrain.kernels included
    top = __name__.partition(".")[0]
    frame, level = sys._getframe(1), 1
    while frame is not None and (os.path.abspath(frame.f_code.co_filename).startswith(package) or (
            # code the package made at run time ("<string>": a dataclass's __init__, Terrain(kind="grid", ...)),
            # in a module of the package: its warnings pointed at "<string>", not at the line that built it
            frame.f_code.co_filename.startswith("<") and str(frame.f_globals.get("__name__", "")).partition(".")[0]
            == top) or (
            # dataclasses.replace(terrain, ...) calling that __init__: its warnings pointed into dataclasses.py
            frame.f_code.co_name in ("replace", "_replace")
            and frame.f_globals.get("__name__") == "dataclasses")):
        frame, level = frame.f_back, level + 1
    return level


def plain_repr(value: Any) -> str:
    """``repr(value)`` for a message, a NumPy number or bool as the plain one it holds: ``{value!r}`` wrote
    ``np.int64(0)`` and ``np.float64(-1.0)`` (NumPy 2's scalar repr) where a size or interval came from an array."""
    numpy = sys.modules.get("numpy")
    if numpy is not None and isinstance(value, (numpy.number, numpy.bool_)):
        return str(value)
    return repr(value)


def counted(count: int, noun: str, plural: str | None = None, *, grouped: bool = False) -> str:
    """``count`` and ``noun`` for a message: "1 item", "2 items", "1 NaN or infinite value" (``plural`` where adding
    an s is wrong: "vertex", "vertices"); ``grouped``: the count with thousands separators ("1,024 vertices", as
    the CLI's progress lines write counts). Messages said "of 1 items" and "1 NaN or infinite values"."""
    number = f"{count:,}" if grouped else f"{count}"
    return f"{number} {noun if count == 1 else plural or noun + 's'}"
