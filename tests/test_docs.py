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
        assert len(ns["solid"].faces) > len(ns["mesh"].faces)  # skirts and base
        assert ns["solid"].is_watertight, "solid=True: watertight, also where integer heights sit on thresholds"
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

    # drop "stepterrain" and a trailing "(remark)"
    return [shlex.split(text.split("  (")[0])[1:] for text in command_lines(epilog.splitlines())]


def command_lines(raw_lines: list[str]) -> list[str]:
    """The ``stepterrain ...`` lines among ``raw_lines``, stripped, a trailing backslash continuing a line."""
    lines, pending = [], ""
    for raw in raw_lines:
        line = raw.strip()
        if pending:
            line, pending = pending + " " + line, ""
        elif not line.startswith("stepterrain "):
            continue
        if line.endswith("\\"):
            pending = line[:-1].strip()
            continue
        lines.append(line)
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


def test_help_examples_write_no_file_they_read():
    """No example line of `--help` names one file as an input and an output: the CLI refuses that (the write would
    replace the input), so such an example fails as shown (texture's --texel-size example read --image ortho.tif and
    wrote -o ortho.tif)."""
    import argparse

    from stepterrain import cli

    parser = cli.build_parser()
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for sub in action.choices.values():
        for argv in help_examples(sub.epilog or ""):
            args = vars(parser.parse_args(argv))
            inputs = args.get("input") if isinstance(args.get("input"), list) else [args.get("input")]
            read = {Path(p) for p in [*inputs, args.get("image"), args.get("texture")] if p is not None}
            written = {Path(args[key]) for key in ("output", "mesh", "png", "gif", "normals") if args.get(key)}
            both = sorted(map(str, read & written))
            assert not both, f"stepterrain {' '.join(argv)}: writes {both}, which it reads"


# ------------------------------------------------------------- docs/batch.md's table of what each mesh format keeps
def format_table() -> dict[str, dict[str, str]]:
    """docs/batch.md's table, {extension: {column: cell}}, a row naming several extensions under each."""
    lines = (ROOT / "docs" / "batch.md").read_text(encoding="utf-8").splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith("| format | coordinates"))
    columns = [c.strip() for c in lines[start].strip("|").split("|")]
    table = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = dict(zip(columns, (c.strip() for c in line.strip("|").split("|")), strict=True))
        for ext in re.findall(r"`(\.\w+)`", cells["format"]):
            table[ext] = cells
    return table


def test_the_format_table_holds_on_round_trips(tmp_path):
    """Each row's cells, read as claims (exact float64, float32, PLY's float32 only where exact, RGBA or RGB, a
    texture's image, UVs and sampler, `level`/`wall` kept or dropped, metadata kept or dropped), hold for a stepped
    solid at UTM-sized coordinates saved by save_mesh and read back by read_mesh."""
    import warnings

    from stepterrain.export import read_mesh, save_mesh, texture_wrap
    from stepterrain.texture import drape, topographic_layer

    table = format_table()
    assert sorted(table) == [".3mf", ".glb", ".gltf", ".obj", ".ply", ".stl"], sorted(table)
    h = np.asarray(st.sample_dem().heights[:12, :16], np.float64)
    dem = st.Terrain.from_heights(h, spacing=(30.0, -30.0), origin=(60000.123, 3798000.7))
    mesh = st.stepped(dem, interval=50.0, colors="terrain", solid=True, device="cpu")
    mesh.visual.vertex_colors[:, 3] = 200  # an alpha to keep or drop
    textured = drape(st.stepped(dem, interval=50.0, device="cpu"), topographic_layer(dem, device="cpu"))
    for ext, row in table.items():
        path = tmp_path / f"m{ext}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # .stl's float32 warning (its cell says so)
            save_mesh(mesh, path)
        back = read_mesh(path)
        coords = row["coordinates"]
        if coords.startswith("float64"):
            assert np.array_equal(back.vertices, mesh.vertices), f"{ext}: coordinates are not kept exactly"
        elif "three points per face" in coords:
            assert coords.startswith("float32") and "two on one float32 position left out" in coords
            for solid in (mesh, st.stepped(dem, interval=50.0, gamma=0.0, solid=True, device="cpu")):  # flat walls
                if solid is not mesh:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        save_mesh(solid, path)
                want = solid.triangles.astype(np.float32)
                point = np.zeros(len(want), bool)
                for i, j in ((0, 1), (1, 2), (2, 0)):
                    point |= (want[:, i] == want[:, j]).all(axis=1)
                assert point.any() == (solid is not mesh)
                got = read_mesh(path).triangles
                assert np.array_equal(got, want[~point].astype(np.float64)), f"{ext}: not float32 of each point"
        else:
            assert coords.startswith("float32")
            gap = np.abs(back.vertices - mesh.vertices).max()
            assert 0 <= gap <= np.spacing(np.float32(np.ptp(mesh.vertices, axis=0).max())), (ext, gap)
        if ext == ".3mf":  # "in the unit its metadata's `units` names (...), else declared millimetres"
            import re
            import zipfile

            assert "in the unit its metadata's `units` names" in coords and "else declared millimetres" in coords
            assert "else metres for a mesh stepterrain made" in coords
            foreign = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)  # no metadata: a foreign mesh's
            for units, unit, what in ((None, "meter", mesh), ("meters", "meter", mesh),
                                      ("millimeters", "millimeter", mesh), (None, "millimeter", foreign),
                                      ("meters", "meter", foreign)):
                copy = what.copy()
                copy.metadata.pop("units", None)
                if units is not None:
                    copy.metadata["units"] = units
                save_mesh(copy, path)
                with zipfile.ZipFile(path) as archive:
                    model = archive.read(next(n for n in archive.namelist() if n.endswith(".model")))
                assert re.search(rb'<model unit="([a-z]+)"', model)[1] == unit.encode(), (units, model[:120])
        if ext == ".ply":
            header = path.read_bytes().split(b"end_header")[0]
            assert b"property double x" in header  # float64 where float32 would round 60000.123
            small = tmp_path / "small.ply"  # "float32 where that holds every vertex exactly"
            save_mesh(st.stepped(np.array([[0.0, 1, 2], [1, 2, 3], [2, 3, 4]]), interval=1.0, base=0.5, device="cpu"),
                      small)
            assert b"property float x" in small.read_bytes().split(b"end_header")[0]
        colours = row["vertex colours"]
        if colours == "dropped":
            assert back.visual.kind is None, ext
        else:
            rgb = back.visual.vertex_colors
            assert np.array_equal(rgb[:, :3], mesh.visual.vertex_colors[:, :3]), f"{ext}: colours not kept"
            want_alpha = 255 if "no alpha" in colours else 200
            assert (rgb[:, 3] == want_alpha).all(), (ext, colours, np.unique(rgb[:, 3]))
        attributes = row["`level`, `wall`, other attributes"]
        if attributes.startswith("kept"):
            assert back.face_attributes["wall"].dtype == bool
            assert np.array_equal(back.face_attributes["wall"], mesh.face_attributes["wall"])
            assert np.array_equal(back.face_attributes["level"], mesh.face_attributes["level"])
        else:
            assert attributes == "dropped" and not {"level", "wall"} & set(back.face_attributes), ext
        if row["metadata"] == "dropped":
            assert "isovalues" not in back.metadata, ext
        else:
            assert list(back.metadata["isovalues"]) == list(mesh.metadata["isovalues"]), ext
        texture = row["texture"]
        if texture == "dropped":
            continue
        path = tmp_path / f"t{ext}"
        save_mesh(textured, path)
        back = read_mesh(path)
        assert "image and UVs" in texture and back.visual.kind == "texture", ext
        assert np.allclose(back.visual.uv, textured.visual.uv, atol=1e-6), ext
        wrap = texture_wrap(back.visual.material)
        if "sampler" in texture:
            assert wrap == ("CLAMP_TO_EDGE", "CLAMP_TO_EDGE"), (ext, wrap)  # drape's sampler, read back
        else:
            assert wrap is None, (ext, wrap)


# --------------------------------------------------------- the command lines of the README's and docs' ```bash blocks
BASH_BLOCK = re.compile(r"^```bash\n(.*?)^```", re.S | re.M)


def page_command_lines(text: str) -> list[str]:
    """The ``stepterrain ...`` lines of a page's ```bash blocks, a trailing backslash continuing a line and a trailing
    ``# comment`` dropped."""
    return [
        re.split(r"\s+#", line)[0] for block in BASH_BLOCK.findall(text) for line in command_lines(block.splitlines())
    ]


def command_line_problems(line: str, parser) -> list[str]:
    """What is wrong with one page command line: an option its subcommand lacks (also in a synopsis line with
    ``[...]`` and ``a|b``), or, for a runnable line (no brackets), arguments argparse refuses."""
    import argparse
    import contextlib
    import io
    import shlex

    from stepterrain.cli import _UsageError

    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    words = shlex.split(line)
    command = words[1]
    if command not in action.choices:
        return [f"no subcommand {command!r}"]
    known = {o for a in (*parser._actions, *action.choices[command]._actions) for o in a.option_strings}
    problems = [f"{command} has no option {o}" for o in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", line)
                if o not in known]
    if "[" not in line:
        try:
            with contextlib.redirect_stderr(io.StringIO()):
                parser.parse_args(words[1:])
        except (SystemExit, _UsageError):  # argparse's refusals, and the CLI's for values argparse cannot check
            problems.append("argparse refuses it")
    return problems


def test_page_command_lines_name_options_that_exist():
    """Every ``stepterrain`` line of the README's and docs' ```bash blocks (the README's synopsis of each command
    included) names options its subcommand has, and every runnable one parses: a renamed or removed option shows
    here, not only to a reader whose copied line fails."""
    from stepterrain import cli

    parser = cli.build_parser()
    assert command_line_problems("stepterrain steps --intervall 50 -o a.glb", parser) == [
        "steps has no option --intervall", "argparse refuses it"]  # the check itself sees a wrong option
    checked = 0
    for page in PAGES:
        for line in page_command_lines(page.read_text(encoding="utf-8")):
            assert not command_line_problems(line, parser), (page.name, line, command_line_problems(line, parser))
            checked += 1
    assert checked >= 20, checked


# ------------------------------------------------------ "`--option ...` (steps, closeup, ...)": the subcommands named
SUBCOMMANDS = "steps|globe|closeup|texture|batch|info"
OPTION_COMMANDS = re.compile(rf"`(--[a-z][a-z0-9-]*)[^`]*`\s+\(((?:{SUBCOMMANDS})(?:,\s+(?:and\s+)?(?:{SUBCOMMANDS}))*)"
                             r"[;:)]")


def option_command_lists(text: str) -> list[tuple[str, list[str]]]:
    """The pages' ``--option ...`` followed by a parenthesised list of the subcommands that take it."""
    return [(m.group(1), re.split(r",\s+(?:and\s+)?", m.group(2))) for m in OPTION_COMMANDS.finditer(text)]


def test_the_subcommands_a_page_lists_for_an_option_are_those_that_take_it():
    """Where the README or a docs page lists the subcommands that take an option (```--band N`` (steps, closeup,
    texture, info, batch)``), the list is the parser's exactly: an option added to or removed from a subcommand
    shows here, not only to a reader who tries it."""
    import argparse

    from stepterrain import cli

    parser = cli.build_parser()
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert option_command_lists("the CLI's `--crop a,b` and `--coarsen N`\n(steps, info) do it") == [
        ("--coarsen", ["steps", "info"])]
    checked = 0
    for page in PAGES:
        for option, listed in option_command_lists(page.read_text(encoding="utf-8")):
            taking = {name for name, sub in action.choices.items()
                      if any(option in a.option_strings for a in sub._actions)}
            assert sorted(listed) == sorted(taking), (page.name, option, listed, sorted(taking))
            checked += 1
    assert checked >= 5, checked


# ---------------------------------------------------- the library names the pages give (``st.export.read_mesh``)
def page_names(text: str) -> list[str]:
    """The dotted ``st.X.Y`` / ``stepterrain.X.Y`` names in a page's inline code and code blocks, and the
    ``from stepterrain.X import a, b`` names, as ``stepterrain.X.a``."""
    code = re.findall(r"`([^`\n]+)`", text) + re.findall(r"^```\w*\n(.*?)^```", text, re.S | re.M)
    # not a path's or file name's ``out/st.tif``, ``my-stepterrain.toml``
    names = [m.group(1) for c in code
             for m in re.finditer(r"(?<![\w./\\-])(?:st|stepterrain)((?:\.[A-Za-z_]\w*)+)(?![\w/\\-])", c)]
    for module, imported in re.findall(r"from stepterrain((?:\.\w+)*) import ([\w, ]+)", text):
        names += [f"{module}.{n.split(' as ')[0].strip()}" for n in imported.split(",") if n.strip()]
    return ["stepterrain" + n for n in names]


def resolves(dotted: str) -> bool:
    import importlib

    obj, parts = st, dotted.split(".")[1:]
    for k, part in enumerate(parts):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            try:
                obj = importlib.import_module(".".join(["stepterrain", *parts[: k + 1]]))
            except ImportError:
                return False
    return True


def test_the_library_names_the_pages_give_exist():
    """Every ``st.…``/``stepterrain.…`` name of the README's and docs' prose and blocks, and every name they import
    from stepterrain, exists: a renamed or moved function shows here, not only to a reader whose copied call fails
    (the python blocks run in test_page_blocks_run; the names in the prose run nowhere)."""
    assert not resolves("stepterrain.export.read_meshes") and resolves("stepterrain.export.read_mesh")
    assert page_names("`st.io.COMMON_NODATA` and\nfrom stepterrain.batch import load_series, batch") == [
        "stepterrain.io.COMMON_NODATA", "stepterrain.batch.load_series", "stepterrain.batch.batch"]
    assert page_names("`out/st.tif`, `st.tif` and\nfrom stepterrain.texture import hillshade as hs, relight") == [
        "stepterrain.tif", "stepterrain.texture.hillshade", "stepterrain.texture.relight"]
    checked = 0
    for page in PAGES:
        for name in page_names(page.read_text(encoding="utf-8")):
            assert resolves(name), (page.name, name)
            checked += 1
    assert checked >= 80, checked
