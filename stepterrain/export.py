"""Mesh and image export by file extension, written atomically (temporary file in the target folder + rename).

Shared output room of every capability (papers 000-004): glTF/GLB (flat-shaded, metadata in ``extras``),
OBJ (metadata in comments), PLY (metadata in header comments), STL (no metadata) and 3MF (metadata in a model
metadata element) meshes, and PNG and TIFF images (a GeoTIFF given an ``extent``, through rasterio).

    from stepterrain.export import save_mesh
    save_mesh(mesh, "out/steps.glb", metadata={"interval": 100.0})
"""

from __future__ import annotations

import base64
import contextlib
import contextvars
import copy
import errno
import importlib.util
import io
import json
import math
import os
import queue
import re
import secrets
import shutil
import stat
import string
import struct
import tempfile
import threading
import warnings
import zipfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO
from xml.sax.saxutils import escape as xml_escape

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from ._compaction import check_budget
from ._device import recycled_empty
from ._files import as_path, refuse_folder_name, require_regular_file
from ._signals import signals_held
from ._warning_filters import FILTERS
from .errors import DataFileError, InvalidInputError, MissingDependencyError, caller_stacklevel, counted
from .mesh import check_face_indices, face_outside, mesh_argument
from .terrain import FLOAT32_MAX, as_array, finite_number, real_numbers

__all__ = ["atomic_path", "save_mesh", "scale_for_print", "save_image", "MESH_EXTENSIONS", "add_write_listener"]

#: Mesh file extensions :func:`save_mesh` writes (lower case; matching is case-insensitive).
MESH_EXTENSIONS: tuple[str, ...] = (".glb", ".gltf", ".obj", ".ply", ".stl", ".3mf")

# Arrays or lists with more elements than this are left out of glTF extras (a per-vertex array would
# bloat the JSON header); scalars, strings and short lists go in.
_MAX_EXTRAS_ITEMS = 4096
# Lists and dicts nested deeper than this in metadata are refused (or, in a mesh's own metadata, written as their
# str): a dict holding itself recursed until Python's RecursionError, and so did any very deep nesting.
_MAX_EXTRAS_DEPTH = 64
# glTF accessors are float32: coordinates beyond this magnitude (UTM metres) move into the node translation.
_LOCAL_ORIGIN_THRESHOLD = 65536.0
# Formats that hold triangles only: a mesh of vertices without faces is refused for them (STL has no vertex list;
# a 3MF mesh object needs triangles and a printer has no use for points).
_TRIANGLES_ONLY = (".stl", ".3mf")
# Formats that keep a texture (UVs and an image); the others drop it (see _check_uv).
_TEXTURED = (".glb", ".gltf", ".obj")
# (lowest, highest) vertex coordinate per axis, float64; None for a mesh without vertices (_vertex_bounds).
Bounds = tuple[NDArray[np.float64], NDArray[np.float64]] | None
_OMIT = object()
# Called with each path save_mesh has just written (see add_write_listener).
_WRITE_LISTENERS: list[Callable[[Path], None]] = []
# The files this process wrote that another output could name: save_image's images and a textured OBJ's side files
# (its .mtl and texture images), absolute path -> the output each belongs to (an image itself, a side file its
# OBJ). One output never replaces a file another wrote while that file is there (see _check_owner).
_OWNERS: dict[str, str] = {}
_OWNERS_LOCK = threading.Lock()


def probe_writable(folder: Path) -> OSError | None:
    """Create and remove a file in the existing ``folder``: the error when that fails, else None, its ``strerror``
    the true reason (:func:`unwritable_reason`). (``os.access`` says yes to root on a read-only mount; a real file
    does not.)"""
    try:
        fd, probe = tempfile.mkstemp(prefix=".stepterrain-probe.", dir=folder)
    except OSError as exc:
        return OSError(exc.errno, unwritable_reason(exc, folder), str(folder))
    os.close(fd)
    os.unlink(probe)
    return None


#: File systems the kernel makes up (process, device and control information), which hold no files of ours: /proc
#: refuses a new file with ENOENT ("No such file or directory", of a folder that exists), /sys with EACCES, as root.
_VIRTUAL_FILE_SYSTEMS = frozenset({
    "proc", "sysfs", "cgroup", "cgroup2", "devpts", "debugfs", "tracefs", "securityfs", "pstore", "bpf", "configfs",
    "fusectl", "efivarfs", "binfmt_misc", "nsfs", "mqueue", "rpc_pipefs", "autofs", "selinuxfs"})


def _file_system_type(folder: Path) -> str | None:
    """The type of the file system ``folder`` lies on (``proc``, ``ext4``, ...) from /proc/self/mounts (the longest
    mount point holding it), None where that cannot be read (not Linux)."""
    try:
        with open("/proc/self/mounts", encoding="utf-8", errors="replace") as mounts:
            entries = [line.split()[1:3] for line in mounts if len(line.split()) >= 3]
        where = os.path.realpath(folder)
    except OSError:
        return None
    best, kind = "", None
    for point, fs in entries:
        point = re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), point)  # "\040" is a blank
        inside = where == point or where.startswith(point.rstrip("/") + "/")
        if inside and len(point) >= len(best):
            best, kind = point, fs
    return kind


def unwritable_reason(error: OSError, folder: Path) -> str:
    """Why a file (or a folder) cannot be made in ``folder``, or in its nearest existing parent when it is missing,
    from the ``error`` making it raised, worded true: a virtual file system says what it is (the kernel's error
    there, "No such file or directory" for /proc, which exists, was taken for the reason); an ENOENT of an existing
    folder says that it refuses new entries, an ENOTDIR below a file names the file; other errors keep the system's
    words ("Permission denied", "Read-only file system")."""
    existing = Path(os.path.abspath(folder))
    with contextlib.suppress(OSError):
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
    kind = _file_system_type(existing)
    where = "it" if existing == Path(os.path.abspath(folder)) else repr(str(existing))
    if kind in _VIRTUAL_FILE_SYSTEMS:
        return f"{where} lies on a {kind} file system, made up by the kernel, which holds no files of ours"
    if error.errno == errno.ENOENT and os.path.isdir(existing):
        return f"{where} exists but refuses new entries (the system answered 'No such file or directory')"
    if error.errno == errno.ENOTDIR and existing.exists() and not existing.is_dir():
        return f"{where} is a file, not a folder"
    return str(error.strerror or error)


#: The longest file name (bytes) most file systems hold; a temporary name adds 14 bytes (".", ".XXXXXXXX.tmp").
_NAME_MAX = 255


def _temporary_stem(name: str, reserve: int = 0) -> str:
    """``name`` for :func:`atomic_path`'s temporary ``.<name>.XXXXXXXX.tmp``, cut to fit :data:`_NAME_MAX` bytes: a
    target name of 242 to 255 bytes is valid, but its temporary name was not (ENAMETOOLONG), and the write was
    refused as "cannot write in the output folder". The stem is UTF-8, cut between characters, an undecodable byte of
    ``name`` (``'\\udcf6'`` for a Latin-1 ``\\xf6``) as ``_``: writers that hand the temporary's name to a C library as
    UTF-8 (PIL's TIFF writer, rasterio) raised UnicodeEncodeError for such a name, and for one cut inside a character
    (``os.fsdecode`` of its first bytes ended in a surrogate). ``reserve`` bytes more are left free, for a side file
    named after the temporary (GDAL's ``<temporary>.aux.xml``, see :func:`_save_geotiff`)."""
    text = _utf8_name(name)
    if text != name:
        text = text.replace("\ufffd", "_")
    raw = text.encode("utf-8")
    room = _NAME_MAX - len(".") - len(".XXXXXXXX.tmp") - reserve
    return text if len(raw) <= room else raw[:room].decode("utf-8", "ignore")  # a character cut: dropped


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``, on error it is removed.

    A failed or killed run never leaves a truncated file at ``path``, and an existing ``path`` is kept
    until the new content is complete and flushed to disk (fsync), so not even a crash of the machine loses both
    (a new file, with no old content to lose, is not flushed). A new file gets the usual permissions (0o666 less
    the umask in force, or what the folder's default ACL gives, as ``open()`` makes it); a file replaced keeps its
    own (a private 0o600 file stays private), and its owner and group where the system lets the writer give them
    (root any; another user a group of theirs), as ``open()`` keeps them.

    A ``path`` that is a symbolic link is written through: the temporary file goes beside the file the link
    points to and replaces that file, so the link stays and shows the new content. A dangling link gets its
    target created (missing folders too), and so does a dangling link to a folder on the way; a loop of links is
    refused.

    Raises
    ------
    DataFileError
        The folder cannot be created or written, ``path`` is a folder, a named pipe, a device or a loop of
        symbolic links, an existing file the writer may not write (read-only, as ``open()`` refuses it), or the
        finished file cannot be flushed to disk or moved onto ``path``.
    InvalidInputError
        ``path`` ends the way only a folder's name does (``out.glb/``, ``out/.``): a Path drops the ending, and a
        file ``out.glb`` was written where a folder was meant (see :func:`~stepterrain._files.refuse_folder_name`).
    """
    text = os.fspath(path)
    if isinstance(text, str):
        refuse_folder_name(text, "path")
    target = _link_target(Path(path))
    special = _special_file_kind(target, folders=True)  # one stat of the target for both refusals
    if special == "folder":  # refused before the content is made: os.replace refused it only after (EISDIR)
        raise DataFileError(f"cannot write {str(target)!r}: it is a folder; expected a file name")
    if special is not None:  # os.replace put a regular file in its place: as root, a link to /dev/null replaced it
        raise DataFileError(f"cannot write {str(target)!r}: it is a {special}, not a regular file; expected the "
                            "name of a file (written whole, then renamed into place)")
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.exists():
        try:  # made where symbolic links lead: a dangling link (out -> /data/new) failed "File exists" (mkdir -p's)
            Path(os.path.realpath(folder)).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataFileError(f"cannot create the output folder {str(folder)!r}: "
                                f"{unwritable_reason(exc, folder)}") from exc
    if not folder.is_dir():
        raise DataFileError(f"output folder {str(folder)!r} is not a folder")
    if not os.access(folder, os.W_OK):
        raise DataFileError(f"output folder {str(folder)!r} is not writable")
    _refuse_read_only(target)  # (after the folder: a read-only mount is the folder's matter)
    try:
        tmp_path = _new_temporary(folder, target.name)
    except OSError as exc:  # the true reason: /proc said "No such file or directory" of itself
        raise DataFileError(f"cannot write in the output folder {str(folder)!r}: "
                            f"{unwritable_reason(exc, folder)}") from exc
    try:
        yield tmp_path
        try:  # a replaced file keeps its mode: the umask's widened a private 0o600 file to 0o644
            old: os.stat_result | None = os.stat(target)
        except OSError:
            old = None  # a new file keeps the mode it was made with
        try:
            _flush_if_replacing(tmp_path, old is not None)
            if old is not None:
                _take_owner_and_mode(tmp_path, old)
            together = _TOGETHER.get()
            if together is None:
                os.replace(tmp_path, target)
            else:  # renamed by _replaced_together's end, or removed there (staged within the try: an interrupt
                together.staged.append((tmp_path, target))  # before it left the temporary behind)
        except OSError as exc:
            raise DataFileError(f"cannot write {str(target)!r}: {exc.strerror}") from exc
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


class _Replacements:
    """The files :func:`atomic_path` staged within one :func:`_replaced_together` (or a pyramid's level files,
    :class:`~stepterrain.texture_lod._StagedFiles`): (temporary, target) in the order they are to be renamed, and
    (None, target) for a file to remove with them (:meth:`remove`)."""

    def __init__(self, what: str = "") -> None:
        self.staged: list[tuple[Path | None, Path]] = []
        self.why: dict[Path, str] = {}  # a staged removal's words in an error (see remove)
        self.what = what  # what a target is, in an error ("the pyramid level ")

    def remove(self, target: Path, why: str) -> None:
        """Stage the removal of ``target`` (where there is one then), in its place among the renames: an old file
        that must not stay beside the new ones (a GeoTIFF's ``.aux.xml``). It is renamed aside there, removed once
        all are in place, and put back with the old files on a failure or an interrupt part-way. ``why`` begins the
        error should it not go aside ("cannot remove X, whose ...")."""
        self.staged.append((None, target))
        self.why[target] = why

    def discard(self, start: int = 0) -> None:
        """Remove the temporary files staged from ``start`` on, and drop them and the removals from the set."""
        for tmp, _ in self.staged[start:]:
            if tmp is not None:
                with contextlib.suppress(OSError):
                    tmp.unlink()
        del self.staged[start:]

    def commit(self) -> None:
        """Rename each temporary file onto its target, in order; on a failure (or an interrupt) part-way, the targets
        already replaced get their old files back (kept under a hard link, their own inode: content, mode, owner)
        and those that did not exist are removed, before the error goes on.

        Ctrl-C, SIGTERM and SIGHUP are held back meanwhile (:func:`~stepterrain._signals.signals_held`, the main
        thread's; of several files): one that came as a rename ran raised KeyboardInterrupt as ``os.replace``
        returned, that file, replaced, was taken for one not replaced (its backup removed, not put back) and the new
        file stayed beside the old ones put back. It goes to its handler once all are in place (or all put back)."""
        with signals_held() if len(self.staged) > 1 else contextlib.nullcontext():
            self._rename_all()

    def _rename_all(self) -> None:
        done: list[tuple[Path, Path | None]] = []  # target, its old file's backup (None: there was none)
        pending = list(self.staged)
        interrupt: BaseException | None = None  # raised as the last rename returned: all are in place
        try:
            while pending:
                tmp, target = pending[0]
                if tmp is None:  # a removal: set aside (put back by itself if that fails), kept for the rollback
                    _set_aside(target, self.why[target], done)  # recorded in done as it goes aside
                    pending.pop(0)
                    continue
                # the last one needs no backup: its failure replaced nothing, and once it is in place all are
                backup = _backup(target) if len(pending) > 1 else None
                try:
                    os.replace(tmp, target)
                except BaseException as exc:
                    # an interrupt raised as os.replace returned (a second Ctrl-C, which signals_held lets through):
                    # the file is in place, put back with the others (the last one: all are in place)
                    if not isinstance(exc, OSError) and not os.path.lexists(tmp):
                        if len(pending) == 1:
                            interrupt = exc
                            pending.pop(0)
                            break
                        pending.pop(0)
                        done.append((target, backup))
                        raise
                    if backup is not None:  # (an interrupt before the rename: the backup is of a file not replaced)
                        with contextlib.suppress(OSError):
                            backup.unlink()
                    if isinstance(exc, OSError):
                        raise DataFileError(f"cannot write {self.what}{str(target)!r}: {exc.strerror}") from exc
                    raise
                pending.pop(0)
                done.append((target, backup))
        except BaseException as exc:
            if pending or isinstance(exc, Exception):
                for tmp, _ in pending:
                    if tmp is not None:
                        with contextlib.suppress(OSError):
                            tmp.unlink()
                lost = _roll_back(done)
                if lost and isinstance(exc, DataFileError):
                    raise DataFileError(f"{exc}; and then {lost}") from exc
                raise
            interrupt = exc  # all in place (the last one has no backup to put back): raised once settled
        for _, backup in done:
            if backup is not None:
                with contextlib.suppress(OSError):
                    backup.unlink()
        if interrupt is not None:
            raise interrupt


def _backup(target: Path) -> Path | None:
    """A second name (``.<name>.XXXXXXXX.tmp`` beside it) for the existing file ``target``, by which
    :class:`_Replacements` puts it back: a hard link (the file itself), or where the file system has none, a copy
    with its mode and owner; None where there is no ``target``."""
    try:
        old = os.stat(target)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise DataFileError(f"cannot write {str(target)!r}: {exc.strerror}") from exc
    try:
        for _ in range(100):
            backup = target.parent / f".{_temporary_stem(target.name)}.{secrets.token_hex(4)}.tmp"
            try:
                os.link(target, backup)
                return backup
            except FileExistsError:
                continue
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.EXDEV, errno.EMLINK, errno.ENOTSUP, errno.ENOSYS,
                                     getattr(errno, "EOPNOTSUPP", errno.ENOTSUP)):
                    raise
                break  # no hard links here (FAT, some network shares): a copy
        backup = _new_temporary(target.parent, target.name)
        try:
            shutil.copyfile(target, backup)
            _take_owner_and_mode(backup, old)
        except BaseException:
            with contextlib.suppress(OSError):
                backup.unlink()
            raise
        return backup
    except OSError as exc:
        raise DataFileError(f"cannot write {str(target)!r}: its old file could not be kept to put back if a file "
                            f"written with it failed: {exc.strerror}") from exc


def _roll_back(done: list[tuple[Path, Path | None]]) -> str:
    """Put back the old files of the targets :class:`_Replacements` replaced (``done``: target, backup), last first;
    remove those that were new. Returns what could not be undone (the backup's name, where the old file is), or ""."""
    lost = []
    for target, backup in reversed(done):
        try:
            if backup is None:
                os.unlink(target)
            else:
                os.replace(backup, target)
        except OSError as exc:
            where = f"its old content is in {str(backup)!r}" if backup is not None else "it is the new file"
            lost.append(f"{str(target)!r} could not be put back ({exc.strerror}; {where})")
    return "; ".join(lost)


#: The :class:`_Replacements` :func:`atomic_path` adds its file to, within :func:`_replaced_together`.
_TOGETHER: contextvars.ContextVar[_Replacements | None] = contextvars.ContextVar("stepterrain_together", default=None)


@contextlib.contextmanager
def _replaced_together() -> Iterator[_Replacements]:
    """Within (this thread or task): :func:`atomic_path` stages its file (written, flushed, given the old file's mode
    and owner) and the block's end renames them all into place, in the order their ``atomic_path`` blocks ended; an
    error in the block removes them all. A rename that fails part-way puts back the files renamed before it (see
    :meth:`_Replacements.commit`): the files of one output (a textured OBJ's ``.obj``, ``.mtl`` and images) are then
    all new or all old, where a failure of the second rename left the new texture beside the old OBJ. (A crash of
    the machine during the renames can still leave a mix: each rename is atomic, the set is not.) Nested: the
    outermost block's end renames; an error in an inner block removes the files staged within it (and its staged
    removals) from the set, so an outer block that goes on after catching it does not rename them into place."""
    outer = _TOGETHER.get()
    if outer is not None:
        start = len(outer.staged)
        try:
            yield outer
        except BaseException:
            outer.discard(start)
            raise
        return
    together = _Replacements()
    token = _TOGETHER.set(together)
    try:
        yield together
    except BaseException:
        _TOGETHER.reset(token)
        together.discard()
        raise
    _TOGETHER.reset(token)
    together.commit()


def _refuse_read_only(target: Path) -> None:
    """Refuse to replace an existing file the writer may not write (``os.access``: its permission bits, ACL or
    read-only attribute), as ``open(path, "w")`` refuses it. The rename into place needs only the folder's
    permission: a file a user had write-protected (``chmod a-w``) to keep a delivered mesh was replaced without a
    word. (Root may write any file, and replaces it as ``open()`` would.)"""
    if os.path.exists(target) and not os.access(target, os.W_OK):
        raise DataFileError(f"cannot write {str(target)!r}: the file exists and is read-only (write-protected for "
                            "this user); make it writable (chmod u+w) to replace it, or choose another name")


def _take_owner_and_mode(path: Path, old: os.stat_result) -> None:
    """Give ``path`` the owner, group (:func:`_keep_owner`) and mode of the file ``old`` describes, as far as the
    system lets the writer: what is refused stays as it is."""
    with contextlib.suppress(OSError):
        _keep_owner(path, old)  # before chmod: a change of owner clears set-id bits
    with contextlib.suppress(OSError):
        os.chmod(path, stat.S_IMODE(old.st_mode))


def _keep_owner(path: Path, old: os.stat_result) -> None:
    """Give the new file ``path`` the owner and group of the file it replaces (``old``), as far as the system allows:
    root (a container writing into a user's folder) replaced a user's file with one of root's, which the user could
    then no longer write, and a file shared through its group went to the writer's own group, its members locked
    out (``open(path, "w")`` keeps both). Another user can only give a group of theirs; what is refused stays."""
    if not hasattr(os, "chown"):
        return
    new = os.stat(path)
    if (new.st_uid, new.st_gid) == (old.st_uid, old.st_gid):
        return
    try:
        os.chown(path, old.st_uid, old.st_gid)
    except PermissionError:  # not root: the group alone, where the writer belongs to it
        os.chown(path, -1, old.st_gid)


#: Whether :func:`atomic_path` flushes a file it replaces (see :func:`replacing_without_flush`).
_FLUSH_REPLACED: contextvars.ContextVar[bool] = contextvars.ContextVar("stepterrain_flush_replaced", default=True)


@contextlib.contextmanager
def replacing_without_flush() -> Iterator[None]:
    """Within (this thread or task): :func:`atomic_path` replaces a file without flushing the new content first.
    For writes whose loss in a crash is noticed and redone: batch's outputs, whose manifest records each file's size
    (an emptied one is redone by the next run); flushing every replaced tile doubled a rerun of many small tiles
    (``--no-resume``: 816 tiles of 32 cells, 11 s of 22 s). The replacement stays atomic."""
    token = _FLUSH_REPLACED.set(False)
    try:
        yield
    finally:
        _FLUSH_REPLACED.reset(token)


def _flush_if_replacing(tmp: Path, replaces: bool) -> None:
    """fsync ``tmp`` where it ``replaces`` an existing file, unless within :func:`replacing_without_flush`: the rule
    of :func:`atomic_path`, and of the OBJ writer before its side files replace theirs."""
    if replaces and _FLUSH_REPLACED.get():
        _flush_to_disk(tmp)


def _flush_to_disk(path: Path) -> None:
    """fsync ``path``'s content, before it is renamed over an existing file: renamed from the page cache, a crash
    (power loss) right after could leave the name with an empty file (XFS; ext4 flushes a rename over a file
    itself), the old content gone and the new one never written. A new file, which has no old content to lose, is
    not flushed: about 5-10 ms a file here, a batch of small tiles took twice as long. A file system that cannot
    flush (EINVAL, ENOTSUP, ENOSYS) is not a write error; a failed flush (EIO, ENOSPC, EDQUOT) is."""
    fd = os.open(path, os.O_RDONLY if os.name == "posix" else os.O_RDWR)  # Windows' fsync needs a writeable handle
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in _NO_FLUSH:
            raise
    finally:
        os.close(fd)


#: fsync's errors that mean "this file system does not flush", not "the data were lost".
_NO_FLUSH = frozenset(code for code in (errno.EINVAL, errno.ENOTSUP, getattr(errno, "EOPNOTSUPP", None), errno.ENOSYS)
                      if code is not None)


#: How a temporary file is opened: a new name only, never through a symbolic link, not inherited by child processes.
_TEMPORARY_FLAGS = (os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
                    | getattr(os, "O_BINARY", 0))


def _new_temporary(folder: Path, name: str, reserve: int = 0) -> Path:
    """A new empty file ``.<name>.XXXXXXXX.tmp`` (8 random characters) in ``folder``, made as ``open()`` makes a file:
    0o666 less the umask in force, or what the folder's default ACL gives. (mkstemp's 0o600 widened to the umask's
    mode, read once per process, kept the first write's umask: after ``os.umask(0o077)`` new files still came out
    0o644.) ``O_EXCL`` makes two processes writing the same target take different names. ``name`` is cut to leave
    ``reserve`` bytes free (see :func:`_temporary_stem`)."""
    stem = _temporary_stem(name, reserve)
    for _ in range(100):
        tmp = folder / f".{stem}.{secrets.token_hex(4)}.tmp"
        try:
            fd = os.open(tmp, _TEMPORARY_FLAGS, 0o666)
        except FileExistsError:
            continue
        try:
            os.close(fd)
        except OSError:  # (a network file system's deferred error): the empty file made here is not left behind
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary file name", str(folder))


def _special_file_kind(path: Path, folders: bool = False) -> str | None:
    """What ``path`` is when it exists and is neither a regular file nor a folder (a named pipe, a device, a
    socket), else None; with ``folders``, "folder" for a folder too (one stat for both checks)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    if folders and stat.S_ISDIR(mode):
        return "folder"
    kinds = ((stat.S_ISFIFO, "named pipe"), (stat.S_ISCHR, "character device"), (stat.S_ISBLK, "block device"),
             (stat.S_ISSOCK, "socket"))
    return next((kind for test, kind in kinds if test(mode)), None)


def _link_target(path: Path) -> Path:
    """``path``, or the file it names through symbolic links (relative links resolved from their own folder),
    so :func:`atomic_path` replaces that file instead of the link. os.replace onto a link replaced the link
    itself with a regular file: the file it pointed to kept the old content."""
    try:
        if not path.is_symlink():
            return path
    except OSError as exc:  # a name too long for the file system (ENAMETOOLONG) went out as a bare OSError
        raise DataFileError(f"cannot write {str(path)!r}: {exc.strerror}") from exc
    resolved = Path(os.path.realpath(path))
    if resolved.is_symlink():  # realpath stops at a link it met before: a loop, which has no file to replace
        raise DataFileError(f"cannot write {str(path)!r}: it is a symbolic link in a loop ({str(resolved)!r})")
    return resolved


def save_mesh(
    mesh: trimesh.Trimesh,
    path: str | os.PathLike[str],
    *,
    metadata: Mapping[str, Any] | None = None,
    shared_bounds: ArrayLike | None = None,
    origin: ArrayLike | None = None,
) -> Path:
    """Write a mesh to ``path`` in the format its extension names, atomically.

    Parameters
    ----------
    mesh : trimesh.Trimesh or pyvista.PolyData
        Any mesh; it is not modified. A PolyData of triangles (``grid.stepterrain.stepped``'s) is written as its Trimesh
        (:func:`~stepterrain.pyvista_accessor.from_polydata`: colours, level/wall, metadata kept). ``face_attributes``
        (e.g. ``level``, ``wall`` of :func:`~stepterrain.stepped`) and ``vertex_attributes`` (numeric (N,) or (N, k)
        arrays) are kept by ``.ply`` only, as properties of its face and vertex elements (a bool as uchar 0/1, named
        in a header comment so that :func:`read_mesh` gives it back as bool; a 64-bit integer as int or uint when
        it fits 32 bits, else as double, with a warning when that rounds values beyond 2**53; one of the wrong length
        is refused, one that is no numbers, text say, left out with a warning); glTF, OBJ, STL and 3MF drop them.
        Vertex colours (RGBA bytes) are kept by ``.glb``/``.gltf``, ``.ply`` and ``.3mf``, by ``.obj`` without their
        alpha (its ``v x y z r g b`` lines hold RGB), and dropped by ``.stl``. Face colours are kept by ``.ply``
        (the face element's red, green, blue, alpha) and ``.3mf`` (each triangle's colour); ``.glb``/``.gltf`` and
        ``.obj`` have no per-face colour and store each vertex as the mean of its faces' colours (call
        ``mesh.unmerge_vertices()`` first to keep them exact), and ``.stl`` drops them. A texture (UVs and an image) is
        kept by ``.glb``/``.gltf`` and ``.obj`` (with its ``.mtl`` and image) and dropped by the others.
    path : str or path-like
        Target file; missing folders are created. Extensions: ``.glb``, ``.gltf`` (one self-contained
        file, buffers embedded as base64 data URIs), ``.obj`` (coordinates and UVs exact: each written as the
        shortest text that reads back as the same float64), ``.ply`` (binary; float64 coordinates, float32 where
        that holds every vertex exactly), ``.stl`` (binary; a
        triangle with two corners on one float32 position, of no area, is left out: the walls of zero height of a
        solid at γ = 0, which a reader merging corners by position would fold onto their neighbours' edges),
        ``.3mf`` (exact coordinates, in the unit it declares: the one ``metadata["units"]`` names, a globe's
        metres, scale_for_print's millimetres; else metres for a mesh stepterrain made, whose coordinates are metres
        (its metadata's ``generator``, ``crs`` or ``source`` shows it: a stepped terrain, a close-up), as the same
        mesh read back from a .glb declares them; else millimetres, 3MF's default, for a foreign unitless mesh (an
        STL's); a print's millimetres come from scale_for_print (``steps --print-size``); vertex or face colours as
        a colour group: a colour 3D print keeps its tints; a triangle naming one vertex twice, of no area, is left
        out, as 3MF requires).
    metadata : mapping, optional
        Merged over ``mesh.metadata`` and stored in the glTF mesh ``extras`` and, as JSON, in a ``.ply``'s header
        (``comment stepterrain-metadata {...}`` lines; see Notes), at the top of an ``.obj`` (``# stepterrain-metadata
        {...}`` comment lines, split as PLY's) and in a ``.3mf``'s model (``<metadata name="stepterrain:metadata"
        preserve="1">{...}</metadata>``, the namespace ``urn:stepterrain:3mf:metadata`` declared on the model), all
        of which :func:`read_mesh` gives back; ``.stl`` has no place for it and drops it (a GIS user's crs, source and
        levels: write another format to keep them).
        JSON values: str, number, bool, None, and lists (or tuples) and dicts of those with string keys; numpy
        scalars and arrays become numbers and lists.
    shared_bounds : (2, 3) array_like, optional
        The lowest and highest corner (x, y, z) of a set of meshes written one by one that share vertices (tiles
        of one raster, as :func:`~stepterrain.batch.batch` writes them). How coordinates are stored is then
        decided by these, the same for every mesh of the set, instead of by the mesh's own bounds: glTF's node
        translation (the floor of their centre) and PLY's float64 beyond 65536 (below it, a PLY is float32 where
        float32 holds every vertex exactly, else float64). A vertex the meshes share is then stored identically in
        each (or, in PLY, read back identically), so they weld exactly. Need not contain the mesh. By default the
        shared bounds the mesh records (``metadata["shared_bounds"]``, which :meth:`~stepterrain.globe.Globe.mesh`
        sets on its six ``per_face`` meshes) when they hold all its vertices (not for a mesh moved or scaled since)
        and its float32 positions round by them at most twice as far as by its own bounds (not for a piece cut
        from such a mesh, ``submesh``, which stored about the whole globe's centre rounded 25 to 1000 times worse),
        or it is the member as made, its vertex and face counts and bounds those it records
        (``metadata["whole_part"]``, which Globe.mesh sets on each of its six: one a view culled to a few triangles
        keeps the set's frame, and its seams stay welded), its bounds exactly as its glTF reads them back too (saved
        again, it is stored as the first time).
    origin : (3,) array_like, optional
        The point (x, y, z) a ``.glb``/``.gltf`` stores its float32 positions relative to, floored to whole units:
        the node translation, in place of the one ``shared_bounds`` or the mesh's bounds give (the floor of their
        centre beyond 65536). Each vertex is stored within float32's rounding of its distance from it (2^-24
        relative), so give the eye of a close view of a globe: the vertices near the eye are then stored as
        finely as the view shows them, where the centre of a view's mesh, which spans thousands of km (the coarse
        triangles at its border and on the far side), moved those under an eye 100 m up by 0.3 m. By default the
        eye a view's mesh records (``metadata["eye"]``, which :meth:`~stepterrain.globe.Globe.mesh` sets with a
        camera) when it lies within one diagonal of the mesh's bounds, or of the shared bounds it records and is
        stored by (not for a mesh scaled or moved far from it since, nor a piece cut from one), and no
        ``shared_bounds`` are given. Ignored by the other formats,
        which store coordinates as they are.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InvalidInputError
        ``mesh`` is not a ``trimesh.Trimesh``, has non-finite vertices or faces indexing outside them, has
        coordinates beyond float32 for a format that stores float32 (STL; glTF relative to its centre or
        ``origin``), ``shared_bounds`` are not finite (2, 3) corners or ``origin`` not 3 finite numbers, would make
        a ``.glb`` over 4 GiB (its lengths are 32-bit; the message names the formats that hold it), has for
        ``.ply`` a numeric ``face_attributes`` or ``vertex_attributes`` array not of one value (or row) per face or
        vertex (trimesh keeps them as they were when ``mesh.faces`` is set), the
        extension is unknown (the message lists the supported ones), has vertices but no faces for ``.stl`` or
        ``.3mf`` (which hold triangles only), or ``metadata`` holds a value that is not
        JSON (a set, bytes, an object; the message names its key) or a key that is not a string, or a texture
        written (``.glb``, ``.gltf``, ``.obj``) has texture coordinates that are not one finite (u, v) per vertex, an
        image without texture coordinates, an image given as an array that is not (H, W), (H, W, 3) or (H, W, 4)
        uint8, a palette image whose palette lacks colours its pixels use (``Image.new("P", ...)``'s is empty), or
        an image of no pixels.
    DataFileError
        The target folder cannot be created or written, or a textured OBJ's side file would replace another
        output this process wrote (see Notes).
    OutputTooLargeError
        Writing the mesh would take more memory than the memory budget (:func:`stepterrain.set_memory_budget`):
        beyond the mesh, about 24 bytes a vertex and 40 a face for ``.glb`` (``.gltf`` 64 and 176, ``.obj`` 16 and 48,
        ``.ply`` 40 and 144, ``.stl`` 8 and 352, ``.3mf`` 4 and 28; face colours add up to 400 a face, a texture's
        UVs up to 96 a vertex), checked before any work.

    Warns
    -----
    UserWarning
        ``.stl`` stores float32 coordinates (the format has no other type) and they would move some vertex by
        more than 1e-3 in the mesh's units (1 mm for metres: UTM coordinates round by up to 0.5 m, the embedded
        DEM's by 0.125 m, a whole globe's by 0.25 m); the file is written and the message says by how much and which
        formats keep float64.
        Also when float32 puts distinct vertices of a watertight mesh on one position so that a reader merging
        ``.stl`` corners by position (slicers, ``trimesh.load``) reads it back open (a solid's copies of a node where
        two nodata holes touch, left on the node, or its walls' corners within float32 rounding of a node or of each
        other, on a grid too fine for its coordinates' float32 steps, as a 1 m grid at UTM northings): the file is
        written and the message says how many edges and what keeps it watertight (the command line leaves out the
        advice only Python can follow: stepping the terrain in local coordinates).

    Notes
    -----
    A mesh without vertices and faces (a view that sees nothing, a tile of sea) writes a valid empty file in
    every format (glTF: a node without a mesh, its ``extras`` holding the metadata; STL: zero triangles; 3MF: an
    object without vertices), which reads back as an empty mesh. A mesh of vertices without faces (points) is kept
    as points by ``.glb``/``.gltf`` (a points primitive), ``.obj`` (``v`` lines) and ``.ply`` (the vertex
    element), which read back as a point cloud; ``.stl`` and ``.3mf`` hold triangles only and refuse it.

    glTF/GLB files are y-up, as glTF 2.0 §3.4 requires: the positions are stored as the mesh holds them, z up, under a
    node turning them -90 degrees about x (rotation quaternion (-sqrt(0.5), 0, 0, sqrt(0.5)); a textured mesh, which
    trimesh's writer writes, the same turn as the node's matrix), so that the world coordinates are (x, z, -y): heights
    along +Y, north (+y) along -Z, and Blender, three.js and model-viewer show a terrain (a globe's pole axis) upright.
    :func:`read_mesh` turns them back z-up exactly; ``trimesh.load`` gives the y-up world.
    glTF/GLB files carry no vertex normals, so viewers shade faces flat (glTF 2.0 §3.7.2.1) and stair edges
    stay crisp. Every primitive has a matte material (metallicFactor 0, roughnessFactor 1, white baseColorFactor,
    double-sided; alphaMode BLEND when some vertex alpha is below 255, as a close-up's anchors, else OPAQUE):
    without one, viewers used glTF's default, metallic 1 (§3.9.6), and showed the terrain as dark metal. A texture
    given as an image (``TextureVisuals(uv=..., image=...)``) is written at full brightness with that material; a
    ``PBRMaterial`` keeps what it sets (an unset metallicFactor becomes 0). A texture's alphaMode (unless its
    ``PBRMaterial`` sets one) follows its alpha: OPAQUE when every texel is opaque, MASK (alphaCutoff 0.5) when
    alpha is only 0 and 255 (a nodata hole: the mesh still writes depth, so terraces hide each other), BLEND when
    some texel is partly transparent or the material's base colour (baseColorFactor, a plain material's diffuse) has
    an alpha below 1, which multiplies every texel's. A texture image opened from a JPEG file
    (``Image.open("photo.jpg")``) is embedded (and an OBJ's side image written) as that file's bytes, unchanged,
    while its pixels are still the file's (and it has no EXIF turn); one changed since, or decoded from bytes, is
    encoded as JPEG at quality 95 with full-resolution chroma (off by a few levels at most; Pillow's default, 75 with
    4:2:0, by up to 119). Other textures are lossless PNG. Vertex colours (sRGB bytes, as matplotlib colormaps
    and images give them) are stored as glTF's ``COLOR_0`` requires, linear (float32; alpha as
    it is): a viewer shows the colours of the other formats and of the renders. trimesh's reader, meeting the
    material, makes a ``TextureVisuals`` without UVs and keeps the linear values only as its
    ``vertex_attributes["color"]`` of a scene's geometry (``force="mesh"`` drops them); :func:`read_mesh` gives
    the mesh back with its vertex colours, the sRGB bytes written (a plain mesh without colours).
    Their extras hold JSON values only: numpy scalars become numbers, short arrays lists,
    non-finite floats ``null`` (JSON has no NaN or Infinity), paths their ``str``; arrays longer than 4096
    elements and keys starting with ``_`` are left out. Other values of ``metadata`` are refused; those already
    in ``mesh.metadata`` (put there by a loader or other code) are written as their ``str``. A ``.ply`` holds the
    same values as one compact JSON object (ASCII, no whitespace: spaces in strings as ``\\u0020``) on header lines
    ``comment stepterrain-metadata <text>``, split into pieces of at most 400 characters joined back in order (PLY
    readers read header lines into fixed buffers: MeshLab's of 512 bytes, VTK's of 4096); usually one line. An ``.obj``
    holds the same pieces on comment lines ``# stepterrain-metadata <text>`` after its first line (no piece ends in
    a backslash, which would continue the line), a ``.3mf`` the whole text in its model's ``stepterrain:metadata``
    element. Readers that do not know them skip comments and other namespaces' metadata (lib3mf reads the 3MF in
    strict mode without a warning); :func:`read_mesh` gives it back as the mesh's metadata. glTF accessors
    are float32, so when coordinates exceed 65536 (UTM metres, a globe) the vertices are stored relative to a node
    translation (float64 in the JSON: the floor of the centre of the bounds, (ox, oz, -oy) in the turned world frame)
    and loaders that apply the scene graph
    get world coordinates back, each within float32's rounding of its distance from that centre (2^-24 relative:
    0.03 mm on a 1 km tile, 0.25 m on a whole globe), or from ``origin`` when given, or the eye a view's mesh
    records (then the translation, at any magnitude); ``.ply``, ``.obj`` and ``.3mf`` keep float64. Textured OBJ
    meshes also write ``<stem>.mtl`` and their images ``<stem>_<material>.png`` (``.jpeg`` for an image opened from
    a JPEG) beside ``path`` (whitespace in the stem becomes ``_``: OBJ and MTL readers split file names on it; an
    image with transparent texels is also the MTL's dissolve, ``map_d -imfchan m``; its ``Kd`` is white and ``Ks``
    black unless the material sets a base colour, so the texture shows at full brightness, matte; a base colour's
    alpha below 1 is its dissolve ``d``), each atomically, once the OBJ itself is complete, and renamed into place
    just before it: a failure of one of these renames (or an interrupt) puts back the files renamed before it (the
    old files themselves, or none where there were none), so the OBJ and its side files are all new or all old
    (a crash of the machine part-way can still leave a mix); one that would
    replace an image :func:`save_image` wrote in this process, or a side file of another OBJ, is refused (a
    DataFileError) before any is written. The file appears complete or not at all: the mesh is
    written to a temporary file in the same folder and renamed, and an existing ``path`` is untouched
    when anything fails. A ``path`` that is a symbolic link is written through (see :func:`atomic_path`): the
    link stays and the file it points to gets the new content (a textured OBJ's side files go beside that file,
    named after its stem).

    Examples
    --------
    >>> import pathlib, tempfile, trimesh
    >>> from stepterrain.export import save_mesh
    >>> out = save_mesh(trimesh.creation.box(), pathlib.Path(tempfile.mkdtemp()) / "box.stl")
    >>> len(trimesh.load(out).faces)
    12
    """
    mesh = mesh_argument(mesh)  # a pyvista PolyData (grid.stepterrain.stepped's) as its Trimesh
    extras = json_metadata(metadata)
    target = _target(path)
    ext = target.suffix.lower()
    vertices = np.asarray(mesh.vertices)
    bounds = _vertex_bounds(vertices)
    if bounds is not None and not (np.isfinite(bounds[0]).all() and np.isfinite(bounds[1]).all()):
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))  # on the error path only: the bounds said so
        raise InvalidInputError(
            f"mesh vertices must be finite to be written; got {bad.size} of "
            f"{counted(len(vertices), 'vertex', 'vertices')} with NaN or inf "
            f"(vertex {bad[0]} at {np.asarray(vertices[bad[0]], dtype=np.float64).tolist()})"
        )
    writer = _WRITERS.get(ext)
    if writer is None:
        raise InvalidInputError(
            f"cannot write {str(target)!r}: unknown mesh extension {target.suffix or '(none)'!r}; "
            f"supported: {', '.join(MESH_EXTENSIONS)}"
        )
    # faces outside the vertices (process=False meshes keep them): every writer put them in the file as they were (a
    # -1 became 4294967295 in glTF), except STL's, which raised trimesh's IndexError
    check_face_indices(mesh.faces, len(vertices), "mesh faces")
    if ext in _TEXTURED:
        _check_uv(mesh, ext, target)
    if ext == ".ply":  # the format that keeps them: one of the wrong length was left out without a word
        _check_ply_attributes(mesh, target)
    if len(mesh.faces) == 0 and len(vertices) and ext in _TRIANGLES_ONLY:
        raise InvalidInputError(
            f"cannot write {str(target)!r}: mesh has {counted(len(vertices), 'vertex', 'vertices')} but no faces, and "
            f"{ext} stores triangles only (the points would be lost); write .ply, .obj, .glb or .gltf to keep them"
        )
    # how coordinates are stored: a set's shared bounds (given, or recorded by the mesh), or the mesh's own
    made = None if shared_bounds is not None else _as_made(mesh.metadata, extras, mesh, bounds)
    recorded = None if shared_bounds is not None else \
        _recorded_bounds(mesh.metadata, extras, made if made is not None else bounds)  # as made: read back, rounded
    if recorded is not None and made is None:  # a culled member keeps it
        recorded = _no_coarser(recorded, bounds)  # not a piece cut from a member
    frame = _shared_bounds(shared_bounds) or recorded or bounds
    anchor = _origin_argument(origin) if origin is not None or shared_bounds is not None else \
        _recorded_eye(mesh.metadata, extras, recorded or bounds)  # a set's shared bounds store shared vertices alike
    _check_float32_reach(bounds, ext, target, frame, anchor)
    if ext == ".glb":
        _check_glb_size(mesh, target)
    _check_write_budget(mesh, ext, target)
    prepared = _prepared_mesh(mesh, extras)
    if ext in _TEXTURED and prepared.visual.kind == "texture":
        _pil_textures(getattr(prepared.visual, "material", None))  # before any folder or file is made
        if ext in (".glb", ".gltf"):  # its sampler's wrap (_sampler_postprocessor): a bad one was refused in the
            texture_wrap(getattr(prepared.visual, "material", None))  # writer, after atomic_path made the folders
    # a textured OBJ's side files (.mtl, images) and the OBJ itself go into place together, all or none of them
    with _replaced_together(), atomic_path(target) as tmp:
        try:
            if ext in (".glb", ".gltf"):
                writer(prepared, tmp, target, bounds, frame, anchor)
            else:
                writer(prepared, tmp, target, bounds, frame)
        except OSError as exc:
            if isinstance(exc, DataFileError):
                raise
            raise DataFileError(f"cannot write {str(target)!r}: {exc}") from exc
    for listener in tuple(_WRITE_LISTENERS):
        listener(target)
    return target


#: Keys of a mesh's metadata that hold world coordinates (:func:`save_mesh`'s recorded frame and eye, the CRS they are
#: in): :func:`scale_for_print` leaves them out of its copy, whose coordinates are millimetres from its own corner.
_WORLD_METADATA = ("shared_bounds", "eye", "crs", "floor")


def scale_for_print(mesh: trimesh.Trimesh, size: float, *, z_scale: float = 1.0) -> trimesh.Trimesh:
    """A copy of ``mesh`` scaled for a 3D print: its longer horizontal side ``size`` long (millimetres, the unit STL
    readers and slicers take and 3MF declares), its lowest corner (x, y, z) at the origin (a solid's base on z = 0),
    its heights exaggerated ``z_scale`` times beyond the common scale.

    A stepped solid of a UTM DEM (``stepped(dem, solid=True)``) is in metres at its place on the globe: a slicer read
    the embedded DEM's ``.stl`` (metres taken as millimetres) as a print 36 m wide, 3.8 km from its bed, and STL's
    float32 moved its vertices by up to 0.125 m there. Scaled, its coordinates lie within ``size`` of 0, where float32
    holds them to about 1e-5 mm. Each vertex (x, y, z) becomes ``((x - x0) s, (y - y0) s, (z - z0) s z_scale)`` with ``s
    = size / max(x1 - x0, y1 - y0)`` over the bounds (x0, y0, z0)-(x1, y1, z1) of the vertices its faces use (as
    ``mesh.bounds``; a vertex of no face is moved alike but sets no bound), in float64: the faces, their winding (all
    factors positive: no mirror) and hence watertightness are kept, and the volume is scaled by ``s³ z_scale``. Vertex
    and face colours, face attributes (``level``, ``wall``) and a texture are kept. The metadata is kept less what holds
    world coordinates (``crs``, ``floor``, a recorded ``shared_bounds`` and ``eye``), with ``print`` added: ``{"size":
    size, "scale": s, "z_scale": z_scale, "origin": [x0, y0, z0]}``, so that ``x = x' / s + x0`` (and ``z = z' / (s
    z_scale) + z0``) gives the world coordinates back, and ``units`` (trimesh's) is ``"millimeters"``. ``mesh`` itself
    is not modified.

    Parameters
    ----------
    mesh : trimesh.Trimesh or pyvista.PolyData
        The mesh to scale (a PolyData of triangles as :func:`save_mesh` takes it), with at least one face.
    size : float
        The length of the model's longer horizontal side (x or y), in the print's unit (millimetres).
    z_scale : float, optional
        Vertical exaggeration on top of the common scale (default 1: true proportions).

    Returns
    -------
    trimesh.Trimesh
        The scaled copy.

    Raises
    ------
    InvalidInputError
        ``size`` or ``z_scale`` is not a positive finite number, the scaled model would not fit in float32 (STL's
        coordinates) or would have coordinates below its least normal number (about 1.2e-38), or ``mesh`` is not a
        mesh, has no faces, faces indexing beyond its vertices, non-finite vertices or no horizontal extent (all its
        vertices on one vertical line).

    Examples
    --------
    >>> import stepterrain as st
    >>> from stepterrain.export import scale_for_print
    >>> solid = st.stepped(st.sample_dem().crop((380000, 381000, 3790000, 3790500)), interval=100.0, solid=True)
    >>> model = scale_for_print(solid, 150.0)
    >>> [round(float(v), 6) for v in model.extents[:2]], model.is_watertight
    ([150.0, 70.3125], True)
    """
    return _scaled_for_print(mesh_argument(mesh), size, z_scale, copy=True)


#: float32's least normal number (about 1.2e-38): a print model's coordinates below it underflow in STL and glTF.
_FLOAT32_TINY = float(np.finfo(np.float32).tiny)


def _scaled_for_print(mesh: trimesh.Trimesh, size: Any, z_scale: Any, *, copy: bool,
                      names: tuple[str, str] = ("size", "z_scale")) -> trimesh.Trimesh:
    """:func:`scale_for_print`'s work: a scaled copy of ``mesh``, or (``copy`` False: the command line, whose stepped
    mesh is its own) ``mesh`` itself scaled, its faces, colours and attributes not copied. ``names``: the arguments
    as the refusals name them (the command line's ``--print-size`` and ``--print-z-scale``)."""
    size = finite_number(size, names[0], positive=True)
    z_scale = finite_number(z_scale, names[1], positive=True)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if len(mesh.faces) == 0:
        raise InvalidInputError(f"mesh must have faces to be scaled for a print; got "
                                f"{counted(len(vertices), 'vertex', 'vertices')} and no faces")
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices).all(axis=1)).sum())
        raise InvalidInputError(f"mesh vertices must be finite to be scaled for a print; got {bad} of "
                                f"{counted(len(vertices), 'vertex', 'vertices')} with NaN or inf")
    faces = np.asarray(mesh.faces)
    check_face_indices(faces, len(vertices), "mesh faces")  # the message save_mesh gives, naming the first bad face
    # the bounds of the vertices the faces use, as trimesh's bounds and a slicer see the model: a stray vertex (a
    # file's unused point) made the print smaller than size and lifted it off the origin
    used = np.zeros(len(vertices), bool)
    used[faces.reshape(-1)] = True
    bounded = vertices if used.all() else vertices[used]  # (no copy of a stepped mesh's, which uses every vertex)
    lo, hi = bounded.min(axis=0), bounded.max(axis=0)
    extent = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    if not extent > 0:
        raise InvalidInputError(f"mesh must have a horizontal extent to be scaled to {names[0]} {size:g}; got the "
                                f"vertices of its faces all at x = {float(lo[0])!r}, y = {float(lo[1])!r}")
    scale = size / extent
    factors = np.array([scale, scale, scale * z_scale])
    with np.errstate(over="ignore"):  # an overflow is refused below: numpy's RuntimeWarning said it first, unasked
        top = float(((hi - lo) * factors).max())
    if not top < FLOAT32_MAX:
        raise InvalidInputError(f"the model scaled to {names[0]} {size:g} with {names[1]} {z_scale:g} reaches {top:g}, "
                                f"beyond float32 (|x| < {FLOAT32_MAX:.2g}, STL's coordinates); give a smaller "
                                f"{names[0]} or {names[1]}")
    moved = (vertices - lo) * factors
    # float32 (STL's and glTF's coordinates) underflows below its least normal number: size=1e-300 wrote an .stl of
    # no face and a .glb of every vertex at 0 (exit 0), 1e-40 an .stl missing faces
    least = min(float(column[column > 0].min(initial=np.inf)) for column in moved.T)  # a column at a time
    if least < _FLOAT32_TINY:
        raise InvalidInputError(f"the model scaled to {names[0]} {size:g} with {names[1]} {z_scale:g} has coordinates "
                                f"down to {least:g}, below float32's least normal number ({_FLOAT32_TINY:.2g}, STL's "
                                f"coordinates), where its vertices lose their precision or become 0; give a larger "
                                f"{names[0]} or {names[1]}")
    scaled = mesh.copy() if copy else mesh
    scaled.vertices = moved
    # the copy's own (deep-copied) metadata: the input's lists (isovalues) were shared, an edit of one the other's
    metadata = {key: value for key, value in scaled.metadata.items() if key not in _WORLD_METADATA}
    metadata["print"] = {"size": size, "scale": scale, "z_scale": z_scale, "origin": [float(v) for v in lo]}
    metadata["units"] = "millimeters"  # trimesh's units: a mesh read from a glTF (metres) kept "meters"
    scaled.metadata = metadata
    return scaled


#: Bytes :func:`save_mesh` holds at its peak beyond the mesh, per vertex and per face, by format: the prepared copy,
#: the arrays each writer packs (float32 positions, uint32 indices, linear colours, text rows, trimesh's exporters).
#: Measured as the process's peak RSS (VmHWM) less that before the call: a stepped mesh of 9.1 M faces and 4.6 M
#: vertices with vertex colours took 317 MiB as .glb, 379 .obj, 1100 .ply, 2408 .stl, 175 .3mf and 1416 .gltf; an
#: unmerged mesh of 3.9 M faces and 11.7 M vertices 181, 136, 728, 1012, 75 and 1077 MiB (nothing was checked: a
#: 956 MiB mesh took 560 MiB more as .glb, 690 as .obj). Fitted to both and rounded up by about 30 %. PLY's, measured
#: again since it writes float64 wherever float32 would round (:func:`_ply_parts` holds the vertices as float64, the
#: float32 try and the float64 columns at once): Big Tujunga's stepped mesh (interval 20 m, 2.7 M vertices, 5.3 M
#: faces, local coordinates + 0.123, vertex colours) 632 MiB, unmerged (16.0 M vertices) 2063 MiB, as peak RSS and
#: tracemalloc alike: 112 bytes a vertex, 68 a face (65 and 66 where float32 holds them; 40 and 144 were measured
#: for float32 and took the unmerged mesh as 1345 MiB).
_WRITE_BYTES: dict[str, tuple[int, int]] = {
    ".glb": (24, 40), ".gltf": (64, 176), ".obj": (16, 48), ".ply": (144, 88), ".stl": (8, 352), ".3mf": (4, 28),
}
#: What face colours add (per face) where a format has none and writes each vertex as the mean of its faces' colours
#: (glTF, OBJ), or packs them per face (PLY, 3MF): the unmerged mesh above with face colours took 1276 MiB more as
#: .glb, 1197 as .obj, 310 as .ply, 952 as .3mf (342, 320, 83 and 255 bytes a face). Rounded up.
_FACE_COLOR_WRITE_BYTES: dict[str, int] = {".glb": 400, ".gltf": 400, ".obj": 400, ".ply": 96, ".3mf": 320}
#: What a texture's UVs add (per vertex) where they are written (trimesh's glTF exporter packs a textured mesh): the
#: unmerged mesh above with a 16² texture took 816 MiB more as .glb, 333 as .obj (73 and 30 bytes a vertex).
_TEXTURE_WRITE_BYTES: dict[str, int] = {".glb": 96, ".gltf": 96, ".obj": 40}


def _check_write_budget(mesh: trimesh.Trimesh, ext: str, target: Path) -> None:
    """An :class:`OutputTooLargeError` before any work when writing ``mesh`` as ``ext`` would take more than the
    memory budget (:data:`_WRITE_BYTES`): nothing was checked, and the writers' copies grew with the mesh."""
    _check_write_counts(len(mesh.vertices), len(mesh.faces), ext, target, face_colors=mesh.visual.kind == "face",
                        textured=mesh.visual.kind == "texture")


def _check_write_counts(n_vertices: int, n_faces: int, ext: str, target: Path, *, face_colors: bool = False,
                        textured: bool = False, at_least: bool = False) -> None:
    """:func:`_check_write_budget` of a mesh of ``n_vertices`` and ``n_faces`` (``at_least`` that many: a mesh not yet
    made, e.g. a drape, named "at least"), before the mesh is made."""

    def need(e: str) -> int:
        per_vertex, per_face = _WRITE_BYTES[e]
        per_face += _FACE_COLOR_WRITE_BYTES.get(e, 0) if face_colors else 0
        per_vertex += _TEXTURE_WRITE_BYTES.get(e, 0) if textured else 0
        return per_vertex * n_vertices + per_face * n_faces

    less = sorted((e for e in _WRITE_BYTES if need(e) < need(ext)), key=need)
    check_budget(need(ext),
                 f"writing {str(target)!r} ({ext}, a mesh of {'at least ' if at_least else ''}"
                 f"{counted(n_faces, 'face', grouped=True)} and "
                 f"{counted(n_vertices, 'vertex', 'vertices', grouped=True)}"
                 + (" with face colours)" if face_colors else ")"),
                 hint="write a mesh of fewer faces (a larger interval, a coarsened or cropped DEM, tiles)"
                      + (f" or a format that needs less memory ({', '.join(less)}, from the least)" if less else ""))


def _check_uv(mesh: trimesh.Trimesh, ext: str, target: Path) -> None:
    """Refuse a texture that ``ext`` (one of :data:`_TEXTURED`) would write broken: texture coordinates that are not
    one finite (u, v) per vertex, or an image without them. An OBJ's ``vt`` index is its vertex's; glTF's
    TEXCOORD_0 is an attribute of every vertex, and its accessor bounds are JSON: trimesh's writer wrote a texture
    without TEXCOORD_0 (for too few or no UVs) and NaN bounds (invalid JSON), files the glTF validator refuses, and
    the OBJ got ``vt nan nan``. glTF points (no faces) are written without their texture."""
    visual = mesh.visual
    if visual.kind != "texture" or (ext != ".obj" and len(mesh.faces) == 0):
        return
    uv = getattr(visual, "uv", None)
    vertices = len(mesh.vertices)
    if uv is None:
        material = getattr(visual, "material", None)
        if getattr(material, "baseColorTexture", getattr(material, "image", None)) is None:
            return  # a material without an image (trimesh reads one from a glTF): nothing to map
        raise InvalidInputError(f"cannot write {str(target)!r}: mesh has a texture image but no texture coordinates "
                                f"(UVs); {ext} needs one (u, v) per vertex")
    uv = np.asarray(uv)
    if uv.shape != (vertices, 2):
        raise InvalidInputError(
            f"cannot write {str(target)!r}: mesh has {len(uv) if uv.ndim else 0} texture coordinates (UVs) "
            f"{'of shape ' + str(uv.shape) + ' ' if uv.ndim != 2 or uv.shape[1] != 2 else ''}for {vertices} "
            f"vertices; {ext} needs one (u, v) per vertex"
        )
    finite = np.isfinite(uv).all(axis=1)
    if not finite.all():
        raise InvalidInputError(f"cannot write {str(target)!r}: texture coordinates (UVs) must be finite; got "
                                f"{int((~finite).sum())} of {vertices} with NaN or inf")


def _shared_bounds(shared_bounds: ArrayLike | None) -> Bounds:
    """``save_mesh``'s ``shared_bounds`` as (lo, hi) float64, checked; None when not given."""
    if shared_bounds is None:
        return None
    corners = _finite_argument(shared_bounds, "shared_bounds", (2, 3), "finite (2, 3) corners (lowest, highest)")
    above = np.flatnonzero(corners[0] > corners[1])
    if above.size:  # corners swapped, or a (3, 2) array transposed: taken as given, a box of no meaning
        axis = "xyz"[int(above[0])]
        raise InvalidInputError(f"shared_bounds must be finite (2, 3) corners (lowest, highest), the lowest no higher "
                                f"than the highest; got {axis} from {corners[0, above[0]]:g} to "
                                f"{corners[1, above[0]]:g} in {shared_bounds!r:.200}")
    return corners[0], corners[1]


def _finite_argument(value: ArrayLike, name: str, shape: tuple[int, ...], expected: str) -> NDArray[np.float64]:
    """``value`` (save_mesh's ``shared_bounds`` or ``origin``) as float64 of ``shape``, finite, else an
    InvalidInputError "``name`` must be ``expected``; got ..." (its repr cut at 200 characters)."""
    try:  # real numbers only: an int beyond float64 (10**400) raised numpy's OverflowError, True was 1.0, text
        array = real_numbers(value, name, expected)
    except InvalidInputError:
        array = np.empty(0)
    if array.shape != shape or not np.isfinite(array).all():
        raise InvalidInputError(f"{name} must be {expected}; got {value!r:.200}")
    return array


def _origin_argument(origin: ArrayLike | None) -> NDArray[np.float64] | None:
    """``save_mesh``'s ``origin`` as 3 float64, floored (whole units: the translation in the JSON is then short and
    tiles given the same origin store shared vertices identically), checked; None when not given."""
    if origin is None:
        return None
    return np.floor(_finite_argument(origin, "origin", (3,), "3 finite numbers (x, y, z)")) + 0.0  # no -0 in JSON


def _metadata_value(recorded: Any, given: Mapping[str, Any], key: str) -> Any:
    """The ``key`` of the ``metadata`` given to :func:`save_mesh` (``given``) where it holds one, else of the mesh's own
    (``recorded``, when a mapping), else None."""
    return given[key] if key in given else recorded.get(key) if isinstance(recorded, Mapping) else None


def _recorded_bounds(recorded: Any, given: Mapping[str, Any], bounds: Bounds) -> Bounds:
    """The default ``shared_bounds`` of :func:`save_mesh`: those a mesh of a set records (``metadata["shared_bounds"]``,
    as :meth:`~stepterrain.globe.Globe.mesh` records them on its six ``per_face`` meshes; ``metadata`` given to
    save_mesh over the mesh's own), when they are finite (2, 3) corners holding every vertex (``bounds``); else None
    (a mesh moved or scaled since: its own bounds decide). Each cube face's glTF stored its float32 positions about
    its own centre, so the copies of a seam vertex in two files rounded apart (0.25 m on the Earth): cracks along
    the cube edges where the six files met in a viewer."""
    value = _metadata_value(recorded, given, "shared_bounds")
    if value is None or bounds is None:
        return None
    try:  # as save_mesh's shared_bounds are read, but bounds it cannot take are left, not refused
        lo, hi = _shared_bounds(value)  # type: ignore[misc]
    except InvalidInputError:
        return None
    if not ((lo <= bounds[0]).all() and (bounds[1] <= hi).all()):
        return None
    return lo, hi


def _as_made(recorded: Any, given: Mapping[str, Any], mesh: trimesh.Trimesh, bounds: Bounds) -> Bounds:
    """The bounds ``mesh`` records as a member of a set as it was made, when it is one: its vertex and face counts and
    its bounds those it records (``metadata["whole_part"]``, ``{"vertices": V, "faces": F, "bounds": [lo, hi]}``, as
    :meth:`~stepterrain.globe.Globe.mesh` records them on its ``per_face`` meshes; ``metadata`` given to save_mesh
    over the mesh's own), or its bounds those a glTF stored by the set's frame reads back (:func:`_read_back`). Such a
    mesh keeps its recorded shared bounds however much smaller it is than they are (:func:`_no_coarser` is not
    asked): a part culled to a few triangles was stored about its own centre while the larger ones kept the shared
    frame (or the eye it holds), and the copies of a seam vertex read back 0.44 m apart. A piece cut from it
    (``submesh``: trimesh copies the metadata), or one moved or scaled, records counts or bounds it no longer has:
    None."""
    value = _metadata_value(recorded, given, "whole_part")
    if not isinstance(value, Mapping) or bounds is None:
        return None
    counts = value.get("vertices"), value.get("faces")
    if not all(isinstance(c, (int, np.integer)) and not isinstance(c, bool) for c in counts) or \
            counts != (len(mesh.vertices), len(mesh.faces)):
        return None
    try:  # as save_mesh's shared_bounds are read, but bounds it cannot take are left, not refused
        own = _shared_bounds(value.get("bounds"))
    except InvalidInputError:
        return None
    if own is None:
        return None
    if (own[0] == bounds[0]).all() and (own[1] == bounds[1]).all() or _read_back(recorded, given, own, bounds):
        return own
    return None


def _read_back(recorded: Any, given: Mapping[str, Any], own: Bounds, bounds: Bounds) -> bool:
    """Whether ``bounds`` are a set member's bounds as made, ``own``, as a glTF save_mesh wrote it by the set's frame
    reads them back: relative to the node translation it took (the eye the mesh records, else the floor of the
    recorded shared bounds' centre), the float32 values of ``own``, exactly. A per-face part read back from its
    .glb was stored again by its own bounds, no longer its recorded ones (rounded): a culled part about its own
    centre, the others about the eye, and the copies of a seam vertex came apart by up to 0.25 m."""
    shared = _recorded_bounds(recorded, given, own)
    if shared is None:
        return False
    offset = _gltf_offset(shared, _recorded_eye(recorded, given, shared))
    for made, got in zip(own, bounds, strict=True):
        stored = (got - offset).astype(np.float32)
        if not ((stored == (made - offset).astype(np.float32)).all() and (stored + offset == got).all()):
            return False
    return True


def _no_coarser(recorded: Bounds, bounds: Bounds) -> Bounds:
    """``recorded`` shared bounds (:func:`_recorded_bounds`) as the storage frame of a mesh of ``bounds`` while its
    positions, stored relative to their glTF node translation (:func:`_local_origin`), reach at most twice as far
    as relative to its own: float32 then rounds them at most one binary order coarser. Else None, its own bounds
    decide. A whole cube face reaches about sqrt(2) times farther from the globe's centre than from its own, so the
    six per-face meshes all keep the shared frame (one culled to a part of its face by a view is not asked: it records
    itself as made, :func:`_as_made`); a piece cut from one (``submesh``, ``update_faces``: trimesh
    copies the metadata), or one shrunk about its own centre, lies within the recorded bounds yet rounded about the
    globe's centre: 0.19 m instead of 7.5 mm for a 320 km triangle of a face, 0.25 m instead of 0.24 mm for a 9 km
    mesh."""
    if recorded is None or bounds is None:
        return None
    lo, hi = bounds
    shared, own = (_local_origin(frame) for frame in (recorded, bounds))
    reach = float(np.maximum(np.abs(lo - shared), np.abs(hi - shared)).max())
    return recorded if reach <= 2.0 * float(np.maximum(np.abs(lo - own), np.abs(hi - own)).max()) else None


def _recorded_eye(recorded: Any, given: Mapping[str, Any], bounds: Bounds) -> NDArray[np.float64] | None:
    """The default ``origin`` of :func:`save_mesh`: the eye a view's mesh records (``metadata["eye"]``, as
    :meth:`~stepterrain.globe.Globe.mesh` does; ``metadata`` given to save_mesh over the mesh's own), floored, when it
    is 3 finite numbers lying within one diagonal of ``bounds`` (the mesh's, or the shared bounds it records: the
    same decision for every mesh of the set). Farther (a mesh scaled or moved since, its
    eye stale), its float32 positions would round worse than about the bounds' centre: None, the centre kept."""
    eye = _metadata_value(recorded, given, "eye")
    if eye is None or bounds is None:
        return None
    try:  # as save_mesh's origin is read, but an eye it cannot take is left, not refused
        point = _finite_argument(eye, "eye", (3,), "3 finite numbers (x, y, z)")
    except InvalidInputError:
        return None
    lo, hi = bounds
    outside = np.maximum(np.maximum(lo - point, point - hi), 0.0)
    if np.linalg.norm(outside) > np.linalg.norm(hi - lo):
        return None
    return np.floor(point) + 0.0


def _gltf_offset(frame: Bounds, origin: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """glTF's node translation: save_mesh's ``origin`` when given, else :func:`_local_origin` of ``frame``."""
    return _local_origin(frame) if origin is None else origin


def _check_float32_reach(bounds: Bounds, ext: str, target: Path, frame: Bounds,
                         origin: NDArray[np.float64] | None = None) -> None:
    """Refuse coordinates that the format's float32 cannot hold: STL stores them as they are, glTF relative to the
    node translation (:func:`_local_origin`). numpy's cast made them infinite
    (invalid files) with a RuntimeWarning only. PLY (float64 beyond 65536 or where float32 rounds), OBJ and 3MF (text)
    hold any finite value."""
    if bounds is None or ext not in (".stl", ".glb", ".gltf"):
        return
    lo, hi = bounds
    offset = _gltf_offset(frame, origin)  # glTF's node translation
    if ext == ".stl":
        reach = np.maximum(np.abs(lo), np.abs(hi))
    else:
        reach = np.maximum(np.abs(lo - offset), np.abs(hi - offset))
    if (reach <= FLOAT32_MAX).all():
        return
    axis = int(np.argmax(reach))
    what = "coordinates" if ext == ".stl" else (
        "coordinates relative to the mesh's centre" if origin is None else "coordinates relative to the origin")
    raise InvalidInputError(
        f"cannot write {str(target)!r}: {ext} stores float32 {what}, |x| < {FLOAT32_MAX:.2g}; the mesh's "
        f"{'xyz'[axis]} reaches {float(reach[axis]):.6g}{'' if ext == '.stl' else ' from it'}: write .ply or .obj "
        "(float64), or move the mesh nearer the origin"
    )


def add_write_listener(listener: Callable[[Path], None]) -> Callable[[], None]:
    """Call ``listener(path)`` after every mesh :func:`save_mesh` writes in this process; returns the remover.

    The test suite uses it to run the Khronos glTF validator over every GLB/glTF it writes.

    Examples
    --------
    >>> import pathlib, tempfile, trimesh
    >>> from stepterrain.export import add_write_listener, save_mesh
    >>> seen = []
    >>> remove = add_write_listener(seen.append)
    >>> _ = save_mesh(trimesh.creation.box(), pathlib.Path(tempfile.mkdtemp()) / "box.ply")
    >>> remove()
    >>> [p.name for p in seen]
    ['box.ply']
    """
    _WRITE_LISTENERS.append(listener)

    def remove() -> None:
        with contextlib.suppress(ValueError):
            _WRITE_LISTENERS.remove(listener)

    return remove


#: Image formats by extension: PNG (Pillow) and TIFF (a GeoTIFF through rasterio when georeferenced).
IMAGE_EXTENSIONS = (".png", ".tif", ".tiff")

#: PNGs of more than this many pixels (2048 x 1024) are deflated with zlib's Z_RLE strategy (:func:`_png_options`).
_FAST_PNG_PIXELS = 1 << 21


def _png_options(picture: Any) -> dict[str, Any]:
    """Pillow's PNG options for ``picture`` (a PIL image), as :func:`save_image` and a glTF's embedded texture
    (:func:`_encoded_textures`) write it. Above :data:`_FAST_PNG_PIXELS` pixels zlib's Z_RLE strategy
    (``compress_type=3``: matches of distance one only, which zlib's manual calls "almost as fast as
    Z_HUFFMAN_ONLY, but [giving] better compression for PNG image data"): lossless as any PNG, the same decoded
    pixels, and about 4x faster to write than zlib's default (level 6, the default strategy) for files 3 to 25 %
    larger (measured: a 3591 x 1929 hillshade with hypsometric colours 3.4 s -> 0.9 s, 5.9 -> 6.7 MB; the same over
    a DEM with nodata, RGBA, 5.2 s -> 1.2 s, 6.5 -> 8.1 MB; a 1790 x 2342 orthophoto texture 2.8 s -> 0.6 s,
    2.31 -> 2.37 MB; level 1 was as fast and larger still, level 3 half as fast and 11-18 % larger). A texture of
    77 M texels took 30 s to deflate at the default, longer than composing it. Smaller images keep the default."""
    return {"compress_type": 3} if picture.width * picture.height > _FAST_PNG_PIXELS else {}


# The last large PNG save_image wrote: (its pixels' digest, its path, the file's (inode, size, mtime)), so that a glTF
# texture of the same pixels takes the file's bytes (_encoded_textures) instead of deflating them again (not the CLI's
# PNGs that no mesh drapes, _save_image's reused=False: their pixels are not hashed, and the entry before stays). The
# stamp is the temporary file's, taken before the rename (which keeps the inode, size and mtime): stamped after it, at
# the path, it could be another writer's file that replaced this one in between, paired with this one's digest.
_LAST_PNG: list[tuple[bytes, Path, tuple[int, int, int]]] = []


def _pixels_digest(picture: Any, array: NDArray[np.uint8] | None = None) -> bytes:
    """A digest of a PIL image's mode, size and pixels (BLAKE2b, about 1 GB/s: 0.3 s at 77 M RGB texels): of
    ``array``, its C-contiguous pixels when given (no copy), else of the image a band of rows at a time (its
    ``tobytes`` would copy all of it at once)."""
    import hashlib

    digest = hashlib.blake2b(f"{picture.mode} {picture.width} {picture.height}".encode(), digest_size=20)
    if array is not None:
        digest.update(memoryview(array).cast("B"))
    else:
        rows = max(1, (1 << 22) // picture.width)
        for top in range(0, picture.height, rows):
            digest.update(picture.crop((0, top, picture.width, min(picture.height, top + rows))).tobytes())
    return digest.digest()


def _file_stamp(path: Path | int) -> tuple[int, int, int]:
    """A file's (inode, size, mtime): of ``path``, or of an open file descriptor."""
    info = os.fstat(path) if isinstance(path, int) else path.stat()
    return info.st_ino, info.st_size, info.st_mtime_ns


def _written_png(picture: Any) -> bytes | None:
    """The bytes of the large PNG :func:`save_image` wrote last in this process when it holds ``picture``'s pixels
    and the file is still the one it wrote; else None, and for an image whose PNG would carry more than its pixels
    (a transparent colour, an ICC profile: Pillow writes them from its ``info``) or in a mode save_image does not
    write."""
    if not _LAST_PNG or picture.mode not in ("RGB", "RGBA") or {"transparency", "icc_profile"} & picture.info.keys():
        return None
    digest, path, stamp = _LAST_PNG[0]
    try:
        with path.open("rb") as file:  # the bytes read are those of the file stamped (not one renamed over it since)
            if _file_stamp(file.fileno()) != stamp or _pixels_digest(picture) != digest:
                return None
            data = file.read()
    except OSError:
        return None
    return data if len(data) == stamp[1] else None


def save_image(
    image: ArrayLike, path: str | os.PathLike[str], *, extent: Any = None, crs: str | None = None
) -> Path:
    """Write an RGB or RGBA image to a PNG or TIFF file, atomically; a TIFF with an ``extent`` is a GeoTIFF.

    Parameters
    ----------
    image : (H, W, 3) or (H, W, 4) uint8
        Row 0 is the top of the picture (what :mod:`stepterrain.render` returns); for a GeoTIFF, the north
        edge (a texture layer's image, see :class:`stepterrain.texture.TextureLayer`).
    path : str or path-like
        Target ``.png``, ``.tif`` or ``.tiff`` file; missing folders are created.
    extent : (xmin, xmax, ymin, ymax), optional
        World coordinates of the pixels' outer edges (a texture layer's ``extent``): the TIFF is written as a
        north-up GeoTIFF (rasterio, ``pip install 'stepterrain[geo]'``), so GIS software places it over the
        DEM it was computed from. A PNG has no place for it.
    crs : str, optional
        The GeoTIFF's coordinate reference system, anything rasterio reads ("EPSG:32611", a PROJ string,
        WKT): a terrain's ``crs``. Needs ``extent``. One that GeoTIFF's keys cannot hold (a rotated pole,
        ``+proj=ob_tran``) goes into ``<path>.aux.xml`` beside it, which GDAL reads with the image; an image written
        over one removes the ``.aux.xml`` it has no use for. So does a PNG or plain TIFF: an old ``<path>.aux.xml``
        (an earlier GeoTIFF's, GDAL's of a PNG it wrote) would give it the old image's CRS, placement and nodata.
        The image and its side file are put in place together: a failure of either rename keeps the old image with
        its old side file. A ``path`` that is a symbolic link is written through (see :func:`atomic_path`): the side
        file goes beside the file the link points to, and an old one beside the link is removed too. GDAL reads the
        side file beside the name it opens: such a CRS is read through the file's own name, not through the link
        (a copy beside the link would go stale once the file is written by its own name, or the link
        pointed elsewhere, and give another image its CRS). A side file name that is itself a symbolic link is
        written through as well: the new side file replaces the file it points to and the link stays (so does one
        beside a linked ``path`` that points to the new side file); a link to an old side file that has no
        successor is removed, the file it points to left as it is. A world file beside ``path`` (``.pgw``, ``.tfw``,
        ``.wld``) is kept: stepterrain writes none, so it is the user's (an orthophoto re-rendered under its name).
        GDAL places a PNG or plain TIFF by it, and a GeoTIFF by its own georeferencing, which GDAL prefers.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InvalidInputError
        ``image`` is not (H, W, 3|4) uint8, ``path`` does not end in .png, .tif or .tiff, ``extent`` is not
        (xmin, xmax, ymin, ymax) with xmin < xmax and ymin < ymax, ``crs`` is unreadable or comes without an
        extent, or an extent is given for a PNG.
    MissingDependencyError
        A GeoTIFF without rasterio installed.
    DataFileError
        The target folder cannot be created or written, ``path`` is a side file (material or texture
        image) of a textured OBJ :func:`save_mesh` wrote in this process, which the image would replace, or
        ``crs`` needs the side file ``<path>.aux.xml`` and its name is over 255 bytes (the image's over 247), or the
        file cannot be written whole (a full disk: the message gives the system's reason); an existing ``path`` is
        then kept as it was. A GeoTIFF is read back once GDAL has closed it, with its CRS where that went into the
        side file (GDAL only prints a failure to write its last pixels, directory and side file as it closes the
        file).

    Notes
    -----
    A PNG of more than 2 M pixels (:data:`_FAST_PNG_PIXELS`) is deflated with zlib's Z_RLE strategy: the same
    pixels, about 4x faster to write, 3 to 25 % larger than zlib's default (see :func:`_png_options`).

    Examples
    --------
    >>> import numpy as np, pathlib, tempfile
    >>> from PIL import Image
    >>> from stepterrain.export import save_image
    >>> out = save_image(np.zeros((4, 6, 3), np.uint8), pathlib.Path(tempfile.mkdtemp()) / "black.png")
    >>> with Image.open(out) as picture:
    ...     picture.size
    (6, 4)
    """
    return _save_image(image, path, extent=extent, crs=crs)


def _save_image(image: ArrayLike, path: str | os.PathLike[str], *, extent: Any = None, crs: str | None = None,
                reused: bool = True) -> Path:
    """:func:`save_image`; ``reused=False`` where no later :func:`save_mesh` can take the PNG's bytes (the CLI's
    outputs that nothing drapes): its pixels are not hashed for :data:`_LAST_PNG` (0.3 s at 77 M texels), which
    keeps the large PNG written before."""
    from PIL import Image

    target = _target(path)
    suffix = target.suffix.lower()
    if suffix not in IMAGE_EXTENSIONS:
        raise InvalidInputError(
            f"cannot write {str(target)!r}: images are written as PNG or TIFF; the path must end in "
            f"{', '.join(IMAGE_EXTENSIONS)}"
        )
    array = as_array(image, "image", "an (H, W, 3) or (H, W, 4) uint8 array")
    if array.dtype != np.uint8:
        raise InvalidInputError(f"image must be uint8 (0-255); got dtype {array.dtype}")
    if array.ndim != 3 or array.shape[2] not in (3, 4) or array.shape[0] < 1 or array.shape[1] < 1:
        raise InvalidInputError(
            f"image must be an (H, W, 3) RGB or (H, W, 4) RGBA array; got shape {array.shape}"
        )
    if extent is None and crs is not None:
        raise InvalidInputError("crs georeferences a GeoTIFF together with its extent; got a crs without extent")
    if extent is not None:
        if suffix == ".png":
            raise InvalidInputError(
                f"cannot georeference {str(target)!r}: a PNG has no place for an extent or CRS; write a .tif"
            )
        return _save_geotiff(array, target, extent, crs)
    pixels = np.ascontiguousarray(array)
    picture = Image.fromarray(pixels)  # uint8 (H, W, 3|4) -> RGB or RGBA
    _check_owner([target], target)
    stamp, options = None, _png_options(picture)
    # an old <image>.aux.xml (GDAL's side file of an earlier GeoTIFF or GDAL write of this name: CRS, geotransform,
    # nodata) stayed, and GDAL read the new image with it; it is removed with the image's rename, as a GeoTIFF's is
    # (_save_geotiff): set aside just before it, gone once the image is in place, back if the rename fails
    with _replaced_together() as together:
        _remove_side_files(together, target)
        with atomic_path(target) as tmp:
            try:
                if suffix == ".png":
                    picture.save(tmp, format="PNG", **options)
                else:
                    picture.save(tmp, format="TIFF", compression="tiff_deflate")
            except OSError as exc:  # libtiff's "encoder error -9" (no errno) on a full disk: the system's words
                failure = None if exc.errno is not None else _write_failure(tmp)
                reason = f"{failure} ({exc})" if failure else exc
                raise DataFileError(f"cannot write {str(target)!r}: {reason}") from exc
            except RuntimeError as exc:  # libtiff could not write the header (a full disk): Pillow's "tiff codec
                # initialization failed" went out uncaught; the system's words where a write says them
                raise DataFileError(f"cannot write {str(target)!r}: {_write_failure(tmp) or exc}") from exc
            if suffix == ".png" and reused and options:  # a large one: a glTF of it takes its bytes
                with contextlib.suppress(OSError):
                    stamp = _file_stamp(tmp)  # the bytes written, before the rename (see _LAST_PNG)
    _record_owner([target], target)
    if stamp is not None:
        _LAST_PNG[:] = [(_pixels_digest(picture, pixels), target.absolute(), stamp)]
    return target


def _write_failure(path: Path) -> str | None:
    """The system's reason a write to ``path`` fails now (``No space left on device``), or None where a write of a few
    bytes (flushed, then cut off again) succeeds: the reason behind a C library's own error. The bytes go after the
    file's end: written at its start, over bytes already on the disk, they fitted where the library's had not (a
    file cut off past its first 4096 bytes gave no reason)."""
    try:
        with open(path, "r+b") as file:
            size = file.seek(0, os.SEEK_END)
            file.write(b"\0" * 4096)
            file.flush()
            os.fsync(file.fileno())
            file.truncate(size)
    except FileNotFoundError:  # (no file: not the reason a write failed)
        return None
    except OSError as exc:
        return str(exc.strerror or exc)
    return None


#: Rows of a GeoTIFF :func:`_check_read_back` reads at a time.
_READ_BACK_ROWS = 512


def _check_read_back(path: Path, array: NDArray[np.uint8], target: Path) -> None:
    """Raise DataFileError, naming ``target``, unless the GeoTIFF GDAL wrote to ``path`` reads back as ``array``.
    GDAL writes a small image's pixels and its directory as the dataset closes, and a write failing there (a full
    disk) is only printed, never raised (rasterio's close): the old GeoTIFF was replaced by an empty or truncated
    file. Read in bands of :data:`_READ_BACK_ROWS` rows (memory bounded; decoding costs less than deflate's
    encoding)."""
    import rasterio
    from rasterio.windows import Window

    height, width, bands = array.shape
    try:
        with rasterio.open(path) as dataset:
            same = (dataset.height, dataset.width, dataset.count) == (height, width, bands)
            for row in range(0, height, _READ_BACK_ROWS) if same else ():
                rows = min(_READ_BACK_ROWS, height - row)
                band = dataset.read(window=Window(0, row, width, rows))
                if not np.array_equal(band, np.moveaxis(array[row:row + rows], 2, 0)):
                    same = False
                    break
    except (OSError, rasterio.errors.RasterioError):
        same = False
    if not same:
        reason = _write_failure(path)
        raise DataFileError(f"cannot write {str(target)!r}: " + (reason or "GDAL could not finish the file (it does "
                                                                           "not read back as written)"))


def _check_side_file_crs(path: Path, aux: Path, crs: Any, target: Path) -> None:
    """Raise DataFileError, naming ``target``, unless the GeoTIFF GDAL wrote to ``path`` reads back with ``crs`` from
    its side file ``aux`` (an ob_tran CRS, which GeoTIFF's keys cannot hold): GDAL writes the side file as the dataset
    closes and only prints a failure to write it (a full disk), and :func:`_check_read_back` reads the pixels only:
    the image was put in place beside an empty or cut-off side file, its CRS lost without a word."""
    import rasterio

    try:
        with FILTERS, warnings.catch_warnings():  # one block at a time in the process (stepterrain._warning_filters)
            warnings.simplefilter("ignore")  # (rasterio's NotGeoreferencedWarning where the side file was lost)
            with rasterio.open(path) as dataset:
                same = dataset.crs == crs
    except (OSError, rasterio.errors.RasterioError):
        same = False
    if not same:
        reason = _write_failure(aux)
        raise DataFileError(f"cannot write {str(target)!r}: " + (reason or "GDAL could not finish its side file "
                                                                           f"{aux.name!r}, which holds the CRS"))


def _save_geotiff(array: NDArray[np.uint8], target: Path, extent: Any, crs: str | None) -> Path:
    """:func:`save_image`'s GeoTIFF: north-up, deflate-compressed, RGB (alpha as the fourth band)."""
    from .texture import _check_extent

    xmin, xmax, ymin, ymax = _check_extent(extent)
    height, width, bands = array.shape
    pixel = ((xmax - xmin) / width, (ymax - ymin) / height)
    if not all(math.isfinite(v) and v > 0 for v in pixel):  # the geotransform holds the pixel size, not the extent
        raise InvalidInputError(f"extent {extent!r} gives a pixel size of {pixel[0]:g} x {pixel[1]:g} over "
                                f"{width} x {height} pixels; it must be finite and positive (float64)")
    try:
        import rasterio
        from rasterio.crs import CRS
        from rasterio.errors import CRSError
    except ImportError as exc:
        raise MissingDependencyError("writing a GeoTIFF needs rasterio: pip install 'stepterrain[geo]'") from exc
    if crs is not None:
        try:
            crs = CRS.from_user_input(crs)
        except (CRSError, TypeError, ValueError) as exc:
            raise InvalidInputError(f"crs must be a coordinate reference system rasterio reads; got {crs!r}") from exc
    profile = {
        "driver": "GTiff", "width": width, "height": height, "count": bands, "dtype": "uint8", "crs": crs,
        "transform": rasterio.Affine(pixel[0], 0.0, xmin, 0.0, -pixel[1], ymax),
        "photometric": "RGB",
        "compress": "deflate", **({"alpha": "YES"} if bands == 4 else {}),
    }  # fmt: skip
    _check_owner([target], target)
    # what GeoTIFF's keys cannot hold (an ob_tran CRS) GDAL writes to <file>.aux.xml, which it reads back with the
    # file: written beside the temporary file, it stayed there under the temporary's name, and the image's CRS was
    # lost. It goes beside the image (the file a link names, as an OBJ's side files). An old one goes aside just before
    # the image is put in place (GDAL removes it when it makes the file: else the new image had the old one's CRS) and
    # the new one after: a reader sees either image with its own side file or none, never the other's, and a failed
    # write puts the old one back beside the old image.
    # GDAL names its side file after the file it writes: for a target name of 234 bytes or more the temporary's name
    # plus ".aux.xml" was over the 255 bytes a name may have, GDAL wrote no side file, and the CRS was lost without a
    # word, where "<name>.aux.xml" fits up to 247 bytes. GDAL then writes to a shorter temporary, renamed onto tmp,
    # and a CRS that needs a side file the image's name leaves no room for is refused before the image is put in place
    # Through a link, GDAL reads the side file beside the name it opens, the link's: an old one beside the link is set
    # aside too (the new one goes beside the file the link points to alone: see save_image's crs). The old side files'
    # removal, the image and its new side file are one set (_replaced_together), in that order: a failed rename of the
    # side file put in place the new image without its CRS, and removed the old one's; now all are put back.
    # A side file name that is itself a symbolic link is written through, as the image is (atomic_path): the old
    # side file it names goes aside and the new one takes its place there, the link stays (the link was set aside
    # and removed with the write, the new side file written to its target, and GDAL read the image without its CRS).
    # The removals are staged once it is known whether there is a new side file, still before the image's rename.
    sides = _side_files_of(target)
    with _replaced_together() as together, contextlib.ExitStack() as side_file:  # (the ExitStack's exit stages the
        with atomic_path(target) as tmp:  # new side file after the image)
            written = tmp
            try:
                if len(os.fsencode(tmp.name + ".aux.xml")) > _NAME_MAX:
                    written = _new_temporary(tmp.parent, tmp.name, reserve=len(".aux.xml"))
            except OSError as exc:
                raise DataFileError(f"cannot write in the output folder {str(tmp.parent)!r}: "
                                    f"{unwritable_reason(exc, tmp.parent)}") from exc
            aux = written.with_name(written.name + ".aux.xml")
            try:
                with rasterio.open(written, "w", **profile) as dataset:
                    dataset.write(np.moveaxis(array, 2, 0))
                _check_read_back(written, array, target)
                has_aux = os.path.exists(aux)
                if has_aux:  # (before written is renamed: GDAL pairs the side file with its name)
                    _check_side_file_crs(written, aux, crs, target)
                if written != tmp:
                    os.replace(written, tmp)
                for own_aux in sides[:1] if has_aux else ():  # beside the file itself
                    if len(os.fsencode(own_aux.name)) > _NAME_MAX:
                        raise DataFileError(
                            f"cannot write {str(target)!r} with its crs: GeoTIFF's keys cannot hold that CRS, and "
                            f"GDAL keeps it in the side file {own_aux.name!r}, whose name of "
                            f"{len(os.fsencode(own_aux.name))} bytes is over the {_NAME_MAX} a file name may "
                            f"have; give the image a name of at most {_NAME_MAX - len('.aux.xml')} bytes")
                    side = side_file.enter_context(atomic_path(own_aux))
                    side.write_bytes(aux.read_bytes())  # (the old one's mode and owner: it is there until the set
                    # lands)
                _remove_side_files(together, target, sides, new=sides[0] if has_aux else None)
            except DataFileError:  # (an OSError: its own words, not wrapped in another "cannot write")
                raise
            except (OSError, rasterio.errors.RasterioError) as exc:
                from .io import gdal_reason  # GDAL's words (No space left on device), not "See previous exception"

                reason = gdal_reason(exc)  # with the system's words: "No space left on device (TIFFAppend
                # ToStrip:Write error at scanline 42)" (an OSError, of the rename or the side file, has its own)
                failure = isinstance(exc, rasterio.errors.RasterioError) and _write_failure(written)
                reason = f"{failure} ({reason})" if failure else reason
                raise DataFileError(f"cannot write {str(target)!r}: {reason}") from exc
            finally:
                with contextlib.suppress(OSError):
                    aux.unlink()
                if written != tmp:  # (gone when renamed onto tmp)
                    with contextlib.suppress(OSError):
                        written.unlink()
    _record_owner([target], target)
    return target


def _side_file(image: Path) -> Path:
    """GDAL's side file ``<name>.aux.xml`` of ``image``, beside the file it names through links (the one
    :func:`atomic_path` writes)."""
    own = _link_target(image)
    return own.with_name(own.name + ".aux.xml")


def _side_files_of(image: Path) -> list[Path]:
    """The side files GDAL may read with ``image``: :func:`_side_file` and, where ``image`` is a symbolic link,
    ``<name>.aux.xml`` beside the link (GDAL reads the one beside the name it opens: the link's, when the image is
    opened by the name it was written to)."""
    own = _side_file(image)
    named = image.with_name(image.name + ".aux.xml")
    return [own] if os.path.abspath(named) == os.path.abspath(own) else [own, named]


def _remove_side_files(together: _Replacements, image: Path, sides: list[Path] | None = None,
                       new: Path | None = None) -> None:
    """Stage the removal of the old side files GDAL reads with ``image`` (``sides``, else :func:`_side_files_of`) in
    ``together``, before the image's rename. ``new`` is the name the new side file is written to (through links, by
    :func:`atomic_path`), None where there is none: a side file name that leads there through symbolic links
    (``t.tif.aux.xml -> store/t.aux.xml``, or a link's ``l.tif.aux.xml -> t.tif.aux.xml`` beside ``l.tif -> t.tif``)
    has the file it names set aside, to be replaced, and stays a link to the new side file. Any other side file name
    is removed itself: a link goes, and the file it names (elsewhere, perhaps another image's) is left alone."""
    written = None if new is None else _link_target(new)
    staged: set[str] = set()
    for side in _side_files_of(image) if sides is None else sides:
        if written is not None and os.path.realpath(side) == os.path.realpath(written):
            side = written  # (the same file for both names: set aside once)
        if str(side) in staged:
            continue
        staged.add(str(side))
        together.remove(side, f"cannot remove {str(side)!r}, whose metadata GDAL would read with the new "
                              f"{str(image)!r}")


def _set_aside(side: Path, why: str, done: list[tuple[Path, Path | None]] | None = None) -> Path | None:
    """Rename ``side`` (a removal :class:`_Replacements` staged) to a new temporary name beside it and return that
    name; None where there is none (or its name is too long to be one). A failure (or an interrupt) leaves ``side``
    where it was: a DataFileError beginning with ``why``."""
    try:
        os.lstat(side)
    except OSError as exc:
        if exc.errno in (errno.ENOENT, errno.ENAMETOOLONG):
            return None
        raise DataFileError(f"{why}: {exc.strerror}") from exc
    aside = None
    try:
        aside = _new_temporary(side.parent, side.name)
        os.replace(side, aside)
        if done is not None:
            done.append((side, aside))
    except BaseException as exc:  # an interrupt too, raised as os.replace returned: the side file moved aside
        if done and done[-1] == (side, aside):
            done.pop()
        if aside is not None:
            with contextlib.suppress(OSError):
                if os.path.lexists(side):
                    aside.unlink()
                else:
                    os.replace(aside, side)
        if not isinstance(exc, OSError):
            raise
        raise DataFileError(f"{why}: {exc.strerror}") from exc
    return aside


def _check_owner(paths: Iterable[Path], owner: Path) -> None:
    """A DataFileError, before anything is written, when one of ``paths`` (written for the output ``owner``) is a
    file this process wrote for another output and still there: an image of :func:`save_image` (which an OBJ's
    texture image named ``<stem>_<material>.png`` would replace) or a side file of another OBJ (which an image
    or an OBJ of the same stem in another case would replace)."""
    mine = os.path.abspath(owner)
    with _OWNERS_LOCK:
        for path in paths:
            key = os.path.abspath(path)
            other = _OWNERS.get(key)
            if other is None or other == mine or not os.path.exists(key):
                continue
            what = "an image" if other == key else f"a side file (material or texture image) of {other!r}"
            side = f" as a side file of {str(owner)!r}" if key != mine else ""
            raise DataFileError(f"cannot write {str(path)!r}{side}: this process wrote it earlier as {what}, which "
                                "it would replace; give each output a name of its own")


def _record_owner(paths: Iterable[Path], owner: Path) -> None:
    """Note ``paths`` as written for the output ``owner`` (see :func:`_check_owner`)."""
    mine = os.path.abspath(owner)
    with _OWNERS_LOCK:
        for path in paths:
            _OWNERS[os.path.abspath(path)] = mine


#: Rows side by side in :func:`_vertex_bounds`' reduction.
_BOUND_ROWS = 64


def _vertex_bounds(vertices: NDArray[Any]) -> Bounds:
    """(lowest, highest) per coordinate as float64, None without vertices: NaN propagates through min/max and
    inf shows in them, so finite bounds mean finite vertices. Computed once per file, for the finiteness check
    and the writers (glTF accessor bounds, the local origin of large coordinates). The rows are reduced as a
    contiguous (N / 64, 64 · 3) view, 64 rows side by side, then the 64 partial results: numpy vectorises an
    axis-0 reduction over wide rows, and reads the array once (one strided reduction per column and bound read
    it six times; 13 -> 6 ms for 1.6 M vertices)."""
    if vertices.size == 0:
        return None
    columns = vertices.shape[1]
    head = len(vertices) // _BOUND_ROWS * _BOUND_ROWS
    lo = np.full(columns, np.inf)
    hi = np.full(columns, -np.inf)
    if head and vertices.flags.c_contiguous:
        wide = vertices[:head].reshape(-1, _BOUND_ROWS * columns)
        lo = wide.min(axis=0).reshape(_BOUND_ROWS, columns).min(axis=0).astype(np.float64)
        hi = wide.max(axis=0).reshape(_BOUND_ROWS, columns).max(axis=0).astype(np.float64)
    else:
        head = 0
    if head < len(vertices):
        rest = vertices[head:]
        lo = np.minimum(lo, np.array([rest[:, k].min() for k in range(columns)], dtype=np.float64))
        hi = np.maximum(hi, np.array([rest[:, k].max() for k in range(columns)], dtype=np.float64))
    return lo, hi


def _local_origin(frame: Bounds) -> NDArray[np.float64]:
    """glTF's node translation for coordinates stored relative to it: the floor of the centre of ``frame`` (the
    vertex bounds, or save_mesh's ``shared_bounds``) when :func:`_is_large`, else 0. The centre, not the lowest
    corner: float32 positions then reach half the extent, not all of it, and round half as far (a globe's lowest
    corner, -R, put its far side at 2R: 0.5 m rounding at the earth's radius instead of 0.25 m)."""
    if not _is_large(frame):
        return np.zeros(3)
    return np.floor(frame[0] / 2 + frame[1] / 2)  # halves first: lo + hi overflows beyond 9e307


def _is_large(bounds: Bounds) -> bool:
    """True when some coordinate exceeds :data:`_LOCAL_ORIGIN_THRESHOLD` in magnitude (float32 would round it
    to worse than 1/128)."""
    return bounds is not None and max(float(np.abs(bounds[0]).max()), float(np.abs(bounds[1]).max())) > (
        _LOCAL_ORIGIN_THRESHOLD
    )


# ---------------------------------------------------------------------------------------------- writers
def _write_glb(mesh: trimesh.Trimesh, tmp: Path, target: Path, bounds: Bounds, frame: Bounds,
               origin: NDArray[np.float64] | None = None) -> None:
    empty = _empty_gltf(mesh)
    if empty or _direct_gltf(mesh):
        tree, blocks = _empty_document(mesh, target) if empty else _gltf_document(mesh, target, bounds, frame, origin)
        header = json.dumps(tree, separators=(",", ":")).encode("utf-8")
        header += b" " * (-len(header) % 4)  # chunks are 4-byte aligned; JSON pads with spaces
        binary: list[Any] = []  # the binary chunk (an empty mesh has none: glTF 2.0 §4.4.3.3, optional)
        if blocks:
            length = tree["buffers"][0]["byteLength"]
            binary = [struct.pack("<I4s", length, b"BIN\x00"), *(memoryview(block).cast("B") for block in blocks)]
        total = 12 + 8 + len(header) + (8 + length if blocks else 0)
        if total > _GLB_MAX_BYTES:
            _refuse_glb_size(target, total, mesh)
        parts = [
            struct.pack("<4sII", b"glTF", 2, total),
            struct.pack("<I4s", len(header), b"JSON"),
            header,
            *binary,
        ]
        with tmp.open("wb") as fh:  # part by part: joining them first would copy the whole buffer once more
            for part in parts:
                fh.write(part)
        return
    try:  # a textured mesh: trimesh packs the lengths as uint32 (numpy's OverflowError beyond)
        data = trimesh.exchange.gltf.export_glb(_gltf_scene(mesh, target, frame, origin), include_normals=False,
                                                tree_postprocessor=_sampler_postprocessor(mesh))
    except (OverflowError, struct.error):
        _refuse_glb_size(target, None, mesh)
    if len(data) > _GLB_MAX_BYTES:
        _refuse_glb_size(target, len(data), mesh)
    tmp.write_bytes(data)


#: The largest GLB: its header's length and its chunks' are uint32 (glTF 2.0 §4.4.3.1, §4.4.3.2).
_GLB_MAX_BYTES = 2**32 - 1


def _check_glb_size(mesh: trimesh.Trimesh, target: Path) -> None:
    """Refuse, before any work, a mesh whose GLB would exceed :data:`_GLB_MAX_BYTES`, counting its binary buffer
    alone (float32 positions, uint32 indices, float32 RGBA colours or float32 UVs; the writers check the whole
    file): the lengths overflowed once the buffer was built, a bare struct.error (numpy's OverflowError for a
    texture), after seconds of work and gigabytes of memory."""
    vertices, faces = len(mesh.vertices), len(mesh.faces)
    need = 12 * vertices + 12 * faces
    kind = mesh.visual.kind
    need += 16 * vertices if kind in ("vertex", "face") and faces else 8 * vertices if kind == "texture" else 0
    if need > _GLB_MAX_BYTES:
        _refuse_glb_size(target, need, mesh)


def _refuse_glb_size(target: Path, size: int | None, mesh: trimesh.Trimesh) -> None:
    """The InvalidInputError of a GLB over :data:`_GLB_MAX_BYTES` (``size`` its bytes, at least; None: unknown)."""
    needs = "more" if size is None else f"{size / 2**30:.3g} GiB" if size >= 2**30 else f"{size:,} bytes"
    raise InvalidInputError(
        f"cannot write {str(target)!r}: a .glb holds at most 4 GiB (its lengths are 32-bit, glTF 2.0 §4.4.3), and "
        f"this mesh of {counted(len(mesh.vertices), 'vertex', 'vertices')} and {counted(len(mesh.faces), 'face')} "
        f"needs {needs}: write .ply, .obj or .3mf, or split it into tiles (stepterrain batch) or coarsen it"
    )


def _write_gltf(mesh: trimesh.Trimesh, tmp: Path, target: Path, bounds: Bounds, frame: Bounds,
                origin: NDArray[np.float64] | None = None) -> None:
    if _empty_gltf(mesh):
        tmp.write_text(json.dumps(_empty_document(mesh, target)[0], separators=(",", ":")), encoding="utf-8")
        return
    if _direct_gltf(mesh):
        tree, blocks = _gltf_document(mesh, target, bounds, frame, origin)
        binary = b"".join(memoryview(block).cast("B") for block in blocks)
        tree["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode("ascii")
        tmp.write_text(json.dumps(tree, separators=(",", ":")), encoding="utf-8")
        return
    files = trimesh.exchange.gltf.export_gltf(
        _gltf_scene(mesh, target, frame, origin), include_normals=False, merge_buffers=True, embed_buffers=True,
        tree_postprocessor=_sampler_postprocessor(mesh),
    )
    tree = json.loads(files["model.gltf"])
    if not tree.get("bufferViews"):  # no faces: trimesh writes a 0-byte buffer and [], which glTF forbids
        tree.pop("bufferViews", None)
        tree.pop("buffers", None)
        tmp.write_text(json.dumps(tree, separators=(",", ":")), encoding="utf-8")
        return
    tmp.write_bytes(files["model.gltf"])


def _direct_gltf(mesh: trimesh.Trimesh) -> bool:
    """Plain, vertex-coloured and face-coloured meshes with vertices, and vertices without faces (points: a texture
    has no use there), are written by :func:`_gltf_document`; textured meshes go to trimesh."""
    if len(mesh.vertices) == 0:
        return False
    if len(mesh.faces) == 0:
        return True
    kind = mesh.visual.kind
    return kind in (None, "face") or (kind == "vertex" and len(mesh.visual.vertex_colors) == len(mesh.vertices))


def _empty_gltf(mesh: trimesh.Trimesh) -> bool:
    """No vertex and no face: written by :func:`_empty_document` (trimesh's writer would drop the metadata)."""
    return len(mesh.faces) == 0 and len(mesh.vertices) == 0


def _empty_document(mesh: trimesh.Trimesh, target: Path) -> tuple[dict[str, Any], list[Any]]:
    """glTF JSON of an empty mesh: one node without a mesh, ``mesh.metadata`` as its ``extras`` (glTF has no
    mesh without a primitive, nor a primitive without POSITION); no buffers."""
    node: dict[str, Any] = {"name": _utf8_name(target.stem) or "mesh"}
    if mesh.metadata:
        node["extras"] = mesh.metadata  # already JSON-safe (_prepared_mesh)
    tree = {"asset": {"version": "2.0", "generator": "stepterrain"}, "scene": 0, "scenes": [{"nodes": [0]}],
            "nodes": [node]}  # fmt: skip
    return tree, []


#: The node transform of every mesh save_mesh writes to glTF: stepterrain's z-up coordinates (as the positions hold
#: them) into glTF's y-up world (glTF 2.0 §3.4: +Y up, and +Z toward the viewer): -90 degrees about x, so that
#: (x, y, z) is (x, z, -y) there: heights along +Y, north along -Z. Without it, Blender's importer (y-up to its
#: z-up) stood a terrain on its edge, and three.js, model-viewer and Cesium orbited it about the wrong axis.
_Z_UP_TO_Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
#: The same turn as the node's rotation, a unit quaternion (x, y, z, w); sqrt(0.5) to float64's last digit, which
#: readers (trimesh) turn into the exact matrix above.
_Z_UP_TO_Y_UP_QUATERNION = (-float(np.sqrt(0.5)), 0.0, 0.0, float(np.sqrt(0.5)))
#: Its inverse, a glTF's y-up world coordinates as stepterrain's z-up ones: (x, y, z) -> (x, -z, y).
_Y_UP_TO_Z_UP = _Z_UP_TO_Y_UP.T.copy()

# glTF 2.0 constants (§3.6.2, §5.11): component types and buffer view targets
_GL_UNSIGNED_INT, _GL_FLOAT = 5125, 5126
_GL_ARRAY_BUFFER, _GL_ELEMENT_ARRAY_BUFFER = 34962, 34963


def _srgb_to_linear(value: NDArray[np.float64]) -> NDArray[np.float64]:
    """sRGB-encoded values in [0, 1] as linear ones (IEC 61966-2-1's transfer function)."""
    return np.where(value <= 0.04045, value / 12.92, ((value + 0.055) / 1.055) ** 2.4)  # type: ignore[no-any-return]


def _linear_to_srgb(value: NDArray[np.float64]) -> NDArray[np.float64]:
    """Linear values in [0, 1] as sRGB-encoded ones (the inverse of :func:`_srgb_to_linear`)."""
    value = np.clip(value, 0.0, 1.0)
    return np.where(value <= 0.0031308, value * 12.92, 1.055 * value ** (1 / 2.4) - 0.055)  # type: ignore[no-any-return]


#: (4, 256) float32: row k maps a colour byte of channel k (R, G, B, A) to glTF's COLOR_0 value. A mesh's vertex
#: colours are sRGB bytes (as matplotlib, PIL and trimesh give them); COLOR_0 is linear (glTF 2.0 §3.7.2.1, §3.9.2).
#: Alpha is linear on both sides. float32 keeps every byte apart (read back exactly, :func:`_srgb_vertex_colors`):
#: 8-bit linear merges the darkest sRGB values.
_COLOR_0_OF_BYTE = np.vstack([np.tile(_srgb_to_linear(np.arange(256) / 255.0), (3, 1)), np.arange(256) / 255.0]
                             ).astype(np.float32)
_CHANNEL_ROWS = np.array([0, 256, 512, 768], np.uint16)  # where channel k's row of _COLOR_0_OF_BYTE starts, flat


def _terrain_material(blend: bool) -> dict[str, Any]:
    """The glTF material of every primitive :func:`save_mesh` writes without a texture. Without one, viewers use
    glTF's default material (glTF 2.0 §3.9.6: metallicFactor 1, roughnessFactor 1), and three.js, Babylon.js,
    Blender and model-viewer showed coloured terrain as dark metal. A dielectric (metallicFactor 0) of roughness 1:
    ground, rock and a print's plastic are matte, and a rough surface has no highlight to shift the hypsometric
    tints, so viewers show the colours of the renders. baseColorFactor white: COLOR_0 (or white without it) is
    the colour. Double-sided: terrain surfaces are open, and their undersides (or a mesh wound the other way) were
    culled; a closed solid only loses back-face culling. ``blend``: some vertex alpha is below 1 (a close-up's
    fading anchor), which the default OPAQUE mode ignored."""
    return {"name": "terrain", "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
            "roughnessFactor": 1.0}, "doubleSided": True, "alphaMode": "BLEND" if blend else "OPAQUE"}  # fmt: skip


def _gltf_document(
    mesh: trimesh.Trimesh, target: Path, bounds: Bounds, frame: Bounds, origin: NDArray[np.float64] | None = None
) -> tuple[dict[str, Any], list[Any]]:
    """glTF JSON and binary buffer of one triangle primitive: POSITION (float32, relative to the node
    translation beyond 65536), indices (uint32), COLOR_0 (linear float32 RGBA, from the sRGB bytes) when the mesh
    has vertex colours (face colours: each vertex the mean of its faces'); no normals (flat shading);
    ``mesh.metadata`` as the mesh ``extras``. ``frame`` (save_mesh's ``shared_bounds``) decides the translation in
    place of ``bounds``, and ``origin`` (save_mesh's) in place of both. A mesh without faces is a points primitive
    (mode 0, no indices): its vertices are kept (trimesh's writer dropped them and wrote an empty file). The one
    material is :func:`_terrain_material`."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    node: dict[str, Any] = {"name": _utf8_name(target.stem) or "mesh", "mesh": 0}
    assert bounds is not None  # _direct_gltf: the mesh has vertices
    lo, hi = bounds
    offset = np.zeros(3)
    # the float32 positions and uint32 indices on recycled memory (a large tile's are tens of MB, written once)
    positions = recycled_empty(vertices.shape, np.dtype("<f4"))
    node["rotation"] = list(_Z_UP_TO_Y_UP_QUATERNION)  # z-up positions, a y-up world (glTF 2.0 §3.4)
    if _is_large(frame) or origin is not None:
        offset = _gltf_offset(frame, origin)
        np.subtract(vertices, offset, out=positions, casting="unsafe")  # in float64, rounded once to float32
        node["translation"] = [float(v) + 0.0 for v in _Z_UP_TO_Y_UP[:3, :3] @ offset]  # in the world frame; no -0
    else:
        np.copyto(positions, vertices, casting="unsafe")
    # v -> float32(v - offset) is monotonic, so the bounds of the stored values are the converted bounds
    p_lo, p_hi = (lo - offset).astype(np.float32), (hi - offset).astype(np.float32)
    faces = np.asarray(mesh.faces)
    indices = recycled_empty(faces.shape, np.dtype("<u4"))
    np.copyto(indices, faces, casting="unsafe")
    indices = indices.reshape(-1)
    blocks: list[Any] = []  # contiguous arrays and padding, written in order without joining
    views: list[dict[str, Any]] = []
    offset_bytes = 0

    def add_view(data: NDArray[Any], view_target: int) -> int:
        nonlocal offset_bytes
        views.append({"buffer": 0, "byteOffset": offset_bytes, "byteLength": data.nbytes, "target": view_target})
        pad = -data.nbytes % 4
        blocks.append(np.ascontiguousarray(data))
        if pad:
            blocks.append(b"\x00" * pad)
        offset_bytes += data.nbytes + pad
        return len(views) - 1

    accessors: list[dict[str, Any]] = []
    primitive: dict[str, Any] = {"attributes": {}, "mode": 4 if indices.size else 0}  # triangles, or points
    if indices.size:
        primitive["indices"] = len(accessors)
        accessors.append({"bufferView": add_view(indices, _GL_ELEMENT_ARRAY_BUFFER), "componentType": _GL_UNSIGNED_INT,
                          "count": int(indices.size), "type": "SCALAR"})  # fmt: skip
    primitive["attributes"]["POSITION"] = len(accessors)
    accessors.append({"bufferView": add_view(positions, _GL_ARRAY_BUFFER), "componentType": _GL_FLOAT,
                      "count": len(positions), "type": "VEC3", "min": [float(v) for v in p_lo],
                      "max": [float(v) for v in p_hi]})  # fmt: skip
    blend = False
    if mesh.visual.kind in ("vertex", "face") and len(mesh.visual.vertex_colors) == len(positions):
        # sRGB bytes to linear float32 (glTF's COLOR_0): written as they were, viewers showed them washed out.
        # Face colours (glTF has no per-face attribute) are trimesh's vertex colours: each vertex the mean of its
        # faces' colours, as trimesh's writer gave them (which wrote the bytes as linear values and no material)
        rgba = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
        colors = _COLOR_0_OF_BYTE.reshape(-1)[rgba + _CHANNEL_ROWS]  # byte + 256 * channel: one gather
        primitive["attributes"]["COLOR_0"] = len(accessors)
        accessors.append({"bufferView": add_view(colors, _GL_ARRAY_BUFFER), "componentType": _GL_FLOAT,
                          "count": len(colors), "type": "VEC4"})  # fmt: skip
        blend = bool(len(rgba)) and int(rgba[:, 3].min()) < 255
    primitive["material"] = 0
    gltf_mesh: dict[str, Any] = {"name": _utf8_name(target.stem) or "mesh", "primitives": [primitive]}
    if mesh.metadata:
        gltf_mesh["extras"] = mesh.metadata  # already JSON-safe (_prepared_mesh)
    tree = {
        "asset": {"version": "2.0", "generator": "stepterrain"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [node],
        "meshes": [gltf_mesh],
        "materials": [_terrain_material(blend)],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": offset_bytes}],
    }
    return tree, blocks


def _write_obj(mesh: trimesh.Trimesh, tmp: Path, target: Path, bounds: Bounds, frame: Bounds) -> None:
    """Wavefront OBJ written by us: ``v`` (with RGB in 0-1 for vertex colours), ``vt`` and ``f`` lines, no vertex
    normals (viewers shade faces flat and stair edges stay crisp). Coordinates and UVs are written by ``repr``, the
    shortest text that reads back as the same float64: trimesh's writer used 8 decimals, so 1e-9 became 0 and a
    millimetre mesh in kilometres lost its detail. Textured meshes get ``<stem>.mtl`` and their images beside (runs
    of whitespace in the stem become ``_``). A ``target`` that is a symbolic link is written as the file it points to:
    the side files go beside that file and take its stem, where a reader opening it looks for them."""
    target, mtl_name, sidecars, material, uv = _obj_side_files(mesh, target)
    paths = [target.parent / name for name in sidecars]
    _check_owner(paths, target)  # all of them before the first is written
    with contextlib.ExitStack() as side_files:
        # each side file replaces its old one only once the OBJ is complete: written first, an OBJ that then failed
        # (disk full, interrupted, a folder in its place) left the old OBJ with the new texture, or side files of no
        # OBJ. Within save_mesh's _replaced_together, they are renamed after the OBJ is written and flushed, just
        # before the OBJ itself, and a failed rename puts back the files renamed before it (all old, or all new)
        for path, data in zip(paths, sidecars.values(), strict=True):
            side_files.enter_context(atomic_path(path)).write_bytes(data)
        _write_obj_text(mesh, tmp, mtl_name, material, uv)
    _record_owner(paths, target)


def _obj_side_files(
    mesh: trimesh.Trimesh, target: Path
) -> tuple[Path, str, dict[str, bytes], str | None, NDArray[Any] | None]:
    """:func:`_write_obj`'s file names and side files for the prepared ``mesh``: the file ``target`` names (through
    symbolic links), its ``.mtl`` name, the side files ({name: bytes} beside that file: the ``.mtl`` and texture
    images; {} without a texture), the material name and the UVs (see :func:`_obj_material`)."""
    # the .obj bytes replace the file the link points to (atomic_path); side files written beside the link were
    # missing beside that file, and an OBJ reader opening it found no material or texture
    target = _link_target(target)
    # side files are named without whitespace: "mtllib my terrain.mtl" names two files for OBJ readers that split
    # the line as the format says (tinyobjloader, many slicers), and the texture was not found
    stem = "_".join(_utf8_name(target.stem).split()) or "mesh"  # written in the UTF-8 OBJ: named so on disk too
    mtl_name = f"{stem}.mtl"
    sidecars, material, uv = _obj_material(mesh, mtl_name)
    sidecars = _own_texture_names(sidecars, mtl_name, stem)
    sidecars = _alpha_map(sidecars, mtl_name, getattr(mesh.visual, "material", None))
    return target, mtl_name, sidecars, material, uv


def _side_files(mesh: trimesh.Trimesh, path: str | os.PathLike[str]) -> list[Path]:
    """The files :func:`save_mesh` writes beside ``path`` for ``mesh``: a textured OBJ's ``.mtl`` and texture images
    (beside the file a symbolic link ``path`` points to); [] for the other formats and a mesh without a texture.
    Writes nothing. A command checks with it, before any work, that they replace none of its inputs or other
    outputs (a texture image named as the orthophoto it drapes was replaced by it without a word).

    Raises
    ------
    InvalidInputError
        As :func:`save_mesh` for ``mesh`` and ``path`` (their checks that need no vertex: a texture image of no
        colours, a path that is no str).
    """
    target = _target(path)
    if target.suffix.lower() != ".obj":
        return []
    prepared = _prepared_mesh(mesh_argument(mesh), None)
    if prepared.visual.kind != "texture":
        return []
    _pil_textures(getattr(prepared.visual, "material", None))
    target, _, sidecars, _, _ = _obj_side_files(prepared, target)
    return [target.parent / name for name in sidecars]


def _write_obj_text(
    mesh: trimesh.Trimesh, tmp: Path, mtl_name: str, material: str | None, uv: NDArray[Any] | None
) -> None:
    """:func:`_write_obj`'s ``.obj`` text into ``tmp``: the metadata as ``# stepterrain-metadata <piece>`` comments
    (:func:`_metadata_pieces`), ``mtllib mtl_name`` and ``usemtl material`` (None: no texture), ``v`` lines (RGB
    for vertex colours), ``vt`` lines of ``uv`` and ``f`` lines."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    colors = None
    if material is None and mesh.visual.kind in ("vertex", "face") and len(mesh.visual.vertex_colors):
        # OBJ's colour is RGB, as 0-1 text of 8 decimals rounded up: VTK's reader (pyvista.read) truncates its value
        # times 255, and 217 / 255 written as 0.85098039 read back as 216 (half of all bytes one less); rounding readers
        # (trimesh's) read the same byte either way
        colors = np.ceil(np.asarray(mesh.visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0 * 1e8) / 1e8
    with tmp.open("w", encoding="utf-8", newline="\n") as fh:
        fh.write("# written by stepterrain\n")
        for piece in _metadata_pieces(mesh.metadata):  # comments: the crs, source, isovalues ... (read_mesh's)
            fh.write(f"{_OBJ_METADATA}{piece}\n")
        name = mesh.metadata.get("name")
        if isinstance(name, str) and name.split():  # one line: a line break in a name started a new statement
            fh.write(f"o {_obj_text(' '.join(name.split()))}\n")
        if material is not None:
            fh.write(f"mtllib {mtl_name}\nusemtl {material}\n")
        row = "v {!r} {!r} {!r}" + (" {:.8f} {:.8f} {:.8f}" if colors is not None else "") + "\n"
        _write_rows(fh.write, row, _blocks(vertices if colors is None else np.concatenate([vertices, colors], 1)))
        if uv is not None:
            _write_rows(fh.write, "vt {!r} {!r}\n", _blocks(uv))
        if uv is None:
            _write_rows(fh.write, "f {} {} {}\n", _blocks(faces + 1))
        else:  # the texture coordinate of a corner is its vertex's: v/vt with the same index
            _write_rows(fh.write, "f {}/{} {}/{} {}/{}\n", _blocks(np.repeat(faces + 1, 2, axis=1)))


def _obj_text(text: str) -> str:
    """``text`` (a name on one line) for the end of an OBJ or MTL statement: a backslash there continues the line in
    OBJ readers (trimesh's, as the OBJ specification has it), so an ``o`` line of a name ending in one (a Windows
    folder, ``C:\\dem\\``) or a ``usemtl`` of a material so named swallowed the first ``v`` line, and every face
    then named the wrong vertices or none (read_mesh: an IndexError). Its trailing backslashes become ``_``, and it is
    UTF-8 (:func:`_utf8_name`)."""
    text = _utf8_name(text)
    stripped = text.rstrip("\\")
    return stripped + "_" * (len(text) - len(stripped))


def _blocks(values: NDArray[Any]) -> Iterator[NDArray[Any]]:
    """``values`` in blocks of :data:`_ROWS_PER_WRITE` rows."""
    for start in range(0, len(values), _ROWS_PER_WRITE):
        yield values[start : start + _ROWS_PER_WRITE]


def _write_rows(write: Callable[[str], Any], row: str, blocks: Iterable[NDArray[Any]]) -> None:
    """Each (n, k) block formatted with ``row`` (k fields) per line, one ``write`` a block: the text writers of OBJ
    and 3MF (``repr`` for a float64 field: the shortest text that reads back exactly).

    A row of plain fields (``{}`` or ``{!r}``) over float64 or integer blocks is joined from its literal pieces and the
    texts of the block's distinct values, each formatted once (by bit pattern: -0.0 and 0.0, or two NaNs, keep their
    own text), the same text as ``str.format`` gave: a terrain's vertices repeat a few grid columns, rows and step
    heights, and ``repr`` of 6.5 M coordinates took most of a 4 M-triangle 3MF's time. Other rows (``{:.8f}``) go
    through ``str.format``."""
    parsed = list(string.Formatter().parse(row))
    pieces = [literal for literal, *_ in parsed]
    fields = [(name, spec, conversion) for _, name, spec, conversion in parsed if name is not None]
    if pieces and parsed[-1][1] is not None:
        pieces.append("")  # the row ends with a field: an empty piece after it
    plain = all(name == "" and not spec and conversion in (None, "r") for name, spec, conversion in fields)
    dedupe = True
    for block in blocks:
        exact = block.dtype == np.float64 or block.dtype.kind in "iu"
        if not (plain and exact and block.ndim == 2 and block.shape[1] == len(fields)) or not len(block):
            write((row * len(block)).format(*block.reshape(-1).tolist()))
            continue
        values = np.ascontiguousarray(block).reshape(-1)
        text = float.__repr__ if block.dtype == np.float64 else int.__str__
        if dedupe:
            distinct, index = np.unique(values.view(np.uint64) if text is float.__repr__ else values,
                                        return_inverse=True)
            if text is float.__repr__:
                distinct = distinct.view(np.float64)
            texts = np.array(list(map(text, distinct.tolist())), dtype=object)[index.reshape(block.shape)]
            dedupe = 4 * len(distinct) <= 3 * len(values)  # over 3/4 distinct: the next blocks skip the sort
        else:
            texts = np.array(list(map(text, values.tolist())), dtype=object).reshape(block.shape)
        line = np.empty((len(block), 2 * len(fields) + 1), dtype=object)
        line[:, 0::2] = pieces
        line[:, 1::2] = texts
        write("".join(line.reshape(-1).tolist()))


def _obj_material(mesh: trimesh.Trimesh, mtl_name: str) -> tuple[dict[str, bytes], str | None, NDArray[Any] | None]:
    """A textured mesh's OBJ side files ({name: bytes}: the ``.mtl`` and its images, as trimesh's ``to_obj`` makes
    them), material name and (V, 2) UVs (None without UVs); ({}, None, None) for a mesh without a material. Its PNG
    image is encoded by :func:`_png_data` (trimesh's ``to_obj`` deflated it again at zlib's default)."""
    from PIL import Image

    visual = mesh.visual
    if not hasattr(visual, "uv") or getattr(visual, "material", None) is None:
        return {}, None, None
    material = visual.material
    if hasattr(material, "to_simple"):
        unset = getattr(material, "baseColorFactor", None) is None
        material = material.to_simple()
        if unset:  # trimesh's default Kd 0.4 dims map_Kd to 40 % (MTL multiplies them; three.js does), Ks 0.4 shines
            material.diffuse = np.array([255, 255, 255, 255], np.uint8)
            material.specular = np.array([0, 0, 0, 255], np.uint8)  # matte, as the glTF material
    elif isinstance(material, trimesh.visual.material.SimpleMaterial) and material.image is not None:
        # an image given as TextureVisuals(uv=..., image=...) (globe.drape_texture's, the globe CLI's --texture): the
        # glTF writes it with a white factor, matte (_textured_material); its MTL kept trimesh's Kd 0.4 and Ks 0.4,
        # the drape at 40 % brightness and shiny. A copy: the mesh's own material stays as it is
        material = copy.copy(material)
        material.diffuse = np.array([255, 255, 255, 255], np.uint8)
        material.specular = np.array([0, 0, 0, 255], np.uint8)
    image = getattr(material, "image", None)
    # trimesh's to_obj writes a PNG (or one opened from none) as PNG: encoded once, as a glTF's texture; a JPEG as the
    # file's bytes, as a glTF's (_encoded_image)
    if isinstance(image, Image.Image) and image.format in (None, "PNG", "JPEG"):
        material = copy.copy(material)  # the mesh's own (a SimpleMaterial): _alpha_map reads its image after
        material.image = _encoded_image(image)
    name = material.name
    if isinstance(name, str):  # one word for newmtl / usemtl: a line break in it started a statement of its own in
        name = _obj_text("_".join(name.split()))  # the OBJ ("v 9 9 9" shifted every face), the MTL lost map_Kd
    files, name = material.to_obj(name=trimesh.util.unique_name(name, set()))
    sidecars = {mtl_name: b"# written by stepterrain\n\n"}
    for file_name, data in files.items():
        if file_name.lower().endswith(".mtl"):
            sidecars[mtl_name] += _with_dissolve(data, getattr(material, "diffuse", None))
        else:
            sidecars[file_name] = data
    uv = getattr(visual, "uv", None)  # one per vertex (_check_uv): each face corner's vt index is its vertex's
    uv = np.asarray(uv, dtype=np.float64) if uv is not None else None
    return sidecars, str(name), uv


def _with_dissolve(mtl: bytes, diffuse: Any) -> bytes:
    """The MTL text ``mtl`` (trimesh's ``to_obj``: Ka, Kd, Ks lines) with ``d <alpha>`` after its ``Kd`` line when the
    ``diffuse`` colour (RGBA bytes: a PBRMaterial's baseColorFactor, a plain material's diffuse) has an alpha below
    255: trimesh wrote its RGB alone, and a translucent material (as the glTF's alphaMode BLEND shows it) was opaque
    in OBJ readers. MTL's dissolve multiplies its ``map_d``, as glTF's factor multiplies the texels' alpha."""
    alpha = _colour_alpha(diffuse)
    if alpha is None:
        return mtl
    lines = mtl.decode("utf-8").split("\n")
    out = []
    for line in lines:
        out.append(line)
        if line.split(None, 1)[:1] == ["Kd"]:
            out.append(f"d {alpha / 255.0:.8f}")
    return "\n".join(out).encode("utf-8")


def _colour_alpha(colour: Any) -> float | None:
    """The alpha of ``colour`` (RGBA bytes: a base colour factor, a material's diffuse) when it is below 255; None for
    an opaque one, one of another length, or None (:func:`_with_dissolve`, :func:`_material_alpha_mode`)."""
    rgba = None if colour is None else np.asarray(colour).reshape(-1)
    if rgba is None or len(rgba) != 4 or float(rgba[3]) >= 255:
        return None
    return float(rgba[3])


#: The texture images of trimesh's materials: SimpleMaterial's one image, PBRMaterial's textures.
_TEXTURE_SLOTS = (
    (trimesh.visual.material.SimpleMaterial, ("image",)),
    (trimesh.visual.material.PBRMaterial, ("baseColorTexture", "metallicRoughnessTexture", "normalTexture",
                                           "emissiveTexture", "occlusionTexture")),
)  # fmt: skip
#: PIL modes of colour images that PNG cannot hold, and the mode each is written in.
_PNG_MODES = {"CMYK": "RGB", "YCbCr": "RGB", "LAB": "RGB", "HSV": "RGB", "RGBX": "RGB", "RGBa": "RGBA", "La": "LA",
              "PA": "RGBA"}
#: PIL modes a PNG texture holds as they are (Pillow writes them); another (32-bit "I" or float "F", a DEM or a
#: hillshade opened from a GeoTIFF) has no PNG of its own and no colour to convert to without a scale.
_PNG_HOLDS = frozenset({"1", "L", "LA", "P", "RGB", "RGBA", "I;16", "I;16B"})


def _pil_textures(material: Any) -> None:
    """Make the texture images of ``material`` (a prepared mesh's copy: changed in place) PIL images in PNG or JPEG,
    as glTF and OBJ readers take them. A numpy array (``TextureVisuals(uv=..., image=array)``, as trimesh allows)
    was no texture at all in glTF (trimesh's writer skips what is not a PIL image, silently) and an AttributeError
    in OBJ. An image opened from a WebP, TIFF, GIF or BMP file went to the OBJ's side files in that format, which
    most MTL readers cannot read (and ``<stem>_<material>.png`` was promised): it is PNG now, as in glTF; a JPEG
    stays a JPEG. A CMYK (or other non-RGB colour space) image is converted to RGB, and a palette one with alpha
    (PA) to RGBA: PNG cannot hold them (a DataFileError, as if the file were at fault) and a CMYK JPEG is no glTF
    texture. An image of 32-bit integers or floats (mode I or F: a GeoTIFF of heights opened as the texture) is
    refused, before any file is made: it was the same DataFileError, once the folder was made. So are a palette image
    whose palette lacks colours its pixels use (:func:`_palette_shortfall`) and an image of no pixels."""
    from PIL import Image

    slots = next((names for kind, names in _TEXTURE_SLOTS if isinstance(material, kind)), ())
    for slot in slots:
        image = getattr(material, slot, None)
        if image is None:
            continue
        if isinstance(image, Image.Image):
            _check_texture_pixels(image, slot)
        if not isinstance(image, Image.Image):
            array = np.asarray(image)
            if array.ndim == 3 and array.shape[2] == 1:
                array = array[..., 0]
            if array.dtype != np.uint8 or not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (3, 4))):
                raise InvalidInputError(
                    f"mesh texture image ({slot}) must be a PIL image or an (H, W), (H, W, 3) or (H, W, 4) uint8 "
                    f"array; got {type(image).__name__} of dtype {array.dtype} and shape {array.shape}"
                )
            image = Image.fromarray(np.ascontiguousarray(array))
            _check_texture_pixels(image, slot)
        elif image.mode in ("P", "PA") and (shortfall := _palette_shortfall(image)) is not None:
            colours, top = shortfall
            raise InvalidInputError(
                f"mesh texture image ({slot}) is a palette image (mode {image.mode!r}) whose pixels use palette index "
                f"{top} but whose palette holds {counted(colours, 'colour', 'colours')} (Image.new('P', ...) makes "
                "none): its texels have no colour to write; give it a palette (image.putpalette(...)), or convert it "
                "to 'L' or 'RGB' first"
            )
        elif image.mode in _PNG_MODES:
            image = image.convert(_PNG_MODES[image.mode])
        elif image.mode not in _PNG_HOLDS:
            raise InvalidInputError(
                f"mesh texture image ({slot}) must be a PIL image of 8-bit colours (mode RGB, RGBA, L, LA, P or 1; "
                f"or I;16) or a uint8 array; got a PIL image of mode {image.mode!r}, which a PNG texture cannot hold: "
                "scale its values to 0-255 and give it as uint8"
            )
        elif image.format not in (None, "PNG", "JPEG"):
            image = image.copy()  # no format: trimesh writes it as PNG
        else:
            continue
        setattr(material, slot, image)


def _check_texture_pixels(image: Any, slot: str) -> None:
    """An InvalidInputError naming its ``slot`` for a PIL texture ``image`` with a side of 0 pixels
    (:func:`_pil_textures`): Pillow's writer raised a bare ValueError ("cannot write empty image") once the folder
    was made."""
    if 0 in image.size:
        raise InvalidInputError(f"mesh texture image ({slot}) must have at least 1 x 1 pixels; got {image.width} x "
                                f"{image.height}")


def _palette_shortfall(image: Any) -> tuple[int, int] | None:
    """(palette colours, highest index its pixels use) of a palette image (mode P or PA) whose pixels use an index
    beyond its palette; None when the palette covers them. Pillow's ``Image.new("P", ...)`` has an empty palette (a
    copy of it, as trimesh's material copy made, none at all): Pillow's PNG writer raised a bare UnboundLocalError
    for none, and wrote a PNG whose indices name no palette entry, invalid (PNG §11.2.3), for an empty one."""
    extrema = image.getextrema()
    top = int(extrema[0][1] if image.mode == "PA" else extrema[1])
    colours = len(image.getpalette() or []) // 3 if image.palette is not None else 0
    return (colours, top) if top >= colours else None


def _own_texture_names(sidecars: Mapping[str, bytes], mtl_name: str, stem: str) -> dict[str, bytes]:
    """Prefix texture images with the OBJ's stem (``material_0.png`` -> ``<stem>_material_0.png``) and point
    the MTL at them, so several textured OBJs in one folder keep their own images. Whitespace in a name
    (a material called "terrain texture") becomes ``_``: MTL readers split ``map_Kd`` lines on it. So do path
    separators: an image is named after its material, and a material named ``../../x`` (as a glTF file read back
    may name it) wrote ``x.png`` outside the OBJ's folder, and one named ``a/b`` made a folder beside it."""
    renamed = {}
    for name in sidecars:
        plain = re.sub(r"[\s/\\]+", "_", name.strip())  # one file name in the OBJ's folder
        plain = plain if plain.startswith(f"{stem}_") else f"{stem}_{plain}"
        if name != mtl_name and plain != name:
            renamed[name] = plain
    out: dict[str, bytes] = {}
    for name, data in sidecars.items():
        if name == mtl_name:
            lines = data.decode("utf-8").splitlines()
            for k, line in enumerate(lines):
                parts = line.split()
                if not parts or not parts[0].startswith("map_"):
                    continue
                whole = line.split(None, 1)[1].strip() if len(parts) > 1 else ""
                if whole in renamed:  # the file name, spaces and all
                    lines[k] = f"{parts[0]} {renamed[whole]}"
                elif parts[-1] in renamed:
                    lines[k] = " ".join(parts[:-1] + [renamed[parts[-1]]])
            out[name] = ("\n".join(lines) + "\n").encode("utf-8")
        else:
            out[renamed.get(name, name)] = data
    return out


def _alpha_map(sidecars: dict[str, bytes], mtl_name: str, material: Any) -> dict[str, bytes]:
    """The MTL with ``map_d -imfchan m <image>`` after its ``map_Kd <image>`` when that image has texels of alpha
    below 255 (:func:`_texture_alpha_mode`): trimesh's MTL named the image only as the diffuse colour, so readers
    showed its transparent texels (nodata, outside a lens) opaque. ``map_d`` is the MTL's dissolve texture, and
    ``-imfchan m`` takes it from the image's matte (alpha) channel, as the glTF's alphaMode does."""
    image = getattr(material, "baseColorTexture", getattr(material, "image", None))
    if mtl_name not in sidecars or _texture_alpha_mode(image)[0] == "OPAQUE":
        return sidecars
    lines = sidecars[mtl_name].decode("utf-8").splitlines()
    out = []
    for line in lines:
        out.append(line)
        parts = line.split(None, 1)
        if len(parts) == 2 and parts[0].lower() == "map_kd":
            out.append(f"map_d -imfchan m {parts[1].strip()}")
    return {**sidecars, mtl_name: ("\n".join(out) + "\n").encode("utf-8")}


def _write_ply(mesh: trimesh.Trimesh, tmp: Path, target: Path, bounds: Bounds, frame: Bounds) -> None:
    with tmp.open("wb") as fh:  # part by part: joining them first would copy the whole file once more
        for part in _ply_parts(mesh, frame):
            fh.write(part)


def _write_stl(mesh: trimesh.Trimesh, tmp: Path, target: Path, bounds: Bounds, frame: Bounds) -> None:
    # the corners as export_stl rounds them, once for the three checks (-0.0 as 0.0: one hash per position)
    corners = np.asarray(mesh.vertices, dtype=np.float64).astype(np.float32) + np.float32(0.0)
    _warn_stl_rounding(mesh, target, bounds, corners)
    _warn_stl_open(mesh, target, corners)
    tmp.write_bytes(trimesh.exchange.stl.export_stl(_without_point_edges(mesh, corners)))


def _stl_open_edges(mesh: trimesh.Trimesh, corners: NDArray[np.float32]) -> int:
    """How many edges of ``mesh`` as an ``.stl`` reader that merges corners by position sees it (float32 corners
    merged, triangles with two corners on one position left out, as :func:`_without_point_edges` does) have other
    than two triangles, among the edges at a merged corner: the others keep their faces (0 for a watertight mesh).
    0 at once for a mesh with a vertex of one corner, which is not watertight (an unmerged mesh's: its 28 M
    vertices took 38 s). One hash and sort (not an argsort) of the vertices where no two share a float32 position
    (a solid at γ > 0, most meshes: 0.4 s of a 9.3 M-face solid's 12 s .stl; 1.1 s with a stable argsort).
    ``corners``: its vertices in float32, -0.0 as 0.0 (:func:`_write_stl`'s)."""
    faces = np.asarray(mesh.faces)
    if len(faces) == 0 or (np.bincount(faces.reshape(-1), minlength=len(mesh.vertices)) == 1).any():
        return 0  # a vertex of one corner has an edge of one face: not watertight (an unmerged mesh's, by design)
    bits = corners.view(np.uint32).astype(np.uint64)
    key = (bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)) ^ (bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) ^ bits[:, 2]
    del bits
    ranked = np.sort(key)  # no two vertices on one position (most meshes): a sort, 10 times an argsort's speed
    if not (ranked[1:] == ranked[:-1]).any():
        return 0
    del ranked
    order = np.argsort(key)  # any head of a group will do: not a stable sort (3 times slower)
    key = key[order]
    same = key[1:] == key[:-1]
    shared = np.zeros(len(order), bool)
    shared[1:] |= same
    shared[:-1] |= same
    candidates, key = order[shared], key[shared]  # the vertices whose hash another shares, by hash
    del order, shared, same
    group = np.concatenate([[0], np.cumsum(key[1:] != key[:-1])])
    head = candidates[np.concatenate([[0], np.flatnonzero(key[1:] != key[:-1]) + 1])]  # each hash's first vertex
    if not (corners[candidates] == corners[head[group]]).all():  # a hash shared by two positions: group exactly
        _, group = np.unique(corners[candidates], axis=0, return_inverse=True)
        group = group.reshape(-1)
        head = np.full(int(group.max()) + 1, len(corners), np.int64)
        np.minimum.at(head, group, candidates)
    merged = np.arange(len(corners))
    merged[candidates] = head[group]
    moved = np.zeros(len(corners), bool)
    moved[candidates] = True
    faces = faces[moved[faces].any(axis=1)]  # the faces at a merged corner: only their edges can change
    faces = merged[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    a = faces.reshape(-1)
    b = np.roll(faces, -1, axis=1).reshape(-1)
    at = moved[a] | moved[b]  # an edge of two unmerged corners has faces beyond these
    return _edges_not_two(a[at], b[at], len(corners))


def _edges_not_two(a: NDArray[Any], b: NDArray[Any], n: int) -> int:
    """How many of the edges (a, b) (vertex indices below ``n``, either way round) occur other than twice."""
    a, b = a.astype(np.int64), b.astype(np.int64)
    keys = np.sort(np.minimum(a, b) * n + np.maximum(a, b))
    if len(keys) == 0:
        return 0
    counts = np.diff(np.flatnonzero(np.concatenate([[True], keys[1:] != keys[:-1], [True]])))
    return int((counts != 2).sum())


def _warn_stl_open(mesh: trimesh.Trimesh, target: Path, corners: NDArray[np.float32]) -> None:
    """Warn (a ``UserWarning`` at the caller's line) when the ``.stl`` of a watertight mesh would not read back
    watertight (:func:`_stl_open_edges`): float32 puts distinct vertices on one position that a reader merging
    corners by position (slicers, ``trimesh.load``) joins. A solid's copies of a pinch node (two nodata holes
    touching at it) are such vertices where :func:`~stepterrain.mesh.close_solid` left them on the node: on a fine
    grid at UTM coordinates (2 float32 steps of the coordinates would leave the copy's cell), or with a wall at the
    node; so is a wall's corner that τ could not keep 4 float32 steps from its node (README, solids), and any wall's
    corner within float32 rounding of a node or of another wall's corner on its edge, a node on a threshold beside it
    or not (the walls stand where the edge's heights interpolate to a threshold; τ moves them only next to a node on
    one): on a 1 m grid at UTM northings (float32 steps of 0.25 to 0.5 m) most small steep solids. Such files
    were written without a word. Only a mesh watertight by its indices is warned about (the corners of an unmerged
    mesh lie on one position by design), and only where some two vertices share a float32 position: one hash and
    sort of the vertices otherwise. ``corners``: the vertices as the ``.stl`` has them (:func:`_write_stl`'s)."""
    open_edges = _stl_open_edges(mesh, corners)
    if not open_edges:
        return
    faces = np.asarray(mesh.faces)
    if _edges_not_two(faces.reshape(-1), np.roll(faces, -1, axis=1).reshape(-1), len(mesh.vertices)):
        return
    warnings.warn(
        f"{str(target)!r}: .stl stores float32 coordinates without indices, which put distinct vertices of this "
        f"watertight mesh on one position: a reader that merges corners by position (slicers, trimesh.load) reads "
        f"it back with {counted(open_edges, 'edge')} not shared by exactly two triangles (a solid's copies of a node "
        "where two nodata holes touch, left on the node, or a wall's corner within float32 rounding of a node or of "
        "another wall's corner: coordinates too large for the grid's spacing, as a 1 m grid at UTM northings); write "
        f".ply, .obj or .3mf, which keep the indices and the float64 world coordinates{_STL_OPEN_LOCAL}",
        stacklevel=caller_stacklevel(),
    )


def _without_point_edges(mesh: trimesh.Trimesh, corners: NDArray[np.float32]) -> trimesh.Trimesh:
    """``mesh`` less its triangles with two corners on one float32 position (as ``.stl`` stores them): they have no
    area, and a reader that merges corners by position (slicers, ``trimesh.load``) would find them folded onto an
    edge of their neighbours, used by three faces or more. A solid's walls of zero height (γ = 0, inside a
    :func:`~stepterrain.stepped.circular_lens` by default) are such triangles: their top and bottom corners are
    distinct vertices on one position, which keep the indexed solid watertight; without them, the corners merged,
    the ``.stl`` reads back watertight too. ``mesh`` itself is not modified. ``corners``: its vertices in float32,
    as ``export_stl`` rounds them (:func:`_write_stl`'s)."""
    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        return mesh
    x, y, z = (np.ascontiguousarray(corners[:, k]) for k in range(3))
    face_x = x[faces]
    point = np.zeros(len(faces), dtype=bool)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        # y and z only where x is one (about a third of a stepped mesh's edges): 3 times faster than comparing whole
        # corners (0.26 s instead of 0.77 s on 5.6 M faces). One index twice is one position (vertices are finite).
        same_x = np.flatnonzero(face_x[:, i] == face_x[:, j])
        a, b = faces[same_x, i], faces[same_x, j]
        point[same_x[(y[a] == y[b]) & (z[a] == z[b])]] = True
    if not point.any():
        return mesh
    return trimesh.Trimesh(mesh.vertices, faces[~point], process=False)


#: How far (in the mesh's units: 1 mm for metres) STL's float32 may move a vertex before save_mesh warns.
_STL_ROUNDING_TOLERANCE = 1e-3
#: The warning of :func:`_warn_stl_rounding`, its largest move as ``error``: batch says it once for all its files
_STL_ROUNDING_RE = re.compile(r": \.stl stores float32 coordinates, which move this mesh's vertices by up to "
                              r"(?P<error>[0-9.e+-]+) ")


#: The ends of the ``.stl`` warnings (:func:`_warn_stl_open`, :func:`_warn_stl_rounding`) that only a Python caller
#: can follow: the command line has no option that places the terrain at a local origin or moves the mesh (its
#: coordinates stay the DEM's, georeferenced), so it leaves them out and keeps the formats' advice (``cli._as_option``).
_STL_OPEN_LOCAL = (", or step the terrain in local coordinates (e.g. origin=(0, 0) of Terrain.from_heights: the .stl's "
                   "coordinates then count from there, not georeferenced)")
_STL_ROUNDING_LOCAL = ", or move the mesh to a local origin first"
#: The warning of :func:`_warn_stl_open`, its count of open edges as ``edges``: batch says it once for all its files
_STL_OPEN_RE = re.compile(r": \.stl stores float32 coordinates without indices, .* reads it back with "
                          r"(?P<edges>[0-9]+) edges? not shared by exactly two triangles")


def _warn_stl_rounding(mesh: trimesh.Trimesh, target: Path, bounds: Bounds, corners: NDArray[np.float32]) -> None:
    """Warn (a ``UserWarning`` at the caller's line) when STL's float32 moves some coordinate by more than
    :data:`_STL_ROUNDING_TOLERANCE`: UTM northings came back up to 0.5 m off, a globe's surface 0.25 m, without a
    word.
    A warning, not a refusal: float32 is the format (every STL reader expects it), and a print or a preview is
    often fine with it; the message says where float64 is kept. Only coordinates beyond 2^15 can round that far
    (half a float32 step at 32768 is 0.002), so smaller meshes cost nothing, and larger ones one cast: a grid of
    whole metres (a UTM DEM's posts) is exact in float32 and is not warned about. ``corners``: the vertices in
    float32, as the ``.stl`` has them (:func:`_write_stl`'s)."""
    if bounds is None:
        return
    reach = max(float(np.abs(bounds[0]).max()), float(np.abs(bounds[1]).max()))
    if np.spacing(np.float32(reach)) / 2 <= _STL_ROUNDING_TOLERANCE:
        return
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    error = np.abs(corners - vertices)  # as export_stl rounds them: round to nearest
    worst = int(np.argmax(error))
    if error.flat[worst] <= _STL_ROUNDING_TOLERANCE:
        return
    row, axis = divmod(worst, vertices.shape[1])
    value = float(vertices[row, axis])
    warnings.warn(
        f"{str(target)!r}: .stl stores float32 coordinates, which move this mesh's vertices by up to "
        f"{float(error.flat[worst]):.3g} (vertex {row} {'xyz'[axis]} = {value!r} is written as "
        f"{float(np.float32(value))!r}), more than {_STL_ROUNDING_TOLERANCE:g} (1 mm in metres): write .ply, .obj "
        f"or .3mf to keep float64{_STL_ROUNDING_LOCAL}",
        stacklevel=caller_stacklevel(),
    )


_3MF_CONTENT_TYPES = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">'
    '<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>'
    '<Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>'
)
_3MF_RELS = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
    '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
    'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>'
)
#: The namespace of the 3MF's own metadata (:func:`_write_3mf`): a URN, as no web page stands behind it.
_3MF_NAMESPACE = "urn:stepterrain:3mf:metadata"
_3MF_PREFIX = "stepterrain"
#: The name of the model's metadata element that holds the mesh's metadata as JSON.
_3MF_METADATA = f"{_3MF_PREFIX}:metadata"
_ROWS_PER_WRITE = 1 << 16  # OBJ lines and 3MF vertices or triangles formatted at a time


def _3mf_member(name: str) -> zipfile.ZipInfo:
    """A member of a 3MF's zip, dated 1980-01-01 (zip's first date) instead of the clock's time, so that the same mesh
    gives the same bytes: every 3MF differed from the last (batch outputs of workers=1 and 2, two runs of the CLI),
    whereas every other format compared equal. Deflated at level 5, as the archive names its own members."""
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_DEFLATED
    # the level ZipFile(compresslevel=5) gives the members it makes: ``compress_level`` from Python 3.13 on
    setattr(info, "compress_level" if hasattr(info, "compress_level") else "_compresslevel", 5)
    info.external_attr = 0o600 << 16  # rw------- as ZipFile.writestr marks a member it names
    return info


@contextlib.contextmanager
def _behind(out: Any) -> Iterator[Callable[[str | bytes], None]]:
    """A ``write`` whose text (encoded as UTF-8) goes to ``out`` in a thread of its own, a few blocks behind: the
    3MF's deflate (zlib lets go of the GIL) runs while the next block is formatted, instead of after it (a third of
    a 4 M-triangle 3MF's time). The same bytes in the same order; the thread's error (disk full) is raised by the
    next ``write`` or on leaving, and leaving (an error here too) waits for the thread to end."""
    pending: queue.Queue[bytes | None] = queue.Queue(maxsize=2)
    failed: list[BaseException] = []

    def drain() -> None:
        while (data := pending.get()) is not None:
            if not failed:
                try:
                    out.write(data)
                except BaseException as error:  # kept for the caller; the queue is still drained, so no put blocks
                    failed.append(error)

    def write(text: str | bytes) -> None:
        if failed:
            raise failed[0]
        pending.put(text.encode() if isinstance(text, str) else text)

    worker = threading.Thread(target=drain, name="stepterrain-3mf-writer", daemon=True)
    worker.start()
    try:
        yield write
    finally:
        pending.put(None)
        worker.join()
    if failed:
        raise failed[0]


#: 3MF's units (core spec §3.4, the model's ``unit``) by the names of a mesh's ``metadata["units"]`` (trimesh's:
#: "meters", and their singulars and symbols).
_3MF_UNITS: dict[str, str] = {
    **dict.fromkeys(("micron", "microns", "micrometer", "micrometers", "micrometre", "micrometres", "um"), "micron"),
    **dict.fromkeys(("millimeter", "millimeters", "millimetre", "millimetres", "mm"), "millimeter"),
    **dict.fromkeys(("centimeter", "centimeters", "centimetre", "centimetres", "cm"), "centimeter"),
    **dict.fromkeys(("meter", "meters", "metre", "metres", "m"), "meter"),
    **dict.fromkeys(("inch", "inches", "in"), "inch"),
    **dict.fromkeys(("foot", "feet", "ft"), "foot"),
}


#: ``metadata["units"]`` (trimesh's names) for a 3MF's ``unit``, as :func:`_read_3mf` reads it
_3MF_UNIT_NAMES = {"micron": "microns", "millimeter": "millimeters", "centimeter": "centimeters", "meter": "meters",
                   "inch": "inches", "foot": "feet"}


def _3mf_unit(metadata: Mapping[str, Any]) -> str:
    """The 3MF ``unit`` of a mesh: the one its ``metadata["units"]`` names (case-insensitive: a globe's "meters",
    scale_for_print's "millimeters", trimesh's of a mesh it read: a glTF's metres), else metre for a mesh of
    stepterrain's world coordinates, which are metres (:func:`_in_world_metres`: a stepped terrain, a close-up, a
    draped mesh, one read back from a file stepterrain wrote), else millimetre (3MF's default, and the unit slicers
    read a unitless file in: a foreign STL or OBJ). Every 3MF said millimetre: a globe, in metres, came out 1000 times
    too small; and a stepped terrain written straight to .3mf declared millimetres while the same mesh saved as .glb,
    read back and saved as .3mf declared metres."""
    units = metadata.get("units")
    if isinstance(units, str) and units.strip().lower() in _3MF_UNITS:
        return _3MF_UNITS[units.strip().lower()]
    return "meter" if _in_world_metres(metadata) else "millimeter"


def _in_world_metres(metadata: Mapping[str, Any]) -> bool:
    """Whether a mesh's ``metadata`` shows it in stepterrain's world coordinates, metres (a projected DEM's, a
    geographic one's local metres, a .npy's at its spacing in metres): stepterrain made it (its ``generator``,
    ``stepterrain.stepped``, ``stepterrain steps``, ...) or from a Terrain (its ``crs`` or ``source``, as
    :func:`~stepterrain.stepped` and :func:`~stepterrain.closeup` record them). A foreign mesh's read metadata holds
    none of them."""
    generator = metadata.get("generator")
    return (isinstance(generator, str) and generator.startswith("stepterrain")) or "crs" in metadata or (
        "source" in metadata)


def _write_3mf(mesh: trimesh.Trimesh, tmp: Path, target: Path, bounds: Bounds, frame: Bounds) -> None:
    """3MF core + materials: one mesh object, coordinates as written by ``repr`` (exact), in the unit its metadata's
    ``units`` names (:func:`_3mf_unit`; without one, metres for stepterrain's own meshes, millimetres for a foreign
    one), and vertex colours as a ``m:colorgroup`` with each
    triangle's corners' colours (p1, p2, p3; trimesh's writer dropped them), or face colours as each triangle's p1.
    Written by us, streamed into the zip: no lxml or networkx needed. A triangle naming one vertex twice (no area:
    trimesh's loader makes one of a sliver when it merges vertices) is left out: 3MF's v1, v2 and v3 MUST be distinct
    (core spec §4.1.4.1), and it was written as it was. The mesh's metadata is the model's ``<metadata
    name="stepterrain:metadata" preserve="1">`` (its compact JSON text, :func:`_metadata_pieces` joined; the core spec,
    §2.3.1, allows names of other namespaces, the prefix declared on the model; ``preserve`` asks an editor to keep it):
    it was dropped, and a GIS user's 3MF lost its crs."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    distinct = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    color_index = palette = face_index = None
    if mesh.visual.kind == "vertex" and len(mesh.visual.vertex_colors) == len(vertices) and len(vertices):
        rgba = np.ascontiguousarray(np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)[:, :4])
        palette, color_index = np.unique(rgba.view(np.uint32).reshape(-1), return_inverse=True)
        palette = palette.view(np.uint8).reshape(-1, 4)
    elif mesh.visual.kind == "face" and len(faces) and len(mesh.visual.face_colors) == len(faces):
        # one colour per triangle: p1 alone (the core spec: without p2 and p3 it colours the whole triangle); they
        # were dropped
        rgba = np.ascontiguousarray(np.asarray(mesh.visual.face_colors, dtype=np.uint8)[:, :4])
        palette, face_index = np.unique(rgba.view(np.uint32).reshape(-1), return_inverse=True)
        palette = palette.view(np.uint8).reshape(-1, 4)
        face_index = face_index.reshape(-1)[distinct] if not distinct.all() else face_index
    if not distinct.all():
        faces = faces[distinct]
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=5) as archive:
        archive.writestr(_3mf_member("[Content_Types].xml"), _3MF_CONTENT_TYPES)
        archive.writestr(_3mf_member("_rels/.rels"), _3MF_RELS)
        with archive.open(_3mf_member("3D/3dmodel.model"), "w", force_zip64=True) as out, _behind(out) as write:
            text = "".join(_metadata_pieces(mesh.metadata))  # ASCII JSON: only & < > to escape in XML
            own = f' xmlns:{_3MF_PREFIX}="{_3MF_NAMESPACE}"' if text else ""
            write(f'<?xml version="1.0" encoding="UTF-8"?>\n<model unit="{_3mf_unit(mesh.metadata)}" xml:lang="en-US" '
                  'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02" '
                  f'xmlns:m="http://schemas.microsoft.com/3dmanufacturing/material/2015/02"{own}>')
            if text:
                write(f'<metadata name="{_3MF_METADATA}" preserve="1">{xml_escape(text)}</metadata>')
            write(b"<resources>")
            obj = b'<object id="1" type="model">'
            if palette is not None:
                colors = "".join(f'<m:color color="#{r:02X}{g:02X}{b:02X}{a:02X}"/>' for r, g, b, a in palette.tolist())
                write(f'<m:colorgroup id="2">{colors}</m:colorgroup>')
                obj = b'<object id="1" type="model" pid="2" pindex="0">'
            write(obj + b"<mesh><vertices>")
            _write_rows(write, '<vertex x="{!r}" y="{!r}" z="{!r}"/>', _blocks(vertices))
            write(b"</vertices><triangles>")
            if face_index is not None:  # each triangle's colour: its index in the palette
                _write_rows(write, '<triangle v1="{}" v2="{}" v3="{}" p1="{}"/>',
                            _blocks(np.column_stack([faces, face_index.reshape(-1)])))
            elif color_index is None:
                _write_rows(write, '<triangle v1="{}" v2="{}" v3="{}"/>', _blocks(faces))
            else:  # each corner's colour: its vertex's index in the palette
                _write_rows(write, '<triangle v1="{}" v2="{}" v3="{}" p1="{}" p2="{}" p3="{}"/>',
                            (np.concatenate([block, color_index[block]], axis=1) for block in _blocks(faces)))
            write(b'</triangles></mesh></object></resources><build><item objectid="1"/></build></model>')


# One writer per extension: (prepared mesh, temporary path to fill, final target, vertex bounds, the bounds that
# decide how coordinates are stored: save_mesh's shared_bounds, else the vertex bounds) -> None; the glTF writers
# take save_mesh's origin (floored, or None) as a sixth argument.
_WRITERS: dict[str, Callable[..., None]] = {
    ".glb": _write_glb,
    ".gltf": _write_gltf,
    ".obj": _write_obj,
    ".ply": _write_ply,
    ".stl": _write_stl,
    ".3mf": _write_3mf,
}


# ---------------------------------------------------------------------------------------------- reading back
def read_mesh(path: str | os.PathLike[str]) -> trimesh.Trimesh:
    """A mesh file read back as one ``trimesh.Trimesh`` (``process=False``), as ``stepterrain info`` describes it,
    but for an STL: it comes back as stored, three vertices per face (a triangle soup, never watertight), where
    ``stepterrain info`` merges its corners by position first; ``mesh.merge_vertices()`` does so here (a ``steps
    --solid -o print.stl`` is then watertight, as ``info`` says).

    trimesh's reader (``force="mesh"``: a scene's meshes in world coordinates; a glTF's world, y-up by its spec, turned
    z-up, (x, y, z) -> (x, -z, y): a file :func:`save_mesh` wrote gives back exactly the vertices written, to float32's
    rounding about its local origin, and one written before its glTF files were turned y-up, whose nodes were not
    rotated (generator "stepterrain", or a textured mesh whose metadata names a stepterrain generator, as the CLI's
    do, and whose faces face along z where its coordinates are small), as it stands), plus what it misses in the files
    :func:`save_mesh` writes: a file of points (vertices without faces; trimesh reads a point cloud, which
    ``force="mesh"`` dropped) comes back as a mesh without faces, an empty glTF (a node without a mesh) with its
    node's ``extras`` as its metadata (trimesh drops them), a glTF's vertex colours come back as sRGB bytes
    (``COLOR_0`` is linear: trimesh's reader took its values as bytes, darker; a file :func:`save_mesh` wrote gives
    exactly the bytes written), a glTF texture's sampler comes back as its material's ``wrap`` (:func:`texture_wrap`:
    trimesh's reader ignores samplers, so a globe's drape read back rendered its poles blended and was written again
    without it), and a 3MF of one mesh object (as :func:`save_mesh`
    writes it) is read by stepterrain, streamed, with its colour group (trimesh's reader ignores ``m:colorgroup``)
    as vertex colours, or face colours where one vertex has corners of several colours, and its
    ``stepterrain:metadata`` element as the mesh's metadata, and its model's ``unit`` as ``metadata["units"]``
    (``"meters"``; none for millimetres, 3MF's default: a 3MF in metres read and saved again declared millimetres;
    trimesh's reader, for other 3MFs, names it as the file does, ``"meter"``). A PLY's other numeric
    properties of its vertex and face elements (the ``face_attributes`` and ``vertex_attributes`` :func:`save_mesh`
    keeps there, as written: an (N, k) array as columns ``name_0`` ...; a bool, written as uchar 0/1 (PLY has no
    boolean type) and named in a header comment, as bool again, as is a 0/1 ``wall`` beside a ``level`` of a PLY
    stepterrain wrote before it named them, so ``mesh.faces[mesh.face_attributes["wall"]]`` are the walls) come back
    as the mesh's
    ``vertex_attributes`` and ``face_attributes`` (trimesh's reader left them in ``metadata["_ply_raw"]`` only, and
    a mesh read and written again lost them), and the metadata :func:`save_mesh` wrote in its header comments as
    the mesh's ``metadata`` (trimesh's reader skips comments), as are an OBJ's ``# stepterrain-metadata`` comments
    (over trimesh's ``name``; an STL's is only its header). An OBJ whose faces name vertex indices only
    (``f 1 2 3``: one :func:`save_mesh` writes without a texture) keeps the vertices no face names, in their
    order, as the other formats do (trimesh's reader dropped them: ``stepterrain info`` counted fewer vertices than
    were written), also one of several materials (``usemtl``): its faces in the file's order, each with its
    material's colour as its face colour (:func:`_obj_materials_joined`; trimesh's reader repeated each vertex in
    each material it is a corner in, open along the seams); one with texture or normal indices comes back with the
    vertices its faces name, one per distinct (v, vt, vn) corner, and, of several materials, its textures packed into
    one image (trimesh's) and its faces in the file's order where each is a triangle (trimesh's reader gave them
    material by material: :func:`_obj_textured_in_file_order`); where one is a polygon (a quad), material by material
    still, as trimesh's reader gives them: how it orders a material's polygons' triangles depends on the mix of its
    faces (of quads only, every quad's first half, then every second half; mixed, face by face), which is not
    followed here. An OBJ whose lines are indented or whose words are
    separated by tabs reads as with single spaces (trimesh's reader skipped such lines: it came back empty, or as
    its first vertex alone), and a comment after a statement of numbers (``v 0 0 0 # a``, ``f 1 2 3 # x``) is dropped
    (trimesh's reader refused the file; a ``#`` in a name, ``usemtl Material#1``, stays in it: :func:`_obj_tidied`).
    A face's negative index counts back from the ``v`` (``vt``, ``vn``) lines before it, as the OBJ specification
    says (trimesh's reader counted back from the file's end: two objects of ``v v v f -3 -2 -1`` read as the second
    triangle twice; :func:`_obj_absolute_indices`), however many digits it is written with (``-0003``; one of more
    than 18 was left to trimesh's reader; one counting back past the file's start is refused naming its line), and
    ``l`` and ``p`` lines (polylines, points) are not read, whatever their indices' signs, as trimesh's reader skips
    them (the vertices they name are kept where every ``v`` line is). An OBJ whose lines end in a carriage return
    alone, or which starts with a UTF-8 byte-order mark, reads as one with newlines and without it (trimesh's reader
    read the first as one line, an empty mesh, and dropped the second's first vertex; :func:`_obj_newlines`), also
    one of vertices only (points), tidied as the others are. An OBJ whose material library (``mtllib``) or one of
    whose materials' texture images (``map_Kd``) is not where it names it is read without it, with a warning naming
    the file and the path looked for (trimesh's reader said so at debug level only:
    :func:`_warn_obj_missing_side_files`).
    A COFF's vertex colours (trimesh's reader dropped them; a UTF-8 byte-order mark before its keyword skipped, and a
    colour that is no number refused by line) come back as vertex colours, written as integers bytes
    and with a decimal point floats 0..1; integers of 0 and 1 only, which read either way, and vertex lines without
    a colour each or of colours of different lengths are dropped with a warning, the mesh read without them
    (:func:`_off_vertex_colors`). An OFF's face colours (after a face line's indices; trimesh's reader dropped them)
    come back as face colours by the same rules, a polygon's on each of its triangles, face lines some with a colour
    and some without dropped with a warning (:func:`_off_face_colors`; a COFF's vertex colours are kept over them,
    with a warning). A PLY's triangle strips (a ``tristrips`` element and no ``face`` one, as the
    Stanford scanning tools and VCG write them; trimesh's reader skipped them, a mesh of vertices only) come back as
    their triangles, in the strips' winding, a stitch naming a vertex twice dropped.

    Raises
    ------
    InvalidInputError
        ``path`` is not a str or path-like (or holds a NUL character).
    DataFileError
        The file does not exist, is not a regular file, or cannot be read as a mesh: the reader's error (trimesh's,
        whatever its kind: a KeyError for a PLY without x) is in the message and is the ``__cause__``; an OBJ face
        naming a vertex past the file's ``v`` lines (trimesh's IndexError, without a line) is said by its line, index
        and how many ``v`` lines the file has (:func:`_obj_index_out_of_range`), and so is one naming a texture or
        normal index the file has no ``vt`` or ``vn`` line for (trimesh's reader dropped the UVs or normals without a
        word: :func:`_check_obj_texture_indices`). An ``.stl`` must be one (a binary
        STL's length as its header
        counts, an ASCII one's ``solid`` ... ``endsolid``), and an ``.obj`` that trimesh reads as no vertices an empty
        one (OBJ statements and comments only), an ``.obj`` :func:`save_mesh` wrote (or a copy of it of CRLF
        or CR line ends) must end with a newline (one ending mid-line was cut short), as must any ``.obj`` whose
        last line is a face of fewer than 3 corners
        (:func:`_check_obj_cut_short`), and a textured ``.obj`` :func:`save_mesh` wrote read as no faces must have a
        ``vt`` line for each ``v`` line (one cut at a line's end among them: :func:`_check_obj_textured_cut`; a cut
        among its faces leaves a whole-looking file, read as the faces before it), and a ``.ply`` must hold the rows
        its header declares: an STL or
        ASCII PLY cut short, or a file of another format under the extension, is refused, and so is a face naming a
        vertex the file does not have (a PLY's or glTF's index as stored), and so are a ``.glb`` that is empty, not a
        GLB, shorter than its header counts or whose header counts fewer bytes than its headers and JSON chunk
        take (a length of 0), and a glTF without a scene, whose scene holds no node or whose
        ``scene`` names none, each said so; and what trimesh's reader reads wrong without a word: a glTF primitive
        that is a triangle fan (mode 6, skipped) or whose positions, normals or UVs are normalized integers
        (KHR_mesh_quantization's, read unscaled), a glTF of lines only (read as an empty mesh), an OBJ face naming
        index 0 (OBJ counts from 1) and an OBJ vertex of fewer than 3 coordinates (every vertex clipped to its
        length); a binary PLY of triangles and quads mixed (which trimesh's binary reader cannot read) and a glTF
        bufferView past its buffer are said so, and a glTF position that is NaN or infinite is refused, naming the
        vertex as stored (the glTF validator refuses such a file; turned z-up, a NaN coordinate spread over the
        vertex's three, where the other formats' readers keep it where it stands). A PLY's quads and polygons come
        back as triangles (trimesh's ``triangulate_quads``), each with its polygon's face properties. So are,
        each named (trimesh's reader said them with a bare IndexError, KeyError, AssertionError or NumPy's words, or
        not at all): an OFF's face line of an index out of range, overflowing or no integer, a bad counts line and
        an OFF of fewer lines than its counts declare, by line (:func:`_off_problem`); a glTF accessor past the
        file's, of no glTF type, past its bufferView's bytes or naming a missing bufferView, float indices, and a
        buffer holding fewer bytes than its ``byteLength`` (:func:`_gltf_accessor_problem`,
        :func:`_gltf_buffer_problem`), and a ``.gltf`` whose buffer file is not beside it, naming the buffer and the
        path looked for (trimesh's reader: "FileNotFoundError: model.bin"; :func:`_gltf_missing_buffer`; a missing
        texture image is warned of, the mesh read without it: :func:`_warn_gltf_missing_images`; a percent-encoded
        uri, ``a%20b.bin``, names the file ``a b.bin``, as glTF's are: trimesh's reader looked for ``a%20b.bin``,
        :class:`_UriResolver`); a 3MF
        triangle or vertex of an attribute missing, no number or overflowing,
        as written.
    """
    file = _target(path, output=False)
    require_regular_file(file, "mesh file", "mesh file")
    missing: list[tuple[str, Path, bool]] = []  # an OBJ's side files trimesh's reader did not find (_ObjSideFiles)
    noting = _OBJ_MISSING.set(missing)
    try:
        if file.suffix.lower() == ".3mf" and zipfile.is_zipfile(file):
            own = _read_3mf(file)
            if own is not None:
                return own
        gltf = file.suffix.lower() in (".glb", ".gltf")
        color, tree, scene = None, None, None
        tidied: bytes | None = None  # an OBJ's text as trimesh's reader is to read it (_obj_tidied), if not its own
        # an OFF's bytes, read once: trimesh's reader and the header, colour and problem scans take them (the file was
        # opened five times, and read whole three times for a COFF)
        off = file.read_bytes() if file.suffix.lower() == ".off" else None
        if gltf:  # trimesh.load(force="mesh") is load_scene().to_mesh(), which drops COLOR_0 beside a material
            tree = _check_dense_gltf(file)  # its JSON, read once
            stored_z_up = _stored_z_up(tree)
            try:
                scene = _trimesh_read(trimesh.load_scene, file, process=False, resolver=_UriResolver(str(file)))
            except AssertionError as exc:  # trimesh's bare "AssertionError: " for a buffer shorter than it declares
                problem = _gltf_buffer_problem(file, tree)
                if problem is None:
                    raise
                raise ValueError(problem) from exc
            except FileNotFoundError as exc:  # trimesh's "FileNotFoundError: model.bin", the folder unsaid
                problem = _gltf_missing_buffer(file, tree)
                if problem is None:
                    raise
                raise ValueError(problem) from exc
            _check_finite_positions(scene)  # before the turn, which spread a NaN over the vertex's coordinates
            y_up = not (_faces_along_z(scene) if stored_z_up is None else stored_z_up)
            if y_up:  # glTF's world is y-up (§3.4); ours z-up. Exact for save_mesh's files: their turn undone
                scene.apply_transform(_Y_UP_TO_Z_UP)
            color = _color_attribute(scene)
            loaded = scene.to_mesh()
        else:  # an OBJ of faces of vertex indices only keeps the vertices no face names (_obj_faces_kind)
            source: bytes | None = None  # an OBJ's text with newlines for its line ends, where one is a CR alone
            kind: str | None = None
            if file.suffix.lower() == ".obj":
                _check_obj_cut_short(file)
                source = _obj_newlines(file)
                _check_obj_indices(file, source)
                kind = _obj_faces_kind(file, source)
                tidied = _obj_tidied(file, source)
                if kind == "texture":  # trimesh's reader drops UVs (normals) of an index out of range
                    _check_obj_texture_indices(file, tidied if tidied is not None else source, source)
            order = {"maintain_order": True} if kind == "vertices" else {}
            try:
                loaded = None  # several usemtl, faces of vertex indices only: one vertex per v line still
                if kind == "materials":
                    loaded = _obj_materials_joined(file, tidied)
                elif kind == "texture":  # several materials: the faces in the file's order
                    loaded = _obj_textured_in_file_order(file, tidied, source)
                if loaded is None:
                    loaded = _trimesh_read(trimesh.load, file, tidied if off is None else off, force="mesh",
                                           process=False, **order)
            except IndexError:
                if file.suffix.lower() == ".obj":  # a relative index past the file's start, or one past its end,
                    # said by its line
                    _obj_index_out_of_range(file, tidied if tidied is not None else source, source)
                raise
            except (ValueError, OverflowError) as exc:
                if off is not None:  # an OFF: trimesh's error named no line
                    problem = _off_problem(off)
                    if problem is not None:
                        raise ValueError(problem) from exc
                mixed = _ply_binary_mixed_lists(file) if file.suffix.lower() == ".ply" else None
                if mixed is None:
                    raise
                raise ValueError(mixed) from exc
        if isinstance(loaded, trimesh.Trimesh) and len(loaded.vertices) == 0:
            loaded = _read_points(file, scene, tidied if off is None else off) or loaded
            if file.suffix.lower() == ".ply" and len(loaded.faces) == 0:  # trimesh's reader skips triangle strips
                strips = _ply_tristrips(loaded)
                if strips is not None:
                    loaded.faces = strips
            if gltf and len(loaded.vertices) == 0:  # an empty mesh's metadata, in its node's extras
                loaded.metadata.update(_empty_gltf_extras(file, tree))
            if len(loaded.vertices) == 0 and file.suffix.lower() == ".obj":  # trimesh reads anything as an empty OBJ
                _check_format(file)
        if file.suffix.lower() == ".stl":  # anything as an empty STL, and an ASCII one cut short as its first solids
            _check_format(file)
        if isinstance(loaded, trimesh.Trimesh) and np.asarray(loaded.vertices).shape[1:] != (3,):
            # an OBJ's "v 0 1": trimesh's reader clipped every vertex to its shortest
            short = _short_obj_vertex(file, source) if file.suffix.lower() == ".obj" else ""
            raise ValueError(f"a vertex has fewer than 3 coordinates{short}: every vertex needs x, y and z; read as "
                             f"{np.asarray(loaded.vertices).shape[1:]} per vertex")
        if isinstance(loaded, trimesh.Trimesh):  # a PLY's or glTF's indices as stored
            faces, count = np.asarray(loaded.faces), len(loaded.vertices)
            bad = face_outside(faces, count)
            if bad is not None:
                row = faces[bad]
                raise ValueError(f"face {bad} names vertex {int(row[(row < 0) | (row >= count)][0])}, and the file "
                                 f"has {counted(count, 'vertex', 'vertices')}")
        if file.suffix.lower() == ".ply" and isinstance(loaded, trimesh.Trimesh):
            _check_ply_rows(loaded)
            metadata, booleans = _ply_comments(file)
            _ply_attributes(loaded, booleans)
            loaded.metadata.update(metadata)
        if file.suffix.lower() == ".obj" and isinstance(loaded, trimesh.Trimesh):
            if len(loaded.faces) == 0:  # a textured stepterrain OBJ cut short among its v or vt lines
                _check_obj_textured_cut(file, source)
            loaded.metadata.update(_obj_metadata(file, source))
            _warn_obj_missing_side_files(file, missing)
        if off is not None and isinstance(loaded, trimesh.Trimesh):
            counts = _off_counts(off)  # a file cut short read as the faces it has, without a word
            if counts is not None and len(loaded.faces) < counts[1]:
                raise ValueError(_off_problem(off) or f"its counts declare {counted(counts[1], 'face')}, and "
                                 f"{counted(len(loaded.faces), 'triangle')} were read")
            colours = _off_vertex_colors(file, off, len(loaded.vertices))
            if colours is not None:
                loaded.visual = trimesh.visual.ColorVisuals(loaded, vertex_colors=colours)
            shades = _off_face_colors(file, off, *counts, len(loaded.faces)) if counts is not None else None
            if shades is not None and colours is not None:
                warnings.warn(f"{str(file)!r}: an OFF of vertex and face colours: its face colours are dropped, the "
                              "mesh read with its vertex colours", stacklevel=caller_stacklevel())
            elif shades is not None:
                loaded.visual = trimesh.visual.ColorVisuals(loaded, face_colors=shades)
        if gltf and isinstance(loaded, trimesh.Trimesh):
            if color is None and len(loaded.faces) == 0:  # points: trimesh rounds COLOR_0 to bytes, the file's
                color = _gltf_color_0(file, tree)
            _srgb_vertex_colors(loaded, color)
            _gltf_sampler_wrap(loaded, tree)
            loaded.metadata.update(_gltf_extras_name(tree))
            _warn_gltf_missing_images(file, tree)
    except Exception as exc:  # noqa: BLE001 - trimesh and the XML reader raise many kinds for a bad file
        raise DataFileError(f"cannot read {str(file)!r} as a mesh: {type(exc).__name__}: {exc}") from exc
    finally:
        _OBJ_MISSING.reset(noting)
    return loaded  # type: ignore[no-any-return]


def _utf8_name(text: str) -> str:
    """``text`` as UTF-8 can hold it: a file name's undecodable byte (Python's ``'\\udcf6'`` for a Latin-1 ``\\xf6``
    on a UTF-8 system, ``os.fsdecode``'s surrogate escape) as U+FFFD; in a name with any other lone surrogate (U+D800),
    every surrogate as three U+FFFD (one per byte of its encoding). A name so made
    (a glTF node's, an OBJ's ``o`` line and its ``.mtl`` beside it) failed the write with a UnicodeEncodeError, or
    wrote glTF JSON holding a lone surrogate, which its specification and readers refuse."""
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        pass
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
    except UnicodeEncodeError:  # a surrogate that is no escaped byte (U+D800)
        return text.encode("utf-8", "surrogatepass").decode("utf-8", "replace")


#: PLY's scalar types, as NumPy's (without byte order), with those trimesh's reader takes beyond the standard's
#: (int64, uint64, float16): the walk of :func:`_ply_binary_mixed_lists` gave up on a file holding one of them
_PLY_NUMPY = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
              "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "int64": "i8", "uint64": "u8",
              "float16": "f2", "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _ply_binary_mixed_lists(file: Path, rows: int = 65536) -> str | None:
    """Why trimesh's reader refused the binary PLY ``file`` ("PLY is unexpected length!") where its lists (a face's
    vertex indices) have different lengths in its first ``rows`` rows of an element (triangles and quads mixed):
    trimesh's binary reader takes every list as long as the first, so a valid file read as cut short. None where
    the lists its walk saw are all as long (or the header does not parse): a file cut short is one."""
    try:
        with open(file, "rb") as stream:
            if stream.readline().strip() != b"ply":
                return None
            elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
            order = None
            for raw in stream:
                words = raw.decode("ascii", "replace").split()
                if not words:
                    continue
                if words[0] == "end_header":
                    break
                if words[0] == "format" and len(words) > 1:
                    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(words[1])
                elif words[0] == "element" and len(words) == 3:
                    elements.append((words[1], int(words[2]), []))
                elif words[0] == "property" and elements:
                    elements[-1][2].append(tuple(words[1:]))
            else:
                return None
            if order is None:
                return None
            for name, count, properties in elements:
                if not any(prop[0] == "list" for prop in properties):
                    stream.seek(count * sum(np.dtype(_PLY_NUMPY[prop[0]]).itemsize for prop in properties), 1)
                    continue
                first = None
                for row in range(min(count, rows)):
                    for prop in properties:
                        if prop[0] != "list":
                            stream.seek(np.dtype(_PLY_NUMPY[prop[0]]).itemsize, 1)
                            continue
                        size = np.dtype(order + _PLY_NUMPY[prop[1]])
                        blob = stream.read(size.itemsize)
                        if len(blob) < size.itemsize:
                            return None
                        length = int(np.frombuffer(blob, dtype=size)[0])
                        if first is None:
                            first = length
                        elif length != first:
                            return (f"a binary PLY whose {name} lists differ in length ({name} 0's {prop[-1]} has "
                                    f"{first}, {name} {row}'s {length}: triangles and quads mixed, say), which "
                                    "trimesh's binary reader cannot read (it takes every list as long as the first); "
                                    "write it as ASCII PLY, or triangulated")
                        stream.seek(length * np.dtype(_PLY_NUMPY[prop[2]]).itemsize, 1)
                if count > rows:
                    return None
    except (OSError, KeyError, ValueError, IndexError, TypeError):
        return None
    return None


#: The OBJ statements of numbers only (and ``s off``), whose ``#`` can only start a comment
_OBJ_NUMBERS = frozenset({b"v", b"vt", b"vn", b"vp", b"f", b"l", b"p", b"s"})


def _obj_ours(head: bytes) -> bool:
    """Whether an OBJ whose first bytes are ``head`` is one :func:`save_mesh` wrote: its first line ``# written by
    stepterrain`` (after a UTF-8 byte-order mark, if any), ended by LF, CRLF or CR (a copy whose line ends were
    turned to CRLF, by a Windows tool or git's autocrlf, was taken for a foreign file, and its cut went unsaid)."""
    return head.removeprefix(b"\xef\xbb\xbf").startswith((b"# written by stepterrain\n", b"# written by stepterrain\r"))


def _check_obj_cut_short(file: Path) -> None:
    """A ValueError where the OBJ ``file`` was cut short mid-line: one :func:`save_mesh` wrote (its first line
    ``# written by stepterrain``), which ends every line with a newline, not ending in one; or any OBJ whose last line,
    without a newline after it, is a face of fewer than 3 corners. A stepterrain OBJ cut to 50 kB (a copy or download
    interrupted) read as its first 627 vertices and no face, without a word. A file of ``v`` lines and no ``f`` line
    is still read (points), as is a hand-written file whose last line has no newline."""
    with open(file, "rb") as stream:
        head = stream.read(64)
        stream.seek(0, os.SEEK_END)
        size = stream.tell()
        stream.seek(max(size - 4096, 0))
        tail = stream.read()
    if not tail or tail.endswith((b"\n", b"\r")):
        return
    last = tail.rsplit(b"\n", 1)[-1].rsplit(b"\r", 1)[-1]
    words = last.split()
    ours = _obj_ours(head)
    if ours or (words[:1] == [b"f"] and len(words) < 4):
        why = ("stepterrain's OBJ writer ends every line with a newline" if ours else
               f"its last line is a face of {len(words) - 1} corner{'s' * (len(words) != 2)}, where a face needs 3")
        raise ValueError(f"the file is cut short: it ends mid-line ({last[:60].decode('utf-8', 'replace')!r}, "
                         f"{size:,} bytes in all, no newline at its end) and {why}; copy or write it again")


def _check_obj_textured_cut(file: Path, source: bytes | None = None) -> None:
    """A ValueError where the OBJ ``file`` (``source``: its text with newline line ends, :func:`_obj_newlines`), one
    :func:`save_mesh` wrote of a textured mesh (its first line ``# written by stepterrain``, a ``usemtl`` line before
    its first ``v`` line), read as no faces and has fewer ``vt`` lines than ``v`` lines: that writer gives each vertex
    its UV (``vt`` lines as many as the ``v`` lines, then the faces), so such a file was cut short at a line's end,
    among its ``v`` or ``vt`` lines, and read as a mesh of points without a word (:func:`_check_obj_cut_short` finds a
    cut mid-line). A cut among its faces, or any cut of an untextured one, leaves a file no different from a whole
    one of fewer faces (or of points), and is read as such. Run only for a file read as no faces."""
    with _obj_mapped(file, source) as text:
        if text is None or not _obj_ours(text[:64]):
            return
        first = text.find(b"\nv ")
        if first < 0 or text.find(b"\nusemtl ", 0, first) < 0:
            return
        counts = [_obj_count_lines(text, keyword) for keyword in (b"v ", b"vt ")]
    if counts[1] < counts[0]:
        raise ValueError(f"the file is cut short: stepterrain's OBJ writer gives each v line of a textured mesh a vt "
                         f"line, then its faces, and it holds {counted(counts[0], 'v line', 'v lines')}, "
                         f"{counted(counts[1], 'vt line', 'vt lines')} and no face; copy or write it again")


def _obj_count_lines(text: Any, keyword: bytes) -> int:
    """How many lines of the OBJ text ``text`` (bytes or an mmap; its statements starting their lines) start with
    ``keyword`` (``b"vt "``): byte counts over blocks of whole lines (an mmap has no count)."""
    count = 0
    for at, end in _obj_line_blocks(text, _OBJ_INDEX_BLOCK):
        block = text[at:end]
        count += block.count(b"\n" + keyword) + block.startswith(keyword)
    return count


def _obj_trailing_comment(data: Any) -> bool:
    """Whether the OBJ text ``data`` (bytes or an mmap) has a comment after a statement of numbers on its line (``v 0
    0 0 # a``, ``f 1 2 3 # x``): a ``#`` whose line (ended by LF or CR), after the blanks starting it, starts with a
    keyword of :data:`_OBJ_NUMBERS` and a blank (a ``#`` starting a line, after blanks, is a plain comment; one in
    a line of names is part of a name). By NumPy over blocks of whole lines holding a ``#`` (a Python step per
    ``#``, each looked at in its line, took 4.6 s of a 58 MB file of a comment line before each vertex)."""
    at = data.find(b"#")
    if at < 0:
        return False
    start = data.rfind(b"\n", 0, at) + 1
    for begin, end in _obj_line_blocks(data, _OBJ_INDEX_BLOCK, start):
        block = data[begin:end]
        if block.find(b"#") >= 0 and _obj_trailing_comment_in(np.frombuffer(block, dtype=np.uint8)):
            return True
    return False


#: the blanks before an OBJ line's keyword and after it, as :func:`_obj_trailing_comment` takes them
_OBJ_SPACE_TAB = np.isin(np.arange(256), np.frombuffer(b" \t", dtype=np.uint8))


def _obj_trailing_comment_in(text: NDArray[np.uint8]) -> bool:
    """:func:`_obj_trailing_comment` of ``text``, whole lines of an OBJ text."""
    hashes = np.flatnonzero(text == ord("#"))
    breaks = np.flatnonzero((text == ord("\n")) | (text == ord("\r")))
    starts = np.concatenate(([-1], breaks))[np.searchsorted(breaks, hashes)] + 1  # each # line's start
    padded = np.concatenate((text, np.zeros(3, np.uint8)))
    first = _obj_run_ends(padded, starts, _OBJ_SPACE_TAB)  # its first byte that is no blank: the # at the latest
    return bool(_obj_numbers_keyword(padded, first).any())  # a keyword holds no #: the blank after it comes first


def _obj_numbers_keyword(padded: NDArray[np.uint8], at: NDArray[np.int64]) -> NDArray[np.bool_]:
    """Whether a keyword of :data:`_OBJ_NUMBERS` and a blank (space or tab) start at each of the places ``at`` of the
    OBJ text ``padded`` (its bytes, then 3 zeros)."""
    one = np.isin(padded[at], np.frombuffer(b"vflps", np.uint8)) & _OBJ_SPACE_TAB[padded[at + 1]]
    two = ((padded[at] == ord("v")) & np.isin(padded[at + 1], np.frombuffer(b"tnp", np.uint8))
           & _OBJ_SPACE_TAB[padded[at + 2]])
    return one | two  # type: ignore[no-any-return]


#: a carriage return that ends a line alone (not CRLF's)
_OBJ_LONE_CR = re.compile(rb"\r(?!\n)")


def _obj_newlines(file: Path) -> bytes | None:
    """The OBJ ``file``'s text with each line's end a newline, where a line ends in a carriage return alone (classic
    Mac OS's line ends, or such a line in another file), and without the UTF-8 byte-order mark it starts with, if
    any; else None (its lines end in newlines, or CRLF, which trimesh's reader reads). trimesh's reader splits lines
    at newlines only: a file of CR line ends was one line, read as an empty mesh (or refused with NumPy's "could not
    be read to its end"), and this module's scans look for newlines too; a byte-order mark made the first line no
    statement (``v 0 0 0`` dropped: its faces named vertices one further on, or none). Decided by byte searches of
    the file mapped (a file without a carriage return is searched once)."""
    with _obj_mapped(file, None) as mapped:
        if mapped is None:
            return None
        mark = mapped[:3] == b"\xef\xbb\xbf"
        if not mark and (mapped.find(b"\r") < 0 or _OBJ_LONE_CR.search(mapped) is None):  # type: ignore[call-overload]
            return None
        # replaced, not split into lines and joined: a list of lines took 9 times the file's size (346 MB for
        # 39 MB) and 0.4-0.8 s, 5-15 times as long
        text = mapped[3 if mark else 0 :]
        if text.find(b"\r") >= 0:
            text = text.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        return text if text.endswith(b"\n") else text + b"\n"  # type: ignore[no-any-return]


@contextlib.contextmanager
def _obj_mapped(file: Path, source: bytes | None) -> Iterator[Any]:
    """The OBJ ``file``'s bytes to scan: ``source`` where given (:func:`_obj_newlines`), else the file mapped, not read
    (None for an empty file)."""
    import mmap

    if source is not None:
        yield source
        return
    with open(file, "rb") as stream:
        if os.fstat(stream.fileno()).st_size == 0:
            yield None
            return
        with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
            yield mapped


#: an OBJ face line (of a text whose statements start their lines) holding a minus: a relative index
_OBJ_RELATIVE_FACE = re.compile(rb"^f [^\n#]*-", re.MULTILINE)


def _obj_line_starting(data: Any, letter: bytes, start: int = 0) -> int:
    """Where the first line from ``start`` of the OBJ text ``data`` (bytes or an mmap) that starts with ``letter``
    begins, or -1: searched for the one byte (a search for a newline and the letter stopped at every line, twice as
    slow as the file's other scans), each find not at a line's start passed over, up to :data:`_OBJ_PASSED_OVER`
    of them; then searched for the newline and the letter (a Python step per find took 1.1 s of a 58 MB file of a
    comment line before each vertex, each comment's ``f`` and ``v`` passed over in turn)."""
    at = data.find(letter, start)
    for _ in range(_OBJ_PASSED_OVER):
        if at <= 0 or data[at - 1 : at] == b"\n":
            return at  # type: ignore[no-any-return]
        at = data.find(letter, at + 1)
    if at <= 0 or data[at - 1 : at] == b"\n":
        return at  # type: ignore[no-any-return]
    at = data.find(b"\n" + letter, at)
    return at + 1 if at >= 0 else -1  # type: ignore[no-any-return]


#: how many finds of a letter not at a line's start :func:`_obj_line_starting` passes over one by one
_OBJ_PASSED_OVER = 64


def _obj_relative_after_vertices(data: Any) -> bool:
    """Whether the OBJ text ``data`` (bytes or an mmap; its statements start their lines, as :func:`_obj_tidied`
    leaves them) has a face of a relative (negative) index and a ``v``, ``vt`` or ``vn`` line after its first face:
    there the index counts back from the lines before the face, not from the file's end. Byte searches; the face
    lines searched for a minus only in such a file."""
    first = _obj_line_starting(data, b"f")
    if first < 0 or _obj_line_starting(data, b"v", first) < 0:
        return False
    return _OBJ_RELATIVE_FACE.search(data, first) is not None  # type: ignore[call-overload,no-any-return]


#: how far :func:`_obj_absolute_indices` looks from a minus for its field's digits, and back for its word's start
_OBJ_FIELD_REACH = 40
#: a run of decimal digits (of a field longer than :data:`_OBJ_FIELD_REACH`)
_OBJ_DIGITS = re.compile(rb"[0-9]*")


def _obj_lines_starting(padded: NDArray[np.uint8], starts: NDArray[np.int64], keyword: bytes) -> NDArray[np.bool_]:
    """Which of the lines at ``starts`` of an OBJ text (``padded``: its bytes and at least ``len(keyword)`` zeros)
    start with ``keyword``."""
    found = np.ones(len(starts), dtype=bool)
    for k, byte in enumerate(keyword):
        found &= padded[starts + k] == byte
    return found


def _obj_line_blocks(data: Any, block: int, at: int = 0) -> Iterator[tuple[int, int]]:
    """The spans (start, end) of the OBJ text ``data`` (bytes or an mmap) from ``at`` in blocks of whole lines: each
    about ``block`` bytes, ended after the first newline past them (the last at the text's end)."""
    size = len(data)
    while at < size:
        end = data.find(b"\n", min(at + block, size - 1))
        end = size if end < 0 else end + 1
        yield at, end
        at = end


def _obj_absolute_indices(data: bytes) -> bytes:
    """The OBJ text ``data`` (its statements starting their lines) with each face's relative indices (``f -3 -2 -1``,
    ``f -3/-3/-1 ...``: -1 is the last ``v``, ``vt`` or ``vn`` line before the face, by the OBJ specification) as the
    1-based indices they name. trimesh's reader counted them back from the file's end: two objects each of ``v v v
    f -3 -2 -1`` read as the second triangle twice. A ValueError names a line whose index counts back past the
    file's start. Vectorised over the text's bytes (a Python loop over its lines took 3 s for 168,200 faces): each
    minus of a face line that starts a field (after a blank or slash) and is followed by digits to the field's end
    is a relative index, its field (v, vt or vn) counted by the slashes before it in its word; the text is the same
    but for those fields. In blocks of whole lines (:data:`_OBJ_INDEX_BLOCK`): the arrays of the whole text took 56
    times its size (292 MB for 5 MB of one-face objects), a text of 500 MB would have taken 28 GB."""
    pieces = [piece for piece, _ in _obj_absolute_pieces(data)]
    return b"".join(pieces) if len(pieces) != 1 else pieces[0]


def _obj_absolute_pieces(data: Any) -> Iterator[tuple[bytes, NDArray[np.int64]]]:
    """:func:`_obj_absolute_indices` of the OBJ text ``data`` (bytes or an mmap) block by block of whole lines
    (:data:`_OBJ_INDEX_BLOCK`), in turn: each block rewritten, and the ``v``, ``vt`` and ``vn`` lines up to its
    end."""
    seen, lines = np.zeros(3, dtype=np.int64), 0
    for at, end in _obj_line_blocks(data, _OBJ_INDEX_BLOCK):
        block = data[at:end]
        piece, seen = _obj_absolute_block(block, seen, lines)
        yield piece, seen
        lines += block.count(b"\n")


def _obj_index_out_of_range(file: Path, data: bytes | None, source: bytes | None = None) -> None:
    """Raise a ValueError naming the line where a face of the OBJ ``file`` (or of ``data``, its text tidied:
    :func:`_obj_tidied`, whose lines are the file's) names an index out of range; else nothing. For trimesh's
    IndexError, which named no line ("index -4 is out of bounds for axis 0 with size 3", "index 6 is out of bounds
    ...", or for an index of more than 18 digits "index 9223372036854775806 ..."); run only after trimesh's reader
    failed. First a relative index counting back past the file's start (:func:`_obj_absolute_indices`' ValueError),
    where no ``v`` line follows a face (else the text was made absolute before trimesh's reader, and the index
    refused then): its blocks of whole lines looked at in turn, the text not rewritten, which counts the ``v``,
    ``vt`` and ``vn`` lines too. Then a positive index past those lines, naming the index and how many the file has:
    the face lines read one by one in blocks of whole lines, up to the first. The line shown for that is the file's
    own (``source``: its text with newline line ends, :func:`_obj_newlines`), not the tidied one. (Two functions
    before, each mapping the text, the second counting the ``v`` lines again.)"""
    with _obj_mapped(file, data) as text:
        if text is None:
            return
        seen = np.zeros(3, dtype=np.int64)
        for piece in _obj_absolute_pieces(text):  # each block's rewritten text dropped as it comes
            seen = piece[1]
        counts = {kind: int(count) for kind, count in zip((b"v", b"vt", b"vn"), seen, strict=True)}
        hit = _obj_first_past_end(text, counts)
    if hit is None:
        return
    number, found = hit
    row = _obj_line(file, source, number)  # the line as the file writes it (relative indices, blanks, comments)
    kind, field = found
    count = counts[kind]
    shown = field if len(field) <= 40 else field[:40] + "..."
    raise ValueError(f"line {number}, {row.decode('utf-8', 'replace').strip()!r}, names {kind.decode()} {shown}, and "
                     f"the file has {count} {kind.decode()} line{'s' if count != 1 else ''}: an OBJ's indices count "
                     "from 1 to them")


def _obj_first_past_end(text: Any, counts: Mapping[bytes, int]) -> tuple[int, tuple[bytes, str]] | None:
    """The line number (from 1) and :func:`_obj_face_past_end` of the first face line of the OBJ text ``text`` (its
    statements starting their lines) naming an index past ``counts``, else None; blocks of whole lines in turn."""
    lines = 0
    for at, end in _obj_line_blocks(text, _OBJ_INDEX_BLOCK):
        block = text[at:end]
        if block.find(b"f ") >= 0:
            for number, row in enumerate(block.split(b"\n"), lines + 1):
                found = _obj_face_past_end(row, counts) if row.startswith(b"f ") else None
                if found is not None:
                    return number, found
        lines += block.count(b"\n")
    return None


def _obj_line(file: Path, source: bytes | None, number: int) -> bytes:
    """Line ``number`` (from 1) of the OBJ ``file`` (or of ``source``, its text with newline line ends), for an
    error's message."""
    with _obj_mapped(file, source) as text:
        lines = 0
        for at, end in _obj_line_blocks(text, _OBJ_INDEX_BLOCK):
            block = text[at:end]
            count = block.count(b"\n")
            if number <= lines + count or end == len(text):  # its lines, and one without a newline at the end
                return bytes(block.split(b"\n")[number - 1 - lines])
            lines += count
    return b""


def _obj_face_past_end(row: bytes, counts: Mapping[bytes, int]) -> tuple[bytes, str] | None:
    """The slot (``b"v"``, ``b"vt"``, ``b"vn"``) and field of the first positive index of the face line ``row`` past
    ``counts`` lines of its kind, else None."""
    for word in row.split()[1:]:
        for kind, field in zip((b"v", b"vt", b"vn"), word.split(b"/")[:3], strict=False):
            if field[:1].isdigit() or (field[:1] == b"+" and field[1:2].isdigit()):
                try:
                    value = int(field)
                except ValueError:
                    continue
                if value > counts[kind]:
                    return kind, field.decode("ascii", "replace")
    return None


def _check_obj_texture_indices(file: Path, data: bytes | None, source: bytes | None = None) -> None:
    """Raise a ValueError naming the line where a face of the OBJ ``file`` (or of ``data``, its text tidied:
    :func:`_obj_tidied`; ``source``, its text with newline line ends, for the line shown) names a texture (``vt``) or
    normal (``vn``) index the file has no line for: past its ``vt`` (``vn``) lines, or counting back past the first.
    trimesh's reader read such a file without a word: a texture index out of range dropped every UV (the mesh came
    back untextured, its ``.mtl`` image lost) or, where faces of another material read, left that material's UVs
    on the wrong corners; a normal index out of range dropped the file's normals. Its vertex indices are checked
    where trimesh's reader fails on them (:func:`_obj_index_out_of_range`). Found by :func:`_obj_texture_index_outside`
    (NumPy over blocks of whole lines), the line then named by the line-by-line searches, run only then."""
    with _obj_mapped(file, data) as text:
        if text is None or not _obj_texture_index_outside(text):
            return
    _obj_index_out_of_range(file, data, source)
    raise ValueError("a face names a texture (vt) or normal (vn) index the file has no line for")  # not reached


def _obj_texture_index_outside(text: Any) -> bool:
    """Whether a face of the OBJ text ``text`` (bytes or an mmap; its statements starting their lines, as
    :func:`_obj_tidied` leaves them, its relative indices counting back from the file's end: where ``v``, ``vt`` or
    ``vn`` lines follow a face they were made absolute, :func:`_obj_absolute_indices`) names a ``vt`` or ``vn`` index
    past the text's lines of that kind, or a relative one before the first (of more than 18 digits: either), by its
    second and third field (``f v/vt/vn``); a field that is no integer is left to trimesh's reader. In blocks of whole
    lines (:data:`_OBJ_INDEX_BLOCK`), from the slashes of face lines: the field after a word's first slash is its
    ``vt`` index, after its second its ``vn``, each ended by the next blank or slash and read by NumPy at once, the
    extremes of each kind compared with its lines at the end: 0.16 s of CPU for a 52 MB textured OBJ whose read
    takes 2.3 s (a pass over each byte of the face words took three times as long)."""
    lines = np.zeros(3, dtype=np.int64)  # the vt and vn lines (slots 1 and 2)
    highest, lowest = np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64)
    for at, end in _obj_line_blocks(text, _OBJ_INDEX_BLOCK):
        data = text[at:end]
        if data.find(b"/") < 0:
            continue
        block = np.frombuffer(data, dtype=np.uint8)
        newlines = np.flatnonzero(block == ord("\n"))
        padded = np.concatenate((block, np.full(_OBJ_FIELD_WINDOW + 1, ord(" "), np.uint8)))
        face = _obj_lines_starting(padded, np.concatenate(([0], newlines + 1)), b"f ")
        slashes = np.flatnonzero(block == ord("/"))
        if not face.all():  # (a block of face lines only, mostly: each slash's line not looked for)
            slashes = slashes[face[np.searchsorted(newlines, slashes)]]  # of face lines
        if not len(slashes):
            continue
        # each slash's field, the bytes after it up to a blank (tab to CR, space) or slash, read a column at a time
        # for all at once, up to the window (a field's bytes gathered into a table of the window's width took longer)
        values = np.zeros(len(slashes), dtype=np.int64)
        width = np.zeros(len(slashes), dtype=np.int64)
        going = np.ones(len(slashes), dtype=bool)
        wrong = np.zeros(len(slashes), dtype=bool)  # a byte that is no digit (nor a sign first)
        signed = np.zeros(len(slashes), dtype=bool)
        negative = np.zeros(len(slashes), dtype=bool)
        for column in range(_OBJ_FIELD_WINDOW):
            byte = padded[slashes + 1 + column]
            going &= ~((byte == ord("/")) | (byte == ord(" ")) | (byte - 9 <= 4))
            if not going.any():
                break
            digit = byte.astype(np.int64) - ord("0")
            if column == 0:
                negative = going & (byte == ord("-"))
                signed = negative | (going & (byte == ord("+")))
                digit[signed] = 0
            wrong |= going & ((digit < 0) | (digit > 9))
            values = np.where(going, values * 10 + digit, values)
            width += going
        digits = width - signed
        number = ~wrong & (digits >= 1)
        for k in np.flatnonzero(going | (number & (digits > 18))):  # wider than the window, or 19 digits (few)
            field = _OBJ_FIELD.match(data, int(slashes[k]) + 1).group()  # type: ignore[union-attr]
            width[k] = len(field)
            body = field[1:] if field[:1] in (b"+", b"-") else field
            number[k] = body.isdigit() and body.isascii()
            if number[k] and len(body.lstrip(b"0")) > 18:  # more digits than an int64's
                return True
            values[k] = int(body) if number[k] else 0  # (leading zeros)
        # a slash right at the end of the field before it (no blank between) is its word's second (third ...)
        chained = np.zeros(len(slashes), dtype=bool)
        chained[1:] = slashes[:-1] + 1 + width[:-1] == slashes[1:]
        third = np.zeros(len(slashes), dtype=bool)
        third[1:] = chained[1:] & chained[:-1]
        slot = np.where(chained, 2, 1)
        number &= ~third
        values[negative] *= -1
        for kind in (1, 2):
            chosen = values[number & (slot == kind)]
            if len(chosen):
                highest[kind] = max(highest[kind], int(chosen.max()))
                lowest[kind] = min(lowest[kind], int(chosen.min()))
    for kind, keyword in ((1, b"vt "), (2, b"vn ")):  # the lines of each kind a face names, counted
        if highest[kind] or lowest[kind]:
            lines[kind] = _obj_count_lines(text, keyword)
    return bool((highest[1:] > lines[1:]).any() or (-lowest[1:] > lines[1:]).any())


#: the most bytes of an OBJ face's field :func:`_obj_texture_index_outside` reads at once, and a field (the bytes up
#: to a blank or slash) of any length
_OBJ_FIELD_WINDOW = 19
_OBJ_FIELD = re.compile(rb"[^ \t-\r/]*")


#: how many bytes of an OBJ's lines :func:`_obj_absolute_indices` rewrites at once
_OBJ_INDEX_BLOCK = 1 << 20


def _obj_absolute_block(data: bytes, before: NDArray[np.int64], lines: int) -> tuple[bytes, NDArray[np.int64]]:
    """:func:`_obj_absolute_indices` of ``data``, whole lines of an OBJ text after ``lines`` lines holding ``before``
    ``v``, ``vt`` and ``vn`` lines: the lines rewritten, and the ``v``, ``vt`` and ``vn`` lines up to their end."""

    text = np.frombuffer(data, dtype=np.uint8)
    size = len(text)
    newlines = np.flatnonzero(text == ord("\n"))
    starts = np.concatenate(([0], newlines + 1))
    padded = np.concatenate((text, np.zeros(_OBJ_FIELD_REACH + 2, np.uint8)))  # zeros: no digit, no blank
    kinds = [_obj_lines_starting(padded, starts, keyword) for keyword in (b"v ", b"vt ", b"vn ", b"f ")]
    seen = np.stack([np.cumsum(kind) for kind in kinds[:3]]) + before[:, None]  # the v, vt, vn lines up to each
    minus = np.flatnonzero(text == ord("-"))
    line = np.searchsorted(starts, minus, side="right") - 1
    minus, line = minus[kinds[3][line]], line[kinds[3][line]]  # in face lines
    reach = np.arange(1, _OBJ_FIELD_REACH + 1)
    windows = np.lib.stride_tricks.sliding_window_view(padded, _OBJ_FIELD_REACH)
    after = windows[minus + 1]  # the bytes after each minus
    number = (after >= ord("0")) & (after <= ord("9"))
    long = number.all(axis=1)  # more digits than the window holds: its end not seen
    digits = np.argmin(number, axis=1)  # its digits (a zero byte ends them)
    end = after[np.arange(len(minus)), digits]
    for k in np.flatnonzero(long):  # such a field's digits counted one by one (few, if any)
        run = _OBJ_DIGITS.match(data, int(minus[k]) + 1).end()  # type: ignore[union-attr]
        digits[k], end[k] = run - int(minus[k]) - 1, data[run] if run < size else ord(" ")
    before = np.concatenate((np.zeros(1, np.uint8), text))[minus]  # the byte before it
    back = np.lib.stride_tricks.sliding_window_view(np.concatenate((np.zeros(_OBJ_FIELD_REACH, np.uint8), text)),
                                                    _OBJ_FIELD_REACH)[minus][:, ::-1]  # the bytes before it, back
    blank = _OBJ_BLANK[back]
    word = np.argmax(blank, axis=1)  # the bytes back to the blank before its word
    own = ((digits > 0) & (_OBJ_BLANK[end] | (end == ord("/")) | (minus + 1 + digits >= size))
           & (_OBJ_BLANK[before] | (before == ord("/"))) & blank.any(axis=1))  # -3, not 1-2 or -3x
    slot = np.sum((back == ord("/")) & (reach - 1 < word[:, None]), axis=1)  # 0: v, 1: vt, 2: vn
    own &= slot < 3
    minus, line, digits, slot, after, long = minus[own], line[own], digits[own], slot[own], after[own], long[own]
    if not len(minus):
        return data, seen[:, -1]
    # its leading zeros (-0003 is -3) and its value, where its other digits are at most an int64's 18 places (more
    # count back past any file's start: such an index was left as written, trimesh's reader counting it back from
    # the file's end, or overflowing)
    zeros = np.minimum(np.argmin(after == ord("0"), axis=1), digits)
    past = digits - zeros > 18
    for k in np.flatnonzero(long):
        past[k] = len(data[int(minus[k]) + 1 : int(minus[k]) + 1 + int(digits[k])].lstrip(b"0")) > 18
    value = np.zeros(len(minus), dtype=np.int64)
    for k in range(int(np.max(np.where(past | long, 0, digits)))):  # the fields' k-th digits, where they have one
        value = np.where((k < digits) & ~past, value * 10 + after[:, k] - ord("0"), value)
    for k in np.flatnonzero(long & ~past):
        value[k] = int(data[int(minus[k]) + 1 : int(minus[k]) + 1 + int(digits[k])])
    index = np.where(past, 0, seen[slot, line] + 1 - value)
    if (index < 1).any():
        bad = int(np.argmax(index < 1))
        number, kind = int(line[bad]), ("v", "vt", "vn")[int(slot[bad])]
        row = data[starts[number] : (newlines[number] if number < len(newlines) else size)]
        field = f"-{value[bad]}" if not past[bad] else data[minus[bad] : minus[bad] + 1 + digits[bad]].decode()
        raise ValueError(f"line {lines + number + 1}, {row.decode('utf-8', 'replace').strip()!r}, names {kind} "
                         f"{field}, and {seen[slot[bad], number]} {kind} lines come before it: a negative index "
                         "counts back from them")
    width = np.searchsorted(_POWERS_OF_TEN, index, side="right")  # the digits of each index
    owner = np.repeat(np.arange(len(index)), width)
    place = np.repeat(width, width) - 1 - (np.arange(len(owner)) - np.repeat(np.cumsum(width) - width, width))
    written = (index[owner] // _POWERS_OF_TEN[place] % 10 + ord("0")).astype(np.uint8)
    removed = np.repeat(minus, 1 + digits) + (np.arange(int(np.sum(1 + digits)))
                                             - np.repeat(np.cumsum(1 + digits) - 1 - digits, 1 + digits))
    at = np.repeat(minus - (np.cumsum(1 + digits) - 1 - digits), width)  # each field's place once they are removed
    return np.insert(np.delete(text, removed), at, written).tobytes(), seen[:, -1]


def _obj_tidied(file: Path, source: bytes | None = None) -> bytes | None:
    """The OBJ ``file``'s text with each line's blanks around it dropped and its tabs made spaces, where a line starts
    with blanks or holds a tab (as the OBJ format allows: its words are separated by white space), and the comment
    after a statement of numbers (``v``, ``vt``, ``vn``, ``vp``, ``f``, ``l``, ``p``, ``s``: ``v 0 0 0 # a``, ``f 1
    2 3 # x``) dropped, else None. trimesh's reader finds statements by a newline, their keyword and a space: it
    skipped every such line without a word (an OBJ indented, or written with tabs, came back empty or as its first
    vertex alone), and it refused a trailing comment with NumPy's "could not be read to its end due to unmatched
    data". A ``#`` in a line of names (``mtllib``, ``usemtl``, ``o``, ``g``) is kept as part of the name: the OBJ
    specification describes comments as lines starting with ``#``, and tools write names holding one
    (``Material#1``), which trimesh's reader keeps. Decided by byte searches of the file mapped, not read (a large
    OBJ, as :func:`save_mesh` writes it, needs no tidying); read only to be tidied. ``source``: the file's text with
    newline line ends (:func:`_obj_newlines`), returned as it is where it needs no tidying. A face's relative
    indices where ``v`` lines follow faces are made absolute too (:func:`_obj_absolute_indices`)."""
    with _obj_mapped(file, source) as mapped:
        if mapped is None:
            return None
        loose = (mapped[:1] in (b" ", b"\t") or mapped.find(b"\t") >= 0
                 or any(mapped.find(pair) >= 0 for pair in (b"\n ", b"\r ")))
        comments = _obj_trailing_comment(mapped)
        if not comments and not loose:  # source as it is: tidied line by line, a 39 MB one took 0.4-0.7 s more
            return _obj_absolute_indices(mapped[:]) if _obj_relative_after_vertices(mapped) else source
        # in blocks of whole lines, each by byte replacements and regular expressions: a list of the text's lines
        # took 9 times its size (354 MB for 40 MB) and a Python call per line
        pieces = [_obj_tidied_block(mapped[at:end], comments)
                  for at, end in _obj_line_blocks(mapped, _OBJ_INDEX_BLOCK)]
    tidied = b"".join(pieces) if len(pieces) != 1 else pieces[0]
    del pieces
    return _obj_absolute_indices(tidied) if _obj_relative_after_vertices(tidied) else tidied


def _obj_tidied_block(data: bytes, comments: bool) -> bytes:
    """:func:`_obj_tidied` of ``data``, whole lines of an OBJ text: its lines (ended by CR, LF or CRLF) each ended by
    a newline, their tabs made spaces and the blanks around them dropped, and with ``comments`` the comment after a
    statement of numbers dropped with the blanks before it, as ``line.strip(b" \\t").replace(b"\\t", b" ")``, then
    ``line.split(b"#", 1)[0].rstrip(b" ")`` where the line's first word is in :data:`_OBJ_NUMBERS`, did line by line
    (bytes.splitlines). By NumPy over the bytes, each line's first and last byte that is no blank stepped to from its
    ends (a regular expression's substitution took 115 ms a MB for the blanks, 137 for the comments)."""
    text = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n").replace(b"\t", b" ")
    if not text.endswith(b"\n"):  # a newline after the last line, as after the others
        text += b"\n"
    array = np.frombuffer(text, dtype=np.uint8)
    size = len(array)
    newlines = np.flatnonzero(array == ord("\n"))
    starts, ends = np.concatenate(([0], newlines[:-1] + 1)), newlines
    first = _obj_run_ends(array, starts, _OBJ_SPACE)  # each line's first byte that is no blank (or its newline)
    last = _obj_blank_run_starts(text, array, ends, first)  # where the blanks before its newline start
    if comments:
        hashes = np.flatnonzero(array == ord("#"))
        line = np.searchsorted(newlines, hashes)
        firsts = np.ones(len(line), dtype=bool)
        firsts[1:] = line[1:] != line[:-1]
        hashes, line = hashes[firsts], line[firsts]  # each line's first #
        at = first[line]
        padded = np.concatenate((array, np.zeros(3, np.uint8)))
        numbers = _obj_numbers_keyword(padded, at)  # a statement of numbers before the #: a keyword holds none
        hashes, line = hashes[numbers], line[numbers]
        last[line] = _obj_blank_run_starts(text, array, hashes, first[line])  # the comment, the blanks before it
    # the spans dropped, [starts, first) and [last, ends) of each line, apart (first <= last): +1 where one starts,
    # -1 where it stops, each set of places distinct
    marks = np.zeros(size + 1, dtype=np.int8)
    marks[starts] += 1
    marks[first] -= 1
    marks[last] += 1
    marks[ends] -= 1
    return array[np.cumsum(marks[:size], dtype=np.int8) == 0].tobytes()  # type: ignore[no-any-return]


#: the blank :func:`_obj_tidied_block` drops around a line (its tabs made spaces), as a table over the 256 byte values
_OBJ_SPACE = np.arange(256) == ord(" ")


def _obj_blank_run_starts(text: bytes, array: NDArray[np.uint8], at: NDArray[np.int64],
                          floor: NDArray[np.int64]) -> NDArray[np.int64]:
    """For each place ``at`` in the bytes ``array`` (``text``), where the run of spaces just before it starts, not
    before ``floor``: stepped back for all at once a few times (such runs are mostly a byte or two long), the longer
    ones then found one by one (bytes.rstrip)."""
    at = at.copy()
    going = np.flatnonzero((at > floor) & (array[np.maximum(at - 1, 0)] == ord(" ")))
    for _ in range(8):
        if not len(going):
            return at
        at[going] -= 1
        going = going[(at[going] > floor[going]) & (array[np.maximum(at[going] - 1, 0)] == ord(" "))]
    for k in going:
        at[k] = int(floor[k]) + len(text[int(floor[k]) : int(at[k])].rstrip(b" "))
    return at


class _UriResolver(trimesh.resolvers.FilePathResolver):
    """trimesh's resolver of a glTF's side files (its buffers' and images' ``uri``), which un-escapes a uri first:
    glTF 2.0 §3.3's uris are percent-encoded (``"a%20b.png"`` names the file ``a b.png``); trimesh's looked for the
    uri as written, so a buffer so named was refused ("FileNotFoundError: a%20b.bin", the file beside it) and a
    texture so named read untextured without a word. A uri as written is looked for next (a file named ``a%20b.png``,
    as some writers name it)."""

    def get(self, name: str) -> bytes:
        import urllib.parse

        plain = urllib.parse.unquote(name)
        if plain != name:
            try:
                return super().get(plain)  # type: ignore[no-any-return]
            except FileNotFoundError:
                pass
        return super().get(name)  # type: ignore[no-any-return]


#: the side files (``(name, path looked for, asked first)``) trimesh's reader did not find while :func:`read_mesh`
#: reads an OBJ (:class:`_ObjSideFiles`), or None outside it
_OBJ_MISSING: contextvars.ContextVar[list[tuple[str, Path, bool]] | None] = contextvars.ContextVar(
    "stepterrain_obj_missing", default=None)


class _ObjSideFiles(trimesh.resolvers.FilePathResolver):
    """trimesh's resolver of an OBJ's side files (its ``mtllib``, then its materials' ``map_Kd`` images), which notes
    in :data:`_OBJ_MISSING` each one it does not find: trimesh's reader read the mesh without its materials, or a
    material without its texture, saying so at debug level only (:func:`_warn_obj_missing_side_files` warns)."""

    def __init__(self, source: str) -> None:
        super().__init__(source)
        self.asked = 0

    def get(self, name: str) -> bytes:
        self.asked += 1
        try:
            return super().get(name)  # type: ignore[no-any-return]
        except (FileNotFoundError, ValueError):  # not there, or outside the OBJ's folder, where trimesh looks not
            missing = _OBJ_MISSING.get()
            if missing is not None:
                missing.append((name.strip(), Path(self.parent) / name.strip(), self.asked == 1))
            raise


def _warn_obj_missing_side_files(file: Path, missing: list[tuple[str, Path, bool]]) -> None:
    """Warn, naming each and the path looked for, where the OBJ ``file``'s material library (``mtllib``) or a texture
    image of its materials (``map_Kd``) was not found (``missing``, as :class:`_ObjSideFiles` noted them, once each):
    trimesh's reader read the mesh without its materials or that texture, without a word, as
    :func:`_warn_gltf_missing_images` warns of a glTF's."""
    for name, side, library in dict.fromkeys(missing):
        if library:
            warnings.warn(f"{str(file)!r}: the OBJ's material library {name!r} (mtllib, {str(side)!r}) is not there: "
                          "the mesh is read without its materials (copy the .mtl and its images with the .obj)",
                          stacklevel=caller_stacklevel())
        else:
            warnings.warn(f"{str(file)!r}: the OBJ's texture image {name!r} (map_Kd, {str(side)!r}) is not there: "
                          "the mesh is read without that texture (copy the image files with the .obj and its .mtl)",
                          stacklevel=caller_stacklevel())


def _trimesh_read(load: Callable[..., Any], file: Path, data: bytes | None = None, **kwargs: Any) -> Any:
    """``load(file, **kwargs)`` (``trimesh.load`` or ``trimesh.load_scene``), also for a ``file`` whose name is no
    UTF-8 (a Latin-1 ``h\\xf6he.ply`` on a UTF-8 system, which Python names ``'h\\udcf6he.ply'``): trimesh names the
    scene node after the file and encodes that name as UTF-8, so such a file was refused ("cannot read ... 'utf-8'
    codec can't encode character '\\udcf6' ... surrogates not allowed"). It is read from the open file then, its side
    files (an OBJ's material and textures, a glTF's buffers) found beside it as before, and named as its name reads
    with the undecodable bytes as U+FFFD (``metadata["name"]``, which every writer can store). ``data``: the file's
    contents to read instead of the file's own (an OBJ tidied, :func:`_obj_tidied`; an OFF's bytes, read once), its side
    files and name still those of ``file``. A ``resolver`` in ``kwargs`` (:class:`_UriResolver`) finds the side files of
    either."""
    name = _utf8_name(file.name)
    if file.suffix.lower() == ".obj" and kwargs.get("resolver") is None:  # its missing side files noted
        kwargs["resolver"] = _ObjSideFiles(str(file))
    if name == file.name and data is None:
        return load(file, **kwargs)
    resolver = kwargs.pop("resolver", None) or trimesh.resolvers.FilePathResolver(str(file))  # the folder
    resolver.file_name = name  # an OBJ's geometry is named by it
    # typed as trimesh types a path: an h\xf6he.tar.gz is a "tar.gz" (its last suffix, "gz", trimesh does not read)
    file_type = trimesh.util.split_extension(file.name, special=["tar.gz", "tar.bz2"]).lower()
    with (file.open("rb") if data is None else io.BytesIO(data)) as stream:
        loaded = load(stream, file_type=file_type, resolver=resolver, **kwargs)
    # named after the files in it, as for a plain name; a tidied OBJ of a plain name is named as its file is read
    # (trimesh's OBJ reader names it by the resolver's file_name; its OFF reader, read from bytes, "geometry_0")
    if file_type in trimesh.exchange.load.compressed_loaders or (name == file.name and file_type == "obj"):
        return loaded
    for item in [loaded, *getattr(loaded, "geometry", {}).values()]:
        metadata = getattr(item, "metadata", None)
        if isinstance(metadata, dict):  # a file name (trimesh's "geometry_0" for a stream) as for a plain name
            metadata.update({key: name for key in ("name", "node") if key in metadata})
    return loaded


#: PLY properties trimesh's reader makes into the mesh itself (positions, normals, colours, UVs, faces): not attributes.
_PLY_OWN = {
    "vertex": frozenset({"x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha", "s", "t", "u", "v",
                         "texture_u", "texture_v"}),
    "face": frozenset({"vertex_indices", "vertex_index", "red", "green", "blue", "alpha", "texcoord"}),
}  # fmt: skip


def _ply_tristrips(mesh: trimesh.Trimesh) -> NDArray[np.int64] | None:
    """The triangles of the ``tristrips`` element of the PLY ``mesh`` was read from, where it has no ``face`` element
    (as the Stanford scanning repository's tools and VCG write strips: each row a list of vertex indices, -1 ending a
    strip and starting the next), else None. Triangle k of a strip is (s[k], s[k+1], s[k+2]), its odd ones turned
    (s[k+1], s[k], s[k+2]) to keep the strip's winding; a triangle naming one vertex twice (a strip's stitch) is
    dropped, as VCG drops it. trimesh's reader skipped the element: the mesh came back as its vertices alone."""
    raw = (mesh.metadata or {}).get("_ply_raw")
    if not isinstance(raw, Mapping) or "face" in raw or not isinstance(raw.get("tristrips"), Mapping):
        return None
    data = raw["tristrips"].get("data")
    rows: Any = None
    for name in ("vertex_indices", "vertex_index"):
        if isinstance(data, Mapping) and name in data:  # an ASCII file's columns
            rows = data[name]
        elif isinstance(data, np.ndarray) and data.dtype.names and name in data.dtype.names:  # a binary one's rows
            rows = data[name]
            rows = rows["f1"] if rows.dtype.names and "f1" in rows.dtype.names else rows  # (count, indices)
        if rows is not None:
            break
    if rows is None:
        return None
    triangles: list[NDArray[np.int64]] = []
    for row in rows:
        indices = np.asarray(row, dtype=np.int64).ravel()
        for strip in np.split(indices, np.flatnonzero(indices < 0)):
            strip = strip[strip >= 0]  # the -1 that starts each piece but the first
            if len(strip) < 3:
                continue
            k = np.arange(len(strip) - 2)
            odd = (k % 2).astype(bool)
            first, second = np.where(odd, strip[k + 1], strip[k]), np.where(odd, strip[k], strip[k + 1])
            tri = np.stack([first, second, strip[k + 2]], axis=1)
            triangles.append(tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])])
    return np.concatenate(triangles) if triangles else np.zeros((0, 3), np.int64)


def _check_ply_rows(mesh: trimesh.Trimesh) -> None:
    """Raise a ValueError where an element of the PLY ``mesh`` was read from holds fewer rows than its header
    declares: trimesh's ASCII reader takes the rows there are, so an ASCII PLY cut short read as the faces (or
    points) before the cut (a binary one is refused by trimesh for its length)."""
    raw = (mesh.metadata or {}).get("_ply_raw")
    if not isinstance(raw, Mapping):
        return
    for element, values in raw.items():
        declared = values.get("length") if isinstance(values, Mapping) else None
        data = values.get("data") if isinstance(values, Mapping) else None
        if isinstance(data, np.ndarray):
            rows = len(data)
        elif isinstance(data, Mapping) and data:
            rows = min(len(column) for column in data.values())
        else:
            continue
        if isinstance(declared, (int, np.integer)) and rows < declared:
            raise ValueError(f"not a whole PLY file: its header declares {declared} {element} rows, the file holds "
                             f"{rows}; is it cut short?")


def _ply_attributes(mesh: trimesh.Trimesh, booleans: Mapping[str, Iterable[str]] | None = None) -> None:
    """Give ``mesh``, read from a PLY, the other numeric scalar properties of its vertex and face elements as its
    ``vertex_attributes`` and ``face_attributes`` (one per vertex or face; trimesh's reader keeps them only in
    ``metadata["_ply_raw"]``); the columns ``booleans`` names by element (:func:`_ply_comments`: bools written as
    uchar 0/1) as bool again."""
    booleans = booleans or {}
    raw = (mesh.metadata or {}).get("_ply_raw")
    if not isinstance(raw, Mapping):
        return
    for element, attributes, count in (("vertex", mesh.vertex_attributes, len(mesh.vertices)),
                                       ("face", mesh.face_attributes, len(mesh.faces))):  # fmt: skip
        data = (raw.get(element) or {}).get("data") if isinstance(raw.get(element), Mapping) else None
        if isinstance(data, np.ndarray) and data.dtype.names:
            columns = {name: data[name] for name in data.dtype.names}
        elif isinstance(data, Mapping):
            columns = dict(data)
        else:
            continue
        flags = set(booleans.get(element, ()))
        # a PLY of quads or polygons: trimesh cut them into triangles, each to carry its polygon's values
        source = _ply_face_source(columns, count) if element == "face" else None
        if element == "face" and "stepped" in booleans and {"level", "wall"} <= set(columns):
            flags.add("wall")
        for name, column in columns.items():
            column = np.asarray(column)
            if column.ndim == 2 and column.shape[1] == 1:  # an ASCII PLY's scalar beside a list, as trimesh reads it
                column = column[:, 0]
            if source is not None and column.ndim == 1 and len(column) != count:
                column = column[source]
            if name in _PLY_OWN[element] or column.ndim != 1 or column.dtype.kind not in "biuf" or len(column) != count:
                continue
            column = column.astype(column.dtype.newbyteorder("="))
            if name in flags and column.dtype.kind in "bu" and column.max(initial=0) <= 1:
                column = column.astype(bool)  # written from a bool: `faces[wall]` took rows 0 and 1, not the walls
            attributes.setdefault(str(name), column)


def _ply_face_source(columns: Mapping[str, Any], count: int) -> NDArray[np.int64] | None:
    """For each of the ``count`` triangles trimesh's reader made of a PLY's faces (``columns``, its face element's
    data), the face it was cut from: trimesh triangulates quads and polygons (``triangulate_quads``: the triangles
    first, then the quads' first halves, their second halves, then the polygons' fans), so a face property, one value
    per polygon, is one per triangle taken from these. Found by triangulating the polygons again with each corner
    numbered after its face, whatever that order. None where the faces were triangles (one each) or cannot be
    matched."""
    indices = next((columns[name] for name in ("vertex_indices", "vertex_index") if name in columns), None)
    if indices is None:
        return None
    indices = np.asarray(indices)
    if indices.dtype.names and "f1" in indices.dtype.names:  # a binary PLY's list: (count, indices)
        indices = indices["f1"]
    if len(indices) == count or len(indices) == 0:
        return None
    if indices.dtype == object:
        lengths = np.fromiter((len(face) for face in indices), dtype=np.int64, count=len(indices))
    elif indices.ndim == 2:
        lengths = np.full(len(indices), indices.shape[1], dtype=np.int64)
    else:
        return None
    widest = int(lengths.max())
    # corner k of face i as i * widest + k: any triangle of it names i by // widest
    numbered = [np.arange(i * widest, i * widest + size, dtype=np.int64) for i, size in enumerate(lengths.tolist())]
    if len(set(lengths.tolist())) == 1:
        numbered = np.array(numbered)  # type: ignore[assignment]
    triangles = np.asarray(trimesh.geometry.triangulate_quads(numbered))
    if triangles.ndim != 2 or len(triangles) != count:
        return None
    return triangles[:, 0] // widest  # type: ignore[no-any-return]


def _color_attribute(scene: Any) -> NDArray[Any] | None:
    """The COLOR_0 values, as stored (float32, or normalised integers), of a glTF scene of one mesh whose material
    trimesh read as a texture without UVs (it keeps COLOR_0 as the visual's vertex attribute, which the scene's
    ``to_mesh`` drops); None otherwise."""
    geometries = list(getattr(scene, "geometry", {}).values())
    if len(geometries) != 1 or not isinstance(geometries[0], trimesh.Trimesh):
        return None
    color = getattr(geometries[0].visual, "vertex_attributes", {}).get("color")
    return None if color is None else np.asarray(color)


def _srgb_vertex_colors(mesh: trimesh.Trimesh, color: NDArray[Any] | None) -> None:
    """Give ``mesh``, read from a glTF file, its vertex colours as sRGB bytes, as the other formats hold them:
    COLOR_0 is linear (glTF 2.0 §3.7.2.1) and trimesh's reader takes its values as bytes as they are. Exact from
    the stored COLOR_0 (``color``, :func:`_color_attribute`: a file :func:`save_mesh` wrote), else from trimesh's
    bytes. A primitive with a material trimesh reads as a texture without UVs, its COLOR_0 a vertex attribute: one
    whose material only multiplies by white (:func:`_terrain_material`) is read as the plain or vertex-coloured
    mesh it is. (The file was read a second time for COLOR_0: 1.3 s more for a 169 MB .gltf.)"""
    visual = mesh.visual
    plain = visual.kind == "texture" and getattr(visual, "uv", None) is None and _white_material(visual.material)
    if visual.kind != "vertex" and not plain:
        return
    if color is not None and color.ndim == 2 and len(color) == len(mesh.vertices) and len(color):
        values = color.astype(np.float64) / (1.0 if color.dtype.kind == "f" else np.iinfo(color.dtype).max)
    elif plain:  # a material and no COLOR_0 (or one that does not fit): plain
        mesh.visual = trimesh.visual.ColorVisuals(mesh)
        return
    else:
        values = np.asarray(mesh.visual.vertex_colors, dtype=np.float64) / 255.0
    rgba = np.ones((len(values), 4))
    rgba[:, : values.shape[1]] = values[:, :4]
    rgba[:, :3] = _linear_to_srgb(rgba[:, :3])
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.rint(np.clip(rgba, 0, 1) * 255).astype(np.uint8))


def _gltf_sampler_wrap(mesh: trimesh.Trimesh, tree: Any) -> None:
    """Give the material of ``mesh``, read from a glTF whose JSON is ``tree`` (:func:`_check_dense_gltf`'s), the wrap
    modes of its base colour texture's sampler as its ``wrap`` (:func:`texture_wrap`), where the primitives' textures
    all have the same ones and they are not glTF's default (REPEAT both ways). trimesh's reader ignores samplers: a
    globe's drape read back (u repeated, v clamped) rendered with each pole blended with the other in the mipmaps,
    and was written again without its sampler."""
    material = getattr(mesh.visual, "material", None)
    if mesh.visual.kind != "texture" or getattr(material, "baseColorTexture", None) is None:
        return
    if not isinstance(tree, Mapping):
        return

    def entry(within: Any, key: str, index: Any) -> Mapping[str, Any]:
        """within[key][index] where that is a JSON object, else {} (a file of odd JSON is left to trimesh)."""
        items = within.get(key) if isinstance(within, Mapping) else None
        ok = isinstance(items, list) and isinstance(index, int) and 0 <= index < len(items)
        return items[index] if ok and isinstance(items[index], Mapping) else {}

    def member(within: Mapping[str, Any], key: str) -> Mapping[str, Any]:
        value = within.get(key)
        return value if isinstance(value, Mapping) else {}

    names = {code: name for name, code in GLTF_WRAP.items()}
    modes: set[tuple[str | None, ...]] = set()
    meshes = tree.get("meshes")
    for k in range(len(meshes) if isinstance(meshes, list) else 0):
        primitives = entry(tree, "meshes", k).get("primitives")
        for n in range(len(primitives) if isinstance(primitives, list) else 0):
            material_json = entry(tree, "materials", entry(entry(tree, "meshes", k), "primitives", n).get("material"))
            base = member(member(material_json, "pbrMetallicRoughness"), "baseColorTexture")
            if not base:  # an untextured primitive
                continue
            sampler = entry(tree, "samplers", entry(tree, "textures", base.get("index")).get("sampler"))
            codes = (sampler.get("wrapS", GLTF_WRAP["REPEAT"]), sampler.get("wrapT", GLTF_WRAP["REPEAT"]))
            modes.add(tuple(names.get(code) if type(code) is int else None for code in codes))
    if len(modes) != 1:  # no texture read, or textures wrapped differently (trimesh packs them into one image)
        return
    (wrap,) = modes
    if None not in wrap and wrap != ("REPEAT", "REPEAT"):  # (an unknown mode: the file is invalid; left as default)
        material.wrap = wrap


def _white_material(material: Any) -> bool:
    """True for a PBR material of a glTF that sets no texture and a white (or no) base colour factor: it leaves the
    vertex colours (or white) as they are."""
    if not isinstance(material, trimesh.visual.material.PBRMaterial) or material.baseColorTexture is not None:
        return False
    factor = material.baseColorFactor
    return factor is None or bool((np.asarray(factor) == 255).all())


def _glb_json(stream: BinaryIO, head: bytes) -> Any:
    """The JSON chunk of a GLB (glTF 2.0 §4.4.3: its first chunk) parsed, ``head`` the file's first 20 bytes (its
    header and the chunk's) read from ``stream``, which is left after the chunk, at the binary chunk's header. A
    struct.error where ``head`` is too short for the chunk's length, json's ValueError for a chunk cut short."""
    return json.loads(stream.read(struct.unpack_from("<I", head, 12)[0]))


def _check_dense_gltf(file: Path) -> dict[str, Any] | None:
    """Raise a ValueError where a primitive of the glTF or GLB ``file`` takes its positions or indices from a sparse
    accessor (glTF 2.0 §3.6.2.3: base values, or zeros, with some elements replaced): trimesh's reader ignores the
    replacements, so the mesh came back with the base values (a terrain flat at z = 0) without a word; and where the
    file requires a compression trimesh's reader cannot decode here (Draco without DracoPy: every position 0, with
    a log line only; meshopt); and where a ``.gltf`` is not JSON. Reads the JSON only (a GLB's chunk), and gives it
    back (None where it cannot be read: a GLB whose JSON cannot be read is left to trimesh's reader)."""
    try:
        with open(file, "rb") as stream:
            head = stream.read(20)
            if file.suffix.lower() == ".gltf" and head[:4] == b"glTF":
                raise ValueError("a GLB (binary glTF: it starts with b'glTF') under the extension .gltf, which names "
                                 "the JSON form: rename it .glb")
            if file.suffix.lower() == ".glb" and head[:4] != b"glTF":  # trimesh's reader: IndexError, "header"
                raise ValueError("not a GLB: an empty file" if not head else
                                 f"not a GLB: a binary glTF starts with b'glTF'; this file with {head[:4]!r}")
            if head[:4] == b"glTF":  # glTF 2.0 §4.4.2: the header's third uint32 counts the whole file's bytes
                declared = struct.unpack_from("<I", head, 8)[0] if len(head) >= 12 else None
                size = file.stat().st_size
                if len(head) < 20 or (declared is not None and size < declared):
                    counts = "" if declared is None else f"its header counts {declared:,} bytes, "
                    raise ValueError(f"a GLB cut short: {counts}the file has {size:,}")
                least = 20 + struct.unpack_from("<I", head, 12)[0]  # its header, the JSON chunk's header and data
                # 0: trimesh's reader read no buffer (IndexError); 1 to least - 1 it read, from a file that is no GLB
                if declared is not None and declared < least:
                    raise ValueError(f"not a valid GLB: its header counts {declared:,} bytes for the whole file, fewer "
                                     f"than its headers and JSON chunk take ({least:,}; glTF 2.0 §4.4.2)")
                tree = _glb_json(stream, head)
            elif file.suffix.lower() == ".gltf":
                text = head + stream.read()
                try:
                    tree = json.loads(text)
                except ValueError as exc:  # trimesh's reader said "FileNotFoundError: model.gltf" of random bytes
                    why = f"{type(exc).__name__}: {exc}"
                    raise ValueError(f"not a glTF file: its JSON does not parse ({why})") from None
            else:
                return None  # not a GLB: trimesh's reader says so
        scenes = tree.get("scenes") if isinstance(tree, dict) else None
        if isinstance(tree, dict) and not scenes:  # trimesh's reader: KeyError 'world'
            raise ValueError("the glTF holds no scene ('scenes' missing or empty; glTF 2.0 §3.5): no node places a "
                             "mesh in its world")
        if isinstance(scenes, list):  # trimesh: IndexError, KeyError 'world'
            index = tree.get("scene", 0)
            if type(index) is int and index >= len(scenes):
                raise ValueError(f"the glTF's 'scene' is {index}, but it holds {len(scenes)} scene(s) (glTF 2.0 §3.5)")
            scene = scenes[index] if type(index) is int else None
            if isinstance(scene, dict) and not scene.get("nodes"):
                raise ValueError(f"the glTF's scene {index} holds no node (glTF 2.0 §3.5: 'nodes' missing or empty): "
                                 "no node places a mesh in its world")
        required = set(tree.get("extensionsRequired") or [])
        if "KHR_draco_mesh_compression" in required and importlib.util.find_spec("DracoPy") is None:
            raise ValueError("the glTF's meshes are Draco-compressed (KHR_draco_mesh_compression), which trimesh's "
                             "reader decodes only with DracoPy installed (pip install DracoPy); without it, it reads "
                             "every position as 0")
        if "EXT_meshopt_compression" in required:
            raise ValueError("the glTF's buffers are meshopt-compressed (EXT_meshopt_compression, required), which "
                             "trimesh's reader cannot decode (it reads the compressed bytes as positions): write the "
                             "file without that compression")
        buffers = tree.get("buffers") or []
        for number, view in enumerate(tree.get("bufferViews") or []):  # trimesh's reader: "AssertionError: ", bare
            which = view.get("buffer") if isinstance(view, dict) else None
            if type(which) is int and 0 <= which < len(buffers) and isinstance(buffers[which], dict):
                end = view.get("byteOffset", 0) + view.get("byteLength", 0)
                size = buffers[which].get("byteLength")
                if isinstance(size, int) and isinstance(end, int) and end > size:
                    raise ValueError(f"glTF bufferView {number} ends at byte {end:,} of buffer {which}, which holds "
                                     f"{size:,} bytes (glTF 2.0 §3.6.1): the file is cut short or not valid")
        accessors = tree.get("accessors") or []
        modes = [primitive.get("mode", 4) for mesh in tree.get("meshes") or [] if isinstance(mesh, dict)
                 for primitive in mesh.get("primitives") or [] if isinstance(primitive, dict)]
        if modes and all(mode in _GL_LINE_MODES for mode in modes):  # read as an empty mesh, its positions lost
            raise ValueError("the glTF holds lines only (primitive modes LINES, LINE_LOOP or LINE_STRIP), no "
                             "triangles or points: not a mesh (trimesh.load_path reads its lines)")
        for mesh in tree.get("meshes") or []:
            for primitive in mesh.get("primitives") or []:
                if primitive.get("mode") == _GL_TRIANGLE_FAN:  # trimesh's reader skips it: its surface left out
                    raise ValueError("a glTF primitive is a TRIANGLE_FAN (mode 6), which trimesh's reader skips (the "
                                     "file read without that surface, or as no scene): write it as triangles (mode 4)")
                attributes = primitive.get("attributes") or {}
                for name, index in [*attributes.items(), ("indices", primitive.get("indices"))]:
                    problem = _gltf_accessor_problem(tree, name, index)  # trimesh: IndexError, KeyError, reshape
                    if problem is not None:
                        raise ValueError(problem)
                used = [("POSITION", attributes.get("POSITION")), ("indices", primitive.get("indices"))]
                for name, index in used:
                    if isinstance(index, int) and 0 <= index < len(accessors) and accessors[index].get("sparse"):
                        sparse = f"glTF accessor {index} (a primitive's {name}) is sparse"
                        raise ValueError(f"{sparse}, which trimesh's reader reads as its base values alone: write "
                                         "the file without sparse accessors (Blender and most exporters do)")
                for name, index in attributes.items():  # colours: _color_attribute scales them
                    if ((name in ("POSITION", "NORMAL") or str(name).startswith("TEXCOORD_"))
                            and isinstance(index, int) and 0 <= index < len(accessors)
                            and accessors[index].get("normalized") is True):
                        raise ValueError(
                            f"glTF accessor {index} (a primitive's {name}) holds normalized integers "
                            "(KHR_mesh_quantization: 65535 for 1.0), which trimesh's reader reads as the integers "
                            "(a mesh or its UVs thousands of times too large): write the file unquantized, or with "
                            "integer positions and a node scale (gltfpack -vpi), or floats (gltfpack -vpf)")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, struct.error, AttributeError, TypeError):
        return None
    return tree if isinstance(tree, dict) else None


def _gltf_buffer_problem(file: Path, tree: Mapping[str, Any] | None) -> str | None:
    """Which buffer of the glTF ``file`` (``tree``: its JSON) holds fewer bytes than its ``byteLength`` declares (a
    GLB's BIN chunk, a data URI's or a file beside it), said with both counts, else None. trimesh's reader said
    such a file with a bare "AssertionError: ". Run only after trimesh's reader failed."""
    import base64
    import urllib.parse

    if not isinstance(tree, Mapping):
        return None
    for number, buffer in enumerate(tree.get("buffers") or []):
        declared = buffer.get("byteLength") if isinstance(buffer, Mapping) else None
        if type(declared) is not int:
            continue
        uri = buffer.get("uri")
        if uri is None and number == 0 and file.suffix.lower() == ".glb":
            data = file.read_bytes()
            at = 20 + struct.unpack_from("<I", data, 12)[0] if len(data) >= 20 else len(data)
            held, where = (struct.unpack_from("<I", data, at)[0] if len(data) >= at + 8 else 0), "the GLB's BIN chunk"
            held = min(held, max(0, len(data) - at - 8))
        elif isinstance(uri, str) and uri.startswith("data:"):
            try:
                held, where = len(base64.b64decode(uri.split(",", 1)[1])), "its data URI"
            except (ValueError, IndexError):
                continue
        elif isinstance(uri, str):
            side = file.parent / urllib.parse.unquote(uri)
            if not side.is_file():
                continue
            held, where = side.stat().st_size, f"its file {str(side)!r}"
        else:
            continue
        if held < declared:
            return (f"glTF buffer {number} declares {declared:,} bytes (byteLength), and {where} holds {held:,}: the "
                    "file is cut short or not valid (glTF 2.0 §3.6.1)")
    return None


def _gltf_missing_buffer(file: Path, tree: Mapping[str, Any] | None) -> str | None:
    """Which buffer of the glTF ``file`` (``tree``: its JSON) names a file (its ``uri``, relative to the glTF's folder)
    that is not there, said with the path looked for and the buffers' count, else None. trimesh's reader said such a
    file with "FileNotFoundError: model.bin" (the buffer's name alone: which folder, and that it is a buffer the
    glTF names, unsaid). Run only after trimesh's reader failed."""
    buffers = tree.get("buffers") if isinstance(tree, Mapping) else None
    for number, buffer in enumerate(buffers if isinstance(buffers, list) else []):
        missing = _gltf_file_missing(file, buffer)
        if missing is not None:
            uri, side = missing
            return (f"glTF buffer {number} (of {len(buffers)}) is the file {uri!r}, and {str(side)!r} does not exist: "
                    "a .gltf's buffers lie beside it (copy the .bin files with it, or write a .glb, which holds them)")
    return None


def _gltf_file_missing(file: Path, entry: Any) -> tuple[str, Path] | None:
    """(its ``uri``, the path looked for) where the glTF buffer or image ``entry`` of the glTF ``file`` names a file
    (its ``uri``, percent-encoded, relative to the glTF's folder; not a ``data:`` URI) that is not there, else None."""
    import urllib.parse

    uri = entry.get("uri") if isinstance(entry, Mapping) else None
    if not isinstance(uri, str) or uri.startswith("data:"):
        return None
    side = file.parent / urllib.parse.unquote(uri)
    if side.is_file() or (file.parent / uri).is_file():  # (trimesh's reader looks for the uri as written)
        return None
    return uri, side


def _warn_gltf_missing_images(file: Path, tree: Mapping[str, Any] | None) -> None:
    """Warn, naming each, where an image of the glTF ``file`` (``tree``: its JSON) is a file (its ``uri``, relative to
    the glTF's folder) that is not there: trimesh's reader read the mesh without that texture, without a word (the
    geometry is whole: the mesh is read, untextured there)."""
    images = tree.get("images") if isinstance(tree, Mapping) else None
    missing = []
    for number, image in enumerate(images if isinstance(images, list) else []):
        found = _gltf_file_missing(file, image)
        if found is not None:
            missing.append(f"image {number}, {found[0]!r} ({str(found[1])!r})")
    if missing:
        warnings.warn(f"{str(file)!r}: the glTF's {'; '.join(missing)} {'is' if len(missing) == 1 else 'are'} not "
                      "there: the mesh is read without that texture (copy the image files with the .gltf, or write "
                      "a .glb, which holds them)", stacklevel=caller_stacklevel())


#: glTF 2.0 §3.6.2.2: the bytes of an accessor's component types, and the components of its element types
_GLTF_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_GLTF_TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _gltf_accessor_problem(tree: Mapping[str, Any], name: str, index: Any) -> str | None:
    """What is wrong with the accessor ``index`` a primitive of the glTF ``tree`` (its JSON) takes as its ``name``
    (an attribute, or ``"indices"``), else None (also for an accessor of no buffer view, or a sparse one, which the
    caller sees to): an index past the accessors, no ``type`` or ``componentType`` of glTF 2.0's, indices not of
    unsigned integers (trimesh's reader read float indices' bits as integers, without a word), a bufferView past the
    file's, or elements past their bufferView's bytes. trimesh's reader said these with IndexError "list index out
    of range", KeyError 'type' or NumPy's "cannot reshape array of size 9 into shape (1000,3)"."""
    if index is None and name == "indices":
        return None
    accessors, views = tree.get("accessors") or [], tree.get("bufferViews") or []
    said = f"a glTF primitive's {name} names accessor {index!r}"
    if type(index) is not int or not 0 <= index < len(accessors) or not isinstance(accessors[index], dict):
        return f"{said}, and the file has {len(accessors)} accessor(s) (glTF 2.0 §3.6.2)"
    accessor = accessors[index]
    kind, component = accessor.get("type"), accessor.get("componentType")
    if kind not in _GLTF_TYPE_COMPONENTS or component not in _GLTF_COMPONENT_BYTES:
        return (f"{said}, whose type {kind!r} and componentType {component!r} are not glTF 2.0's (§3.6.2.2: "
                f"{', '.join(_GLTF_TYPE_COMPONENTS)}; {', '.join(map(str, _GLTF_COMPONENT_BYTES))})")
    if name == "indices" and (kind != "SCALAR" or component not in (5121, 5123, 5125)):
        return (f"{said} of {kind} {component}: indices are SCALAR unsigned bytes, shorts or ints (5121, 5123, "
                "5125; glTF 2.0 §3.7.2.1)")
    view = accessor.get("bufferView")
    if view is None or accessor.get("sparse"):
        return None
    if type(view) is not int or not 0 <= view < len(views) or not isinstance(views[view], dict):
        return f"{said}, whose bufferView is {view!r}, and the file has {len(views)} bufferView(s)"
    count, offset = accessor.get("count"), accessor.get("byteOffset", 0)
    size = _GLTF_COMPONENT_BYTES[component] * _GLTF_TYPE_COMPONENTS[kind]
    stride, length = views[view].get("byteStride") or size, views[view].get("byteLength")
    if not all(type(value) is int for value in (count, offset, stride, length)):
        return None  # trimesh's reader says so
    if count > 0 and offset + stride * (count - 1) + size > length:
        return (f"{said} of {count:,} {kind} elements from byte {offset:,} of bufferView {view}, whose "
                f"{length:,} bytes hold {max(0, (length - offset - size) // stride + 1):,} of them: the file is "
                "cut short or not valid (glTF 2.0 §3.6.2.4)")
    return None


#: glTF 2.0 §3.7.2.1: a primitive's mode 6, triangles sharing its first vertex, which trimesh's reader skips.
_GL_TRIANGLE_FAN = 6
#: glTF 2.0 §3.7.2.1: the primitive modes of lines (LINES, LINE_LOOP, LINE_STRIP), which no mesh holds
_GL_LINE_MODES = (1, 2, 3)


def _check_finite_positions(scene: trimesh.Scene) -> None:
    """Raise ValueError naming the first vertex of a glTF ``scene`` (as stored) that is not finite: the glTF
    validator refuses NaN and infinite accessor values (ACCESSOR_INVALID_FLOAT), and the turn z-up (a matrix product,
    0 · NaN = NaN) spread one NaN coordinate over its vertex's three, without a word; save_mesh writes none."""
    for name, geometry in getattr(scene, "geometry", {}).items():
        vertices = np.asarray(getattr(geometry, "vertices", np.zeros((0, 3))), dtype=np.float64)
        bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1)) if vertices.ndim == 2 else []
        if len(bad):
            x, y, z = vertices[bad[0]].tolist()
            raise ValueError(f"mesh {name!r} has {counted(len(bad), 'vertex', 'vertices')} with NaN or inf, vertex "
                             f"{bad[0]} first, at ({x}, {y}, {z}) as stored: glTF positions must be finite")


def _stored_z_up(tree: dict[str, Any] | None) -> bool | None:
    """True for a glTF whose world holds z up, against glTF's convention (§3.4: +Y up): one stepterrain wrote before it
    turned its meshes y-up, no node rotated (its nodes held a translation at most) and generator "stepterrain" (its
    own writer), or, a textured mesh, which trimesh's writer wrote under trimesh's generator, a mesh whose ``extras``
    name a stepterrain generator (the metadata the CLI writes: ``texture --mesh``, ``globe --texture``; those read on
    their edge when only the asset's generator was looked at) with a node matrix of its offset (a translation). Such
    a file without a matrix (small coordinates) is None, undecided: the same as a stepterrain glTF that trimesh
    loaded as a mesh (its y-up world) and wrote again, the extras kept; :func:`read_mesh` then looks at which way its
    faces face (:func:`_faces_along_z`). Every other glTF is y-up (False), and :func:`read_mesh` turns it z-up."""
    if not isinstance(tree, dict) or not isinstance(tree.get("asset"), dict):
        return False
    nodes, meshes = tree.get("nodes"), tree.get("meshes")
    if not isinstance(nodes, list):
        return False
    if any(isinstance(node, dict) and ("rotation" in node or not _translation_matrix(node.get("matrix")))
           for node in nodes):
        return False
    if tree["asset"].get("generator") == "stepterrain":
        return True
    ours = isinstance(meshes, list) and any(
        isinstance(mesh, dict) and isinstance(mesh.get("extras"), dict)
        and str(mesh["extras"].get("generator", "")).split(" ")[0] == "stepterrain" for mesh in meshes)
    if not ours:
        return False
    return True if any(isinstance(node, dict) and "matrix" in node for node in nodes) else None


def _faces_along_z(scene: trimesh.Scene) -> bool:
    """True where the faces of ``scene`` (its world, as stored) face along z, mostly one way (a z-up terrain's, summed
    by area), more than along y; False for a y-up terrain, and for a closed surface (a globe, a box) facing no
    one way."""
    net, total = np.zeros(3), np.zeros(3)
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry.get(name)
        if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces):
            normals = (np.asarray(transform)[:3, :3] @ (geometry.face_normals * geometry.area_faces[:, None]).T).T
            net += normals.sum(axis=0)
            total += np.abs(normals).sum(axis=0)
    net = np.abs(net)  # x is x in either frame: z against y only
    return bool(net[2] > net[1] and net[2] > 0.5 * total[2])


def _translation_matrix(matrix: Any) -> bool:
    """True for a glTF node's ``matrix`` (column-major, 16 numbers) that translates at most, or none given."""
    if matrix is None:
        return True
    try:
        m = np.asarray(matrix, dtype=np.float64).reshape(4, 4).T
    except (TypeError, ValueError):
        return False
    return bool(np.array_equal(m[:3, :3], np.eye(3)) and np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]))


def _empty_gltf_extras(file: Path, tree: Any = None) -> dict[str, Any]:
    """The ``extras`` of the one node of a glTF or GLB ``file`` without meshes: an empty mesh as :func:`save_mesh`
    writes it, its metadata there (glTF has no mesh without a primitive), which trimesh's reader drops: ``stepterrain
    info`` of a batch's tile of sea showed none of the metadata of its other tiles. {} for any other file. ``tree``:
    the file's JSON where :func:`_check_dense_gltf` has read it (None: read here)."""
    if tree is None:
        try:
            with open(file, "rb") as stream:
                head = stream.read(20)
                tree = _glb_json(stream, head) if head[:4] == b"glTF" else json.loads(head + stream.read())
        except (OSError, ValueError, struct.error):
            return {}
    nodes = tree.get("nodes") if isinstance(tree, dict) else None
    if tree.get("meshes") or not isinstance(nodes, list) or len(nodes) != 1 or not isinstance(nodes[0], dict):
        return {}
    extras = nodes[0].get("extras")
    return dict(extras) if isinstance(extras, dict) else {}


def _gltf_extras_name(tree: Any) -> dict[str, Any]:
    """``{"name": ...}`` from the ``extras`` of the one mesh of a glTF whose JSON is ``tree``, where they hold one
    (the metadata :func:`save_mesh` wrote), else {}: trimesh's reader merges the extras into the metadata but puts
    the mesh's (or node's) own name over theirs, so a name given as metadata came back as the file's stem, where
    the other formats give it back as written."""
    meshes = tree.get("meshes") if isinstance(tree, dict) else None
    if not isinstance(meshes, list) or len(meshes) != 1 or not isinstance(meshes[0], dict):
        return {}
    extras = meshes[0].get("extras")
    return {"name": extras["name"]} if isinstance(extras, dict) and "name" in extras else {}


def _gltf_color_0(file: Path, tree: Any = None) -> NDArray[np.float64] | None:
    """The COLOR_0 values, in [0, 1], of a glTF or GLB ``file`` holding one mesh of one primitive with its buffer
    embedded (as :func:`save_mesh` writes it); None for any other layout. Read for a file of points, whose colours
    trimesh's PointCloud holds only as rounded bytes. ``tree``: the file's JSON where :func:`_check_dense_gltf` has
    read it (None: read here; a GLB's binary chunk is read past it)."""
    try:
        with open(file, "rb") as stream:
            head = stream.read(20)
            if head[:4] == b"glTF":
                if tree is None:
                    tree = _glb_json(stream, head)
                else:  # to the binary chunk's header, after the JSON chunk (as _glb_json leaves the stream)
                    stream.seek(20 + struct.unpack_from("<I", head, 12)[0])
                chunk = stream.read(8)  # the binary chunk's header: its length
                binary = stream.read()[: struct.unpack_from("<I", chunk)[0]] if len(chunk) == 8 else b""
            else:
                if tree is None:
                    tree = json.loads(head + stream.read())
                uri = (tree.get("buffers") or [{}])[0].get("uri", "")
                if not uri.startswith("data:"):
                    return None
                binary = base64.b64decode(uri.split(",", 1)[1])
        meshes = tree.get("meshes") or []
        if len(meshes) != 1 or len(meshes[0].get("primitives", [])) != 1 or len(tree.get("buffers", [])) != 1:
            return None
        index = meshes[0]["primitives"][0].get("attributes", {}).get("COLOR_0")
        if index is None:
            return None
        accessor = tree["accessors"][index]
        view = tree["bufferViews"][accessor["bufferView"]]
        dtype = {_GL_FLOAT: np.dtype("<f4"), 5121: np.dtype("u1"), 5123: np.dtype("<u2")}.get(accessor["componentType"])
        width = {"VEC3": 3, "VEC4": 4}.get(accessor["type"])
        if dtype is None or width is None or view.get("byteStride", dtype.itemsize * width) != dtype.itemsize * width:
            return None
        start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
        values = np.frombuffer(binary, dtype, accessor["count"] * width, start).reshape(-1, width).astype(np.float64)
    except (OSError, ValueError, KeyError, IndexError, TypeError, AttributeError, struct.error):
        return None
    return values if dtype.kind == "f" else values / np.iinfo(dtype).max


#: An OBJ face statement with a texture or normal index (``f 1/1 2/2 3/3``, ``f 1//1 ...``) and a material statement.
_OBJ_FACE_WITH_SLASH = re.compile(rb"^[ \t]*f[ \t][^\n#]*/", re.MULTILINE)
_OBJ_USEMTL = re.compile(rb"^[ \t]*usemtl[ \t]", re.MULTILINE)
_OBJ_FACE = re.compile(rb"^[ \t]*f[ \t]", re.MULTILINE)
#: an OBJ vertex of fewer than three coordinates
_OBJ_SHORT_VERTEX = re.compile(rb"^[ \t]*v[ \t]+(?:[^ \t\r\n#]+[ \t]+)?[^ \t\r\n#]*[ \t]*(?:#[^\r\n]*)?\r?$",
                               re.MULTILINE)


#: tables over the 256 byte values: the bytes before an index 0 of an OBJ face (a blank, or the slash before a texture
#: or normal index), a zero, the bytes after an index's zeros that make it no index 0 (``10``, ``0.5``, ``0e1``), and
#: the blanks bytes.strip() drops within a line (before its keyword)
_OBJ_ZERO_BEFORE = np.isin(np.arange(256), np.frombuffer(b" \t/", dtype=np.uint8))
_OBJ_ZERO_DIGIT = np.arange(256) == ord("0")
_OBJ_ZERO_AFTER = np.isin(np.arange(256), np.frombuffer(b"0123456789.eE", dtype=np.uint8))
_OBJ_LINE_BLANK = np.isin(np.arange(256), np.frombuffer(b" \t\r\x0b\x0c", dtype=np.uint8))
#: how many bytes of an OBJ's lines :func:`_check_obj_indices` looks at at once (its arrays' memory bounded by it)
_OBJ_ZERO_BLOCK = 1 << 24


def _obj_run_ends(text: NDArray[np.uint8], at: NDArray[np.int64], table: NDArray[np.bool_]) -> NDArray[np.int64]:
    """From each of the places ``at`` in ``text`` (which ends in a byte outside ``table``), the first place whose byte
    is outside ``table``: stepped for all of them at once a few times (such runs are mostly a byte or two long), the
    longer ones then searched one by one."""
    at = at.copy()
    going = np.flatnonzero(table[text[at]])
    for _ in range(8):
        if not len(going):
            return at
        at[going] += 1
        going = going[table[text[at[going]]]]
    if len(going):
        outside = re.compile(b"[^" + b"".join(re.escape(bytes([int(b)])) for b in np.flatnonzero(table)) + b"]")
        data = text.tobytes()
        for k in going:
            at[k] = outside.search(data, int(at[k])).start()  # type: ignore[union-attr]
    return at


def _obj_zero_in_block(text: NDArray[np.uint8]) -> int:
    """Where in ``text`` (whole lines of an OBJ, the last ending in a newline) the blank or slash before the first
    index 0 of a face line is (as :func:`_check_obj_indices` looks for it), or -1."""
    zeros = np.flatnonzero(text[1:] == ord("0")) + 1
    signs = (text[zeros - 1] == ord("-")) | (text[zeros - 1] == ord("+"))  # -0, +0: index 0 too
    before = zeros - 1 - signs
    first = (before >= 0) & _OBJ_ZERO_BEFORE[text[np.maximum(before, 0)]]  # a number's first zero: after a blank or /
    zeros, before = zeros[first], before[first]
    if len(zeros):
        kept = ~_OBJ_ZERO_AFTER[text[_obj_run_ends(text, zeros, _OBJ_ZERO_DIGIT)]]  # 0, 00: not 10, 0.5
        zeros, before = zeros[kept], before[kept]
    if not len(zeros):
        return -1
    newlines = np.flatnonzero(text == ord("\n"))
    starts = np.concatenate(([0], newlines + 1))[np.searchsorted(newlines, before)]  # each one's line
    first = _obj_run_ends(text, starts, _OBJ_LINE_BLANK)  # its line's first byte that is no blank
    after = text[np.minimum(first + 1, len(text) - 1)]  # (a first byte that is the last is a newline, no f)
    face = (text[first] == ord("f")) & ((after == ord(" ")) | (after == ord("\t")))
    hashes = np.flatnonzero(text == ord("#"))
    last = np.searchsorted(hashes, before) - 1  # the last # before it (f 1 2 3 # 0 apples: a comment's zero)
    commented = (last >= 0) & (hashes[np.maximum(last, 0)] >= starts) if len(hashes) else np.zeros(len(before), bool)
    found = np.flatnonzero(face & ~commented)
    return int(before[found[0]]) if len(found) else -1


def _obj_first_face_line(data: Any) -> int:
    """Where the first line of the OBJ text ``data`` (bytes or an mmap) whose first byte but blanks is ``f`` begins, or
    -1: each ``f`` found in turn (a byte search), only its own line looked at, then on from the next line."""
    at = data.find(b"f")
    while at >= 0:
        start = data.rfind(b"\n", 0, at) + 1
        if not bytes(data[start:at]).strip():
            return start  # type: ignore[no-any-return]
        end = data.find(b"\n", at)
        at = -1 if end < 0 else data.find(b"f", end)
    return -1


def _check_obj_indices(file: Path, source: bytes | None = None) -> None:
    """Raise a ValueError where a face of the OBJ ``file`` names index 0, which names nothing (OBJ counts from 1, and
    back from -1): trimesh's reader took it as the first vertex and shifted none of the others, so ``f 0 1 2`` read as
    the degenerate face (0, 0, 1) without a word. Scanned without reading the file into memory (``source``: its text
    with newline line ends, :func:`_obj_newlines`, scanned instead), from its first face on (an indented one too,
    which the scan from the first line starting with ``f`` passed over: `` f 0 1 2`` read as (0, 0, 1)): the
    vertices mostly come first, and their zeros are not looked at. A signed zero, ``-0`` or ``+0``, is index 0 too
    (it read as the first vertex, or where ``v`` lines follow faces as the one after the face:
    :func:`_obj_absolute_indices`). By NumPy over blocks of whole lines (a regular expression's search, then a
    Python loop over the zero coordinates of the ``v`` lines after a face, took 0.4 s of a 47 MB OBJ's read, and
    0.63 s for one of 168,000 faces before its vertices)."""
    with _obj_mapped(file, source) as data:
        if data is None:
            return
        first = _obj_first_face_line(data)
        if first < 0:
            return
        size = len(data)
        for at, end in _obj_line_blocks(data, _OBJ_ZERO_BLOCK, first):
            if data[end - 1 : end] == b"\n":  # the block looked at in place
                view = np.frombuffer(data, dtype=np.uint8, count=end - at, offset=at)
            else:  # the last line, and no newline after it
                view = np.frombuffer(bytes(data[at:end]) + b"\n", dtype=np.uint8)
            found = _obj_zero_in_block(view)
            del view  # no view of the mapped file outlives it
            if found >= 0:
                found += at
                start = data.rfind(b"\n", 0, found) + 1
                stop = data.find(b"\n", found)
                text = data[start : stop if stop >= 0 else size]
                line = data[:start].count(b"\n") + 1  # a copy, on the way to the error only
                break
        else:
            return
    raise ValueError(f"line {line}, {text.decode('utf-8', 'replace').strip()!r}, names index 0, which names nothing: "
                     "an OBJ's indices count from 1 (or back from -1)")


def _short_obj_vertex(file: Path, source: bytes | None = None) -> str:
    """The first ``v`` line of the OBJ ``file`` (or of ``source``, its text with newline line ends:
    :func:`_obj_newlines`) with fewer than three coordinates, as ``" (line N, 'v 0 1')"``, or ``""``."""
    with open(file, "rb") if source is None else io.BytesIO(source) as stream:
        for number, row in enumerate(stream, 1):
            if _OBJ_SHORT_VERTEX.match(row.rstrip(b"\n")):
                return f" (line {number}, {row.decode('utf-8', 'replace').strip()!r})"
    return ""


def _obj_faces_kind(file: Path, source: bytes | None = None) -> str:
    """How the OBJ ``file``'s faces are read, from one scan of it (mapped, not read into memory): ``"texture"`` where a
    face names a texture or normal index (``f 1/1 2/2 3/3``, ``f 1//1 ...``), or the file is empty (trimesh's
    reader, by default); else ``"vertices"`` where it has at most one ``usemtl``, before any face: what
    :func:`save_mesh` writes for a mesh without a texture; else ``"materials"`` (several ``usemtl``, or faces before
    its one, a group of their own), read by :func:`_obj_materials_joined`. trimesh's reader keeps every ``v`` with
    ``maintain_order=True`` (by default it drops the vertices no face names, so ``stepterrain info`` counted fewer
    than were written, and a mesh read back was renumbered); with texture or normal indices that option takes one UV
    per vertex (a vertex on a UV seam got the median of its UVs) and lost the texture of a file with unused vertices,
    and with several ``usemtl`` it repeated every vertex in each material's mesh. ``source``: the file's text with
    newline line ends (:func:`_obj_newlines`), scanned instead."""
    with _obj_mapped(file, source) as data:  # no match object outlives it
        if data is None:
            return "texture"
        if data.find(b"/") >= 0 and _OBJ_FACE_WITH_SLASH.search(data) is not None:  # type: ignore[call-overload]
            return "texture"
        if data.find(b"usemtl") < 0:
            return "vertices"
        first = _OBJ_USEMTL.search(data)  # type: ignore[call-overload]
        if first is None:
            return "vertices"
        start, end = first.span()
        del first
        # one material, for every face: not a second usemtl, nor faces before this one (a group of their own)
        one = (_OBJ_USEMTL.search(data, end) is None  # type: ignore[call-overload]
               and _OBJ_FACE.search(data, 0, start) is None)  # type: ignore[call-overload]
        return "vertices" if one else "materials"


#: the bytes an OBJ line's words are separated by (bytes.split's white space), as a table over the 256 byte values
_OBJ_BLANK = np.isin(np.arange(256), np.frombuffer(b" \t\r\n\x0b\x0c", dtype=np.uint8))
#: 10 ** k for the 18 places of a decimal int64 (a table: NumPy's power of an array took twice the read's other steps)
_POWERS_OF_TEN = 10 ** np.arange(18, dtype=np.int64)


def _obj_chunk_faces(data: bytes) -> tuple[list[bytes | None], list[NDArray[np.int64]]] | None:
    """The OBJ text ``data``'s faces of vertex indices only, per ``usemtl`` chunk in the file's order: each chunk's
    material name (None before the first ``usemtl``) and its triangles as 0-based indices into the file's ``v``
    lines (a negative index counted back from the ``v`` lines before it; a quad split as trimesh's reader splits it,
    (a, b, c) and (c, d, a), a larger polygon as a fan from its first corner; a face of fewer than 3 corners
    skipped). None where a face does not read so. Vectorised over the text's bytes (a Python loop over its lines
    took 1.3 s of a 2.2 s read of 90,000 vertices in two materials): the lines found by their newlines, each face
    line's words by the blanks before them, the numbers read by NumPy at once, in blocks of whole lines
    (:data:`_OBJ_INDEX_BLOCK`: the arrays of the whole text took 28 times its size, 285 MB for 10 MB)."""
    names: list[bytes | None] = [None]
    faces, owners, seen = [], [], 0
    for at, end in _obj_line_blocks(data, _OBJ_INDEX_BLOCK):
        read = _obj_chunk_block(data[at:end], seen, len(names) - 1)
        if read is None:
            return None
        names += read[0]
        faces.append(read[1])
        owners.append(read[2])
        seen = read[3]
    joined = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    bounds = np.searchsorted(np.concatenate(owners) if owners else np.zeros(0, np.int64), np.arange(1, len(names)))
    return names, np.split(joined, bounds)


def _obj_block_lines(data: bytes) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64], NDArray[np.uint8]]:
    """The lines of ``data``, whole lines of an OBJ text, for NumPy scans: its bytes, each line's start and its
    newline (or the text's end), and its bytes padded with 8 zeros (for :func:`_obj_lines_starting`)."""
    text = np.frombuffer(data, dtype=np.uint8)
    newlines = np.flatnonzero(text == ord("\n"))
    starts = np.concatenate(([0], newlines + 1))
    ends = np.append(newlines, len(text))
    return text, starts, ends, np.concatenate((text, np.zeros(8, np.uint8)))


def _obj_usemtl_names(data: bytes, starts: NDArray[np.int64], ends: NDArray[np.int64],
                      usemtl: NDArray[np.bool_]) -> list[bytes | None]:
    """The material names of the ``usemtl`` lines (``usemtl``: which of the lines at ``starts`` to ``ends`` of
    ``data`` are), in order."""
    return [data[start + 7 : end].strip() for start, end in zip(starts[usemtl], ends[usemtl], strict=True)]


def _obj_chunk_block(data: bytes, before: int, chunks: int) -> tuple[list[bytes | None], NDArray[np.int64],
                                                                      NDArray[np.int64], int] | None:
    """:func:`_obj_chunk_faces` of ``data``, whole lines of an OBJ text after ``before`` ``v`` lines and ``chunks``
    ``usemtl`` lines: its ``usemtl`` names, its triangles, each one's chunk, and the ``v`` lines up to its end; None
    where a face does not read so."""
    text, starts, ends, padded = _obj_block_lines(data)
    size = len(text)
    vertex, face, usemtl = (_obj_lines_starting(padded, starts, keyword) for keyword in (b"v ", b"f ", b"usemtl "))
    names = _obj_usemtl_names(data, starts, ends, usemtl)
    seen = np.cumsum(vertex) - vertex + before  # the v lines before each line
    chunk = np.cumsum(usemtl) + chunks  # each line's usemtl chunk
    # the face lines' words: the bytes after "f " up to and with the newline (a blank between lines)
    marks = np.zeros(size + 2, dtype=np.int8)
    marks[starts[face] + 2] += 1
    marks[ends[face] + 1] -= 1
    blank = _OBJ_BLANK[text]
    where = np.flatnonzero(np.cumsum(marks[:size], dtype=np.int8).view(bool) & ~blank)  # the words' bytes
    byte = text[where].astype(np.int64)
    heads = np.flatnonzero(blank[where - 1])  # each word's first byte, in where (a word starts after a blank)
    lengths = np.diff(np.append(heads, len(where)))
    signs = np.isin(byte[heads], (ord("-"), ord("+")))
    digit = byte - ord("0")
    digit[heads[signs]] = 0  # a sign is allowed as a word's first byte only
    if (digit < 0).any() or (digit > 9).any() or (lengths - signs < 1).any() or (lengths - signs > 18).any():
        return None  # not a plain integer (trimesh's reader decides; an int64 holds 18 digits)
    places = np.repeat(heads + lengths, lengths) - 1 - np.arange(len(where))  # each digit's place from its word's end
    corners = np.add.reduceat(digit * _POWERS_OF_TEN[places], heads) if len(heads) else np.zeros(0, np.int64)
    corners[byte[heads] == ord("-")] *= -1
    line = np.searchsorted(starts, where[heads], side="right") - 1
    corners = np.where(corners > 0, corners - 1, seen[line] + corners)
    lines = np.flatnonzero(face)
    counts = np.bincount(line, minlength=len(starts))[lines]
    offsets = np.cumsum(counts) - counts
    keep = counts >= 3
    lines, counts, offsets = lines[keep], counts[keep], offsets[keep]
    triangles = counts - 2
    owner = np.repeat(np.arange(len(lines)), triangles)
    j = np.arange(len(owner)) - np.repeat(np.cumsum(triangles) - triangles, triangles)
    at = offsets[owner]
    picks = np.column_stack([at, at + j + 1, at + j + 2])  # a fan from the first corner
    second = (counts[owner] == 4) & (j == 1)  # a quad's second triangle: (c, d, a)
    picks[second] = np.column_stack([at[second] + 2, at[second] + 3, at[second]])
    return names, corners[picks].reshape(-1, 3), chunk[lines][owner], before + int(np.count_nonzero(vertex))


def _obj_triangle_materials(data: Any) -> list[bytes | None] | None:
    """The ``usemtl`` name of each face line of the OBJ text ``data`` (bytes or an mmap; statements starting their
    lines), in the file's order (None before the first ``usemtl``), where every face is a triangle (3 corners, no
    comment) and it names two materials or more; else None. By NumPy over blocks of whole lines, after a count of its
    ``usemtl`` lines (a file of one, as :func:`save_mesh` writes a textured mesh, is not scanned)."""
    if _obj_count_lines(data, b"usemtl ") < 2:
        return None
    names: list[bytes | None] = [None]
    owners = []
    for at, end in _obj_line_blocks(data, _OBJ_INDEX_BLOCK):
        block = bytes(data[at:end])
        text, starts, ends, padded = _obj_block_lines(block)
        face, usemtl = (_obj_lines_starting(padded, starts, keyword) for keyword in (b"f ", b"usemtl "))
        chunk = np.cumsum(usemtl) + len(names) - 1  # each line's usemtl chunk
        names += _obj_usemtl_names(block, starts, ends, usemtl)
        blank = _OBJ_BLANK[text]
        heads = np.flatnonzero(~blank & np.concatenate(([True], blank[:-1])))  # each word's first byte
        words = np.bincount(np.searchsorted(starts, heads, side="right") - 1, minlength=len(starts))
        if (words[face] != 4).any() or (b"#" in block and (text[heads] == ord("#")).any()):
            return None  # a polygon (trimesh's reader orders its triangles apart) or a comment
        owners.append(chunk[face])
    owner = np.concatenate(owners) if owners else np.zeros(0, np.int64)
    if len(set(names[1:])) < 2:
        return None
    return [names[k] for k in owner.tolist()]


def _obj_textured_in_file_order(file: Path, data: bytes | None, source: bytes | None) -> trimesh.Trimesh | None:
    """The textured OBJ ``file`` (``data``: its text tidied, :func:`_obj_tidied`, if it is; ``source``: its text with
    newline line ends, :func:`_obj_newlines`, if made) of several materials, read as trimesh's reader reads it
    (``force="mesh"``: one mesh per material, joined, its textures packed into one image), with its faces in the
    file's order, where every face is a triangle: trimesh's reader gave them material by material (a face index of
    the file named another face). Each material's mesh holds its faces in the file's order, so each face's place in
    the file is its material's faces' (``usemtl`` chunk by chunk) in turn; the order is kept as read where a material
    name, or a material's count of faces, is not the file's. None for another OBJ (one material, polygons): read as
    before."""
    with _obj_mapped(file, data if data is not None else source) as text:
        owners = _obj_triangle_materials(text) if text is not None else None
    if owners is None:
        return None
    scene = _trimesh_read(trimesh.load_scene, file, data, process=False)
    parts = [part for part in scene.dump() if isinstance(part, trimesh.Trimesh)]  # Scene.to_mesh()'s
    mesh = trimesh.util.concatenate(parts)
    name = _utf8_name(file.name)
    if name != file.name:  # named as _trimesh_read names the joined mesh of trimesh.load
        mesh.metadata.update({key: name for key in ("name", "node") if key in mesh.metadata})
    names = [getattr(getattr(part.visual, "material", None), "name", None) for part in parts]
    if None in names or len(set(names)) != len(names) or sum(len(part.faces) for part in parts) != len(owners):
        return mesh  # type: ignore[no-any-return]
    where: dict[bytes | None, list[int]] = {}
    for place, name in enumerate(owners):
        where.setdefault(name, []).append(place)
    places = [where.get(str(name).encode("utf-8", "surrogateescape"), []) for name in names]
    if any(len(found) != len(part.faces) for found, part in zip(places, parts, strict=True)):
        return mesh  # type: ignore[no-any-return]
    order = np.argsort(np.concatenate([np.asarray(found, np.int64) for found in places]), kind="stable")
    mesh.faces = np.asarray(mesh.faces)[order]
    return mesh  # type: ignore[no-any-return]


def _obj_materials_joined(file: Path, tidied: bytes | None) -> trimesh.Trimesh | None:
    """The OBJ ``file`` whose faces name vertex indices only but which :func:`_obj_faces_kind` does not
    read in one piece (several ``usemtl``, or faces before its one) as one mesh of the file's vertices, one per ``v``
    line in their order, and its faces in the file's order, indexing them. trimesh's reader made one mesh per material
    (``maintain_order`` gave each every vertex) and ``force="mesh"`` joined them, each vertex repeated in each
    material it is a corner in and the vertices no face names dropped: a closed surface of two materials came back
    open along their seam. Read with trimesh's reader one mesh per material (``group_material=True``: each with every
    vertex, one copy per material, not per ``usemtl``), for the vertices and the materials; the faces, per ``usemtl``
    chunk in the file's order, are read from the file's ``f`` lines (:func:`_obj_chunk_faces`), checked to be the
    triangles trimesh's reader read (else read one mesh per chunk, ``group_material=False``, as trimesh lists them,
    last first). Each face's material is kept as its face colour (the material's colour, trimesh's grey where its
    ``.mtl`` names no ``Kd``; a face before any ``usemtl`` or of a material the ``.mtl`` lacks, trimesh's default
    colour), as the 3MF reader keeps a colour per face: trimesh packed the materials' colours into an atlas of its
    own, by UVs that cannot be kept on a vertex shared by two materials. A file without materials (no ``.mtl``
    found) keeps its ``v`` lines' colours, if any. None for a file of no faces."""
    scene = _trimesh_read(trimesh.load_scene, file, tidied, process=False, maintain_order=True)
    parts = [part for part in scene.geometry.values() if isinstance(part, trimesh.Trimesh)]
    if not parts:
        return None
    vertices = _obj_parts_vertices(parts)
    read = _obj_chunk_faces(file.read_bytes() if tidied is None else tidied)
    loaded = np.concatenate([np.asarray(part.faces, dtype=np.int64).reshape(-1, 3) for part in parts])
    if read is not None:
        faces = np.concatenate(read[1])
        if len(faces) != len(loaded) or not np.array_equal(faces[np.lexsort(faces.T)], loaded[np.lexsort(loaded.T)]):
            read = None
    materials = {getattr(part.visual, "material", None) for part in parts} - {None}
    by_name = {str(material.name).encode("utf-8", "surrogateescape"): material for material in materials}
    if read is None or not set(by_name) <= set(read[0]):  # faces, or material names, this scan does not read as
        del scene, parts, loaded  # trimesh's reader does: one mesh per usemtl chunk
        return _obj_chunks_joined(file, tidied)
    names, chunks = read
    del loaded
    return _obj_joined(file, vertices, faces, [by_name.get(name) for name in names] if materials else None,
                       [len(chunk) for chunk in chunks], parts)


def _obj_parts_vertices(parts: list[trimesh.Trimesh]) -> NDArray[Any]:
    """The vertices of the OBJ meshes ``parts``, one per material or ``usemtl`` chunk, each of which has every vertex,
    as trimesh's reader reads them with ``maintain_order``: the first's; a ValueError where their counts differ."""
    vertices = np.asarray(parts[0].vertices)
    if any(len(part.vertices) != len(vertices) for part in parts):
        raise ValueError("the file's materials read with different vertices")
    return vertices


def _obj_joined(file: Path, vertices: NDArray[Any], faces: NDArray[np.int64], materials: list[Any] | None,
                counts: list[int], parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """The joined OBJ mesh of :func:`_obj_materials_joined` and :func:`_obj_chunks_joined`: ``faces`` in chunks of
    ``counts``, each chunk's faces coloured by its material (``materials``; None in it: trimesh's default colour),
    or where the file has no materials (``materials`` None) the ``v`` lines' colours of the ``parts`` read, if
    any; named after the file."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if materials is not None:
        default = np.asarray(trimesh.visual.color.DEFAULT_COLOR, dtype=np.uint8)
        colours = [np.asarray(material.main_color, dtype=np.uint8) if material is not None else default
                   for material in materials]
        mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.repeat(np.asarray(colours), counts, axis=0))
    elif all(part.visual.kind == "vertex" for part in parts):
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.asarray(parts[0].visual.vertex_colors))
    name = _utf8_name(file.name)
    mesh.metadata.update({"name": name, "node": name})
    return mesh


def _obj_chunks_joined(file: Path, tidied: bytes | None) -> trimesh.Trimesh | None:
    """:func:`_obj_materials_joined` read with trimesh's reader one mesh per ``usemtl`` chunk
    (``group_material=False``; it lists them last first), each with every vertex: for faces its own scan does not
    read as trimesh's reader does."""
    scene = _trimesh_read(trimesh.load_scene, file, tidied, process=False, maintain_order=True,
                          group_material=False)
    parts = [part for part in reversed(list(scene.geometry.values())) if isinstance(part, trimesh.Trimesh)]
    if not parts:
        return None
    vertices = _obj_parts_vertices(parts)
    faces = np.concatenate([np.asarray(part.faces, dtype=np.int64).reshape(-1, 3) for part in parts])
    materials = [getattr(part.visual, "material", None) for part in parts]
    return _obj_joined(file, vertices, faces, materials if any(m is not None for m in materials) else None,
                       [len(part.faces) for part in parts], parts)


#: an OFF file's keyword (Geomview's [ST][C][N][4][n]OFF): its groups say what each vertex line holds
_OFF_KEYWORD = re.compile(r"(ST)?(C)?(N)?(4)?(n)?OFF")


def _off_keyword(data: bytes) -> str | None:
    """The first word of an OFF file's bytes ``data`` (its keyword, ``OFF``, ``COFF``, ...), comments and blank lines
    before it skipped, read line by line: not the whole file. A UTF-8 byte-order mark before it is skipped (it was
    read as part of the keyword, so a COFF written with one lost its colours; trimesh's reader skips it)."""
    for number, raw in enumerate(io.BytesIO(data)):
        words = raw.removeprefix(b"\xef\xbb\xbf" if number == 0 else b"").split(b"#", 1)[0].split(maxsplit=1)
        if words:
            return words[0].decode("utf-8", "replace")
    return None


def _off_counts(data: bytes) -> tuple[int, int] | None:
    """The counts of vertices and faces an OFF file's header declares (``data``: its bytes; on its keyword's line or
    the next, comments and blank lines skipped), read line by line, or None where they cannot be read."""
    words: list[bytes] = []
    for raw in io.BytesIO(data):
        words += raw.removeprefix(b"\xef\xbb\xbf").split(b"#", 1)[0].split()
        if len(words) >= 3:
            try:
                return int(words[1]), int(words[2])
            except ValueError:
                return None
        if len(words) > 1:
            return None
    return None


def _off_problem(data: bytes) -> str | None:
    """What is wrong with an OFF file (``data``: its bytes) as trimesh's reader reads it (comments after ``#`` and blank
    lines skipped, the keyword, the counts ``V F [E]`` on its line or the next, ``V`` vertex lines of at least x y z,
    then ``F`` face lines of a count ``n`` and ``n`` vertex indices from 0 to ``V - 1``), naming the line and what was
    expected, or None. trimesh's reader refused such a file without a line ("invalid literal for int()", "cannot reshape
    array of size 12 into shape (5,3)", "Python int too large to convert to C long", "a face index outside the range of
    its vertices"), or read it without a word: a face line of fewer indices than its count, and a file of fewer face
    lines than its counts declare (cut short), read as the faces it has."""
    text = data.decode("utf-8", "replace").removeprefix("\ufeff")
    numbered = [(number, line) for number, line in enumerate(text.splitlines(), 1) if line.split("#", 1)[0].split()]
    if not numbered:
        return None  # trimesh's own error (no keyword) stands
    words = numbered[0][1].split("#", 1)[0].split()
    at = 1
    if len(words) == 1:
        if len(numbered) < 2:
            return f"its keyword {words[0]!r} is not followed by the counts of vertices and faces ('V F E')"
        number, line = numbered[1]
        words, at = [words[0], *line.split("#", 1)[0].split()], 2
    else:
        number, line = numbered[0]
    try:
        vertices, faces = (int(word) for word in words[1:3])
    except ValueError:
        vertices = faces = -1
    if len(words) < 3 or vertices < 0 or faces < 0:
        return (f"line {number}, {line.strip()!r}: expected the counts of vertices and faces ('V F E', integers of "
                "at least 0)")
    if len(numbered) - at < vertices + faces:
        return (f"its counts declare {counted(vertices, 'vertex', 'vertices')} and "
                f"{counted(faces, 'face', 'faces')}, a line each, and the file has "
                f"{len(numbered) - at} lines after them: is it cut short?")
    rows = numbered[at : at + vertices]
    for number, line in rows:
        values = line.split("#", 1)[0].split()
        try:
            [float(value) for value in values[:3]]
        except ValueError:
            values = []
        if len(values) < 3:
            return f"line {number}, {line.strip()!r}: a vertex line needs 3 numbers, x y z"
    rows = numbered[at + vertices : at + vertices + faces]
    for number, line in rows:
        values = line.split("#", 1)[0].split()
        try:
            indices = [int(value) for value in values[: int(values[0]) + 1]] if values[0].isdigit() else []
        except ValueError:
            indices = []
        if len(indices) < 4 or len(indices) != indices[0] + 1:
            return (f"line {number}, {line.strip()!r}: a face line needs its count n (at least 3) and n vertex "
                    "indices, integers")
        bad = [index for index in indices[1:] if not 0 <= index < vertices]
        if bad:
            return (f"line {number}, {line.strip()!r}, names vertex {bad[0]}, and the file has "
                    f"{counted(vertices, 'vertex', 'vertices')}: "
                    f"an OFF's indices count from 0 to {vertices - 1}")
    return None


def _off_vertex_colors(file: Path, data: bytes, count: int) -> NDArray[np.uint8] | None:
    """The vertex colours of the OFF ``file`` (``data``: its bytes; ``count`` vertices, as trimesh's reader read them)
    as RGBA bytes, or None where its keyword has no ``C`` (``COFF``, ``CNOFF``, ...): trimesh's reader reads the
    coordinates alone (the keyword read first, the file only for a ``C``). Each vertex line holds x y z, then nx ny nz
    with an ``N``, then the colour, RGB or RGBA, then s t with an ``ST``. Written with a decimal point or exponent
    anywhere, the colours are floats from 0 to 1 (Geomview's); written as integers, bytes from 0 to 255 (MeshLab's).
    Where they cannot be read so without guessing, a warning says why and None (the mesh without colours, as trimesh's
    reader reads it): a vertex without a colour or of colours of different lengths (Geomview's colour map index, one
    number), or integers of 0 and 1 only (0 1 0 is green as floats and nearly black as bytes). A ValueError for a float
    outside 0..1 or an integer outside 0..255."""
    head = _off_keyword(data)
    keyword = _OFF_KEYWORD.fullmatch(head) if head is not None else None
    if keyword is None or keyword.group(2) is None:
        return None
    if keyword.group(4) or keyword.group(5):
        raise ValueError(f"an OFF of {head!r}, whose vertices have other than 3 coordinates, is not read")
    text = data.decode("utf-8", "replace").removeprefix("\ufeff")  # a byte-order mark, as the keyword's
    numbered = [(number, line.split("#", 1)[0].split()) for number, line in enumerate(text.splitlines(), 1)]
    numbered = [(number, line) for number, line in numbered if line]
    lines = [line for _, line in numbered]
    rest = lines[0][1:] or (lines[1] if len(lines) > 1 else [])
    first = 1 if lines[0][1:] else 2
    rows = lines[first : first + count]
    skip, tail = 3 + (3 if keyword.group(3) else 0), 2 if keyword.group(1) else 0
    widths = {len(row) - skip - tail for row in rows}
    if not rest or len(rows) != count or len(widths) != 1 or widths.pop() not in (3, 4):
        warnings.warn(f"{str(file)!r}: a {head} file's vertex lines hold {sorted({len(row) for row in rows})} "
                      f"numbers, where {skip} before an RGB or RGBA colour{' and 2 after it' if tail else ''} were "
                      "expected on each: its vertex colours are dropped, the mesh read without them",
                      stacklevel=caller_stacklevel())
        return None
    words = [row[skip : len(row) - tail] for row in rows]
    values = _off_colour_values(
        numbered[first : first + count], words,
        lambda: f"a {head} vertex line holds {skip} numbers (x y z{' nx ny nz' if skip > 3 else ''}), then an RGB or "
                f"RGBA colour as integers 0..255 or floats 0..1{', then s t' if tail else ''}")
    return _off_colour_bytes(file, head, "vertex", words, values)


def _off_colour_values(lines: list[tuple[int, list[str]]], words: list[list[str]],
                       holds: Callable[[], str]) -> NDArray[np.float64]:
    """The colours ``words`` (a row each) of an OFF's vertex or face ``lines`` (their numbers and words) as numbers;
    where one is no number, a ValueError naming its line, then what such a line holds (``holds()``, made only then):
    NumPy's "could not convert string to float: 'red'" named no line."""
    try:
        return np.array(words, dtype=np.float64)
    except ValueError:
        for (number, line), colour in zip(lines, words, strict=True):
            for word in colour:
                try:
                    float(word)
                except ValueError:
                    raise ValueError(f"line {number}, {' '.join(line)!r}: its colour {word!r} is not a number; "
                                     f"{holds()}") from None
        raise


def _off_colour_bytes(file: Path, head: str, kind: str, words: list[list[str]],
                      values: NDArray[np.float64]) -> NDArray[np.uint8] | None:
    """An OFF ``file``'s (keyword ``head``) ``kind`` ("vertex", "face") colours, ``words`` as written and ``values``
    their numbers (a row each, RGB or RGBA), as RGBA bytes by :func:`_off_vertex_colors`' rules: floats 0..1 where
    any is written with a decimal point or exponent, else bytes 0..255; None, with a warning, for integers of 0 and 1
    only. A ValueError for a float outside 0..1 or an integer outside 0..255."""
    floats = any(any(c in word for c in ".eE") for row in words for word in row)
    if floats:
        if not np.all((values >= 0) & (values <= 1)):
            raise ValueError(f"a {head} file's {kind} colours written as floats are not all in 0..1")
        values = np.round(values * 255)
    elif not np.all((values >= 0) & (values <= 255)):
        raise ValueError(f"a {head} file's {kind} colours written as integers are not all in 0..255")
    elif values.size and values.max() <= 1 and values.max() > 0:
        warnings.warn(f"{str(file)!r}: a {head} file's {kind} colours are integers of 0 and 1 only: floats from 0 "
                      "to 1 or bytes from 0 to 255? They are dropped, the mesh read without them; write them as 0.0 "
                      "and 1.0, or as 0 and 255", stacklevel=caller_stacklevel())
        return None
    colours = values.astype(np.uint8)
    if colours.shape[1] == 3:
        colours = np.column_stack([colours, np.full(len(colours), 255, np.uint8)])
    return colours


def _off_line_words(data: bytes) -> NDArray[np.int64]:
    """The count of words on each line of an OFF file's ``data`` (its lines as ``bytes.splitlines`` splits them:
    LF, CRLF or CR; a comment from ``#`` to the line's end skipped), counted by NumPy, without a loop over the lines."""
    raw = np.frombuffer(data, np.uint8)
    if raw.size == 0:
        return np.zeros(1, np.int64)
    ends = raw == 10
    ends[:-1] |= (raw[:-1] == 13) & (raw[1:] != 10)  # a CR alone ends a line; of a CRLF, the LF
    ends[-1] |= raw[-1] == 13
    space = _SPACE_BYTES[raw]
    if b"#" in data:  # from a # to its line's end: as spaces
        at = np.arange(raw.size)
        last_hash = np.maximum.accumulate(np.where(raw == 35, at, -1))
        last_end = np.maximum.accumulate(np.where(ends, at, -1))
        space |= last_hash > last_end
    starts = ~space  # each word's first byte
    starts[1:] &= space[:-1]
    at = np.flatnonzero(starts)
    return np.diff(np.concatenate([[0], np.searchsorted(at, np.flatnonzero(ends)), [len(at)]]))  # words per line


#: the bytes an OFF's words are separated by (Python's ``bytes.split``'s)
_SPACE_BYTES = np.zeros(256, bool)
_SPACE_BYTES[list(b" \t\r\n\x0b\x0c")] = True


def _off_face_colors(file: Path, data: bytes, vertices: int, faces: int,
                     triangles: int) -> NDArray[np.uint8] | None:
    """The face colours of the OFF ``file`` (``data``: its bytes; ``vertices`` and ``faces`` as its counts declare, read
    by trimesh's reader as ``triangles`` triangles) as RGBA bytes, one per triangle, or None where its face lines hold
    no more than a count and its indices (trimesh's reader dropped the rest of a line): each face line, ``n i1 .. in``,
    then RGB or RGBA, as integers bytes, or with a decimal point floats 0..1 (:func:`_off_colour_bytes`, the vertex
    colours' rules). Face lines some with a colour and some without, or of colours of different lengths (Geomview's
    colour map index, one number), are dropped with a warning, as the vertex colours are. The words on each line are
    counted by NumPy first: a file of faces without colours is not split line by line again. A polygon's colour is its
    triangles' (trimesh's reader's order: triangles, then quads' halves, then polygons' fans)."""
    data = data.removeprefix(b"\xef\xbb\xbf")
    counts = _off_line_words(data)
    counts = counts[counts > 0]
    first = 1 if len(counts) and counts[0] > 1 else 2  # the counts on the keyword's line or the next
    rows = counts[first + vertices : first + vertices + faces]
    if len(rows) != faces or int(rows.sum()) == 3 * faces + triangles:  # n + 1 words per face, n - 2 triangles
        return None
    text = data.decode("utf-8", "replace")
    numbered = [(number, line.split("#", 1)[0].split()) for number, line in enumerate(text.splitlines(), 1)]
    numbered = [(number, line) for number, line in numbered if line]
    lines = numbered[first + vertices : first + vertices + faces]
    try:
        sizes = np.array([int(line[0]) for _, line in lines], np.int64)
    except ValueError:
        return None  # trimesh's reader refused it
    words = [line[size + 1 :] for size, (_, line) in zip(sizes.tolist(), lines, strict=True)]
    widths = sorted({len(row) for row in words})
    head = _off_keyword(data) or "OFF"
    if widths not in ([3], [4]) or np.any(sizes < 3):
        warnings.warn(f"{str(file)!r}: a {head} file's face lines hold {widths} "
                      "numbers after their indices, where none or an RGB or RGBA colour on each were expected: its "
                      "face colours are dropped, the mesh read without them", stacklevel=caller_stacklevel())
        return None
    values = _off_colour_values(lines, words, lambda: f"a {head} face line holds its count n, n vertex indices, then "
                                                      "an RGB or RGBA colour as integers 0..255 or floats 0..1")
    colours = _off_colour_bytes(file, head, "face", words, values)
    if colours is None:
        return None
    order = np.arange(faces)  # trimesh's triangulate_quads: triangles, quads' first and second halves, fans
    quads, fans = order[sizes == 4], order[sizes > 4]
    source = np.concatenate([order[sizes == 3], quads, quads, np.repeat(fans, sizes[fans] - 2)])
    if len(source) != triangles:
        return None
    return colours[source]


#: the statements of Wavefront OBJ (and of its curves and surfaces), which an OBJ's lines start with
_OBJ_STATEMENTS = frozenset(
    "v vt vn vp f l p o g s mg mtllib usemtl maplib usemap cstype deg bmat step curv curv2 surf parm trim hole scrv sp "
    "end con lod bevel c_interp d_interp trace_obj shadow_obj ctech stech call csh".split()
)


def _check_format(file: Path) -> None:
    """Raise a ValueError unless ``file`` is a whole STL (binary or ASCII), or, an OBJ trimesh read as a mesh without
    vertices, an empty OBJ. trimesh's STL reader takes a file whose length does not match a binary STL's header (cut
    short, another format) as ASCII, and its OBJ reader skips lines it does not know: either read any file (a PLY or
    GLB under the wrong extension, random bytes, an STL cut short) as an empty mesh, which ``stepterrain info``
    described as one; and an ASCII STL of several solids cut short was read as the solids before the cut."""
    suffix = file.suffix.lower()
    if suffix == ".stl":
        size = file.stat().st_size
        with open(file, "rb") as stream:
            head = stream.read(4096)
            stream.seek(max(size - 4096, 0))
            tail = stream.read()
        count = int.from_bytes(head[80:84], "little") if size >= 84 else None
        if count is not None and size == 84 + 50 * count:
            return  # a binary STL (of no triangles, as trimesh read it)
        text = head.lstrip().lower()
        if text.startswith(b"solid") and b"endsolid" in tail.lower():
            return  # an ASCII STL
        if text.startswith(b"solid") and b"facet" in text:
            raise ValueError(f"not a whole STL file: an ASCII STL ('solid' ... 'facet' ...) of {size} bytes without "
                             "its closing 'endsolid'; is it cut short?")
        binary = (f"the header's count of {count} triangles makes {84 + 50 * count} bytes" if count is not None
                  else "at least 84 bytes")
        raise ValueError(f"not an STL file: its {size} bytes are neither a binary STL (84 bytes of header and 50 per "
                         f"triangle: {binary}) nor an ASCII STL ('solid' ... 'endsolid'); is it cut short, or of "
                         "another format?")
    if suffix == ".obj":
        with open(file, "rb") as stream:
            for number, line in enumerate(stream, 1):
                words = line.split(maxsplit=1)
                if not words or words[0].startswith(b"#"):
                    continue
                if words[0].decode("latin-1") not in _OBJ_STATEMENTS:
                    raise ValueError(f"not an OBJ file: line {number} starts with {words[0][:20]!r}, not an OBJ "
                                     "statement (v, vt, vn, f, o, g, usemtl, ...); is it of another format?")


def _read_points(file: Path, scene: trimesh.Scene | None = None, data: bytes | None = None) -> trimesh.Trimesh | None:
    """The point clouds of ``file`` (in world coordinates, with their colours) as one mesh without faces; None without
    any. ``scene``: a glTF's, as :func:`read_mesh` loaded it (and turned z-up), not loaded again; ``data``: an OBJ's
    text tidied (:func:`_obj_tidied`), read instead of the file (an OBJ of vertices only read from the file lost
    its first vertex to a byte-order mark, or was refused for it or for a comment after a vertex)."""
    loaded = scene if scene is not None else _trimesh_read(trimesh.load, file, data, process=False)
    parts = loaded.dump() if isinstance(loaded, trimesh.Scene) else [loaded]
    clouds = [part for part in parts if isinstance(part, trimesh.PointCloud) and len(part.vertices)]
    if not clouds:
        return None
    vertices = np.concatenate([np.asarray(cloud.vertices, dtype=np.float64) for cloud in clouds])
    mesh = trimesh.Trimesh(vertices, np.zeros((0, 3), np.int64), process=False)
    colors = [np.asarray(cloud.colors) for cloud in clouds]
    if all(c.ndim == 2 and len(c) == len(cloud.vertices) for c, cloud in zip(colors, clouds, strict=True)):
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.concatenate(colors))
    metadata = dict(getattr(loaded, "metadata", {}) or {})
    for cloud in clouds:
        metadata.update(cloud.metadata or {})
    mesh.metadata.update(metadata)
    return mesh


_3MF_CORE = "{http://schemas.microsoft.com/3dmanufacturing/core/2015/02}"
_3MF_MATERIAL = "{http://schemas.microsoft.com/3dmanufacturing/material/2015/02}"


def _3mf_element_problem(kind: str, number: int, attributes: Mapping[str, str], expected: str,
                         exc: Exception) -> str:
    """A 3MF ``<kind>`` element's (``triangle``, ``vertex``; ``number`` from 0, in its object's order) error: its
    attributes as written, what was expected of them, and what was wrong (``exc``: a missing attribute's KeyError,
    ``int()``'s or ``float()``'s ValueError, an index's OverflowError)."""
    written = " ".join(f'{key}="{value}"' for key, value in attributes.items())
    why = f"no {exc.args[0]!r}" if isinstance(exc, KeyError) else str(exc)
    return f"3MF {kind} {number} (<{kind} {written}/>): expected {expected}; {why}"


def _read_3mf(file: Path) -> trimesh.Trimesh | None:
    """The 3MF ``file`` read by stepterrain itself when its model is one mesh object built once without a transform
    (as :func:`save_mesh` writes it): vertices, triangles and the colours of its ``m:colorgroup`` (each triangle's
    corner colours p1, p2, p3 into the group its pid, or its object's, names; trimesh's reader ignores them) as
    vertex colours (a vertex no triangle names, which has none in the file, trimesh's default opaque grey), or face
    colours where one vertex has corners of several colours. Streamed (iterparse, elements
    cleared as read, numbers in compact arrays): trimesh's reader holds the whole XML tree, 9.8 GB for the embedded
    DEM's 4.3 M-face solid. The model's ``stepterrain:metadata`` element (:func:`_write_3mf`) becomes the mesh's
    metadata, and its ``unit`` its ``metadata["units"]`` (``"meters"`` for ``meter``, :data:`_3MF_UNIT_NAMES`) where
    that metadata does not name it already: a foreign 3MF in metres read and saved again declared millimetres. A
    model in millimetres (3MF's default, :func:`_write_3mf`'s for a mesh without units) adds none. None for
    anything else (several objects, components, a build transform, no model):
    trimesh reads those."""
    import array
    import xml.etree.ElementTree as ET

    groups: dict[str, list[tuple[int, int, int, int]]] = {}
    points = array.array("d")
    rows = array.array("q")  # v1 v2 v3 pid p1 p2 p3 per triangle (-1: absent)
    group: list[tuple[int, int, int, int]] | None = None
    objects = items = 0
    container: Any = None  # the <vertices> or <triangles> being read: emptied after each child, so memory stays flat
    default_pid = default_index = -1
    pid_ids: dict[str, int] = {}
    own: list[bytes] = []  # the text of its stepterrain:metadata element (_write_3mf)
    unit = "millimeter"  # the model's, 3MF's default
    with zipfile.ZipFile(file) as archive:
        models = [name for name in archive.namelist() if name.lower().endswith(".model")]
        if len(models) != 1:
            return None
        with archive.open(models[0]) as stream:
            for event, element in ET.iterparse(stream, events=("start", "end")):
                tag = element.tag
                if event == "start":
                    if tag == _3MF_MATERIAL + "colorgroup":
                        group = groups.setdefault(element.get("id", ""), [])
                    elif tag == _3MF_CORE + "object":
                        objects += 1
                        default_pid = pid_ids.setdefault(element.get("pid", ""), len(pid_ids))
                        default_index = int(element.get("pindex", "-1"))
                    elif tag == _3MF_CORE + "components":
                        return None
                    elif tag == _3MF_CORE + "item":
                        items += 1
                        transform = element.get("transform")
                        if transform is not None and _3mf_matrix(transform) != _3MF_IDENTITY:
                            return None
                    elif tag in (_3MF_CORE + "vertices", _3MF_CORE + "triangles"):
                        container = element
                    elif tag == _3MF_CORE + "model":
                        unit = element.get("unit", unit).strip().lower()
                    continue
                if tag == _3MF_CORE + "triangle":
                    a = element.attrib
                    try:  # a KeyError 'v3', int()'s "invalid literal", OverflowError "int too big", of no element
                        pid = pid_ids.setdefault(a["pid"], len(pid_ids)) if "pid" in a else default_pid
                        p1 = int(a.get("p1", default_index))
                        rows.extend((int(a["v1"]), int(a["v2"]), int(a["v3"]), pid, p1, int(a.get("p2", p1)),
                                     int(a.get("p3", p1))))  # fmt: skip
                    except (KeyError, ValueError, OverflowError) as exc:
                        raise ValueError(_3mf_element_problem("triangle", len(rows) // 7, a, "v1, v2 and v3 integers "
                                         "(vertex indices from 0; p1, p2, p3 too, where given)", exc)) from exc
                elif tag == _3MF_CORE + "vertex":
                    a = element.attrib
                    try:
                        points.extend((float(a["x"]), float(a["y"]), float(a["z"])))
                    except (KeyError, ValueError) as exc:
                        raise ValueError(_3mf_element_problem("vertex", len(points) // 3, a, "x, y and z numbers",
                                                              exc)) from exc
                elif tag == _3MF_MATERIAL + "color" and group is not None:
                    group.append(_3mf_rgba(element.get("color", "")))
                elif tag == _3MF_MATERIAL + "colorgroup":
                    group = None
                elif tag == _3MF_CORE + "metadata" and element.get("name") == _3MF_METADATA and container is None:
                    own.append((element.text or "").strip().encode("ascii", "replace"))
                else:
                    continue
                element.clear()
                if container is not None and tag != _3MF_MATERIAL + "color":
                    container.clear()
    if objects != 1 or items > 1:
        return None
    vertices = np.frombuffer(points, dtype=np.float64).reshape(-1, 3).copy()
    triangles = np.frombuffer(rows, dtype=np.int64).reshape(-1, 7)
    faces = triangles[:, :3].copy()
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices)):
        return None  # trimesh words what is wrong with it
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if own:
        mesh.metadata.update(_metadata_from_pieces(own))
    if unit in _3MF_UNIT_NAMES and _3mf_unit(mesh.metadata) != unit:  # a foreign file's, or one edited
        mesh.metadata["units"] = _3MF_UNIT_NAMES[unit]
    names = {index: name for name, index in pid_ids.items()}
    pids = np.unique(triangles[:, 3])
    if len(pids) != 1 or names.get(int(pids[0])) not in groups:
        return mesh
    palette = np.array(groups[names[int(pids[0])]], dtype=np.uint8).reshape(-1, 4)
    corners = triangles[:, 4:]
    if len(palette) == 0 or corners.min() < 0 or corners.max() >= len(palette):
        return mesh
    corner_colors = palette[corners.reshape(-1)]
    # a vertex no triangle names has no colour in the file: trimesh's default (opaque grey), as it gives a mesh
    # without colours. Such a vertex made the whole mesh's colours face colours (each face its first corner's), the
    # vertex colours written lost, although every vertex with corners had one colour
    vertex_colors = np.tile(np.asarray(trimesh.visual.color.DEFAULT_COLOR, np.uint8), (len(mesh.vertices), 1))
    vertex_colors[faces.reshape(-1)] = corner_colors
    if np.array_equal(vertex_colors[faces.reshape(-1)], corner_colors):
        mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=vertex_colors)
    else:  # a vertex with corners of several colours: each face takes its first corner's
        mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=corner_colors[::3])
    return mesh


_3MF_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


def _3mf_matrix(text: str) -> tuple[float, ...] | None:
    """A 3MF ``transform`` attribute's twelve numbers, or None when it is not twelve numbers."""
    try:
        values = tuple(float(v) for v in text.split())
    except ValueError:
        return None
    return values if len(values) == 12 else None


def _3mf_rgba(text: str) -> tuple[int, int, int, int]:
    """``#RRGGBB`` or ``#RRGGBBAA`` (3MF's sRGB colour) as RGBA bytes; opaque black for anything else."""
    digits = text.strip().lstrip("#")
    if len(digits) == 6:
        digits += "FF"
    try:
        value = int(digits, 16) if len(digits) == 8 else 255
    except ValueError:
        value = 255
    return value >> 24 & 255, value >> 16 & 255, value >> 8 & 255, value & 255


# ---------------------------------------------------------------------------------------------- helpers
def _target(path: str | os.PathLike[str], *, output: bool = True) -> Path:
    """``path`` as a Path, else an :class:`InvalidInputError`: not a str or path-like, or holding a NUL character
    (which no file name can: tempfile's ValueError "embedded null byte" came out of the write). An ``output`` path
    that ends in a folder separator (``x.glb/``) or ``.`` is refused too: pathlib drops those, and a file ``x.glb``
    was written where a folder was meant."""
    target = as_path(path, "path")
    if "\x00" in str(target):
        raise InvalidInputError(f"path must be a file name without NUL characters; got {str(target)!r}")
    if output:
        refuse_folder_name(os.fspath(path), "path")
    return target


def _prepared_mesh(mesh: trimesh.Trimesh, metadata: Mapping[str, Any] | None) -> trimesh.Trimesh:
    """A copy of ``mesh`` with JSON-safe metadata and face/vertex attributes every exporter accepts."""
    # built field by field: Trimesh.copy() would deep-copy metadata, which may hold objects that refuse it.
    # The vertex and face arrays are shared, not copied (the writers only read them): for a large mesh a copy
    # costs as much memory traffic as the file itself.
    out = trimesh.Trimesh(
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        faces=np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3),
        process=False,
        validate=False,
    )
    kind = mesh.visual.kind
    if kind == "vertex":  # ColorVisuals.copy() would also build face colours
        out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=np.array(mesh.visual.vertex_colors))
    elif kind is not None:
        out.visual = _texture_copy(mesh.visual)
    out.units = mesh.units
    merged = dict(mesh.metadata)
    if metadata:
        merged.update(metadata)
    out.metadata = _json_value(merged)
    out.face_attributes = _attributes(mesh.face_attributes, len(mesh.faces))
    out.vertex_attributes = _attributes(mesh.vertex_attributes, len(mesh.vertices))
    return out


def _texture_copy(original: Any) -> Any:
    """``original.copy()`` (a mesh, a visual or a material), its material given the texture images of
    ``original``'s opened from a JPEG themselves: trimesh's ``PBRMaterial.copy`` copied each PIL image with
    ``Image.copy()``, which drops its ``format`` and file name, so such a texture was written as a PNG three times its
    size (and an OBJ's ``.png``), and :func:`_jpeg_data` could not find its file. The writers replace images on the
    copy (:func:`_pil_textures`, :func:`_encoded_textures`), never change them in place; other images keep their
    copies. The copy also gets the material's ``wrap`` (:func:`texture_wrap`), which ``PBRMaterial.copy`` dropped: a
    terrain drape's GLB was written without its clamping sampler."""
    from PIL import Image

    def material_of(thing: Any) -> Any:
        visual = thing.visual if isinstance(thing, trimesh.Trimesh) else thing
        return visual if isinstance(visual, trimesh.visual.material.Material) else getattr(visual, "material", None)

    copied = original.copy()
    material, mine = material_of(original), material_of(copied)
    slots = next((names for kind, names in _TEXTURE_SLOTS if isinstance(material, kind)), ())
    if type(mine) is type(material):
        if getattr(material, "wrap", None) is not None:
            mine.wrap = material.wrap
        for slot in slots:
            image = getattr(material, slot, None)
            if isinstance(image, Image.Image) and image.format == "JPEG":
                setattr(mine, slot, image)
    return copied


def _check_ply_attributes(mesh: trimesh.Trimesh, target: Path) -> None:
    """Before a ``.ply`` is written (the format that keeps ``face_attributes`` and ``vertex_attributes``): an
    InvalidInputError for a numeric attribute that is not one value (or row) per face or vertex, and a warning naming
    the attributes PLY cannot hold (text, objects, complex numbers, arrays of more than two dimensions), which are
    left out. :func:`_attributes` dropped both without a word: ``mesh.faces = mesh.faces[keep]`` keeps trimesh's
    ``face_attributes`` as they were, and a stepped mesh so cut down was written without its ``level`` and ``wall``,
    read back without them."""
    dropped = []
    for element, attributes, count in (("face", mesh.face_attributes, len(mesh.faces)),
                                       ("vertex", mesh.vertex_attributes, len(mesh.vertices))):  # fmt: skip
        for name, values in attributes.items():
            array = _attribute_array(values)
            if array is None:
                dropped.append(f"{element}_attributes[{name!r}] (a {type(values).__name__} of no array shape: ragged)")
                continue
            if array.dtype.kind not in "biuf" or array.ndim > 2:
                dropped.append(f"{element}_attributes[{name!r}] ({array.dtype}, shape {array.shape})")
                continue
            if array.ndim == 0 or len(array) != count:
                got = "a single value" if array.ndim == 0 else f"{len(array)} (shape {array.shape})"
                raise InvalidInputError(
                    f"cannot write {str(target)!r}: mesh.{element}_attributes[{name!r}] must hold one value per "
                    f"{element} ({count}), as .ply stores it; got {got}: give it one per {element}, or remove it "
                    f"(del mesh.{element}_attributes[{name!r}]; setting mesh.faces keeps the old ones, "
                    "mesh.update_faces cuts them too)")
    if dropped:
        warnings.warn(f"{str(target)!r}: .ply stores numeric attributes of one value (or row) per face or vertex; "
                      f"left out {', '.join(dropped)}", stacklevel=caller_stacklevel())


def _attributes(attributes: Mapping[str, Any], count: int) -> dict[str, NDArray[Any]]:
    """Keep per-element numeric (N,) or (N, k) arrays of the right length; drop anything else (a ragged list too:
    NumPy's ValueError for it went out of :func:`save_mesh` in every format, for .ply after the warning that it was
    left out)."""
    kept: dict[str, NDArray[Any]] = {}
    for name, values in attributes.items():
        array = _attribute_array(values)
        if array is None or array.ndim not in (1, 2) or len(array) != count or array.dtype.kind not in "biuf":
            continue
        kept[str(name)] = array
    return kept


def _attribute_array(values: Any) -> NDArray[Any] | None:
    """``values`` of a mesh's ``face_attributes`` or ``vertex_attributes`` as an array; None where NumPy cannot make
    one (a ragged list: its ValueError)."""
    try:
        return np.asarray(values)
    except (ValueError, TypeError):
        return None


def _ply_compatible(array: NDArray[Any]) -> NDArray[Any]:
    """bool -> uint8, 64-bit ints -> 32-bit when they fit (else float64), float16 -> float32."""
    if array.dtype.kind == "b":
        return array.astype(np.uint8)
    if array.dtype == np.float16:
        return array.astype(np.float32)
    if array.dtype.kind in "iu" and array.dtype.itemsize == 8:
        narrow = np.dtype(np.int32 if array.dtype.kind == "i" else np.uint32)
        info = np.iinfo(narrow)
        if array.size == 0 or (array.min() >= info.min and array.max() <= info.max):
            return array.astype(narrow)
        return array.astype(np.float64)
    return array


# PLY's standard scalar types by numpy dtype string.
_PLY_TYPES: dict[str, str] = {
    "|i1": "char",
    "|u1": "uchar",
    "<i2": "short",
    "<u2": "ushort",
    "<i4": "int",
    "<u4": "uint",
    "<f4": "float",
    "<f8": "double",
}
#: The other element's own property names (:data:`_PLY_OWN` holds each element's): not written as a column either.
_PLY_RESERVED = frozenset({"x", "y", "z", "vertex_indices"})
#: Header words no column is named: trimesh's reader (read_mesh's) ends the header at a line holding the word
#: ``end_header`` anywhere, so an attribute so named (``property int end_header``, and a bool one's flag comment) cut
#: the header short, and the file was refused as "PLY is unexpected length".
_PLY_KEYWORDS = frozenset({"end_header"})
# An attribute is not written under a name readers take for something else (:data:`_PLY_OWN`: ``nx``, ``u``, ``s``
# ... of a vertex, ``texcoord`` of a face): trimesh's reader and VTK's made such a column normals or texture
# coordinates, read_mesh left it out, and a face attribute named ``texcoord`` made the file unreadable.


def _ply_parts(mesh: trimesh.Trimesh, bounds: Bounds) -> list[Any]:
    """Binary little-endian PLY, as its header, vertex block and face block (bytes-like, written one after another):
    vertices (float64 beyond 65536 or where float32 would round them, else float32), RGBA vertex or face colours,
    attributes."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    coordinate = np.dtype("<f8" if _is_large(bounds) else "<f4")
    xyz = [vertices[:, k].astype(coordinate, copy=False) for k in range(3)]  # float64: views, not copies
    if coordinate.itemsize == 4 and not all(np.array_equal(xyz[k], vertices[:, k]) for k in range(3)):
        # float64 where float32 would round (60000.123 by 1.9 mm): .ply keeps the vertices; a set's tiles still weld,
        # a float32 one holding its shared vertices exactly as the float64 one beside it does
        xyz = [vertices[:, k].astype("<f8", copy=False) for k in range(3)]
    vertex_columns: list[tuple[str, NDArray[Any]]] = [("x", xyz[0]), ("y", xyz[1]), ("z", xyz[2])]
    if mesh.visual.kind == "vertex" and len(mesh.visual.vertex_colors) == len(vertices):
        rgba = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
        vertex_columns += [(name, rgba[:, k]) for k, name in enumerate(("red", "green", "blue", "alpha"))]
    booleans: dict[str, list[str]] = {"vertex": [], "face": []}  # columns written from bools, as uchar 0/1
    vertex_columns += _ply_columns(mesh.vertex_attributes, [name for name, _ in vertex_columns]
                                  + list(_PLY_RESERVED | _PLY_KEYWORDS | _PLY_OWN["vertex"]), booleans["vertex"])
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3).astype("<i4")
    face_columns: list[tuple[str, NDArray[Any]]] = []
    if mesh.visual.kind == "face" and len(faces) and len(mesh.visual.face_colors) == len(faces):
        # face colours as the face element's red, green, blue, alpha (trimesh's reader reads them back); they were
        # dropped
        face_rgba = np.asarray(mesh.visual.face_colors, dtype=np.uint8)
        face_columns += [(name, face_rgba[:, k]) for k, name in enumerate(("red", "green", "blue", "alpha"))]
    face_columns += _ply_columns(mesh.face_attributes, ["count", *_PLY_RESERVED, *_PLY_KEYWORDS, *_PLY_OWN["face"]],
                                 booleans["face"])

    header = ["ply", "format binary_little_endian 1.0", "comment written by stepterrain"]
    header += [f"{_PLY_METADATA}{piece}" for piece in _metadata_pieces(mesh.metadata)]
    flags = [f"{_PLY_BOOL}{element} {name}" for element, names in booleans.items() for name in names
             if "texturefile" not in name.lower()]  # trimesh's reader takes a line naming it for a texture's file
    header += flags or [_PLY_BOOL.rstrip()]  # the bare marker: no bools, a file of before the lines is legacy
    header.append(f"element vertex {len(vertices)}")
    header += [f"property {_PLY_TYPES[column.dtype.str]} {name}" for name, column in vertex_columns]
    header.append(f"element face {len(faces)}")
    header.append("property list uchar int vertex_indices")
    header += [f"property {_PLY_TYPES[column.dtype.str]} {name}" for name, column in face_columns]
    header.append("end_header")

    vertex_block = np.empty(len(vertices), dtype=[(name, column.dtype) for name, column in vertex_columns])
    for name, column in vertex_columns:
        vertex_block[name] = column
    face_dtype = [("count", "u1"), ("vertex_indices", "<i4", (3,))]
    face_block = np.empty(
        len(faces), dtype=face_dtype + [(name, column.dtype) for name, column in face_columns]
    )
    face_block["count"] = 3
    face_block["vertex_indices"] = faces
    for name, column in face_columns:
        face_block[name] = column
    return [("\n".join(header) + "\n").encode("ascii"), vertex_block.view(np.uint8), face_block.view(np.uint8)]


#: The start of the PLY header's comment lines that hold a mesh's metadata (:func:`_metadata_pieces`).
_PLY_METADATA = "comment stepterrain-metadata "
#: The start of the OBJ's comment lines, at its top, that hold a mesh's metadata (:func:`_metadata_pieces`).
_OBJ_METADATA = "# stepterrain-metadata "
#: The start of the PLY header's comment lines that name a column written from a bool attribute (PLY has no boolean
#: type: it is written as uchar 0/1), ``comment stepterrain-bool face wall``: :func:`read_mesh` gives it back as bool.
_PLY_BOOL = "comment stepterrain-bool "
#: The most characters of metadata JSON on one comment line: with its start, a header line of at most 430 characters.
#: PLY readers read header lines into fixed buffers: MeshLab's (vcglib) 512 bytes, rply's 1024, VTK's 4096 (pyvista
#: read nothing from a file with a longer line).
_PLY_METADATA_PIECE = 400
#: How far into a PLY file :func:`_ply_comments` looks for the end of its header, and into an OBJ
#: :func:`_obj_metadata` for its first statement.
_PLY_HEADER_LIMIT = 64 << 20


def _metadata_pieces(metadata: Mapping[str, Any]) -> list[str]:
    """A mesh's metadata (JSON-safe: :func:`_prepared_mesh`'s, as a glTF's ``extras`` holds it) as the pieces of
    one compact JSON text, in order, for the PLY header's ``comment stepterrain-metadata <piece>`` lines and the
    OBJ's ``# stepterrain-metadata <piece>`` comments (none without metadata; a 3MF's metadata element holds them
    joined). The text has no whitespace, so a reader that splits header lines into words sees the piece as
    one word, and joining the pieces gives it back: ASCII only, spaces in strings written ``\\u0020``, and the
    words readers look for anywhere in a line (trimesh takes ``TextureFile`` in any PLY line for a texture's file
    name and ``mtllib`` in any OBJ line for its material file, ``end_header`` ends a header) escaped by their last
    letter. Each piece is at most :data:`_PLY_METADATA_PIECE` characters (a crs, spacing and origin fit on one
    line) and does not end with a backslash, which continues an OBJ line onto the next (trimesh joined them): a
    backslash in a string is written ``\\u005c``, so a backslash in the text starts an escape and the cut goes
    before it."""
    if not metadata:
        return []
    text = json.dumps(metadata, ensure_ascii=True, allow_nan=False, separators=(",", ":"))
    text = text.replace("\\\\", "\\u005c").replace(" ", "\\u0020")  # left to right: as JSON reads its escapes
    text = re.sub(r"(?i)end_heade(r)|texturefil(e)|mtlli(b)",
                  lambda found: f"{found.group(0)[:-1]}\\u{ord(found.group(0)[-1]):04x}", text)
    pieces, start = [], 0
    while start < len(text):
        end = min(start + _PLY_METADATA_PIECE, len(text))
        if text[end - 1] == "\\":  # an escape's start (never after another backslash: see above)
            end -= 1
        pieces.append(text[start:end])
        start = end
    return pieces


def _metadata_from_pieces(pieces: Iterable[bytes]) -> dict[str, Any]:
    """The metadata :func:`_metadata_pieces` split into ``pieces`` (read from a file, in order), joined back; {}
    when they do not join into a JSON object (a file edited by hand: the mesh is still read)."""
    try:
        value = json.loads(b"".join(pieces).decode("ascii"))
    except ValueError:  # UnicodeDecodeError and JSONDecodeError
        return {}
    return value if isinstance(value, dict) else {}


def _obj_metadata(file: Path, source: bytes | None = None) -> dict[str, Any]:
    """The metadata :func:`save_mesh` wrote in the OBJ ``file``'s ``# stepterrain-metadata <piece>`` comments
    (:func:`_metadata_pieces`), read from the comments and blank lines it starts with; {} without any. ``source``:
    the file's text with newline line ends (:func:`_obj_newlines`), read instead."""
    pieces: list[bytes] = []
    start = _OBJ_METADATA.encode("ascii")
    with open(file, "rb") if source is None else io.BytesIO(source) as stream:
        while stream.tell() < _PLY_HEADER_LIMIT:
            line = stream.readline(1 << 20)
            if line.startswith(start):
                pieces.append(line[len(start) :].strip())
            elif not line or (line.strip() and not line.startswith(b"#")):  # the first statement
                break
    return _metadata_from_pieces(pieces) if pieces else {}


def _ply_comments(file: Path) -> tuple[dict[str, Any], dict[str, set[str]]]:
    """The metadata :func:`save_mesh` wrote in the header of the PLY ``file`` (its ``comment stepterrain-metadata``
    lines, :func:`_metadata_pieces`; {} without any, or when they do not join into a JSON object: a header
    edited by hand, the mesh is still read), and the columns it wrote from bools, by element (its
    ``comment stepterrain-bool`` lines; a bare ``comment stepterrain-bool`` where there are none). A file
    stepterrain wrote before it named them (``comment written by stepterrain`` and no such line) is marked
    ``"stepped"``: its face ``wall`` beside a ``level`` is
    :func:`~stepterrain.stepped`'s flag."""
    pieces, booleans, ours, marked = [], {"vertex": set(), "face": set()}, False, False
    start, flag = _PLY_METADATA.encode("ascii"), _PLY_BOOL.encode("ascii")
    with open(file, "rb") as stream:
        if stream.readline(16).strip() != b"ply":
            return {}, booleans
        while stream.tell() < _PLY_HEADER_LIMIT:
            line = stream.readline(1 << 20)
            if not line or line.strip() == b"end_header":
                break
            if line.startswith(start):
                pieces.append(line[len(start) :].strip())
            elif line.startswith(flag):
                element, _, name = line[len(flag) :].decode("ascii", "replace").strip().partition(" ")
                booleans.setdefault(element, set()).add(name)
                marked = True
            elif line.strip() == flag.strip():  # the bare marker: a file naming its bools, none of them
                marked = True
            elif line.strip() == b"comment written by stepterrain":
                ours = True
    if ours and not marked:
        booleans["stepped"] = set()  # an older file of ours: a 0/1 face wall beside a level is stepped's flag
    return (_metadata_from_pieces(pieces) if pieces else {}), booleans


def _ply_columns(
    attributes: Mapping[str, NDArray[Any]], taken: Iterable[str], booleans: list[str] | None = None
) -> list[tuple[str, NDArray[Any]]]:
    """Attribute arrays as named PLY scalar columns ((N, k) -> name_0 .. name_k-1) of standard types. A name that
    is no plain ASCII word, or is one of the element's own properties (``taken``: also the names readers take for
    normals or UVs, ``nx`` or ``u``), is written under a word made from it (``level-2`` -> ``level_2``, ``x`` ->
    ``x_attr``), with a warning naming both: they were dropped. The names of the columns of bool arrays (written as
    uchar 0/1) are appended to ``booleans``."""
    used = set(taken)
    renamed: list[str] = []
    columns: list[tuple[str, NDArray[Any]]] = []
    for name, values in attributes.items():
        word = re.sub(r"\W", "_", str(name), flags=re.ASCII) or "attr"
        if word[0].isdigit():
            word = "a_" + word
        array = _ply_compatible(np.asarray(values))
        array = array.astype(array.dtype.newbyteorder("<"), copy=False)
        _warn_rounded_integers(np.asarray(values), array, name)
        names = [word] if array.ndim == 1 else [f"{word}_{k}" for k in range(array.shape[1])]
        suffix, tries = "", 0
        while any(n + suffix in used for n in names):  # _attr, _attr2, _attr3 ...
            tries += 1
            suffix = "_attr" if tries == 1 else f"_attr{tries}"
        names = [n + suffix for n in names]
        if word + suffix != name:
            renamed.append(f"{name!r} as {word + suffix!r}")
        used.update(names)
        if booleans is not None and np.asarray(values).dtype.kind == "b":
            booleans.extend(names)
        if array.ndim == 1:
            columns.append((names[0], array))
        else:
            columns += [(n, array[:, k]) for k, n in enumerate(names)]
    if renamed:
        warnings.warn("PLY property names must be distinct ASCII words other than the element's own (x, nx, u, s, "
                      "red, texcoord, ...: readers take those for coordinates, normals, UVs or colours) and "
                      f"end_header (which ends the header for some readers): wrote {', '.join(renamed)}",
                      stacklevel=caller_stacklevel())
    return columns


def _warn_rounded_integers(values: NDArray[Any], written: NDArray[Any], name: Any) -> None:
    """A warning when the 64-bit integer attribute ``values`` is ``written`` as double (:func:`_ply_compatible`: PLY
    has no 64-bit integer type) and some of them lie beyond 2**53, where doubles do not hold every integer: they
    came back changed (2**53 + 1 as 2**53) without a word."""
    if values.dtype.kind not in "iu" or written.dtype.kind != "f" or not values.size:
        return
    beyond = values > 2**53 if values.dtype.kind == "u" else (values > 2**53) | (values < -(2**53))
    if not beyond.any():
        return
    with np.errstate(invalid="ignore"):  # 2**63 - 1 is written as 2**63, beyond int64: changed, whatever its cast
        changed = int(np.count_nonzero(written[beyond].astype(values.dtype) != values[beyond]))
    if changed:
        warnings.warn(f"PLY has no 64-bit integer type: attribute {name!r} ({values.dtype}, beyond 32 bits) is written "
                      f"as double, which holds integers exactly only within ±2**53; {changed} of its {values.size} "
                      "values are rounded (read back changed): give them as two 32-bit columns, or write them "
                      "elsewhere", stacklevel=caller_stacklevel())


#: What a ``metadata`` value may be, in the message that refuses another.
_JSON_EXPECTED = "JSON (str, number, bool, None, list or dict of those)"


def json_metadata(metadata: Mapping[str, Any] | None) -> dict[str, Any]:
    """``metadata`` (a mapping or None) as plain JSON values, as :func:`save_mesh` writes them to glTF extras
    (see its Notes); the one check of the ``metadata`` of :func:`save_mesh` and :func:`~stepterrain.batch.batch`.

    A value that is not JSON (a set, bytes, a complex number, an object, an array of such) or a key that is not a
    string is an :class:`InvalidInputError` naming where it lies (``metadata['run']['tags'][2]``): written as
    its ``str`` before, silently.

    Examples
    --------
    >>> import numpy as np
    >>> json_metadata({"height": np.float64(12.5), "levels": np.arange(3), "gap": float("nan")})
    {'height': 12.5, 'levels': [0, 1, 2], 'gap': None}
    >>> json_metadata({"owner": {"ann"}})  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    stepterrain.errors.InvalidInputError: metadata['owner'] must be JSON (...); got set
    """
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise InvalidInputError(f"metadata must be a mapping (dict); got {type(metadata).__name__}")
    return _json_value(metadata, "metadata")  # type: ignore[no-any-return]


def _json_value(value: Any, where: str | None = None, depth: int = 0) -> Any:
    """``value`` as plain JSON types (see :func:`save_mesh` Notes), or ``_OMIT`` for a dropped item. With
    ``where`` (the value's name, for the message) a value that is not JSON is refused; without, it is written
    as its ``str`` (a mesh's own metadata). ``depth``: the lists and dicts around ``value``; beyond
    :data:`_MAX_EXTRAS_DEPTH` (a dict that holds itself) the value is refused, or written as its ``str``."""
    if depth > _MAX_EXTRAS_DEPTH and isinstance(value, (Mapping, list, tuple, set, frozenset, np.ndarray)):
        if where is not None:
            shown = where if len(where) <= 120 else f"{where[:100]}...{where[-17:]}"
            raise InvalidInputError(f"{shown} must be {_JSON_EXPECTED} nested at most {_MAX_EXTRAS_DEPTH} deep; got "
                                    f"a {type(value).__name__} deeper (a list or dict that holds itself?)")
        return f"<{type(value).__name__} nested too deep>"
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, np.bool_):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        if value.size > _MAX_EXTRAS_ITEMS:
            return _OMIT
        if value.dtype.kind not in ("biufU" if where is not None else "biufUS"):  # bytes' str is their repr
            if where is not None:
                raise InvalidInputError(f"{where} must be {_JSON_EXPECTED}; got an array of dtype {value.dtype}")
            return _OMIT
        return _json_value(value.tolist(), where, depth)
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if where is not None and not isinstance(key, str):  # {1: 2, "1": 3} would lose one value, silently
                raise InvalidInputError(f"{where} keys must be strings (glTF extras are a JSON object); got {key!r}")
            if str(key).startswith("_"):
                continue
            converted = _json_value(item, None if where is None else f"{where}[{str(key)!r}]", depth + 1)
            if converted is not _OMIT:
                out[str(key)] = converted
        return out
    if isinstance(value, (list, tuple)) or (where is None and isinstance(value, (set, frozenset))):
        if len(value) > _MAX_EXTRAS_ITEMS:
            return _OMIT
        items = [
            _json_value(item, None if where is None else f"{where}[{k}]", depth + 1) for k, item in enumerate(value)
        ]
        return [item for item in items if item is not _OMIT]
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if where is not None:
        raise InvalidInputError(f"{where} must be {_JSON_EXPECTED}; got {type(value).__name__}")
    return str(value)


def _gltf_scene(mesh: trimesh.Trimesh, target: Path, bounds: Bounds,
                origin: NDArray[np.float64] | None = None) -> trimesh.Scene:
    """One node holding ``mesh`` (a prepared copy: its visual, material and vertices may be replaced); large
    coordinates move into the node translation (float64 in JSON); a texture's material as :func:`_textured_material`
    makes it. Vertex attributes are dropped, as :func:`_gltf_document` drops them: trimesh's writer raised a bare
    KeyError for an integer or bool one ('i8') and wrote the others as custom attributes of its own layout (uint8 as
    VEC4)."""
    mesh.vertex_attributes.clear()  # the prepared copy's own dict
    material = getattr(mesh.visual, "material", None)
    if mesh.visual.kind == "texture" and material is not None:
        mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=_textured_material(material))
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    transform = _Z_UP_TO_Y_UP.copy()  # exact 0 and ±1: trimesh writes it as the node's matrix
    if _is_large(bounds) or origin is not None:
        offset = _gltf_offset(bounds, origin)
        mesh.vertices = vertices - offset  # a new array: the caller's (shared with the prepared copy) stays as it is
        transform[:3, 3] = _Z_UP_TO_Y_UP[:3, :3] @ offset + 0.0  # in the world frame
    if mesh.visual.kind == "texture" and isinstance(mesh.visual.material, trimesh.visual.material.PBRMaterial):
        _encoded_textures(mesh.visual.material)  # the prepared copy's own material (or _textured_material's)
    scene = trimesh.Scene()
    name = _utf8_name(target.stem) or "mesh"
    scene.add_geometry(mesh, geom_name=name, node_name=name, transform=transform)
    return scene


class _EncodedImage:
    """A texture image already encoded, as trimesh's glTF writer takes an image: its ``format`` and its
    ``save(file, format=...)``, which writes the bytes as they are (trimesh names the mimeType image/png for any
    format but JPEG)."""

    def __init__(self, data: bytes, format: str) -> None:
        self.data = data
        self.format = format

    def save(self, fp: Any, format: str | None = None, **params: Any) -> None:  # noqa: A002 - PIL's name
        fp.write(self.data)


def _encoded_textures(material: Any) -> None:
    """Each PIL texture image of ``material`` (a PBRMaterial of the prepared copy: changed in place) that trimesh
    writes as PNG, encoded here once with :func:`_png_options` (Z_RLE for a large one) as an :class:`_EncodedImage`.
    trimesh's writer re-encoded it at zlib's default (30 s for a texture of 77 M texels, the slowest step of
    ``stepterrain texture --mesh``), and hashed the material through the decoded image's bytes first. The PNG
    decodes to the same pixels either way. A large image :func:`save_image` has just written as PNG (the texture
    ``stepterrain texture -o tex.png --mesh out.glb`` drapes) takes that file's bytes (:func:`_written_png`) instead
    of being deflated a second time. An image opened from a JPEG stays a JPEG (:func:`_jpeg_data`): trimesh's writer
    re-encoded it at Pillow's default quality."""
    from PIL import Image

    for slot in _TEXTURE_SLOTS[1][1]:
        image = getattr(material, slot, None)
        if not isinstance(image, Image.Image):
            continue
        fill = slot == "baseColorTexture" and getattr(material, "alphaMode", None) in ("MASK", "BLEND")
        setattr(material, slot, _encoded_image(image, fill=fill, profile=False))


def _encoded_image(image: Any, *, fill: bool = True, profile: bool = True) -> _EncodedImage:
    """A PIL image as an :class:`_EncodedImage`: one opened from a JPEG as JPEG bytes (:func:`_jpeg_data`), any other
    as PNG bytes (:func:`_png_data`), with ``fill`` the colour of its transparent texels (alpha 0) that of the opaque
    ones near them (:func:`~stepterrain.io.fill_transparent`): a viewer's bilinear filter and mipmaps blend straight
    colour, and the garbage under a texture's transparent texels (`gdalwarp -dstalpha`'s nodata) showed as a fringe
    of that colour along the edge of its opaque ones (magenta under a world map's transparent polar caps).

    The PNG keeps the image's ICC profile with ``profile`` (an OBJ's side image: the filled texels' colours are
    those of opaque ones in the same colour space, and the filled image lost it), and carries none without (a glTF's
    texture: glTF 2.0 §3.8.3 says images SHOULD NOT embed ICC profiles, which clients MUST ignore, and the Khronos
    validator warns of a PNG with an iCCP chunk, IMAGE_FEATURES_UNSUPPORTED). A JPEG's bytes are kept as they are:
    the validator takes its ICC profile."""
    if image.format == "JPEG":
        return _EncodedImage(_jpeg_data(image), "JPEG")
    icc = image.info.get("icc_profile") if profile else None
    if fill and image.mode in _TRANSPARENT_COLOUR_MODES and "transparency" in image.info:
        # a palette's transparent index or an L or RGB PNG's transparent colour (tRNS): alpha without an alpha band,
        # whose texels of alpha 0 hold that one colour (magenta, say), which viewers filter into their opaque
        # neighbours' edge as they do an RGBA texture's garbage; written as LA or RGBA, filled, when some texel is it
        with_alpha = image.convert(_TRANSPARENT_COLOUR_MODES[image.mode])
        if _has_alpha_hole(with_alpha):
            image = with_alpha
    # the alpha's extrema read by Pillow first: an opaque texture (the common case, every OBJ side image's) is not
    # copied whole into a NumPy array (a 21600 x 10800's 0.9 GB, and 0.2 GB for the mask of its holes) to find none
    if fill and image.mode in ("RGBA", "LA") and _has_alpha_hole(image):
        from PIL import Image

        from .io import fill_transparent

        pixels = np.asarray(image)
        filled = fill_transparent(pixels)
        if filled is not pixels:
            image = Image.fromarray(filled, image.mode)
    return _EncodedImage(_png_data(image, icc), "PNG")


#: PIL modes whose PNG holds alpha as a transparent colour (``info["transparency"]``: a palette's transparent index
#: or alpha per entry, an L or RGB image's transparent grey or colour), and the mode with an alpha band each is
#: filled in (:func:`_encoded_image`).
_TRANSPARENT_COLOUR_MODES = {"P": "RGBA", "L": "LA", "RGB": "RGBA", "1": "LA"}


def _has_alpha_hole(image: Any) -> bool:
    """Whether the RGBA or LA PIL ``image`` has a texel of alpha 0 and one of more (what
    :func:`~stepterrain.io.fill_transparent` fills), from its alpha band's extrema."""
    low, high = image.getchannel("A").getextrema()
    return low == 0 < high


def _png_data(image: Any, icc_profile: bytes | None = None) -> bytes:
    """A PIL image as PNG bytes, as :func:`save_image` writes it (:func:`_png_options`), with the ICC profile
    ``icc_profile`` or none (whatever the image's ``info`` holds): the bytes of the large PNG it last wrote when
    that holds the same pixels (:func:`_written_png`), else encoded here."""
    options = _png_options(image)
    data = _written_png(image) if options and icc_profile is None else None
    if data is None:
        buffer = io.BytesIO()
        image.save(buffer, format="PNG", icc_profile=icc_profile, **options)
        data = buffer.getvalue()
    return data


#: The JPEG quality a texture image opened from a JPEG is re-encoded at when it is not that file's pixels any more
#: (:func:`_jpeg_data`), without chroma subsampling.
_JPEG_QUALITY = 95


def _jpeg_data(image: Any) -> bytes:
    """A PIL image opened from a JPEG (``format`` "JPEG") as JPEG bytes, for a glTF's embedded texture or an OBJ's
    side image: the bytes of the file it was opened from, unchanged, when that file still decodes to the image's
    pixels (:func:`_source_jpeg`); else encoded here at quality :data:`_JPEG_QUALITY` with 4:4:4 chroma (an image
    changed in place since, or decoded from bytes). trimesh's writers called ``save(format="JPEG")``: Pillow's
    default quality 75 with 4:2:0 chroma, a second lossy generation (the 3840 x 1920 Blue Marble: 4.7 MB -> 0.78 MB,
    its colours off by up to 119 levels, 4.9 on average, at coastlines and city lights); at quality 95 and 4:4:4 they
    are off by at most 6 levels, 0.06 on average, for a file the size of the source's."""
    data = _source_jpeg(image)
    if data is None:
        buffer = io.BytesIO()
        image.save(buffer, format="JPEG", quality=_JPEG_QUALITY, subsampling=0)
        data = buffer.getvalue()
    return data


def _source_jpeg(image: Any) -> bytes | None:
    """The bytes of the JPEG file ``image`` (a PIL image) was opened from (its ``filename``), when the file decodes to
    the same mode, size and pixels and carries no EXIF orientation but the upright one; else None (no file name, the
    file gone or changed, the image changed since, or a phone's photo stored turned: browsers, and so web glTF
    viewers, turn it upright by its tag, the texture is its stored pixels)."""
    from PIL import Image

    name = getattr(image, "filename", None)
    if not name or not isinstance(name, (str, bytes, os.PathLike)):
        return None
    try:
        data = Path(os.fsdecode(name)).read_bytes()
        with FILTERS, warnings.catch_warnings():  # one block at a time in the process (stepterrain._warning_filters)
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # warned when the image was opened
            with Image.open(io.BytesIO(data)) as source:
                if (source.format != "JPEG" or source.mode != image.mode or source.size != image.size
                        or source.getexif().get(0x0112, 1) != 1):
                    return None
                same = _pixels_digest(source) == _pixels_digest(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):
        return None
    return data if same else None


#: glTF sampler wrap modes by name (glTF 2.0 §5.26, sampler.wrapS / wrapT).
GLTF_WRAP = {"REPEAT": 10497, "CLAMP_TO_EDGE": 33071, "MIRRORED_REPEAT": 33648}


def texture_wrap(material: Any) -> tuple[str, str] | None:
    """The (u, v) wrap modes a textured mesh's ``material`` asks its sampler for, names of :data:`GLTF_WRAP` (its
    ``wrap`` attribute: :func:`~stepterrain.globe.drape_texture` sets ("REPEAT", "CLAMP_TO_EDGE"), the image
    periodic in longitude, not from pole to pole; :func:`~stepterrain.texture.drape` ("CLAMP_TO_EDGE",
    "CLAMP_TO_EDGE"), the image ending at the terrain's border), or None: glTF's default sampler, REPEAT both ways."""
    wrap = getattr(material, "wrap", None)
    if wrap is None:
        return None
    wrap = tuple(wrap)
    if len(wrap) != 2 or not all(mode in GLTF_WRAP for mode in wrap):
        raise InvalidInputError(f"material.wrap must be two of {sorted(GLTF_WRAP)} (u, v); got {wrap!r}")
    return wrap[0], wrap[1]


def _sampler_postprocessor(mesh: trimesh.Trimesh) -> Any:
    """trimesh's tree_postprocessor that gives the texture of ``mesh``'s material its :func:`texture_wrap` as a glTF
    sampler, or None when the material asks for none. trimesh writes no sampler, so a viewer wrapped a globe's
    plate-carrée image from pole to pole (glTF's default REPEAT in v): with mipmaps, the texels at one pole blended
    with those at the other, a grey diamond at the north pole and a dark spot at the white south pole."""
    wrap = texture_wrap(getattr(mesh.visual, "material", None)) if mesh.visual.kind == "texture" else None
    if wrap is None:
        return None

    def add_sampler(tree: dict[str, Any]) -> None:
        if not tree.get("textures"):
            return
        samplers = tree.setdefault("samplers", [])
        samplers.append({"wrapS": GLTF_WRAP[wrap[0]], "wrapT": GLTF_WRAP[wrap[1]]})
        for texture in tree["textures"]:
            texture["sampler"] = len(samplers) - 1

    return add_sampler


def _textured_material(material: Any) -> Any:
    """The material a textured mesh is written to glTF with. trimesh's ``SimpleMaterial`` (an image given as
    ``TextureVisuals(uv=..., image=...)``, as :func:`~stepterrain.globe.drape_texture` makes it) became
    baseColorFactor 0.4 (its default diffuse grey, multiplying the texture: the drape at 40 % brightness) and no
    metallicFactor (glTF's default 1: dark metal); it is now the image with a white factor (a colour without one),
    metallic 0, roughness 1 and double-sided, as :func:`_terrain_material`. A ``PBRMaterial`` (the prepared copy's
    own, changed in place) keeps what it sets; an unset metallicFactor becomes 0, an unset alphaMode that of its
    texture. The alphaMode follows the texture (:func:`_texture_alpha_mode`): glTF's default, OPAQUE, showed its
    transparent texels (nodata, outside a lens) as whatever colour they hold. Other materials are written as trimesh
    writes them."""
    if isinstance(material, trimesh.visual.material.SimpleMaterial):
        image = material.image
        factor = None if image is not None else material.diffuse
        mode, cutoff = _material_alpha_mode(image, factor)
        pbr = trimesh.visual.material.PBRMaterial(
            name=material.name, baseColorTexture=image, baseColorFactor=factor,
            metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True, alphaMode=mode, alphaCutoff=cutoff)
        wrap = texture_wrap(material)
        if wrap is not None:  # the sampler the texture asks for (a globe's drape)
            pbr.wrap = wrap
        return pbr
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        mode, cutoff = _material_alpha_mode(material.baseColorTexture, material.baseColorFactor)
        unset_alpha = material.alphaMode is None and mode != "OPAQUE"
        if material.metallicFactor is None:  # the prepared copy's own material: changed in place
            material.metallicFactor = 0.0
        if unset_alpha:
            material.alphaMode, material.alphaCutoff = mode, cutoff
    return material


def _material_alpha_mode(image: Any, factor: Any) -> tuple[str, float | None]:
    """:func:`_texture_alpha_mode` of a base colour texture ``image`` (or None) under the base colour ``factor`` (RGBA
    bytes, or None: white) that multiplies it (glTF 2.0 §3.9.2): "BLEND" when the factor's alpha is below 255, which
    makes every texel partly transparent. A translucent factor (a PBRMaterial's baseColorFactor alpha 0.5, a plain
    material's diffuse alpha) was written OPAQUE (its texture's mode, or none), and viewers ignored it where
    render_mesh blends it, or MASK, which at cutoff 0.5 showed its texels of alpha 0.5 opaque."""
    if _colour_alpha(factor) is not None:
        return "BLEND", None
    return _texture_alpha_mode(image)


def _texture_alpha_mode(image: Any) -> tuple[str, float | None]:
    """glTF's alphaMode (and alphaCutoff) for a base colour texture ``image`` (a PIL image, or None): "OPAQUE" when
    every texel is opaque (or the image has no alpha); "MASK" with cutoff 0.5 when its alpha is only 0 and 255 (a
    nodata hole, the outside of a hard-edged lens): each texel is shown or not, and the mesh keeps writing depth, so
    its terraces hide each other as opaque ones do (viewers draw a BLEND mesh without depth writes and without
    sorting its triangles, which showed far terraces through near ones); "BLEND" when some alpha lies between
    (a feathered lens, a layer of alpha 0.5), which only blending shows."""
    if image is None or not hasattr(image, "getbands"):
        return "OPAQUE", None
    if not ({"A", "a"} & set(image.getbands()) or "transparency" in image.info):
        return "OPAQUE", None
    alpha = np.asarray(image.convert("RGBA"))[..., 3]
    if alpha.size == 0 or alpha.min() == 255:
        return "OPAQUE", None
    if np.isin(alpha, (0, 255)).all():
        return "MASK", 0.5
    return "BLEND", None
