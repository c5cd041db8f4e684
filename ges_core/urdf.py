"""URDF text utilities shared by hands and simulators (parsers take text and return text).

The floating wrist is six virtual joints above the hand's base link, in this order:
prismatic x, y, z (world axes), then revolute about x, y, z, so the base orientation is
``R = Rx(rx) @ Ry(ry) @ Rz(rz)``. Both simulators drive them with PD like any other joint,
which makes a floating hand behave the same in every engine.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError

__all__ = [
    "WRIST_JOINTS",
    "add_floating_base",
    "inertia_tensor",
    "reach_bound",
    "absolutize_mesh_paths",
    "strip_render_data",
    "root_link",
    "neighbour_link_pairs",
    "origin_matrix",
    "solid_links",
]

WRIST_JOINTS: tuple[str, ...] = (
    "ges_wrist_x",
    "ges_wrist_y",
    "ges_wrist_z",
    "ges_wrist_rx",
    "ges_wrist_ry",
    "ges_wrist_rz",
)
"""Names of the six virtual floating-wrist joints, outermost first."""

_WRIST_AXES = ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 0), (0, 1, 0), (0, 0, 1))
_WRIST_LIMIT_M = 5.0
"""Wrist translation range, metres either side of the world origin."""


def inertia_tensor(node: ET.Element | None) -> np.ndarray:
    """(3, 3) symmetric tensor of an ``<inertia ixx=.. ixy=.. .. izz=..>`` element (absent attributes 0; a missing
    element, None, gives zeros), kg m^2, in its ``<inertial>``'s frame."""
    get = (lambda k: float(node.get(k, "0"))) if node is not None else (lambda k: 0.0)
    return np.array(
        [
            [get("ixx"), get("ixy"), get("ixz")],
            [get("ixy"), get("iyy"), get("iyz")],
            [get("ixz"), get("iyz"), get("izz")],
        ]
    )


def reach_bound(mass: float, offsets: np.ndarray) -> float:
    """kg m^2: the largest principal moment of inertia a body of ``mass`` can have when its points lie at
    ``offsets`` (N, 3) from its centre of mass, ``mass R^2`` with ``R`` the farthest (inf for N = 0: no bound).

    ``I_k = sum m_i d_ik^2 <= sum m_i |d_i|^2 <= m R^2``: a file tensor above it belongs to no such body.
    """
    if len(offsets) == 0:
        return float("inf")
    return mass * float(np.max(np.sum(np.asarray(offsets, dtype=np.float64) ** 2, axis=1)))


def solid_links(root: ET.Element) -> list[str]:
    """Names of the links of a parsed URDF (:func:`parse_urdf`) that have collision geometry, in file order."""
    return [link.get("name") for link in root.iter("link") if link.find("collision") is not None]


def parse_urdf(text: str) -> ET.Element:
    """Parse URDF text; malformed XML or a non-robot root gives an AssetError."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise AssetError(f"URDF is not valid XML: {exc}") from exc
    if root.tag != "robot":
        raise AssetError(f"URDF root element is <{root.tag}>, expected <robot>")
    return root


def origin_matrix(element: ET.Element | None) -> np.ndarray:
    """(4, 4) parent <- element frame of an element's ``<origin>`` (a joint, collision, visual; None: identity).

    URDF ``rpy`` is roll, pitch, yaw about the fixed x, y, z axes: ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
    """
    from scipy.spatial.transform import Rotation

    origin = element.find("origin") if element is not None else None
    xyz = [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
    rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    out[:3, 3] = xyz
    return out


def root_link(text: str) -> str:
    """Name of the one link that is no joint's child."""
    root = parse_urdf(text)
    links = [link.get("name") for link in root.findall("link")]
    children = {j.find("child").get("link") for j in root.findall("joint") if j.find("child") is not None}
    roots = [name for name in links if name not in children]
    if len(roots) != 1:
        raise AssetError(f"URDF must have exactly one root link, found {roots}")
    return roots[0]


def strip_render_data(text: str, *, keep_visuals: bool = False) -> str:
    """Remove ``<material>`` tags (SAPIEN's loader needs a render device for them) and optionally visuals."""
    root = parse_urdf(text)
    for parent in root.iter():
        for child in list(parent):
            if child.tag == "material" or (child.tag == "visual" and not keep_visuals):
                parent.remove(child)
    return ET.tostring(root, encoding="unicode")


def absolutize_mesh_paths(text: str, base_dir: Path) -> str:
    """Rewrite relative (and ``package://``) mesh filenames against ``base_dir``."""
    root = parse_urdf(text)
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if name.startswith("package://"):
            name = name.split("://", 1)[1].split("/", 1)[-1]
        path = Path(name)
        if not path.is_absolute():
            path = (base_dir / path).resolve()
        mesh.set("filename", str(path))
    return ET.tostring(root, encoding="unicode")


def add_floating_base(text: str, *, world_link: str = "ges_world") -> str:
    """Put six PD-drivable virtual joints (:data:`WRIST_JOINTS`) between a world link and the base."""
    root = parse_urdf(text)
    base = root_link(text)
    names = [world_link] + [f"{j}_link" for j in WRIST_JOINTS[:-1]] + [base]
    new_links = [world_link] + [f"{j}_link" for j in WRIST_JOINTS[:-1]]
    for i, name in enumerate(new_links):
        link = ET.Element("link", name=name)
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
        ET.SubElement(inertial, "mass", value="0.01" if i else "0")  # tiny virtual masses keep solvers stable
        ET.SubElement(inertial, "inertia", ixx="1e-5", iyy="1e-5", izz="1e-5", ixy="0", ixz="0", iyz="0")
        root.insert(i, link)
    for i, joint_name in enumerate(WRIST_JOINTS):
        kind = "prismatic" if i < 3 else "revolute"
        joint = ET.Element("joint", name=joint_name, type=kind)
        ET.SubElement(joint, "parent", link=names[i])
        ET.SubElement(joint, "child", link=names[i + 1])
        ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz=" ".join(str(a) for a in _WRIST_AXES[i]))
        lim = _WRIST_LIMIT_M if i < 3 else 2 * np.pi
        ET.SubElement(joint, "limit", lower=str(-lim), upper=str(lim), effort="1e6", velocity="100")
        root.append(joint)
    return ET.tostring(root, encoding="unicode")


def neighbour_link_pairs(text: str) -> set[frozenset[str]]:
    """Link pairs that must not collide with each other: parent-child, and pairs joined through zero-length links.

    A zero-length link is one whose child joints all sit at its origin (a knuckle between two
    coincident joint axes, e.g. the Shadow hand's ``ffknuckle`` or ``thbase``). Its parent and its
    children touch by construction, as do the links on either side of a chain of them; MuJoCo's
    Shadow model avoids this with an explicit contact-pair list, we derive the exclusions from
    the kinematic tree so that every simulator applies the same rule.
    """
    root = parse_urdf(text)
    parent_of: dict[str, str] = {}
    offsets: dict[str, list[float]] = {}
    for joint in root.findall("joint"):
        parent, child = joint.find("parent").get("link"), joint.find("child").get("link")
        parent_of[child] = parent
        origin = joint.find("origin")
        xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()] if origin is not None else [0.0]
        offsets.setdefault(parent, []).append(float(np.linalg.norm(xyz)))

    def zero_length(link: str) -> bool:
        return bool(offsets.get(link)) and max(offsets[link]) < 1e-9

    pairs: set[frozenset[str]] = set()
    for child, parent in parent_of.items():
        pairs.add(frozenset((child, parent)))
        while zero_length(parent) and parent in parent_of:
            parent = parent_of[parent]
            pairs.add(frozenset((child, parent)))
    return pairs
