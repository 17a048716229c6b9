"""Multiresolution texture model and its level of detail (paper 004 §3.1-3.2.2 and §4, Fig. 1-2).

:class:`ImagePyramid` halves an image of any size down to 1 x 1 (area-weighted, so odd sizes keep the mean),
each level a memory-mapped file so images larger than RAM work. :class:`PatchQuadtree` is the geometry
multiresolution model H(G) (a quadtree of grid patches with their geometric error e(N) and bounding boxes
B(N)); :class:`TextureTree` names, per geometry patch, the pyramid level and sub-image that cover it at the
highest resolution within a maximum texture size, without copying image data. :func:`render_with_textures` is
the simultaneous traversal ``renderWithTextures`` of §4: visual geometric error γ(N) and visual texture error
τ(N, M) in screen pixels for a :class:`Camera`, parent reduction, on-demand loading in a background thread with
the parent as fallback (:class:`TextureCache`, LRU memory budget) and hybrid shading (§7.3). Typical use:

    pyramid = ImagePyramid.build("big.npy", extent=(x0, x1, y0, y1))
    quadtree = PatchQuadtree(terrain, leaf_size=64)
    tree = TextureTree(pyramid, quadtree, max_texture_size=1024)
    cache = TextureCache()   # one for every frame: it loads patches in the background
    draws = render_with_textures(quadtree.root, [tree.root], camera, gamma_user=1.0, tau_user=1.0, cache=cache)
"""

from __future__ import annotations

import contextlib
import math
import mmap
import os
import re
import shutil
import tempfile
import threading
import uuid
import warnings
import weakref
from collections import OrderedDict
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import warp as wp
from numpy.typing import ArrayLike, NDArray

from ._device import host_copy, launch, resolve_device
from .camera import Camera, _box
from .errors import DataFileError, InvalidInputError, OutputTooLargeError, caller_stacklevel, counted, plain_repr
from .io import (
    _ROTATION_TOLERANCE,
    _check_read_budget,
    _crs_object,
    _crs_string,
    _geographic_body,
    _is_geographic,
    _negligible_rotation,
    _projected_units,
    _spherical_eqc,
    _wkt_block,
    gdal_reason,
    lonlat_as_local_metres,
    open_raster,
    picture_uint8,
    prj_crs,
    world_file_names,
)
from .kernels import texture as texture_kernels
from .terrain import Terrain, as_array, as_number, as_terrain, check_flag, finite_number, real_numbers
from .texture import TextureLayer, _check_extent, _grid_terrain, _masked_pixels, terrain_extent

__all__ = [
    "ImagePyramid",
    "PatchQuadtree",
    "GeometryPatch",
    "TextureTree",
    "TexturePatch",
    "Camera",
    "TextureCache",
    "DrawItem",
    "render_with_textures",
    "paint_with_textures",
    "visual_geometric_error",
    "visual_texture_error",
    "pyramid_shapes",
    "image_layer",
    "is_georeferenced",
]

Extent = tuple[float, float, float, float]
_BAND_BYTES = 32 * 1024**2  # source bytes read per band while building a level
#: :func:`image_layer` warns when its image covers less than this fraction of the terrain's extent: a sliver of it is
#: more often a wrong CRS, a misread world file or a swapped extent than an image meant to cover so little
_MIN_IMAGE_COVERAGE = 0.1


# ---------------------------------------------------------------------------------------------- pyramid
def pyramid_shapes(height: int, width: int) -> list[tuple[int, int]]:
    """Level sizes: each ceil(previous / 2) per axis, down to 1 x 1 (level 0 = the image).

    Examples
    --------
    >>> pyramid_shapes(5, 8)
    [(5, 8), (3, 4), (2, 2), (1, 1)]

    ``height`` and ``width`` must be whole numbers >= 1 (an InvalidInputError naming the argument): a size of 0 or
    less halved to 0 for ever (never reaching 1 x 1, the list grew until memory ran out), and 2.5 was cut to 2.
    """
    sizes = []
    for value, name in ((height, "height"), (width, "width")):
        whole = isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
        if not whole or value < 1:
            raise InvalidInputError(f"{name} must be a whole number of pixels >= 1; got {plain_repr(value)}")
        sizes.append(int(value))
    shapes = [(sizes[0], sizes[1])]
    while shapes[-1] != (1, 1):
        h, w = shapes[-1]
        shapes.append(((h + 1) // 2, (w + 1) // 2))
    return shapes


def _georeferencing(dataset: Any) -> tuple[Any, tuple[int, int], str | None]:
    """(transform, (height, width), CRS string) of an open rasterio dataset, for :func:`_georeferenced_extent`."""
    return dataset.transform, (int(dataset.height), int(dataset.width)), _crs_string(dataset.crs)


def _georeferenced_extent(image: Any, found: tuple[Any, tuple[int, int], str | None] | None) -> tuple[
        Extent, str | None] | None:
    """((xmin, xmax, ymin, ymax), CRS or None) of an image path ``image`` from its own georeferencing ``found`` (a
    GeoTIFF's, or a JPEG's or PNG's world file: :func:`_georeferencing`, read with its pixels by
    :func:`_source_image`), else None; in metres for a projected
    CRS (or a site grid) in feet or another linear unit, with that projection in metres as the CRS, as
    :func:`~stepterrain.io.load_dem` reads a DEM in it (the bounds of an orthophoto in EPSG:2229 stayed in feet,
    refused against its DEM's metres)."""
    if found is None:  # not an image path, or one GDAL cannot read: pixel units, no warning
        return None
    transform, shape, crs = found
    if transform.is_identity:
        return None
    # rotation terms of float noise (1e-16, as some tools write) are read as 0, by load_dem's rule, so a texture and
    # its DEM are judged alike: any non-zero term fell back to pixel units (0, W, 0, H), silently misplaced
    if not _negligible_rotation(transform.b, transform.d, transform.a, transform.e, shape):
        raise InvalidInputError(
            f"image {str(image)!r} is georeferenced with a rotated geotransform {tuple(transform)[:6]} (its rotation "
            f"terms move pixels by more than {_ROTATION_TOLERANCE:g} of a pixel over {shape[0]} x {shape[1]} "
            "pixels); a pyramid's extent is north-up: `gdalwarp -dstalpha` makes the image north-up, or pass "
            "extent=(xmin, xmax, ymin, ymax) for it as it is")
    left, right = transform.c, transform.c + transform.a * shape[1]  # the bounds without the noise terms
    top, bottom = transform.f, transform.f + transform.e * shape[0]
    if transform.a < 0 or transform.e > 0:  # its bounds came back as an extent with ymin > ymax, "not given"
        raise InvalidInputError(
            f"image {str(image)!r} is georeferenced with its rows running south to north or its columns east to "
            f"west (pixel size {transform.a:g} x {transform.e:g}); a pyramid's row 0 is the north edge and column 0 "
            "the west edge: write the image north-up, or pass extent=(xmin, xmax, ymin, ymax) for it as it is")
    units = _projected_units(crs)
    factor = 1.0
    if units is not None:  # feet -> metres, named as load_dem names the DEM's CRS
        _, factor, crs = units
    return (float(left * factor), float(right * factor), float(bottom * factor), float(top * factor)), crs


def _source_image(image: Any, dataset: Any = None) -> tuple[NDArray[np.uint8], str | None, bool, Any]:
    """(array (H, W, C) uint8, backing file or None, whether its pixels can change after this: the caller's
    writeable array, or a view of one; an image path's :func:`_georeferencing`, else None). An image file is
    opened with rasterio once (``dataset``: already open), for its georeferencing (a GeoTIFF's own, a world file
    beside a JPEG or PNG), its nodata mask and (a TIFF Pillow cannot read) its pixels."""
    path = None
    georeferencing = None
    if isinstance(image, (bytes, bytearray)):  # np.asarray made it a dtype |S array, refused as not uint8
        raise InvalidInputError("image must be an (H, W) or (H, W, C) uint8 array or a path (a str or os.PathLike); "
                                f"got {type(image).__name__}")
    if isinstance(image, (str, os.PathLike)):
        path = Path(image)
        if path.is_dir():  # was called a file that "does not exist"
            raise DataFileError(f"image file {str(path)!r} is a folder; expected an image file")
        if not path.is_file():
            raise DataFileError(f"image file {str(path)!r} does not exist")
        if path.suffix.lower() == ".npy":
            try:
                image = np.load(path, mmap_mode="r")
            except (ValueError, OSError) as exc:
                raise DataFileError(f"cannot read {str(path)!r} as a .npy image: {exc}") from exc
        else:
            from PIL import Image, UnidentifiedImageError

            try:
                with Image.open(path) as picture:
                    orientation = _tiff_as_stored(picture)  # not turned by Pillow, as GDAL (the window read) reads it
                    # its pixels are decoded whole (level 0): checked first, as a GeoTIFF read with rasterio is
                    _check_read_budget(path, (len(picture.getbands()), picture.height, picture.width),
                                       np.dtype(np.uint8), "the image")
                    image = picture_uint8(picture, f"image {str(path)!r}", alpha=True)
                    _warn_exif_orientation(picture, path, orientation=orientation)
            except (InvalidInputError, OutputTooLargeError):  # readable, but not an image a pyramid holds, or too big
                raise
            except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
                # past Pillow's decompression-bomb limit (not an OSError: it went past raw), a TIFF reads with rasterio
                found = _read_tiff(path, _tiff_reader(path, None), dataset=dataset)  # a TIFF Pillow cannot identify
                if found is None:  # that GDAL reads
                    raise DataFileError(f"cannot read {str(path)!r} as an image: {exc}") from exc
                image, mask, georeferencing = found
            else:
                # any format GDAL reads, not only a TIFF: a JPEG or PNG is georeferenced by its world file (.jgw,
                # .pgw, .wld) or .aux.xml, which GDAL reads (it was placed at (0, W, 0, H), "no georeferencing")
                found = _read_tiff(path, _tiff_reader(path, image), any_format=True, dataset=dataset)
                image, mask, georeferencing = found or (image, None, None)
            if mask is not None:
                image = np.concatenate([image, mask[:, :, None]], axis=2)
    array = image if isinstance(image, np.ndarray) else as_array(image, "image", "an (H, W) or (H, W, C) uint8 array")
    if array.dtype != np.uint8:
        raise InvalidInputError(f"pyramid image must be uint8 (0-255); got dtype {array.dtype}")
    if array.ndim == 2:
        array = array[:, :, None]
    if array.ndim != 3 or array.shape[0] < 1 or array.shape[1] < 1 or not 1 <= array.shape[2] <= 4:
        raise InvalidInputError(f"pyramid image must be (H, W) or (H, W, C<=4); got shape {array.shape}")
    masked = _masked_pixels(array)
    if masked is not None:  # its masked pixels transparent (alpha 0), as a GeoTIFF's nodata: the mask was dropped
        # and the values under it drawn (an orthophoto read with rasterio's masked=True: its collar opaque black)
        pixels = np.ma.getdata(array)
        if pixels.shape[2] in (1, 3):  # no alpha yet: one added, 255 where not masked
            pixels = np.concatenate([pixels, np.full((*pixels.shape[:2], 1), 255, np.uint8)], axis=2)
        else:
            pixels = pixels.copy()
        pixels[masked, -1] = 0
        pixels.flags.writeable = False  # this call's own copy: level 0 as it is
        return pixels, None, False, None
    array = np.ma.getdata(array)  # a masked array masking nothing: its values
    backing = _memmap_backing(array)
    if path is not None:  # pixels this call decoded or mapped read-only: level 0 as they are, and read-only
        array.flags.writeable = False
        return array, backing, False, georeferencing
    return array, backing, _may_change(array), None


def _placement(image: Any, extent: ArrayLike | None, crs: Any, georeferencing: Any,
               shape: tuple[int, int]) -> tuple[Extent, str | None, bool]:
    """(extent, CRS, whether the file's georeferencing placed it) of an image of ``shape`` (H, W), as
    :meth:`ImagePyramid.build` places it: ``extent`` as given, else its file's georeferencing (``georeferencing``:
    :func:`_georeferencing`) with its CRS (``crs``, given, must be that one), else (0, W, 0, H)."""
    crs = _optional_crs(crs)
    placed_by_file = False
    if extent is None:
        georeferenced = _georeferenced_extent(image, georeferencing)
        placed_by_file = georeferenced is not None
        if georeferenced is not None:
            if crs is not None and georeferenced[1] is not None and not _same_crs(crs, georeferenced[1]):
                raise InvalidInputError(f"crs {crs!r} is not the CRS {georeferenced[1]!r} of image {str(image)!r}, "
                                        "whose bounds are the extent; pass extent= in crs to place it yourself")
            extent, crs = georeferenced[0], crs or georeferenced[1]
        else:
            extent = (0.0, float(shape[1]), 0.0, float(shape[0]))
    return _check_extent(extent), crs, placed_by_file


#: EXIF orientations (tag 0x0112) other than 1, as a viewer turns the stored pixels to show them.
_EXIF_TURNS = {2: "mirrored left to right", 3: "rotated 180°", 4: "mirrored top to bottom",
               5: "mirrored and rotated 90° counter-clockwise", 6: "rotated 90° clockwise",
               7: "mirrored and rotated 90° clockwise", 8: "rotated 90° counter-clockwise"}


def _warn_exif_orientation(picture: Any, path: Path, exif: Any = None, orientation: int | None = None) -> None:
    """Warn when an image file carries an EXIF orientation other than 1: viewers show it turned, the pyramid (as GDAL
    and QGIS) takes its stored pixels, so an extent given for the picture as seen places it turned. ``exif``: its
    EXIF already read (a ``PIL.Image.Exif``), else ``picture.getexif()``; ``orientation``: a TIFF's Orientation tag
    as :func:`_tiff_as_stored` took it out of ``picture`` (its EXIF no longer holds it)."""
    if orientation is None:
        try:
            orientation = (picture.getexif() if exif is None else exif).get(0x0112)
        except Exception:  # noqa: BLE001 - unreadable EXIF: nothing to say
            return
    turn = _EXIF_TURNS.get(orientation)
    if turn is None:
        return
    width, height = picture.size
    warnings.warn(f"image {str(path)!r} has EXIF orientation {orientation} ({turn} to view): it is drawn as stored, "
                  f"{width} x {height} pixels, as GDAL reads it; to use it as viewers show it, build from "
                  "np.asarray(PIL.ImageOps.exif_transpose(Image.open(path)))", stacklevel=caller_stacklevel())


def _tiff_as_stored(picture: Any) -> int | None:
    """The Orientation tag (274) of ``picture``, a TIFF opened with Pillow and not decoded yet, taken out of it so
    that Pillow decodes its pixels as stored, as GDAL reads them (and :func:`_warn_exif_orientation` says so); None
    for another format or without the tag. Pillow (13: every TIFF; earlier, one libtiff decodes, compressed) turns a
    TIFF by its tag as it decodes it and then drops the tag: a whole read drew it turned, over GDAL's extent of the
    stored pixels (stretched for a 90° turn), unlike the window read (rasterio), without the warning; an uncompressed
    grey or palette TIFF turned 90° came out scrambled (Pillow maps its stored rows at the turned size)."""
    if getattr(picture, "format", None) != "TIFF":
        return None
    tags = picture.tag_v2
    orientation = tags.get(274)
    if orientation is None:
        return None
    del tags[274]
    with contextlib.suppress(Exception):  # its EXIF, read at open, holds the tag that Pillow turns by
        picture.getexif().pop(274, None)
    if 256 in tags and 257 in tags:  # the size Pillow gives (turned for a 90° turn at open): the stored one
        picture._size = (int(tags[256]), int(tags[257]))
    return int(orientation) if isinstance(orientation, int) else None


def _read_tiff(path: Path, read: Callable[[Any], Any], any_format: bool = False, dataset: Any = None) -> Any:
    """``read(dataset)`` of a .tif/.tiff ``path`` (with ``any_format``, of any image file but .npy: a JPEG or PNG
    that GDAL georeferences by its world file) opened with rasterio (a plain image without the warning that it is
    not georeferenced; ``dataset``: the file already open, read without opening it again); None for another
    extension, without rasterio, or when GDAL cannot read the file (Pillow's verdict stands). ``read``'s own refusals
    (InvalidInputError, OutputTooLargeError, DataFileError) go through."""
    suffix = path.suffix.lower()
    if suffix not in (".tif", ".tiff") and (not any_format or suffix == ".npy"):
        return None
    if dataset is None:
        try:
            import rasterio  # noqa: F401 - only whether it is there
        except ImportError:
            return None
    try:
        with open_raster(path) if dataset is None else contextlib.nullcontext(dataset) as opened:
            return read(opened)
    except (InvalidInputError, OutputTooLargeError, DataFileError):
        raise
    except Exception:  # noqa: BLE001 - GDAL cannot read it either
        return None


def _tiff_reader(path: Path, image: NDArray[np.uint8] | None) -> Callable[[Any], Any]:
    """A :func:`_read_tiff` reader giving (image, nodata mask or None, georeferencing or None) in one open: ``image``
    as Pillow read it, or (None) its pixels read with rasterio (:func:`_raster_uint8`); the mask of a 3-channel
    image (:func:`_nodata_mask`); :func:`_georeferencing` (its CRS from a .prj beside it where GDAL reads none:
    :func:`~stepterrain.io.prj_crs`). A mask or georeferencing GDAL cannot read is None, and the others stand, as
    when each was read in an open of its own."""

    def read(dataset: Any) -> tuple[NDArray[np.uint8], NDArray[np.uint8] | None, Any]:
        pixels = _raster_pixels(path, dataset) if image is None else image
        mask = None
        if pixels.shape[2] == 3:  # alpha: Pillow (or the alpha band) gave it
            with contextlib.suppress(Exception):
                mask = _nodata_mask(dataset, pixels.shape[:2])
        return pixels, mask, _dataset_georeferencing(path, dataset)

    return read


def _dataset_georeferencing(path: Path, dataset: Any) -> Any:
    """:func:`_georeferencing` of the open rasterio ``dataset`` of image ``path``, its CRS from a .prj beside it
    where GDAL reads none (:func:`~stepterrain.io.prj_crs`); None where GDAL cannot read it."""
    georeferencing = None
    with contextlib.suppress(Exception):
        georeferencing = _georeferencing(dataset)
    if georeferencing is not None and georeferencing[2] is None and not georeferencing[0].is_identity:
        # ``ortho.prj`` or ``ortho.jpg.prj``, which GDAL does not read for a JPEG or PNG; a .prj that is no CRS is
        # refused, naming it: the image would be taken in the terrain's CRS without a word
        georeferencing = (*georeferencing[:2], prj_crs(path, "image"))
    return georeferencing


def _raster_uint8(path: Path) -> NDArray[np.uint8] | None:
    """A TIFF that Pillow cannot identify (a 3-band 16-bit satellite image, written as bands, not photometric RGB)
    read with rasterio as :func:`~stepterrain.io.picture_uint8` reads an image: the band whose colour interpretation
    is alpha (GDAL's ALPHA=YES) as alpha (RGBA), of the others the first three as RGB or the only one as grey (as
    RGB); a fourth band that is not alpha is left out, as Pillow leaves out an extra sample (the near-infrared of an
    RGB + NIR image is no alpha); 16-bit values scaled by their full range (value / 257). None without rasterio or
    when GDAL cannot read it either; an InvalidInputError for bands of another count or type."""
    return _read_tiff(path, lambda dataset: _raster_pixels(path, dataset))


def _image_bands(dataset: Any) -> tuple[list[int], list[int]]:
    """The bands (0-based) of the open rasterio ``dataset`` as an image's channels, as :func:`_raster_uint8` takes
    them, and its alpha band ([] or one): of the bands whose colour interpretation is not alpha the first three
    (RGB), or the first three times (grey as RGB), then the first alpha band."""
    from rasterio.enums import ColorInterp

    alphas = [k for k, interp in enumerate(dataset.colorinterp) if interp == ColorInterp.alpha][:1]
    colour = [k for k in range(dataset.count) if k not in alphas]
    return (colour[:3] if len(colour) >= 3 else colour[:1] * 3) + alphas, alphas


def _all_valid(dataset: Any) -> bool:
    """Whether the open rasterio ``dataset`` has no GDAL mask (nodata, a mask band): every band all valid."""
    from rasterio.enums import MaskFlags

    return all(flags == [MaskFlags.all_valid] for flags in dataset.mask_flag_enums)


def _raster_pixels(path: Path, dataset: Any) -> NDArray[np.uint8]:
    """The pixels of :func:`_raster_uint8` from its open rasterio ``dataset``."""
    count, types = dataset.count, sorted(set(dataset.dtypes))
    bands, _ = _image_bands(dataset)
    if not 1 <= count <= 4 or types not in (["uint8"], ["uint16"]):
        raise InvalidInputError(f"image {str(path)!r} must be an 8-bit or 16-bit image of 1-4 bands; got "
                                f"{counted(count, 'band')} of {', '.join(types)}")
    _check_read_budget(path, (count, dataset.height, dataset.width), np.dtype(types[0]), "the image")
    # band by band, 16 bits scaled by a table: all bands through float64 at once peaked at 18 bytes a cell,
    # four and a half times what the budget counted
    image = np.empty((dataset.height, dataset.width, len(bands)), dtype=np.uint8)
    scale = None  # round(v / 257) = (2 v + 257) // 514 (v / 257 is never halfway), per 16-bit value
    if types == ["uint16"]:
        scale = ((np.arange(65536, dtype=np.uint32) * 2 + 257) // 514).astype(np.uint8)
    for k, band in enumerate(bands):
        if k and band == bands[k - 1]:  # grey as RGB: the band once
            image[:, :, k] = image[:, :, k - 1]
            continue
        data = dataset.read(band + 1)
        image[:, :, k] = data if scale is None else scale[data]
        del data
    return image


def _nodata_mask(dataset: Any, shape: tuple[int, ...]) -> NDArray[np.uint8] | None:
    """A GeoTIFF's GDAL mask (nodata, a mask band; rasterio's ``dataset_mask``: 0 missing, 255 valid) of an open
    rasterio ``dataset`` when some pixel is missing, else None (nothing masked, another shape than ``shape``).
    Pillow reads nodata as ordinary pixels: an orthophoto's collar tagged nodata=0 was draped opaque black."""
    if _all_valid(dataset):
        return None
    mask = dataset.dataset_mask()
    if mask.shape != tuple(shape) or mask.min() == 255:
        return None
    return np.where(mask > 0, 255, 0).astype(np.uint8)


def _may_change(array: NDArray[Any]) -> bool:
    """Whether the pixels of ``array`` can still change: it or an array it views is writeable, or the buffer under
    them is (a read-only ``np.load(..., mmap_mode="r")`` map is not)."""
    node: Any = array
    while isinstance(node, np.ndarray):
        if node.flags.writeable:
            return True
        node = node.base
    if node is None:
        return False
    try:
        return not memoryview(node).readonly
    except TypeError:  # a buffer that cannot say: assume it can
        return True


def _write_bands(path: Path, height: int, rows: int, band: Callable[[int, int], NDArray[np.uint8]],
                 level: Path | None = None) -> None:
    """Write an image of ``height`` rows into the raw file ``path``, ``rows`` rows at a time: ``band(r0, r1)`` gives
    rows r0..r1 (whole rows, C order in the file), each freed once written, a memmap's pages dropped from the
    resident set. A failure is a DataFileError naming the pyramid level ``level`` (default ``path``)."""
    name = str(path if level is None else level)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    except OSError as exc:
        raise DataFileError(f"cannot write the pyramid level {name!r}: {exc.strerror}") from exc
    try:
        for r0 in range(0, height, rows):  # a handful of bands, never a loop over pixels
            data = band(r0, min(height, r0 + rows))
            _write_at(fd, data, r0 * (data.size // len(data)))
            if isinstance(data, np.memmap):  # its pages stayed resident: the whole image by the end
                _drop_resident(data)
            del data
    except DataFileError:  # band's own refusal (an image whose read failed): not a failed write of the level
        raise
    except OSError as exc:
        raise DataFileError(f"cannot write the pyramid level {name!r}: {exc}") from exc
    finally:
        os.close(fd)


def _snapshot(source: NDArray[np.uint8], path: Path, band_bytes: int) -> NDArray[np.uint8]:
    """Copy ``source`` into the raw file ``path`` band by band (memory bounded by ``band_bytes``) and map it
    read-only: the pyramid's level 0, which later edits of ``source`` leave alone."""
    height, width, channels = source.shape
    _write_bands(path, height, max(1, band_bytes // max(1, width * channels)), lambda r0, r1: source[r0:r1])
    return np.memmap(path, dtype=np.uint8, mode="r", shape=source.shape)


def _stream_level_0(tiff: _WindowedTiff, path: Path, band_bytes: int) -> int:
    """Write the pixels of ``tiff`` (a :class:`_WindowedTiff`) into the raw file ``path``, level 0 of its pyramid, a
    band of rows at a time (about ``band_bytes``, whole blocks of the file: no tile decoded twice); the channel
    count written. The bytes are those :func:`_source_image` decodes whole: a 3-band image with a GDAL mask of
    which no pixel is masked has no alpha, which only the last band tells (its alpha is then dropped, file to
    file)."""
    height, width, channels = tiff.shape
    rows = max(1, band_bytes // (width * channels))
    if rows > tiff.block_rows:
        rows -= rows % tiff.block_rows
    masked = False

    def band(r0: int, r1: int) -> NDArray[np.uint8]:
        nonlocal masked
        pixels = tiff.rows((0, height, 0, width), r0, r1)
        masked = masked or (tiff.masked and not pixels[:, :, -1].all())
        return pixels

    _write_bands(path, height, rows, band)
    if not tiff.masked or masked:
        return channels
    # a mask with every pixel valid: the whole read gives RGB (_nodata_mask's None), so level 0 drops the alpha
    reader = _Reader(None, str(path), shape=(height, width, channels))
    rgb = path.with_name(path.name + ".rgb")
    try:
        _write_bands(rgb, height, rows, lambda r0, r1: reader.rows(r0, r1)[:, :, :3], level=path)
        os.replace(rgb, path)
    except OSError as exc:
        raise DataFileError(f"cannot write the pyramid level {str(path)!r}: {exc}") from exc
    finally:  # gone once it replaced level 0; a failed build leaves no stray file in storage
        with contextlib.suppress(OSError):
            os.unlink(rgb)
    return channels - 1


def _write_at(fd: int, data: NDArray[Any], offset: int) -> None:
    """All of ``data``'s bytes (C order) into file ``fd`` from byte ``offset`` (pwrite may write less than asked)."""
    view = memoryview(np.ascontiguousarray(data)).cast("B")
    written = 0
    while written < len(view):
        written += os.pwrite(fd, view[written:], offset + written)


def _memmap_backing(array: NDArray[Any]) -> str | None:
    """The file of a C-contiguous memmap, else None."""
    if not (isinstance(array, np.memmap) and array.filename and array.flags.c_contiguous):
        return None
    return array.filename


def _file_state(path: str) -> tuple[str, Any] | None:
    """(path, ((device, inode), size, mtime_ns)) of the file ``path``, None when it cannot be stat'ed. No ctime: a
    chmod or a new hard link (a backup's ``cp -l``) changes it, not the bytes; a rewrite changes mtime or size."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return path, ((st.st_dev, st.st_ino), st.st_size, st.st_mtime_ns)


def _mapped_file(array: Any) -> str | None:
    """The file ``array`` maps, whatever its layout: its own memmap's, or its base's for a view (a slice of channels,
    ``np.asarray`` of a memmap), else None."""
    while isinstance(array, np.ndarray):
        if isinstance(array, np.memmap) and array.filename:
            return array.filename
        array = array.base
    return None


def _storage_folder(storage: Any) -> Path | None:
    """``storage`` as a Path (None stays None), else an InvalidInputError: pathlib raised a TypeError for 5, and
    read "" as the working directory."""
    path = os.fspath(storage) if isinstance(storage, (str, os.PathLike)) else None
    if storage is not None and not isinstance(path, str):
        raise InvalidInputError(f"storage must be a folder path (str or os.PathLike) or None; got {storage!r}")
    if path == "":
        raise InvalidInputError("storage must be a folder path (str or os.PathLike) or None; got '' (an empty path, "
                                "which would put the level files in the working directory; pass '.' for that)")
    return None if path is None else Path(path)


class ImagePyramid:
    """An image pyramid (paper 004 §3.2.1): level 0 is the image, each next level half the size (ceil), down to
    1 x 1, over a georeferenced ``extent`` (xmin, xmax, ymin, ymax; row 0 = north) in the coordinate reference
    system ``crs`` (None: unknown; :class:`TextureTree` refuses a terrain whose own ``crs`` is another, except a
    geographic ``crs`` on a DEM load_dem read from degrees into local metres, where it places the extent exactly).

    Levels 1+ are raw uint8 files in ``storage`` opened as read-only ``numpy.memmap``. Level 0 is the source itself
    when nothing can change it (an image file decoded whole; a .npy stays on disk, memory-mapped read-only: rewritten
    in place after the build, the pyramid refuses to be read, a :class:`DataFileError`); a TIFF of
    8-bit bands or a PNG is read a band of rows at a time into ``storage`` as ``level_0.u8`` (see :meth:`build`); an
    array the caller can still edit (writeable, or a view of one) is copied first, read-only (a writeable memmap into
    ``storage`` as ``level_0.u8``), so editing it after :meth:`build` leaves the pyramid's levels in agreement (the
    image as it was then). Use as a context manager, or :meth:`close`, to delete a
    temporary storage folder (a pyramid never closed deletes it when it is garbage collected, or at the interpreter's
    exit); a closed pyramid refuses to be read (an :class:`InvalidInputError`).
    """

    def __init__(self, levels: list[NDArray[np.uint8]], extent: Extent, storage: str | os.PathLike[str] | None,
                 anisotropic: dict[tuple[int, int], NDArray[np.uint8]] | None = None, owned: bool = False,
                 crs: str | None = None) -> None:
        """Wrap levels already built (:meth:`build` is the usual constructor), e.g. reopened from a ``storage``
        folder with ``numpy.memmap``: ``levels`` from the image (level 0) down to 1 x 1, each (h, w, C) uint8 of
        the sizes :func:`pyramid_shapes` gives; ``anisotropic`` the rip-map levels by (kx, ky); ``owned``:
        :meth:`close` deletes ``storage`` (so does the pyramid's garbage collection, if never closed); ``crs`` the
        extent's CRS. The levels are used as given, not copied
        (:meth:`build` copies an image the caller can still edit). A bad argument raises an
        :class:`InvalidInputError` naming it."""
        expected = "a list of (H, W, C) uint8 arrays from the image (level 0) down to 1 x 1"
        if isinstance(levels, (str, bytes)) or not isinstance(levels, Sequence) or not levels:
            got = "an empty list" if isinstance(levels, Sequence) and not levels else type(levels).__name__
            raise InvalidInputError(f"levels must be {expected}; got {got}")
        levels = list(levels)
        for k, level in enumerate(levels):
            if not (isinstance(level, np.ndarray) and level.dtype == np.uint8 and level.ndim == 3
                    and min(level.shape) >= 1 and level.shape[2] <= 4):
                got = (f"dtype {level.dtype}, shape {level.shape}" if isinstance(level, np.ndarray)
                       else type(level).__name__)
                raise InvalidInputError(f"levels[{k}] must be an (H, W, C) uint8 array with 1-4 channels; got {got}")
        height, width, channels = levels[0].shape
        shapes = [(*shape, channels) for shape in pyramid_shapes(height, width)]
        if len(levels) != len(shapes):  # TextureTree found no level that fits, and blamed the extent
            raise InvalidInputError(f"levels must run from the image down to 1 x 1: {counted(len(shapes), 'level')} "
                                    f"for a {height} x {width} image; got {len(levels)}")
        for k in range(1, len(levels)):
            if levels[k].shape != shapes[k]:
                raise InvalidInputError(f"levels[{k}] must have shape {shapes[k]} (levels[{k - 1}] halved, rounded "
                                        f"up); got {levels[k].shape}")
        if anisotropic is not None and not isinstance(anisotropic, dict):
            raise InvalidInputError(f"anisotropic must be a dict of levels by (kx, ky) or None; got "
                                    f"{type(anisotropic).__name__}")
        owned = check_flag(owned, "owned")
        folder = _storage_folder(storage)
        if owned and folder is None:
            raise InvalidInputError("owned=True deletes the storage folder on close(); got storage=None")
        self._levels = levels
        self.extent = _check_extent(extent)
        self.crs = _optional_crs(crs)
        self.storage = folder
        self._anisotropic = anisotropic or {}
        self._owned = owned
        # an owned folder goes with the pyramid, closed or not (as tempfile.TemporaryDirectory's): one never closed,
        # as the module's typical use builds it, stayed in the temporary folder for good, a third of its image's
        # bytes each time (its maps, still held, keep their pages where the system allows removing a mapped file).
        # Made absolute now: a relative storage, removed after a chdir, was another folder of that name
        self._finalizer = (weakref.finalize(self, shutil.rmtree, os.path.abspath(folder), ignore_errors=True)
                           if owned else None)
        self._closed = False
        self._georeferenced = False  # build() placed it by its file's georeferencing (image_layer asks, not reopens)
        # (the file level 0 maps, its _file_state at the build): set by build() for a .npy path's (or a read-only
        # memmap's) pyramid, checked before its levels are handed out (_check_source)
        self._source: tuple[str, Any] | None = None

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(
        cls,
        image: ArrayLike | str | os.PathLike[str],
        *,
        extent: ArrayLike | None = None,
        storage: str | os.PathLike[str] | None = None,
        anisotropic: bool = False,
        band_bytes: int = _BAND_BYTES,
        device: wp.DeviceLike = None,
        crs: str | None = None,
    ) -> ImagePyramid:
        """Build the pyramid of ``image`` band by band, so memory stays bounded by ``band_bytes``.

        Parameters
        ----------
        image : (H, W) or (H, W, C) uint8 array (a numpy masked array's masked pixels transparent: alpha 0, an
            alpha channel added to grey or RGB), a numpy memmap, or a path (.npy is memory-mapped; PNG, JPEG,
            TIFF are read with Pillow, and a TIFF of 8-bit bands or a PNG as Pillow reads them with rasterio, a band
            of rows at a time, never whole: see Notes; a transparent colour, and a GeoTIFF's nodata or mask band,
            read with rasterio, become alpha; an EXIF orientation, or a TIFF's Orientation tag, is not applied, as
            GDAL does not apply it: warned)
        extent : (xmin, xmax, ymin, ymax), optional
            World extent of the image's outer pixel edges (default: a GeoTIFF's own bounds, or a JPEG's or PNG's
            from the world file beside it (``.jgw``, ``.pgw``, ``.wld``, or an ``.aux.xml``), read with rasterio,
            in metres for a CRS in feet or another linear unit, as load_dem reads a DEM in it; else (0, W, 0, H),
            one unit per pixel).
        crs : str, optional
            The coordinate reference system of the extent, e.g. ``"EPSG:32611"`` (default: a GeoTIFF's own when its
            extent is read from it, a world file's from the ``.prj`` (or ``.aux.xml``) beside the image, else None,
            unknown: taken in the terrain's coordinates). :class:`TextureTree` refuses a terrain in another CRS, but
            places an image in degrees (EPSG:4326, ...) on a DEM that load_dem read from degrees (of the same body)
            into local metres exactly, through the linear map of those metres.
        storage : folder, optional
            Where the level files go (default: a new temporary folder, deleted by :meth:`close`, or when the
            pyramid is garbage collected unclosed). They are written under temporary names and renamed into place
            when all are complete, so a failed build leaves the folder's earlier files as they were (and removes
            the folder if it made it), and a pyramid built there before keeps its levels; a complete build then
            removes the level files there it did not write (an earlier pyramid's: of a larger image, or its
            anisotropic levels, or level_0.u8 of another image), so the folder holds this pyramid's alone; the
            file the image itself maps (a level of the folder, reopened) stays.
        anisotropic : bool
            Also store the anisotropic levels (kx, ky): width halved kx times, height ky times (a rip-map),
            used against blurring at grazing angles (§3.2.1).
        band_bytes : int
            Source bytes processed per band (of an image file read by bands, also its bytes read per band, in whole
            tiles or strips of the file).
        device : warp device, optional
            Where the levels are reduced (default: Warp's default device).

        Raises
        ------
        DataFileError
            Missing or corrupt image file, or the storage folder cannot be written.
        InvalidInputError
            Not a uint8 image of 1-4 channels, or a bad extent; a .prj beside a georeferenced image that is no
            CRS; a GeoTIFF (or world file) that is rotated (rotation terms of float
            noise, as load_dem reads them, count as 0), south-up or east-to-west, without ``extent``.

        Notes
        -----
        Level k+1 pixel r covers source pixels [r n/m, (r+1) n/m) of level k (n source, m = ceil(n / 2)
        target pixels per axis): an area-weighted mean, so every level keeps the image mean up to the rounding
        to uint8, for odd sizes too (a plain 2 x 2 box when n is even). The mean is summed exactly (integers) and
        rounded half up, floor(mean + 0.5), on both paths. An image with alpha (2 channels, grey + alpha, or 4, RGBA;
        straight alpha, as PNG and glTF hold it) averages its colour weighted by alpha, sum(w a c) / sum(w a), so a
        transparent pixel's colour (a nodata collar's black) does not darken the edge of the coarser levels; its alpha
        and premultiplied colour keep their means. The values are averaged as stored (sRGB-encoded bytes, gamma
        space, as GDAL's overviews and Pillow's reduce average), not in linear light: a fine black-and-white
        pattern averages to 128, which displays darker than its linear-light mean (188). One Warp thread per target
        pixel; the levels are written with ``pwrite`` and read back with ``pread``, never mapped while building; a
        memmap source is read through its own mapping (not its file name, which may name a replacement by now), each
        band's pages dropped from the resident set once copied, so the resident memory stays about two bands whatever
        the image size. An image array the caller can still
        edit is copied first, so that later edits do not make level 0 disagree with the levels built from it: in
        memory (the image's bytes once more; about 7 % of the build time at 2048²), a writeable memmap band by band
        into ``storage`` (``level_0.u8``). A read-only array that owns its pixels, or a .npy path, is not copied.
        An image file is decoded whole into memory (checked against the memory budget) and taken as level 0, except
        a TIFF of 8-bit bands or a PNG that GDAL reads to the bytes Pillow reads (L, RGB or RGBA without a
        transparent colour; not a JPEG-compressed, min-is-white or 1-7 bit TIFF, an interlaced PNG, nor a PNG with a
        GDAL nodata mask): that is read with rasterio a band of rows at a time (``band_bytes``, whole tiles or strips,
        all bands in one read) into ``storage`` as ``level_0.u8``, and the levels reduced from that file, byte for
        byte the pyramid of the whole read, with memory bounded by the band and GDAL's block cache (5 % of RAM by
        default, ``GDAL_CACHEMAX``) instead of the image: a tiled deflate 16000 x 16000 RGB GeoTIFF peaked at 1.15 GB
        (0.48 GB with ``GDAL_CACHEMAX=64``) for 6-10 s of CPU time (5-6.5 s), from 2.0 GB (1.33 GB) and 6-7.5 s
        (9.6-10.8 s), imports included, on 2 shared cores; a 9000 x 9000 RGB PNG at 0.61 GB (0.45 GB) from 1.33 GB,
        for about 1 s more (3.5-4.7 s: level 0 goes through its file). A 3-band image with a mask (nodata) that
        masks no pixel has no alpha, as read whole.

        Examples
        --------
        >>> import numpy as np
        >>> from stepterrain.texture_lod import ImagePyramid
        >>> with ImagePyramid.build(np.full((5, 3, 3), 200, np.uint8), device="cpu") as pyramid:
        ...     [level.shape for level in pyramid.levels]
        [(5, 3, 3), (3, 2, 3), (2, 1, 3), (1, 1, 3)]
        """
        with contextlib.ExitStack() as files:
            opened: dict[str, Any] = {}  # the file opened with rasterio, read whole below if not by bands: one open
            tiff = _WindowedTiff.open(image, files, opened=opened)  # a TIFF of 8-bit bands, a PNG: by bands
            return cls._build(image, tiff, opened.get("dataset"), extent=extent, storage=storage,
                              anisotropic=anisotropic, band_bytes=band_bytes, device=device, crs=crs)

    @classmethod
    def _build(cls, image: Any, tiff: _WindowedTiff | None, dataset: Any, *, extent: ArrayLike | None,
               storage: str | os.PathLike[str] | None, anisotropic: bool, band_bytes: int, device: wp.DeviceLike,
               crs: str | None) -> ImagePyramid:
        """:meth:`build`, the image's pixels from ``tiff`` (streamed into ``level_0.u8``) when it is one, else
        decoded whole (``dataset``: the image file already open with rasterio, or None)."""
        if tiff is None:
            source, backing, changeable, georeferencing = _source_image(image, dataset)
            height, width, channels = (int(n) for n in source.shape)
        else:  # nothing decoded yet: its pixels go into level 0's file band by band below
            source, backing, changeable, georeferencing = None, None, False, tiff.georeferencing
            height, width, channels = tiff.shape
        extent, crs, placed_by_file = _placement(image, extent, crs, georeferencing, (height, width))
        if isinstance(band_bytes, bool) or not isinstance(band_bytes, (int, np.integer)) or band_bytes < 1:
            raise InvalidInputError(f"band_bytes must be a positive int; got {plain_repr(band_bytes)}")
        band_bytes = int(band_bytes)  # a NumPy integer too (as a level, a lens' resolution): refused before
        anisotropic = check_flag(anisotropic, "anisotropic")
        given = _storage_folder(storage)
        dev = resolve_device(device)  # before a folder is made: a bad device left it (and a temporary one) behind
        owned = given is None
        made: list[Path] = []  # the folders this build made for a given storage, removed again if it fails
        try:
            folder = Path(tempfile.mkdtemp(prefix="stepterrain-pyramid-")) if given is None else given
            # made where symbolic links lead, as export.atomic_path makes a file's folder: a dangling link (levels ->
            # /scratch/new) was refused "File exists" (mkdir of the link's own name)
            real = Path(os.path.realpath(folder))
            if given is not None:
                made = [p for p in (real, *real.parents) if not p.exists()]
            real.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise DataFileError(f"cannot create the pyramid storage folder {str(storage)!r}: {exc}") from exc
        shapes = pyramid_shapes(height, width)
        # every level file is written under a temporary name and renamed into place once all are complete: writing
        # over the files of an earlier pyramid in the same storage changed its levels under it (its maps showed the
        # new image; a smaller one read zeros or crashed with SIGBUS past the shortened file), and a failed build
        # left truncated files in place of the earlier complete ones
        staged = _StagedFiles(folder)
        try:
            if tiff is not None:  # never decoded whole: a band of rows at a time into level 0's file
                path = staged.path("level_0.u8")
                channels = _stream_level_0(tiff, path, band_bytes)
                source = np.memmap(path, dtype=np.uint8, mode="r", shape=(height, width, channels))
            elif changeable and backing is None:  # the caller may edit it later: then level 0 would disagree with
                source = source.copy()  # the levels below; in memory already, so a copy there (a memcpy)
                source.flags.writeable = False
            elif changeable:  # a writeable memmap: the copy goes to storage, band by band (memory stays bounded)
                path = staged.path("level_0.u8")
                source = _snapshot(source, path, band_bytes)
            levels: list[NDArray[np.uint8]] = [source]
            reader = _Reader(source, None)  # level 0 itself, through its mapping (never its file name)
            for k in range(1, len(shapes)):
                path = staged.path(f"level_{k}.u8")
                _reduce_file(reader, shapes[k - 1], shapes[k], channels, path, band_bytes, dev)
                reader = _Reader(None, str(path), shape=(*shapes[k], channels))
            for k in range(1, len(shapes)):
                levels.append(np.memmap(staged.path(f"level_{k}.u8"), dtype=np.uint8, mode="r",
                                        shape=(*shapes[k], channels)))
            aniso: dict[tuple[int, int], NDArray[np.uint8]] = {}
            if anisotropic:
                aniso = _anisotropic_levels(levels, shapes, channels, staged, band_bytes, dev)
            staged.commit()  # the files under their own names, mapped from there (a later build replaces the names)
            levels = [staged.reopen(level) for level in levels]
            aniso = {key: staged.reopen(level) for key, level in aniso.items()}
            # an earlier, other pyramid's files there, but not the file level 0 maps (the caller's image, read
            # there in any layout: a C-contiguous memmap's alone was known, and a view's file deleted under it)
            staged.remove_stale(keep=[_mapped_file(levels[0])])
        except BaseException:
            staged.discard()
            if owned:
                shutil.rmtree(folder, ignore_errors=True)
            for path in made:  # deepest first: a failed build left the storage folder it made, empty, behind
                try:
                    path.rmdir()
                except OSError:  # not empty (something else wrote there meanwhile), or gone: left as it is
                    break
            raise
        pyramid = cls(levels, extent, folder, aniso, owned, crs)
        pyramid._georeferenced = placed_by_file
        if tiff is None and backing is not None and not changeable:  # level 0 maps the caller's file (a .npy path)
            pyramid._source = _file_state(backing)
        return pyramid

    @classmethod
    def _header(cls, shape: tuple[int, int, int], extent: Extent, crs: str | None) -> ImagePyramid:
        """A pyramid of an image of ``shape`` (H, W, C) over ``extent`` with no pixels (each level a broadcast zero,
        no memory): its shapes, windows and extents for :func:`image_layer`, which reads the pixels of one window
        itself (:class:`_WindowedTiff`)."""
        blank = np.zeros((1, 1, shape[2]), dtype=np.uint8)
        levels = [np.broadcast_to(blank, (*level, shape[2])) for level in pyramid_shapes(*shape[:2])]
        return cls(levels, extent, None, crs=crs)

    # ------------------------------------------------------------------ access
    def _open(self, what: str) -> None:
        if self._closed:  # level 0 (the source) could still be read, the other levels raised IndexError
            raise InvalidInputError(f"the ImagePyramid is closed (by close() or the end of its with block), so "
                                    f"{what} cannot be read; build the pyramid again")

    @property
    def levels(self) -> list[NDArray[np.uint8]]:
        """The levels, 0 (the image) to the 1 x 1 one."""
        self._open("its levels")
        if self._source is not None:
            self._check_source()
        return self._levels

    def _check_source(self) -> None:
        """Raise a DataFileError when the file level 0 maps (a .npy path's) was rewritten in place since the build:
        level 0 showed the new image under levels 1+ of the old one, without a word (and a shorter file killed the
        process with SIGBUS on the next read). A file replaced under its name, or deleted, leaves the old one mapped,
        whole: nothing to refuse."""
        path, built = self._source
        found = _file_state(path)
        now = None if found is None else found[1]
        if now is not None and now[0] == built[0] and now != built:  # the same file (device, inode), rewritten
            raise DataFileError(f"image file {str(path)!r} changed since its ImagePyramid was built from it (level 0 "
                                "maps the file, the coarser levels hold the image as it was): build the pyramid "
                                "again, or replace the file (write another and rename it over) instead of "
                                "rewriting it in place")

    @property
    def anisotropic(self) -> dict[tuple[int, int], NDArray[np.uint8]]:
        """The anisotropic levels by (kx, ky), empty unless built with ``anisotropic=True``."""
        self._open("its anisotropic levels")
        if self._source is not None:
            self._check_source()
        return self._anisotropic

    def __len__(self) -> int:
        return len(self.levels)

    # Each public method below reads ``self.levels`` once (the closed check, and the stat of a .npy path's file:
    # _check_source) and hands the list down: the helpers stat'ed it again at every step, 3 to 5 times a call (a
    # TextureTree's build and walk made ~58 000 stats on the sample DEM at leaf_size 16).

    def __enter__(self) -> ImagePyramid:
        self._open("it")
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        """Drop the level maps; delete the storage folder when the pyramid made it. Closing twice is fine."""
        self._closed = True
        self._levels = []
        self._anisotropic = {}
        if self._owned:
            self._finalizer()  # shutil.rmtree of the folder, once
            self._owned = False

    @staticmethod
    def _level(levels: list[NDArray[np.uint8]], level: Any) -> NDArray[np.uint8]:
        """The array of ``level`` in ``levels`` (``self.levels``: a closed pyramid is refused first), else an
        InvalidInputError naming it: level -1 read the last (1 x 1) level through Python's negative indexing, True
        level 1."""
        if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 0 <= level < len(levels):
            raise InvalidInputError(f"level must index the pyramid's {counted(len(levels), 'level')} (0 to "
                                    f"{len(levels) - 1}); got {level!r}")
        return levels[level]

    def shape(self, level: int) -> tuple[int, int]:
        """(rows, cols) of ``level``."""
        return self._shape(self.levels, level)

    def _shape(self, levels: list[NDArray[np.uint8]], level: Any) -> tuple[int, int]:
        shape = self._level(levels, level).shape
        return int(shape[0]), int(shape[1])

    def pixel_size(self, level: int) -> tuple[float, float]:
        """(width, height) of one pixel of ``level`` in world units."""
        return self._pixel_size(*self.shape(level))

    def _pixel_size(self, rows: int, cols: int) -> tuple[float, float]:
        xmin, xmax, ymin, ymax = self.extent
        return (xmax - xmin) / cols, (ymax - ymin) / rows

    def window(self, level: int, domain: Extent) -> tuple[int, int, int, int] | None:
        """(r0, r1, c0, c1): the smallest pixel window of ``level`` covering ``domain`` (clipped to the image; for
        a world image spanning a whole turn of longitude, placed on a DEM in degrees, the columns go on past its
        west or east edge, read from its other end), or None when the image does not overlap it."""
        return self._window_over(self.levels, level, domain)

    def _window_over(self, levels: list[NDArray[np.uint8]], level: int,
                     domain: Extent) -> tuple[int, int, int, int] | None:
        domain = _check_extent(domain, "domain")  # NaN raised math.floor's ValueError, text a TypeError
        rows, cols = self._shape(levels, level)
        px, py = self._pixel_size(rows, cols)
        xmin, xmax, ymin, ymax = self.extent
        c0 = math.floor((domain[0] - xmin) / px + 1e-9)
        c1 = math.ceil((domain[1] - xmin) / px - 1e-9)
        r0 = math.floor((ymax - domain[3]) / py + 1e-9)
        r1 = math.ceil((ymax - domain[2]) / py - 1e-9)
        if not self._wraps:
            c0, c1 = max(c0, 0), min(c1, cols)
        r0, r1 = max(r0, 0), min(r1, rows)
        if c0 >= c1 or r0 >= r1:
            return None
        return r0, r1, c0, c1

    @property
    def _wraps(self) -> bool:
        """Whether the image spans a whole turn of longitude, so its columns go on past its east edge from its west
        edge (a window may then reach past either, up to a turn: see :func:`_placed`)."""
        return bool(getattr(self, "whole_turn", False))

    def _with_margin(self, levels: list[NDArray[np.uint8]], level: int,
                     window: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
        """``window`` grown by one pixel on each side within the image (past its seam for a world image): a
        bilinear sample within half a pixel of the window's edge then takes the image's next pixel, as over the
        whole image, instead of repeating the edge pixel (adjacent crops or texture patches differed at their
        seams)."""
        r0, r1, c0, c1 = window
        rows, cols = self._shape(levels, level)
        if not self._wraps:
            c0, c1 = max(c0 - 1, 0), min(c1 + 1, cols)
        else:
            c0, c1 = c0 - 1, c1 + 1
        return max(r0 - 1, 0), min(r1 + 1, rows), c0, c1

    def _window(self, levels: list[NDArray[np.uint8]], level: int, window: Any) -> tuple[int, int, int, int]:
        """``window`` (r0, r1, c0, c1) as ints when it is a non-empty pixel window of ``level``, else an
        InvalidInputError naming it: a negative index sliced from the end, a reversed window gave an empty image, one
        past the edge a clipped image, and the extents of all three did not match their images."""
        rows, cols = self._shape(levels, level)
        if type(window) is tuple and len(window) == 4 and all(type(v) is int for v in window):
            r0, r1, c0, c1 = window  # what window() gives and a TexturePatch holds: read on every traversal
        else:
            expected = _window_expected(rows, cols, level, self._wraps)
            given = real_numbers(window, "window", expected)
            if given.shape != (4,) or not np.all(given == np.round(given)):  # NaN and inf fail too
                raise InvalidInputError(f"window must be {expected}; got {window!r}")
            r0, r1, c0, c1 = (int(v) for v in given)
        columns = (-cols <= c0 < c1 <= 2 * cols) if self._wraps else (0 <= c0 < c1 <= cols)
        if not (0 <= r0 < r1 <= rows and columns):
            raise InvalidInputError(f"window must be {_window_expected(rows, cols, level, self._wraps)}; got "
                                    f"{window!r}")
        return r0, r1, c0, c1

    def window_extent(self, level: int, window: tuple[int, int, int, int]) -> Extent:
        """World extent of a pixel window of ``level`` (as :meth:`window` gives it)."""
        levels = self.levels
        r0, r1, c0, c1 = self._window(levels, level, window)
        px, py = self._pixel_size(*self._shape(levels, level))
        xmin, _, _, ymax = self.extent
        return xmin + c0 * px, xmin + c1 * px, ymax - r1 * py, ymax - r0 * py

    def sub_image(self, level: int, window: tuple[int, int, int, int]) -> NDArray[np.uint8]:
        """A view of a pixel window of ``level`` (as :meth:`window` gives it; no copy: a memmap slice stays on disk
        until read; a copy of a world image's window past its seam, its columns read from the other end)."""
        levels = self.levels
        r0, r1, c0, c1 = self._window(levels, level, window)
        pixels = self._level(levels, level)
        if 0 <= c0 and c1 <= pixels.shape[1]:
            return pixels[r0:r1, c0:c1]
        return np.take(pixels[r0:r1], np.arange(c0, c1) % pixels.shape[1], axis=1)


def _optional_crs(crs: Any) -> str | None:
    if crs is not None and (not isinstance(crs, str) or not crs.strip()):
        raise InvalidInputError(f"crs must be a CRS string (e.g. 'EPSG:32611') or None; got {crs!r}")
    return crs


def _horizontal_crs(crs: str) -> str:
    """The horizontal part of ``crs`` as a short string (``EPSG:32611`` where it has a code): a compound CRS (UTM +
    NAVD88 height, as a DEM's GeoTIFF may carry) places an image as its horizontal CRS does. The string itself
    without rasterio or where it does not parse."""
    parsed = _crs_object(crs)
    if parsed is None:
        return crs
    try:
        wkt = parsed.to_wkt()
        if wkt.lstrip().startswith(("COMPD_CS[", "COMPOUNDCRS[")):
            block = _wkt_block(wkt, ("PROJCS", "PROJCRS", "GEOGCS", "GEOGCRS"))
            return crs if block is None else _crs_string(type(parsed).from_wkt(block)) or crs
        epsg = parsed.to_epsg()
        return crs if epsg is None else f"EPSG:{epsg}"
    except Exception:  # noqa: BLE001 - a CRS rasterio reads but cannot split or name: as given
        return crs


def _same_crs(a: str, b: str) -> bool:
    """Whether two CRS strings name the same horizontal CRS (rasterio's comparison where both parse, else the
    strings)."""
    if a.strip().upper() == b.strip().upper():
        return True
    a, b = _horizontal_crs(a), _horizontal_crs(b)
    if a.strip().upper() == b.strip().upper():
        return True
    parsed_a, parsed_b = _crs_object(a), _crs_object(b)
    return parsed_a is not None and parsed_b is not None and parsed_a == parsed_b


def _window_expected(rows: int, cols: int, level: int, wraps: bool = False) -> str:
    """What :meth:`ImagePyramid.sub_image` and :meth:`ImagePyramid.window_extent` take as a window of ``level``."""
    columns = (f"{-cols} <= c0 < c1 <= {2 * cols}, past the seam of a world image" if wraps
               else f"0 <= c0 < c1 <= {cols}")
    return f"(r0, r1, c0, c1) whole pixel indices with 0 <= r0 < r1 <= {rows} and {columns} (level {level})"


class _Reader:
    """Rows of an (H, W, C) uint8 image: copied from ``array`` (a memmap's pages dropped from the resident set after
    each band), else read with ``pread`` from the file ``path`` that this build wrote (no mapping).

    A memmap is read through its own mapping, never through its file name: the file may have been replaced since it
    was mapped (a level of a pyramid whose storage a later build reused), and a same-size replacement was read
    without a word, the levels built from another image than level 0."""

    def __init__(self, array: NDArray[np.uint8] | None, path: str | None,
                 shape: tuple[int, int, int] | None = None) -> None:
        self.array = array
        self.path = path
        self.shape = tuple(array.shape) if array is not None else shape

    def rows(self, r0: int, r1: int) -> NDArray[np.uint8]:
        _, width, channels = self.shape
        if self.path is None:
            band = self.array[r0:r1]
            if not isinstance(band, np.memmap):
                return np.ascontiguousarray(band)
            # a band-sized copy, like pread's, taken a few MiB at a time with each piece's pages dropped at once:
            # the whole band's mapped pages resident beside its copy put the peak up by a band (83 -> 119 MB)
            out = np.empty(band.shape, dtype=np.uint8)
            step = max(1, _DROP_BYTES // max(1, width * channels))
            for a in range(0, r1 - r0, step):
                piece = band[a : a + step]
                out[a : a + step] = piece
                _drop_resident(piece)
            return out
        row_bytes = width * channels
        out = np.empty((r1 - r0, width, channels), dtype=np.uint8)
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except OSError as exc:
            raise DataFileError(f"cannot read {self.path!r}: {exc.strerror}") from exc
        try:
            view = memoryview(out).cast("B")
            done, want = 0, (r1 - r0) * row_bytes
            while done < want:
                n = os.preadv(fd, [view[done:]], r0 * row_bytes + done)
                if n <= 0:
                    raise DataFileError(f"{self.path!r} is shorter than its image ({self.shape}); truncated?")
                done += n
            if hasattr(os, "posix_fadvise"):  # the pages are not needed again by this pass
                os.posix_fadvise(fd, r0 * row_bytes, want, os.POSIX_FADV_DONTNEED)
        finally:
            os.close(fd)
        return out


#: Bytes of a memmap band copied between two drops of its pages from the resident set (:meth:`_Reader.rows`).
_DROP_BYTES = 4 << 20


def _drop_resident(band: np.memmap) -> None:
    """Drop the pages under ``band`` (a C-contiguous run of a memmap) from this process's resident set
    (``madvise(MADV_DONTNEED)``; the file's data stay in the page cache), so reading a memmap band by band keeps the
    resident memory about one band. Nothing where the platform lacks it, nor for a copy-on-write map (mode "c"):
    there it would discard the caller's edits, which live in those pages only."""
    mapping = getattr(band, "_mmap", None)
    if (mapping is None or getattr(band, "mode", "c") == "c" or not band.flags.c_contiguous
            or not hasattr(mmap, "MADV_DONTNEED") or band.nbytes == 0):
        return
    try:
        start = int(band.ctypes.data) - int(np.frombuffer(mapping, dtype=np.uint8).ctypes.data)
        first = start - start % mmap.PAGESIZE
        mapping.madvise(mmap.MADV_DONTNEED, first, min(len(mapping), start + band.nbytes) - first)
    except (ValueError, OSError):  # a closed or odd mapping: the band was read, only its pages stay resident
        pass


def _reduce_file(reader: _Reader, src_shape: tuple[int, int], dst_shape: tuple[int, int], channels: int,
                 path: Path, band_bytes: int, device: wp.Device, window: tuple[int, int, int, int] | None = None,
                 src_origin: tuple[int, int] = (0, 0)) -> None:
    """Write one level: bands of target rows, each from the source rows it covers. ``window`` (r0, r1, c0, c1): only
    that window of the target level (default: all of it; the same pixels as the whole level's), from a ``reader`` of
    the source level's window from row and column ``src_origin`` on (:func:`_source_window` of ``window``)."""
    n_rows, n_cols = src_shape
    m_rows, m_cols = dst_shape
    w_r0, w_r1, w_c0, w_c1 = window or (0, m_rows, 0, m_cols)
    o_r, o_c = src_origin
    width = w_c1 - w_c0
    src_row_bytes = int(reader.shape[1]) * channels
    band = max(1, band_bytes // max(1, 2 * src_row_bytes))  # target rows per band (~2 source rows each)

    def reduced(a: int, b: int) -> NDArray[np.uint8]:  # target rows w_r0 + a .. w_r0 + b
        r0, r1 = w_r0 + a, w_r0 + b
        s0 = (r0 * n_rows) // m_rows
        s1 = min(n_rows, -((-r1 * n_rows) // m_rows))
        src = reader.rows(s0 - o_r, s1 - o_r)
        src_wp = wp.array(src, dtype=wp.uint8, device=device, copy=not device.is_cpu)
        if device.is_cpu:
            dst = np.empty((r1 - r0, width, channels), dtype=np.uint8)
            dst_wp = wp.array(dst, dtype=wp.uint8, device=device, copy=False)
        else:
            dst_wp = wp.empty((r1 - r0, width, channels), dtype=wp.uint8, device=device)
        launch(texture_kernels.reduce_band, dim=(r1 - r0) * width,
               inputs=[src_wp, s0, o_c, wp.vec2i(n_rows, n_cols), r0, w_c0, wp.vec2i(m_rows, m_cols)],
               outputs=[dst_wp], device=device)
        return dst if device.is_cpu else host_copy(dst_wp)

    _write_bands(path, w_r1 - w_r0, band, reduced)


def _source_window(window: tuple[int, int, int, int], src_shape: tuple[int, int],
                   dst_shape: tuple[int, int]) -> tuple[int, int, int, int]:
    """The window (r0, r1, c0, c1) of a level of ``src_shape`` holding every pixel the pixels of ``window`` of the
    next level (``dst_shape``) are reduced from (target pixel r covers source [r n / m, (r + 1) n / m))."""
    (r0, r1, c0, c1), (n_rows, n_cols), (m_rows, m_cols) = window, src_shape, dst_shape
    return ((r0 * n_rows) // m_rows, min(n_rows, -((-r1 * n_rows) // m_rows)),
            (c0 * n_cols) // m_cols, min(n_cols, -((-c1 * n_cols) // m_cols)))


#: The name of a level file :meth:`ImagePyramid.build` writes in its storage: level_K.u8, or level_KX_KY.u8 (rip-map).
_LEVEL_FILE = re.compile(r"level_\d+(?:_\d+)?\.u8")


class _StagedFiles:
    """The level files of one build, written under temporary names in ``folder`` (``.level_1.u8.<random>.tmp``)
    and renamed to their own names (``level_1.u8``) together by :meth:`commit`, or removed by :meth:`discard`. A
    rename failing part-way puts back the level files renamed before it (:class:`~stepterrain.export._Replacements`):
    the storage then holds the earlier pyramid's levels, where it held the new image's first levels beside the old
    one's last."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.temporary: dict[str, Path] = {}
        self.committed: dict[str, Path] = {}  # temporary path -> the level file's own path

    def path(self, name: str) -> Path:
        """The temporary path of level file ``name`` (the same one on every call)."""
        if name not in self.temporary:
            self.temporary[name] = self.folder / f".{name}.{uuid.uuid4().hex}.tmp"
        return self.temporary[name]

    def commit(self) -> None:
        from .export import _Replacements

        together = _Replacements("the pyramid level ")
        together.staged = [(temporary, self.folder / name) for name, temporary in self.temporary.items()]
        together.commit()
        for temporary, final in together.staged:
            self.committed[os.path.abspath(temporary)] = final

    def reopen(self, level: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """``level`` mapped from its own name when it was a staged file (the source itself is kept as it is)."""
        filename = getattr(level, "filename", None)
        final = self.committed.get(os.path.abspath(filename)) if filename else None
        if final is None:
            return level
        return np.memmap(final, dtype=np.uint8, mode="r", shape=level.shape)

    def remove_stale(self, keep: Sequence[str | None] = ()) -> None:
        """Remove the level files (``level_K.u8``, ``level_KX_KY.u8``) in the folder that this build did not write
        (after :meth:`commit`): an earlier pyramid's there, of a larger image or with anisotropic levels, stayed
        beside this one's under the same names (level_0.u8 of another image beside this one's levels 1+). A file
        in ``keep`` (the file this pyramid's level 0 maps) stays; an earlier pyramid still open keeps its maps of
        the files removed (POSIX); one that cannot be removed (mapped on Windows) is left."""
        kept = {os.path.realpath(path) for path in keep if path}
        written = set(self.temporary)
        try:
            names = os.listdir(self.folder)
        except OSError:
            return
        for name in names:
            if name in written or not _LEVEL_FILE.fullmatch(name):
                continue
            path = self.folder / name
            if os.path.realpath(path) in kept:
                continue
            with contextlib.suppress(OSError):
                os.unlink(path)

    def discard(self) -> None:
        for temporary in self.temporary.values():
            if os.path.abspath(temporary) not in self.committed:
                with contextlib.suppress(OSError):
                    os.unlink(temporary)


def _anisotropic_levels(levels: list[NDArray[np.uint8]], shapes: list[tuple[int, int]], channels: int,
                        staged: _StagedFiles, band_bytes: int,
                        device: wp.Device) -> dict[tuple[int, int], NDArray[np.uint8]]:
    """Rip-map levels (kx, ky), kx != ky: from level (min, min) halve only the longer-reduced axis."""
    out: dict[tuple[int, int], NDArray[np.uint8]] = {}
    for k in range(len(shapes)):
        out[(k, k)] = levels[k]
    heights = [s[0] for s in shapes]
    widths = [s[1] for s in shapes]
    n = len(shapes)
    for ky in range(n):
        for kx in range(n):  # a few dozen levels at most, never pixels
            if kx == ky:
                continue
            if kx > ky:
                parent, src_shape = (kx - 1, ky), (heights[ky], widths[kx - 1])
            else:
                parent, src_shape = (kx, ky - 1), (heights[ky - 1], widths[kx])
            dst_shape = (heights[ky], widths[kx])
            path = staged.path(f"level_{kx}_{ky}.u8")
            reader = _Reader(out[parent], None)  # level 0 or a staged level, through its mapping
            _reduce_file(reader, src_shape, dst_shape, channels, path, band_bytes, device)
            out[(kx, ky)] = np.memmap(path, dtype=np.uint8, mode="r", shape=(*dst_shape, channels))
    return out


# ---------------------------------------------------------------------------------------------- geometry tree
@dataclass(eq=False)
class GeometryPatch:
    """A node N of the geometry multiresolution model H(G) (§3.1): grid nodes rows[0]..rows[1] x
    cols[0]..cols[1] (inclusive), approximated by every ``stride``-th node; ``error`` e(N) is the largest
    vertical distance between the terrain and that approximation (the triangles :func:`paint_with_textures` draws;
    where a nodata node leaves terrain with data undrawn, or a void is drawn over, at least the coarse cell's
    diagonal); ``box`` B(N) =
    (min xyz, max xyz); ``seam_errors`` s(N) per side (first row, last row, first column, last column): the
    largest vertical distance :func:`paint_with_textures` moves that border's nodes by when a patch one level coarser
    is drawn across it (the drawn mesh then lies within e(N) + that of the terrain)."""

    domain: Extent
    rows: tuple[int, int]
    cols: tuple[int, int]
    depth: int
    stride: int
    error: float
    box: NDArray[np.float64]
    parent: GeometryPatch | None = None
    children: list[GeometryPatch] = field(default_factory=list)
    heights: NDArray[Any] | None = field(default=None, repr=False)  # the terrain's, for seam_errors

    @property
    def is_leaf(self) -> bool:
        return not self.children

    @property
    def seam_errors(self) -> tuple[float, ...]:
        """s(N) per side (see the class), measured on first use (only stitched patches need it)."""
        return tuple(self._seam_error(side) for side in range(4))

    def _seam_error(self, side: int) -> float:
        """s(N) of one side, measured on first use: :func:`render_with_textures` needs only a stitched side's."""
        found = self.__dict__.setdefault("_seam_errors", [None] * 4)
        if found[side] is None:
            parent = self.parent
            found[side] = 0.0 if parent is None or self.heights is None else _seam_error(
                self.heights, self, side, parent.cols if side < 2 else parent.rows, parent.stride)
        return found[side]


class PatchQuadtree:
    """The terrain's patch quadtree: the root covers the grid, each patch splits in four until a patch has at
    most ``leaf_size`` cells per side. A patch at depth d takes every 2^(D − d)-th node (D = the leaves' depth),
    so leaves are at full resolution (e = 0)."""

    def __init__(self, terrain: Terrain | ArrayLike, *, leaf_size: int = 64, spacing: ArrayLike | None = None,
                 origin: ArrayLike | None = None) -> None:
        t = as_terrain(terrain, spacing=spacing, origin=origin)
        if t.kind != "grid":
            raise InvalidInputError("PatchQuadtree needs a regular heightfield")
        if isinstance(leaf_size, bool) or not isinstance(leaf_size, (int, np.integer)) or leaf_size < 2:
            raise InvalidInputError(f"leaf_size must be an int >= 2; got {plain_repr(leaf_size)}")
        leaf_size = int(leaf_size)  # a NumPy integer too (as a level, a lens' resolution): refused before
        self.terrain = t
        rows, cols = t.heights.shape
        cells = max(rows, cols) - 1
        self.depth = max(0, math.ceil(math.log2(max(cells, 1) / leaf_size))) if cells > leaf_size else 0
        self.root = self._build(None, (0, rows - 1), (0, cols - 1), 0)
        self._measure(self.patches())

    def _measure(self, patches: list[GeometryPatch]) -> None:
        """Sets each patch's e(N): the patches of one shape, stride and sample pattern (their corner modulo the
        stride) measured together (:func:`_approximation_errors`)."""
        heights = self.terrain.heights
        groups: dict[tuple[int, int, int, int, int], list[GeometryPatch]] = {}
        for patch in patches:
            if patch.stride > 1:  # leaves: full resolution, e = 0
                (top, bottom), (left, right), stride = patch.rows, patch.cols, patch.stride
                # where the sample lines (_samples: the grid's multiples of the stride) fall: the corner modulo stride
                key = (bottom - top + 1, right - left + 1, stride, top % stride, left % stride)
                groups.setdefault(key, []).append(patch)
        for (rows, cols, stride, row_phase, col_phase), group in groups.items():
            r0 = np.array([p.rows[0] for p in group])[:, None, None] + np.arange(rows)[None, :, None]
            c0 = np.array([p.cols[0] for p in group])[:, None, None] + np.arange(cols)[None, None, :]
            for at in range(0, len(group), band := max(1, _ERROR_PASS_NODES // (rows * cols))):
                z = np.asarray(heights[r0[at: at + band], c0[at: at + band]], dtype=np.float64)
                for patch, error in zip(group[at: at + band], _approximation_errors(
                        z, stride, self.terrain.spacing, (row_phase, col_phase)), strict=True):
                    patch.error = float(error)

    def _domain(self, rows: tuple[int, int], cols: tuple[int, int]) -> Extent:
        t = self.terrain
        x = [t.origin[0] + c * t.spacing[0] for c in cols]
        y = [t.origin[1] + r * t.spacing[1] for r in rows]
        return min(x), max(x), min(y), max(y)

    def _build(self, parent: GeometryPatch | None, rows: tuple[int, int], cols: tuple[int, int],
               depth: int) -> GeometryPatch:
        t = self.terrain
        block = t.heights[rows[0]: rows[1] + 1, cols[0]: cols[1] + 1]
        finite = block[np.isfinite(block)]
        zmin, zmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
        stride = 2 ** (self.depth - depth)
        domain = self._domain(rows, cols)
        box = np.array([[domain[0], domain[2], zmin], [domain[1], domain[3], zmax]])
        # error: set by _measure; heights: a neighbour one level coarser spans the parent's rows or columns at its
        # stride (seam_errors)
        patch = GeometryPatch(domain, rows, cols, depth, stride, 0.0, box, parent, heights=t.heights)
        if depth < self.depth and (rows[1] - rows[0] > 1 or cols[1] - cols[0] > 1):
            rm = (rows[0] + rows[1]) // 2
            cm = (cols[0] + cols[1]) // 2
            row_parts = [(rows[0], rm), (rm, rows[1])] if rows[1] - rows[0] > 1 else [rows]
            col_parts = [(cols[0], cm), (cm, cols[1])] if cols[1] - cols[0] > 1 else [cols]
            patch.children = [self._build(patch, r, c, depth + 1) for r in row_parts for c in col_parts]
        return patch

    def patches(self) -> list[GeometryPatch]:
        """Every patch, parents before children."""
        out, stack = [], [self.root]
        while stack:
            patch = stack.pop()
            out.append(patch)
            stack.extend(reversed(patch.children))
        return out


def _samples(first: int, last: int, stride: int) -> NDArray[np.intp]:
    """The grid lines (rows or columns) a patch over ``first``..``last`` draws at ``stride``: the multiples of the
    stride within it (counted from the grid's first line, not the patch's) and its two ends. A patch's lines are then
    a subset of every finer patch's along a common border (a coarse stride is a multiple of a fine one), so
    :func:`paint_with_textures` can stitch the finer one onto the coarser one's edges; counted from the patch's own
    first line, a DEM whose size is no power of two plus one left them apart (a child starts at its parent's middle
    line, no multiple of its stride). Relative to ``first``, they depend on ``first % stride`` and the span alone."""
    start = -(-first // stride) * stride
    inner = np.arange(start, last + 1, stride, dtype=np.intp)
    head = [first] if first < start else []  # (np.unique of the three: 3 times slower, called per patch and side)
    tail = [last] if (int(inner[-1]) if len(inner) else first) < last else []
    return np.concatenate([np.array(head, np.intp), inner, np.array(tail, np.intp)]) if head or tail else inner


def _approximation_error(block: NDArray[np.float32], stride: int, spacing: tuple[float, float] = (1.0, 1.0),
                         corner: tuple[int, int] = (0, 0)) -> float:
    """e(N) of one patch, ``corner`` the grid node of its block's first row and column: :func:`_approximation_errors`
    of a stack of one block."""
    return float(_approximation_errors(np.asarray(block, dtype=np.float64)[None], stride, spacing, corner)[0])


#: Nodes of one pass of :func:`_approximation_errors` (a stack of patches of one shape) in
#: :meth:`PatchQuadtree._measure`: each float64 temporary of the pass holds at most this many values (16 MiB) unless
#: one patch is larger, so a level of a large DEM is measured a band of patches at a time.
_ERROR_PASS_NODES = 1 << 21


def _approximation_errors(z: NDArray[np.float64], stride: int, spacing: tuple[float, float] = (1.0, 1.0),
                          corner: tuple[int, int] = (0, 0)) -> NDArray[np.float64]:
    """e(N) of each of n patches of one shape and sample pattern, z their heights (n, rows, cols) in float64: max
    |h − G(N)| over the block's nodes with data and where a narrow coarse cell's diagonal crosses the terrain's edges
    (:func:`_diagonal_gaps`), h the terrain's mesh and G(N) the mesh :func:`paint_with_textures` draws (the block's
    rows and columns of :func:`_samples`, ``corner`` the grid node of a block's first row and column, the same for
    every block modulo ``stride``; two triangles a cell split along (r, c)-(r+1, c+1) as
    :func:`~stepterrain.terrain.grid_faces`; a triangle with a nodata corner is not drawn): the largest vertical
    distance between the two surfaces, which lies at one of those points.

    A node with data that no drawn triangle covers (the approximation's hole around a nodata node is wider than the
    terrain's) counts as the coarse cell's diagonal, stride × hypot(dx, dy) in world units: γ(N) then refines the
    patch once that hole spans more than γ_user pixels on screen (its vertical distance is undefined). So does a
    nodata node that a drawn triangle covers (a void inside coarse cells whose corners have data, drawn over as
    ground): it counted 0, and a flat DEM with a lake of nodata drew its root, the lake covered, from any distance.

    The patches of one shape and sample pattern share their coarse nodes, cells and crossings, so they are measured
    together: the same elementwise arithmetic as one patch at a time, with a leading axis (measuring each patch apart
    cost the sample DEM's leaf_size 8 build ~3 s of its 7)."""
    n, rows, cols = z.shape
    if stride <= 1 or n == 0:
        return np.zeros(n)
    ri = _samples(corner[0], corner[0] + rows - 1, stride) - corner[0]
    ci = _samples(corner[1], corner[1] + cols - 1, stride) - corner[1]
    if len(ri) == 1 or len(ci) == 1:  # one coarse row or column: its mean per patch (a sum: kept one patch at a time)
        return np.array([float(np.nanmax(np.abs(zi - np.nanmean(zi[np.ix_(ri, ci)])))) if np.isfinite(zi).any()
                         else 0.0 for zi in z])
    coarse = np.take(np.take(z, ri, axis=1), ci, axis=2)
    voidless = np.isfinite(coarse).all(axis=(1, 2))
    hole = ~np.isfinite(z).all(axis=(1, 2))  # terrain with data left undrawn, or a void drawn over
    if voidless.all():  # every triangle drawn: a nodata node is a void inside the coarse cells, drawn over
        error = _node_errors_voidless(z, coarse, ri, ci)
    else:
        error = np.zeros(n)
        if voidless.any():
            error[voidless] = _node_errors_voidless(z[voidless], coarse[voidless], ri, ci)
        error[~voidless], hole[~voidless] = _node_errors(z[~voidless], coarse[~voidless], ri, ci)
    error = np.maximum(error, _diagonal_gaps(z, ri, ci))
    return np.where(hole, np.maximum(error, stride * math.hypot(*spacing)), error)


def _largest_finite(values: NDArray[np.float64], axes: tuple[int, ...]) -> NDArray[np.float64]:
    """Per patch (the leading axis), the largest of ``values`` over ``axes`` ignoring NaN (+inf counts), or 0 where
    none is finite: ``float(np.nanmax(v)) if np.isfinite(v).any() else 0.0`` of each patch at once."""
    top = np.where(np.isnan(values), -np.inf, values).max(axis=axes)
    return np.where(np.isfinite(values).any(axis=axes), top, 0.0)


def _cells(index: NDArray[np.intp], at: NDArray[np.intp], side: Any) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Each node's coarse cell along one axis (the one on ``side`` for a node on a coarse line), and its fraction across
    that cell."""
    k = np.clip(np.searchsorted(index, at, side=side) - 1, 0, len(index) - 2)
    return k, (at - index[k]) / (index[k + 1] - index[k])


def _planes(coarse: NDArray[np.float64], k: NDArray[np.intp], m: NDArray[np.intp], fr: NDArray[np.float64],
            fc: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The heights of the cell's two triangles at each node of each patch: (n00, n01, n11), drawn where fc >= fr, and
    (n00, n11, n10), drawn where fc <= fr (NaN where a corner is nodata)."""
    flat, at = coarse.reshape(len(coarse), -1), k[:, None] * coarse.shape[2] + m  # np.take: ~3x a 3-d fancy index
    a, b = np.take(flat, at, axis=1), np.take(flat, at + 1, axis=1)
    cc, d = np.take(flat, at + coarse.shape[2], axis=1), np.take(flat, at + coarse.shape[2] + 1, axis=1)
    return a + (b - a) * fc + (d - b) * fr, a + (cc - a) * fr + (d - cc) * fc


def _node_errors_voidless(z: NDArray[np.float64], coarse: NDArray[np.float64], ri: NDArray[np.intp],
                          ci: NDArray[np.intp]) -> NDArray[np.float64]:
    """max |h − G(N)| over each patch's nodes with data where its coarse nodes all have data (every triangle drawn: a
    node's own cell covers it)."""
    (k, fr), (m, fc) = _cells(ri, np.arange(z.shape[1]), "right"), _cells(ci, np.arange(z.shape[2]), "right")
    fr, fc = fr[:, None], fc[None, :]
    upper, lower = _planes(coarse, k, m, fr, fc)
    return _largest_finite(np.abs(z - np.where(fc >= fr, upper, lower)), (1, 2))


def _node_errors(z: NDArray[np.float64], coarse: NDArray[np.float64], ri: NDArray[np.intp],
                 ci: NDArray[np.intp]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """max |h − G(N)| over each patch's nodes with data that a drawn triangle covers (0 where none), and whether
    the patch has a node with data that none covers or a nodata node that one does."""
    worst = np.zeros(z.shape)
    covered = np.zeros(z.shape, dtype=bool)
    r, c = np.arange(z.shape[1]), np.arange(z.shape[2])
    # a node on a coarse row or column lies in the cells on both sides of it: where one side's triangle is not drawn
    # (a nodata corner), the other may cover it, so both sides are tried
    for side_r in ("left", "right"):
        k, fr = _cells(ri, r, side_r)
        fr = fr[:, None]
        for side_c in ("left", "right"):
            m, fc = _cells(ci, c, side_c)
            fc = fc[None, :]
            upper, lower = _planes(coarse, k, m, fr, fc)
            for inside, value in ((fc >= fr, upper), (fc <= fr, lower)):
                drawn = inside & np.isfinite(value)  # NaN where a corner is nodata
                with np.errstate(invalid="ignore"):
                    np.fmax(worst, np.where(drawn, np.abs(z - value), 0.0), out=worst)
                covered |= drawn
    data = np.isfinite(z)
    seen = data & covered
    error = np.where(seen.any(axis=(1, 2)), np.where(seen, worst, -np.inf).max(axis=(1, 2)), 0.0)
    return error, (data != covered).any(axis=(1, 2))


def _diagonal_gaps(z: NDArray[np.float64], ri: NDArray[np.intp], ci: NDArray[np.intp]) -> NDArray[np.float64]:
    """max |h − G(N)| of each patch (z: n, rows, cols) where the diagonal of a coarse cell that is not square crosses
    the terrain's edges, for :func:`_approximation_errors` (0 where every coarse cell is square).

    The two meshes differ linearly on each piece of their overlay, so the largest difference lies at a node or where a
    coarse edge crosses a terrain edge. A coarse cell's sides run along the terrain's rows and columns, and a square
    one's diagonal along the terrain's diagonals through its nodes; but the first and last rows and columns of coarse
    cells are narrower than the stride where the patch's ends are no multiples of it (:func:`_samples`), and their
    diagonals cross the terrain's rows, columns and diagonals between nodes, where the surfaces may lie farther apart
    than at any node (Big Tujunga, leaf_size 8: 820 of 21845 patches' e(N) fell short, by up to 7 m of 25.5). A crossing
    whose terrain triangle has a nodata corner, or whose coarse diagonal is not drawn (a nodata end, or both its cell's
    triangles not drawn), is skipped (the node rules of :func:`_approximation_errors` count those)."""
    heights, widths = np.diff(ri), np.diff(ci)
    worst = np.zeros(len(z))
    flat = z.reshape(len(z), -1)

    def nodes(i: NDArray[np.intp], j: NDArray[np.intp]) -> NDArray[np.float64]:
        """z[:, i, j] (np.take: ~3x a 3-d fancy index)."""
        return np.take(flat, i * z.shape[2] + j, axis=1)

    for h in np.unique(heights):
        for w in np.unique(widths):
            if h == w:
                continue
            # the diagonal (r, c) = t · (h, w) crosses the terrain's rows at t = i / h, its columns at j / w and its
            # diagonals at k / |w − h|
            skew = abs(int(w) - int(h))
            t = np.unique(np.concatenate([np.arange(1, h) / h, np.arange(1, w) / w, np.arange(1, skew) / skew]))
            if not len(t):
                continue
            k, m = np.nonzero(heights == h)[0], np.nonzero(widths == w)[0]
            r = ri[k][:, None, None] + t * h  # (cells' rows, cells' columns, crossings), after the patch axis
            c = ci[m][None, :, None] + t * w
            i0 = np.clip(np.floor(r).astype(np.intp), 0, z.shape[1] - 2)
            j0 = np.clip(np.floor(c).astype(np.intp), 0, z.shape[2] - 2)
            fr, fc = r - i0, c - j0
            a, b, cc, d = nodes(i0, j0), nodes(i0, j0 + 1), nodes(i0 + 1, j0), nodes(i0 + 1, j0 + 1)
            terrain = np.where(fc >= fr, a + (b - a) * fc + (d - b) * fr, a + (cc - a) * fr + (d - cc) * fc)
            start = nodes(ri[k][:, None], ci[m][None, :])[..., None]
            end = nodes(ri[k][:, None] + h, ci[m][None, :] + w)[..., None]
            gap = np.abs(terrain - (start + (end - start) * t))
            # the diagonal is drawn where one of its cell's two triangles is: both other corners nodata, it is not
            drawn = np.isfinite(nodes(ri[k][:, None], ci[m][None, :] + w)) | np.isfinite(nodes(ri[k][:, None] + h,
                                                                                             ci[m][None, :]))
            gap = np.where(drawn[..., None], gap, np.nan)
            worst = np.maximum(worst, _largest_finite(gap, (1, 2, 3)))
    return worst


# ---------------------------------------------------------------------------------------------- texture tree
@dataclass(eq=False)
class TexturePatch:
    """A node M of a texture tree (§3.2.2): the pyramid ``level`` and the pixel ``window`` (r0, r1, c0, c1) of
    that level covering its geometry patch (or the part of it the image covers) and one pixel beyond it on each side
    within the image (columns past a world image's seam: see :class:`TextureTree`). Holds no image data."""

    tree: TextureTree
    geometry: GeometryPatch
    level: int
    window: tuple[int, int, int, int]
    parent: TexturePatch | None = None
    children: dict[int, TexturePatch] = field(default_factory=dict)  # by id of the child geometry patch

    @property
    def domain(self) -> Extent:
        """D(M): world extent of the window."""
        return self.tree.pyramid.window_extent(self.level, self.window)

    @property
    def texel_size(self) -> tuple[float, float]:
        """(w, h): one texel of M in world units."""
        return self.tree.pyramid.pixel_size(self.level)

    @property
    def full_resolution(self) -> bool:
        return self.level == 0

    @property
    def is_leaf(self) -> bool:
        return not self.children

    @property
    def nbytes(self) -> int:
        r0, r1, c0, c1 = self.window
        return (r1 - r0) * (c1 - c0) * int(self.tree.pyramid.levels[self.level].shape[2])

    def image(self) -> NDArray[np.uint8]:
        """The sub-image, a view into the pyramid level (no copy; a copy for a window past a world image's seam)."""
        return self.tree.pyramid.sub_image(self.level, self.window)

    def child_for(self, geometry: GeometryPatch) -> TexturePatch | None:
        """The texture patch for child geometry patch ``geometry``: M's child, M itself when M is pruned at full
        resolution (its texture already covers the child at the best resolution), None where the texture does
        not reach the child (partial coverage)."""
        child = self.children.get(id(geometry))
        if child is not None:
            return child
        if self.full_resolution and _overlap(self.domain, geometry.domain):
            return self
        return None


def _overlap(a: Extent, b: Extent) -> bool:
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


class _PlacedPyramid(ImagePyramid):
    """A pyramid's levels over another ``extent`` in another ``crs`` (:func:`_placed`): no copy, and the levels are
    read through the pyramid itself, so closing it closes this view too (closing the view closes only the view).
    ``whole_turn``: the image spans 360 degrees of longitude, so its east edge meets its west edge."""

    def __init__(self, source: ImagePyramid, extent: Extent, crs: str | None, whole_turn: bool = False) -> None:
        self.source = source
        self.extent = _check_extent(extent)
        self.crs = crs
        self.whole_turn = whole_turn
        self.storage = source.storage
        self._owned = False
        self._closed = False

    @property
    def levels(self) -> list[NDArray[np.uint8]]:
        self._open("its levels")
        return self.source.levels

    @property
    def anisotropic(self) -> dict[tuple[int, int], NDArray[np.uint8]]:
        self._open("its anisotropic levels")
        return self.source.anisotropic


def _placed(pyramid: ImagePyramid, terrain: Terrain) -> ImagePyramid:
    """The pyramid in the terrain's coordinates: itself when their CRSs agree or one is unknown; a view of it over
    its extent in the local equirectangular metres of a DEM that load_dem read from degrees (the terrain's ``crs`` a
    spherical ``+proj=eqc``) when the image is in a geographic CRS of the same body (an orthophoto in EPSG:4326 on an
    SRTM tile in EPSG:4326: those metres are linear in longitude and latitude, so the extent maps exactly; the
    image's grads or prime meridian are read as load_dem reads the DEM's, and its longitudes are taken by whole
    turns nearest the terrain, so an image in 0..360 places on a DEM at -105); else an InvalidInputError naming
    both CRSs: the extents were compared as numbers, so a Blue Marble in degrees (-180..180) over the metres of a
    DEM in UTM (or of another body) draped it anywhere without a word."""
    if pyramid.crs is None or terrain.crs is None or _same_crs(pyramid.crs, terrain.crs):
        return pyramid
    image_crs, terrain_crs = _horizontal_crs(pyramid.crs), _horizontal_crs(terrain.crs)
    hint = f"reproject the image to the terrain's CRS first (`gdalwarp -dstalpha -t_srs '{terrain_crs}' ...`)"
    local = _spherical_eqc(terrain.crs)
    if local is not None and _is_geographic(image_crs):
        radius, x_radius, _, lon_0, x_0, _ = local
        body = _geographic_body(image_crs)
        if body.east < 0:  # column 0 at xmin, the smallest west longitude: the image would run east to west
            raise InvalidInputError(
                f"the image is in CRS {image_crs!r}, whose longitude axis increases westwards, so its extent "
                f"{pyramid.extent} (column 0 at xmin) runs east to west; give the image north-up and east-right "
                "in a CRS whose longitudes increase eastwards (e.g. `gdalwarp -dstalpha -t_srs EPSG:4326`)")
        if abs(body.radius / radius - 1.0) <= 0.01:  # the same body (the earth: any earth ellipsoid, as load_dem)
            xmin, xmax, ymin, ymax = pyramid.extent
            lons = [body.meridian + v * body.degrees for v in (xmin, xmax)]
            centre = lon_0 + math.degrees((0.5 * (terrain.extent[0] + terrain.extent[1]) - x_0) / x_radius)
            turns = 360.0 * round((centre - 0.5 * (lons[0] + lons[1])) / 360.0)
            found = lonlat_as_local_metres(terrain.crs, [v + turns for v in lons],
                                           [v * body.degrees for v in (ymin, ymax)])
            if found is not None:
                (x0, x1), (y0, y1) = found
                whole_turn = abs(abs(lons[1] - lons[0]) - 360.0) <= 1e-9 * 360.0  # a global image: it wraps
                return _PlacedPyramid(pyramid, (x0, x1, y0, y1), terrain.crs, whole_turn)
        hint = (f"the terrain is a DEM in degrees of a body of radius {radius:.10g} m read as local metres, but the "
                f"image's CRS is of a body of radius {body.radius:.10g} m")
    raise InvalidInputError(f"the image is in CRS {image_crs!r} but the terrain is in {terrain_crs!r} (mismatched "
                            f"CRS: the extent {pyramid.extent} is not in the terrain's coordinates); {hint}")


class TextureTree:
    """The texture tree of one layer over a :class:`PatchQuadtree` (§3.2.2 and §4, partial textures).

    Each texture patch names the finest pyramid level whose window over its geometry patch fits
    ``max_texture_size`` per side, and takes one pixel more on each side of it (within the image; a border, as
    OpenGL's, not counted in that size: a patch's texture is up to ``max_texture_size`` + 2 per side), so a texel
    near the patch's edge interpolates as over the whole level and adjacent patches at one level agree along their
    seam (the UVs map the window's extent, :attr:`TexturePatch.domain`, so a texel's centre stays on its world
    position). Subtrees are pruned below patches already at full resolution (level 0); geometry patches the image
    does not overlap get no texture patch. ``tree.pyramid`` is the pyramid, or for an image in degrees on a DEM read
    from degrees into local metres a view of it over its extent in those metres (the same levels, read through the
    pyramid: closing it closes the view); a world image in degrees (360 degrees of longitude) goes on past its seam
    there, so a DEM across the antimeridian is textured on both sides (the window
    of a patch across the seam, :meth:`TexturePatch.image`, is then a copy).
    """

    def __init__(self, pyramid: ImagePyramid, quadtree: PatchQuadtree, *, max_texture_size: int = 1024) -> None:
        if not isinstance(pyramid, ImagePyramid):
            raise InvalidInputError(f"pyramid must be an ImagePyramid; got {type(pyramid).__name__}")
        if not isinstance(quadtree, PatchQuadtree):
            raise InvalidInputError(f"quadtree must be a PatchQuadtree; got {type(quadtree).__name__}")
        if (isinstance(max_texture_size, bool) or not isinstance(max_texture_size, (int, np.integer))
                or max_texture_size < 1):
            raise InvalidInputError(f"max_texture_size must be a positive int; got {plain_repr(max_texture_size)}")
        max_texture_size = int(max_texture_size)  # a NumPy integer too (as a level, a lens' resolution): refused before
        pyramid = _placed(pyramid, quadtree.terrain)
        self.pyramid = pyramid
        self.quadtree = quadtree
        self.max_texture_size = max_texture_size
        self.root = self._build(quadtree.root, None, pyramid.levels)  # checked once (ImagePyramid.levels)
        if self.root is None:
            raise InvalidInputError(f"the image extent {pyramid.extent} does not overlap the terrain's "
                                    f"{quadtree.root.domain} (mismatched extent)")

    def _build(self, geometry: GeometryPatch, parent: TexturePatch | None,
               levels: list[NDArray[np.uint8]]) -> TexturePatch | None:
        choice = None
        for level in range(len(levels)):
            window = self.pyramid._window_over(levels, level, geometry.domain)
            if window is None:
                return None
            r0, r1, c0, c1 = window
            if r1 - r0 <= self.max_texture_size and c1 - c0 <= self.max_texture_size:
                # a pixel more on each side (OpenGL's texture border, §4: not counted in the size), as image_layer's:
                # the patch's texels within half a pixel of its edge were sampled from its edge pixel repeated, so
                # adjacent patches at one level differed at their seam
                choice = (level, self.pyramid._with_margin(levels, level, window))
                break
        if choice is None:  # pragma: no cover - the 1 x 1 level always fits
            return None
        patch = TexturePatch(self, geometry, choice[0], choice[1], parent)
        if choice[0] > 0:
            for child in geometry.children:
                sub = self._build(child, patch, levels)
                if sub is not None:
                    patch.children[id(child)] = sub
        return patch

    def patches(self) -> list[TexturePatch]:
        out, stack = [], [self.root]
        while stack:
            patch = stack.pop()
            out.append(patch)
            stack.extend(patch.children.values())
        return out


def _world_file_hint(path: Path) -> str:
    """How to georeference the image file ``path`` beside it, for a refusal of one without georeferencing: GDAL's
    world file name for it (the extension's first and last letters and "w": ortho.jgw for ortho.jpg or .jpeg,
    .pgw for a PNG, .tfw for a TIFF; .wld without an extension) and the .prj that names its CRS."""
    world = world_file_names(path)[0].name
    return f"put a world file {world!r} beside it, with its CRS in {path.with_suffix('.prj').name!r}"


def is_georeferenced(image: str | os.PathLike[str]) -> bool:
    """Whether the image file ``image`` places itself: a GeoTIFF, or a JPEG or PNG with a world file (``.jgw``,
    ``.pgw``, ``.wld``) or ``.aux.xml`` beside it, whose geotransform (read with rasterio) is not the identity, as
    :meth:`ImagePyramid.build` reads its extent from it. False for a PNG or JPEG without one, a plain TIFF, or
    without rasterio. A path that is no file (missing, a folder) raises a :class:`DataFileError`, as
    :meth:`ImagePyramid.build` does (it answered False: "not georeferenced" of a mistyped name), and a value that is
    no path an :class:`InvalidInputError` (Path()'s TypeError)."""
    if not isinstance(image, (str, os.PathLike)):
        raise InvalidInputError(f"image must be the path of an image file; got {type(image).__name__}")
    path = Path(image)
    if path.is_dir():
        raise DataFileError(f"image file {str(image)!r} is a folder; expected an image file")
    if not path.is_file():
        raise DataFileError(f"image file {str(image)!r} does not exist")
    return bool(_read_tiff(path, lambda dataset: not dataset.transform.is_identity, any_format=True))


class _WindowedTiff:
    """A TIFF of 8-bit bands (or a PNG) that :func:`image_layer` reads window by window with rasterio, as
    :meth:`ImagePyramid.build` reads it whole (and :meth:`ImagePyramid.build` a band of rows at a time into level 0:
    :meth:`rows`): its shape (H, W, C), its georeferencing, and :meth:`read`, the pixels of
    one window of one pyramid level, equal to the built pyramid's. Only the image's window over the terrain is
    decoded, a band of rows at a time, and reduced to the level through files of that window: the whole image was
    decoded (its bytes in memory, refused past the memory budget, 3.1 GB peak for a 20000 x 20000 orthophoto under a
    1197 x 643 node DEM) and every level of it built, to keep one window of one level.

    :meth:`open` takes only a file whose pixels the whole read takes with rasterio alike: one Pillow cannot read
    (those :func:`_raster_uint8` reads), or one Pillow reads as L, RGB or RGBA from 1, 3 or 4 bands (the fourth
    alpha), without a transparent colour nor JPEG compression (Pillow decodes its YCbCr otherwise than GDAL), neither
    min-is-white nor of 1-7 bit samples (Pillow inverts or scales them, GDAL gives them as stored); else None (16
    bits, a JPEG-compressed TIFF Pillow reads, ...: :meth:`ImagePyramid.build`, which decodes it whole).
    A 3-band image with a GDAL mask (nodata, a mask band) always gets its alpha (255 where valid): the whole read gave
    none where no pixel of the whole image is masked, which only the whole image tells."""

    def __init__(self, path: Path, dataset: Any, bands: list[int], masked: bool, georeferencing: Any) -> None:
        self.path = path
        self.dataset = dataset
        self.bands = bands  # the file's bands (0-based) as the image's channels, before the mask's alpha
        self.masked = masked
        self.georeferencing = georeferencing
        self.shape = (int(dataset.height), int(dataset.width), len(bands) + int(masked))
        self.block_rows = 1  # rows of one block (tile or strip) of the file, or 1 where GDAL does not say
        with contextlib.suppress(Exception):
            self.block_rows = max(1, int(dataset.block_shapes[0][0]))

    @classmethod
    def open(cls, image: Any, stack: contextlib.ExitStack,
             opened: dict[str, Any] | None = None) -> _WindowedTiff | None:
        """The image file ``image`` opened in ``stack`` when it is such a TIFF (or a PNG that Pillow
        reads as L, RGB or RGBA, not interlaced, without a GDAL mask: GDAL decodes it row by row to the same bytes),
        else None (nothing is refused here: :meth:`ImagePyramid.build` reads it, refusing what it refuses; the
        rasterio dataset it opened, open until ``stack`` closes, as ``opened["dataset"]``)."""
        if not isinstance(image, (str, os.PathLike)):
            return None
        path = Path(image)
        suffix = path.suffix.lower()
        if suffix not in (".tif", ".tiff", ".png") or not path.is_file():
            return None
        try:
            import rasterio  # noqa: F401 - only whether it is there
        except ImportError:
            return None
        try:
            dataset = stack.enter_context(open_raster(path))
            if opened is not None:
                opened["dataset"] = dataset
            count, types, (bands, alphas) = dataset.count, set(dataset.dtypes), _image_bands(dataset)
            jpeg = str(getattr(dataset.compression, "name", dataset.compression)).lower() in ("jpeg", "ojpeg")
            masked = not _all_valid(dataset)
            structure = {**dataset.tags(ns="IMAGE_STRUCTURE"), **dataset.tags(1, ns="IMAGE_STRUCTURE")}
        except Exception:  # noqa: BLE001 - GDAL cannot read it: ImagePyramid.build says what is wrong
            return None
        if types != {"uint8"} or not 1 <= count <= 4:
            return None
        if structure.get("MINISWHITE") == "YES" or structure.get("NBITS", "8") != "8":
            # GDAL gives the stored values: Pillow inverts a min-is-white grey (0 is white) and scales 1-7 bit
            # samples to 0-255 (a 4-bit 15 is 255), so the windows were the negative, or nearly black
            return None
        found = _pillow_mode(path)
        if found is None and suffix == ".png":  # past Pillow's decompression-bomb limit: refused as the whole read
            return None
        if suffix == ".png" and ((masked and len(bands) == 3) or found[2]):  # a mask (an .aux.xml's nodata) rereads
            return None  # rows; Adam7 passes are decoded whole by GDAL for each chunk of rows
        if found is not None:  # Pillow reads it (the whole read's pixels): only where rasterio's are the same
            mode, transparent = found[0], found[1]
            if jpeg or transparent or mode not in ("L", "RGB", "RGBA"):
                return None  # JPEG tiles: Pillow's YCbCr decoding and GDAL's differ (up to 21 levels)
            if mode != {1: "L", 3: "RGB", 4: "RGBA"}.get(count) or (count == 4) != bool(alphas):
                return None
        if found is not None:  # warned here, as the whole read warns (a file left to it is warned of there, once)
            found[3]()
        return cls(path, dataset, bands, masked and len(bands) == 3, _dataset_georeferencing(path, dataset))

    def rows(self, window: tuple[int, int, int, int], r0: int, r1: int) -> NDArray[np.uint8]:
        """Rows ``r0``..``r1`` of ``window`` (r0, r1, c0, c1) of the image, (rows, cols, C) uint8."""
        from rasterio.windows import Window

        height, width = r1 - r0, window[3] - window[2]
        part = Window(window[2], window[0] + r0, width, height)
        out = np.empty((height, width, self.shape[2]), dtype=np.uint8)
        try:
            indexes = sorted(set(self.bands))  # all at once: a pixel-interleaved tile is decoded once, not per band
            data = self.dataset.read([band + 1 for band in indexes], window=part)
            for k, band in enumerate(self.bands):
                out[:, :, k] = data[indexes.index(band)]
            del data
            if self.masked:
                out[:, :, -1] = np.where(self.dataset.dataset_mask(window=part) > 0, 255, 0)
        except Exception as exc:  # noqa: BLE001 - rasterio's RasterioIOError of a damaged tile, ...
            raise DataFileError(f"cannot read {str(self.path)!r} as an image: {gdal_reason(exc)}") from exc
        return out

    def read(self, shapes: list[tuple[int, int]], level: int, window: tuple[int, int, int, int],
             band_bytes: int, device: wp.Device) -> NDArray[np.uint8]:
        """The pixels of ``window`` (r0, r1, c0, c1; past the seam of a world image too) of pyramid ``level`` (the
        levels' ``shapes``), as :meth:`ImagePyramid.sub_image` of the built pyramid gives them: the windows of the
        finer levels it is reduced from, down to the image's, read a band of rows at a time."""
        r0, r1, c0, c1 = window
        cols = shapes[level][1]
        wraps = c0 < 0 or c1 > cols
        windows = [(r0, r1, 0, cols) if wraps else window]  # past the seam: the whole rows, then taken around
        for k in range(level, 0, -1):
            windows.append(_source_window(windows[-1], shapes[k - 1], shapes[k]))
        windows.reverse()  # windows[k]: the window of level k
        channels = self.shape[2]
        height, width = windows[level][1] - windows[level][0], windows[level][3] - windows[level][2]
        _check_read_budget(self.path, (channels, height, width), np.dtype(np.uint8), "the image's window")
        reader: Any = _RasterRows(self, windows[0])
        with tempfile.TemporaryDirectory(prefix="stepterrain-window-") as folder:
            for k in range(1, level + 1):
                path = Path(folder) / f"level_{k}.u8"
                _reduce_file(reader, shapes[k - 1], shapes[k], channels, path, band_bytes, device,
                             window=windows[k], src_origin=(windows[k - 1][0], windows[k - 1][2]))
                w = windows[k]
                reader = _Reader(None, str(path), shape=(w[1] - w[0], w[3] - w[2], channels))
            pixels = reader.rows(0, height)
        if wraps:
            pixels = np.take(pixels, np.arange(c0, c1) % cols, axis=1)
        return pixels


class _RasterRows:
    """A :class:`_Reader` of ``window`` of a :class:`_WindowedTiff` (rows from the window's first)."""

    def __init__(self, image: _WindowedTiff, window: tuple[int, int, int, int]) -> None:
        self.image = image
        self.window = window
        self.shape = (window[1] - window[0], window[3] - window[2], image.shape[2])

    def rows(self, r0: int, r1: int) -> NDArray[np.uint8]:
        return self.image.rows(self.window, r0, r1)


def _pillow_mode(path: Path) -> tuple[str, bool, bool, Callable[[], None]] | None:
    """(Pillow's mode, whether it has a transparent colour, whether it is interlaced, a function warning of its EXIF
    orientation as reading it with Pillow does: :func:`_warn_exif_orientation`) of the image file ``path``, opened
    without decoding its pixels; None where Pillow cannot open it."""
    from PIL import Image

    try:
        with Image.open(path) as picture:
            exif = None
            orientation = _tiff_as_stored(picture)  # its size as stored, for the warning
            if picture.format == "PNG" and "exif" not in picture.info:
                # an eXIf chunk after the image data, or none: Pillow's getexif() decoded the whole image to look
                exif = Image.Exif()
                data = _png_exif(path)
                if data:
                    exif.load(data)
            else:
                with contextlib.suppress(Exception):  # unreadable EXIF: nothing to warn of
                    exif = picture.getexif()
            return (picture.mode, "transparency" in picture.info, bool(picture.info.get("interlace")),
                    lambda: _warn_exif_orientation(picture, path, exif, orientation))
    except Exception:  # noqa: BLE001 - UnidentifiedImageError, DecompressionBombError, OSError: rasterio reads it
        return None


def _png_exif(path: Path) -> bytes | None:
    """The data of the eXIf chunk of the PNG file ``path``, found by its chunk headers (the image data skipped, not
    decoded), else None."""
    try:
        with open(path, "rb") as file:
            if file.read(8) != b"\x89PNG\r\n\x1a\n":
                return None
            while True:  # a few dozen chunks at most (IDAT split in many is skipped one seek each)
                head = file.read(8)
                if len(head) < 8 or head[4:] == b"IEND":
                    return None
                length = int.from_bytes(head[:4], "big")
                if head[4:] == b"eXIf":
                    return file.read(length)
                file.seek(length + 4, os.SEEK_CUR)  # the data and its CRC
    except OSError:
        return None


def _covered_fraction(placed: ImagePyramid, target: Extent) -> float:
    """The fraction of ``target``'s area (the terrain's extent) that ``placed``'s extent covers (a world image,
    spanning a whole turn of longitude, covers every column)."""
    xmin, xmax, ymin, ymax = placed.extent
    tx0, tx1, ty0, ty1 = target
    across = 1.0 if placed._wraps else max(0.0, min(xmax, tx1) - max(xmin, tx0)) / (tx1 - tx0)
    return across * max(0.0, min(ymax, ty1) - max(ymin, ty0)) / (ty1 - ty0)


def _warn_sliver(image: Any, placed: ImagePyramid, target: Extent) -> None:
    """A warning when the image overlaps less than :data:`_MIN_IMAGE_COVERAGE` of the terrain's extent, naming
    the fraction and both extents: the rest of the layer is transparent (the layers beneath it show there), which an
    image in the wrong CRS or at a swapped extent made silently, a corner of it coloured."""
    fraction = _covered_fraction(placed, target)
    if fraction >= _MIN_IMAGE_COVERAGE:
        return
    what = f"image {str(image)!r}" if isinstance(image, (str, os.PathLike)) else "the image"
    warnings.warn(f"{what} covers only {100 * fraction:.3g} % of the terrain: its extent {placed.extent}, the "
                  f"terrain's {target} (xmin, xmax, ymin, ymax); the layer is transparent over the rest (the layers "
                  "beneath it show there): check the image's CRS and georeferencing (or extent=) if it should cover "
                  "more", stacklevel=caller_stacklevel())


def image_layer(image: ArrayLike | str | os.PathLike[str], terrain: Terrain, *, extent: ArrayLike | None = None,
                device: wp.DeviceLike = None, name: str = "image", texel_size: float | None = None) -> TextureLayer:
    """An image placed over a grid ``terrain`` as a thematic layer (RGB, or RGBA: alpha 0 at its nodata or
    transparent pixels), at about the terrain's resolution: the pixels of the image over the terrain's area from the
    coarsest level of its :class:`ImagePyramid` whose pixels are no larger than the terrain's node spacing (the image
    itself when it is that coarse already); ``texel_size`` (world units, > 0) asks for that resolution instead (a
    texture finer than the DEM keeps an orthophoto's detail: the coarsest level no coarser than ``texel_size``). The
    pyramid is built band by band in a temporary folder and deleted after, so memory holds the decoded image (checked
    against the memory budget) and the window read (a pixel beyond the terrain on each side, within the image, so a
    texel near its edge interpolates as over the whole image), never its full-resolution copy in floats. Of a TIFF of
    8-bit bands (a GeoTIFF orthophoto), or a PNG (GDAL decodes its rows down to the window's last, keeping a band),
    only the window over the terrain is decoded, a band of rows at a time, and reduced to that level alone (the
    same pixels as the whole pyramid's; not a JPEG-compressed TIFF Pillow reads, nor those :meth:`ImagePyramid.build`
    decodes whole):
    memory holds a band and the window read, the budget checks the window, and an image far larger than the terrain
    costs the time of its window only (a 20000 x 20000 GeoTIFF under a 1197 x 643 node DEM: `stepterrain texture`
    peaked at 0.98 GB, GDAL's block cache included, and placed it in 10 s, from 3.1 GB and 34 s). A 3-band image
    with a GDAL mask (nodata) then always has alpha, 255 where valid. Combine the layer with the terrain's layers as
    any other (:func:`~stepterrain.texture.blend`, :func:`~stepterrain.texture.modulate`): it is sampled bilinearly
    onto theirs, transparent outside its extent.

    ``image`` (a path, or an array as :meth:`ImagePyramid.build` takes it) is placed as :class:`TextureTree` places
    a pyramid: a GeoTIFF, or a JPEG or PNG with a world file (its CRS from a .prj or .aux.xml beside it), by its own
    georeferencing, in the terrain's CRS (refused in another, with the ``gdalwarp`` to run; one without a CRS is
    taken in the terrain's coordinates, refused over a DEM load_dem read from degrees), or in degrees over a DEM
    load_dem read from degrees (one spanning 360 degrees of longitude, a world image, goes on past its seam: a DEM
    across the antimeridian takes its other end there); an image without georeferencing (an array, a PNG or JPEG
    without a world file, a plain TIFF) needs ``extent`` = (xmin, xmax, ymin, ymax), the outer edges of its pixels
    in the terrain's own coordinates (those of ``terrain.extent``; a geographic DEM's local metres), which also
    places a georeferenced image there instead of its georeferencing.

    An image that overlaps the terrain only in part is transparent beyond its edges; one that covers less than 10 %
    of the terrain's extent warns, naming the fraction covered and both extents (a wrong CRS, a misread world file or
    a swapped ``extent`` more often gives such a sliver than an image meant to cover so little).

    Raises
    ------
    DataFileError
        A missing or unreadable image file.
    InvalidInputError
        An image without georeferencing and no ``extent``; one georeferenced without a CRS over a DEM in degrees;
        a CRS mismatch; an image that does not overlap the
        terrain; what :meth:`ImagePyramid.build` refuses.
    OutputTooLargeError
        The decoded image (of a TIFF or PNG read by windows, its window read) over the memory budget
        (:func:`stepterrain.set_memory_budget`).
    """
    t = _grid_terrain(terrain, None)
    target = terrain_extent(t)
    sx, sy = abs(t.spacing[0]), abs(t.spacing[1])
    if texel_size is not None:
        sx = sy = finite_number(texel_size, "texel_size", positive=True)
    with contextlib.ExitStack() as stack:
        opened: dict[str, Any] = {}  # the file opened with rasterio, read whole below if not by windows: one open
        tiff = _WindowedTiff.open(image, stack, opened=opened)  # a GeoTIFF (a PNG): only the window read
        if tiff is None:  # ImagePyramid.build of it (a file it cannot read is refused here)
            pyramid = stack.enter_context(ImagePyramid._build(
                image, None, opened.get("dataset"), extent=extent, storage=None, anisotropic=False,
                band_bytes=_BAND_BYTES, device=device, crs=None))
        else:
            placement = _placement(image, extent, None, tiff.georeferencing, tiff.shape[:2])
            pyramid = ImagePyramid._header(tiff.shape, placement[0], placement[1])
            pyramid._georeferenced = placement[2]
        if extent is None and not pyramid._georeferenced:  # its file's georeferencing, read as it was built
            # it would lie at (0, W, 0, H), one unit per pixel: anywhere on the terrain
            path = isinstance(image, (str, os.PathLike))
            what = f"image {str(image)!r}" if path else "an image array"
            raise InvalidInputError(f"{what} carries no georeferencing (an array, a PNG or JPEG without a world "
                                    "file, a TIFF without a geotransform): "
                                    + (f"{_world_file_hint(Path(image))}, or " if path else "")
                                    + "pass extent=(xmin, xmax, ymin, ymax), the outer edges of its pixels in the "
                                    "terrain's coordinates")
        unknown = extent is None and pyramid.crs is None  # georeferenced by the file, in no CRS it names
        if unknown and t.crs is not None and _spherical_eqc(t.crs) is not None:
            # the local metres load_dem made of a DEM's degrees are no file's coordinates: a world file in degrees
            # without a .prj was compared with them as numbers (placed as a patch of a few metres, or nowhere)
            raise InvalidInputError(f"image {str(image)!r} is georeferenced without a CRS, but the terrain is a DEM in "
                                    f"degrees read as local metres ({t.crs!r}), which no image file is in: put a "
                                    ".prj with the image's CRS beside it (EPSG:4326 for degrees), or pass "
                                    "extent=(xmin, xmax, ymin, ymax), the outer edges of its pixels in the "
                                    "terrain's coordinates")
        placed = _placed(pyramid, t)
        level = 0
        for k in range(1, len(placed.levels)):
            px, py = placed.pixel_size(k)
            if px > sx * (1 + 1e-9) or py > sy * (1 + 1e-9):
                break
            level = k
        window = placed.window(level, target)
        if window is None:
            hint = ""
            if unknown:  # its coordinates were taken as the terrain's: they may be in another CRS
                hint = ("; the image is georeferenced without a CRS, so it was taken in the terrain's CRS: put a .prj "
                        "with its CRS beside it, or pass extent=(xmin, xmax, ymin, ymax), the outer edges of its "
                        "pixels in the terrain's coordinates")
            raise InvalidInputError(f"the image extent {placed.extent} does not overlap the terrain's {target} "
                                    f"(mismatched extent){hint}")
        _warn_sliver(image, placed, target)
        # a pixel more on each side (within the image): a texel near the terrain's edge is interpolated with the
        # image's next pixel beyond it, not the window's edge pixel repeated (a cropped DEM, or a tile beside
        # another, took other colours on its nodes near the edge than the whole DEM did on the same nodes); a world
        # image's window goes on past its seam (a DEM across the antimeridian was draped on one side only)
        window = placed._with_margin(placed.levels, level, window)
        if tiff is None:
            pixels = np.array(placed.sub_image(level, window))  # a copy: the level files go with the pyramid
        else:
            pixels = tiff.read(pyramid_shapes(*tiff.shape[:2]), level, window, _BAND_BYTES, resolve_device(device))
        where = placed.window_extent(level, window)
    channels = pixels.shape[2]
    if channels < 3:  # grey, grey + alpha: as RGB(A)
        pixels = np.concatenate([np.repeat(pixels[:, :, :1], 3, axis=2), pixels[:, :, 1:]], axis=2)
    pixels.flags.writeable = False  # its RGBA is cached
    return TextureLayer("thematic", pixels, where, name=name)


# ---------------------------------------------------------------------------------------------- camera, errors
def visual_geometric_error(patch: GeometryPatch, camera: Camera) -> float:
    """γ(N) (§4, Fig. 2): the screen length in pixels of a vertical segment of length e(N) centred at a point of B(N)
    inside the view frustum, bounded from above over every such point, and raised to f · e(N) · |p − eye| /
    depth(p)², the longest a segment of length e(N) projects in any direction at the point p of B(N) in view nearest
    to the camera (:meth:`Camera.nearest_visible_point`; B(N)'s nearest point where it misses the frustum), f the
    focal length in pixels; 0 for a patch without children.

    Deviations from the paper, which projects the vertical segment at p alone:

    - that segment degenerates where it lies along the line of sight. For a camera looking (nearly) straight down,
      a map view, p is the point right below the eye wherever that is in view, the segment projects to 0 pixels, so
      γ(root) was 0 and the root was drawn alone (Big Tujunga from 3 km above: one patch with a 676 m error, while
      tilting the view past half the field of view drew hundreds). Hence the raise at p, continuous in the view
      direction.
    - elsewhere in view the error showed larger on screen than at p, beyond the tolerance: at the corners of a wide
      view (e(N) 1.6 times γ_user in a 90° map view, 3.4 times in a 120° one), on the side of a tilted view nearer
      the eye. The vertical segment is bounded over all of B(N) in view, the polytope B(N) ∩ frustum with corners
      (:meth:`Camera.visible_corners`), by :func:`_bounded_segment`, so every point of a patch drawn shows its
      error within γ_user (or the patch is a leaf). Drawn patches' bounds lie within about 3 % (at most 10 %) of
      their sampled worst, and about as many patches are drawn as before (Big Tujunga, 1280 x 800, γ_user = 4,
      τ_user = 2: 78 from 3 km straight down, 158 tilted 45°, 167 → 169 from beyond its corner)."""
    if patch.is_leaf:
        return 0.0
    return _geometric_error_in(patch, camera, _in_view(camera, patch.box))


@dataclass(frozen=True, eq=False)
class _InView:
    """B(N) in view in the camera's frame (:func:`_in_view`): the least depth of the corners of B(N) ∩ frustum, their
    screen positions over the focal length (s, t), the camera's forward, right and up axes (rows), and p of §4. Compared
    and hashed by identity (it holds arrays)."""

    depth: float
    s: NDArray[np.float64]
    t: NDArray[np.float64]
    axes: NDArray[np.float64]
    nearest: NDArray[np.float64]


def _in_view(camera: Camera, box: NDArray[np.float64]) -> _InView:
    """B(N) in view, for γ(N) and every τ(N, M) of the patch: the corners of B(N) ∩ view frustum
    (:meth:`Camera.visible_corners`) and p, its point nearest to the camera (:meth:`Camera.nearest_visible_point`),
    both by :meth:`Camera.visible_part`;
    where the box misses the frustum (:meth:`Camera.box_visible` is conservative), the box's point nearest to the
    camera stands for both, as before. The box's own nearest point had been taken for p, outside the view wherever
    the eye is over the terrain: straight below the eye, where the vertical segment of γ lies along the eye's ray,
    so γ(root) was 0 pixels and any view from above the highest peak drew the root alone."""
    return _in_views(camera, _box(np.ascontiguousarray(box, dtype=np.float64))[None])[0]


def _in_views(camera: Camera, boxes: NDArray[np.float64]) -> list[_InView]:
    """:func:`_in_view` of (K, 2, 3) float64 boxes (checked) at once (:meth:`Camera._visible_parts`), each box's
    numbers as its own call's: the boxes of a like number of corners in view projected together. The texture LOD's
    render called it patch by patch, 60-70 % of its time in NumPy's per-call costs."""
    nearest, seen, points, feasible = camera._visible_parts(boxes)
    counts = feasible.sum(axis=1)
    fallback = ~seen | (counts == 0)
    eye = np.asarray(camera.eye, dtype=np.float64)
    clipped = np.clip(eye, boxes[:, 0], boxes[:, 1])  # nearest_point
    counts[fallback] = 0  # a group of its own: the box's nearest point stands for both
    axes = camera._frustum[1]
    views: list[_InView] = [None] * len(boxes)  # type: ignore[list-item]
    for count in np.unique(counts):
        group = np.flatnonzero(counts == count)
        if count:
            corners = points[group][feasible[group]].reshape(len(group), count, 3)
            near = nearest[group]
        else:
            near = clipped[group]
            corners = near[:, None]
        rel = (corners - eye) @ axes.T  # (g, k, 3): depth, right, up
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # a point behind the eye: inf, refined
            depth, s, t = rel[..., 0].min(axis=1), rel[..., 1] / rel[..., 0], rel[..., 2] / rel[..., 0]
        for j, k in enumerate(group.tolist()):
            views[k] = _InView(float(depth[j]), s[j], t[j], axes, near[j])
    return views


def _bounded_segment(camera: Camera, view: _InView, vector: NDArray[np.float64]) -> float:
    """The longest screen length in pixels of the segment ``vector`` centred at any point of B(N) in view (paper 004
    §4's projected segments, over all of B(N) in view rather than at its one nearest point); inf where an end may
    lie behind the near plane, as :meth:`Camera.segment_pixels`.

    Centred at a point of depth d and screen position (s, t) over the focal length f, the segment projects, exactly,
    to f · |(v_r − s·v_f, v_u − t·v_f)| · d / (d² − v_f² / 4) pixels, with v_r, v_u, v_f its components along the
    camera's right, up and forward axes. The first factor is convex in (s, t), so at most its largest at the image
    of a corner of B(N) ∩ frustum (the projection maps the polytope onto the convex polygon of its corners' images),
    and the second decreasing in d (for d > |v_f| / 2), so at most its value at the corners' least depth. The
    bound is reached where one corner is both the nearest in depth and the farthest off the axis (a patch at a map
    view's corner); elsewhere it exceeds the largest by the spread of the two over the patch's view, small for the
    patches a fine tolerance draws."""
    return _bounded_segments(camera, [view], np.asarray(vector, dtype=np.float64).reshape(1, 3))[0]


def _bounded_segments(camera: Camera, views: Sequence[_InView], vectors: NDArray[np.float64]) -> list[float]:
    """:func:`_bounded_segment` of each view with the row of (K, 3) ``vectors`` of its index, at once (the views of
    a like number of corners together), each as its own call's numbers."""
    v = np.matmul(camera._frustum[1], vectors[:, :, None])[..., 0]  # (K, 3): along forward, right, up
    v_f, v_r, v_u = v[:, 0], v[:, 1], v[:, 2]
    half = np.abs(v_f) / 2.0
    d = np.array([view.depth for view in views], dtype=np.float64)
    counts = np.array([len(view.s) for view in views])
    spread = np.empty(len(views))
    with np.errstate(over="ignore", invalid="ignore"):  # a magnification near float64's limit: inf pixels, refine
        for count in np.unique(counts).tolist():
            group = np.flatnonzero(counts == count)
            s = np.array([views[k].s for k in group.tolist()]).reshape(len(group), count)
            t = np.array([views[k].t for k in group.tolist()]).reshape(len(group), count)
            f = v_f[group, None]
            spread[group] = np.hypot(v_r[group, None] - s * f, v_u[group, None] - t * f).max(axis=1)
        value = camera.focal_pixels * spread * d / ((d - half) * (d + half))
    value[~(d - half >= camera.near)] = math.inf  # the nearest corner's segment reaches behind the near plane (or eye)
    return value.tolist()


def _geometric_error_in(patch: GeometryPatch, camera: Camera, view: _InView, error: float | None = None) -> float:
    """γ(N) of a patch with children (:func:`visual_geometric_error`) over its :func:`_in_view` ``view`` (of
    ``error`` in place of e(N) where given)."""
    return _geometric_errors_in(camera, [view], [patch.error if error is None else error])[0]


def _geometric_errors_in(camera: Camera, views: Sequence[_InView], errors: Sequence[float]) -> list[float]:
    """:func:`_geometric_error_in` of each view with the error of its index (e(N), or that and a seam error), at once,
    each as its own call's numbers."""
    vertical = _bounded_segments(camera, views, np.array([[0.0, 0.0, error] for error in errors]).reshape(-1, 3))
    offset = np.array([view.nearest for view in views]).reshape(-1, 3) - np.asarray(camera.eye, dtype=np.float64)
    depths = np.matmul(offset[:, None, :], camera._frustum[1][0])[:, 0]
    norms = np.sqrt(np.matmul(offset[:, None, :], offset[:, :, None])[:, 0, 0])  # as np.linalg.norm: √(x · x)
    out = []
    with np.errstate(over="ignore", divide="ignore"):  # a huge error, or depth² underflowing to 0: inf
        for error, segment, depth, norm in zip(errors, vertical, depths.tolist(), norms, strict=True):
            if not depth > 0.0:  # p behind the eye (a box out of view, or around the eye): refine, as segment_pixels
                out.append(math.inf)
                continue
            out.append(max(segment, float(camera.focal_pixels * error * norm / depth ** 2)))
    return out


def texel_pixels(geometry: GeometryPatch, texture: TexturePatch, camera: Camera) -> float:
    """The screen size in pixels of one texel of M over the points of B(N) in view (τ without the leaf convention):
    the longer of the projected x segment of length w and y segment of length h, bounded from above over every point
    of B(N) in view as γ is (:func:`visual_geometric_error`; at the paper's one nearest point in view, a texel showed
    larger elsewhere in view than the tolerance: 1.06 times τ_user in a 45° view tilted 10°, 1.36 times in a 90°
    view tilted 15°)."""
    return _texel_pixels_in(texture, camera, _in_view(camera, geometry.box))


def _texel_pixels_in(texture: TexturePatch, camera: Camera, view: _InView) -> float:
    """:func:`texel_pixels` over the geometry patch's :func:`_in_view` ``view``."""
    return _texels_pixels_in(camera, [texture], [view])[0]


def _texels_pixels_in(camera: Camera, textures: Sequence[TexturePatch], views: Sequence[_InView]) -> list[float]:
    """:func:`_texel_pixels_in` of each texture patch over the view of its index, at once, each as its own call's
    numbers."""
    rows = []
    for texture in textures:
        w, h = texture.texel_size
        rows += [[w, 0.0, 0.0], [0.0, h, 0.0]]
    segments = _bounded_segments(camera, [view for view in views for _ in (0, 1)], np.array(rows).reshape(-1, 3))
    return [max(segments[k], segments[k + 1]) for k in range(0, len(segments), 2)]


def visual_texture_error(geometry: GeometryPatch, texture: TexturePatch, camera: Camera) -> float:
    """τ(N, M) (§4): the screen size of one texel of M in pixels over B(N) in view (:func:`texel_pixels`); 0 when M
    has no children (nothing finer exists)."""
    if texture.is_leaf:
        return 0.0
    return texel_pixels(geometry, texture, camera)


def _texture_errors_in(camera: Camera, textures: Sequence[TexturePatch], views: Sequence[_InView]) -> list[float]:
    """:func:`visual_texture_error` of each texture patch over the geometry patch's :func:`_in_view` of its index,
    at once."""
    inner = [k for k, texture in enumerate(textures) if not texture.is_leaf]
    out = [0.0] * len(textures)
    for k, value in zip(inner, _texels_pixels_in(camera, [textures[k] for k in inner], [views[k] for k in inner]),
                        strict=True):
        out[k] = value
    return out


# ---------------------------------------------------------------------------------------------- loading
class TextureCache:
    """Texture data loaded on demand in a background thread, least recently used evicted over ``budget`` bytes.

    ``request`` never blocks (§4: "non-blocking!!!"); ``loader(M)`` (default: a copy of ``M.image()``) runs in
    the background thread. ``is_loaded`` marks the patch as recently used. Loaded NumPy data is handed out
    read-only (a read-only view of the loader's array), so a caller cannot change what later hits get. The bytes
    held never exceed ``budget``: a patch whose data alone is larger fails to load
    (:class:`~stepterrain.errors.OutputTooLargeError`). A load that fails (the loader raised: a corrupt or missing
    tile) is raised to the caller as a :class:`~stepterrain.errors.DataFileError` naming the patch, from the
    loader's exception, by the next :meth:`request`, :meth:`load_now`, :meth:`wait` or
    :func:`render_with_textures` with this cache; once raised it is forgotten, so a later request loads the patch
    again.
    """

    def __init__(self, budget: int = 256 * 1024**2, loader: Callable[[TexturePatch], Any] | None = None,
                 workers: int = 1) -> None:
        # a NumPy integer too (as a pyramid level, a lens' resolution): refused before
        if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
            raise InvalidInputError(f"budget must be a positive int of bytes; got {plain_repr(budget)}")
        if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
            raise InvalidInputError(f"workers must be a positive int of threads; got {plain_repr(workers)}")
        budget, workers = int(budget), int(workers)
        if loader is not None and not callable(loader):
            raise InvalidInputError(f"loader must be a function of a TexturePatch; got {type(loader).__name__}")
        self.budget = budget
        self.loader = loader or (lambda patch: np.array(patch.image()))
        self._loaded: OrderedDict[int, tuple[TexturePatch, Any, int]] = OrderedDict()
        self._pending: dict[int, Future] = {}
        self._failed: OrderedDict[int, tuple[TexturePatch, Exception]] = OrderedDict()  # not yet raised
        self._lock = threading.Lock()
        self._executor = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="stepterrain-texture")
        self._closed = False
        self.bytes_loaded = 0
        self.evictions = 0

    def is_loaded(self, patch: TexturePatch) -> bool:
        with self._lock:
            if id(patch) in self._loaded:
                self._loaded.move_to_end(id(patch))
                return True
            return False

    def get(self, patch: TexturePatch) -> Any:
        with self._lock:
            item = self._loaded.get(id(patch))
            return None if item is None else item[1]

    def request(self, patch: TexturePatch) -> None:
        """Start loading ``patch`` in the background unless it is loaded or on its way (raising a failed load
        first)."""
        self._raise_failed()
        with self._lock:
            if id(patch) in self._loaded or id(patch) in self._pending:
                return
            if self._closed:  # its threads are gone: the executor's RuntimeError ("cannot schedule new futures after
                # shutdown") came out of request, load_now and render_with_textures
                raise InvalidInputError("the TextureCache is closed (by close()), so it loads no more patches; make a "
                                        "new TextureCache (its loaded patches are still handed out by get)")
            self._pending[id(patch)] = self._executor.submit(self._load, patch)

    def load_now(self, patch: TexturePatch) -> Any:
        """Load ``patch`` in this thread (e.g. the root before the first frame)."""
        self.request(patch)
        with self._lock:
            future = self._pending.get(id(patch))
        if future is not None:
            future.result()
        self._raise_failed()
        return self.get(patch)

    def wait(self) -> None:
        """Block until every requested load has finished (tests, benchmarks)."""
        while True:
            with self._lock:
                futures = list(self._pending.values())
            if not futures:
                self._raise_failed()
                return
            for future in futures:
                future.result()

    def _raise_failed(self) -> None:
        """Raise the oldest failed load not yet raised (a background thread's exception was lost: the patch was
        requested again every frame, failing each time, and its parent drawn without a word)."""
        with self._lock:
            if not self._failed:
                return
            _, (patch, error) = self._failed.popitem(last=False)
        r0, r1, c0, c1 = patch.window
        kind = OutputTooLargeError if isinstance(error, OutputTooLargeError) else DataFileError
        raise kind(f"loading the texture patch at pyramid level {patch.level}, window rows {r0}:{r1}, "
                            f"columns {c0}:{c1} failed: {type(error).__name__}: {error}") from error

    def _load(self, patch: TexturePatch) -> None:
        try:
            data = self.loader(patch)
            if isinstance(data, np.ndarray) and data.flags.writeable:
                # handed out read-only, every hit the same array: a caller's in-place edit (a gamma, premultiplied
                # alpha) went into the cache, drawn by every later hit and frame; a view, so a loader's own array
                # stays writeable for its owner
                data = data.view()
                data.flags.writeable = False
            size = int(getattr(data, "nbytes", patch.nbytes))
            if size > self.budget:  # it was kept anyway, alone: the bytes held went past the budget
                raise OutputTooLargeError(f"its data takes {size} bytes, more than the cache's budget of "  # size > 1
                                          f"{self.budget} byte{'' if self.budget == 1 else 's'} (raise budget or "
                                          "lower the TextureTree's max_texture_size)")
            with self._lock:
                self._loaded[id(patch)] = (patch, data, size)
                self.bytes_loaded += size
                while self.bytes_loaded > self.budget and len(self._loaded) > 1:
                    _, (_, _, old) = self._loaded.popitem(last=False)
                    self.bytes_loaded -= old
                    self.evictions += 1
        except Exception as error:  # kept for the caller: a thread's exception went nowhere
            with self._lock:
                self._failed[id(patch)] = (patch, error)
        finally:
            with self._lock:
                self._pending.pop(id(patch), None)

    def close(self) -> None:
        """Stop the loading threads (after the loads under way); a later request is refused."""
        with self._lock:
            self._closed = True
        self._executor.shutdown(wait=True)


# ---------------------------------------------------------------------------------------------- traversal
@dataclass(frozen=True)
class DrawItem:
    """One ``paintWithTextures(N, T)`` call: the geometry patch, one texture patch per active layer (None while a
    layer has nothing loaded yet) and, per layer, whether hybrid shading replaces it by computed lighting
    (§7.3: a topographic leaf texture whose texel exceeds τ_user on screen). ``seams`` names, per side of the patch
    (its first row, last row, first column, last column of grid nodes), the coarser patch drawn across it, onto whose
    edge :func:`paint_with_textures` moves that border's nodes (None: no coarser neighbour drawn there); ``finer``,
    per side, the finer patches drawn across it (those whose ``seams`` name this one), in order along the side, at
    whose border nodes it splits that side's edges (empty: none)."""

    geometry: GeometryPatch
    textures: tuple[TexturePatch | None, ...]
    lighting: tuple[bool, ...]
    seams: tuple[GeometryPatch | None, ...] = (None, None, None, None)
    finer: tuple[tuple[GeometryPatch, ...], ...] = ((), (), (), ())


def render_with_textures(
    root: GeometryPatch,
    textures: Sequence[TexturePatch],
    camera: Camera,
    *,
    gamma_user: float = 1.0,
    tau_user: float = 1.0,
    cache: TextureCache | None = None,
    hybrid: Sequence[bool] | None = None,
) -> list[DrawItem]:
    """The simultaneous traversal ``renderWithTextures`` of §4 over a geometry tree and texture trees.

    Parameters
    ----------
    root : GeometryPatch
        N_root of a :class:`PatchQuadtree`.
    textures : sequence of TexturePatch
        The roots M_root of the active layers' texture trees (the set S).
    camera : Camera
    gamma_user, tau_user : float
        Thresholds in screen pixels for γ(N) and τ(N, S) = max over S of τ(N, M).
    cache : TextureCache, optional
        When given, a texture patch whose data is not loaded is requested (non-blocking) and its parent used
        instead; None treats every patch as loaded.
    hybrid : sequence of bool, optional
        Per layer, whether it is a topographic layer subject to hybrid shading (§7.3).

    Returns
    -------
    list of DrawItem
        In traversal order. Every item satisfies γ(N) ≤ γ_user and τ(N, M) ≤ τ_user for each loaded M, or
        its geometry patch is a leaf (or its texture a pruned full-resolution leaf).

    Notes
    -----
    Frustum culling with B(N); refinement while γ(N) > γ_user or τ(N, S) > τ_user; children take M's child
    texture patch, M itself where M is pruned at full resolution, and drop a layer that does not reach them
    (partial textures). Before painting, each M is reduced to its parent while τ(N, M_parent) ≤ τ_user, then
    to its parent while its data is not loaded (requesting it). The cut is balanced: a drawn patch with a neighbour
    drawn more than one level finer is split too (not in the paper, whose patches leave T-junction cracks), and each
    item names its coarser neighbours in ``seams`` for :func:`paint_with_textures` to stitch onto, and its finer ones
    in ``finer`` for it to split its border edges at their nodes (no T-junction left). A stitched patch's
    mesh lies within e(N) + s(N) of the terrain, s(N) its largest seam error (:class:`GeometryPatch`
    ``seam_errors``) on a stitched side; where γ of that exceeds γ_user, the coarser neighbours split too, so it holds
    for every item whose coarser neighbours have children.
    """
    gamma_user = _threshold(gamma_user, "gamma_user")
    tau_user = _threshold(tau_user, "tau_user")
    if not isinstance(root, GeometryPatch):
        raise InvalidInputError(f"root must be a GeometryPatch (PatchQuadtree.root); got {type(root).__name__}")
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be a stepterrain Camera; got {type(camera).__name__}")
    if cache is not None and not isinstance(cache, TextureCache):
        raise InvalidInputError(f"cache must be a TextureCache or None; got {type(cache).__name__}")
    if cache is not None:
        cache._raise_failed()  # a load failed since the last frame
    if isinstance(textures, TexturePatch) or not isinstance(textures, Sequence):
        raise InvalidInputError(f"textures must be a sequence of texture tree roots (TextureTree.root); got "
                                f"{type(textures).__name__}")
    layers = list(textures)
    for k, m in enumerate(layers):
        if not isinstance(m, TexturePatch):
            raise InvalidInputError(f"textures[{k}] must be a TexturePatch (TextureTree.root); got {type(m).__name__}")
        if m.geometry is not root:  # child_for looks children up by geometry patch: another tree's find none
            raise InvalidInputError(f"textures[{k}] belongs to a texture tree over another geometry patch than root "
                                    "(build the TextureTree on the PatchQuadtree whose root is traversed)")
    if hybrid is not None and (isinstance(hybrid, (str, bytes)) or not isinstance(hybrid, Sequence | np.ndarray)):
        raise InvalidInputError(f"hybrid must be a sequence of one bool per layer; got {hybrid!r}")
    flags = (tuple(check_flag(v, f"hybrid[{k}]") for k, v in enumerate(hybrid)) if hybrid is not None
             else (False,) * len(layers))
    if len(flags) != len(layers):
        raise InvalidInputError(f"hybrid needs one flag per layer ({len(layers)}); got {len(flags)}")
    forced: set[GeometryPatch] = set()
    # per patch visited, over the passes: None where culled, else its view, γ(N), τ(N, S) and texture patches
    visits: dict[GeometryPatch, _Visit | None] = {}
    probes: dict[GeometryPatch, tuple[tuple[GeometryPatch, ...], ...]] = {}  # per drawn patch: _probe_paths
    within: set[tuple[GeometryPatch, float]] = set()  # (patch, seam error) whose γ of e(N) + it is within γ_user
    while True:  # balanced: split a drawn patch while a neighbour is drawn more than one level finer (a few passes)
        cut = _traverse(root, layers, camera, gamma_user, tau_user, forced, visits)
        drawn = set(cut)
        seams = [_coarser_neighbours(node, root, drawn, probes) for node in cut]
        # a leaf is not split: one coarser than its depth is a single cell (both its sides <= 1 cell), no node between
        split = {n for node, sides in zip(cut, seams, strict=True) for n in sides
                 if n is not None and n.children and node.depth - n.depth > 1}
        checks = []  # γ of e(N) + the seam error, measured together: over γ_user, the coarser neighbour splits
        for node, sides in zip(cut, seams, strict=True):
            seam = max((node._seam_error(k) for k, n in enumerate(sides) if n is not None), default=0.0)
            if seam > 0.0 and (node, seam) not in within:
                checks.append((node, sides, seam))
        for (node, sides, seam), gamma in zip(checks, _geometric_errors_in(
                camera, [visits[node].view for node, _, _ in checks],  # type: ignore[union-attr]
                [node.error + seam for node, _, seam in checks]), strict=True):
            if gamma > gamma_user:
                split.update(n for n in sides if n is not None and n.children)
            else:  # (a patch stays drawn over passes, its coarser neighbours too: measured once)
                within.add((node, seam))
        split -= forced
        if not split:
            break
        forced |= split
    finer = _finer_neighbours(cut, seams)
    textures = _textures(cut, visits, flags, camera, tau_user, cache)  # the final cut's (loads requested)
    return [DrawItem(node, chosen, lighting, sides, across)
            for node, (chosen, lighting), sides, across in zip(cut, textures, seams, finer, strict=True)]


def _finer_neighbours(cut: list[GeometryPatch], seams: list[tuple[GeometryPatch | None, ...]]) -> list[
        tuple[tuple[GeometryPatch, ...], ...]]:
    """Per patch of ``cut``, per side, the finer drawn patches across it: those whose ``seams`` (per patch) name it on
    their opposite side (a finer patch's first row lies on a coarser one's last row), ordered along the side."""
    index = {node: k for k, node in enumerate(cut)}
    finer: list[list[list[GeometryPatch]]] = [[[], [], [], []] for _ in cut]
    for node, sides in zip(cut, seams, strict=True):
        for side, coarse in enumerate(sides):
            if coarse is not None:
                finer[index[coarse]][side ^ 1].append(node)
    return [tuple(tuple(sorted(across, key=lambda n, s=side: (n.cols if s < 2 else n.rows)[0]))
                  for side, across in enumerate(sides)) for sides in finer]


def _coarser_neighbours(patch: GeometryPatch, root: GeometryPatch, drawn: set[GeometryPatch],
                        probes: dict[GeometryPatch, tuple[tuple[GeometryPatch, ...], ...]]) -> tuple[
        GeometryPatch | None, ...]:
    """Per side of ``patch`` (first row, last row, first column, last column), the patch of ``drawn`` across it
    when that one is coarser, else None: the drawn one among the patches coarser than ``patch`` holding the cell
    just outside the side's middle (:func:`_probe_paths`; ``drawn``, a cut, holds at most one of them). A coarser one
    spans the whole side (quadtree patches of one depth share their rows or columns). ``probes`` keeps the paths
    per patch over the balancing passes."""
    paths = probes.get(patch)
    if paths is None:
        paths = probes[patch] = _probe_paths(patch, root)
    # most sides have none drawn: told by one C-level pass over the path (a generator per side before)
    return tuple(None if drawn.isdisjoint(path) else next(n for n in path if n in drawn) for path in paths)


def _probe_paths(patch: GeometryPatch, root: GeometryPatch) -> tuple[tuple[GeometryPatch, ...], ...]:
    """Per side of ``patch``, the patches coarser than it holding the cell just outside the side's middle, root
    first (none where the side is on the grid's outline or a single node)."""
    (r0, r1), (c0, c1) = patch.rows, patch.cols
    last_row, last_col = root.rows[1], root.cols[1]
    probes = [(r0 - 1, (c0 + c1) // 2) if r0 > 0 and c1 > c0 else None,
              (r1, (c0 + c1) // 2) if r1 < last_row and c1 > c0 else None,
              ((r0 + r1) // 2, c0 - 1) if c0 > 0 and r1 > r0 else None,
              ((r0 + r1) // 2, c1) if c1 < last_col and r1 > r0 else None]
    out: list[tuple[GeometryPatch, ...]] = []
    for probe in probes:
        path: list[GeometryPatch] = []
        node = root
        while probe is not None and node.depth < patch.depth:  # down to the patch holding the cell
            path.append(node)
            if not node.children:
                break
            first = node.children[0]  # children: row parts x column parts, each axis split in two or kept whole
            split_cols = first.cols[1] != node.cols[1]
            below = first.rows[1] != node.rows[1] and probe[0] >= first.rows[1]
            right = split_cols and probe[1] >= first.cols[1]
            node = node.children[(2 if split_cols else 1) * below + right]
        out.append(tuple(path))
    return tuple(out)


class _Visit(NamedTuple):
    """A visible patch in :func:`_traverse`: its :func:`_in_view`, γ(N), τ(N, S) (0 for a leaf: never split) and
    texture patches per layer (from the root down by ``child_for``)."""

    view: _InView
    gamma: float
    tau: float
    textures: list[TexturePatch | None]


def _traverse(root: GeometryPatch, layers: list[TexturePatch], camera: Camera, gamma_user: float, tau_user: float,
              forced: set[GeometryPatch], visits: dict[GeometryPatch, _Visit | None]) -> list[GeometryPatch]:
    """One pass of :func:`render_with_textures`' traversal, splitting the patches of ``forced`` too: the drawn
    patches in traversal order. ``visits``: per patch visited, None where culled, else its :class:`_Visit`, filled in
    as they are first visited (a pass after the first computes nothing for the patches seen before). The patches to
    visit are found level by level, each level's new ones culled and put in view together (:func:`_visit`), then
    walked depth first as before."""
    level: list[tuple[GeometryPatch, list[TexturePatch | None] | None]] = [(root, list(layers))]
    while level:  # (current None: visited in an earlier pass)
        _visit([(node, current) for node, current in level if current is not None and node not in visits], camera,
               visits)
        below: list[tuple[GeometryPatch, list[TexturePatch | None] | None]] = []
        for node, _ in level:
            seen = visits[node]
            if seen is not None and _refined(node, seen, forced, gamma_user, tau_user):
                below.extend((child, None if child in visits else [m.child_for(child) if m is not None else None
                                                                   for m in seen.textures])
                             for child in node.children)  # a child visited in an earlier pass has its textures already
        level = below
    out: list[GeometryPatch] = []
    stack = [root]
    while stack:  # depth-first over patches (a few thousand at most), never over cells
        node = stack.pop()
        seen = visits[node]
        if seen is None:
            continue
        if _refined(node, seen, forced, gamma_user, tau_user):
            stack.extend(reversed(node.children))
            continue
        out.append(node)
    return out


def _refined(node: GeometryPatch, seen: _Visit, forced: set[GeometryPatch], gamma_user: float,
             tau_user: float) -> bool:
    """Whether :func:`_traverse` splits a visible patch: not a leaf, and forced or over a tolerance."""
    return not node.is_leaf and (node in forced or seen.gamma > gamma_user or seen.tau > tau_user)


def _visit(new: list[tuple[GeometryPatch, list[TexturePatch | None]]], camera: Camera,
           visits: dict[GeometryPatch, _Visit | None]) -> None:
    """Fills ``visits`` for patches first visited, each with its texture patches per layer: culled together
    (:meth:`Camera._boxes_visible`), the visible ones put in view together (:func:`_in_views`), their γ(N) and
    τ(N, S) measured together (:func:`_geometric_errors_in`, :func:`_texture_errors_in`)."""
    if not new:
        return
    boxes = np.array([node.box for node, _ in new], dtype=np.float64).reshape(len(new), 2, 3)
    visible = camera._boxes_visible(boxes)
    views = iter(_in_views(camera, boxes[visible]) if visible.any() else ())
    inner = []  # (node, textures, view) of the visible patches with children
    for (node, current), shown in zip(new, visible.tolist(), strict=True):
        if not shown:
            visits[node] = None
        elif node.is_leaf:
            visits[node] = _Visit(next(views), 0.0, 0.0, current)
        else:
            inner.append((node, current, next(views)))  # γ's and every τ's of this patch
    gammas = _geometric_errors_in(camera, [view for _, _, view in inner], [node.error for node, _, _ in inner])
    pairs = [(m, view) for _, current, view in inner for m in current if m is not None]
    taus = iter(_texture_errors_in(camera, [m for m, _ in pairs], [view for _, view in pairs]))
    for (node, current, view), gamma in zip(inner, gammas, strict=True):
        visits[node] = _Visit(view, gamma, max((next(taus) for m in current if m is not None), default=0.0), current)


def _textures(cut: list[GeometryPatch], visits: dict[GeometryPatch, _Visit | None], flags: tuple[bool, ...],
              camera: Camera, tau_user: float, cache: TextureCache | None) -> list[
        tuple[tuple[TexturePatch | None, ...], tuple[bool, ...]]]:
    """Per drawn patch, its texture patch per layer, reduced from its visit's (§4: to the parent while τ of the parent
    stays within ``tau_user``, then while not loaded, requesting it), and whether hybrid shading lights it. The τ of
    every patch's parents are measured together, a generation at a time (the same ones as patch by patch); the cache is
    asked patch by patch, layer by layer, in the cut's order."""
    views = [visits[node].view for node in cut]  # type: ignore[union-attr]
    chosen = [list(visits[node].textures) for node in cut]  # type: ignore[union-attr]
    pending = [(i, k) for i, current in enumerate(chosen) for k, m in enumerate(current)
               if m is not None and m.parent is not None]
    while pending:  # reduction of texture data
        parents = [chosen[i][k].parent for i, k in pending]
        errors = _texture_errors_in(camera, parents, [views[i] for i, _ in pending])  # type: ignore[arg-type]
        reduced = []
        for (i, k), parent, error in zip(pending, parents, errors, strict=True):
            if error <= tau_user:
                chosen[i][k] = parent
                if parent.parent is not None:  # type: ignore[union-attr]
                    reduced.append((i, k))
        pending = reduced
    for current in chosen:
        for k, m in enumerate(current):
            while m is not None and cache is not None and not cache.is_loaded(m):
                cache.request(m)  # non-blocking; the parent stands in meanwhile
                m = m.parent
            current[k] = m
    leaves = [(i, k) for i, current in enumerate(chosen) for k, m in enumerate(current)
              if flags[k] and m is not None and m.is_leaf]
    over = {key: texel > tau_user for key, texel in zip(leaves, _texels_pixels_in(
        camera, [chosen[i][k] for i, k in leaves], [views[i] for i, _ in leaves]), strict=True)}  # type: ignore[misc]
    return [(tuple(current), tuple(flags[k] and (m is None or over.get((i, k), False)) for k, m in enumerate(current)))
            for i, current in enumerate(chosen)]


def _threshold(value: Any, name: str) -> float:
    try:
        number = as_number(value)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{name} must be a number of pixels; got {plain_repr(value)}") from None
    if not math.isfinite(number) or number < 0:
        raise InvalidInputError(f"{name} must be a finite number of pixels >= 0; got {plain_repr(value)}")
    return number



def paint_with_textures(item: DrawItem, layer: int = 0) -> Any:
    """``paintWithTextures(N, T)`` (§4) as a mesh: the geometry patch at its level of detail (every
    ``stride``-th node of its block, the last row and column kept) textured with the sub-image of the chosen
    texture patch of ``layer`` (UVs through the patch's georeferenced window; a 1-channel pyramid drapes as
    luminance, a 2-channel one as grey + alpha, i.e. RGBA; with nodata, as :func:`~stepterrain.heightfield_mesh`, no
    face touches a NaN node and those nodes are left out). Returns a ``trimesh.Trimesh``;
    an item whose layer has no texture patch yet raises :class:`~stepterrain.errors.InvalidInputError`.

    Patches are stitched (the paper draws them as they are): a patch samples the grid lines that are multiples of its
    stride (:func:`_samples`), so a coarser neighbour's border nodes are among its own, and its border nodes between
    two of them, on a side the item's ``seams`` names, are moved onto the coarser patch's edge (linear between its two
    ends). The border of two patches drawn at different levels is then one polyline: no crack (unstitched, Big
    Tujunga, ``leaf_size=32``, ``gamma_user=1``: about 6,000 T-junction border edges in an oblique view, gaps up to
    0.7 px). The moved nodes leave the terrain by the patch's seam error on that side (:class:`GeometryPatch`
    ``seam_errors``), which :func:`render_with_textures` counts in γ. An entry of ``seams`` that is not None nor a
    coarser patch of the same quadtree drawn across that side (its last row or column on the side's line, spanning
    the side), or ``seams`` of other than 4 entries, raises :class:`~stepterrain.errors.InvalidInputError`.

    The closure is topological too: on a side the item's ``finer`` names finer patches across, each border triangle
    whose edge has their border nodes between its ends is split at them (a fan from its opposite vertex), the extra
    vertices at the very floats the finer patches give those nodes (the same arithmetic; UVs, from x and y, along the
    edge), so the surface is the same and the meshes of a cut, each its own (own texture patch's image and UVs),
    welded by exact position share every border edge: no T-junction for a rasterizer to drop pixels along (unsplit,
    the sample DEM in an oblique view, ``leaf_size=32``: 346 coarse border edges used once each). An entry of
    ``finer`` that is not a finer patch of the same quadtree drawn across that side, or a side named in both
    ``seams`` and ``finer``, raises :class:`~stepterrain.errors.InvalidInputError`.

    Examples
    --------
    >>> import numpy as np
    >>> from stepterrain.texture_lod import (Camera, ImagePyramid, PatchQuadtree, TextureTree,
    ...                                      paint_with_textures, render_with_textures)
    >>> quadtree = PatchQuadtree(np.zeros((17, 17)), leaf_size=8)
    >>> with ImagePyramid.build(np.full((32, 32, 3), 90, np.uint8), extent=quadtree.root.domain) as pyramid:
    ...     tree = TextureTree(pyramid, quadtree, max_texture_size=16)
    ...     items = render_with_textures(quadtree.root, [tree.root], Camera((8, -30, 20), (8, 8, 0)))
    ...     meshes = [paint_with_textures(item) for item in items]
    >>> float(sum(m.area for m in meshes))   # the drawn patches tile the 16 x 16 domain
    256.0
    """
    import trimesh

    from .terrain import grid_faces, without_nan_nodes
    from .texture import TextureLayer, drape

    tree = _tree_of(item, layer)
    patch = item.geometry
    terrain = tree.quadtree.terrain if tree is not None else None
    if terrain is None:
        raise InvalidInputError("paint_with_textures needs a DrawItem whose layer has a texture patch")
    seams = _checked_seams(item)
    finer = _checked_finer(item, seams)
    (r0, r1), (c0, c1) = patch.rows, patch.cols
    rows, cols = _samples(r0, r1, patch.stride), _samples(c0, c1, patch.stride)
    dx, dy = terrain.spacing
    jj, ii = np.meshgrid(cols, rows)
    z = terrain.heights[np.ix_(rows, cols)].astype(np.float64)
    edge = [(0, slice(None)), (-1, slice(None)), (slice(None), 0), (slice(None), -1)]  # first/last row/column of z
    for side, coarse in enumerate(seams):  # T-junctions closed: border nodes moved onto the coarser edge
        if coarse is not None:
            profile, at = _border(terrain.heights, patch, side)
            z[edge[side]] = _stitched(profile, at, coarse.cols if side < 2 else coarse.rows, coarse.stride,
                                      z[edge[side]])
    vertices = np.column_stack([terrain.origin[0] + jj.reshape(-1) * dx, terrain.origin[1] + ii.reshape(-1) * dy,
                                z.reshape(-1)])
    faces = grid_faces(len(rows), len(cols), flip=dx * dy < 0)
    for side, across in enumerate(finer):  # T-junctions closed: the border edges split at the finer nodes
        if across:
            vertices, faces = _split_border(terrain, patch, side, across, vertices, faces, (len(rows), len(cols)))
    # nodata, as heightfield_mesh: no face touches a NaN node, and the NaN nodes go (they were kept: NaN vertices in
    # the mesh, its faces spanning the void)
    vertices, faces, _ = without_nan_nodes(vertices, faces)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    texture = item.textures[layer]
    image = np.asarray(texture.image())
    if image.shape[2] == 1:
        texture_layer = TextureLayer("luminance", image[:, :, 0], texture.domain)
    elif image.shape[2] == 2:  # grey + alpha (PNG's LA): as RGBA, not refused as "(h, w, 3) RGB" by the layer
        rgba = np.concatenate([np.repeat(image[:, :, :1], 3, axis=2), image[:, :, 1:]], axis=2)
        texture_layer = TextureLayer("thematic", rgba, texture.domain)
    else:
        texture_layer = TextureLayer("thematic", image, texture.domain)
    return drape(mesh, texture_layer)


_SIDES = ("first row", "last row", "first column", "last column")


def _checked_seams(item: DrawItem) -> tuple[GeometryPatch | None, ...]:
    """``item.seams``, each entry None or a coarser patch of the item's quadtree drawn across that side (its last row
    or column the side's line, its columns or rows spanning the side's), else an InvalidInputError naming it: a fifth
    entry raised a bare IndexError, a non-patch an AttributeError, and a patch not across the side (or not coarser)
    was stitched onto anyway, the border moved onto its edges extrapolated past its ends."""
    patch, seams = item.geometry, item.seams
    if not isinstance(patch, GeometryPatch):
        raise InvalidInputError(f"item.geometry must be a GeometryPatch; got {type(patch).__name__}")
    if isinstance(seams, (str, bytes)) or not isinstance(seams, Sequence) or len(seams) != 4:
        got = counted(len(seams), "entry", "entries") if isinstance(seams, Sequence) else repr(seams)
        raise InvalidInputError("item.seams must be 4 entries (the patch's first row, last row, first column, last "
                                f"column), each the coarser GeometryPatch drawn across that side or None; got {got}")
    root = _root_of(patch)
    for side, coarse in enumerate(seams):
        if coarse is None:
            continue
        got = _not_across(patch, root, side, coarse, coarser=True)
        if got is None:
            continue
        axis, along, line, own, ends = _side_terms(patch, side)
        raise InvalidInputError(f"item.seams[{side}] must be None or a coarser patch of the item's quadtree drawn "
                                f"across its {_SIDES[side]} (depth < {patch.depth}, its {axis} {ends} at "
                                f"{axis[:-1]} {line}, its {along} spanning {own[0]}-{own[1]}); got {got}")
    return tuple(seams)


def _checked_finer(item: DrawItem, seams: tuple[GeometryPatch | None, ...]) -> tuple[tuple[GeometryPatch, ...], ...]:
    """``item.finer``, each entry a sequence of finer patches of the item's quadtree drawn across that side (their
    first or last row or column the side's line, their columns or rows within the side's), on a side ``seams`` leaves
    None, else an InvalidInputError naming it."""
    patch, finer = item.geometry, item.finer
    if isinstance(finer, (str, bytes)) or not isinstance(finer, Sequence) or len(finer) != 4 or any(
            isinstance(f, (str, bytes)) or not isinstance(f, Sequence) for f in finer):
        got = counted(len(finer), "entry", "entries") if isinstance(finer, Sequence) else repr(finer)
        raise InvalidInputError("item.finer must be 4 sequences (the patch's first row, last row, first column, last "
                                "column), each of the finer GeometryPatches drawn across that side; got " + got)
    root = _root_of(patch)
    for side, across in enumerate(finer):
        if across and seams[side] is not None:
            raise InvalidInputError(f"item.finer[{side}] must be empty where item.seams[{side}] names a coarser patch "
                                    f"across its {_SIDES[side]}; got {counted(len(across), 'patch', 'patches')}")
        for k, fine in enumerate(across):
            got = _not_across(patch, root, side, fine, coarser=False)
            if got is None:
                continue
            axis, along, line, own, ends = _side_terms(patch, side)
            raise InvalidInputError(f"item.finer[{side}][{k}] must be a finer patch of the item's quadtree drawn "
                                    f"across its {_SIDES[side]} (depth > {patch.depth}, its {axis} {ends} at "
                                    f"{axis[:-1]} {line}, its {along} within {own[0]}-{own[1]}); got {got}")
    return tuple(tuple(across) for across in finer)


def _side_terms(patch: GeometryPatch, side: int) -> tuple[str, str, int, tuple[int, int], str]:
    """For :func:`_checked_seams`' and :func:`_checked_finer`'s messages, a side of ``patch``: the axis its line is
    one of and the one along it, the line, the patch's span along it, and where a neighbour's lines end on it."""
    axis, along = ("rows", "columns") if side < 2 else ("columns", "rows")
    line = (patch.rows + patch.cols)[side]
    own = patch.cols if side < 2 else patch.rows
    return axis, along, line, own, "starting" if side % 2 else "ending"  # its line: the neighbour's last or first


def _not_across(patch: GeometryPatch, root: GeometryPatch, side: int, other: object, coarser: bool) -> str | None:
    """None where ``other`` is a patch of ``root``'s quadtree drawn across ``patch``'s side ``side`` (its last or
    first row or column the side's line), coarser (its span along the side holding the side's) or, with ``coarser``
    False, finer (its span within the side's); else what it is, for the error."""
    if not isinstance(other, GeometryPatch):
        return type(other).__name__
    if _root_of(other) is not root:
        return "a patch of another quadtree"
    _, _, line, own, _ = _side_terms(patch, side)
    theirs = other.rows if side < 2 else other.cols
    span = other.cols if side < 2 else other.rows
    if theirs[1 if side % 2 == 0 else 0] == line and (
            other.depth < patch.depth and span[0] <= own[0] and own[1] <= span[1] if coarser
            else other.depth > patch.depth and own[0] <= span[0] and span[1] <= own[1]):
        return None
    return (f"a patch of depth {other.depth} over rows {other.rows[0]}-{other.rows[1]}, columns "
            f"{other.cols[0]}-{other.cols[1]}")


def _split_border(terrain: Terrain, patch: GeometryPatch, side: int, finer: Sequence[GeometryPatch],
                  vertices: NDArray[np.float64], faces: NDArray[np.int64], shape: tuple[int, int]) -> tuple[
        NDArray[np.float64], NDArray[np.int64]]:
    """(vertices, faces) of ``patch``'s grid mesh (``shape``: its sampled rows x columns, :func:`grid_faces`'
    order) with each border triangle on ``side`` whose edge has ``finer`` patches' border nodes between its ends split
    at them (a fan from its opposite vertex, winding kept): the extra vertices at the floats the finer patches give
    their stitched nodes (:func:`_stitched` onto this patch's edge, x and y as :func:`paint_with_textures` places a
    grid node), so the meshes welded by exact position share every border edge. A triangle with a nodata corner
    (dropped afterwards) or a finer node with nodata (the finer patch draws no face at it) is not split there."""
    profile, own = _border(terrain.heights, patch, side)
    span = patch.cols if side < 2 else patch.rows
    at = np.unique(np.concatenate([_samples(*(f.cols if side < 2 else f.rows), f.stride) for f in finer]))
    at = at[(at > span[0]) & (at < span[1]) & ~np.isin(at, own)]
    if not len(at):
        return vertices, faces
    z = _stitched(profile, at, span, patch.stride, profile[at].astype(np.float64))
    at, z = at[np.isfinite(z)], z[np.isfinite(z)]
    line = (patch.rows + patch.cols)[side]
    ii, jj = (np.full(len(at), line, np.intp), at) if side < 2 else (at, np.full(len(at), line, np.intp))
    dx, dy = terrain.spacing
    extra = np.column_stack([terrain.origin[0] + jj * dx, terrain.origin[1] + ii * dy, z])
    first = len(vertices)
    vertices = np.concatenate([vertices, extra])
    n_rows, n_cols = shape
    cells = n_cols - 1
    faces = faces.copy()
    new_faces = [faces]
    for k in range(len(own) - 1):
        inside = np.flatnonzero((at > own[k]) & (at < own[k + 1]))
        if not len(inside):
            continue
        if side < 2:  # grid_faces: cell (i, j) is faces 2 (i * cells + j) + 0 (n00 n01 n11) and + 1 (n00 n11 n10)
            i = 0 if side == 0 else n_rows - 1
            a, b = i * n_cols + k, i * n_cols + k + 1
            f = 2 * ((0 if side == 0 else n_rows - 2) * cells + k) + (side == 1)
        else:
            j = 0 if side == 2 else n_cols - 1
            a, b = k * n_cols + j, (k + 1) * n_cols + j
            f = 2 * (k * cells + (0 if side == 2 else n_cols - 2)) + (side == 2)
        tri = [int(v) for v in faces[f]]
        if a not in tri or b not in tri:
            # a corner cell (or a one-cell patch) split at another side already, by this call or an earlier side's:
            # a fan piece holds the edge, among all the faces so far
            faces = np.concatenate(new_faces)
            new_faces = [faces]
            hit = np.flatnonzero((faces == a).any(axis=1) & (faces == b).any(axis=1))
            if not len(hit):
                continue
            f = int(hit[0])
            tri = [int(v) for v in faces[f]]
        if not np.isfinite(vertices[tri, 2]).all():
            continue
        w = next(v for v in tri if v not in (a, b))
        turn = tri.index(w)
        u, v = tri[(turn + 1) % 3], tri[(turn + 2) % 3]  # the border edge in the face's winding
        mid = list(first + inside) if u == a else list(first + inside[::-1])
        chain = [u, *mid, v]
        fan = np.array([[chain[m], chain[m + 1], w] for m in range(len(chain) - 1)], dtype=faces.dtype)
        faces[f] = fan[0]
        new_faces.append(fan[1:])
    return vertices, np.concatenate(new_faces)


def _root_of(patch: GeometryPatch) -> GeometryPatch:
    while patch.parent is not None:
        patch = patch.parent
    return patch


def _stitched(profile: NDArray[Any], at: NDArray[np.intp], span: tuple[int, int], stride: int,
              z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Heights ``z`` of a patch's border nodes ``at`` (grid indices along the border line, whose terrain heights are
    ``profile``) with each node between two of the coarser neighbour's (:func:`_samples` of ``span`` at ``stride``)
    moved onto that neighbour's edge: linear between its two ends' heights. The same arithmetic in every patch, so two
    finer patches meeting on the coarse edge move their common corner to the same float. A node with nodata, or on an
    edge with a nodata end (the coarse patch draws no face there), keeps its height."""
    coarse = _samples(span[0], span[1], stride)
    k = np.clip(np.searchsorted(coarse, at), 1, len(coarse) - 1)
    a, b = coarse[k - 1], coarse[k]
    between = (at > a) & (at < b)
    za, zb = profile[a].astype(np.float64), profile[b].astype(np.float64)
    moved = za + (zb - za) * ((at - a) / np.maximum(b - a, 1))
    return np.where(between & np.isfinite(za) & np.isfinite(zb) & np.isfinite(z), moved, z)


def _border(heights: NDArray[Any], patch: GeometryPatch, side: int) -> tuple[NDArray[Any], NDArray[np.intp]]:
    """(the terrain's heights along the grid line of ``patch``'s ``side``, the patch's nodes on it), for
    :func:`_stitched`."""
    (r0, r1), (c0, c1) = patch.rows, patch.cols
    if side < 2:
        return heights[r0 if side == 0 else r1, :], _samples(c0, c1, patch.stride)
    return heights[:, c0 if side == 2 else c1], _samples(r0, r1, patch.stride)


def _seam_error(heights: NDArray[Any], patch: GeometryPatch, side: int, span: tuple[int, int], stride: int) -> float:
    """The largest vertical distance :func:`_stitched` moves ``patch``'s nodes on ``side`` by onto the edges of a
    coarser neighbour over ``span`` at ``stride`` (0 where none moves)."""
    profile, at = _border(heights, patch, side)
    z = profile[at].astype(np.float64)
    moved = np.abs(_stitched(profile, at, span, stride, z) - z)
    return float(np.nanmax(moved)) if np.isfinite(moved).any() else 0.0


def _tree_of(item: DrawItem, layer: int) -> TextureTree | None:
    if not isinstance(item, DrawItem):
        raise InvalidInputError(f"item must be a DrawItem (from render_with_textures); got {type(item).__name__}")
    if isinstance(layer, bool) or not isinstance(layer, (int, np.integer)) or not 0 <= layer < len(item.textures):
        raise InvalidInputError(f"layer must index the item's {counted(len(item.textures), 'texture layer')}; got "
                                f"{layer}")
    texture = item.textures[layer]
    return None if texture is None else texture.tree
