"""The prior ablation (Init/NoInit x Goal/NoGoal) on the real simulators (Allegro, a box)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers_env import build_grasp_env
from scipy.spatial.transform import Rotation

from ges_core.env.grasp_env import PRIOR_PRESETS, EnvConfig, prior_preset
from ges_core.env.layout import GOAL_BLOCKS
from ges_core.errors import ConfigError
from ges_plugins.experts.scripted.expert import ScriptedExpert

pytestmark = pytest.mark.sim


def test_prior_presets_are_the_four_combinations() -> None:
    combos = {(c["init_prior"], c["goal_prior"]) for c in PRIOR_PRESETS.values()}
    assert combos == {(True, True), (True, False), (False, True), (False, False)}
    cfg = EnvConfig().model_copy(update=prior_preset("noinit_nogoal"))
    assert (cfg.init_prior, cfg.goal_prior) == (False, False)
    assert EnvConfig(**prior_preset("init_goal")) == EnvConfig()
    with pytest.raises(ConfigError, match="unknown prior preset 'noinit'; choose one of init_goal, init_nogoal"):
        prior_preset("noinit")


@pytest.mark.parametrize("sim_name", ["sapien", "pybullet"])
def test_noinit_starts_with_the_open_hand_above_the_object(sim_name: str) -> None:
    env = build_grasp_env(sim_name, 2, **prior_preset("noinit_goal"), settle_steps=5)
    env.reset_all()
    d = env.hand.description
    q, _ = env.sim.joint_state()
    wrist_link = env.sim.link_poses([d.wrist.link])[:, 0]  # the engine's own FK, not ours
    wrist = env.sim.wrist_pose()
    obj = env.sim.object_pose()
    obs, _ = env.observe()
    env.sim.close()
    assert np.allclose(q, np.asarray(d.open_pose), atol=0.02)
    assert np.allclose(wrist_link[:, :3], obj[:, :3] + [0.0, 0.0, env.cfg.noinit_height], atol=0.005)
    palm = Rotation.from_quat(wrist_link[:, [4, 5, 6, 3]]).apply(np.asarray(d.wrist.palm_normal))
    assert np.allclose(palm, [0.0, 0.0, -1.0], atol=0.01)  # palm down
    # away from the grasp: the policy has to reach (the pre-grasp's base is ~0.16 m lower)
    assert (np.linalg.norm(wrist[:, :3] - env.grasps["pre_wrist_pose"][:, :3].numpy(), axis=1) > 0.1).all()
    goal_pos = env.obs_layout.unpack(obs, "goal_pos").numpy()
    assert np.allclose(goal_pos, env.grasps["wrist_pose"][:, :3].numpy() - wrist[:, :3], atol=1e-5)


def test_nogoal_observation_drops_the_goal_blocks_only() -> None:
    envs = {
        name: build_grasp_env("sapien", 2, **prior_preset(name), reach_steps=5, settle_steps=2)
        for name in ("init_goal", "init_nogoal")
    }
    obs = {}
    for name, env in envs.items():
        env.reset_all()
        obs[name] = env.observe()[0]
        env.sim.close()
    full, small = envs["init_goal"].obs_layout, envs["init_nogoal"].obs_layout
    assert small.size == full.size - (6 + full.num_joints) and obs["init_nogoal"].shape == (2, small.size)
    assert not set(GOAL_BLOCKS) & set(small.slices)
    kept = torch.cat([obs["init_goal"][:, s] for name, s in full.slices.items() if name not in GOAL_BLOCKS], dim=1)
    assert torch.equal(kept, obs["init_nogoal"])  # same deterministic scene: every other block is unchanged
    expert = ScriptedExpert(small, envs["init_nogoal"].act_layout)
    with pytest.raises(ConfigError, match=r"block 'goal_q' is not in this layout \(a NoGoal layout"):
        expert.act(obs["init_nogoal"])
