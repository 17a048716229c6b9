"""Side-by-side benchmark of stepterrain's Warp step tessellation against what a VTK or NumPy user writes.

One process, the same inputs and the same isovalues for every contender:

- ``warp``: ``stepterrain.stepped(heights, levels=..., spacing=..., device=...)`` to a ``trimesh.Trimesh``
  (end to end, from the raw heights; kernels compiled and warmed up on a small grid first), with its
  stages (count -> scan -> emit in ``step_arrays`` with the γ blend in the vertex pass; the separate blend pass of a
  γ-only re-step) timed separately as well;
- ``vtk_banded``: ``vtkBandedPolyDataContourFilter`` (flat bands only, no walls);
- ``vtk_clip_per_band``: the full stepped model with pyvista clip/contour/extrude (a triangle soup);
- ``numpy_ref``: the vectorised NumPy reference of ``tests/reference.py`` (welded).

Reported per case: median and best wall time of ``--repeat`` runs, output triangles per second, output bytes
per second (float32 xyz + int32 triangles, the compact welded size) against this machine's memory write
bandwidth (measured here with numpy), peak memory (a fresh subprocess per contender: the rise of the peak
resident set size, VmHWM, over the resident size just before the run) and the ratios to Warp. Also the
interactive case: re-stepping a 512² terrain after a change of interval, and after a change of γ only.

Everything is pinned to one CPU core by default (the goals in issue 2 are per core); ``--all-cores`` lifts it.

    python benchmarks/run_stepped.py --sizes 256 1024 --steps 5 20 50 --output benchmarks/out.md
    python benchmarks/run_stepped.py --sizes 2048 --steps 20 --skip-slow --dems none
"""

from __future__ import annotations

import argparse
import datetime as _dt
import functools
import gc
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

_HERE = Path(__file__).resolve().parent
if str(_HERE.parent) not in sys.path:
    sys.path.insert(0, str(_HERE.parent))

from benchmarks import baselines  # noqa: E402
from benchmarks.machine import cpu_model, pin_to_one_core, repeat_count  # noqa: E402

CONTENDERS = ("warp", "vtk_banded", "vtk_clip_per_band", "numpy_ref")
BASELINES = ("vtk_banded", "numpy_ref", "vtk_clip_per_band")
# with --skip-slow: contender -> largest node count it still runs on
SLOW_LIMITS = {"vtk_clip_per_band": 1100 * 1100}
GOALS = {"vtk_banded": 150.0, "numpy_ref": 100.0}  # issue 2 §6, at 2048² cells with 20 steps
RESTEP_GOAL_MS = 10.0
SLOW_REPEAT = 3  # runs of a contender slower than --slow-seconds (medians of three, not one cold run)
PEAK_GOAL = 2.0


# ----------------------------------------------------------------------------- machine


def memory_bandwidth(gib: float = 1.0, repeat: int = 5) -> dict[str, float]:
    """Single-core write bandwidth in GB/s: ``ndarray.fill`` and ``np.copyto`` of ``gib`` GiB (best of)."""
    n = int(gib * 2**30) // 8
    dst = np.ones(n)  # touched: no page faults in the timed part
    src = np.full(n, 2.0)
    fill, copy = [], []
    for i in range(repeat):
        t0 = time.perf_counter()
        dst.fill(float(i))
        fill.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        np.copyto(dst, src)
        copy.append(time.perf_counter() - t0)
    nbytes = dst.nbytes
    del dst, src
    gc.collect()
    out = {
        "fill_GBps": nbytes / min(fill) / 1e9,
        "copy_GBps": nbytes / min(copy) / 1e9,
        "bytes": float(nbytes),
    }
    out["write_GBps"] = max(out["fill_GBps"], out["copy_GBps"])  # the optimistic one: the floor is a floor
    return out


def code_version() -> str:
    """The commit, and whether the package's sources differ from it (others edit the tree while we run)."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", *args], cwd=_HERE.parent, capture_output=True, text=True, check=False
        ).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = git("status", "--porcelain", "--", "stepterrain", "kernels")
    if not dirty:
        return f"commit {head}"
    digest = git("diff", "HEAD", "--", "stepterrain", "kernels")
    import hashlib

    changed = ", ".join(line[3:] for line in dirty.splitlines())
    sha = hashlib.sha1(digest.encode()).hexdigest()[:10]
    return f"commit {head} + uncommitted changes in {changed} (diff sha1 {sha})"


# ----------------------------------------------------------------------------- cases and contenders


@dataclass
class Case:
    name: str  # "256" (cells per side) or a REAL_DEMS name
    steps: int

    @property
    def label(self) -> str:
        return f"{self.name}²" if self.name.isdigit() else f"{self.name} (native)"

    def inputs(self) -> tuple[np.ndarray, tuple[float, float], np.ndarray]:
        if self.name.isdigit():
            heights, spacing = baselines.grid_heights(int(self.name) + 1)
        else:
            heights, spacing = baselines.real_dem(self.name)
        return heights, spacing, baselines.steps_isovalues(heights, self.steps)


def warp_device(name: str) -> Any:
    from stepterrain._device import resolve_device

    return resolve_device(name)


def contender_fn(name: str, device: Any) -> Callable[[np.ndarray, tuple[float, float], np.ndarray], Any]:
    if name == "warp":
        import warp as wp

        import stepterrain

        def run_warp(heights: np.ndarray, spacing: tuple[float, float], values: np.ndarray) -> Any:
            mesh = stepterrain.stepped(heights, levels=values, spacing=spacing, device=device)
            wp.synchronize_device(device)
            return mesh

        return run_warp
    return baselines.CONTENDERS[name]


def output_sizes(result: Any) -> tuple[int, int, int]:
    """(triangles, vertices, actual bytes of the output arrays)."""
    import pyvista as pv

    tris = baselines.triangle_count(result)
    verts = baselines.vertex_count(result)
    if isinstance(result, baselines.ReferenceResult):
        actual = sum(np.asarray(v).nbytes for v in asdict(result).values())
    elif isinstance(result, pv.PolyData):
        actual = int(result.GetActualMemorySize()) * 1024
    else:  # trimesh
        actual = result.vertices.nbytes + result.faces.nbytes
        actual += sum(np.asarray(v).nbytes for v in result.face_attributes.values())
    return tris, verts, actual


def warm_up(fn: Callable, device: Any) -> None:
    heights, spacing = baselines.grid_heights(33)
    fn(heights, spacing, baselines.steps_isovalues(heights, 5))


def skipped(contender: str, case: Case, heights: np.ndarray, skip_slow: bool) -> bool:
    return skip_slow and heights.size > SLOW_LIMITS.get(contender, 1 << 62)


# ----------------------------------------------------------------------------- timing


@dataclass
class Row:
    case: str
    steps: int
    levels: int
    contender: str
    times: list[float] = field(default_factory=list)
    triangles: int = 0
    vertices: int = 0
    actual_bytes: int = 0
    peak_bytes: int | None = None
    stages: dict[str, float] = field(default_factory=dict)
    note: str = ""

    @property
    def median(self) -> float:
        return statistics.median(self.times) if self.times else float("nan")

    @property
    def best(self) -> float:
        return min(self.times) if self.times else float("nan")

    @property
    def compact_bytes(self) -> int:
        return 12 * self.vertices + 12 * self.triangles


def time_contender(fn: Callable, heights, spacing, values, repeat: int, slow_s: float) -> tuple[list[float], Any]:
    times: list[float] = []
    result = None
    for _ in range(repeat):
        result = None
        gc.collect()
        t0 = time.perf_counter()
        result = fn(heights, spacing, values)
        times.append(time.perf_counter() - t0)
        # a slow baseline runs at most SLOW_REPEAT times: its first run on this project's VMs can pay the host's
        # first touch of the guest memory it allocates (VTK's banded filter at 2048²: 11.8-17 s once, 6.5 s warm;
        # RESULTS.md "Session 23"), which a single run would charge to the baseline
        if times[-1] > slow_s and len(times) >= min(repeat, SLOW_REPEAT):
            break
    return times, result


def median_time(fn: Callable[[], Any], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def warp_stages(heights, spacing, values, device, repeat: int) -> dict[str, float]:
    """Median seconds of the Warp stages: terrain + count/scan/emit with the γ = 1 blend in the vertex pass, as
    ``stepped()`` runs them (``step_arrays(..., gamma=1.0)``), and the separate blend pass alone (what a γ-only
    re-step runs, over arrays stepped without ``gamma``)."""
    import warp as wp

    from stepterrain import Terrain
    from stepterrain.stepped import blend, step_arrays

    steps, blends = [], []
    for _ in range(repeat):
        gc.collect()
        t0 = time.perf_counter()
        terrain = Terrain.from_heights(heights, spacing=spacing)
        arrays = step_arrays(terrain, values, device=device, gamma=1.0)
        wp.synchronize_device(device)
        t1 = time.perf_counter()
        steps.append(t1 - t0)
        del arrays
        gc.collect()
        arrays = step_arrays(terrain, values, device=device)
        wp.synchronize_device(device)
        t1 = time.perf_counter()
        blend(terrain, arrays, 1.0, device=device)
        wp.synchronize_device(device)
        blends.append(time.perf_counter() - t1)
        del arrays, terrain
    return {"step_arrays": statistics.median(steps), "blend": statistics.median(blends)}


def restep(device: Any, cells: int = 512, repeat: int = 30) -> dict[str, float]:
    """Interactive re-stepping of a ``cells``² terrain, kernels compiled and the terrain's buffers cached."""
    import warp as wp

    import stepterrain
    from stepterrain.stepped import blend, step_arrays

    heights, spacing = baselines.grid_heights(cells + 1)
    terrain = stepterrain.Terrain.from_heights(heights, spacing=spacing)
    lo, hi = terrain.height_range
    intervals = [(hi - lo) / 20, (hi - lo) / 25]
    gammas = [0.5, 0.75]
    for k in range(3):  # compile and warm
        stepterrain.stepped(terrain, interval=intervals[k % 2], device=device)

    def med(fn: Callable[[int], Any]) -> float:
        times = []
        for k in range(repeat):
            gc.collect()
            t0 = time.perf_counter()
            fn(k)
            wp.synchronize_device(device)
            times.append(time.perf_counter() - t0)
        return statistics.median(times) * 1e3

    out = {"cells": cells, "faces": 0}
    out["interval_mesh_ms"] = med(lambda k: stepterrain.stepped(terrain, interval=intervals[k % 2], device=device))

    def arrays_only(k: int) -> None:
        values = stepterrain.isovalues(terrain.height_range, interval=intervals[k % 2])
        step_arrays(terrain, values, device=device, gamma=1.0)  # the blend in the vertex pass

    def two_passes(k: int) -> None:  # keeps the points and step heights a later γ-only re-step blends
        values = stepterrain.isovalues(terrain.height_range, interval=intervals[k % 2])
        blend(terrain, step_arrays(terrain, values, device=device), 1.0, device=device)

    out["interval_arrays_ms"] = med(arrays_only)

    # The loop a user writes without collecting: ``mesh = stepped(...)`` drops the previous Trimesh, a reference
    # cycle (trimesh's own) whose arrays go back to the output pool when a later call frees it
    # (stepterrain.mesh.reclaim_dropped) or the cyclic collector runs (the rows above collect before each call,
    # outside the timer); and what one full collection costs in this process
    gc.collect()
    kept, times = None, []
    for k in range(repeat):
        t0 = time.perf_counter()
        kept = stepterrain.stepped(terrain, interval=intervals[k % 2], device=device)
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t0)
    out["interval_mesh_nogc_ms"] = statistics.median(times) * 1e3
    del kept
    collects = []
    for _ in range(5):
        t0 = time.perf_counter()
        gc.collect()
        collects.append(time.perf_counter() - t0)
    out["gc_collect_ms"] = statistics.median(collects) * 1e3
    out["interval_two_pass_ms"] = med(two_passes)
    values = stepterrain.isovalues(terrain.height_range, interval=intervals[0])
    arrays = step_arrays(terrain, values, device=device)
    out["faces"] = arrays.face_count
    out["vertices"] = arrays.vertex_count
    out["gamma_ms"] = med(lambda k: blend(terrain, arrays, gammas[k % 2], device=device))
    mesh = stepterrain.stepped(terrain, interval=intervals[0], device=device)

    def gamma_into_mesh(k: int) -> None:
        mesh.vertices = blend(terrain, arrays, gammas[k % 2], device=device)

    out["gamma_mesh_ms"] = med(gamma_into_mesh)
    return out


# ----------------------------------------------------------------------------- peak memory (child process)


def _status_kib(key: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise KeyError(key)


def child_peak(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one contender once in this (fresh) process; return the rise of VmHWM over VmRSS before the run."""
    if spec.get("pin"):
        pin_to_one_core()
    device = warp_device(spec["device"]) if spec["contender"] == "warp" else None
    fn = contender_fn(spec["contender"], device)
    case = Case(spec["case"], spec["steps"])
    heights, spacing, values = case.inputs()
    warm_up(fn, device)
    gc.collect()
    try:
        with open("/proc/self/clear_refs", "w") as fh:  # reset the peak (Linux >= 4.0)
            fh.write("5")
        reset = True
    except OSError:
        reset = False
    before = _status_kib("VmRSS")
    result = fn(heights, spacing, values)
    peak = _status_kib("VmHWM")
    tris, verts, actual = output_sizes(result)
    return {"peak_bytes": (peak - before) * 1024, "reset": reset, "triangles": tris, "actual_bytes": actual}


def measure_peak(contender: str, case: Case, device: str, pin: bool) -> int | None:
    spec = {"contender": contender, "case": case.name, "steps": case.steps, "device": device, "pin": pin}
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--child", json.dumps(spec)],
        capture_output=True,
        text=True,
        check=False,
    )
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith("{"):
            return int(json.loads(line)["peak_bytes"])
    sys.stderr.write(f"peak memory of {contender} on {case.label} failed:\n{proc.stderr[-2000:]}\n")
    return None


# ----------------------------------------------------------------------------- report


def _mb(n: float | None) -> str:
    return "-" if n is None else f"{n / 1e6:,.0f}"


def _s(x: float) -> str:
    if x != x:
        return "-"
    return f"{x * 1e3:.1f} ms" if x < 1 else f"{x:.2f} s"


def markdown(rows: list[Row], bw: dict[str, float], meta: dict[str, Any], restep_out: dict[str, float] | None) -> str:
    write_bw = bw["write_GBps"] * 1e9
    lines = [
        f"### Run started {meta['date']}",
        "",
        f"- command: `{meta['command']}`",
        f"- machine: {meta['cpu']}, {meta['cores']} cores ({meta['pinning']}), {meta['platform']}",
        f"- software: Python {meta['python']}, numpy {meta['numpy']}, warp {meta['warp']}, "
        f"VTK {meta['vtk']}, pyvista {meta['pyvista']}; "
        f"Warp device `{meta['device']}` ({meta['device_name']})",
        f"- memory write bandwidth (one core, 1 GiB): fill {bw['fill_GBps']:.1f} GB/s, "
        f"copy {bw['copy_GBps']:.1f} GB/s (bytes written per second); "
        f"the floor uses {bw['write_GBps']:.1f} GB/s",
        f"- code: {meta['code']}",
        f"- repeats: {meta['repeat']} (a contender whose run takes over {meta['slow_s']:.0f} s runs "
        f"{min(meta['repeat'], SLOW_REPEAT)} times); "
        "times are medians, "
        "`best` the fastest run",
        "",
        "Output MB and GB/s count the compact welded size, 12 B per vertex (float32 xyz) + 12 B per triangle "
        "(int32); the floor is that size written at the write bandwidth above. "
        "Peak MB is the rise of the peak resident set over the resident set just before the run, "
        "in a fresh process; `peak/out` divides it by "
        "the contender's actual output arrays (Warp: the trimesh's float64 vertices, int64 faces and face "
        "attributes).",
        "",
        "| case | steps | contender | median | best | triangles | vertices | Mtri/s | out MB | GB/s | "
        "% write BW | peak MB | peak/out | × Warp |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    warp_by_case = {(r.case, r.steps): r for r in rows if r.contender == "warp"}
    for r in rows:
        w = warp_by_case.get((r.case, r.steps))
        if not r.times:
            lines.append(f"| {r.case} | {r.steps} | {r.contender} | {r.note or 'skipped'} |||||||||||")
            continue
        ratio = "1" if r.contender == "warp" else (f"{r.median / w.median:,.1f}" if w and w.times else "-")
        gbps = r.compact_bytes / r.median / 1e9
        peak_ratio = "-" if r.peak_bytes is None else f"{r.peak_bytes / max(r.actual_bytes, 1):.2f}"
        lines.append(
            f"| {r.case} | {r.steps} | {r.contender} | {_s(r.median)} | {_s(r.best)} | {r.triangles:,} | "
            f"{r.vertices:,} | {r.triangles / r.median / 1e6:,.1f} | {_mb(r.compact_bytes)} | {gbps:.3f} | "
            f"{100 * gbps * 1e9 / write_bw:.2f} | {_mb(r.peak_bytes)} | {peak_ratio} | {ratio}{r.note} |"
        )
    lines += [
        "",
        "Ratios (baseline median / Warp median; > 1 means Warp is faster), Warp stages and the write floor "
        "(`rest` = total - stages: terrain checks, trimesh; VTK surface build = ImageData -> warped, "
        "triangulated surface, included in both VTK contenders' times):",
        "",
        "| case | steps | Warp total | step_arrays (blend in the vertex pass) | separate blend | rest (trimesh, …) | "
        "floor | Warp / floor | "
        "VTK banded / Warp | NumPy ref / Warp | clip-per-band / Warp | VTK surface build |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for (case, steps), w in warp_by_case.items():
        cells = []
        for b in BASELINES:
            r = next((x for x in rows if x.case == case and x.steps == steps and x.contender == b), None)
            cells.append("skipped" if r is None or not r.times else f"{r.median / w.median:,.1f}×")
        st = w.stages
        rest = max(0.0, w.median - st.get("step_arrays", 0))
        floor = w.compact_bytes / write_bw
        lines.append(
            f"| {case} | {steps} | {_s(w.median)} | {_s(st.get('step_arrays', float('nan')))} | "
            f"{_s(st.get('blend', float('nan')))} | {_s(rest)} | {_s(floor)} | {w.median / floor:,.0f}× | "
            + " | ".join(cells)
            + f" | {_s(meta.get('surface_s', {}).get(case, float('nan')))} |"
        )
    if restep_out:
        r = restep_out
        lines += [
            "",
            f"Re-stepping a {r['cells']}² terrain ({r['faces']:,} faces, {r['vertices']:,} vertices at 20 "
            "steps), kernels compiled, terrain buffers cached, median of 30; each timed call but the no-collection "
            f"row follows a `gc.collect()` outside the timer (one takes {r['gc_collect_ms']:.1f} ms in this process):",
            "",
            "| change | what is redone | median | goal |",
            "|---|---|---:|---:|",
            f"| interval (20 ↔ 25 steps) | `stepped(terrain, interval=...)` to a trimesh | "
            f"{r['interval_mesh_ms']:.1f} ms | < {RESTEP_GOAL_MS:.0f} ms |",
            f"| interval (20 ↔ 25 steps) | the same in a loop that never calls `gc.collect()` (each dropped Trimesh "
            f"is a reference cycle: the next call frees the one before last, whose memory serves it) | "
            f"{r['interval_mesh_nogc_ms']:.1f} ms | < {RESTEP_GOAL_MS:.0f} ms |",
            f"| interval (20 ↔ 25 steps) | `step_arrays(..., gamma=1.0)` (numpy arrays, blended in the vertex pass) | "
            f"{r['interval_arrays_ms']:.1f} ms | < {RESTEP_GOAL_MS:.0f} ms |",
            f"| interval (20 ↔ 25 steps) | `step_arrays` + `blend` (keeps the points for γ-only re-steps) | "
            f"{r['interval_two_pass_ms']:.1f} ms | < {RESTEP_GOAL_MS:.0f} ms |",
            f"| γ only (0.5 ↔ 0.75) | `blend` | {r['gamma_ms']:.1f} ms | < {RESTEP_GOAL_MS:.0f} ms |",
            f"| γ only (0.5 ↔ 0.75) | `blend` into `mesh.vertices` | {r['gamma_mesh_ms']:.1f} ms | "
            f"< {RESTEP_GOAL_MS:.0f} ms |",
        ]
    lines += ["", "Goals (issue 2 §6):", ""] + goal_lines(rows, restep_out) + [""]
    return "\n".join(lines)


def goal_lines(rows: list[Row], restep_out: dict[str, float] | None) -> list[str]:
    def verdict(ok: bool) -> str:
        return "**met**" if ok else "**not met**"

    out = []
    w = next((r for r in rows if r.case == "2048²" and r.steps == 20 and r.contender == "warp" and r.times), None)
    for b, goal in GOALS.items():
        r = next((x for x in rows if x.case == "2048²" and x.steps == 20 and x.contender == b and x.times), None)
        if w is None or r is None:
            out.append(f"- ≥ {goal:.0f}× vs {b} at 2048²/20 steps: not measured in this run")
        else:
            ratio = r.median / w.median
            out.append(f"- ≥ {goal:.0f}× vs {b} at 2048²/20 steps: measured {ratio:,.1f}× — {verdict(ratio >= goal)}")
    if restep_out:
        worst = max(restep_out["interval_mesh_ms"], restep_out["interval_arrays_ms"])
        out.append(
            f"- re-step {restep_out['cells']}² after a change of interval < {RESTEP_GOAL_MS:.0f} ms: "
            f"{restep_out['interval_arrays_ms']:.1f} ms (arrays), {restep_out['interval_mesh_ms']:.1f} ms "
            f"(trimesh, collected between calls) — {verdict(worst < RESTEP_GOAL_MS)}; a trimesh in a loop that never "
            f"collects: {restep_out['interval_mesh_nogc_ms']:.1f} ms"
        )
        out.append(
            f"- re-step after a change of γ only < {RESTEP_GOAL_MS:.0f} ms: "
            f"{restep_out['gamma_ms']:.1f} ms — "
            f"{verdict(restep_out['gamma_ms'] < RESTEP_GOAL_MS)}"
        )
    peaks = [r for r in rows if r.contender == "warp" and r.peak_bytes is not None]
    if peaks:
        worst_row = max(peaks, key=lambda r: r.peak_bytes / max(r.actual_bytes, 1))
        ratio = worst_row.peak_bytes / max(worst_row.actual_bytes, 1)
        out.append(
            f"- Warp peak memory ≤ {PEAK_GOAL:.0f}× the output mesh: worst {ratio:.2f}× "
            f"({worst_row.case}, {worst_row.steps} steps) — {verdict(ratio <= PEAK_GOAL)}"
        )
    return out


# ----------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes",
        type=int,
        nargs="*",
        default=[256, 1024],
        help="grid sizes in cells per side (nodes = size + 1), a crop/mirror-tiling of a real DEM",
    )
    parser.add_argument("--steps", type=int, nargs="+", default=[5, 20, 50], help="equal height intervals")
    parser.add_argument(
        "--dems",
        nargs="*",
        default=list(baselines.REAL_DEMS),
        help=f"real DEMs at native size ({', '.join(baselines.REAL_DEMS)}; 'none' for none)",
    )
    parser.add_argument("--contenders", nargs="+", default=list(CONTENDERS), choices=CONTENDERS)
    parser.add_argument("--repeat", type=repeat_count, default=3, help="timed runs per contender and case")
    parser.add_argument("--slow-seconds", type=float, default=10.0,
                        help=f"a contender whose run takes longer runs at most {SLOW_REPEAT} times")  # fmt: skip
    parser.add_argument(
        "--skip-slow", action="store_true", help="skip clip-per-band above 1024² (it takes minutes at 2048²)"
    )
    parser.add_argument("--no-memory", action="store_true", help="skip the peak-memory subprocesses")
    parser.add_argument("--no-restep", action="store_true", help="skip the 512² re-step timings")
    parser.add_argument("--device", default="cpu", help="Warp device (default cpu)")
    parser.add_argument("--all-cores", action="store_true", help="do not pin the process to one core")
    parser.add_argument("--output", type=Path, help="write the markdown report here (also printed)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.child:
        print(json.dumps(child_peak(json.loads(args.child))))
        return 0

    import pyvista as pv
    import vtk
    import warp as wp

    started = _dt.datetime.now().astimezone().strftime("%Y-%m-%d %H:%M %Z")
    pinning = "all cores" if args.all_cores else pin_to_one_core()
    device = warp_device(args.device)
    bw = memory_bandwidth()
    print(f"write bandwidth: fill {bw['fill_GBps']:.1f} GB/s, copy {bw['copy_GBps']:.1f} GB/s", flush=True)
    code_before = code_version()
    print(code_before, flush=True)
    fns = {c: contender_fn(c, device) for c in args.contenders}
    for fn in fns.values():
        warm_up(fn, device)

    dems = [] if args.dems in ([], ["none"]) else args.dems
    cases = [Case(str(s), k) for s in args.sizes for k in args.steps] + [Case(d, k) for d in dems for k in args.steps]
    rows: list[Row] = []
    surface_s: dict[str, float] = {}
    for case in cases:
        heights, spacing, values = case.inputs()
        if case.label not in surface_s and any(c.startswith("vtk") for c in args.contenders):
            surface_s[case.label] = median_time(
                functools.partial(baselines.build_surface, heights, spacing), args.repeat
            )
        for contender in args.contenders:
            row = Row(case.label, case.steps, len(values), contender)
            rows.append(row)
            if skipped(contender, case, heights, args.skip_slow):
                row.note = "skipped (--skip-slow)"
                print(f"{case.label:>22} {case.steps:3d} {contender:>18}: skipped", flush=True)
                continue
            row.times, result = time_contender(fns[contender], heights, spacing, values, args.repeat, args.slow_seconds)
            row.triangles, row.vertices, row.actual_bytes = output_sizes(result)
            del result
            gc.collect()
            if contender == "warp":
                row.stages = warp_stages(heights, spacing, values, device, max(args.repeat, 5))
            if not args.no_memory:
                row.peak_bytes = measure_peak(contender, case, args.device, not args.all_cores)
            print(
                f"{case.label:>22} {case.steps:3d} {contender:>18}: median {_s(row.median):>10}, "
                f"{row.triangles:,} triangles, peak {_mb(row.peak_bytes)} MB",
                flush=True,
            )
        ref = next(
            (r for r in rows if r.case == case.label and r.steps == case.steps and r.contender == "numpy_ref"),
            None,
        )
        warp_row = next(
            (r for r in rows if r.case == case.label and r.steps == case.steps and r.contender == "warp"),
            None,
        )
        if (
            ref
            and warp_row
            and ref.times
            and warp_row.times
            and (ref.triangles, ref.vertices) != (warp_row.triangles, warp_row.vertices)
        ):
            warp_row.note = f" (ref differs: {ref.triangles:,} tri)"

    restep_out = None if args.no_restep else restep(device)
    if restep_out:
        print(f"re-step 512²: {restep_out}", flush=True)
    meta = {
        "date": started,
        "command": "python benchmarks/run_stepped.py " + " ".join(sys.argv[1:] if argv is None else argv),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "pinning": pinning,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "warp": wp.__version__,
        "vtk": vtk.vtkVersion.GetVTKVersion(),
        "pyvista": pv.__version__,
        "device": str(device),
        "device_name": getattr(device, "name", str(device)),
        "surface_s": surface_s,
        "code": code_before,
        "repeat": args.repeat,
        "slow_s": args.slow_seconds,
    }
    if code_version() != code_before:
        meta["code"] += f" — CHANGED during the run, now: {code_version()}"
    text = markdown(rows, bw, meta, restep_out)
    print(text)
    if args.output:
        args.output.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
