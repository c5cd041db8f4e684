"""The right Allegro Hand: description from ``allegro.yaml``, model from mani-skill's URDF.

:meth:`AllegroHand.urdf_path` writes a simulator-ready copy of
``mani_skill/assets/robots/allegro/allegro_hand_right.urdf`` once per source file (cached by
hash under :func:`ges_core.paths.cache_dir`):

* ``<material>`` tags removed (SAPIEN's loader needs a render device for them); visuals and
  collision geometry kept; mesh paths made absolute.
* Inertia tensors that no rigid body inside the link's collision geometry can have are replaced
  (see :func:`fix_inertias`): 16 of the file's 21 inertial links. 13 break the triangle inequality
  of principal moments (what makes PyBullet's ``URDF_USE_INERTIA_FROM_FILE`` zero them), 3 have a
  radius of gyration larger than the link itself. Details: ``docs/hands/allegro.md``.
* The massless virtual frames ``palm`` and ``wrist`` get a tiny inertial (PyBullet gives a link
  without ``<inertial>`` 1 kg).
"""

from __future__ import annotations

import hashlib
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from ges_core.errors import AssetError
from ges_core.hand import HandDescription, HandModel
from ges_core.hand_files import installed_file
from ges_core.hand_yaml import description_from_yaml
from ges_core.paths import atomic_write_text, cache_dir
from ges_core.urdf import absolutize_mesh_paths, inertia_tensor, parse_urdf, reach_bound, strip_render_data

__all__ = [
    "HUMAN_MIDDLE_FINGER_LENGTH",
    "AllegroHand",
    "build_hand",
    "fix_inertias",
    "prepare_urdf",
    "source_urdf_path",
]

HERE = Path(__file__).resolve().parent
SOURCE_RELPATH = "assets/robots/allegro/allegro_hand_right.urdf"
"""The URDF inside the installed ``mani_skill`` package."""
HUMAN_MIDDLE_FINGER_LENGTH = 0.100
"""Metres, MCP joint centre to fingertip of an adult human middle finger: the reference of ``scale``
(about 0.54 of a 0.19 m hand length; see docs/hands/allegro.md)."""
CACHE_VERSION = "1"
"""Part of the cache key: bump it whenever :func:`prepare_urdf` changes what it writes."""
VIRTUAL_MASS = 1e-3
"""kg given to links without ``<inertial>`` (the fixed frames ``palm`` and ``wrist``): PyBullet would
give them 1 kg each; 1 g is 0.1 % of the hand's mass and keeps every link's mass nonzero."""
VIRTUAL_INERTIA = 1e-8
"""kg·m² principal moments of those links: a 1 g ball of 5 mm radius."""
_REL_TOL = 1e-9
"""Relative slack of the realizability tests (the file's values are printed to ~12 digits)."""


def source_urdf_path() -> Path:
    """mani-skill's right Allegro URDF, found without importing ``mani_skill`` (slow, pulls in SAPIEN)."""
    return installed_file(
        "mani_skill", SOURCE_RELPATH, what="the 'allegro' hand", distribution="mani-skill", version="3.0.1",
        install="pip install 'ges-unigrasp[allegro]'",
    )  # fmt: skip


def build_hand(**settings: Any) -> AllegroHand:
    """Registry factory; ``settings`` replace top-level keys of ``allegro.yaml`` (e.g. ``scale``)."""
    return AllegroHand(**settings)


class AllegroHand(HandModel):
    """The right Allegro Hand; ``overrides`` replace top-level keys of ``allegro.yaml``."""

    def __init__(self, **overrides: Any) -> None:
        self._source = source_urdf_path()
        yaml_text = (HERE / "allegro.yaml").read_text()
        self._description = description_from_yaml(
            yaml_text, self._source.read_text(), source=str(HERE / "allegro.yaml"), **overrides
        )
        self._urdf: Path | None = None

    @property
    def description(self) -> HandDescription:
        """Joints, fingers, wrist convention, sizes and gains from ``allegro.yaml``."""
        return self._description

    def urdf_path(self) -> Path:
        """The simulator-ready copy of the URDF (written to the cache on first call)."""
        if self._urdf is None:
            self._urdf = _cached_urdf(self._source)
        return self._urdf


def _cached_urdf(source: Path) -> Path:
    data = source.read_bytes()
    key = hashlib.sha256(data + str(source).encode() + CACHE_VERSION.encode()).hexdigest()[:16]
    path = cache_dir("hands", "allegro") / f"allegro_hand_right_{key}.urdf"
    if not path.is_file():
        atomic_write_text(path, prepare_urdf(data.decode("utf-8"), source.parent))
    return path


def prepare_urdf(text: str, base_dir: Path) -> str:
    """The sim-ready URDF text: no ``<material>``, absolute mesh paths, realizable inertias.

    base_dir: folder the source's relative mesh paths start from.
    """
    text = absolutize_mesh_paths(strip_render_data(text, keep_visuals=True), base_dir)
    root = parse_urdf(text)
    fixed = fix_inertias(root)
    virtual = _add_virtual_inertials(root)
    fixed_list, virtual_list = ", ".join(fixed) or "none", ", ".join(virtual) or "none"
    root.insert(
        0, ET.Comment(f" ges-unigrasp: inertia replaced on {fixed_list}; tiny inertial added to {virtual_list} ")
    )
    return ET.tostring(root, encoding="unicode")


# -- inertia ------------------------------------------------------------------------------
def fix_inertias(root: ET.Element) -> list[str]:
    """Replace every physically impossible inertia tensor in ``root`` (in place); return those links.

    A tensor is impossible when its principal moments are not positive, break the triangle
    inequality (``I1 + I2 >= I3`` holds for every rigid body), or exceed ``m R^2`` with ``R`` the
    distance from the centre of mass to the farthest point of the link's collision geometry. The
    replacement is a uniform solid box filling the collision geometry's bounding box, with the
    file's mass and centre of mass, axes along the link frame.
    """
    fixed = []
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass, com, tensor = _read_inertial(inertial, link.get("name"))
        points = _collision_points(link)
        if not _realizable(mass, tensor, points - com):
            _write_box_inertia(inertial, mass, points, link.get("name"))
            fixed.append(link.get("name"))
    return fixed


def _read_inertial(inertial: ET.Element, name: str | None) -> tuple[float, np.ndarray, np.ndarray]:
    """(mass kg, centre of mass (3,) link frame, (3, 3) tensor in the inertial frame)."""
    mass_el, inertia_el = inertial.find("mass"), inertial.find("inertia")
    if mass_el is None or inertia_el is None:
        raise AssetError(f"Allegro URDF: link '{name}' has an <inertial> without <mass> or <inertia>")
    com, _ = _origin(inertial)
    return float(mass_el.get("value")), com, inertia_tensor(inertia_el)


def _realizable(mass: float, tensor: np.ndarray, offsets: np.ndarray) -> bool:
    """Whether a body of ``mass`` with points at ``offsets`` (N, 3) from its COM can have ``tensor``."""
    moments = np.linalg.eigvalsh(tensor)  # ascending
    if moments[0] <= 0 or moments[0] + moments[1] < moments[2] * (1 - _REL_TOL):
        return False
    return moments[2] <= reach_bound(mass, offsets) * (1 + _REL_TOL)


def _write_box_inertia(inertial: ET.Element, mass: float, points: np.ndarray, name: str | None) -> None:
    if len(points) == 0:
        raise AssetError(f"Allegro URDF: link '{name}' has an impossible inertia and no collision geometry to fix it")
    dx, dy, dz = points.max(axis=0) - points.min(axis=0)
    moments = mass / 12.0 * np.array([dy**2 + dz**2, dx**2 + dz**2, dx**2 + dy**2])
    origin = inertial.find("origin")
    if origin is not None:
        origin.set("rpy", "0 0 0")  # the box's axes are the link's
    values = {"ixx": moments[0], "iyy": moments[1], "izz": moments[2], "ixy": 0.0, "ixz": 0.0, "iyz": 0.0}
    inertia_el = inertial.find("inertia")
    for key, value in values.items():
        inertia_el.set(key, f"{value:.9g}")


def _add_virtual_inertials(root: ET.Element) -> list[str]:
    """Give every link without ``<inertial>`` a tiny one; return their names."""
    added = []
    for link in root.findall("link"):
        if link.find("inertial") is not None:
            continue
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=str(VIRTUAL_MASS))
        moment = str(VIRTUAL_INERTIA)
        ET.SubElement(inertial, "inertia", ixx=moment, iyy=moment, izz=moment, ixy="0", ixz="0", iyz="0")
        added.append(link.get("name"))
    return added


# -- collision geometry -------------------------------------------------------------------
def _collision_points(link: ET.Element) -> np.ndarray:
    """(N, 3) points bounding the link's collision geometry, link frame, metres."""
    chunks = [_shape_points(c) for c in link.findall("collision")]
    chunks = [c for c in chunks if len(c)]
    return np.concatenate(chunks) if chunks else np.zeros((0, 3))


def _shape_points(collision: ET.Element) -> np.ndarray:
    geometry = collision.find("geometry")
    shape = geometry[0] if geometry is not None and len(geometry) else None
    if shape is None:
        return np.zeros((0, 3))
    local = _local_points(shape)
    xyz, rot = _origin(collision)
    return local @ rot.T + xyz


def _local_points(shape: ET.Element) -> np.ndarray:
    """Points of one geometry element in its own frame (corners of its bounding box, or mesh vertices)."""
    if shape.tag == "mesh":
        import trimesh

        scale = np.array([float(s) for s in shape.get("scale", "1 1 1").split()])
        return np.asarray(trimesh.load(shape.get("filename"), force="mesh").vertices) * scale
    if shape.tag == "box":
        half = np.array([float(s) for s in shape.get("size").split()]) / 2
    elif shape.tag == "sphere":
        half = np.full(3, float(shape.get("radius")))
    elif shape.tag == "cylinder":
        r = float(shape.get("radius"))
        half = np.array([r, r, float(shape.get("length")) / 2])
    else:
        raise AssetError(f"Allegro URDF: unsupported collision geometry <{shape.tag}>")
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    return signs * half


def _origin(element: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (3,), rotation (3, 3)) of an element's ``<origin>`` (identity when absent)."""
    origin = element.find("origin")
    xyz = np.array([float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()])
    rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
    return xyz, _rpy_matrix(*rpy)


def _rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx
