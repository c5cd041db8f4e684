"""CoACD settings: seconds per object and fit, default vs tuned, on five concave library meshes.

Run: ``python benchmarks/coacd_settings.py [--settings default fast ...] [--ids ...] [--results NAME]``; writes
``benchmarks/results/NAME.json`` (default NAME ``coacd_settings``; ``--out PATH``, the older flag, writes that
path instead). Fit is measured by Monte-Carlo points in the mesh's
bounding box: ``precision`` = share of the convex parts' volume that is inside the mesh (1 = the
parts add no false volume, e.g. across a mug's opening), ``recall`` = share of the mesh's volume
covered by parts (CoACD covers everything: ~1.0). Single process; the machine's other load shows in
the times, so compare settings within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from ges_core.objects.decompose import DEFAULT, FAST

from _results import results_path, write_results

IDS = (
    "pybullet/classic/bunny",
    "pybullet/classic/duck",
    "pybullet/classic/torus",
    "procedural/mug/000",
    "procedural/bowl/000",
)
CANDIDATES = {
    "default": DEFAULT,
    "fast": FAST,
    "faster": replace(FAST, threshold=0.15, max_convex_hull=12, resolution=500, mcts_iterations=40),
    "fast_capped": replace(FAST, threshold=0.1, max_convex_hull=16),
}
CONTAINS_BLOCK = 200


def fit(mesh, parts, n: int = 20000) -> tuple[float, float]:
    """(precision, recall) of the union of convex ``parts`` against ``mesh``."""
    from scipy.spatial import ConvexHull

    points = np.random.default_rng(0).uniform(*mesh.bounds, size=(n, 3))
    # in blocks: trimesh's ray test on a 16k-face scan takes ~0.8 GB per 100 points at once (20,000 points
    # at once passed 20 GB)
    in_mesh = np.concatenate([mesh.contains(points[i : i + CONTAINS_BLOCK]) for i in range(0, n, CONTAINS_BLOCK)])
    in_parts = np.zeros(n, dtype=bool)
    for vertices, _faces in parts:
        eq = ConvexHull(vertices).equations
        in_parts |= np.all(points @ eq[:, :3].T + eq[:, 3] <= 1e-9, axis=1)
    both = (in_mesh & in_parts).sum()
    return float(both / max(in_parts.sum(), 1)), float(both / max(in_mesh.sum(), 1))


def measure(mesh, settings, n: int = 20000) -> dict:
    import coacd

    coacd.set_log_level("error")
    start = time.perf_counter()
    parts = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), **asdict(settings))
    seconds = time.perf_counter() - start
    precision, recall = fit(mesh, parts, n)
    return {
        "seconds": round(seconds, 2),
        "parts": len(parts),
        "precision": round(precision, 3),
        "recall": round(recall, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settings", nargs="+", default=list(CANDIDATES), choices=list(CANDIDATES))
    parser.add_argument("--ids", nargs="+", default=list(IDS))
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--results", default="coacd_settings", help="benchmarks/results/NAME.json")
    where.add_argument("--out", type=Path, help="write this path instead (older flag; --results is preferred)")
    args = parser.parse_args()
    out = args.out or results_path(args.results)  # a bad name stops here, not after the decompositions
    os.environ.setdefault("GES_CACHE_DIR", tempfile.mkdtemp(prefix="ges-bench-"))
    from ges_core.objects.library import LibraryConfig, ObjectLibrary

    library = ObjectLibrary(LibraryConfig(sources=("procedural", "pybullet"), procedural_count=1))
    meshes = {oid: library.processed(oid).mesh for oid in args.ids}
    rows = []
    for name in args.settings:
        for oid, mesh in meshes.items():
            row = {"settings": name, "object": oid, "faces": len(mesh.faces), **measure(mesh, CANDIDATES[name])}
            print(json.dumps(row), flush=True)
            rows.append(row)
    summary = {
        name: {
            "mean_seconds": round(float(np.mean([r["seconds"] for r in rows if r["settings"] == name])), 2),
            "mean_precision": round(float(np.mean([r["precision"] for r in rows if r["settings"] == name])), 3),
        }
        for name in args.settings
    }
    result = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores (shared)",
        "settings": {name: asdict(CANDIDATES[name]) for name in args.settings},
        "rows": rows,
        "summary": summary,
    }
    write_results(out, result)
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
