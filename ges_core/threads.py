"""How many threads torch uses in each GES process: one by default, set on purpose.

Torch starts with one intra-op thread per core. The project's torch work (batched kinematics and the
retargeting solver) is many small tensor operations, where threads buy little and cost a lot when the
cores are busy: on a loaded 2-core machine the retargeting step took 1.80 s per object with torch's
default of 2 threads against 0.17 s with one, with bit-identical records (docs/speed.md;
``benchmarks/stage1_speed.py`` measures it again). Parallel work is done by worker processes instead
(``ges synth --workers N``), each with its own thread count.

Where the count comes from, first found wins: an explicit value (``ges --threads N``,
``SynthesisConfig.threads``), the environment variable ``GES_THREADS``, :data:`DEFAULT_THREADS`.

>>> from ges_core.threads import set_torch_threads
>>> set_torch_threads()   # 1, or $GES_THREADS
1
"""

from __future__ import annotations

import os
import sys

from ges_core.errors import ConfigError

__all__ = ["DEFAULT_THREADS", "ENV_VAR", "configure_threads", "resolve_threads", "set_torch_threads"]

DEFAULT_THREADS = 1
"""Torch threads per process when nothing else is asked for (see the module docstring for why one)."""
ENV_VAR = "GES_THREADS"
"""Environment variable holding the count; the CLI sets it so that spawned worker processes inherit it."""


def resolve_threads(requested: int | None = None) -> int:
    """The torch thread count to use: ``requested``, else ``$GES_THREADS``, else :data:`DEFAULT_THREADS`.

    ConfigError when the value found is not a whole number >= 1 (it names where the value came from)."""
    if requested is not None:
        return _checked(requested, "the requested thread count")
    raw = os.environ.get(ENV_VAR, "").strip()
    if not raw:
        return DEFAULT_THREADS
    try:
        value = int(raw)
    except ValueError:
        raise ConfigError(
            f"{ENV_VAR}={raw!r} is not a whole number; set it to the torch threads per process (e.g. 1) or unset it"
        ) from None
    return _checked(value, f"{ENV_VAR}")


def _checked(value: int, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{where} must be a whole number >= 1 (torch threads per process), got {value!r}")
    return value


def configure_threads(requested: int | None = None) -> int:
    """Choose this process's torch thread count without importing torch; returns it.

    The count is exported as ``$GES_THREADS`` (spawned worker processes inherit it) and applied at once if
    torch is already imported; otherwise :func:`set_torch_threads` applies it where torch work starts."""
    n = resolve_threads(requested)
    os.environ[ENV_VAR] = str(n)
    if "torch" in sys.modules:
        set_torch_threads(n)
    return n


def set_torch_threads(requested: int | None = None) -> int:
    """Set torch's intra-op thread count of this process (:func:`resolve_threads` of ``requested``); returns it."""
    import torch

    n = resolve_threads(requested)
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n
