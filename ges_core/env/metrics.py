"""The paper's Table 3 motion metrics over an episode, batched over envs (our reading; the paper gives no formulas).

Velocities are sampled once per control step (``dt`` seconds apart): ``v_t``, t = 1..T of an episode.

* **arm (wrist) oscillation** ``O_arm = Σ_{t=2..T} ‖w_t − w_{t−1}‖² / dt``, ``w_t`` the wrist's (6,) velocity
  (linear m/s, angular rad/s, world): a discrete integral of squared acceleration, ``∫‖ẇ‖² dt``.
  Units m²/s³ (linear part) plus rad²/s³ (angular part). Lower is better; 0 for any constant velocity.
* **hand oscillation** ``O_hand``: the same over the (K,) hand joint velocities, rad²/s³.
* **finger directional consistency** ``FDC = −Σ_{t=1..T} Σ_j Var_f(sign(v_{t,j,f}))``: j indexes the
  same-position joints of the non-thumb fingers f (:func:`~ges_core.env.reward.consistency_groups`),
  Var is the population variance; the per-step summand is the reward's ``r_c``. Higher is better; 0 when
  the fingers always move the same way. Dimensionless, summed over control steps.

All three are sums over the episode (the paper's magnitudes, −87.8 to −140 for FDC, cannot come from a
per-step mean, which lies in [−J, 0]); divide by ``steps`` for per-step rates. See ``docs/env.md``.
"""

from __future__ import annotations

import torch

from ges_core.env.reward import direction_variance
from ges_core.errors import ConfigError

__all__ = ["METRIC_NAMES", "EpisodeMetrics", "finger_directional_consistency", "oscillation"]

METRIC_NAMES = ("arm_oscillation", "hand_oscillation", "fdc")
"""Names of the Table 3 metrics, as read out by :meth:`EpisodeMetrics.read` and logged as ``/metrics/<name>``."""


def oscillation(vel: torch.Tensor, dt: float) -> torch.Tensor:
    """(n,) ``Σ_t ‖v_t − v_{t−1}‖² / dt`` of a whole trajectory ``vel`` (T, n, D); dt: seconds between samples."""
    return (vel[1:] - vel[:-1]).square().sum(dim=(0, 2)) / dt


def finger_directional_consistency(joint_vel: torch.Tensor, groups: torch.Tensor) -> torch.Tensor:
    """(n,) FDC ``−Σ_t Σ_j Var_f(sign(v))`` of a trajectory ``joint_vel`` (T, n, K); groups (J, P) joint indices."""
    steps, n, k = joint_vel.shape
    return -direction_variance(joint_vel.reshape(steps * n, k), groups).reshape(steps, n).sum(dim=0)


class EpisodeMetrics:
    """Running Table 3 metrics of ``num_envs`` episodes; :meth:`update` once per control step.

    groups: (J, P) same-position joint indices of the non-thumb fingers (``consistency_groups``).
    dt: seconds per control step.
    """

    def __init__(self, num_envs: int, groups: torch.Tensor, dt: float) -> None:
        if dt <= 0:
            raise ConfigError(f"EpisodeMetrics: dt = {dt} s; the control step must be > 0")
        self.groups, self.dt = groups, dt
        self.sums = {name: torch.zeros(num_envs, dtype=torch.float64) for name in METRIC_NAMES}
        """Per-env running sums of the current episodes."""
        self.steps = torch.zeros(num_envs, dtype=torch.int64)
        """(n,) velocity samples recorded this episode."""
        self._prev_joint: torch.Tensor | None = None
        self._prev_wrist: torch.Tensor | None = None

    def update(self, joint_vel: torch.Tensor, wrist_vel: torch.Tensor, mask: torch.Tensor | None = None) -> None:
        """Record one control step: joint_vel (n, K) rad/s, wrist_vel (n, 6) m/s and rad/s, world.

        mask: (n,) bool, envs to record (default all); envs whose velocities are not finite are skipped too.
        The first sample of an episode only starts the differences (no oscillation term).
        """
        jv, wv = joint_vel.to(torch.float64), wrist_vel.to(torch.float64)
        ok = torch.isfinite(jv).all(dim=1) & torch.isfinite(wv).all(dim=1)
        if mask is not None:
            ok &= mask
        if self._prev_joint is None:
            self._prev_joint, self._prev_wrist = torch.zeros_like(jv), torch.zeros_like(wv)
        started = ok & (self.steps > 0)
        arm = (wv - self._prev_wrist).square().sum(dim=1) / self.dt
        hand = (jv - self._prev_joint).square().sum(dim=1) / self.dt
        self.sums["arm_oscillation"] += torch.where(started, arm, 0.0)
        self.sums["hand_oscillation"] += torch.where(started, hand, 0.0)
        self.sums["fdc"] -= torch.where(ok, direction_variance(torch.nan_to_num(jv), self.groups), 0.0)
        self._prev_joint = torch.where(ok[:, None], jv, self._prev_joint)
        self._prev_wrist = torch.where(ok[:, None], wv, self._prev_wrist)
        self.steps += ok.to(torch.int64)

    def read(self, env_ids: torch.Tensor) -> dict[str, torch.Tensor]:
        """The metrics so far of the episodes in ``env_ids``: name -> (len(env_ids),) float64, plus ``steps``."""
        out = {name: value[env_ids].clone() for name, value in self.sums.items()}
        out["steps"] = self.steps[env_ids].clone()
        return out

    def reset(self, env_ids: torch.Tensor) -> None:
        """Start new episodes in ``env_ids``."""
        for value in self.sums.values():
            value[env_ids] = 0.0
        self.steps[env_ids] = 0
