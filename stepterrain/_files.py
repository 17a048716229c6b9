"""The one check that an input path names an existing regular file, shared by load_dem and read_mesh."""

from __future__ import annotations

from pathlib import Path

from .errors import DataFileError

__all__ = ["require_regular_file"]


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
