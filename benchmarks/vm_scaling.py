"""How well this machine runs two processes at once, for three kinds of work: the ceiling of any 2-worker speed-up.

Each round runs one process pinned to core 0 alone, then two at once (cores 0 and 1), and takes
2 × t(alone) / t(slower of the two) as the speed-up. The work:

- ``alu``: a pure-Python integer loop (registers and L1 only, no memory traffic);
- ``mem``: 512 MB numpy copies (memory-bound);
- ``tile``: 4 stepped 1024²/20 tiles and their GLB writes (the batch benchmark's unit of work).

If even ``alu`` stays below 2×, the hypervisor (steal when both vCPUs are busy) sets the ceiling, and no change
to the pipeline can lift a 2-worker batch above it.

Run: ``python benchmarks/vm_scaling.py [--rounds 8] [--kinds alu mem tile]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_HERE = Path(__file__).resolve().parent


def work(kind: str) -> float:
    """Seconds of one unit of ``kind`` (warmed up first where it compiles or allocates)."""
    if kind == "alu":
        def unit() -> None:
            x = 0
            for _ in range(6_000_000):
                x = (x * 1103515245 + 12345) & 0xFFFFFFFF
    elif kind == "mem":
        import numpy as np

        a = np.ones(64_000_000, np.float64)
        b = np.empty_like(a)

        def unit() -> None:
            for _ in range(6):
                np.copyto(b, a)
    else:
        sys.path.insert(0, str(_HERE.parent))
        import stepterrain as st
        from benchmarks import baselines
        from stepterrain.export import save_mesh

        h, spacing = baselines.grid_heights(1025)
        values = baselines.steps_isovalues(h, 20)
        target = Path(tempfile.mkdtemp()) / "tile.glb"

        def unit() -> None:
            for _ in range(4):
                save_mesh(st.stepped(h, levels=values, spacing=spacing, device="cpu"), target)
    unit()
    start = time.perf_counter()
    unit()
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--kinds", nargs="+", default=["alu", "mem", "tile"], choices=["alu", "mem", "tile"])
    parser.add_argument("--child", nargs=2, metavar=("KIND", "CORE"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        kind, core = args.child
        os.sched_setaffinity(0, {int(core)})
        print(work(kind))
        return 0
    if len(os.sched_getaffinity(0)) < 2:
        parser.error("needs two cores")

    def run(kind: str, cores: tuple[int, ...]) -> list[float]:
        command = [sys.executable, __file__, "--child", kind]
        procs = [subprocess.Popen([*command, str(c)], stdout=subprocess.PIPE, text=True) for c in cores]
        return [float(p.communicate()[0].split()[-1]) for p in procs]

    print(f"{args.rounds} rounds each; speed-up = 2 x t(alone) / t(two at once)")
    for kind in args.kinds:
        ratios = []
        for _ in range(args.rounds):
            (alone,) = run(kind, (0,))
            both = run(kind, (0, 1))
            ratios.append(2 * alone / max(both))
            print(f"  {kind}: alone {alone:.3f} s, two at once {both[0]:.3f} / {both[1]:.3f} s -> {ratios[-1]:.2f}x",
                  flush=True)
        print(f"{kind}: median {statistics.median(ratios):.2f}x (min {min(ratios):.2f}, max {max(ratios):.2f})",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
