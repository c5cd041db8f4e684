"""Checks of the PyBullet backend: its own setting, and which envs blew up after stepping.

A state check returns a short description per bad env (``"pybullet env N: ... after stepping"``); the
core (:meth:`ges_core.sim.SimBackend.step`) joins them and adds :data:`BLOWUP_HINT` once, so a single
bad env reads exactly as it always has. Command arguments are checked by the core.
"""

from __future__ import annotations

import math

import numpy as np

from ges_core.errors import ConfigError

from .engine import p
from .scene import Scene

__all__ = [
    "BLOWUP_HINT",
    "MAX_JOINT_SPEED",
    "MAX_OBJECT_SPEED",
    "MAX_OBJECT_SPIN",
    "drive_problems",
    "object_problem",
    "solver_iterations_setting",
]

MAX_JOINT_SPEED = 1e3
"""rad/s (m/s for the wrist's slides): faster is an explosion (the SAPIEN backend's value). Allegro's
drives at Kp = 400, Kd = 10 close a 3 rad error at about 90 rad/s. PyBullet clamps hand joints at
100 rad/s after each step, so here this catches NaN/inf and states set between steps."""
MAX_OBJECT_SPEED = 1e2
"""m/s; a box flung by a bad grasp leaves at a few m/s, an exploding solver at thousands."""
MAX_OBJECT_SPIN = 1e3
"""rad/s, the same for rotation."""
BLOWUP_HINT = (
    "likely causes: a start pose deep inside the object or table, a time step too large for the "
    "gains, or a target far outside the joint limits. reset() or reload the scene"
)
"""What follows the per-env descriptions in the SimulationError of a blow-up."""


def drive_problems(q: np.ndarray, v: np.ndarray) -> dict[int, str]:
    """Env -> description for every env whose drive state (E, D) is non-finite or exploding; {} if none."""
    if np.abs(v).max(initial=0.0) <= MAX_JOINT_SPEED and np.isfinite(q).all():
        return {}  # the common case in two numpy calls (a NaN speed fails the comparison)
    finite = np.isfinite(q).all(axis=1) & np.isfinite(v).all(axis=1)
    bad = np.flatnonzero(~finite | (np.abs(np.nan_to_num(v)).max(axis=1) > MAX_JOINT_SPEED))
    speeds = np.abs(v).max(axis=1)
    what = [
        "hand joint state is NaN or inf" if not finite[e] else f"a hand joint moves at {speeds[e]:.3g}" for e in bad
    ]
    return {int(e): _blown(int(e), w) for e, w in zip(bad, what, strict=True)}


def object_problem(env: int, scene: Scene) -> str | None:
    """Description of env ``env``'s non-finite or exploding object state, else None (plain floats: runs every step)."""
    lin, ang = p.getBaseVelocity(scene.obj, physicsClientId=scene.cid)
    pos, _ = p.getBasePositionAndOrientation(scene.obj, physicsClientId=scene.cid)
    speed = math.sqrt(lin[0] ** 2 + lin[1] ** 2 + lin[2] ** 2)
    spin = math.sqrt(ang[0] ** 2 + ang[1] ** 2 + ang[2] ** 2)
    if speed <= MAX_OBJECT_SPEED and spin <= MAX_OBJECT_SPIN and math.isfinite(pos[0] + pos[1] + pos[2]):
        return None
    if not (math.isfinite(speed + spin) and math.isfinite(pos[0] + pos[1] + pos[2])):
        return _blown(env, "the object's pose or velocity is NaN or inf")
    return _blown(env, f"the object moves at {speed:.3g} m/s, {spin:.3g} rad/s")


def _blown(env: int, what: str) -> str:
    return f"pybullet env {env}: {what} after stepping"


def solver_iterations_setting(value: object) -> int:
    """The ``solver_iterations`` setting as an int >= 1, else a ConfigError."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ConfigError(f"pybullet: solver_iterations={value!r}; give a whole number >= 1 or leave it unset")
    return int(value)
