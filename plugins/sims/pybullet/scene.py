"""Building one PyBullet scene: client, table, hand body and its layout, object body.

Every scene is its own ``BulletClient`` (``p.DIRECT``). Hot-path calls elsewhere go straight to
``pybullet`` with ``physicsClientId`` (``BulletClient.__getattr__`` builds a ``functools.partial``
on every attribute access, about a microsecond each).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ges_core.errors import AssetError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset
from ges_core.sim import SceneConfig
from ges_core.transforms import wxyz_to_xyzw
from ges_core.urdf import WRIST_JOINTS, root_link

from .drive import ImplicitPD
from .engine import BulletClient, connect_direct, p
from .hand_urdf import pybullet_hand_urdf
from .shapes import MassProperties, mass_properties, shape_arrays

__all__ = [
    "HandLayout",
    "Scene",
    "create_object",
    "exclude_link_pairs",
    "hand_layout",
    "link_indices",
    "load_hand_body",
    "new_scene",
    "set_hand_friction",
]

_MOVABLE = (p.JOINT_REVOLUTE, p.JOINT_PRISMATIC)
TABLE_HALF_EXTENTS = (10.0, 10.0, 0.5)
"""m: the table is a static box with its top at z = 0, not a ``GEOM_PLANE``: plane-convex contacts
gain one point per step, and a 4 cm cube dropped 20 cm on the plane landed 5-12 mm off to the side
(once on another face); on the box it lands flat, in place. 10 m reaches past the wrist's 5 m range."""
_OBJECT_MAX_VELOCITY = 1e3
"""m/s and rad/s: PyBullet clamps every velocity coordinate of a body at 100 by default, which would hide
a blown-up object from the backend's 100 m/s check (PhysX leaves a body's linear speed unclamped). The
hand keeps PyBullet's 100 rad/s, like PhysX's default joint speed limit."""
_OBJECT_ANGULAR_DAMPING = 0.05
"""1/s, SAPIEN's default angular damping of a rigid body (PyBullet's default is 0.04 on both)."""


@dataclass
class Scene:
    """One PyBullet world: the table plane and, once loaded, the hand and the object."""

    client: BulletClient
    cid: int
    table: int
    hand: int = -1
    obj: int = -1
    obj_mass: float = 0.0
    """kg; its weight is applied by hand when the hand has no gravity (see the backend)."""
    base_in_obj: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    """The object's PyBullet base (principal inertial) frame in the object frame, PyBullet (pos, xyzw)."""
    obj_in_base: tuple = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    """The inverse: object frame in the base frame, PyBullet (pos, xyzw)."""
    obj_friction: float | None = None
    """The object's own (PhysX-style) friction coefficient."""
    asset: ObjectAsset | None = None
    """The object's asset (kept to rebuild the scene of an env that blew up)."""
    obj_fixed: bool = False
    """The object is static (``load_object(fixed=True)``)."""
    friction_anchors: bool | str = "on_touch"
    """Bullet's friction anchor on the object (:func:`new_scene`): True, False or ``"on_touch"``."""
    anchored: bool = False
    """The object's links carry the friction anchor now (``"on_touch"``: from the hand's first touch on)."""
    obj_links: tuple[int, ...] = (-1,)
    """The object body's links: -1 (the base) and one fixed link per further :data:`MAX_SHAPES_PER_LINK` shapes
    (:func:`create_object`); per-link settings (friction, anchors) go to each."""


@dataclass(frozen=True)
class HandLayout:
    """Names and PyBullet indices of a loaded hand; identical in every scene."""

    floating: bool
    link_ids: dict[str, int]
    """Hand URDF link name -> PyBullet link index (virtual wrist links excluded)."""
    link_names: dict[int, str]
    """PyBullet link index -> name, every link (virtual ones included)."""
    base_link: int
    """PyBullet link index of the hand's base (URDF root) link."""
    drive_ids: np.ndarray
    """(D,) PyBullet joint indices of every driven joint: wrist joints (floating only), then the
    hand's joints in ``HandDescription.joint_names`` order."""
    idx_sim_to_hand: np.ndarray
    """(K,) ``q_hand = q_sim[idx_sim_to_hand]``: position of hand joint k among the hand's movable
    PyBullet joints in PyBullet's (URDF file) order (the SAPIEN backend's convention)."""
    idx_hand_to_sim: np.ndarray
    """(K,) ``q_sim = q_hand[idx_hand_to_sim]``."""
    pd: ImplicitPD
    """Gains of the ``drive_ids`` joints."""

    @property
    def num_wrist(self) -> int:
        """6 for a floating hand, else 0."""
        return len(WRIST_JOINTS) if self.floating else 0


def new_scene(
    config: SceneConfig, solver_iterations: int | None = None, *, friction_anchors: bool | str = "on_touch"
) -> Scene:
    """A DIRECT client with the config's physics settings and a static table whose top is z = 0.

    solver_iterations: overrides ``config.solver_iterations`` (None keeps it). friction_anchors: the object
    loaded into this scene gets Bullet's friction anchor (``changeDynamics(frictionAnchor=1)``), which covers
    every contact it makes (Bullet anchors a contact when either body asks; the flag on the hand's links made no
    measured difference): a contact in static friction keeps its first contact point, as PhysX's patch friction
    does, instead of the friction rows being rebuilt at each step's new point, which let a squeezed object creep
    out of the fingers (docs/simulators.md, "Friction anchors"). ``"on_touch"``: the object is loaded without
    it and gets it at the first step the hand touches it (:func:`anchor_on_touch`), so an object alone on the table
    rocks and settles on un-anchored contacts.
    """
    client = connect_direct()
    client.setPhysicsEngineParameter(
        fixedTimeStep=config.timestep,
        numSolverIterations=config.solver_iterations if solver_iterations is None else solver_iterations,
        numSubSteps=0,
        deterministicOverlappingPairs=1,  # same contact order every run: determinism
    )
    # No per-body gravity switch in PyBullet: with hand_gravity off, gravity is zero and the
    # backend applies the object's weight itself every step.
    client.setGravity(0.0, 0.0, config.gravity if config.hand_gravity else 0.0)
    slab = client.createCollisionShape(p.GEOM_BOX, halfExtents=TABLE_HALF_EXTENTS)
    table = client.createMultiBody(
        baseMass=0.0, baseCollisionShapeIndex=slab, basePosition=(0, 0, -TABLE_HALF_EXTENTS[2])
    )
    client.changeDynamics(table, -1, lateralFriction=config.table_friction)
    return Scene(client=client, cid=client._client, table=table, friction_anchors=friction_anchors)


def load_hand_body(scene: Scene, hand: HandModel, config: SceneConfig, floating: bool) -> None:
    """Load the hand (prepared URDF, fixed world link) into ``scene``, velocity motors off."""
    path = pybullet_hand_urdf(hand.urdf_text(), hand.name, floating=floating, base_dir=hand.urdf_path().parent)
    flags = p.URDF_USE_INERTIA_FROM_FILE  # safe: hand_urdf made every inertia valid
    if config.self_collision:
        flags |= p.URDF_USE_SELF_COLLISION | p.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT
    if scene.hand >= 0:
        p.removeBody(scene.hand, physicsClientId=scene.cid)
    try:
        scene.hand = p.loadURDF(str(path), useFixedBase=True, flags=flags, physicsClientId=scene.cid)
    except p.error as exc:
        raise AssetError(
            f"PyBullet cannot load the URDF of hand '{hand.name}' ({path}): {exc}; "
            "check that its mesh files exist (HandModel.urdf_path must give absolute mesh paths)"
        ) from exc
    n = p.getNumJoints(scene.hand, physicsClientId=scene.cid)
    if config.self_collision:
        exclude_link_pairs(scene, hand.excluded_link_pairs())
    movable = [j for j in range(n) if p.getJointInfo(scene.hand, j, physicsClientId=scene.cid)[2] in _MOVABLE]
    # PyBullet gives every movable joint a velocity motor with a small force: switch them off.
    p.setJointMotorControlArray(
        scene.hand, movable, p.VELOCITY_CONTROL, forces=[0.0] * len(movable), physicsClientId=scene.cid
    )
    for link in range(-1, n):
        # The PD damping is the hand's damping; PyBullet's default body damping (0.04) would add to it.
        p.changeDynamics(
            scene.hand,
            link,
            linearDamping=0.0,
            angularDamping=0.0,
            activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING,
            physicsClientId=scene.cid,
        )


def exclude_link_pairs(scene: Scene, pairs: set[frozenset[str]]) -> None:
    """Switch off collisions between the named link pairs of the scene's hand (both directions).

    ``URDF_USE_SELF_COLLISION_EXCLUDE_PARENT`` already drops parent-child pairs; the pairs joined
    through a zero-length link (Shadow: palm-ffproximal through ``ffknuckle``) and those the hand lists in
    ``self_collision_exclude`` (:meth:`ges_core.hand.HandModel.excluded_link_pairs`) need this call.
    Every pair of ``pairs`` is switched off, parent-child ones included, so the rule does not rest
    on the flag alone.
    """
    index = link_indices(scene.hand, scene.cid)
    for pair in pairs:
        link_a, link_b = sorted(index[name] for name in pair)
        p.setCollisionFilterPair(scene.hand, scene.hand, link_a, link_b, 0, physicsClientId=scene.cid)


def link_indices(body: int, cid: int) -> dict[str, int]:
    """Link name -> PyBullet link index of a loaded body: each joint's child link by its joint's index, the base
    link -1."""
    count = p.getNumJoints(body, physicsClientId=cid)
    index = {p.getJointInfo(body, j, physicsClientId=cid)[12].decode(): j for j in range(count)}
    return {p.getBodyInfo(body, physicsClientId=cid)[0].decode(): -1, **index}


def hand_layout(scene: Scene, hand: HandModel, config: SceneConfig, floating: bool) -> HandLayout:
    """Index maps of the hand loaded in ``scene``, checked against the hand's declared joints."""
    d = hand.description
    count = p.getNumJoints(scene.hand, physicsClientId=scene.cid)
    infos = [p.getJointInfo(scene.hand, j, physicsClientId=scene.cid) for j in range(count)]
    link_names = {j: info[12].decode() for j, info in enumerate(infos)}
    joint_ids = {info[1].decode(): j for j, info in enumerate(infos) if info[2] in _MOVABLE}
    wrist = [joint_ids.pop(name) for name in WRIST_JOINTS] if floating else []
    sim_order = sorted(joint_ids, key=joint_ids.get)
    _check_joints(hand.name, d.joint_names, sim_order)
    idx_sim_to_hand = np.array([sim_order.index(name) for name in d.joint_names], dtype=np.int64)
    virtual = {f"{j}_link" for j in WRIST_JOINTS}
    stiffness = [config.wrist_stiffness] * len(wrist) + list(d.pd_stiffness)
    damping = [config.wrist_damping] * len(wrist) + list(d.pd_damping)
    drive_ids = wrist + [joint_ids[name] for name in d.joint_names]
    start = [0.0] * len(wrist) + list(d.open_pose)
    # Bullet has no joint armature (HandDescription.armature): its joints keep their links' inertia, and the drive's
    # model of them does too (adding the armature there only, measured on the Shadow, made a blocked tip press 2.5-4.7
    # N where SAPIEN with the armature presses 4.5-6.8 and Bullet without it 3.4-6.4; docs/hands/shadow.md, "Armature").
    inertia = _joint_inertia(scene, drive_ids, start)
    return HandLayout(
        floating=floating,
        link_ids={name: j for j, name in link_names.items() if name not in virtual},
        link_names=link_names,
        base_link=next(j for j, name in link_names.items() if name == (d.base_link or root_link(hand.urdf_text()))),
        drive_ids=np.array(drive_ids, dtype=np.int64),
        idx_sim_to_hand=idx_sim_to_hand,
        idx_hand_to_sim=np.argsort(idx_sim_to_hand),
        pd=ImplicitPD(
            np.array(stiffness, dtype=np.float64),
            np.array(damping, dtype=np.float64),
            inertia,
            config.timestep,
            spring_limit=np.arange(len(drive_ids)) >= len(wrist),  # the hand's joints (drive.py)
        ),
    )


def _joint_inertia(scene: Scene, drive_ids: list[int], start: list[float]) -> np.ndarray:
    """(D,) diagonal of the joint-space mass matrix at ``start`` (kg m^2 or kg), ``drive_ids`` order.

    ``calculateMassMatrix`` orders degrees of freedom by joint index; every movable joint is driven.
    """
    order = np.argsort(drive_ids)
    q = np.asarray(start, dtype=np.float64)[order].tolist()
    mass = np.asarray(p.calculateMassMatrix(scene.hand, q, physicsClientId=scene.cid))
    diagonal = np.empty(len(drive_ids))
    diagonal[order] = np.diag(mass)
    return diagonal


def _check_joints(hand: str, declared: tuple[str, ...], urdf: list[str]) -> None:
    missing = [n for n in declared if n not in urdf]
    extra = [n for n in urdf if n not in declared]
    if missing or extra:
        raise AssetError(
            f"hand '{hand}': joint_names and the URDF's movable joints differ: declared but not in the URDF "
            f"{missing}, in the URDF but not declared {extra}; fix the hand's joint_names"
        )


def set_hand_friction(scene: Scene, layout: HandLayout, friction: float) -> None:
    """Lateral friction of every hand link (Bullet's per-body value, see ``drive.product_friction``)."""
    for link in range(-1, len(layout.link_names)):
        p.changeDynamics(scene.hand, link, lateralFriction=friction, physicsClientId=scene.cid)


MAX_SHAPES_PER_LINK = 16
"""PyBullet's ``createCollisionShapeArray`` keeps the first 16 shapes and drops the rest without a word (measured:
20 and 45 boxes both give 16 children). An object with more convex parts (CoACD gives a mug 17-45, pybullet's
bunny 25) gets one fixed link per further 16, so every part collides."""
_LINK_MASS_SHARE = 1e-6
"""Mass of each extra shape link, as a share of the object's: the base carries the object's whole mass and inertia
(computed from every part, :func:`~.shapes.mass_properties`), and a Featherstone fixed joint adds the link's
negligible mass to it."""


def create_object(scene: Scene, obj: ObjectAsset, *, fixed: bool = False) -> MassProperties:
    """Replace the scene's object by a new body of ``obj``'s collision shapes (no visuals), at the origin;
    ``fixed``: a static body (mass 0), which contacts do not move."""
    if scene.obj >= 0:
        p.removeBody(scene.obj, physicsClientId=scene.cid)
        scene.obj = -1
    props = mass_properties(obj)
    arrays = shape_arrays(obj)
    count = len(arrays["shapeTypes"])
    chunks = [range(i, min(i + MAX_SHAPES_PER_LINK, count)) for i in range(0, count, MAX_SHAPES_PER_LINK)]
    try:
        shapes = [
            p.createCollisionShapeArray(
                **{k: [v[i] for i in chunk] for k, v in arrays.items()}, physicsClientId=scene.cid
            )
            for chunk in chunks
        ]
    except p.error as exc:
        raise AssetError(
            f"PyBullet could not create the collision shapes of object '{obj.object_id}' ({exc}); "
            "check that its convex part files exist and are Wavefront OBJ or a format trimesh reads"
        ) from exc
    extra = len(shapes) - 1  # links carrying the shapes past the base's 16, fixed at the base's link frame
    scene.obj = p.createMultiBody(
        baseMass=props.mass,
        baseCollisionShapeIndex=shapes[0],
        baseInertialFramePosition=props.inertial_pose[:3].tolist(),
        baseInertialFrameOrientation=wxyz_to_xyzw(props.inertial_pose[3:]).tolist(),
        linkMasses=[props.mass * _LINK_MASS_SHARE] * extra,
        linkCollisionShapeIndices=shapes[1:],
        linkVisualShapeIndices=[-1] * extra,
        linkPositions=[[0.0, 0.0, 0.0]] * extra,
        linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * extra,
        linkInertialFramePositions=[[0.0, 0.0, 0.0]] * extra,
        linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * extra,
        linkParentIndices=[0] * extra,
        linkJointTypes=[p.JOINT_FIXED] * extra,
        linkJointAxis=[[0.0, 0.0, 1.0]] * extra,
        physicsClientId=scene.cid,
    )
    scene.obj_links = tuple(range(-1, extra))
    p.changeDynamics(
        scene.obj,
        -1,
        localInertiaDiagonal=props.inertia.tolist(),
        linearDamping=0.0,  # SAPIEN's default
        angularDamping=_OBJECT_ANGULAR_DAMPING,
        maxJointVelocity=_OBJECT_MAX_VELOCITY,
        activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING,  # the object's weight is an external force
        physicsClientId=scene.cid,
    )
    set_object_anchor(scene, scene.friction_anchors is True)
    if fixed:
        p.changeDynamics(scene.obj, -1, mass=0.0, physicsClientId=scene.cid)
    scene.obj_mass, scene.asset, scene.obj_fixed = (0.0 if fixed else props.mass), obj, fixed
    scene.base_in_obj = (tuple(props.inertial_pose[:3]), tuple(wxyz_to_xyzw(props.inertial_pose[3:])))
    scene.obj_in_base = p.invertTransform(*scene.base_in_obj)
    return props


def set_object_anchor(scene: Scene, on: bool) -> None:
    """Give every link of the scene's object Bullet's friction anchor (``on``) or take it away."""
    for link in scene.obj_links:
        p.changeDynamics(scene.obj, link, frictionAnchor=int(on), physicsClientId=scene.cid)
    scene.anchored = on


def anchor_on_touch(scene: Scene) -> None:
    """``friction_anchors="on_touch"``: anchor the object once any hand link touches it (checked before each
    physics step; contacts the step then makes carry the anchor). Anchored, it stays so until the object is
    placed again (:meth:`PybulletBackend._set_object_pose`)."""
    if scene.friction_anchors != "on_touch" or scene.anchored or scene.obj < 0 or scene.hand < 0:
        return
    if p.getContactPoints(bodyA=scene.obj, bodyB=scene.hand, physicsClientId=scene.cid):
        set_object_anchor(scene, True)
