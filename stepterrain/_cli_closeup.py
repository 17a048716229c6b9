"""``stepterrain closeup``: render a terrain with 3D close-ups (paper 001) to PNG, GIF or MP4.

    stepterrain closeup --roi-relative 0.3,0.5,0.12 --scale 1.5 --offset 0,0,4000 -o out/closeup.png
"""

from __future__ import annotations

import argparse
import importlib.util
import math
from typing import Any

from .errors import InvalidInputError, MissingDependencyError
from .export import MESH_EXTENSIONS

_EPILOG = """\
examples:
  stepterrain closeup -o out/closeup.png
      the embedded Big Tujunga DEM with one close-up at the centre, lifted and enlarged
  stepterrain closeup --roi 390000,3798000,2500 --scale 2 --offset 0,0,5000 --stepped 100 -o steps.png
      a stepped close-up (MPFR) over the continuous overview (paper 001, Fig. 1)
  stepterrain closeup --roi-relative 0.5,0.5,0.15 --png view.png
      the render alone: --png without -o (the same picture as -o view.png)
  stepterrain closeup --roi-relative 0.25,0.5,0.12 --roi-relative 0.75,0.5,0.12 --scale 1.5 \\
      --offset 0,0,5000 --anchor ends --gif spin.gif --spin 0.25 --frames 24 -o first.png
      two close-ups (one per --roi), a spinning animation as GIF (or .mp4); without -o, the animation alone
  stepterrain closeup dem.tif --roi-relative 0.5,0.5,0.2 --shape rectangle --scalars slope -o slope.png
  stepterrain closeup --roi-relative 0.5,0.5,0.15 -o scene.glb --png scene.png
      the overview, close-up and anchor as one colored mesh (anchor opacity in the vertex alpha), and a render

--scale, --offset, --rotation, --color and --stepped apply to every close-up when given once, or one per
ROI (--roi and --roi-relative, in the order given) when given as often. Values may start with a minus:
--offset -500,0,3000.
"""


class _RoiAction(argparse.Action):
    """``action="append"`` to its own option's list, and to ``rois`` as (option, value) in command-line order: the
    close-ups of --roi and --roi-relative given in turn keep that order, which the per-close-up options (and the
    close-up numbers in messages) follow; every --roi came first, so --color red --color blue went to the wrong
    close-ups."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        setattr(namespace, self.dest, [*(getattr(namespace, self.dest, None) or []), values])
        namespace.rois = [*(getattr(namespace, "rois", None) or []), (self.dest, values)]


def _color_option(text: str) -> str | tuple[float, ...]:
    """--color: ``r,g,b`` (numbers, in [0, 1] as CloseUp checks) as that RGB tuple, any other text as matplotlib reads
    it (a name, '#rrggbb'); matplotlib reads no "1,0,0", which the refusal's "RGB in [0, 1]" offered. Checked here,
    before the DEM is read, so that a refusal names what was typed (CloseUp's named the parsed tuple, (1.0, 2.0, 0.0)
    for ``--color 1,2,0``)."""
    from .cli import _untyped
    from .closeup import _color

    parts = text.split(",")
    value: str | tuple[float, ...] = text
    if len(parts) == 3 and not _untyped(text):  # 0_0,0,0 is no r,g,b (float() reads 0_0 as 0): matplotlib's to read
        try:
            value = tuple(float(part) for part in parts)
        except ValueError:
            pass
    try:
        _color(value, "--color")
    except InvalidInputError:
        raise argparse.ArgumentTypeError(f"expected a matplotlib color name, '#rrggbb' or r,g,b with each number in "
                                         f"[0, 1]; got {text!r}") from None
    return value


def _spin(text: str) -> float:
    """--spin: a finite non-zero number of turns per second (negative turns the other way), refused by argparse:
    inf, NaN and 0 were refused only after the output paths and the other options were checked, 1e308 not at all."""
    from .cli import _real

    try:
        value = _real(text)  # in ASCII digits, without underscores
    except argparse.ArgumentTypeError:
        value = math.nan
    if not math.isfinite(value) or value == 0:
        raise argparse.ArgumentTypeError(f"expected a finite non-zero number of turns per second (negative: the "
                                         f"other way); got {text!r}")
    return value


def add_parser(commands: Any) -> None:
    """Add the ``closeup`` subcommand to the ``stepterrain`` parser."""
    from .cli import _add_camera, _add_device, _add_input_options, _floats, _path, _real, _whole, _window

    p = commands.add_parser(
        "closeup",
        help="detail+overview views: 3D close-ups of ROIs over the terrain (paper 001)",
        description="Render a DEM with 3D close-ups (Trapp & Döllner 2019): each ROI is lifted, scaled and turned "
                    "into a detail view joined to the overview by a colored anchor; PNG, and GIF/MP4 when spinning. "
                    "Give -o, --png, --gif or several (--png alone writes only the render, --gif alone only the "
                    "animation).",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_input_options(p)
    p.add_argument("--roi", type=_floats(3, "x,y,r"), action=_RoiAction, metavar="x,y,r",
                   help="a close-up's ROI: centre and radius (half size) in world units; repeat for more (default, "
                        "without --roi or --roi-relative: one at the DEM's centre, radius 0.12 of its shorter side)")
    p.add_argument("--roi-relative", type=_floats(3, "fx,fy,fr"), action=_RoiAction, metavar="fx,fy,fr",
                   help="ROI centre as fractions of the extent from its south-west corner (0,0; 1,1 the north-east, "
                        "whichever way the DEM's rows run), radius as a fraction of its shorter side")
    p.add_argument("--shape", choices=("circle", "rectangle", "rounded"), default="circle",
                   help="ROI shape from the library (default circle)")
    p.add_argument("--edge", type=_real, default=None, metavar="W",
                   help="soft edge width in world units, at most the ROI radius (default: a fifth of the radius)")
    p.add_argument("--scale", type=_floats(None, "s or sx,sy,sz"), action="append", metavar="s",
                   help="close-up scale: s or sx,sy,sz (default 1.5)")
    p.add_argument("--offset", type=_floats(3, "dx,dy,dz"), action="append", metavar="dx,dy,dz",
                   help="close-up displacement in world units (default: lifted by a fifth of the extent's longer "
                        "side, at least 0.3 of its north-south depth: it clears the overview seen from the south)")
    p.add_argument("--rotation", type=_floats(2, "alpha,beta (degrees)"), action="append", metavar="a,b",
                   help="tilt about x and turn about the vertical, degrees (default 0,0; whole turns are taken off)")
    p.add_argument("--color", type=_color_option, action="append", metavar="COLOR",
                   help="close-up color: a matplotlib name, #rrggbb or r,g,b in [0, 1] (default: a palette)")
    p.add_argument("--stepped", type=_real, action="append", metavar="INTERVAL",
                   help="the close-up shows the stepped terrain at this interval (a mapping of its own: multi-pass "
                        "forward rendering, MPFR); 0: continuous")
    p.add_argument("--anchor", default=None, metavar="PRESET",
                   help="anchor transparency: opaque, linear, inverse, ends, hidden (default linear); in the renders "
                        "(a .png --output, --png, --gif) and the vertex alpha of a .glb, .gltf, .ply or .3mf "
                        "--output: refused with an .obj or .stl --output alone, which hold no alpha")
    p.add_argument("--billboard", action="store_true",
                   help="overview-independent close-ups: orthographic, seen from above; in the renders (a .png "
                        "--output, --png, --gif) only, not in a scene mesh --output")
    p.add_argument("--scalars", choices=("height", "slope", "aspect", "none"), default=None,
                   help="overview data mapping (default height): its colours, in the renders and a mesh --output's "
                        "vertex colours: refused with an .stl --output alone, which holds no colours")
    p.add_argument("--colormap", default=None, metavar="NAME",
                   help="matplotlib colormap of the overview and the stepped close-ups (default terrain): refused "
                        "with --scalars none and no --stepped close-up, which leave it nothing to colour")
    p.add_argument("--z-scale", type=_real, default=None, metavar="S",
                   help="vertical exaggeration of the render and the animation (default 2)")
    _add_device(p)
    p.add_argument("-o", "--output", type=_path, metavar="OUT",
                   help="the rendered image (.png), or the scene as a mesh by extension: " + " ".join(MESH_EXTENSIONS)
                   + " (overview, close-ups and anchors with vertex colors, the anchors' transparency in their "
                     "alpha; .obj holds RGB only, the anchors opaque: --anchor is refused with it unless --png or "
                     "--gif renders them; .stl holds no colors: --colormap, --color, --scalars and --anchor are "
                     "refused with it unless --png or --gif renders them); optional with --png or --gif")
    p.add_argument("--png", type=_path, metavar="OUT.png",
                   help="write the render here: beside a mesh --output, or alone without -o (a render-only run, as "
                        "a .png --output)")
    p.add_argument("--size", type=_window, default=None, metavar="WxH",
                   help="image size of the render and the animation (default 1280x720)")
    p.add_argument("--gif", type=_path, metavar="OUT.gif|OUT.mp4",
                   help="write a spinning animation (beside -o or --png, or alone: the animation only)")
    p.add_argument("--spin", type=_spin, default=None, metavar="TURNS/S",
                   help="spin speed of the animation in turns per second, negative the other way, at most half a "
                        "turn a frame: |TURNS/S| <= --fps / 2 (default 0.25); with --gif only, of 2 --frames or "
                        "more (the still render, the scene mesh and the first frame show the close-ups before any "
                        "spin)")
    p.add_argument("--frames", type=_whole, default=None, metavar="N",
                   help="animation frames (default 24); with --gif only")
    p.add_argument("--fps", type=_real, default=None, metavar="FPS",
                   help="animation frame rate (default 12); with --gif only")
    _add_camera(p, "the render and the animation (a .png --output, --png or --gif), framing the overview and "
                   "the close-ups")
    p.set_defaults(run=_run_closeup)


def _per_closeup(values: list | None, n: int, default: Any, name: str) -> list:
    if not values:
        return [default] * n
    if len(values) == 1:
        return values * n
    if len(values) != n:
        raise InvalidInputError(f"{name} must be given once or once per ROI ({n}); got {len(values)}")
    return list(values)


def _run_closeup(args: argparse.Namespace, progress: Any) -> int:
    from . import render
    from ._compaction import check_budget
    from .cli import (
        _check_output,
        _check_outputs,
        _check_size,
        _counted,
        _given,
        _input_metadata,
        _input_terrain,
        _mesh_and_png,
        _refuse_unused,
    )
    from .closeup import (
        _MAX_CLOSEUPS,
        _MAX_OFFSET,
        _MIN_PIXELS_PER_CLOSEUP,
        ROI,
        TRANSFER_PRESETS,
        AnchorStyle,
        CloseUp,
        _check_animation,
        _check_fps,
        _check_mp4_size,
        _closeup_scale,
        max_closeups,
        save_animation,
    )
    from .stepped import colormap, isovalues

    # -o, --png, --gif: any of them (--png alone: a render-only run, no -o file; --gif alone: the animation only)
    out, png = _mesh_and_png(args.output, args.png, extensions=(".png", *MESH_EXTENSIONS),
                             output_is="OUT (the render .png, or the scene as a mesh)",
                             others=[("--gif", args.gif, "OUT.gif|OUT.mp4 (a spinning animation)")])
    mesh_out = out if out is not None and out.suffix.lower() != ".png" else None
    anim = _check_output(args.gif, (".gif", ".mp4"), "--gif") if args.gif else None
    _check_outputs({"INPUT": args.input}, output=out, png=png, gif=anim)
    if png is not None and out is not None and mesh_out is None:  # the same render was written to both files
        raise InvalidInputError(f"--png writes the render beside a mesh --output, or alone (a .png --output is the "
                                f"render already); got --output {args.output!r} with --png {args.png!r}")
    picture = png if out is None or mesh_out is not None else out  # the still render's one file, if any
    if args.anchor is not None and args.anchor not in TRANSFER_PRESETS:  # the library's message offered an opacity
        # table, which no option takes
        raise InvalidInputError(f"--anchor must be one of {', '.join(TRANSFER_PRESETS)}; got {args.anchor!r}")
    # the scene mesh's format when it alone is written (no render shows what it cannot hold), else None
    alone = mesh_out.suffix.lower() if mesh_out is not None and picture is None and anim is None else None
    if alone == ".stl":
        # the colours went nowhere: an STL holds none and no render showed them (as steps --colormap with an .stl)
        # --anchor and --scalars likewise: the anchors' opacity, in the vertex alpha of the other formats, and the
        # overview's colours (`-o scene.stl --anchor hidden --scalars slope` wrote the file without them)
        given = ([f"--colormap {args.colormap}"] * (args.colormap is not None) + ["--color"] * bool(args.color)
                 + [f"--anchor {args.anchor}"] * (args.anchor is not None)
                 + [f"--scalars {args.scalars}"] * (args.scalars is not None))
        if given:
            raise InvalidInputError(f"an .stl --output holds no colours: got {' and '.join(given)} (colouring the "
                                    f"scene and its renders) with --output {args.output!r} and no --png or --gif; "
                                    "write .glb, .ply or .3mf for colours, or leave them out")
    if alone == ".obj" and args.anchor is not None:
        # an OBJ's `v x y z r g b` lines hold no alpha, the anchors' opacity: `-o scene.obj --anchor hidden` wrote the
        # file every other preset writes (byte for byte) and said nothing
        raise InvalidInputError(f"an .obj --output holds RGB only, the anchors opaque: got --anchor {args.anchor} (the "
                                f"anchors' opacity, in the vertex alpha of the other formats and in the renders) "
                                f"with --output {args.output!r} and no --png or --gif; write .glb, .ply or .3mf for "
                                "the anchors' opacity, or leave --anchor out")
    if anim is not None and anim.suffix.lower() == ".mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise MissingDependencyError("MP4 output needs imageio-ffmpeg: pip install 'stepterrain[video]'")
    render_options = _given(args, {"z_scale": 2.0, "size": (1280, 720), "camera": "oblique"})
    if not (math.isfinite(args.z_scale) and args.z_scale > 0):
        raise InvalidInputError(f"--z-scale must be a positive number; got {args.z_scale}")
    args.scalars = "height" if args.scalars is None else args.scalars
    if args.colormap is not None and args.scalars == "none" and not any(args.stepped or []):
        # nothing is coloured by it: the same image and scene mesh as without it
        raise InvalidInputError(f"--colormap colours the overview's --scalars and the --stepped close-ups; with "
                                f"--scalars none and no --stepped close-up it colours nothing; got --colormap "
                                f"{args.colormap}")
    args.colormap = "terrain" if args.colormap is None else args.colormap
    colormap(args.colormap, argument="--colormap")  # an unknown name fails here, before any work
    _check_size(args.size, renders=picture is not None or anim is not None, layered=True)
    # the animation's options: the still render and the scene mesh are the close-ups at time 0, before any spin
    unanimated = _given(args, {"spin": 0.25, "frames": 24, "fps": 12.0})
    if args.frames < 1:
        raise InvalidInputError(f"--frames must be >= 1; got {args.frames}")
    if not (math.isfinite(args.fps) and args.fps > 0):
        raise InvalidInputError(f"--fps must be a positive number; got {args.fps:g}")
    if anim is not None:  # a rate the format cannot store failed (or wrote a broken MP4) after every frame
        _check_fps(args.fps, anim.suffix.lower(), "--fps")
        if anim.suffix.lower() == ".mp4":  # refused here, not after rendering every frame
            _check_mp4_size(*args.size, "--size")
    if anim is not None and args.frames == 1 and "--spin" in unanimated:
        # one frame, at time 0, before any turn: `--frames 1 --spin 0.5` wrote the animation `--frames 1` writes
        raise InvalidInputError(f"--spin turns the close-ups from frame to frame; --frames 1 renders one, at time 0 "
                                f"(before any turn): give --frames 2 or more, or leave --spin out; got --spin "
                                f"{args.spin:g}")
    if anim is not None and args.frames > 1 and abs(args.spin) > args.fps / 2:
        # a faster spin turns more than half a turn between frames: the animation shows it aliased (turning slower,
        # or backwards; at --fps turns per second it stands still), and 1e308 made every frame the same
        if "--spin" not in unanimated:  # the default spin at a slow --fps: not a --spin the user typed
            raise InvalidInputError(f"the default --spin {args.spin:g} turns more than half a turn a frame at --fps "
                                    f"{args.fps:g} (it would be shown aliased: slower, backwards or standing still); "
                                    f"give a --spin with |TURNS/S| <= --fps / 2 = {args.fps / 2:g}")
        raise InvalidInputError(f"--spin must be at most half a turn a frame, |--spin| <= --fps / 2 = "
                                f"{args.fps / 2:g} turns per second (a faster spin is shown aliased: slower, "
                                f"backwards or standing still); got {args.spin:g}")
    if anim is None:  # (after their values, which are named first)
        _refuse_unused(unanimated, "--gif (the still render and the scene mesh show the close-ups before any spin)",
                       "without --gif")
        if picture is None:  # the scene mesh alone: --size, --z-scale and --billboard shape the renders only (a
            # billboard is an orthographic render pasted over the close-up's place: the scene mesh was the same)
            _refuse_unused(render_options + ["--billboard"] * args.billboard, "a render (a .png --output, --png or "
                           "--gif)", f"with the mesh --output {args.output!r} alone")
    if args.edge is not None and not (math.isfinite(args.edge) and args.edge >= 0):
        raise InvalidInputError(f"--edge must be a finite number >= 0; got {args.edge:g}")  # inf is >= 0
    # degrees (finite: _floats), whole turns taken off exactly: math.radians(1e308) kept none of the angle
    rotations_deg = [tuple(math.fmod(a, 360.0) for a in rot) for rot in args.rotation or []]
    for _fx, _fy, fr in args.roi_relative or []:  # else named as '--roi radius', in world units
        if not fr > 0:
            raise InvalidInputError(f"--roi-relative radius fraction must be positive; got {fr:g}")
    n_rois = len(args.roi or []) + len(args.roi_relative or []) or 1
    # the per-close-up options, their counts and the values CloseUp refuses whatever the DEM, before it is loaded
    # (they were refused after it): --offset's default lift and --roi-relative's radii need its extent
    scales = _per_closeup(args.scale, n_rois, (1.5,), "--scale")
    for s in scales:
        if len(s) not in (1, 3):
            raise InvalidInputError(f"--scale must be s or sx,sy,sz; got {','.join(f'{v:g}' for v in s)}")
        _closeup_scale(s, "--scale")  # CloseUp's own check, named as the option
    _per_closeup(args.offset, n_rois, None, "--offset")
    for p in args.offset or []:  # CloseUp's bound (float32 positions; finite: _floats): it came after the DEM was read
        if max(abs(v) for v in p) > _MAX_OFFSET:
            raise InvalidInputError(f"--offset must be finite (dx, dy, dz) metres, each within ±{_MAX_OFFSET:g}; got "
                                    f"{tuple(float(v) for v in p)}")
    rotations = _per_closeup(rotations_deg, n_rois, (0.0, 0.0), "--rotation")
    colors = _per_closeup(args.color, n_rois, None, "--color")
    steps = _per_closeup(args.stepped, n_rois, None, "--stepped")
    for interval in steps:
        if interval is not None and not (math.isfinite(interval) and interval >= 0):  # 0 is allowed: continuous
            raise InvalidInputError(f"--stepped must be a finite number >= 0 (0: a continuous close-up); got "
                                    f"{interval:g}")
    for _x, _y, r in args.roi or []:  # closeup's ROI size bound: float32 positions (finite: _floats)
        if not 0 < r <= _MAX_OFFSET:
            raise InvalidInputError(f"--roi radius must lie in (0, {_MAX_OFFSET:g}]; got {r:g}")
        if args.edge is not None and args.edge > r:  # as below, for a radius known before the DEM is read
            raise InvalidInputError(f"--edge must be at most the ROI radius {r:g}; got {args.edge:g}")
    if (picture is not None or anim is not None) and n_rois > max_closeups(args.size):
        raise InvalidInputError(f"--size {args.size[0]}x{args.size[1]} holds at most "
                                f"{_counted(max_closeups(args.size), 'close-up')} (one per {_MIN_PIXELS_PER_CLOSEUP}x"
                                f"{_MIN_PIXELS_PER_CLOSEUP} pixels, at most {_MAX_CLOSEUPS}); got {n_rois}")
    if picture is not None or anim is not None:
        render.require_offscreen()  # fail before any work when no OpenGL context can exist here
    if anim is not None:  # refused here, not after loading the DEM and the still render (animate_closeups' check)
        width, height = args.size  # every frame is kept until written, and the writer (np.stack) copies them all once
        check_budget(2 * args.frames * width * height * 3, f"--frames {args.frames} of {width} x {height} pixels "
                     "(kept, then copied once by the writer)", hint="render fewer or smaller frames")

    progress.stage("load", f"loading {args.input if args.input else 'the embedded Big Tujunga DEM'}")
    terrain = _input_terrain(args)
    progress.done(f"{' x '.join(str(n) for n in terrain.shape)} nodes,")
    xmin, xmax, ymin, ymax = terrain.extent
    short = min(xmax - xmin, ymax - ymin)
    given = getattr(args, "rois", None) or []  # in command-line order
    rois = [value if option == "roi" else (xmin + value[0] * (xmax - xmin), ymin + value[1] * (ymax - ymin),
                                            value[2] * short)
            for option, value in given]
    for (option, value), (x, y, r) in zip(given, rois, strict=True):
        if option == "roi_relative" and not (math.isfinite(x) and math.isfinite(y) and r <= _MAX_OFFSET):
            # named as the library's "ROI center" or "--roi radius ... got inf", not the fractions typed
            fx, fy, fr = value
            raise InvalidInputError(f"--roi-relative {fx:g},{fy:g},{fr:g} places a close-up at ({x:g}, {y:g}) with "
                                    f"radius {r:g}: expected fractions of the extent (0 to 1 across it) giving a "
                                    f"finite centre and a radius within {_MAX_OFFSET:g}")
    if not rois:
        rois = [((xmin + xmax) / 2, (ymin + ymax) / 2, 0.12 * short)]
    n = len(rois)  # n_rois
    # a fifth of the longer side, and at least 0.3 of the north-south depth: the default camera looks from the south,
    # and a close-up lifted by a fifth of a north-south strip's length sat on its far end, drawn over the terrain
    lift = max(0.2 * max(xmax - xmin, ymax - ymin), 0.3 * (ymax - ymin))
    offsets = _per_closeup(args.offset, n, (0.0, 0.0, lift), "--offset")
    for interval in steps:
        if interval:  # the levels of a stepped close-up span the terrain's height range: named by the option
            try:
                isovalues(terrain.height_range, interval=interval)
            except InvalidInputError as exc:  # "interval=1e-09 over ..." reads "--stepped 1e-09 over ..." (cli's
                text = str(exc)  # _OPTION_ALIASES): not after "--stepped 1e-09: "
                raise InvalidInputError(text if text.startswith("interval") else f"--stepped {interval:g}: {text}"
                                        ) from None
    anchor = AnchorStyle("linear" if args.anchor is None else args.anchor)
    # repetitions enough for the animation; |spin| * frames / fps overflowed to inf (an OverflowError in ceil) for
    # --spin 1e308: capped where float64 still counts whole turns
    turns = abs(args.spin) * args.frames / args.fps
    repetitions = max(1, math.ceil(min(turns, 2.0**53)))
    closeups = []
    for (x, y, r), s, p, rot, c, st_ in zip(rois, scales, offsets, rotations, colors, steps, strict=True):
        if not (math.isfinite(r) and 0 < r <= _MAX_OFFSET):  # closeup's ROI size bound: float32 positions
            raise InvalidInputError(f"--roi radius must lie in (0, {_MAX_OFFSET:g}]; got {r:g}")
        edge = args.edge if args.edge is not None else r / 5
        if edge > r:  # m would stay below 1 everywhere: a close-up with no content
            raise InvalidInputError(f"--edge must be at most the ROI radius {r:g}; got {edge:g}")
        if args.shape == "circle":
            roi = ROI.circle((x, y), r, edge_width=edge)
        elif args.shape == "rectangle":
            roi = ROI.rectangle((x, y), (2 * r, 2 * r), edge_width=edge)
        else:
            roi = ROI.rounded_rectangle((x, y), (2 * r, 2 * r), edge_width=edge)
        closeups.append(CloseUp(roi, scale=s[0] if len(s) == 1 else s, offset=p,
                                rotation=(math.radians(rot[0]), math.radians(rot[1])), color=c, anchor=anchor,
                                stepped=st_ or None, view="billboard" if args.billboard else "overview",
                                spin=(args.spin, repetitions)))
    scalars = None if args.scalars == "none" else args.scalars
    options = dict(z_scale=args.z_scale, scalars=scalars, cmap=args.colormap, device=args.device, camera=args.camera)

    # everything is computed in memory first, then written: a run that fails anywhere writes no file
    try:
        scene, image, frames = _closeup_outputs(args, progress, terrain, closeups, mesh_out, picture, anim, options)
    except InvalidInputError as exc:
        text = str(exc)
        if given or not text.startswith("closeups[0]: ROI box"):
            raise
        # the default close-up: the library's "closeups[0]" read as "--roi/--roi-relative (close-up 1)", options the
        # user never gave, and "make it larger or move it" named no way to
        raise InvalidInputError(f"no --roi or --roi-relative given: the default close-up at the DEM's centre (radius "
                                f"{rois[0][2]:g}, 0.12 of its shorter side) {text[len('closeups[0]: '):]}; give "
                                "--roi x,y,r or --roi-relative fx,fy,fr over the terrain") from None
    if frames is not None and anim is not None:  # before any file: a GIF refused for its runs of identical frames
        _check_animation(frames, anim, args.fps)  # (--spin 1e-12 at a slow --fps) left the mesh and PNG written
    if scene is not None and mesh_out is not None:
        from .export import save_mesh

        progress.stage("write", f"writing {mesh_out}")
        save_mesh(scene, mesh_out, metadata={"generator": "stepterrain closeup", **_input_metadata(args),
                                              "closeups": n})
        progress.done()
    if image is not None and picture is not None:
        progress.stage("write", f"writing {picture}")
        render.save_png(image, picture)
        progress.done()
    if frames is not None and anim is not None:
        progress.stage("write", f"writing {anim}")
        save_animation(frames, anim, fps=args.fps)
        progress.done()
    return 0


def _closeup_outputs(args: argparse.Namespace, progress: Any, terrain: Any, closeups: list, mesh_out: Any, picture: Any,
                     anim: Any, options: dict[str, Any]) -> tuple[Any, Any, Any]:
    """The scene mesh, the still render and the animation frames that were asked for (None otherwise), in memory."""
    from .cli import _counted
    from .closeup import animate_closeups, render_closeups

    n = len(closeups)
    scene = image = frames = None
    if mesh_out is not None:
        from .closeup import closeup_scene

        progress.stage("mesh", f"building the scene mesh with {_counted(n, 'close-up')}")
        scene = closeup_scene(terrain, closeups, scalars=options["scalars"], cmap=args.colormap, device=args.device)
        progress.done(f"{_counted(len(scene.faces), 'face')},")
    if picture is not None:
        progress.stage("render", f"rendering {_counted(n, 'close-up')} at {args.size[0]}x{args.size[1]}")
        timings: dict[str, float] = {}
        image = render_closeups(terrain, closeups, window_size=args.size, timings=timings, **options)
        progress.done(f"transform {timings['transform']:.2f} s, passes {timings['render']:.2f} s, "
                      f"composite {timings['composite']:.2f} s;")
    if anim is not None:
        progress.stage("animate", f"rendering {_counted(args.frames, 'frame')} for {anim}")
        frames = animate_closeups(terrain, closeups, frames=args.frames, fps=args.fps, window_size=args.size,
                                  progress=not progress.quiet, **options)
        progress.done()
    return scene, image, frames
