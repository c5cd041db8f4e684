"""``ges cluster``'s pipeline: a dataset's objects -> shape features -> clusters -> JSON and PNG beside it.

>>> clusters, path = cluster_dataset("runs/demo/dataset", ClusterConfig(k=3))   # writes clusters.json/.png
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ges_core.clustering.features import object_features
from ges_core.clustering.kmeans import ClusterConfig, ObjectShape, cluster_objects
from ges_core.clustering.plot import plot_clusters
from ges_core.clustering.store import Clusters, clusters_path, save_clusters
from ges_core.errors import AssetError

__all__ = ["cluster_dataset", "dataset_objects"]


def dataset_objects(dataset) -> list[tuple[str, str, str]]:
    """``(object id, category, split)`` of every object in an open dataset (any hand, any outcome), by id."""
    seen: dict[str, tuple[str, str]] = {}
    for entry in dataset.entries:
        seen.setdefault(entry["object_id"], (entry.get("category", ""), entry.get("split", "")))
    return [(oid, cat, split) for oid, (cat, split) in sorted(seen.items())]


def cluster_dataset(
    dataset_path: str | Path, config: ClusterConfig, *, out: str | Path | None = None, progress: bool = False
) -> tuple[Clusters, Path]:
    """Cluster the objects of the dataset at ``dataset_path``; write ``out`` (default ``DATASET/clusters.json``)
    and the picture beside it (same name, ``.png``). Returns the clusters and the JSON path.

    The objects' meshes come from the library the dataset was made with (its ``run_config.library``).
    """
    from ges_core.dataset import open_dataset
    from ges_core.env.grasp_source import library_for

    dataset = open_dataset(dataset_path)
    objects = dataset_objects(dataset)
    if not objects:
        raise AssetError(f"dataset {dataset_path} holds no records, so no objects to cluster")
    library = library_for(dataset)
    shapes, skipped = _features(library, objects, config, progress=progress)
    clusters = cluster_objects(shapes, config)
    target = clusters_path(Path(dataset_path) if out is None else Path(out))
    picture = target.with_suffix(".png")
    clusters = replace(clusters, dataset=str(dataset_path), skipped=skipped, plot=picture.name)
    plot_clusters(clusters, picture)
    return clusters, save_clusters(clusters, target)


def _features(
    library, objects: list[tuple[str, str, str]], config: ClusterConfig, *, progress: bool
) -> tuple[list[ObjectShape], dict[str, str]]:
    """Features of each object; with ``skip_bad`` the failures are returned (id -> why) instead of raised."""
    from tqdm import tqdm

    shapes, skipped = [], {}
    for oid, category, split in tqdm(objects, desc="shape features", unit="obj", disable=not progress):
        try:
            features = object_features(library, oid, points=config.points, seed=config.seed)
        except AssetError as exc:
            if not config.skip_bad:
                raise AssetError(
                    f"cannot compute the shape features of '{oid}': {exc}. Pass --skip-bad (ClusterConfig.skip_bad) "
                    "to leave such objects out; they are then listed under 'skipped' in the clusters file"
                ) from exc
            skipped[oid] = str(exc)  # the caller reports them (`ges cluster` prints each)
            continue
        shapes.append(ObjectShape(oid, category, split, features))
    return shapes, skipped
