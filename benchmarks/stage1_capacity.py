"""What the fingertips of Stage 1's kept grasps can hold within the hand's actuators, against the perturbation trials.

For every record of the given datasets with a refined grasp and perturbation trials, the quasi-static fingertip
capacity (``ges_core.synthesis.physics.capacity``: a linear program over the touching fingertips' friction cones,
every joint within its effort limit) at the nominal effective friction and at the friction trial's, as a multiple of
the object's weight. Each drive-limited trial's bound follows: ``limits`` needs 1x at the nominal friction,
``mass_xS`` S x, ``friction_F`` 1x at F. The table sets each trial's bound beside its outcome in every validating
simulator, and counts per hand how many failed trials were beyond the bound (no closing of those fingertips could
pass them), how many failed within it, and how many passed beyond it (contacts the model leaves out or misreads:
phalanges, the palm, a pad's nearest sample on the wrong face of a thin part). Pose trials are not bounded (their
weight is the nominal's; they fail by geometry) and are left out. ``--pressing SIM`` counts only the fingers that
press the object at the end of the limits trial's close, replayed in SIM.

    python benchmarks/stage1_capacity.py --dataset runs/real_s41 runs/demo/dataset [--near 0.02]
    python benchmarks/stage1_capacity.py --dataset runs/library --no-records --results stage1_capacity_library
    python benchmarks/stage1_capacity.py --dataset runs/real --pressing sapien --results stage1_capacity_pressing

Prints the tables and writes ``benchmarks/results/stage1_capacity.json`` (``--results`` another name). The rows and
counts are ``ges_core.synthesis.run.capacity``'s, as ``ges dataset capacity`` prints them.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.registry import load_registry
from ges_core.synthesis.physics.capacity import NEAR
from ges_core.synthesis.run.capacity import bound_counts, bounds_table, counts_table, trial_bounds
from ges_core.threads import set_torch_threads

from _results import code_state, results_path, write_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", nargs="+", type=Path, required=True, help="Stage 1 datasets with robust trials")
    parser.add_argument("--near", type=float, default=NEAR, help="a pad this close to the surface touches, m")
    parser.add_argument("--results", default="stage1_capacity", help="name of the JSON under benchmarks/results/")
    parser.add_argument("--no-records", action="store_true", help="store the counts only (a whole-library run)")
    parser.add_argument(
        "--pressing", metavar="SIM", default=None,
        help="bound with the fingers the limits trial's close leaves pressing, replayed in SIM (as `ges dataset "
        "capacity --pressing`)",
    )  # fmt: skip
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the datasets
    set_torch_threads(1)
    registry = load_registry()
    out = {"near": args.near, "pressing": args.pressing, "datasets": {}, "code": code_state()}
    for folder in args.dataset:
        rows = trial_bounds(folder, registry, near=args.near, pressing=args.pressing, progress=True)
        counts = bound_counts(rows)
        by_source = {}  # object ids' first two parts: procedural/cone, pybullet/random_urdfs, real/can, ...
        for source in sorted({"/".join(r["object"].split("/")[:2]) for r in rows}):
            by_source[source] = bound_counts([r for r in rows if r["object"].startswith(source + "/")])
        entry = {"counts": counts, "counts_by_source": by_source}
        out["datasets"][str(folder)] = entry if args.no_records else {"records": rows, **entry}
        table = "" if args.no_records else bounds_table(rows) + "\n\n"
        print(f"\n{folder}\n" + table + counts_table(counts))
    write_results(results, out)


if __name__ == "__main__":
    main()
