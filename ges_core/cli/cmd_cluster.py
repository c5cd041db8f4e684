"""``ges cluster DATASET``: group a dataset's objects by shape (K-means + category), for the Stage 2 experts."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ges_core.cli.args import non_negative_int, positive_float, positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges cluster``."""
    p = sub.add_parser(
        "cluster", help="cluster a dataset's objects by shape features (writes DATASET/clusters.json and .png)"
    )
    p.add_argument("dataset", type=Path, metavar="DATASET", help="a grasp dataset folder (ges synth / ges demo)")
    p.add_argument(
        "-k", type=positive_int, default=3, help="number of clusters, one expert each (default 3, as the paper)"
    )
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of point clouds and K-means (default 0)")
    p.add_argument(
        "--category-share", type=positive_float, default=2 / 3, metavar="S",
        help="a category moves whole to the cluster holding most of its training objects when that cluster holds "
        "at least this share of them (default 2/3; <= 1/k: always, as a majority holds at least 1/k)",
    )  # fmt: skip
    p.add_argument(
        "--points", type=positive_int, default=2048, metavar="N", help="surface points per object (default 2048)"
    )
    p.add_argument(
        "--out", type=Path, metavar="PATH", help="clusters JSON to write (default DATASET/clusters.json; PNG beside)"
    )
    p.add_argument("--skip-bad", action="store_true", help="leave out (and record) objects whose features fail")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_cluster)


def run_cluster(args: argparse.Namespace) -> int:
    """Cluster, write the files, print the summary table and any warning."""
    from ges_core.clustering.kmeans import ClusterConfig
    from ges_core.clustering.run import cluster_dataset
    from ges_core.config import parse_model

    settings = {"k": args.k, "seed": args.seed, "points": args.points, "skip_bad": args.skip_bad}
    settings["category_share"] = args.category_share
    config = parse_model(ClusterConfig, settings, where="cluster settings (-k, --seed, --points, --category-share)")
    start = time.perf_counter()
    clusters, path = cluster_dataset(args.dataset, config, out=args.out, progress=not args.no_progress)
    print(summary_table(clusters))
    for oid, why in clusters.skipped.items():
        print(f"left out {oid}: {why}")
    for line in clusters.warnings:
        print(f"warning: {line}")
    print(f"wrote {path} and {path.with_suffix('.png')} ({time.perf_counter() - start:.1f} s)")
    return 0


def summary_table(clusters) -> str:
    """Per cluster: objects by split and the training categories it holds."""
    rows = [f"{'cluster':>7}  {'train':>5}  {'unseen obj':>10}  {'unseen cat':>10}  categories (train)"]
    for row in clusters.summary():
        mixed = [f"{cat} ({n}, mixed)" for cat, n in row["mixed"].items()]
        cats = ", ".join(row["categories"] + mixed) or "-"
        rows.append(
            f"{row['cluster']:>7}  {row['train']:>5}  {row['unseen_object']:>10}  {row['unseen_category']:>10}  {cats}"
        )
    cats, total = len(clusters.categories) + len(clusters.mixed_categories), len(clusters.objects)
    rows.append(f"{cats} training categories, {total} objects, k = {clusters.k}, seed {clusters.seed}")
    return "\n".join(rows)
