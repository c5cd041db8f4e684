"""rsl-rl-lib ``VecEnv`` over :class:`~ges_core.env.grasp_env.GraspEnv`.

``get_observations()`` returns a TensorDict (batch ``[num_envs]``) with the group ``"policy"``;
``step(actions)`` resets finished envs itself and returns the first observation of their next
episode. ``extras["time_outs"]`` flags episodes cut by the length limit (not_lifted and timeout),
``extras["log"]`` holds the mean of every reward term and, for the episodes that ended, the rate of
each end reason, of both success protocols and the mean Table 3 metrics (``/metrics/arm_oscillation``,
``/metrics/hand_oscillation``, ``/metrics/fdc``, :mod:`~ges_core.env.metrics`); ``extras["end_reason"]``
the (n,) EndReason codes.
"""

from __future__ import annotations

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from ges_core.env.grasp_env import GraspEnv
from ges_core.env.metrics import METRIC_NAMES, EpisodeMetrics
from ges_core.env.success import EndReason

__all__ = ["GraspVecEnv"]


class GraspVecEnv(VecEnv):
    """Batched grasp execution for PPO (CPU tensors)."""

    def __init__(self, env: GraspEnv, seed: int = 0) -> None:
        self.env = env
        self.num_envs = env.n
        self.num_actions = env.act_layout.size
        self.max_episode_length = env.cfg.episode_length
        self.episode_length_buf = torch.zeros(env.n, dtype=torch.long)
        self.device = "cpu"
        self.cfg = env.cfg
        self.metrics = EpisodeMetrics(env.n, env.groups, env.control_dt)
        """Table 3 metrics of the running episodes (the step a SimulationError hit is not recorded)."""
        torch.manual_seed(seed)
        env.reset_all()
        self._obs = self._observe()[0]

    def get_observations(self) -> TensorDict:
        """Observations of the current step: {"policy": (num_envs, obs size) float32}."""
        return TensorDict({"policy": self._obs}, batch_size=[self.num_envs])

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Apply actions (num_envs, num_actions) in [-1, 1]; rewards (n,), dones (n,) long, extras."""
        env = self.env
        unstable = env.apply_action(actions.detach().cpu())
        self.episode_length_buf += 1
        obs, state = self._observe()
        reward, terms = env.reward(state)
        self.metrics.update(state["dq"], state["wrist_vel"], mask=~unstable)
        timeout = self.episode_length_buf >= self.max_episode_length
        reason = env.end_reasons(state, timeout, unstable)
        reward = torch.where(unstable, 0.0, torch.nan_to_num(reward)).to(torch.float32)
        done = reason != EndReason.RUNNING
        extras = self._extras(reason, done, terms, unstable)
        if done.any():
            ended = done.nonzero().flatten()
            env.reset_envs(ended)
            self.metrics.reset(ended)
            self.episode_length_buf[done] = 0
            fresh = self.env.observe()[0]  # reset envs: their first observation of the next episode
            obs = torch.where(done[:, None], torch.nan_to_num(fresh, nan=0.0, posinf=0.0, neginf=0.0), obs)
        self._obs = obs  # the others keep this step's observation (a second read has zero wrist velocity)
        return self.get_observations(), reward, done.long(), extras

    def _observe(self) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        obs, state = self.env.observe()
        return torch.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0), state

    def _extras(self, reason: torch.Tensor, done: torch.Tensor, terms: dict, unstable: torch.Tensor) -> dict:
        cut = (reason == EndReason.NOT_LIFTED) | (reason == EndReason.TIMEOUT)
        log = {f"/reward/{name}": torch.nan_to_num(value[~unstable]).mean() for name, value in terms.items()}
        if done.any():
            for r in EndReason:
                if r is not EndReason.RUNNING:
                    log[f"/end/{r.name.lower()}"] = (reason[done] == r).float().mean()
            log["/success/paper"] = (reason[done] == EndReason.SUCCESS).float().mean()
            log["/success/peers"] = self.env.tracker.peer_success[done].float().mean()
            metrics = self.metrics.read(done.nonzero().flatten())
            log.update({f"/metrics/{name}": metrics[name].mean() for name in METRIC_NAMES})
        return {"time_outs": cut, "log": log, "end_reason": reason.clone()}
