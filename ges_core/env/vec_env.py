"""rsl-rl-lib ``VecEnv`` over :class:`~ges_core.env.grasp_env.GraspEnv`.

``get_observations()`` returns a TensorDict (batch ``[num_envs]``) with the group ``"policy"``;
``step(actions)`` resets finished envs itself and returns the first observation of their next
episode. ``extras["time_outs"]`` flags episodes cut by the length limit (not_lifted and timeout),
``extras["log"]`` holds the mean of every reward term and, for the episodes that ended, the rate of
each end reason, of both success protocols and the mean Table 3 metrics (``/metrics/arm_oscillation``,
``/metrics/hand_oscillation``, ``/metrics/fdc``, :mod:`~ges_core.env.metrics`); ``extras["end_reason"]``
the (n,) EndReason codes, ``extras["peer_success"]`` (n,) bool and ``extras["max_rise"]`` (n,) metres: the
peers' protocol and the object's highest rise so far in each env's episode, read before finished envs
restart (so an ended episode's values survive its reset); ``extras["entry"]`` (n,) int64 the pool entry
each env's episode ran (:meth:`GraspEnv.from_pool`; -1 without a pool), read before the reset draws the next.
On a step where an episode ended, ``extras["episode_metrics"]`` holds each env's Table 3 metrics so far (name ->
(n,) float64, plus ``steps``), read before the reset: an ended env's entry is its whole episode's.

Faults: an env whose action row holds NaN or inf (a diverging policy) ends that step ``unstable`` with reward 0
and restarts like any finished env; the batch goes on. ``extras["log"]["/faults/nan_actions"]`` is, at every
step, the number of such envs (rsl-rl logs its mean per step over an iteration) and :attr:`GraspVecEnv.fault_counts`
keeps the running total. A wrongly shaped or non-numeric action is one ArrayError before anything is sent; after
:meth:`GraspVecEnv.close` every call is a SimulationError (rsl-rl's ``VecEnv`` declares no ``close``; this one
adds it, as gymnasium and Isaac Lab environments have).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from ges_core.env.grasp_env import GraspEnv
from ges_core.env.metrics import METRIC_NAMES, EpisodeMetrics
from ges_core.env.success import EndReason

__all__ = ["GraspVecEnv"]

_RUNNING, _NOT_LIFTED, _TIMEOUT = (int(r) for r in (EndReason.RUNNING, EndReason.NOT_LIFTED, EndReason.TIMEOUT))
"""Plain ints: numpy compares IntEnum members several times slower."""


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
        self.fault_counts = {"nan_actions": 0}
        """Running totals since construction: ``nan_actions``, env steps whose action row held NaN or inf."""
        torch.manual_seed(seed)
        env.reset_all()
        self._obs = self._observe()[0]

    def get_observations(self) -> TensorDict:
        """Observations of the current step: {"policy": (num_envs, obs size) float32}."""
        self.env.check_open("GraspVecEnv.get_observations")
        return TensorDict({"policy": self._obs}, batch_size=[self.num_envs])

    def close(self) -> None:
        """Close the environment and its backend; every later call raises SimulationError. Twice is harmless."""
        self.env.close()

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Apply actions (num_envs, num_actions) in [-1, 1]; rewards (n,), dones (n,) long, extras.

        A row holding NaN or inf ends that env ``unstable`` (:meth:`GraspEnv.apply_action`); it is counted in
        ``extras["log"]["/faults/nan_actions"]`` and :attr:`fault_counts`.

        The bookkeeping between the env's calls is numpy on views of the tensors; the only torch ops per
        step copy the tracker's peers flags and highest rises into ``extras`` before the auto-reset and make
        the fault count's log value.
        """
        env = self.env
        env.check_open("GraspVecEnv.step")
        unstable = env.apply_action(actions, what="GraspVecEnv.step: actions")
        nan_actions = 0 if env.bad_actions is None else int(env.bad_actions.sum())
        self.fault_counts["nan_actions"] += nan_actions
        bad = unstable.numpy()
        any_bad = bool(bad.any())
        steps = self.episode_length_buf.numpy()  # a view: rsl-rl may replace the tensor, never on another device
        steps += 1
        obs, state = self._observe()
        reward, terms = env.reward(state)
        self.metrics.update(state["dq"], state["wrist_vel"], mask=~bad, consistency=terms["consistency"])
        reason = env.end_reasons(state, steps >= self.max_episode_length, unstable)
        code = reason.numpy()
        done = code != _RUNNING
        any_done = bool(done.any())
        extras = self._extras(code, done if any_done else None, terms, bad if any_bad else None)
        extras["log"]["/faults/nan_actions"] = torch.tensor(float(nan_actions))
        extras["end_reason"] = reason
        extras["peer_success"] = env.tracker.peer_success.clone()  # before the reset below clears them
        extras["max_rise"] = env.tracker.max_rise.clone()
        extras["entry"] = torch.from_numpy(env.entry.copy())  # pool entry of each env's episode (-1: no pool)
        if any_done:
            ended = torch.from_numpy(done.nonzero()[0])
            extras["episode_metrics"] = self.metrics.read(torch.arange(self.num_envs))
            env.reset_envs(ended)
            self.metrics.reset(ended)
            steps[done] = 0
            fresh = self._observe(ended)[0]  # reset envs: their first observation of the next episode
            obs = torch.where(torch.from_numpy(done)[:, None], fresh, obs)
        self._obs = obs  # the others keep this step's observation (a second read has zero wrist velocity)
        rew = _clean_reward(reward.numpy(), bad if any_bad else None)
        return self.get_observations(), torch.from_numpy(rew), torch.from_numpy(done.astype(np.int64)), extras

    def _observe(self, noise_rows=None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """noise_rows: the envs whose observation is kept (None: all), the only ones drawing observation noise, so
        an env's noise stream never depends on other envs' resets (workers give the same noise as one process)."""
        obs, state = self.env.observe(noise_rows=noise_rows)
        if not math.isfinite(np.add.reduce(obs.numpy(), axis=None)):  # a finite sum: every value is finite
            obs = torch.nan_to_num(obs, nan=0.0, posinf=0.0, neginf=0.0)
        return obs, state

    def _extras(self, code: np.ndarray, done: np.ndarray | None, terms: dict, unstable: np.ndarray | None) -> dict:
        """``time_outs`` and ``log`` from the (n,) end-reason codes, the reward terms and the (n,) done and
        unstable flags (None: no env done, no env unstable)."""
        cut = (code == _NOT_LIFTED) | (code == _TIMEOUT)
        means = _stable_means(self.env.terms_array(terms), unstable)
        log = dict(zip([f"/reward/{name}" for name in terms], torch.from_numpy(means).unbind(), strict=True))
        if done is not None:
            log.update(self._episode_log(torch.from_numpy(code), torch.from_numpy(done)))
        return {"time_outs": torch.from_numpy(cut), "log": log}

    def _episode_log(self, reason: torch.Tensor, done: torch.Tensor) -> dict[str, torch.Tensor]:
        """Rates of each end reason and both protocols, and the mean Table 3 metrics, over the episodes that ended."""
        ended = reason[done]
        log = {f"/end/{r.name.lower()}": (ended == r).float().mean() for r in EndReason if r is not EndReason.RUNNING}
        log["/success/paper"] = (ended == EndReason.SUCCESS).float().mean()
        log["/success/peers"] = self.env.tracker.peer_success[done].float().mean()
        metrics = self.metrics.read(done.nonzero().flatten())
        log.update({f"/metrics/{name}": metrics[name].mean() for name in METRIC_NAMES})
        return log


def _stable_means(terms: np.ndarray, unstable: np.ndarray | None) -> np.ndarray:
    """(T,) float64: per term (rows of ``terms`` (T, n)), the mean over the envs that did not blow up.

    Non-finite values count as 0 (NaN as 0, +-inf as the largest float, as torch.nan_to_num); NaN if every
    env blew up. unstable: (n,) bool, or None when no env blew up.
    """
    if unstable is not None:
        terms = terms[:, ~unstable]
    n = terms.shape[1]
    if n == 0:
        return np.full(len(terms), np.nan)
    means = np.add.reduce(terms, axis=1) / n
    if not np.isfinite(means).all():  # a finite mean: every value was finite
        means = np.add.reduce(np.nan_to_num(terms), axis=1) / n
    return means


def _clean_reward(reward: np.ndarray, unstable: np.ndarray | None) -> np.ndarray:
    """(n,) float32 rewards: 0 where the env blew up (unstable: (n,) bool or None), non-finite values as
    torch.nan_to_num makes them."""
    if unstable is not None:
        reward = np.where(unstable, 0.0, np.nan_to_num(reward))
    elif not math.isfinite(np.add.reduce(reward)):
        reward = np.nan_to_num(reward)
    return reward.astype(np.float32)
