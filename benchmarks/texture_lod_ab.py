"""One side of an interleaved before/after timing of the LOD traversal and painting (texture_lod's
``render_with_textures`` and ``paint_with_textures``) on the sample DEM, leaf_size 32, 1280 x 800.

    git worktree add /tmp/old <old commit>
    for k in 1 2 3 4 5; do for r in /tmp/old .; do python benchmarks/texture_lod_ab.py $r >> /tmp/ab.jsonl; done; done
    python benchmarks/texture_lod_ab.py --summary /tmp/ab.jsonl

Imports stepterrain from ROOT and prints one JSON line: per view (far oblique and near oblique at γ_user = 1, a map
view at γ_user = 4; τ_user = 2 over a 1197 x 643 image), the number of items, the wall seconds of the first
``render_with_textures`` on a fresh quadtree (its lazily measured seam errors included), of a second one (``warm``),
and of painting every item. ``--profile VIEW`` runs cProfile over the first render and the painting of that view
instead.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

VIEWS = ("far oblique", "near oblique", "map view")


def summary(path: str) -> None:
    rows: dict[str, dict[str, dict[str, list[float]]]] = {}
    for line in Path(path).read_text().splitlines():
        if not line.startswith("{"):
            continue
        d = json.loads(line)
        for view, numbers in d["views"].items():
            side = rows.setdefault(view, {}).setdefault(d["root"], {})
            for key, value in numbers.items():
                side.setdefault(key, []).append(value)
    for view, sides in rows.items():
        for root, numbers in sides.items():
            text = " | ".join(f"{key} {statistics.median(v):.3f}" + (f" (min {min(v):.3f})" if key != "items" else "")
                              for key, v in numbers.items())
            print(f"{view:13s} {root}: {text} ({len(numbers['items'])} runs)")


def scene(st, texture_lod):
    """The sample DEM's quadtree (leaf_size 32), a texture tree over a 643 x 1197 image, and the three cameras."""
    import math

    import numpy as np

    terrain = st.sample_dem()
    quadtree = texture_lod.PatchQuadtree(terrain, leaf_size=32)
    root = quadtree.root
    x0, x1, y0, y1 = root.domain
    low, top = float(root.box[0, 2]), float(root.box[1, 2])
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (*terrain.heights.shape, 3), dtype=np.uint8)
    w, cy = x1 - x0, (y0 + y1) / 2
    a = math.radians(1.0)
    cameras = {
        "far oblique": (st.Camera((x0 - 1.5 * w, cy, top + 0.5 * w), ((x0 + x1) / 2, cy, low), viewport=(1280, 800)),
                        1.0),
        "near oblique": (st.Camera((x0 + 0.2 * w, y0 + 0.1 * (y1 - y0), top + 300.0),
                                   (x0 + 0.6 * w, cy, low), viewport=(1280, 800)), 1.0),
        "map view": (st.Camera(((x0 + x1) / 2, cy, top + 25000.0),
                               ((x0 + x1) / 2, cy + math.sin(a), top + 25000.0 - math.cos(a)), up=(0.0, 1.0, 0.0),
                               viewport=(1280, 800)), 4.0),
    }
    return quadtree, image, cameras


def main() -> None:
    if sys.argv[1:2] == ["--summary"]:
        summary(sys.argv[2])
        return
    root_dir = Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
    profile = sys.argv[sys.argv.index("--profile") + 1] if "--profile" in sys.argv else None
    sys.path.insert(0, str(root_dir))
    import stepterrain as st
    from stepterrain import texture_lod

    if not st.__file__.startswith(str(root_dir)):
        raise SystemExit(f"stepterrain imported from {st.__file__}, not {root_dir}")
    _, image, cameras = scene(st, texture_lod)
    out = {"root": str(root_dir), "views": {}}
    for view, (camera, gamma_user) in cameras.items():
        if profile is not None and view != profile:
            continue
        quadtree, _, _ = scene(st, texture_lod)  # fresh: no seam error measured yet
        with texture_lod.ImagePyramid.build(image, extent=quadtree.root.domain) as pyramid:
            tree = texture_lod.TextureTree(pyramid, quadtree, max_texture_size=256)

            def render(root=quadtree.root, tree=tree, camera=camera, gamma_user=gamma_user):
                return texture_lod.render_with_textures(root, [tree.root], camera, gamma_user=gamma_user,
                                                        tau_user=2.0)

            def paint(items):
                return [texture_lod.paint_with_textures(item) for item in items]

            if profile is not None:
                import cProfile
                import pstats

                pr = cProfile.Profile()
                pr.enable()
                items = render()
                pr.disable()
                pstats.Stats(pr).sort_stats("cumulative").print_stats(25)
                pr = cProfile.Profile()
                pr.enable()
                paint(items)
                pr.disable()
                pstats.Stats(pr).sort_stats("cumulative").print_stats(25)
                return
            t0 = time.perf_counter()
            items = render()
            t1 = time.perf_counter()
            render()
            t2 = time.perf_counter()
            paint(items)
            t3 = time.perf_counter()
        out["views"][view] = {"items": len(items), "render": t1 - t0, "warm": t2 - t1, "paint": t3 - t2}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
