"""The observation's wrist rotation in the real engines, while the wrist turns through a half turn.

The rotation vector of a rotation whose angle passes pi jumps to the opposite vector (the same wrist, 2 pi apart in
the observation); the rotation matrix's first two columns move with the wrist. Both forms are read against the
engine's own base pose through scipy.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers_env import build_grasp_env, grasp_targets
from scipy.spatial.transform import Rotation

from ges_core.env.grasp_env import GraspTargets

START_ANGLE = np.pi - 0.3
"""The wrist starts turned this far about world z (rad), 0.3 rad short of the half turn."""
TURN = 0.5
"""Wrist action about world z per control step: 0.05 rad with the env's max_wrist_turn of 0.1."""


def _turned_in_the_air(hand) -> GraspTargets:
    """The test grasp with its pre-grasp (where the episode starts) 0.5 m above the box, turned START_ANGLE about z."""
    t = grasp_targets(hand, 1)
    pre = t.pre_wrist_pose.copy()
    pre[:, :3] = [0.0, 0.0, 0.5]
    pre[:, 3:] = Rotation.from_euler("z", START_ANGLE).as_quat(scalar_first=True)
    return GraspTargets(t.wrist_pose, t.q, pre, t.pre_q)


@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_the_wrist_rotation_observed_through_a_half_turn(sim_name: str) -> None:
    steps = {}
    for form in ("matrix", "rotvec"):
        env = build_grasp_env(sim_name, 1, targets=_turned_in_the_air, reach_steps=0, settle_steps=0,
                              wrist_rotation=form)  # fmt: skip
        try:
            env.reset_all()
            layout, action = env.obs_layout, torch.zeros(1, env.act_layout.size)
            action[0, 5] = TURN
            action[0, 6:] = env.act_layout.normalize_joints(env.grasps["pre_q"])[0]
            block, angles = [], []
            for _ in range(12):  # 0.6 rad: through the half turn
                env.apply_action(action)
                obs, _ = env.observe()
                quat = env.sim.wrist_pose()[0, 3:]
                engine = Rotation.from_quat(quat, scalar_first=True)
                rot = layout.unpack(obs, "wrist_pose")[0, 3:].double().numpy()
                want = engine.as_matrix()[:, :2].T.reshape(6) if form == "matrix" else engine.as_rotvec()
                if form == "rotvec" and np.dot(rot, want) < 0:  # at pi both signs are the rotation
                    want = -want
                np.testing.assert_allclose(rot, want, atol=2e-6)  # float32 observation of the engine's pose
                back = Rotation.from_quat(layout.wrist_quat(obs)[0].numpy(), scalar_first=True)
                assert (back.inv() * engine).magnitude() < 1e-5
                block.append(rot)
                angles.append(engine.magnitude())
        finally:
            env.sim.close()
        assert max(angles) > np.pi - 0.05 and angles[-1] < angles[int(np.argmax(angles))]  # passed the half turn
        steps[form] = np.abs(np.diff(np.array(block), axis=0)).max()
    assert steps["matrix"] < 0.1  # ~0.05 rad a step moves each column entry by at most that
    assert steps["rotvec"] > 5.0  # the jump the matrix form removes: ~2 pi at the half turn
