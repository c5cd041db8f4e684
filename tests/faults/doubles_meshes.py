"""Test doubles of the Stage 1 task runner for ``test_faults_meshes.py``, in a module of their own: the pool's
spawned workers import the module a runner lives in, and this one imports nothing heavy (1 s per worker
instead of 4)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import NamedTuple


class FakeTask(NamedTuple):
    """What ``pipeline._results`` needs of a task: it hands the task to the runner untouched."""

    index: int


def finish_when_told(task, flag: str) -> list[int]:
    """Task 0 waits (up to 20 s) for the file ``flag`` to exist; the others return at once. Returns [index]."""
    deadline = time.monotonic() + 20
    while task.index == 0 and not Path(flag).exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return [task.index]


def records_when_told(task, flag: str) -> list:
    """Like :func:`finish_when_told`, returning one valid record per (object, hand) of a real task."""
    from test_dataset import make_record

    finish_when_told(task, flag)
    return [make_record(oid, hand) for oid, hands in task.pairs for hand in hands]
