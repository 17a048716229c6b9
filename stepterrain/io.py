"""Elevation files -> :class:`~stepterrain.terrain.Terrain`: NumPy (.npy, .npz), PNG heightmaps and terrain tiles,
GeoTIFF and the other rasters GDAL reads (.asc, .hgt, .img, .vrt, ...: rasterio), also gzipped, zipped or by URL.

Shared input room of every capability (papers 000-004); the embedded Big Tujunga SRTM DEM is the default.

    >>> import stepterrain as st
    >>> st.sample_dem().shape
    (643, 1197)
"""

from __future__ import annotations

import contextlib
import contextvars
import gzip
import importlib.resources
import math
import os
import re
import shlex
import threading
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path, PurePath, PurePosixPath
from typing import Any, BinaryIO, Literal, NamedTuple, TypeVar

import numpy as np
from numpy.typing import NDArray

from ._compaction import WHOLE_RASTER_HINT, check_budget
from ._files import URL_FILE_SYSTEMS, GdalPath, _restored, as_path, gdal_path, local_archive, require_regular_file
from ._warning_filters import FILTERS
from .errors import (
    DataFileError,
    InvalidInputError,
    MissingDependencyError,
    StepTerrainError,
    caller_stacklevel,
    counted,
)
from .terrain import (
    FLOAT32_MAX,
    Terrain,
    as_terrain,
    crop_of_nodata,
    first_index,
    unwrapped_longitudes,
)

__all__ = ["load_dem", "sample_dem", "describe_dem", "SUPPORTED_EXTENSIONS", "HEIGHT_ENCODINGS", "EARTH_RADIUS_M",
           "COMMON_NODATA"]

#: Raster formats :func:`load_dem` reads through rasterio (GDAL), as it reads a GeoTIFF, by extension: the format's
#: name for messages. Dispatch is by this list, not by trying GDAL on any file: a folder of tiles holds sidecars GDAL
#: opens too (a .bil's .hdr, a .prj, an .aux.xml), and an unknown extension says what is read.
GDAL_FORMATS: dict[str, str] = {
    ".tif": "a GeoTIFF", ".tiff": "a GeoTIFF", ".asc": "an ESRI ASCII grid", ".hgt": "an SRTM tile",
    ".img": "an ERDAS Imagine raster", ".vrt": "a GDAL virtual raster (VRT)", ".bil": "an ESRI BIL raster",
    ".flt": "an ESRI float grid", ".dem": "a USGS DEM", ".dt0": "a DTED tile", ".dt1": "a DTED tile",
    ".dt2": "a DTED tile",
}
#: Rasters :func:`load_dem` reads from a local gzip file of one (``N46E007.hgt.gz``, ``dem.tif.gz``), through GDAL's
#: ``/vsigzip/`` (:func:`gzip_member`): those of :data:`GDAL_FORMATS` but a .bil or .flt (GDAL reads no .hdr beside a
#: gzip: it cannot open them) and a .vrt (its sources are named beside it).
GZIP_FORMATS: tuple[str, ...] = tuple(ext for ext in GDAL_FORMATS if ext not in (".bil", ".flt", ".vrt"))
#: File extensions :func:`load_dem` reads (lower case; matching is case-insensitive).
SUPPORTED_EXTENSIONS: tuple[str, ...] = (".npy", ".npz", ".png", *GDAL_FORMATS)

#: The elevation encodings of RGB web-map terrain tiles :func:`load_dem` decodes (its ``height_encoding``): the
#: formula from a pixel's 8-bit red, green and blue to its height in metres.
HEIGHT_ENCODINGS: dict[str, str] = {
    "terrain-rgb": "Mapbox Terrain-RGB: -10000 + (R * 65536 + G * 256 + B) * 0.1",
    "terrarium": "Mapzen/AWS Terrarium: R * 256 + G + B / 256 - 32768",
}

#: Mean earth radius (IUGG R1, metres) used to turn geographic degrees into local metres.
EARTH_RADIUS_M = 6371008.8
#: WGS 84 semi-major axis (m) and flattening: the ellipsoid the local metres of a geographic grid are checked against.
_WGS84_A, _WGS84_F = 6378137.0, 1 / 298.257223563
#: Worst relative error of a geographic grid's local metres (scale along a parallel or a meridian, or cell area)
#: against WGS 84 over its rows beyond which :func:`load_dem` warns.
_LOCAL_METRES_TOLERANCE = 0.01
#: PROJ names of the Mercator projections, whose metres are ground metres times about 1/cos φ (EPSG:3857 is the CRS
#: of web map and terrain tiles): the map-scale warning of a projected grid names them.
_MERCATOR = frozenset({"merc", "webmerc"})
#: Nodes along each axis at which a projected grid's map scale is measured (:func:`_check_projected_metres`), and the
#: ground metres between the two neighbours of each, along x and along y, that measure it.
_SCALE_SAMPLES, _SCALE_STEP_M = 7, 100.0
#: Largest shift, in cells, that dropping a geotransform's rotation terms may make to any node of the grid for them
#: to be taken as float noise (:func:`negligible_rotation`) rather than refused as a rotated grid.
_ROTATION_TOLERANCE = 1e-6
#: Heights spanning more than this many times a grid's width and height, georeferenced without a CRS inside longitudes
#: and latitudes, make :func:`load_dem` warn that its coordinates look like degrees read as metres.
_DEGREES_RELIEF = 100.0

_SAMPLE_NAME = "big_tujunga_srtm_30m_utm11n.npz"
_GENERIC_KEYS = ("heights", "elevation", "z")
#: .npz keys that georeference the heights, refused without a 'transform' or a 'lat' and 'lon' pair to read them by
#: (they were ignored, the grid read as 1 m cells at (0, 0)).
_NPZ_GEOREFERENCE = ("crs", "dx", "dy", "dx_m", "dy_m", "spacing", "origin", "x", "y", "lat", "lon", "units_xy",
                     "cellsize", "xllcorner", "yllcorner", "bounds", "extent")  # fmt: skip
#: .npz keys that would scale the stored heights (GDAL's band scale and offset, CF's scale_factor and add_offset:
#: value * scale + offset), which load_dem does not read: refused when they change the values (they were ignored, an
#: int16 grid of decimetres read as metres, 10 times too high).
_NPZ_SCALING = {"scale": 1.0, "offset": 0.0, "scale_factor": 1.0, "add_offset": 0.0, "scales": 1.0, "offsets": 0.0}
#: 2-D .npz members that are never the heights (an archive of one unnamed array and a 'mask' reads the array).
_NPZ_NOT_HEIGHTS = ("transform", "mask", "valid")
_NPY_MAGIC = b"\x93NUMPY"
#: Whether :func:`nodata_as_nan` reads a grid of nodata only as all NaN instead of refusing it: set by
#: :func:`read_dem`'s ``nodata_only`` for its own read (this thread or task only).
_NODATA_ONLY: contextvars.ContextVar[bool] = contextvars.ContextVar("stepterrain_nodata_only", default=False)
#: :func:`load_dem`'s ``nodata``: the values the caller marks missing besides the file's own nodata and mask, set by
#: :func:`read_dem` for its own read (this thread or task only; see :func:`check_nodata`).
_GIVEN_NODATA: contextvars.ContextVar[tuple[float, ...]] = contextvars.ContextVar("stepterrain_given_nodata",
                                                                                  default=())
_ZIP_MAGIC = b"PK\x03\x04"
_EMPTY_ZIP_MAGIC = b"PK\x05\x06"  # a zip with no members starts at its end-of-directory record: np.savez()
_GEOGRAPHIC_CODES = frozenset({"EPSG:4326", "EPSG:4269", "EPSG:4258", "EPSG:4979", "OGC:CRS84", "CRS:84"})
_US_FOOT_M = 1200 / 3937
#: Height units a file (or ``load_dem(height_unit=...)``) may name -> metres per unit. Keys are lower case, as GDAL
#: band units, PROJ and EPSG write them; a name is matched ignoring case and surrounding blanks and dots.
_HEIGHT_UNITS = {
    **dict.fromkeys(("m", "metre", "meter", "metres", "meters"), 1.0),
    **dict.fromkeys(("km", "kilometre", "kilometer", "kilometres", "kilometers"), 1000.0),
    **dict.fromkeys(("dm", "decimetre", "decimeter", "decimetres", "decimeters"), 0.1),
    **dict.fromkeys(("cm", "centimetre", "centimeter", "centimetres", "centimeters"), 0.01),
    **dict.fromkeys(("mm", "millimetre", "millimeter", "millimetres", "millimeters"), 0.001),
    **dict.fromkeys(("ft", "foot", "feet", "international foot", "international feet", "intl ft"), 0.3048),
    **dict.fromkeys(
        ("us-ft", "ftus", "ft_us", "us_ft", "us ft", "us survey foot", "us survey feet", "foot_us", "us_survey_foot",
         "foot (us survey)", "feet (us survey)", "us foot", "us feet"),
        _US_FOOT_M,
    ),  # fmt: skip
}


#: GDAL colour interpretations of colour image bands (GeoTIFF): refused as elevation, as are alpha and spectral bands.
_COLOUR_BANDS = frozenset(
    ("palette", "red", "green", "blue", "hue", "saturation", "lightness", "cyan", "magenta", "yellow", "black", "Y",
     "Cb", "Cr")
)  # fmt: skip
_KNOWN_UNITS = "m, km, dm, cm, mm, ft (international foot), US survey foot"


# ---------------------------------------------------------------------------------------------- public API
def load_dem(
    path: str | os.PathLike[str], *, band: int = 1, height_unit: str | None = None,
    crop: Sequence[float] | None = None, height_encoding: str | None = None,
    nodata: float | Sequence[float] | None = None,
) -> Terrain:
    """Read an elevation raster into a :class:`Terrain`, choosing the reader by file extension.

    Parameters
    ----------
    path : str or path-like
        ``.npy`` (one (H, W) array), ``.npz`` (heights under the first 2-D key of ``heights``, ``elevation``
        and ``z``, or the archive's one 2-D array besides ``mask``/``valid``; a ``transform`` beside them
        georeferences them, as in the layout of ``shared/data``: ``elevation``, ``transform``, ``crs``, optional
        ``dx_m``/``dy_m``, ``units`` (the heights' unit) and ``units_xy`` (the transform's unit where the CRS is
        not geographic: degrees, "deg", make it geographic; a length unit as for the heights, a note after it
        allowed ("metres (EPSG:32611)"), is read where no CRS states a unit, none or one PROJ cannot read, else
        must name the CRS's own unit, any foot for one in feet); without a ``transform``, 1-D ``lat`` and ``lon`` axes
        of evenly spaced node degrees (to 0.1 % of the step, or to the rounding of a float32 axis), one per row and
        column, georeference them as geographic, the layout of the global relief grids (``lon`` may cross the
        antimeridian, [179.5, -179.5, ...]: a step of 1 degree, read as [179.5, 180.5, ...]); a ``nodata`` number,
        0-d or in a one-element array, marks missing cells, and so do a boolean ``mask`` (True = missing, as in a
        NumPy masked array: ``np.savez(..., elevation=m.data, mask=m.mask)``) and ``valid`` (True = present) of the
        heights' shape (or 0-d, for every cell: ``m.mask`` is a 0-d False when no cell is masked), either or both),
        ``.png`` (8- or 16-bit greyscale heightmap, values are heights, a 2- or
        4-bit one's scaled to 0-255 as Pillow reads them; a transparent grey value (tRNS), else the grey band's
        ``NoDataValue`` in GDAL's ``dem.png.aux.xml`` beside it, and, in 8-bit grey + alpha, alpha 0 mark missing
        cells, as GDAL reads them (the NoDataValue text as GDAL's CPLAtof reads it, ``7abc`` as 7, ``abc`` as 0, with a
        warning; a fraction, ``7.5``, cut to the integer band's 7); 16-bit grey + alpha is refused: Pillow reads it as
        8 bits; an RGB(A) web-map terrain tile with ``height_encoding``, below),
        ``.tif``/``.tiff`` (GeoTIFF, needs rasterio) or another raster GDAL reads, through rasterio as a GeoTIFF is
        read (its georeferencing, CRS, nodata, scale and offset, unit, a .prj beside it, ``band`` and ``crop``
        windows alike; below, what is said of a GeoTIFF holds for them): ``.asc`` (ESRI ASCII grid; ``xllcorner``
        and ``xllcenter`` both place node (0, 0) at the top-left cell's centre; its CRS from the ``.prj`` beside
        it, none without one; a local one, gzipped or in a local zip, whose values do not match its header is
        refused where GDAL reads it cut or shifted without a word: more values than nrows x ncols, a first row not
        ending at a line's end, the very last value missing, an indented header line; a byte-order mark, spaces or
        a blank line before its first keyword are named), ``.hgt`` (SRTM tile, placed by its name
        ``N34W119.hgt``, -32768 voids as nodata),
        ``.img`` (ERDAS Imagine), ``.vrt`` (GDAL virtual raster, its sources read where it names them), ``.bil``
        and ``.flt`` (ESRI band-interleaved and float grids, with their ``.hdr``), ``.dem`` (USGS DEM) and
        ``.dt0``/``.dt1``/``.dt2`` (DTED): :data:`GDAL_FORMATS`. Another GDAL format (netCDF ``.nc``, a Surfer
        ``.grd``, an ``.xyz`` grid, ...) is refused as an unknown extension, the message giving the ``gdal_translate
        -of GTiff`` that converts it (a local ``.tar``/``.tgz``: the ``/vsitar/`` path of a file inside). These are
        read through GDAL's virtual file systems too, as GDAL tools take them, by the extension of the file named
        inside (a ``.hgt`` in a zip is placed by its name, its -32768 voids nodata, as the plain tile):
        ``/vsizip/srtm.zip/N46E007.hgt``
        (``/vsizip//abs/tiles.zip/dem.tif`` for an absolute path), ``/vsigzip/dem.tif.gz``, ``/vsitar/...``,
        ``/vsicurl/https://...`` and a URL, mapped as rasterio maps it (``https://``/``http://``/``ftp://`` to
        ``/vsicurl/``, ``s3://`` to ``/vsis3/``, ``gs://`` to ``/vsigs/``, ``az://`` to ``/vsiaz/``, ...: GDAL's
        ``GDAL_HTTP_*``/``AWS_*`` settings apply); ``source`` is then the inner file's name, no ``.prj`` beside it is
        looked for but in a local zip (``/vsizip/`` of a zip file: a world file's ``.prj`` beside the TIFF in the
        zip), and ``.npy``/``.npz``/``.png`` are refused there (read from local files only). A local ``.zip``
        is read as the ``/vsizip/`` path of the one raster of :data:`GDAL_FORMATS` it holds (an SRTM download,
        ``N46E007.SRTMGL1.hgt.zip``; its sidecars beside it in the zip, a TIFF's ``.tfw`` and ``.prj`` too); one
        of several is refused, naming them
        (``/vsizip/<zip>/<name>`` picks one). A local single-file gzip of one of :data:`GZIP_FORMATS` (an SRTM tile as
        AWS Terrain Tiles serve it, ``N46E007.hgt.gz``, placed by the inner name; ``dem.tif.gz``, ``dem.asc.gz``) is
        read as the file inside, through its ``/vsigzip/`` path (:func:`gzip_member`; ``source`` names the inner
        file): first checked whole (its CRC-32 and length; a cut short or corrupt one, or one that is no gzip, is
        refused, a ``/vsigzip/`` path of a local file too); of the files beside it only the inner file's ``.prj``
        (``dem.prj`` or ``dem.tif.prj`` beside ``dem.tif.gz``) is read, as beside the plain file (GDAL reads none
        through a gzip: a world file beside a gzipped TIFF without georeferencing of its own is refused, an
        ``.aux.xml`` is not read); a ``.bil``/``.flt`` (its ``.hdr``), ``.vrt``, ``.npy``/``.npz``/``.png`` or
        ``.tar`` in one is refused (gunzip it).
    band : int
        1-based raster band to read; GeoTIFF and the other GDAL rasters only (the other formats hold one band). It
        must be a grey or undefined band; the file's mask (nodata, an internal mask or an alpha band) marks its
        missing cells.
    height_unit : str, optional
        The heights' length unit, overriding the one the file names (if any): "m", "ft", "US survey foot", "km",
        "cm", ... (see Returns). For a file that names none (a PNG, a plain array) or one not on that list
        ("metres above sea level"): ``height_unit="m"`` takes the heights as stored.
    crop : (xmin, xmax, ymin, ymax), optional
        Keep only the nodes inside this extent: the Terrain ``load_dem(path).crop(crop)`` gives (see
        :meth:`Terrain.crop <stepterrain.terrain.Terrain.crop>`: the extent is in the grid's own coordinates, those
        described under Returns, a geographic DEM's local metres placed by its whole grid). A GeoTIFF's whole grid is
        then placed from its header and only the window of those nodes is read, its size checked against the memory
        budget instead of the whole file's: a small crop of a DEM over the budget (its warnings are the whole
        read's, but that of a grid without a CRS that looks like degrees weighs the crop's heights; heights beyond
        float32 outside the window go unread). Other formats are read whole first.
    height_encoding : str, optional
        Read a ``.png`` as an 8-bit RGB or RGBA web-map terrain tile whose colours encode heights in metres (any
        case; :data:`HEIGHT_ENCODINGS`): ``"terrain-rgb"``, Mapbox Terrain-RGB, -10000 + (R·65536 + G·256 + B)·0.1;
        ``"terrarium"``, Mapzen/AWS Terrarium, R·256 + G + B/256 - 32768. Decoded exactly in float64 (Terrain-RGB's
        0.1 m steps as (code - 100000) / 10) and kept as float32, as all heights are: exact to the code within
        ±10 km for Terrain-RGB, everywhere for Terrarium. The heights are metres (``height_unit`` "m"; another
        ``height_unit`` is refused). The encodings have no nodata value: a transparent pixel
        (alpha 0, or the PNG's transparent colour) is a missing cell. A palette PNG reads through its palette. A
        world file beside the tile (``tile.pgw``, ``tile.pngw``, ``tile.wld``) places it as GDAL reads one, with
        the CRS of a ``.prj`` beside it (``EPSG:3857`` for a web-map tile, whose scale warning follows); without one
        it is unreferenced, as a greyscale PNG is. Without ``height_encoding`` an RGB PNG is refused (the message
        names the encodings); with it a greyscale or 16-bit-per-channel PNG, or a file that is no local PNG, is.
    nodata : float or sequence of floats, optional
        Value(s) marking missing cells besides the file's own nodata value and mask, which still apply (the CLI's
        ``--nodata``): for a file whose nodata value was lost or never declared (``nodata=-9999``, or ``nodata=(-9999,
        -32768)``), as ``gdal_edit.py -a_nodata`` would declare it, without editing the file. Compared, as GDAL compares
        a nodata value, with the values as stored: a GeoTIFF band's before its scale and offset, exactly, in the band's
        own dtype (a float32 band's cells with the float32 rounding of the value, an integer band's with the value
        itself: 0.5 or -99999 marks no cell of an int16 one, and a warning says so); a PNG's grey values as Pillow reads
        them (0-255, 0-65535), an RGB terrain tile's decoded heights (Terrarium's void, black, is -32768). Its cells are
        NaN and no warning of an undeclared nodata (see Warns) names that value; a value that no cell holds changes
        nothing. NaN and ±inf are accepted and change nothing (non-finite cells are nodata anyway). Not a real number (a
        string, a bool) is refused.

    Returns
    -------
    Terrain
        ``kind == "grid"``, float32 ``heights`` with NaN for nodata (a file's nodata value and any
        non-finite value), rows as stored: north-first for the usual north-up file, south-first with
        ``spacing`` dy > 0 for a south-up one (a positive pixel height), placed right either way.
        Georeferenced files: node (0, 0) is the centre of the top-left cell (first stored row), ``origin`` its
        world position and ``spacing`` = (dx, -dy) from the geotransform,
        ``crs`` the file's CRS ("EPSG:32611"; for a TIFF georeferenced without one, by a world file ``.tfw``, the CRS
        of a ``.prj`` beside it, ``dem.prj`` or ``dem.tif.prj``, as GIS software writes it and GDAL does not read it
        for a TIFF). A geographic CRS (degrees) is converted to local metres with one spacing,
        exact in an equidistant cylindrical projection on a sphere of radius :data:`EARTH_RADIUS_M` (another body's
        CRS, Mars or the Moon (IAU_2015:49900, ``+R=3396190``): its ellipsoid's mean radius a·(1 - f/3), its errors
        below measured against that ellipsoid; angles in grads (EPSG:4807), longitudes from another prime meridian
        (Paris) and longitudes on a west-positive axis (``AXIS["Longitude",WEST]``, as planetographic CRSs have them)
        are read as degrees east of Greenwich first) (dx = R·cos φc·Δλ at
        the latitude φc halfway between the first and last node rows, dy = R·Δφ; an .npz's ``dx_m``/``dy_m`` override
        them, and R and the standard parallel become those they are exact with, or no ``crs``, with a warning, for more
        metres per degree of longitude than of latitude): ``origin`` = (0, 0) at the top-left node, ``crs`` that
        projection's PROJ definition and ``source`` names the node's longitude and latitude. Against true WGS 84 ground
        distances and areas these metres err by the sphere (north-south +0.56 % at the equator to -0.45 % at the poles,
        east-west -0.11 % to -0.45 %) and by the change of cos φ away from φc (east-west, about tan φc times half the
        latitude span in radians): the worst scale or cell-area error over a grid 0.5 (1) degree tall is 0.56 (0.56) %
        at the equator, 0.71 (1.1) % at 45°, 1.3 (2.0) % at 60°, 2.4 (3.9) % at 75°, and a warning names it when it
        passes 1 % (see Warns); a row of nodes at a pole warns always. A projected CRS's coordinates are taken as
        ground metres (one whose map scale errs by more than 1 % over the grid warns, see Warns); one in another
        linear unit
        (EPSG:2229 counts US survey feet), or a local engineering CRS (a site grid, LOCAL_CS) in one, has
        ``spacing`` and ``origin`` converted to metres, ``crs`` the same projection (or site grid) in metres
        ("EPSG:26945") and ``source`` names the unit; looking an EPSG code's unit up needs
        rasterio (without it an .npz keeps its CRS's units, unless ``units_xy`` names them). An .npz's
        ``units_xy`` in a unit other than the metre converts its coordinates so too when no CRS states their unit,
        ``crs`` kept as given and ``source`` naming ``units_xy``. Heights are taken as stored unless their unit is
        named (``height_unit``, else a GeoTIFF band's unit, an .npz ``units``, or the vertical unit of a compound
        CRS: EPSG:26911+6360 is NAVD88 height in US survey feet, and ``crs`` is then the horizontal part), in
        which case they become metres: metre, kilometre, decimetre, centimetre, millimetre (m, km, dm, cm, mm),
        international foot (ft, foot, feet: 0.3048 m) and US survey foot (us-ft, ftUS: 1200/3937 m), in the
        spellings GDAL, PROJ and EPSG use, any case; a compound CRS's vertical unit outside this list (British
        foot, Clarke's foot) converts by the metres per unit its WKT states; another unit is refused (see Raises).
        A grid converted to metres whose heights' unit is not named warns that they were kept as stored. Plain
        arrays, PNGs and GeoTIFFs without a geotransform: ``spacing`` (1, -1), ``origin`` (0, 0), ``crs`` None (a
        GeoTIFF's CRS without a geotransform is ignored, with a warning; one referenced by ground control points or
        RPCs instead is refused, see Raises). ``source`` is the file name.

    Warns
    -----
    UserWarning
        At the caller's line: a geographic grid whose local metres err by more than 1 % against WGS 84 in some row
        (east-west or north-south scale, or cell area; the message names the error, the node latitudes and a
        projected CRS to reproject it to, e.g. ``gdalwarp -r bilinear -dstalpha -t_srs EPSG:32613``, -dstalpha
        marking the cells outside the grid missing); a grid in a projected CRS, whose
        metres are read as stored, that errs by more than 1 % in the same sense somewhere (x or y scale, or cell
        area, sheared too): a Mercator one (EPSG:3857, the CRS of web map and terrain tiles; EPSG:3395, ...) away
        from the equator (its metres are ground metres times about 1/cos φ: 1.41 at 45°), a continent-wide Albers or
        Lambert conformal conic one at its edges (EPSG:5070 errs by 1.7 % at 50° N), a sinusoidal one (MODIS) far
        from its central meridian, a polar stereographic one away from its true-scale latitude (EPSG:3413 and
        EPSG:3031 by 3 % at the poles); a UTM grid of a zone's extent and a small local grid do not. It is measured
        through PROJ (so with rasterio only) at up to 7 x 7 nodes of the grid, its corners and edges included; the
        message names the worst node and its scales. Also: a grid converted to metres whose heights' unit is not named;
        a GeoTIFF CRS ignored for want of a geotransform; a greyscale PNG's world file (``.pgw``, ``.wld``) or
        ``.aux.xml`` geotransform, or a terrain tile's ``.aux.xml`` one, which is not read (the message gives the
        ``gdal_translate`` to a GeoTIFF, or a tile's to a world file, that keeps it); a PNG's ``.aux.xml`` NoDataValue
        that is no number (``7abc``, ``abc``), naming the value it was read as; cells no nodata value or mask
        marks that hold the lowest value of a signed integer (-32768 in int16, SRTM's void) or the lowest or highest
        of a float dtype (-3.4028235e+38 in float32, ArcGIS's NoData, or +3.4028235e+38, also kept in a float64
        grid), read as heights, counted and named with the nodata value to declare (a float64 grid's own extremes,
        -1.7976931348623157e+308, GDAL's and ArcGIS's Float64 NoData, lie beyond float32 and are refused, counted and
        named likewise: see Raises); cells no nodata value or mask marks that hold one of :data:`COMMON_NODATA`
        (-9999, -32767, -32768 in a wider dtype than int16, -99999, 1e+20, ...; a float32 value kept in a float64 grid
        too) lying far outside the other cells' values (beyond their lowest or highest by more than a quarter of
        their span, or no other value), read as heights, counted and named likewise with the other values' range
        (legitimate heights do not warn: the Dead Sea's -430 m, ocean depths to -11000 m, a trench's cells of -9999 m
        among other depths); a grid georeferenced without a CRS (or with one PROJ cannot read, kept as
        given: an .npz's ``crs="4326"``) whose coordinates look like degrees (nodes within x -180 to 360 and y -90 to
        90, heights spanning more than 100 times its width and height: read as metres, an SRTM tile was a needle
        centimetres wide), naming the CRS to give it.
        Also a GeoTIFF band's unit that is not the vertical unit of its compound CRS (metres in a file of
        EPSG:32633+6360, NAVD88 height in US survey feet): read in the band's unit, as GDAL reads it, the warning naming
        the ``height_unit`` that reads the CRS's; and a ``nodata`` value no cell of the file's dtype can hold (3.5 or
        -99999 in int16, 1e40 in float32), which marks no cell.

    Raises
    ------
    InvalidInputError
        Unknown extension (the message lists the supported ones; a local ``.gz`` of another file than
        :data:`GZIP_FORMATS`'s names them; a virtual path's or URL's inner file of
        ``.npy``/``.npz``/``.png``, or another extension, says what GDAL is asked to read), ``band`` not a valid band
        number, ``height_encoding`` not one of :data:`HEIGHT_ENCODINGS` (the message lists them) or given for a file
        that is no local PNG or with a ``height_unit`` other than the metre,
        ``height_unit`` not a known length unit (the message lists them), ``nodata`` not a real number nor a
        sequence of them, or a ``crop`` that
        :meth:`Terrain.crop <stepterrain.terrain.Terrain.crop>` refuses (its message after ``crop:``).
    DataFileError
        The file does not exist, cannot be read (a GDAL raster whose path is not UTF-8, as GDAL takes names; a
        virtual path or URL GDAL cannot open: a file missing from the zip, a gzip cut short or corrupt, a world
        file beside a gzipped TIFF without georeferencing,
        an unreachable URL, with GDAL's reason; a URL scheme GDAL has no file system for; a ``.zip`` holding no
        raster of :data:`GDAL_FORMATS`, or several), or is not elevation data (a colour image, another image format
        under a .png name, with ``height_encoding`` a greyscale PNG or one of 16 bits per channel or a world file
        that is not six finite numbers, a GeoTIFF band that is colour, alpha or other imagery, a 1-D array, text, an
        archive without a 2-D array, a rotated grid (rotation terms that move no node by more than 1e-6 of a cell over
        the grid, the float noise some tools write, are taken as 0), a geotransform that is not finite (NaN, inf), a
        geographic grid whose latitudes lie beyond ±90 or whose node longitudes span more than 360 degrees or lie
        beyond ±720, ``lat``/``lon`` axes not matching the heights or
        unevenly spaced,
        an .npz with keys that would georeference it (``crs``, ``dx``/``dy``, ``spacing``/``origin``, ``x``/``y``,
        one of ``lat`` and ``lon``, ...) but neither a ``transform`` nor both ``lat`` and ``lon``, an .npz
        ``nodata`` that is not one real number, an .npz ``units_xy`` that names no length unit nor degrees
        ("furlong") or a unit other than its CRS's (feet for EPSG:32611), an .npz in degrees with one of
        ``dx_m``/``dy_m`` or either not
        finite, non-zero metres, an .npz ``scale``/``offset`` (``scale_factor``/``add_offset``) of its
        heights other than 1/0 (not read: the heights are taken as stored), or a PNG's in its ``.aux.xml`` (as
        ``gdal_translate -of PNG`` writes a scaled band's), a ``mask`` or ``valid`` that is not a
        boolean array of the heights' shape, a .prj beside a GeoTIFF georeferenced without a CRS that is no CRS,
        nothing but nodata, a finite height beyond float32 (|z| < 3.4e+38; float64's lowest or highest value, or one
        value several cells hold, is named as an undeclared nodata: the message counts its cells and gives the
        nodata to declare, ``gdal_edit.py -a_nodata -1.7976931348623157e+308 dem.tif``, or through a ``.gz``, zip
        or URL the ``gdal_translate -a_nodata`` to a GeoTIFF; a scaled band's value as stored), a GeoTIFF band's scale
        that is 0 or not finite or offset that is not finite, heights
        in a unit that is not a known length unit:
        "degC", "meters above sea level"; ``height_unit`` overrides it), a ``.hgt`` not named by its south-west
        corner (``everest.hgt``: GDAL places a tile by its name, ``N27E086.hgt``, and reads no other) or not of a
        tile's size (cut short), an ESRI (or GRASS) ASCII grid (local, or in a local gzip or zip) holding fewer
        values than its header declares (GDAL refuses one cut short but read a missing last value as 0), or is a
        GeoTIFF
        georeferenced only by ground control points (GCPs) or rational polynomial coefficients (RPCs), which is
        not a regular grid until warped (``gdalwarp`` makes it one; the message gives the command).
    MissingDependencyError
        A GeoTIFF or another GDAL raster (``.asc``, ``.hgt``, ...) is given and rasterio is not installed.
    OutputTooLargeError
        The file's declared cells (with a GeoTIFF's ``crop``, its window's) exceed the memory budget
        (:func:`stepterrain.set_memory_budget`), checked from its header before reading. What is checked is the
        larger of the stored values and the float32 heights the Terrain keeps: cells x max(stored bytes per cell,
        4). That is a lower bound of what the read allocates at its peak: the stored band, a mask, and float32 or
        float64 working copies (nodata, a GeoTIFF's scale and offset, a height unit) live together for a moment,
        about 8-9 bytes per cell for 8-, 16- and 32-bit rasters, up to about 16 for float64 or scaled bands and 17
        for an RGB(A) terrain tile (``height_encoding``), so leave that much headroom.

    Examples
    --------
    >>> import numpy as np, pathlib, tempfile, stepterrain as st
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "ramp.npy"
    >>> np.save(path, np.arange(12.0).reshape(3, 4))
    >>> t = st.load_dem(path)
    >>> t.shape, t.spacing, t.heights.dtype.name
    ((3, 4), (1.0, -1.0), 'float32')
    >>> st.load_dem(path, crop=(1.0, 2.0, -2.0, -1.0)).heights.tolist()
    [[5.0, 6.0], [9.0, 10.0]]
    """
    return read_dem(path, band=band, height_unit=height_unit, crop=crop, height_encoding=height_encoding,
                    nodata=nodata)


def read_dem(
    path: str | os.PathLike[str], *, band: int = 1, height_unit: str | None = None,
    crop: Sequence[float] | None = None, option: str = "crop", refuse: Callable[[Terrain], None] | None = None,
    nodata_only: bool = False, height_encoding: str | None = None, nodata: float | Sequence[float] | None = None,
) -> Terrain:
    """:func:`load_dem`, its ``crop`` refusals named ``option`` (the CLI's "--crop") and, with ``crop``, ``refuse``
    called with the whole grid before it is cropped (for a GeoTIFF, a
    :meth:`~stepterrain.terrain.Terrain._geometry_only`: geometry and CRS, no heights), to refuse a crop the
    caller's own way before any pixel of it is read. ``nodata_only``: a grid of nodata only is read (all heights
    NaN, placed as any other) instead of refused as not elevation data: a batch's tile file of sea off a coast, an
    empty item (:mod:`stepterrain.batch`). ``nodata``: :func:`load_dem`'s, checked first (:func:`check_nodata`)."""
    given = check_nodata(nodata)
    token = _NODATA_ONLY.set(nodata_only)
    given_token = _GIVEN_NODATA.set(given)
    try:
        return _read_dem(path, band, height_unit, crop, option, refuse, height_encoding)
    finally:
        _GIVEN_NODATA.reset(given_token)
        _NODATA_ONLY.reset(token)


def check_nodata(nodata: Any, name: str = "nodata") -> tuple[float, ...]:
    """:func:`load_dem`'s ``nodata`` (``name`` in the message: the CLI's ``--nodata``) as a tuple of floats: () for
    None, one real number (a Python or NumPy int or float; a 0-d or 1-D array) or a sequence of them. A string, a
    bool, a complex or another object is an InvalidInputError naming ``name``, what it expects and what it got: a
    ``nodata="-9999"`` compared with no cell, silently. NaN and ±inf are kept (they match no finite cell; non-finite
    cells are nodata anyway)."""
    if nodata is None:
        return ()
    expected = f"{name} must be a real number or a sequence of real numbers (the values of missing cells)"
    values = list(nodata) if isinstance(nodata, (list, tuple)) or (
        isinstance(nodata, np.ndarray) and nodata.ndim == 1) else [nodata]
    if not values:
        raise InvalidInputError(f"{expected}, or None for none; got an empty {type(nodata).__name__}")
    out = []
    for value in values:
        if isinstance(value, np.ndarray) and value.ndim == 0:
            value = value[()]
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise InvalidInputError(f"{expected}; got {value!r} of type {type(value).__name__}")
        try:
            number = float(value)
        except OverflowError:  # an int beyond float64 (10**400): no cell of any dtype holds it
            raise InvalidInputError(f"{expected} within float64; got {value!r}") from None
        if isinstance(value, np.floating) and np.isfinite(value) and (math.isinf(number) or (number == 0.0) != (
                value == 0)):  # a long double beyond float64 became inf (marking nothing) or 0 (marking 0 m cells)
            raise InvalidInputError(f"{expected} within float64; got {value!r}, which float64 rounds to {number:g}")
        out.append(number)
    return tuple(dict.fromkeys(out))


def recorded_nodata(nodata: Sequence[float]) -> list[float]:
    """The ``nodata`` values (:func:`check_nodata`'s, the CLI's ``--nodata``) an output's metadata records: the finite
    ones, as floats. NaN and ±inf mark no cell (non-finite cells are nodata anyway), and JSON, having neither, wrote
    them as null: ``--nodata nan`` recorded ``[null]``, which reads as "no nodata value"."""
    return [float(v) for v in nodata if math.isfinite(v)]


def _read_dem(
    path: str | os.PathLike[str], band: int, height_unit: str | None, crop: Sequence[float] | None, option: str,
    refuse: Callable[[Terrain], None] | None, height_encoding: str | None = None,
) -> Terrain:
    """:func:`read_dem`, its ``nodata_only`` set."""
    band = check_band(band)
    if height_unit is not None:
        height_unit = check_height_unit(height_unit)
    if height_encoding is not None:
        height_encoding = check_height_encoding(height_encoding, height_unit)
    file = dem_path(path)
    ext = file.suffix.lower()
    if isinstance(file, GdalPath):  # GDAL reads it, by the extension of the file inside (a URL's path)
        if ext not in GDAL_FORMATS:
            raise InvalidInputError(_virtual_refusal(file))
        check_gzip(file)  # a local .gz (N46E007.hgt.gz, /vsigzip/dem.tif.gz): whole, or refused
    elif ext not in SUPPORTED_EXTENSIONS:
        if os.path.isdir(file):  # `steps tiles/` said "unknown DEM extension '(none)'"
            raise DataFileError(f"DEM path {str(file)!r} is a folder; expected a DEM file "
                                f"({', '.join(SUPPORTED_EXTENSIONS)})")
        raise InvalidInputError(
            f"cannot read {str(file)!r}: unknown DEM extension {file.suffix or '(none)'!r}; "
            f"supported: {', '.join(SUPPORTED_EXTENSIONS)}{_unknown_extension_hint(file)}"
        )
    else:
        require_regular_file(file, "DEM file", "DEM path")
    if ext not in GDAL_FORMATS and band != 1:
        raise InvalidInputError(
            f"band applies to GDAL rasters only; {str(file)!r} holds one band, got band={band}"
        )
    if height_encoding is not None and (ext != ".png" or isinstance(file, GdalPath)):
        raise InvalidInputError(
            f"height_encoding applies to a local RGB PNG tile (Terrain-RGB or Terrarium); {str(file)!r} is no PNG; "
            f"got height_encoding={height_encoding!r}"
        )
    reader = {".npy": _load_npy, ".npz": _load_npz, ".png": _load_png}.get(ext)
    try:
        if height_encoding is not None:
            terrain = _load_encoded_png(file, height_encoding)
        elif reader is None:
            return _load_geotiff(file, int(band), height_unit, crop, option, refuse)
        else:
            terrain = reader(file, height_unit)
    except MemoryError as exc:  # a header declaring 400000 x 400000 cells (a sparse GeoTIFF of a few MB)
        if isinstance(exc, StepTerrainError):
            raise
        raise DataFileError(
            f"cannot read {str(file)!r}: expected elevation data that fits in memory; got {exc}"
        ) from exc
    if crop is None:
        return terrain
    if refuse is not None:
        refuse(terrain)
    try:
        return terrain.crop(crop)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{option}: {exc}") from None


#: Rasters GDAL reads (by its drivers' own extensions) that :func:`load_dem` does not: their refusal gives the
#: ``gdal_translate`` that writes a GeoTIFF of them. Elevation grids, not every image GDAL opens (a .jpg, a .pdf).
_CONVERTIBLE_FORMATS: dict[str, str] = {
    ".nc": "a netCDF grid", ".grd": "a grid (Surfer, GMT, NWT or R raster)", ".xyz": "an XYZ ASCII grid",
    ".sdat": "a SAGA grid", ".rst": "an Idrisi raster", ".ers": "an ER Mapper raster", ".bt": "a VTP binary terrain",
    ".ter": "a Terragen heightfield", ".hf2": "an HF2 heightfield", ".jp2": "a JPEG 2000 raster",
    ".grb": "a GRIB grid", ".grb2": "a GRIB grid", ".grib2": "a GRIB grid", ".bag": "a BAG bathymetry grid",
    ".gtx": "a vertical-datum grid (GTX)", ".sigdem": "a SIGDEM grid", ".rsw": "an RMF raster",
    ".kea": "a KEA raster", ".gpkg": "a GeoPackage raster", ".envi": "an ENVI raster",
}


def _unknown_extension_hint(file: Path) -> str:
    """The way on for :func:`load_dem`'s refusal of the local ``file`` of an unknown extension: a tar archive's
    ``/vsitar/`` path (as a ``.tar.gz``'s refusal gives it, :func:`gzip_member`), a raster GDAL reads in another format
    (:data:`_CONVERTIBLE_FORMATS`: netCDF, a Surfer grid) the ``gdal_translate`` to a GeoTIFF; "" otherwise."""
    ext = file.suffix.lower()
    if ext in (".tar", ".tgz"):
        return f"; a tar archive: name the file inside it, '/vsitar/{file}/<name>.tif'"
    if ext in _CONVERTIBLE_FORMATS:
        quoted = shlex.quote(os.fspath(file))
        return (f"; {_CONVERTIBLE_FORMATS[ext]}, which GDAL reads: convert it to a GeoTIFF first, "
                f"`gdal_translate -of GTiff {quoted} {shlex.quote(file.stem + '.tif')}`")
    return ""


def dem_path(path: str | os.PathLike[str]) -> Path:
    """The file :func:`load_dem` reads for ``path``: a :class:`~stepterrain._files.GdalPath` for a GDAL virtual path
    (``/vsizip/...``, ``/vsigzip/...``, ``/vsicurl/...``) or a URL (``https://``, ``s3://``, ...), and for a local
    ``.zip`` holding one raster of :data:`GDAL_FORMATS` (:func:`zip_member`) and a local ``.gz`` of one of
    :data:`GZIP_FORMATS` (:func:`gzip_member`); the Path of a local file otherwise.
    A path argument that is no str or path-like is an InvalidInputError."""
    if isinstance(path, GdalPath):
        return path
    file = as_path(path, "path")
    text = os.fspath(path)
    virtual = gdal_path(text) if isinstance(text, str) else None
    if virtual is not None:
        return virtual
    if file.suffix.lower() == ".zip":
        return zip_member(file)
    if file.suffix.lower() == ".gz":
        return gzip_member(file)
    return file


def zip_member(file: Path) -> GdalPath:
    """The ``/vsizip/`` path of the one raster GDAL reads (an extension of :data:`GDAL_FORMATS`) in the local zip
    ``file`` (an SRTM download, ``N46E007.SRTMGL1.hgt.zip``): its sidecars (a .bil's .hdr, a .prj, an .aux.xml) are
    read beside it by GDAL. A zip of none, or of several (a zip of tiles: which one is meant?), is refused (a
    DataFileError naming them: ``/vsizip/<zip>/<name>`` picks one), as is a file that is no zip."""
    require_regular_file(file, "DEM file", "DEM path")
    try:
        with zipfile.ZipFile(file) as archive:
            names = [info.filename for info in archive.infolist() if not info.is_dir()]
    except (OSError, zipfile.BadZipFile) as exc:
        raise DataFileError(f"cannot read {str(file)!r}: expected a zip archive holding a DEM; got {exc}") from exc
    rasters = [n for n in names if PurePosixPath(n).suffix.lower() in GDAL_FORMATS
               and not any(part.startswith(("__MACOSX", "._")) for part in PurePosixPath(n).parts)]
    given = str(file)
    if len(rasters) != 1:
        def listed(members: list[str]) -> str:  # the first 10 named
            more = f" and {len(members) - 10} more" if len(members) > 10 else ""
            return ", ".join(repr(n) for n in members[:10]) + more

        if not rasters:
            found = "holds no raster GDAL reads; it holds " + (listed(names) if names else "nothing")
        else:
            found = (f"holds {len(rasters)} rasters: {listed(rasters)}; name the one to read, e.g. "
                     f"'/vsizip/{given}/{rasters[0]}'")
        raise DataFileError(f"cannot read {given!r}: expected a zip holding one DEM ({', '.join(GDAL_FORMATS)}); it "
                            + found)
    gdal = f"/vsizip/{os.path.abspath(file)}/{rasters[0]}"
    return _restored(f"{given}/{rasters[0]}", gdal, gdal)  # named as the member; str() the GDAL path, which reads it


def gzip_member(file: Path) -> GdalPath:
    """The ``/vsigzip/`` path of the local gzip file ``file`` of one raster of :data:`GZIP_FORMATS`
    (``N46E007.hgt.gz``, as AWS Terrain Tiles serve SRTM; ``dem.tif.gz``): a GdalPath named as the file inside
    (``N46E007.hgt``: an SRTM tile placed by its name), its ``str()`` the path as given. Another inner extension is
    refused, naming those read (an InvalidInputError): ``.npy``/``.npz``/``.png`` and the .bil, .flt and .vrt GDAL
    cannot read alone (gunzip them), a ``.tar.gz`` (``/vsitar/`` names its file). Whether the file exists and is a whole
    gzip stream is checked when it is read (:func:`check_gzip`)."""
    given = str(file)
    inner = Path(file.name[: -len(file.suffix)])
    ext = inner.suffix.lower()
    if ext not in GZIP_FORMATS:
        if ext == ".tar":
            why = f"a tar archive: name the file inside it, '/vsitar/{given}/<name>.tif'"
        elif ext in SUPPORTED_EXTENSIONS:  # .npy .npz .png .bil .flt .vrt
            why = (f"{ext} files are read uncompressed only" + (
                " (GDAL reads no .hdr beside a gzip)" if ext in (".bil", ".flt") else
                " (its sources are named beside it)" if ext == ".vrt" else "")
                + f": gunzip it first, `gunzip -k {given}`")
        else:
            why = f"unknown DEM extension {inner.suffix or '(none)'!r} of the file inside, {inner.name!r}"
        raise InvalidInputError(f"cannot read {given!r}: a .gz is read as the raster it compresses, one of "
                                f"{', '.join(e + '.gz' for e in GZIP_FORMATS)}; {why}")
    gdal = f"/vsigzip/{os.path.abspath(file)}"
    return _restored(given[: -len(file.suffix)], gdal, given)


#: Local gzip files :func:`check_gzip` found whole, by (path, size, mtime, ctime, inode): a batch reads a file's header
#: and then its heights, and a rerun's pass of ranges reads it again, each decompressing it once more.
_WHOLE_GZIPS: set[tuple[str, int, int, int, int]] = set()
_WHOLE_GZIPS_LOCK = threading.Lock()


def check_gzip(file: GdalPath) -> None:
    """Refuse the ``/vsigzip/`` path ``file`` of a local gzip file unless that file is one whole gzip stream: it
    exists, is gzip, is not cut short, and its CRC-32 and length match its data (a DataFileError naming the file and
    zlib's reason). GDAL read a cut short .gz up to where it ends, and read no CRC: a corrupt byte gave wrong heights
    without a word, and a window of a crop read before the damage unchecked. The file is decompressed once, in
    blocks, for the check (:data:`_WHOLE_GZIPS` remembers a whole one). Nothing for another path or a remote one."""
    archive = _local_gzip(file)
    if archive is None:
        return
    local = Path(archive)
    require_regular_file(local, "DEM file", "DEM path")
    st = local.stat()
    key = (os.path.abspath(archive), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
    with _WHOLE_GZIPS_LOCK:
        if key in _WHOLE_GZIPS:
            return
    try:
        with gzip.open(local, "rb") as stream:
            while stream.read(1 << 20):
                pass
    except (OSError, EOFError, zlib.error) as exc:  # gzip.BadGzipFile is an OSError
        reason = "it is cut short" if isinstance(exc, EOFError) else "it is corrupt or no gzip"
        raise DataFileError(
            f"cannot read {str(file)!r}: expected a whole gzip file of {_gdal_format(file)}; {reason} "
            f"({str(exc) or type(exc).__name__}): download or compress it again"
        ) from exc
    with _WHOLE_GZIPS_LOCK:
        if len(_WHOLE_GZIPS) > 4096:
            _WHOLE_GZIPS.clear()
        _WHOLE_GZIPS.add(key)


def _virtual_refusal(file: GdalPath) -> str:
    """Why :func:`load_dem` refuses the GDAL virtual path or URL ``file``: an extension GDAL is not asked to read."""
    ext, gdal, example = file.suffix.lower(), os.fspath(file), f"<name>{next(iter(GDAL_FORMATS))}"
    if ext in SUPPORTED_EXTENSIONS:  # .npy .npz .png: read by NumPy and Pillow from local files only
        why = f"{ext} files are read from a local file only"
    elif ext == ".zip":
        # a zip reached through another file system (a URL, /vsis3/, /vsitar/) is opened by /vsizip/ chained to it:
        # its path with the member's name after it ('https://host/srtm.zip/<name>.tif') asked the server (or the
        # tar) for a file of that name, which is not there; a zip inside a zip, or one of a URL with a query (a
        # signed URL: no '.zip/' in it), in braces (GDAL splits the path at its first '.zip/')
        own = gdal.rstrip("/")  # a trailing slash names no member (/vsizip//data/srtm.zip/): the zip, as without it
        rest = own[len("/vsizip/"):] if own.startswith("/vsizip/") else None
        if rest is not None and rest.startswith("{") and rest.endswith("}"):  # the zip itself, in braces, whatever
            archive = rest[1:-1]  # they hold (/vsizip/{/vsicurl/...?sig=1}, a zip in a zip /vsizip/{/vsizip//a/b.zip})
        elif rest is None or ".zip/" in rest.lower() or rest.startswith("{"):
            archive = own  # reached through another file system, or a member of a zip: a zip in a zip
        else:  # the zip itself, opened by /vsizip/ already (/vsizip//data/srtm.zip)
            archive = rest
        braces = "?" in archive or ".zip/" in archive.lower() or archive.startswith("/vsizip/")
        inside = f"/vsizip/{{{archive}}}/{example}" if braces else f"/vsizip/{archive}/{example}"
        why = f"name the file inside the zip: '{inside}'"
    elif ext == ".gz" and not gdal.startswith("/vsigzip/") and PurePath(file.stem).suffix.lower() in GZIP_FORMATS:
        why = f"read a gzip file through /vsigzip/: '/vsigzip/{gdal}'"  # a URL's dem.tif.gz, as a local one is
    else:
        why = f"unknown DEM extension {file.suffix or '(none)'!r} of {file.name!r}"
    return (f"cannot read {str(file)!r}: a GDAL virtual path (/vsizip/, /vsigzip/, /vsicurl/, ...) or a URL "
            f"({', '.join(s + '://' for s in URL_FILE_SYSTEMS)}) is read through GDAL, as a raster of "
            f"{', '.join(GDAL_FORMATS)} (by the extension of the file it names); {why}")


def own_placement(crs: str | None, spacing: tuple[float, float], origin: tuple[float, float]) -> str | None:
    """How a DEM that :func:`load_dem` read places its nodes ("spacing (30.0, -30.0), origin (x, y), CRS ..."), or
    None for a file with no georeferencing, which it reads as 1 m cells at (0, 0), rows north to south: the one a
    cell size given for the file (the CLI's ``--spacing``, batch's ``spacing=``) may replace."""
    if crs is None and spacing == (1.0, -1.0) and origin == (0.0, 0.0):
        return None
    return f"spacing {spacing}, origin {origin}" + (f", CRS {crs}" if crs else "")


def sample_dem() -> Terrain:
    """The embedded default DEM: 30 m SRTM of the Big Tujunga catchment, San Gabriel Mountains, California.

    Returns
    -------
    Terrain
        643 x 1197 nodes, spacing (30, -30) m, EPSG:32611 (UTM 11N), heights 315-2295 m, no nodata.
        A fresh object each call. Source, licence (public domain) and checksum:
        ``stepterrain/data/README.md``.

    Examples
    --------
    >>> import stepterrain as st
    >>> t = st.sample_dem()
    >>> t.spacing, t.crs, t.height_range
    ((30.0, -30.0), 'EPSG:32611', (315.0, 2295.0))
    """
    return _sample_dem()


def _sample_dem(nodata: float | Sequence[float] | None = None) -> Terrain:
    """:func:`sample_dem`, with :func:`load_dem`'s ``nodata`` (the CLI's ``--nodata`` without an INPUT)."""
    resource = importlib.resources.files("stepterrain") / "data" / _SAMPLE_NAME
    with importlib.resources.as_file(resource) as file:
        return read_dem(file, nodata=nodata)


def describe_dem(terrain: Terrain) -> dict[str, Any]:
    """A plain-Python summary of a terrain, for ``stepterrain info`` and logs.

    Parameters
    ----------
    terrain : Terrain
        Or anything :func:`~stepterrain.terrain.as_terrain` accepts ((H, W) array, trimesh TIN).

    Returns
    -------
    dict
        ``kind`` ("grid" or "tin"), ``shape``, ``spacing`` (dx, dy) and ``origin`` (x0, y0) (None for a
        TIN), ``extent`` (xmin, xmax, ymin, ymax), ``height_range`` (min, max) of the finite heights
        (None when all are nodata), ``nodata_count`` and ``nodata_fraction`` (its share of the heights, 0 to 1),
        ``height_unit`` ("m" when the heights were read in a named length unit and are metres now, None when no
        unit was named: as stored) and ``height_unit_read`` (that unit as named, e.g. "ft"; see
        :attr:`Terrain.height_unit <stepterrain.terrain.Terrain>`), ``crs`` and ``source`` (None when unknown); for a
        geographic grid (read from degrees into local metres: ``crs`` an equidistant cylindrical projection on a
        sphere, as :func:`load_dem` writes it) also ``lonlat_extent`` (lon_min, lon_max, lat_min, lat_max) of
        the nodes and ``lonlat_step`` (dlon, dlat), in degrees, signed as ``spacing`` is (None otherwise).
        Only ints, floats, strings, tuples and None, so ``json.dumps`` works.

    Examples
    --------
    >>> import numpy as np, stepterrain as st
    >>> from stepterrain.io import describe_dem
    >>> info = describe_dem(st.Terrain.from_heights([[0.0, np.nan], [2.0, 3.0]], spacing=(10.0, -10.0)))
    >>> info["shape"], info["extent"], info["height_range"], info["nodata_count"], info["nodata_fraction"]
    ((2, 2), (0.0, 10.0, -10.0, 0.0), (0.0, 3.0), 1, 0.25)
    """
    t = as_terrain(terrain)
    finite = np.isfinite(t.heights)
    height_range = None
    if finite.any():
        height_range = (float(t.heights[finite].min()), float(t.heights[finite].max()))
    grid = t.kind == "grid"
    lonlat = _lonlat_grid(t) if grid else None
    nodata = int(finite.size - np.count_nonzero(finite))
    return {
        "kind": t.kind,
        "shape": tuple(int(n) for n in t.shape),
        "spacing": tuple(float(v) for v in t.spacing) if grid else None,
        "origin": tuple(float(v) for v in t.origin) if grid else None,
        "extent": tuple(float(v) for v in t.extent),
        "height_range": height_range,
        "nodata_count": nodata,
        "nodata_fraction": nodata / finite.size if finite.size else 0.0,
        "height_unit": "m" if t.height_unit else None,
        "height_unit_read": t.height_unit,
        "crs": t.crs,
        "source": t.source,
        "lonlat_extent": lonlat[0] if lonlat else None,
        "lonlat_step": lonlat[1] if lonlat else None,
    }


def _lonlat_grid(
    t: Terrain,
) -> tuple[tuple[float, float, float, float], tuple[float, float]] | None:
    """(lon_min, lon_max, lat_min, lat_max) of a grid's nodes and its (dlon, dlat), in degrees, when its ``crs``
    is a spherical equidistant cylindrical projection (``+proj=eqc ... +R=``, what geographic files become in
    :func:`load_dem`): x = R·(λ - λ0)·cos φts + x0, y = R·(φ - φ0) + y0 inverted; else None."""
    found = _spherical_eqc(t.crs)
    if found is None:
        return None
    radius, x_radius, lat_0, lon_0, x_0, y_0 = found
    (x_min, x_max, y_min, y_max), (dx, dy) = t.extent, t.spacing
    lon = (lon_0 + math.degrees((x_min - x_0) / x_radius), lon_0 + math.degrees((x_max - x_0) / x_radius))
    lat = (lat_0 + math.degrees((y_min - y_0) / radius), lat_0 + math.degrees((y_max - y_0) / radius))
    return (*lon, *lat), (math.degrees(dx / x_radius), math.degrees(dy / radius))


def _spherical_eqc(crs: str | None) -> tuple[float, float, float, float, float, float] | None:
    """(R, R·cos φts, φ0, λ0, x0, y0) of a spherical equidistant cylindrical ``crs`` (``+proj=eqc ... +R=``, what
    geographic files become in :func:`load_dem`), else None."""
    params = dict(token[1:].partition("=")[::2] for token in (crs or "").split() if token.startswith("+"))
    if params.get("proj") != "eqc" or "R" not in params or "ellps" in params or "datum" in params:
        return None
    try:
        radius = float(params["R"])
        lat_ts, lat_0, lon_0, x_0, y_0 = (float(params.get(k, 0.0)) for k in ("lat_ts", "lat_0", "lon_0", "x_0", "y_0"))
    except ValueError:
        return None
    x_radius = radius * math.cos(math.radians(lat_ts))
    if not radius > 0.0 or not x_radius > 0.0:
        return None
    return radius, x_radius, lat_0, lon_0, x_0, y_0


def lonlat_as_local_metres(crs: str | None, lons: Sequence[float], lats: Sequence[float]) -> tuple[list[float],
                                                                                                  list[float]] | None:
    """Longitudes and latitudes (degrees) as x and y of the local equirectangular metres a geographic DEM is read in
    (:func:`load_dem`; ``crs`` as its Terrain holds it): x = R·cos φts·(λ − λ0) + x0, y = R·(φ − φ0) + y0, linear,
    so an extent in degrees maps onto an extent in those metres exactly; None when ``crs`` is not such a CRS."""
    found = _spherical_eqc(crs)
    if found is None:
        return None
    radius, x_radius, lat_0, lon_0, x_0, y_0 = found
    return ([x_0 + x_radius * math.radians(lon - lon_0) for lon in lons],
            [y_0 + radius * math.radians(lat - lat_0) for lat in lats])


def extent_in_degrees_as_metres(
    terrain: Terrain, extent: Sequence[float],
) -> tuple[tuple[float, float, float, float], tuple[float, float, float, float]] | None:
    """For a grid :func:`load_dem` read from degrees (local metres), an ``extent`` (xmin, xmax, ymin, ymax) that
    looks given in degrees: as degrees it overlaps the DEM's longitudes and latitudes, as metres it misses the DEM or
    covers under 1% of it. Then the DEM's (lon_min, lon_max, lat_min, lat_max) and the extent in its metres
    (:func:`lonlat_as_local_metres`), else None."""
    lonlat = _lonlat_grid(terrain) if terrain.kind == "grid" else None
    if lonlat is None or len(extent) != 4 or not all(math.isfinite(float(v)) for v in extent):
        return None
    x0, x1, y0, y1 = (float(v) for v in extent)
    (lon0, lon1, lat0, lat1), _ = lonlat
    lon0, lon1, lat0, lat1 = min(lon0, lon1), max(lon0, lon1), min(lat0, lat1), max(lat0, lat1)
    if not (x0 < lon1 and x1 > lon0 and y0 < lat1 and y1 > lat0):
        return None  # as degrees it is not over the DEM: its numbers are not degrees meant for it
    ex0, ex1, ey0, ey1 = terrain.extent
    overlap = max(0.0, min(x1, ex1) - max(x0, ex0)) * max(0.0, min(y1, ey1) - max(y0, ey0))
    if overlap >= 0.01 * (ex1 - ex0) * (ey1 - ey0):
        return None
    found = lonlat_as_local_metres(terrain.crs, [x0, x1], [y0, y1])
    assert found is not None  # _lonlat_grid read the same CRS
    (mx0, mx1), (my0, my1) = found
    return (lon0, lon1, lat0, lat1), (mx0, mx1, my0, my1)


def degrees_hint(terrain: Terrain, box: Sequence[float]) -> str:
    """For a refusal of a ``box`` (xmin, xmax, ymin, ymax: a circle's or ROI's) off a DEM read from degrees, what to
    add when it looks given in degrees (:func:`extent_in_degrees_as_metres`): its centre in the DEM's metres."""
    found = extent_in_degrees_as_metres(terrain, box)
    if found is None:
        return ""
    (mx0, mx1, my0, my1) = found[1]
    return (f"; it looks like degrees, but a DEM in degrees is read as local metres (`stepterrain info` prints its "
            f"extent): the centre ({(box[0] + box[1]) / 2:.10g}, {(box[2] + box[3]) / 2:.10g}) is there "
            f"({(mx0 + mx1) / 2:.2f}, {(my0 + my1) / 2:.2f}), and a radius is in metres too")


# ---------------------------------------------------------------------------------------------- readers
def _load_npy(file: Path, height_unit: str | None) -> Terrain:
    heights, unit = _heights_in_metres(_elevation(read_npy(file), file, "array"), height_unit, file, "height_unit")
    return _grid(file, heights, spacing=(1.0, -1.0), origin=(0.0, 0.0), crs=None, height_unit=unit)


def read_npy(file: Path, mmap_mode: Literal["r"] | None = None) -> NDArray[Any]:
    """The one array of an .npy file (memory-mapped read-only with ``mmap_mode="r"``), else a DataFileError: not
    an .npy, a header declaring more data than the file holds (truncated), pickled objects, unreadable content.
    Its declared size is checked against the memory budget (an OutputTooLargeError) either way: every caller
    reads the map into memory as float32 (a series in :func:`~stepterrain.batch.load_series`).
    :func:`load_dem` and :func:`~stepterrain.batch.load_series` read .npy files through this."""
    _check_magic(file, (_NPY_MAGIC,), "a NumPy .npy array file")
    with open(file, "rb") as handle:  # readable: _check_magic has read it
        _check_declared_size(handle, os.fstat(handle.fileno()).st_size, file, "the array")
    try:
        array = np.load(file, mmap_mode=mmap_mode, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DataFileError(
            f"cannot read {str(file)!r}: expected a NumPy .npy array file; got unreadable content ({exc})"
        ) from exc
    if not isinstance(array, np.ndarray):  # an .npz archive saved under a .npy name
        if hasattr(array, "close"):
            array.close()
        raise DataFileError(f"cannot read {str(file)!r}: expected a single .npy array; got an .npz archive")
    return array


def read_npz(file: Path) -> dict[str, NDArray[Any]] | NDArray[Any]:
    """The members of an .npz archive by key (each member's header checked against its size, as
    :func:`read_npy` checks a file's), or the array of an .npy saved under an .npz name; else a DataFileError.
    :func:`load_dem` and :func:`~stepterrain.batch.load_series` read .npz files through this."""
    if _check_magic(file, (_ZIP_MAGIC, _EMPTY_ZIP_MAGIC, _NPY_MAGIC), "a NumPy .npz archive").startswith(_NPY_MAGIC):
        return read_npy(file)  # a .npy saved under an .npz name: a plain array (its size checked too)
    return _each_npz_member(file, _npz_member)


def open_npz(file: Path) -> tuple[BinaryIO, Any]:
    """``np.load(file, allow_pickle=False)`` on a file opened here, and that file: the caller closes it (``with
    handle, archive:``; an .npy's array is read whole). np.load left the file it opened itself open when zipfile
    refused it (a truncated archive): a ResourceWarning, a handle held until the garbage collector found it. Its
    errors are np.load's."""
    handle = open(file, "rb")
    try:
        return handle, np.load(handle, allow_pickle=False)
    except BaseException:
        handle.close()
        raise


def _each_npz_member(file: Path, read: Callable[[Any, str, Path], Any]) -> dict[str, Any]:
    """``{key: read(archive, key, file)}`` for the members of the .npz archive ``file`` (an archive, not a .npy under
    an .npz name: :func:`read_npz` and :func:`npz_member_ndims` test that first), an unreadable archive or member a
    DataFileError in :func:`read_npz`'s words."""
    try:
        handle, archive = open_npz(file)  # the zip directory only
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise DataFileError(
            f"cannot read {str(file)!r}: expected a NumPy .npz archive; got unreadable content ({exc})"
        ) from exc
    try:
        with handle, archive:
            return {key: read(archive, key, file) for key in archive.files}
    except DataFileError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise DataFileError(
            f"cannot read {str(file)!r}: a member of the .npz archive is unreadable ({exc})"
        ) from exc


def npz_member_ndims(file: Path) -> dict[str, int] | int:
    """What :func:`read_npz` would return, as each array's number of dimensions read from its .npy header: the
    members' data is not read (a decision before the one read that needs only the shapes: batch's one INPUT, a
    raster or a series). The checks the headers allow are :func:`read_npz`'s (declared sizes against the members',
    the memory budget; unreadable archives), in its words; a member's damaged data is left to the read."""
    if _check_magic(file, (_ZIP_MAGIC, _EMPTY_ZIP_MAGIC, _NPY_MAGIC), "a NumPy .npz archive").startswith(_NPY_MAGIC):
        return read_npy(file, mmap_mode="r").ndim  # a map: its header only
    return _each_npz_member(file, _npz_member_ndim)


def _npz_member_ndim(archive: Any, key: str, file: Path) -> int:
    """:func:`_npz_member`'s array's number of dimensions, from its header (0 for a member that is no .npy: NumPy
    reads its bytes, a 0-d array)."""
    name = f"{key}.npy" if f"{key}.npy" in archive.zip.namelist() else key
    with archive.zip.open(name) as member:
        header = _check_declared_size(member, archive.zip.getinfo(name).file_size, file, f"member {key!r}")
    if header is None:  # none read: not an .npy, another header version, or one NumPy cannot parse (raised here)
        with archive.zip.open(name) as member:
            if member.read(len(np.lib.format.MAGIC_PREFIX)) != np.lib.format.MAGIC_PREFIX:
                return 0
            member.seek(0)
            header = _npy_header(member)
    if header is not None and not header[1].hasobject:
        return len(header[0])
    return _npz_member(archive, key, file).ndim  # another header version, or pickled objects: as read_npz reads it


def _load_npz(file: Path, height_unit: str | None) -> Terrain:
    arrays = read_npz(file)
    if isinstance(arrays, np.ndarray):  # a .npy saved under a .npz name: take it as a plain array
        heights, unit = _heights_in_metres(_elevation(arrays, file, "array"), height_unit, file, "height_unit")
        return _grid(file, heights, spacing=(1.0, -1.0), origin=(0.0, 0.0), crs=None, height_unit=unit)
    nodata = npz_nodata(arrays.get("nodata"), file)
    two_d = [key for key, value in arrays.items() if value.ndim == 2 and key not in _NPZ_NOT_HEIGHTS]
    # the same key with a transform (which georeferences it) and without
    key = npz_heights_key(arrays, (2,))
    if key is None and len(two_d) == 1:
        key = two_d[0]
    latlon = "transform" not in arrays and "lat" in arrays and "lon" in arrays
    if key is not None:
        refuse_npz_scaling(arrays, key, file)
    if key is not None and ("transform" in arrays or latlon):
        heights = _elevation(arrays[key], file, repr(key), nodata, npz_missing(arrays, key, file))
        crs = _npz_text(arrays, "crs", file)
        xy_unit = None
        if latlon:  # degree axes of the nodes (the layout of the global relief grids): geographic by definition
            transform = _latlon_geotransform(arrays["lat"], arrays["lon"], heights.shape, file)
            geographic = True
        else:
            raw = arrays["transform"]
            transform = np.asarray(raw, dtype=np.float64).reshape(-1) if raw.dtype.kind in "iuf" else np.empty(0)
            # rasterio's Affine(dx, 0, x0, 0, -dy, y0) saved as is (np.array(affine), or its first 6 numbers), not as
            # its to_gdal(): 6 of them were refused as a "rotated" grid (c, e = x0, -dy) or a zero pixel size
            affine = transform.size in (6, 9) and np.all(np.isfinite(transform)) and transform[0] != 0.0 and \
                transform[4] != 0.0 and \
                _negligible_rotation(transform[1], transform[3], transform[0], transform[4], heights.shape) and \
                (transform.size == 6 or tuple(transform[6:]) == (0.0, 0.0, 1.0))
            if affine:
                a, _, c, _, e, f = (float(v) for v in transform[:6])
                raise DataFileError(
                    f"cannot read {str(file)!r}: 'transform' must be a GDAL geotransform (x0, dx, 0, y0, 0, -dy); got "
                    f"{raw.tolist()}, rasterio's Affine (dx, 0, x0, 0, -dy, y0{', 0, 0, 1' * (transform.size == 9)}) "
                    f"by the look of it: save transform.to_gdal(), here ({c!r}, {a!r}, 0.0, {f!r}, 0.0, {e!r})"
                )
            if transform.size != 6 or not np.all(np.isfinite(transform)):
                raise DataFileError(
                    f"cannot read {str(file)!r}: 'transform' must be a GDAL geotransform of 6 finite numbers "
                    f"(x0, dx, 0, y0, 0, -dy); got {raw.tolist()}"
                )
            units_xy = _npz_text(arrays, "units_xy", file) or ""
            geographic = _is_geographic(crs) or _degree_unit(units_xy)
            # the transform's unit when the CRS does not state one: units_xy="ft" was read as metres
            xy_unit = None if geographic else _npz_xy_unit(units_xy, crs, file)
        metres = None
        if geographic and ("dx_m" in arrays) != ("dy_m" in arrays):  # one was ignored: metres from R and the degrees
            given, missing = ("dx_m", "dy_m") if "dx_m" in arrays else ("dy_m", "dx_m")
            raise DataFileError(
                f"cannot read {str(file)!r}: expected both 'dx_m' and 'dy_m' (the metres per cell of its degrees) or "
                f"neither; got {given!r} without {missing!r}"
            )
        if geographic and "dx_m" in arrays and "dy_m" in arrays:
            dx_m, dy_m = arrays["dx_m"], arrays["dy_m"]
            if dx_m.size != 1 or dy_m.size != 1 or dx_m.dtype.kind not in "iuf" or dy_m.dtype.kind not in "iuf":
                raise DataFileError(
                    f"cannot read {str(file)!r}: 'dx_m' and 'dy_m' must be numbers (metres); "
                    f"got {dx_m.tolist()!r} and {dy_m.tolist()!r}"
                )
            metres = (float(dx_m.reshape(())), float(dy_m.reshape(())))
            if not all(math.isfinite(m) and m != 0.0 for m in metres):  # warned of "100 %" errors, then "spacing"
                raise DataFileError(
                    f"cannot read {str(file)!r}: 'dx_m' and 'dy_m' must be finite, non-zero metres per cell; "
                    f"got {metres[0]!r} and {metres[1]!r}"
                )
        named_by = "height_unit" if height_unit else "its 'units'" if "units" in arrays else f"its CRS {crs}"
        declared = _npz_text(arrays, "units", file)
        _warn_unit_override(file, height_unit, declared, "its 'units'")
        unit, crs, factor = _vertical_unit(height_unit or declared, crs)
        heights, height_unit = _heights_in_metres(heights, unit, file, named_by, factor)
        return _georeferenced(
            file, heights, transform, crs, geographic=geographic, metres=metres, height_unit=height_unit,
            xy_unit=xy_unit,
        )

    unused = npz_georeference_keys(arrays)
    if key is not None and unused:  # np.savez(elevation=z, dx=30, dy=30, crs=...) read as 1 m cells at (0, 0)
        raise DataFileError(
            f"cannot read {str(file)!r}: expected a 'transform' (the GDAL geotransform (x0, dx, 0, y0, 0, -dy)) or 1-D "
            f"'lat' and 'lon' node axes beside {key!r} to georeference it; got {', '.join(map(repr, unused))} "
            "but neither, which load_dem does not read (the grid would be 1 m cells at (0, 0)): add a "
            "'transform', or drop those keys to read it unreferenced"
        )
    if key is not None:  # the heights' unit applies without a transform too: 'units' = "ft" was ignored here
        named_by = "height_unit" if height_unit else "its 'units'"
        declared = _npz_text(arrays, "units", file)
        _warn_unit_override(file, height_unit, declared, "its 'units'")
        heights, unit = _heights_in_metres(
            _elevation(arrays[key], file, repr(key), nodata, npz_missing(arrays, key, file)),
            height_unit or declared, file,
            named_by,
        )
        return _grid(file, heights, spacing=(1.0, -1.0), origin=(0.0, 0.0), crs=None, height_unit=unit)
    described = ", ".join(f"{k} {v.shape}" for k, v in arrays.items()) or "no arrays"
    raise DataFileError(
        f"cannot read {str(file)!r}: expected an .npz with a key {'/'.join(_GENERIC_KEYS)} (georeferenced by a "
        f"'transform' beside it), or exactly one 2-D array; got {described}"
    )


#: Metres per unit within which an .npz's ``units_xy`` names its CRS's own unit (any foot for one in US survey feet,
#: 2 ppm apart): the CRS's exact unit then applies.
_SAME_UNIT_TOLERANCE = 1e-5


def _degree_unit(unit: str) -> bool:
    """Whether an .npz's ``units_xy`` names degrees ("degrees", "decimal degrees (EPSG:4326)", "deg", "°"): its
    transform is then geographic."""
    word = unit.strip(" \t.").lower()
    return "degree" in word or word in ("deg", "degs", "°")


def _npz_xy_unit(units_xy: str, crs: str | None, file: Path) -> tuple[str, float] | None:
    """(unit, metres per unit) of a projected .npz's transform as its ``units_xy`` names it (a length unit of
    :data:`_HEIGHT_UNITS`, or one followed by a note: "metres (EPSG:32611)") when its coordinates are to be converted
    by it: no CRS, or one whose unit cannot be looked
    up (PROJ cannot read it, no rasterio); None when it is blank, the metre, or the unit of the CRS, which then
    converts them (:func:`_placement`). A unit that is none (nor degrees: :func:`_degree_unit`), or that its CRS
    contradicts (feet named for EPSG:32611's metres), is a DataFileError naming ``units_xy`` and its value: read
    as metres, a grid in feet was 3.28 times too wide."""
    if not units_xy.strip():
        return None
    # the unit named first, a note after it ("metres (EPSG:32611)", "ft; State Plane"), as _degree_unit reads
    # "decimal degrees (EPSG:4326)": such a file in metres was read until units_xy was parsed, then refused. A note
    # naming the survey foot ("ft (US survey)") is no note: "ft" alone, the international foot, is 2 ppm off it
    head = re.split(r"[(;,]", units_xy, maxsplit=1)[0]
    note = units_xy[len(head):]
    factor = _unit_factor(units_xy) or (None if "survey" in note.lower() else _unit_factor(head))
    if factor is None:
        raise DataFileError(
            f"cannot read {str(file)!r}: 'units_xy' must name the unit of the 'transform' (a length unit: "
            f"{_KNOWN_UNITS}; or degrees); got {units_xy!r}"
        )
    stated = _crs_linear_unit(crs)
    if stated is None:
        return (units_xy, factor) if factor != 1.0 else None
    name, crs_factor = stated
    if abs(factor / crs_factor - 1.0) > _SAME_UNIT_TOLERANCE:
        raise DataFileError(
            f"cannot read {str(file)!r}: 'units_xy' is {units_xy!r} ({factor:.10g} m), but its CRS {crs} counts "
            f"{name} ({crs_factor:.10g} m): save the 'transform' in the CRS's unit and units_xy={name!r} (or "
            "neither), or the CRS the coordinates are in"
        )
    return None


def _crs_linear_unit(crs: str | None) -> tuple[str, float] | None:
    """(unit, metres per unit) of a projected or local engineering CRS (a site grid: LOCAL_CS, ENGCRS), ("metre", 1.0)
    for a projected one in metres; None for none, a geographic or other CRS (geocentric, vertical: no horizontal
    plane in a linear unit), one PROJ cannot read, a site grid without a linear unit, or without rasterio to look it
    up. The one reading of a CRS's unit: :func:`_projected_units` builds on it."""
    crs_obj = _crs_object(crs) if crs else None
    if crs_obj is None or crs_obj.is_geographic:
        return None
    if crs_obj.is_projected:
        try:
            unit, factor = crs_obj.linear_units_factor
        except Exception:  # no linear unit to read: the grid keeps its own units, taken as metres
            return "metre", 1.0
        return ("metre", 1.0) if factor == 1.0 else (str(unit), float(factor))
    if not crs_obj.to_wkt().lstrip().startswith(("LOCAL_CS[", "ENGCRS[", "ENGINEERINGCRS[")):
        return None
    try:
        unit, factor = crs_obj.units_factor
    except Exception:  # no linear unit to read
        return None
    return str(unit), float(factor)


def npz_georeference_keys(arrays: Mapping[str, Any]) -> list[str]:
    """The members of an .npz that georeference its heights other than a ``transform`` (:data:`_NPZ_GEOREFERENCE`:
    ``crs``, ``dx``/``dy``, ``spacing``/``origin``, ``x``/``y``, ``lat``/``lon``, ...), in the archive's order:
    :func:`load_dem` refuses them without a ``transform`` or a ``lat`` and ``lon`` pair, and
    :func:`~stepterrain.batch.load_series` (which reads no georeferencing) always, rather than ignore them."""
    return [name for name in arrays if name in _NPZ_GEOREFERENCE]


def refuse_npz_scaling(arrays: Mapping[str, Any], key: str, file: Path) -> None:
    """A DataFileError when an .npz holds a scale or offset of its heights ``arrays[key]`` (:data:`_NPZ_SCALING`:
    ``scale``/``offset`` as rasterio names a band's, ``scale_factor``/``add_offset`` as CF and xarray do) that is a
    number other than 1 or 0: :func:`load_dem` (and :func:`~stepterrain.batch.load_series`) take the heights as
    stored, so an int16 grid of decimetres saved with ``scale=0.1`` read as metres, 10 times too high."""
    found = []
    for name, identity in _NPZ_SCALING.items():
        value = arrays.get(name)
        if value is None or value.size != 1 or value.dtype.kind not in "iuf":  # not one number: metadata of its own
            continue
        number = float(value.reshape(()))
        if number != identity:
            found.append(f"{name}={number:g}")
    if found:
        raise DataFileError(
            f"cannot read {str(file)!r}: expected heights as stored beside {key!r}; got {', '.join(found)}, a scale "
            "of the stored values (height = value * scale + offset) that load_dem does not read (the heights would "
            "be taken as stored): save them scaled, e.g. np.savez(..., elevation=np.where(z == nodata, np.nan, "
            "z * scale + offset)), without those keys"
        )


def _latlon_geotransform(
    lat: NDArray[Any], lon: NDArray[Any], shape: tuple[int, ...], file: Path
) -> NDArray[np.float64]:
    """The GDAL geotransform of a grid whose nodes lie at the evenly spaced degrees ``lat`` (one per row) and
    ``lon`` (one per column), e.g. the cell centres of the global relief grids; else a DataFileError. ``lon`` may
    cross the antimeridian ([178, 179, 180, -179]): it is unwrapped first (:func:`unwrapped_longitudes`)."""
    axes = []
    for name, axis, n in (("lon", lon, shape[1]), ("lat", lat, shape[0])):
        values = np.asarray(axis, dtype=np.float64) if axis.dtype.kind in "iuf" else np.empty(0)
        if values.ndim != 1 or values.size != n or n < 2 or not np.all(np.isfinite(values)):
            raise DataFileError(
                f"cannot read {str(file)!r}: {name!r} must hold {counted(n, 'finite degree')}, one per "
                f"{'column' if name == 'lon' else 'row'} of the heights {tuple(shape)}; got {axis.dtype} "
                f"shape {axis.shape}"
            )
        if name == "lon":  # across the antimeridian: [179.5, -179.5, ...] is a step of 1 degree, not of -359
            given, values = values, unwrapped_longitudes(values)
            same = np.flatnonzero((np.diff(values) == 0) & (np.diff(given) != 0))  # 360° apart, made equal
            if len(same):  # "from -180 to -180, no span" of lon [-180, 180]: values the file does not hold
                i = int(same[0])
                raise DataFileError(
                    f"cannot read {str(file)!r}: 'lon' must be a different meridian in each neighbouring column; got "
                    f"lon[{i}] = {given[i]:.9g} and lon[{i + 1}] = {given[i + 1]:.9g}, "
                    f"{abs(given[i + 1] - given[i]):.9g}° apart: the same meridian twice"
                )
        step = (values[-1] - values[0]) / (n - 1)
        worst = float(np.abs(np.diff(values) - step).max())
        if step == 0.0:
            raise DataFileError(
                f"cannot read {str(file)!r}: {name!r} must be evenly spaced degrees, increasing or decreasing; got "
                f"{n} values from {values[0]:.9g} to {values[-1]:.9g}, no span"
            )
        # within 0.1 % of the step, or within the axis's own rounding: a float32 axis of 1 or 3 arc-seconds (an
        # xarray DEM's coordinates) has steps that differ by one float32 spacing of its degrees, 1.5e-5 near 180
        rounding = 2.0 * float(np.spacing(np.abs(axis).max())) if axis.dtype.kind == "f" else 0.0
        if worst > max(1e-3 * abs(step), rounding):
            raise DataFileError(
                f"cannot read {str(file)!r}: {name!r} must be evenly spaced degrees; got steps that differ from "
                f"their mean {step:.9g} by up to {worst:.3g}"
                + (f" (more than the {axis.dtype} rounding of its values, {rounding:.3g})" if rounding else "")
            )
        axes.append((float(values[0]), float(step)))
    (lon0, dlon), (lat0, dlat) = axes
    return np.array([lon0 - 0.5 * dlon, dlon, 0.0, lat0 - 0.5 * dlat, 0.0, dlat], dtype=np.float64)


def npz_heights_key(arrays: Mapping[str, NDArray[Any]], ndims: tuple[int, ...]) -> str | None:
    """The ``.npz`` member that holds the heights: the first of ``heights``, ``elevation`` and ``z`` with one of
    ``ndims`` dimensions (2 for a raster; 2 or 3 where a series may be), else the first of them present (for its
    shape to be refused), else None. A 1-D ``heights`` (a profile, say) beside a 2-D ``elevation`` was read first
    and refused; with a transform, ``elevation`` came first, without one ``heights``."""
    present = [key for key in _GENERIC_KEYS if key in arrays]
    return next((key for key in present if arrays[key].ndim in ndims), present[0] if present else None)


@contextlib.contextmanager
def _pillow_read(file: Path, expected: str, *, detail: str = "", bomb_hint: str = "") -> Iterator[None]:
    """Pillow's refusals while reading the PNG ``file`` as ``expected`` as DataFileErrors: its decompression-bomb
    limit (not an OSError: it went past as Pillow's own exception; ``bomb_hint`` after it) and unreadable content
    (``detail`` after ``expected``); a DataFileError raised inside passes as it is."""
    from PIL import Image, UnidentifiedImageError

    try:
        yield
    except Image.DecompressionBombError as exc:
        raise DataFileError(
            f"cannot read {str(file)!r}: expected {expected} within Pillow's decompression-bomb limit "
            f"(PIL.Image.MAX_IMAGE_PIXELS); got {exc}{bomb_hint}"
        ) from exc
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        if isinstance(exc, DataFileError):
            raise
        raise DataFileError(
            f"cannot read {str(file)!r}: expected {expected}{detail}; got unreadable content ({exc})"
        ) from exc


def _load_png(file: Path, height_unit: str | None) -> Terrain:
    from PIL import Image

    with _pillow_read(file, "a PNG heightmap", bomb_hint=" (a DEM this large reads as a GeoTIFF or .npy)"):
        with Image.open(file) as image:
            mode = image.mode
            if image.format != "PNG":  # Pillow opens any image it knows: a lossy JPEG, a GeoTIFF's bare pixels
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected a PNG heightmap; got a {image.format} image under a .png "
                    "name (a GeoTIFF reads under .tif, keeping its georeferencing)"
                )
            if image.tile and str(image.tile[0][3]).startswith("LA;16"):  # Pillow has no 16-bit grey + alpha mode
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected a greyscale heightmap Pillow reads at full depth; got a "
                    "16-bit greyscale PNG with an alpha channel, which Pillow reads only as 8-bit RGBA (the heights "
                    "would lose their low byte); save it without alpha (missing cells as a transparent grey value or "
                    "a nodata height), or as a GeoTIFF"
                )
            if mode not in ("L", "LA", "I", "I;16", "I;16B", "I;16L", "F"):
                got = (
                    "a 1-bit black-and-white image (mode '1': two levels are no elevation data; save the heights as "
                    "8- or 16-bit greyscale)"
                    if mode == "1"
                    else f"a {mode} image (colour or palette images are not elevation data; an RGB terrain tile reads "
                         f"with its encoding named, height_encoding={' or '.join(map(repr, HEIGHT_ENCODINGS))})"
                )
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected a single-channel 8- or 16-bit greyscale heightmap; got {got}"
                )
            stored = {"L": np.uint8, "LA": np.uint8, "I": np.int32, "F": np.float32}.get(mode, np.uint16)  # I;16*
            _check_read_budget(file, (image.height, image.width), np.dtype(stored))
            # a 2- or 4-bit grey PNG: Pillow scales its samples to 0-255 (x 85, x 17), not its tRNS value
            low_bits = re.fullmatch(r"L;([24])", str(image.tile[0][3])) if image.tile else None
            array = np.array(image)
            transparent = image.info.get("transparency")  # a grey PNG's tRNS value, GDAL's nodata for PNG
    nodata: float | None = (
        transparent if isinstance(transparent, int) and not isinstance(transparent, bool)
        else _png_pam_nodata(file, 255 if mode in ("L", "LA") else 65535)
    )
    if nodata is not None and low_bits:  # the tRNS value in the samples' 0-255 scale (tRNS 15 of 4 bits is 255)
        nodata *= 255 // (2 ** int(low_bits.group(1)) - 1)
    if mode == "LA":  # grey + alpha: a transparent cell (alpha 0) is missing, as GDAL reads alpha as the mask
        array = np.where(array[..., 1] == 0, np.float32(np.nan), array[..., 0].astype(np.float32))
    _refuse_png_scaling(file)
    heights = _elevation(array, file, f"{mode} image", nodata)
    heights, unit = _heights_in_metres(heights, height_unit, file, "height_unit")
    _warn_png_georeferencing(file)
    return _grid(file, heights, spacing=(1.0, -1.0), origin=(0.0, 0.0), crs=None, height_unit=unit)


def _png_pam_nodata(file: Path, top: int) -> float | None:
    """The nodata value of the PNG heightmap ``file``'s grey band in GDAL's PAM file beside it (``dem.png.aux.xml``,
    ``<NoDataValue>`` of ``PAMRasterBand`` 1), which GDAL reads where the PNG has no transparent grey value (tRNS,
    which it takes first): ``gdal_translate -of PNG`` writes it there for a grey + alpha PNG, which has no tRNS, and a
    PNG's nodata set by hand or another tool lies there. Pillow reads no such file: the cells at that value were
    heights (a 9999 m spike, a 0 m pit) where GDAL and every GIS masked them. None without one (or an empty one).

    Read as GDAL reads it, checked against GDAL 3.10 (rasterio's masks) on 8- and 16-bit PNGs: the text as its
    ``CPLAtof`` reads it (:func:`_c_atof`: ``7abc`` and ``1_0`` as the number they start with, 7 and 1, ``0x7`` as 0,
    a text that starts with no number, ``abc`` or ``NAN``, as 0, with a warning naming what it was read as; its
    spellings of NaN and infinity, ``nan`` or ``1.#QNAN``, as such), then, the band being of integers from 0 to
    ``top`` (255 for 8 bits, 65535 for 16), a value within that range cut to its whole part as GDAL casts it (``7.5``
    masks the cells at 7), one outside it (``-0.5``, ``255.5`` of 8 bits, NaN) none."""
    root = _pam_root(file)
    if root is None:
        return None
    for band in root.iter("PAMRasterBand"):
        if band.get("band", "1").strip() != "1":  # a grey + alpha PNG's alpha band
            continue
        text = band.findtext("NoDataValue")
        if text is None or not text.strip():
            return None
        value, whole = _c_atof(text)
        if not math.isfinite(value) or not 0 <= value <= top:
            return None  # no cell of the band holds it (1.#QNAN junk: GDAL's NaN, masking none, said nothing of)
        if not whole:
            warnings.warn(
                f"{file.name}: the NoDataValue {text!r} in {file.name}.aux.xml is not a number; read as "
                f"{value:g}, as GDAL reads it (the number the text starts with, else 0): its cells at "
                f"{math.trunc(value):d} are nodata; write the nodata value as a number there",
                stacklevel=caller_stacklevel(),
            )
        return float(math.trunc(value))
    return None


#: C's ``isspace``, the white space GDAL skips before a number (Python's ``str.strip`` and ``\s`` take Unicode's too:
#: a no-break space before 7 is no number to GDAL)
_C_SPACE = " \t\n\v\f\r"
#: A decimal number as GDAL reads one from the start of a text (fast_float's: ASCII digits, no hex, no '+')
_C_NUMBER = re.compile(r"-?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
#: GDAL's own spellings of NaN and infinity, read before a '+' is skipped: MSVC's (which GDAL built with it wrote) by
#: the text's start, ``1.#INF`` in any case, the rest case-sensitive
_GDAL_PREFIXES = (("-1.#QNAN", math.nan), ("-1.#IND", math.nan), ("-1.#INF", -math.inf), ("1.#QNAN", math.nan),
                  ("1.#SNAN", math.nan), ("1.#INF", math.inf))
#: ... and as the whole text only, after a '+' (``NAN``, ``INFINITY``, ``-nan`` and ``inf `` are 0 to it)
_GDAL_WORDS = {"inf": math.inf, "INF": math.inf, "Inf": math.inf, "Infinity": math.inf, "-inf": -math.inf,
               "-INF": -math.inf, "-Inf": -math.inf, "-Infinity": -math.inf, "nan": math.nan, "NaN": math.nan}


def _c_atof(text: str) -> tuple[float, bool]:
    """``text`` read as a number the way GDAL's ``CPLAtof`` reads a nodata text (``CPLStrtod``; checked against GDAL
    3.10 for each rule here): after C's white space, its spellings of NaN and infinity (:data:`_GDAL_PREFIXES`,
    :data:`_GDAL_WORDS`), else, one '+' skipped, the decimal number the text starts with (``7abc`` -> 7, ``1_0`` -> 1,
    ``0x7`` -> 0, ``7 8`` -> 7, ``+-7`` -> -7), else 0 (``abc``, ``NAN``); with whether that was the whole text (white
    space aside)."""
    start = text.lstrip(_C_SPACE)
    rest = start.rstrip(_C_SPACE)
    for prefix, special in _GDAL_PREFIXES:
        if start.startswith(prefix) or (prefix.endswith("INF") and start.upper().startswith(prefix)):
            return special, rest == prefix or rest.upper() == prefix
    unsigned = start[1:] if start.startswith("+") else start
    if unsigned in _GDAL_WORDS:
        return _GDAL_WORDS[unsigned], True
    match = _C_NUMBER.match(unsigned)
    if match is None:
        return 0.0, False
    return float(match.group(0)), match.group(0) == unsigned.rstrip(_C_SPACE)


def _refuse_png_scaling(file: Path) -> None:
    """A DataFileError when the PNG heightmap ``file``'s ``dem.png.aux.xml`` (GDAL's PAM file) gives its band a scale
    or offset other than 1 and 0 (height = value * scale + offset): `gdal_translate -of PNG` of a DEM of scaled
    integers keeps the integers and writes them there, and the PNG's pixels, which Pillow reads, were taken as heights
    (decimetres as metres: 10 times too high) without a word. A GeoTIFF made from the PNG keeps them, and load_dem
    reads it scaled. An aux.xml that cannot be read or parsed is left to the georeferencing warning."""
    aux = file.with_name(file.name + ".aux.xml")
    root = _pam_root(file)
    if root is None:
        return
    for band in root.iter("PAMRasterBand"):
        if band.get("band", "1").strip() != "1":  # a grey + alpha PNG's alpha band
            continue
        try:
            scale, offset = (float(band.findtext(tag) or default) for tag, default in (("Scale", 1), ("Offset", 0)))
        except ValueError:  # not numbers: GDAL reads none either
            return
        if scale != 1.0 or offset != 0.0:
            prj = _prj_beside(file)
            srs = f"-a_srs {prj.name} " if prj is not None else ""
            raise DataFileError(
                f"cannot read {str(file)!r}: expected a PNG heightmap of heights as stored; got scale {scale:g}, "
                f"offset {offset:g} of its values in {aux.name} (height = value * scale + offset), which load_dem "
                f"does not read for a PNG: make it a GeoTIFF, which GDAL reads with them (`gdal_translate "
                f"{srs}{file.name} {file.stem}.tif`)"
            )


def _pam_root(image: Path) -> Any:
    """The parsed XML (an ElementTree element) of GDAL's PAM file beside the local raster ``image``
    (``earth.png.aux.xml``); None without one, or with one that cannot be read or parsed (GDAL reads nothing from
    it either, and says nothing)."""
    from xml.etree import ElementTree

    aux = image.with_name(image.name + ".aux.xml")
    try:
        return ElementTree.fromstring(aux.read_bytes()) if aux.is_file() else None
    except (OSError, ElementTree.ParseError):
        return None


def _warn_png_georeferencing(file: Path, tile: bool = False) -> None:
    """Warn, at the caller of :func:`load_dem`, when GDAL would georeference the PNG heightmap ``file`` by a world
    file beside it (``dem.pgw``, ``dem.pngw``, ``dem.wld``, in lower or UPPER case) or by a geotransform in its
    ``dem.png.aux.xml`` (as a GIS exports a PNG): load_dem reads a PNG as an unreferenced grid of 1 m cells at
    (0, 0), and a 30 m DEM exported so was meshed 30 times too steep, away from its place, without a word (the
    texture readers place such a PNG by its world file). The command it suggests names the .prj :func:`prj_crs`
    would read (:func:`_prj_files`). A terrain ``tile`` (``height_encoding``), placed by a world file only, is told
    to write one from its ``.aux.xml`` (a GeoTIFF of its colours is refused)."""
    # a tile's world file, if any, placed it (_png_world_file): only its .aux.xml is left to look for
    found = None if tile else next((side for side in world_file_names(file) if side.is_file()), None)
    if found is None:
        aux = file.with_name(file.name + ".aux.xml")
        try:
            found = aux if aux.is_file() and "<GeoTransform>" in aux.read_text(errors="replace") else None
        except OSError:
            found = None
    if found is None:
        return
    if tile:
        warnings.warn(
            f"{file.name}: its georeferencing in {found.name} is not read: load_dem places a terrain tile by a world "
            f"file beside it ({file.stem}.pgw, .pngw or .wld) and reads it unreferenced otherwise, spacing (1, -1) and "
            f"origin (0, 0); to place it, write one (`gdal_translate -of PNG -co WORLDFILE=YES {file.name} "
            f"placed.png` writes placed.png and placed.wld; a .prj beside it gives its CRS), or give its cell size "
            f"(the CLI's --spacing)",
            stacklevel=caller_stacklevel(),
        )
        return
    prj = _prj_beside(file)  # as prj_crs looks (dem.png.prj too)
    srs = f"-a_srs {prj.name} " if prj is not None else ""
    warnings.warn(
        f"{file.name}: its georeferencing in {found.name} is not read: load_dem reads a PNG heightmap as an "
        f"unreferenced grid, spacing (1, -1) and origin (0, 0); to place it, make it a GeoTIFF, which GDAL reads "
        f"with it (`gdal_translate {srs}{file.name} {file.stem}.tif`), or give its cell size (the CLI's --spacing)",
        stacklevel=caller_stacklevel(),
    )


def decode_terrain_rgb(rgb: NDArray[Any], encoding: str) -> NDArray[np.float64]:
    """The heights in metres, float64, of the (..., 3 or more) 8-bit ``rgb`` pixels of a terrain tile in
    ``encoding`` (:data:`HEIGHT_ENCODINGS`; a fourth channel, alpha, is ignored). Both are exact in float64 up to its
    rounding of the decimal: Terrain-RGB's 0.1 m steps as (code - 100000) / 10, the float64 nearest the decimal
    height, Terrarium's 1/256 m steps exactly, as (code - 32768·256) / 256, code = R·65536 + G·256 + B in both.
    The 24-bit code is built in one int32 array and divided into one float64 (12 bytes a pixel besides ``rgb``;
    three int64 channels and their sums took 40)."""
    code = rgb[..., 0].astype(np.int32)
    for channel in (1, 2):
        code <<= 8
        code |= rgb[..., channel]
    code -= 100000 if encoding == "terrain-rgb" else 32768 * 256
    heights = code.astype(np.float64)
    del code
    heights /= 10.0 if encoding == "terrain-rgb" else 256.0
    return heights


def _load_encoded_png(file: Path, encoding: str) -> Terrain:
    """:func:`load_dem` of an RGB(A) PNG web-map terrain tile whose pixels encode heights in ``encoding``
    (:data:`HEIGHT_ENCODINGS`, checked), decoded in float64 (:func:`decode_terrain_rgb`) and kept as float32, as
    any heights are; alpha 0 (a transparent pixel, or a transparent colour, tRNS) marks a missing cell, the
    encodings' only nodata. A palette PNG reads through its palette (its colours are the codes, losslessly). A world
    file beside it (``tile.pgw``, ``tile.pngw``, ``tile.wld``) places it, with the CRS of a ``.prj`` beside it, as
    GDAL reads one: a web-map tile is in EPSG:3857, whose metres are ground metres times 1/cos φ (warned, see
    :func:`load_dem`). A greyscale PNG, or one of 16 bits per channel (Pillow reads 8), is refused."""
    from PIL import Image

    label = f"height_encoding={encoding!r}"
    with _pillow_read(file, "a PNG terrain tile", detail=f" ({label})"):
        with Image.open(file) as image:
            mode = image.mode
            rawmode = str(image.tile[0][3]) if image.tile else ""
            if image.format != "PNG":
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected a PNG terrain tile ({label}); got a {image.format} image "
                    f"under a .png name (a lossy format would not keep the codes)"
                )
            if mode not in ("RGB", "RGBA", "P", "PA") or rawmode.startswith("LA;16"):
                got = ("a 16-bit greyscale + alpha" if rawmode.startswith("LA;16")
                       else f"a greyscale ({mode})" if mode in ("1", "L", "LA", "La", "I", "F") or mode.startswith("I;")
                       else f"a {mode}")
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected an 8-bit RGB or RGBA PNG terrain tile ({label}); got {got} "
                    f"image (a greyscale heightmap reads its values as heights, without height_encoding)"
                )
            if ";16" in rawmode:  # Pillow reads 16-bit RGB(A) as 8 bits per channel: the codes' low bytes lost
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected an 8-bit RGB or RGBA PNG terrain tile ({label}); got a "
                    f"PNG of 16 bits per channel, which Pillow reads only as 8 (the encodings use 8 bits per channel)"
                )
            _check_read_budget(file, (image.height, image.width), np.dtype(np.uint32))
            rgba = picture_uint8(image, f"terrain tile {str(file)!r}", alpha=True)
    missing = rgba[..., 3] == 0 if rgba.shape[-1] == 4 else None
    decoded = decode_terrain_rgb(rgba, encoding)
    del rgba
    heights = _elevation(decoded, file, f"{encoding} {mode} image", None, missing, warn_voids=False)
    del decoded
    unit = "m"  # the encoding's unit (a height_unit of another was refused): no placement asks for one
    geotransform = _png_world_file(file)
    if geotransform is None:
        _warn_png_georeferencing(file, tile=True)  # an .aux.xml geotransform, not read
        return _grid(file, heights, spacing=(1.0, -1.0), origin=(0.0, 0.0), crs=None, height_unit=unit)
    crs = prj_crs(file, "the PNG tile", DataFileError)  # None without a .prj (and rasterio unimported)
    return _georeferenced(file, heights, geotransform, crs, geographic=_is_geographic(crs), metres=None,
                          height_unit=unit)


def _png_world_file(file: Path) -> NDArray[np.float64] | None:
    """The GDAL geotransform (of the cell corners) of the world file beside the PNG ``file`` (:func:`world_file`,
    strict: one that is not six finite numbers is a DataFileError); None without one."""
    found = world_file(file, strict=True)
    if found is None:
        return None
    (a, d, b, e, c, f), _ = found
    return np.array([c - (a + b) / 2, a, b, f - (d + e) / 2, d, e], dtype=np.float64)


def world_file_names(image: Path) -> list[Path]:
    """The world files GDAL looks for beside ``image``, in its order: the extension's first and last letters and
    "w" (``tile.pgw`` for ``tile.png``, ``ortho.jgw`` for ``ortho.jpg``), the extension and "w" (``tile.pngw``),
    then ``.wld``, each in lower case, then UPPER."""
    ext = image.suffix[1:].lower()
    names = [f"{ext[0]}{ext[-1]}w", f"{ext}w"] if ext else []
    return [image.with_suffix(f".{name}") for suffix in [*names, "wld"] for name in (suffix, suffix.upper())]


def world_file(image: Path, *, strict: bool = False) -> tuple[tuple[float, ...], Path] | None:
    """The six numbers A, D, B, E, C, F of the first world file beside ``image`` (:func:`world_file_names`; (C, F)
    the centre of the upper-left pixel) and its path; None without one. One that does not start with six finite
    numbers gives None, as GDAL ignores it; with ``strict`` it is a DataFileError naming it, as is one of more than
    six numbers or one that cannot be read."""
    for side in world_file_names(image):
        try:
            words = side.read_text(errors="replace").split()
        except (OSError, ValueError) as exc:
            if strict and side.is_file():
                raise DataFileError(f"cannot read {str(side)!r}, the world file of {str(image)!r}: {exc}") from exc
            continue
        try:
            numbers = tuple(float(w) for w in (words if strict else words[:6]))
        except ValueError:
            numbers = ()
        if len(numbers) == 6 and all(map(math.isfinite, numbers)):
            return numbers, side
        if strict:
            raise DataFileError(
                f"cannot read {str(image)!r}: expected its world file {side.name!r} to hold six finite numbers "
                f"(A, D, B, E, C, F: pixel width, rotations, pixel height, upper-left pixel centre); got "
                f"{' '.join(words)[:200]!r}"
            )
        return None
    return None


#: Texels of the full-size level :func:`fill_transparent` reads and writes at a time (half as many rows).
_FILL_BAND_TEXELS = 1 << 22


def fill_transparent(pixels: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """The straight-alpha texture ``pixels`` ((H, W, 2) grey + alpha or (H, W, 4) RGBA uint8) with the colour of
    each fully transparent texel (alpha 0) replaced by that of the opaque texels near it, by pull-push (a pyramid of
    2 x 2 sums weighted by alpha, each texel of no weight taking its coarser level's colour); the alpha and every
    texel of some alpha are kept. ``pixels`` itself when no texel is transparent, or every one is. A texture sampler
    (bilinear, mipmaps: a glTF viewer's, VTK's) filters straight colour and alpha apart, so a transparent texel's
    colour, meaningless (the magenta or black under the polar caps `gdalwarp -dstalpha` leaves transparent), showed
    in the opaque texels' edge, and in whole coarser mipmaps, as a fringe of that colour. The full-size level is
    read and written in bands of rows: the float32 pyramid from level 1 on holds a third of the texels."""
    alpha = pixels[..., -1]
    if not alpha.size or alpha.min() > 0 or alpha.max() == 0:  # before the mask of holes: none for an opaque texture
        return pixels
    hole = alpha == 0
    h, w, channels = pixels.shape
    check_budget(pixels.nbytes + 6 * channels * ((h + 1) // 2) * ((w + 1) // 2) * 4, f"the colour pyramid filling "
                 f"the transparent texels of a {w} x {h} texture", hint="give a smaller texture")
    band = 2 * max(1, _FILL_BAND_TEXELS // max(w, 1))  # full-size rows at a time (even: whole 2 x 2 blocks)

    def halved(colour: NDArray[np.float32], weight: NDArray[np.float32]) -> tuple[NDArray[np.float32], ...]:
        if colour.shape[0] % 2 or colour.shape[1] % 2:  # an odd side padded with no weight (np.pad copies)
            pad = ((0, colour.shape[0] % 2), (0, colour.shape[1] % 2))
            colour, weight = np.pad(colour, pad + ((0, 0),)), np.pad(weight, pad)
        return (colour[0::2, 0::2] + colour[1::2, 0::2] + colour[0::2, 1::2] + colour[1::2, 1::2],
                weight[0::2, 0::2] + weight[1::2, 0::2] + weight[0::2, 1::2] + weight[1::2, 1::2])

    # level 1 written band by band into arrays of its size (the bands' list concatenated held it twice)
    level = (np.empty(((h + 1) // 2, (w + 1) // 2, channels - 1), np.float32),
             np.empty(((h + 1) // 2, (w + 1) // 2), np.float32))
    for r in range(0, h, band):  # pull, level 0 -> 1 in bands
        weight = pixels[r:r + band, :, -1].astype(np.float32)
        colour, weight = halved(pixels[r:r + band, :, :-1] * weight[..., None], weight)
        level[0][r // 2:r // 2 + len(weight)], level[1][r // 2:r // 2 + len(weight)] = colour, weight
    levels = [level]
    del level, colour, weight
    while levels[-1][1].shape != (1, 1):  # pull: 2 x 2 sums
        levels.append(halved(*levels[-1]))
    filled = levels[-1][0] / levels[-1][1][..., None]  # the coarsest: one texel, of some weight
    del levels[-1]
    while levels:  # push: a texel of no weight takes its coarser texel's colour (each level let go once pushed)
        colour, weight = levels.pop()
        rows, cols = weight.shape
        coarser = np.repeat(np.repeat(filled, 2, axis=0), 2, axis=1)[:rows, :cols]
        # in place: the boolean gathers (colour[some], weight[some], their quotient) each took a level's size
        np.divide(colour, weight[..., None], out=coarser, where=(weight > 0)[..., None])
        filled = coarser
        del colour, weight
    out = pixels.copy()
    for r in range(0, h, band):  # push, level 1 -> 0 in bands
        gap = hole[r:r + band]
        coarser = np.repeat(np.repeat(filled[r // 2:(r + band) // 2], 2, axis=0), 2, axis=1)[:len(gap), :w]
        out[r:r + band, :, :-1][gap] = np.clip(np.round(coarser[gap]), 0, 255).astype(np.uint8)
    return out


def picture_uint8(picture: Any, what: str, *, alpha: bool = False) -> NDArray[np.uint8]:
    """An opened Pillow image as an (H, W, 3) uint8 array, (H, W, 4) with ``alpha`` when it has an alpha band (a
    premultiplied one, modes ``RGBa`` and ``La``, un-premultiplied as RGBA and LA) or a transparent colour (a
    palette's, an L, RGB or 1-bit PNG's tRNS: Pillow's ``info["transparency"]``).

    A 16-bit greyscale image (modes ``I;16*``, and ``I`` within 0-65535) is scaled by its full range (value / 257,
    as Pillow reads 16-bit RGB): Pillow's own conversion to RGB saturates every value above 255, which draped a
    16-bit relief almost all white. A float image, or an ``I`` image beyond 0-65535, is refused naming ``what``.
    """
    mode = picture.mode
    if mode in ("I", "F") or mode.startswith("I;16"):
        # a TIFF of signed integer samples (SampleFormat 2: an int16 DEM, which Pillow opens as mode I) is elevation
        # or other data, not a picture: its heights were scaled by 1/257, a nearly black drape, and accepted only
        # while no value was negative; refused as rasterio's read of such a TIFF refuses it (int16)
        tags = getattr(picture, "tag_v2", None)
        sample_format = tags.get(339) if tags is not None else None
        if mode != "F" and sample_format is not None and 2 in np.atleast_1d(sample_format).tolist():
            bits = tags.get(258) if tags is not None else None
            depth = f"{int(np.atleast_1d(bits)[0])}-bit " if bits is not None else ""
            raise InvalidInputError(f"{what} must be an 8-bit or 16-bit image of unsigned samples; got a TIFF of "
                                    f"signed {depth}integers (SampleFormat 2), such as a DEM's heights, not a "
                                    "picture: convert it to 8 bits first (`gdal_translate -ot Byte -scale ...`)")
        gray = np.asarray(picture)
        if mode == "F" or (gray.size and (gray.min() < 0 or gray.max() > 65535)):
            low, high = (float(gray.min()), float(gray.max())) if gray.size else (0.0, 0.0)
            raise InvalidInputError(f"{what} must be an 8-bit or 16-bit image; got Pillow mode {mode} with values "
                                    f"{low:g} to {high:g}")
        return np.repeat(np.round(gray / 257.0).astype(np.uint8)[..., None], 3, axis=2)
    if mode in _PREMULTIPLIED:  # alpha band "a": RGBa kept no alpha (converted to RGB), La raised Pillow's ValueError
        picture = picture.convert(_PREMULTIPLIED[mode])  # un-premultiplied, as RGBA and LA are
    elif alpha and mode in ("P", "L", "RGB", "1") and "transparency" in picture.info:
        # a palette's or a PNG's transparent colour (tRNS; a 1-bit one's too) is alpha without an alpha band:
        # converted to RGB, its pixels came out opaque in whatever colour they hold
        picture = picture.convert("RGBA")
    return np.asarray(picture.convert("RGBA" if alpha and "A" in picture.getbands() else "RGB"))


#: Pillow's premultiplied-alpha modes and the straight-alpha ones they convert to (dividing the colour by alpha).
_PREMULTIPLIED = {"RGBa": "RGBA", "La": "LA"}


#: Held while a raster is opened with rasterio's NotGeoreferencedWarning filtered out (:func:`open_raster`): the lock of
#: every warning block of the library (stepterrain._warning_filters).
_OPEN_QUIETLY = FILTERS


def open_raster(path: str | os.PathLike[str]) -> Any:
    """``rasterio.open(path)`` without rasterio's NotGeoreferencedWarning ("Dataset has no geotransform ..."), which
    it gives when it opens a plain TIFF; the caller closes the dataset (``with open_raster(path) as dataset``).

    ``warnings.catch_warnings`` swaps the filters of the whole process and puts back the list it found: two threads
    reading plain TIFFs at once (a service loading DEMs, building pyramids) left the "ignore" filter in the process
    for good, as the second put back the first's list. The opens are one at a time here, and only the opens (the
    warning comes from the open; the reads run at once)."""
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with _OPEN_QUIETLY, warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        # a gzip's size found once, at its end: GDAL wrote it to a '.gz.properties' file beside the user's .gz
        with rasterio.Env(CPL_VSIL_GZIP_WRITE_PROPERTIES="NO"):
            return rasterio.open(os.fspath(path))  # a GdalPath's GDAL path (its str() is the text as given)


def _load_geotiff(
    file: Path, band: int, height_unit: str | None, crop: Sequence[float] | None = None, option: str = "crop",
    refuse: Callable[[Terrain], None] | None = None,
) -> Terrain:
    """A GeoTIFF's band as :func:`load_dem` reads it; with ``crop`` only the window of the nodes
    ``Terrain.crop(crop)`` keeps (see :func:`read_dem`)."""
    try:
        import rasterio
        from rasterio.enums import ColorInterp
        from rasterio.errors import RasterioError
        from rasterio.windows import Window
    except ImportError as exc:
        raise MissingDependencyError(
            f"reading {'GeoTIFF' if file.suffix.lower() in ('.tif', '.tiff') else _gdal_format(file)} needs "
            "rasterio: pip install 'stepterrain[geo]'"
        ) from exc

    window = header = place = None
    try:
        try:
            opened = open_raster(file)
        except UnicodeEncodeError as exc:  # a Latin-1 name ('H\xf6he.tif'): surrogate escapes rasterio can't encode
            raise DataFileError(
                f"cannot read {str(file)!r}: its path is not UTF-8 (its bytes: {os.fsencode(str(file))!r}), and GDAL "
                "takes file names in UTF-8 only; rename the file (or its folder), e.g. `convmv -f latin1 -t utf8 "
                "--notest NAME`"
            ) from exc
        except RasterioError as exc:
            if not isinstance(file, GdalPath):
                raise
            # a missing file inside a zip, an unreachable URL: GDAL's reason, not "unreadable content"
            gdal = os.fspath(file)
            reason = gdal_reason(exc)
            reason = (_hgt_refusal(file, reason) or _asc_refusal(file, reason)
                      or f"GDAL cannot open it as {_gdal_format(file)}: {reason}")
            raise DataFileError(f"cannot read {str(file)!r}" + (f" (GDAL path {gdal!r})" if gdal != str(file) else "")
                                + f": {reason}") from exc
        with opened as dataset:
            if band > dataset.count:
                raise InvalidInputError(
                    f"band must be between 1 and {dataset.count} for {str(file)!r}; got band={band}"
                )
            interp = dataset.colorinterp[band - 1]
            if interp not in (ColorInterp.gray, ColorInterp.undefined):  # an alpha band was read as heights
                what = (
                    "an alpha (transparency) band, which masks the other bands"
                    if interp == ColorInterp.alpha
                    else f"a colour image band ({interp.name})"
                    if interp.name in _COLOUR_BANDS
                    else f"an image band ({interp.name})"
                )
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected an elevation band (grey or undefined); band {band} is "
                    f"{what}, not elevation data"
                )
            stored = dataset.dtypes[band - 1]
            if stored.startswith("complex"):  # from the header, before the read: CInt16 ('complex_int16') has no
                # NumPy dtype, and np.dtype() of it in the budget check raised a raw TypeError
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected real-valued elevation data; got band {band} of dtype "
                    f"{stored}"
                )
            scale, offset = dataset.scales[band - 1], dataset.offsets[band - 1]
            if not (math.isfinite(scale) and scale != 0.0 and math.isfinite(offset)):  # 0: one flat height, silently
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected band {band}'s scale and offset (height = value * scale + "
                    f"offset) to be a finite, non-zero scale and a finite offset; got scale {scale!r}, offset "
                    f"{offset!r} (if the values are heights as stored: `gdal_edit.py -scale 1 -offset 0 {file.name}`)"
                )
            file_unit = dataset.units[band - 1]
            transform = dataset.transform
            crs_obj = dataset.crs
            shape = (dataset.height, dataset.width)
            if transform.is_identity:  # no geotransform: perhaps ground control points or RPCs instead
                _refuse_warped_georeferencing(file, dataset.gcps, dataset.rpcs)
                _refuse_gzip_world_file(file)
            elif crs_obj is None:  # a world file's grid: its CRS in a .prj beside it (degrees were read as metres)
                prj = prj_crs(file, "DEM", DataFileError)
                crs_obj = _crs_object(prj) if prj else None
            crs = _crs_string(crs_obj)
            named_by = (
                "height_unit" if height_unit else f"band {band}'s unit" if file_unit else f"the vertical unit of {crs}"
            )
            _warn_unit_override(file, height_unit, file_unit, f"band {band}'s unit")
            if not height_unit:
                _warn_unit_against_vertical(file, file_unit, crs, f"band {band}'s unit")
            unit, crs, factor = _vertical_unit(height_unit or file_unit, crs)
            if crop is not None:  # the whole grid placed from the header, then only the crop's window read
                # the unit as _heights_in_metres returns it: the Terrain's height_unit
                kept_unit = unit if unit and unit.strip() else None
                header, place = _geotiff_header(file, shape, transform, crs_obj, crs, kept_unit)
                if refuse is not None:
                    refuse(header)
                try:
                    bounds, (i0, i1), (j0, j1) = header._crop_nodes(crop)
                except InvalidInputError as exc:
                    raise InvalidInputError(f"{option}: {exc}") from None
                window = Window(j0, i0, j1 - j0 + 1, i1 - i0 + 1)
                _check_read_budget(file, (i1 - i0 + 1, j1 - j0 + 1), np.dtype(dataset.dtypes[band - 1]),
                                   f"rows {i0}-{i1}, columns {j0}-{j1} of its {shape[0]} x {shape[1]}, the crop's",
                                   hint=f"make the {option} smaller, or coarsen the file first (gdal_translate "
                                        "-outsize)")
            else:
                _check_read_budget(file, shape, np.dtype(dataset.dtypes[band - 1]),
                                   hint=WHOLE_RASTER_HINT)
            # block by block: GDAL's one big read of a raw raster (.bil, .flt) cut short filled the missing rows with
            # zeros without an error (heights of 0 m); its block reads fail there, as a GeoTIFF's do
            with rasterio.Env(GDAL_ONE_BIG_READ="NO"):
                masked = dataset.read(band, masked=True, window=window)
                unmasked = _missing_beyond_gdal_mask(dataset, band, masked.data, window)
            if dataset.driver in _ASCII_GRIDS and shape[0] and shape[1]:  # values GDAL ignores, or a last one
                # it made up (0 m), where it read the last cell
                last_is_zero = (masked.shape[0] and masked.shape[1] and masked.data[-1, -1] == 0
                                and (window is None or (i1 == shape[0] - 1 and j1 == shape[1] - 1)))
                _check_ascii_grid(file, shape, dataset.driver, bool(last_is_zero))
    except RasterioError as exc:
        reason = gdal_reason(exc)
        raise DataFileError(
            f"cannot read {str(file)!r}: "
            + (_hgt_refusal(file, reason) or _asc_refusal(file, reason)
               or f"expected {_gdal_format(file)}; got unreadable content ({reason})")
        ) from exc

    if masked.dtype == np.bool_ or masked.dtype.kind not in "iuf":  # a complex band kept its real part silently
        raise DataFileError(
            f"cannot read {str(file)!r}: expected real-valued elevation data; got band {band} of dtype {masked.dtype}"
        )
    # one working copy, scaled and filled in place (the masked array's astype, arithmetic and filled each made one,
    # and the stored band and its mask stayed alive to the end): float64 stays float64 until _elevation, which names
    # a value beyond float32 (a cast here made it nodata)
    mask = np.ma.getmask(masked)
    if unmasked is not None:
        mask = unmasked if mask is np.ma.nomask else np.logical_or(mask, unmasked, out=unmasked)
    del unmasked
    # load_dem's nodata, compared with the values as stored, as the file's own nodata is (GDAL's convention)
    given = given_nodata(masked.data, _GIVEN_NODATA.get(), None if mask is np.ma.nomask else mask)
    if given is not None:
        mask = given
    del given
    _warn_void_values(file, masked.data, None if mask is np.ma.nomask else mask, f"band {band}")
    stored = None
    if scale != 1.0 or offset != 0.0:  # stored values -> heights, GDAL's convention: value * scale + offset
        array = masked.data.astype(np.float64)
        array *= scale
        array += offset
        stored = (masked.dtype, scale, offset)  # for a refusal of values beyond float32, naming them as stored
    else:  # a float band as stored is already a copy of the file's data: filled in place
        array = masked.data.astype(np.float64 if masked.dtype.itemsize > 4 else np.float32, copy=False)
    del masked
    if mask is not np.ma.nomask:
        np.copyto(array, np.nan, where=mask)
    del mask
    try:
        # warned above, and its given nodata applied, as stored
        heights = _elevation(array, file, f"band {band}", warn_voids=False, stored=stored, given=())
    except Exception:
        if window is not None and not np.isfinite(array).any():  # as Terrain.crop refuses it
            raise InvalidInputError(f"{option}: {crop_of_nodata(bounds, array.shape)}") from None
        raise
    del array  # a float64 band's copy, before the heights are converted to metres
    heights, height_unit = _heights_in_metres(heights, unit, file, named_by, factor)
    if header is None or place is None:  # the whole file, placed now (its warnings after the heights')
        place = _geotiff_placement(file, shape, transform, crs_obj, crs, height_unit)
        spacing, origin, crs, source = place.spacing, place.origin, place.crs, place.source
    else:  # the crop's nodes, where Terrain.crop puts them
        (dx, dy), (ox, oy) = header.spacing, header.origin
        spacing, origin, crs, source = (dx, dy), (ox + j0 * dx, oy + i0 * dy), header.crs, header.source
    terrain = _grid(file, heights, spacing=spacing, origin=origin, crs=crs, source=source, height_unit=height_unit)
    _check_placed(file, place, terrain)  # a grid without a CRS that looks like degrees: told by its (crop's) heights
    return terrain


#: Bytes of an ASCII grid counted at a time.
_ASC_CHUNK = 1 << 22

#: Bytes at the start of an ASCII grid's values looked at for the values each line holds (a grid of another width).
_ASC_FIRST_ROW = 1 << 20

#: Bytes at the start of an ASCII grid looked at for its header (a few lines; blank ones among them).
_ASC_HEADER = 1 << 20

#: A line of an ASCII grid as GDAL's reader ends it: at \n, \r\n or a lone \r (a classic Mac file); empty at the end.
_ASC_LINE = re.compile(rb"[^\r\n]*(?:\r\n|\r|\n)?")

#: NUL padding and a DOS end-of-file mark (Ctrl-Z), which end an ASCII grid's values, as spaces.
_ASC_NO_VALUE = bytes.maketrans(b"\x00\x1a", b"  ")

#: The header keywords of an ESRI ASCII grid (GDAL's AAIGrid) and a GRASS one (GRASSASCIIGrid: ``north: 4000030``,
#: read under an .asc name too), lower case, without the GRASS colon.
_ASC_KEYWORDS = frozenset(("ncols", "nrows", "xllcorner", "yllcorner", "xllcenter", "yllcenter", "cellsize", "dx",
                           "dy", "nodata_value", "nodata", "north", "south", "east", "west", "rows", "cols", "null",
                           "type", "multiplier"))

#: GDAL's ASCII grid drivers whose reader takes the end of the file for the end of a missing last value, the format
#: as messages name it, and its header's keywords for the rows and columns.
_ASCII_GRIDS = {"AAIGrid": ("an ESRI ASCII grid", "nrows", "ncols"),
                "GRASSASCIIGrid": ("a GRASS ASCII grid", "rows", "cols")}


def _ascii_grid_opener(file: Path) -> Callable[[], BinaryIO] | None:
    """A function opening the bytes of the ASCII grid ``file`` as GDAL reads them: a local file, or one in a local
    gzip (``/vsigzip/``) or zip (``/vsizip/``, the archive's path in GDAL's braces or not); None for one GDAL reads
    through another virtual file system (a URL, a tar, a zip in a zip)."""
    gdal = os.fspath(file)
    if not isinstance(file, GdalPath):
        return lambda: open(gdal, "rb")
    if gdal.startswith("/vsigzip/") and os.path.isfile(gdal[len("/vsigzip/"):]):
        return lambda: gzip.open(gdal[len("/vsigzip/"):], "rb")
    archive = local_archive(file) if gdal.startswith("/vsizip/") else None
    if archive is None or not os.path.isfile(archive):
        return None
    named = next((n for n in (f"/vsizip/{archive}/", f"/vsizip/{{{archive}}}/") if gdal.startswith(n)), None)
    if named is None:
        return None
    member = gdal[len(named):]

    def opener() -> BinaryIO:
        with zipfile.ZipFile(archive) as zipped:  # the member's stream keeps the archive's file open
            return zipped.open(member)

    return opener


def _check_ascii_grid(file: Path, shape: tuple[int, int], driver: str, last_is_zero: bool) -> None:
    """Refuse the ASCII grid ``file`` (GDAL's ``driver``: ESRI's or GRASS's) of ``shape`` where its values do not
    match its header, which GDAL reads without a word:

    - an indented header line after the first: GDAL's header ends at the first line not starting with a letter,
      and the rest of it was read as heights (the keywords as 0);
    - more values than the header's rows x columns: GDAL reads the first rows x columns in order and ignores the
      rest (a header declaring too few rows read the grid cut, and placed from its lower-left corner, too low; too
      few columns read every row shifted);
    - rows and columns swapped: every data line (of those in the values' first MiB) holding nrows values (not a
      multiple nor a divisor of ncols), the lines of nrows making up all the values (past the first MiB: nrows
      dividing their count), ncols lines of nrows. Other widths read: a row a line, several whole rows a line,
      rows wrapped evenly over lines, the whole grid on one line, and a file wrapping its values at a fixed width
      across rows (ESRI's format needs no line break at a row's end; GDAL reads the values in order), which no
      count tells from a wrong ncols with as many values as declared;
    - fewer values than declared where the last cell read 0 (``last_is_zero``): GDAL refuses a file cut short
      ("File short"), but for the very last value, which it reads as 0 (the end of the file ends the last but one).

    Lines end at \n, \r\n or a lone \r (a classic Mac file), as GDAL's reader ends them. A line after the first
    starting with a letter is a header line to GDAL: a one-column grid's first value ``NaN`` on its own line too
    (GDAL then misses a value and reads the last as 0), which the refusal names.

    Not detected: a row longer and another shorter further down (as many values, the first row whole); lines of k
    values where k divides ncols or ncols divides k (a grid 3 wide declared 6 wide, with half its rows); a file
    GDAL reads through another virtual file system (a URL, a tar: see :func:`_ascii_grid_opener`). The values are
    counted at about 250 MB/s (vectorised, 0.2 s for a 55 MB grid GDAL reads in 2.5 s), a crop's file whole."""
    opener = _ascii_grid_opener(file)
    if opener is None:
        return
    what, rows_word, cols_word = _ASCII_GRIDS[driver]
    nrows, ncols = shape
    expected = nrows * ncols
    declares = f"{rows_word} {nrows}, {cols_word} {ncols}, as its header declares"
    with opener() as handle:
        # the header as GDAL finds its end: the first line, then those starting with a letter (or blank), up to the
        # first starting otherwise, but for values of 'null ' or 'nan '; a line ends at \n, \r\n or a lone \r (a
        # classic Mac file), as GDAL's reader takes either for a line's end
        head = handle.read(_ASC_HEADER)
        start = _ASC_LINE.match(head).end()
        number = 1
        taken = None  # the last header line taken that is not blank: its number and text
        while True:
            line = _ASC_LINE.match(head, start).group()
            number += 1
            if not line:
                break
            if line[:1] in (b"\r", b"\n") or (line[:1].isalpha() and not line.startswith(b"null ")
                                                and line[:4].lower() != b"nan "):
                if line[:1] not in (b"\r", b"\n"):
                    taken = (number, line)
                start += len(line)
                continue
            words = line.split()
            if line[:1].isspace() and words and words[0].decode("latin-1").rstrip(":").lower() in _ASC_KEYWORDS:
                shown = line.decode("latin-1").rstrip("\r\n")
                raise DataFileError(
                    f"cannot read {str(file)!r}: expected {what}'s header lines each starting with its keyword; got "
                    f"header line {number} ({shown!r}) starting with spaces, where GDAL's reader ends the header and "
                    "would read the rest of it as heights; remove the spaces at the lines' starts"
                )
            break
        handle.seek(start)
        first = handle.read(_ASC_FIRST_ROW)
        handle.seek(start)
        cut = len(first) == _ASC_FIRST_ROW
        lines = first.translate(_ASC_NO_VALUE).replace(b"\r", b"\n").split(b"\n")
        if cut:
            lines.pop()  # perhaps cut: not known to end there
        counts = {len(line.split()) for line in lines} - {0}
        values = 0
        joined = False  # whether the last chunk ended inside a value
        while chunk := handle.read(_ASC_CHUNK):
            data = np.frombuffer(chunk, np.uint8)
            space = (data == 32) | ((data - 9) < 5)  # C's isspace, as GDAL's reader: ' ', \t \n \v \f \r
            space |= (data == 0) | (data == 26)  # and NUL padding or a DOS end-of-file mark (Ctrl-Z) after the values
            values += int(np.count_nonzero(space[:-1] > space[1:])) + (not joined and not space[0])
            joined = not space[-1]
    # rows and columns swapped: every data line (of those looked at) holding nrows values, nrows neither a multiple
    # nor a divisor of ncols, the lines making up all the values: ncols lines of nrows. Any other even width reads:
    # values wrapped at a fixed width across rows (as GDAL reads them) cannot be told from a wrong ncols (r136: a
    # 40 x 25 grid written 10 a line was refused)
    if len(counts) == 1:
        (k,) = counts
        held = sum(1 for line in lines if line.split()) * k
        if k == nrows and k % ncols and ncols % k and (held == values if not cut else values % k == 0):
            rows = f"{values // k:,} lines of {k:,} values"
            raise DataFileError(
                f"cannot read {str(file)!r}: expected {what} of rows of {ncols:,} values ({declares}); got {rows} "
                f"each: its {rows_word} and {cols_word} swapped? (GDAL would read every row shifted)"
            )
    if values > expected:
        whole = f" ({values // ncols:,} rows of {ncols:,})" if values % ncols == 0 else ""
        raise DataFileError(
            f"cannot read {str(file)!r}: expected {what} of {nrows:,} x {ncols:,} = {expected:,} values ({declares}); "
            f"got {values:,} values{whole}: GDAL reads the first {expected:,} in order and ignores the rest, so the "
            f"grid would be read cut or its rows shifted (a wrong {rows_word} or {cols_word} in the header?)"
        )
    if values < expected and last_is_zero:
        shown = taken[1].decode("latin-1").strip() if taken else ""
        if shown and shown.split()[0].rstrip(":").lower() not in _ASC_KEYWORDS:  # a value GDAL took for a header
            # line ('NaN' starting a one-column grid's values): its values are missing, not the file's end
            why = (f"line {taken[0]} ({shown!r}) was read as a header line: GDAL's reader takes a line after the "
                   "first starting with a letter for one, so its values are missing, and reads the missing last "
                   "value as 0")
        else:
            why = "cut short: GDAL reads the missing last value as 0"
        raise DataFileError(
            f"cannot read {str(file)!r}: expected {what} of {nrows} x {ncols} = {expected:,} "
            f"values, as its header declares; got {values:,} ({why})"
        )


def gdal_reason(exc: BaseException) -> str:
    """What GDAL said of a failure rasterio raised as ``exc``: rasterio's read errors say only "Read failed. See
    previous exception for details.", which a message never showed (a .vrt whose source tile is missing, a GeoTIFF
    cut short), while GDAL's own error ("tiles/b.tif: No such file or directory", "IReadBlock failed at X offset 0")
    is their ``__cause__``: the causes' messages, the outer one's only where it says more than to look at them."""
    parts = []
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        text = str(current).strip()
        if text and not (current is exc and "previous exception" in text and current.__cause__ is not None):
            parts.append(text)
        current = current.__cause__
    return "; ".join(dict.fromkeys(parts)) or str(exc)


def _gdal_format(file: Path) -> str:
    """The raster format of ``file``'s extension as messages name it: "a GeoTIFF", "an SRTM tile (.hgt)"."""
    ext = file.suffix.lower()
    name = GDAL_FORMATS.get(ext, "a raster GDAL reads")
    return name if name == "a GeoTIFF" else f"{name} ({ext})"


#: The sizes of the SRTM tiles GDAL's SRTMHGT driver reads (bytes of big-endian int16 samples): 1201 x 1201 (SRTM3,
#: 3 arc-seconds), 3601 x 3601 (SRTM1), 1801 x 3601 (SRTM1 above 50 degrees) and 7201 x 7201 (0.5 arc-seconds).
_HGT_SIZES = frozenset(2 * rows * cols for rows, cols in ((1201, 1201), (3601, 3601), (1801, 3601), (7201, 7201)))
_HGT_NAME = re.compile(r"[NS]\d\d[EW]\d\d\d\.", re.IGNORECASE)


def _asc_refusal(file: Path, reason: str) -> str | None:
    """Why GDAL did not know the ``.asc`` ``file`` (local, or in a local gzip or zip) as an ESRI ASCII grid, where
    a header keyword follows a UTF-8 byte-order mark, spaces or blank lines at the start of the file: GDAL knows
    the format only by a keyword at its very first byte, and said only "not recognized as being in a supported file
    format". None otherwise (GDAL's ``reason`` is the one to give)."""
    if file.suffix.lower() != ".asc" or "not recognized as being in a supported file format" not in reason:
        return None
    opener = _ascii_grid_opener(file)
    if opener is None:
        return None
    try:
        with opener() as handle:
            head = handle.read(4096)
    except (OSError, zipfile.BadZipFile, KeyError):
        return None
    if head.startswith(b"\xef\xbb\xbf"):
        said, rest = "a UTF-8 byte-order mark (bytes EF BB BF)", head[3:]
        fix = "save it as UTF-8 without a byte-order mark (`sed -i '1s/^\\xEF\\xBB\\xBF//' FILE`)"
    elif head[:1] in (b"\r", b"\n"):
        said, rest = "a blank line", head
        fix = "remove the lines before it"
    elif head[:1].isspace():
        said, rest = "spaces", head
        fix = "remove the spaces before it"
    else:
        return None
    words = rest.split(maxsplit=1)
    word = words[0].decode("latin-1") if words else ""
    if word.rstrip(":").lower() not in _ASC_KEYWORDS:
        return None
    return (f"expected {_gdal_format(file)} starting with its first header keyword; got a file that starts with "
            f"{said} before {word!r}, and GDAL knows the format only by a keyword at the file's very start: {fix}")


def _hgt_refusal(file: Path, reason: str) -> str | None:
    """Why GDAL did not know the ``.hgt`` ``file`` as an SRTM tile, where its name or size says so: GDAL's SRTMHGT
    driver takes a .hgt only named by its south-west corner (``N34W119.hgt``, ``N34W119.SRTMGL1.hgt``: the corner,
    then a dot), which places it, and of a tile's size. Its refusal was "unreadable content (... not recognized as
    being in a supported file format)", for a tile a user renamed (``everest.hgt``) or one cut short. None for
    another extension, a .hgt whose name and size (of a local file) are a tile's, or GDAL's ``reason`` other than
    knowing no format of the file it found (a file missing from a zip, a raster it opened by its content and failed
    to read): that reason is the one to give."""
    if file.suffix.lower() != ".hgt" or "not recognized as being in a supported file format" not in reason:
        return None
    if _HGT_NAME.match(file.name) is None:
        return (f"expected an SRTM tile named by its south-west corner (N34W119.hgt, N34W119.SRTMGL1.hgt: GDAL "
                f"places a .hgt by its name and reads no other); got the name {file.name!r}: rename it so")
    if isinstance(file, GdalPath):
        return None
    try:
        size = file.stat().st_size
    except OSError:
        return None
    if size in _HGT_SIZES:
        return None
    return (f"expected an SRTM tile of 1201 x 1201 or 3601 x 3601 16-bit samples (2,884,802 or 25,934,402 bytes; "
            f"1801 x 3601 above 50 degrees of latitude); got {size:,} bytes (cut short, or not an SRTM tile)")


def _warn_crs_without_geotransform(file: Path, crs_obj: Any, crs: str | None) -> None:
    """Warn that a GeoTIFF's CRS is ignored for want of a geotransform (read as an unreferenced grid)."""
    if crs_obj is not None:
        warnings.warn(
            f"{file.name}: its CRS {crs} is ignored because the file has no geotransform; read as an "
            "unreferenced grid, spacing (1, -1) and origin (0, 0)",
            stacklevel=caller_stacklevel(),
        )


def _geotiff_header(
    file: Path, shape: tuple[int, int], transform: Any, crs_obj: Any, crs: str | None, height_unit: str | None,
) -> tuple[Terrain, _Placement]:
    """The whole grid of a GeoTIFF of ``shape`` as :func:`_load_geotiff` places it (its warnings and refusals told),
    from its header alone: a :meth:`~stepterrain.terrain.Terrain._geometry_only` (no heights) and its placement, whose
    :func:`_check_placed` warnings are told once the heights are read."""
    place = _geotiff_placement(file, shape, transform, crs_obj, crs, height_unit)
    try:
        header = Terrain._geometry_only(shape, place.spacing, place.origin, place.crs, source=place.source,
                                        height_unit=height_unit)
    except InvalidInputError as exc:  # as _grid refuses the whole grid's geometry
        raise DataFileError(f"cannot read {str(file)!r}: {exc}") from exc
    return header, place


def _geotiff_placement(
    file: Path, shape: tuple[int, int], transform: Any, crs_obj: Any, crs: str | None, height_unit: str | None,
) -> _Placement:
    """Where :func:`_load_geotiff` puts the nodes of a GeoTIFF's grid of ``shape`` (:func:`_placement`; a file
    without a geotransform at spacing (1, -1), origin (0, 0), its CRS ignored with a warning), from its header."""
    if transform.is_identity:  # no geotransform (rasterio then reports the identity): a plain TIFF, north-up
        _warn_crs_without_geotransform(file, crs_obj, crs)
        return _Placement((1.0, -1.0), (0.0, 0.0), None, file.name, None)
    return _placement(file, shape, np.array(transform.to_gdal(), dtype=np.float64), crs,
                      geographic=bool(crs_obj is not None and crs_obj.is_geographic), metres=None,
                      height_unit=height_unit)


def raster_header(path: str | os.PathLike[str]) -> tuple[str, bool, tuple[float, ...], tuple[int, int]] | None:
    """(crs, geographic, GDAL geotransform, (rows, cols)) of a georeferenced raster of :data:`GDAL_FORMATS` (or a
    GDAL virtual path to one), from its header alone, as :func:`load_dem` reads them (a world file's grid with the
    CRS of the ``.prj`` beside it; a compound CRS's horizontal part where its heights become metres); None for any
    other file, one without a geotransform or a CRS, a rotated grid (rotation terms of float noise, which load_dem
    takes as 0, are no rotation), or one GDAL cannot open (its read says why)."""
    file = dem_path(path)
    if file.suffix.lower() not in GDAL_FORMATS:
        return None
    try:
        with open_raster(file) as dataset:
            transform, crs_obj, shape = dataset.transform, dataset.crs, (int(dataset.height), int(dataset.width))
            if crs_obj is None and not transform.is_identity:
                prj = prj_crs(file, "DEM", DataFileError)
                crs_obj = _crs_object(prj) if prj else None
            if transform.is_identity or crs_obj is None:
                return None
            geographic = bool(crs_obj.is_geographic)
            crs = _vertical_unit(dataset.units[0] or None, _crs_string(crs_obj))[1]
    except Exception:  # noqa: BLE001 - no rasterio, or a file GDAL refuses: the item's own read says why
        return None
    geotransform = tuple(float(v) for v in transform.to_gdal())
    # rotation terms of float noise are 0 to load_dem (_placement): such tiles were left out of their mosaic's frame
    if crs is None or not _negligible_rotation(geotransform[2], geotransform[4], geotransform[1], geotransform[5],
                                               shape):
        return None
    return crs, geographic, geotransform, shape


def degree_header(path: str | os.PathLike[str]) -> tuple[str, tuple[float, ...], tuple[int, int]] | None:
    """(crs, GDAL geotransform, (rows, cols)) of a raster of :data:`GDAL_FORMATS` (or a GDAL virtual path to one) in
    a geographic CRS, from its header alone, as :func:`load_dem` reads them (:func:`raster_header`); None for any
    other file, one in a projected CRS or none, a rotated grid, or one GDAL cannot open. For
    :mod:`stepterrain.batch`, which places a folder's files in degrees in the local metres they share
    (:func:`shared_degree_frame`)."""
    header = raster_header(path)
    if header is None or not header[1]:
        return None
    return header[0], header[2], header[3]


def projected_frame_crs(crs: str) -> str:
    """The CRS whose coordinates :func:`load_dem` places the nodes of a grid in projected ``crs`` in: ``crs`` itself
    for one in metres, the same projection in metres for one in another unit (EPSG:2229, US survey feet, is read in
    its metre twin EPSG:26945), the horizontal part of a compound CRS; for :mod:`stepterrain.batch`, which tells
    when a folder's files lie in several CRSs (their meshes do not line up)."""
    compound = _compound_heights(crs)
    if compound is not None and compound[2]:
        crs = compound[2]
    projected = _projected_units(crs)
    return crs if projected is None else projected[2] or crs


def _mean_step(steps: Sequence[float], sign: float) -> float:
    """The mean of the grids' ``steps`` along one axis, as ``gdalbuildvrt -resolution average`` takes it, independent
    of their order (:func:`math.fsum`), and the step itself where all are one; its sign theirs where they agree, else
    ``sign`` (gdalbuildvrt's mosaic is north-up)."""
    magnitudes = [abs(float(v)) for v in steps]
    mean = magnitudes[0] if len(set(magnitudes)) == 1 else math.fsum(magnitudes) / len(magnitudes)
    signs = {math.copysign(1.0, float(v)) for v in steps}
    return math.copysign(mean, signs.pop() if len(signs) == 1 else sign)


def shared_degree_frame(
    crs: str, geotransforms: Sequence[Sequence[float]], shapes: Sequence[tuple[int, int]],
) -> tuple[tuple[float, float], str | None, str, list[tuple[tuple[float, float], tuple[float, float]]]]:
    """The local metres :func:`load_dem` would read the mosaic of several grids in ``crs`` (degrees) in, as
    ``gdalbuildvrt`` mosaics them (``-resolution average``, its default): the grid of the mean of their steps (their
    own where all have one; whatever their order, so a list's files are placed alike in any order) over the union of
    their cells, read as one
    file (:func:`_placement`: one spacing at the union's middle latitude, node (0, 0) at its top-left node, its
    warnings those of the mosaic). Returns its (spacing, crs, source) and, for each grid, (spacing, origin) of its
    nodes in it: a grid on the mosaic's lattice has the mosaic's spacing and its node (0, 0) at a whole number of
    the mosaic's nodes, placed as a tile cut from the mosaic is (``origin + col * dx``), so the border nodes that
    neighbours share land on identical coordinates; one of other steps is scaled to them (x linear in longitude).
    A :class:`DataFileError` when the union is no degrees (:func:`_placement`)."""
    dx, dy = _mean_step([g[1] for g in geotransforms], 1.0), _mean_step([g[5] for g in geotransforms], -1.0)
    xs = [x for g, (_, w) in zip(geotransforms, shapes, strict=True) for x in (g[0], g[0] + w * g[1])]
    ys = [y for g, (h, _) in zip(geotransforms, shapes, strict=True) for y in (g[3], g[3] + h * g[5])]
    x0, y0 = (min(xs) if dx > 0 else max(xs)), (min(ys) if dy > 0 else max(ys))
    # int(0.5 + n) as gdalbuildvrt sizes its mosaic: a half cell up (round() took 2.5 rows to 2, the .vrt has 3)
    shape = (max(int(0.5 + (max(ys) - min(ys)) / abs(dy)), 1), max(int(0.5 + (max(xs) - min(xs)) / abs(dx)), 1))
    name = "the mosaic of the DEM files"  # not their number: a file within it moves no other
    place = _placement(Path(name), shape, np.array([x0, dx, 0.0, y0, 0.0, dy], dtype=np.float64), crs,
                       geographic=True, metres=None, height_unit=None, name=name)
    assert place.source is not None
    (sx, sy), placed = place.spacing, []

    def nodes(offset: float) -> float:  # a whole number of the mosaic's nodes, as a tile cut from it lies
        whole = float(round(offset))
        return whole if abs(offset - whole) < 1e-6 else offset

    for g in geotransforms:
        spacing = (sx * (g[1] / dx), sy * (g[5] / dy))  # the mosaic's own where the steps are its steps
        origin = (sx * nodes((g[0] + 0.5 * g[1] - (x0 + 0.5 * dx)) / dx),
                  sy * nodes((g[3] + 0.5 * g[5] - (y0 + 0.5 * dy)) / dy))
        placed.append((spacing, origin))
    return place.spacing, place.crs, place.source, placed


def equals_nodata(array: NDArray[Any], nodata: float) -> NDArray[np.bool_]:
    """Where ``array`` equals ``nodata``, compared in the array's own dtype as GDAL compares it (a float nodata
    rounded to a float32 band's value); a nodata beyond the dtype (inf there) matches no finite cell: call under
    ``np.errstate(over="ignore")``. An integer array matches a whole number within its dtype only, compared as an
    integer: numpy 1.x's value-based casting compared ``uint8 == 100.01`` in float16, where it is 100."""
    if array.dtype.kind in "iu":
        value, info = float(nodata), np.iinfo(array.dtype)
        if not (value.is_integer() and info.min <= value <= info.max):  # a fraction or beyond the dtype: no cell
            return np.zeros(array.shape, dtype=bool)
        return array == array.dtype.type(int(value))
    return array == (array.dtype.type(nodata) if array.dtype.kind == "f" else nodata)


def given_nodata(
    array: NDArray[Any], given: Sequence[float], hits: NDArray[np.bool_] | None = None,
) -> NDArray[np.bool_] | None:
    """``hits`` (None: no cell) with the cells of ``array`` equal to one of ``given`` (:func:`load_dem`'s ``nodata``,
    compared as :func:`equals_nodata` compares a file's) marked too; non-finite values are passed over (NaN matches
    no cell, and an inf cell is nodata anyway). In place where ``hits`` is an array. A finite value that no cell of
    ``array``'s dtype can hold (a fraction or a value beyond an integer dtype's range, a value beyond a float dtype's)
    is warned of (:func:`_warn_unheld_nodata`): it marks no cell, which ``--nodata 3.5`` or ``--nodata -99999`` on an
    int16 or uint16 GeoTIFF or PNG did silently."""
    for value in given:
        if not math.isfinite(value):
            continue
        _warn_unheld_nodata(array.dtype, value)
        with np.errstate(over="ignore"):  # a value beyond the dtype (1e40 in float32) is inf there: no finite cell
            hit = equals_nodata(array, value)
        hits = hit if hits is None else np.logical_or(hits, hit, out=hits if hits.flags.writeable else None)
    return hits


def _warn_unheld_nodata(dtype: np.dtype[Any], value: float) -> None:
    """Warn, at the caller of :func:`load_dem`, when ``value`` (one of its ``nodata``, finite) is no value of ``dtype``
    (the values as stored: :func:`equals_nodata` compares it with none of them): a fraction or beyond the range of
    an integer dtype, beyond the largest finite value of a float one (inf there). Its cells were read as heights
    without a word, ``--nodata -99999`` on an int16 DEM whose voids are -32768 masking nothing."""
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        if value.is_integer() and info.min <= value <= info.max:
            return
        held = f"whole numbers {info.min} to {info.max}"
    elif dtype.kind == "f":
        top = float(np.finfo(dtype).max)
        if -top <= value <= top:
            return
        held = f"magnitudes up to {top:.8g}"
    else:
        return
    text = repr(value)[:-2] if repr(value).endswith(".0") else repr(value)  # -99999, 3.5, 1e+40
    warnings.warn(
        f"nodata={text} is no value of the file's {dtype} cells as stored ({held}): it marks no cell; give "
        f"the value its missing cells hold (`stepterrain info` shows the height range, `gdalinfo -stats` the stored "
        f"values)",
        stacklevel=caller_stacklevel(),
    )


def _missing_beyond_gdal_mask(
    dataset: Any, band: int, data: NDArray[Any], window: Any = None,
) -> NDArray[np.bool_] | None:
    """The cells of ``band`` (stored values ``data``, of ``window`` if given) that its nodata value or an alpha band
    of ``dataset`` marks
    missing where GDAL's mask does not use them, else None. GDAL masks a band by one of its internal mask, its nodata
    value and an alpha band, in that order (RFC 15), so with an internal mask a cell at the nodata value read as a
    height (a -9999 m pit), and with a nodata value a transparent cell did. The nodata value is compared in the
    band's own dtype, as GDAL compares it; alpha 0 is missing, as GDAL's alpha mask reads it."""
    from rasterio.enums import ColorInterp, MaskFlags

    flags = dataset.mask_flag_enums[band - 1]
    missing = None
    nodata = dataset.nodatavals[band - 1]
    if MaskFlags.nodata not in flags and nodata is not None and not math.isnan(nodata):
        with np.errstate(over="ignore"):  # a nodata beyond a float band's dtype is inf: no finite cell
            missing = equals_nodata(data, nodata)
    if MaskFlags.alpha not in flags:
        for index, interp in enumerate(dataset.colorinterp, start=1):
            if interp == ColorInterp.alpha and index != band:
                transparent = dataset.read(index, window=window) == 0
                missing = transparent if missing is None else np.logical_or(missing, transparent, out=missing)
    return missing


_P = TypeVar("_P", bound=PurePath)


def _prj_files(path: _P) -> list[_P]:
    """The .prj files that may hold the CRS of the raster ``path``, in the order :func:`prj_crs` reads them:
    ``ortho.prj``, ``ortho.PRJ``, ``ortho.jpg.prj``, ``ortho.jpg.PRJ`` (a local file's, or a zip member's,
    :func:`_zipped_prj`)."""
    return [path.with_suffix(ext) for ext in (".prj", ".PRJ")] + [path.with_name(path.name + ext)
                                                                  for ext in (".prj", ".PRJ")]


def _prj_beside(path: Path) -> Path | None:
    """The first of :func:`_prj_files` beside the local raster ``path`` that is a file, the one :func:`prj_crs`
    reads; None without one."""
    return next((prj for prj in _prj_files(path) if prj.is_file()), None)


def prj_crs(path: Path, what: str, refusal: type[StepTerrainError] = InvalidInputError) -> str | None:
    """The CRS in a .prj file beside the raster ``path`` (``ortho.prj`` or ``ortho.jpg.prj``, the ESRI convention for
    a world file's CRS, which GDAL does not read for a TIFF, JPEG or PNG: their CRS was unknown; WKT, or the ArcInfo
    keyword form GDAL reads beside a grid, :func:`_arcinfo_prj_crs`; in a local zip, the one beside it there,
    :func:`_zipped_prj`; of a local gzip, ``dem.asc.gz``, the inner file's beside it, ``dem.prj``), for a raster GDAL
    georeferences without a CRS; None without one. A .prj that is no CRS is refused (a ``refusal``), naming it and
    ``what`` the raster is ("image", "DEM"): the raster would be taken in no CRS, or another's, without a word. Its
    extension in either case (``DEM.PRJ`` beside ``DEM.TIF``, as DOS-era ESRI data ships it, and GDAL reads the world
    file ``DEM.TFW``)."""
    gzipped = _local_gzip(path)
    if gzipped is None and isinstance(path, GdalPath):  # in a local zip, the .prj beside it there; elsewhere (a URL)
        found = _zipped_prj(path)  # none is looked for
    else:  # a local file's; a local .gz's (dem.asc.gz): the .prj of the file inside, beside the .gz (dem.prj)
        local = _prj_beside(Path(gzipped[:-3]) if gzipped is not None else path)
        found = (str(local), local) if local is not None else None
    if found is not None:
        named, prj = found
        from rasterio.crs import CRS

        try:
            text = (prj.read_text(errors="replace") if isinstance(prj, Path) else prj).strip()
        except OSError as exc:
            raise DataFileError(f"cannot read {named!r}, the CRS of {what} {str(path)!r}: {exc}") from exc
        try:
            return _crs_string(CRS.from_user_input(text))
        except Exception as exc:  # noqa: BLE001 - rasterio's CRSError, or a WKT it parses but cannot name
            arcinfo = _arcinfo_prj_crs(text)
            if arcinfo is not None:
                return arcinfo
            raise refusal(f"{named!r} beside {what} {str(path)!r} is not a CRS (WKT, as GIS software writes it "
                          f"beside a world file): {exc}") from exc
    return None


#: The 2 x 2 ASCII grid beside which :func:`_arcinfo_prj_crs` has GDAL read a .prj.
_PRJ_PROBE_GRID = b"ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n0 0\n0 0\n"


def _arcinfo_prj_crs(text: str) -> str | None:
    """The CRS of a .prj in the ESRI ArcInfo keyword form (``Projection UTM``, ``Zone 11``, ``Units METERS``, ...,
    as ArcInfo and ArcView 3 wrote it beside grids and their TIFF exports), which GDAL reads beside an ASCII grid
    (its ESRI import) but no WKT parser takes: read so, beside a 2 x 2 ASCII grid in GDAL's memory file system (the
    one way rasterio reaches that import). None for WKT (refused as it is), text GDAL finds no CRS in, or a CRS it
    cannot name; a projection GDAL does not know (``Projection UTMX``), which it takes as a local CRS of that name
    (neither geographic nor projected), is none either: refused, as before, not a grid in no CRS without a word."""
    if "[" in text or not re.match(r"\s*projection\b", text, re.IGNORECASE):
        return None
    import uuid

    from rasterio.io import MemoryFile

    folder = f"stepterrain-prj-{uuid.uuid4().hex}"  # the two files side by side, apart from any other read's
    try:
        with MemoryFile(text.encode(), dirname=folder, filename="grid.prj"), \
                MemoryFile(_PRJ_PROBE_GRID, dirname=folder, filename="grid.asc") as grid, grid.open() as dataset:
            crs = dataset.crs
            return _crs_string(crs) if crs is not None and (crs.is_geographic or crs.is_projected) else None
    except Exception:  # noqa: BLE001 - GDAL reads no grid or CRS of it: refused as not a CRS
        return None


def _local_gzip(path: Path) -> str | None:
    """The local gzip file (as GDAL names it) that the ``/vsigzip/`` path ``path`` reads (a local ``.gz``,
    :func:`gzip_member`), else None."""
    if not isinstance(path, GdalPath) or not os.fspath(path).startswith("/vsigzip/"):
        return None
    return local_archive(path)


#: World files GDAL reads beside a TIFF (``{stem}``: its name without the extension), matched in any case: beside a
#: gzipped TIFF GDAL reads none, and :func:`_refuse_gzip_world_file` refuses one.
_WORLD_FILES = ("{stem}.tfw", "{stem}.tifw", "{stem}.tiffw", "{stem}.wld")


def _refuse_gzip_world_file(file: Path) -> None:
    """Refuse the raster ``file``, read without a geotransform from a local gzip (``dem.tif.gz``), when a world file of
    the file inside lies beside the gzip (``dem.tfw``): GDAL reads no file beside a gzip, and the grid was read as
    1 m cells at (0, 0) without a word where the plain TIFF is placed by it."""
    gzipped = _local_gzip(file)
    if gzipped is None:
        return
    folder = os.path.dirname(gzipped) or "."
    try:
        names = {n.lower(): n for n in os.listdir(folder)}
    except OSError:
        return
    inner = Path(gzipped[:-3]).name
    for pattern in _WORLD_FILES:
        found = names.get(pattern.format(stem=Path(inner).stem).lower())
        if found is not None:
            raise DataFileError(
                f"cannot read {str(file)!r}: it has no georeferencing of its own, and GDAL reads no world file beside "
                f"a gzip: {found!r} beside it is not read (the grid would lie at 1 m cells at (0, 0)); gunzip it "
                f"first, `gunzip -k {str(file)}`, and read the TIFF beside its world file"
            )


def _zipped_prj(path: GdalPath) -> tuple[str, str] | None:
    """(name, text) of the first .prj :func:`prj_crs` reads beside the raster ``path`` when it is a ``/vsizip/``
    path into a local zip (a zip's own raster, :func:`zip_member`): a TIFF's world file (.tfw) GDAL reads inside the
    zip, but not its .prj, and the CRS of the grid it places was lost (a grid in US survey feet kept feet as metres).
    None for any other virtual path, or without one."""
    gdal = os.fspath(path)
    archive_path = local_archive(path) if gdal.startswith("/vsizip/") else None
    if archive_path is None or not os.path.isfile(archive_path):
        return None
    after = gdal[len("/vsizip/"):]  # the archive's path, in GDAL's braces or not, then the member's
    member = PurePosixPath((after[after.find("}") + 1:] if after.startswith("{") else after[len(archive_path):])
                           .lstrip("/"))
    try:
        with zipfile.ZipFile(archive_path) as archive:
            names = set(archive.namelist())
            for prj in _prj_files(member):  # as beside a local file
                if str(prj) in names:
                    text = archive.read(str(prj)).decode(errors="replace")
                    return f"{str(path)[: -len(member.name)]}{prj.name}", text
    except (OSError, RuntimeError, zipfile.BadZipFile) as exc:  # RuntimeError: an encrypted member
        raise DataFileError(f"cannot read the zip {archive_path!r} of {str(path)!r}: {exc}") from exc
    return None


def _refuse_warped_georeferencing(file: Path, gcps: tuple[Any, Any], rpcs: Any) -> None:
    """Refuse a GeoTIFF georeferenced by ground control points or rational polynomial coefficients instead of a
    geotransform: rasterio then reports the identity, and such a file was read as an unreferenced grid of 1 m
    cells without a word. Its cells are not a regular grid in any CRS until warped, which load_dem does not do."""
    points, crs_obj = gcps
    if points:
        what = f"{counted(len(points), 'ground control point')} (GCPs) in {_crs_string(crs_obj) or 'an unknown CRS'}"
    elif rpcs is not None:
        what = "rational polynomial coefficients (RPCs)"
    else:
        return
    name = file.name
    raise DataFileError(
        f"cannot read {str(file)!r}: expected a GeoTIFF on a regular grid (a geotransform); got one referenced "
        f"only by {what}, which load_dem does not warp; resample it to a regular grid first, e.g. "
        f"`gdalwarp -r bilinear{' -rpc' if not points else ''} -dstalpha -t_srs EPSG:<code> {name} "
        f"{file.stem}_grid.tif` (-dstalpha marks the cells outside the scene missing: without it they are 0 m)"
    )


# ---------------------------------------------------------------------------------------------- helpers
def _check_magic(file: Path, magics: tuple[bytes, ...], expected: str) -> bytes:
    """The first bytes of ``file``; refuse a file they match none of ``magics`` (text saved under a NumPy
    extension)."""
    try:
        with open(file, "rb") as handle:
            head = handle.read(16)
    except OSError as exc:
        raise DataFileError(f"cannot read {str(file)!r}: {exc.strerror}") from exc
    if not head.startswith(magics):
        got = "an empty file" if not head else f"content starting {head[:8]!r}"
        raise DataFileError(f"cannot read {str(file)!r}: expected {expected}; got {got}")
    return head


def _npy_header(handle: Any) -> tuple[tuple[int, ...], np.dtype] | None:
    """(shape, dtype) of the .npy header at the start of the stream ``handle`` (left after it); None for a header
    version NumPy's readers (1.0, 2.0) do not take. NumPy's ValueError for a header it cannot parse."""
    version = np.lib.format.read_magic(handle)
    read = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}.get(version)
    if read is None:
        return None
    shape, _, dtype = read(handle)
    return shape, dtype


def _check_declared_size(handle: Any, size: int, file: Path, what: str) -> tuple[tuple[int, ...], np.dtype] | None:
    """Refuse an .npy stream (at its start, ``size`` bytes in all) whose header declares more data than follows
    it: NumPy allocates the declared shape before reading, so a 100-byte file declaring 10^8 x 10^8 floats
    raised a MemoryError for 71 PiB. Refuse one the memory budget cannot hold as well (:func:`_check_read_budget`),
    memory-mapped or not: every caller copies it. A header NumPy cannot parse is left to ``np.load``'s own error.
    The header read (:func:`_npy_header`), else None."""
    try:
        header = _npy_header(handle)
        if header is None:
            return None
        shape, dtype = header
        start = handle.tell()
    except (ValueError, OSError, EOFError, zipfile.BadZipFile):
        return None
    if dtype.hasobject:
        return header  # pickled: refused by np.load (allow_pickle=False)
    declared = math.prod(int(n) for n in shape) * dtype.itemsize
    if declared > size - start:
        raise DataFileError(
            f"cannot read {str(file)!r}: {what} declares shape {tuple(shape)} of {dtype} ({declared:,} bytes) but "
            f"the file holds {max(size - start, 0):,} bytes after its header (truncated or corrupt)"
        )
    _check_read_budget(file, tuple(shape), dtype, what, hint=_ARRAY_HINT)
    return header


#: What makes an .npy or .npz over the memory budget smaller: GDAL (the default hint's gdal_translate) reads neither.
_ARRAY_HINT = ("crop or coarsen it first in NumPy (heights[r0:r1, c0:c1] or heights[::n, ::n]; an .npy's "
               "np.load(path, mmap_mode='r') reads only that part) and save it again")


def _check_read_budget(file: Path, shape: tuple[int, ...], dtype: np.dtype, what: str = "the raster",
                       hint: str = "crop or coarsen it first (gdal_translate -srcwin or -outsize)") -> None:
    """An :class:`~stepterrain.errors.OutputTooLargeError` naming ``file``, its declared shape and the bytes, before
    reading, when its cells (as stored, at least float32 as the Terrain keeps them) exceed the memory budget
    (:func:`stepterrain.set_memory_budget`): a header declaring 400000 x 400000 cells otherwise allocated until the
    machine swapped or NumPy raised a raw MemoryError. A lower bound of the read's peak, as :func:`load_dem` says
    (measured by tests/test_io_fixes.py: 8-9 bytes per cell for 8- to 32-bit rasters, up to 16 for float64 or a
    scaled band; 17 for a terrain tile, tests/test_io_terrain_rgb.py); it checks what the Terrain keeps, as the
    budget bounds a call's output elsewhere."""
    cells = math.prod(int(n) for n in shape)
    check_budget(
        cells * max(dtype.itemsize, 4),
        f"reading {str(file)!r} ({what}: {' x '.join(str(int(n)) for n in shape)} cells of {dtype})",
        hint=hint,
    )


def _npz_member(archive: Any, key: str, file: Path) -> NDArray[Any]:
    name = f"{key}.npy" if f"{key}.npy" in archive.zip.namelist() else key
    with archive.zip.open(name) as member:
        _check_declared_size(member, archive.zip.getinfo(name).file_size, file, f"member {key!r}")
    try:
        return np.asarray(archive[key])
    except ValueError as exc:  # object arrays need pickle, which stays off; else a damaged member (a header cut short)
        what = "holds Python objects" if "allow_pickle" in str(exc) else "is unreadable"
        raise DataFileError(f"cannot read {str(file)!r}: member {key!r} {what} ({exc})") from exc


def _npz_one(value: Any, key: str, kinds: str, expected: str, file: Path) -> NDArray[Any] | None:
    """The one value an .npz stores under ``key``, 0-d or in a one-element array (``np.savez(crs=[...])``,
    ``np.savez(nodata=dataset.nodatavals)``), as a 0-d array of a dtype kind in ``kinds``; None when absent.
    Anything else is a DataFileError naming ``file`` and ``key``: such values were ignored silently (a lost
    geographic CRS took degrees for metres; a lost nodata read -32768 cells as heights)."""
    if value is None:
        return None
    arr = np.asarray(value)
    if arr.size != 1 or arr.dtype.kind not in kinds:
        got = arr.tolist() if arr.ndim else arr.item()
        raise DataFileError(f"cannot read {str(file)!r}: {key!r} must be {expected}; got {arr.dtype} {got!r:.80}")
    return arr.reshape(())


def _npz_text(arrays: Any, key: str, file: Path) -> str | None:
    """The text an .npz stores under ``key`` (``crs``, ``units``, ``units_xy``; see :func:`_npz_one`), None when
    absent or empty."""
    arr = _npz_one(arrays.get(key), key, "US", "one text value (e.g. 'EPSG:32611', 'metre')", file)
    if arr is None:
        return None
    text = arr.item()
    text = text.decode() if isinstance(text, bytes) else str(text)
    return text or None


def npz_nodata(value: Any, file: Path) -> float | None:
    """The finite nodata value an .npz stores under ``nodata`` (one real number, see :func:`_npz_one`), None
    without one or for a non-finite one (NaN heights are nodata anyway)."""
    arr = _npz_one(value, "nodata", "iuf", "one real number (the value of missing cells)", file)
    if arr is None or not np.isfinite(arr):
        return None
    return float(arr)


def npz_missing(
    arrays: Mapping[str, NDArray[Any]], key: str, file: Path, *, series: bool = False
) -> NDArray[np.bool_] | None:
    """The cells an .npz marks missing beside its heights ``arrays[key]`` by a boolean ``mask`` (True = missing, as
    in NumPy's masked arrays: ``np.savez(..., elevation=m.data, mask=m.mask)``) and/or ``valid`` (True = present),
    of the heights' shape, or 0-d for every cell (NumPy's ``nomask``, the ``m.mask`` of a masked array with no cell
    masked, saves as a 0-d False); both: a cell is missing if either says so. None without them (or for heights that
    are not 2-D, refused as such). Any other dtype or shape is a DataFileError: such keys were ignored, the masked cells
    read as heights (0 or -32768 pits), and a 0/255 integer mask (GDAL's mask band, 255 = valid) means the opposite
    of a 0/1 one.

    ``series``: the heights are a (T, H, W) series (:func:`stepterrain.batch.load_series`), and a mask is either
    (T, H, W), one per frame, or (H, W), the same cells of every frame; the result has the heights' shape."""
    heights = arrays[key]
    if heights.ndim != (3 if series else 2) or not ("mask" in arrays or "valid" in arrays):
        return None
    shapes = (heights.shape, heights.shape[1:]) if series else (heights.shape,)
    missing = None
    for name, present in (("mask", False), ("valid", True)):
        value = arrays.get(name)
        if value is None:
            continue
        # a 0-d one is NumPy's nomask, the m.mask of a masked array with no cell masked (np.ma.masked_equal(z, -9999)
        # of a tile without voids): np.False_, saved as a 0-d False, meaning every cell of the heights
        if value.dtype != np.bool_ or value.shape not in (*shapes, ()):
            meaning = "present" if present else "missing"
            hint = ""
            if value.dtype.kind in "iu" and value.size and set(np.unique(value).tolist()) <= {0, 1, 255}:
                hint = (f"; save {name}=array.astype(bool) for 0/1 with 1 = {meaning}, or valid=array > 0 for GDAL's "
                        "mask band (read_masks(): 255 = valid)")
            shape = (f"the series' shape {heights.shape} (one per frame) or a frame's {heights.shape[1:]} (every "
                     "frame's)") if series else f"the heights' shape {heights.shape}"
            raise DataFileError(
                f"cannot read {str(file)!r}: {name!r} must be a boolean array of {shape}, "
                f"True where a cell is {meaning}; got {value.dtype} of shape {value.shape}{hint}"
            )
        cells = ~value if present else value
        missing = cells if missing is None else missing | cells
    if missing is not None and missing.shape != heights.shape:  # a frame's or a 0-d mask: the same cells of each frame
        missing = np.broadcast_to(missing, heights.shape)
    return missing


def _elevation(
    array: NDArray[Any], file: Path, what: str, nodata: float | None = None,
    missing: NDArray[np.bool_] | None = None, *, warn_voids: bool = True, stored: _Stored | None = None,
    given: Sequence[float] | None = None,
) -> NDArray[np.float32]:
    """Check that ``array`` is an (H, W) real grid of at least 2 x 2 nodes; float32 with NaN nodata
    (non-finite values, cells equal to ``nodata``, compared in the array's own dtype, and cells True in
    ``missing``, of the array's shape). ``warn_voids``, ``stored`` and ``given`` (None: :func:`read_dem`'s
    ``nodata``): see :func:`nodata_as_nan`."""
    where = f"cannot read {str(file)!r}"
    if array.dtype == np.bool_ or array.dtype.kind not in "iuf":
        raise DataFileError(
            f"{where}: expected real-valued elevation data; got {what} of dtype {array.dtype}"
        )
    if array.ndim != 2:
        raise DataFileError(
            f"{where}: expected a 2-D (H, W) elevation grid; got {what} of shape {array.shape}"
        )
    if array.shape[0] < 2 or array.shape[1] < 2:
        raise DataFileError(
            f"{where}: expected an elevation grid of at least 2 x 2 nodes; got {what} of shape {array.shape}"
        )
    return nodata_as_nan(array, file, what, nodata, missing, warn_voids=warn_voids, stored=stored,
                         given=_GIVEN_NODATA.get() if given is None else given)


def _warn_void_values(file: Path, data: NDArray[Any], missing: NDArray[np.bool_] | None, what: str) -> None:
    """Warn, at the caller of :func:`load_dem`, when cells of the stored values ``data`` that no nodata value or mask
    marks (``missing``, of its shape, or None) hold the lowest value of a signed integer dtype of 16 bits or more
    (-32768, the void of SRTM and most int16 DEMs) or the lowest or highest of a float dtype (-3.4028235e+38,
    ArcGIS's float32 NoData, or +3.4028235e+38, FLT_MAX, no height in any unit): no elevation, but a file that lost
    its nodata value. They were read as heights without a word: a pit 33 km deep in the mesh, or "3.4e+37 levels"
    refused by stepped. One reduction finds the lowest (and one the highest) value; only when it is the sentinel are
    its cells counted, a block of rows at a time (no temporary of the grid's size). In a float64 grid the sentinels
    are float32's: float64's own lie beyond float32 and are refused, naming them (:func:`_undeclared_sentinel`),
    while a float32 DEM's NoData kept through a widening copy (``src.read(1).astype(float)`` saved as .npy,
    ``gdal_translate -ot Float64``) was read as heights without a word."""
    kind = data.dtype.kind
    if data.size == 0 or not (kind == "f" or (kind == "i" and data.dtype.itemsize >= 2)):
        return
    lowest_of = np.dtype(np.float32) if kind == "f" and data.dtype.itemsize > 4 else data.dtype
    info = (np.finfo if kind == "f" else np.iinfo)(lowest_of)
    # fmin/fmax: NaN cells pass over; a float dtype's highest value marks voids as its lowest does (no height is
    # 3.4e+38 in any unit), an integer's (32767: 3276.7 m in decimetres, a 16-bit PNG's peak) is a height
    ends = [("lowest", info.min, np.fmin if kind == "f" else np.minimum)]
    if kind == "f":
        ends.append(("highest", info.max, np.fmax))
    extremes, reduced = [], []
    for end, extreme, reduce in ends:
        sentinel = data.dtype.type(extreme)
        reduced.append(reduce.reduce(data, axis=None))
        extremes.append(sentinel)
        if reduced[-1] == sentinel:
            _warn_void_value(file, data, missing, what, sentinel, f"the {end} {lowest_of} value")
    _warn_common_nodata(file, data, missing, what, reduced[0], reduced[1] if len(reduced) > 1 else None, extremes)


def _warn_void_value(
    file: Path, data: NDArray[Any], missing: NDArray[np.bool_] | None, what: str, sentinel: Any, named: str,
) -> None:
    """:func:`_warn_void_values`' warning of the cells of ``data`` holding ``sentinel`` (``named``: "the lowest
    float32 value") that ``missing`` does not mark, counted a block of rows at a time; none, no warning."""
    count, rows = 0, max(1, (1 << 20) // max(1, data[0].size))
    for start in range(0, data.shape[0], rows):
        hit = data[start:start + rows] == sentinel
        if missing is not None:
            hit &= ~missing[start:start + rows]
        count += int(np.count_nonzero(hit))
    if count:
        # float64 cells equal the float32 value only as written in full, which a nodata of them must match exactly
        wide = data.dtype.kind == "f" and data.dtype.itemsize > 4
        _warn_undeclared_voids(file, count, what, _nodata_text(sentinel, data.dtype),
                               f"{named}{f' (stored as {data.dtype})' if wide else ''}")


def _warn_undeclared_voids(file: Path, count: int, what: str, text: str, described: str) -> None:
    """Warn, at the caller of :func:`load_dem`, that ``count`` cells of ``what`` hold the value ``text`` (as a nodata
    to declare), ``described`` ("the lowest float32 value"), which no nodata value or mask of ``file`` marks: how to
    declare it (:func:`_declare_nodata`). The one wording of :func:`_warn_void_value` and
    :func:`_warn_common_nodata`."""
    warnings.warn(
        f"{file.name}: {counted(count, 'cell')} of {what} {'holds' if count == 1 else 'hold'} {text}, {described}, "
        "which marks voids, but no nodata value or mask of the file marks them: read as heights; if they are voids, "
        f"declare it ({_declare_nodata(file, text)})",
        stacklevel=caller_stacklevel(),
    )


#: Values that DEM files commonly hold in their voids besides a dtype's extremes (:func:`_warn_common_nodata`):
#: -9999 (ESRI ASCII grids' and many GeoTIFFs' NODATA_value), -32767 and -32768 (int16 voids, SRTM's, here in
#: another dtype: a float32 or int32 copy of an SRTM tile), -99999, 1e+20 (the _FillValue of CF/netCDF climate
#: and ocean models), netCDF's default float fill 9.96921e+36 and Golden Software Surfer's blank 1.70141e+38.
COMMON_NODATA: tuple[float, ...] = (-9999.0, -32767.0, -32768.0, -99999.0, 1e20, 9.969209968386869e36, 1.70141e38)

#: How far outside the other cells' values a common nodata value must lie to be named a void: more than this share
#: of their span (their highest less their lowest) beyond the nearest of them.
_COMMON_NODATA_GAP = 0.25


def _common_nodata_in(dtype: np.dtype[Any]) -> list[Any]:
    """:data:`COMMON_NODATA` as ``dtype`` holds them: a signed integer of 16 bits or more those within its range
    (not its own lowest value, which :func:`_warn_void_values` names), a float of 32 bits or more each rounded to it
    (a float32 file's 1e+20 is 1.00000002e+20) and, in a wider float, also as a float32 value kept through a
    widening copy; none for another dtype."""
    values: list[Any] = []
    if dtype.kind == "i" and dtype.itemsize >= 2:
        info = np.iinfo(dtype)
        values = [dtype.type(v) for v in COMMON_NODATA if v == int(v) and info.min < v <= info.max]
    elif dtype.kind == "f" and dtype.itemsize >= 4:
        for v in COMMON_NODATA:
            values += [dtype.type(v), dtype.type(np.float32(v))]
    return list(dict.fromkeys(values))


def _warn_common_nodata(
    file: Path, data: NDArray[Any], missing: NDArray[np.bool_] | None, what: str, lowest: Any, highest: Any,
    extremes: Sequence[Any],
) -> None:
    """Warn, at the caller of :func:`load_dem`, when cells of ``data`` that ``missing`` does not mark hold one of
    :data:`COMMON_NODATA` (-9999, -32768 in a float32 grid, 1e+20, ...) lying far outside the other cells' values:
    below their lowest (or above their highest) by more than :data:`_COMMON_NODATA_GAP` of their span, or the only
    values. A file whose nodata value was lost had them read as heights without a word: a pit 10 km deep in the
    stepped terrain. Legitimate heights are not named: the Dead Sea's -430 m and ocean depths to -11000 m are no
    such value, and a trench's cell of -9999 m lies among other depths, no gap apart. ``lowest`` and ``highest``: the
    values' reductions, missing cells included (None: not reduced; an integer dtype holds no high one), which rule
    out most grids without a further pass; ``extremes``: the dtype's own sentinels, warned of already and left out
    of the other cells. Otherwise a pass of comparisons, a block of rows at a time, looks for their cells that
    ``missing`` does not mark (none where the file declares the value its nodata), and only where some are found a
    second counts each value's cells and the others' range."""
    candidates = [v for v in _common_nodata_in(data.dtype)
                  if (v < 0 and lowest <= v) or (v > 0 and highest is not None and highest >= v)]
    if not candidates:
        return
    rows = max(1, (1 << 20) // max(1, data[0].size))
    # first their cells that nothing marks: none in a file whose declared nodata is the value (a GeoTIFF's -9999, an
    # SRTM tile's -32768 with -32767 and -9999 above it), where the pass below over the other cells' range cost a
    # third more on load_dem's read (0.07 s on 16M float32 cells); np.greater of booleans: hit and not marked
    if not any(_unmarked_hit(data[start:start + rows], None if missing is None else missing[start:start + rows],
                             candidates) for start in range(0, data.shape[0], rows)):
        return
    counts = dict.fromkeys(candidates, 0)
    low, high = math.inf, -math.inf
    for start in range(0, data.shape[0], rows):
        block = data[start:start + rows]
        keep = np.isfinite(block) if data.dtype.kind == "f" else np.ones(block.shape, np.bool_)
        if missing is not None:
            keep &= ~missing[start:start + rows]
        for value in candidates:
            hit = block == value
            hit &= keep
            counts[value] += int(np.count_nonzero(hit))
            keep &= ~hit
        for value in extremes:
            keep &= block != value
        if keep.any():
            kept = block[keep]
            low, high = min(low, float(kept.min())), max(high, float(kept.max()))
    present = [v for v in candidates if counts[v]]
    # nearest the other values first: one that is not far from them is a height, and the next is measured from it
    for side in (sorted((v for v in present if v < 0), reverse=True), sorted(v for v in present if v > 0)):
        for value in side:
            gap = (low - float(value)) if value < 0 else (float(value) - high)
            if math.isfinite(low) and gap <= _COMMON_NODATA_GAP * (high - low):
                if low <= float(value) <= high:
                    continue
                low, high = min(low, float(value)), max(high, float(value))  # a height: the others reach it
                continue
            where = (f"far {'below' if value < 0 else 'above'} the other cells' values ({low:.6g} to {high:.6g})"
                     if math.isfinite(low) else "and no other cell holds a value")
            _warn_undeclared_voids(file, counts[value], what, _nodata_text(value, data.dtype),
                                   f"a common nodata value, {where}")


def _unmarked_hit(block: NDArray[Any], marked: NDArray[np.bool_] | None, values: Sequence[Any]) -> bool:
    """Whether a cell of ``block`` that ``marked`` (of its shape, or None) does not mark holds one of ``values``."""
    for value in values:
        hit = block == value
        if marked is not None:
            np.greater(hit, marked, out=hit)
        if hit.any():
            return True
    return False


def _nodata_text(value: Any, dtype: np.dtype[Any]) -> str:
    """``value`` of ``dtype`` as a nodata to declare: an integer's digits, a float32's 8 significant digits, a
    wider float's in full (a nodata matches a float64 cell only as written exactly)."""
    return (str(int(value)) if dtype.kind in "iu" else repr(float(value)) if dtype.itemsize > 4
            else f"{float(value):.8g}")


def _declare_nodata(file: Path, value: str) -> str:
    """How to declare ``value`` (as written in full) the nodata of ``file``, by its format: ``gdal_edit.py`` for a
    GeoTIFF, ``gdal_translate`` to one for another GDAL raster or one GDAL reads through a virtual path (a local
    ``.gz`` or zip, ``/vsizip/``, a URL: gdal_edit.py cannot write inside an archive, and no ``dem.tif`` lies there
    to edit), an .npz ``nodata`` otherwise; then, for this read alone, :func:`load_dem`'s ``nodata`` (the CLI spells
    ``nodata=-9999`` as its ``--nodata``). The paths are quoted for a shell ("my dem.tif")."""
    suffix = file.suffix.lower()
    tif = shlex.quote(f"{file.stem}.tif")
    given = f", or pass nodata={value}"
    if isinstance(file, GdalPath):  # read from the path GDAL reads, written beside the working folder
        return f"`gdal_translate -a_nodata {value} {shlex.quote(os.fspath(file))} {tif}`{given}"
    name = shlex.quote(file.name)
    return (f"`gdal_edit.py -a_nodata {value} {name}`" if suffix in (".tif", ".tiff") else
            f"`gdal_translate -a_nodata {value} {name} {tif}`" if suffix in GDAL_FORMATS else
            f"save a 'nodata' of {value} beside the heights" if suffix == ".npz" else
            f"save it as an .npz with a 'nodata' of {value}") + given


#: A GeoTIFF band's stored dtype, scale and offset, where its heights were scaled (:func:`_undeclared_sentinel`).
_Stored = tuple[np.dtype[Any], float, float]


def _undeclared_sentinel(
    file: Path, array: NDArray[Any], big: NDArray[np.bool_], at: tuple[int, ...], stored: _Stored | None = None,
) -> str:
    """The cause and the fix of the refusal of a float64 ``array``'s values beyond float32 (``big``, not nodata; the
    first at ``at``) when they are a nodata value the file does not declare: float64's lowest or highest value
    (-1.7976931348623157e+308, the nodata GDAL and ArcGIS give a Float64 raster by default) or one value held by
    several cells (no measurement repeats beyond float32), counted and named in full with the nodata to declare;
    "" for a lone odd value. The refusal said only "heights beyond float32", which named no void nor how to mark
    them. ``stored``: where ``array`` is a GeoTIFF band scaled by its scale and offset, the band's stored dtype,
    scale and offset: a nodata is declared (and GDAL compares it) in the stored values, so the stored value is named,
    found exactly (a stored extreme, or a value whose scaling gives the cell's again), or no hint is given."""
    value = array[at]
    count = int(np.count_nonzero(array[big] == value))  # among the cells beyond float32 only
    dtype, raw = array.dtype, value
    if stored is not None:  # the stored value that scales to it, exactly; else none named
        dtype, scale, offset = stored
        limits = np.finfo(dtype) if dtype.kind == "f" else np.iinfo(dtype)
        guess = (float(value) - offset) / scale
        raw = None
        for candidate in (float(limits.max), float(limits.min), guess if dtype.kind == "f" else round(guess)):
            if limits.min <= candidate <= limits.max and np.float64(dtype.type(candidate)) * scale + offset == value:
                raw = dtype.type(candidate)
                break
        if raw is None:
            return ""
    extreme = dtype.kind == "f" and abs(float(raw)) == np.finfo(dtype).max
    if (count < 2 and not extreme) or not math.isfinite(float(raw)):  # a float128 one beyond float64: no nodata
        return ""
    text = _nodata_text(raw, dtype)
    others = int(np.count_nonzero(big)) - count
    also = f" (and {counted(others, 'other cell')} beyond float32)" if others else ""
    kept = "" if stored is None else " as stored"
    what = (f"the {'lowest' if raw < 0 else 'highest'} {dtype} value{kept}, which marks voids" if extreme
            else f"one value{kept} repeated beyond float32 when scaled, no height: a mark of voids" if kept else
            "one value repeated beyond float32, no height: a mark of voids")
    return (f", in {counted(count, 'cell')}{also}: {what}, but no nodata value or mask of the file marks "
            f"{'it' if count == 1 else 'them'}; if they are voids, declare it ({_declare_nodata(file, text)})")


def missing_cells(
    array: NDArray[Any], nodata: float | None = None, given: Sequence[float] = (),
    missing: NDArray[np.bool_] | None = None, *, marked_by: list[str] | None = None,
) -> NDArray[np.bool_] | None:
    """The cells of ``array`` missing as :func:`load_dem` reads them, besides its non-finite values: equal to the
    file's ``nodata`` (compared in the array's own dtype, :func:`equals_nodata`: one beyond the dtype marks no finite
    cell), to one of the caller's ``given`` values (:func:`given_nodata`, which warns of one no cell can hold), or
    True in ``missing`` (an .npz ``mask``/``valid``, :func:`npz_missing`, of ``array``'s shape). None where none of
    the three is given; values are compared in a real dtype only (another marks no cell by value). ``marked_by``: a
    list to which the names of those that mark some cell are added, ``"nodata"``, ``"given"``, ``"mask"`` in that
    order (the globe's refusal names them). :func:`nodata_as_nan` and the globe command's .npz INPUT (which refuses
    missing cells, naming what marks them) decide alike by it: the globe had its own copy of these rules."""
    hits = None
    if array.dtype.kind in "iuf":
        if nodata is not None:
            with np.errstate(over="ignore"):  # beyond the dtype (1e40, -99999 in float16) it is inf: no finite cell
                hits = equals_nodata(array, nodata)
            if marked_by is not None and hits.any():
                marked_by.append("nodata")
        own = given_nodata(array, given)  # apart, to tell whether they mark a cell (no more arrays than in place)
        if own is not None:
            if marked_by is not None and own.any():
                marked_by.append("given")
            hits = own if hits is None else np.logical_or(hits, own, out=hits)
    if missing is not None:
        if marked_by is not None and missing.any():
            marked_by.append("mask")
        hits = missing.copy() if hits is None else np.logical_or(hits, missing, out=hits)
    return hits


def nodata_as_nan(
    array: NDArray[Any], file: Path, what: str, nodata: float | None = None,
    missing: NDArray[np.bool_] | None = None, *, warn_voids: bool = True, stored: _Stored | None = None,
    given: Sequence[float] = (),
) -> NDArray[np.float32]:
    """Real ``array`` (any shape: a (T, H, W) series too) as C-contiguous float32 with NaN nodata: non-finite
    values, cells equal to ``nodata`` (compared in the array's own dtype) and cells True in ``missing`` (a boolean
    array of ``array``'s shape: an .npz ``mask``/``valid``, see :func:`npz_missing`). A finite value beyond float32
    (in a cell not missing) or nothing but nodata (read as all NaN within :func:`read_dem`'s ``nodata_only``) is a
    DataFileError naming ``file`` and ``what``. A read-only array (a memory map) is read into memory.
    ``warn_voids``: :func:`_warn_void_values` on ``array`` (False where the caller warned on the values as stored: a
    GeoTIFF's band, before its scale and offset). ``stored``: a scaled band's stored dtype, scale and offset, by
    which a refusal of values beyond float32 names them as stored (:func:`_undeclared_sentinel`). ``given``: the
    caller's nodata values (:func:`load_dem`'s ``nodata``), compared as ``nodata`` is, missing too (no warning nor
    refusal names them)."""
    hits = missing_cells(array, nodata, given, missing)
    if warn_voids:
        _warn_void_values(file, array, hits, what)
    if array.dtype.kind == "f" and array.dtype.itemsize > 4:  # finite in float64, inf in float32: not nodata
        big = array > FLOAT32_MAX  # |array| > FLOAT32_MAX in boolean temporaries (np.abs made a float64 copy)
        big |= array < -FLOAT32_MAX
        big &= np.isfinite(array)
        if hits is not None:
            big &= ~hits
        if big.any():
            at = first_index(big)
            why = _undeclared_sentinel(file, array, big, at, stored)
            raise DataFileError(f"cannot read {str(file)!r}: {what} holds heights beyond float32 (|z| < 3.4e+38); "
                                f"got {float(array[at])!r} at index {at}{why}")
    with np.errstate(over="ignore"):  # only nodata overflows here (beyond float32, refused above otherwise)
        heights = np.ascontiguousarray(array, dtype=np.float32)
    if not heights.flags.writeable:  # float32 as stored, a view of a read-only memory map
        heights = heights.copy()
    if hits is not None and hits.any():
        heights[hits] = np.nan
    finite = np.isfinite(heights)
    if not finite.all():
        if not finite.any() and not _NODATA_ONLY.get():
            raise DataFileError(
                f"cannot read {str(file)!r}: expected elevation data; got {what} that is all nodata"
            )
        heights[np.logical_not(finite, out=finite)] = np.nan  # in place: ~finite was one more mask
    return heights


def _grid(
    file: Path,
    heights: NDArray[np.float32],
    *,
    spacing: tuple[float, float],
    origin: tuple[float, float],
    crs: str | None,
    source: str | None = None,
    height_unit: str | None = None,
) -> Terrain:
    """The Terrain of a file's ``heights``, placed (``spacing``, ``origin`` and ``crs``) by :func:`_placement` or
    unreferenced (``crs`` None): from_heights does not look the CRS up again (``_placed``)."""
    try:
        return Terrain.from_heights(
            heights, spacing=spacing, origin=origin, crs=crs, source=source or file.name, height_unit=height_unit,
            _placed=True,
        )
    except InvalidInputError as exc:
        raise DataFileError(f"cannot read {str(file)!r}: {exc}") from exc


class _Placement(NamedTuple):
    """Where :func:`load_dem` puts a georeferenced grid's nodes (:func:`_placement`), known from its header alone:
    the Terrain's ``spacing``, ``origin``, ``crs`` and ``source``, and ``projected`` the arguments of
    :func:`_check_projected_metres` (None for a geographic grid, checked by :func:`_check_local_metres` already)."""

    spacing: tuple[float, float]
    origin: tuple[float, float]
    crs: str | None
    source: str | None
    projected: tuple[Any, ...] | None


def _georeferenced(
    file: Path,
    heights: NDArray[np.float32],
    geotransform: NDArray[np.float64],
    crs: str | None,
    *,
    geographic: bool,
    metres: tuple[float, float] | None,
    height_unit: str | None,
    xy_unit: tuple[str, float] | None = None,
) -> Terrain:
    """Grid from a GDAL geotransform of the cell corners: node (0, 0) is the centre of the top-left cell.
    A projected CRS in feet (or any unit but the metre) is converted to metres, and so is a geotransform in the
    ``xy_unit`` (unit, metres per unit) an .npz names (:func:`_npz_xy_unit`); ``height_unit`` is the
    heights' unit when the file names a known one (they are then metres already), else None."""
    place = _placement(file, heights.shape, geotransform, crs, geographic=geographic, metres=metres,
                       height_unit=height_unit, xy_unit=xy_unit)
    terrain = _grid(file, heights, spacing=place.spacing, origin=place.origin, crs=place.crs, source=place.source,
                    height_unit=height_unit)
    _check_placed(file, place, terrain)
    return terrain


def _check_placed(file: Path, place: _Placement, terrain: Terrain) -> None:
    """The warnings of a projected grid (:func:`_check_projected_metres`) or one without a CRS
    (:func:`_check_degrees_without_crs`) read into ``terrain`` as ``place`` placed it."""
    if place.projected is None:
        return
    _check_projected_metres(file, *place.projected)
    crs = place.projected[0]
    if crs is None or _unreadable_crs(crs):  # one PROJ cannot read (an .npz's crs="4326") says no more than none
        _check_degrees_without_crs(file, terrain, crs)


def _unreadable_crs(crs: str) -> bool:
    """Whether rasterio is installed and cannot read ``crs`` (an .npz's ``crs="4326"``, an EPSG code that does not
    exist, a free-text name): :func:`load_dem` keeps such a CRS and reads the grid's coordinates as metres."""
    try:
        import rasterio.crs  # noqa: F401  (without it no CRS is read: nothing to tell)
    except ImportError:
        return False
    return _crs_object(crs) is None


class _NotDegrees(DataFileError):
    """:func:`_placement`'s refusal of a grid whose CRS is geographic but whose nodes are no degrees (latitudes beyond
    ±90, longitudes over more than 360 or beyond ±720): ``reason`` what its nodes give, which
    :func:`degrees_as_local_metres` names for the spacing and origin given instead of the file."""

    def __init__(self, file: Path, crs: str | None, reason: str) -> None:
        super().__init__(f"cannot read {str(file)!r}: {crs or 'its CRS'} is geographic (degrees), but {reason}")
        self.reason = reason


#: The farthest from 0 :func:`_placement` takes a geographic grid's node longitudes: both conventions (-180 to 180,
#: 0 to 360) and a grid unwrapped once round the globe from either lie within it.
_LONGITUDE_LIMIT = 720.0


def _placement(
    file: Path,
    shape: tuple[int, ...],
    geotransform: NDArray[np.float64],
    crs: str | None,
    *,
    geographic: bool,
    metres: tuple[float, float] | None,
    height_unit: str | None,
    name: str | None = None,
    xy_unit: tuple[str, float] | None = None,
) -> _Placement:
    """The placement of a grid of ``shape`` by :func:`_georeferenced`, from its geotransform, CRS and shape alone
    (no heights), its refusals and warnings but those of :func:`_check_placed` given: :func:`load_dem` places a
    GeoTIFF's whole grid so before it reads a window of it (``crop=``). ``name`` what the warnings and ``source`` call
    the grid (default the file's name); a geographic grid's nodes that are no degrees are a :class:`_NotDegrees`.
    ``xy_unit``: (unit, metres per unit) of a projected geotransform whose CRS states no unit (an .npz's
    ``units_xy``), converted as a CRS in that unit is."""
    name = file.name if name is None else name
    x0, dx, row_x, y0, col_y, dy = (float(v) for v in geotransform)
    if not all(math.isfinite(v) for v in (x0, dx, row_x, y0, col_y, dy)):  # a geographic grid was read at lon nan
        raise DataFileError(
            f"cannot read {str(file)!r}: expected a geotransform of 6 finite numbers (x0, dx, 0, y0, 0, dy); got "
            f"{tuple(float(v) for v in geotransform)}"
        )
    if not _negligible_rotation(row_x, col_y, dx, dy, shape):
        # -dstalpha: the corners of the north-up grid outside the rotated one are missing; without it (and without a
        # nodata value of the file's) gdalwarp filled them with 0, heights of 0 m read back without a word
        warp = (f"`gdalwarp -dstalpha {shlex.quote(file.name)} {shlex.quote(file.stem + '_north_up.tif')}`"
                if file.suffix.lower() in GDAL_FORMATS else "`gdalwarp -dstalpha`")
        raise DataFileError(
            f"cannot read {str(file)!r}: expected a north-up grid; got a rotated geotransform "
            f"{tuple(float(v) for v in geotransform)} (its rotation terms move nodes by more than "
            f"{_ROTATION_TOLERANCE:g} of a cell over {shape[0]} x {shape[1]} nodes; {warp} makes "
            "it north-up, the cells outside the rotated grid missing)"
        )
    if dx == 0.0 or dy == 0.0:
        raise DataFileError(f"cannot read {str(file)!r}: geotransform has a zero pixel size ({dx}, {dy})")
    node_x, node_y = x0 + 0.5 * dx, y0 + 0.5 * dy
    if not geographic:  # metres as stored; another unit (feet, ...) converted, as the CRS's metre twin
        projected = _projected_units(crs)
        factor, metre_crs, source, unit, what, converted = 1.0, crs, None, "metre", "", ""
        if projected is not None:
            unit, factor, metre_crs = projected
            what, converted = f"{crs} is in {unit} units", f"{crs} {unit}"
        elif xy_unit is not None:  # a unit no CRS states (none, or one PROJ cannot read): the CRS kept as given
            unit, factor = xy_unit
            what, converted = f"its 'units_xy' is {unit!r}", f"units_xy {unit!r}"
        if factor != 1.0:
            if height_unit is None:
                warnings.warn(
                    f"{name}: {what}, so spacing and origin were converted to metres; the "
                    f"heights are kept as stored (the file does not name their unit): if they are in {unit} too, "
                    f"pass height_unit={unit!r} (metres per unit: {factor:.10g})",
                    stacklevel=caller_stacklevel(),
                )
            source = f"{name} ({converted} as metres: x {factor:.10g})"
        return _Placement((dx * factor, dy * factor), (node_x * factor, node_y * factor), metre_crs,
                          source or name, (crs, (node_x, node_y), (dx, dy), tuple(shape), factor))

    body = _geographic_body(crs)
    if body.degrees != 1.0 or body.meridian != 0.0 or body.east != 1.0:  # grads (EPSG:4807), longitudes east of
        # Paris, or west longitudes (taken as east ones, the grid sat mirrored at the mirrored longitude): as such
        x0, dx = body.meridian + body.east * x0 * body.degrees, body.east * dx * body.degrees
        y0, dy = y0 * body.degrees, dy * body.degrees
        node_x, node_y = x0 + 0.5 * dx, y0 + 0.5 * dy
    rows = shape[0]
    node_lats = (node_y, node_y + (rows - 1) * dy)
    if not all(abs(lat) <= 90.0 + 1e-9 for lat in node_lats):  # metres would be made of impossible degrees
        raise _NotDegrees(
            file, crs, f"the grid's node latitudes run from {min(node_lats):.9g} to {max(node_lats):.9g}; expected "
            "them within [-90, 90] (a projected grid labelled with a geographic CRS?)"
        )
    node_lons = (node_x, node_x + (shape[1] - 1) * dx)
    if not all(abs(lon) <= _LONGITUDE_LIMIT for lon in node_lons):  # lon_0=1e300 made no local metres
        raise _NotDegrees(
            file, crs, f"the grid's node longitudes run from {min(node_lons):.9g} to {max(node_lons):.9g}; expected "
            f"them within [-{_LONGITUDE_LIMIT:g}, {_LONGITUDE_LIMIT:g}] (a projected grid labelled with a geographic "
            "CRS?)"
        )
    lon_span = (shape[1] - 1) * abs(dx)
    if lon_span > 360.0 + 1e-9:  # the nodes went round the globe more than once: a strip wider than the earth
        raise _NotDegrees(
            file, crs, f"the grid's node longitudes span {lon_span:.9g} degrees ({shape[1]} columns of "
            f"{abs(dx):.9g}); expected at most 360 (a projected grid labelled with a geographic CRS, or a wrong "
            "longitude step?)"
        )
    centre_lat = y0 + 0.5 * rows * dy
    # R as the crs writes it (10 digits: the mean radius of Mars is 3389526.666...): metres from another R read back
    # as lon/lat steps of 0.009999999999016579 for 0.01
    radius, lat_ts, stated = float(f"{body.radius:.10g}"), centre_lat, metres is not None
    if metres is None:
        metres = (
            radius * math.cos(math.radians(centre_lat)) * math.radians(abs(dx)),
            radius * math.radians(abs(dy)),
        )
    else:  # the file's own metres: the sphere and standard parallel of the projection they are exact in
        radius = abs(metres[1]) / math.radians(abs(dy))
        cos_ts = abs(metres[0]) / (radius * math.radians(abs(dx)))
        lat_ts = math.degrees(math.acos(cos_ts)) if cos_ts <= 1.0 else math.nan
    spacing = (math.copysign(abs(metres[0]), dx), math.copysign(abs(metres[1]), dy))
    _check_local_metres(file, crs, (node_x, node_x + (shape[1] - 1) * dx), node_y + np.arange(rows) * dy,
                        (abs(metres[0]) / abs(dx), abs(metres[1]) / abs(dy)), body, name=name)
    local_crs: str | None = (
        f"+proj=eqc +lat_ts={lat_ts:.9f} +lat_0={node_y:.9f} +lon_0={node_x:.9f} "
        f"+x_0=0 +y_0=0 +R={radius:.10g} +units=m +no_defs"
    )
    how = f"dx at lat {centre_lat:.6f}, R = {radius:.10g} m"
    if stated:  # the crs described R = 6371008.8 m and dx at the centre latitude, not these metres
        how = f"dx_m, dy_m from the file: lat_ts {lat_ts:.6f}, R = {radius:.10g} m"
        if math.isnan(lat_ts):
            local_crs, how = None, "dx_m, dy_m from the file, no CRS"
            warnings.warn(
                f"{name}: its dx_m, dy_m ({metres[0]:.10g}, {metres[1]:.10g} m) give more metres per degree of "
                f"longitude than of latitude, which no equidistant cylindrical projection of a sphere does: the grid "
                "keeps them, without a CRS",
                stacklevel=caller_stacklevel(),
            )
    source = (
        f"{name} ({crs or 'geographic'} degrees as local metres: node (0, 0) at lon {node_x:.9f}, "
        f"lat {node_y:.9f}; {how})"
    )
    return _Placement(spacing, (0.0, 0.0), local_crs, source, None)


#: What :func:`degrees_as_local_metres` names the grid in its refusals and warnings when it has no ``source``.
_GIVEN_GRID = "the heights"


def degrees_as_local_metres(
    shape: tuple[int, int], spacing: tuple[float, float], origin: tuple[float, float], crs: str | None,
    source: str | None,
) -> tuple[tuple[float, float], tuple[float, float], str | None, str] | None:
    """For :meth:`Terrain.from_heights` (and a grid Terrain built directly) whose ``crs`` is geographic: its
    ``spacing`` and ``origin`` (node (0, 0)) are degrees, placed as :func:`load_dem` places a file in degrees (local
    metres, origin (0, 0), a spherical ``+proj=eqc`` CRS; the same warnings) as (spacing, origin, crs, source); None
    for any other ``crs`` (projected, local, none: the grid is in its own units). Built as given, such a grid had
    cells of a thousandth of a metre under heights in metres: slopes 10^5 too steep (an ROI's ``slope_above``
    marked the whole terrain, renders asked for z_scale 8e-5). An InvalidInputError naming crs, spacing and origin
    when they are no degrees (latitudes beyond ±90, longitudes over more than 360 or beyond ±720: metres labelled
    geographic)."""
    if not crs or crs.lstrip().lower().startswith("+proj=eqc") or not _is_geographic(crs):
        return None
    (dx, dy), (x0, y0) = spacing, origin
    geotransform = np.array([x0 - 0.5 * dx, dx, 0.0, y0 - 0.5 * dy, 0.0, dy], dtype=np.float64)  # cell corners
    try:  # its warnings (told at the caller's line) and source name the grid as the caller did
        place = _placement(Path(_GIVEN_GRID), shape, geotransform, crs, geographic=True, metres=None,
                           height_unit=None, name=source or _GIVEN_GRID)
    except _NotDegrees as exc:
        raise InvalidInputError(
            f"crs {crs!r} is geographic, so spacing {tuple(spacing)} and origin {tuple(origin)} are read as degrees "
            f"(and made local metres, as load_dem makes a file in degrees), but {exc.reason}; if they are metres, "
            "pass the projected CRS they are in (or crs=None)"
        ) from exc
    assert place.source is not None
    return place.spacing, place.origin, place.crs, place.source


def units_as_metres(
    spacing: tuple[float, float], origin: tuple[float, float], crs: str | None, source: str | None,
    height_unit: str | None, *, what: str = "spacing and origin",
) -> tuple[tuple[float, float], tuple[float, float], str | None, str] | None:
    """For :meth:`Terrain.from_heights` (and a grid Terrain built directly) whose ``crs`` is projected (or a local
    engineering CRS) in a unit other than the metre (EPSG:2229 counts US survey feet): its ``spacing`` and ``origin``
    (node (0, 0)) in that unit made metres, as :func:`load_dem` makes a file's (:func:`_placement`: the CRS its metre
    twin, EPSG:26945, the unit named in the source) as (spacing, origin, crs, source); None for a CRS in metres, a
    geographic or unknown one, none, or without rasterio to look it up. Kept as given, a grid in feet was 3.28
    times wider than load_dem's of the same raster, its heights in metres standing on feet (slopes 3.28 times too
    steep). Without ``height_unit`` it warns, at the caller's line, that the heights are taken as given (metres):
    from_heights converts no heights, so heights in that unit too are the caller's to convert. ``what`` the warning
    says was converted (a TIN's "x and y of its points": :func:`points_as_metres`)."""
    projected = _projected_units(crs) if crs else None
    if projected is None:
        return None
    unit, factor, metre_crs = projected
    name = source or _GIVEN_GRID
    if height_unit is None:
        warnings.warn(
            f"{name}: {crs} is in {unit} units, so {what} were converted to metres; the heights are "
            f"taken as given, as metres (height_unit is not named): if they are in {unit} too, convert them "
            f"(heights * {factor:.10g}) and pass height_unit={unit!r}, or height_unit='m' if they are metres",
            stacklevel=caller_stacklevel(),
        )
    (dx, dy), (x0, y0) = spacing, origin
    return ((dx * factor, dy * factor), (x0 * factor, y0 * factor), metre_crs,
            f"{name} ({crs} {unit} as metres: x {factor:.10g})")


def check_projected_scale(
    shape: tuple[int, int], spacing: tuple[float, float], origin: tuple[float, float], crs: str | None,
    source: str | None,
) -> None:
    """For :meth:`Terrain.from_heights` (and a grid Terrain built directly) whose ``crs`` is projected: load_dem's
    warning, at the caller's line, when the projection's map scale over the grid is far from 1
    (:func:`_check_projected_metres`: Web Mercator at 60° N meshes the ground twice too large), ``spacing`` and
    ``origin`` (node (0, 0)) in the CRS's own unit, as given. from_heights ran no such check, so the same grid
    warned when load_dem read it as a GeoTIFF and not when built from its heights. Nothing for a geographic CRS
    (:func:`degrees_as_local_metres` checks its degrees), the local metres of one (a spherical ``+proj=eqc ...
    +R=``: :func:`_spherical_eqc`; degrees placed already, their drift warned of then: a grid rebuilt from a placed
    one's fields, or replaced, warned again, of the sphere's eqc as a projection), none, or one PROJ cannot read."""
    if not crs or _spherical_eqc(crs) is not None or _is_geographic(crs):
        return
    linear = _crs_linear_unit(crs)  # its metres per unit only: not the metre twin _projected_units builds
    _check_projected_metres(Path(_GIVEN_GRID), crs, origin, spacing, shape, 1.0 if linear is None else linear[1],
                            name=source or _GIVEN_GRID)


def points_as_metres(
    xy: NDArray[np.float64], used: NDArray[np.bool_], crs: str | None, source: str | None, height_unit: str | None,
    faces: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.float64], str | None, str] | None:
    """For :meth:`Terrain.from_mesh` (and a TIN Terrain built directly) whose ``crs`` is geographic or projected in a
    unit other than the metre: its points' ``xy`` (N, 2) made metres as a grid's spacing and origin are
    (:func:`degrees_as_local_metres`, :func:`units_as_metres`, load_dem's placement) as (xy, crs, source); None for a
    CRS in metres (its map scale over the points' extent checked as a grid's: :func:`check_projected_scale`), a local
    ``+proj=eqc`` one (degrees placed already), an unknown one or none. ``used``: the points on the TIN's kept faces,
    whose extent is the TIN's. Degrees become local metres of a spherical ``+proj=eqc`` CRS true at the points' middle
    latitude, (0, 0) at their lowest longitude and latitude (load_dem's sphere and warnings; an InvalidInputError
    when they are no degrees); another unit becomes metres, the CRS its metre twin, warning, at the caller's line,
    when ``height_unit`` is None that the heights are taken as given. A TIN kept its degrees or feet under heights in
    metres (slopes 10^5 or 3.28 times too steep) while the same surface as a grid was made metres. ``faces`` (the
    kept faces): where one spans more than 180° of longitude the points cross the antimeridian ([179.99, -179.99],
    or [359.99, 0.01]), and their longitudes are unwrapped first (cut at their widest gap round the circle): taken
    as given, each such face spanned the globe, the TIN 40,000 km wide."""
    if not crs or crs.lstrip().lower().startswith("+proj=eqc"):
        return None
    name = source or "the mesh"
    if _is_geographic(crs):
        body = _geographic_body(crs)
        lon = body.meridian + body.east * xy[:, 0] * body.degrees
        lat = xy[:, 1] * body.degrees
        lons, lats = lon[used], lat[used]
        lon_0, lon_1, lat_0, lat_1 = float(lons.min()), float(lons.max()), float(lats.min()), float(lats.max())
        reason = None
        if not (-90.0 - 1e-9 <= lat_0 and lat_1 <= 90.0 + 1e-9):
            reason = f"its points' latitudes run from {lat_0:.9g} to {lat_1:.9g}; expected them within [-90, 90]"
        elif lon_1 - lon_0 > 360.0 + 1e-9:
            reason = f"its points' longitudes span {lon_1 - lon_0:.9g} degrees; expected at most 360"
        if reason is not None:
            raise InvalidInputError(
                f"crs {crs!r} is geographic, so the mesh's x and y are read as degrees (and made local metres, as "
                f"load_dem makes a file in degrees), but {reason}; if they are metres, give the mesh the projected "
                "CRS they are in (metadata['crs']), or none"
            )
        if faces is not None and len(faces) and (np.ptp(lon[faces], axis=1) > 180.0).any():
            circle = np.unique(np.mod(lons, 360.0))  # sorted; the widest gap round the circle is where none lie
            gaps = np.diff(np.append(circle, circle[0] + 360.0))
            start = float(circle[(int(np.argmax(gaps)) + 1) % len(circle)])
            start = start - 360.0 if start >= 180.0 else start
            lon = start + np.mod(lon - start, 360.0)
            lons = lon[used]
            lon_0, lon_1 = float(lons.min()), float(lons.max())
        lat_ts = 0.5 * (lat_0 + lat_1)
        radius = float(f"{body.radius:.10g}")  # as the CRS writes it (see _placement)
        per_degree = (radius * math.cos(math.radians(lat_ts)) * math.pi / 180.0, radius * math.pi / 180.0)
        _check_local_metres(Path(_GIVEN_GRID), crs, (lon_0, lon_1), np.linspace(lat_0, lat_1, 257), per_degree, body,
                            name=name)
        metres = np.column_stack([(lon - lon_0) * per_degree[0], (lat - lat_0) * per_degree[1]])
        local_crs = (f"+proj=eqc +lat_ts={lat_ts:.9f} +lat_0={lat_0:.9f} +lon_0={lon_0:.9f} "
                     f"+x_0=0 +y_0=0 +R={radius:.10g} +units=m +no_defs")
        return metres, local_crs, (f"{name} ({crs} degrees as local metres: (0, 0) at lon {lon_0:.9f}, lat "
                                   f"{lat_0:.9f}; dx at lat {lat_ts:.6f}, R = {radius:.10g} m)")
    # the points' extent as a grid of _SCALE_SAMPLES x _SCALE_SAMPLES nodes: its map scale checked as a grid's
    inside = xy[used]
    low, high = inside.min(axis=0), inside.max(axis=0)
    samples = _SCALE_SAMPLES
    check_projected_scale((samples, samples), (float(high[0] - low[0]) / (samples - 1),
                                               float(high[1] - low[1]) / (samples - 1)),
                          (float(low[0]), float(low[1])), crs, name)
    placed = units_as_metres((1.0, 1.0), (0.0, 0.0), crs, name, height_unit, what="x and y of its points")
    if placed is None:
        return None
    factor = placed[0][0]
    return xy * factor, placed[2], placed[3]


def _check_degrees_without_crs(file: Path, terrain: Terrain, crs: str | None = None) -> None:
    """Warn, at the caller of :func:`load_dem`, when a grid georeferenced without a CRS (or with ``crs``, one that
    PROJ cannot read: :func:`_unreadable_crs`) looks given in degrees: its
    nodes lie within longitudes and latitudes (x in [-180, 360], y in [-90, 90]) and its heights span more than
    :data:`_DEGREES_RELIEF` times its width and height. Read as metres (a GeoTIFF whose CRS was lost, a world file
    without its .prj), an SRTM tile became a needle a few centimetres wide under hundreds of metres of relief,
    without a word; no terrain in one unit is that steep."""
    x_min, x_max, y_min, y_max = terrain.extent
    if not (-180.0 <= x_min and x_max <= 360.0 and -90.0 <= y_min and y_max <= 90.0):
        return
    try:
        low, high = terrain.height_range
    except InvalidInputError:  # nodata only (read_dem's nodata_only: a batch's tile file of sea): no relief to judge
        return
    across = max(x_max - x_min, y_max - y_min)
    if not high - low > _DEGREES_RELIEF * across:
        return
    name = file.name
    if _local_gzip(file) is not None:  # a local .gz: the .prj of the file inside is read beside it
        hint = f"put a .prj with it beside the file ({file.with_suffix('.prj').name})"
    elif isinstance(file, GdalPath):  # in a zip or at a URL: no .prj beside it is read, and gdal_edit cannot edit it
        hint = f"`gdal_translate -a_srs EPSG:4326 {os.fspath(file)} {file.stem}.tif` writes a copy that names it"
    elif file.suffix.lower() in (".tif", ".tiff"):
        hint = (f"put a .prj with it beside the file ({file.with_suffix('.prj').name}), or assign it: "
                f"`gdal_edit.py -a_srs EPSG:4326 {name}`")
    elif file.suffix.lower() in GDAL_FORMATS:
        hint = f"put a .prj with it beside the file ({file.with_suffix('.prj').name})"
    else:
        hint = "save it beside the 'transform' (crs='EPSG:4326')"
    dx, dy = terrain.spacing
    warnings.warn(
        f"{name}: {'it names no CRS' if crs is None else f'its CRS {crs!r} is not one PROJ can read'}, so its "
        f"coordinates were read as metres, but they look like degrees: nodes at x "
        f"{x_min:.9g} to {x_max:.9g}, y {y_min:.9g} to {y_max:.9g} (cells of {abs(dx):.6g} x {abs(dy):.6g}) under "
        f"heights spanning {high - low:.6g}, {(high - low) / across:.3g} times the grid's size; if they are degrees, "
        f"give the file its CRS: {hint}",
        stacklevel=caller_stacklevel(),
    )


def _negligible_rotation(
    row_x: float, col_y: float, dx: float, dy: float, shape: tuple[int, ...]
) -> bool:
    """Whether a geotransform's rotation terms (``row_x``, x per row, and ``col_y``, y per column) are float noise
    (1e-16, or 1e-12 of the pixel size, as some tools write) rather than a rotation: taken as 0 they move no node of
    a grid of ``shape`` (H, W) by more than :data:`_ROTATION_TOLERANCE` of the smaller pixel size, i.e.
    max(|row_x|, |col_y|) * max(H, W) <= 1e-6 * min(|dx|, |dy|). Exact zeros always pass."""
    if row_x == 0.0 and col_y == 0.0:
        return True
    worst = max(abs(row_x), abs(col_y)) * max(shape[0], shape[1])
    return bool(math.isfinite(worst) and worst <= _ROTATION_TOLERANCE * min(abs(dx), abs(dy)))


class _Body(NamedTuple):
    """What a geographic CRS's coordinates mean (:func:`_geographic_body`): ``degrees`` per unit of its angles (0.9
    for grads), its prime ``meridian`` in degrees east of Greenwich (Paris: 2.33722917), the semi-major axis ``a``
    (m) and flattening ``f`` of its ellipsoid and its ``name``, the ``radius`` (m) of the sphere its degrees become
    metres on, and whether it is the ``earth`` (WGS 84 and :data:`EARTH_RADIUS_M` then); ``east`` is -1 for a
    longitude axis that increases westwards (``AXIS["Longitude",WEST]``), else 1."""

    degrees: float = 1.0
    meridian: float = 0.0
    a: float = _WGS84_A
    f: float = _WGS84_F
    name: str = "WGS 84"
    radius: float = EARTH_RADIUS_M
    earth: bool = True
    east: float = 1.0


_EARTH = _Body()


def _geographic_body(crs: str | None) -> _Body:
    """The angular unit, prime meridian and body of a geographic CRS (its GDAL WKT's GEOGCS: PRIMEM in degrees, as
    GDAL writes it, UNIT in radians, SPHEROID a and 1/f): an earth ellipsoid (a within 1 % of WGS 84's) is compared
    with WGS 84 and made metres on the sphere of :data:`EARTH_RADIUS_M`, another body's (Mars, the Moon: IAU_2015
    codes, ``+R=3396190``) with its own ellipsoid on the sphere of its mean radius a·(1 - f/3) (IUGG R1). Degrees
    from Greenwich on the earth without rasterio to read the CRS, or for a CRS it cannot."""
    crs_obj = _crs_object(crs) if crs else None
    try:
        wkt = crs_obj.to_wkt() if crs_obj is not None else ""
    except Exception:  # no WKT1 form: nothing to read
        wkt = ""
    geogcs = _wkt_block(wkt, ("GEOGCS",)) if wkt else None
    if geogcs is None:
        return _EARTH

    def numbers(keyword: str) -> tuple[str, list[float]]:
        return _wkt_name_numbers(_wkt_block(geogcs, (keyword,)) or "")

    name, spheroid = numbers("SPHEROID")
    _, meridian = numbers("PRIMEM")
    _, unit = numbers("UNIT")
    degrees = math.degrees(unit[0]) if unit and math.isfinite(unit[0]) and unit[0] > 0 else 1.0
    if abs(degrees - 1.0) < 1e-12:  # the degree, as WKT rounds it (0.0174532925199433)
        degrees = 1.0
    west = re.search(r'AXIS\["[^"]*",\s*WEST\s*\]', geogcs) is not None  # the longitude axis increases westwards
    body = _EARTH._replace(degrees=degrees, meridian=meridian[0] if meridian and math.isfinite(meridian[0]) else 0.0,
                           east=-1.0 if west else 1.0)
    if len(spheroid) < 2 or not (math.isfinite(spheroid[0]) and spheroid[0] > 0 and math.isfinite(spheroid[1])):
        return body
    a, inverse = spheroid[0], spheroid[1]
    if abs(a / _WGS84_A - 1.0) <= 0.01:  # an earth ellipsoid (Clarke, Bessel, GRS 80, ...): the earth's sphere
        return body
    f = 1.0 / inverse if inverse > 1.0 else 0.0
    return body._replace(a=a, f=f, name=name or "its", radius=a * (1.0 - f / 3.0), earth=False)


def _wgs84_metres_per_degree(
    lats: NDArray[np.float64], body: _Body = _EARTH
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """WGS 84 (or ``body``'s ellipsoid's) ground metres per degree of longitude along the parallels at ``lats``
    (N(φ) cos φ) and per degree of latitude along the meridian there (M(φ)), latitudes in degrees."""
    e2 = body.f * (2.0 - body.f)
    phi = np.radians(np.asarray(lats, dtype=np.float64))
    w2 = 1.0 - e2 * np.sin(phi) ** 2
    per_lon = np.radians(body.a / np.sqrt(w2) * np.cos(phi))
    per_lat = np.radians(body.a * (1.0 - e2) / w2**1.5)
    return per_lon, per_lat


def local_metres_error(node_lats: NDArray[np.float64], per_degree: tuple[float, float], body: _Body = _EARTH) -> float:
    """Worst relative error, over the rows at ``node_lats`` (degrees), of one local spacing of ``per_degree`` (metres
    per degree of longitude, of latitude) against the WGS 84 ellipsoid (or ``body``'s): of the scale along the
    parallel (N cos φ), along the meridian (M) and of their product, the cell area; inf for a row at a pole (a degree
    of longitude is 0 m there)."""
    per_lon, per_lat = _wgs84_metres_per_degree(node_lats, body)
    with np.errstate(divide="ignore"):
        east = np.where(per_lon > 1e-6, per_degree[0] / np.maximum(per_lon, 1e-6), np.inf)
    north = per_degree[1] / per_lat
    worst = np.max(np.maximum(np.maximum(np.abs(east - 1.0), np.abs(north - 1.0)), np.abs(east * north - 1.0)))
    return float(worst)


def _check_local_metres(
    file: Path, crs: str | None, lons: tuple[float, float], node_lats: NDArray[np.float64],
    per_degree: tuple[float, float], body: _Body = _EARTH, *, name: str | None = None,
) -> None:
    """Warn, at the caller of :func:`load_dem`, when a geographic grid's one local spacing errs by more than
    :data:`_LOCAL_METRES_TOLERANCE` against WGS 84 (another body's own ellipsoid, ``body``) somewhere in its rows
    (:func:`local_metres_error`): a tall grid, or one far from the equator, whose east-west metres drift with cos φ.
    ``lons`` are its first and last node longitudes, for the hint (an earth CRS's, as a projection on another body
    has no EPSG code). ``name`` what the warning calls the grid (default the file's name)."""
    error = local_metres_error(node_lats, per_degree, body)
    if error <= _LOCAL_METRES_TOLERANCE:
        return
    low, high = float(np.min(node_lats)), float(np.max(node_lats))
    how = f"up to {100 * error:.3g} %"
    if math.isinf(error):
        how = "an unbounded amount (a row of nodes at a pole, where a degree of longitude is 0 m)"
    warnings.warn(
        f"{file.name if name is None else name}: {crs or 'geographic'} degrees read as local metres with one spacing "
        f"({per_degree[0]:.6g} m per degree of longitude, {per_degree[1]:.6g} m per degree of latitude) err against "
        f"{body.name if body.earth else f'the {body.name} ellipsoid'}'s ground distances and cell areas by "
        f"{how} over its node latitudes {low:.6g} to {high:.6g} ({high - low:.6g} degrees), more than "
        f"{100 * _LOCAL_METRES_TOLERANCE:g} %; for true metres "
        f"{_reprojection_hint(file, lons, low, high, earth=body.earth)}",
        stacklevel=caller_stacklevel(),
    )


def _check_projected_metres(
    file: Path, crs: str | None, node: tuple[float, float], spacing: tuple[float, float], shape: tuple[int, ...],
    factor: float, *, name: str | None = None,
) -> None:
    """Warn, at the caller of :func:`load_dem`, when a grid in a projected CRS, whose metres are read as ground
    metres, errs by more than :data:`_LOCAL_METRES_TOLERANCE` against WGS 84 ground distances or cell areas
    somewhere: a projection's scale drifts away from its standard point or lines (Mercator 1/cos φ, 1.41 at 45°;
    a continent-wide Albers or Lambert conformal conic 1-2 % at its edges; a sinusoidal grid far from its central
    meridian shears and stretches north-south), and the mesh is that much larger or smaller than the ground, its
    slopes flatter or steeper. ``node`` is node (0, 0), ``spacing`` (dx, dy), both in the CRS's unit of ``factor``
    metres, ``shape`` the grid's (H, W).

    The scale is measured through PROJ at up to :data:`_SCALE_SAMPLES` x :data:`_SCALE_SAMPLES` nodes (the grid's
    corners, edges and inside): each node's neighbours :data:`_SCALE_STEP_M` apart along x and along y (central
    differences) go to WGS 84 degrees and their WGS 84 ground chords (earth-centred coordinates) are compared with
    the mesh's lengths along x and y and with its cell area (the chords' cross product, so a sheared projection's
    area too). A UTM grid of a zone's extent (0.9996-1.001) and a small local grid stay within 1 %. Without
    rasterio, for a CRS on another body or one PROJ cannot invert, nothing is said. ``name`` what the warning calls
    the grid (default the file's name)."""
    crs_obj = _crs_object(crs) if crs else None
    if crs_obj is None:
        return
    (node_x, node_y), (dx, dy) = node, spacing
    rows = node_y + dy * np.unique(np.linspace(0, shape[0] - 1, min(shape[0], _SCALE_SAMPLES)).round())
    cols = node_x + dx * np.unique(np.linspace(0, shape[1] - 1, min(shape[1], _SCALE_SAMPLES)).round())
    px, py = (v.ravel() for v in np.meshgrid(cols, rows))
    half = 0.5 * _SCALE_STEP_M / factor  # in the CRS's unit
    xs = np.concatenate([px, px - half, px + half, px, px])
    ys = np.concatenate([py, py, py, py - half, py + half])
    try:
        import rasterio
        from rasterio.warp import transform

        with rasterio.Env():
            lon, lat = (np.asarray(v, dtype=np.float64).reshape(5, -1)
                        for v in transform(crs_obj, "EPSG:4326", xs.tolist(), ys.tolist()))
    except Exception:  # PROJ cannot take it to WGS 84 degrees (another body, a broken CRS): nothing to compare with
        return
    ok = np.isfinite(lat).all(axis=0) & np.isfinite(lon).all(axis=0) & (np.abs(lat) <= 90.0).all(axis=0)
    if not ok.any():
        return
    lon, lat = lon[:, ok], lat[:, ok]
    ecef = _wgs84_ecef(lon, lat)  # (5, n, 3)
    along_x, along_y = ecef[2] - ecef[1], ecef[4] - ecef[3]
    with np.errstate(divide="ignore", invalid="ignore"):
        kx = _SCALE_STEP_M / np.linalg.norm(along_x, axis=-1)
        ky = _SCALE_STEP_M / np.linalg.norm(along_y, axis=-1)
        karea = _SCALE_STEP_M**2 / np.linalg.norm(np.cross(along_x, along_y), axis=-1)
    errors = np.maximum(np.maximum(np.abs(kx - 1.0), np.abs(ky - 1.0)), np.abs(karea - 1.0))
    errors = np.where(np.isnan(errors), np.inf, errors)  # two neighbours on one point: a singular projection there
    error = float(errors.max())
    if not error > _LOCAL_METRES_TOLERANCE:
        return
    node_lats, node_lons = lat[0], lon[0]
    low, high = float(node_lats.min()), float(node_lats.max())
    east = (node_lons - node_lons[0] + 180.0) % 360.0 - 180.0  # relative to one node: across the antimeridian too
    lons = (float(node_lons[0] + east.min()), float(node_lons[0] + east.max()))
    at = int(np.argmax(errors))
    try:
        mercator = crs_obj.to_dict().get("proj") in _MERCATOR
    except Exception:
        mercator = False
    what = (
        "is a Mercator projection, whose metres are not ground metres away from the equator"
        if mercator
        else "is a projection whose metres are ground metres only near its standard point or lines"
    )
    warnings.warn(
        f"{file.name if name is None else name}: {crs} {what}: its grid, read as stored, errs against WGS 84 ground "
        f"distances and cell areas by "
        f"up to {100 * error:.3g} % over its node latitudes {low:.6g} to {high:.6g} (x {float(kx[at]):.4g} east-west "
        f"and x {float(ky[at]):.4g} north-south along the grid's x and y, x {float(karea[at]):.4g} in cell area, at "
        f"latitude {float(node_lats[at]):.6g}, longitude {float(node_lons[at]):.6g}: the mesh is that much larger "
        f"than the ground there, or smaller below 1, its slopes that much flatter or steeper), more than "
        f"{100 * _LOCAL_METRES_TOLERANCE:g} %; for true metres {_reprojection_hint(file, lons, low, high, crs)}",
        stacklevel=caller_stacklevel(),
    )


def _wgs84_ecef(lon: NDArray[np.float64], lat: NDArray[np.float64]) -> NDArray[np.float64]:
    """Earth-centred coordinates (metres, a trailing axis of 3) of WGS 84 longitudes and latitudes (degrees) on the
    ellipsoid: their differences are ground chords, exact at the poles and across the antimeridian."""
    e2 = _WGS84_F * (2.0 - _WGS84_F)
    phi, lam = np.radians(lat), np.radians(lon)
    n = _WGS84_A / np.sqrt(1.0 - e2 * np.sin(phi) ** 2)
    return np.stack([n * np.cos(phi) * np.cos(lam), n * np.cos(phi) * np.sin(lam), n * (1.0 - e2) * np.sin(phi)],
                    axis=-1)


def _reprojection_hint(
    file: Path, lons: tuple[float, float], low: float, high: float, current: str | None = None, *, earth: bool = True
) -> str:
    """How to reproject a grid whose node longitudes run over ``lons`` and latitudes from ``low`` to ``high`` to true
    metres: its UTM zone when it fits one (unless that is ``current``, the grid's own CRS), a polar stereographic
    projection true at its middle latitude near a pole (EPSG:3413 and EPSG:3031, true at 70° N and 71° S, err by 3 %
    at the poles and 4 % at 60°; where ``current`` is that projection already, advice to mesh the grid in smaller
    parts), else a projected CRS of its region."""
    centre, centre_lon = 0.5 * (low + high), 0.5 * (lons[0] + lons[1])
    if not earth:  # another body (Mars, the Moon): no EPSG projection of it
        code = target = ""
    elif abs(lons[1] - lons[0]) <= 6.0 and high - low <= 20.0 and abs(centre) <= 80.0:
        zone = int(math.floor(((centre_lon + 180.0) % 360.0) / 6.0)) % 60 + 1
        code = f"EPSG:{(32600 if centre >= 0 else 32700) + zone}"
        target = f"{code} (WGS 84 / UTM zone {zone}{'N' if centre >= 0 else 'S'})"
        if current is not None and current.strip().upper() == code:
            code = target = ""
    elif low >= 60.0 or high <= -60.0:
        lon_0 = (centre_lon + 180.0) % 360.0 - 180.0
        code = f"'+proj=stere +lat_0={90 if centre > 0 else -90} +lat_ts={centre:.1f} +lon_0={lon_0:.1f} " \
               "+datum=WGS84 +units=m'"
        target = "a polar stereographic projection true at its middle latitude"
        if current is not None and _polar_stereographic_near(current, 90.0 if centre > 0 else -90.0, centre):
            # the grid is in that projection already (the CRS this hint gave it): warped again, it warned again,
            # naming the same gdalwarp; a polar grid over some 8 degrees of latitude errs by over 1 % in any one
            return (f"no one projection keeps a grid over {high - low:.3g} degrees of latitude within "
                    f"{100 * _LOCAL_METRES_TOLERANCE:g} %, and {current} is the polar stereographic projection true "
                    "at its middle latitude already: mesh it in smaller parts for truer metres")
    else:
        code = target = ""
    if not code:
        return "reproject it to a projected CRS of its region first, or mesh a global grid on the globe " \
               "(stepterrain globe)"
    if file.suffix.lower() in GDAL_FORMATS:
        # -dstalpha: the cells of the projected grid outside the file's (the corners round a polar wedge) missing;
        # without it (and a nodata value of the file's) gdalwarp filled them with 0, cliffs to 0 m without a word
        return (f"reproject it first: `gdalwarp -r bilinear -dstalpha -t_srs {code} {shlex.quote(file.name)} "
                f"{shlex.quote(file.stem + '_m.tif')}`, {target}")
    return f"reproject it first, e.g. to {target}" + ("" if target.startswith(code) else f", {code}")


def _polar_stereographic_near(crs: str, pole: float, latitude: float) -> bool:
    """Whether ``crs`` is a polar stereographic projection about ``pole`` (90 or -90) true within a degree of
    ``latitude``: what :func:`_reprojection_hint` would advise for a grid there."""
    crs_obj = _crs_object(crs)
    try:
        params = crs_obj.to_dict() if crs_obj is not None else {}
        return bool(params.get("proj") == "stere" and float(params.get("lat_0", 0.0)) == pole
                    and abs(float(params.get("lat_ts", pole)) - latitude) <= 1.0)
    except Exception:  # noqa: BLE001 - a CRS PROJ cannot describe as parameters: not that projection
        return False


_PARSED_CRS: dict[str, Any] = {}  # CRS string -> rasterio CRS: a batch reads many files in one CRS


def _crs_object(crs: str) -> Any:
    """rasterio's CRS for ``crs``, parsed once per string; None without rasterio or for a string it cannot read
    (the grid then keeps its own units). Only parsed CRSs are kept."""
    parsed = _PARSED_CRS.get(crs)
    if parsed is not None:
        return parsed
    try:
        import rasterio
        from rasterio.crs import CRS
    except ImportError:
        return None
    try:
        # outside an Env, GDAL's own handler printed "ERROR 1: PROJ: ... crs not found" to stderr for an unknown
        # EPSG code (once per lookup) though the file still loads; inside one its errors go to rasterio's logger
        with rasterio.Env():
            parsed = CRS.from_user_input(crs)
    except Exception:  # an unparseable CRS string
        return None
    if len(_PARSED_CRS) >= 64:
        _PARSED_CRS.clear()
    _PARSED_CRS[crs] = parsed
    return parsed


def _is_geographic(crs: str | None) -> bool:
    if not crs:
        return False
    if crs.strip().upper() in _GEOGRAPHIC_CODES:
        return True
    try:
        import rasterio.crs  # noqa: F401  (without it: read the CRS string's first word)
    except ImportError:
        return crs.lstrip().upper().startswith(("GEOGCS", "GEOGCRS", "+PROJ=LONGLAT", "+PROJ=LATLONG"))
    crs_obj = _crs_object(crs)
    return bool(crs_obj is not None and crs_obj.is_geographic)


def _projected_units(crs: str | None) -> tuple[str, float, str | None] | None:
    """(unit, metres per unit, the same projection in metres) of a projected CRS, or a local engineering one (a site
    grid: LOCAL_CS, ENGCRS), whose unit is not the metre; None for metres, a geographic or unknown CRS, or without
    rasterio to look the CRS up. (A site grid in feet kept feet as metres while a band's unit "ft" made its heights
    metres: 3.28 times too wide for them.)"""
    linear = _crs_linear_unit(crs)  # a CRS read already (_crs_object keeps it)
    if linear is None or linear[1] == 1.0:
        return None
    unit, factor = linear
    crs_obj = _crs_object(crs)
    wkt = "" if crs_obj.is_projected else crs_obj.to_wkt()
    if wkt:  # the site grid in metres: its one UNIT (no PROJ form to change it in)
        block = _wkt_block(wkt, ("LENGTHUNIT", "UNIT"))
        try:
            metre_wkt = wkt.replace(block, 'UNIT["metre",1,AUTHORITY["EPSG","9001"]]', 1) if block else None
            return str(unit), float(factor), _crs_string(type(crs_obj).from_wkt(metre_wkt)) if metre_wkt else None
        except Exception:  # a site grid GDAL cannot write back: metres without a CRS to name them
            return str(unit), float(factor), None
    try:  # PROJ's false easting and northing are metres whatever +units says: only the unit changes
        params = {key: value for key, value in crs_obj.to_dict().items() if key != "to_meter"}
        metre_crs = _crs_string(type(crs_obj).from_dict({**params, "units": "m"})) if params else None
    except Exception:  # no PROJ form of this CRS: metres without a CRS to name them
        metre_crs = None
    return str(unit), float(factor), metre_crs


def _wkt_block(wkt: str, keywords: tuple[str, ...]) -> str | None:
    """The first ``KEYWORD[...]`` of ``keywords`` in a WKT string, brackets matched (names hold none)."""
    starts = [i for i in (wkt.find(k + "[") for k in keywords) if i >= 0]
    if not starts:
        return None
    start = min(starts)
    depth = 0
    for end in range(wkt.index("[", start), len(wkt)):
        depth += {"[": 1, "]": -1}.get(wkt[end], 0)
        if depth == 0:
            return wkt[start: end + 1]
    return None


def _wkt_name_numbers(block: str) -> tuple[str, list[float]]:
    """The quoted name of a WKT ``KEYWORD["name",n1,n2,...]`` block ("" without one) and the numbers right after
    it, up to the first field that is not one (an AUTHORITY, the closing bracket): ``SPHEROID["WGS 84",6378137,
    298.257223563,AUTHORITY["EPSG","7030"]]`` gives ("WGS 84", [6378137.0, 298.257223563])."""
    parts = block.split('"')
    values: list[float] = []
    for field in re.split(r"[,\]]", parts[2].lstrip(" ,")) if len(parts) > 2 else []:
        try:
            values.append(float(field))
        except ValueError:
            break
    return (parts[1] if len(parts) > 1 else ""), values


def _compound_heights(crs: str | None) -> tuple[str, float | None, str | None] | None:
    """(the vertical part's length unit, its metres per unit as the WKT states it (None when it states none), the
    horizontal part as a CRS string) of a compound CRS (e.g. "EPSG:26911+6360", NAD83 / UTM 11N + NAVD88 height in
    US survey feet); None for any other CRS or without rasterio to read it."""
    crs_obj = _crs_object(crs) if crs else None
    if crs_obj is None:  # no rasterio, or a CRS it cannot read: nothing to say about the heights
        return None
    wkt = crs_obj.to_wkt()
    if not wkt.lstrip().startswith(("COMPD_CS[", "COMPOUNDCRS[")):
        return None
    vertical = _wkt_block(wkt, ("VERT_CS", "VERTCRS"))
    unit = _wkt_block(vertical, ("LENGTHUNIT", "UNIT")) if vertical else None
    if unit is None or '"' not in unit:
        return None
    horizontal = _wkt_block(wkt, ("PROJCS", "PROJCRS", "GEOGCS", "GEOGCRS"))
    try:
        horizontal_crs = _crs_string(type(crs_obj).from_wkt(horizontal)) if horizontal else None
    except Exception:  # keep the compound CRS when its horizontal part does not stand alone
        horizontal_crs = crs
    # UNIT["British foot (Sears 1922)",0.304799471538676,...]: the metres per unit after the name
    name, values = _wkt_name_numbers(unit)
    factor = values[0] if values else math.nan
    return name, factor if math.isfinite(factor) and factor > 0 else None, horizontal_crs


def _warn_unit_against_vertical(file: Path, unit: str | None, crs: str | None, named_by: str) -> None:
    """Warn, at the caller of :func:`load_dem`, when the file's own height ``unit`` (``named_by``: "band 1's unit")
    and the vertical unit of its compound CRS ``crs`` are both known lengths that differ (by more than 1e-5: a
    US survey foot is a foot): the file's own is used, as GDAL reads it, and the heights are 3.28 times off if the
    CRS is right. A band unit of metres in a GeoTIFF of NAVD88 height (ftUS) was read as metres without a word."""
    compound = _compound_heights(crs) if unit and unit.strip() and crs else None
    if compound is None:
        return
    name, stated, _ = compound
    own, vertical = _unit_factor(unit), _unit_factor(name) or stated
    if own is None or vertical is None or abs(own / vertical - 1.0) <= 1e-5:
        return
    warnings.warn(
        f"{file.name}: {named_by} {unit!r} is not the vertical unit of its CRS, {name!r} ({crs}): heights read in "
        f"{unit}, as GDAL reads them ({own / vertical:.6g} times what the CRS's unit makes them); if they are in "
        f"{name}, pass height_unit={name!r}",
        stacklevel=caller_stacklevel(),
    )


def _vertical_unit(unit: str | None, crs: str | None) -> tuple[str | None, str | None, float | None]:
    """The heights' unit (the file's own, else a compound CRS's vertical unit), the CRS to keep and, when the unit
    is the compound CRS's and not one of :data:`_HEIGHT_UNITS` (British foot, Clarke's foot, ...), the metres per
    unit its WKT states (else None). The CRS kept is its horizontal part when the heights become metres from a
    vertical part in another unit (GDAL names a band's unit after the vertical CRS; an .npz names none), which then
    no longer describes them."""
    compound = _compound_heights(crs)
    if compound is None:
        return unit, crs, None
    name, stated, horizontal = compound
    vertical = _unit_factor(name) or stated
    if vertical is None:  # a vertical unit without a factor: named by the error of _heights_in_metres
        return unit or name, crs, None
    # the CRS's factor for its own unit: no unit named by the file, or the one GDAL named the band after it
    factor = stated if _unit_factor(name) is None and (not unit or unit.strip() == name) else None
    unit = unit or name
    if (_unit_factor(unit) or factor) is None or vertical == 1.0:
        return unit, crs, factor  # heights refused by unit, or the vertical part is in metres and still applies
    return unit, horizontal, factor


def check_band(band: Any) -> int:
    """``band`` as an int when it is a positive 1-based band number (:func:`load_dem`), else an InvalidInputError."""
    if isinstance(band, bool) or not isinstance(band, (int, np.integer)) or band < 1:
        raise InvalidInputError(f"band must be a positive 1-based band number; got {band!r}")
    return int(band)


def check_height_encoding(height_encoding: Any, height_unit: str | None = None) -> str:
    """``height_encoding`` in lower case when it names one of :data:`HEIGHT_ENCODINGS` (any case), else an
    InvalidInputError listing them; also one when a ``height_unit`` (checked) other than the metre comes with it: the
    encodings define metres (a unit of feet scaled the decoded metres by 0.3048 without a word)."""
    name = height_encoding.strip().lower() if isinstance(height_encoding, str) else None
    if name not in HEIGHT_ENCODINGS:
        raise InvalidInputError(
            f"height_encoding must be one of {', '.join(map(repr, HEIGHT_ENCODINGS))} or None; got {height_encoding!r}"
        )
    if height_unit is not None and _unit_factor(height_unit) != 1.0:
        raise InvalidInputError(
            f"height_unit applies to heights of no stated unit; height_encoding={name!r} gives metres; "
            f"got height_unit={height_unit!r}"
        )
    return name


def check_height_unit(height_unit: Any) -> str:
    """``height_unit`` when it names a known length unit (:func:`load_dem`), else an InvalidInputError listing them."""
    if not isinstance(height_unit, str) or _unit_factor(height_unit) is None:
        raise InvalidInputError(f"height_unit must be a length unit ({_KNOWN_UNITS}) or None; got {height_unit!r}")
    return height_unit


def _unit_factor(unit: str | None) -> float | None:
    """Metres per ``unit`` for a known height unit (:data:`_HEIGHT_UNITS`, any case, blanks and dots around it
    ignored), else None."""
    return _HEIGHT_UNITS.get(unit.strip(" \t.").lower()) if unit else None


def _warn_unit_override(file: Path, height_unit: str | None, declared: str | None, where: str) -> None:
    """Warn when ``height_unit`` (load_dem's) overrides a known unit the file declares (``declared``, named by
    ``where``: "its 'units'", "band 1's unit") that gives other metres: ``stepterrain info dem.npz --height-unit ft``
    read heights the file declares metres as feet without a word, where --height-unit's help said it was for a file
    naming no unit or one not known. Silent where the file names none, one not known, or one of the same length."""
    if height_unit is None or not declared or not declared.strip():
        return
    own, given = _unit_factor(declared), _unit_factor(height_unit)
    if own is None or own == given:
        return
    warnings.warn(
        f"{file.name}: height_unit={height_unit!r} overrides the unit the file declares ({where}: "
        f"{declared.strip()!r}): its heights are read in {height_unit} ({given:.10g} m each), not in "
        f"{declared.strip()} ({own:.10g} m each)",
        stacklevel=caller_stacklevel(),
    )


def _heights_in_metres(
    heights: NDArray[np.float32], unit: str | None, file: Path, named_by: str, factor: float | None = None
) -> tuple[NDArray[np.float32], str | None]:
    """Heights in metres when ``unit`` is a known length unit, or one a compound CRS states the ``factor`` (metres
    per unit) of (returned as named), as stored and None when no unit is named (None or blank). Any other unit is a
    DataFileError naming ``file`` and where the unit came from (``named_by``): heights in "km" or "cm" were used as
    metres, 1000 times too low or 100 times too high."""
    if not unit or not unit.strip():
        return heights, None
    factor = _unit_factor(unit) or factor
    if factor is None:
        raise DataFileError(
            f"cannot read {str(file)!r}: expected heights in a known length unit ({_KNOWN_UNITS}); got {unit!r} "
            f"({named_by}); if they are lengths, name their unit: height_unit='m' (or 'ft', ...)"
        )
    if factor != 1.0:  # scaled in float64, in place (the product was a second float64 copy)
        scaled = heights.astype(np.float64)
        scaled *= factor
        heights = scaled.astype(np.float32)
    return heights, unit


def _crs_string(crs_obj: Any) -> str | None:
    """``crs_obj`` (rasterio's CRS) as a CRS string: ``EPSG:n`` where it is one EPSG CRS, ``EPSG:h+v`` where it is a
    compound CRS of two (:func:`_compound_epsg`: a GeoTIFF of WGS 84 / UTM 33N + EGM96 height gave its WKT, a
    thousand characters in `info` and in a message), else its WKT or PROJ string."""
    if crs_obj is None:
        return None
    epsg = crs_obj.to_epsg()
    if epsg is not None:
        return f"EPSG:{epsg}"
    return _compound_epsg(crs_obj) or crs_obj.to_string() or None


def _compound_epsg(crs_obj: Any) -> str | None:
    """``EPSG:h+v`` for a compound CRS whose horizontal and vertical parts are EPSG CRSs and which that string reads
    back as (GDAL's ``EPSG:32633+5773``), else None."""
    try:
        wkt = crs_obj.to_wkt()
        if not wkt.lstrip().startswith(("COMPD_CS[", "COMPOUNDCRS[")):
            return None
        parts = (_wkt_block(wkt, ("PROJCS", "PROJCRS", "GEOGCS", "GEOGCRS")), _wkt_block(wkt, ("VERT_CS", "VERTCRS")))
        codes = [type(crs_obj).from_wkt(part).to_epsg() if part else None for part in parts]
        if None in codes:
            return None
        text = f"EPSG:{codes[0]}+{codes[1]}"
        return text if type(crs_obj).from_user_input(text) == crs_obj else None
    except Exception:  # noqa: BLE001 - a part GDAL cannot read alone: the WKT as it is
        return None
