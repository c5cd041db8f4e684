"""``ges eval-experts``: every expert on every object of the three splits, as an objects x experts success matrix."""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from typing import TYPE_CHECKING

from ges_core.cli.args import positive_int

if TYPE_CHECKING:
    from ges_core.env.evaluate import BaselineConfig
    from ges_core.experts.choice import ExpertChoice


EPISODES = 4
"""Episodes per object and expert when ``--episodes`` is not given."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges eval-experts``."""
    p = sub.add_parser(
        "eval-experts",
        help="success of every expert on every object (train / unseen objects / unseen categories) as a matrix",
        description="Runs each --expert (and the scripted baseline) for E episodes on every selected grasp of a "
        "Stage 1 dataset, one fresh GraspEnv per object and expert, and writes the objects x experts success matrix "
        "OUT/matrix-HAND-SIM.json after every cell (a rerun with the same settings resumes; docs/experts.md). "
        "Prints success per expert and split under both protocols, with the oracle (best expert per object).",
    )
    p.add_argument("dataset", type=Path, metavar="DATASET", help="Stage 1 dataset folder (ges synth / ges demo)")
    p.add_argument(
        "--expert",
        action="append",
        default=[],
        metavar="[LABEL=]NAME[:KEY=VALUE,...]",
        help="an expert column: registry name and settings, e.g. ppo:checkpoint=runs/e1/model.pt or "
        "slow=scripted:close_steps=60 (repeatable; the scripted baseline is always added)",
    )
    add_episode_options(p)
    p.add_argument("--clusters", type=Path, metavar="PATH", help="clusters file of ges cluster (stored per object)")
    p.add_argument("--out", type=Path, metavar="DIR", help="matrix folder (default: DATASET/../experts)")
    add_run_options(p)
    add_fanout_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_eval_experts)


def add_episode_options(p: argparse.ArgumentParser) -> None:
    """The options saying which episodes an evaluation runs (``ges env baseline``, ``ges eval-experts``): hand,
    simulator, which records give grasps, which splits."""
    p.add_argument(
        "--hand",
        metavar="NAME",
        help="hand (default: the hand the given experts were made for, e.g. a PPO checkpoint's; else the dataset's "
        "only hand, else registry.yaml defaults.hand)",
    )
    p.add_argument("--sim", metavar="NAME", help="simulator of the episodes (default: registry.yaml defaults.sim)")
    p.add_argument(
        "--select",
        default="validated",
        choices=("validated", "refined", "any"),
        help="which records give grasps: validated (default), refined, or any record with a grasp",
    )
    p.add_argument("--split", action="append", metavar="SPLIT", help="only this split (repeatable; default all)")


def add_run_options(p: argparse.ArgumentParser) -> None:
    """The options of an evaluation run's settings (``ges eval-experts``, ``ges evaluate``): episodes per cell,
    ``-o`` overrides of :class:`~ges_core.env.evaluate.BaselineConfig`, randomization off."""
    p.add_argument(
        "--episodes", type=positive_int, default=None, metavar="E",
        help=f"episodes per object and expert ({EPISODES}; ges evaluate without --expert: its gate's matrix's)",
    )  # fmt: skip
    p.add_argument(
        "-o", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
        help="override a run setting (BaselineConfig), e.g. env.episode_length=150 or seed=1",
    )  # fmt: skip
    p.add_argument(
        "--no-randomization",
        action="store_true",
        help="episodes without per-episode randomization (its files are named ...-norand.json); by default the "
        "object start pose, mass, friction and observation noise are randomized (env.randomization, seeded)",
    )


def run_from_args(
    args: argparse.Namespace,
    registry,
    where: str,
    *,
    experts: list[ExpertChoice] | None = None,
    base: dict | None = None,
) -> tuple[list[ExpertChoice], BaselineConfig]:
    """(the ``--expert`` choices, or ``experts`` when given; the run's BaselineConfig) of an evaluation command's
    options (:func:`add_episode_options`, :func:`add_run_options`); unknown hand, simulator or expert names fail
    here, listing the known ones. ``base``: a success matrix's ``run`` header whose ``seed``, ``env`` and ``scene``
    the run takes instead of the defaults (``--no-randomization`` and ``-o`` still apply on top)."""
    from ges_core.config import parse_overridden
    from ges_core.env.evaluate import BaselineConfig
    from ges_core.env.grasp_source import dataset_hand
    from ges_core.experts.choice import parse_expert
    from ges_core.experts.evaluate import RANDOMIZED
    from ges_core.experts.made_for import experts_hand

    experts = [parse_expert(text) for text in args.expert] if experts is None else list(experts)
    for choice in experts:
        registry.spec("expert", choice.name)
    hand = dataset_hand(args.dataset, registry, experts_hand(registry, experts, args.hand))
    sim = args.sim or registry.default("sim")
    registry.spec("hand", hand), registry.spec("sim", sim)
    episodes = EPISODES if args.episodes is None else args.episodes
    data = {"hand": hand, "sim": sim, "envs": episodes, "selection": args.select}
    data |= {"splits": tuple(args.split)} if args.split else {}
    if base is None:
        data["env"] = {"randomization": {"enabled": False} if args.no_randomization else RANDOMIZED}
    else:
        data |= copy.deepcopy({key: base[key] for key in ("seed", "env", "scene") if key in base})
        if args.no_randomization:
            data.setdefault("env", {}).setdefault("randomization", {})["enabled"] = False
    return experts, parse_overridden(BaselineConfig, data, args.overrides, where=where)


def randomization_text(config: BaselineConfig) -> str:
    """How the run's episodes are randomized, for the header line a command prints."""
    from ges_core.experts.evaluate import is_randomized

    return "randomized start pose, mass, friction, obs noise" if is_randomized(config) else "randomization off"


def add_fanout_options(parser: argparse.ArgumentParser) -> None:
    """``--workers``, ``--executor`` and ``--address`` (ges_core.executors) for an evaluation command."""
    from ges_core.executors import add_executor_options

    parser.add_argument(
        "--workers", type=positive_int, default=1, metavar="N", help="worker processes, one object at a time each (1)"
    )
    add_executor_options(parser)


def fanout_from_args(args: argparse.Namespace):
    """The :class:`~ges_core.env.evaluate.fanout.Fanout` of ``--workers/--executor/--address`` and the global
    registry options (workers build their registry from them)."""
    from ges_core.env.evaluate.fanout import Fanout
    from ges_core.executors import executor_options
    from ges_core.synthesis.run.tasks import RegistrySpec

    where = executor_options(args)
    spec = RegistrySpec(args.registry, tuple(args.registry_overrides), tuple(args.no_plugin))
    return Fanout(where["executor"], args.workers, where["address"], spec)


def run_eval_experts(args: argparse.Namespace) -> int:
    """Evaluate, print both tables and the summary."""
    from ges_core.cli import registry_from_args
    from ges_core.experts.evaluate import evaluate_experts
    from ges_core.threads import set_torch_threads

    set_torch_threads()  # ges --threads / $GES_THREADS / 1 (ges_core.threads)
    registry = registry_from_args(args)
    experts, config = run_from_args(args, registry, "ges eval-experts")
    out = args.out or args.dataset.parent / "experts"
    fanout = fanout_from_args(args)
    report = evaluate_experts(
        args.dataset, config, experts, out, clusters=args.clusters, registry=registry,
        progress=not args.no_progress, fanout=fanout,
    )  # fmt: skip
    print(f"{len(report.matrix.experts)} expert(s) | hand {config.hand} | sim {config.sim} | {config.envs} "
          f"episode(s) per cell | {randomization_text(config)}\n")  # fmt: skip
    print(report.table("paper") + "\n\n" + report.table("peers"))
    for line in report.late:
        print(f"note: {line}")
    if report.matrix.baseline in report.matrix.experts and len(report.matrix.experts) > 1:
        from ges_core.experts.compare import compare_to_baseline, comparison_table

        print("\n" + comparison_table(compare_to_baseline(report.matrix)))
        print(
            "(an expert is above the baseline on a split when the whole interval is; more episodes: rerun with "
            "-o seed=1 -o env.randomization.seed=1 into another --out and pool with ges compare-experts)"
        )
    for line in report.errors[:10]:
        print(f"error: {line}")
    print(f"\n{report.summary()}")
    return 0
