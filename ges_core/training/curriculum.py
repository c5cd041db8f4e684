"""The paper's three-stage curriculum per expert, as pool weights over the training objects.

Stages (``CurriculumConfig.stages``, default 1, 2, 3):

1. **intra-cluster central**: the cluster's objects nearest its centre in the standardized shape-feature space
   (``centre_fraction`` of them, at least one; ``Clusters.central``);
2. **intra-cluster expansion**: every object of the cluster;
3. **inter-cluster generalization**: every training object.

The hard-case expert runs stages 1-2 on a given object set (``objects``): its "centre" is the mean of those
objects' standardized features. Only objects with a usable Stage 1 grasp take part (``available``).

Promotion: once the stage has seen ``window`` episodes and their success rate (``protocol``) reaches
``promote_success``, or after ``max_iterations`` iterations in the stage, whichever comes first. With
``promote_on: evaluation`` the rate is the stage's objects' success in the latest in-run evaluation of the stage
(:meth:`Curriculum.record_evaluation`; the noise-free policy, :mod:`ges_core.training.evaluation`) instead.
The last stage is never left. Each promotion is returned as a :class:`Promotion` (the runner logs it) and kept
in :attr:`history`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from ges_core.errors import AssetError, ConfigError
from ges_core.training.config import CurriculumConfig

__all__ = ["SET_STAGE_NAMES", "STAGE_NAMES", "Curriculum", "Promotion"]

STAGE_NAMES = {1: "cluster centre", 2: "whole cluster", 3: "all training objects"}
SET_STAGE_NAMES = {1: "centre of the set", 2: "whole set", 3: "whole set"}
"""Stage names of an expert trained on a given object set (the hard-case expert): it has no cluster."""


@dataclass(frozen=True)
class Promotion:
    """One stage change: from stage to stage, at which iteration, why, and the rate that was seen."""

    iteration: int
    from_stage: int
    to_stage: int
    reason: str
    """'success' (the training episodes' rate reached the threshold), 'evaluation' (the in-run evaluation's did)
    or 'iteration_cap'."""
    success_rate: float
    """Success rate the rule read when it happened (NaN: no episode ended in the stage / no evaluation yet)."""
    episodes: int
    """Episodes that rate is over (the window's, or the evaluation's on the stage's objects)."""
    stage_name: str = ""
    """What the new stage trains on (empty in records written before it was stored: STAGE_NAMES then)."""

    def describe(self) -> str:
        rate = "no episode" if math.isnan(self.success_rate) else f"success {self.success_rate:.2f}"
        name = self.stage_name or STAGE_NAMES[self.to_stage]
        over = (f"in the evaluation's {self.episodes} noise-free episode(s)" if self.reason == "evaluation"
                else f"over the last {self.episodes} episode(s)")  # fmt: skip
        return (
            f"iteration {self.iteration}: curriculum stage {self.from_stage} -> {self.to_stage} "
            f"({name}), {self.reason}: {rate} {over}"
        )


class Curriculum:
    """Stage objects, the success window and the promotion rule (module docs)."""

    def __init__(
        self, cfg: CurriculumConfig, stage_objects: dict[int, list[str]], names: dict[int, str] | None = None
    ) -> None:
        """stage_objects: stage number -> object ids of that stage (each non-empty). names: stage number -> what
        it trains on, for the log (default :data:`STAGE_NAMES`)."""
        empty = [s for s in cfg.stages if not stage_objects.get(s)]
        if empty:
            raise AssetError(f"curriculum stage(s) {empty} have no object with a usable grasp")
        self.cfg = cfg
        self.stages = list(cfg.stages) if cfg.enabled else [cfg.stages[-1]]
        self.stage_objects = {s: list(stage_objects[s]) for s in self.stages}
        self.index = 0
        self.iterations_in_stage = 0
        self.window: deque[bool] = deque(maxlen=cfg.window)
        self.episodes_in_stage = 0
        self.history: list[Promotion] = []
        self.names = dict(names or STAGE_NAMES)
        self.evaluation: tuple[float, int] | None = None
        """The latest in-run evaluation of the current stage: (success rate on its objects, episodes)."""

    @classmethod
    def for_cluster(
        cls,
        cfg: CurriculumConfig,
        clusters,
        cluster: int,
        available: Sequence[str],
        *,
        objects: Sequence[str] | None = None,
    ) -> Curriculum:
        """The stages of expert ``cluster`` from a :class:`~ges_core.clustering.Clusters`, over the training
        objects in ``available`` (those with a usable grasp). ``objects``: a given set instead of the cluster
        (the hard-case expert; stage 3 is then the same set). AssetError when the cluster has no usable object."""
        usable = set(available)
        if objects is not None:
            group = [o for o in _by_distance(clusters, objects) if o in usable]
            where = f"the given object set ({len(objects)} ids)"
        else:
            group = [o for o in clusters.members(cluster, split="train") if o in usable]
            where = f"cluster {cluster} ({len(clusters.members(cluster, split='train'))} training objects)"
        if not group:
            raise AssetError(
                f"{where} holds no training object with a usable Stage 1 grasp among the {len(usable)} selected; "
                "run Stage 1 on more of its objects, pick another --cluster, or relax the grasp selection "
                "(-o selection=refined)"
            )
        centre = group[: max(1, math.ceil(cfg.centre_fraction * len(group)))]
        everything = [o for o in available if o in usable] if objects is None else group
        return cls(cfg, {1: centre, 2: group, 3: everything}, None if objects is None else SET_STAGE_NAMES)

    @property
    def stage(self) -> int:
        """The current stage number (1, 2 or 3)."""
        return self.stages[self.index]

    def objects(self) -> list[str]:
        """Object ids of the current stage."""
        return self.stage_objects[self.stage]

    def all_objects(self) -> list[str]:
        """Every object of any stage, sorted (what the in-run evaluation runs on)."""
        return sorted({o for objects in self.stage_objects.values() for o in objects})

    def weights(self) -> dict[str, float]:
        """Pool weights: 1 for each object of the current stage (objects left out get 0)."""
        return dict.fromkeys(self.objects(), 1.0)

    def record(self, successes: Sequence[bool]) -> None:
        """Outcomes of episodes that ended (True: a success under ``protocol``)."""
        self.window.extend(bool(s) for s in successes)
        self.episodes_in_stage += len(successes)

    def record_evaluation(self, rate: float, episodes: int) -> None:
        """The in-run evaluation's success rate on the current stage's objects (read with ``promote_on:
        evaluation``; kept until the next evaluation or promotion)."""
        self.evaluation = (float(rate), int(episodes))

    def success_rate(self) -> float:
        """Success rate over the window (NaN before any episode ended in the stage)."""
        return float(np.mean(self.window)) if self.window else math.nan

    def end_iteration(self, iteration: int) -> Promotion | None:
        """Count one iteration; promote (and return the Promotion) when the rule says so."""
        self.iterations_in_stage += 1
        if self.index == len(self.stages) - 1:
            return None
        if self.cfg.promote_on == "evaluation":
            rate, seen = self.evaluation if self.evaluation is not None else (math.nan, 0)
            reached = seen > 0 and rate >= self.cfg.promote_success
        else:
            rate, seen = self.success_rate(), len(self.window)
            reached = seen >= self.cfg.window and rate >= self.cfg.promote_success
        if reached:
            reason = "evaluation" if self.cfg.promote_on == "evaluation" else "success"
        elif self.iterations_in_stage >= self.cfg.max_iterations:
            reason = "iteration_cap"
        else:
            return None
        to = self.stages[self.index + 1]
        promotion = Promotion(iteration, self.stage, to, reason, rate, seen, self.names[to])
        self.index += 1
        self.iterations_in_stage, self.episodes_in_stage = 0, 0
        self.window.clear()
        self.evaluation = None
        self.history.append(promotion)
        return promotion

    def state_dict(self) -> dict:
        """What a checkpoint keeps to resume the curriculum where it was."""
        return {
            "index": self.index,
            "iterations_in_stage": self.iterations_in_stage,
            "episodes_in_stage": self.episodes_in_stage,
            "window": list(self.window),
            "history": [asdict(p) for p in self.history],
            "stage_objects": {str(k): v for k, v in self.stage_objects.items()},
            "evaluation": None if self.evaluation is None else list(self.evaluation),
        }

    def load_state_dict(self, state: dict) -> None:
        """Resume from :meth:`state_dict`; ConfigError if the checkpoint's stages hold other objects."""
        saved = {int(k): v for k, v in state["stage_objects"].items()}
        if saved != self.stage_objects:
            raise ConfigError(
                "the checkpoint's curriculum stages hold other objects than this run's (the dataset, the clusters "
                "or the selection changed); start a new run folder instead of --resume"
            )
        self.index, self.iterations_in_stage = int(state["index"]), int(state["iterations_in_stage"])
        self.episodes_in_stage = int(state["episodes_in_stage"])
        self.window.clear()
        self.window.extend(bool(s) for s in state["window"])
        self.history = [Promotion(**p) for p in state["history"]]
        evaluation = state.get("evaluation")  # absent in checkpoints written before in-run evaluations
        self.evaluation = None if evaluation is None else (float(evaluation[0]), int(evaluation[1]))


def _by_distance(clusters, objects: Sequence[str]) -> list[str]:
    """``objects`` sorted by the distance of their standardized features to the set's mean (ties by id)."""
    missing = [o for o in objects if o not in clusters.objects]
    if missing:
        raise ConfigError(f"objects {missing} are not in the clustering; run 'ges cluster' on their dataset")
    feats = np.stack([clusters.standardize(clusters.objects[o].features) for o in objects])
    dist = np.linalg.norm(feats - feats.mean(axis=0), axis=1)
    return [o for _, o in sorted(zip(dist.tolist(), objects, strict=True))]
