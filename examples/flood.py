"""A rising water level over a real DEM, animated by texture keyframes (paper 004 §6, Fig. 4).

Keyframe layers hold the flooded area (blue, alpha = 1 below the water level) at a few time stamps over the
embedded Big Tujunga DEM (30 m SRTM), subsampled to about SIZE x SIZE nodes. Each frame at time t draws the
two keyframes around t with weights 1 - alpha and alpha (weighted layer addition: no intermediate texture is
stored) and blends the result over the shaded terrain (hypsometric layer modulated by a topographic layer with
self-shadowing). Writes a GIF of the animation and a PNG of its last frame, and with ``--mp4`` an H.264 MP4
too (through imageio; needs imageio-ffmpeg: ``pip install 'stepterrain[video]'``). The GIF's frames share one
palette (:func:`shared_palette`); the PNG and the MP4 keep full colour.

    python examples/flood.py --size 256 --frames 24 --output out/flood.png     # also writes out/flood.gif
    python examples/flood.py --mp4 --output out/flood.png                      # and out/flood.mp4
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import matplotlib
import numpy as np

from stepterrain import get_memory_budget
from stepterrain.cli import add_dem_option, check_example_outputs, example_dem, usage_errors
from stepterrain.closeup import save_animation
from stepterrain.errors import InvalidInputError, MissingDependencyError, OutputTooLargeError
from stepterrain.export import save_image
from stepterrain.texture import TextureAnimation, blend, modulate, terrain_layer, topographic_layer

sys.path.insert(0, str(Path(__file__).resolve().parent))
from textures import crop_sample  # noqa: E402

FRAME_MS = 120  # display time of one frame: the GIF and the MP4 run at 1000 / FRAME_MS frames per second


def require_video() -> None:
    """Raise MissingDependencyError naming the ``video`` extra unless imageio-ffmpeg is importable."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError("--mp4 needs imageio-ffmpeg (MP4 through imageio): "
                                     "pip install 'stepterrain[video]'") from exc


def write_mp4(frames: list[np.ndarray], path: Path) -> Path:
    """H.264 MP4 of the RGB frames, written atomically by the library's :func:`~stepterrain.closeup.save_animation`:
    the frames keep their size, which must be even both ways (:func:`run` checks the crop before any work; imageio
    stretched an odd-sized frame by a pixel, with only a printed warning), and a truncated MP4 is refused."""
    require_video()
    return save_animation(frames, path, fps=1000.0 / FRAME_MS)


def frame_size(terrain, even: bool = False) -> tuple[int, int]:
    """(width, height) of a frame in pixels, square on the ground: one pixel per node across the DEM's finer
    direction, the other stretched (one pixel per node drew a DEM of cells taller than wide, a 3" one's, squashed
    north-south), to an even number of pixels when ``even`` (an MP4's); one per node both ways for square cells."""
    rows, cols = terrain.shape
    dx, dy = (abs(float(v)) for v in terrain.spacing)
    if math.isclose(dx, dy, rel_tol=1e-9):
        return cols, rows

    def stretched(n: int, ratio: float) -> int:
        return max(2, 2 * round(n * ratio / 2)) if even else max(1, round(n * ratio))

    return (cols, stretched(rows, dy / dx)) if dy > dx else (stretched(cols, dx / dy), rows)


def square_pixels(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``frame`` (H, W, 3) uint8 resampled to ``size`` (width, height); as it is when it has that size."""
    if frame.shape[1::-1] == size:
        return frame
    from PIL import Image

    return np.asarray(Image.fromarray(frame).resize(size, Image.Resampling.BILINEAR))


def shared_palette(frames: list[np.ndarray], colors: int = 256) -> list[np.ndarray]:
    """The RGB ``frames`` in one palette of ``colors`` colours (Pillow's octree, fitted to every other pixel of every
    other row of all the frames, no dithering), each still RGB. Written as they came, each GIF frame got its own
    palette: the 24 frames of docs/flood.gif took 1.09 MB (nothing carried from frame to frame, the still terrain
    re-coded in each), and the dry summits of the early frames showed flat yellow blotches where their palette ran
    short. In one palette the frames take about 0.21 MB, within 3 levels of full colour on average."""
    from PIL import Image

    sample = Image.fromarray(np.ascontiguousarray(np.concatenate([f[::2, ::2, :3] for f in frames], axis=0)))
    palette = sample.quantize(colors, method=Image.Quantize.FASTOCTREE)
    return [np.asarray(Image.fromarray(np.ascontiguousarray(f[..., :3])).quantize(palette=palette,
                                                                              dither=Image.Dither.NONE).convert("RGB"))
            for f in frames]


def water_layer(terrain, level: float, lo: float, hi: float):
    """A thematic RGBA keyframe: water below ``level``, deeper water darker; transparent above."""
    h = terrain.heights
    depth = np.clip((level - h) / max(hi - lo, 1e-9) * 4.0, 0.0, 1.0)
    rgba = np.zeros((*h.shape, 4), np.float32)
    rgba[..., 0] = 0.15 * (1 - depth)
    rgba[..., 1] = 0.45 * (1 - depth) + 0.15 * depth
    rgba[..., 2] = 0.9 - 0.35 * depth
    rgba[..., 3] = np.where(h < level, 0.85, 0.0)
    return terrain_layer(terrain, rgba, "thematic", name=f"water {level:.0f} m")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda, cuda:0 (default: Warp's)")
    parser.add_argument("--size", type=int, default=256, help="nodes per side of the DEM crop (default 256)")
    add_dem_option(parser)
    parser.add_argument("--frames", type=int, default=24, help="frames of the animation (default 24)")
    parser.add_argument("--keyframes", type=int, default=5, help="keyframe layers (default 5)")
    parser.add_argument("--output", type=Path, default=Path("out/flood.png"),
                        help="PNG of the last frame; the GIF is written beside it")
    parser.add_argument("--mp4", action="store_true",
                        help="also write an MP4 beside the PNG (needs: pip install 'stepterrain[video]')")
    args = parser.parse_args(argv)
    if args.frames < 2 or args.keyframes < 2:
        parser.error("--frames and --keyframes must be at least 2")
    if args.mp4:
        require_video()  # before any work: a missing extra fails at once, naming what to install
    if args.size < 2:  # 0 raised a ZeroDivisionError in the crop; below 2 is no grid
        parser.error(f"--size must be at least 2 nodes; got {args.size}")
    if args.output.suffix.lower() != ".png":  # the GIF goes beside it: --output x.gif wrote the GIF, then failed
        parser.error(f"--output must end in .png (the GIF is written beside it); got {str(args.output)!r}")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        # before any work: a folder named as the PNG was refused after the GIF was written
        check_example_outputs({"--output": args.output, "the GIF beside --output": args.output.with_suffix(".gif"),
                               "the MP4 beside --output": args.output.with_suffix(".mp4") if args.mp4 else None},
                              args.dem)
        return run(args)


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    terrain = crop_sample(args.size, example_dem(args.dem, args.nodata))
    rows, cols = terrain.shape
    width, height = frame_size(terrain, even=args.mp4)
    if args.mp4 and (width % 2 or height % 2):  # before any work: the GIF and PNG were written, then the MP4 stretched
        pixels = "one pixel each" if (width, height) == (cols, rows) else f"frames of {width} x {height} square pixels"
        raise InvalidInputError(f"--mp4 needs frames of an even width and height (H.264 codes 2 x 2 colour blocks; "
                                f"the GIF takes any size); --size {args.size} crops {cols} x {rows} nodes, {pixels}"
                                ": give an even --size, no larger than the DEM's shorter side")
    # the frames, their copy in the GIF's palette, the GIF's (and the MP4's) stack
    held = args.frames * width * height * 3 * (4 if args.mp4 else 3)
    if held > get_memory_budget():  # every frame is kept for the GIF: a large --frames ran out of memory
        raise OutputTooLargeError(
            f"--frames {args.frames} of {width} x {height} pixels would hold {held / 2**20:,.1f} "
            f"MiB, over the memory budget of {get_memory_budget() / 2**20:,.1f} MiB; give fewer frames or a smaller "
            "--size")
    lo, hi = terrain.height_range
    h = terrain.heights
    # RGBA: the colormap's colour for NaN is transparent (its RGB alone drew a --dem file's voids as black ground)
    hyps = matplotlib.colormaps["terrain"](0.25 + 0.75 * (h - lo) / max(hi - lo, 1e-9)).astype(np.float32)
    shaded = modulate(terrain_layer(terrain, hyps),
                      topographic_layer(terrain, azimuth=math.radians(315), altitude=math.radians(35),
                                        shadows=True, shadow_strength=0.5, device=args.device),
                      device=args.device)
    levels = lo + (hi - lo) * np.linspace(0.0, 0.45, args.keyframes)
    times = np.linspace(0.0, 1.0, args.keyframes)
    animation = TextureAnimation([water_layer(terrain, float(level), lo, hi) for level in levels], times)

    frames = []
    for t in np.linspace(0.0, 1.0, args.frames):
        water = animation.frame(float(t), device=args.device)
        frames.append(square_pixels(np.asarray(blend(shaded, water, device=args.device).to_uint8(background=(1, 1, 1))),
                                    (width, height)))
    # through the library, as the MP4: atomic, a full disk a DataFileError naming the file (a usage error here)
    written = [save_animation(shared_palette(frames), args.output.with_suffix(".gif"), fps=1000.0 / FRAME_MS)]
    if args.mp4:
        written.append(write_mp4(frames, args.output.with_suffix(".mp4")))
    save_image(frames[-1], args.output)
    print(f"wrote {', '.join(map(str, written))} and {args.output}: {args.frames} frames from {args.keyframes} "
          "keyframes, water "
          f"{levels[0]:.0f} to {levels[-1]:.0f} m, {time.perf_counter() - start:.2f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
