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

import numpy as np
import torch

from ges_core.arrays import as_numpy
from ges_core.env.reward import direction_variance, direction_variance_np
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
    dt: seconds per control step. The running sums are torch tensors updated in place through numpy
    views (a few numpy calls per step); :func:`oscillation` and :func:`finger_directional_consistency`
    state the same sums over a whole trajectory.
    """

    def __init__(self, num_envs: int, groups: torch.Tensor, dt: float) -> None:
        if dt <= 0:
            raise ConfigError(f"EpisodeMetrics: dt = {dt} s; the control step must be > 0")
        self.dt = dt
        self._groups = np.asarray(groups, dtype=np.int64)
        self._all_sums = torch.zeros(len(METRIC_NAMES), num_envs, dtype=torch.float64)
        self.sums = dict(zip(METRIC_NAMES, self._all_sums.unbind(), strict=True))
        """Per-env running sums of the current episodes (views of one (3, n) tensor)."""
        self.steps = torch.zeros(num_envs, dtype=torch.int64)
        """(n,) velocity samples recorded this episode."""
        self._sums = self._all_sums.numpy()  # (3, n) view, METRIC_NAMES order: updates are in place
        self._steps = self.steps.numpy()
        self._prev: np.ndarray | None = None  # (n, 6 + K) the last recorded wrist then joint velocities
        self._split_matrix: np.ndarray | None = None

    def update(
        self,
        joint_vel: torch.Tensor,
        wrist_vel: torch.Tensor,
        mask: torch.Tensor | None = None,
        consistency: torch.Tensor | None = None,
    ) -> None:
        """Record one control step: joint_vel (n, K) rad/s, wrist_vel (n, 6) m/s and rad/s, world.

        mask: (n,) bool, envs to record (default all); envs whose velocities are not finite are skipped too.
        The first sample of an episode only starts the differences (no oscillation term). consistency: (n,)
        the reward's ``r_c`` of these joint velocities if already computed (the FDC summand), else computed here.
        Torch tensors or numpy arrays.
        """
        jv = as_numpy(joint_vel)
        vel = np.concatenate([as_numpy(wrist_vel), jv], axis=1, dtype=np.float64)  # (n, 6 + K)
        ok = np.logical_and.reduce(np.isfinite(vel), axis=1)
        if mask is not None:
            ok &= as_numpy(mask)
        if self._prev is None:
            self._prev = np.zeros_like(vel)
        started = ok & (self._steps > 0)
        with np.errstate(all="ignore"):  # skipped envs may hold huge or non-finite values
            step = vel - self._prev
            osc = (step * step) @ self._split(vel.shape[1] - jv.shape[1], jv.shape[1]) / self.dt  # (n, 2): arm, hand
        np.add(self._sums[:2], osc.T, out=self._sums[:2], where=started)
        fdc = as_numpy(consistency) if consistency is not None else -direction_variance_np(jv, self._groups)
        np.add(self._sums[2], fdc, out=self._sums[2], where=ok)
        np.copyto(self._prev, vel, where=ok[:, None])
        self._steps += ok

    def _split(self, arm: int, hand: int) -> np.ndarray:
        """(arm + hand, 2) 0/1 matrix summing the first ``arm`` columns, then the next ``hand`` ones."""
        if self._split_matrix is None or self._split_matrix.shape[0] != arm + hand:
            m = np.zeros((arm + hand, 2))
            m[:arm, 0], m[arm:, 1] = 1.0, 1.0
            self._split_matrix = m
        return self._split_matrix

    def read(self, env_ids: torch.Tensor) -> dict[str, torch.Tensor]:
        """The metrics so far of the episodes in ``env_ids``: name -> (len(env_ids),) float64, plus ``steps``."""
        out = {name: value[env_ids].clone() for name, value in self.sums.items()}
        out["steps"] = self.steps[env_ids].clone()
        return out

    def reset(self, env_ids: torch.Tensor) -> None:
        """Start new episodes in ``env_ids``."""
        self._all_sums[:, env_ids] = 0.0
        self.steps[env_ids] = 0
