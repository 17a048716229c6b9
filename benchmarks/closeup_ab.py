"""One side of an interleaved before/after timing of the close-up frame (benchmarks/RESULTS.md, close-ups run
2026-11-22 09:01 UTC (helper)).

    git archive <old commit> | tar -x -C /tmp/old && cp -r /tmp/old/kernels /tmp/old/stepterrain/kernels
    for k in 1 2 3; do for r in /tmp/old .; do python benchmarks/closeup_ab.py $r 6 >> /tmp/ab.jsonl; done; done
    python benchmarks/closeup_ab.py --summary /tmp/ab.jsonl

Imports stepterrain from ROOT, pins itself to core 0 (``--core`` to change) and one thread, renders FRAMES
frames each of 0 and 4 close-ups (the whole pipeline, ``reuse_closeups=False``, the run_closeup.py scene),
interleaved, and prints one JSON line: the root and each frame's wall and CPU seconds.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from pathlib import Path


def summary(path: str) -> None:
    rows: dict[str, dict[str, list[list[float]]]] = {}
    for line in Path(path).read_text().splitlines():
        if not line.startswith("{"):
            continue
        d = json.loads(line)
        side = rows.setdefault(d["root"], {"0": [[], []], "4": [[], []]})
        for count in ("0", "4"):
            side[count][0].extend(d[count]["wall"])
            side[count][1].extend(d[count]["cpu"])
    for root, side in rows.items():
        for i, what in ((0, "wall"), (1, "CPU")):
            b0, b4 = min(side["0"][i]), min(side["4"][i])
            m0, m4 = statistics.median(side["0"][i]), statistics.median(side["4"][i])
            print(f"{root} {what}: 0 close-ups best {b0:.3f} median {m0:.3f} | 4 best {b4:.3f} median {m4:.3f} | "
                  f"ratio best {b4 / b0:.2f}x median {m4 / m0:.2f}x ({len(side['0'][i])} frames each)")


def main() -> None:
    if sys.argv[1:2] == ["--summary"]:
        summary(sys.argv[2])
        return
    root = Path(sys.argv[1] if len(sys.argv) > 1 else ".").resolve()
    frames = int(sys.argv[2]) if len(sys.argv) > 2 else 6
    core = int(sys.argv[sys.argv.index("--core") + 1]) if "--core" in sys.argv else 0
    sys.path.insert(0, str(root))
    # the scene of ROOT's own run_closeup.py (which puts ROOT first on the path)
    bench = root / "benchmarks" if (root / "benchmarks" / "run_closeup.py").exists() else Path(__file__).parent
    sys.path.insert(0, str(bench.resolve()))
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    import run_closeup as rc

    import stepterrain as st
    from stepterrain import render
    from stepterrain.closeup import render_closeups

    if not st.__file__.startswith(str(root)):
        raise SystemExit(f"imported {st.__file__}, not from {root}")
    st.set_cpu_threads(1)
    terrain, _ = rc.load_terrain()
    setups = {}
    for count in (0, 4):
        cus = rc.closeups_for(terrain, count)
        renderer = render.LayeredRenderer(window_size=rc.WINDOW, z_scale=2.0)
        box = rc.frame_bounds(terrain, cus)
        render_closeups(terrain, cus, window_size=rc.WINDOW, z_scale=2.0, bounds=box, renderer=renderer, device="cpu",
                        reuse_closeups=False)  # warm-up
        setups[count] = (cus, box, renderer)
    out: dict[str, object] = {"root": str(root)}
    times = {count: {"wall": [], "cpu": []} for count in setups}
    for _ in range(frames):
        for count, (cus, box, renderer) in setups.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            render_closeups(terrain, cus, window_size=rc.WINDOW, z_scale=2.0, bounds=box, renderer=renderer,
                            device="cpu", reuse_closeups=False)
            times[count]["wall"].append(time.perf_counter() - start)
            times[count]["cpu"].append(time.process_time() - start_cpu)
    for count, (_, _, renderer) in setups.items():
        renderer.close()
        out[str(count)] = times[count]
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
