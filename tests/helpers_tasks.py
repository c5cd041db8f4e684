"""Task doubles for the executor tests (tests/test_executors.py, tests/test_executor_ray.py).

Module level, so a spawned pool worker imports them by name; a Ray worker gets them pickled by value
(``ray.cloudpickle.register_pickle_by_value`` of this module, in the Ray test's fixture).
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

__all__ = [
    "die_on_victim",
    "fail_on_three",
    "gone_within",
    "process_gone",
    "run_all",
    "sleep_with_pid",
    "square_with_pid",
]


def square_with_pid(i: int) -> tuple[int, int]:
    return i * i, os.getpid()


def sleep_with_pid(i: int, marker_dir: str, seconds: float) -> int:
    """Write this worker's pid to ``marker_dir/pid-<i>``, then sleep ``seconds`` (a long task to kill under)."""
    import time

    (Path(marker_dir) / f"pid-{i}").write_text(str(os.getpid()))
    time.sleep(seconds)
    return i


def fail_on_three(i: int) -> int:
    if i == 3:
        raise ValueError(f"task {i} fails on purpose")
    return i


def die_on_victim(i: int, victim: int, marker_dir: str, times: int) -> tuple[int, int]:
    """SIGKILL this worker process when ``i == victim``, on its first ``times`` attempts (counted by marker files)."""
    if i == victim:
        marks = Path(marker_dir)
        done = len(list(marks.glob("attempt-*")))
        (marks / f"attempt-{done}").touch()
        if done < times:
            os.kill(os.getpid(), signal.SIGKILL)
    return i, os.getpid()


def run_all(executor, fn, items, *extra) -> dict:
    """``fn(i, *extra)`` for each ``i`` of ``items`` on ``executor``: ``{i: Done}``."""
    with executor as ex:
        tickets = {ex.submit(fn, i, *extra): i for i in items}
        return {tickets[d.ticket]: d for d in ex.as_completed()}


def process_gone(pid: int) -> bool:
    """True once ``pid`` no longer runs (exited, or a zombie nobody reaped); reads /proc (Linux)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def gone_within(pids: list[int], seconds: float) -> bool:
    """Whether every process of ``pids`` is gone (:func:`process_gone`) within ``seconds``."""
    import time

    deadline = time.monotonic() + seconds
    while not all(process_gone(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    return all(process_gone(p) for p in pids)
