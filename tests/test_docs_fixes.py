"""Fixes found by a truth audit of the user-facing documentation: README.md, docs/*.md, benchmarks/README.md, the
public docstrings and every ``stepterrain COMMAND --help``, each claim checked against what the code does."""

from __future__ import annotations

import importlib.util
from pathlib import Path

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
