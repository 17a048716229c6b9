"""What a pyvista/VTK or NumPy user would write instead of ``stepterrain.stepped`` (the benchmark contenders).

Every contender takes the same inputs as the Warp path, ``(heights (H, W) float32, spacing (dx, dy),
isovalues)``, and starts from the heights (building its own surface is part of its job, as it is part of
``stepterrain.stepped``'s):

- :func:`vtk_banded_contour` - ``vtkBandedPolyDataContourFilter`` over the elevation scalars with the
  thresholds as clip values: the bands only (not flattened, no walls). It does strictly less than a stepped
  model, which makes it the fastest VTK building block and a *lower bound* on a VTK user's time.
- :func:`vtk_clip_per_band` - the full stepped model the pyvista way: per band clip the surface twice by
  scalar (above the lower threshold, below the upper one), flatten the band to its isovalue; per threshold
  contour the surface and extrude the lines by the step height into walls; append everything. It is a
  triangle soup (bands and walls do not share vertices), unlike stepterrain's welded mesh.
- :func:`numpy_reference` - the independent vectorised NumPy reference of ``tests/reference.py``
  (welded output, the same topology as the Warp kernels).

The surface is a ``pyvista.ImageData`` with the heights as point scalars ``"elevation"``, warped by them
along +z, its surface extracted and triangulated. :func:`build_surface` is exposed so that its share of the
time can be reported on its own. :func:`triangle_count` counts any contender's output in triangles (a
polygon with n corners counts n - 2), so triangles per second compare like with like.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # pyvista/VTK load only with the VTK contenders: the NumPy reference runs without them
    import pyvista as pv
    import vtk

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from tests.reference import ReferenceResult, grid_tin, step_reference  # noqa: E402

SHARED_DATA = Path(os.environ.get("STEPTERRAIN_SHARED_DATA") or _ROOT.parent / "shared" / "data")
DEM_FILE = "big_tujunga_srtm_30m_utm11n.npz"
# the real DEMs benchmarked at their native size: name -> (file, spacing keys in the npz)
REAL_DEMS = {
    "big_tujunga": ("big_tujunga_srtm_30m_utm11n.npz", ("dx", "dy")),
    "front_range": ("front_range_srtmgl3_3arcsec.npz", ("dx_m", "dy_m")),
}

__all__ = [
    "REAL_DEMS",
    "grid_heights",
    "real_dem",
    "steps_isovalues",
    "thresholds_of",
    "build_surface",
    "vtk_banded_contour",
    "vtk_clip_per_band",
    "numpy_reference",
    "reference_polydata",
    "triangle_count",
    "CONTENDERS",
]


# ----------------------------------------------------------------------------- inputs


def _load(name: str) -> tuple[NDArray[np.float32], dict]:
    path = SHARED_DATA / name
    if not path.exists():
        raise FileNotFoundError(f"benchmark DEM {path} not found (expected ../shared/data beside the repository)")
    with np.load(path) as data:
        return np.asarray(data["elevation"], dtype=np.float32), {k: data[k] for k in data.files if k != "elevation"}


def grid_heights(nodes: int) -> tuple[NDArray[np.float32], tuple[float, float]]:
    """A real DEM (Big Tujunga, SRTM 30 m) cropped or mirror-tiled to ``nodes`` x ``nodes``, and its spacing.

    Sizes up to the DEM's shorter side are a centred crop; larger ones tile the DEM with mirrored copies
    (continuous across the seams, so the contour density stays that of real terrain).
    """
    heights, meta = _load(DEM_FILE)
    rows, cols = heights.shape
    if nodes <= min(rows, cols):
        r0, c0 = (rows - nodes) // 2, (cols - nodes) // 2
        out = heights[r0 : r0 + nodes, c0 : c0 + nodes]
    else:
        mirrored = np.block([[heights, heights[:, ::-1]], [heights[::-1], heights[::-1, ::-1]]])
        reps = (-(-nodes // mirrored.shape[0]), -(-nodes // mirrored.shape[1]))
        out = np.tile(mirrored, reps)[:nodes, :nodes]
    return np.ascontiguousarray(out, dtype=np.float32), (float(meta["dx"]), float(meta["dy"]))


def real_dem(name: str) -> tuple[NDArray[np.float32], tuple[float, float]]:
    """A real DEM of ``shared/data`` at its native size, with its spacing in metres (see REAL_DEMS)."""
    file, (kx, ky) = REAL_DEMS[name]
    heights, meta = _load(file)
    return np.ascontiguousarray(heights), (abs(float(meta[kx])), abs(float(meta[ky])))


def steps_isovalues(heights: NDArray[np.float32], steps: int) -> NDArray[np.float32]:
    """Isovalues for ``steps`` equal intervals over the height range (stepterrain's own rule, float32)."""
    from stepterrain.stepped import isovalues

    lo, hi = float(np.nanmin(heights)), float(np.nanmax(heights))
    return isovalues((lo, hi), interval=(hi - lo) / steps)


# ----------------------------------------------------------------------------- contenders


def thresholds_of(isovalues: NDArray[np.float32]) -> NDArray[np.float64]:
    """The band boundaries t_i = (α_i + α_i+1) / 2 between consecutive isovalues."""
    v = np.asarray(isovalues, dtype=np.float64)
    return (v[:-1] + v[1:]) * 0.5


def build_surface(heights: NDArray[np.float32], spacing: tuple[float, float]) -> pv.PolyData:
    """The terrain as a triangulated pyvista surface with the heights as point scalars ``"elevation"``.

    Node (i, j) lies at (j * dx, i * dy, heights[i, j]), as in ``stepterrain.heightfield_mesh``.
    """
    import pyvista as pv

    rows, cols = heights.shape
    grid = pv.ImageData(dimensions=(cols, rows, 1), spacing=(float(spacing[0]), float(spacing[1]), 1.0))
    grid.point_data["elevation"] = np.ascontiguousarray(heights, dtype=np.float32).reshape(-1)
    warped = grid.warp_by_scalar("elevation", normal=(0.0, 0.0, 1.0))
    surface = warped.extract_surface(algorithm="dataset_surface") if _takes_algorithm() else warped.extract_surface()
    return surface.triangulate()


def _takes_algorithm() -> bool:
    import inspect

    import pyvista as pv

    return "algorithm" in inspect.signature(pv.DataSet.extract_surface).parameters


def vtk_banded_contour(
    heights: NDArray[np.float32],
    spacing: tuple[float, float],
    isovalues: NDArray[np.float32],
    surface: pv.PolyData | None = None,
) -> pv.PolyData:
    """Flat bands only: ``vtkBandedPolyDataContourFilter`` (ScalarModeToValue, no contour edges)."""
    import pyvista as pv
    import vtk

    surface = build_surface(heights, spacing) if surface is None else surface
    surface.set_active_scalars("elevation")
    bands = vtk.vtkBandedPolyDataContourFilter()
    bands.SetInputData(surface)
    thresholds = thresholds_of(isovalues)
    bands.SetNumberOfContours(len(thresholds))
    for i, t in enumerate(thresholds):
        bands.SetValue(i, float(t))
    bands.SetScalarModeToValue()
    bands.GenerateContourEdgesOff()
    bands.Update()
    return pv.wrap(bands.GetOutput())


def vtk_clip_per_band(
    heights: NDArray[np.float32],
    spacing: tuple[float, float],
    isovalues: NDArray[np.float32],
    surface: pv.PolyData | None = None,
) -> pv.PolyData:
    """The full stepped model with pyvista filters: clip band by band, flatten, contour and extrude walls."""
    import pyvista as pv

    surface = build_surface(heights, spacing) if surface is None else surface
    values = np.asarray(isovalues, dtype=np.float64)
    thresholds = thresholds_of(isovalues)
    pieces: list[pv.PolyData] = []
    for i, alpha in enumerate(values):
        band = surface
        if i > 0:  # keep what lies above the lower threshold
            band = band.clip_scalar(scalars="elevation", invert=False, value=float(thresholds[i - 1]))
        if i < len(thresholds):  # keep what lies below the upper threshold
            band = band.clip_scalar(scalars="elevation", invert=True, value=float(thresholds[i]))
        if band.n_cells == 0:
            continue
        band = band.copy() if band is surface else band
        band.points[:, 2] = alpha
        pieces.append(band)
    for i, t in enumerate(thresholds):
        lines = surface.contour([float(t)], scalars="elevation")
        if lines.n_cells == 0:
            continue
        lines.points[:, 2] = values[i]
        pieces.append(lines.extrude((0.0, 0.0, float(values[i + 1] - values[i])), capping=False))
    if not pieces:
        return pv.PolyData()
    return pv.merge(pieces, merge_points=False) if len(pieces) > 1 else pieces[0]


def numpy_reference(
    heights: NDArray[np.float32],
    spacing: tuple[float, float],
    isovalues: NDArray[np.float32],
) -> ReferenceResult:
    """The independent NumPy reference (welded, same topology as the kernels), from the heights.

    Returns the reference's raw arrays (points at γ = 0, step heights at γ = 1, faces); wrapping them in a
    PolyData (:func:`reference_polydata`) is left out of the timing, which only flatters the reference.
    """
    points, faces = grid_tin(np.ascontiguousarray(heights, dtype=np.float32), spacing)
    return step_reference(points, faces, np.asarray(isovalues, dtype=np.float32))


def reference_polydata(result: ReferenceResult, gamma: float = 1.0) -> pv.PolyData:
    """The reference result as a PolyData at blend ``gamma`` (z = (1 - γ) z + γ α)."""
    import pyvista as pv

    points = result.points.copy()
    points[:, 2] = (1.0 - gamma) * points[:, 2] + gamma * result.step_heights
    return pv.PolyData.from_regular_faces(points, result.faces)


def triangle_count(result: object) -> int:
    """Triangles in a contender's output: a polygon or quad strip with n corners counts n - 2."""
    if isinstance(result, ReferenceResult):
        return len(result.faces)
    faces = getattr(result, "faces", None)
    if _is_polydata(result):
        sizes = _cell_sizes(result.GetPolys()) + _cell_sizes(result.GetStrips())
        return int(sizes)
    if faces is not None:
        return len(faces)
    raise TypeError(f"cannot count the triangles of {type(result).__name__}")


def _is_polydata(result: object) -> bool:
    """Whether ``result`` is a pyvista PolyData, without importing pyvista when it was never loaded."""
    pv = sys.modules.get("pyvista")
    return pv is not None and isinstance(result, pv.PolyData)


def _cell_sizes(cells: vtk.vtkCellArray) -> int:
    import pyvista as pv

    if cells is None or cells.GetNumberOfCells() == 0:
        return 0
    offsets = pv.convert_array(cells.GetOffsetsArray())
    return int(np.sum(np.diff(offsets) - 2))


def vertex_count(result: object) -> int:
    """Vertices in a contender's output."""
    if isinstance(result, ReferenceResult):
        return len(result.points)
    if _is_polydata(result):
        return int(result.n_points)
    return len(result.vertices)  # trimesh


CONTENDERS = {
    "vtk_banded": vtk_banded_contour,
    "vtk_clip_per_band": vtk_clip_per_band,
    "numpy_ref": numpy_reference,
}
