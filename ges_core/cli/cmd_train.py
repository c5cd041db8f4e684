"""``ges train-expert``: train one PPO expert (rsl-rl's OnPolicyRunner) on a Stage 1 dataset's grasps."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import non_negative_int, positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges train-expert``."""
    p = sub.add_parser(
        "train-expert",
        help="train one PPO expert on a dataset's grasps (three-stage curriculum per cluster)",
        description="Trains one goal-conditioned PPO expert (rsl-rl OnPolicyRunner) on the Stage 1 grasps of a "
        "dataset's training objects, with the three-stage curriculum of one geometry cluster (ges cluster). "
        "Writes TensorBoard logs, checkpoints (atomic) and a summary to OUT; --resume continues from the last "
        "checkpoint. See docs/training.md.",
    )
    p.add_argument("dataset", type=Path, metavar="DATASET", help="Stage 1 dataset folder (ges synth / ges demo)")
    p.add_argument("--preset", default="tiny", help="training preset: tiny (default), small, paper (docs/training.md)")
    p.add_argument("--config", type=Path, metavar="YAML", help="a TrainConfig YAML over the preset")
    p.add_argument("--clusters", type=Path, metavar="JSON", help="cluster file (default: the one beside DATASET)")
    p.add_argument("--cluster", type=non_negative_int, metavar="K", help="the cluster this expert is for (default 0)")
    p.add_argument(
        "--hand",
        metavar="NAME",
        help="hand (default: the preset's, else the dataset's only hand, else registry.yaml defaults.hand)",
    )
    p.add_argument("--sim", metavar="NAME", help="simulator (default: the preset's, else registry.yaml defaults.sim)")
    p.add_argument("--envs", type=positive_int, metavar="N", help="parallel envs (default: the preset's)")
    p.add_argument(
        "--workers", type=positive_int, metavar="N",
        help="env worker processes the envs are split across (default 1: in this process; 2 uses both cores of "
        "a 2-core machine, same trajectories; docs/training.md 'Env workers')",
    )  # fmt: skip
    p.add_argument("--iterations", type=positive_int, metavar="N", help="PPO iterations (default: the preset's)")
    p.add_argument(
        "--eval-every", type=positive_int, metavar="N",
        help="every N iterations, evaluate the policy without action noise on the run's objects, as ges eval-experts "
        "does; writes evaluations.jsonl and checkpoints/best.pt (evaluation.*; docs/training.md)",
    )  # fmt: skip
    p.add_argument("--seed", type=non_negative_int, metavar="N", help="seed of the run (default: the preset's)")
    p.add_argument("--out", type=Path, metavar="DIR", help="run folder (default: DATASET/../experts/<name>)")
    p.add_argument("--name", metavar="NAME", help="expert name (default: expert<cluster>)")
    p.add_argument("--resume", action="store_true", help="continue from the last checkpoint in the run folder")
    p.add_argument(
        "-o", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
        help="override a TrainConfig value, e.g. action_mode=residual or env.reward.preset=tsr",
    )  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_train_cmd)


def run_train_cmd(args: argparse.Namespace) -> int:
    """Build the config, train, print the summary."""
    from ges_core.cli import registry_from_args
    from ges_core.threads import set_torch_threads
    from ges_core.training.run import train_from_args

    set_torch_threads()  # ges --threads / $GES_THREADS / 1 (ges_core.threads)
    if args.workers is not None:
        args.overrides = [*args.overrides, f"workers={args.workers}"]
    if args.eval_every is not None:
        args.overrides = [*args.overrides, f"evaluation.interval={args.eval_every}"]
    summary = train_from_args(args, registry_from_args(args))
    print(summary.table())
    return 0
