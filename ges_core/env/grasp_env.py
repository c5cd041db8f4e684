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
its object to its start pose, through the backend's per-env teleports: the other envs are untouched. See
``docs/env.md``.

One object in every env (``GraspEnv(sim, hand, obj, grasps, cfg)``, one grasp row per env), or a multi-object
environment (:meth:`GraspEnv.from_pool`): each env holds its own object and grasp, and every episode start
draws that env's next (object, grasp) from a weighted :class:`~ges_core.env.grasp_pool.GraspPool`. Either way
``EnvConfig.randomization`` (:mod:`ges_core.env.randomization`) may shift and turn the object's start pose,
scale its mass and friction, and add observation noise, each switchable and seeded.

Faults at the inputs: a wrongly shaped or non-numeric action is one ArrayError, raised before anything reaches
the backend; a NaN or inf in an env's action row ends that env's step as ``unstable`` (its targets stay where
they were, nothing non-finite is stored or sent, the other envs step as if it were not there); bad ``env_ids``
are a ConfigError; every call after :meth:`GraspEnv.close` (or the backend's own ``close()``) is a
SimulationError saying the environment is closed.

The per-control-step maths (wrist target, observation, reward, success) runs in numpy float64 over the
batch and converts to torch once per result: on a few envs, torch's per-op dispatch cost several times the
physics (benchmarks/env_throughput.py). tests/test_env_fast_path.py checks it against the torch helpers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np
import torch
from pydantic import Field

from ges_core.arrays import as_numpy, checked_array
from ges_core.config import ConfigModel, absent_means
from ges_core.env.layout import GOAL_BLOCKS, ActionLayout, ObservationLayout
from ges_core.env.priors import PRIOR_PRESETS, open_hand_start_pose, prior_preset
from ges_core.env.randomization import RandomizationConfig, Randomizer
from ges_core.env.reward import TERMS, RewardConfig, RewardFunction, consistency_groups
from ges_core.env.success import EndReason, SuccessConfig, SuccessTracker
from ges_core.errors import ConfigError, SimulationError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import SimBackend
from ges_core.sim_args import env_id_list
from ges_core.transforms import (
    compose,
    matrix_columns,
    quat_conj,
    quat_mul,
    quat_to_rotvec,
    rotvec_to_quat,
    unit_quat_to_matrix,
)
from ges_core.transforms_torch import interpolate_pose

if TYPE_CHECKING:
    from ges_core.env.grasp_pool import GraspPool

_UNSTABLE = int(EndReason.UNSTABLE)  # plain ints: numpy compares IntEnum members several times slower

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
    wrist_rotation: Literal["matrix", "rotvec"] = Field(
        "matrix",
        description="the observation's wrist rotation: 'matrix', the rotation matrix's first two columns (6 floats, "
        "continuous); 'rotvec', a rotation vector (3 floats; jumps to the opposite vector where the wrist's angle "
        "passes pi; what checkpoints from before 8 December 2026 read)",
        json_schema_extra=absent_means("rotvec"),
    )
    noinit_height: float = Field(
        0.25, gt=0, description="NoInit: metres of the wrist-link origin above the object's origin at the start"
    )
    reward: RewardConfig = Field(default_factory=RewardConfig)
    success: SuccessConfig = Field(default_factory=SuccessConfig)
    randomization: RandomizationConfig = Field(
        default_factory=RandomizationConfig, description="per-episode randomization (every kind off by default)"
    )


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
    """Grasp execution over ``sim``'s envs (hand loaded here): one object in all, or a pool (:meth:`from_pool`)."""

    def __init__(
        self,
        sim: SimBackend,
        hand: HandModel,
        obj: ObjectAsset | None,
        grasps: GraspTargets | None,
        cfg: EnvConfig,
        *,
        pool: GraspPool | None = None,
        env_index=None,
    ) -> None:
        """One object: ``obj`` in every env, ``grasps`` one world-frame row per env. Pool: ``obj`` and ``grasps``
        None, ``pool`` given (use :meth:`from_pool`); each env draws its own entry at every episode start.
        env_index: (n,) global index of each env, seeding its random streams (None: 0..n-1; an env worker
        process passes its slice, :mod:`ges_core.env.workers`)."""
        if (pool is None) == (obj is None or grasps is None) or (pool is not None and (obj, grasps) != (None, None)):
            raise ConfigError(
                "GraspEnv: give either an object and its grasps (one object in every env) or a GraspPool "
                "(GraspEnv.from_pool), not both and not neither"
            )
        self.sim, self.hand, self.obj, self.cfg, self.pool = sim, hand, obj, cfg, pool
        self.n = sim.num_envs
        d = hand.description
        if grasps is not None:
            self._check_grasps(grasps, d.num_joints)
        else:
            grasps = GraspTargets(*(np.zeros((self.n, w)) for w in (7, d.num_joints, 7, d.num_joints)))
        self.grasps = {k: torch.as_tensor(np.asarray(v, dtype=np.float64)) for k, v in vars(grasps).items()}
        """Each env's grasp, world frame (n, ...) float64 (a pool env's row changes when it draws a new entry)."""
        self._goal_pose, self._goal_q = self.grasps["wrist_pose"].numpy(), self.grasps["q"].numpy()
        self.tip_links = list(d.tip_links)
        self.tip_offsets = torch.tensor([f.tip_offset for f in d.fingers], dtype=torch.float64)
        self._tip_offsets = self.tip_offsets.numpy()[:, :, None]  # (F, 3, 1) for batched R @ offset
        self.contact_links = list(dict.fromkeys([*d.tip_links, d.wrist.link]))
        self.obs_layout = ObservationLayout.for_hand(
            d, tuple(self.contact_links), goal=cfg.goal_prior, wrist_rotation=cfg.wrist_rotation
        )
        lim = torch.as_tensor(d.limits_array)
        self.act_layout = ActionLayout(lim[:, 0], lim[:, 1], cfg.max_wrist_step, cfg.max_wrist_turn)
        self._action_shape, self._action_doc = (self.n, self.act_layout.size), self.act_layout.describe()
        self.finger_joints = [torch.as_tensor(d.joint_index(f.joints)) for f in d.fingers]
        self.groups = consistency_groups(d)
        self._reward = RewardFunction(cfg.reward, self.finger_joints, self.groups, d.num_joints)
        self.tracker = SuccessTracker(cfg.success, self.n, cfg.sim_steps)
        self.control_dt = cfg.sim_steps * sim.config.timestep
        self.prev_action = np.zeros((self.n, self.act_layout.size))
        """(n, K + 6) float64, the last action clipped to [-1, 1] (zeros at an episode start and for a bad row)."""
        self.wrist_target = np.zeros((self.n, 7))
        """(n, 7) float64 wrist (base-link) targets, world: integrated by :meth:`apply_action`."""
        self.joint_target = np.zeros((self.n, d.num_joints))
        """(n, K) float64 joint targets last sent, rad (the episode's start joints after a reset)."""
        self.bad_actions: np.ndarray | None = None
        """(n,) bool, the envs whose row of the last :meth:`apply_action` held NaN or inf; None: none did."""
        self.goal_obs = np.zeros((self.n, 6 + d.num_joints), dtype=np.float32)
        """(n, 6 + K) float32, NoGoal layouts only (``goal_prior=False``): the goal blocks G (:data:`GOAL_BLOCKS`
        order, exact: no observation noise) of the latest :meth:`observe`, which the policy does not see. What a
        teacher that knows the goal reads beside it (``ObservationLayout.add_goal``: the NoGoal warm start)."""
        self._last_terms: tuple[dict | None, np.ndarray | None] = (None, None)  # see terms_array
        self._last_state: tuple = (None, None, None)  # see _state_arrays
        self._quat_buf = (np.empty((2, self.n, 4)), np.empty((2, self.n, 4)), np.empty((3, self.n, 4)))
        self.random = Randomizer(
            cfg.randomization, self.obs_layout.slices, range(self.n) if env_index is None else env_index
        )
        self.objects: list[ObjectAsset | None] = [None] * self.n
        """The object each env holds, as loaded (mass and friction randomization included)."""
        self.entry = np.full(self.n, -1, dtype=np.int64)
        """(n,) the pool entry each env's episode runs (-1: no pool)."""
        self.rest_pose = np.zeros((self.n, 7))
        """(n, 7) world pose each env's object rests at after loading (the frame its grasp is given in)."""
        self.start_pose = np.zeros((self.n, 7))
        """(n, 7) world pose each env's object started its episode at (rest pose, randomized if switched on)."""
        self.noinit_start = torch.zeros((self.n, 7), dtype=torch.float64)
        """(n, 7) NoInit: base poses of the open hand above each env's object (set at episode starts)."""
        sim.load_hand(hand, floating=True)
        if pool is None:
            sim.load_object(obj)
            self.objects = [obj] * self.n
            self.rest_pose[:] = sim.object_pose()
        self._place(list(range(self.n)))

    @classmethod
    def from_pool(cls, sim: SimBackend, hand: HandModel, pool: GraspPool, cfg: EnvConfig, env_index=None) -> GraspEnv:
        """A multi-object environment: every env draws its (object, grasp) from ``pool`` at each episode start."""
        return cls(sim, hand, None, None, cfg, pool=pool, env_index=env_index)

    @property
    def object_ids(self) -> list[str]:
        """The object id each env holds."""
        return [o.object_id for o in self.objects]

    def reseed(self, seed: int) -> None:
        """Restart the randomization's and the pool draws' random streams from ``seed``."""
        self.random.reseed(seed)

    def _place(self, ids: list[int]) -> None:
        """Choose the objects of envs ``ids`` for their next episode: a pool draw, mass and friction randomized
        (each switchable), loaded where it changed; set their rest poses, grasps, start poses and NoInit starts.

        The objects are left at their rest poses (a fresh load) or where they were: the caller teleports them
        to :attr:`start_pose`."""
        if self.pool is not None:
            self.entry[ids] = self.random.pool_entries(self.pool, ids)
            base = [self.pool.entries[k].asset for k in self.entry[ids]]
        else:
            base = [self.obj] * len(ids)
        changed: dict[int, list[int]] = {}  # id(asset) -> envs to load it into (one load_object call per asset)
        assets = {}
        for e, asset in zip(ids, base, strict=True):
            asset = self.random.physics(asset, e)
            if asset is not self.objects[e]:
                changed.setdefault(id(asset), []).append(e)
                assets[id(asset)] = asset
                self.objects[e] = asset
        for key, envs in changed.items():
            self.sim.load_object(assets[key], env_ids=envs)  # rests it on the table at the origin
        loaded = [e for envs in changed.values() for e in envs]
        if loaded:
            self.rest_pose[loaded] = self.sim.object_pose()[loaded]
        if self.pool is not None:
            self._set_pool_grasps(ids)
        self.start_pose[ids] = self.random.start_poses(self.rest_pose[ids], ids)
        if not self.cfg.init_prior:
            start = open_hand_start_pose(self.hand, self.rest_pose[ids, :3], self.cfg.noinit_height)
            self.noinit_start[ids] = torch.as_tensor(start)

    def _set_pool_grasps(self, ids: list[int]) -> None:
        """Grasp rows of envs ``ids`` from their pool entries, mapped to the world through each rest pose."""
        g = {k: v.numpy() for k, v in self.grasps.items()}  # views: writes reach the tensors
        for e in ids:
            entry, rest = self.pool.entries[self.entry[e]], self.rest_pose[e]
            g["wrist_pose"][e] = compose(rest, entry.wrist_pose)
            g["pre_wrist_pose"][e] = compose(rest, entry.pre_wrist_pose)
            g["q"][e], g["pre_q"][e] = entry.q, entry.pre_q

    def _check_grasps(self, g: GraspTargets, k: int) -> None:
        """ArrayError unless every field holds one finite row per env: poses (n, 7), joints (n, K)."""
        for name, value in vars(g).items():
            width, layout = (7, "x, y, z, qw, qx, qy, qz, world") if "pose" in name else (k, "hand joint_names order")
            checked_array(value, (self.n, width), f"GraspTargets: {name}", layout=f"one row per env; {layout}")

    # -- resets ----------------------------------------------------------------------------
    def reset_all(self) -> None:
        """Every env: object drawn (a pool) and at its start pose, hand at its episode start (:meth:`start_state`),
        ``settle_steps`` holding.

        Init: the hand starts ``reach_offset`` above the pre-grasp and stage one (PD reaching) takes it
        there. NoInit: the open hand is teleported to its fixed start above the object; no reaching.
        """
        self._check_open("reset_all")
        sim, cfg = self.sim, self.cfg
        sim.reset()
        if self.pool is None and not self._reloads():
            self.rest_pose[:] = sim.object_pose()  # the one object, at its load pose: no reload, no draw
        self._place(list(range(self.n)))
        if self.random.cfg.active("start_pose"):
            sim.set_object_pose(self.start_pose)
        q, pose = self.start_state(torch.arange(self.n))
        if cfg.init_prior:
            self._reach(q, pose)
        else:
            sim.set_hand_state(q.numpy(), pose.numpy())
        sim.step(cfg.sim_steps * cfg.settle_steps)
        self._begin(np.arange(self.n), q.numpy())

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
        (above each env's object, set when its episode starts).
        """
        if self.cfg.init_prior:
            return self.grasps["pre_q"][env_ids], self.grasps["pre_wrist_pose"][env_ids]
        q_open = torch.as_tensor(self.hand.description.open_pose, dtype=torch.float64)
        return q_open.expand(len(env_ids), -1).clone(), self.noinit_start[env_ids]

    def reset_envs(self, env_ids) -> None:
        """Envs ``env_ids``: next object drawn (a pool) and placed at its start pose, hand at its episode start
        (:meth:`start_state`); others untouched.

        No stage one here: the hand is teleported straight to where the policy takes over. env_ids: distinct
        env indices as the backends take them: a list or tuple of ints, a 1-D numpy or torch integer array
        (``[]``: none; None: every env). A float, out-of-range, negative or repeated id, a boolean mask (give
        ``mask.nonzero()``) or a scalar is one ConfigError, raised before any env changes.
        """
        self._check_open("reset_envs")
        ids = env_id_list(env_ids, self.n, "GraspEnv.reset_envs")
        if not ids:
            return
        self._place(ids)
        q, pose = self.start_state(torch.tensor(ids))
        self.sim.set_hand_state(q.numpy(), pose.numpy(), env_ids=ids)  # also restores a blown-up env
        self.sim.set_object_pose(self.start_pose[ids], env_ids=ids)
        self._begin(np.array(ids), q.numpy())

    def _reloads(self) -> bool:
        """True when an episode start may load a new object (a pool, or mass or friction randomized)."""
        r = self.random.cfg
        return self.pool is not None or r.active("mass") or r.active("friction")

    def _begin(self, ids: np.ndarray, q: np.ndarray) -> None:
        """Start episodes in envs ``ids`` (m,) whose hands were just put at joints ``q`` (m, K): targets there."""
        wrist = self.sim.wrist_pose()
        self.wrist_target[ids] = wrist[ids]
        self.joint_target[ids] = q
        self.wrist_prev = wrist
        """(n, 7) the wrist pose at the last observation (for the finite-difference velocity)."""
        self.prev_action[ids] = 0.0
        self.tracker.reset(ids, self.sim.object_pose()[ids, :3])

    # -- stepping --------------------------------------------------------------------------
    def apply_action(self, action: torch.Tensor, *, what: str = "GraspEnv.apply_action: action") -> torch.Tensor:
        """Set targets from ``action`` (n, K + 6) and step; returns (n,) bool, the envs to end ``unstable``.

        action: torch or numpy, :class:`~ges_core.env.layout.ActionLayout` order, clipped to [-1, 1]. A wrong
        shape or a non-numeric value is one ArrayError (``what`` names the argument), raised before anything
        reaches the backend. An env whose row holds NaN or inf keeps its wrist and joint targets for this step
        (its ``prev_action`` row becomes zeros), is listed in :attr:`bad_actions` and returned as unstable,
        like an env whose state blew up (:meth:`_step_physics`); the other envs step as if it were not there.
        """
        self._check_open("apply_action")
        raw = checked_array(action, self._action_shape, what, layout=self._action_doc, finite=False)
        a = np.maximum(raw, -1.0)  # a new array: raw may share the caller's memory
        np.minimum(a, 1.0, out=a)
        bad = None if np.isfinite(raw).all() else ~np.isfinite(raw).all(axis=1)  # inf clips to +-1: test raw
        if bad is not None:
            a[bad] = 0.0
        delta = self.act_layout.wrist_deltas_np(a)  # (n, 6): metres, then a rotation vector (world, rad)
        wt = self.wrist_target
        target = np.empty_like(wt)
        np.add(wt[:, :3], delta[:, :3], out=target[:, :3])
        quat_mul(rotvec_to_quat(delta[:, 3:]), wt[:, 3:], out=target[:, 3:])
        joints = self.act_layout.joint_targets_np(a)
        if bad is not None:
            target[bad], joints[bad] = wt[bad], self.joint_target[bad]
        self.sim.set_wrist_targets(target)
        self.sim.set_joint_targets(joints)
        self.wrist_target, self.joint_target, self.prev_action, self.bad_actions = target, joints, a, bad
        unstable = self._step_physics()
        return unstable if bad is None else unstable | torch.from_numpy(bad)

    def _step_physics(self) -> torch.Tensor:
        """Step ``sim_steps``; on SimulationError mark its ``env_ids`` (every env if it names none) unstable.

        The backend finishes the step in every healthy env before raising."""
        unstable = np.zeros(self.n, dtype=bool)
        try:
            self.sim.step(self.cfg.sim_steps)
        except SimulationError as err:
            unstable[list(err.env_ids) if err.env_ids else slice(None)] = True
        return torch.from_numpy(unstable)

    def observe(self, *, noise_rows=None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Flat observation (n, obs size) float32 and the raw state (float64) reused by rewards.

        State: ``q``, ``dq`` (n, K); ``tip_world`` (n, F, 3) fingertip points, world, m; ``obj`` (n, 3)
        object origin, world, m; ``wrist_vel`` (n, 6). Each call advances the wrist velocity's finite
        difference (a second call without physics in between reads zero). noise_rows: the envs that draw
        observation noise (None: all; the others' rows stay noise-free and their noise streams untouched).
        """
        self._check_open("observe")
        sim = self.sim
        q, dq = sim.joint_state()
        wrist = sim.wrist_pose()
        forces = sim.contact_forces(self.contact_links, "object")
        tips = sim.link_poses(self.tip_links)
        obj = sim.object_pose()[:, :3]
        with np.errstate(all="ignore"):  # a blown-up env reads NaN or huge values; keep going like torch
            blocks, tip_world, vel = self._blocks(q, dq, wrist, forces, tips, obj)
        arrays = {"q": q, "dq": dq, "tip_world": tip_world, "obj": obj, "wrist_vel": vel}
        state = {name: torch.from_numpy(value) for name, value in arrays.items()}
        self._last_state = (state, arrays, blocks["goal_q"])
        flat = self.obs_layout.pack_np(blocks)
        if not self.obs_layout.goal:
            self.goal_obs = np.concatenate([blocks[name] for name in GOAL_BLOCKS], axis=1, dtype=np.float32)
        self.random.add_noise(flat, noise_rows)  # the policy's view only: the state (reward, success) stays exact
        return torch.from_numpy(flat), state

    def _state_arrays(self, state: dict[str, torch.Tensor]) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Numpy float64 views of a state dict of :meth:`observe` and its goal joint error (n, K) (grasp - q).

        The latest observation's arrays are reused as they are (the tensors share their memory)."""
        if state is self._last_state[0]:
            return self._last_state[1], self._last_state[2]
        arrays = {name: as_numpy(value, np.float64) for name, value in state.items()}
        return arrays, self._goal_q - arrays["q"]

    def _blocks(self, q, dq, wrist, forces, tips, obj) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
        """Observation blocks (n, size) float64, fingertip points (n, F, 3) and wrist velocity (n, 6) from reads.

        One rotation-matrix batch for the wrist and the tips; one quaternion product for the goal rotation
        and the wrist's turn since the last observation, one rotation-vector batch for those and the wrist.
        """
        n, f = len(q), len(self.tip_links)
        ab, wv, rv = self._quat_buf  # (2, n, 4): goal, wrist; (2, n, 4): wrist, previous wrist; (3, n, 4)
        rot = unit_quat_to_matrix(np.concatenate([wrist[:, None, 3:], tips[..., 3:]], axis=1))  # (n, 1 + F, 3, 3)
        tip_world = tips[..., :3] + (rot[:, 1:] @ self._tip_offsets)[..., 0]
        wpos, wq, prev = wrist[:, :3], wrist[:, 3:], self.wrist_prev
        local = np.concatenate([forces[:, :f], tip_world - wpos[:, None]], axis=1) @ rot[:, 0]  # v @ R = R^T v
        ab[0], ab[1], wv[0], wv[1], rv[0] = self._goal_pose[:, 3:], wq, wq, prev[:, 3:], wq
        quat_mul(ab, quat_conj(wv), out=rv[1:])  # goal * wrist^-1, wrist * previous^-1
        rotvec = quat_to_rotvec(rv)  # (3, n, 3): wrist, goal rotation, turn since the last observation
        vel = np.concatenate([wpos - prev[:, :3], rotvec[2]], axis=1) / self.control_dt
        self.wrist_prev = wrist
        blocks = {
            "q": q,
            "dq": dq,
            "contact": np.sqrt(np.einsum("nli,nli->nl", forces, forces)) > self.cfg.contact_threshold,
            "tip_force": local[:, :f].reshape(n, -1),
            "tip_pos": local[:, f:].reshape(n, -1),
            "wrist_pose": np.concatenate([wpos, self._wrist_rotation(rot[:, 0], rotvec[0])], axis=1),
            "wrist_vel": vel,
            "prev_action": self.prev_action,
            "obj_pos": obj,
            "goal_pos": self._goal_pose[:, :3] - wpos,
            "goal_rot": rotvec[1],
            "goal_q": self._goal_q - q,
        }
        return blocks, tip_world, vel

    def _wrist_rotation(self, matrix: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
        """(n, R) the ``wrist_pose`` block's rotation part from the wrist's (n, 3, 3) matrix and (n, 3) rotation
        vector, in the form ``EnvConfig.wrist_rotation`` names (:data:`~ges_core.env.layout.WRIST_ROTATIONS`)."""
        if self.cfg.wrist_rotation == "rotvec":
            return rotvec
        return matrix_columns(matrix)

    def reward(self, state: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Reward (n,) float64 and its terms (n,) before weighting, for the state returned by :meth:`observe`."""
        arrays, q_error = self._state_arrays(state)
        total, terms = self._reward(
            q_error=q_error,
            tip_pos=arrays["tip_world"],
            obj_pos=arrays["obj"],
            obj_start=self.tracker.start.numpy(),
            joint_vel=arrays["dq"],
            wrist_vel=arrays["wrist_vel"],
        )
        out = dict(zip(TERMS, torch.from_numpy(terms).unbind(), strict=True))
        self._last_terms = (out, terms)
        return torch.from_numpy(total), out

    def terms_array(self, terms: dict[str, torch.Tensor]) -> np.ndarray:
        """(T, n) float64 reward terms in :data:`~ges_core.env.reward.TERMS` order, for a terms dict of :meth:`reward`.

        The array behind the latest :meth:`reward` result without a copy; any other dict is stacked anew.
        """
        if terms is self._last_terms[0]:
            return self._last_terms[1]
        return torch.stack([terms[name] for name in TERMS]).numpy()

    # -- lifetime ------------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """True after :meth:`close`, or once the backend itself was closed (the backend's flag is the one state)."""
        return self.sim.closed

    def close(self) -> None:
        """Close the backend; every later call raises SimulationError. Calling twice is harmless."""
        self.sim.close()

    def check_open(self, who: str) -> None:
        """SimulationError (no ``env_ids``) naming ``who`` once the environment is :attr:`closed`."""
        if self.closed:
            raise SimulationError(
                f"{who}: the environment is closed; build a new one (a GraspEnv over a new backend from "
                "registry.build_sim) instead of reusing it"
            )

    def _check_open(self, method: str) -> None:
        self.check_open(f"GraspEnv.{method}")

    def end_reasons(self, state: dict[str, torch.Tensor], timeout: torch.Tensor, unstable: torch.Tensor):
        """(n,) int64 EndReason codes after a control step; timeout and unstable: (n,) bool, torch or numpy."""
        reason = self.tracker.update(self._state_arrays(state)[0]["obj"], timeout)
        bad = as_numpy(unstable)
        return torch.from_numpy(np.where(bad, _UNSTABLE, reason.numpy())) if bad.any() else reason
