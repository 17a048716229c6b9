"""Every ```python block of the README and docs/*.md runs as written, and does what its comments promise.

The blocks use a few names they leave to the reader (a heights array, a TIN, a folder of tiles); the fixtures
below give them real data (crops of the embedded DEM). Each block runs in a fresh folder, with the names the
earlier blocks of the same page defined (a page reads top to bottom).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

import stepterrain as st
from stepterrain import render

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
AVAILABLE, REASON = render.offscreen_available()


def python_blocks(page: Path) -> list[str]:
    return BLOCK.findall(page.read_text(encoding="utf-8"))


def reader_names(folder: Path) -> dict:
    """The names the pages use without defining them, bound to crops of the embedded DEM."""
    import pyvista as pv

    heights = np.asarray(st.sample_dem().heights, dtype=np.float32)
    crop = np.ascontiguousarray(heights[:257, :257])
    tiles = folder / "dem_tiles"
    tiles.mkdir()
    for k in range(2):
        np.save(tiles / f"tile_{k}.npy", heights[:64, 64 * k : 64 * k + 65])
    return {
        "heights_array": heights[:48, :64].copy(),
        "trimesh_tin": st.heightfield_mesh(heights[:24, :32], spacing=(30.0, 30.0)),
        "heights": crop,
        "H": crop.shape[0],
        "W": crop.shape[1],
        "pv": pv,
        "__name__": "__main__",  # the blocks run as a script would (batch.md's LocalCluster guard)
    }


def test_the_pages_have_python_blocks():
    found = {page.name: len(python_blocks(page)) for page in PAGES}
    assert found["README.md"] >= 4, found
    assert all(found[name] >= 1 for name in ("globe.md", "closeup.md", "texture.md", "batch.md")), found


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_page_blocks_run(page, tmp_path, monkeypatch):
    blocks = python_blocks(page)
    if not blocks:
        pytest.skip(f"{page.name} has no python block")
    monkeypatch.chdir(tmp_path)
    names = reader_names(tmp_path)
    for k, block in enumerate(blocks):
        exec(compile(block, f"{page.name} block {k + 1}", "exec"), names)  # noqa: S102 - the page's own code
    check_promises(page.name, names, tmp_path)


def check_promises(page: str, ns: dict, folder: Path) -> None:
    """What the blocks' comments say holds for the results they made."""
    if page == "README.md":
        assert isinstance(ns["mesh"], trimesh.Trimesh) and len(ns["mesh"].faces) > 0
        assert (folder / "steps.glb").stat().st_size > 0
        assert len(ns["solid"].faces) > len(ns["mesh"].faces)  # skirts and base (watertight: tests/test_stepped.py)
        assert isinstance(ns["tin"], trimesh.Trimesh) and len(ns["tin"].faces) > 0
        z = ns["grid"].vertices[:, 2]
        assert np.isin(np.round(z, 4), [0, 10, 25, 50, 100]).all(), "levels=[...]: heights on the levels"
    if page in ("README.md", "globe.md"):
        full, n = ns["full"], 512  # face_size=513: N = 512 cells (closed, Euler 2: tests/test_globe.py)
        assert len(full.vertices) == 6 * n * n + 2 and len(full.faces) == 12 * n * n
        assert 0 < len(ns["view"].faces) < len(full.faces)
        assert len(ns["local"].faces) > 0
    if page == "closeup.md":
        assert (folder / "closeup.png").stat().st_size > 0 and (folder / "closeup.gif").stat().st_size > 0
    if page == "texture.md":
        assert ns["rgba"].shape[2] == 4
        assert ns["mesh"].visual.kind == "texture"
    if page == "batch.md":
        assert ns["report"].ok and len(ns["report"].done) == 2
        assert sorted(p.name for p in (folder / "out").glob("*.glb")) == ["tile_0.glb", "tile_1.glb"]
        assert ns["steps"].n_cells > 0 and "level" in ns["steps"].cell_data
        assert (folder / "steps.glb").stat().st_size > 0
        assert dict(ns["poly"].user_dict) == ns["mesh"].metadata and "colors_rgba" in ns["poly"].point_data
        assert np.array_equal(ns["back"].visual.vertex_colors, ns["mesh"].visual.vertex_colors)


# ------------------------------------------------------------------------- the examples of `stepterrain COMMAND --help`
def help_examples(epilog: str) -> list[list[str]]:
    """The command lines of an epilog's ``examples:`` section (a trailing backslash continues a line)."""
    import shlex

    lines, pending = [], ""
    for raw in epilog.splitlines():
        text = raw.strip()
        if pending:
            text, pending = pending + " " + text, ""
        elif not text.startswith("stepterrain "):
            continue
        if text.endswith("\\"):
            pending = text[:-1].strip()
            continue
        lines.append(shlex.split(text.split("  (")[0])[1:])  # drop "stepterrain" and a trailing "(remark)"
    return lines


def test_help_examples_parse():
    """Every example line that `--help` shows names options that exist, with values argparse accepts."""
    import argparse

    from stepterrain import cli

    parser = cli.build_parser()
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    checked = 0
    for name, sub in action.choices.items():
        examples = help_examples(sub.epilog or "")
        assert examples, f"stepterrain {name} --help shows no example command lines"
        for argv in examples:
            assert argv[0] == name, f"stepterrain {name} --help shows an example of another command: {argv}"
            try:
                args = parser.parse_args(argv)
            except SystemExit as exc:  # argparse refused it (message on stderr)
                raise AssertionError(f"stepterrain {name} --help example does not parse: {' '.join(argv)}") from exc
            assert args.command == name
            checked += 1
    assert checked >= 20
