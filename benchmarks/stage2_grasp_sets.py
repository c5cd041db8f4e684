"""Does a better Stage 1 dataset raise Stage 2? One expert's success on the same objects with two datasets' grasps.

Reads two success matrices of ``ges eval-experts`` (the same expert columns, evaluation seeds and run settings, but
the grasps of two Stage 1 datasets, e.g. before and after a Stage 1 change) and, per expert column, pairs the
objects both hold: the old grasps' rate, the new grasps' rate, and the difference with a paired bootstrap interval
over objects (:func:`ges_core.experts.compare.compare_to_baseline`, the old grasps as the baseline), per split and
per Stage 1 verdict of the new grasp (:mod:`ges_core.experts.by_grasp`). Several matrices per side (other seeds) are
pooled first. Prints the tables and writes ``benchmarks/results/stage2_grasp_sets.json``.

    python benchmarks/stage2_grasp_sets.py --old M_OLD [M_OLD ...] --new M_NEW [M_NEW ...] [--experts scripted,res1s2]
        [--results NAME]

The two sides must have run the same settings (the matrices' ``run``: hand, simulator, seeds, environment) and the
same settings per compared column; anything else is refused.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ges_core.dataset import open_dataset
from ges_core.dataset.layout import config_differences
from ges_core.experts.by_grasp import GRASP_GROUPS, by_grasp
from ges_core.experts.compare import column_list, compare_to_baseline, comparison_table, pool_matrices
from ges_core.experts.matrix import PROTOCOLS, SuccessMatrix, load_matrix, read_matrix_json
from ges_core.experts.table import expert_table, split_rates
from ges_core.objects.splits import SPLITS

from _results import code_state, results_path, write_results

OLD, NEW = "old grasps", "new grasps"


def paired(old: SuccessMatrix, new: SuccessMatrix, expert: str) -> SuccessMatrix:
    """Two columns, ``OLD`` (the baseline) and ``NEW``: ``expert``'s cells of each matrix on the objects both hold,
    in ``new``'s order, with ``new``'s splits."""
    rows = [(i, old.object_ids.index(o)) for i, o in enumerate(new.object_ids) if o in old.object_ids]
    i_new, i_old = (np.array(x, dtype=np.int64) for x in zip(*rows, strict=True))
    j_old, j_new = old.column(expert), new.column(expert)

    def both(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.stack([a[i_old, j_old], b[i_new, j_new]], axis=1)

    return SuccessMatrix(
        object_ids=tuple(new.object_ids[i] for i in i_new),
        splits=tuple(new.splits[i] for i in i_new),
        categories=tuple(new.categories[i] for i in i_new),
        clusters=tuple(new.clusters[i] for i in i_new),
        experts=(OLD, NEW),
        expert_names=(expert, expert),
        expert_settings=(old.expert_settings[j_old], new.expert_settings[j_new]),
        episodes=both(old.episodes, new.episodes),
        successes={p: both(old.successes[p], new.successes[p]) for p in PROTOCOLS},
        baseline=OLD,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", nargs="+", type=Path, required=True, help="matrices run on the old dataset")
    parser.add_argument("--new", nargs="+", type=Path, required=True, help="matrices run on the new dataset")
    parser.add_argument("--experts", default="scripted", help="expert columns to compare (comma-separated)")
    parser.add_argument("--protocol", default="paper", choices=tuple(PROTOCOLS))
    parser.add_argument(
        "--results", default="stage2_grasp_sets", help="benchmarks/results/NAME.json (default stage2_grasp_sets)"
    )
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, before any work
    old, new = pool_matrices([load_matrix(p) for p in args.old]), pool_matrices([load_matrix(p) for p in args.new])
    data = read_matrix_json(args.new[0])
    if differ := config_differences(read_matrix_json(args.old[0])["run"], data["run"]):
        parser.error(f"the two sides ran other settings, so their episodes are not comparable: {differ}")
    keys = {oid: entry.get("grasp_key") for oid, entry in data["objects"].items()}
    new_groups = by_grasp(new, keys, open_dataset(data["dataset"]), data["run"]["hand"])
    out = {"benchmark": "stage2_grasp_sets", "old": [str(p) for p in args.old], "new": [str(p) for p in args.new],
           "protocol": args.protocol, "experts": {}, "code": code_state()}  # fmt: skip
    for expert in column_list(args.experts):
        if old.expert_settings[old.column(expert)] != new.expert_settings[new.column(expert)]:
            parser.error(f"column '{expert}' ran other settings on the two sides (another checkpoint?)")
        pair = paired(old, new, expert)
        groups = paired(old, new_groups, expert)
        present = tuple(g for g in GRASP_GROUPS if g in groups.splits)
        split_diffs = compare_to_baseline(pair, args.protocol)
        group_diffs = compare_to_baseline(groups, args.protocol, splits=(*present, None))
        print(f"\n## {expert}: {len(pair.object_ids)} objects in both matrices\n")
        print(expert_table(pair, args.protocol) + "\n\n" + comparison_table(split_diffs, title="new against old"))
        print(f"\nby the new grasp's Stage 1 verdict ({', '.join(f'{g} {groups.splits.count(g)}' for g in present)})\n")
        print(expert_table(groups, args.protocol, splits=present) + "\n\n"
              + comparison_table(group_diffs, title="new against old"))  # fmt: skip
        out["experts"][expert] = {
            "objects": len(pair.object_ids),
            "rates": {s or "all": split_rates(pair, args.protocol, s) for s in (*SPLITS, None)},
            "group_objects": {g: groups.splits.count(g) for g in present},
            "group_rates": {g: split_rates(groups, args.protocol, g) for g in present},
            "split_differences": [_row(d) for d in split_diffs],
            "group_differences": [_row(d) for d in group_diffs],
        }
    write_results(results, out)
    print(json.dumps({e: v["rates"]["all"] for e, v in out["experts"].items()}))


def _row(d) -> dict:
    """A difference (new minus old grasps, points) as a JSON row; ``split`` is the split or grasp group."""
    return {"split": d.split or "all", "objects": d.objects, "points": d.points, "low": d.low, "high": d.high,
            "up": d.better, "down": d.worse, "verdict": d.verdict}  # fmt: skip


if __name__ == "__main__":
    main()
