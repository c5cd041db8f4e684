"""The simulator interface: one physics engine running ``num_envs`` independent scenes.

Arrays are numpy float64. Poses are ``(..., 7)``: position x, y, z in metres, then a unit
quaternion **w, x, y, z**, world frame. Joint vectors follow the loaded hand's
``HandDescription.joint_names``; links are addressed by name. Each backend maps its engine's
own orders once at load time (``idx_sim_to_hand`` / ``idx_hand_to_sim``).

Per-env operations: :meth:`SimBackend.set_hand_state`, :meth:`SimBackend.set_object_pose`,
:meth:`SimBackend.reset` and :meth:`SimBackend.load_object` take ``env_ids``, a sequence of distinct
env indices (list, tuple, numpy or torch integer array; None = every env). Their arrays then hold
one row per listed env, in the order listed, and only those envs change: every other env keeps its
exact state, velocities and PD targets included. Backends check ``env_ids`` with
:func:`env_id_list` and :func:`check_env_rows`.

The world: a table plane at z = 0 (the top of the table), gravity along -z.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.errors import ConfigError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset

__all__ = ["ContactPair", "ContactPartner", "SceneConfig", "SimBackend", "check_env_rows", "env_id_list"]

ContactPartner = Literal["object", "table", "any"]
"""Whose contacts :meth:`SimBackend.contact_forces` sums: the object's, the table's or all."""


class SceneConfig(ConfigModel):
    """Physics settings shared by every backend.

    ``self_collision=True`` collides every pair of hand links except the pairs of
    :func:`ges_core.urdf.neighbour_link_pairs`: parent-child pairs and pairs joined through
    zero-length links (the Shadow hand's palm and ffproximal, through ``ffknuckle``). Every backend
    excludes exactly those, so a hand touches itself in the same places in every engine.
    """

    num_envs: int = Field(1, ge=1, description="independent scenes stepped together")
    timestep: float = Field(1 / 120, gt=0, le=0.05, description="physics step, seconds")
    gravity: float = Field(-9.81, description="gravity along z, m/s^2")
    table_friction: float = Field(1.0, ge=0, description="Coulomb friction of the table plane")
    hand_friction: float = Field(1.0, ge=0, description="Coulomb friction of the hand links")
    solver_iterations: int = Field(20, ge=1, description="position iterations of the contact solver")
    self_collision: bool = Field(
        True, description="collide hand links, except the pairs of ges_core.urdf.neighbour_link_pairs"
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
    """A physics engine behind one small interface. Create through the registry (``build_sim``)."""

    name: str = ""
    """Registry name of the backend."""

    def __init__(self, config: SceneConfig) -> None:
        self.config = config

    @property
    def num_envs(self) -> int:
        """Number of independent scenes."""
        return self.config.num_envs

    # -- building -------------------------------------------------------------------------
    @abstractmethod
    def load_hand(self, hand: HandModel, *, floating: bool = True) -> None:
        """Add the hand to every scene, PD drives on every joint, at its open pose.

        floating: True adds a 6-DoF wrist driven by :meth:`set_wrist_targets`; False fixes the
        hand's base link at the world origin. Either way the base starts at the origin (inside the
        table): place a floating hand with :meth:`set_hand_state` before stepping.
        """

    @abstractmethod
    def load_object(
        self,
        obj: ObjectAsset,
        pose: np.ndarray | None = None,
        env_ids: Sequence[int] | None = None,
        *,
        fixed: bool = False,
    ) -> None:
        """Put ``obj`` into the scenes ``env_ids`` (all if None), replacing any object there.

        pose: (7,) or (len(env_ids), 7); None rests it on the table at the origin. fixed: the object
        stays where it is put (kinematic in SAPIEN, static in PyBullet), contacts push only the hand and
        are reported as usual; until the next load_object.
        """

    # -- commands -------------------------------------------------------------------------
    @abstractmethod
    def set_joint_targets(self, q: np.ndarray) -> None:
        """PD position targets, (num_envs, K), hand joint order, radians."""

    @abstractmethod
    def set_wrist_targets(self, pose: np.ndarray) -> None:
        """PD targets of the floating wrist, (num_envs, 7) base-link pose, world frame."""

    @abstractmethod
    def set_hand_state(
        self, q: np.ndarray, wrist_pose: np.ndarray | None = None, *, env_ids: Sequence[int] | None = None
    ) -> None:
        """Teleport the hand of envs ``env_ids`` (all if None); every joint's velocity zero, targets follow.

        q: (M, K) hand joint order, radians; wrist_pose: (M, 7) base-link pose, world frame, or None
        to keep each env's base where it is. M = num_envs, or len(env_ids) when given (rows in the
        order of env_ids). A given base pose becomes that env's :meth:`reset` pose. Other envs keep
        their exact state, velocities and targets. An env that blew up is restored first (see :meth:`step`).
        """

    @abstractmethod
    def set_object_pose(self, pose: np.ndarray, *, env_ids: Sequence[int] | None = None) -> None:
        """Teleport the object of envs ``env_ids`` (all if None), zero velocity; other envs untouched.

        pose: (M, 7) world frame, M = num_envs or len(env_ids). An env that blew up is restored first.
        """

    @abstractmethod
    def step(self, n: int = 1) -> None:
        """Advance every scene ``n`` physics steps, then check every env's state.

        Every env whose state went non-finite or exploding is listed in one SimulationError
        (message ``... env N: ...`` per env, attribute ``env_ids``); every other env has taken all
        ``n`` steps. (A backend may check after each physics step and stop stepping an env found
        blown.) A blown env stays blown, and is reported again by later steps, until :meth:`reset`,
        :meth:`set_hand_state`, :meth:`set_object_pose` or :meth:`load_object` names it: that call
        first restores it as :meth:`reset` would, then does its own work.
        """

    def engine_step(self) -> None:
        """One raw engine step in every scene, skipping our checks and bookkeeping (for benchmarks)."""
        raise NotImplementedError(f"{type(self).__name__} does not expose a raw engine step")

    # -- reading --------------------------------------------------------------------------
    @abstractmethod
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions and velocities, each (num_envs, K), hand joint order."""

    @abstractmethod
    def wrist_pose(self) -> np.ndarray:
        """Base-link pose, (num_envs, 7), world frame."""

    @abstractmethod
    def link_poses(self, links: Sequence[str]) -> np.ndarray:
        """Poses of the named hand links, (num_envs, L, 7), world frame."""

    @abstractmethod
    def contact_forces(self, links: Sequence[str], partner: ContactPartner = "object") -> np.ndarray:
        """Net contact force on each named hand link from ``partner``, (num_envs, L, 3), world frame, N."""

    @abstractmethod
    def object_pose(self) -> np.ndarray:
        """Object pose, (num_envs, 7), world frame."""

    @abstractmethod
    def contact_pairs(self, env_id: int = 0) -> list[ContactPair]:
        """Every touching pair in scene ``env_id`` (slow; for diagnostics and linting)."""

    # -- lifetime -------------------------------------------------------------------------
    @abstractmethod
    def reset(self, *, env_ids: Sequence[int] | None = None) -> None:
        """Put the scenes ``env_ids`` (all if None) back at their start, each env on its own; others untouched.

        The hand: joints at the open pose, base at the pose last given to :meth:`set_hand_state` in
        that env (the world origin if none was given; poses the wrist reached under
        :meth:`set_wrist_targets` do not count), joint and wrist targets equal to that state, every
        velocity zero. The object: back at its load pose (the one :meth:`load_object` used), at rest.
        Settings and loaded bodies stay (a backend may rebuild the scene of an env that blew up).
        """

    @abstractmethod
    def close(self) -> None:
        """Release the engine. Calling twice is harmless."""

    def __enter__(self) -> SimBackend:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def env_id_list(env_ids: Sequence[int] | None, num_envs: int, who: str) -> list[int]:
    """``env_ids`` as a list of distinct ints in [0, num_envs); None gives every env, ``[]`` none.

    env_ids: a 1-D sequence of integers (list, tuple, numpy or torch integer array). who: the
    method, for messages ("sapien.reset"). Raises ConfigError naming the problem.
    """
    if env_ids is None:
        return list(range(num_envs))
    ids = np.asarray(env_ids)
    if ids.ndim != 1 or (ids.size and ids.dtype.kind not in "iu"):
        raise ConfigError(
            f"{who}: env_ids must be a 1-D sequence of integer env indices, got {_show(env_ids)} "
            f"(shape {ids.shape}, dtype {ids.dtype}); a boolean mask m gives indices with m.nonzero()[0]"
        )
    out = [int(i) for i in ids]
    bad = [i for i in out if not 0 <= i < num_envs]
    if bad:
        raise ConfigError(f"{who}: env ids {bad} out of range for num_envs={num_envs} (valid: 0..{num_envs - 1})")
    repeated = sorted({i for i in out if out.count(i) > 1})
    if repeated:
        raise ConfigError(f"{who}: env_ids {out} repeat {repeated}; name each env once")
    return out


def check_env_rows(value: object, env_ids: Sequence[int] | None, ids: list[int], who: str, what: str) -> None:
    """ConfigError when ``env_ids`` was given and ``value`` (M, ...) has M != len(ids) rows.

    A 2-D ``value`` only: other shapes are left to the backend's own shape check.
    """
    if env_ids is None or value is None or np.ndim(value) != 2:
        return
    rows = np.shape(value)[0]
    if rows != len(ids):
        raise ConfigError(
            f"{who}: {what} has {rows} rows but env_ids names {len(ids)} env(s) {ids}; "
            "give one row per listed env, in the order of env_ids"
        )


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
