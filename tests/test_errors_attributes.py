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
    assert advised.value.advice is None  # it ends in the bracket: not advised a second time
    assert _render_too(advised.value, (640, 480)) is None


def test_the_budget_refusal_declares_the_advice_its_message_ends_in():
    """The command line's re-advice (a --png render needing more than the mesh) found the figure to replace by
    matching the message's end against a figure of ``nbytes``; the refusal declares it now, as ``advice``."""
    with pytest.raises(OutputTooLargeError) as refused:
        check_budget(5 * 1024**2, "the stepped mesh", 1024**2, mesh=(100, 200))
    assert refused.value.advice == " to at least 5MiB" and str(refused.value).endswith(" to at least 5MiB")
    copy = pickle.loads(pickle.dumps(refused.value))
    assert copy.advice == " to at least 5MiB" and vars(copy) == vars(refused.value)
    with pytest.raises(OutputTooLargeError) as beyond:  # a need past 1024 TiB: no figure advised
        check_budget(2 * 1024**5, "the stepped mesh", 1024**2)
    assert beyond.value.advice is None and beyond.value.nbytes == 2 * 1024**5
    assert OutputTooLargeError.advice is None and OutputTooLargeError("m", nbytes=5).advice is None


def test_the_cli_advises_again_by_the_declared_advice_not_by_the_words():
    """An OutputTooLargeError whose message merely ends in a budget figure of its ``nbytes`` (made elsewhere, not the
    budget's refusal) was rewritten as if it were one; one that declares its advice is rewritten, the rest of its
    message kept."""
    from stepterrain.cli import _render_too

    lookalike = OutputTooLargeError("the cache holds 1 MiB; raise it to at least 1MiB", nbytes=1024**2,
                                    mesh=(70000, 140000))
    assert _render_too(lookalike, (640, 480)) is None  # not the budget's refusal: raised as it is by the caller
    declared = OutputTooLargeError("the stepped mesh is big; say so to at least 1MiB", nbytes=1024**2,
                                   mesh=(70000, 140000), advice=" to at least 1MiB")
    with pytest.raises(OutputTooLargeError) as advised:
        _render_too(declared, (640, 480))
    assert re.fullmatch(r"the stepped mesh is big; say so to at least \d+MiB \(its --png render, 640x480, needs "
                        r"[\d.]+ MiB for a mesh of at least 140,000 faces\)", str(advised.value)), str(advised.value)


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
    errors = (OutputTooLargeError("m to at least 1KiB", nbytes=5, mesh=(1, 2), advice=" to at least 1KiB"),
              OutputTooLargeError("plain"),
              InvalidInputError("lon must cover 360 degrees", not_global=True), InvalidInputError("x"))
    pickling_support.install(*errors)
    for error in errors:
        try:
            raise error from ValueError("the cause")
        except type(error) as raised:
            copy = pickle.loads(pickle.dumps(raised))
        assert type(copy) is type(error) and copy.args == error.args and vars(copy) == vars(error)
        assert isinstance(copy.__cause__, ValueError) and copy.__traceback__ is not None


# ------------------------------------------------------------------ render_mesh's refusal of a mesh under a pixel
def _under_a_pixel_refusals():
    """render_mesh's four refusals of a mesh it would show under a pixel (each before any OpenGL context)."""
    import trimesh

    box = trimesh.creation.box()
    strip = st.stepped(np.stack([np.linspace(0.0, 0.01, 2000)] * 2).astype(np.float32), interval=2.0)
    sliver = trimesh.Trimesh([[0, 0, 0], [1e6, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    return [
        (box, {"camera": [(1e7, 1e7, 1e7), (0, 0, 0), (0, 0, 1)]}, "too small to see"),  # an explicit camera's
        (box, {"bounds": [[-1e5] * 3, [1e5] * 3]}, "too small to see"),  # within bounds far larger than the mesh
        (strip, {"camera": "top", "window_size": (50, 80)}, "too thin to see"),  # a fitted camera's
        (sliver, {}, "too thin to see"),  # slivers covering under a pixel in all
    ]


def test_render_refusals_of_a_mesh_under_a_pixel_are_flagged_and_no_others():
    """overview_image told a contact-sheet item too small or too thin to see in its cell from every other refusal by
    the words "too thin to see" / "too small to see" in render_mesh's message: reworded, each such item would have
    lost the whole sheet. Each of the four refusals carries ``too_small_to_see`` now; every other refusal of a mesh
    that would render blank (bounds missing it, a camera seeing none of it, faces of no area) does not."""
    import trimesh

    from stepterrain.render import render_mesh

    assert InvalidInputError.too_small_to_see is False and InvalidInputError("x").too_small_to_see is False
    for mesh, kwargs, words in _under_a_pixel_refusals():
        with pytest.raises(InvalidInputError, match=words) as refused:
            render_mesh(mesh, **{"window_size": (64, 48), **kwargs})
        assert refused.value.too_small_to_see is True, (words, kwargs)
    box, far = trimesh.creation.box(), trimesh.creation.box()
    far.vertices += [500_000.0, 5_000_000.0, 1_000.0]
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], process=False)
    for mesh, kwargs, words in [(far, {"bounds": [[0, 0, 0], [10, 10, 10]]}, "frame none of the mesh"),
                                (box, {"camera": [(10, 0, 0), (20, 0, 0), (0, 0, 1)]}, "sees none of the mesh"),
                                (flat, {}, "no face of some area")]:
        with pytest.raises(InvalidInputError, match=words) as refused:
            render_mesh(mesh, window_size=(64, 48), **kwargs)
        assert refused.value.too_small_to_see is False, (words, str(refused.value))


def test_the_flag_is_kept_through_a_pickle_and_tblib():
    pickling_support = pytest.importorskip("tblib.pickling_support")
    error = InvalidInputError("the mesh would render 47 x 0.024 pixels", too_small_to_see=True)
    assert error.too_small_to_see is True and error.not_global is False and str(error).startswith("the mesh")
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is InvalidInputError and copy.too_small_to_see is True and vars(copy) == vars(error)
    pickling_support.install(error)
    try:
        raise error from ValueError("the cause")
    except InvalidInputError as raised:
        copy = pickle.loads(pickle.dumps(raised))
    assert copy.too_small_to_see is True and copy.args == error.args and isinstance(copy.__cause__, ValueError)


def test_overview_image_leaves_a_cell_blank_by_the_flag_not_by_the_words(tmp_path, monkeypatch):
    """A contact sheet's item refused as under a pixel in its cell is left blank with a warning; any other refusal
    is raised. Told by ``too_small_to_see``: a flagged refusal worded otherwise was raised (the sheet lost), and an
    unflagged one that happened to say "too small to see" was passed over as a blank cell."""
    import trimesh

    from stepterrain import render
    from stepterrain.batch import BatchReport, ItemResult, overview_image
    from stepterrain.export import save_mesh

    results = []
    for name in ("a", "b"):
        path = save_mesh(trimesh.creation.box(), tmp_path / f"{name}.ply")
        results.append(ItemResult(name, "done", str(path)))
    report = BatchReport(tmp_path, results, kind="file")
    calls, refusal = [], {}

    def render_mesh(mesh, *, window_size, **kwargs):  # item a (each first call) drawn black; item b refused
        calls.append(mesh)
        if len(calls) % 2 == 0:
            raise refusal["b"]
        return np.zeros((window_size[1], window_size[0], 4), np.uint8)

    monkeypatch.setattr(render, "render_mesh", render_mesh)
    refusal["b"] = InvalidInputError("the mesh is a speck in its cell, reworded", too_small_to_see=True)
    with pytest.warns(UserWarning, match=r"^the overview's cell of b\.ply \(50 x 80 pixels\) is left blank: the mesh "
                                         r"is a speck in its cell, reworded$"):
        sheet = overview_image(report, window_size=(100, 80))
    assert (sheet[:, :50] == 0).all() and (sheet[:, 50:] == 255).all()
    refusal["b"] = InvalidInputError("window_size too small to see the point of")  # not flagged: raised
    with pytest.raises(InvalidInputError, match="too small to see the point of"):
        overview_image(report, window_size=(100, 80))
