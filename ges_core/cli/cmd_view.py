"""``ges view DATASET``: the grasp viewer, an interactive 3D page in the browser (viser)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges view``."""
    p = sub.add_parser(
        "view",
        help="browse a grasp dataset in the browser: object, contacts, hand at grasp and pre-grasp, verdicts "
        "(needs the [view] extra: viser)",
    )
    p.add_argument("path", type=Path, metavar="DATASET", help="dataset folder (holds manifest.json)")
    p.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080; 0 = any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; 0.0.0.0 = all)")
    p.set_defaults(func=run_view)


def run_view(args: argparse.Namespace) -> int:
    """Serve the viewer until Ctrl-C."""
    from ges_core.viewer import serve

    serve(args.path, host=args.host, port=args.port, registry_factory=lambda: _registry(args))
    return 0


def _registry(args: argparse.Namespace):
    from ges_core.cli import registry_from_args

    return registry_from_args(args)
