"""Lint checks that read only the URDF and the hand description."""

from __future__ import annotations

import numpy as np

from ges_core.contact import FINGER_SLOTS
from ges_core.errors import AssetError
from ges_core.hand import HandDescription
from ges_core.lint.problems import LintProblem
from ges_core.lint.urdf_tree import UrdfTree

__all__ = ["check_collision_geometry", "check_inertia", "check_joint_limits", "check_slots", "check_tip_links"]

MIN_LINK_MASS = 1e-4
"""kg; lighter links make PhysX and Bullet unstable (a 1e-6 kg knuckle flung boxes in PyBullet)."""
MAX_HAND_MASS = 20.0
"""kg; a hand (with forearm) heavier than this is almost surely a unit error (g instead of kg)."""


def check_joint_limits(d: HandDescription, tree: UrdfTree) -> list[LintProblem]:
    """Every hand joint is limited, lower < upper, and the open pose lies inside the limits."""
    out = []
    for name, q0 in zip(d.joint_names, d.open_pose, strict=True):
        limit = tree.joint_limit.get(name)
        if limit is None:
            out.append(LintProblem("joint-limits", f"joint '{name}' has no limit", "add <limit lower= upper=> to it"))
        elif limit[0] >= limit[1]:
            out.append(
                LintProblem(
                    "joint-limits",
                    f"joint '{name}' has lower {limit[0]} >= upper {limit[1]}",
                    "swap or correct the limits",
                )
            )
        elif not limit[0] - 1e-6 <= q0 <= limit[1] + 1e-6:
            out.append(
                LintProblem(
                    "joint-limits",
                    f"open pose of '{name}' ({q0:.3f}) is outside [{limit[0]:.3f}, {limit[1]:.3f}]",
                    "set open_pose inside the limits",
                )
            )
    return out


def check_slots(d: HandDescription, tree: UrdfTree) -> list[LintProblem]:
    """Every canonical slot is served once; fingers name real joints; slot_fill names real fingers."""
    out = []
    names = [f.name for f in d.fingers]
    for slot in FINGER_SLOTS:
        direct = [f.name for f in d.fingers if f.slot == slot]
        if len(direct) > 1:
            out.append(
                LintProblem("slots", f"slot '{slot}' is claimed by fingers {direct}", "give each finger its own slot")
            )
        elif not direct and slot not in d.slot_fill:
            out.append(
                LintProblem(
                    "slots",
                    f"no finger serves slot '{slot}'",
                    f"map a finger to it or add slot_fill: {{{slot}: <finger>}}",
                )
            )
        elif not direct and d.slot_fill[slot] not in names:
            out.append(
                LintProblem(
                    "slots", f"slot_fill maps '{slot}' to unknown finger '{d.slot_fill[slot]}'", f"use one of {names}"
                )
            )
    out += [
        LintProblem("slots", f"finger '{f.name}' has unknown slot '{f.slot}'", f"use one of {list(FINGER_SLOTS)}")
        for f in d.fingers
        if f.slot not in FINGER_SLOTS
    ]
    for f in d.fingers:
        missing = [j for j in f.joints if j not in d.joint_names]
        if missing:
            out.append(
                LintProblem(
                    "slots",
                    f"finger '{f.name}' names joints {missing} that the hand does not have",
                    "fix the finger's joints list",
                )
            )
    if not out:  # every slot resolves: the rule Stage 1 refuses a hand by, said here before any run
        from ges_core.synthesis.retarget.wrist import check_handedness_fingers

        try:
            check_handedness_fingers(d)
        except AssetError as exc:  # a note: the model itself is sound (it loads and simulates), Stage 1 cannot use it
            fix = "map the middle and little slots to two different fingers to synthesize grasps with it"
            out.append(LintProblem("slots", str(exc), fix, note=True))
    return out


def check_tip_links(d: HandDescription, tree: UrdfTree) -> list[LintProblem]:
    """Fingertip and keypoint links exist; the tip is distal: below its finger's joints, nothing movable below it."""
    out = []
    for f in d.fingers:
        for link in (f.tip_link, *f.keypoint_links):
            if link not in tree.links:
                out.append(
                    LintProblem(
                        "tip-links", f"finger '{f.name}': link '{link}' is not in the URDF", "name an existing link"
                    )
                )
        if f.tip_link not in tree.links:
            continue
        below = tree.movable_joints_below(f.tip_link)
        if below:
            out.append(
                LintProblem(
                    "tip-links",
                    f"finger '{f.name}': tip link '{f.tip_link}' is not distal (joints {below} move below it)",
                    "use the finger's last link as tip_link",
                )
            )
        chain = set(tree.ancestors(f.tip_link)) | {f.tip_link}
        off_chain = [j for j in f.joints if tree.joint_child.get(j) not in chain]
        if off_chain:
            out.append(
                LintProblem(
                    "tip-links",
                    f"finger '{f.name}': joints {off_chain} do not move its tip '{f.tip_link}'",
                    "list the joints between palm and this tip",
                )
            )
        out += [
            LintProblem(
                "tip-links",
                f"finger '{f.name}': keypoint '{k}' is not on the chain to its tip",
                "use links between palm and tip",
            )
            for k in f.keypoint_links
            if k in tree.links and k not in chain
        ]
    return out


def check_collision_geometry(d: HandDescription, tree: UrdfTree) -> list[LintProblem]:
    """Every link a finger joint moves carries collision geometry (zero-length knuckle links excepted)."""
    out = []
    for f in d.fingers:
        for joint in f.joints:
            child = tree.joint_child.get(joint)
            if child is not None and child not in tree.has_collision and not tree.is_zero_length(child):
                out.append(
                    LintProblem(
                        "collision",
                        f"finger '{f.name}': link '{child}' has no collision geometry",
                        "add a <collision> (box, capsule or convex mesh) to it",
                    )
                )
    return out


def check_inertia(d: HandDescription, tree: UrdfTree) -> list[LintProblem]:
    """Masses positive and plausible; inertia tensors symmetric positive definite and physically valid."""
    out = []
    for link in sorted(tree.has_collision):
        mass = tree.mass.get(link, 0.0)
        if mass < MIN_LINK_MASS:
            out.append(
                LintProblem("inertia", f"link '{link}' has mass {mass:g} kg", f"give it at least {MIN_LINK_MASS} kg")
            )
        inertia = tree.inertia.get(link)
        if inertia is not None and not _valid_inertia(inertia):
            out.append(
                LintProblem(
                    "inertia",
                    f"link '{link}' has an invalid inertia tensor (eigenvalues "
                    f"{np.round(np.linalg.eigvalsh(inertia), 9).tolist()})",
                    "use positive principal moments that satisfy the triangle inequality",
                )
            )
    total = sum(tree.mass.values())
    if not 0 < total <= MAX_HAND_MASS:
        out.append(
            LintProblem(
                "inertia", f"total mass {total:g} kg is implausible for a hand", "check the units of <mass> (kg)"
            )
        )
    return out


def _valid_inertia(inertia: np.ndarray) -> bool:
    eig = np.linalg.eigvalsh(inertia)
    if eig.min() <= 0:
        return False
    a, b, c = eig
    return a + b >= c * (1 - 1e-6)
