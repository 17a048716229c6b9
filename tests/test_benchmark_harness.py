"""Fixes found by an audit of the benchmark harness (benchmarks/run_*.py): crashes on documented options, reports that
print another command line than the one run. The scripts are loaded from their files, as ``python benchmarks/X.py``
runs them (``benchmarks/`` first on ``sys.path``), and stopped before any timed work."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"


def _script(name: str, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(BENCH))  # the scripts import ``machine`` as their own folder's module
    spec = importlib.util.spec_from_file_location(f"bench_harness_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # as a script's __main__ is: its dataclasses look it up
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


_COLLECT = [sys.executable, "-m", "pytest", "benchmarks", "-k", "small", "--collect-only", "-q"]


@pytest.fixture(scope="module")
def benchmark_collections():
    """``pytest benchmarks -k small --collect-only -q`` as is and with ``--ignore=benchmarks/bench_texture.py``, run
    at once in two interpreters (each imports the project: one after the other took twice the time on two cores):
    their CompletedProcesses by the options added."""
    import subprocess

    extras = ((), ("--ignore=benchmarks/bench_texture.py",))
    started = [subprocess.Popen([*_COLLECT, *extra], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True) for extra in extras]  # fmt: skip
    try:
        outputs = [p.communicate(timeout=300) for p in started]  # then their exit statuses are set
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
                p.communicate()
    return {extra: subprocess.CompletedProcess(p.args, p.returncode, *out)
            for extra, p, out in zip(extras, started, outputs, strict=True)}


def test_pytest_benchmarks_collects_the_bench_modules_only(benchmark_collections):
    """benchmarks/README.md's ``pytest benchmarks -k small --benchmark-enable`` failed at collection:
    ``--doctest-modules`` (the project's addopts) imported every script of the folder, and ``globe_ab.py`` parsed
    pytest's ``sys.argv`` as its own (``int('small')``) at import, after pinning the process to one core where it got
    that far. benchmarks/conftest.py now lets pytest collect ``bench_*.py`` only."""
    proc = benchmark_collections[()]
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    collected = [line for line in proc.stdout.splitlines() if "::" in line]
    assert collected and all(line.startswith(("benchmarks/bench_stepped.py::", "benchmarks/bench_texture.py::"))
                             for line in collected)
    assert any("small-257" in line for line in collected)


def test_pytest_benchmarks_still_honours_ignore(benchmark_collections):
    """benchmarks/conftest.py answered False ("collect it") for ``bench_*.py``, and pytest takes the first answer of
    ``pytest_ignore_collect``: ``pytest benchmarks --ignore=benchmarks/bench_texture.py`` (or ``--ignore-glob``)
    collected bench_texture.py all the same. It now answers only for the scripts it leaves out."""
    proc = benchmark_collections[("--ignore=benchmarks/bench_texture.py",)]
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    collected = [line for line in proc.stdout.splitlines() if "::" in line]
    assert collected and all(line.startswith("benchmarks/bench_stepped.py::") for line in collected), collected


_REPEAT_SCRIPTS = ["run_batch", "run_closeup", "run_cuda", "run_globe", "run_nodata_levels", "run_solid", "run_stepped",
                   "run_texture"]


@pytest.mark.parametrize("name", _REPEAT_SCRIPTS)
@pytest.mark.parametrize("repeat", ["0", "-2", "two"])
def test_run_scripts_refuse_a_repeat_below_one(monkeypatch, capsys, name, repeat):
    """``--repeat 0`` set every contender up (a DEM read, a terrain stepped) and then crashed on the best or median of
    no run (``min()`` of an empty list, ``statistics.median``); it is a usage error now, before any work, in each
    run_*.py script (machine.repeat_count)."""
    try:
        module = _script(name, monkeypatch)
    except ImportError as exc:  # a contender the script imports at the top
        pytest.skip(f"{name}: {exc}")
    with pytest.raises(SystemExit) as exit_info:
        module.main(["--repeat", repeat])
    assert exit_info.value.code == 2
    assert "argument --repeat: expected" in capsys.readouterr().err


def test_run_scripts_accept_a_repeat_of_one():
    """The type's other side: 1 and more are runs."""
    sys.path.insert(0, str(BENCH))
    try:
        from machine import repeat_count
    finally:
        sys.path.remove(str(BENCH))
    assert [repeat_count(text) for text in ("1", "7")] == [1, 7]


def test_run_texture_finds_the_dem_in_stepterrain_shared_data(monkeypatch, tmp_path):
    """``run_texture.find_dem`` looked only in a shared/data above benchmarks/ and ignored ``STEPTERRAIN_SHARED_DATA``
    (which the other scripts and the tests honour): the folder it names comes first."""
    (tmp_path / "big_tujunga_srtm_30m_utm11n.npz").write_bytes(b"")
    module = _script("run_texture", monkeypatch)
    monkeypatch.setenv("STEPTERRAIN_SHARED_DATA", str(tmp_path))
    assert module.find_dem() == tmp_path / "big_tujunga_srtm_30m_utm11n.npz"


def test_run_cuda_restep_row_gets_its_ratio(monkeypatch):
    """run_cuda's re-step row held "new γ ... ms" in its check column, so the report gave the other devices no ratio to
    the first (every other pipeline has one): the γ time moved to "also", the ratio is there."""
    import types

    import warp as wp

    module = _script("run_cuda", monkeypatch)
    from benchmarks import run_stepped

    timings = {"cpu": 40.0, "cuda:0": 4.0}
    monkeypatch.setattr(run_stepped, "restep", lambda device, cells, repeat: {
        "faces": 1000, "interval_mesh_ms": timings[device.name], "interval_arrays_ms": timings[device.name] / 2,
        "gamma_ms": 1.0})
    monkeypatch.setattr(wp, "get_device", lambda name: types.SimpleNamespace(name=str(name)))
    rows: list[list[str]] = []
    module.bench_restep(["cpu", "cuda:0"], 1, rows)
    text = module.markdown(rows, ["cpu", "cuda:0"], types.SimpleNamespace(repeat=1), "now", ["--benches", "restep"])
    row = next(line for line in text.splitlines() if line.startswith("| re-step 512²") and "cuda:0" in line)
    assert "10.0x faster than `cpu`" in row and "new γ 1.00 ms" in row
