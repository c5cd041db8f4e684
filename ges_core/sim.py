"""The simulator interface: one physics engine running ``num_envs`` independent scenes.

Arrays are numpy float64. Poses are ``(..., 7)``: position x, y, z in metres, then a quaternion
**w, x, y, z** (non-zero; it need not be normalised), world frame. Joint vectors follow the loaded
hand's ``HandDescription.joint_names``; links are addressed by name. Each backend maps its engine's
own orders once at load time (``idx_sim_to_hand`` / ``idx_hand_to_sim``).

Per-env operations: :meth:`SimBackend.set_hand_state`, :meth:`SimBackend.set_object_pose`,
:meth:`SimBackend.reset` and :meth:`SimBackend.load_object` take ``env_ids``, a sequence of distinct
env indices (list, tuple, numpy or torch integer array; None = every env). Their arrays then hold
one row per listed env, in the order listed, and only those envs change: every other env keeps its
exact state, velocities and PD targets included.

The world: a table plane at z = 0 (the top of the table), gravity along -z.

**One front, engine hooks behind it.** The public methods of :class:`SimBackend` are concrete: they
check that the backend is open and holds what the call needs, check every argument once
(:mod:`ges_core.sim_args`, :mod:`ges_core.arrays`), restore blown-up envs, keep the per-env
bookkeeping (reset poses, load poses, which envs hold an object, which blew up) and turn wrist poses
into the six wrist joint values; then they call small abstract ``_hooks`` that only talk to the
engine, with arguments already checked. A backend implements the hooks and overrides no public
method but :meth:`SimBackend.engine_step` (``tests/test_sim_conformance.py`` checks it). Errors, the
same in every backend:

* a bad ``env_ids``, ``partner`` or step count: :class:`~ges_core.errors.ConfigError`;
* a wrongly shaped array (rows that do not match ``env_ids`` included), NaN or inf, a zero
  quaternion, a drive limit that is not > 0: :class:`~ges_core.errors.ArrayError`;
* a call the backend's state does not allow (closed, no hand, no object, a fixed hand asked to fly, a
  second hand): :class:`~ges_core.errors.SimulationError` without ``env_ids``;
* a state that blew up while stepping: :class:`~ges_core.errors.SimulationError` with ``env_ids``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from ges_core.arrays import checked_array, checked_poses
from ges_core.config import ConfigModel
from ges_core.errors import ArrayError, ConfigError, SimulationError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim_args import (
    IDENTITY_POSE,
    PARTNERS,
    check_env_rows,
    env_id_list,
    unit_quaternions,
    wrist_coordinates,
)

__all__ = ["ContactPair", "ContactPartner", "SceneConfig", "SimBackend"]

ContactPartner = Literal["object", "table", "any"]
"""Whose contacts :meth:`SimBackend.contact_forces` sums: the object's, the table's or all."""


class SceneConfig(ConfigModel):
    """Physics settings shared by every backend.

    ``self_collision=True`` collides every pair of hand links except the pairs of
    :meth:`ges_core.hand.HandModel.excluded_link_pairs`: parent-child pairs and pairs joined through
    zero-length links (the Shadow hand's palm and ffproximal, through ``ffknuckle``;
    :func:`ges_core.urdf.neighbour_link_pairs`), and the pairs the hand's description lists in
    ``self_collision_exclude``. Every backend excludes exactly those, so a hand touches itself in the same
    places in every engine.
    """

    num_envs: int = Field(1, ge=1, description="independent scenes stepped together")
    timestep: float = Field(1 / 120, gt=0, le=0.05, description="physics step, seconds")
    gravity: float = Field(-9.81, description="gravity along z, m/s^2")
    table_friction: float = Field(1.0, ge=0, description="Coulomb friction of the table plane")
    hand_friction: float = Field(1.0, ge=0, description="Coulomb friction of the hand links")
    solver_iterations: int = Field(20, ge=1, description="position iterations of the contact solver")
    self_collision: bool = Field(
        True, description="collide hand links, except the pairs of HandModel.excluded_link_pairs"
    )
    hand_gravity: bool = Field(False, description="apply gravity to the hand (off: the wrist drive holds it)")
    wrist_stiffness: float = Field(2.0e4, gt=0, description="PD stiffness of the floating wrist, N/m and N·m/rad")
    wrist_damping: float = Field(4.0e2, ge=0, description="PD damping of the floating wrist")


@dataclass(frozen=True)
class ContactPair:
    """One touching pair (diagnostics; the fast path is :meth:`SimBackend.contact_forces`)."""

    body_a: str
    link_a: str
    body_b: str
    link_b: str
    separation: float
    """Signed distance, metres; negative = penetration."""
    force: float
    """Normal force magnitude, N."""


class SimBackend(ABC):
    """A physics engine behind one small interface. Create through the registry (``build_sim``).

    Subclasses implement the ``_hooks`` (engine calls only; every argument arrives checked) and set
    :attr:`name`; see the module docs and ``docs/simulators.md`` ("Writing a backend").
    """

    name: str = ""
    """Registry name of the backend (messages start with it: ``sapien.set_hand_state: ...``)."""
    normalise_quaternions: ClassVar[bool] = False
    """True: pose arguments reach the hooks with unit quaternions (each divided by its float64 norm),
    for an engine that needs them so; False: as the caller gave them (checked non-zero), for an engine
    that normalises in its own precision."""
    blowup_hint: ClassVar[str] = "the state blew up; reset() the env, or lower the gains or the timestep"
    """Appended to the per-env descriptions of a blow-up (likely causes and a fix, in the engine's terms)."""

    def __init__(self, config: SceneConfig) -> None:
        self.config = config
        n = config.num_envs
        self._closed = False
        self._hand: HandModel | None = None
        """The loaded hand (one per backend, for its lifetime)."""
        self._floating = False
        self._blown: set[int] = set()
        """Envs reported by step() as blown up and not restored since."""
        self._reset_base = np.tile(IDENTITY_POSE, (n, 1))
        """(num_envs, 7) base pose that reset() returns to: the last one given to set_hand_state."""
        self._load_poses = np.tile(IDENTITY_POSE, (n, 1))
        """(num_envs, 7) object pose each env's load_object used (reset() returns the object there)."""
        self._has_object = np.zeros(n, dtype=bool)

    @property
    def num_envs(self) -> int:
        """Number of independent scenes."""
        return self.config.num_envs

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called (every other call then raises SimulationError)."""
        return self._closed

    # -- building -------------------------------------------------------------------------
    def load_hand(self, hand: HandModel, *, floating: bool = True) -> None:
        """Add the hand to every scene, PD drives on every joint, at its open pose.

        floating: True adds a 6-DoF wrist driven by :meth:`set_wrist_targets`; False fixes the
        hand's base link at the world origin. Either way the base starts at the origin (inside the
        table): place a floating hand with :meth:`set_hand_state` before stepping. One hand per backend.
        """
        self._check_open()
        if self._hand is not None:
            raise SimulationError(
                f"{self.name}: hand '{self._hand.name}' is already loaded; build a new backend for '{hand.name}'"
            )
        self._load_hand(hand, bool(floating))
        self._hand, self._floating = hand, bool(floating)
        self._reset_envs(list(range(self.num_envs)), objects=False)

    def load_object(
        self,
        obj: ObjectAsset,
        pose: np.ndarray | None = None,
        env_ids: Sequence[int] | None = None,
        *,
        fixed: bool = False,
    ) -> None:
        """Put ``obj`` into the scenes ``env_ids`` (all if None), replacing any object there.

        pose: (7,) or (len(env_ids), 7); None rests it on the table at the origin, its lowest collision
        point a backend's rest margin above z = 0. fixed: the object stays where it is put (kinematic in
        SAPIEN, static in PyBullet), contacts push only the hand and are reported as usual; until the
        next load_object.
        """
        self._check_open()
        who = f"{self.name}.load_object"
        ids = env_id_list(env_ids, self.num_envs, who)
        check_env_rows(pose, env_ids, ids, who, "pose")
        if pose is not None:
            single = np.ndim(pose) == 1
            poses = self._poses(pose, None if single else len(ids), "load_object", "pose")
            poses = np.tile(poses, (len(ids), 1)) if single else poses
        self._restore(ids)
        if not ids:
            return
        self._load_object(obj, ids, bool(fixed))
        if pose is None:
            poses = np.tile([0.0, 0.0, self._rest_height(obj, ids[0]), 1.0, 0.0, 0.0, 0.0], (len(ids), 1))
        self._load_poses[ids] = poses
        self._has_object[ids] = True
        self._set_object_pose(poses, ids)

    # -- commands -------------------------------------------------------------------------
    def set_joint_targets(self, q: np.ndarray) -> None:
        """PD position targets, (num_envs, K), hand joint order, radians."""
        self._need_hand("set_joint_targets")
        self._set_joint_targets(self._joints(q, self.num_envs, "set_joint_targets"))

    def set_drive_limits(self, limits: np.ndarray | Sequence[float] | None) -> None:
        """Cap the force of each hand joint's drive in every env: ``limits`` (K,) hand joint order, N·m (N for a
        prismatic joint), each > 0 (``inf``: no cap on that joint); None lifts every cap (the default).

        A joint whose drive asks for more (a finger blocked against the object) pushes with at most its limit,
        as a real actuator would (``HandDescription.effort_limits``). The floating wrist is never capped. Stays
        until the next call, through :meth:`reset` and teleports.
        """
        self._need_hand("set_drive_limits")
        if limits is not None:
            k = self._hand.description.num_joints
            limits = checked_array(
                limits,
                (k,),
                f"{self.name}.set_drive_limits: limits",
                layout="hand joint_names order, N·m",
                finite=False,
            )
            if np.isnan(limits).any() or (limits <= 0).any():
                bad = [n for n, v in zip(self._hand.description.joint_names, limits, strict=True) if not v > 0]
                raise ArrayError(
                    f"{self.name}.set_drive_limits: limits must be > 0 N·m (inf: no cap), not for {bad}; give each "
                    "joint's actuator torque (HandDescription.effort_limits) or None to lift the caps"
                )
        self._set_drive_limits(limits)

    def set_wrist_targets(self, pose: np.ndarray) -> None:
        """PD targets of the floating wrist, (num_envs, 7) base-link pose, world frame.

        Rotation targets are unwrapped toward the present ones (:func:`ges_core.sim_args.unwrap_angles`).
        """
        self._need_hand("set_wrist_targets")
        if not self._floating:
            raise SimulationError(
                f"{self.name}.set_wrist_targets: the hand was loaded with floating=False; load it with "
                "load_hand(hand, floating=True) or move it with set_hand_state(q, wrist_pose)"
            )
        pose = self._poses(pose, self.num_envs, "set_wrist_targets", "pose")
        self._set_wrist_targets(wrist_coordinates(pose, self._wrist_rotation_targets()))

    def set_hand_state(
        self, q: np.ndarray, wrist_pose: np.ndarray | None = None, *, env_ids: Sequence[int] | None = None
    ) -> None:
        """Teleport the hand of envs ``env_ids`` (all if None); every joint's velocity zero, targets follow.

        q: (M, K) hand joint order, radians; wrist_pose: (M, 7) base-link pose, world frame, or None
        to keep each env's base where it is. M = num_envs, or len(env_ids) when given (rows in the
        order of env_ids). A given base pose becomes that env's :meth:`reset` pose. Other envs keep
        their exact state, velocities and targets. An env that blew up is restored first (see :meth:`step`).
        """
        self._need_hand("set_hand_state")
        who = f"{self.name}.set_hand_state"
        ids = env_id_list(env_ids, self.num_envs, who)
        check_env_rows(q, env_ids, ids, who, "q")
        check_env_rows(wrist_pose, env_ids, ids, who, "wrist_pose")
        q = self._joints(q, len(ids), "set_hand_state")
        wrist = None if wrist_pose is None else self._poses(wrist_pose, len(ids), "set_hand_state", "wrist_pose")
        self._restore(ids)
        self._set_hand_state(q, None if wrist is None else self._base(wrist), ids)
        if wrist is not None:
            self._reset_base[ids] = wrist

    def set_object_pose(self, pose: np.ndarray, *, env_ids: Sequence[int] | None = None) -> None:
        """Teleport the object of envs ``env_ids`` (all if None), zero velocity; other envs untouched.

        pose: (M, 7) world frame, M = num_envs or len(env_ids). An env that blew up is restored first.
        """
        self._check_open()
        who = f"{self.name}.set_object_pose"
        ids = env_id_list(env_ids, self.num_envs, who)
        check_env_rows(pose, env_ids, ids, who, "pose")
        pose = self._poses(pose, len(ids), "set_object_pose", "pose")
        self._need_objects("set_object_pose", ids)
        self._restore(ids)
        self._set_object_pose(pose, ids)

    def step(self, n: int = 1) -> None:
        """Advance every scene ``n`` physics steps, then check every env's state.

        Every env whose state went non-finite or exploding is listed in one SimulationError
        (message ``... env N: ...`` per env, attribute ``env_ids``); every other env has taken all
        ``n`` steps. (A backend may check after each physics step and stop stepping an env found
        blown.) A blown env stays blown, and is reported again by later steps, until :meth:`reset`,
        :meth:`set_hand_state`, :meth:`set_object_pose` or :meth:`load_object` names it: that call
        first restores it as :meth:`reset` would, then does its own work.
        """
        self._check_open()
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
            raise ConfigError(f"{self.name}.step: n={n!r}; give a whole number of steps >= 0")
        problems = self._step(int(n))
        if problems:
            self._blown.update(problems)
            message = "; ".join(problems[e] for e in sorted(problems)) + "; " + self.blowup_hint
            raise SimulationError(message, env_ids=problems)

    def engine_step(self) -> None:
        """One raw engine step in every scene, skipping our checks and bookkeeping (for benchmarks).

        The one public method a backend may override (the default says it has none).
        """
        raise NotImplementedError(f"{type(self).__name__} does not expose a raw engine step")

    # -- reading --------------------------------------------------------------------------
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions and velocities, each (num_envs, K), hand joint order (rad, rad/s)."""
        self._need_hand("joint_state")
        return self._joint_state()

    def wrist_pose(self) -> np.ndarray:
        """Base-link pose, (num_envs, 7), world frame."""
        self._need_hand("wrist_pose")
        return self._wrist_pose()

    def link_poses(self, links: Sequence[str]) -> np.ndarray:
        """Poses of the named hand links, (num_envs, L, 7), world frame; an unknown name is an UnknownNameError."""
        self._need_hand("link_poses")
        return self._link_poses(links)

    def contact_forces(self, links: Sequence[str], partner: ContactPartner = "object") -> np.ndarray:
        """Net contact force on each named hand link from ``partner``, (num_envs, L, 3), world frame, N.

        partner: "object", "table", or "any" (every other body, the hand's other links included).
        """
        self._need_hand("contact_forces")
        if partner not in PARTNERS:
            raise ConfigError(f"{self.name}.contact_forces: partner '{partner}' is not one of {', '.join(PARTNERS)}")
        return self._contact_forces(links, partner)

    def object_pose(self) -> np.ndarray:
        """Object pose, (num_envs, 7), world frame."""
        self._check_open()
        self._need_objects("object_pose")
        return self._object_pose()

    def contact_pairs(self, env_id: int = 0) -> list[ContactPair]:
        """Every touching pair in scene ``env_id`` (slow; for diagnostics and linting)."""
        self._check_open()
        return self._contact_pairs(env_id_list([env_id], self.num_envs, f"{self.name}.contact_pairs")[0])

    # -- lifetime -------------------------------------------------------------------------
    def reset(self, *, env_ids: Sequence[int] | None = None) -> None:
        """Put the scenes ``env_ids`` (all if None) back at their start, each env on its own; others untouched.

        The hand: joints at the open pose, base at the pose last given to :meth:`set_hand_state` in
        that env (the world origin if none was given; poses the wrist reached under
        :meth:`set_wrist_targets` do not count), joint and wrist targets equal to that state, every
        velocity zero. The object: back at its load pose (the one :meth:`load_object` used), at rest.
        Settings and loaded bodies stay (a backend may rebuild the scene of an env that blew up).
        """
        self._check_open()
        ids = env_id_list(env_ids, self.num_envs, f"{self.name}.reset")
        self._rebuild_blown(ids)
        self._reset_envs(ids)

    def close(self) -> None:
        """Release the engine. Calling twice is harmless."""
        if not self._closed:
            self._closed = True
            self._close()

    def __enter__(self) -> SimBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- engine hooks: building ----------------------------------------------------------------
    @abstractmethod
    def _load_hand(self, hand: HandModel, floating: bool) -> None:
        """Add ``hand`` to every scene with PD drives and build the index maps (no hand is loaded yet).

        The core then puts every env's hand at the open pose, base at the origin, through
        :meth:`_set_hand_state`.
        """

    @abstractmethod
    def _load_object(self, obj: ObjectAsset, ids: list[int], fixed: bool) -> None:
        """Build ``obj`` into the scenes ``ids`` (non-empty), replacing any object there; ``fixed``: it never moves.

        Where it lands does not matter: the core places it next, with :meth:`_set_object_pose`.
        """

    @abstractmethod
    def _rest_height(self, obj: ObjectAsset, env_id: int) -> float:
        """z (m) of the object frame, identity orientation, that puts ``obj``'s lowest collision point a
        small rest margin above the table (``obj`` was just built into env ``env_id``)."""

    # -- engine hooks: commands ------------------------------------------------------------------
    @abstractmethod
    def _set_joint_targets(self, q: np.ndarray) -> None:
        """PD targets of the hand joints: q (num_envs, K) float64, hand joint order, rad."""

    @abstractmethod
    def _set_drive_limits(self, limits: np.ndarray | None) -> None:
        """Cap every env's hand-joint drive forces at ``limits`` (K,) float64 > 0, hand joint order (``inf``: no
        cap), or lift the caps (None). The wrist's drives stay as they are."""

    @abstractmethod
    def _set_wrist_targets(self, coords: np.ndarray) -> None:
        """PD targets of the six wrist joints: coords (num_envs, 6) x, y, z (m), rx, ry, rz (rad), unwrapped."""

    @abstractmethod
    def _wrist_rotation_targets(self) -> np.ndarray:
        """(num_envs, 3) present PD targets rx, ry, rz (rad) of the wrist hinges, the unwrapping reference."""

    @abstractmethod
    def _set_hand_state(self, q: np.ndarray, base: np.ndarray | None, ids: list[int]) -> None:
        """Teleport the hands of envs ``ids``: joints, velocities zero, every PD target at the new state.

        q: (M, K) hand joint order, rad; base: (M, 6) wrist joint values (x, y, z, rx, ry, rz) of a
        floating hand, (M, 7) base poses of a fixed one, or None to keep each base where it is.
        """

    @abstractmethod
    def _set_object_pose(self, pose: np.ndarray, ids: list[int]) -> None:
        """Teleport the objects of envs ``ids`` (each holds one) to ``pose`` (M, 7), world frame, at rest."""

    @abstractmethod
    def _step(self, n: int) -> dict[int, str]:
        """Step every scene ``n`` times (n >= 0, maybe 0); return env -> description of each env that blew up.

        A description names the env as ``"<name> env N: ..."``; the core joins them and adds :attr:`blowup_hint`.
        """

    def _rebuild(self, ids: list[int]) -> None:
        """Make the scenes ``ids`` of blown-up envs usable again before the core resets them.

        Default: nothing (teleports restore them). An engine whose broken state outlives a teleport
        rebuilds the scene here, holding the same hand and object.
        """
        return

    # -- engine hooks: reading and closing ---------------------------------------------------------
    @abstractmethod
    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Hand joint positions and velocities, each (num_envs, K), hand joint order."""

    @abstractmethod
    def _wrist_pose(self) -> np.ndarray:
        """Base-link pose, (num_envs, 7), world frame."""

    @abstractmethod
    def _link_poses(self, links: Sequence[str]) -> np.ndarray:
        """Poses (num_envs, L, 7) of the named hand links; UnknownNameError for an unknown name."""

    @abstractmethod
    def _contact_forces(self, links: Sequence[str], partner: str) -> np.ndarray:
        """Net contact forces (num_envs, L, 3) on the named links from ``partner`` (one of PARTNERS), N."""

    @abstractmethod
    def _object_pose(self) -> np.ndarray:
        """Object poses, (num_envs, 7) (every env holds one)."""

    @abstractmethod
    def _contact_pairs(self, env_id: int) -> list[ContactPair]:
        """Every touching pair in scene ``env_id`` (a valid index)."""

    @abstractmethod
    def _close(self) -> None:
        """Release the engine (called once)."""

    # -- checks and bookkeeping ----------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError(
                f"{self.name}: this backend is closed; build a new one with registry.build_sim('{self.name}')"
            )

    def _need_hand(self, method: str) -> None:
        self._check_open()
        if self._hand is None:
            raise SimulationError(f"{self.name}.{method}: no hand loaded; call load_hand(hand) first")

    def _need_objects(self, method: str, ids: Sequence[int] | None = None) -> None:
        held = self._has_object if ids is None else self._has_object[list(ids)]
        if not held.all():
            empty = (np.flatnonzero(~held) if ids is None else np.asarray(ids)[~held]).tolist()
            raise SimulationError(f"{self.name}.{method}: no object in env(s) {empty}; call load_object(obj) first")

    def _joints(self, q: object, rows: int, method: str) -> np.ndarray:
        """``q`` checked as (rows, K) finite float64 values, hand joint order."""
        shape = (rows, self._hand.description.num_joints)
        layout = "one row per env, hand joint_names order, rad"
        return checked_array(q, shape, f"{self.name}.{method}: q", layout=layout)

    def _poses(self, pose: object, rows: int | None, method: str, arg: str) -> np.ndarray:
        """``pose`` checked as (rows, 7) (rows None: one (7,) pose), unit quaternions if the engine wants them."""
        pose = checked_poses(pose, rows, f"{self.name}.{method}: {arg}")
        return unit_quaternions(pose) if self.normalise_quaternions else pose

    def _base(self, wrist: np.ndarray) -> np.ndarray:
        """What :meth:`_set_hand_state` takes for base poses (M, 7): wrist joint values if floating, else the poses."""
        return wrist_coordinates(wrist) if self._floating else wrist

    def _restore(self, ids: list[int]) -> None:
        """Restore every env among ``ids`` that blew up, as :meth:`reset` would."""
        bad = sorted(self._blown.intersection(ids))
        if bad:
            self._rebuild_blown(bad)
            self._reset_envs(bad)

    def _rebuild_blown(self, ids: list[int]) -> None:
        bad = sorted(self._blown.intersection(ids))
        if bad:
            self._rebuild(bad)
            self._blown.difference_update(bad)

    def _reset_envs(self, ids: list[int], *, objects: bool = True) -> None:
        """Hands of envs ``ids`` open at their reset base, targets there, at rest; objects at their load poses."""
        if self._hand is not None and ids:
            open_q = np.tile(np.asarray(self._hand.description.open_pose, dtype=np.float64), (len(ids), 1))
            self._set_hand_state(open_q, self._base(self._reset_base[ids]), ids)
        held = [e for e in ids if self._has_object[e]] if objects else []
        if held:
            self._set_object_pose(self._load_poses[held], held)
