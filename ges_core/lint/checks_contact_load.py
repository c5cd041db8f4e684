"""Lint note: how many of a hand's collision-shape pairs sit within an engine's contact distance at random poses.

Every pair of shapes closer than the contact distance (PhysX: the two shapes' contact offsets added) is a contact
pair the engine tracks and solves at each physics step, whether the links touch or not. A hand whose neighbouring
fingers carry several convex parts each, a tenth of a millimetre apart, keeps dozens of such pairs at most poses:
the Ability hand (docs/hands/ability.md) stepped 5x slower in SAPIEN with its self-collision on than off, and PPO
ran at 657 env-steps/s against the Allegro's 1,664 (docs/training.md, "Per hand"). This check counts them without
an engine, so it says so before any run.

How: ``POSES`` seeded joint configurations uniform within the limits (couplings applied), forward kinematics
(:func:`ges_core.kinematics.shared_kinematics`), the shapes as the engines load them (convex hulls, a decomposed
mesh's parts, primitives: :func:`ges_core.hand_prep.geometry.engine_link_shapes`), every pair of shapes on two links
that may collide (not :meth:`~ges_core.hand.HandModel.excluded_link_pairs`). A pair counts as near when no axis of
the separating-axis test (each hull's face normals, cross products of their edge directions, :data:`EDGE_AXES` per
shape) separates them by ``distance`` or more. The largest separation along those axes is a lower bound on the
distance, so a pair whose closest points are two vertices may count near a little early (cross-checked against
SAPIEN's own pair list in ``tests/test_lint_contact_load.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ges_core.hand import HandModel
from ges_core.lint.problems import LintProblem

__all__ = ["CONTACT_DISTANCE", "NOTE_PAIRS", "POSES", "NearPairs", "check_contact_load", "near_shape_pairs"]

CONTACT_DISTANCE = 0.004
"""m: SAPIEN's contact distance between two hand shapes at the registry's 2 mm contact offset per shape."""
POSES = 32
"""Random joint configurations sampled (seed 0)."""
NOTE_PAIRS = 16
"""A median above this many near shape pairs per pose gets the note. Measured (docs/hands/assets.md, "Contact
load"): the Allegro 1, the Shadow 3 (its MJCF's pairs; 7.5 with every pair), the Ability 60 (SAPIEN lists 47.5 at
the same poses)."""
EDGE_AXES = 24
"""Edge directions per shape in the separating-axis test (evenly subsampled): fewer can only count a pair near
early."""
SHOWN = 8
"""Link pairs named in the note, most often near first."""


@dataclass(frozen=True)
class NearPairs:
    """What :func:`near_shape_pairs` counted."""

    per_pose: np.ndarray
    """(poses,) near shape pairs at each pose."""
    link_share: dict[tuple[str, str], float]
    """(link_a, link_b) sorted -> share of the poses at which some shape pair of the two links is near."""
    shape_pairs: int
    """Shape pairs that may collide (on two links not excluded)."""


def near_shape_pairs(
    hand: HandModel, distance: float = CONTACT_DISTANCE, *, poses: int = POSES, seed: int = 0
) -> NearPairs:
    """Near shape pairs of ``hand`` at ``poses`` random configurations (module docs)."""
    import torch

    from ges_core.hand_prep.geometry import engine_link_shapes
    from ges_core.kinematics import shared_kinematics

    shapes = engine_link_shapes(hand.urdf_text(), hand.urdf_path().parent)
    links = sorted(shapes)
    d = hand.description
    lim = d.limits_array
    q = np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], size=(poses, d.num_joints))
    q = np.stack([d.apply_couplings(row) for row in q])
    placed = shared_kinematics(hand).link_poses(torch.as_tensor(q), links).numpy()  # (P, L, 4, 4)
    convex = [(li, _Convex.of(s.hull)) for li, link in enumerate(links) for s in shapes[link]]
    excluded = hand.excluded_link_pairs()
    pairs = [
        (i, j)
        for i in range(len(convex))
        for j in range(i + 1, len(convex))
        if convex[i][0] != convex[j][0] and frozenset((links[convex[i][0]], links[convex[j][0]])) not in excluded
    ]
    rot, trans = placed[..., :3, :3], placed[..., :3, 3]
    centres = np.stack([rot[:, li] @ c.centre + trans[:, li] for li, c in convex], axis=1)  # (P, S, 3)
    radii = np.array([c.radius for _, c in convex])
    near = np.zeros((poses, len(pairs)), dtype=bool)
    if pairs:
        a, b = np.array(pairs).T
        gaps = np.linalg.norm(centres[:, a] - centres[:, b], axis=2) - radii[a] - radii[b]
        for p, k in zip(*np.nonzero(gaps < distance), strict=True):  # bounding spheres first
            (la, ca), (lb, cb) = convex[a[k]], convex[b[k]]
            near[p, k] = not _apart(ca, cb, placed[p, la], placed[p, lb], distance)
    share: dict[tuple[str, str], np.ndarray] = {}
    for k, (i, j) in enumerate(pairs):
        key = (links[convex[i][0]], links[convex[j][0]])
        share[key] = share.get(key, np.zeros(poses, dtype=bool)) | near[:, k]
    return NearPairs(near.sum(1), {k: float(v.mean()) for k, v in share.items() if v.any()}, len(pairs))


def check_contact_load(hand: HandModel, distance: float = CONTACT_DISTANCE) -> list[LintProblem]:
    """A note when a median of more than :data:`NOTE_PAIRS` shape pairs sit within ``distance`` at random poses."""
    found = near_shape_pairs(hand, distance)
    median = float(np.median(found.per_pose))
    if median <= NOTE_PAIRS:
        return []
    top = sorted(found.link_share.items(), key=lambda kv: (-kv[1], kv[0]))[:SHOWN]
    named = ", ".join(f"{a}-{b} ({s:.0%})" for (a, b), s in top)
    return [
        LintProblem(
            "contact-load",
            f"at {len(found.per_pose)} random poses a median of {median:.0f} collision-shape pairs on different links "
            f"(of {found.shape_pairs}) lie within {distance * 1000:.0f} mm of each other (SAPIEN's contact distance "
            f"at the registry's 2 mm offset per shape): each is a contact pair every physics step solves, touching or "
            f"not. Link pairs most often near (share of poses): {named}",
            "nothing, if those links must collide; where two links cannot touch in a way that matters (neighbouring "
            "fingers side by side, as their source's own contact list may say), list the pair in the hand's "
            "self_collision_exclude (docs/hands/format.md) and measure: docs/hands/assets.md, 'Contact load'",
            note=True,
        )
    ]


@dataclass(frozen=True)
class _Convex:
    """A convex shape in its link frame: vertices, unique outward face normals, centre and radius."""

    vertices: np.ndarray
    normals: np.ndarray
    edges: np.ndarray
    centre: np.ndarray
    radius: float

    @classmethod
    def of(cls, hull) -> _Convex:
        vertices = np.asarray(hull.vertices, dtype=np.float64)
        normals = np.unique(np.round(np.asarray(hull.face_normals, dtype=np.float64), 2), axis=0)  # ~0.6 deg bins
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        edges = vertices[hull.edges_unique[:, 1]] - vertices[hull.edges_unique[:, 0]]
        edges /= np.linalg.norm(edges, axis=1, keepdims=True)
        edges *= np.where(edges[:, :1] < 0, -1.0, 1.0)  # one sign per direction
        edges = np.unique(np.round(edges, 3), axis=0)
        edges = edges[:: max(1, len(edges) // EDGE_AXES)]
        centre = 0.5 * (vertices.min(0) + vertices.max(0))
        return cls(vertices, normals, edges, centre, float(np.linalg.norm(vertices - centre, axis=1).max()))


def _apart(a: _Convex, b: _Convex, pose_a: np.ndarray, pose_b: np.ndarray, distance: float) -> bool:
    """Whether some axis separates ``a`` and ``b`` placed at ``pose_a``, ``pose_b`` (4, 4) by ``distance`` or more.

    Axes in order of cost, each set tried only when the cheaper ones did not separate: the line between the centres,
    the face normals of both, the cross products of their edge directions (:data:`EDGE_AXES` each)."""
    ra, rb = pose_a[:3, :3], pose_b[:3, :3]
    va, vb = a.vertices @ ra.T + pose_a[:3, 3], b.vertices @ rb.T + pose_b[:3, 3]
    line = (rb @ b.centre + pose_b[:3, 3]) - (ra @ a.centre + pose_a[:3, 3])
    if _separation(va, vb, line[None] / max(float(np.linalg.norm(line)), 1e-12)) >= distance:
        return True
    if _separation(va, vb, np.concatenate([a.normals @ ra.T, b.normals @ rb.T])) >= distance:
        return True
    cross = np.cross((a.edges @ ra.T)[:, None, :], (b.edges @ rb.T)[None, :, :]).reshape(-1, 3)
    norm = np.linalg.norm(cross, axis=1)
    return _separation(va, vb, cross[norm > 1e-9] / norm[norm > 1e-9, None]) >= distance


def _separation(va: np.ndarray, vb: np.ndarray, axes: np.ndarray) -> float:
    """Largest gap between the projections of the point sets ``va``, ``vb`` on unit ``axes`` (A, 3), metres
    (negative: they overlap on every axis); -inf without axes. The separating-axis test of ``ges hand prepare``'s
    overlap check (:func:`ges_core.hand_prep.geometry.sat_overlap`), sign turned."""
    from ges_core.hand_prep.geometry import sat_overlap

    return -sat_overlap(va, vb, axes)
