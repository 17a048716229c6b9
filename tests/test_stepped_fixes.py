"""Bugs found by an adversarial hunt over the stepped-terrain path (issue 2), one test each."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st_
from stepterrain.kernels import stepped as stepped_kernels

import stepterrain as st
from stepterrain._device import launch_chunked, resolve_device
from stepterrain.stepped import step_arrays, thresholds_of
from stepterrain.terrain import as_terrain

from .conftest import assert_valid_mesh
from .test_stepped import compare_with_reference, projected_area

stepped_module = st.stepped  # the module, callable as its function stepped


def test_isovalue_memo_is_built_from_the_float32_values_it_is_keyed_by():
    """The isovalue memo was keyed by the float32 bytes of the values but built from the values as given: float64
    levels (step_arrays given them, as the benchmarks and tests call it) put thresholds rounded from their float64
    midpoints into the memo, and every later call with the same float32 values (stepped(levels=...)) got them.
    (64.7 + 67.1) / 2 rounds to 65.9 in float32 from float64, to 65.899994 from the float32 levels: a height of
    65.899994 sits on the threshold (upper level) in the reference and fell below it. Found by stepping levels given
    once as float64 and once as float32, as the brief's "levels equal as values but different dtype" asked."""
    levels64 = np.array([64.7, 67.1])
    on = np.float32(65.899994)
    assert np.float32((levels64[0] + levels64[1]) / 2) != on  # the two roundings differ
    heights = np.array([[64.0, on, 68.0], [on, 68.0, on], [64.0, on, 64.0]], np.float32)
    stepped_module._ISOVALUES.clear()
    step_arrays(as_terrain(heights), levels64, device=resolve_device("cpu"))  # float64 values first
    compare_with_reference(heights, levels64.astype(np.float32), "cpu")
    fresh = stepped_module._build_isovalue_struct(levels64.astype(np.float32), resolve_device("cpu"))
    stepped_module._ISOVALUES.clear()
    mesh = st.stepped(heights, levels=levels64)
    assert fresh.thresholds.numpy()[0] == on
    stepped_module._ISOVALUES.clear()
    step_arrays(as_terrain(heights), levels64, device=resolve_device("cpu"))
    again = st.stepped(heights, levels=levels64)
    np.testing.assert_array_equal(again.vertices, mesh.vertices)
    np.testing.assert_array_equal(again.faces, mesh.faces)


def test_uniform_isovalues_memo_hands_out_copies_and_keeps_refusals():
    """isovalues(interval=...) keeps its results by (lo, hi, interval, base) bits (a re-step going back and forth
    between intervals): every call gets its own array, equal to a fresh computation (writing to one changed the next
    call's isovalues when the memo handed out its own), and a refusal is refused again."""
    stepped_module._UNIFORM.clear()
    first = st.isovalues((3.0, 21.0), interval=10.0)
    first[:] = -1.0
    again = st.isovalues((3.0, 21.0), interval=10.0)
    assert again.dtype == np.float32 and again.tolist() == [0.0, 10.0, 20.0, 30.0]
    again[0] = 5.0
    assert st.isovalues((3.0, 21.0), interval=10.0).tolist() == [0.0, 10.0, 20.0, 30.0]
    for _ in range(2):
        with pytest.raises(st.InvalidInputError, match="too small"):
            st.isovalues((1e7, 1e7 + 4), interval=0.5)


@pytest.mark.parametrize("bad", [np.inf, -np.inf, 1e300], ids=["inf", "-inf", "beyond-float32"])
def test_series_stack_refuses_a_bad_frame_before_the_first_frame(bad):
    """stepped_series' docstring: a frame with bad heights is refused naming frames[k], for a (T, H, W) stack
    before the first frame. An infinite height in frames[2] was refused only after frames 0 and 1 had been
    yielded (a caller writing each frame got two files and then the error), and a float64 height beyond float32
    reached isovalues() first: "interval=1 over heights [0.02, 1e+300] gives 1e+300 levels", blaming the interval
    and naming no frame. Found by feeding a stack with one bad cell in its last frame and counting the frames
    yielded before the error."""
    frames = np.random.default_rng(0).random((3, 5, 5)) * 10
    frames[2, 1, 1] = bad
    frames[0, 0, 0] = np.nan  # nodata elsewhere stays nodata
    yielded = []
    expected = (
        "heights must be finite or NaN (nodata); got an infinite value at index (1, 1)"
        if np.isinf(bad)
        else "heights must fit in float32"
    )
    with pytest.raises(st.InvalidInputError, match=r"^frames\[2\]: " + re.escape(expected)):
        for mesh in st.stepped_series(frames, interval=1.0):
            yielded.append(mesh)
    assert yielded == []
    frames[2, 1, 1] = 5.0
    frames[1] = np.nan  # an all-nodata frame before a bad one is named first
    frames[2, 1, 1] = bad
    with pytest.raises(st.InvalidInputError, match=r"^frames\[1\]: terrain has no finite height \(all nodata\)$"):
        next(st.stepped_series(frames, interval=1.0))


def test_memory_budget_counts_the_colours():
    """colors= adds an RGBA and a level index per vertex (12 bytes) after the budget check, which counted the
    surface only: a budget that holds the plain mesh but not its colours let the coloured mesh through."""
    heights = np.add.outer(np.arange(40.0), np.arange(30.0) * 0.7).astype(np.float32)
    plain = st.stepped(heights, interval=3.0)
    v, f = len(plain.vertices), len(plain.faces)
    budget = 40 * v + 29 * f + 6 * v  # the surface's arrays (stepped.py), and half the colours' bytes
    assert len(st.stepped(heights, interval=3.0, memory_budget=budget).faces) == f
    with pytest.raises(st.OutputTooLargeError, match=r"the stepped mesh"):
        st.stepped(heights, interval=3.0, colors="terrain", memory_budget=budget)


@pytest.mark.parametrize("radius, edge_width", [(1e-320, None), (1.0, 1e-320)], ids=["radius", "edge_width"])
def test_a_subnormal_lens_edge_leaks_no_overflow_warning(radius, edge_width):
    # (d - (r - w / 2)) / w overflowed for a subnormal edge width (numpy's RuntimeWarning), before the clip took it to
    # 0 or 1: the lens is a hard circle, without the warning
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lens = st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), radius, edge_width=edge_width, resolution=9)
    x0, x1, y0, y1 = lens.extent  # the mask's samples span the lens's own square
    inside = np.hypot(*np.meshgrid(np.linspace(x0 - 2, x1 - 2, 9), np.linspace(y0 - 2, y1 - 2, 9))) <= radius
    np.testing.assert_array_equal(lens.mask, np.where(inside, 0.0, 1.0))


def test_a_lens_resolution_beyond_float64_is_over_the_budget():
    # the budget message divided 10**800 bytes by 1024**2 in float: OverflowError instead of the budget's error
    with pytest.raises(st.OutputTooLargeError, match=r"would need over 10\^795 MiB, over the memory budget"):
        st.circular_lens(np.zeros((5, 5)), (2.0, 2.0), 1.0, resolution=10**400)


def test_stepped_series_steps_a_warp_stack_as_the_numpy_stack():
    """A (T, H, W) Warp array was refused as "frames must be a (T, H, W) stack or an iterable ...; got array",
    though it is one (stepped() takes a 2-D Warp array). Found by feeding stepped_series every kind of stack. Now
    its frames share the stack's isovalues, as the numpy stack's do."""
    import warp as wp

    frames = np.random.default_rng(4).random((3, 5, 6)).astype(np.float32)
    frames[1] *= 3  # its range exceeds frame 0's: shared isovalues show in the level indices
    expected = list(st.stepped_series(frames, interval=0.25, device="cpu"))
    got = list(st.stepped_series(wp.array(frames, device="cpu"), interval=0.25, device="cpu"))
    assert len(got) == 3
    for mesh, ref in zip(got, expected, strict=True):
        np.testing.assert_array_equal(mesh.vertices, ref.vertices)
        np.testing.assert_array_equal(mesh.faces, ref.faces)
        np.testing.assert_array_equal(mesh.face_attributes["level"], ref.face_attributes["level"])
        assert mesh.metadata["isovalues"] == ref.metadata["isovalues"]


def test_stepped_series_names_the_frame_whose_isovalues_the_colors_do_not_fit():
    """Frames from an iterable get their own isovalues; colours with one row per isovalue of frame 0 failed at a
    later frame with a message about the colours alone ("shape (13, 3|4); got shape (5, 4)"), naming no frame:
    the frame that has 13 isovalues was left to guess. Found by stepping a generator whose second frame spans
    three times the first's range. Now the error names frames[1] and its isovalue count."""
    frames = np.random.default_rng(1).random((3, 6, 7)).astype(np.float32)
    frames[1] *= 3
    first = st.isovalues((float(frames[0].min()), float(frames[0].max())), interval=0.25)
    second = st.isovalues((float(frames[1].min()), float(frames[1].max())), interval=0.25)
    colors = np.full((len(first), 4), 0.5)
    series = st.stepped_series(iter(frames), interval=0.25, colors=colors, device="cpu")
    assert len(next(series).faces) > 0  # frame 0 fits
    with pytest.raises(st.InvalidInputError, match=rf"^frames\[1\] \({len(second)} isovalues, shape \(6, 7\)\): col"):
        next(series)


def test_stepped_series_steps_terrain_and_tin_frames_as_stepped_does():
    """An iterable of Terrain objects (or TINs) was refused frame by frame as "got dtype object": the series read
    every frame as a raw array. Each frame is now taken as stepped() takes it, with its own spacing and origin."""
    dem = st.sample_dem()
    small = st.Terrain.from_heights(dem.heights[:40, :50], spacing=(30.0, -30.0), origin=(1000.0, 2000.0))
    tin = st.heightfield_mesh(dem.heights[10:30, 5:25], spacing=(30.0, -30.0))
    meshes = list(st.stepped_series([small, tin], interval=40.0))
    for got, frame in zip(meshes, (small, tin), strict=True):
        want = st.stepped(frame, interval=40.0)
        np.testing.assert_array_equal(got.vertices, want.vertices)
        np.testing.assert_array_equal(got.faces, want.faces)
    with pytest.raises(st.errors.InvalidInputError, match="spacing/origin apply to raw"):
        list(st.stepped_series([small], interval=40.0, spacing=(10.0, 10.0)))


def test_stepped_series_refuses_a_stack_of_no_frames():
    """A (0, H, W) stack said "frames hold no finite height"; it holds no frame at all."""
    with pytest.raises(st.errors.InvalidInputError, match=r"at least one frame; got shape \(0, 4, 5\)"):
        list(st.stepped_series(np.zeros((0, 4, 5)), interval=1.0))

@settings(max_examples=40, deadline=None)
@given(
    start=st_.floats(float(np.float32(-3e38)), float(np.float32(3e38)), width=32, allow_subnormal=False),
    count=st_.integers(2, 4),
    at=st_.integers(0, 3),
)
def test_levels_that_are_neighbouring_float32_values_never_step_a_height_off_its_own_level(start, count, at):
    """A height equal to an isovalue is its own nearest isovalue. Levels one float32 step apart (1e7 and 1e7 + 1)
    have a midpoint that float32 cannot hold; rounded to even it fell onto the lower level, so a height on that level
    sat on the threshold and stepped up: a flat terrain at 1e7 with levels [1e7, 1e7 + 1] came back at 1e7 + 1, and
    three such levels could give two equal thresholds (an empty band). Such levels are refused, naming them; levels
    whose thresholds lie above their lower level keep every height on its own. Found by stepping flat terrains at
    levels given as consecutive float32 values."""
    levels = [np.float32(start)]
    for _ in range(count - 1):
        levels.append(np.nextafter(levels[-1], np.float32(np.inf)))
    levels = np.array(levels, np.float32)
    height = float(levels[min(at, count - 1)])
    flat = np.full((2, 2), height)
    if (thresholds_of(levels) <= levels[:-1]).any():
        with pytest.raises(
            st.InvalidInputError,
            match=r"^levels must be more than one float32 step apart .*"
            r"levels\[\d\]=.* are neighbouring float32 values",
        ):
            st.stepped(flat, levels=levels.astype(np.float64))
        return
    mesh = st.stepped(flat, levels=levels.astype(np.float64))
    assert set(mesh.vertices[:, 2].tolist()) == {height}


def test_an_interval_of_one_float32_step_is_refused_not_stepped_up():
    """The same through interval=: at 1e7 float32 holds only integers, so interval=1 gives isovalues 1e7, 1e7 + 1
    whose threshold rounds onto 1e7; a flat terrain at 1e7 came back at 1e7 + 1. Refused, with the interval that
    works there; 2 steps apart the heights keep their level."""
    flat = np.full((2, 2), 1e7)
    flat[1, 1] = 1e7 + 1
    with pytest.raises(
        st.InvalidInputError,
        match=r"^interval=1 is too small for float32 heights around 1e\+07: the "
        r"isovalues 10000000\.0 and 10000001\.0 are neighbouring float32 values.* at least 2 there$",
    ):
        st.stepped(flat, interval=1.0)
    mesh = st.stepped(flat, interval=2.0)
    assert set(mesh.vertices[:, 2].tolist()) == {1e7}
    with pytest.raises(
        st.InvalidInputError,
        match=r"^levels must be strictly increasing in float32 .*levels\[0\]="
        r"10000000\.0 and levels\[1\]=10000000\.25 both round to 10000000\.0$",
    ):
        st.stepped(flat, levels=[1e7, 1e7 + 0.25])  # was "strictly increasing; got [10000000.0, 10000000.25]"


def _cliff_tin(kind, low, high):
    """A TIN with faces of zero area in xy beside real ones: a vertical cliff (two points on one xy, along an axis or
    a diagonal) or a collinear sliver between two faces."""
    if kind == "collinear sliver":
        points = [(0, 0, low), (1, 0, high), (0.5, 0, (low + high) / 2 + 0.1), (0.5, 1, low), (0.5, -1, high)]
        return trimesh.Trimesh(np.array(points, float), [[0, 1, 2], [0, 2, 3], [2, 1, 3], [0, 4, 1]], process=False)
    shift = 0.3 if kind == "diagonal cliff" else 0.0
    points = [(0, 0, low), (0, 1, low), (1, 0, low), (1 + shift, 1, low), (1, 0, high), (1 + shift, 1, high),
              (2, 0, high), (2 + shift, 1, high)]  # fmt: skip
    faces = [[0, 2, 3], [0, 3, 1], [2, 4, 5], [2, 5, 3], [4, 6, 7], [4, 7, 5]]
    return trimesh.Trimesh(np.array(points, float), faces, process=False)


@settings(max_examples=30, deadline=None)
@given(
    kind=st_.sampled_from(["axis cliff", "diagonal cliff", "collinear sliver"]),
    low=st_.floats(0.0, 3.0),
    rise=st_.floats(0.3, 6.0),
    gamma=st_.sampled_from([1.0, 0.5]),
)
def test_solid_of_a_tin_with_zero_area_faces_is_watertight(kind, low, rise, gamma):
    """The base took one vertex per xy, so two surface vertices on one xy that no wall joins (a cliff's foot and top
    crossings, or a crossing on a collinear sliver that lands on another point) shared it: the base folded onto a
    base edge used four times (or, on a cliff face, a chain of vertical boundary edges left skirt edges used once),
    and the solid leaked without the warning that heights on thresholds give. Such TINs are accepted ("zero-area
    slivers beside real faces are stepped"). The base now keys a wall's bottom and top to one vertex, everything else
    to its own. Found by closing TINs with a vertical cliff (same xy, two heights) and a collinear face."""
    import warnings

    tin = _cliff_tin(kind, low, low + rise)
    heights = tin.vertices[:, 2].astype(np.float32)
    # a height on a threshold is stepped from one float32 step above it: the volume moves by that rounding
    on = np.isin(heights, thresholds_of(st.isovalues((heights.min(), heights.max()), interval=0.7))).any()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = st.stepped(tin, interval=0.7, gamma=gamma, solid=True, floor=-1.0)
    assert_valid_mesh(mesh)
    assert mesh.is_watertight and mesh.is_winding_consistent
    surface = st.stepped(tin, interval=0.7, gamma=gamma)
    expected = float((projected_area(surface) * (surface.triangles[:, :, 2].mean(axis=1) + 1.0)).sum())
    assert mesh.volume == pytest.approx(expected, rel=1e-6 if on else 1e-9)


def test_the_package_attribute_stepped_is_the_module_and_its_entry_point():
    """``stepterrain/__init__`` bound ``st.stepped`` to the function, so ``st.stepped.thresholds_of`` (and every name
    of the module) raised AttributeError. It is now the module, callable as :func:`stepped` with stepped's signature
    (the same helper as ``st.batch``), and it pickles by name, as the function does."""
    import inspect
    import pickle
    import sys

    import cloudpickle

    from stepterrain.stepped import stepped

    module = sys.modules["stepterrain.stepped"]
    assert st.stepped is module
    assert st.stepped.thresholds_of is thresholds_of and st.stepped.stepped is stepped
    assert inspect.signature(st.stepped) == inspect.signature(stepped)
    for dumps, loads in ((pickle.dumps, pickle.loads), (cloudpickle.dumps, cloudpickle.loads)):
        assert loads(dumps(st.stepped)) is st.stepped
        assert loads(dumps(stepped)) is stepped
    heights = np.add.outer(np.arange(6.0), np.arange(6.0)).astype(np.float32)
    mesh = st.stepped(heights, interval=2.0, device="cpu")
    expected = stepped(heights, interval=2.0, device="cpu")
    assert np.array_equal(mesh.vertices, expected.vertices) and np.array_equal(mesh.faces, expected.faces)
    with pytest.raises(TypeError, match="intervals"):  # the call is stepped's: its keywords are checked
        st.stepped(heights, intervals=2.0)


def test_a_floor_above_the_surface_is_refused_before_stepping(monkeypatch):
    """``stepped(solid=True, floor=...)`` stepped the whole terrain, warned that heights sit on thresholds, and only
    then close_solid refused the floor (the CLI printed the warning, then the --floor error). A floor at or above
    the lowest node's blended height is refused before stepping now, with no warning."""
    import warnings

    heights = np.array([[10.0, 15.0, 20.0], [15.0, 25.0, 30.0], [20.0, 30.0, 40.0]], np.float32)  # 15 on a threshold
    stepped_calls = []
    real = stepped_module._stepped_arrays
    monkeypatch.setattr(stepped_module, "_stepped_arrays", lambda *a, **k: stepped_calls.append(1) or real(*a, **k))
    cases = ((1.0, 10.0, "10"), (1.0, 12.0, "10"), (0.0, 10.0, "10"), (0.5, 11.0, "10"),
             (np.full((3, 3), 0.5), 10.5, "at most 10"))
    for gamma, floor, lowest in cases:
        message = f"^floor must lie below the lowest surface height,? {lowest} "
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(st.InvalidInputError, match=message):
                st.stepped(heights, interval=10.0, gamma=gamma, solid=True, floor=floor, device="cpu")
        assert caught == [] and stepped_calls == []
    # with nodata the lowest height a triangle uses decides (grids with nodata were left to close_solid): -100 m
    # sits in no triangle (its neighbours are nodata), the lowest used height is 25 m, on the threshold to 30 m
    holed = heights.copy()
    holed[0, 0], holed[0, 1], holed[1, 0] = -100.0, np.nan, np.nan
    for gamma, floor, lowest in ((1.0, 30.0, "30"), (0.0, 26.0, "25")):
        with pytest.raises(st.InvalidInputError, match=f"^floor must lie below the lowest surface height {lowest} "):
            st.stepped(holed, interval=10.0, gamma=gamma, solid=True, floor=floor, device="cpu")
        assert stepped_calls == []
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # 15 m on a threshold: stepped from one float32 step above, no warning
        mesh = st.stepped(heights, interval=10.0, solid=True, floor=9.5, device="cpu")  # just below: stepped, closed
        assert stepped_calls == [1] and mesh.vertices[:, 2].min() == 9.5
        mesh = st.stepped(holed, interval=10.0, solid=True, floor=20.0, device="cpu")  # above -100 m, below 30 m
    assert mesh.is_watertight and mesh.vertices[:, 2].min() == 20.0


@settings(max_examples=40, deadline=None)
@given(
    heights=st_.lists(st_.floats(-2e4, 2e4, width=32), min_size=12, max_size=12),
    interval=st_.sampled_from([0.7, 3.0, 10.0, 40.0]),
    gamma=st_.sampled_from([0.0, 1.0, 0.3, 0.5, 0.999, "array"]),
    offset=st_.sampled_from([-1e-3, -1e-6, 0.0, 1e-6, 1e-3, 1.0]),
    tin=st_.booleans(),
    hole=st_.sampled_from([None, 0, 5, 11]),
)
def test_the_early_floor_refusal_never_refuses_a_floor_the_solid_takes(heights, interval, gamma, offset, tin, hole):
    """The check before stepping refuses only floors that close_solid refuses after stepping: floors around the
    lowest surface point (exactly on it, a float32 rounding away, a bit above or below), at γ 0, 1, in between and
    per node, on grids and TINs, with a nodata node (a corner's hole leaves a node in no triangle)."""
    import warnings

    z = np.array(heights, np.float32).reshape(3, 4)
    if hole is not None and not tin:  # a grid's nodata (a TIN drops its NaN points, and their γ with them)
        z.reshape(-1)[hole] = np.nan
    terrain = st.heightfield_mesh(z) if tin else z
    g = np.linspace(0.0, 1.0, 12).reshape((12,) if tin else (3, 4)) if gamma == "array" else gamma  # γ per node
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        surface = st.stepped(terrain, interval=interval, gamma=g, device="cpu")
        floor = float(surface.vertices[:, 2].min()) + offset
        try:
            t = as_terrain(terrain)
            stepped_module._refuse_floor_above_surface(t, st.isovalues(t.height_range, interval=interval), g, floor)
        except st.InvalidInputError:
            early = True
        else:
            early = False
        try:
            st.stepped(terrain, interval=interval, gamma=g, solid=True, floor=floor, device="cpu")
        except st.InvalidInputError as exc:
            assert "floor must lie below" in str(exc)
            refused = True
        else:
            refused = False
    lowest = surface.vertices[:, 2].min()
    # the final word: close_solid's (a floor on the lowest point in float32 too: no thickness in an .stl or a .glb)
    assert refused == (floor >= lowest or np.float32(floor) >= np.float32(lowest))
    assert refused or not early  # never a floor the solid takes
    if offset >= 0 and not isinstance(g, np.ndarray) and g in (0.0, 1.0):
        assert early  # γ 0 or 1: the lowest point is known exactly, so every such floor is refused before stepping
    if not isinstance(g, np.ndarray) and g in (0.0, 1.0):
        assert early == refused  # and so is one that rounds onto it in float32 (close_solid's rule, before stepping)


@pytest.mark.parametrize("gamma", [0.0, 1.0])
def test_a_floor_on_the_lowest_point_in_float32_is_refused_before_stepping(monkeypatch, gamma):
    """A floor one float64 step below the lowest surface point lies on it in float32: close_solid refuses it after
    stepping (no thickness in an .stl or a .glb), so the check before stepping refuses it too, by the same rule,
    naming the float32 floor below (the check only applied float64's ``floor >= lowest``: the terrain was stepped,
    with its warnings, only to be refused). At γ 0 and 1, where the check knows the lowest point exactly (in between
    it leaves the last few float32 steps to close_solid)."""
    heights = np.array([[15.0, 22.0, 41.0], [33.0, 27.0, 58.0], [19.0, 44.0, 36.0]], np.float32)
    lowest = float(st.stepped(heights, interval=10.0, gamma=gamma, device="cpu").vertices[:, 2].min())
    floor = float(np.nextafter(lowest, -np.inf))
    assert floor < lowest and np.float32(floor) == np.float32(lowest)
    stepped_calls = []
    real = stepped_module._stepped_arrays
    monkeypatch.setattr(stepped_module, "_stepped_arrays", lambda *a, **k: stepped_calls.append(1) or real(*a, **k))
    with pytest.raises(st.InvalidInputError, match=r"^floor must lie below the lowest surface height .* in float32 "
                       rf"too .* at most {float(np.nextafter(np.float32(lowest), np.float32(-np.inf))):.9g}\)"):
        st.stepped(heights, interval=10.0, gamma=gamma, solid=True, floor=floor, device="cpu")
    assert stepped_calls == []
    highest = float(np.nextafter(np.float32(lowest), np.float32(-np.inf)))  # the floor it names is taken
    mesh = st.stepped(heights, interval=10.0, gamma=gamma, solid=True, floor=highest, device="cpu")
    assert mesh.is_watertight and mesh.vertices[:, 2].min() == highest


class _Unreadable:
    """An array-like numpy cannot read, as a GPU tensor (torch on CUDA, cupy): its ``__array__`` raises TypeError."""

    def __array__(self, *args: object, **kwargs: object) -> None:
        raise TypeError("implicit conversion to a NumPy array is not allowed")


@pytest.mark.parametrize(
    "gamma, cause",
    [
        (lambda points: 1 / 0, ZeroDivisionError),  # the callable raises
        (lambda: 0.5, TypeError),  # a callable of the wrong signature
        (lambda points: _Unreadable(), TypeError),  # its result cannot be read
        (_Unreadable(), TypeError),  # γ itself cannot be read
    ],
    ids=["raises", "signature", "unreadable-result", "unreadable-gamma"],
)
@pytest.mark.parametrize("solid", [False, True])
def test_a_gamma_that_fails_is_an_error_naming_gamma_with_its_cause(gamma, cause, solid):
    """A γ callable that raised (or took no argument), or returned an object numpy cannot read (a GPU tensor), and such
    an object as γ itself, escaped as a bare ZeroDivisionError / TypeError from deep inside stepped(), naming neither
    gamma nor the argument. They are InvalidInputErrors naming gamma, with the original exception as the cause (its
    type and message in the text); in a series of frames from an iterable the cause survives the frame's name."""
    heights = np.random.default_rng(0).random((6, 7)) * 10
    kwargs = {"solid": True, "floor": -5.0} if solid else {}
    with pytest.raises(st.InvalidInputError, match=r"^gamma") as info:
        st.stepped(heights, interval=2.0, gamma=gamma, device="cpu", **kwargs)
    assert isinstance(info.value.__cause__, cause)
    assert type(info.value.__cause__).__name__ in str(info.value)
    assert str(info.value.__cause__) in str(info.value)
    with pytest.raises(st.InvalidInputError, match=r"^frames\[0\] .*: gamma") as info:
        list(st.stepped_series(iter([heights, heights]), interval=2.0, gamma=gamma, device="cpu"))
    assert isinstance(info.value.__cause__, cause)


@pytest.mark.parametrize("kind", ["colors", "uv"])
def test_a_solid_keeps_the_colours_or_uvs_carried_from_its_tin(kind):
    """stepped(tin, solid=True) of a TIN with vertex colours or UVs returned a solid without any visual: the carried
    visual was built for surfaces only and dropped without a word (colors= kept its colours on solids). A solid now
    carries them too: the surface's vertices as on the surface, the skirt and base grey (as with colors=) or, for
    UVs, those of the surface above. Colours and UVs affine in xy must come out affine in xy on every vertex."""
    rng = np.random.default_rng(4)
    heights = rng.normal(size=(8, 11)).cumsum(0).cumsum(1) * 3 + 0.1
    heights[3, 4] = np.nan  # a hole: an inner skirt
    tin = st.heightfield_mesh(heights, spacing=(1.5, 2.0), origin=(5.0, 7.0))
    lo, span = tin.vertices[:, :2].min(axis=0), np.ptp(tin.vertices[:, :2], axis=0)
    ramp = (tin.vertices[:, :2] - lo) / span  # (r, s) in [0, 1], affine in xy
    if kind == "colors":
        rgba = np.column_stack([ramp * 255, 255 - ramp[:, 0] * 255, np.full(len(ramp), 255)])
        tin.visual = trimesh.visual.ColorVisuals(tin, vertex_colors=np.round(rgba).astype(np.uint8))
    else:
        tin.visual = trimesh.visual.TextureVisuals(uv=ramp)
    surface = st.stepped(tin, interval=2.0, gamma=0.6, device="cpu")
    solid = st.stepped(tin, interval=2.0, gamma=0.6, solid=True, device="cpu")
    assert solid.is_watertight
    assert type(solid.visual) is type(surface.visual)
    expected = (solid.vertices[:, :2] - lo) / span
    if kind == "uv":
        assert solid.visual.uv.shape == (len(solid.vertices), 2)
        np.testing.assert_allclose(solid.visual.uv, expected, atol=1e-6)  # the base's too: the surface above
    else:
        colours = solid.visual.vertex_colors.astype(float)
        grey = (colours[:, :3] == 96).all(axis=1)
        below = solid.vertices[:, 2] == solid.metadata["floor"]
        assert grey[below].all()  # the base is grey
        ours = ~grey
        assert ours.sum() >= len(surface.vertices)  # every surface vertex keeps its colour (a pinch's copies too)
        np.testing.assert_allclose(colours[ours, :2], expected[ours] * 255, atol=1.0)


def test_trimesh_own_ply_writer_writes_a_stepped_mesh(tmp_path):
    """trimesh's PLY writer had no PLY type for the bool ``wall`` mask: ``mesh.export("x.ply")`` raised KeyError 'b1'.
    The file (binary, trimesh's default) now holds the wall mask as uchar 0/1 and the level per face, next to the
    same faces. (trimesh's ASCII PLY formatter has no bool either; stepterrain.export.save_mesh writes both.)"""
    dem = st.sample_dem()
    mesh = st.stepped(dem.heights[:40, :50], interval=50.0, spacing=(30.0, 30.0), colors="terrain")
    assert mesh.face_attributes["wall"].dtype == np.bool_ and mesh.face_attributes["wall"].any()
    path = tmp_path / "steps.ply"
    mesh.export(path)
    back = trimesh.load(path, process=False)
    faces = back.metadata["_ply_raw"]["face"]["data"]
    np.testing.assert_array_equal(back.faces, mesh.faces)
    np.testing.assert_array_equal(np.asarray(faces["wall"]).reshape(-1), mesh.face_attributes["wall"].astype(np.uint8))
    np.testing.assert_array_equal(np.asarray(faces["level"]).reshape(-1), mesh.face_attributes["level"])
    assert b"property uchar wall" in path.read_bytes()[:1000]


def test_a_small_lens_on_a_large_dem_follows_its_smoothstep():
    """circular_lens spread its 512 x 512 samples over the whole terrain: on the 36 x 19 km sample DEM a 60 m lens
    fell between the mask's 70 m samples, and the stepped heights in it were up to 19 m off those of the lens's own
    smoothstep. The mask now covers the lens's square (γ is `outside` beyond it)."""
    dem = st.sample_dem()
    x0, x1, y0, y1 = dem.extent
    cx, cy, radius, edge = (x0 + x1) / 2, (y0 + y1) / 2, 60.0, 30.0
    lens = st.circular_lens(dem, (cx, cy), radius, edge_width=edge)

    def smoothstep(points):
        s = np.clip((np.hypot(points[:, 0] - cx, points[:, 1] - cy) - (radius - edge / 2)) / edge, 0.0, 1.0)
        return s * s * (3.0 - 2.0 * s)

    by_lens = st.stepped(dem, interval=100.0, gamma=lens)
    exact = st.stepped(dem, interval=100.0, gamma=smoothstep)
    np.testing.assert_array_equal(by_lens.faces, exact.faces)
    assert np.abs(by_lens.vertices - exact.vertices).max() < 0.01  # metres, heights 300-2300 m
    plain = st.stepped(dem, interval=100.0)
    near = np.hypot(plain.vertices[:, 0] - cx, plain.vertices[:, 1] - cy) < radius - edge / 2
    assert near.sum() >= 4 and not np.allclose(by_lens.vertices[near, 2], plain.vertices[near, 2])
    far = np.hypot(plain.vertices[:, 0] - cx, plain.vertices[:, 1] - cy) > radius + edge / 2
    np.testing.assert_array_equal(by_lens.vertices[far], plain.vertices[far])


def test_a_solids_skirt_and_base_are_level_minus_one_and_no_wall():
    # the documented face attributes of a solid: the surface's faces keep their levels and wall marks
    heights = st.sample_dem().heights[:30, :40]
    surface = st.stepped(heights, interval=50.0, base=0.5, spacing=(30.0, 30.0))
    solid = st.stepped(heights, interval=50.0, base=0.5, spacing=(30.0, 30.0), solid=True)
    levels, walls = solid.face_attributes["level"], solid.face_attributes["wall"]
    extra = levels == -1
    assert extra.sum() == len(solid.faces) - len(surface.faces) and not walls[extra].any()
    assert np.array_equal(np.sort(levels[~extra]), np.sort(surface.face_attributes["level"]))
    assert walls[~extra].sum() == surface.face_attributes["wall"].sum()


def test_the_solids_threshold_warning_points_at_the_callers_line():
    # a fixed stacklevel=3 pointed into stepterrain/_callable_module.py when stepped() was called as st.stepped(...).
    # A height on a threshold whose next float32 value is the next threshold (levels a few float32 steps apart:
    # 1.0 lies on t_0, and one step above it on t_1) cannot be moved up within its level: that still warns
    levels = np.array([np.nextafter(np.float32(1), np.float32(0)), 1.0, 1.0 + 2.0**-22], np.float32)
    assert thresholds_of(levels).tolist() == [1.0, 1.0 + 2.0**-23]
    heights = np.array([[0.0, 1.0, 2.0], [1.0, 2.0, 1.0]], np.float32)
    with pytest.warns(UserWarning, match="sit exactly on a threshold") as record:
        st.stepped(heights, levels=levels, solid=True)
    assert [w.filename for w in record] == [__file__]


def test_a_base_far_from_the_heights_is_named_not_reported_as_isovalues_0_0():
    """``stepterrain steps --interval 1 --base 1e39`` (and base=1e20 over heights near 0) said the interval "gives
    isovalues [0.0, 0.0] that do not cover the heights": base + k * interval near the heights cancelled to base's
    rounding error, values no interval ever gives. A base beyond float32 is refused as levels beyond it are, and one
    whose rounding exceeds an interval says why; heights lost in lo - base (interval=3.4e38, base=-3.4e38 over
    [1000, 1011]: k0 = k1 = 1, the one isovalue 0 below them) get the interval above them, and levels from -3.4e38 to
    3.4e38 no longer overflow numpy's diff (a RuntimeWarning)."""
    heights = np.add.outer(np.arange(6.0), np.arange(7.0)) + 1000.0
    with pytest.raises(st.InvalidInputError, match=r"^base must fit in float32 \(\|x\| < 3.4e\+38\), .*; got 1e\+39$"):
        st.isovalues((315.0, 2295.0), interval=1.0, base=1e39)
    with pytest.raises(st.InvalidInputError, match=r"^interval=1 with base=1e\+20, more than 2\*\*53 intervals from "
                                                   r"zero: float64 rounds it by more than an interval"):
        st.isovalues((0.0, 10.0), interval=1.0, base=1e20)
    assert st.isovalues((1000.0, 1011.0), interval=3.4e38, base=-3.4e38).tolist() == [0.0, np.float32(3.4e38)]
    assert st.isovalues((0.0, 10.0), interval=1e30, base=3e38).tolist() == [0.0, np.float32(1e30)]
    assert st.isovalues((0.0, 10.0), interval=1e12, base=1e20).tolist() == [0.0, np.float32(1e12)]  # no cancellation
    mesh = st.stepped(heights, interval=3.4e38, base=-3.4e38)
    assert (mesh.vertices[:, 2] == 0.0).all()  # every height below the threshold 1.7e38 steps down to 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = st.stepped(heights, levels=[-3.4e38, 3.4e38])
    assert np.isfinite(mesh.vertices).all() and (mesh.vertices[:, 2] == np.float32(3.4e38)).all()


@pytest.mark.parametrize(
    ("values", "uniform"),
    [
        (np.concatenate([np.arange(1000.0, 1250.0, 0.05), np.arange(1250.0, 1500.0, 0.06)]), False),  # two intervals
        (np.geomspace(1000.0, 1450.0, 5000), False),  # every gap within 25 % of the mean, drifting from -18 to +18 %
        (np.arange(5000) * 2.5 - 10.0, True),
        (st.isovalues((0.0, 4000.0), interval=0.5, base=0.25), True),
        (st.isovalues((4.0e6, 4.004e6), interval=2.0), True),  # float32 rounds them: gaps of 2 +- a quarter ulp
    ],
)
def test_the_linear_level_estimate_is_taken_only_where_it_lands_near_the_level(values, uniform):
    """quantize_levels' estimate-and-correct (kernels/stepped.py, level_of) walks from the linear estimate
    (h - first) * inv_gap + 1 to the exact level one threshold at a time. It was taken whenever every gap lay within
    25 % of their mean, which bounds each gap but not their sum: thousands of levels whose gaps drift (two intervals,
    0.05 up to 1250 m and 0.06 above; log-spaced levels) put the estimate hundreds of levels off, and every node
    walked that far: quantizing 512² nodes took 0.87-1.13 s instead of 7 ms (the binary search: 27 ms even at a
    million levels). The estimate is now taken only where it lands within two levels of every threshold's count."""
    values = np.asarray(values, np.float32)
    iso = stepped_module._build_isovalue_struct(values, resolve_device("cpu"))
    assert iso.uniform == int(uniform)  # evenly spaced isovalues (rounded to float32) keep the fast path
    if not iso.uniform:
        return
    thresholds = thresholds_of(values)
    heights = np.concatenate([thresholds, (thresholds[:-1] + thresholds[1:]) / 2]).astype(np.float32)
    exact = np.searchsorted(thresholds, heights, side="right")
    x = (heights - np.float32(iso.first)) * np.float32(iso.inv_gap) + np.float32(1.0)  # float32, as level_of
    estimate = np.where(x >= len(thresholds), len(thresholds), np.maximum(x, 0).astype(np.int64))
    assert np.abs(estimate - exact).max() <= 3


def test_grid_isovalues_ignore_heights_on_no_complete_triangle():
    """A grid node whose every cell touches nodata is in no triangle, so in no stepped mesh; its height still set the
    isovalues (the TIN of the same grid, heightfield_mesh, ignored it since test_tin_isovalues_ignore_heights_on_no_
    kept_face): a lone pixel in a void (here -9999 beside a void column) moved the hypsometric colours of every level
    and the level indices, lowered the solid's default floor by 10 km, warned of heights on thresholds that open no
    solid, and made interval=0.001 "too many levels" for 1.3 m of terrain."""
    h = np.add.outer(np.arange(5.0), np.arange(6.0)) * 0.3 + 100.1  # no height on a threshold k + 0.5
    h[:, 4] = np.nan
    h[2, 5] = -9999.0  # the strip of column 5 has no complete triangle
    h[3, 5] = 101.5  # on the threshold between isovalues 101 and 102
    tin = st.heightfield_mesh(h)
    for kwargs in ({"interval": 1.0, "colors": "terrain"}, {"interval": 1.0, "solid": True}, {"interval": 0.001}):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no warning of heights on thresholds
            grid_mesh, tin_mesh = st.stepped(h, **kwargs), st.stepped(tin, **kwargs)
        assert grid_mesh.metadata == tin_mesh.metadata  # the isovalues, and a solid's floor
        order = [np.lexsort(m.triangles.reshape(len(m.faces), 9).T) for m in (grid_mesh, tin_mesh)]
        np.testing.assert_array_equal(grid_mesh.triangles[order[0]], tin_mesh.triangles[order[1]])
        np.testing.assert_array_equal(grid_mesh.face_attributes["level"][order[0]],
                                      tin_mesh.face_attributes["level"][order[1]])
        if "colors" in kwargs:  # by face corner: the two number their vertices differently
            np.testing.assert_array_equal(grid_mesh.visual.vertex_colors[grid_mesh.faces[order[0]]],
                                          tin_mesh.visual.vertex_colors[tin_mesh.faces[order[1]]])
    assert st.Terrain.from_heights(h).height_range == (float(np.float32(100.1)), float(np.float32(102.2)))
    expected = st.stepped(tin, interval=1.0).metadata["isovalues"]
    for frame in st.stepped_series(np.stack([h, h]), interval=1.0):  # a stack's shared isovalues
        assert frame.metadata["isovalues"] == expected
    from stepterrain.batch import _shared_levels, plan_items

    _, src = plan_items(h.astype(np.float32), tile_size=2)  # batch's tiles of the raster
    assert list(_shared_levels(src, 1.0, None, 0.0)) == expected
    # finite heights on no triangle at all: an empty mesh, as before
    assert len(st.stepped(np.array([[1.0, np.nan], [np.nan, np.nan]]), interval=1.0).faces) == 0


def test_a_stack_without_nodata_takes_no_pass_over_its_triangles_for_its_range(monkeypatch, tmp_path):
    """stepped_series of a (T, H, W) stack, and batch's shared levels of a series file, took the range of the nodes a
    complete triangle uses (6d3155e) for every stack, nodata or not: five boolean masks of the stack's size and a
    masked min and max, 2.5 s for a 64 x 1024 x 1024 stack whose finite range (0.9 s, already taken) is the same
    answer without nodata. Such a stack now takes no mask of triangles; one with nodata still does."""
    import stepterrain.terrain as terrain_module
    from stepterrain.batch import _shared_levels, plan_items

    rng = np.random.default_rng(3)
    stack = rng.normal(100.0, 20.0, (3, 12, 10)).astype(np.float32)
    expected = [m.metadata["isovalues"] for m in st.stepped_series(stack, interval=5.0)]
    np.save(tmp_path / "series.npy", stack)
    calls = []
    real = terrain_module.used_nodes
    monkeypatch.setattr(terrain_module, "used_nodes", lambda finite: calls.append(finite.shape) or real(finite))
    assert [m.metadata["isovalues"] for m in st.stepped_series(stack, interval=5.0)] == expected
    _, src = plan_items(tmp_path / "series.npy")
    assert list(_shared_levels(src, 5.0, None, 0.0)) == expected[0]
    assert calls == []
    stack[1, 4, 4] = np.nan  # nodata: the triangles decide, of that frame alone (the range is taken frame by frame)
    next(st.stepped_series(stack, interval=5.0))
    assert calls == [stack.shape[1:]]


def test_heights_of_subnormal_scale_step_without_an_overflow_warning():
    """Isovalues 1e-39 apart (heights of float32's subnormal scale) have a threshold gap whose inverse, the level
    estimate's float32 inv_gap, overflows: its cast warned "RuntimeWarning: overflow encountered in cast" from deep
    inside stepped() (an error under -W error, as in a test suite that turns warnings into errors). Such isovalues
    take the binary search, silently, and the mesh is the reference's."""
    heights = np.random.default_rng(0).uniform(0.0, 1e-38, (8, 9))
    values = st.isovalues((float(heights.astype(np.float32).min()), float(heights.astype(np.float32).max())),
                          interval=1e-39)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        iso = stepped_module._build_isovalue_struct(values, resolve_device("cpu"))
        mesh = st.stepped(heights, interval=1e-39)
    assert iso.uniform == 0
    assert len(mesh.faces) > 0 and np.isin(mesh.vertices[:, 2].astype(np.float32), values).all()
    compare_with_reference(heights, values, "cpu")


def test_a_solid_of_a_grid_with_nodata_asks_its_triangles_once(monkeypatch):
    """stepped(solid=True, floor=...) of a grid with nodata found the nodes a triangle with three finite heights uses
    three times: for the isovalues (Terrain.height_range), for the floor check (lowest_used_height) and for the
    threshold warning (Terrain.used_heights, a copy of them), ~45 ms each at 4000 x 4000. The terrain keeps the first
    pass's range and whether a triangle has three finite heights, and the warning compares the heights where they lie,
    asking the triangles again only when a height sits on a threshold. The answers are the same: a lone finite node
    beside nodata (on no triangle) neither lowers the floor's bound nor warns from a threshold; a used one does."""
    import stepterrain.terrain as terrain_module

    heights = np.random.default_rng(5).uniform(100.0, 200.0, (12, 14)).astype(np.float32) + np.float32(0.25)
    heights = np.where(np.isin(heights, thresholds_of(st.isovalues((100.0, 201.0), interval=10.0))), 150.25, heights)
    heights[4:6, 5:8] = np.nan
    heights[1, 1] = np.nan  # node (0, 0) is then on no triangle: a lone node, far below the rest
    heights[0, 0] = 95.0
    heights[10, 12] = np.nan  # and node (11, 13)
    lowest_used = float(np.min(heights[~np.isnan(heights)][1:]))
    expected = st.stepped(st.Terrain.from_heights(heights), interval=10.0, solid=True, floor=60.0)
    calls = []
    real = terrain_module.used_nodes
    monkeypatch.setattr(terrain_module, "used_nodes", lambda finite: calls.append(finite.shape) or real(finite))
    mesh = st.stepped(heights, interval=10.0, solid=True, floor=60.0)  # below the used nodes, above the lone one
    assert calls == [heights.shape]
    np.testing.assert_array_equal(mesh.vertices, expected.vertices)
    np.testing.assert_array_equal(mesh.faces, expected.faces)
    assert mesh.is_watertight and mesh.vertices[:, 2].min() == 60.0
    with pytest.raises(st.InvalidInputError, match="floor must lie below the lowest surface height"):
        st.stepped(heights, interval=10.0, solid=True, floor=lowest_used)  # the used nodes' lowest, not the lone one's
    lone_on_threshold = heights.copy()
    lone_on_threshold[11, 13] = 105.0
    assert 105.0 in thresholds_of(st.isovalues(st.Terrain.from_heights(heights).height_range, interval=10.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a lone node's height on a threshold cannot open the solid: no warning
        st.stepped(lone_on_threshold, interval=10.0, solid=True)
    used_on_threshold = heights.copy()
    used_on_threshold[8, 8] = 115.0
    calls.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a used one is stepped from one float32 step above: watertight, no warning
        assert st.stepped(used_on_threshold, interval=10.0, solid=True).is_watertight
    assert len(calls) == 2  # the range, then the triangles at the nodes on a threshold
    assert st.Terrain.from_heights(heights).height_range == (lowest_used, float(np.nanmax(heights)))
    # a grid whose finite nodes are on no triangle: no surface, refused after stepping as before
    lone = np.full((3, 3), np.nan, np.float32)
    lone[0, 0] = 5.0
    with pytest.raises(st.InvalidInputError, match="solid=True needs a surface"):
        st.stepped(lone, interval=1.0, solid=True, floor=10.0)


@pytest.mark.parametrize("solid", [False, True])
def test_a_tins_face_colours_are_carried_onto_its_steps(solid, tmp_path):
    """A TIN with face colours (a land-cover map per triangle; what read_mesh gives for a PLY or 3MF coloured per
    face) was stepped into a plain mesh: the docstring carries "the input's vertex colors or UVs", and face colours
    were dropped without a word. Found by stepping TINs with each kind of visual. Every output face now takes the
    colour of the input triangle it was cut from (terrace and wall alike; a solid's skirt and base grey, as for
    vertex colours), also when faces with nodata are left out, and a PLY keeps them."""
    from stepterrain.export import read_mesh, save_mesh

    rng = np.random.default_rng(6)
    heights = rng.normal(size=(7, 9)).cumsum(0).cumsum(1) * 3 + 0.1
    heights[2, 5] = np.nan  # faces with nodata are dropped: the colours must not shift onto the wrong faces
    full = st.heightfield_mesh(np.nan_to_num(heights, nan=1.0), spacing=(2.0, -3.0), origin=(500.0, 900.0))
    full.vertices[:, 2] = heights.reshape(-1)  # the nodata node's faces are given too
    colours = rng.integers(0, 256, (len(full.faces), 4)).astype(np.uint8)
    colours[:, 3] = 255
    full.visual = trimesh.visual.ColorVisuals(full, face_colors=colours)
    mesh = st.stepped(full, interval=2.0, gamma=0.7, solid=solid, device="cpu")
    assert mesh.visual.kind == "face"
    got = np.asarray(mesh.visual.face_colors)
    assert got.shape == (len(mesh.faces), 4)
    ours = mesh.face_attributes["level"] >= 0  # the surface's faces (a solid's skirt and base: level -1)
    assert (got[~ours, :3] == 96).all()
    # each surface face lies inside the input triangle whose colour it has: the one its centroid lies deepest in
    a, b, c = (full.vertices[full.faces[:, k], :2] for k in range(3))
    p = mesh.triangles_center[ours, :2][:, None, :]
    def cross(u, v, w):  # noqa: E306 - twice the signed area of (u, v, w), per centroid and input triangle
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])
    depth = np.minimum(np.minimum(cross(a, b, p), cross(b, c, p)), cross(c, a, p)) * np.sign(cross(a, b, c))
    owner = np.argmax(np.nan_to_num(depth, nan=-np.inf), axis=1)
    walls = mesh.face_attributes["wall"][ours]
    # a wall stands on an input edge shared by two triangles: its colour is one of theirs; a terrace's is its own
    np.testing.assert_array_equal(got[ours][~walls], colours[owner[~walls]])
    assert np.isin(got[ours][walls].view(np.uint32), colours.view(np.uint32)).all()
    assert np.isfinite(full.vertices[full.faces[owner[~walls]]]).all()  # never a dropped face's colour
    back = read_mesh(save_mesh(mesh, tmp_path / "steps.ply"))
    np.testing.assert_array_equal(np.asarray(back.visual.face_colors), got)


def test_a_stack_names_the_later_frame_a_gamma_fails_on():
    """stepped_series of a (T, H, W) stack re-raised a frame's error as it was, on the grounds that every frame of a
    stack shares its isovalues and shape so that the first frame fails: but a γ array made from frame 0's heights
    (NaN at its nodata, as stepped() allows) fails at the first later frame with a height there, and a γ callable may
    fail on one frame's points only. The error ("gamma must lie in [0, 1]; got nan at index (1, 1)") named no frame,
    where the same frames as a list name theirs. Found by stepping frames whose nodata moves. Now frames[k] is named,
    the callable's exception kept as the cause."""
    frames = np.random.default_rng(0).random((3, 5, 6)) * 10
    frames[0, 1, 1] = np.nan
    gamma = np.where(np.isnan(frames[0]), np.nan, 0.5)  # γ per node from frame 0: NaN at its nodata
    series = st.stepped_series(frames, interval=2.0, gamma=gamma, device="cpu")
    assert len(next(series).faces) > 0
    with pytest.raises(st.InvalidInputError, match=r"^frames\[1\]: gamma must lie in \[0, 1\].* at index \(1, 1\)"):
        next(series)

    def fails_late(points):
        if len(points) > 400:  # frame 2's, three times as steep: more vertices
            raise ValueError("out of the camera's range")
        return np.full(len(points), 0.5)

    frames = np.random.default_rng(1).random((3, 5, 6)) * 10
    frames[2] *= 3
    with pytest.raises(st.InvalidInputError, match=r"^frames\[2\]: gamma, a callable .* raised ValueError") as info:
        list(st.stepped_series(frames, interval=2.0, gamma=fails_late, device="cpu"))
    assert isinstance(info.value.__cause__, ValueError)
    # a γ that fits no frame still fails at the first, as stepped() words it
    with pytest.raises(st.InvalidInputError, match=r"^gamma must be shape \(5, 6\)"):
        next(st.stepped_series(frames, interval=2.0, gamma=np.full((4, 4), 0.5), device="cpu"))


def _solid_checks(mesh, surface, floor, values=None):
    """A closed, consistently wound solid whose volume is the stepped surface's over ``floor`` (walls are vertical:
    the terraces' projected area times their mean height), with the level and wall attributes on their faces."""
    assert_valid_mesh(mesh)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.is_volume
    expected = float((projected_area(surface) * (surface.triangles[:, :, 2].mean(axis=1) - floor)).sum())
    assert mesh.volume > 0
    assert mesh.volume == pytest.approx(expected, rel=1e-6, abs=1e-6)
    level, wall = mesh.face_attributes["level"], mesh.face_attributes["wall"]
    assert len(level) == len(wall) == len(mesh.faces)
    n = int((level >= 0).sum())  # the surface's faces first, then the skirts and base (level -1, no wall)
    assert (level[:n] >= 0).all() and (level[n:] == -1).all() and not wall[n:].any()
    area = projected_area(mesh)
    scale = float(np.abs(area).max())
    assert (np.abs(area[wall]) <= 1e-6 * scale).all()  # walls stand vertical
    # terraces face up, but for float32 slivers where a crossing lies within rounding of a node (a float32 step of the
    # local coordinates: 0.004 m at 36 km; -0.03 m² of a 450 m² cell), as for any height just above a threshold
    assert (area[:n][~wall[:n]] >= -1e-4 * scale).all()
    if values is not None:  # γ = 1: a terrace lies on its level's isovalue
        terrace = np.flatnonzero(~wall[:n])
        z = mesh.triangles[terrace, :, 2]
        np.testing.assert_array_equal(z, np.repeat(values[level[terrace]][:, None], 3, axis=1).astype(np.float64))


@settings(max_examples=60, deadline=None)
@given(
    heights=st_.lists(st_.integers(0, 9), min_size=4, max_size=49),
    cols=st_.integers(2, 7),
    interval=st_.sampled_from([2.0, 4.0, 10.0, 1.0]),
    gamma=st_.sampled_from([1.0, 0.0, 0.5]),
    tin=st_.booleans(),
    hole=st_.sampled_from([None, 0, 4, 7]),
)
def test_solid_is_watertight_where_integer_heights_sit_on_thresholds(heights, cols, interval, gamma, tin, hole):
    """A height exactly on a threshold (integer heights, interval 2: 1, 3, 5, ...) got a twin vertex one level down,
    and where the threshold's contour passes through such a node twice (a saddle) four walls shared its vertical
    edge: about a third of small random integer grids gave a solid that was not watertight (the embedded DEM at
    intervals 20, 50 and 100 with base 0 too), with only a warning to shift base. A solid is now stepped from the
    heights with those on a threshold moved up one float32 step (the same level), so no twin arises: watertight,
    consistently wound, with the surface's volume, and no warning."""
    rows = len(heights) // cols
    if rows < 2:
        return
    h = np.array(heights[: rows * cols], np.float32).reshape(rows, cols)
    if hole is not None and hole < h.size:
        h.reshape(-1)[hole] = np.nan
    if np.isnan(h).all() or np.nanmax(h) == np.nanmin(h) and not np.isfinite(h).all():
        return
    terrain = st.heightfield_mesh(h) if tin else h
    values = st.isovalues(st.Terrain.from_heights(h).height_range, interval=interval)
    surface = st.stepped(terrain, interval=interval, gamma=gamma)  # the surface as stepped from the input itself
    if len(surface.faces) == 0:
        return
    # a solid's top is the surface stepped from the heights with those on a threshold moved up by τ (the same level;
    # the walls' crossings next to them move by a few float32 steps of the coordinates, so that an .stl of the solid
    # reads back watertight: tests/test_solid_stl.py): its volume is that surface's
    nudged = stepped_module._off_thresholds(as_terrain(terrain), values)
    moved = nudged.heights.astype(np.float64) - as_terrain(terrain).heights
    moved = moved[np.isfinite(moved)]
    assert ((moved == 0) | (moved > 0) & (moved <= interval / 4)).all()
    surface = st.stepped(nudged, interval=interval, gamma=gamma)
    floor = float(values[0]) - interval
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = st.stepped(terrain, interval=interval, gamma=gamma, solid=True)
    assert mesh.metadata["floor"] == floor
    _solid_checks(mesh, surface, floor, values if gamma == 1.0 else None)
    if gamma == 0.0:  # the (nudged) input surface's volume over the floor, the heightfield triangulated
        inp = nudged.mesh()
        expected = float((projected_area(inp) * (inp.triangles[:, :, 2].mean(axis=1) - floor)).sum())
        assert mesh.volume == pytest.approx(expected, rel=1e-6)


# the embedded DEM's nodes (row, column) where, stepped as given at interval 100, base 0, a threshold's contour passed
# through a node on it twice (a saddle) and four walls shared its vertical edge: all 20 of them
_EMBEDDED_DEM_SADDLES = [(43, 1166), (71, 570), (72, 39), (172, 827), (192, 536), (266, 622), (271, 324), (280, 476),
                         (282, 306), (302, 524), (322, 899), (339, 68), (359, 622), (377, 568), (429, 465), (432, 462),
                         (505, 9), (513, 1166), (553, 1166), (614, 490)]


def test_solid_of_the_embedded_dem_on_thresholds_is_watertight():
    """Big Tujunga's integer heights at interval 100, base 0 (thresholds 50, 150, ...): the solid was not
    watertight (20 vertical edges each shared by four walls, at saddle nodes on a threshold). Checked on a window of
    12 x 12 nodes around each of those nodes, at the DEM's own coordinates (the whole DEM's solid, 4.3 million
    faces, took 8 s of trimesh's checks; stepped as given, each of these windows' solids is not watertight)."""
    dem = st.sample_dem()
    assert np.isin(dem.heights, thresholds_of(st.isovalues(dem.height_range, interval=100.0))).any()
    rows, cols = dem.shape
    (x0, y0), (dx, dy) = dem.origin, dem.spacing
    for r, c in _EMBEDDED_DEM_SADDLES:
        r0, c0 = min(max(r - 5, 0), rows - 12), min(max(c - 5, 0), cols - 12)
        window = st.Terrain.from_heights(dem.heights[r0 : r0 + 12, c0 : c0 + 12], spacing=dem.spacing,
                                         origin=(x0 + c0 * dx, y0 + r0 * dy))
        on = thresholds_of(st.isovalues(window.height_range, interval=100.0))
        assert np.isin(dem.heights[r, c], on), (r, c)  # the saddle node lies on a threshold
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            mesh = st.stepped(window, interval=100.0, solid=True)
        values = np.asarray(mesh.metadata["isovalues"], np.float32)
        # its top: the surface of the heights with those on a threshold moved up by τ (see the test above)
        surface = st.stepped(stepped_module._off_thresholds(window, values), interval=100.0)
        _solid_checks(mesh, surface, mesh.metadata["floor"], values)
        assert mesh.vertices[:, 2].max() == surface.vertices[:, 2].max()


def _nodata_face_coloured_tin() -> tuple[trimesh.Trimesh, st.Terrain]:
    """A face-coloured TIN whose first face touches a NaN height (dropped): its kept faces are rows 1 and 2."""
    points = np.array([[0, 0, 0], [1, 0, 1], [0, 1, 2], [1, 1, np.nan], [2, 0, 1.5], [2, 1, 2.5]], float)
    faces = np.array([[1, 3, 2], [0, 1, 2], [1, 4, 5]])
    colours = np.array([[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]], np.uint8)
    mesh = trimesh.Trimesh(points, faces, face_colors=colours, process=False)
    return mesh, st.Terrain.from_mesh(mesh)


def test_replaced_tin_keeps_its_face_colours_rows():
    """dataclasses.replace of a face-coloured TIN with nodata faces dropped rebuilt face_index from the kept faces
    (0, 1) while visual.face_colors kept a row per face of the mesh given: every step took the colour of the face
    before it, silently. The given face_index is composed; without one, a visual whose rows are not one per face is
    refused."""
    import dataclasses

    _, tin = _nodata_face_coloured_tin()
    np.testing.assert_array_equal(tin.face_index, [1, 2])
    replaced = dataclasses.replace(tin, source="survey")
    np.testing.assert_array_equal(replaced.face_index, [1, 2])
    want = np.asarray(st.stepped(tin, interval=0.5).visual.face_colors)
    np.testing.assert_array_equal(np.asarray(st.stepped(replaced, interval=0.5).visual.face_colors), want)
    assert not (want[:, :3] == [255, 0, 0]).all(axis=1).any()  # the dropped face's red is on no step
    with pytest.raises(st.InvalidInputError, match=r"one visual.face_colors row per face \(2\).*got 3 rows"):
        st.Terrain(kind="tin", heights=None, points=tin.points, faces=tin.faces, visual=tin.visual)
    with pytest.raises(st.InvalidInputError, match="face_index must hold"):
        dataclasses.replace(tin, face_index=np.array([1, 3]))


def test_face_coloured_tin_counts_its_face_sources_against_the_budget():
    """A face-coloured TIN's per-face sources (int64) and carried RGBA were allocated before the budget check and
    not counted: a budget covering only the vertices and faces let them through. Now 12 bytes per face more."""
    _, tin = _nodata_face_coloured_tin()
    mesh = st.stepped(tin, interval=0.5)
    vertex_bytes, face_bytes = stepped_module._VERTEX_BYTES, stepped_module._FACE_BYTES
    bare = len(mesh.vertices) * vertex_bytes + len(mesh.faces) * face_bytes
    with pytest.raises(st.OutputTooLargeError, match="memory_budget"):
        st.stepped(tin, interval=0.5, memory_budget=bare)
    budget = bare + len(mesh.faces) * stepped_module._FACE_SOURCE_BYTES
    again = st.stepped(tin, interval=0.5, memory_budget=budget)
    np.testing.assert_array_equal(np.asarray(again.visual.face_colors), np.asarray(mesh.visual.face_colors))


def test_short_detached_face_colours_are_refused_before_stepping():
    """A TIN whose visual is a ColorVisuals(face_colors=...) built apart from the mesh keeps the rows given: with
    fewer rows than faces, stepped() raised numpy's IndexError after the kernels ran (and stepped_series too). Now
    an InvalidInputError naming visual.face_colors, before the passes; colors= still steps it."""
    points = np.array([[0, 0, 0], [1, 0, 1], [0, 1, 2], [1, 1, 3.0]])
    visual = trimesh.visual.ColorVisuals(face_colors=np.array([[255, 0, 0, 255]], np.uint8))
    mesh = trimesh.Trimesh(points, [[0, 1, 2], [1, 3, 2]], visual=visual, process=False)
    assert len(mesh.visual.face_colors) == 1
    message = r"visual.face_colors must hold one RGBA row per face \(at least 2\).*got 1 row"
    with pytest.raises(st.InvalidInputError, match=message):
        st.stepped(mesh, interval=0.5)
    with pytest.raises(st.InvalidInputError, match=message):
        list(st.stepped_series([mesh], interval=0.5))
    assert len(st.stepped(mesh, interval=0.5, colors="terrain").faces) > 0


def test_solid_does_not_warn_for_heights_no_triangle_uses():
    """solid=True nudged, and warned for, every height on a threshold whose next float32 value is another
    threshold, a TIN's unused point and a grid node isolated by nodata included: a warning that the solid may leak
    where it has no vertex. Only the heights the surface uses are considered now; the solids are unchanged."""
    levels = np.array([1.0, 1.9999991655349731, 1.9999992847442627, 1.9999995231628418, 3.0], np.float32)
    low, stuck = (float(x) for x in thresholds_of(levels)[:2])
    assert np.nextafter(np.float32(stuck), np.float32(np.inf)) in thresholds_of(levels)  # it would warn if used
    points = np.array([[0, 0, 1], [1, 0, low], [0, 1, 2.5], [1, 1, 3.0]])
    faces = [[0, 1, 2], [1, 3, 2]]
    stray = trimesh.Trimesh(np.vstack([points, [5, 5, stuck]]), faces, process=False)
    grid = np.array([[1, low, np.nan, stuck], [2.5, 3.0, np.nan, np.nan]], np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tin_solid = st.stepped(stray, levels=levels, solid=True)
        grid_solid = st.stepped(grid, levels=levels, solid=True)
    bare = st.stepped(trimesh.Trimesh(points, faces, process=False), levels=levels, solid=True)
    np.testing.assert_array_equal(tin_solid.faces, bare.faces)
    np.testing.assert_array_equal(tin_solid.vertices, bare.vertices)
    assert tin_solid.is_watertight and grid_solid.is_watertight


def test_grid_past_the_int32_vertex_slots_is_refused_before_the_count_pass(monkeypatch):
    """A grid's vertex pass (kernels/stepped.py, count_grid and its readers) keeps 4 int32-indexed slots a node at
    ``4 * n``: from 2^29 nodes (a 23171² DEM, 2 GiB of float32 heights, under the default budget) that product
    wrapped and count_grid streamed its prefixes to negative offsets (memory written outside the slot array) before
    any total or budget was checked. Such a grid is refused up front; the guard is checked at its boundary with the
    limit lowered (no 2^29-node grid)."""
    import stepterrain.stepped as stepped_module

    heights = np.add.outer(np.arange(20.0), np.arange(30.0))
    slots = 4 * heights.size
    monkeypatch.setattr(stepped_module, "_MAX_INT32", slots - 1)
    with pytest.raises(st.OutputTooLargeError, match=r"20 x 30 nodes.*2,400 int32 vertex slots"):
        st.stepped(heights, interval=20.0, device="cpu")
    monkeypatch.setattr(stepped_module, "_MAX_INT32", slots)
    assert len(st.stepped(heights, interval=20.0, device="cpu").faces) > 0


def _rolled_triangles(mesh):
    """The mesh's triangles as sorted rows of corner coordinates, each rotated to start at its smallest corner
    (winding kept): an order-free comparison of two meshes' faces."""
    tri = mesh.vertices[mesh.faces]
    _, rank = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)  # corners ranked by their coordinates
    first = np.argmin(rank.reshape(-1, 3), axis=1)
    rolled = tri[np.arange(len(tri))[:, None], (first[:, None] + np.arange(3)) % 3].reshape(-1, 9)
    return rolled[np.lexsort(rolled.T[::-1])]


@settings(max_examples=12, deadline=None)
@given(seed=st_.integers(0, 2**31 - 1), solid=st_.booleans())
def test_a_tin_with_faces_wound_either_way_steps_as_the_one_wound_up(seed, solid):
    """A TIN some of whose faces are wound clockwise and the others counter-clockwise (two tiles of a DEM from
    exporters of opposite conventions, merged; a triangle soup whose faces were flipped one by one) projects
    one-to-one onto the xy plane, yet was refused as folding over ("wound against the rest", with advice on
    decimation): only a mesh wound all one way was turned up. Faces wound down that overlap no other face now turn
    up, and the TIN steps as the one wound consistently; real folds are still refused (they overlap their
    neighbours: test_folded_faces_are_counted_named_placed_and_the_hints_in_the_refusal_work)."""
    rng = np.random.default_rng(seed)
    heights = st.sample_dem().heights[::8, ::8][:24, :20].astype(np.float64)
    up = st.heightfield_mesh(heights, spacing=(30.0, -30.0), origin=(376000.0, 3807000.0))
    down = rng.random(len(up.faces)) < rng.choice([0.1, 0.5, 0.9])
    centre = up.triangles_center[:, 0] < np.median(up.vertices[:, 0])
    down = down if rng.random() < 0.5 else centre  # single faces, or a whole tile
    faces = np.where(down[:, None], up.faces[:, ::-1], up.faces)
    mixed = trimesh.Trimesh(up.vertices, faces, process=False)
    if rng.random() < 0.3:  # as an STL file holds it: three points of its own per face
        mixed = trimesh.Trimesh(up.vertices[faces].reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3),
                                process=False)
    want = st.stepped(up, interval=50.0, solid=solid)
    got = st.stepped(mixed, interval=50.0, solid=solid)
    np.testing.assert_array_equal(_rolled_triangles(got), _rolled_triangles(want))
    assert_valid_mesh(got)
    if solid:
        assert got.is_watertight and got.volume == pytest.approx(want.volume, rel=1e-12)


def test_a_count_of_levels_just_over_the_limit_is_given_exactly():
    """interval=1 over heights [0, 1e6] gives 1,000,001 levels, one over the limit: the refusal rounded the count to
    three digits, "gives 1e+06 levels; at most 1,000,000 are supported", which reads as within it. A count under a
    billion is now written out; larger ones stay rounded (test_stepped: "gives 1e+300 levels")."""
    heights = np.array([[0.0, 5e5], [2.5e5, 1e6]])
    with pytest.raises(st.InvalidInputError, match=r"gives 1,000,001 levels; at most 1,000,000 are supported"):
        st.stepped(heights, interval=1.0)
    with pytest.raises(st.InvalidInputError, match=r"gives 2,000,001 levels; at most 1,000,000 are supported"):
        st.isovalues((0.0, 1e6), interval=0.5)
    assert len(st.isovalues((0.0, 999_999.0), interval=1.0)) == 1_000_000


@pytest.mark.parametrize("moved", [(1.4, 0.3), (1.0 + 1e-6, 1e-6)], ids=["across", "onto its neighbour"])
@pytest.mark.parametrize("kind", ["welded", "soup", "coloured soup"])
def test_a_fold_is_refused_however_its_points_are_shared(kind, moved):
    """Faces wound down turn up only where no face then runs an edge of another the same way in xy (a fold does,
    with the neighbour it folds over): a triangle soup whose points stay apart (one vertex colour per corner) shares
    no edge by index, and a fold there, too small for the overlap check, was stepped when wound faces were turned."""
    base = st.heightfield_mesh(np.random.default_rng(1).random((9, 12)) * 3.0)
    points = base.vertices.copy()
    points[4 * 12 + 5, :2] += moved
    mesh = trimesh.Trimesh(points, base.faces, process=False)
    if kind != "welded":
        soup = points[base.faces].reshape(-1, 3)
        colours = np.random.default_rng(0).integers(0, 255, (len(soup), 4)).astype(np.uint8) if kind != "soup" else None
        mesh = trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), vertex_colors=colours, process=False)
    with pytest.raises(st.InvalidInputError, match=r"faces with finite heights fold over \(wound against the rest\)"):
        st.stepped(mesh, interval=0.5)


@pytest.mark.parametrize("half", [2e38, 1e39])
def test_a_lens_extent_wider_than_float32_is_refused_not_sampled_at_its_corner(half):
    """A lens extent whose span (or whose corner relative to the terrain) is beyond float32 was sampled wrongly,
    silently: sample_lens takes the extent's lower corner and size in float32, so a span of 4e38 became inf and every
    vertex read the mask's first column ((p - lower) / inf = 0; at ±1e39 the corner is -inf too, inf / inf = NaN),
    where the mask's centre lies over the terrain. Found by the fresh-eyes hunt (lenses at huge coordinates)."""
    heights = np.arange(20.0).reshape(4, 5)
    mask = np.array([[0.0, 1.0], [1.0, 0.0]], np.float32)  # 0.5 at its centre, over the terrain
    refused = r"^gamma: the lens extent .* must be at most 3.4028235e\+38 wide and tall .*got .*e\+3[89] wide"
    with pytest.raises(st.InvalidInputError, match=refused):
        st.stepped(heights, interval=2.0, gamma=st.Lens(mask, (-half, half, -half, half)))
    # within float32 the same lens reads its centre: γ = 0.5 at every vertex, as the scalar gives it
    wide = st.stepped(heights, interval=2.0, gamma=st.Lens(mask, (-1e38, 1e38, -1e38, 1e38)))
    np.testing.assert_array_equal(wide.vertices, st.stepped(heights, interval=2.0, gamma=0.5).vertices)


@pytest.mark.parametrize("corner, edge", [((1e39, 0.0), 0.0), ((-1e39, 0.0), 1.0), ((0.0, 1e39), 0.0),
                                          ((0.0, -1e39), 1.0)])
def test_a_lens_far_beyond_float32_but_narrow_is_sampled_at_its_edge_not_refused(corner, edge):
    """A lens whose corner lies beyond float32 from the terrain, but whose width and height float32 holds, is a valid
    lens wholly to one side of the terrain: every vertex takes the mask's edge facing it (the sampler clamps). The
    float32-reach check refused it with the too-wide lenses, though sample_lens gets it right (its corner ±inf in
    float32, (p - lower) / size = ∓inf, clamped to the facing edge); only the width and height must fit float32."""
    heights = np.arange(20.0).reshape(4, 5)
    mask = np.array([[0.0, 1.0], [0.0, 1.0]], np.float32)  # γ 0 on its low-x edge, 1 on its high-x edge
    x, y = corner
    if x == 0.0:
        mask = np.ascontiguousarray(mask.T)  # γ 0 on its low-y edge (row 0), 1 on its high-y edge
    span = 1e30  # within float32 (and within float64's precision at 1e39)
    lens = st.Lens(mask, (x, x + span, y, y + span))
    expected = st.stepped(heights, interval=2.0, gamma=edge).vertices
    np.testing.assert_array_equal(st.stepped(heights, interval=2.0, gamma=lens).vertices, expected)
    (frame,) = st.stepped_series(heights[None], interval=2.0, gamma=lens)
    np.testing.assert_array_equal(frame.vertices, expected)


@pytest.mark.parametrize("case", ["lone pixel", "unreferenced point", "welded copy"])
def test_per_node_gamma_may_be_nan_where_no_vertex_reads_it(case):
    """A per-node γ NaN was taken only where the height is nodata ("it gives no vertex"), but a grid node with a height
    whose every triangle touches nodata (a lone pixel in a void of a real DEM), a TIN point on no face (left by
    ``mesh.update_faces``, as the refusal of degenerate faces suggests) and a point welded into an earlier copy (a
    triangle soup: γ "is read at the first of such points") give no vertex either: NaN there was refused ("got nan at
    index"), naming a node the mesh does not hold. A γ raster whose nodata covers the void, lone pixel included, is
    such a γ. Now NaN at any node no vertex reads is taken; the mesh is the one any value there gives."""
    heights = st.sample_dem().heights[:40, :50].astype(np.float64)
    gamma = np.clip((heights - heights.min()) / np.ptp(heights), 0.0, 1.0)
    if case == "lone pixel":
        heights[10:20, 10:20] = np.nan
        heights[15, 15] = 1000.0  # a lone pixel in the void: a height, on no triangle
        gamma[10:20, 10:20] = np.nan  # the γ raster's own nodata: the void as drawn
        terrain = heights
        unread = (15, 15)
    else:
        mesh = st.heightfield_mesh(heights)
        gamma = gamma.reshape(-1)
        if case == "unreferenced point":
            unread = 7 * 50 + 9  # the faces around node (7, 9) dropped: its point stays, on no face
            mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[~(mesh.faces == unread).any(axis=1)], process=False)
        else:  # a soup: one point per corner, welded where x, y and z coincide
            corners = mesh.faces.reshape(-1)
            mesh = trimesh.Trimesh(mesh.vertices[corners], np.arange(len(corners)).reshape(-1, 3), process=False)
            gamma = gamma[corners]
            unread = int(np.flatnonzero(corners == corners[-1])[-1])
            assert unread != int(np.flatnonzero(corners == corners[-1])[0])  # a later copy of a point
        terrain = mesh
        gamma[unread] = np.nan
    filled = st.stepped(terrain, interval=50.0, gamma=np.where(np.isnan(gamma), 0.25, gamma))
    other = st.stepped(terrain, interval=50.0, gamma=np.where(np.isnan(gamma), 0.75, gamma))
    np.testing.assert_array_equal(filled.vertices, other.vertices)  # the value there is read by no vertex
    mesh = st.stepped(terrain, interval=50.0, gamma=gamma)
    np.testing.assert_array_equal(mesh.vertices, filled.vertices)
    np.testing.assert_array_equal(mesh.faces, filled.faces)
    (frame,) = st.stepped_series([terrain], interval=50.0, gamma=gamma)
    np.testing.assert_array_equal(frame.vertices, filled.vertices)
    if case == "lone pixel":  # a stack too
        (frame,) = st.stepped_series(heights[None], interval=50.0, gamma=gamma)
        np.testing.assert_array_equal(frame.vertices, filled.vertices)
    # NaN at a node the surface uses is still refused, with its index
    gamma[(0,) * gamma.ndim] = np.nan
    at = "0," if gamma.ndim == 1 else "0, 0"
    with pytest.raises(st.InvalidInputError, match=rf"^gamma must lie in \[0, 1\] .*; got nan at index \({at}\)$"):
        st.stepped(terrain, interval=50.0, gamma=gamma)


def test_nice_interval_refuses_a_bad_target_or_height_range_by_name():
    """nice_interval (public in stepterrain.stepped, the CLI's and batch's default interval) divided by ``target``
    unchecked: target=0 raised a bare ZeroDivisionError and target=-1 "math domain error" from math.log10, naming no
    argument; a reversed, NaN or infinite height range returned 1.0 without a word (an interval of 1 for heights it
    never looked at). Both are refused now as isovalues() refuses such a range; a flat range (min == max) still
    gives 1.0, and the CLI's ranges (finite, min <= max) are unchanged."""
    from stepterrain.stepped import nice_interval

    for target in (0, -1, np.nan, True, "15"):
        with pytest.raises(st.InvalidInputError, match=r"^target must be"):
            nice_interval((0.0, 100.0), target)
    for height_range in ((10.0, 0.0), (np.nan, 1.0), (0.0, np.inf), (1.0,), "ab"):
        with pytest.raises(st.InvalidInputError, match=r"^height_range must be"):
            nice_interval(height_range)
    assert nice_interval((5.0, 5.0)) == 1.0
    assert nice_interval((315.0, 2295.0)) == 100.0 and nice_interval((0.0, 100.0), 1.5) == 50.0
    heights = st.sample_dem().height_range
    assert len(st.isovalues(heights, interval=nice_interval(heights))) in range(10, 25)


def _nodes_on_finite_triangles(heights: np.ndarray) -> np.ndarray:
    """Reference for the nodes a stepped grid mesh holds: those of a triangle (n00, n01, n11) or (n00, n11, n10)
    with three finite heights, cell by cell."""
    rows, cols = heights.shape
    used = np.zeros(heights.shape, dtype=bool)
    for r in range(rows - 1):
        for c in range(cols - 1):
            for tri in (((r, c), (r, c + 1), (r + 1, c + 1)), ((r, c), (r + 1, c + 1), (r + 1, c))):
                if all(np.isfinite(heights[n]) for n in tri):
                    for n in tri:
                        used[n] = True
    return used


@settings(max_examples=25, deadline=None)
@given(seed=st_.integers(0, 2**31 - 1), kind=st_.sampled_from(["grid", "tin", "solid", "series"]))
def test_per_node_gamma_nan_is_taken_exactly_where_no_vertex_reads_it(seed, kind):
    """Property of the per-node γ NaN rule: on random grids with voids (lone pixels included), NaN at every node the
    mesh does not hold (reference: the nodes of a triangle with three finite heights, cell by cell) gives the mesh
    any value there gives, with no NaN vertex (grid, TIN with NaN z, solid, a two-frame stack whose frames void
    different nodes); NaN at one node the mesh holds is refused naming that node (in a stack, the frame)."""
    rng = np.random.default_rng(seed)
    rows, cols = int(rng.integers(3, 9)), int(rng.integers(3, 9))
    heights = rng.uniform(0.0, 10.0, (rows, cols))
    heights[rng.random((rows, cols)) < rng.uniform(0.1, 0.5)] = np.nan
    frames = [heights]
    if kind == "series":
        other = rng.uniform(0.0, 10.0, (rows, cols))
        other[rng.random((rows, cols)) < rng.uniform(0.1, 0.5)] = np.nan
        frames.append(other)
    used = [_nodes_on_finite_triangles(h) for h in frames]
    if not all(u.any() for u in used):
        return  # a frame with no triangle: refused whatever γ is
    unused = ~np.logical_or.reduce(used)
    gamma = rng.uniform(0.0, 1.0, (rows, cols))
    gamma[unused] = np.nan

    def run(g):
        if kind == "series":
            return [m.vertices for m in st.stepped_series(np.stack(frames), interval=2.0, gamma=g)]
        if kind == "tin":
            mesh = st.heightfield_mesh(np.nan_to_num(heights))
            mesh.vertices[:, 2] = heights.reshape(-1)
            return [st.stepped(mesh, interval=2.0, gamma=g.reshape(-1)).vertices]
        return [st.stepped(heights, interval=2.0, gamma=g, solid=kind == "solid").vertices]

    low, high, got = run(np.where(unused, 0.25, gamma)), run(np.where(unused, 0.75, gamma)), run(gamma)
    for a, b, c in zip(low, high, got, strict=True):
        assert np.isfinite(c).all()
        np.testing.assert_array_equal(a, b)  # no vertex reads those nodes
        np.testing.assert_array_equal(c, a)
    k = int(rng.integers(len(frames)))
    at = tuple(int(i) for i in np.argwhere(used[k] & ~used[0])[0]) if k and (used[k] & ~used[0]).any() else None
    if at is None:
        k = 0
        candidates = np.argwhere(used[0])
        at = tuple(int(i) for i in candidates[rng.integers(len(candidates))])
    gamma[at] = np.nan
    index = f"{at[0] * cols + at[1]}," if kind == "tin" else f"{at[0]}, {at[1]}"
    prefix = rf"frames\[{k}\]: " if k else ""
    with pytest.raises(st.InvalidInputError, match=rf"^{prefix}gamma must lie in \[0, 1\] .*; got nan at index "
                                                   rf"\({index}\)$"):
        run(gamma)


@pytest.mark.parametrize(
    ("values", "uniform"),
    [
        (st.isovalues((0.0, 100.0), interval=0.005), True),  # 20,001 levels: level_of's estimate-and-correct walk
        (st.isovalues((0.0, 100.0), interval=2.0), True),  # 51: the CPU's vector path (at most 64 thresholds)
        (np.geomspace(1.0, 100.0, 5000), False),  # the binary search
    ],
    ids=["uniform", "vector", "binary"],
)
def test_a_nodata_node_takes_level_0_on_every_quantize_path(device, values, uniform):
    """level_of (kernels/stepped.py) gives NaN level 0, but on the estimate-and-correct path of uniform levels (every
    ``interval=``; on the CPU above 64 thresholds, on CUDA always) a NaN estimate started at 0 and NaN compares false:
    the walk stepped up through every threshold and back down again, 2 x levels comparisons a nodata node, before
    returning 0. It now returns 0 at once (the speed-up is measured by benchmarks/run_nodata_levels.py, not here).
    Every path still gives a nodata node level 0 and every other height the count of thresholds at or below it."""
    dev = resolve_device(device)
    values = np.asarray(values, np.float32)
    iso = stepped_module._build_isovalue_struct(values, dev)
    assert iso.uniform == int(uniform)
    thresholds = thresholds_of(values)
    finite = np.concatenate([thresholds, (thresholds[:-1] + thresholds[1:]) / 2, np.nextafter(thresholds, -np.inf),
                             [-np.inf, -1e30, values[0], values[-1], 1e30, np.inf]]).astype(np.float32)
    heights = np.full(2 * len(finite), np.nan, np.float32)  # every other node nodata
    heights[1::2] = finite
    levels = wp.zeros(len(heights), dtype=wp.int32, device=dev)
    launch_chunked(stepped_kernels.quantize_levels, n=len(heights), inputs=[wp.array(heights, device=dev), iso],
                   outputs=[levels], device=dev)
    got = levels.numpy()
    assert not got[0::2].any()  # NaN: level 0
    np.testing.assert_array_equal(got[1::2], np.searchsorted(thresholds, finite, side="right"))


@pytest.mark.parametrize("hole", [False, True], ids=["no-nodata", "nodata"])
def test_a_float64_stack_shares_the_isovalues_its_float32_frames_are_stepped_with(hole):
    """stepped_series of a (T, H, W) stack took its shared isovalues from the float64 heights, while every frame is
    stepped from its float32 heights (a Terrain's): a height 1e-9 above an isovalue (or below one) rounds onto it in
    float32, yet added a level above (below) that no vertex reaches, so the frame's colours by level, its level
    indices and its recorded isovalues differed from stepped() of the same frame and from the stack as float32. The
    range is now the float32 heights'."""
    heights = st.sample_dem().heights[:40, :50].astype(np.float64)
    heights = heights - heights.max() + 1000.0  # the highest height exactly on the isovalue 1000
    lo = float(heights.min())
    heights[heights == heights.max()] += 1e-9  # float32 rounds it back onto 1000
    heights[heights == lo] = np.floor(lo / 50.0) * 50.0 - 1e-9  # and the lowest onto an isovalue from below
    if hole:
        heights[10:14, 20:25] = np.nan
    stack = np.stack([heights, heights - 50.0])
    got = list(st.stepped_series(stack, interval=50.0, colors="viridis"))
    want = list(st.stepped_series(stack.astype(np.float32), interval=50.0, colors="viridis"))
    for a, b in zip(got, want, strict=True):
        assert a.metadata["isovalues"] == b.metadata["isovalues"]
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.face_attributes["level"], b.face_attributes["level"])
        np.testing.assert_array_equal(a.visual.vertex_colors, b.visual.vertex_colors)
    single = next(st.stepped_series(heights[None], interval=50.0, colors="viridis"))
    alone = st.stepped(heights, interval=50.0, colors="viridis")
    assert single.metadata["isovalues"] == alone.metadata["isovalues"]
    np.testing.assert_array_equal(single.visual.vertex_colors, alone.visual.vertex_colors)


@pytest.mark.parametrize("stray", [(5.0, 5.0, 1e39), (1e300, 5.0, 1.0), (5.0, -1e300, 1.0)],
                         ids=["z-beyond-float32", "x-beyond-float32", "y-beyond-float32"])
def test_a_point_on_no_face_beyond_float32_steps_without_a_numpy_warning(stray):
    """A point no face uses does not matter (Terrain.from_mesh refuses coordinates beyond float32 only on kept faces):
    its z cast to the float32 heights, and its x or y to the float32 local points, each raised numpy's "overflow
    encountered in cast" RuntimeWarning (an error where warnings are, as under pytest's -W error), from a TIN that
    then stepped exactly as the TIN without the point (and Terrain(kind="tin", ...) given its heights warned comparing
    them with the points' z). Now it steps silently, as that TIN does."""
    base = st.heightfield_mesh(st.sample_dem().heights[:12, :15], spacing=(30.0, 30.0))
    points = np.vstack([base.vertices + [376000.0, 3790000.0, 0.0], [stray]])
    with_stray = trimesh.Trimesh(points, base.faces, process=False)
    without = trimesh.Trimesh(points[:-1], base.faces, process=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = st.stepped(with_stray, interval=50.0, solid=True)
        terrain = st.Terrain(kind="tin", heights=as_terrain(with_stray).heights, points=points, faces=base.faces)
    want = st.stepped(without, interval=50.0, solid=True)
    np.testing.assert_array_equal(got.vertices, want.vertices)
    np.testing.assert_array_equal(got.faces, want.faces)
    assert terrain.height_range == as_terrain(without).height_range


def test_carried_vertex_colours_are_the_input_colours_interpolated_at_every_output_vertex():
    """Issue §3: a TIN's vertex colours are carried onto the steps by the crossings' β. The tests before checked the
    nodes' colours only; here every output vertex (wall bottoms and tops, twins, nodes) of a Delaunay TIN of the
    embedded DEM at UTM coordinates, with a hole, takes the input's colour interpolated at its xy: colours affine in
    x and y, so that the interpolation over any triangle gives them (to the bytes' rounding), whatever γ."""
    from scipy.spatial import Delaunay

    dem = st.sample_dem()
    rng = np.random.default_rng(4)
    rows, cols = rng.integers(0, 120, 600), rng.integers(0, 160, 600)
    x0, y0 = dem.origin
    points = np.unique(np.column_stack([x0 + cols * dem.spacing[0], y0 + rows * dem.spacing[1],
                                        dem.heights[rows, cols]]), axis=0)
    faces = Delaunay(points[:, :2]).simplices
    centre = points[faces, :2].mean(axis=1)
    middle = points[:, :2].mean(axis=0)
    faces = faces[np.abs(centre - middle).max(axis=1) > 600.0]  # a hole in the middle
    lo, span = points[:, :2].min(axis=0), np.ptp(points[:, :2], axis=0)

    def colour_at(xy):
        s = (xy - lo) / span
        return np.column_stack([255 * s[:, 0], 255 * s[:, 1], 255 * (1 - s[:, 0]), 127 + 100 * s[:, 1]])

    tin = trimesh.Trimesh(points, faces, process=False)
    tin.visual = trimesh.visual.ColorVisuals(tin, vertex_colors=np.round(colour_at(points[:, :2])).astype(np.uint8))
    for gamma in (1.0, 0.4):
        mesh = st.stepped(tin, interval=25.0, gamma=gamma)
        assert mesh.face_attributes["wall"].any()
        got = mesh.visual.vertex_colors.astype(np.float64)
        assert np.abs(got - colour_at(mesh.vertices[:, :2])).max() <= 1.0 + 1e-6


@pytest.mark.parametrize("soup", [False, True], ids=["welded", "soup"])
def test_short_detached_vertex_colours_are_refused_before_stepping(soup):
    """As face colours and UVs are: a TIN whose visual is a ColorVisuals(vertex_colors=...) built apart from the mesh
    keeps the rows given, and with fewer rows than the points its faces use, Terrain.from_mesh (welding coincident
    points by position and colour) raised numpy's IndexError, so stepped(), stepped_series() and every other use
    of such a TIN failed with it. Now the terrain is built (a soup welded by position alone) and stepped() refuses
    the colours it cannot carry, naming visual.vertex_colors, before the passes; colors= still steps it (as one
    welded surface), and rows beyond the points are still fine."""
    mesh = st.heightfield_mesh(st.sample_dem().heights[:6, :7], spacing=(30.0, 30.0))
    if soup:
        mesh.unmerge_vertices()
    short = trimesh.visual.ColorVisuals(vertex_colors=np.full((5, 4), 200, np.uint8))
    mesh.visual = short
    assert len(mesh.visual.vertex_colors) == 5
    st.Terrain.from_mesh(mesh)
    message = rf"visual.vertex_colors must hold one RGBA row per vertex \(at least {len(mesh.vertices)}\).*got 5 rows"
    with pytest.raises(st.InvalidInputError, match=message):
        st.stepped(mesh, interval=20.0)
    with pytest.raises(st.InvalidInputError, match=message):
        list(st.stepped_series([mesh], interval=20.0))
    coloured = st.stepped(mesh, interval=20.0, colors="terrain")
    welded = st.stepped(st.heightfield_mesh(st.sample_dem().heights[:6, :7], spacing=(30.0, 30.0)), interval=20.0)
    assert len(coloured.vertices) == len(welded.vertices) and len(coloured.faces) == len(welded.faces)
    mesh.visual = trimesh.visual.ColorVisuals(vertex_colors=np.full((len(mesh.vertices) + 3, 4), 200, np.uint8))
    assert (st.stepped(mesh, interval=20.0).visual.vertex_colors == 200).all()


def test_short_vertex_colours_are_refused_where_the_welded_faces_use_only_points_with_a_row():
    """A soup with short detached vertex colours is welded by position alone; the refusal counted the rows the welded
    faces need, so a soup whose last points coincide with earlier ones stepped, a given colour merged into a
    coincident point's: here point 3 (white) lies on point 1 (green) and point 5, with no row, on point 2; six rows
    keep 1 and 3 apart (both colours at (10, 0)), five stepped all green there. Now short colours are refused."""
    points = np.array([[0, 0, 0], [10, 0, 5], [0, 10, 30], [10, 0, 5], [10, 10, 40], [0, 10, 30]], dtype=np.float64)
    rows = np.array([[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [255, 255, 255, 255], [9, 9, 9, 255],
                     [0, 0, 255, 255]], dtype=np.uint8)
    mesh = trimesh.Trimesh(points, [[0, 1, 2], [3, 4, 5]], process=False)
    mesh.visual = trimesh.visual.ColorVisuals(vertex_colors=rows)
    full = st.stepped(mesh, interval=10.0)
    at = np.linalg.norm(full.vertices[:, :2] - [10.0, 0.0], axis=1) < 1e-9
    assert {tuple(c) for c in full.visual.vertex_colors[at].tolist()} == {(0, 255, 0, 255), (255, 255, 255, 255)}
    mesh.visual = trimesh.visual.ColorVisuals(vertex_colors=rows[:5])
    with pytest.raises(st.InvalidInputError, match=r"visual.vertex_colors .*\(at least 6\).*got 5 rows"):
        st.stepped(mesh, interval=10.0)
    assert len(st.stepped(mesh, interval=10.0, colors="terrain").vertices) < len(full.vertices)  # welded


def test_a_grid_terrain_carries_its_vertex_colours_and_short_ones_are_refused():
    """The refusal of short vertex colours read a TIN's point_used, which a grid Terrain has not (an IndexError for
    every grid carrying vertex colours); a grid's rows are its nodes: all of them carried, fewer refused."""
    heights = st.sample_dem().heights[:20, :24]
    rgba = np.zeros((heights.size, 4), np.uint8)
    rgba[:, 0], rgba[:, 3] = np.arange(heights.size) % 256, 255
    terrain = st.Terrain(kind="grid", heights=heights, visual=trimesh.visual.ColorVisuals(vertex_colors=rgba))
    mesh = st.stepped(terrain, interval=50.0)
    at_node = np.all(mesh.vertices[:, :2] == np.round(mesh.vertices[:, :2]), axis=1)  # spacing 1: nodes' xy whole
    rows, cols = mesh.vertices[at_node, 1].astype(int), mesh.vertices[at_node, 0].astype(int)
    np.testing.assert_array_equal(mesh.visual.vertex_colors[at_node, 0], rgba[rows * heights.shape[1] + cols, 0])
    short = st.Terrain(kind="grid", heights=heights, visual=trimesh.visual.ColorVisuals(vertex_colors=rgba[:-1]))
    with pytest.raises(st.InvalidInputError, match=rf"^terrain visual.vertex_colors .*\(at least {heights.size}\)"):
        st.stepped(short, interval=50.0)


def test_a_grid_terrain_carries_its_uvs_and_a_uv_row_short_is_refused():
    """The check of carried texture coordinates took len(terrain.points), None on a grid Terrain: a TypeError for
    every grid with a TextureVisuals. A grid's UVs are one row per node: carried (a node's output vertex keeps its
    row), and one row short refused naming visual.uv."""
    heights = st.sample_dem().heights[:20, :24]
    rows, cols = np.divmod(np.arange(heights.size), heights.shape[1])
    uv = np.column_stack([cols / (heights.shape[1] - 1), rows / (heights.shape[0] - 1)])
    terrain = st.Terrain(kind="grid", heights=heights, visual=trimesh.visual.TextureVisuals(uv=uv))
    mesh = st.stepped(terrain, interval=50.0)
    at_node = np.all(mesh.vertices[:, :2] == np.round(mesh.vertices[:, :2]), axis=1)  # spacing 1: nodes' xy whole
    node = mesh.vertices[at_node, 1].astype(int) * heights.shape[1] + mesh.vertices[at_node, 0].astype(int)
    np.testing.assert_allclose(mesh.visual.uv[at_node], uv[node], atol=1e-12)
    short = st.Terrain(kind="grid", heights=heights, visual=trimesh.visual.TextureVisuals(uv=uv[:-1]))
    with pytest.raises(st.InvalidInputError, match=rf"^terrain visual.uv .*shape \({heights.size}, 2\)"):
        st.stepped(short, interval=50.0)


@pytest.mark.parametrize("kind", ["uv", "colors", "soup"])
def test_a_solid_of_a_tin_with_seams_in_its_uvs_or_colours_has_no_skirt_inside(kind, tmp_path):
    """A TIN's points that coincide are welded only where their vertex colours or UVs agree too (the surface keeps
    its seams), and solid=True closed that surface: it stood a skirt down to the base on both sides of every seam
    (a glTF of two textured primitives, an OBJ's UV seam, a soup with a colour per corner: a prism under every face),
    two or more bodies back to back whose .stl, its corners merged by position, read back not watertight. A solid is
    now closed over the surface welded by position: one body, the solid of the seamless TIN, watertight as .stl."""
    heights = np.asarray(st.sample_dem().heights[:9, :11], np.float64)
    tin = st.heightfield_mesh(heights, spacing=(30.0, 30.0), origin=(376000.0, 3807000.0))
    n = len(tin.vertices)
    points = np.vstack([tin.vertices, tin.vertices])
    faces = tin.faces.copy()
    if kind == "soup":  # every corner a point of its own
        points = tin.vertices[faces.reshape(-1)]
        faces = np.arange(len(points)).reshape(-1, 3)
    else:  # the faces right of a seam use the second copy of the points
        right = tin.triangles_center[:, 0] > np.median(tin.triangles_center[:, 0])
        faces[right] += n
    ramp = (points[:, :2] - points[:, :2].min(axis=0)) / np.ptp(points[:, :2], axis=0)
    if kind == "uv":
        ramp[n:] = ramp[n:] * 0.5 + 0.5  # the second primitive's texture elsewhere in the atlas
        visual = trimesh.visual.TextureVisuals(uv=ramp)
    else:
        rgba = np.tile(np.array([200, 120, 40, 255], np.uint8), (len(points), 1))
        rgba[np.arange(len(points)) % (3 if kind == "soup" else 2 * n) >= (1 if kind == "soup" else n), 0] = 10
        visual = trimesh.visual.ColorVisuals(vertex_colors=rgba)
    seamed = trimesh.Trimesh(points, faces, visual=visual, process=False)
    with pytest.warns(UserWarning, match=r"^terrain: \d+ points of the TIN coincide with others but differ"):
        solid = st.stepped(seamed, interval=40.0, gamma=0.7, solid=True, device="cpu")
    plain = st.stepped(tin, interval=40.0, gamma=0.7, solid=True, device="cpu")
    assert solid.is_watertight and solid.body_count == 1
    assert len(solid.faces) == len(plain.faces)
    np.testing.assert_allclose(solid.volume, plain.volume, rtol=1e-9)
    assert type(solid.visual) is type(seamed.visual)
    path = tmp_path / "solid.stl"
    solid.export(path)
    assert trimesh.load(path).is_watertight


def test_a_tin_is_welded_by_position_once_for_all_its_solids():
    """The weld by position that a solid of a seamed TIN is closed over (a hash of every point and a new edge table:
    about 1.5 s for a million faces, more than the solid's stepping) was redone by every stepped(solid=True) call of
    the same mesh, whose Terrain (Terrain.from_mesh) is cached on it for that very reason: now once per terrain, and
    the welded terrain steps as before."""
    heights = np.asarray(st.sample_dem().heights[:7, :8], np.float64)
    tin = st.heightfield_mesh(heights, spacing=(30.0, 30.0))
    points = tin.vertices[tin.faces.reshape(-1)]  # a soup with a colour per corner
    corners = np.array([[200, 120, 40, 255], [10, 120, 40, 255], [10, 20, 240, 255]], np.uint8)
    rgba = np.tile(corners, (len(tin.faces), 1))
    soup = trimesh.Trimesh(points, np.arange(len(points)).reshape(-1, 3),
                           visual=trimesh.visual.ColorVisuals(vertex_colors=rgba), process=False)
    terrain = st.Terrain.from_mesh(soup)
    welded = terrain._welded_by_position()
    assert welded is not terrain and terrain._welded_by_position() is welded
    assert len(np.unique(welded.faces)) == len(tin.vertices)
    with pytest.warns(UserWarning, match=r"differ in their vertex colours.*the colours blend"):
        first = st.stepped(soup, interval=40.0, solid=True, device="cpu")
        again = st.stepped(soup, interval=40.0, solid=True, device="cpu")
    assert first.is_watertight and first.body_count == 1
    np.testing.assert_array_equal(first.vertices, again.vertices)
    np.testing.assert_array_equal(first.faces, again.faces)
    plain = st.Terrain.from_mesh(tin)
    assert plain._welded_by_position() is plain


def test_a_solid_of_a_tin_with_uv_seams_warns_that_its_texture_smears_along_them():
    """A solid is closed over a seamed TIN welded by position, each seam point taking its first copy's UV (one UV per
    vertex of an indexed watertight mesh): the faces on the other side of a seam (a glTF's primitives packed into one
    atlas, an OBJ's texture charts) then stretch their texture across the atlas to the other chart, silently. The
    terrace faces beside the seam below span three times the texture of any face of the surface without solid=True:
    now a warning names the seam points and the way out; no warning without seams, nor where ``colors`` replaces
    the visual."""
    heights = np.asarray(st.sample_dem().heights[:9, :11], np.float64)
    tin = st.heightfield_mesh(heights, spacing=(30.0, 30.0), origin=(376000.0, 3807000.0))
    n = len(tin.vertices)
    points = np.vstack([tin.vertices, tin.vertices])
    faces = tin.faces.copy()
    faces[tin.triangles_center[:, 0] > np.median(tin.triangles_center[:, 0])] += n
    uv = (points[:, :2] - points[:, :2].min(axis=0)) / np.ptp(points[:, :2], axis=0)
    uv[n:] = uv[n:] * 0.5 + 0.5  # the second primitive's texture elsewhere in the atlas
    seamed = trimesh.Trimesh(points, faces, visual=trimesh.visual.TextureVisuals(uv=uv), process=False)

    def largest_terrace_span(mesh):
        top = mesh.face_normals[:, 2] > 0.99
        return np.ptp(mesh.visual.uv[mesh.faces[top]][..., 0], axis=1).max()

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        surface = st.stepped(seamed, interval=40.0, gamma=0.7, device="cpu")
        st.stepped(seamed, interval=40.0, gamma=0.7, solid=True, colors="terrain", device="cpu")
        st.stepped(tin, interval=40.0, gamma=0.7, solid=True, device="cpu")
    seam_points = int(np.isin(np.unique(faces[faces >= n]) - n, faces[faces < n]).sum())
    with pytest.warns(UserWarning, match=rf"^terrain: {seam_points} points of the TIN coincide with others but differ "
                                         r"in their UVs.*texture.*smears.*without solid=True") as caught:
        solid = st.stepped(seamed, interval=40.0, gamma=0.7, solid=True, device="cpu")
    assert caught[0].filename == __file__
    assert largest_terrace_span(solid) > 2.5 * largest_terrace_span(surface)  # what the warning is about
    assert solid.is_watertight and solid.body_count == 1


def test_a_solid_of_a_coloured_tin_without_seams_but_with_a_zero_area_face_does_not_warn_of_seams():
    """A face two of whose corners coincide (an STL's or a PLY's sliver) keeps those points apart in every weld; the
    weld by position found them alike, rebuilt the same faces and warned that "0 points of the TIN coincide with
    others but differ in their vertex colours" of a TIN with one colour at every point: no seam, no warning."""
    heights = np.asarray(st.sample_dem().heights[:6, :7], np.float64)
    tin = st.heightfield_mesh(heights, spacing=(30.0, 30.0))
    points = np.vstack([tin.vertices, tin.vertices[:1]])  # point 0 twice, the copy in a face of no area
    faces = np.vstack([tin.faces, [[0, len(points) - 1, 1]]])
    rgba = np.tile(np.array([200, 120, 40, 255], np.uint8), (len(points), 1))
    mesh = trimesh.Trimesh(points, faces, visual=trimesh.visual.ColorVisuals(vertex_colors=rgba), process=False)
    terrain = st.Terrain.from_mesh(mesh)
    assert terrain._welded_by_position() is terrain
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        solid = st.stepped(mesh, interval=40.0, solid=True, device="cpu")
    plain = st.stepped(tin, interval=40.0, solid=True, device="cpu")
    assert solid.is_watertight
    np.testing.assert_allclose(solid.volume, plain.volume, rtol=1e-9)


def test_lenses_compare_and_hash_by_identity_as_rois_do():
    """``Lens`` was a frozen dataclass with the generated ``__eq__`` and ``__hash__`` over its fields: comparing two
    lenses (``lens == other``, ``lens in [a, b]``) raised numpy's "truth value of an array ... is ambiguous" from
    comparing their masks, and ``hash(lens)`` (a lens in a set or as a dict key, a memo keyed by γ) raised "unhashable
    type: 'numpy.ndarray'". It compares by identity now, as :class:`~stepterrain.closeup.ROI` and ``CloseUp`` do (they
    hold arrays too)."""
    a = st.Lens(np.zeros((2, 2)))
    b = st.Lens(np.zeros((2, 2)), extent=(0.0, 1.0, 0.0, 1.0))
    assert a == a and a != b and not (a == b)
    assert b in [a, b] and st.Lens(np.ones((3, 3))) not in [a, b]
    assert len({a, b, a}) == 2 and {a: 1, b: 2}[b] == 2
    assert a != 1.0 and a != np.zeros((2, 2)).tolist()
    # stepping with it is unchanged: a lens of γ 0 gives the original surface
    h = np.random.default_rng(0).random((6, 7)) * 10
    np.testing.assert_array_equal(st.stepped(h, interval=2.0, gamma=a).vertices,
                                  st.stepped(h, interval=2.0, gamma=0.0).vertices)


def test_colors_refuse_a_masked_entry_and_a_bool_instead_of_reading_under_them():
    """``colors`` was the one numeric argument read with ``np.asarray`` alone: a masked array's masked entries lent
    the values under the mask to their levels (0.9 under the mask coloured its level 230 grey, without a word) and a
    bool beside numbers was 1 ([1, True, 0] a near-black green), where heights, levels, γ and the lens mask refuse
    both. Both are refused now, naming colors and the index; a masked array with nothing masked colours as its data."""
    heights = np.add.outer(np.arange(5.0), np.arange(5.0))  # 0..8: levels 0, 4, 8 at interval 4
    data = np.array([[0.2, 0.4, 0.6], [0.9, 0.9, 0.9], [0.1, 0.5, 1.0]])
    plain = st.stepped(heights, interval=4.0, colors=data)
    mask = np.zeros(data.shape, bool)
    mask[1, 2] = True
    with pytest.raises(st.InvalidInputError, match=r"colors must be numbers .*; got a masked entry at index \(1, 2\)"):
        st.stepped(heights, interval=4.0, colors=np.ma.masked_array(data, mask=mask))
    unmasked = st.stepped(heights, interval=4.0, colors=np.ma.masked_array(data, mask=np.zeros(data.shape, bool)))
    np.testing.assert_array_equal(unmasked.visual.vertex_colors, plain.visual.vertex_colors)
    with pytest.raises(st.InvalidInputError, match=r"colors must be numbers .*; got a bool \(True\) at index \(2, 1\)"):
        st.stepped(heights, interval=4.0, colors=[[255, 0, 0], [0, 255, 0], [0, True, 0]])
    ints = st.stepped(heights, interval=4.0, colors=[[255, 0, 0], [0, 255, 0], [0, 1, 0]])  # numbers: as they were
    assert ints.visual.vertex_colors[:, :3].max() == 255


def test_colors_that_do_not_fit_are_refused_before_the_terrain_is_stepped(monkeypatch):
    """A misnamed colormap or a colours table with a row per isovalue too few was refused only in the assembly,
    after every pass over the terrain had run (a large DEM stepped in full to be told 'viridss' is no colormap); it
    is checked with the isovalues now, before the passes, as a solid's floor is."""
    heights = np.add.outer(np.arange(5.0), np.arange(5.0))

    def no_passes(*args, **kwargs):
        raise AssertionError("the terrain was stepped before colors was checked")

    monkeypatch.setattr(stepped_module, "step_arrays", no_passes)
    with pytest.raises(st.InvalidInputError, match=r"colors must name a matplotlib colormap"):
        st.stepped(heights, interval=4.0, colors="viridss")
    with pytest.raises(st.InvalidInputError, match=r"shape \(3, 3\|4\); got shape \(2, 3\)"):
        st.stepped(heights, interval=4.0, colors=np.zeros((2, 3)))
    with pytest.raises(AssertionError, match="stepped before"):  # colors that fit go on to the passes
        st.stepped(heights, interval=4.0, colors="viridis")


def test_a_stacks_range_is_taken_frame_by_frame_not_in_copies_of_the_whole_stack():
    """stepped_series of a (T, H, W) stack took its height range from a finite mask of the whole stack and a copy of
    all its finite heights (``stack[np.isfinite(stack)]``): as much memory again as the stack, float64 for a float64
    one, before the first frame was stepped, and a memory-mapped series was read into memory whole there. The range
    is taken a frame at a time now; the isovalues (and so every mesh) are the same."""
    import tracemalloc

    rng = np.random.default_rng(4)
    stack = rng.normal(100.0, 20.0, (48, 64, 64))  # float64: 1.5 MiB
    stack[5, 10:20, 10:20] = np.nan
    stack[7, 3, 3] = np.nan  # nodata: the triangles' range, frame by frame
    expected = [st.stepped(frame, interval=25.0, device="cpu") for frame in stack[:2]]

    def peak_of(call):
        tracemalloc.start()
        try:
            result = call()
            return result, tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    _, stepping = peak_of(lambda: st.stepped(stack[0], interval=25.0, device="cpu"))  # the frame's own work
    series = st.stepped_series(stack, interval=25.0, device="cpu")
    first, peak = peak_of(lambda: next(series))
    assert peak - stepping < stack.nbytes / 4, f"{peak - stepping:,} bytes more than stepping the frame alone, " \
        f"for a stack of {stack.nbytes:,}"
    for mesh, want in zip([first, next(series)], expected, strict=True):
        np.testing.assert_array_equal(mesh.vertices, want.vertices)
        np.testing.assert_array_equal(mesh.faces, want.faces)
    values = [m.metadata["isovalues"] for m in st.stepped_series(stack, interval=25.0, device="cpu")]
    finite = stack[np.isfinite(stack)]
    assert values[0] == st.isovalues((finite.min(), finite.max()), interval=25.0).tolist()
    assert all(v == values[0] for v in values)


def test_a_memory_mapped_stack_is_budgeted_frame_by_frame_as_stepped_budgets_a_mapped_frame(tmp_path):
    """stepped(mapped[0]) refuses a memory-mapped frame whose float32 copy exceeds the memory budget before reading
    it; stepped_series(mapped) made the map a plain array and read every frame (and the whole map for its range),
    refused only later for the size of the first mesh. Each frame of a mapped stack is budgeted as stepped() budgets
    it now; a mapped stack within the budget steps as the array does."""
    path = tmp_path / "series.npy"
    stack = np.random.default_rng(5).normal(100.0, 20.0, (3, 40, 30))
    np.save(path, stack)
    mapped = np.load(path, mmap_mode="r")
    previous = st.set_memory_budget(4_000)  # under one frame's 4,800 bytes as float32
    try:
        with pytest.raises(st.OutputTooLargeError, match=r"memory-mapped array of shape \(40, 30\), float64"):
            next(st.stepped_series(mapped, interval=25.0, device="cpu"))
    finally:
        st.set_memory_budget(previous)
    for got, want in zip(st.stepped_series(mapped, interval=25.0, device="cpu"),
                         st.stepped_series(stack, interval=25.0, device="cpu"), strict=True):
        np.testing.assert_array_equal(got.vertices, want.vertices)
        np.testing.assert_array_equal(got.faces, want.faces)


def _whole_stack_ranges(stack):
    """The whole-stack computation ``_stack_ranges`` replaced (9dd5c0d): a finite mask and a copy of all finite
    heights, the triangles of every frame at once (tests/reference.py's, in plain NumPy: used_height_range reads a
    stack a frame at a time now); None without a finite height."""
    from .reference import used_height_range_reference

    finite_mask = np.isfinite(stack)
    finite = stack[finite_mask]
    if finite.size == 0:
        return None
    lo, hi = float(finite.min()), float(finite.max())
    bad = np.isinf(stack).any(axis=(1, 2))
    with np.errstate(invalid="ignore"):
        bad |= (np.abs(stack.astype(np.float64)) > st.terrain.FLOAT32_MAX).any(axis=(1, 2))
    used = (lo, hi) if finite.size == stack.size else used_height_range_reference(stack)
    return lo, hi, used, bad, ~finite_mask.any(axis=(1, 2))


@settings(max_examples=60, deadline=None)
@given(seed=st_.integers(0, 2**31 - 1), shape=st_.tuples(st_.integers(1, 3), st_.integers(0, 4), st_.integers(0, 4)),
       dtype=st_.sampled_from(["float64", "float32", "float16", "int64", "uint64", "int8"]),
       fortran=st_.booleans())
def test_a_stacks_frame_by_frame_ranges_are_the_whole_stacks(seed, shape, dtype, fortran):
    """``_stack_ranges`` (stepped_series' height range of a stack, a frame at a time) against the whole-stack
    computation it replaced, over NaN, infinities, values beyond float32, integer extremes, float16 and frames of
    1 x N or of no node at all: the same (lo, hi), used range and frames refused. A frame of no node (an (T, 0, W)
    stack) is ``finite.all()`` and raised numpy's "zero-size array to reduction operation minimum"."""
    rng = np.random.default_rng(seed)
    if np.dtype(dtype).kind == "f":
        stack = rng.normal(0.0, 10.0, shape)
        stack[rng.random(shape) < rng.random()] = np.nan
        stack[rng.random(shape) < 0.05] = np.inf * rng.choice([-1, 1])
        if dtype == "float64":
            stack[rng.random(shape) < 0.05] = 1e39 * rng.choice([-1, 1])
        stack = stack.astype(dtype)
    else:
        info = np.iinfo(dtype)
        stack = rng.integers(info.min, info.max, shape, dtype=dtype, endpoint=True)
    stack = np.asfortranarray(stack) if fortran else stack
    want = _whole_stack_ranges(stack)
    lo, hi, used, bad, empty = stepped_module._stack_ranges(stack)
    if want is None:
        assert (lo, hi, used) == (None, None, None)
        assert empty.all()
        return
    assert (lo, hi, used) == want[:3]
    np.testing.assert_array_equal(empty, want[4])
    np.testing.assert_array_equal(bad, want[3])


@pytest.mark.parametrize("shape", [(2, 0, 5), (3, 5, 0), (1, 0, 0)])
def test_a_stack_of_frames_with_no_node_is_refused_not_a_numpy_error(shape, tmp_path):
    """A (T, 0, W) stack: each frame of no node is ``finite.all()``, and ``_stack_ranges`` took the min of its empty
    heights (numpy's ValueError "zero-size array to reduction operation minimum"); the whole-stack computation before
    it, and now, refuse it as holding no finite height, a memory-mapped one too."""
    np.save(tmp_path / "empty.npy", np.zeros(shape))
    for frames in (np.zeros(shape), np.load(tmp_path / "empty.npy", mmap_mode="r")):
        with pytest.raises(st.InvalidInputError, match=r"^frames hold no finite height$"):
            next(st.stepped_series(frames, interval=1.0, device="cpu"))


def test_a_stack_frame_of_nodata_and_an_infinity_is_refused_for_the_infinity_as_stepped_refuses_it():
    """A frame holding NaN and an infinity but no finite height: stepped() of it, and a list of such frames, name the
    infinity; a stack of them said "terrain has no finite height (all nodata)" (and a stack of only such frames "frames
    hold no finite height"), as if the infinity were nodata. Both name the infinity and the frame now."""
    frame = np.full((3, 3), np.nan)
    frame[1, 2] = -np.inf
    with pytest.raises(st.InvalidInputError, match=r"infinite value at index \(1, 2\)") as alone:
        st.stepped(frame, interval=1.0, device="cpu")
    good = np.arange(9.0).reshape(3, 3)
    for stack, k in ((np.stack([good, frame]), 1), (np.stack([frame, frame]), 0)):
        with pytest.raises(st.InvalidInputError, match=rf"^frames\[{k}\]: ") as got:
            next(st.stepped_series(stack, interval=1.0, device="cpu"))
        assert str(got.value) == f"frames[{k}]: {alone.value}"
    nodata = np.stack([good, np.full((3, 3), np.nan)])  # all NaN, no infinity: refused as before
    with pytest.raises(st.InvalidInputError, match=r"^frames\[1\]: terrain has no finite height \(all nodata\)$"):
        next(st.stepped_series(nodata, interval=1.0, device="cpu"))


def test_a_stacks_colors_that_do_not_fit_are_refused_before_its_first_frame_is_stepped(monkeypatch):
    """stepped() checks ``colors`` with the isovalues, before the passes (4293c7c); stepped_series of a (T, H, W)
    stack, whose frames share one list of isovalues known before the first frame, still stepped that frame in full
    before a misnamed colormap or a table a row short was refused. Both are refused before any pass now, with the
    message the first frame gave; colors that fit go on to the passes."""
    stack = np.stack([np.add.outer(np.arange(5.0), np.arange(5.0))] * 3)  # levels 0, 4, 8 at interval 4
    with pytest.raises(st.InvalidInputError, match=r"shape \(3, 3\|4\); got shape \(2, 3\)") as before:
        next(st.stepped_series(stack, interval=4.0, colors=np.zeros((2, 3)), device="cpu"))

    def no_passes(*args, **kwargs):
        raise AssertionError("a frame was stepped before colors was checked")

    monkeypatch.setattr(stepped_module, "step_arrays", no_passes)
    with pytest.raises(st.InvalidInputError, match=r"colors must name a matplotlib colormap"):
        next(st.stepped_series(stack, interval=4.0, colors="viridss", device="cpu"))
    with pytest.raises(st.InvalidInputError) as got:
        next(st.stepped_series(stack, interval=4.0, colors=np.zeros((2, 3)), device="cpu"))
    assert str(got.value) == str(before.value)
    with pytest.raises(AssertionError, match="stepped before"):  # colors that fit go on to the passes
        next(st.stepped_series(stack, interval=4.0, colors=np.zeros((3, 3)), device="cpu"))


def test_kept_grid_struct_serves_only_its_own_terrain_and_lets_it_go():
    """stepped keeps the last grid struct a thread built (the terrain's heights, the thread's levels scratch) for a
    re-step of the same terrain: another terrain of the same shape gets its own heights, and a dropped terrain's
    heights are not kept alive by it."""
    import gc
    import weakref

    from stepterrain import _device

    rng = np.random.default_rng(3)
    a = st.Terrain.from_heights((rng.random((40, 50)) * 30).astype(np.float32))
    b = st.Terrain.from_heights((rng.random((40, 50)) * 30).astype(np.float32))
    expected = []
    for t in (a, b):
        _device.release_scratch()
        expected.append(st.stepped(t, interval=4.0))
    _device.release_scratch()
    for t, mesh in zip((a, b, a, a, b), (expected[0], expected[1], expected[0], expected[0], expected[1]), strict=True):
        again = st.stepped(t, interval=4.0)
        np.testing.assert_array_equal(again.vertices, mesh.vertices)
        np.testing.assert_array_equal(again.faces, mesh.faces)
    heights = weakref.ref(b.heights.base if b.heights.base is not None else b.heights)
    del b, t, again, mesh, expected
    gc.collect()
    assert heights() is None


def test_a_kept_grid_struct_and_its_levels_go_with_release_scratch_and_the_threads_exit_without_gc():
    """The grid struct a thread keeps (and the levels scratch it names) goes as soon as release_scratch() drops it or
    the thread that built it exits, without the cyclic gc: its weakref callback named the structs' dict strongly
    (dict -> entry -> weakref -> callback -> dict), a cycle that kept 8.6 MiB of levels for a 1500 x 1500 grid
    until gc.collect()."""
    import gc
    import threading
    import weakref

    from stepterrain import _device

    def kept_structs():
        return [o for o in gc.get_objects() if isinstance(o, stepped_kernels.HeightField.cls)]

    terrain = st.Terrain.from_heights((np.random.default_rng(5).random((60, 70)) * 30).astype(np.float32))
    gc.collect()
    gc.disable()
    try:
        _device.release_scratch()
        assert kept_structs() == []
        st.stepped(terrain, interval=4.0, device="cpu")
        (struct,) = kept_structs()
        levels = weakref.ref(struct.levels)
        del struct
        _device.release_scratch()
        assert kept_structs() == []
        assert levels() is None

        def step():
            st.stepped(terrain, interval=4.0, device="cpu")
            seen.append(len(kept_structs()))

        seen = []
        worker = threading.Thread(target=step)
        worker.start()
        worker.join()
        assert seen == [1]  # the worker kept its own while it ran
        assert kept_structs() == []
    finally:
        gc.enable()
