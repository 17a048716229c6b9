"""Identity memos: a value derived from objects the caller keeps (read-only arrays, ROIs, uploads), made once
while those very objects come back. Shared by the close-ups (per-ROI uploads, culls, anchors) and the layered
renderer (the joined faces and colours of merged passes)."""

from __future__ import annotations

from typing import Any

import numpy as np


def derived(memo: dict, key: tuple, refs: tuple, build: Any, *, limit: int = 64) -> Any:
    """``build()`` memoized under ``key`` while the objects ``refs`` are the same objects (the key holds their
    ids, which stay theirs while the entry keeps them). Arrays in the value are made read-only: the callers
    that find it share them. The memo is emptied when it reaches ``limit`` entries."""
    entry = memo.get(key)
    if entry is not None and all(a is b for a, b in zip(entry[0], refs, strict=True)):
        return entry[1]
    value = build()
    for array in value if isinstance(value, tuple) else (value,):
        if isinstance(array, np.ndarray):  # shared by the callers that find it here
            array.setflags(write=False)
    if len(memo) >= limit:
        memo.clear()
    memo[key] = (refs, value)
    return value


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
