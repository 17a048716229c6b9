"""Regression tests for texture level-of-detail and camera bugs found by an adversarial hunt."""

from __future__ import annotations

import math
import os
import re
import warnings

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as hst

import stepterrain
from stepterrain import texture_lod
from stepterrain.camera import Camera
from stepterrain.errors import InvalidInputError
from stepterrain.terrain import as_terrain
from stepterrain.texture_lod import ImagePyramid, PatchQuadtree, TextureTree, render_with_textures

from .reference_lod import approximation_error_reference
from .reference_texture import real_dem_crop, reduce_rounded_reference
from .test_texture_lod import big_memmap_npy, pyramid_build_rise


@pytest.mark.parametrize("fov", [1e-310, 1e-320, 5e-324])
def test_a_field_of_view_too_narrow_for_a_finite_focal_length_is_named(fov):
    """tan(fov / 2) of a subnormal fov made the focal length in pixels inf: the screen-space errors γ and τ came out
    NaN, compared false with the thresholds, and the traversal drew the root at the coarsest texture level."""
    with pytest.raises(InvalidInputError, match=r"Camera fov must be wide enough for a finite focal length .*; got "
                                                 r"fov="):
        Camera((32.0, -60.0, 40.0), (32.0, 32.0, 0.0), fov=fov)


def test_a_narrow_but_finite_field_of_view_refines_to_full_resolution():
    heights = np.random.default_rng(0).normal(0.0, 5.0, (65, 65)).astype(np.float32)
    quadtree = PatchQuadtree(heights, leaf_size=8)
    image = np.random.default_rng(1).integers(0, 256, (256, 256, 3), dtype=np.uint8)
    with ImagePyramid.build(image, extent=quadtree.root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=32)
        camera = Camera((32.0, -60.0, 40.0), (32.0, 32.0, 0.0), fov=1e-300)  # a huge magnification
        items = render_with_textures(quadtree.root, [tree.root], camera)
        assert items and all(item.geometry.is_leaf and item.textures[0].level == 0 for item in items)


@pytest.mark.parametrize("kind", ["array", "read-only view", "writeable memmap"])
def test_a_pyramid_keeps_its_image_when_the_source_array_is_edited_afterwards(tmp_path, kind):
    """Level 0 was the caller's array itself: editing it after build changed level 0 but none of the coarser levels,
    so the pyramid served two different images by level without a word (and writing into pyramid.levels[0]
    edited the caller's image)."""
    rng = np.random.default_rng(3)
    original = rng.integers(0, 256, (13, 10, 3), dtype=np.uint8)
    if kind == "writeable memmap":
        source = np.lib.format.open_memmap(tmp_path / "image.npy", mode="w+", dtype=np.uint8, shape=original.shape)
        source[:] = original
        edit = source
    else:
        edit = original.copy()
        source = edit if kind == "array" else edit.view()
        if kind == "read-only view":
            source.flags.writeable = False  # the pixels still change through the array it views
    with ImagePyramid.build(source, device="cpu") as pyramid:
        expected = [np.array(level) for level in pyramid.levels]
        edit[:] = 255 - edit
        assert np.array_equal(pyramid.levels[0], original)
        assert all(np.array_equal(level, copy) for level, copy in zip(pyramid.levels, expected, strict=True))
        with pytest.raises(ValueError, match="read-only"):
            pyramid.levels[0][0, 0] = 7


def test_a_pyramid_over_a_read_only_source_is_not_copied(tmp_path):
    """A source nothing can change (a .npy opened memory-mapped read-only) stays level 0 as it is: no snapshot."""
    image = np.random.default_rng(4).integers(0, 256, (9, 9, 1), dtype=np.uint8)
    np.save(tmp_path / "image.npy", image)
    storage = tmp_path / "levels"
    with ImagePyramid.build(tmp_path / "image.npy", storage=storage, device="cpu") as pyramid:
        assert str(pyramid.levels[0].filename) == str(tmp_path / "image.npy")
        assert sorted(p.name for p in storage.iterdir()) == ["level_1.u8", "level_2.u8", "level_3.u8", "level_4.u8"]


# ------------------------------------------------------------------------------------------ fuzzing (h9)
CAMERA = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
BAD_BOXES = [None, "box", [(0.0, 0.0, 0.0)], np.zeros((2, 2)), [("a", "b", "c"), ("d", "e", "f")],
             [(1.0, 1.0, 1.0), (0.0, 0.0, 0.0)], [(np.nan, 0.0, 0.0), (1.0, 1.0, 1.0)], np.zeros((3, 3))]


@pytest.mark.parametrize("method", ["box_visible", "nearest_point"])
@pytest.mark.parametrize("box", BAD_BOXES, ids=["None", "str", "one corner", "2x2", "text", "max<min", "NaN", "3x3"])
def test_a_camera_box_that_is_not_min_and_max_corners_is_named(method, box):
    """Unpacking, broadcasting and indexing errors (TypeError, ValueError, IndexError) escaped, or a wrong answer
    came back (a 3 x 3 array clipped the eye to its first two rows; max < min clipped it anywhere)."""
    with pytest.raises(InvalidInputError, match=r"^box must be an axis-aligned box"):
        getattr(CAMERA, method)(box)


@pytest.mark.parametrize("point", [None, "abc", (1.0, 2.0), (0.0, 0.0, np.nan), np.zeros((2, 3))])
def test_segment_pixels_names_a_point_that_is_not_a_3d_point(point):
    """np.stack raised numpy's "all input arrays must have the same shape"; NaN came back as NaN pixels."""
    with pytest.raises(InvalidInputError, match=r"^b must be a finite world point"):
        CAMERA.segment_pixels(np.zeros(3), point)


def test_camera_box_methods_keep_their_answers():
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert CAMERA.box_visible(box) and CAMERA.box_visible(box.tolist())
    np.testing.assert_array_equal(CAMERA.nearest_point(box), [0.0, 0.0, 1.0])
    assert CAMERA.segment_pixels([0.0, 0.0, 0.0], (1.0, 0.0, 0.0)) == CAMERA.segment_pixels(np.zeros(3), np.eye(3)[0])


def test_a_ragged_pyramid_image_is_named():
    """np.asarray of ragged rows raised numpy's "inhomogeneous shape" ValueError, naming no argument."""
    with pytest.raises(InvalidInputError, match=r"^image must be .*got rows of different lengths"):
        ImagePyramid.build([[1, 2], [3]], extent=(0, 2, 0, 2), device="cpu")


@pytest.mark.parametrize("shape", [(27, 46, 3), (14, 23, 3), (31, 18, 2), (25, 40, 4)])
def test_pyramid_levels_round_the_exact_area_weighted_mean_half_up(shape):
    """With an odd dimension reduce_band summed the area weights (overlap / n, 0.6 and 0.4 for 5 -> 3) in float32,
    so a mean exactly halfway between two grey levels (3 A + 2 B = 10 k + 5) came out just below it now and then
    and rounded down: a level one grey level off the exact mean, where the even 2 x 2 path rounds half up."""
    image = np.random.default_rng(27).integers(0, 256, shape, dtype=np.uint8)
    with ImagePyramid.build(image, device="cpu") as pyramid:
        previous = image
        for level in pyramid.levels[1:]:
            np.testing.assert_array_equal(level, reduce_rounded_reference(previous))
            previous = np.asarray(level)


# ------------------------------------------------------------------------------------------ shared storage (h5)
def test_a_pyramid_keeps_its_levels_when_another_is_built_into_its_storage(tmp_path, monkeypatch):
    """A second build into the storage folder of an open pyramid wrote over its level files: the first pyramid's
    levels showed the second image (and read past a smaller one's shortened files: zeros, or a SIGBUS crash), and a
    build that failed half-way left truncated files in place of the earlier complete ones. The level files are now
    written under temporary names and renamed into place once all are complete."""
    from stepterrain import texture_lod

    storage = tmp_path / "levels"
    rng = np.random.default_rng(5)
    first_image, second_image = rng.integers(0, 256, (2, 37, 29, 3), dtype=np.uint8)
    first = ImagePyramid.build(first_image, storage=storage, anisotropic=True, device="cpu")
    expected = [np.array(level) for level in first.levels]
    expected_rip = {key: np.array(level) for key, level in first.anisotropic.items()}
    np.testing.assert_array_equal(expected[1], reduce_rounded_reference(first_image))
    names = sorted(p.name for p in storage.iterdir())
    with ImagePyramid.build(second_image, storage=storage, anisotropic=True, device="cpu") as second:
        np.testing.assert_array_equal(second.levels[1], reduce_rounded_reference(second_image))
        assert not np.array_equal(second.levels[1], expected[1])
        for level, copy in zip(first.levels, expected, strict=True):
            np.testing.assert_array_equal(level, copy)
        for key, level in first.anisotropic.items():
            np.testing.assert_array_equal(level, expected_rip[key])
        assert sorted(p.name for p in storage.iterdir()) == names  # the second's files under the level names
        saved = {name: (storage / name).read_bytes() for name in names}

    calls = []

    def failing(*args, **kwargs):  # a build that fails at its third level (disk full, killed)
        calls.append(1)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real(*args, **kwargs)

    real = texture_lod._reduce_file
    monkeypatch.setattr(texture_lod, "_reduce_file", failing)
    with pytest.raises(OSError):
        ImagePyramid.build(first_image, storage=storage, device="cpu")
    assert sorted(p.name for p in storage.iterdir()) == names  # no temporary file left, no level file touched
    assert all((storage / name).read_bytes() == data for name, data in saved.items())
    first.close()


@pytest.mark.parametrize(
    ("transform", "extent"),
    [
        ((2.0, 1e-17, 100.0, -1e-17, -2.0, 50.0), (100.0, 120.0, 34.0, 50.0)),  # float noise: placed, as load_dem does
        ((2.0, 0.1, 100.0, 0.1, -2.0, 50.0), None),  # a real rotation: refused by name
    ],
)
def test_a_geotiff_texture_with_rotation_terms_is_judged_like_its_dem(tmp_path, transform, extent):
    """Any non-zero rotation term sent a GeoTIFF back to pixel units, (0, W, 0, H), without a word: terms of float
    noise (1e-17) that load_dem reads as north-up put the texture nowhere near its DEM, and a really rotated image
    was draped as if north-up over a made-up extent."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    path = tmp_path / "texture.tif"
    with rasterio.open(path, "w", driver="GTiff", height=8, width=10, count=3, dtype="uint8", crs="EPSG:32633",
                       transform=Affine(*transform)) as dataset:  # fmt: skip
        dataset.write(np.zeros((3, 8, 10), np.uint8))
    if extent is None:
        with pytest.raises(InvalidInputError, match=r"texture\.tif' is georeferenced with a rotated geotransform "
                                                    r"\(2\.0, 0\.1, .*gdalwarp.*pass extent="):
            ImagePyramid.build(path, device="cpu")
        with ImagePyramid.build(path, extent=(0.0, 10.0, 0.0, 8.0), device="cpu") as pyramid:  # placed by the caller
            assert pyramid.extent == (0.0, 10.0, 0.0, 8.0)
    else:
        with ImagePyramid.build(path, device="cpu") as pyramid:
            assert pyramid.extent == pytest.approx(extent, abs=1e-9)


@pytest.mark.parametrize("anisotropic", [False, True])
def test_a_pyramid_of_a_memmap_whose_file_was_replaced_reads_the_mapped_pixels(tmp_path, anisotropic):
    """build read a memmap source through its file name: a level of a pyramid whose storage a later build reused
    (its file replaced by one of the same size) gave levels 1+ of the other image under level 0 of this one."""
    first = ImagePyramid.build(np.full((16, 16, 3), 10, np.uint8), storage=tmp_path, device="cpu")
    level = first.levels[1]  # maps tmp_path / level_1.u8
    ImagePyramid.build(np.full((16, 16, 3), 250, np.uint8), storage=tmp_path, device="cpu")  # replaces that file
    with ImagePyramid.build(level, anisotropic=anisotropic, device="cpu") as pyramid:
        assert [int(v.max()) for v in pyramid.levels] == [10, 10, 10, 10]
        assert all(int(v.max()) == 10 for v in pyramid.anisotropic.values())
    first.close()


def _drawn_lines(first, count, stride):
    """The block's lines (0-based) a patch whose first line is grid line ``first`` draws: the grid's multiples of the
    stride within it and its two ends."""
    return sorted({0, count - 1, *(k - first for k in range(first, first + count) if k % stride == 0)})


def _drawn_mesh_error(block, stride, spacing, corner=(0, 0)):
    """e(N) by brute force: every node with data against every drawn triangle of the coarse mesh containing it
    (paint_with_textures' mesh: grid_faces' split, no triangle with a nodata corner); a node with data no triangle
    covers, or a node without data a triangle covers, counts as the coarse cell's diagonal. A leaf (stride 1) is the
    terrain itself: 0."""
    if stride == 1:
        return 0.0
    rows, cols = block.shape
    ri, ci = _drawn_lines(corner[0], rows, stride), _drawn_lines(corner[1], cols, stride)
    triangles = []
    for k in range(len(ri) - 1):
        for m in range(len(ci) - 1):
            n00, n01 = (ri[k], ci[m]), (ri[k], ci[m + 1])
            n10, n11 = (ri[k + 1], ci[m]), (ri[k + 1], ci[m + 1])
            for tri in ((n00, n01, n11), (n00, n11, n10)):
                if all(np.isfinite(block[p]) for p in tri):
                    triangles.append(tri)
    worst = 0.0
    for i in range(rows):
        for j in range(cols):
            data = bool(np.isfinite(block[i, j]))
            covered = False
            for (r0, c0), (r1, c1), (r2, c2) in triangles:
                det = (r1 - r0) * (c2 - c0) - (r2 - r0) * (c1 - c0)
                w1 = ((i - r0) * (c2 - c0) - (r2 - r0) * (j - c0)) / det
                w2 = ((r1 - r0) * (j - c0) - (i - r0) * (c1 - c0)) / det
                if min(w1, w2, 1.0 - w1 - w2) < -1e-12:
                    continue
                covered = True
                if data:
                    value = (1 - w1 - w2) * block[r0, c0] + w1 * block[r1, c1] + w2 * block[r2, c2]
                    worst = max(worst, abs(float(block[i, j]) - float(value)))
            if covered != data:  # ground left undrawn, or a void drawn over
                worst = max(worst, stride * float(np.hypot(*spacing)))
    return worst


def test_the_geometric_error_is_the_distance_to_the_drawn_mesh_near_nodata_too():
    """e(N) was measured against a bilinear surface (up to a quarter of a cell's twist off the two triangles a
    patch is drawn with) and skipped every cell with a nodata corner: beside a hole the terrain's error went
    unmeasured, and terrain with data that the coarse mesh leaves undrawn (its hole around a nodata node is a coarse
    cell wider) counted as 0, so a flat DEM with one void drew its root with a hole 2 × stride cells wide from
    any distance."""
    rng = np.random.default_rng(0)
    heights = np.cumsum(np.cumsum(rng.normal(0.0, 1.0, (33, 33)), 0), 1).astype(np.float32)
    heights[8:11, 15:18] = np.nan  # a void over the coarse node (8, 16)
    heights[20, 4] = heights[3, 27] = np.nan
    spacing = (2.0, -1.5)
    quadtree = PatchQuadtree(heights, leaf_size=4, spacing=spacing)
    for patch in quadtree.patches():
        block = heights[patch.rows[0]: patch.rows[1] + 1, patch.cols[0]: patch.cols[1] + 1].astype(np.float64)
        corner = patch.rows[0], patch.cols[0]
        assert patch.error == pytest.approx(_drawn_mesh_error(block, patch.stride, spacing, corner), rel=1e-9, abs=1e-9)
    flat = np.zeros((33, 33), np.float32)
    flat[16, 16] = np.nan  # one void, on a node of the root's coarse mesh
    root = PatchQuadtree(flat, leaf_size=4).root
    assert root.error == pytest.approx(8 * np.sqrt(2.0))  # stride 8: the undrawn ground is up to a cell across
    camera = Camera((16.0, -10.0, 20.0), (16.0, 16.0, 0.0))
    with ImagePyramid.build(np.zeros((32, 32, 3), np.uint8), extent=root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, PatchQuadtree(flat, leaf_size=4), max_texture_size=64)
        items = render_with_textures(tree.quadtree.root, [tree.root], camera, gamma_user=1.0)
        assert any(item.geometry.stride == 1 for item in items)  # refined near the void, not drawn at the root


def test_a_painted_patch_leaves_nodata_out_as_heightfield_mesh_does():
    """paint_with_textures kept NaN heights as vertices: every patch over a void gave a mesh with NaN vertices
    and faces spanning the void (NaN areas and normals; an export of it is broken)."""
    from stepterrain.terrain import heightfield_mesh
    from stepterrain.texture_lod import paint_with_textures

    heights = np.random.default_rng(2).normal(0.0, 1.0, (17, 17)).astype(np.float32)
    heights[8, 8] = heights[3, 12] = np.nan
    quadtree = PatchQuadtree(heights, leaf_size=8)
    camera = Camera((8.0, -1.0, 3.0), (8.0, 8.0, 0.0))  # close: every leaf drawn at full resolution
    with ImagePyramid.build(np.full((32, 32, 3), 90, np.uint8), extent=quadtree.root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        items = render_with_textures(quadtree.root, [tree.root], camera)
        assert len(items) == 4 and all(item.geometry.is_leaf for item in items)
        meshes = [paint_with_textures(item) for item in items]
    assert all(np.isfinite(mesh.vertices).all() for mesh in meshes)
    assert sum(len(mesh.faces) for mesh in meshes) == len(heightfield_mesh(heights).faces)  # 512 - 6 - 2 faces
    assert sum(mesh.area for mesh in meshes) == pytest.approx(heightfield_mesh(heights).area)


def test_a_writeable_memmap_is_copied_into_storage_with_memory_bounded(tmp_path):
    """The copy of a writeable memmap into storage (level_0.u8) read it through its mapping, band by band, but left
    every page resident: the peak resident set rose by the whole image (48 MB here), not about a band."""
    source = big_memmap_npy(tmp_path)
    rise = pyramid_build_rise(f"np.load({str(source)!r}, mmap_mode='r+')",  # writeable: copied into storage first
                              1 << 20, check="assert 25 <= int(pyramid.levels[-1][0, 0, 0]) <= 32")
    assert rise < 20 * 1024**2, f"peak resident set rose by {rise / 1024**2:.1f} MB for a 48 MB image"


def test_a_copy_on_write_memmap_keeps_its_edits_through_a_build(tmp_path):
    """Dropping a band's pages after reading it (to keep the resident set small) must spare a copy-on-write map: its
    edits live in those pages only, and madvise(MADV_DONTNEED) would put the file's pixels back under the caller."""
    np.save(tmp_path / "image.npy", np.zeros((256, 256, 3), np.uint8))
    image = np.load(tmp_path / "image.npy", mmap_mode="c")
    image[:] = 77  # edits in memory only
    with ImagePyramid.build(image, band_bytes=1 << 14, device="cpu") as pyramid:
        assert [int(level.min()) for level in pyramid.levels] == [77] * len(pyramid.levels)
    assert int(image.min()) == int(image.max()) == 77
    assert int(np.load(tmp_path / "image.npy").max()) == 0  # and the file as it was


def test_a_memmap_band_is_copied_without_its_whole_mapping_resident(tmp_path):
    """Reading a memmap source through its mapping copied a whole band while all of the band's mapped pages were
    resident, and only then dropped them: the peak rose by a band more than pread's copy (52 MB against 40 MB
    for 16 MB bands of a 48 MB image; the benchmark's 16384 x 8192 pyramid 83 -> 119 MB). The band is now copied a
    few MiB at a time, each piece's pages dropped at once."""
    rise = pyramid_build_rise(repr(str(big_memmap_npy(tmp_path))), 16 << 20)
    assert rise < 46 * 1024**2, f"peak resident set rose by {rise / 1024**2:.1f} MB with 16 MB bands"


def test_a_geotiff_texture_in_feet_drapes_its_dem_in_feet_read_as_metres(tmp_path):
    """load_dem reads a DEM in a CRS in feet (EPSG:2229, US survey feet) as metres, but the pyramid of an orthophoto
    in the same CRS kept its bounds in feet: TextureTree refused the pair as a "mismatched extent" (6.4e6 ft against
    1.95e6 m). The bounds become metres by the same factor, so the texture's pixels cover the DEM's cells as rasterio
    places both (the DEM's node (0, 0) at the centre of its first cell, a texture pixel of half its size)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.io import load_dem

    dem, ortho = tmp_path / "dem_ft.tif", tmp_path / "ortho_ft.tif"
    with rasterio.open(dem, "w", driver="GTiff", height=17, width=17, count=1, dtype="float32", crs="EPSG:2229",
                       transform=Affine(10.0, 0.0, 6.4e6, 0.0, -10.0, 1.9e6)) as dataset:  # fmt: skip
        dataset.write(np.zeros((1, 17, 17), np.float32))
        dataset.units = ["US survey foot"]
    with rasterio.open(ortho, "w", driver="GTiff", height=34, width=34, count=3, dtype="uint8", crs="EPSG:2229",
                       transform=Affine(5.0, 0.0, 6.4e6, 0.0, -5.0, 1.9e6)) as dataset:  # fmt: skip
        dataset.write(np.zeros((3, 34, 34), np.uint8))
    terrain = load_dem(dem)
    foot = 1200 / 3937
    with ImagePyramid.build(ortho, device="cpu") as pyramid:
        assert pyramid.extent == pytest.approx((6.4e6 * foot, 6.40017e6 * foot, 1.89983e6 * foot, 1.9e6 * foot),
                                               rel=1e-12)
        x0, x1, y0, y1 = terrain.extent  # the nodes: half a cell (5 ft) inside the texture's edges
        assert (x0 - pyramid.extent[0], pyramid.extent[1] - x1) == pytest.approx((5 * foot, 5 * foot), rel=1e-6)
        assert (y0 - pyramid.extent[2], pyramid.extent[3] - y1) == pytest.approx((5 * foot, 5 * foot), rel=1e-6)
        tree = TextureTree(pyramid, PatchQuadtree(terrain, leaf_size=8))
        assert tree.root is not None


@pytest.mark.parametrize("size", [(8, 12), (9, 13)])  # the 2 x 2 box path and the area-weighted one
def test_pyramid_levels_of_an_image_with_alpha_take_no_colour_from_transparent_pixels(size):
    """A straight-alpha image with a transparent collar (RGB 0, alpha 0, as gdalwarp -dstalpha writes outside the
    data) was averaged channel by channel: the collar's black bled into every coarser level's edge pixels, white
    land becoming (128, 128, 128, 128), a dark rim once composited. The colour is averaged weighted by alpha (the
    premultiplied mean over the mean alpha), so the edge is white at half alpha; RGBA and grey + alpha alike."""
    rows, cols = size
    image = np.zeros((rows, cols, 4), np.uint8)
    image[:, : cols // 2 + 1] = (255, 255, 255, 255)  # white land, then the transparent black collar
    grey_alpha = image[..., [0, 3]]
    for source in (image, grey_alpha):
        with ImagePyramid.build(source, device="cpu") as pyramid:
            for level in pyramid.levels[1:]:
                level = np.asarray(level)
                seen = level[..., -1] > 0
                assert seen.any() and (level[..., -1] < 255).any()  # some edge pixels are partly transparent
                assert (level[seen][:, :-1] == 255).all()  # every pixel that shows anything shows white
    rgba = np.random.default_rng(8).integers(0, 256, (rows, cols, 4), dtype=np.uint8)
    rgba[..., 3] *= np.random.default_rng(9).random((rows, cols)) < 0.5  # half the pixels transparent
    with ImagePyramid.build(rgba, device="cpu") as pyramid:
        previous = rgba
        for level in pyramid.levels[1:]:
            np.testing.assert_array_equal(level, reduce_rounded_reference(previous))
            previous = np.asarray(level)


def test_a_16_bit_geotiffs_read_stays_near_the_memory_budgets_count(tmp_path):
    """ImagePyramid.build of a 16-bit multi-band GeoTIFF (read with rasterio since ff1b0cd) checked the read against
    the memory budget at 4 bytes a cell (as load_dem counts a raster) and then scaled all bands at once through
    float64 (value / 257, then np.round): 18 bytes a cell at its peak, so an orthophoto the budget let through took
    four and a half times what it counted. The bands are now read and scaled one at a time in integers (the same
    bytes: v / 257 is never halfway between two integers): the read's peak stays under the 4 bytes counted."""
    rasterio = pytest.importorskip("rasterio")
    import tracemalloc

    from rasterio.transform import Affine

    rows, cols = 512, 512
    data = np.random.default_rng(8).integers(0, 65536, (3, rows, cols)).astype(np.uint16)
    data[0, :128] = np.arange(65536).reshape(128, 512)  # every 16-bit value
    with rasterio.open(tmp_path / "rgb16.tif", "w", driver="GTiff", height=rows, width=cols, count=3, dtype="uint16",
                       crs="EPSG:32611", transform=Affine(1.0, 0.0, 0.0, 0.0, -1.0, float(rows))) as out:
        out.write(data)
    from stepterrain.texture_lod import _raster_uint8

    _raster_uint8(tmp_path / "rgb16.tif")  # the imports' and GDAL's one-time allocations, not counted
    tracemalloc.start()
    try:
        image = _raster_uint8(tmp_path / "rgb16.tif")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(image, np.moveaxis(np.round(data / 257.0).astype(np.uint8), 0, 2))
    assert peak < 4 * data.size, f"{peak / data.size:.1f} bytes a cell"


def test_a_geotiff_texture_in_degrees_drapes_its_dem_in_degrees_read_as_local_metres(tmp_path):
    """The most common GIS case: an SRTM DEM in EPSG:4326 (the Front Range) and an orthophoto in EPSG:4326 over it.
    load_dem reads the DEM into local equirectangular metres, so the image's extent in degrees was refused as another
    CRS (the user had to copy an extent out of the message). The tree places it through the exact, linear map of
    those metres: every painted vertex of an image on the DEM's own grid, each pixel coding its row and column,
    samples its own node's pixel, for longitudes given in -180..180 or 0..360 alike; an image of another body (a
    sphere of Mars' radius) is still refused."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.io import load_dem
    from stepterrain.texture_lod import paint_with_textures

    from .reference_texture import find_shared

    source = find_shared("front_range_srtmgl3_3arcsec.tif")
    terrain = load_dem(source)
    with rasterio.open(source) as dataset:
        profile, transform = dataset.profile, dataset.transform
    profile.update(count=3, dtype="uint8", nodata=None, predictor=1)
    rows, cols = np.indices(terrain.shape)
    code = np.stack([rows % 256, cols % 256, 16 * (rows // 256) + cols // 256]).astype(np.uint8)
    east = tmp_path / "ortho.tif"
    with rasterio.open(east, "w", **profile) as out:
        out.write(code)
    shifted = tmp_path / "ortho_360.tif"
    with rasterio.open(shifted, "w", **{**profile, "transform": Affine.translation(360.0, 0.0) @ transform}) as out:
        out.write(code)
    (x0, y0), (dx, dy) = terrain.origin, terrain.spacing
    for path in (east, shifted):
        with ImagePyramid.build(path, device="cpu") as pyramid:
            assert pyramid.crs == "EPSG:4326"
            tree = TextureTree(pyramid, PatchQuadtree(terrain, leaf_size=128), max_texture_size=1024)
            assert tree.root.level == 0 and tree.root.window == (0, 758, 0, 758)
            camera = Camera((x0 + 400 * dx, y0 + 900 * dy, 3e4), (x0 + 400 * dx, y0 + 400 * dy, 3000.0))
            painted = 0
            for item in render_with_textures(tree.quadtree.root, [tree.root], camera):
                mesh = paint_with_textures(item)
                image = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
                height, width = image.shape[:2]
                u, v = mesh.visual.uv.T
                texels = image[np.minimum((1.0 - v) * height, height - 1).astype(int),
                               np.minimum(u * width, width - 1).astype(int)]
                node_rows = np.rint((mesh.vertices[:, 1] - y0) / dy).astype(int)
                node_cols = np.rint((mesh.vertices[:, 0] - x0) / dx).astype(int)
                np.testing.assert_array_equal(texels, code[:, node_rows, node_cols].T)
                painted += len(mesh.vertices)
            assert painted > 10_000
        with pytest.raises(InvalidInputError, match=r"^the ImagePyramid is closed"):  # the view reads through it
            tree.pyramid.sub_image(0, (0, 1, 0, 1))
    with ImagePyramid.build(east, extent=(0, 1, 0, 1), crs="+proj=longlat +R=3396190 +no_defs",
                            device="cpu") as pyramid:
        with pytest.raises(InvalidInputError, match=r"^the image is in CRS .*mismatched CRS.*radius 6371008.8 m.*"
                                                    r"radius 3396190 m"):
            TextureTree(pyramid, PatchQuadtree(terrain))


def test_an_image_in_a_west_positive_geographic_crs_is_refused_on_a_dem_in_degrees():
    """An image whose CRS's longitudes increase westwards (AXIS["Longitude",WEST]): its extent puts column 0 at
    xmin, the smallest west longitude, the east edge, so the image runs east to west; placed as east degrees it drew
    mirrored without a word. The tree refuses it, saying why; the same image in EPSG:4326 is placed."""
    pytest.importorskip("rasterio")
    from stepterrain.io import load_dem

    from .reference_texture import find_shared

    west = ('GEOGCS["WGS 84 west-positive",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
            'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AXIS["Latitude",NORTH],AXIS["Longitude",WEST]]')
    terrain = load_dem(find_shared("front_range_srtmgl3_3arcsec.tif"))
    image = np.zeros((8, 8, 3), np.uint8)
    with ImagePyramid.build(image, extent=(105.2, 105.8, 39.9, 40.4), crs=west, device="cpu") as pyramid:
        with pytest.raises(InvalidInputError, match=r"^the image is in CRS .*longitude axis increases westwards.*"
                                                    r"runs east to west.*EPSG:4326"):
            TextureTree(pyramid, PatchQuadtree(terrain))
    with ImagePyramid.build(image, extent=(-105.8, -105.2, 39.9, 40.4), crs="EPSG:4326", device="cpu") as pyramid:
        assert TextureTree(pyramid, PatchQuadtree(terrain)).root is not None


@pytest.mark.parametrize("dtype", ["uint8", "uint16"])  # Pillow reads the pixels / rasterio does
def test_a_geotiff_pyramid_opens_the_file_with_rasterio_once(tmp_path, monkeypatch, dtype):
    """A GeoTIFF texture was opened with rasterio two or three times per build: for its pixels (a 16-bit one),
    its nodata mask and its extent. One open now reads all three, with the same pixels, alpha and extent."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    rgb = np.random.default_rng(0).integers(1, 255, (3, 6, 8), dtype=np.uint8)
    rgb[:, :, :2] = 0  # a nodata collar
    scale = 257 if dtype == "uint16" else 1
    with rasterio.open(tmp_path / "ortho.tif", "w", driver="GTiff", height=6, width=8, count=3, dtype=dtype,
                       crs="EPSG:32611", nodata=0, transform=Affine(2.0, 0.0, 376000.0, 0.0, -2.0, 3808000.0)) as out:
        out.write(rgb.astype(dtype) * scale)
    opened = []
    real_open = rasterio.open
    monkeypatch.setattr(rasterio, "open", lambda *args, **kwargs: opened.append(args) or real_open(*args, **kwargs))
    with ImagePyramid.build(tmp_path / "ortho.tif", device="cpu") as pyramid:
        level = np.asarray(pyramid.levels[0])
        assert len(opened) == 1
        assert pyramid.extent == (376000.0, 376016.0, 3807988.0, 3808000.0) and pyramid.crs == "EPSG:32611"
        np.testing.assert_array_equal(level[..., :3], rgb.transpose(1, 2, 0))
        np.testing.assert_array_equal(level[..., 3], np.where(rgb[0] > 0, 255, 0))


def test_an_image_pillow_decodes_is_checked_against_the_memory_budget_and_a_big_tiff_reads_with_rasterio(
        tmp_path, monkeypatch):
    """ImagePyramid.build decoded a PNG or JPEG whole with Pillow whatever the memory budget (only a TIFF read with
    rasterio was checked), and an image past Pillow's decompression-bomb limit raised Pillow's own
    DecompressionBombError, a TIFF too, though rasterio reads it. Now the decode is checked first (an
    OutputTooLargeError naming the file), a TIFF past Pillow's limit is read with rasterio, and a PNG past it is a
    DataFileError naming it. (A PNG Pillow reads as RGB is read a band of rows at a time since: no decode to check,
    test_an_image_file_pyramid_is_built_a_band_of_rows_at_a_time; a JPEG is still decoded whole.)"""
    import PIL.Image

    import stepterrain as st
    from stepterrain.errors import DataFileError, OutputTooLargeError
    from stepterrain.texture_lod import ImagePyramid

    pixels = np.random.default_rng(5).integers(0, 256, (60, 80, 3), dtype=np.uint8)
    png = tmp_path / "map.png"
    PIL.Image.fromarray(pixels).save(png)
    jpeg = tmp_path / "map.jpg"
    PIL.Image.fromarray(pixels).save(jpeg)
    previous = st.set_memory_budget(4 * 60 * 80 * 3 - 1)  # the check counts 4 bytes a sample, as rasterio's read
    try:
        with pytest.raises(OutputTooLargeError, match=r"reading '.*map\.jpg' \(the image: 3 x 60 x 80 cells"):
            ImagePyramid.build(jpeg, device="cpu")
    finally:
        st.set_memory_budget(previous)
    rasterio = pytest.importorskip("rasterio")
    from rasterio.errors import NotGeoreferencedWarning

    tif = tmp_path / "map.tif"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)  # a plain TIFF, on purpose
        with rasterio.open(tif, "w", driver="GTiff", height=60, width=80, count=3, dtype="uint8") as out:
            out.write(np.moveaxis(pixels, 2, 0))
    monkeypatch.setattr(PIL.Image, "MAX_IMAGE_PIXELS", 1000)  # 4800 pixels: past twice the limit, an error
    with ImagePyramid.build(tif, device="cpu") as pyramid:
        assert np.array_equal(pyramid.levels[0], pixels)
    with pytest.raises(DataFileError, match=r"cannot read '.*map\.png' as an image: .*decompression bomb"):
        ImagePyramid.build(png, device="cpu")


def _bilinear(image, extent, x, y):
    """A texture sampler's colours (bilinear, texel centres at half-pixels, clamped to the edge) of ``image`` over
    ``extent`` at world points (x, y). Only the four pixels around each point are taken as float64 (not the whole
    image: a level of the Blue Marble, 22 million values, once per patch)."""
    image = np.asarray(image)
    rows, cols = image.shape[:2]
    xmin, xmax, ymin, ymax = extent
    u = np.clip((x - xmin) / (xmax - xmin) * cols - 0.5, 0, cols - 1)
    v = np.clip((ymax - y) / (ymax - ymin) * rows - 0.5, 0, rows - 1)
    c0, r0 = np.minimum(np.floor(u).astype(int), cols - 2), np.minimum(np.floor(v).astype(int), rows - 2)
    fu, fv = (u - c0)[:, None], (v - r0)[:, None]

    def at(r, c):
        return image[r, c].astype(np.float64)

    return (at(r0, c0) * (1 - fu) * (1 - fv) + at(r0, c0 + 1) * fu * (1 - fv)
            + at(r0 + 1, c0) * (1 - fu) * fv + at(r0 + 1, c0 + 1) * fu * fv)


def _painted_against_level(tree, patch, level_image, level_extent):
    """The largest difference (grey levels) between the colours paint_with_textures gives the vertices of ``patch``'s
    geometry (its texture sampled at their UVs) and ``level_image`` over ``level_extent`` sampled at their world
    positions."""
    from stepterrain.texture_lod import DrawItem, paint_with_textures

    mesh = paint_with_textures(DrawItem(patch.geometry, (patch,), (False,)))
    image = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
    height, width = image.shape[:2]
    u, v = mesh.visual.uv.T
    # the UVs as a sampler reads them: the painted texture over the unit square
    painted = _bilinear(image, (0.0, 1.0, 0.0, 1.0), u, v)
    whole = _bilinear(level_image, level_extent, mesh.vertices[:, 0], mesh.vertices[:, 1])
    return float(np.abs(painted - whole).max())


def test_adjacent_texture_patches_agree_with_their_level_along_their_seam():
    """A texture patch's window was the tight pixel window over its geometry patch, so a texel within half an image
    pixel of the patch's edge was sampled from its edge pixel repeated instead of interpolated with the next one:
    two adjacent patches at one level gave other colours along their shared edge than each other and than the
    level sampled as a whole (Front Range + Blue Marble: up to 21.8 grey levels; a hillshade GeoTIFF of Big
    Tujunga, up to 77). The window now takes a pixel more on each side (as image_layer's): every painted vertex of
    every patch takes the colour of the whole level at its world position, and a texel's centre stays on its
    world position (the UVs map the grown window)."""
    pytest.importorskip("rasterio")
    import stepterrain as st
    from stepterrain.texture import TextureLayer, texture_uv

    from .reference_texture import find_shared

    terrain = st.load_dem(find_shared("front_range_srtmgl3_3arcsec.tif"))
    with ImagePyramid.build(find_shared("earth_day_bluemarble_3840x1920.tif"), device="cpu") as pyramid:
        for size in (2, 4):
            tree = TextureTree(pyramid, PatchQuadtree(terrain, leaf_size=64), max_texture_size=size)
            patches = tree.patches()
            assert len({m.level for m in patches}) > 1
            for m in patches:
                r0, r1, c0, c1 = m.window
                assert r1 - r0 <= size + 2 and c1 - c0 <= size + 2  # a border, as OpenGL's
                level = tree.pyramid.levels[m.level]
                assert _painted_against_level(tree, m, level, tree.pyramid.extent) < 1e-6
                # the centre of the window's pixel (1, 1) (the first inside the margin) is at texel (1, 1) of M
                px, py = m.texel_size
                centre = [[m.domain[0] + 1.5 * px, m.domain[3] - 1.5 * py]]
                uv = texture_uv(centre, TextureLayer("thematic", np.asarray(m.image()), m.domain))[0]
                np.testing.assert_allclose([uv[0] * (c1 - c0) - 0.5, (1 - uv[1]) * (r1 - r0) - 0.5], [1, 1],
                                           atol=1e-9)
                np.testing.assert_array_equal(m.image()[1, 1], level[r0 + 1, c0 + 1])


def test_a_world_image_textures_a_dem_across_the_antimeridian(tmp_path):
    """The Blue Marble (360 degrees of longitude, EPSG:4326) over a DEM in degrees from 170 E to 170 W (the 1-degree
    global relief around Fiji): the tree placed the image at one turn only, so the 24 of 64 leaf patches east of 180
    got no texture patch (left untextured). The image now goes on past its seam, as image_layer's: every leaf patch
    has one, and every painted vertex takes the colour of the level wrapped across the seam."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    import stepterrain as st

    from .reference_texture import find_shared

    with np.load(find_shared("global_relief_1deg.npz")) as data:
        relief = data["elevation"].astype(np.float32)
    heights = np.concatenate([relief[100:116, 350:], relief[100:116, :10]], axis=1)  # 170.5 E .. 189.5 E
    dem = tmp_path / "fiji.tif"
    with rasterio.open(dem, "w", driver="GTiff", height=16, width=20, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(1.0, 0.0, 170.0, 0.0, -1.0, -10.0)) as out:
        out.write(heights, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # degrees read as local metres over 15 degrees of latitude
        terrain = st.load_dem(dem)
    with ImagePyramid.build(find_shared("earth_day_bluemarble_3840x1920.tif"), device="cpu") as pyramid:
        tree = TextureTree(pyramid, PatchQuadtree(terrain, leaf_size=4), max_texture_size=64)
        xmin, xmax, ymin, ymax = tree.pyramid.extent
        assert xmax < tree.quadtree.root.domain[1]  # the DEM reaches past the image's east edge (180)
        textured = 0
        stack = [(tree.quadtree.root, tree.root)]
        wrapped_levels: dict[int, np.ndarray] = {}
        while stack:
            geometry, patch = stack.pop()
            assert patch is not None, f"no texture over {geometry.domain}"
            if patch.level not in wrapped_levels:  # the image's next turn east, put beside each level once
                level = tree.pyramid.levels[patch.level]
                wrapped_levels[patch.level] = np.concatenate([level, level], axis=1)
            wrapped = wrapped_levels[patch.level]
            assert _painted_against_level(tree, patch, wrapped, (xmin, 2 * xmax - xmin, ymin, ymax)) < 1e-6
            textured += geometry.is_leaf
            stack.extend((child, patch.child_for(child)) for child in geometry.children)
        assert textured == 64


@pytest.mark.parametrize("nodata", [None, 0])
def test_a_geotiff_image_layer_reads_only_its_window_over_the_terrain(tmp_path, monkeypatch, nodata):
    """image_layer of a GeoTIFF decoded the whole image (checked against the memory budget: a 20000 x 20000
    orthophoto under the Big Tujunga DEM took 3 GB and 45 s, and one past the budget was refused though the DEM
    covers a corner of it) and built every level of it, to keep one window of one level. Now only the image's window
    over the terrain is read, a band of rows at a time, and reduced to that level: the pixels are those of the whole
    image's pyramid (odd sizes, the area-weighted path; a nodata collar as alpha), the budget counts the window, and
    the reads cover the window, a tenth of the image, not the image."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.io import DatasetReader
    from rasterio.transform import Affine

    import stepterrain as st
    from stepterrain.terrain import Terrain
    from stepterrain.texture_lod import image_layer

    rows, cols, west, north, pixel = 1501, 2003, 5000.0, 9000.0, 2.0  # odd sizes: weights across the window's edge
    data = np.random.default_rng(11).integers(1, 256, (3, rows, cols), dtype=np.uint8)
    if nodata is not None:
        data[:, 900:, :400] = 0  # a collar reaching under the terrain's south-west corner
    path = tmp_path / "ortho.tif"
    with rasterio.open(path, "w", driver="GTiff", height=rows, width=cols, count=3, dtype="uint8", crs="EPSG:32611",
                       transform=Affine(pixel, 0.0, west, 0.0, -pixel, north), tiled=True, blockxsize=256,
                       blockysize=256, compress="deflate", nodata=nodata) as out:
        out.write(data)
    terrain = Terrain.from_heights(np.zeros((31, 41), np.float32), spacing=(30.0, -30.0),
                                   origin=(west + 501.0, north - 1203.0), crs="EPSG:32611")
    array = np.moveaxis(data, 0, 2)  # the same pixels as an array: the whole image's pyramid
    if nodata is not None:
        array = np.concatenate([array, np.where((data != 0).any(axis=0), 255, 0).astype(np.uint8)[:, :, None]], 2)
    extent = (west, west + cols * pixel, north - rows * pixel, north)
    read_cells = []
    original = DatasetReader.read

    def read(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        read_cells.append(out.shape[-2] * out.shape[-1])
        return out

    monkeypatch.setattr(DatasetReader, "read", read)
    for texel in (None, 3.0):  # level 3 (16 m pixels, for the 30 m nodes), level 0 (the image's own pixels)
        options = {} if texel is None else {"texel_size": texel}
        expected = image_layer(array, terrain, extent=extent, device="cpu", **options)
        read_cells.clear()
        previous = st.set_memory_budget(rows * cols * 3 * 4 // 2)  # the whole image's decode (4 bytes counted) is past
        try:
            layer = image_layer(path, terrain, device="cpu", **options)
        finally:
            st.set_memory_budget(previous)
        assert layer.extent == pytest.approx(expected.extent, abs=1e-9)
        np.testing.assert_array_equal(layer.image, expected.image)
        assert 0 < sum(read_cells) < rows * cols / 8, f"{sum(read_cells)} of {rows * cols} pixels read"


@pytest.mark.parametrize("kind", ["min-is-white", "4-bit"])
def test_a_grey_geotiff_pillow_reads_otherwise_than_gdal_keeps_its_image_layer_pixels(tmp_path, kind):
    """image_layer read a GeoTIFF of 8-bit bands window by window with rasterio, which gives the stored values, where
    the whole read (Pillow) gives the picture: a min-is-white grey (0 is white, as scanned maps are stored) came out
    as its negative and a 4-bit grey (0-15, Pillow scales 15 to 255) nearly black. Such a TIFF is read as before
    now, with the pixels Pillow reads: the layer is the one of those pixels as an array."""
    rasterio = pytest.importorskip("rasterio")
    import PIL.Image
    from rasterio.transform import Affine

    from stepterrain.terrain import Terrain
    from stepterrain.texture_lod import image_layer

    rows, cols = 61, 83
    grey = np.random.default_rng(12).integers(0, 256, (1, rows, cols), dtype=np.uint8)
    options = {"photometric": "MINISWHITE"} if kind == "min-is-white" else {"nbits": 4}
    if kind == "4-bit":
        grey //= 16
    path = tmp_path / "scan.tif"
    with rasterio.open(path, "w", driver="GTiff", height=rows, width=cols, count=1, dtype="uint8", crs="EPSG:32611",
                       transform=Affine(10.0, 0.0, 5000.0, 0.0, -10.0, 9000.0), **options) as out:
        out.write(grey)
    with PIL.Image.open(path) as picture:
        pixels = np.asarray(picture.convert("L"))
    assert not np.array_equal(pixels, grey[0])  # Pillow's picture is not the stored values
    terrain = Terrain.from_heights(np.zeros((9, 11), np.float32), spacing=(30.0, -30.0), origin=(5100.0, 8800.0),
                                   crs="EPSG:32611")
    extent = (5000.0, 5000.0 + cols * 10.0, 9000.0 - rows * 10.0, 9000.0)
    for texel in (None, 10.0):
        options = {} if texel is None else {"texel_size": texel}
        expected = image_layer(pixels, terrain, extent=extent, device="cpu", **options)
        layer = image_layer(path, terrain, device="cpu", **options)
        np.testing.assert_array_equal(layer.image, expected.image)


@pytest.mark.parametrize("kind", ["rgb with nodata", "rgb, nodata nowhere", "rgba", "grey", "png"])
def test_an_image_file_pyramid_is_built_a_band_of_rows_at_a_time(tmp_path, monkeypatch, kind):
    """ImagePyramid.build of an image file decoded it whole into memory as level 0 (checked against the memory
    budget: a 16000 x 16000 GeoTIFF orthophoto took 2 GB) before building the levels band by band. A TIFF of 8-bit
    bands, or a PNG, that GDAL reads as the whole read does is now read a band of rows at a time (whole blocks) into
    level 0's file in storage and reduced from there: the levels are byte for byte those of the same pixels built
    as an array (odd sizes; a nodata collar as alpha, none where no pixel is nodata), each row is read once, in bands
    of the band size, and a memory budget below the whole decode no longer refuses it."""
    rasterio = pytest.importorskip("rasterio")
    import PIL.Image
    import PIL.ImageFile
    from rasterio.io import DatasetReader
    from rasterio.transform import Affine

    import stepterrain as st

    rows, cols = 301, 203
    count = {"rgba": 4, "grey": 1}.get(kind, 3)
    data = np.random.default_rng(13).integers(1, 256, (count, rows, cols), dtype=np.uint8)
    array = np.moveaxis(data, 0, 2)
    if count == 1:
        array = np.repeat(array, 3, axis=2)  # a grey image is read as RGB
    if kind == "rgb with nodata":
        data[:, 200:, :90] = 0  # a collar
        array = np.concatenate([array, np.where((data != 0).any(axis=0), 255, 0).astype(np.uint8)[:, :, None]], 2)
    if kind == "png":
        path = tmp_path / "map.png"
        PIL.Image.fromarray(array).save(path)
    else:
        path = tmp_path / "ortho.tif"
        with rasterio.open(path, "w", driver="GTiff", height=rows, width=cols, count=count, dtype="uint8",
                           crs="EPSG:32611", transform=Affine(2.0, 0.0, 5000.0, 0.0, -2.0, 9000.0), tiled=True,
                           blockxsize=32, blockysize=32, compress="deflate", alpha="YES" if count == 4 else None,
                           nodata=0 if "nodata" in kind else None) as out:
            out.write(data)
    read_rows = []
    original = DatasetReader.read

    def read(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        read_rows.append(out.shape[-2])
        return out

    monkeypatch.setattr(DatasetReader, "read", read)
    decoded = []  # Pillow reads the header only (a PNG's EXIF orientation too: getexif() decoded the image)
    monkeypatch.setattr(PIL.ImageFile.ImageFile, "load", lambda self: decoded.append(self))
    band_bytes = 45 * cols * array.shape[2]  # 45 rows a band: 32 in whole blocks of a TIFF (a PNG's are rows)
    previous = st.set_memory_budget(rows * cols * array.shape[2])  # a quarter of the whole decode's count
    try:
        pyramid = ImagePyramid.build(path, storage=tmp_path / "levels", band_bytes=band_bytes, anisotropic=True,
                                     device="cpu")
    finally:
        st.set_memory_budget(previous)
    with pyramid, ImagePyramid.build(array, anisotropic=True, device="cpu") as expected:
        assert pyramid.levels[0].shape == array.shape
        for level, want in zip(pyramid.levels, expected.levels, strict=True):
            np.testing.assert_array_equal(level, want)
        for key, want in expected.anisotropic.items():
            np.testing.assert_array_equal(pyramid.anisotropic[key], want)
        assert str(pyramid.levels[0].filename) == str(tmp_path / "levels" / "level_0.u8")
        assert not pyramid.levels[0].flags.writeable
        if kind != "png":
            assert pyramid.extent == (5000.0, 5000.0 + 2 * cols, 9000.0 - 2 * rows, 9000.0)
            assert pyramid.crs == "EPSG:32611"
    assert sum(read_rows) == rows and max(read_rows) == (45 if kind == "png" else 32), read_rows
    assert not decoded


@pytest.mark.parametrize("kind", ["rgb, exif after the pixels", "palette"])
def test_an_image_files_exif_orientation_is_warned_of_once_without_decoding_it(tmp_path, monkeypatch, kind):
    """ImagePyramid.build warned of a palette PNG's EXIF orientation twice (once looking whether to read it by bands,
    once decoding it whole), and finding a PNG's eXIf chunk after its image data through Pillow's getexif() decoded
    the whole image. It is warned of once, where the image is read, and a PNG read by bands is never decoded whole."""
    pytest.importorskip("rasterio")
    import PIL.Image
    import PIL.ImageFile

    pixels = np.random.default_rng(14).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    exif = PIL.Image.Exif()
    exif[0x0112] = 6
    path = tmp_path / "photo.png"
    (PIL.Image.fromarray(pixels).quantize(64) if kind == "palette" else PIL.Image.fromarray(pixels)).save(path,
                                                                                                        exif=exif)
    if kind != "palette":  # the eXIf chunk moved after IDAT, where some writers put it
        data, chunks, at = path.read_bytes(), [], 8
        while at < len(data):
            end = at + 12 + int.from_bytes(data[at:at + 4], "big")
            chunks.append(data[at:end])
            at = end
        moved = [c for c in chunks if c[4:8] != b"eXIf"]
        path.write_bytes(data[:8] + b"".join(moved[:-1] + [c for c in chunks if c[4:8] == b"eXIf"] + moved[-1:]))
        decoded = []
        monkeypatch.setattr(PIL.ImageFile.ImageFile, "load", lambda self: decoded.append(self))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with ImagePyramid.build(path, device="cpu") as pyramid:
            assert pyramid.levels[0].shape == (20, 30, 3)
            if kind != "palette":
                np.testing.assert_array_equal(pyramid.levels[0], pixels)
                assert not decoded
    assert [str(w.message) for w in caught if "EXIF" in str(w.message)] == [
        f"image {str(path)!r} has EXIF orientation 6 (rotated 90° clockwise to view): it is drawn as stored, 30 x 20 "
        "pixels, as GDAL reads it; to use it as viewers show it, build from "
        "np.asarray(PIL.ImageOps.exif_transpose(Image.open(path)))"]


@pytest.mark.parametrize("compression", [None, "tiff_deflate"])
@pytest.mark.parametrize("orientation", [3, 6])
def test_a_tiff_with_an_orientation_tag_is_drawn_as_stored_read_whole_or_by_bands(tmp_path, compression, orientation):
    """Pillow turns a TIFF by its Orientation tag (274) as it decodes it (13: every TIFF; earlier, a compressed one)
    and drops the tag: ImagePyramid.build reading a palette TIFF whole drew it turned (10 x 6 pixels stored, 6 x 10
    drawn, over the world file's 20 x 12 m: stretched), without the orientation warning (an uncompressed one turned
    90 degrees came out scrambled), while an RGB TIFF read by bands with rasterio was drawn as stored and warned of,
    as documented. Both are drawn as stored now, over the same extent, with one warning naming the stored size."""
    pytest.importorskip("rasterio")
    import PIL.Image

    palette = PIL.Image.fromarray(np.random.default_rng(15).integers(0, 256, (6, 10, 3), dtype=np.uint8)).quantize(8)
    stored = np.asarray(palette.convert("RGB"))
    options = {"compression": compression} if compression else {}
    paths = {"whole": tmp_path / "palette.tif", "by bands": tmp_path / "rgb.tif"}
    palette.save(paths["whole"], tiffinfo={274: orientation}, **options)
    palette.convert("RGB").save(paths["by bands"], tiffinfo={274: orientation}, **options)
    for path in paths.values():  # 2 m pixels, the top left corner at (1000, 2000)
        path.with_suffix(".tfw").write_text("2\n0\n0\n-2\n1001\n1999\n")
    turn = {3: "rotated 180°", 6: "rotated 90° clockwise"}[orientation]
    for how, path in paths.items():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with ImagePyramid.build(path, device="cpu") as pyramid:
                np.testing.assert_array_equal(pyramid.levels[0], stored, err_msg=how)
                assert pyramid.extent == (1000.0, 1020.0, 1988.0, 2000.0), how
        assert [str(w.message) for w in caught if "orientation" in str(w.message)] == [
            f"image {str(path)!r} has EXIF orientation {orientation} ({turn} to view): it is drawn as stored, 10 x 6 "
            "pixels, as GDAL reads it; to use it as viewers show it, build from "
            "np.asarray(PIL.ImageOps.exif_transpose(Image.open(path)))"], how


def test_a_texture_load_that_fails_in_the_background_is_raised_to_the_caller():
    """TextureCache's background thread swallowed a loader's exception (a corrupt tile mid-stream): the patch was left
    neither loaded nor pending, so every frame requested it again (hundreds of failing loads a frame) and drew its
    parent without a word; wait() raised it only when it happened to catch the load still in flight."""
    from stepterrain.errors import DataFileError
    from stepterrain.texture_lod import TextureCache

    from .test_texture_lod import lod_setup

    quadtree, tree, pyramid, camera = lod_setup()
    calls = []

    def loader(patch):
        calls.append(patch)
        if patch is not tree.root:
            raise OSError("tile_7.jpg: corrupt JPEG data")
        return np.array(patch.image())

    cache = TextureCache(budget=1 << 30, loader=loader)
    raised = []
    with pyramid:
        cache.load_now(tree.root)
        for _ in range(5):  # frames: a failure is raised by the next frame's traversal or by wait()
            try:
                render_with_textures(quadtree.root, [tree.root], camera, cache=cache)
                cache.wait()
            except DataFileError as error:
                raised.append(error)
        while True:  # the failures left over
            try:
                cache.wait()
                break
            except DataFileError as error:
                raised.append(error)
        assert len(calls) > 1 and len(raised) == len(calls) - 1  # every failed load reached the caller, once
        assert all(isinstance(error.__cause__, OSError) for error in raised)
        assert all(re.fullmatch(r"loading the texture patch at pyramid level \d+, window rows \d+:\d+, columns "
                                r"\d+:\d+ failed: OSError: tile_7.jpg: corrupt JPEG data", str(error))
                   for error in raised)
    cache.close()


def test_a_texture_cache_never_holds_more_than_its_budget_even_for_one_patch_larger_than_it():
    """A patch whose data alone was larger than the budget was kept (the eviction stopped at one patch), so the bytes
    held went past the budget without a word; it is now refused by name, the bytes held stay within the budget."""
    from stepterrain.errors import OutputTooLargeError
    from stepterrain.texture_lod import TextureCache

    from .test_texture_lod import lod_setup

    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        small = min((m for m in tree.patches() if m.nbytes > 0), key=lambda m: m.nbytes)
        big = max(tree.patches(), key=lambda m: m.nbytes)
        budget = big.nbytes - 1
        cache = TextureCache(budget=budget)
        cache.load_now(small)
        with pytest.raises(OutputTooLargeError, match=rf"takes {big.nbytes} bytes, more than the cache's budget of "
                                                      rf"{budget} bytes"):
            cache.load_now(big)
        assert cache.bytes_loaded <= budget and not cache.is_loaded(big) and cache.is_loaded(small)
        cache.close()


def test_a_texture_cache_of_a_one_byte_budget_says_1_byte():
    """``TextureCache(budget=1)`` (the least it takes) refused a patch as "more than the cache's budget of 1 bytes"."""
    from stepterrain.errors import OutputTooLargeError
    from stepterrain.texture_lod import TextureCache

    from .test_texture_lod import lod_setup

    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        patch = min((m for m in tree.patches() if m.nbytes > 1), key=lambda m: m.nbytes)
        cache = TextureCache(budget=1)
        with pytest.raises(OutputTooLargeError, match=rf"takes {patch.nbytes} bytes, more than the cache's budget of "
                                                      r"1 byte \(") as caught:
            cache.load_now(patch)
        assert "1 bytes" not in str(caught.value)
        assert cache.bytes_loaded == 0 and not cache.is_loaded(patch)
        cache.close()


@pytest.mark.parametrize("pitch", [30.0, 45.0, 60.0])
def test_a_view_from_above_the_terrain_refines_the_patches_in_view(pitch):
    """γ(N) and τ(N, M) took the point of B(N) nearest to the eye, not (as §4 says) the nearest one inside the view
    frustum: for an eye above the terrain that is the point straight below it, out of view for a camera pitched down
    30-60 degrees, where γ's vertical segment lies along the eye's ray and projects to 0 pixels. So any such view drew
    the root alone (Big Tujunga from 300 m above its highest peak: one patch with a 481 m error)."""
    from scipy.optimize import nnls

    from stepterrain.texture_lod import visual_geometric_error

    rng = np.random.default_rng(5)
    heights = np.cumsum(np.cumsum(rng.normal(0.0, 1.0, (129, 129)), axis=0), axis=1).astype(np.float32)
    quadtree = PatchQuadtree(heights, leaf_size=8, spacing=(30.0, 30.0))
    root = quadtree.root
    xmin, xmax, ymin, ymax = root.domain
    eye = np.array([0.5 * (xmin + xmax), ymin + 0.25 * (ymax - ymin), root.box[1, 2] + 300.0])
    camera = Camera(tuple(eye), tuple(eye + [0.0, math.cos(math.radians(pitch)), -math.sin(math.radians(pitch))]),
                    viewport=(800, 600))
    # an independent p: feasible for the 12 half-spaces (frustum and box) and optimal by its KKT certificate
    p = camera.nearest_visible_point(root.box)
    planes = np.concatenate([camera.planes(), np.c_[np.r_[-np.eye(3), np.eye(3)], np.r_[root.box[0], -root.box[1]]]])
    slack = planes[:, :3] @ p + planes[:, 3]
    assert slack.max() <= 1e-6
    _, residual = nnls(planes[np.abs(slack) <= 1e-6, :3].T, 2.0 * (eye - p))
    assert residual <= 1e-6 * np.linalg.norm(eye - p)
    pixels, depth = camera.project(np.stack([p - [0, 0, root.error / 2], p + [0, 0, root.error / 2]]))
    expected = math.inf if depth.min() < camera.near else float(np.linalg.norm(pixels[0] - pixels[1]))
    # raised to the longest projection of e(N) at p in any direction (test_a_map_view_straight_down_...), and to
    # the vertical segment's on-screen size anywhere else in view (test_every_drawn_patch_meets_the_tolerances_...)
    bound = camera.focal_pixels * root.error * np.linalg.norm(p - eye) / ((p - eye) @ camera.frame()[0]) ** 2
    gamma = visual_geometric_error(root, camera)
    assert gamma >= max(expected, bound) * (1 - 1e-9) and expected > 1.0
    assert gamma >= _worst_on_screen(camera, root.box, np.array([0.0, 0.0, root.error]), samples=17) * (1 - 1e-9)
    items = render_with_textures(root, [], camera)
    assert len(items) > 1 and all(item.geometry.is_leaf or visual_geometric_error(item.geometry, camera) <= 1.0
                                  for item in items)


def _largest_projection(camera, p, length, directions):
    """Independent of Camera.project and texture_lod: the longest screen length in pixels, over ``directions``, of a
    segment of ``length`` centred at p, by a pinhole projection built from eye, target, up, fov and viewport."""
    eye, target = np.array(camera.eye), np.array(camera.target)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    focal = camera.viewport[1] / 2.0 / math.tan(camera.fov / 2.0)

    def screen(points):
        rel = points - eye
        return focal * np.c_[rel @ right, rel @ up] / (rel @ forward)[:, None]

    ends = screen(p + directions * length / 2), screen(p - directions * length / 2)
    return float(np.linalg.norm(ends[0] - ends[1], axis=1).max())


@pytest.mark.parametrize("above", [300.0, 3000.0])
def test_a_map_view_straight_down_refines_like_a_slightly_tilted_one(above):
    """For a camera looking straight down (a map view), the point of B(N) in view nearest to the eye is the one right
    below it, where γ's vertical segment lies along the eye's ray and projects to 0 pixels: γ was 0, so
    render_with_textures drew the root alone (Big Tujunga from 3 km above: one patch with a 676 m error) until the view
    tilted past half the field of view (25 degrees: 208 patches). γ is now raised to the longest projection of a
    segment of length e(N) at p in any direction: every drawn pair still satisfies γ ≤ γ_user or is a leaf, checked
    by an independent projection of e(N) at p in 2000 directions, and the patch count is continuous in the tilt."""
    from stepterrain.texture_lod import visual_geometric_error

    rng = np.random.default_rng(7)
    heights = np.cumsum(np.cumsum(rng.normal(0.0, 1.0, (129, 129)), axis=0), axis=1).astype(np.float32)
    quadtree = PatchQuadtree(heights, leaf_size=8, spacing=(30.0, 30.0))
    root = quadtree.root
    xmin, xmax, ymin, ymax = root.domain
    eye = np.array([0.5 * (xmin + xmax), 0.5 * (ymin + ymax), root.box[1, 2] + above])
    directions = rng.normal(size=(2000, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    counts = {}
    for tilt in (0.0, 2.0, 5.0, 10.0, 30.0):
        a = math.radians(tilt)
        camera = Camera(tuple(eye), tuple(eye + [0.0, math.sin(a), -math.cos(a)]), up=(0.0, 1.0, 0.0),
                        viewport=(800, 600))
        items = render_with_textures(root, [], camera)
        counts[tilt] = len(items)
        for item in items:
            n = item.geometry
            if n.is_leaf:
                continue
            gamma = visual_geometric_error(n, camera)
            p = camera.nearest_visible_point(n.box)
            assert p is not None and gamma <= 1.0
            # the error's on-screen size at p, in any direction (the vertical one among them), is within γ_user
            assert _largest_projection(camera, p, n.error, np.r_[directions, [[0.0, 0.0, 1.0]]]) <= 1.0 + 1e-3
        assert counts[tilt] > 4 and root not in [item.geometry for item in items], (tilt, counts)
    # continuous in the tilt: no jump from the root alone to hundreds of patches as the view leaves the nadir
    assert max(counts.values()) <= 2.5 * min(counts.values()), counts


def _worst_on_screen(camera, box, vector, samples=9):
    """Independent of texture_lod: the longest screen length in pixels of the segment ``vector`` centred at any point
    of a dense grid over ``box`` inside the view frustum (inf where an end lies behind the near plane), by a pinhole
    projection built from eye, target, up, fov and viewport; 0 where no grid point is in view."""
    eye, target = np.array(camera.eye), np.array(camera.target)
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, camera.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_y = math.tan(camera.fov / 2.0)
    tan_x = tan_y * camera.viewport[0] / camera.viewport[1]
    focal = camera.viewport[1] / 2.0 / tan_y
    axes = [np.linspace(box[0, k], box[1, k], samples) for k in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    rel = points - eye
    depth = rel @ forward
    inside = ((depth >= camera.near) & (depth <= camera.far) & (np.abs(rel @ right) <= tan_x * depth * (1 + 1e-12))
              & (np.abs(rel @ up) <= tan_y * depth * (1 + 1e-12)))
    if not inside.any():
        return 0.0
    ends = [rel[inside] + sign * vector / 2.0 for sign in (1.0, -1.0)]
    if min((end @ forward).min() for end in ends) < camera.near:
        return math.inf
    screen = [focal * np.c_[end @ right, end @ up] / (end @ forward)[:, None] for end in ends]
    return float(np.linalg.norm(screen[0] - screen[1], axis=1).max())


def _views(root):
    """Straight down over the centre and off-centre, tilted 10°, wide (100°, and 90° tilted 15°), narrow (10°), and
    from beyond the terrain's corner looking across it."""
    xmin, xmax, ymin, ymax = root.domain
    top, low = root.box[1, 2], root.box[0, 2]
    centre = np.array([(xmin + xmax) / 2, (ymin + ymax) / 2, top + 6000.0])
    off = np.array([xmin + 0.15 * (xmax - xmin), ymin + 0.2 * (ymax - ymin), top + 3000.0])

    def tilted(eye, degrees, **kw):
        a = math.radians(degrees)
        return Camera(tuple(eye), tuple(eye + [0.0, math.sin(a), -math.cos(a)]), up=(0.0, 1.0, 0.0),
                      viewport=(800, 600), **kw)

    return {"down": tilted(centre, 0.0), "down off-centre": tilted(off, 0.0), "tilted 10": tilted(centre, 10.0),
            "wide 100": tilted(centre, 0.0, fov=math.radians(100)),
            "wide 90 tilted 15": tilted(off, 15.0, fov=math.radians(90)),
            "narrow 10": tilted(centre + [0.0, 0.0, 24000.0], 3.0, fov=math.radians(10)),
            "terrain corner": Camera((xmin - 2000.0, ymin - 3000.0, top + 1500.0), (xmin + 4000.0, ymin + 3000.0, low),
                                     viewport=(800, 600))}


@pytest.mark.parametrize("gamma_user,tau_user", [(1.0, 1.0), (6.0, 2.0), (20.0, 8.0), (1e9, 2.5), (1e9, 6.0),
                                                 (1e9, 12.0)])
def test_every_drawn_patch_meets_the_tolerances_at_its_worst_point_in_view(gamma_user, tau_user):
    """γ(N) and τ(N, M) were measured at one point of B(N) in view, the nearest to the eye (§4), γ raised to the
    longest on-screen size of e(N) there: elsewhere in view, at the corners of a wide view or on the side of a tilted
    one nearer the eye, the error showed larger on screen than the tolerance (e(N) 1.6 times γ_user in a 90° view,
    3.4 times in a 120° one; a texel 1.08 times τ_user in a tilted 45° view). Every drawn patch's e(N), vertical,
    and the texel of its texture, along x and y, now project within γ_user and τ_user at every point of a dense grid
    over B(N) inside the view frustum, by an independent projection, unless it is a leaf."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=129, step=4)
    quadtree = PatchQuadtree(heights, leaf_size=8, spacing=(100.0, 100.0))
    root = quadtree.root
    image = np.random.default_rng(11).integers(0, 256, (1000, 1000, 3), dtype=np.uint8)
    with ImagePyramid.build(image, extent=root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=64)
        for name, camera in _views(root).items():
            items = render_with_textures(root, [tree.root], camera, gamma_user=gamma_user, tau_user=tau_user)
            assert items, name
            for item in items:
                n, m = item.geometry, item.textures[0]
                if not n.is_leaf:
                    gamma = _worst_on_screen(camera, n.box, np.array([0.0, 0.0, n.error]))
                    assert gamma <= gamma_user * (1 + 1e-9), (name, gamma)
                if m is not None and not m.is_leaf:
                    w, h = m.texel_size
                    tau = max(_worst_on_screen(camera, n.box, np.array(v)) for v in ([w, 0.0, 0.0], [0.0, h, 0.0]))
                    assert tau <= tau_user * (1 + 1e-9), (name, tau)


def test_the_visible_corners_of_a_box_span_every_point_of_it_in_view():
    """Camera.visible_corners (the corners of box ∩ view frustum that γ and τ are bounded over): each lies in the box
    and in the frustum, every point of a dense grid over the box in view lies in their convex hull (and the nearest
    visible point too), and a box out of view has none."""
    from scipy.optimize import linprog

    rng = np.random.default_rng(17)
    for _ in range(12):
        eye = rng.uniform(-50.0, 50.0, 3) + [0.0, 0.0, 60.0]
        camera = Camera(tuple(eye), tuple(eye + rng.normal(size=3) + [0.0, 0.0, -2.0]), up=(0.0, 1.0, 0.0),
                        fov=rng.uniform(0.2, 2.5), viewport=(800, 600), near=rng.uniform(0.5, 5.0))
        lo = rng.uniform(-80.0, 40.0, 3)
        box = np.array([lo, lo + rng.uniform(1.0, 60.0, 3)])
        corners = camera.visible_corners(box)
        planes = camera.planes()
        assert ((corners @ planes[:, :3].T + planes[:, 3]) <= 1e-6).all()
        assert ((corners >= box[0] - 1e-6) & (corners <= box[1] + 1e-6)).all()
        axes = [np.linspace(box[0, k], box[1, k], 7) for k in range(3)]
        points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        points = points[((points @ planes[:, :3].T + planes[:, 3]) <= -1e-6).all(axis=1)]
        nearest = camera.nearest_visible_point(box)
        assert (nearest is None) == (len(corners) == 0)
        if nearest is not None:
            points = np.r_[points, [nearest]]
        for point in points:  # a convex combination of the corners, by a feasibility LP
            k = len(corners)
            found = linprog(np.zeros(k), A_eq=np.r_[corners.T, np.ones((1, k))], b_eq=np.r_[point, 1.0],
                            bounds=(0, None), method="highs")
            assert found.status == 0, (point, corners)
    camera = Camera((0.0, 0.0, 100.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    assert camera.visible_corners(np.array([[5000.0, 5000.0, 0.0], [6000.0, 6000.0, 10.0]])).shape == (0, 3)
    assert len(camera.visible_corners(np.array([[-10.0, -10.0, 0.0], [10.0, 10.0, 10.0]]))) == 8  # the box's own


def test_a_pyramid_of_a_tiff_cut_short_names_gdals_reason_not_a_failed_write(tmp_path):
    """A GeoTIFF image cut short (a download stopped half-way), read by bands of rows into level 0, was refused as
    "cannot write the pyramid level '/tmp/.../.level_0.u8....tmp': cannot read 'short.tif' as an image: Read failed.
    See previous exception for details.": a write of a temporary file that did not fail, and rasterio's words in
    place of GDAL's reason. It is the image's read that failed, with GDAL's reason named."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.errors import DataFileError

    from .conftest import SHARED_DATA

    with rasterio.open(SHARED_DATA / "big_tujunga_srtm_30m_utm11n.tif") as dataset:
        z = dataset.read(1)[:120, :160].astype(np.float64)
    grey = np.round(255 * (z - z.min()) / (z.max() - z.min())).astype(np.uint8)  # the DEM's heights as an image
    with rasterio.open(tmp_path / "whole.tif", "w", driver="GTiff", height=120, width=160, count=3, dtype="uint8",
                       photometric="RGB", crs="EPSG:32611",
                       transform=Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0)) as dataset:
        dataset.write(np.stack([grey, grey[::-1], 255 - grey]))
    with ImagePyramid.build(tmp_path / "whole.tif", device="cpu") as pyramid:  # read whole, it builds
        assert pyramid.levels
    data = (tmp_path / "whole.tif").read_bytes()
    (tmp_path / "short.tif").write_bytes(data[: len(data) // 2])  # its header whole, its strips cut
    with pytest.raises(DataFileError, match=r"^cannot read '.*short\.tif' as an image: short\.tif, band \d: ") as cut:
        ImagePyramid.build(tmp_path / "short.tif", device="cpu")
    assert "previous exception" not in str(cut.value) and "pyramid level" not in str(cut.value)


def test_a_storage_folder_that_is_a_dangling_symbolic_link_is_made_where_the_link_leads(tmp_path):
    """A storage folder given as a dangling symbolic link (levels -> scratch/new) was refused "cannot create the
    pyramid storage folder ...: File exists" (mkdir of the link's own name), as export.atomic_path's output folders
    were; it is made where the link leads and the level files are written there."""
    link = tmp_path / "levels"
    link.symlink_to(tmp_path / "scratch" / "new")
    image = np.arange(16 * 16 * 3, dtype=np.uint8).reshape(16, 16, 3)
    with ImagePyramid.build(image, storage=link, device="cpu") as pyramid:
        with ImagePyramid.build(image, storage=tmp_path / "plain", device="cpu") as reference:
            assert len(pyramid.levels) == len(reference.levels) > 1
            assert all(np.array_equal(a, b) for a, b in zip(pyramid.levels, reference.levels, strict=True))
        assert link.is_symlink() and sorted(p.name for p in (tmp_path / "scratch" / "new").iterdir()) == sorted(
            p.name for p in (tmp_path / "plain").iterdir()) != []


def test_a_build_into_a_storage_folder_leaves_only_its_own_level_files_there(tmp_path):
    """A build into a storage folder holding an earlier pyramid's level files replaced only the names it wrote: a
    5 x 6 image built where a 40 x 40 one was built with anisotropic levels (and level 0 copied from a writeable
    memmap) left 46 of the 49 files of the other image there beside its 3, level_0.u8 and level_4.u8 to level_6.u8
    among them: a folder that reads as one pyramid of two images (and keeps the larger's bytes on disk). The files it
    did not write are removed; the earlier pyramid, still open, keeps its levels (its maps), and a level 0 mapped
    from the folder's level_0.u8 keeps that file."""
    storage = tmp_path / "levels"
    rng = np.random.default_rng(7)
    first_image = rng.integers(0, 256, (40, 40, 3), dtype=np.uint8)
    np.save(tmp_path / "first.npy", first_image)
    first = ImagePyramid.build(np.load(tmp_path / "first.npy", mmap_mode="r+"), storage=storage, anisotropic=True,
                               device="cpu")  # a writeable memmap: level 0 copied into storage, level_0.u8
    expected = [np.array(level) for level in first.levels]
    expected_rip = {key: np.array(level) for key, level in first.anisotropic.items()}
    assert (storage / "level_0.u8").is_file() and (storage / "level_6.u8").is_file()
    second_image = rng.integers(0, 256, (5, 6, 3), dtype=np.uint8)
    with ImagePyramid.build(second_image, storage=storage, device="cpu") as second:
        assert sorted(p.name for p in storage.iterdir()) == ["level_1.u8", "level_2.u8", "level_3.u8"]
        for k in range(1, len(second.levels)):  # what the folder holds is this pyramid's levels
            np.testing.assert_array_equal(
                np.fromfile(storage / f"level_{k}.u8", np.uint8).reshape(second.levels[k].shape), second.levels[k])
        np.testing.assert_array_equal(second.levels[1], reduce_rounded_reference(second_image))
    for level, copy in zip(first.levels, expected, strict=True):  # the first, still open, reads its own levels
        np.testing.assert_array_equal(level, copy)
    for key, level in first.anisotropic.items():
        np.testing.assert_array_equal(level, expected_rip[key])
    first.close()

    # a pyramid whose level 0 is a map of the folder's level_0.u8 keeps that file
    third = ImagePyramid.build(np.load(tmp_path / "first.npy", mmap_mode="r+"), storage=storage, device="cpu")
    with ImagePyramid.build(third.levels[0], storage=storage, device="cpu") as fourth:
        assert (storage / "level_0.u8").is_file()
        np.testing.assert_array_equal(fourth.levels[0], first_image)
        assert sorted(p.name for p in storage.iterdir()) == [f"level_{k}.u8" for k in range(7)]
    third.close()


def test_a_pyramid_never_closed_leaves_no_temporary_folder_behind(tmp_path):
    """A pyramid built without storage (a temporary folder) deleted it only in close(): the module's typical use,
    ``pyramid = ImagePyramid.build("big.npy", ...)`` with no close, left stepterrain-pyramid-* in the temporary folder
    for good, a third of the image's bytes each time. It goes with the pyramid now (garbage collected, or at the
    interpreter's exit), as a tempfile.TemporaryDirectory's; the levels a caller still holds stay readable, and a
    storage folder the caller gave is kept."""
    import gc
    import subprocess
    import sys

    image = np.random.default_rng(3).integers(0, 256, (33, 20, 3), dtype=np.uint8)
    pyramid = ImagePyramid.build(image, device="cpu")
    folder = pyramid.storage
    held = pyramid.levels
    expected = [np.array(level) for level in held]
    assert folder.is_dir()
    del pyramid
    gc.collect()
    assert not folder.exists()
    for level, copy in zip(held, expected, strict=True):  # the maps outlive their files
        np.testing.assert_array_equal(level, copy)
    del held

    kept = ImagePyramid.build(image, storage=tmp_path / "levels", device="cpu")
    del kept
    gc.collect()
    assert sorted(p.name for p in (tmp_path / "levels").iterdir()) == [f"level_{k}.u8" for k in range(1, 7)]

    closed = ImagePyramid.build(image, device="cpu")
    closed.close()
    assert not closed.storage.exists()
    closed.close()  # twice: nothing to do

    script = ("import numpy as np\nfrom stepterrain.texture_lod import ImagePyramid\n"
              "p = ImagePyramid.build(np.zeros((9, 9, 3), np.uint8), device='cpu')\nprint(p.storage)\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, check=True)
    left = done.stdout.strip().splitlines()[-1]
    assert left and not os.path.exists(left), left


def test_a_failed_build_removes_the_storage_folders_it_made(tmp_path, monkeypatch):
    """A build into a storage folder that did not exist made it (and its missing parents), and a build that failed
    (disk full at a level, interrupted) left them behind, empty: an output folder of nothing. They are removed
    again; a folder that existed before is kept, as are its files."""
    from stepterrain import texture_lod

    def failing(*args, **kwargs):
        raise OSError(28, "No space left on device")

    image = np.zeros((9, 9, 3), np.uint8)
    monkeypatch.setattr(texture_lod, "_reduce_file", failing)
    with pytest.raises(OSError, match="No space"):
        ImagePyramid.build(image, storage=tmp_path / "new" / "deeper" / "levels", device="cpu")
    assert list(tmp_path.iterdir()) == []
    existing = tmp_path / "kept"
    existing.mkdir()
    with pytest.raises(OSError, match="No space"):
        ImagePyramid.build(image, storage=existing, device="cpu")
    assert existing.is_dir() and list(existing.iterdir()) == []
    monkeypatch.undo()
    with ImagePyramid.build(image, storage=tmp_path / "made" / "levels", device="cpu") as pyramid:  # kept when built
        assert sorted(p.name for p in pyramid.storage.iterdir()) == ["level_1.u8", "level_2.u8", "level_3.u8",
                                                                     "level_4.u8"]


@pytest.mark.parametrize("view", ["channels", "asarray"])
def test_a_build_keeps_the_level_file_its_image_maps_through_a_view(tmp_path, view):
    """A build into a storage folder removes the level files there it did not write, but keeps the one its image
    maps (level 0 reopened from the folder's level_0.u8). It knew that file only from a C-contiguous np.memmap: the
    same image as a view, its RGB of an RGBA level (``[:, :, :3]``, not contiguous) or ``np.asarray`` of the map (a
    plain ndarray over it), was built from and its file deleted, the caller's image gone from disk once the pyramid
    (whose map outlived the file) was closed. The file stays, byte for byte, and the folder holds the new levels."""
    storage = tmp_path / "levels"
    image = np.random.default_rng(11).integers(0, 256, (40, 40, 4), dtype=np.uint8)
    np.save(tmp_path / "image.npy", image)
    ImagePyramid.build(np.load(tmp_path / "image.npy", mmap_mode="r+"), storage=storage, device="cpu").close()
    level_0 = storage / "level_0.u8"
    assert np.array_equal(np.fromfile(level_0, np.uint8).reshape(image.shape), image)
    mapped = np.memmap(level_0, dtype=np.uint8, mode="r", shape=image.shape)
    source = mapped[:, :, :3] if view == "channels" else np.asarray(mapped)
    with ImagePyramid.build(source, storage=storage, device="cpu") as pyramid:
        np.testing.assert_array_equal(pyramid.levels[0], source)
        np.testing.assert_array_equal(pyramid.levels[1], reduce_rounded_reference(np.array(source)))
        for k in range(1, len(pyramid.levels)):  # the folder's levels are this pyramid's
            np.testing.assert_array_equal(np.fromfile(storage / f"level_{k}.u8", np.uint8)
                                          .reshape(pyramid.levels[k].shape), pyramid.levels[k])
    del mapped, source
    assert level_0.is_file()
    np.testing.assert_array_equal(np.fromfile(level_0, np.uint8).reshape(image.shape), image)
    assert sorted(p.name for p in storage.iterdir()) == [f"level_{k}.u8" for k in range(7)]


def test_a_build_refused_for_its_device_makes_no_storage_folder(tmp_path, monkeypatch):
    """A bad ``device`` was resolved after the storage folder was made, outside the build's clean-up: the refused
    build left the storage folder it made (and a temporary one, without ``storage``) behind, empty."""
    import tempfile

    from stepterrain.errors import DeviceError

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    image = np.zeros((9, 9, 3), np.uint8)
    with pytest.raises(DeviceError):
        ImagePyramid.build(image, storage=tmp_path / "new" / "levels", device="cuda:99")
    with pytest.raises(DeviceError):
        ImagePyramid.build(image, device="cuda:99")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tmp"]
    assert list((tmp_path / "tmp").iterdir()) == []


def test_an_owned_relative_storage_is_deleted_where_it_was_given(tmp_path, monkeypatch):
    """``owned=True`` with a relative ``storage``: close() (and the garbage collection's clean-up) removed the
    folder of that name in the working directory of the moment, after a chdir another folder, not the pyramid's."""
    image = np.zeros((4, 4, 3), np.uint8)
    (tmp_path / "a" / "levels").mkdir(parents=True)
    (tmp_path / "b" / "levels").mkdir(parents=True)
    (tmp_path / "b" / "levels" / "keep.txt").write_text("not the pyramid's")
    monkeypatch.chdir(tmp_path / "a")
    levels = [image, image[:2, :2].copy(), image[:1, :1].copy()]
    pyramid = ImagePyramid(levels, (0.0, 1.0, 0.0, 1.0), "levels", owned=True)
    monkeypatch.chdir(tmp_path / "b")
    pyramid.close()
    assert (tmp_path / "b" / "levels" / "keep.txt").is_file()
    assert not (tmp_path / "a" / "levels").exists()


@pytest.mark.parametrize("own_loader", [False, True])
def test_texture_cache_hands_out_data_a_caller_cannot_corrupt(own_loader):
    """TextureCache.load_now / get gave every caller the one array it held: a caller editing it in place (a gamma,
    premultiplying alpha) changed what every later hit and every later frame drew, without a word. The cached array
    is read-only (a loader's own array stays writeable, the cache holding a read-only view of it)."""
    from stepterrain.texture_lod import TextureCache

    from .test_texture_lod import lod_setup

    quadtree, tree, pyramid, _ = lod_setup()
    given = []

    def loader(patch):
        given.append(np.array(patch.image()))
        return given[-1]

    cache = TextureCache(budget=1 << 30, loader=loader if own_loader else None)
    with pyramid:
        patch = tree.patches()[1]
        expected = np.array(patch.image())
        data = cache.load_now(patch)
        assert data is cache.get(patch) and np.array_equal(data, expected)  # a hit: the same array
        with pytest.raises(ValueError):
            data[...] = 0  # an in-place edit is refused, not written into the cache
        assert np.array_equal(cache.get(patch), expected)
        if own_loader:
            assert given[0].flags.writeable  # the loader's array is not made read-only under its owner
    cache.close()


def test_pyramid_over_a_npy_file_rewritten_after_build_is_refused(tmp_path):
    """A pyramid built from a .npy path maps that file as level 0; rewriting the file in place (np.save over it) after
    the build changed level 0 under the pyramid while levels 1+ kept the old image: a patch drew the new image at full
    resolution and the old one coarser, without a word (and a shorter file killed the process with SIGBUS on the next
    read). The pyramid notices the change before reading and raises a DataFileError naming the file."""
    import time

    from stepterrain.errors import DataFileError

    path = tmp_path / "image.npy"
    np.save(path, np.full((9, 7, 3), 10, np.uint8))
    with ImagePyramid.build(path) as pyramid:
        assert np.asarray(pyramid.levels[1]).max() == 10
        time.sleep(0.05)  # past the file system's timestamp granularity
        np.save(path, np.full((9, 7, 3), 200, np.uint8))  # the same size, the same file (truncated, rewritten)
        with pytest.raises(DataFileError, match=r"image\.npy.*changed"):
            _ = pyramid.levels
        with pytest.raises(DataFileError, match=r"image\.npy.*changed"):
            pyramid.sub_image(0, (0, 2, 0, 2))
    # replaced by another file under its name (renamed over it): the old file stays mapped, whole; nothing to refuse
    np.save(path, np.full((9, 7, 3), 10, np.uint8))
    with ImagePyramid.build(path) as pyramid:
        np.save(tmp_path / "other.npy", np.full((9, 7, 3), 200, np.uint8))
        os.replace(tmp_path / "other.npy", path)
        assert np.asarray(pyramid.levels[0]).max() == np.asarray(pyramid.levels[1]).max() == 10


def test_pyramid_over_a_npy_file_whose_mode_or_links_changed_still_reads(tmp_path):
    """Only a rewrite of the bytes refuses a pyramid: a chmod or a new hard link to the .npy (a backup's ``cp -l``)
    changes the file's ctime, not its contents, and left the pyramid unreadable when ctime was compared."""
    path = tmp_path / "image.npy"
    np.save(path, np.full((9, 7, 3), 10, np.uint8))
    with ImagePyramid.build(path) as pyramid:
        os.chmod(path, 0o444)
        os.link(path, tmp_path / "backup.npy")
        assert np.asarray(pyramid.levels[1]).max() == 10
        assert np.asarray(pyramid.sub_image(0, (0, 2, 0, 2))).max() == 10


def test_a_void_the_coarse_mesh_draws_over_counts_in_the_geometric_error():
    """e(N) skipped nodes without data: a void inside a coarse cell whose corners have data is drawn over by the
    coarse mesh (ground where the DEM has none) and counted 0, so a flat DEM with a lake of nodata drew its root alone,
    the lake covered, from any distance, even a few cells above it (e(root) 0, while its children, whose finer mesh
    leaves the void's rim undrawn, had 4·√2). The void drawn over now counts as the coarse cell's diagonal, as terrain
    left undrawn does, so γ refines until the void opens on screen."""
    from stepterrain.terrain import heightfield_mesh
    from stepterrain.texture_lod import paint_with_textures

    flat = np.zeros((65, 65), np.float32)
    flat[10:15, 10:15] = np.nan  # inside the root's coarse cell rows 8..16, cols 8..16 (stride 8): drawn over
    quadtree = PatchQuadtree(flat, leaf_size=8)
    assert quadtree.root.error == pytest.approx(8 * np.sqrt(2.0))
    # an eye 100 units above the void sees the whole DEM, a cell ~10 pixels across, the void ~50
    camera = Camera((12.0, 12.0, 100.0), (12.0, 12.0001, 0.0), up=(0.0, 1.0, 0.0), viewport=(800, 800))
    with ImagePyramid.build(np.full((64, 64, 3), 90, np.uint8), extent=quadtree.root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        items = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=1.0, tau_user=1e9)
        area = sum(paint_with_textures(item).area for item in items)
    assert area == pytest.approx(heightfield_mesh(flat).area)  # the void is open: 4096 - 35 cells of ground
    small = np.zeros((33, 33), np.float32)
    small[10:13, 10:13] = small[3, 27] = np.nan  # drawn over by the coarser patches, a hole in the finer ones
    for patch in PatchQuadtree(small, leaf_size=4, spacing=(2.0, -1.5)).patches():
        block = small[patch.rows[0]: patch.rows[1] + 1, patch.cols[0]: patch.cols[1] + 1].astype(np.float64)
        corner = patch.rows[0], patch.cols[0]
        expected = _drawn_mesh_error(block, patch.stride, (2.0, -1.5), corner)
        assert patch.error == pytest.approx(expected, rel=1e-9, abs=1e-9)


def _surface_at(block, ri, ci, points):
    """Heights at ``points`` (n, 2) (row, column, fractional) of the mesh on nodes ri x ci of ``block`` (two triangles a
    cell, split along (r, c)-(r+1, c+1)) by barycentric weights in the cell holding each point."""
    ri, ci = np.asarray(ri), np.asarray(ci)
    r, c = points[:, 0], points[:, 1]
    k = np.clip(np.searchsorted(ri, r, side="right") - 1, 0, len(ri) - 2)
    m = np.clip(np.searchsorted(ci, c, side="right") - 1, 0, len(ci) - 2)
    u = (r - ri[k]) / (ri[k + 1] - ri[k])
    v = (c - ci[m]) / (ci[m + 1] - ci[m])
    z00, z01 = block[ri[k], ci[m]], block[ri[k], ci[m + 1]]
    z10, z11 = block[ri[k + 1], ci[m]], block[ri[k + 1], ci[m + 1]]
    return np.where(v >= u, z00 * (1 - v) + z01 * (v - u) + z11 * u, z00 * (1 - u) + z10 * (u - v) + z11 * v)


def _overlay_error(block, stride, corner=(0, 0)):
    """The largest vertical distance between the terrain's mesh and the coarse mesh over a block with data everywhere,
    exactly: their difference is linear on each piece of the two triangulations' overlay, so it is largest at a node
    or where a coarse edge crosses a fine edge (each found here by intersecting every pair of segments)."""
    rows, cols = block.shape
    ri, ci = _drawn_lines(corner[0], rows, stride), _drawn_lines(corner[1], cols, stride)

    def edges(rs, cs):
        out = []
        for a, r in enumerate(rs):
            for b, c in enumerate(cs):
                if b + 1 < len(cs):
                    out.append((r, c, r, cs[b + 1]))
                if a + 1 < len(rs):
                    out.append((r, c, rs[a + 1], c))
                if a + 1 < len(rs) and b + 1 < len(cs):
                    out.append((r, c, rs[a + 1], cs[b + 1]))
        return np.array(out, dtype=np.float64)

    fine, coarse = edges(range(rows), range(cols)), edges(ri, ci)
    p, d = fine[:, None, :2], fine[:, None, 2:] - fine[:, None, :2]
    q, e = coarse[None, :, :2], coarse[None, :, 2:] - coarse[None, :, :2]
    cross = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    w = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / cross
        t = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / cross
    hit = (cross != 0) & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    crossings = (p + np.where(hit, s, 0.0)[..., None] * d)[hit]
    nodes = np.stack(np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij"), -1).reshape(-1, 2).astype(float)
    points = np.concatenate([nodes, crossings])
    fine_z = _surface_at(block, range(rows), range(cols), points)
    return float(np.abs(fine_z - _surface_at(block, ri, ci, points)).max())


def test_the_geometric_error_includes_where_a_narrow_coarse_cells_diagonal_crosses_the_terrain():
    """e(N) was measured at the terrain's nodes only. The coarse mesh's last row and column of cells are narrower than
    the stride wherever the patch's size is no multiple of it (odd-sized DEMs); their diagonals then cross the
    terrain's edges between nodes, where the two surfaces may lie farther apart than at any node: on Big Tujunga
    (leaf_size 8) 820 of 21845 patches' e(N) fell short, by up to 7 m (18.5 for 25.5 m), so γ let the drawn error
    pass γ_user by a third. The crossings are measured too."""
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=45, step=3).astype(np.float64)[:, :37]
    assert np.isfinite(heights).all()
    quadtree = PatchQuadtree(heights, leaf_size=4)
    checked = 0
    for patch in quadtree.patches():
        if patch.stride == 1:
            continue
        block = heights[patch.rows[0]: patch.rows[1] + 1, patch.cols[0]: patch.cols[1] + 1]
        corner = patch.rows[0], patch.cols[0]
        assert patch.error == pytest.approx(_overlay_error(block, patch.stride, corner), rel=1e-9, abs=1e-9)
        checked += 1
    assert checked > 10
    # the smallest case: one coarse cell 1 x 2, its diagonal crossing the middle column between the nodes
    from stepterrain.texture_lod import _approximation_error

    block = np.array([[0.0, 5.0, 10.0], [10.0, 5.0, 0.0]])  # 0 at every node, 5 m apart at (0.5, 1)

    assert _approximation_error(block, 2) == pytest.approx(_overlay_error(block, 2)) == pytest.approx(5.0)


def _assert_errors_match_the_per_patch_reference(quadtree):
    """Every patch's e(N) equals, bit for bit, the per-patch computation (sampling the grid's multiples of the stride
    from the patch's corner) the library used before measuring the patches of one shape together; returns how many
    patches shared a pass with another of their shape, stride and sample pattern, and how many patterns (corners
    modulo the stride) a shape and stride took."""
    heights = quadtree.terrain.heights
    shapes, patterns = {}, {}
    for patch in quadtree.patches():
        block = heights[patch.rows[0]: patch.rows[1] + 1, patch.cols[0]: patch.cols[1] + 1]
        corner = patch.rows[0], patch.cols[0]
        expected = approximation_error_reference(block, patch.stride, quadtree.terrain.spacing, corner)
        assert patch.error == expected, (patch.rows, patch.cols, patch.stride, patch.error, expected)
        phase = (corner[0] % patch.stride, corner[1] % patch.stride)
        key = (*block.shape, patch.stride, *phase)
        shapes[key] = shapes.get(key, 0) + (patch.stride > 1)
        if patch.stride > 1:
            patterns.setdefault((*block.shape, patch.stride), set()).add(phase)
    return sum(n for n in shapes.values() if n > 1), max((len(p) for p in patterns.values()), default=0)


@given(rows=hst.integers(2, 41), cols=hst.integers(2, 41), leaf_size=hst.integers(2, 5), seed=hst.integers(0, 10**6),
       voids=hst.sampled_from([0.0, 0.04, 0.3]), lake=hst.booleans(), pass_nodes=hst.sampled_from([1, 200, 1 << 21]))
def test_patches_of_one_shape_measured_together_keep_the_per_patch_geometric_error(rows, cols, leaf_size, seed, voids,
                                                                                  lake, pass_nodes):
    """PatchQuadtree measures e(N) of a level's patches of one shape in one pass (the per-patch computation, with
    _diagonal_gap's crossings, took the sample DEM's leaf_size 8 build from 2.7 s to 7 s): the result must be the per-
    patch one bit for bit, on odd shapes (narrow first and last coarse cells; patches of one shape and stride whose
    corners lie differently about the grid's multiples of the stride sample other lines), with scattered nodata and a
    nodata lake, whatever the band of patches one pass takes."""
    rng = np.random.default_rng(seed)
    heights = np.cumsum(rng.normal(0.0, 3.0, (rows, cols)), axis=1) + np.cumsum(rng.normal(0.0, 3.0, (rows, 1)), 0)
    heights[rng.random((rows, cols)) < voids] = np.nan
    if lake:
        r, c = rng.integers(0, rows), rng.integers(0, cols)
        heights[r: r + rng.integers(1, 9), c: c + rng.integers(1, 9)] = np.nan
    spacing = (float(rng.uniform(0.5, 30.0)), float(rng.uniform(0.5, 30.0)))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(texture_lod, "_ERROR_PASS_NODES", pass_nodes)
        quadtree = PatchQuadtree(heights, leaf_size=leaf_size, spacing=spacing)
    _assert_errors_match_the_per_patch_reference(quadtree)


def test_the_sample_dems_patches_measured_together_keep_the_per_patch_geometric_error():
    """As above on a crop of the sample DEM no multiple of the strides (and with a nodata lake): many patches of one
    shape, stride and sample pattern share a pass, and patches of one shape and stride take several patterns."""
    heights = stepterrain.sample_dem().heights[:157, :203].astype(np.float64)
    heights[40:61, 90:118] = np.nan
    shared, patterns = _assert_errors_match_the_per_patch_reference(PatchQuadtree(heights, leaf_size=8))
    assert shared > 100 and patterns > 1
    # a stack of blocks one node tall (one coarse row: the mean's distance, kept one block at a time), and square ones,
    # their corner on a multiple of the stride or not
    rng = np.random.default_rng(5)
    for shape, stride in (((6, 1, 23), 4), ((6, 9, 1), 2), ((5, 13, 13), 4), ((4, 9, 14), 8)):
        blocks = rng.normal(0.0, 50.0, shape)
        blocks[rng.random(shape) < 0.2] = np.nan
        blocks[0] = np.nan
        for corner in ((0, 0), (stride + 1, 3), (5, 2 * stride - 1)):
            got = texture_lod._approximation_errors(blocks, stride, (2.0, 3.0), corner)
            expected = [approximation_error_reference(b, stride, (2.0, 3.0), corner) for b in blocks]
            assert [float(e) for e in got] == expected


def test_a_pyramid_stats_its_source_once_per_public_call_and_still_refuses_a_rewrite(tmp_path, monkeypatch):
    """A .npy path's pyramid stat'ed its file at every internal level access (shape, pixel_size, _window...): 3 to 5
    stats a window() or sub_image(), ~25 000 for a TextureTree's build over the sample DEM. It stats once per public
    call (a TextureTree's build once), and a file rewritten in place is still refused by each of them."""
    import time

    from stepterrain.errors import DataFileError

    path = tmp_path / "image.npy"
    np.save(path, np.full((33, 29, 3), 10, np.uint8))
    stats = []
    state = texture_lod._file_state
    monkeypatch.setattr(texture_lod, "_file_state", lambda p: stats.append(p) or state(p))
    quadtree = PatchQuadtree(np.arange(17 * 15, dtype=np.float64).reshape(17, 15), leaf_size=2)
    with ImagePyramid.build(path, extent=(0.0, 14.0, 0.0, 16.0)) as pyramid:
        calls = {
            "levels": lambda: pyramid.levels, "len": lambda: len(pyramid), "anisotropic": lambda: pyramid.anisotropic,
            "shape": lambda: pyramid.shape(1), "pixel_size": lambda: pyramid.pixel_size(1),
            "window": lambda: pyramid.window(1, (1.0, 5.0, 2.0, 9.0)),
            "window_extent": lambda: pyramid.window_extent(1, (1, 4, 2, 5)),
            "sub_image": lambda: pyramid.sub_image(1, (1, 4, 2, 5)),
        }
        for name, call in calls.items():
            stats.clear()
            call()
            assert len(stats) == 1, (name, len(stats))
        stats.clear()
        tree = TextureTree(pyramid, quadtree, max_texture_size=4)
        assert len(tree.patches()) > 20 and len(stats) == 1
        patch = tree.patches()[-1]
        for name, call in {"image": patch.image, "domain": lambda: patch.domain, "nbytes": lambda: patch.nbytes,
                           "texel_size": lambda: patch.texel_size}.items():
            stats.clear()
            call()
            assert len(stats) == 1, (name, len(stats))
        time.sleep(0.05)  # past the file system's timestamp granularity
        np.save(path, np.full((33, 29, 3), 200, np.uint8))  # rewritten in place
        for call in [*calls.values(), patch.image, lambda: TextureTree(pyramid, quadtree)]:
            with pytest.raises(DataFileError, match=r"image\.npy.*changed"):
                call()


def _border_edges(meshes, terrain):
    """The painted patches' border edges, each split at every border node of the other patches lying on it (a
    T-junction), counted per piece (a pair of grid nodes), with the largest height gap between such a node and the edge
    it splits and between two patches' heights at one border node: 0 where the patches' borders are one polyline."""
    import trimesh

    nodes, edges = {}, []
    gap = 0.0
    for mesh in meshes:
        col = np.rint((mesh.vertices[:, 0] - terrain.origin[0]) / terrain.spacing[0]).astype(int)
        row = np.rint((mesh.vertices[:, 1] - terrain.origin[1]) / terrain.spacing[1]).astype(int)
        once = trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)  # the patch's outline
        for a, b in mesh.edges_sorted[once]:
            ends = [((int(row[v]), int(col[v])), float(mesh.vertices[v, 2])) for v in (a, b)]
            edges.append(ends)
            for node, z in ends:
                gap = max(gap, abs(nodes.setdefault(node, z) - z))
    on_row, on_col = {}, {}
    for (r, c) in nodes:
        on_row.setdefault(r, []).append(c)
        on_col.setdefault(c, []).append(r)
    pieces = {}
    for ((r0, c0), z0), ((r1, c1), z1) in edges:
        flat = r0 == r1  # along a row, else along a column

        def line(k, flat=flat, r0=r0, c0=c0):
            return (r0, k) if flat else (k, c0)

        along = on_row[r0] if flat else on_col[c0]
        s0, s1 = (c0, c1) if flat else (r0, r1)
        if s0 > s1:
            s0, s1, z0, z1 = s1, s0, z1, z0
        stops = sorted({s0, s1, *(k for k in along if s0 < k < s1)})
        for k in stops[1:-1]:
            gap = max(gap, abs(nodes[line(k)] - (z0 + (z1 - z0) * (k - s0) / (s1 - s0))))
        for a, b in zip(stops[:-1], stops[1:], strict=True):
            pieces[line(a), line(b)] = pieces.get((line(a), line(b)), 0) + 1
    return pieces, gap


def _weld(meshes):
    """``meshes`` welded by exact vertex position: the distinct positions, the edges of the faces (undirected, as
    pairs of position indices, each once) and how many faces use each."""
    vertices = np.concatenate([m.vertices for m in meshes])
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    faces = np.concatenate([np.asarray(m.faces) + o for m, o in zip(meshes, offsets, strict=True)])
    positions, weld = np.unique(vertices, axis=0, return_inverse=True)
    faces = weld.reshape(-1)[faces]
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    edges, counts = np.unique(edges, axis=0, return_counts=True)
    return positions, edges, counts


def _welded_edges(meshes, t):
    """Per edge of ``meshes`` welded by exact vertex position (:func:`_weld`), how many faces use it, and which of
    them lie on the grid's outline (both ends on its first or last row, or first or last column; from the vertices'
    grid nodes)."""
    positions, unique, counts = _weld(meshes)
    node = np.column_stack([np.rint((positions[:, 1] - t.origin[1]) / t.spacing[1]),
                            np.rint((positions[:, 0] - t.origin[0]) / t.spacing[0])]).astype(int)
    rows, cols = t.heights.shape
    a, b = node[unique[:, 0]], node[unique[:, 1]]
    outline = (((a[:, 0] == b[:, 0]) & np.isin(a[:, 0], (0, rows - 1)))
               | ((a[:, 1] == b[:, 1]) & np.isin(a[:, 1], (0, cols - 1))))
    length = np.abs(a - b).sum(axis=1)
    return counts, outline, length


@pytest.mark.parametrize("case", ["sample_dem", "synthetic"])
def test_patches_drawn_at_different_levels_meet_without_cracks(case):
    """Neighbouring patches drawn at different levels left T-junction cracks along their border: the finer one's
    border nodes between the coarser one's lay on the terrain, off the coarser one's edge (this view: gaps up to 50 m
    on the sample DEM, 2.8 m on the synthetic one), and a patch counted its stride from its own first row and column,
    so on a DEM of no power-of-two-plus-one size the coarser one's nodes were not even among the finer one's. Patches
    now sample the grid's multiples of their stride, the cut is balanced (neighbours at most one level apart) and the
    finer border is moved onto the coarser edge: every border piece is shared by two patches, with one height."""
    import dataclasses

    from stepterrain import sample_dem
    from stepterrain.texture_lod import _geometric_error_in, _in_view, _samples, paint_with_textures

    if case == "sample_dem":
        terrain, leaf_size, gamma_user = sample_dem(), 32, 1.0  # 643 x 1197
    else:  # 101 x 77, no power of two plus one either way
        yy, xx = np.mgrid[0:101, 0:77]
        heights = 40 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + np.random.default_rng(3).normal(0, 0.5, xx.shape)
        terrain, leaf_size, gamma_user = as_terrain(heights, spacing=(10.0, -10.0)), 4, 2.0
    quadtree = PatchQuadtree(terrain, leaf_size=leaf_size)
    t = quadtree.terrain
    x0, x1, y0, y1 = quadtree.root.domain
    camera = Camera((x0 - 1.5 * (x1 - x0), (y0 + y1) / 2, quadtree.root.box[1, 2] + 0.5 * (x1 - x0)),
                    ((x0 + x1) / 2, (y0 + y1) / 2, quadtree.root.box[0, 2]), viewport=(640, 480))
    with ImagePyramid.build(np.full((64, 64, 3), 90, np.uint8), extent=quadtree.root.domain) as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        items = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=gamma_user, tau_user=1e9)
        meshes = [paint_with_textures(item) for item in items]
        unstitched = [paint_with_textures(dataclasses.replace(item, seams=(None,) * 4, finer=((),) * 4))
                      for item in items]
        unsplit = [paint_with_textures(dataclasses.replace(item, finer=((),) * 4)) for item in items]
    assert len({item.geometry.depth for item in items}) >= 2  # a cut of mixed levels
    assert sum(seam is not None for item in items for seam in item.seams) > 5
    area = sum(float(np.prod(np.ptp(m.vertices[:, :2], axis=0))) for m in meshes)
    assert area == pytest.approx((x1 - x0) * (y1 - y0), rel=1e-9)  # every patch in view: no border to a culled one
    rows, cols = t.heights.shape
    for item in items:  # balanced: a coarser neighbour is one level coarser, and covers the whole side
        for side, seam in enumerate(item.seams):
            if seam is not None:
                assert item.geometry.depth - seam.depth == 1
                span, own = (seam.cols, item.geometry.cols) if side < 2 else (seam.rows, item.geometry.rows)
                assert span[0] <= own[0] and own[1] <= span[1]
    for item, mesh in zip(items, meshes, strict=True):  # the stitched nodes move by the seam error counted in γ
        col = np.rint((mesh.vertices[:, 0] - t.origin[0]) / t.spacing[0]).astype(int)
        row = np.rint((mesh.vertices[:, 1] - t.origin[1]) / t.spacing[1]).astype(int)
        node = item.geometry
        own = np.isin(row, _samples(*node.rows, node.stride)) & np.isin(col, _samples(*node.cols, node.stride))
        moved = float(np.abs(mesh.vertices[own, 2] - t.heights[row, col][own]).max())  # not a finer one's, on its edge
        seam = max((node.seam_errors[k] for k, n in enumerate(item.seams) if n is not None), default=0.0)
        assert moved == pytest.approx(seam, rel=1e-12, abs=1e-12)
        if seam:
            error = _geometric_error_in(node, camera, _in_view(camera, node.box), node.error + seam)
            assert error <= gamma_user
    pieces, gap = _border_edges(meshes, t)
    outline = {key for key in pieces if (key[0][0] == key[1][0] and key[0][0] in (0, rows - 1))
               or (key[0][1] == key[1][1] and key[0][1] in (0, cols - 1))}
    assert gap <= 1e-9 * float(np.abs(t.heights).max())
    assert all(count == (1 if key in outline else 2) for key, count in pieces.items())  # watertight inside
    length = sum(abs(b[0] - a[0]) + abs(b[1] - a[1]) for a, b in outline)
    assert length == 2 * ((rows - 1) + (cols - 1))  # the outline whole, once
    # unstitched, the same cut cracks: the check sees it
    _, open_gap = _border_edges(unstitched, t)
    assert open_gap > 1.0
    # and the topology is closed: welded by exact position, every inner edge has two faces, the outline's one (a
    # coarse border edge stayed whole, a T-junction: 59 edges used once inside on the synthetic DEM)
    counts, on_outline, length = _welded_edges(meshes, t)
    assert (counts[~on_outline] == 2).all(), f"{int((counts[~on_outline] != 2).sum())} inner edges not used twice"
    assert (counts[on_outline] == 1).all()
    assert length[on_outline].sum() == 2 * ((rows - 1) + (cols - 1))
    assert sum(len(across) for item in items for across in item.finer) == sum(
        seam is not None for item in items for seam in item.seams)  # each stitched side named from its coarse side
    counts, on_outline, _ = _welded_edges(unsplit, t)  # without the split, the check sees the T-junctions
    assert (counts[~on_outline] == 1).sum() > 10


def test_a_patchs_seam_errors_are_the_distances_its_border_nodes_move_onto_its_parents_lines():
    """GeometryPatch.seam_errors (s(N), counted in γ with e(N) for a stitched patch) against a reference: each border
    node's distance to the line through the terrain at the two nearest nodes the parent draws on that border (the
    grid's multiples of twice the stride and the parent's ends)."""
    yy, xx = np.mgrid[0:45, 0:38]
    heights = 30 * np.sin(xx / 4.0) * np.cos(yy / 6.0) + np.random.default_rng(5).normal(0, 1.0, xx.shape)
    quadtree = PatchQuadtree(heights, leaf_size=4)
    heights = quadtree.terrain.heights.astype(np.float64)  # as stored (float32)
    checked = 0
    for patch in quadtree.patches():
        if patch.parent is None:
            assert patch.seam_errors == (0.0, 0.0, 0.0, 0.0)
            continue
        parent = patch.parent
        for side in range(4):
            if side < 2:
                line, own, span = heights[patch.rows[side], :], patch.cols, parent.cols
            else:
                line, own, span = heights[:, patch.cols[side - 2]], patch.rows, parent.rows
            nodes = sorted({own[0], own[1], *(k for k in range(own[0], own[1] + 1) if k % patch.stride == 0)})
            coarse = sorted({span[0], span[1], *(k for k in range(span[0], span[1] + 1) if k % parent.stride == 0)})
            expected = max(abs(line[k] - np.interp(k, coarse, line[coarse])) for k in nodes)
            assert patch.seam_errors[side] == pytest.approx(expected, rel=1e-9, abs=1e-9)
            checked += expected > 0
    assert checked > 20


def _seam_quadtree(seed=11):
    """A 33 x 33 node quadtree of leaf size 8 (depths 0-2), not flat, so a stitched border moves."""
    yy, xx = np.mgrid[0:33, 0:33]
    heights = 20 * np.sin(xx / 3.0) * np.cos(yy / 4.0) + np.random.default_rng(seed).normal(0, 1.0, xx.shape)
    quadtree = PatchQuadtree(heights, leaf_size=8)
    return quadtree, {(p.rows, p.cols): p for p in quadtree.patches()}


_FINE = ((16, 24), (8, 16))  # depth 2; its first row borders the depth-1 patch over rows 0-16, columns 0-16


@pytest.mark.parametrize("seams, match", [
    ((None,) * 4 + (((0, 16), (0, 16)),), r"^item\.seams must be 4 entries .*; got 5 entries"),  # a bare IndexError
    ((None,) * 3, r"^item\.seams must be 4 entries .*; got 3 entries"),  # was painted, the fourth side unstitched
    (None, r"^item\.seams must be 4 entries .*; got None"),  # was a TypeError
    ((5, None, None, None), r"^item\.seams\[0\] must be None or a coarser patch .*; got int"),  # an AttributeError
    # the rest were stitched: onto edges extrapolated past the named patch's ends, or onto its lines far away
    ((((0, 16), (16, 32)), None, None, None), r"^item\.seams\[0\] must be None or a coarser patch of the item's "
     r"quadtree drawn across its first row \(depth < 2, its rows ending at row 16, its columns spanning 8-16\); got "
     r"a patch of depth 1 over rows 0-16, columns 16-32"),  # coarser, across the row, but not next to it
    ((None, ((0, 16), (0, 16)), None, None), r"^item\.seams\[1\] must be .*across its last row .*rows starting at "
     r"row 24.*; got a patch of depth 1 over rows 0-16, columns 0-16"),  # next to another side
    # not coarser (its neighbour at its own depth), then the root holding it
    ((((8, 16), (8, 16)), None, None, None), r"^item\.seams\[0\] .*; got a patch of depth 2 over rows 8-16"),
    ((((0, 32), (0, 32)), None, None, None), r"^item\.seams\[0\] .*; got a patch of depth 0 over rows 0-32"),
    ((None, None, "other", None), r"^item\.seams\[2\] .*across its first column .*; got a patch of another quadtree"),
])
def test_paint_with_textures_refuses_malformed_seams(seams, match):
    """DrawItem.seams was read unchecked: a fifth entry raised a bare IndexError, a non-patch an AttributeError, and a
    patch not drawn across that side, or not coarser, was stitched onto anyway (the border moved onto its edges
    extrapolated past its ends). Each is now an InvalidInputError naming item.seams, what was expected and what was
    got; render_with_textures' own seams paint as before."""
    from stepterrain.texture_lod import DrawItem, paint_with_textures

    quadtree, by_span = _seam_quadtree()
    other = _seam_quadtree(12)[1]
    fine = by_span[_FINE]
    if isinstance(seams, tuple):
        seams = tuple(other[((8, 16), (0, 8))] if s == "other" else by_span[s] if isinstance(s, tuple) else s
                      for s in seams)
    with ImagePyramid.build(np.full((32, 32, 3), 90, np.uint8), extent=quadtree.root.domain) as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        good = DrawItem(fine, (tree.root,), (False,), (by_span[(0, 16), (0, 16)], None, None,
                                                         by_span[(16, 32), (16, 32)]))
        stitched = paint_with_textures(good)
        assert np.abs(stitched.vertices[:, 2] - paint_with_textures(DrawItem(fine, (tree.root,), (False,))).vertices[
            :, 2]).max() > 0.1  # the good seams stitch
        with pytest.raises(InvalidInputError, match=match):
            paint_with_textures(DrawItem(fine, (tree.root,), (False,), seams))


_COARSE = ((0, 16), (0, 16))  # depth 1; its last row borders _FINE and the depth-2 patch over columns 0-8


@pytest.mark.parametrize("finer, match", [
    (((), (), ()), r"^item\.finer must be 4 sequences .*; got 3 entries"),
    (None, r"^item\.finer must be 4 sequences .*; got None"),
    (((), 5, (), ()), r"^item\.finer must be 4 sequences .*; got 4 entries"),  # an entry not a sequence
    (((), (5,), (), ()), r"^item\.finer\[1\]\[0\] must be a finer patch of the item's quadtree drawn across its last "
     r"row \(depth > 1, its rows starting at row 16, its columns within 0-16\); got int"),
    (((((16, 24), (8, 16)),), (), (), ()), r"^item\.finer\[0\]\[0\] .*across its first row .*rows ending at row 0.*; "
     r"got a patch of depth 2 over rows 16-24, columns 8-16"),  # across another side
    (((), (((16, 32), (0, 16)),), (), ()), r"^item\.finer\[1\]\[0\] .*; got a patch of depth 1 over rows 16-32"),
    (((), (((16, 24), (16, 24)),), (), ()), r"^item\.finer\[1\]\[0\] .*; got a patch of depth 2 over rows 16-24, "
     r"columns 16-24"),  # finer, on the line, but past the side's end
    (((), ("other",), (), ()), r"^item\.finer\[1\]\[0\] .*; got a patch of another quadtree"),
])
def test_paint_with_textures_refuses_malformed_finer(finer, match):
    """DrawItem.finer (the finer patches across each side, at whose border nodes paint_with_textures splits that
    side's edges) is checked as seams is: an InvalidInputError naming item.finer, what was expected and what was got,
    not a patch's border split at the nodes of one not across it. The good finer neighbours split the border: the
    extra vertices are the finer patches' stitched nodes, on the coarse edge (the surface the same)."""
    from stepterrain.texture_lod import DrawItem, paint_with_textures

    quadtree, by_span = _seam_quadtree()
    other = _seam_quadtree(12)[1]
    coarse = by_span[_COARSE]
    if isinstance(finer, tuple):
        finer = tuple(tuple(other[((16, 24), (0, 8))] if s == "other" else by_span[s] if isinstance(s, tuple) else s
                            for s in side) if isinstance(side, tuple) else side for side in finer)
    with ImagePyramid.build(np.full((32, 32, 3), 90, np.uint8), extent=quadtree.root.domain) as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        across = (by_span[(16, 24), (0, 8)], by_span[_FINE])
        plain = paint_with_textures(DrawItem(coarse, (tree.root,), (False,)))
        split = paint_with_textures(DrawItem(coarse, (tree.root,), (False,), (None,) * 4, ((), across, (), ())))
        fine = paint_with_textures(DrawItem(by_span[_FINE], (tree.root,), (False,), (coarse, None, None, None)))
        assert len(split.vertices) > len(plain.vertices) and split.area == pytest.approx(plain.area, rel=1e-12)
        extra = {tuple(v) for v in split.vertices[len(plain.vertices):]}
        assert extra & {tuple(v) for v in fine.vertices}  # at the very floats the finer patch draws
        with pytest.raises(InvalidInputError, match=match):
            paint_with_textures(DrawItem(coarse, (tree.root,), (False,), (None,) * 4, finer))
        with pytest.raises(InvalidInputError, match=r"^item\.finer\[0\] must be empty where item\.seams\[0\] names"):
            paint_with_textures(DrawItem(by_span[_FINE], (tree.root,), (False,), (coarse, None, None, None),
                                         ((coarse,), (), (), ())))


@pytest.mark.parametrize("spacing", [(10.0, 10.0), (-10.0, -10.0), (10.0, -10.0)])
def test_a_corner_cell_with_finer_patches_on_two_sides_is_split_on_both(spacing):
    """A patch with finer neighbours on two sides meeting at one triangle (first row and last column: the top-right
    cell's n00 n01 n11; last row and first column: the bottom-left cell's n00 n11 n10) had that triangle fanned for
    the first side only: the second side's call looked for the edge among its own fan pieces, not the earlier side's,
    and left the coarse edge whole, a T-junction. With dx * dy < 0 the first fan piece happened to keep the other
    edge (the other tests' spacing); with dx * dy > 0 it did not (1-4 T-junction edges in four of eight views)."""
    import math

    from stepterrain.texture_lod import paint_with_textures

    yy, xx = np.mgrid[0:101, 0:77]
    heights = 40 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + np.random.default_rng(3).normal(0, 0.5, xx.shape)
    quadtree = PatchQuadtree(as_terrain(heights, spacing=spacing), leaf_size=4)
    t = quadtree.terrain
    x0, x1, y0, y1 = quadtree.root.domain
    cx, cy, reach = (x0 + x1) / 2, (y0 + y1) / 2, 1.2 * abs(x1 - x0)
    t_junctions, views = {}, 0
    with ImagePyramid.build(np.full((64, 64, 3), 90, np.uint8), extent=quadtree.root.domain) as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        for azimuth in range(0, 360, 45):
            a = math.radians(azimuth)
            camera = Camera((cx + reach * math.cos(a), cy + reach * math.sin(a),
                             quadtree.root.box[1, 2] + 0.4 * abs(x1 - x0)), (cx, cy, quadtree.root.box[0, 2]),
                            viewport=(640, 480))
            items = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=2.0, tau_user=1e9)
            views += sum(any(across) for item in items for across in item.finer) > 0
            unique, edges, counts = _weld([paint_with_textures(item) for item in items])
            assert (counts <= 2).all()
            col = np.rint((unique[:, 0] - t.origin[0]) / t.spacing[0]).astype(int)
            row = np.rint((unique[:, 1] - t.origin[1]) / t.spacing[1]).astype(int)
            nodes = set(zip(row.tolist(), col.tolist(), strict=True))
            bad = 0
            for a_, b_ in edges[counts == 1]:  # a border edge used once with a drawn node inside it: a T-junction
                (ra, ca), (rb, cb) = (row[a_], col[a_]), (row[b_], col[b_])
                if ra == rb:
                    bad += any((ra, c) in nodes for c in range(min(ca, cb) + 1, max(ca, cb)))
                elif ca == cb:
                    bad += any((r, ca) in nodes for r in range(min(ra, rb) + 1, max(ra, rb)))
            if bad:
                t_junctions[azimuth] = bad
    assert views >= 4  # the views have cuts of mixed levels
    assert not t_junctions, f"T-junction edges by azimuth: {t_junctions}"


def test_the_balanced_traversal_looks_each_patchs_textures_up_once_and_asks_the_cache_for_the_final_cut_only(
        monkeypatch):
    """render_with_textures reran the whole traversal per balancing pass: every patch visited again looked its
    texture patches up (child_for), measured τ again, and every patch drawn in a pass, split in a later one, had its
    textures reduced and asked of the cache (is_loaded, which marks them used, and request). Now each patch's texture
    patches are looked up once over the passes and the textures chosen once, for the final cut: with every texture
    loaded, one is_loaded per item and layer."""
    from stepterrain.texture_lod import TextureCache, TexturePatch

    yy, xx = np.mgrid[0:101, 0:77]
    heights = 40 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + np.random.default_rng(3).normal(0, 0.5, xx.shape)
    quadtree = PatchQuadtree(as_terrain(heights, spacing=(10.0, -10.0)), leaf_size=4)
    x0, x1, y0, y1 = quadtree.root.domain
    camera = Camera((x0 - 1.5 * (x1 - x0), (y0 + y1) / 2, quadtree.root.box[1, 2] + 0.5 * (x1 - x0)),
                    ((x0 + x1) / 2, (y0 + y1) / 2, quadtree.root.box[0, 2]), viewport=(640, 480))
    passes, looked_up, asked = [], [], []
    traverse, child_for = texture_lod._traverse, TexturePatch.child_for
    monkeypatch.setattr(texture_lod, "_traverse", lambda *a: passes.append(1) or traverse(*a))
    monkeypatch.setattr(TexturePatch, "child_for", lambda m, g: looked_up.append((id(m), id(g))) or child_for(m, g))

    class Recording(TextureCache):
        def is_loaded(self, patch):
            asked.append(patch)
            return super().is_loaded(patch)

    with ImagePyramid.build(np.full((64, 64, 3), 90, np.uint8), extent=quadtree.root.domain) as pyramid:
        trees = [TextureTree(pyramid, quadtree, max_texture_size=16), TextureTree(pyramid, quadtree,
                                                                                    max_texture_size=8)]
        cache = Recording(budget=1 << 30)
        try:
            for tree in trees:
                for m in tree.patches():
                    cache.load_now(m)
            items = render_with_textures(quadtree.root, [tree.root for tree in trees], camera, gamma_user=1.0,
                                         tau_user=1e9, cache=cache)
        finally:
            cache.close()
    assert len(passes) >= 3  # the cut was balanced in more than one pass
    assert len(looked_up) == len(set(looked_up))
    assert len(asked) == 2 * len(items)
    assert all(m is not None for item in items for m in item.textures)


@pytest.mark.parametrize("eye, target", [((-100.0, 100.0, 150.0), (200.0, -300.0, -20.0)),  # beyond a corner
                                         ((300.0, -400.0, 60.0), (500.0, -700.0, -20.0)),  # inside the patches
                                         ((380.0, -500.0, 600.0), (380.0, -499.0, 0.0))])  # a map view
def test_patches_put_in_view_together_get_each_ones_own_numbers(eye, target):
    """render_with_textures culls each level's patches, puts them in view and measures their γ and τ in one call
    each (h340: the per-patch calls were 60-70 % of a render); each patch's numbers must be those of its own call
    (byte for byte: the cut's decisions compare them with the tolerances), whatever boxes share the batch."""
    from stepterrain.texture_lod import (
        _bounded_segment,
        _bounded_segments,
        _geometric_error_in,
        _geometric_errors_in,
        _in_view,
        _in_views,
    )

    yy, xx = np.mgrid[0:101, 0:77]
    heights = 40 * np.sin(xx / 9.0) * np.cos(yy / 13.0) + np.random.default_rng(3).normal(0, 0.5, xx.shape)
    heights[40:44, 30:33] = np.nan
    patches = PatchQuadtree(as_terrain(heights, spacing=(10.0, -10.0)), leaf_size=4).patches()
    camera = Camera(eye, target, viewport=(640, 480), fov=math.radians(50), near=5.0)
    boxes = np.array([p.box for p in patches])
    visible = camera._boxes_visible(boxes)
    assert visible.tolist() == [camera.box_visible(box) for box in boxes] and 0 < visible.sum() < len(boxes)
    views = _in_views(camera, boxes[::-1])[::-1]  # another order: other neighbours in each batch
    counts = {len(view.s) for view in views}
    assert len(counts) > 3  # boxes of several corner counts, batched by count
    for patch, view in zip(patches, views, strict=True):
        alone = _in_view(camera, patch.box)
        assert view.depth == alone.depth or (math.isnan(view.depth) and math.isnan(alone.depth))
        for a, b in ((view.s, alone.s), (view.t, alone.t), (view.nearest, alone.nearest)):
            assert a.tobytes() == b.tobytes()
    vectors = np.array([[0.0, 0.0, 3.7], [12.5, 0.0, 0.0], [0.0, 7.25, 0.0]])[np.arange(len(views)) % 3]
    together = _bounded_segments(camera, views, vectors)
    assert np.array_equal(together, [_bounded_segment(camera, v, w) for v, w in zip(views, vectors, strict=True)],
                          equal_nan=True)
    gammas = _geometric_errors_in(camera, views, [p.error + 0.5 for p in patches])
    assert np.array_equal(gammas, [_geometric_error_in(p, camera, v, p.error + 0.5)
                                   for p, v in zip(patches, views, strict=True)], equal_nan=True)
    assert len(set(gammas)) > len(patches) // 2


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_corner_solves_shared_between_boxes_are_each_box_own_solve(seed):
    """Camera._visible_parts solves the regular sets of three planes once per distinct right-hand side (a set of
    three frustum planes once per camera, a set with one box face once per distinct offset of that face), not ~150
    per box: every corner is byte for byte the box's own ``np.linalg.solve``, including boxes that share faces,
    faces at 0.0 and at -0.0 (told apart: their solves may differ in the sign of a zero) and a lone box."""
    rng = np.random.default_rng(seed)
    eye = rng.normal(0.0, 50.0, 3)
    camera = Camera(eye, eye + rng.normal(0.0, 1.0, 3), viewport=(800, 600), fov=rng.uniform(0.5, 1.8))
    lo = np.round(rng.normal(0.0, 40.0, (300, 3)) / 10.0) * 10.0  # few distinct faces: shared by many boxes
    hi = lo + np.round(rng.uniform(0.0, 30.0, (300, 3)) / 10.0) * 10.0
    zero = np.flatnonzero(lo[:, 0] == 0.0)
    lo[zero[::2], 0] = -0.0
    hi[hi == 0.0] = -0.0
    boxes = np.stack([lo, hi], axis=1)
    _, (n3, sets3), _ = camera._plane_solver
    assert len(camera._shared_sets[0]) and camera._shared_sets[2] and len(camera._shared_sets[3])
    for part in (boxes, boxes[:20], boxes[:3]):  # shared solves, and a few boxes solving their own
        offsets = np.empty((len(part), 12))
        offsets[:, :6] = camera._frustum[0][:, 3]
        offsets[:, 6:9], offsets[:, 9:] = part[:, 0], -part[:, 1]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            own = np.linalg.solve(n3, -offsets[:, sets3][..., None])[..., 0]
        assert camera._corner_solves(offsets).tobytes() == own.tobytes()
    zeros = boxes[:, 0, 0][boxes[:, 0, 0] == 0.0]
    assert np.signbit(zeros).any() and not np.signbit(zeros).all()  # both zeros among the shared faces
