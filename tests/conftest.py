"""Shared fixtures: the device fixture, hypothesis profiles, real DEM crops, the mesh validity helper, and the
command-line tests' DEM file and in-process runner."""

from __future__ import annotations

import functools
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

# STEPTERRAIN_SHARED_DATA points elsewhere explicitly
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
if not SHARED_DATA.exists():  # a git worktree (e.g. /work/wt/NAME): look further up for shared/data
    SHARED_DATA = next((p / "shared" / "data" for p in Path(__file__).resolve().parents[2:]
                        if (p / "shared" / "data").is_dir()), SHARED_DATA)
if os.environ.get("STEPTERRAIN_SHARED_DATA"):
    SHARED_DATA = Path(os.environ["STEPTERRAIN_SHARED_DATA"])

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


@functools.cache
def offscreen() -> tuple[bool, str]:
    """``render.offscreen_available()``, asked once per test session (it opens a window)."""
    from stepterrain import render

    return render.offscreen_available()


def needs_render(test):
    """Mark ``test`` as a render test that skips, with the reason, where no off-screen context exists."""
    available, reason = offscreen()
    test = pytest.mark.skipif(not available, reason=f"no off-screen OpenGL context: {reason}")(test)
    return pytest.mark.render(test)


def trimeshes_left_by(call) -> int:
    """How many more ``trimesh.Trimesh`` objects are alive after ``call()`` than before, with Python's automatic
    garbage collection off while it runs: a Trimesh refers to itself, so one that was dropped stays alive until
    the cyclic collector runs."""
    import gc

    call()  # compile, warm
    gc.collect()
    before = sum(isinstance(o, trimesh.Trimesh) for o in gc.get_objects())
    gc.disable()
    try:
        call()
        return sum(isinstance(o, trimesh.Trimesh) for o in gc.get_objects()) - before
    finally:
        gc.enable()


def python_calls(function, *args) -> int:
    """How many functions ``function(*args)`` calls: Python's (list comprehensions and generator expressions
    included) and built-in ones (``bytes.find``, NumPy's)."""
    import sys

    calls = 0

    def count(frame, event, arg):  # noqa: ANN001, ANN202 - sys.setprofile's signature
        nonlocal calls
        calls += event in ("call", "c_call")

    sys.setprofile(count)
    try:
        function(*args)
    finally:
        sys.setprofile(None)
    return calls


def traced_peak(call, *args) -> int:
    """The peak of the memory tracemalloc traced while ``call(*args)`` ran."""
    import tracemalloc

    tracemalloc.start()
    try:
        call(*args)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def budget_counts(monkeypatch, module) -> list[int]:
    """The byte counts ``module``'s calls of ``check_budget`` check from now on (each still checked), in a list the
    caller reads after the call under test."""
    counted: list[int] = []
    check = module.check_budget

    def counting(nbytes, *args, **kwargs):
        counted.append(nbytes)
        return check(nbytes, *args, **kwargs)

    monkeypatch.setattr(module, "check_budget", counting)
    return counted


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


# ------------------------------------------------------------------ every glTF/GLB the suite writes is validated
@pytest.fixture(scope="session", autouse=True)
def gltf_written_files_are_valid(tmp_path_factory):
    """Copy every .glb/.gltf written through export.save_mesh during the session, then run the Khronos glTF
    validator over all of them at once (one node process) and fail the session on any error or warning.
    Without node or the validator package the check is skipped (tests/test_gltf_validator.py says why)."""
    import shutil

    from stepterrain import export

    from . import gltf_validator

    ok, _reason = gltf_validator.available()
    if not ok:
        yield
        return
    folder = tmp_path_factory.mktemp("gltf_written")
    copies: dict[Path, Path] = {}

    def record(path: Path) -> None:
        if path.suffix.lower() in (".glb", ".gltf") and path.is_file():
            # a name that is no UTF-8 (h\udcf6he.glb, Latin-1) as one that is: node opens files by UTF-8 names
            copy = folder / f"{len(copies):05d}_{os.fsencode(path.name).decode('utf-8', 'replace')}"
            shutil.copyfile(path, copy)
            copies[copy] = path

    remove = export.add_write_listener(record)
    yield
    remove()
    reports = gltf_validator.validate(sorted(copies))
    bad = gltf_validator.problems(reports)
    if bad:
        pytest.fail(f"{len(bad)} of {len(copies)} glTF/GLB files written by the tests fail the Khronos glTF "
                    "validator:\n" + "\n".join(bad), pytrace=False)


@pytest.fixture
def dem(tmp_path):
    """A 24 x 32 synthetic hill (the command-line tests' DEM file) (heights 0-10) saved as .npy."""
    y, x = np.mgrid[0:24, 0:32].astype(np.float32)
    heights = 10.0 * np.exp(-((x - 15.0) ** 2 + (y - 11.0) ** 2) / 60.0) + 0.05 * x
    path = tmp_path / "hill.npy"
    np.save(path, heights.astype(np.float32))
    return path


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """The ``stepterrain`` command run in this process on ``argv`` (each through ``str``: paths go as they are): its
    exit code and what it wrote to stdout and stderr, read through the test's ``capsys``. The command-line tests
    import it as ``run``."""
    from stepterrain import cli

    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err
