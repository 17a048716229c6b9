"""Bugs found by a hunt over stepped's less-travelled options (γ callables, TIN visuals, lenses, series, solids), one
test each."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import stepterrain as st


def _half(points: np.ndarray) -> np.ndarray:
    return np.full(len(points), 0.5)


def _tin_with_colours(heights: np.ndarray, seed: int) -> trimesh.Trimesh:
    tin = st.heightfield_mesh(heights)
    rng = np.random.default_rng(seed)
    tin.visual = trimesh.visual.ColorVisuals(tin, vertex_colors=rng.integers(0, 256, (len(tin.vertices), 4),
                                                                             dtype=np.uint8))
    return tin


@pytest.mark.parametrize("case", ["grid colours", "tin colours", "solid"])
def test_a_gamma_callable_that_steps_another_terrain_leaves_the_calling_steps_alone(case):
    """The passes' points, step heights, sources and βs are this thread's scratch arrays, which blend() and _assemble
    read after the γ callable returned: a callable that stepped another terrain itself (a γ from another surface's
    steps) overwrote them where its arrays fit in theirs, so the outer mesh got the inner one's heights, colours or a
    solid's positions. Each result must equal the one of a callable giving the same γ without stepping anything."""
    rng = np.random.default_rng(0)
    heights = rng.uniform(0.0, 10.0, (20, 20))
    other = rng.uniform(0.0, 100.0, (9, 8))  # smaller: its passes fit in, and overwrote, the arrays of the outer
    other_tin = _tin_with_colours(other, 1)

    def stepping(points: np.ndarray) -> np.ndarray:
        st.stepped(other, interval=3.0, gamma=0.3)
        st.stepped(other_tin, interval=2.0)
        st.stepped(other, interval=7.0, colors="terrain", solid=True)
        return _half(points)

    terrain = _tin_with_colours(heights, 2) if case == "tin colours" else heights
    options = {"interval": 1.0, "colors": "terrain" if case == "grid colours" else None, "solid": case == "solid"}
    want = st.stepped(terrain, gamma=_half, **options)
    got = st.stepped(terrain, gamma=stepping, **options)
    np.testing.assert_array_equal(got.vertices, want.vertices)
    np.testing.assert_array_equal(got.faces, want.faces)
    if case != "solid":
        np.testing.assert_array_equal(got.visual.vertex_colors, want.visual.vertex_colors)


@pytest.mark.parametrize("visual", ["vertex colours", "uv"])
@pytest.mark.parametrize("how", ["assigned", "in place"])
def test_a_tin_whose_colours_change_after_a_step_is_welded_by_its_new_colours(visual, how):
    """Coinciding points are welded only where their vertex colours (or UVs) agree, and the TIN built from a mesh was
    cached on it while its vertices, faces and visual object stayed the same: colours set anew on the same visual
    (``mesh.visual.vertex_colors = ...``, or changed in place) that open a seam were stepped with the old weld, the
    seam's points one vertex taking its first copy's colour. The result must equal that of a fresh mesh."""
    from scipy.spatial import Delaunay

    rng = np.random.default_rng(0)
    xy = rng.uniform(0.0, 100.0, (30, 2))
    faces = Delaunay(xy).simplices
    points = np.column_stack([xy, rng.uniform(0.0, 9.0, 30)])
    points = np.vstack([points, points[faces[0]]])  # face 0 on copies of its corners, welded while colours agree
    faces[0] = [30, 31, 32]

    def visual_of(mesh: trimesh.Trimesh, seam: float):
        if visual == "uv":
            uv = np.zeros((33, 2))
            uv[30:] = seam
            return trimesh.visual.TextureVisuals(uv=uv)
        colours = np.tile(np.uint8([255, 0, 0, 255]), (33, 1))
        colours[30:, 1] = int(seam * 255)
        return trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)

    mesh = trimesh.Trimesh(points.copy(), faces, process=False)
    mesh.visual = visual_of(mesh, 0.0)
    before = st.stepped(mesh, interval=1.0)
    changed = visual_of(mesh, 1.0)
    attribute = "uv" if visual == "uv" else "vertex_colors"
    if how == "assigned":
        setattr(mesh.visual, attribute, getattr(changed, attribute))
    else:
        getattr(mesh.visual, attribute)[30:] = getattr(changed, attribute)[30:]
    got = st.stepped(mesh, interval=1.0)
    fresh = trimesh.Trimesh(points.copy(), faces, process=False)
    fresh.visual = visual_of(fresh, 1.0)
    want = st.stepped(fresh, interval=1.0)
    assert len(want.vertices) > len(before.vertices)  # the seam kept apart
    np.testing.assert_array_equal(got.vertices, want.vertices)
    np.testing.assert_array_equal(got.faces, want.faces)
    np.testing.assert_array_equal(getattr(got.visual, attribute), getattr(want.visual, attribute))


def test_thresholds_of_takes_a_list_of_isovalues_and_names_bad_ones():
    """``st.stepped.thresholds_of`` (named public in the README and docs/texture.md) did ``values.astype``: a list of
    isovalues raised AttributeError ('list' object has no attribute 'astype'). A sequence is taken as float32, as the
    kernels take levels; what is no 1-D sequence of numbers is an InvalidInputError naming ``values``."""
    thresholds_of = st.stepped.thresholds_of
    np.testing.assert_array_equal(thresholds_of([1, 2, 4]), np.float32([1.5, 3.0]))
    np.testing.assert_array_equal(thresholds_of((0.1, 0.2)), thresholds_of(np.float32([0.1, 0.2])))
    for bad, said in (("ab", "got dtype <U2"), ([[1, 2]], r"got shape \(1, 2\)"), ([True, 2], "got a bool"),
                      (None, "got dtype object")):
        with pytest.raises(st.InvalidInputError, match=rf"^values must be a 1-D sequence of isovalues.*{said}"):
            thresholds_of(bad)


@pytest.mark.parametrize("kind", ["grid", "tin"])
@pytest.mark.parametrize("visual", ["red", 5, np.zeros((4, 4))])
def test_a_terrain_built_directly_refuses_a_visual_that_is_no_trimesh_visual(kind, visual):
    """``Terrain(..., visual=...)`` took any object and ignored it: the steps came out without the colours meant,
    unsaid. It is an InvalidInputError naming ``visual``, what it takes and what it got."""
    fields = ({"heights": np.zeros((3, 3))} if kind == "grid" else
              {"heights": None, "points": np.array([[0, 0, 0], [1, 0, 1], [1, 1, 2], [0, 1, 3]], float),
               "faces": np.array([[0, 1, 2], [0, 2, 3]])})
    with pytest.raises(st.InvalidInputError, match=r"^visual must be a trimesh visual \(trimesh.visual.ColorVisuals or "
                                                   r"TextureVisuals\) or None; got "):
        st.Terrain(kind=kind, visual=visual, **fields)
