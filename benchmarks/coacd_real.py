"""Collision shapes per object on the real set: CoACD for every concave scan (before) versus the hull test
first (after: one hull when the surface lies within ``decompose.hull_tolerance`` of it, otherwise CoACD with
``decompose.settings_for``: a lower threshold on objects longer than 15 cm).

Run: ``python benchmarks/coacd_real.py [--ids ...] [--results NAME]`` (needs the ``[real]`` extra); writes
``benchmarks/results/NAME.json`` (default NAME ``coacd_real``; ``--out PATH``, the older flag, writes that
path instead) and prints a table. Per object: faces, hull depth (mm) and the
tolerance, the choice, the hull test's seconds, CoACD's (``FAST`` settings) seconds and parts, and the fit
(precision: share of the collision volume inside the mesh, 1 = no false volume) of the CoACD parts and of the
hull. "after" seconds = hull test + CoACD only where it is still run (the same run as "before" where the
settings are unchanged: same mesh, same seeded settings). Single process; other load on the machine shows in the times.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from coacd_settings import measure

from ges_core.objects.decompose import FAST, hull_depth, hull_tolerance, settings_for

from _results import code_state, results_path, write_results

EXTRA = ("pybullet/classic/bunny", "pybullet/classic/duck", "pybullet/classic/torus")
FIT_POINTS = 4000  # Monte-Carlo points of the CoACD parts' precision (trimesh's inside test: ~2 ms a point here)


def hull_fit(mesh) -> float:
    """Precision of the convex hull as the collision shape (mesh volume / hull volume)."""
    return float(mesh.volume / mesh.convex_hull.volume)


def row_for(library, oid: str) -> dict:
    from ges_core.objects.processing import min_width

    obj = library.processed(oid)
    mesh = obj.mesh
    start = time.perf_counter()
    depth, tol = hull_depth(mesh), hull_tolerance(min_width(mesh))
    test_s = time.perf_counter() - start
    before = measure(mesh, FAST, FIT_POINTS) if obj.kind in ("near_convex", "concave") else None
    hull = obj.kind in ("convex", "near_convex")
    own = settings_for(mesh, FAST)
    coacd = None if hull or before is None else before if own == FAST else measure(mesh, own, FIT_POINTS)
    after_s = test_s + (coacd["seconds"] if coacd else 0.0)
    return {
        "object": oid, "faces": len(mesh.faces), "kind": obj.kind, "hull_depth_mm": round(depth * 1000, 1),
        "tolerance_mm": round(tol * 1000, 1), "hull_test_s": round(test_s, 2), "threshold": own.threshold,
        "before": before, "after": {"parts": coacd["parts"] if coacd else 1, "seconds": round(after_s, 2),
                                    "precision": coacd["precision"] if coacd else round(hull_fit(mesh), 3)},
    }  # fmt: skip


def table(rows: list[dict]) -> str:
    head = f"{'object':34s} {'faces':>6s} {'depth/tol mm':>13s} {'kind':12s} "
    head += f"{'before parts/s/prec':>21s} {'after parts/s/prec':>20s}"
    lines = [head]
    for r in rows:
        b, a = r["before"], r["after"]
        before = f"{b['parts']:3d} {b['seconds']:6.1f} {b['precision']:.2f}" if b else "   -      -    -"
        lines.append(
            f"{r['object']:34s} {r['faces']:6d} {r['hull_depth_mm']:5.1f}/{r['tolerance_mm']:4.1f}    "
            f"{r['kind']:12s} {before:>21s} {a['parts']:3d} {a['seconds']:6.1f} {a['precision']:.2f}"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", nargs="+", help="object ids (default: the real set and three pybullet classics)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--results", default="coacd_real", help="benchmarks/results/NAME.json")
    where.add_argument("--out", type=Path, help="write this path instead (older flag; --results is preferred)")
    args = parser.parse_args()
    out = args.out or results_path(args.results)  # a bad name stops here, not after the decompositions
    os.environ.setdefault("GES_CACHE_DIR", tempfile.mkdtemp(prefix="ges-bench-"))
    from ges_core.objects.library import LibraryConfig, ObjectLibrary
    from ges_core.objects.real import REAL_OBJECTS

    library = ObjectLibrary(LibraryConfig(sources=("real", "pybullet")))
    ids = args.ids or [o.object_id for o in REAL_OBJECTS] + list(EXTRA)
    rows = []
    for oid in ids:
        rows.append(row_for(library, oid))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    total = {k: round(sum(r[k]["seconds"] for r in rows if r[k]), 1) for k in ("before", "after")}
    print(table(rows))
    print(f"total seconds: before {total['before']}, after {total['after']}")
    result = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores (shared)",
        "code": code_state(),
        "settings": "decompose.FAST",
        "rows": rows,
        "total_seconds": total,
        "median_parts": {k: float(np.median([r[k]["parts"] for r in rows if r[k]])) for k in ("before", "after")},
    }
    write_results(out, result)


if __name__ == "__main__":
    main()
