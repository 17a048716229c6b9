"""Two mappings of one DEM in one image (paper 001, Fig. 1): a continuous overview and stepped close-ups.

The overview shows the terrain colored by height; one close-up shows the stepped terrain (paper 000) of its
ROI, enlarged and lifted (MPFR, overview-dependent, Fig. 1a); another shows the slope of its ROI as an
overview-independent billboard seen from above with an orthographic projection (Fig. 1b). A legend along the top
names each close-up by its anchor's colour, on as many rows as the window's width needs. Writes a PNG and, with
--gif, an animation of the first close-up spinning.

    python examples/closeup_mappings.py --output closeup.png --gif closeup.gif
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import stepterrain as st
from stepterrain.cli import add_dem_option, check_example_outputs, example_dem, nice_interval, usage_errors
from stepterrain.closeup import ROI, AnchorStyle, CloseUp, animate_closeups, render_closeups, save_animation
from stepterrain.render import save_png

sys.path.insert(0, str(Path(__file__).resolve().parent))
from closeup_anchors import draw_legend  # noqa: E402

#: the anchors' colours, named again by the legend
STEPPED_COLOR, SLOPE_COLOR = "#d62728", "#1f77b4"


def closeups(terrain: st.Terrain) -> list[CloseUp]:
    """The two close-ups of the figure, placed by fractions of the terrain's extent."""
    xmin, xmax, ymin, ymax = terrain.extent
    w, h = xmax - xmin, ymax - ymin
    r = 0.12 * min(w, h)
    lift = 0.25 * max(w, h)
    # about 20 steps, a round interval (100 m for the embedded DEM): max(1, range / 20 rounded to tens) gave a DEM
    # of under 20 m relief one flat terrace, and one of 100 m (5, rounded to 0) 100 steps of 1 m
    interval = nice_interval(terrain.height_range, target=20)
    stepped = CloseUp(ROI.circle((xmin + 0.3 * w, ymin + 0.45 * h), r), scale=(1.6, 1.6, 2.0),
                      offset=(-0.05 * w, 0.0, lift), rotation=(0.0, math.radians(20)), stepped=interval,
                      color=STEPPED_COLOR, anchor=AnchorStyle("linear"), spin=(0.25, 1))
    slope = CloseUp(ROI.rounded_rectangle((xmin + 0.72 * w, ymin + 0.55 * h), (2.2 * r, 1.6 * r)), scale=1.4,
                    offset=(0.05 * w, 0.0, lift), scalars="slope", view="billboard", color=SLOPE_COLOR,
                    anchor=AnchorStyle("ends"))
    return [stepped, slope]


def legend(image, closeups: list[CloseUp]):
    """``image`` with a legend along its top naming the two close-ups by their anchors' colours (see
    :func:`closeup_anchors.draw_legend`). Without it docs/closeup.png showed a red and a blue fence and a purple
    patch, and did not say that one close-up was the terrain stepped and the other its slope."""
    stepped = closeups[0]
    return draw_legend(image, "close-ups:", [(f"the terrain stepped every {stepped.stepped:g} m", STEPPED_COLOR),
                                             ("its slope (bright: steep), a billboard seen from above", SLOPE_COLOR)])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=0,
                        help="crop the DEM to SIZE x SIZE nodes from its centre (0: the whole DEM)")
    add_dem_option(parser)
    # 4:3: the overview and its lifted close-ups fill the height; at 1280 x 720 a fifth of the width each side of
    # them was blank (docs/closeup.png)
    parser.add_argument("--window", type=int, nargs=2, default=(960, 720), metavar=("W", "H"))
    parser.add_argument("--output", default="closeup_mappings.png")
    parser.add_argument("--gif", default=None, help="also write a spinning animation (.gif or .mp4)")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    if args.size < 0 or args.size == 1:  # cropped to nothing or one node: the library named no option
        parser.error(f"--size must be 0 (the whole DEM) or at least 2 nodes; got {args.size}")
    if args.gif and args.frames < 1:  # refused by the library only after the PNG was written
        parser.error(f"--frames must be at least 1; got {args.frames}")
    if args.gif and Path(args.gif).suffix.lower() not in (".gif", ".mp4"):  # refused after the PNG was written too
        parser.error(f"--gif must end in .gif or .mp4; got {args.gif!r}")
    if args.gif and Path(args.gif).suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            parser.error("--gif: MP4 output needs imageio-ffmpeg: pip install 'stepterrain[video]'")
        if args.window[0] % 2 or args.window[1] % 2:  # save_animation refused it after the renders and the PNG
            parser.error(f"--window of an MP4 must have an even width and height (H.264 codes 2 x 2 colour blocks; "
                         f"a GIF takes any size); got {args.window[0]}x{args.window[1]}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output, "--gif": args.gif}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    terrain = example_dem(args.dem, args.nodata)
    if args.size:
        rows, cols = terrain.shape
        i0, j0 = max(0, (rows - args.size) // 2), max(0, (cols - args.size) // 2)
        dx, dy = terrain.spacing
        terrain = st.Terrain.from_heights(terrain.heights[i0: i0 + args.size, j0: j0 + args.size], spacing=(dx, dy),
                                          origin=(terrain.origin[0] + j0 * dx, terrain.origin[1] + i0 * dy),
                                          crs=terrain.crs, source=terrain.source)
    cus = closeups(terrain)
    image = render_closeups(terrain, cus, window_size=tuple(args.window), z_scale=2.0, device=args.device)
    frames = None
    if args.gif:  # before the PNG is written: frames refused for the memory budget left the PNG behind
        frames = animate_closeups(terrain, cus[:1], frames=args.frames, fps=12.0, window_size=tuple(args.window),
                                  z_scale=2.0, device=args.device)
    save_png(legend(image, cus), args.output)
    if frames is not None:
        save_animation(frames, args.gif, fps=12.0)
    return 0


if __name__ == "__main__":
    sys.exit(main())
