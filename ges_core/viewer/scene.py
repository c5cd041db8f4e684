"""What the viewer draws for one record, engine- and browser-free: meshes with poses and colours, and line segments.

Everything is in the record's **object frame** (z up, table plane z = 0, metres). The parts, each under its own
name (a viser scene path):

* ``/object``: the object's surface mesh (``ObjectAsset.mesh_path``), and ``/table``: a square under it;
* ``/contacts/<slot>``: a ball per finger slot in the slot's colour (:data:`ges_core.render.SLOT_COLORS`) and
  ``/normals``: a stick along each outward normal, as in the grasp pictures (:mod:`ges_core.render`);
* ``/grasp/<link>/<i>`` and ``/pregrasp/<link>/<i>``: the hand's link shapes (:mod:`.geometry`) placed by forward
  kinematics at the final grasp and at the pre-grasp.

:func:`build_scene` is pure: the viser adapter (:mod:`.app`) only sends what it returns.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from ges_core.config import ConfigModel
from ges_core.contact import FINGER_SLOTS
from ges_core.render.base import HAND_COLOR, OBJECT_COLOR, SLOT_COLORS, TABLE_COLOR, RenderConfig
from ges_core.transforms import matrix_to_quat

if TYPE_CHECKING:
    from ges_core.dataset.record import GraspRecord, HandPose
    from ges_core.viewer.geometry import HandView

__all__ = ["LineItem", "MeshItem", "Scene", "ViewerConfig", "build_scene"]

_PICTURE = RenderConfig()
"""The grasp pictures' sizes, so the viewer's markers match them."""


class ViewerConfig(ConfigModel):
    """How the viewer draws a record."""

    contact_radius: float = Field(_PICTURE.contact_radius, gt=0, description="radius of a contact ball, metres")
    normal_length: float = Field(_PICTURE.normal_length, gt=0, description="length of a normal stick, metres")
    hand_opacity: float = Field(
        _PICTURE.hand_opacity, ge=0, le=1, description="hand at grasp: 0 invisible .. 1 opaque (the pictures' value)"
    )
    pregrasp_opacity: float = Field(
        0.3, ge=0, le=1, description="hand at pre-grasp: fainter than the grasp so the two read apart"
    )
    table_margin: float = Field(0.05, ge=0, description="table square beyond the object's footprint, metres")
    camera_elevation_deg: float = Field(
        _PICTURE.elevation_deg, ge=-90, le=90, description="first camera's height above the table plane, degrees"
    )
    camera_turn_deg: float = Field(
        _PICTURE.away_from_base or 0.0,
        description="first camera: from the side opposite the hand's base, turned this many degrees (a 3/4 view; "
        "the grasp pictures' value: the Shadow's forearm otherwise hides the object)",
    )


PREGRASP_COLOR = (0.55, 0.75, 0.95)
"""RGB in [0, 1] of the hand at pre-grasp (a light blue beside the grasp's slate)."""


@dataclass(frozen=True)
class MeshItem:
    """A triangle mesh placed in the object frame.

    vertices: (V, 3) float64 in the item's own frame, metres; faces: (F, 3) int32. position: (3,) m and wxyz: (4,)
    unit quaternion of the item's frame in the object frame. color: RGB 0-255. geometry: a key naming the vertex
    data (same key, same vertices), so a viewer can move a drawn mesh instead of sending it again.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    color: tuple[int, int, int]
    position: np.ndarray
    wxyz: np.ndarray
    opacity: float = 1.0
    geometry: str = ""

    def world_vertices(self) -> np.ndarray:
        """(V, 3) vertices in the object frame, metres."""
        from ges_core.transforms import quat_to_matrix

        return self.vertices @ quat_to_matrix(self.wxyz).T + self.position


@dataclass(frozen=True)
class LineItem:
    """Line segments: points (N, 2, 3) object frame, metres; colors (N, 2, 3) RGB 0-255 per end."""

    name: str
    points: np.ndarray
    colors: np.ndarray


@dataclass(frozen=True)
class Scene:
    """One record's drawing; ``center`` (3,) and ``radius`` (m) frame a camera on the object and the fingers."""

    meshes: tuple[MeshItem, ...]
    lines: tuple[LineItem, ...]
    center: np.ndarray
    radius: float
    view_direction: np.ndarray
    """(3,) unit vector from ``center`` toward a good camera position (away from the hand's base, from above)."""
    notes: tuple[str, ...] = field(default=())
    """What could not be drawn and why (no object mesh, a hand that is not installed), one line each."""

    def group(self, prefix: str) -> tuple[MeshItem, ...]:
        """The meshes whose name starts with ``prefix`` (e.g. ``/grasp/``)."""
        return tuple(m for m in self.meshes if m.name.startswith(prefix))


def _rgb(color: tuple[float, float, float]) -> tuple[int, int, int]:
    return tuple(int(round(255 * c)) for c in color)


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def build_scene(
    record: GraspRecord,
    *,
    object_mesh: tuple[np.ndarray, np.ndarray] | None,
    hand: HandView | None,
    config: ViewerConfig | None = None,
    notes: tuple[str, ...] = (),
) -> Scene:
    """The drawing of ``record``: object, table, contacts and normals, hand at grasp and at pre-grasp.

    object_mesh: (vertices (V, 3) object frame m, faces (F, 3)) or None (not drawn). hand: the record's hand
    (:class:`~ges_core.viewer.geometry.HandView`) or None (no hand drawn). What the record lacks (no contacts, no
    grasp: a failed step) is left out. ``notes`` are kept in :attr:`Scene.notes`.
    """
    config = config or ViewerConfig()
    meshes: list[MeshItem] = []
    lines: list[LineItem] = []
    if object_mesh is not None:
        meshes += _object_items(record.object_id, object_mesh, config)
    if record.contacts is not None:
        meshes += _contact_items(record.contacts.positions, config)
        lines.append(_normal_lines(record.contacts.positions, record.contacts.normals, config))
    if hand is not None:
        meshes += _hand_items("/grasp", record.grasp, record, hand, HAND_COLOR, config.hand_opacity)
        meshes += _hand_items("/pregrasp", record.pregrasp, record, hand, PREGRASP_COLOR, config.pregrasp_opacity)
    center, radius = _frame(meshes, hand)
    view = _view_direction(center, record, config)
    return Scene(tuple(meshes), tuple(lines), center, radius, view, tuple(notes))


def _object_items(object_id: str, mesh: tuple[np.ndarray, np.ndarray], config: ViewerConfig) -> list[MeshItem]:
    vertices, faces = np.asarray(mesh[0], dtype=np.float64), np.asarray(mesh[1], dtype=np.int32)
    low, high = vertices[:, :2].min(axis=0) - config.table_margin, vertices[:, :2].max(axis=0) + config.table_margin
    table_v = np.array([[low[0], low[1], 0], [high[0], low[1], 0], [high[0], high[1], 0], [low[0], high[1], 0]])
    table_v[:, 2] = -1e-4  # just under z = 0, so the object's resting face does not flicker against the table
    table_f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    zero = np.zeros(3)
    return [
        MeshItem("/table", table_v, table_f, _rgb(TABLE_COLOR), zero, _IDENTITY, geometry=f"table:{object_id}"),
        MeshItem("/object", vertices, faces, _rgb(OBJECT_COLOR), zero, _IDENTITY, geometry=f"object:{object_id}"),
    ]


def _contact_items(positions: np.ndarray, config: ViewerConfig) -> list[MeshItem]:
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=2, radius=config.contact_radius)
    v, f = np.asarray(ball.vertices), np.asarray(ball.faces, dtype=np.int32)
    return [
        MeshItem(f"/contacts/{slot}", v, f, _rgb(SLOT_COLORS[slot]), positions[i].copy(), _IDENTITY, geometry="ball")
        for i, slot in enumerate(FINGER_SLOTS)
    ]


def _normal_lines(positions: np.ndarray, normals: np.ndarray, config: ViewerConfig) -> LineItem:
    points = np.stack([positions, positions + config.normal_length * normals], axis=1)  # (5, 2, 3)
    colors = np.array([[_rgb(SLOT_COLORS[s])] * 2 for s in FINGER_SLOTS], dtype=np.uint8)
    return LineItem("/normals", points, colors)


def _hand_items(
    prefix: str,
    pose: HandPose | None,
    record: GraspRecord,
    hand: HandView,
    color: tuple[float, float, float],
    opacity: float,
) -> list[MeshItem]:
    """The hand's shapes at ``pose`` (joints matched by the record's names); [] without a pose."""
    if pose is None:
        return []
    link_poses = hand.link_poses(pose.wrist_pose, dict(zip(record.joint_names, pose.q, strict=True)))
    items, counts = [], dict.fromkeys(hand.links, 0)
    for k, shape in enumerate(hand.meshes):
        i, counts[shape.link] = counts[shape.link], counts[shape.link] + 1
        placed = link_poses[shape.link]
        items.append(
            MeshItem(
                f"{prefix}/{shape.link}/{i}",
                shape.vertices,
                shape.faces,
                _rgb(color),
                placed[:3, 3].copy(),
                matrix_to_quat(placed[:3, :3]),
                opacity,
                geometry=f"hand:{hand.name}:{k}",
            )
        )
    return items


def _frame(meshes: list[MeshItem], hand: HandView | None) -> tuple[np.ndarray, float]:
    """Centre and radius (m) of the object, the contacts and the origins of the hand's links at grasp, its base link
    left out (the Shadow's base is its forearm, 29 cm behind the palm: framing it would leave the object small)."""
    skip = f"/grasp/{hand.kinematics.base_link}/" if hand is not None else None
    points = [m.world_vertices() for m in meshes if m.name == "/object" or m.name.startswith("/contacts/")]
    points += [m.position[None] for m in meshes if m.name.startswith("/grasp/") and not m.name.startswith(skip)]
    if not points:
        return np.zeros(3), 0.1
    cloud = np.concatenate(points)
    center = (cloud.min(axis=0) + cloud.max(axis=0)) / 2
    return center, float(max(np.linalg.norm(cloud - center, axis=1).max(), 0.02))


def _view_direction(center: np.ndarray, record: GraspRecord, config: ViewerConfig) -> np.ndarray:
    """(3,) unit direction from ``center`` to the camera: opposite the wrist (the base link's origin) in the table
    plane, turned by ``camera_turn_deg``, raised by ``camera_elevation_deg``; the pictures' -60° azimuth without
    a grasp."""
    azimuth = np.deg2rad(_PICTURE.azimuth_deg)
    if record.grasp is not None:
        away = center[:2] - np.asarray(record.grasp.wrist_pose[:2])
        if np.linalg.norm(away) > 1e-6:
            azimuth = np.arctan2(away[1], away[0]) + np.deg2rad(config.camera_turn_deg)
    elevation = np.deg2rad(config.camera_elevation_deg)
    return np.array([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
