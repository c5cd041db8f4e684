"""``ges hard-cases MATRIX``: the training objects whose two best experts both fail often (the hard-case set)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ges_core.cli.args import unit_fraction


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges hard-cases``."""
    p = sub.add_parser(
        "hard-cases",
        help="the training objects whose two best experts both stay under a success threshold (hard-case expert)",
        description="Reads an objects x experts success matrix (ges eval-experts), takes each training object's two "
        "best expert columns (the scripted baseline left out unless --with-baseline) and lists the objects where "
        "both stay under --threshold, as the paper picks its hard-case expert's objects. Prints the ges train-expert "
        "line that trains that expert (curriculum stages 1-2); --out writes the set as JSON.",
    )
    p.add_argument("matrix", type=Path, metavar="MATRIX", help="success matrix JSON (ges eval-experts)")
    p.add_argument(
        "--threshold", type=unit_fraction, default=0.5, help="success rate both best experts stay under (0.5)"
    )
    p.add_argument("--protocol", default="paper", choices=("paper", "peers"), help="success protocol (paper)")
    p.add_argument("--split", default="train", help="rows to consider (train, as the paper)")
    p.add_argument("--with-baseline", action="store_true", help="count the scripted baseline's column too")
    p.add_argument("--experts", metavar="A,B,...", help="count only these expert columns (default: every column "
                   "but the baseline), e.g. the cluster experts of one run in a matrix holding several")  # fmt: skip
    p.add_argument("--dataset", type=Path, metavar="DIR", help="dataset for the printed command (default: the "
                   "matrix run's dataset)")  # fmt: skip
    p.add_argument("--out", type=Path, metavar="JSON", help="write the set and its evidence here")
    p.set_defaults(func=run_hard_cases)


def run_hard_cases(args: argparse.Namespace) -> int:
    """Find the set, print the evidence and the training command."""
    from ges_core.experts.hard_cases import find_hard_cases
    from ges_core.experts.matrix import matrix_from_json, read_matrix_json
    from ges_core.paths import atomic_write_text

    data = read_matrix_json(args.matrix)
    matrix = matrix_from_json(data)
    if args.experts:
        from ges_core.experts.compare import column_list, select_columns

        chosen = column_list(args.experts)
        if args.with_baseline and matrix.baseline in matrix.experts:
            chosen = [matrix.baseline, *chosen]
        matrix = select_columns(matrix, chosen)
    hard = find_hard_cases(
        matrix, args.threshold, protocol=args.protocol, split=args.split,
        with_baseline=args.with_baseline,
    )  # fmt: skip
    print(hard.table())
    print(f"\n{len(hard.object_ids)} of {len(hard.best)} {args.split} object(s) are hard: both best of "
          f"{', '.join(hard.experts)} under {args.threshold:g} ({args.protocol} protocol)")  # fmt: skip
    if args.out:
        record = {"matrix": str(args.matrix), "threshold": hard.threshold, "protocol": hard.protocol,
                  "split": hard.split, "experts": list(hard.experts), "objects": list(hard.object_ids),
                  "best": {o: [list(b) for b in best] for o, best in hard.best.items()}}  # fmt: skip
        atomic_write_text(args.out, json.dumps(record, indent=1) + "\n")
        print(f"wrote {args.out}")
    if hard.object_ids:
        dataset = args.dataset or data.get("dataset") or "DATASET"
        config = expert_run_config(data, hard.experts)
        if config is None:
            print("\nno run folder of these experts was found beside their checkpoints: the line below trains with "
                  "the tiny preset's settings (add the experts' --config or -o settings)")  # fmt: skip
        else:
            print(f"\n--config: the training settings of expert run '{config.parent.name}' ({config}); the objects "
                  "and the curriculum stages replace its own")  # fmt: skip
        print(f"\ntrain the hard-case expert:\n  {hard.train_command(dataset, config=config)}")
    else:
        print("no hard case: no hard-case expert is needed at this threshold")
    return 0


def expert_run_config(data: dict, labels) -> Path | None:
    """The resolved ``config.yaml`` of the first of ``labels`` whose ``checkpoint`` setting lies in a
    ``ges train-expert`` run folder (``RUN/checkpoints/FILE``, ``RUN/config.yaml``), or None."""
    for label in labels:
        checkpoint = (data.get("experts", {}).get(label, {}).get("settings") or {}).get("checkpoint")
        if checkpoint:
            config = Path(checkpoint).parent.parent / "config.yaml"
            if config.is_file():
                return config
    return None
