"""Off-screen pyvista renders lit so that the steps of a stepped terrain read (paper 000, Fig. 1 right).

A key light from the north-west at about 40° elevation plus a weaker fill from the camera's side gives
terraces one brightness and walls another (walls facing the key light bright, walls turned away from it
darker but readable), with flat shading so no normal is smoothed across a step edge. The camera is a fixed
oblique view from the south fitted to the mesh, so renders are reproducible. Typical use:

    image = render_mesh(stepterrain.stepped(stepterrain.sample_dem(), interval=100.0, colors="terrain"))
    save_png(image, "steps.png")
"""

from __future__ import annotations

import contextlib
import ctypes.util
import math
import numbers
import os
import sys
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from ._compaction import check_budget
from ._memo import derived
from ._signals import signals_held
from .camera import QUARTER_TURN
from .errors import InvalidInputError, MissingDependencyError, counted
from .mesh import check_face_indices, mesh_argument
from .terrain import check_flag, finite_or_nan, is_name, number_or_nan, real_numbers, real_vector

__all__ = ["render_mesh", "save_png", "offscreen_available", "require_offscreen", "KEY_LIGHT_AZIMUTH",
           "KEY_LIGHT_ELEVATION", "render_textured_mesh", "LayeredRenderer"]

#: Direction the key light comes from: azimuth clockwise from north (+y), radians (north-west).
KEY_LIGHT_AZIMUTH = math.radians(315.0)
#: Elevation of the key light above the horizon, radians.
KEY_LIGHT_ELEVATION = math.radians(40.0)
_KEY_INTENSITY = 0.8
_FILL_INTENSITY = 0.45
_FILL_ELEVATION = math.radians(30.0)
_AMBIENT = 0.2
_DIFFUSE = 0.9
#: The ambient of ``render_textured_mesh(lighting="relief")``: what the key and fill lights leave to make a level face
#: 1, its texture's own colour (the fill's azimuth follows the camera; a level face sees its elevation alone).
_RELIEF_AMBIENT = 1.0 - _DIFFUSE * (_KEY_INTENSITY * math.sin(KEY_LIGHT_ELEVATION)
                                    + _FILL_INTENSITY * math.sin(_FILL_ELEVATION))

#: The fixed oblique view: camera azimuth (clockwise from north, radians; 180° = looking from the south
#: towards the north) and elevation above the horizon.
_OBLIQUE = (math.radians(190.0), math.radians(45.0))
#: A fitted camera's margin: its eye lies this many times as far from the framed box's centre as the nearest eye
#: that sees all of it.
_FRAME_MARGIN = 1.06
#: How far off the view's axis (a fraction of its half-width) a fitted camera may leave the middle of the framed box
#: before it is placed exactly (:func:`_framing_eye`): the fit-and-recentre steps leave it within 2 % in a narrow view.
_CENTRED = 0.05
#: A fitted camera's least distance in front of the framed points, as a fraction of their depth along the view.
_STAND_OFF = 0.1
#: The least extent of a box a fitted camera shows: VTK draws in single precision, and a mesh smaller than about
#: 1e-37 (float32's least normal number is 1.2e-38) came back blank.
_LEAST_EXTENT = 1e-30
_VIEW_ANGLE = 30.0  # degrees, vertical field of view
_VIEW_ANGLE_RANGE = (1e-8, 179.0)  # degrees: VTK clamps a camera's view angle to this range
_DEFAULT_COLOR = (0.86, 0.82, 0.74)
#: add_mesh arguments pyvista otherwise takes from the plotter's theme (_default_theme's, not ``pv.global_theme``): a
#: pyvista user's theme (show_edges, opacity, silhouette, show_vertices) changed every render (edges over a textured
#: mesh or close-ups, a half-transparent terrain, dots at every vertex), and a LayeredRenderer values pass read the
#: edges' colour as values.
_UNTHEMED: dict[str, Any] = {"show_edges": False, "opacity": 1.0, "silhouette": False, "show_vertices": False,
                             "smooth_shading": False}

CameraLike = Literal["oblique", "top"] | tuple[float, float] | Sequence[Sequence[float]]

_backend_checked: str | None = None


def _select_backend() -> str:
    """Pick VTK's OpenGL window class for this process; raise when no offscreen context can exist."""
    global _backend_checked
    if _backend_checked is not None:
        return _backend_checked
    chosen = os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "")
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    if not chosen and sys.platform.startswith("linux") and not has_display:
        # no X server: go straight to EGL (Mesa llvmpipe or a GPU) or OSMesa rather than letting VTK try X
        if ctypes.util.find_library("EGL"):
            chosen = "vtkEGLRenderWindow"
        elif ctypes.util.find_library("OSMesa"):
            chosen = "vtkOSOpenGLRenderWindow"
        else:
            raise MissingDependencyError(
                "off-screen rendering needs an OpenGL context, but there is no display and neither libEGL "
                "nor libOSMesa was found; install Mesa (e.g. apt-get install libegl1 libgl1-mesa-dri, or "
                "libosmesa6) or run with a DISPLAY"
            )
        os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = chosen
    _backend_checked = chosen or "default"
    return _backend_checked


def _polydata(pv: Any, vertices: NDArray[Any], faces: NDArray[Any]) -> Any:
    """A triangle PolyData on these arrays, float64 points and int64 faces, as ``pv.wrap`` of a Trimesh gives.

    Built directly: a Trimesh refers to itself, so a temporary one holds its arrays until Python's cyclic
    collector runs (frame after frame in an animation).
    """
    points = np.asarray(vertices, dtype=np.float64)
    triangles = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    return pv.PolyData.from_regular_faces(points, triangles, deep=False)


def _default_theme(pv: Any) -> Any:
    """pyvista's default theme, for stepterrain's own plotters: ``pv.global_theme`` as a pyvista user set it (a camera
    orientation widget, edges, opacity, a silhouette, vertices shown) changed every render."""
    return pv.themes.DocumentTheme()


def _import_pyvista() -> Any:
    _select_backend()
    try:
        # Ctrl-C while VTK's extension modules load (pyvista.plotting's, on the first pv.Color or Plotter) crashed the
        # process (SIGSEGV) or came out as "ImportError: Failed to load vtkRenderingContextOpenGL2": held back, it is
        # a KeyboardInterrupt once they are loaded
        with signals_held():
            import pyvista
            import pyvista.plotting  # noqa: F401 - loaded here, not on pyvista's first use of it
    except ImportError as exc:  # pragma: no cover - pyvista is a core dependency
        raise MissingDependencyError(f"rendering needs pyvista: pip install 'pyvista>=0.44' ({exc})") from exc
    # every plotter here is made with off_screen=True; pyvista.OFF_SCREEN, which it set, is the caller's: set, it
    # kept every later pv.Plotter() and mesh.plot() of the process from opening a window
    return pyvista


#: Renders in progress in this process (every thread) that quieted VTK, and the caller's settings the first one saved:
#: :func:`_quiet_vtk` restores them when the last one ends.
_QUIET_LOCK = threading.Lock()
_quiet_depth = 0
_quiet_saved: tuple[int, int] = (1, 0)


@contextlib.contextmanager
def _quiet_vtk() -> Any:
    """VTK's warnings off and its log on stderr at errors only while stepterrain renders ("bad X server
    connection" and similar start-up warnings; real errors still raise), then both as they were. They were set
    for the whole process on the first render: a user's own VTK and pyvista code in it lost its warnings.

    Both settings are VTK's, for the whole process: renders in several threads at once keep them quiet until the last
    one ends, which restores what the first one found (each restoring what it found left them off for good when two
    overlapped: the second found the first's quiet settings and put them back after the first had restored)."""
    from vtkmodules.vtkCommonCore import vtkLogger, vtkObject

    global _quiet_depth, _quiet_saved
    with _QUIET_LOCK:
        if _quiet_depth == 0:
            # VTK has no getter for the stderr verbosity alone; the cutoff over all sinks is what pyvista.vtk_verbosity
            # reads
            _quiet_saved = (vtkObject.GetGlobalWarningDisplay(), vtkLogger.GetCurrentVerbosityCutoff())
            vtkObject.GlobalWarningDisplayOff()
            # a quieter setting stays
            vtkLogger.SetStderrVerbosity(min(_quiet_saved[1], vtkLogger.VERBOSITY_ERROR))
        _quiet_depth += 1
    try:
        yield
    finally:
        with _QUIET_LOCK:
            _quiet_depth -= 1
            if _quiet_depth == 0:
                vtkObject.SetGlobalWarningDisplay(_quiet_saved[0])
                vtkLogger.SetStderrVerbosity(_quiet_saved[1])


def _quietly(method: Any) -> Any:
    """``method`` run within :func:`_quiet_vtk`."""
    import functools

    @functools.wraps(method)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with _quiet_vtk():
            return method(*args, **kwargs)

    return wrapper


def require_offscreen() -> str:
    """Check cheaply that an off-screen OpenGL context can exist here; return the VTK window class chosen.

    Raises
    ------
    MissingDependencyError
        No display and neither EGL nor OSMesa is installed.
    """
    return _select_backend()


@_quietly
def offscreen_available() -> tuple[bool, str]:
    """(True, backend) when an off-screen OpenGL context can be made here, else (False, the reason).

    Cheap: it picks the backend and opens a 16 x 16 render window once.
    """
    try:
        pv = _import_pyvista()
        plotter = pv.Plotter(off_screen=True, window_size=(16, 16))
        try:
            if not plotter.render_window.SupportsOpenGL():
                return False, "VTK reports no OpenGL support for an off-screen window"
            plotter.add_mesh(pv.Sphere(theta_resolution=4, phi_resolution=4))
            image = plotter.screenshot(return_img=True)
        finally:
            plotter.close()
        if image is None or image.size == 0:
            return False, "the off-screen render window returned no image"
        return True, _backend_checked or "default"
    except MissingDependencyError as exc:
        return False, str(exc)
    except Exception as exc:  # noqa: BLE001 - any VTK failure means "unavailable"
        return False, f"{type(exc).__name__}: {exc}"


def _direction(azimuth: float, elevation: float) -> NDArray[np.float64]:
    """Unit vector pointing *towards* the light/camera: azimuth clockwise from north (+y), elevation up."""
    return np.array([
        math.sin(azimuth) * math.cos(elevation),
        math.cos(azimuth) * math.cos(elevation),
        math.sin(elevation),
    ])


def _screen_axes(forward: NDArray[np.float64], up: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The unit right vector and the true up vector of a camera looking along the unit ``forward``."""
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward)


def _fit_distance(corners: NDArray[np.float64], view_dir: NDArray[np.float64], up: NDArray[np.float64],
                  aspect: float, view_angle: float = _VIEW_ANGLE) -> float:
    """Distance from the box centre along ``view_dir`` at which every corner lies inside the view frustum
    (``view_angle``: its vertical field of view, degrees); at least 1e-9 of the corners' box size (an absolute 1e-9
    framed a mesh smaller than about 1e-10 from afar, and refused it as too thin to see)."""
    forward = -view_dir
    right, true_up = _screen_axes(forward, up)
    tan_v = math.tan(math.radians(view_angle) / 2.0)
    tan_h = tan_v * aspect
    depth = corners @ forward  # corner offset along the viewing direction (positive: farther away)
    need_v = np.abs(corners @ true_up) / tan_v - depth
    need_h = np.abs(corners @ right) / tan_h - depth
    # the box's size, not its corners' reach from the focal point (that of a single point shrank to 1e-300 as the
    # focal point moved, the eye landing on it): 0, a single point, seen from 1e-9
    size = float(np.ptp(corners, axis=0).max())
    return float(max(need_v.max(), need_h.max(), 1e-9 * (size if size > 0 else 1.0)))


def _framing_eye(points: NDArray[np.float64], forward: NDArray[np.float64], right: NDArray[np.float64],
                 up: NDArray[np.float64], aspect: float, view_angle: float = _VIEW_ANGLE) -> NDArray[np.float64]:
    """The eye of a camera looking along the unit ``forward`` (screen axes ``right`` and ``up``, vertical field of
    view ``view_angle`` degrees, width / height ``aspect``) that frames ``points`` (N, 3): the nearest eye that sees
    them all, :data:`_FRAME_MARGIN` times as far from their box's centre (along ``forward``), and placed across the
    view so that their extreme directions are symmetric about its axis on both screen axes (centred on screen).

    Exact: a point p lies in the view of the eye at depth w (along ``forward``) and offsets u, v (along ``right``,
    ``up``) iff ``|p_r - u| <= tan_h (p_f - w)`` and ``|p_u - v| <= tan_v (p_f - w)`` (p_r, p_u, p_f: its
    coordinates), so along each screen axis w <= A + u / tan and w <= B - u / tan, A and B the least p_f -/+ p_r / tan:
    the nearest eye has the smaller of the axes' (A + B) / 2, kept :data:`_STAND_OFF` of the points' depth in front of
    them. At each axis's offsets from (w - A) tan to (B - w) tan every point is in view, and the sum of the extreme
    directions falls as the offset grows: bisection finds where it is 0. :func:`_camera_position` takes it where its
    fit-and-recentre steps leave the points off centre: in a wide view (view_angle 120 and more) their whole steps
    overshot, the near corners swinging from one side of the picture to the other, and the last left the mesh
    against one edge of it (from 170 degrees not drawn at all)."""
    tan_v = math.tan(math.radians(view_angle) / 2.0)
    tans = (tan_v * aspect, tan_v)
    origin = (points.min(axis=0) + points.max(axis=0)) / 2  # precise near the points
    rel = points - origin
    along, across = rel @ forward, (rel @ right, rel @ up)
    bounds = [(float((along - s / tan).min()), float((along + s / tan).min()))
              for s, tan in zip(across, tans, strict=True)]
    # in a view wide enough to see all of the points from the nearest of them, the nearest eye lies on it (a box's
    # corner), and the near plane cut its surroundings away: the eye stays in front of them
    stand_off = max(_STAND_OFF * float(along.max() - along.min()), 1e-9 * float(np.abs(rel).max()), 1e-300)
    w = min(min((a + b) / 2 for a, b in bounds), float(along.min()) - stand_off)
    w -= (_FRAME_MARGIN - 1.0) * abs(w)  # the margin: farther from the box's centre (depth 0)
    depth = along - w
    offsets = []
    for s, tan, (a, b) in zip(across, tans, bounds, strict=True):
        lo, hi = (w - a) * tan, (b - w) * tan
        for _ in range(64 if lo < hi else 0):
            mid = (lo + hi) / 2
            direction = (s - mid) / depth
            if direction.max() + direction.min() > 0:
                lo = mid
            else:
                hi = mid
        offsets.append((lo + hi) / 2)
    return origin + right * offsets[0] + up * offsets[1] + forward * w


def _camera_position(
    camera: CameraLike, points: NDArray[np.float64], aspect: float, view_angle: float = _VIEW_ANGLE
) -> list[tuple[float, ...]]:
    """A pyvista camera position [(eye), (focal point), (view up)] framing ``points`` (N, 3), centred."""
    if isinstance(camera, str):
        if camera == "oblique":
            azimuth, elevation = _OBLIQUE
        elif camera == "top":
            azimuth, elevation = math.pi, math.radians(89.9)
        else:
            raise InvalidInputError(f"camera must be 'oblique', 'top', (azimuth, elevation) or a pyvista "
                                    f"camera position; got {camera!r}")
    else:
        try:  # real_numbers: ("1", "2") and (True, False) are no angles
            spec = real_numbers(camera, "camera", "angles or points")
        except InvalidInputError as exc:
            raise InvalidInputError(f"camera must be 'oblique', 'top', (azimuth, elevation) in radians or "
                                    f"[(eye), (focal point), (view up)]; got {camera!r}") from exc
        if spec.shape == (3, 3) and np.all(np.isfinite(spec)):
            _check_position(spec, camera)
            return [tuple(row) for row in spec.tolist()]
        if spec.shape != (2,) or not np.all(np.isfinite(spec)):
            raise InvalidInputError(f"camera must be 'oblique', 'top', (azimuth, elevation) in radians or "
                                    f"[(eye), (focal point), (view up)]; got {camera!r}")
        if abs(float(spec[1])) > QUARTER_TURN:  # clipped to +-89.9 degrees: camera=(190, 45), degrees for radians,
            # rendered the top view without a word (--camera refuses an EL beyond +-90 degrees alike)
            raise InvalidInputError(f"camera's elevation must lie in [-π/2, π/2] radians (-90 to 90 degrees, "
                                    f"math.radians(degrees)); got {camera!r}, elevation {float(spec[1]):g}")
        azimuth, elevation = float(spec[0]), float(np.clip(spec[1], -math.radians(89.9), math.radians(89.9)))
    view_dir = _direction(azimuth, elevation)
    if abs(elevation) < math.radians(89.0):
        up = np.array([0.0, 0.0, 1.0])
    else:  # nearly vertical: +z's own direction on screen (the far side up), as just below 89° (+y turned the image)
        up = -math.copysign(1.0, elevation) * np.array([math.sin(azimuth), math.cos(azimuth), 0.0])
    corners = points
    focal = (corners.min(axis=0) + corners.max(axis=0)) / 2
    forward = -view_dir
    right, true_up = _screen_axes(forward, up)
    for _ in range(4):  # fit, then recentre the projected box on screen, and fit again
        distance = _fit_distance(corners - focal, view_dir, up, aspect, view_angle)
        eye = focal + view_dir * distance
        rel = corners - eye
        depth = rel @ forward
        sx = (rel @ right) / depth
        sy = (rel @ true_up) / depth
        shift = right * (sx.max() + sx.min()) / 2 + true_up * (sy.max() + sy.min()) / 2
        focal = focal + shift * distance
    distance = _fit_distance(corners - focal, view_dir, up, aspect, view_angle) * _FRAME_MARGIN
    eye = focal + view_dir * distance
    if not _off_centre(corners, eye, forward, (right, true_up), aspect, view_angle):
        return [tuple(eye.tolist()), tuple(focal.tolist()), tuple(up.tolist())]
    # a wide view (view_angle 120 and more): the steps above overshot, the near corners swinging from one side of the
    # picture to the other, and the last left the mesh against one edge (from 170 degrees not drawn at all)
    eye = _framing_eye(points, forward, right, true_up, aspect, view_angle)
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    focal = eye + forward * max(float((centre - eye) @ forward), float(((points - eye) @ forward).min()))
    return [tuple(eye.tolist()), tuple(focal.tolist()), tuple(up.tolist())]


def _off_centre(points: NDArray[np.float64], eye: NDArray[np.float64], forward: NDArray[np.float64],
                axes: tuple[NDArray[np.float64], NDArray[np.float64]], aspect: float, view_angle: float) -> bool:
    """Whether ``points`` seen from ``eye`` (looking along ``forward``, screen axes ``axes``: right, up) lie partly
    outside the view or off its centre: the middle of their extreme directions on a screen axis more than
    :data:`_CENTRED` of the view's half-width from its axis."""
    rel = points - eye
    depth = rel @ forward
    if not (depth > 0).all():
        return True
    tan_v = math.tan(math.radians(view_angle) / 2.0)
    for axis, tan in zip(axes, (tan_v * aspect, tan_v), strict=True):
        direction = (rel @ axis) / depth
        if np.abs(direction).max() > tan or abs(direction.max() + direction.min()) / 2 > _CENTRED * tan:
            return True
    return False


def _check_position(spec: NDArray[np.float64], camera: Any) -> None:
    """An InvalidInputError unless the explicit camera position (3, 3) has an eye apart from its focal point and
    a view up that is neither zero nor parallel to the view direction: VTK rendered such a camera blank (or
    raised its own ValueError for a zero up), without naming the camera."""
    eye, focal, up = spec
    with np.errstate(over="ignore", invalid="ignore"):
        forward = focal - eye
        length, up_length = float(np.linalg.norm(forward)), float(np.linalg.norm(up))
        usable = (math.isfinite(length) and length > 0 and math.isfinite(up_length) and up_length > 0
                  and float(np.linalg.norm(np.cross(forward / length, up / up_length))) > 1e-9)
    if not usable:
        raise InvalidInputError(
            f"camera [(eye), (focal point), (view up)] needs an eye apart from its focal point and a view up that is "
            f"neither zero nor parallel to the view direction (all within float64 range); got {camera!r}")


def _lights(pv: Any, bounds: NDArray[np.float64], fill: tuple[float, float]) -> list[Any]:
    """Directional key light from the north-west at ~40° elevation, and a weaker fill from ``fill``.

    The fill comes from the camera's side (azimuth, elevation in radians), so walls turned away from the key
    light stay readable instead of black.
    """
    centre = bounds.mean(axis=0)
    size = float(np.linalg.norm(bounds[1] - bounds[0])) or 1.0
    key_dir = _direction(KEY_LIGHT_AZIMUTH, KEY_LIGHT_ELEVATION)
    fill_dir = _direction(*fill)
    lights = []
    for direction, intensity in ((key_dir, _KEY_INTENSITY), (fill_dir, _FILL_INTENSITY)):
        light = pv.Light(position=tuple((centre + direction * size).tolist()),
                         focal_point=tuple(centre.tolist()), color="white", light_type="scene light",
                         intensity=intensity)
        light.positional = False
        lights.append(light)
    return lights


def _colors_rgb(mesh: trimesh.Trimesh, kind: Literal["vertex", "face"]) -> NDArray[np.uint8] | None:
    """The mesh's colours, (N, 3) uint8, or (N, 4) when some alpha is below 255, when its visual holds one per
    ``kind`` ("vertex": a stepped terrain's; "face": a PLY or 3MF read back), else None. The alpha was dropped: a
    mesh coloured semi-transparent (as its GLB shows it, alphaMode BLEND) rendered opaque."""
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == kind:
        colors = np.asarray(visual.vertex_colors if kind == "vertex" else visual.face_colors)
        if colors.shape == (len(mesh.vertices if kind == "vertex" else mesh.faces), 4):
            translucent = len(colors) and int(colors[:, 3].min()) < 255
            return np.ascontiguousarray(colors if translucent else colors[:, :3], dtype=np.uint8)
    return None


_TRIMESH_GRAY = np.asarray(trimesh.visual.color.DEFAULT_COLOR[:3], dtype=np.uint8)  # SimpleMaterial's diffuse=None


def _material_rgb(mesh: trimesh.Trimesh) -> NDArray[np.uint8] | None:
    """Per vertex, the colour of a mesh's material without a texture, (N, 3) uint8 or (N, 4) where it blends, as a
    glTF or OBJ viewer shows it; None when the visual has no such material. A PBR material's baseColorFactor is
    linear (glTF §3.9.2): shown sRGB-encoded, its alpha used as the material's alphaMode says (as
    :func:`_base_color_factor` and :func:`_texture_alpha` treat a texture's); a plain material's (an OBJ's ``Kd``)
    diffuse colour as it is (a ``.mtl`` that names no ``Kd``, which trimesh fills with its grey, is no colour). A GLB
    of one plain-coloured mesh (trimesh reads it as TextureVisuals without UVs) and an OBJ with a ``.mtl`` rendered
    in the uniform tan instead. An opaque white factor is no colour (None): the material
    :func:`~stepterrain.export.save_mesh` writes for a mesh without colours, which
    :func:`~stepterrain.export.read_mesh` reads back as plain, renders in the tan as the mesh did.

    A ``SimpleMaterial`` whose diffuse is trimesh's grey (102, 102, 102) and that holds no ``kd`` is taken for the
    filler too, so one built as ``SimpleMaterial(diffuse=(102, 102, 102))`` renders in the tan: nothing tells the two
    apart. trimesh fills an absent diffuse with its ``DEFAULT_COLOR`` array itself, but its OBJ reader and
    ``mesh.copy()`` copy it, and an ``.mtl`` of a ``newmtl`` line alone gives a material with no kwargs and that grey,
    the same object as the hand-built one."""
    visual = mesh.visual
    material = getattr(visual, "material", None)
    if not isinstance(visual, trimesh.visual.TextureVisuals) or material is None:
        return None
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        factor = material.baseColorFactor
        if factor is None or (np.asarray(factor) == 255).all():  # white multiplies nothing: the material save_mesh
            return None  # gives a mesh without colours, read_mesh reads as plain (trimesh.load as this material)
        white = np.full((1, 1, 3), 255, dtype=np.uint8)
        color = _texture_alpha(_base_color_factor(white, material), material).reshape(-1)
    elif isinstance(material, trimesh.visual.material.SimpleMaterial) and material.diffuse is not None:
        color = np.asarray(material.diffuse, dtype=np.uint8).reshape(-1)[:3]
        if "kd" not in (getattr(material, "kwargs", None) or {}) and (color == _TRIMESH_GRAY).all():
            return None  # an .mtl without Kd (or a material built without a diffuse): trimesh's filler, no colour
    else:
        return None
    return np.ascontiguousarray(np.broadcast_to(color, (len(mesh.vertices), len(color))))


def render_mesh(
    mesh: trimesh.Trimesh,
    *,
    window_size: tuple[int, int] = (1280, 800),
    z_scale: float = 1.0,
    camera: CameraLike = "oblique",
    background: str | tuple[float, float, float] = "white",
    scalars: Literal["level", "height"] | None = None,
    cmap: str = "terrain",
    show_edges: bool = False,
    anti_aliasing: bool = False,
    bounds: ArrayLike | None = None,
    view_angle: float = _VIEW_ANGLE,
) -> NDArray[np.uint8]:
    """Render ``mesh`` off-screen and return the image.

    Parameters
    ----------
    mesh : trimesh.Trimesh or pyvista.PolyData
        Any triangle mesh (a PolyData of triangles as its Trimesh, see
        :func:`~stepterrain.pyvista_accessor.from_polydata`); it renders with its vertex colors (a stepped
        terrain's), or else its face colors, when it has them, their alpha included: colours with some alpha below
        255 blend with what lies behind them (in depth order, by depth peeling), as the mesh's GLB shows them. A
        textured mesh (``TextureVisuals`` with one UV per vertex and an image: :func:`~stepterrain.texture.drape`'s,
        a GLB read back) renders with its texture, lit, as :func:`render_textured_mesh` with ``lighting=True`` draws
        it (which also draws it unlit).
    window_size : (width, height)
        Image size in pixels: two whole numbers, each 8 to 16384.
    z_scale : float
        Vertical exaggeration applied for the render only (the mesh is not modified); default 1, true
        proportions (the CLI's ``--z-scale`` defaults to 2).
    camera : "oblique", "top", (azimuth, elevation) or [(eye), (focal point), (view up)]
        "oblique" is the fixed reproducible view from just west of south at 45° elevation; a pair gives the
        direction the camera looks from (radians, azimuth clockwise from north = +y, elevation in [-π/2, π/2]: one
        beyond is refused, as degrees given for radians), +z up in the image at every elevation (seen from above the
        far side is up, from below, a negative elevation, the near side); "top"
        looks straight down, north (+y) up and east (+x) to the right. All are fitted to the bounds. An explicit
        pyvista camera position is used as given, in the mesh's coordinates minus the centre of ``bounds`` (else of
        the box of the vertices drawn), z times ``z_scale`` (the render recentres the mesh to keep UTM-sized
        coordinates precise); one that sees none of the mesh (given in the mesh's own coordinates, or looking away),
        or shows it less than a pixel wide or tall (too far off), is refused, as it rendered blank.
    background : color
        Any pyvista color: a name, '#rrggbb', (r, g, b) floats in [0, 1] or whole numbers in 0-255 (whole numbers
        all 0 or 1, such as (1, 0, 0), are refused as ambiguous, as are whole numbers other than 0 beside floats,
        such as (1, 0.5, 0); (0, 0.5, 1.0) is taken). Opaque: one with an alpha below 1 is refused (the
        image has no alpha channel).
    scalars : None, "level" or "height"
        None: the mesh's texture or vertex colors if it has them, else its face colors, else its material's colour (a
        plain-coloured GLB's baseColorFactor other than opaque white, an OBJ's ``Kd``), else a uniform light tan.
        A ``SimpleMaterial`` of trimesh's default grey (102, 102, 102) without an OBJ ``Kd`` is taken for no colour
        (trimesh gives a material without a diffuse that grey, and the two cannot be told apart): give such a grey as
        vertex colours, or as (102, 102, 103).
        "level": faces colored by ``face_attributes["level"]`` (stepped meshes); "height": vertices colored by z, the
        colormap spanning the heights of the vertices drawn (finite, used by a face). Both use ``cmap``.
    cmap : str
        Matplotlib colormap for ``scalars`` (with ``scalars=None`` unused, but it must still be a str).
    show_edges : bool
        Draw triangle edges.
    anti_aliasing : bool
        Multi-sample anti-aliasing (off by default: reproducible, and faster on software OpenGL).
    bounds : (2, 3) array_like, optional
        A world-space box [(xmin, ymin, zmin), (xmax, ymax, zmax)] to frame instead of the mesh itself: the
        same box for every frame of an animation keeps the camera still. A fitted camera needs a box of some size
        (a single point is refused) around the mesh: one that frames none of it, or shows it less than a pixel wide
        or tall (a box in other coordinates than the mesh's, or far larger), is refused, as it rendered blank; an
        explicit camera position takes only its centre.
    view_angle : float
        The camera's vertical field of view in degrees, in [1e-8, 179] (VTK's range; default 30); the horizontal
        one follows from the window's aspect. A fitted camera frames the bounds with it.

    Returns
    -------
    (H, W, 3) uint8
        The rendered image, H = window_size[1], W = window_size[0].

    Raises
    ------
    InvalidInputError
        Bad window size, z_scale, camera, scalars, cmap or view_angle, an empty mesh, one whose faces all have no
        area (it renders blank) or whose faces, slivers, cover less than a pixel in all from the fitted camera,
        ``bounds`` whose fitted camera sees none of the mesh (given in other coordinates),
        a mesh shown less than a pixel wide or tall within its ``bounds`` or by an explicit camera (it renders
        blank), an infinite vertex (NaN ones are left out), or a textured mesh's bad UVs or texture image (as
        :func:`render_textured_mesh`).
    OutputTooLargeError
        The render's framebuffers and image (about 48 bytes per pixel, 80 with ``anti_aliasing``, 288 with it and
        translucent colours, which take SSAA with depth peeling), with a textured mesh's texture (16 bytes per
        texel) and the copies of the mesh made for rendering (about 40 bytes per face, 64 with face colours, and
        112 per vertex: an 18 M-face stepped mesh needs 1.7 GiB in any window), exceed the memory budget
        (:func:`stepterrain.set_memory_budget`), checked before rendering.
    MissingDependencyError
        No off-screen OpenGL context can be made (no display, no EGL/OSMesa).

    Notes
    -----
    Flat shading: each face keeps its own normal, so terraces (normal +z) and walls (horizontal normals)
    get different brightness from the key light and no step edge is smoothed away. Vertices are recentred
    (float64) before VTK sees them. Cost on software OpenGL (Mesa llvmpipe, 2 cores): about a second per
    million faces, most of it uploading the geometry.
    """
    if not is_name(scalars, (None, "level", "height")):
        raise InvalidInputError(f"scalars must be None, 'level' or 'height'; got {scalars!r}")
    show_edges = check_flag(show_edges, "show_edges")
    anti_aliasing = check_flag(anti_aliasing, "anti_aliasing")
    if scalars is not None:
        from .stepped import colormap

        colormap(cmap, argument="cmap")  # matplotlib's ValueError (or a TypeError for cmap=5) named nothing
    elif not isinstance(cmap, str):  # unused without scalars and passed unchecked; the name is looked up when used
        raise InvalidInputError(f"cmap must name a matplotlib colormap (e.g. 'terrain', 'viridis'); got {cmap!r}")
    view_angle = _check_view_angle(view_angle)
    mesh = mesh_argument(mesh)  # a pyvista PolyData (grid.stepterrain.stepped's) as its Trimesh
    width, height, vertices, local, finite, box, position = _frame_mesh(mesh, window_size, z_scale, bounds, camera,
                                                                        anti_aliasing, view_angle)
    source = _texture_source(mesh) if scalars is None else None
    size = (len(vertices), len(mesh.faces))  # the mesh's copies count too (_frame_mesh checked them uncoloured)
    if source is not None:  # its texels count too (only the window did: a 17000² texture took 4.6 GB), counted
        # from its size before it is decoded (a PIL image opened from a file: decoding it was the largest allocation)
        _check_render_budget(width, height, anti_aliasing=anti_aliasing, texture=_texture_shape(source[1]), mesh=size)
    # the picture as drawn: a globe drape's is widened by _periodic_columns (256 columns each side and more: 13-25 %
    # of the Blue Marble's), counted by its check= before it is made (any other keeps the size counted above)
    textured = None if source is None else _decoded_texture(*source, check=lambda shape: _check_render_budget(
        width, height, anti_aliasing=anti_aliasing, texture=shape, mesh=size))
    face_attributes = {}
    if scalars == "level":
        if "level" not in mesh.face_attributes:
            raise InvalidInputError("scalars='level' needs face_attributes['level'] (a stepped mesh)")
        given = mesh.face_attributes["level"]
        try:
            with np.errstate(over="ignore"):  # a level beyond float32 becomes inf, named below
                levels = np.asarray(given, dtype=np.float32).reshape(-1)
        except (TypeError, ValueError, OverflowError):  # OverflowError: a Python int beyond float (10**400)
            levels = None
        # what is wrong, named: a NaN level (or one beyond float32) was reported as its shape alone, "got (2,)" for
        # two faces, and values that are no numbers ('a') likewise
        got = None
        if levels is None:
            try:
                got = f"{np.asarray(given).dtype} values"
            except ValueError:  # a ragged list (face_attributes is a dict: kept as given): numpy's ValueError again
                got = f"a ragged {type(given).__name__}"
        elif levels.shape != (len(mesh.faces),):
            got = f"shape {np.shape(given)}"
        elif not np.isfinite(levels).all():
            k = int(np.flatnonzero(~np.isfinite(levels))[0])
            got = f"{np.asarray(given, dtype=np.float64).reshape(-1)[k]:g} at face {k}"
        if got is not None:
            raise InvalidInputError(f"face_attributes['level'] must hold one finite number per face "
                                    f"({len(mesh.faces)}); got {got}")
        face_attributes["level"] = levels

    rgb = _colors_rgb(mesh, "vertex") if scalars is None else None
    face_rgb = _colors_rgb(mesh, "face") if scalars is None and rgb is None else None
    if scalars is None and textured is None and rgb is None and face_rgb is None:
        rgb = _material_rgb(mesh)  # one colour, as a vertex colour: alpha and depth peeling as for those
    if face_rgb is not None:  # a colour per face costs more than one per vertex
        _check_render_budget(width, height, anti_aliasing=anti_aliasing, mesh=size, face_colors=True)

    pv = _import_pyvista()
    _check_background(pv, background)
    poly = _polydata(pv, local, mesh.faces)
    for key, value in face_attributes.items():
        poly.cell_data[key] = value
    add_kwargs: dict[str, Any] = {}
    if textured is not None:  # it drew in the plain tan: a draped DEM or a GLB read back lost its texture
        add_kwargs.update(texture=_texture(pv, poly, *textured, clamp=_clamped(source[2])))
    elif rgb is not None:
        poly.point_data["rgb"] = rgb
        add_kwargs.update(scalars="rgb", rgb=True)
    elif face_rgb is not None:
        poly.cell_data["rgb"] = face_rgb
        add_kwargs.update(scalars="rgb", rgb=True, preference="cell")
    elif scalars == "level":
        add_kwargs.update(scalars="level", cmap=cmap, preference="cell", show_scalar_bar=False)
    elif scalars == "height":
        # the colormap spans the heights drawn: a vertex no face uses (a mesh cut down with update_faces, a PLY's loose
        # points) stretched it, as it no longer stretches the framing, and the drawn part took a sliver of its colours
        heights = vertices[:, 2].astype(np.float32)
        heights[~finite] = np.nan  # not drawn; NaN is left out of the range
        poly.point_data["height"] = heights
        add_kwargs.update(scalars="height", cmap=cmap, show_scalar_bar=False)
    else:
        add_kwargs.update(color=_DEFAULT_COLOR)

    mesh_kwargs = dict(smooth_shading=False, show_edges=show_edges, ambient=_AMBIENT, diffuse=_DIFFUSE,
                       specular=0.0, lighting=True, **add_kwargs)
    translucent = (any(colors is not None and colors.shape[1] == 4 for colors in (rgb, face_rgb))
                   or (textured is not None and textured[1].ndim == 3 and textured[1].shape[2] == 4))
    if translucent and anti_aliasing:  # SSAA, not MSAA (see _shoot): more memory
        _check_render_budget(width, height, anti_aliasing=True, ssaa=True,
                             texture=None if textured is None else textured[1].shape, mesh=size,
                             face_colors=face_rgb is not None)
    return _shoot(pv, poly, mesh_kwargs, local=local, faces=mesh.faces, finite=finite, box=box,
                  position=position, size=(width, height), background=background, anti_aliasing=anti_aliasing,
                  lighting=True, translucent=translucent, view_angle=view_angle)


def _check_view_angle(view_angle: Any) -> float:
    """``view_angle`` as a float in :data:`_VIEW_ANGLE_RANGE` degrees, else an InvalidInputError naming it."""
    lo, hi = _VIEW_ANGLE_RANGE
    if not lo <= number_or_nan(view_angle) <= hi:  # VTK clamps the view angle to its range: a different picture
        raise InvalidInputError(f"view_angle must be a vertical field of view in [{lo:g}, {hi:g}] degrees; got "
                                f"{view_angle!r}")
    return float(view_angle)


#: The largest half-extent of a framed box (z scaled): the camera fit squares distances, which overflow float64
#: beyond ~1.3e154 (RuntimeWarnings, then a blank image or a misleading "0 x 0 pixels").
_MAX_REACH = 1e150


def _check_reach(box: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64], z_scale: float,
                 subject: str, too_large: str, about: str) -> None:
    """Refuse a z-scaled ``box`` (lowest and highest corner about ``about``) beyond ±:data:`_MAX_REACH`, where the
    camera's squared distances overflow float64 (RuntimeWarnings and a blank image): named as ``subject`` made too
    tall by ``z_scale`` when only z is beyond, else by ``too_large``."""
    reach = np.abs(box).max(axis=0)
    if (reach <= _MAX_REACH).all():
        return
    what = (f"z_scale={z_scale:g} makes {subject} {hi[2] - lo[2]:g} x {z_scale:g} tall"
            if (reach[:2] <= _MAX_REACH).all() else too_large)
    raise InvalidInputError(f"{what}: beyond ±{_MAX_REACH:g} about {about} the camera's squared distances overflow "
                            "float64")


def _fmt_box(lo: NDArray[np.float64], hi: NDArray[np.float64]) -> str:
    return f"[{', '.join(f'{v:g}' for v in lo)}] - [{', '.join(f'{v:g}' for v in hi)}]"


def _frame_mesh(
    mesh: trimesh.Trimesh, window_size: tuple[int, int], z_scale: float, bounds: ArrayLike | None,
    camera: CameraLike, anti_aliasing: bool = False, view_angle: float = _VIEW_ANGLE,
) -> tuple[int, int, NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64], Any]:
    """Check the arguments every render shares (before pyvista loads, so a bad one is named even where it
    is missing); return (width, height, vertices, local vertices recentred on the framed box with z scaled,
    mask of the vertices drawn (finite and used by a face), local box, the render's pyvista camera position). The
    window's memory is checked against the budget first. The camera is fitted to the vertices drawn: those no face
    uses (trimesh's ``update_faces`` keeps every vertex, a PLY may hold loose points) framed the whole of them, a mesh
    cut down to a part rendered as a small patch in a picture framed for all of it."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh; got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise InvalidInputError("mesh has no faces; nothing to render")
    width, height, z_scale = _check_window(window_size, z_scale)
    # the mesh's copies too, before the first of them (the recentred vertices below)
    _check_render_budget(width, height, anti_aliasing=anti_aliasing, mesh=(len(mesh.vertices), len(mesh.faces)))
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    check_face_indices(mesh.faces, len(vertices), "mesh.faces")  # VTK read an index past the end from outside
    # the point buffer (garbage triangles, or a crash), without an error
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():  # an infinite vertex, even one no face uses, left VTK's render blank, without a word
        finite_or_nan(vertices, "mesh.vertices")
    used = np.zeros(len(vertices), dtype=bool)
    used[np.asarray(mesh.faces).reshape(-1)] = True
    finite &= used
    if not finite.any():
        raise InvalidInputError("mesh has no finite vertex used by a face")
    fitted = _fitted_camera(camera)  # a name or (azimuth, elevation), not an explicit position
    thin = False  # seen a few pixels across by a camera fitted to its vertices (see _check_covers_a_pixel)
    if bounds is None:
        lo, hi = vertices[finite].min(axis=0), vertices[finite].max(axis=0)
    else:
        given = _check_box(bounds, "bounds")
        if fitted:
            _check_fitted_box(given, "bounds")
        lo, hi = given
    centre = (lo + hi) / 2.0
    local = vertices - centre
    box = np.array([lo - centre, hi - centre])
    with np.errstate(over="ignore", invalid="ignore"):  # beyond float64: refused below, not RuntimeWarnings
        local[:, 2] *= z_scale
        box[:, 2] *= z_scale
    _check_reach(box, lo, hi, z_scale, "the mesh", f"the framed box {_fmt_box(lo, hi)} is too large", "its centre")
    corners = _box_corners(box)
    position = _camera_position(camera, corners, width / height, view_angle)  # raises on a bad camera; 8 corners
    # the box of the vertices drawn (the framed box itself without bounds), no copy of them: with bounds one pass over
    # them, for the in-view check and the area check below (each of them took its own)
    drawn_box = box if bounds is None else np.array([
        np.min(local, axis=0, where=finite[:, None], initial=np.inf),
        np.max(local, axis=0, where=finite[:, None], initial=-np.inf)])
    if fitted:  # a fitted camera: it frames the box's larger side
        _check_visible(corners, position, (width, height), box, z_scale, view_angle, camera,
                       "the mesh" if bounds is None else "bounds")
        if bounds is not None:  # the box is seen; the mesh within it (or not) too?
            _check_mesh_in_bounds(drawn_box, position, (width, height), view_angle, centre, z_scale, lo, hi)
    else:
        _check_in_view(drawn_box, position, width / height, view_angle, centre, z_scale, camera)
        pixels = _box_pixels(drawn_box, position, (width, height), view_angle)
        if pixels is not None and min(pixels) < 1.0:  # seen, but too far off (or too thin) to cover a pixel
            raise InvalidInputError(
                f"camera [(eye), (focal point), (view up)] shows the mesh at most {pixels[0]:.2g} x {pixels[1]:.2g} "
                f"pixels, too small to see (it would render blank): its faces span "
                f"{' x '.join(f'{v:.3g}' for v in (drawn_box[1] - drawn_box[0]).tolist())} (z times "
                f"z_scale={z_scale:g}) and the eye is {float(np.linalg.norm(position[0])):.3g} from the centre of the "
                f"framed box; move the eye nearer or give a larger window_size; got {camera!r}", too_small_to_see=True)
    if bounds is None and fitted:  # the camera the render takes: fitted to the vertices drawn themselves, not their
        # box (an explicit position is the one above, as given)
        drawn = local if finite.all() else local[finite]
        position = _fit_points(camera, drawn, width / height, view_angle)
        # the surface within its box may show thinner than the box: the embedded DEM seen 11° up in an 8 x 500
        # window spans 0.94 pixels (its box 1.5) and rendered blank, without a word. The extent of a strided
        # subset is at most the whole's: the whole is projected only when that one is under a pixel
        thinnest = min(_pixel_extent(drawn[::max(1, len(drawn) // 100_000)], position, (width, height), view_angle))
        if thinnest < 1.0:
            _check_visible(drawn, position, (width, height), box, z_scale, view_angle, camera, "the mesh")
        thin = thinnest < _THIN_PIXELS  # a few pixels across: its faces may still cover none (slivers), below
    # last: the checks above name what they find first. The drawn box is at hand: its span is free, where a pass over
    # the vertices took 50 ms a million vertices (0.17 s for a 3.4M-vertex stepped mesh)
    _check_some_area(local, mesh.faces, finite, z_scale, drawn_box[1] - drawn_box[0])
    if thin:  # faces of some area in space (a degenerate mesh is named so, above), but do they cover a pixel?
        _check_covers_a_pixel(local, mesh.faces, position, (width, height), view_angle)
    return width, height, vertices, local, finite, box, position


#: A mesh drawn fewer pixels across than this (one way) by a fitted camera has the area its faces cover checked
#: (:func:`_check_covers_a_pixel`); a wider one covers pixels wherever its faces have some area.
_THIN_PIXELS = 32.0


def _check_covers_a_pixel(local: NDArray[np.float64], faces: ArrayLike, position: Any, size: tuple[int, int],
                          view_angle: float) -> None:
    """An InvalidInputError when the faces drawn (corners finite) of a mesh seen thin by the fitted camera
    ``position`` cover less than one pixel in all, projected: slivers (a triangle 1e6 long and 1 wide, seen oblique)
    rendered blank without a word, their box a few pixels wide passing :func:`_check_visible` and their area in
    space passing :func:`_check_some_area`. Chunked, stopping at a pixel covered; a face at or behind the eye stops it
    too (its projection is not bounded)."""
    width, height = size
    scale = height / (2.0 * math.tan(math.radians(view_angle) / 2.0))  # pixels per unit of the image plane, both ways
    faces = np.asarray(faces)
    covered = 0.0
    for start in range(0, len(faces), _AREA_CHUNK):
        rel, depth, right, true_up = _eye_frame(local[faces[start:start + _AREA_CHUNK]], position)  # (n, 3 corners)
        drawn = np.isfinite(rel).all(axis=(1, 2))
        rel, depth = rel[drawn], depth[drawn]
        if (depth <= 0).any():
            return
        x, y = (rel @ right) / depth * scale, (rel @ true_up) / depth * scale
        covered += 0.5 * float(np.abs((x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0])
                                      - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])).sum())
        if covered >= 1.0:
            return
    raise InvalidInputError(
        f"the mesh's faces would cover {covered:.2g} pixels in all from a camera fitted to it, in a "
        f"{width}x{height} window: they are slivers, too thin to see (it would render blank); look from another "
        "direction (camera) or give a larger window_size", too_small_to_see=True)


#: Faces checked at a time by :func:`_check_some_area` (it stops at the first chunk with a face of some area).
_AREA_CHUNK = 65536


def _check_some_area(local: NDArray[np.float64], faces: ArrayLike, finite: NDArray[np.bool_],
                     z_scale: float = 1.0, span: NDArray[np.float64] | None = None) -> None:
    """An InvalidInputError when no face drawn (all its corners finite) has an area: VTK rasterises none of a
    mesh of degenerate faces (corners repeated, or on one line), and it rendered blank without a word, its box
    of some size passing every other check. An area below 1e-12 of the square of the drawn vertices' extent (z
    scaled, as ``local``) counts as none: such a sliver covers no pixel. Chunked, stopping at the first face of some
    area (the first one, for a terrain). ``span``: that extent (3,) where the caller has it, else computed here."""
    faces = np.asarray(faces)
    if span is None:
        span = np.max(local, axis=0, where=finite[:, None], initial=-np.inf) - np.min(
            local, axis=0, where=finite[:, None], initial=np.inf)
    least = 1e-12 * float(np.max(span)) ** 2
    for start in range(0, len(faces), _AREA_CHUNK):
        chunk = faces[start:start + _AREA_CHUNK]
        a, b, c = (local[chunk[:, k]] for k in range(3))
        with np.errstate(invalid="ignore", over="ignore"):  # NaN corners: faces not drawn, NaN is no area
            doubled = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        if (doubled > least).any():
            return
    raise InvalidInputError(f"mesh has no face of some area: every one of its {counted(len(faces), 'face')} is "
                            "degenerate (corners repeated or on one line, or not finite)"
                            + (f" with z_scale={z_scale:g}" if z_scale != 1.0 else "")
                            + ", so it renders blank; nothing to render")


def _misses_view(box: NDArray[np.float64], position: Any, aspect: float, view_angle: float) -> bool:
    """Whether the pyvista camera ``position`` [(eye), (focal point), (view up)] with the vertical field of view
    ``view_angle`` (degrees) and ``aspect`` (width / height) sees none of ``box`` (2, 3), in the camera's coordinates.
    Conservative, as :meth:`~stepterrain.camera.Camera.box_visible`: a box that lies outside one plane of the view
    (the eye's, or a side of the view's pyramid) misses it; one that may touch the view does not."""
    eye, focal, up = (np.asarray(v, dtype=np.float64) for v in position)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        forward = (focal - eye) / np.linalg.norm(focal - eye)
        right, true_up = _screen_axes(forward, up)
        tan_v = math.tan(math.radians(view_angle) / 2.0)
        normals = [forward] + [forward * tan - sign * axis for axis, tan in ((right, tan_v * aspect),
                                                                              (true_up, tan_v))
                               for sign in (1.0, -1.0)]
        lo, hi = np.asarray(box, dtype=np.float64)
        # inside a plane: (p - eye) . normal >= 0; the box corner farthest along the normal decides
        reach = [float((np.where(n >= 0, hi, lo) - eye) @ n) for n in normals]
    return all(math.isfinite(r) for r in reach) and min(reach) < 0.0


def _check_in_view(drawn: NDArray[np.float64], position: Any, aspect: float, view_angle: float,
                   centre: NDArray[np.float64], z_scale: float, camera: Any) -> None:
    """An InvalidInputError when the explicit pyvista camera ``position`` sees none of the box ``drawn`` (2, 3) of
    the vertices drawn (recentred on ``centre``, z times ``z_scale``): the render came back blank without a word,
    most often for a position given in the mesh's own (world) coordinates, where the render takes them less
    ``centre``.
    Conservative, as :func:`_misses_view`."""
    eye, focal, up = (np.asarray(v, dtype=np.float64) for v in position)
    if not _misses_view(drawn, (eye, focal, up), aspect, view_angle):
        return
    scale = np.array([1.0, 1.0, z_scale])  # given in the mesh's own (world) coordinates, as the render takes them?
    world = not _misses_view(drawn, ((eye - centre) * scale, (focal - centre) * scale, up), aspect, view_angle)
    hint = (f"; it looks given in the mesh's own coordinates: less {tuple(float(v) for v in centre)}, z then times "
            "z_scale, it sees the mesh" if world else "")
    raise InvalidInputError(
        f"camera [(eye), (focal point), (view up)] sees none of the mesh (it would render blank): the position is "
        f"taken in the mesh's coordinates less the centre of the framed box, {tuple(float(v) for v in centre)}, z "
        f"times z_scale={z_scale:g}{hint}; got {camera!r}")


def _check_mesh_in_bounds(drawn: NDArray[np.float64], position: Any, size: tuple[int, int], view_angle: float,
                          centre: NDArray[np.float64], z_scale: float, lo: NDArray[np.float64],
                          hi: NDArray[np.float64]) -> None:
    """An InvalidInputError when the camera ``position`` fitted to ``bounds`` (``lo``, ``hi``) sees none of the box
    ``drawn`` (2, 3) of the vertices drawn (recentred on ``centre``, z times ``z_scale``), or shows all of it less
    than a pixel wide or tall: bounds given in other coordinates than the mesh's (local ones for a mesh in UTM metres),
    or far larger than it, rendered blank without a word, where an explicit camera that sees none of the mesh is
    refused (:func:`_check_in_view`) and so is a mesh that renders under a pixel without bounds
    (:func:`_check_visible`). Conservative: the box's projection is at least the mesh's."""
    def mesh_box() -> str:  # in world coordinates, for a refusal (not formatted on every render)
        scale = np.array([1.0, 1.0, z_scale])
        return _fmt_box(drawn[0] / scale + centre, drawn[1] / scale + centre)

    if _misses_view(drawn, position, size[0] / size[1], view_angle):
        raise InvalidInputError(
            f"bounds {_fmt_box(lo, hi)} frame none of the mesh, whose faces span {mesh_box()}: the camera fitted to "
            "them sees none of it (it would render blank); give bounds around the mesh, in its own coordinates")
    pixels = _box_pixels(drawn, position, size, view_angle)
    if pixels is not None and min(pixels) < 1.0:
        px, py = pixels
        raise InvalidInputError(
            f"the mesh, whose faces span {mesh_box()}, would render at most {px:.2g} x {py:.2g} pixels within bounds "
            f"{_fmt_box(lo, hi)} (with z_scale={z_scale:g}), too small to see (it would render blank); give bounds "
            "nearer the mesh's size or a larger window_size", too_small_to_see=True)


def _box_pixels(box: NDArray[np.float64], position: Any, size: tuple[int, int],
                view_angle: float) -> tuple[float, float] | None:
    """Width and height in pixels of the corners of ``box`` (2, 3) seen from the pyvista camera ``position``
    (:func:`_pixel_extent`: at least those of what the box holds), or None when a corner lies at or behind the eye
    (part of the box may then fill the view)."""
    corners = _box_corners(box)
    if (_eye_frame(corners, position)[1] <= 0).any():
        return None
    return _pixel_extent(corners, position, size, view_angle)


def _pixel_extent(points: NDArray[np.float64], position: Any, size: tuple[int, int],
                  view_angle: float = _VIEW_ANGLE) -> tuple[float, float]:
    """Width and height in pixels of ``points`` (those in front of the eye) seen from the pyvista camera
    ``position`` with the vertical field of view ``view_angle`` (degrees), at image ``size``."""
    rel, depth, right, true_up = _eye_frame(points, position)
    front = depth > 0
    if not front.any():
        return 0.0, 0.0
    sx, sy = (rel[front] @ right) / depth[front], (rel[front] @ true_up) / depth[front]
    tan_v = math.tan(math.radians(view_angle) / 2.0)
    width, height = size
    tan_h = tan_v * width / height
    return float(np.ptp(sx)) / (2 * tan_h) * width, float(np.ptp(sy)) / (2 * tan_v) * height


def _eye_frame(points: NDArray[np.float64], position: Any
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(``points`` less the eye, their depths along the view direction, the screen's right and up vectors) of the
    pyvista camera ``position``."""
    eye, focal, up = (np.asarray(v, dtype=np.float64) for v in position)
    forward = (focal - eye) / np.linalg.norm(focal - eye)
    right, true_up = _screen_axes(forward, up)
    rel = points - eye
    return rel, rel @ forward, right, true_up


def _check_visible(corners: NDArray[np.float64], position: Any, size: tuple[int, int], box: NDArray[np.float64],
                   z_scale: float, view_angle: float = _VIEW_ANGLE, camera: CameraLike = "oblique",
                   what: str = "the mesh") -> None:
    """An InvalidInputError when the fitted ``camera`` shows the framed box less than a pixel wide or tall: a mesh
    whose height range (times ``z_scale``) dwarfs its horizontal extent, or the reverse, rendered blank; or a box
    smaller than :data:`_LEAST_EXTENT` (VTK drew it blank). ``what``: the box's name in the message (``bounds``
    where the caller gave the box)."""
    dx, dy, dz = (box[1] - box[0]).tolist()
    if 0 < max(dx, dy, dz) < _LEAST_EXTENT:
        raise InvalidInputError(
            f"{what} spans {dx:.3g} x {dy:.3g} across and {dz:.3g} tall (with z_scale={z_scale:g}): too small to "
            f"render (below {_LEAST_EXTENT:g}, VTK draws in single precision); scale its vertices up")
    px, py = _pixel_extent(corners, position, size, view_angle)
    if min(px, py) >= 1.0:
        return
    across, tall = max(dx, dy), dz / z_scale
    hint = "; it has no extent in one direction"
    if across > 0 and tall > 0:
        # the z_scale that makes the box as tall as it is wide, named only where the camera then sees it: a strip
        # of ground seen from the top is too thin across whatever its height (it named a z_scale that failed alike)
        even = box.copy()
        even[:, 2] *= across / dz  # box is z-scaled: dz > 0 as tall > 0
        even_corners = _box_corners(even)
        if min(_pixel_extent(even_corners, _camera_position(camera, even_corners, size[0] / size[1], view_angle),
                             size, view_angle)) >= 1.0:
            hint = f"; a z_scale near {across / tall:.3g} makes it as tall as it is wide"
        else:
            hint = (f"; a z_scale near {across / tall:.3g}, as tall as it is wide, does not show it from this "
                    "camera either: look from another direction (camera) or give a larger window_size")
    raise InvalidInputError(
        f"{what} would render {px:.2g} x {py:.2g} pixels: it spans {dx:.3g} x {dy:.3g} across and {dz:.3g} tall "
        f"(with z_scale={z_scale:g}), too thin to see from a camera fitted to it{hint}", too_small_to_see=True)


_BOX = "[(xmin, ymin, zmin), (xmax, ymax, zmax)] with max >= min"


def _fitted_camera(camera: Any) -> bool:
    """Whether ``camera`` is fitted to the framed box (a name or (azimuth, elevation)), not an explicit position. A
    ragged sequence is neither (``np.shape`` raised numpy's ValueError for it, ahead of :func:`_camera_position`,
    which refuses it by name)."""
    if isinstance(camera, str):
        return True
    try:
        return np.shape(camera) == (2,)
    except ValueError:
        return False


def _check_fitted_box(box: NDArray[np.float64], name: str) -> None:
    """An InvalidInputError naming ``name`` for a ``box`` (checked by :func:`_check_box`) that is a single point, to
    which a camera is to be fitted: it has no size to frame (far from the renderer's origin its eye fell on the point
    itself, and numpy warned "invalid value encountered in divide" before the error named "the mesh")."""
    if np.array_equal(box[0], box[1]):
        raise InvalidInputError(
            f"{name} must be a box of some size for a fitted camera: [(xmin, ymin, zmin), (xmax, ymax, zmax)] with max "
            f"> min along at least one axis; got the single point {tuple(box[0].tolist())}; give a larger box, or a "
            "camera position [(eye), (focal point), (view up)] (relative to the box's centre)")


def _check_box(value: Any, name: str) -> NDArray[np.float64]:
    """A world box (2, 3) of finite real numbers with max >= min, else an InvalidInputError naming ``name``:
    ``np.asarray(value, dtype=float)`` took text and bools as numbers, and raised numpy's ValueError for 'abc'."""
    box = real_numbers(value, name, _BOX)
    if box.shape != (2, 3) or not np.isfinite(box).all() or np.any(box[1] < box[0]):
        raise InvalidInputError(f"{name} must be {_BOX}; got {value!r}")
    return box


def _check_background(pv: Any, background: Any) -> None:
    """A colour pyvista reads (a name, '#rrggbb', (r, g, b) in [0, 1] or 0-255), else an InvalidInputError:
    pyvista's own ValueError came from set_background, after the scene was built. Whole numbers that are all 0 or 1
    with a 1 among them ((1, 0, 0)) are refused as ambiguous: pyvista reads whole numbers as 0-255, so (1, 0, 0)
    meant for red rendered black and (1, 1, 1) meant for white too; so are whole numbers other than 0 beside floats
    among r, g, b, which pyvista reads channel by channel."""
    try:
        color = pv.Color(background)
    except (ValueError, TypeError):
        raise InvalidInputError(f"background must be a colour (a name, '#rrggbb' or (r, g, b)); got "
                                f"{background!r}") from None
    # its alpha was dropped: (1.0, 1.0, 1.0, 0.0) asked for transparency, got opaque white. An alpha written 1 is
    # opaque however it is read (pyvista takes a whole 1 as 1/255: CSS's rgba(255, 128, 0, 1) was refused)
    if color.opacity < 255 and not _alpha_is_one(background):
        raise InvalidInputError(f"background must be opaque: renders are (H, W, 3) RGB images, with no alpha; got "
                                f"{background!r} (alpha {color.opacity / 255:.3g}); give an opaque colour")
    if not isinstance(background, str):
        parts = np.asarray(background)
        if parts.dtype.kind in "iub" and parts.size and parts.max() == 1 and parts.min() >= 0:
            raise InvalidInputError(f"background {background!r} is ambiguous: whole numbers are read as 0-255 (so "
                                    "it would be nearly black); give floats in [0, 1] such as (1.0, 0.0, 0.0), or "
                                    "0-255 values")
        # pyvista reads each channel by its own type, an int as 0-255 and a float as 0-1: (1, 0.5, 0) meant for orange
        # rendered (1, 128, 0), green, and (1, 1, 1.0) meant for white a dark blue (numpy made floats of them all)
        rgb = list(background)[:3] if isinstance(background, Sequence) else []
        whole = [c for c in rgb if isinstance(c, (int, np.integer))]  # bools too: pyvista reads True as 1
        if any(whole) and any(isinstance(c, (float, np.floating)) for c in rgb):
            read = tuple(int(c) for c in color.int_rgb)
            raise InvalidInputError(
                f"background {background!r} is ambiguous: it mixes whole numbers, read as 0-255, with floats, read "
                f"as 0-1 (it would be {read}); give all three as floats in [0, 1] such as (1.0, 0.5, 0.0), or all as "
                "0-255 whole numbers")


def _alpha_is_one(background: Any) -> bool:
    """Whether ``background`` is a sequence of four numbers whose last, the alpha, is 1."""
    if isinstance(background, str):
        return False
    try:
        parts = np.asarray(background, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return parts.shape == (4,) and bool(parts[3] == 1.0)

def _whole_pixels(value: Any) -> int | None:
    """``value`` as an int when it is a whole number (640 or 640.0), else None: int() truncated 64.7, read
    True as 1 and "640" as 640, and raised its own OverflowError for inf."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    if isinstance(value, (bool, np.bool_)):
        return None
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real) and float(value).is_integer():  # NaN and inf are not
        return int(float(value))
    return None


def _pixel_sequence(value: Any) -> list[int | None]:
    """``value``'s items as whole pixel numbers (None for one that is not), [] when it is no ordered sequence: text
    ("640"), a number, or a set or dict ({32, 40} could come out as height x width)."""
    if isinstance(value, (str, bytes, set, frozenset, dict)):
        return []
    try:
        return [_whole_pixels(v) for v in value]
    except TypeError:  # not a sequence
        return []


def _check_window(window_size: tuple[int, int], z_scale: float) -> tuple[int, int, float]:
    """(width, height, z_scale) checked: two whole numbers of 8 to 16384 pixels, a positive finite vertical
    scale."""
    sides = _pixel_sequence(window_size)
    if len(sides) != 2 or None in sides or min(sides) <= 0:
        raise InvalidInputError(
            f"window_size must be two positive whole numbers (width, height); got {window_size!r}")
    width, height = sides
    if not (8 <= width <= 16384 and 8 <= height <= 16384):
        raise InvalidInputError(f"window_size must lie in [8, 16384] pixels; got {window_size!r}")
    scale = number_or_nan(z_scale)
    if not math.isfinite(scale) or scale <= 0:
        raise InvalidInputError(f"z_scale must be a positive finite number; got {z_scale!r}")
    z_scale = scale
    return width, height, z_scale


#: Bytes an off-screen render holds per pixel of its window, measured as the process's peak RSS (VmHWM) over
#: renders of 1024² to 3072² on Mesa llvmpipe (EGL): ~43 for render_mesh (VTK's colour and depth buffers, the
#: screenshot and its RGB copy), ~70 with anti_aliasing (MSAA's multi-sampled colour and depth), ~55 for
#: render_closeups (a LayeredRenderer's window plus every pass's colour and float32 depth read back and composited).
#: Rounded up; a 16384 x 16384 render thus needs 12 GiB (20 GiB with MSAA).
_RENDER_BYTES_PER_PIXEL = 48
_MSAA_BYTES_PER_PIXEL = 32
#: What anti-aliasing adds for translucent colours (or textures), which take SSAA (the scene drawn larger, then
#: filtered down) in place of MSAA, with depth peeling's buffers at the larger size: ~283 bytes per pixel in all,
#: measured as above (1024² to 3072²).
_SSAA_BYTES_PER_PIXEL = 240
_LAYERED_BYTES_PER_PIXEL = 64
#: Bytes a render holds per texel of a textured mesh's texture, measured as above (peak RSS less that of the same
#: render with a 16 x 16 texture) with RGB textures of 4096² to 17000² in a 320 x 200 window: ~11-12 (VTK's copy of
#: the image, the texture and its mipmaps that llvmpipe holds), ~15 past OpenGL's largest texture (16384 a side),
#: which VTK resamples first. Rounded up; the mesh's own image is not counted. A 17000² texture took 4.6 GB.
_TEXTURE_BYTES_PER_TEXEL = 16
#: Bytes a render holds per vertex and per face of its mesh, beyond its window's: the recentred float64 copy of the
#: vertices, the PolyData's cells, VTK's and llvmpipe's buffers (points, indices, cell normals for flat shading).
#: Measured as above (peak RSS less that before the call, 400 x 300 window) on meshes of 0.5 M to 18 M faces: a grid
#: of 8 M faces and 4 M vertices took 557 MiB, its unmerged copy (8 M faces, 24 M vertices) 2272 MiB, the stepped
#: embedded DEM at interval 5 (18.2 M faces, 9.1 M vertices) 1.2-1.3 GiB where only the window (5.5 MiB) was
#: checked: ~26 per face and ~94 per vertex fitted (plus ~30 MiB however small the mesh). Vertex colours added 0-19
#: per vertex, UVs (a texture) 5-25 per vertex, face colours 13-19 per face. Rounded up (those included), they do not
#: depend on the window: only a mesh of fewer faces and vertices makes them smaller.
_RENDER_BYTES_PER_FACE = 40
_RENDER_BYTES_PER_VERTEX = 112
_FACE_COLOR_BYTES_PER_FACE = 24
#: What makes a render of a mesh too large for the budget smaller, when the mesh weighs most.
_MESH_HINT = "render a mesh of fewer faces (a larger interval, a coarsened or cropped DEM)"


#: The render budget's hint for a smaller texture, in the library (:func:`_check_render_budget`).
_SMALLER_TEXTURE = "a smaller texture (a larger texel size, or the image resampled)"


def _render_bytes(width: int, height: int, *, anti_aliasing: bool = False, layered: bool = False,
                  ssaa: bool = False, texels: int = 0, vertices: int = 0, faces: int = 0,
                  face_colors: bool = False) -> int:
    """Memory an off-screen render of width x height pixels holds at its peak (see _RENDER_BYTES_PER_PIXEL);
    ``ssaa``: its anti-aliasing is SSAA (translucent colours), not MSAA; ``texels``: those of a textured mesh's
    texture (see _TEXTURE_BYTES_PER_TEXEL); ``vertices``, ``faces``: the mesh's (see _RENDER_BYTES_PER_FACE),
    ``face_colors``: drawn with a colour per face."""
    per_pixel = _LAYERED_BYTES_PER_PIXEL if layered else _RENDER_BYTES_PER_PIXEL
    extra = (_SSAA_BYTES_PER_PIXEL if ssaa else _MSAA_BYTES_PER_PIXEL) if anti_aliasing else 0
    per_face = _RENDER_BYTES_PER_FACE + (_FACE_COLOR_BYTES_PER_FACE if face_colors else 0)
    return (int(width) * int(height) * (per_pixel + extra) + int(texels) * _TEXTURE_BYTES_PER_TEXEL
            + int(vertices) * _RENDER_BYTES_PER_VERTEX + int(faces) * per_face)


def _check_render_budget(width: int, height: int, name: str = "window_size", *, anti_aliasing: bool = False,
                         layered: bool = False, ssaa: bool = False, texture: tuple[int, ...] | None = None,
                         smaller_texture: str = _SMALLER_TEXTURE, mesh: tuple[int, int] | None = None,
                         face_colors: bool = False, mesh_hint: str = _MESH_HINT, at_least: bool = False) -> None:
    """An :class:`OutputTooLargeError` naming the size and ``name`` (the argument or CLI option giving it) when the
    render's framebuffers and images (:func:`_render_bytes`) exceed the memory budget; called before any render
    starts (and, in the CLI, before the DEM is read). ``texture``: the (rows, cols) of a textured mesh's texture,
    whose texels count too (only the window was counted: a 17000 x 17000 texture in a small window took 4.6 GB past
    any budget); ``smaller_texture``: how the caller makes it smaller, in the hint (a command names its own option:
    the library's "a larger texel size" named none ``stepterrain globe`` has). ``mesh``: the (vertices, faces) of
    the mesh drawn, whose copies count too (``face_colors``: drawn with a colour per face; only the window was
    counted: an 18 M-face stepped mesh took 1.2 GiB in a 400 x 300 window checked as 5.5 MiB); ``mesh_hint`` says how
    to make it smaller when it weighs more than the window; ``at_least``: ``mesh`` is the fewest the mesh will have
    (the CLI's, before it is made)."""
    what = f"an off-screen render of {width} x {height} pixels ({name} {width}x{height}" \
           + (", anti-aliased)" if anti_aliasing else ")")
    texels = 0
    hint = f"give a smaller {name}" + (" or turn anti_aliasing off" if anti_aliasing else "")
    if texture is not None:
        rows, cols = (int(n) for n in texture[:2])
        texels = rows * cols
        what += f" of a mesh with a {cols} x {rows} texel texture"
        hint += f" or {smaller_texture}"
    n_vertices, n_faces = (0, 0) if mesh is None else (int(n) for n in mesh)
    need = _render_bytes(width, height, anti_aliasing=anti_aliasing, layered=layered, ssaa=ssaa, texels=texels,
                         vertices=n_vertices, faces=n_faces, face_colors=face_colors)
    window = _render_bytes(width, height, anti_aliasing=anti_aliasing, layered=layered, ssaa=ssaa, texels=texels)
    if 2 * window < need:  # the mesh's copies weigh most: named, and a smaller window does not help
        size = f"{counted(n_faces, 'face', grouped=True)} and {counted(n_vertices, 'vertex', 'vertices', grouped=True)}"
        what += (" and" if texture is not None else " of a mesh") + f" of {'at least ' if at_least else ''}{size}"
        hint = f"{mesh_hint} (its copies for rendering grow with the mesh, not with the {name})"
    check_budget(need, what, hint=hint)


@_quietly
def _shoot(pv: Any, poly: Any, mesh_kwargs: dict[str, Any], *, local: NDArray[np.float64], faces: ArrayLike,
           finite: NDArray[np.bool_], box: NDArray[np.float64], position: Any,
           size: tuple[int, int], background: Any, anti_aliasing: bool, lighting: bool,
           translucent: bool = False, view_angle: float = _VIEW_ANGLE) -> NDArray[np.uint8]:
    """One off-screen render of ``poly``: the camera ``position`` (:func:`_frame_mesh`'s), the key and fill lights, a
    clipping range that holds the whole mesh; returns the (H, W, 3) image. ``translucent``: its colours have alpha,
    blended in depth order by depth peeling (without it the surface behind showed over the one in front);
    ``view_angle``: the vertical field of view, degrees."""
    width, height = size
    plotter = pv.Plotter(off_screen=True, window_size=(width, height), lighting="none", theme=_default_theme(pv))
    try:
        if not plotter.render_window.SupportsOpenGL():
            raise MissingDependencyError(
                "off-screen rendering needs OpenGL, but VTK could not create a context; install Mesa "
                "(libegl1, libgl1-mesa-dri or libosmesa6) or run where a GPU driver is present"
            )
        if anti_aliasing and not translucent:
            plotter.enable_anti_aliasing("msaa")
        else:
            plotter.disable_anti_aliasing()
        plotter.set_background(background)
        if translucent:
            plotter.enable_depth_peeling()
            if anti_aliasing:  # MSAA with depth peeling rendered blank (Mesa), without it out of depth order: SSAA
                _ssaa_with_depth_peeling(plotter.renderer)
        look_from = np.subtract(position[0], position[1])
        fill = (math.atan2(look_from[0], look_from[1]), _FILL_ELEVATION)
        if lighting:
            for light in _lights(pv, box, fill):
                plotter.add_light(light)
        plotter.add_mesh(poly, **{**_UNTHEMED, **mesh_kwargs})
        plotter.camera_position = position
        plotter.camera.view_angle = view_angle
        seen = local[finite]
        union = np.array([np.minimum(box[0], seen.min(axis=0)), np.maximum(box[1], seen.max(axis=0))])
        plotter.camera.clipping_range = _clipping_range(plotter.camera_position, union, [(local, faces)])
        image = plotter.screenshot(return_img=True)
    finally:
        with contextlib.suppress(Exception):
            plotter.close()
    if image is None or image.ndim != 3 or image.shape[:2] != (height, width):
        raise MissingDependencyError("off-screen rendering produced no image; the OpenGL context is unusable")
    return np.ascontiguousarray(image[:, :, :3], dtype=np.uint8)


def _ssaa_with_depth_peeling(renderer: Any) -> None:
    """Render through an SSAA pass whose translucent step peels depth as ``renderer`` does without passes (dual
    depth peeling, its number of peels and occlusion ratio). pyvista's SSAA pass replaced the renderer's own
    drawing, whose depth peeling it never reached: translucent faces blended in the order they were drawn, so a
    surface drawn after the one in front of it hid it."""
    from vtkmodules.vtkRenderingOpenGL2 import vtkCameraPass, vtkDualDepthPeelingPass, vtkRenderStepsPass, vtkSSAAPass

    steps = vtkRenderStepsPass()
    peeling = vtkDualDepthPeelingPass()
    peeling.SetTranslucentPass(steps.GetTranslucentPass())
    peeling.SetVolumetricPass(steps.GetVolumetricPass())
    peeling.SetMaximumNumberOfPeels(renderer.GetMaximumNumberOfPeels())
    peeling.SetOcclusionRatio(renderer.GetOcclusionRatio())
    steps.SetTranslucentPass(peeling)
    camera = vtkCameraPass()
    camera.SetDelegatePass(steps)
    ssaa = vtkSSAAPass()
    ssaa.SetDelegatePass(camera)
    renderer.SetPass(ssaa)


def _box_corners(box: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[x, y, z] for x in box[:, 0] for y in box[:, 1] for z in box[:, 2]])


def _fit_points(camera: CameraLike, points: NDArray[np.float64], aspect: float,
                view_angle: float) -> list[tuple[float, ...]]:
    """:func:`_camera_position` of a fitted ``camera`` framing the vertices drawn, ``points``, themselves (not their
    box): fitted to at most ~100k of them, evenly strided, then to those the fit left outside the view, until none is
    (the strided ones alone missed a tower or a mast of a few vertices, cut off at the picture's edge)."""
    stride = max(1, len(points) // 100_000)
    framed = points[::stride]
    position = _camera_position(camera, framed, aspect, view_angle)
    if stride == 1:  # all framed
        return position
    for _ in range(8):
        outside = _outside_view(points, position, aspect, view_angle)
        if not outside.any():
            break
        framed = np.concatenate([framed, points[outside]])
        position = _camera_position(camera, framed, aspect, view_angle)
    return position


def _outside_view(points: NDArray[np.float64], position: Any, aspect: float, view_angle: float) -> NDArray[np.bool_]:
    """Which ``points`` lie outside the view of the pyvista camera ``position`` (vertical field of view
    ``view_angle`` degrees, width / height ``aspect``), behind the eye included."""
    rel, depth, right, true_up = _eye_frame(points, position)
    tan_v = math.tan(math.radians(view_angle) / 2.0)
    inside = (depth > 0) & (np.abs(rel @ right) <= depth * (tan_v * aspect)) & (np.abs(rel @ true_up) <= depth * tan_v)
    return ~inside


def _clipping_range(position: Any, bounds: NDArray[np.float64],
                    meshes: Sequence[tuple[NDArray[np.float64], ArrayLike]] = ()) -> tuple[float, float]:
    """(near, far) holding all of ``bounds``: far beyond its farthest corner, near half the eye's distance to the
    box itself (0 inside it, then far / 10^4). Half the distance to the nearest *corner* clipped nearer geometry:
    a globe seen from 400 km up had its near plane 1,000-3,000 km out, and the far side's inner faces showed
    through where the terrain was cut away.

    With ``meshes``, (vertices, faces) pairs, the near plane comes no nearer than half the eye's distance to the mesh
    (a lower bound of it, :func:`_mesh_distance`, at least far / 10^7) where far / 10^4 would lie beyond that: an eye
    inside the box of a large mesh, close over its ground (a globe seen from 300 m, a walk-through of a DEM), had
    the ground up to far / 10^4 (1.6 km for the earth) clipped away, and the far side of the globe showed there."""
    eye = np.asarray(position[0], dtype=np.float64)
    far = float(np.linalg.norm(_box_corners(bounds) - eye, axis=1).max()) * 1.05
    gap = np.maximum(np.maximum(bounds[0] - eye, eye - bounds[1]), 0.0)  # per axis, 0 where the eye is within
    box_near = float(np.linalg.norm(gap)) * 0.5
    near = max(far * 1e-4, box_near)
    if meshes and near > box_near:  # the floor decides: may it clip a mesh?
        # only triangles within 2 near of the eye can move it: the others are skipped cheaply (all of a 20M-face
        # mesh's took 4.6 GB and longer than the render itself)
        closest = min(_mesh_distance(eye, vertices, faces, within=2.0 * near) for vertices, faces in meshes)
        near = max(box_near, min(near, max(0.5 * closest, far * 1e-7)))
    return near, far


def _mesh_distance(eye: NDArray[np.float64], vertices: NDArray[np.float64], faces: ArrayLike,
                   within: float = math.inf) -> float:
    """A lower bound of the distance from ``eye`` to the triangles ``faces`` of ``vertices`` (those with a NaN
    vertex, not drawn, left out): per triangle the larger of the eye's distance to its plane and its farthest
    vertex's distance less its longest edge (no point of a triangle lies farther than that from a vertex).
    ``within`` at most: a triangle whose three vertices lie beyond ``within`` of the eye on one side of one axis
    (its box off the cube of half-side ``within`` round the eye, so no point of it nearer) is skipped by a byte per
    vertex, and the rest are taken a million at a time, component by component (every triangle at once took
    ~230 bytes a triangle, 4.6 GB for 20 million, and longer than their render; norms over (F, 3, 3) took 6 s)."""
    index = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    rel = np.asarray(vertices, dtype=np.float64) - eye
    if math.isfinite(within) and len(index):
        side = np.zeros(len(rel), dtype=np.uint8)  # bit 2k: below the cube along axis k, bit 2k + 1: above it
        for k in range(3):
            side |= (rel[:, k] < -within).view(np.uint8) << np.uint8(2 * k)
            side |= (rel[:, k] > within).view(np.uint8) << np.uint8(2 * k + 1)
        index = index[(side[index[:, 0]] & side[index[:, 1]] & side[index[:, 2]]) == 0]
    reach2 = np.einsum("ij,ij->i", rel, rel)  # squared distance of each vertex from the eye
    x, y, z = (np.ascontiguousarray(rel[:, k]) for k in range(3))
    closest, found = within, False
    for start in range(0, len(index), 1 << 20):
        a, b, c = index[start:start + (1 << 20)].T
        ax, ay, az, bx, by, bz, cx, cy, cz = x[a], y[a], z[a], x[b], y[b], z[b], x[c], y[c], z[c]
        with np.errstate(invalid="ignore", divide="ignore"):
            reach = np.sqrt(np.maximum(np.maximum(reach2[a], reach2[b]), reach2[c]))
            ux, uy, uz, vx, vy, vz = bx - ax, by - ay, bz - az, cx - ax, cy - ay, cz - az
            edge2 = np.maximum(np.maximum(ux * ux + uy * uy + uz * uz, vx * vx + vy * vy + vz * vz),
                               (cx - bx) ** 2 + (cy - by) ** 2 + (cz - bz) ** 2)
            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            length = np.sqrt(nx * nx + ny * ny + nz * nz)
            plane = np.abs(nx * ax + ny * ay + nz * az) / length  # the eye is the origin of rel
            bound = np.maximum(reach - np.sqrt(edge2), np.where(length > 0, plane, 0.0))
        bound = bound[np.isfinite(reach)]
        if len(bound):
            closest, found = min(closest, float(max(bound.min(), 0.0))), True
    return closest if found or math.isfinite(within) else 0.0


def save_png(image: NDArray[np.uint8], path: str | os.PathLike[str]) -> Path:
    """Write an (H, W, 3|4) uint8 image as PNG, atomically (see :func:`stepterrain.export.save_image`)."""
    from .export import save_image

    return save_image(image, path)


def render_textured_mesh(
    mesh: trimesh.Trimesh,
    *,
    window_size: tuple[int, int] = (1280, 800),
    z_scale: float = 1.0,
    camera: CameraLike = "oblique",
    background: str | tuple[float, float, float] = "white",
    lighting: bool | Literal["relief"] = True,
    anti_aliasing: bool = False,
    bounds: ArrayLike | None = None,
    view_angle: float = _VIEW_ANGLE,
) -> NDArray[np.uint8]:
    """Render a mesh with its texture (``trimesh.visual.TextureVisuals``: UVs and a base-colour image) off-screen.

    Same camera (its vertical field of view ``view_angle`` in degrees too), lights and framing as
    :func:`render_mesh`. The texture is sampled linearly (bilinear) where magnified and through mipmaps (trilinear)
    where shrunk on screen, as a glTF viewer shows the mesh's GLB: a texture finer than the picture renders as the
    average of the texels under each pixel, not as one of them. A PBR material's ``baseColorFactor`` multiplies the
    texture, in linear light, as glTF defines the base colour.
    ``lighting=False`` shows the texture unlit (a
    topographic texture already carries its shading, paper 004 §7); True (the default) adds the key and fill
    lights. ``"relief"`` lights the relief the texture's shading does not show (the terraces and walls of a stepped
    terrain under a hillshade of the continuous DEM): the same lights, with the ambient raised so that a level face
    shows the texture's own colour (:data:`_RELIEF_AMBIENT`) and faces turned from the light darker. Lit fully, a
    hillshade was shaded twice: its terraces at 0.87 of their colour and walls facing the camera at 0.55 (the
    draped view of docs/texture.png darker than the texture beside it). ``z_scale`` defaults to 1, true
    proportions. The CLI's ``texture --png`` defaults differ: ``--z-scale 2`` and ``--lighting auto`` (relief on the
    stepped terrain under a hillshade, ``--shadows`` or ``--occlusion``, lit on it without them, lit on the
    heightfield with ``--hillshade none`` and no ``--image``, unlit otherwise).

    A texture with some alpha below 255 (an alpha band, or a PNG's transparent colour) blends with what lies behind
    it, in depth order (depth peeling), as the mesh's GLB shows it; a material's glTF ``alphaMode`` is followed when
    set (OPAQUE: alpha ignored; MASK: each texel shown or hidden at ``alphaCutoff``). Anti-aliasing such a render
    takes SSAA, as translucent colours do in :func:`render_mesh`. An opaque texture (:func:`~stepterrain.texture.drape`
    composites its layer over a background) renders opaque.

    Raises
    ------
    InvalidInputError
        The mesh has no UVs, UVs that are not (V, 2) finite numbers, or no texture image, an infinite vertex, or a
        bad window size, z_scale, camera or view_angle.
    OutputTooLargeError
        The render's memory, its window's, its texture's (16 bytes per texel) and its mesh's copies (about 40 bytes
        per face and 112 per vertex), exceeds the memory budget, as in :func:`render_mesh`.
    MissingDependencyError
        No off-screen OpenGL context can be made.
    """
    mesh = mesh_argument(mesh)  # a pyvista PolyData (grid.stepterrain.stepped's) as its Trimesh
    source = _texture_source(mesh)
    if source is None:
        raise InvalidInputError("mesh has no texture: expected TextureVisuals with one UV per vertex and an image "
                                "(see stepterrain.texture.drape)")
    relief = isinstance(lighting, str) and lighting == "relief"
    if not relief and not isinstance(lighting, (bool, np.bool_)):
        raise InvalidInputError(f"lighting must be True, False or 'relief'; got {lighting!r}")
    lighting = relief or bool(lighting)
    anti_aliasing = check_flag(anti_aliasing, "anti_aliasing")
    view_angle = _check_view_angle(view_angle)
    width, height, _vertices, local, finite, box, position = _frame_mesh(mesh, window_size, z_scale, bounds, camera,
                                                                         anti_aliasing, view_angle)
    # the texels counted from the texture's size before it is decoded (see render_mesh)
    _check_render_budget(width, height, anti_aliasing=anti_aliasing, texture=_texture_shape(source[1]))
    uv, picture = _decoded_texture(*source, check=lambda shape: _check_render_budget(
        width, height, anti_aliasing=anti_aliasing, ssaa=len(shape) == 3 and shape[2] == 4, texture=shape,
        mesh=(len(local), len(mesh.faces))))
    translucent = picture.ndim == 3 and picture.shape[2] == 4
    # the texture's texels too; SSAA, not MSAA, for a translucent one (see _shoot): more memory
    _check_render_budget(width, height, anti_aliasing=anti_aliasing, ssaa=translucent, texture=picture.shape,
                         mesh=(len(local), len(mesh.faces)))

    pv = _import_pyvista()
    _check_background(pv, background)
    poly = _polydata(pv, local, mesh.faces)
    mesh_kwargs = dict(texture=_texture(pv, poly, uv, picture, clamp=_clamped(source[2])), smooth_shading=False,
                       ambient=(_RELIEF_AMBIENT if relief else _AMBIENT) if lighting else 1.0,
                       diffuse=_DIFFUSE if lighting else 0.0, specular=0.0, lighting=lighting)
    return _shoot(pv, poly, mesh_kwargs, local=local, faces=mesh.faces, finite=finite, box=box,
                  position=position, size=(width, height), background=background, anti_aliasing=anti_aliasing,
                  lighting=lighting, translucent=translucent, view_angle=view_angle)


def _texture_source(mesh: trimesh.Trimesh) -> tuple[Any, Any, Any] | None:
    """(UVs, base-colour image, material) of a textured mesh (TextureVisuals with one UV per vertex and an image), as
    they are (the image not decoded), else None."""
    visual = mesh.visual
    uv = getattr(visual, "uv", None)
    material = getattr(visual, "material", None)
    image = None
    if material is not None:  # "or" between them: an array's truth value raised numpy's ValueError (ambiguous)
        image = getattr(material, "baseColorTexture", None)
        if image is None:
            image = getattr(material, "image", None)
    if uv is None or image is None or len(uv) != len(mesh.vertices):
        return None
    return uv, image, material


def _texture_shape(image: Any) -> tuple[int, int]:
    """(rows, cols) of a texture image without decoding it: a PIL image's size (known from a file's header), an
    array's shape (a 1-D or empty one: (0, 0), refused when the image is read)."""
    if hasattr(image, "convert") and hasattr(image, "mode"):  # a Pillow image (as _texture_picture tells one)
        width, height = image.size
        return int(height), int(width)
    try:
        shape = tuple(getattr(image, "shape", None) or np.shape(image))
    except (TypeError, ValueError):  # a ragged list: refused when the image is read
        return 0, 0
    return (int(shape[0]), int(shape[1])) if len(shape) >= 2 else (0, 0)


def _decoded_texture(uv: Any, image: Any, material: Any, check: Callable[[tuple[int, ...]], None] | None = None
                     ) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """The (UVs, texture picture) a textured mesh is drawn with, from its :func:`_texture_source`: the image decoded,
    both checked (an InvalidInputError for bad ones); for a material whose ``wrap`` repeats u and clamps v (a globe's
    drape), :func:`_periodic_columns`' picture, drawn clamped (:func:`_texture`'s ``clamp``); one that clamps both
    (a terrain's drape) is drawn clamped as it is. ``check``: called with the widened picture's shape before it is
    made (the caller's render budget: UVs spanning many periods widen it as many times)."""
    from .export import texture_wrap

    uv, picture = _texture_coordinates(uv), _texture_alpha(_base_color_factor(_texture_picture(image), material),
                                                           material)
    if _clamped(material) and texture_wrap(material)[0] != "CLAMP_TO_EDGE":
        uv, picture = _periodic_columns(uv, picture, check)
    return uv, picture


def _clamped(material: Any) -> bool:
    """Whether a texture with ``material`` is drawn clamped to its edges: its ``wrap`` (see
    :func:`~stepterrain.export.texture_wrap`) clamps v (VTK wraps both ways alike; a u that repeats does so through
    :func:`_periodic_columns`, one that clamps as v)."""
    from .export import texture_wrap

    wrap = texture_wrap(material)
    return wrap is not None and wrap[1] == "CLAMP_TO_EDGE"


#: Columns of the texture repeated beyond a periodic texture's UVs on each side (:func:`_periodic_columns`), a multiple
#: of the mipmap blocks it keeps aligned: the coarser levels' texels at the ends blend with the right neighbours up to
#: blocks of this many columns.
_PERIODIC_MARGIN = 256


def _periodic_columns(uv: NDArray[np.float32], picture: NDArray[np.uint8],
                      check: Callable[[tuple[int, ...]], None] | None = None
                      ) -> tuple[NDArray[np.float32], NDArray[Any]]:
    """(UVs, picture) for a texture that repeats in u and is clamped in v, drawn with one clamped wrap (VTK's is the
    same both ways): the picture's columns repeated over the UVs' u range and :data:`_PERIODIC_MARGIN` beyond on each
    side, starting at a multiple of it (the mipmaps' blocks as the picture's), and u moved into it. With VTK's
    REPEAT both ways, each pole of a globe's drape blended with the other's in the mipmaps (a grey diamond at the
    north pole of the Blue Marble, a dark spot at its white south pole). ``check`` (the render budget's) is called
    with the widened picture's shape before it is made: UVs spanning many periods allocated it many times over
    (a MemoryError, not the budget's OutputTooLargeError)."""
    if picture.ndim < 2 or not len(uv) or not picture.shape[1]:
        return uv, picture
    cols = picture.shape[1]
    u = uv[:, 0].astype(np.float64) * cols
    start = (math.floor(u.min()) // _PERIODIC_MARGIN - 1) * _PERIODIC_MARGIN
    stop = (math.ceil(u.max()) // _PERIODIC_MARGIN + 2) * _PERIODIC_MARGIN
    if check is not None:
        check((picture.shape[0], stop - start, *picture.shape[2:]))
    wide = np.ascontiguousarray(picture[:, np.arange(start, stop) % cols])
    out = np.array(uv, dtype=np.float32)
    out[:, 0] = (u - start) / (stop - start)
    return out, wide


def _base_color_factor(picture: NDArray[np.uint8], material: Any) -> NDArray[np.uint8]:
    """``picture`` times a PBR material's baseColorFactor, as glTF defines the base colour and a viewer shows the
    mesh's GLB (:func:`~stepterrain.export.save_mesh` writes the factor): the colour in linear light (the texture
    decoded from sRGB, the product encoded back), the alpha times the factor's where the material blends or masks (its
    alphaMode, or unset with a texture with alpha, which the GLB gets as BLEND or MASK; unset with an opaque texture
    it is OPAQUE, glTF's default). The factor was ignored: a tinted or dimmed texture rendered at full brightness."""
    factor = getattr(material, "baseColorFactor", None)
    if not isinstance(material, trimesh.visual.material.PBRMaterial) or factor is None:
        return picture
    factor = np.asarray(factor, dtype=np.float64).reshape(-1)
    if factor.shape != (4,) or (factor == 255).all():  # trimesh holds it as RGBA bytes
        return picture
    from .export import _linear_to_srgb, _srgb_to_linear

    rgb = picture if picture.ndim == 3 else picture[..., None]
    alpha = rgb[..., 3] if rgb.shape[2] == 4 else None
    rgb = rgb[..., :3] if rgb.shape[2] >= 3 else np.repeat(rgb, 3, axis=2)  # grey: one channel
    levels = _srgb_to_linear(np.arange(256) / 255.0)
    mode = getattr(material, "alphaMode", None)
    blends = mode in ("BLEND", "MASK") or (mode is None and alpha is not None and alpha.size and int(alpha.min()) < 255)
    out = np.empty(rgb.shape[:2] + (4 if alpha is not None or (blends and factor[3] < 255) else 3,), dtype=np.uint8)
    for c in range(3):  # a table of the 256 levels per channel: no float copy of a large texture
        table = np.rint(_linear_to_srgb(levels * (factor[c] / 255.0)) * 255.0).astype(np.uint8)
        out[..., c] = table[rgb[..., c]]
    if out.shape[2] == 4:
        table = np.rint(np.arange(256) * (factor[3] / 255.0 if blends else 1.0)).astype(np.uint8)
        out[..., 3] = table[alpha] if alpha is not None else table[255]
    return out


def _texture(pv: Any, poly: Any, uv: NDArray[np.float32], picture: NDArray[np.uint8], clamp: bool = False) -> Any:
    """The pv.Texture of ``picture`` for ``poly``, whose texture coordinates become ``uv``; ``clamp``: clamped to its
    edges (see :func:`_clamped`), else repeated (glTF's default sampler)."""
    poly.active_texture_coordinates = uv
    texture = pv.Texture(picture)  # row 0 = the top of the image (v = 1)
    texture.interpolate = True  # linear, as a glTF viewer samples the GLB: nearest drew a magnified texel as a block
    # and mipmapped (trilinear), as a glTF viewer's default sampler: a texture larger than its picture (a DEM's, one
    # texel per node, in a 1280-pixel window) took one texel of many per pixel and shimmered, fine detail as noise
    texture.mipmap = True
    # isotropic, as three.js's default: VTK's 4x anisotropic filtering blended a constant-UV face's texel with its
    # neighbours on Mesa's llvmpipe (a face of one texel came out in a mix of two)
    texture.SetMaximumAnisotropicFiltering(1.0)
    if clamp:
        texture.SetWrap(texture.ClampToEdge)
    return texture


def _texture_alpha(picture: NDArray[np.uint8], material: Any) -> NDArray[np.uint8]:
    """The texture ``picture`` as VTK gets it: RGBA when some alpha is below 255 (blended as the mesh's GLB shows
    it), else without its alpha (an opaque texture renders as before). A material's glTF alphaMode is followed
    when set: OPAQUE ignores the alpha, MASK shows a texel (alpha 255) or hides it (alpha 0) at its alphaCutoff
    (0.5 unset). The alpha was dropped: a texture with transparent texels (nodata, the outside of a lens) rendered
    them opaque, in whatever colour they hold."""
    if picture.ndim != 3 or picture.shape[2] != 4:
        return picture
    mode = getattr(material, "alphaMode", None)
    alpha = picture[..., 3]
    if mode == "MASK":
        cutoff = getattr(material, "alphaCutoff", None)
        cutoff = 0.5 if cutoff is None else float(cutoff)
        picture = picture.copy()
        picture[..., 3] = np.where(alpha / 255.0 >= cutoff, 255, 0).astype(np.uint8)
        alpha = picture[..., 3]
    if mode == "OPAQUE" or not alpha.size or int(alpha.min()) == 255:
        return np.ascontiguousarray(picture[..., :3])
    from .io import fill_transparent

    # VTK interpolates straight colour and alpha apart: a transparent texel's colour (garbage under a `gdalwarp
    # -dstalpha` nodata area, magenta) tinted the opaque texels' edge, and all of a view magnified across it
    return fill_transparent(picture)


def _texture_picture(image: Any) -> NDArray[np.uint8]:
    """The texture image as the contiguous uint8 array VTK gets, (H, W, 4) when it has alpha (an alpha band or a
    transparent colour), else an InvalidInputError: casting to uint8 wrapped a uint16 array modulo 256 and truncated
    a float one in [0, 1] to black, and Pillow's conversion of a 16-bit image to RGB saturated it almost all white
    (:func:`~stepterrain.io.picture_uint8` scales it, as the texture pyramid reads it)."""
    from .io import picture_uint8

    what = "the mesh's texture image"
    if hasattr(image, "convert") and hasattr(image, "mode"):  # a Pillow image (a transparent colour read as alpha)
        return np.ascontiguousarray(picture_uint8(image, what, alpha=True))
    array = np.asarray(image)
    if array.dtype != np.uint8 or not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] in (1, 3, 4))) \
            or array.size == 0:
        raise InvalidInputError(f"{what} must be an (H, W), (H, W, 3) or (H, W, 4) uint8 array or a Pillow image; "
                                f"got dtype {array.dtype}, shape {array.shape}")
    return np.ascontiguousarray(array)


def _texture_coordinates(uv: Any) -> NDArray[np.float32]:
    """The mesh's UVs as the (V, 2) float32 array VTK gets, else an InvalidInputError: a NaN or inf UV (or one
    beyond float32) was drawn without an error, with garbage texels on every face it touches."""
    try:
        with np.errstate(over="ignore"):  # a UV beyond float32 becomes inf, named below
            coords = np.ascontiguousarray(uv, dtype=np.float32)
    except (TypeError, ValueError):
        raise InvalidInputError(f"mesh.visual.uv must be (V, 2) texture coordinates (u, v); got "
                                f"dtype {np.asarray(uv).dtype}") from None
    if coords.ndim != 2 or coords.shape[1] != 2:
        raise InvalidInputError(f"mesh.visual.uv must be (V, 2) texture coordinates (u, v); got shape {coords.shape}")
    if len(coords) and not (np.isfinite(coords.min()) and np.isfinite(coords.max())):  # no mask when all are finite
        bad = np.flatnonzero(~np.isfinite(coords).all(axis=1))
        raise InvalidInputError(
            f"mesh.visual.uv must hold finite texture coordinates (u, v); got {len(bad)} of {len(coords)} "
            f"vertices not finite in float32 (first: vertex {bad[0]} at {np.asarray(uv)[bad[0]].tolist()})")
    return coords


# ------------------------------------------------------------------------------------------ layered passes
def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _finite_bounds(vertices: NDArray[np.float64], name: str | None = None) -> NDArray[np.float64] | None:
    """(2, 3) bounds of the finite rows of (N, 3) ``vertices`` (None when no row is finite). Column by column:
    NumPy reduces a contiguous column faster than axis 0 of an (N, 3) array; a NaN or inf anywhere shows in
    the column extrema, and only then are the non-finite rows dropped. With ``name``, an infinite vertex is
    refused there (:func:`~stepterrain.terrain.finite_or_nan`; NaN is nodata): no pass of its own."""
    if len(vertices) == 0:
        return None
    box = np.array([[vertices[:, i].min() for i in range(3)], [vertices[:, i].max() for i in range(3)]])
    if np.isfinite(box).all():
        return box
    if name is not None:
        finite_or_nan(vertices, name)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.any():
        return None
    return _finite_bounds(vertices[finite])


def _frozen(array: Any) -> bool:
    """True for a read-only NumPy array (whose contents a caller promises not to change)."""
    return isinstance(array, np.ndarray) and not array.flags.writeable


def _gray_levels(values: ArrayLike) -> NDArray[np.uint8]:
    """(V,) values in [0, 1] as (V, 3) uint8 gray levels (read back from the red channel)."""
    gray = np.clip(np.rint(np.asarray(values, dtype=np.float64).reshape(-1) * 255.0), 0, 255).astype(np.uint8)
    return np.repeat(gray[:, None], 3, axis=1)


def _layer_rows(array: Any, name: str, expected: str) -> NDArray[Any]:
    """``array`` as (N, 3) rows (a flat array of 3N numbers too), else an InvalidInputError "``name`` must be
    ``expected``": numpy's ValueError ("cannot reshape", "could not convert string") named nothing. A NumPy
    array of numbers is taken as it is (no copy: an overview has millions of vertices and faces)."""
    numeric = isinstance(array, np.ndarray) and array.dtype.kind in "iuf" and not np.ma.isMaskedArray(array)
    rows = array if numeric else real_numbers(array, name, expected)
    if rows.size % 3 or (rows.ndim > 1 and rows.shape[-1] != 3):
        raise InvalidInputError(f"{name} must be {expected}; got shape {rows.shape}")
    return rows.reshape(-1, 3)


def _layer_faces(faces: Any, label: str) -> NDArray[np.int64]:
    """(F, 3) int64 vertex indices (``label``: the argument's name in messages): a fractional index (1.5) was
    truncated to a vertex."""
    expected = "(F, 3) vertex indices"
    if isinstance(faces, np.ndarray) and faces.dtype.kind in "iu":
        given = faces
    else:
        given = real_numbers(faces, label, expected)
        wrong = given[given != np.round(given)]  # fractions, NaN and inf
        if wrong.size:
            raise InvalidInputError(f"{label} must be {expected}; got {wrong[0]:g} (not a whole number)")
    rows = _layer_rows(given, label, expected)
    return rows if rows.dtype == np.int64 else rows.astype(np.int64)


def _layer_rgb(rgb: Any, n_vertices: int, label: str) -> NDArray[Any]:
    """``rgb`` (V, 3|4) colours in 0-255 for ``n_vertices`` vertices, else an InvalidInputError naming ``label``:
    the wrong length raised pyvista's ValueError, one column numpy's IndexError, 300 wrapped to 44. A uint8
    array is taken as it is."""
    expected = f"(V, 3) or (V, 4) colours in 0-255, one per vertex ({n_vertices})"
    uint8 = isinstance(rgb, np.ndarray) and rgb.dtype == np.uint8
    colors = rgb if uint8 else real_numbers(rgb, label, expected)
    if colors.ndim != 2 or colors.shape[0] != n_vertices or colors.shape[1] not in (3, 4):
        raise InvalidInputError(f"{label} must be {expected}; got shape {colors.shape}")
    if not uint8 and colors.size and not (0 <= colors.min() and colors.max() <= 255):  # NaN fails both
        raise InvalidInputError(f"{label} must be {expected}; got values from {colors.min():g} to {colors.max():g}")
    return colors


def _layer_values(values: Any, n_vertices: int, name: str) -> NDArray[np.float64]:
    """``values`` (V,) numbers in [0, 1] for the ``n_vertices`` of layer ``name``, else an InvalidInputError: the
    wrong length raised pyvista's ValueError, NaN became an arbitrary gray, 1.5 was clipped to white."""
    label, expected = f"values of layer {name!r}", f"one finite number in [0, 1] per vertex ({n_vertices})"
    array = real_numbers(values, label, expected)
    if array.size != n_vertices:
        raise InvalidInputError(f"{label} must be {expected}; got shape {array.shape}")
    array = array.reshape(-1)
    if array.size and not np.isfinite(array.sum()):  # no mask when all are finite
        bad = np.flatnonzero(~np.isfinite(array))
        if bad.size:
            raise InvalidInputError(f"{label} must be {expected}; got NaN or inf at vertex {bad[0]}")
    if array.size and not (0.0 <= array.min() and array.max() <= 1.0):
        k = int(np.flatnonzero((array < 0.0) | (array > 1.0))[0])
        raise InvalidInputError(f"{label} must be {expected}; got {array[k]:g} at vertex {k}")
    return array


#: The most passes :meth:`LayeredRenderer.render` keeps for ``reuse`` (those of the current view; the oldest go first).
_REUSED_PASSES = 8


def _check_layers(layers: Any) -> dict[int, tuple[Any, Any, dict[str, Any]]]:
    """:meth:`LayeredRenderer.render_layers`' ``layers`` checked for their shape, else an InvalidInputError naming the
    layer: a list raised AttributeError ('items'), a short entry ValueError (unpack), options None AttributeError
    ('get'), an unknown option set_mesh's TypeError, and a str key "merged0" took the name of a merged pass (one actor
    for two layers). Their arrays are checked by :meth:`LayeredRenderer.set_mesh`."""
    expected = "(vertices, faces, options), options a dict of 'rgb' or 'values' (or {})"
    if not isinstance(layers, Mapping):
        raise InvalidInputError(f"layers must be a dict {{k: (vertices, faces, options)}} (k an int); got "
                                f"{type(layers).__name__}")
    for k, entry in layers.items():
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)):
            raise InvalidInputError(f"layers keys must be ints (the layer numbers); got {k!r:.80}")
        if not isinstance(entry, (tuple, list)) or len(entry) != 3:
            got = type(entry).__name__ + (f" of {len(entry)}" if isinstance(entry, (tuple, list)) else "")
            raise InvalidInputError(f"layers[{k}] must be {expected}; got {got}")
        if not isinstance(entry[2], Mapping):
            raise InvalidInputError(f"layers[{k}] must be {expected}; got options {type(entry[2]).__name__}")
        unknown = sorted(str(name) for name in entry[2] if name not in ("rgb", "values"))
        if unknown:
            raise InvalidInputError(f"layers[{k}] options may hold 'rgb' and 'values' only; got {unknown}")
    return layers


def _camera_token(camera: CameraLike) -> Any:
    """What tells one camera from another exactly: a name, or its numbers' float64 bytes. ``repr`` of a numpy camera
    prints 8 digits, so two UTM eye positions centimetres apart had one token and the second kept the first's view."""
    if isinstance(camera, str):
        return camera
    try:
        numbers = np.asarray(camera, dtype=np.float64)
    except (TypeError, ValueError):  # ragged or not numbers: refused by _camera_position, repr is enough till then
        return repr(camera)
    return numbers.shape, numbers.tobytes()


class LayeredRenderer:
    """Off-screen layered rendering (paper 001 §IV): one pass per layer into a color and a depth image.

    Meshes are uploaded once under a name (:meth:`set_mesh`) and stay between passes and frames; a pass
    (:meth:`render`) shows only the named meshes and reads back the color and the depth buffer without
    rendering twice. Every pass of a frame shares the camera, lights and clipping range set by
    :meth:`set_view`, so their depths compare. Lit meshes are drawn exactly as :func:`render_mesh` draws
    them (same lights, flat shading, material); ``values`` meshes are unlit and carry a value in [0, 1] as
    their gray level (read back from the red channel), for image-based mappings such as anchor opacity.

        renderer = LayeredRenderer(window_size=(1280, 720))
        renderer.set_mesh("overview", mesh.vertices, mesh.faces)
        renderer.set_view("oblique", box)
        color, depth = renderer.render(["overview"])   # depth: z-buffer in [0, 1), inf where empty

    A window whose passes would exceed the memory budget (about 64 bytes per pixel with the images read back) is
    refused when the renderer is made, with an OutputTooLargeError; so is a :meth:`set_mesh` whose mesh, with those
    already held, would (their copies for rendering, about 40 bytes per face and 112 per vertex, as in
    :func:`render_mesh`).
    """

    def __init__(self, *, window_size: tuple[int, int] = (1280, 720),
                 background: str | tuple[float, float, float] = "white", z_scale: float = 1.0) -> None:
        width, height, z_scale = _check_window(window_size, z_scale)
        _check_render_budget(width, height, layered=True)
        self.size = (width, height)
        self.z_scale = z_scale
        self.background = background
        self._pv = _import_pyvista()
        _check_background(self._pv, background)
        self._plotter = self._new_plotter(self.size)
        self._actors: dict[str, Any] = {}
        self._meshes: dict[str, Any] = {}
        self._versions: dict[str, int] = {}
        self._view_version = 0
        self._passes: dict[tuple[str, ...], Any] = {}
        self._joined: dict[Any, Any] = {}
        self._layer_names: dict[str, set[str]] = {}  # render_layers' layers by prefix, as of its last call
        self._keys: dict[str, Any] = {}
        self._bounds: dict[str, NDArray[np.float64]] = {}
        self._local_bounds: dict[str, NDArray[np.float64]] = {}
        self._origin: NDArray[np.float64] | None = None
        self._box: NDArray[np.float64] | None = None
        self._view_token: Any = None
        self._closed = False

    def _check_open(self) -> None:
        """An InvalidInputError once :meth:`close` ran: the closed plotter's window is gone, and a renderer used
        after it went on against it (set_mesh and set_view without a word, then VTK's AttributeError at the first
        pass, or render_closeups' "no layer named ['overview']; have []")."""
        if self._closed:
            raise InvalidInputError("this LayeredRenderer is closed (close() ran, or its with-block ended); its render "
                                    "window is released: make a new one")

    @_quietly
    def _new_plotter(self, size: tuple[int, int]) -> Any:
        plotter = self._pv.Plotter(off_screen=True, window_size=size, lighting="none", theme=_default_theme(self._pv))
        if not plotter.render_window.SupportsOpenGL():
            plotter.close()
            raise MissingDependencyError(
                "off-screen rendering needs OpenGL, but VTK could not create a context; install Mesa "
                "(libegl1, libgl1-mesa-dri or libosmesa6) or run where a GPU driver is present"
            )
        plotter.disable_anti_aliasing()
        plotter.set_background(self.background)
        # passes are read back from the buffer they were drawn into (``_read``); nothing is shown, so no frame
        # needs presenting: without the swap VTK skips copying every pass to the display framebuffer
        plotter.render_window.SwapBuffersOff()
        return plotter

    # -------------------------------------------------------------------------- meshes
    def has(self, name: str, key: Any) -> bool:
        """True when ``name`` was uploaded with this ``key`` (e.g. the overview of the same terrain)."""
        return name in self._actors and self._keys.get(name) == key

    def bounds_of(self, name: str) -> NDArray[np.float64]:
        """World bounds (2, 3) of an uploaded mesh."""
        if not isinstance(name, str) or name not in self._bounds:  # a bare KeyError (a list: TypeError) named nothing
            raise InvalidInputError(f"no layer named {name!r}; have {sorted(self._bounds)}")
        return self._bounds[name]

    def _local(self, vertices: NDArray[np.float64]) -> NDArray[np.float64]:
        local = np.asarray(vertices, dtype=np.float64) - self._origin
        local[:, 2] *= self.z_scale
        return local

    def _misses(self, box: ArrayLike) -> bool:
        """Whether the camera of :meth:`set_view` sees none of the world ``box`` (2, 3), as :func:`_misses_view`
        (conservative: a box that may touch the view is seen)."""
        width, height = self.size
        return _misses_view(self._local(np.asarray(box, dtype=np.float64)), self._plotter.camera_position,
                            width / height, float(self._plotter.camera.view_angle))

    @_quietly
    def set_mesh(self, name: str, vertices: ArrayLike, faces: ArrayLike, *, rgb: ArrayLike | None = None,
                 values: ArrayLike | None = None, key: Any = None, bounds: ArrayLike | None = None) -> None:
        """Upload (or replace) the mesh ``name`` (a string): lit, with vertex ``rgb`` (V, 3) uint8 (or (V, 4), or
        numbers in 0-255) or the default tan, or unlit with ``values`` (V,) in [0, 1] as gray levels (not both).
        A (V, 4) ``rgb``'s alpha is ignored: the layer is drawn opaque (layers are read back opaque and composited
        by depth, with no blending; blend a translucent colour over what lies behind it before passing it).
        The first mesh fixes the local origin. ``bounds``: the (2, 3) bounds of the finite vertices when the caller
        already has them. A NaN vertex is left out of the framing (its faces are not drawn); an infinite one, like
        any bad argument, raises an InvalidInputError naming it."""
        self._check_open()
        if not isinstance(name, str):  # render() sorts the names: a number beside a string raised a TypeError
            raise InvalidInputError(f"name must be a string; got {name!r}")
        if rgb is not None and values is not None:
            raise InvalidInputError(f"layer {name!r} takes rgb or values, not both; got both")
        faces_in, rgb_in = (a if _frozen(a) else None for a in (faces, rgb))  # read-only inputs: kept by identity
        label = f"vertices of layer {name!r}"
        vertices = np.asarray(_layer_rows(vertices, label, "(V, 3) coordinates"), np.float64)
        # an infinite vertex, even one no face uses, left VTK's render blank, without a word
        if bounds is None:
            bounds = _finite_bounds(vertices, label)
        else:  # a (3,) box failed to unpack; a NaN one made a NaN origin
            if len(vertices):
                finite_or_nan(vertices, label)
            bounds = _check_box(bounds, f"bounds of layer {name!r}")
        faces = _layer_faces(faces, f"faces of layer {name!r}")
        if rgb is not None:
            rgb = _layer_rgb(rgb, len(vertices), f"rgb of layer {name!r}")
        if values is not None:
            values = _layer_values(values, len(vertices), name)
        if len(faces) == 0 or bounds is None:
            raise InvalidInputError(f"layer {name!r} has no faces or no finite vertex; nothing to render")
        # the copies of every mesh held, this one's included, as render_mesh counts its mesh's (only the window was)
        held = [(entry[0].n_points, len(entry[2])) for other, entry in self._meshes.items() if other != name]
        _check_render_budget(*self.size, layered=True, mesh=(len(vertices) + sum(v for v, _ in held),
                                                             len(faces) + sum(f for _, f in held)))
        lo, hi = bounds
        origin = (lo + hi) / 2.0 if self._origin is None else self._origin
        local_box = np.array([lo, hi]) - origin
        with np.errstate(over="ignore", invalid="ignore"):  # beyond float64: refused below, not RuntimeWarnings
            local_box[:, 2] *= self.z_scale  # z_scale > 0 keeps the order
        # as render_mesh: z_scale=1e308 rendered a blank image, with a warning
        _check_reach(local_box, lo, hi, self.z_scale, f"layer {name!r}", f"layer {name!r} spans {_fmt_box(lo, hi)}, "
                     "too large", "the origin")
        self._origin = origin
        local = self._local(vertices)
        self._versions[name] = self._versions.get(name, 0) + 1
        kind = ("values" if values is not None else "rgb" if rgb is not None else "plain", len(local))
        previous = self._meshes.get(name)
        if previous is not None and previous[1] == kind and (
                (faces_in is not None and previous[3] is faces_in) or np.array_equal(previous[2], faces)):
            # same topology (a close-up that moved or turned): update the points and colors in place (the same
            # read-only faces or colors object as last time is known equal without comparing)
            poly = previous[0]
            if not np.array_equal(poly.points, local):  # unchanged points stay uploaded
                poly.points = local
            if not (rgb_in is not None and previous[4] is rgb_in):
                colors = (_gray_levels(values) if values is not None else
                          np.ascontiguousarray(np.asarray(rgb)[:, :3], dtype=np.uint8) if rgb is not None else None)
                if colors is not None and not np.array_equal(poly.point_data["rgb"], colors):
                    poly.point_data["rgb"] = colors
            self._meshes[name] = (poly, kind, previous[2], faces_in, rgb_in)
            self._keys[name] = key
            self._bounds[name] = np.array([lo, hi])
            self._local_bounds[name] = local_box
            return
        check_face_indices(faces, len(local), f"faces of layer {name!r}")  # a new topology: checked once
        self.remove(name)
        poly = _polydata(self._pv, local, faces)
        self._meshes[name] = (poly, kind, faces.copy(), faces_in, rgb_in)
        kwargs: dict[str, Any] = {}
        if values is not None:
            poly.point_data["rgb"] = _gray_levels(values)
            kwargs.update(scalars="rgb", rgb=True, lighting=False, ambient=1.0, diffuse=0.0, specular=0.0)
        else:
            if rgb is not None:
                poly.point_data["rgb"] = np.ascontiguousarray(np.asarray(rgb)[:, :3], dtype=np.uint8)
                kwargs.update(scalars="rgb", rgb=True)
            else:
                kwargs.update(color=_DEFAULT_COLOR)
            kwargs.update(ambient=_AMBIENT, diffuse=_DIFFUSE, specular=0.0, lighting=True)
        self._actors[name] = self._plotter.add_mesh(poly, **_UNTHEMED, show_scalar_bar=False, reset_camera=False,
                                                    **kwargs)
        self._keys[name] = key
        self._bounds[name] = np.array([lo, hi])
        self._local_bounds[name] = local_box

    @_quietly
    def remove(self, name: str) -> None:
        """Drop the mesh ``name`` if present."""
        actor = self._actors.pop(name, None)
        self._meshes.pop(name, None)
        if actor is not None:
            self._plotter.remove_actor(actor, render=False)
        self._keys.pop(name, None)
        self._bounds.pop(name, None)
        self._local_bounds.pop(name, None)

    # -------------------------------------------------------------------------- view
    @_quietly
    def set_view(self, camera: CameraLike, box: ArrayLike, *, view_angle: float = _VIEW_ANGLE) -> None:
        """Camera (as in :func:`render_mesh` with ``bounds=box``: an explicit position is in world coordinates minus
        the centre of ``box``, z scaled) fitted to the world ``box`` (2, 3) with the vertical field of view
        ``view_angle`` (degrees, as render_mesh's), its lights and clipping range. A
        fitted camera that would show the z-scaled box less than a pixel wide or tall (a ``z_scale`` far too large or
        small for the terrain) is an InvalidInputError, as in :func:`render_mesh`: such a render came out blank. The
        near plane keeps off the meshes uploaded by then, as render_mesh's keeps off its mesh. A fitted camera needs a
        ``box`` of some size (a single point is refused)."""
        self._check_open()
        if self._origin is None:
            raise InvalidInputError("set_view needs a mesh first (set_mesh)")
        view_angle = _check_view_angle(view_angle)
        world = _check_box(box, "box")
        fitted = _fitted_camera(camera)
        if fitted:  # a single point: refused by name (far from the origin the eye fell on it, numpy warned)
            _check_fitted_box(world, "box")
        local = world - self._origin
        local[:, 2] *= self.z_scale
        token = (_camera_token(camera), local.tobytes(), view_angle)
        if token == self._view_token:
            return  # the same camera and box: view, lights and clipping range stay (and so may cached passes)
        width, height = self.size
        corners = _box_corners(local)
        position = _camera_position(camera, corners, width / height, view_angle)
        if fitted:  # as render_mesh, a sliver is refused
            _check_visible(corners, position, (width, height), local, self.z_scale, view_angle, camera)
        else:  # an explicit position is relative to the centre of ``box``, as render_mesh's to that of its bounds: it
            # was taken relative to the first mesh's centre, another view wherever the box was not centred on it
            centre = local.mean(axis=0)
            position = [tuple((np.asarray(position[0]) + centre).tolist()),
                        tuple((np.asarray(position[1]) + centre).tolist()), position[2]]
        # the token once the camera passed its checks: a refused camera asked again is refused again
        self._view_token = token
        self._view_version += 1
        look_from = np.subtract(position[0], position[1])
        fill = (math.atan2(look_from[0], look_from[1]), _FILL_ELEVATION)
        self._plotter.remove_all_lights()
        for light in _lights(self._pv, local, fill):
            self._plotter.add_light(light)
        self._plotter.camera_position = position
        self._plotter.camera.view_angle = view_angle
        seen = [local] + list(self._local_bounds.values())
        union = np.array([np.min([b[0] for b in seen], axis=0), np.max([b[1] for b in seen], axis=0)])
        # the meshes uploaded by now (the overview, before its close-ups) keep the near plane off a close eye's ground
        meshes = [(np.asarray(entry[0].points, dtype=np.float64), entry[2]) for entry in self._meshes.values()]
        self._plotter.camera.clipping_range = _clipping_range(self._plotter.camera_position, union, meshes)
        self._box = local

    # -------------------------------------------------------------------------- passes
    @_quietly
    def _read(self, plotter: Any, rect: tuple[int, int, int, int] | None = None
              ) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkCommonCore import vtkFloatArray, vtkUnsignedCharArray

        window = plotter.render_window
        window.Render()
        width, height = window.GetSize()
        c0, r0, c1, r1 = (0, 0, width, height) if rect is None else rect
        if c1 <= c0 or r1 <= r0:  # an empty box: nothing to read back
            return np.zeros((max(r1 - r0, 0), max(c1 - c0, 0), 3), np.uint8), \
                np.full((max(r1 - r0, 0), max(c1 - c0, 0)), np.inf, np.float32)
        # OpenGL rows count from the bottom: image rows r0..r1 are window rows height-r1..height-r0
        x0, y0, x1, y1 = c0, height - r1, c1 - 1, height - r0 - 1
        pixels = vtkUnsignedCharArray()
        window.GetPixelData(x0, y0, x1, y1, 0, pixels, 0)
        depth = vtkFloatArray()
        window.GetZbufferData(x0, y0, x1, y1, depth)
        w, h = c1 - c0, r1 - r0
        color = vtk_to_numpy(pixels).reshape(h, w, -1)[::-1, :, :3]
        z = vtk_to_numpy(depth).reshape(h, w)[::-1].astype(np.float32)
        z[z >= 1.0] = np.inf
        if color.size == 0:
            raise MissingDependencyError("off-screen rendering produced no image; the OpenGL context is unusable")
        return np.ascontiguousarray(color, dtype=np.uint8), np.ascontiguousarray(z)

    def render(self, names: Sequence[str], *, reuse: bool = False, rect: tuple[int, int, int, int] | None = None
               ) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
        """One pass with only ``names`` (a sequence of layer names, e.g. ``["overview"]``) visible: (H, W, 3) uint8
        color and (H, W) float32 depth (inf: empty).

        With ``reuse`` the previous images of the same pass come back without rendering when neither the view
        nor those meshes changed since (a still camera over a still overview while close-ups move); a pass with
        ``reuse`` comes back read-only (the cached images themselves: copy them to edit). With
        ``rect`` = (col0, row0, col1, row1) (end exclusive, row 0 at the top) only that part of the window is
        read back: the images are ``window[row0:row1, col0:col1]`` of the full pass, pixel for pixel."""
        self._check_open()
        if self._box is None:
            raise InvalidInputError("render needs a view first (set_view)")
        reuse = check_flag(reuse, "reuse")  # "no" is true to Python: a cached pass came back
        try:  # a string is a sequence of characters: render("ab") showed layers 'a' and 'b'
            wanted = set(names) if not isinstance(names, (str, bytes)) else None
        except TypeError:  # not iterable (5), or unhashable names
            wanted = None
        if wanted is None:
            raise InvalidInputError(f"names must be a sequence of layer names, e.g. ['overview']; got {names!r}")
        unknown = wanted - set(self._actors)
        if unknown:
            raise InvalidInputError(f"no layer named {sorted(unknown)}; have {sorted(self._actors)}")
        if rect is not None:  # before the pass key: int() truncated 1.7 and read True as 1, 'abcd' raised its own
            rect = self._check_rect(rect)
        key = tuple(sorted(wanted)) + (() if rect is None else (rect,))
        state = (self._view_version, tuple(self._versions.get(n, 0) for n in sorted(wanted)))
        cached = self._passes.get(key)
        if reuse and cached is not None and cached[0] == state:
            return cached[1].view(), cached[2].view()
        for name, actor in self._actors.items():
            actor.SetVisibility(name in wanted)
        color, depth = self._read(self._plotter, rect)
        if reuse:  # the cache's own images, read-only: a caller who edited the returned image (it was the cached
            # array itself) changed what the next reuse returned. Views of read-only arrays cannot be made writeable
            # again, and cost no copy; a caller who edits one makes a copy
            color.flags.writeable = depth.flags.writeable = False
            # a pass of an earlier view is never reused (the view's version only grows): kept, a loop moving the
            # camera with a crop following a mesh held every frame's images; of this view's, the latest few stay
            for old in [k for k, (kept, _c, _d) in list(self._passes.items()) if kept[0] != self._view_version]:
                self._passes.pop(old, None)
            self._passes.pop(key, None)  # put back last: the most recent
            while len(self._passes) >= _REUSED_PASSES:
                self._passes.pop(next(iter(self._passes)))
            self._passes[key] = (state, color, depth)
            return color.view(), depth.view()
        return color, depth

    def _check_rect(self, rect: Any) -> tuple[int, int, int, int]:
        """``rect`` (col0, row0, col1, row1) as four ints inside the window, else an InvalidInputError naming it."""
        width, height = self.size
        expected = f"four whole pixel numbers (col0, row0, col1, row1) in the {width}x{height} window"
        sides = _pixel_sequence(rect)
        if len(sides) != 4 or None in sides:
            raise InvalidInputError(f"rect must be {expected}; got {rect!r}")
        c0, r0, c1, r1 = sides
        if not (0 <= c0 <= c1 <= width and 0 <= r0 <= r1 <= height):
            raise InvalidInputError(f"rect must lie in the {width}x{height} window as (col0, row0, col1, "
                                    f"row1); got {rect!r}")
        return c0, r0, c1, r1

    def render_layers(self, prefix: str, layers: dict[int, tuple[Any, Any, dict[str, Any]]], *,
                      merge: bool = True, crop: bool = False) -> dict[int, tuple[Any, ...]]:
        """Color and depth of each layer k as if rendered alone (``layers[k]`` = vertices, faces, and
        ``rgb=`` or ``values=`` as for :meth:`set_mesh`).

        With ``merge``, layers of the same kind whose screen boxes (the projected corners of their bounds,
        all in front of the camera) do not overlap share one pass, whose images are then split by those
        boxes: no fragment of one layer can fall in another's box, so each layer's pixels are those of its
        own pass (to the float32 rounding of VTK's per-buffer coordinate shift, a gray level at a few
        pixels), with fewer passes (a pass has a fixed cost: clearing, reading back).

        With ``crop`` each layer comes back as (color, depth, rect): only its screen box ``rect`` = (col0, row0,
        col1, row1) is read back (the whole window where the box is unknown), and the images are exactly that
        part of the full-window images (outside it a layer has no fragment), so the read-backs and the
        compositing cost follow the close-up's size on screen, not the window's.

        The layers of this ``prefix`` that the previous call uploaded and this one does not draw (a close-up gone,
        layers merged otherwise) are removed first: their memory is freed, and they no longer widen the clipping range
        of the next :meth:`set_view`. The layers are named ``"{prefix}:{k}"`` (``"{prefix}:merged{g}"`` for a shared
        pass), so ``prefix`` is a str without ':'."""
        self._check_open()
        if not isinstance(prefix, str) or ":" in prefix:
            raise InvalidInputError(f"render_layers prefix must be a str without ':' (its layers are named "
                                    f"'prefix:k'); got {prefix!r}")
        layers = _check_layers(layers)
        merge, crop = check_flag(merge, "merge"), check_flag(crop, "crop")
        rects: dict[int, tuple[int, int, int, int] | None] = {}
        # (V, 3) rows once per layer, checked here: "x" raised numpy's ValueError before set_mesh saw it, and a flat
        # (3V,) array counted 3V vertices in a merged pass (its faces shifted onto the next layer's vertices)
        rows = {k: np.asarray(_layer_rows(v, f"layers[{k}] vertices", "(V, 3) coordinates"), np.float64)
                for k, (v, _f, _kw) in layers.items()}
        boxes = {k: _finite_bounds(rows[k]) for k in layers}
        for k in layers:
            rects[k] = self._box_rect(boxes[k]) if merge else None
        groups: list[list[int]] = []
        for k, (_v, _f, kw) in layers.items():
            kind = "values" if kw.get("values") is not None else "rgb" if kw.get("rgb") is not None else "plain"
            placed = False
            if rects[k] is not None:
                for group in groups:
                    first = group[0]
                    kind0 = ("values" if layers[first][2].get("values") is not None
                             else "rgb" if layers[first][2].get("rgb") is not None else "plain")
                    if kind0 == kind and all(rects[j] is not None and not _overlap(rects[k], rects[j])
                                             for j in group):
                        group.append(k)
                        placed = True
                        break
            if not placed:
                groups.append([k])
        # this call's layer names; those of this prefix's previous call not among them (a close-up gone, layers merged
        # otherwise) are dropped first: kept hidden, they held their meshes' memory, counted against the budget of
        # this call's uploads (a frame the budget allowed was refused), and widened the next view's clipping range
        # (its far plane out to where a close-up once was, its near plane 300 times nearer: depth precision lost)
        # "prefix:k" and "prefix:merged<g>": the prefix holds no ':', so a name tells its prefix (bare prefix + k
        # collided: "cu" + "10" and "cu1" + "0" were one actor, and a call of one prefix removed the other's layer)
        names = [f"{prefix}:{group[0]}" if len(group) == 1 else f"{prefix}:merged{g}" for g, group in enumerate(groups)]
        for stale in self._layer_names.get(prefix, set()) - set(names):
            self.remove(stale)
        self._layer_names[prefix] = set(names)
        out: dict[int, tuple[NDArray[np.uint8], NDArray[np.float32]]] = {}
        for name, group in zip(names, groups, strict=True):
            if len(group) == 1:
                k = group[0]
                _v, faces, kw = layers[k]
                self.set_mesh(name, rows[k], faces, bounds=boxes[k], **kw)  # the float64 rows: not converted again
                if crop:
                    rect = rects[k] if rects[k] is not None else self._box_rect(boxes[k])
                    rect = rect if rect is not None else (0, 0, *self.size)
                    out[k] = (*self.render([name], rect=rect), rect)
                else:
                    out[k] = self.render([name])
                continue
            counts = np.cumsum([0] + [len(rows[k]) for k in group])
            vertices = np.concatenate([rows[k] for k in group])
            kw0 = layers[group[0]][2]

            def join(group: list[int] = group, counts: Any = counts, kw0: dict = kw0
                     ) -> tuple[NDArray[np.int64], NDArray[np.uint8] | None]:
                faces = np.concatenate([np.asarray(layers[k][1], np.int64) + counts[i] for i, k in enumerate(group)])
                joined_rgb = (np.concatenate([np.asarray(layers[k][2]["rgb"]) for k in group])
                              if kw0.get("rgb") is not None else None)
                return faces, joined_rgb

            # the joined faces and colors of read-only parts are kept while the parts are the same objects
            refs = tuple(x for k in group for x in (layers[k][1], layers[k][2].get("rgb")))
            if all(x is None or _frozen(x) for x in refs):
                faces, joined_rgb = derived(self._joined, (prefix, tuple(group)), refs, join, limit=16)
            else:
                faces, joined_rgb = join()
            kw = {"values": np.concatenate([np.asarray(layers[k][2]["values"]) for k in group])} \
                if kw0.get("values") is not None else {}
            if joined_rgb is not None:
                kw["rgb"] = joined_rgb
            parts = [boxes[k] for k in group if boxes[k] is not None]
            group_box = (np.array([np.min([b[0] for b in parts], axis=0), np.max([b[1] for b in parts], axis=0)])
                         if parts else None)
            self.set_mesh(name, vertices, faces, bounds=group_box, **kw)
            if crop:  # read back the union of the group's boxes, then cut each layer's own box out of it
                union = (min(rects[k][0] for k in group), min(rects[k][1] for k in group),
                         max(rects[k][2] for k in group), max(rects[k][3] for k in group))
                color, depth = self.render([name], rect=union)
                for k in group:
                    c0, r0, c1, r1 = rects[k]
                    box = (slice(r0 - union[1], r1 - union[1]), slice(c0 - union[0], c1 - union[0]))
                    out[k] = (color[box], depth[box], rects[k])
                continue
            color, depth = self.render([name])
            for k in group:
                c0, r0, c1, r1 = rects[k]
                own_color = np.zeros_like(color)
                own_depth = np.full(depth.shape, np.inf, np.float32)
                own_color[r0:r1, c0:c1] = color[r0:r1, c0:c1]
                own_depth[r0:r1, c0:c1] = depth[r0:r1, c0:c1]
                out[k] = (own_color, own_depth)
        return out

    def screen_rect(self, vertices: ArrayLike) -> tuple[int, int, int, int] | None:
        """Pixel box (col0, row0, col1, row1), end exclusive, holding every fragment of a mesh with these
        vertices, from the projected corners of their bounds (padded by 2 pixels); None when a corner lies
        behind the camera."""
        rows = _layer_rows(vertices, "vertices", "(N, 3) world points")  # "x" raised numpy's ValueError
        return self._box_rect(_finite_bounds(np.asarray(rows, dtype=np.float64)))

    def _box_rect(self, box: NDArray[np.float64] | None) -> tuple[int, int, int, int] | None:
        """:meth:`screen_rect` of the vertex bounds ``box`` (2, 3) (None: no finite vertex)."""
        if box is None:
            return None
        pixels = self.project(_box_corners(box))
        if not np.isfinite(pixels).all():
            return None
        width, height = self.size
        c0, r0 = np.floor(pixels.min(axis=0)).astype(int) - 2
        c1, r1 = np.ceil(pixels.max(axis=0)).astype(int) + 3
        # each side inside the window: a box wholly right of or below it was (col0 > col1 = width), a rect refused
        return (min(max(c0, 0), width), min(max(r0, 0), height), min(max(c1, 0), width), min(max(r1, 0), height))

    def project(self, points: ArrayLike) -> NDArray[np.float64]:
        """Pixel (column, row) of world points (N, 3) in the current view (row 0 at the top); NaN for a
        point behind the camera."""
        self._check_open()
        points = self._local(_layer_rows(points, "points", "(N, 3) world points"))
        width, height = self.size
        camera = self._plotter.renderer.GetActiveCamera()
        matrix = camera.GetCompositeProjectionTransformMatrix(width / height, -1, 1)
        m = np.array([[matrix.GetElement(i, j) for j in range(4)] for i in range(4)])
        clip = np.column_stack([points, np.ones(len(points))]) @ m.T
        w = np.where(clip[:, 3:4] > 1e-12, clip[:, 3:4], np.nan)
        ndc = clip[:, :3] / w
        col = (ndc[:, 0] + 1) / 2 * width
        row = height - (ndc[:, 1] + 1) / 2 * height
        return np.column_stack([col, row])

    @_quietly
    def render_billboard(self, vertices: ArrayLike, faces: ArrayLike, rgb: ArrayLike | None,
                         view: tuple[float, float], anchor_points: ArrayLike, *, axis: ArrayLike | None = None
                         ) -> tuple[NDArray[np.uint8], NDArray[np.bool_], NDArray[np.float32]]:
        """An overview-independent close-up (paper 001 §II.C): an orthographic render from the fixed direction
        ``view`` (azimuth, elevation; radians, the elevation in [-π/2, π/2]) pasted over the screen box of
        ``anchor_points`` (N, 3).

        ``vertices``, ``faces`` and ``rgb`` (or None: the default tan) as for :meth:`set_mesh`; as there, a NaN
        vertex is left out of the framing (its faces are not drawn). Returns the full-window color, coverage and
        depth (0 where covered: a billboard lies in front).

        ``axis``: (x, y) of the vertical axis the content and ``anchor_points`` turn about (a spinning close-up).
        The picture is then fitted from their bounding cylinders about it, which do not change as they turn: the
        content's (its largest distance from the axis and its height range) as seen from ``view``, into the screen
        box of the anchor points' cylinder, and centred there with the axis in the middle. The picture keeps one
        size and place over a spin (fitted to the turned content's box, it shrank by a quarter and more as the
        box's corners turned away from the screen axes), at the cost of being somewhat smaller than the box fit of
        content that does not turn (None)."""
        self._check_open()
        vertices = np.asarray(_layer_rows(vertices, "vertices", "(V, 3) coordinates"), dtype=np.float64)
        # an infinite vertex left VTK's render blank, one NaN vertex made the centre (every coordinate) NaN
        bounds = _finite_bounds(vertices, "vertices")
        if bounds is None:
            raise InvalidInputError(f"vertices must include a finite vertex; got "
                                    f"{counted(len(vertices), 'vertex', 'vertices')}, none finite (nothing to render)")
        faces = _layer_faces(faces, "faces")
        check_face_indices(faces, len(vertices), "faces")
        if rgb is not None:
            rgb = _layer_rgb(rgb, len(vertices), "rgb")
        direction = real_vector(view, "view", "(azimuth, elevation) in radians, finite", 2)  # it named "camera"
        if abs(float(direction[1])) > QUARTER_TURN:  # refused by _camera_position too, naming its "camera"
            raise InvalidInputError(f"view's elevation must lie in [-π/2, π/2] radians (-90 to 90 degrees, "
                                    f"math.radians(degrees)); got {view!r}, elevation {float(direction[1]):g}")
        anchor_points = _layer_rows(anchor_points, "anchor_points", "(N, 3) world points")
        spin_axis = None if axis is None else real_vector(axis, "axis", "finite (x, y)", 2)
        width, height = self.size
        color = np.zeros((height, width, 3), np.uint8)
        coverage = np.zeros((height, width), bool)
        depth = np.full((height, width), np.inf, np.float32)
        finite = np.isfinite(anchor_points).all(axis=1)
        if spin_axis is not None and finite.any():  # the anchor points' cylinder about the axis: turns keep it
            ring = np.linspace(0.0, 2 * math.pi, 64, endpoint=False)
            top = anchor_points[finite]
            # a 64-gon about the largest radius, widened to hold its circle
            radius = float(np.hypot(*(top[:, :2] - spin_axis).T).max()) / math.cos(math.pi / 64)
            circle = spin_axis + radius * np.column_stack([np.cos(ring), np.sin(ring)])
            anchor_points = np.vstack([np.column_stack([circle, np.full(len(ring), z)])
                                       for z in (top[:, 2].min(), top[:, 2].max())])
        pixels = self.project(anchor_points)
        pixels = pixels[np.isfinite(pixels).all(axis=1)]
        if len(pixels) == 0:
            return color, coverage, depth
        fc0, fr0 = np.floor(pixels.min(axis=0)).astype(int)
        fc1, fr1 = np.ceil(pixels.max(axis=0)).astype(int)
        c0, r0, c1, r1 = max(fc0, 0), max(fr0, 0), min(fc1, width), min(fr1, height)
        # the picture keeps its whole screen box and the window's edge cuts it: it was fitted whole into the part
        # inside the window (squeezed and shifted near the edge) and left out below 8 pixels there
        if fc1 - fc0 < 8 or fr1 - fr0 < 8 or c1 <= c0 or r1 <= r0:  # too small a picture, or none in the window
            return color, coverage, depth
        if spin_axis is None:  # rendered at least 8 pixels wide and tall, inside the whole box, then cut (a spinning
            if c1 - c0 < 8:  # one's part is cut by _spin_fit)
                c0 = max(fc0, c1 - 8)
                c1 = c0 + 8
            if r1 - r0 < 8:
                r0 = max(fr0, r1 - 8)
                r1 = r0 + 8
        bw, bh = c1 - c0, r1 - r0
        if spin_axis is None:
            centre = (bounds[0] + bounds[1]) / 2
        else:
            centre = np.array([spin_axis[0], spin_axis[1], (bounds[0, 2] + bounds[1, 2]) / 2])
        local = vertices - centre
        local[:, 2] *= self.z_scale
        fit = None
        if spin_axis is not None:
            fit = _spin_fit(local, direction, pixels, (width, height))
            if fit is None:
                return color, coverage, depth
            c0, r0, c1, r1 = fit[0]
            bw, bh = c1 - c0, r1 - r0
        plotter = self._new_plotter((bw, bh))
        try:
            poly = _polydata(self._pv, local, faces)
            kwargs: dict[str, Any] = {"color": _DEFAULT_COLOR}
            if rgb is not None:
                poly.point_data["rgb"] = np.ascontiguousarray(np.asarray(rgb)[:, :3], dtype=np.uint8)
                kwargs = {"scalars": "rgb", "rgb": True}
            plotter.add_mesh(poly, **_UNTHEMED, ambient=_AMBIENT, diffuse=_DIFFUSE, specular=0.0,
                             show_scalar_bar=False, **kwargs)
            box = bounds - centre  # the finite vertices' local bounds
            box[:, 2] *= self.z_scale
            position = _camera_position(tuple(direction.tolist()), _box_corners(box), bw / bh)
            look_from = np.subtract(position[0], position[1])
            for light in _lights(self._pv, box, (math.atan2(look_from[0], look_from[1]), _FILL_ELEVATION)):
                plotter.add_light(light)
            plotter.camera_position = position
            plotter.enable_parallel_projection()
            plotter.reset_camera(bounds=box.T.reshape(-1))
            plotter.camera_position = position[:1] + [position[1], position[2]]
            corners = _box_corners(box) - np.asarray(position[1])
            forward = np.asarray(position[1]) - np.asarray(position[0])
            forward /= np.linalg.norm(forward)
            right, up = _screen_axes(forward, np.asarray(position[2], dtype=np.float64))
            full_w, full_h = fc1 - fc0, fr1 - fr0
            half_h = max(np.abs(corners @ up).max(), np.abs(corners @ right).max() * full_h / full_w) * 1.02
            if fit is None and (bw, bh) != (full_w, full_h):  # the rendered part of the whole box, at its scale
                per_unit = full_h / (2 * half_h)
                dx, dy = (c0 + c1 - fc0 - fc1) / 2, (r0 + r1 - fr0 - fr1) / 2  # its centre from the box's, pixels
                shift = dx / per_unit * right - dy / per_unit * up
                position = [tuple((np.asarray(position[0]) + shift).tolist()),
                            tuple((np.asarray(position[1]) + shift).tolist()), position[2]]
                plotter.camera_position = position
                half_h = bh / 2 / per_unit
            if fit is not None:  # the axis at its place on screen, at the scale of the cylinders' fit
                _, per_unit, (dx, dy) = fit
                focal = -dx / per_unit * right + dy / per_unit * up
                distance = float(np.linalg.norm(np.subtract(position[0], position[1]))) + float(np.linalg.norm(focal))
                position = [tuple((focal - forward * distance).tolist()), tuple(focal.tolist()), position[2]]
                plotter.camera_position = position
                half_h = bh / 2 / per_unit
            plotter.camera.parallel_scale = float(half_h)
            plotter.camera.clipping_range = _clipping_range(plotter.camera_position, box)
            image, z = self._read(plotter)
        finally:
            with contextlib.suppress(Exception):
                plotter.close()
        covered = np.isfinite(z)
        window = (slice(max(r0, 0), min(r1, height)), slice(max(c0, 0), min(c1, width)))
        part = (slice(window[0].start - r0, window[0].stop - r0), slice(window[1].start - c0, window[1].stop - c0))
        color[window] = image[part]
        coverage[window] = covered[part]
        depth[window] = np.where(covered[part], 0.0, np.inf)
        return color, coverage, depth

    @_quietly
    def close(self) -> None:
        """Release the render window, and the meshes and passes held for it; the renderer is then unusable (an
        InvalidInputError says so). Closing again does nothing."""
        self._closed = True
        with contextlib.suppress(Exception):
            self._plotter.close()
        for held in (self._actors, self._meshes, self._versions, self._passes, self._joined, self._keys, self._bounds,
                     self._local_bounds):
            held.clear()

    def __enter__(self) -> LayeredRenderer:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _spin_fit(local: NDArray[np.float64], view: NDArray[np.float64], pixels: NDArray[np.float64],
              size: tuple[int, int]) -> tuple[tuple[int, int, int, int], float, tuple[float, float]] | None:
    """A turning billboard's picture (:meth:`LayeredRenderer.render_billboard` with ``axis``): ``local`` its content
    about the axis (x = y = 0) and its mid-height (z = 0), z scaled; ``view`` (azimuth, elevation); ``pixels`` the
    projected cylinder of its anchor points. Its content's cylinder seen from ``view`` fitted into their screen box
    and centred there: the pixel box (col0, row0, col1, row1), end exclusive, cut to the window ``size``; pixels per
    world unit; and the offset (columns, rows) of the axis from the cut box's centre. None: no pixel left."""
    position = _camera_position(tuple(view.tolist()), np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), 1.0)
    forward = np.subtract(position[1], position[0])
    forward /= np.linalg.norm(forward)
    right, up = _screen_axes(forward, np.asarray(position[2], dtype=np.float64))
    points = local[np.isfinite(local).all(axis=1)]
    radius = float(np.hypot(points[:, 0], points[:, 1]).max())
    half_z = float(np.abs(points[:, 2]).max())
    # a horizontal circle of radius r spans r·|e_xy| along a screen axis e, a vertical segment of ±h h·|e_z|
    half_w, half_h = ((radius * math.hypot(e[0], e[1]) + half_z * abs(e[2])) * 1.02 for e in (right, up))
    low, high = pixels.min(axis=0), pixels.max(axis=0)
    per_unit = float(min((high[0] - low[0]) / (2 * half_w) if half_w > 0 else math.inf,
                         (high[1] - low[1]) / (2 * half_h) if half_h > 0 else math.inf))
    if not math.isfinite(per_unit) or per_unit <= 0:
        return None
    cx, cy = (low + high) / 2
    width, height = size
    c0, r0 = max(math.floor(cx - half_w * per_unit), 0), max(math.floor(cy - half_h * per_unit), 0)
    c1, r1 = min(math.ceil(cx + half_w * per_unit), width), min(math.ceil(cy + half_h * per_unit), height)
    if c1 - c0 < 1 or r1 - r0 < 1:
        return None
    return (c0, r0, c1, r1), per_unit, (cx - (c0 + c1) / 2, cy - (r0 + r1) / 2)
