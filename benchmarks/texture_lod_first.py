"""First renders only: wall and CPU seconds of ``render_with_textures`` on a fresh quadtree, texture tree and camera
(texture_lod_ab.py's scene: sample DEM, leaf_size 32, 1280 x 800, τ_user = 2), REPEAT per view in one process, no
painting; CPU time (``time.process_time``) is steadier than wall time on a shared, loaded box (helper h350).

    mkdir /tmp/old && git archive <old commit> | tar -x -C /tmp/old
    for k in 1 2 3; do for r in /tmp/old .; do
        python benchmarks/texture_lod_first.py $r 3 >> /tmp/first.jsonl; done; done
    python benchmarks/texture_lod_first.py --summary /tmp/first.jsonl
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path


def summary(path: str) -> None:
    rows: dict[str, dict[str, list[list[float]]]] = {}
    for line in Path(path).read_text().splitlines():
        if line.startswith("{"):
            d = json.loads(line)
            for view, runs in d["views"].items():
                rows.setdefault(view, {}).setdefault(d["root"], []).extend(runs)
    for view, sides in rows.items():
        for root, runs in sides.items():
            wall, cpu = [r[0] * 1e3 for r in runs], [r[1] * 1e3 for r in runs]
            print(f"{view:13s} {root}: {len(runs)} renders, {sorted({int(r[2]) for r in runs})} items; wall best "
                  f"{min(wall):.1f} median {statistics.median(wall):.1f} ms; CPU best {min(cpu):.1f} median "
                  f"{statistics.median(cpu):.1f} ms")


def main() -> None:
    if sys.argv[1:2] == ["--summary"]:
        summary(sys.argv[2])
        return
    root_dir = Path(sys.argv[1]).resolve()
    repeat = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    sys.path.insert(0, str(root_dir))
    sys.path.insert(1, str(Path(__file__).resolve().parent))
    from texture_lod_ab import VIEWS, scene

    import stepterrain as st
    from stepterrain import texture_lod

    if not st.__file__.startswith(str(root_dir)):
        raise SystemExit(f"stepterrain imported from {st.__file__}, not {root_dir}")
    out: dict[str, list[list[float]]] = {}
    for _ in range(repeat):
        for view in VIEWS:
            quadtree, image, cameras = scene(st, texture_lod)  # fresh: no seam error measured, no camera cache
            camera, gamma_user = cameras[view]
            with texture_lod.ImagePyramid.build(image, extent=quadtree.root.domain) as pyramid:
                tree = texture_lod.TextureTree(pyramid, quadtree, max_texture_size=256)
                cpu, wall = time.process_time(), time.perf_counter()
                items = texture_lod.render_with_textures(quadtree.root, [tree.root], camera, gamma_user=gamma_user,
                                                         tau_user=2.0)
                wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
            out.setdefault(view, []).append([wall, cpu, len(items)])
    print(json.dumps({"root": str(root_dir), "views": out}))


if __name__ == "__main__":
    main()
