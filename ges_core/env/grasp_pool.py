"""A weighted pool of (object, Stage 1 grasp) pairs from which a multi-object :class:`GraspEnv` draws episodes.

Each env of a pool-built environment (:meth:`GraspEnv.from_pool`) holds its own object and its own grasp; when
its episode starts it draws its next entry with probability proportional to the entry's weight (the curriculum
sets the weights: :mod:`ges_core.training.curriculum`). Entries keep their grasps in the **object frame** (the
object's resting frame, as the dataset stores them): the environment maps them to the world through the pose
the object actually rests at after ``load_object`` in that env, as :func:`~ges_core.env.grasp_source.grasp_targets`
does for one object.

    dataset = open_grasp_dataset("runs/demo/dataset")
    pool = GraspPool.from_selection(select_records(dataset, "allegro", split="train"), hand, library_for(dataset))
    env = GraspEnv.from_pool(sim, hand, pool, EnvConfig())
    pool.set_weights({"procedural/box/000": 1.0})      # only that object from the next episode on
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ges_core.errors import AssetError, ConfigError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset

__all__ = ["GraspPool", "PoolEntry"]


@dataclass(frozen=True)
class PoolEntry:
    """One object and one grasp of it; poses (7,) in the object's resting frame (m, wxyz), joints (K,) rad."""

    asset: ObjectAsset
    wrist_pose: np.ndarray
    """(7,) base-link pose of the grasp g, object frame."""
    q: np.ndarray
    """(K,) goal joint angles, hand joint_names order."""
    pre_wrist_pose: np.ndarray
    """(7,) base-link pose of the pre-grasp g_init, object frame."""
    pre_q: np.ndarray
    """(K,) pre-grasp joint angles."""

    @property
    def key(self) -> str:
        """The object id (the curriculum's and the logs' name for this entry)."""
        return self.asset.object_id


class GraspPool:
    """Entries and their draw weights (>= 0, not all 0); draws are i.i.d. with probability weight / sum."""

    def __init__(self, entries: Sequence[PoolEntry], weights: Sequence[float] | None = None) -> None:
        if not entries:
            raise AssetError("GraspPool: no entries; select at least one object with a usable Stage 1 grasp")
        self.entries = tuple(entries)
        self.keys = tuple(e.key for e in self.entries)
        self._index = {}
        for i, key in enumerate(self.keys):
            self._index.setdefault(key, []).append(i)
        self.weights = np.ones(len(self.entries))
        """(E,) float64 draw weights, entry order."""
        if weights is not None:
            self.set_weights(weights)

    def __len__(self) -> int:
        return len(self.entries)

    def set_weights(self, weights: Sequence[float] | Mapping[str, float] | np.ndarray) -> None:
        """New draw weights: one per entry (entry order), or object id -> weight (ids left out get 0; an id
        shared by several entries gives each that weight). ConfigError on a negative, non-finite or unknown one,
        or when every weight is 0."""
        if isinstance(weights, Mapping):
            unknown = sorted(set(weights) - set(self._index))
            if unknown:
                raise ConfigError(f"GraspPool.set_weights: no entry for object(s) {unknown}; it holds {self.keys}")
            w = np.zeros(len(self.entries))
            for key, value in weights.items():
                w[self._index[key]] = value
        else:
            w = np.asarray(weights, dtype=np.float64)
            if w.shape != (len(self.entries),):
                raise ConfigError(
                    f"GraspPool.set_weights: {w.shape} weights for {len(self.entries)} entries; give one per entry"
                )
        if not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise ConfigError(f"GraspPool.set_weights: weights must be finite, >= 0 and not all 0, got {w.tolist()}")
        self.weights = w

    def probabilities(self) -> np.ndarray:
        """(E,) draw probabilities (weights / their sum)."""
        return self.weights / self.weights.sum()

    def draw(self, rng: np.random.Generator, m: int) -> np.ndarray:
        """(m,) int64 entry indices drawn independently with :meth:`probabilities`."""
        return rng.choice(len(self.entries), size=m, p=self.probabilities()).astype(np.int64)

    @classmethod
    def from_selection(cls, selection, hand: HandModel, library) -> GraspPool:
        """One entry per record of a :class:`~ges_core.env.grasp_source.GraspSelection` (its objects from
        ``library``, an ObjectLibrary, checked by :func:`~ges_core.env.grasp_source.record_asset`), grasps mapped to
        ``hand``'s joint order. AssetError if it is empty or a record does not fit its object."""
        from ges_core.env.grasp_source import grasp_targets, record_asset

        if not selection.records:
            raise AssetError(
                f"no usable Stage 1 grasp of hand '{selection.hand}' under selection '{selection.selection}' "
                f"({len(selection.rejected)} record(s) left out); run Stage 1 on more objects or pick another selection"
            )
        entries = []
        for record in selection.records:
            t = grasp_targets(record, hand.description, 1)  # object frame: no object pose given
            entries.append(
                PoolEntry(record_asset(library, record), t.wrist_pose[0], t.q[0], t.pre_wrist_pose[0], t.pre_q[0])
            )
        return cls(entries)
