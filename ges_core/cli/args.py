"""Numbers on the command line: every count option of every ``ges`` command is checked here.

Each function is an argparse ``type=``; a value it refuses is argparse's usage error (exit 2, one line
``ges CMD: error: argument --limit: 0 is not a whole number >= 1``), raised before the command starts.
Values given with ``-o key=value`` are checked by the config models instead (``ConfigError``, exit 1).
"""

from __future__ import annotations

import argparse
import math

__all__ = ["non_negative_int", "positive_float", "positive_int", "unit_fraction"]


def _whole(text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or value < minimum:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number >= {minimum}")
    return value


def positive_int(text: str) -> int:
    """A count of at least one (``--limit``, ``--workers``, ``--envs``)."""
    return _whole(text, 1)


def non_negative_int(text: str) -> int:
    """A whole number of at least zero (a seed, an index)."""
    return _whole(text, 0)


def positive_float(text: str) -> float:
    """A finite number above zero (a scale, a size in metres)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number > 0")
    return value


def unit_fraction(text: str) -> float:
    """A number in (0, 1] (a success-rate threshold)."""
    value = positive_float(text)
    if value > 1.0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number in (0, 1]")
    return value
