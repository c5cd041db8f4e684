"""Residual action mode (as ResDex builds on a base policy): action = base expert's action + scale x the policy's.

:class:`ResidualVecEnv` wraps a :class:`~ges_core.env.vec_env.GraspVecEnv`: each step it adds the policy's
residual (scaled) to the base expert's action for the current observation, clamps to [-1, 1] and steps the env;
the observation carries the base action as its own group ``"base_action"`` (n, K + 6), which the residual policy
reads beside ``"policy"``. A NaN residual stays NaN through the sum and the clamp, so the env ends that episode
``unstable`` as for any NaN action. The base expert is told about every finished episode (``reset(env_ids)``)
before it sees the first observation of the next.

Start the policy *at* the base expert (zero output layer, small noise): Gaussian noise of std 0.05 on the
scripted expert's finger actions took it from 32/32 to 0/32 held grasps (docs/platform-notes, 2026-12-01).
"""

from __future__ import annotations

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from ges_core.env.vec_env import GraspVecEnv
from ges_core.policy import Expert

__all__ = ["BASE_GROUP", "ResidualVecEnv", "residual_action"]

BASE_GROUP = "base_action"
"""Observation group holding the base expert's action (n, K + 6)."""


def residual_action(base: torch.Tensor, residual: torch.Tensor, scale: float) -> torch.Tensor:
    """(n, A) clamp(base + scale x residual, -1, 1); NaN in ``residual`` stays NaN (the env ends that episode)."""
    return torch.clamp(base + scale * residual.to(base.dtype), -1.0, 1.0)


class ResidualVecEnv(VecEnv):
    """A GraspVecEnv whose actions are residuals on ``base``'s actions (module docs)."""

    def __init__(self, venv: GraspVecEnv, base: Expert, scale: float) -> None:
        self.venv, self.base, self.scale = venv, base, float(scale)
        self.env = venv.env
        self.num_envs, self.num_actions = venv.num_envs, venv.num_actions
        self.max_episode_length, self.device, self.cfg = venv.max_episode_length, venv.device, venv.cfg
        base.reset()
        self._base = base.act(venv.get_observations()["policy"]).to(torch.float32)

    @property
    def episode_length_buf(self) -> torch.Tensor:
        return self.venv.episode_length_buf

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        self.venv.episode_length_buf = value

    @property
    def fault_counts(self) -> dict[str, int]:
        return self.venv.fault_counts

    def get_observations(self) -> TensorDict:
        """{"policy": (n, obs size), "base_action": (n, K + 6)} float32."""
        td = self.venv.get_observations()
        td[BASE_GROUP] = self._base
        return td

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Step with base + scale x ``actions`` (n, K + 6); the returned observation holds the next base action."""
        td, reward, done, extras = self.venv.step(residual_action(self._base, actions, self.scale))
        ended = done.nonzero().flatten()
        if len(ended):
            self.base.reset(ended)
        self._base = self.base.act(td["policy"]).to(torch.float32)
        td[BASE_GROUP] = self._base
        return td, reward, done, extras

    def close(self) -> None:
        self.venv.close()
