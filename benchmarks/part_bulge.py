"""How far a capped decomposition of a hand's link meshes stands out beyond the uncapped one, per mesh and cap.

A cap on CoACD's parts per mesh (``max_convex_hull``) merges parts, and a merged convex part can reach beyond the
mesh it stands for, into what the hand touches (docs/hands/assets.md, "Tried, not adopted: a cap on parts per
mesh"). The hull-gap rule ``ges hand prepare`` uses measures the other way (the mesh's surface inside a part) and
cannot see it. Here, for every link mesh the hand's preparation decomposed and every cap asked for:

* points are sampled on the capped parts' surfaces (about one per ``--spacing`` squared, seeded);
* a point inside any uncapped part (exact: each part is convex, tested against its hull's planes) stands for
  geometry the uncapped hand has too, faces the merged parts share among them included;
* for the others, the bulge is their distance to the uncapped parts (the nearest of points sampled as densely on
  their surfaces: an overestimate by at most about the spacing).

The table gives per mesh and cap the parts, the share of sampled area outside the uncapped parts, and the bulge's
95th percentile and maximum, mm. The uncapped parts are the reference, not the mesh itself: they follow it to within
the hands' CoACD threshold. The caps' decompositions must be in the cache (``benchmarks/hand_parts.py`` makes them;
a missing one is reported and skipped). Results: ``benchmarks/results/NAME.json``.

    python benchmarks/part_bulge.py [--hand inspire] [--caps 32 16 8] [--spacing 0.0005] [--results part_bulge_inspire]

The hand's package must be installed (``pip install -e examples/ges-inspire-hand``).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import code_state, results_path, write_results  # noqa: E402


def load_parts(paths: list[Path]) -> list:
    """The part files as trimesh meshes."""
    import trimesh

    return [trimesh.load(str(p), force="mesh") for p in paths]


def surface_samples(meshes: list, spacing: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) points on the meshes' surfaces, about one per ``spacing`` squared, and (N,) the area each stands for."""
    import trimesh

    rng = np.random.default_rng(seed)
    points, weights = [], []
    for mesh in meshes:
        count = max(int(np.ceil(mesh.area / spacing**2)), 1)
        sampled, _ = trimesh.sample.sample_surface(mesh, count, seed=int(rng.integers(2**31)))
        points.append(np.asarray(sampled))
        weights.append(np.full(len(sampled), mesh.area / len(sampled)))
    return np.concatenate(points), np.concatenate(weights)


def inside_any(points: np.ndarray, meshes: list, tolerance: float = 1e-6) -> np.ndarray:
    """(N,) whether each point lies inside (or within ``tolerance`` m of) at least one of the convex meshes."""
    from scipy.spatial import ConvexHull

    inside = np.zeros(len(points), dtype=bool)
    for mesh in meshes:
        planes = ConvexHull(np.asarray(mesh.vertices)).equations  # (P, 4): n . x + d <= 0 inside
        todo = ~inside
        inside[todo] = (points[todo] @ planes[:, :3].T + planes[:, 3]).max(axis=1) <= tolerance
    return inside


def mesh_bulge(capped: list, uncapped: list, spacing: float, seed: int) -> dict:
    """Share of the capped parts' area outside the uncapped parts and how far it reaches (mm)."""
    from scipy.spatial import cKDTree

    points, weights = surface_samples(capped, spacing, seed)
    outside = ~inside_any(points, uncapped)
    row = {"samples": len(points), "outside_share": float(weights[outside].sum() / weights.sum())}
    if not outside.any():
        return {**row, "bulge_p95_mm": 0.0, "bulge_max_mm": 0.0}
    reference, _ = surface_samples(uncapped, spacing, seed + 1)
    distance = cKDTree(reference).query(points[outside])[0]
    return {
        **row,
        "bulge_p95_mm": float(np.percentile(distance, 95) * 1000),
        "bulge_max_mm": float(distance.max() * 1000),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--hand", default="inspire")
    p.add_argument("--caps", nargs="+", type=int, default=[32, 16, 8])
    p.add_argument("--spacing", type=float, default=0.0005, help="sample spacing, m")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--results", default=None, help="benchmarks/results/NAME.json (default part_bulge_HAND)")
    args = p.parse_args()
    results = results_path(args.results or f"part_bulge_{args.hand}")

    from ges_core.hand_prep.decompose import HAND_COACD
    from ges_core.hand_prep.prepare import prepare_hand
    from ges_core.objects.decompose import cached_parts
    from ges_core.paths import file_sha256
    from ges_core.registry import load_registry

    start = time.perf_counter()
    report = prepare_hand(load_registry().build_hand(args.hand), progress=False)  # cached: reads the manifests
    rows = []
    for plan in (m for m in report.meshes if m.parts):
        key = file_sha256(plan.path)
        uncapped = load_parts(cached_parts(key, HAND_COACD))
        for cap in args.caps:
            paths = cached_parts(key, replace(HAND_COACD, max_convex_hull=cap))
            row = {"mesh": plan.path.name, "links": list(plan.links), "cap": cap, "uncapped_parts": len(uncapped)}
            if paths is None:
                rows.append({**row, "parts": None})
                print(f"{plan.path.name}: no decomposition at cap {cap} in the cache (run benchmarks/hand_parts.py)")
                continue
            bulge = mesh_bulge(load_parts(paths), uncapped, args.spacing, args.seed)
            rows.append({**row, "parts": len(paths), **bulge})
    print_table(rows)
    meta = {"hand": args.hand, "caps": args.caps, "spacing_m": args.spacing, "seed": args.seed,
            "seconds": round(time.perf_counter() - start, 1), **code_state()}  # fmt: skip
    write_results(results, {"meta": meta, "rows": rows})


def print_table(rows: list[dict]) -> None:
    """Markdown table: a row per mesh and cap."""
    print("| mesh (links) | parts, uncapped -> cap | area outside the uncapped parts | bulge p95 / max (mm) |")
    print("|---|---|---|---|")
    for r in rows:
        links = ", ".join(r["links"])[:40]
        if r["parts"] is None:
            print(f"| {r['mesh']} ({links}) | {r['uncapped_parts']} -> cap {r['cap']}: not cached | - | - |")
            continue
        print(
            f"| {r['mesh']} ({links}) | {r['uncapped_parts']} -> {r['parts']} (cap {r['cap']}) | "
            f"{r['outside_share'] * 100:.1f} % | {r['bulge_p95_mm']:.1f} / {r['bulge_max_mm']:.1f} |"
        )


if __name__ == "__main__":
    main()
