"""Lint checks of what a URDF from elsewhere brings: tip frames without geometry, mimic tags, mesh formats, link
inertias no body of the link's mass and size can have."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ges_core.hand import HandModel
from ges_core.hand_prep.meshes import (
    converted_mesh_if_cached,
    engines_that_cannot_load,
    format_name,
    resolve_mesh_path,
)
from ges_core.hand_prep.mimic import mimic_couplings
from ges_core.lint.problems import LintProblem
from ges_core.lint.urdf_tree import UrdfTree
from ges_core.urdf import origin_matrix, parse_urdf

__all__ = ["check_inertia_bound", "check_mesh_formats", "check_mimic", "check_tip_collision"]

COUPLING_TOL = 1e-6
"""Ratio/offset difference (rad) below which a declared coupling equals the URDF's mimic tag."""
OPEN_POSE_TOL = 1e-3
"""rad: an open pose whose follower is further than this from its coupled value is inconsistent."""


def _fmt(values) -> str:
    return "[" + ", ".join(str(round(float(v), 5) + 0.0) for v in values) + "]"


# -- (a) fingertip links without collision geometry ---------------------------------------------
def check_tip_collision(hand: HandModel, tree: UrdfTree, ref: str) -> list[LintProblem]:
    """Every finger's tip link carries collision geometry (contact forces are read on it)."""
    out = []
    root = parse_urdf(hand.urdf_text())
    for f in hand.description.fingers:
        if f.tip_link not in tree.links or f.tip_link in tree.has_collision:
            continue
        out.append(
            LintProblem(
                "tip-collision",
                f"finger '{f.name}': tip link '{f.tip_link}' has no collision geometry, so nothing touches through "
                f"it: `ges sim check` reads 0 N on this finger and validation never sees its contact",
                _tip_fix(root, tree, f.tip_link, f.tip_offset, f.pad_normal),
            )
        )
    return out


def _tip_fix(root: ET.Element, tree: UrdfTree, tip: str, offset, pad) -> str:
    """Name the nearest solid ancestor reached through fixed joints, with the tip point and pad in its frame."""
    rot, pos, link = np.eye(3), np.asarray(offset, dtype=float), tip
    while link not in tree.has_collision and link in tree.parent_joint:
        joint = tree.parent_joint[link]
        if tree.joint_type[joint] != "fixed":
            break
        r, t = _joint_origin(root, joint)
        rot, pos, link = r @ rot, r @ pos + t, tree.joint_parent[joint]
    add = f"or add a <collision> (e.g. a sphere of the fingertip's radius) and an <inertial> to '{tip}'"
    if link not in tree.has_collision or link == tip:
        return add
    pad_text = f", pad_normal: {_fmt(rot @ np.asarray(pad))}" if pad is not None else ""
    return (
        f"use tip_link: {link} with tip_offset: {_fmt(pos)}{pad_text} (the point of '{tip}' in the frame of "
        f"'{link}') and end keypoint_links with '{link}'; {add}"
    )


def _joint_origin(root: ET.Element, joint: str) -> tuple[np.ndarray, np.ndarray]:
    m = origin_matrix(root.find(f"joint[@name='{joint}']"))
    return m[:3, :3], m[:3, 3]


# -- (b) mimic tags ---------------------------------------------------------------------------
def check_mimic(hand: HandModel, tree: UrdfTree, ref: str) -> list[LintProblem]:
    """Each ``<mimic>`` is a coupling of the description; the open pose obeys every coupling."""
    d = hand.description
    declared = {c.follower: c for c in d.couplings}
    out = []
    for c in mimic_couplings(hand.urdf_text()):
        formula = f"{c.follower} = {c.ratio:.6g} x {c.leader} {'+' if c.offset >= 0 else '-'} {abs(c.offset):.6g} rad"
        have = declared.get(c.follower)
        if have is None:
            yaml = f"{{follower: {c.follower}, leader: {c.leader}, ratio: {c.ratio:.8g}, offset: {c.offset:.8g}}}"
            out.append(
                LintProblem(
                    "mimic",
                    f"joint '{c.follower}' has a <mimic> tag ({formula}) that the hand's description does not couple",
                    f"add to couplings: {yaml} (FileHand adds it by itself)",
                )
            )
        elif (
            abs(have.ratio - c.ratio) > COUPLING_TOL
            or abs(have.offset - c.offset) > COUPLING_TOL
            or (have.leader != c.leader)
        ):
            out.append(_declared_differs(have, formula))
        else:
            out.append(_handled(formula))
    return out + _open_pose_couplings(hand)


def _handled(formula: str) -> LintProblem:
    return LintProblem(
        "mimic",
        f"<mimic> handled as the coupling {formula}: the follower stays a PD-driven joint whose target follows "
        "its leader in both simulators (SAPIEN's own mimic tendons, which explode under PD drives, are not built)",
        "none needed",
        note=True,
    )


def _declared_differs(have, formula: str) -> LintProblem:
    return LintProblem(
        "mimic",
        f"the URDF's <mimic> says {formula}, the description couples {have.follower} = {have.ratio:.6g} x "
        f"{have.leader} + {have.offset:.6g} rad; the description's coupling is used",
        "none needed if the description is right; otherwise correct its couplings entry",
        note=True,
    )


def _open_pose_couplings(hand: HandModel) -> list[LintProblem]:
    d = hand.description
    q0 = np.asarray(d.open_pose, dtype=float)
    coupled = d.apply_couplings(q0)
    return [
        LintProblem(
            "mimic",
            f"open_pose gives follower '{name}' {q0[i]:.4f} rad but its coupling makes it {coupled[i]:.4f} rad",
            f'set open_pose "{name}": {coupled[i]:.6g} in the hand\'s YAML',
        )
        for i, name in enumerate(d.joint_names)
        if abs(coupled[i] - q0[i]) > OPEN_POSE_TOL
    ]


# -- (c) mesh formats -------------------------------------------------------------------------
def check_mesh_formats(hand: HandModel, tree: UrdfTree, ref: str) -> list[LintProblem]:
    """Every mesh file exists and each engine can load it (or its converted copy is in the cache).

    ref: how the user names the hand on the command line (in the fix)."""
    base_dir = hand.urdf_path().parent
    users: dict[Path, list[str]] = {}
    for link in parse_urdf(hand.urdf_text()).findall("link"):
        for kind in ("visual", "collision"):
            for mesh in link.findall(f"{kind}/geometry/mesh"):
                path = resolve_mesh_path(mesh.get("filename", ""), base_dir)
                users.setdefault(path, []).append(f"{link.get('name')} ({kind})")
    return [p for path, who in users.items() if (p := _mesh_problem(ref, path, who)) is not None]


def _mesh_problem(ref: str, path: Path, users: list[str]) -> LintProblem | None:
    who = ", ".join(sorted(set(users)))
    if not path.is_file():
        return LintProblem("meshes", f"mesh {path} of {who} does not exist", "fix the filename in the URDF")
    engines = engines_that_cannot_load(path)
    if not engines:
        return None
    what = f"mesh {path.name} of {who} is {format_name(path)}, which {' and '.join(engines)} cannot load"
    converted = converted_mesh_if_cached(path)
    if converted is not None:
        return LintProblem("meshes", f"{what}; its OBJ copy {converted} is used", "none needed", note=True)
    return LintProblem(
        "meshes",
        what,
        f"run `ges hand prepare {ref}` (converts it to OBJ in the cache; both simulators load that), "
        "or export it as .obj/.stl",
    )


# -- (d) inertias above what the link's mass and size allow ---------------------------------------
def check_inertia_bound(hand: HandModel) -> list[LintProblem]:
    """One note naming every link whose largest principal moment exceeds ``m R^2`` (``R``: the farthest point of
    its geometry from its centre of mass), the most any body of that mass and size can have
    (:func:`ges_core.hand_prep.inertia.implausible_inertias`). A note, not a problem: the engines load the tensors
    as given, and replacing them by the geometry's made PyBullet hold fewer grasps on the one hand measured
    (mani-skill's Ability: docs/hands/ability.md)."""
    from ges_core.hand_prep.inertia import implausible_inertias

    found = implausible_inertias(hand.urdf_text(), hand.urdf_path().parent)
    if not found:
        return []
    ratios = [f.largest / f.bound for f in found]
    links = ", ".join(f"'{f.link}' ({r:.0f}x)" for f, r in zip(found, ratios, strict=True))
    what = (
        f"{len(found)} link(s) have a largest moment of inertia above m R^2, the most a body of the link's mass and "
        f"size can have: {links}"
    )
    fix = (
        "check the <inertia> values' units (tensors computed with the mass in grams are 1000x too large); the "
        "engines use them as given, and swapping in the geometry's tensors made PyBullet hold fewer grasps on the "
        "Ability hand (docs/hands/ability.md), so measure before changing them"
    )
    return [LintProblem("inertia", what, fix, note=True)]
