"""The clusters file: :class:`Clusters` in memory, ``clusters.json`` on disk (format in ``docs/clustering.md``).

>>> clusters = load_clusters("runs/demo/dataset")            # the folder, or the JSON file itself
>>> clusters.cluster_of("procedural/box/000")                  # -> 1
>>> clusters.members(1, split="train")                         # ids, nearest the centre first
>>> clusters.central(1, 0.3)                                   # the curriculum's first stage: nearest 30 %

Every vector in the file is a plain JSON list; ``centres`` and ``distance`` live in the *standardized* feature
space (each feature minus ``mean``, over ``std``: :meth:`Clusters.standardize`). The file is written atomically
(:func:`ges_core.paths.atomic_write_text`), so a reader sees the old file or the new one.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError, ConfigError
from ges_core.paths import atomic_write_text

__all__ = [
    "CLUSTERS_FILE",
    "CLUSTERS_FORMAT",
    "CLUSTERS_VERSION",
    "ClusterMember",
    "Clusters",
    "clusters_path",
    "load_clusters",
    "save_clusters",
]

CLUSTERS_FORMAT = "ges.object_clusters"
CLUSTERS_VERSION = 1
CLUSTERS_FILE = "clusters.json"
"""Default file name, inside the dataset folder (its picture: ``clusters.png`` beside it)."""

ASSIGNED_BY = ("category", "kmeans", "nearest_centre")
"""How an object got its cluster: its training category's cluster, its own K-means cluster (a training object of
a category K-means splits: ``mixed_categories``), or the nearest centre (objects outside the training split);
see :mod:`.kmeans`."""


@dataclass(frozen=True, kw_only=True)
class ClusterMember:
    """One object of a clustering."""

    object_id: str
    category: str
    split: str
    """'train', 'unseen_object' or 'unseen_category' (the dataset's split)."""
    cluster: int
    """The cluster the object belongs to, 0..k-1 (the expert that owns it)."""
    assigned_by: str
    """'category' (its training category's cluster), 'kmeans' (its own K-means cluster: a category in
    :attr:`Clusters.mixed_categories`) or 'nearest_centre' (objects outside the training split)."""
    features: np.ndarray
    """(F,) float64 raw shape features, in :attr:`Clusters.feature_names` order and units."""
    distance: float
    """Euclidean distance from the standardized features to the centre of ``cluster`` (dimensionless)."""
    nearest_cluster: int
    """The cluster whose centre is nearest (equals ``cluster`` unless the category rule moved the object)."""
    kmeans_cluster: int | None = None
    """The plain K-means label (training objects only; None for the others)."""


@dataclass(frozen=True, kw_only=True)
class Clusters:
    """A clustering of a dataset's objects; see ``docs/clustering.md`` for every field."""

    k: int
    seed: int
    feature_names: tuple[str, ...]
    mean: np.ndarray
    """(F,) float64 mean of the training objects' raw features."""
    std: np.ndarray
    """(F,) float64 their standard deviation (1.0 where a feature is constant: it then standardizes to 0)."""
    centres: np.ndarray
    """(k, F) float64 cluster centres in the standardized space: the mean of each cluster's training objects
    after the category rule (an empty cluster keeps its K-means centre)."""
    kmeans_centres: np.ndarray
    """(k, F) float64 the plain K-means centres, standardized space."""
    objects: Mapping[str, ClusterMember]
    """object id -> member, sorted by id."""
    categories: Mapping[str, int]
    """training category -> its cluster (the categories moved whole)."""
    mixed_categories: Mapping[str, list[int]] = field(default_factory=dict)
    """training category -> its training objects per cluster (k,), for the categories K-means splits too evenly
    to move whole (``ClusterConfig.category_share``); their objects keep their K-means clusters."""
    warnings: tuple[str, ...] = ()
    """Recorded outcomes worth a look (a cluster of one object, an empty cluster), one line each."""
    skipped: Mapping[str, str] = field(default_factory=dict)
    """object id -> why its features could not be computed (only with ``skip_bad``)."""
    config: Mapping[str, object] = field(default_factory=dict)
    """The :class:`~ges_core.clustering.kmeans.ClusterConfig` used, as JSON."""
    dataset: str = ""
    """The dataset folder clustered (as given)."""
    pca: Mapping[str, list] = field(default_factory=dict)
    """The picture's projection: ``mean`` (F,), ``components`` (2, F) of the standardized training features,
    ``explained_variance_ratio`` (2,)."""
    plot: str | None = None
    """File name of the picture beside the JSON (None: not drawn)."""

    def cluster_of(self, object_id: str) -> int:
        """The cluster of ``object_id``; ConfigError naming the known count if the object is not clustered."""
        try:
            return self.objects[object_id].cluster
        except KeyError:
            raise ConfigError(
                f"object '{object_id}' is not in this clustering ({len(self.objects)} objects of {self.dataset}); "
                "run 'ges cluster' on the dataset that holds it"
            ) from None

    def members(self, cluster: int, *, split: str | None = "train") -> list[str]:
        """Ids of ``cluster``'s objects (of ``split``; None: all), nearest its centre first (ties by id)."""
        self._check_cluster(cluster)
        chosen = [m for m in self.objects.values() if m.cluster == cluster and (split is None or m.split == split)]
        return [m.object_id for m in sorted(chosen, key=lambda m: (m.distance, m.object_id))]

    def central(self, cluster: int, fraction: float, *, split: str | None = "train") -> list[str]:
        """The ``ceil(fraction * n)`` members of ``cluster`` nearest its centre (at least one if it has any):
        the curriculum's first stage. fraction in (0, 1]."""
        if not 0.0 < fraction <= 1.0:
            raise ConfigError(f"central: fraction must be in (0, 1], got {fraction}")
        ids = self.members(cluster, split=split)
        return ids[: max(1, math.ceil(fraction * len(ids)))] if ids else []

    def sizes(self, *, split: str | None = "train") -> list[int]:
        """(k,) number of objects (of ``split``) per cluster."""
        return [len(self.members(c, split=split)) for c in range(self.k)]

    def summary(self) -> list[dict]:
        """Per cluster: ``cluster``, ``size``, objects per split and the training ``categories`` it holds."""
        out = []
        for cluster in range(self.k):
            members = [m for m in self.objects.values() if m.cluster == cluster]
            by_split = {s: sum(m.split == s for m in members) for s in ("train", "unseen_object", "unseen_category")}
            cats = sorted(cat for cat, cl in self.categories.items() if cl == cluster)
            mixed = {cat: counts[cluster] for cat, counts in sorted(self.mixed_categories.items()) if counts[cluster]}
            out.append({"cluster": cluster, "size": len(members), **by_split, "categories": cats, "mixed": mixed})
        return out

    def standardize(self, features: np.ndarray) -> np.ndarray:
        """(..., F) raw features -> standardized, the space of ``centres``."""
        return (np.asarray(features, dtype=np.float64) - self.mean) / self.std

    def _check_cluster(self, cluster: int) -> None:
        if not 0 <= cluster < self.k:
            raise ConfigError(f"cluster {cluster} does not exist: this clustering has k = {self.k} (0..{self.k - 1})")


def clusters_path(path: str | Path) -> Path:
    """The clusters file of ``path``: ``path/clusters.json`` for a folder, else ``path`` itself."""
    path = Path(path)
    return path / CLUSTERS_FILE if path.is_dir() else path


def save_clusters(clusters: Clusters, path: str | Path) -> Path:
    """Write ``clusters`` as JSON to ``path`` (a folder: ``path/clusters.json``), atomically; returns the file."""
    target = clusters_path(path)
    atomic_write_text(target, json.dumps(to_json(clusters), indent=1, sort_keys=False) + "\n")
    return target


def load_clusters(path: str | Path) -> Clusters:
    """Read a clusters file (or a dataset folder holding ``clusters.json``); AssetError saying how to make one."""
    target = clusters_path(path)
    if not target.is_file():
        raise AssetError(
            f"no clusters file at {target}: run 'ges cluster DATASET' first (it writes DATASET/clusters.json)"
        )
    try:
        data = json.loads(target.read_text(encoding="utf-8"))
        if data.get("format") != CLUSTERS_FORMAT:
            raise ValueError(f"format is {data.get('format')!r}, not {CLUSTERS_FORMAT!r}")
        if data.get("version") != CLUSTERS_VERSION:
            raise ValueError(f"version {data.get('version')} (this code reads {CLUSTERS_VERSION})")
        return from_json(data)
    except (ValueError, KeyError, TypeError) as exc:
        raise AssetError(f"cannot read clusters file {target}: {exc}; run 'ges cluster' again to rewrite it") from exc


def to_json(clusters: Clusters) -> dict:
    """The JSON document of ``clusters`` (see ``docs/clustering.md``)."""
    c = clusters
    return {
        "format": CLUSTERS_FORMAT,
        "version": CLUSTERS_VERSION,
        "dataset": c.dataset,
        "k": c.k,
        "seed": c.seed,
        "config": dict(c.config),
        "rule": "category_majority",
        "feature_names": list(c.feature_names),
        "standardization": {"mean": _floats(c.mean), "std": _floats(c.std)},
        "centres": [_floats(row) for row in c.centres],
        "kmeans_centres": [_floats(row) for row in c.kmeans_centres],
        "categories": dict(sorted(c.categories.items())),
        "mixed_categories": {cat: list(counts) for cat, counts in sorted(c.mixed_categories.items())},
        "clusters": c.summary(),
        "objects": {oid: _member_json(m) for oid, m in sorted(c.objects.items())},
        "skipped": dict(sorted(c.skipped.items())),
        "warnings": list(c.warnings),
        "pca": {key: value for key, value in c.pca.items()},
        "plot": c.plot,
    }


def _member_json(m: ClusterMember) -> dict:
    return {
        "category": m.category,
        "split": m.split,
        "cluster": m.cluster,
        "assigned_by": m.assigned_by,
        "distance": float(m.distance),
        "nearest_cluster": m.nearest_cluster,
        "kmeans_cluster": m.kmeans_cluster,
        "features": _floats(m.features),
    }


def from_json(data: dict) -> Clusters:
    """The :class:`Clusters` of a JSON document (ValueError/KeyError/TypeError when malformed)."""
    k, names = int(data["k"]), tuple(data["feature_names"])
    centres = _matrix(data["centres"], (k, len(names)), "centres")
    objects = {oid: _member(oid, raw, k, len(names)) for oid, raw in data["objects"].items()}
    return Clusters(
        k=k, seed=int(data["seed"]), feature_names=names,
        mean=_matrix(data["standardization"]["mean"], (len(names),), "standardization.mean"),
        std=_matrix(data["standardization"]["std"], (len(names),), "standardization.std"),
        centres=centres, kmeans_centres=_matrix(data["kmeans_centres"], (k, len(names)), "kmeans_centres"),
        objects=dict(sorted(objects.items())), categories={str(a): int(b) for a, b in data["categories"].items()},
        mixed_categories={str(a): [int(n) for n in b] for a, b in data.get("mixed_categories", {}).items()},
        warnings=tuple(data.get("warnings", ())), skipped=dict(data.get("skipped", {})),
        config=dict(data.get("config", {})), dataset=str(data.get("dataset", "")), pca=dict(data.get("pca", {})),
        plot=data.get("plot"),
    )  # fmt: skip


def _member(oid: str, raw: dict, k: int, n_features: int) -> ClusterMember:
    member = ClusterMember(
        object_id=oid, category=str(raw["category"]), split=str(raw["split"]), cluster=int(raw["cluster"]),
        assigned_by=str(raw["assigned_by"]), distance=float(raw["distance"]),
        nearest_cluster=int(raw["nearest_cluster"]),
        kmeans_cluster=None if raw.get("kmeans_cluster") is None else int(raw["kmeans_cluster"]),
        features=_matrix(raw["features"], (n_features,), f"objects[{oid}].features"),
    )  # fmt: skip
    if not 0 <= member.cluster < k:
        raise ValueError(f"objects[{oid}].cluster = {member.cluster} is outside 0..{k - 1}")
    return member


def _matrix(values: list, shape: tuple[int, ...], where: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.shape != shape:
        raise ValueError(f"{where} has shape {array.shape}, expected {shape}")
    return array


def _floats(values: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(values, dtype=np.float64).ravel()]
