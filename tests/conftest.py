"""Shared fixtures: the device fixture, hypothesis profiles, real DEM crops and the mesh validity helper."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import HealthCheck, settings

settings.register_profile("ci", derandomize=True, deadline=None, max_examples=40,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", deadline=None, max_examples=100)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
if not SHARED_DATA.exists():  # a git worktree (e.g. /work/wt/NAME): look further up for shared/data
    SHARED_DATA = next((p / "shared" / "data" for p in Path(__file__).resolve().parents[2:]
                        if (p / "shared" / "data").is_dir()), SHARED_DATA)

wp.init()
DEVICES = ["cpu"] + [str(d) for d in wp.get_cuda_devices()]


@pytest.fixture(params=DEVICES, ids=DEVICES)
def device(request) -> str:
    return request.param


def shared_file(name: str) -> Path:
    path = SHARED_DATA / name
    if not path.exists():
        pytest.skip(f"shared data {name} not found beside the project ({SHARED_DATA})")
    return path


def real_dem(name: str, size: int = 96, step: int = 4) -> np.ndarray:
    """A subsampled crop (size x size nodes, every ``step``-th node) of a real DEM in shared/data."""
    with np.load(shared_file(name)) as data:
        z = np.asarray(data["elevation"], dtype=np.float32)
    return np.ascontiguousarray(z[: size * step : step, : size * step : step])


def assert_valid_mesh(mesh: trimesh.Trimesh) -> None:
    """Indices in range, no repeated index in a face, every vertex referenced, all coordinates finite."""
    faces = np.asarray(mesh.faces)
    vertices = np.asarray(mesh.vertices)
    assert np.isfinite(vertices).all(), "non-finite vertex coordinates"
    if len(faces) == 0:
        assert len(vertices) == 0, "an empty mesh must have no vertices"
        return
    assert faces.min() >= 0 and faces.max() < len(vertices), "face index out of range"
    assert ((faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])).all(), (
        "degenerate face (repeated vertex index)"
    )
    referenced = np.zeros(len(vertices), bool)
    referenced[faces.reshape(-1)] = True
    assert referenced.all(), f"{(~referenced).sum()} unreferenced vertices"
