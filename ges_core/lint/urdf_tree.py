"""A parsed URDF as a tree: parents, children, links with collision, inertias."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ges_core.urdf import inertia_tensor, parse_urdf

__all__ = ["UrdfTree"]


@dataclass
class UrdfTree:
    """Links and joints of a URDF, indexed for lint checks."""

    links: set[str] = field(default_factory=set)
    parent_joint: dict[str, str] = field(default_factory=dict)
    """child link -> joint name"""
    joint_parent: dict[str, str] = field(default_factory=dict)
    """joint -> parent link"""
    joint_child: dict[str, str] = field(default_factory=dict)
    joint_type: dict[str, str] = field(default_factory=dict)
    joint_offset: dict[str, float] = field(default_factory=dict)
    """joint -> length of its origin translation, metres"""
    joint_limit: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    has_collision: set[str] = field(default_factory=set)
    mass: dict[str, float] = field(default_factory=dict)
    inertia: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def from_text(cls, text: str) -> UrdfTree:
        """Parse URDF text."""
        tree = cls()
        root = parse_urdf(text)
        for link in root.findall("link"):
            tree._add_link(link)
        for joint in root.findall("joint"):
            tree._add_joint(joint)
        return tree

    def _add_link(self, link) -> None:
        name = link.get("name")
        self.links.add(name)
        if link.find("collision") is not None:
            self.has_collision.add(name)
        inertial = link.find("inertial")
        if inertial is None:
            return
        mass = inertial.find("mass")
        self.mass[name] = float(mass.get("value", 0)) if mass is not None else 0.0
        i = inertial.find("inertia")
        if i is not None:
            self.inertia[name] = inertia_tensor(i)

    def _add_joint(self, joint) -> None:
        name, kind = joint.get("name"), joint.get("type")
        parent, child = joint.find("parent").get("link"), joint.find("child").get("link")
        self.joint_type[name], self.joint_parent[name], self.joint_child[name] = kind, parent, child
        self.parent_joint[child] = name
        origin = joint.find("origin")
        xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()] if origin is not None else [0.0]
        self.joint_offset[name] = float(np.linalg.norm(xyz))
        limit = joint.find("limit")
        ok = kind not in ("continuous", "floating", "planar") and limit is not None
        ok = ok and limit.get("lower") is not None and limit.get("upper") is not None
        self.joint_limit[name] = (float(limit.get("lower")), float(limit.get("upper"))) if ok else None

    def is_zero_length(self, link: str) -> bool:
        """True for a link whose child joints all sit at its origin (a knuckle between coincident axes)."""
        children = [j for j, parent in self.joint_parent.items() if parent == link]
        return bool(children) and all(self.joint_offset[j] < 1e-9 for j in children)

    def ancestors(self, link: str) -> list[str]:
        """Links from ``link``'s parent up to the root."""
        out = []
        while link in self.parent_joint:
            link = self.joint_parent[self.parent_joint[link]]
            out.append(link)
        return out

    def movable_joints_below(self, link: str) -> list[str]:
        """Movable joints anywhere in the subtree under ``link``."""
        found, stack = [], [link]
        while stack:
            current = stack.pop()
            for joint, parent in self.joint_parent.items():
                if parent == current:
                    stack.append(self.joint_child[joint])
                    if self.joint_type[joint] != "fixed":
                        found.append(joint)
        return found
