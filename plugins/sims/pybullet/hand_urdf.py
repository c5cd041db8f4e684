"""Prepare a hand's URDF for PyBullet: a world root link, valid inertias, a cached file.

Two measured PyBullet 3.2.7 behaviours drive this module:

* A link without ``<inertial>`` gets **1 kg** and unit inertia (the Allegro's virtual ``palm``
  and ``wrist`` links: +2 kg on a 1 kg hand). SAPIEN gives such links a negligible mass.
* With ``URDF_USE_INERTIA_FROM_FILE`` an inertia tensor whose principal moments break the
  triangle inequality (``I1 + I2 >= I3``, true of any real body) is replaced by **zero**
  ("bad inertia tensor": 12 Allegro links); without the flag PyBullet ignores the file and
  uses the collision shapes' bounding boxes (link_1.0: 2e-5 instead of 7e-5..1e-4 kg m^2).

So every inertia is rewritten in principal axes (as SAPIEN's loader does: ``eigh`` of the
tensor, the rotation folded into the inertial origin), the largest moment is clamped just below
the sum of the two others, massless links get a tiny inertial, and the file is loaded with
``URDF_USE_INERTIA_FROM_FILE``.

The hand's base link is always made a PyBullet *link* below a massless world link
(:func:`ges_core.urdf.add_floating_base` for a floating hand, one fixed joint otherwise),
because PyBullet reports a *base* at its centre of mass, not at its URDF frame.
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ges_core.hand_prep.engine_files import engine_file_memo
from ges_core.paths import cached_text_file
from ges_core.urdf import add_floating_base, inertia_tensor, parse_urdf, root_link

__all__ = ["FIXED_WRIST_JOINT", "WORLD_LINK", "add_fixed_base", "pybullet_hand_urdf", "sanitize_inertias"]

WORLD_LINK = "ges_world"
"""Name of the massless root link the hand hangs from (PyBullet's base of the hand body)."""
FIXED_WRIST_JOINT = "ges_wrist_fixed"
"""Fixed joint between :data:`WORLD_LINK` and the hand's base link when the hand is not floating."""

_TINY_MASS = 1e-3
"""kg given to links without an inertial (PyBullet's default would be 1 kg); a 1 g bead."""
_TINY_INERTIA = 1e-8
"""kg m^2, principal moments of such a link (a 1 g sphere of about 5 mm radius)."""
_MIN_MOMENT = 1e-10
"""kg m^2 floor of a principal moment; zero moments make Featherstone's inverse singular."""
_TRIANGLE_SLACK = 1e-3
"""Relative room kept below the triangle-inequality bound: clamping to the exact sum still
tripped PyBullet's check after the decimal round trip (3 Allegro links)."""


@engine_file_memo  # made once per process (every backend loads the hand again)
def pybullet_hand_urdf(text: str, name: str, *, floating: bool, base_dir: Path | None = None) -> Path:
    """Write the PyBullet-ready URDF of a hand to the cache (keyed by its text) and return the path; made once
    per process for the same arguments (:func:`ges_core.hand_prep.engine_files.engine_file_memo`).

    base_dir: the folder of the hand's URDF file. With it, :func:`ges_core.hand_prep.engine_urdf.engine_urdf`
    first makes mesh paths absolute, converts meshes PyBullet cannot load (``.glb``: "invalid mesh filename
    extension", the shape is dropped) to OBJ, drops ``<mimic>`` tags and uses ``ges hand prepare``'s convex parts.
    """
    if base_dir is not None:
        from ges_core.hand_prep.engine_urdf import engine_urdf  # trimesh and CoACD: imported when first needed

        text = engine_urdf(text, base_dir)
    text = add_floating_base(text, world_link=WORLD_LINK) if floating else add_fixed_base(text)
    stem = f"{name}_{'floating' if floating else 'fixed'}"
    return cached_text_file(sanitize_inertias(text), "pybullet", "hands", stem=stem)


def add_fixed_base(text: str) -> str:
    """Hang the base link from a massless :data:`WORLD_LINK` by :data:`FIXED_WRIST_JOINT` (identity origin)."""
    root = parse_urdf(text)
    base = root_link(text)
    world = ET.Element("link", name=WORLD_LINK)
    inertial = ET.SubElement(world, "inertial")  # massless, as add_floating_base's world link
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value="0")
    ET.SubElement(inertial, "inertia", ixx="0", iyy="0", izz="0", ixy="0", ixz="0", iyz="0")
    root.insert(0, world)
    joint = ET.SubElement(root, "joint", name=FIXED_WRIST_JOINT, type="fixed")
    ET.SubElement(joint, "parent", link=WORLD_LINK)
    ET.SubElement(joint, "child", link=base)
    ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    return ET.tostring(root, encoding="unicode")


def sanitize_inertias(text: str) -> str:
    """Every link's inertial in principal axes with physically valid moments (see module docs).

    The world link keeps its (absent) inertial: it is the fixed PyBullet base, whose mass is ignored.
    """
    root = parse_urdf(text)
    for link in root.findall("link"):
        if link.get("name") == WORLD_LINK:
            continue
        inertial = link.find("inertial")
        if inertial is None or _mass(inertial) <= 0:
            if inertial is not None:
                link.remove(inertial)
            _write_inertial(link, _TINY_MASS, np.zeros(3), np.eye(3), np.full(3, _TINY_INERTIA))
            continue
        origin_xyz, origin_rot = _origin(inertial)
        moments, axes = principal_moments(inertia_tensor(inertial.find("inertia")))
        link.remove(inertial)
        _write_inertial(link, _mass(inertial), origin_xyz, origin_rot @ axes, moments)
    return ET.tostring(root, encoding="unicode")


def principal_moments(tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) valid principal moments and (3, 3) right-handed axes (columns) of an inertia tensor.

    Moments are floored at a tiny positive value and the largest is clamped just below the sum of
    the other two (the triangle inequality PyBullet checks).
    """
    if np.count_nonzero(tensor - np.diag(np.diag(tensor))) == 0:
        moments, axes = np.diag(tensor).copy(), np.eye(3)  # already principal: keep the file's frame
    else:
        moments, axes = np.linalg.eigh(tensor)
        if np.linalg.det(axes) < 0:
            axes[:, 2] = -axes[:, 2]
    moments = np.maximum(moments, _MIN_MOMENT)
    for i in range(3):
        others = moments.sum() - moments[i]
        moments[i] = min(moments[i], others * (1 - _TRIANGLE_SLACK))
    return moments, axes


def _mass(inertial: ET.Element) -> float:
    mass = inertial.find("mass")
    return float(mass.get("value", "0")) if mass is not None else 0.0


def _origin(inertial: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    node = inertial.find("origin")
    xyz = np.array(node.get("xyz", "0 0 0").split(), dtype=float) if node is not None else np.zeros(3)
    rpy = np.array(node.get("rpy", "0 0 0").split(), dtype=float) if node is not None else np.zeros(3)
    return xyz, Rotation.from_euler("xyz", rpy).as_matrix()  # URDF rpy = fixed-axis x, y, z


def _write_inertial(link: ET.Element, mass: float, xyz: np.ndarray, rot: np.ndarray, moments: np.ndarray) -> None:
    with warnings.catch_warnings():  # at +-90 deg pitch scipy warns, and still returns angles that give ``rot``
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_matrix(rot).as_euler("xyz")
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz=_fmt(xyz), rpy=_fmt(rpy))
    ET.SubElement(inertial, "mass", value=repr(float(mass)))
    ixx, iyy, izz = (repr(float(m)) for m in moments)
    ET.SubElement(inertial, "inertia", ixx=ixx, iyy=iyy, izz=izz, ixy="0", ixz="0", iyz="0")


def _fmt(values: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in values)
