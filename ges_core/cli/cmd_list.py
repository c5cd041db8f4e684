"""``ges list``: every registered plugin, its source and whether its engine is importable."""

from __future__ import annotations

import argparse
import importlib.util

from ges_core.registry import KINDS


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges list``."""
    p = sub.add_parser("list", help="list registered hands, simulators, experts and gates")
    p.add_argument("kind", nargs="?", choices=sorted(KINDS), help="only this kind")
    p.set_defaults(func=run)


def _available(spec) -> str:
    missing = [m for m in getattr(spec, "requires", ()) if importlib.util.find_spec(m) is None]
    return f"  [missing: {', '.join(missing)}]" if missing else ""


def run(args: argparse.Namespace) -> int:
    """Print one line per spec, grouped by kind."""
    from ges_core.cli import registry_from_args

    registry = registry_from_args(args)
    for kind in [args.kind] if args.kind else list(KINDS):
        specs = registry.specs(kind)
        print(f"{kind}s:")
        if not specs:
            print("  (none)")
        default = getattr(registry.config.defaults, kind, None)
        for spec in specs:
            mark = "*" if spec.name == default else " "
            print(f" {mark}{spec.name:<14} {spec.description}  <{spec.source}>{_available(spec)}")
    return 0
