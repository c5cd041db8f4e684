"""The retracted hand kept above the table: each finger's retraction shortened until its links clear it.

Refinement closes from the retracted hand (:func:`ges_core.synthesis.physics.squeeze.retract_joints`): every
finger backed off its contact along its reversed press direction. On low contacts that direction points down as
well as away, and in 83 of the 103 Shadow placements that failed ``table_contact`` the retracted hand's lowest
point was already below the table before the close began (docs/synthesis/refine_validate.md, "Why the retracted
hand meets the table"). :func:`table_clear_retract` keeps each finger's retraction only as far as its collision
points (:mod:`ges_core.collision_points`) stay ``clearance`` above the table, or as high as they are at the grasp
where that is lower: it tries the fractions 1, 3/4, ..., 0 of each finger's travel and keeps the largest that
clears. Fingers are independent chains below the base, so one forward-kinematics batch (every fraction applied to
every finger at once) decides them all.

Frames: the grasp's base pose is in the object's resting frame, whose z = 0 is the table top (the wrist search's
table penalty reads the same heights, :func:`ges_core.synthesis.retarget.search.table_penalty`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np
import torch

from ges_core.hand import HandModel
from ges_core.kinematics import HandKinematics, cached_kinematics, shared_kinematics
from ges_core.synthesis.physics.squeeze import RetractSteps
from ges_core.transforms import pose_to_matrix

__all__ = ["FingerPoints", "finger_points", "table_clear_retract"]

# 1e-6: a link a finger's joints move shifts (or turns) by millimetres under the 0.3 rad probe, one they do not by
# nothing (a distal link turns about its own origin, so its rotation is compared too).
_MOVED = 1e-6
_PROBE = 0.3


@dataclass(frozen=True)
class FingerPoints:
    """A hand's collision points grouped by the finger whose joints move them."""

    links: tuple[str, ...]
    """Links with collision geometry, in the order of ``link_of``."""
    points: np.ndarray
    """(N, 3) points on the collision geometry, each in its link's frame, m."""
    link_of: np.ndarray
    """(N,) index into ``links`` of each point."""
    finger_of: np.ndarray
    """(N,) index into ``description.fingers`` of the finger whose joints move each point; -1: none (the palm)."""

    def local(self, kinematics: HandKinematics, q: np.ndarray | torch.Tensor) -> np.ndarray:
        """(B, N, 3) every point in the hand's base frame, m, for joints ``q`` (B, K)."""
        link_of, points = self._tensors
        poses = kinematics.link_poses(torch.as_tensor(q, dtype=torch.float64), list(self.links))[:, link_of]
        return ((poses[..., :3, :3] @ points[..., None])[..., 0] + poses[..., :3, 3]).numpy()  # (B, N, 3), base frame

    @cached_property
    def _tensors(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``link_of`` and ``points`` as tensors, made once (copies: the shared arrays are read-only); the wrist
        search calls :meth:`local` twice per batch of placements."""
        return torch.tensor(self.link_of), torch.tensor(self.points)

    def heights(self, kinematics: HandKinematics, q: np.ndarray, base: np.ndarray) -> np.ndarray:
        """(B, N) z of every point, m, for joints ``q`` (B, K) and the base-link pose ``base`` (4, 4), z-up frame."""
        return self.local(kinematics, q) @ base[2, :3] + base[2, 3]


def finger_points(hand: HandModel) -> FingerPoints:
    """The :class:`FingerPoints` of ``hand`` (built once per URDF, joint order and fingers, then shared, read-only):
    the points the wrist search (:class:`ges_core.synthesis.retarget.retargeter.GraspRetargeter`), refinement's
    start and the pre-grasp keep off the table."""
    d = hand.description
    fingers = tuple(tuple(d.joint_index(f.joints)) for f in d.fingers)
    return _finger_points(
        hand.urdf_text(), str(hand.urdf_path().parent), tuple(d.joint_names), fingers, tuple(d.open_pose)
    )


@lru_cache(maxsize=8)
def _finger_points(
    urdf_text: str,
    urdf_dir: str,
    joint_names: tuple[str, ...],
    fingers: tuple[tuple[int, ...], ...],
    open_pose: tuple[float, ...],
) -> FingerPoints:
    # imported here: both pull in trimesh, which the scripted expert's import of the physics package must not
    from ges_core.collision_points import collision_points
    from ges_core.hand_prep.engine_urdf import engine_urdf

    # engine_urdf: the geometry the simulators load (absolute mesh paths, prepared parts), as the wrist search reads
    hull = collision_points(engine_urdf(urdf_text, Path(urdf_dir)))
    links = tuple(hull)
    link_of = np.repeat(np.arange(len(links)), [len(v) for v in hull.values()])
    points = np.concatenate(list(hull.values())) if hull else np.zeros((0, 3))
    # A link belongs to the finger whose joints move it: each finger's joints turned _PROBE rad from the open pose.
    probes = np.repeat(np.asarray(open_pose, dtype=np.float64)[None], len(fingers) + 1, axis=0)
    for f, idx in enumerate(fingers):
        probes[f + 1, list(idx)] += _PROBE
    poses = cached_kinematics(urdf_text, joint_names).link_poses(torch.as_tensor(probes), list(links))
    origins = poses[..., :3, 3].numpy()  # (F + 1, L, 3)
    turned = poses[..., :3, :3].numpy()
    moved = (np.linalg.norm(origins[1:] - origins[0], axis=-1) > _MOVED) | (
        np.abs(turned[1:] - turned[0]).max(axis=(-1, -2)) > _MOVED
    )  # (F, L)
    finger_of_link = np.where(moved.any(axis=0), moved.argmax(axis=0), -1)
    arrays = (points, link_of, finger_of_link[link_of])
    for a in arrays:  # shared by every caller (the wrist search, refinement, the pre-grasp)
        a.flags.writeable = False
    return FingerPoints(links, *arrays)


def table_clear_retract(
    hand: HandModel,
    q_grasp: np.ndarray,
    base_pose: np.ndarray,
    *,
    travel: float,
    clearance: float | None,
    fractions: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ges_core.synthesis.physics.squeeze.retract_joints` of ``q_grasp`` with each finger's travel shortened
    to clear the table.

    q_grasp: (K,) grasp joints. base_pose: (7,) or (P, 7) the hand's base-link pose(s) [x, y, z, qw, qx, qy, qz] in
    the object's resting frame (table top at z = 0), m; with several, a finger must clear the table at each (the
    pre-grasp's approach: a move between two poses of one rotation is lowest at one of its ends).
    clearance: m the retracted finger's collision points should stay above the table; a finger lower than that at
    the grasp joints itself is kept no lower than it is there; None: the full retraction (no table read).
    fractions: travel is tried at 1, 1 - 1/fractions, ..., 0.
    Returns the (K,) retracted joints (limits and couplings applied) and the (F,) fraction of the travel each
    finger kept (``description.fingers`` order).
    """
    if fractions < 1:
        raise ValueError(f"table_clear_retract: fractions must be at least 1, got {fractions}")
    d = hand.description
    n_fingers = len(d.fingers)
    steps = np.linspace(1.0, 0.0, fractions + 1)
    retract = RetractSteps.of(hand, q_grasp, travel=travel)  # one Jacobian for every fraction
    if clearance is None:
        return retract.joints(), np.ones(n_fingers)
    qs = np.stack([retract.joints(np.full(n_fingers, s)) for s in steps])
    pts = finger_points(hand)
    local = pts.local(shared_kinematics(hand), qs)  # (S, N, 3): one forward-kinematics batch
    bases = pose_to_matrix(np.asarray(base_pose, dtype=np.float64).reshape(-1, 7))
    z = np.min([local @ base[2, :3] + base[2, 3] for base in bases], axis=0)  # (S, N), lowest over the poses
    kept = np.ones(n_fingers)
    for f in range(n_fingers):
        mine = pts.finger_of == f
        if not mine.any():
            continue
        low = z[:, mine].min(axis=1)  # (S,), the last row is the grasp's own joints
        floor = min(clearance, float(low[-1]))
        kept[f] = steps[int(np.argmax(low >= floor))]
    return retract.joints(kept), kept
