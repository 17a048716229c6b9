"""Digest of texture_lod's cuts and painted meshes, to check a speed-up changes no result (helper h332).

    git worktree add /tmp/head HEAD
    python benchmarks/texture_lod_same.py /tmp/head /tmp/head.json
    python benchmarks/texture_lod_same.py . /tmp/new.json && diff /tmp/head.json /tmp/new.json

Imports stepterrain from ROOT; per quadtree (sample DEM at leaf_size 32, a 101 x 77 synthetic DEM with a nodata hole
at leaf_size 4), view (far and near oblique, map view, across from a corner) and hybrid setting, two texture layers:
writes the number of items and SHA-256s of every item's geometry, textures, lighting, seams and finer patches (by
depth, rows and columns), of the drawn patches' seam errors, and of both layers' painted meshes (vertices, faces, UVs).
"""

from __future__ import annotations

import hashlib
import json
import math
import sys


def key(p):
    return None if p is None else [p.depth, *p.rows, *p.cols]


def texture_key(m):
    return None if m is None else [m.level, *map(int, m.window), key(m.geometry)]


def cameras(st, root):
    x0, x1, y0, y1 = root.domain
    low, top = float(root.box[0, 2]), float(root.box[1, 2])
    w, cy = x1 - x0, (y0 + y1) / 2
    a = math.radians(1.0)
    high = top + 0.7 * w
    return {
        "far": (st.Camera((x0 - 1.5 * w, cy, top + 0.5 * w), ((x0 + x1) / 2, cy, low), viewport=(1280, 800)), 1.0, 8.0),
        "near": (st.Camera((x0 + 0.2 * w, y0 + 0.1 * (y1 - y0), top + 0.01 * w), (x0 + 0.6 * w, cy, low),
                           viewport=(1280, 800)), 1.0, 8.0),
        "map": (st.Camera(((x0 + x1) / 2, cy, high), ((x0 + x1) / 2, cy + math.sin(a), high - math.cos(a)),
                          up=(0.0, 1.0, 0.0), viewport=(1280, 800)), 4.0, 8.0),
        "corner": (st.Camera((x0 - 0.05 * w, y1 + 0.05 * w, top + 0.05 * w), (x1, y0, low), viewport=(800, 600),
                             fov=math.radians(90)), 0.5, 1e9),
    }


def main() -> None:
    sys.path.insert(0, sys.argv[1])
    import numpy as np

    import stepterrain as st
    from stepterrain import texture_lod as tl
    from stepterrain.terrain import as_terrain

    yy, xx = np.mgrid[0:101, 0:77]
    heights = 40 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + np.random.default_rng(3).normal(0, 0.5, xx.shape)
    heights[40:44, 30:33] = np.nan
    cases = [("sample32", tl.PatchQuadtree(st.sample_dem(), leaf_size=32)),
             ("synthetic", tl.PatchQuadtree(as_terrain(heights, spacing=(10.0, -10.0)), leaf_size=4))]
    rng = np.random.default_rng(0)
    out = {}
    for name, quadtree in cases:
        root = quadtree.root
        image = rng.integers(0, 255, (*quadtree.terrain.heights.shape, 3), dtype=np.uint8)
        with tl.ImagePyramid.build(image, extent=root.domain) as pyramid:
            trees = [tl.TextureTree(pyramid, quadtree, max_texture_size=64),
                     tl.TextureTree(pyramid, quadtree, max_texture_size=16)]
            for view, (camera, gamma_user, tau_user) in cameras(st, root).items():
                for hybrid in (None, [False, True]):
                    items = tl.render_with_textures(root, [t.root for t in trees], camera, gamma_user=gamma_user,
                                                    tau_user=tau_user, hybrid=hybrid)
                    meshes = hashlib.sha256()
                    record = []
                    for item in items:
                        record.append([key(item.geometry), [texture_key(m) for m in item.textures],
                                       list(item.lighting), [key(s) for s in item.seams],
                                       [[key(f) for f in across] for across in item.finer]])
                        for layer in (0, 1) if hybrid is None else ():
                            if item.textures[layer] is not None:
                                mesh = tl.paint_with_textures(item, layer)
                                for array in (mesh.vertices, mesh.faces, mesh.visual.uv):
                                    meshes.update(np.ascontiguousarray(array).tobytes())
                    seams = np.array([item.geometry.seam_errors for item in items])
                    out[f"{name}/{view}/{hybrid}"] = {
                        "n": len(items), "items": hashlib.sha256(json.dumps(record).encode()).hexdigest(),
                        "meshes": meshes.hexdigest(), "seam": hashlib.sha256(seams.tobytes()).hexdigest()}
                    print(name, view, hybrid, len(items), file=sys.stderr)
    with open(sys.argv[2], "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
