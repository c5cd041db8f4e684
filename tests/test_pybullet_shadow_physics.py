"""The PyBullet backend's joint drives on the Shadow hand's light, soft fingers (Kp = 1 N·m/rad).

A drive blocked by contact must push with its spring force ``Kp (q* - q)`` and keep still, as SAPIEN's
implicit spring-damper does. Closed-form check: in static balance the table's contact forces on the
finger beyond a joint exert, about that joint's axis, minus the drive's torque (hand gravity off, so
nothing else acts on that subtree about the axis).
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as p
import pytest

from ges_core.registry import load_registry
from ges_core.transforms import quat_to_matrix
from ges_plugins.sims.pybullet.backend import PybulletBackend

from helpers_sim import loaded_sim, open_q

pytestmark = pytest.mark.sim

_PALM_DOWN_AT_6CM = np.array([0.0, 0.0, 0.06, math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
"""Shadow base pose: R_x(90 deg) turns the palm (base -y) to face the table, fingers along world -y,
the FFJ2 axis 6 cm above the table: the index finger flexed toward 1.5 rad stops on the table (~1.1 rad)."""


def _finger_torque_about(scene, ids, joint_link: str, links: list[str]) -> float:
    """Torque (N m) of the table's contact forces on ``links`` about the axis of the joint moving ``joint_link``."""
    state = p.getLinkState(scene.hand, ids[joint_link], physicsClientId=scene.cid)
    axis = quat_to_matrix(np.r_[state[5][3], state[5][:3]]) @ np.array(
        p.getJointInfo(scene.hand, ids[joint_link], physicsClientId=scene.cid)[13]
    )
    chosen = {ids[name] for name in links}
    torque = np.zeros(3)
    for c in p.getContactPoints(bodyA=scene.hand, bodyB=scene.table, physicsClientId=scene.cid):
        if c[3] in chosen:
            force = c[9] * np.array(c[7]) + c[10] * np.array(c[11]) + c[12] * np.array(c[13])
            torque += np.cross(np.array(c[5]) - np.array(state[4]), force)
    return float(torque @ axis)


def test_a_soft_shadow_finger_pressed_on_the_table_keeps_still_and_pushes_with_the_spring_force():
    """Shadow FFJ2 (Kp = 1, Kd = 0.1) driven into the table: over the last 50 of 150 steps the joint is
    at rest and the table's torque about FFJ2 balances ``Kp (q* - q)`` within 2 %.

    Before the force limit dropped its explicit damping term (``drive.py``) the finger chattered
    (period-two ringing, joint speed 0.57 rad/s rms while blocked) and the Shadow's fingertip grasps
    slipped out of the hand in PyBullet validation.
    """
    hand = load_registry().build_hand("shadow")
    d = hand.description
    sim = loaded_sim(PybulletBackend, hand, floating=False, self_collision=True, solver_iterations=100)
    sim.set_hand_state(open_q(hand), _PALM_DOWN_AT_6CM[None])
    k = d.joint_names.index("FFJ2")
    target = open_q(hand)
    target[0, k] = 1.5
    sim.set_joint_targets(target)
    speeds, balance = [], []
    scene, ids = sim._scenes[0], sim._layout.link_ids
    for step in range(150):
        sim.step()
        if step >= 100:
            q, v = sim.joint_state()
            spring = d.pd_stiffness[k] * (target[0, k] - q[0, k])
            torque = _finger_torque_about(scene, ids, "ffproximal", ["ffproximal", "ffmiddle", "ffdistal"])
            speeds.append(v[0, k])
            balance.append(-torque / spring)
    sim.close()
    assert 0.5 < q[0, k] < 1.4  # stopped by the table, short of the target
    assert np.sqrt(np.mean(np.square(speeds))) < 0.05  # rad/s
    assert np.mean(balance) == pytest.approx(1.0, abs=0.02)
