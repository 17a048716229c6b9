"""read_mesh's preparation of an OBJ's lines against an independent line-by-line reader: relative (negative) indices
of faces, and of ``l`` and ``p`` lines, which are not read; relative indices of more than 18 digits; the tidying of
tabs, indents and trailing comments in blocks of lines; the search for a line starting with a letter."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stepterrain import export
from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh

from .conftest import python_calls, traced_peak

_NUMBERS = (b"v", b"vt", b"vn", b"vp", b"f", b"l", b"p", b"s")


def _reference(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The vertices (one per ``v`` line) and triangles of the OBJ text ``data``, by a Python loop over its lines: a
    UTF-8 byte-order mark dropped, lines ended by CR, LF or CRLF, words separated by spaces and tabs, a comment after
    a statement of numbers dropped; a face's negative index counts back from the ``v`` lines before it (the OBJ
    specification); a quad split (a, b, c), (c, d, a), a larger polygon as a fan from its first corner; ``l`` and
    ``p`` lines not read."""
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    for raw in data.removeprefix(b"\xef\xbb\xbf").splitlines():
        words = raw.split()
        if words and words[0] in _NUMBERS:
            words = raw.split(b"#", 1)[0].split()
        if not words:
            continue
        if words[0] == b"v":
            vertices.append([float(word) for word in words[1:4]])
        elif words[0] == b"f":
            corners = []
            for word in words[1:]:
                index = int(word.split(b"/")[0])
                corners.append(index - 1 if index > 0 else len(vertices) + index)
            if len(corners) == 4:
                faces += [corners[:3], [corners[2], corners[3], corners[0]]]
            else:
                faces += [[corners[0], corners[k], corners[k + 1]] for k in range(1, len(corners) - 1)]
    return np.asarray(vertices, dtype=np.float64).reshape(-1, 3), np.asarray(faces, dtype=np.int64).reshape(-1, 3)


def _triangles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The triangles' corner positions, sorted by row (an order-free comparison of meshes)."""
    corners = np.asarray(vertices, dtype=np.float64)[np.asarray(faces, dtype=np.int64)].reshape(-1, 9)
    return corners[np.lexsort(corners.T[::-1])] if len(corners) else corners


@st.composite
def _obj_files(draw: st.DrawFn) -> tuple[bytes, str]:
    """A random OBJ text and its faces' form: objects of ``v`` (``vt``, ``vn``) lines and faces naming them by
    positive and negative indices, ``g``, ``usemtl``, ``l`` and ``p`` lines of either sign, comments, tabs, indents,
    and CR, LF or CRLF line ends (each line its own)."""
    form = draw(st.sampled_from(["v", "v/vt", "v//vn", "v/vt/vn"]))
    seen = {"v": 0, "vt": 0, "vn": 0}
    lines: list[str] = []
    for _ in range(draw(st.integers(1, 5))):  # objects: vertices, then statements naming them
        for _ in range(draw(st.integers(1, 5))):
            seen["v"] += 1
            lines.append(f"v {seen['v']} {seen['v'] % 7}.5 {len(lines)}.25")
            for kind, text in (("vt", "vt 0.5 0.25"), ("vn", "vn 0 0 1")):
                if kind in form:
                    seen[kind] += 1
                    lines.append(text)

        def index(kind: str) -> str:
            k = draw(st.integers(1, seen[kind]))
            return str(k) if draw(st.booleans()) else str(k - seen[kind] - 1)

        for _ in range(draw(st.integers(0, 4))):
            statement = draw(st.sampled_from(["f", "f", "f", "l", "p", "g", "usemtl", "#", "s"]))
            if statement == "f":
                corners = []
                for _ in range(draw(st.integers(3, 5))):
                    fields = [index("v"), index("vt") if "vt" in form else "", index("vn") if "vn" in form else ""]
                    corners.append("/".join(fields[: 3 if "vn" in form else 2 if "vt" in form else 1]))
                lines.append("f " + " ".join(corners))
            elif statement in ("l", "p"):
                lines.append(statement + " " + " ".join(index("v") for _ in range(draw(st.integers(1, 4)))))
            elif statement in ("g", "usemtl"):
                lines.append(f"{statement} part{draw(st.integers(0, 2))}")
            elif statement == "#":
                lines.append("# a comment of f -1 v 2")
            else:
                lines.append("s off")
    if draw(st.booleans()):  # tidying: tabs, indents, a comment after numbers
        lines = [draw(st.sampled_from(["", " ", "\t", "  "])) + line.replace(" ", draw(st.sampled_from([" ", "\t"])))
                 + draw(st.sampled_from(["", " ", " # x", "\t#y"])) * (line.split(" ")[0] in ("v", "f", "l", "p"))
                 for line in lines]
    ends = [draw(st.sampled_from(["\n", "\r\n", "\r"])) if draw(st.booleans()) else "\n" for _ in lines]
    text = "".join(line + end for line, end in zip(lines, ends, strict=True))
    return (b"\xef\xbb\xbf" if draw(st.booleans()) else b"") + text.encode(), form


@given(_obj_files())
def test_random_obj_reads_as_the_reference_reader(tmp_path_factory, drawn):
    """Random OBJ files of positive and negative indices (v, v/vt, v//vn, v/vt/vn), ``g``, ``usemtl``, ``l`` and
    ``p`` lines, comments, tabs, indents, a byte-order mark and CR, LF and CRLF line ends read as a line-by-line
    reference reads them: every ``v`` line's vertex in order and the faces exactly where faces name vertex indices
    only, the same triangles (by corner positions) where they name UVs or normals (trimesh's reader makes a vertex
    per distinct corner there)."""
    data, form = drawn
    path = tmp_path_factory.mktemp("obj") / "random.obj"
    path.write_bytes(data)
    mesh = read_mesh(path)
    vertices, faces = _reference(data)
    if form == "v":
        np.testing.assert_array_equal(mesh.vertices, vertices)
        np.testing.assert_array_equal(mesh.faces, faces)
    else:
        np.testing.assert_array_equal(_triangles(mesh.vertices, mesh.faces), _triangles(vertices, faces))


@pytest.mark.parametrize("statement", ["l", "p"])
def test_obj_line_and_point_statements_of_relative_indices_are_not_read(tmp_path, statement):
    """``l`` (polyline) and ``p`` (point) statements are not read, whatever the sign of their indices (trimesh's
    reader skips them; a negative index there would count back from the ``v`` lines before it): the mesh reads as the
    file without them, every ``v`` line a vertex, a face's negative indices after them counted as the reference
    counts them, and one counting back past the file's start (``l -9``) is not refused."""
    body = "v 0 0 0\nv 1 0 0\nv 0 1 0\n{s} -3 -2 -1\n{s} -9\nf -3 -2 -1\nv 1 1 0\n{s} -1 2\nf -1 -2 -3\n"
    with_them = body.format(s=statement)
    without = "".join(line + "\n" for line in with_them.splitlines() if not line.startswith(statement))
    (tmp_path / "with.obj").write_text(with_them)
    (tmp_path / "without.obj").write_text(without)
    mesh, plain = read_mesh(tmp_path / "with.obj"), read_mesh(tmp_path / "without.obj")
    vertices, faces = _reference(with_them.encode())
    assert faces.tolist() == [[0, 1, 2], [3, 2, 1]]  # the reference itself
    for read in (mesh, plain):
        np.testing.assert_array_equal(read.vertices, vertices)
        np.testing.assert_array_equal(read.faces, faces)


@pytest.mark.parametrize("zeros", [17, 18, 19, 25, 45])
def test_obj_relative_index_of_leading_zeros_counts_back_from_the_face(tmp_path, zeros):
    """A relative index written with leading zeros (``-0003``) counts back from the ``v`` lines before its face,
    however many digits it has: one of more than 18 was left as written, and trimesh's reader counted it back from
    the file's end (``f -000...003 -2 -1`` before a fourth ``v`` read as [1, 1, 2])."""
    index = "-" + "0" * zeros + "3"
    data = f"v 0 0 0\nv 1 0 0\nv 0 1 0\nf {index} -2 -1\nv 1 1 0\nf -1 -2 {index}\n"
    (tmp_path / "zeros.obj").write_text(data)
    mesh = read_mesh(tmp_path / "zeros.obj")
    vertices, faces = _reference(data.encode())
    assert faces.tolist() == [[0, 1, 2], [3, 2, 1]]
    np.testing.assert_array_equal(mesh.vertices, vertices)
    np.testing.assert_array_equal(mesh.faces, faces)


@pytest.mark.parametrize("after", ["v 1 1 0\n", ""])
@pytest.mark.parametrize("index", ["-9999999999999999999", "-" + "9" * 30, "-" + "1" * 60, "-4"])
def test_obj_relative_index_past_the_start_refused_by_line(tmp_path, index, after):
    """A relative index counting back past the file's start is refused naming its line and index, of any number of
    digits, whether ``v`` lines follow the face or not: of more than 18 digits it was left as written, and trimesh's
    reader refused it as "index 9223372036854775806 is out of bounds" (an int64's overflow), naming no line; without
    ``v`` lines after its face ``-4`` was refused as "index -4 is out of bounds"."""
    data = f"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf {index} -2 -1\n{after}"
    (tmp_path / "past.obj").write_text(data)
    shown = index if len(index) <= 40 else index[:40]
    with pytest.raises(DataFileError, match=rf"line 5, 'f {index} -2 -1', names v {shown}.*3 v lines come before it"):
        read_mesh(tmp_path / "past.obj")


def _tidy_reference(data: bytes, comments: bool) -> bytes:
    """The OBJ text ``data`` tidied line by line, as :func:`_obj_tidied` tidied it before it was done in blocks."""

    def tidy(line: bytes) -> bytes:
        line = line.strip(b" \t").replace(b"\t", b" ")
        if comments and line.split(b" ", 1)[0] in _NUMBERS:
            line = line.split(b"#", 1)[0].rstrip(b" ")
        return line

    return b"\n".join(tidy(line) for line in data.splitlines()) + b"\n"


_PIECES = [b"v", b"vt", b"vn", b"f", b"s", b"l", b"g", b"usemtl", b" ", b" ", b"\t", b"#", b"1", b"-2", b"/", b"\r",
           b"\n", b"\r\n", b"x", b"\x0b", b"\x0c", b"off"]


@given(st.lists(st.sampled_from(_PIECES), min_size=1, max_size=30), st.booleans())
def test_obj_tidied_block_as_lines_tidied_one_by_one(pieces, comments):
    """A block of lines is tidied by NumPy over its bytes as the line-by-line reference tidies it: lines ended by
    CR, LF or CRLF, tabs made spaces, blanks around lines dropped, a comment after a statement of numbers dropped."""
    data = b"".join(pieces)
    assert export._obj_tidied_block(data, comments) == _tidy_reference(data, comments)


@pytest.mark.parametrize("block", [1, 7, 1 << 20])
def test_obj_tidied_in_blocks_of_lines(tmp_path, monkeypatch, block):
    """An OBJ that needs tidying is tidied in blocks of whole lines (its text as a list of lines took 9 times its
    size: 354 MB for 40 MB), as the reference tidies it, and 8 MB tidied within 3 times its size (the text tidied,
    and its blocks), and read as the reference reads it."""
    monkeypatch.setattr(export, "_OBJ_INDEX_BLOCK", block)
    rng = np.random.default_rng(5)
    lines = [b"v 1 2 3", b"\tv 1\t2 3 # c", b"  f 1 2 3", b"f\t1 2 3 #", b"usemtl a#1", b"# f 1 2", b"", b" \t "]
    path = tmp_path / "tidy.obj"
    for _ in range(30):
        ends = [[b"\n", b"\r\n"][k] for k in rng.integers(0, 2, 30)]
        data = b"".join(lines[k] + end for k, end in zip(rng.integers(0, len(lines), 30), ends, strict=True))
        path.write_bytes(data + b"\tv 0 0 0")
        assert export._obj_tidied(path) == _tidy_reference(data + b"\tv 0 0 0", True)
    if block == 1 << 20:
        data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n" + b"\tv\t0.125 1.5 2.25\n v 1 0.5 2\n v 0 1 3\nf 3 1 2 # a\n" * (
            8_000_000 // 59)
        path.write_bytes(data)
        peak = traced_peak(export._obj_tidied, path, None)
        assert peak < 3 * len(data), (peak, len(data))
        vertices, faces = _reference(data)
        mesh = read_mesh(path)
        np.testing.assert_array_equal(mesh.faces, faces)
        np.testing.assert_array_equal(mesh.vertices, vertices)


def test_obj_line_starting_passes_over_a_bounded_number_of_letters():
    """The first line starting with a letter is found with a bounded number of calls, however many of the letter
    come first elsewhere in lines (a Python step each: 1.1 s of a 58 MB file of a comment line before each vertex),
    where a line-by-line reference finds it, or -1."""
    for count in (0, 1, 63, 64, 65, 5000):
        data = b"# of faces\nv 0 0 0\n" * count + b" f\nvf\nf 1 2 3\nf 1 1 1\n"
        expected = next(at for at in range(len(data)) if data[at : at + 1] == b"f" and (at == 0 or data[at - 1] == 10))
        assert export._obj_line_starting(data, b"f") == expected
        assert export._obj_line_starting(data, b"f", expected + 1) == data.rindex(b"\nf") + 1
        assert export._obj_line_starting(data, b"x") == -1
        assert export._obj_line_starting(data, b"o") == -1
    assert export._obj_line_starting(b"f 1 2 3\n", b"f") == 0
    assert export._obj_line_starting(b"if\nff", b"f", 1) == 3
    few = python_calls(export._obj_line_starting, b"# of faces\n" * 10 + b"f 1 2 3\n", b"f")
    many = python_calls(export._obj_line_starting, b"# of faces\n" * 10_000 + b"f 1 2 3\n", b"f")
    assert many < few + 80, (few, many)


def _trailing_comment_reference(data: bytes) -> bool:
    """Whether a line of the OBJ text ``data`` (lines ended by LF, CR or CRLF) holds a ``#`` after a statement of
    numbers: its words before the ``#`` (split at spaces and tabs) are a keyword of numbers and more."""
    for line in data.replace(b"\r", b"\n").split(b"\n"):
        if b"#" in line:
            words = line.split(b"#", 1)[0].replace(b"\t", b" ").lstrip(b" ").split(b" ")
            if len(words) > 1 and words[0] in _NUMBERS:
                return True
    return False


@given(st.lists(st.sampled_from([*_PIECES, b"vp", b"p", b"o"]), min_size=1, max_size=30))
def test_obj_trailing_comment_found_as_line_by_line(pieces):
    """A comment after a statement of numbers is found by NumPy over blocks of lines (of 1 byte and more, 5 and
    more, 1 MB) as a line-by-line reference finds it (the ``#`` of a plain comment line, or of a name, is none)."""
    data = b"".join(pieces)
    for block in (1, 5, 1 << 20):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(export, "_OBJ_INDEX_BLOCK", block)
            assert export._obj_trailing_comment(data) == _trailing_comment_reference(data), block


def test_obj_trailing_comment_search_not_a_step_per_comment_line():
    """The search for a comment after numbers takes as many calls for 5,000 comment lines as for 50 (a Python step
    per ``#`` took 4.6 s of a 58 MB file of a comment line before each vertex), and finds one after them."""
    def text(count: int) -> bytes:
        return b"# a vertex\nv 0 0 0\n" * count + b"f 1 1 1 # x\n"

    assert export._obj_trailing_comment(text(5000))
    assert not export._obj_trailing_comment(text(5000)[:-4] + b"\n")
    few, many = python_calls(export._obj_trailing_comment, text(50)), python_calls(export._obj_trailing_comment,
                                                                                   text(5000))
    assert many < few + 50, (few, many)


@pytest.mark.parametrize(
    ("face", "shown", "kind", "count"),
    [
        ("f 1 2 7", "7", "v", 3),
        ("f 1 2 4", "4", "v", 3),
        ("f 1 2 99999999999999999999", "99999999999999999999", "v", 3),
        ("f 1 2 " + "9" * 60, "9" * 40 + r"\.\.\.", "v", 3),
        ("f 1/1 2/1 9/1", "9", "v", 3),
        ("f\t1  2 +8   # past", r"\+8", "v", 3),
    ],
)
@pytest.mark.parametrize("layout", ["plain", "crlf", "materials", "after", "blocks"])
def test_obj_index_past_the_end_refused_by_line(tmp_path, monkeypatch, face, shown, kind, count, layout):
    """A face's positive index past the file's ``v`` lines (of any number of digits) is refused naming its line as
    the file writes it, the index and how many ``v`` lines the file has: trimesh's reader refused it as "index 6 is
    out of bounds for axis 0 with size 3" (or, of more than 18 digits, "index 9223372036854775806 ..."), naming no
    line; so for a file of CRLF line ends, of several materials (read by stepterrain's own joiner), of ``v`` lines
    after its faces (its relative indices made absolute before trimesh's reader), and read in blocks of lines."""
    lines = ["v 0 0 0", "v 1 0 0", "v 0 1 0", "vt 0 0", "f 1 2 3", face]
    if layout == "blocks":  # lines counted and searched in blocks of a line or two
        monkeypatch.setattr(export, "_OBJ_INDEX_BLOCK", 4)
    if layout == "materials":
        lines[4:4] = ["usemtl a"]
        lines[-1:-1] = ["usemtl b"]
    if layout == "after":
        lines[4] = "f -3 -2 -1"
        lines.append("v 1 1 1")
        count += 1
    number = lines.index(face) + 1
    end = "\r\n" if layout == "crlf" else "\n"
    (tmp_path / "past.obj").write_bytes((end.join(lines) + end).encode())
    if layout == "after" and shown == "4":  # the v line after the faces is the 4th: named, read
        assert read_mesh(tmp_path / "past.obj").faces.tolist() == [[0, 1, 2], [0, 1, 3]]
        return
    written = re.escape(repr(face.strip())[1:-1]) if len(face) < 40 else re.escape(face[:20]) + ".*"
    with pytest.raises(DataFileError, match=rf"line {number}, '{written}', names {kind} {shown}, and the file has "
                                            rf"{count} {kind} lines"):
        read_mesh(tmp_path / "past.obj")


def test_obj_index_within_reads():
    """The check of indices past the end finds nothing in a face whose indices are all within the file's lines,
    of every slot, nor in fields that are no integer (trimesh's error then stands)."""
    counts = {b"v": 3, b"vt": 1, b"vn": 2}
    assert export._obj_face_past_end(b"f 1/1/2 2//1 3/1/1 -1 x 2.5", counts) is None
    assert export._obj_face_past_end(b"f 1/2/1 2 3", counts) == (b"vt", "2")
    assert export._obj_face_past_end(b"f 1//1 2//3 3//1", counts) == (b"vn", "3")
