"""The SAPIEN 3 backend: ``num_envs`` CPU PhysX scenes, headless, stepped one after another.

Frames and units follow :mod:`ges_core.sim`: world frame, metres, quaternions w, x, y, z (SAPIEN's
own convention, so poses pass through unchanged). Joint vectors are in the hand's
``joint_names`` order; SAPIEN's breadth-first order is mapped once in :meth:`SapienBackend.load_hand`.
With self-collision on, hand links collide except the pairs of :meth:`ges_core.hand.HandModel.excluded_link_pairs`
(PhysX skips parent-child pairs itself; the others get collision-group bits, :func:`.loading.pair_exclusion_bits`).

Argument checks, per-env bookkeeping and wrist unwrapping live in :class:`ges_core.sim.SimBackend`; this
class only implements its engine hooks. An env that blew up is restored by teleports alone (the core's
reset of that env; no :meth:`~ges_core.sim.SimBackend._rebuild` needed): after a NaN or 500 m/s object
velocity or a NaN joint velocity it then evolves bit for bit like the same env of a backend that never
blew up (``tests/test_sim_env_ids.py``). Bodies are never removed for it (reading contacts of a removed
body segfaults).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ges_core.errors import ConfigError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import ContactPair, SceneConfig, SimBackend
from ges_plugins.sims.sapien import loading
from ges_plugins.sims.sapien.checks import BLOWUP_HINT, MAX_JOINT_SPEED, MAX_OBJECT_SPEED, state_problem
from ges_plugins.sims.sapien.contacts import ContactReader
from ges_plugins.sims.sapien.engine import sapien
from ges_plugins.sims.sapien.poses import PoseTable, sapien_pose

__all__ = ["MAX_JOINT_SPEED", "MAX_OBJECT_SPEED", "SapienBackend"]


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
    poses: PoseTable | None = None


class SapienBackend(SimBackend):
    """SAPIEN 3.0 CPU PhysX behind :class:`ges_core.sim.SimBackend`."""

    name = "sapien"
    blowup_hint = BLOWUP_HINT

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
        self._base_link = ""
        self.idx_sim_to_hand = np.zeros(0, dtype=np.int64)
        """(K,) ``q_hand = q_fingers[idx_sim_to_hand]``; ``q_fingers`` = SAPIEN's active-joint vector
        after the six wrist joints."""
        self.idx_hand_to_sim = np.zeros(0, dtype=np.int64)
        """(K,) ``q_fingers = q_hand[idx_hand_to_sim]``."""

    def engine_step(self) -> None:
        """One raw ``scene.step()`` per scene: no state check, no bookkeeping (for benchmarks)."""
        for env in self._envs:
            env.scene.step()
            env.contacts.after_step()

    # -- building -------------------------------------------------------------------------
    def _load_hand(self, hand: HandModel, floating: bool) -> None:
        urdf = loading.prepare_urdf(hand, floating=floating)
        pair_bits = (
            loading.pair_exclusion_bits(hand.name, hand.urdf_text(), hand.excluded_link_pairs())
            if self.config.self_collision
            else None
        )
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
        self._base_link = base.name

    def _load_object(self, obj: ObjectAsset, ids: list[int], fixed: bool) -> None:
        for env_id in ids:
            env = self._envs[env_id]
            if env.obj is not None:
                env.scene.remove_entity(env.obj)
            env.obj = loading.build_object(env.scene, obj, self.config)
            env.obj_body = env.obj.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
            env.obj_body.kinematic = fixed
            loading.set_contact_offset([env.obj_body], self._contact_offset)
            env.contacts.set_object(env.obj_body, obj.object_id)
            env.poses = None

    def _rest_height(self, obj: ObjectAsset, env_id: int) -> float:
        return loading.rest_height(self._envs[env_id].obj)

    # -- commands -------------------------------------------------------------------------
    def _set_joint_targets(self, q: np.ndarray) -> None:
        for env, row in zip(self._envs, q.tolist(), strict=True):
            for joint, target in zip(env.hand_joints, row, strict=True):
                joint.set_drive_target(target)

    def _set_drive_limits(self, limits: np.ndarray | None) -> None:
        d = self._hand.description
        caps = loading.force_limits(limits, d.num_joints)
        for env in self._envs:
            for joint, kp, kd, cap in zip(env.hand_joints, d.pd_stiffness, d.pd_damping, caps, strict=True):
                joint.set_drive_property(kp, kd, cap)

    def _set_wrist_targets(self, coords: np.ndarray) -> None:
        for env, row in zip(self._envs, coords.tolist(), strict=True):
            for joint, target in zip(env.wrist_joints, row, strict=True):
                joint.set_drive_target(target)

    def _wrist_rotation_targets(self) -> np.ndarray:
        targets = [[float(joint.get_drive_target()[0]) for joint in env.wrist_joints[3:]] for env in self._envs]
        return np.array(targets, dtype=np.float64)

    def _set_hand_state(self, q: np.ndarray, base: np.ndarray | None, ids: list[int]) -> None:
        for row, e in enumerate(ids):
            env = self._envs[e]
            qpos = env.hand.get_qpos()
            qpos[len(env.wrist_joints) :] = q[row][self.idx_hand_to_sim]
            if base is not None and env.wrist_joints:
                qpos[:6] = base[row]
            elif base is not None:
                env.hand.set_root_pose(sapien_pose(base[row]))
            self._teleport_hand(env, qpos)

    def _set_object_pose(self, pose: np.ndarray, ids: list[int]) -> None:
        for e, row in zip(ids, pose, strict=True):
            env = self._envs[e]
            env.obj.pose = sapien_pose(row)
            env.obj_body.set_linear_velocity(np.zeros(3))
            env.obj_body.set_angular_velocity(np.zeros(3))

    def _step(self, n: int) -> dict[int, str]:
        """Every scene ``n`` steps, each checked after every step; a scene that blew up is not stepped further."""
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
        return blown

    # -- reading --------------------------------------------------------------------------
    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        qpos = np.empty((self.num_envs, len(self.idx_hand_to_sim)))
        qvel = np.empty_like(qpos)
        for e, env in enumerate(self._envs):
            n_wrist = len(env.wrist_joints)
            qpos[e] = env.hand.get_qpos()[n_wrist:][self.idx_sim_to_hand]
            qvel[e] = env.hand.get_qvel()[n_wrist:][self.idx_sim_to_hand]
        return qpos, qvel

    def _wrist_pose(self) -> np.ndarray:
        return self._link_poses([self._base_link])[:, 0]

    def _link_poses(self, links: Sequence[str]) -> np.ndarray:
        out = np.empty((self.num_envs, len(links), 7))
        for e, env in enumerate(self._envs):
            out[e] = self._pose_table(env).read(links)
        return out

    def _contact_forces(self, links: Sequence[str], partner: str) -> np.ndarray:
        out = np.empty((self.num_envs, len(links), 3))
        for e, env in enumerate(self._envs):
            out[e] = env.contacts.forces(links, partner)
        return out

    def _object_pose(self) -> np.ndarray:
        out = np.empty((self.num_envs, 7))
        for e, env in enumerate(self._envs):
            out[e] = self._pose_table(env).read_object()
        return out

    def _contact_pairs(self, env_id: int) -> list[ContactPair]:
        return self._envs[env_id].contacts.pairs()

    def _close(self) -> None:
        self._envs = []

    # -- helpers --------------------------------------------------------------------------
    @staticmethod
    def _teleport_hand(env: _Env, qpos: np.ndarray) -> None:
        env.hand.set_qpos(qpos)
        env.hand.set_qvel(np.zeros_like(qpos))
        for joint, target in zip(env.hand.get_active_joints(), qpos.tolist(), strict=True):
            joint.set_drive_target(target)

    def _pose_table(self, env: _Env) -> PoseTable:
        if env.poses is None:
            env.poses = PoseTable(env.scene, env.hand, env.obj)
        return env.poses
