"""Executors: where the tasks of a command that fans out run (``--executor local|ray``, ``--address``).

``local`` (the default) is a pool of spawned worker processes on this machine (``--workers N``; 1 = this
process); ``ray`` runs the same tasks on a Ray cluster (``--address``) or on a Ray instance started here
(no ``--address``), installed with ``pip install 'ges-unigrasp[ray]'``. Both give the same results: a
task's result depends on its arguments only, and the caller alone writes them (docs/scale.md).

Using one (the pattern of :func:`ges_core.synthesis.run.pipeline.run_synthesis`)::

    from ges_core.executors import make_executor

    with make_executor("ray", workers=2, address=None, setup=set_torch_threads, setup_args=(1,)) as ex:
        tickets = {ex.submit(run_task, task, context): task for task in tasks}   # fn: module-level, args: picklable
        for done in ex.as_completed():        # one Done per task, as each finishes
            if done.ok:
                write(done.value)             # write each result at once (atomic), so a killed run resumes
            else:                             # done.error: what the task raised, or TaskLostError when its
                failed.append(tickets[done.ticket])   # worker died on every attempt (max_retries, default 3)

Rules for tasks: ``fn`` is importable by the workers (a module-level function of an installed module: a Ray
node imports it by name) and its arguments and return value are picklable; a task must not write the shared
output itself (results come back to the caller, which writes them), so a dying worker loses only its task.
``setup(*setup_args)`` runs in each worker before its tasks (e.g. torch's thread count).

On the command line: :func:`add_executor_options` adds ``--executor`` and ``--address`` to a parser and
:func:`executor_options` reads them back as keyword arguments of :func:`make_executor` (checked: ``--address``
needs ``--executor ray``).
"""

from __future__ import annotations

import argparse

from ges_core.errors import ConfigError, UnknownNameError
from ges_core.executors.base import DEFAULT_MAX_RETRIES, Done, Executor, TaskLostError, call_with_setup
from ges_core.executors.local import LocalExecutor

__all__ = [
    "DEFAULT_MAX_RETRIES",
    "EXECUTORS",
    "Done",
    "Executor",
    "LocalExecutor",
    "TaskLostError",
    "add_executor_options",
    "call_with_setup",
    "executor_options",
    "make_executor",
]

EXECUTORS: tuple[str, ...] = ("local", "ray")
"""The names ``--executor`` accepts."""


def make_executor(name: str = "local", *, address: str | None = None, **kwargs) -> Executor:
    """The executor called ``name`` (``local`` or ``ray``), built with ``kwargs`` (``workers``, ``setup``,
    ``setup_args``, ``max_retries``; ``local``: ``in_process``; ``ray``: ``log_to_driver``).

    ``address``: the Ray cluster to connect to (``ray`` only; None starts a local Ray instance).
    UnknownNameError for another name, ConfigError for an address given to ``local``."""
    if name == "local":
        if address is not None:
            raise ConfigError(
                f"--address {address} names a Ray cluster but the executor is 'local'; add --executor ray "
                "(or drop --address to run on this machine's worker processes)"
            )
        return LocalExecutor(**kwargs)
    if name == "ray":
        from ges_core.executors.ray_cluster import RayExecutor, import_ray

        import_ray()  # the install hint now, before any work
        return RayExecutor(address=address, **kwargs)
    raise UnknownNameError("executor", name, EXECUTORS)


def add_executor_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--executor {local,ray}`` (default local) and ``--address ADDR`` to ``parser``."""
    parser.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="where the tasks run: local worker processes (default) or Ray (pip install 'ges-unigrasp[ray]')",
    )
    parser.add_argument(
        "--address",
        metavar="ADDR",
        help="Ray cluster to run on (e.g. ray://head:10001 or auto; with --executor ray); "
        "without it --executor ray starts a Ray instance on this machine",
    )


def executor_options(args: argparse.Namespace) -> dict:
    """``{"executor": name, "address": addr}`` from the parsed ``--executor``/``--address`` (ConfigError when
    ``--address`` comes without ``--executor ray``)."""
    name, address = getattr(args, "executor", "local"), getattr(args, "address", None)
    if address is not None and name != "ray":
        raise ConfigError(f"--address {address} is the address of a Ray cluster: add --executor ray")
    return {"executor": name, "address": address}
