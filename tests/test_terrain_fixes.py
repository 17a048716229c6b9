"""Regression tests for bugs found in Terrain (terrain.py): each fails without its fix."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

import stepterrain as st
from stepterrain.errors import InvalidInputError

_H = np.add.outer(np.arange(6.0), 2.0 * np.arange(7.0)).astype(np.float32)  # heights 0 to 17


@pytest.mark.parametrize(
    "fields, message",
    [
        (dict(kind="grid", heights=np.arange(5.0)), r"^heights must be a 2-D \(H, W\) array; got shape \(5,\)$"),
        (dict(kind="grid", heights=np.zeros((1, 5))), r"^heights needs at least 2 x 2 nodes; got shape \(1, 5\)$"),
        (
            dict(kind="grid", heights=[["a", "b"], ["c", "d"]]),
            r"^heights must be a real-valued \(H, W\) array; got "
            r"dtype <U1$",
        ),
        (
            dict(kind="grid", heights=np.full((3, 3), np.inf)),
            r"^heights must be finite or NaN \(nodata\); got an "
            r"infinite value at index \(0, 0\)$",
        ),
        (
            dict(kind="grid", heights=_H, spacing=(1.0, 2.0, 3.0)),
            r"^spacing must be a pair of finite numbers \(x, y\) "
            r"\(or one number for both\); got \(1\.0, 2\.0, 3\.0\)$",
        ),
        (
            dict(kind="grid", heights=_H, spacing=(0.0, 1.0)),
            r"^spacing must be non-zero in x and y; got \(0\.0, 1\.0\)$",
        ),
        (dict(kind="grid", heights=_H, origin="ab"), r"^origin must be a pair of numbers \(x, y\); got 'ab'$"),
        (
            dict(kind="grid", heights=_H, origin=(1.0,)),
            r"^origin must be a pair of finite numbers \(x, y\); got "
            r"\(1\.0,\)$",
        ),
        (dict(kind="grd", heights=_H), r"^kind must be 'grid' or 'tin'; got 'grd'$"),
        (dict(kind="grid", heights=_H, crs=32611), r"^crs must be a str \(e\.g\. 'EPSG:32611'\) or None; got 32611$"),
        (
            dict(kind="grid", heights=_H, faces=np.zeros((1, 3), int)),
            r"^a Terrain of kind 'grid' takes heights, "
            r"spacing and origin; got faces too",
        ),
        (
            dict(kind="tin", heights=np.zeros(3, np.float32)),
            r"^a Terrain of kind 'tin' needs points \(N, 3\) and "
            r"faces \(F, 3\); got points None, faces None: build it "
            r"with Terrain\.from_mesh",
        ),
        (
            dict(kind="tin", heights=None, points=np.zeros((4, 2)), faces=[[0, 1, 2]]),
            r"^points must be an \(N, 3\) array of x, y, z; got shape \(4, 2\)$",
        ),
        (
            dict(kind="tin", heights=None, points=np.eye(3), faces=[[0.0, 1.0, 2.0]]),
            r"^faces must be an \(F, 3\) integer array of point indices; got shape \(1, 3\), dtype float64$",
        ),
        (
            dict(kind="tin", heights=None, points=np.eye(3), faces=[[0, 1, 5]]),
            r"^terrain mesh faces must index its vertices \(0 to 2\); face 0 is \[0, 1, 5\]",
        ),
        (
            dict(kind="tin", heights=np.ones(3), points=np.eye(3), faces=[[0, 1, 2]]),
            r"^heights of a Terrain of kind 'tin' are its points' z \(None to take them\); got an array of shape "
            r"\(3,\), dtype float64 that differs from points\[:, 2\]$",
        ),
    ],
)
def test_a_terrain_built_directly_is_checked_by_field(fields, message):
    """``Terrain(kind=..., heights=...)`` checked nothing: a 1-D array failed deep in stepped ('not enough values
    to unpack'), a TIN without faces with a NoneType error, a text origin with 'must be real number'; a 3-number
    or zero spacing was meshed (flat, or with its third number ignored). Each is now an InvalidInputError naming
    the field, what was expected and what was got, at construction."""
    with pytest.raises(InvalidInputError, match=message):
        st.Terrain(**fields)


def test_a_terrain_built_directly_takes_lists_and_other_dtypes_as_float32():
    """A list of rows failed in stepped ('list' object has no attribute 'min'); float64 and int heights and a
    Fortran-ordered array are now the same float32 grid as from_heights makes, and mesh the same."""
    reference = st.stepped(st.Terrain.from_heights(_H, spacing=(2.0, 3.0)), interval=2.0, device="cpu")
    for given in (_H.tolist(), _H.astype(np.float64), _H.astype(np.int32), np.asfortranarray(_H)):
        terrain = st.Terrain(kind="grid", heights=given, spacing=(2.0, 3.0))
        assert terrain.heights.dtype == np.float32 and terrain.heights.flags.c_contiguous
        mesh = st.stepped(terrain, interval=2.0, device="cpu")
        np.testing.assert_array_equal(mesh.vertices, reference.vertices)
        np.testing.assert_array_equal(mesh.faces, reference.faces)


def test_dataclasses_replace_does_not_carry_the_old_caches():
    """``dataclasses.replace(terrain, heights=new)`` passed the old terrain's cache dict to the new one: its height
    range (0 to 17 m) stayed, and stepped() clamped the new heights (100 to 117 m) into it. The replaced terrain
    now starts with its own caches; a TIN replaced keeps working (its edge tables rebuilt)."""
    terrain = st.Terrain.from_heights(_H)
    assert terrain.height_range == (0.0, 17.0)
    raised = dataclasses.replace(terrain, heights=_H + 100.0)
    assert raised.height_range == (100.0, 117.0)
    mesh = st.stepped(raised, interval=2.0, device="cpu")
    assert mesh.vertices[:, 2].min() >= 100.0 - 1.0
    assert terrain.height_range == (0.0, 17.0)
    tin = st.Terrain.from_mesh(
        trimesh.Trimesh([[0, 0, 0], [1, 0, 1], [0, 1, 2], [1, 1, 3]], [[0, 1, 2], [1, 3, 2]], process=False)
    )
    renamed = dataclasses.replace(tin, source="survey.ply")
    np.testing.assert_array_equal(renamed.edges, tin.edges)
    np.testing.assert_array_equal(
        st.stepped(renamed, interval=1.0, device="cpu").faces, st.stepped(tin, interval=1.0, device="cpu").faces
    )


_DURATIONS = np.arange(16).reshape(4, 4).astype("timedelta64[s]")


@pytest.mark.parametrize(
    "call, message",
    [
        (
            lambda: st.Terrain.from_heights(_DURATIONS),
            r"^heights must be a real-valued \(H, W\) array; got dtype "
            r"timedelta64\[s\]$",
        ),
        (lambda: st.stepped(_DURATIONS, interval=1.0, device="cpu"), r"^heights must be a real-valued"),
        (
            lambda: st.isovalues((0.0, 3.0), levels=_DURATIONS[0]),
            r"^levels must be a sequence of numbers \(real "
            r"numbers\); got dtype timedelta64\[s\]$",
        ),
        (
            lambda: st.stepped(_H[:4, :4], interval=2.0, gamma=_DURATIONS, device="cpu"),
            r"^gamma must be .*\(real numbers\); got dtype timedelta64\[s\]$",
        ),
        (
            lambda: list(st.stepped_series(_DURATIONS[None], interval=1.0, device="cpu")),
            r"^frames must be a real-valued \(T, H, W\) stack; got dtype timedelta64\[s\]$",
        ),
        (
            lambda: st.stepped(_H, levels=[0.0, 8.0, 16.0], colors=_DURATIONS[:3, :3], device="cpu"),
            r"^colors must be numbers \(0-1 floats or 0-255 integers\); got dtype timedelta64\[s\]$",
        ),
        (
            lambda: st.Terrain(kind="tin", heights=None, points=np.eye(3), faces=_DURATIONS[:1, :3]),
            r"^faces must be an \(F, 3\) integer array of point indices; got shape \(1, 3\), dtype timedelta64\[s\]$",
        ),
    ],
    ids=["from_heights", "stepped", "levels", "gamma", "stepped_series", "colors", "tin_faces"],
)
def test_durations_are_no_real_numbers(call, message):
    """numpy makes timedelta64 a subtype of signedinteger, so the dtype checks (``np.issubdtype(dtype, np.integer)``)
    took durations as heights, levels, γ, colours and point indices (a mesh stepped from seconds, silently), and a
    (T, H, W) stack of them reached ``float(min)``, a bare TypeError. They are refused as datetime64 always was."""
    with pytest.raises(InvalidInputError, match=message):
        call()


@pytest.mark.parametrize("make", ["from_heights", "direct", "stepped", "heightfield_mesh"])
@pytest.mark.parametrize(("origin", "spacing"), [((1e17, 0.0), (1.0, 1.0)), ((0.0, -1e300), (30.0, -30.0))])
def test_an_origin_too_far_for_float64_to_keep_the_nodes_apart_is_refused(make, origin, spacing):
    """An origin of 1e17 with spacing 1 put neighbouring nodes on one float64 value (1e300: every node on one):
    a stepped mesh of zero area, silently. Found by stepping grids at ever farther origins. Refused, naming it;
    UTM-sized origins (millions of metres, centimetre spacing) stay far inside the bound."""
    heights = np.arange(12.0).reshape(3, 4)
    calls = {
        "from_heights": lambda: st.Terrain.from_heights(heights, spacing=spacing, origin=origin),
        "direct": lambda: st.Terrain(kind="grid", heights=heights, spacing=spacing, origin=origin),
        "stepped": lambda: st.stepped(heights, interval=2.0, spacing=spacing, origin=origin),
        "heightfield_mesh": lambda: st.heightfield_mesh(heights, spacing=spacing, origin=origin),
    }
    with pytest.raises(st.InvalidInputError, match=r"^origin .* lies too far from zero for spacing .* float64"):
        calls[make]()
    near = st.stepped(heights, interval=2.0, spacing=(0.01, -0.01), origin=(4.5e6, 5e5))
    assert near.area_faces.min() > 0


def test_a_trimesh_scene_or_point_cloud_as_terrain_is_named_with_a_hint():
    """trimesh.load of a GLB (stepterrain's own output too) gives a trimesh.Scene, not a Trimesh; stepped() and
    circular_lens took it for a raw array and said "heights must be a real-valued (H, W) array; got dtype object",
    naming neither the Scene nor the way out. Such trimesh objects (a Scene, a PointCloud) are now refused by type,
    a Scene with how to get its mesh; the mesh it gives steps as a TIN."""
    tin = st.heightfield_mesh(_H)
    scene = trimesh.load(trimesh.util.wrap_as_stream(tin.export(file_type="glb")), file_type="glb")
    assert isinstance(scene, trimesh.Scene)
    for call in (lambda: st.stepped(scene, interval=2.0), lambda: st.circular_lens(scene, (1.0, 1.0), 1.0)):
        with pytest.raises(InvalidInputError, match=r"^terrain must be .*; got a trimesh\..*Scene .*force='mesh'"):
            call()
    with pytest.raises(InvalidInputError, match=r"^terrain must be .*; got a trimesh\..*PointCloud$"):
        st.stepped(trimesh.PointCloud(tin.vertices), interval=2.0)
    mesh = trimesh.load(trimesh.util.wrap_as_stream(tin.export(file_type="glb")), file_type="glb", force="mesh")
    assert st.stepped(mesh, interval=2.0).area == pytest.approx(st.stepped(_H, interval=2.0).area, rel=1e-6)
