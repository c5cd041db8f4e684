"""``ges sim check``: a short real simulation, the hand closing on a box, with contact forces printed."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges sim``."""
    p = sub.add_parser("sim", help="simulator tools")
    sim_sub = p.add_subparsers(dest="sim_command", metavar="ACTION", required=True)
    check = sim_sub.add_parser("check", help="close a hand on a box in a real simulator and print contact forces")
    check.add_argument("--hand", action="append", help="hand plugin (repeatable; default: registry.yaml)")
    check.add_argument("--sim", action="append", help="simulator plugin (repeatable; default: registry.yaml)")
    check.add_argument("--config", metavar="YAML", help="SimCheckConfig file")
    check.add_argument(
        "-o",
        "--override",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value, e.g. scene.timestep=0.005 or close_steps=120",
    )
    check.set_defaults(func=run_check)


def run_check(args: argparse.Namespace) -> int:
    """Run the check for every hand x simulator asked for; exit 1 if any fails."""
    from ges_core.cli import registry_from_args
    from ges_core.config import load_config
    from ges_core.sim_check import SimCheckConfig, run_sim_check

    config = load_config(SimCheckConfig, args.config, args.override)
    registry = registry_from_args(args)
    hands = args.hand or [config.hand or registry.default("hand")]
    sims = args.sim or [config.sim or registry.default("sim")]
    for kind, names in (("hand", hands), ("sim", sims)):  # fail on a typo before any simulation runs
        for name in names:
            registry.spec(kind, name)
    failed = 0
    for hand_name in hands:
        hand = registry.build_hand(hand_name)
        for sim_name in sims:
            with registry.build_sim(sim_name, config.scene) as sim:
                report = run_sim_check(hand, sim, config)
            print(report.format(), flush=True)
            failed += not report.ok
    return 1 if failed else 0
