"""Batch bugs found by an adversarial pass (each test failed before its fix)."""

from __future__ import annotations

import numpy as np

from stepterrain.batch import MANIFEST_NAME, batch


def test_a_rerun_removes_the_partial_temporary_files_a_killed_run_left(tmp_path):
    # a run killed while writing left its hidden temporary file (16 MB of a 174 MB tile, say) beside the outputs,
    # and every rerun kept it, done or not: the truncated bytes stayed in the output folder for good
    z = np.add.outer(np.arange(9.0), np.arange(9.0)).astype(np.float32)
    out = tmp_path / "out"
    out.mkdir()
    stale = [out / ".tile_r0_c0.glb.k2x9abcd.tmp", out / ".tile_r1_c1.glb.zz_1e0_q.tmp",
             out / f".{MANIFEST_NAME}.q1w2e3r4.tmp"]
    for path in stale:
        path.write_bytes(b"glTF partial")
    kept = [out / ".tile_r0_c0.ply.k2x9abcd.tmp", out / ".notes.k2x9abcd.tmp", out / "tile_r0_c0.glb.tmp",
            out / ".tile_r0_c0.glb.k2x9abcdef.tmp"]  # not this run's temporary files
    for path in kept:
        path.write_bytes(b"other")
    report = batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
    assert report.ok and len(report.done) == 4
    assert not any(p.exists() for p in stale)
    assert all(p.read_bytes() == b"other" for p in kept)
    # a skipped (complete) item's leftover goes too
    (out / ".tile_r0_c1.glb.abc_1234.tmp").write_bytes(b"glTF partial")
    report = batch(z, out, tile_size=4, interval=2.0, scheduler="serial")
    assert len(report.skipped) == 4 and not (out / ".tile_r0_c1.glb.abc_1234.tmp").exists()
