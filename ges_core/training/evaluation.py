"""Evaluation during training: the policy of a checkpoint, without action noise, on the run's objects.

The training episodes show the policy with PPO's action noise, and their success is what the curriculum's default
rule and the run's curves read. What an expert is used with (``ges eval-experts``, ``ges evaluate``) is the noise-free
policy, and the two can differ: the residual experts of stop 43 kept a flat training success of 79-86 % while the
noise-free policy gained. Before the first iteration (the starting policy: a residual's base expert, a warm
start's cloned actor) and every ``evaluation.interval`` iterations :class:`InRunEvaluator` runs a checkpoint of the
current weights exactly as ``ges eval-experts`` runs a column: the registry's ``ppo`` expert built from that file,
one fresh simulator per object, :func:`~ges_core.env.evaluate.evaluate_object`, ``evaluation.episodes`` envs, the
run's env settings (randomization included) seeded with ``evaluation.seed``. So an evaluation's figure for an
object is the cell ``ges eval-experts`` writes for that checkpoint with the same seed and episodes.

It runs in the training process between two iterations, on its own simulators and with torch's random state put
back afterwards: the training trajectories are those of a run without it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import torch

__all__ = ["EvaluationResult", "InRunEvaluator", "describe_evaluation"]


@dataclass
class EvaluationResult:
    """One evaluation: per object [episodes, paper successes, peers successes]."""

    iteration: int
    """Iterations done when it ran (the weights after that many updates)."""
    per_object: dict[str, list[int]]
    max_rise: dict[str, list[float]] = field(default_factory=dict)
    """object id -> per episode the highest rise of the object above its start, m (how near a failure came)."""
    seconds: float = 0.0
    errors: dict[str, str] = field(default_factory=dict)
    """object id -> the error that ended its episodes (they count as failures)."""

    def rate(self, objects: Sequence[str] | None = None, protocol: str = "paper") -> float:
        """Success rate over ``objects`` (None: all evaluated) under ``protocol``; NaN when none of them ran."""
        col = 1 if protocol == "paper" else 2
        rows = [self.per_object[o] for o in (self.per_object if objects is None else objects) if o in self.per_object]
        episodes = sum(r[0] for r in rows)
        return sum(r[col] for r in rows) / episodes if episodes else math.nan

    def episodes(self, objects: Sequence[str] | None = None) -> int:
        return sum(r[0] for o, r in self.per_object.items() if objects is None or o in objects)

    def against(self, start: dict[str, list[int]]) -> dict:
        """This evaluation against the starting policy's per-object rows ``start`` (iteration 0's ``per_object``),
        on the objects both ran: paper-protocol points (percentage points of success) and objects up / down."""
        common = [o for o in self.per_object if o in start]
        now, then = self.rate(common), EvaluationResult(0, start).rate(common)
        up = sum(self.per_object[o][1] * start[o][0] > start[o][1] * self.per_object[o][0] for o in common)
        down = sum(self.per_object[o][1] * start[o][0] < start[o][1] * self.per_object[o][0] for o in common)
        points = None if math.isnan(now) or math.isnan(then) else round(100 * (now - then), 2)
        return {"points": points, "objects_up": up, "objects_down": down}

    def to_row(self) -> dict:
        """One line of ``evaluations.jsonl``."""
        return {
            "iteration": self.iteration, "success_paper": _num(self.rate()),
            "success_peers": _num(self.rate(None, "peers")), "episodes": self.episodes(), "per_object": self.per_object,
            "max_rise": self.max_rise, "errors": self.errors, "seconds": round(self.seconds, 2),
        }  # fmt: skip


class InRunEvaluator:
    """Runs a checkpoint on a fixed set of training objects (module docs)."""

    def __init__(self, registry, hand, records: Sequence, library, config, scene) -> None:
        """hand: the run's HandModel; records: one GraspRecord per object (the pool's); config: the
        :class:`~ges_core.env.evaluate.BaselineConfig` of every cell but the checkpoint; scene: its SceneConfig."""
        self.registry, self.hand, self.library, self.config, self.scene = registry, hand, library, config, scene
        self.records = {r.object_id: r for r in records}
        self.on_object: Callable[[int, int], None] | None = None
        """Called after each object with (objects done, objects): the training's progress bar."""

    @classmethod
    def for_run(cls, cfg, setup, registry) -> InRunEvaluator:
        """The evaluator of a training run: the pool's records of every object of its curriculum,
        ``cfg.evaluation``'s episodes and seed, the run's env settings and physics (all from the run's
        :class:`~ges_core.training.envs.TrainingSetup`)."""
        from ges_core.env.evaluate import BaselineConfig
        from ges_core.training.envs import env_config

        e = cfg.evaluation
        wanted = set(setup.curriculum.all_objects())
        records = [r for r in setup.grasps.records if r.object_id in wanted]
        env = env_config(cfg)
        env = env.model_copy(update={"randomization": env.randomization.model_copy(update={"seed": e.seed})})
        config = BaselineConfig(hand=setup.hand, sim=setup.sim, envs=e.episodes, selection=cfg.selection, seed=e.seed,
                                env=env, expert="ppo")  # fmt: skip
        scene = setup.scene.model_copy(update={"num_envs": e.episodes})
        return cls(registry, setup.hand_model, records, setup.library, config, scene)

    @property
    def objects(self) -> list[str]:
        return list(self.records)

    def evaluate(self, checkpoint: str | Path, iteration: int) -> EvaluationResult:
        """Every object's episodes with the policy of ``checkpoint``; torch's random state is restored after."""
        from ges_core.env.evaluate.runner import evaluate_object

        start = time.perf_counter()
        config = self.config.model_copy(update={"expert_settings": {"checkpoint": str(checkpoint)}})
        result = EvaluationResult(iteration, {})
        with torch.random.fork_rng(devices=[]):
            for object_id, record in self.records.items():
                row = evaluate_object(self.registry, self.hand, record, self.library, config, self.scene)
                result.per_object[object_id] = [row["envs"], row["paper_success"], row["peers_success"]]
                result.max_rise[object_id] = row["max_rise"]
                if "error" in row:
                    result.errors[object_id] = row["error"]
                if self.on_object is not None:
                    self.on_object(len(result.per_object), len(self.records))
        result.seconds = time.perf_counter() - start
        return result


def describe_evaluation(row: dict, objects: int, episodes: int) -> str:
    """One line for the terminal from an ``evaluations.jsonl`` row."""

    def pct(x):
        return "-" if x is None else f"{100 * x:.1f} %"

    vs = row.get("vs_start")
    against = (
        f"; against the start {vs['points']:+.1f} points ({vs['objects_up']} object(s) up, {vs['objects_down']} down)"
        if vs and vs["points"] is not None
        else ""
    )
    return (
        f"iteration {row['iteration']}: evaluation {pct(row['success_paper'])} (paper), {pct(row['success_peers'])} "
        f"(peers) over {objects} object(s) x {episodes} noise-free episode(s); stage {row['stage']}'s objects "
        f"{pct(row['stage_success_paper'])}{against}; {row['seconds']:.0f} s"
        + (" (best so far)" if row["best"] else "")
    )


def _num(value: float) -> float | None:
    return None if math.isnan(value) else round(float(value), 4)
