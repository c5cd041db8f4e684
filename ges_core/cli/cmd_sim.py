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
    check.add_argument("--object", help="object-library id to grasp (default: a box); see `ges objects list`")
    check.add_argument("--user-dir", help="user object folder, for --object user/...")
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
    from ges_core.graspability import check_graspable
    from ges_core.hand_settings import hand_sim_check_config
    from ges_core.sim_check import SimCheckConfig, build_check_object, run_sim_check

    overrides = [*args.override]
    overrides += [f"object={args.object}"] if args.object else []
    overrides += [f"user_dir={args.user_dir}"] if args.user_dir else []
    config = load_config(SimCheckConfig, args.config, overrides)
    registry = registry_from_args(args)
    hands = args.hand or [config.hand or registry.default("hand")]
    sims = args.sim or [config.sim or registry.default("sim")]
    for kind, names in (("hand", hands), ("sim", sims)):  # fail on a typo before any simulation runs
        for name in names:
            registry.spec(kind, name)
    obj = build_check_object(config)
    failed = 0
    for hand_name in hands:
        hand = registry.build_hand(hand_name)
        check_graspable(hand, obj)  # before any simulator starts
        hand_config = hand_sim_check_config(hand.description, config)  # the hand's own closure, unless given
        for sim_name in sims:
            with registry.build_sim(sim_name, hand_config.scene) as sim:
                report = run_sim_check(hand, sim, hand_config, obj)
            print(report.format(), flush=True)
            failed += not report.ok
    return 1 if failed else 0
