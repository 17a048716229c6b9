"""The ``stepterrain globe`` subcommand and examples/globe.py, run in-process at tiny sizes."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from stepterrain import render
from stepterrain.cli import main
from stepterrain.errors import InvalidInputError

AVAILABLE, REASON = render.offscreen_available()


def test_globe_writes_a_mesh(tmp_path, capsys):
    out = tmp_path / "globe.ply"
    assert main(["-q", "globe", "--face-size", "17", "--error", "0", "--no-camera", "-o", str(out),
                 "--device", "cpu"]) == 0
    mesh = trimesh.load(out, process=False)
    assert len(mesh.faces) == 12 * 16**2
    assert mesh.is_watertight


def test_globe_from_an_npz_grid(tmp_path):
    grid = tmp_path / "grid.npz"
    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    np.savez(grid, elevation=np.zeros((180, 360), np.float32), lat=lat, lon=lon)
    out = tmp_path / "g.obj"
    assert main(["-q", "globe", str(grid), "--face-size", "9", "--eye", "0,0,1e7", "-o", str(out)]) == 0
    assert out.stat().st_size > 0


def globe_ply(source, tmp_path, capsys):
    """The whole globe of ``source`` (face size 9, no camera, every node) written as PLY by the CLI and read back."""
    out = tmp_path / f"{Path(source).name}.ply"
    code = main(["-q", "globe", str(source), "--face-size", "9", "--no-camera", "--error", "0", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    return trimesh.load(out, process=False)


def test_globe_from_a_geotiff_in_degrees(tmp_path, capsys):
    """A global GeoTIFF (ETOPO, GEBCO: the GIS user's global grid) was refused as "INPUT must be a .npz". It is read as
    load_dem reads it (here scale and offset), its node degrees from its geotransform, longitudes 0..360 or
    -180..180, north-up or south-up: the same mesh as the .npz of the same grid. A projected GeoTIFF and nodata
    cells are refused."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    z = (np.add.outer(np.arange(18), np.arange(36)) % 50 * 100).astype(np.int16)  # metres / 10 below, + 5 m
    lat, lon = 85.0 - 10.0 * np.arange(18), 5.0 + 10.0 * np.arange(36)

    def geotiff(name, data, transform, crs="EPSG:4326", nodata=None):
        path = tmp_path / name
        with rasterio.open(path, "w", driver="GTiff", width=36, height=18, count=1, dtype="int16", crs=crs,
                           transform=transform, nodata=nodata) as ds:  # fmt: skip
            ds.write(data, 1)
            ds.scales, ds.offsets = (10.0,), (5.0,)
        return path

    def mesh(source):
        return globe_ply(source, tmp_path, capsys)

    grid = tmp_path / "grid.npz"
    np.savez(grid, elevation=z * 10.0 + 5.0, lat=lat, lon=lon)
    expected = mesh(grid)
    for path in (geotiff("east.tif", z, Affine(10.0, 0.0, 0.0, 0.0, -10.0, 90.0)),  # longitudes 0..360
                 geotiff("south_up.tif", z[::-1], Affine(10.0, 0.0, 0.0, 0.0, 10.0, -90.0))):
        got = mesh(path)
        assert np.allclose(got.vertices, expected.vertices, rtol=0, atol=1e-3) and np.array_equal(got.faces,
                                                                                                  expected.faces)
    west = np.roll(z, 18, axis=1)  # the same grid in longitudes -180..180
    got = mesh(geotiff("west.tif", west, Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0)))
    assert np.allclose(got.vertices, expected.vertices, rtol=0, atol=1e-3)

    projected = geotiff("utm.tif", z, Affine(30.0, 0.0, 500000.0, 0.0, -30.0, 4000000.0), crs="EPSG:32611")
    holes = z.copy()
    holes[3, 4] = -32768
    holes_tif = geotiff("holes.tif", holes, Affine(10.0, 0.0, 0.0, 0.0, -10.0, 90.0), nodata=-32768)
    # the nodata cells: named as the INPUT's, with what to do (was "elevation has 1 NaN or infinite value", the
    # array's words, naming no INPUT; see test_globe_of_a_raster_with_nodata_cells_names_the_input_and_the_fix)
    for path, message in [(projected, "must be a raster in a geographic CRS (degrees: EPSG:4326); got CRS EPSG:32611"),
                          (holes_tif, f"INPUT {str(holes_tif)!r} has 1 nodata cell (first at row 3, column 4)")]:
        assert main(["globe", str(path), "--face-size", "9", "-o", str(tmp_path / "x.glb")]) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "x.glb").exists()


def test_globe_from_other_rasters_in_degrees_as_load_dem_reads_them(tmp_path, capsys):
    """load_dem reads every GDAL raster of io.GDAL_FORMATS (.asc, .img, .vrt, ...); the globe took only a GeoTIFF and
    refused an ESRI ASCII grid or a VRT of a global grid as "must be a .npz". Each gives the .npz's mesh."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    z = (np.add.outer(np.arange(18), np.arange(36)) % 50 * 100).astype(np.float32)
    lat, lon = 85.0 - 10.0 * np.arange(18), 5.0 + 10.0 * np.arange(36)
    transform = Affine(10.0, 0.0, 0.0, 0.0, -10.0, 90.0)

    def mesh(source):
        return globe_ply(source, tmp_path, capsys)

    grid = tmp_path / "grid.npz"
    np.savez(grid, elevation=z, lat=lat, lon=lon)
    expected = mesh(grid)
    tif = tmp_path / "g.tif"
    for path, driver in ((tmp_path / "g.asc", "AAIGrid"), (tmp_path / "g.img", "HFA"), (tif, "GTiff")):
        with rasterio.open(path, "w", driver=driver, width=36, height=18, count=1, dtype="float32",
                           crs="EPSG:4326", transform=transform) as ds:  # fmt: skip
            ds.write(z, 1)
    vrt = tmp_path / "g.vrt"
    vrt.write_text("""<VRTDataset rasterXSize="36" rasterYSize="18"><SRS>EPSG:4326</SRS>
<GeoTransform>0, 10, 0, 90, 0, -10</GeoTransform><VRTRasterBand dataType="Float32" band="1"><SimpleSource>
<SourceFilename relativeToVRT="1">g.tif</SourceFilename><SourceBand>1</SourceBand></SimpleSource></VRTRasterBand>
</VRTDataset>""")
    for path in (tmp_path / "g.asc", tmp_path / "g.img", vrt):
        got = mesh(path)
        assert np.allclose(got.vertices, expected.vertices, rtol=0, atol=1e-3), path.name
        assert np.array_equal(got.faces, expected.faces)
    bad = tmp_path / "g.txt"
    bad.write_text("x")
    assert main(["globe", str(bad), "--face-size", "9", "-o", str(tmp_path / "x.glb")]) == 2
    assert "or a raster in degrees (.tif .tiff .asc" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--face-size", "100"], "--face-size must be 2"),
        (["--bounds", "box"], "invalid choice"),
        (["--metrics", "geometric,screen"], "metrics must be"),
        (["--metrics", ""], "--metrics must be names among geometric, distance, clip separated by commas; got ''"),
        (["--metrics", "geometric,,clip"], "got 'geometric,,clip' (an empty name)"),
        (["--error", "-1"], "error must be"),
        (["--eye", "95,0,1e6"], "latitude must lie"),
        (["--eye", "0,0,-1e7"], "--eye 0,0,-1e+07 lies below the terrain there (the altitude is metres above the "
                                "sphere of --radius): the eye at or beyond the planet's centre"),
        (["--eye", "0,0,1e300"], "--eye altitude must keep the eye within 1e+30 m of the centre"),  # "Camera eye"
        (["--radius", "1e300"], "radius must be at most 8.5e+37 m (float32 node positions); got 1e+300"),
        (["missing.npz"], "does not exist"),
    ],
)
def test_globe_bad_input_exits_2(tmp_path, capsys, argv, message):
    status = main(["globe", *argv, "--face-size" if "--face-size" not in argv else "--radius",
                   "9" if "--face-size" not in argv else "6371000", "-o", str(tmp_path / "x.glb")])
    assert status == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.glb").exists()


@pytest.mark.parametrize("argv, message", [
    (["--face-size", "100"], "--face-size must be 2^k + 1 with k >= 1 (3, 5, 9, ..., 1025); got 100"),
    (["--radius", "-1"], "--radius must be a positive finite number; got -1.0"),
    (["--radius", "1e39"], "--radius must be at most 8.5e+37 m (float32 node positions); got 1e+39"),
    (["--radius", "1e-50"], "--radius must be at least 1.18e-38 m (a normal float32, as the node positions are "
                            "stored); got 1e-50"),
    (["--exaggeration", "0"], "--exaggeration must be a positive finite number; got 0.0"),
    (["--exaggeration", "1e-40"], "--exaggeration must be at least 1.18e-38 (a normal float32, as the kernels take "
                                  "it); got 1e-40"),
    (["--error", "nan"], "--error must be a finite number >= 0 (metres); got nan"),
    (["--heading", "nan"], "--heading must be a finite number; got nan"),
])
def test_globe_numbers_are_refused_before_the_grid_is_loaded(tmp_path, capsys, monkeypatch, argv, message):
    """--face-size 100, a --radius, --exaggeration, --error or --heading the library refuses whatever the grid were
    refused only after the whole lat/lon grid had been read (a global GeoTIFF: minutes); now before, with the same
    message. Without the bad value the grid is loaded."""
    import stepterrain.globe as globe_module

    loads = []

    def relief():
        loads.append(1)
        raise InvalidInputError("the grid was loaded")

    monkeypatch.setattr(globe_module, "load_global_relief", relief)
    status = main(["-q", "globe", *argv, "-o", str(tmp_path / "x.glb")])
    assert status == 2
    assert capsys.readouterr().err.strip() == f"stepterrain globe: error: {message}"
    assert loads == [] and list(tmp_path.iterdir()) == []
    assert main(["-q", "globe", "-o", str(tmp_path / "x.glb")]) == 2
    assert "the grid was loaded" in capsys.readouterr().err and loads == [1]


@pytest.mark.parametrize(
    "content, message",
    [
        (b"", r"cannot read '.*grid.npz' as \.npz: No data left in file"),
        (b"PK\x03\x04garbage", r"cannot read '.*grid.npz' as \.npz: File is not a zip file"),
        (b"npy", r"'.*grid.npz' must be an \.npz archive with arrays 'elevation', 'lat' and 'lon'; got one \.npy"),
        (b"other", r"'.*grid.npz' must hold arrays 'elevation', 'lat' and 'lon'; missing 'lat', 'lon'$"),
        (b"dir", r"INPUT '.*grid.npz' is not a file"),
    ],
)
def test_globe_bad_npz_exits_2_with_one_line(tmp_path, capsys, content, message):
    grid = tmp_path / "grid.npz"
    if content == b"npy":
        with grid.open("wb") as fh:
            np.save(fh, np.zeros((4, 8)))
    elif content == b"other":
        np.savez(grid, elevation=np.zeros((4, 8)))
    elif content == b"dir":
        grid.mkdir()
    else:
        grid.write_bytes(content)
    assert main(["-q", "globe", str(grid), "--face-size", "9", "-o", str(tmp_path / "x.glb")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert re.search(message, err.removeprefix("stepterrain globe: error: ")), err


def test_globe_help_has_examples(capsys):
    assert main(["globe", "--help"]) == 0
    assert "examples:" in capsys.readouterr().out


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_globe_png(tmp_path):
    out, png = tmp_path / "globe.glb", tmp_path / "globe.png"
    assert main(["-q", "globe", "--face-size", "33", "--error", "500", "-o", str(out), "--png", str(png),
                 "--size", "160x100"]) == 0
    from PIL import Image

    with Image.open(png) as image:
        pixels = np.asarray(image)
    assert pixels.shape[:2] == (100, 160) and pixels.std() > 5


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_globe_png_without_output_writes_the_render_alone(tmp_path, capsys):
    """A user who wants only the picture: ``globe --png out.png`` without ``-o`` was refused (-o was required). It
    builds, renders and writes the PNG, and no mesh file."""
    png = tmp_path / "globe.png"
    code = main(["globe", "--face-size", "5", "--error", "0", "--png", str(png), "--size", "64x48",
                 "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert [p.name for p in tmp_path.iterdir()] == ["globe.png"]
    from PIL import Image

    with Image.open(png) as image:
        assert image.format == "PNG" and image.size == (64, 48)
        pixels = np.asarray(image.convert("RGB")).reshape(-1, 3)
    assert len(np.unique(pixels, axis=0)) > 1  # a picture of the globe, not one flat colour
    assert f"writing {png}" in err and "writing None" not in err, err


def test_globe_without_output_or_png_is_a_usage_error(tmp_path, capsys, monkeypatch):
    """-o/--output is optional with --png; with neither, the run has nothing to write: exit 2 naming both options,
    before any work (the grid is not loaded), nothing written."""
    import stepterrain.globe as globe_module

    monkeypatch.setattr(globe_module, "load_global_relief", lambda: pytest.fail("the grid was loaded"))
    monkeypatch.chdir(tmp_path)
    assert main(["globe", "--face-size", "5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("stepterrain globe: error: give -o/--output OUT (the mesh file), --png OUT.png (a render) or "
                   "both; got neither")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_example_globe(tmp_path):
    path = Path(__file__).resolve().parents[1] / "examples" / "globe.py"
    spec = importlib.util.spec_from_file_location("example_globe", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    assert example.__doc__ and "cone frustums against spheres" in example.__doc__
    out = tmp_path / "globe.png"
    assert example.main(["--size", "33", "--panel", "160", "100", "--output", str(out), "--device", "cpu"]) == 0
    from PIL import Image

    with Image.open(out) as image:
        pixels = np.asarray(image)
    assert pixels.shape[:2] == (200, 320)
    assert pixels[:100].std() > 5 and pixels[100:].std() > 5


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_example_adaptive_mesh(tmp_path, capsys):
    path = Path(__file__).resolve().parents[1] / "examples" / "adaptive_mesh.py"
    spec = importlib.util.spec_from_file_location("example_adaptive_mesh", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    assert example.__doc__ and "true vertical error bound" in example.__doc__
    out = tmp_path / "adaptive.png"
    argv = ["--size", "33", "--errors", "20", "2", "--panel", "120", "100", "--output", str(out), "--device", "cpu"]
    assert example.main(argv) == 0
    from PIL import Image

    with Image.open(out) as image:
        pixels = np.asarray(image)
    assert pixels.shape[:2] == (100, 240) and pixels.std() > 5
    terrain = example.crop(33)
    from stepterrain.globe import adaptive_mesh

    for error in (20.0, 2.0):
        assert example.true_error(adaptive_mesh(terrain, error=error), terrain) <= error


def test_globe_texture_is_embedded_in_the_glb(tmp_path):
    image = np.zeros((32, 64, 3), np.uint8)
    image[:, :32] = (200, 30, 30)
    picture = tmp_path / "earth.png"
    from PIL import Image

    Image.fromarray(image).save(picture)
    out = tmp_path / "textured.glb"
    assert main(["-q", "globe", "--face-size", "17", "--error", "0", "--no-camera", "--texture", str(picture),
                 "-o", str(out)]) == 0
    back = trimesh.load(out, force="mesh", process=False)
    assert isinstance(back.visual, trimesh.visual.TextureVisuals)
    assert back.visual.material.baseColorTexture.size == (64, 32)
    assert len(back.faces) == 12 * 16**2 and len(back.visual.uv) == len(back.vertices)


def test_globe_texture_file_with_transparent_nodata_keeps_its_alpha(tmp_path):
    """An RGBA PNG --texture whose eastern half is nodata (alpha 0, black): the .ply's vertex colours were opaque
    black there (the file was read as RGB, its alpha dropped, and drape_colors set alpha 255), and the .glb's
    texture was opaque. Both keep its alpha now, as an RGBA array given to drape_texture keeps it."""
    from PIL import Image

    from stepterrain.export import read_mesh

    image = np.zeros((32, 64, 4), np.uint8)
    image[:, :32] = (200, 30, 30, 255)
    Image.fromarray(image).save(tmp_path / "overlay.png")
    argv = ["-q", "globe", "--face-size", "17", "--error", "0", "--no-camera", "--texture",
            str(tmp_path / "overlay.png")]
    assert main([*argv, "-o", str(tmp_path / "earth.ply")]) == 0
    mesh = read_mesh(tmp_path / "earth.ply")
    colours = np.asarray(mesh.visual.vertex_colors)
    lon = np.degrees(np.arctan2(mesh.vertices[:, 1], mesh.vertices[:, 0]))
    assert (colours[(lon > 10) & (lon < 170), 3] == 0).all()
    assert (colours[(lon < -10) & (lon > -170)] == (200, 30, 30, 255)).all()
    assert main([*argv, "-o", str(tmp_path / "earth.glb")]) == 0
    texture = trimesh.load(tmp_path / "earth.glb", force="mesh", process=False).visual.material.baseColorTexture
    texture = np.asarray(texture.convert("RGBA"))
    np.testing.assert_array_equal(texture[..., 3], image[..., 3])
    np.testing.assert_array_equal(texture[:, :32], image[:, :32])
    # the nodata's colour is that of the opaque texels near it (io.fill_transparent), not a fringe of black
    np.testing.assert_array_equal(texture[:, 32:, :3], np.broadcast_to((200, 30, 30), (32, 32, 3)))


@pytest.mark.parametrize("texture", ["missing.png", "folder", "notes.png", "dot.png", "ppm.png", "bomb.png"])
def test_globe_texture_is_checked_before_the_work(tmp_path, capsys, monkeypatch, texture):
    """--texture was read only after the globe was built and meshed: a missing file, a folder, a text file or an
    image too small to drape failed after that work. It is read first now; the globe is never built. A 1 x 1 RGB
    image was refused as not "an (H, W, 3|4) image": the message now says it needs 2 x 2 pixels. A file whose header
    Pillow refuses with a ValueError (a PPM cut short) was a traceback, and so was one past Pillow's decompression-bomb
    limit (a PNG header of the full 21600 x 10800 Blue Marble): its DecompressionBombError is no OSError either."""
    import struct
    import zlib

    from PIL import Image

    from stepterrain import globe

    (tmp_path / "folder").mkdir()
    (tmp_path / "notes.png").write_text("not an image")
    Image.fromarray(np.zeros((1, 1, 3), np.uint8)).save(tmp_path / "dot.png")
    (tmp_path / "ppm.png").write_bytes(b"P6\n")  # a PPM header cut short: Pillow's ValueError, a traceback

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", 21600, 10800, 8, 2, 0, 0, 0)  # 233 Mpx of RGB: the header alone
    (tmp_path / "bomb.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IEND", b""))

    def built(*args, **kwargs):
        raise AssertionError("the globe was built before --texture was read")

    monkeypatch.setattr(globe.Globe, "from_latlon", built)
    path = tmp_path / texture
    assert main(["-q", "globe", "--face-size", "9", "--texture", str(path), "-o", str(tmp_path / "x.glb")]) == 2
    err = capsys.readouterr().err.strip()
    expected = ("--texture must be an (H, W, 3|4) image of at least 2 x 2 pixels; got shape (1, 1, 3)"
                if texture == "dot.png" else f"cannot read texture {str(path)!r}: ")
    assert err.startswith(f"stepterrain globe: error: {expected}") and "\n" not in err
    assert ("decompression-bomb limit" in err) == (texture == "bomb.png"), err


@pytest.mark.parametrize("elevation", [np.float32(1.0), np.zeros(360, np.float32), np.zeros((2, 180, 360))])
def test_globe_npz_elevation_not_2d_exits_2(tmp_path, capsys, elevation):
    grid = tmp_path / "grid.npz"
    np.savez(grid, elevation=elevation, lat=np.linspace(89.5, -89.5, 180), lon=np.linspace(-179.5, 179.5, 360))
    assert main(["-q", "globe", str(grid), "--face-size", "5", "-o", str(tmp_path / "x.glb")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"stepterrain globe: error: {str(grid)!r}: 'elevation' must be a 2-D (H, W) array; got shape "
                   f"{np.shape(elevation)}")


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_globe_view_angle_sets_the_eye_s_field_of_view(tmp_path, capsys):
    """The globe command placed its eye (--eye, --tilt, --heading) but had no field of view: the mesh was always
    refined and culled for, and the --png rendered at, look_from's 30 degrees. --view-angle sets it: a narrower view
    keeps fewer triangles and its render sees a smaller part of the globe (the whole globe from 3 R at 30 degrees, a
    patch filling the picture at 10); the default is 30 as before; a bad one is named."""
    from PIL import Image

    def run(*extra: str) -> tuple[int, np.ndarray]:
        out, png = tmp_path / "g.ply", tmp_path / "g.png"
        assert main(["-q", "globe", "--face-size", "33", "--error", "500", "-o", str(out), "--png", str(png),
                     "--size", "160x100", "--device", "cpu", *extra]) == 0
        with Image.open(png) as image:
            return len(trimesh.load(out, process=False).faces), np.asarray(image)

    faces30, wide = run()
    assert run("--view-angle", "30")[0] == faces30
    faces10, narrow = run("--view-angle", "10")
    assert faces10 < faces30
    space = lambda image: (image.max(axis=2) < 8).mean()  # noqa: E731 - black sky round the globe
    assert space(wide) > 0.2 and space(narrow) < 0.05
    for bad in ("0", "180", "nan"):
        assert main(["globe", "--face-size", "9", "--view-angle", bad, "-o", str(tmp_path / "x.glb")]) == 2
        assert f"--view-angle must be a vertical field of view in [1e-08, 179] degrees; got {bad}" \
            in capsys.readouterr().err


@pytest.mark.render
@pytest.mark.skipif(not AVAILABLE, reason=f"no off-screen OpenGL context: {REASON}")
def test_globe_texture_is_drawn_as_a_texture_in_the_png(tmp_path):
    """``globe --texture bluemarble.jpg --png``: the render showed the image as vertex colours, one colour per mesh
    vertex, so from 3000 km over the Mediterranean the coasts were blurred into the triangles of the adaptive mesh
    (hundreds of km wide there). The render now draws the draped texture (the GLB's): it equals the render of the
    written GLB from the same camera, where the .ply run's vertex-coloured mesh differs from it by far more."""
    from stepterrain.export import read_mesh
    from stepterrain.globe import look_from, render_view

    from .conftest import shared_file

    picture = shared_file("earth_day_bluemarble_3840x1920.jpg")
    base = ["-q", "globe", "--texture", str(picture), "--eye", "40,10,3000000", "--size", "320x200",
            "--device", "cpu"]
    assert main([*base, "-o", str(tmp_path / "g.glb"), "--png", str(tmp_path / "g.png")]) == 0
    from PIL import Image

    shot = np.asarray(Image.open(tmp_path / "g.png").convert("RGB")).astype(float)
    camera = look_from(40.0, 10.0, 3000000.0)
    from_glb = render_view(read_mesh(tmp_path / "g.glb"), camera, window_size=(320, 200)).astype(float)
    assert np.abs(shot - from_glb).mean() < 2.0
    assert main([*base, "-o", str(tmp_path / "g.ply")]) == 0
    coloured = read_mesh(tmp_path / "g.ply")
    assert coloured.visual.kind == "vertex"  # the .ply keeps its vertex colours
    blurred = render_view(coloured, camera, window_size=(320, 200)).astype(float)
    assert np.abs(blurred - from_glb).mean() > 4 * max(np.abs(shot - from_glb).mean(), 1.0)


def test_an_inside_out_globe_names_both_options(tmp_path, capsys):
    """``globe --exaggeration 2000`` puts the Mariana Trench through the earth's centre; the refusal said
    "--radius + exaggeration · elevation", naming one option and the library's word for the other."""
    out = tmp_path / "g.ply"
    assert main(["-q", "globe", "--exaggeration", "2000", "--face-size", "9", "-o", str(out), "--device", "cpu"]) == 2
    assert "error: --radius + --exaggeration · elevation must stay > 0" in capsys.readouterr().err
    assert not out.exists()


def test_globe_obj_texture_image_never_replaces_the_texture_given(tmp_path, capsys):
    """``--texture earth_material_0.png -o earth.obj``: the OBJ's texture image, written beside it as
    ``earth_material_0.png``, replaced the picture given, without a word. Refused by name before any work."""
    from PIL import Image

    picture = tmp_path / "earth_material_0.png"
    Image.fromarray(np.full((32, 64, 3), (200, 30, 30), np.uint8)).save(picture)
    before = picture.read_bytes()
    out = tmp_path / "earth.obj"
    assert main(["-q", "globe", "--face-size", "9", "--error", "0", "--no-camera", "--texture", str(picture),
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"--output {str(out)!r} writes 'earth_material_0.png' beside it (its texture image), which is the " \
           "--texture file" in err, err
    assert picture.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [picture.name]
    assert main(["-q", "globe", "--face-size", "9", "--error", "0", "--no-camera", "--texture", str(picture),
                 "-o", str(tmp_path / "globe.obj")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["earth_material_0.png", "globe.mtl", "globe.obj",
                                                          "globe_material_0.png"]
    assert picture.read_bytes() == before


@pytest.mark.skipif(not AVAILABLE, reason=REASON)
def test_globe_png_counts_the_texture_against_the_budget_before_any_work(tmp_path, capsys, monkeypatch):
    """``globe --texture ... --png`` whose --size fitted --memory-budget but not with the draped texture (the render
    counts 16 bytes a texel) loaded the relief, built the globe and meshed it, then refused the render. The texture
    is counted with the window once it is decoded, before any work: exit 2 naming --size and the texture's texels,
    the globe never built, nothing written."""
    from PIL import Image

    from stepterrain import globe

    picture = tmp_path / "earth.png"
    Image.fromarray(np.zeros((100, 200, 3), np.uint8)).save(picture)
    window = render._render_bytes(64, 48)
    with_texture = render._render_bytes(64, 48, texels=100 * 200)
    budget = (window + with_texture) // 2  # the window alone fits

    def built(*args, **kwargs):
        raise AssertionError("the globe was built before the render's budget was checked")

    monkeypatch.setattr(globe.Globe, "from_latlon", built)
    out, png = tmp_path / "g.glb", tmp_path / "g.png"
    code = main(["globe", "--face-size", "9", "--texture", str(picture), "-o", str(out), "--png", str(png),
                 "--size", "64x48", "--memory-budget", str(budget), "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and "an off-screen render of 64 x 48 pixels (--size 64x48) of a mesh with a 200 x 100 texel " \
                         "texture would need" in err, err
    assert not out.exists() and not png.exists()
    # the hint names the command's own way to a smaller texture (it has no texel size, which the hint suggested)
    assert "give a smaller --size or a smaller --texture image (resampled to fewer pixels)" in err, err
    assert "texel size" not in err, err


def test_globe_close_view_glb_is_stored_relative_to_the_eye(tmp_path):
    """A close view's GLB stored its float32 positions relative to the centre of the mesh's bounds, and a view's mesh
    spans thousands of km (the coarse triangles at the border of the view and on the far side, inside the frustum):
    the vertices under an eye 100 m up were read back up to 0.3 m off, a 0.3 m jump of a vertex 5 km from the
    eye. The positions are now stored relative to the eye (its floor, the node translation): each vertex read back
    within float32's rounding of its own distance from the eye, the same fraction of the view everywhere."""
    glb, ply = tmp_path / "close.glb", tmp_path / "close.ply"
    for out in (glb, ply):  # (0, 0): the centre node of the +x cube face lies under the eye
        assert main(["-q", "globe", "--face-size", "65", "--eye", "0,0,100", "--error", "0.5", "-o", str(out),
                     "--device", "cpu"]) == 0
    from stepterrain.export import read_mesh
    stored, exact = read_mesh(glb).vertices, read_mesh(ply).vertices  # the PLY holds the float64 vertices
    assert exact.dtype == np.float64 and stored.shape == exact.shape and np.ptp(exact, axis=0).max() > 1e6
    eye = np.array([6_371_100.0, 0.0, 0.0])
    distance = np.linalg.norm(exact - eye, axis=1)
    assert distance.min() < 10_000.0  # a vertex near the eye
    error = np.linalg.norm(stored - exact, axis=1)
    assert (error <= 2.0**-23 * (distance + 2.0)).all(), float((error / distance).max())


@pytest.mark.parametrize("altitude", ["1e9", "1e12", "1e29"])
def test_a_far_view_glb_is_not_stored_relative_to_its_far_eye(tmp_path, altitude):
    """The CLI stored every view's GLB relative to its eye, however far: float32 positions about an eye 1e12 m away
    round by up to 32 km (the globe's vertices read back from 6,331 to 6,409 km from the centre), and about one
    1e29 m away all 1,538 vertices of a 17² globe became one point, every triangle of the file degenerate. Now the
    eye the mesh records decides as save_mesh's own default does (the eye while within one diagonal of the mesh's
    bounds, else the centre of its bounds): the far view's GLB is the PLY's mesh within float32's rounding of the
    globe's own size, as the library's save_mesh of the same view writes it."""
    glb, ply = tmp_path / "far.glb", tmp_path / "far.ply"
    for out in (glb, ply):
        assert main(["-q", "globe", "--face-size", "17", "--eye", f"46,9,{altitude}", "-o", str(out),
                     "--device", "cpu"]) == 0
    from stepterrain.export import read_mesh
    stored, exact = read_mesh(glb).vertices, read_mesh(ply).vertices
    assert stored.shape == exact.shape and len(np.unique(stored, axis=0)) == len(exact)
    error = np.linalg.norm(stored - exact, axis=1)
    assert error.max() <= 2.0**-23 * np.abs(exact).max(), float(error.max())


def test_a_view_tilted_off_the_globe_names_the_view_options(tmp_path, capsys):
    """A view tilted past the globe's limb sees nothing, and the refusal said only "point the eye at the earth or
    pass --no-cull", naming neither --tilt nor how far the globe lies from straight down. It now names the --eye and
    --tilt given, the limb's angle from straight down (asin((R + highest) / |eye|)) and the largest --tilt that sees
    the globe (that angle plus half the --view-angle), and the options to change; a --tilt below it meshes."""
    out = tmp_path / "g.glb"
    base = ["globe", "--face-size", "9", "--eye", "0,0,20000000", "--view-angle", "30", "-o", str(out),
            "--device", "cpu"]
    assert main([*base, "--tilt", "80"]) == 2
    err = capsys.readouterr().err
    top = 6_371_000.0 + 8_000.0  # the embedded relief's highest node at face size 9 lies below 8 km
    limb = np.degrees(np.arcsin(top / (6_371_000.0 + 2e7)))
    found = re.search(r"the globe lies within ([\d.]+) degrees of straight down.* lower --tilt 80 below "
                      r"([\d.]+) degrees", err)
    assert found and "--eye 0,0,20000000" in err and "--view-angle" in err and "--no-cull" in err, err
    assert abs(float(found[1]) - limb) < 0.2 and abs(float(found[2]) - (limb + 15.0)) < 0.2, err
    assert not out.exists()
    assert main([*base, "--tilt", f"{float(found[2]) - 1.0:.6g}"]) == 0  # just below the bound: sees the globe
    assert main([*base, "--tilt", f"{float(found[2]) + 1.0:.6g}"]) == 2  # just above it: sees nothing


def test_globe_truncated_npz_leaves_no_file_open(tmp_path, capsys):
    """A truncated .npz INPUT (its zip directory cut off) was refused, but np.load, which opened the file itself,
    left it open when zipfile failed on it (a ResourceWarning), as load_dem's reading did before io.open_npz."""
    import gc
    import warnings

    np.savez(tmp_path / "whole.npz", elevation=np.zeros((4, 8)), lat=np.zeros(4), lon=np.zeros(8))
    data = (tmp_path / "whole.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["-q", "globe", str(tmp_path / "cut.npz"), "--face-size", "9", "-o",
                     str(tmp_path / "x.glb")]) == 2
        gc.collect()
    assert "cut.npz' as .npz" in capsys.readouterr().err
    assert [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)] == []


def test_globe_npz_heights_in_the_unit_it_names_become_metres(tmp_path, capsys):
    """The globe read its .npz itself and ignored its 'units' (which load_dem reads): heights in feet were meshed as
    metres, 3.28 times too high. They become metres as load_dem makes them: the globe of 1000 ft is that of
    304.8 m, and a unit that is no length is refused, naming it."""
    lat, lon = np.linspace(-85.0, 85.0, 18), np.linspace(-175.0, 175.0, 36)
    relief = np.add.outer(np.linspace(0.0, 500.0, 18), np.linspace(0.0, 500.0, 36))
    meshes = {}
    for name, heights, units in (("ft", relief, "ft"), ("m", relief * 0.3048, "m"), ("bare", relief * 0.3048, None),
                                 ("numbers", relief, None)):
        extra = {} if units is None else {"units": np.array(units)}
        np.savez(tmp_path / f"{name}.npz", elevation=heights, lat=lat, lon=lon, **extra)
        out = tmp_path / f"{name}.ply"
        assert main(["-q", "globe", str(tmp_path / f"{name}.npz"), "--no-camera", "--face-size", "9",
                     "--device", "cpu", "-o", str(out)]) == 0, capsys.readouterr().err
        meshes[name] = trimesh.load(out, process=False)
    assert np.array_equal(meshes["ft"].faces, meshes["m"].faces)
    assert np.allclose(meshes["ft"].vertices, meshes["m"].vertices, rtol=0.0, atol=1e-3)
    assert np.array_equal(meshes["m"].vertices, meshes["bare"].vertices)
    lifted = {name: np.linalg.norm(meshes[name].vertices, axis=1) - 6_371_000.0 for name in ("ft", "numbers")}
    assert lifted["ft"].max() == pytest.approx(0.3048 * lifted["numbers"].max(), rel=1e-4)  # not the feet as metres
    np.savez(tmp_path / "odd.npz", elevation=relief, lat=lat, lon=lon, units=np.array("parsec"))
    assert main(["-q", "globe", str(tmp_path / "odd.npz"), "--face-size", "9", "-o", str(tmp_path / "x.ply")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("stepterrain globe: error: cannot read ") and "got 'parsec' (its 'units')" in err, err
    assert not (tmp_path / "x.ply").exists()


def test_globe_height_unit_names_a_unit_the_file_lacks_or_overrides(tmp_path, capsys):
    """The globe's refusal of an unknown height unit said "the CLI's --height-unit m", an option globe lacked (exit
    2, "unrecognized arguments"). globe takes --height-unit as steps does: it overrides an .npz 'units' and a GeoTIFF
    band's unit (heights in feet become metres), names a unit for a file that names none, and is refused for the
    embedded relief (metres) before any work."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    lat, lon = np.linspace(-85.0, 85.0, 18), np.linspace(-175.0, 175.0, 36)
    relief = np.add.outer(np.linspace(0.0, 500.0, 18), np.linspace(0.0, 500.0, 36)).astype(np.float32)
    np.savez(tmp_path / "metres.npz", elevation=relief * np.float32(0.3048), lat=lat, lon=lon)
    np.savez(tmp_path / "odd.npz", elevation=relief, lat=lat, lon=lon, units=np.array("parsec"))
    np.savez(tmp_path / "bare.npz", elevation=relief, lat=lat, lon=lon)
    tif = tmp_path / "odd.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=36, height=18, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0)) as ds:  # fmt: skip
        ds.write(relief[::-1], 1)  # north-up rows: latitudes 85 to -85
        ds.units = ("parsec",)

    def radii(source, *extra):
        out = tmp_path / "g.ply"
        assert main(["-q", "globe", str(source), "--no-camera", "--face-size", "9", "--device", "cpu", "-o", str(out),
                     *extra]) == 0, capsys.readouterr().err
        return np.linalg.norm(trimesh.load(out, process=False).vertices, axis=1)

    assert main(["-q", "globe", str(tmp_path / "odd.npz"), "--face-size", "9", "-o", str(tmp_path / "x.ply")]) == 2
    assert "name their unit: --height-unit 'm'" in capsys.readouterr().err  # which it now has
    expected = radii(tmp_path / "metres.npz")
    for source in ("odd.npz", "bare.npz", "odd.tif"):
        assert np.allclose(radii(tmp_path / source, "--height-unit", "ft"), expected, rtol=0.0, atol=1e-3), source
    assert main(["-q", "globe", "--height-unit", "ft", "-o", str(tmp_path / "e.ply")]) == 2
    err = capsys.readouterr().err
    assert "--height-unit applies to an INPUT file; the embedded ETOPO 2022 relief is in metres; got 'ft'" in err, err
    assert main(["-q", "globe", str(tmp_path / "bare.npz"), "--height-unit", "parsec", "-o", str(tmp_path / "y.ply")]) \
        == 2
    assert "argument --height-unit: expected a length unit" in capsys.readouterr().err
    assert not (tmp_path / "e.ply").exists() and not (tmp_path / "y.ply").exists()


#: Mars 2000 as GDAL writes a MOLA/HRSC DEM's CRS (Esri's GEOGCS): its ellipsoid a = 3396190 m, 1/f = 169.894...
_MARS_2000 = ('GEOGCS["Mars 2000",DATUM["D_Mars_2000",SPHEROID["Mars_2000_IAU_IAG",3396190,169.894447223612]],'
              'PRIMEM["Reference_Meridian",0],UNIT["degree",0.0174532925199433]]')


@pytest.mark.parametrize("crs, radius", [
    (_MARS_2000, 3396190.0 * (1.0 - 1.0 / (3.0 * 169.894447223612))),  # its mean radius a·(1 - f/3)
    ("IAU_2015:49900", 3396190.0),  # Mars (2015) sphere
    ("IAU_2015:30100", 1737400.0),  # Moon (2015) sphere: a LOLA DEM
    ("EPSG:4326", 6371000.0),  # the earth's: as before (globe.EARTH_RADIUS)
])
def test_a_globe_of_another_body_is_meshed_on_the_sphere_its_crs_names(tmp_path, capsys, crs, radius):
    """``stepterrain globe mars_mola.tif`` meshed a Mars (or Moon) DEM on the earth's sphere, R = 6371000 m, unless
    --radius was given: Mars 1.88 times too large for its heights, and the default eye 3 earth radii up. Without
    --radius the sphere is now the one load_dem makes the file's degrees metres on (its CRS's ellipsoid's mean
    radius, to the 10 digits load_dem's CRS states), the progress line and the mesh's metadata say which; an .npz's
    'crs' counts too; --radius still rules; an earth CRS keeps 6371000 m, with nothing said."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.export import read_mesh

    radius = float(f"{radius:.10g}")
    tif = tmp_path / "body.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=36, height=18, count=1, dtype="float32", crs=crs,
                       transform=Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0)) as ds:
        ds.write(np.zeros((18, 36), np.float32), 1)
        wkt = ds.crs.to_wkt()
    npz = tmp_path / "body.npz"
    np.savez(npz, elevation=np.zeros((18, 36), np.float32), lat=np.linspace(85.0, -85.0, 18),
             lon=np.linspace(-175.0, 175.0, 36), crs=np.array(wkt))
    for source in (tif, npz):
        out = tmp_path / f"{source.stem}.glb"
        assert main(["globe", str(source), "--face-size", "9", "--error", "0", "-o", str(out), "--device",
                     "cpu"]) == 0
        said = capsys.readouterr().err
        mesh = read_mesh(out)
        np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1), radius, rtol=1e-6)  # float32 positions
        assert mesh.metadata["eye_lat_lon_alt"] == [30.0, 10.0, 3 * radius]  # the default eye: 3 R up
        if radius == 6371000.0:
            assert "radius" not in mesh.metadata and "on a sphere" not in said
        else:
            assert mesh.metadata["radius"] == radius
            assert f"nodes on a sphere of radius {radius:.10g} m (the mean radius of INPUT's CRS's ellipsoid" in said
    given = tmp_path / "given.ply"
    assert main(["-q", "globe", str(tif), "--face-size", "9", "--no-camera", "--radius", "1000000", "-o",
                 str(given), "--device", "cpu"]) == 0
    np.testing.assert_allclose(np.linalg.norm(trimesh.load(given, process=False).vertices, axis=1), 1e6, rtol=1e-6)


def test_an_eye_beyond_the_centre_of_another_body_is_refused_by_its_radius(tmp_path, capsys):
    """An --eye altitude below the centre of the body an INPUT's CRS names (Mars: 3396190 m) but above the earth's was
    taken as an eye inside the earth's sphere; it is refused as beyond the centre of the sphere the globe is meshed
    on, naming that sphere (no --radius was given)."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    tif = tmp_path / "mars.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=36, height=18, count=1, dtype="float32", crs="IAU_2015:49900",
                       transform=Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0)) as ds:
        ds.write(np.zeros((18, 36), np.float32), 1)
    out = tmp_path / "g.ply"
    assert main(["-q", "globe", str(tif), "--face-size", "9", "--eye", "0,0,-4e6", "-o", str(out)]) == 2
    assert capsys.readouterr().err == (
        "stepterrain globe: error: --eye 0,0,-4e+06 lies below the terrain there (the altitude is metres above the "
        "sphere of the radius of INPUT's CRS): the eye at or beyond the planet's centre (altitude <= -3.39619e+06 m, "
        "the radius of INPUT's CRS)\n")
    assert not out.exists()


def test_globe_of_a_raster_with_nodata_cells_names_the_input_and_the_fix(tmp_path, capsys):
    """A global raster with nodata cells was refused as "elevation has 1 NaN or infinite value (first at row 5,
    column 7); fill them first": the words of an array, naming neither the INPUT nor that its nodata cells were the
    NaN. The refusal names the INPUT, counts its nodata cells and gives a gdal_fillnodata.py command for the INPUT
    as given (quoted for the shell: a name with a blank), before any mesh is written."""
    import shlex

    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    z = (np.add.outer(np.arange(18), np.arange(36)) % 50 * 100).astype(np.float32)
    z[5, 7] = z[6, 30] = -9999.0
    path = tmp_path / "my grid.tif"
    with rasterio.open(path, "w", driver="GTiff", width=36, height=18, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0), nodata=-9999.0) as ds:
        ds.write(z, 1)
    out = tmp_path / "x.glb"
    assert main(["-q", "globe", str(path), "--face-size", "9", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stepterrain globe: error: INPUT {str(path)!r} has 2 nodata cells (first at row 5, column "
                          "7); a global grid cannot have holes: fill them first, e.g. gdal_fillnodata.py "), err
    command = err[err.index("gdal_fillnodata.py"):err.index(", and give")]
    assert shlex.split(command) == ["gdal_fillnodata.py", str(path), "filled.tif"]
    assert "NaN" not in err and len(err.strip().splitlines()) == 1 and not out.exists()


def test_globe_nodata_refusal_of_cells_only_nodata_marks_gives_a_fix_that_fills_them(tmp_path, capsys):
    """Cells --nodata marks (a -9999 GDAL does not know as the file's nodata) were refused with the advice
    ``gdal_fillnodata.py grid.tif filled.tif``, which fills only a declared nodata: filled.tif kept its -9999 cells,
    and was refused again. The advice declares --nodata's value first, then fills that file."""
    import shlex

    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    z = (np.add.outer(np.arange(18), np.arange(36)) % 50 * 100).astype(np.float32)
    z[5, 7] = -9999.0
    path = tmp_path / "my grid.tif"
    with rasterio.open(path, "w", driver="GTiff", width=36, height=18, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0)) as ds:  # no nodata declared
        ds.write(z, 1)
    out = tmp_path / "x.glb"
    assert main(["-q", "globe", str(path), "--nodata", "-9999", "--face-size", "9", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stepterrain globe: error: INPUT {str(path)!r} has 1 nodata cell (first at row 5, column "
                          "7; --nodata -9999 marks cells the file does not declare nodata); "), err
    declare = err[err.index("gdal_translate"):err.index(", then")]
    assert shlex.split(declare) == ["gdal_translate", "-a_nodata", "-9999", str(path), "declared.tif"]
    fill = err[err.index("then gdal_fillnodata.py") + 5:err.index(", and give")]
    assert shlex.split(fill) == ["gdal_fillnodata.py", "declared.tif", "filled.tif"]
    assert len(err.strip().splitlines()) == 1 and not out.exists()


def test_the_gdalwarp_a_projected_globe_input_is_refused_with_leaves_no_0_m_cells(tmp_path, capsys, monkeypatch):
    """A raster in a projected CRS is refused by `stepterrain globe` with the gdalwarp that puts it in degrees. As
    said, `gdalwarp -t_srs EPSG:4326`, the cells of the grid in degrees outside the file's (the corners round a UTM
    grid, turned a few degrees) were filled with 0 (the file has no nodata value), and the globe meshed them as
    heights of 0 m without a word. It says -dstalpha now, and names the files: those cells are missing, and the
    globe refuses them as holes to fill, naming the INPUT."""
    import shlex
    import shutil
    import subprocess

    rasterio = pytest.importorskip("rasterio")
    from stepterrain.io import load_dem

    if shutil.which("gdalwarp") is None:
        pytest.skip("gdalwarp (gdal-bin) is not installed")
    heights = (np.add.outer(np.arange(40.0), np.arange(50.0)) * 10.0 + 500.0).astype(np.float32)
    with rasterio.open(tmp_path / "utm.tif", "w", driver="GTiff", width=50, height=40, count=1, dtype="float32",
                       crs="EPSG:32611", transform=rasterio.Affine(30.0, 0.0, 700000.0, 0.0, -30.0, 4000000.0)) as out:
        out.write(heights, 1)
    monkeypatch.chdir(tmp_path)
    assert main(["globe", "utm.tif", "--face-size", "9", "-o", "x.glb"]) == 2
    command = shlex.split(re.search(r"(gdalwarp .*) makes it one", capsys.readouterr().err).group(1))
    subprocess.run([*command, "-q"], check=True, capture_output=True)
    warped = load_dem(command[-1])
    assert warped.has_nodata and np.nanmin(warped.heights) >= heights.min()  # no 0 m cell
    assert main(["globe", command[-1], "--face-size", "9", "-o", "x.glb"]) == 2
    assert f"INPUT {command[-1]!r} has " in capsys.readouterr().err  # holes to fill, not a globe of 0 m there
    assert not (tmp_path / "x.glb").exists()
