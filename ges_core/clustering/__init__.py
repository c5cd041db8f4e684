"""Geometry clustering of a dataset's objects (the paper's Stage 2 expert groups); see ``docs/clustering.md``.

>>> from ges_core.clustering import load_clusters
>>> clusters = load_clusters("runs/demo/dataset")      # DATASET/clusters.json, written by `ges cluster DATASET`
>>> clusters.cluster_of(object_id), clusters.central(0, 0.3), clusters.members(0)

Readers import from here: :class:`Clusters`, :class:`ClusterMember`, :func:`load_clusters` (stable, format
version 1). Writers: :func:`cluster_dataset` (the whole command), :func:`cluster_objects`, :func:`shape_features`.
"""

from __future__ import annotations

from ges_core.clustering.features import FEATURE_NAMES, FEATURE_UNITS, object_features, shape_features
from ges_core.clustering.kmeans import ClusterConfig, ObjectShape, cluster_objects
from ges_core.clustering.store import (
    CLUSTERS_FILE,
    CLUSTERS_FORMAT,
    CLUSTERS_VERSION,
    ClusterMember,
    Clusters,
    clusters_path,
    load_clusters,
    save_clusters,
)

__all__ = [
    "CLUSTERS_FILE",
    "CLUSTERS_FORMAT",
    "CLUSTERS_VERSION",
    "FEATURE_NAMES",
    "FEATURE_UNITS",
    "ClusterConfig",
    "ClusterMember",
    "Clusters",
    "ObjectShape",
    "cluster_dataset",
    "cluster_objects",
    "clusters_path",
    "load_clusters",
    "object_features",
    "save_clusters",
    "shape_features",
]


def __getattr__(name: str):
    if name == "cluster_dataset":  # lazily: it pulls in the dataset, the object library and matplotlib
        from ges_core.clustering.run import cluster_dataset

        return cluster_dataset
    raise AttributeError(f"module 'ges_core.clustering' has no attribute '{name}'")
