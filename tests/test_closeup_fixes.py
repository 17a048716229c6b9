"""Close-up bugs found by an adversarial pass (each test failed before its fix)."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain import render
from stepterrain.closeup import ROI, animate_closeups, render_closeups
from stepterrain.errors import InvalidInputError

from .test_closeup import hills
from .test_closeup_render import AVAILABLE, REASON, SIZE, one, terrain


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_reused_renderer_redraws_an_overview_texture_changed_in_place():
    # the overview was keyed by id(texture): a texture edited in place kept the old colours on a reused renderer
    t = terrain()
    texture = np.zeros((16, 16, 3), np.uint8)
    texture[..., 0] = 255
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")
        texture[..., 0], texture[..., 2] = 0, 255
        again = render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")
    finally:
        renderer.close()
    fresh = render_closeups(t, [one()], window_size=SIZE, texture=texture.copy(), device="cpu")
    assert np.array_equal(again, fresh)



@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_reused_renderer_knows_a_read_only_texture_by_identity(monkeypatch):
    """A read-only texture is a promise not to change it: its overview is found again without hashing its pixels
    every frame (a 3840 x 1920 image is 22 MB); the frames equal a fresh render."""
    import stepterrain.closeup as closeup_module

    t = terrain()
    texture = np.zeros((16, 16, 3), np.uint8)
    texture[..., 1] = 200
    texture.setflags(write=False)
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")

        def refuse(*args, **kwargs):
            raise AssertionError("a read-only texture was hashed")

        monkeypatch.setattr(closeup_module.hashlib, "blake2b", refuse)
        again = render_closeups(t, [one()], window_size=SIZE, renderer=renderer, texture=texture, device="cpu")
    finally:
        renderer.close()
    monkeypatch.undo()
    fresh = render_closeups(t, [one()], window_size=SIZE, texture=texture.copy(), device="cpu")
    assert np.array_equal(again, fresh)

@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
@pytest.mark.parametrize("option", [{"window_size": (320, 240)}, {"window_size": (320, 240), "cus": "billboard"},
                                    {"z_scale": 3.0}, {"z_scale": -1.0}, {"background": "black"}])
def test_render_closeups_refuses_options_its_renderer_does_not_have(option):
    # a renderer of 160x120 gave a 160x120 image for window_size=(320, 240) (a billboard: an error about a "box");
    # its z_scale silently replaced the one asked for (even a negative one)
    option = dict(option)
    cus = [one(view="billboard")] if option.pop("cus", None) else [one()]
    name = next(iter(option))
    renderer = render.LayeredRenderer(window_size=SIZE)
    try:
        with pytest.raises(InvalidInputError, match=name):
            render_closeups(terrain(), cus, renderer=renderer, device="cpu",
                            **{"window_size": SIZE, **option})  # fmt: skip
    finally:
        renderer.close()


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_animate_closeups_keeps_its_z_scale():
    # animate_closeups builds its renderer with z_scale: the frames must still render (and with that scale)
    t = terrain()
    flat, tall = (animate_closeups(t, [one(spin=(1.0, 1))], frames=1, window_size=SIZE, z_scale=z, device="cpu")[0]
                  for z in (1.0, 3.0))
    assert flat.shape == tall.shape == (SIZE[1], SIZE[0], 3)
    dark = animate_closeups(t, [one(spin=(1.0, 1))], frames=1, window_size=SIZE, background="black", device="cpu")[0]
    assert dark.shape == flat.shape and (dark[0, 0] == 0).all() and (flat[0, 0] == 255).all()
    assert not np.array_equal(flat, tall)


@pytest.mark.parametrize("make", [
    lambda: ROI.circle((0.0, 0.0), 5.0, edge_width=100.0),
    lambda: ROI.ellipse((0.0, 0.0), (10.0, 4.0), edge_width=4.5),
    lambda: ROI.rectangle((0.0, 0.0), (20.0, 8.0), edge_width=4.5),
    lambda: ROI.rounded_rectangle((0.0, 0.0), (20.0, 8.0), corner_radius=2.0, edge_width=5.0),
])
def test_soft_edge_wider_than_the_shape_is_refused(make):
    # m stayed below 1 everywhere (a circle of radius 5 with a 100-wide edge peaked at 0.007): a close-up with no
    # content, silently
    with pytest.raises(InvalidInputError, match="edge_width"):
        make()


def test_soft_edge_as_deep_as_the_shape_still_reaches_one():
    assert ROI.circle((0.0, 0.0), 5.0, edge_width=5.0).mask.max() == 1.0
    assert ROI.rectangle((0.0, 0.0), (20.0, 8.0), edge_width=4.0).mask.max() == 1.0


def test_cli_refuses_an_edge_wider_than_the_roi(tmp_path, capsys):
    import stepterrain.cli as cli

    dem = tmp_path / "dem.npy"
    np.save(dem, hills())
    assert cli.main(["-q", "closeup", str(dem), "--roi-relative", "0.5,0.5,0.1", "--edge", "1000",
                     "-o", str(tmp_path / "o.glb")]) == 2  # fmt: skip
    assert "--edge must be at most the ROI radius" in capsys.readouterr().err
    assert not (tmp_path / "o.glb").exists()
