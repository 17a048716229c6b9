"""Identity memos: a value derived from objects the caller keeps (read-only arrays, ROIs, uploads), made once
while those very objects come back. Shared by the close-ups (per-ROI uploads, culls, anchors) and the layered
renderer (the joined faces and colours of merged passes)."""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np


def derived(memo: dict, key: tuple, refs: tuple, build: Any, *, limit: int = 64) -> Any:
    """``build()`` memoized under ``key`` while the objects ``refs`` are the same objects (the key holds their
    ids). Arrays in the value are made read-only: the callers that find it share them. Entries are kept and dropped
    as :func:`keep` does."""
    value = recall(memo, key, refs)
    if value is not MISSING:
        return value
    value = build()
    for array in value if isinstance(value, tuple) else (value,):
        if isinstance(array, np.ndarray):  # shared by the callers that find it here
            array.setflags(write=False)
    keep(memo, key, refs, value, limit=limit)
    return value


#: What :func:`recall` gives for no entry (a value may be None).
MISSING = object()


def recall(memo: dict, key: tuple, refs: tuple) -> Any:
    """The value :func:`keep` put under ``key`` with these very objects ``refs``; ``MISSING`` for none (or one kept
    with other objects, some perhaps gone: a dead object's id may come back with another object)."""
    entry = memo.get(key)  # one read: the objects and the value of one entry, whatever other threads put meanwhile
    if entry is not None and all(same(held, ref) for held, ref in zip(entry[0], refs, strict=True)):
        return entry[1]
    return MISSING


def keep(memo: dict, key: tuple, refs: tuple, value: Any, *, limit: int) -> None:
    """Put ``value`` under ``key`` for :func:`recall` with the objects ``refs``, held weakly where they take a weak
    reference (ROIs, arrays, close-ups, textures; others, such as tuples or None, strongly). Held strongly, every ROI
    of a loop over new ones (a height band swept over a DEM's heights) stayed alive with its mask, upload, cull and
    outline until ``limit`` entries (64: ~800 MB on the embedded DEM). The entries one of whose objects is gone are
    dropped first (:func:`sweep`), then all of them when ``limit`` are left and ``key`` is a new one (one put again in
    place does not grow the memo).

    Threads may share a memo: an entry is one tuple, put and read in one step, so :func:`recall` finds a value with the
    objects it was made from or nothing; at worst a sweep or a clearing drops an entry another thread just put, which
    is made again when next asked for."""
    sweep(memo)
    if len(memo) >= limit and key not in memo:
        memo.clear()
    memo[key] = (tuple(hold(ref) for ref in refs), value)


def sweep(memo: dict) -> None:
    """Drop the entries of ``memo`` (each a tuple whose first item holds its objects, as :func:`hold` gives them) one
    of whose objects is gone."""
    # list(): a snapshot in one step, so that a thread adding an entry meanwhile does not break the loop
    for gone, entry in list(memo.items()):
        if any(isinstance(h, weakref.ref) and h() is None for h in entry[0]):
            memo.pop(gone, None)


class _Strong:
    """A strong reference called as a weak one is: ``_Strong(obj)()`` is ``obj``."""

    __slots__ = ("obj",)

    def __init__(self, obj: Any) -> None:
        self.obj = obj

    def __call__(self) -> Any:
        return self.obj


def same(held: weakref.ref | _Strong, obj: Any) -> bool:
    """Whether ``held`` (as :func:`hold` gives it) holds ``obj`` itself. A weak reference whose object is gone holds
    nothing, not None: a renderer's joined layers (a key without the ids) made with colours now gone were found for
    the same faces without colours (None), and drawn in the gone colours."""
    got = held()
    return got is obj and (got is not None or isinstance(held, _Strong))


def hold(obj: Any) -> weakref.ref | _Strong:
    """A weak reference to ``obj`` where it takes one, else a strong one."""
    try:
        return weakref.ref(obj)
    except TypeError:  # None, tuples, ints: no weak references
        return _Strong(obj)


class Same:
    """A key part that stands for one object by its identity and keeps it alive: equal to another ``Same`` of the
    very same object only. A bare ``id(obj)`` in a key that outlives ``obj`` (a renderer's upload key) matched a
    later object that Python gave the freed id."""

    __slots__ = ("obj",)

    def __init__(self, obj: Any) -> None:
        self.obj = obj

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Same) and other.obj is self.obj

    def __hash__(self) -> int:
        return id(self.obj)

    def __repr__(self) -> str:
        return f"Same({type(self.obj).__name__} at {id(self.obj):#x})"
