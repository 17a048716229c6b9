"""The colour under a texture's transparent texels (alpha 0: `gdalwarp -dstalpha`'s nodata, the polar caps of a Web
Mercator world map warped to EPSG:4326) is garbage; samplers filter straight colour and alpha apart, so it must not
reach a render or an exported texture (:func:`stepterrain.io.fill_transparent`)."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as hst
from PIL import Image

from stepterrain import export, globe
from stepterrain.io import fill_transparent

MAGENTA = (255, 0, 255)
GREEN = (30, 120, 60)


def _world(garbage: tuple[int, int, int] = MAGENTA) -> np.ndarray:
    """A 180 x 90 plate-carrée RGBA world, opaque green, its polar caps (beyond 60°) transparent over ``garbage``."""
    img = np.zeros((90, 180, 4), np.uint8)
    img[..., :3], img[..., 3] = GREEN, 255
    for cap in (slice(0, 15), slice(75, 90)):
        img[cap, :, :3], img[cap, :, 3] = garbage, 0
    return img


@pytest.fixture(scope="module")
def globe_mesh():
    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    return globe.Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=9, device="cpu").mesh()


@settings(max_examples=25, deadline=None)
@given(h=hst.integers(1, 9), w=hst.integers(1, 9), channels=hst.sampled_from([2, 4]), seed=hst.integers(0, 2**31))
def test_fill_transparent_keeps_alpha_and_opaque_texels_and_takes_colours_from_them(h, w, channels, seed):
    rng = np.random.default_rng(seed)
    pixels = rng.integers(0, 256, (h, w, channels), dtype=np.uint8)
    pixels[..., -1] = np.where(rng.random((h, w)) < 0.5, 0, pixels[..., -1])
    out = fill_transparent(pixels)
    assert out.shape == pixels.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(out[..., -1], pixels[..., -1])
    some = pixels[..., -1] > 0
    np.testing.assert_array_equal(out[some], pixels[some])
    if some.any() and not some.all():  # each filled colour a weighted mean of the texels of some alpha
        lo, hi = pixels[some][:, :-1].min(axis=0), pixels[some][:, :-1].max(axis=0)
        filled = out[~some][:, :-1]
        assert (filled >= lo).all() and (filled <= hi).all()


@settings(max_examples=10, deadline=None)
@given(h=hst.integers(1, 23), w=hst.integers(1, 23), band=hst.integers(1, 40), seed=hst.integers(0, 2**31))
def test_fill_transparent_in_bands_of_rows_is_the_whole_fill(h, w, band, seed):
    import stepterrain.io as st_io

    rng = np.random.default_rng(seed)
    pixels = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    pixels[..., 3] = np.where(rng.random((h, w)) < 0.7, 0, pixels[..., 3])
    whole = fill_transparent(pixels)
    before = st_io._FILL_BAND_TEXELS
    st_io._FILL_BAND_TEXELS = band
    try:
        np.testing.assert_array_equal(fill_transparent(pixels), whole)
    finally:
        st_io._FILL_BAND_TEXELS = before


def test_fill_transparent_fills_from_the_nearby_opaque_colour():
    img = _world()
    img[15:45, :, :3] = (200, 10, 10)  # the northern half red, the southern green
    out = fill_transparent(img)
    np.testing.assert_array_equal(out[:15, :, :3], np.broadcast_to((200, 10, 10), (15, 180, 3)))
    np.testing.assert_array_equal(out[75:, :, :3], np.broadcast_to(GREEN, (15, 180, 3)))


def _glb_texture(path) -> tuple[np.ndarray, dict]:
    data = path.read_bytes()
    n = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + n])
    view = doc["bufferViews"][doc["images"][0]["bufferView"]]
    start = 20 + n + 8 + view.get("byteOffset", 0)
    return np.asarray(Image.open(io.BytesIO(data[start:start + view["byteLength"]])).convert("RGBA")), doc


def test_glb_texture_holds_no_garbage_colour_under_alpha_0(globe_mesh, tmp_path):
    img = _world()
    export.save_mesh(globe.drape_texture(globe_mesh, img), tmp_path / "g.glb")
    texture, doc = _glb_texture(tmp_path / "g.glb")
    assert doc["materials"][0]["alphaMode"] == "MASK"
    np.testing.assert_array_equal(texture[..., 3], img[..., 3])
    np.testing.assert_array_equal(texture[15:75], img[15:75])
    # a viewer's bilinear filter and mipmaps blend these into the opaque edge: the caps hold the opaque colour now
    np.testing.assert_array_equal(texture[..., :3], np.broadcast_to(GREEN, texture.shape[:2] + (3,)))


def test_obj_texture_holds_no_garbage_colour_under_alpha_0(globe_mesh, tmp_path):
    export.save_mesh(globe.drape_texture(globe_mesh, _world()), tmp_path / "g.obj")
    pngs = [p for p in tmp_path.iterdir() if p.suffix == ".png"]
    assert len(pngs) == 1
    texture = np.asarray(Image.open(pngs[0]).convert("RGBA"))
    assert (texture[..., 3] == 0).any()
    np.testing.assert_array_equal(texture[..., :3], np.broadcast_to(GREEN, texture.shape[:2] + (3,)))


@pytest.mark.parametrize("latitude, altitude", [(60.0, 3e5), (0.0, 2e7)])
def test_render_view_does_not_show_the_colour_under_alpha_0(globe_mesh, latitude, altitude):
    """A view across the caps' edge was tinted magenta (the whole of a close one: VTK interpolates straight colour)."""
    camera = globe.look_from(latitude, 0.0, altitude)
    garbage, clean = (globe.render_view(globe.drape_texture(globe_mesh, _world(colour)), camera, window_size=(160, 100))
                      for colour in (MAGENTA, GREEN))
    np.testing.assert_array_equal(garbage, clean)


def test_drape_colors_gives_transparent_vertices_the_nearby_opaque_colour(globe_mesh):
    """A vertex among transparent texels kept their colour (magenta), which its faces blended into their opaque
    corners' colour in a render and in a viewer of the GLB (COLOR_0 with alphaMode BLEND)."""
    colours = globe.drape_colors(globe_mesh.vertices, _world())
    assert (colours[:, 3] == 0).any() and (colours[:, 3] == 255).any()
    np.testing.assert_array_equal(colours[:, :3], np.broadcast_to(GREEN, (len(colours), 3)))
    coloured = [globe_mesh.copy() for _ in range(2)]
    for mesh, colour in zip(coloured, (MAGENTA, GREEN), strict=True):
        mesh.visual.vertex_colors = globe.drape_colors(globe_mesh.vertices, _world(colour))
    camera = globe.look_from(0.0, 0.0, 2e7)
    garbage, clean = (globe.render_view(mesh, camera, window_size=(160, 100)) for mesh in coloured)
    np.testing.assert_array_equal(garbage, clean)


@pytest.mark.parametrize("mode", ["RGBA", "LA"])
def test_opaque_texture_is_not_copied_to_look_for_transparent_texels(mode):
    """An OBJ's side image (every RGBA or LA one goes through the fill) that is opaque, the common case, was copied
    whole into a NumPy array, and a mask of its alpha 0 made, to find nothing to fill: 1.25 times the image's bytes
    more at its peak (1.2 GB more for a 21600 x 10800 RGBA, and 5 % of the OBJ's export time). Same bytes either way."""
    import tracemalloc

    rng = np.random.default_rng(5)
    pixels = rng.integers(0, 256, (512, 1024, len(mode)), dtype=np.uint8)
    pixels[..., -1] = rng.integers(1, 256, pixels.shape[:2])  # translucent, but no texel of alpha 0
    image = Image.fromarray(pixels, mode)
    peaks, data = [], []
    for fill in (False, True):
        tracemalloc.start()
        try:
            data.append(export._encoded_image(image, fill=fill).data)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    assert data[0] == data[1]
    assert peaks[1] - peaks[0] < pixels.nbytes / 2, (peaks, pixels.nbytes)


def test_fill_transparent_memory_peak(monkeypatch):
    """Beyond the texture's own bytes, the fill's peak (bands of rows small against the texture, as a 21600 x 10800
    one's 388 rows are) is the float32 pyramid (4/3 of them), the push's finer level and the mask of holes: under 3.4
    times them. It was 4 times (4.7 GB for a 21600 x 10800 RGBA, drape_colors included): level 1 was held twice
    while its bands were concatenated, np.pad copied every even level whole, and each push gathered a level's
    colour, weight and quotient by boolean index."""
    import tracemalloc

    import stepterrain.io as st_io

    monkeypatch.setattr(st_io, "_FILL_BAND_TEXELS", 1 << 14)
    rng = np.random.default_rng(7)
    pixels = rng.integers(0, 256, (768, 1536, 4), dtype=np.uint8)
    pixels[..., 3] = np.maximum(pixels[..., 3], 1)
    pixels[:96, :, 3] = pixels[-96:, :, 3] = 0
    tracemalloc.start()
    try:
        out = fill_transparent(pixels)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 3.4 * pixels.nbytes, peak / pixels.nbytes
    np.testing.assert_array_equal(out[96:-96], pixels[96:-96])
    assert (out[:96, :, 3] == 0).all()


def _textured_box(image) -> trimesh.Trimesh:
    mesh = trimesh.creation.box()
    mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.vertices[:, :2] + 0.5, image=image)
    return mesh


def _transparent_colour_png(path, kind: str):
    """A PNG of ``_world``'s layout (green, the caps transparent over magenta) whose alpha is a transparent colour
    (tRNS), no alpha band: ``kind`` "P" a palette with a transparent index, "P bytes" a palette with an alpha per
    entry (one half transparent), "L" and "RGB" a transparent grey or colour."""
    caps = _world()[..., 3] == 0
    if kind.startswith("P"):
        index = np.where(caps, 0, 1).astype(np.uint8)
        index[45:, ::2] = np.where(caps[45:, ::2], 0, 2)
        picture = Image.fromarray(index, "P")
        picture.putpalette([*MAGENTA, *GREEN, 200, 10, 10] + [0] * (253 * 3))
        picture.save(path, transparency=0 if kind == "P" else bytes([0, 255, 128]))
    elif kind == "L":
        Image.fromarray(np.where(caps, 7, 90).astype(np.uint8), "L").save(path, transparency=7)
    else:
        Image.fromarray(_world()[..., :3]).save(path, transparency=MAGENTA)
    picture = Image.open(path)
    assert picture.mode == kind.split()[0] and "transparency" in picture.info
    return picture


@pytest.mark.parametrize("kind", ["P", "P bytes", "L", "RGB"])
@pytest.mark.parametrize("ext", [".glb", ".obj"])
def test_a_transparent_colours_texels_hold_the_nearby_opaque_colour_in_an_exported_texture(tmp_path, kind, ext):
    """A palette PNG with a transparent index (or an L or RGB one with a transparent colour, tRNS) is a texture with
    alpha (alphaMode MASK, map_d), and a render fills the colour under its transparent texels, but save_mesh wrote it
    as it was: a viewer's filtering blended the transparent index's colour (magenta) into the opaque texels' edge.
    It is written as RGBA (LA) with that colour filled, as an RGBA texture is; the alpha is the file's."""
    picture = _transparent_colour_png(tmp_path / "texture.png", kind)
    source = np.asarray(picture.convert("RGBA"))
    export.save_mesh(_textured_box(picture), tmp_path / f"box{ext}")
    if ext == ".glb":
        texture, doc = _glb_texture(tmp_path / "box.glb")
        assert doc["materials"][0]["alphaMode"] == ("BLEND" if kind == "P bytes" else "MASK")
    else:
        texture = np.asarray(Image.open(tmp_path / "box_material_0.png").convert("RGBA"))
        assert "map_d -imfchan m box_material_0.png" in (tmp_path / "box.mtl").read_text()
    np.testing.assert_array_equal(texture[..., 3], source[..., 3])
    some = source[..., 3] > 0
    np.testing.assert_array_equal(texture[some], source[some])
    np.testing.assert_array_equal(texture, fill_transparent(source))
    assert not (texture[~some][:, :3] == source[~some][:, :3]).all(axis=1).any()  # no texel kept its hidden colour


def test_a_transparent_colour_no_texel_uses_is_written_as_it_is(tmp_path):
    """A palette image whose transparent index no pixel uses has nothing to fill: its PNG stays a palette one."""
    index = np.ones((8, 8), np.uint8)
    picture = Image.fromarray(index, "P")
    picture.putpalette([*MAGENTA, *GREEN] + [0] * (254 * 3))
    picture.save(tmp_path / "texture.png", transparency=0)
    export.save_mesh(_textured_box(Image.open(tmp_path / "texture.png")), tmp_path / "box.obj")
    with Image.open(tmp_path / "box_material_0.png") as written:
        assert written.mode == "P"
        np.testing.assert_array_equal(np.asarray(written), index)


@pytest.mark.parametrize("holes", [False, True])
def test_a_textures_icc_profile_is_dropped_in_gltf_and_kept_in_an_objs_side_image(tmp_path, holes):
    """glTF 2.0 §3.8.3 says images SHOULD NOT embed ICC profiles (clients MUST ignore them), and the Khronos validator
    warns of a PNG that carries some (IMAGE_FEATURES_UNSUPPORTED): an ICC-tagged PNG texture went into the GLB with
    its profile, where one with transparent texels (filled, so re-encoded) lost it. The GLB's PNG now never carries
    one; an OBJ's side image, an image file like any other, keeps it whether filled or not."""
    from PIL import ImageCms

    from . import gltf_validator

    profile = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    pixels = _world()
    if not holes:
        pixels[..., 3] = 255
    Image.fromarray(pixels, "RGBA").save(tmp_path / "texture.png", icc_profile=profile)
    mesh = _textured_box(Image.open(tmp_path / "texture.png"))
    export.save_mesh(mesh, tmp_path / "box.glb")
    export.save_mesh(mesh, tmp_path / "box.obj")
    data = (tmp_path / "box.glb").read_bytes()
    n = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + n])
    view = doc["bufferViews"][doc["images"][0]["bufferView"]]
    start = 20 + n + 8 + view.get("byteOffset", 0)
    with Image.open(io.BytesIO(data[start:start + view["byteLength"]])) as embedded:
        assert "icc_profile" not in embedded.info
    with Image.open(tmp_path / "box_material_0.png") as side:
        assert side.info.get("icc_profile") == profile
        assert (np.asarray(side)[..., :3] == MAGENTA).all(axis=-1).any() == (not holes)  # opaque caps, or filled
    if gltf_validator.available()[0]:
        assert gltf_validator.problems(gltf_validator.validate([tmp_path / "box.glb"])) == []
