"""A solid written as ``.stl`` reads back watertight: STL has no indices, so readers and slicers (``trimesh.load``)
merge its corners by position, in float32 world coordinates. A solid used to be stepped from heights on a threshold
moved up by one float32 step only: a wall's top vertex then lay within float32 rounding of the node (the same height
at γ = 1), and the merged STL had degenerate faces and open edges although the indexed mesh was watertight (a 167²
crop of the embedded DEM at interval 100: 2128 coincident pairs; 0 once 0.5 m is added to every height). Found by a
bug hunt over ``stepterrain steps --solid -o x.stl``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st_

import stepterrain as st
from stepterrain.export import save_mesh
from stepterrain.stepped import isovalues, thresholds_of

stepped_module = st.stepped  # the module, callable as its function stepped


def _stl_round_trip(mesh: trimesh.Trimesh, path) -> trimesh.Trimesh:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # UTM coordinates: .stl's float32 moves them by centimetres (it says so)
        save_mesh(mesh, path)
    return trimesh.load(path)  # merges the corners by position, as STL readers do


def _coincident(mesh: trimesh.Trimesh) -> int:
    """Distinct vertices that float32 (STL) puts on one position."""
    _, counts = np.unique(mesh.vertices.astype(np.float32), axis=0, return_counts=True)
    return int((counts - 1).sum())


def _assert_stl_is_the_solid(mesh: trimesh.Trimesh, path) -> None:
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert _coincident(mesh) == 0
    back = _stl_round_trip(mesh, path)
    assert back.is_watertight and back.is_winding_consistent
    assert len(back.vertices) == len(mesh.vertices)
    # float32 world coordinates (3.8e6 m northings: steps of 0.25 m) move the volume by that rounding only: each
    # vertex by at most half a float32 step u, the volume by at most u times the area
    u = float(np.spacing(np.float32(np.abs(mesh.vertices).max())))
    assert back.volume == pytest.approx(mesh.volume, abs=u * mesh.area)


@pytest.fixture(scope="module")
def crop():
    dem = st.sample_dem()
    return st.Terrain.from_heights(dem.heights[:167, :167], spacing=dem.spacing, origin=dem.origin, crs=dem.crs)


@pytest.mark.parametrize("gamma", [1.0, 0.5])
def test_solid_of_the_sample_dem_reads_back_watertight_from_stl(crop, gamma, tmp_path):
    assert np.isin(crop.heights, thresholds_of(isovalues(crop.height_range, interval=100.0))).any()
    mesh = st.stepped(crop, interval=100.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path / "solid.stl")


def test_solid_with_a_nodata_hole_reads_back_watertight_from_stl(crop, tmp_path):
    heights = crop.heights.copy()
    heights[60:70, 60:75] = np.nan
    holed = st.Terrain.from_heights(heights, spacing=crop.spacing, origin=crop.origin)
    mesh = st.stepped(holed, interval=100.0, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path / "holed.stl")


def test_nodes_keep_their_isovalue_and_move_at_most_a_quarter_gap(crop):
    """At γ = 1 the nodes on a threshold keep their isovalue bit for bit; the move τ stays within a quarter of the gap
    to the next threshold (the level is kept) and is what the docs say: metres at most in UTM coordinates."""
    values = isovalues(crop.height_range, interval=100.0)
    nudged = stepped_module._off_thresholds(crop, values)
    moved = nudged.heights.astype(np.float64) - crop.heights
    on = np.isin(crop.heights, thresholds_of(values))
    assert (moved[on] > 0).all() and (moved[~on] == 0).all()
    assert moved.max() <= 25.0 and moved.max() < 3.0
    snap = stepped_module.snapped_isovalue
    assert all(snap(a, values) == snap(b, values) for a, b in zip(crop.heights[on], nudged.heights[on], strict=True))


@settings(max_examples=15, deadline=None)
@given(
    rows=st_.integers(3, 9),
    cols=st_.integers(3, 9),
    seed=st_.integers(0, 2**32 - 1),
    gamma=st_.sampled_from([1.0, 0.5]),
    far=st_.sampled_from([(0.0, 0.0), (12345.0, 23456.0)]),
)
def test_integer_grids_read_back_watertight_from_stl(rows, cols, seed, gamma, far, tmp_path_factory):
    """Small integer grids with interval 2 (thresholds on odd integers: many heights on them), near the origin and
    away from it (float32 steps of 2^-9 m)."""
    rng = np.random.default_rng(seed)
    heights = rng.integers(0, 9, size=(rows, cols)).astype(np.float32)
    t = st.Terrain.from_heights(heights, spacing=(1.0, 1.0), origin=far)
    mesh = st.stepped(t, interval=2.0, gamma=gamma, solid=True)
    _assert_stl_is_the_solid(mesh, tmp_path_factory.mktemp("stl") / "grid.stl")
