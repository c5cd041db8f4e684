"""The hand interface: what every hand plugin declares and provides.

A hand plugin returns a :class:`HandModel`. Its :class:`HandDescription` is pure data (names,
limits, finger-to-slot map, wrist convention, sizes, gains), usually read from a YAML file that
sits beside the plugin; :meth:`HandModel.urdf_path` gives the kinematic and collision model.

Conventions
-----------
* Joints are addressed by name. ``HandDescription.joint_names`` is the canonical order of every
  joint vector ``q`` in GES-UniGrasp; simulators and kinematics map their own order to it once.
* The hand's URDF root link is the *base*: with ``floating=True`` a simulator adds six virtual
  joints above it (see :mod:`ges_core.urdf`), with ``floating=False`` it is fixed in the world.
* The *wrist frame* is the frame of ``WristConvention.link``; its palm normal and finger direction
  are declared in that frame and checked by ``ges hand lint``.
* Coupled joints (tendon-driven distal joints of the Shadow hand) are declared in ``couplings``;
  :meth:`HandDescription.apply_couplings` sets every follower from its leader.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ges_core.contact import FINGER_SLOTS
from ges_core.errors import UnknownNameError

__all__ = [
    "HUMAN_MIDDLE_FINGER_LENGTH",
    "FingerSpec",
    "HandDescription",
    "HandModel",
    "JointCoupling",
    "WristConvention",
]

HUMAN_MIDDLE_FINGER_LENGTH = 0.100
"""Metres, MCP joint to fingertip of an adult human middle finger: every hand's ``scale`` (alpha)
is its ``middle_finger_length`` divided by this, so alphas compare across hands."""


@dataclass(frozen=True, kw_only=True)
class FingerSpec:
    """One physical finger of a hand."""

    name: str
    """The hand's own finger name (e.g. ``"ff"`` or ``"index"``)."""
    slot: str
    """The canonical slot this finger fills, one of :data:`ges_core.contact.FINGER_SLOTS`."""
    joints: tuple[str, ...]
    """Joint names of this finger, proximal to distal."""
    tip_link: str
    """Link whose origin (plus ``tip_offset``) is the fingertip contact point."""
    tip_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Fingertip point in ``tip_link``'s frame, metres."""
    pad_normal: tuple[float, float, float] | None = None
    """Unit direction the fingertip pad faces (out of the finger, toward what it presses), ``tip_link`` frame.

    None: unknown; retargeting then aims only the fingertip point, not the pad's orientation."""
    keypoint_links: tuple[str, ...] = ()
    """Links used as retargeting keypoints, proximal to distal (``tip_link`` last)."""


@dataclass(frozen=True, kw_only=True)
class WristConvention:
    """Where the wrist frame is and how a hand sits in it."""

    link: str
    """Link whose frame is the wrist frame."""
    palm_normal: tuple[float, float, float]
    """Unit vector out of the palm (the side the fingers close toward), wrist frame."""
    finger_direction: tuple[float, float, float]
    """Unit vector from the wrist toward the middle fingertip at the open pose, wrist frame."""


@dataclass(frozen=True, kw_only=True)
class JointCoupling:
    """``q[follower] = ratio * q[leader] + offset``: joints moved together by one tendon or linkage.

    A URDF ``<mimic joint=leader multiplier=ratio offset=offset>`` tag becomes one of these
    (:func:`ges_core.hand_prep.mimic.mimic_couplings`). A leader is never itself a follower: chains of
    mimic tags are resolved to the first leader when they are read.
    """

    follower: str
    """The joint that follows."""
    leader: str
    """The joint it follows (an actuated joint)."""
    ratio: float = 1.0
    """Multiplier, follower radians (metres) per leader radian (metre)."""
    offset: float = 0.0
    """Follower value when the leader is at 0, radians (metres for a prismatic follower)."""


@dataclass(frozen=True, kw_only=True)
class HandDescription:
    """Everything the framework needs to know about a hand, as data."""

    name: str
    """Registry name, e.g. ``"shadow"``."""
    joint_names: tuple[str, ...]
    """Canonical joint order of every hand joint vector (K joints)."""
    joint_limits: tuple[tuple[float, float], ...]
    """(K,) pairs (lower, upper), radians or metres, in ``joint_names`` order."""
    fingers: tuple[FingerSpec, ...]
    """Physical fingers of the hand."""
    wrist: WristConvention
    """Wrist-frame convention."""
    middle_finger_length: float
    """``l_p`` of the paper: anatomical middle-finger length of this hand, metres."""
    scale: float
    """``alpha`` of the paper: this hand's size relative to a human hand (1.0 = human)."""
    open_pose: tuple[float, ...]
    """(K,) joint values of the open hand."""
    pd_stiffness: tuple[float, ...]
    """(K,) PD stiffness per joint (N·m/rad)."""
    pd_damping: tuple[float, ...]
    """(K,) PD damping per joint (N·m·s/rad)."""
    effort_limits: tuple[float, ...] = ()
    """(K,) largest torque (N·m; N for a prismatic joint) each joint's real actuator gives, ``joint_names``
    order; () when the hand declares none. Simulators apply them on request
    (:meth:`ges_core.sim.SimBackend.set_drive_limits`); robust validation runs its trials with them."""
    armature: tuple[float, ...] = ()
    """(K,) reflected inertia of each joint's actuator (kg·m²; kg for a prismatic joint), ``joint_names`` order; ()
    when the hand declares none. SAPIEN adds it to the joint's inertia (PhysX joint armature); PyBullet has no
    armature and leaves it out. On a light finger link it is most of what the drive moves: the Shadow MJCF's
    0.001 kg·m² is 100-1000x its distal links' inertia (docs/hands/shadow.md, "Armature")."""
    slot_fill: dict[str, str] = field(default_factory=dict, hash=False)
    """Slot -> finger name for slots no physical finger fills (e.g. Allegro's little finger)."""
    couplings: tuple[JointCoupling, ...] = ()
    """Joints that follow another joint (tendons)."""
    self_collision_exclude: tuple[tuple[str, str], ...] = ()
    """Link pairs that never collide with each other, besides :func:`ges_core.urdf.neighbour_link_pairs` (e.g. a
    palm and a thumb link whose collision meshes overlap at every pose); each pair's names sorted. Every engine
    applies them through :meth:`HandModel.excluded_link_pairs`."""
    base_link: str = ""
    """URDF root link; filled by the plugin from its URDF."""
    settings: dict = field(default_factory=dict, hash=False)
    """The hand's own Stage 1 settings, the YAML's ``settings:``: partial sections of the run config
    (``contacts``, ``retarget``, ``refine``, ``pregrasp``, ``validate``, ``robust``; ``thumb_keep``), checked against
    their models; {} when the hand sets none. How they combine with the run's: :mod:`ges_core.hand_settings`."""

    @property
    def num_joints(self) -> int:
        """K, the number of hand joints."""
        return len(self.joint_names)

    @property
    def limits_array(self) -> np.ndarray:
        """(K, 2) float64 joint limits."""
        return np.asarray(self.joint_limits, dtype=np.float64).reshape(-1, 2)

    @property
    def armature_array(self) -> np.ndarray:
        """(K,) float64 :attr:`armature`, zeros when the hand declares none."""
        return np.asarray(self.armature or (0.0,) * self.num_joints, dtype=np.float64)

    @property
    def effort_limits_array(self) -> np.ndarray | None:
        """(K,) float64 :attr:`effort_limits`, or None when the hand declares none."""
        return np.asarray(self.effort_limits, dtype=np.float64) if self.effort_limits else None

    def finger_for_slot(self, slot: str) -> FingerSpec:
        """The physical finger that serves ``slot`` (directly or through ``slot_fill``)."""
        for finger in self.fingers:
            if finger.slot == slot:
                return finger
        if slot in self.slot_fill:
            return self.finger(self.slot_fill[slot])
        where = f" in hand '{self.name}' (no finger and no slot_fill rule)"
        raise UnknownNameError("finger slot", slot, [f.slot for f in self.fingers], where=where)

    def finger(self, name: str) -> FingerSpec:
        """The finger called ``name``."""
        for finger in self.fingers:
            if finger.name == name:
                return finger
        raise UnknownNameError("finger", name, [f.name for f in self.fingers], where=f" in hand '{self.name}'")

    @property
    def slot_tip_links(self) -> tuple[str, ...]:
        """Fingertip link per canonical slot, in :data:`FINGER_SLOTS` order."""
        return tuple(self.finger_for_slot(s).tip_link for s in FINGER_SLOTS)

    @property
    def tip_links(self) -> tuple[str, ...]:
        """Fingertip link of every physical finger, in ``fingers`` order."""
        return tuple(f.tip_link for f in self.fingers)

    def joint_index(self, names: list[str] | tuple[str, ...]) -> np.ndarray:
        """Indices of ``names`` in ``joint_names``."""
        lookup = {n: i for i, n in enumerate(self.joint_names)}
        return np.array([lookup[n] for n in names], dtype=np.int64)

    def closed_pose(self, fraction: float = 0.6) -> np.ndarray:
        """(K,) finger joints moved ``fraction`` of the way from open toward their farther limit.

        For the usual hand (flexion range much larger than extension) this curls the fingers
        toward the palm; wrist and arm joints stay at the open pose. Couplings applied.
        """
        q0, lim = np.asarray(self.open_pose, dtype=np.float64), self.limits_array
        far = np.where(lim[:, 1] - q0 >= q0 - lim[:, 0], lim[:, 1], lim[:, 0])
        finger_joints = {j for f in self.fingers for j in f.joints}
        mask = np.array([n in finger_joints for n in self.joint_names])
        return self.apply_couplings(np.where(mask, q0 + fraction * (far - q0), q0))

    def apply_couplings(self, q: np.ndarray) -> np.ndarray:
        """Copy of ``q`` (..., K) with every follower set to ``ratio * q[leader] + offset``, then clipped."""
        q = np.array(q, dtype=np.float64, copy=True)
        for c in self.couplings:
            f, lead = self.joint_index([c.follower, c.leader])
            q[..., f] = c.ratio * q[..., lead] + c.offset
        lim = self.limits_array
        return np.clip(q, lim[:, 0], lim[:, 1])


class HandModel(ABC):
    """A hand that GES-UniGrasp can simulate, retarget to and lint."""

    @property
    @abstractmethod
    def description(self) -> HandDescription:
        """The hand's declared data."""

    @abstractmethod
    def urdf_path(self) -> Path:
        """Path of a URDF with the hand's links, joints, inertias and collision geometry.

        No ``<material>`` tags; mesh paths absolute. Built (and cached) on first call.
        """

    @property
    def name(self) -> str:
        """Registry name of the hand."""
        return self.description.name

    def urdf_text(self) -> str:
        """The URDF as text."""
        return self.urdf_path().read_text()

    def excluded_link_pairs(self) -> set[frozenset[str]]:
        """Link pairs no engine collides with each other (self-collision on): the URDF's neighbours
        (:func:`ges_core.urdf.neighbour_link_pairs`) and the description's ``self_collision_exclude``."""
        own = {frozenset(pair) for pair in self.description.self_collision_exclude}
        return set(_neighbour_pairs(self.urdf_text())) | own


@functools.lru_cache(maxsize=16)
def _neighbour_pairs(urdf_text: str) -> frozenset[frozenset[str]]:
    """:func:`ges_core.urdf.neighbour_link_pairs`, parsed once per URDF text and process: a backend loads the hand
    once per trial, and the parse (0.4 ms) was a fifth of a SAPIEN backend's whole hand load."""
    from ges_core.urdf import neighbour_link_pairs

    return frozenset(neighbour_link_pairs(urdf_text))
