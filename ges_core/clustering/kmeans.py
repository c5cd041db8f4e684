"""K-means of the objects' shape features, combined with their categories (the paper's Stage 2 grouping).

The paper clusters objects "with K-means plus category-based clustering" and gives no more detail. **Our
reading**, in three steps:

1. Only **training** objects define the clusters: their features are standardized (mean and standard deviation
   of the training objects) and clustered by K-means (scikit-learn, ``n_init`` seeded restarts).
2. **Category rule**: each training category goes whole to the K-means cluster holding most of its training
   objects, so one category never spans two experts -- provided that cluster holds at least ``category_share``
   (default 2/3) of them. A category K-means splits more evenly is not one shape family, and its objects keep
   their K-means clusters (``assigned_by = "kmeans"``; the category is listed in ``mixed_categories``).
   Measured on the 1,269-object library dataset: pybullet's 809 training ``random_urdfs`` (random shapes under
   one name) had 54 % in one cluster; moved whole they put 873 of 922 training objects in one cluster and left
   another empty. A tie (with ``category_share <= 0.5``) goes to the cluster whose centre is nearest the
   category's mean standardized features, then to the lower cluster index (deterministic). The centres are then
   recomputed as the means of each cluster's training objects (a cluster the rule emptied keeps its K-means
   centre and is reported in ``warnings``).
3. Objects **outside the training split** (unseen objects, unseen categories) do not move the centres; each
   goes to the **nearest centre** (``assigned_by = "nearest_centre"``), as a gate meeting a new object would.

scikit-learn (a core dependency for this) is used for K-means itself: k-means++ seeding and Lloyd iterations
with seeded restarts are well tested there, and one ``random_state`` makes the result repeat.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from pydantic import Field

from ges_core.clustering.features import FEATURE_NAMES
from ges_core.clustering.store import ClusterMember, Clusters
from ges_core.config import ConfigModel
from ges_core.errors import ConfigError

__all__ = ["ClusterConfig", "ObjectShape", "cluster_objects"]


class ClusterConfig(ConfigModel):
    """Settings of ``ges cluster``."""

    k: int = Field(3, ge=1, description="number of clusters (experts); the paper uses 3")
    seed: int = Field(0, ge=0, description="seed of the point clouds and of K-means' restarts")
    points: int = Field(
        2048, ge=16, description="surface points per object for the PCA features (2048: eigenvalue ratios within "
        "about 0.05 of a sphere's 1.0; 1024 doubles the scatter)",
    )  # fmt: skip
    category_share: float = Field(
        2 / 3, ge=0, le=1, description="a category moves whole to its majority cluster when that cluster holds at "
        "least this share of its training objects; else its objects keep their K-means clusters (0: always whole, "
        "the plain rule; 1: only categories K-means keeps together)",
    )  # fmt: skip
    n_init: int = Field(10, ge=1, description="K-means restarts (the best inertia is kept); scikit-learn's default")
    skip_bad: bool = Field(
        False, description="leave out (and record) objects whose features cannot be computed, instead of stopping"
    )


@dataclass(frozen=True)
class ObjectShape:
    """One object to cluster."""

    object_id: str
    category: str
    split: str
    """'train', 'unseen_object' or 'unseen_category': only 'train' objects define the clusters."""
    features: np.ndarray
    """(F,) float64 raw shape features (:data:`~ges_core.clustering.features.FEATURE_NAMES` order)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "features", np.asarray(self.features, dtype=np.float64))


def cluster_objects(
    shapes: list[ObjectShape], config: ClusterConfig, *, feature_names: tuple[str, ...] = FEATURE_NAMES
) -> Clusters:
    """Cluster ``shapes`` as the module docstring says; ConfigError when the training objects are fewer than k."""
    train = [s for s in shapes if s.split == "train"]
    if len(train) < config.k:
        raise ConfigError(
            f"cannot make k = {config.k} clusters from {len(train)} training object(s) "
            f"({len(shapes)} objects in all): lower k (-k) or cluster a dataset with more training objects"
        )
    x = np.stack([s.features for s in train])
    mean, std = x.mean(axis=0), x.std(axis=0)
    std = np.where(std > 0, std, 1.0)  # a constant feature standardizes to 0 instead of dividing by zero
    z = (x - mean) / std
    labels, kmeans_centres = _kmeans(z, config)
    categories, mixed = _category_clusters(train, z, labels, kmeans_centres, config)
    final = np.array([categories.get(s.category, label) for s, label in zip(train, labels, strict=True)])
    centres = np.array(
        [z[final == c].mean(axis=0) if np.any(final == c) else kmeans_centres[c] for c in range(config.k)]
    )
    members = _members(shapes, labels, categories, centres, mean, std)
    return Clusters(
        k=config.k, seed=config.seed, feature_names=tuple(feature_names), mean=mean, std=std, centres=centres,
        kmeans_centres=kmeans_centres, objects=members, categories=categories, mixed_categories=mixed,
        warnings=_warnings(members, config.k), config=config.model_dump(mode="json"), pca=_pca(z),
    )  # fmt: skip


def _kmeans(z: np.ndarray, config: ClusterConfig) -> tuple[np.ndarray, np.ndarray]:
    """K-means labels (n,) and centres (k, F) of standardized features ``z``."""
    from sklearn.cluster import KMeans

    model = KMeans(n_clusters=config.k, n_init=config.n_init, random_state=config.seed).fit(z)
    return model.labels_.astype(np.int64), np.asarray(model.cluster_centers_, dtype=np.float64)


def _category_clusters(
    train: list[ObjectShape], z: np.ndarray, labels: np.ndarray, centres: np.ndarray, config: ClusterConfig
) -> tuple[dict[str, int], dict[str, list[int]]]:
    """(training category -> the cluster holding most of its objects (ties: nearest centre to the category's
    mean, then the lower index), for the categories whose majority reaches ``category_share``; the other
    categories -> their training objects per cluster (k,))."""
    whole, mixed = {}, {}
    for category in sorted({s.category for s in train}):
        rows = np.array([s.category == category for s in train])
        votes = Counter(labels[rows].tolist())
        top = max(votes.values())
        if top < config.category_share * int(rows.sum()):
            mixed[category] = [votes.get(c, 0) for c in range(config.k)]
            continue
        tied = sorted(c for c, n in votes.items() if n == top)
        distance = np.linalg.norm(centres[tied] - z[rows].mean(axis=0), axis=1)
        whole[category] = int(tied[int(np.argmin(distance))])  # argmin returns the first (lower index) on a tie
    return whole, mixed


def _members(
    shapes: list[ObjectShape],
    labels: np.ndarray,
    categories: Mapping[str, int],
    centres: np.ndarray,
    mean: np.ndarray,
    std: np.ndarray,
) -> dict[str, ClusterMember]:
    """Every object's member entry (training objects in ``labels`` order)."""
    out, train_index = {}, 0
    for s in shapes:
        zs = (s.features - mean) / std
        distances = np.linalg.norm(centres - zs, axis=1)
        nearest = int(np.argmin(distances))
        kmeans_label = None
        if s.split == "train":
            kmeans_label = int(labels[train_index])
            train_index += 1
            whole = s.category in categories
            cluster, how = (categories[s.category], "category") if whole else (kmeans_label, "kmeans")
        else:
            cluster, how = nearest, "nearest_centre"
        out[s.object_id] = ClusterMember(
            object_id=s.object_id, category=s.category, split=s.split, cluster=cluster, assigned_by=how,
            features=s.features, distance=float(distances[cluster]), nearest_cluster=nearest,
            kmeans_cluster=kmeans_label,
        )  # fmt: skip
    return dict(sorted(out.items()))


def _warnings(members: Mapping[str, ClusterMember], k: int) -> tuple[str, ...]:
    """One line per cluster with fewer than two training objects (an expert cannot generalize from one)."""
    out = []
    for cluster in range(k):
        ids = sorted(m.object_id for m in members.values() if m.cluster == cluster and m.split == "train")
        if not ids:
            out.append(
                f"cluster {cluster} holds no training object: the category rule moved them all to other clusters "
                "(fewer training categories than k, or one category dominating); its expert has nothing to train on"
            )
        elif len(ids) == 1:
            out.append(
                f"cluster {cluster} holds one training object ({ids[0]}): its expert trains on that object alone; "
                "lower k or add objects"
            )
    return tuple(out)


def _pca(z: np.ndarray) -> dict[str, list]:
    """First two principal axes of the standardized training features (for the picture), sign fixed so the
    largest-magnitude entry of each axis is positive (SVD's sign is arbitrary)."""
    centre = z.mean(axis=0)
    _, s, vt = np.linalg.svd(z - centre, full_matrices=False)
    axes = np.zeros((2, z.shape[1]))
    axes[: min(2, len(vt))] = vt[:2]
    for row in axes:
        if row.any() and row[np.argmax(np.abs(row))] < 0:
            row *= -1
    var = s**2
    ratio = (var / var.sum())[:2] if var.sum() > 0 else np.zeros(min(2, len(s)))
    ratio = np.pad(ratio, (0, 2 - len(ratio)))
    return {"mean": centre.tolist(), "components": axes.tolist(), "explained_variance_ratio": ratio.tolist()}
