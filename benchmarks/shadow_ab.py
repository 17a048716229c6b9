"""Interleaved before/after timing of the sweep-line shadows: best of 7 CPU times of ``cast_shadows`` on a 4096²
tiling of the embedded DEM at three light azimuths (315° = the default diagonal, 300° and 20° off the axes).

Run once per tree, alternating, each in its own process (an old tree extracted with ``git archive REV | tar -x -C
/tmp/old && cp -r /tmp/old/kernels /tmp/old/stepterrain/kernels``)::

    for k in 1 2; do for r in /tmp/old .; do python benchmarks/shadow_ab.py $r; done; done
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path


def main(root: str) -> None:
    sys.path.insert(0, str(Path(root).resolve()))
    import numpy as np

    import stepterrain as st
    from stepterrain import kernels
    from stepterrain import texture as tx

    # a tree without stepterrain/kernels (a checkout) gets its kernels from the running venv's editable install:
    # another worktree's, timed under this tree's name
    for module in (st, kernels):
        if not module.__file__.startswith(str(Path(root).resolve())):
            raise SystemExit(f"imported {module.__name__} from {module.__file__}, not from {root} (run a checkout "
                             "with its own venv's python, or copy its kernels/ to stepterrain/kernels)")
    dem = st.sample_dem()
    z = np.tile(dem.heights, (7, 4))[:4096, :4096].copy()
    tx.cast_shadows(z[:64, :64], spacing=dem.spacing, device="cpu")  # compile / load
    timings = []
    for degrees in (315.0, 300.0, 20.0):
        times = []
        for _ in range(7):
            t0 = time.process_time()
            tx.cast_shadows(z, azimuth=math.radians(degrees), spacing=dem.spacing, device="cpu")
            times.append(time.process_time() - t0)
        timings.append(f"shadows {degrees:.0f}°: {min(times) * 1e3:.1f} ms")
    print(root, "; ".join(timings))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
