"""The executor interface: submit picklable tasks, get each one's outcome as soon as it finishes.

An :class:`Executor` is used once, as a context manager: :meth:`Executor.submit` queues calls
``fn(*args)``, :meth:`Executor.as_completed` starts them and yields one :class:`Done` per call in the order
they finish, and leaving the ``with`` block cancels the calls not started yet (a stopped run starts nothing
more). A task that raises gives a :class:`Done` whose ``error`` is that exception; a task whose worker
process died more than ``max_retries`` times gives one whose ``error`` is a :class:`TaskLostError`. Every
other task still runs: a dying worker loses only the tasks it was running.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, ClassVar

from ges_core.errors import ConfigError, GesError

__all__ = ["DEFAULT_MAX_RETRIES", "Done", "Executor", "TaskLostError", "call_with_setup"]

DEFAULT_MAX_RETRIES = 3
"""Times a task is run again after its worker process died (Ray's own default for tasks is 3 too). A task
that kills its worker each time is given up after 1 + 3 attempts, so one bad input cannot hold a run forever."""


class TaskLostError(GesError):
    """A task's worker process died (killed, out of memory, a crash in native code) on every attempt."""


@dataclass(frozen=True)
class Done:
    """The outcome of one submitted call."""

    ticket: int
    """What :meth:`Executor.submit` returned for the call: 0, 1, 2, ... in submission order."""
    value: Any = None
    """What the call returned (None when it failed)."""
    error: BaseException | None = None
    """The exception the call raised, or a :class:`TaskLostError` when its worker died on every attempt."""
    attempts: int = 1
    """How many times the call was started (more than one after a worker died)."""

    @property
    def ok(self) -> bool:
        """Whether the call returned."""
        return self.error is None

    def result(self) -> Any:
        """The call's value; raises its error when it failed."""
        if self.error is not None:
            raise self.error
        return self.value


def call_with_setup(setup: Callable | None, setup_args: tuple, fn: Callable, args: tuple) -> Any:
    """``setup(*setup_args)`` then ``fn(*args)``: how a worker runs one task (``setup`` sets per-process state,
    e.g. :func:`ges_core.threads.set_torch_threads`; it is cheap and idempotent, so it may run before every task)."""
    if setup is not None:
        setup(*setup_args)
    return fn(*args)


class Executor(ABC):
    """Runs submitted calls ``fn(*args)`` in worker processes and yields their outcomes as they finish.

    ``fn`` must be importable by the workers (a module-level function of an installed module) and ``args``
    picklable. ``setup(*setup_args)`` runs in each worker before its tasks (per-process state such as torch's
    thread count). ``workers``: tasks running at once (see each implementation for what it means there).
    """

    name: ClassVar[str]
    """The name ``--executor`` selects this executor by."""

    def __init__(
        self,
        *,
        workers: int = 1,
        setup: Callable | None = None,
        setup_args: tuple = (),
        max_retries: int = DEFAULT_MAX_RETRIES,
    ) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ConfigError(f"executor '{self.name}': workers must be a whole number >= 1, got {workers!r}")
        if isinstance(max_retries, bool) or not isinstance(max_retries, int) or max_retries < 0:
            raise ConfigError(f"executor '{self.name}': max_retries must be a whole number >= 0, got {max_retries!r}")
        self.workers, self.setup, self.setup_args, self.max_retries = workers, setup, tuple(setup_args), max_retries
        self._queue: list[tuple[int, Callable, tuple]] = []
        self._started = False
        self._results: Iterator[Done] | None = None

    def submit(self, fn: Callable, *args: Any) -> int:
        """Queue the call ``fn(*args)``; returns its ticket (0, 1, 2, ... in submission order)."""
        if self._started:
            raise RuntimeError(f"executor '{self.name}': submit every task before iterating as_completed()")
        self._queue.append((len(self._queue), fn, args))
        return len(self._queue) - 1

    def as_completed(self) -> Iterator[Done]:
        """One :class:`Done` per submitted call, in the order they finish (call once, after every submit)."""
        if self._started:
            raise RuntimeError(f"executor '{self.name}': as_completed() can be iterated once")
        self._started = True
        self._results = self._run(list(self._queue))
        return self._results

    @abstractmethod
    def _run(self, calls: list[tuple[int, Callable, tuple]]) -> Iterator[Done]:
        """Run ``calls`` ((ticket, fn, args), ...) and yield their outcomes as they finish; on close (a consumer
        that stops early) start no queued call."""

    def close(self) -> None:
        """Release the workers (idempotent). Calls not started are cancelled; running ones are waited for (local)
        or cancelled (Ray)."""
        if self._results is not None:
            self._results.close()  # runs the implementation's clean-up now, not when the generator is collected

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def lost(self, ticket: int, attempts: int, how: str) -> Done:
        """The outcome of a call given up after its worker died ``attempts`` times."""
        error = TaskLostError(
            f"task {ticket} was lost: its worker process died on each of {attempts} attempt(s) ({how}); "
            "it was not retried further (max_retries="
            f"{self.max_retries}). The worker may have been killed or run out of memory: check the machine's "
            "memory and logs, then run the same command again to resume the missing work"
        )
        return Done(ticket, error=error, attempts=attempts)
