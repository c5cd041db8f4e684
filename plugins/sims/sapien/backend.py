"""The SAPIEN 3 backend: ``num_envs`` CPU PhysX scenes, headless, stepped one after another.

Frames and units follow :mod:`ges_core.sim`: world frame, metres, quaternions w, x, y, z (SAPIEN's
own convention, so poses pass through unchanged). Joint vectors are in the hand's
``joint_names`` order; SAPIEN's breadth-first order is mapped once in :meth:`SapienBackend.load_hand`.
With self-collision on, hand links collide except the pairs of :func:`ges_core.urdf.neighbour_link_pairs`
(PhysX skips parent-child pairs itself; the others get collision-group bits, :func:`.loading.pair_exclusion_bits`).

An env that blew up is restored by teleports alone (:meth:`SapienBackend.reset` of that env): after a
NaN or 500 m/s object velocity or a NaN joint velocity it then evolves bit for bit like the same env of
a backend that never blew up (``tests/test_sim_env_ids.py``). Bodies are never removed for it (reading
contacts of a removed body segfaults).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ges_core.errors import ConfigError, SimulationError
from ges_core.hand import HandDescription, HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import ContactPair, ContactPartner, SceneConfig, SimBackend, check_env_rows, env_id_list
from ges_core.urdf import quat_to_euler_xyz
from ges_plugins.sims.sapien import loading
from ges_plugins.sims.sapien.checks import MAX_JOINT_SPEED, MAX_OBJECT_SPEED, blown_message, state_problem
from ges_plugins.sims.sapien.contacts import PARTNERS, ContactReader
from ges_plugins.sims.sapien.engine import sapien
from ges_plugins.sims.sapien.poses import PoseTable, sapien_pose

__all__ = ["MAX_JOINT_SPEED", "MAX_OBJECT_SPEED", "SapienBackend"]

_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
"""(7,) the identity pose: x, y, z, qw, qx, qy, qz."""


@dataclass
class _Env:
    """One scene and handles into it."""

    scene: sapien.Scene
    contacts: ContactReader
    hand: sapien.physx.PhysxArticulation | None = None
    wrist_joints: list = field(default_factory=list)
    """Six virtual wrist joints, outermost first (floating hands only)."""
    hand_joints: list = field(default_factory=list)
    """Hand joints in ``joint_names`` order."""
    obj: sapien.Entity | None = None
    obj_body: sapien.physx.PhysxRigidDynamicComponent | None = None
    obj_load_pose: np.ndarray | None = None
    poses: PoseTable | None = None


class SapienBackend(SimBackend):
    """SAPIEN 3.0 CPU PhysX behind :class:`ges_core.sim.SimBackend`."""

    name = "sapien"

    def __init__(self, config: SceneConfig, *, contact_offset: float | None = None) -> None:
        """contact_offset: per-shape contact offset, metres (registry setting); None keeps SAPIEN's 0.01.

        PhysX lists (and solves, as speculative contacts) every shape pair closer than the sum of the
        two offsets; 0.002 (IsaacGymEnvs' hand tasks) lists about half the pairs of the default.
        """
        super().__init__(config)
        if contact_offset is not None and not 0.0 < contact_offset <= 0.1:
            raise ConfigError(f"sapien: contact_offset={contact_offset} m; give a value in (0, 0.1] or leave it unset")
        self._contact_offset = contact_offset
        self._envs: list[_Env] = []
        for _ in range(config.num_envs):
            scene = loading.create_scene(config)
            table = scene.entities[0].find_component_by_type(sapien.physx.PhysxRigidStaticComponent)
            loading.set_contact_offset([table], contact_offset)
            self._envs.append(_Env(scene=scene, contacts=ContactReader(scene, table, config.timestep)))
        self._description: HandDescription | None = None
        self._floating = False
        self._base_link = ""
        self._start_qpos = np.zeros(0, dtype=np.float32)
        """(D,) SAPIEN qpos of the open hand with the wrist joints at zero."""
        self._reset_base = np.tile(_IDENTITY, (config.num_envs, 1))
        """(num_envs, 7) base pose that reset() returns to: the last one given to set_hand_state."""
        self.idx_sim_to_hand = np.zeros(0, dtype=np.int64)
        """(K,) ``q_hand = q_fingers[idx_sim_to_hand]``; ``q_fingers`` = SAPIEN's active-joint vector
        after the six wrist joints."""
        self.idx_hand_to_sim = np.zeros(0, dtype=np.int64)
        """(K,) ``q_fingers = q_hand[idx_hand_to_sim]``."""
        self._blown: set[int] = set()
        """Envs reported by step() as blown up and not restored since."""
        self._closed = False
        self._all_have_objects = False

    # -- building -------------------------------------------------------------------------
    def load_hand(self, hand: HandModel, *, floating: bool = True) -> None:
        self._live()
        if self._description is not None:
            raise SimulationError(
                f"sapien: hand '{self._description.name}' is already loaded; build a new backend for '{hand.name}'"
            )
        urdf = loading.prepare_urdf(hand, floating=floating)
        pair_bits = loading.pair_exclusion_bits(hand.name, hand.urdf_text()) if self.config.self_collision else None
        description = hand.description
        for env in self._envs:
            env.hand = loading.build_hand(env.scene, urdf, self.config, pair_bits)
            loading.set_contact_offset(env.hand.get_links(), self._contact_offset)
            joints, self.idx_sim_to_hand, self.idx_hand_to_sim = loading.sim_joint_order(
                env.hand, description, floating=floating
            )
            loading.set_drives(joints, description, self.idx_sim_to_hand, self.config)
            n_wrist = len(joints) - description.num_joints
            env.wrist_joints = joints[:n_wrist]
            env.hand_joints = [joints[n_wrist + int(i)] for i in self.idx_sim_to_hand]
            env.contacts.set_hand({link.name: link for link in env.hand.get_links()})
            env.poses = None
        base = env.wrist_joints[-1].child_link if floating else env.hand.get_links()[0]
        self._description, self._floating, self._base_link = description, floating, base.name
        self._start_qpos = self._sim_qpos(np.asarray(description.open_pose, dtype=np.float64))
        self._reset_hand(list(range(self.num_envs)))

    def load_object(
        self,
        obj: ObjectAsset,
        pose: np.ndarray | None = None,
        env_ids: Sequence[int] | None = None,
        *,
        fixed: bool = False,
    ) -> None:
        self._live()
        ids = env_id_list(env_ids, self.num_envs, "sapien.load_object")
        check_env_rows(pose, env_ids, ids, "sapien.load_object", "pose")
        poses = None if pose is None else self._poses(pose, len(ids), "load_object pose")
        self._restore(ids)
        for row, env_id in enumerate(ids):
            env = self._envs[env_id]
            if env.obj is not None:
                env.scene.remove_entity(env.obj)
            env.obj = loading.build_object(env.scene, obj, self.config)
            env.obj_body = env.obj.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
            env.obj_body.kinematic = bool(fixed)
            loading.set_contact_offset([env.obj_body], self._contact_offset)
            if poses is None:
                start = np.array([0.0, 0.0, loading.rest_height(env.obj), 1.0, 0.0, 0.0, 0.0])
            else:
                start = poses[row]
            env.obj_load_pose = start
            self._teleport_object(env, start)
            env.contacts.set_object(env.obj_body, obj.object_id)
            env.poses = None

    # -- commands -------------------------------------------------------------------------
    def set_joint_targets(self, q: np.ndarray) -> None:
        q = self._joint_array(q, self.num_envs, "set_joint_targets q")
        for env, row in zip(self._envs, q.tolist(), strict=True):
            for joint, target in zip(env.hand_joints, row, strict=True):
                joint.set_drive_target(target)

    def set_wrist_targets(self, pose: np.ndarray) -> None:
        self._need_floating("set_wrist_targets")
        pose = self._poses(pose, self.num_envs, "set_wrist_targets pose")
        for env, row in zip(self._envs, pose.tolist(), strict=True):
            current = env.hand.get_qpos()[3:6].tolist()
            targets = row[:3] + [_unwrap(a, c) for a, c in zip(euler_xyz(*row[3:]), current, strict=True)]
            for joint, target in zip(env.wrist_joints, targets, strict=True):
                joint.set_drive_target(target)

    def set_hand_state(
        self, q: np.ndarray, wrist_pose: np.ndarray | None = None, *, env_ids: Sequence[int] | None = None
    ) -> None:
        """Teleport the hand of envs ``env_ids`` (all if None): q (M, K) rad, wrist_pose (M, 7) or None;
        M = len(env_ids) or num_envs. Zero velocity, drive targets at the new state; other envs untouched."""
        self._need_hand("set_hand_state")
        ids = env_id_list(env_ids, self.num_envs, "sapien.set_hand_state")
        check_env_rows(q, env_ids, ids, "sapien.set_hand_state", "q")
        check_env_rows(wrist_pose, env_ids, ids, "sapien.set_hand_state", "wrist_pose")
        q = self._joint_array(q, len(ids), "set_hand_state q")
        wrist = None if wrist_pose is None else self._poses(wrist_pose, len(ids), "set_hand_state wrist_pose")
        coords = None if wrist is None or not self._floating else self._wrist_coordinates(wrist)
        self._restore(ids)
        for row, e in enumerate(ids):
            env = self._envs[e]
            qpos = env.hand.get_qpos()
            qpos[len(env.wrist_joints) :] = q[row][self.idx_hand_to_sim]
            if coords is not None:
                qpos[:6] = coords[row]
            elif wrist is not None:
                env.hand.set_root_pose(sapien_pose(wrist[row]))
            self._teleport_hand(env, qpos)
        if wrist is not None:
            self._reset_base[ids] = wrist

    def set_object_pose(self, pose: np.ndarray, *, env_ids: Sequence[int] | None = None) -> None:
        """Teleport the object of envs ``env_ids`` (all if None), pose (M, 7) world frame, zero velocity."""
        self._live()
        ids = env_id_list(env_ids, self.num_envs, "sapien.set_object_pose")
        check_env_rows(pose, env_ids, ids, "sapien.set_object_pose", "pose")
        pose = self._poses(pose, len(ids), "set_object_pose pose")
        envs = self._objects("set_object_pose", ids)
        self._restore(ids)
        for e, row in zip(ids, pose, strict=True):
            self._teleport_object(envs[e], row)

    def step(self, n: int = 1) -> None:
        """Advance every scene ``n`` steps, checking each after every step; a scene that blew up is not stepped
        further, and one SimulationError at the end lists every such env (``env_ids``)."""
        self._live()
        if n < 0:
            raise SimulationError(f"sapien.step: n={n}; give a number of steps >= 0")
        blown: dict[int, str] = {}
        for _ in range(n):
            for e, env in enumerate(self._envs):
                if e in blown:
                    continue
                env.scene.step()
                env.contacts.after_step()
                problem = state_problem(e, env.hand, env.obj_body)
                if problem is not None:
                    blown[e] = problem
        if blown:
            self._blown.update(blown)
            raise SimulationError(blown_message(blown), env_ids=blown)

    def engine_step(self) -> None:
        """One raw ``scene.step()`` per scene: no state check, no bookkeeping (for benchmarks)."""
        for env in self._envs:
            env.scene.step()
            env.contacts.after_step()

    # -- reading --------------------------------------------------------------------------
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        self._need_hand("joint_state")
        n_wrist = 6 if self._floating else 0
        qpos = np.empty((self.num_envs, self._description.num_joints))
        qvel = np.empty_like(qpos)
        for e, env in enumerate(self._envs):
            qpos[e] = env.hand.get_qpos()[n_wrist:][self.idx_sim_to_hand]
            qvel[e] = env.hand.get_qvel()[n_wrist:][self.idx_sim_to_hand]
        return qpos, qvel

    def wrist_pose(self) -> np.ndarray:
        self._need_hand("wrist_pose")
        return self.link_poses([self._base_link])[:, 0]

    def link_poses(self, links: Sequence[str]) -> np.ndarray:
        self._need_hand("link_poses")
        out = np.empty((self.num_envs, len(links), 7))
        for e, env in enumerate(self._envs):
            out[e] = self._pose_table(env).read(links)
        return out

    def contact_forces(self, links: Sequence[str], partner: ContactPartner = "object") -> np.ndarray:
        self._need_hand("contact_forces")
        if partner not in PARTNERS:
            raise SimulationError(f"sapien.contact_forces: partner '{partner}' is not one of {', '.join(PARTNERS)}")
        out = np.empty((self.num_envs, len(links), 3))
        for e, env in enumerate(self._envs):
            out[e] = env.contacts.forces(links, partner)
        return out

    def object_pose(self) -> np.ndarray:
        out = np.empty((self.num_envs, 7))
        for e, env in enumerate(self._objects("object_pose")):
            out[e] = self._pose_table(env).read_object()
        return out

    def contact_pairs(self, env_id: int = 0) -> list[ContactPair]:
        self._live()
        return self._envs[env_id_list([env_id], self.num_envs, "sapien.contact_pairs")[0]].contacts.pairs()

    # -- lifetime -------------------------------------------------------------------------
    def reset(self, *, env_ids: Sequence[int] | None = None) -> None:
        """Envs ``env_ids`` (all if None): open hand at the base pose last given to set_hand_state (else the
        origin), targets there, at rest; objects at their load poses. Other envs untouched."""
        self._live()
        ids = env_id_list(env_ids, self.num_envs, "sapien.reset")
        self._reset_envs(ids)
        self._blown.difference_update(ids)

    def _restore(self, ids: list[int]) -> None:
        """Reset every env among ``ids`` that blew up (module docs: teleports bring it back)."""
        bad = sorted(self._blown.intersection(ids))
        if bad:
            self._reset_envs(bad)
            self._blown.difference_update(bad)

    def _reset_envs(self, ids: list[int]) -> None:
        if self._description is not None:
            self._reset_hand(ids)
        for e in ids:
            env = self._envs[e]
            if env.obj is not None:
                self._teleport_object(env, env.obj_load_pose)

    def _reset_hand(self, ids: list[int]) -> None:
        """Hands of envs ``ids`` open with their base at ``_reset_base``, every drive target there, at rest."""
        coords = self._wrist_coordinates(self._reset_base[ids]) if self._floating else None
        for row, e in enumerate(ids):
            env = self._envs[e]
            qpos = self._start_qpos.copy()
            if coords is not None:
                qpos[:6] = coords[row]
            else:
                env.hand.set_root_pose(sapien_pose(self._reset_base[e]))
            self._teleport_hand(env, qpos)

    def close(self) -> None:
        self._envs = []
        self._closed = True

    # -- helpers --------------------------------------------------------------------------
    def _sim_qpos(self, q_hand: np.ndarray) -> np.ndarray:
        """(D,) float32 SAPIEN qpos: wrist joints at zero, hand joints from ``q_hand`` (K,)."""
        n_wrist = 6 if self._floating else 0
        return np.concatenate([np.zeros(n_wrist), q_hand[self.idx_hand_to_sim]]).astype(np.float32)

    def _teleport_hand(self, env: _Env, qpos: np.ndarray) -> None:
        env.hand.set_qpos(qpos)
        env.hand.set_qvel(np.zeros_like(qpos))
        for joint, target in zip(env.hand.get_active_joints(), qpos.tolist(), strict=True):
            joint.set_drive_target(target)

    @staticmethod
    def _teleport_object(env: _Env, pose: np.ndarray) -> None:
        env.obj.pose = sapien_pose(pose)
        env.obj_body.set_linear_velocity(np.zeros(3))
        env.obj_body.set_angular_velocity(np.zeros(3))

    @staticmethod
    def _wrist_coordinates(pose: np.ndarray) -> np.ndarray:
        """(N, 7) base poses -> (N, 6) wrist joint values: x, y, z, then (rx, ry, rz) of R = Rx Ry Rz."""
        return np.concatenate([pose[:, :3], quat_to_euler_xyz(pose[:, 3:])], axis=1)

    def _pose_table(self, env: _Env) -> PoseTable:
        if env.poses is None:
            env.poses = PoseTable(env.scene, env.hand, env.obj)
        return env.poses

    # -- argument checks ------------------------------------------------------------------
    def _live(self) -> None:
        if self._closed:
            raise SimulationError("sapien: this backend is closed; build a new one with registry.build_sim('sapien')")

    def _need_hand(self, what: str) -> None:
        self._live()
        if self._description is None:
            raise SimulationError(f"sapien.{what}: no hand loaded; call load_hand(hand) first")

    def _need_floating(self, what: str) -> None:
        self._need_hand(what)
        if not self._floating:
            raise SimulationError(
                f"sapien.{what}: the hand was loaded with floating=False; move it with set_hand_state(q, wrist_pose)"
            )

    def _objects(self, what: str, ids: Sequence[int] | None = None) -> list[_Env]:
        """Every env, once the envs ``ids`` (all if None) are checked to hold an object."""
        self._live()
        if self._all_have_objects:
            return self._envs
        empty = [e for e in (range(self.num_envs) if ids is None else ids) if self._envs[e].obj is None]
        self._all_have_objects = ids is None and not empty
        if empty:
            raise SimulationError(f"sapien.{what}: no object in env(s) {empty}; call load_object(obj) first")
        return self._envs

    def _joint_array(self, q: np.ndarray, rows: int, what: str) -> np.ndarray:
        """``q`` checked as (rows, K) finite values, hand joint order."""
        self._need_hand(what.split()[0])
        return _checked(q, (rows, self._description.num_joints), what, "hand joint_names order")

    @staticmethod
    def _poses(pose: np.ndarray, rows: int, what: str) -> np.ndarray:
        """``pose`` as (rows, 7) float64; a (7,) pose is repeated. Quaternions are checked, not normalised."""
        pose = np.asarray(pose, dtype=np.float64)
        pose = np.broadcast_to(pose, (rows, 7)) if pose.shape == (7,) else pose
        pose = _checked(pose, (rows, 7), what, "x, y, z, qw, qx, qy, qz")
        norms = np.einsum("ij,ij->i", pose[:, 3:], pose[:, 3:])
        if not (norms.min() > 1e-12):
            raise SimulationError(f"sapien: {what} has a zero quaternion; poses are (x, y, z, qw, qx, qy, qz)")
        return pose


def _checked(array: np.ndarray, shape: tuple[int, ...], what: str, layout: str) -> np.ndarray:
    """``array`` as float64 if it has ``shape`` and only finite values, else a SimulationError."""
    array = np.asarray(array, dtype=np.float64)
    if array.shape != shape:
        raise SimulationError(f"sapien: {what} has shape {array.shape}, expected {shape} ({layout})")
    if not np.all(np.isfinite(array)):
        raise SimulationError(f"sapien: {what} holds NaN or inf values; check the command's source")
    return array


def _unwrap(angle: float, current: float) -> float:
    """``angle`` shifted by a multiple of 2 pi to lie within pi of ``current`` (no full turns of the wrist)."""
    return current + (angle - current + math.pi) % (2 * math.pi) - math.pi


def euler_xyz(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Quaternion -> (rx, ry, rz) with R = Rx Ry Rz: :func:`ges_core.urdf.quat_to_euler_xyz` for one pose.

    The same formula in scalar math: 1 µs instead of 30 µs of small-array numpy per call (tested equal).
    """
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    ry = math.asin(max(-1.0, min(1.0, 2 * (x * z + w * y))))
    rx = math.atan2(-2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
    rz = math.atan2(-2 * (x * y - w * z), 1 - 2 * (y * y + z * z))
    return rx, ry, rz
