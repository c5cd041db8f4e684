"""``ges hand lint NAME|PATH``: check a hand definition before use."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.errors import AssetError


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges hand``."""
    p = sub.add_parser("hand", help="hand tools")
    hand_sub = p.add_subparsers(dest="hand_command", metavar="ACTION", required=True)
    lint = hand_sub.add_parser(
        "lint", help="check a hand definition (limits, slots, tips, wrist frame, collisions, FK)"
    )
    lint.add_argument("hand", help="registered hand name, or a description .yaml (its URDF beside it, or --urdf)")
    lint.add_argument("--urdf", help="URDF of a hand given as a .yaml path (default: same stem, .urdf)")
    lint.add_argument(
        "--sim", action="append", default=None, help="simulator(s) for physical checks (default: all installed)"
    )
    lint.add_argument("--skip", action="append", default=[], help="skip a check by name")
    lint.set_defaults(func=run_lint)


def _load_hand(args: argparse.Namespace, registry):
    from ges_core.hand_files import FileHand

    path = Path(args.hand)
    if path.suffix in (".yaml", ".yml"):
        urdf = Path(args.urdf) if args.urdf else path.with_suffix(".urdf")
        return FileHand(path, urdf, strict=False)
    if args.urdf:
        raise AssetError("--urdf only applies when the hand is given as a .yaml path")
    return registry.build_hand(args.hand)


def run_lint(args: argparse.Namespace) -> int:
    """Print one line per problem; exit 1 if there is any."""
    from ges_core.cli import registry_from_args
    from ges_core.lint import lint_hand
    from ges_core.lint.runner import installed_sims

    registry = registry_from_args(args)
    hand = _load_hand(args, registry)
    names = args.sim or registry.names("sim")
    sims = installed_sims(names, {s.name: getattr(s, "requires", ()) for s in registry.specs("sim")})
    problems = lint_hand(hand, sims=sims, make_sim=lambda n, cfg: registry.build_sim(n, cfg), skip=args.skip)
    for problem in problems:
        print(problem)
    checked = ", ".join(sims) if sims else "no simulator"
    status = f"{len(problems)} problem(s)" if problems else "OK"
    print(f"hand '{hand.name}': {status} (physical checks in {checked})")
    return 1 if problems else 0
