"""``ges list``: every registered plugin, its source, and what to install where its engine is missing."""

from __future__ import annotations

import argparse

from ges_core.registry import KINDS
from ges_core.specs import PluginSpec


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges list``."""
    p = sub.add_parser("list", help="list registered hands, simulators, experts and gates")
    p.add_argument("kind", nargs="?", choices=sorted(KINDS), help="only this kind")
    p.set_defaults(func=run)


def _available(spec: PluginSpec) -> str:
    """Empty when every module the plugin requires is installed, else what to install."""
    missing = spec.missing()
    if not missing:
        return ""
    return f"  [needs: {spec.install}]" if spec.install else f"  [missing: {', '.join(missing)}]"


def run(args: argparse.Namespace) -> int:
    """Print one line per spec, grouped by kind; then fail if a listed kind's registry.yaml default names nothing."""
    from ges_core.cli import registry_from_args

    registry = registry_from_args(args)
    kinds = [args.kind] if args.kind else list(KINDS)
    for kind in kinds:
        specs = registry.specs(kind)
        print(f"{kind}s:")
        if not specs:
            print("  (none)")
        default = getattr(registry.config.defaults, kind, None)
        for spec in specs:
            mark = "*" if spec.name == default else " "
            print(f" {mark}{spec.name:<14} {spec.description}  <{spec.source}>{_available(spec)}")
    registry.check_defaults(tuple(kinds))
    return 0
