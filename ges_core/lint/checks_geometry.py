"""Lint checks on the hand's shapes and reach: hulls far off their meshes, hull overlaps the meshes do not have,
thumb opposition."""

from __future__ import annotations

import numpy as np

from ges_core.hand import HandModel
from ges_core.lint.problems import LintProblem

__all__ = ["check_hull_gaps", "check_hull_overlaps", "check_thumb_opposition"]

OPPOSITION_TOL_DEG = 45.0
"""deg: the thumb pad must come within this of facing some finger pad (normals anti-parallel). A pinch with
the pads 45 deg off still has both contact normals inside a friction cone of mu = 1 (45 deg)."""
OPPOSITION_SAMPLES = 2048
"""Configurations sampled (seeded, uniform within the joint limits, couplings applied): one batched FK."""


def check_hull_gaps(hand: HandModel, ref: str) -> list[LintProblem]:
    """Collision meshes whose convex hull stands more than ``HULL_GAP_TOL`` off the mesh and that are not decomposed
    yet (:func:`ges_core.hand_prep.prepare.undecomposed_deep_hulls`): a contact there lands on the hull, not on
    the mesh."""
    from ges_core.hand_prep.prepare import HULL_GAP_TOL, undecomposed_deep_hulls

    return [
        LintProblem(
            "hull-gap",
            f"collision mesh {p.path.name} (link(s) {', '.join(p.links)}): its surface lies {p.hull_gap * 1000:.1f} mm "
            f"below its convex hull (over {HULL_GAP_TOL * 1000:.0f} mm), and both engines collide it as that hull "
            "(no CoACD parts in the cache)",
            f"run `ges hand prepare {ref}` (decomposes it with CoACD, cached; `ges synth` and `ges demo` also do it "
            "before a run)",
        )
        for p in undecomposed_deep_hulls(hand)
    ]


def check_hull_overlaps(hand: HandModel, ref: str) -> list[LintProblem]:
    """Links that may touch whose convex hulls overlap more than their meshes (:mod:`ges_core.hand_prep.geometry`)."""
    from ges_core.hand_prep.geometry import HULL_OVERLAP_TOL, engine_link_shapes, hand_link_poses, pair_overlaps

    text = hand.urdf_text()
    shapes = engine_link_shapes(text, hand.urdf_path().parent)
    if all(s.primitive for group in shapes.values() for s in group):
        return []  # primitives only: every hull is the shape itself
    found = pair_overlaps(shapes, hand_link_poses(hand, sorted(shapes)), hand.excluded_link_pairs(), HULL_OVERLAP_TOL)
    return [_overlap_problem(o, ref) for o in found]


def _overlap_problem(o, ref: str) -> LintProblem:
    gap = f"{o.mesh_gap * 1000:.1f} mm apart" if o.mesh_gap >= 0 else f"{-o.mesh_gap * 1000:.1f} mm into each other"
    if abs(o.mesh_gap) < 1e-4:
        gap = "touching or crossing (not closed surfaces: how deep is not known)"
    return LintProblem(
        "hull-overlap",
        f"links '{o.link_a}' and '{o.link_b}' ({o.pose} pose): their convex hulls overlap by "
        f"{o.hull_overlap * 1000:.1f} mm where the meshes are {gap} (both engines collide each mesh as its hull)",
        f"run `ges hand prepare {ref}` (decomposes those links' meshes with CoACD, cached; both simulators then "
        "collide the parts)",
    )


def check_thumb_opposition(hand: HandModel) -> list[LintProblem]:
    """Some joint configuration brings the thumb pad within :data:`OPPOSITION_TOL_DEG` of facing a finger pad."""
    d = hand.description
    thumb = d.finger_for_slot("thumb")
    others = [f for f in d.fingers if f is not thumb and f.pad_normal is not None]
    if thumb.pad_normal is None or not others:
        return []  # nothing declared to check; retargeting then ignores pad orientation too
    best = _best_facing_angles(hand, thumb, others)
    if min(best.values()) <= OPPOSITION_TOL_DEG:
        return []
    listed = ", ".join(f"{name} {angle:.0f} deg" for name, angle in best.items())
    return [
        LintProblem(
            "opposition",
            f"no configuration of {OPPOSITION_SAMPLES} sampled brings the thumb pad within {OPPOSITION_TOL_DEG:.0f} "
            f"deg of facing a finger pad (best: {listed}); pinch and precision grasps cannot hold",
            "check pad_normal of the thumb and fingers (tip-link frame, pointing out of the pad) and the thumb's "
            "joint limits",
        )
    ]


def _best_facing_angles(hand: HandModel, thumb, others) -> dict[str, float]:
    """Finger name -> smallest angle (deg) between the thumb pad normal and the reversed finger pad normal,
    over sampled configurations where each pad lies in front of the other."""
    import torch

    from ges_core.kinematics import shared_kinematics

    d = hand.description
    lim = d.limits_array
    q = np.random.default_rng(0).uniform(lim[:, 0], lim[:, 1], size=(OPPOSITION_SAMPLES, d.num_joints))
    q = torch.as_tensor(d.apply_couplings(q))
    fingers = [thumb, *others]
    kin = shared_kinematics(hand)
    poses = kin.link_poses(q, [f.tip_link for f in fingers]).numpy()  # (B, F, 4, 4)
    pads = np.stack([poses[:, i, :3, :3] @ np.asarray(f.pad_normal) for i, f in enumerate(fingers)], axis=1)
    offsets = np.asarray([f.tip_offset for f in fingers])
    points = np.einsum("bfij,fj->bfi", poses[..., :3, :3], offsets) + poses[..., :3, 3]
    out = {}
    for i, f in enumerate(others, start=1):
        cos = -np.einsum("bi,bi->b", pads[:, 0], pads[:, i])
        between = points[:, i] - points[:, 0]
        facing = (np.einsum("bi,bi->b", between, pads[:, 0]) > 0) & (np.einsum("bi,bi->b", between, pads[:, i]) < 0)
        angles = np.degrees(np.arccos(np.clip(cos[facing], -1, 1)))
        out[f.name] = float(angles.min()) if len(angles) else 180.0
    return out
