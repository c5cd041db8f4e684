"""Evaluation cells run here or on an executor: one task per (object, expert run settings), results to the caller.

A cell is :func:`~ges_core.env.evaluate.runner.evaluate_object` of one record under one :class:`BaselineConfig`
(``ges env baseline``: one cell per object; ``ges eval-experts``: one per object and expert). With one worker
on the ``local`` executor the cells run in this process, in order, with the caller's registry object. Otherwise
each cell is a task of :mod:`ges_core.executors` (``local`` worker processes or ``ray``): the worker opens the
dataset and builds the registry from a :class:`~ges_core.synthesis.run.tasks.RegistrySpec` (a registry does not
pickle) once per process, and the row comes back to the caller, which alone writes the results file. A cell's row
depends on its record and settings only (a fresh simulator per cell), so every executor gives the same rows.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from ges_core.dataset import GraspRecord
from ges_core.dataset.hands import warn_if_hand_changed
from ges_core.env.evaluate.config import BaselineConfig
from ges_core.env.evaluate.runner import dataset_scene, evaluate_object
from ges_core.env.grasp_source import library_for, open_grasp_dataset
from ges_core.executors.base import TaskLostError
from ges_core.hand_prep.prepare import built_prepared

__all__ = ["Cell", "Fanout", "evaluate_cells"]


@dataclass(frozen=True)
class Cell:
    """One evaluation: the record of ``object_id`` (hand ``config.hand``) under ``config``."""

    object_id: str
    config: BaselineConfig


@dataclass(frozen=True)
class Fanout:
    """Where cells run: ``executor`` (local, ray), ``workers`` (processes; 1 on local = this process), ``address``
    (a Ray cluster), ``registry`` (how workers build the registry: a RegistrySpec; None: the default one)."""

    executor: str = "local"
    workers: int = 1
    address: str | None = None
    registry: Any = None

    @property
    def here(self) -> bool:
        """Cells run in this process, with the caller's registry."""
        return self.executor == "local" and self.workers == 1


def evaluate_cells(
    data, cells: Sequence[Cell], records: dict[str, GraspRecord], registry, fanout: Fanout
) -> Iterator[tuple[int, dict]]:
    """(index into ``cells``, row of :func:`evaluate_object`) per cell as each finishes.

    data: the opened grasp dataset (:func:`~ges_core.env.grasp_source.open_grasp_dataset`); workers reopen it
    from its folder.
    records: object id -> record (this process's selection). A cell whose worker died on every attempt is left
    out and, after every other row, raised as one TaskLostError naming its objects (a rerun resumes them).
    Each hand's deep hulls are decomposed first as ``ges synth`` does (:func:`~ges_core.hand_prep.prepare.
    built_prepared`), then a hand other than the dataset's (:func:`~ges_core.dataset.hands.warn_if_hand_changed`) is
    warned about.
    """
    hands = {name: built_prepared(registry, name) for name in sorted({c.config.hand for c in cells})}
    for name, hand in hands.items():
        warn_if_hand_changed(data.manifest, data.root, name, hand)
    if fanout.here:
        sources = _Sources(data, registry, hands)
        for i, cell in enumerate(cells):
            yield i, sources.evaluate(records[cell.object_id], cell.config)
        return
    from ges_core.executors import make_executor
    from ges_core.synthesis.run.tasks import RegistrySpec
    from ges_core.threads import resolve_threads, set_torch_threads

    spec = fanout.registry or RegistrySpec()
    options = {"workers": fanout.workers, "setup": set_torch_threads, "setup_args": (resolve_threads(None),)}
    lost = []
    with make_executor(fanout.executor, address=fanout.address, **options) as pool:
        for cell in cells:
            pool.submit(cell_task, str(data.root.resolve()), cell, spec)
        for done in pool.as_completed():
            if isinstance(done.error, TaskLostError):
                lost.append(cells[done.ticket].object_id)
                continue
            yield done.ticket, done.result()
    if lost:
        raise TaskLostError(
            f"{len(lost)} of {len(cells)} evaluation cells were lost (their worker died on every attempt): objects "
            f"{', '.join(sorted(set(lost)))}. Every other cell is written; run the same command again to resume"
        )


class _Sources:
    """What every cell of one dataset needs, built once: the dataset, its object library, hands and scenes."""

    def __init__(self, data, registry, hands: dict[str, Any] | None = None) -> None:
        """hands: hands already built (name -> HandModel; the caller's), the rest built on first use."""
        self.data, self.registry = data, registry
        self.library = library_for(self.data)
        self._hands: dict[str, Any] = dict(hands or {})
        self._scenes: dict[tuple, Any] = {}

    def evaluate(self, record: GraspRecord, c: BaselineConfig) -> dict:
        if c.hand not in self._hands:
            self._hands[c.hand] = self.registry.build_hand(c.hand)
        key = (c.envs, c.scene.model_dump_json() if c.scene else None)
        if key not in self._scenes:
            self._scenes[key] = dataset_scene(self.data, c.envs, c.scene)
        return evaluate_object(self.registry, self._hands[c.hand], record, self.library, c, self._scenes[key])


_WORKER: dict[tuple, _Sources] = {}
"""Per worker process: (dataset, registry spec) -> its sources; one run at a time."""


def cell_task(dataset: str, cell: Cell, spec) -> dict:
    """The task a worker runs: the dataset and registry opened once per process, then :func:`evaluate_object`."""
    key = (dataset, spec)
    if key not in _WORKER:
        _WORKER.clear()
        _WORKER[key] = _Sources(open_grasp_dataset(dataset), spec.load())
    sources = _WORKER[key]
    return sources.evaluate(sources.data.get(cell.object_id, cell.config.hand), cell.config)
