"""Geometry clustering (``ges cluster``) on real datasets: feature time, cluster sizes, where categories go, and
how stable the clusters are.

Run: ``python benchmarks/clustering.py [DATASET ...] [--reuse CLUSTERS_JSON ...] [--results NAME]``; writes
``benchmarks/results/NAME.json`` (default NAME ``clustering``) and prints a table. Default datasets:
``runs/demo/dataset`` and ``/work/ds_run`` where they exist. Per dataset:

- features: seconds per object (mean, max) and in all, single process (other load on the machine shows);
- k = 3, seed 0: training objects per cluster, the categories of each, and the share of training objects the
  category rule moved away from their K-means cluster;
- stability: the adjusted Rand index (1 = the same partition) of the final training labels between seed 0 and
  seeds 1..4 (K-means restarts only: the features are computed once, with seed 0);
- for k = 2..5: the silhouette of the K-means labels and of the labels after the category rule (standardized
  training features; higher = better separated), and the number of clusters of one or no training object.

``--reuse`` takes the features stored in a clusters file (``ges cluster``'s output) instead of recomputing them
(then no feature times).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ges_core.clustering import ClusterConfig, ObjectShape, cluster_objects, load_clusters, object_features
from ges_core.clustering.run import dataset_objects
from ges_core.errors import AssetError

from _results import code_state, results_path, write_results

DEFAULTS = (Path("runs/demo/dataset"), Path("/work/ds_run"))
SEEDS = (0, 1, 2, 3, 4)
KS = (2, 3, 4, 5)


def compute_shapes(dataset_path: Path, points: int) -> tuple[list[ObjectShape], dict, dict[str, str]]:
    """Shapes of every object (features with seed 0), the timing and the objects that failed (id -> why)."""
    from tqdm import tqdm

    from ges_core.dataset import open_dataset
    from ges_core.env.grasp_source import library_for

    dataset = open_dataset(dataset_path)
    library = library_for(dataset)
    shapes, seconds, failed = [], [], {}
    for oid, category, split in tqdm(dataset_objects(dataset), desc=dataset_path.name, unit="obj"):
        start = time.perf_counter()
        try:
            features = object_features(library, oid, points=points, seed=0)
        except AssetError as exc:
            failed[oid] = str(exc)
            continue
        seconds.append(time.perf_counter() - start)
        shapes.append(ObjectShape(oid, category, split, features))
    times = {"objects": len(seconds), "total_s": float(np.sum(seconds)), "mean_s": float(np.mean(seconds))}
    return shapes, times | {"max_s": float(np.max(seconds))}, failed


def reused_shapes(path: Path) -> list[ObjectShape]:
    clusters = load_clusters(path)
    return [ObjectShape(m.object_id, m.category, m.split, m.features) for m in clusters.objects.values()]


def analyse(shapes: list[ObjectShape]) -> dict:
    from sklearn.metrics import adjusted_rand_score, silhouette_score

    base = cluster_objects(shapes, ClusterConfig(k=3, seed=0))
    train = sorted(o for o, m in base.objects.items() if m.split == "train")
    runs = {s: cluster_objects(shapes, ClusterConfig(k=3, seed=s)) for s in SEEDS}
    labels = {s: [run.objects[o].cluster for o in train] for s, run in runs.items()}
    moved = sum(base.objects[o].kmeans_cluster != base.objects[o].cluster for o in train)
    per_k = {}
    for k in KS:
        c = cluster_objects(shapes, ClusterConfig(k=k, seed=0))
        z = c.standardize(np.stack([c.objects[o].features for o in train]))
        final, raw = [c.objects[o].cluster for o in train], [c.objects[o].kmeans_cluster for o in train]
        sizes = c.sizes()
        per_k[k] = {
            "train_sizes": sizes,
            "silhouette_kmeans": _silhouette(silhouette_score, z, raw),
            "silhouette_after_category_rule": _silhouette(silhouette_score, z, final),
            "clusters_with_0_or_1_training_objects": sum(n <= 1 for n in sizes),
        }
    return {
        "objects": len(shapes),
        "train_objects": len(train),
        "k3_seed0": base.summary(),
        "k3_moved_by_category_rule": moved,
        "k3_ari_vs_seed0": {s: float(adjusted_rand_score(labels[0], labels[s])) for s in SEEDS[1:]},
        "per_k": per_k,
        "warnings_k3": list(base.warnings),
    }


def _silhouette(score, z: np.ndarray, labels: list[int]) -> float | None:
    return float(score(z, labels)) if 1 < len(set(labels)) < len(labels) else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("datasets", nargs="*", type=Path, help="dataset folders (default: demo and /work/ds_run)")
    parser.add_argument("--reuse", nargs="*", type=Path, default=[], help="clusters files whose features to reuse")
    parser.add_argument("--points", type=int, default=ClusterConfig().points)
    parser.add_argument("--results", default="clustering", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    out = results_path(args.results)  # a bad name stops here, not after the features
    results = {"code": code_state(), "points": args.points, "datasets": {}}
    for path in args.datasets or [p for p in DEFAULTS if p.is_dir()]:
        shapes, times, failed = compute_shapes(path, args.points)
        results["datasets"][str(path)] = {"features": times, "failed": failed, **analyse(shapes)}
    for path in args.reuse:
        results["datasets"][f"{path} (reused features)"] = analyse(reused_shapes(path))
    write_results(out, results)
    print_table(results)


def print_table(results: dict) -> None:
    for name, r in results["datasets"].items():
        t = r.get("features")
        timing = f", features {t['total_s']:.0f} s ({1000 * t['mean_s']:.0f} ms/object)" if t else ""
        print(f"\n{name}: {r['objects']} objects, {r['train_objects']} training{timing}")
        for row in r["k3_seed0"]:
            cats = ", ".join(row["categories"] + [f"{c} ({n}, mixed)" for c, n in row["mixed"].items()])
            print(f"  cluster {row['cluster']}: {row['train']:>4} train {row['unseen_object']:>4} unseen obj "
                  f"{row['unseen_category']:>4} unseen cat | {cats}")  # fmt: skip
        ari = ", ".join(f"{v:.2f}" for v in r["k3_ari_vs_seed0"].values())
        print(f"  moved by the category rule: {r['k3_moved_by_category_rule']}; ARI vs seed 0 (seeds 1-4): {ari}")
        print("   k  silhouette(K-means)  silhouette(+category)  clusters with <= 1 train object")
        for k, row in r["per_k"].items():
            a, b = row["silhouette_kmeans"], row["silhouette_after_category_rule"]
            print(f"  {k:>2}  {_fmt(a):>19}  {_fmt(b):>21}  {row['clusters_with_0_or_1_training_objects']:>5}")


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


if __name__ == "__main__":
    main()
