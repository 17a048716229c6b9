"""Bugs found by a hunt for silent wrong results in the pyvista accessor (grid.stepterrain), one test each."""

from __future__ import annotations

import numpy as np
import pytest
import pyvista as pv

import stepterrain.pyvista_accessor  # noqa: F401 - registers the accessor
from stepterrain.errors import InvalidInputError


def test_structured_grid_with_elevation_in_cell_data_is_refused_not_stepped_flat():
    """A flat StructuredGrid (z = 0) whose elevation sits in cell data stepped its points' z without a word: one
    flat terrace at 0 whatever the elevation held. Found by stepping grids with elevation in point data, cell data
    and z. Now the elevation in cell data is named with the conversion to point data; after it, the grid steps."""
    heights = np.random.default_rng(0).random((5, 6)) * 100
    x, y = np.meshgrid(np.arange(6) * 30.0, np.arange(5) * 30.0)
    grid = pv.StructuredGrid(x, y, np.zeros_like(x))
    grid.cell_data["elevation"] = heights[:-1, :-1].ravel(order="F")
    with pytest.raises(InvalidInputError, match=r"cell data 'elevation'.*cell_data_to_point_data"):
        grid.stepterrain.stepped(interval=10.0)
    steps = grid.cell_data_to_point_data().stepterrain.stepped(interval=10.0)
    assert np.ptp(steps.points[:, 2]) > 0


def test_image_data_elevation_in_cell_data_is_named_in_the_error():
    """An ImageData with elevation in cell data only was refused with "point data: []", not saying where its
    elevation was nor how to use it; elevation=NAME of a cell-data array the same."""
    grid = pv.ImageData(dimensions=(4, 3, 1))
    grid.cell_data["height"] = np.arange(6.0)
    with pytest.raises(InvalidInputError, match=r"cell data 'height'.*cell_data_to_point_data"):
        grid.stepterrain.stepped(interval=1.0)
    with pytest.raises(InvalidInputError, match=r"got 'height'.*cell_data_to_point_data"):
        grid.stepterrain.stepped(interval=1.0, elevation="height")
