"""The ``ges`` command line.

Each sub-command lives in its own module with ``add_parser(subparsers)``; the handler receives
the parsed arguments and a lazily built :class:`~ges_core.registry.Registry`. Errors derived
from :class:`~ges_core.errors.GesError` print one line and exit 1; ``--debug`` shows the traceback. An
``OSError`` that no writer turned into a :class:`~ges_core.errors.StorageError` (a file a command writes
itself, a file it cannot read) prints one line too: its cause, its path and what to do.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from ges_core.cli.args import positive_int
from ges_core.errors import GesError

__all__ = ["build_parser", "main"]

_COMMAND_MODULES = (
    "ges_core.cli.cmd_list",
    "ges_core.cli.cmd_info",
    "ges_core.cli.cmd_hand",
    "ges_core.cli.cmd_objects",
    "ges_core.cli.cmd_sim",
    "ges_core.cli.cmd_dataset",
    "ges_core.cli.cmd_synth",
    "ges_core.cli.cmd_env",
    "ges_core.cli.cmd_experts",
    "ges_core.cli.cmd_train",
    "ges_core.cli.cmd_compare",
    "ges_core.cli.cmd_hard_cases",
    "ges_core.cli.cmd_view",
    "ges_core.cli.cmd_cluster",
    "ges_core.cli.cmd_gate",
    "ges_core.cli.cmd_evaluate",
)
"""Modules that add sub-commands, in ``--help`` order."""


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser."""
    import importlib

    parser = argparse.ArgumentParser(
        prog="ges", description="GES-UniGrasp: dexterous grasping with swappable hands and simulators."
    )
    parser.add_argument("--debug", action="store_true", help="show full tracebacks")
    parser.add_argument(
        "--registry", metavar="PATH", help="registry.yaml to use (default: $GES_REGISTRY, ./registry.yaml)"
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        metavar="N",
        help="torch threads per process, workers included (default: $GES_THREADS, else 1)",
    )
    parser.add_argument("--no-plugin", action="append", default=[], metavar="NAME", help="do not load plugin NAME")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="registry_overrides",
        help="override a registry.yaml value, e.g. defaults.sim=pybullet",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in _COMMAND_MODULES:
        importlib.import_module(module_name).add_parser(sub)
    return parser


def registry_from_args(args: argparse.Namespace):
    """The registry the global options describe."""
    from ges_core.registry import load_registry

    return load_registry(args.registry, overrides=tuple(args.registry_overrides), blocked=tuple(args.no_plugin))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``ges``; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        from ges_core.threads import configure_threads

        configure_threads(args.threads)  # before any torch work; spawned workers inherit it ($GES_THREADS)
        return int(args.func(args) or 0)
    except GesError as exc:
        if args.debug:
            raise
        print(f"ges: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # `ges ... | head` closed our output: stop quietly, as other command-line tools do
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - the interpreter flushes stdout at exit
        return 141
    except OSError as exc:  # the last resort: a disk error outside the project's writers is one line too
        if args.debug:
            raise
        from ges_core.paths import describe_os_error

        print(f"ges: error: {describe_os_error(exc, doing='at')}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("ges: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
