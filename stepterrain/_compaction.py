"""The one count -> scan -> emit helper.

Every variable-size output (terrace faces, crossing vertices, refined triangles, culled primitives) is
allocated in three steps: a ``count_*`` kernel writes one int32 per thread into ``counts`` (length n + 1,
the last slot 0), :func:`exclusive_offsets` scans it and reads the total in the pass's single host sync,
and an ``emit_*`` kernel writes thread i's items from ``offsets[i]``. Before anything is allocated the
predicted size is checked against the memory budget (:func:`set_memory_budget`).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ._device import read_int32, scratch, zero_int32
from .errors import InvalidInputError, OutputTooLargeError

__all__ = ["count_buffer", "exclusive_offsets", "check_budget", "get_memory_budget", "set_memory_budget"]

_memory_budget: int = 16 * 1024**3

#: How a refusal of :func:`check_budget` says to raise the budget; the command line names its --memory-budget instead.
BUDGET_HINT = "raise the budget (stepterrain.set_memory_budget or memory_budget=)"

#: The hint refusals give now: :data:`BUDGET_HINT`, or the command line's while a command runs (:func:`budget_hint`).
_budget_hint: str = BUDGET_HINT


def budget_hint(text: str | None = None) -> str:
    """How a refusal over the budget says to raise it (:data:`BUDGET_HINT` by default); with ``text``, set it (the
    command line names its ``--memory-budget``) and return the previous one."""
    global _budget_hint
    previous = _budget_hint
    if text is not None:
        _budget_hint = text
    return previous


def get_memory_budget() -> int:
    """The largest output, in bytes, a single call may allocate (default 16 GiB); :func:`stepterrain.load_dem`
    refuses a file whose declared cells exceed it, before reading (the heights it keeps, not the read's working
    copies: see load_dem's Raises)."""
    return _memory_budget


def set_memory_budget(nbytes: int) -> int:
    """Set the output memory budget in bytes; returns the previous value.

    Examples
    --------
    >>> import stepterrain as st
    >>> previous = st.set_memory_budget(1 << 30)
    >>> st.get_memory_budget() == 1 << 30
    True
    >>> _ = st.set_memory_budget(previous)
    """
    global _memory_budget
    previous, _memory_budget = _memory_budget, budget_value(nbytes, "memory budget")
    return previous


#: The most an int32 index, count or offset holds: the kernels' counts, their exclusive offsets and the indices
#: they write are int32, so a total past it wraps whatever the memory budget allows (stepped, globe, close-ups).
MAX_INT32 = (1 << 31) - 1

#: What makes a stepped output smaller: the default hint of :func:`check_budget`.
SMALLER_HINT = "crop or coarsen the input (Terrain.crop, Terrain.coarsen; --crop, --coarsen) or coarsen the isovalues"

#: What makes a raster read whole (no crop) smaller: the hint of load_dem's refusal of one over the budget. The
#: commands without a --crop (info, globe) replace it (cli._OPTION_PHRASES): they pointed at an option they lack.
WHOLE_RASTER_HINT = ("crop or coarsen it first (crop= (the CLI's --crop) reads only the crop's window; gdal_translate "
                     "-outsize coarsens)")


def budget_value(nbytes: object, name: str = "memory_budget") -> int:
    """``nbytes`` checked as a memory budget: a positive int of bytes (an :class:`InvalidInputError` naming
    ``name`` otherwise)."""
    if isinstance(nbytes, bool) or not isinstance(nbytes, (int, np.integer)) or nbytes <= 0:
        raise InvalidInputError(f"{name} must be a positive int of bytes; got {nbytes!r}")
    return int(nbytes)


def check_budget(nbytes: int, what: str, budget: int | None = None, *,
                 hint: str = SMALLER_HINT, mesh: tuple[int, int] | None = None) -> None:
    """Raise :class:`OutputTooLargeError` when ``nbytes`` exceeds the budget, naming the size; ``budget`` (a
    caller's ``memory_budget=``) is checked first, ``hint`` says what would make the output smaller. The error
    carries ``nbytes``, ``advice`` (the figure its message ends in) and ``mesh`` (its declared attributes), the
    (vertices, faces) of the mesh refused (None for other outputs): the command line's advice for a run that
    renders that mesh too names the budget both need in place of that figure (cli's steps with --png)."""
    limit = _memory_budget if budget is None else budget_value(budget)
    if nbytes > limit:
        figure = _budget_figure(nbytes)
        raise OutputTooLargeError(
            f"{what} would need {_size_text(nbytes)}, over the memory budget of {_size_text(limit)}; {hint}, or "
            f"{_budget_hint}{figure}", nbytes=nbytes, mesh=mesh, advice=figure or None)


def _budget_figure(nbytes: int) -> str:
    """What a refusal's hint adds: " to at least 20GiB", the need rounded up to one significant digit of its largest
    unit (KiB to TiB, a size --memory-budget reads; ``20 * 1024**3`` bytes for the library), so that the budget
    suggested covers it (a fixed "e.g. 32GiB" did not, past 32 GiB); nothing for a need beyond 1024 TiB."""
    nbytes = int(nbytes)
    if nbytes > 1024**5:
        return ""
    for power, unit in ((4, "TiB"), (3, "GiB"), (2, "MiB"), (1, "KiB")):
        if nbytes >= 1024**power or power == 1:
            step = 10 ** (len(str(max(nbytes // 1024**power, 1))) - 1)  # one significant digit of the whole units
            count = -(-nbytes // (step * 1024**power)) * step  # rounded up
            return f" to at least {count}{unit}"
    return ""


def _size_text(nbytes: int) -> str:
    """Bytes as MiB to one decimal, or as bytes below a tenth of a MiB (which read "0.0 MiB"). Beyond float64 (a lens
    of resolution 10**400 asks for 10**800 bytes) as a power of ten: the division raised OverflowError."""
    if nbytes >= 2**1000:
        return f"over 10^{len(str(int(nbytes) // 1024**2)) - 1} MiB"
    if nbytes >= 0.1 * 1024**2:
        return f"{nbytes / 1024**2:,.1f} MiB"
    return f"{int(nbytes):,} byte{'' if int(nbytes) == 1 else 's'}"  # --memory-budget 1: "of 1 bytes"


def count_buffer(name: str, n: int, device: wp.Device) -> wp.array:
    """``counts`` for n threads: n + 1 int32 from the scratch pool, the last slot 0 (count kernels write the rest)."""
    counts = scratch(f"{name}.counts", n + 1, wp.int32, device)
    zero_int32(counts, n)
    return counts


def exclusive_offsets(counts: wp.array, name: str | None = None) -> tuple[wp.array, int]:
    """Exclusive prefix sum of ``counts`` (length n + 1) and the total ``offsets[n]``.

    With ``name`` the offsets live in the scratch pool (valid until the next pass of that name on this
    thread). The one host sync of a count -> scan -> emit pass happens here.
    """
    n1 = counts.shape[0]
    offsets = wp.empty_like(counts) if name is None else scratch(f"{name}.offsets", n1, wp.int32, counts.device)
    wp.utils.array_scan(counts, offsets, inclusive=False)
    total = read_int32(offsets, n1 - 1)
    return offsets, total
