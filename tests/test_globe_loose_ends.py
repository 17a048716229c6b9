"""Loose ends of the globe drape and its exports: a node-registered texture's closing column, the poles'
colours, NaN in a glTF read back, the 3MF unit of a globe in metres."""

from __future__ import annotations

import numpy as np
import pytest

from stepterrain.globe import EARTH_RADIUS, Globe

LAT1 = np.linspace(89.5, -89.5, 180)
LON1 = np.linspace(-179.5, 179.5, 360)


def _node_registered(tmp_path, west):
    """A node-registered 361 x 181 PNG (pixel centres on whole degrees, its PAM file's geotransform from ``west``,
    -0.5 for 0..360, -180.5 for -180..180), its last column the first's meridian again, and its pixels."""
    from PIL import Image

    rng = np.random.default_rng(3)
    pixels = rng.integers(0, 256, (181, 361, 3)).astype(np.uint8)
    pixels[:, 360] = pixels[:, 0]  # the same meridian
    path = tmp_path / f"node{int(west)}.png"
    Image.fromarray(pixels).save(path)
    path.with_name(path.name + ".aux.xml").write_text(
        f"<PAMDataset><GeoTransform>{west!r}, 1, 0, 90.5, 0, -1</GeoTransform></PAMDataset>")
    return path, pixels


def _lerp_columns(row, x):
    """Bilinear along a row of pixels (columns wrapping), at column coordinates ``x`` of pixel centres."""
    x0 = np.floor(x).astype(int)
    t = (x - x0)[:, None]
    return (1 - t) * row[x0 % len(row)] + t * row[(x0 + 1) % len(row)]


@pytest.mark.parametrize("west", [-0.5, -180.5])
def test_a_node_registered_texture_puts_every_column_at_its_longitude_without_a_stretched_face(tmp_path, west):
    """A node-registered 361 x 181 texture (its first and last columns one meridian) was rolled by whole columns and
    kept both copies of that meridian: over 0..360 the copies landed side by side at Greenwich, where each face
    across it spanned one texture column more than its longitudes (a face column showing 2° of image over 1°), and
    over -180..180 each face across the antimeridian did. The closing column is dropped now (the grid's own closing
    column is, Globe.from_latlon): every face spans the columns of its longitudes, the seams too, and each vertex
    samples the image at its own longitude (compared with the file's pixels at its georeferenced column)."""
    from stepterrain.globe import drape_texture

    path, pixels = _node_registered(tmp_path, west)
    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh(error=0.0)
    draped = drape_texture(mesh, path)
    image = np.asarray(draped.visual.material.image.convert("RGB"), dtype=np.float64)
    height, width = image.shape[:2]
    vertices = np.asarray(draped.vertices, dtype=np.float64)
    uv = np.asarray(draped.visual.uv, dtype=np.float64)
    lon = np.degrees(np.arctan2(vertices[:, 1], vertices[:, 0]))
    pole = np.hypot(vertices[:, 0], vertices[:, 1]) <= 1e-9 * np.abs(vertices[:, 2])
    faces = np.asarray(draped.faces)
    # each face: its texture columns (u times the embedded image's width) against its longitudes (1° a column)
    corner_lon = np.where(pole[faces], np.nan, lon[faces])
    across = np.nanmax(corner_lon, axis=1) - np.nanmin(corner_lon, axis=1) > 180
    corner_lon = np.where(across[:, None] & (corner_lon < 0), corner_lon + 360, corner_lon)
    degrees = np.nanmax(corner_lon, axis=1) - np.nanmin(corner_lon, axis=1)
    corner_u = np.where(pole[faces], np.nan, uv[faces, 0] * width)
    columns = np.nanmax(corner_u, axis=1) - np.nanmin(corner_u, axis=1)
    worst = np.argmax(np.abs(columns - degrees))
    assert np.abs(columns - degrees).max() < 1e-6, (worst, lon[faces[worst]].tolist(), columns[worst],
                                                     degrees[worst])
    # each vertex samples, along its row, the file's pixels at its georeferenced column (x from the geotransform)
    keep = ~pole
    row = np.clip(np.round((1 - uv[keep, 1]) * height - 0.5).astype(int), 0, height - 1)
    x_image = (uv[keep, 0] * width - 0.5) % width
    x_file = (lon[keep] - west - 0.5) % 360  # the file's columns 0..359: its column 360 repeats column 0
    embedded = np.array([_lerp_columns(image[r], np.array([x]))[0] for r, x in zip(row, x_image, strict=True)])
    expected = np.array([_lerp_columns(pixels[r, :360].astype(np.float64), np.array([x]))[0]
                         for r, x in zip(row, x_file, strict=True)])
    np.testing.assert_allclose(embedded, expected, atol=1e-6)


def test_drape_colors_gives_a_pole_the_mean_of_the_image_s_edge_row(tmp_path):
    """A pole vertex (every longitude at once) took the edge row's colour at longitude 0, arctan2(0, 0): a pole of
    an image whose edge row varies got one column's colour. It takes the row's mean now (premultiplied by alpha in an
    RGBA image: the opaque texels' mean colour, the mean alpha), as Globe.from_latlon gives a pole node its row's mean
    height; a uniform edge row (a node-registered image's pole row) gives its colour, as before."""
    from stepterrain.globe import drape_colors

    pixels = np.zeros((18, 36, 4), np.uint8)
    pixels[..., 3] = 255
    red = np.random.default_rng(5).integers(0, 256, 36)
    pixels[0, :, 0] = red  # red along the north row
    pixels[0, :, 1] = 40
    pixels[-1, :, 2] = (np.arange(36) % 5) * 60  # blue along the south row
    pixels[-1, :18, 3] = 0  # its western half transparent
    poles = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]) * EARTH_RADIUS
    got = drape_colors(poles, pixels).astype(int)
    north = [round(red.mean()), 40, 0, 255]
    assert abs(red.mean() - (red[17] + red[18]) / 2) > 1  # longitude 0's colour is not the mean
    opaque = (np.arange(36) % 5)[18:] * 60
    south = [0, 0, round(opaque.mean()), round(255 * 18 / 36)]
    assert got.tolist() == [north, south]
    # the RGB image alike, and a pole's colour does not depend on which way the tiny horizontal part points
    rgb = pixels[..., :3].copy()
    np.testing.assert_array_equal(drape_colors(poles, rgb)[0], [*north[:3], 255])
    tilted = np.array([[1e-12, -1e-12, 1.0]]) * EARTH_RADIUS  # a pole to float64's rounding, arctan2 135° W
    np.testing.assert_array_equal(drape_colors(tilted, rgb)[0], [*north[:3], 255])
    # a uniform edge row: its colour
    rgb[0] = (12, 34, 56)
    np.testing.assert_array_equal(drape_colors(poles, rgb)[0], [12, 34, 56, 255])
    # a vertex off the pole keeps its own longitude's colour (0°: between columns 17 and 18)
    near = np.array([[np.cos(np.radians(89.99)), 0.0, np.sin(np.radians(89.99))]]) * EARTH_RADIUS
    expected = np.round((pixels[0, 17, :3].astype(float) + pixels[0, 18, :3]) / 2)
    np.testing.assert_array_equal(drape_colors(near, pixels[..., :3])[0, :3], expected)


def _model_unit(path):
    """The ``unit`` a 3MF's model declares (millimetre when absent, as the 3MF core spec says)."""
    import re
    import zipfile

    with zipfile.ZipFile(path) as archive:
        head = archive.read("3D/3dmodel.model")[:400].decode()
    found = re.search(r'<model [^>]*unit="([a-z]+)"', head)
    return found.group(1) if found else "millimeter"


def test_a_globe_in_metres_is_written_to_3mf_in_metres(tmp_path):
    """A 3MF declared millimetres whatever the mesh's unit: a globe (its radius and heights in metres) came out
    1000 times too small in a slicer (12.7 km across, not 12 742 km), and a mesh whose metadata says ``units``
    (trimesh's "meters" of a mesh read from a glTF) alike. Globe.mesh records units "meters" and the 3MF declares
    the unit its metadata names (millimetres without one: a terrain scaled for a print, print_mesh's), the
    coordinates as they are; read back, the metadata names it again."""
    import trimesh

    from stepterrain.export import read_mesh, save_mesh

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh()
    assert mesh.metadata["units"] == "meters"
    path = save_mesh(mesh, tmp_path / "globe.3mf")
    assert _model_unit(path) == "meter"
    back = read_mesh(path)
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    assert back.metadata["units"] == "meters"
    # trimesh's names, and none (millimetres, as before)
    box = trimesh.creation.box()
    for units, unit in (("millimeters", "millimeter"), ("inches", "inch"), ("feet", "foot"),
                        ("centimeters", "centimeter"), ("microns", "micron"), ("m", "meter"), (None, "millimeter")):
        box.metadata.clear()
        if units is not None:
            box.metadata["units"] = units
        assert _model_unit(save_mesh(box, tmp_path / "box.3mf")) == unit, units


def test_a_nan_vertex_is_refused_naming_it_in_every_format_and_a_gltf_holding_one_is_not_turned(tmp_path):
    """save_mesh refused a NaN vertex in every format by count alone (which vertex?): it names the first now. A glTF
    holding one (another tool's: its validator calls it ACCESSOR_INVALID_FLOAT) was turned z-up by a matrix product
    (0 · NaN is NaN): the NaN spread to the vertex's three coordinates without a word, where the other formats read it
    where it stands. read_mesh refuses it now, naming the vertex as stored."""
    import trimesh

    from stepterrain.errors import DataFileError, InvalidInputError
    from stepterrain.export import MESH_EXTENSIONS, read_mesh, save_mesh

    box = trimesh.creation.box()
    vertices = np.asarray(box.vertices).copy()
    vertices[5, 1] = np.nan
    bad = trimesh.Trimesh(vertices, box.faces, process=False)
    for ext in MESH_EXTENSIONS:
        with pytest.raises(InvalidInputError, match=r"^mesh vertices must be finite to be written; got 1 of 8 "
                                                    r"vertices with NaN or inf \(vertex 5 at \[0\.5, nan, 0\.5\]\)$"):
            save_mesh(bad, tmp_path / f"bad{ext}")
        assert not (tmp_path / f"bad{ext}").exists()
    path = tmp_path / "other.glb"  # y-up, as any other tool writes a glTF
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(bad)))
    with pytest.raises(DataFileError, match=r"1 vertex with NaN or inf, vertex 5 first, at \(0\.5, nan, 0\.5\) "
                                            r"as stored: glTF positions must be finite$"):
        read_mesh(path)
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(box)))  # finite: read as before
    np.testing.assert_array_equal(read_mesh(path).vertices, np.asarray(box.vertices)[:, [0, 2, 1]] * [1, -1, 1])


def test_the_globe_example_frames_its_clipped_close_views_whole():
    """examples/globe.py rendered the clipped close views (from 48° N to the horizon beyond the north pole) from a
    fixed camera 2600 km above 51° N: their far part reached 3.7 times the panel's half height above its centre and
    was cut off at the top of docs/globe.png. Its overview camera frames every vertex now (an independent pinhole
    projection: within the image, and in front of the eye), the part under the close eye at the bottom."""
    import importlib.util
    import math
    from pathlib import Path

    from stepterrain.globe import look_from

    spec = importlib.util.spec_from_file_location("globe_example",
                                                  Path(__file__).parents[1] / "examples" / "globe.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    globe = Globe.sample(face_size=65, exaggeration=10.0, device="cpu")
    close = look_from(44.0, 9.0, 400_000.0, tilt=65.0, heading=0.0, aspect=1.6)
    meshes = [example.coloured_mesh(globe, close, bounds, 100.0) for bounds in ("cone", "sphere")]
    points = np.concatenate([m.vertices for m in meshes])

    def image(camera):  # (x, y) in [-1, 1] across the image, and the depth
        eye = np.asarray(camera.eye, dtype=np.float64)
        forward = np.asarray(camera.target) - eye
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, camera.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        rel = points - eye
        depth = rel @ forward
        t = math.tan(camera.fov / 2)
        return (rel @ right) / depth / (t * camera.aspect), (rel @ up) / depth / t, depth

    x, y, depth = image(look_from(51.0, 9.0, 2_600_000.0, aspect=1.6))  # the old camera
    assert y.max() > 2  # cut off
    overview = example.overview_of(meshes, -np.asarray(close.eye), 1.6)
    x, y, depth = image(overview)
    assert (depth > 0).all() and np.abs(x).max() <= 1 and np.abs(y).max() <= 1
    assert max(np.abs(x).max(), np.abs(y).max()) > 0.6  # framed, not a speck
    ground = np.asarray(close.eye) / np.linalg.norm(close.eye)
    under = np.argmin(np.linalg.norm(points / np.linalg.norm(points, axis=1, keepdims=True) - ground, axis=1))
    assert y[under] < 0  # the vertex nearest the close eye's ground lies in the lower half


@pytest.mark.parametrize("radius, altitude", [(EARTH_RADIUS, 1.0), (1e15, 10.0), (1e17, 10.0), (1e20, 1.0)])
def test_look_from_keeps_its_view_direction_over_a_large_sphere(radius, altitude):
    """look_from put the target max(altitude, 1 m) along the view from the eye: against a large radius that step
    rounded away in float64, 10 m above a sphere of 1e17 m the view turned 0.17 rad off the tilt and heading asked
    for (0.003 rad at 1e15), and 1 m above one of 1e20 m the target was the eye, refused as "Camera eye and target
    must differ" naming no argument of look_from. The view direction is the one asked for, to float64's precision
    of the direction (checked against the east / north / up frame written out here)."""
    from stepterrain.globe import look_from

    lat, lon, tilt, heading = np.radians([46.0, 9.0, 60.0, 30.0])
    outward = np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
    east = np.array([-np.sin(lon), np.cos(lon), 0.0])
    north = np.cross(outward, east)
    wanted = -np.cos(tilt) * outward + np.sin(tilt) * (np.cos(heading) * north + np.sin(heading) * east)
    camera = look_from(46.0, 9.0, altitude, tilt=60.0, heading=30.0, radius=radius)
    forward = np.subtract(camera.target, camera.eye)
    forward /= np.linalg.norm(forward)
    assert np.arctan2(np.linalg.norm(np.cross(forward, wanted)), forward @ wanted) < 1e-9
    assert np.allclose(camera.eye, (radius + altitude) * outward, rtol=1e-15, atol=0)


def test_the_view_metrics_alone_without_a_camera_are_refused():
    """Without a camera the distance and clip metrics are dropped; metrics of them alone left nothing to steer the
    refinement (μ = 1): Globe.mesh gave the whole sphere below error 1 and its 12 root triangles from error 1 up (the
    planar mesh its 2), whatever the heights, without a word. Refused, naming the metrics and what they need; with
    'geometric' beside them, a user metric or metrics=() (none, as documented) the mesh is made as before."""
    from stepterrain.errors import InvalidInputError
    from stepterrain.globe import adaptive_mesh

    lat = np.linspace(89.5, -89.5, 18)
    lon = np.linspace(-175.0, 175.0, 36)
    z = np.add.outer(np.sin(np.radians(lat)) * 3000.0, np.cos(np.radians(lon)) * 2000.0)
    globe = Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")
    heights = np.add.outer(np.arange(9.0), np.arange(9.0)) ** 2
    for metrics, named in [(("distance",), "metric 'distance' needs"), (["clip"], "metric 'clip' needs"),
                           (("clip", "distance"), "metrics 'distance' and 'clip' need")]:
        with pytest.raises(InvalidInputError, match=f"^the {named} a camera .* no camera: give a camera, add "
                                                    "'geometric', or metrics=\\(\\) for none$"):
            globe.mesh(error=100.0, metrics=metrics)
        with pytest.raises(InvalidInputError, match=f"^the {named} a camera"):
            adaptive_mesh(heights, error=1.0, metrics=metrics, device="cpu")
    geometric = globe.mesh(error=1e5, metrics=("geometric",))  # the chords' sag: e of some 100 km at face size 9
    assert len(globe.mesh(error=1e5, metrics=("geometric", "distance", "clip")).faces) == len(geometric.faces)
    assert len(globe.mesh(error=1e5, metrics=("distance", lambda p, r: np.ones(len(p)))).faces) == 12
    assert len(globe.mesh(error=0.5, metrics=()).faces) == 12 * 8**2
    assert 12 < len(geometric.faces) < 12 * 8**2
