"""SAPIEN 3 simulator backend (CPU PhysX, headless). The engine is imported only when the backend is built."""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import SimSpec


@hookimpl
def ges_register_sims(register: Callable[[SimSpec], None]) -> None:
    """Register the ``sapien`` backend."""
    register(
        SimSpec(
            name="sapien",
            entry_point="ges_plugins.sims.sapien.backend:SapienBackend",
            requires=("sapien",),
            description="SAPIEN 3.0 with CPU PhysX, one scene per env, headless (no render device needed)",
        )
    )
