"""A hand's URDF as MuJoCo bodies, joints and collision geoms, added to an ``mujoco.MjSpec``.

The URDF is turned into the spec directly (not through MuJoCo's own URDF importer), so that what the
engine holds is exactly the URDF's kinematic tree:

* every URDF link is one MuJoCo body **of the same name**, its frame the link frame (the joint origin);
  links joined by fixed joints stay separate bodies (MuJoCo's importer would fuse them, and the hand's
  ``*_tip`` links, addressed by name, would disappear);
* every revolute / continuous / prismatic joint is a hinge / slide of the same name, at the child body's
  origin, along the URDF axis, limited as in the URDF (continuous: unlimited);
* inertias are the URDF's, rewritten in principal axes with the largest moment clamped just inside the
  triangle inequality (MuJoCo refuses ``A + B < C``); a link without ``<inertial>`` gets 1 g, as in the
  PyBullet backend (SAPIEN: a negligible mass);
* collision shapes: box, sphere, cylinder and capsule (axis z, as URDF's cylinder) map to the MuJoCo
  primitives of the same kind, meshes to mesh assets (MuJoCo collides with their convex hull, like the
  other two engines); visuals are ignored.

The root link is a **mocap** body for a fixed hand (its pose is per-env data, ``set_hand_state`` moves it)
and a static body for a floating one (the URDF then comes from :func:`ges_core.urdf.add_floating_base`,
whose root is the massless world link above the six wrist joints).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from ges_core.errors import AssetError
from ges_core.transforms import matrix_to_quat
from ges_core.urdf import origin_matrix, parse_urdf, root_link

__all__ = ["HandBodies", "add_hand", "principal_inertia"]

_TINY_MASS = 1e-3
"""kg of a link without ``<inertial>`` (the PyBullet backend's value: a 1 g bead; MuJoCo needs a moving body
to have mass)."""
_TINY_INERTIA = 1e-8
"""kg m^2, principal moments of such a link (a 1 g sphere of about 5 mm radius)."""
_MIN_MOMENT = 1e-10
"""kg m^2 floor of a principal moment (MuJoCo rejects a moving body's zero moment)."""
_TRIANGLE_SLACK = 1e-3
"""Relative room kept below ``A + B``: MuJoCo's compiler rejects ``A + B < C`` (12 Allegro links break it
slightly, as PyBullet also reports)."""
_JOINT_TYPES = {
    "revolute": mujoco.mjtJoint.mjJNT_HINGE,
    "continuous": mujoco.mjtJoint.mjJNT_HINGE,
    "prismatic": mujoco.mjtJoint.mjJNT_SLIDE,
}


@dataclass(frozen=True)
class HandBodies:
    """What :func:`add_hand` added: names, in URDF order."""

    root: str
    """The root link's body name (mocap for a fixed hand)."""
    links: tuple[str, ...]
    """Every link (body) name."""
    joints: tuple[str, ...]
    """Every movable joint name, URDF file order."""


def add_hand(spec: mujoco.MjSpec, urdf_text: str, *, hand: str, mocap_root: bool, geom: dict) -> HandBodies:
    """Add the URDF's links and joints under ``spec.worldbody``.

    geom: attributes given to every collision geom (``friction``, ``contype``, ``conaffinity``, ...).
    """
    root = parse_urdf(urdf_text)
    links = {link.get("name"): link for link in root.findall("link")}
    children: dict[str, list[ET.Element]] = defaultdict(list)
    for joint in root.findall("joint"):
        children[joint.find("parent").get("link")].append(joint)
    base = root_link(urdf_text)
    movable: list[str] = []
    body = spec.worldbody.add_body(name=base, mocap=mocap_root)
    _fill_link(spec, body, links[base], hand, geom)
    stack = [(base, body)]
    while stack:
        parent, parent_body = stack.pop()
        for joint in children.get(parent, []):
            child = joint.find("child").get("link")
            if child not in links:
                raise AssetError(f"hand '{hand}': joint '{joint.get('name')}' names a missing child link '{child}'")
            frame = origin_matrix(joint)
            child_body = parent_body.add_body(name=child, pos=frame[:3, 3], quat=matrix_to_quat(frame[:3, :3]))
            _add_joint(child_body, joint, hand, movable)
            _fill_link(spec, child_body, links[child], hand, geom)
            stack.append((child, child_body))
    return HandBodies(root=base, links=tuple(links), joints=tuple(movable))


def _add_joint(body: mujoco.MjsBody, joint: ET.Element, hand: str, movable: list[str]) -> None:
    kind, name = joint.get("type"), joint.get("name")
    if kind == "fixed":
        return
    if kind not in _JOINT_TYPES:
        raise AssetError(f"hand '{hand}': joint '{name}' has type '{kind}'; MuJoCo backend takes revolute, "
                         "continuous, prismatic and fixed joints")  # fmt: skip
    axis_node = joint.find("axis")
    axis = np.array((axis_node.get("xyz", "1 0 0") if axis_node is not None else "1 0 0").split(), dtype=float)
    limit = joint.find("limit")
    limited = kind != "continuous" and limit is not None
    rng = [float(limit.get("lower", "0")), float(limit.get("upper", "0"))] if limited else [0.0, 0.0]
    body.add_joint(
        name=name,
        type=_JOINT_TYPES[kind],
        axis=axis / np.linalg.norm(axis),
        limited=mujoco.mjtLimited.mjLIMITED_TRUE if limited else mujoco.mjtLimited.mjLIMITED_FALSE,
        range=rng,
    )
    movable.append(name)


def _fill_link(spec: mujoco.MjSpec, body: mujoco.MjsBody, link: ET.Element, hand: str, geom: dict) -> None:
    """The link's inertial (explicit) and collision geoms on ``body``."""
    inertial = link.find("inertial")
    mass_node = inertial.find("mass") if inertial is not None else None
    mass = float(mass_node.get("value", "0")) if mass_node is not None else 0.0
    body.explicitinertial = True
    if mass <= 0:
        body.mass, body.ipos, body.iquat, body.inertia = _TINY_MASS, [0, 0, 0], [1, 0, 0, 0], [_TINY_INERTIA] * 3
    else:
        frame = origin_matrix(inertial)
        moments, axes = principal_inertia(_tensor(inertial))
        body.mass, body.ipos = mass, frame[:3, 3]
        body.iquat, body.inertia = matrix_to_quat(frame[:3, :3] @ axes), moments
    for i, collision in enumerate(link.findall("collision")):
        _add_geom(spec, body, collision, f"{link.get('name')}:{i}", hand, geom)


def _add_geom(spec: mujoco.MjSpec, body: mujoco.MjsBody, collision: ET.Element, name: str, hand: str, attrs: dict):
    frame = origin_matrix(collision)
    shape = collision.find("geometry")
    shape = shape[0] if shape is not None and len(shape) else None
    kw = {"pos": frame[:3, 3], "quat": matrix_to_quat(frame[:3, :3]), **attrs}
    get = (lambda k: float(shape.get(k))) if shape is not None else None
    if shape is None:
        raise AssetError(f"hand '{hand}': collision {name} has no geometry")
    if shape.tag == "box":
        size = np.array(shape.get("size").split(), dtype=float) / 2
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=size, **kw)
    elif shape.tag == "sphere":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[get("radius"), 0, 0], **kw)
    elif shape.tag in ("cylinder", "capsule"):  # URDF: axis z, full length (between the caps' centres)
        kind = mujoco.mjtGeom.mjGEOM_CYLINDER if shape.tag == "cylinder" else mujoco.mjtGeom.mjGEOM_CAPSULE
        body.add_geom(type=kind, size=[get("radius"), get("length") / 2, 0], **kw)
    elif shape.tag == "mesh":
        path = Path(shape.get("filename", ""))
        if not path.is_file():
            raise AssetError(f"hand '{hand}': collision mesh {path} of {name} does not exist; reinstall the hand's "
                             "assets (mesh paths must be absolute)")  # fmt: skip
        scale = np.array(shape.get("scale", "1 1 1").split(), dtype=float)
        mesh = spec.add_mesh(name=f"hand:{name}", file=str(path), scale=scale)
        mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_CONVEX
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name, **kw)
    else:
        raise AssetError(f"hand '{hand}': collision {name} is a <{shape.tag}>; give box, sphere, cylinder, capsule "
                         "or mesh")  # fmt: skip


def principal_inertia(tensor: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(3,) valid principal moments (kg m^2) and (3, 3) right-handed axes (columns) of an inertia tensor.

    Moments are floored at :data:`_MIN_MOMENT` and each is clamped just below the sum of the other two.
    """
    if np.count_nonzero(tensor - np.diag(np.diag(tensor))) == 0:
        moments, axes = np.diag(tensor).copy(), np.eye(3)  # already principal: keep the file's frame
    else:
        moments, axes = np.linalg.eigh(tensor)
        if np.linalg.det(axes) < 0:
            axes[:, 2] = -axes[:, 2]
    moments = np.maximum(moments, _MIN_MOMENT)
    for i in range(3):
        moments[i] = min(moments[i], (moments.sum() - moments[i]) * (1 - _TRIANGLE_SLACK))
    return moments, axes


def _tensor(inertial: ET.Element) -> np.ndarray:
    node = inertial.find("inertia")
    get = (lambda k: float(node.get(k, "0"))) if node is not None else (lambda k: 0.0)
    xx, yy, zz, xy, xz, yz = (get(k) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"))
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
