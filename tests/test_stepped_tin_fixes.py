"""Bugs found by a hunt over the stepped-terrain API's less-trodden inputs (TIN input, γ forms, levels, series),
one test each."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay

import stepterrain as st


def _tin(n: int = 80, seed: int = 0) -> trimesh.Trimesh:
    """A Delaunay TIN of the sample DEM's heights at random xy (bilinear), on [0, 63]²."""
    rng = np.random.default_rng(seed)
    heights = np.asarray(st.sample_dem().heights, np.float64)[:64, :64]
    xy = np.vstack([rng.random((n, 2)) * 63.0, [[0, 0], [63, 0], [0, 63], [63, 63]]])
    i, j = np.minimum(xy[:, 1].astype(int), 62), np.minimum(xy[:, 0].astype(int), 62)
    fy, fx = xy[:, 1] - i, xy[:, 0] - j
    z = ((1 - fy) * ((1 - fx) * heights[i, j] + fx * heights[i, j + 1])
         + fy * ((1 - fx) * heights[i + 1, j] + fx * heights[i + 1, j + 1]))
    return trimesh.Trimesh(np.column_stack([xy, z]), Delaunay(xy).simplices, process=False)


@pytest.mark.parametrize("stray", [[np.nan, np.nan, np.nan], [np.inf, 0.0, 5.0], [np.nan, 1.0, 1000.0]],
                         ids=["all-nan", "inf-x", "nan-x"])
def test_a_tin_point_on_no_face_may_have_non_finite_x_and_y(stray):
    """A point on no face (an unreferenced vertex) is in no mesh: its z is not checked (NaN, beyond float32), but a
    NaN or infinite x or y of it refused the whole TIN ("terrain mesh vertices must have finite x and y"). Stepped,
    the TIN gives the mesh it gives without that point, bit for bit."""
    mesh = _tin()
    plain = st.stepped(mesh, interval=50.0, gamma=0.5, solid=True)
    strayed = trimesh.Trimesh(np.vstack([mesh.vertices, stray]), mesh.faces, process=False)
    steps = st.stepped(strayed, interval=50.0, gamma=0.5, solid=True)
    assert np.array_equal(steps.vertices, plain.vertices) and np.array_equal(steps.faces, plain.faces)
    for name in ("level", "wall"):
        assert np.array_equal(steps.face_attributes[name], plain.face_attributes[name])


def test_a_nodata_tin_point_written_as_nan_nan_nan_drops_its_faces():
    """A nodata point written as (NaN, NaN, NaN), as some exporters write a void, drops the faces it is on, as one
    with a finite x and y and a NaN height does (the docstring's "faces touching a non-finite height are dropped"):
    it refused the whole TIN. A point with a NaN x on a face with finite heights is still refused, naming it."""
    mesh = _tin()
    k = int(mesh.faces[len(mesh.faces) // 2, 0])
    holed = mesh.vertices.copy()
    holed[k, 2] = np.nan
    voided = holed.copy()
    voided[k] = np.nan
    expected = st.stepped(trimesh.Trimesh(holed, mesh.faces, process=False), interval=50.0)
    steps = st.stepped(trimesh.Trimesh(voided, mesh.faces, process=False), interval=50.0)
    assert np.array_equal(steps.vertices, expected.vertices) and np.array_equal(steps.faces, expected.faces)
    assert len(steps.faces) > 0
    bad = mesh.vertices.copy()
    bad[k, 0] = np.nan
    with pytest.raises(st.InvalidInputError, match=rf"finite x and y; vertex {k} is \[nan, "):
        st.stepped(trimesh.Trimesh(bad, mesh.faces, process=False), interval=50.0)


@pytest.mark.parametrize("stray", [[30.0, 30.0, 900.0], [np.nan, np.nan, np.nan]], ids=["near", "nan"])
def test_the_cli_lens_check_measures_to_the_points_the_steps_use(stray):
    """steps --lens warns when the lens holds no node of the terrain; for a TIN it measured to every point, a stray
    one (on no face) included: one inside the lens kept the warning back, and one with a NaN x or y made the
    distance NaN (``NaN >= reach`` is False: no warning either)."""
    from stepterrain import cli

    rng = np.random.default_rng(5)
    xy = np.vstack([rng.random((30, 2)) * 10.0, [[0, 0], [10, 0], [0, 10], [10, 10]]])
    mesh = trimesh.Trimesh(np.column_stack([xy, xy[:, 0]]), Delaunay(xy).simplices, process=False)
    strayed = trimesh.Trimesh(np.vstack([mesh.vertices, stray]), mesh.faces, process=False)
    expected = float(np.hypot(xy[:, 0] - 30.0, xy[:, 1] - 30.0).min())
    assert cli._nearest_node_distance(st.Terrain.from_mesh(strayed), 30.0, 30.0) == expected


def test_stepped_series_names_the_frame_of_an_iterable_whose_heights_the_interval_does_not_fit():
    """Frames from an iterable get isovalues of their own heights; a later frame whose heights the interval does not
    fit (too fine for float32 there) was refused without naming the frame, after the frames before it had been
    yielded: which of a thousand frames was it? The first frame's refusal stays as stepped() gives it."""
    heights = np.asarray(st.sample_dem().heights, np.float64)[:16, :16]
    frames = st.stepped_series(iter([heights, heights + 1.0, heights + 1e9]), interval=50.0)
    assert len(next(frames).faces) and len(next(frames).faces)
    with pytest.raises(st.InvalidInputError, match=r"^frames\[2\] \(heights 1e\+09 to 1e\+09\): interval=50.0 is too "
                                                   r"small for float32 heights"):
        next(frames)
    with pytest.raises(st.InvalidInputError) as first:
        next(st.stepped_series(iter([heights + 1e9]), interval=50.0))
    with pytest.raises(st.InvalidInputError) as alone:
        st.stepped(heights + 1e9, interval=50.0)
    assert str(first.value) == str(alone.value)


def test_a_tin_point_only_on_faces_dropped_for_nodata_is_not_checked():
    """A point whose every face is dropped for a nodata corner is in no mesh, as an unreferenced one: its z beyond
    float32 (or its NaN x and y) refused the whole TIN. It steps as the TIN without that face, bit for bit; such a
    height on a kept face is still refused, naming the vertex."""
    mesh = _tin()
    n = len(mesh.vertices)
    plain = st.stepped(mesh, interval=50.0)
    for extra in ([[5.0, 5.0, 1e300], [6.0, 5.0, np.nan]], [[np.nan, np.nan, 1e300], [np.nan, np.nan, np.nan]]):
        points = np.vstack([mesh.vertices, extra])
        faces = np.vstack([mesh.faces, [[0, n, n + 1]]])
        steps = st.stepped(trimesh.Trimesh(points, faces, process=False), interval=50.0)
        assert np.array_equal(steps.vertices, plain.vertices) and np.array_equal(steps.faces, plain.faces)
    points = mesh.vertices.copy()
    points[3, 2] = 1e300
    with pytest.raises(st.InvalidInputError, match=r"must fit in float32 .*; vertex 3 has z=1e\+300"):
        st.stepped(trimesh.Trimesh(points, mesh.faces, process=False), interval=50.0)
