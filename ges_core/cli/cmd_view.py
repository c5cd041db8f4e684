"""``ges view DATASET``: the grasp viewer, an interactive 3D page in the browser (viser)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import positive_int


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges view``."""
    p = sub.add_parser(
        "view",
        help="browse a grasp dataset in the browser: object, contacts, hand at grasp and pre-grasp, verdicts "
        "(needs the [view] extra: viser)",
    )
    p.add_argument("path", type=Path, metavar="DATASET", help="dataset folder (holds manifest.json)")
    p.add_argument("--port", type=_port, default=8080, help="port to serve on (default 8080; taken: the next free one)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1; 0.0.0.0: all)")
    p.add_argument("--object", metavar="ID", help="object shown first (default: the first one)")
    p.add_argument("--hand", metavar="NAME", help="hand shown first (default: the object's first hand)")
    p.add_argument(
        "--screenshot",
        type=Path,
        metavar="PNG",
        help="instead of serving: load the page in headless Chromium, write a PNG of it and exit",
    )
    p.add_argument(
        "--size", type=positive_int, nargs=2, default=(1280, 800), metavar=("W", "H"), help="--screenshot's pixels"
    )
    p.set_defaults(func=run_view)


def run_view(args: argparse.Namespace) -> int:
    """Serve the viewer until Ctrl-C, or write one screenshot."""
    from ges_core.viewer import serve, start

    initial = (args.object, args.hand) if args.object else None
    if args.hand and not args.object:
        from ges_core.errors import ConfigError

        raise ConfigError("ges view: --hand needs --object (the object to show it on)")
    options = {"host": args.host, "port": args.port, "registry": lambda: _registry(args), "initial": initial}
    if args.screenshot is None:
        serve(args.path, **options)
        return 0
    from ges_core.viewer.chromium import screenshot

    viewer = start(args.path, **options)
    try:
        screenshot(viewer.url, args.screenshot, size=tuple(args.size))
    finally:
        viewer.server.stop()
    print(f"wrote {args.screenshot} ({viewer.shown[0]}, hand {viewer.shown[1]})")
    return 0


def _port(text: str) -> int:
    """A TCP port number, 1-65535."""
    try:
        port = int(text)
    except ValueError:
        port = 0
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"a port is a whole number from 1 to 65535, got '{text}'")
    return port


def _registry(args: argparse.Namespace):
    from ges_core.cli import registry_from_args

    return registry_from_args(args)
