"""Regression tests for bugs found by an adversarial hunt of the globe (paper 003): each fails without its fix."""

from __future__ import annotations

import numpy as np
import pytest

import stepterrain._compaction as compaction
from stepterrain.errors import OutputTooLargeError
from stepterrain.globe import Globe, adaptive_mesh

LAT1 = np.linspace(89.5, -89.5, 180)
LON1 = np.linspace(-179.5, 179.5, 360)


@pytest.fixture
def budget():
    """Set the memory budget for one test, restored afterwards."""
    previous = compaction.get_memory_budget()
    yield compaction.set_memory_budget
    compaction.set_memory_budget(previous)


def test_a_globe_mesh_over_the_memory_budget_is_refused(budget):
    """The full-resolution mesh of a 65² globe holds 49,152 faces (int64, 24 bytes, and the int32 cube face) and
    24,578 vertices (float64, 24 bytes, and the int32 node entry): 2,064,440 bytes. Only each refinement level was
    checked (the largest needs ~1.5 MiB), so a 1.6 MiB budget let the 2 MiB mesh through."""
    globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=65, device="cpu")
    budget(1600 << 10)
    with pytest.raises(OutputTooLargeError, match=r"the mesh \(24,578 vertices, up to 49,152 faces\) would need "
                                                  r"2\.0 MiB.*raise the error or narrow the view"):
        globe.mesh()
    budget(4 << 20)
    assert len(globe.mesh().faces) == 49_152  # within the budget: the same mesh as ever


def test_a_planar_mesh_over_the_memory_budget_is_refused(budget):
    """adaptive_mesh at error 0 on a 129² grid: 32,768 faces and 16,641 vertices (1.3 MiB) got through a 1 MiB
    budget that each of its levels fitted."""
    budget(1 << 20)
    with pytest.raises(OutputTooLargeError, match=r"the mesh \(16,641 vertices, up to 32,768 faces\) would need "
                                                  r"1\.3 MiB"):
        adaptive_mesh(np.zeros((129, 129)), error=0.0, device="cpu")
