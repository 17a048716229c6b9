"""``stepterrain texture`` in-process, and the examples examples/textures.py and examples/flood.py at tiny sizes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import trimesh

from stepterrain import render
from stepterrain.cli import main
from stepterrain.errors import InvalidInputError

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
AVAILABLE, REASON = render.offscreen_available()
needs_render = [pytest.mark.render, pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")]


def read_png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image)


@pytest.fixture
def small_dem(tmp_path) -> Path:
    i, j = np.meshgrid(np.arange(40), np.arange(50), indexing="ij")
    heights = (100 * np.exp(-((i - 20) ** 2 + (j - 25) ** 2) / 80.0)).astype(np.float32)
    path = tmp_path / "hill.npy"
    np.save(path, heights)
    return path


def test_cli_texture_png_and_glb(tmp_path, small_dem, capsys):
    out, mesh = tmp_path / "t.png", tmp_path / "t.glb"
    code = main(["texture", str(small_dem), "--hillshade", "combined", "--shadows", "--azimuth", "270",
                 "--altitude", "20", "-o", str(out),
                 "--mesh", str(mesh), "--normals", str(tmp_path / "n.png"), "--device", "cpu"])
    assert code == 0, capsys.readouterr().err
    image = read_png(out)
    assert image.shape == (40, 50, 3) and image.std() > 5
    assert read_png(tmp_path / "n.png").shape == (40, 50, 3)
    back = trimesh.load(mesh, force="mesh", process=False)
    assert isinstance(back.visual, trimesh.visual.TextureVisuals)
    assert len(back.faces) == 2 * 39 * 49


def test_cli_texture_obj_image_does_not_replace_the_normal_map(tmp_path, small_dem, capsys):
    """--mesh t.obj writes its texture as t_terrain_texture.png: named so, --normals was replaced by it without a
    word (the OBJ written after it). It was then refused once the texture and normal map were written; now before
    any work, naming both options, and nothing is written."""
    normals = tmp_path / "t_terrain_texture.png"
    code = main(["texture", str(small_dem), "-o", str(tmp_path / "t.png"), "--mesh", str(tmp_path / "t.obj"),
                 "--normals", str(normals), "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and "writes 't_terrain_texture.png' beside it (its texture image), which is what --normals " \
                         "names" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hill.npy"]


def test_cli_texture_azimuth_is_degrees_clockwise_from_north(tmp_path, capsys):
    # --azimuth 315 (the default, gdaldem's -az) lights from the north-west: a plane sloping down to the north-west
    # is bright, one sloping down to the south-east dark; --azimuth 135 swaps them
    i, j = np.meshgrid(np.arange(12), np.arange(12), indexing="ij")
    np.save(tmp_path / "nw.npy", (i + j).astype(np.float32))  # rows north-first: heights grow to the south-east
    np.save(tmp_path / "se.npy", -(i + j).astype(np.float32))
    grey = {}
    for plane in ("nw", "se"):
        for azimuth in ([], ["--azimuth", "315"], ["--azimuth", "135"]):
            out = tmp_path / f"{plane}{''.join(azimuth)}.png"
            code = main(["texture", str(tmp_path / f"{plane}.npy"), *azimuth, "--colormap", "none", "-o", str(out),
                         "--device", "cpu"])
            assert code == 0, capsys.readouterr().err
            grey[plane, "".join(azimuth[1:]) or "default"] = read_png(out)[1:-1, 1:-1].mean()
    assert grey["nw", "315"] == grey["nw", "default"] > 200 and grey["se", "315"] == grey["se", "default"] < 100
    assert grey["se", "135"] > 200 and grey["nw", "135"] < 100


def test_cli_texture_azimuth_past_a_turn_is_degrees_without_the_radians_warning(tmp_path, small_dem, capsys):
    # the CLI takes degrees: 1000 is 280 degrees, the same image, and no "azimuth is in radians" hint (that warning
    # is for API callers who pass degrees where radians are expected)
    images = []
    for azimuth in ("280", "1000", "-80"):
        out = tmp_path / f"a{azimuth}.png"
        assert main(["-q", "texture", str(small_dem), "--azimuth", azimuth, "-o", str(out), "--device", "cpu"]) == 0
        assert "radians" not in capsys.readouterr().err
        images.append(read_png(out))
    assert np.array_equal(images[0], images[1]) and np.array_equal(images[0], images[2])


def test_cli_texture_help_has_examples(capsys):
    assert main(["texture", "--help"]) == 0
    assert "examples:" in capsys.readouterr().out


@pytest.mark.parametrize("argv,match", [
    (["--altitude", "95"], "--altitude must lie in"),
    (["--hillshade", "basic"], "invalid choice"),
    (["--mesh", "x.xyz"], "unknown extension"),
    (["--interval", "10"], "--interval applies only with"),
    (["--colormap", "nope"], "--colormap must name"),
    (["--png", "{out}"], "--output and --png name the same file"),
    (["--normals", "{out}"], "--output and --normals name the same file"),
    # slopes are squared in float32: 1e30 gave a uniform grey image with exit 0
    (["--z-factor", "1e30"], "--z-factor x height range / spacing must stay below 1e+18 (float32 slopes)"),
])
def test_cli_texture_bad_input_exits_2(tmp_path, small_dem, capsys, argv, match):
    out = tmp_path / "t.png"
    assert main(["texture", str(small_dem), "-o", str(out), *[a.format(out=out) for a in argv]]) == 2
    assert match in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("dem, crs_kept", [("big_tujunga_srtm_30m_utm11n.tif", True),
                                           ("front_range_srtmgl3_3arcsec.tif", False)])
def test_cli_texture_geotiff_lies_over_the_real_dem(tmp_path, capsys, dem, crs_kept):
    """-o .tif: a GeoTIFF on the DEM's own pixel grid. A projected DEM keeps its CRS and geotransform exactly;
    a geographic one (read as local equirectangular metres) comes back onto the same degrees when a GIS
    reprojects it (the local CRS is linear in longitude and latitude)."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF output needs rasterio")
    from rasterio.warp import transform_bounds

    from .conftest import shared_file

    source = shared_file(dem)
    out, normals = tmp_path / "shade.tif", tmp_path / "normals.tiff"
    assert main(["texture", str(source), "--shadows", "-o", str(out), "--normals", str(normals)]) == 0, \
        capsys.readouterr().err
    with rasterio.open(source) as src, rasterio.open(out) as tex, rasterio.open(normals) as nrm:
        assert tex.shape == nrm.shape == src.shape and tex.count == nrm.count == 3
        assert tex.transform == nrm.transform and tex.crs == nrm.crs
        if crs_kept:
            assert tex.crs == src.crs and tex.transform.almost_equals(src.transform, precision=1e-6)
        else:
            back = transform_bounds(tex.crs, src.crs, *tex.bounds)
            assert back == pytest.approx(tuple(src.bounds), abs=1e-6)  # degrees: ~0.1 m
        assert tex.read().std() > 5


def test_cli_texture_geotiff_without_rasterio_is_refused_up_front(tmp_path, small_dem, capsys, monkeypatch):
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "rasterio" else
                        real_find_spec(name, *a))  # fmt: skip
    assert main(["texture", str(small_dem), "-o", str(tmp_path / "t.tif")]) == 2
    assert "writing a GeoTIFF needs rasterio: pip install 'stepterrain[geo]'" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [small_dem]


@pytest.mark.parametrize("interval", ["0", "-5", "nan"])
def test_cli_texture_interval_must_be_positive(tmp_path, small_dem, capsys, interval):
    out, mesh = tmp_path / "t.png", tmp_path / "m.glb"
    assert main(["texture", str(small_dem), "-o", str(out), "--mesh", str(mesh), f"--interval={interval}"]) == 2
    message = f"stepterrain texture: error: --interval must be a positive number; got {interval}\n"
    assert capsys.readouterr().err == message
    assert not out.exists() and not mesh.exists()


def test_cli_texture_missing_file(tmp_path, capsys):
    assert main(["texture", str(tmp_path / "missing.tif"), "-o", str(tmp_path / "t.png")]) == 2
    assert "missing.tif" in capsys.readouterr().err


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_texture_render_stepped(tmp_path, small_dem):
    png = tmp_path / "r.png"
    assert main(["-q", "texture", str(small_dem), "-o", str(tmp_path / "t.png"), "--interval", "20", "--png", str(png),
                 "--size", "160x120"]) == 0
    assert read_png(png).shape[:2] == (120, 160)


def _rendered(tmp_path: Path, name: str, *argv: str) -> np.ndarray:
    png = tmp_path / f"{name}.png"
    assert main(["-q", "texture", *argv, "--png", str(png), "--size", "160x120", "--z-scale", "0.2",
                 "--device", "cpu"]) == 0
    return read_png(png).astype(np.float64)


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_texture_png_lights_the_stepped_terrain_as_steps_does(tmp_path, small_dem, capsys):
    """``texture --interval --png`` rendered the draped stepped terrain unlit: the texture's hillshade shades the DEM's
    slopes, not the terraces and walls, so the steps showed only at the silhouette (a uniform-colour texture rendered
    as one flat colour). The render is lit now (--lighting auto) as ``steps --png`` lights its render, so terraces
    and walls take different brightnesses; ``--lighting off`` is the texture as it is, and the heightfield under a
    hillshade stays unlit by default (lit, it was shaded twice). The draped mesh is the same either way."""
    from PIL import Image

    grey = (150, 150, 150)
    image = tmp_path / "grey.png"
    Image.new("RGB", (16, 16), grey).save(image)
    # one uniform colour over the whole DEM (its nodes 0-39 by 0-49 at spacing 1, north up): no shading in the texture
    plain = ("--image", str(image), "--image-extent=-1,50,-40,1", "--hillshade", "none", "--colormap", "none",
             "--interval", "20", "--camera", "200,35")
    lit = _rendered(tmp_path, "lit", str(small_dem), *plain)
    unlit = _rendered(tmp_path, "unlit", str(small_dem), *plain, "--lighting", "off")
    terrain = np.abs(unlit - 255).max(axis=2) > 0  # the mesh's pixels (the background is white)
    assert terrain.mean() > 0.1
    assert np.abs(unlit[terrain] - grey).max() <= 1  # unlit: the texture's one colour, terraces unseen
    brightness = lit[terrain].mean(axis=1)
    assert brightness.std() > 10, brightness.std()  # lit: terraces and walls apart
    levels = np.unique(np.round(brightness / 8))
    assert len(levels) >= 3, levels  # several brightnesses (flat terraces, walls facing the light, walls turned away)
    assert np.array_equal(_rendered(tmp_path, "on", str(small_dem), *plain, "--lighting", "on"), lit)

    # the heightfield under the hillshade: unlit by default (the texture shades it), lit on request
    shaded = _rendered(tmp_path, "shaded", str(small_dem), "--camera", "200,35")
    assert np.array_equal(shaded, _rendered(tmp_path, "shaded_off", str(small_dem), "--camera", "200,35",
                                            "--lighting", "off"))
    assert not np.array_equal(shaded, _rendered(tmp_path, "shaded_on", str(small_dem), "--camera", "200,35",
                                                "--lighting", "on"))

    # --hillshade none without --image: hypsometric colours, no shading in them: lit by default
    colours = ("--hillshade", "none", "--camera", "200,35")
    assert np.array_equal(_rendered(tmp_path, "colours", str(small_dem), *colours),
                          _rendered(tmp_path, "colours_on", str(small_dem), *colours, "--lighting", "on"))

    # the draped mesh (and the texture) are the same bytes whatever lights the render
    files = {}
    for lighting in ("on", "off"):
        (tmp_path / lighting).mkdir()  # the same names: a GLB names its mesh after its file
        mesh, out = tmp_path / lighting / "m.glb", tmp_path / lighting / "t.png"
        assert main(["-q", "texture", str(small_dem), "--interval", "20", "-o", str(out), "--mesh", str(mesh), "--png",
                     str(tmp_path / f"r_{lighting}.png"), "--size", "64x48", "--lighting", lighting,
                     "--device", "cpu"]) == 0
        files[lighting] = (mesh.read_bytes(), out.read_bytes())
    assert files["on"] == files["off"]

    # a render option without --png, as --size and --camera are
    capsys.readouterr()
    assert main(["texture", str(small_dem), "-o", str(tmp_path / "t.png"), "--lighting", "on"]) == 2
    assert ("--lighting applies only with --png (the render of the draped mesh); got it without --png"
            in capsys.readouterr().err)


def load_example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_example_textures(tmp_path):
    example = load_example("textures")
    assert example.__doc__ and "draped" in example.__doc__
    out = tmp_path / "textures.png"
    assert example.main(["--size", "40", "--panel", "160", "120", "--output", str(out), "--device", "cpu"]) == 0
    from PIL import Image

    with Image.open(out) as picture:  # a 256-colour palette PNG (the example's --colors): its colours, not indices
        image = np.asarray(picture.convert("RGB"))
    assert image.shape[:2] == (120, 320)
    left, right = image[:, :160, :3].astype(int), image[:, 160:, :3].astype(int)
    assert left.std() > 5 and right.std() > 5


def test_example_flood(tmp_path):
    import imageio.v3 as iio

    example = load_example("flood")
    assert example.__doc__ and "rising water" in example.__doc__
    out = tmp_path / "flood.png"
    assert example.main(["--size", "32", "--frames", "4", "--keyframes", "3", "--output", str(out),
                         "--device", "cpu"]) == 0
    frames = iio.imread(out.with_suffix(".gif"), index=None)
    assert frames.shape[0] == 4 and frames.shape[1:3] == (32, 32)
    # the water rises: more blue-dominated pixels in the last frame than in the first
    blue = [(f[..., 2].astype(int) - f[..., 0].astype(int) > 60).sum() for f in frames]
    assert blue[-1] > blue[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flood.gif", "flood.png"]


def test_example_flood_mp4(tmp_path):
    pytest.importorskip("imageio_ffmpeg", reason="MP4 output needs imageio-ffmpeg (pip install 'stepterrain[video]')")
    import imageio.v3 as iio

    example = load_example("flood")
    out = tmp_path / "flood.png"
    assert example.main(["--size", "32", "--frames", "4", "--keyframes", "3", "--mp4", "--output", str(out),
                         "--device", "cpu"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flood.gif", "flood.mp4", "flood.png"]
    video = iio.imread(out.with_suffix(".mp4"), index=None, extension=".mp4")
    assert video.shape[0] == 4 and video.shape[1:3] == (32, 32)
    last = read_png(out)[..., :3].astype(float)
    # lossy H.264 (4:2:0 chroma) of the same frames: the last one has the PNG's colours and its pattern
    np.testing.assert_allclose(video[-1].reshape(-1, 3).mean(0), last.reshape(-1, 3).mean(0), atol=6)
    assert np.corrcoef(video[-1].astype(float).mean(-1).ravel(), last.mean(-1).ravel())[0, 1] > 0.8


def test_example_flood_mp4_without_ffmpeg_names_the_extra(tmp_path, monkeypatch):
    import sys

    from stepterrain.errors import MissingDependencyError

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import fails as if not installed
    example = load_example("flood")
    with pytest.raises(MissingDependencyError, match=r"stepterrain\[video\]"):
        example.main(["--size", "32", "--frames", "2", "--keyframes", "2", "--mp4",
                      "--output", str(tmp_path / "flood.png"), "--device", "cpu"])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("method", ["multidirectional", "igor"])
def test_cli_texture_of_a_method_that_ignores_an_angle_passes_only_the_angles_given(tmp_path, small_dem, method):
    """The command line resolved --azimuth and --altitude to 315 and 45 and passed them on: hillshade, which refuses an
    angle its method ignores, would refuse `--hillshade multidirectional` (or igor) given no angle at all. The
    texture is the library's default-light one."""
    from stepterrain import texture as tx
    from stepterrain.io import load_dem

    out = tmp_path / "t.png"
    assert main(["texture", str(small_dem), "--hillshade", method, "--colormap", "none", "-o", str(out),
                 "--device", "cpu"]) == 0
    layer = tx.topographic_layer(load_dem(small_dem), method=method, shadows=False, device="cpu")
    np.testing.assert_array_equal(read_png(out)[..., 0], layer.to_uint8(background=(1.0, 1.0, 1.0))[..., 0])


@pytest.mark.parametrize("method", ["standard", "multidirectional", "combined", "igor", "none"])
@pytest.mark.parametrize("shadows", [False, True])
def test_cli_texture_mesh_metadata_records_only_the_light_angles_that_shaped_it(tmp_path, small_dem, method, shadows):
    """A draped mesh's metadata recorded azimuth_deg 315 and altitude_deg 45 whatever the shading: --hillshade none
    (no light at all), multidirectional (four fixed lights: no azimuth) and igor (no altitude) said a light shaded the
    texture that none did. An angle is recorded where the library takes it, as the hillshade refuses one its method
    ignores; --shadows aims the shadows with both."""
    from stepterrain import texture as tx
    from stepterrain.export import read_mesh
    from stepterrain.io import load_dem

    terrain = load_dem(small_dem)
    used = set()
    for key, angle in (("azimuth_deg", "azimuth"), ("altitude_deg", "altitude")):
        try:
            tx.topographic_layer(terrain, method=method, shadows=shadows, device="cpu", **{angle: 0.5})
        except InvalidInputError as exc:
            assert "has no effect" in str(exc), exc
        else:
            used.add(key)
    mesh = tmp_path / "t.ply"
    assert main(["texture", str(small_dem), "--hillshade", method, *(["--shadows"] if shadows else []), "--mesh",
                 str(mesh), "--device", "cpu", "-q"]) == 0
    metadata = read_mesh(mesh).metadata
    assert {key for key in ("azimuth_deg", "altitude_deg") if key in metadata} == used
    assert metadata["method"] == method and metadata["shadows"] is shadows
    assert metadata.get("azimuth_deg", 315.0) == 315.0 and metadata.get("altitude_deg", 45.0) == 45.0


def test_cli_texture_mesh_metadata_records_every_option_that_shaped_the_texture(tmp_path, small_dem):
    """A draped mesh's metadata left out --z-factor, --shadow-strength, --occlusion, --colormap and --image-extent (a
    texture shaded by z 2, occlusion 0.3 in viridis recorded as the default one) and recorded --texel-size as given
    only, not the texel size of the grid the texture was cut into (whole texels no larger than it). Every option
    that shaped the texture is recorded with the value used, defaults included; ``texel_size`` stays the number given
    (scripts read it as one) and ``texel_size_used`` is the texture image's own (x, y) texel."""
    from PIL import Image

    from stepterrain.export import read_mesh

    png = tmp_path / "photo.png"
    Image.fromarray(np.full((8, 10, 3), 200, np.uint8)).save(png)
    mesh = tmp_path / "t.glb"
    assert main(["texture", str(small_dem), "--shadows", "--shadow-strength", "0.4", "--occlusion", "0.3",
                 "--z-factor", "2", "--colormap", "viridis", "--image", str(png), "--image-extent=-1,50,-40,1",
                 "--texel-size", "0.3", "--contours", "20", "--contour-width", "1.5", "--mesh", str(mesh),
                 "--device", "cpu", "-q"]) == 0
    draped = read_mesh(mesh)
    metadata = draped.metadata
    assert (metadata["z_factor"], metadata["shadow_strength"], metadata["occlusion"]) == (2.0, 0.4, 0.3)
    assert metadata["colormap"] == "viridis" and metadata["image_extent"] == [-1.0, 50.0, -40.0, 1.0]
    # the npy's unit spacing: a 50 x 40 texture extent (half a cell beyond the nodes), cut into 167 x 134 texels
    cols, rows = draped.visual.material.baseColorTexture.size
    assert (cols, rows) == (167, 134)
    np.testing.assert_allclose(metadata["texel_size_used"], [50.0 / cols, 40.0 / rows], rtol=1e-12)
    assert metadata["texel_size_used"][0] < 0.3 and metadata["texel_size_used"][1] < 0.3
    assert metadata["texel_size"] == 0.3  # the number given, as before (a script reading it as one keeps working)
    assert (metadata["contours"], metadata["contour_width"], metadata["contour_index"]) == (20.0, 1.5, 5)
    np.testing.assert_allclose(metadata["contour_color"], [0.55, 0.32, 0.14, 1.0])

    # the defaults, recorded as used; what shaped nothing is not recorded (no shadows: no strength; no relief used by
    # --hillshade none without --shadows or --occlusion: no z factor)
    plain = tmp_path / "plain.ply"
    assert main(["texture", str(small_dem), "--mesh", str(plain), "--device", "cpu", "-q"]) == 0
    metadata = read_mesh(plain).metadata
    assert (metadata["z_factor"], metadata["occlusion"], metadata["colormap"]) == (1.0, 0.0, "terrain")
    assert metadata["texel_size_used"] == [1.0, 1.0]  # one texel per node; no --texel-size given: none recorded
    assert not {"shadow_strength", "image_extent", "contours", "contour_width", "texel_size"} & set(metadata)
    assert main(["texture", str(small_dem), "--hillshade", "none", "--colormap", "None", "--image", str(png),
                 "--image-extent=-1,50,-40,1", "--mesh", str(plain), "--device", "cpu", "-q"]) == 0
    metadata = read_mesh(plain).metadata
    assert "z_factor" not in metadata and metadata["colormap"] == "none" and metadata["occlusion"] == 0.0

# ------------------------------------------------------------------------------------------ --image
TUJUNGA = "big_tujunga_srtm_30m_utm11n.tif"


def coded_pixels(rows: int, cols: int) -> np.ndarray:
    """(rows, cols, 3) uint8 colours that name their pixel: red from the row, green from the column."""
    i, j = np.mgrid[0:rows, 0:cols]
    return np.stack([(i * 7) % 256, (j * 5) % 256, ((i + j) * 3) % 256], axis=2).astype(np.uint8)


def coded_png_over_the_dem(tmp_path: Path, source: Path):
    """The DEM ``source``, a PNG of :func:`coded_pixels` on its own grid, and that grid's extent as
    ``--image-extent`` takes it: (terrain, pixels, png path, "xmin,xmax,ymin,ymax")."""
    from PIL import Image

    from stepterrain import load_dem
    from stepterrain.texture import terrain_extent

    terrain = load_dem(source)
    pixels = coded_pixels(*terrain.shape)
    png = tmp_path / "map.png"
    Image.fromarray(pixels).save(png)
    return terrain, pixels, png, ",".join(f"{v!r}" for v in terrain_extent(terrain))


def write_geotiff(path: Path, pixels: np.ndarray, transform, crs) -> Path:
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    with rasterio.open(path, "w", driver="GTiff", height=pixels.shape[0], width=pixels.shape[1],
                       count=pixels.shape[2], dtype="uint8", crs=crs, transform=transform) as out:
        out.write(np.moveaxis(pixels, 2, 0))
        if pixels.shape[2] == 4:
            from rasterio.enums import ColorInterp

            out.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue, ColorInterp.alpha]
    return path


def texture_of(tmp_path: Path, name: str, *argv: str) -> np.ndarray:
    out = tmp_path / f"{name}.png"
    assert main(["-q", "texture", *argv, "-o", str(out), "--device", "cpu"]) == 0
    return read_png(out).astype(np.float64)


def test_cli_texture_image_geotiff_is_placed_by_its_georeferencing_and_shaded(tmp_path, capsys):
    """--image GEOTIFF: a colour-coded image over part of the Big Tujunga DEM (rows 100-399, columns 200-699 of its
    grid, same CRS), alpha 0 in its first 50 rows. Where it is opaque the texture is the image's pixel at that
    node shaded by the hillshade (the --colormap none texture's grey); where it is transparent and outside it, the
    texture is the one without --image (hypsometric colours shaded). -o .tif lies on the DEM's grid."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from rasterio.transform import Affine

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    with rasterio.open(source) as dem:
        transform, crs = dem.transform, dem.crs
    pixels = np.dstack([coded_pixels(300, 500), np.full((300, 500), 255, np.uint8)])
    pixels[:50, :, 3] = 0
    image = write_geotiff(tmp_path / "ortho.tif", pixels, transform @ Affine.translation(200, 100), crs)
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(image))
    grey = texture_of(tmp_path, "grey", str(source), "--colormap", "none")[..., 0]
    plain = texture_of(tmp_path, "plain", str(source))
    inside = (slice(150, 400), slice(200, 700))  # the opaque part, in the DEM's rows and columns
    expected = pixels[50:, :, :3] * grey[inside][..., None] / 255.0
    assert np.abs(draped[inside] - expected).max() <= 1.0
    assert draped[234, 456].tolist() == pytest.approx((pixels[134, 256, :3] * grey[234, 456] / 255).tolist(), abs=1)
    outside = np.ones(draped.shape[:2], bool)
    outside[inside] = False
    assert np.array_equal(draped[outside], plain[outside])  # the transparent rows and off the image
    assert (draped[outside] != 0).any() and np.abs(draped[inside] - plain[inside]).max() > 50
    # --colormap none: the image over white, so off it the grey hillshade; -o .tif on the DEM's own grid
    out = tmp_path / "draped.tif"
    assert main(["-q", "texture", str(source), "--image", str(image), "--colormap", "none", "-o", str(out)]) == 0
    with rasterio.open(out) as tex:
        assert tex.crs == crs and tex.transform.almost_equals(transform, precision=1e-6)
        shaded = np.moveaxis(tex.read(), 0, 2).astype(np.float64)
    assert np.abs(shaded[inside] - expected).max() <= 1.0
    off = np.abs(shaded[outside] - grey[outside][:, None])  # float32 noise of the sampling: a rounding tie or two
    assert off.max() <= 1.0 and (off > 0).mean() < 1e-4
    assert capsys.readouterr().err == ""


def test_cli_texture_image_png_with_extent_drapes_the_mesh(tmp_path, capsys):
    """--image PNG --image-extent: a PNG of the DEM's own grid, placed by the extent of its outer pixel edges in
    the DEM's coordinates, gives the texture a GeoTIFF of it gives; --mesh drapes that texture (the GLB's image)."""


    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    terrain, pixels, png, extent = coded_png_over_the_dem(tmp_path, source)
    mesh = tmp_path / "draped.glb"
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(png), f"--image-extent={extent}",
                        "--colormap", "none", "--mesh", str(mesh))
    grey = texture_of(tmp_path, "grey", str(source), "--colormap", "none")[..., :1]
    assert np.abs(draped - pixels * grey / 255.0).max() <= 1.0
    assert np.abs(draped[321, 654] - pixels[321, 654] * grey[321, 654] / 255.0).max() <= 1.0
    back = trimesh.load(mesh, force="mesh", process=False)
    embedded = np.asarray(back.visual.material.baseColorTexture.convert("RGB")).astype(np.float64)
    assert embedded.shape == draped.shape and np.array_equal(embedded, draped)


def test_cli_texture_image_in_degrees_lies_on_a_dem_in_degrees(tmp_path):
    """A GeoTIFF in EPSG:4326 on the Front Range SRTM tile in EPSG:4326 (read as local equirectangular metres):
    placed by its degrees through those metres, pixel (i, j) of the image on node (i, j) of the same grid."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")

    from .conftest import shared_file

    source = shared_file("front_range_srtmgl3_3arcsec.tif")
    with rasterio.open(source) as dem:
        pixels = coded_pixels(*dem.shape)
        image = write_geotiff(tmp_path / "ortho.tif", pixels, dem.transform, dem.crs)
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(image), "--colormap", "none")
    grey = texture_of(tmp_path, "grey", str(source), "--colormap", "none")[..., :1]
    assert np.abs(draped - pixels * grey / 255.0).max() <= 1.0
    assert np.abs(draped[500, 100] - pixels[500, 100] * grey[500, 100] / 255.0).max() <= 1.0


def test_cli_extents_and_texel_size_in_degrees_for_a_dem_in_degrees_are_refused_with_their_metres(tmp_path, capsys):
    """A DEM in degrees is read as local metres, which --image-extent, --crop and --texel-size take. Given in degrees
    (a whole-world JPEG's -180,180,-90,90), --image-extent draped the image on a 360 x 180 m corner of the Front
    Range tile without a word, and --crop said it held 0 x 0 nodes: both are refused now, naming the same extent in
    the DEM's metres, which places the image exactly where the same pixels lie as a GeoTIFF in degrees, and crops the
    nodes inside those degrees. --texel-size 0.0001 (degrees) is told it is in metres, with the node spacing."""
    import re

    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from PIL import Image

    from .conftest import shared_file

    source = shared_file("front_range_srtmgl3_3arcsec.tif")
    with rasterio.open(source) as dem:
        pixels, bounds, step = coded_pixels(*dem.shape), dem.bounds, dem.res[0]
    image = tmp_path / "map.png"
    Image.fromarray(pixels).save(image)
    degrees = f"{bounds.left!r},{bounds.right!r},{bounds.bottom!r},{bounds.top!r}"
    out = tmp_path / "t.png"
    assert main(["texture", str(source), "--image", str(image), f"--image-extent={degrees}", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--image-extent=" in err and "looks like degrees" in err and not out.exists(), err
    metres = re.search(r"those degrees are --image-extent=(\S+)", err).group(1)
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(image), f"--image-extent={metres}",
                        "--colormap", "none")
    grey = texture_of(tmp_path, "grey", str(source), "--colormap", "none")[..., :1]
    assert np.abs(draped - pixels * grey / 255.0).max() <= 1.0

    # nodes 100..299 west to east, 50..249 north to south: the box's edges lie halfway between nodes
    box = (bounds.left + 100 * step, bounds.left + 300 * step, bounds.top - 250 * step, bounds.top - 50 * step)
    assert main(["texture", str(source), "--crop=" + ",".join(repr(v) for v in box), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--crop=" in err and "looks like degrees" in err and "0 x 0 nodes" not in err, err
    crop = re.search(r"those degrees are --crop=(\S+)", err).group(1)
    assert texture_of(tmp_path, "cropped", str(source), f"--crop={crop}").shape == (200, 200, 3)

    assert main(["texture", str(source), "--texel-size", "0.0001", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--texel-size, in metres" in err and "node spacing 70.827 x 92.6626 m), not in degrees" in err, err


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_texture_image_keeps_the_dems_nodata_transparent_and_renders(tmp_path):
    """A DEM with a nodata hole: the texture with --image is RGBA with alpha 0 over the hole (the image covers it,
    the DEM has no ground there) and opaque elsewhere; --png renders the draped image."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")

    from .conftest import shared_file

    with rasterio.open(shared_file(TUJUNGA)) as dem:
        heights, transform, crs = dem.read(1).astype(np.float32), dem.transform, dem.crs
    heights[200:260, 300:400] = -9999.0
    source = tmp_path / "holes.tif"
    with rasterio.open(source, "w", driver="GTiff", height=heights.shape[0], width=heights.shape[1], count=1,
                       dtype="float32", crs=crs, transform=transform, nodata=-9999.0) as out:
        out.write(heights, 1)
    image = write_geotiff(tmp_path / "ortho.tif", coded_pixels(*heights.shape), transform, crs)
    png = tmp_path / "render.png"
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(image), "--png", str(png), "--size", "320x200")
    hole = np.zeros(heights.shape, bool)
    hole[200:260, 300:400] = True
    assert draped.shape == (*heights.shape, 4)
    assert (draped[hole, 3] == 0).all() and (draped[~hole, 3] == 255).all()
    shot = read_png(png)
    assert shot.shape[:2] == (200, 320) and shot[..., :3].std() > 20


@pytest.mark.parametrize("case, match", [
    ("missing", "--image '{image}' does not exist"),
    ("not an image", "--image '{image}': cannot read it as an image"),
    ("png without extent", "--image '{image}' carries no georeferencing (a PNG or JPEG without a world file (.pgw, "
                           ".jgw, .wld) beside it, or a TIFF without a geotransform): put a world file 'map.pgw' "
                           "beside it, with its CRS in 'map.prj', or give --image-extent xmin,xmax,ymin,ymax"),
    ("extent without image", "--image-extent applies only with --image"),
    ("bad extent", "--image-extent must be finite (xmin, xmax, ymin, ymax) with xmin < xmax"),
    ("crs mismatch", "--image '{image}': the image is in CRS 'EPSG:32610' but the terrain is in 'EPSG:32611' "
                     "(mismatched CRS"),
    ("off the dem", "does not overlap the terrain's"),
    ("south up", "with its rows running south to north or its columns east to west (pixel size 30 x 30); a "
                 "pyramid's row 0 is the north edge and column 0 the west edge: write the image north-up, or give "
                 "--image-extent xmin,xmax,ymin,ymax for it as it is"),
    ("rotated", "rotated geotransform (30.0, 2.0, 376313.0, 2.0, -30.0, 3807917.0) (its rotation terms move pixels "
                "by more than 1e-06 of a pixel over 64 x 64 pixels); a pyramid's extent is north-up: `gdalwarp "
                "-dstalpha` makes the image north-up, or give --image-extent xmin,xmax,ymin,ymax for it as it is"),
    ("over the budget", "reading '{image}' (the image's window: 3 x 1222 x 2275 cells of uint8)"),  # a PNG: its window
])
def test_cli_texture_image_is_refused_clearly(tmp_path, capsys, case, match):
    """Each refusal exits 2 before writing anything, naming the option and what it got; what the image file alone
    tells (a rotated or south-up geotransform too, which was refused only once the DEM was loaded) before the DEM is
    loaded."""
    from PIL import Image

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    image = tmp_path / ("ortho.tif" if case in ("crs mismatch", "south up", "rotated") else "map.png")
    argv = ["--image", str(image)]
    if case == "not an image":
        image.write_text("not an image\n")
    elif case in ("png without extent", "off the dem", "bad extent"):
        Image.fromarray(coded_pixels(643, 1197)).save(image)
    elif case == "over the budget":  # pixels of 15.8 m over the 30 m DEM, read as they are: their window's 33 MB past
        # the budget, which the DEM's own texture (16 MiB at one texel a node, checked first) is within
        Image.fromarray(coded_pixels(1222, 2275)).save(image)
    if case in ("png without extent", "off the dem", "over the budget", "bad extent"):
        argv += {"png without extent": [], "off the dem": ["--image-extent=0,100,0,100"],
                 "bad extent": ["--image-extent=10,0,0,100"],
                 "over the budget": ["--image-extent=376313,412223,3788627,3807917", "--memory-budget", "25MB"]}[case]
    elif case == "extent without image":
        argv = ["--image-extent=0,100,0,100"]
    elif case == "crs mismatch":
        rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
        with rasterio.open(source) as dem:
            write_geotiff(image, coded_pixels(*dem.shape), dem.transform, "EPSG:32610")
    elif case in ("south up", "rotated"):  # the library's extent= was named, not the option
        from rasterio.transform import Affine

        transform = (Affine(30.0, 0.0, 376313.0, 0.0, 30.0, 3788627.0) if case == "south up"
                     else Affine(30.0, 2.0, 376313.0, 2.0, -30.0, 3807917.0))
        write_geotiff(image, coded_pixels(64, 64), transform, "EPSG:32611")
    out = tmp_path / "t.png"
    assert main(["texture", str(source), *argv, "-o", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert match.format(image=image) in err, err
    assert not out.exists()
    assert ("stepterrain: loading" in err) == (case in ("crs mismatch", "off the dem", "over the budget")), err


def test_cli_texture_image_geotiff_is_opened_once_to_check_and_once_to_read(tmp_path, monkeypatch):
    """--image ortho.tif was opened with GDAL three times: by the CLI's check (is_georeferenced), by the pyramid's
    build (pixels, mask, georeferencing), and by image_layer asking is_georeferenced again after the build. The
    check's open now also refuses a rotated image, and image_layer asks the pyramid how it was placed: two opens,
    the same texture."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from stepterrain import texture_lod

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    with rasterio.open(source) as dem:
        transform, crs = dem.transform, dem.crs
    from rasterio.transform import Affine

    image = write_geotiff(tmp_path / "ortho.tif", coded_pixels(60, 80), transform @ Affine.translation(200, 100), crs)
    opened = []
    real = texture_lod.open_raster

    def counted(path, *args, **kwargs):
        opened.append(Path(path).name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(texture_lod, "open_raster", counted)
    draped = texture_of(tmp_path, "ortho", str(source), "--image", str(image), "--colormap", "none",
                        "--hillshade", "none")
    assert opened.count("ortho.tif") == 2, opened
    assert np.array_equal(draped[100:160, 200:280], coded_pixels(60, 80))


@pytest.mark.parametrize("suffix, world", [(".jpg", "photo.jgw"), (".jpeg", "photo.jgw"), (".png", "photo.pgw")])
def test_cli_texture_image_without_georeferencing_names_both_ways_to_place_it(tmp_path, capsys, suffix, world):
    """A JPEG (or PNG) with neither a world file nor --image-extent: the refusal named only --image-extent, though a
    world file beside it (with a .prj of its CRS) places it as well; both are named now, the world file as GDAL looks
    for it, and following the hint (the world file it names, the .prj it names) places the image."""
    pytest.importorskip("rasterio", reason="world files are read with rasterio")
    from PIL import Image

    from stepterrain.io import load_dem
    from stepterrain.texture_lod import image_layer

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    image = tmp_path / f"photo{suffix}"
    Image.fromarray(coded_pixels(40, 50)).save(image)
    assert main(["-q", "texture", str(source), "--image", str(image), "-o", str(tmp_path / "x.png"),
                 "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert (f"carries no georeferencing (a PNG or JPEG without a world file (.pgw, .jgw, .wld) beside it, or a TIFF "
            f"without a geotransform): put a world file {world!r} beside it, with its CRS in 'photo.prj', or give "
            "--image-extent xmin,xmax,ymin,ymax, the outer edges of its pixels in the DEM's coordinates") in err, err
    terrain = load_dem(source)
    with pytest.raises(InvalidInputError, match=f"put a world file '{world}' beside it, with its CRS in 'photo.prj', "
                                                r"or pass extent=\(xmin, xmax, ymin, ymax\)"):
        image_layer(image, terrain, device="cpu")
    xmin, ymax = 376313.0 + 30 * 200, 3807917.0 - 30 * 100  # the hint followed: placed by the files it names
    (tmp_path / world).write_text(f"30\n0\n0\n-30\n{xmin + 15}\n{ymax - 15}\n")
    (tmp_path / "photo.prj").write_text(terrain.crs)
    with pytest.warns(UserWarning, match="covers only 0.26 % of the terrain"):  # 50 x 40 of its 1197 x 643 nodes
        placed = image_layer(image, terrain, device="cpu")
    assert placed.extent == pytest.approx((xmin, xmin + 50 * 30, ymax - 40 * 30, ymax))


def test_cli_texture_hillshade_none_drapes_an_image_unshaded_and_shadows_still_darken(tmp_path):
    """--hillshade none: no hillshade, every node fully lit, so an orthophoto keeps its own light. The texture is the
    PNG of the DEM's own grid exactly (what --image places there), and without --image the hypsometric colours of
    the default texture's colormap exactly; --shadows (a low sun) darkens the nodes cast_shadows marks to
    0.25 + 0.75 · 0.4 of their colour (topographic_layer's formula with a shade of 1) and leaves the lit ones as they
    are."""

    from stepterrain.texture import _north_up, cast_shadows

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    terrain, pixels, png, extent = coded_png_over_the_dem(tmp_path, source)
    image = ("--image", str(png), f"--image-extent={extent}")
    unshaded = texture_of(tmp_path, "unshaded", str(source), *image, "--hillshade", "none", "--colormap", "none")
    assert np.array_equal(unshaded, pixels)  # the image itself, no light on it
    shaded = texture_of(tmp_path, "shaded", str(source), *image, "--colormap", "none")
    assert np.abs(shaded - pixels).max() > 100  # the default hillshade does shade it
    # the colours alone: the default texture's colours without the shading, lit nodes unchanged under --shadows
    colours = texture_of(tmp_path, "colours", str(source), "--hillshade", "none")
    shadowed = texture_of(tmp_path, "shadowed", str(source), "--hillshade", "none", "--shadows", "--altitude", "15")
    mask = _north_up(terrain, cast_shadows(terrain, altitude=np.radians(15.0), device="cpu")).astype(bool)
    assert 0.01 < mask.mean() < 0.5
    assert np.array_equal(shadowed[~mask], colours[~mask])
    assert np.abs(shadowed[mask] - colours[mask] * (0.25 + 0.75 * 0.4)).max() <= 1.0
    assert len(np.unique(colours.reshape(-1, 3), axis=0)) > 50  # a colormap over the relief, not one colour


@pytest.mark.parametrize(("argv", "message"), [
    (["--azimuth", "200"], "--azimuth has no effect with --hillshade none (no light shades the terrain); it aims "
                           "--shadows only; got --azimuth 200 without --shadows"),
    (["--altitude", "30"], "--altitude has no effect with --hillshade none"),
    (["--z-factor", "2"], "--z-factor has no effect with --hillshade none unless --shadows, --occlusion or --normals "
                          "use the relief; got --z-factor 2"),
    (["--colormap", "none"], "--hillshade none with --colormap none and no --image, --shadows, --occlusion or "
                             "--contours leaves nothing to draw"),
    (["--shadows", "--occlusion", "nan"], "--occlusion must be finite; got nan"),
    (["--shadows", "--shadow-strength", "1.5"], "--shadow-strength must lie in [0, 1]"),
])
def test_cli_texture_hillshade_none_refuses_what_only_the_hillshade_uses(tmp_path, capsys, argv, message):
    """Options that would change nothing without a hillshade, and a texture of nothing at all, are refused by name
    before anything is written; a bad --occlusion or --shadow-strength is named as with a hillshade."""
    out = tmp_path / "t.png"
    assert main(["-q", "texture", "--hillshade", "none", *argv, "-o", str(out), "--device", "cpu"]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def _fine_ortho(tmp_path: Path) -> tuple[Path, np.ndarray, object, str]:
    """A 5 m GeoTIFF (6 x 6 pixels a DEM cell) over the Big Tujunga DEM's cells rows 100-199, columns 200-349, in its
    CRS: the colour-coded pattern, one white pixel in a black 12 x 12 square at image pixel (303, 405)."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from rasterio.transform import Affine

    from .conftest import shared_file

    with rasterio.open(shared_file(TUJUNGA)) as dem:
        transform, crs = dem.transform, dem.crs
    pixels = coded_pixels(600, 900)
    pixels[297:309, 399:411] = 0
    pixels[303, 405] = 255
    image = write_geotiff(tmp_path / "ortho5.tif", pixels, transform @ Affine.translation(200, 100)
                          @ Affine.scale(1 / 6), crs)
    return image, pixels, transform, crs


def _crop_nodes(rows: tuple[int, int], cols: tuple[int, int]) -> str:
    """--crop keeping the Big Tujunga DEM's nodes rows[0]..rows[1], cols[0]..cols[1] (inclusive)."""
    x0, y0 = 376328.6554542635, 3807902.8276283755  # node (0, 0); 30 m spacing
    return (f"--crop={x0 + 30 * cols[0] - 1!r},{x0 + 30 * cols[1] + 1!r},{y0 - 30 * rows[1] - 1!r},"
            f"{y0 - 30 * rows[0] + 1!r}")


def test_cli_texture_texel_size_keeps_a_fine_images_detail(tmp_path):
    """--texel-size 5 on the 30 m DEM (cropped to nodes rows 90-209, columns 190-359): the texture has 6 x 6 texels
    a node, the 5 m orthophoto's pixels at their own positions (texel (60 + i, 60 + j) is image pixel (i, j), exactly
    with --hillshade none), its lone white pixel too; the -o GeoTIFF's transform is the DEM's with 5 m pixels, from
    the same corner; at the default texel size (one per node) that pixel is averaged away."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from rasterio.transform import Affine

    from .conftest import shared_file

    image, pixels, transform, crs = _fine_ortho(tmp_path)
    crop = _crop_nodes((90, 209), (190, 359))
    common = [str(shared_file(TUJUNGA)), crop, "--image", str(image), "--colormap", "none", "--hillshade", "none"]
    fine = texture_of(tmp_path, "fine", *common, "--texel-size", "5")
    assert fine.shape == (120 * 6, 170 * 6, 3)
    assert np.array_equal(fine[60:660, 60:960], pixels)
    assert fine[60 + 303, 60 + 405].tolist() == [255, 255, 255]
    coarse = texture_of(tmp_path, "coarse", *common)
    assert coarse.shape == (120, 170, 3)
    assert coarse[10 + 50, 10 + 67].max() < 32  # the node at image pixel (303, 405): black around it, white lost
    out = tmp_path / "fine.tif"
    assert main(["-q", "texture", *common, "--texel-size", "5", "-o", str(out), "--device", "cpu"]) == 0
    with rasterio.open(out) as tex:
        assert tex.crs == crs and tex.shape == (720, 1020)
        corner = transform @ Affine.translation(190, 90)  # the cropped DEM's north-west pixel corner
        assert tex.transform.almost_equals(corner @ Affine.scale(1 / 6), precision=1e-6)
        assert np.array_equal(np.moveaxis(tex.read(), 0, 2)[60:660, 60:960], pixels)


def test_cli_texture_texel_size_shades_the_finer_grid_and_drapes_it(tmp_path, small_dem):
    """--texel-size 0.25 on a DEM of 1 m spacing: the shaded hypsometric texture at 4 texels a node, the texture on
    the nodes interpolated (each node's own texel colour near its centre: the 2 x 2 texels around a node centre
    average it), the GLB's embedded image that size and the draped UVs mapping a node to its texels."""
    coarse = texture_of(tmp_path, "coarse", str(small_dem), "--shadows")
    mesh = tmp_path / "fine.glb"
    fine = texture_of(tmp_path, "fine", str(small_dem), "--shadows", "--texel-size", "0.25", "--mesh", str(mesh))
    assert coarse.shape == (40, 50, 3) and fine.shape == (160, 200, 3)
    around = fine.reshape(40, 4, 50, 4, 3)[:, 1:3, :, 1:3].mean(axis=(1, 3))  # 2 x 2 texels around each node centre
    assert np.abs(around - coarse)[1:-1, 1:-1].mean() < 2.0
    back = trimesh.load(mesh, force="mesh", process=False)
    embedded = np.asarray(back.visual.material.baseColorTexture.convert("RGB"))
    assert embedded.shape == (160, 200, 3) and np.array_equal(embedded, fine)
    uv = np.asarray(back.visual.uv)
    world = np.asarray(back.vertices)  # glTF's y-up world, as trimesh and viewers read it: y is -z there
    xy = np.c_[world[:, 0], -world[:, 2]]  # the nodes' x 0..49, y -39..0; the texture's extent half a node beyond
    assert np.allclose(uv[:, 0], (xy[:, 0] + 0.5) / 50) and np.allclose(uv[:, 1], (xy[:, 1] + 39.5) / 40)


@pytest.mark.parametrize("argv,match", [
    (["--texel-size", "0"], "--texel-size must be a positive number of the DEM's units (metres) per texel; got 0"),
    (["--texel-size", "-2"], "--texel-size must be a positive number of the DEM's units (metres) per texel; got -2"),
    (["--texel-size", "nan"], "--texel-size must be a positive number of the DEM's units (metres) per texel; got nan"),
    (["--texel-size", "45"], "--texel-size must be no larger than the DEM's node spacing (30; the default is one "
                             "texel per node): it makes the texture finer; got --texel-size 45"),
    # so small that the texels a side overflow float64: math.ceil's OverflowError, a traceback
    (["--texel-size", "1e-320"], "--texel-size must be a positive size that cuts the terrain's 35910 x 19290 texture "
                                 "extent into a finite number of texels; got 9.99989e-321"),
    (["--texel-size", "1", "--memory-budget", "1GiB"],
     "the 35910 x 19290 texel texture of --texel-size 1 (while it is composed and written) would need "),
    (["--texel-size", "2", "--memory-budget", "64GiB", "--mesh", "{tmp}/m.glb"],
     "--texel-size 2 makes a 17955 x 9645 texel texture, over the 16384 texels a side GPUs load as one texture, for "
     "--mesh {tmp}/m.glb: give a larger --texel-size"),
])
def test_cli_texture_texel_size_is_refused_by_name(tmp_path, capsys, argv, match):
    """Each bad --texel-size exits 2 before any work, naming the option and what it got (the size over the budget,
    the texels a side over a GPU's texture limit for a textured mesh)."""
    from .conftest import shared_file

    out = tmp_path / "t.png"
    argv = [a.format(tmp=tmp_path) for a in argv]
    assert main(["texture", str(shared_file(TUJUNGA)), *argv, "-o", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert match.format(tmp=tmp_path) in err, err
    if "budget" in " ".join(argv) and "64GiB" not in argv:
        assert "give a larger --texel-size" in err
    assert not out.exists()


def test_cli_texture_texel_size_is_no_coarser_than_a_geographic_dem_either_way(tmp_path, capsys):
    """The Front Range DEM in degrees, read as local metres, has nodes 70.8 m apart in x and 92.7 m in y: a
    --texel-size up to the larger spacing was taken (90: 597 texels across its 758 nodes, coarser than the DEM in x,
    while --help says "no larger than the node spacing"). The smaller spacing is the limit now, named with both;
    just under it the texture has at least one texel a node both ways."""
    from .conftest import shared_file

    source = str(shared_file("front_range_srtmgl3_3arcsec.tif"))
    out = tmp_path / "t.png"
    assert main(["-q", "texture", source, "--texel-size", "90", "-o", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert ("--texel-size must be no larger than the DEM's node spacing (70.827, the smaller of its 70.827 x "
            "92.6626; the default is one texel per node)") in err and "got --texel-size 90" in err, err
    assert not out.exists()
    assert main(["-q", "texture", source, "--texel-size", "70.8", "-o", str(out), "--device", "cpu"]) == 0
    rows, cols = read_png(out).shape[:2]
    assert cols >= 758 and rows >= 758, (rows, cols)


@pytest.mark.parametrize("texel", [None, "10"])
def test_cli_texture_image_on_a_cropped_dem_keeps_its_colours_at_the_crops_edge(tmp_path, texel):
    """--image over a --crop of the DEM: the texture of the crop is the texture of a larger crop over the same nodes
    (texels), also next to the crop's edges, to a grey level. image_layer read only the image's pixels over the
    terrain, so a texel near its edge was interpolated with the window's edge pixel repeated instead of the image's
    next pixel beyond it: the colours there depended on where the DEM was cropped (tiles of one orthophoto did not
    match at their seams)."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from rasterio.transform import Affine

    from .conftest import shared_file

    with rasterio.open(shared_file(TUJUNGA)) as dem:
        transform, crs = dem.transform, dem.crs
    pixels = np.random.default_rng(5).integers(0, 256, (60, 80, 3), dtype=np.uint8)  # 45 m pixels, off the nodes
    image = write_geotiff(tmp_path / "noise.tif", pixels, transform @ Affine.translation(95.3, 95.7)
                          @ Affine.scale(1.5), crs)
    common = [str(shared_file(TUJUNGA)), "--image", str(image), "--colormap", "none", "--hillshade", "none"]
    common += [] if texel is None else ["--texel-size", texel]
    per_node = 1 if texel is None else 3
    large = texture_of(tmp_path, "large", *common, _crop_nodes((100, 180), (100, 210)))
    small = texture_of(tmp_path, "small", *common, _crop_nodes((120, 160), (130, 180)))
    assert small.shape == (41 * per_node, 51 * per_node, 3)
    r0, c0 = 20 * per_node, 30 * per_node
    # a grey level of float32 rounding (the sampling runs relative to each texture's corner); was 8 at the edges
    assert np.abs(small - large[r0:r0 + small.shape[0], c0:c0 + small.shape[1]]).max() <= 1.0


def test_cli_texture_a_global_image_drapes_a_dem_across_the_antimeridian(tmp_path):
    """A whole-world image in degrees (1 degree pixels: the western hemisphere one colour, the eastern another) on a
    DEM in degrees from 178 E to 182 E (178 E to 178 W): the image goes on past its seam at 180, so the nodes east
    of 180.5 take the western hemisphere's colour and those west of 179.5 the eastern's. image_layer placed the image
    at one turn only, so the nodes on the far side of the seam were left transparent (white)."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")
    from rasterio.transform import Affine

    pixels = np.empty((180, 360, 3), np.uint8)
    pixels[:, :180] = (10, 20, 30)  # 180 W .. 0
    pixels[:, 180:] = (200, 100, 50)  # 0 .. 180 E
    image = write_geotiff(tmp_path / "world.tif", pixels, Affine(1.0, 0.0, -180.0, 0.0, -1.0, 90.0), "EPSG:4326")
    dem = tmp_path / "across.tif"
    heights = np.random.default_rng(3).normal(100.0, 5.0, (9, 17)).astype(np.float32)
    with rasterio.open(dem, "w", driver="GTiff", height=9, width=17, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(0.25, 0.0, 177.875, 0.0, -0.25, -15.875)) as out:  # nodes at 178 .. 182 E
        out.write(heights, 1)
    draped = texture_of(tmp_path, "draped", str(dem), "--image", str(image), "--colormap", "none",
                        "--hillshade", "none")
    lons = 178.0 + 0.25 * np.arange(17)
    assert (draped[:, lons <= 179.5] == (200, 100, 50)).all()
    assert (draped[:, lons >= 180.5] == (10, 20, 30)).all()


def write_world_image(path: Path, pixels: np.ndarray, transform, wkt: str | None) -> np.ndarray:
    """``pixels`` saved as a JPEG or PNG (by ``path``'s extension) with a world file written by hand beside it (A, D,
    B, E, C, F: the pixel size, the rotation terms, and the centre of the top-left pixel), and a .prj of ``wkt``;
    the pixels as Pillow decodes them back (a JPEG's are not those saved)."""
    from PIL import Image

    Image.fromarray(pixels).save(path, quality=90)
    a, b, c, d, e, f = tuple(transform)[:6]
    world = path.with_suffix({".jpg": ".jgw", ".png": ".pgw"}[path.suffix])
    centre_x, centre_y = c + 0.5 * a + 0.5 * b, f + 0.5 * d + 0.5 * e
    world.write_text("\n".join(f"{v!r}" for v in (a, d, b, e, centre_x, centre_y)) + "\n")
    if wkt is not None:
        path.with_suffix(".prj").write_text(wkt)
    return read_png(path)


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_cli_texture_image_with_a_world_file_is_placed_as_a_geotiff(tmp_path, suffix):
    """--image ORTHO.jpg/.png with a world file (.jgw/.pgw) and a .prj beside it (the DEM's CRS), a colour-coded
    image of 30 m pixels over rows 100-159, columns 200-279 of the Big Tujunga DEM: each pixel (as Pillow decodes it)
    lands on its node, and the texture (and image_layer's layer) is the one a GeoTIFF of those pixels on the same
    grid gives. A JPEG or PNG was taken as not georeferenced (GDAL reads world files; rasterio was asked only for a
    .tif), so --image-extent was demanded."""
    rasterio = pytest.importorskip("rasterio", reason="world files are read with rasterio")
    from rasterio.transform import Affine

    from stepterrain import load_dem
    from stepterrain.texture_lod import ImagePyramid, image_layer, is_georeferenced

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    with rasterio.open(source) as dem:
        transform, crs = dem.transform, dem.crs
    placed = transform @ Affine.translation(200, 100)
    image = tmp_path / f"ortho{suffix}"
    pixels = write_world_image(image, coded_pixels(60, 80), placed, crs.to_wkt())
    assert is_georeferenced(image)
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(image), "--colormap", "none",
                        "--hillshade", "none")
    assert np.array_equal(draped[100:160, 200:280], pixels)  # each pixel on its node
    assert draped[123, 245].tolist() == pixels[23, 45].tolist()
    off = np.ones(draped.shape[:2], bool)
    off[100:160, 200:280] = False
    assert (draped[off] == 255).all()  # white off the image (--colormap none)
    geotiff = write_geotiff(tmp_path / "ortho.tif", pixels, placed, crs)
    assert np.array_equal(draped, texture_of(tmp_path, "geotiff", str(source), "--image", str(geotiff),
                                             "--colormap", "none", "--hillshade", "none"))
    terrain = load_dem(source)
    with pytest.warns(UserWarning, match="covers only 0.624 % of the terrain"):  # one warning each
        layer, reference = image_layer(image, terrain, device="cpu"), image_layer(geotiff, terrain, device="cpu")
    assert layer.extent == reference.extent and np.array_equal(layer.image, reference.image)
    with ImagePyramid.build(image, device="cpu") as pyramid:  # its CRS from the .prj
        assert pyramid.crs == "EPSG:32611" and pyramid.extent == pytest.approx(
            (placed.c, placed.c + 80 * 30.0, placed.f - 60 * 30.0, placed.f))


def test_cli_texture_image_world_file_crs_rules(tmp_path, capsys):
    """A world file without a CRS is taken in the DEM's CRS, as a GeoTIFF without one (placed as with its .prj);
    over a DEM in degrees (read as local metres, no file's coordinates) it is refused, naming a .prj and
    --image-extent, as it is when its extent misses the DEM; an .aux.xml's CRS counts (another one refused), a
    .prj that is no CRS is refused by name, and a rotated world file is refused as a rotated GeoTIFF is."""
    rasterio = pytest.importorskip("rasterio", reason="world files are read with rasterio")
    from rasterio.crs import CRS
    from rasterio.transform import Affine

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    with rasterio.open(source) as dem:
        transform, crs = dem.transform, dem.crs
    placed = transform @ Affine.translation(200, 100)
    with_prj = tmp_path / "with" / "ortho.png"
    with_prj.parent.mkdir()
    write_world_image(with_prj, coded_pixels(60, 80), placed, crs.to_wkt())
    bare = tmp_path / "bare" / "ortho.png"
    bare.parent.mkdir()
    pixels = write_world_image(bare, coded_pixels(60, 80), placed, None)
    draped = texture_of(tmp_path, "bare", str(source), "--image", str(bare), "--colormap", "none",
                        "--hillshade", "none")
    assert np.array_equal(draped[100:160, 200:280], pixels)
    assert np.array_equal(draped, texture_of(tmp_path, "prj", str(source), "--image", str(with_prj),
                                             "--colormap", "none", "--hillshade", "none"))

    def refused(dem: Path, image: Path) -> str:
        assert main(["-q", "texture", str(dem), "--image", str(image), "-o", str(tmp_path / "x.png"),
                     "--device", "cpu"]) == 2
        return capsys.readouterr().err

    degrees = tmp_path / "degrees" / "ortho.png"  # a world file in degrees over the Front Range DEM, no .prj
    degrees.parent.mkdir()
    write_world_image(degrees, coded_pixels(60, 80), Affine(0.001, 0, -105.7, 0, -0.001, 40.4), None)
    err = refused(shared_file("front_range_srtmgl3_3arcsec.tif"), degrees)
    assert "is georeferenced without a CRS, but the terrain is a DEM in degrees read as local metres" in err
    assert "put a .prj with the image's CRS beside it (EPSG:4326 for degrees), or give --image-extent" in err
    degrees.with_suffix(".prj").write_text(CRS.from_epsg(4326).to_wkt())  # with its CRS: placed as a GeoTIFF is
    front_range = shared_file("front_range_srtmgl3_3arcsec.tif")
    on_degrees = texture_of(tmp_path, "degrees", str(front_range), "--image", str(degrees), "--colormap", "none",
                            "--hillshade", "none")
    geotiff = write_geotiff(tmp_path / "degrees.tif", read_png(degrees), Affine(0.001, 0, -105.7, 0, -0.001, 40.4),
                            "EPSG:4326")
    from_geotiff = texture_of(tmp_path, "degrees_tif", str(front_range), "--image", str(geotiff), "--colormap",
                              "none", "--hillshade", "none")
    assert (on_degrees != 255).any() and np.array_equal(on_degrees, from_geotiff)
    far = tmp_path / "far" / "ortho.png"
    far.parent.mkdir()
    write_world_image(far, coded_pixels(60, 80), Affine(30, 0, 1000, 0, -30, 2000), None)
    err = refused(source, far)
    assert "(mismatched extent); the image is georeferenced without a CRS, so it was taken in the terrain's CRS: " \
           "put a .prj with its CRS beside it, or give --image-extent" in err
    aux = tmp_path / "aux" / "ortho.png"
    aux.parent.mkdir()
    write_world_image(aux, coded_pixels(60, 80), placed, None)
    Path(f"{aux}.aux.xml").write_text(f"<PAMDataset><SRS>{CRS.from_epsg(32610).to_wkt()}</SRS></PAMDataset>")
    assert "the image is in CRS 'EPSG:32610' but the terrain is in 'EPSG:32611'" in refused(source, aux)
    bare.with_suffix(".prj").write_text("not a CRS")
    assert f"'{bare.with_suffix('.prj')}' beside image '{bare}' is not a CRS" in refused(source, bare)
    rotated = tmp_path / "rotated" / "ortho.jpg"
    rotated.parent.mkdir()
    write_world_image(rotated, coded_pixels(60, 80), placed @ Affine.rotation(5), crs.to_wkt())
    err = refused(source, rotated)
    assert "rotated geotransform" in err
    assert "`gdalwarp -dstalpha` makes the image north-up, or give --image-extent" in err


def _one_at_a_time(topo, colours, picture, extent, shape, background):
    """The texture as the command composed it before its one-pass kernel: each layer sampled onto the grid as a
    float32 layer of its own, ``blend``, ``modulate`` and ``to_uint8`` one after another."""
    import warp as wp

    from stepterrain import texture as tx

    dev = wp.get_device("cpu")

    def on_grid(layer):
        return tx.TextureLayer("thematic", tx._sampled(layer, extent, shape, dev, "layer").numpy(), extent)

    topo = on_grid(topo)
    colours = None if colours is None else on_grid(colours)
    composite = topo
    if picture is not None:
        base = picture if colours is None else tx.blend(colours, picture, device=dev)
        composite = tx.modulate(topo, base, device=dev)
    elif colours is not None:
        composite = tx.modulate(colours, topo, device=dev)
    return composite.to_uint8(background=background)


@pytest.mark.parametrize("fine", [1, 3])
def test_composed_texture_is_the_layer_operations_one_at_a_time_bit_for_bit(fine):
    """texture._composed (the command's one pass, uint8 out) gives the bytes of blend, modulate and to_uint8 one layer
    at a time: a DEM with a nodata hole, its shading and hypsometric colours on the nodes (fine 1: the texture's grid;
    3: resampled onto 3 x 3 texels a node), a picture sampled onto the grid (RGBA, part transparent, part half; its
    border transparent or its edge texels repeated) or on the grid itself (uint8 RGB, RGBA, read as they are), with
    and without colours, RGBA and over a background."""
    from stepterrain import texture as tx

    rng = np.random.default_rng(7)
    heights = np.cumsum(rng.normal(size=(23, 31)), axis=0) * 5.0 + np.linspace(0, 40, 31)
    heights[8:12, 10:15] = np.nan
    topo = tx.topographic_layer(heights, spacing=(30.0, -30.0), shadows=True, device="cpu")
    colours = tx.terrain_layer(heights, rng.random((23, 31, 4)).astype(np.float32), spacing=(30.0, -30.0))
    extent = topo.extent
    shape = (23 * fine, 31 * fine)
    sampled = rng.integers(0, 256, (40, 50, 4), dtype=np.uint8)
    sampled[:10, :, 3] = 0
    sampled[20:25, :, 3] = 128
    sampled.flags.writeable = False
    inside = (extent[0] + 100, extent[1] - 200, extent[2] + 50, extent[3] - 40)
    pictures = [None, tx.TextureLayer("thematic", sampled, inside),
                tx.TextureLayer("thematic", sampled, inside, border="edge")]
    for channels in (3, 4):
        own = rng.integers(0, 256, (*shape, channels), dtype=np.uint8)
        own[..., 3:][:5] = 0
        own.flags.writeable = False
        pictures.append(tx.TextureLayer("thematic", own, extent))
    for picture in pictures:
        for hypsometric in (None, colours):
            for background in (None, (1.0, 1.0, 1.0), (0.2, 0.5, 0.9)):
                got = tx._composed(topo, hypsometric, picture, extent, shape, background, "cpu")
                want = _one_at_a_time(topo, hypsometric, picture, extent, shape, background)
                assert got.dtype == np.uint8 and got.shape == want.shape == (*shape, 4 if background is None else 3)
                assert np.array_equal(got, want)


def test_cli_texture_texel_size_composes_without_float_layers_on_its_grid(tmp_path):
    """--texel-size with an --image on the cropped Big Tujunga DEM, 5 m and 2.5 m (734 400 and 2 937 600 texels): the
    texture is composed in one pass into uint8, no float32 RGBA layer (16 bytes a texel) on its grid: the Python
    allocations' peak grows by under 16 bytes a texel more (it grew by about 90: the resampled layers, their checked
    copies, blend's and modulate's results and to_uint8's temporaries)."""
    import tracemalloc

    from .conftest import shared_file

    image, _, _, _ = _fine_ortho(tmp_path)
    argv = ["-q", "texture", str(shared_file(TUJUNGA)), _crop_nodes((90, 209), (190, 359)), "--image", str(image),
            "--shadows", "-o", str(tmp_path / "t.png"), "--device", "cpu"]
    assert main([*argv, "--texel-size", "5"]) == 0  # kernels compiled, modules imported
    peaks = []
    for size in ("5", "2.5"):
        tracemalloc.start()
        try:
            assert main([*argv, "--texel-size", size]) == 0
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert read_png(tmp_path / "t.png").shape == (1440, 2040, 3)
    per_texel = (peaks[1] - peaks[0]) / (1440 * 2040 - 720 * 1020)
    assert per_texel < 16, f"{per_texel:.1f} bytes a texel"


def test_cli_texture_obj_side_files_never_replace_the_image_or_another_output(tmp_path, small_dem, capsys):
    """A textured --mesh OBJ writes its texture image beside it, ``<stem>_terrain_texture.png`` (``terrain.obj``:
    ``terrain_texture.png``). ``--image terrain_texture.png --mesh terrain.obj`` replaced the orthophoto given with
    that image, without a word; ``-o terrain_texture.png --mesh terrain.obj`` wrote the texture, then refused the
    mesh. Both are refused by name before any work, and the side files named are those the drape writes."""
    _, _, png, extent = coded_png_over_the_dem(tmp_path, small_dem)
    photo = png.rename(tmp_path / "terrain_texture.png")
    before = photo.read_bytes()
    obj = tmp_path / "terrain.obj"
    for argv, other in (
        (["--image", str(photo), f"--image-extent={extent}", "-o", str(tmp_path / "t.png")], "--image file"),
        (["-o", str(photo)], "what --output names"),
        (["-o", str(tmp_path / "t.png"), "--normals", str(photo)], "what --normals names"),
    ):
        assert main(["-q", "texture", str(small_dem), "--mesh", str(obj), *argv]) == 2
        err = capsys.readouterr().err
        assert f"--mesh {str(obj)!r} writes " in err and other in err, err
        assert photo.read_bytes() == before
        assert sorted(p.name for p in tmp_path.iterdir()) == ["hill.npy", "terrain_texture.png"]
    assert main(["-q", "texture", str(small_dem), "--mesh", str(tmp_path / "other.obj"), "--image", str(photo),
                 f"--image-extent={extent}", "-o", str(tmp_path / "t.png")]) == 0
    assert photo.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hill.npy", "other.mtl", "other.obj",
                                                          "other_terrain_texture.png", "t.png", "terrain_texture.png"]


def test_cli_texture_png_counts_the_texture_against_the_budget_before_any_work(tmp_path, small_dem, capsys):
    """--png counted only its --size window against --memory-budget; the render holds the draped texture too (16
    bytes a texel), which render_textured_mesh now counts. The run checks it with the window once the DEM is read,
    before the texture is composed: exit 2 naming --size and the texture's texels, nothing written."""
    mesh = {"vertices": 40 * 50, "faces": 2 * 39 * 49}  # the draped DEM's surface, whose render copies count too
    window = render._render_bytes(400, 300, **mesh)
    with_texture = render._render_bytes(400, 300, texels=40 * 50, **mesh)
    budget = (window + with_texture) // 2  # the window (and the mesh) alone fit
    out = tmp_path / "t.png"
    code = main(["texture", str(small_dem), "-o", str(out), "--png", str(tmp_path / "r.png"), "--size", "400x300",
                 "--memory-budget", str(budget), "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and "an off-screen render of 400 x 300 pixels (--size 400x300) of a mesh with a 50 x 40 texel " \
                         "texture would need" in err, err
    assert "topographic texture" not in err and not out.exists() and not (tmp_path / "r.png").exists()
    # the hint names what makes the texture smaller here: a texel a node without --texel-size, else a larger one
    assert "give a smaller --size or a smaller texture (one texel per DEM node: --coarsen or --crop the DEM)" in err
    window = render._render_bytes(1024, 768, **mesh)  # a window larger than the texture's composition needs
    budget = window + render._TEXTURE_BYTES_PER_TEXEL * 150 * 120 // 2
    code = main(["texture", str(small_dem), "--spacing", "30", "--texel-size", "10", "-o", str(out), "--png",
                 str(tmp_path / "r.png"), "--size", "1024x768", "--memory-budget", str(budget), "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and "of a mesh with a 150 x 120 texel texture would need" in err, err
    assert "give a smaller --size or a larger --texel-size (or --crop the DEM), or raise" in err, err


@pytest.mark.parametrize("interval", [None, "5"])
def test_cli_texture_png_counts_the_draped_mesh_against_the_budget_before_any_work(tmp_path, capsys, monkeypatch,
                                                                                   interval):
    """The render's copies of the draped mesh count against --memory-budget too (render._check_render_budget's
    mesh term), but texture --png checked only the window and the texture before the work: a budget they fit and
    the mesh's copies do not composed the texture, draped and stepped the mesh, then was refused by the library.
    Now the DEM's surface (at least that, stepped by --interval) is checked with them once the DEM is read: exit 2
    naming the faces and how to make the mesh smaller, before the texture is composed; nothing written."""
    from stepterrain import texture

    def no_compose(*args, **kwargs):
        raise AssertionError("the texture was composed before the render's mesh was checked")

    monkeypatch.setattr(texture, "_composed_pair", no_compose)
    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((80, 80)) * 100)
    textured = render._render_bytes(64, 48, texels=80 * 80)
    with_mesh = render._render_bytes(64, 48, texels=80 * 80, vertices=80 * 80, faces=2 * 79 * 79)
    assert 2 * textured < with_mesh  # the mesh's copies weigh most
    budget = (textured + with_mesh) // 2  # the window and the texture fit, the mesh's copies not
    out, png = tmp_path / "t.png", tmp_path / "r.png"
    code = main(["--memory-budget", str(budget), "texture", str(dem), "-o", str(out), "--png", str(png),
                 "--size", "64x48", "--device", "cpu"] + (["--interval", interval] if interval else []))
    err = capsys.readouterr().err
    at_least = "at least " if interval else ""
    assert code == 2 and ("an off-screen render of 64 x 48 pixels (--size 64x48) of a mesh with a 80 x 80 texel "
                          f"texture and of {at_least}12,482 faces and 6,400 vertices would need") in err, err
    more = "a larger --interval, " if interval else ""
    assert f"give {more}--coarsen N or a --crop, or leave --png out (its copies for rendering grow" in err, err
    assert "topographic texture" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dem.npy"]


def test_hypsometric_colours_of_a_reversed_cmap_are_its_land_part_reversed():
    """--colormap terrain_r: the texture's hypsometric colours are terrain's land part reversed (stepped.land_range),
    not the whole reversed map, whose last quarter (sea blue) fell on the highest ground."""
    import matplotlib

    import stepterrain as st
    from stepterrain._cli_texture import _hypsometric

    terrain = st.sample_dem()
    table = matplotlib.colormaps["terrain"]
    step = np.abs(np.diff(table(np.linspace(0, 1, 257)), axis=0)).max()  # one of its 256 table entries
    lo, hi = terrain.finite_height_range
    scaled = np.clip((terrain.heights - lo) / (hi - lo), 0, 1)
    finite = np.isfinite(terrain.heights)
    reference = table(0.25 + 0.75 * (1.0 - np.where(finite, scaled, 0.0)))  # independent: the forward map's land part
    got = _hypsometric(terrain, "terrain_r")
    assert np.abs(got[finite] - reference[finite]).max() <= step + 1e-6
    top = got[np.unravel_index(np.nanargmax(terrain.heights), terrain.heights.shape)]
    assert not (top[2] > top[0] + 0.15 and top[2] > top[1]), f"the highest ground is sea blue: {top}"


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_cli_texture_png_without_output_writes_the_render_alone(tmp_path, small_dem, capsys):
    """A user who wants only the picture of the draped texture: ``texture --png render.png`` without ``-o`` was refused
    (-o was required, so a texture file came along unasked), as ``steps`` and ``globe`` take --png alone. It renders
    and writes the PNG alone, the same picture as beside ``-o``."""
    args = ["texture", str(small_dem), "--shadows", "--interval", "20", "--size", "64x48", "--device", "cpu"]
    alone = tmp_path / "alone"
    alone.mkdir()
    assert main([*args, "--png", str(alone / "render.png")]) == 0, capsys.readouterr().err
    assert "writing None" not in capsys.readouterr().err
    assert [p.name for p in alone.iterdir()] == ["render.png"]
    pixels = read_png(alone / "render.png")
    assert pixels.shape[:2] == (48, 64) and len(np.unique(pixels.reshape(-1, pixels.shape[2]), axis=0)) > 10
    assert main(["-q", *args, "-o", str(tmp_path / "t.png"), "--png", str(tmp_path / "r.png")]) == 0
    np.testing.assert_array_equal(read_png(tmp_path / "r.png"), pixels)


def test_cli_texture_mesh_without_output_writes_the_draped_mesh_alone(tmp_path, small_dem, capsys):
    """``texture --mesh draped.glb`` without ``-o`` was refused: the GLB embeds the texture, and a separate texture
    file was forced on the user. It writes the draped mesh alone, its texture the one ``-o`` writes."""
    mesh = tmp_path / "draped.glb"
    args = ["texture", str(small_dem), "--shadows", "--device", "cpu", "-q"]
    assert main([*args, "--mesh", str(mesh)]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["draped.glb", "hill.npy"]
    back = trimesh.load(mesh, force="mesh", process=False)
    assert isinstance(back.visual, trimesh.visual.TextureVisuals) and len(back.faces) == 2 * 39 * 49
    assert main([*args, "-o", str(tmp_path / "t.png")]) == 0, capsys.readouterr().err
    np.testing.assert_array_equal(np.asarray(back.visual.material.baseColorTexture.convert("RGB")),
                                  read_png(tmp_path / "t.png"))


def test_cli_texture_without_any_output_is_a_usage_error(tmp_path, capsys):
    """-o/--output is optional with --mesh or --png; with none of them (--normals alone included: it is written
    beside the texture) the run has nothing to write: exit 2 with one line naming them, before any work (a DEM that
    does not exist is not looked at), nothing written."""
    expected = ("stepterrain texture: error: give -o/--output OUT.png|OUT.tif (the texture), --png OUT.png (a render "
                "of the draped texture) or --mesh OUT (the texture draped on a mesh), or several of them; got none")
    dem = str(tmp_path / "missing.npy")
    assert main(["texture", dem, "--shadows"]) == 2
    assert capsys.readouterr().err == expected + "\n"
    normals = str(tmp_path / "n.png")
    assert main(["texture", dem, "--normals", normals]) == 2
    assert capsys.readouterr().err == f"{expected} (--normals {normals!r} is written beside them, not alone)\n"
    assert list(tmp_path.iterdir()) == []


def test_cli_texture_normals_leaves_a_bad_output_s_message_as_it_was(tmp_path, capsys):
    """With --normals, the refusal of a bad -o or --png (an unknown extension) gained "(--normals ... is written
    beside them, not alone)", a note for a run with none of -o, --mesh and --png, false there: the -o or --png given
    is refused for its extension, and --normals is written beside it. The message is the one without --normals."""
    dem = str(tmp_path / "missing.npy")
    normals = ["--normals", str(tmp_path / "n.png")]
    for bad in (["-o", str(tmp_path / "t.jpg")], ["--png", str(tmp_path / "r.jpg")],
                ["-o", str(tmp_path / "t.png"), "--png", str(tmp_path / "r.jpg")]):
        assert main(["texture", dem, "--shadows", *bad]) == 2
        alone = capsys.readouterr().err
        assert "unknown extension '.jpg'" in alone, alone
        assert main(["texture", dem, "--shadows", *bad, *normals]) == 2
        assert capsys.readouterr().err == alone
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("rows, cols", [(190, 80), (430, 609), (643, 1197)])
def test_cli_texture_image_over_a_sliver_of_the_dem_warns_with_the_fraction_and_both_extents(tmp_path, capsys,
                                                                                               rows, cols):
    """--image GEOTIFF over the north-west corner of the Big Tujunga DEM (its own grid and CRS), covering 2 %, 34 %
    and all of it: under 10 % a warning names --image, the fraction of the DEM it covers (rows x cols of its 643 x
    1197 nodes) and both extents, so a wrong CRS or swapped extent is noticed (it was drawn without a word); the
    texture is the same either way (the image's pixels there, the plain texture elsewhere), and a larger image is
    drawn silently."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF images need rasterio")

    from stepterrain import load_dem
    from stepterrain.texture import terrain_extent

    from .conftest import shared_file

    source = shared_file(TUJUNGA)
    with rasterio.open(source) as dem:
        transform, crs = dem.transform, dem.crs
    image = write_geotiff(tmp_path / "ortho.tif", coded_pixels(rows, cols), transform, crs)
    draped = texture_of(tmp_path, "draped", str(source), "--image", str(image))
    err = capsys.readouterr().err
    fraction = rows * cols / (643 * 1197)
    if fraction < 0.1:
        x0, y1 = transform @ (0, 0)
        x1, y0 = transform @ (cols, rows)
        assert (f"stepterrain texture: warning: --image {str(image)!r} covers only {100 * fraction:.3g} % of the "
                f"terrain: its extent {(x0, x1, y0, y1)}, the terrain's {terrain_extent(load_dem(source))}") in err
        assert "--image-extent" in err and "extent=" not in err, err
    else:
        assert err == ""
    plain = texture_of(tmp_path, "plain", str(source))
    off = np.ones(draped.shape[:2], bool)
    off[:rows, :cols] = False
    assert np.array_equal(draped[off], plain[off])  # outside the image: the texture without it
    assert np.abs(draped[:rows, :cols] - plain[:rows, :cols]).max() > 50


def test_image_layer_over_a_sliver_of_the_terrain_warns_at_the_callers_line():
    """image_layer (the library call behind --image): an image placed by extent= over a corner of the Big Tujunga
    DEM that covers 1 % of it warns once, with the fraction and both extents, pointing at the caller's line; one
    covering 20 % does not; one wholly off it is refused naming both extents."""
    import warnings

    from stepterrain import load_dem
    from stepterrain.texture import terrain_extent
    from stepterrain.texture_lod import image_layer

    from .conftest import shared_file

    terrain = load_dem(shared_file(TUJUNGA))
    xmin, xmax, ymin, ymax = terrain_extent(terrain)
    width, height = xmax - xmin, ymax - ymin
    sliver = (xmax - 0.1 * width, xmax + width, ymin - height, ymin + 0.1 * height)  # 1 % of it, mostly beyond it
    with pytest.warns(UserWarning, match=r"^the image covers only 1 % of the terrain: its extent ") as caught:
        layer = image_layer(coded_pixels(64, 64), terrain, extent=sliver, device="cpu")
    assert len(caught) == 1 and caught[0].filename == __file__
    assert f"its extent {sliver}, the terrain's {(xmin, xmax, ymin, ymax)}" in str(caught[0].message)
    assert layer.border == "transparent"  # the rest of the terrain: transparent, the layers beneath showing
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        image_layer(coded_pixels(64, 64), terrain, extent=(xmin, xmin + 0.2 * width, ymin, ymax), device="cpu")
    with pytest.raises(InvalidInputError, match=r"does not overlap the terrain's \(376313"):
        image_layer(coded_pixels(64, 64), terrain, extent=(xmax, xmax + width, ymin, ymax), device="cpu")


@pytest.mark.parametrize("alias", ["link to the file", "link to the folder"])
def test_cli_texture_outputs_through_a_symlink_are_one_file(tmp_path, small_dem, capsys, alias):
    """Two outputs that name one file through a symbolic link (a link to the -o file, or a folder reached by a
    link) were both written: the render replaced the texture, exit 0, and the texture was lost. Refused before
    any work, as two spellings of one path are."""
    out = tmp_path / "t.png"
    if alias == "link to the file":
        out.write_bytes(b"")  # an existing file the link points at (the texture replaces it)
        (tmp_path / "link.png").symlink_to(out)
        png = tmp_path / "link.png"
    else:
        (tmp_path / "linked").symlink_to(tmp_path, target_is_directory=True)
        png = tmp_path / "linked" / "t.png"
    assert main(["texture", str(small_dem), "-o", str(out), "--png", str(png)]) == 2
    assert "--output and --png name the same file" in capsys.readouterr().err
    assert not out.exists() or out.stat().st_size == 0


def test_cli_texture_obj_side_image_through_a_linked_folder_is_refused(tmp_path, small_dem, capsys):
    """--mesh x.obj writes x_terrain_texture.png beside it: -o naming that file through a folder reached by a
    symbolic link was written, then replaced by the OBJ's image (exit 0). Refused as the plain name is."""
    (tmp_path / "linked").symlink_to(tmp_path, target_is_directory=True)
    out = tmp_path / "linked" / "x_terrain_texture.png"
    assert main(["texture", str(small_dem), "-o", str(out), "--mesh", str(tmp_path / "x.obj")]) == 2
    assert "which is what --output names" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "x.obj").exists()


def test_texture_occlusion_over_the_budget_is_refused_before_the_shading(tmp_path, capsys, monkeypatch):
    """With --occlusion the topographic layer takes 33 bytes a DEM node (28.2 to 30.8 measured as peak RSS), more than
    the texture's RGBA (22) that was the command's only up-front check: a budget between them let the shading start
    (then topographic_layer refused it, minutes into a large DEM). Now refused once the DEM is loaded, naming the
    layer."""
    from stepterrain import texture as tx

    dem = tmp_path / "dem.npy"
    np.save(dem, np.random.default_rng(0).random((40, 50)).astype(np.float32) * 100)
    out = tmp_path / "t.png"
    shade = tx.topographic_layer

    def no_shading(*args, **kwargs):
        raise AssertionError("the texture was shaded before the memory budget was checked")

    monkeypatch.setattr(tx, "topographic_layer", no_shading)
    budget = tx._RGBA_BYTES * 40 * 50  # holds the RGBA, not the occlusion's working memory
    code = main(["texture", str(dem), "--occlusion", "0.5", "-o", str(out), "--device", "cpu", "--memory-budget",
                 str(budget)])
    err = capsys.readouterr().err
    assert code == 2 and "the topographic layer of a 50 x 40 DEM" in err and "--memory-budget" in err, err
    assert not out.exists()
    monkeypatch.setattr(tx, "topographic_layer", shade)
    assert main(["texture", str(dem), "-o", str(out), "--device", "cpu", "-q", "--memory-budget", str(budget)]) == 0
