"""The Khronos glTF validator (npm ``gltf-validator``) from Python: one node process validates many files.

``.ci/run`` installs it under ``.ci/node_modules``; without node or the package, :func:`available` says why
and the tests that need it skip.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / ".ci" / "validate_gltf.js"
PACKAGE = ROOT / ".ci" / "node_modules" / "gltf-validator"


def available() -> tuple[bool, str]:
    """(True, "") when node and the validator package are installed, else (False, the reason)."""
    if shutil.which("node") is None:
        return False, "node is not installed (the Khronos glTF validator runs on Node.js)"
    if not PACKAGE.is_dir():
        return False, f"gltf-validator is not installed in {PACKAGE.parent} (bash .ci/run installs it)"
    return True, ""


def validate(paths: list[Path] | list[str], timeout: float = 600.0) -> dict[str, dict]:
    """Validate ``paths`` in one node process; {path: {"errors", "warnings", "infos", "hints", "messages"}}."""
    if not paths:
        return {}
    result = subprocess.run(
        ["node", str(SCRIPT), *[str(p) for p in paths]], capture_output=True, text=True, timeout=timeout
    )
    if result.returncode not in (0, 1):
        raise RuntimeError(f"glTF validator failed (exit {result.returncode}): {result.stderr.strip()}")
    return json.loads(result.stdout)["reports"]


def problems(reports: dict[str, dict]) -> list[str]:
    """One line per file with errors or warnings: the file, the counts and the first messages."""
    lines = []
    for path, report in reports.items():
        if report["errors"] or report["warnings"]:
            bad = [m for m in report["messages"] if m["severity"] <= 1][:5]
            detail = "; ".join(f"{m['code']} at {m['pointer']}: {m['message']}" for m in bad)
            lines.append(f"{path}: {report['errors']} errors, {report['warnings']} warnings: {detail}")
    return lines
