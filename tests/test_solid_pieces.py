"""close_solid (stepterrain.mesh) on foreign surfaces made of several pieces, or folded over themselves.

Bugs found (helper h342, session 46), one failing test each:

* Pieces wound opposite ways (a TIN of two tiles, one with its faces flipped): the surface was turned by the sign of
  its total projected area, so the other piece came out inside out: two 385-face TINs of 409 150 m³ closed into a
  solid of volume -8 457 (watertight and consistently wound by trimesh, 387 of the 770 base faces facing -z), the
  warning saying the whole surface was reversed. Each piece (faces joined through edges) is now turned on its own.
* A closed piece (a box) beside an open one was closed without a word: its faces flattened onto the base twice
  over (395 base faces, 10 of them facing +z). Refused now.
* An overhang (a surface folded over itself, its projection covering some ground twice) closed into a solid that
  intersects itself (a 10 x 10 grid folded at x = 6: volume -55, 120 of 200 base faces facing -z). Refused now,
  naming how many faces fold and where the first lies.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as hs

from stepterrain.errors import InvalidInputError
from stepterrain.mesh import close_solid
from tests.test_solid_kernels import _surface
from tests.test_solid_orientation import _prism_volume, _tin


def _close(vertices, faces, floor):
    return close_solid(vertices, faces, np.ones(len(faces), bool), floor)


def _signed_areas(vertices, faces):
    """Twice each face's projected area, signed (NumPy: the determinant of its two edges from the first corner;
    positive counter-clockwise from +z)."""
    p = np.asarray(vertices, np.float64)[:, :2][faces]
    return np.linalg.det(np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=1))


def _grid(rows, cols, seed=0, jitter=0.0):
    """A (rows x cols)-node grid surface on unit cells, two faces a cell, counter-clockwise; nodes moved by up to
    ``jitter`` in x and y."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:rows, 0:cols].astype(float)
    xy = np.column_stack([xx.ravel(), yy.ravel()]) + rng.uniform(-jitter, jitter, (rows * cols, 2))
    vertices = np.column_stack([xy, rng.uniform(5.0, 9.0, rows * cols)])
    i = np.arange(rows * cols).reshape(rows, cols)
    q = np.stack([i[:-1, :-1], i[:-1, 1:], i[1:, 1:], i[1:, :-1]], -1).reshape(-1, 4)
    return vertices, np.vstack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def _base_and_top(solid_vertices, solid_faces, n_surface_faces, floor):
    mesh = trimesh.Trimesh(solid_vertices, solid_faces, process=False)
    added = solid_faces[n_surface_faces:]
    on_floor = np.all(solid_vertices[added][:, :, 2] == floor, axis=1)
    return mesh, mesh.face_normals[n_surface_faces:][on_floor], mesh.face_normals[:n_surface_faces]


@settings(max_examples=15, deadline=None)
@given(seed=hs.integers(0, 2**31 - 1), n=hs.integers(4, 40), pieces=hs.integers(2, 4), data=hs.data())
def test_pieces_wound_opposite_ways_are_each_turned_to_face_up(seed, n, pieces, data):
    """Some pieces (not all, not none) flipped: each flipped piece is closed reversed, with a warning counting them;
    the solid is watertight, consistently wound, its volume the pieces' prism integrals, every base face facing -z
    and every surface face facing up (or level: none down)."""
    flipped = data.draw(hs.lists(hs.booleans(), min_size=pieces, max_size=pieces).filter(
        lambda f: any(f) and not all(f)))
    vertices, faces, given_faces = [], [], []
    for k in range(pieces):
        v, f = _tin(seed + k, n, offset=(150.0 * k, 0.0))
        start = sum(len(x) for x in vertices)
        vertices.append(v)
        faces.append(f + start)
        given_faces.append((f[:, ::-1] if flipped[k] else f) + start)
    vertices, faces, given_faces = np.vstack(vertices), np.vstack(faces), np.vstack(given_faces)
    with pytest.warns(UserWarning, match=rf"faces: {sum(flipped)} pieces? of the surface's {pieces} .* wound "
                                         r"clockwise") as caught:
        solid_vertices, solid_faces, kept, _, _ = _close(vertices, given_faces, 0.0)
    assert len(caught) == 1 and caught[0].filename == __file__
    assert kept.all()
    mesh, base, top = _base_and_top(solid_vertices, solid_faces, len(given_faces), 0.0)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(_prism_volume(vertices, faces, 0.0), rel=1e-9)
    assert len(base) == len(faces) and np.allclose(base[:, 2], -1.0, rtol=0.0, atol=1e-12)  # level, facing -z
    assert np.all(top[:, 2] >= 0.0)
    # the surface's faces in the solid: the given ones, those of the flipped pieces reversed back
    assert np.array_equal(solid_faces[:len(faces)], faces)


def test_a_closed_piece_beside_an_open_one_is_refused():
    vertices, faces = _tin(1, 60)
    for closed in (trimesh.creation.box((10.0, 10.0, 10.0)), trimesh.creation.icosphere(1)):
        box_vertices = np.asarray(closed.vertices) + [200.0, 0.0, 20.0]
        both = np.vstack([vertices, box_vertices]), np.vstack([faces, np.asarray(closed.faces) + len(vertices)])
        for flip in (False, True):  # beside an open piece facing up, or down (turned alone, it still faces down)
            surface = both[1][:, ::-1] if flip else both[1]
            message = (rf"faces: close_solid skirts a surface's boundary down to the floor; got 1 closed piece "
                       rf"\({len(closed.faces)} faces, no boundary edge: a solid already; the first face "
                       rf"{len(faces)} at x, y = \S+, \S+\) beside 1 open one: close the open pieces without it")
            with pytest.raises(InvalidInputError, match=message):
                _close(both[0], surface, 0.0)
    # two closed pieces and nothing open: a closed mesh, refused as before
    two = trimesh.util.concatenate([trimesh.creation.box((1.0, 1.0, 1.0)),
                                    trimesh.creation.box((1.0, 1.0, 1.0)).apply_translation([5.0, 0.0, 0.0])])
    with pytest.raises(InvalidInputError, match="got a closed mesh .* no boundary edge"):
        _close(np.asarray(two.vertices) + [0.0, 0.0, 5.0], np.asarray(two.faces), 0.0)


@settings(max_examples=20, deadline=None)
@given(rows=hs.integers(2, 9), cols=hs.integers(3, 9), data=hs.data(), flip=hs.booleans())
def test_a_surface_folded_over_itself_is_refused_naming_its_folded_faces(rows, cols, data, flip):
    """A grid folded at column k (the nodes past it mirrored back over it, rising: an overhang): refused, naming the
    faces of the smaller side (the folded side on a tie), which face against the piece, and the first's xy."""
    k = data.draw(hs.integers(1, cols - 2))
    vertices, faces = _grid(rows, cols)
    x = vertices[:, 0].copy()
    past = x > k
    vertices[past, 0] = 2 * k - x[past]
    vertices[past, 2] += 10.0 + x[past]
    if flip:  # the whole surface wound clockwise: the same faces fold
        faces = np.ascontiguousarray(faces[:, ::-1])
    folded_side = 2 * (rows - 1) * (cols - 1 - k)
    other_side = 2 * (rows - 1) * k
    want = folded_side if folded_side <= other_side else other_side
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no turn warning before the refusal
        with pytest.raises(InvalidInputError, match=rf"faces must project one-to-one onto the xy plane .*; got "
                                                    rf"{want} faces? folding over .* in 1 piece, the first face "
                                                    r"(\d+) at x, y = ") as raised:
            _close(vertices, faces, 0.0)
    face = int(re.search(r"the first face (\d+)", str(raised.value)).group(1))
    x, y = (float(v) for v in re.search(r"at x, y = (\S+), (\S+):", str(raised.value)).groups())
    centre = vertices[faces[face], :2].mean(axis=0)
    assert (x, y) == pytest.approx(tuple(centre), abs=1e-7)
    minority = -1.0 if folded_side <= other_side else 1.0  # the folded side faces -z (+z reversed)
    if flip:
        minority = -minority
    assert np.sign(_signed_areas(vertices, faces)[face]) == minority


@settings(max_examples=20, deadline=None)
@given(seed=hs.integers(0, 2**31 - 1), rows=hs.integers(3, 12), cols=hs.integers(3, 12),
       jitter=hs.sampled_from([0.1, 0.3, 0.45, 0.6]))
def test_a_grid_whose_moved_nodes_turn_faces_over_is_refused_exactly_then(seed, rows, cols, jitter):
    """Nodes moved far enough turn some faces over (the surface overhangs itself there): refused, naming exactly
    those faces (NumPy determinants; the piece faces up, most faces do); else closed with the prism volume."""
    vertices, faces = _grid(rows, cols, seed, jitter)
    areas = _signed_areas(vertices, faces)
    assume_clear = np.all(np.abs(areas) > 1e-6)  # no face within rounding of level, so the reference is exact
    if not assume_clear:
        return
    over = int(np.count_nonzero(areas < 0))
    if over == 0:
        solid_vertices, solid_faces, *_ = _close(vertices, faces, 0.0)
        mesh = trimesh.Trimesh(solid_vertices, solid_faces, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume == pytest.approx(_prism_volume(vertices, faces, 0.0), rel=1e-9)
        return
    with pytest.raises(InvalidInputError, match=rf"got {over} faces? folding over"):
        _close(vertices, faces, 0.0)


def test_pieces_that_touch_at_a_vertex_only_are_turned_each():
    """Two pieces sharing one vertex (a pinch: no edge between them), the second wound the other way: orientation
    does not cross a vertex, so each piece is turned on its own (its own copy of the pinch vertex after the split)."""
    vertices, faces = _grid(3, 3)
    other = vertices + [2.0, 2.0, 0.0]  # its corner (0, 0) on the first's corner (2, 2): node 8
    both = np.vstack([vertices, other])
    second = faces + len(vertices)
    second[second == len(vertices)] = 8
    with pytest.warns(UserWarning, match=r"1 piece of the surface's 2"):
        solid_vertices, solid_faces, *_ = _close(both, np.vstack([faces, second[:, ::-1]]), 0.0)
    mesh = trimesh.Trimesh(solid_vertices, solid_faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(_prism_volume(both, np.vstack([faces, second]), 0.0), rel=1e-5)


@settings(max_examples=10, deadline=None)
@given(seed=hs.integers(0, 2**31 - 1), rows=hs.integers(3, 8), cols=hs.integers(2, 5), which=hs.sampled_from([0, 1]))
def test_a_stepped_surface_with_one_island_reversed_closes_as_the_surface_itself(seed, rows, cols, which):
    """Two islands of a stepped surface (a nodata column between them), one reversed (its faces, walls included):
    closed bit for bit as the surface as stepped (the reversed island turned back, the wall pairs read as the step
    kernels emit them), with the warning."""
    rng = np.random.default_rng(seed)
    heights = rng.normal(0.0, 3.0, (rows, 2 * cols + 1)).cumsum(0).cumsum(1).astype(np.float32)
    heights[:, cols] = np.nan
    vertices, faces, terrace, floor = _surface(heights, interval=1.0)
    island = np.all(vertices[faces][:, :, 0] > vertices[:, 0].min() + cols - 0.5, axis=1)
    part = island if which else ~island
    if not island.any() or island.all() or not np.any(terrace & part):
        return
    given_faces = faces.copy()
    given_faces[part] = given_faces[part][:, ::-1]
    want = close_solid(vertices, faces, terrace, floor)
    with pytest.warns(UserWarning, match=r"1 piece of the surface's 2"):
        got = close_solid(vertices, given_faces, terrace, floor)
    assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))


def test_a_stepped_surface_at_utm_coordinates_through_an_stl_closes_watertight(tmp_path):
    """A stepped surface at a UTM origin written to .stl (float32 positions: steps of 0.25 at y = 4 000 000, where a
    60 m surface's 2^-20 extent is 6e-5) and read back closes watertight with about the float64 surface's volume.
    Before, its float32-rounded slivers counted as faces folding over (refused: 286 faces, an overhang)."""
    from stepterrain import Terrain, stepped
    from stepterrain.export import read_mesh, save_mesh

    yy, xx = np.mgrid[0:60, 0:60]
    heights = (30 * np.sin(xx / 5.0) * np.cos(yy / 7.0)
               + np.random.default_rng(0).normal(0, 2, xx.shape)).astype(np.float32)
    surface = stepped(Terrain.from_heights(heights, spacing=(1.0, 1.0), origin=(500000.0, 4000000.0)), interval=3.0,
                      device="cpu")
    vertices = np.asarray(surface.vertices)
    floor = float(vertices[:, 2].min()) - 5.0
    want = trimesh.Trimesh(*close_solid(vertices, np.asarray(surface.faces), ~surface.face_attributes["wall"],
                                        floor)[:2], process=False).volume
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # .stl moves the vertices by up to 0.125: said so
        save_mesh(surface, tmp_path / "utm.stl")
    back = read_mesh(tmp_path / "utm.stl")
    back_vertices = np.asarray(back.vertices)
    assert np.array_equal(back_vertices.astype(np.float32), back_vertices)  # float32 positions
    assert np.abs(back_vertices[:, :2]).max() > 4e6
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no turn warning either: every face faces up
        solid_vertices, solid_faces, *_ = _close(back_vertices, np.asarray(back.faces), floor)
    mesh = trimesh.Trimesh(solid_vertices, solid_faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(want, rel=1e-3)


@pytest.mark.parametrize("origin", [(500000.3, 4000000.7), (500000.0, 4000000.0)])
def test_a_surface_folded_over_itself_at_utm_coordinates_is_refused(origin):
    """An overhang (a unit grid folded at column 4) at UTM coordinates is refused in float64 (the extent's margin:
    its own rounding is 2^-29 of float32's) and on a float32 grid (integer metres: a float32 step of 0.25 at y =
    4 000 000 is the margin's scale, and a unit face's twice-area 1 lies beyond its 0.25 x 3 + 2 x 0.25^2)."""
    vertices, faces = _grid(6, 8)
    x = vertices[:, 0].copy()
    past = x > 4
    vertices[past, 0] = 8 - x[past]
    vertices[past, 2] += 10.0 + x[past]
    vertices[:, :2] += origin
    float32_grid = bool(np.array_equal(vertices[:, :2].astype(np.float32), vertices[:, :2]))
    assert float32_grid == (origin == (500000.0, 4000000.0))
    with pytest.raises(InvalidInputError, match=r"got 30 faces folding over .* in 1 piece"):
        _close(vertices, faces, 0.0)


def test_the_piece_pass_peaks_at_about_80_bytes_a_face():
    """_orient_pieces (two 200 x 200 grids wound opposite ways) allocates at most 100 bytes a face beside its
    arguments (tracemalloc): its edge keys and owners in place and freed as soon as done, the owners in int32 (76).
    Before, their temporaries peaked at 160 bytes a face (4.5 GiB at 30 M faces)."""
    import tracemalloc

    from stepterrain import mesh as mesh_module

    one, faces = _grid(201, 201)
    vertices = np.vstack([one, one + [300.0, 0.0, 0.0]])
    faces = np.vstack([faces, (faces + len(one))[:, ::-1]]).astype(np.int64)
    area, margin = mesh_module._face_areas(vertices, faces)
    tracemalloc.start()
    try:
        turned, count, total = mesh_module._orient_pieces(vertices, faces, area, margin)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert (count, total) == (1, 2)
    assert np.array_equal(turned[: len(faces) // 2], faces[: len(faces) // 2])
    assert np.array_equal(turned[len(faces) // 2:], faces[len(faces) // 2:, ::-1])
    assert peak / len(faces) < 100.0, peak / len(faces)
