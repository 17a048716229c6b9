"""``stepterrain globe``: a view-dependent mesh of a global grid on the cube sphere (paper 003): the earth's relief by
default, another body's (Mars, the Moon) on its own sphere when the INPUT's CRS names it.

    stepterrain globe -o out/globe.glb --png out/globe.png
    stepterrain globe --eye 46,9,400000 --tilt 60 --heading 0 --error 30 -o alps.glb --png alps.png
"""

from __future__ import annotations

import argparse
import math
import shlex
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ._files import gdal_path
from .camera import _MAX_COORDINATE
from .cli import (
    Progress,
    _add_device,
    _add_height_unit,
    _add_nodata,
    _check_outputs,
    _check_side_files,
    _check_size,
    _counted,
    _floats,
    _given,
    _mesh_and_png,
    _option_list,
    _path,
    _real,
    _refuse_unused,
    _size,
    _whole,
    _window,
)
from .errors import DataFileError, InvalidInputError
from .export import MESH_EXTENSIONS
from .io import (
    _NPZ_SCALING,
    GDAL_FORMATS,
    _heights_in_metres,
    _npz_text,
    _vertical_unit,
    _virtual_refusal,
    _warn_unit_override,
    _warn_void_values,
    dem_path,
    missing_cells,
    npz_missing,
    npz_nodata,
    open_npz,
    refuse_npz_scaling,
)

_EARTH_RADIUS = 6_371_000.0  # --radius's default (globe.EARTH_RADIUS, not imported before the command runs)


class _Body(NamedTuple):
    """The body an INPUT's CRS names when it is not the earth (Mars, the Moon): the ``radius`` (m) of the sphere its
    degrees became metres on in load_dem (its ellipsoid's mean radius a·(1 - f/3), to the 10 digits load_dem's local
    CRS states) and its ellipsoid's ``name``."""

    radius: float
    name: str


def _crs_body(crs: str | None) -> _Body | None:
    """The body a geographic (or projected) ``crs`` names when it is not the earth's (io._geographic_body: an
    ellipsoid whose semi-major axis is more than 1 % off WGS 84's), else None: no CRS, an earth one, or none rasterio
    can read."""
    from .io import _geographic_body

    body = _geographic_body(crs)
    return None if body.earth else _Body(float(f"{body.radius:.10g}"), body.name)


def _drape_side_files(out: Path, jpeg: bool) -> list[Path]:
    """The side files the --output writes for a --texture drape (a textured OBJ's .mtl and image): those of a
    one-triangle mesh draped as :func:`~stepterrain.globe.drape_texture` drapes the globe with the texture; ``jpeg``
    whether it is a JPEG the drape embeds as it is (written as .jpeg, see :func:`~stepterrain.globe._kept_jpeg`):
    the picture :func:`~stepterrain.globe._texture_image` read, not the file opened again."""
    if out.suffix.lower() != ".obj":
        return []
    import io

    import trimesh
    from PIL import Image

    from .export import _side_files
    from .globe import _drape_texture

    picture = None
    if jpeg:
        buffer = io.BytesIO()
        Image.new("RGB", (4, 2)).save(buffer, format="JPEG")
        picture = Image.open(buffer)
    triangle = trimesh.Trimesh([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], [[0, 1, 2]], process=False)
    return _side_files(_drape_texture(triangle, np.zeros((2, 4, 3), np.uint8), picture), out)


_EPILOG = """\
examples:
  stepterrain globe -o out/globe.glb --png out/globe.png
      the embedded ETOPO 2022 relief (20'), 257^2 nodes per face, seen from 3 earth radii above 30N 10E
  stepterrain globe --eye 46,9,400000 --tilt 60 --error 20 --png alps.png
      the render alone: no -o, no mesh file
  stepterrain globe --face-size 1025 --error 0 -o full.ply
      the full-resolution sphere: 6 x 1024^2 x 2 triangles
  stepterrain globe --eye 46,9,400000 --tilt 60 --error 20 --exaggeration 10 -o alps.glb --png alps.png
      from 400 km above the Alps, tilted 60 degrees to the north, clipped to the view (paper 003, Abb. 12)
  stepterrain globe --bounds sphere --metrics geometric,distance -o spheres.glb
      bounding spheres instead of cone frustums, no clipping
  stepterrain globe relief.npz --texture bluemarble.jpg -o textured.glb
      a lat/lon grid (.npz with elevation, lat, lon in degrees) draped with a plate-carree image
  stepterrain globe gebco_2024_1deg.tif -o gebco.glb
      a global GeoTIFF in degrees (EPSG:4326), longitudes -180..180 or 0..360
"""


def add_parser(commands: Any) -> None:
    """Add the ``globe`` subcommand."""
    p = commands.add_parser(
        "globe",
        help="global terrain on the cube sphere: view-dependent, crack-free meshes (paper 003)",
        description="Resample a global lat/lon elevation grid onto the six faces of a cube sphere, build the "
        "longest-edge bisection hierarchy with saturated bounding spheres / cone frustums (Adelsberger), and "
        "write a view-dependent mesh by extension (.glb .gltf .obj .ply .stl .3mf), optionally rendered; give -o, "
        "--png or both (--png alone writes only the render).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("input", nargs="?", type=_path, metavar="INPUT",
                   help="global grid .npz (elevation, lat, lon in degrees; heights in metres, or in the length unit "
                        "an optional units names, as load_dem reads it; cells equal to an optional nodata value, "
                        "or marked by a boolean mask or valid, are refused: fill them first), or a raster in degrees "
                        "(a GeoTIFF or any other load_dem reads: .asc .hgt .img .vrt ..., a GDAL virtual path or URL "
                        "to one, /vsizip/srtm.zip/N46E007.hgt, or a .zip or gzip of one, dem.tif.gz; EPSG:4326, or "
                        "Mars's or the Moon's degrees, meshed on that body's sphere; nodata refused as well); "
                        "default: the embedded ETOPO 2022 20'")
    _add_height_unit(p, help="the INPUT heights' length unit (m, ft, US survey foot, km, cm, ...), for a file that "
                             "names none or one not known (an .npz 'units', a raster band's unit); it overrides a "
                             "unit the file names (with a warning where that unit is known and another length); "
                             "heights become metres (default: the unit the file names, else as stored)")
    _add_nodata(p, "the INPUT", "the globe refuses such cells as it refuses the file's own nodata: fill "
                                  "them first")
    p.add_argument("--face-size", type=_whole, default=257, metavar="N",
                   help="nodes per cube face edge, 2^k+1 (default 257; the paper uses 1025)")
    p.add_argument("--exaggeration", type=_real, default=1.0, metavar="X", help="vertical exaggeration (default 1)")
    p.add_argument("--radius", type=_real, default=None, metavar="M",
                   help="sphere radius in metres (default: the mean radius a(1 - f/3) of the body the INPUT's CRS "
                        "names when it is not the earth (Mars: IAU_2015:49900, a GEOGCS of Mars 2000; the Moon: "
                        "IAU_2015:30100); else the earth's, 6371000)")
    p.add_argument("--error", type=_real, default=500.0, metavar="E",
                   help="metres of error tolerated: at the eye's altitude with the distance metric (growing with "
                        "distance squared), else everywhere (the geometric error alone); 0 = full resolution where "
                        "visible (default 500)")
    p.add_argument("--eye", type=_floats(3, "lat,lon,altitude (degrees, degrees, metres)"),
                   default=None, metavar="LAT,LON,ALT",
                   help="eye position: latitude, longitude (degrees) and altitude (metres above the sphere, and "
                        "above the terrain there: negative over land or sea floor below it, such as the Dead Sea); "
                        "default 30,10,3R, R the --radius (the whole globe in view); read by the distance and clip "
                        "metrics and the --png render: refused without one of them (--no-camera, or --metrics "
                        "geometric alone, and no --png)")
    p.add_argument("--tilt", type=_real, default=None, metavar="DEG",
                   help="tilt of the view from straight down, in [0, 90) degrees (default 0); the view of the clip "
                        "metric and the --png render: refused without either")
    p.add_argument("--heading", type=_real, default=None, metavar="DEG",
                   help="direction of the tilt, degrees clockwise from north; whole turns are taken off (default "
                        "0); the view of the clip metric and the --png render: refused without either")
    p.add_argument("--view-angle", type=_real, default=None, metavar="DEG",
                   help="vertical field of view of the eye in [1e-08, 179] degrees (default 30): the view the clip "
                        "metric refines and culls the mesh for, and the --png render's: refused without either")
    p.add_argument("--no-camera", action="store_true",
                   help="no view dependence: refine by the geometric error alone (--error in metres)")
    p.add_argument("--bounds", choices=("cone", "sphere"), default=None,
                   help="bounding shapes the distance and clip metrics measure: cone frustums (default) or "
                        "spheres; with the camera and the distance or clip metric only (refused with --no-camera or "
                        "--metrics geometric)")
    p.add_argument("--metrics", default=None, metavar="a,b,c",
                   help="metrics multiplied together (default geometric,distance,clip; with --no-camera geometric: "
                        "distance and clip need the camera)")
    p.add_argument("--no-cull", action="store_true",
                   help="keep triangles outside the view (a closed mesh); with the camera and the clip metric")
    p.add_argument("--texture", type=_path, metavar="IMAGE",
                   help="global plate-carree image (row 0 at 90N, column 0 at 180W; a GeoTIFF, .aux.xml or world "
                        "file georeferenced from 0 to 360 is shifted, one regional or projected refused) draped by "
                        "latitude and longitude: "
                        "embedded as the mesh's texture in .glb/.gltf/.obj and drawn as a texture in the --png "
                        "render, as vertex colours in .ply/.3mf (an .stl holds no colours: refused with an .stl -o "
                        "and no --png); default: colours by elevation")
    _add_device(p)
    p.add_argument("-o", "--output", type=_path, metavar="OUT",
                   help="mesh file; format by extension: " + " ".join(MESH_EXTENSIONS)
                        + " (optional with --png: a render-only run writes no mesh)")
    p.add_argument("--png", type=_path, metavar="OUT.png",
                   help="write an off-screen render from the eye (beside the mesh, or alone without -o)")
    p.add_argument("--size", type=_window, default=None, metavar="WxH",
                   help="render size with --png, and the aspect of the clip metric's view (default 1280x800): "
                        "refused without either")
    p.set_defaults(run=_run_globe)


def _load_grid(path: str, height_unit: str | None = None, nodata: Sequence[float] | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, _Body | None]:
    """The (lat, lon, elevation, body) of a global grid INPUT, its heights in metres: in ``height_unit``
    (--height-unit) when given, else in the unit the file names (as load_dem reads it); cells of ``nodata``
    (--nodata) missing besides the file's own, as load_dem reads them (and refused alike); ``body`` the body its CRS
    (a raster's, an .npz's 'crs') names when it is not the earth (:func:`_crs_body`), else None."""
    virtual = gdal_path(path)  # a /vsizip/... path or a URL: read by GDAL, as load_dem reads it
    if virtual is not None and virtual.suffix.lower() not in GDAL_FORMATS:
        raise InvalidInputError(_virtual_refusal(virtual))
    nodata_given = tuple(nodata or ())
    file = Path(path) if virtual is None else virtual
    if virtual is None and not file.exists():
        raise DataFileError(f"INPUT {path!r} does not exist")
    if virtual is None and not file.is_file():
        raise DataFileError(f"INPUT {path!r} is not a file")
    if file.suffix.lower() in (".zip", ".gz"):  # a zip or gzip of one raster (an SRTM download), as load_dem reads
        file = dem_path(file)  # it (a .gz of an .npz refused: gunzip it)
    if file.suffix.lower() in GDAL_FORMATS:  # a GeoTIFF, .asc, .hgt, .img, .vrt, ...: as load_dem reads them
        return _load_geotiff_grid(file, height_unit, nodata)
    if file.suffix.lower() != ".npz":
        raise InvalidInputError(f"INPUT must be a .npz with elevation, lat and lon arrays, or a raster in degrees "
                                f"({' '.join(GDAL_FORMATS)}, or a .zip or .gz of one); got {path!r}")
    try:
        handle, data = open_npz(file)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise DataFileError(f"cannot read {path!r} as .npz: {exc}") from exc
    if isinstance(data, np.ndarray):
        handle.close()
        raise DataFileError(f"{path!r} must be an .npz archive with arrays 'elevation', 'lat' and 'lon'; "
                            "got one .npy array")
    with handle, data:
        missing = [key for key in ("elevation", "lat", "lon") if key not in data.files]
        if missing:
            raise DataFileError(f"{path!r} must hold arrays 'elevation', 'lat' and 'lon'; missing "
                                f"{', '.join(repr(key) for key in missing)}")
        try:
            lat, lon, elevation = np.asarray(data["lat"]), np.asarray(data["lon"]), np.asarray(data["elevation"])
            nodata = npz_nodata(data["nodata"] if "nodata" in data.files else None, file)
            # a boolean mask/valid and a scale, as load_dem reads and refuses them (they were ignored here)
            beside = {key: np.asarray(data[key]) for key in ("mask", "valid", *_NPZ_SCALING) if key in data.files}
            # the heights' unit as load_dem reads it: 'units', else a compound 'crs''s vertical unit (both ignored
            # here: heights in feet were meshed as metres, 3.28 times too high)
            texts = {key: np.asarray(data[key]) for key in ("units", "crs") if key in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise DataFileError(f"cannot read {path!r} as .npz: {exc}") from exc
    if elevation.ndim != 2:  # the progress line reads its shape before Globe.from_latlon checks it
        raise InvalidInputError(f"{path!r}: 'elevation' must be a 2-D (H, W) array; got shape {elevation.shape}")
    refuse_npz_scaling(beside, "elevation", file)
    # the cells missing as io.load_dem finds them (its own rules, shared): the file's nodata (meshed as heights before,
    # a -32768 m pit per cell), --nodata compared as the file's own nodata is, a boolean mask or valid (meshed as
    # their stored values); other dtypes than real ones: Globe.from_latlon names them
    marks: list[str] = []
    missing = missing_cells(elevation, nodata, nodata_given,
                            npz_missing({"elevation": elevation, **beside}, "elevation", file), marked_by=marks)
    # the refusal names what marks a cell: a mask, nodata value or --nodata that marks none was named beside the NaN
    # cells that were missing ("(nodata -9999, NaN or infinite; ...)" of one NaN cell)
    names = {"given": lambda: f"--nodata {','.join(f'{v:g}' for v in nodata_given)}",
             "nodata": lambda: f"nodata {nodata:g}",
             "mask": lambda: " or ".join(repr(key) for key in ("mask", "valid") if key in beside)}
    marked_by = [names[mark]() for mark in ("given", "nodata", "mask") if mark in marks]
    if elevation.dtype.kind == "f":  # NaN and ±inf: nodata as load_dem reads them (Globe.from_latlon's refusal said
        # "elevation has 1 NaN or infinite value", naming no INPUT, as a raster's nodata once did)
        void = ~np.isfinite(elevation)
        if void.any():
            missing = void if missing is None else void | missing
            marked_by.append("NaN or infinite")
    if missing is not None and missing.any():
        row, col = np.argwhere(missing)[0]
        cells = _counted(int(missing.sum()), "nodata cell")
        raise InvalidInputError(f"{path!r}: 'elevation' has {cells} ({', '.join(marked_by)}; first at row {row}, "
                                f"column {col}); the globe needs a height everywhere: fill "
                                "them first (e.g. from neighbours)")
    if elevation.dtype.kind in "iuf":  # undeclared voids (-32768, -9999, ...) warned of as load_dem warns of a raster's
        _warn_void_values(file, elevation, None, "'elevation'")  # (they were meshed silently: pits 10 to 33 km deep)
    # --height-unit overrides the file's unit, as load_dem's height_unit does (an unknown one was refused with a
    # pointer to a --height-unit the globe lacked)
    crs = _npz_text(texts, "crs", file)
    declared = _npz_text(texts, "units", file)
    if elevation.dtype.kind in "iuf":
        _warn_unit_override(file, height_unit, declared, "its 'units'")
    unit, _, factor = _vertical_unit(height_unit or declared, crs)
    if unit is not None and elevation.dtype.kind in "iuf":  # (other dtypes: Globe.from_latlon names them)
        named_by = "--height-unit" if height_unit else "its 'units'" if "units" in texts else f"its CRS {crs}"
        elevation, _ = _heights_in_metres(elevation, unit, file, named_by, factor)
    return lat, lon, elevation, _crs_body(crs)


def _load_geotiff_grid(
    file: Path, height_unit: str | None = None, nodata: Sequence[float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, _Body | None]:
    """A global GeoTIFF (or any raster of io.GDAL_FORMATS) in a geographic CRS as (lat, lon, elevation, body): the
    heights as load_dem reads them (nodata, ``nodata`` besides, an internal mask, scale and offset, a height unit, a
    .prj; missing cells as NaN, which the globe refuses: fill them first), and the node degrees of its rows and
    columns from the degrees it read (stored order: north-first for a north-up file, longitudes 0..360 or -180..180
    as the file has them). It was refused as not an .npz: a GIS user's global grid (ETOPO, GEBCO) is a GeoTIFF.
    load_dem's warning that its local metres err far from the equator is left out: the globe reads degrees.
    ``body``: the body of another CRS than the earth's (Mars, the Moon), its radius the sphere load_dem made its
    degrees metres on, else None."""
    import warnings

    from .io import EARTH_RADIUS_M, _lonlat_grid, _spherical_eqc, load_dem, raster_header

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".* degrees read as local metres with one spacing")
        terrain = load_dem(file, height_unit=height_unit, nodata=nodata)
    eqc = _spherical_eqc(terrain.crs)
    lonlat = _lonlat_grid(terrain)  # describe_dem's lonlat_step, without its passes over the heights
    step = lonlat[1] if lonlat else None
    if eqc is None or step is None or terrain.origin != (0.0, 0.0):
        # -dstalpha: the cells of the grid in degrees outside the file's are missing (refused below, to fill); without
        # it (and a nodata value of the file's) gdalwarp filled them with 0, a globe of 0 m there without a word
        warp = f"gdalwarp -dstalpha -t_srs EPSG:4326 {shlex.quote(str(file))} {shlex.quote(file.stem + '_4326.tif')}"
        raise InvalidInputError(f"INPUT {str(file)!r} must be a raster in a geographic CRS (degrees: EPSG:4326); got "
                                f"CRS {terrain.crs or 'none'}; {warp} makes it one")
    if terrain.has_nodata:  # refused by Globe.from_latlon as "elevation has 1 NaN or infinite value", naming no
        # INPUT and hiding that the file's own nodata cells were the NaN
        missing = terrain.nodata_mask
        row, col = np.argwhere(missing)[0]
        count = int(missing.sum())
        del terrain, missing
        quoted = shlex.quote(str(file))
        fix = f"fill them first, e.g. gdal_fillnodata.py {quoted} filled.tif, and give filled.tif"
        given = [v for v in (nodata or ()) if math.isfinite(v)]
        own = _own_nodata_count(file, height_unit) if given else count
        if own != count:  # cells --nodata marks: gdal_fillnodata.py fills only a declared nodata (filled.tif kept
            # them, and was refused again)
            values = ",".join(f"{v:.17g}" for v in given)
            where = f"; --nodata {values} marks cells the file does not declare nodata"
            fix = (f"fill them first, e.g. gdal_translate -a_nodata {given[0]:.17g} {quoted} declared.tif, then "
                   "gdal_fillnodata.py declared.tif filled.tif, and give filled.tif" if len(given) == 1 and own == 0
                   else "fill them first (gdal_fillnodata.py fills only the nodata value a file declares, one per "
                   "band: give those cells that value first)")
        else:
            where = ""
        raise InvalidInputError(f"INPUT {str(file)!r} has {_counted(count, 'nodata cell')} (first at row {row}, "
                                f"column {col}{where}); a global grid cannot have holes: {fix}")
    radius, _, lat_0, lon_0, _, _ = eqc  # node (0, 0), the origin of load_dem's local metres
    rows, cols = terrain.shape
    lat = lat_0 + step[1] * np.arange(rows, dtype=np.float64)
    lon = lon_0 + step[0] * np.arange(cols, dtype=np.float64)
    body = None
    if abs(radius / EARTH_RADIUS_M - 1.0) > 0.01:  # another body's sphere (Mars: R = 3389526.667, not 6371008.8)
        header = raster_header(file)  # its ellipsoid's name, from the CRS load_dem read
        named = _crs_body(header[0]) if header is not None else None
        body = _Body(radius, named.name if named is not None else "its")
    return lat, lon, terrain.heights, body


def _own_nodata_count(file: Path, height_unit: str | None) -> int | None:
    """The nodata cells of the raster ``file`` as load_dem reads it without ``--nodata`` (its own nodata and mask),
    read again for a refusal's advice; None where it cannot be read so (a float64 grid's lowest value, which only
    --nodata lifts)."""
    import warnings

    from .errors import StepTerrainError
    from .io import load_dem

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return int(load_dem(file, height_unit=height_unit).nodata_mask.sum())
    except StepTerrainError:
        return None


def _check_globe_numbers(args: argparse.Namespace) -> None:
    """The numbers :meth:`~stepterrain.globe.Globe.from_latlon`, :meth:`~stepterrain.globe.Globe.mesh` and
    :func:`~stepterrain.globe.look_from` refuse whatever the grid (``--face-size`` not 2^k + 1, ``--radius`` not
    positive or beyond float32 node positions, ``--exaggeration`` not positive or below a normal float32, ``--error``
    below 0 or NaN, a non-finite ``--heading``), by their option names, before the INPUT is loaded: they were refused
    only once the whole lat/lon grid had been read (an ``--exaggeration`` too large for the grid's heights still is)."""
    from .globe import _error_value, _exaggeration_value, _face_cells, _radius_value

    _face_cells(args.face_size, "--face-size")  # from_latlon's checks, by the options' names
    if args.radius is not None:  # (else the earth's, or the radius of the body the INPUT's CRS names)
        _radius_value(args.radius, "--radius")
    _exaggeration_value(args.exaggeration, "--exaggeration")
    try:
        _error_value(args.error)
    except InvalidInputError as exc:  # the library's 'error must be ...'
        raise InvalidInputError(f"--{exc}") from None
    if args.heading is not None and not math.isfinite(args.heading):  # look_from's, once the globe was built
        raise InvalidInputError(f"--heading must be a finite number; got {args.heading!r}")


def _not_global(path: str, lat: np.ndarray, lon: np.ndarray) -> str:
    """Why the grid of INPUT ``path`` (its node ``lat`` and ``lon`` in degrees) is no globe: what globe needs and what
    the file covers. Globe.from_latlon said "lon must cover 360 degrees (W · step = 360)", naming a Python argument a
    user of ``stepterrain globe front_range.tif`` never gave, and not the file."""
    lat64, lon64 = np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64)
    step = float(np.abs(lon64[-1] - lon64[0]) / (len(lon64) - 1)) if len(lon64) > 1 else 0.0
    return (f"INPUT {path!r} is no global grid: globe meshes a lat/lon grid covering 360 degrees of longitude with "
            f"rows reaching both poles; the file covers {len(lon64) * step:.6g} degrees of longitude "
            f"({lon64.min():.6g} to {lon64.max():.6g}) and latitudes {lat64.min():.6g} to {lat64.max():.6g} (cell "
            f"centres, {len(lat64)} x {len(lon64)} cells): mesh a regional DEM with stepterrain steps, texture or "
            "closeup")


def _run_globe(args: argparse.Namespace, progress: Progress) -> int:
    from . import export, render
    from .globe import (
        METRICS,
        Globe,
        _drape_colors,
        _drape_texture,
        _radius_value,
        _texture_image,
        _unresolved_altitude,
        elevation_colors,
        load_global_relief,
        look_from,
        render_view,
    )

    out, png = _mesh_and_png(args.output, args.png)
    _check_globe_numbers(args)
    if args.height_unit is not None and not args.input:
        raise InvalidInputError(f"--height-unit applies to an INPUT file; the embedded ETOPO 2022 relief is in metres; "
                                f"got {args.height_unit!r}")
    if args.nodata is not None and not args.input:
        raise InvalidInputError(f"--nodata applies to an INPUT file; the embedded ETOPO 2022 relief has a height "
                                f"everywhere; got --nodata {','.join(f'{v:g}' for v in args.nodata)}")
    metrics = tuple(m.strip() for m in (args.metrics if args.metrics is not None else ",".join(METRICS)).split(","))
    if "" in metrics:  # '' or 'geometric,,clip': a metric left out, not fewer metrics
        raise InvalidInputError(f"--metrics must be names among geometric, distance, clip separated by commas; "
                                f"got {args.metrics!r} (an empty name)")
    unknown = [m for m in metrics if m not in METRICS]  # the library's message offered callables, which no option takes
    if unknown:
        raise InvalidInputError(f"--metrics must be names among geometric, distance, clip separated by commas; "
                                f"got {args.metrics!r} ({', '.join(repr(m) for m in unknown)} unknown)")
    repeated = sorted({m for m in metrics if metrics.count(m) > 1})
    if repeated:  # a metric multiplied in twice is the same metric: the metadata and progress line named it twice
        raise InvalidInputError(f"--metrics names each metric once; got {args.metrics!r} ({', '.join(repeated)} "
                                "repeated)")
    # the library ignores the view's metrics without a camera, and culls only by the clip metric: such options
    # were accepted, did nothing, and the mesh's metadata and the progress line named metrics that were not applied
    viewed = [m for m in metrics if m in ("distance", "clip")]
    if args.no_camera:
        if viewed and args.metrics is not None:
            verb = "needs" if len(viewed) == 1 else "need"
            raise InvalidInputError(f"--metrics {','.join(viewed)} {verb} the camera: not with --no-camera, which "
                                    "refines by the geometric error alone")
        if args.no_cull:
            raise InvalidInputError("--no-cull applies only with the camera (with --no-camera nothing is culled)")
        metrics = tuple(m for m in metrics if m not in viewed)
    elif args.no_cull and "clip" not in metrics:
        raise InvalidInputError(f"--no-cull applies only with the clip metric (only it culls); got --metrics "
                                f"{args.metrics}")
    # the bounding shapes are measured only against the eye (distance) and the view (clip): --bounds sphere with
    # --no-camera made the same mesh as cones, and the metadata and progress line named the shapes all the same
    shaped = not args.no_camera and bool(viewed)
    if args.bounds is not None and not shaped:
        why = "--no-camera" if args.no_camera else f"--metrics {args.metrics}"
        raise InvalidInputError(f"--bounds applies only with the camera and the distance or clip metric (the "
                                f"bounding shapes are measured against the eye and the view); got --bounds "
                                f"{args.bounds} with {why}")
    bounds = args.bounds or "cone"
    # the view's options place the camera (the mesh's view dependence) and the --png render: with --no-camera and
    # no --png they did nothing, and the run said nothing of it
    unused = ["--eye"] * (args.eye is not None) + _given(args, {"tilt": 0.0, "heading": 0.0, "size": (1280, 800),
                                                                 "view_angle": 30.0})
    _check_size(args.size, renders=png is not None)
    if args.texture is not None and png is None and out.suffix.lower() == ".stl":  # colours nowhere: it did nothing
        raise InvalidInputError(f"--texture colours the mesh and the --png render; an .stl --output holds no colours: "
                                f"got --texture {args.texture!r} with --output {args.output!r} and no --png")
    _check_outputs({"INPUT": args.input, "--texture": args.texture}, output=out, png=png)
    # positive, within float32 positions (_check_globe_numbers); without --radius the earth's until an INPUT's CRS
    # names another body (Mars, the Moon: its radius, once the INPUT is read)
    radius = args.radius if args.radius is not None else _EARTH_RADIUS
    lat_deg, lon_deg = args.eye[:2] if args.eye is not None else (30.0, 10.0)
    # the eye places the camera and the --png render: with --no-camera or the geometric metric alone, no --png and no
    # --eye (refused below as unused) nothing looks from it, and the default one, 3 radii up, was refused past the
    # camera's bound (--radius 1e35 --no-camera, a radius the library takes; --metrics geometric --radius 1e30 until
    # session 46)
    eye_used = shaped or png is not None or args.eye is not None
    if not (-90.0 <= lat_deg <= 90.0):
        raise InvalidInputError(f"--eye latitude must lie in [-90, 90]; got {lat_deg}")
    if not (-360.0 <= lon_deg <= 360.0):  # look_from's bound, which named the library's 'longitude'
        raise InvalidInputError(f"--eye longitude must lie in [-360, 360] degrees; got {lon_deg:g}")

    def eye_altitude(radius: float, sphere: str) -> float:
        """The --eye altitude above the sphere of ``radius`` (named ``sphere`` in the messages), checked: the default
        eye 3R above 30N 10E: R the sphere's radius (a fixed 3 earth radii showed a larger planet as a patch of its
        surface and a smaller one as a speck, not the whole globe the help promises). Any altitude above the terrain
        there, below the sphere too (the Dead Sea lies 430 m under it): the library refuses an eye below the
        terrain, named by --eye below. The CLI's own "altitude > 0" refused such views; an eye at or beyond the
        centre is below any terrain (every node lies outside the centre), refused here alike."""
        altitude = args.eye[2] if args.eye is not None else 3 * radius
        the = "the " if sphere.startswith("--") else ""
        if radius + altitude <= 0:
            raise InvalidInputError(f"--eye {lat_deg:g},{lon_deg:g},{altitude:g} lies below the terrain there (the "
                                    f"altitude is metres above the sphere of {sphere}): the eye at or beyond the "
                                    f"planet's centre (altitude <= -{radius:g} m, {the}{sphere})")
        if radius + altitude > _MAX_COORDINATE and eye_used:  # look_from's bound, which named the library's 'radius'
            where = "--eye altitude" if altitude > _MAX_COORDINATE and args.eye is not None else \
                f"{sphere} + the --eye altitude"
            default = "" if args.eye is not None else f" (the default --eye, 3 x {sphere})"
            raise InvalidInputError(f"{where} must keep the eye within {_MAX_COORDINATE:g} m of the centre; got "
                                    f"{sphere} {radius:g} + altitude {altitude:g} m{default}")
        return altitude

    # before the work, on the earth's sphere without --radius: an INPUT of a smaller body (Mars, the Moon) is checked
    # again once read, on its own
    altitude = eye_altitude(radius, "--radius")
    if not (0.0 <= args.tilt < 90.0):
        raise InvalidInputError(f"--tilt must lie in [0, 90) degrees; got {args.tilt}")
    lo, hi = render._VIEW_ANGLE_RANGE  # VTK's: the --png render's camera takes no other
    if not lo <= args.view_angle <= hi:  # NaN too
        raise InvalidInputError(f"--view-angle must be a vertical field of view in [{lo:g}, {hi:g}] degrees; got "
                                f"{args.view_angle:g}")
    if args.no_camera and png is None:  # (after their values, which are named first)
        _refuse_unused(unused, "the camera or a --png render (with --no-camera the mesh is refined by the geometric "
                       "error alone)", "with --no-camera and no --png")
    elif "clip" not in metrics and png is None:
        # the view's direction, angle and aspect make the clip metric's (and the culling's) planes alone; the
        # distance metric reads the eye's position alone: `--metrics geometric,distance --tilt 30` wrote the mesh
        # that run writes without --tilt, and said nothing. The geometric metric reads nothing of the view (each
        # node's own error, kernels/bounds.py refine_node): `--metrics geometric --eye 46,9,400000` wrote the mesh
        # of `--metrics geometric`, and the message of the others said the geometric metric read the eye
        got = f"with --metrics {args.metrics} and no --png"
        if "distance" in metrics:
            _refuse_unused([o for o in unused if o != "--eye"], "the clip metric or a --png render (the distance "
                           "metric reads only the --eye position)", got)
        elif unused:  # the geometric metric alone
            view = [o for o in unused if o != "--eye"]
            parts = ["--eye applies only with the distance or clip metric or a --png render"] * ("--eye" in unused)
            if view:
                parts.append(f"{_option_list(view)} {'apply' if len(view) > 1 else 'applies'} only with the clip "
                             "metric or a --png render")
            them = "it" if len(unused) == 1 else "them"
            raise InvalidInputError(f"{'; '.join(parts)} (the geometric metric measures each node's own error, "
                                    f"nothing of the view); got {them} {got}")
    if png is not None:
        render.require_offscreen()
    # the image before the work: a missing, unreadable or non-image --texture failed after the globe was built
    # decoded once for both drapes; a JPEG used as is (picture) is embedded as its file's bytes, not a PNG 3x larger
    pixels, picture, placement = _texture_image(args.texture) if args.texture else (None, None, None)
    if args.texture is not None and out is not None:  # a textured OBJ's .mtl and image, named as drape_texture's
        _check_side_files("--output", out, _drape_side_files(out, picture is not None),
                          {"INPUT": args.input, "--texture": args.texture}, {"--png": png})
    if png is not None and pixels is not None:  # the render holds the draped texture too (16 bytes a texel)
        render._check_render_budget(args.size[0], args.size[1], "--size", texture=pixels.shape,
                                    smaller_texture="a smaller --texture image (resampled to fewer pixels)")

    progress.stage("load", f"loading {args.input or 'the embedded ETOPO 2022 relief (20 arc-minutes)'}")
    lat, lon, elevation, body = _load_grid(args.input, args.height_unit, args.nodata) if args.input else \
        (*load_global_relief(), None)
    progress.done(f"{elevation.shape[0]} x {elevation.shape[1]} lat/lon grid,")
    on, sphere = "", "--radius"
    if args.radius is None and body is not None:  # Mars, the Moon: meshed on the earth's sphere (Mars 1.88 x too big)
        sphere = "the radius of INPUT's CRS"
        radius = _radius_value(body.radius, sphere)
        named = f" {body.name!r}" if body.name.lower() not in ("", "its", "unknown") else ""
        on = (f" on a sphere of radius {radius:.10g} m (the mean radius of INPUT's CRS's ellipsoid{named}, not the "
              "earth's; --radius to change)")
        altitude = eye_altitude(radius, sphere)

    progress.stage("build", f"resampling onto 6 x {args.face_size}^2 nodes{on} and building the hierarchy")
    try:
        globe = Globe.from_latlon(elevation, lat, lon, face_size=args.face_size, radius=radius,
                                  exaggeration=args.exaggeration, device=args.device)
    except InvalidInputError as exc:
        if args.input is not None and exc.not_global:
            raise InvalidInputError(_not_global(args.input, lat, lon)) from None
        raise
    progress.done(f"on {globe.device},")

    aspect = args.size[0] / args.size[1]
    camera = look_from(lat_deg, lon_deg, altitude, tilt=args.tilt, heading=args.heading, aspect=aspect,
                       fov=math.radians(args.view_angle),
                       radius=radius, max_radius=globe.radius + float(globe.heights.max())) if eye_used else None
    if camera is not None:  # the eye meshes or renders: above the terrain there, named by --eye
        try:
            globe._check_eye(camera.eye)
        except InvalidInputError as exc:
            unresolved = _unresolved_altitude(radius, altitude)
            if unresolved:  # was "lies inside the planet ... |eye| = 1e20 m, the surface 1e20 m, terrain +0.0 m"
                # (--radius 1e20 --eye 0,0,1000); over terrain below the sphere such an eye is taken, as before
                raise InvalidInputError(f"--eye altitude must be resolved against {sphere} in float64 (|altitude| at "
                                        f"least {unresolved}); got altitude {altitude:g} m, {sphere} {radius:g} m: "
                                        "the eye rounded onto the sphere, below the terrain there") from None
            raise InvalidInputError(f"--eye {lat_deg:g},{lon_deg:g},{altitude:g} lies below the terrain there (the "
                                    f"altitude is metres above the sphere of {sphere}): {exc}") from None
    shapes = f"{bounds}s, " if shaped else ""
    progress.stage("mesh", f"refining: error {args.error:g}, {shapes}metrics {','.join(metrics)}")
    # the camera only where a metric reads it (shaped): with the geometric metric alone it refined nothing, yet the
    # mesh recorded its eye (metadata "eye"), and a glTF was stored relative to that eye, not to the mesh's centre
    # (1 m of float32 rounding off on the globe of `--metrics geometric`, another file with --png than without)
    mesh = globe.mesh(error=args.error, camera=camera if shaped else None, bounds=bounds,
                      metrics=metrics, cull=not args.no_cull)
    progress.done(f"{_counted(len(mesh.faces), 'triangle')}, {_counted(len(mesh.vertices), 'vertex', 'vertices')}")
    if len(mesh.faces) == 0 and camera is not None:  # an eye above the terrain looking down sees it: the --tilt
        # looks past the limb; the sphere through the highest node lies within asin(top / |eye|) of straight down,
        # and the view's lowest edge half the --view-angle below its centre: a --tilt below their sum sees (a part
        # of) that sphere
        top = globe.radius + float(globe.heights.max())
        limb = math.degrees(math.asin(min(1.0, top / float(np.linalg.norm(camera.eye)))))
        lowest = args.tilt - args.view_angle / 2
        where = f"--eye {lat_deg:.12g},{lon_deg:.12g},{altitude:.12g}"
        if lowest < limb:  # it sees that sphere but not the terrain below it (at its limb): no bound to name
            raise InvalidInputError(f"the view sees no part of the globe (every triangle was clipped) from {where} "
                                    f"with --tilt {args.tilt:g}; lower --tilt, widen --view-angle, bring the --eye "
                                    "closer, or pass --no-cull")
        raise InvalidInputError(
            f"the view sees no part of the globe (every triangle was clipped): from {where} the globe lies within "
            f"{limb:.4g} degrees of straight down, and the view's lowest edge looks {lowest:.4g} degrees from it "
            f"(--tilt {args.tilt:g} less half the --view-angle {args.view_angle:g}); lower --tilt {args.tilt:g} "
            f"below {limb + args.view_angle / 2:.4g} degrees, widen --view-angle, bring the --eye closer, or pass "
            "--no-cull")

    textured = None
    keeps_texture = out is not None and out.suffix.lower() in (".glb", ".gltf", ".obj")
    if pixels is not None:
        mesh.visual.vertex_colors = _drape_colors(mesh.vertices, pixels, placement)
        # the render draws the image itself (vertex colours blurred it to the mesh's triangles: far from the eye,
        # whole countries)
        if keeps_texture or png is not None:
            textured = _drape_texture(mesh, pixels, picture, placement)
    else:
        heights = globe.heights.reshape(-1)[mesh.metadata["node_entry"]] / args.exaggeration
        mesh.visual.vertex_colors = elevation_colors(heights)

    image = None
    if png is not None:
        progress.stage("render", f"rendering {args.size[0]}x{args.size[1]} off-screen from the eye")
        image = render_view(textured if textured is not None else mesh, camera, window_size=args.size)
        progress.done()

    # no mesh file for a render-only run (--png without -o)
    if out is not None:
        progress.stage("write", f"writing {out}")
        metadata = {
            "generator": "stepterrain globe",
            "input": args.input or "embedded ETOPO 2022 global relief, 20 arc-minutes",
            **({"height_unit": args.height_unit} if args.height_unit is not None else {}),
            "face_size": args.face_size,
            "error": args.error,
            "metrics": ",".join(metrics),
            "exaggeration": args.exaggeration,
        }
        if radius != _EARTH_RADIUS:  # the sphere's radius: --radius's, or that of the body INPUT's CRS names
            metadata["radius"] = radius
        if shaped:  # the bounding shapes the distance and clip metrics measured
            metadata["bounds"] = bounds
        if shaped:  # the eye the mesh was refined for (with --no-camera or the geometric metric alone it only places
            # a --png: the default eye was recorded for `--metrics geometric`, which reads nothing of it)
            metadata["eye_lat_lon_alt"] = [lat_deg, lon_deg, altitude]
        mesh.metadata.pop("node_entry", None)
        # a view's glTF stored relative to the eye its mesh records (metadata["eye"]), as save_mesh's default takes
        # it: relative to the centre of the mesh, which spans thousands of km (the coarse triangles at the view's
        # border and on the far side), float32 moved the vertices under an eye 100 m up by 0.3 m; relative to the
        # eye each is stored within float32's rounding of its own distance from it. An eye farther than one diagonal
        # of the mesh's bounds keeps the centre: passed as origin whatever its distance, an eye 1e12 m out rounded
        # the vertices by 32 km, one 1e29 m out put every vertex on one point
        written = export.save_mesh(textured if textured is not None and keeps_texture else mesh, out,
                                   metadata=metadata)
        progress.done(_size(written))
    if image is not None:
        progress.stage("write_png", f"writing {png}")
        export._save_image(image, png, reused=False)
        progress.done(_size(png))
    return 0
