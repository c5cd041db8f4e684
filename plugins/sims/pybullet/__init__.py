"""The PyBullet simulator plugin (PyBullet 3.2.7, headless DIRECT clients, one per scene).

Importing this package is light: ``pybullet`` is imported when the backend (or its grasp-picture
renderer, :mod:`.render`) is built.
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
            install="pip install 'ges-unigrasp[pybullet]'",
            # PyBullet's solver needs ~100 iterations to hold a stiff fingertip squeeze: at the shared
            # default of 20 (SceneConfig.solver_iterations), Stage 1 validation lifted 3/9 objects with
            # Allegro, at 100 it lifted 8/9 (SAPIEN: 7/9 at 20). Costs about 1.4x per step. See
            # docs/simulators.md. registry.yaml's settings.sim.pybullet overrides it.
            # friction_anchors: the object's contacts keep their first point (PhysX-like static friction); a
            # squeezed object otherwise creeps out of the fingers (stored demo-set grasps re-validated: Ability
            # 11 -> 16 of 19, Allegro 17 -> 17, Shadow 14 -> 14; docs/simulators.md "Friction anchors").
            # "on_touch": from the hand's first touch on, so an object alone on the table rocks back instead of
            # pivoting about an anchored point (the YCB pear: 29 deg -> 1.5 deg in the resting check).
            settings={"solver_iterations": 100, "friction_anchors": "on_touch"},
            renderer="ges_plugins.sims.pybullet.render:PybulletRenderer",
            description="PyBullet 3.2.7 on the CPU: one DIRECT client per scene, SAPIEN-like implicit PD drives",
        )
    )
