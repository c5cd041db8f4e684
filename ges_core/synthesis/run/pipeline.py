"""The Stage 1 pipeline: objects x hands -> contacts -> retargeting -> refinement -> pre-grasp -> validation -> dataset.

>>> config = SynthesisConfig(refine_sim="sapien", validate_sims=("sapien",))
>>> report = run_synthesis(["procedural/can/000", "procedural/box/000"], ["allegro"], config, "runs/mine")
>>> report.written, report.skipped

Per object (one seed per object, derived from ``(seed, object_id)``, never from the order):
point cloud (``points`` samples) -> five contacts (shared by every hand with the same contact settings). Each
hand's steps run with :meth:`SynthesisConfig.for_hand` (the run config < the hand YAML's ``settings`` <
``hand_settings[hand]``, :mod:`ges_core.hand_settings`). Per hand: the contact sets of
a whole chunk of objects are retargeted as one batch (batched solves are much cheaper per grasp;
each grasp's solution does not depend on its batch mates, see ``tests/test_synthesis_pipeline.py``),
then per object: refinement in ``refine_sim``, pre-grasp, validation in every ``validate_sims``
simulator, one :class:`~ges_core.dataset.GraspRecord`. A ``SynthesisError``, ``SimulationError`` or
``AssetError`` of one object becomes that record's failed step with its reason and the run goes on.

Objects are cut into fixed chunks of ``chunk_size`` (in the order given) whatever the number of
workers; each (object, hand) gets fresh simulators (a reused scene carries the previous object's
history, see :mod:`.worker`), so a record does not depend on its chunk mates, on resuming or on
``workers``. The parent process alone writes the dataset (atomic, resumable:
stored (object, hand) pairs are skipped), each task's records as soon as that task finishes. It keeps each
hand's description and hash in the manifest and refuses to resume with a hand that changed
(:mod:`ges_core.dataset.hands`).
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Generator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

from ges_core.dataset import DatasetWriter
from ges_core.errors import ConfigError
from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.run.tasks import (
    RegistrySpec,
    RunContext,
    Task,
    check_plugin_names,
    hand_entries,
    plan_tasks,
)
from ges_core.synthesis.run.worker import run_task
from ges_core.threads import resolve_threads, set_torch_threads

__all__ = ["RunReport", "run_synthesis"]


@dataclass
class RunReport:
    """What a run did."""

    root: Path
    written: list[tuple[str, str]] = field(default_factory=list)
    """(object_id, hand) of the records written by this run."""
    skipped: list[tuple[str, str]] = field(default_factory=list)
    """Pairs already in the dataset (resume)."""
    recovered: list[str] = field(default_factory=list)
    """What opening the dataset repaired (see DatasetWriter.recovered)."""


def run_synthesis(
    object_ids: Sequence[str],
    hands: Sequence[str],
    config: SynthesisConfig,
    out: str | Path,
    *,
    workers: int = 1,
    progress: bool = False,
    registry: RegistrySpec | None = None,
    pictures: str | Path | None = None,
    source: tuple[str, str] | None = None,
    on_record: Callable | None = None,
) -> RunReport:
    """Synthesize and validate grasps of ``object_ids`` x ``hands``; write them to the dataset ``out``.

    workers: processes (1 = this process). Torch threads: ``config.threads``, else ``$GES_THREADS``, else 1, set in
    each worker process, or in this process when it runs the tasks itself (:mod:`ges_core.threads`).
    pictures: folder for one PNG per record (None: none).
    source: (dataset folder, hand): that hand's stored contacts replace contact generation (cross-hand
    retargeting); every object needs a record of that hand there. on_record: called with each record as it is written.
    """
    _check_run(object_ids, hands, workers)
    resolve_threads(config.threads)  # a bad $GES_THREADS fails here, before the dataset folder exists
    registry = registry or RegistrySpec()
    check_plugin_names(hands, config, registry)  # before the dataset folder exists
    entries = hand_entries(hands, registry)  # a resumed dataset refuses hands that changed (docs/dataset.md)
    with DatasetWriter(out, config.dump(), hands=entries) as writer:
        report = RunReport(Path(out), recovered=list(writer.recovered))
        tasks, report.skipped = plan_tasks(list(object_ids), list(hands), config.chunk_size, writer.has)
        context = RunContext(config, registry, str(pictures) if pictures else None, _source(source))
        bar = _progress_bar(sum(t.size for t in tasks), progress)
        results = _results(tasks, context, workers, threads=config.threads)
        try:
            for records in results:
                for record in records:
                    writer.add(record)
                    report.written.append(record.key)
                    if on_record is not None:
                        on_record(record)
                bar.update(len(records))
        finally:
            results.close()  # a stopped run cancels the queued tasks now, not when the generator is collected
            bar.close()
    return report


def _source(source: tuple[str, str] | None) -> tuple[str, str] | None:
    return None if source is None else (str(source[0]), str(source[1]))


def _check_run(object_ids: Sequence[str], hands: Sequence[str], workers: int) -> None:
    problems = []
    if not object_ids:
        problems.append("no objects given")
    if not hands:
        problems.append("no hands given")
    if len(set(object_ids)) != len(object_ids):
        problems.append("an object is listed twice")
    if workers < 1:
        problems.append(f"workers must be >= 1, got {workers}")
    if problems:
        raise ConfigError("cannot start the synthesis run: " + "; ".join(problems), problems=problems)


def _results(
    tasks: list[Task], context: RunContext, workers: int, runner: Callable = run_task, threads: int | None = None
) -> Generator[list, None, None]:
    """Records of each task as soon as it finishes, so that a slow task holds back no other task's records and
    a stopped run keeps every finished task. The dataset does not depend on this order: one file per
    (object, hand), and the manifest's index is sorted. ``runner``: a test double of :func:`run_task`
    (picklable: a module-level function). ``threads``: torch threads of the process(es) running the tasks
    (:func:`~ges_core.threads.set_torch_threads`)."""
    if workers == 1 or len(tasks) <= 1:
        set_torch_threads(threads)  # this process does the torch work (ges_core.threads: why one by default)
        for task in tasks:
            yield runner(task, context)
        return
    ctx = multiprocessing.get_context("spawn")  # fork would copy engine state (SAPIEN, PyBullet clients, torch threads)
    pool = ProcessPoolExecutor(
        max_workers=min(workers, len(tasks)), mp_context=ctx, initializer=set_torch_threads, initargs=(threads,)
    )
    with pool:
        futures = [pool.submit(runner, task, context) for task in tasks]
        try:
            for future in as_completed(futures):
                yield future.result()
        except BaseException:  # stopped (Ctrl-C, a failing write): start no queued task
            pool.shutdown(wait=False, cancel_futures=True)
            raise


def _progress_bar(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, disable=not enabled, unit="grasp", desc="synthesis", dynamic_ncols=True)
