"""State checks of the SAPIEN backend: which envs blew up, and what probably caused it.

:func:`state_problem` describes one env's bad state (``"sapien env N: ..."``) or returns None; the core
(:meth:`ges_core.sim.SimBackend.step`) joins the descriptions and adds :data:`BLOWUP_HINT` once, so a
single bad env reads exactly as it always has.
"""

from __future__ import annotations

import numpy as np

from ges_plugins.sims.sapien.engine import sapien

__all__ = ["BLOWUP_HINT", "MAX_JOINT_SPEED", "MAX_OBJECT_SPEED", "state_problem"]

MAX_JOINT_SPEED = 1.0e3
"""rad/s or m/s. Above this a joint velocity counts as exploding. PhysX caps joint speed at 100
(``joint.max_velocity``; a wrist target jumped by 0.3 m reaches it), so only a broken state passes
1e3: overflowing drive forces showed 1e25, and NaN fails the check too."""

MAX_OBJECT_SPEED = 1.0e2
"""m/s. Above this the object counts as exploding: a box dropped from 30 cm and struck by a
snapping hand peaked at 2.2 m/s; 100 leaves room for throws and still catches blow-ups."""

BLOWUP_HINT = (
    "the state blew up. Likely causes: absurd or huge PD targets, gains too stiff for the timestep, "
    "or deep interpenetration after a teleport; fix the command, lower the gains or the timestep, or "
    "start collision-free"
)
"""What follows the per-env descriptions in the SimulationError of a blow-up."""


def state_problem(
    env_id: int,
    hand: sapien.physx.PhysxArticulation | None,
    obj_body: sapien.physx.PhysxRigidDynamicComponent | None,
) -> str | None:
    """Description of env ``env_id``'s non-finite or exploding velocities (hand first), else None."""
    if hand is not None:
        qvel = hand.get_qvel()
        if not -MAX_JOINT_SPEED < qvel.min() <= qvel.max() < MAX_JOINT_SPEED:  # NaN fails every comparison
            worst = int(np.argmax(np.where(np.isfinite(qvel), np.abs(qvel), np.inf)))
            joint = hand.get_active_joints()[worst].name
            return _explosion(env_id, f"hand joint '{joint}'", qvel[worst], MAX_JOINT_SPEED)
    if obj_body is not None:
        vel = obj_body.get_linear_velocity()
        if not -MAX_OBJECT_SPEED < vel.min() <= vel.max() < MAX_OBJECT_SPEED:
            return _explosion(env_id, "object", float(np.linalg.norm(vel)), MAX_OBJECT_SPEED)
    return None


def _explosion(env_id: int, who: str, speed: float, limit: float) -> str:
    kind = "non-finite" if not np.isfinite(speed) else "exploding"
    return f"sapien env {env_id}: {kind} {who} velocity ({abs(speed):.3g}, limit {limit:g} in SI units)"
