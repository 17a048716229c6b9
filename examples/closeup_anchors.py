"""Anchor styles side by side (paper 001, Fig. 4) and inactive depictions (Fig. 5).

Four close-ups of one DEM, each anchored to its ROI by a fence in its color whose transparency follows a
different 1D transfer function of the normalized distance between overview and close-up: opaque, linear
(solid at the ROI, fading towards the close-up), inverse and ends. With --inactive the close-ups are drawn
inactive in the three depictions of Fig. 5 (anchor hidden, gray, faint) plus one active for comparison. A legend
along the top names each close-up by its anchor's colour, left to right.

    python examples/closeup_anchors.py --output anchors.png
"""

from __future__ import annotations

import argparse
import sys

import stepterrain as st
from stepterrain.cli import add_dem_option, check_example_outputs, example_dem, usage_errors
from stepterrain.closeup import PALETTE, ROI, AnchorStyle, CloseUp, render_closeups
from stepterrain.render import save_png

STYLES = ("opaque", "linear", "inverse", "ends")
INACTIVE = ("hidden", "gray", "faint", None)


def closeups(terrain: st.Terrain, inactive: bool = False) -> list[CloseUp]:
    xmin, xmax, ymin, ymax = terrain.extent
    w, h = xmax - xmin, ymax - ymin
    # a tenth of the height, and narrow enough that four 1.3 x close-ups 0.225 w apart stay apart (a tenth of the
    # shorter side overlapped them on a DEM not much wider than tall, a square one)
    r = 0.1 * min(h, 0.85 * w)
    out = []
    for k, style in enumerate(STYLES):
        fx = 0.16 + 0.225 * k
        depiction = INACTIVE[k] if inactive else None
        anchor = AnchorStyle(style, inactive=depiction or "faint")
        out.append(CloseUp(ROI.circle((xmin + fx * w, ymin + 0.5 * h), r), scale=1.3,
                           offset=(0.0, 0.1 * h, 0.22 * max(w, h)), anchor=anchor,
                           active=depiction is None))
    return out


def draw_legend(image, title: str, entries):
    """``image`` with a legend along its top: ``title``, then each ``(name, colour)`` of ``entries`` left to right, a
    swatch of the colour (a hex string; None: no swatch) before the name; none on an image under 240 px high, where
    the type would be too small to read.

    The type is a thirtieth of the height, made smaller (down to 12 px) until the widest entry fits the width, and
    entries that do not fit on a row start the next one (an entry wider than the image breaks between its words).
    Laid out in one row at a thirtieth of the height, the legend of docs/closeup.png took 1155 px: an image under
    that wide (``--window 800 720``) cut it off mid-name."""
    if image.shape[0] < 240:
        return image
    import numpy as np
    from PIL import Image, ImageColor, ImageDraw, ImageFont

    height, width = image.shape[:2]
    picture = Image.fromarray(np.ascontiguousarray(image[..., :3]))
    draw = ImageDraw.Draw(picture)
    items = [(title, None), *entries]

    def extent(text, font):  # how far right of its x the text reaches
        return draw.textbbox((0, 0), text, font=font)[2]

    def swatch(size, colour):  # the room a swatch and its gap take before the name
        return size + size // 3 if colour is not None else 0

    size = height // 30
    while True:  # a smaller type, down to 12 px, until the widest entry fits on a row
        font = ImageFont.load_default(size=size)
        widest = max(swatch(size, colour) + extent(name, font) for name, colour in items)
        if widest <= width - 2 * size or size <= 12:
            break
        size -= 1
    line = round(1.4 * size)
    x, y, right = size, size // 2, width - size
    for name, colour in items:
        if x > size and x + swatch(size, colour) + extent(name, font) > right:  # not after the last: the next row
            x, y = size, y + line
        if colour is not None:
            draw.rectangle([x, y + size // 8, x + size - 1, y + size + size // 8 - 1], fill=ImageColor.getrgb(colour))
            x += swatch(size, colour)
        if x + extent(name, font) <= right:
            draw.text((x, y), name, fill=(0, 0, 0), font=font)
            x += extent(name, font) + size
            continue
        for k, word in enumerate(name.split()):  # wider than a row: on between its words
            if k and x + extent(" " + word, font) > right:
                x, y = size, y + line
            elif k:
                word = " " + word
            draw.text((x, y), word, fill=(0, 0, 0), font=font)
            x += extent(word, font)
        x += size
    return np.asarray(picture)


def legend(image, inactive: bool = False):
    """``image`` with :func:`draw_legend`'s legend: a swatch of each close-up's anchor colour (the library's
    :data:`~stepterrain.closeup.PALETTE`, in the close-ups' order, left to right) and its style's name; with
    ``inactive``, the depictions' names alone (their fences are hidden, gray or faint, not in their colours).
    Without it docs/closeup_anchors.png showed four coloured fences and left the reader to guess which transfer
    function each one drew."""
    if inactive:
        names = ("inactive: anchor hidden", "inactive: gray", "inactive: faint", "active")
        return draw_legend(image, "left to right:", [(name, None) for name in names])
    return draw_legend(image, "anchor transparency:",
                       [(name, PALETTE[k % len(PALETTE)]) for k, name in enumerate(STYLES)])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=0, help="crop the DEM to SIZE x SIZE nodes (0: whole DEM)")
    add_dem_option(parser)
    parser.add_argument("--window", type=int, nargs=2, default=(1280, 720), metavar=("W", "H"))
    parser.add_argument("--output", default="closeup_anchors.png")
    parser.add_argument("--inactive", action="store_true", help="show the inactive depictions of Fig. 5")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)
    if args.size < 0 or args.size == 1:  # cropped to nothing or one node: the library named no option
        parser.error(f"--size must be 0 (the whole DEM) or at least 2 nodes; got {args.size}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        check_example_outputs({"--output": args.output}, args.dem)  # before any work
        return run(args)


def run(args: argparse.Namespace) -> int:
    terrain = example_dem(args.dem, args.nodata)
    if args.size:
        rows, cols = terrain.shape
        dx, dy = terrain.spacing
        i0, j0 = max(0, (rows - args.size) // 2), max(0, (cols - args.size) // 2)
        terrain = st.Terrain.from_heights(terrain.heights[i0: i0 + args.size, j0: j0 + args.size], spacing=(dx, dy),
                                          origin=(terrain.origin[0] + j0 * dx, terrain.origin[1] + i0 * dy),
                                          crs=terrain.crs, source=terrain.source)
    image = render_closeups(terrain, closeups(terrain, args.inactive), window_size=tuple(args.window), z_scale=2.0,
                            device=args.device)
    save_png(legend(image, args.inactive), args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
