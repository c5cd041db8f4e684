"""Success protocols and episode-end reasons, batched torch.

* **paper**: the object's centre rises ``lift_height`` (0.2 m) above its start and stays there for
  ``hold_steps`` (200) consecutive *simulation* steps.
* **peers** (UniDexGrasp, UniDexGrasp++, ResDex): the object's centre comes within ``peer_radius``
  (5 cm) of the point ``lift_height`` above its start at any step of the episode; no hold.

Episodes end with one :class:`EndReason`.
"""

from __future__ import annotations

from enum import IntEnum

import torch
from pydantic import Field

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

    def reset(self, env_ids: torch.Tensor, start: torch.Tensor) -> None:
        """Start new episodes in ``env_ids`` with the object centre at ``start`` (len(env_ids), 3)."""
        self.start[env_ids] = start.to(self.start.dtype)
        self.held[env_ids] = 0
        self.max_rise[env_ids] = 0.0
        self.peer_success[env_ids] = False

    def update(self, obj_pos: torch.Tensor, timeout: torch.Tensor) -> torch.Tensor:
        """Advance one control step with the object centre ``obj_pos`` (n, 3); (n,) int64 EndReason codes.

        timeout: (n,) bool, the episode has used its last step.
        """
        cfg = self.cfg
        pos = obj_pos.to(self.start.dtype)
        rise = pos[:, 2] - self.start[:, 2]
        self.max_rise = torch.maximum(self.max_rise, rise)
        self.held = torch.where(rise >= cfg.lift_height, self.held + self.sim_steps, torch.zeros_like(self.held))
        target = self.start + torch.tensor([0.0, 0.0, cfg.lift_height], dtype=pos.dtype)
        self.peer_success |= (pos - target).norm(dim=1) < cfg.peer_radius
        return self.reasons(rise, timeout)

    def reasons(self, rise: torch.Tensor, timeout: torch.Tensor) -> torch.Tensor:
        """(n,) EndReason codes from the current rise (n,) m and the timeout flags (n,)."""
        cfg = self.cfg
        was_lifted = self.max_rise >= cfg.lifted_rise
        reason = torch.full_like(self.held, EndReason.RUNNING)
        reason = torch.where(timeout & ~was_lifted, EndReason.NOT_LIFTED, reason)
        reason = torch.where(timeout & was_lifted, EndReason.TIMEOUT, reason)
        reason = torch.where(was_lifted & (rise < cfg.dropped_rise), EndReason.DROPPED, reason)
        return torch.where(self.held >= cfg.hold_steps, EndReason.SUCCESS, reason)
