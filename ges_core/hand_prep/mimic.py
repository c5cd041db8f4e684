"""URDF ``<mimic>`` tags as :class:`~ges_core.hand.JointCoupling` s, and URDF text without them.

A ``<mimic joint="L" multiplier="m" offset="o"/>`` inside joint ``F`` means ``q_F = m * q_L + o``
(URDF defaults: m = 1, o = 0). GES-UniGrasp keeps every such joint as an ordinary joint of the
hand's joint vector and sets it from its leader with :meth:`HandDescription.apply_couplings`
wherever targets are made; the engines then drive it with PD like any other joint. The tags
themselves are removed from what an engine loads: SAPIEN 3.0.3's URDF loader turns them into
fixed tendons, which fight the follower's own PD drive and explode (platform notes), and PyBullet
and pytorch-kinematics ignore them anyway.

Chains (``C`` mimics ``B`` which mimics ``A``, as in the Inspire hand's thumb) are resolved to the
first leader: ``q_C = m_C (m_B q_A + o_B) + o_C``, so no coupling's leader is itself a follower.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from ges_core.errors import AssetError
from ges_core.hand import HandDescription, JointCoupling
from ges_core.urdf import parse_urdf

__all__ = ["add_mimic_couplings", "mimic_couplings", "mimic_tags", "strip_mimic"]


def mimic_tags(urdf_text: str) -> dict[str, tuple[str, float, float]]:
    """Follower joint -> (leader, multiplier, offset) as written in the URDF (chains not resolved)."""
    out: dict[str, tuple[str, float, float]] = {}
    movable = set()
    for joint in parse_urdf(urdf_text).findall("joint"):
        if joint.get("type") not in ("fixed", None):
            movable.add(joint.get("name"))
        tag = joint.find("mimic")
        if tag is None:
            continue
        try:
            out[joint.get("name")] = (tag.get("joint"), float(tag.get("multiplier", 1)), float(tag.get("offset", 0)))
        except ValueError as exc:
            raise AssetError(f"URDF joint '{joint.get('name')}': <mimic> has a non-numeric value ({exc})") from None
    bad = {f: lead for f, (lead, _, _) in out.items() if lead not in movable}
    if bad:
        raise AssetError(
            "URDF <mimic> tags name leaders that are not movable joints of the file: "
            + ", ".join(f"{f} -> '{lead}'" for f, lead in bad.items())
            + "; fix the joint= attribute"
        )
    return out


def mimic_couplings(urdf_text: str) -> tuple[JointCoupling, ...]:
    """One coupling per ``<mimic>`` tag, chains resolved to the first leader, in URDF order."""
    tags = mimic_tags(urdf_text)
    out = []
    for follower in tags:
        leader, ratio, offset = _resolve(follower, tags)
        out.append(JointCoupling(follower=follower, leader=leader, ratio=ratio, offset=offset))
    return tuple(out)


def _resolve(follower: str, tags: dict[str, tuple[str, float, float]]) -> tuple[str, float, float]:
    """(first leader, multiplier, offset) of ``follower`` through a chain of mimic tags."""
    leader, ratio, offset = tags[follower]
    seen = [follower]
    while leader in tags:
        if leader in seen:
            raise AssetError(f"URDF <mimic> tags form a cycle: {' -> '.join([*seen, leader])}; break it")
        seen.append(leader)
        up, m, o = tags[leader]
        leader, ratio, offset = up, ratio * m, ratio * o + offset
    return leader, ratio, offset


def strip_mimic(urdf_text: str) -> str:
    """The URDF without ``<mimic>`` tags; the same string when it has none."""
    if "<mimic" not in urdf_text:
        return urdf_text
    root = parse_urdf(urdf_text)
    for joint in root.findall("joint"):
        for tag in joint.findall("mimic"):
            joint.remove(tag)
    return ET.tostring(root, encoding="unicode")


def add_mimic_couplings(description: HandDescription, urdf_text: str) -> HandDescription:
    """``description`` plus a coupling for each mimic follower it does not already couple.

    A coupling the description declares for the same follower wins (the hand's YAML may correct a
    URDF). Followers stay in ``joint_names``: they are real joints of the engines' models.
    """
    from dataclasses import replace

    declared = {c.follower for c in description.couplings}
    extra = tuple(c for c in mimic_couplings(urdf_text) if c.follower not in declared)
    if not extra:
        return description
    unknown = [c.follower for c in extra if c.follower not in description.joint_names]
    if unknown:
        raise AssetError(f"hand '{description.name}': mimic joints {unknown} are not in joint_names; list them")
    return replace(description, couplings=description.couplings + extra)
