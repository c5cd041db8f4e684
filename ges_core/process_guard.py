"""Worker processes that do not outlive their parent: :func:`die_with_parent`, called first in a worker.

A spawned worker (an env worker of ``ges train-expert --workers``, a process-pool worker of ``ges synth
--workers``) whose parent is killed would otherwise go on with its task, minutes of engine work nobody reads.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys

__all__ = ["die_with_parent"]

_PR_SET_PDEATHSIG = 1
"""prctl option (linux/prctl.h): the signal this process gets when its parent dies."""


def die_with_parent(parent_pid: int) -> None:
    """Linux: ask for SIGKILL when the parent dies (prctl PR_SET_PDEATHSIG); exit at once if it already has.

    ``parent_pid``: the parent's pid as the parent saw it (``os.getpid()`` there, passed to the worker). Elsewhere
    nothing is set up: a worker then ends when its pipe to the parent closes (env workers at their next command,
    pool workers after their current task).
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL))
    if os.getppid() != parent_pid:
        os._exit(0)
