"""Scripted baseline expert: close toward the goal joint angles, then lift.

It reads only the documented observation: goal joints are ``q + goal_q``; while closing the wrist is
servoed toward the grasp's wrist position (``goal_pos``); then the wrist moves the object (``obj_pos``)
toward the point ``lift`` above where the object was when the episode began. Servoing on the object,
not the wrist, matters for the peers' protocol (object within 5 cm of the point 0.2 m up): in PyBullet
the squeezed test box slid ~9 cm up within the hand and was dragged 6-7 cm sideways during the close, so a
fixed 0.23 m wrist rise carried it to 0.32 m, 7 cm off the target point.
"""

from __future__ import annotations

import torch

from ges_core.env.layout import WRIST_DOF, ActionLayout, ObservationLayout
from ges_core.hand import HandModel
from ges_core.policy import Expert
from ges_core.synthesis.squeeze import squeeze_targets

__all__ = ["ScriptedExpert"]


class ScriptedExpert(Expert):
    """Close over ``close_steps`` control steps (joint targets ramp to ``overshoot`` past the goal), then lift."""

    name = "scripted"

    def __init__(
        self,
        obs_layout: ObservationLayout,
        act_layout: ActionLayout,
        close_steps: int = 30,
        overshoot: float = 0.3,
        lift: float = 0.225,
        hand: HandModel | None = None,
        squeeze_force: float = 5.0,
    ) -> None:
        """lift: metres above its start the object is carried to: the 0.2 m bar + 2.5 cm for slip in the hand
        (1 cm let a slipping box dip to 0.195 m in PyBullet), still within the peers' 5 cm.

        overshoot: fraction of (goal - pre-grasp) added past the goal so the fingers press on the object
        (PD targets exactly at a contact pose give no grip force). Used without ``hand``.

        hand: the env's hand; given, the closing targets are Stage 1 validation's squeeze instead
        (:func:`ges_core.synthesis.squeeze.squeeze_targets`: each fingertip pressing ``squeeze_force`` N
        toward what it opposes). The overshoot rule pushed the Shadow thumb across its contact (0 of 21
        objects lifted, benchmarks/scripted_baseline.py)."""
        self.obs_layout, self.act_layout = obs_layout, act_layout
        self.hand, self.squeeze_force = hand, squeeze_force
        self.close_q: torch.Tensor | None = None
        self.close_steps, self.overshoot, self.lift = close_steps, overshoot, lift
        self.t: torch.Tensor | None = None
        self.start_q: torch.Tensor | None = None
        self.start_obj: torch.Tensor | None = None

    def _closing_targets(self, goal: torch.Tensor, fresh: torch.Tensor) -> torch.Tensor:
        """(n, K) where the finger targets end: past the goal joints (overshoot rule, or the squeeze with a hand)."""
        if self.hand is None:
            return self.start_q + (1.0 + self.overshoot) * (goal - self.start_q)
        if self.close_q is None or self.close_q.shape != goal.shape:
            self.close_q, fresh = goal.clone(), torch.ones_like(fresh)
        for i in fresh.nonzero().flatten().tolist():
            press = squeeze_targets(
                self.hand, goal[i].numpy(), force=self.squeeze_force, min_squeeze=0.05, max_squeeze=0.6
            )
            self.close_q[i] = torch.as_tensor(press)
        return self.close_q

    def reset(self, env_ids: torch.Tensor | None = None) -> None:
        """Restart the script in ``env_ids`` (all if None)."""
        if self.t is not None:
            self.t[slice(None) if env_ids is None else env_ids] = 0

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """(n, K + 6) actions in [-1, 1] for observations (n, obs size)."""
        obs = obs.to(torch.float64)
        q = self.obs_layout.unpack(obs, "q")
        obj = self.obs_layout.unpack(obs, "obj_pos")
        if self.t is None:
            self.t, self.start_q, self.start_obj = torch.zeros(obs.shape[0], dtype=torch.long), q.clone(), obj.clone()
        fresh = self.t == 0
        self.start_q = torch.where(fresh[:, None], q, self.start_q)
        self.start_obj = torch.where(fresh[:, None], obj, self.start_obj)
        goal = q + self.obs_layout.unpack(obs, "goal_q")
        close = self._closing_targets(goal, fresh)
        frac = (self.t.to(torch.float64) / self.close_steps).clamp(max=1.0)[:, None]
        target = self.start_q + frac * (close - self.start_q)
        wrist = (self.obs_layout.unpack(obs, "goal_pos") / self.act_layout.max_wrist_step).clamp(-1.0, 1.0)
        lifting = self.t >= self.close_steps
        aim = self.start_obj + torch.tensor([0.0, 0.0, self.lift], dtype=obj.dtype)
        carry = ((aim - obj) / self.act_layout.max_wrist_step).clamp(-1.0, 1.0)
        wrist = torch.where(lifting[:, None], carry, wrist)
        action = torch.zeros(obs.shape[0], self.act_layout.size, dtype=torch.float64)
        action[:, :3] = wrist
        action[:, WRIST_DOF:] = self.act_layout.normalize_joints(target)
        self.t += 1
        return action.to(torch.float32)
