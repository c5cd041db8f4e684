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
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ges_core.errors import ConfigError, SimulationError, UnknownNameError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import ContactPair, ContactPartner, SceneConfig, SimBackend
from ges_core.urdf import quat_to_euler_xyz

from .contacts import contact_pairs, link_forces
from .drive import product_friction
from .engine import p
from .hand_urdf import WORLD_LINK
from .poses import IDENTITY_POSE, from_pybullet, to_pybullet
from .scene import HandLayout, Scene, create_object, hand_layout, load_hand_body, new_scene, set_hand_friction
from .shapes import lowest_point

__all__ = ["PybulletBackend"]

MAX_JOINT_SPEED = 1e3
"""rad/s (m/s for the wrist's slides): faster is an explosion (the SAPIEN backend's value). Allegro's
drives at Kp = 400, Kd = 10 close a 3 rad error at about 90 rad/s. PyBullet clamps hand joints at
100 rad/s after each step, so here this catches NaN/inf and states set between steps."""
MAX_OBJECT_SPEED = 1e2
"""m/s; a box flung by a bad grasp leaves at a few m/s, an exploding solver at thousands."""
MAX_OBJECT_SPIN = 1e3
"""rad/s, the same for rotation."""
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
            config.solver_iterations if solver_iterations is None else _iterations(solver_iterations)
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
        self._layout, self._link_ids = layout, {}
        d = len(layout.drive_ids)
        pd = layout.pd
        self._motor_args = (
            layout.drive_ids.tolist(),
            pd.position_gains.tolist(),
            pd.velocity_gains.tolist(),
            [0.0] * d,
        )
        self._start = np.concatenate([np.zeros(layout.num_wrist), open_pose])
        for scene in scenes:
            self._apply_friction(scene)
        self._reset_hand(np.tile(self._start, (self.num_envs, 1)))

    def load_object(
        self, obj: ObjectAsset, pose: np.ndarray | None = None, env_ids: Sequence[int] | None = None
    ) -> None:
        """Put ``obj`` into scenes ``env_ids`` (all if None), replacing any object; pose None rests it on the table.

        pose: (7,) or (len(env_ids), 7), object frame in the world, position m + quaternion wxyz.
        """
        ids = self._env_ids(env_ids)
        if pose is None:
            pose = np.array([0.0, 0.0, REST_MARGIN - lowest_point(obj), 1.0, 0.0, 0.0, 0.0])
        if np.ndim(pose) == 1:
            poses = np.tile(_pose_array(pose, None, "load_object pose"), (len(ids), 1))
        else:
            poses = _pose_array(pose, (len(ids), 7), "load_object pose")
        for e, row in zip(ids, poses, strict=True):
            scene = self._scenes[e]
            create_object(scene, obj)
            scene.obj_friction = obj.friction
            self._apply_friction(scene)
            scene.obj_load_pose = row.copy()
            _teleport_object(scene, row)

    # -- commands ------------------------------------------------------------------------------
    def set_joint_targets(self, q: np.ndarray) -> None:
        """PD position targets, (num_envs, K), hand joint order, radians."""
        layout = self._hand_layout()
        self._targets[:, layout.num_wrist :] = _array(q, (self.num_envs, self._num_joints()), "joint targets q")

    def set_wrist_targets(self, pose: np.ndarray) -> None:
        """PD targets of the floating wrist, (num_envs, 7) base-link pose, world frame, wxyz."""
        self._require_floating("set_wrist_targets")
        pose = _pose_array(pose, (self.num_envs, 7), "wrist target pose")
        self._targets[:, :3] = pose[:, :3]
        self._targets[:, 3:6] = _unwrap(quat_to_euler_xyz(pose[:, 3:]), self._targets[:, 3:6])

    def set_hand_state(self, q: np.ndarray, wrist_pose: np.ndarray | None = None) -> None:
        """Teleport joints (num_envs, K) and optionally the base pose (num_envs, 7); zero velocity; targets follow."""
        layout = self._hand_layout()
        q = _array(q, (self.num_envs, self._num_joints()), "hand state q")
        drives = np.array(self._drive_state()[0])
        drives[:, layout.num_wrist :] = q
        if wrist_pose is not None:
            self._reset_base = _pose_array(wrist_pose, (self.num_envs, 7), "hand state wrist_pose")
            self._place_base(drives, self._reset_base)
        self._reset_hand(drives)

    def set_object_pose(self, pose: np.ndarray) -> None:
        """Teleport the object, (num_envs, 7) world frame wxyz, zero velocity."""
        pose = _pose_array(pose, (self.num_envs, 7), "object pose")
        for scene, row in zip(self._scenes_with_object(), pose, strict=True):
            _teleport_object(scene, row)

    def step(self, n: int = 1) -> None:
        """Advance every scene ``n`` physics steps; SimulationError names the first env whose state blew up."""
        scenes = self._live()
        if not isinstance(n, int | np.integer) or n < 0:
            raise SimulationError(f"pybullet backend: step(n) needs a whole number n >= 0, got {n!r}")
        weight = 0.0 if self.config.hand_gravity else self.config.gravity
        for _ in range(int(n)):
            commands = self._drive_commands()
            for e, scene in enumerate(scenes):
                if commands is not None:
                    self._send_drives(scene, *(c[e] for c in commands))
                if weight and scene.obj >= 0:
                    _apply_weight(scene, weight)
                p.stepSimulation(physicsClientId=scene.cid)
            self._state = None
        self._check_state()

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
        scene = self._live()[self._env_ids([env_id])[0]]
        names = {scene.hand: "hand", scene.obj: "object", scene.table: "table"}
        names.pop(-1, None)
        links = {scene.hand: {-1: WORLD_LINK, **self._layout.link_names}} if self._layout else {}
        return contact_pairs(scene.cid, names, links)

    # -- lifetime ------------------------------------------------------------------------------
    def reset(self) -> None:
        """Open hand at the base pose last given to set_hand_state (else the origin), targets there, at rest;
        objects at their load poses."""
        for scene in self._live():
            if scene.obj >= 0:
                _teleport_object(scene, scene.obj_load_pose)
        if self._layout is not None:
            drives = np.tile(self._start, (self.num_envs, 1))
            self._place_base(drives, self._reset_base)
            self._reset_hand(drives)

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

    def _env_ids(self, env_ids: Sequence[int] | None) -> list[int]:
        ids = list(range(self.num_envs)) if env_ids is None else [int(e) for e in env_ids]
        bad = [e for e in ids if not 0 <= e < self.num_envs]
        if bad or not ids:
            raise SimulationError(f"pybullet backend: env ids {bad or ids} out of range 0..{self.num_envs - 1}")
        return ids

    def _scenes_with_object(self) -> list[Scene]:
        scenes = self._live()
        missing = [e for e, s in enumerate(scenes) if s.obj < 0]
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

    def _place_base(self, drives: np.ndarray, base: np.ndarray) -> None:
        """Put the hand's base at ``base`` (E, 7): the wrist coordinates of ``drives`` (E, D) if floating,
        else the fixed root, moved now."""
        if self._hand_layout().floating:
            drives[:, :3], drives[:, 3:6] = base[:, :3], quat_to_euler_xyz(base[:, 3:])
            return
        for scene, pose in zip(self._scenes, base, strict=True):
            p.resetBasePositionAndOrientation(scene.hand, *to_pybullet(pose), physicsClientId=scene.cid)

    def _reset_hand(self, drives: np.ndarray) -> None:
        """Teleport every drive joint to ``drives`` (E, D), zero velocity, targets = positions."""
        ids = self._hand_layout().drive_ids.tolist()
        zeros = [[0.0]] * len(ids)
        for scene, row in zip(self._scenes, drives, strict=True):
            values = [[x] for x in row.tolist()]
            p.resetJointStatesMultiDof(scene.hand, ids, values, zeros, physicsClientId=scene.cid)
        self._targets = np.array(drives, dtype=np.float64)
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

    def _drive_commands(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(E, D) targets and force limits for this physics step (None without a hand)."""
        layout = self._layout
        if layout is None:
            return None
        fresh = self._state is None
        q, v = self._drive_state()
        if fresh:  # a cached state was checked when it was read at the end of the last step
            _check_drives(q, v, layout)
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

    def _check_state(self) -> None:
        if self._layout is not None:
            _check_drives(*self._drive_state(), self._layout)
        for e, scene in enumerate(self._scenes):
            if scene.obj >= 0:
                _check_object(e, scene)


# -- helpers ---------------------------------------------------------------------------------------
def _check_drives(q: np.ndarray, v: np.ndarray, layout: HandLayout) -> None:
    """SimulationError naming the first env with non-finite or exploding joint state."""
    if np.abs(v).max(initial=0.0) <= MAX_JOINT_SPEED and np.isfinite(q).all():
        return  # the common case in two numpy calls (a NaN speed fails the comparison)
    finite = np.isfinite(q).all(axis=1) & np.isfinite(v).all(axis=1)
    e = int(np.flatnonzero(~finite | (np.abs(np.nan_to_num(v)).max(axis=1) > MAX_JOINT_SPEED))[0])
    what = "hand joint state is NaN or inf" if not finite[e] else f"a hand joint moves at {np.abs(v[e]).max():.3g}"
    raise SimulationError(_blown(e, what))


def _check_object(env: int, scene: Scene) -> None:
    """SimulationError when the object's state is non-finite or exploding (plain floats: this runs every step)."""
    lin, ang = p.getBaseVelocity(scene.obj, physicsClientId=scene.cid)
    pos, _ = p.getBasePositionAndOrientation(scene.obj, physicsClientId=scene.cid)
    speed = math.sqrt(lin[0] ** 2 + lin[1] ** 2 + lin[2] ** 2)
    spin = math.sqrt(ang[0] ** 2 + ang[1] ** 2 + ang[2] ** 2)
    if speed <= MAX_OBJECT_SPEED and spin <= MAX_OBJECT_SPIN and math.isfinite(pos[0] + pos[1] + pos[2]):
        return
    if not (math.isfinite(speed + spin) and math.isfinite(pos[0] + pos[1] + pos[2])):
        raise SimulationError(_blown(env, "the object's pose or velocity is NaN or inf"))
    raise SimulationError(_blown(env, f"the object moves at {speed:.3g} m/s, {spin:.3g} rad/s"))


def _blown(env: int, what: str) -> str:
    return (
        f"pybullet env {env}: {what} after stepping; likely causes: a start pose deep inside the object "
        "or table, a time step too large for the gains, or a target far outside the joint limits. "
        "reset() or reload the scene"
    )


def _iterations(value: object) -> int:
    """The ``solver_iterations`` setting as an int >= 1, else a ConfigError."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ConfigError(f"pybullet: solver_iterations={value!r}; give a whole number >= 1 or leave it unset")
    return int(value)


def _array(value: np.ndarray, shape: tuple[int, ...], what: str) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != shape:
        raise SimulationError(f"pybullet backend: {what} must have shape {shape} (num_envs, ...), got {a.shape}")
    if not np.isfinite(a).all():
        raise SimulationError(f"pybullet backend: {what} contains NaN or inf; check the policy or planner output")
    return a


def _pose_array(value: np.ndarray, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    """Checked (..., 7) poses with unit wxyz quaternions (shape None: one (7,) pose)."""
    a = _array(value, shape or (7,), what)
    norm = np.linalg.norm(a[..., 3:], axis=-1, keepdims=True)
    if np.any(norm < 1e-9):
        raise SimulationError(f"pybullet backend: {what} has a zero quaternion; poses are xyz + wxyz")
    return np.concatenate([a[..., :3], a[..., 3:] / norm], axis=-1)


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
