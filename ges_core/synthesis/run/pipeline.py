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
``workers`` or on the executor (:mod:`ges_core.executors`: local worker processes or Ray tasks, whose
records travel back to this process). The parent process alone writes the dataset (atomic, resumable:
stored (object, hand) pairs are skipped, unless their record no longer fits its object as the library builds it
now, :mod:`.resume`), each task's records as soon as that task finishes. It keeps each
hand's description and hash in the manifest and refuses to resume with a hand that changed
(:mod:`ges_core.dataset.hands`).
"""

from __future__ import annotations

import json
import logging
import uuid
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ges_core.config import absent_paths
from ges_core.dataset import DatasetWriter
from ges_core.errors import ConfigError
from ges_core.executors import DEFAULT_MAX_RETRIES, TaskLostError, make_executor
from ges_core.synthesis.retarget.wrist import check_handedness_fingers
from ges_core.synthesis.run.config import SynthesisConfig
from ges_core.synthesis.run.resume import set_aside_misfits
from ges_core.synthesis.run.tasks import (
    RegistrySpec,
    RunContext,
    Task,
    built_hands,
    check_plugin_names,
    hand_entries,
    plan_tasks,
)
from ges_core.synthesis.run.worker import run_task
from ges_core.threads import resolve_threads, set_torch_threads

if TYPE_CHECKING:
    from ges_core.hand import HandModel

__all__ = ["RunReport", "run_synthesis", "warn_shadowed_settings"]

_LOG = logging.getLogger(__name__)


@dataclass
class RunReport:
    """What a run did."""

    root: Path
    written: list[tuple[str, str]] = field(default_factory=list)
    """(object_id, hand) of the records written by this run."""
    skipped: list[tuple[str, str]] = field(default_factory=list)
    """Pairs already in the dataset (resume)."""
    recovered: list[str] = field(default_factory=list)
    """What opening the dataset repaired (see DatasetWriter.recovered), and the records set aside as stale."""
    redone: list[tuple[str, str]] = field(default_factory=list)
    """Stored pairs whose record no longer fit its object as the library builds it now (:mod:`.resume`): moved to
    the dataset's ``.damaged/`` folder and made again by this run."""


def warn_shadowed_settings(config: SynthesisConfig, hands: Mapping[str, HandModel]) -> list[str]:
    """Log (and return) a note per run setting a hand's own YAML settings replace for that hand
    (:meth:`SynthesisConfig.shadowed_by`): ``-o retarget.low_raise_height=0.01`` does not reach the Allegro, whose
    YAML sets 0.02, and without the note nothing says so."""
    notes = []
    for name, hand in hands.items():
        for key, ran, own in config.shadowed_by(name, hand.description.settings):
            value = json.dumps(ran)
            notes.append(
                f"hand '{name}' sets {key}={json.dumps(own)} in its own settings, over this run's {value}; "
                f"hand_settings.{name}.{key}={value} sets it for that hand (ges synth -o hand_settings.{name}.{key}="
                f"{value}; ges demo -o synthesis.hand_settings.{name}.{key}={value})"
            )
    for note in notes:
        _LOG.warning("ges: note: %s", note)
    return notes


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
    executor: str = "local",
    address: str | None = None,
    allow_config_change: bool = False,
) -> RunReport:
    """Synthesize and validate grasps of ``object_ids`` x ``hands``; write them to the dataset ``out``.

    workers: processes (1 = this process); with ``executor="ray"`` the CPUs of the Ray instance started here.
    executor: ``local`` (worker processes here) or ``ray`` (Ray tasks; ``address``: an existing cluster, None:
    a Ray instance started here and stopped after the run); the records are the same (docs/scale.md).
    Torch threads: ``config.threads``, else ``$GES_THREADS``, else 1, set in each worker process, or in this
    process when it runs the tasks itself (:mod:`ges_core.threads`).
    pictures: folder for one PNG per record (None: none).
    source: (dataset folder, hand): that hand's stored contacts replace contact generation (cross-hand
    retargeting); every object needs a record of that hand there. on_record: called with each record as it is written.
    allow_config_change: continue a dataset written with another run config (its records keep the hash of the
    config they were made with; the old config goes to the manifest's ``config_history``); else ConfigError.
    """
    _check_run(object_ids, hands, workers)
    make_executor(executor, address=address, workers=workers)  # a bad name, or Ray missing: before the folder exists
    # a bad $GES_THREADS fails here, before the dataset folder exists; resolved here, as a Ray cluster's
    # workers do not share this process's environment
    threads = resolve_threads(config.threads)
    registry = registry or RegistrySpec()
    check_plugin_names(hands, config, registry)  # before the dataset folder exists
    from ges_core.hand_prep.prepare import warn_undecomposed_hulls  # trimesh: imported when a run starts

    built = built_hands(hands, registry)
    for hand in built.values():  # a hand Stage 1 cannot place fails here, not in a worker after the folder exists
        check_handedness_fingers(hand.description)
    warn_undecomposed_hulls(built)  # `ges synth` / `ges demo` decomposed them before calling this
    warn_shadowed_settings(config, built)
    entries = hand_entries(built)  # a resumed dataset refuses hands that changed (docs/dataset.md)
    absent = absent_paths(type(config))  # settings a folder may predate: a refused resume names them
    with DatasetWriter(
        out, config.dump(), hands=entries, allow_config_change=allow_config_change, absent_means=absent
    ) as writer:
        report = RunReport(Path(out))
        report.redone = set_aside_misfits(writer, object_ids, hands, config.library.build())
        report.recovered = list(writer.recovered)
        tasks, report.skipped = plan_tasks(list(object_ids), list(hands), config.chunk_size, writer.has)
        context = RunContext(config, registry, str(pictures) if pictures else None, _source(source), uuid.uuid4().hex)
        bar = _progress_bar(sum(t.size for t in tasks), progress)
        results = _results(tasks, context, workers, threads=threads, executor=executor, address=address)
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
    tasks: list[Task],
    context: RunContext,
    workers: int,
    runner: Callable = run_task,
    threads: int | None = None,
    executor: str = "local",
    address: str | None = None,
    max_retries: int = DEFAULT_MAX_RETRIES,
) -> Generator[list, None, None]:
    """Records of each task as soon as it finishes, so that a slow task holds back no other task's records and
    a stopped run keeps every finished task. The dataset does not depend on this order: one file per
    (object, hand), and the manifest's index is sorted. ``runner``: a test double of :func:`run_task`
    (picklable: a module-level function). ``threads``: torch threads of the process(es) running the tasks
    (:func:`~ges_core.threads.set_torch_threads`). ``executor``/``address``: where the tasks run
    (:mod:`ges_core.executors`). A task whose worker died on every attempt (1 + ``max_retries``) is left out and,
    once every other task's records are yielded, raised as one TaskLostError naming its objects (a rerun resumes
    them)."""
    lost: list[Task] = []
    options = {"workers": workers, "setup": set_torch_threads, "setup_args": (threads,), "max_retries": max_retries}
    with make_executor(executor, address=address, **options) as pool:
        for task in tasks:
            pool.submit(runner, task, context)
        for done in pool.as_completed():
            if isinstance(done.error, TaskLostError):
                lost.append(tasks[done.ticket])
                continue
            yield done.result()  # a task that raised stops the run, as before (its records were not written)
    if lost:
        raise _lost_error(lost, len(tasks))


def _lost_error(lost: list[Task], total: int) -> TaskLostError:
    pairs = [f"{oid} ({', '.join(hands)})" for task in lost for oid, hands in getattr(task, "pairs", ())]
    return TaskLostError(
        f"{len(lost)} of {total} synthesis tasks were lost: their worker process died on every attempt "
        f"(killed, out of memory or a crash in native code); objects not written: {', '.join(pairs) or '?'}. "
        "Every other task's records are written; run the same command again to resume the missing ones"
    )


def _progress_bar(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, disable=not enabled, unit="grasp", desc="synthesis", dynamic_ncols=True)
