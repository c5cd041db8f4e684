"""``ges env baseline``: run an expert (the scripted baseline by default) on a Stage 1 dataset's grasps."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import positive_int
from ges_core.cli.cmd_experts import add_episode_options, add_fanout_options, fanout_from_args


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges env baseline``."""
    p = sub.add_parser("env", help="Stage 2 grasp-execution environment")
    esub = p.add_subparsers(dest="env_command", metavar="ACTION", required=True)
    bp = esub.add_parser(
        "baseline",
        help="success rate of the scripted baseline expert per split (the floor learned experts must beat)",
        description="Runs an expert (default: the scripted baseline) on every selected grasp of a Stage 1 dataset, "
        "one GraspEnv per object; prints success per split under the paper's and the peers' protocols. Results are "
        "stored per object in OUT/baseline-HAND-SIM.json; a rerun with the same settings resumes. Several experts "
        "on every object, as a success matrix: ges eval-experts.",
    )
    bp.add_argument("dataset", type=Path, metavar="DATASET", help="Stage 1 dataset folder (ges synth / ges demo)")
    add_episode_options(bp)
    bp.add_argument(
        "--expert",
        default="scripted",
        metavar="NAME[:KEY=VALUE,...]",
        help="expert plugin and its settings (default: scripted; ges list / ges info expert NAME)",
    )
    bp.add_argument("--envs", type=positive_int, default=1, metavar="N", help="episodes (envs) per object (default 1)")
    bp.add_argument("--out", type=Path, metavar="DIR", help="results folder (default: DATASET/../baseline)")
    bp.add_argument(
        "-o", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
        help="override a BaselineConfig value, e.g. env.episode_length=150 or expert_settings.overshoot=0.5",
    )  # fmt: skip
    add_fanout_options(bp)
    bp.add_argument("--no-progress", action="store_true", help="no progress bar")
    bp.set_defaults(func=run_baseline_cmd)


def run_baseline_cmd(args: argparse.Namespace) -> int:
    """Evaluate, print the table and where the results are."""
    from ges_core.cli import registry_from_args
    from ges_core.config import parse_overridden
    from ges_core.env.evaluate import BaselineConfig, evaluate_baseline
    from ges_core.env.grasp_source import dataset_hand
    from ges_core.experts.choice import parse_expert
    from ges_core.experts.made_for import experts_hand
    from ges_core.threads import set_torch_threads

    set_torch_threads()  # ges --threads / $GES_THREADS / 1 (ges_core.threads)

    registry = registry_from_args(args)
    expert = parse_expert(args.expert)
    registry.spec("expert", expert.name)  # a known name before its checkpoint is read
    hand = dataset_hand(args.dataset, registry, experts_hand(registry, [expert], args.hand))
    sim = args.sim or registry.default("sim")
    registry.spec("hand", hand), registry.spec("sim", sim)  # known names
    data = {"hand": hand, "sim": sim, "envs": args.envs, "selection": args.select, "expert": expert.name}
    data |= {"expert_settings": expert.settings} | ({"splits": tuple(args.split)} if args.split else {})
    config = parse_overridden(BaselineConfig, data, args.overrides, where="ges env baseline")
    out = args.out or args.dataset.parent / "baseline"
    fanout = fanout_from_args(args)
    report = evaluate_baseline(
        args.dataset, config, out, registry=registry, progress=not args.no_progress, fanout=fanout
    )
    print(report.table())
    rejected = len(report.selection.rejected)
    print(
        f"\n{len(report.evaluated)} object(s) evaluated, {len(report.reused)} reused from {report.path}; "
        f"{rejected} record(s) left out by selection '{config.selection}'; {report.seconds:.1f} s"
    )
    return 0
