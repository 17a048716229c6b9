"""Bugs found by a bug hunt over the texture code (``stepterrain texture``, stepterrain.texture, texture_lod)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st_

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


def test_lod_sizes_take_numpy_integers():
    """max_texture_size, leaf_size, a cache's budget and workers, and band_bytes refused a NumPy integer
    (``2 ** np.arange(...)``, a size read from an array's shape arithmetic) as "must be a positive int; got
    np.int64(64)", while the pyramid's level, a lens' resolution and the occlusion's directions take one. Taken as the
    int they are, with the results of the Python ints; a bool and a non-integer are still refused by name."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.texture_lod import ImagePyramid, PatchQuadtree, TextureCache, TextureTree

    heights = np.random.default_rng(1).random((33, 41)) * 50
    image = np.random.default_rng(2).integers(0, 256, (64, 80, 3), dtype=np.uint8)
    trees = []
    for cast in (int, np.int64, np.int32):
        quadtree = PatchQuadtree(heights, leaf_size=cast(8))
        with ImagePyramid.build(image, extent=quadtree.root.domain, band_bytes=cast(4096), device="cpu") as pyramid:
            tree = TextureTree(pyramid, quadtree, max_texture_size=cast(16))
            trees.append([(p.level, p.window) for p in tree.patches()])
            assert all(type(v) is int for p in tree.patches() for v in p.window)
            assert type(tree.max_texture_size) is int and type(quadtree.depth) is int
        cache = TextureCache(budget=cast(1 << 20), workers=cast(2))
        assert type(cache.budget) is int
        cache.close()
    assert trees[0] == trees[1] == trees[2]
    for bad in (True, 8.0, np.float64(8.0), "8"):
        with pytest.raises(InvalidInputError, match="leaf_size"):
            PatchQuadtree(heights, leaf_size=bad)
        with pytest.raises(InvalidInputError, match="budget"):
            TextureCache(budget=bad)
    with ImagePyramid.build(image, device="cpu") as pyramid, pytest.raises(InvalidInputError, match="max_texture_size"):
        TextureTree(pyramid, PatchQuadtree(heights), max_texture_size=np.bool_(True))


@pytest.mark.parametrize("center, radius", [((1e300, 0.0), 1.0), ((0.0, 1e17), 1.0), ((1e16, 5.0), 1.0),
                                            ((0.0, 0.0), 1.7e308)])
@pytest.mark.parametrize("make", ["thematic_lens", "highlight_lens"])
def test_lens_too_small_for_its_centre_is_refused_naming_radius_and_center(center, radius, make):
    """A lens whose radius float64 cannot resolve at its centre was refused as "extent must be finite (xmin, xmax,
    ...)", an argument the caller never gave, or (1e16: the extent rounded to 4 units wide) made as a lens of twice
    the radius, silently; a radius beyond float64 likewise (an infinite extent). Now refused naming radius and
    center; one float64 resolves is made with its exact size."""
    from stepterrain import texture
    from stepterrain.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match=r"radius must be large enough .* center"):
        getattr(texture, make)(center, radius)
    lens = getattr(texture, make)((1e7, 4e6), 2.0, resolution=16)
    xmin, xmax, ymin, ymax = lens.extent
    assert abs((xmax - xmin) - 2 * (2.0 + 4.0 / 14)) < 1e-8 and abs((ymax - ymin) - (xmax - xmin)) < 1e-8


@pytest.mark.parametrize("last_row", [(0.0, 0.0, 2.0), (0.01, 0.0, 1.0), (0.0, -1e-9, 1.0)])
def test_a_texture_matrix_that_is_not_affine_is_refused(last_row):
    """The layer operations, texture_uv and the coverage test read a texel's (column, row) as the matrix's first
    two rows and never divide by the third: 2 * M (the same map in homogeneous coordinates) sampled the image twice
    as far out (weighted_add of it with weight 1 over black was off by up to 0.9), and a perspective last row was
    dropped, both without a word. Refused, naming matrix; the layer's own affine matrix is taken as before."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.texture import TextureLayer, weighted_add

    image = np.random.default_rng(0).random((4, 6))
    extent = (0.0, 6.0, 0.0, 4.0)
    own = TextureLayer("luminance", image, extent)
    matrix = own.matrix.copy()
    matrix[2] = last_row
    with pytest.raises(InvalidInputError, match=r"matrix must be an affine texture matrix, its last row \(0, 0, 1\)"):
        TextureLayer("luminance", image, extent, matrix=matrix)
    same = TextureLayer("luminance", image, extent, matrix=own.matrix.copy())
    black = TextureLayer("thematic", np.zeros((4, 6, 3)), extent)
    out = weighted_add([black, same], [1.0, 1.0], device="cpu").rgba()[..., 0]
    np.testing.assert_allclose(out, image, atol=1e-6)


@pytest.mark.parametrize("colour", [(True, 0, 0), ("1", "0", "0"), [(0.2, 0.2, 0.2), (1, np.True_, 0)],
                                    np.ma.masked_array([1.0, 0.0, 0.0], mask=[True, False, False])])
@pytest.mark.parametrize("option", ["shadow_color", "highlight_color", "accent_color"])
def test_maplibre_colours_of_text_bools_or_masked_components_are_refused(option, colour):
    """hillshade's MapLibre colours went through np.asarray(row, dtype=float64): (True, 0, 0) and ("1", "0", "0")
    were read as red and a masked component as the value under its mask, where every other colour of the library
    (a layer's background, contour_layer's color) refuses them. Refused, naming the option."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.texture import hillshade

    heights = np.random.default_rng(0).random((4, 5)) * 10
    if option == "accent_color" and isinstance(colour, list):  # one colour only: its bad one
        colour = colour[1]
    many = isinstance(colour, list)
    method = "maplibre-multidirectional" if many else "maplibre-standard"
    extra = {"azimuth": [1.0, 2.0]} if many else {}
    with pytest.raises(InvalidInputError, match=option):
        hillshade(heights, method=method, device="cpu", **{option: colour}, **extra)
    ok = hillshade(heights, method=method, device="cpu", **{option: (1.0, 0.0, 0.0)}, **extra)
    assert np.isfinite(ok).all()


@pytest.mark.parametrize("interval", [None, "1"])
def test_cli_texture_empty_mesh_is_warned_about(tmp_path, capsys, interval):
    """A DEM with no triangle of three finite heights (one finite node) made an empty --mesh, written without a word
    (a progress line "0 faces" only, nothing with -q), where steps warns "the mesh is empty". Warned the same way;
    the texture and the mesh are still written, as steps writes its empty mesh."""
    heights = np.full((6, 7), np.nan)
    heights[2, 3] = 5.0
    dem, out, mesh = tmp_path / "dem.npy", tmp_path / "t.tif", tmp_path / "t.glb"
    np.save(dem, heights)
    code = main(["texture", str(dem), "-q", "-o", str(out), "--mesh", str(mesh), "--device", "cpu"]
                + (["--interval", interval] if interval else []))
    err = capsys.readouterr().err
    assert code == 0 and "warning: the mesh is empty: no triangle of the input has three finite heights" in err, err
    assert out.exists() and mesh.exists()
    full = np.random.default_rng(0).random((6, 7)) * 10
    np.save(dem, full)
    assert main(["texture", str(dem), "-q", "--mesh", str(mesh), "--device", "cpu"]) == 0
    assert "empty" not in capsys.readouterr().err


def _world_value(layer, x, y):
    """The layer's RGBA at world (x, y), nearest texel through its texture matrix (None outside its image)."""
    u, v, _ = layer.matrix @ [x, y, 1.0]
    r, c = int(round(v)), int(round(u))
    rows, cols = layer.shape
    return layer.rgba()[r, c] if 0 <= r < rows and 0 <= c < cols else None


@pytest.mark.parametrize("offset", [(5.0, -3.0), (100.0, 0.0), (-40.0, 250.0)])
def test_operations_on_a_moved_first_layer_keep_its_texels_where_they_moved(offset):
    """A moved layer (a lens following a point, TextureLayer.moved: only its texture matrix changes) as the first
    layer of blend, weighted_add, modulate or a TextureAnimation key was resampled onto its unmoved extent: the result
    kept the part of it still over that extent, so a lens moved by more than its radius came out as its rim alone
    (a highlight lens' frame had no hot spot: 1 - strength everywhere), and blend with weights given as an array
    (placed by the layer's matrix) was refused as covering none of the extent. The result now lies on the moved
    layer's own texels (as adjust's does), its values those of the operation at the same world points."""
    from stepterrain.texture import TextureAnimation, blend, highlight_lens, modulate, thematic_lens, weighted_add

    dx, dy = offset
    weak, strong = (highlight_lens((0.0, 0.0), 10.0, strength=s, resolution=32) for s in (0.2, 0.8))
    keys = [weak.moved(dx, dy), strong.moved(dx, dy)]
    frame = TextureAnimation(keys, (0.0, 1.0)).frame(0.5, device="cpu")
    centre = _world_value(frame, dx, dy)
    assert centre is not None and np.allclose(centre, (1.0, 1.0, 1.0, 1.0), atol=1e-6), centre  # the hot spot
    rim = _world_value(frame, dx + 10.5, dy)
    assert rim is not None and np.allclose(rim[:3], 0.5, atol=1e-6)  # (0.8 + 0.2) / 2 beyond the radius
    moved = weak.moved(dx, dy)
    half = np.full(moved.shape, 0.5, np.float32)
    results = {"modulate": modulate(moved, half, device="cpu"),
               "weighted_add": weighted_add([moved], [0.5], device="cpu"),
               "blend": blend(moved, np.zeros((*moved.shape, 3)), half, device="cpu")}
    for name, out in results.items():
        got = _world_value(out, dx, dy)
        assert got is not None and np.allclose(got[:3], 0.5, atol=1e-6), (name, got)
    lens = thematic_lens((0.0, 0.0), 10.0, resolution=32).moved(dx, dy)
    out = weighted_add([lens], [1.0], device="cpu")
    assert np.allclose(_world_value(out, dx, dy), (1.0, 1.0, 1.0, 1.0), atol=1e-6)
    assert out.shape == lens.shape


def test_a_closed_texture_cache_refuses_requests_by_name():
    """TextureCache.close() shut its thread pool down; a later request (by render_with_textures, load_now) raised
    concurrent.futures' RuntimeError "cannot schedule new futures after shutdown". Refused as an InvalidInputError
    naming the closed cache; the patches it loaded before are still handed out."""
    from stepterrain import Camera
    from stepterrain.errors import InvalidInputError
    from stepterrain.texture_lod import ImagePyramid, PatchQuadtree, TextureCache, TextureTree, render_with_textures

    quadtree = PatchQuadtree(np.zeros((17, 17)), leaf_size=8)
    with ImagePyramid.build(np.full((32, 32, 3), 90, np.uint8), extent=quadtree.root.domain, device="cpu") as pyramid:
        tree = TextureTree(pyramid, quadtree, max_texture_size=16)
        cache = TextureCache()
        root = cache.load_now(tree.root)
        cache.close()
        camera = Camera((8, -30, 20), (8, 8, 0))
        with pytest.raises(InvalidInputError, match="the TextureCache is closed"):
            render_with_textures(quadtree.root, [tree.root], camera, cache=cache)
        with pytest.raises(InvalidInputError, match="the TextureCache is closed"):
            cache.load_now(next(p for p in tree.patches() if p is not tree.root))
        assert cache.load_now(tree.root) is root and cache.is_loaded(tree.root)
        cache.close()  # twice: nothing more


def test_is_georeferenced_refuses_what_is_no_image_file(tmp_path):
    """is_georeferenced answered False for a missing file or a folder (a mistyped name read as "not georeferenced",
    so a caller went on to pass an extent for it) and raised Path()'s TypeError for a number. Now a DataFileError
    naming the path, as ImagePyramid.build refuses them, and an InvalidInputError; a real image is answered."""
    from PIL import Image

    from stepterrain.errors import DataFileError, InvalidInputError
    from stepterrain.texture_lod import is_georeferenced

    with pytest.raises(DataFileError, match="does not exist"):
        is_georeferenced(tmp_path / "ortho.tif")
    with pytest.raises(DataFileError, match="is a folder"):
        is_georeferenced(tmp_path)
    with pytest.raises(InvalidInputError, match="image must be the path of an image file"):
        is_georeferenced(5)
    plain = tmp_path / "plain.png"
    Image.fromarray(np.zeros((4, 5, 3), np.uint8)).save(plain)
    assert is_georeferenced(plain) is False
    (tmp_path / "plain.pgw").write_text("10\n0\n0\n-10\n1000\n2000\n")
    assert is_georeferenced(str(plain)) is True


@pytest.mark.parametrize("base, index_every", [(1e12, 5), (1e17, 5), (-1e20, 5), (1e20, 0), (2.5e15 + 50.0, 0)])
def test_contour_base_far_from_the_heights_draws_the_same_lines(base, index_every):
    """contour_layer's lines base + k * interval went wrong for a base far from the heights: the kernel's
    (h - base) / interval in float64 lost the heights' fraction of the interval (base 1e17 over 100 m lines drew
    lines off their levels, 1e20 made every texel a line; at 1e12 the index lines changed). A base a whole number of
    periods (interval, times index_every with index lines) away draws the same lines."""
    import math

    from stepterrain import sample_dem
    from stepterrain.texture import contour_layer

    dem = sample_dem()
    period = 100.0 * index_every if index_every else 100.0
    near = math.fmod(base, period)  # exact: the same levels and index lines
    want = contour_layer(dem, interval=100.0, base=near, index_every=index_every, device="cpu").image
    got = contour_layer(dem, interval=100.0, base=base, index_every=index_every, device="cpu").image
    assert 0.05 < want[..., 3].mean() < 0.5
    np.testing.assert_allclose(got, want, atol=1e-5)


@pytest.mark.parametrize("options", [[], ["--shadows", "--occlusion", "0.5"], ["--contours", "20"]])
def test_cli_texture_over_the_memory_budget_is_refused_before_the_shading(tmp_path, capsys, monkeypatch, options):
    """A texture of one texel per DEM node whose layers' RGBA (22 bytes a node while it is checked) exceeds
    --memory-budget, the DEM itself within it, was refused only once its hillshade, shadows and occlusion were computed
    (minutes on a large DEM: the topographic layer's RGBA is checked as the texture is composed), as --texel-size's
    texture is not: now once the DEM is loaded, before any work. A budget that holds it still writes the texture."""
    from stepterrain import texture as tx

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((40, 50)).astype(np.float32) * 100)  # 8,000 bytes; RGBA 44,000
    out = tmp_path / "t.png"
    shade = tx.topographic_layer

    def no_shading(*args, **kwargs):
        raise AssertionError("the texture was shaded before the memory budget was checked")

    monkeypatch.setattr(tx, "topographic_layer", no_shading)
    code = main(["texture", str(dem), *options, "-o", str(out), "--device", "cpu", "--memory-budget", "30000"])
    err = capsys.readouterr().err
    assert code == 2 and "50 x 40 texel texture" in err and "over the memory budget of 30,000 bytes" in err, err
    assert "--coarsen" in err and not out.exists()
    monkeypatch.setattr(tx, "topographic_layer", shade)
    # the RGBA, or the topographic layer's working memory where it is more (with --occlusion: 33 bytes a node)
    shading = tx._NODE_BYTES["topographic_layer"] + (tx._NODE_BYTES["occlusion"] if "--occlusion" in options else 0)
    assert main(["texture", str(dem), *options, "-o", str(out), "--device", "cpu", "-q", "--memory-budget",
                 str(max(tx._RGBA_BYTES, shading) * 40 * 50)]) == 0
    assert out.exists()


def test_a_texel_size_of_astronomically_many_texels_is_refused_in_a_readable_line(tmp_path, capsys):
    """--texel-size 1e-300 (and contour_layer's texel_size) was refused naming its texel counts digit by digit: a
    300-digit number each way, an error line of 950 characters. Counts past 10^12 are written in floating point."""
    from stepterrain import texture as tx
    from stepterrain.errors import OutputTooLargeError

    heights = np.random.default_rng(0).random((40, 50)).astype(np.float32) * 100
    dem = tmp_path / "dem.npy"
    np.save(dem, heights)
    assert main(["texture", str(dem), "--texel-size", "1e-300", "-o", str(tmp_path / "t.png"), "--device", "cpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "the 5e+301 x 4e+301 texel texture of --texel-size 1e-300" in err and len(err) < 400, err
    with pytest.raises(OutputTooLargeError, match=r"the 5e\+301 x 4e\+301 float32 RGBA contour layer") as info:
        tx.contour_layer(heights, interval=10.0, texel_size=1e-300, device="cpu")
    assert len(str(info.value)) < 400, info.value
    # counts a budget can hold keep their digits
    assert main(["texture", str(dem), "--texel-size", "0.001", "-o", str(tmp_path / "t.png"), "--device", "cpu"]) == 2
    assert "the 50000 x 40000 texel texture" in capsys.readouterr().err


@pytest.mark.parametrize("case", ["interval", "heightfield"])
def test_cli_texture_drape_that_cannot_be_made_is_refused_before_the_shading(tmp_path, capsys, monkeypatch, case):
    """--mesh on the stepped terrain of an --interval giving more levels than stepped takes, or on a heightfield mesh
    over --memory-budget (the DEM and its texture within it), was refused only in the drape stage, once the texture's
    hillshade, shadows and occlusion had been computed (minutes on a large DEM): now once the DEM is loaded, as steps
    refuses its --interval, with the same error."""
    from stepterrain import texture as tx

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((40, 50)).astype(np.float32) * 100)
    mesh = tmp_path / "m.glb"
    options = {"interval": ["--interval", "1e-5"], "heightfield": ["--memory-budget", "100000"]}[case]
    shade = tx.topographic_layer

    def no_shading(*args, **kwargs):
        raise AssertionError("the texture was shaded before its drape was checked")

    monkeypatch.setattr(tx, "topographic_layer", no_shading)
    code = main(["texture", str(dem), "--shadows", "--occlusion", "0.5", *options, "--mesh", str(mesh), "--device",
                 "cpu"])
    err = capsys.readouterr().err
    expected = {"interval": "levels; at most 1,000,000 are supported",
                "heightfield": "the heightfield mesh of a 40 x 50 grid would need"}[case]
    assert code == 2 and expected in err and "Traceback" not in err, err
    assert not mesh.exists()
    # what the checks let through is draped as before
    monkeypatch.setattr(tx, "topographic_layer", shade)
    fine = {"interval": ["--interval", "10"], "heightfield": ["--memory-budget", "400000"]}[case]
    assert main(["texture", str(dem), "--shadows", *fine, "--mesh", str(mesh), "--device", "cpu", "-q"]) == 0
    assert mesh.exists()


@pytest.mark.parametrize("suffix", [".glb", ".ply"])
@pytest.mark.parametrize("interval", [None, "10"])
def test_cli_texture_mesh_that_cannot_be_written_is_refused_before_the_shading(tmp_path, capsys, monkeypatch, suffix,
                                                                                interval):
    """A --mesh whose writing needs more than --memory-budget (GLB's textured vertices, 120 bytes each, and PLY's
    coloured ones: more than the heightfield mesh itself) was refused by save_mesh, after the texture was shaded and
    draped. The DEM's surface, which the draped mesh has at least (exactly, on the heightfield), is now checked
    against the writer's budget once the DEM is loaded; what fits is written as before."""
    from stepterrain import export
    from stepterrain import texture as tx

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((40, 50)).astype(np.float32) * 100)
    mesh = tmp_path / f"m{suffix}"
    per_vertex, per_face = export._WRITE_BYTES[suffix]
    per_vertex += export._TEXTURE_WRITE_BYTES.get(suffix, 0)
    need = per_vertex * 40 * 50 + per_face * 2 * 39 * 49  # the heightfield's vertices and faces
    budget = need - 1
    assert budget > 144 * 40 * 50  # terrain.mesh()'s own budget holds it
    shade = tx.topographic_layer

    def no_shading(*args, **kwargs):
        raise AssertionError("the texture was shaded before the --mesh's writing was checked")

    monkeypatch.setattr(tx, "topographic_layer", no_shading)
    options = [] if interval is None else ["--interval", interval]
    code = main(["texture", str(dem), "--shadows", *options, "--mesh", str(mesh), "--memory-budget", str(budget),
                 "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and f"writing '{mesh}' ({suffix}, a mesh of " in err and "3,822 faces" in err, err
    assert not mesh.exists()
    # what save_mesh writes within the budget is not refused early: a budget of exactly the draped mesh's own need
    # (the heightfield's, or the stepped mesh's, more than the DEM's surface) writes it
    monkeypatch.setattr(tx, "topographic_layer", shade)
    if interval is not None:
        import stepterrain as st

        stepped = st.stepped(np.load(dem), interval=float(interval), device="cpu")
        need = per_vertex * len(stepped.vertices) + per_face * len(stepped.faces)
    assert main(["texture", str(dem), "--shadows", *options, "--mesh", str(mesh), "--memory-budget", str(need),
                 "--device", "cpu", "-q"]) == 0
    assert mesh.exists()


@settings(max_examples=15, deadline=None)
@given(seed=st_.integers(0, 2**32 - 1), ties=st_.booleans(), holes=st_.floats(0.0, 0.5), flat=st_.booleans(),
       interval=st_.sampled_from([5.0, 10.0, 25.0, 200.0]))
def test_a_stepped_mesh_has_at_least_the_dems_surface(seed, ties, holes, flat, interval):
    """texture --mesh --interval (and steps --png) refuse before stepping by the DEM's surface (grid_surface_counts:
    a vertex per node a triangle with three finite heights uses, a face per such triangle), the fewest the stepped
    mesh has: a lower bound, which must never exceed the stepped mesh's counts, or a write that fits would be
    refused. Heights on the levels, flat patches and nodata holes included."""
    import stepterrain as st
    from stepterrain.terrain import grid_surface_counts

    rng = np.random.default_rng(seed)
    heights = (rng.random((12, 15)) * 100).astype(np.float32)
    if ties:  # many heights exactly on a level
        heights = np.round(heights / interval) * interval
    if flat:
        heights[2:10, 3:12] = 40.0
    heights[rng.random(heights.shape) < holes] = np.nan
    terrain = st.Terrain.from_heights(heights)
    mesh = st.stepped(terrain, interval=interval, device="cpu")
    vertices, faces = grid_surface_counts(terrain.heights, terrain.has_nodata)
    assert len(mesh.vertices) >= vertices and len(mesh.faces) >= faces
