"""``ges dataset info``, ``ges dataset validate`` and ``ges dataset capacity``: look into a grasp dataset folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import positive_float


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges dataset {info,validate,capacity}``."""
    p = sub.add_parser("dataset", help="summarize or validate a grasp dataset folder, or bound its trials")
    dsub = p.add_subparsers(dest="dataset_command", metavar="ACTION", required=True)
    ip = dsub.add_parser(
        "info",
        help="counts, success rate, failure reasons and timing medians per step; per hand and validating "
        "simulator: validated (single trial), robust (all perturbations held), cross-engine agreement",
    )
    ip.add_argument("path", type=Path, metavar="PATH", help="dataset folder (holds manifest.json)")
    ip.set_defaults(func=run_info)
    vp = dsub.add_parser("validate", help="check every record; one line per problem, exit 1 on problems")
    vp.add_argument("path", type=Path, metavar="PATH", help="dataset folder (holds manifest.json)")
    vp.add_argument(
        "--objects",
        action="store_true",
        help="also rebuild each record's object from the dataset's library and check that the record's contacts "
        "still lie on its surface (a library change since Stage 1 would make Stage 2 refuse the record)",
    )
    vp.set_defaults(func=run_validate)
    cp = dsub.add_parser(
        "capacity",
        help="each kept grasp's drive-limited perturbation trials (limits, mass, friction) against the weight its "
        "fingertips can hold within the hand's actuator limits (a quasi-static bound): which failures no closing "
        "of those fingertips could pass",
    )
    cp.add_argument("path", type=Path, metavar="PATH", help="dataset folder (holds manifest.json)")
    cp.add_argument("--hand", action="append", metavar="NAME", help="only this hand's records (repeatable)")
    cp.add_argument(
        "--near", type=positive_float, default=None, metavar="M",
        help="a fingertip pad this close to the surface touches, m (default 0.02)",
    )  # fmt: skip
    cp.add_argument(
        "--pressing", metavar="SIM", default=None,
        help="count only the fingers that press the object at the end of the limits trial's close, run again in "
        "this simulator for every record (a finger the close leaves on another finger carries nothing; ~0.1-0.5 s "
        "per record)",
    )  # fmt: skip
    cp.set_defaults(func=run_capacity)


def run_info(args: argparse.Namespace) -> int:
    """Print the dataset summary."""
    from ges_core.dataset import open_dataset, summarize

    print(summarize(open_dataset(args.path)).format())
    return 0


def run_validate(args: argparse.Namespace) -> int:
    """Print every problem; 0 when there is none."""
    from ges_core.dataset import open_dataset, validate_dataset

    problems = validate_dataset(args.path)
    if args.objects and not problems:  # a damaged dataset is mended first: its records may not open
        from ges_core.env.grasp_source import object_problems

        problems = object_problems(open_dataset(args.path))
    for line in problems:
        print(line)
    if problems:
        print(f"{len(problems)} problem(s) in {args.path}")
        return 1
    checked = ", each record's contacts on its object's surface" if args.objects else ""
    print(f"{args.path}: {len(open_dataset(args.path))} records, no problems{checked}")
    return 0


def run_capacity(args: argparse.Namespace) -> int:
    """Print the per-record table and the per-hand counts (ges_core.synthesis.run.capacity)."""
    from ges_core.cli import registry_from_args
    from ges_core.synthesis.physics.capacity import NEAR
    from ges_core.synthesis.run.capacity import bound_counts, bounds_table, counts_table, trial_bounds
    from ges_core.threads import set_torch_threads

    set_torch_threads()
    registry = registry_from_args(args)
    if args.pressing is not None:
        registry.spec("sim", args.pressing)  # an unknown simulator stops here, naming the known ones
    rows = trial_bounds(
        args.path, registry, near=args.near or NEAR, hands=args.hand, pressing=args.pressing, progress=True
    )
    if not rows:
        whose = f" of hand {', '.join(args.hand)}" if args.hand else ""
        print(f"{args.path}: no record{whose} with a grasp and perturbation trials (robust validation off, or none "
              "passed its nominal trial)")  # fmt: skip
        return 0
    print(bounds_table(rows) + "\n\n" + counts_table(bound_counts(rows)))
    return 0
