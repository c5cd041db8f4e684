"""Closing targets that make each fingertip press toward the grasp's opposing fingers.

A refined grasp is the pose where the tips *just* touch: PD targets exactly there give no grip. The
validator therefore drives the fingers to targets past the grasp. Which way past matters: pushing every
joint further along its own closing direction made the Shadow thumb (5 joints, rotation and abduction
among them) press *across* its contact, about 90 degrees off the surface normal, and the box slid away.

Here the extra angles come from the fingertip force wanted, through the Jacobian transpose:
``dq_f = Kp^-1 J_f(q)^T (force * u_f)`` for each finger f, where ``u_f`` is the unit direction from the
fingertip toward what it opposes (the thumb toward the mean of the other fingertips; every other finger
toward the thumb tip), all at the grasp pose in the hand's base frame. Quasi-statically a PD drive held
``dq`` short of its target then pushes the tip with ``force`` along ``u_f``. The whole vector is scaled
up so its largest angle is at least ``min_squeeze`` (stiff hands: the refined pose's own error is
larger than ``force / Kp``) and each angle is clipped to ``max_squeeze``; limits and couplings applied.

The same directions, reversed, open the hand for the pre-grasp (:func:`retract_joints`): each finger moves
back from its contact along ``-J_f^T u_f``, so the opened hand is the closed one a few centimetres short of
the object, rather than a fixed open pose that may sweep through it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ges_core.hand import HandDescription, HandModel
from ges_core.kinematics import shared_kinematics

__all__ = [
    "MAX_RETRACT_ANGLE",
    "MAX_SQUEEZE",
    "MIN_SQUEEZE",
    "SQUEEZE_FORCE",
    "RetractSteps",
    "press_directions",
    "press_torques",
    "retract_joints",
    "squeeze_targets",
    "tips_and_jacobians",
]

# Stage 1 validation's squeeze (ValidateConfig's defaults; the scripted expert of Stage 2 uses the same).
# 5 N per tip holds the 0.1-0.3 kg demo objects with mu = 1 and two tips. The Shadow hand (Kp = 1 N·m/rad)
# then gets 0.1-0.5 rad past the grasp; the Allegro (Kp = 400) gets the 0.05 rad floor (5 N would be
# ~1 mrad, lost in the refined pose's own error: 0.02 rad left PyBullet's fingertips off the box).
# 0.6 rad keeps a weak hand's targets within reach of the grasp (a 1.5 rad cap did not hold better).
SQUEEZE_FORCE = 5.0
"""Fingertip force the closing targets ask for, N."""
MIN_SQUEEZE = 0.05
"""Floor on the largest extra target angle, rad."""
MAX_SQUEEZE = 0.6
"""Cap on the extra target angle per joint, rad."""


# 1 rad: a finger whose Jacobian barely moves its tip along its press direction (a near-singular thumb) would
# otherwise be asked for several radians to travel the retract distance; 1 rad on one joint already moves a
# 5-10 cm finger far more than the retract distance.
MAX_RETRACT_ANGLE = 1.0
"""Cap on one joint's change when retracting a finger, rad."""


def squeeze_targets(
    hand: HandModel,
    q_grasp: np.ndarray,
    *,
    force: float,
    min_squeeze: float,
    max_squeeze: float,
    thumb_force: float | None = None,
) -> np.ndarray:
    """(K,) closing targets past ``q_grasp`` (K,) so each fingertip presses with about ``force`` N (module docs).

    thumb_force: N the thumb asks for instead of ``force`` (None: ``force``); its joints' cap ``max_squeeze`` grows
    in the same ratio, so a thumb asked for twice the force may also go twice as far past the grasp
    (:meth:`ges_core.synthesis.physics.validate.ValidateConfig.thumb_force`, which sizes it by the object's mass).
    """
    d = hand.description
    q = d.apply_couplings(np.asarray(q_grasp, dtype=np.float64))
    extra = force * press_torques(hand, q) / np.asarray(d.pd_stiffness, dtype=np.float64)
    cap = np.full(d.num_joints, float(max_squeeze))
    if thumb_force is not None and force > 0.0 and thumb_force != force:
        thumb = d.joint_index(d.finger_for_slot("thumb").joints)
        extra[thumb] *= thumb_force / force
        cap[thumb] *= thumb_force / force
    largest = float(np.abs(extra).max())
    if 0.0 < largest < min_squeeze:
        extra *= min_squeeze / largest
    return d.apply_couplings(q + np.clip(extra, -cap, cap))


def press_torques(hand: HandModel, q: np.ndarray) -> np.ndarray:
    """(K,) joint torques ``J_f(q)^T u_f`` per finger: each fingertip pushing 1 N along :func:`press_directions`.

    q: (K,) joints, couplings applied. Joints of no finger get 0. Also the joint-space direction that
    moves each fingertip toward what it opposes (``J J^T u`` has a positive component along ``u``).
    """
    d = hand.description
    tips, jac = tips_and_jacobians(hand, q)  # (F, 3), (F, 3, K)
    directions = press_directions(d, tips)
    torque = np.zeros(d.num_joints)
    for f, finger in enumerate(d.fingers):
        idx = d.joint_index(finger.joints)
        torque[idx] = jac[f][:, idx].T @ directions[f]
    return torque


def press_directions(d: HandDescription, tips: np.ndarray) -> np.ndarray:
    """(F, 3) unit directions each fingertip presses: thumb -> mean of the other tips, others -> thumb tip.

    tips: (F, 3) fingertip points in one frame, ``d.fingers`` order. A finger at its target's spot gets 0.
    """
    thumb = [f.name for f in d.fingers].index(d.finger_for_slot("thumb").name)
    others = np.delete(np.arange(len(tips)), thumb)
    aims = np.repeat(tips[thumb][None], len(tips), axis=0)
    aims[thumb] = tips[others].mean(axis=0)
    u = aims - tips
    norm = np.linalg.norm(u, axis=1, keepdims=True)
    return np.divide(u, norm, out=np.zeros_like(u), where=norm > 1e-9)


def retract_joints(
    hand: HandModel,
    q_grasp: np.ndarray,
    *,
    travel: float,
    max_angle: float = MAX_RETRACT_ANGLE,
    finger_scale: np.ndarray | None = None,
) -> np.ndarray:
    """(K,) joints with each fingertip backed off about ``travel`` m from ``q_grasp`` (K,) against its press direction.

    Per finger f, the joints move along ``-J_f^T u_f`` (:func:`press_torques`, reversed), scaled so the tip's
    first-order travel along ``-u_f`` is ``travel``; the finger's largest change is capped at ``max_angle`` rad
    (the whole finger scaled, so the direction is kept), then multiplied by ``finger_scale[f]`` ((F,) in [0, 1],
    fingers in ``description.fingers`` order; None: all 1), then joint limits and couplings are applied. Joints
    of no finger (the Shadow's wrist) keep their values. ``travel = 0`` returns ``q_grasp`` (couplings applied).
    """
    return RetractSteps.of(hand, q_grasp, travel=travel, max_angle=max_angle).joints(finger_scale)


@dataclass(frozen=True)
class RetractSteps:
    """Each finger's full retraction step from one grasp (:func:`retract_joints`), computed once (one Jacobian)
    and applied at any per-finger fraction."""

    description: HandDescription
    q: np.ndarray
    """(K,) the grasp's joints, couplings applied."""
    steps: tuple[np.ndarray | None, ...]
    """Per finger, its joints' change at the full travel (``description.joint_index(finger.joints)`` order, capped
    at ``max_angle``); None where it does not move (no travel, or a tip its joints cannot move along its press
    direction)."""

    @classmethod
    def of(
        cls, hand: HandModel, q_grasp: np.ndarray, *, travel: float, max_angle: float = MAX_RETRACT_ANGLE
    ) -> RetractSteps:
        d = hand.description
        q = d.apply_couplings(np.asarray(q_grasp, dtype=np.float64))
        tips, jac = tips_and_jacobians(hand, q)
        directions = press_directions(d, tips)
        steps = []
        for f, finger in enumerate(d.fingers):
            idx = d.joint_index(finger.joints)
            grad = jac[f][:, idx].T @ directions[f]  # joint direction that moves the tip along u_f
            speed = float(directions[f] @ (jac[f][:, idx] @ grad))  # tip travel along u_f per unit of grad, m
            if speed <= 1e-12 or travel <= 0.0:
                steps.append(None)
                continue
            step = -grad * (travel / speed)
            largest = float(np.abs(step).max())
            if largest > max_angle:
                step *= max_angle / largest
            steps.append(step)
        return cls(d, q, tuple(steps))

    def joints(self, finger_scale: np.ndarray | None = None) -> np.ndarray:
        """(K,) the grasp with each finger f moved ``finger_scale[f]`` of its step (None: all of it), then joint
        limits and couplings."""
        d, out = self.description, self.q.copy()
        limits = d.limits_array
        for f, finger in enumerate(d.fingers):
            if self.steps[f] is None:
                continue
            idx = d.joint_index(finger.joints)
            step = self.steps[f] if finger_scale is None else self.steps[f] * float(finger_scale[f])
            out[idx] = np.clip(self.q[idx] + step, limits[idx, 0], limits[idx, 1])
        return d.apply_couplings(out)


def tips_and_jacobians(hand: HandModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fingertip pads (F, 3) and their Jacobians (F, 3, K) at joints ``q`` (K,; couplings applied), hand base frame.

    Each joint's own column, couplings ignored: a follower's part of the push is overwritten when
    :meth:`HandDescription.apply_couplings` sets it from its leader. Folding the follower's column into its
    leader's (the Shadow's tendon-coupled J0 into J1) was tried and measured worse: Shadow on the 20 demo
    objects, PyBullet 15 -> 12 validated and 14 -> 8 robust, SAPIEN unchanged (16, 11).
    """
    d = hand.description
    kin = shared_kinematics(hand)
    offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
    tips, jac = kin.points_and_jacobians(torch.as_tensor(q, dtype=torch.float64)[None], list(d.tip_links), offsets)
    return tips[0].numpy(), jac[0].numpy()
