"""Bugs found by a bug hunt over the texture code (``stepterrain texture``, stepterrain.texture, texture_lod)."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain.cli import main


def test_cli_texture_unknown_colormap_is_refused_before_the_dem_is_loaded(tmp_path, capsys, monkeypatch):
    """A mistyped --colormap was refused only after the DEM was loaded and its hillshade, shadows and occlusion
    computed (minutes on a large DEM), as the other options are not: now before any work, naming the option."""
    from stepterrain import _cli_texture

    def no_load(*args, **kwargs):
        raise AssertionError("the DEM was loaded before --colormap was checked")

    monkeypatch.setattr(_cli_texture, "_input_terrain", no_load)
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((20, 30)) * 100)
    out = tmp_path / "t.png"
    code = main(["texture", str(dem), "--shadows", "--colormap", "terain", "-o", str(out), "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and "--colormap must name a matplotlib colormap" in err and "'terain'" in err, err
    assert not out.exists()
