"""The path checks shared by the readers and writers: a path argument as a Path (load_dem, save_mesh and
save_image, batch's output folder) and an input path naming an existing regular file (load_dem, read_mesh)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .errors import DataFileError, InvalidInputError

__all__ = ["as_path", "require_regular_file"]


def as_path(value: Any, name: str) -> Path:
    """``value`` as a Path, else an InvalidInputError naming the argument ``name``: not a str or path-like."""
    try:
        return Path(os.fspath(value))
    except TypeError as exc:
        raise InvalidInputError(f"{name} must be a str or os.PathLike; got {type(value).__name__}") from exc


def require_regular_file(file: Path, missing: str, irregular: str) -> None:
    """Raise DataFileError unless ``file`` is an existing regular file.

    ``missing`` and ``irregular`` start the two messages ("DEM file", "DEM path"): ``"<missing> '<file>' does not
    exist"`` and ``"<irregular> '<file>' is not a regular file"``. A name too long for the file system (ENAMETOOLONG)
    raised os.stat's bare OSError from exists() / is_file(); it is ``"cannot read '<file>': <reason>"``.
    """
    try:
        exists, regular = file.exists(), file.is_file()
    except OSError as exc:
        raise DataFileError(f"cannot read {str(file)!r}: {exc.strerror or exc}") from exc
    if not exists:
        raise DataFileError(f"{missing} {str(file)!r} does not exist")
    if not regular:
        raise DataFileError(f"{irregular} {str(file)!r} is not a regular file")
