"""The ``stepterrain`` command (also ``python -m stepterrain``): one subcommand per capability.

``steps`` is the main job of paper 000 (stepped terrain): load a DEM (default: the embedded Big Tujunga
DEM), step it with Warp, write the mesh by extension and an off-screen render lit so that the steps read.
``globe``, ``closeup``, ``texture`` and ``batch`` live in ``_cli_<name>.py`` beside this module (see
``CAPABILITY_COMMANDS``); ``info`` describes a DEM or a mesh.

    stepterrain steps -o out/terrain.glb --png out/terrain.png
    stepterrain info out/terrain.glb

Progress goes to stderr as short stage lines; errors from :mod:`stepterrain.errors` print one line and exit
with status 2 (no traceback), as do usage errors.

A command with several outputs (``-o``, ``--png``, ``--mesh``, ``--normals``) checks every one before any work
(a folder, a read-only file, two options naming one file are refused then), and writes them once the work is done,
one after another, each atomically (:func:`~stepterrain.export.atomic_path`) and whole with its own side files (a
textured OBJ's ``.mtl`` and images, a GeoTIFF's ``.aux.xml``: all new or all old). A write failing part-way (a
full disk) stops the command with an error naming that file: the outputs written before it are complete and new,
that one and those after it are as they were. Each output stands alone (none names another), so no file refers to
one of another run.
"""

from __future__ import annotations

import argparse
import contextlib
import decimal
import json
import math
import os
import re
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ._compaction import SMALLER_HINT, WHOLE_RASTER_HINT, budget_hint, get_memory_budget, set_memory_budget
from ._files import refuse_folder_name
from .errors import DataFileError, InvalidInputError, OutputTooLargeError, StepTerrainError, counted
from .export import _STL_OPEN_LOCAL, _STL_ROUNDING_LOCAL, MESH_EXTENSIONS, _special_file_kind, probe_writable
from .stepped import TARGET_STEPS, _default_isovalues, colormap, colormap_samples, nice_interval
from .terrain import FLOAT32_MAX, Terrain, finite_number

__all__ = ["main", "build_parser", "nice_interval"]

EXIT_USAGE = 2

_STEPS_EPILOG = """\
examples:
  stepterrain steps -o out/terrain.glb --png out/terrain.png
      the embedded Big Tujunga DEM (30 m SRTM), 100 m steps (the round interval nearest ~15; 21 levels), GLB + render
  stepterrain steps dem.tif --interval 50 --gamma 0.7 -o dem.ply
  stepterrain steps dem.tif --interval 100 --png dem.png
      the render alone: no -o, no mesh file
  stepterrain steps --png top.png --camera top
      the render seen straight down, north up (--camera AZ,EL: from azimuth AZ, EL degrees up)
  stepterrain steps --levels 400,800,1200,1600,2000 --colormap viridis -o levels.obj
  stepterrain steps --lens-relative 0.5,0.5,0.2 -o lens.glb --png lens.png
      original terrain inside a soft circular lens at the centre, steps outside (paper 000, Fig. 4)
  stepterrain steps --interval 200 --solid --floor 0 -o print.3mf
      a watertight solid for 3D printing (also where integer heights sit on thresholds), with its colours;
      .stl holds float32, which rounds UTM coordinates by centimetres (a warning says by how much)
  stepterrain steps --interval 100 --solid --print-size 150 --print-z-scale 2 -o model.stl
      the solid scaled for a print: longer side 150 mm, lowest corner at 0,0,0, heights twice as steep
"""

_INFO_EPILOG = """\
examples:
  stepterrain info
      the embedded Big Tujunga DEM: size, spacing, extent, CRS, height range and unit, nodata count and fraction
  stepterrain info dem.tif --json
  stepterrain info out/terrain.glb
      a mesh: vertices, faces, bounds, watertightness, vertex or face colours, a texture image's size, the
      metadata that stepterrain wrote (and, for a .ply, how many levels its faces lie on and how many are walls)
"""

_MAIN_EPILOG = """\
examples:
  stepterrain steps -o out/terrain.glb --png out/terrain.png
  stepterrain info                      (the embedded DEM)
  stepterrain info out/terrain.glb
run 'stepterrain COMMAND --help' for the options of a command.
"""


class _UsageError(Exception):
    """A command-line value that argparse cannot check on its own (exit status 2)."""


#: An argument that is a value even though it starts with a minus: a digit or '.digit' next ('-1e20', '-5,0,5',
#: '-.5') or -inf/-nan (so the value checks, not argparse, refuse them). argparse's own pattern takes only '-5'
#: and '-0.5', so '--base -1e20' failed with "expected one argument". No stepterrain option looks like this.
_NEGATIVE_NUMBER = re.compile(r"^-(\.?\d|(inf|infinity|nan)$)", re.IGNORECASE)


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so :func:`main` returns the status to in-process callers, takes
    negative numbers in any float notation (and lists starting with one) as values, and refuses an option that takes
    one value given twice with different values (:meth:`_get_values`): every subcommand's parser is one
    (``parser_class``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_NUMBER
        self._given_values: dict[argparse.Action, Any] = {}

    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{self.prog}: error: {message}")

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:  # type: ignore[override]
        self._given_values = {}  # the values of this parse's options so far (a subcommand's parser parses its own)
        return super().parse_known_args(args, namespace)

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> Any:
        """argparse's, and a store option (``--interval 10``, ``-o a.glb``: one value, kept) given a second time with
        another value refused, naming it and both values as typed: argparse kept the last silently, so ``-o a.glb -o
        b.glb`` wrote b.glb alone and ``--interval 10 ... --interval 20`` stepped at 20. The same value again
        (``--interval 10 --interval 10.0``, ``nan`` twice: :func:`_same_value`) is no conflict; the options meant to
        repeat (``--nodata``, closeup's ``--roi``, ``--scale``, ...: append, extend) and flags (``-q``) are not
        checked. ``--memory-budget`` before and after the subcommand (two parsers) is checked in :func:`_main`."""
        values = super()._get_values(action, arg_strings)
        if type(action) is argparse._StoreAction and action.option_strings:
            typed = " ".join(arg_strings)
            if action in self._given_values and not _same_value(self._given_values[action][0], values):
                raise argparse.ArgumentError(
                    action, f"given twice ({self._given_values[action][1]!r}, then {typed!r}); it takes one value: "
                            f"give it once")
            self._given_values[action] = (values, typed)
        return values


def _as_typed(parser: argparse.ArgumentParser | None, dest: str, value: Any) -> str:
    """The text the option of ``parser`` stored in ``dest`` was given as in its last parse, quoted as
    :meth:`_Parser._get_values` quotes it ('1GB'); ``value``, as it was stored, where the parser kept no text."""
    for action, (_, typed) in getattr(parser, "_given_values", {}).items():
        if action.dest == dest:
            return repr(typed)
    return repr(value)


def _same_value(first: Any, second: Any) -> bool:
    """Whether two values of one option (:meth:`_Parser._get_values`) are the same: equal, or alike in their repr
    where they are not (NaN, as a number or in a tuple of them, is not equal to itself)."""
    return bool(first == second) or repr(first) == repr(second)


class Progress:
    """Short stage lines on stderr: ``stage("writing out.glb")`` ... ``done("1.2 MB")`` -> timing appended."""

    def __init__(self, stream: TextIO | None = None, quiet: bool = False) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self._start = 0.0
        self.timings: dict[str, float] = {}

    def say(self, message: str) -> None:
        if not self.quiet:
            print(f"stepterrain: {message}", file=self.stream, flush=True)

    def stage(self, name: str, message: str) -> None:
        self._name = name
        self._start = time.perf_counter()
        self.say(message)

    def done(self, message: str = "") -> float:
        elapsed = time.perf_counter() - self._start
        self.timings[self._name] = elapsed
        self.say(f"  {message + ' ' if message else ''}in {elapsed:.2f} s")
        return elapsed


def _counted(count: int, noun: str, plural: str | None = None) -> str:
    """``count`` and ``noun`` for progress and summary lines, the count grouped: "1 level", "1,024 vertices"
    (:func:`stepterrain.errors.counted`). The lines said "1 levels" and "1 workers"."""
    return counted(count, noun, plural, grouped=True)


# ------------------------------------------------------------------------------------------ argument types
@contextlib.contextmanager
def usage_errors(parser: argparse.ArgumentParser) -> Iterator[None]:
    """Within: a value the library refuses (a :class:`~stepterrain.errors.StepTerrainError`: no GPU for
    ``--device cuda``, a window too small) becomes ``parser.error``, one line and exit 2, not a traceback; and the
    library's warnings print as the ``stepterrain`` command's do (:func:`_warning_line`): one ``PROG: warning:``
    line, without Python's source line, the library arguments they name spelled as ``parser``'s options (load_dem's
    ``pass nodata=-32768`` for ``--dem``'s file: ``pass --nodata -32768``), in its errors as in its warnings
    (:func:`_as_option`). For scripts' own argparse mains (examples/)."""
    with warnings.catch_warnings():  # restored on exit, as the CLI's main() restores its own
        warnings.showwarning = _warning_line(parser.prog, parser)
        try:
            yield
        except StepTerrainError as exc:  # its advice as parser's options, as its warnings' (nodata= -> --nodata)
            parser.error(_as_option(str(exc), parser))


def add_dem_option(parser: argparse.ArgumentParser) -> None:
    """``--dem PATH`` for scripts' own argparse mains (examples/): a DEM file to use instead of the embedded one,
    loaded by :func:`example_dem` (within :func:`usage_errors`: a file it cannot read is a usage error); and
    ``--nodata V[,V...]``, load_dem's ``nodata`` for it (the CLI's own ``--nodata``, parsed the same way: the parser
    takes a value starting with a minus and a digit as a value, as the CLI's do)."""
    parser.add_argument("--dem", type=_path, default=None, metavar="PATH",
                        help="a DEM file to use instead of the embedded Big Tujunga DEM (any format load_dem reads: "
                             ".tif, .npy, .asc, .hgt, ...; heights in metres, a .npy's cells 1 m apart); --size cuts "
                             "it down as it cuts the embedded one (a crop, or every n-th node, as its help says)")
    _add_nodata(parser, "the --dem file (or the embedded DEM)")
    # as _Parser: '--nodata -9999,-32768' (the form its help shows) and '-1e20' are values, not unknown options
    parser._negative_number_matcher = _NEGATIVE_NUMBER


def example_dem(path: str | os.PathLike[str] | None, nodata: Sequence[float] | None = None) -> Terrain:
    """``--dem``'s terrain (:func:`add_dem_option`): :func:`~stepterrain.load_dem` of ``path`` with ``--nodata``'s
    ``nodata``, or the embedded Big Tujunga DEM (:func:`~stepterrain.sample_dem`) when it is None (``--nodata``
    applied to it as the CLI applies it without an INPUT)."""
    import stepterrain as st

    if path is not None:
        return st.load_dem(path, nodata=nodata)
    if nodata is None:
        return st.sample_dem()
    from .io import _sample_dem

    return _sample_dem(nodata)


def check_example_outputs(outputs: dict[str, str | os.PathLike[str] | None],
                          dem: str | os.PathLike[str] | None = None) -> None:
    """For scripts' own argparse mains (examples/), within :func:`usage_errors`, before any work: the files they will
    write (``outputs``: what each is called in a message, ``"--output"`` or ``"the GIF beside --output"``, -> its
    path; None: not written) checked as the CLI checks its outputs (``_check_outputs``): none is a folder, a file in
    a folder that is a file or not writable, another of them, or the ``--dem`` file ``dem`` (replaced by the write).
    A failed check wrote the first output and refused the next, or failed after all the work."""
    names = {f"out{k}": name for k, name in enumerate(outputs)}
    paths = {f"out{k}": None if path is None else Path(path) for k, path in enumerate(outputs.values())}
    _check_outputs({"--dem": dem}, names, **paths)


def add_colors_option(parser: argparse.ArgumentParser) -> None:
    """For scripts' own argparse mains (examples/): ``--colors N``, the palette of the PNG they write (default 256;
    0: full colour), checked by :func:`check_colors_option` and used by :func:`save_example_picture`."""
    parser.add_argument("--colors", type=_whole, default=256,
                        help="colours in the PNG's palette, 2 to 256 (default 256); 0: full colour")


def check_colors_option(parser: argparse.ArgumentParser, colors: int, output: Path) -> None:
    """Refuse (``parser.error``) a ``--colors`` other than 0 or 2 to 256, and an ``output`` not .png with a palette (a
    palette picture is a PNG; in full colour :func:`~stepterrain.export.save_image` writes a .tif too)."""
    if colors != 0 and not 2 <= colors <= 256:
        parser.error(f"--colors must be 0 (full colour) or 2 to 256; got {colors}")
    if colors != 0 and output.suffix.lower() != ".png":
        parser.error(f"--output must end in .png with a palette (--colors {colors}; --colors 0 writes a .tif too); "
                     f"got {str(output)!r}")


def save_example_picture(image: np.ndarray, path: Path, colors: int) -> None:
    """``image`` as a PNG at ``path``, atomically: in full colour where ``colors`` is 0
    (:func:`~stepterrain.export.save_image`), else with a palette of that many colours, Pillow's FASTOCTREE without
    dithering (its noise costs a third more bytes and speckles flat areas): the docs' panels of half-tone edges and
    shading take a third of their full-colour bytes or less (docs/adaptive_mesh.png 0.86 -> 0.26 MB,
    docs/texture.png 1.02 -> 0.30 MB), the colours as they were to the eye."""
    from PIL import Image

    from .export import atomic_path, save_image

    if colors == 0:
        save_image(image, path)
        return
    picture = Image.fromarray(np.ascontiguousarray(image[..., :3])).quantize(colors, method=Image.Quantize.FASTOCTREE)
    with atomic_path(path) as tmp:
        picture.save(tmp, format="PNG", optimize=True)


#: float() and int() read digit grouping ('1_0' is 10) and the digits of every script (an Arabic-Indic 3 is 3): a number
#: not typed as such (strtod, and so GDAL's tools and awk, read 1_0 as 1), which a refusal then named as its reading
#: ('--gamma 1_0': got 10.0); every numeric option refuses them, as --band, --coarsen and --nodata do
_PLAIN_DIGITS = "in ASCII digits, without underscores (digit grouping: 1_0 is 10 to Python, 1 to strtod)"


def _untyped(text: str) -> bool:
    """Whether ``text`` holds what float()/int() read but no one types as a number: an underscore, a non-ASCII digit."""
    return "_" in text or not text.isascii()


def _typed(convert: Callable[[str], Any], what: str) -> Callable[[str], Any]:
    """An option type as argparse's ``type=float`` / ``type=int``, the number in ASCII digits, without underscores;
    other bad text is refused in the house style, "expected {what}; got 'abc'" (argparse names the option before it:
    its stock "invalid float value: 'abc'" said neither what was expected nor, for '200,0', why it was no number)."""

    def number(text: str) -> Any:
        if _untyped(text):
            raise argparse.ArgumentTypeError(f"expected {what} {_PLAIN_DIGITS}; got {text!r}")
        try:
            return convert(text)
        except ValueError:
            hint = " (one value, with a decimal point: a comma is no part of a number)" if "," in text else ""
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}{hint}") from None

    return number


_real: Callable[[str], float] = _typed(float, "a number")  # a number option
_whole: Callable[[str], int] = _typed(int, "a whole number")  # a whole-number option


def _floats(count: int | None, what: str) -> Callable[[str], tuple[float, ...]]:
    def parse(text: str) -> tuple[float, ...]:
        if _untyped(text):
            raise argparse.ArgumentTypeError(f"expected {what} {_PLAIN_DIGITS}; got {text!r}")
        # blanks around a value go ('1, 2, 3'); blanks inside one are an error, not removed ('1 2 3' read as 123)
        items = [item.strip() for item in text.split(",")]
        if "" in items and text.strip():  # '1,,2' or '1,2,': a value left out, not a shorter list
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r} (an empty value)")
        try:
            values = tuple(float(v) for v in items if v != "")
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}") from None
        if (count is not None and len(values) != count) or not values:
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}")
        if not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected finite numbers for {what}; got {text!r}")
        return values

    return parse


def _path(text: str) -> str:
    """A file or folder argument: an empty string (an unset shell variable) is refused, not read as 'not given'."""
    if not text:
        raise argparse.ArgumentTypeError(f"expected a file name; got {text!r}")
    return text


def _camera(text: str) -> str | tuple[float, float]:
    """A ``--camera``: ``oblique``, ``top`` or ``AZ,EL`` in degrees, as render_mesh's ``camera`` takes it (its pair in
    radians: the direction the camera looks from, azimuth clockwise from north = +y, elevation above the horizon).
    Checked by argparse (exit 2, naming --camera) before any file is read."""
    name = text.strip().lower()
    if name in ("oblique", "top"):
        return name
    expected = ("oblique, top or AZ,EL in degrees (azimuth clockwise from north, elevation -90 to 90), e.g. "
                "--camera=225,30")
    try:
        azimuth, elevation = _floats(2, expected)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected {expected}; got {text!r}") from None
    if not -90.0 <= elevation <= 90.0:
        raise argparse.ArgumentTypeError(f"expected an elevation EL from -90 to 90 degrees; got {text!r}")
    # whole turns taken off exactly, into one turn from 0 as texture's --azimuth: math.radians(1e308) kept none of
    # the angle, and radians(-170) was not radians(190) (the default's azimuth) to the last bit
    return math.radians(azimuth % 360.0), math.radians(elevation)


#: ``--camera``'s help, with the render it applies to.
_CAMERA_HELP = ("the view of {what}: oblique (default: 190,45, from just west of south, 45 degrees up), top "
                "(straight down, north up: 180,90) or AZ,EL in degrees: the direction the camera looks from, azimuth "
                "clockwise from north "
                "(0 from the north, 90 from the east, 180 from the south), elevation above the horizon (-90 to 90, "
                "negative from below; within 0.1 of +-90 taken as +-89.9; a negative AZ as --camera=-90,30); "
                "framed to the terrain either way")


def _add_camera(p: argparse.ArgumentParser, what: str = "the render, with --png") -> None:
    """``--camera``: the render's camera (render_mesh's ``camera``), parsed by :func:`_camera`; left out it is None,
    for :func:`_given` (default ``"oblique"``) and :func:`_refuse_unused` without a render."""
    p.add_argument("--camera", type=_camera, default=None, metavar="oblique|top|AZ,EL",
                   help=_CAMERA_HELP.format(what=what))


def _height_unit(text: str) -> str:
    """A ``--height-unit``: a length unit load_dem knows, checked before any file is read."""
    from .io import _KNOWN_UNITS, _unit_factor

    if _unit_factor(text) is None:
        raise argparse.ArgumentTypeError(f"expected a length unit ({_KNOWN_UNITS}); got {text!r}")
    return text


def _add_height_unit(p: argparse.ArgumentParser, help: str | None = None) -> None:
    """``--height-unit``: load_dem's ``height_unit`` for an INPUT file that names no unit or one it does not know; it
    overrides a unit the file names, which load_dem warns of where that unit is known and gives other metres."""
    p.add_argument("--height-unit", type=_height_unit, default=None, metavar="UNIT",
                   help=help or "the INPUT heights' length unit (m, ft, US survey foot, km, cm, ...), for a file that "
                                "names none or one not known; it overrides a unit the file names (with a warning where "
                                "that unit is known and another length); heights become metres (default: the unit the "
                                "file names, else as stored)")


def _add_band(p: argparse.ArgumentParser) -> None:
    """``--band``: load_dem's ``band``, the band of a GeoTIFF (or another GDAL raster) an INPUT's heights are read
    from (the first, else)."""
    p.add_argument("--band", type=_positive_int, default=None, metavar="N",
                   help="the 1-based band of a GeoTIFF INPUT (or .img, .vrt, ...: a GDAL raster) to read the heights "
                        "from (default 1, as GDAL's tools read it); .npy, .npz and PNG hold one band")


def _nodata_values(text: str) -> list[float]:
    """A ``--nodata``: one number or several, comma-separated (``-9999,-32768``), checked before any file is read."""
    values = []
    for part in text.split(","):
        if _untyped(part):  # float() reads '1_0' as 10 (digit grouping) and '٣' as 3; GDAL's
            # -a_nodata (strtod) declares 1 and 0
            raise argparse.ArgumentTypeError(
                f"expected a number or comma-separated numbers (the values of missing cells) in ASCII digits, without "
                f"underscores (digit grouping: 1_0 is 10 to Python, 1 to GDAL's -a_nodata); got {part.strip()!r} in "
                f"{text!r}")
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected a number or comma-separated numbers (the values of missing cells); got {text!r}") from None
        exact = decimal.Decimal(part.strip())  # float() took it, so Decimal does: the value as written
        if exact.is_finite() and (math.isinf(value) or (value == 0.0 and exact != 0)):
            # float() rounds 1e400 to inf (which marks no cell: the value given is lost, silently) and 1e-400 to 0
            # (which marks every cell at height 0): load_dem refuses nodata=10**400 as beyond float64; so does this
            raise argparse.ArgumentTypeError(
                f"expected numbers within float64 (magnitudes from about 4.9e-324 to 1.8e+308, or 0, inf, nan: the "
                f"values of missing cells); got {part.strip()!r} in {text!r}, which float64 rounds to {value:g}")
        values.append(value)
    return values


def _add_nodata(p: argparse.ArgumentParser, what: str = "the INPUT", note: str = "") -> None:
    """``--nodata``: load_dem's ``nodata``, values marking missing cells of ``what`` besides its own nodata; ``note``:
    the subcommand's own word on them, after the forms (placed after ``what``, it read "a DEM; not for a mesh besides
    its own nodata value")."""
    p.add_argument("--nodata", type=_nodata_values, action="extend", default=None, metavar="V[,V...]",
                   help=f"value(s) marking missing cells of {what} besides its own nodata value and mask, as "
                        "`gdal_edit.py -a_nodata V` would declare them: compared with the values as stored (a "
                        "GeoTIFF band's before its scale and offset, in its dtype); repeat it or give a "
                        f"comma-separated list: --nodata -9999,-32768{'; ' + note if note else ''} (default: none, "
                        "the file's own nodata only)")


def _height_encoding(text: str) -> str:
    """A ``--height-encoding``: one of load_dem's :data:`~stepterrain.io.HEIGHT_ENCODINGS`, checked before any file
    is read."""
    from .io import HEIGHT_ENCODINGS

    name = text.strip().lower()
    if name not in HEIGHT_ENCODINGS:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(HEIGHT_ENCODINGS)}; got {text!r}")
    return name


def _add_height_encoding(p: argparse.ArgumentParser) -> None:
    """``--height-encoding``: load_dem's ``height_encoding``, the RGB encoding of an INPUT PNG terrain tile."""
    p.add_argument("--height-encoding", type=_height_encoding, default=None, metavar="NAME",
                   help="decode an RGB(A) PNG INPUT's heights from its colours, as web-map terrain tiles store them: "
                        "terrain-rgb (Mapbox: -10000 + (R*65536 + G*256 + B)*0.1 m) or terrarium (Mapzen/AWS: "
                        "R*256 + G + B/256 - 32768 m); transparent pixels are nodata, a world file (.pgw) beside it "
                        "places it (default: a PNG is a greyscale heightmap)")


def _positive_int(text: str) -> int:
    """A count option (``--band``, ``--coarsen``): a whole number >= 1, refused by argparse before any file is read;
    in ASCII digits, without underscores (int() reads '1_0' as 10: a file's band 10, "got --band 10" of a 1_0)."""
    try:
        value = 0 if _untyped(text) else int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive whole number; got {text!r}")
    return value


def _coarsen_factor(text: str) -> int:
    """A ``--coarsen N``: a whole number >= 2; 1 keeps every node, refused as the other options that do nothing are
    (:func:`_positive_int`'s refusal for the rest)."""
    value = _positive_int(text)
    if value == 1:
        raise argparse.ArgumentTypeError(
            f"expected a whole number >= 2 (N x N nodes averaged into one); 1 keeps every node: leave --coarsen out; "
            f"got {text!r}")
    return value


def _cell_size(text: str) -> tuple[float, ...]:
    """A ``--spacing``: one cell size D or dx,dy, positive metres."""
    from .terrain import SPACING_RANGE

    what = "one cell size D or dx,dy in positive metres"
    values = _floats(None, what)(text)
    if len(values) > 2 or min(values) <= 0:
        raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}")
    lo, hi = SPACING_RANGE  # Terrain's, checked here: batch ran every item into it (exit 1 after the work)
    if not all(lo <= v <= hi for v in values):
        raise argparse.ArgumentTypeError(f"expected {what} from {lo:g} to {hi:g} (nodes are placed in float32); got "
                                         f"{text!r}")
    return values


#: The DEM files an INPUT may name (load_dem's), for the help of steps, closeup, texture and info.
INPUT_HELP = ("DEM file (.npy .npz .png .tif .asc .hgt .img .vrt .bil .flt .dem .dt0-2), a GDAL virtual path or URL to "
              "one of the GDAL rasters (/vsizip/srtm.zip/N46E007.hgt, /vsigzip/dem.tif.gz, https://.../cog.tif, "
              "s3://bucket/dem.tif), a .zip holding one or a gzip of one (N46E007.hgt.gz, dem.tif.gz)")


def _add_input_options(p: argparse.ArgumentParser) -> None:
    """The one DEM INPUT of steps, closeup and texture and its options: ``--height-unit``, ``--band``, ``--spacing``,
    ``--crop`` and ``--coarsen`` (see :func:`_load_input`). The formats its help lists are load_dem's (one list for
    the three subcommands)."""
    p.add_argument("input", nargs="?", type=_path, metavar="INPUT",
                   help=INPUT_HELP + "; default: the embedded Big Tujunga DEM")
    _add_height_unit(p)
    _add_band(p)
    _add_height_encoding(p)
    _add_nodata(p, "the INPUT (or the embedded DEM)")
    p.add_argument("--spacing", type=_cell_size, metavar="D|dx,dy",
                   help="the node spacing in metres of an INPUT with no georeferencing (.npy, a PNG heightmap, a "
                        "GeoTIFF without a geotransform), read as 1 m otherwise; rows run north to south")
    p.add_argument("--crop", type=_floats(4, "xmin,xmax,ymin,ymax"), metavar="xmin,xmax,ymin,ymax",
                   help="keep the DEM's nodes inside this extent, in its coordinates (those `stepterrain info` "
                        "prints; a geographic DEM's local metres); of a GeoTIFF (or .asc, .hgt, ...: a GDAL raster) "
                        "only this window is read")
    p.add_argument("--coarsen", type=_coarsen_factor, metavar="N",
                   help="average N x N blocks of nodes into one (nodata ignored), after --crop: a DEM too big "
                        "for the memory budget, or more detail than needed")


def _load_input(path: str | None, height_unit: str | None, *, spacing: Sequence[float] | None = None,
                crop: Sequence[float] | None = None, coarsen: int | None = None, band: int | None = None,
                height_encoding: str | None = None, nodata: Sequence[float] | None = None) -> Any:
    """The DEM at ``path`` (``--height-unit``, ``--band``, ``--height-encoding`` and ``--nodata`` applied), else the
    embedded one (where a unit, a band or an encoding is refused; ``--nodata`` applies to it as to a file); then
    ``--spacing`` (a grid load_dem could not place),
    ``--crop`` (:meth:`Terrain.crop`) and ``--coarsen`` (:meth:`Terrain.coarsen`, block means). A file's ``--crop``
    without ``--spacing`` is load_dem's ``crop``: a GeoTIFF's (or another GDAL raster's) window is all that is read (a
    crop of a file over the memory budget), the same nodes."""
    from .io import _sample_dem, own_placement, read_dem

    def refuse(whole: Any) -> None:
        assert crop is not None
        _refuse_degrees(whole, crop, "--crop")
        _refuse_gdal_order(whole, crop)

    if path:  # load_dem, with --crop unless --spacing must place the grid first
        terrain = read_dem(path, band=1 if band is None else band, height_unit=height_unit,
                           crop=crop if spacing is None else None, option="--crop", refuse=refuse,
                           height_encoding=height_encoding, nodata=nodata)
        if spacing is None:
            crop = None  # done
    elif height_unit is not None:
        raise InvalidInputError(
            f"--height-unit applies to an INPUT file; the embedded DEM is in metres; got {height_unit!r}")
    elif band is not None:
        raise InvalidInputError(f"--band applies to a GeoTIFF INPUT; the embedded DEM holds one band; got {band}")
    elif height_encoding is not None:
        raise InvalidInputError(f"--height-encoding applies to an RGB PNG INPUT; the embedded DEM holds heights; "
                                f"got {height_encoding!r}")
    else:
        terrain = _sample_dem(nodata)
    if spacing is not None:
        placed = own_placement(terrain.crs, terrain.spacing, terrain.origin)
        if placed is not None:
            raise InvalidInputError(
                f"--spacing applies to a DEM file with no georeferencing (.npy, a PNG heightmap, a GeoTIFF without a "
                f"geotransform); {path or 'the embedded DEM'} places its nodes itself: {placed}")
        dx, dy = (spacing[0], spacing[-1])
        terrain = type(terrain).from_heights(terrain.heights, spacing=(dx, -dy), source=terrain.source,
                                             height_unit=terrain.height_unit)
    if crop is not None:
        refuse(terrain)
    try:  # the methods' refusals, prefixed with the option that passed their argument
        option = "--crop"
        if crop is not None:
            terrain = terrain.crop(crop)
        option = "--coarsen"
        if coarsen is not None:
            terrain = terrain.coarsen(coarsen)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{option}: {exc}") from None
    return terrain


def _refuse_degrees(terrain: Any, extent: Sequence[float], option: str) -> None:
    """An extent option given in degrees for a DEM load_dem read from degrees (whose coordinates are local metres)
    is refused, with the same extent in those metres (:func:`~stepterrain.io.extent_in_degrees_as_metres`): a
    whole-world image's -180,180,-90,90 would have draped a 360 x 180 m corner."""
    from .io import extent_in_degrees_as_metres

    found = extent_in_degrees_as_metres(terrain, extent)
    if found is None:
        return
    x0, x1, y0, y1 = (float(v) for v in extent)
    (lon0, lon1, lat0, lat1), (mx0, mx1, my0, my1) = found
    raise InvalidInputError(
        f"{option}={x0:.10g},{x1:.10g},{y0:.10g},{y1:.10g} looks like degrees (over the DEM's longitudes "
        f"{lon0:.6g}..{lon1:.6g} and latitudes {lat0:.6g}..{lat1:.6g}), but a DEM in degrees is read as local "
        f"metres (its extent {tuple(round(v, 2) for v in terrain.extent)}, as `stepterrain info` prints it), which "
        f"{option} takes: those degrees are {option}={mx0:.2f},{mx1:.2f},{my0:.2f},{my1:.2f}")


def _refuse_gdal_order(terrain: Any, crop: Sequence[float]) -> None:
    """A ``--crop`` in GDAL's order (-te and rasterio's bounds: xmin,ymin,xmax,ymax) is refused, with the numbers in
    ours: projected bounds read as xmin,xmax,ymin,ymax span a box more than 10 times the DEM's width and height (an
    easting to a northing, each way), cropping one corner of it, where the other order crops a box on the DEM."""
    x0, x1, y0, y1 = (float(v) for v in crop)
    ex0, ex1, ey0, ey1 = terrain.extent
    if not (x0 < y0 and x1 < y1):  # the numbers in GDAL's order make no box
        return
    if not (min(y0, ex1) > max(x0, ex0) and min(y1, ey1) > max(x1, ey0)):  # nor one over the DEM
        return
    if x1 - x0 > 10 * (ex1 - ex0) and y1 - y0 > 10 * (ey1 - ey0):
        raise InvalidInputError(
            f"--crop={x0:.10g},{x1:.10g},{y0:.10g},{y1:.10g} spans more than 10 times the DEM's width and height "
            f"(its extent {tuple(round(v, 2) for v in terrain.extent)}): its numbers are xmin,xmax,ymin,ymax, not "
            f"GDAL's -te xmin,ymin,xmax,ymax; in this order that box is --crop={x0:.10g},{y0:.10g},{x1:.10g},{y1:.10g}")


def _input_terrain(args: argparse.Namespace) -> Any:
    """The INPUT DEM of a subcommand with :func:`_add_input_options`, its options applied (:func:`_load_input`)."""
    return _load_input(args.input, args.height_unit, spacing=args.spacing, crop=args.crop, coarsen=args.coarsen,
                       band=args.band, height_encoding=args.height_encoding, nodata=args.nodata)


def _add_device(p: argparse.ArgumentParser, where: str = "") -> None:
    """``--device``: the Warp device (``where`` it runs, e.g. " on the workers"), Warp's default when left out."""
    p.add_argument("--device", default=None, metavar="DEVICE",
                   help=f"Warp device{where}: cpu, cuda, cuda:0 (default: Warp's)")


def _input_metadata(args: argparse.Namespace) -> dict[str, Any]:
    """The INPUT and the options of :func:`_add_input_options` given, for a mesh's metadata: a cropped or coarsened
    mesh recorded only its whole file as its input, as if it covered all of it at the file's spacing."""
    metadata: dict[str, Any] = {"input": args.input or "embedded Big Tujunga DEM"}
    if args.height_unit is not None:
        metadata["height_unit"] = args.height_unit
    if args.band is not None:  # which of the file's bands the heights are
        metadata["band"] = int(args.band)
    if args.height_encoding is not None:  # the colours its heights were decoded from
        metadata["height_encoding"] = args.height_encoding
    if args.nodata is not None:  # the values read as missing besides the file's own nodata
        from .io import recorded_nodata

        if recorded := recorded_nodata(args.nodata):
            metadata["nodata"] = recorded
    if args.spacing is not None:
        # the DEM's (dx, dy) as Terrain.spacing, `info` and a heightfield mesh's own metadata give it: rows run north
        # to south, dy negative (--spacing 30 recorded (30, 30), and replaced a draped mesh's (30, -30))
        metadata["spacing"] = [float(args.spacing[0]), -float(args.spacing[-1])]
    if args.crop is not None:
        metadata["crop"] = [float(v) for v in args.crop]
    if args.coarsen is not None:
        metadata["coarsen"] = int(args.coarsen)
    return metadata


#: ``--memory-budget`` units, case-insensitive: decimal (kB, MB, GB, TB), binary (KiB, MiB, GiB, TiB); B or none: bytes.
_BYTE_UNITS = {"": 1, "b": 1, **{f"{p}b": 1000**k for k, p in enumerate("kmgt", 1)},
               **{f"{p}ib": 1024**k for k, p in enumerate("kmgt", 1)}}
_BYTE_SIZE = re.compile(r"^\s*([0-9]+(\.[0-9]*)?|\.[0-9]+)\s*([a-z]*)\s*$", re.IGNORECASE)  # \d: any script's


def _byte_size(text: str) -> int:
    """A ``--memory-budget``: bytes (``17179869184``) or a number and a unit (``8GiB``, ``500MB``, ``1.5 GiB``); at
    least one byte."""
    match = _BYTE_SIZE.match(text)
    unit = _BYTE_UNITS.get(match.group(3).lower()) if match else None
    nbytes = 0
    if match is not None and unit is not None:  # whole numbers exactly (no float rounding of a long byte count)
        number = match.group(1)
        nbytes = int(float(number) * unit) if "." in number else int(number) * unit
    if nbytes < 1:
        raise argparse.ArgumentTypeError(
            f"expected a positive size in bytes, or a number and a unit (B, kB, MB, GB, TB, KiB, MiB, GiB, TiB), "
            f"e.g. 8GiB or 500MB; got {text!r}")
    return nbytes


def _window(text: str) -> tuple[int, int]:
    try:
        if _untyped(text):
            raise ValueError(text)
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 1280x800; got {text!r}") from None
    return w, h


def _given(args: argparse.Namespace, defaults: dict[str, Any]) -> list[str]:
    """The options among ``defaults`` (dest -> its value when left out; the option's default None) given on the command
    line, as ``--option`` names; those left out are set to their default. For :func:`_refuse_unused`."""
    given = []
    for dest, default in defaults.items():
        if getattr(args, dest) is None:
            setattr(args, dest, default)
        else:
            given.append("--" + dest.replace("_", "-"))
    return given


def _option_list(options: Sequence[str]) -> str:
    """``options`` (one or more) as a phrase: "--a", "--a and --b", "--a, --b and --c"."""
    return " and ".join([", ".join(options[:-1]), options[-1]] if len(options) > 1 else options)


def _refuse_unused(options: Sequence[str], needs: str, got: str) -> None:
    """Refuse the ``options`` given that do nothing in this run (none: nothing to refuse), naming them: "--a and --b
    apply only with ``needs``; got them ``got``"."""
    if options:
        verb, them = ("applies", "it") if len(options) == 1 else ("apply", "them")
        raise InvalidInputError(f"{_option_list(options)} {verb} only with {needs}; got {them} {got}")


def _check_size(size: tuple[int, int], *, renders: bool = True, layered: bool = False) -> None:
    """``--size`` of every subcommand: 8 to 16384 pixels per side (an InvalidInputError, exit code 2). When the run
    ``renders`` (a --png, a close-up image), the render's memory is checked against the memory budget too, before
    the DEM is read (an OutputTooLargeError, exit code 2); ``layered``: close-up passes, not one render."""
    if size[0] < 8 or size[1] < 8 or max(size) > 16384:
        raise InvalidInputError(f"--size must lie in [8, 16384] pixels per side; got {size[0]}x{size[1]}")
    if renders:
        from .render import _check_render_budget

        _check_render_budget(size[0], size[1], "--size", layered=layered)


# ------------------------------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    """The ``stepterrain`` parser; each subcommand sets ``run`` to its handler ``(args, progress) -> int``."""
    from . import __version__

    parser = _Parser(
        prog="stepterrain",
        description="Warp kernels that turn terrain data into meshes people can look at, measure and ship.",
        epilog=_MAIN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"stepterrain {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    parser.add_argument("--memory-budget", type=_byte_size, default=None, metavar="SIZE", help=_MEMORY_BUDGET_HELP)
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    _add_steps(commands)
    for name in CAPABILITY_COMMANDS:
        module = _command_module(name)
        if module is not None:
            module.add_parser(commands)
    _add_info(commands)
    for sub in commands.choices.values():  # -q also after the subcommand; SUPPRESS keeps a -q given before it
        sub.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                         help="no progress lines on stderr")
        sub.add_argument("--memory-budget", type=_byte_size, default=argparse.SUPPRESS, metavar="SIZE",
                         dest="memory_budget_after", help=_MEMORY_BUDGET_HELP)  # see _main: given on both sides
    return parser


_MEMORY_BUDGET_HELP = ("largest output, DEM or image read or render a step may allocate: bytes or a size such as "
                       "8GiB, 500MB (default: the library's, 16 GiB); a run over it stops with exit status 2 before "
                       "allocating")

#: What a refusal over the memory budget (stepterrain._compaction.check_budget) says, as a command-line user raises it.
_CLI_BUDGET_HINT = "raise the budget (--memory-budget SIZE)"


#: Subcommands that live in their capability's own module ``stepterrain._cli_<name>``; each module defines
#: ``add_parser(commands)`` that adds one parser (its handler set as ``run``, signature ``(args, progress)``).
CAPABILITY_COMMANDS = ("globe", "closeup", "texture", "batch")


def _command_module(name: str) -> Any:
    import importlib
    import importlib.util

    qualified = f"{__package__}._cli_{name}"
    if importlib.util.find_spec(qualified) is None:
        return None
    return importlib.import_module(qualified)


def _add_steps(commands: Any) -> None:
    p = commands.add_parser(
        "steps",
        help="stepped terrain: terraces and walls at isovalues (paper 000)",
        description="Step a DEM into terraces and walls (Glander et al. 2010), write the mesh by extension "
        "(.glb .gltf .obj .ply .stl .3mf) and optionally an off-screen render; give -o, --png or both "
        "(--png alone writes only the render).",
        epilog=_STEPS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_input_options(p)
    iso = p.add_mutually_exclusive_group()
    iso.add_argument("--interval", type=_real, metavar="M",
                     help=f"uniform isovalues base + k*M (default: a round M giving ~{TARGET_STEPS} steps)")
    iso.add_argument("--levels", type=_floats(None, "comma-separated heights a,b,c"), metavar="a,b,c",
                     help="explicit, strictly increasing isovalues")
    p.add_argument("--base", type=_real, metavar="B",
                   help="isovalue offset for --interval (default 0); not with --levels")
    p.add_argument("--gamma", type=_real, default=1.0, metavar="G",
                   help="blend in [0, 1]: 0 = original surface, 1 = fully stepped (default 1)")
    lens = p.add_mutually_exclusive_group()
    lens.add_argument("--lens", type=_floats(3, "x,y,r"), metavar="x,y,r",
                      help="circular lens in world coordinates: original terrain inside, steps outside (--gamma's; "
                           "with --gamma 0 the terrain is original everywhere: refused)")
    lens.add_argument("--lens-relative", type=_floats(3, "fx,fy,fr"), metavar="fx,fy,fr",
                      help="lens centre as fractions of the extent, radius as a fraction of its shorter side (as "
                           "--lens: refused with --gamma 0)")
    p.add_argument("--lens-edge", type=_real, metavar="W", help="width of the lens' soft edge (default r/4)")
    p.add_argument("--solid", action="store_true",
                   help="close into a watertight solid (side skirts and a base)")
    p.add_argument("--floor", type=_real, metavar="Z",
                   help="base height of --solid (default one --interval below the lowest isovalue or surface "
                        "point, whichever is lower; with --levels a tenth of their span, at least 0.1, below it)")
    p.add_argument("--colormap", default=None, metavar="NAME",
                   help="matplotlib colormap for the level colors, or 'none' (default terrain, land part); an .stl -o "
                        "holds no colours: a colormap is refused there without --png")
    _add_device(p)
    p.add_argument("-o", "--output", type=_path, metavar="OUT",
                   help="mesh file; format by extension: " + " ".join(MESH_EXTENSIONS)
                        + " (optional with --png: a render-only run writes no mesh)")
    p.add_argument("--print-size", type=_real, default=None, metavar="MM",
                   help="scale the mesh file (-o, required) for a 3D print: its longer horizontal side MM long "
                        "(millimetres, as "
                        "slicers read .stl and .3mf), its lowest corner at 0,0,0 (the base of --solid on z = 0); "
                        "the mesh is no longer georeferenced (its metadata 'print' maps it back); with --solid "
                        "(a surface alone is no printable solid: a warning says so)")
    p.add_argument("--print-z-scale", type=_real, default=None, metavar="S",
                   help="vertical exaggeration of the --print-size model (default 1: true proportions)")
    p.add_argument("--png", type=_path, metavar="OUT.png",
                   help="write an off-screen render (beside the mesh, or alone without -o)")
    p.add_argument("--size", type=_window, default=None, metavar="WxH",
                   help="render size, with --png (default 1280x800)")
    p.add_argument("--z-scale", type=_real, default=None, metavar="S",
                   help="vertical exaggeration of the render only, with --png (default 2)")
    _add_camera(p)
    p.set_defaults(run=_run_steps)


def _add_info(commands: Any) -> None:
    p = commands.add_parser(
        "info",
        help="describe a DEM or a mesh file",
        description="Print a summary of a DEM (.npy .npz .png .tif .asc .hgt .img .vrt ...) or a mesh "
                    "(.glb .gltf .obj .ply .stl .3mf). It only reads files: no --device.",
        epilog=_INFO_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", nargs="?", type=_path, metavar="FILE",
                   help=INPUT_HELP + ", or a mesh file (.glb .gltf .obj .ply .stl .3mf, local); default: the embedded "
                                     "DEM")
    _add_height_unit(p, help="a DEM's heights' length unit (m, ft, US survey foot, km, ...), for a file that names "
                              "none or one not known; it overrides a unit the file names (with a warning where that "
                              "unit is known and another length); not for a mesh")
    _add_band(p)
    _add_height_encoding(p)
    _add_nodata(p, "a DEM (or the embedded one)", "not for a mesh")
    # the spacing steps', closeup's and texture's --spacing places a grid with: their --crop takes the coordinates
    # info prints, which it could not print for such a grid ("unrecognized arguments: --spacing 30")
    p.add_argument("--spacing", type=_cell_size, metavar="D|dx,dy",
                   help="the node spacing in metres of a DEM with no georeferencing (.npy, a PNG heightmap, a GeoTIFF "
                        "without a geotransform), as the other commands' --spacing places it (their --crop takes "
                        "the coordinates printed); not for a mesh")
    p.add_argument("--json", action="store_true", help="print JSON instead of aligned text")
    p.set_defaults(run=_run_info)


# ------------------------------------------------------------------------------------------ steps
def _isovalue_base(args: argparse.Namespace) -> float:
    """``--base`` (default 0), refused beside ``--levels``, which are absolute (it was silently ignored)."""
    if args.base is not None and args.levels is not None:
        raise InvalidInputError(f"--base applies only to uniform isovalues (--interval or the default one), "
                                f"not to --levels; got --base {args.base:g} with --levels")
    return 0.0 if args.base is None else float(args.base)


def _check_output(path: str, extensions: Sequence[str], what: str) -> Path:
    refuse_folder_name(path, what)  # 'x.glb/' (a folder meant) was written as the file x.glb: Path drops the '/'
    out = Path(path)
    if out.suffix.lower() not in extensions:
        # 'steps -o render.png' (closeup's and texture's --output take a .png): the picture has an option of its own
        png = out.suffix.lower() == ".png" and what == "--output"
        render = "; --png writes a render, beside the mesh" if png else ""
        raise InvalidInputError(
            f"{what} {path!r} has an unknown extension {out.suffix!r}; "
            f"expected one of {', '.join(extensions)}{render}"
        )
    return out


def _mesh_and_png(output: str | None, png: str | None, *, extensions: Sequence[str] = MESH_EXTENSIONS,
                  output_is: str = "OUT (the mesh file)", png_is: str = "a render",
                  others: Sequence[tuple[str, str | None, str]] = ()) -> tuple[Path | None, Path | None]:
    """``-o/--output`` and ``--png`` (a render) of every subcommand that renders, each checked by
    :func:`_check_output` (``-o`` against ``extensions``: ``steps`` and ``globe`` a mesh file, ``closeup`` a mesh or
    its render, ``texture`` the texture image): either or both (``--png`` alone, a render-only run, writes no ``-o``
    file), neither refused, naming both (``output_is``, ``png_is``: what each writes). ``others``: the command's
    further outputs that make a run without ``-o`` too, as (option, value, "METAVAR (what it writes)"), named after
    them in the refusal (``closeup --gif``, ``texture --mesh``); their values are checked by the caller."""
    if output is None and png is None and not any(value for _, value, _ in others):
        names = [f"-o/--output {output_is}", f"--png OUT.png ({png_is})",
                 *(f"{option} {what}" for option, _, what in others)]
        if len(names) == 2:
            raise InvalidInputError(f"give {names[0]}, {names[1]} or both; got neither")
        raise InvalidInputError(f"give {', '.join(names[:-1])} or {names[-1]}, or several of them; got none")
    return (_check_output(output, extensions, "--output") if output is not None else None,
            _check_output(png, (".png",), "--png") if png else None)


def _check_outputs(inputs: dict[str, str | os.PathLike[str] | None] | None = None,
                   names: dict[str, str] | None = None, /,
                   **paths: Path | None) -> None:
    """Refuse, before any work, output options that name the same file (the second write would replace the
    first), an input file (``inputs``: option name -> path, e.g. ``{"INPUT": args.input}``; the write would
    replace the input) or a file that cannot be written (the path is a folder, a named pipe, a device or a
    read-only file, or its nearest existing folder is a file or not writable): a command with several outputs would
    otherwise write the first and fail on the next. Creates nothing. An output is named ``--option`` for its keyword
    ``option``, or ``names[option]`` (a file with no option of its own: "the GIF beside --output")."""
    seen: dict[Path, str] = {}
    for option, path in paths.items():
        if path is None:
            continue
        name = (names or {}).get(option) or "--" + option.replace("_", "-")
        key = Path(os.path.abspath(path))
        # symbolic links resolved: '-o t.png --png link.png' (link.png -> t.png), or a folder reached by a link, wrote
        # both, the second replacing the first (the texture lost, exit 0)
        resolved = Path(os.path.realpath(path))
        if resolved in seen:
            raise InvalidInputError(f"{seen[resolved]} and {name} name the same file {str(path)!r}; give each its "
                                    "own")
        seen[resolved] = name
        try:  # a name the system refuses to look up (a part over 255 bytes) raised a bare OSError naming no option
            for source, given in (inputs or {}).items():
                if given and (Path(os.path.abspath(given)) == key
                              or (key.exists() and Path(given).exists() and os.path.samefile(key, given))):
                    raise InvalidInputError(f"{name} {str(path)!r} is the {source} file; writing it would replace "
                                            "the input: give the output its own name")
            if key.is_dir():
                raise DataFileError(f"{name} {str(path)!r} is a folder; expected a file name")
            special = _special_file_kind(key)
            if special is not None:  # refused by atomic_path too, but only once the work was done
                raise DataFileError(f"{name} {str(path)!r} is a {special}, not a regular file; expected a file name")
            # where symbolic links lead: a dangling link to a folder (out -> /data/new) is written through, and its
            # target's nearest folder was never looked at (a missing or unwritable one failed after all the work)
            folder = Path(os.path.realpath(key.parent))
            while not folder.exists() and folder != folder.parent:
                folder = folder.parent
        except DataFileError:  # the refusals above, whole ("cannot be written: --png 'x' is a folder" said it twice)
            raise
        except OSError as exc:
            raise DataFileError(f"{name} {str(path)!r} cannot be written: {exc.strerror or exc}") from exc
        if not folder.is_dir():
            raise DataFileError(f"{name} {str(path)!r} cannot be written: {str(folder)!r} is not a folder")
        error = probe_writable(folder)
        if error is not None:
            raise DataFileError(f"{name} {str(path)!r} cannot be written: folder {str(folder)!r} is not writable "
                                f"({error.strerror})") from error
        if key.is_file() and not os.access(key, os.W_OK):  # refused by atomic_path too, but after the work
            raise DataFileError(f"{name} {str(path)!r} cannot be written: the file exists and is read-only "
                                "(write-protected for this user); make it writable (chmod u+w) to replace it, or "
                                "choose another name")


def _name_max(folder: Path) -> int:
    """The longest file name, in bytes, ``folder`` takes (``os.pathconf``'s ``PC_NAME_MAX``; 255 where unknown)."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (AttributeError, ValueError, OSError):  # no pathconf (Windows), no such name or folder
        return 255


def _check_side_files(option: str, path: Path, sides: list[Path], inputs: dict[str, str | None],
                      outputs: dict[str, Path | None]) -> None:
    """Refuse, before any work, a side file ``sides`` of the output ``option`` ``path`` (a textured OBJ's .mtl and
    texture image, :func:`~stepterrain.export._side_files`) that is an input file (``inputs``: name -> path),
    another output (``outputs``: option -> path), or a folder, named pipe or device (the write refused it after all the
    work, the other outputs written). ``texture --image terrain_texture.png --mesh terrain.obj`` replaced
    the orthophoto given with the OBJ's texture image of the same name, without a word; ``-o terrain_texture.png
    --mesh terrain.obj`` wrote the texture and then refused the mesh. A side file's name longer than its folder
    allows (``PC_NAME_MAX``, else 255 bytes: ``<stem>_terrain_texture.png`` of a long stem) is refused too: it failed
    only after all the work, and after the other outputs were written."""
    for side in sides:
        key = Path(os.path.abspath(side))
        role = "material" if key.suffix.lower() == ".mtl" else "texture image"
        limit = _name_max(key.parent)
        if len(os.fsencode(key.name)) > limit:
            raise InvalidInputError(
                f"{option} {str(path)!r} writes {key.name!r} beside it (its {role}), a name of "
                f"{len(os.fsencode(key.name))} bytes, over the {limit} its folder allows; give {option} a shorter name")
        kind = _special_file_kind(key, folders=True)
        if kind is not None:  # refused by the write, but only after all the work and the other outputs written
            raise DataFileError(
                f"{option} {str(path)!r} writes {key.name!r} beside it (its {role}), which is a {kind}, not a "
                f"regular file; remove it or give {option} another name")
        for name, given in [*inputs.items(), *outputs.items()]:
            if not given:
                continue
            try:
                # symbolic links resolved: an output named through a linked folder was replaced by the side file
                same = (Path(os.path.abspath(given)) == key or os.path.realpath(given) == os.path.realpath(key)
                        or (key.exists() and Path(given).exists() and os.path.samefile(key, given)))
            except OSError:
                same = False
            if not same:
                continue
            what = (f"the {name} file, which it would replace" if name in inputs
                    else f"what {name} names: one would replace the other")  # fmt: skip
            raise InvalidInputError(f"{option} {str(path)!r} writes {key.name!r} beside it (its {role}), which is "
                                    f"{what}; give {option} or {name} another name")


def _colormap(name: str) -> tuple[Any, float, float] | None:
    """The matplotlib colormap ``--colormap NAME`` names and the fractions its land colours lie between
    (``stepped.land_range``); None for 'none'."""
    if name.lower() == "none":
        return None
    return colormap(name, argument="--colormap", hint=" or 'none'")


def _level_colors(name: str, n_levels: int) -> np.ndarray | None:
    """(L, 4) float colors of ``--colormap NAME`` (as :func:`stepterrain.stepped` samples a colormap name)."""
    if name.lower() == "none":
        return None
    return colormap_samples(name, n_levels, argument="--colormap")


def _kernel_cache_warm(device: Any) -> bool | None:
    """True when the stepped kernels are already compiled for ``device`` in Warp's cache (None: unknown)."""
    try:
        import warp as wp

        from .kernels import stepped as stepped_kernels

        module = wp.get_module(stepped_kernels.__name__)
        # Warp launches CPU kernels with block_dim 1, CUDA kernels with the module's default
        block_dim = 1 if device.is_cpu else None
        folder = Path(wp.config.kernel_cache_dir) / module.get_module_identifier(block_dim=block_dim)
        if not folder.is_dir():
            return False
        suffixes = (".o",) if device.is_cpu else (".ptx", ".cubin")
        return any(f.name.endswith(suffixes) for f in folder.iterdir())
    except Exception:  # noqa: BLE001 - private cache layout; only used for a progress message
        return None


def _nearest_node_distance(terrain: Any, x: float, y: float) -> float:
    """Distance from (x, y) to the terrain's nearest node (a grid's nearest row and column, a TIN's nearest point on a
    kept face: a point on none is in no mesh, and one with a NaN x or y made the distance NaN)."""
    if terrain.kind == "grid":
        rows, cols = terrain.shape
        (dx, dy), (x0, y0) = terrain.spacing, terrain.origin
        col = min(max(round((x - x0) / dx), 0), cols - 1)
        row = min(max(round((y - y0) / dy), 0), rows - 1)
        return math.hypot(x - (x0 + col * dx), y - (y0 + row * dy))
    used = terrain.points[terrain.point_used != 0]
    return float(np.hypot(used[:, 0] - x, used[:, 1] - y).min())


def _run_steps(args: argparse.Namespace, progress: Progress) -> int:
    import stepterrain as st

    from . import render

    out, png = _mesh_and_png(args.output, args.png)
    if not (0.0 <= args.gamma <= 1.0):
        raise InvalidInputError(f"--gamma must lie in [0, 1] (0 = original, 1 = stepped); got {args.gamma}")
    base = _isovalue_base(args)
    if args.floor is not None and not args.solid:
        raise InvalidInputError("--floor applies only with --solid")
    # close_solid's refusals, before the DEM is read and the whole terrain stepped (they came after both)
    if args.floor is not None and abs(finite_number(args.floor, "--floor")) > FLOAT32_MAX:
        raise InvalidInputError(f"--floor must fit in float32 (|x| < 3.4e+38); got {args.floor:g}")
    if args.lens_relative is not None and not args.lens_relative[2] > 0:  # else named as '--lens radius', in metres
        raise InvalidInputError(f"--lens-relative radius fraction must be positive; got {args.lens_relative[2]:g}")
    if args.lens_edge is not None and args.lens is None and args.lens_relative is None:
        raise InvalidInputError("--lens-edge applies only with --lens or --lens-relative")
    # isovalues' and circular_lens's refusals whatever the DEM, by their options before it is read (after it)
    if args.interval is not None and not (math.isfinite(args.interval) and args.interval > 0):
        raise InvalidInputError(f"--interval must be a positive finite number; got {args.interval!r}")
    if not math.isfinite(base):
        raise InvalidInputError(f"--base must be finite; got {base!r}")
    if args.lens is not None and not args.lens[2] > 0:  # finite: _floats
        raise InvalidInputError(f"--lens radius must be a positive finite number; got {args.lens[2]!r}")
    if args.lens_edge is not None and finite_number(args.lens_edge, "--lens-edge") < 0:
        raise InvalidInputError(f"--lens-edge must be >= 0; got {args.lens_edge!r}")
    if (args.lens is not None or args.lens_relative is not None) and args.gamma == 0.0:
        # original terrain inside the lens, --gamma 0 (the original terrain) outside: the mesh was the same without it
        option = "--lens" if args.lens is not None else "--lens-relative"
        raise InvalidInputError(f"{option} shows the original terrain inside it and --gamma outside: with --gamma 0 "
                                f"the terrain is original everywhere and the lens changes nothing; give --gamma > 0 "
                                f"or leave {option} out")
    if args.print_z_scale is not None and args.print_size is None:
        raise InvalidInputError("--print-z-scale applies only with --print-size (the model scaled for a print)")
    if args.print_size is not None:
        if out is None:  # the render shows the terrain as stepped: the print's scale shaped nothing
            raise InvalidInputError("--print-size scales the mesh file (-o); got it without -o")
        finite_number(args.print_size, "--print-size", positive=True)  # before the DEM is read and stepped
        if args.print_z_scale is not None:
            finite_number(args.print_z_scale, "--print-z-scale", positive=True)
    render_options = _given(args, {"size": (1280, 800), "z_scale": 2.0, "camera": "oblique"})
    if not (math.isfinite(args.z_scale) and args.z_scale > 0):
        raise InvalidInputError(f"--z-scale must be a positive number; got {args.z_scale}")
    _check_size(args.size, renders=png is not None)
    if png is None:  # (after their values, which are named first) they shape the render alone, and were ignored
        _refuse_unused(render_options, "--png (the render)", "without --png")
    if (args.colormap is not None and args.colormap.lower() != "none" and png is None and out is not None
            and out.suffix.lower() == ".stl"):
        # the level colours were dropped unsaid: an STL holds none, and no render showed them
        raise InvalidInputError(f"--colormap colours the mesh and the --png render; an .stl --output holds no "
                                f"colours: got --colormap {args.colormap} with --output {args.output!r} and no --png")
    args.colormap = "terrain" if args.colormap is None else args.colormap
    _check_outputs({"INPUT": args.input}, output=out, png=png)
    if png is not None:
        render.require_offscreen()  # fail before any work when no OpenGL context can exist here

    # load
    progress.stage("load", f"loading {args.input if args.input else 'the embedded Big Tujunga DEM'}")
    terrain = _input_terrain(args)
    lo, hi = terrain.height_range
    progress.done(f"{' x '.join(str(n) for n in terrain.shape)} nodes, heights {lo:g} to {hi:g},")

    # isovalues
    interval = args.interval
    if interval is None and args.levels is None:
        # the interval picked here, not one given: a refusal named an --interval the user never typed
        interval, values = _default_isovalues(lo, hi, base, interval_name="--interval", levels_name="--levels")
        progress.say(f"no --interval or --levels given: using --interval {interval:g}, a round interval "
                     f"giving {_counted(len(values), 'level')} over heights {lo:g} to {hi:g} "
                     f"(aim ~{TARGET_STEPS} steps)")
    else:
        values = st.isovalues((lo, hi), interval=interval, levels=args.levels, base=base)
    flat = None  # isovalues given: levels in another unit, or an interval over the relief, gave one flat terrace unsaid
    if args.interval is not None or args.levels is not None:
        from .stepped import _one_level

        span = f"{values[0]:g}" if len(values) == 1 else f"{values[0]:g} to {values[-1]:g}"
        given = f"--levels {span}" if args.levels is not None else f"--interval {interval:g} ({span})"
        lens = args.lens is not None or args.lens_relative is not None
        flat = _one_level(lo, hi, values, given, args.gamma, lens=lens)
    colors = _level_colors(args.colormap, len(values))

    # γ: scalar or a lens
    gamma: Any = args.gamma
    lens_metadata = None  # the lens as used, for the mesh file's metadata
    if args.lens is not None or args.lens_relative is not None:
        xmin, xmax, ymin, ymax = terrain.extent
        if args.lens is not None:
            cx, cy, radius = args.lens
        else:
            fx, fy, fr = args.lens_relative
            cx, cy = xmin + fx * (xmax - xmin), ymin + fy * (ymax - ymin)
            radius = fr * min(xmax - xmin, ymax - ymin)
            if not all(math.isfinite(v) for v in (cx, cy, radius)):  # named as the library's '--lens radius', inf
                raise InvalidInputError(f"--lens-relative {fx:g},{fy:g},{fr:g} places the lens at ({cx:g}, {cy:g}) "
                                        f"with radius {radius:g}: expected fractions of the extent (0 to 1 across "
                                        "it) giving a finite centre and radius")
        with warnings.catch_warnings():  # a lens beside the terrain: said below, naming --lens and --lens-relative
            warnings.filterwarnings("ignore", message="circular_lens: the lens at ")
            gamma = st.circular_lens(terrain, (cx, cy), radius, edge_width=args.lens_edge, outside=args.gamma)
        # the lens as circular_lens got it (--lens-relative's fractions resolved, --lens-edge's default r/4): "gamma":
        # "lens" alone lost the lens and the γ outside it (--gamma 0.3 and 0.7 files carried the same metadata)
        edge_width = radius / 4.0 if args.lens_edge is None else args.lens_edge
        lens_metadata = {"center": [float(cx), float(cy)], "radius": float(radius), "edge_width": float(edge_width),
                         "outside": float(args.gamma)}
        progress.say(f"lens at ({cx:.1f}, {cy:.1f}), radius {radius:.1f}: original terrain inside, "
                     f"gamma {args.gamma:g} outside")
        reach = radius + edge_width / 2.0  # γ < --gamma within
        # γ is float32 in the kernels: a --gamma below its least (1e-50) is 0, the original surface, lens or not
        stepping = bool(np.float32(args.gamma) > 0.0)
        if stepping and not (gamma.mask < np.float32(args.gamma)).any():  # the mesh came out as without it
            from .io import degrees_hint

            crs = f" in the DEM's CRS, {terrain.crs}" if terrain.crs else ""
            outside = math.hypot(max(xmin - cx, 0.0, cx - xmax), max(ymin - cy, 0.0, cy - ymax))
            if outside >= radius:
                why = (f"lies outside the terrain's extent x {xmin:.9g} to {xmax:.9g}, y {ymin:.9g} to {ymax:.9g} "
                       f"(--lens takes world coordinates{crs}; --lens-relative fractions of the extent)"
                       + degrees_hint(terrain, (cx - radius, cx + radius, cy - radius, cy + radius)))
            elif outside > 0:  # a sliver of it overlaps the extent, between the mask's samples (UnboundLocalError)
                why = (f"reaches only {radius - outside:.3g} into the terrain's extent x {xmin:.9g} to {xmax:.9g}, "
                       f"y {ymin:.9g} to {ymax:.9g}, less than its mask resolves; move it inside or give a larger "
                       "radius")
            else:  # centred on the terrain, too small to show: "move it inside" was advice for a lens already inside
                why = (f"lies inside the terrain's extent x {xmin:.9g} to {xmax:.9g}, y {ymin:.9g} to {ymax:.9g}, "
                       "but is smaller than its mask resolves; give a larger radius")
            warnings.warn(f"the lens at ({cx:.9g}, {cy:.9g}), radius {radius:.9g}, changes nothing: it {why}",
                          stacklevel=1)
        elif stepping and _nearest_node_distance(terrain, cx, cy) >= reach:
            spacing = f" (node spacing {abs(terrain.spacing[0]):.9g} x {abs(terrain.spacing[1]):.9g})"
            warnings.warn(f"the lens at ({cx:.9g}, {cy:.9g}), radius {radius:.9g}, changes nothing at the terrain's "
                          f"nodes: it holds none of them{spacing if terrain.kind == 'grid' else ''}; give a larger "
                          "radius", stacklevel=1)

    if png is not None:  # the render's copies of the mesh, at least the DEM's surface: before stepping
        try:
            render._check_render_budget(args.size[0], args.size[1], "--size", mesh=_surface_size(terrain),
                                        mesh_hint=_STEPS_RENDER_HINT, at_least=True)
        except st.OutputTooLargeError as exc:
            if args.solid:  # the budget the whole run needs, not the surface's render alone
                _solid_too(exc, args.size, lambda budget: st.stepped(
                    terrain, interval=interval, levels=args.levels, base=base, gamma=gamma, colors=colors,
                    solid=True, floor=args.floor, device=args.device, memory_budget=budget))
            raise

    # kernels: compile (first run on this machine) or load from Warp's cache
    from ._device import resolve_device

    device = resolve_device(args.device)
    warm = _kernel_cache_warm(device)
    if warm:
        progress.stage("kernels", f"loading Warp kernels for {device}")
    else:
        progress.stage("kernels", f"compiling Warp kernels for {device} (first run on this machine only)...")
    st.stepped(np.zeros((3, 3), np.float32), interval=1.0, device=device)
    progress.done("kernels ready")

    # step
    gamma_text = "lens" if isinstance(gamma, st.Lens) else f"{args.gamma:g}"
    progress.stage("step", f"stepping on {device}: {_counted(len(values), 'level')} ({values[0]:g} to {values[-1]:g}), "
                           f"gamma {gamma_text}")
    try:
        mesh = st.stepped(terrain, interval=interval, levels=args.levels, base=base, gamma=gamma,
                          colors=colors, solid=args.solid, floor=args.floor, device=device)
    except st.OutputTooLargeError as exc:
        if png is not None:
            _render_too(exc, args.size)
        raise
    progress.done(f"{_counted(len(mesh.faces), 'face')}, {_counted(len(mesh.vertices), 'vertex', 'vertices')}")
    if len(mesh.faces) == 0:
        warnings.warn("the mesh is empty: no triangle of the input has three finite heights", stacklevel=1)
    elif flat is not None:  # said of a mesh that has a surface (the heights of nodes on no triangle say nothing)
        warnings.warn(flat, stacklevel=1)

    from . import export

    if out is not None:  # before the render: a write refused after it wasted it
        export._check_write_budget(mesh, out.suffix.lower(), out)

    # render first (in memory), so a run that fails anywhere writes neither file
    image = None
    if png is not None:  # the mesh known: its copies for the render checked before it starts
        render._check_render_budget(args.size[0], args.size[1], "--size", mesh=(len(mesh.vertices), len(mesh.faces)),
                                    mesh_hint=_STEPS_RENDER_HINT)
        progress.stage("render", f"rendering {args.size[0]}x{args.size[1]} off-screen")
        image = render.render_mesh(mesh, window_size=args.size, z_scale=args.z_scale, camera=args.camera)
        progress.done()

    if args.print_size is not None:  # after the render, which shows the terrain as stepped (its --z-scale alone)
        mesh = export._scaled_for_print(mesh, args.print_size, 1.0 if args.print_z_scale is None else
                                        args.print_z_scale, copy=False, names=("--print-size", "--print-z-scale"))
        scale = mesh.metadata["print"]["scale"]
        extents = " x ".join(f"{v:.4g}" for v in mesh.extents)
        progress.say(f"scaled for a print: {extents} mm (one unit of the terrain's coordinates is {scale:.4g} mm)")
        if not args.solid:  # scaled as asked, but a sheet of no thickness: a slicer opened it as nothing to print
            warnings.warn("--print-size without --solid: the model is the open stepped surface, of no thickness, "
                          "which a slicer cannot print; add --solid for a watertight model with a base",
                          stacklevel=1)
        if out is not None and out.suffix.lower() in (".glb", ".gltf"):  # glTF's unit is the metre, by its spec
            warnings.warn(f"--print-size {args.print_size:g} writes millimetres, but glTF's unit is the metre: "
                          f"{out.name} opens {args.print_size:g} m wide in a glTF viewer or slicer; write .stl or "
                          ".3mf (millimetres) for a print", stacklevel=1)

    # write: each file atomically (temporary file + rename); no mesh file for a render-only run (--png without -o)
    if out is not None:
        progress.stage("write", f"writing {out}")
        metadata = {
            "generator": "stepterrain steps",
            **_input_metadata(args),
            "isovalues_count": int(len(values)),
            "interval": interval,
            "gamma": "lens" if isinstance(gamma, st.Lens) else float(args.gamma),
            "solid": bool(args.solid),
        }
        if lens_metadata is not None:
            metadata["lens"] = lens_metadata
        written = export.save_mesh(mesh, out, metadata=metadata)
        progress.done(_size(written))
    if image is not None:
        progress.stage("write_png", f"writing {png}")
        export._save_image(image, png, reused=False)
        progress.done(_size(png))
    return 0


#: What makes the mesh of a ``steps --png`` render smaller (a smaller --size does not: the mesh's copies weigh most).
_STEPS_RENDER_HINT = "give a larger --interval, --coarsen N or a --crop, or leave --png out"


def _render_too(exc: OutputTooLargeError, size: tuple[int, int]) -> None:
    """Raise ``exc``, a refusal of a mesh over the budget (:func:`~stepterrain._compaction.check_budget`'s, which
    carries the mesh's (vertices, faces)), again advising the budget its --png render needs too, where that is more
    than the mesh's: ``--memory-budget 20MB steps dem.tif -o m.glb --png p.png`` was told "at least 30MiB" for the
    mesh, and at 30MiB the render of it was refused, "at least 50MiB" (a budget per try, each too small). Returns
    where the render needs no more than the mesh, or the error carries no mesh (the caller raises it as it is)."""
    from ._compaction import _size_text
    from .render import _render_bytes

    nbytes, mesh = exc.nbytes, exc.mesh
    if mesh is None or not _advisable(exc):
        return
    render = _render_bytes(size[0], size[1], vertices=mesh[0], faces=mesh[1])  # as the --png check counts it
    if render <= nbytes:
        return
    raise _advised_again(exc, render, f"its --png render, {size[0]}x{size[1]}, needs {_size_text(render)} "
                                      f"for a mesh of at least {mesh[1]:,} faces") from None


def _solid_too(exc: OutputTooLargeError, size: tuple[int, int], count: Callable[[int], Any]) -> None:
    """Raise ``exc``, the --png render of a --solid run refused before stepping (its figure from the DEM's surface,
    the fewest faces the mesh can have), again advising the budget the whole run needs: the stepped solid's own (its
    count pass run by ``count``, the stepping under a budget of one byte, which refuses before allocating) or its
    render's with the most faces the solid has, whichever is more. ``steps --solid --png`` was told 200MiB for the
    render of the surface, then 500MiB for the solid: a budget per try, each too small. Returns where the count
    gives no figure (the caller raises ``exc`` as it is)."""
    from ._compaction import _size_text
    from .render import _render_bytes

    nbytes = exc.nbytes
    if not _advisable(exc):
        return
    try:
        count(1)
    except OutputTooLargeError as refused:
        solid, mesh = refused.nbytes, refused.mesh
    except StepTerrainError:  # refused before its budget was counted: no figure
        return
    else:  # pragma: no cover - a budget of one byte holds no solid
        return
    if solid is None or mesh is None:
        return
    render = _render_bytes(size[0], size[1], vertices=mesh[0], faces=mesh[1])
    need = max(nbytes, solid, render)
    raise _advised_again(exc, need, f"the whole run: the stepped solid needs {_size_text(solid)} and its "
                                    f"--png render, {size[0]}x{size[1]}, up to {_size_text(render)}") from None


def _advisable(exc: OutputTooLargeError) -> bool:
    """Whether ``exc`` declares the budget advice its message ends in (its ``advice``, " to at least 30MiB", with its
    ``nbytes``): :func:`_render_too` and :func:`_solid_too` advise again only a message they can rewrite (it matched
    the message's end against a figure of ``nbytes`` before)."""
    return exc.nbytes is not None and bool(exc.advice)


def _advised_again(exc: OutputTooLargeError, need: int, why: str) -> OutputTooLargeError:
    """``exc`` (:func:`_advisable`), its message's ``advice`` replaced by one of a budget of ``need`` bytes, ``why``
    in brackets after it; the same ``nbytes`` and ``mesh``, and no ``advice`` (the message ends in the bracket: it is
    not advised again)."""
    from ._compaction import _budget_figure

    return type(exc)(f"{str(exc).removesuffix(exc.advice or '')}{_budget_figure(need)} ({why})", nbytes=exc.nbytes,
                     mesh=exc.mesh)


def _surface_size(terrain: Any) -> tuple[int, int]:
    """(vertices, faces) of ``terrain``'s own surface, the fewest its stepped mesh has: a vertex per node a triangle
    with three finite heights uses, at least a terrace face per such triangle (walls and twins add more)."""
    from .terrain import grid_surface_counts

    if terrain.kind == "tin":
        return int(np.count_nonzero(terrain.point_used)), len(terrain.faces)  # the faces with three finite heights
    return grid_surface_counts(terrain.heights, terrain.has_nodata)


def _size(path: Path | str) -> str:
    try:
        n = os.path.getsize(path)
    except OSError:
        return "?"
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.1f} kB"


# ------------------------------------------------------------------------------------------ info
#: A file ``info`` reads at least this large says so first on a terminal (trimesh reads a mesh in one call, with no
#: progress to report: a 190 MB OBJ took a minute without a word).
_INFO_LOUD_BYTES = 20_000_000


def _reading(path: str | None, progress: Progress) -> bool:
    """Start a progress stage "reading PATH (N MB)..." for ``info`` when the file is a large one and stderr is a
    terminal, not piped or captured: info's stderr is otherwise empty when it succeeds (its summary is the output, and
    scripts read both); True when one was started."""
    if path is None or progress.quiet:
        return False
    isatty = getattr(progress.stream, "isatty", None)  # None with stderr closed (2>&-): sys.stderr is None
    try:
        if isatty is None or not isatty() or not os.path.isfile(path) or os.path.getsize(path) < _INFO_LOUD_BYTES:
            return False
    except (OSError, ValueError):  # a closed stream, a path the OS refuses: no line; the reader says what is wrong
        return False
    progress.stage("read", f"reading {path} ({_size(path)})...")
    return True


def _run_info(args: argparse.Namespace, progress: Progress) -> int:
    if sys.stdout is None:  # `info FILE >&-`: the summary went nowhere (print to None writes nothing) and it exited 0
        raise OSError("standard output is closed (>&-): info prints its summary there, so it has nowhere to go")
    loud = _reading(args.file, progress)
    if args.file and Path(args.file).suffix.lower() in MESH_EXTENSIONS:
        if args.height_unit is not None:  # it was ignored without a word: a mesh's z is not converted
            raise InvalidInputError(f"--height-unit applies to a DEM; {args.file!r} is a mesh file, described as "
                                    f"stored; got --height-unit {args.height_unit!r}")
        if args.band is not None:
            raise InvalidInputError(f"--band applies to a GeoTIFF DEM; {args.file!r} is a mesh file; got --band "
                                    f"{args.band}")
        if args.height_encoding is not None:
            raise InvalidInputError(f"--height-encoding applies to an RGB PNG DEM; {args.file!r} is a mesh file; got "
                                    f"--height-encoding {args.height_encoding!r}")
        if args.nodata is not None:
            raise InvalidInputError(f"--nodata applies to a DEM; {args.file!r} is a mesh file; got --nodata "
                                    f"{','.join(f'{v:g}' for v in args.nodata)}")
        if args.spacing is not None:
            raise InvalidInputError(f"--spacing applies to a DEM with no georeferencing; {args.file!r} is a mesh "
                                    f"file; got --spacing {','.join(f'{v:g}' for v in args.spacing)}")
        summary = _mesh_summary(Path(args.file))
    else:
        from .io import describe_dem

        try:
            terrain = _load_input(args.file, args.height_unit, spacing=args.spacing, band=args.band,
                                  height_encoding=args.height_encoding, nodata=args.nodata)
        except InvalidInputError as exc:  # load_dem's refusal listed the DEM formats alone: info reads meshes too
            if "unknown DEM extension" not in str(exc):
                raise
            meshes = ", ".join(MESH_EXTENSIONS)
            name = Path(args.file).name
            if name.lower().endswith(".gz") and Path(name[:-3]).suffix.lower() in MESH_EXTENSIONS:  # m.stl.gz
                raise InvalidInputError(f"{exc}; a mesh file ({meshes}) is read uncompressed only: gunzip it first, "
                                        f"`gunzip -k {args.file}`") from None
            raise InvalidInputError(f"{exc}; or a mesh file: {meshes}") from None
        summary = describe_dem(terrain)
    if loud:
        progress.done()
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        width = max(len(k) for k in summary)
        for key, value in summary.items():
            print(f"{key:<{width}}  {_NONE_TEXT.get(key, 'None') if value is None else _fmt(value)}")
    return 0


#: What the text output of ``info`` says for a None that is not simply "unknown" (JSON keeps null).
_NONE_TEXT = {"height_unit": "as stored (no unit named; --height-unit names one)"}


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.2f}".rstrip("0").rstrip(".") if abs(value) >= 1e4 else f"{value:.6g}"
    if isinstance(value, (tuple, list)):
        if len(value) > _FMT_ITEMS:  # a long list (isovalues at a fine interval): its ends and its length
            shown = [_fmt(v) for v in value[: _FMT_ITEMS - 2]] + ["...", _fmt(value[-1])]
            return "(" + ", ".join(shown) + f"; {len(value)} values)"
        return "(" + ", ".join(_fmt(v) for v in value) + ")"
    return str(value)


#: The most items of a list the text output of ``info`` writes out in full (JSON writes every one).
_FMT_ITEMS = 8


def _texture_size(mesh: Any) -> list[int] | None:
    """The (width, height) of the texture image a mesh read by ``read_mesh`` carries (an OBJ's material image, a
    glTF's base colour texture), None when it has none."""
    if mesh.visual.kind != "texture":
        return None
    material = getattr(mesh.visual, "material", None)
    for name in ("image", "baseColorTexture"):
        image = getattr(material, name, None)
        if image is not None and hasattr(image, "size"):
            return [int(image.size[0]), int(image.size[1])]
    return None


def _mesh_summary(path: Path) -> dict[str, Any]:
    import trimesh

    from .errors import DataFileError
    from .export import read_mesh

    # with what trimesh's reader misses (a file of points, a 3MF's colour group); a DataFileError for a missing file,
    # a folder named x.glb, or one trimesh cannot read (its error in the message)
    mesh = read_mesh(path)
    if not isinstance(mesh, trimesh.Trimesh):  # an empty mesh is one (steps writes it, with a warning): described
        raise DataFileError(f"{str(path)!r} holds no triangle mesh")
    if path.suffix.lower() == ".stl":  # STL stores every triangle's corners apart: weld them, as its readers do, or
        mesh.merge_vertices()  # a watertight solid (steps --solid -o print.stl) read as open, 3 vertices per face
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    finite = np.isfinite(vertices).all(axis=1)
    # the bounds of the finite vertices (None without any: NaN is no JSON); a NaN or inf vertex is counted, not
    # smeared over the bounds
    lo = hi = None
    if finite.any():
        lo, hi = (tuple(values.tolist()) for values in (vertices[finite].min(axis=0), vertices[finite].max(axis=0)))
    summary: dict[str, Any] = {
        "kind": "mesh",
        "file": str(path),
        "bytes": path.stat().st_size,
        "vertices": int(len(mesh.vertices)),
        "faces": int(len(mesh.faces)),
        "bounds_min": lo,
        "bounds_max": hi,
        "nonfinite_vertices": int(len(vertices) - finite.sum()),
        # trimesh calls a mesh without faces watertight (no edge is open): points and empty files enclose nothing
        "watertight": bool(len(mesh.faces) and mesh.is_watertight),
        "winding_consistent": bool(mesh.is_winding_consistent),
        "vertex_colors": bool(mesh.visual.kind == "vertex"),
        "face_colors": bool(mesh.visual.kind == "face"),  # PLY and 3MF keep them (glTF: vertex means)
        # the texture image's (width, height), None without one: a textured GLB, glTF or OBJ (texture --mesh, globe
        # --texture) read "vertex_colors False, face_colors False", as if it had no colour at all
        "texture": _texture_size(mesh),
    }
    # stepped's face attributes, which a .ply keeps: the levels its faces lie on (a solid's skirts and base, -1, are
    # none) and its walls
    attributes = mesh.face_attributes
    level, wall = attributes.get("level"), attributes.get("wall")
    if isinstance(level, np.ndarray) and level.ndim == 1 and level.dtype.kind in "iu" and len(level) == len(mesh.faces):
        summary["levels"] = int(len(np.unique(level[level >= 0])))
    if isinstance(wall, np.ndarray) and wall.dtype == np.bool_ and wall.shape == (len(mesh.faces),):
        summary["wall_faces"] = int(wall.sum())
    items = []
    for key, value in (mesh.metadata or {}).items():
        # a record of plain items as meta.KEY.ITEM: steps --print-size's 'print' (size, scale, z_scale, origin), the
        # mapping of a print model back to the world, was left out, a dict
        if isinstance(value, dict) and not str(key).startswith("_"):
            items.extend((f"{key}.{name}", item) for name, item in value.items())
        else:
            items.append((key, value))
    for key, value in items:
        if isinstance(value, str):  # an STL header is 80 bytes padded with NULs, which made the text output binary
            value = value.strip("\x00").strip()
            if not value:
                continue
        # lists of plain values too: the globe's eye (eye_lat_lon_alt), a batch tile's node_rows/node_cols, the
        # isovalues; they were left out, so `info` showed no eye for a view-dependent globe mesh
        if isinstance(value, (tuple, list)) and all(isinstance(v, (str, int, float, bool)) for v in value):
            value = list(value)
        # meta.KEY clashes with none of the summary's own fields: a key named like one ("faces", "kind") was left
        # out, checked by its plain name; the first of two items giving one meta.KEY (a "print.size" key beside the
        # "print" record's size) is kept
        if isinstance(value, (str, int, float, bool, list)) and f"meta.{key}" not in summary:
            summary[f"meta.{key}"] = value
    return summary


# ------------------------------------------------------------------------------------------ entry point
#: An error message that starts by naming a library argument: ``interval must ...``, ``face_size must ...``,
#: ``device='cuda' needs ...`` (the house style names the argument first).
_ARGUMENT_FIRST = re.compile(r"^([a-z][a-z0-9_]*)(=| )")

#: Second words that show a message is about a thing, not about the argument of that name ("mesh has no faces",
#: "output folder ... is not writable"): such messages keep their wording.
_NOT_ABOUT_THE_ARGUMENT = frozenset({"has", "folder", "file", "is", "of", "with"})

#: Library argument names whose option is spelled otherwise, per subcommand (checked before the general rule).
#: closeup's CloseUp checks name "close-up scale" etc., which reached the command line as they were.
#: The one-word entries apply mid-message too: batch's ``tile_size`` is --tile, a stepped close-up's ``interval=`` is
#: --stepped, a render's ``window_size`` is --size.
_OPTION_ALIASES = {
    "steps": {"lens edge_width": "--lens-edge", "window_size": "--size"},
    "closeup": {"close-up scale": "--scale", "close-up offset": "--offset", "close-up rotation": "--rotation",
                "close-up color": "--color", "close-up stepped interval": "--stepped", "interval": "--stepped",
                "window_size": "--size"},
    # tile_size: "tile_size applies to one raster" reached the user as it was; window_size: overview_image's, of the
    # --png; overview_size: batch's name for that window_size; output_dir: "output_dir '/dev/stdout' exists and is
    # not a folder"
    "batch": {"tile_size": "--tile", "window_size": "--size", "overview_size": "--size", "output_dir": "--output",
              "overview_z_scale": "--z-scale"},
    "globe": {"window_size": "--size"},
    "texture": {"window_size": "--size"},
}

#: render._check_visible's advice for a fitted camera that shows the mesh under a pixel from any z_scale: its
#: ``camera`` is --camera in the subcommands that render with one.
_LOOK_FROM = {"look from another direction (camera)": "look from another direction (--camera)"}

#: Library arguments named as plain words in mid-sentence, which the general rule leaves alone (a plain word may be
#: just a word: "gives 2000 levels"), per subcommand: the library's phrase and the command line's.
#: SMALLER_HINT (a stepped mesh over the budget) as steps' and batch's options give it: it named the
#: Terrain methods beside the options, and "coarsen the isovalues", which no option says (a larger --interval does).
_SMALLER_OPTIONS = "crop or coarsen the DEM (--crop, --coarsen) or give a larger --interval (fewer --levels)"

_OPTION_PHRASES = {
    "steps": {"bring base closer": "bring --base closer", **_LOOK_FROM, SMALLER_HINT: _SMALLER_OPTIONS},
    "closeup": {**_LOOK_FROM,
                # closeup._check_framed's, of a close-up moved absurdly far or scaled absurdly large: no option of
                # closeup gives bounds
                "move it nearer, or frame what to see with bounds": "move it nearer: give it a smaller --offset",
                "scale it down, or frame what to see with bounds": "scale it down: give it a smaller --scale",
                # closeup.STEPPED_CLOSEUP_HINT, of a --stepped close-up over the budget
                "step the close-up at a larger interval (CloseUp.stepped) or give it a smaller ROI, or crop or coarsen "
                "the terrain (Terrain.crop, Terrain.coarsen)": "step the close-up at a larger interval (--stepped) or "
                "give it a smaller ROI (the r of --roi x,y,r or --roi-relative fx,fy,fr), or crop or coarsen the DEM "
                "(--crop, --coarsen)"},
    "batch": {"bring base closer": "bring --base closer", **_LOOK_FROM, SMALLER_HINT: _SMALLER_OPTIONS,
              # batch._check_unreferenced's, in a failed item's line ("failed KEY: InvalidInputError: spacing ...")
              ": spacing applies to DEM files": ": --spacing applies to DEM files",
              "render no overview": "leave --png out",  # batch._check_overview's hint
              "a larger max_items= or --tile": "a larger --tile"},  # overview_image's partial mosaic
    "globe": {"raise the error": "raise --error", "--radius + exaggeration": "--radius + --exaggeration",
              # load_dem's refusal of a raster over the budget: globe has no --crop, and meshes the whole globe
              WHOLE_RASTER_HINT: "coarsen it first (gdal_translate -outsize; the globe needs the whole grid)"},
    # the same refusal: info has no --crop either (steps, closeup and texture --crop read only the window)
    "info": {WHOLE_RASTER_HINT: "coarsen it first (gdal_translate -outsize)"},
    # a rotated, south-up or east-to-west GeoTIFF --image (texture_lod's refusal names image_layer's argument)
    "texture": {"pass extent=(xmin, xmax, ymin, ymax)": "give --image-extent xmin,xmax,ymin,ymax",
                # image_layer's warning of an image over a sliver of the terrain
                "georeferencing (or extent=)": "georeferencing (or --image-extent)", **_LOOK_FROM},
}

#: Advice in the library's messages that only a Python caller can follow, left out of every subcommand's lines: no
#: option places the terrain at a local origin or moves the mesh (the ``.stl`` warnings: their formats' advice stays).
_PYTHON_ONLY = (_STL_OPEN_LOCAL, _STL_ROUNDING_LOCAL)

#: closeup's ``closeups[k]: ROI box ...``: the k-th ROI (counted from 1), given by --roi or --roi-relative.
_CLOSEUP_INDEX = re.compile(r"^closeups\[(\d+)\]: (?=ROI box)")

#: closeup's ``closeups[k]`` in mid-message (closeup._check_framed's "because closeups[0] (offset (0.0, 0.0, 1e9)) is
#: drawn ..."), with the offset or scale it names when it does: the k-th close-up (counted from 1) and its --offset
#: or --scale.
_CLOSEUP_NAMED = re.compile(r"closeups\[(\d+)\](?: \((offset|scale) \(([^()]*)\)\))?")


def _closeup_named(match: re.Match[str]) -> str:
    """A :data:`_CLOSEUP_NAMED` match in the CLI's terms: ``close-up 1``, ``close-up 1 (--offset 0,0,1e+09)``,
    ``close-up 1 (--scale 1e+06,1e+06,1e+06)``."""
    named = f"close-up {int(match.group(1)) + 1}"
    if match.group(2) is None:
        return named
    return f"{named} (--{match.group(2)} {','.join(f'{float(v):g}' for v in match.group(3).split(','))})"

#: A library argument named anywhere in a message, as a whole word: ``name=`` (``needs interval= or levels=``,
#: ``got interval=5``) or a snake_case name (``use a smaller face_size``). A plain word is not taken for an argument
#: in mid-sentence ("gives 2000 levels"); quoted text, paths and ``name[k]`` are left as they are.
_ARGUMENT_ANYWHERE = re.compile(r"(?<![\w./'\"-])([a-z][a-z0-9]*(?:_[a-z0-9]+)*)(?:(=)(?=([^\s;,)]?))|(?![\w=\[-]))")


#: An option followed by the library's pointer to that same option: ``--tile (the CLI's --tile)``.
_CLI_ASIDE = re.compile(r"(--[a-z][a-z0-9-]*) \(the CLI's \1\)")


def _library_options(sub: argparse.ArgumentParser) -> dict[str, str]:
    """The subcommand's options by the library argument each gives: ``face_size`` -> ``--face-size`` (every
    ``--long-option``), then the names it spells otherwise (the one-word entries of :data:`_OPTION_ALIASES`)."""
    options = {string[2:].replace("-", "_"): string for action in sub._actions for string in action.option_strings
               if string.startswith("--")}
    command = sub.prog.split()[-1]
    options.update({name: option for name, option in _OPTION_ALIASES.get(command, {}).items() if " " not in name})
    return options


def _names_as_options(message: str, options: dict[str, str]) -> str:
    """``message`` with each library argument it names anywhere (see :data:`_ARGUMENT_ANYWHERE`) spelled as the
    option: ``interval=5`` -> ``--interval 5``, ``interval= or`` -> ``--interval or``, ``face_size`` ->
    ``--face-size``; names the subcommand has no option for stay as they are."""

    def option(match: re.Match[str]) -> str:
        name, equals, value = match.groups()
        if name not in options or (equals is None and "_" not in name):
            return match.group(0)
        return options[name] + (" " if equals and value else "")

    # the library's pointer to the option, now that the option is named: "give --tile (the CLI's --tile)" said it twice
    return _CLI_ASIDE.sub(r"\1", _ARGUMENT_ANYWHERE.sub(option, message))


def _subcommand(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices.get(name)
    return None


def _as_option(message: str, sub: argparse.ArgumentParser | None) -> str:
    """``message`` with the library arguments it names spelled as the subcommand's options where it has them: the
    leading one (``interval must`` -> ``--interval must``, ``device='cuda'`` -> ``--device 'cuda'``), then any
    other as a whole word (:func:`_names_as_options`: ``needs interval= or levels=`` -> ``needs --interval or
    --levels``, ``use a smaller face_size`` -> ``use a smaller --face-size``), then the plain-word phrases of
    :data:`_OPTION_PHRASES` (``bring base closer`` -> ``bring --base closer``). A command-line user never typed
    ``face_size``; nor can they follow :data:`_PYTHON_ONLY`'s advice, left out (``steps --solid -o x.stl`` was told to
    step the terrain at ``origin=(0, 0)``). For errors, warnings and batch's failure lines alike."""
    if sub is None:
        return message
    for advice in _PYTHON_ONLY:  # first: the options' spelling below would not find it again
        message = message.replace(advice, "")
    command = sub.prog.split()[-1]
    text = _leading_as_option(message, sub, command)
    for phrase, spelled in _OPTION_PHRASES.get(command, {}).items():
        text = text.replace(phrase, spelled)
    if command == "closeup":  # the library's closeups[k] anywhere else: a Python argument no option names
        text = _CLOSEUP_NAMED.sub(_closeup_named, text)
    if text.startswith("--device must be one of "):  # the library's device=None is the option left out here
        text = text.replace(" (or None); got", ", or left out for Warp's default; got", 1)
    return text


def _leading_as_option(message: str, sub: argparse.ArgumentParser, command: str) -> str:
    """:func:`_as_option` but for its phrases."""
    options = _library_options(sub)
    indexed = _CLOSEUP_INDEX.match(message) if command == "closeup" else None
    if indexed is not None:
        rest = _names_as_options(message[indexed.end():], options)
        return f"--roi/--roi-relative (close-up {int(indexed.group(1)) + 1}): {rest}"
    for name, option in _OPTION_ALIASES.get(command, {}).items():
        if message.startswith(name + " "):
            return option + _names_as_options(message[len(name):], options)
    match = _ARGUMENT_FIRST.match(message)
    if match is None or message[match.end():].split(" ", 1)[0] in _NOT_ABOUT_THE_ARGUMENT:
        return _names_as_options(message, options)
    option = "--" + match.group(1).replace("_", "-")
    if option not in options.values():
        return _names_as_options(message, options)
    rest = message[match.end():]
    aside = f"(the CLI's {option}) "  # the library's pointer to the option, once the option leads: said twice
    return option + " " + _names_as_options(rest[len(aside):] if rest.startswith(aside) else rest, options)


def _warning_line(prog: str, sub: argparse.ArgumentParser | None = None) -> Any:
    """A ``warnings.showwarning`` that prints the library's warnings as one ``PROG: warning:`` line (``stepterrain
    CMD: warning:``; an example's ``flood.py: warning:``, as its parser's errors begin), no source line, on stderr,
    the library arguments they name spelled as ``sub``'s options (:func:`_as_option`: ``pass height_unit='ft'`` ->
    ``pass --height-unit 'ft'``); a progress bar on screen (batch's) is cleared first and drawn again below it."""

    def show(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        text = f"{prog}: warning: {_as_option(str(message), sub)}"
        if "tqdm" in sys.modules:  # else the line was appended to the bar's line
            sys.modules["tqdm"].tqdm.write(text, file=sys.stderr)
            sys.stderr.flush()
        else:
            print(text, file=sys.stderr, flush=True)

    return show


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``stepterrain`` command; return the exit status (0 ok, 2 bad input or usage, 130 interrupted, 143
    terminated: SIGTERM, which ends the run as Ctrl-C does, its partial files removed; 129 for SIGHUP likewise).

    ``argv`` defaults to ``sys.argv[1:]``. Errors derived from :class:`~stepterrain.errors.StepTerrainError`
    print one line on stderr, without a traceback. With stderr closed (``2>&-``: Python's ``sys.stderr`` is None)
    what it would print there is dropped, not written to stdout.

    One command at a time in a process: while it runs, its ``--memory-budget`` is the process's memory budget and
    its warning lines replace ``warnings.showwarning`` (both put back after), for every thread. Threads that serve
    requests call the library's functions instead (``memory_budget=`` gives a call its own budget).
    """
    if sys.stderr is not None:
        return _main(argv)
    # stderr closed: print(file=None) writes to stdout, so the progress lines and errors landed in the command's
    # output (`steps ... 2>&-` printed its stages on stdout; `info --json 2>&-` would be no JSON on an error)
    with open(os.devnull, "w") as sink:
        sys.stderr = sink
        try:
            return _main(argv)
        finally:
            sys.stderr = None


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:
        print(exc, file=sys.stderr)
        return EXIT_USAGE
    except SystemExit as exc:  # --help, --version
        return int(exc.code or 0)
    if getattr(args, "run", None) is None:
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    after = getattr(args, "memory_budget_after", None)  # --memory-budget after the subcommand (its parser's)
    if after is not None:
        if args.memory_budget not in (None, after):  # the subcommand's replaced the command's silently
            # as typed, as the option given twice to one parser is named (it said "1000000000 bytes" for 1GB)
            before = _as_typed(parser, "memory_budget", args.memory_budget)
            after_text = _as_typed(_subcommand(parser, args.command), "memory_budget_after", after)
            print(f"stepterrain: error: argument --memory-budget: given twice ({before} before {args.command}, then "
                  f"{after_text} after it); it takes one value: give it once", file=sys.stderr)
            return EXIT_USAGE
        args.memory_budget = after
    progress = Progress(quiet=args.quiet)
    previous_budget = get_memory_budget()
    previous_hint = budget_hint(_CLI_BUDGET_HINT)  # refusals in this process name the option
    previous_terms = _terminate_as_interrupt()
    try:
        if args.memory_budget is not None:  # for this run only: main() may be called in-process
            set_memory_budget(args.memory_budget)
        with warnings.catch_warnings():
            # restored on exit by catch_warnings
            warnings.showwarning = _warning_line(f"stepterrain {args.command}", _subcommand(parser, args.command))
            # before any input is read (a large DEM loaded first), unless the work runs on another machine: batch
            # --scheduler tcp://... --device cuda from a login node without a GPU was refused for lacking one
            if getattr(args, "device", None) is not None and getattr(args, "scheduler", None) in (None, "serial"):
                from ._device import resolve_device

                resolve_device(args.device)
            return int(args.run(args, progress))
    except StepTerrainError as exc:
        message = _as_option(str(exc), _subcommand(parser, args.command))  # a budget's hint names the option already
        print(f"stepterrain {args.command}: error: {message}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # `stepterrain info FILE | head` when the reader left: "error: [Errno 32] Broken pipe"
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except OSError as exc:  # a write failing below the library's own checks (disk full, permissions)
        print(f"stepterrain {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as exc:
        if isinstance(exc, _Terminated):
            hung_up = exc.signum == getattr(signal, "SIGHUP", None)
            with contextlib.suppress(OSError):  # the terminal that hung up takes no more lines (EIO)
                print(f"stepterrain: {'hung up' if hung_up else 'terminated'}", file=sys.stderr)
            return EXIT_HUNG_UP if hung_up else EXIT_TERMINATED
        print("stepterrain: interrupted", file=sys.stderr)
        return 130
    finally:
        set_memory_budget(previous_budget)
        budget_hint(previous_hint)
        for number, handler in previous_terms.items():
            signal.signal(number, handler)


#: The exit status of a run ended by SIGTERM (128 + 15, as a shell reports a command that SIGTERM killed).
EXIT_TERMINATED = 143


#: The exit status of a run ended by SIGHUP (128 + 1: its terminal closed, its ssh connection dropped).
EXIT_HUNG_UP = 129


class _Terminated(KeyboardInterrupt):
    """SIGTERM (or SIGHUP) during a command, raised as Ctrl-C raises KeyboardInterrupt, so that the run ends as after
    Ctrl-C; ``signum`` is the signal's number."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__()
        self.signum = signum


def _raise_terminated(signum: int, frame: Any) -> None:
    raise _Terminated(signum)


def _terminate_as_interrupt() -> dict[int, Any]:
    """Make SIGTERM and SIGHUP raise :class:`_Terminated` while the command runs; return the handlers to put back
    ({signal: handler}, empty where none was replaced). `kill`, `timeout` or a job scheduler's SIGTERM killed the
    process outright: the file being written stayed as a hidden partial file (tens of MB of a tile), batch's manifest
    lost its last second of finished items and the LocalCluster's semaphores were reported leaked; SIGHUP (the
    terminal closed, the ssh connection dropped) left the same. Only the system's default action is replaced (a
    program that calls main() and handles SIGTERM keeps its handler; `nohup`'s ignored SIGHUP stays ignored), and
    only in the main thread."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for number in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)):
        if number is not None and signal.getsignal(number) is signal.SIG_DFL:
            previous[number] = signal.signal(number, _raise_terminated)
    return previous


#: The exit status of a run whose standard output was closed by its reader (128 + SIGPIPE, as a shell reports a
#: command that SIGPIPE ended).
EXIT_BROKEN_PIPE = 141


def _silence_stdout() -> None:
    """Point standard output at the null device, so that the interpreter's final flush of what is still buffered
    does not raise a second BrokenPipeError at exit (the recipe of Python's signal documentation)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # a captured stdout (tests, an embedding program) has no fd
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
