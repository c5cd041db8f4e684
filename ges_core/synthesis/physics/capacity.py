"""How much weight a grasp's fingertips can hold within the hand's actuators, quasi-statically.

The perturbation trials (:mod:`ges_core.synthesis.physics.robust`) cap every hand joint at its actuator's torque
(``HandDescription.effort_limits``) and ask the grasp to lift the object at twice its mass (``mass_x2``) and at
friction 0.5 (``friction_0.5``). Whether a placement's fingertips can do that at all, however the hand closes, is a
linear program (:func:`ges_core.synthesis.contacts.lift_friction.held_weight`): contact forces inside the friction
cones, lifting the weight with no net torque, every joint's ``J^T f`` within its limit. This module sets it up for a
:class:`~ges_core.synthesis.types.Grasp`:

* the fingertip pads (each finger's tip link and ``tip_offset``) and their Jacobians come from forward kinematics at
  the grasp's joints (``ges_core.kinematics``, pytorch-kinematics), in the hand's base frame, moved into the object
  frame by the grasp's wrist pose;
* a finger touches when its pad lies within ``near`` of its slot's Stage 1 contact (``contacts``, when given) or of
  one of the object's surface samples, and pushes along that contact's normal, else the nearest sample's; fingers
  farther off are left out (they carry nothing). The contact's normal is the contact step's own, from the object's
  surface where the finger was sent; the nearest sample of a pad can lie on another face of a small or thin part
  (measured below).

It bounds what the fingertips can do. Phalanges and the palm, which the model leaves out, can add to it; the drives'
PD law and the simulators' contact solvers can fall short of it. Measured against the trials of the real scans and
the whole library (``benchmarks/stage1_capacity.py``, docs/synthesis/refine_validate.md, "What the fingertips can
hold"): trials that passed beyond the bound, Allegro / Shadow, whole library 25 / 21 % of the passes with the nearest
samples alone, 6.7 / 11 % with the slots' contacts.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np

from ges_core.arrays import checked_array
from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import ConfigError
from ges_core.hand import HandModel
from ges_core.synthesis.contacts.lift_friction import held_weight
from ges_core.synthesis.physics.squeeze import tips_and_jacobians
from ges_core.synthesis.types import Grasp
from ges_core.transforms import pose_to_matrix

__all__ = ["NEAR", "TipCapacity", "fingertip_capacity"]

NEAR = 0.02
"""m: a fingertip pad this close to a surface sample counts as touching. The pad (tip link plus ``tip_offset``) is a
reference point on the fingertip, not where its collision shape meets the object: on the real scans' refined grasps
the pads of touching fingers lie 0-17 mm off the nearest of 4096 surface samples (both built-in hands), and the
validation's squeeze then drives every finger toward the object."""


@dataclass(frozen=True)
class TipCapacity:
    """What :func:`fingertip_capacity` found for one grasp and friction coefficient."""

    weight: float
    """Largest weight the touching fingertips hold within the drive limits, N (0: none; inf: no limit binds)."""
    fingers: tuple[str, ...]
    """The fingers whose pads touch the surface (``HandDescription.fingers`` order)."""

    def ratio(self, mass: float, gravity: float) -> float:
        """:attr:`weight` over the weight of ``mass`` kg under ``gravity`` m/s^2 (its magnitude; the scene's
        ``SceneConfig.gravity``): 2 or more passes a ``mass_x2`` trial's bound."""
        return self.weight / (mass * gravity)


def fingertip_capacity(
    hand: HandModel,
    grasp: Grasp,
    points: np.ndarray,
    normals: np.ndarray,
    mu: float,
    *,
    center: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    near: float = NEAR,
    contacts: ContactSet | None = None,
    fingers: Collection[str] | None = None,
) -> TipCapacity:
    """The weight ``grasp``'s fingertips can hold at friction ``mu`` within ``hand``'s effort limits (module docs).

    points, normals: (N, 3) the object's surface samples and outward unit normals, object frame (the grasp's), metres;
    center: (3,) the object's centre of mass there (a library object's lies above the origin: only its horizontal
    part matters for a vertical weight); contacts: the grasp's Stage 1 contacts (a record's ``contacts``), whose slot
    contact, when within ``near`` of a finger's pad, gives that finger's normal (the pad stays the point of force);
    fingers: only these may count as touching (e.g. those a simulated close left pressing the object,
    :func:`ges_core.synthesis.physics.validate.pressing_fingers`); None: every finger. A hand that declares no effort
    limits is a ConfigError: there is no bound.
    """
    d = hand.description
    effort = d.effort_limits_array
    if effort is None:
        raise ConfigError(f"hand '{d.name}' declares no effort_limits: the fingertips' capacity has no bound")
    pts = checked_array(points, (None, 3), "fingertip_capacity: points", layout="object frame, metres")
    nrm = checked_array(normals, (len(pts), 3), "fingertip_capacity: normals", layout="outward, one per point")
    tips, jac = _pads_in_object_frame(hand, grasp)
    gaps = np.linalg.norm(pts[None, :, :] - tips[:, None, :], axis=2)  # (F, N)
    nearest = gaps.argmin(axis=1)
    touching, pushes = [], []
    for f, finger in enumerate(d.fingers):
        if fingers is not None and finger.name not in fingers:
            continue
        slot = FINGER_SLOTS.index(finger.slot)
        if contacts is not None and np.linalg.norm(contacts.positions[slot] - tips[f]) <= near:
            touching.append(f)
            pushes.append(contacts.normals[slot])
        elif gaps[f, nearest[f]] <= near:
            touching.append(f)
            pushes.append(nrm[nearest[f]])
    fingers = tuple(d.fingers[f].name for f in touching)
    if len(touching) < 2:
        return TipCapacity(0.0, fingers)
    joints = [np.asarray(d.joint_index(d.fingers[f].joints)) for f in touching]
    weight = held_weight(
        tips[touching], np.asarray(pushes), mu, np.asarray(center, dtype=np.float64), jac[touching], joints, effort
    )
    return TipCapacity(weight, fingers)


def _pads_in_object_frame(hand: HandModel, grasp: Grasp) -> tuple[np.ndarray, np.ndarray]:
    """Fingertip pads (F, 3) and their Jacobians (F, 3, K) at ``grasp``, object frame."""
    q = hand.description.apply_couplings(np.asarray(grasp.q, dtype=np.float64))
    tips, jac = tips_and_jacobians(hand, q)  # hand base frame
    wrist = pose_to_matrix(np.asarray(grasp.wrist_pose, dtype=np.float64))
    rot, shift = wrist[:3, :3], wrist[:3, 3]
    return tips @ rot.T + shift, np.einsum("ij,fjk->fik", rot, jac)
