"""One side of an interleaved before/after timing of the globe (benchmarks/RESULTS.md, globe run 3).

    git archive <old commit> | tar -x -C /tmp/old && cp -r /tmp/old/kernels /tmp/old/stepterrain/kernels
    for k in 1 2 3; do for r in /tmp/old .; do python benchmarks/globe_ab.py $r [MESH_REPEAT] [THREADS]; done; done

Imports stepterrain from ROOT, pins itself to core 0 and one thread (THREADS > 1: to the first THREADS cores and
``set_cpu_threads(THREADS)``), and prints one JSON line: CPU and wall
seconds (best of N) of ``Globe.from_latlon`` at 6 x 1025² (best of 3), a far-view ``Globe.mesh`` at error 433
(best of MESH_REPEAT, default 7; also the median, ``mesh_median_wall``), ``run_globe.py``'s close view at errors
1000, 100 and 20 (best and median wall of MESH_REPEAT each) and ``adaptive_mesh`` of the 1025² Big Tujunga tile at
error 5 (best of 3).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
THREADS = int(sys.argv[3]) if len(sys.argv) > 3 else 1
if hasattr(os, "sched_setaffinity"):
    os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[:THREADS]))

import numpy as np  # noqa: E402

import stepterrain._device as _device  # noqa: E402  (before run_globe, which puts this checkout first)
from stepterrain.globe import EARTH_RADIUS, Globe, adaptive_mesh, look_from  # noqa: E402

from run_globe import best, data_file, tiled_dem, views  # noqa: E402  # isort: skip


def main() -> int:
    _device.set_cpu_threads(THREADS)
    with np.load(data_file("global_relief.npz")) as d:
        lat, lon, z = d["lat"], d["lon"], d["elevation"]
    Globe.from_latlon(z, lat, lon, face_size=33, device="cpu")  # compile / load
    globe, pre_cpu, pre_wall = best(lambda: Globe.from_latlon(z, lat, lon, face_size=1025, device="cpu"), 3)
    cam = look_from(30.0, 10.0, 3.0 * EARTH_RADIUS, aspect=1.6)
    repeat = int(sys.argv[2]) if len(sys.argv) > 2 else 7
    walls: list[float] = []

    def timed(camera: object, error: float, into: list[float]) -> object:
        start = time.perf_counter()
        out = globe.mesh(error=error, camera=camera)
        into.append(time.perf_counter() - start)
        return out

    mesh, mesh_cpu, mesh_wall = best(lambda: timed(cam, 433.0, walls), repeat)
    close = views(globe)["close"]
    close_walls: dict[float, list[float]] = {}
    for error in (1000.0, 100.0, 20.0):
        close_walls[error] = []
        best(lambda error=error: timed(close, error, close_walls[error]), 3)  # warm
        close_walls[error].clear()
        best(lambda error=error: timed(close, error, close_walls[error]), repeat)
    dem = tiled_dem(1025)
    adaptive_mesh(dem[:65, :65], error=1.0)
    planar, planar_cpu, planar_wall = best(lambda: adaptive_mesh(dem, error=5.0, spacing=1.0), 3)
    import stepterrain.globe

    print(json.dumps({"root": str(Path(stepterrain.globe.__file__).parents[1]), "threads": THREADS, "pre_cpu": pre_cpu,
                      "pre_wall": pre_wall, "mesh_cpu": mesh_cpu,
                      "mesh_wall": mesh_wall, "mesh_median_wall": float(np.median(walls)),
                      "triangles": len(mesh.faces), "planar_cpu": planar_cpu,
                      "planar_wall": planar_wall, "planar_triangles": len(planar.faces),
                      "close_best_wall": {str(e): min(w) for e, w in close_walls.items()},
                      "close_median_wall": {str(e): float(np.median(w)) for e, w in close_walls.items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
