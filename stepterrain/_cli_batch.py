"""``stepterrain batch``: many inputs, one stepped mesh each, on dask.distributed (see :mod:`stepterrain.batch`).

    stepterrain batch dem_tiles/ --interval 50 -o out/
    stepterrain batch big.tif --tile 1024 --interval 100 --scheduler tcp://10.0.0.5:8786 -o out/
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import re
from pathlib import Path
from typing import Any

from .errors import DeviceError, InvalidInputError

_EPILOG = """\
examples:
  stepterrain batch --tile 256 -o out/tiles
      the embedded Big Tujunga DEM cut into 256-cell tiles (shared borders), one .glb each, 2 local workers
  stepterrain batch dem_tiles/ --interval 50 --format .ply -o out/ply
      every DEM file in a folder (.npy .npz .png .tif .asc .hgt .img .bil ..., .hgt.gz; not a .vrt), one PLY each
  stepterrain batch npy_tiles/ --spacing 30 --coarsen 2 --interval 50 -o out/half
      .npy tiles (no georeferencing) of 30 m cells, each averaged to 60 m
  stepterrain batch big.tif --crop 380000,390000,3790000,3800000 --coarsen 4 --tile 256 -o out/
      a part of one raster, coarsened before it is cut, so that the tiles still weld
  stepterrain batch dem_tiles/n3*.tif --interval 50 -o out/
      the DEM files a shell glob names, one .glb each (one file without --tile: one item, as among several)
  stepterrain batch series.npy --interval 0.1 -o out/frames --png out/frames.png
      a (T, H, W) time series, one mesh per frame with the same isovalues, and a contact sheet
  stepterrain batch big.tif --tile 1024 --interval 100 --scheduler tcp://10.0.0.5:8786 -o out/
      an existing dask cluster (connect timeout --connect-timeout, default 10 s)
  stepterrain batch --tile 256 -o out/tiles            (again: complete outputs are skipped)

exit status: 0 every item written (a tile, frame or file of nodata only, sea off a coast, as an empty mesh) or
complete already; 1 some items failed (listed with their reasons);
2 bad input (unknown format, unreadable source, output folder not writable, scheduler unreachable, a --floor
not below the stepped surface of every item, a --spacing for DEM files that all place their nodes themselves, a
--band no input holds, a --coarsen that leaves every item too few nodes or only nodata); 130 interrupted (Ctrl-C),
143 terminated (SIGTERM), 129 hung up (SIGHUP): finished outputs are kept, partial files removed, and a rerun goes
on from there.
"""


def _failed_alike(report: Any, marker: str) -> list[Any]:
    """The failed items when every item of ``report`` failed with an error holding ``marker`` (one option refused by
    every input alike), else none."""
    failed = [r for r in report.failed if marker in (r.error or "")]
    return failed if failed and len(failed) == len(report.results) else []


def _refuse_alike(report: Any, marker: str, head: str, inputs: tuple[str, str], tail: str,
                  after: str | None = None) -> None:
    """One usage error where every item of ``report`` failed with ``marker`` in its error (an option every input
    refused alike), not a list of identical failures: ``head``, then ``inputs`` (for one input, or for n: ``{n}``),
    the first failure ``(e.g. KEY: its error after 'after', default the marker)`` and ``tail``."""
    failed = _failed_alike(report, marker)
    if failed:
        first, n = failed[0], len(failed)
        example = (first.error or "").split(marker if after is None else after, 1)[-1]
        raise InvalidInputError(f"{head}{inputs[0] if n == 1 else inputs[1].format(n=n)} (e.g. {first.key}: "
                                f"{example}){tail}")


def _tile(text: str) -> int | tuple[int, int]:
    from .cli import _untyped

    try:
        if _untyped(text):  # int() reads 1_0 as 10, an Arabic-Indic 3 as 3
            raise ValueError(text)
        parts = [int(v) for v in text.lower().split("x")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected cells per tile N or RxC, e.g. 1024 or 512x1024; got {text!r}"
        ) from None
    if len(parts) not in (1, 2) or min(parts) < 1:
        raise argparse.ArgumentTypeError(f"expected positive cells per tile N or RxC; got {text!r}")
    return parts[0] if len(parts) == 1 else (parts[0], parts[1])


def add_parser(commands: Any) -> None:
    """Add the ``batch`` subcommand to the ``stepterrain`` parser."""
    from .cli import (
        _add_band,
        _add_camera,
        _add_device,
        _add_height_encoding,
        _add_height_unit,
        _add_nodata,
        _cell_size,
        _coarsen_factor,
        _floats,
        _path,
        _real,
        _whole,
        _window,
    )
    from .export import MESH_EXTENSIONS
    from .stepped import TARGET_STEPS

    p = commands.add_parser(
        "batch",
        help="many DEMs (a folder, a time series, tiles of one raster) -> one stepped mesh each, on dask",
        description="Step many terrains on dask.distributed (a LocalCluster, or --scheduler), one mesh file each, "
        "written atomically; reruns skip complete outputs, failures are retried then reported.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("input", nargs="*", type=_path, metavar="INPUT",
                   help="a folder of DEM files, several DEM files (a shell glob: tiles/*.tif; one DEM file without "
                        "--tile is one item too, as is a GDAL virtual path or URL, /vsizip/srtm.zip/N46E007.hgt, or "
                        "a .zip holding one raster: a zip of tiles is no folder here; a folder's N46E007.hgt.gz "
                        "tiles are read as their .hgt), a (T, H, W) .npy/.npz series, "
                        "or one DEM to cut with --tile; "
                        "default: the embedded Big Tujunga DEM")
    _add_height_unit(p)
    _add_band(p)
    _add_height_encoding(p)
    _add_nodata(p, "every DEM file (or the embedded DEM)", "the shared levels' height range is read with it too")
    p.add_argument("--spacing", type=_cell_size, metavar="D|dx,dy",
                   help="the node spacing in metres of DEM files with no georeferencing (.npy, a PNG heightmap, a "
                        "GeoTIFF without a geotransform), each read as 1 m cells otherwise; rows run north to south; "
                        "a file that places its nodes itself is refused (in a folder: its item fails; every item: exit "
                        "status 2)")
    p.add_argument("--crop", type=_floats(4, "xmin,xmax,ymin,ymax"), metavar="xmin,xmax,ymin,ymax",
                   help="keep the nodes inside this extent (the coordinates `stepterrain info` prints) of the one "
                        "raster cut with --tile, or of every frame of a series; not for several files or a folder")
    p.add_argument("--coarsen", type=_coarsen_factor, metavar="N",
                   help="average N x N blocks of nodes into one (nodata ignored), after --crop: the raster before "
                        "--tile cuts it (--tile then counts coarse cells; the tiles still weld), every frame, or "
                        "each file")
    p.add_argument("-o", "--output", type=_path, required=True, metavar="DIR",
                   help="output folder (created if missing; '-', standard output, is refused: ./- names a folder '-')")
    p.add_argument("--format", default=".glb", metavar="EXT",
                   help="mesh format of every output: " + " ".join(MESH_EXTENSIONS) + " (default .glb)")
    p.add_argument("--tile", type=_tile, metavar="N|RxC",
                   help="cut one raster into tiles of N (or R x C) cells; neighbours share border nodes "
                        "(default 256 for the embedded DEM)")
    iso = p.add_mutually_exclusive_group()
    iso.add_argument("--interval", type=_real, metavar="M",
                     help=f"uniform isovalues base + k*M (default a round M giving ~{TARGET_STEPS} steps over "
                          f"the whole source: a raster's tiles, a series' frames, all the files of a folder)")
    iso.add_argument("--levels", type=_floats(None, "comma-separated heights a,b,c"), metavar="a,b,c",
                     help="explicit, strictly increasing isovalues")
    p.add_argument("--base", type=_real, metavar="B",
                   help="isovalue offset for --interval (default 0); not with --levels")
    p.add_argument("--gamma", type=_real, default=1.0, metavar="G",
                   help="blend in [0, 1]: 0 = original surface, 1 = fully stepped (default 1)")
    p.add_argument("--colormap", default=None, metavar="NAME",
                   help="matplotlib colormap for level colors, or 'none' (default terrain, land part, as steps; "
                        "none for --format .stl, which holds no colours: a colormap is refused there); tiles, "
                        "frames and the files of a folder "
                        "share their levels, so a height has one colour in all of them (a folder's files are read "
                        "once more first, for their common height range, recorded for reruns)")
    p.add_argument("--solid", action="store_true", help="watertight solids (for .stl/.3mf printing)")
    p.add_argument("--floor", type=_real, metavar="Z",
                   help="base height of --solid (default: one --interval under the whole raster, series or "
                        "folder, with --levels a tenth of their span (at least 0.1), shared by every item)")
    p.add_argument("--scheduler", metavar="ADDR",
                   help="an existing dask scheduler, e.g. tcp://host:8786; 'serial' runs in this process "
                        "(default: a LocalCluster of --workers processes)")
    p.add_argument("--workers", type=_whole, metavar="N",
                   help="LocalCluster worker processes (default 2; at most one per item to run); not with --scheduler")
    p.add_argument("--connect-timeout", type=_real, default=None, metavar="S",
                   help="seconds to reach --scheduler (or start the LocalCluster) before giving up (default 10); "
                        "not with --scheduler serial")
    p.add_argument("--retries", type=_whole, default=2, metavar="N",
                   help="extra attempts for an item whose task failed (default 2)")
    p.add_argument("--no-resume", action="store_true", help="redo every item, even complete ones")
    _add_device(p, " on the workers")
    p.add_argument("--png", type=_path, metavar="OUT.png",
                   help="also render an overview: the welded tiles, or a contact sheet of up to 16 items")
    p.add_argument("--size", type=_window, default=None, metavar="WxH", help="--png size (default 1280x800)")
    p.add_argument("--z-scale", type=_real, default=None, metavar="S",
                   help="vertical exaggeration of the overview render only, with --png (default 2; the meshes are "
                        "written as they are)")
    _add_camera(p, "the overview render, with --png (each cell of a contact sheet alike)")
    p.set_defaults(run=functools.partial(_run_batch, sub=p))  # its failure lines spell library arguments as p's options


def _run_batch(args: argparse.Namespace, progress: Any, sub: argparse.ArgumentParser) -> int:
    from . import render
    from .batch import (
        MAX_CONNECT_TIMEOUT,
        _absolute,
        _check_ext,
        _one_raster_file,
        _virtual_source,
        batch,
        overview_image,
    )
    from .cli import (
        _as_option,
        _check_output,
        _check_outputs,
        _check_size,
        _colormap,
        _counted,
        _given,
        _isovalue_base,
        _load_input,
        _refuse_unused,
    )

    if os.fspath(args.output) == "-":  # a dash reads as standard output: it made a folder named '-' here
        raise InvalidInputError("--output '-' would be standard output, which is no folder: batch writes a mesh file "
                                "per item into the folder --output names; give a folder (./- for one named '-')")
    files = list(args.input)  # several: one item each, as a folder's files
    if len(files) > 1 and args.tile is not None:
        raise InvalidInputError(f"--tile cuts one DEM into tiles; got {len(files)} INPUT files (each file is one "
                                "item): give one file, or leave --tile out")
    # one DEM file without --tile (a shell glob that matched one, tiles/*.tif) is one item, as several are: it was
    # refused with "give --tile to cut it into tiles"; a (T, H, W) series stays one item per frame
    # a raster in a zip or at a URL (/vsizip/..., https://...) is one file too; a zip of several tiles is refused
    listed = len(files) > 1 or (len(files) == 1 and args.tile is None and (_one_raster_file(Path(files[0]))
                                                                           or _virtual_source(files[0]) is not None))
    args.input = files if listed else files[0] if files else None
    png = _check_output(args.png, (".png",), "--png") if args.png else None
    if not (0.0 <= args.gamma <= 1.0):
        raise InvalidInputError(f"--gamma must lie in [0, 1] (0 = original, 1 = stepped); got {args.gamma}")
    base = _isovalue_base(args)
    if args.floor is not None and not args.solid:
        raise InvalidInputError("--floor applies only with --solid")
    if args.workers is not None and args.scheduler is not None:  # the LocalCluster's: ignored without a word
        raise InvalidInputError(f"--workers applies only to the default LocalCluster, not with --scheduler; got "
                                f"--workers {args.workers} with --scheduler {args.scheduler}")
    workers = 2 if args.workers is None else args.workers
    render_options = _given(args, {"size": (1280, 800), "z_scale": 2.0, "camera": "oblique"})
    _check_size(args.size, renders=png is not None)
    if not (math.isfinite(args.z_scale) and args.z_scale > 0):
        raise InvalidInputError(f"--z-scale must be a positive number; got {args.z_scale}")
    if png is None:  # (after its value, which is named first) it was ignored
        _refuse_unused(render_options, "--png (the overview render)", "without --png")
    _check_outputs({"INPUT" if len(files) == 1 else f"INPUT {k + 1}": f for k, f in enumerate(files)}, png=png)
    if png is not None and Path(os.path.abspath(png)) == Path(os.path.abspath(args.output)):
        # the overview went to the folder the meshes had just been written into: every item done, then an error
        raise InvalidInputError(f"--output and --png name the same path {args.output!r}; give the overview "
                                "its own file name")
    source_folder = Path(files[0]).resolve() if len(files) == 1 and Path(files[0]).is_dir() else None
    if png is not None and png.resolve().parent == source_folder:
        # a folder's DEM files are its .npy .npz .png .tif ...: a rerun read the overview as a tile and failed on it
        raise InvalidInputError(f"--png {str(png)!r} lies in the INPUT folder {args.input!r}, where a rerun would read "
                                "it as a DEM tile; write the overview elsewhere")
    if args.connect_timeout is not None and args.scheduler == "serial":  # no cluster to reach: ignored without a word
        raise InvalidInputError(f"--connect-timeout applies to a dask cluster, not with --scheduler serial; got "
                                f"--connect-timeout {args.connect_timeout:g}")
    if args.connect_timeout is None:
        args.connect_timeout = 10.0
    if not (math.isfinite(args.connect_timeout) and 0 < args.connect_timeout <= MAX_CONNECT_TIMEOUT):
        raise InvalidInputError(f"--connect-timeout must be a positive number of seconds up to "
                                f"{MAX_CONNECT_TIMEOUT:g} (a day); got {args.connect_timeout:g}")
    if args.colormap is None:  # steps' default; an STL holds no colours (steps drops them there unsaid too)
        args.colormap = "none" if _check_ext(args.format) == ".stl" else "terrain"
    _colormap(args.colormap)  # an unknown name fails here, before the cluster starts
    if args.colormap.lower() != "none" and _check_ext(args.format) == ".stl":  # the colours were dropped unsaid
        raise InvalidInputError(f"--colormap colours the meshes by level; --format .stl holds no colours (the --png "
                                f"overview reads the files): got --colormap {args.colormap}; write .ply, .3mf or .glb "
                                "for colours, or leave --colormap out")
    # this machine's device (no --scheduler, or serial) was resolved by main() before any input was read
    remote = args.scheduler not in (None, "serial")
    if args.device is not None and remote and not re.fullmatch(r"cpu|cuda(:\d+)?", args.device):
        # a cluster's workers find their own devices (a GPU this machine may lack): only the name's form here
        raise DeviceError(f"--device must be cpu, cuda or cuda:N (a Warp device of the workers of --scheduler); "
                          f"got {args.device!r}")
    if png is not None:
        render.require_offscreen()

    if args.input:  # read by batch (a folder's files by its workers), --height-unit passed on
        source: Any = args.input
        what = args.input
        if listed:  # one: said how to cut it into tiles instead
            what = _counted(len(files), "DEM file") + (f" ({files[0]}; --tile N cuts it)" if len(files) == 1 else "")
    else:  # the embedded DEM, which refuses a --height-unit
        source = _load_input(None, args.height_unit, spacing=args.spacing, band=args.band,  # and --spacing, --band
                             height_encoding=args.height_encoding, nodata=args.nodata)  # --nodata: read with it
        args.spacing = None
        what = "the embedded Big Tujunga DEM"
    tile = args.tile if args.tile is not None else (256 if not args.input else None)
    scheduler = args.scheduler
    rows, cols = (tile, tile) if isinstance(tile, int) else tile or (0, 0)  # "(512, 1024) cells" read as Python
    # at most one worker per item to run (batch), which only the run knows (a rerun's complete items start none)
    cluster = f"a LocalCluster of {'up to ' if workers > 1 else ''}{_counted(workers, 'worker')}"
    progress.stage("batch", f"stepping {what}" + (f" in tiles of {rows} x {cols} cells" if tile else "")
                   + f" -> {Path(args.output)}/*{_check_ext(args.format)}" + f" on {scheduler or cluster}")
    def failure_line(line: str) -> str:  # the bar's line of a failed item, as the summary's below
        return f"stepterrain: {_as_option(line, sub)}"

    from .io import recorded_nodata

    # the embedded DEM's --nodata, applied as it was read (batch records a file source's itself)
    embedded_nodata = [] if args.input else recorded_nodata(args.nodata or ())
    report = batch(
        source, args.output, format=args.format, tile_size=tile, interval=args.interval, levels=args.levels,
        base=base, gamma=args.gamma, colors=None if args.colormap.lower() == "none" else args.colormap,
        solid=args.solid, floor=args.floor, scheduler=scheduler, workers=workers, retries=args.retries,
        resume=not args.no_resume, connect_timeout=args.connect_timeout,
        progress=False if progress.quiet else failure_line,
        # "input" is part of every item's fingerprint: by its absolute path, so that the raster named from another
        # folder (or by its absolute path) keeps its complete tiles instead of redoing them all
        metadata={"generator": "stepterrain batch"} if source_folder is not None or listed else {  # each file's
            "generator": "stepterrain batch",
            "input": _absolute(args.input) if args.input else "embedded Big Tujunga DEM",
            **({"nodata": embedded_nodata} if embedded_nodata else {})},
        height_unit=args.height_unit, spacing=args.spacing, crop=args.crop, coarsen=args.coarsen, device=args.device,
        band=args.band, overview_size=None if png is None else args.size,  # its render checked before the items run
        overview_z_scale=None if png is None else args.z_scale,  # checked before the items run too
        height_encoding=args.height_encoding, nodata=args.nodata if args.input else None,
    )  # fmt: skip
    progress.done(f"{len(report.done)} written, {len(report.skipped)} complete already, {len(report.failed)} failed")
    # a folder's georeferencing is known only item by item (tiles and series are checked up front, and a floor
    # against every file's lowest height): a floor that close_solid still refuses for every item (within the float32
    # rounding of a γ < 1 blend), a --spacing for files that all place their nodes themselves, a --band every file
    # refuses (files of one band, or rasters of fewer bands), a --coarsen every file refuses, is a usage error, said
    # once, not a list of identical failures
    if args.floor is not None:  # mesh.close_solid's
        _refuse_alike(report, "floor must lie below", f"--floor {args.floor:g} must lie below the stepped surface of "
                      "every input; it lies above ", ("the only one", "all {n}"), "", after=": ")
    if args.spacing is not None:  # batch._check_unreferenced's
        _refuse_alike(report, "places its nodes itself: ", "--spacing applies to DEM files with no georeferencing "
                      "(.npy, a PNG heightmap, a GeoTIFF without a geotransform); ",
                      ("the only input places its nodes itself", "all {n} inputs place their nodes themselves"),
                      ": leave --spacing out")
    if args.band is not None:  # load_dem's, for files of one band
        _refuse_alike(report, "band applies to GDAL rasters only; ",
                      f"--band {args.band} applies to GDAL rasters only; ",
                      ("the only input holds one band", "all {n} inputs hold one band"), ": leave --band out",
                      after="holds one band, ")
        # GDAL rasters all of fewer bands (load_dem's): refused alike by every item, said once, as a .npy's one band
        _refuse_alike(report, "band must be between 1 and ", f"--band {args.band} is beyond the bands of ",
                      ("the only input", "all {n} inputs"), ": give a --band every input holds, or leave --band out",
                      after="band must be ")
    if args.height_encoding is not None:  # load_dem's, for files that are no PNG
        _refuse_alike(report, "height_encoding applies to a local RGB PNG tile ",
                      f"--height-encoding {args.height_encoding} applies to RGB PNG terrain tiles; ",
                      ("the only input is no PNG", "all {n} inputs are no PNG"), ": leave --height-encoding out",
                      after="(Terrain-RGB or Terrarium); ")
    if args.coarsen is not None:  # batch._coarsened's
        _refuse_alike(report, f"coarsen={args.coarsen}: ", f"--coarsen {args.coarsen} leaves no mesh of ",
                      ("the only input", "any of the {n} inputs"), ": give a smaller --coarsen")
    for line in report.summary().splitlines()[1:]:  # the failures (a budget's hint as the option) and the notes
        if not progress.quiet and line.startswith("  failed "):  # the bar wrote it as the item failed: once
            continue
        print(failure_line(line.strip()), file=progress.stream, flush=True)
    if png is not None and not (report.done or report.skipped):  # the run's exit status 1 alone said nothing of it
        print(failure_line(f"no overview written to {png}: every item failed, none has an output to show"),
              file=progress.stream, flush=True)
    elif png is not None:
        from .export import _save_image

        progress.stage("render", f"rendering an overview {args.size[0]}x{args.size[1]}")
        image = overview_image(report, window_size=args.size, z_scale=args.z_scale, camera=args.camera)
        _save_image(image, png, reused=False)  # no mesh takes its bytes
        progress.done(str(png))
    return 0 if report.ok else 1
