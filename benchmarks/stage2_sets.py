"""Stage 2 on the sets users bring: each expert's success per split and per Stage 1 verdict, one row per set and hand.

Reads success matrices of ``ges eval-experts`` (one per evaluation seed; several are pooled over the columns they
all hold) and prints one table: per (set, hand, engine) and expert column, the paper-protocol success on train,
unseen objects, unseen categories and all objects, and on the objects whose Stage 1 grasp was robust, validated
only, or failed its nominal trial (:mod:`ges_core.experts.by_grasp`). Where a learned column sits beside the
scripted one, the difference over all objects with its paired bootstrap interval
(:func:`ges_core.experts.compare.compare_to_baseline`).

    python benchmarks/stage2_sets.py --set real/allegro=runs/real_v2_eval/matrix-allegro-sapien.json \\
        --set demo/allegro=runs/demo_eval/matrix-allegro-sapien.json,runs/demo_eval1/matrix-allegro-sapien.json

``--set LABEL=M1[,M2...]``: a row label and its matrices. Writes ``benchmarks/results/stage2_sets.json``
(``--results NAME`` for another file name).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ges_core.experts.by_grasp import GRASP_GROUPS, by_grasp_of_file
from ges_core.experts.compare import compare_to_baseline, pool_matrices
from ges_core.experts.matrix import load_matrix, read_matrix_json
from ges_core.experts.table import split_rates
from ges_core.objects.splits import SPLITS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import code_state, results_path, write_results  # noqa: E402

PROTOCOL = "paper"


def measure_set(label: str, paths: list[Path]) -> dict:
    """Pooled rates per expert, split and grasp verdict of one set's matrices; the learned columns' differences."""
    matrix = pool_matrices([load_matrix(p) for p in paths])
    data = read_matrix_json(paths[0])
    grouped = by_grasp_of_file(matrix, paths[0])
    groups = [g for g in GRASP_GROUPS if g in grouped.splits]
    rates = {s or "all": split_rates(matrix, PROTOCOL, s) for s in (*SPLITS, None)}
    verdicts = {g: split_rates(grouped, PROTOCOL, g) for g in groups}
    diffs = compare_to_baseline(matrix, PROTOCOL, splits=(None,))  # over all objects, the column the table shows
    return {
        "label": label, "matrices": [str(p) for p in paths], "hand": data["run"]["hand"], "sim": data["run"]["sim"],
        "dataset": data["dataset"], "experts": list(matrix.experts), "baseline": matrix.baseline,
        "objects": {s or "all": int(matrix.rows(s).sum()) for s in (*SPLITS, None)},
        "grasp_groups": {g: grouped.splits.count(g) for g in groups},
        "episodes": int(matrix.episodes.sum()), "rates": rates, "by_grasp": verdicts,
        "against_baseline": [d.as_dict() for d in diffs],
    }  # fmt: skip


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}"


def table(rows: list[dict]) -> str:
    """Markdown: one line per (set, expert)."""
    lines = [
        "| set | expert | seeds | train | unseen obj | unseen cat | all | robust grasps | validated only | "
        "nominal failed | vs script (all) |",
        "|---" * 11 + "|",
    ]
    for row in rows:
        for expert in row["experts"]:
            r = {k: v.get(expert) for k, v in row["rates"].items()}
            g = {k: v.get(expert) for k, v in row["by_grasp"].items()}
            diff = next((d for d in row["against_baseline"] if d["expert"] == expert), None)
            versus = "" if diff is None else f"{diff['points']:+.1f} [{diff['low']:+.1f}, {diff['high']:+.1f}]"
            lines.append(
                f"| {row['label']} | {expert} | {len(row['matrices'])} | {_pct(r['train'])} | "
                f"{_pct(r['unseen_object'])} | {_pct(r['unseen_category'])} | {_pct(r['all'])} | "
                f"{_pct(g.get('robust'))} | {_pct(g.get('validated'))} | {_pct(g.get('refined'))} | {versus} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", action="append", required=True, metavar="LABEL=M1[,M2...]", help="a row")
    parser.add_argument("--results", default="stage2_sets", help="results file name (no .json)")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the matrices
    rows = []
    for item in args.set:
        label, _, paths = item.partition("=")
        if not paths:
            parser.error(f"--set {item}: give LABEL=MATRIX[,MATRIX...]")
        rows.append(measure_set(label, [Path(p) for p in paths.split(",")]))
    print(table(rows))
    print(f"\nsuccess: {PROTOCOL} protocol, % of episodes; objects per row and grasp group in the JSON")
    write_results(results, {"benchmark": "stage2_sets", "protocol": PROTOCOL,
                            "rows": rows, "code": code_state()})  # fmt: skip


if __name__ == "__main__":
    main()
