"""Scripted baseline expert: approach the grasp, close, carry the object up, as Stage 1 validation does.

Built by the registry as ``build_expert(context, **settings)`` (the expert factory contract,
:mod:`ges_core.policy`); its parameters are :class:`~ges_plugins.experts.scripted.config.ScriptedConfig`.

Phases per env, counted in control steps from the episode's start (the pre-grasp, where stage one ends):

1. **approach** (``approach_steps``): the wrist target moves from the start pose toward the grasp pose
   (linear position, slerp rotation) in equal steps, fingers at the start joints. A step in which the
   wrist link touches the object (the ``contact`` block's last entry) does not advance: the palm is
   not driven into the object (a test grasp with the palm 7 mm inside a box pressed it into the table
   with 100 N, and the box shot out of the PyBullet hand when the fingers closed). ``palm_shift`` /
   ``finger_shift`` move the grasp position first, along the hand's palm normal / finger direction;
2. **close** (``close_steps``): the finger targets ramp from the start joints to the closing targets
   (Stage 1 validation's squeeze with ``hand``, else the overshoot rule); the wrist target stays;
3. **pause** (``pause_steps``): everything held while the grip builds;
4. **carry**: the wrist target rises straight up (world +z, ``max_wrist_step`` per step) while the
   object (``obj_pos``) is below the point ``lift`` above where it began, at most ``lift + carry_margin``
   above the grasp; it never descends. Orientation stays the grasp's. Sideways the wrist target moves
   ``carry_gain`` per step of how far the lifted object has drifted past :data:`DRIFT_TOLERANCE` from
   its start (at most ``max_wrist_step``), so the object ends within the peers' 5 cm.

It reads only the documented observation: the grasp pose is ``wrist_pose`` + ``goal_pos`` / ``goal_rot``
and the goal joints ``q + goal_q`` at the episode's first step.

**Wrist targets are steered open loop.** The environment integrates the wrist target from the measured
pose at reset (``docs/env.md``), so the expert keeps its own copy of that target (the same integration of
its own clamped actions) and sends the difference between the target it wants and that copy. The first
version servoed the *measured* wrist on the grasp position and the object on its aim at full gain: the
PD lag (4-8 mm) was integrated into the target, which ran past the grasp and swung the wrist 5-7 mm
about it while the fingers closed, and the object servo rocked the carried object +-1-2 cm sideways; the
Shadow hand's weak fingers (Kp about 1 N m/rad) lost their grip (1 of 8 Shadow grasps that Stage 1
validation holds were held in SAPIEN; ``docs/env_baseline.md``).
"""

from __future__ import annotations

from typing import Any

import torch

from ges_core.config import parse_model
from ges_core.env.layout import WRIST_DOF, ActionLayout, ObservationLayout
from ges_core.errors import ConfigError
from ges_core.hand import HandModel
from ges_core.hand_settings import hand_validate_config
from ges_core.kinematics import palm_offset
from ges_core.policy import Expert, ExpertContext
from ges_core.synthesis.physics.squeeze import SQUEEZE_FORCE, squeeze_targets
from ges_core.transforms_torch import (
    interpolate_pose,
    quat_conj,
    quat_mul,
    quat_rotate,
    quat_to_rotvec,
    rotvec_to_quat,
)
from ges_plugins.experts.scripted.config import ScriptedConfig

__all__ = ["ScriptedExpert", "build_expert"]

DRIFT_TOLERANCE = 0.025
"""m: sideways drift of the carried object left alone: half the peers' 5 cm. Correcting every drift
(the 1-2 cm a Shadow grasp shifts the object while closing) moved the hand sideways against its grip
(4 more of 59 Shadow grasps dropped in SAPIEN, docs/env_baseline.md)."""
LIFTED = 0.03
"""m above its start from which the object counts as off the table (the success tracker's 'lifted' bar)."""
DRIFT_SMOOTHING = 0.1
"""Per-step weight of the newest offset in the averaged drift: a time constant of 10 control steps."""


class ScriptedExpert(Expert):
    """Approach, close (targets past the goal joints), pause, then carry the object up (module docs)."""

    name = "scripted"

    def __init__(
        self,
        obs_layout: ObservationLayout,
        act_layout: ActionLayout,
        hand: HandModel | None = None,
        **settings: Any,
    ) -> None:
        """obs_layout, act_layout: the env's layouts (the observation must hold the goal blocks).

        hand: the env's hand; given, the closing targets are Stage 1 validation's squeeze
        (:func:`ges_core.synthesis.physics.squeeze.squeeze_targets`: each fingertip pressing ``squeeze_force`` N
        toward what it opposes), else the ``overshoot`` rule. The squeeze's floor and cap (``min_squeeze``,
        ``max_squeeze``) and, when ``squeeze_force`` is None, its force are the hand's, read as Stage 1 reads them:
        :class:`~ges_core.synthesis.physics.validate.ValidateConfig`'s defaults with the hand YAML's
        ``settings.validate`` over them (:func:`ges_core.hand_settings.hand_validate_config`); a hand that sets
        none squeezes with 5 N, floor 0.05 rad, cap 0.6 rad.

        settings: :class:`~ges_plugins.experts.scripted.config.ScriptedConfig` fields (each documented there, with
        where its default comes from); an unknown or out-of-range one is a ConfigError.
        """
        self.config = parse_model(ScriptedConfig, settings, where="settings of expert 'scripted'")
        c = self.config
        self.obs_layout, self.act_layout = obs_layout, act_layout
        self.squeeze = hand_validate_config(hand.description) if hand is not None else None
        """The hand's squeeze settings (None without ``hand``)."""
        squeeze_force = c.squeeze_force
        if squeeze_force is None:
            squeeze_force = self.squeeze.squeeze_force if self.squeeze is not None else SQUEEZE_FORCE
        self.hand, self.squeeze_force, self.overshoot = hand, squeeze_force, c.overshoot
        self.approach_steps, self.close_steps, self.pause_steps = c.approach_steps, c.close_steps, c.pause_steps
        self.lift, self.carry_margin, self.carry_gain = c.lift, c.carry_margin, c.carry_gain
        self.grasp_shift = self._grasp_shift(hand, c.palm_shift, c.finger_shift)
        """(palm, finger) offset of the grasp position along the hand's palm normal and finger direction, m (None:
        the Stage 1 grasp)."""
        self.t: torch.Tensor | None = None
        self.plan: dict[str, torch.Tensor] = {}
        """Per env, set at its episode's first step (float64): start_q, close_q (n, K); start_obj, start_pos,
        grasp_pos, target_pos (n, 3) m; start_rot, grasp_rot, target_rot (n, 4) wxyz; progress (n,) of the
        approach in [0, 1]; drift (n, 2) m, the lifted object's smoothed sideways offset (:meth:`_drift`).
        target_* mirror the env's integrated wrist target (world frame)."""

    @staticmethod
    def _grasp_shift(hand: HandModel | None, palm: float, finger: float) -> tuple[float, float] | None:
        """(palm, finger): the grasp position's offset along the palm normal and the finger direction, m (None when
        both are 0); ConfigError without the hand, whose wrist convention gives the directions."""
        if palm == 0.0 and finger == 0.0:
            return None
        if hand is None:
            raise ConfigError(
                "settings of expert 'scripted': palm_shift and finger_shift need the hand (its wrist.palm_normal "
                "and wrist.finger_direction); build the expert with the env's hand"
            )
        return palm, finger

    def reset(self, env_ids: torch.Tensor | None = None) -> None:
        """Restart the script in ``env_ids`` (all if None)."""
        if self.t is not None:
            self.t[slice(None) if env_ids is None else env_ids] = 0

    def act(self, obs: torch.Tensor) -> torch.Tensor:
        """(n, K + 6) actions in [-1, 1] for observations (n, obs size)."""
        obs = obs.to(torch.float64)
        if self.t is None or self.t.shape[0] != obs.shape[0]:
            self.t = torch.zeros(obs.shape[0], dtype=torch.long)
        fresh = self.t == 0
        if fresh.any():
            self._begin(obs, fresh)
        self._advance(self.obs_layout.unpack(obs, "contact")[:, -1] > 0.5)
        pos, rot = self._wrist_goal(self.obs_layout.unpack(obs, "obj_pos"))
        action = torch.zeros(obs.shape[0], self.act_layout.size, dtype=torch.float64)
        action[:, :WRIST_DOF] = self._wrist_action(pos, rot)
        action[:, WRIST_DOF:] = self.act_layout.normalize_joints(self._finger_targets())
        self._follow(action)
        self.t += 1
        return action.to(torch.float32)

    # -- the plan of an episode ---------------------------------------------------------------------
    def _begin(self, obs: torch.Tensor, fresh: torch.Tensor) -> None:
        """Latch each fresh env's start (joints, object, wrist) and grasp (pose, closing targets)."""
        unpack = self.obs_layout.unpack
        q, wrist = unpack(obs, "q"), unpack(obs, "wrist_pose")
        goal_q = q + unpack(obs, "goal_q")
        rot = self.obs_layout.wrist_quat(obs)
        grasp_rot = quat_mul(rotvec_to_quat(unpack(obs, "goal_rot")), rot)
        new = {
            "start_q": q,
            "close_q": self._closing_targets(q, goal_q, fresh),
            "start_obj": unpack(obs, "obj_pos"),
            "start_pos": wrist[:, :3],
            "start_rot": rot,
            "target_pos": wrist[:, :3],
            "target_rot": rot,
            "grasp_pos": wrist[:, :3] + unpack(obs, "goal_pos") + self._shift(goal_q, grasp_rot, fresh),
            "grasp_rot": grasp_rot,
            "progress": torch.full((q.shape[0],), 0.0 if self.approach_steps else 1.0, dtype=torch.float64),
            "drift": torch.zeros(q.shape[0], 2, dtype=torch.float64),
        }
        for key, value in new.items():
            old = self.plan.get(key)
            self.plan[key] = value.clone() if old is None or old.shape != value.shape else old
            self.plan[key][fresh] = value[fresh]

    def _shift(self, goal_q: torch.Tensor, grasp_rot: torch.Tensor, fresh: torch.Tensor) -> torch.Tensor:
        """(n, 3) world offset of the grasp position: :attr:`grasp_shift` from the wrist link's frame at the goal
        joints ``goal_q`` (n, K) through the base link's grasp orientation ``grasp_rot`` (n, 4) wxyz; zeros if unset
        and in the rows that are not ``fresh`` (n,) (only fresh rows are latched, so only they get the kinematics).

        The observation's wrist pose is the base link's; the wrist link may sit behind wrist joints (the Shadow's
        palm), so the offset is turned by the base-to-wrist-link rotation at the goal joints first."""
        out = torch.zeros(goal_q.shape[0], 3, dtype=torch.float64)
        if self.grasp_shift is None:
            return out
        offset = palm_offset(self.hand, goal_q[fresh], *self.grasp_shift)
        out[fresh] = quat_rotate(grasp_rot[fresh], offset)
        return out

    def _closing_targets(self, q: torch.Tensor, goal: torch.Tensor, fresh: torch.Tensor) -> torch.Tensor:
        """(n, K) where the finger targets end, past the goal joints (only the rows of ``fresh`` envs matter)."""
        if self.hand is None:
            return q + (1.0 + self.overshoot) * (goal - q)
        close = goal.clone()
        for i in fresh.nonzero().flatten().tolist():
            press = squeeze_targets(
                self.hand,
                goal[i].numpy(),
                force=self.squeeze_force,
                min_squeeze=self.squeeze.min_squeeze,
                max_squeeze=self.squeeze.max_squeeze,
            )
            close[i] = torch.as_tensor(press)
        return close

    # -- per step -----------------------------------------------------------------------------------
    def _advance(self, palm: torch.Tensor) -> None:
        """One approach step for envs still approaching whose wrist link does not touch the object (palm (n,))."""
        step = 1.0 / max(self.approach_steps, 1)
        moving = (self.t < self.approach_steps) & ~palm
        progress = self.plan["progress"]
        self.plan["progress"] = torch.where(moving, (progress + step).clamp(max=1.0), progress)

    def _finger_targets(self) -> torch.Tensor:
        """(n, K) joint targets: the start joints, ramping to ``close_q`` over the close phase."""
        p = self.plan
        frac = ((self.t - self.approach_steps).to(torch.float64) / self.close_steps).clamp(0.0, 1.0)[:, None]
        return p["start_q"] + frac * (p["close_q"] - p["start_q"])

    def _wrist_goal(self, obj: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Where the wrist target should be after this step: (n, 3) position m, (n, 4) wxyz, world."""
        p = self.plan
        start, grasp = (torch.cat([p[f"{k}_pos"], p[f"{k}_rot"]], dim=1) for k in ("start", "grasp"))
        pose = interpolate_pose(start, grasp, p["progress"][:, None])
        pos, rot = pose[:, :3], pose[:, 3:]
        carrying = (self.t >= self.approach_steps + self.close_steps + self.pause_steps)[:, None]
        return torch.where(carrying, self._carry(obj, pos), pos), rot

    def _carry(self, obj: torch.Tensor, held: torch.Tensor) -> torch.Tensor:
        """(n, 3) carry position from the held grasp position ``held`` (n, 3) and the object ``obj`` (n, 3)."""
        p, step = self.plan, self.act_layout.max_wrist_step
        pos = p["target_pos"].clone()
        pos[:, :2] += (self.carry_gain * self._drift(obj)).clamp(-step, step)
        below = (p["start_obj"][:, 2] + self.lift - obj[:, 2]).clamp(0.0, step)
        top = held[:, 2] + self.lift + self.carry_margin
        pos[:, 2] = torch.minimum(torch.maximum(pos[:, 2] + below, held[:, 2]), top)
        return pos

    def _drift(self, obj: torch.Tensor) -> torch.Tensor:
        """(n, 2) how far the lifted object's smoothed sideways offset from its start goes past
        :data:`DRIFT_TOLERANCE`, pointing back to the start, m.

        The offset is averaged over the steps the object is more than :data:`LIFTED` above its start
        (exponential, :data:`DRIFT_SMOOTHING` per step): on the table the hand would drag the object, and a
        pinched plate swinging +-5 cm under the fingers (procedural/plate/004, Shadow) was rocked out of the
        hand by a wrist chasing each swing."""
        p = self.plan
        offset = p["start_obj"][:, :2] - obj[:, :2]
        lifted = (obj[:, 2] - p["start_obj"][:, 2] > LIFTED)[:, None]
        p["drift"] = torch.where(lifted, p["drift"] + DRIFT_SMOOTHING * (offset - p["drift"]), p["drift"])
        size = p["drift"].norm(dim=1, keepdim=True)
        return p["drift"] * (1.0 - DRIFT_TOLERANCE / size.clamp(min=1e-9)).clamp(min=0.0)

    def _wrist_action(self, pos: torch.Tensor, rot: torch.Tensor) -> torch.Tensor:
        """(n, 6) normalized wrist action moving the mirrored target toward ``pos``, ``rot`` (clamped)."""
        p, a = self.plan, self.act_layout
        move = (pos - p["target_pos"]) / a.max_wrist_step
        turn = quat_to_rotvec(quat_mul(rot, quat_conj(p["target_rot"]))) / a.max_wrist_turn
        return torch.cat([move, turn], dim=1).clamp(-1.0, 1.0)

    def _follow(self, action: torch.Tensor) -> None:
        """Integrate the wrist target as the env does (``GraspEnv.apply_action``)."""
        p = self.plan
        dp, dr = self.act_layout.wrist_deltas(action)
        p["target_pos"] = p["target_pos"] + dp.to(torch.float64)
        p["target_rot"] = quat_mul(rotvec_to_quat(dr.to(torch.float64)), p["target_rot"])


def build_expert(context: ExpertContext, **settings: Any) -> ScriptedExpert:
    """The expert factory (``registry.build_expert("scripted", context, **settings)``): closes with the hand's squeeze.

    ConfigError when the observation has no goal blocks (the NoGoal ablation): the script reads the grasp from them.
    """
    if not context.obs_layout.goal:
        raise ConfigError(
            "the scripted expert reads the goal blocks (goal_pos, goal_q) of the observation; it cannot run "
            "with env.goal_prior=false (NoGoal). Evaluate a learned expert there, or keep goal_prior=true"
        )
    return ScriptedExpert(context.obs_layout, context.act_layout, hand=context.hand, **settings)
