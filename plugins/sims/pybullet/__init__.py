"""The PyBullet simulator plugin (PyBullet 3.2.7, headless DIRECT clients, one per scene).

Importing this package is light: ``pybullet`` is imported when the backend is built.
"""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import SimSpec


@hookimpl
def ges_register_sims(register: Callable[[SimSpec], None]) -> None:
    """Register the ``pybullet`` backend."""
    register(
        SimSpec(
            name="pybullet",
            entry_point="ges_plugins.sims.pybullet.backend:PybulletBackend",
            requires=("pybullet",),
            description="PyBullet 3.2.7 on the CPU: one DIRECT client per scene, SAPIEN-like implicit PD drives",
        )
    )
