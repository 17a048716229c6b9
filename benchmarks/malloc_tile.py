"""CPU time of one batch tile under three glibc malloc settings: why the default LocalCluster sets its own.

One unit is the batch benchmark's: a 1025² stepped tile of the real Big Tujunga DEM (mirror-tiled), interval
100 m, base 0.5, written as GLB to ``--work`` (tmpfs by default), then freed. Each setting runs in its own
process (glibc reads the variables at start-up), one core, ``--tiles`` tiles after one warm-up; the settings
take turns, ``--rounds`` times, so this VM's drift hits them alike. Printed: the median and best CPU time per
tile of each process.

- ``glibc``: glibc's defaults (what a plain Python loop gets);
- ``dask``: ``MALLOC_TRIM_THRESHOLD_=65536``, which dask's nannies set for their workers;
- ``batch``: ``stepterrain.batch.LOCAL_CLUSTER_MALLOC`` (1 GB thresholds), what the default LocalCluster sets.

Run: ``python benchmarks/malloc_tile.py [--rounds 3] [--tiles 14] [--work /dev/shm]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

_HERE = Path(__file__).resolve().parent

_CHILD = """
import gc, os, sys, time
sys.path[:0] = [{bench!r}, {root!r}]
import stepterrain as st
from baselines import grid_heights
from stepterrain.export import save_mesh
st.set_cpu_threads(1)
heights, spacing = grid_heights(1025)
out = os.path.join({work!r}, "malloc_tile_%d.glb" % os.getpid())
times = []
for k in range({tiles} + 1):
    gc.collect()
    t0 = time.process_time()
    mesh = st.stepped(heights, interval=100.0, base=0.5, spacing=spacing)
    save_mesh(mesh, out)
    del mesh
    gc.collect(1)
    times.append(time.process_time() - t0)
os.remove(out)
print(" ".join(repr(t) for t in times[1:]))
"""


def settings() -> dict[str, dict[str, str]]:
    sys.path.insert(0, str(_HERE.parent))
    from stepterrain.batch import LOCAL_CLUSTER_MALLOC

    return {
        "glibc": {},
        "dask": {"MALLOC_TRIM_THRESHOLD_": "65536"},
        "batch": {key: str(value) for key, value in LOCAL_CLUSTER_MALLOC.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--tiles", type=int, default=14, help="tiles per process, after one warm-up tile")
    parser.add_argument("--work", default="/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir())
    args = parser.parse_args()
    code = _CHILD.format(bench=str(_HERE), root=str(_HERE.parent), work=args.work, tiles=args.tiles)
    base = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    results: dict[str, list[tuple[float, float]]] = {name: [] for name in settings()}
    pin = ["taskset", "-c", "0"] if os.path.exists("/usr/bin/taskset") else []
    for r in range(args.rounds):
        for name, extra in settings().items():
            run = subprocess.run([*pin, sys.executable, "-c", code], env={**base, **extra}, capture_output=True,
                                 text=True, check=True)  # fmt: skip
            times = [float(t) for t in run.stdout.split()]
            results[name].append((statistics.median(times), min(times)))
            print(f"round {r + 1} {name:6s} CPU ms per tile: median {statistics.median(times) * 1e3:.1f}, "
                  f"best {min(times) * 1e3:.1f}", flush=True)
    print()
    print("| malloc setting | CPU ms per tile, median of each process | best |")
    print("|---|---|---|")
    for name, rows in results.items():
        print(f"| {name} | {', '.join(f'{m * 1e3:.1f}' for m, _ in rows)} | {min(b for _, b in rows) * 1e3:.1f} |")


if __name__ == "__main__":
    main()
