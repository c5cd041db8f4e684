"""PyBullet 3.2.7 behind :class:`ges_core.sim.SimBackend`: ``num_envs`` DIRECT clients, stepped in a loop.

Choices that make it behave like the SAPIEN backend (details in the helper modules):

* joint drives: PyBullet ``POSITION_CONTROL`` motors whose gain and force limit are recomputed
  every physics step from physical Kp/Kd so they act like SAPIEN's implicit spring-damper
  (:mod:`.drive`); ``set_drive_limits`` caps that per-step force limit at the actuator's torque;
* inertias rewritten in principal axes and made valid, massless links given a tiny mass
  (:mod:`.hand_urdf`); object mass and inertia computed exactly from density (:mod:`.shapes`);
* friction: per-body coefficients whose Bullet products equal PhysX's pairwise averages;
* ``hand_gravity=False``: world gravity is zero and the object's weight is applied at its
  centre of mass every step (PyBullet has no per-body gravity switch);
* the table is a static box whose top is z = 0 (a ``GEOM_PLANE`` let dropped boxes skid);
* self-collision: ``URDF_USE_SELF_COLLISION`` with every pair of
  :meth:`ges_core.hand.HandModel.excluded_link_pairs` switched off (:func:`.scene.exclude_link_pairs`),
  the SAPIEN backend's rule.

``SceneConfig.solver_iterations`` goes to PyBullet's ``numSolverIterations`` unchanged unless the
backend's own ``solver_iterations`` setting (``registry.yaml``: ``settings.sim.pybullet``) overrides
it. PyBullet's PGS converges more slowly than PhysX's TGS on light finger links in contact: a
finger pressed on the table chatters at 20 iterations and balances its drive within 1 % at 100.

Quaternions are wxyz at this class's boundary and xyzw inside PyBullet (:mod:`.poses`); they reach the
hooks normalised in float64 (``normalise_quaternions``), as PyBullet's double-precision state wants.
Argument checks, per-env bookkeeping and wrist unwrapping live in :class:`ges_core.sim.SimBackend`; this
class only implements its engine hooks.

An env that blew up gets a new client on its next reset (or teleport naming it, :meth:`PybulletBackend._rebuild`):
after a NaN object velocity PyBullet's collision detection in that world stays broken (measured, 3.2.7:
after teleporting the object back, it and the hand fell through the table; reloading the object did not
help). The new scene then evolves bit for bit like the same env of a backend that never blew up
(``tests/test_sim_env_ids.py``). Rebuilding one Allegro scene takes 30-45 ms here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np

from ges_core.errors import UnknownNameError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import ContactPair, SceneConfig, SimBackend

from .checks import BLOWUP_HINT, MAX_JOINT_SPEED, drive_problems, object_problem, solver_iterations_setting
from .contacts import contact_pairs, link_forces
from .drive import product_friction
from .engine import p
from .hand_urdf import WORLD_LINK
from .poses import from_pybullet, to_pybullet
from .scene import (
    HandLayout,
    Scene,
    anchor_on_touch,
    create_object,
    hand_layout,
    load_hand_body,
    new_scene,
    set_hand_friction,
    set_object_anchor,
)
from .shapes import lowest_point

__all__ = ["MAX_JOINT_SPEED", "PybulletBackend"]

REST_MARGIN = 2e-4
"""m left between the table and an object put down by ``load_object(pose=None)``: it starts
out of contact and settles without a bounce (the SAPIEN backend's value, so both start alike)."""
_XYZ_WXYZ = [0, 1, 2, 6, 3, 4, 5]
"""Column order taking PyBullet's (x, y, z, qx, qy, qz, qw) to ours (x, y, z, qw, qx, qy, qz)."""


class PybulletBackend(SimBackend):
    """``num_envs`` independent PyBullet worlds (see the module docs for the physics choices)."""

    name = "pybullet"
    normalise_quaternions = True
    blowup_hint = BLOWUP_HINT

    def __init__(
        self,
        config: SceneConfig,
        *,
        solver_iterations: int | None = None,
        friction_anchors: bool | Literal["on_touch"] = "on_touch",
    ) -> None:
        """solver_iterations: PyBullet's ``numSolverIterations`` (registry setting), overriding
        ``config.solver_iterations`` for this backend only; None keeps the config's value.

        PyBullet's PGS needs about 100 where SAPIEN's TGS is fine at 20 (module docs), so
        ``registry.yaml`` can raise it here without changing SAPIEN's.

        friction_anchors: Bullet's friction anchor on the object (registry setting; :func:`.scene.new_scene`):
        without it a squeezed object creeps out of the fingers. ``"on_touch"`` (the default): from the hand's first
        touch on (:func:`.scene.anchor_on_touch`), the object resting on plain contacts before; True: from the
        object's load on, so a rocking object pivots about its first table contact.
        """
        super().__init__(config)
        self.solver_iterations = (
            config.solver_iterations if solver_iterations is None else solver_iterations_setting(solver_iterations)
        )
        """Solver iterations in use: the setting if given, else ``config.solver_iterations``."""
        self.friction_anchors = friction_anchors
        """Friction anchor on the object (the setting)."""
        self._scenes: list[Scene] = [self._new_scene() for _ in range(config.num_envs)]
        self._layout: HandLayout | None = None
        self._targets = np.zeros((config.num_envs, 0))
        """(E, D) drive targets, ``HandLayout.drive_ids`` order."""
        self._state: tuple[np.ndarray, np.ndarray] | None = None
        """Cached (q, v) of the drives, each (E, D), valid until the state changes."""
        self._link_ids: dict[tuple[str, ...], list[int]] = {}
        self._motor_args: tuple[list[int], list[float], list[float], list[float]] = ([], [], [], [])
        """PyBullet motor call arguments fixed at load time: joint ids, position and velocity gains, zeros."""
        self._caps: np.ndarray | None = None
        """(K,) drive force caps of the hand joints, hand joint order, N·m (set_drive_limits); None: no caps."""

    # -- index maps ----------------------------------------------------------------------------
    @property
    def idx_sim_to_hand(self) -> np.ndarray:
        """(K,) ``q_hand = q_sim[idx_sim_to_hand]``; ``q_sim``: the hand's joints in PyBullet's (URDF file) order."""
        self._need_hand("idx_sim_to_hand")
        return self._layout.idx_sim_to_hand

    @property
    def idx_hand_to_sim(self) -> np.ndarray:
        """(K,) ``q_sim = q_hand[idx_hand_to_sim]``."""
        self._need_hand("idx_hand_to_sim")
        return self._layout.idx_hand_to_sim

    def engine_step(self) -> None:
        """One bare ``stepSimulation`` per scene: no PD update, no weight force, no checks (benchmarks)."""
        self._check_open()
        for scene in self._scenes:
            p.stepSimulation(physicsClientId=scene.cid)

    # -- building ------------------------------------------------------------------------------
    def _load_hand(self, hand: HandModel, floating: bool) -> None:
        for scene in self._scenes:
            load_hand_body(scene, hand, self.config, floating)
        layout = hand_layout(self._scenes[0], hand, self.config, floating)
        self._layout, self._link_ids = layout, {}
        pd = layout.pd
        d = len(layout.drive_ids)
        self._motor_args = (
            layout.drive_ids.tolist(),
            pd.position_gains.tolist(),
            pd.velocity_gains.tolist(),
            [0.0] * d,
        )
        self._targets = np.zeros((self.num_envs, d))
        for scene in self._scenes:
            self._apply_friction(scene)

    def _load_object(self, obj: ObjectAsset, ids: list[int], fixed: bool) -> None:
        for e in ids:
            scene = self._scenes[e]
            create_object(scene, obj, fixed=fixed)
            scene.obj_friction = obj.friction
            self._apply_friction(scene)

    def _rest_height(self, obj: ObjectAsset, env_id: int) -> float:
        return REST_MARGIN - lowest_point(obj)

    # -- commands ------------------------------------------------------------------------------
    def _set_joint_targets(self, q: np.ndarray) -> None:
        self._targets[:, self._layout.num_wrist :] = q

    def _set_drive_limits(self, limits: np.ndarray | None) -> None:
        self._caps = None if limits is None else limits.copy()

    def _set_wrist_targets(self, coords: np.ndarray) -> None:
        self._targets[:, :6] = coords

    def _wrist_rotation_targets(self) -> np.ndarray:
        return self._targets[:, 3:6]

    def _set_hand_state(self, q: np.ndarray, base: np.ndarray | None, ids: list[int]) -> None:
        layout = self._layout
        drives = self._drive_state()[0][ids]  # a copy (fancy indexing)
        drives[:, layout.num_wrist :] = q
        if base is not None and layout.floating:
            drives[:, :6] = base
        elif base is not None:
            for e, pose in zip(ids, base, strict=True):
                scene = self._scenes[e]
                p.resetBasePositionAndOrientation(scene.hand, *to_pybullet(pose), physicsClientId=scene.cid)
        zeros = [[0.0]] * len(layout.drive_ids)
        for e, row in zip(ids, drives, strict=True):
            scene = self._scenes[e]
            values = [[x] for x in row.tolist()]
            p.resetJointStatesMultiDof(scene.hand, layout.drive_ids.tolist(), values, zeros, physicsClientId=scene.cid)
        self._targets[ids] = drives
        self._state = None

    def _set_object_pose(self, pose: np.ndarray, ids: list[int]) -> None:
        for e, row in zip(ids, pose, strict=True):
            scene = self._scenes[e]
            base = p.multiplyTransforms(*to_pybullet(row), *scene.base_in_obj)
            p.resetBasePositionAndOrientation(scene.obj, *base, physicsClientId=scene.cid)
            p.resetBaseVelocity(scene.obj, [0.0] * 3, [0.0] * 3, physicsClientId=scene.cid)
            if scene.friction_anchors == "on_touch" and scene.anchored:
                set_object_anchor(scene, False)  # placed again: untouched until the hand comes

    def _step(self, n: int) -> dict[int, str]:
        """Every scene ``n`` physics steps; problems of every env that blew up.

        Hand joints are checked after every physics step (their state is read for the drives anyway) and
        an env whose hand blew up is not stepped further; objects are checked once, at the end (a check
        costs about 6 µs per env, 6 % of a step).
        """
        weight = 0.0 if self.config.hand_gravity else self.config.gravity
        blown: dict[int, str] = {}
        for _ in range(n):
            commands = self._drive_commands(blown)
            for e, scene in enumerate(self._scenes):
                if e in blown:
                    continue
                if commands is not None:
                    self._send_drives(scene, *(c[e] for c in commands))
                if weight and scene.obj >= 0:
                    _apply_weight(scene, weight)
                anchor_on_touch(scene)
                p.stepSimulation(physicsClientId=scene.cid)
            self._state = None
        if self._layout is not None:
            blown = {**drive_problems(*self._drive_state()), **blown}
        for e, scene in enumerate(self._scenes):
            problem = object_problem(e, scene) if scene.obj >= 0 and e not in blown else None
            if problem is not None:
                blown[e] = problem
        return blown

    def _new_scene(self) -> Scene:
        return new_scene(self.config, self.solver_iterations, friction_anchors=self.friction_anchors)

    def _rebuild(self, ids: list[int]) -> None:
        """Give every env of ``ids`` a new client holding the same hand and object (the core resets it next).

        A NaN leaves PyBullet's collision detection in that world broken (module docs), so teleports alone
        cannot bring it back.
        """
        for e in ids:
            old = self._scenes[e]
            scene = self._scenes[e] = self._new_scene()
            old.client.disconnect()
            if self._hand is not None:
                load_hand_body(scene, self._hand, self.config, self._layout.floating)
            if old.asset is not None:
                create_object(scene, old.asset, fixed=old.obj_fixed)
                scene.obj_friction = old.obj_friction
            self._apply_friction(scene)
        self._state = None

    # -- reading -------------------------------------------------------------------------------
    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        nw = self._layout.num_wrist
        q, v = self._drive_state()
        return q[:, nw:].copy(), v[:, nw:].copy()

    def _wrist_pose(self) -> np.ndarray:
        base = self._layout.base_link
        states = [p.getLinkState(s.hand, base, physicsClientId=s.cid) for s in self._scenes]
        return np.stack([from_pybullet(st[4], st[5]) for st in states])

    def _link_poses(self, links: Sequence[str]) -> np.ndarray:
        """Poses of the named links' URDF frames; PyBullet reports link frames in single precision (~1e-7 relative)."""
        ids = self._resolve_links(links)
        rows = [[st[4] + st[5] for st in p.getLinkStates(s.hand, ids, physicsClientId=s.cid)] for s in self._scenes]
        return np.array(rows).reshape(self.num_envs, len(ids), 7)[..., _XYZ_WXYZ]

    def _contact_forces(self, links: Sequence[str], partner: str) -> np.ndarray:
        ids = self._resolve_links(links)
        out = np.zeros((self.num_envs, len(ids), 3))
        for e, scene in enumerate(self._scenes):
            bodies = [b for b in _partner_bodies(scene, partner) if b >= 0]
            out[e] = link_forces(scene.cid, scene.hand, bodies, ids)
        return out

    def _object_pose(self) -> np.ndarray:
        rows = []
        for s in self._scenes:
            base = p.getBasePositionAndOrientation(s.obj, physicsClientId=s.cid)
            pos, orn = p.multiplyTransforms(*base, *s.obj_in_base)
            rows.append((*pos, orn[3], orn[0], orn[1], orn[2]))
        return np.array(rows)

    def _contact_pairs(self, env_id: int) -> list[ContactPair]:
        """Every touching pair (separation <= 0.5 mm) in scene ``env_id``."""
        scene = self._scenes[env_id]
        names = {scene.hand: "hand", scene.obj: "object", scene.table: "table"}
        names.pop(-1, None)
        links = {scene.hand: {-1: WORLD_LINK, **self._layout.link_names}} if self._layout else {}
        return contact_pairs(scene.cid, names, links)

    def _close(self) -> None:
        for scene in self._scenes:
            scene.client.disconnect()

    # -- internals -----------------------------------------------------------------------------
    def _resolve_links(self, links: Sequence[str]) -> list[int]:
        key = tuple(links)
        if key not in self._link_ids:
            known = self._layout.link_ids
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
            for link in scene.obj_links:
                p.changeDynamics(scene.obj, link, lateralFriction=k_obj, physicsClientId=scene.cid)
        p.changeDynamics(scene.table, -1, lateralFriction=k_table, physicsClientId=scene.cid)
        if self._layout is not None:
            set_hand_friction(scene, self._layout, k_hand)

    def _drive_state(self) -> tuple[np.ndarray, np.ndarray]:
        if self._state is None:
            ids = self._layout.drive_ids.tolist()
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
        forces = layout.pd.force_limits(q, v, self._targets)
        if self._caps is not None:  # the hand's actuators: at most their torque (set_drive_limits)
            forces[:, layout.num_wrist :] = np.minimum(forces[:, layout.num_wrist :], self._caps)
        return self._targets, forces

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
