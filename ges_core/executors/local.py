"""``--executor local`` (the default): a pool of spawned worker processes on this machine, or this process.

With ``workers == 1`` (or a single call) the calls run in this process, one after the other, as
``ges synth`` has always done; ``in_process=False`` forces a pool of one worker (the benchmark's
"1 worker, process pool" row). Otherwise a :class:`~concurrent.futures.ProcessPoolExecutor` with the
``spawn`` start method (fork would copy engine state: SAPIEN, PyBullet clients, torch threads) runs at most
``workers`` calls at a time.

A worker that dies (SIGKILL, out of memory, a crash in native code) breaks a process pool as a whole: every
call running then fails with ``BrokenProcessPool``, and the pool does not say whose worker died. At most
``workers`` calls are in flight, so only those are affected: the finished calls are kept, and the broken ones
are run again one at a time in a fresh pool, where a death names its call. A call whose worker dies alone is
rerun at most ``max_retries`` times, then reported lost; the calls that merely shared the broken pool are not
charged, and the rest of the queue goes on. A worker that dies between one result and the next submission makes
that ``submit`` raise ``BrokenProcessPool``: the call never ran, so it goes back to the queue uncharged for the next
pool (the running calls report the break as above). A call that dies in this process (``workers == 1``) ends the run,
as before. The workers die with the process that started them (:func:`ges_core.process_guard.die_with_parent`):
a killed ``ges synth --workers 2`` leaves no worker finishing its chunk.
"""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from ges_core.executors.base import Done, Executor, call_with_setup
from ges_core.process_guard import die_with_parent

__all__ = ["LocalExecutor"]

_Call = tuple[int, Callable, tuple]


class LocalExecutor(Executor):
    """Worker processes on this machine (``workers``: processes; 1 = this process unless ``in_process=False``)."""

    name = "local"

    def __init__(self, *, in_process: bool | None = None, **kwargs) -> None:
        super().__init__(**kwargs)
        self.in_process = in_process
        """None: this process when ``workers == 1`` or there is one call; True/False: always/never."""

    def _run(self, calls: list[_Call]) -> Iterator[Done]:
        in_process = self.in_process if self.in_process is not None else (self.workers == 1 or len(calls) <= 1)
        if in_process:
            return self._run_here(calls)
        return self._run_pool(calls)

    def _run_here(self, calls: list[_Call]) -> Iterator[Done]:
        if self.setup is not None:
            self.setup(*self.setup_args)
        for ticket, fn, args in calls:
            try:
                value = fn(*args)
            except Exception as exc:  # the caller decides; KeyboardInterrupt still stops the run at once
                yield Done(ticket, error=exc)
            else:
                yield Done(ticket, value)

    def _run_pool(self, calls: list[_Call]) -> Iterator[Done]:
        queue: deque[_Call] = deque(calls)
        suspects: deque[_Call] = deque()
        attempts = {ticket: 0 for ticket, _, _ in calls}
        deaths = dict.fromkeys(attempts, 0)
        while queue or suspects:
            broken: list[_Call] = []
            if not suspects:  # the normal case: up to `workers` calls at a time
                yield from self._one_pool(queue, self.workers, attempts, broken)
                suspects.extend(broken)
                continue
            yield from self._one_pool(suspects, 1, attempts, broken)  # alone: a death names its call
            for call in broken:
                deaths[call[0]] += 1
                if deaths[call[0]] > self.max_retries:
                    yield self.lost(call[0], attempts[call[0]], "a worker process of the pool died")
                else:
                    suspects.appendleft(call)

    def _one_pool(
        self, queue: deque[_Call], limit: int, attempts: dict[int, int], broken: list[_Call]
    ) -> Iterator[Done]:
        """Run ``queue`` in one pool, ``limit`` calls at a time, until it is empty or the pool breaks (the calls
        running then go to ``broken``)."""
        ctx = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(
            max_workers=min(limit, len(queue)), mp_context=ctx, initializer=die_with_parent, initargs=(os.getpid(),)
        )
        running: dict[Future, _Call] = {}
        refused = False  # the pool broke after the last wait: submit raises; the running calls report it
        try:
            while queue or running:
                while queue and len(running) < limit and not broken and not refused:
                    call = queue.popleft()
                    try:
                        future = pool.submit(call_with_setup, self.setup, self.setup_args, call[1], call[2])
                    except BrokenProcessPool:  # a worker died since the last wait; this call never ran
                        queue.appendleft(call)
                        refused = True
                        break
                    attempts[call[0]] += 1
                    running[future] = call
                if not running:  # refused with nothing running: the next pool takes the queue
                    return
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for future in finished:
                    call = running.pop(future)
                    error = future.exception()
                    if isinstance(error, BrokenProcessPool):
                        broken.append(call)
                    else:
                        yield Done(call[0], None if error else future.result(), error, attempts[call[0]])
                if (broken or refused) and not running:
                    return
        finally:  # stopped early or done: start nothing more; a stop waits for the running calls to end
            pool.shutdown(wait=True, cancel_futures=True)
