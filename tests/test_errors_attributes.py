"""The attributes stepterrain's errors carry besides their message, declared on their classes.

OutputTooLargeError's ``nbytes`` and ``mesh`` (the memory budget's refusal) and InvalidInputError's ``not_global``
(Globe.from_latlon's refusal of a grid that is no globe) were set on instances ad hoc and read with getattr
defaults: an error raised anywhere else had no such attribute at all. Each is a class attribute with a documented
default now, set by a constructor keyword; messages are unchanged.
"""

from __future__ import annotations

import pickle
import re

import numpy as np
import pytest

import stepterrain as st
from stepterrain._compaction import check_budget
from stepterrain.errors import InvalidInputError, OutputTooLargeError
from stepterrain.globe import Globe


def test_defaults_are_declared_on_the_classes_and_on_every_instance():
    assert OutputTooLargeError.nbytes is None and OutputTooLargeError.mesh is None
    assert InvalidInputError.not_global is False
    too_large, invalid = OutputTooLargeError("faces: too many"), InvalidInputError("x must be positive")
    assert too_large.nbytes is None and too_large.mesh is None and invalid.not_global is False
    assert str(too_large) == "faces: too many" and too_large.args == ("faces: too many",)
    assert str(invalid) == "x must be positive" and invalid.args == ("x must be positive",)
    assert isinstance(too_large, MemoryError) and isinstance(invalid, ValueError)


def test_the_keywords_set_them_and_a_pickle_keeps_them():
    too_large = OutputTooLargeError("m", nbytes=np.int64(12345), mesh=(np.int32(3), 7))
    assert too_large.nbytes == 12345 and type(too_large.nbytes) is int
    assert too_large.mesh == (3, 7) and all(type(k) is int for k in too_large.mesh)
    invalid = InvalidInputError("lon must cover 360 degrees", not_global=True)
    assert invalid.not_global is True and str(invalid) == "lon must cover 360 degrees"
    for error in (too_large, invalid):  # batch hands errors between processes
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error) and copy.args == error.args and vars(copy) == vars(error)


def test_the_budget_refusal_carries_the_bytes_and_the_mesh():
    with pytest.raises(OutputTooLargeError) as refused:
        check_budget(5 * 1024**2, "the stepped mesh", 1024**2, mesh=(100, 200))
    assert refused.value.nbytes == 5 * 1024**2 and refused.value.mesh == (100, 200)
    assert str(refused.value).startswith("the stepped mesh would need 5.0 MiB, over the memory budget of 1.0 MiB; ")
    with pytest.raises(OutputTooLargeError) as refused:  # an output that is no mesh
        check_budget(5 * 1024**2, "the render", 1024**2)
    assert refused.value.nbytes == 5 * 1024**2 and refused.value.mesh is None


def test_stepped_refusal_names_the_mesh_it_counted():
    surface = np.zeros((40, 40)) + np.arange(40)
    mesh = st.stepped(surface, interval=1)
    with pytest.raises(OutputTooLargeError) as refused:
        st.stepped(surface, interval=1, memory_budget=1024)
    error = refused.value
    assert error.mesh == (len(mesh.vertices), len(mesh.faces)), (error.mesh, mesh)
    assert error.nbytes > 1024 and f"({len(mesh.vertices):,} vertices, {len(mesh.faces):,} faces)" in str(error)


def test_the_cli_render_advice_keeps_the_attributes():
    from stepterrain.cli import _render_too

    with pytest.raises(OutputTooLargeError) as refused:
        check_budget(1024**2, "the stepped mesh", 1024, mesh=(70000, 140000))
    with pytest.raises(OutputTooLargeError) as advised:
        _render_too(refused.value, (640, 480))
    assert advised.value is not refused.value and "its --png render, 640x480" in str(advised.value)
    assert advised.value.nbytes == 1024**2 and advised.value.mesh == (70000, 140000)


def test_no_global_grid_refusals_are_marked_and_others_are_not():
    lat, lon = np.linspace(89.5, -89.5, 180), np.linspace(-179.5, 179.5, 360)
    z = np.zeros((180, 360))
    for args, words in (((z[:, :180], lat, lon[:180]), "lon must cover 360"),
                        ((z[:90], lat[:90], lon), "both poles")):
        with pytest.raises(InvalidInputError, match=re.escape(words)) as refused:
            Globe.from_latlon(*args, face_size=9)
        assert refused.value.not_global is True
    with pytest.raises(InvalidInputError, match="lat must be strictly monotone") as refused:
        Globe.from_latlon(z, np.r_[lat[:90], lat[:90]], lon, face_size=9)
    assert refused.value.not_global is False


def test_a_pickle_through_tblib_as_dask_sends_errors_keeps_them():
    """dask.distributed installs tblib's pickling of every exception class (``tblib.pickling_support.install()`` on
    importing distributed.utils), which rebuilt a class with an ``__init__`` of its own by ``__new__`` alone: an
    OutputTooLargeError (a MemoryError) could not be unpickled ("MemoryError.__new__(OutputTooLargeError) is not
    safe"), a batch worker's budget refusal lost. Each class says its own ``__reduce__`` now."""
    pickling_support = pytest.importorskip("tblib.pickling_support")
    errors = (OutputTooLargeError("m", nbytes=5, mesh=(1, 2)), OutputTooLargeError("plain"),
              InvalidInputError("lon must cover 360 degrees", not_global=True), InvalidInputError("x"))
    pickling_support.install(*errors)
    for error in errors:
        try:
            raise error from ValueError("the cause")
        except type(error) as raised:
            copy = pickle.loads(pickle.dumps(raised))
        assert type(copy) is type(error) and copy.args == error.args and vars(copy) == vars(error)
        assert isinstance(copy.__cause__, ValueError) and copy.__traceback__ is not None
