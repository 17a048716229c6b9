"""Close-up bugs found by an adversarial pass (each test failed before its fix)."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain import render
from stepterrain.closeup import ROI, CloseUp, render_closeups
from stepterrain.terrain import Terrain

from .test_closeup import hills

AVAILABLE, REASON = render.offscreen_available()
SIZE = (160, 120)


def terrain() -> Terrain:
    return Terrain.from_heights(hills(), spacing=(2.0, 2.0), origin=(1000.0, 2000.0))


def one(**kwargs) -> CloseUp:
    base = dict(scale=1.5, offset=(0.0, 0.0, 60.0), color="red")
    base.update(kwargs)
    return CloseUp(ROI.circle((1040.0, 2030.0), 12.0), **base)


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
