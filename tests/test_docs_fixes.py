"""Fixes found by a truth audit of the user-facing documentation: README.md, docs/*.md, benchmarks/README.md, the
public docstrings and every ``stepterrain COMMAND --help``, each claim checked against what the code does."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

import stepterrain as st

ROOT = Path(__file__).resolve().parents[1]


def test_bench_stepped_imports_as_benchmarks_readme_runs_it():
    """``pytest benchmarks/bench_stepped.py ...`` (every command of benchmarks/README.md's "Warp alone") failed at
    collection: the module called ``stepterrain._init_warp()``, which no longer exists (``_device.init_warp``)."""
    spec = importlib.util.spec_from_file_location("bench_stepped_docs_check", ROOT / "benchmarks" / "bench_stepped.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.DEVICES[0] == "cpu"
    assert [case.id for case in module.CASES][:3] == ["small-257", "medium-1025", "large-2049"]


def test_readme_adaptive_mesh_lies_on_the_dem_it_meshes():
    """README's ``local = st.adaptive_mesh(dem.heights, error=5.0, spacing=30.0)`` meshed the north-up DEM's rows as
    if they ran south to north (adaptive_mesh puts row i at y0 + i * dy, dy > 0): a mirror image of the terrain, at
    (0, 0). The line as the README now gives it puts every vertex on the DEM node it comes from, at its height."""
    import re

    import numpy as np
    import warp as wp

    import stepterrain as st

    wp.config.quiet = True
    (line,) = [m for m in re.findall(r"^local = st\.adaptive_mesh\(.*$", (ROOT / "README.md").read_text(), re.M)]
    names = {"st": st, "dem": st.sample_dem()}
    exec(line.split("  #")[0], names)  # noqa: S102 - the README's own line
    dem, local = names["dem"], names["local"]
    assert local.metadata is not None and len(local.faces) > 0
    x0, y0 = dem.origin
    dx, dy = dem.spacing
    j = (local.vertices[:, 0] - x0) / dx
    i = (local.vertices[:, 1] - y0) / dy
    assert np.allclose(i, np.round(i), atol=1e-6) and np.allclose(j, np.round(j), atol=1e-6)
    i, j = np.round(i).astype(int), np.round(j).astype(int)
    assert i.min() == 0 and j.min() == 0 and i.max() == dem.shape[0] - 1 and j.max() == dem.shape[1] - 1
    np.testing.assert_array_equal(local.vertices[:, 2], dem.heights[i, j])


def _north_up_crop():
    import numpy as np

    import stepterrain as st

    heights = np.asarray(st.sample_dem().heights, dtype=np.float32)[:65, :97].copy()
    assert not np.array_equal(heights[0], heights[-1])  # a mirror image would show
    return heights


def test_globe_md_adaptive_mesh_keeps_a_north_up_array_north_up():
    """docs/globe.md's ``local = adaptive_mesh(heights, error=5.0, spacing=30.0)`` put row i at y = 30 i: a north-up
    array's (load_dem's, the docs' ``heights``) north row at the south edge, a mirror image, as the README's line did
    (test above). The line as the page gives it puts row 0 at the north edge: y falls as the row grows."""
    import re

    import numpy as np
    import warp as wp

    from stepterrain.globe import adaptive_mesh

    wp.config.quiet = True
    (line,) = re.findall(r"^local = adaptive_mesh\(.*$", (ROOT / "docs" / "globe.md").read_text(), re.M)
    heights = _north_up_crop()
    names = {"adaptive_mesh": adaptive_mesh, "heights": heights}
    exec(line.split("  #")[0], names)  # noqa: S102 - the page's own line
    local = names["local"]
    i, j = np.asarray(local.metadata["node_index"]).T
    np.testing.assert_array_equal(local.vertices[:, 2], heights[i, j])
    north = local.vertices[i == 0, 1]
    south = local.vertices[i == heights.shape[0] - 1, 1]
    assert north.min() > south.max(), "row 0 of a north-up array lies south of its last row: a mirror image"
    assert np.allclose(np.diff(sorted(set(local.vertices[:, 1]))), 30.0)


def test_batch_md_image_data_keeps_a_north_up_array_north_up():
    """docs/batch.md says a north-up DEM's heights go into an ImageData (rows south to north) as ``heights[::-1]``,
    and its block then filled the grid with ``heights.ravel()``: the north row at y = 0, the terrain stepped as its
    mirror image. The block's line as the page gives it puts row 0 of a north-up array at the grid's north edge."""
    import re

    import numpy as np
    import pyvista as pv

    (line,) = re.findall(r"^grid = pv\.ImageData\(.*$", (ROOT / "docs" / "batch.md").read_text(), re.M)
    heights = _north_up_crop()
    names = {"pv": pv, "heights": heights, "H": heights.shape[0], "W": heights.shape[1]}
    exec(line.split("  #")[0], names)  # noqa: S102 - the page's own line
    grid = names["grid"]
    y = np.asarray(grid.points)[:, 1]
    z = np.asarray(grid["elevation"])
    np.testing.assert_array_equal(z[y == y.max()], heights[0], err_msg="the north row is not at the north edge")
    np.testing.assert_array_equal(z[y == y.min()], heights[-1])


def test_info_refusal_of_an_unknown_extension_names_the_mesh_formats_too(tmp_path, capsys):
    """``stepterrain info FILE`` describes "a DEM or a mesh file" (its --help), but a FILE of another extension (a
    photo, ``scan.xyz``) was refused as "unknown DEM extension '.jpg'; supported: .npy, .npz, ..., .dt2": the DEM
    formats alone, as if info read no mesh. The refusal names the mesh formats too; steps' keeps to DEMs."""
    from stepterrain import cli

    for name in ("photo.jpg", "scan.xyz"):
        path = tmp_path / name
        path.write_bytes(b"not a DEM nor a mesh")
        assert cli.main(["info", str(path)]) == 2
        err = capsys.readouterr().err
        assert f"unknown DEM extension '{path.suffix}'" in err and ".dt2" in err, err
        assert "a mesh file" in err and ".glb, .gltf, .obj, .ply, .stl, .3mf" in err, err
        assert len(err.strip().splitlines()) == 1, err
    assert cli.main(["steps", str(tmp_path / "photo.jpg"), "-o", str(tmp_path / "a.glb")]) == 2
    assert "mesh file" not in capsys.readouterr().err


def test_info_refusal_of_a_gzipped_mesh_says_to_gunzip_it(tmp_path, capsys):
    """``stepterrain info m.stl.gz`` was refused as "unknown DEM extension '.stl' of the file inside ...; or a mesh
    file: ..., .stl, ...": the extension refused and then listed as read. A gzip of a mesh file is refused saying that
    info reads a mesh uncompressed only; a gzip of another file keeps the refusal naming the mesh formats."""
    import gzip

    from stepterrain import cli

    path = tmp_path / "m.stl.gz"
    path.write_bytes(gzip.compress(b"solid x\nendsolid x\n"))
    assert cli.main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert "is read uncompressed only: gunzip it first" in err and "or a mesh file" not in err, err
    other = tmp_path / "notes.txt.gz"
    other.write_bytes(gzip.compress(b"x"))
    assert cli.main(["info", str(other)]) == 2
    err = capsys.readouterr().err
    assert "or a mesh file: .glb" in err and "gunzip" not in err, err


def test_the_image_extent_example_lays_the_map_over_its_npy_dem(tmp_path, monkeypatch):
    """texture --help and docs/texture.md showed ``dem.npy --spacing 30 --image map.png --image-extent=0,1500,0,1200``
    for a DEM 1500 x 1200 m: but an .npy's node (0, 0) is its north-west corner at (0, 0) and its rows run south, so
    it lies at y -1200..0, and that extent touched it along its north edge only (half a cell): the map showed in the
    first row of texels, the hypsometric colours everywhere else, without a word. The examples say -1200,0 now; run
    as shown (on a crop of the real Big Tujunga DEM, 51 x 41 nodes of 30 m), the map covers the texture."""
    import argparse
    import shlex

    from PIL import Image

    from stepterrain import cli

    from .test_docs import help_examples, page_command_lines

    parser = cli.build_parser()
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    lines = [argv for argv in help_examples(action.choices["texture"].epilog) if "dem.npy" in argv]
    page = (ROOT / "docs" / "texture.md").read_text(encoding="utf-8")
    lines += [shlex.split(line)[1:] for line in page_command_lines(page) if "dem.npy" in line]
    assert len(lines) == 2 and all(any(a.startswith("--image-extent") for a in argv) for argv in lines)
    np.save(tmp_path / "dem.npy", np.asarray(st.sample_dem().heights)[:41, :51])  # 51 x 41 nodes: 1500 x 1200 m
    magenta = np.zeros((120, 150, 3), np.uint8)
    magenta[..., 0] = magenta[..., 2] = 255
    Image.fromarray(magenta).save(tmp_path / "map.png")
    monkeypatch.chdir(tmp_path)
    for argv in lines:
        if "--png" in argv:  # no render
            k = argv.index("--png")
            argv = argv[:k] + argv[k + 2:]
        assert cli.main(["-q", *argv]) == 0, argv
        out = argv[argv.index("-o") + 1]
        with Image.open(tmp_path / out) as written:
            texture = np.asarray(written.convert("RGB")).astype(int)
        # the map shaded by the hillshade keeps no green; the hypsometric colours (terrain) all have some
        covered = (texture[..., 1] == 0) & (texture[..., 0] > 0)
        assert covered.mean() > 0.95, (" ".join(argv), covered.mean())
