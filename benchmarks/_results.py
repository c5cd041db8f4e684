"""What the benchmark scripts share when they write ``benchmarks/results/*.json``."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from ges_core.paths import atomic_write_text

__all__ = ["code_state", "results_path", "write_results"]


def code_state() -> dict:
    """The commit measured and the tracked files that differed from it (read-only git queries)."""

    def git(*args: str) -> str:
        run = subprocess.run(["git", *args], cwd=Path(__file__).resolve().parent, capture_output=True, text=True)
        return run.stdout.strip()

    modified = git("status", "--porcelain", "--untracked-files=no").splitlines()
    return {"commit": git("rev-parse", "HEAD"), "modified": modified}


RESULTS_DIR = Path(__file__).resolve().parent / "results"


def results_path(name: str) -> Path:
    """benchmarks/results/NAME.json for a script's ``--results NAME``; a path or a name ending in .json is refused
    (SystemExit saying so) instead of writing outside the results folder."""
    if not name or "/" in name or "\\" in name or name.endswith(".json"):
        raise SystemExit(f"--results takes a name (written to benchmarks/results/NAME.json), got {name!r}")
    return RESULTS_DIR / f"{name}.json"


def write_results(path: Path, data: dict) -> None:
    """``data`` as indented JSON at ``path`` (atomically: a killed run leaves the previous file)."""
    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
    print(f"wrote {path}")
