"""Compiled MuJoCo model (``mjModel``) -> URDF text: pure functions, no file I/O.

MuJoCo's compiler is the ground truth: class defaults, ``euler``/``axisangle`` orientations and
inertial frames are already resolved in ``mjModel``, so the converter copies numbers, it does not
re-interpret MJCF. What it writes, per body of the exported subtree (root body first):

* a ``<link>`` with the body's mass and full inertia tensor (``body_inertia`` rotated by
  ``body_iquat`` into the link frame, origin at ``body_ipos``; rpy 0, so no loader has to honour
  an inertial rotation) and one ``<collision>`` per geom that collides (``contype`` or
  ``conaffinity`` non-zero): box -> ``<box>`` (full sizes), sphere -> ``<sphere>``, capsule ->
  ``<capsule radius length>`` (length = cylinder part; PyBullet, SAPIEN and pytorch-kinematics
  read it, axis z as in MuJoCo), cylinder -> ``<cylinder>``, mesh -> ``<mesh filename="NAME.obj">``
  holding MuJoCo's compiled vertices in the geom frame (:func:`collision_meshes_from_mjmodel`);
* a ``<joint>`` from the parent body: ``body_pos``/``body_quat`` as origin, a hinge as
  ``revolute`` (``continuous`` if unlimited) or a slide as ``prismatic`` with ``jnt_axis`` and
  ``jnt_range``; a body without joints is welded with ``fixed``.

No ``<visual>`` and no ``<material>`` (SAPIEN cannot parse materials without a render device),
no ``<dynamics>`` (the hand's PD damping is declared once, in its YAML, for every simulator).
What a URDF cannot carry is returned separately: tendon couplings
(:func:`tendon_couplings_from_mjmodel`) and explicit contact pairs
(:func:`contact_pairs_from_mjmodel`). Units: metres, kilograms, radians.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from ges_core.errors import AssetError
from ges_core.transforms import quat_to_matrix

__all__ = [
    "TendonCoupling",
    "collision_meshes_from_mjmodel",
    "contact_pairs_from_mjmodel",
    "geom_collides",
    "link_name",
    "subtree_bodies",
    "tendon_couplings_from_mjmodel",
    "urdf_from_mjmodel",
]

_OBJ_BODY, _OBJ_JOINT, _OBJ_GEOM, _OBJ_MESH, _OBJ_TENDON = (
    int(getattr(mujoco.mjtObj, f"mjOBJ_{k}")) for k in ("BODY", "JOINT", "GEOM", "MESH", "TENDON")
)
_HINGE, _SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
_SPHERE, _CAPSULE, _CYLINDER, _BOX, _MESH = (
    int(getattr(mujoco.mjtGeom, f"mjGEOM_{k}")) for k in ("SPHERE", "CAPSULE", "CYLINDER", "BOX", "MESH")
)
_TRN_JOINT, _WRAP_JOINT = int(mujoco.mjtTrn.mjTRN_JOINT), int(mujoco.mjtWrap.mjWRAP_JOINT)

FALLBACK_EFFORT = 1.0
"""N·m (N); URDF ``effort`` of a joint with no force-limited actuator. Unused by the Shadow hand:
every joint has an actuator or a coupling leader whose ``forcerange`` it takes."""
URDF_VELOCITY = 10.0
"""rad/s (m/s); URDF ``velocity`` is mandatory but the MJCF has no velocity limit. Not a cap in our
engines: SAPIEN's loader ignores it and PyBullet's position motor kept its own 100 rad/s cap
(measured on FFJ2 with this URDF, PyBullet 3.2.7)."""


@dataclass(frozen=True)
class TendonCoupling:
    """A fixed tendon that ties two joints: ``q[follower] ≈ ratio * q[leader] ± slack``.

    From a limited fixed tendon ``c_f q_f + c_l q_l ∈ [lo, hi]`` whose coefficients have opposite
    signs; the leader is the joint with an actuator. ``ratio = -c_l / c_f`` (the centre line of the
    allowed band when ``lo = -hi``); ``slack = max(|lo|, |hi|) / |c_f|`` radians of the follower.
    """

    tendon: str
    follower: str
    leader: str
    ratio: float
    slack: float


def _name(model: Any, objtype: int, idx: int) -> str:
    return mujoco.mj_id2name(model, objtype, idx) or ""


def link_name(model: Any, body: int, prefix: str = "") -> str:
    """URDF name of MuJoCo body ``body``: its name without ``prefix`` (``body<id>`` if unnamed)."""
    return _strip(_name(model, _OBJ_BODY, body), prefix) or f"body{body}"


def _strip(name: str, prefix: str) -> str:
    return name[len(prefix) :] if prefix and name.startswith(prefix) else name


def subtree_bodies(model: Any, root: int) -> list[int]:
    """Body ids of ``root`` and all its descendants, in MuJoCo (depth-first) order."""
    out = [root]
    for body in range(root + 1, model.nbody):
        if int(model.body_parentid[body]) in out:
            out.append(body)
    return out


def geom_collides(model: Any, geom: int) -> bool:
    """True when the geom takes part in MuJoCo collisions (``contype`` or ``conaffinity`` non-zero)."""
    return bool(model.geom_contype[geom] or model.geom_conaffinity[geom])


def _body_id(model: Any, name: str) -> int:
    idx = mujoco.mj_name2id(model, _OBJ_BODY, name)
    if idx < 0:
        names = [_name(model, _OBJ_BODY, b) for b in range(1, model.nbody)]
        raise AssetError(f"MJCF has no body '{name}' to export as the URDF root; bodies: {', '.join(names)}")
    return idx


# -- numbers and frames -----------------------------------------------------------------------
def _fmt(values: Iterable[float]) -> str:
    """Shortest round-trip decimal text of each value, space separated (-0.0 written as 0.0)."""
    return " ".join(repr(float(v) + 0.0) for v in values)


def _rpy(quat_wxyz: np.ndarray) -> np.ndarray:
    """URDF roll, pitch, yaw (``R = Rz(yaw) Ry(pitch) Rx(roll)``) of a wxyz quaternion."""
    return Rotation.from_matrix(quat_to_matrix(quat_wxyz)).as_euler("xyz")


def _origin(parent: ET.Element, pos: np.ndarray, quat: np.ndarray) -> None:
    ET.SubElement(parent, "origin", xyz=_fmt(pos), rpy=_fmt(_rpy(quat)))


def link_inertia(model: Any, body: int) -> np.ndarray:
    """(3, 3) inertia tensor of ``body`` about its centre of mass, in the body (link) frame, kg·m²."""
    rot = quat_to_matrix(model.body_iquat[body])
    inertia = rot @ np.diag(model.body_inertia[body]) @ rot.T
    inertia = (inertia + inertia.T) / 2
    inertia[np.abs(inertia) < 1e-12 * np.abs(inertia).max()] = 0.0  # rotation round-off (1e-20) is not data
    return inertia


# -- links ------------------------------------------------------------------------------------
def _inertial(link: ET.Element, model: Any, body: int) -> None:
    if model.body_mass[body] <= 0:
        return
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz=_fmt(model.body_ipos[body]), rpy="0.0 0.0 0.0")
    ET.SubElement(inertial, "mass", value=_fmt([model.body_mass[body]]))
    i = link_inertia(model, body)
    values = {"ixx": i[0, 0], "ixy": i[0, 1], "ixz": i[0, 2], "iyy": i[1, 1], "iyz": i[1, 2], "izz": i[2, 2]}
    ET.SubElement(inertial, "inertia", {k: _fmt([v]) for k, v in values.items()})


def _geometry(model: Any, geom: int, prefix: str) -> tuple[str, dict[str, str]]:
    """URDF geometry tag and attributes of one collision geom."""
    kind, size = int(model.geom_type[geom]), model.geom_size[geom]
    if kind == _BOX:
        return "box", {"size": _fmt(2 * size)}
    if kind == _SPHERE:
        return "sphere", {"radius": _fmt(size[:1])}
    if kind in (_CAPSULE, _CYLINDER):
        return ("capsule" if kind == _CAPSULE else "cylinder"), {
            "radius": _fmt(size[:1]),
            "length": _fmt([2 * size[1]]),
        }
    if kind == _MESH:
        return "mesh", {"filename": _mesh_file(model, int(model.geom_dataid[geom]), prefix)}
    raise AssetError(
        f"geom '{_name(model, _OBJ_GEOM, geom)}' has MuJoCo geom type {kind}, which has no URDF equivalent; "
        "use a box, sphere, capsule, cylinder or mesh, or set contype=conaffinity=0 to leave it out"
    )


def _mesh_file(model: Any, mesh: int, prefix: str) -> str:
    return f"{_strip(_name(model, _OBJ_MESH, mesh), prefix) or f'mesh{mesh}'}.obj"


def _collisions(link: ET.Element, model: Any, body: int, prefix: str) -> None:
    start = int(model.body_geomadr[body])
    for geom in range(start, start + int(model.body_geomnum[body])):
        if not geom_collides(model, geom):
            continue
        tag, attrs = _geometry(model, geom, prefix)
        collision = ET.SubElement(link, "collision")  # no name: pytorch-kinematics' parser warns on it
        _origin(collision, model.geom_pos[geom], model.geom_quat[geom])
        ET.SubElement(ET.SubElement(collision, "geometry"), tag, attrs)


def _link(model: Any, body: int, prefix: str) -> ET.Element:
    link = ET.Element("link", name=link_name(model, body, prefix))
    _inertial(link, model, body)
    _collisions(link, model, body, prefix)
    return link


# -- joints -----------------------------------------------------------------------------------
def joint_efforts(model: Any) -> dict[int, float]:
    """Joint id -> largest actuator force (N·m or N): from force-limited joint actuators, then
    copied from leader to follower of every tendon coupling; joints with neither are absent."""
    efforts: dict[int, float] = {}
    for act in range(model.nu):
        if int(model.actuator_trntype[act]) == _TRN_JOINT and model.actuator_forcelimited[act]:
            efforts[int(model.actuator_trnid[act, 0])] = float(np.abs(model.actuator_forcerange[act]).max())
    for coupling in _coupling_ids(model):
        if coupling[1] in efforts:
            efforts.setdefault(coupling[0], efforts[coupling[1]])
    return efforts


def _joint(model: Any, body: int, prefix: str, efforts: dict[int, float]) -> ET.Element:
    parent = link_name(model, int(model.body_parentid[body]), prefix)
    child = link_name(model, body, prefix)
    count = int(model.body_jntnum[body])
    if count > 1:
        raise AssetError(f"body '{child}' has {count} joints; a URDF link has one parent joint (split the body)")
    if count == 0:
        joint = ET.Element("joint", name=f"{parent}_to_{child}", type="fixed")
    else:
        joint = _movable_joint(model, int(model.body_jntadr[body]), prefix)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    _origin(joint, model.body_pos[body], model.body_quat[body])
    if count:
        _axis_and_limit(joint, model, int(model.body_jntadr[body]), efforts)
    return joint


def _movable_joint(model: Any, jnt: int, prefix: str) -> ET.Element:
    name, kind = _strip(_name(model, _OBJ_JOINT, jnt), prefix), int(model.jnt_type[jnt])
    if kind not in (_HINGE, _SLIDE):
        raise AssetError(f"joint '{name}' has MuJoCo type {kind}; only hinge and slide joints convert to URDF")
    if np.linalg.norm(model.jnt_pos[jnt]) > 1e-9:
        raise AssetError(
            f"joint '{name}' sits at {model.jnt_pos[jnt].tolist()} in its body, not at the body origin; "
            "a URDF joint frame is its child link frame (move the joint's pos into the body's pos)"
        )
    urdf_kind = "prismatic" if kind == _SLIDE else ("revolute" if model.jnt_limited[jnt] else "continuous")
    return ET.Element("joint", name=name, type=urdf_kind)


def _axis_and_limit(joint: ET.Element, model: Any, jnt: int, efforts: dict[int, float]) -> None:
    ET.SubElement(joint, "axis", xyz=_fmt(model.jnt_axis[jnt]))
    limit = {"effort": _fmt([efforts.get(jnt, FALLBACK_EFFORT)]), "velocity": _fmt([URDF_VELOCITY])}
    if joint.get("type") != "continuous":
        lower, upper = model.jnt_range[jnt] if model.jnt_limited[jnt] else (-np.inf, np.inf)
        limit.update(lower=_fmt([lower]), upper=_fmt([upper]))
    ET.SubElement(joint, "limit", limit)


# -- public -----------------------------------------------------------------------------------
def urdf_from_mjmodel(
    model: Any, *, root_body: str = "robot0:forearm", prefix: str = "robot0:", robot_name: str = "shadow_hand"
) -> str:
    """URDF text of the subtree of ``root_body`` in a compiled ``mujoco.MjModel``.

    Names lose ``prefix``; ``root_body`` becomes the URDF root link (its frame is the base frame).
    Mesh collisions name ``NAME.obj`` relative to the URDF; write the files from
    :func:`collision_meshes_from_mjmodel` beside it. Raises AssetError for what URDF cannot hold
    (ball/free joints, several joints in one body, a joint off its body origin, ellipsoid/plane geoms).
    """
    bodies = subtree_bodies(model, _body_id(model, root_body))
    efforts = joint_efforts(model)
    robot = ET.Element("robot", name=robot_name)
    robot.extend([_link(model, body, prefix) for body in bodies])
    robot.extend([_joint(model, body, prefix, efforts) for body in bodies[1:]])  # a list: extend() would mask errors
    ET.indent(robot)
    return ET.tostring(robot, encoding="unicode") + "\n"


def collision_meshes_from_mjmodel(
    model: Any, *, root_body: str = "robot0:forearm", prefix: str = "robot0:"
) -> dict[str, str]:
    """``{file name: OBJ text}`` of every colliding mesh geom in the exported subtree.

    Vertices are MuJoCo's compiled ones (metres, in the geom frame MuJoCo re-centred them to), so
    the URDF ``<collision>`` origin is the compiled ``geom_pos``/``geom_quat``.
    """
    out: dict[str, str] = {}
    for body in subtree_bodies(model, _body_id(model, root_body)):
        start = int(model.body_geomadr[body])
        for geom in range(start, start + int(model.body_geomnum[body])):
            if geom_collides(model, geom) and int(model.geom_type[geom]) == _MESH:
                mesh = int(model.geom_dataid[geom])
                out[_mesh_file(model, mesh, prefix)] = _obj_text(model, mesh)
    return out


def _obj_text(model: Any, mesh: int) -> str:
    v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    lines = [f"# MuJoCo compiled mesh '{_name(model, _OBJ_MESH, mesh)}', geom frame, metres"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in model.mesh_vert[v0 : v0 + nv].astype(float).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in model.mesh_face[f0 : f0 + nf].tolist()]
    return "\n".join(lines) + "\n"


def _tendon_joints(model: Any, tendon: int) -> list[tuple[int, float]]:
    """(joint id, coefficient) of a fixed tendon; empty if any wrap is not a joint."""
    start, count = int(model.tendon_adr[tendon]), int(model.tendon_num[tendon])
    wraps = range(start, start + count)
    if any(int(model.wrap_type[w]) != _WRAP_JOINT for w in wraps):
        return []
    return [(int(model.wrap_objid[w]), float(model.wrap_prm[w])) for w in wraps]


def _coupling_ids(model: Any) -> list[tuple[int, int, int, float, float]]:
    """(follower, leader, tendon, ratio, slack) of every two-joint coupling tendon (see TendonCoupling)."""
    actuated = {int(model.actuator_trnid[a, 0]) for a in range(model.nu) if model.actuator_trntype[a] == _TRN_JOINT}
    out = []
    for tendon in range(model.ntendon):
        pair = _tendon_joints(model, tendon)
        if len(pair) != 2 or not model.tendon_limited[tendon] or pair[0][1] * pair[1][1] >= 0:
            continue
        followers = [p for p in pair if p[0] not in actuated]
        leaders = [p for p in pair if p[0] in actuated]
        if len(followers) == 1 and len(leaders) == 1:
            (fj, fc), (lj, lc) = followers[0], leaders[0]
            slack = float(np.abs(model.tendon_range[tendon]).max()) / abs(fc)
            out.append((fj, lj, tendon, -lc / fc, slack))
    return out


def tendon_couplings_from_mjmodel(model: Any, *, prefix: str = "robot0:") -> list[TendonCoupling]:
    """Joints tied by a fixed tendon (the Shadow hand's J0 follows J1 in each finger), MuJoCo order."""
    return [
        TendonCoupling(
            tendon=_strip(_name(model, _OBJ_TENDON, t), prefix),
            follower=_strip(_name(model, _OBJ_JOINT, f), prefix),
            leader=_strip(_name(model, _OBJ_JOINT, lead), prefix),
            ratio=ratio,
            slack=slack,
        )
        for f, lead, t, ratio, slack in _coupling_ids(model)
    ]


def contact_pairs_from_mjmodel(model: Any, *, prefix: str = "robot0:") -> list[tuple[str, str]]:
    """Link pairs of MuJoCo's explicit ``<contact><pair>`` list, deduplicated, in file order.

    The Shadow MJCF turns hand-hand collisions off (``contype=1, conaffinity=0``) and lists the
    finger pairs that may touch; a URDF cannot say this, so it is returned for simulators to use.
    """
    out: list[tuple[str, str]] = []
    for p in range(model.npair):
        bodies = (int(model.geom_bodyid[model.pair_geom1[p]]), int(model.geom_bodyid[model.pair_geom2[p]]))
        pair = tuple(sorted(link_name(model, b, prefix) for b in bodies))
        if pair not in out:
            out.append(pair)
    return out
