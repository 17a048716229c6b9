"""The one camera type of stepterrain: eye, target, up, vertical field of view, aspect or pixel viewport, near
and far planes. The globe (paper 003) uses its frustum planes for the clip metric, the texture level of
detail (paper 004) its pixel projection for the screen-space errors γ(N) and τ(N, M).

    >>> cam = Camera(eye=(0.0, -10.0, 5.0), target=(0.0, 0.0, 0.0), viewport=(640, 480))
    >>> cam.aspect
    1.3333333333333333
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InvalidInputError
from .terrain import as_number, finite_number, number_or_nan, real_numbers

__all__ = ["Camera"]

#: Viewport height in pixels when none is given.
_DEFAULT_HEIGHT = 800
_MAX_COORDINATE = 1e30  # eye, target and up: their products (norms, crosses) stay finite in float64
#: Width / height bounds: far beyond any image (a horizontal field of view is within 0.03 degrees of 180 at 1e4
#: for a 45-degree fov), and within them the side planes' normals stay finite: at 1e300 their norm overflowed to
#: inf, the normals came out zero and nothing was clipped at the sides; at 1e307 the default viewport overflowed.
ASPECT_RANGE = (1e-6, 1e6)
#: The largest elevation of a camera's (azimuth, elevation) pair or a billboard's view: π/2 as float32 rounds it,
#: 4e-8 above float64's π/2 (np.float32(np.pi / 2), np.radians(np.float32(90)) look straight down as np.pi / 2
#: does: they were refused).
QUARTER_TURN = float(np.float32(math.pi / 2))


@dataclass(frozen=True)
class Camera:
    """A pinhole camera shared by every capability: the eye point, the six clipping planes of its view frustum
    (paper 003 §7.2-§7.3) and the pixel projection that screen-space errors use (paper 004 §4).

    Parameters
    ----------
    eye, target : (3,) float
        Eye point and a point it looks at, metres (planet-centred for :class:`Globe`, the mesh's
        coordinates for :func:`adaptive_mesh`).
    up : (3,) float
        Up direction (need not be orthogonal to the view direction, must not be parallel to it).
    fov : float
        Vertical field of view in radians, in (0, π).
    aspect : float, optional
        Width / height of the image, in [1e-6, 1e6]; default: the viewport's, else 1.
    near, far : float
        Distances of the near and far clipping planes, 0 < near < far.
    viewport : (width, height) pixels, optional
        The image size for pixel measures (:meth:`project`, :attr:`focal_pixels`); default: 800 pixels high
        at ``aspect``. When both are given they must agree.

    Examples
    --------
    >>> cam = Camera(eye=(0.0, 0.0, 10.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    >>> planes = cam.planes()
    >>> bool(((planes[:, :3] @ [0.0, 0.0, 0.0] + planes[:, 3]) <= 0).all())   # the target is inside
    True
    """

    eye: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = math.radians(45.0)
    aspect: float | None = None  # type: ignore[assignment]  # resolved to a float in __post_init__
    near: float = 1.0
    far: float = 1.0e9
    viewport: tuple[int, int] | None = None  # type: ignore[assignment]  # resolved in __post_init__

    def __post_init__(self) -> None:
        for name in ("eye", "target", "up"):
            try:
                value = real_numbers(getattr(self, name), f"Camera {name}", "3 numbers")
            except InvalidInputError:
                value = np.full(0, np.nan)  # not numbers (text such as "0", bools): refused below
            if value.shape != (3,) or not np.isfinite(value).all() or np.abs(value).max() > _MAX_COORDINATE:
                raise InvalidInputError(f"Camera {name} must be 3 finite numbers within ±{_MAX_COORDINATE:g}; got "
                                        f"{getattr(self, name)!r}")
            object.__setattr__(self, name, tuple(float(v) for v in value))
        for name in ("fov", "near", "far"):  # finite numbers (not strings, None or bools) before any comparison
            object.__setattr__(self, name, finite_number(getattr(self, name), f"Camera {name}"))
        forward = np.subtract(self.target, self.eye)
        if not forward.any():
            raise InvalidInputError(f"Camera eye and target must differ; both are {self.eye}")
        # lengths below ~1e-154 square to 0 in float64: such a view direction or up vector cannot be normalised
        length = np.linalg.norm(forward)
        if length == 0.0:
            raise InvalidInputError(f"Camera eye and target lie too close together for a view direction in float64 "
                                    f"(|target - eye| below 1e-154); got eye {self.eye}, target {self.target}")
        up = np.asarray(self.up)
        if np.linalg.norm(up) == 0.0 and up.any():
            raise InvalidInputError(f"Camera up {self.up} is too short to normalise in float64 (length below 1e-154)")
        if np.linalg.norm(np.cross(forward / length, up)) < 1e-9 * max(np.linalg.norm(up), 1e-300):
            # the direction as plain numbers: tuple(forward) printed "(np.float64(0.0), np.float64(0.0), ...)"; the
            # axis least along it as the up suggested (a fixed (1, 0, 0) was the refused up of a view along x)
            across = tuple(np.eye(3, dtype=int)[np.argmin(np.abs(forward))].tolist())
            raise InvalidInputError(f"Camera up {self.up} must not be zero or parallel to the view direction "
                                    f"{tuple(forward.tolist())} (target - eye); give an up across it, e.g. "
                                    f"up={across}")
        if not (0.0 < self.fov < math.pi):
            raise InvalidInputError(f"Camera fov must lie in (0, π) radians; got {self.fov!r}")
        if self.aspect is not None:  # a number before the viewport is compared with it
            aspect = number_or_nan(self.aspect)
            if not (math.isfinite(aspect) and aspect > 0):
                raise InvalidInputError(f"Camera aspect must be a positive number; got {self.aspect!r}")
            lo, hi = ASPECT_RANGE
            if not lo <= aspect <= hi:
                raise InvalidInputError(f"Camera aspect (width / height) must lie in [{lo:g}, {hi:g}]; got {aspect:g}")
            object.__setattr__(self, "aspect", aspect)
        if self.viewport is not None:
            try:  # as_number: text ("640", or "64" read as 6 x 4) and bools are not pixels; a set has no order
                if isinstance(self.viewport, (set, frozenset, dict)):
                    raise ValueError("no order")
                if any(not as_number(v).is_integer() for v in self.viewport):
                    raise ValueError("not whole pixels")
                width, height = (int(v) for v in self.viewport)
            except (TypeError, ValueError, OverflowError):
                raise InvalidInputError(f"Camera viewport must be (width, height) pixels; got {self.viewport!r}") \
                    from None
            if width < 1 or height < 1:
                raise InvalidInputError(f"Camera viewport must be positive pixels; got {self.viewport!r}")
            if self.aspect is None:
                lo, hi = ASPECT_RANGE
                if not lo <= width / height <= hi:
                    raise InvalidInputError(f"Camera viewport must have an aspect (width / height) in [{lo:g}, "
                                            f"{hi:g}]; got {self.viewport!r}, {width / height:g}")
                object.__setattr__(self, "aspect", width / height)
            elif not (abs(self.aspect * height - width) <= 0.5 or (width == 1 and self.aspect * height < 1.0)):
                # agree to the pixel (replace() keeps both); an aspect under one pixel's width (below 1/1600 at
                # the default 800 rows) agrees with the 1-pixel width its default viewport rounds up to: replace()
                # refused the camera it had made (adaptive_mesh's, moved by the origin: aspect 1e-4)
                raise InvalidInputError(f"Camera aspect {self.aspect!r} disagrees with viewport {self.viewport!r}")
            object.__setattr__(self, "viewport", (width, height))
        elif self.aspect is None:
            object.__setattr__(self, "aspect", 1.0)
        if self.viewport is None:
            object.__setattr__(self, "viewport", (max(1, round(_DEFAULT_HEIGHT * self.aspect)), _DEFAULT_HEIGHT))
        if not (math.isfinite(self.near) and math.isfinite(self.far) and 0.0 < self.near < self.far):
            raise InvalidInputError(f"Camera needs 0 < near < far (finite); got near={self.near!r}, far={self.far!r}")
        tan = math.tan(self.fov / 2.0)  # the screen-space errors came out NaN (the root drawn, unrefined), or 0
        if tan == 0.0 or not math.isfinite(self.viewport[1] / 2.0 / tan):
            raise InvalidInputError(f"Camera fov must be wide enough for a finite focal length in pixels (viewport "
                                    f"height / 2 / tan(fov / 2)); got fov={self.fov!r} with viewport {self.viewport}")

    def frame(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Unit forward, right and up vectors of the camera."""
        forward, right, up = self._axes()
        return np.array(forward), np.array(right), np.array(up)

    def _axes(self) -> tuple[list[float], list[float], list[float]]:
        """:meth:`frame` in Python floats: numpy's per-call cost on 3-vectors was most of a 200k-triangle globe
        view's set-up (through :meth:`planes`)."""
        eye = [float(v) for v in self.eye]
        forward = _unit([float(t) - e for t, e in zip(self.target, eye, strict=True)])
        right = _unit(_cross(forward, [float(v) for v in self.up]))
        return forward, right, _cross(right, forward)

    def planes(self) -> NDArray[np.float64]:
        """(6, 4) float64: outward unit normal n and offset a of the left, right, bottom, top, near and far
        planes; x lies inside the frustum iff n · x + a <= 0 for all six."""
        eye = [float(v) for v in self.eye]
        forward, right, up = self._axes()
        tv = math.tan(self.fov / 2.0)
        th = tv * self.aspect
        normals = [[-r - th * f for r, f in zip(right, forward, strict=True)],
                   [r - th * f for r, f in zip(right, forward, strict=True)],
                   [-u - tv * f for u, f in zip(up, forward, strict=True)],
                   [u - tv * f for u, f in zip(up, forward, strict=True)]]
        rows = []
        for n in normals:
            n = _unit(n)
            rows.append([*n, -_dot(n, eye)])
        rows.append([-forward[0], -forward[1], -forward[2], _dot(forward, eye) + self.near])
        rows.append([*forward, -_dot(forward, eye) - self.far])
        return np.asarray(rows, dtype=np.float64)

    @cached_property
    def _frustum(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(:meth:`planes`, :meth:`frame` as rows), read-only, computed once per camera: the texture LOD's
        per-patch :meth:`visible_part` and ``texture_lod._in_view`` took them anew for every patch (a tenth of its
        set-up)."""
        planes, axes = self.planes(), np.stack(self.frame())
        planes.flags.writeable = axes.flags.writeable = False
        return planes, axes

    @property
    def focal_pixels(self) -> float:
        """Focal length in pixels: (viewport height / 2) / tan(fov / 2)."""
        return self.viewport[1] / 2.0 / math.tan(self.fov / 2.0)

    def project(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(pixel coordinates (N, 2), depth (N,)) of world points (N, 3), or of one point (3,)."""
        expected = "(N, 3) world points"
        given = real_numbers(points, "points", expected)  # text and bools were taken as numbers
        array = np.atleast_2d(given)
        if array.ndim != 2 or array.shape[1] != 3:
            raise InvalidInputError(f"points must be {expected}; got shape {given.shape}")
        forward, right, up = self.frame()
        rel = array - np.asarray(self.eye, dtype=np.float64)
        depth = rel @ forward
        f = self.focal_pixels
        with np.errstate(divide="ignore", invalid="ignore"):
            px = np.column_stack([f * (rel @ right) / depth + self.viewport[0] / 2,
                                  self.viewport[1] / 2 - f * (rel @ up) / depth])
        return px, depth

    def box_visible(self, box: NDArray[np.float64]) -> bool:
        """Whether the axis-aligned box [(min), (max)] may intersect the view frustum (conservative)."""
        return bool(self._boxes_visible(_box(box)[None])[0])

    @cached_property
    def _cull_planes(self) -> list[tuple[NDArray[np.float64], float]]:
        """:meth:`box_visible`'s six planes, (inward unit normal, offset): a box is out of view where its corner
        farthest along one plane's normal lies below the offset. Computed once per camera (they were computed anew for
        every box: a fifth of a texture LOD render)."""
        forward, right, up = self.frame()
        tan_y = math.tan(self.fov / 2.0)
        tan_x = tan_y * self.aspect
        planes = [(forward, self.near), (-forward, -self.far)]
        for axis, tan in ((right, tan_x), (up, tan_y)):
            # side planes through the eye: (forward * tan -/+ axis) . (p - eye) >= 0 inside
            for sign in (1.0, -1.0):
                normal = forward * tan - sign * axis
                planes.append((normal / np.linalg.norm(normal), 0.0))
        return planes

    def _boxes_visible(self, boxes: NDArray[np.float64]) -> NDArray[np.bool_]:
        """:meth:`box_visible` of (K, 2, 3) float64 boxes (checked) at once: (K,) bool, each as one box's test (the
        same dot product per box and plane)."""
        eye = np.asarray(self.eye, dtype=np.float64)
        lo, hi = boxes[:, 0], boxes[:, 1]
        visible = np.ones(len(boxes), dtype=bool)
        for normal, offset in self._cull_planes:
            corner = np.where(normal >= 0, hi, lo)  # the box corner farthest along the plane normal
            visible &= ~(np.matmul((corner - eye)[:, None, :], normal)[:, 0] < offset)
        return visible

    def nearest_point(self, box: NDArray[np.float64]) -> NDArray[np.float64]:
        """The point of the box nearest to the camera position (the position itself when inside)."""
        box = _box(box)
        return np.clip(np.asarray(self.eye, dtype=np.float64), box[0], box[1])

    def nearest_visible_point(self, box: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """The point of the box inside the view frustum nearest to the camera position (paper 004 §4's p for γ(N)
        and τ(N, M)), or None where the box and the frustum do not meet.

        Exact: the nearest point of the convex polytope box ∩ frustum (12 half-spaces) is the projection of the eye
        onto the intersection of at most three of their planes, so the nearest feasible one of those projections is
        it. The box's own nearest point (:meth:`nearest_point`) may lie outside the view: straight below an eye
        above the terrain, where a vertical segment lies along the eye's ray and projects to 0 pixels.
        """
        return self.visible_part(box, corners=False)[0]

    def visible_corners(self, box: NDArray[np.float64]) -> NDArray[np.float64]:
        """(k, 3) float64: the corners of the convex polytope box ∩ view frustum (12 half-spaces), each where three of
        their planes meet; (0, 3) where the box and the frustum do not meet. Every point of the box in view is a
        convex combination of them, so a convex function of the point (or of its image on the screen: the pinhole
        projection maps the polytope, in front of the eye, onto the convex polygon of its corners' images) is
        largest in view at one of them, and a linear one (the depth) smallest at one of them (paper 004 §4's
        screen-space errors bounded over all of B(N) in view, not at one point)."""
        return self.visible_part(box)[1]

    def visible_part(self, box: NDArray[np.float64], corners: bool = True) -> tuple[
            NDArray[np.float64] | None, NDArray[np.float64]]:
        """(:meth:`nearest_visible_point`, :meth:`visible_corners`) of the box, from one set of plane intersections
        (the corners are the feasible points where three planes meet, among the nearest point's candidates); with
        ``corners=False`` the corners come back empty and a box whose own nearest point is in view solves nothing."""
        box = _box(box)
        nearest, seen, points, feasible = self._visible_parts(box[None], corners)
        found = points[0][feasible[0]] if corners else np.empty((0, 3))
        return (nearest[0] if seen[0] else None), found

    @cached_property
    def _plane_solver(self) -> tuple[NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.intp]], list[
            tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.intp], NDArray[np.float64]]]]:
        """What :meth:`visible_part` solves that does not depend on the box, once per camera: the 12 planes' normals
        (the frustum's six, then the box's faces -x, -y, -z, x, y, z: the same for every box, only their offsets
        differ), the regular sets of three planes (their matrices and indices) and, for the eye's projections onto one
        or two planes, the regular sets' normals, Gram matrices, indices and normals · eye. Every box took the 220
        determinants and the Gram matrices anew (of the same matrices: the same values)."""
        planes = np.zeros((12, 4))
        planes[:6] = self._frustum[0]
        planes[6:, :3] = np.r_[-np.eye(3), np.eye(3)]
        normals = planes[:, :3]  # (a view with the strides of the one visible_part took per box)
        normals.flags.writeable = False
        n = normals[_PLANE_SETS[2]]  # (220, 3, 3)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # parallel planes: a singular matrix
            regular = np.abs(np.linalg.det(n)) > 1e-6  # the Gram matrix's determinant above 1e-12, as below
        eye = np.asarray(self.eye, dtype=np.float64)
        projections = []
        for combos in _PLANE_SETS[:2]:
            m = normals[combos]  # (m, k, 3)
            gram = m @ m.transpose(0, 2, 1)
            with np.errstate(divide="ignore", invalid="ignore"):  # parallel planes: a singular Gram matrix
                independent = np.abs(np.linalg.det(gram)) > 1e-12
            if independent.any():
                m = m[independent]
                projections.append((m, gram[independent], combos[independent], m @ eye))
        return normals, (n[regular], _PLANE_SETS[2][regular]), projections

    @cached_property
    def _shared_sets(self) -> tuple[NDArray[np.intp], NDArray[np.float64], list[tuple[int, NDArray[np.intp],
                                                                                        NDArray[np.float64]]],
                                    NDArray[np.intp]]:
        """The regular sets of three planes (:meth:`_plane_solver`) by what their right-hand sides hold, once per
        camera: those of three frustum planes (indices, and their solutions: the same for every box), those of two
        frustum planes and one box face, per face (its offset column, the indices, the frustum planes' side of their
        right-hand sides), and the others (two or three box faces: indices)."""
        _, (n3, sets3), _ = self._plane_solver
        offsets = self._frustum[0][:, 3]
        faces = (sets3 >= 6).sum(axis=1)  # sets3's rows ascend: a set's box faces come last
        free = np.flatnonzero(faces == 0)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            solved = np.linalg.solve(n3[free], -offsets[sets3[free]][..., None])[..., 0]
        single = []
        for column in range(6, 12):
            rows = np.flatnonzero((faces == 1) & (sets3[:, 2] == column))
            if len(rows):
                single.append((column, rows, -offsets[sets3[rows, :2]]))
        return free, solved, single, np.flatnonzero(faces > 1)

    def _corner_solves(self, offsets: NDArray[np.float64]) -> NDArray[np.float64]:
        """Where the regular sets of three planes meet, per box of (g, 12) plane ``offsets``: (g, R, 3), each what
        ``np.linalg.solve`` gives for its matrix and right-hand side (LAPACK's solve per matrix, a function of the
        two alone), solved once per distinct right-hand side (:meth:`_shared_sets`): a set of three frustum planes
        once per camera, a set with one box face once per distinct offset of that face (told apart by its bits, so
        0.0 and -0.0 stay apart). Every box solved all ~150 anew, over half of them the same as another box's."""
        _, (n3, sets3), _ = self._plane_solver
        if len(offsets) < _SHARED_SOLVES_FROM:  # a few boxes: sorting out the repeats costs more than they do
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                return np.linalg.solve(n3, -offsets[:, sets3][..., None])[..., 0]
        free, solved, single, rest = self._shared_sets
        out = np.empty((len(offsets), len(sets3), 3))
        out[:, free] = solved
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for column, rows, frustum in single:
                values = offsets[:, column]
                _, first, back = np.unique(values.view(np.int64), return_index=True, return_inverse=True)
                rhs = np.empty((len(first), len(rows), 3))
                rhs[:, :, :2] = frustum
                rhs[:, :, 2] = -values[first][:, None]
                out[:, rows] = np.linalg.solve(n3[rows], rhs[..., None])[..., 0][back.reshape(-1)]
            if len(rest):
                out[:, rest] = np.linalg.solve(n3[rest], -offsets[:, sets3[rest]][..., None])[..., 0]
        return out

    def _visible_parts(self, boxes: NDArray[np.float64], corners: bool = True) -> tuple[
            NDArray[np.float64], NDArray[np.bool_], NDArray[np.float64], NDArray[np.bool_]]:
        """:meth:`visible_part` of (K, 2, 3) float64 boxes (checked) at once, each box's numbers as its own call's
        (the same solves, products and sums per box): the nearest points in view (K, 3), whether there is one (K,),
        and the candidate corners (K, R, 3) with which are corners of box ∩ frustum (K, R) (none where ``corners``
        is False)."""
        normals, (n3, sets3), projections = self._plane_solver
        eye = np.asarray(self.eye, dtype=np.float64)
        count = len(boxes)
        # the box's faces as half-spaces n . x + a <= 0: -x + xmin <= 0, ..., x - xmax <= 0, ...
        offsets = np.empty((count, 12))
        offsets[:, :6] = self._frustum[0][:, 3]
        offsets[:, 6:9] = boxes[:, 0]
        offsets[:, 9:] = -boxes[:, 1]
        scale = np.maximum(max(1.0, float(np.abs(eye).max())), np.abs(boxes).max(axis=(1, 2)))
        tolerance = 1e-9 * scale
        nearest = np.clip(eye, boxes[:, 0], boxes[:, 1])  # the box's nearest point: the answer where it is in view
        with np.errstate(over="ignore", invalid="ignore"):
            inside = ((np.matmul(normals, nearest[:, :, None])[..., 0] + offsets) <= tolerance[:, None]).all(axis=1)
        seen = inside.copy()
        points = np.zeros((count, len(sets3), 3))
        feasible = np.zeros((count, len(sets3)), dtype=bool)
        # the corners: where three independent planes meet (the eye's projection onto their intersection, a point)
        for group in (np.flatnonzero(inside) if corners else np.empty(0, np.intp), np.flatnonzero(~inside)):
            if not len(group):
                continue
            candidates = [self._corner_solves(offsets[group])]
            if not inside[group[0]]:  # the nearest point: also the eye's projections onto one and two planes
                for n, gram, combos, n_eye in projections:
                    lam = np.linalg.solve(gram, (n_eye + offsets[group][:, combos])[..., None])[..., 0]  # (g, m, k)
                    k = n.shape[1]
                    moved = np.einsum("mk,mkd->md", lam.reshape(-1, k), np.broadcast_to(n, (len(group), *n.shape))
                                      .reshape(-1, k, 3))
                    candidates.append(eye - moved.reshape(len(group), -1, 3))
            found = np.concatenate(candidates, axis=1)
            ok = np.empty(found.shape[:2], dtype=bool)
            with np.errstate(over="ignore", invalid="ignore"):
                for at in range(0, len(group), _FEASIBLE_BOXES):  # boxes a slice at a time: the (g, R, 12) sums
                    part = slice(at, at + _FEASIBLE_BOXES)  # stayed in cache (each box's product is its own gemm)
                    ok[part] = ((found[part] @ normals.T + offsets[group[part]][:, None])
                                <= tolerance[group[part]][:, None, None]).all(axis=2)
            points[group] = found[:, :len(sets3)]
            feasible[group] = ok[:, :len(sets3)]
            if not inside[group[0]]:  # the feasible candidate nearest to the eye, the first of equals
                with np.errstate(over="ignore", invalid="ignore"):  # (far infeasible points: not compared)
                    distance = np.where(ok, ((found - eye) ** 2).sum(axis=2), np.inf)
                first = np.argmax(ok & (distance == distance.min(axis=1)[:, None]), axis=1)
                seen[group] = ok.any(axis=1)
                nearest[group] = np.where(seen[group][:, None], found[np.arange(len(group)), first], nearest[group])
        return nearest, seen, points, feasible

    def segment_pixels(self, a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
        """Screen length in pixels of the segment a-b (inf when it reaches behind the near plane)."""
        px, depth = self.project(np.stack([_point(a, "a"), _point(b, "b")]))
        if np.any(depth < self.near):
            return math.inf
        with np.errstate(over="ignore"):  # a magnification near float64's limit (fov 1e-300): inf pixels, refine
            return float(np.linalg.norm(px[0] - px[1]))


#: boxes per slice of :meth:`Camera._visible_parts`' feasibility test (their (R, 12) sums stay in cache)
_FEASIBLE_BOXES = 64
#: :meth:`Camera._corner_solves` solves each box's sets itself below this many boxes (the same numbers either way)
_SHARED_SOLVES_FROM = 16
# every set of one, two and three of the 12 planes (6 of the frustum, 6 of the box): the nearest point's active sets
_PLANE_SETS = [np.array(list(itertools.combinations(range(12), k)), dtype=np.intp) for k in (1, 2, 3)]

_BOX = "an axis-aligned box [(xmin, ymin, zmin), (xmax, ymax, zmax)] with max >= min"


def _box(box: Any) -> NDArray[np.float64]:
    """``box`` as a (2, 3) float64 array, min <= max (no NaN), else an InvalidInputError: unpacking, broadcasting
    and indexing errors escaped from the box tests (a list of text, one corner, None)."""
    array = box if isinstance(box, np.ndarray) and box.dtype == np.float64 else real_numbers(box, "box", _BOX)
    if array.shape != (2, 3) or not (array[0] <= array[1]).all():
        raise InvalidInputError(f"box must be {_BOX}; got {box!r:.200}")
    return array


def _point(value: Any, name: str) -> NDArray[np.float64]:
    """``value`` as a finite (3,) float64 world point, else an InvalidInputError naming ``name``: np.stack raised
    numpy's "all input arrays must have the same shape" for anything else."""
    array = value if isinstance(value, np.ndarray) and value.dtype == np.float64 else real_numbers(
        value, name, "a finite world point (x, y, z)")
    if array.shape != (3,) or not np.isfinite(array).all():
        raise InvalidInputError(f"{name} must be a finite world point (x, y, z); got {value!r:.200}")
    return array


def _dot(a: list[float], b: list[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: list[float], b: list[float]) -> list[float]:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _unit(a: list[float]) -> list[float]:
    length = math.sqrt(_dot(a, a))
    return [a[0] / length, a[1] / length, a[2] / length]
