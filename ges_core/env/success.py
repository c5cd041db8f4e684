"""Success protocols and episode-end reasons, batched torch.

* **paper**: the object's centre rises ``lift_height`` (0.2 m) above its start and stays there for
  ``hold_steps`` (200) consecutive *simulation* steps.
* **peers** (UniDexGrasp, UniDexGrasp++, ResDex): the object's centre comes within ``peer_radius``
  (5 cm) of the point ``lift_height`` above its start at any step of the episode; no hold.

Episodes end with one :class:`EndReason`. The tracker keeps its state in torch tensors (its public
attributes) and updates them in place through numpy views: a handful of numpy calls per control step.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
import torch
from pydantic import Field

from ges_core.arrays import as_numpy
from ges_core.config import ConfigModel

__all__ = ["EndReason", "SuccessConfig", "SuccessTracker"]


class EndReason(IntEnum):
    """Why an episode ended (``RUNNING`` while it has not)."""

    RUNNING = 0
    SUCCESS = 1
    DROPPED = 2
    NOT_LIFTED = 3
    TIMEOUT = 4
    UNSTABLE = 5


class SuccessConfig(ConfigModel):
    """The success protocol."""

    lift_height: float = Field(0.2, gt=0, description="metres above the object's start (the paper's 0.2 m)")
    hold_steps: int = Field(200, ge=1, description="simulation steps the lift must be held (the paper's 200)")
    peer_radius: float = Field(0.05, gt=0, description="metres, the peers' success radius around the target")
    lifted_rise: float = Field(0.03, gt=0, description="metres of rise that count as 'the object was lifted'")
    dropped_rise: float = Field(
        0.03,
        ge=0,
        description="metres: a lifted object back below this rise is 'dropped' (ends the episode); 0.03 catches a "
        "box that fell and tipped onto its side (its origin ends ~2.5 cm up)",
    )


def _reason(timeout: bool, was_lifted: bool, dropped: bool, success: bool) -> EndReason:
    """The end reason of one env, by priority: success, dropped, then the episode limit."""
    if success:
        return EndReason.SUCCESS
    if dropped:
        return EndReason.DROPPED
    if timeout:
        return EndReason.TIMEOUT if was_lifted else EndReason.NOT_LIFTED
    return EndReason.RUNNING


_REASONS = np.array([_reason(*(bool(code >> bit & 1) for bit in range(4))) for code in range(16)], dtype=np.int64)
"""EndReason per code ``timeout + 2 was_lifted + 4 dropped + 8 success``: one look-up instead of a where-chain."""
_BITS = np.array([1, 2, 4, 8])


class SuccessTracker:
    """Per-env success bookkeeping for ``num_envs`` episodes; ``sim_steps`` physics steps per update."""

    def __init__(self, cfg: SuccessConfig, num_envs: int, sim_steps: int = 1) -> None:
        self.cfg, self.sim_steps = cfg, sim_steps
        self.start = torch.zeros(num_envs, 3, dtype=torch.float64)
        """(n, 3) object centre at episode start, world, m."""
        self.held = torch.zeros(num_envs, dtype=torch.int64)
        """(n,) consecutive simulation steps the object has been at the lift height."""
        self.max_rise = torch.zeros(num_envs, dtype=torch.float64)
        """(n,) highest rise of the episode so far, m."""
        self.peer_success = torch.zeros(num_envs, dtype=torch.bool)
        """(n,) the peers' protocol has succeeded at some step of this episode."""
        # numpy views of the tensors above (same memory): every update is in place
        self._start, self._held = self.start.numpy(), self.held.numpy()
        self._max_rise, self._peer = self.max_rise.numpy(), self.peer_success.numpy()
        self._lift = np.array([0.0, 0.0, cfg.lift_height])
        self._flags = np.zeros((4, num_envs), dtype=bool)  # timeout, was lifted, dropped, success

    def reset(self, env_ids: torch.Tensor, start: torch.Tensor) -> None:
        """Start new episodes in ``env_ids`` with the object centre at ``start`` (len(env_ids), 3)."""
        ids = as_numpy(env_ids)
        self._start[ids] = as_numpy(start, np.float64)
        self._held[ids] = 0
        self._max_rise[ids] = 0.0
        self._peer[ids] = False

    def update(self, obj_pos: torch.Tensor, timeout: torch.Tensor) -> torch.Tensor:
        """Advance one control step with the object centre ``obj_pos`` (n, 3); (n,) int64 EndReason codes.

        timeout: (n,) bool, the episode has used its last step. Numpy arrays are accepted too.
        """
        cfg = self.cfg
        pos = as_numpy(obj_pos, np.float64)
        rise = pos[:, 2] - self._start[:, 2]
        np.maximum(self._max_rise, rise, out=self._max_rise)
        self._held += self.sim_steps
        self._held *= rise >= cfg.lift_height  # the hold restarts when the object dips
        to_target = pos - (self._start + self._lift)
        self._peer |= np.sqrt(np.add.reduce(to_target * to_target, axis=1)) < cfg.peer_radius
        return self.reasons(rise, timeout)

    def reasons(self, rise: torch.Tensor, timeout: torch.Tensor) -> torch.Tensor:
        """(n,) EndReason codes from the current rise (n,) m and the timeout flags (n,)."""
        cfg, flags = self.cfg, self._flags
        flags[0] = as_numpy(timeout)
        np.greater_equal(self._max_rise, cfg.lifted_rise, out=flags[1])  # was lifted
        np.logical_and(flags[1], as_numpy(rise) < cfg.dropped_rise, out=flags[2])  # dropped
        np.greater_equal(self._held, cfg.hold_steps, out=flags[3])  # success
        return torch.from_numpy(_REASONS[_BITS @ flags])
