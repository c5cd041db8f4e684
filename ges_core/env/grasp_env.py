"""The grasp-execution environment: ``num_envs`` scenes of one :class:`SimBackend`, batched torch state.

Control has two stages, as in the paper: (1) pre-grasp reaching: the wrist is PD-driven along a
planned straight-line / slerp trajectory from a start pose (the pre-grasp backed off ``reach_offset``
upward) to the pre-grasp, fingers held at the pre-grasp joints; (2) grasp execution: every
:meth:`GraspEnv.apply_action` sets wrist and joint targets from a normalized action, then the
backend steps ``sim_steps`` physics steps. The wrist target is integrated: each action moves the
previous wrist *target* (not the measured pose, which would let a loaded wrist sag under zero action).

Prior ablation (the paper's Init/NoInit x Goal/NoGoal, :data:`PRIOR_PRESETS`): ``init_prior=False``
starts every episode with the open hand at a fixed pose above the object and no reaching;
``goal_prior=False`` leaves the goal blocks G out of the observation (the reward still uses the goal).

Per-env resets (:meth:`GraspEnv.reset_envs`) teleport that env's hand straight to its episode start and
its object to its rest pose, through the backend's per-env teleports: the other envs are untouched. See
``docs/env.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.env.layout import ActionLayout, ObservationLayout
from ges_core.env.reward import RewardConfig, compute_reward, consistency_groups
from ges_core.env.rotations import quat_conj, quat_mul, quat_rotate, quat_to_rotvec, rotvec_to_quat
from ges_core.env.success import EndReason, SuccessConfig, SuccessTracker
from ges_core.errors import ConfigError, SimulationError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import SimBackend
from ges_core.transforms import matrix_to_pose, rotation_between_frames

__all__ = ["PRIOR_PRESETS", "EnvConfig", "GraspEnv", "GraspTargets", "open_hand_start_pose", "prior_preset"]


class EnvConfig(ConfigModel):
    """Settings of the grasp-execution environment."""

    sim_steps: int = Field(2, ge=1, description="physics steps per control step")
    episode_length: int = Field(200, ge=1, description="control steps per episode (the peers' 200)")
    reach_steps: int = Field(60, ge=0, description="control steps of stage one (PD reaching) on a full reset")
    settle_steps: int = Field(
        10, ge=0, description="control steps holding the pre-grasp after reaching (PyBullet's wrist lags ~7 mm)"
    )
    reach_offset: float = Field(0.10, ge=0, description="metres above the pre-grasp where reaching starts")
    contact_threshold: float = Field(0.05, gt=0, description="N: a link 'touches' above this contact force")
    max_wrist_step: float = Field(
        0.005, gt=0, description="m per control step the wrist target may move (0.3 m/s at 60 Hz control)"
    )
    max_wrist_turn: float = Field(0.1, gt=0, description="rad per control step the wrist target may turn")
    init_prior: bool = Field(
        True, description="Init: stage one reaches the pre-grasp; False (NoInit): open hand above the object"
    )
    goal_prior: bool = Field(True, description="Goal: observation holds G (goal_pos, goal_rot, goal_q); False: not")
    noinit_height: float = Field(
        0.25, gt=0, description="NoInit: metres of the wrist-link origin above the object's origin at the start"
    )
    reward: RewardConfig = Field(default_factory=RewardConfig)
    success: SuccessConfig = Field(default_factory=SuccessConfig)


PRIOR_PRESETS: dict[str, dict[str, bool]] = {
    "init_goal": {"init_prior": True, "goal_prior": True},
    "init_nogoal": {"init_prior": True, "goal_prior": False},
    "noinit_goal": {"init_prior": False, "goal_prior": True},
    "noinit_nogoal": {"init_prior": False, "goal_prior": False},
}
"""The paper's prior ablation: EnvConfig overrides per preset (``cfg.model_copy(update=prior_preset(name))``)."""


def prior_preset(name: str) -> dict[str, bool]:
    """The EnvConfig overrides of the prior-ablation preset ``name`` (a fresh dict)."""
    if name not in PRIOR_PRESETS:
        raise ConfigError(f"unknown prior preset '{name}'; choose one of {', '.join(PRIOR_PRESETS)}")
    return dict(PRIOR_PRESETS[name])


@dataclass(frozen=True)
class GraspTargets:
    """One Stage 1 grasp per env: arrays (num_envs, ...), world frame, metres, wxyz, radians."""

    wrist_pose: np.ndarray
    """(n, 7) base-link pose of the grasp g."""
    q: np.ndarray
    """(n, K) goal joint angles of the grasp."""
    pre_wrist_pose: np.ndarray
    """(n, 7) base-link pose of the pre-grasp g_init."""
    pre_q: np.ndarray
    """(n, K) joint angles of the pre-grasp."""


class GraspEnv:
    """Batched grasp execution over ``sim`` (hand loaded here, one object in every env)."""

    def __init__(
        self, sim: SimBackend, hand: HandModel, obj: ObjectAsset, grasps: GraspTargets, cfg: EnvConfig
    ) -> None:
        self.sim, self.hand, self.obj, self.cfg = sim, hand, obj, cfg
        self.n = sim.num_envs
        d = hand.description
        self._check_grasps(grasps, d.num_joints)
        self.grasps = {k: torch.as_tensor(np.asarray(v, dtype=np.float64)) for k, v in vars(grasps).items()}
        self.tip_links = list(d.tip_links)
        self.tip_offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
        self.contact_links = list(dict.fromkeys([*d.tip_links, d.wrist.link]))
        self.obs_layout = ObservationLayout.for_hand(d, tuple(self.contact_links), goal=cfg.goal_prior)
        lim = torch.as_tensor(d.limits_array)
        self.act_layout = ActionLayout(lim[:, 0], lim[:, 1], cfg.max_wrist_step, cfg.max_wrist_turn)
        self.finger_joints = [torch.as_tensor(d.joint_index(f.joints)) for f in d.fingers]
        self.groups = consistency_groups(d)
        self.tracker = SuccessTracker(cfg.success, self.n, cfg.sim_steps)
        self.control_dt = cfg.sim_steps * sim.config.timestep
        self.prev_action = torch.zeros(self.n, self.act_layout.size, dtype=torch.float64)
        sim.load_hand(hand, floating=True)
        sim.load_object(obj)

    @staticmethod
    def _check_grasps(g: GraspTargets, k: int) -> None:
        rows = {name: np.asarray(v).shape for name, v in vars(g).items()}
        n = rows["q"][0] if rows["q"] else 0
        want = {"wrist_pose": (n, 7), "q": (n, k), "pre_wrist_pose": (n, 7), "pre_q": (n, k)}
        bad = {name: shape for name, shape in rows.items() if shape != want[name]}
        if bad or not all(np.isfinite(np.asarray(v)).all() for v in vars(g).values()):
            raise ConfigError(f"GraspTargets: shapes {bad or rows} should be {want} (K={k}), all values finite")

    # -- resets ----------------------------------------------------------------------------
    def reset_all(self) -> None:
        """Every env: object at rest, hand at its episode start (:meth:`start_state`), ``settle_steps`` holding.

        Init: the hand starts ``reach_offset`` above the pre-grasp and stage one (PD reaching) takes it
        there. NoInit: the open hand is teleported to its fixed start above the object; no reaching.
        """
        sim, cfg = self.sim, self.cfg
        sim.reset()
        self.rest_pose = sim.object_pose()
        if not cfg.init_prior:
            start = open_hand_start_pose(self.hand, self.rest_pose[:, :3], cfg.noinit_height)
            self.noinit_start = torch.as_tensor(start)  # (n, 7) base poses, world
        q, pose = self.start_state(torch.arange(self.n))
        if cfg.init_prior:
            self._reach(q, pose)
        else:
            sim.set_hand_state(q.numpy(), pose.numpy())
        sim.step(cfg.sim_steps * cfg.settle_steps)
        self._begin(torch.arange(self.n))

    def _reach(self, q: torch.Tensor, pose: torch.Tensor) -> None:
        """Stage one: from ``reach_offset`` above ``pose`` (n, 7), PD-drive the wrist there, fingers held at q."""
        start = pose.clone()
        start[:, 2] += self.cfg.reach_offset
        self.sim.set_hand_state(q.numpy(), start.numpy())
        self.sim.set_joint_targets(q.numpy())
        for t in range(1, self.cfg.reach_steps + 1):
            self.sim.set_wrist_targets(interpolate_pose(start, pose, t / self.cfg.reach_steps).numpy())
            self.sim.step(self.cfg.sim_steps)

    def start_state(self, env_ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Where episodes of ``env_ids`` hand over to the policy: joints (m, K) rad, base pose (m, 7) world.

        Init: the pre-grasp (``pre_q``, ``pre_wrist_pose``). NoInit: the open pose at ``noinit_start``
        (set by :meth:`reset_all`).
        """
        if self.cfg.init_prior:
            return self.grasps["pre_q"][env_ids], self.grasps["pre_wrist_pose"][env_ids]
        q_open = torch.as_tensor(self.hand.description.open_pose, dtype=torch.float64)
        return q_open.expand(len(env_ids), -1).clone(), self.noinit_start[env_ids]

    def reset_envs(self, env_ids: torch.Tensor) -> None:
        """Envs ``env_ids``: object back at rest, hand at its episode start (:meth:`start_state`); others untouched.

        No stage one here: the hand is teleported straight to where the policy takes over.
        """
        ids = env_ids.tolist()
        if not ids:
            return
        q, pose = self.start_state(env_ids)
        self.sim.set_hand_state(q.numpy(), pose.numpy(), env_ids=ids)  # also restores a blown-up env
        self.sim.set_object_pose(self.rest_pose[ids], env_ids=ids)  # not load_object: SAPIEN segfaults reading
        self._begin(env_ids)  # contacts of a removed body

    def _begin(self, env_ids: torch.Tensor) -> None:
        wrist = torch.as_tensor(self.sim.wrist_pose())
        if env_ids.numel() == self.n:
            self.wrist_target = wrist.clone()
        self.wrist_target[env_ids] = wrist[env_ids]
        self.wrist_prev = wrist
        self.prev_action[env_ids] = 0.0
        obj = torch.as_tensor(self.sim.object_pose()[:, :3])
        self.tracker.reset(env_ids, obj[env_ids])

    # -- stepping --------------------------------------------------------------------------
    def apply_action(self, action: torch.Tensor) -> torch.Tensor:
        """Set targets from ``action`` (n, K + 6) and step; returns (n,) bool, envs whose state blew up."""
        action = action.to(torch.float64)
        dp, dr = self.act_layout.wrist_deltas(action)
        wt = self.wrist_target
        self.wrist_target = torch.cat([wt[:, :3] + dp, quat_mul(rotvec_to_quat(dr), wt[:, 3:])], dim=1)
        self.sim.set_wrist_targets(self.wrist_target.numpy())
        self.sim.set_joint_targets(self.act_layout.joint_targets(action).numpy())
        self.prev_action = action.clamp(-1.0, 1.0)
        return self._step_physics()

    def _step_physics(self) -> torch.Tensor:
        """Step ``sim_steps``; on SimulationError mark its ``env_ids`` (every env if it names none) unstable.

        The backend finishes the step in every healthy env before raising."""
        unstable = torch.zeros(self.n, dtype=torch.bool)
        try:
            self.sim.step(self.cfg.sim_steps)
        except SimulationError as err:
            unstable[list(err.env_ids) if err.env_ids else slice(None)] = True
        return unstable

    def observe(self) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Flat observation (n, obs size) float32 and the raw state (float64) reused by rewards."""
        sim = self.sim
        q, dq = (torch.as_tensor(a) for a in sim.joint_state())
        wrist = torch.as_tensor(sim.wrist_pose())
        forces = torch.as_tensor(sim.contact_forces(self.contact_links, "object"))
        tips = torch.as_tensor(sim.link_poses(self.tip_links))
        tip_world = tips[..., :3] + quat_rotate(tips[..., 3:], self.tip_offsets.expand_as(tips[..., :3]))
        inv = quat_conj(wrist[:, 3:])[:, None]
        obj = torch.as_tensor(sim.object_pose()[:, :3])
        vel = self._wrist_velocity(wrist)
        g = self.grasps
        blocks = {
            "q": q,
            "dq": dq,
            "contact": (forces.norm(dim=-1) > self.cfg.contact_threshold).to(torch.float64),
            "tip_force": quat_rotate(inv, forces[:, : len(self.tip_links)]),
            "tip_pos": quat_rotate(inv, tip_world - wrist[:, None, :3]),
            "wrist_pose": torch.cat([wrist[:, :3], quat_to_rotvec(wrist[:, 3:])], dim=1),
            "wrist_vel": vel,
            "prev_action": self.prev_action,
            "obj_pos": obj,
        }
        if self.obs_layout.goal:
            blocks["goal_pos"] = g["wrist_pose"][:, :3] - wrist[:, :3]
            blocks["goal_rot"] = quat_to_rotvec(quat_mul(g["wrist_pose"][:, 3:], quat_conj(wrist[:, 3:])))
            blocks["goal_q"] = g["q"] - q
        state = {"q": q, "dq": dq, "tip_world": tip_world, "obj": obj, "wrist_vel": vel}
        return self.obs_layout.pack(blocks), state

    def _wrist_velocity(self, wrist: torch.Tensor) -> torch.Tensor:
        """(n, 6) finite-difference wrist velocity since the last call, world, m/s and rad/s."""
        lin = (wrist[:, :3] - self.wrist_prev[:, :3]) / self.control_dt
        ang = quat_to_rotvec(quat_mul(wrist[:, 3:], quat_conj(self.wrist_prev[:, 3:]))) / self.control_dt
        self.wrist_prev = wrist
        return torch.cat([lin, ang], dim=1)

    def reward(self, state: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Reward (n,) and its terms for the state returned by :meth:`observe`."""
        return compute_reward(
            self.cfg.reward,
            q_error=self.grasps["q"] - state["q"],
            finger_joints=self.finger_joints,
            tip_pos=state["tip_world"],
            obj_pos=state["obj"],
            obj_start=self.tracker.start,
            joint_vel=state["dq"],
            wrist_vel=state["wrist_vel"],
            groups=self.groups,
        )

    def end_reasons(self, state: dict[str, torch.Tensor], timeout: torch.Tensor, unstable: torch.Tensor):
        """(n,) int64 EndReason codes after a control step."""
        reason = self.tracker.update(state["obj"], timeout)
        return torch.where(unstable, EndReason.UNSTABLE, reason)


def interpolate_pose(a: torch.Tensor, b: torch.Tensor, s: float) -> torch.Tensor:
    """(n, 7) poses a fraction ``s`` in [0, 1] from ``a`` to ``b``: linear position, slerp rotation."""
    rel = quat_to_rotvec(quat_mul(b[:, 3:], quat_conj(a[:, 3:])))
    return torch.cat([a[:, :3] + s * (b[:, :3] - a[:, :3]), quat_mul(rotvec_to_quat(s * rel), a[:, 3:])], dim=1)


def open_hand_start_pose(hand: HandModel, obj_pos: np.ndarray, height: float) -> np.ndarray:
    """(n, 7) base-link poses of the NoInit start: open hand, palm down, wrist link ``height`` m above ``obj_pos``.

    obj_pos: (n, 3) object origins, world, m. Palm down per the hand's wrist convention: ``palm_normal``
    along world -z, ``finger_direction`` toward world +x (as :func:`ges_core.sim_check.grasp_start_pose`).
    """
    from ges_core.kinematics import HandKinematics

    d = hand.description
    q_open = torch.as_tensor(d.open_pose, dtype=torch.float64)[None]
    base_to_wrist = HandKinematics.from_hand(hand).link_poses(q_open, [d.wrist.link])[0, 0].numpy()
    rot = rotation_between_frames(
        np.array(d.wrist.palm_normal),
        np.array(d.wrist.finger_direction),
        np.array([0.0, 0.0, -1.0]),
        np.array([1.0, 0.0, 0.0]),
    )
    world_wrist = np.tile(np.eye(4), (len(obj_pos), 1, 1))
    world_wrist[:, :3, :3] = rot
    world_wrist[:, :3, 3] = np.asarray(obj_pos) + np.array([0.0, 0.0, height])
    return matrix_to_pose(world_wrist @ np.linalg.inv(base_to_wrist))
