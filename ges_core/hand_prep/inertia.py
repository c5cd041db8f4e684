"""Find link inertias that no body of the link's mass and size can have (``ges hand lint`` reports them).

A body of mass ``m`` whose every point lies within ``R`` of its centre of mass has every moment of inertia
about that centre at most ``m R^2`` (``I_k = sum m_i d_ik^2 <= sum m_i |d_i|^2 <= m R^2``). mani-skill's
Ability hand URDF (``ability_hand_right.urdf``, PSYONIC's values) breaks this on every phalanx, 38-182x over
the bound (the tensors look computed with the mass in grams): ``thumb_L2`` has 5.5 g and a largest moment of
1.8e-3 kg m^2, a radius of gyration of 0.57 m on a 7 cm link, whose bound is 9.9e-6 kg m^2.

Found, not replaced: replacing the Ability's tensors by their geometry's (a uniform convex hull of the link's
collision shapes) cured the grasps PyBullet dropped because a finger sank into the object (sphere/000,
sphere/001, wedge) but broke five others (box/001, capsule, cube, cylinder, random_urdfs/002): with ~1e-6 kg m^2
links PyBullet's solver delivers 0.2-1.3 N m of a drive whose force limit is 195-377 N m, and the object slides
out. Demo set: PyBullet 9/20 -> 7/20 (measured 2026-12-02, ``docs/hands/ability.md``). ``ges hand lint`` reports
what :func:`implausible_inertias` finds as a note (:func:`ges_core.lint.checks_assets.check_inertia_bound`).

Links within the bound, links at most :data:`PLACEHOLDER_MOMENT` (deliberate placeholders) and links whose
geometry cannot be read are not reported: no link of the built-in Allegro and Shadow hands is.
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError
from ges_core.urdf import inertia_tensor, parse_urdf, reach_bound

__all__ = ["ImplausibleInertia", "geometry_points", "implausible_inertias"]

BOUND_SLACK = 1e-6
"""Relative room above ``m R^2`` before a tensor counts as impossible: only rounding, the bound is exact."""
PLACEHOLDER_MOMENT = 1e-5
"""kg m^2: a tensor whose largest moment is at most this is left alone even above ``m R^2``. Tiny links carry
such regularised placeholders on purpose: the Shadow's ``thbase`` (10 g) and ``thhub`` (2 g) keep MuJoCo's
1e-5 (333x and 1667x their bound); near-zero knuckle inertias flung grasped boxes in PyBullet
(``docs/hands/shadow.md``). The Ability's phalanges are 8-180x above 1e-5."""


@dataclass(frozen=True)
class ImplausibleInertia:
    """One link whose file inertia exceeds what its mass and size allow."""

    link: str
    mass: float
    """kg (the file's)."""
    largest: float
    """The file's largest principal moment, kg m^2."""
    bound: float
    """``m R^2``, kg m^2."""


def implausible_inertias(text: str, base_dir: Path) -> list[ImplausibleInertia]:
    """Every link of the URDF ``text`` whose largest principal moment exceeds ``m R^2``.

    base_dir: the folder relative mesh names start from (absolute names ignore it).
    """
    out = []
    for link in parse_urdf(text).findall("link"):
        inertial = link.find("inertial")
        if inertial is None or inertial.find("inertia") is None or link.find("collision") is None:
            continue
        mass = float(inertial.find("mass").get("value", "0")) if inertial.find("mass") is not None else 0.0
        if mass <= 0:
            continue
        origin = inertial.find("origin")
        com = np.array(origin.get("xyz", "0 0 0").split(), dtype=float) if origin is not None else np.zeros(3)
        tensor = inertia_tensor(inertial.find("inertia"))
        largest = float(np.linalg.eigvalsh(tensor).max())  # any frame: eigenvalues
        if largest <= PLACEHOLDER_MOMENT:
            continue
        points = geometry_points(link, base_dir, ("collision", "visual"))
        if points is None:
            continue
        bound = reach_bound(mass, points - com)
        if largest > bound * (1 + BOUND_SLACK):
            out.append(ImplausibleInertia(link.get("name"), mass, largest, bound))
    return out


def geometry_points(link: ET.Element, base_dir: Path, kinds: tuple[str, ...]) -> np.ndarray | None:
    """(P, 3) points spanning the hull of the link's ``kinds`` elements (``collision``, ``visual``), link frame, m.

    None when an element's geometry cannot be read (an unknown tag, a missing or unreadable mesh): the caller
    then keeps the file's inertia rather than judge it on part of the link.
    """
    from ges_core.hand_prep.geometry import link_shapes

    elements = [e for kind in kinds for e in link.findall(kind)]
    if not elements:
        return None
    probe = ET.Element("robot", name="probe")
    holder = ET.SubElement(probe, "link", name="probe")
    for e in elements:
        copy = ET.SubElement(holder, "collision")
        copy.extend(list(e))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # capsules left out, as before link_shapes read them (5 December 2026): with them the bound flags 9 of
            # the Shadow's links at 2-3x, which nobody has looked into yet
            shapes = link_shapes(ET.tostring(probe, encoding="unicode"), base_dir, capsules=False).get("probe", [])
    except (AssetError, OSError, ValueError):
        return None
    if len(shapes) != len(elements):
        return None
    return np.concatenate([np.asarray(s.mesh.vertices, dtype=np.float64) for s in shapes])
