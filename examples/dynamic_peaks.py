"""Dynamic data (paper 000, §4): moving Gaussian peaks that emerge and collapse, stepped frame by frame.

A time series of heightfields (T, H, W) -- a few Gaussian peaks drifting on circles while their amplitude
rises and falls, over a gently undulating base -- goes through :func:`stepterrain.stepped_series`, which
compiles the Warp kernels once and reuses the device buffers for every frame. Each stepped frame is rendered
off-screen with a fixed camera and the frames are written as an animated GIF (:func:`stepterrain.save_animation`)
beside a PNG of the middle frame.

    python examples/dynamic_peaks.py --size 128 --frames 48 --output out/dynamic_peaks.png
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import stepterrain as st
from stepterrain.cli import check_example_outputs, usage_errors
from stepterrain.closeup import save_animation
from stepterrain.render import render_mesh, save_png

FRAME_MS = 80  # display time of one GIF frame: 12.5 frames per second


def moving_peaks(size: int, frames: int, *, n_peaks: int = 5, seed: int = 7) -> np.ndarray:
    """(frames, size, size) float32 heights in [0, 1]: drifting Gaussian peaks over smooth undulations."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64) / max(size - 1, 1)
    t = np.arange(frames, dtype=np.float64) / max(frames, 1)  # one period over the series: the GIF loops
    centres = rng.uniform(0.25, 0.75, size=(n_peaks, 2))
    radii = rng.uniform(0.08, 0.22, size=n_peaks)
    phases = rng.uniform(0.0, 2 * np.pi, size=n_peaks)
    widths = rng.uniform(0.06, 0.14, size=n_peaks)
    heights = np.empty((frames, size, size), dtype=np.float32)
    base = 0.08 * np.sin(3 * np.pi * x) * np.cos(2 * np.pi * y)
    for k in range(frames):
        angle = 2 * np.pi * t[k]
        z = base + 0.1 * np.sin(2 * np.pi * (x + y) + angle)
        for c, r, phase, w in zip(centres, radii, phases, widths, strict=True):
            cx = c[0] + r * np.cos(angle + phase)
            cy = c[1] + r * np.sin(angle + phase)
            amplitude = np.sin(angle + phase) ** 2  # emerges from the plain, then collapses back
            z = z + amplitude * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * w * w))
        heights[k] = z
    heights -= heights.min()
    heights /= max(float(heights.max()), 1e-12)
    return heights


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device: cpu, cuda, cuda:0 (default: Warp's)")
    parser.add_argument("--size", type=int, default=128, help="grid nodes per side (default 128)")
    parser.add_argument("--frames", type=int, default=48, help="number of frames (default 48)")
    parser.add_argument("--output", type=Path, default=Path("out/dynamic_peaks.png"),
                        help="PNG of the middle frame; the GIF is written beside it (.gif)")
    parser.add_argument("--window", type=int, nargs=2, default=(480, 360), metavar=("W", "H"),
                        help="render size per frame (default 480 360)")
    args = parser.parse_args(argv)
    if args.size < 2 or args.frames < 1:
        parser.error("--size must be >= 2 and --frames >= 1")
    if args.output.suffix.lower() != ".png":  # the GIF goes beside it: --output x.gif wrote the GIF, then failed
        parser.error(f"--output must end in .png (the GIF is written beside it); got {str(args.output)!r}")
    width, height = args.window
    held = args.frames * (4 * args.size**2 + 2 * 3 * max(width, 0) * max(height, 0))  # heights, frames, GIF stack
    if held > st.get_memory_budget():  # every frame is kept for the GIF: a large --frames ran out of memory
        parser.error(f"--frames {args.frames} of {args.size} x {args.size} nodes and {width} x {height} pixels would "
                     f"hold {held / 2**20:,.1f} MiB, over the memory budget of {st.get_memory_budget() / 2**20:,.1f} "
                     "MiB; give fewer frames or a smaller --size or --window")
    with usage_errors(parser):  # a value the library refuses: a usage error (exit 2), not a traceback
        # before any work: a folder of that name, or a file where a folder goes, refused after every frame
        check_example_outputs({"--output": args.output, "the GIF beside --output": args.output.with_suffix(".gif")})
        return run(args)


def run(args: argparse.Namespace) -> int:
    frames = moving_peaks(args.size, args.frames)
    spacing = 1.0 / (args.size - 1)
    interval = 1.0 / 12
    levels = st.isovalues((float(frames.min()), float(frames.max())), interval=interval)
    bounds = [(0.0, 0.0, float(levels[0])), (1.0, 1.0, float(levels[-1]))]  # fixed camera for every frame

    start = time.perf_counter()
    images = []
    for mesh in st.stepped_series(frames, interval=interval, colors="viridis", spacing=(spacing, spacing),
                                  progress=True, device=args.device):
        images.append(render_mesh(mesh, window_size=tuple(args.window), z_scale=0.45, bounds=bounds))
    elapsed = time.perf_counter() - start

    # through the library: atomic, a full disk a DataFileError naming the file (a usage error here), 80 ms a frame
    gif = save_animation(images, args.output.with_suffix(".gif"), fps=1000.0 / FRAME_MS)
    save_png(images[len(images) // 2], args.output)
    print(f"wrote {gif} and {args.output}: {len(images)} frames of {args.size} x {args.size} "
          f"in {elapsed:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
