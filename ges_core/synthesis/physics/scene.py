"""Shared simulator plumbing of refinement and validation: staging a scene, frames, fingertip reads.

Both steps run one grasp in env 0 of a :class:`ges_core.sim.SimBackend` with ``num_envs == 1``. The
object rests on the table (``load_object(obj)`` with no pose), so its resting frame is the world
frame up to the backend's rest margin; grasps are given in the object frame and mapped to the world
through the object's pose read right after loading.

Every physics trial of Stage 1 (a refinement, a nominal validation, each perturbation trial) runs in a backend
of its own (:class:`TrialScenes`): a backend reused across trials carries the earlier trials' solver state
(``benchmarks/trial_history.py``: 4 of 24 procedural and 4 of 20 real placement histories changed between a
backend reused for an object's trials and one per trial), so a grasp's verdict would depend on which trials came
before it, and a replay of a stored record would not reproduce it.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from ges_core.arrays import checked_array, checked_poses
from ges_core.errors import ConfigError, SimulationError
from ges_core.hand import HandDescription, HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import SceneConfig, SimBackend
from ges_core.synthesis.types import Grasp

__all__ = [
    "REST_AWAY",
    "TOUCH_SEPARATION",
    "HandContacts",
    "RestDrift",
    "TrialScenes",
    "check_grasp",
    "closing_direction",
    "finger_joint_indices",
    "hand_contacts",
    "stage_scene",
    "tip_forces",
    "tip_rule",
]

TOUCH_SEPARATION = 5e-4
"""m: a listed hand-table or hand-object pair closer than this touches (both backends' own touching distance)."""

REST_AWAY = 1.0
"""m: how far above the object the hand waits while the object settles alone (:func:`rest_drift`)."""

_LOADED: weakref.WeakKeyDictionary[SimBackend, str] = weakref.WeakKeyDictionary()
"""Which hand these helpers loaded into which backend (a backend takes one hand for its lifetime)."""


class TrialScenes:
    """A new single-env backend of simulator ``name`` for every physics trial, ``hand`` loaded (module docs).

    build_sim: ``(name, scene_config) -> SimBackend``, e.g. :meth:`ges_core.registry.Registry.build_sim`.
    ``seconds`` sums the builds and hand loads so far (the record's ``setup_seconds``).
    """

    def __init__(
        self, build_sim: Callable[[str, SceneConfig], SimBackend], name: str, config: SceneConfig, hand: HandModel
    ) -> None:
        self.build_sim, self.name, self.config, self.hand = build_sim, name, config, hand
        self.seconds = 0.0

    def build(self) -> SimBackend:
        """A new backend holding the hand (no object yet); the caller closes it (:meth:`open` does)."""
        start = time.perf_counter()
        sim = self.build_sim(self.name, self.config)
        try:
            _load_hand(sim, self.hand)
        except BaseException:
            sim.close()
            raise
        self.seconds += time.perf_counter() - start
        return sim

    @contextmanager
    def open(self) -> Iterator[SimBackend]:
        """:meth:`build`, closed on exit."""
        sim = self.build()
        try:
            yield sim
        finally:
            sim.close()


def stage_scene(sim: SimBackend, hand: HandModel, obj: ObjectAsset, *, fixed: bool = False) -> np.ndarray:
    """Load ``hand`` (floating, once per backend) and ``obj`` (resting on the table); return the object pose.

    Returns (7,) the object's pose in the world right after loading, position m + quaternion wxyz.
    A backend keeps the hand between calls; the object is replaced on every call. fixed: the object
    stays at its resting pose whatever pushes it (``SimBackend.load_object(fixed=True)``).
    """
    if sim.num_envs != 1:
        raise ConfigError(
            f"{sim.name}: refinement and validation run one grasp in one scene, but the backend has "
            f"num_envs={sim.num_envs}; build it with SceneConfig(num_envs=1)"
        )
    _load_hand(sim, hand)
    sim.load_object(obj, fixed=fixed)
    return sim.object_pose()[0]


def _load_hand(sim: SimBackend, hand: HandModel) -> None:
    """Load ``hand`` floating into ``sim`` unless it is there already; SimulationError if another hand is."""
    loaded = _LOADED.get(sim)
    if loaded is None:
        sim.load_hand(hand, floating=True)
        _LOADED[sim] = hand.name
    elif loaded != hand.name:
        raise SimulationError(
            f"{sim.name}: this backend already holds hand '{loaded}'; build a new backend for hand '{hand.name}'"
        )


@dataclass(frozen=True)
class RestDrift:
    """How far an object left alone on the table moved from the pose it was set down in (:func:`rest_drift`)."""

    shift: float
    """Displacement of the object frame's origin, m."""
    turn_deg: float
    """Rotation, degrees."""
    seconds: float
    """Simulated time it was left alone, s."""

    def exceeds(self, max_shift: float, max_turn_deg: float) -> bool:
        """Whether it moved more than ``max_shift`` m or turned more than ``max_turn_deg`` degrees."""
        return self.shift > max_shift or self.turn_deg > max_turn_deg


def rest_drift(sim: SimBackend, hand: HandModel, obj: ObjectAsset, steps: int, *, tilt_deg: float = 0.0) -> RestDrift:
    """Set ``obj`` down at its resting pose, leave it alone ``steps`` physics steps, and measure how far it went.

    The hand (loaded once per backend, as :func:`stage_scene`) waits :data:`REST_AWAY` m above the object,
    open, held by its drives. An object that rolls or tips over on its own from the library's resting pose
    (a sphere-like scan on a slightly off support, an egg set on its tip) drifts centimetres or tens of degrees
    in a second; one at rest moves by the engines' settling (well under a millimetre).

    tilt_deg: set it down tilted this much about the world x axis through its lowest point, raised just
    enough to clear the table: a stable pose falls back to where it rests, while a balance point (an egg on
    its tip, which an untouched simulation keeps standing) tips over. The drift is measured from the untilted
    resting pose. The object is left where it drifted to: stage it again before using the scene.
    """
    if steps < 1:
        raise ConfigError(f"rest_drift: steps must be >= 1, got {steps}")
    start = stage_scene(sim, hand, obj)
    if tilt_deg:
        sim.set_object_pose(_tilted(start, obj, tilt_deg)[None])
    away = start.copy()
    away[2] += REST_AWAY
    away[3:] = (1.0, 0.0, 0.0, 0.0)
    open_q = hand.description.apply_couplings(np.asarray(hand.description.open_pose, dtype=np.float64))
    sim.set_hand_state(open_q[None], away[None])
    sim.set_wrist_targets(away[None])
    sim.set_joint_targets(open_q[None])
    sim.step(steps)
    end = sim.object_pose()[0]
    w = float(np.clip(abs(np.dot(start[3:], end[3:])), 0.0, 1.0))
    turn = float(np.degrees(2.0 * np.arccos(w)))
    return RestDrift(float(np.linalg.norm(end[:3] - start[:3])), turn, steps * sim.config.timestep)


def _tilted(rest: np.ndarray, obj: ObjectAsset, tilt_deg: float) -> np.ndarray:
    """(7,) ``rest`` (7,) turned ``tilt_deg`` about world x through its origin, raised to clear the table."""
    import trimesh
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_euler("x", tilt_deg, degrees=True)
    w, x, y, z = rest[3:]
    rotation = turn * Rotation.from_quat([x, y, z, w])
    verts = rotation.apply(np.asarray(trimesh.load(obj.mesh_path, force="mesh").vertices))
    pose = rest.copy()
    pose[2] = rest[2] - min(0.0, float(verts[:, 2].min()))
    qx, qy, qz, qw = rotation.as_quat()
    pose[3:] = (qw, qx, qy, qz)
    return pose


def check_grasp(description: HandDescription, grasp: Grasp, what: str) -> None:
    """ConfigError unless ``grasp`` belongs to this hand; ArrayError unless it holds a finite (7,) pose with a
    non-zero quaternion and (K,) joints."""
    if grasp.hand != description.name:
        raise ConfigError(f"{what}: bad grasp: it is for hand '{grasp.hand}', not '{description.name}'")
    checked_array(grasp.q, (description.num_joints,), f"{what}: grasp q", layout="hand joint_names order")
    checked_poses(grasp.wrist_pose, None, f"{what}: grasp wrist_pose")


def closing_direction(q_from: np.ndarray, q_to: np.ndarray) -> np.ndarray:
    """(K,) sign of each joint's motion from ``q_from`` to ``q_to``; 0 for joints that move less than 1 mrad."""
    delta = np.asarray(q_to, dtype=np.float64) - np.asarray(q_from, dtype=np.float64)
    return np.sign(delta) * (np.abs(delta) > 1e-3)


def finger_joint_indices(description: HandDescription) -> list[np.ndarray]:
    """Per finger (``fingers`` order), the indices of its joints in ``joint_names``."""
    return [description.joint_index(f.joints) for f in description.fingers]


def tip_forces(sim: SimBackend, tips: list[str]) -> np.ndarray:
    """(F,) magnitude of the object's contact force on each fingertip link, N (env 0)."""
    return np.linalg.norm(sim.contact_forces(tips, "object")[0], axis=-1)


def tip_rule(forces: np.ndarray, thumb: int, min_force: float, min_tips: int, require_thumb: bool) -> bool:
    """Whether fingertip forces (F,) N count as a fingertip grasp: ``min_tips`` tips above ``min_force``,
    the thumb (index ``thumb``) among them if ``require_thumb``."""
    touching = forces > min_force
    return bool(int(touching.sum()) >= min_tips and (touching[thumb] or not require_thumb))


@dataclass(frozen=True)
class HandContacts:
    """The hand's contacts in env 0 at one moment (from the slow pair list)."""

    depth: float
    """Deepest hand-object penetration, m (>= 0)."""
    table: bool
    """Some hand link touches the table."""
    object_links: frozenset[str]
    """Hand links touching the object (closer than :data:`TOUCH_SEPARATION` or pushing)."""
    deepest_link: str | None = None
    """The hand link of :attr:`depth` (None: no hand link inside the object)."""


def hand_contacts(
    sim: SimBackend, table_force: float, table_separation: float | None = TOUCH_SEPARATION
) -> HandContacts:
    """Penetration, table contact and object-touching links of the hand in env 0.

    A hand-table pair touches when pushing harder than ``table_force`` N or closer than ``table_separation`` m
    (:data:`TOUCH_SEPARATION` by default; None: the force alone says it). Reads the slow pair list: call it once, not
    every step.
    """
    near = -np.inf if table_separation is None else table_separation
    depth, deepest, table, links = 0.0, None, False, set()
    for pair in sim.contact_pairs(0):
        bodies = {pair.body_a, pair.body_b}
        if bodies == {"hand", "object"}:
            link = pair.link_a if pair.body_a == "hand" else pair.link_b
            if -pair.separation > depth:
                depth, deepest = -pair.separation, link
            if pair.separation < TOUCH_SEPARATION or pair.force > 0.0:
                links.add(link)
        elif bodies == {"hand", "table"} and (pair.separation < near or pair.force > table_force):
            table = True
    return HandContacts(depth, table, frozenset(links), deepest)
