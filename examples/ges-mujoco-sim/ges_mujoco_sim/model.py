"""One compiled MuJoCo scene: table plane, the hand with its PD actuators, the object; and its index layout.

A scene is built as an ``mujoco.MjSpec`` and compiled into an ``MjModel`` that every env holding the same
object shares (each env has its own ``MjData``). Physics choices, each made so MuJoCo behaves like the
SAPIEN backend (docs/simulators.md, "MuJoCo"):

* **Drives.** One position actuator per driven joint, ``force = Kp (q* - q) - (Kd + Kp dt) qdot``, stepped
  with the ``implicitfast`` integrator, which takes the velocity term implicitly (at the next step's
  velocity) and the spring explicitly. With ``dt`` the MuJoCo step that is exactly PhysX's implicit drive,
  ``Kp (q* - q') - Kd v'`` with ``q' = q + dt v'``; with substeps ``dt`` stays the scene's step, so the drive
  keeps the damping a PhysX step of that length adds (a free Allegro joint closes 22.5 % of its error per
  1/120 s, 30 % in SAPIEN; docs/simulators.md). Targets beyond a joint's limits are kept (no control
  range), so a blocked joint pushes with the raw target's spring force, as in SAPIEN. ``set_drive_limits``
  is the actuator's ``forcerange``.
* **Gravity off for the hand** (``hand_gravity=False``): ``gravcomp = 1`` on every hand body, MuJoCo's
  per-body gravity compensation (the object keeps its weight).
* **Friction.** MuJoCo takes a contact's friction from the geom of higher ``priority`` (PhysX averages the
  two). Object geoms get priority 1 and the hand-object average, the table priority 2 and the
  object-table average, so those two pairs are exact; hand-table contacts get the object-table value
  (exact when the hand's and the object's coefficients are equal, as in every built-in setting).
* **Self-collision.** MuJoCo's parent-child filter is switched off and every pair of
  :func:`ges_core.urdf.neighbour_link_pairs` is an explicit ``<exclude>``: the same rule as the other
  backends, not MuJoCo's (which also skips a link's grandparent through a fixed joint).
* **Blow-ups stay visible.** MuJoCo resets a state whose acceleration went bad unless ``AUTORESET`` is
  disabled; it is, so the backend sees the NaN and reports the env like the other engines.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from ges_core.errors import AssetError
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.sim import SceneConfig
from ges_core.urdf import WRIST_JOINTS

from .hand_spec import HandBodies, add_hand

__all__ = ["HandSetup", "SceneModel", "build_scene"]

OBJECT_BODY = "object"
TABLE_GEOM = "table"
CONE = mujoco.mjtCone.mjCONE_ELLIPTIC
"""Elliptic friction cones: Coulomb's circle (a pyramidal cone, MuJoCo's default, makes friction depend on the
direction of sliding relative to the contact frame); :mod:`.contacts` reads their forces directly."""
IMPRATIO = 10.0
"""Ratio of frictional to normal constraint impedance. MuJoCo's soft friction lets a held object creep out of
a grasp at its default of 1 (its documentation suggests raising it for grasping). Measured, Stage 1
validation of SAPIEN-refined Allegro grasps of the first five demo objects (SAPIEN held 5): 1 held at 1,
4 at 10 (noslip_iterations=4 instead: also 4, at 1.2x the time)."""
NOSLIP_ITERATIONS = 10
"""Iterations of MuJoCo's no-slip post-solver (friction without the soft constraints' creep), on top of
:data:`IMPRATIO`. Measured on the first eight demo objects, grasps refined in SAPIEN: Allegro grasps held
5 -> 6 (SAPIEN: 7; verdicts agreeing with SAPIEN 6 -> 7 of 8), Shadow unchanged (6, all 8 agreeing)."""
_Y_TO_X = np.array([np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0])
"""wxyz rotation by +90 deg about y: takes MuJoCo's capsule/cylinder axis (z) onto the asset's (x)."""


@dataclass(frozen=True)
class HandSetup:
    """A hand ready to build into scenes (prepared once per backend)."""

    name: str
    urdf_text: str
    """Engine-ready URDF: mesh paths absolute, no ``<mimic>``, floating base added if floating."""
    floating: bool
    joint_names: tuple[str, ...]
    """The hand's joints, ``HandDescription.joint_names`` order."""
    stiffness: tuple[float, ...]
    damping: tuple[float, ...]
    armature: tuple[float, ...]
    """(K,) each hand joint's armature, kg·m² (``HandDescription.armature_array``; zeros when the hand declares none):
    MuJoCo's own joint ``armature``, as the MJCF the Shadow comes from sets it."""
    base_link: str
    excluded: tuple[tuple[str, str], ...]
    """Link pairs that never collide (``HandModel.excluded_link_pairs``), used when self-collision is on."""


@dataclass(frozen=True)
class SceneModel:
    """A compiled scene and where its parts sit in MuJoCo's arrays."""

    model: mujoco.MjModel
    hand_qpos: np.ndarray
    """(K,) qpos addresses of the hand joints, hand joint order."""
    hand_dof: np.ndarray
    """(K,) qvel addresses, hand joint order."""
    wrist_qpos: np.ndarray
    """(6,) qpos addresses of the wrist joints (floating), else (0,)."""
    wrist_dof: np.ndarray
    drive_dof: np.ndarray
    """(D,) qvel addresses of every driven joint: wrist, then hand joint order (the actuator order)."""
    sim_order: tuple[str, ...]
    """The hand's joints in MuJoCo's (depth-first tree) order."""
    links: dict[str, int]
    """Hand link name -> body id."""
    base_body: int
    root_mocap: int
    """Mocap index of a fixed hand's root body, else -1."""
    object_body: int
    """Body id of the object, -1 without one."""
    object_qpos: int
    """qpos address of the object's free joint, -1 if fixed or absent."""
    object_dof: int
    object_mocap: int
    """Mocap index of a fixed object, else -1."""


def build_scene(
    config: SceneConfig, hand: HandSetup | None, obj: ObjectAsset | None, fixed: bool, substeps: int = 1
) -> SceneModel:
    """Compile the scene: table, ``hand`` (or none), ``obj`` (or none; ``fixed``: a mocap body).

    substeps: MuJoCo steps per ``SceneConfig.timestep`` (its ``timestep`` is ``config.timestep / substeps``);
    the drives keep the damping of one SAPIEN step of ``config.timestep`` (module docs).
    """
    spec = mujoco.MjSpec()
    _options(spec, config, substeps)
    hand_geoms = _contact_classes(config)
    obj_friction = obj.friction if obj is not None else None
    table_mu = config.table_friction if obj_friction is None else (config.table_friction + obj_friction) / 2
    spec.worldbody.add_geom(
        name=TABLE_GEOM, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], friction=[table_mu, 0, 0],
        priority=2, **hand_geoms["world"],
    )  # fmt: skip
    bodies = None
    if hand is not None:
        attrs = {"friction": [config.hand_friction, 0, 0], **hand_geoms["hand"]}
        bodies = add_hand(spec, hand.urdf_text, hand=hand.name, mocap_root=not hand.floating, geom=attrs)
        _hand_physics(spec, config, hand, bodies)
    if obj is not None:
        mu = (config.hand_friction + obj.friction) / 2
        _add_object(spec, obj, fixed, {"friction": [mu, 0, 0], "priority": 1, **hand_geoms["world"]})
    try:
        model = spec.compile()
    except ValueError as exc:
        who = f"object '{obj.object_id}'" if obj is not None else f"hand '{hand.name}'" if hand else "the table"
        raise AssetError(f"mujoco: the scene with {who} does not compile: {exc}; check its collision shapes "
                         "(convex parts need a volume) and inertias") from exc  # fmt: skip
    return _layout(model, hand, bodies, obj, fixed)


def _options(spec: mujoco.MjSpec, config: SceneConfig, substeps: int) -> None:
    opt = spec.option
    opt.timestep = config.timestep / substeps
    opt.gravity = [0.0, 0.0, config.gravity]
    opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST  # implicit drive damping (module docs)
    opt.iterations = config.solver_iterations
    opt.cone = CONE
    opt.impratio = IMPRATIO
    opt.noslip_iterations = NOSLIP_ITERATIONS
    opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_FILTERPARENT | mujoco.mjtDisableBit.mjDSBL_AUTORESET
    spec.compiler.degree = False  # joint ranges in radians, as in the URDF (MuJoCo's default is degrees)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO  # the object's, from its geoms


def _contact_classes(config: SceneConfig) -> dict[str, dict]:
    """contype/conaffinity of hand geoms and of the rest: hand-hand pairs only with self-collision on."""
    if config.self_collision:
        return {"hand": {"contype": 1, "conaffinity": 1}, "world": {"contype": 1, "conaffinity": 1}}
    # a pair collides when (contype_a & conaffinity_b) or (contype_b & conaffinity_a): hand-hand 2&1 = 0
    return {"hand": {"contype": 2, "conaffinity": 1}, "world": {"contype": 1, "conaffinity": 3}}


def _hand_physics(spec: mujoco.MjSpec, config: SceneConfig, hand: HandSetup, bodies: HandBodies) -> None:
    """Gravity compensation, neighbour exclusions, each hand joint's armature and one PD actuator per driven joint
    (wrist first)."""
    if not config.hand_gravity:
        for name in bodies.links:
            spec.body(name).gravcomp = 1.0
    if config.self_collision:
        for a, b in hand.excluded:
            spec.add_exclude(bodyname1=a, bodyname2=b)
    for joint, armature in zip(hand.joint_names, hand.armature, strict=True):
        spec.joint(joint).armature = armature
    wrist = WRIST_JOINTS if hand.floating else ()
    gains = [(config.wrist_stiffness, config.wrist_damping)] * len(wrist) + list(
        zip(hand.stiffness, hand.damping, strict=True)
    )
    for joint, (kp, kd) in zip((*wrist, *hand.joint_names), gains, strict=True):
        act = spec.add_actuator(name=f"drive:{joint}", target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.gaintype, act.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
        act.gainprm[0] = kp
        act.biasprm[:3] = [0.0, -kp, -(kd + kp * config.timestep)]  # implicit spring-damper (module docs)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE


def _add_object(spec: mujoco.MjSpec, obj: ObjectAsset, fixed: bool, attrs: dict) -> None:
    if not obj.collision:
        raise AssetError(f"object '{obj.object_id}' has no collision shapes; give it primitives or convex parts")
    body = spec.worldbody.add_body(name=OBJECT_BODY, mocap=fixed)
    if not fixed:
        body.add_freejoint(name=OBJECT_BODY)
    for i, shape in enumerate(obj.collision):
        if isinstance(shape, ConvexPart):
            if not shape.path.is_file():
                raise AssetError(
                    f"object '{obj.object_id}': convex part {shape.path} does not exist; rebuild its asset"
                )
            mesh = spec.add_mesh(name=f"object:{i}", file=str(shape.path))
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_CONVEX  # PhysX: the hull's mass properties
            body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name, density=obj.density, **attrs)
        else:
            body.add_geom(density=obj.density, **_primitive(shape, obj.object_id), **attrs)


def _primitive(shape: PrimitiveShape, object_id: str) -> dict:
    from ges_core.transforms import quat_mul

    size, pose = tuple(shape.size), np.asarray(shape.pose, dtype=float)
    g = mujoco.mjtGeom
    kinds = {"box": (g.mjGEOM_BOX, 3), "sphere": (g.mjGEOM_SPHERE, 1), "capsule": (g.mjGEOM_CAPSULE, 2),
             "cylinder": (g.mjGEOM_CYLINDER, 2)}  # fmt: skip
    kind, count = kinds.get(shape.kind, (None, 0))
    if kind is None or len(size) != count:
        raise AssetError(f"object '{object_id}': bad {shape.kind} size {size}; box takes 3 half extents, sphere "
                         "(radius,), capsule and cylinder (radius, half_length)")  # fmt: skip
    quat = pose[3:] / np.linalg.norm(pose[3:])
    if shape.kind in ("capsule", "cylinder"):
        quat = quat_mul(quat, _Y_TO_X)  # the asset's axis is local x, MuJoCo's local z
    return {"type": kind, "size": [*size, 0.0, 0.0][:3], "pos": pose[:3], "quat": quat}


def _layout(
    model: mujoco.MjModel, hand: HandSetup | None, bodies: HandBodies | None, obj: ObjectAsset | None, fixed: bool
) -> SceneModel:
    empty = np.zeros(0, dtype=np.int64)
    out = {"hand_qpos": empty, "hand_dof": empty, "wrist_qpos": empty, "wrist_dof": empty, "drive_dof": empty,
           "sim_order": (), "links": {}, "base_body": -1, "root_mocap": -1}  # fmt: skip
    if hand is not None:
        _check_joints(hand, bodies)
        qpos = {n: int(model.joint(n).qposadr[0]) for n in bodies.joints}
        dof = {n: int(model.joint(n).dofadr[0]) for n in bodies.joints}
        wrist = WRIST_JOINTS if hand.floating else ()
        hand_joints = [n for n in bodies.joints if n not in wrist]
        root = model.body(bodies.root)
        out.update(
            hand_qpos=np.array([qpos[n] for n in hand.joint_names]),
            hand_dof=np.array([dof[n] for n in hand.joint_names]),
            wrist_qpos=np.array([qpos[n] for n in wrist], dtype=np.int64),
            wrist_dof=np.array([dof[n] for n in wrist], dtype=np.int64),
            drive_dof=np.array([dof[n] for n in (*wrist, *hand.joint_names)]),
            sim_order=tuple(sorted(hand_joints, key=qpos.get)),
            links={n: int(model.body(n).id) for n in bodies.links if n not in _virtual(hand)},
            base_body=int(model.body(hand.base_link).id),
            root_mocap=int(model.body_mocapid[root.id]) if not hand.floating else -1,
        )
    body = int(model.body(OBJECT_BODY).id) if obj is not None else -1
    free = obj is not None and not fixed
    return SceneModel(
        model=model,
        object_body=body,
        object_qpos=int(model.joint(OBJECT_BODY).qposadr[0]) if free else -1,
        object_dof=int(model.joint(OBJECT_BODY).dofadr[0]) if free else -1,
        object_mocap=int(model.body_mocapid[body]) if obj is not None and fixed else -1,
        **out,
    )


def _virtual(hand: HandSetup) -> set[str]:
    """The floating wrist's massless links (not the hand's)."""
    return {"ges_world", *(f"{j}_link" for j in WRIST_JOINTS[:-1])} if hand.floating else set()


def _check_joints(hand: HandSetup, bodies: HandBodies) -> None:
    urdf = [n for n in bodies.joints if n not in WRIST_JOINTS]
    missing = [n for n in hand.joint_names if n not in urdf]
    extra = [n for n in urdf if n not in hand.joint_names]
    if missing or extra:
        raise AssetError(
            f"hand '{hand.name}': joint_names and the URDF's movable joints differ: declared but not in the URDF "
            f"{missing}, in the URDF but not declared {extra}; fix the hand's joint_names"
        )
