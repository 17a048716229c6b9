"""Time and traced peak memory of the OBJ preparation steps :func:`read_mesh` runs before trimesh's reader.

Files of about ``--mb`` MB each, written to ``--work`` (tmpfs by default):

- ``tidy``: tab-separated words, indented lines, a comment after each face and, after the first faces, more objects
  of ``v`` lines and faces of relative indices (so the text is tidied and then made absolute);
- ``tidy-crlf``: the same with CRLF line ends;
- ``plain``: what :func:`save_mesh` writes (vertices, then faces), for the line-start searches;
- ``comments``: ``plain`` with a comment line full of ``f`` and ``v`` bytes before each vertex line, for the
  line-start searches' worst case (each ``f`` or ``v`` not at a line's start passed over in turn).

Printed per file: the best of ``--rounds`` wall times and the tracemalloc peak of ``_obj_tidied(file,
_obj_newlines(file))`` (the whole preparation of the text trimesh reads) and of ``_obj_relative_after_vertices``
(the line-start searches) on the file mapped.

Run: ``python benchmarks/obj_tidy.py [--mb 40] [--rounds 3] [--work /dev/shm]``.
"""

from __future__ import annotations

import argparse
import mmap
import tempfile
import time
import tracemalloc
from pathlib import Path

from stepterrain import export


def _files(work: Path, mb: float) -> dict[str, Path]:
    target = int(mb * 1e6)
    obj = b"\tv\t0.125\t1.5\t2.25\n  v 1.125 0.5 2.25\n v 0.125 1.5 3.25\nf\t-3 -2\t-1   # a face\n"
    head = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    tidy = head + obj * ((target - len(head)) // len(obj))
    rows = target // 2 // 24
    plain = (b"".join(b"v %d.25 %d.5 0.125\n" % (i, i % 977) for i in range(rows))
             + b"".join(b"f %d %d %d\n" % (i, i + 1, i + 2) for i in range(1, rows - 2)))
    lines = plain.split(b"\n")
    comments = b"\n".join(b"# of faces of vertices\n" + line if line.startswith(b"v") else line for line in lines)
    paths = {}
    for name, data in (("tidy", tidy), ("tidy-crlf", tidy.replace(b"\n", b"\r\n")), ("plain", plain),
                       ("comments", comments)):
        paths[name] = work / f"obj_tidy_{name}.obj"
        paths[name].write_bytes(data)
    return paths


def _measure(call, rounds: int) -> tuple[float, int]:
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - start)
    tracemalloc.start()
    try:
        call()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return best, peak


def _searches(path: Path) -> None:
    with open(path, "rb") as stream, mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
        export._obj_relative_after_vertices(mapped)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=40.0)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--work", default="/dev/shm" if Path("/dev/shm").is_dir() else None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.work) as folder:
        for name, path in _files(Path(folder), args.mb).items():
            size = path.stat().st_size
            tidied, peak = _measure(lambda p=path: export._obj_tidied(p, export._obj_newlines(p)), args.rounds)
            searched, _ = _measure(lambda p=path: _searches(p), args.rounds)
            print(f"{name:10s} {size / 1e6:6.1f} MB  prepare {tidied:6.3f} s  peak {peak / 1e6:7.1f} MB "
                  f"({peak / size:4.1f}x)  line-start searches {searched * 1e3:7.1f} ms")


if __name__ == "__main__":
    main()
