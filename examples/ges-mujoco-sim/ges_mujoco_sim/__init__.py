"""GES-UniGrasp plugin: registers the simulator ``mujoco`` (MuJoCo from PyPI) through the ``ges.plugins`` entry
point.

Importing this package is light: ``mujoco`` is imported when the backend is built
(:class:`ges_mujoco_sim.backend.MujocoBackend`). Select it like a built-in simulator: ``--sim mujoco``,
``registry.yaml``'s ``defaults.sim``, or ``registry.build_sim("mujoco", SceneConfig(...))``.
"""

from __future__ import annotations

from collections.abc import Callable

from ges_core import hookimpl
from ges_core.specs import SimSpec

__all__ = ["ges_register_sims"]


@hookimpl
def ges_register_sims(register: Callable[[SimSpec], None]) -> None:
    """Register the ``mujoco`` backend."""
    register(
        SimSpec(
            name="mujoco",
            entry_point="ges_mujoco_sim.backend:MujocoBackend",
            requires=("mujoco",),
            install="pip install ges-mujoco-sim (or: pip install mujoco)",
            # MuJoCo steps per scene step: fewer let fingertips tunnel into objects at 1/120 s (the measurement is
            # at backend.DEFAULT_SUBSTEPS, the class default, which this repeats so `ges info sim mujoco` shows it).
            # registry.yaml's settings.sim.mujoco overrides it.
            settings={"substeps": 8},
            description="MuJoCo on the CPU: one MjData per env, implicit PD actuators, elliptic friction cones",
        )
    )
