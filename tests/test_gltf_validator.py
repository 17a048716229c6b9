"""The Khronos glTF validator accepts what save_mesh writes: zero errors and zero warnings.

Every GLB/glTF any test writes is also validated at the end of the session (tests/conftest.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import stepterrain as st
from stepterrain.batch import batch
from stepterrain.export import save_mesh

from . import gltf_validator
from .conftest import real_dem
from .test_export_formats import textured

AVAILABLE, REASON = gltf_validator.available()
pytestmark = pytest.mark.skipif(not AVAILABLE, reason=REASON)


def assert_valid(paths):
    reports = gltf_validator.validate(paths)
    assert set(reports) == {str(p) for p in paths}
    assert gltf_validator.problems(reports) == []


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_representative_meshes_pass(tmp_path, ext):
    z = real_dem("big_tujunga_srtm_30m_utm11n.npz", size=40, step=3)
    utm = st.Terrain.from_heights(z, spacing=(90.0, -90.0), origin=(376313.66, 3807917.83), crs="EPSG:32611")
    meshes = {
        "plain": st.stepped(z, interval=100.0),
        "colors": st.stepped(z, interval=100.0, colors="terrain"),
        "utm": st.stepped(utm, interval=50.0, gamma=0.5),
        "solid": st.stepped(z, interval=100.0, base=0.5, solid=True, colors="viridis"),
        "textured": textured(),
        "lens": st.stepped(z, interval=100.0, gamma=st.circular_lens(z, (20.0, 20.0), 8.0)),
    }
    paths = [save_mesh(m, tmp_path / f"{name}{ext}", metadata={"name": name}) for name, m in meshes.items()]
    assert_valid(paths)


def test_batch_outputs_pass(tmp_path):
    report = batch(real_dem("big_tujunga_srtm_30m_utm11n.npz", size=33, step=4), tmp_path, tile_size=16,
                   interval=100.0, colors="terrain", scheduler="serial")  # fmt: skip
    assert_valid([r.path for r in report.done])


def test_validator_catches_a_broken_file(tmp_path):
    good = save_mesh(trimesh.creation.box(), tmp_path / "box.glb")
    broken = tmp_path / "broken.glb"
    data = bytearray(good.read_bytes())
    data[12:16] = (len(data) * 4).to_bytes(4, "little")  # JSON chunk length past the end of the file
    broken.write_bytes(bytes(data))
    reports = gltf_validator.validate([broken])
    assert reports[str(broken)]["errors"] > 0
    assert gltf_validator.problems(reports)


def test_empty_mesh_has_no_errors_or_warnings(tmp_path):
    empty = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), process=False)
    assert_valid([save_mesh(empty, tmp_path / "empty.glb")])


def test_a_report_past_the_pipes_64_kib_arrives_whole(tmp_path):
    # the script called process.exit() right after writing its JSON, which cut the pipe's output at 64 KiB: the
    # end-of-session validation of every GLB the suite wrote failed with "Unterminated string" once there were many
    good = save_mesh(trimesh.creation.box(), tmp_path / "box.glb").read_bytes()
    paths = []
    for k in range(700):
        path = tmp_path / f"copy_{k:04d}_{'x' * 40}.glb"
        path.write_bytes(good)
        paths.append(path)
    reports = gltf_validator.validate(paths)
    assert len(reports) == len(paths) and gltf_validator.problems(reports) == []
