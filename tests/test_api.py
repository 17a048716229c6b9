"""The public namespace: every exported name resolves, lazily loaded names are the modules' own objects."""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

import stepterrain as st
from stepterrain.terrain import finite_number, real_numbers


@pytest.mark.parametrize("name", st.__all__)
def test_every_exported_name_resolves(name):
    assert getattr(st, name) is not None


@pytest.mark.parametrize("name, module", sorted(st._LAZY.items()))
def test_lazy_names_are_the_capability_modules_objects(name, module):
    assert getattr(st, name) is getattr(importlib.import_module(f"stepterrain.{module}"), name)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        st.not_a_name  # noqa: B018


def test_entry_points_survive_importing_their_modules():
    import stepterrain.batch
    import stepterrain.stepped  # the submodule import binds the module, which is callable as its function

    assert st.stepped is stepterrain.stepped and st.stepped.stepped.__module__ == "stepterrain.stepped"
    assert st.batch is stepterrain.batch and st.batch.batch.__module__ == "stepterrain.batch"
    assert callable(st.stepped) and callable(st.batch)


def test_the_namespace_shows_the_public_names_only_and_loads_nothing():
    """dir(stepterrain) (and so tab completion) listed the names its own code imports: Any, TYPE_CHECKING,
    annotations, importlib, beside the private ones. Now __all__ (the lazy names unloaded), the submodules and the
    dunders; dir() loads no capability module, and ``from stepterrain import *`` still takes every public name."""
    import subprocess
    import sys

    script = """
import sys
import stepterrain as st
lazy = ["stepterrain." + m for m in sorted(set(st._LAZY.values()))]
names = dir(st)
assert not [m for m in lazy if m in sys.modules], [m for m in lazy if m in sys.modules]
print(names)
for name in ("Any", "TYPE_CHECKING", "annotations", "importlib"):
    assert not hasattr(st, name), name
namespace = {}
exec("from stepterrain import *", namespace)
assert sorted(set(namespace) - {"__builtins__"}) == sorted(st.__all__)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    names = eval(done.stdout.strip().splitlines()[-1])  # noqa: S307 - the list the child printed
    public = [name for name in names if not name.startswith("__")]
    assert not [name for name in public if name.startswith("_")]
    assert set(st.__all__) | st._SUBMODULES <= set(public)
    assert set(public) - set(st.__all__) - st._SUBMODULES <= {"batch", "errors", "io", "kernels", "stepped",
                                                              "terrain"}  # submodules loaded with the package
    assert {"__version__", "__doc__", "__name__"} <= set(names)


@pytest.mark.parametrize("name", sorted(st._SUBMODULES))
def test_submodules_are_attributes(name):
    if name == "pyvista_accessor":
        pytest.importorskip("pyvista", reason="the accessor module needs pyvista")
    assert getattr(st, name).__name__ == f"stepterrain.{name}"


def test_one_camera_type_for_every_capability():
    from stepterrain import globe, texture_lod
    from stepterrain.camera import Camera

    assert st.Camera is Camera is globe.Camera is texture_lod.Camera


def test_camera_viewport_sets_aspect_and_pixels():
    import math

    import numpy as np

    from stepterrain.camera import Camera

    cam = Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0), fov=math.radians(90.0), viewport=(640, 480))
    assert cam.aspect == 640 / 480 and math.isclose(cam.focal_pixels, 240.0)
    pixels, depth = cam.project([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    assert np.allclose(pixels[0], (320.0, 240.0)) and np.allclose(depth, 10.0)
    assert np.allclose(pixels[1], (320.0 + 240.0, 240.0))            # 45° off axis: one focal length
    inside = cam.planes()[:, :3] @ [0.0, 0.0, 0.0] + cam.planes()[:, 3]
    assert (inside <= 0).all()
    assert Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0), aspect=2.0).viewport == (1600, 800)
    with pytest.raises(st.InvalidInputError, match="disagrees"):
        Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0), aspect=1.0, viewport=(640, 480))
    with pytest.raises(st.InvalidInputError, match="viewport"):
        Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0), viewport=(0, 480))


def test_camera_survives_dataclasses_replace():
    import dataclasses

    from stepterrain.camera import Camera

    cam = Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0), aspect=4.0 / 3.0)
    moved = dataclasses.replace(cam, eye=(1.0, -10.0, 0.0))
    assert moved.aspect == cam.aspect and moved.viewport == cam.viewport == (1067, 800)


@pytest.mark.parametrize("aspect", [1e-6, 1e-4, 6e-4])
def test_a_camera_narrower_than_one_pixel_survives_replace_and_adaptive_mesh(aspect):
    """An aspect in range but under one pixel's width at 800 rows (below 1/1600): the default viewport rounds its
    width up to 1 pixel, and the agreement check (to half a pixel) refused that viewport with its own aspect:
    dataclasses.replace raised "Camera aspect 0.0001 disagrees with viewport (1, 800)", and so did adaptive_mesh
    (which moves the camera by the origin) for any such camera."""
    import dataclasses

    from stepterrain.camera import Camera
    from stepterrain.globe import adaptive_mesh

    cam = Camera((1.0, 1.0, 10.0), (1.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), aspect=aspect)
    assert cam.viewport == (1, 800)
    moved = dataclasses.replace(cam, eye=(1.0, 1.0, 11.0))
    assert moved.aspect == aspect and moved.viewport == (1, 800)
    assert Camera((1.0, 1.0, 10.0), (1.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), aspect=aspect, viewport=(1, 800)) == cam
    mesh = adaptive_mesh(np.zeros((3, 3)), error=0.1, camera=cam, cull=False, device="cpu")
    assert len(mesh.faces) == 2  # a plane: the two roots
    with pytest.raises(st.InvalidInputError, match="disagrees"):  # a 2-pixel width is still not that aspect
        Camera((1.0, 1.0, 10.0), (1.0, 1.0, 0.0), up=(0.0, 1.0, 0.0), aspect=aspect, viewport=(2, 800))


def test_camera_vectors_too_short_for_float64_are_named():
    """eye (1e-200, 0, 0) and target at the origin differ, but |target - eye| squares to 0: the camera said
    'eye and target must differ; both are (1e-200, 0, 0)'; an up of length 1e-300 was called zero or parallel."""
    from stepterrain import InvalidInputError
    from stepterrain.camera import Camera

    with pytest.raises(InvalidInputError, match="lie too close together for a view direction in float64"):
        Camera((1e-200, 0.0, 0.0), (0.0, 0.0, 0.0))
    with pytest.raises(InvalidInputError, match="must differ; both are"):
        Camera((1.0, 2.0, 3.0), (1.0, 2.0, 3.0))
    with pytest.raises(InvalidInputError, match=r"Camera up .* is too short to normalise in float64"):
        Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0), up=(0.0, 0.0, 1e-300))


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"aspect": 1e300}, r"^Camera aspect \(width / height\) must lie in \[1e-06, 1e\+06\]; got 1e\+300$"),
        ({"aspect": 1e307}, r"^Camera aspect \(width / height\) must lie in \[1e-06, 1e\+06\]; got 1e\+307$"),
        ({"aspect": 1e-300}, r"^Camera aspect \(width / height\) must lie in \[1e-06, 1e\+06\]; got 1e-300$"),
        ({"viewport": (10**7, 1)}, r"^Camera viewport must have an aspect \(width / height\) in \[1e-06, 1e\+06\]; "
                                   r"got \(10000000, 1\), 1e\+07$"),
    ],
)
def test_camera_aspect_is_bounded(options, match):
    """Camera(aspect=1e300) squared its side-plane normals to inf: they came out zero, so nothing was clipped at
    the sides (and aspect=1e307 overflowed the default viewport); the aspect must lie in [1e-6, 1e6]. Within it,
    the side planes are unit normals that clip a box off to the side."""
    from stepterrain import InvalidInputError
    from stepterrain.camera import Camera

    with pytest.raises(InvalidInputError, match=match):
        Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), **options)
    import numpy as np

    for aspect in (1e-6, 1e6):
        cam = Camera((0.0, 0.0, 10.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), aspect=aspect)
        np.testing.assert_allclose(np.linalg.norm(cam.planes()[:, :3], axis=1), 1.0)
        assert not cam.box_visible(np.array([[-1.0, 1e3, -1.0], [1.0, 1e3 + 1.0, 1.0]]))  # above the view


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"viewport": ("640", "480")}, r"Camera viewport must be \(width, height\) pixels; got \('640', '480'\)"),
        ({"viewport": "64"}, r"Camera viewport must be \(width, height\) pixels; got '64'"),
        ({"viewport": ("640", 480)}, r"Camera viewport must be \(width, height\) pixels; got \('640', 480\)"),
        ({"viewport": ("0", "0", "1", "1")}, r"Camera viewport must be \(width, height\) pixels"),
        ({"viewport": (10**400, 480)}, r"Camera viewport must be \(width, height\) pixels"),
        ({"aspect": "1.5"}, r"Camera aspect must be a positive number; got '1.5'"),
        ({"aspect": True}, r"Camera aspect must be a positive number; got True"),
        ({"aspect": "1.5", "viewport": (640, 480)}, r"Camera aspect must be a positive number; got '1.5'"),
        ({"eye": ("0", "-10", "5")}, r"Camera eye must be 3 finite numbers within ±1e\+30; got \('0', '-10', '5'\)"),
        ({"target": (True, False, False)}, r"Camera target must be 3 finite numbers"),
        ({"up": ("0", "0", "1")}, r"Camera up must be 3 finite numbers"),
    ],
)
def test_camera_refuses_numbers_given_as_text_or_bools(options, match):
    """viewport=("640", "480") was taken as 640 x 480 and "64" as 6 x 4 pixels, aspect "1.5" as 1.5 and True as
    1, eye ("0", "-10", "5") as numbers; fov, near and far already refused text and bools by name."""
    from stepterrain.camera import Camera

    kwargs = {"eye": (0.0, -10.0, 5.0), "target": (0.0, 0.0, 0.0), **options}
    with pytest.raises(st.InvalidInputError, match=match):
        Camera(**kwargs)


@pytest.mark.parametrize(
    ("points", "match"),
    [
        ([["0", "0", "0"]], r"points must be \(N, 3\) world points \(real numbers\); got dtype <U1"),  # taken
        ([[True, False, False]], r"points must be \(N, 3\) world points \(real numbers\); got dtype bool"),
        ("abc", r"points must be .*; got dtype <U3"),  # numpy's "could not convert string to float"
        ([[0.0, 0.0]], r"points must be \(N, 3\) world points; got shape \(1, 2\)"),  # numpy's broadcast error
        ([[0.0, 0.0, 0.0], [0.0]], r"points must be .*; got rows of different lengths"),  # "inhomogeneous shape"
    ],
)
def test_camera_project_refuses_points_that_are_not_numbers(points, match):
    import numpy as np

    from stepterrain.camera import Camera

    cam = Camera(eye=(0.0, -10.0, 5.0), target=(0.0, 0.0, 0.0), viewport=(640, 480))
    with pytest.raises(st.InvalidInputError, match=match):
        cam.project(points)
    px, depth = cam.project(np.array([0, 0, 0], np.int32))  # one point, numpy integers
    assert px.tolist()[0] == pytest.approx([320.0, 240.0]) and depth.shape == (1,)


def test_camera_takes_numpy_numbers():
    import numpy as np

    from stepterrain.camera import Camera

    cam = Camera(np.array([0.0, -10.0, 5.0], np.float32), (0, 0, 0), aspect=np.float32(2.0),
                 viewport=(np.int64(640), np.float64(320.0)))
    assert cam.viewport == (640, 320) and cam.aspect == 2.0 and type(cam.aspect) is float
    assert Camera((0.0, -10.0, 5.0), (0, 0, 0), aspect=np.int32(2)).viewport == (1600, 800)


def test_finite_number_refuses_by_name_with_one_bound_or_an_overflowing_int():
    """finite_number(lo=0) alone raised a bare TypeError formatting the missing upper bound, and an int beyond
    float64 (10**400) a bare OverflowError from float()."""
    from stepterrain.terrain import finite_number

    with pytest.raises(st.InvalidInputError, match=r"^width must be >= 0; got -1$"):
        finite_number(-1, "width", lo=0.0)
    with pytest.raises(st.InvalidInputError, match=r"^width must be <= 2; got 3$"):
        finite_number(3, "width", hi=2.0)
    with pytest.raises(st.InvalidInputError,
                       match=r"^angle must be <= 90 degrees \(1.5708 radians\); got 180 degrees$"):
        finite_number(math.pi, "angle", hi=math.pi / 2, unit="rad")
    with pytest.raises(st.InvalidInputError, match=r"^width must be finite; got an integer too large for a float"):
        finite_number(10**400, "width")
    with pytest.raises(st.InvalidInputError, match=r"^width must lie in \[0, 1\]; got 2$"):
        finite_number(2, "width", lo=0.0, hi=1.0)
    assert finite_number(0, "width", lo=0.0) == 0.0 and finite_number(-5, "width", hi=2.0) == -5.0


_H = [[0.0, 1.0, 2.0], [1.0, 2.0, 3.0], [2.0, 3.0, 4.0]]


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: st.stepped(_H, interval="1"), r"interval and base must be numbers; got interval='1'"),
        (lambda: st.stepped(_H, interval=True), r"interval and base must be numbers; got interval=True"),
        (lambda: st.stepped(_H, interval=1.0, base=b"0"), r"got interval=1.0, base=b'0'"),
        (lambda: st.stepped(_H, levels=[1.0, 2.0], base=0.5), r"^base applies only to interval=.*got base=0.5 with"),
        (lambda: st.isovalues((0.0, 4.0), levels=[1.0], base="0"), r"^base applies only to interval="),
        (lambda: st.heightfield_mesh(_H, spacing="30"), r"spacing must be a pair of numbers \(x, y\); got '30'"),
        (lambda: st.heightfield_mesh(_H, spacing=("30", "30")), r"spacing must be a pair of numbers"),
        (lambda: st.heightfield_mesh(_H, spacing=(True, 2.0)), r"spacing must be a pair of numbers.*True"),
        (lambda: st.adaptive_mesh(_H, error="5", spacing=1.0), r"error must be a number >= 0 \(metres\); got '5'"),
        (lambda: st.look_from(True, 0.0, 1.0e7), r"latitude and longitude must be numbers \(degrees\); got True"),
        (lambda: st.look_from(0.0, 0.0, "1e7"), r"altitude must be a finite number; got '1e7'"),
    ],
)
def test_numbers_given_as_text_or_bools_are_refused(call, match):
    """float() takes "1" and True, so a number read from a file as text, or a flag passed in a number's place,
    used to be taken as a number in some arguments (interval, base, spacing, error, look_from's angles) and
    refused in others (a lens resolution, a Camera's fov); every scalar check now refuses text and bools."""
    with pytest.raises(st.InvalidInputError, match=match):
        call()


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: finite_number(10**400, "x"), r"^x must be finite; got an integer too large for a float \(beyond "),
        (lambda: finite_number(-(10**400), "lens radius", positive=True), r"^lens radius must be finite; got an "),
        (lambda: st.stepped(_H, interval=10**400), r"^interval and base must be numbers; got interval=1000"),
        (lambda: st.adaptive_mesh(_H, error=10**400, spacing=1.0), r"^error must be a number >= 0 \(metres\)"),
        (lambda: st.look_from(0.0, 10**400, 1.0e7), r"^latitude and longitude must be numbers \(degrees\)"),
        (lambda: st.look_from(0.0, 0.0, 10**400), r"^altitude must be a finite number; got 1000"),
        (lambda: st.isovalues((0, 10**400), interval=1.0), r"^height_range must be \(min, max\) heights"),
        (lambda: st.stepped(_H, levels=[0, 10**400]), r"^levels must be a sequence of numbers"),
        (lambda: st.stepped(_H, interval=1.0, gamma=10**400), r"^gamma must be a number in \[0, 1\]"),
        (lambda: st.stepped(_H, interval=1.0, solid=True, floor=-(10**400)), r"^floor must be a number \(the base"),
        (lambda: st.Camera(eye=(0, 0, 10**400), target=(0, 0, 0)), r"^Camera eye must be 3 finite numbers"),
        (lambda: st.Camera(eye=(0, 0, 10), target=(0, 0, 0), fov=10**400), r"^Camera fov must be finite; got an "
                                                                            r"integer too large for a float"),
    ],
)
def test_integers_too_large_for_a_float_are_refused_by_name(call, match):
    """float(10**400) raises OverflowError, which is no ValueError: every scalar check caught (TypeError,
    ValueError) and let it through as a bare 'int too large to convert to float' naming no argument."""
    with pytest.raises(st.InvalidInputError, match=match):
        call()


@pytest.mark.parametrize(("values", "expected"), [
    ([10**20, 1.0], [1e20, 1.0]),
    ([10**20], [1e20]),
    ([[2**64, 0], [1, -(2**64)]], [[2.0**64, 0.0], [1.0, -(2.0**64)]]),
    (np.array([10**20, 1.5, np.float32(2), np.nan], dtype=object), [1e20, 1.5, 2.0, np.nan]),
])  # fmt: skip
def test_real_numbers_takes_integers_beyond_int64(values, expected):
    """numpy keeps an int beyond int64 as a Python object, so [10**20, 1.0] was refused as 'dtype object' although
    a float holds it (1e20); an object array is now read number by number."""
    array = real_numbers(values, "x", "numbers")
    assert array.dtype == np.float64
    np.testing.assert_array_equal(array, expected)
    assert st.Terrain.from_heights(_H, spacing=(1e10, 1e10), origin=(10**20, 0)).origin == (1e20, 0.0)


_NOT_REAL = r"^x must be numbers \(real numbers\); got "


@pytest.mark.parametrize(("values", "match"), [
    ([10**400], r"^x must be numbers; got an integer too large for a float \(beyond ±1.8e\+308\) at index \(0,\)$"),
    ([1.0, -(10**400)], r"^x must be numbers; got an integer too large for a float \(beyond ±1.8e\+308\) at index "
                        r"\(1,\)$"),
    ([10**20, None], _NOT_REAL + r"dtype object: None at index \(1,\)$"),
    (np.array([10**20, "1"], dtype=object), _NOT_REAL + r"dtype object: '1' at index \(1,\)$"),
    (np.array(1j, dtype=object), _NOT_REAL + r"dtype object: 1j$"),
    ([10**20, True], _NOT_REAL + r"a bool \(True\) at index \(1,\)$"),
    ((True, 2.0), _NOT_REAL + r"a bool \(True\) at index \(0,\)$"),
    ([True, 0, 0], _NOT_REAL + r"a bool \(True\) at index \(0,\)$"),
    ([[1.0, 2.0], (3.0, np.False_)], _NOT_REAL + r"a bool \(np.False_\) at index \(1, 1\)$"),
    ([np.zeros(2), np.ones(2, bool)], _NOT_REAL + r"a bool \(np.True_\) at index \(1, 0\)$"),
    ([True, False], _NOT_REAL + r"dtype bool$"),
])  # fmt: skip
def test_real_numbers_refuses_what_is_not_a_number_by_index(values, match):
    """numpy turned True into 1.0 beside numbers ((True, 2.0), [True, 0, 0]): a flag in a number's place was
    taken silently where an all-bool array is refused; an object array was refused as a whole. Each value that
    is not a number is now named with its index; an integer beyond float64 in as_number's words."""
    with pytest.raises(st.InvalidInputError, match=match):
        real_numbers(values, "x", "numbers")


def test_a_masked_spacing_or_origin_is_refused_not_read_under_its_mask():
    """_pair read np.asarray of a masked array: the value under the mask became dy, silently."""
    import numpy as np

    for name in ("spacing", "origin"):
        masked = np.ma.masked_array([30.0, -30.0], mask=[False, True])
        with pytest.raises(st.InvalidInputError, match=rf"^{name} must be a pair of finite numbers \(x, y\); got "):
            st.heightfield_mesh(_H, **{name: masked})
    assert st.heightfield_mesh(_H, spacing=np.ma.masked_array([30.0, -30.0])).metadata["spacing"] == (30.0, -30.0)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: st.Terrain.from_heights(_H, crs=5), r"^crs must be a str \(e.g. 'EPSG:32611'\) or None; got 5$"),
        (lambda: st.Terrain.from_heights(_H, crs=b"EPSG:4326"), r"^crs must be a str .*; got b'EPSG:4326'$"),
        (lambda: st.Terrain.from_heights(_H, source=object()), r"^source must be a str .* or None; got <object"),
        (lambda: st.Terrain.from_mesh(st.heightfield_mesh(_H), source=7), r"^source must be a str .* or None; got 7$"),
    ],
)
def test_crs_and_source_must_be_text(call, match):
    """Terrain.from_heights(crs=5, source=object()) stored them as they were, for the mesh metadata (and files
    written from it) to carry; they are named now."""
    with pytest.raises(st.InvalidInputError, match=match):
        call()
    assert st.Terrain.from_heights(_H, crs="EPSG:32611", source="dem.npy").crs == "EPSG:32611"


def test_numpy_scalars_stay_numbers():
    import numpy as np

    mesh = st.stepped(_H, interval=np.float32(1.0), base=np.int64(0), spacing=(np.float64(2.0), 3))
    assert len(mesh.faces) > 0
    assert st.look_from(np.float32(10.0), np.int16(5), np.float64(1.0e7)).eye is not None
