"""What the benchmark scripts share when they write ``benchmarks/results/*.json``."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from ges_core.paths import atomic_write_text

__all__ = ["code_state", "write_results"]


def code_state() -> dict:
    """The commit measured and the tracked files that differed from it (read-only git queries)."""

    def git(*args: str) -> str:
        run = subprocess.run(["git", *args], cwd=Path(__file__).resolve().parent, capture_output=True, text=True)
        return run.stdout.strip()

    modified = git("status", "--porcelain", "--untracked-files=no").splitlines()
    return {"commit": git("rev-parse", "HEAD"), "modified": modified}


def write_results(path: Path, data: dict) -> None:
    """``data`` as indented JSON at ``path`` (atomically: a killed run leaves the previous file)."""
    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
    print(f"wrote {path}")
