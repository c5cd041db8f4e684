"""The gymnasium wrapper on the real SAPIEN backend (Allegro, a box, one env)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env
from helpers_env import build_grasp_env

from ges_core.env.grasp_env import prior_preset
from ges_core.env.gym_env import GraspGymEnv
from ges_core.env.reward import TERMS
from ges_core.errors import ArrayError, ConfigError
from ges_plugins.experts.scripted.expert import ScriptedExpert

pytestmark = pytest.mark.sim

# check_env's warnings that this env earns on purpose: unbounded observations (forces, velocities)
# and no gymnasium.make spec to test other render modes with.
EXPECTED_WARNINGS = ("space minimum value is -infinity", "space maximum value is infinity", "render modes")


def _gym(**cfg) -> GraspGymEnv:
    return GraspGymEnv(build_grasp_env("sapien", 1, **cfg))


def test_check_env_passes_on_sapien() -> None:
    env = _gym(reach_steps=5, settle_steps=2, episode_length=10)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, skip_close_check=True)
    unexpected = [str(w.message) for w in caught if not any(e in str(w.message) for e in EXPECTED_WARNINGS)]
    assert unexpected == []
    assert env.observation_space.shape == (env.env.obs_layout.size,) and env.observation_space.dtype == np.float32
    assert env.action_space.shape == (16 + 6,) and env.action_space.dtype == np.float32
    env.close()
    env.close()


def test_episode_truncates_at_the_limit_with_info_and_metrics() -> None:
    env = _gym(reach_steps=5, settle_steps=2, episode_length=6)
    with pytest.raises(ConfigError, match=r"step before reset\(\)"):
        env.step(np.zeros(22, dtype=np.float32))
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape and info == {}
    w = env.env.cfg.reward
    weights = dict(zip(TERMS, (w.w_goal, w.w_reach, w.w_lift, w.w_move, w.w_smooth, w.w_consistency), strict=True))
    for t in range(1, 7):
        obs, reward, terminated, truncated, info = env.step(np.zeros(22, dtype=np.float32))
        assert set(info["reward_terms"]) == set(TERMS)
        assert reward == pytest.approx(sum(weights[k] * v for k, v in info["reward_terms"].items()), rel=1e-6)
        assert (terminated, truncated) == (False, t == 6)
    assert info["end_reason"] == "not_lifted" and info["success_paper"] is False and info["success_peers"] is False
    assert info["metrics"]["steps"] == 6 and info["metrics"]["arm_oscillation"] >= 0.0
    with pytest.raises(ConfigError, match=r"after the episode ended \(not_lifted\); call reset\(\) first"):
        env.step(np.zeros(22, dtype=np.float32))
    with pytest.raises(ConfigError, match="unknown options"):
        env.reset(options={"object": "x"})
    env.close()


def test_scripted_expert_terminates_with_success() -> None:
    env = _gym(reach_steps=60)
    obs, _ = env.reset(seed=0)
    expert = ScriptedExpert(env.env.obs_layout, env.env.act_layout)
    for _ in range(env.env.cfg.episode_length):
        action = expert.act(torch.as_tensor(obs)[None])[0].numpy()
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    assert (terminated, truncated) == (True, False)
    assert info["end_reason"] == "success" and info["success_paper"] and info["success_peers"] and info["is_success"]


def test_noinit_nogoal_preset_in_one_env() -> None:
    full = _gym(reach_steps=0, settle_steps=0)
    env = _gym(**prior_preset("noinit_nogoal"), settle_steps=2)
    assert env.observation_space.shape[0] == full.observation_space.shape[0] - (6 + 16)
    full.close()
    obs, _ = env.reset(seed=0)
    start = env.env.sim.wrist_pose()[0, :3]
    assert obs.shape == env.observation_space.shape
    assert np.allclose(start, env.env.rest_pose[0, :3] + [0.0, 0.0, env.env.cfg.noinit_height], atol=0.005)
    _, _, terminated, truncated, info = env.step(env.action_space.sample())
    assert not (terminated or truncated) and info["end_reason"] == "running"
    env.close()


def test_needs_exactly_one_env() -> None:
    inner = build_grasp_env("sapien", 2, reach_steps=0, settle_steps=0)
    with pytest.raises(ConfigError, match=r"wraps one env but the GraspEnv has 2; build its backend with"):
        GraspGymEnv(inner)
    inner.sim.close()


def test_wrong_action_shape_is_rejected() -> None:
    env = _gym(reach_steps=0, settle_steps=0)
    env.reset()
    with pytest.raises(ArrayError, match=r"GraspGymEnv.step: action has shape \(16,\), expected \(22,\)"):
        env.step(np.zeros(16, dtype=np.float32))
    env.close()
