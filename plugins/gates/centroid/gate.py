"""The nearest-centroid baseline gate: the expert of the nearest cluster centre in shape-feature space.

Features: :func:`ges_core.clustering.shape_features` (the clustering's ten, in its order) computed from
the cloud alone, the convex hull of the points standing in for the mesh. So the volume is the hull's
(``hull_ratio`` is 1 and a mug measures as its hull); everything else (extents, PCA ratios, height,
sphericity of the hull, centre-of-mass height of the hull) is as the clustering computes it.

Centres, two ways (the checkpoint and the log say which):

- **with a clustering** (``clusters``: a dataset folder or clusters.json from ``ges cluster``): its
  standardization and centres; cluster c goes to the expert ``cluster_experts[c]``, or, when that is not
  given, to the expert with the highest mean success on the cluster's training objects (the expert
  trained for a cluster should win there).
- **without one**: a nearest-class-mean classifier on the training objects: features standardized by
  their mean and spread, one centre per expert at the mean of the objects where it is the best expert
  (an expert best nowhere gets none and is never chosen).

Scores: softmax(-d^2 / temperature) over each expert's nearest centre, so the argmax is the nearest
centre's expert.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from pydantic import Field

from ges_core.config import parse_model
from ges_core.errors import ArrayError, ConfigError
from ges_core.gating.checkpoint import read_checkpoint, write_checkpoint
from ges_core.gating.data import split_indices, targets
from ges_core.gating.inputs import gate_input
from ges_core.gating.loss import gate_accuracy
from ges_core.gating.torch_gate import GateSettings
from ges_core.gating.train import GateData, TrainConfig, TrainResult
from ges_core.policy import Gate

__all__ = ["CentroidGate", "CentroidSettings", "cloud_features"]

log = logging.getLogger(__name__)


class CentroidSettings(GateSettings):
    """The nearest-centroid baseline."""

    clusters: str | None = Field(
        None, description="clustering to use: a dataset folder holding clusters.json, or the file (None: own centres)"
    )
    cluster_experts: dict[int, str] | None = Field(
        None, description="cluster -> expert name (None: each cluster's best expert on its training objects)"
    )
    temperature: float = Field(
        1.0, gt=0, description="softmax temperature, squared standardized feature units (only the scores' spread)"
    )


def cloud_features(points: np.ndarray, object_id: str = "?") -> np.ndarray:
    """(F,) the clustering's shape features of one cloud (n, 3), object frame, metres; the convex hull of
    the points is the mesh (module docstring). ArrayError naming the object for a flat or degenerate cloud."""
    from ges_core.clustering import FEATURE_NAMES, shape_features

    points = np.asarray(points, dtype=np.float64)
    # sorted first: qhull's triangulation, and with it trimesh's oriented box, depends on the input order
    points = points[np.lexsort(points.T[::-1])]
    try:
        hull = trimesh.convex.convex_hull(points)
    except Exception as exc:  # noqa: BLE001 - qhull raises its own error types for flat input
        raise ArrayError(f"object '{object_id}': no convex hull of its cloud ({exc}); is it flat or a line?") from exc
    features = shape_features(hull, points, volume=float(hull.volume))
    if not np.isfinite(features).all():
        bad = [n for n, v in zip(FEATURE_NAMES, features, strict=True) if not np.isfinite(v)]
        raise ArrayError(f"object '{object_id}': shape features {bad} not finite (a flat or degenerate cloud?)")
    return features


class CentroidGate(Gate):
    """Nearest cluster centre in shape-feature space -> that cluster's expert."""

    name = "centroid"

    def __init__(self, **settings: Any) -> None:
        self.settings = parse_model(CentroidSettings, settings, where="gate 'centroid' settings")
        self.experts: tuple[str, ...] = ()
        self.state: dict[str, torch.Tensor] = {}
        self.train_info: dict[str, Any] = {}

    # -- use ----------------------------------------------------------------------------------
    def predict(
        self, points: torch.Tensor | Sequence[np.ndarray], object_ids: Sequence[str] | None = None
    ) -> torch.Tensor:
        """(n, k) float32 expert scores for clouds (n, N, 3) or a list of (m_i, 3), object frame, metres."""
        if not self.state:
            raise ConfigError("gate 'centroid' is not fitted: fit it (ges train-gate --gate centroid) or load one")
        x = gate_input(points, self.settings.n_points, object_ids)
        ids = list(object_ids) if object_ids is not None else [f"#{i} of the batch" for i in range(len(x))]
        feats = (
            np.stack([cloud_features(c, i) for c, i in zip(x.numpy(), ids, strict=True)])
            if len(x)
            else np.zeros((0, 10))
        )
        return self._scores(torch.from_numpy(feats))

    def _scores(self, features: torch.Tensor) -> torch.Tensor:
        z = (features - self.state["mean"]) / self.state["std"]
        d2 = torch.cdist(z, self.state["centres"]) ** 2  # (n, centres)
        owner = self.state["owner"]  # (centres,) expert column of each centre
        best = torch.full((len(z), len(self.experts)), float("inf"), dtype=d2.dtype)
        best = best.scatter_reduce(1, owner.expand(len(z), -1), d2, reduce="amin")
        return torch.softmax(-(best - best.min(dim=1, keepdim=True).values) / self.settings.temperature, dim=1).float()

    # -- fitting ------------------------------------------------------------------------------
    def fit(self, data: GateData, config: TrainConfig | None = None, **_: Any) -> TrainResult:
        """Centres from the clustering (or the training objects); accuracy on the same split as the
        trained gates (``config``'s val_fraction, seed and all_failed)."""
        config = config or TrainConfig()
        rates = data.rates
        kept, _ = targets(rates, config.all_failed)
        train_rows, val_rows = (kept[i] for i in split_indices(len(kept), config.val_fraction, config.seed))
        ids = rates.object_ids
        x = gate_input(data.clouds, self.settings.n_points, ids)
        feats = np.stack([cloud_features(c, i) for c, i in zip(x.numpy(), ids, strict=True)])
        self.experts = rates.experts
        how = self._fit_clusters(rates.rates, train_rows, ids) if self.settings.clusters else None
        if how is None:
            how = self._fit_own(feats[train_rows], rates.rates[train_rows])
        log.info("centroid gate: %s", how)
        probs = self._scores(torch.from_numpy(feats))
        row = {
            "epoch": 1,
            "accuracy/train": gate_accuracy(probs[train_rows], rates.rates[train_rows]),
            "accuracy/val": gate_accuracy(probs[val_rows], rates.rates[val_rows]),
        }
        dropped = [ids[i] for i in sorted(set(range(len(ids))) - set(kept))]
        result = TrainResult([ids[i] for i in train_rows], [ids[i] for i in val_rows], dropped, [row], 1)
        self.train_info = {
            "config": config.model_dump(mode="json"),
            "summary": result.summary(),
            "centres": how,
            "train_ids": result.train_ids,
            "val_ids": result.val_ids,
            "dropped_ids": dropped,
        }
        return result

    def _fit_own(self, feats: np.ndarray, rates: np.ndarray) -> str:
        mean, std = feats.mean(axis=0), feats.std(axis=0)
        std = np.where(std > 0, std, 1.0)  # a constant feature standardizes to 0 instead of NaN
        z = (feats - mean) / std
        best = rates.argmax(axis=1)
        owners = [e for e in range(rates.shape[1]) if (best == e).any()]
        centres = np.stack([z[best == e].mean(axis=0) for e in owners])
        self._set(mean, std, centres, owners)
        return (
            f"no clustering given: one centre per expert, the mean standardized features of the {len(feats)} training "
            f"objects where it is best ({len(owners)} of {rates.shape[1]} experts are best somewhere)"
        )

    def _fit_clusters(self, rates: np.ndarray, train_rows: np.ndarray, ids: tuple[str, ...]) -> str:
        from ges_core.clustering import load_clusters

        clusters = load_clusters(self.settings.clusters)
        if self.settings.cluster_experts is not None:
            owners = self._named_owners(clusters.k)
            how = "cluster_experts setting"
        else:
            owners = self._best_owners(clusters, rates, train_rows, ids)
            how = "each cluster's best expert on its training objects"
        self._set(clusters.mean, clusters.std, clusters.centres, owners)
        named = dict(enumerate(self.experts[o] for o in owners))
        return f"clustering {self.settings.clusters} (k = {clusters.k}), cluster -> expert by {how}: {named}"

    def _named_owners(self, k: int) -> list[int]:
        given = self.settings.cluster_experts or {}
        missing = [c for c in range(k) if c not in given]
        unknown = sorted({e for e in given.values() if e not in self.experts})
        if missing or unknown:
            raise ConfigError(
                f"centroid gate: cluster_experts {given} must name an expert for every cluster 0..{k - 1} "
                f"(missing {missing}) among the data's experts {list(self.experts)} (unknown {unknown})"
            )
        return [self.experts.index(given[c]) for c in range(k)]

    @staticmethod
    def _best_owners(clusters, rates: np.ndarray, train_rows: np.ndarray, ids: tuple[str, ...]) -> list[int]:
        owners = []
        for c in range(clusters.k):
            rows = [r for r in train_rows if ids[r] in clusters.objects and clusters.objects[ids[r]].cluster == c]
            if not rows:
                raise ConfigError(
                    f"centroid gate: cluster {c} of {clusters.dataset} has none of the training objects of the "
                    "success rates; give cluster_experts, or a clustering of the same dataset"
                )
            owners.append(int(rates[rows].mean(axis=0).argmax()))
        return owners

    def _set(self, mean, std, centres, owners) -> None:
        self.state = {
            "mean": torch.as_tensor(np.asarray(mean), dtype=torch.float64),
            "std": torch.as_tensor(np.asarray(std), dtype=torch.float64),
            "centres": torch.as_tensor(np.asarray(centres), dtype=torch.float64),
            "owner": torch.as_tensor(owners, dtype=torch.int64),
        }

    # -- checkpoints --------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write centres, standardization, owners, settings and experts to ``path`` (atomically)."""
        if not self.state:
            raise ConfigError("gate 'centroid' is not fitted: nothing to save")
        payload = {"gate": self.name, "experts": list(self.experts), "state": self.state, "train": self.train_info}
        write_checkpoint(path, {**payload, "settings": self.settings.model_dump(mode="json")})

    @classmethod
    def load(cls, path: str | Path) -> CentroidGate:
        """The centroid gate saved at ``path``."""
        data = read_checkpoint(path, gate=cls.name)
        gate = cls(**data["settings"])
        gate.experts, gate.state, gate.train_info = tuple(data["experts"]), dict(data["state"]), data.get("train", {})
        return gate
