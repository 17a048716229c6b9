"""Collect only the pytest-benchmark modules ``bench_*.py`` from this folder.

The project's ``addopts`` include ``--doctest-modules``, which imports every ``.py`` file of a folder named on the
command line: ``pytest benchmarks -k small`` imported the scripts as well, and ``globe_ab.py`` reads ``sys.argv`` (here
pytest's) and pins its process to one core at import, which broke the collection. The scripts are run as
``python benchmarks/NAME.py``, never collected.
"""

from __future__ import annotations

from pathlib import Path


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    """True for this folder's scripts; None (pytest decides) for the rest: the hook takes the first answer, and a
    False would also override ``--ignore``, ``--ignore-glob`` and ``collect_ignore`` for ``bench_*.py``."""
    here = Path(__file__).parent
    if collection_path.suffix == ".py" and collection_path.parent == here and collection_path.name != "conftest.py":
        if not collection_path.name.startswith("bench_"):
            return True
    return None
