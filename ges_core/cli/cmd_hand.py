"""``ges hand lint NAME|PATH`` (check a hand definition) and ``ges hand prepare NAME|PATH`` (its assets)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.errors import AssetError

HAND_HELP = "registered hand name, or a description .yaml (its URDF beside it, or --urdf)"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges hand``."""
    p = sub.add_parser("hand", help="hand tools")
    hand_sub = p.add_subparsers(dest="hand_command", metavar="ACTION", required=True)
    lint = hand_sub.add_parser(
        "lint",
        help="check a hand definition (limits, slots, tips, mimic joints, meshes, hulls, opposition, FK, ...)",
    )
    _hand_arguments(lint)
    lint.add_argument(
        "--sim", action="append", default=None, help="simulator(s) for physical checks (default: all installed)"
    )
    lint.add_argument("--skip", action="append", default=[], help="skip a check by name")
    lint.add_argument(
        "--probe", action="store_true", help="also run the physics probe of fingertip forces (a few seconds per sim)"
    )
    lint.set_defaults(func=run_lint)
    prepare = hand_sub.add_parser(
        "prepare", help="convert the hand's meshes and decompose the link meshes a convex hull gets wrong (cached)"
    )
    _hand_arguments(prepare)
    prepare.add_argument("--no-progress", action="store_true", help="no progress bar")
    prepare.set_defaults(func=run_prepare)


def _hand_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("hand", help=HAND_HELP)
    p.add_argument("--urdf", help="URDF of a hand given as a .yaml path (default: same stem, .urdf)")


def _load_hand(args: argparse.Namespace, registry):
    from ges_core.hand_files import FileHand

    path = Path(args.hand)
    if path.suffix in (".yaml", ".yml"):
        urdf = Path(args.urdf) if args.urdf else path.with_suffix(".urdf")
        return FileHand(path, urdf, strict=False)
    if args.urdf:
        raise AssetError("--urdf only applies when the hand is given as a .yaml path")
    return registry.build_hand(args.hand)


def _ref(args: argparse.Namespace) -> str:
    """How the user named the hand, repeated in fixes (``--urdf`` kept)."""
    return f"{args.hand} --urdf {args.urdf}" if args.urdf else args.hand


def run_lint(args: argparse.Namespace) -> int:
    """Print one line per problem and note; exit 1 if there is any problem (notes alone exit 0)."""
    from ges_core.cli import registry_from_args
    from ges_core.lint import lint_hand
    from ges_core.lint.runner import installed_sims

    registry = registry_from_args(args)
    hand = _load_hand(args, registry)
    names = args.sim or registry.names("sim")
    sims = installed_sims(names, {s.name: getattr(s, "requires", ()) for s in registry.specs("sim")})
    problems = lint_hand(
        hand,
        sims=sims,
        make_sim=lambda n, cfg: registry.build_sim(n, cfg),
        skip=args.skip,
        probe=args.probe,
        ref=_ref(args),
    )
    for problem in problems:
        print(problem)
    errors = [p for p in problems if not p.note]
    checked = ", ".join(sims) if sims else "no simulator"
    status = f"{len(errors)} problem(s)" if errors else "OK"
    notes = f", {len(problems) - len(errors)} note(s)" if len(problems) > len(errors) else ""
    print(f"hand '{hand.name}': {status}{notes} (physical checks in {checked})")
    return 1 if errors else 0


def run_prepare(args: argparse.Namespace) -> int:
    """Prepare the hand's assets and print what was done."""
    from ges_core.cli import registry_from_args
    from ges_core.hand_prep.prepare import prepare_hand

    hand = _load_hand(args, registry_from_args(args))
    print(prepare_hand(hand, progress=not args.no_progress).format())
    return 0
