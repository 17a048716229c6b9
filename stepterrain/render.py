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
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from .errors import InvalidInputError, MissingDependencyError

__all__ = ["render_mesh", "save_png", "offscreen_available", "require_offscreen", "KEY_LIGHT_AZIMUTH",
           "KEY_LIGHT_ELEVATION", "render_textured_mesh"]

#: Direction the key light comes from: azimuth clockwise from north (+y), radians (north-west).
KEY_LIGHT_AZIMUTH = math.radians(315.0)
#: Elevation of the key light above the horizon, radians.
KEY_LIGHT_ELEVATION = math.radians(40.0)
_KEY_INTENSITY = 0.8
_FILL_INTENSITY = 0.45
_FILL_ELEVATION = math.radians(30.0)
_AMBIENT = 0.2
_DIFFUSE = 0.9

#: The fixed oblique view: camera azimuth (clockwise from north, radians; 180° = looking from the south
#: towards the north) and elevation above the horizon.
_OBLIQUE = (math.radians(190.0), math.radians(45.0))
_VIEW_ANGLE = 30.0  # degrees, vertical field of view
_DEFAULT_COLOR = (0.86, 0.82, 0.74)

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


def _import_pyvista() -> Any:
    _select_backend()
    try:
        import pyvista
        from vtkmodules.vtkCommonCore import vtkLogger, vtkObject
    except ImportError as exc:  # pragma: no cover - pyvista is a core dependency
        raise MissingDependencyError(f"rendering needs pyvista: pip install 'pyvista>=0.44' ({exc})") from exc
    # silence "bad X server connection" and similar start-up warnings; real errors still raise below
    vtkObject.GlobalWarningDisplayOff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    pyvista.OFF_SCREEN = True
    return pyvista


def require_offscreen() -> str:
    """Check cheaply that an off-screen OpenGL context can exist here; return the VTK window class chosen.

    Raises
    ------
    MissingDependencyError
        No display and neither EGL nor OSMesa is installed.
    """
    return _select_backend()


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


def _fit_distance(corners: NDArray[np.float64], view_dir: NDArray[np.float64], up: NDArray[np.float64],
                  aspect: float) -> float:
    """Distance from the box centre along ``view_dir`` at which every corner lies inside the view frustum."""
    forward = -view_dir
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    tan_v = math.tan(math.radians(_VIEW_ANGLE) / 2.0)
    tan_h = tan_v * aspect
    depth = corners @ forward  # corner offset along the viewing direction (positive: farther away)
    need_v = np.abs(corners @ true_up) / tan_v - depth
    need_h = np.abs(corners @ right) / tan_h - depth
    return float(max(need_v.max(), need_h.max(), 1e-9))


def _camera_position(
    camera: CameraLike, points: NDArray[np.float64], aspect: float
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
        try:
            spec = np.asarray(camera, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"camera must be 'oblique', 'top', (azimuth, elevation) in radians or "
                                    f"[(eye), (focal point), (view up)]; got {camera!r}") from exc
        if spec.shape == (3, 3) and np.all(np.isfinite(spec)):
            return [tuple(row) for row in spec.tolist()]
        if spec.shape != (2,) or not np.all(np.isfinite(spec)):
            raise InvalidInputError(f"camera must be 'oblique', 'top', (azimuth, elevation) in radians or "
                                    f"[(eye), (focal point), (view up)]; got {camera!r}")
        azimuth, elevation = float(spec[0]), float(np.clip(spec[1], -math.radians(89.9), math.radians(89.9)))
    view_dir = _direction(azimuth, elevation)
    up = np.array([0.0, 0.0, 1.0]) if abs(elevation) < math.radians(89.0) else np.array([0.0, 1.0, 0.0])
    corners = points
    focal = (corners.min(axis=0) + corners.max(axis=0)) / 2
    forward = -view_dir
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    for _ in range(4):  # fit, then recentre the projected box on screen, and fit again
        distance = _fit_distance(corners - focal, view_dir, up, aspect)
        eye = focal + view_dir * distance
        rel = corners - eye
        depth = rel @ forward
        sx = (rel @ right) / depth
        sy = (rel @ true_up) / depth
        shift = right * (sx.max() + sx.min()) / 2 + true_up * (sy.max() + sy.min()) / 2
        focal = focal + shift * distance
    distance = _fit_distance(corners - focal, view_dir, up, aspect) * 1.06
    eye = focal + view_dir * distance
    return [tuple(eye.tolist()), tuple(focal.tolist()), tuple(up.tolist())]


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


def _vertex_rgb(mesh: trimesh.Trimesh) -> NDArray[np.uint8] | None:
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.ColorVisuals) and visual.kind == "vertex":
        colors = np.asarray(visual.vertex_colors)
        if colors.shape == (len(mesh.vertices), 4):
            return np.ascontiguousarray(colors[:, :3], dtype=np.uint8)
    return None


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
) -> NDArray[np.uint8]:
    """Render ``mesh`` off-screen and return the image.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Any triangle mesh; a stepped terrain renders with its vertex colors when it has them.
    window_size : (width, height)
        Image size in pixels.
    z_scale : float
        Vertical exaggeration applied for the render only (the mesh is not modified).
    camera : "oblique", "top", (azimuth, elevation) or [(eye), (focal point), (view up)]
        "oblique" is the fixed reproducible view from just west of south at 45° elevation; a pair gives the
        direction the camera looks from (radians, azimuth clockwise from north = +y); both are fitted to the
        bounds. An explicit pyvista camera position is used as given, in the mesh's coordinates minus the
        centre of ``bounds`` (the render recentres the mesh to keep UTM-sized coordinates precise).
    background : color
        Any pyvista color.
    scalars : None, "level" or "height"
        None: the mesh's vertex colors if it has them, else a uniform light tan. "level": faces colored by
        ``face_attributes["level"]`` (stepped meshes); "height": vertices colored by z. Both use ``cmap``.
    cmap : str
        Matplotlib colormap for ``scalars``.
    show_edges : bool
        Draw triangle edges.
    anti_aliasing : bool
        Multi-sample anti-aliasing (off by default: reproducible, and faster on software OpenGL).
    bounds : (2, 3) array_like, optional
        A world-space box [(xmin, ymin, zmin), (xmax, ymax, zmax)] to frame instead of the mesh itself: the
        same box for every frame of an animation keeps the camera still.

    Returns
    -------
    (H, W, 3) uint8
        The rendered image, H = window_size[1], W = window_size[0].

    Raises
    ------
    InvalidInputError
        Bad window size, z_scale, camera or scalars, or an empty mesh.
    MissingDependencyError
        No off-screen OpenGL context can be made (no display, no EGL/OSMesa).

    Notes
    -----
    Flat shading: each face keeps its own normal, so terraces (normal +z) and walls (horizontal normals)
    get different brightness from the key light and no step edge is smoothed away. Vertices are recentred
    (float64) before VTK sees them. Cost on software OpenGL (Mesa llvmpipe, 2 cores): about a second per
    million faces, most of it uploading the geometry.
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh; got {type(mesh).__name__}")
    if len(mesh.faces) == 0:
        raise InvalidInputError("mesh has no faces; nothing to render")
    try:
        width, height = (int(v) for v in window_size)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"window_size must be (width, height); got {window_size!r}") from exc
    if not (8 <= width <= 16384 and 8 <= height <= 16384):
        raise InvalidInputError(f"window_size must lie in [8, 16384] pixels; got {window_size!r}")
    z_scale = float(z_scale)
    if not math.isfinite(z_scale) or z_scale <= 0:
        raise InvalidInputError(f"z_scale must be a positive finite number; got {z_scale}")
    if scalars not in (None, "level", "height"):
        raise InvalidInputError(f"scalars must be None, 'level' or 'height'; got {scalars!r}")

    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.any():
        raise InvalidInputError("mesh has no finite vertex")
    if bounds is None:
        lo, hi = vertices[finite].min(axis=0), vertices[finite].max(axis=0)
    else:
        box = np.asarray(bounds, dtype=np.float64)
        if box.shape != (2, 3) or not np.isfinite(box).all() or np.any(box[1] < box[0]):
            raise InvalidInputError(
                f"bounds must be [(xmin, ymin, zmin), (xmax, ymax, zmax)] with max >= min; got {bounds!r}")
        lo, hi = box[0], box[1]
    centre = (lo + hi) / 2.0
    local = vertices - centre
    local[:, 2] *= z_scale
    box = np.array([lo - centre, hi - centre])
    box[:, 2] *= z_scale
    face_attributes = {}
    if scalars == "level":
        if "level" not in mesh.face_attributes:
            raise InvalidInputError("scalars='level' needs face_attributes['level'] (a stepped mesh)")
        face_attributes["level"] = np.asarray(mesh.face_attributes["level"], dtype=np.float32)

    pv = _import_pyvista()
    poly = pv.wrap(trimesh.Trimesh(local, mesh.faces, process=False, face_attributes=face_attributes))
    add_kwargs: dict[str, Any] = {}
    rgb = _vertex_rgb(mesh) if scalars is None else None
    if rgb is not None:
        poly.point_data["rgb"] = rgb
        add_kwargs.update(scalars="rgb", rgb=True)
    elif scalars == "level":
        add_kwargs.update(scalars="level", cmap=cmap, preference="cell", show_scalar_bar=False)
    elif scalars == "height":
        poly.point_data["height"] = vertices[:, 2].astype(np.float32)
        add_kwargs.update(scalars="height", cmap=cmap, show_scalar_bar=False)
    else:
        add_kwargs.update(color=_DEFAULT_COLOR)

    plotter = pv.Plotter(off_screen=True, window_size=(width, height), lighting="none")
    try:
        if not plotter.render_window.SupportsOpenGL():
            raise MissingDependencyError(
                "off-screen rendering needs OpenGL, but VTK could not create a context; install Mesa "
                "(libegl1, libgl1-mesa-dri or libosmesa6) or run where a GPU driver is present"
            )
        if anti_aliasing:
            plotter.enable_anti_aliasing("msaa")
        else:
            plotter.disable_anti_aliasing()
        plotter.set_background(background)
        framed = _frame_points(local, finite) if bounds is None else _box_corners(box)
        position = _camera_position(camera, framed, width / height)
        look_from = np.subtract(position[0], position[1])
        fill = (math.atan2(look_from[0], look_from[1]), _FILL_ELEVATION)
        for light in _lights(pv, box, fill):
            plotter.add_light(light)
        plotter.add_mesh(poly, smooth_shading=False, show_edges=show_edges, ambient=_AMBIENT,
                         diffuse=_DIFFUSE, specular=0.0, lighting=True, **add_kwargs)
        plotter.camera_position = position
        plotter.camera.view_angle = _VIEW_ANGLE
        seen = local[finite]
        union = np.array([np.minimum(box[0], seen.min(axis=0)), np.maximum(box[1], seen.max(axis=0))])
        plotter.camera.clipping_range = _clipping_range(plotter.camera_position, union)
        image = plotter.screenshot(return_img=True)
    finally:
        with contextlib.suppress(Exception):
            plotter.close()
    if image is None or image.ndim != 3 or image.shape[:2] != (height, width):
        raise MissingDependencyError("off-screen rendering produced no image; the OpenGL context is unusable")
    return np.ascontiguousarray(image[:, :, :3], dtype=np.uint8)


def _box_corners(box: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[x, y, z] for x in box[:, 0] for y in box[:, 1] for z in box[:, 2]])


def _frame_points(local: NDArray[np.float64], finite: NDArray[np.bool_]) -> NDArray[np.float64]:
    """At most ~100k finite vertices, evenly strided: the camera frames the mesh itself, not its box."""
    points = local[finite]
    stride = max(1, len(points) // 100_000)
    return points[::stride]


def _clipping_range(position: Any, bounds: NDArray[np.float64]) -> tuple[float, float]:
    eye = np.asarray(position[0], dtype=np.float64)
    corners = _box_corners(bounds)
    distances = np.linalg.norm(corners - eye, axis=1)
    far = float(distances.max()) * 1.05
    return max(far * 1e-4, float(distances.min()) * 0.5), far


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
    lighting: bool = True,
    anti_aliasing: bool = False,
    bounds: ArrayLike | None = None,
) -> NDArray[np.uint8]:
    """Render a mesh with its texture (``trimesh.visual.TextureVisuals``: UVs and a base-colour image) off-screen.

    Same camera, lights and framing as :func:`render_mesh`. ``lighting=False`` shows the texture unlit (a
    topographic texture already carries its shading, paper 004 §7); True adds the key and fill lights.

    Raises
    ------
    InvalidInputError
        The mesh has no UVs or no texture image, or a bad window size, z_scale or camera.
    MissingDependencyError
        No off-screen OpenGL context can be made.
    """
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh; got {type(mesh).__name__}")
    visual = mesh.visual
    uv = getattr(visual, "uv", None)
    material = getattr(visual, "material", None)
    image = None
    if material is not None:
        image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    if uv is None or image is None or len(uv) != len(mesh.vertices):
        raise InvalidInputError("mesh has no texture: expected TextureVisuals with one UV per vertex and an image "
                                "(see stepterrain.texture.drape)")
    if len(mesh.faces) == 0:
        raise InvalidInputError("mesh has no faces; nothing to render")
    try:
        width, height = (int(v) for v in window_size)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"window_size must be (width, height); got {window_size!r}") from exc
    if not (8 <= width <= 16384 and 8 <= height <= 16384):
        raise InvalidInputError(f"window_size must lie in [8, 16384] pixels; got {window_size!r}")
    z_scale = float(z_scale)
    if not math.isfinite(z_scale) or z_scale <= 0:
        raise InvalidInputError(f"z_scale must be a positive finite number; got {z_scale}")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    finite = np.isfinite(vertices).all(axis=1)
    if bounds is None:
        lo, hi = vertices[finite].min(axis=0), vertices[finite].max(axis=0)
    else:
        box = np.asarray(bounds, dtype=np.float64)
        if box.shape != (2, 3) or not np.isfinite(box).all() or np.any(box[1] < box[0]):
            raise InvalidInputError(
                f"bounds must be [(xmin, ymin, zmin), (xmax, ymax, zmax)] with max >= min; got {bounds!r}")
        lo, hi = box[0], box[1]
    centre = (lo + hi) / 2.0
    local = vertices - centre
    local[:, 2] *= z_scale
    box = np.array([lo - centre, hi - centre])
    box[:, 2] *= z_scale

    pv = _import_pyvista()
    poly = pv.wrap(trimesh.Trimesh(local, mesh.faces, process=False))
    poly.active_texture_coordinates = np.ascontiguousarray(uv, dtype=np.float32)
    picture = np.asarray(image.convert("RGB") if hasattr(image, "convert") else image, dtype=np.uint8)
    texture = pv.Texture(np.ascontiguousarray(picture))  # row 0 = the top of the image (v = 1)
    plotter = pv.Plotter(off_screen=True, window_size=(width, height), lighting="none")
    try:
        if not plotter.render_window.SupportsOpenGL():
            raise MissingDependencyError(
                "off-screen rendering needs OpenGL, but VTK could not create a context; install Mesa "
                "(libegl1, libgl1-mesa-dri or libosmesa6) or run where a GPU driver is present"
            )
        if anti_aliasing:
            plotter.enable_anti_aliasing("msaa")
        else:
            plotter.disable_anti_aliasing()
        plotter.set_background(background)
        framed = _frame_points(local, finite) if bounds is None else _box_corners(box)
        position = _camera_position(camera, framed, width / height)
        look_from = np.subtract(position[0], position[1])
        fill = (math.atan2(look_from[0], look_from[1]), _FILL_ELEVATION)
        if lighting:
            for light in _lights(pv, box, fill):
                plotter.add_light(light)
        plotter.add_mesh(poly, texture=texture, smooth_shading=False, ambient=_AMBIENT if lighting else 1.0,
                         diffuse=_DIFFUSE if lighting else 0.0, specular=0.0, lighting=lighting)
        plotter.camera_position = position
        plotter.camera.view_angle = _VIEW_ANGLE
        seen = local[finite]
        union = np.array([np.minimum(box[0], seen.min(axis=0)), np.maximum(box[1], seen.max(axis=0))])
        plotter.camera.clipping_range = _clipping_range(plotter.camera_position, union)
        shot = plotter.screenshot(return_img=True)
    finally:
        with contextlib.suppress(Exception):
            plotter.close()
    if shot is None or shot.ndim != 3 or shot.shape[:2] != (height, width):
        raise MissingDependencyError("off-screen rendering produced no image; the OpenGL context is unusable")
    return np.ascontiguousarray(shot[:, :, :3], dtype=np.uint8)
