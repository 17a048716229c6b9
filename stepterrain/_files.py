"""The path checks shared by the readers and writers: a path argument as a Path (load_dem, save_mesh and
save_image, batch's output folder), an input path naming an existing regular file (load_dem, read_mesh), and the
paths GDAL reads through its virtual file systems (a ``/vsizip/`` path, a URL: :class:`GdalPath`, :func:`gdal_path`,
:func:`local_archive`)."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from .errors import DataFileError, InvalidInputError

__all__ = ["as_path", "refuse_folder_name", "require_regular_file", "gdal_path", "GdalPath", "URL_FILE_SYSTEMS",
           "local_archive"]


def as_path(value: Any, name: str) -> Path:
    """``value`` as a Path, else an InvalidInputError naming the argument ``name``: not a str or path-like."""
    try:
        return Path(os.fspath(value))
    except TypeError as exc:
        raise InvalidInputError(f"{name} must be a str or os.PathLike; got {type(value).__name__}") from exc


def refuse_folder_name(path: str, name: str) -> None:
    """Raise InvalidInputError, naming the argument ``name``, when the output file name ``path`` ends the way only a
    folder's does: in a folder separator (``x.glb/``) or in ``.`` or ``..`` (``x.glb/.``). pathlib drops a trailing
    separator and a ``.`` (``Path("x.glb/") == Path("x.glb")``), so a writer given ``x.glb/``, meant as a folder,
    wrote a file named ``x.glb``. An empty ``path`` is refused too: ``Path("")`` is ``Path(".")``, and the message
    was "cannot write '.'", naming a folder no one gave."""
    if path == "":
        raise InvalidInputError(f"{name} is empty (''); expected a file name")
    separators = tuple(sep for sep in (os.sep, os.altsep) if sep)
    split = re.compile("|".join(map(re.escape, separators)))
    last = split.split(path)[-1]
    ending = path[-1] if path.endswith(separators) else last if last in (".", "..") else None
    if ending is None:
        return
    file = path
    while file.endswith(separators) or split.split(file)[-1] == ".":  # 'x.glb/', 'x.glb/.', 'x.glb//' -> 'x.glb'
        file = file[:-1]
    meant = f"{file!r} to write that file, or " if file and not file.endswith(separators) and ending != ".." else ""
    raise InvalidInputError(f"{name} {path!r} ends in {ending!r}, so it names a folder; expected a file name "
                            f"({meant}the name of a file inside that folder)")


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


#: URL schemes read through GDAL, and the GDAL virtual file system each maps to (as rasterio maps them): an http(s)
#: or ftp URL keeps its whole text after /vsicurl/; a bucket URL (s3://bucket/key) its bucket and key.
URL_FILE_SYSTEMS = {"http": "/vsicurl/", "https": "/vsicurl/", "ftp": "/vsicurl/", "s3": "/vsis3/", "gs": "/vsigs/",
                    "az": "/vsiaz/", "azure": "/vsiaz/", "oss": "/vsioss/", "swift": "/vsiswift/"}
_URL = re.compile(r"([A-Za-z][A-Za-z0-9+.-]+)://(.*)", re.DOTALL)


class GdalPath(type(Path())):  # type: ignore[misc]
    """A path GDAL reads (a ``/vsi...`` virtual file system path, a URL) as a Path of the file it names: ``name``,
    ``suffix`` and ``stem`` are those of the file inside (``/vsizip//data/srtm.zip/N46E007.hgt``: ``N46E007.hgt``;
    a URL's without its query; ``/vsigzip/dem.tif.gz``: ``dem.tif``), while ``str()`` gives the text as given (for
    messages: the URL) and ``os.fspath()`` the GDAL path, exactly (a Path turns the ``//`` of an absolute path
    inside /vsizip/ into one ``/``, a relative path to GDAL). It exists nowhere on the local file system
    (``exists()`` is False), and the paths made from it (``with_suffix``, ``parent``) are GdalPaths of the display
    text without a GDAL path of their own (their ``os.fspath()`` is that text). A copy or a pickle (a dask worker's
    argument) keeps both texts. Made by :func:`gdal_path`."""

    _gdal: str | None = None
    _given: str | None = None

    def __str__(self) -> str:
        return self._given if self._given is not None else super().__str__()

    def __fspath__(self) -> str:
        return self._gdal if self._gdal is not None else super().__fspath__()

    def __repr__(self) -> str:
        return f"GdalPath({str(self)!r})"

    def __reduce__(self) -> tuple[Any, tuple[str, str | None, str | None]]:
        # a Path pickles (and copies) as its parts: the GDAL path and the given text were lost, os.fspath() then the
        # display text (/vsizip//data/a.zip/t.tif read as the relative /vsizip/data/a.zip/t.tif)
        return _restored, (super().__str__(), self._gdal, self._given)


def _restored(display: str, gdal: str | None, given: str | None) -> GdalPath:
    """The GdalPath named ``display`` reading the GDAL path ``gdal``, given as ``given``."""
    path = GdalPath(display)
    path._gdal, path._given = gdal, given
    return path


def gdal_path(text: str) -> GdalPath | None:
    """``text`` as a :class:`GdalPath` when it names a file through a GDAL virtual file system: a path starting with
    ``/vsi`` (``/vsizip/``, ``/vsigzip/``, ``/vsitar/``, ``/vsicurl/``, ``/vsis3/``, ...), kept as given, or a URL of
    one of :data:`URL_FILE_SYSTEMS`'s schemes, mapped to its file system as rasterio maps it (``https://h/dem.tif``:
    ``/vsicurl/https://h/dem.tif``; ``s3://bucket/dem.tif``: ``/vsis3/bucket/dem.tif``); else None (a local path).
    Another URL scheme is refused (a DataFileError naming it and those read), and so is a ``file://`` URL (naming
    the local path to give)."""
    if text.startswith("/vsi"):
        if re.match(r"/vsi\w+/\{.*\}", text):
            # GDAL's braces round an archive's path (/vsizip/{/vsicurl/https://h/a.zip?sig=1}/dem.tif): named by the
            # member after them, not the URL's query; by the archive in them without one. A brace in a URL's query
            # (/vsicurl/https://h/dem.tif?t={a}&x=1) rounds no archive: that is dem.tif, below. A trailing slash
            # (/vsizip/{/data/a.zip}/) names no member: the archive, as without it
            braced, member = text.rsplit("}", 1)
            return _made(text, member if member.strip("/") else braced)
        return _made(text, text.split("/vsicurl/", 1)[-1])  # a URL's own path, for its name
    found = _URL.fullmatch(text)
    if found is None:
        return None
    scheme, rest = found.group(1).lower(), found.group(2)
    if scheme == "file":  # a local file named as a URL: read as a local path it was 'file:/data/dem.tif', "does not
        # exist" (a Path joins the slashes), and GDAL has no file system for it
        from urllib.parse import urlsplit
        from urllib.request import url2pathname

        raise DataFileError(f"cannot read {text!r}: a file:// URL names a local file; give its path, "
                            f"{url2pathname(urlsplit(text).path)!r}")
    system = URL_FILE_SYSTEMS.get(scheme)
    if system is None:
        raise DataFileError(f"cannot read {text!r}: unknown URL scheme {scheme + '://'!r}; expected a local file, a "
                            f"GDAL virtual path (/vsizip/..., /vsicurl/...) or a URL of "
                            f"{', '.join(s + '://' for s in URL_FILE_SYSTEMS)}")
    return _made(system + (text if system == "/vsicurl/" else rest), text, text)


def _made(gdal: str, display: str, given: str | None = None) -> GdalPath:
    """The GdalPath of the GDAL path ``gdal``, named by ``display`` (a URL's path, without its query), ``given`` as
    the user wrote it (``gdal`` if None)."""
    display = _URL.sub(lambda m: m.group(2), display.split("?", 1)[0].split("#", 1)[0])
    if display.lower().endswith(".gz") and "/vsigzip/" in gdal:  # the gzip stream's file: dem.tif
        display = display[:-3]
    return _restored(display or gdal, gdal, gdal if given is None else given)


#: GDAL's archive file systems, whose path names a local archive file first (``/vsizip/<archive>/<member>``).
_ARCHIVES = {"/vsizip/": (".zip", ".kmz", ".ods", ".xlsx"), "/vsitar/": (".tar", ".tgz", ".tar.gz"),
             "/vsigzip/": (".gz",), "/vsi7z/": (".7z",), "/vsirar/": (".rar",)}


def local_archive(file: GdalPath) -> str | None:
    """The local archive file a GDAL path reads from (``/vsizip//data/srtm.zip/N46E007.hgt``: ``/data/srtm.zip``),
    for a file's identity (batch's fingerprint); None for a remote one (a URL, ``/vsizip//vsicurl/...``)."""
    text = os.fspath(file)
    for prefix, extensions in _ARCHIVES.items():
        if not text.startswith(prefix):
            continue
        rest = text[len(prefix):]
        if rest.startswith("{"):  # GDAL's braces around the archive's path: /vsizip/{/vsizip//data/a.zip/b.zip}/c.tif
            end = rest.find("}")
            rest = rest[1:end] if end > 0 else ""
            return None if not rest or rest.startswith("/vsi") else rest  # one reached through another file system
        if rest.startswith("/vsi"):
            return None
        lowered = rest.lower()
        for ext in extensions:
            end = lowered.find(ext + "/") if prefix != "/vsigzip/" else -1
            if end >= 0:
                return rest[:end + len(ext)]
        return rest if any(lowered.endswith(ext) for ext in extensions) else None
    return None
