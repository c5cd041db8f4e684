"""A gymnasium ``Env`` over a one-env :class:`~ges_core.env.grasp_env.GraspEnv`.

Observation: ``Box(-inf, inf, (obs size,), float32)`` in :class:`~ges_core.env.layout.ObservationLayout`
order; action: ``Box(-1, 1, (K + 6,), float32)`` in :class:`~ges_core.env.layout.ActionLayout` order.
``reset()`` is a full reset (stage one included, :meth:`GraspEnv.reset_all`). An episode ends
``terminated`` on success, dropped or unstable and ``truncated`` on not_lifted or timeout (the episode
limit). ``reset(seed=...)`` seeds ``self.np_random`` and restarts the environment's randomization and pool-draw
streams from ``seed`` (:meth:`GraspEnv.reseed`); without a seed they go on.

A NaN or inf in the action ends the episode ``terminated`` as ``unstable`` (reward 0, ``info["nan_action"]``
True); a non-numeric action is an ArrayError; after :meth:`GraspGymEnv.close` ``step`` and ``reset`` raise
SimulationError.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from ges_core.arrays import checked_array
from ges_core.env.grasp_env import GraspEnv
from ges_core.env.metrics import EpisodeMetrics
from ges_core.env.success import EndReason
from ges_core.errors import ConfigError

__all__ = ["GraspGymEnv"]

TERMINATED = (EndReason.SUCCESS, EndReason.DROPPED, EndReason.UNSTABLE)
"""End reasons that are a terminal state of the task."""
TRUNCATED = (EndReason.NOT_LIFTED, EndReason.TIMEOUT)
"""End reasons that only cut the episode (the length limit)."""
_ACTION = "GraspGymEnv.step: action"
"""Who and what an action error names."""


class GraspGymEnv(gym.Env[np.ndarray, np.ndarray]):
    """Grasp execution for one env, gymnasium API; build the GraspEnv on a backend with ``num_envs == 1``.

    ``info`` of every step: ``end_reason`` (EndReason name, lower case; ``"running"`` mid-episode),
    ``reward_terms`` (term -> float, before weighting), ``success_paper``, ``success_peers``,
    ``is_success`` (= ``success_paper``), ``nan_action`` (the action held NaN or inf: the episode ended
    unstable); at the episode's end also ``metrics`` (the Table 3 metrics of
    the episode, :mod:`~ges_core.env.metrics`, plus ``steps``).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, env: GraspEnv) -> None:
        if env.n != 1:
            raise ConfigError(
                f"GraspGymEnv wraps one env but the GraspEnv has {env.n}; build its backend with "
                "SceneConfig(num_envs=1), or use GraspVecEnv for batches"
            )
        self.env = env
        self.observation_space = spaces.Box(-np.inf, np.inf, (env.obs_layout.size,), np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (env.act_layout.size,), np.float32)
        self.metrics = EpisodeMetrics(1, env.groups, env.control_dt)
        self._t: int | None = None  # control steps of this episode; None: reset() not called yet
        self._ended: EndReason | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        """Full reset; returns the first observation (obs size,) float32 and an empty info dict."""
        super().reset(seed=seed)
        self.env.check_open("GraspGymEnv.reset")
        if options:
            raise ConfigError(f"GraspGymEnv.reset: unknown options {sorted(options)}; it takes none")
        if seed is not None:
            self.env.reseed(seed)
        self.env.reset_all()
        self.metrics.reset(torch.arange(1))
        self._t, self._ended = 0, None
        obs, _ = self.env.observe()
        return self._to_numpy(obs), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply ``action`` (K + 6,) in [-1, 1] (clipped); observation, reward, terminated, truncated, info."""
        a = self._checked_action(action)
        env = self.env
        unstable = env.apply_action(a.reshape(1, -1), what=_ACTION)
        self._t += 1
        obs, state = env.observe()
        reward, terms = env.reward(state)
        self.metrics.update(state["dq"], state["wrist_vel"], mask=~unstable)
        timeout = torch.tensor([self._t >= env.cfg.episode_length])
        reason = EndReason(int(env.end_reasons(state, timeout, unstable)[0]))
        terminated, truncated = reason in TERMINATED, reason in TRUNCATED
        info = self._info(reason, terms)
        info["nan_action"] = env.bad_actions is not None
        if terminated or truncated:
            self._ended = reason
            info["metrics"] = {name: float(v[0]) for name, v in self.metrics.read(torch.arange(1)).items()}
        r = 0.0 if bool(unstable[0]) else float(torch.nan_to_num(reward[0]))
        return self._to_numpy(obs), r, terminated, truncated, info

    def close(self) -> None:
        """Release the simulator; ``step`` and ``reset`` then raise SimulationError (calling twice is harmless)."""
        self.env.close()

    def _checked_action(self, action: np.ndarray) -> np.ndarray:
        """``action`` as the space's float32 array, once the env may step; NaN passes (the episode ends unstable)."""
        self.env.check_open("GraspGymEnv.step")
        if self._t is None:
            raise ConfigError("GraspGymEnv.step before reset(); call reset() first")
        if self._ended is not None:
            raise ConfigError(
                f"GraspGymEnv.step after the episode ended ({self._ended.name.lower()}); call reset() first"
            )
        layout = self.env.act_layout.describe()
        return checked_array(action, self.action_space.shape, _ACTION, layout=layout, dtype=np.float32, finite=False)

    def _info(self, reason: EndReason, terms: dict[str, torch.Tensor]) -> dict[str, Any]:
        paper = reason is EndReason.SUCCESS
        return {
            "end_reason": reason.name.lower(),
            "reward_terms": {name: float(value[0]) for name, value in terms.items()},
            "success_paper": paper,
            "success_peers": bool(self.env.tracker.peer_success[0]),
            "is_success": paper,
        }

    @staticmethod
    def _to_numpy(obs: torch.Tensor) -> np.ndarray:
        """(obs size,) float32, non-finite values zeroed as in GraspVecEnv."""
        return torch.nan_to_num(obs[0], nan=0.0, posinf=0.0, neginf=0.0).numpy().astype(np.float32, copy=True)
