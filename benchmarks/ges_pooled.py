"""GES runs of several episode seeds pooled: Table 2, GES against the best single expert and the held-out oracle.

One ``ges evaluate`` run scores GES on 4 episodes per object, where one episode moves a split's rate by 0.4-2.6
points. This pools runs of the same gates, experts and objects under other episode seeds (``--seed N`` into
another ``--out``, each with its own matrix): the episodes of each (object, expert) cell and of each gate's picks
add up, and the comparisons of ``benchmarks/ges_evaluate.py`` are made on the sums.

    python benchmarks/ges_pooled.py runs/proc/ges_shift/ges-allegro-sapien.json \\
        runs/proc/ges_shift3/ges-allegro-sapien.json --oracle-from M_SEED0 M_SEED1 --results ges_shift_pooled

``--versus A=B`` adds GES of gate A minus GES of gate B per split, paired over objects (e.g. a distilled gate against
the averaged one it imitates).

Gates are matched by label, in whatever order a run lists them; a gate not every run holds is left out (a note
names it). Each GES results file names its matrix; the gates' picks come from the results files (a gate's pick does not
depend on the episode seed when the clouds are sampled with the same seed; if they differ, the episodes of each
run's own pick are added). Writes ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.experts.compare import held_out_oracle, held_out_oracle_table, pool_matrices, select_columns
from ges_core.experts.matrix import PROTOCOLS, load_matrix
from ges_core.ges_eval.against_best import (
    against_best_json,
    ges_against_best,
    ges_against_best_table,
    ges_between,
)
from ges_core.ges_eval.results import ResultsFile, read_results_json
from ges_core.ges_eval.run import ges_row
from ges_core.ges_eval.table import GesRow, table2

from _results import code_state, results_path, write_results


def pooled_rows(runs: list[list[GesRow]]) -> list[GesRow]:
    """The rows of the gates every run holds, matched by label (in any order), episodes added; the first run's order.
    A gate some runs lack is left out (:func:`common_gates` says which)."""
    by_label = [{r.label: r for r in run} for run in runs]
    out = []
    for label in common_gates([[r.label for r in run] for run in runs]):
        same = [rows[label] for rows in by_label]
        out.append(GesRow(
            label, {p: sum(r.successes[p] for r in same) for p in PROTOCOLS}, sum(r.episodes for r in same),
            same[0].picked,
        ))  # fmt: skip
    return out


def common_gates(labels: list[list[str]]) -> list[str]:
    """The gate labels every run holds, in the first run's order; SystemExit if there is none."""
    common = [label for label in labels[0] if all(label in run for run in labels[1:])]
    if not common:
        raise SystemExit(f"the runs share no gate: {[sorted(run) for run in labels]}")
    return common


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results_files", nargs="+", type=Path, help="GES results JSON of each run (ges evaluate)")
    parser.add_argument("--oracle-from", nargs="+", type=Path, default=[], metavar="MATRIX",
                        help="matrices the gates were trained on (pooled): the oracle picked on them, scored on the "
                        "pooled runs")  # fmt: skip
    parser.add_argument("--versus", action="append", default=[], metavar="A=B",
                        help="also GES of gate A minus GES of gate B, paired over objects (repeatable)")  # fmt: skip
    parser.add_argument("--results", default="ges_pooled", help="name of the JSON under benchmarks/results/")
    args = parser.parse_args()
    results = results_path(args.results)
    pairs = [tuple(v.split("=", 1)) for v in args.versus]
    if bad := [v for v, pair in zip(args.versus, pairs, strict=True) if len(pair) != 2]:
        raise SystemExit(f"--versus takes A=B (two gate labels), got {bad}")

    datas = [read_results_json(p) for p in args.results_files]
    experts = list(datas[0]["experts"])
    for p, d in zip(args.results_files, datas, strict=True):
        if sorted(d["experts"]) != sorted(experts):
            raise SystemExit(f"{p} chooses among {list(d['experts'])}; the first run among {experts}: pool runs of "
                             "the same experts")  # fmt: skip
    common = common_gates([list(d["gates"]) for d in datas])
    for p, d in zip(args.results_files, datas, strict=True):
        if left := [label for label in d["gates"] if label not in common]:
            print(f"note: {p} also holds gates {left}, which not every run holds: left out")
    views = [select_columns(load_matrix(d["matrix"]), experts) for d in datas]
    ids = tuple(oid for oid in views[0].object_ids if all(oid in d["cells"] for d in datas))
    matrix = pool_matrices(views)  # ConfigError unless the runs' matrices hold the same objects
    rows = pooled_rows(
        [
            [ges_row(view, label, gate["picks"], ResultsFile(path, d)) for label, gate in d["gates"].items()]
            for path, d, view in zip(args.results_files, datas, views, strict=True)
        ]
    )
    missing = [r.label for r in rows if (r.episodes == 0).any()]
    if missing:
        print(f"note: gates {missing} lack GES episodes on some objects (left out of their comparisons)")
    print(f"{len(args.results_files)} runs pooled: {len(matrix.object_ids)} objects ({len(ids)} with GES cells in "
          f"every run), experts {', '.join(experts)}, gates {', '.join(r.label for r in rows)}\n")  # fmt: skip
    table = table2(matrix, tuple(experts), rows)
    for p in PROTOCOLS:
        print(table.markdown(p) + "\n")
    diffs = ges_against_best(matrix, rows, experts)
    print(ges_against_best_table(diffs))
    between = ges_between(matrix, rows, pairs) if pairs else []
    if between:
        print("\n" + ges_against_best_table(between, title="GES of one gate against another's"))
    held = []
    if args.oracle_from:
        pick = pool_matrices([select_columns(load_matrix(m), experts) for m in args.oracle_from])
        held = held_out_oracle(pick, matrix)
        print("\n" + held_out_oracle_table(held, picked="the gates' matrices", scored="the pooled runs"))
    write_results(results, {
        "runs": [str(p) for p in args.results_files], "matrices": [d["matrix"] for d in datas],
        "experts": experts, "table2": table.rows, "against_best": against_best_json(diffs),
        "versus": against_best_json(between),
        "oracle_from": [str(m) for m in args.oracle_from], "held_out_oracle": [r.__dict__ for r in held],
        "code": code_state(),
    })  # fmt: skip


if __name__ == "__main__":
    main()
