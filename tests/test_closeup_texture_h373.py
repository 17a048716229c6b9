"""Helper h373: close-up and overview textures placed as terrain_layer / ImagePyramid place images (pixel edges on
:func:`~stepterrain.texture.terrain_extent`, half a cell beyond the corner nodes), checked against an independent
NumPy reference; each test failed before its fix."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stepterrain import Terrain
from stepterrain.closeup import ROI, CloseUp, _overview_rgb, _texture_rgb, closeup_scene

#: colour steps a pixel's row (red) and column (green) are encoded with: bilinear sampling of a colour linear in
#: (row, col) is that linear function of the sampled continuous (row, col), so the colour says where it sampled
STEP = 5.0


def coded_image(h: int, w: int) -> np.ndarray:
    """(h, w, 3) uint8: red = STEP * row, green = STEP * col, blue 255 (row 0 north, as the texture= convention)."""
    assert STEP * (max(h, w) - 1) <= 255, (h, w)  # no wrap-around
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    return np.stack([STEP * rows, STEP * cols, np.full((h, w), 255.0)], axis=-1).astype(np.uint8)


def reference_pixel(xy: np.ndarray, edges: tuple[float, float, float, float], h: int, w: int) -> np.ndarray:
    """(n, 2) continuous (row, col) of the pixel grid whose OUTER EDGES are ``edges`` (xmin, xmax, ymin, ymax; row 0
    at ymax): pixel (i, j)'s centre at (xmin + (j + 0.5) * px, ymax - (i + 0.5) * py); clamped to the outer pixel
    centres (clamp-to-edge) beyond them."""
    xmin, xmax, ymin, ymax = edges
    col = (xy[:, 0] - xmin) / ((xmax - xmin) / w) - 0.5
    row = (ymax - xy[:, 1]) / ((ymax - ymin) / h) - 0.5
    return np.column_stack([np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)])


def decoded(rgb: np.ndarray) -> np.ndarray:
    return rgb[:, :2].astype(np.float64) / STEP


def grid(spacing=(30.0, -20.0), origin=(1000.0, 5000.0), shape=(9, 12)) -> Terrain:
    heights = np.add.outer(np.linspace(0.0, 5.0, shape[0]), np.linspace(0.0, 3.0, shape[1])).astype(np.float32)
    return Terrain.from_heights(heights, spacing=spacing, origin=origin)


def node_edges(t: Terrain) -> tuple[float, float, float, float]:
    """The terrain's node extent plus half a cell each side, computed here (not terrain_extent)."""
    xs = t.origin[0] + np.arange(t.heights.shape[1]) * t.spacing[0]
    ys = t.origin[1] + np.arange(t.heights.shape[0]) * t.spacing[1]
    hx, hy = abs(t.spacing[0]) / 2, abs(t.spacing[1]) / 2
    return xs.min() - hx, xs.max() + hx, ys.min() - hy, ys.max() + hy


SIZES = [(1.0, 1.0), (2.0, 2.0), (0.37, 0.37), (2.0, 0.5), (3.3, 1.0)]


@pytest.mark.parametrize("spacing", [(30.0, -20.0), (30.0, 20.0), (-7.5, 40.0)])
@pytest.mark.parametrize("kx, ky", SIZES)
def test_texture_pixel_edges_lie_on_the_terrain_extent(spacing, kx, ky):
    """A texture= image of (ky·H, kx·W) pixels over a grid of H x W nodes: its pixel edges lie on terrain_extent
    (the node extent plus half a cell), as terrain_layer and ImagePyramid place an image. The close-up path put its
    first and last pixel centres on the corner nodes instead: 1/4 cell off near the edges at 2 pixels a node (a
    sample at node 0 read pixel 0, not between pixels 0 and 1), 0.8 cell at 0.37 (0.82 on this 9 x 12 grid)."""
    t = grid(spacing)
    H, W = t.heights.shape
    h, w = max(2, round(ky * H)), max(2, round(kx * W))
    image = coded_image(h, w)
    edges = node_edges(t)
    rng = np.random.default_rng(373)
    xmin, xmax, ymin, ymax = edges
    inside = np.column_stack([rng.uniform(xmin, xmax, 400), rng.uniform(ymin, ymax, 400)])
    nodes = np.column_stack([a.ravel() for a in np.meshgrid(
        t.origin[0] + np.arange(W) * t.spacing[0], t.origin[1] + np.arange(H) * t.spacing[1])])
    beyond = np.array([[xmin - 50.0, ymax + 50.0], [xmax + 50.0, ymin - 50.0], [xmin, ymin], [xmax, ymax]])
    xy = np.concatenate([inside, nodes, beyond])
    got = decoded(_texture_rgb(t, image, xy))
    np.testing.assert_allclose(got, reference_pixel(xy, edges, h, w), atol=0.5 / STEP + 1e-9)
    if (h, w) == (H, W):  # one pixel a node: each node reads its own pixel exactly (north-up: row 0 at the max y)
        rows = (np.max(nodes[:, 1]) - nodes[:, 1]) / abs(t.spacing[1])
        cols = (nodes[:, 0] - np.min(nodes[:, 0])) / abs(t.spacing[0])
        np.testing.assert_array_equal(got[len(inside):len(inside) + len(nodes)], np.column_stack([rows, cols]))


@pytest.mark.parametrize("spacing", [(30.0, -20.0), (30.0, 20.0), (-7.5, 40.0), (-5.0, -5.0)])
def test_one_pixel_a_node_texture_matches_terrain_layer(spacing):
    """At one pixel a node the close-up's texture and terrain_layer's layer of the same picture agree at every
    node: texture_uv (where drape samples a layer) and the close-up's sampling read the same pixel."""
    from stepterrain.texture import terrain_layer, texture_uv

    t = grid(spacing)
    H, W = t.heights.shape
    north_up = coded_image(H, W)
    grid_order = north_up[::-1] if t.spacing[1] > 0 else north_up  # terrain_layer takes pixel (i, j) = node (i, j)
    grid_order = grid_order[:, ::-1] if t.spacing[0] < 0 else grid_order
    layer = terrain_layer(t, grid_order, "thematic")
    xy = np.asarray(t.mesh().vertices, np.float64)[:, :2]
    uv = texture_uv(np.column_stack([xy, np.zeros(len(xy))]), layer)
    col, row = uv[:, 0] * W - 0.5, (1.0 - uv[:, 1]) * H - 0.5  # uv (0, 0) at the south-west pixel corner
    np.testing.assert_allclose(decoded(_texture_rgb(t, north_up, xy)), np.column_stack([row, col]), atol=1e-9)


@pytest.mark.parametrize("kx, ky", SIZES)
def test_closeup_scene_colours_a_textured_closeup_by_the_pixel_edge_convention(kx, ky):
    """closeup_scene's close-up layer (a close-up lifted straight up: its vertices keep their xy) coloured by its
    texture= image at each vertex as the pixel-edge convention places the image."""
    t = grid((25.0, -25.0), (0.0, 0.0), (10, 14))
    H, W = t.heights.shape
    h, w = max(2, round(ky * H)), max(2, round(kx * W))
    xmin, xmax, ymin, ymax = t.extent
    # a rectangle reaching the terrain's corner: its edge vertices lie on the corner nodes
    roi = ROI.rectangle(((xmin + xmax) / 2, (ymin + ymax) / 2), (xmax - xmin, ymax - ymin), edge_width=0.0)
    cu = CloseUp(roi, offset=(0.0, 0.0, 100.0), texture=coded_image(h, w))
    scene = closeup_scene(t, [cu], scalars=None, device="cpu")
    faces = scene.faces[scene.face_attributes["layer"] == 1]
    used = np.unique(faces)
    xy = np.asarray(scene.vertices, np.float64)[used, :2]
    got = decoded(np.asarray(scene.visual.vertex_colors)[used, :3])
    np.testing.assert_allclose(got, reference_pixel(xy, node_edges(t), h, w), atol=0.5 / STEP + 1e-6)


def test_overview_texture_uses_the_same_placement():
    """The overview's texture= (render_closeups) samples at its mesh's vertices as a close-up's does, RGBA too."""
    t = grid((10.0, 10.0), (0.0, 0.0), (6, 7))
    image = coded_image(13, 5)
    mesh = t.mesh()
    xy = np.asarray(mesh.vertices, np.float64)[:, :2]
    expected = reference_pixel(xy, node_edges(t), 13, 5)
    np.testing.assert_allclose(decoded(_overview_rgb(t, mesh, None, "terrain", image)), expected, atol=0.5 / STEP)
    opaque = np.concatenate([image, np.full((13, 5, 1), 255, np.uint8)], axis=-1)
    opaque[0, 0, 3] = 254  # some alpha below 255: the RGBA path (laid over the tan by alpha ~1)
    got = decoded(_overview_rgb(t, mesh, None, "terrain", opaque))
    far = (expected[:, 0] > 1) | (expected[:, 1] > 1)  # away from the one translucent texel
    np.testing.assert_allclose(got[far], expected[far], atol=0.5 / STEP)


def test_a_tin_texture_spans_its_point_extent_by_pixel_edges():
    """A TIN has no cells: its texture's outer pixel edges lie on its point extent (ImagePyramid's extent is its
    image's outer pixel edges)."""
    rng = np.random.default_rng(5)
    pts = np.column_stack([rng.uniform(0.0, 100.0, 60), rng.uniform(0.0, 40.0, 60)])
    pts = np.concatenate([pts, [[0.0, 0.0], [100.0, 0.0], [0.0, 40.0], [100.0, 40.0]]])
    from scipy.spatial import Delaunay

    faces = Delaunay(pts).simplices
    t = Terrain.from_mesh(trimesh.Trimesh(np.column_stack([pts, np.zeros(len(pts))]), faces, process=False))
    image = coded_image(9, 21)
    got = decoded(_texture_rgb(t, image, pts))
    np.testing.assert_allclose(got, reference_pixel(pts, (0.0, 100.0, 0.0, 40.0), 9, 21), atol=0.5 / STEP + 1e-9)
