"""The γ blend of paper 000 §3.3 through :func:`stepped`'s public mesh, against the NumPy reference.

``tests/test_stepped.py`` compares :func:`step_arrays` (γ-free) with the reference and the blend for a scalar or a
constant γ; these follow a varying γ to every output vertex of the welded mesh: a per-node γ carried onto a wall's
vertices with its crossing's β (the paper's "using β_l, β_r to interpolate given values from the original vertices"),
γ = 1 putting every vertex on its isovalue and γ = 0 every vertex on the input surface, a lens's inside and outside.
"""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import assume, given, settings
from hypothesis import strategies as st_
from hypothesis.extra.numpy import arrays

import stepterrain as st
from stepterrain._device import resolve_device
from stepterrain.stepped import isovalues, step_arrays
from stepterrain.terrain import as_terrain

from .reference import grid_tin, step_reference

UTM = np.array([512000.0, 4012000.0])


def reference_order(t, values, ref) -> np.ndarray:
    """For each reference vertex the index of the same vertex of :func:`stepped`'s mesh (the order of
    :func:`step_arrays`' vertices), matched by key (source nodes, height at γ = 0, at γ = 1) as tests/test_stepped.py
    matches them."""
    arrays = step_arrays(t, np.asarray(values, np.float32), device=resolve_device("cpu"), want_sources=True)
    src = arrays.sources.numpy().astype(np.float64)
    keys = np.column_stack([src, arrays.points.numpy()[:, 2], arrays.step_heights.numpy()]).astype(np.float64)
    mine = np.lexsort(keys.T[::-1])
    theirs = np.lexsort(ref.keys.T[::-1])
    np.testing.assert_array_equal(keys[mine], ref.keys[theirs])
    to_mine = np.empty(len(mine), np.int64)
    to_mine[theirs] = mine
    return to_mine


def expected_heights(points, ref, node_gamma: np.ndarray) -> np.ndarray:
    """z = (1 - γ) z_0 + γ z_step at each reference vertex, γ lerped from its source nodes with the crossing's β."""
    lo, hi = ref.keys[:, 0].astype(np.int64), ref.keys[:, 1].astype(np.int64)
    h = points[:, 2].astype(np.float64)
    span = h[hi] - h[lo]
    with np.errstate(divide="ignore", invalid="ignore"):
        beta = np.where(lo == hi, 0.0, (ref.points[:, 2] - h[lo]) / np.where(span == 0, 1.0, span))
    g = (1.0 - beta) * node_gamma[lo] + beta * node_gamma[hi]
    return (1.0 - g) * ref.points[:, 2] + g * ref.step_heights, g


def check_blend(t, mesh_at_one, mesh, points, faces, values, node_gamma):
    ref = step_reference(points, faces, values)
    assert len(mesh.vertices) == len(ref.points)
    order = reference_order(t, values, ref)
    np.testing.assert_array_equal(mesh.faces, mesh_at_one.faces)
    np.testing.assert_array_equal(mesh.faces, order[ref.faces])
    np.testing.assert_array_equal(mesh.vertices[:, :2], mesh_at_one.vertices[:, :2])  # walls stay vertical
    z, g = expected_heights(points, ref, node_gamma)
    got = mesh.vertices[order, 2]
    scale = max(1.0, float(np.abs(ref.points[:, 2]).max()))
    np.testing.assert_allclose(got, z, rtol=0, atol=4e-6 * scale)
    # γ = 1 and γ = 0 read exactly: the isovalue, the float32 height on the input surface (a crossing's threshold)
    one, zero = g == 1.0, g == 0.0
    np.testing.assert_array_equal(got[one], ref.step_heights[one])
    np.testing.assert_array_equal(got[zero], ref.points[zero, 2])


@settings(max_examples=25, deadline=None)
@given(
    heights=arrays(np.float32, st_.tuples(st_.integers(2, 6), st_.integers(2, 6)),
                   elements=st_.sampled_from([0.0, 0.5, 1.0, 1.25, 2.0, 3.5, 4.0, np.nan])),
    gamma=arrays(np.float64, 36, elements=st_.sampled_from([0.0, 0.25, 0.6, 1.0])),
    interval=st_.sampled_from([1.0, 0.75]),
)
def test_a_per_node_gamma_reaches_every_grid_vertex_with_its_crossings_beta(heights, gamma, interval):
    """Grids with heights on thresholds (twins) and nodata, a per-node γ of 0, 1 and between: each vertex of the
    welded mesh is at (1 - γ) z_0 + γ z_step with γ lerped from its edge's nodes by β, exactly 1 or 0 read exactly."""
    assume(np.isfinite(heights).sum() >= 3)
    t = st.Terrain.from_heights(heights, spacing=(3.0, 2.0), origin=tuple(UTM))
    points, faces = grid_tin(t.heights, t.spacing)
    assume(len(faces) > 0)
    values = isovalues(t.height_range, interval=interval)
    node_gamma = gamma[: heights.size].reshape(heights.shape)
    node_gamma = np.where(np.isfinite(heights), node_gamma, np.nan)  # nodata: no vertex reads it
    mesh = st.stepped(t, interval=interval, gamma=node_gamma)
    mesh_at_one = st.stepped(t, interval=interval)
    check_blend(t, mesh_at_one, mesh, points, faces, values, np.nan_to_num(node_gamma.reshape(-1)))


@settings(max_examples=25, deadline=None)
@given(
    xy=arrays(np.float64, st_.tuples(st_.integers(4, 12), st_.just(2)), elements=st_.integers(0, 6)),
    z=st_.lists(st_.sampled_from([0.0, 0.5, 1.0, 1.5, 2.5, 4.0]), min_size=12, max_size=12),
    gamma=arrays(np.float64, 12, elements=st_.sampled_from([0.0, 0.3, 1.0])),
    clockwise=st_.booleans(),
)
def test_a_per_node_gamma_reaches_every_tin_vertex_at_utm_coordinates(xy, z, gamma, clockwise):
    """Delaunay TINs on an integer lattice (duplicate and collinear points, slivers) at UTM coordinates, wound
    either way: the per-node γ blend as above, in the float32 frame of the TIN's local origin."""
    from scipy.spatial import Delaunay, QhullError

    try:
        faces = Delaunay(xy).simplices
    except QhullError:
        assume(False)
    if clockwise:
        faces = faces[:, ::-1]
    tin = trimesh.Trimesh(np.column_stack([xy + UTM, z[: len(xy)]]), faces, process=False)
    t = as_terrain(tin)
    values = isovalues(t.height_range, interval=1.0)
    node_gamma = gamma[: len(xy)]
    mesh = st.stepped(tin, interval=1.0, gamma=node_gamma)
    mesh_at_one = st.stepped(tin, interval=1.0)
    check_blend(t, mesh_at_one, mesh, t.local_points(), t.faces, values, node_gamma)


def test_a_lens_is_the_input_surface_inside_and_exact_isovalues_outside():
    """Paper 000 §4, Fig. 4: where the lens mask is 0 every vertex is the γ = 0 mesh's bit for bit, where it is 1 the
    γ = 1 mesh's (a vertex's bilinear γ of equal samples is that value exactly), walls vertical throughout."""
    dem = st.sample_dem()
    heights = np.asarray(getattr(dem, "heights", dem), np.float32)[:48, :48]
    t = st.Terrain.from_heights(heights, spacing=(30.0, 30.0), origin=tuple(UTM))
    cx, cy = UTM + 23.5 * 30.0
    radius, width = 400.0, 100.0
    lens = st.circular_lens(t, (cx, cy), radius, edge_width=width)
    mesh = st.stepped(t, interval=20.0, gamma=lens)
    at_zero = st.stepped(t, interval=20.0, gamma=0.0)
    at_one = st.stepped(t, interval=20.0, gamma=1.0)
    np.testing.assert_array_equal(mesh.faces, at_one.faces)
    np.testing.assert_array_equal(mesh.vertices[:, :2], at_one.vertices[:, :2])
    spacing = 2 * (radius + width) / 511  # at most a mask sample, so that the bilinear lookup reads equal samples
    d = np.hypot(mesh.vertices[:, 0] - cx, mesh.vertices[:, 1] - cy)
    inside = d < radius - width / 2 - 2 * spacing
    outside = d > radius + width / 2 + 2 * spacing
    assert inside.sum() > 100 and outside.sum() > 100
    np.testing.assert_array_equal(mesh.vertices[inside], at_zero.vertices[inside])
    np.testing.assert_array_equal(mesh.vertices[outside], at_one.vertices[outside])
    values = isovalues(t.height_range, interval=20.0).astype(np.float64)
    assert np.isin(mesh.vertices[outside, 2], values).all()


@settings(max_examples=20, deadline=None)
@given(
    heights=arrays(np.float32, st_.tuples(st_.integers(2, 6), st_.integers(2, 6)),
                   elements=st_.sampled_from([-1.0, 0.0, 0.5, 1.0, 2.25, 3.0, 6.0, 9.5, np.nan])),
    gamma=st_.sampled_from([1.0, 0.0, 0.35]),
    uniform=st_.booleans(),
    solid=st_.booleans(),
)
def test_face_levels_and_level_colours_agree_with_the_geometry(heights, gamma, uniform, solid):
    """§3.1-3.2: a terrace lies on the isovalue of its ``level`` and a wall spans ``level`` to ``level + 1`` (at γ = 1),
    each vertex takes the colour row of the isovalue it steps to, whatever γ (γ moves heights, not levels), a solid's
    skirt and base are level -1 and grey; the mesh from an interval equals the one from the same isovalues given as
    ``levels``, bit for bit."""
    assume(np.isfinite(heights).sum() >= 3)
    t = st.Terrain.from_heights(heights)
    points, faces = grid_tin(t.heights, t.spacing)
    assume(len(faces) > 0 and np.ptp(t.heights[np.isfinite(t.heights)]) > 0)
    if uniform:
        values = isovalues(t.height_range, interval=2.0)
    else:
        values = np.array([-0.5, 0.25, 1.0, 4.0, 4.5, 8.0], np.float32)
    table = np.column_stack([np.arange(len(values)) * 40 % 256, np.arange(len(values)) * 7, np.full(len(values), 9)])
    kwargs = {"interval": 2.0} if uniform else {"levels": values}
    mesh = st.stepped(t, gamma=gamma, colors=table.astype(np.uint8), solid=solid, **kwargs)
    stepped_at_one = st.stepped(t, colors=table.astype(np.uint8), solid=solid, **kwargs)
    np.testing.assert_array_equal(mesh.faces, stepped_at_one.faces)
    np.testing.assert_array_equal(mesh.face_attributes["level"], stepped_at_one.face_attributes["level"])
    np.testing.assert_array_equal(mesh.visual.vertex_colors, stepped_at_one.visual.vertex_colors)
    level = stepped_at_one.face_attributes["level"]
    wall = stepped_at_one.face_attributes["wall"]
    z = stepped_at_one.vertices[stepped_at_one.faces, 2]
    surface = level >= 0
    assert not (wall & ~surface).any()
    terrace = surface & ~wall
    v = values.astype(np.float64)
    np.testing.assert_array_equal(z[terrace], np.repeat(v[level[terrace]][:, None], 3, axis=1))
    lower, upper = v[level[wall]][:, None], v[np.minimum(level[wall] + 1, len(v) - 1)][:, None]
    assert ((z[wall] == lower) | (z[wall] == upper)).all()
    assert ((z[wall] == lower).any(axis=1) & (z[wall] == upper).any(axis=1)).all()
    colours = stepped_at_one.visual.vertex_colors
    on_surface = np.zeros(len(stepped_at_one.vertices), bool)
    on_surface[stepped_at_one.faces[surface].reshape(-1)] = True
    rows = np.searchsorted(v, stepped_at_one.vertices[on_surface, 2])
    np.testing.assert_array_equal(colours[on_surface, :3], table[rows])
    if solid:
        assert stepped_at_one.is_watertight and mesh.is_watertight
        np.testing.assert_array_equal(colours[~on_surface], np.tile([96, 96, 96, 255], ((~on_surface).sum(), 1)))
    given = st.stepped(t, gamma=gamma, levels=isovalues(t.height_range, interval=2.0))  # (a solid's default floor
    by_interval = st.stepped(t, gamma=gamma, interval=2.0)  # differs: an interval below, a tenth of the levels' span)
    np.testing.assert_array_equal(given.vertices, by_interval.vertices)
    np.testing.assert_array_equal(given.faces, by_interval.faces)
