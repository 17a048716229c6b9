"""Fixes found by an audit of the benchmark harness (benchmarks/run_*.py): crashes on documented options, reports that
print another command line than the one run. The scripts are loaded from their files, as ``python benchmarks/X.py``
runs them (``benchmarks/`` first on ``sys.path``), and stopped before any timed work."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


def _script(name: str, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(BENCH))  # the scripts import ``machine`` as their own folder's module
    spec = importlib.util.spec_from_file_location(f"bench_harness_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _RanOn(Exception):
    """Raised by a stubbed first step: the script got past its argument checks."""


@pytest.mark.parametrize("counts", [["1", "2"], ["4"], ["0", "5"], ["0", "-1"]])
def test_run_closeup_rejects_counts_it_cannot_report(monkeypatch, counts):
    """``run_closeup.py --counts 1 2`` (any list without 0) rendered every configuration, then crashed with a TypeError
    (``base['best']`` of the missing 0-close-up frame, every ratio's denominator) after minutes; ``--counts 5`` timed 4
    close-ups (there are four ROI spots) and labelled them 5. Both are now usage errors, before any work."""
    module = _script("run_closeup", monkeypatch)

    def stop(*_args, **_kwargs):
        raise _RanOn

    monkeypatch.setattr(module, "load_terrain", stop)
    with pytest.raises(SystemExit) as exit_info:
        module.main(["--counts", *counts, "--all-cores"])
    assert exit_info.value.code == 2


def test_run_closeup_accepts_its_documented_counts(monkeypatch):
    """The default and README's counts still run on (to the first step, stubbed here)."""
    module = _script("run_closeup", monkeypatch)

    def stop(*_args, **_kwargs):
        raise _RanOn

    monkeypatch.setattr(module, "load_terrain", stop)
    for argv in (["--all-cores"], ["--counts", "0", "4", "--all-cores"]):
        with pytest.raises(_RanOn):
            module.main(argv)


def test_run_texture_reports_the_command_it_was_given(monkeypatch, capsys):
    """``run_texture.main(argv)`` printed ``sys.argv`` (here pytest's) as its command, not ``argv``: the report's
    "Command:" line, which RESULTS.md sections quote, named another run than the one measured."""
    from .conftest import shared_file

    dem = shared_file("big_tujunga_srtm_30m_utm11n.npz")  # skips without shared/data, as the tests do
    module = _script("run_texture", monkeypatch)
    monkeypatch.setattr(module, "find_dem", lambda: dem)  # the tests' shared/data (STEPTERRAIN_SHARED_DATA too)
    argv = ["--cases", "contours", "--contour-size", "32", "--repeat", "1", "--all-cores"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    assert f"Command: `python benchmarks/run_texture.py {' '.join(argv)}`" in out
    assert "### Contour lines on a 32² DEM" in out


def test_run_cuda_reports_the_command_it_was_given(monkeypatch, capsys):
    """``run_cuda.main(argv)`` printed ``sys.argv`` as its command, as run_texture did."""
    from .conftest import SHARED_DATA

    module = _script("run_cuda", monkeypatch)
    if not (SHARED_DATA / module.baselines.DEM_FILE).exists():
        pytest.skip(f"{module.baselines.DEM_FILE} not in {SHARED_DATA}")
    monkeypatch.setattr(module.baselines, "SHARED_DATA", SHARED_DATA)  # a worktree finds it as the tests do
    argv = ["--devices", "cpu", "--benches", "closeup", "--repeat", "1"]
    assert module.main(argv) == 0
    out = capsys.readouterr().out
    assert f"with `python benchmarks/run_cuda.py {' '.join(argv)}`" in out
    assert "| close-up layers per frame, 4 ROIs on 1025²" in out


def test_run_globe_gives_pymartini_as_many_runs_as_ours(monkeypatch):
    """Preprocessing reported the best of ``--repeat`` runs of ``Globe.from_latlon`` against the best of ``--repeat //
    2`` of pymartini's set-up: a best of fewer runs is a slower best, a bias in our favour. Both get ``--repeat``."""
    from .conftest import shared_file

    pytest.importorskip("pymartini")
    relief = shared_file("global_relief.npz")  # skips without shared/data, as the tests do
    module = _script("run_globe", monkeypatch)
    monkeypatch.setattr(module, "DATA_DIRS", [relief.parent])
    real_best, repeats = module.best, []

    def counting(fn, repeat):
        repeats.append(repeat)
        return real_best(fn, repeat)

    monkeypatch.setattr(module, "best", counting)
    lines: list[str] = []
    module.preprocessing(33, 4, lines)
    assert repeats == [4, 4]
    assert any("pymartini `Martini(33)`" in line for line in lines)


def test_pytest_benchmarks_collects_the_bench_modules_only():
    """benchmarks/README.md's ``pytest benchmarks -k small --benchmark-enable`` failed at collection:
    ``--doctest-modules`` (the project's addopts) imported every script of the folder, and ``globe_ab.py`` parsed
    pytest's ``sys.argv`` as its own (``int('small')``) at import, after pinning the process to one core where it got
    that far. benchmarks/conftest.py now lets pytest collect ``bench_*.py`` only."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "pytest", "benchmarks", "-k", "small", "--collect-only", "-q"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    collected = [line for line in proc.stdout.splitlines() if "::" in line]
    assert collected and all(line.startswith(("benchmarks/bench_stepped.py::", "benchmarks/bench_texture.py::"))
                             for line in collected)
    assert any("small-257" in line for line in collected)


def test_pytest_benchmarks_still_honours_ignore():
    """benchmarks/conftest.py answered False ("collect it") for ``bench_*.py``, and pytest takes the first answer of
    ``pytest_ignore_collect``: ``pytest benchmarks --ignore=benchmarks/bench_texture.py`` (or ``--ignore-glob``)
    collected bench_texture.py all the same. It now answers only for the scripts it leaves out."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "pytest", "benchmarks", "-k", "small", "--collect-only", "-q",
                           "--ignore=benchmarks/bench_texture.py"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    collected = [line for line in proc.stdout.splitlines() if "::" in line]
    assert collected and all(line.startswith("benchmarks/bench_stepped.py::") for line in collected), collected
