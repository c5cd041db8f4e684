"""Evaluate an expert plugin on Stage 1 grasps: per object one :class:`GraspEnv`, one episode per env.

>>> config = BaselineConfig(hand="allegro", sim="sapien", envs=2, selection="refined")
>>> report = evaluate_baseline("runs/demo/dataset", config, "runs/demo/baseline")
>>> print(report.table())

Per selected record (:mod:`ges_core.env.grasp_source`): the object's rest pose in ``sim``, a fresh
``sim`` with ``envs`` scenes (objects never share a scene: a reused scene carries the previous object's
history, see ``ges_core/synthesis/run/worker.py``), ``GraspEnv`` + ``GraspVecEnv`` (full reset: stage
one reaching to the pre-grasp), then the expert (``config.expert`` built by the registry for that env,
:mod:`ges_core.policy`) acts until every env has ended one episode. Recorded
per object: each env's end reason, whether the paper's protocol (0.2 m up, held 200 simulation steps)
and the peers' protocol (within 5 cm of the lift target at some step) succeeded, the highest rise.

Results: ``<out>/baseline-<hand>-<sim>.json``, rewritten atomically after every object. A rerun with the
same settings reuses every stored object whose grasp is unchanged (a killed run resumes where it
stopped); other settings raise ConfigError. Without randomization every env of one object runs the
same physics, so ``envs > 1`` only repeats the episode (a determinism check), see ``docs/env_baseline.md``.

One job per module:

* :mod:`~ges_core.env.evaluate.config`: :class:`BaselineConfig` (the expert by registry name, with its settings);
* :mod:`~ges_core.env.evaluate.runner`: the episodes (:func:`evaluate_baseline`, :func:`evaluate_object`,
  :func:`run_episodes`); ``ges eval-experts`` (:mod:`ges_core.experts.evaluate`) runs :func:`evaluate_object`
  per object and expert;
* :mod:`~ges_core.env.evaluate.fanout`: where objects run (:class:`Fanout`: here, local worker processes, Ray);
* :mod:`~ges_core.env.evaluate.store`: the resumable results file (:func:`results_path`, :func:`grasp_key`);
* :mod:`~ges_core.env.evaluate.table`: the per-split summary (:func:`summarize`, :func:`format_table`).
"""

from __future__ import annotations

from ges_core.env.evaluate.config import BaselineConfig
from ges_core.env.evaluate.fanout import Cell, Fanout, evaluate_cells
from ges_core.env.evaluate.runner import (
    BaselineReport,
    EpisodeOutcome,
    build_expert_for,
    config_records,
    dataset_scene,
    evaluate_baseline,
    evaluate_object,
    expert_defaults,
    run_episodes,
)
from ges_core.env.evaluate.store import RESULTS_FORMAT, RESULTS_VERSION, grasp_key, results_path
from ges_core.env.evaluate.table import REASONS, SplitRow, format_table, summarize

__all__ = [
    "REASONS",
    "RESULTS_FORMAT",
    "RESULTS_VERSION",
    "BaselineConfig",
    "BaselineReport",
    "Cell",
    "EpisodeOutcome",
    "Fanout",
    "SplitRow",
    "build_expert_for",
    "config_records",
    "dataset_scene",
    "evaluate_baseline",
    "evaluate_cells",
    "evaluate_object",
    "format_table",
    "grasp_key",
    "results_path",
    "expert_defaults",
    "run_episodes",
    "summarize",
]
