"""Fixes to the animation writers: GIF frame delays and runs of identical frames (save_animation)."""

from __future__ import annotations

import errno
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from stepterrain.closeup import save_animation
from stepterrain.errors import InvalidInputError


def gif_delays(path) -> list[int]:
    """The GIF's frame delays in milliseconds (whole hundredths of a second, as stored), read back by Pillow."""
    with Image.open(path) as image:
        delays = []
        for k in range(image.n_frames):
            image.seek(k)
            delays.append(int(image.info["duration"]))
    return delays


@pytest.mark.filterwarnings("ignore:save_animation. fps .* browsers")
@pytest.mark.parametrize("fps", [12.0, 30.0, 40.0, 60.0, 7.3, 100.0])
def test_gif_frames_start_at_their_time_within_half_a_hundredth(tmp_path, fps):
    """Pillow truncated each frame's delay to whole hundredths of a second (int(100 / fps)): a 12 fps GIF played at
    12.5 fps, 30 fps at 33.3 and 60 fps at 100 (24 frames in 0.24 s, not 0.4 s), the spin faster than asked. Frame k
    must start at k / fps, rounded to the nearest hundredth; the delays then add up to the animation's length."""
    n = 24
    frames = [np.full((6, 5, 3), 10 * k, np.uint8) for k in range(n)]  # all different: none merged
    delays = gif_delays(save_animation(frames, tmp_path / "a.gif", fps=fps))
    assert len(delays) == n
    starts = np.concatenate([[0], np.cumsum(delays)])  # ms
    expected = np.arange(n + 1) * 1000.0 / fps
    assert np.abs(starts - expected).max() <= 5.0 + 1e-9, (delays, fps)
    assert min(delays) >= 10  # no 0 delay (a player's default rate)


def test_gif_identical_frames_keep_their_total_time(tmp_path):
    """Pillow merges runs of identical frames into one GIF frame with their delays added: the time stays."""
    frames = [np.zeros((4, 4, 3), np.uint8)] * 3 + [np.full((4, 4, 3), 200, np.uint8)]
    delays = gif_delays(save_animation(frames, tmp_path / "a.gif", fps=30.0))
    assert len(delays) == 2
    assert delays[0] == 100  # frames 0..2: 0.1 s (3.33 hundredths each, rounded as they add up)
    assert sum(delays) == round(4 * 100 / 30) * 10


@pytest.mark.parametrize("count, kept", [(7, False), (6, True)])
def test_gif_a_run_of_identical_frames_too_long_for_a_gif_delay_is_refused(tmp_path, count, kept):
    """Identical frames are one GIF frame (Pillow merges them, adding their delays): 7 still frames at 0.01 fps
    (700 s) raised Pillow's bare OverflowError "int too big to convert" after every close-up frame was rendered (a
    GIF delay is at most 655.35 s). Now an InvalidInputError naming fps and the frames; the old file stays. 6 of
    them (600 s) are written, as one frame of 600 s."""
    target = tmp_path / "still.gif"
    target.write_bytes(b"an earlier animation")
    frames = [np.full((4, 6, 3), 90, np.uint8)] * count + [np.zeros((4, 6, 3), np.uint8)]
    if kept:
        assert gif_delays(save_animation(frames, target, fps=0.01)) == [600_000, 100_000]
        return
    with pytest.raises(InvalidInputError, match=r"^fps 0\.01 shows frames\[0\] to frames\[6\] \(identical: one GIF "
                                                r"frame\) for 700 s, longer than a GIF frame's longest delay \(655\.35 "
                                                r"s\)"):
        save_animation(frames, target, fps=0.01)
    assert target.read_bytes() == b"an earlier animation"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["still.gif"]


def test_gif_slowest_rate_still_written(tmp_path):
    """The slowest rate _check_fps accepts (int(100 / fps) = 65535 hundredths) is written, its delays clipped to a
    GIF's longest, not refused by Pillow."""
    fps = 100.0 / 65535.5
    frames = [np.full((2, 2, 3), 60 * k, np.uint8) for k in range(3)]
    delays = gif_delays(save_animation(frames, tmp_path / "slow.gif", fps=fps))
    assert delays == [655_350] * 3
    assert math.isclose(sum(delays) / 1000, 3 / fps, rel_tol=1e-4)


def test_gif_frames_alike_in_the_gif_palette_too_long_are_refused(tmp_path):
    """Frames that differ in one bit of one pixel are alike once Pillow quantizes them to 256 colours: it merged
    them too, and 8 of them at 0.01 fps raised the bare OverflowError. Now an InvalidInputError naming fps; nothing
    is left behind."""
    a = np.random.default_rng(1).integers(0, 256, (32, 32, 3), dtype=np.uint8)  # more colours than a GIF has
    b = a.copy()
    b[0, 0, 0] ^= 1
    with pytest.raises(InvalidInputError, match=r"^fps 0\.01 shows frames that are alike in a GIF's colours for "
                                                r"longer than a GIF frame's longest delay \(655\.35 s\)"):
        save_animation([a, b] * 4, tmp_path / "q.gif", fps=0.01)
    assert list(tmp_path.iterdir()) == []


def test_texture_animation_ends_on_its_last_key_where_that_key_lies():
    """frame(t) at or after the last key time drew the last key resampled onto the previous key's grid: with keys
    over other extents (a lens moved with TextureLayer.moved to follow a point) the last frame lay where the previous
    key was, and a lens moved off it was lost (a uniform rim colour), while every other key time gave its own key.
    Now the last key time gives the last key, on its own grid, as the first key time gives the first."""
    from stepterrain.texture import TextureAnimation, TextureLayer, highlight_lens

    rng = np.random.default_rng(0)
    a = TextureLayer("thematic", rng.random((8, 10, 4)), (0.0, 10.0, 0.0, 8.0))
    b = TextureLayer("thematic", rng.random((8, 10, 4)), (5.0, 15.0, 0.0, 8.0))
    anim = TextureAnimation([a, b], (0.0, 1.0))
    for t, key in ((0.0, a), (1.0, b), (7.5, b)):
        frame = anim.frame(t, device="cpu")
        assert frame.extent == key.extent and frame.shape == key.shape
        np.testing.assert_allclose(frame.rgba(), key.rgba(), atol=1e-6)

    lens = highlight_lens((0.0, 0.0), 1.0, strength=0.5, resolution=16)
    keys = [lens, lens.moved(10.0, 0.0), lens.moved(20.0, 0.0)]
    anim = TextureAnimation(keys, (0.0, 1.0, 2.0))
    for t, key in ((1.0, keys[1]), (2.0, keys[2]), (3.0, keys[2])):  # an inner key and the last one, alike
        frame = anim.frame(t, device="cpu")
        centre = frame.rgba()[8, 8, 0]  # the hot spot: 1 (the rim is 1 - strength = 0.5)
        assert centre == pytest.approx(1.0, abs=1e-6), t
        x0, x1, _, _ = frame.extent
        assert x0 < 10.0 * keys.index(key) < x1


@pytest.mark.parametrize("shape", [(1, 65536), (65536, 1)])
def test_gif_frames_wider_or_taller_than_a_gif_stores_are_refused_naming_their_size(tmp_path, shape):
    """A GIF's width and height are 16-bit numbers: Pillow raised a bare OverflowError for a 65536-pixel frame, which
    the backstop for merged delays in _write_gif reported as "fps 12 shows frames that are alike ... give a higher
    fps" (a wrong cause). Now an InvalidInputError naming the frames' size; nothing is left behind."""
    frames = [np.zeros((*shape, 3), np.uint8), np.full((*shape, 3), 9, np.uint8)]
    with pytest.raises(InvalidInputError, match=rf"^frames of a GIF must be at most 65535 pixels each way .*got "
                                                rf"{shape[1]}x{shape[0]}$"):
        save_animation(frames, tmp_path / "wide.gif", fps=12.0)
    assert list(tmp_path.iterdir()) == []


_EXAMPLE_GIFS = {  # the example, small arguments, its GIF's delay per frame in ms
    "flood": (["--size", "16", "--frames", "3", "--keyframes", "2", "--device", "cpu"], 120),
    "dynamic_peaks": (["--size", "12", "--frames", "3", "--window", "64", "48", "--device", "cpu"], 80),
}


@pytest.mark.parametrize("name", sorted(_EXAMPLE_GIFS))
def test_example_gif_on_a_full_disk_is_a_usage_error_keeping_the_old_gif(tmp_path, monkeypatch, capsys, name):
    """examples/flood.py and dynamic_peaks.py wrote their GIF through imageio directly: a full disk ended them in the
    bare OSError "[Errno 28] No space left on device" (a traceback naming no file), and imageio's plugin wrote its
    queued frames once more in __del__, a second traceback. Through save_animation it is one usage-error line naming
    the GIF (exit 2); the old GIF stays, nothing else is written. Each frame keeps the delay the example gave it."""
    from PIL import ImageFile

    from .test_examples import load_example

    argv, delay = _EXAMPLE_GIFS[name]
    out = tmp_path / f"{name}.png"
    assert load_example(name).main([*argv, "--output", str(out)]) == 0
    assert gif_delays(out.with_suffix(".gif")) == [delay] * 3  # the frames differ: none merged
    capsys.readouterr()

    old = tmp_path / "full" / f"{name}.gif"
    old.parent.mkdir()
    old.write_bytes(b"the old animation")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(ImageFile, "_save", full)
    with pytest.raises(SystemExit) as exit_info:
        load_example(name).main([*argv, "--output", str(old.with_suffix(".png"))])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert f"error: cannot write {str(old)!r}: No space left on device" in err and "Traceback" not in err, err
    assert [p.name for p in old.parent.iterdir()] == [old.name]
    assert old.read_bytes() == b"the old animation"


def _rgba_frames(count=3, shape=(6, 8), seed=0):
    """``count`` RGBA frames of few colours (a GIF palette holds them exactly), each transparent in its own row."""
    rng = np.random.default_rng(seed)
    palette = rng.integers(0, 256, (5, 3), dtype=np.uint8)
    frames = []
    for k in range(count):
        frame = np.empty((*shape, 4), np.uint8)
        frame[..., :3] = palette[rng.integers(0, len(palette), shape)]
        frame[..., 3] = 255
        frame[k % shape[0], :, 3] = 0  # transparent, its colours hidden
        frames.append(frame)
    return frames


def _gif_frames(path):
    """The GIF's frames as shown (Pillow composites each over the last as its disposal says), RGBA, and disposals."""
    with Image.open(path) as image:
        shown, disposals = [], []
        for k in range(image.n_frames):
            image.seek(k)
            shown.append(np.asarray(image.convert("RGBA")))
            disposals.append(image.disposal_method)
    return shown, disposals


def test_gif_keeps_rgba_frames_transparent_where_their_alpha_is_0(tmp_path):
    """save_animation dropped the alpha of RGBA frames: a transparent background was written opaque, in whatever
    colour its hidden pixels held. A GIF holds 1-bit transparency: each frame's transparent pixels are transparent
    now (each frame replaces the last, disposal 2: a pixel transparent in frame 1 shows nothing of frame 0), its
    opaque ones keep their colours."""
    frames = _rgba_frames()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # alpha 0 and 255 only: nothing lost, no warning
        gif = save_animation(frames, tmp_path / "a.gif", fps=4.0)
    shown, disposals = _gif_frames(gif)
    assert len(shown) == len(frames) and set(disposals) == {2}
    for frame, got in zip(frames, shown, strict=True):
        opaque = frame[..., 3] == 255
        assert np.array_equal(got[..., 3], frame[..., 3])
        assert np.array_equal(got[opaque][:, :3], frame[opaque][:, :3])


def test_gif_partial_alpha_is_rounded_to_one_bit_with_a_warning(tmp_path):
    """Alpha between 0 and 255 has no place in a GIF (1-bit transparency): alpha below 128 is transparent, the rest
    opaque, and a warning says so and counts the pixels."""
    frames = _rgba_frames(2)
    frames[0][2, :4, 3] = 127
    frames[1][3, :3, 3] = 128
    expected = [np.where(f[..., 3] < 128, 0, 255) for f in frames]
    with pytest.warns(UserWarning, match=r"GIF stores 1-bit transparency: 7 pixels of partial alpha"):
        gif = save_animation(frames, tmp_path / "a.gif", fps=4.0)
    shown, _ = _gif_frames(gif)
    for want, got in zip(expected, shown, strict=True):
        assert np.array_equal(got[..., 3], want)


def test_gif_of_opaque_rgba_frames_is_the_gif_of_their_rgb(tmp_path):
    """RGBA frames whose alpha is all 255 lose nothing: the same file as their RGB, no warning."""
    frames = _rgba_frames(3)
    for frame in frames:
        frame[..., 3] = 255
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rgba = save_animation(frames, tmp_path / "rgba.gif", fps=4.0).read_bytes()
    assert rgba == save_animation([f[..., :3] for f in frames], tmp_path / "rgb.gif", fps=4.0).read_bytes()


def test_mp4_of_transparent_rgba_frames_warns_that_their_alpha_is_dropped(tmp_path):
    """An MP4 (H.264) holds no transparency: RGBA frames with alpha below 255 were written as their RGB without a
    word. A warning says the alpha is dropped and what keeps it; opaque RGBA frames write without one."""
    pytest.importorskip("imageio_ffmpeg")
    frames = _rgba_frames(2, shape=(8, 8))
    with pytest.warns(UserWarning, match=r"MP4 .*no transparency: the alpha of 2 frames .*dropped"):
        save_animation(frames, tmp_path / "a.mp4", fps=4.0)
    for frame in frames:
        frame[..., 3] = 255
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_animation(frames, tmp_path / "b.mp4", fps=4.0)


@pytest.mark.parametrize(("fps", "warned"), [(60.0, True), (100.0, True), (50.0, False), (30.0, False)])
def test_gif_faster_than_50_fps_warns_that_browsers_play_it_slower(tmp_path, fps, warned):
    """A GIF frame of 1 hundredth of a second (fps above 50) is played as 10 hundredths by browsers (Chrome, Firefox,
    Safari): a 100 fps spin ran ten times slower there, without a word. A warning says so; 50 fps and below, none."""
    frames = [np.full((4, 4, 3), 10 * k, np.uint8) for k in range(6)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_animation(frames, tmp_path / "a.gif", fps=fps)
    said = [str(w.message) for w in caught if "browsers" in str(w.message)]
    assert bool(said) == warned, said
    if warned:
        assert f"fps {fps:g}" in said[0] and "1 hundredth" in said[0]


def _gif_controls(path):
    """(disposal, transparent?) of each frame's graphic control extension, read from the bytes (GIF89a §23):
    Pillow's reader restores a disposal-2 frame to the background colour unless the first frame has a transparent
    index, where browsers clear to transparent."""
    data, controls = Path(path).read_bytes(), []
    i = 13 + (3 << ((data[10] & 7) + 1) if data[10] & 0x80 else 0)
    while data[i] != 0x3B:
        if data[i] == 0x21:  # an extension: its label, then sub-blocks
            if data[i + 1] == 0xF9:
                controls.append(((data[i + 3] >> 2) & 7, bool(data[i + 3] & 1)))
            i += 2
        else:  # an image: its descriptor, a local colour table, the LZW code size, then sub-blocks
            i += 10 + (3 << ((data[i + 9] & 7) + 1) if data[i + 9] & 0x80 else 0) + 1
        while data[i]:
            i += data[i] + 1
        i += 1
    return controls


def test_gif_frames_transparent_after_an_opaque_one_say_so_in_the_file(tmp_path):
    """An opaque first frame, transparent ones after it: every frame is disposed of (2: cleared, as browsers clear
    it, to transparent), and each frame with transparent pixels has its transparent index. Opaque frames are written
    as before (Pillow's delta frames: a frame is drawn over the last, unchanged pixels transparent)."""
    frames = _rgba_frames(3)
    frames[0][..., 3] = 255
    gif = save_animation(frames, tmp_path / "a.gif", fps=4.0)
    assert _gif_controls(gif) == [(2, False), (2, True), (2, True)]
    rgb = save_animation([f[..., :3] for f in frames], tmp_path / "rgb.gif", fps=4.0)
    assert [disposal for disposal, _ in _gif_controls(rgb)] == [0, 0, 0]  # opaque frames: Pillow's delta frames


def test_gif_faster_than_50_fps_warning_counts_one_frame_in_the_singular(tmp_path):
    """The warning's verb agrees with its count: one short frame 'lasts' 1 hundredth (it said '1 GIF frame of the
    animation last'), several 'last'."""
    from stepterrain.closeup import _browser_slow_frames

    frames = [np.full((4, 4, 3), 10 * k, np.uint8) for k in range(4)]
    assert _browser_slow_frames(frames, 60.0) == 1  # delays 2, 1, 2, 2 hundredths
    many = [np.full((4, 4, 3), 10 * k, np.uint8) for k in range(12)]
    assert _browser_slow_frames(many, 60.0) > 1
    for stack, verb in ((frames, "1 GIF frame of the animation lasts 1 hundredth"),
                        (many, "GIF frames of the animation last 1 hundredth")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            save_animation(stack, tmp_path / "a.gif", fps=60.0)
        said = [str(w.message) for w in caught if "browsers" in str(w.message)]
        assert len(said) == 1 and verb in said[0], said


def gif_frames(path) -> np.ndarray:
    """The GIF's frames, (N, H, W, 3) int16, each as shown (Pillow composes a delta frame over the last)."""
    with Image.open(path) as image:
        out = []
        for k in range(image.n_frames):
            image.seek(k)
            out.append(np.asarray(image.convert("RGB")))
    return np.stack(out).astype(np.int16)


def spinning_frames(n: int = 12) -> list[np.ndarray]:
    """A still smooth-shaded backdrop (a 2-D colour ramp, thousands of colours) with a bright disc moving across it:
    as a spinning close-up over its overview."""
    y, x = np.mgrid[0:96, 0:128]
    backdrop = np.stack([x * 2, y * 2 + 30, (x + y) % 256], axis=2).astype(np.uint8)
    frames = []
    for k in range(n):
        frame = backdrop.copy()
        disc = (x - 10 - 9 * k) ** 2 + (y - 48) ** 2 < 12 ** 2
        frame[disc] = (250, 40 + 15 * k, 40)
        frames.append(frame)
    return frames


def test_gif_frames_share_one_palette_and_shrink(tmp_path):
    """save_animation let Pillow fit each GIF frame a palette of its own: docs/closeup_spin.gif (24 frames of a
    close-up spinning over a still overview) took 423 kB and docs/dynamic_peaks.gif 472 kB, the still pixels coded
    anew in each frame in slightly different colours. The frames of a GIF share one palette now (97 and 301 kB):
    at most 256 colours in the whole GIF, what stays still stays the same colour, the file smaller, and each frame
    within a few levels of full colour. ``palette="per-frame"`` still gives each its own."""
    frames = spinning_frames()
    full = np.stack(frames).astype(np.int16)
    shared = save_animation(frames, tmp_path / "shared.gif", fps=12.0)
    own = save_animation(frames, tmp_path / "own.gif", fps=12.0, palette="per-frame")
    one, each = gif_frames(shared), gif_frames(own)
    assert one.shape == each.shape == full.shape
    assert len(np.unique(one.reshape(-1, 3), axis=0)) <= 256 < len(np.unique(each.reshape(-1, 3), axis=0))
    still = (full == full[0]).all(axis=(0, 3))  # the backdrop no frame's disc covers
    assert still.mean() > 0.5 and (one[:, still] == one[0, still]).all()  # one colour for a still pixel, all along
    assert not (each[:, still] == each[0, still]).all()
    difference = np.abs(one - full)
    assert difference.mean() < 4 and np.percentile(difference, 99) < 24
    assert shared.stat().st_size < 0.8 * own.stat().st_size


def test_gif_frames_of_few_colours_keep_them_exactly(tmp_path):
    """Frames with 256 colours or fewer between them (already in one palette, as flood.py writes its frames) keep
    their colours exactly: the shared palette is theirs, not an octree's fit of them."""
    rng = np.random.default_rng(3)
    colours = rng.integers(0, 256, (250, 3), dtype=np.uint8)
    frames = [colours[rng.integers(0, 250, (20, 30))] for _ in range(5)]
    assert len(np.unique(np.concatenate(frames).reshape(-1, 3), axis=0)) > 200
    assert np.array_equal(gif_frames(save_animation(frames, tmp_path / "a.gif")), np.stack(frames))


def test_gif_palette_other_than_shared_or_per_frame_is_refused(tmp_path):
    with pytest.raises(InvalidInputError, match="palette must be 'shared' or 'per-frame'; got 'global'"):
        save_animation([np.zeros((4, 4, 3), np.uint8)], tmp_path / "a.gif", palette="global")
    assert not (tmp_path / "a.gif").exists()
