"""``--executor ray``: the calls run as Ray tasks, on an existing cluster (``--address``) or a local Ray instance.

* ``address`` given (``ray://head:10001``, ``head:6379`` or ``auto``): connect to that cluster; the tasks
  are spread over all its CPUs (one CPU per task), ``workers`` does not limit them. Every node needs the same
  ``ges-unigrasp`` install (and plugins) as this machine: a task names its function by module, it is not
  shipped by value.
* no address: start a Ray instance on this machine with ``workers`` CPUs (so ``workers`` tasks run at once),
  a small object store and no dashboard, and stop it again when the executor closes.
* Ray already started in this process (``ray.init`` by the caller, e.g. a test): use it, leave it running.

A task whose worker process dies is run again by Ray itself (``max_retries`` times, Ray's system-failure
retries; an exception the task raises is not retried: it is that task's outcome). Ray is an optional extra:
without it this module's executor fails with the pip command that installs it.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from typing import Any

from ges_core.errors import BackendUnavailable
from ges_core.executors.base import Done, Executor, call_with_setup

__all__ = ["OBJECT_STORE_BYTES", "RayExecutor", "import_ray"]

OBJECT_STORE_BYTES = 200 * 1024**2
"""Object store of a Ray instance started here. Ray's default is 30 % of RAM (7 GiB on a 24 GiB machine);
a Stage 1 task returns a few records of tens of kB, so 200 MiB holds thousands of results in flight
(Ray refuses less than 75 MiB)."""

INSTALL_HINT = "pip install 'ges-unigrasp[ray]'  (or: pip install ray)"


def import_ray() -> Any:
    """The ``ray`` module; BackendUnavailable with the install command when Ray is not installed."""
    try:
        import ray
    except ImportError as exc:
        raise BackendUnavailable(
            f"--executor ray needs Ray, which is not installed in this Python ({exc}); install it with: "
            f"{INSTALL_HINT}. Without Ray, use --executor local (the default: worker processes on this machine)"
        ) from None
    return ray


def _deaths(ray: Any) -> tuple[type, ...]:
    """Ray's errors for a task whose worker process or node died (killed, Ray's memory monitor, a crash)."""
    errors = ray.exceptions
    return (errors.WorkerCrashedError, errors.NodeDiedError, errors.OutOfMemoryError)


class RayExecutor(Executor):
    """Ray tasks on the cluster at ``address``, or on a Ray instance started here with ``workers`` CPUs."""

    name = "ray"

    def __init__(self, *, address: str | None = None, log_to_driver: bool = True, **kwargs) -> None:
        super().__init__(**kwargs)
        self.address = address
        self.log_to_driver = log_to_driver
        """Print the workers' output (warnings of a task) here, prefixed with the worker's pid."""
        self._ray: Any = None
        self._owns_ray = False
        self._pending: list = []

    def connect(self) -> None:
        """Connect to (or start) Ray; a no-op when this executor is connected or Ray runs in this process. Done on
        the first task (:meth:`as_completed`), so a run with nothing left to do starts no Ray."""
        if self._ray is not None:
            return
        ray = import_ray()
        if not ray.is_initialized():
            ray.init(**self._init_kwargs())
            self._owns_ray = True
        self._ray = ray

    def _init_kwargs(self) -> dict:
        common = {"log_to_driver": self.log_to_driver, "logging_level": logging.WARNING}
        if self.address is not None:  # a cluster's resources are its own: nothing to size here
            return {"address": self.address, **common}
        return {
            "num_cpus": self.workers,
            "object_store_memory": OBJECT_STORE_BYTES,
            "include_dashboard": False,
            **common,
        }

    def _run(self, calls: list[tuple[int, Callable, tuple]]) -> Iterator[Done]:
        if not calls:  # e.g. a fully resumed run: no Ray to start
            return
        self.connect()
        ray = self._ray
        remote = ray.remote(call_with_setup).options(
            num_cpus=1, max_retries=self.max_retries, retry_exceptions=False, name="ges-task"
        )
        tickets = {}
        for ticket, fn, args in calls:
            tickets[remote.remote(self.setup, self.setup_args, fn, args)] = ticket
        self._pending = list(tickets)
        try:
            while self._pending:
                ready, self._pending = ray.wait(self._pending, num_returns=1)
                yield self._outcome(ready[0], tickets[ready[0]])
        finally:
            self._cancel()

    def _outcome(self, ref: Any, ticket: int) -> Done:
        ray = self._ray
        try:
            return Done(ticket, ray.get(ref))
        except _deaths(ray) as exc:  # Ray ran it again max_retries times already
            return self.lost(ticket, self.max_retries + 1, type(exc).__name__)
        except ray.exceptions.RayTaskError as exc:  # the task raised: its own exception, as a local run gives it
            cause = exc.cause if isinstance(exc.cause, BaseException) else exc
            return Done(ticket, error=cause)
        except ray.exceptions.RayError as exc:
            return Done(ticket, error=exc)

    def _cancel(self) -> None:
        """Cancel the tasks not finished (a stopped run starts nothing more)."""
        for ref in self._pending:
            with contextlib.suppress(Exception):  # already finished or gone: nothing to cancel
                self._ray.cancel(ref)
        self._pending = []

    def close(self) -> None:
        """Cancel what is left and stop the Ray instance this executor started (a cluster is left running)."""
        super().close()
        if self._ray is None:
            return
        self._cancel()
        if self._owns_ray:
            self._ray.shutdown()
        self._ray, self._owns_ray = None, False
