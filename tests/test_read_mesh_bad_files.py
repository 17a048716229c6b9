"""read_mesh of small hand-made bad OFF files: each refused as a DataFileError naming the file, the line and what
is wrong (trimesh's reader refused them without a line, with NumPy's or Python's words, or read them without a
word), and a valid one read as before."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain.errors import DataFileError
from stepterrain.export import read_mesh

_HEAD = "OFF\n3 {faces} 0\n0 0 0\n1 0 0\n0 1 0\n"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (_HEAD.format(faces=1) + "3 0 1 3\n", r"line 6, '3 0 1 3', names vertex 3, and the file has 3 vertices"),
        (_HEAD.format(faces=1) + "3 0 1 -1\n", r"line 6, '3 0 1 -1', names vertex -1, and the file has 3"),
        (_HEAD.format(faces=1) + "3 0 1 99999999999999999999\n", r"line 6, .*names vertex 9{20}, and"),
        (_HEAD.format(faces=1) + "3 0 1 2.5\n", r"line 6, '3 0 1 2\.5': a face line needs its count n"),
        (_HEAD.format(faces=2) + "3 0 1 2\n", r"its counts declare 3 vertices and 2 faces, .*4 lines after them: is"),
        (_HEAD.format(faces=2) + "3 0 1 2\n\n# more\n", r"its counts declare 3 vertices and 2 faces, .*4 lines after"),
        ("OFF\n5 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", r"its counts declare 5 vertices and 1 face, .*4 lines"),
        ("OFF\n3 x 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", r"line 2, '3 x 0': expected the counts of vertices and"),
    ],
)
def test_bad_off_refused_by_line(tmp_path, text, expected):
    """A face index past the vertices, negative, overflowing an int64 or no integer, and a file of fewer lines than
    its counts declare (of faces: read as the faces it had, without a word) are refused naming the file and the
    line, not with trimesh's "OFF file has a face index outside the range of its vertices", "invalid literal for
    int()", "Python int too large to convert to C long" or "cannot reshape array of size 12 into shape (5,3)"."""
    (tmp_path / "bad.off").write_text(text)
    with pytest.raises(DataFileError, match=rf"'{tmp_path / 'bad.off'}' as a mesh: ValueError: {expected}"):
        read_mesh(tmp_path / "bad.off")


@pytest.mark.parametrize("text", ["OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
                                  "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 # c\n",
                                  "OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n4 0 1 3 2\n\n"])
def test_valid_off_reads(tmp_path, text):
    """A valid OFF (counts on the keyword's line, a comment after a face, a quad) reads as its faces."""
    (tmp_path / "ok.off").write_text(text)
    mesh = read_mesh(tmp_path / "ok.off")
    assert len(mesh.vertices) == int(text.split()[1 if text.startswith("OFF ") else 1])
    assert np.asarray(mesh.faces).max() < len(mesh.vertices)
