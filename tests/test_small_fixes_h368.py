"""Small fixes (h368): thresholds_of for float64 levels, NumPy scalars in messages, singular counts, an empty path."""

from __future__ import annotations

import numpy as np
import pytest

import stepterrain as st
from stepterrain.stepped import _isovalue_struct


def test_thresholds_of_float64_levels_are_the_thresholds_stepped_uses():
    """``thresholds_of`` averaged a float64 array in float64 as it was, while ``stepped`` takes levels as float32
    first: for levels 0.1 to 0.9 (np.arange(1, 10) / 10) the midpoint of 0.3 and 0.4 came out one float32 step off
    the threshold the kernels step at. Every input must give the kernels' thresholds bit for bit."""
    levels = np.arange(1, 10) / 10.0
    thresholds_of = st.stepped.thresholds_of
    kernels = _isovalue_struct(levels, "cpu").thresholds.numpy()  # what stepped(levels=levels) uploads
    float64_midpoints = ((levels[:-1] + levels[1:]) * 0.5).astype(np.float32)
    assert not np.array_equal(float64_midpoints, kernels)  # the case does round differently
    for given in (levels, list(levels), tuple(levels), levels.astype(np.float32), levels.astype(np.longdouble)):
        got = thresholds_of(given)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got.view(np.uint32), kernels.view(np.uint32))


def test_numpy_scalars_show_as_plain_numbers_in_messages():
    """Sizes and intervals taken from arrays are NumPy scalars: ``{value!r}`` wrote them as ``np.int64(0)`` and
    ``np.float64(-1.0)`` (NumPy 2's repr). Messages show the number; a plain Python value is shown as before."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.texture_lod import pyramid_shapes

    cases = (
        (lambda: pyramid_shapes(np.int64(0), 5), "height must be a whole number of pixels >= 1; got 0"),
        (lambda: pyramid_shapes(np.float64(2.5), 5), "height must be a whole number of pixels >= 1; got 2.5"),
        (lambda: pyramid_shapes(0, 5), "height must be a whole number of pixels >= 1; got 0"),
        (lambda: st.isovalues((0.0, 1.0), interval=np.float64(-1.0)),
         "interval must be a positive finite number; got -1.0"),
        (lambda: st.isovalues((0.0, 1.0), interval=np.float32("nan")),
         "interval must be a positive finite number; got nan"),
    )
    for call, message in cases:
        with pytest.raises(InvalidInputError) as caught:
            call()
        assert str(caught.value) == message
    from stepterrain.errors import plain_repr

    assert plain_repr("2") == "'2'" and plain_repr(np.str_("a")) == repr(np.str_("a")) and plain_repr([1]) == "[1]"


def test_counts_of_one_vertex_are_singular():
    """Messages said "got 1 vertices and no faces" and "of 1 vertices with NaN or inf"."""
    import trimesh

    from stepterrain.errors import InvalidInputError
    from stepterrain.export import scale_for_print

    point = trimesh.Trimesh(vertices=np.zeros((1, 3)), faces=np.zeros((0, 3), dtype=np.int64), process=False)
    with pytest.raises(InvalidInputError, match=r"; got 1 vertex and no faces$"):
        scale_for_print(point, 100.0)
    pair = trimesh.Trimesh(vertices=np.zeros((2, 3)), faces=np.zeros((0, 3), dtype=np.int64), process=False)
    with pytest.raises(InvalidInputError, match=r"; got 2 vertices and no faces$"):
        scale_for_print(pair, 100.0)


def test_an_empty_output_path_is_named_empty(tmp_path, monkeypatch):
    """``Path("")`` is ``Path(".")``: save_mesh(mesh, "") said "cannot write '.'" (a folder no one named)."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.export import save_mesh

    monkeypatch.chdir(tmp_path)
    mesh = st.stepped(np.arange(9.0).reshape(3, 3), interval=1.0)
    with pytest.raises(InvalidInputError) as caught:
        save_mesh(mesh, "")
    assert str(caught.value) == "path is empty (''); expected a file name"
    assert list(tmp_path.iterdir()) == []
