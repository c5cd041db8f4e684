"""``ges compare-experts MATRIX [MATRIX ...]``: each expert against the scripted baseline, with its uncertainty."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ges_core.cli.args import non_negative_int, positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges compare-experts``."""
    p = sub.add_parser(
        "compare-experts",
        help="each expert against the scripted baseline per split, with a paired bootstrap interval; pools seeds",
        description="Reads one or more success matrices of ges eval-experts (the same objects and expert columns "
        "run with other seeds, e.g. -o seed=1 -o env.randomization.seed=1, pooled into more episodes per cell) and "
        "prints the expert table of the pooled matrix, then each expert's difference to the scripted baseline per "
        "split in points with a paired bootstrap interval over objects and the objects up / down. An expert is "
        "'above' the baseline on a split only when the whole interval is above 0 (docs/experts.md). With several "
        "matrices it also scores the oracle picked on the first one on the others' episodes.",
    )
    p.add_argument(
        "matrices", type=Path, nargs="+", metavar="MATRIX",
        help="success matrix JSON (ges eval-experts); several: pooled over the columns they all have",
    )  # fmt: skip
    p.add_argument(
        "--experts", metavar="A,B,...",
        help="only these expert columns (the baseline is kept for the comparison; the held-out oracle picks among "
        "exactly these, e.g. a gate's experts)",
    )  # fmt: skip
    p.add_argument("--protocol", default="paper", choices=("paper", "peers"), help="success protocol (paper)")
    p.add_argument("--resamples", type=positive_int, default=4000, help="bootstrap resamples (4000)")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the resampling (0)")
    p.add_argument(
        "--by-grasp", nargs="?", const="", metavar="DATASET",
        help="also per Stage 1 verdict of each object's grasp (robust / validated / refined / other), from DATASET "
        "(default: the dataset the first matrix was evaluated on)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, metavar="JSON", help="also write the comparison here")
    p.set_defaults(func=run_compare_experts)


def run_compare_experts(args: argparse.Namespace) -> int:
    """Pool, print both tables, optionally write the JSON."""
    from ges_core.experts.by_grasp import GRASP_GROUPS, by_grasp_of_file
    from ges_core.experts.compare import (
        column_list,
        compare_to_baseline,
        comparison_table,
        held_out_oracle,
        held_out_oracle_table,
        pool_matrices,
        select_columns,
    )
    from ges_core.experts.matrix import load_matrix
    from ges_core.experts.table import expert_table, split_rates
    from ges_core.paths import atomic_write_text

    matrices = [load_matrix(path) for path in args.matrices]
    chosen = column_list(args.experts) if args.experts else None
    if chosen:
        matrices = [select_columns(m, [*([m.baseline] if m.baseline else []), *chosen]) for m in matrices]
    matrix = pool_matrices(matrices)
    for path, m in zip(args.matrices, matrices, strict=True):
        if left := [e for e in m.experts if e not in matrix.experts]:
            print(f"note: {path}: column(s) {', '.join(left)} not in every matrix, left out")
    if not matrix.complete:
        print(f"note: {int((matrix.episodes == 0).sum())} cell(s) have no episodes; they are left out of the "
              "comparison (an object counts only where both columns ran)\n")  # fmt: skip
    diffs = compare_to_baseline(matrix, args.protocol, resamples=args.resamples, seed=args.seed)
    print(f"{len(args.matrices)} matrix file(s) pooled: {int(matrix.episodes.sum())} episodes\n")
    print(expert_table(matrix, args.protocol) + "\n\n" + comparison_table(diffs))
    held = None
    if len(matrices) > 1:
        picks = [select_columns(m, chosen) for m in matrices] if chosen else matrices
        held = held_out_oracle(picks[0], pool_matrices(picks[1:]), args.protocol)
        print("\n" + held_out_oracle_table(held))
    grouped = None
    if args.by_grasp is not None:
        grouped = by_grasp_of_file(matrix, args.matrices[0], args.by_grasp)
        groups = tuple(g for g in GRASP_GROUPS if g in grouped.splits)
        counts = ", ".join(f"{g} {grouped.splits.count(g)}" for g in groups)
        grasp_diffs = compare_to_baseline(
            grouped, args.protocol, splits=(*groups, None), resamples=args.resamples, seed=args.seed
        )
        print(f"\nby the Stage 1 verdict of each object's grasp (objects: {counts}; docs/experts.md)\n")
        print(expert_table(grouped, args.protocol, splits=groups) + "\n\n" + comparison_table(grasp_diffs))
    if args.out:
        record = {
            "matrices": [str(p) for p in args.matrices], "protocol": args.protocol, "resamples": args.resamples,
            "seed": args.seed, "level": 0.95,
            "rows": [d.as_dict() for d in diffs],
            "held_out_oracle": [{"split": h.split or "all", "objects": h.objects, "same": h.same,
                                 "held_out": h.held_out, "other": h.other, "best_single": h.best_single,
                                 "best_label": h.best_label} for h in held or []],
        }  # fmt: skip
        if grouped is not None:
            record["by_grasp"] = {
                "groups": {g: grouped.splits.count(g) for g in groups},
                "rates": {g or "all": split_rates(grouped, args.protocol, g) for g in (*groups, None)},
                "rows": [d.as_dict() for d in grasp_diffs],
            }
        atomic_write_text(args.out, json.dumps(record, indent=1) + "\n")
        print(f"\nwrote {args.out}")
    return 0
