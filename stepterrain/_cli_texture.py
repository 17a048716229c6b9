"""The ``stepterrain texture`` subcommand: a topographic texture (hillshade, shadows, occlusion) of a DEM, optionally
modulated with a hypsometric thematic layer, written as PNG or GeoTIFF and draped on a mesh (paper 004 §3.2.3, §7).

    stepterrain texture --shadows -o out/texture.png --mesh out/textured.glb --png out/render.png
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .cli import (
    Progress,
    _add_camera,
    _add_device,
    _add_input_options,
    _check_output,
    _check_outputs,
    _check_side_files,
    _check_size,
    _colormap,
    _counted,
    _floats,
    _given,
    _input_metadata,
    _input_terrain,
    _mesh_and_png,
    _path,
    _real,
    _refuse_degrees,
    _refuse_unused,
    _size,
    _surface_size,
    _whole,
    _window,
)
from .errors import DataFileError, InvalidInputError, MissingDependencyError
from .export import IMAGE_EXTENSIONS, MESH_EXTENSIONS
from .terrain import finite_number

_EPILOG = """\
examples:
  stepterrain texture --shadows -o out/texture.png
      hillshade (GDAL conventions, light from 315 deg at 45 deg) with self-shadowing, hypsometric colours
  stepterrain texture dem.tif --hillshade multidirectional --colormap none -o shade.png
  stepterrain texture dem.tif --shadows -o shade.tif
      a GeoTIFF on the DEM's own pixel grid and CRS (a DEM in degrees: an equirectangular CRS in metres that
      reprojects exactly onto its degrees): it lies exactly over the DEM in QGIS or ArcGIS
  stepterrain texture --shadows --occlusion 0.5 --azimuth 270 --altitude 20 -o low_sun.png
  stepterrain texture --shadows -o tex.png --mesh out/steps.glb --interval 100 --png out/steps.png
      the texture draped on the stepped terrain (100 m steps), GLB with the image embedded, and a render, lit so
      the terraces read, a level face in the texture's own colour (--lighting relief; off: the texture's shading
      alone; on: as steps --png lights its own, the hillshade shaded twice)
  stepterrain texture --shadows --interval 100 --png out/steps.png
      the render alone: no -o, no texture file (--mesh alone likewise writes only the draped mesh)
  stepterrain texture --shadows --png out/map.png --camera top
      the render seen straight down, north up (--camera AZ,EL: from azimuth AZ, EL degrees up)
  stepterrain texture --shadows --contours 100 -o topo.png
      contour lines every 100 m (every 5th, from 0 m, an index line: twice as wide, darker) over the shaded colours
  stepterrain texture --contours 50 --contour-width 1.5 --contour-color 0.2,0.2,0.2 --contour-index 0 -o c.png
  stepterrain texture --normals normals.png -o shade.png
      also the normals encoded as RGB (relight them later without recomputing, paper 004 §7.4)
  stepterrain texture dem.tif --image ortho.tif --colormap none --shadows -o draped.tif --mesh out/ortho.glb
      your own orthophoto (a GeoTIFF in the DEM's CRS, placed by its georeferencing) shaded by the hillshade and
      shadows, on the DEM's grid and draped on the mesh
  stepterrain texture dem.tif --image ortho.jpg -o draped.png
      a JPEG placed by the world file beside it (ortho.jgw; its CRS from ortho.prj, else taken as the DEM's)
  stepterrain texture dem.npy --spacing 30 --image map.png --image-extent=0,1500,-1200,0 -o tex.png --png out/map.png
      a PNG without georeferencing, its outer pixel edges at x 0..1500, y -1200..0 in the DEM's coordinates
      (an .npy's node (0, 0) is its north-west corner at (0, 0): its rows run south)
  stepterrain texture dem.tif --image ortho.tif --hillshade none -o ortho.png --mesh out/ortho.glb
      the orthophoto as it is (its own light), no hillshade over it
  stepterrain texture dem.tif --image ortho.tif --texel-size 0.5 -o out/ortho_05m.tif --mesh out/ortho.glb
      a texture of 0.5 m texels over the (say 30 m) DEM: the orthophoto's detail kept in the GeoTIFF (on that finer
      grid, exactly over the DEM) and the GLB, the hillshade interpolated onto it; for a DEM up to 8 km across (a
      --mesh takes 16384 texels a side at most): --crop a larger one, or give a larger --texel-size
"""


def add_parser(commands: Any) -> None:
    p = commands.add_parser(
        "texture",
        help="topographic textures: hillshade, self-shadowing, thematic layers, draping (paper 004)",
        description="Compute a topographic texture of a DEM in Warp (Horn hillshade as gdaldem defines it, "
                    "sweep-line self-shadowing, horizon-based ambient occlusion), modulate it with a "
                    "hypsometric thematic layer, write it as PNG or GeoTIFF and optionally drape it on a mesh "
                    "(Döllner, Baumann & Hinrichs 2000). Give -o, --mesh, --png or several (--png alone writes only "
                    "the render of the draped texture, --mesh alone only the draped mesh).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_input_options(p)
    p.add_argument("--hillshade", "--method", dest="method", default="standard", metavar="METHOD",
                   choices=("standard", "multidirectional", "combined", "igor", "none"),
                   help="hillshade variant as gdaldem defines it: standard, multidirectional, combined, igor (default "
                        "standard; MapLibre's shaders are in the Python API only, method='maplibre-...'), or none: "
                        "no hillshade, every node fully lit (an orthophoto's own light kept), --shadows and "
                        "--occlusion still darken")
    p.add_argument("--azimuth", type=_real, default=None, metavar="DEG",
                   help="light azimuth, degrees clockwise from north (default 315); multidirectional shades by its "
                        "four fixed lights and --hillshade none by none, so there it aims --shadows only (refused "
                        "without them)")
    p.add_argument("--altitude", type=_real, default=None, metavar="DEG",
                   help="light altitude above the horizon in [0, 90] degrees (default 45); igor and --hillshade "
                        "none ignore it, so there it aims --shadows only (refused without them)")
    p.add_argument("--z-factor", type=_real, default=None, metavar="Z",
                   help="vertical exaggeration of the shading (default 1); with --hillshade none only with --shadows, "
                        "--occlusion or --normals, which use the relief")
    p.add_argument("--shadows", action="store_true",
                   help="self-shadowing by the full-resolution terrain (default off; the library's topographic_layer "
                        "casts them by default, shadows=True)")
    p.add_argument("--shadow-strength", type=_real, default=None, metavar="S",
                   help="with --shadows: how much a shadow darkens, in [0, 1] (default 0.6)")
    p.add_argument("--occlusion", type=_real, default=0.0, metavar="W",
                   help="weight in [0, 1] of horizon-based ambient occlusion (default 0: off)")
    p.add_argument("--colormap", default="terrain", metavar="NAME",
                   help="matplotlib colormap of the hypsometric thematic layer, or 'none' (default terrain)")
    p.add_argument("--image", type=_path, metavar="PATH",
                   help="your own image (an orthophoto, a map) as the thematic layer, laid over the --colormap's "
                        "colours (or, with --colormap none, over plain white) and shaded by the hillshade, --shadows "
                        "and --occlusion as the colours are; where it is transparent (alpha, a GeoTIFF's nodata) or "
                        "outside it those show. A GeoTIFF, or a JPEG or PNG with a world file beside it (.jgw, .pgw, "
                        ".wld; its CRS from a .prj or .aux.xml beside it), is placed by its georeferencing: in the "
                        "DEM's CRS (one without a CRS is taken in the DEM's CRS, refused over a DEM in degrees), or "
                        "in degrees over a DEM in degrees (another CRS is refused: gdalwarp it first; one off the DEM "
                        "is refused, one covering under 10%% of it warned of); resampled to the DEM's grid (or "
                        "--texel-size's) through an image pyramid (the decoded image is checked "
                        "against --memory-budget; of a GeoTIFF or PNG, only its window over the DEM is read and "
                        "checked)")
    p.add_argument("--image-extent", type=_floats(4, "xmin,xmax,ymin,ymax"), metavar="xmin,xmax,ymin,ymax",
                   help="with --image: the outer edges of its pixels in the DEM's coordinates (those `stepterrain "
                        "info` prints, as --crop takes them; a geographic DEM's local metres); needed for an image "
                        "without georeferencing (PNG, JPEG without a world file, a TIFF without a geotransform); for "
                        "a georeferenced image it replaces the georeferencing")
    p.add_argument("--texel-size", type=_real, metavar="M",
                   help="metres (the DEM's units) per texel of the texture, for -o, --mesh and --png alike (default: "
                        "the DEM's node spacing, one texel per node); finer keeps an --image's detail (a 0.5 m "
                        "orthophoto on a 30 m DEM: --texel-size 0.5), the hillshade, shadows and colours "
                        "interpolated onto it; the DEM's extent in whole texels no larger than M (a GeoTIFF -o on that "
                        "finer grid, exactly over the DEM). No larger than the node spacing (the smaller of a "
                        "geographic DEM's x and y spacings: the texture no coarser than the DEM either way); the "
                        "texture is checked against --memory-budget, and a textured --mesh or --png refuses more than "
                        f"{_GPU_TEXTURE_LIMIT} texels a side (the largest texture GPUs load); --normals stay on the "
                        "DEM's grid")
    p.add_argument("--contours", type=_real, metavar="M",
                   help="contour lines every M height units (levels 0, M, 2M, ...), drawn last, over the shaded "
                        "colours and --image (unshaded, as on a topographic map), anti-aliased, their width in texels "
                        "of the texture (on --texel-size's grid too); not over the DEM's nodata. Heights in a named "
                        "unit (the file's, or --height-unit ft) are metres once loaded, so M then counts metres")
    p.add_argument("--contour-width", type=_real, default=None, metavar="TEXELS",
                   help="with --contours: line width in texels (default 1); index lines are twice as wide")
    p.add_argument("--contour-color", type=_floats(None, "r,g,b or r,g,b,a in [0, 1]"), default=None,
                   metavar="R,G,B", help="with --contours: line colour, r,g,b (or r,g,b,a) in [0, 1] (default "
                                         "0.55,0.32,0.14, a map's contour brown); index lines 30%% darker")
    p.add_argument("--contour-index", type=_whole, default=None, metavar="N",
                   help="with --contours: every Nth line (0, N x M, 2N x M, ... in height) is an index line, twice as "
                        "wide and darker (default 5; 0: none)")
    p.add_argument("--normals", type=_path, metavar="OUT.png", help="also write the normals encoded as RGB "
                   "(.png, or .tif: a GeoTIFF; RGBA, alpha 0 at nodata, for a DEM with nodata)")
    _add_device(p)
    p.add_argument("-o", "--output", type=_path, metavar="OUT.png",
                   help="the texture as PNG, or as a GeoTIFF (.tif, .tiff: georeferenced on the DEM's pixel grid and "
                        "CRS; needs rasterio, pip install 'stepterrain[geo]'); RGBA with alpha 0 at nodata for a DEM "
                        "with nodata, else RGB; optional with --mesh or --png (a run without it writes no texture "
                        "file)")
    p.add_argument("--mesh", type=_path, metavar="OUT", help="drape the texture on a mesh; format by extension: "
                   + " ".join(MESH_EXTENSIONS) + " (GLB/glTF embed the image, OBJ writes it beside; .ply and .3mf "
                   "hold no texture: the texture's colour at each vertex instead; .stl, which holds no colours, is "
                   "refused)")
    p.add_argument("--interval", type=_real, metavar="M",
                   help="with --mesh/--png: drape on the stepped terrain with this step interval (default: the "
                        "continuous heightfield)")
    p.add_argument("--png", type=_path, metavar="OUT.png",
                   help="write an off-screen render of the draped mesh (beside -o and --mesh, or alone: a render-only "
                        "run)")
    p.add_argument("--size", type=_window, default=None, metavar="WxH",
                   help="render size, with --png (default 1280x800)")
    p.add_argument("--z-scale", type=_real, default=None, metavar="S",
                   help="vertical exaggeration of the render only, with --png (default 2)")
    _add_camera(p, "the render of the draped mesh, with --png")
    p.add_argument("--lighting", choices=("auto", "on", "off", "relief"), default=None,
                   help="light the render's mesh, with --png, as steps --png lights its render (key light from the "
                        "north-west, fill from the camera): on, off (the texture as it is, its own shading alone), "
                        "relief (the same lights, a level face in the texture's own colour: the relief the texture's "
                        "shading does not show), or auto (default): relief for the stepped terrain (--interval) under "
                        "a hillshade, shadows or occlusion (they shade the DEM's slopes, not its terraces and walls; "
                        "on, they were shaded twice, darker), on for it without them and for --hillshade none "
                        "without --image (no shading in the texture), off for the heightfield under a hillshade or an "
                        "orthophoto, which would be shaded twice")
    p.set_defaults(run=_run_texture)


#: The largest texture a side that GPUs load (OpenGL's GL_MAX_TEXTURE_SIZE on current desktop GPUs, WebGL2 and
#: glTF viewers often less): a finer --texel-size texture for a textured --mesh or a --png render is refused above it.
_GPU_TEXTURE_LIMIT = 16384

#: Bytes per texel of a --texel-size texture while it is composed and written: the image's float32 RGBA where it is
#: resampled (16 bytes a pixel, at about the texel size), the uint8 texture (composed in one pass, no float32 layers on
#: its grid) and its copies for the file, the drape and the render (Pillow keeps RGB as 4 bytes a pixel); measured
#: 30 (-o) and 42 (with --mesh) on Big Tujunga at 7 m, 14 M texels.
_COMPOSE_BYTES_PER_TEXEL = 48

def _check_texel_size(terrain: Any, texel: float, textured_gpu: str | None,
                      contours: bool = False) -> tuple[Any, tuple[int, int]]:
    """``--texel-size`` once the DEM is loaded, before any work: no coarser than its node spacing, its texture within
    the memory budget (with ``contours``, their float32 RGBA layer too) and, for a textured mesh or a render
    (``textured_gpu`` names it), a GPU's texture size."""
    from ._compaction import check_budget
    from .io import _lonlat_grid
    from .texture import (  # the grid contour_layer draws on
        _CONTOUR_TEXEL_BYTES,
        _coarser_than_nodes,
        _texel_grid,
        _texels,
    )

    sx, sy = abs(float(terrain.spacing[0])), abs(float(terrain.spacing[1]))
    # square texels no coarser than the nodes either way: a geographic DEM's x and y spacings differ, and a texel of
    # the larger made the texture coarser than the DEM along the other
    spacing = _coarser_than_nodes(terrain, texel)
    if spacing is not None:
        shown = f"{spacing:g}" if sx == sy else f"{spacing:g}, the smaller of its {sx:g} x {sy:g}"
        raise InvalidInputError(f"--texel-size must be no larger than the DEM's node spacing ({shown}; the default is "
                                f"one texel per node): it makes the texture finer; got --texel-size {texel:g}")
    larger = "give a larger --texel-size (or --crop the DEM)"
    if _lonlat_grid(terrain) is not None:  # a size in degrees is the likely mistake
        larger = (f"give a larger --texel-size, in metres: a DEM in degrees is read as local metres (its node spacing "
                  f"{sx:g} x {sy:g} m), not in degrees (or --crop the DEM)")
    extent, (rows, cols) = _texel_grid(terrain, texel, "--texel-size")
    check_budget((_COMPOSE_BYTES_PER_TEXEL + (_CONTOUR_TEXEL_BYTES if contours else 0)) * rows * cols,
                 f"the {_texels(cols)} x {_texels(rows)} texel texture of --texel-size {texel:g} (while it is "
                 "composed and written)", hint=larger)
    if textured_gpu is not None and max(rows, cols) > _GPU_TEXTURE_LIMIT:
        raise InvalidInputError(f"--texel-size {texel:g} makes a {_texels(cols)} x {_texels(rows)} texel texture, "
                                f"over the {_GPU_TEXTURE_LIMIT} texels a side GPUs load as one texture, for "
                                f"{textured_gpu}: {larger}, or write the texture with -o alone")
    return extent, (rows, cols)


def _check_node_texture(terrain: Any) -> None:
    """The texture of one texel per DEM node (no ``--texel-size``) once the DEM is loaded, before any work: its
    layers' RGBA, which the compose reads (:meth:`~stepterrain.texture.TextureLayer.rgba`, checked there against the
    memory budget as its largest piece), within the budget. A DEM within the budget whose texture was not was refused
    only once its hillshade, shadows and occlusion had been computed (minutes on a large DEM)."""
    from ._compaction import check_budget
    from .texture import _RGBA_BYTES

    rows, cols = terrain.shape
    check_budget(_RGBA_BYTES * rows * cols, f"the {cols} x {rows} texel texture (one texel per DEM node, while it is "
                 "composed)", hint="give --coarsen N or a --crop")


def _check_shading(terrain: Any, occlusion: bool) -> None:
    """The topographic layer's working memory (:data:`~stepterrain.texture._NODE_BYTES`, one texel per DEM node
    whatever ``--texel-size``), checked as :func:`~stepterrain.texture.topographic_layer` checks it, once the DEM is
    loaded: with ``--occlusion`` it takes more than the texture's RGBA that :func:`_check_node_texture` counts."""
    from .texture import _check_topographic

    _check_topographic(terrain, occlusion)


def _is_tiff(path: Path | None) -> bool:
    return path is not None and path.suffix.lower() in (".tif", ".tiff")


def _georeference(path: Path, extent: Any, crs: str | None) -> dict[str, Any]:
    """``save_image``'s extent and CRS for a TIFF output (a GeoTIFF over the DEM), nothing for a PNG."""
    return {"extent": extent, "crs": crs} if _is_tiff(path) else {}


def _hypsometric(terrain: Any, name: str) -> np.ndarray | None:
    found = _colormap(name)
    if found is None:
        return None
    cmap, lo_frac, hi_frac = found
    heights = terrain.heights
    finite = np.isfinite(heights)
    lo, hi = terrain.finite_height_range  # computed once per terrain (the texture's relief check asked already)
    scaled = np.clip((heights - lo) / max(hi - lo, 1e-12), 0, 1)
    rgba = cmap(lo_frac + (hi_frac - lo_frac) * np.where(finite, scaled, 0.0)).astype(np.float32)
    rgba[~finite, 3] = 0.0
    return rgba


def _check_unshaded(args: argparse.Namespace) -> None:
    """``--hillshade none`` before any work: an option only the hillshade uses is refused (the texture came out the
    same whatever it was), and a texture of nothing at all (plain white) too."""
    if not args.shadows:
        for option, value in (("--azimuth", args.azimuth), ("--altitude", args.altitude)):
            if value is not None:
                raise InvalidInputError(f"{option} has no effect with --hillshade none (no light shades the "
                                        f"terrain); it aims --shadows only; got {option} {value:g} without --shadows")
    if args.z_factor is not None and not (args.shadows or args.occlusion > 0 or args.normals):
        raise InvalidInputError(f"--z-factor has no effect with --hillshade none unless --shadows, --occlusion or "
                                f"--normals use the relief; got --z-factor {args.z_factor:g}")
    if (args.colormap.lower() == "none" and args.image is None and not args.shadows
            and not args.occlusion > 0 and args.contours is None):
        raise InvalidInputError("--hillshade none with --colormap none and no --image, --shadows, --occlusion or "
                                "--contours leaves nothing to draw (a plain white texture); give one of them")


def _check_image(path: str | None, extent: tuple[float, ...] | None) -> tuple[int, int] | None:
    """``--image`` and ``--image-extent`` before any work: the file exists and, without an extent, places itself (a
    georeferenced GeoTIFF, a JPEG or PNG with a world file) north-up (a rotated or south-up one was refused only once
    the DEM was loaded); an image without georeferencing would lie at x 0..W, y 0..H, one unit per pixel. The file
    is opened once (with GDAL, and Pillow reads the header of one GDAL finds no georeferencing in). With an extent,
    the image's (width, height) from its header, for :func:`_refuse_gdal_image_extent` (None where Pillow cannot
    read it)."""
    from .texture import _check_extent
    from .texture_lod import _georeferenced_extent, _georeferencing, _read_tiff, _tiff_as_stored, _world_file_hint

    if path is None:
        if extent is not None:
            raise InvalidInputError("--image-extent applies only with --image")
        return None
    file = Path(path)
    if file.is_dir():
        raise DataFileError(f"--image {path!r} is a folder; expected an image file")
    if not file.is_file():
        raise DataFileError(f"--image {path!r} does not exist")
    if extent is not None:
        _check_extent(extent, "--image-extent")
        from PIL import Image

        try:  # the header only
            with Image.open(file) as image:
                _tiff_as_stored(image)  # a TIFF's size as stored (drawn so), not as its Orientation tag turns it
                return image.size
        except Exception:  # noqa: BLE001 - a TIFF only GDAL reads: left to image_layer, unchecked
            return None
    found = _read_tiff(file, _georeferencing, any_format=True)  # as ImagePyramid.build reads it; None: GDAL cannot
    if found is not None and not found[0].is_identity:
        try:  # a rotated, south-up or east-to-west geotransform is refused as the pyramid's build refuses it
            _georeferenced_extent(file, found)
        except InvalidInputError as exc:
            raise InvalidInputError(f"--image {path!r}: {exc}") from None
        return None
    from PIL import Image

    try:  # the header only: a file that is no image is named so, not asked for an extent
        with Image.open(file):
            pass
    except Exception as exc:  # noqa: BLE001 - Pillow's many refusals (a TIFF only GDAL reads is an image too)
        if found is None or not _is_tiff(file):
            raise DataFileError(f"--image {path!r}: cannot read it as an image ({exc})") from exc
    raise InvalidInputError(f"--image {path!r} carries no georeferencing (a PNG or JPEG without a world file "
                            "(.pgw, .jgw, .wld) beside it, or a TIFF without a geotransform): "
                            f"{_world_file_hint(file)}, or give --image-extent xmin,xmax,ymin,ymax, the outer edges "
                            "of its pixels in the DEM's coordinates")


def _refuse_gdal_image_extent(terrain: Any, extent: tuple[float, ...], size: tuple[int, int]) -> None:
    """An ``--image-extent`` in GDAL's order (-te and rasterio's bounds: xmin,ymin,xmax,ymax) is refused, with the
    numbers in ours (xmin,xmax,ymin,ymax), where the same numbers in GDAL's order make a box over the DEM with
    nearly square pixels (within 2x) while as given its pixels are over 20 times longer one way than the other, or
    it spans more than 10 times the DEM's width and height (projected bounds: an easting to a northing, each way):
    the DEM took a pixel or two of the image, smeared over it. ``size``: the image's (width, height)."""
    x0, x1, y0, y1 = (float(v) for v in extent)
    width, height = size
    ex0, ex1, ey0, ey1 = terrain.extent
    if not (x0 < y0 and x1 < y1):  # the numbers in GDAL's order make no box
        return
    if not (min(y0, ex1) > max(x0, ex0) and min(y1, ey1) > max(x1, ey0)):  # nor one over the DEM
        return

    def aspect(dx: float, dy: float) -> float:  # of a pixel, >= 1
        return max(dx / width, dy / height) / min(dx / width, dy / height)

    if aspect(y0 - x0, y1 - x1) > 2:
        return
    if aspect(x1 - x0, y1 - y0) > 20 or (x1 - x0 > 10 * (ex1 - ex0) and y1 - y0 > 10 * (ey1 - ey0)):
        raise InvalidInputError(
            f"--image-extent={x0:.10g},{x1:.10g},{y0:.10g},{y1:.10g} puts the {width} x {height} pixel image "
            f"{x1 - x0:.6g} x {y1 - y0:.6g} units over the DEM's {ex1 - ex0:.6g} x {ey1 - ey0:.6g} (its extent "
            f"{tuple(round(v, 2) for v in terrain.extent)}): its numbers are xmin,xmax,ymin,ymax, not GDAL's -te "
            f"xmin,ymin,xmax,ymax; in this order that box is --image-extent={x0:.10g},{y0:.10g},{x1:.10g},{y1:.10g}")


def _texture_colours(draped: Any) -> Any:
    """The draped mesh with its texture's colour at each vertex (the texel its UV falls in) as vertex colours, for
    the formats that keep vertex colours but no texture (.ply, .3mf): they dropped the texture, and wrote the mesh
    without any colour."""
    import trimesh

    picture = np.asarray(draped.visual.material.baseColorTexture.convert("RGB"))
    rows, cols = picture.shape[:2]
    uv = np.asarray(draped.visual.uv, dtype=np.float64)  # texel centres at ((j + 0.5) / cols, 1 - (i + 0.5) / rows)
    j = np.clip(np.floor(uv[:, 0] * cols), 0, cols - 1).astype(np.intp)
    i = np.clip(np.floor((1.0 - uv[:, 1]) * rows), 0, rows - 1).astype(np.intp)
    out = trimesh.Trimesh(np.asarray(draped.vertices), np.asarray(draped.faces), process=False,
                          metadata=dict(draped.metadata), vertex_colors=picture[i, j])
    out.face_attributes = dict(draped.face_attributes)
    return out


def _render_lit(args: argparse.Namespace) -> bool | str:
    """How ``--png`` lights the draped mesh (render_textured_mesh's ``lighting``): ``--lighting on``/``off``/``relief``,
    or for ``auto`` what the texture lacks of the shading of the surface shown. A hillshade shades the DEM's
    continuous slopes (paper 004 §7: a topographic texture carries its shading), so lighting the heightfield under it
    shaded it twice; on the stepped terrain (``--interval``) the flat terraces and their walls bore the slopes'
    hillshade, unlit, and read as one smooth surface: the steps showed only at the silhouette. Lit fully, that
    hillshade was shaded twice all the same (terraces at 0.87 of the texture, walls facing the camera 0.55): "relief"
    lights the steps with a level face in the texture's own colour. ``--hillshade none`` without ``--image`` leaves
    the colours unshaded; an orthophoto keeps its own light."""
    if args.lighting != "auto":
        return {"on": True, "off": False, "relief": "relief"}[args.lighting]
    if args.interval is not None:
        shaded = args.method != "none" or args.shadows or args.occlusion > 0
        return "relief" if shaded else True
    return args.method == "none" and args.image is None


#: The material of the --mesh drape (its name names a textured OBJ's image: ``<stem>_terrain_texture.png``).
_DRAPE_MATERIAL = "terrain texture"


def _drape_stand_in() -> Any:
    """A one-triangle mesh draped as the --mesh is (:func:`~stepterrain.texture._draped`, the material
    :data:`_DRAPE_MATERIAL`, an RGB image): its side files are named as the --mesh's will be."""
    import trimesh

    from . import texture as tx

    pixels = np.zeros((2, 2, 3), np.uint8)
    layer = tx.TextureLayer("thematic", pixels, (0.0, 1.0, 0.0, 1.0), name="texture")
    triangle = trimesh.Trimesh([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[0, 1, 2]], process=False)
    return tx._draped(triangle, layer, pixels, np.ones(3), _DRAPE_MATERIAL)


def _contour_options(args: argparse.Namespace) -> dict[str, Any] | None:
    """``--contours`` and its options as :func:`~stepterrain.texture.contour_layer`'s keywords, checked before any
    work (the library's errors renamed to the options); None without --contours, whose options are then refused
    (they drew nothing)."""
    from .texture import _contour_colour

    given = {"--contour-width": args.contour_width, "--contour-color": args.contour_color,
             "--contour-index": args.contour_index}
    if args.contours is None:
        for option, value in given.items():
            if value is not None:
                raise InvalidInputError(f"{option} applies only with --contours (the contour interval)")
        return None
    if not (math.isfinite(args.contours) and args.contours > 0):
        raise InvalidInputError(f"--contours must be a positive contour interval (the DEM's height units); got "
                                f"{args.contours:g}")
    options: dict[str, Any] = {"interval": args.contours}
    if args.contour_width is not None:
        if not (math.isfinite(args.contour_width) and args.contour_width > 0):
            raise InvalidInputError(f"--contour-width must be a positive number of texels; got {args.contour_width:g}")
        options["width"] = args.contour_width
    if args.contour_color is not None:
        shown = ",".join(f"{v:g}" for v in args.contour_color)
        try:
            _contour_colour(args.contour_color, "--contour-color")
        except InvalidInputError as exc:
            raise InvalidInputError(f"{str(exc).split('; got')[0]}; got {shown}") from None
        if len(args.contour_color) == 4 and args.contour_color[3] == 0:  # index lines take its alpha too: no line
            raise InvalidInputError(f"--contour-color must have an alpha above 0 (0 draws every contour line "
                                    f"transparent: the texture as without --contours); got {shown}")
        options["color"] = args.contour_color
    if args.contour_index is not None:
        if not 0 <= args.contour_index <= np.iinfo(np.int32).max:  # contour_layer's bound, by the option's name
            raise InvalidInputError(f"--contour-index must be 0 (no index lines) or more, below 2**31; got "
                                    f"{args.contour_index}")
        options["index_every"] = args.contour_index
    return options


def _texture_metadata(args: argparse.Namespace, contours: dict[str, Any] | None,
                      grid: tuple[Any, tuple[int, int]]) -> dict[str, Any]:
    """The options that shaped the texture, with the values it was made with (defaults included), for the draped
    mesh's metadata beside ``method`` and the light's angles: ``--z-factor`` where the relief was shaded (a hillshade,
    ``--shadows``, ``--occlusion``), ``--shadow-strength`` with ``--shadows``, ``--occlusion`` and ``--colormap`` (the
    colormap's name, or 'none'), ``--image`` with ``--image-extent`` where one placed it, ``--texel-size`` as given
    (``texel_size``, a number, where it was given) and ``texel_size_used``, the texel size of the texture's ``grid``
    (extent, (rows, cols)) in x and y (``--texel-size`` cut the extent into whole texels no larger than it; one texel
    per node without it), and ``--contours`` with the width, colour and index lines drawn. They were left out (a
    texture shaded by z 3 and occlusion 0.5 recorded as one of the defaults)."""
    metadata: dict[str, Any] = {"shadows": bool(args.shadows)}
    if args.method != "none" or args.shadows or args.occlusion > 0:  # (--hillshade none alone: no relief used)
        metadata["z_factor"] = float(args.z_factor)
    if args.shadows:
        metadata["shadow_strength"] = float(args.shadow_strength)
    metadata["occlusion"] = float(args.occlusion)
    found = _colormap(args.colormap)  # None for 'none', as _hypsometric colours nothing
    metadata["colormap"] = found[0].name if found is not None else "none"
    if args.image is not None:
        metadata["image"] = str(args.image)
        if args.image_extent is not None:
            metadata["image_extent"] = [float(v) for v in args.image_extent]
    if args.texel_size is not None:  # the number given, as recorded before (scripts read it as one)
        metadata["texel_size"] = float(args.texel_size)
    (xmin, xmax, ymin, ymax), (rows, cols) = grid
    metadata["texel_size_used"] = [(xmax - xmin) / cols, (ymax - ymin) / rows]
    if contours is not None:
        import inspect

        from .texture import _contour_colour, contour_layer

        drawn = {name: contours.get(name, parameter.default)  # contour_layer's defaults where an option was not given
                 for name, parameter in inspect.signature(contour_layer).parameters.items()}
        metadata["contours"] = float(drawn["interval"])
        metadata["contour_width"] = float(drawn["width"])
        metadata["contour_color"] = list(_contour_colour(drawn["color"], "--contour-color"))
        metadata["contour_index"] = int(drawn["index_every"])
    return metadata


def _run_texture(args: argparse.Namespace, progress: Progress) -> int:
    from . import export, render
    from . import texture as tx
    from ._device import resolve_device

    # -o, --mesh, --png: any of them (--png alone: a render-only run, no texture file; --mesh alone: the drape only)
    try:
        out, png = _mesh_and_png(args.output, args.png, extensions=IMAGE_EXTENSIONS,
                                 output_is="OUT.png|OUT.tif (the texture)", png_is="a render of the draped texture",
                                 others=[("--mesh", args.mesh, "OUT (the texture draped on a mesh)")])
    except InvalidInputError as exc:  # the normal map is written beside the texture, not in its place: said where
        # none of them was given (not to a bad -o or --png, refused for itself)
        if args.normals is None or any(given is not None for given in (args.output, args.png, args.mesh)):
            raise
        raise InvalidInputError(f"{exc} (--normals {args.normals!r} is written beside them, not alone)") from None
    mesh_out = _check_output(args.mesh, MESH_EXTENSIONS, "--mesh") if args.mesh else None
    if mesh_out is not None and mesh_out.suffix.lower() == ".stl":  # the drape went nowhere: an STL holds no colour
        # (as steps refuses --colormap and globe --texture with an .stl): refused before the DEM is read
        raise InvalidInputError(f"--mesh drapes the texture on a mesh; an .stl --mesh holds no texture or colours: got "
                                f"--mesh {args.mesh!r}; write .glb, .gltf or .obj (the texture) or .ply or .3mf (its "
                                f"colour at each vertex)")
    textured_mesh = mesh_out is not None and mesh_out.suffix.lower() in export._TEXTURED  # they keep a texture
    normals_out = _check_output(args.normals, IMAGE_EXTENSIONS, "--normals") if args.normals else None
    if any(_is_tiff(path) for path in (out, normals_out)) and importlib.util.find_spec("rasterio") is None:
        raise MissingDependencyError("writing a GeoTIFF needs rasterio: pip install 'stepterrain[geo]'")
    _check_outputs({"INPUT": args.input, "--image": args.image}, output=out, mesh=mesh_out, png=png,
                   normals=normals_out)
    if mesh_out is not None:  # a textured OBJ's .mtl and texture image, named as the drape will name them
        _check_side_files("--mesh", mesh_out, export._side_files(_drape_stand_in(), mesh_out),
                          {"INPUT": args.input, "--image": args.image},
                          {"--output": out, "--png": png, "--normals": normals_out})
    image_size = _check_image(args.image, args.image_extent)
    if args.azimuth is not None and not math.isfinite(args.azimuth):  # named by the library as 'azimuth', radians
        raise InvalidInputError(f"--azimuth must be a finite number of degrees; got {args.azimuth}")
    if args.altitude is not None and not (0.0 <= args.altitude <= 90.0):
        raise InvalidInputError(f"--altitude must lie in [0, 90] degrees; got {args.altitude:g}")
    # an option the shading ignores is refused (gdaldem refuses -multidirectional with -az, -igor with -alt): the
    # texture came out the same whatever was given; with --shadows the light still aims the shadows
    ignored = {"multidirectional": ("--azimuth", args.azimuth, "its four fixed lights, from 225, 270, 315 and 360 "
                                                               "degrees"),
               "igor": ("--altitude", args.altitude, "the light's azimuth and the slope alone")}.get(args.method)
    if ignored is not None and ignored[1] is not None and not args.shadows:
        option, value, why = ignored
        raise InvalidInputError(f"{option} has no effect on --hillshade {args.method}, which shades by {why} (as "
                                f"gdaldem -{args.method}); it aims --shadows only; got {option} {value:g} without "
                                "--shadows")
    # topographic_layer's numbers, whatever the DEM, by their options before it is loaded (refused after it)
    for option, value, bounds in (("--z-factor", args.z_factor, {"positive": True}),
                                  ("--shadow-strength", args.shadow_strength, {"lo": 0.0, "hi": 1.0}),
                                  ("--occlusion", args.occlusion, {"lo": 0.0, "hi": 1.0})):
        if value is not None:
            finite_number(value, option, **bounds)
    # a mistyped name was refused only once the DEM was loaded and shaded (shadows, occlusion: minutes on a large one)
    _colormap(args.colormap)
    if args.method == "none":  # no hillshade: what only shapes the hillshade would come out the same whatever it was
        _check_unshaded(args)
    # the library refuses an angle its method ignores, as this does: only the angles given are passed on
    given = {"azimuth": args.azimuth is not None, "altitude": args.altitude is not None}
    args.azimuth = 315.0 if args.azimuth is None else args.azimuth
    args.altitude = 45.0 if args.altitude is None else args.altitude
    if args.shadow_strength is not None and not args.shadows:  # it wrote the texture without shadows, the same
        raise InvalidInputError("--shadow-strength applies only with --shadows")
    args.shadow_strength = 0.6 if args.shadow_strength is None else args.shadow_strength
    args.z_factor = 1.0 if args.z_factor is None else args.z_factor
    if args.interval is not None and mesh_out is None and png is None:
        raise InvalidInputError("--interval applies only with --mesh or --png")
    if args.interval is not None and not (math.isfinite(args.interval) and args.interval > 0):
        raise InvalidInputError(f"--interval must be a positive number; got {args.interval:g}")
    render_options = _given(args, {"size": (1280, 800), "z_scale": 2.0, "camera": "oblique", "lighting": "auto"})
    _check_size(args.size, renders=png is not None)
    if not (math.isfinite(args.z_scale) and args.z_scale > 0):
        raise InvalidInputError(f"--z-scale must be a positive number; got {args.z_scale}")
    if png is None:  # (after their values, which are named first) they shape the render alone, and were ignored
        _refuse_unused(render_options, "--png (the render of the draped mesh)", "without --png")
    if png is not None:
        render.require_offscreen()
    contour_options = _contour_options(args)
    if args.texel_size is not None and not (math.isfinite(args.texel_size) and args.texel_size > 0):
        raise InvalidInputError(f"--texel-size must be a positive number of the DEM's units (metres) per texel; got "
                                f"{args.texel_size:g}")

    progress.stage("load", f"loading {args.input if args.input else 'the embedded Big Tujunga DEM'}")
    terrain = _input_terrain(args)
    progress.done(f"{' x '.join(str(n) for n in terrain.shape)} nodes,")
    device = resolve_device(args.device)
    grid = None  # --texel-size: the texture's (extent, shape), finer than the DEM's nodes
    if args.texel_size is not None:
        textured = [name for name, wanted in (
            (f"--mesh {mesh_out}", textured_mesh),
            ("--png", png is not None)) if wanted]
        grid = _check_texel_size(terrain, args.texel_size, " and ".join(textured) or None,
                                 contours=args.contours is not None)
    else:
        _check_node_texture(terrain)
    _check_shading(terrain, args.occlusion > 0)
    if png is not None:  # the render holds the texture too, one texel per node or --texel-size's, and its copies of
        # the mesh draped: the DEM's surface (at least that, stepped by --interval): before any work
        render._check_render_budget(args.size[0], args.size[1], "--size",
                                    texture=grid[1] if grid is not None else terrain.shape,
                                    smaller_texture="a larger --texel-size (or --crop the DEM)" if grid is not None else
                                    "a smaller texture (one texel per DEM node: --coarsen or --crop the DEM)",
                                    mesh=_surface_size(terrain), at_least=args.interval is not None,
                                    mesh_hint=("give a larger --interval, " if args.interval is not None else "give ")
                                    + "--coarsen N or a --crop, or leave --png out")
    if mesh_out is not None or png is not None:  # what the drape stage refuses of the mesh, known from the DEM: refused
        # there, after the texture's hillshade, shadows and occlusion
        from .stepped import isovalues
        from .terrain import check_heightfield_budget

        if args.interval is not None:  # the isovalues stepped() takes (too many levels), the steps command's check
            isovalues(terrain.height_range, interval=args.interval)
        else:
            check_heightfield_budget(terrain)  # terrain.mesh()'s
    if mesh_out is not None:  # save_mesh's writer: the draped mesh has the DEM's surface at least (exactly, unstepped)
        vertices, faces = _surface_size(terrain)
        export._check_write_counts(vertices, faces, mesh_out.suffix.lower(), mesh_out, textured=textured_mesh,
                                   at_least=args.interval is not None)
    picture = None
    if args.image is not None:
        from .texture_lod import image_layer

        if args.image_extent is not None:
            _refuse_degrees(terrain, args.image_extent, "--image-extent")
            if image_size is not None:
                _refuse_gdal_image_extent(terrain, args.image_extent, image_size)

        progress.stage("image", f"placing {args.image} over the DEM")
        try:
            picture = image_layer(args.image, terrain, extent=args.image_extent, device=device,
                                  texel_size=args.texel_size)
        except InvalidInputError as exc:  # a CRS mismatch, an image off the DEM: named as the option gave it
            raise InvalidInputError(f"--image {args.image!r}: {exc}") from None
        progress.done(f"{picture.shape[1]} x {picture.shape[0]} pixels over the DEM,")

    what = ", ".join([("hillshade " + args.method) if args.method != "none" else "no hillshade"]
                     + (["shadows"] if args.shadows else [])
                     + ([f"occlusion {args.occlusion:g}"] if args.occlusion > 0 else [])
                     + ([f"contours every {args.contours:g}"] if args.contours is not None else []))
    progress.stage("texture", f"topographic texture on {device}: {what}")
    # degrees wrapped into one turn: the library's radians-or-degrees warning (past 4π) is for API callers
    azimuth = math.radians(args.azimuth % 360.0) if given["azimuth"] else None
    altitude = math.radians(args.altitude) if given["altitude"] else None
    # --hillshade none: topographic_layer's method "none" (a shade of 1, darkened by --shadows and --occlusion alone)
    topo = tx.topographic_layer(terrain, azimuth=azimuth, altitude=altitude, z_factor=args.z_factor,
                                method=args.method, shadows=args.shadows,
                                shadow_strength=args.shadow_strength if args.shadows else None,
                                occlusion=args.occlusion, device=device)
    colors = _hypsometric(terrain, args.colormap)
    hypsometric = None if colors is None else tx.terrain_layer(terrain, colors, "thematic", name="hypsometric")
    # the image over the colours (white without), shaded as the colours are (alpha: the shading's, 0 at the DEM's
    # nodata); the layers on the DEM's nodes interpolated onto the --texel-size grid, the image sampled there: one
    # pass writing the uint8 texture (tx._composed), as blend, modulate and to_uint8 compose it
    extent, shape = grid if grid is not None else topo.frame
    # a DEM with nodata: RGBA, alpha 0 over its nodata (white over a white background hid the holes in a GIS, and the
    # normals' (0, 0, 1) there read as flat ground); without nodata RGB as before
    holes = terrain.nodata_mask if terrain.has_nodata else None
    white = np.ones(3)  # drape's default background: the image composed over it, RGB
    # with nodata and a drape, the RGBA and the drape's RGB over white come from one pass (two took twice the time)
    over = white if holes is not None and (mesh_out is not None or png is not None) else None
    image, over_white = tx._composed_pair(topo, hypsometric, picture, extent, shape,
                                          None if holes is not None else white, over, device)
    if contour_options is not None:  # the contour lines last, unshaded, over both textures (as blend lays them)
        # on the composite's grid (both from texture._texel_grid, or the DEM's nodes; _lay_over_uint8 checks the shape)
        lines = tx.contour_layer(terrain, texel_size=args.texel_size, device=device, **contour_options)
        if not lines.image[..., 3].max() > 0:  # (NaN-free: nodata texels hold alpha 0)
            # no level passed within a line's width of a texel's height: the texture came out as without --contours
            # and said nothing. Not refused: a tile no level crosses, in a set textured at one interval, is no
            # mistake, and a level just beyond the heights is drawn (within half a line's width of the edge texels)
            lo, hi = terrain.finite_height_range
            q = lo / args.contours  # the lowest level at or above the heights' minimum (none: 1e-300 past float64)
            level = math.ceil(q) * args.contours if math.isfinite(q) else math.inf
            if level <= hi:  # one within them, on a loop narrower than a texel: a lone summit's node, a DSM's mast
                warnings.warn(f"--contours {args.contours:g} drew no line: its level {level:g}, within the heights "
                              f"{lo:g} to {hi:g}, passes within half a line's width of no texel (a loop narrower than "
                              f"a texel, around a lone peak or pit node); the texture is as without --contours (a "
                              f"wider --contour-width may draw it)", stacklevel=1)
            else:
                hint = "a smaller interval draws lines" if lo < hi else \
                    "flat ground draws a line only exactly on a level"
                warnings.warn(f"--contours {args.contours:g} drew no line: no contour level (a multiple of it) passes "
                              f"within the heights {lo:g} to {hi:g}; the texture is as without --contours ({hint})",
                              stacklevel=1)
        for picture_out in (image, over_white):
            if picture_out is not None:
                tx._lay_over_uint8(picture_out, lines)
        del lines
    composite = tx.TextureLayer("thematic", image, extent, name="texture")  # its grid, for the drape's UVs
    normals = tx.normal_map(terrain, z_factor=args.z_factor, device=device) if normals_out else None
    progress.done(f"{image.shape[1]} x {image.shape[0]} pixels")

    draped = shot = None
    if mesh_out is not None or png is not None:
        import stepterrain as st

        progress.stage("drape", "draping on the " + (f"stepped terrain (interval {args.interval:g})"
                                                     if args.interval is not None else "heightfield"))
        base = (st.stepped(terrain, interval=args.interval, device=device) if args.interval is not None
                else terrain.mesh())
        draped = tx._draped(base, composite, image if over_white is None else over_white, white, _DRAPE_MATERIAL)
        progress.done(f"{_counted(len(draped.faces), 'face')}")
        if len(draped.faces) == 0 and png is None:  # as steps says it (a --png refuses an empty mesh): the --mesh was
            # written empty without a word (a line "0 faces" on the progress only, none with -q)
            warnings.warn("the mesh is empty: no triangle of the input has three finite heights", stacklevel=1)
        if png is not None:
            progress.stage("render", f"rendering {args.size[0]}x{args.size[1]} off-screen")
            shot = render.render_textured_mesh(draped, window_size=args.size, z_scale=args.z_scale,
                                                lighting=_render_lit(args), camera=args.camera)
            progress.done()

    if out is not None:  # no texture file for a run without -o (--mesh or --png alone)
        progress.stage("write", f"writing {out}")
        # the mesh's texture is this image (not over_white's RGB): the mesh takes the PNG's bytes, its pixels hashed
        # for it
        reused = draped is not None and textured_mesh and over_white is None
        export._save_image(image, out, reused=reused, **_georeference(out, composite.extent, terrain.crs))
        progress.done(_size(out))
    if normals is not None:
        if holes is not None:
            normals = np.dstack([normals, np.where(holes, 0, 255).astype(np.uint8)])
        export._save_image(tx._north_up(terrain, normals), normals_out, reused=False,
                           **_georeference(normals_out, tx.terrain_extent(terrain), terrain.crs))
        progress.say(f"wrote {normals_out} ({_size(normals_out)})")
    if draped is not None and mesh_out is not None:
        metadata = {"generator": "stepterrain texture", **_input_metadata(args), "method": args.method}
        # the light's angles only where they shaped the texture: --hillshade none (no shading) recorded the default
        # light 315 / 45, multidirectional (four fixed lights) its azimuth and igor its altitude, none of them used
        # unless --shadows aimed the shadows with them
        if args.shadows or args.method not in ("multidirectional", "none"):
            metadata["azimuth_deg"] = args.azimuth
        if args.shadows or args.method not in ("igor", "none"):
            metadata["altitude_deg"] = args.altitude
        metadata.update(_texture_metadata(args, contour_options, (composite.extent, image.shape[:2])))
        export.save_mesh(draped if textured_mesh else _texture_colours(draped), mesh_out, metadata=metadata)
        progress.say(f"wrote {mesh_out} ({_size(mesh_out)})")
    if shot is not None:
        export._save_image(shot, png, reused=False)
        progress.say(f"wrote {png} ({_size(png)})")
    return 0
