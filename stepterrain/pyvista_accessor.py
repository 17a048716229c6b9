"""A pyvista dataset accessor: ``grid.stepterrain.stepped(interval=50)`` on ImageData, RectilinearGrid and
StructuredGrid.

Paper 000 (Glander, Trapp & Döllner, *3D Isocontours*, Eurographics 2010, §3) for pyvista users: a grid that
carries elevation (a point-data array, or the z of a StructuredGrid's points) steps into terraces and walls
without leaving pyvista. Importing this module registers the accessor; pyvista does that itself on the first
``dataset.stepterrain`` through the ``pyvista.accessors`` entry point in ``pyproject.toml``, so neither
``import stepterrain`` nor an explicit import of this module is needed.

    grid = pv.ImageData(dimensions=(W, H, 1), spacing=(30, 30, 1))   # rows run south to north in an ImageData:
    grid["elevation"] = heights[::-1].ravel()                        # a north-up DEM's rows go in reversed
    steps = grid.stepterrain.stepped(interval=50)      # pv.PolyData, cell data "level" and "wall"
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from .errors import InvalidInputError, MissingDependencyError, caller_stacklevel, counted
from .mesh import check_face_indices
from .terrain import Terrain, finite_or_nan, float32_heights, grid_faces

__all__ = ["StepTerrainAccessor", "to_polydata", "from_polydata", "ELEVATION_NAMES", "RGBA_ALIAS"]

#: Point-data names of elevation, in order of preference when ``elevation`` is not given (an array under one of them
#: wins over active scalars of another name; among several, the active scalars if they are one, else the first).
ELEVATION_NAMES = ("elevation", "Elevation", "height", "heights", "z", "Z")

#: The point-data name under which the stepped colours ("RGBA") are also the active scalars: pyvista plots an
#: array ending in "_rgba" as colours, so ``steps.plot()`` shows them (``"RGBA"`` needs ``rgb=True``).
RGBA_ALIAS = "colors_rgba"

#: The choice of a StructuredGrid's points' z as its elevation (no point-data array is stepped).
_POINTS_Z = object()

#: What to do with elevation found in cell data: the terraces are cut at grid nodes.
_CELL_DATA_HINT = " (stepping needs one height per point: convert with grid.cell_data_to_point_data())"

try:
    import pyvista as pv
except ImportError as exc:  # pragma: no cover - pyvista is a core dependency
    raise MissingDependencyError("the pyvista accessor needs pyvista: pip install pyvista") from exc


class StepTerrainAccessor:
    """``dataset.stepterrain``: stepped terrain for a pyvista ``ImageData``, ``RectilinearGrid`` (pyvista-xarray's
    DEM: evenly spaced x and y, ascending or descending, step as a grid; others as a TIN on its nodes) or
    ``StructuredGrid`` with elevation.

    The grid must be one node thick in z (dimensions (W, H, 1)); an ImageData's direction_matrix may flip x and/or
    y (``np.diag([1, -1, 1])``: a north-up raster's rows as they are), not rotate. Elevation is the point-data
    array named by ``elevation``, else an array under one of :data:`ELEVATION_NAMES` (the active scalars if they
    are one, else the first in that order: pyvista makes the first array added the active scalars, so
    ``grid["gamma"] = ...; grid["elevation"] = ...`` steps the elevation), else the active scalars (the common
    ``grid["data"] = heights``). A StructuredGrid whose points' z are not all equal (a surface of its own) and with
    no array under :data:`ELEVATION_NAMES` steps its points' z, and says so in a warning when its active scalars
    (``grid["slope"] = ...``) were passed over (``elevation="slope"`` steps them); a flat one (all z equal) steps
    its active scalars, as an ImageData does; one without point data steps its z. Elevation found only in cell
    data (one value per cell, under one of :data:`ELEVATION_NAMES`) is refused, naming
    ``grid.cell_data_to_point_data()``: steps are cut at nodes.
    """

    def __init__(self, dataset: Any) -> None:
        self._dataset = dataset

    # ------------------------------------------------------------------------------------------ inputs
    def elevation(self, name: str | None = None) -> NDArray[np.float32]:
        """The (H, W) elevation of the grid (row = y index, column = x index), float32, NaN for nodata."""
        ds = self._dataset
        nx, ny, nz = (int(d) for d in ds.dimensions)
        if nz != 1 or nx < 2 or ny < 2:
            raise InvalidInputError(
                f"the grid must be a (W, H, 1) surface with W, H >= 2 to step; got dimensions {ds.dimensions}"
            )
        values = self._elevation_values(name)
        # float64 values beyond float32 are named, not cast to inf (an 'infinite value' error, or TIN nodata)
        heights = float32_heights(values.reshape(ny, nx), "elevation")
        # NaN is nodata on both kinds of grid; an infinity is an error on both (a StructuredGrid's TIN made it a hole)
        finite_or_nan(heights, "elevation")
        return heights

    def _elevation_values(self, name: str | None) -> NDArray[Any]:
        ds = self._dataset
        if name is not None:
            if not isinstance(name, str):  # VTK raised a TypeError
                raise InvalidInputError(f"elevation must name a point-data array (a str); got {name!r}")
            if name not in ds.point_data:
                raise InvalidInputError(
                    f"elevation must name a point-data array; got {name!r}, available: {list(ds.point_data.keys())}"
                    + _CELL_DATA_HINT * (name in ds.cell_data)
                )
            chosen = name
        else:
            chosen = self._default_elevation_name()
            if chosen is _POINTS_Z:
                return np.asarray(ds.points[:, 2], dtype=np.float64)
        if chosen is None:
            # elevation in cell data (one value per cell, not per node): a StructuredGrid fell back to its points'
            # z without a word, a flat grid (z = 0) stepping into one flat terrace whatever the cell data held
            in_cells = next((n for n in ELEVATION_NAMES if n in ds.cell_data), None)
            if isinstance(ds, pv.StructuredGrid) and in_cells is None:
                return np.asarray(ds.points[:, 2], dtype=np.float64)
            raise InvalidInputError(
                "the grid has no elevation: set a point-data array (e.g. grid['elevation'] = heights.ravel()) "
                f"or pass elevation=NAME; point data: {list(ds.point_data.keys())}"
                + (f"; cell data {in_cells!r} holds one value per cell{_CELL_DATA_HINT}" if in_cells else "")
            )
        values = np.asarray(ds.point_data[chosen])
        if values.ndim != 1 or values.dtype.kind not in "iuf":  # bools are no heights, as for stepped()
            raise InvalidInputError(
                f"elevation array {chosen!r} must hold one real number per point; got shape {values.shape}, "
                f"dtype {values.dtype}"
            )
        return values

    def _default_elevation_name(self) -> str | object | None:
        """The point-data array stepped without ``elevation=`` (see the class docstring), ``_POINTS_Z`` for a
        StructuredGrid's points' z, None for none. pyvista makes the first array added the active scalars, so the
        active scalars alone decided: ``grid["gamma"] = ...; grid["elevation"] = ...`` stepped gamma, and a
        StructuredGrid whose points' z are its heights stepped any array added to it (``grid["slope"] = ...``: nearly
        flat terraces), both without a word."""
        ds = self._dataset
        active = ds.point_data.active_scalars_name
        if active in ELEVATION_NAMES:  # the choice among several elevation-named arrays
            return active
        named = next((n for n in ELEVATION_NAMES if n in ds.point_data), None)
        if named is not None or active is None:
            return named
        if isinstance(ds, pv.StructuredGrid):
            z = np.asarray(ds.points[:, 2], dtype=np.float64)
            z = z[np.isfinite(z)]
            if z.size and z.min() != z.max():  # a real surface: its z are the heights, not some other array's values
                warnings.warn(
                    f"the StructuredGrid's points' z are stepped as its elevation, not its active scalars {active!r} "
                    f"(no point-data array under {', '.join(map(repr, ELEVATION_NAMES))}); pass elevation={active!r} "
                    f"to step that array, or set grid['elevation'] = grid.points[:, 2] to step the z without this "
                    "warning",
                    stacklevel=caller_stacklevel(),
                )
                return _POINTS_Z
        return active

    def terrain(self, elevation: str | None = None) -> Terrain | trimesh.Trimesh:
        """The grid as what :func:`~stepterrain.stepped` takes: a grid Terrain (an ImageData, an evenly spaced
        RectilinearGrid) or a TIN mesh (a StructuredGrid, an unevenly spaced RectilinearGrid)."""
        ds = self._dataset
        heights = self.elevation(elevation)
        if isinstance(ds, pv.ImageData):
            direction = np.asarray(ds.direction_matrix, dtype=np.float64)
            signs = np.diag(direction)
            # an axis flipped (diag(1, -1, 1): rows north to south, as a north-up raster) is a negative spacing, as
            # load_dem's dy < 0; it was refused as "rotated" (a rotation, or z flipped, still is)
            if not (np.array_equal(direction, np.diag(signs)) and np.all(np.abs(signs) == 1) and signs[2] == 1):
                raise InvalidInputError(
                    "a rotated ImageData cannot be stepped: its direction_matrix must be the identity or flip x and/or "
                    f"y (diag(+-1, +-1, 1)); got {direction.tolist()}"
                )
            dx, dy, dz = (float(s) * float(f) for s, f in zip(ds.spacing, signs, strict=True))
            # node (i, j) lies at origin + (extent start + (i, j)) x spacing: a grid cut out of a larger one (a VOI,
            # a .vti piece) or given an offset starts past 0, and its origin alone put the terraces there
            i0, _, j0, _, k0, _ = (int(e) for e in ds.extent)
            ox, oy, oz = (float(o) + k * d for o, k, d in zip(ds.origin, (i0, j0, k0), (dx, dy, dz), strict=True))
            if not np.isfinite([ox, oy, oz]).all():  # a NaN z was reported as "no finite height", inf as heights'
                raise InvalidInputError(f"the grid's origin (and its extent start times spacing) must be finite; got "
                                        f"origin {tuple(float(o) for o in ds.origin)}, node (0, 0, 0) at "
                                        f"({ox:g}, {oy:g}, {oz:g})")  # fmt: skip
            if oz != 0.0:  # added in float64: a sum beyond float32 is named, not inf
                heights = float32_heights(heights.astype(np.float64) + oz, "elevation + the grid's origin z")
            return Terrain.from_heights(heights, spacing=(dx, dy), origin=(ox, oy), source="pyvista.ImageData")
        if isinstance(ds, pv.RectilinearGrid):  # what pyvista-xarray makes of a DEM: x and y coordinate arrays
            xs, ys, zs = (np.asarray(c, dtype=np.float64) for c in (ds.x, ds.y, ds.z))
            if not (np.isfinite(xs).all() and np.isfinite(ys).all() and np.isfinite(zs).all()):
                raise InvalidInputError("the grid's x, y and z coordinates must be finite")
            if zs[0] != 0.0:  # the plane's z, as an ImageData's origin z
                heights = float32_heights(heights.astype(np.float64) + zs[0], "elevation + the grid's z")
            dx, dy = _uniform_step(xs), _uniform_step(ys)
            if dx is not None and dy is not None:  # evenly spaced (y often north to south, dy < 0): a grid Terrain
                return Terrain.from_heights(heights, spacing=(dx, dy), origin=(xs[0], ys[0]),
                                            source="pyvista.RectilinearGrid")  # fmt: skip
        if isinstance(ds, (pv.StructuredGrid, pv.RectilinearGrid)):  # unevenly spaced: a TIN on the grid's nodes
            ny, nx = heights.shape
            points = np.asarray(ds.points, dtype=np.float64).copy()
            points[:, 2] = heights.reshape(-1)
            # Terrain.from_mesh flips a clockwise grid and refuses one that folds over in projection
            mesh = trimesh.Trimesh(points, grid_faces(ny, nx), process=False)
            return mesh
        raise InvalidInputError(  # pragma: no cover - the accessor is registered on these three classes only
            f"stepterrain steps ImageData, RectilinearGrid and StructuredGrid; got {type(ds).__name__}"
        )

    # ------------------------------------------------------------------------------------------ stepping
    def stepped(
        self,
        interval: float | None = None,
        *,
        levels: ArrayLike | None = None,
        base: float = 0.0,
        gamma: Any = 1.0,
        colors: str | ArrayLike | None = None,
        solid: bool = False,
        floor: float | None = None,
        elevation: str | None = None,
        memory_budget: int | None = None,
        device: wp.DeviceLike = None,
    ) -> Any:
        """Stepped terrain of the grid as ``pyvista.PolyData`` (see :func:`stepterrain.stepped`; ``memory_budget``
        as there: bytes the output may take, else an OutputTooLargeError naming its size).

        A per-node ``gamma`` array may be (H, W) or hold one value per point, (N,), as pyvista's point data does
        (``gamma=grid["gamma"]``), on every grid: whether the grid steps as a grid Terrain (an ImageData, an evenly
        spaced RectilinearGrid) or as a TIN (a StructuredGrid, an unevenly spaced RectilinearGrid), point k is node
        (k // W, k % W).

        Returns
        -------
        pyvista.PolyData
            As :func:`to_polydata` makes it: triangles; cell data ``level`` (int32) and ``wall`` (bool: uint8 in
            VTK, read as bool, as pyvista keeps bools); point data ``RGBA`` (uint8) when ``colors`` is given,
            sharing its buffer with the active scalars ``colors_rgba`` (a name pyvista plots as colours:
            ``steps.plot()`` shows them);
            ``field_data["isovalues"]``; the mesh metadata (source, CRS, γ, isovalues, floor) in ``user_dict``.
            :func:`~stepterrain.export.save_mesh`, :func:`~stepterrain.render.render_mesh` and
            :func:`~stepterrain.texture.drape` take it as it is (see :func:`from_polydata`).

        Examples
        --------
        >>> import numpy as np, pyvista as pv
        >>> import stepterrain.pyvista_accessor
        >>> grid = pv.ImageData(dimensions=(4, 3, 1))
        >>> grid["elevation"] = np.arange(12.0)
        >>> steps = grid.stepterrain.stepped(interval=2.0)
        >>> bool(np.allclose(steps.points[:, 2] % 2.0, 0.0)), int(steps.cell_data["wall"].sum()) > 0
        (True, True)
        """
        from .mesh import release
        from .stepped import stepped

        if interval is None and levels is None:
            raise InvalidInputError("give interval (uniform isovalues) or levels (explicit isovalues)")
        terrain = self.terrain(elevation)
        mesh = stepped(terrain, interval=interval, levels=levels, base=base, gamma=self._node_gamma(gamma, terrain),
                       colors=colors, solid=solid, floor=floor, memory_budget=memory_budget,
                       device=device)  # fmt: skip
        try:
            return _to_polydata(mesh, share=True)  # the mesh is this call's own: its buffers need no copy
        finally:
            # left to the cyclic collector, the Trimesh kept the shared buffers from the output pool after the
            # PolyData was gone: a slider re-stepping the sample DEM took fresh memory (220 MB) every call
            release(mesh)

    def _node_gamma(self, gamma: Any, terrain: Terrain | trimesh.Trimesh) -> Any:
        """A per-node ``gamma`` laid out as the terrain :meth:`terrain` made takes it: (H, W) for a grid Terrain, (N,)
        for a TIN on the grid's points (in point order, row-major as the heights). A γ array had to match the kind of
        terrain the grid happened to become: pyvista's (N,) point data was refused on an ImageData, an (H, W) array
        on a StructuredGrid, and a RectilinearGrid wanted one or the other by whether its coordinates were even. Any
        other γ (a scalar, a callable, a Lens) is passed on as it is, for stepped's checks; an array of another shape is
        refused naming both shapes the accessor takes.
        """
        from .stepped import Lens

        if callable(gamma) or isinstance(gamma, Lens):
            return gamma
        try:
            shape = np.shape(gamma)
        except Exception:  # noqa: BLE001 - a ragged sequence, an unreadable object: stepped() names it
            return gamma
        nx, ny = (int(d) for d in self._dataset.dimensions[:2])
        if isinstance(terrain, Terrain) and shape == (ny * nx,):
            return np.reshape(gamma, (ny, nx))
        if not isinstance(terrain, Terrain) and shape == (ny, nx):
            return np.reshape(gamma, -1)
        if len(shape) and shape not in ((ny, nx), (ny * nx,)):
            # stepped() named the one shape of the terrain the grid became, (H, W) or (N,), as the only one
            raise InvalidInputError(f"gamma must be one γ per node, shape ({ny}, {nx}) or ({ny * nx},) (point data), "
                                    f"or a scalar, a callable or a Lens; got shape {shape}")
        return gamma


def to_polydata(mesh: trimesh.Trimesh) -> Any:
    """A stepped ``trimesh.Trimesh`` as ``pyvista.PolyData``: faces, vertex and face colours and attributes, UVs,
    metadata.

    ``pv.wrap`` of a Trimesh drops its vertex colours (pyvista carries vertex attributes only); this keeps them as
    point data ``RGBA`` (uint8), also the active scalars ``colors_rgba`` (plotted as colours); colours by face go to
    cell data so. Face attributes become cell data and vertex attributes point data (bools as pyvista keeps them,
    uint8 in VTK read back as bool, half floats as float32, long doubles as float64, (N, a, b) as (N, a * b); numbers
    and ASCII strings, anything else left out with a warning naming it, as are complex numbers of several components
    and attributes not named by a str or named ""), a textured mesh's UVs (one per vertex) the active texture
    coordinates (named "Texture Coordinates", or "Texture Coordinates (uv)" beside an attribute of that name; its
    image is not data of a PolyData: plot with ``texture=np.asarray(image)``, the image being
    ``mesh.visual.material.baseColorTexture``, or ``.image`` for a globe's ``drape_texture``), ``isovalues`` a
    float64 ``field_data`` array, and every metadata item that is JSON (values as
    :func:`~stepterrain.export.save_mesh` writes them to glTF extras) goes to ``user_dict``, as ``pv.wrap`` keeps
    them; a numeric array too long for that (a globe's ``node_entry``, a close-up layer's ``source_faces``) is a
    ``field_data`` array, as ``pv.wrap`` keeps it; any other item is left out with a warning naming it.

    :func:`from_polydata` is the way back: it gives the vertices, faces, colours, attributes and metadata back,
    dtypes kept (with the conversions above; bytes as str, metadata as JSON values), except that (N, 1) attributes
    come back (N,) (VTK's one-component arrays) and an uncoloured mesh's attribute under a colour name (``RGBA``,
    ``colors_rgba``, ``RGB``, holding colour values) comes back as its colours (what a mesh from ``pv.to_trimesh``
    of a PolyData holds).

    The colours' names are theirs: a coloured mesh's attribute under ``RGBA`` or ``colors_rgba`` in the data its
    colours go to (or ``colors_rgba`` by vertex beside colours by face, which :func:`from_polydata` would read
    first) is left out with a warning naming it (rename it to keep it), unless it holds those very colours. The
    colours win, not the attribute: they are what the PolyData plots and what every way back (``from_polydata``,
    ``save_mesh`` and ``render_mesh`` of the PolyData) reads as its colours; refusing the mesh would stop the
    common ``pv.to_trimesh`` round trip, whose attributes hold the colours as they were before a recolouring.

    Vertices are passed on as they are, NaN or infinite ones too, as :func:`from_polydata` takes them back (both
    ways agree: a PolyData and its Trimesh render and save alike).

    The PolyData's points and data arrays are its own copies (as ``pv.wrap`` makes them): they were the mesh's own
    buffers, so exaggerating the PolyData's heights (``poly.points[:, 2] *= 3``) or setting its colours changed the
    Trimesh too, and what was saved from it afterwards. Only VTK's connectivity is ``mesh.faces``' buffer (VTK does
    not change it in place; a copy of it cost as much again as the conversion).

    Raises
    ------
    InvalidInputError
        ``mesh`` is not a ``trimesh.Trimesh`` (a Scene, a PointCloud, a PolyData already, None): trimesh's or
        Python's AttributeError ("'Scene' object has no attribute 'faces'") came out of it, naming no argument;
        or its faces index outside its vertices (a ``process=False`` mesh keeps them; VTK crashed on them).
    """
    if not isinstance(mesh, trimesh.Trimesh):
        hint = (" (trimesh.load gives one for a glTF/GLB: read the file with stepterrain.export.read_mesh(path), one "
                "mesh, z up)" if isinstance(mesh, trimesh.Scene) else
                " (it is one already)" if isinstance(mesh, pv.PolyData) else "")
        raise InvalidInputError(f"mesh must be a trimesh.Trimesh; got {type(mesh).__module__}.{type(mesh).__name__}"
                                f"{hint}")
    return _to_polydata(mesh, share=False)


def _to_polydata(mesh: trimesh.Trimesh, share: bool) -> Any:
    """:func:`to_polydata`; ``share``: hand the mesh's own buffers to VTK, no copy (for a mesh nothing else holds, as
    :meth:`StepTerrainAccessor.stepped`'s)."""
    from .export import json_metadata

    own = np.asarray if share else np.array  # np.array copies
    faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    if not share:  # (a stepped mesh's faces index its vertices)
        # VTK took indices past the points (or -1) as they were: the PolyData's compute_normals(), clean() and
        # decimate() then crashed Python with a segmentation fault
        check_face_indices(faces, len(mesh.vertices), "mesh faces")
    # VTK's offsets and connectivity on the faces as they are: a padded [3, a, b, c] copy took 2.5 s and 550 MB
    # more for 13 M faces (a 2600² grid stepped), almost all of grid.stepterrain.stepped's time past the kernels
    poly = pv.PolyData.from_regular_faces(own(mesh.vertices, dtype=np.float64), faces, deep=False)
    # vertex attributes (a close-up layer's mask_factor, a PLY's properties) and a draped mesh's UVs were dropped,
    # where pv.wrap keeps them: pl.add_mesh(poly, texture=...) found no texture coordinates. Both kinds follow one
    # rule: numbers and strings are kept (a string vertex attribute was dropped without a word while a face one was
    # kept); what VTK holds no array of (objects, which VTK turned into their str, None into 'None'; datetimes,
    # whose TypeError came out of to_polydata) is left out with a warning, as metadata is
    left_out, shadowed, unnamed = [], [], []
    coloured = mesh.visual.kind if mesh.visual.kind in ("vertex", "face") else None
    colours = None
    if coloured is not None:
        colours = np.asarray(mesh.visual.vertex_colors if coloured == "vertex" else mesh.visual.face_colors)
    for kind, attributes, count, data in (("face", mesh.face_attributes, len(faces), poly.cell_data),
                                          ("vertex", mesh.vertex_attributes, len(mesh.vertices), poly.point_data)):
        for name, values in attributes.items():
            array = np.asarray(values)
            if array.shape[:1] != (count,):
                continue
            # not a str: pyvista's TypeError "Only strings are valid keys" came out of to_polydata; "": VTK's unnamed
            # array, which pyvista calls "Unnamed_0", came back from from_polydata under that name, without a word
            if not isinstance(name, str) or not name:
                unnamed.append(f"{kind} attribute {name!r}")
                continue
            if colours is not None and _shadows_colours(name, kind, coloured):
                # the colours go under these names (a user's "RGBA" scalar field was written over without a word);
                # one holding the very colours (a mesh from pv.to_trimesh) loses nothing
                if not (array.shape == colours.shape and kind == coloured and np.array_equal(array, colours)):
                    shadowed.append(f"{kind} attribute {name!r}")
                continue
            if array.dtype.kind == "O" and all(isinstance(v, str) for v in array.ravel()):
                array = array.astype(str)  # strings held as objects (a pandas column's values) are strings
            if array.size == 0 and array.ndim > 1:  # (N, 0): pyvista's ValueError "Empty arrays are not allowed"
                # came out of to_polydata (and of render_mesh and save_mesh of the mesh), naming no argument; (0,) of
                # a mesh with no faces VTK holds
                left_out.append(f"{kind} attribute {name!r} ({array.dtype} of shape {array.shape})")
            elif array.dtype.kind == "c" and array.ndim > 1:  # pyvista's ValueError "Complex data must be single
                # dimensional" came out of to_polydata: it stores a complex value as two floats, one value a cell
                left_out.append(f"{kind} attribute {name!r} ({array.dtype} of shape {array.shape})")
            elif array.dtype.kind in "US" and not all(v.isascii() for v in array.ravel().tolist()):
                # pyvista's ValueError "String array contains non-ASCII characters that are not supported by VTK"
                # (bytes: a UnicodeDecodeError) came out of to_polydata
                left_out.append(f"{kind} attribute {name!r} (non-ASCII strings)")
            elif array.dtype.kind in _DATA_KINDS:
                data[name] = _vtk_values(array, own)
            else:
                left_out.append(f"{kind} attribute {name!r} ({array.dtype})")
    if left_out:
        warnings.warn(f"to_polydata: {', '.join(left_out)} left out: VTK holds arrays of numbers and ASCII strings "
                      "only (complex numbers one to a point or cell), of at least one value each",
                      stacklevel=caller_stacklevel())
    if unnamed:
        warnings.warn(f"to_polydata: {', '.join(unnamed)} left out: VTK's arrays are named by a str that is not "
                      "empty (as metadata keys must be)", stacklevel=caller_stacklevel())
    if shadowed:
        warnings.warn(f"to_polydata: {', '.join(shadowed)} left out: the mesh's {coloured} colours go under 'RGBA' "
                      f"and {RGBA_ALIAS!r} in the PolyData, and from_polydata reads those names as the colours "
                      "(rename the attribute to keep it)", stacklevel=caller_stacklevel())
    uv = getattr(mesh.visual, "uv", None) if mesh.visual.kind == "texture" else None
    if uv is not None and np.shape(uv) == (len(mesh.vertices), 2):
        # pyvista's setter stores them as "Texture Coordinates": a vertex attribute of that name was written over by
        # them without a word. Under a name of their own then, both kept (from_polydata passes the UVs over by it)
        uv_name = "Texture Coordinates"
        while uv_name in poly.point_data:
            uv_name += " (uv)"
        poly.point_data[uv_name] = own(uv, dtype=np.float64)
        poly.point_data.active_texture_coordinates_name = uv_name
    if colours is not None:  # colours by face (a PLY or 3MF read back) were dropped
        data = poly.point_data if coloured == "vertex" else poly.cell_data
        data["RGBA"] = own(colours, dtype=np.uint8)
        # pyvista shows an array as colours (no colormap, no scalar bar) only when its name ends in "_rgb" or
        # "_rgba": steps.plot() drew "RGBA" through viridis, with a bar of 'RGBA' magnitudes. The same bytes (one
        # buffer, no copy) under RGBA_ALIAS are the active scalars, so the default plot shows the level colours.
        data[RGBA_ALIAS] = data["RGBA"]
        data.active_scalars_name = RGBA_ALIAS
    if "isovalues" in mesh.metadata:
        try:  # numbers; others (strings, ragged lists: numpy's ValueError came out of to_polydata) go as any item
            poly.field_data["isovalues"] = np.asarray(mesh.metadata["isovalues"], dtype=np.float64)
        except (TypeError, ValueError):
            pass
    # only the isovalues were kept (source, CRS, gamma, floor dropped), where pv.wrap keeps them in user_dict
    kept, dropped = {}, []
    for key, value in mesh.metadata.items():
        try:
            item = json_metadata({key: value})
        except InvalidInputError:
            item = {}
        kept.update(item)
        # "_" items are private (trimesh's "_ply_raw"), as in glTF extras; the isovalues are a field_data array above
        if item or str(key).startswith("_") or (key == "isovalues" and key in poly.field_data):
            continue
        # an array past glTF extras' length (a globe's per-vertex node_entry) was left out without a word
        array = value if isinstance(value, np.ndarray) else None
        # (N, 0) raised pyvista's ValueError "Empty arrays are not allowed" out of to_polydata
        # a key "" too: VTK's unnamed array came back as "Unnamed_0"
        if array is not None and array.dtype.kind in "biuf" and isinstance(key, str) and key \
                and 0 not in array.shape[1:]:
            poly.field_data[key] = _vtk_values(array, own)
        else:
            dropped.append(key)
    if dropped:
        warnings.warn(f"to_polydata: mesh.metadata items {dropped!r} are not JSON (or are lists too long for "
                      "glTF extras) and were left out of user_dict", stacklevel=caller_stacklevel())
    if kept:
        poly.user_dict.update(kept)
    return poly


def _shadows_colours(name: str, kind: str, coloured: str) -> bool:
    """Whether a ``kind`` ("vertex" or "face") attribute ``name`` of a mesh coloured by ``coloured`` would be taken
    for its colours: written over by them (their names, "RGBA" and :data:`RGBA_ALIAS`, in the data they go to), or
    read back by :func:`from_polydata` instead of them (:data:`RGBA_ALIAS` in point data beside colours by face)."""
    return name in (RGBA_ALIAS, "RGBA") if kind == coloured else (kind == "vertex" and name == RGBA_ALIAS)


#: The dtype kinds :func:`to_polydata` keeps as point or cell data: booleans, integers, floats, complex, strings
#: (str and bytes, both VTK string arrays).
_DATA_KINDS = "biufcUS"


def _vtk_values(array: NDArray[Any], own: Any) -> NDArray[Any]:
    """``array`` as VTK takes it: half floats as float32 (VTK has no float16: its TypeError "Could not find a suitable
    VTK type for float16" came out of to_polydata), long doubles as float64 (complex128), complex numbers and
    strings in native byte order, else ``own(array)``. Bools go to pyvista as they are: it stores
    them as uint8 (VTK has no bool arrays) and reads them back as bool; cast to uint8 here, they came back from
    :func:`from_polydata` as 0/1 numbers (``wall`` aside), so a mask face attribute indexed rows 0 and 1 instead of
    selecting faces."""
    if array.dtype.kind == "f" and array.dtype.itemsize == 2:  # ">f2" (big-endian) too: VTK's TypeError for it
        return array.astype(np.float32)
    # long doubles (VTK's TypeError "Could not find a suitable VTK type for float128", pyvista's ValueError "Only
    # numpy.complex64 or numpy.complex128 is supported") as double, the widest VTK holds
    if array.dtype.kind in "fc" and array.dtype.itemsize > (8 if array.dtype.kind == "f" else 16):
        return array.astype(np.float64 if array.dtype.kind == "f" else np.complex128)
    if array.dtype.kind in "cU" and not array.dtype.isnative:  # pyvista's ValueErrors ("Only numpy.complex64 or
        # numpy.complex128", "non-ASCII characters" of ASCII strings) for them; its other arrays it swaps itself
        return array.astype(array.dtype.newbyteorder("="))
    return own(array)


def from_polydata(poly: Any, name: str = "mesh") -> trimesh.Trimesh:
    """A ``pyvista.PolyData`` of triangles as a ``trimesh.Trimesh``: the way back from :func:`to_polydata`
    (``grid.stepterrain.stepped``'s result), which :func:`~stepterrain.export.save_mesh`,
    :func:`~stepterrain.render.render_mesh` and :func:`~stepterrain.texture.drape` call on a PolyData given to them.

    Points and faces are copied as they are (float64, int64; non-finite points too, as a Trimesh holds them and
    :func:`to_polydata` passes them on: :func:`~stepterrain.export.save_mesh` refuses them by name,
    :func:`~stepterrain.render.render_mesh` leaves NaN points out (nodata) and refuses infinite ones). The array
    named ``colors_rgba`` (else ``RGBA``, else ``RGB``, as VTK's PLY and OBJ readers name colours, else active
    scalars named ``*_rgb``/``*_rgba``), point data before cell data at one name, of 3 or 4 columns of uint8, or of
    other whole numbers in [0, 255] or floats in [0, 1] (as pyvista plots them), becomes the vertex colours, or the
    face colours if in cell data (pv.to_trimesh leaves them as a plain attribute, so they were not written nor
    drawn); an array under such a name that holds no colours (floats beyond 1, one column) is passed over, an
    attribute. Other point data become vertex attributes (normals and texture coordinates aside: a PolyData holds no
    texture image, drape it instead). Other cell data become face attributes, ``wall`` (0/1) as bool again.
    ``user_dict`` items and the other field data (``isovalues`` as a list) become the metadata. ``name`` names the
    argument in errors.

    Raises
    ------
    InvalidInputError
        ``poly`` is not a PolyData, or holds cells other than triangles (vertices, lines, strips, polygons of
        more corners: ``poly.triangulate()`` makes triangles of the strips and polygons; vertices and lines beside
        faces are removed first, ``poly.remove_cells(range(poly.n_verts + poly.n_lines))``; points alone, or
        lines, have no face to triangulate: ``poly.delaunay_2d()`` makes a TIN of them), or faces that index
        outside its points (the Trimesh's first use raised numpy's IndexError).
    """
    from pyvista.core.dataobject import USER_DICT_KEY

    if not isinstance(poly, pv.PolyData):
        raise InvalidInputError(f"{name} must be a pyvista.PolyData; got {type(poly).__name__}")
    # pyvista's is_all_triangles looks at the polygons alone: strips beside triangles passed, and their faces were
    # dropped without a word (regular_faces holds the polygons), a cell-data array longer than the faces kept
    if poly.n_cells and (poly.n_strips or not poly.is_all_triangles):
        polygons = int((np.diff(poly.GetPolys().GetOffsetsArray()) != 3).sum()) if poly.GetNumberOfPolys() else 0
        others = {("vertex cell", None): poly.n_verts, ("line", None): poly.n_lines, ("strip", None): poly.n_strips,
                  ("polygon of 4 or more corners", "polygons of 4 or more corners"): polygons}  # fmt: skip
        found = ", ".join(counted(n, *kind) for kind, n in others.items() if n)  # "1 lines" said before
        if not poly.GetNumberOfPolys() and not poly.n_strips:
            # points (pv.PolyData(points) makes a vertex cell of each) or lines: no face for triangulate(), which
            # drops vertex cells and lines and returned an empty mesh; a TIN of their points is what steps
            raise InvalidInputError(f"{name} must be a PolyData of triangles only; got {found} and no faces, so "
                                    f"{name}.triangulate() makes nothing of it; {name}.delaunay_2d() makes a TIN "
                                    "(triangles) of its points")
        if not poly.n_verts and not poly.n_lines:
            raise InvalidInputError(f"{name} must be a PolyData of triangles only; got {found} ({name}.triangulate() "
                                    "makes triangles of them)")
        # triangulate() drops vertex cells but keeps lines beside faces that are all triangles (VTK's triangle
        # filter): VTK numbers the vertex cells and lines first, so removing those ids leaves the faces alone
        raise InvalidInputError(f"{name} must be a PolyData of triangles only; got {found} ({name}.remove_cells(range("
                                f"{name}.n_verts + {name}.n_lines)).triangulate() keeps its faces alone, as triangles)")
    vertices = np.array(poly.points, dtype=np.float64)
    faces = np.array(poly.regular_faces, dtype=np.int64) if poly.n_cells else np.zeros((0, 3), np.int64)
    # VTK keeps indices past the points (or -1) as they are: the Trimesh's first use raised numpy's IndexError
    check_face_indices(faces, len(vertices), f"{name} faces", "point", "points")
    point_data, cell_data = poly.point_data, poly.cell_data
    coloured, found, colour_names = _colours(point_data, cell_data)
    colors, face_colors = (found, None) if coloured == "vertex" else (None, found)
    face_colour_names = colour_names if coloured == "face" else set()
    colour_names = colour_names if coloured == "vertex" else set()
    skipped = {point_data.active_normals_name, point_data.active_texture_coordinates_name} | colour_names
    # (pyvista reads a complex array of one value back as a 0-d array: shape (), no value per vertex or face)
    vertex_attributes = {n: np.array(point_data[n], ndmin=1) for n in point_data.keys() if n not in skipped}
    face_attributes = {}
    for key in cell_data.keys():
        if key == cell_data.active_normals_name or key in face_colour_names:
            continue
        values = np.array(cell_data[key], ndmin=1)
        if key == "wall" and values.dtype == np.uint8 and values.max(initial=0) <= 1:  # bool as uint8 in VTK
            values = values.astype(bool)
        face_attributes[key] = values
    metadata: dict[str, Any] = dict(poly.user_dict) if USER_DICT_KEY in poly.field_data else {}
    for key in poly.field_data.keys():
        if key != USER_DICT_KEY and key not in metadata:
            values = np.array(poly.field_data[key])
            metadata[key] = values.tolist() if key == "isovalues" else values
    return trimesh.Trimesh(vertices, faces, process=False, vertex_colors=colors, face_colors=face_colors,
                           face_attributes=face_attributes, vertex_attributes=vertex_attributes, metadata=metadata)


def _colours(point_data: Any, cell_data: Any) -> tuple[str | None, NDArray[np.uint8] | None, set[str]]:
    """The colours among a PolyData's ``point_data`` and ``cell_data`` (see :func:`from_polydata`): "vertex" or
    "face", the colours (a copy) and the names of the arrays they are (none of them an attribute besides), else
    (None, None, no names). The strongest name wins wherever it is (point data first at one name): point data was
    looked at first whatever its names, so a mesh coloured by face with a vertex attribute "RGB" came back coloured
    by that attribute, its colours face attributes."""
    # "RGB": pv.read of a PLY without alpha, or of an OBJ, (VTK's readers) rendered tan, its colours a vertex attribute
    candidates = [(kind, data, n) for n in (RGBA_ALIAS, "RGBA", "RGB")
                  for kind, data in (("vertex", point_data), ("face", cell_data)) if n in data]
    for kind, data in (("vertex", point_data), ("face", cell_data)):
        active = data.active_scalars_name
        if active is not None and active.lower().endswith(("_rgb", "_rgba")):
            candidates.append((kind, data, active))
    for kind, data, colour_name in candidates:
        values = np.asarray(data[colour_name])
        if values.ndim != 2 or values.shape[1] not in (3, 4):
            continue
        colours = _uint8_colours(values)
        if colours is None:
            continue
        # "RGBA" and its alias share one buffer (to_polydata): neither is an attribute besides
        same = {n for n in (RGBA_ALIAS, "RGBA") if n in data and np.array_equal(np.asarray(data[n]), values)}
        return kind, colours, {colour_name} | same
    return None, None, set()


def _uint8_colours(values: NDArray[Any]) -> NDArray[np.uint8] | None:
    """Colour rows as uint8 (a copy), read as VTK's direct colour mode reads them (pyvista plots an array named
    ``*_rgb``/``*_rgba`` so): floats in [0, 1], whole numbers in [0, 255]; None for anything else (NaN, floats
    beyond 1, negative numbers, bools), left a plain attribute. Only uint8 was taken: ``poly["colors_rgba"] =``
    floats, shown as colours by ``poly.plot()``, rendered in plain tan through render_mesh and were saved
    uncoloured."""
    if values.dtype == np.uint8:
        return values.copy()
    if values.dtype.kind in "iu":
        if values.size and (values.min() < 0 or values.max() > 255):
            return None
        return values.astype(np.uint8)
    if values.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            if not (np.isfinite(values).all() and (values >= 0).all() and (values <= 1).all()):
                return None
        # VTK's direct colour mode computes floor(c * 255 + 0.5) in double: np.rint rounded exact halves (a float64
        # c = (2k + 1) / 510) to even, one level below what poly.plot() shows for every other half
        return np.floor(values.astype(np.float64) * 255.0 + 0.5).astype(np.uint8)
    return None


def _uniform_step(coords: NDArray[np.float64]) -> float | None:
    """The step of evenly spaced coordinates (each within 1e-6 of a step of where it should be), else None."""
    step = float(coords[-1] - coords[0]) / (len(coords) - 1)
    even = coords[0] + np.arange(len(coords)) * step
    return step if step != 0.0 and float(np.abs(coords - even).max()) <= 1e-6 * abs(step) else None


for _cls in (pv.ImageData, pv.RectilinearGrid, pv.StructuredGrid):
    try:
        pv.register_dataset_accessor("stepterrain", _cls)(StepTerrainAccessor)
    except (ValueError, RuntimeError):  # already registered (module reloaded)
        pass
