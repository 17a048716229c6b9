"""Ctrl-C (SIGINT), SIGTERM and SIGHUP held back while third-party code runs that an exception in its middle leaves
half made: the package's own imports in ``__init__.py`` (trimesh swallows any exception of its optional imports,
KeyboardInterrupt too), a dask cluster starting (batch), VTK's extension modules loading (render)."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["signals_held", "terminal_signals_blocked_for_children"]


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold back SIGINT, SIGTERM and SIGHUP while the block runs; a signal that came meanwhile goes to its own handler
    when the block ends (several: in the order they came), also when it ends with an exception (Ctrl-C:
    KeyboardInterrupt there, the exception its context).

    A LocalCluster interrupted while its nannies started was never closed: dask's exit hook then failed on it
    ("Exception ignored in atexit callback ... AssertionError: Status.init"); heights half scattered or tasks half
    submitted reached a scheduler whose client had closed, which logged a CRITICAL traceback for each of them.
    Only a Python handler is held back (a signal ignored or left to the system stays so), and only in the main
    thread, the one Python's handlers run in. The same signal a second time goes to its handler at once: a second
    Ctrl-C still ends a start or a scatter that hangs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: dict[int, Any] = {}
    came: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        if signum in came:
            held[signum](signum, frame)
        came.append(signum)

    for number in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)):
        handler = None if number is None else signal.getsignal(number)
        if callable(handler):
            held[number] = handler  # type: ignore[index]
            signal.signal(number, hold)  # type: ignore[arg-type]
    try:
        yield
    finally:
        for number, handler in held.items():
            signal.signal(number, handler)
        # also when the block failed: the failure is most likely the signal's own doing (the terminal's Ctrl-C reaches
        # the LocalCluster's worker processes too, which died as they started), and the user asked to stop; it was
        # lost, and `batch` ended "error: cannot start a LocalCluster ... Nanny failed to start", exit status 2
        # in the order they came: SIGTERM, then Ctrl-C, ended the run as Ctrl-C (exit status 130, not 143), the
        # SIGTERM never raised
        for number in dict.fromkeys(came):
            held[number](number, None)  # Python's default SIGINT handler raises KeyboardInterrupt here


@contextmanager
def terminal_signals_blocked_for_children() -> Iterator[None]:
    """Block SIGINT and SIGHUP in this thread while the block runs, so that the threads it starts, and the processes
    those spawn, start with them blocked (a thread inherits its creator's signal mask; fork and exec keep it); such a
    signal meanwhile stays pending and goes to this process's handler when the block ends (inside
    :func:`signals_held`: held back until that ends).

    The terminal's Ctrl-C goes to its whole foreground process group: the LocalCluster's worker processes got it too,
    and those still importing the package as they started (multiprocessing's spawn runs the main script) each printed
    a KeyboardInterrupt traceback above the command's "stepterrain: interrupted". A closed terminal's SIGHUP (the
    shell sends it to each job's process group) killed the workers, whose lost connections printed CommClosedError
    tracebacks and whose outputs were lost, and multiprocessing's resource tracker, whose relaunched successor printed
    a KeyError traceback for each semaphore the workers had registered. The workers are the cluster's to stop (this
    process closes it after either signal): started from the cluster's event loop thread, made in this block, they
    never see them, also those the nanny restarts later; SIGTERM still ends them (the nanny's own way to stop one).
    batch.start_local_cluster makes only that thread in this block, not the whole cluster: this thread's mask is back
    before the workers start, so a second Ctrl-C still ends a start that hangs.
    multiprocessing's resource tracker starts here, with both blocked: ``resource_tracker.ensure_running`` unblocks
    SIGINT in the thread that starts it as it returns, which was the cluster's event loop thread (as it made the
    workers' queues): their threads, and so the workers, had SIGINT unblocked again. A no-op off the main thread
    and where the system has no signal masks."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    signals = {signal.SIGINT, signal.SIGHUP}
    before = signal.pthread_sigmask(signal.SIG_BLOCK, signals)
    try:
        resource_tracker.ensure_running()  # unblocks SIGINT (and SIGTERM) here as it returns: blocked again below
        signal.pthread_sigmask(signal.SIG_BLOCK, signals)
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)
