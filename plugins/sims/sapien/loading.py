"""Building SAPIEN scenes, hands and objects on a CPU without a render device.

Every function here follows the recipe in ``docs/platform-notes.md``: no render material or
render shape is ever created (they need a Vulkan device), URDFs are loaded from text without
``<material>`` tags through ``loader.parse`` with every link's visual records cleared.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError
from ges_core.hand import HandDescription, HandModel
from ges_core.hand_prep.engine_files import engine_file_memo
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.paths import cached_text_file
from ges_core.sim import SceneConfig
from ges_core.urdf import (
    WRIST_JOINTS,
    absolutize_mesh_paths,
    add_floating_base,
    parse_urdf,
    solid_links,
    strip_render_data,
)
from ges_plugins.sims.sapien.engine import sapien

__all__ = [
    "build_hand",
    "build_object",
    "create_scene",
    "exclusion_groups",
    "force_limits",
    "pair_exclusion_bits",
    "prepare_urdf",
    "rest_height",
    "set_contact_offset",
]

NO_SELF_COLLISION_BIT = 1 << 29
"""Collision-group-2 bit put on every hand shape when self-collision is off. SAPIEN's PhysX filter
(``TypeAffinityIgnoreFilterShader``) drops a shape pair when the two group-2 words share a bit and the
low 16 bits of their group-3 words are equal; every shape here keeps group 3 at 0. Objects and the
table leave group 2 empty, so they collide with everything."""

PAIR_BITS = 29
"""Group-2 bits 0..28 are handed out to groups of mutually excluded links (:func:`pair_exclusion_bits`); bit 29
is :data:`NO_SELF_COLLISION_BIT` and bits 30-31 stay free for users."""

REST_MARGIN = 2e-4
"""Gap (m) left under an object placed on the table: a start in contact or slight penetration makes
PhysX push it up; 0.2 mm falls in one step without a visible bounce."""


def create_scene(config: SceneConfig) -> sapien.Scene:
    """One CPU PhysX scene: timestep, gravity along z, a table plane at z = 0 with ``table_friction``."""
    previous = sapien.physx.get_scene_config()
    sapien.physx.set_scene_config(gravity=np.array([0.0, 0.0, config.gravity], dtype=np.float32))
    try:
        scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])  # the system reads gravity when created
    finally:
        sapien.physx.set_scene_config(previous)
    scene.set_timestep(config.timestep)
    material = sapien.physx.PhysxMaterial(config.table_friction, config.table_friction, 0.0)
    scene.add_ground(0.0, render=False, material=material)
    return scene


def prepare_urdf(hand: HandModel, *, floating: bool) -> Path:
    """The hand's URDF without render data, mesh paths absolute, plus the floating wrist if asked.

    :func:`ges_core.hand_prep.engine_urdf.engine_urdf` removes ``<mimic>`` tags (SAPIEN's loader would
    build them as fixed tendons that fight the followers' PD drives: the hand explodes), converts
    collision meshes to OBJ where needed and uses ``ges hand prepare``'s convex parts. Written once to
    the cache (keyed by a hash of the text) and reused; made once per process
    (:func:`ges_core.hand_prep.engine_files.engine_file_memo`).
    """
    source = hand.urdf_path()
    return _prepared_urdf(source.read_text(), source.parent, hand.name, floating)


@engine_file_memo  # made once per process (every backend loads the hand again)
def _prepared_urdf(text: str, folder: Path, name: str, floating: bool) -> Path:
    from ges_core.hand_prep.engine_urdf import engine_urdf  # trimesh and CoACD: imported when first needed

    text = absolutize_mesh_paths(engine_urdf(strip_render_data(text), folder), folder)
    if floating:
        text = add_floating_base(text)
    return cached_text_file(text, "sapien", "urdf", stem=f"{name}_{'floating' if floating else 'fixed'}")


def build_hand(
    scene: sapien.Scene, urdf: Path, config: SceneConfig, pair_bits: dict[str, int] | None = None
) -> sapien.physx.PhysxArticulation:
    """Load the articulation with its root fixed in the world, hand friction, optional self-collision; the URDF is
    parsed once per process for each file and setting (:data:`_HAND_BUILDERS`).

    pair_bits: link name -> group-2 bits that switch off its excluded pairs (:func:`pair_exclusion_bits`).
    """
    bits = tuple(sorted(pair_bits.items())) if pair_bits and config.self_collision else ()
    key = (str(urdf), config.hand_friction, config.self_collision, bits)
    builder = _HAND_BUILDERS.get(key)
    if builder is None:
        builder = _HAND_BUILDERS[key] = _parsed_hand(scene, urdf, config, dict(bits))
    articulation = builder.set_scene(scene).build(fix_root_link=True)
    builder.set_scene(None)  # the builder outlives the scene
    _configure_hand_body(articulation, config)
    return articulation


_HAND_BUILDERS: dict[tuple, sapien.wrapper.articulation_builder.ArticulationBuilder] = {}
"""Parsed hands, per URDF file, hand friction and collision bits. SAPIEN's URDF parser (Python) took most of the
16-24 ms of a hand load (benchmarks/hand_load_memo.py), and every Stage 1 trial builds a backend. A builder keeps
only records (shapes by file name, materials, joints) and builds into whichever scene it is given, unchanged by
building, so the articulation is the one a fresh parse gives (the tests compare them step by step)."""


def _parsed_hand(
    scene: sapien.Scene, urdf: Path, config: SceneConfig, pair_bits: dict[str, int]
) -> sapien.wrapper.articulation_builder.ArticulationBuilder:
    """The hand's articulation builder as SAPIEN's loader parses it, render records cleared, collision bits set."""
    loader = scene.create_urdf_loader()
    loader.fix_root_link = True
    loader.set_material(config.hand_friction, config.hand_friction, 0.0)
    builders, actors, _cameras = loader.parse(str(urdf))
    if len(builders) != 1 or actors:
        raise AssetError(f"{urdf}: expected one articulation, SAPIEN found {len(builders)} and {len(actors)} actors")
    builder = builders[0]
    for link_builder in builder.link_builders:
        link_builder.visual_records.clear()  # render shapes need a render device
        if not config.self_collision:
            link_builder.collision_groups[2] |= NO_SELF_COLLISION_BIT
        elif pair_bits:
            link_builder.collision_groups[2] |= pair_bits.get(link_builder.name, 0)
    return builder


def pair_exclusion_bits(hand_name: str, urdf_text: str, excluded: set[frozenset[str]]) -> dict[str, int]:
    """:func:`_pair_exclusion_bits`, worked out once per process for each hand, text and pair set (a fresh dict
    each call)."""
    return dict(_pair_exclusion_bits(hand_name, urdf_text, frozenset(excluded)))


@functools.lru_cache(maxsize=16)
def _pair_exclusion_bits(
    hand_name: str, urdf_text: str, excluded: frozenset[frozenset[str]]
) -> tuple[tuple[str, int], ...]:
    """Group-2 bits that keep apart exactly the excluded pairs that PhysX does not already skip.

    ``excluded`` (:meth:`ges_core.hand.HandModel.excluded_link_pairs`: the URDF's neighbours and the hand's own
    ``self_collision_exclude``) lists the pairs that must not collide. A PhysX articulation never collides a link
    with its parent. Every other excluded pair whose two links both have collision geometry must share a bit, and
    no pair that collides may: each bit goes to a group of links that are pairwise excluded (or parent and child),
    set on every link of the group (:func:`exclusion_groups`). Two links then share a bit exactly when they must
    not collide. One bit per pair, as before 5 December 2026, ran out at 29 pairs: a hand that keeps only the pairs
    its MJCF lists (the Shadow, 18 of 188) excludes 170.
    Returns (link name, bit mask) pairs (links without excluded pairs absent).
    """
    root = parse_urdf(urdf_text)
    solid = set(solid_links(root))
    parent_child = {frozenset((j.find("parent").get("link"), j.find("child").get("link"))) for j in root.iter("joint")}
    must = {pair for pair in excluded - parent_child if pair <= solid}
    groups = exclusion_groups(must, must | {pair for pair in parent_child if pair <= solid})
    if len(groups) > PAIR_BITS:
        raise AssetError(
            f"hand '{hand_name}': {len(must)} link pairs (joined through zero-length links, or listed in "
            f"self_collision_exclude) must not collide, which takes {len(groups)} groups of mutually excluded links, "
            f"but SAPIEN has {PAIR_BITS} collision-group bits to exclude them with; merge zero-length links into "
            "their parents in the URDF, list fewer pairs, or run with self_collision=False"
        )
    bits: dict[str, int] = {}
    for bit, group in enumerate(groups):
        for name in group:
            bits[name] = bits.get(name, 0) | 1 << bit
    return tuple(bits.items())


def exclusion_groups(must: set[frozenset[str]], may: set[frozenset[str]]) -> list[tuple[str, ...]]:
    """Groups of links covering every pair of ``must``, each group's pairs all in ``may`` (``must`` within it).

    A greedy cover by cliques, deterministic (names sorted): the first uncovered pair starts a group, then the link
    that joins it with the most uncovered pairs (every pair it makes in ``may``) is added until none adds one. Two
    links share a group only through a pair of ``may``; every pair of ``must`` shares one. Not always the fewest
    groups (that is NP-hard); one group per pair at worst.
    """
    left = set(must)
    links = sorted({name for pair in must for name in pair})
    groups: list[tuple[str, ...]] = []
    while left:
        group = sorted(min(sorted(pair) for pair in left))
        while True:
            best, gain = None, 0
            for link in links:
                if link in group or any(frozenset((link, m)) not in may for m in group):
                    continue
                new = sum(frozenset((link, m)) in left for m in group)
                if new > gain:
                    best, gain = link, new
            if best is None:
                break
            group.append(best)
        groups.append(tuple(sorted(group)))
        left -= {frozenset((a, b)) for i, a in enumerate(group) for b in group[i + 1 :]}
    return groups


def _configure_hand_body(articulation: sapien.physx.PhysxArticulation, config: SceneConfig) -> None:
    articulation.set_sleep_threshold(0.0)  # a sleeping hand stops simulating (platform notes)
    articulation.set_solver_position_iterations(config.solver_iterations)
    for link in articulation.get_links():
        link.disable_gravity = not config.hand_gravity


def sim_joint_order(
    articulation: sapien.physx.PhysxArticulation, description: HandDescription, *, floating: bool
) -> tuple[list[sapien.physx.PhysxArticulationJoint], np.ndarray, np.ndarray]:
    """Split SAPIEN's breadth-first active joints into wrist and hand joints and map the hand's order.

    Returns the active joints (sim order), ``idx_sim_to_hand`` (K,) and ``idx_hand_to_sim`` (K,):
    with ``q_fingers`` the sim vector after the wrist joints, ``q_hand = q_fingers[idx_sim_to_hand]``
    and ``q_fingers = q_hand[idx_hand_to_sim]``.
    """
    joints = list(articulation.get_active_joints())
    names = [j.name for j in joints]
    n_wrist = len(WRIST_JOINTS) if floating else 0
    if tuple(names[:n_wrist]) != WRIST_JOINTS[:n_wrist]:
        raise AssetError(f"hand '{description.name}': SAPIEN put the wrist joints at {names[:n_wrist]}")
    finger_names = names[n_wrist:]
    missing = sorted(set(description.joint_names) - set(finger_names))
    extra = sorted(set(finger_names) - set(description.joint_names))
    if missing or extra:
        raise AssetError(
            f"hand '{description.name}': joint_names and the URDF's movable joints differ "
            f"(not in URDF: {missing}; not in joint_names: {extra}); make the description list every movable joint"
        )
    idx_sim_to_hand = np.array([finger_names.index(n) for n in description.joint_names], dtype=np.int64)
    idx_hand_to_sim = np.argsort(idx_sim_to_hand)
    return joints, idx_sim_to_hand, idx_hand_to_sim


def set_drives(
    joints: list[sapien.physx.PhysxArticulationJoint],
    description: HandDescription,
    idx_sim_to_hand: np.ndarray,
    config: SceneConfig,
) -> None:
    """Force-mode PD drives: wrist joints from the scene config, hand joints from the description, and each hand
    joint's armature (``HandDescription.armature``; PhysX's own default, 0, where the hand declares none)."""
    n_wrist = len(joints) - description.num_joints
    for joint in joints[:n_wrist]:
        joint.set_drive_property(config.wrist_stiffness, config.wrist_damping)
    for k, sim_index in enumerate(idx_sim_to_hand):
        joint = joints[n_wrist + int(sim_index)]
        joint.set_drive_property(description.pd_stiffness[k], description.pd_damping[k])
        if description.armature:
            joint.set_armature(np.array([description.armature[k]], dtype=np.float32))


NO_FORCE_LIMIT = 3.4028234663852886e38
"""PhysX's default drive force limit (FLT_MAX): no cap. A limit of ``inf`` is passed as this."""


def force_limits(limits: np.ndarray | None, joints: int) -> list[float]:
    """Per hand joint, the ``force_limit`` of ``set_drive_property``: ``limits`` (K,) N·m, inf or None -> no cap."""
    if limits is None:
        return [NO_FORCE_LIMIT] * joints
    return [min(float(v), NO_FORCE_LIMIT) for v in limits]


def build_object(scene: sapien.Scene, obj: ObjectAsset, config: SceneConfig) -> sapien.Entity:
    """A dynamic actor with ``obj.collision`` shapes (density ``obj.density``, friction ``obj.friction``)."""
    if not obj.collision:
        raise AssetError(f"object '{obj.object_id}' has no collision shapes; give it primitives or convex parts")
    builder = scene.create_actor_builder()
    material = sapien.physx.PhysxMaterial(obj.friction, obj.friction, 0.0)
    for shape in obj.collision:
        _add_shape(builder, shape, material, obj)
    entity = builder.build(name=f"object:{obj.object_id}")
    body = entity.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    body.set_sleep_threshold(0.0)  # a sleeping object ignores a closing hand until woken (platform notes)
    body.set_solver_position_iterations(config.solver_iterations)
    return entity


def _add_shape(
    builder: sapien.ActorBuilder, shape: PrimitiveShape | ConvexPart, material: object, obj: ObjectAsset
) -> None:
    if isinstance(shape, ConvexPart):
        if not Path(shape.path).is_file():
            raise AssetError(f"object '{obj.object_id}': convex part {shape.path} does not exist; rebuild its asset")
        builder.add_convex_collision_from_file(str(shape.path), material=material, density=obj.density)
        return
    pose = sapien.Pose(p=list(shape.pose[:3]), q=list(shape.pose[3:]))
    kw = {"pose": pose, "material": material, "density": obj.density}
    size = shape.size
    if shape.kind == "box" and len(size) == 3:
        builder.add_box_collision(half_size=list(size), **kw)
    elif shape.kind == "sphere" and len(size) == 1:
        builder.add_sphere_collision(radius=size[0], **kw)
    elif shape.kind == "capsule" and len(size) == 2:  # SAPIEN's capsule axis is local x, as in PrimitiveShape
        builder.add_capsule_collision(radius=size[0], half_length=size[1], **kw)
    elif shape.kind == "cylinder" and len(size) == 2:
        builder.add_cylinder_collision(radius=size[0], half_length=size[1], **kw)
    else:
        raise AssetError(
            f"object '{obj.object_id}': bad {shape.kind} size {size}; box takes 3 half extents, sphere (radius,), "
            "capsule and cylinder (radius, half_length)"
        )


def set_contact_offset(bodies: list[sapien.physx.PhysxRigidBaseComponent], offset: float | None) -> None:
    """Set every collision shape's contact offset (m); None keeps SAPIEN's default of 0.01 m."""
    if offset is None:
        return
    for body in bodies:
        for shape in body.get_collision_shapes():
            shape.set_contact_offset(offset)


def rest_height(entity: sapien.Entity) -> float:
    """z of the object frame that puts its lowest collision point ``REST_MARGIN`` above the table.

    Uses the shapes' tight world bounding box at the identity orientation.
    """
    body = entity.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    entity.pose = sapien.Pose()
    z_min = float(body.compute_global_aabb_tight()[0, 2])
    return -z_min + REST_MARGIN
