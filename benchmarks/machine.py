"""Machine facts the benchmark reports print (shared by the run_*.py scripts; standard library only)."""

from __future__ import annotations

import argparse
import os
import platform
import subprocess


def cpu_model() -> str:
    """The CPU's model name from ``lscpu``, else ``platform.processor()``."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def pin_to_one_core() -> str:
    """Pin this process to the first core it may run on; returns what was done, for the report."""
    if not hasattr(os, "sched_setaffinity"):
        return "not pinned (no sched_setaffinity)"
    core = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {core})
    return f"pinned to CPU {core}"


def repeat_count(text: str) -> int:
    """The ``type`` of the run_*.py scripts' ``--repeat``: a whole number of runs, at least 1 (``--repeat 0`` timed
    nothing and crashed on the best or median of no run, after the set-up)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of runs (at least 1); got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected at least 1 run; got {value}")
    return value
