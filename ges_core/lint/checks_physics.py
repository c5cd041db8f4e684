"""Lint checks that run forward kinematics and the installed simulators."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ges_core.contact import FINGER_SLOTS
from ges_core.errors import GesError
from ges_core.hand import HandModel
from ges_core.lint.problems import LintProblem
from ges_core.sim import SceneConfig, SimBackend

__all__ = ["check_fk_matches_sims", "check_self_collision", "check_wrist_convention"]

FINGER_DIRECTION_TOL_DEG = 35.0
"""Largest angle between the declared finger direction and wrist -> middle fingertip at the open pose."""
PALM_NORMAL_TOL_DEG = 60.0
"""Largest angle between the declared palm normal and the direction fingertips move when the hand closes."""
FK_TOL_M = 1e-3
"""Largest link-position difference between pytorch-kinematics and a simulator, metres."""
SELF_PENETRATION_M = 1e-3
"""Deeper overlap between two hand links at the open pose counts as self-collision, metres."""

SimFactory = Callable[[str, SceneConfig], SimBackend]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b) + 1e-12))
    return float(np.degrees(np.arccos(np.clip(cos, -1, 1))))


def _tips_in_wrist(hand: HandModel, q: np.ndarray) -> np.ndarray:
    """(n, 5, 3) slot fingertip points in the wrist frame for joint rows q (n, K)."""
    import torch

    from ges_core.kinematics import HandKinematics

    d = hand.description
    kin = HandKinematics.from_hand(hand)
    fingers = [d.finger_for_slot(s) for s in FINGER_SLOTS]
    qt = torch.as_tensor(q, dtype=torch.float64)
    tips = kin.points(qt, [f.tip_link for f in fingers], [f.tip_offset for f in fingers]).numpy()
    wrist = kin.link_poses(qt, [d.wrist.link])[:, 0].numpy()  # (n, 4, 4) base frame
    rot, pos = wrist[:, :3, :3], wrist[:, :3, 3]
    return np.einsum("nji,nlj->nli", rot, tips - pos[:, None, :])


def check_wrist_convention(hand: HandModel) -> list[LintProblem]:
    """Declared finger direction and palm normal agree with the kinematics at the open and a closed pose."""
    d = hand.description
    out = []
    declared_dir, declared_normal = np.asarray(d.wrist.finger_direction), np.asarray(d.wrist.palm_normal)
    for label, vec in (("finger_direction", declared_dir), ("palm_normal", declared_normal)):
        if abs(np.linalg.norm(vec) - 1) > 1e-3:
            out.append(LintProblem("wrist-frame", f"{label} {vec.tolist()} is not a unit vector", "normalize it"))
    tips = _tips_in_wrist(hand, np.stack([np.asarray(d.open_pose), d.closed_pose()]))
    middle = tips[0, FINGER_SLOTS.index("middle")]
    angle = _angle_deg(middle, declared_dir)
    if angle > FINGER_DIRECTION_TOL_DEG:
        out.append(
            LintProblem(
                "wrist-frame",
                f"finger_direction is {angle:.0f} deg from wrist->middle fingertip "
                f"{np.round(middle / np.linalg.norm(middle), 3).tolist()}",
                "declare the direction the fingers point in the wrist frame",
            )
        )
    motion = (tips[1] - tips[0]).mean(axis=0)
    motion -= (motion @ declared_dir) * declared_dir  # keep the part across the finger direction
    angle = _angle_deg(motion, declared_normal)
    if angle > PALM_NORMAL_TOL_DEG:
        out.append(
            LintProblem(
                "wrist-frame",
                f"palm_normal is {angle:.0f} deg from the way the fingers close "
                f"{np.round(motion / (np.linalg.norm(motion) + 1e-12), 3).tolist()}",
                "declare the palm normal pointing out of the palm, toward the closing fingers",
            )
        )
    return out


def check_self_collision(hand: HandModel, sim_name: str, make_sim: SimFactory) -> list[LintProblem]:
    """The open pose has no overlapping hand links in ``sim_name`` (``HandModel.excluded_link_pairs`` excepted)."""
    config = SceneConfig(self_collision=True, gravity=0.0)
    try:
        with make_sim(sim_name, config) as sim:
            sim.load_hand(hand, floating=False)
            sim.set_hand_state(np.asarray(hand.description.open_pose)[None])
            sim.step(1)
            pairs = [p for p in sim.contact_pairs(0) if p.body_a == p.body_b and p.separation < -SELF_PENETRATION_M]
    except GesError as exc:
        return [LintProblem("self-collision", f"{sim_name} could not load the hand: {exc}", "fix the URDF")]
    return [
        LintProblem(
            "self-collision",
            f"open pose: links '{p.link_a}' and '{p.link_b}' overlap by {-p.separation * 1000:.1f} mm in {sim_name}",
            "change open_pose or the collision geometry, or (where the two links overlap at every pose, as meshes "
            "that meet at a joint) list the pair in the hand's self_collision_exclude",
        )
        for p in pairs
    ]


def check_fk_matches_sims(
    hand: HandModel, sim_name: str, make_sim: SimFactory, *, samples: int = 5, seed: int = 0
) -> list[LintProblem]:
    """Fingertip and keypoint link poses from pytorch-kinematics equal ``sim_name``'s for random joint values."""
    import torch

    from ges_core.kinematics import HandKinematics

    d = hand.description
    links = sorted({f.tip_link for f in d.fingers} | {k for f in d.fingers for k in f.keypoint_links} | {d.wrist.link})
    lim = d.limits_array
    q = np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], size=(samples, d.num_joints))
    expected = HandKinematics.from_hand(hand).link_poses(torch.as_tensor(q), links)[..., :3, 3].numpy()
    got = np.empty_like(expected)
    with make_sim(sim_name, SceneConfig(self_collision=False, gravity=0.0)) as sim:
        sim.load_hand(hand, floating=False)
        for i in range(samples):
            sim.set_hand_state(q[i : i + 1])
            got[i] = sim.link_poses(links)[0, :, :3]  # base fixed at the world origin
    err = np.linalg.norm(got - expected, axis=-1).max(axis=0)
    return [
        LintProblem(
            "fk",
            f"link '{link}' is {e * 1000:.2f} mm apart in pytorch-kinematics and {sim_name}",
            "check joint axes, origins and that the URDF parses identically in both",
        )
        for link, e in zip(links, err, strict=True)
        if e > FK_TOL_M
    ]
