"""Image pyramids, texture trees and the level-of-detail traversal (paper 004 §3.2.1-3.2.2, §4, §7.3)."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as hst

from stepterrain.errors import DataFileError, InvalidInputError
from stepterrain.texture_lod import (
    Camera,
    ImagePyramid,
    PatchQuadtree,
    TextureCache,
    TextureTree,
    pyramid_shapes,
    render_with_textures,
    texel_pixels,
    visual_geometric_error,
    visual_texture_error,
)

from .reference_texture import real_dem_crop, reduce_reference

rng = np.random.default_rng(11)


# ------------------------------------------------------------------------------------------ pyramid
@pytest.mark.parametrize("shape", [(8, 8, 3), (5, 7, 3), (13, 6, 4), (1, 9, 1), (6, 1, 3), (1, 1, 3), (17, 33, 2)])
def test_pyramid_levels_match_reference_and_keep_the_mean(device, shape):
    image = rng.integers(0, 256, shape, dtype=np.uint8)
    with ImagePyramid.build(image, device=device) as pyramid:
        assert [level.shape[:2] for level in pyramid.levels] == pyramid_shapes(*shape[:2])
        assert pyramid.levels[-1].shape[:2] == (1, 1)
        assert np.array_equal(pyramid.levels[0], image)  # level 0 is the image (a snapshot: the caller may edit it)
        previous = image
        for level in pyramid.levels[1:]:
            exact = reduce_reference(previous)
            assert np.abs(level.astype(np.float64) - exact).max() <= 0.5 + 1e-4
            # area weighting keeps the mean; rounding each pixel to uint8 moves it by at most 0.5. With alpha (2 or 4
            # channels) it keeps the alpha's mean and the premultiplied colour's, c · a / 255 (by at most 0.5 + 0.5)
            if shape[2] in (2, 4):
                new, old = np.asarray(level, dtype=np.float64), previous.astype(np.float64)
                assert abs(new[..., -1].mean() - old[..., -1].mean()) <= 0.5
                premultiplied = [(x[..., :-1] * x[..., -1:] / 255.0).mean() for x in (new, old)]
                assert abs(premultiplied[0] - premultiplied[1]) <= 1.0 + 1e-9
            else:
                assert abs(level.mean() - previous.astype(np.float64).mean()) <= 0.5
            previous = np.asarray(level)


def test_pyramid_sizes_odd_and_even():
    assert pyramid_shapes(16, 16) == [(16, 16), (8, 8), (4, 4), (2, 2), (1, 1)]
    assert pyramid_shapes(7, 5) == [(7, 5), (4, 3), (2, 2), (1, 1)]
    assert pyramid_shapes(1, 1) == [(1, 1)]
    assert pyramid_shapes(16384, 8192)[-1] == (1, 1) and len(pyramid_shapes(16384, 8192)) == 15


@given(rows=hst.integers(1, 40), cols=hst.integers(1, 40), seed=hst.integers(0, 1000))
def test_pyramid_mean_property(rows, cols, seed):
    image = np.random.default_rng(seed).integers(0, 256, (rows, cols, 3), dtype=np.uint8)
    with ImagePyramid.build(image, device="cpu") as pyramid:
        means = [float(np.asarray(level, dtype=np.float64).mean()) for level in pyramid.levels]
        assert all(abs(a - b) <= 0.5 for a, b in zip(means, means[1:], strict=False))


def test_pyramid_anisotropic_levels():
    image = rng.integers(0, 256, (9, 20, 3), dtype=np.uint8)
    with ImagePyramid.build(image, anisotropic=True, device="cpu") as pyramid:
        heights = [s[0] for s in pyramid_shapes(9, 20)]
        widths = [s[1] for s in pyramid_shapes(9, 20)]
        for (kx, ky), level in pyramid.anisotropic.items():
            assert level.shape[:2] == (heights[ky], widths[kx])
        # halving only x: the reference along axis 1
        from .reference_texture import reduce_axis

        expected = reduce_axis(image, 1)
        assert np.abs(pyramid.anisotropic[(1, 0)].astype(float) - expected).max() <= 0.5 + 1e-4


def test_pyramid_from_npy_memmap_and_storage(tmp_path):
    image = rng.integers(0, 256, (30, 50, 3), dtype=np.uint8)
    np.save(tmp_path / "big.npy", image)
    storage = tmp_path / "levels"
    pyramid = ImagePyramid.build(tmp_path / "big.npy", extent=(1000.0, 1500.0, 200.0, 500.0), storage=storage,
                                 device="cpu")
    assert isinstance(pyramid.levels[0], np.memmap) and isinstance(pyramid.levels[1], np.memmap)
    np.testing.assert_array_equal(pyramid.levels[0], image)
    assert pyramid.pixel_size(0) == (10.0, 10.0) and pyramid.pixel_size(1) == (20.0, 20.0)
    assert pyramid.window(0, (1000.0, 1100.0, 400.0, 500.0)) == (0, 10, 0, 10)
    assert pyramid.window_extent(1, (0, 5, 0, 5)) == (1000.0, 1100.0, 400.0, 500.0)
    assert pyramid.window(0, (0.0, 10.0, 0.0, 10.0)) is None
    # NaN raised math.floor's ValueError, inf its OverflowError and text a TypeError
    for domain in ((math.nan, 1.0, 0.0, 1.0), (0.0, math.inf, 0.0, 1.0), "abcd", (1.0, 2.0, 3.0)):
        with pytest.raises(InvalidInputError, match=r"domain must be .*\(xmin, xmax, ymin, ymax\).*; got "):
            pyramid.window(0, domain)
    pyramid.close()
    assert storage.exists()  # a storage folder given by the caller is kept


def test_pyramid_of_a_sliced_memmap_reads_the_slice(tmp_path):
    """A row slice of a memmap keeps its parent's ``offset``: the levels must come from the slice's rows."""
    image = rng.integers(0, 256, (40, 6, 3), dtype=np.uint8)
    np.save(tmp_path / "img.npy", image)
    window = np.load(tmp_path / "img.npy", mmap_mode="r")[20:28]
    with ImagePyramid.build(window, anisotropic=True, device="cpu") as ours, \
            ImagePyramid.build(np.array(window), anisotropic=True, device="cpu") as copy:
        for a, b in zip(ours.levels, copy.levels, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ours.anisotropic[(1, 0)], copy.anisotropic[(1, 0)])


def big_memmap_npy(tmp_path: Path) -> Path:
    """A 48 MB (4000, 4000, 3) uint8 .npy (every 7th row 200, else 0), written through a memmap."""
    source = tmp_path / "big.npy"
    image = np.lib.format.open_memmap(source, mode="w+", dtype=np.uint8, shape=(4000, 4000, 3))
    image[::7] = 200
    image.flush()
    del image
    return source


def pyramid_build_rise(image: str, band_bytes: int, check: str = "") -> int:
    """The peak resident set's rise (bytes) while ``ImagePyramid.build(<image>, band_bytes=...)`` runs in a fresh
    process (``image``: a Python expression, evaluated before the measurement), after a warm-up build; ``check``: one
    more line of assertions on ``pyramid``. Skips where /proc/self/clear_refs cannot be written."""
    script = textwrap.dedent(f"""
        import numpy as np
        from stepterrain.texture_lod import ImagePyramid
        # compile, and warm up every launch path (split over threads, odd sizes) outside the measurement
        ImagePyramid.build(np.zeros((1001, 1003, 3), np.uint8), band_bytes=1 << 20, device="cpu").close()
        def status(key):
            for line in open("/proc/self/status"):
                if line.startswith(key):
                    return int(line.split()[1]) * 1024
        image = {image}
        open("/proc/self/clear_refs", "w").write("5")   # reset the peak resident set
        before = status("VmRSS")
        pyramid = ImagePyramid.build(image, band_bytes={band_bytes}, device="cpu")
        rise = status("VmHWM") - before
        assert pyramid.levels[-1].shape == (1, 1, 3)
        {check}
        pyramid.close()
        print(rise)
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    if result.returncode != 0 and "clear_refs" in result.stderr:
        pytest.skip("/proc/self/clear_refs is not writable here")
    assert result.returncode == 0, result.stderr
    return int(result.stdout.strip().splitlines()[-1])


def test_pyramid_memory_bounded_for_memmap_larger_than_budget(tmp_path):
    """Build from a 48 MB memory-mapped .npy with 1 MB bands: the resident set must not grow by the image."""
    rise = pyramid_build_rise(repr(str(big_memmap_npy(tmp_path))), 1 << 20)
    assert rise < 20 * 1024**2, f"peak resident set rose by {rise / 1024**2:.1f} MB for a 48 MB image"


def test_pyramid_bad_input(tmp_path):
    with pytest.raises(DataFileError, match="does not exist"):
        ImagePyramid.build(tmp_path / "missing.png")
    (tmp_path / "corrupt.png").write_bytes(b"\x89PNG not really")
    with pytest.raises(DataFileError, match="cannot read"):
        ImagePyramid.build(tmp_path / "corrupt.png")
    with pytest.raises(InvalidInputError, match="must be uint8"):
        ImagePyramid.build(np.zeros((4, 4), np.float32))
    with pytest.raises(InvalidInputError, match="xmin < xmax"):
        ImagePyramid.build(np.zeros((4, 4), np.uint8), extent=(1, 0, 0, 1))
    # a folder was a file that "does not exist"; a bytes path an image "of dtype |S..."
    with pytest.raises(DataFileError, match=rf"^image file {re.escape(repr(str(tmp_path)))} is a folder; expected an "
                                            "image file$"):
        ImagePyramid.build(tmp_path)
    with pytest.raises(InvalidInputError, match=r"^image must be an \(H, W\) or \(H, W, C\) uint8 array or a path "
                                                r"\(a str or os.PathLike\); got bytes$"):
        ImagePyramid.build(os.fsencode(tmp_path / "corrupt.png"))


def test_pyramid_of_a_16_bit_greyscale_file_is_read_by_its_range(tmp_path):
    """Pillow's convert("RGB") of a 16-bit greyscale PNG saturates every value above 255: the pyramid of a 16-bit
    relief was almost all white. It is read to 8 bits by its full range (as the globe's textures are); a float
    image is refused by name."""
    from PIL import Image

    ramp = np.round(np.linspace(0, 65535, 32 * 64)).astype(np.uint16).reshape(32, 64)
    Image.fromarray(ramp).save(tmp_path / "relief16.png")
    Image.fromarray((ramp / 257.0).round().astype(np.uint8)).save(tmp_path / "relief8.png")
    with ImagePyramid.build(tmp_path / "relief16.png", device="cpu") as wide, \
            ImagePyramid.build(tmp_path / "relief8.png", device="cpu") as narrow:
        for a, b in zip(wide.levels, narrow.levels, strict=True):
            np.testing.assert_array_equal(a, b)
    Image.fromarray(np.full((8, 8), 0.5, np.float32)).save(tmp_path / "float.tif")
    with pytest.raises(InvalidInputError, match=r"image .*float\.tif' must be an 8-bit or 16-bit image; got Pillow "
                                                "mode F"):
        ImagePyramid.build(tmp_path / "float.tif")


def test_paint_with_textures_of_a_grey_alpha_pyramid():
    """A 2-channel (grey + alpha) pyramid built, then failed in paint_with_textures with "a thematic layer needs an
    (h, w, 3) RGB or (h, w, 4) RGBA image"; it is painted as the RGBA image (grey repeated, alpha kept)."""
    from stepterrain.texture_lod import paint_with_textures

    quadtree = PatchQuadtree(np.zeros((17, 17)), leaf_size=8)
    image = np.random.default_rng(2).integers(0, 256, (32, 32, 2), dtype=np.uint8)
    rgba = image[:, :, [0, 0, 0, 1]]
    textures = []
    for source in (image, rgba):
        with ImagePyramid.build(source, extent=quadtree.root.domain, device="cpu") as pyramid:
            tree = TextureTree(pyramid, quadtree, max_texture_size=16)
            items = render_with_textures(quadtree.root, [tree.root], Camera((8, -30, 20), (8, 8, 0)))
            textures.append([np.asarray(paint_with_textures(item).visual.material.baseColorTexture) for item in items])
    assert len(textures[0]) == len(textures[1]) > 0
    for grey_alpha, as_rgba in zip(*textures, strict=True):
        np.testing.assert_array_equal(grey_alpha, as_rgba)


@pytest.mark.parametrize("storage", [5, 2.5, True, b"levels", ["levels"]])
def test_pyramid_storage_must_be_a_folder_path(storage):
    """storage=5 raised pathlib's 'expected str, bytes or os.PathLike object' TypeError."""
    with pytest.raises(InvalidInputError,
                       match=r"storage must be a folder path \(str or os.PathLike\) or None; got "):
        ImagePyramid.build(np.zeros((4, 4), np.uint8), storage=storage, device="cpu")


def test_pyramid_storage_must_not_be_an_empty_path(tmp_path, monkeypatch):
    """storage="" was accepted as Path(""), the working directory: the level files were written there."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InvalidInputError, match=r"storage must be a folder path \(str or os.PathLike\) or None; "
                                                r"got '' \(an empty path"):
        ImagePyramid.build(np.zeros((4, 4), np.uint8), storage="", device="cpu")
    assert list(tmp_path.iterdir()) == []


IMAGE = np.zeros((5, 3, 3), np.uint8)  # levels (5, 3), (3, 2), (2, 1), (1, 1)


def pyramid_levels(image=IMAGE):
    return [np.zeros((*shape, image.shape[2]), np.uint8) for shape in pyramid_shapes(*image.shape[:2])]


@pytest.mark.parametrize("args, match", [
    (("x", (0, 1, 0, 1), "levels"), r"levels must be a list of \(H, W, C\) uint8 arrays from the image \(level 0\) "
                                     r"down to 1 x 1; got str"),
    ((IMAGE, (0, 1, 0, 1), "levels"), r"levels must be a list of .*; got ndarray"),
    (([], (0, 1, 0, 1), "levels"), r"levels must be a list of .*; got an empty list"),
    (([np.zeros((4, 4, 3))], (0, 1, 0, 1), "levels"),
     r"levels\[0\] must be an \(H, W, C\) uint8 array with 1-4 channels; got dtype float64, shape \(4, 4, 3\)"),
    (([IMAGE, "y"], (0, 1, 0, 1), "levels"), r"levels\[1\] must be an \(H, W, C\) uint8 array .*; got str"),
    (([np.zeros((0, 4, 3), np.uint8)], (0, 1, 0, 1), "levels"),  # pyramid_shapes(0, 4) never reached 1 x 1
     r"levels\[0\] must be an \(H, W, C\) uint8 array with 1-4 channels; got dtype uint8, shape \(0, 4, 3\)"),
    ((pyramid_levels()[:2], (0, 1, 0, 1), "levels"),  # a TextureTree over them found no level that fits
     r"levels must run from the image down to 1 x 1: 4 levels for a 5 x 3 image; got 2"),
    (([IMAGE, np.zeros((3, 2, 1), np.uint8), *pyramid_levels()[2:]], (0, 1, 0, 1), "levels"),
     r"levels\[1\] must have shape \(3, 2, 3\) \(levels\[0\] halved, rounded up\); got \(3, 2, 1\)"),
    ((pyramid_levels(), (1, 0, 0, 1), "levels"), r"extent must be finite \(xmin, xmax, ymin, ymax\)"),
    ((pyramid_levels(), None, "levels"), r"extent must be \(xmin, xmax, ymin, ymax\); got None"),
    ((pyramid_levels(), (0, 1, 0, 1), 5), r"storage must be a folder path \(str or os.PathLike\) or None; got 5"),
    ((pyramid_levels(), (0, 1, 0, 1), ""), r"storage must be a folder path .*; got '' \(an empty path"),
    ((pyramid_levels(), (0, 1, 0, 1), "levels", [1]), r"anisotropic must be a dict of levels by \(kx, ky\) or "
                                                      r"None; got list"),
    ((pyramid_levels(), (0, 1, 0, 1), "levels", None, "yes"), r"owned must be True or False; got 'yes'"),
    ((pyramid_levels(), (0, 1, 0, 1), None, None, True),
     r"owned=True deletes the storage folder on close\(\); got storage=None"),
])
def test_pyramid_constructor_checks_its_arguments(args, match):
    """ImagePyramid(...) took anything: a string of levels failed at shape() with AttributeError, missing levels
    made TextureTree report a mismatched extent, a bad extent gave NaN windows."""
    with pytest.raises(InvalidInputError, match=match):
        ImagePyramid(*args)


def test_pyramid_constructor_reopens_built_levels(tmp_path):
    with ImagePyramid.build(IMAGE, extent=(0, 3, 0, 5), storage=tmp_path, device="cpu") as built:
        again = ImagePyramid(list(built.levels), built.extent, tmp_path)
        assert [level.shape for level in again.levels] == [level.shape for level in built.levels]
        assert again.extent == (0.0, 3.0, 0.0, 5.0) and again.storage == tmp_path
        assert again.window(0, (0.0, 3.0, 0.0, 5.0)) == (0, 5, 0, 3)
        again.close()
    assert ImagePyramid(pyramid_levels(), (0, 3, 0, 5), None).shape(3) == (1, 1)  # in-memory levels


@pytest.mark.parametrize("level", [-1, -4, 4, 10**20, True, "1", 1.0, np.float64(2.0), None])
def test_pyramid_levels_outside_the_pyramid_are_refused(level):
    """shape(-1), window(-1, ...), sub_image(-1, ...) (and pixel_size, window_extent) read the last level (1 x 1)
    through Python's negative indexing, True level 1; 4, "1" and 1.0 raised the list's IndexError or TypeError."""
    pyramid = ImagePyramid(pyramid_levels(), (0, 3, 0, 5), None)  # 4 levels
    uses = [lambda: pyramid.shape(level), lambda: pyramid.pixel_size(level),
            lambda: pyramid.window(level, (0.0, 3.0, 0.0, 5.0)), lambda: pyramid.window_extent(level, (0, 1, 0, 1)),
            lambda: pyramid.sub_image(level, (0, 1, 0, 1))]
    for use in uses:
        with pytest.raises(InvalidInputError, match=rf"level must index the pyramid's 4 levels \(0 to 3\); "
                                                    rf"got {re.escape(repr(level))}"):
            use()
    assert pyramid.shape(np.int64(3)) == (1, 1) and pyramid.sub_image(np.uint8(1), (0, 3, 0, 2)).shape == (3, 2, 3)


WINDOW = (r"window must be \(r0, r1, c0, c1\) whole pixel indices with 0 <= r0 < r1 <= 5 and 0 <= c0 < c1 <= 3 "
          r"\(level 0\)")


@pytest.mark.parametrize(("window", "match"), [
    ((-1, 5, 0, 3), rf"{WINDOW}; got \(-1, 5, 0, 3\)"),  # sliced from the end: a 1-row image, extent to y = 6
    ((3, 1, 0, 3), rf"{WINDOW}; got \(3, 1, 0, 3\)"),  # reversed: an empty image, a reversed extent
    ((0, 5, 0, 9), rf"{WINDOW}; got \(0, 5, 0, 9\)"),  # past the edge: clipped image, wider extent
    ((0, 0, 0, 3), rf"{WINDOW}; got \(0, 0, 0, 3\)"),  # empty
    ((0, 5.5, 0, 3), rf"{WINDOW}; got \(0, 5.5, 0, 3\)"),  # slicing's TypeError, or a fractional extent
    (("0", 5, 0, 3), rf"{WINDOW} \(real numbers\); got dtype <U21"),  # slicing's or multiplying's TypeError
    ((True, 5, 0, 3), rf"{WINDOW} \(real numbers\); got a bool \(True\) at index \(0,\)"),  # read as row 1
    ((0, 5, 0), rf"{WINDOW}; got \(0, 5, 0\)"),  # "not enough values to unpack"
    ("abc", rf"{WINDOW} \(real numbers\); got dtype <U3"),
])
def test_pyramid_windows_outside_the_level_or_reversed_are_refused(window, match):
    """sub_image and window_extent sliced and measured any window: a negative index counted from the end, a
    reversed window gave an empty image, one past the edge a clipped image with a wider extent."""
    pyramid = ImagePyramid(pyramid_levels(), (0, 3, 0, 5), None)  # level 0: 5 x 3
    for use in (pyramid.sub_image, pyramid.window_extent):
        with pytest.raises(InvalidInputError, match=match):
            use(0, window)
    assert pyramid.sub_image(0, (np.int64(1), 5, 0, 3.0)).shape == (4, 3, 3)
    assert pyramid.window_extent(0, [0, 5, 0, 3]) == (0.0, 3.0, 0.0, 5.0)


@pytest.mark.parametrize("given_storage", [False, True])
def test_a_closed_pyramid_is_refused(tmp_path, given_storage):
    """After close() (or its with block) level 0 could still be read, the other levels raised IndexError, and
    len() answered 1."""
    quadtree = PatchQuadtree(np.zeros((9, 9), np.float32), leaf_size=4)
    image = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    storage = tmp_path / "levels" if given_storage else None
    with ImagePyramid.build(image, extent=quadtree.root.domain, storage=storage, anisotropic=True,
                            device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=4)
        assert len(pyramid) == 5 and tree.root.image().shape[2] == 3
    pyramid.close()  # closing twice is fine
    uses = {
        "levels": lambda: pyramid.levels,
        "anisotropic": lambda: pyramid.anisotropic,
        "len": lambda: len(pyramid),
        "shape 0": lambda: pyramid.shape(0),
        "shape 1": lambda: pyramid.shape(1),
        "pixel_size": lambda: pyramid.pixel_size(0),
        "window": lambda: pyramid.window(0, quadtree.root.domain),
        "window_extent": lambda: pyramid.window_extent(0, (0, 1, 0, 1)),
        "sub_image 0": lambda: pyramid.sub_image(0, (0, 1, 0, 1)),
        "sub_image 1": lambda: pyramid.sub_image(1, (0, 1, 0, 1)),
        "with": lambda: pyramid.__enter__(),
        "patch image": lambda: tree.root.image(),
        "patch nbytes": lambda: tree.root.nbytes,
        "new tree": lambda: TextureTree(pyramid, quadtree),
    }
    for name, use in uses.items():
        with pytest.raises(InvalidInputError, match=r"the ImagePyramid is closed \(by close\(\) or the end of its "
                                                    r"with block\)"):
            use()
            pytest.fail(f"{name} read a closed pyramid")
    assert pyramid.extent == tuple(quadtree.root.domain)


# ------------------------------------------------------------------------------------------ trees
def terrain_and_image(size=129, image_size=(1000, 1000)):
    heights = real_dem_crop("big_tujunga_srtm_30m_utm11n.npz", size=size, step=4)
    # a north-up grid: node (0, 0) at the north-west corner, 100 m spacing
    from stepterrain.terrain import Terrain

    terrain = Terrain.from_heights(heights, spacing=(100.0, -100.0), origin=(0.0, (size - 1) * 100.0))
    image = rng.integers(0, 256, (*image_size, 3), dtype=np.uint8)
    return terrain, image


def test_texture_tree_windows_cover_patches_at_the_finest_level():
    terrain, image = terrain_and_image()
    quadtree = PatchQuadtree(terrain, leaf_size=16)
    xmin, xmax, ymin, ymax = quadtree.root.domain
    with ImagePyramid.build(image, extent=(xmin, xmax, ymin, ymax), device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=128)
        patches = tree.patches()
        assert len(patches) > 5
        for m in patches:
            d, g = m.domain, m.geometry.domain
            assert d[0] <= g[0] + 1e-6 and d[1] >= g[1] - 1e-6 and d[2] <= g[2] + 1e-6 and d[3] >= g[3] - 1e-6
            r0, r1, c0, c1 = m.window
            assert r1 - r0 <= 128 + 2 and c1 - c0 <= 128 + 2  # and a pixel more on each side
            if m.level > 0:  # the next finer level would not fit
                w = pyramid.window(m.level - 1, g)
                assert w[1] - w[0] > 128 or w[3] - w[2] > 128
                assert len(m.children) == len(m.geometry.children)
            else:
                assert m.is_leaf  # pruned: full resolution reached
            view = m.image()
            assert np.shares_memory(view, pyramid.levels[m.level]) or view.size == 0
        assert any(m.level == 0 for m in patches)


def test_texture_tree_partial_coverage():
    terrain, image = terrain_and_image()
    quadtree = PatchQuadtree(terrain, leaf_size=32)
    xmin, xmax, ymin, ymax = quadtree.root.domain
    west = (xmin, (xmin + xmax) / 2, ymin, ymax)
    with ImagePyramid.build(image[:, :500], extent=west, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=64)
        for m in tree.patches():
            assert m.domain[0] >= west[0] - 1e-6 and m.domain[1] <= west[1] + 1e-6
        east_children = [c for c in quadtree.root.children if c.domain[0] >= west[1] - 1e-6]
        assert east_children and all(tree.root.child_for(c) is None for c in east_children)
    with ImagePyramid.build(image, extent=(1e6, 1e6 + 10, 0, 10), device="cpu") as far, \
            pytest.raises(InvalidInputError, match="mismatched extent"):
        TextureTree(far, quadtree)


def test_quadtree_errors_and_boxes():
    terrain, _ = terrain_and_image(size=65)
    quadtree = PatchQuadtree(terrain, leaf_size=8)
    for patch in quadtree.patches():
        block = terrain.heights[patch.rows[0]: patch.rows[1] + 1, patch.cols[0]: patch.cols[1] + 1]
        assert patch.box[0, 2] == block.min() and patch.box[1, 2] == block.max()
        if patch.is_leaf:
            assert patch.stride == 1 and patch.error == 0.0
        else:
            assert patch.error >= 0 and len(patch.children) == 4
    assert quadtree.root.error > 0


# ------------------------------------------------------------------------------------------ errors, traversal
def test_visual_geometric_error_matches_projection():
    terrain, _ = terrain_and_image(size=65)
    quadtree = PatchQuadtree(terrain, leaf_size=8)
    root = quadtree.root
    box = root.box
    # camera south of the box at the height of its centre, looking north: the nearest point is on the south face
    centre = box.mean(axis=0)
    distance = 5000.0
    eye = (centre[0], box[0, 1] - distance, centre[2])
    camera = Camera(eye, (centre[0], box[1, 1], centre[2]), viewport=(800, 600), fov=math.radians(60))
    expected = camera.focal_pixels * root.error / distance
    assert visual_geometric_error(root, camera) == pytest.approx(expected, rel=1e-6)


def lod_setup(leaf_size=16, max_texture_size=64):
    terrain, image = terrain_and_image()
    quadtree = PatchQuadtree(terrain, leaf_size=leaf_size)
    xmin, xmax, ymin, ymax = quadtree.root.domain
    pyramid = ImagePyramid.build(image, extent=(xmin, xmax, ymin, ymax), device="cpu")
    tree = TextureTree(pyramid, quadtree, max_texture_size=max_texture_size)
    centre = quadtree.root.box.mean(axis=0)
    camera = Camera((xmin + 0.3 * (xmax - xmin), ymin - 2000.0, quadtree.root.box[1, 2] + 3000.0),
                    (centre[0], centre[1], quadtree.root.box[0, 2]), viewport=(640, 480))
    return quadtree, tree, pyramid, camera


@pytest.mark.parametrize("gamma_user,tau_user", [(1.0, 1.0), (4.0, 2.0), (0.5, 8.0)])
def test_every_draw_satisfies_thresholds_or_is_a_leaf(gamma_user, tau_user):
    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        draws = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=gamma_user, tau_user=tau_user)
        assert draws
        for item in draws:
            n, (m,) = item.geometry, item.textures
            assert n.is_leaf or visual_geometric_error(n, camera) <= gamma_user
            assert n.is_leaf or m.is_leaf or visual_texture_error(n, m, camera) <= tau_user
            # the texture covers the geometry patch
            assert m.domain[0] <= n.domain[0] + 1e-6 and m.domain[1] >= n.domain[1] - 1e-6
            # parent reduction: the parent would be too coarse
            assert m.parent is None or visual_texture_error(n, m.parent, camera) > tau_user
        # drawn patches never overlap (a cut through the tree)
        ids = {id(item.geometry) for item in draws}
        for item in draws:
            parent = item.geometry.parent
            while parent is not None:
                assert id(parent) not in ids
                parent = parent.parent


def test_finer_thresholds_refine_more():
    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        coarse = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=50.0, tau_user=50.0)
        fine = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=0.5, tau_user=0.5)
        assert len(fine) > len(coarse)


def test_parent_fallback_while_loading_then_finer():
    quadtree, tree, pyramid, camera = lod_setup()
    gate = threading.Event()

    def slow_loader(patch):
        if patch is not tree.root:
            gate.wait(timeout=30)
        return np.array(patch.image())

    cache = TextureCache(budget=1 << 30, loader=slow_loader)
    with pyramid:
        cache.load_now(tree.root)
        first = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=1.0, tau_user=1.0, cache=cache)
        assert all(item.textures[0] is tree.root for item in first), "everything falls back to the loaded root"
        gate.set()
        cache.wait()
        second = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=1.0, tau_user=1.0, cache=cache)
        assert any(item.textures[0] is not tree.root for item in second)
        assert all(cache.is_loaded(item.textures[0]) for item in second)
    cache.close()


def test_lru_budget_evicts_least_recently_used():
    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        patches = [m for m in tree.patches() if m.nbytes > 0][:6]
        budget = sum(m.nbytes for m in patches[:3])
        cache = TextureCache(budget=budget)
        for m in patches:
            cache.load_now(m)
        assert cache.bytes_loaded <= budget and cache.evictions >= 1
        assert not cache.is_loaded(patches[0]) and cache.is_loaded(patches[-1])
        cache.close()


def test_hybrid_shading_switches_to_lighting_close_up():
    quadtree, tree, pyramid, camera = lod_setup(max_texture_size=1024)
    with pyramid:
        root = quadtree.root
        low = root.box[0, 2]
        near = Camera((root.domain[0] + 50, root.domain[2] + 50, low + 30.0),
                      (root.domain[0] + 800, root.domain[2] + 800, low), viewport=(640, 480))
        draws = render_with_textures(root, [tree.root], near, gamma_user=1.0, tau_user=1.0, hybrid=[True])
        lit = [item for item in draws if item.lighting[0]]
        assert lit, "texels larger than tau_user close to the camera switch to computed lighting"
        for item in lit:
            assert texel_pixels(item.geometry, item.textures[0], near) > 1.0


def test_bad_traversal_input():
    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        with pytest.raises(InvalidInputError, match="gamma_user must be"):
            render_with_textures(quadtree.root, [tree.root], camera, gamma_user=-1)
        with pytest.raises(InvalidInputError, match="one flag per layer"):
            render_with_textures(quadtree.root, [tree.root], camera, hybrid=[True, False])
    with pytest.raises(InvalidInputError, match="must differ"):
        Camera((0, 0, 0), (0, 0, 0))


def test_traversal_arguments_of_the_wrong_type_are_named():
    # each raised an AttributeError or TypeError from deep in the traversal ('str' object has no attribute
    # 'box', 'NoneType' object is not iterable, ...); a texture tree over another quadtree of the same terrain
    # was accepted and its layer silently dropped below the root (child_for found none of root's children)
    from stepterrain.texture_lod import paint_with_textures

    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        cases = [
            (("x", [tree.root], camera), {}, "root must be a GeometryPatch"),
            ((quadtree.root, None, camera), {}, "textures must be a sequence"),
            ((quadtree.root, tree.root, camera), {}, "textures must be a sequence"),
            ((quadtree.root, ["x"], camera), {}, r"textures\[0\] must be a TexturePatch"),
            ((quadtree.root, [tree.root], "camera"), {}, "camera must be a stepterrain Camera"),
            ((quadtree.root, [tree.root], camera), {"cache": "x"}, "cache must be a TextureCache"),
            ((PatchQuadtree(quadtree.terrain, leaf_size=16).root, [tree.root], camera), {}, "another geometry patch"),
        ]
        for args, kwargs, match in cases:
            with pytest.raises(InvalidInputError, match=match):
                render_with_textures(*args, **kwargs)
        item = render_with_textures(quadtree.root, [tree.root], camera)[0]
        with pytest.raises(InvalidInputError, match="item must be a DrawItem"):
            paint_with_textures("x")
        with pytest.raises(InvalidInputError, match="layer must index"):
            paint_with_textures(item, "0")
        with pytest.raises(InvalidInputError, match="pyramid must be an ImagePyramid"):
            TextureTree("x", quadtree)
        with pytest.raises(InvalidInputError, match="quadtree must be a PatchQuadtree"):
            TextureTree(pyramid, "x")
    for workers in (0, "2", 1.5):  # ThreadPoolExecutor's ValueError / TypeError before
        with pytest.raises(InvalidInputError, match="workers must be a positive int"):
            TextureCache(100, workers=workers)
    with pytest.raises(InvalidInputError, match="loader must be a function"):
        TextureCache(100, loader="x")  # accepted, and every background load failed


def test_flags_must_be_bools():
    # a non-empty string is true: hybrid=['no'] lit the layer, hybrid='n' read as one flag 'n' (True), and
    # anisotropic='no' built the rip-map; hybrid=5 raised the int's 'not iterable' TypeError
    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        for hybrid, match in ((["no"], r"hybrid\[0\] must be True or False"), ("n", "hybrid must be a sequence"),
                              (5, "hybrid must be a sequence")):
            with pytest.raises(InvalidInputError, match=match):
                render_with_textures(quadtree.root, [tree.root], camera, hybrid=hybrid)
        assert render_with_textures(quadtree.root, [tree.root], camera, hybrid=np.array([True]))
    with pytest.raises(InvalidInputError, match="anisotropic must be True or False"):
        ImagePyramid.build(np.zeros((4, 4), np.uint8), anisotropic="no", device="cpu")


def test_storage_file_of_pyramid_removed_on_close():
    pyramid = ImagePyramid.build(np.zeros((6, 6, 3), np.uint8), device="cpu")
    folder = Path(pyramid.storage)
    assert folder.exists()
    pyramid.close()
    assert not folder.exists()


def test_paint_with_textures_tiles_the_visible_terrain():
    from stepterrain.texture_lod import _samples, paint_with_textures

    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid:
        xmin, xmax, ymin, ymax = quadtree.root.domain
        above = Camera(((xmin + xmax) / 2, (ymin + ymax) / 2 - 1.0, quadtree.root.box[1, 2] + 30000.0),
                       ((xmin + xmax) / 2, (ymin + ymax) / 2, quadtree.root.box[0, 2]), viewport=(640, 480))
        draws = render_with_textures(quadtree.root, [tree.root], above, gamma_user=2.0, tau_user=2.0)
        meshes = [paint_with_textures(item) for item in draws]
        def xy_area(mesh):
            e1 = mesh.triangles[:, 1, :2] - mesh.triangles[:, 0, :2]
            e2 = mesh.triangles[:, 2, :2] - mesh.triangles[:, 0, :2]
            return float(np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()) / 2

        projected = sum(xy_area(m) for m in meshes)
        assert projected == pytest.approx((xmax - xmin) * (ymax - ymin), rel=1e-9)
        for item, mesh in zip(draws, meshes, strict=True):
            uv = mesh.visual.uv
            assert uv.min() >= 0 and uv.max() <= 1
            image = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
            np.testing.assert_array_equal(image, np.asarray(item.textures[0].image()))
            # vertices lie on the terrain at their grid nodes, but those stitched onto a coarser neighbour's edge
            t = quadtree.terrain
            col = np.rint((mesh.vertices[:, 0] - t.origin[0]) / t.spacing[0]).astype(int)
            row = np.rint((mesh.vertices[:, 1] - t.origin[1]) / t.spacing[1]).astype(int)
            (r0, r1), (c0, c1) = item.geometry.rows, item.geometry.cols
            stitched = np.zeros(len(col), dtype=bool)
            for line, seam in zip((row == r0, row == r1, col == c0, col == c1), item.seams, strict=True):
                stitched |= line & (seam is not None)
            stride = item.geometry.stride  # and a finer neighbour's nodes on its edge, where it splits its border
            extra = ~(np.isin(row, _samples(r0, r1, stride)) & np.isin(col, _samples(c0, c1, stride)))
            assert extra.any() == any(item.finer)
            stitched |= extra
            assert (mesh.vertices[~stitched, 2] == t.heights[row, col][~stitched]).all()


def test_pyramid_of_a_georeferenced_geotiff():
    pytest.importorskip("rasterio")
    from .reference_texture import find_shared

    path = find_shared("earth_day_bluemarble_3840x1920.tif")  # paletted GeoTIFF, EPSG:4326, whole globe
    with ImagePyramid.build(path, device="cpu") as pyramid:
        assert pyramid.extent == pytest.approx((-180.0, 180.0, -90.0, 90.0))
        assert pyramid.levels[0].shape == (1920, 3840, 3) and pyramid.levels[-1].shape == (1, 1, 3)
        assert pyramid.pixel_size(0) == pytest.approx((0.09375, 0.09375))
        # the Pacific west of South America (lon -100, lat -20) is ocean: blue dominates at every level
        for level in range(0, 6):
            r0, r1, c0, c1 = pyramid.window(level, (-101.0, -99.0, -21.0, -19.0))
            patch = np.asarray(pyramid.sub_image(level, (r0, r1, c0, c1)), dtype=float).reshape(-1, 3).mean(axis=0)
            assert patch[2] > patch[0]


@pytest.mark.parametrize("transform", [(1.0, 0.0, 100.0, 0.0, 1.0, 200.0), (-1.0, 0.0, 106.0, 0.0, -1.0, 204.0)])
def test_pyramid_of_a_geotiff_stored_south_up_or_east_to_west_is_refused_by_name(tmp_path, transform):
    """A GeoTIFF whose rows run south to north (or columns east to west) has bounds with bottom > top (or left >
    right): the pyramid blamed an "extent" nobody gave; row 0 is read as the north edge, so it cannot be placed."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    path = tmp_path / "flipped.tif"
    image = np.arange(4 * 6, dtype=np.uint8).reshape(1, 4, 6)
    with rasterio.open(path, "w", driver="GTiff", height=4, width=6, count=1, dtype="uint8",
                       transform=Affine(*transform)) as dataset:  # fmt: skip
        dataset.write(image)
    with pytest.raises(InvalidInputError, match=r"flipped\.tif' is georeferenced with its rows running south to "
                                                r"north or its columns east to west .*pass extent="):
        ImagePyramid.build(path, device="cpu")
    with ImagePyramid.build(path, extent=(0.0, 6.0, 0.0, 4.0), device="cpu") as pyramid:  # placed by the caller
        assert pyramid.extent == (0.0, 6.0, 0.0, 4.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"gamma_user": "2"}, r"gamma_user must be a number of pixels; got '2'"),
        ({"tau_user": True}, r"tau_user must be a number of pixels; got True"),
        ({"gamma_user": -1.0}, r"gamma_user must be a finite number of pixels >= 0; got -1.0"),
        ({"tau_user": float("nan")}, r"tau_user must be a finite number of pixels >= 0; got nan"),
    ],
)
def test_render_with_textures_thresholds_are_numbers_of_pixels(kwargs, match):
    """Text and bools were taken by float() as pixel thresholds ("2" -> 2.0, True -> 1.0)."""
    quadtree, tree, pyramid, camera = lod_setup()
    with pyramid, pytest.raises(InvalidInputError, match=match):
        render_with_textures(quadtree.root, [tree.root], camera, **kwargs)


def test_pyramid_of_an_image_with_a_transparent_colour_keeps_it_transparent(tmp_path):
    """A palette PNG (or an L / RGB one) whose transparent colour is a tRNS chunk (Pillow's info["transparency"], as
    gdal_translate writes nodata to a paletted PNG) has no alpha band: the pyramid converted it to RGB and drew the
    transparent pixels opaque in their palette colour. They are alpha 0 now, as render_textured_mesh reads them."""
    from PIL import Image

    palette = Image.new("P", (4, 2))
    palette.putpalette([255, 0, 0, 0, 255, 0] + [0] * 762)
    palette.putdata([0, 1, 1, 0, 0, 0, 1, 1])
    palette.save(tmp_path / "palette.png", transparency=1)
    grey = Image.fromarray(np.array([[10, 200, 200, 10], [10, 10, 200, 200]], np.uint8))
    grey.save(tmp_path / "grey.png", transparency=200)
    rgb = Image.fromarray(np.array([[[255, 0, 0], [0, 255, 0], [0, 255, 0], [255, 0, 0]]] * 2, np.uint8))
    rgb.save(tmp_path / "rgb.png", transparency=(0, 255, 0))
    for name, opaque in (("palette.png", (255, 0, 0)), ("grey.png", (10, 10, 10)), ("rgb.png", (255, 0, 0))):
        with Image.open(tmp_path / name) as picture:
            expected = np.asarray(picture.convert("RGBA"))
        with ImagePyramid.build(tmp_path / name, device="cpu") as pyramid:
            level = np.asarray(pyramid.levels[0])
            assert level.shape[2] == 4, name
            np.testing.assert_array_equal(level, expected)
            assert level[..., 3].tolist() != [[255] * 4] * 2  # some pixels transparent
            assert (level[level[..., 3] == 255][:, :3] == opaque).all()


def test_texture_tree_refuses_an_image_in_another_crs_than_the_terrain():
    """The Blue Marble GeoTIFF (EPSG:4326, -180..180) over the Front Range DEM in degrees, which load_dem reads as
    local equirectangular metres (0..53 km): the extents were compared as numbers, so the tree draped lon 0..180,
    lat -90..0 (the Indian Ocean) on Colorado without a word. The pyramid keeps the GeoTIFF's CRS and the tree
    refuses another CRS than the terrain's, naming both; on a DEM read from degrees into local metres it places the
    image at its exact extent there (as the extent given in those metres does): its Colorado pixels on the DEM."""
    pytest.importorskip("rasterio")
    import stepterrain as st

    from .reference_texture import find_shared

    front_range = st.load_dem(find_shared("front_range_srtmgl3_3arcsec.tif"))
    tujunga = st.load_dem(find_shared("big_tujunga_srtm_30m_utm11n.tif"))
    marble = find_shared("earth_day_bluemarble_3840x1920.tif")
    with ImagePyramid.build(marble, device="cpu") as pyramid:
        assert pyramid.crs == "EPSG:4326"
        with pytest.raises(InvalidInputError, match=r"^the image is in CRS 'EPSG:4326' but the terrain is in "
                                                    r"'EPSG:32611' \(mismatched CRS.*gdalwarp -dstalpha -t_srs "
                                                    r"'EPSG:32611'"):
            TextureTree(pyramid, PatchQuadtree(tujunga))
        placed = TextureTree(pyramid, PatchQuadtree(front_range))
        assert placed.pyramid.crs == front_range.crs and placed.pyramid.levels is pyramid.levels
        extent = placed.pyramid.extent
        placed_window = placed.root.window
    with ImagePyramid.build(marble, extent=extent, crs=front_range.crs, device="cpu") as pyramid:
        tree = TextureTree(pyramid, PatchQuadtree(front_range))
        # the DEM's nodes span lon -105.8158..-105.1846, lat 39.8346..40.4658: Blue Marble pixels of 0.09375°
        lon = (-105.815833, -105.184583)
        lat = (39.834583, 40.465833)
        cols = [math.floor((lon[0] + 180) / 0.09375), math.ceil((lon[1] + 180) / 0.09375)]
        rows = [math.floor((90 - lat[1]) / 0.09375), math.ceil((90 - lat[0]) / 0.09375)]
        assert tree.root.level == 0
        assert pyramid.window(0, front_range.extent) == (rows[0], rows[1], cols[0], cols[1])
        assert tree.root.window == (rows[0] - 1, rows[1] + 1, cols[0] - 1, cols[1] + 1)  # a pixel more a side
        assert placed_window == tree.root.window
    with ImagePyramid.build(marble, extent=extent, device="cpu") as pyramid:  # an extent given: its CRS unknown
        assert pyramid.crs is None and TextureTree(pyramid, PatchQuadtree(front_range)).root.level == 0
    with pytest.raises(InvalidInputError, match=r"^crs 'EPSG:32611' is not the CRS 'EPSG:4326' of image .*pass "
                                                r"extent= in crs"):
        ImagePyramid.build(marble, crs="EPSG:32611", device="cpu")
    with pytest.raises(InvalidInputError, match=r"^crs must be a CRS string \(e\.g\. 'EPSG:32611'\) or None; got 5$"):
        ImagePyramid.build(np.zeros((2, 2, 3), np.uint8), crs=5, device="cpu")


def test_pyramid_of_a_geotiff_with_nodata_makes_it_transparent(tmp_path):
    """A GeoTIFF's nodata (an orthophoto's black collar tagged nodata=0, as gdalwarp -dstnodata 0 writes it) was read
    by Pillow as ordinary pixels: the pyramid drew the collar opaque black over the terrain. Its GDAL mask (rasterio's
    dataset_mask: nodata, a mask band) becomes the pyramid's alpha, so the collar is transparent; a GeoTIFF without
    nodata keeps its 3 channels."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    rgb = np.random.default_rng(3).integers(1, 256, (3, 6, 8), dtype=np.uint8)
    rgb[:, :, :3] = 0  # the collar: every band 0
    grey = rgb[:1].copy()
    profile = {"driver": "GTiff", "height": 6, "width": 8, "dtype": "uint8", "crs": "EPSG:32611",
               "transform": Affine(30.0, 0.0, 376000.0, 0.0, -30.0, 3808000.0)}
    for name, bands, nodata in (("rgb.tif", rgb, 0), ("grey.tif", grey, 0), ("plain.tif", rgb, None)):
        with rasterio.open(tmp_path / name, "w", count=len(bands), nodata=nodata, **profile) as dataset:
            dataset.write(bands)
        with ImagePyramid.build(tmp_path / name, device="cpu") as pyramid:
            level = np.asarray(pyramid.levels[0])
            colour = np.repeat(bands, 3, axis=0) if len(bands) == 1 else bands
            np.testing.assert_array_equal(level[..., :3], np.moveaxis(colour, 0, 2))
            if nodata is None:
                assert level.shape[2] == 3
                continue
            assert level.shape[2] == 4, name
            np.testing.assert_array_equal(level[..., 3], np.where(np.arange(8) < 3, 0, 255)[None, :].repeat(6, 0))
            assert (np.asarray(pyramid.levels[1])[..., 3] > 0).any()


def test_pyramid_of_a_16_bit_rgb_geotiff_is_read_by_its_range(tmp_path):
    """A 16-bit 3-band GeoTIFF (satellite imagery: Landsat, Sentinel-2 composites, written as bands rather than
    photometric RGB) is one Pillow cannot identify: the pyramid called the file unreadable ("cannot identify image
    file"). It is read with rasterio and scaled by its full
    range to 8 bits (value / 257, as a 16-bit greyscale file is); a float one is refused by name."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    data = np.random.default_rng(4).integers(0, 65536, (3, 6, 8)).astype(np.uint16)
    data[:, 0, 0] = (0, 65535, 257 * 100 + 128)  # 100.498 rounds to 100
    profile = {"driver": "GTiff", "height": 6, "width": 8, "crs": "EPSG:32611",
               "transform": Affine(30.0, 0.0, 376000.0, 0.0, -30.0, 3808000.0)}
    with rasterio.open(tmp_path / "rgb16.tif", "w", count=3, dtype="uint16", **profile) as out:  # bands, not RGB
        out.write(data)
    with ImagePyramid.build(tmp_path / "rgb16.tif", device="cpu") as pyramid:
        level = np.asarray(pyramid.levels[0])
        np.testing.assert_array_equal(level, np.moveaxis(np.round(data / 257.0).astype(np.uint8), 0, 2))
        assert level[0, 0].tolist() == [0, 255, 100]
        assert pyramid.crs == "EPSG:32611" and pyramid.extent == (376000.0, 376240.0, 3807820.0, 3808000.0)
    with rasterio.open(tmp_path / "rgbf.tif", "w", count=3, dtype="float32", **profile) as out:
        out.write(data.astype(np.float32) / 65535.0)
    with pytest.raises(InvalidInputError, match=r"image .*rgbf\.tif' must be an 8-bit or 16-bit image of 1-4 "
                                                r"bands; got 3 bands of float32$"):
        ImagePyramid.build(tmp_path / "rgbf.tif", device="cpu")
    import stepterrain as st
    from stepterrain.errors import OutputTooLargeError

    previous = st.set_memory_budget(100)  # the 3 x 6 x 8 bands' 576 bytes (as float32) are over it: refused, not read
    try:
        with pytest.raises(OutputTooLargeError, match=r"rgb16\.tif' \(the image: 3 x 6 x 8 cells of uint16\)"):
            ImagePyramid.build(tmp_path / "rgb16.tif", device="cpu")
    finally:
        st.set_memory_budget(previous)


def test_pyramid_of_an_exif_rotated_photo_warns_that_it_is_drawn_as_stored(tmp_path):
    """A phone's JPEG stores its pixels landscape with an EXIF orientation tag (6: turn 90° clockwise to view): every
    viewer shows it turned, the pyramid took the stored pixels (as GDAL and QGIS read a JPEG), so an extent given for
    the picture as seen drew it turned and stretched without a word. It is still drawn as stored, with a warning that
    says so and how to turn it (PIL.ImageOps.exif_transpose)."""
    import warnings

    from PIL import Image

    stored = np.zeros((4, 6, 3), np.uint8)
    stored[0, 0] = (255, 0, 0)
    for orientation in (6, 1):
        exif = Image.Exif()
        exif[0x0112] = orientation
        Image.fromarray(stored).save(tmp_path / f"photo{orientation}.png", exif=exif)
    with pytest.warns(UserWarning, match=r"photo6\.png' has EXIF orientation 6 \(rotated 90° clockwise to view\): "
                                         r"it is drawn as stored, 6 x 4 pixels, .*ImageOps\.exif_transpose"):
        pyramid = ImagePyramid.build(tmp_path / "photo6.png", device="cpu")
    with pyramid:
        np.testing.assert_array_equal(pyramid.levels[0], stored)
        assert pyramid.extent == (0.0, 6.0, 0.0, 4.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ImagePyramid.build(tmp_path / "photo1.png", device="cpu").close()


def test_pyramid_of_a_four_band_16_bit_geotiff_takes_alpha_only_from_an_alpha_band(tmp_path):
    """A 4-band 16-bit RGB + near-infrared GeoTIFF (NAIP, PlanetScope) read through rasterio took the NIR band for
    alpha: vegetation opaque, water transparent. Only a band whose colour interpretation is alpha (GDAL's ALPHA=YES,
    which marks the first extra band) is alpha; a fourth band that is not is left out (as Pillow reads an extra
    sample)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    data = np.random.default_rng(6).integers(0, 65536, (4, 5, 7)).astype(np.uint16)
    profile = {"driver": "GTiff", "height": 5, "width": 7, "count": 4, "dtype": "uint16",
               "transform": Affine(30.0, 0.0, 376000.0, 0.0, -30.0, 3808000.0)}
    scaled = np.moveaxis(np.round(data / 257.0).astype(np.uint8), 0, 2)
    for name, options, expected in (("rgbn.tif", {}, scaled[..., :3]),
                                    ("alpha.tif", {"alpha": "YES"}, scaled[..., [0, 2, 3, 1]])):
        with rasterio.open(tmp_path / name, "w", **profile, **options) as out:
            out.write(data)
        with ImagePyramid.build(tmp_path / name, device="cpu") as pyramid:
            np.testing.assert_array_equal(pyramid.levels[0], expected)


def test_texture_tree_takes_an_image_in_the_horizontal_crs_of_a_compound_crs_dem(tmp_path):
    """A DEM whose GeoTIFF carries a compound CRS (WGS 84 / UTM 11N + NAVD88 height) and an orthophoto in EPSG:32611
    lie in the same horizontal coordinates: the CRS check compared the whole CRSs and refused the pair (with the
    compound CRS's whole WKT in the message). The horizontal parts are compared, and named by their EPSG codes."""
    rasterio = pytest.importorskip("rasterio")
    import warnings

    from rasterio.crs import CRS
    from rasterio.transform import Affine

    import stepterrain as st

    heights = np.random.default_rng(7).random((1, 32, 32)).astype(np.float32) * 100
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", height=32, width=32, count=1, dtype="float32",
                       crs=CRS.from_user_input("EPSG:32611+5703"),
                       transform=Affine(30.0, 0.0, 380000.0, 0.0, -30.0, 3800000.0)) as out:
        out.write(heights)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        terrain = st.load_dem(tmp_path / "dem.tif")
    assert terrain.crs == "EPSG:32611+5703"  # the compound CRS kept, named by its two EPSG codes (was its WKT)
    for name, crs in (("utm.tif", "EPSG:32611"), ("utm12.tif", "EPSG:32612")):
        with rasterio.open(tmp_path / name, "w", driver="GTiff", height=16, width=16, count=3, dtype="uint8", crs=crs,
                           transform=Affine(60.0, 0.0, 380000.0, 0.0, -60.0, 3800000.0), photometric="RGB") as out:
            out.write(np.full((3, 16, 16), 90, np.uint8))
        with ImagePyramid.build(tmp_path / name, device="cpu") as pyramid:
            if crs == "EPSG:32611":
                assert TextureTree(pyramid, PatchQuadtree(terrain, leaf_size=8)).root.level == 0
            else:
                with pytest.raises(InvalidInputError, match=r"^the image is in CRS 'EPSG:32612' but the terrain is in "
                                                            r"'EPSG:32611' \(mismatched CRS"):
                    TextureTree(pyramid, PatchQuadtree(terrain, leaf_size=8))


def test_texture_tree_takes_the_geotiff_of_a_texture_of_a_dem_in_degrees(tmp_path):
    """The round trip the docs describe: a texture of the Front Range DEM (degrees read as local metres) saved as a
    GeoTIFF on its grid and CRS, then a pyramid of that file over the same DEM: the CRS check must take it (the file's
    CRS is the DEM's equirectangular one, written back as WKT), at full resolution over the whole DEM."""
    pytest.importorskip("rasterio")
    import stepterrain as st
    from stepterrain.texture import topographic_layer

    from .reference_texture import find_shared

    dem = st.load_dem(find_shared("front_range_srtmgl3_3arcsec.tif"))
    layer = topographic_layer(dem, shadows=False, device="cpu")
    st.export.save_image(layer.to_uint8(), tmp_path / "shade.tif", extent=layer.extent, crs=dem.crs)
    with ImagePyramid.build(tmp_path / "shade.tif", device="cpu") as pyramid:
        assert pyramid.crs is not None and pyramid.extent == pytest.approx(layer.extent)
        tree = TextureTree(pyramid, PatchQuadtree(dem, leaf_size=256), max_texture_size=1024)
        assert tree.root.level == 0 and tree.root.window == (0, 758, 0, 758)


def test_image_layer_reads_the_pyramid_level_of_the_terrain_resolution_over_the_terrain_only():
    """image_layer: an image four times finer than the terrain's nodes comes from its pyramid's level 2 (pixels of
    the node spacing), only the window over the terrain and one pixel beyond it where the image reaches past it (its
    south edge here, for the bilinear sampling of the texels there), placed by ``extent``; an
    image without georeferencing and no extent is refused, as it would lie in pixel units anywhere."""
    from stepterrain.terrain import Terrain
    from stepterrain.texture import terrain_extent
    from stepterrain.texture_lod import image_layer

    terrain = Terrain.from_heights(np.zeros((20, 30), np.float32), spacing=(4.0, -4.0), origin=(1000.0, 2000.0))
    xmin, xmax, ymin, ymax = terrain_extent(terrain)
    pixels = np.random.default_rng(7).integers(0, 256, (144, 120, 3), dtype=np.uint8)
    extent = (xmin, xmax, ymin - 16 * 4.0, ymax)  # 16 nodes' worth more image south of the terrain (at 1 m pixels)
    layer = image_layer(pixels, terrain, extent=extent, device="cpu")
    with ImagePyramid.build(pixels, extent=extent, device="cpu") as pyramid:
        level2 = np.asarray(pyramid.levels[2])
    assert layer.kind == "thematic" and layer.shape == (21, 30)
    assert layer.extent == pytest.approx((xmin, xmax, ymin - 4.0, ymax)) and np.array_equal(layer.image, level2[:21])
    with pytest.raises(InvalidInputError, match="carries no georeferencing .*pass extent="):
        image_layer(pixels, terrain, device="cpu")


def test_image_layer_texel_size_reads_the_finer_level_asked_for():
    """image_layer(texel_size=...): the same 1 m image over a terrain of 4 m nodes comes from the level no coarser
    than the texel size asked for (2 m: level 1, 1 m: the image itself), over the terrain only; a texel size that is
    not a positive finite number is refused by name."""
    from stepterrain.terrain import Terrain
    from stepterrain.texture import terrain_extent
    from stepterrain.texture_lod import image_layer

    terrain = Terrain.from_heights(np.zeros((20, 30), np.float32), spacing=(4.0, -4.0), origin=(1000.0, 2000.0))
    xmin, xmax, ymin, ymax = terrain_extent(terrain)
    pixels = np.random.default_rng(7).integers(0, 256, (144, 120, 3), dtype=np.uint8)
    extent = (xmin, xmax, ymin - 16 * 4.0, ymax)
    with ImagePyramid.build(pixels, extent=extent, device="cpu") as pyramid:
        level1 = np.asarray(pyramid.levels[1])
    for texel, expected in ((2.0, level1[:41]), (1.0, pixels[:81]), (1.5, pixels[:81])):  # a pixel more south
        layer = image_layer(pixels, terrain, extent=extent, device="cpu", texel_size=texel)
        south = ymin - 80.0 / (len(expected) - 1)  # one pixel of the level below the terrain's 80 m
        assert layer.extent == pytest.approx((xmin, xmax, south, ymax)) and np.array_equal(layer.image, expected)
    for bad in (0, -1.0, float("nan"), "x"):
        with pytest.raises(InvalidInputError, match="texel_size must be"):
            image_layer(pixels, terrain, extent=extent, device="cpu", texel_size=bad)


def _blue_marble_tif(path, crs, transform, rows=slice(700, 764), cols=slice(1500, 1596)):
    """A GeoTIFF of an RGB crop of the Blue Marble (no pixel of it black: (0, 0, 0) can only be a warp's fill) with
    ``crs`` and ``transform``; its pixels."""
    import rasterio
    from PIL import Image

    from .reference_texture import find_shared

    with Image.open(find_shared("earth_day_bluemarble_3840x1920.tif")) as picture:
        pixels = np.asarray(picture.convert("RGB"))[rows, cols]
    assert pixels.max(axis=2).min() > 0
    with rasterio.open(path, "w", driver="GTiff", width=pixels.shape[1], height=pixels.shape[0], count=3,
                       dtype="uint8", crs=crs, transform=transform, photometric="RGB") as out:
        out.write(np.moveaxis(pixels, 2, 0))
    return pixels


def _run_hint(command, source, target, folder):
    """Run the gdalwarp ``command`` of a message (its ``...`` dropped) on ``source``, writing ``target``."""
    import shlex
    import shutil

    if shutil.which("gdalwarp") is None:
        pytest.skip("gdalwarp (gdal-bin) is not installed")
    words = [w for w in shlex.split(command) if w != "..."]
    subprocess.run([*words, "-q", str(source), str(target)], cwd=folder, check=True, capture_output=True)


def _assert_no_black_fill(level, source):
    """The warped ``level``: where the source had no data it is transparent (alpha 0), not opaque black, and what
    is opaque holds the source's colours."""
    assert level.shape[2] == 4, "no alpha: the area outside the source is opaque"
    opaque = level[..., 3] == 255
    assert (level[..., 3] == 0).any() and opaque.any()
    assert not (level[opaque][:, :3] == 0).all(axis=1).any(), "opaque black fill where the source had no data"
    assert set(map(tuple, level[opaque][:, :3])) <= set(map(tuple, source.reshape(-1, 3)))  # nearest: its pixels


def test_the_gdalwarp_a_rotated_image_is_refused_with_leaves_it_transparent_outside_not_black(tmp_path):
    """An image with a rotated geotransform is refused with the gdalwarp that makes it north-up. Run as said,
    `gdalwarp`, the corners of the north-up grid outside the rotated image were filled with opaque black (the
    image has no nodata), draped as a black frame round the orthophoto. It says -dstalpha now: the pyramid reads
    that alpha band, and the corners are transparent (the layers under them show)."""
    pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    turn = math.radians(30.0)
    pixels = _blue_marble_tif(tmp_path / "rotated.tif", "EPSG:32611", Affine(
        30.0 * math.cos(turn), 30.0 * math.sin(turn), 400000.0, 30.0 * math.sin(turn), -30.0 * math.cos(turn),
        3800000.0))
    with pytest.raises(InvalidInputError, match="rotated geotransform") as refused:
        ImagePyramid.build(tmp_path / "rotated.tif", device="cpu")
    command = re.search(r"`(gdalwarp[^`]*)` makes the image north-up", str(refused.value)).group(1)
    _run_hint(command, "rotated.tif", "north_up.tif", tmp_path)
    with ImagePyramid.build(tmp_path / "north_up.tif", device="cpu") as pyramid:
        _assert_no_black_fill(np.asarray(pyramid.levels[0]), pixels)


def test_the_gdalwarp_an_image_in_another_crs_is_refused_with_leaves_it_transparent_outside_not_black(tmp_path):
    """An image in another CRS than the terrain's is refused with the gdalwarp that reprojects it. Run as said,
    `gdalwarp -t_srs 'EPSG:32611'`, the corners of the grid in EPSG:32611 outside the image (from the west of zone
    12, turned some 5 degrees) were filled with opaque black, a black frame draped on the terrain. It says -dstalpha
    now: those corners read transparent."""
    pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    import stepterrain as st

    from .reference_texture import find_shared

    tujunga = st.load_dem(find_shared("big_tujunga_srtm_30m_utm11n.tif"))
    pixels = _blue_marble_tif(tmp_path / "east.tif", "EPSG:32612", Affine(30.0, 0.0, 200000.0, 0.0, -30.0, 3800000.0))
    with ImagePyramid.build(tmp_path / "east.tif", device="cpu") as pyramid:
        with pytest.raises(InvalidInputError, match="mismatched CRS") as refused:
            TextureTree(pyramid, PatchQuadtree(tujunga))
    command = re.search(r"\(`(gdalwarp[^`]*)`\)", str(refused.value)).group(1)
    _run_hint(command, "east.tif", "zone_11.tif", tmp_path)
    with ImagePyramid.build(tmp_path / "zone_11.tif", device="cpu") as pyramid:
        assert "32611" in pyramid.crs or "zone 11N" in pyramid.crs, pyramid.crs
        _assert_no_black_fill(np.asarray(pyramid.levels[0]), pixels)
