"""PyBullet 3.2.7 behind :class:`ges_core.sim.SimBackend`: ``num_envs`` DIRECT clients, stepped in a loop.

Choices that make it behave like the SAPIEN backend (details in the helper modules):

* joint drives: PyBullet ``POSITION_CONTROL`` motors whose gain and force limit are recomputed
  every physics step from physical Kp/Kd so they act like SAPIEN's implicit spring-damper
  (:mod:`.drive`);
* inertias rewritten in principal axes and made valid, massless links given a tiny mass
  (:mod:`.hand_urdf`); object mass and inertia computed exactly from density (:mod:`.shapes`);
* friction: per-body coefficients whose Bullet products equal PhysX's pairwise averages;
* ``hand_gravity=False``: world gravity is zero and the object's weight is applied at its
  centre of mass every step (PyBullet has no per-body gravity switch);
* the table is a static box whose top is z = 0 (a ``GEOM_PLANE`` let dropped boxes skid);
* self-collision: ``URDF_USE_SELF_COLLISION`` with every pair of
  :func:`ges_core.urdf.neighbour_link_pairs` switched off (:func:`.scene.exclude_neighbour_pairs`),
  the SAPIEN backend's rule.

``SceneConfig.solver_iterations`` goes to PyBullet's ``numSolverIterations`` unchanged unless the
backend's own ``solver_iterations`` setting (``registry.yaml``: ``settings.sim.pybullet``) overrides
it. PyBullet's PGS converges more slowly than PhysX's TGS on light finger links in contact: a
finger pressed on the table chatters at 20 iterations and balances its drive within 1 % at 100.

Quaternions are wxyz at this class's boundary and xyzw inside PyBullet (:mod:`.poses`).

An env that blew up gets a new client on its next reset (or teleport naming it): after a NaN object
velocity PyBullet's collision detection in that world stays broken (measured, 3.2.7: after teleporting
the object back, it and the hand fell through the table; reloading the object did not help). The new
scene then evolves bit for bit like the same env of a backend that never blew up
(``tests/test_sim_env_ids.py``). Rebuilding one Allegro scene takes 30-45 ms here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ges_core.errors import SimulationError, UnknownNameError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import ContactPair, ContactPartner, SceneConfig, SimBackend, check_env_rows, env_id_list
from ges_core.urdf import quat_to_euler_xyz

from .checks import (
    MAX_JOINT_SPEED,
    blown_message,
    checked_array,
    checked_poses,
    drive_problems,
    object_problem,
    solver_iterations_setting,
)
from .contacts import contact_pairs, link_forces
from .drive import product_friction
from .engine import p
from .hand_urdf import WORLD_LINK
from .poses import IDENTITY_POSE, from_pybullet, to_pybullet
from .scene import HandLayout, Scene, create_object, hand_layout, load_hand_body, new_scene, set_hand_friction
from .shapes import lowest_point

__all__ = ["MAX_JOINT_SPEED", "PybulletBackend"]

REST_MARGIN = 2e-4
"""m left between the table and an object put down by ``load_object(pose=None)``: it starts
out of contact and settles without a bounce (the SAPIEN backend's value, so both start alike)."""
_PARTNERS = ("object", "table", "any")
_XYZ_WXYZ = [0, 1, 2, 6, 3, 4, 5]
"""Column order taking PyBullet's (x, y, z, qx, qy, qz, qw) to ours (x, y, z, qw, qx, qy, qz)."""


class PybulletBackend(SimBackend):
    """``num_envs`` independent PyBullet worlds (see the module docs for the physics choices)."""

    name = "pybullet"

    def __init__(self, config: SceneConfig, *, solver_iterations: int | None = None) -> None:
        """solver_iterations: PyBullet's ``numSolverIterations`` (registry setting), overriding
        ``config.solver_iterations`` for this backend only; None keeps the config's value.

        PyBullet's PGS needs about 100 where SAPIEN's TGS is fine at 20 (module docs), so
        ``registry.yaml`` can raise it here without changing SAPIEN's.
        """
        super().__init__(config)
        self.solver_iterations = (
            config.solver_iterations if solver_iterations is None else solver_iterations_setting(solver_iterations)
        )
        """Solver iterations in use: the setting if given, else ``config.solver_iterations``."""
        self._scenes: list[Scene] = [new_scene(config, self.solver_iterations) for _ in range(config.num_envs)]
        self._layout: HandLayout | None = None
        self._start = np.zeros(0)
        """(D,) drive positions of the start pose (wrist joints at 0, fingers open)."""
        self._reset_base = np.tile(IDENTITY_POSE, (config.num_envs, 1))
        """(E, 7) base pose that reset() returns to: the last one given to set_hand_state, wxyz."""
        self._targets = np.zeros((config.num_envs, 0))
        """(E, D) drive targets, ``HandLayout.drive_ids`` order."""
        self._state: tuple[np.ndarray, np.ndarray] | None = None
        """Cached (q, v) of the drives, each (E, D), valid until the state changes."""
        self._link_ids: dict[tuple[str, ...], list[int]] = {}
        self._motor_args: tuple[list[int], list[float], list[float], list[float]] = ([], [], [], [])
        """PyBullet motor call arguments fixed at load time: joint ids, position and velocity gains, zeros."""
        self._hand: HandModel | None = None
        self._blown: set[int] = set()
        """Envs reported by step() as blown up and not restored since (see :meth:`_restore`)."""
        self._closed = False

    # -- index maps ----------------------------------------------------------------------------
    @property
    def idx_sim_to_hand(self) -> np.ndarray:
        """(K,) ``q_hand = q_sim[idx_sim_to_hand]``; ``q_sim``: the hand's joints in PyBullet's (URDF file) order."""
        return self._hand_layout().idx_sim_to_hand

    @property
    def idx_hand_to_sim(self) -> np.ndarray:
        """(K,) ``q_sim = q_hand[idx_hand_to_sim]``."""
        return self._hand_layout().idx_hand_to_sim

    # -- building ------------------------------------------------------------------------------
    def load_hand(self, hand: HandModel, *, floating: bool = True) -> None:
        """Add the hand to every scene at its open pose; floating: six PD wrist joints at the origin."""
        scenes = self._live()
        for scene in scenes:
            load_hand_body(scene, hand, self.config, floating)
        layout = hand_layout(scenes[0], hand, self.config, floating)
        open_pose = np.asarray(hand.description.open_pose, dtype=np.float64)
        self._layout, self._link_ids, self._hand = layout, {}, hand
        d = len(layout.drive_ids)
        pd = layout.pd
        self._motor_args = (
            layout.drive_ids.tolist(),
            pd.position_gains.tolist(),
            pd.velocity_gains.tolist(),
            [0.0] * d,
        )
        self._start = np.concatenate([np.zeros(layout.num_wrist), open_pose])
        self._targets = np.tile(self._start, (self.num_envs, 1))
        for scene in scenes:
            self._apply_friction(scene)
        self._reset_hand(np.tile(self._start, (self.num_envs, 1)), list(range(self.num_envs)))

    def load_object(
        self,
        obj: ObjectAsset,
        pose: np.ndarray | None = None,
        env_ids: Sequence[int] | None = None,
        *,
        fixed: bool = False,
    ) -> None:
        """Put ``obj`` into scenes ``env_ids`` (all if None), replacing any object; pose None rests it on the table.

        pose: (7,) or (len(env_ids), 7), object frame in the world, position m + quaternion wxyz.
        """
        self._live()
        ids = env_id_list(env_ids, self.num_envs, "pybullet.load_object")
        check_env_rows(pose, env_ids, ids, "pybullet.load_object", "pose")
        if pose is None:
            pose = np.array([0.0, 0.0, REST_MARGIN - lowest_point(obj), 1.0, 0.0, 0.0, 0.0])
        if np.ndim(pose) == 1:
            poses = np.tile(checked_poses(pose, None, "load_object pose"), (len(ids), 1))
        else:
            poses = checked_poses(pose, (len(ids), 7), "load_object pose")
        self._restore(ids)
        for e, row in zip(ids, poses, strict=True):
            scene = self._scenes[e]
            create_object(scene, obj, fixed=fixed)
            scene.obj_friction = obj.friction
            self._apply_friction(scene)
            scene.obj_load_pose = row.copy()
            _teleport_object(scene, row)

    # -- commands ------------------------------------------------------------------------------
    def set_joint_targets(self, q: np.ndarray) -> None:
        """PD position targets, (num_envs, K), hand joint order, radians."""
        layout = self._hand_layout()
        self._targets[:, layout.num_wrist :] = checked_array(q, (self.num_envs, self._num_joints()), "joint targets q")

    def set_wrist_targets(self, pose: np.ndarray) -> None:
        """PD targets of the floating wrist, (num_envs, 7) base-link pose, world frame, wxyz."""
        self._require_floating("set_wrist_targets")
        pose = checked_poses(pose, (self.num_envs, 7), "wrist target pose")
        self._targets[:, :3] = pose[:, :3]
        self._targets[:, 3:6] = _unwrap(quat_to_euler_xyz(pose[:, 3:]), self._targets[:, 3:6])

    def set_hand_state(
        self, q: np.ndarray, wrist_pose: np.ndarray | None = None, *, env_ids: Sequence[int] | None = None
    ) -> None:
        """Teleport the hand of envs ``env_ids`` (all if None): joints (M, K) rad, optionally base poses
        (M, 7) world wxyz, M = len(env_ids) or num_envs; zero velocity; targets follow. Others untouched."""
        layout = self._hand_layout()
        ids = env_id_list(env_ids, self.num_envs, "pybullet.set_hand_state")
        check_env_rows(q, env_ids, ids, "pybullet.set_hand_state", "q")
        check_env_rows(wrist_pose, env_ids, ids, "pybullet.set_hand_state", "wrist_pose")
        q = checked_array(q, (len(ids), self._num_joints()), "hand state q")
        base = None if wrist_pose is None else checked_poses(wrist_pose, (len(ids), 7), "hand state wrist_pose")
        self._restore(ids)
        drives = self._drive_state()[0][ids]  # a copy (fancy indexing)
        drives[:, layout.num_wrist :] = q
        if base is not None:
            self._reset_base[ids] = base
            self._place_base(drives, base, ids)
        self._reset_hand(drives, ids)

    def set_object_pose(self, pose: np.ndarray, *, env_ids: Sequence[int] | None = None) -> None:
        """Teleport the object of envs ``env_ids`` (all if None), (M, 7) world frame wxyz, zero velocity."""
        ids = env_id_list(env_ids, self.num_envs, "pybullet.set_object_pose")
        check_env_rows(pose, env_ids, ids, "pybullet.set_object_pose", "pose")
        pose = checked_poses(pose, (len(ids), 7), "object pose")
        scenes = self._scenes_with_object(ids)
        self._restore(ids)
        for e, row in zip(ids, pose, strict=True):
            _teleport_object(scenes[e], row)

    def step(self, n: int = 1) -> None:
        """Advance every scene ``n`` physics steps; one SimulationError at the end lists every env that blew up.

        Hand joints are checked after every physics step (their state is read for the drives anyway) and
        an env whose hand blew up is not stepped further; objects are checked once, at the end (a check
        costs about 6 µs per env, 6 % of a step).
        """
        scenes = self._live()
        if not isinstance(n, int | np.integer) or n < 0:
            raise SimulationError(f"pybullet backend: step(n) needs a whole number n >= 0, got {n!r}")
        weight = 0.0 if self.config.hand_gravity else self.config.gravity
        blown: dict[int, str] = {}
        for _ in range(int(n)):
            commands = self._drive_commands(blown)
            for e, scene in enumerate(scenes):
                if e in blown:
                    continue
                if commands is not None:
                    self._send_drives(scene, *(c[e] for c in commands))
                if weight and scene.obj >= 0:
                    _apply_weight(scene, weight)
                p.stepSimulation(physicsClientId=scene.cid)
            self._state = None
        if self._layout is not None:
            blown = {**drive_problems(*self._drive_state()), **blown}
        for e, scene in enumerate(scenes):
            problem = object_problem(e, scene) if scene.obj >= 0 and e not in blown else None
            if problem is not None:
                blown[e] = problem
        if blown:
            self._blown.update(blown)
            raise SimulationError(blown_message(blown), env_ids=blown)

    def engine_step(self) -> None:
        """One bare ``stepSimulation`` per scene: no PD update, no weight force, no checks (benchmarks)."""
        for scene in self._live():
            p.stepSimulation(physicsClientId=scene.cid)

    # -- reading -------------------------------------------------------------------------------
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions and velocities, each (num_envs, K), hand joint order (rad, rad/s)."""
        nw = self._hand_layout().num_wrist
        q, v = self._drive_state()
        return q[:, nw:].copy(), v[:, nw:].copy()

    def wrist_pose(self) -> np.ndarray:
        """Base-link pose, (num_envs, 7), world frame, wxyz."""
        base = self._hand_layout().base_link
        states = [p.getLinkState(s.hand, base, physicsClientId=s.cid) for s in self._live()]
        return np.stack([from_pybullet(st[4], st[5]) for st in states])

    def link_poses(self, links: Sequence[str]) -> np.ndarray:
        """Poses of the named hand links' URDF frames, (num_envs, L, 7), world frame, wxyz.

        PyBullet reports link frames in single precision (about 1e-7 relative).
        """
        ids = self._resolve_links(links)
        rows = [[st[4] + st[5] for st in p.getLinkStates(s.hand, ids, physicsClientId=s.cid)] for s in self._live()]
        return np.array(rows).reshape(self.num_envs, len(ids), 7)[..., _XYZ_WXYZ]

    def contact_forces(self, links: Sequence[str], partner: ContactPartner = "object") -> np.ndarray:
        """Net contact force on each named hand link from ``partner``, (num_envs, L, 3), world frame, N.

        partner: "object", "table", or "any" (every other body and the hand's other links).
        """
        if partner not in _PARTNERS:
            raise SimulationError(f"pybullet.contact_forces: partner '{partner}' is not one of {', '.join(_PARTNERS)}")
        ids = self._resolve_links(links)
        out = np.zeros((self.num_envs, len(ids), 3))
        for e, scene in enumerate(self._live()):
            bodies = [b for b in _partner_bodies(scene, partner) if b >= 0]
            out[e] = link_forces(scene.cid, scene.hand, bodies, ids)
        return out

    def object_pose(self) -> np.ndarray:
        """Object pose, (num_envs, 7), world frame, wxyz."""
        rows = []
        for s in self._scenes_with_object():
            base = p.getBasePositionAndOrientation(s.obj, physicsClientId=s.cid)
            pos, orn = p.multiplyTransforms(*base, *s.obj_in_base)
            rows.append((*pos, orn[3], orn[0], orn[1], orn[2]))
        return np.array(rows)

    def contact_pairs(self, env_id: int = 0) -> list[ContactPair]:
        """Every touching pair (separation <= 0.5 mm) in scene ``env_id``; slow, for diagnostics."""
        scene = self._live()[env_id_list([env_id], self.num_envs, "pybullet.contact_pairs")[0]]
        names = {scene.hand: "hand", scene.obj: "object", scene.table: "table"}
        names.pop(-1, None)
        links = {scene.hand: {-1: WORLD_LINK, **self._layout.link_names}} if self._layout else {}
        return contact_pairs(scene.cid, names, links)

    # -- lifetime ------------------------------------------------------------------------------
    def reset(self, *, env_ids: Sequence[int] | None = None) -> None:
        """Envs ``env_ids`` (all if None): open hand at the base pose last given to set_hand_state (else the
        origin), targets there, at rest; objects at their load poses. Blown envs get a new scene first."""
        self._live()
        ids = env_id_list(env_ids, self.num_envs, "pybullet.reset")
        self._restore(ids)
        self._reset_envs(ids)

    def _reset_envs(self, ids: list[int]) -> None:
        for e in ids:
            scene = self._scenes[e]
            if scene.obj >= 0:
                _teleport_object(scene, scene.obj_load_pose)
        if self._layout is not None:
            drives = np.tile(self._start, (len(ids), 1))
            self._place_base(drives, self._reset_base[ids], ids)
            self._reset_hand(drives, ids)

    def _restore(self, ids: list[int]) -> None:
        """Give every blown env among ``ids`` a new client holding the same hand and object, reset.

        A NaN leaves PyBullet's collision detection in that world broken (module docs), so teleports alone
        cannot bring it back.
        """
        bad = sorted(self._blown.intersection(ids))
        for e in bad:
            old = self._scenes[e]
            scene = self._scenes[e] = new_scene(self.config, self.solver_iterations)
            old.client.disconnect()
            if self._hand is not None:
                load_hand_body(scene, self._hand, self.config, self._layout.floating)
            if old.asset is not None:
                create_object(scene, old.asset, fixed=old.obj_fixed)
                scene.obj_friction, scene.obj_load_pose = old.obj_friction, old.obj_load_pose
            self._apply_friction(scene)
            self._blown.discard(e)
        if bad:
            self._state = None
            self._reset_envs(bad)

    def close(self) -> None:
        """Disconnect every client; calling twice is harmless."""
        if self._closed:
            return
        self._closed = True
        for scene in self._scenes:
            scene.client.disconnect()

    # -- internals -----------------------------------------------------------------------------
    def _live(self) -> list[Scene]:
        if self._closed:
            raise SimulationError("pybullet backend is closed; build a new one with registry.build_sim('pybullet')")
        return self._scenes

    def _hand_layout(self) -> HandLayout:
        self._live()
        if self._layout is None:
            raise SimulationError("pybullet backend: no hand loaded; call load_hand(hand) first")
        return self._layout

    def _num_joints(self) -> int:
        return len(self._hand_layout().idx_hand_to_sim)

    def _require_floating(self, what: str) -> None:
        if not self._hand_layout().floating:
            raise SimulationError(
                f"pybullet backend: {what} needs a floating wrist, but the hand was loaded with floating=False; "
                "load it with load_hand(hand, floating=True) or move it with set_hand_state(q, wrist_pose)"
            )

    def _scenes_with_object(self, ids: Sequence[int] | None = None) -> list[Scene]:
        """Every scene, once the scenes ``ids`` (all if None) are checked to hold an object."""
        scenes = self._live()
        missing = [e for e in (range(self.num_envs) if ids is None else ids) if scenes[e].obj < 0]
        if missing:
            raise SimulationError(f"pybullet backend: no object in envs {missing}; call load_object(obj) first")
        return scenes

    def _resolve_links(self, links: Sequence[str]) -> list[int]:
        key = tuple(links)
        if key not in self._link_ids:
            known = self._hand_layout().link_ids
            for name in key:
                if name not in known:
                    raise UnknownNameError("hand link", name, known)
            self._link_ids[key] = [known[name] for name in key]
        return self._link_ids[key]

    def _apply_friction(self, scene: Scene) -> None:
        cfg = self.config
        obj = scene.obj_friction if scene.obj >= 0 else None
        if obj is None:
            k_hand = k_table = math.sqrt((cfg.hand_friction + cfg.table_friction) / 2)
        else:
            k_hand, k_obj, k_table = product_friction(cfg.hand_friction, obj, cfg.table_friction)
            p.changeDynamics(scene.obj, -1, lateralFriction=k_obj, physicsClientId=scene.cid)
        p.changeDynamics(scene.table, -1, lateralFriction=k_table, physicsClientId=scene.cid)
        if self._layout is not None:
            set_hand_friction(scene, self._layout, k_hand)

    def _place_base(self, drives: np.ndarray, base: np.ndarray, env_ids: list[int]) -> None:
        """Put the hand's base of envs ``env_ids`` (M) at ``base`` (M, 7): the wrist coordinates of
        ``drives`` (M, D) if floating, else the fixed root, moved now."""
        if self._hand_layout().floating:
            drives[:, :3], drives[:, 3:6] = base[:, :3], quat_to_euler_xyz(base[:, 3:])
            return
        for e, pose in zip(env_ids, base, strict=True):
            scene = self._scenes[e]
            p.resetBasePositionAndOrientation(scene.hand, *to_pybullet(pose), physicsClientId=scene.cid)

    def _reset_hand(self, drives: np.ndarray, env_ids: list[int]) -> None:
        """Teleport the drive joints of envs ``env_ids`` (M) to ``drives`` (M, D), zero velocity, targets there."""
        ids = self._hand_layout().drive_ids.tolist()
        zeros = [[0.0]] * len(ids)
        for e, row in zip(env_ids, drives, strict=True):
            values = [[x] for x in row.tolist()]
            p.resetJointStatesMultiDof(self._scenes[e].hand, ids, values, zeros, physicsClientId=self._scenes[e].cid)
        self._targets[env_ids] = drives
        self._state = None

    def _drive_state(self) -> tuple[np.ndarray, np.ndarray]:
        if self._state is None:
            ids = self._hand_layout().drive_ids.tolist()
            rows = [
                list(zip(*p.getJointStates(s.hand, ids, physicsClientId=s.cid), strict=True))[:2] for s in self._scenes
            ]
            qv = np.array(rows)  # (E, 2, D)
            self._state = (qv[:, 0], qv[:, 1])
        return self._state

    def _drive_commands(self, blown: dict[int, str]) -> tuple[np.ndarray, np.ndarray] | None:
        """(E, D) targets and force limits for this physics step (None without a hand); envs whose drive
        state blew up are added to ``blown`` (env -> description) unless already there."""
        layout = self._layout
        if layout is None:
            return None
        fresh = self._state is None
        q, v = self._drive_state()
        if fresh:  # a cached state was checked when it was read at the end of the last step
            for e, problem in drive_problems(q, v).items():
                blown.setdefault(e, problem)
        return self._targets, layout.pd.force_limits(q, v, self._targets)

    def _send_drives(self, scene: Scene, targets: np.ndarray, forces: np.ndarray) -> None:
        ids, position_gains, velocity_gains, zeros = self._motor_args
        p.setJointMotorControlArray(
            scene.hand,
            ids,
            p.POSITION_CONTROL,
            targetPositions=targets.tolist(),  # PyBullet clips them to the joint limits
            targetVelocities=zeros,
            forces=forces.tolist(),
            positionGains=position_gains,
            velocityGains=velocity_gains,  # v' = pGain * error / dt + (1 - vGain) v* (see drive.py)
            physicsClientId=scene.cid,
        )


# -- helpers ---------------------------------------------------------------------------------------
def _unwrap(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``angles`` shifted by whole turns to lie nearest ``reference`` (within the wrist's +-2 pi)."""
    turn = 2 * np.pi
    out = angles + turn * np.round((reference - angles) / turn)
    return np.where(np.abs(out) > turn, out - turn * np.sign(out), out)


def _teleport_object(scene: Scene, pose: np.ndarray) -> None:
    base = p.multiplyTransforms(*to_pybullet(pose), *scene.base_in_obj)
    p.resetBasePositionAndOrientation(scene.obj, *base, physicsClientId=scene.cid)
    p.resetBaseVelocity(scene.obj, [0.0] * 3, [0.0] * 3, physicsClientId=scene.cid)


def _apply_weight(scene: Scene, gravity: float) -> None:
    """The object's weight at its centre of mass (world gravity is off while the hand has none)."""
    com, _ = p.getBasePositionAndOrientation(scene.obj, physicsClientId=scene.cid)
    p.applyExternalForce(
        scene.obj, -1, (0.0, 0.0, scene.obj_mass * gravity), com, p.WORLD_FRAME, physicsClientId=scene.cid
    )


def _partner_bodies(scene: Scene, partner: str) -> list[int]:
    if partner == "object":
        return [scene.obj]
    if partner == "table":
        return [scene.table]
    return [scene.obj, scene.table, scene.hand]
