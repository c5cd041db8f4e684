"""A hand's link geometry for the viewer, and where forward kinematics puts it for a stored grasp.

Each link is drawn with its ``<visual>`` meshes where the URDF has them (the Allegro's), otherwise with its
``<collision>`` shapes (the converted Shadow has capsules, boxes and one forearm mesh, no visuals): a box, sphere,
cylinder, capsule (URDF and trimesh both put its axis along z, ``length`` between the cap centres) or a mesh file
(``scale`` applied). Link poses come from the hand's kinematics (:func:`ges_core.kinematics.shared_kinematics`,
pytorch-kinematics) at the record's joint values, composed with the record's wrist pose (the base link's pose in
the object frame).

:func:`ges_core.hand_prep.geometry.link_shapes` parses collisions only and leaves capsules out (it measures hull
overlaps for the linter), so the viewer reads its own shapes here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ges_core.errors import AssetError
from ges_core.transforms import pose_to_matrix
from ges_core.urdf import origin_matrix, parse_urdf

if TYPE_CHECKING:
    from ges_core.hand import HandModel

__all__ = ["HandView", "LinkMesh", "link_meshes"]

_SPHERE_SUBDIVISIONS = 2
"""Icosphere level of a sphere shape: 320 faces, smooth enough at a fingertip's size (1-2 cm)."""
_ROUND_SECTIONS = 16
"""Segments around a cylinder or capsule: 16 keeps a 1.5 cm capsule round on screen at 700 faces."""


@dataclass(frozen=True)
class LinkMesh:
    """One drawn shape of a link.

    vertices: (V, 3) float64, link frame, metres (the element's ``<origin>`` and the mesh ``scale`` applied).
    faces: (F, 3) int32 vertex indices.
    source: ``visual`` or ``collision``: which URDF element it came from.
    """

    link: str
    vertices: np.ndarray
    faces: np.ndarray
    source: str


def link_meshes(urdf_text: str, base_dir: Path) -> tuple[LinkMesh, ...]:
    """Every link's drawn shapes, in URDF order: its visuals if it has any, else its collisions.

    base_dir: the folder relative mesh paths are read from (the URDF's). AssetError for a missing mesh file.
    """
    out: list[LinkMesh] = []
    for link in parse_urdf(urdf_text).findall("link"):
        name = link.get("name")
        source = "visual" if link.find("visual/geometry") is not None else "collision"
        for element in link.findall(source):
            mesh = _element_mesh(name, element, base_dir)
            if mesh is not None:
                out.append(LinkMesh(name, mesh[0], mesh[1], source))
    return tuple(out)


def _element_mesh(link: str, element, base_dir: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices, faces) of a ``<visual>`` or ``<collision>`` in the link frame; None without a geometry."""
    geometry = element.find("geometry")
    if geometry is None or not len(geometry):
        return None
    mesh = _shape_mesh(link, geometry[0], base_dir)
    mesh.apply_transform(origin_matrix(element))
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)


def _shape_mesh(link: str, shape, base_dir: Path):
    """A trimesh of one URDF geometry element in its own frame."""
    import trimesh

    kind = shape.tag
    if kind == "mesh":
        return _mesh_file(link, shape, base_dir)
    if kind == "box":
        return trimesh.creation.box(extents=[float(v) for v in shape.get("size").split()])
    if kind == "sphere":
        return trimesh.creation.icosphere(subdivisions=_SPHERE_SUBDIVISIONS, radius=float(shape.get("radius")))
    radius, length = float(shape.get("radius", 0)), float(shape.get("length", 0))
    if kind == "cylinder":
        return trimesh.creation.cylinder(radius=radius, height=length, sections=_ROUND_SECTIONS)
    if kind == "capsule":
        return trimesh.creation.capsule(height=length, radius=radius, count=[_ROUND_SECTIONS, _ROUND_SECTIONS])
    raise AssetError(f"link '{link}': unknown URDF geometry <{kind}>; the viewer draws box, sphere, cylinder, "
                     "capsule and mesh")  # fmt: skip


def _mesh_file(link: str, shape, base_dir: Path):
    import trimesh

    from ges_core.hand_prep.meshes import resolve_mesh_path

    path = resolve_mesh_path(shape.get("filename", ""), base_dir)
    if not path.is_file():
        raise AssetError(
            f"link '{link}': mesh {path} does not exist; fix the URDF's filename or install the package that holds it"
        )
    mesh = trimesh.load(str(path), force="mesh")
    mesh.apply_scale([float(v) for v in shape.get("scale", "1 1 1").split()])
    return mesh


class HandView:
    """A hand's drawn shapes and kinematics: where each shape goes for a wrist pose and joint values.

    Built once per hand (parsing the meshes and the kinematic chain takes ~0.1-0.7 s) and reused for every record.
    """

    def __init__(self, hand: HandModel) -> None:
        from ges_core.kinematics import shared_kinematics

        self.name = hand.name
        self.joint_names: tuple[str, ...] = tuple(hand.description.joint_names)
        self.meshes = link_meshes(hand.urdf_text(), hand.urdf_path().parent)
        self.kinematics = shared_kinematics(hand)
        self.links: tuple[str, ...] = tuple(dict.fromkeys(m.link for m in self.meshes))
        """Links that have a drawn shape, in URDF order."""

    def link_poses(self, wrist_pose: np.ndarray, joints: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Link -> (4, 4) pose in the object frame, for every link in :attr:`links`.

        wrist_pose: (7,) base-link pose in the object frame, position m, quaternion wxyz. joints: joint name ->
        value (rad, m for prismatic); a joint not named stays 0, a name the hand lacks is an AssetError (the
        record was made with another version of the hand).
        """
        import torch

        unknown = sorted(set(joints) - set(self.joint_names))
        if unknown:
            raise AssetError(
                f"hand '{self.name}' has no joint(s) {', '.join(unknown)}: the record was made with another version "
                "of this hand; view it with the hand it was made with"
            )
        q = torch.tensor([[float(joints.get(n, 0.0)) for n in self.joint_names]], dtype=torch.float64)
        local = self.kinematics.link_poses(q, self.links)[0].numpy()  # (L, 4, 4), base frame
        base = pose_to_matrix(np.asarray(wrist_pose, dtype=np.float64))
        return {link: base @ local[i] for i, link in enumerate(self.links)}
